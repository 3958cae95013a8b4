//! The page's tables from `report.json`: the paper's per-view comparison (mean luminance,
//! spread and chromaticity, photo against re-render, per shape) and each view's capture
//! calibration (exposure, white balance, what fixed them, the pose's residual shift) and pose
//! correction.

use super::html::{esc, num, pct, table};
use crate::report::{PoseCorrection, Report, ViewCapture};

/// The paper's table: one row per view and shape.
pub fn paper_table(r: &Report) -> String {
    let rows: Vec<Vec<String>> = r
        .table
        .iter()
        .map(|t| {
            let dy =
                (t.mean_luminance[1] - t.mean_luminance[0]) / t.mean_luminance[0].abs().max(1e-30);
            vec![
                esc(&t.view),
                esc(&t.shape),
                t.pixels.to_string(),
                num(t.mean_luminance[0]),
                num(t.mean_luminance[1]),
                pct(dy, 2),
                num(t.std_luminance[0]),
                num(t.std_luminance[1]),
                format!("({:.4}, {:.4})", t.xy[0][0], t.xy[0][1]),
                format!("({:.4}, {:.4})", t.xy[1][0], t.xy[1][1]),
            ]
        })
        .collect();
    let head = [
        "view",
        "shape",
        "pixels",
        "mean Y photo",
        "mean Y render",
        "difference",
        "std Y photo",
        "std Y render",
        "xy photo",
        "xy render",
    ];
    format!(
        "<p>Over the pixels where a view sees a shape cleanly (no silhouette or depth edge): the \
         photo's and the re-render's mean and spread of luminance Y (scene radiance units) and \
         CIE xy chromaticity of the mean colour.</p>{}",
        table(&head, &rows)
    )
}

/// Each view's gain and how it agrees after calibration.
pub fn capture_table(capture: &[ViewCapture]) -> String {
    let rows: Vec<Vec<String>> = capture
        .iter()
        .map(|c| {
            let e = c.exposure();
            let wb = c.gain.map(|g| g / e.max(1e-30));
            let source = serde_json::to_value(c.source)
                .ok()
                .and_then(|v| v.as_str().map(String::from))
                .unwrap_or_default();
            let check = c.check.as_ref();
            vec![
                esc(&c.view),
                num(e as f64),
                format!("{:+.2} EV", e.log2()),
                format!("[{:.3}, {:.3}, {:.3}]", wb[0], wb[1], wb[2]),
                esc(&source),
                c.anchor_pixels.to_string(),
                check.map_or("-".into(), |k| {
                    format!("[{:.3}, {:.3}, {:.3}]", k.ratio[0], k.ratio[1], k.ratio[2])
                }),
                check.map_or("-".into(), |k| pct(k.disagreeing as f64, 2)),
                check
                    .and_then(|k| k.shift)
                    .map_or("-".into(), |s| format!("({:.2}, {:.2}) px", s[0], s[1])),
            ]
        })
        .collect();
    let head = [
        "view",
        "exposure (gain)",
        "exposure",
        "white balance (R, G, B)",
        "fixed by",
        "light pixels",
        "photo / re-render after",
        "disagreeing",
        "pose shift",
    ];
    format!(
        "<p>Each photo's gain (photo = gain x radiance): its exposure (the luminance-weighted \
         mean) and white balance (the channels over it), what fixed it, and how the view agrees \
         with the others afterwards.</p>{}",
        table(&head, &rows)
    )
}

/// Each view's pose correction (`[views] refine_pose`): what was found, whether it was used.
pub fn pose_table(poses: &[PoseCorrection]) -> String {
    let rows: Vec<Vec<String>> = poses
        .iter()
        .map(|c| {
            vec![
                esc(&c.view),
                match c.applied {
                    true => "moved".into(),
                    false => format!("kept the scene's ({})", esc(&c.status)),
                },
                format!("{:.3} deg", c.rotation_deg),
                pct(c.translation_rel, 2),
                format!("{:.2} px", c.shift_px),
                format!(
                    "{} &rarr; {}",
                    pct(c.residual_before, 2),
                    pct(c.residual_after, 2)
                ),
                format!(
                    "{:.2} px &rarr; {:.2} px",
                    c.edge_px_before, c.edge_px_after
                ),
                c.iterations.to_string(),
            ]
        })
        .collect();
    let head = [
        "view",
        "pose",
        "rotation",
        "translation (of the distance)",
        "mean pixel shift",
        "residual against the others",
        "off the mesh's edges (median)",
        "iterations",
    ];
    format!(
        "<p>Each camera's pose as refined against the other views (at most 2 degrees and 2% of \
         the viewing distance): the correction found, the photo's mean relative difference \
         from the others' re-render before and after, and the median distance between the \
         geometry's edges as the camera projects them and the photo's edges.</p>{}",
        table(&head, &rows)
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pose_table_says_which_views_moved_and_by_how_much() {
        let moved = PoseCorrection {
            view: "cam_a".into(),
            applied: true,
            status: "aligned".into(),
            rotation_deg: 0.2134,
            translation_rel: 0.004,
            shift_px: 1.38,
            edge_px_before: 1.27,
            edge_px_after: 0.21,
            ..Default::default()
        };
        let kept = PoseCorrection {
            view: "cam_b".into(),
            status: "beyond the bound".into(),
            applied: false,
            ..moved.clone()
        };
        let html = pose_table(&[moved, kept]);
        let a = "<td>cam_a</td><td>moved</td><td class=\"n\">0.213 deg</td>";
        assert!(html.contains(a), "{html}");
        assert!(html.contains("<td>cam_b</td><td>kept the scene's (beyond the bound)</td>"));
        assert!(html.contains("1.38 px"), "{html}");
        assert!(html.contains("1.27 px &rarr; 0.21 px"), "{html}");
    }
}
