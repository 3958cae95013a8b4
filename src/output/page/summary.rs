//! The page's first section: what was run, on what, how long it took and how well it fits,
//! the scores against a truth where `kdmap accuracy` wrote them, and the run's warnings and
//! notes in plain words (from `report.json`'s figures).

use super::html::{esc, num, pct, secs, table};
use super::Sources;
use crate::report::{GainSource, Report};
use serde_json::Value;
use std::fmt::Write as _;

/// The summary section's body.
pub fn summary(src: &Sources) -> String {
    let mut s = String::new();
    match &src.report {
        Some(r) => {
            s += &facts_list(r);
            s += &fit(r);
        }
        None => {
            s.push_str("<ul class=\"facts\">");
            for line in &src.facts.summary {
                let _ = write!(s, "<li>{}</li>", esc(line));
            }
            s.push_str("</ul>");
        }
    }
    if let Some(a) = &src.accuracy {
        s += &truth_scores(a);
    }
    let notes = src.report.as_ref().map(notes).unwrap_or_default();
    if !notes.is_empty() {
        s.push_str("<h3>Warnings and notes</h3><ul class=\"notes\">");
        for (warn, n) in notes {
            let class = if warn { " class=\"warn\"" } else { "" };
            let _ = write!(s, "<li{class}>{}</li>", esc(&n));
        }
        s.push_str("</ul>");
    }
    s
}

/// Scene, sizes, method, time and memory as a definition list.
fn facts_list(r: &Report) -> String {
    let c = &r.counts;
    let st = &r.settings;
    let peak = r
        .resources
        .peak_rss_mib
        .iter()
        .map(|p| p.1)
        .fold(0.0, f64::max);
    let method = serde_json::to_value(st.method)
        .ok()
        .and_then(|v| v.as_str().map(String::from));
    let rows: Vec<(&str, String)> = vec![
        ("Scene", st.scene.display().to_string()),
        (
            "Shapes",
            format!(
                "{} ({} reconstructed), {} triangles, {} emitters",
                c.shapes, c.reconstructed_shapes, c.triangles, c.emitters
            ),
        ),
        ("Views", c.views.to_string()),
        (
            "Texels",
            format!(
                "{} on surfaces, {} seen by a view ({}), {} filled from neighbours",
                c.covered_texels,
                c.observed_texels,
                pct(ratio(c.observed_texels, c.covered_texels), 1),
                c.filled_texels
            ),
        ),
        (
            "Method",
            format!(
                "{} for the secondary light, {} iterations (stopped by {}), seed {}",
                method.unwrap_or_default(),
                r.iterations.len(),
                r.stopped_by.replace('_', " "),
                st.seed
            ),
        ),
        ("Time", secs(r.timings.total)),
        (
            "Peak memory",
            format!(
                "{peak:.0} MiB (budget {} MiB for per-texel data)",
                r.resources.memory_budget_mib
            ),
        ),
    ];
    let mut s = String::from("<dl class=\"facts\">");
    for (k, v) in rows {
        let _ = write!(s, "<dt>{k}</dt><dd>{}</dd>", esc(&v));
    }
    s.push_str("</dl>");
    s
}

/// `a / b`, 0 when `b` is 0.
fn ratio(a: u64, b: u64) -> f64 {
    a as f64 / b.max(1) as f64
}

/// The run's own fit: the last iteration's relative errors and the confidence of `K_d`.
fn fit(r: &Report) -> String {
    let s = String::from("<h3>Fit to the photos</h3>");
    let Some(last) = r.iterations.last() else {
        return s + "<p>No solver iteration ran.</p>";
    };
    let k = &r.confidence;
    let rows = vec![
        vec![
            "relative error of the re-rendered luminance, RMS over observed texels".into(),
            pct(last.rms_rel_error, 3),
        ],
        vec!["... mean".into(), pct(last.mean_rel_error, 3)],
        vec!["... largest".into(), pct(last.max_rel_error, 2)],
        vec![
            "standard error of K_d, median (relative)".into(),
            pct(k.kd_rel_stderr_median, 2),
        ],
        vec!["... 90th percentile".into(), pct(k.kd_rel_stderr_p90, 2)],
    ];
    s + &table(&["figure", "value"], &rows)
}

/// The scores of `accuracy/accuracy.json`: per shape and for the scene.
fn truth_scores(a: &Value) -> String {
    let f = |v: &Value, k: &str| v[k].as_f64().unwrap_or(f64::NAN);
    let mut s = String::from("<h3>Against the true albedo</h3>");
    let _ = write!(
        s,
        "<p>Scene: mean relative albedo error <b>{}</b>, relative L1 <b>{}</b> (<a href=\"accuracy/accuracy.json\">accuracy/accuracy.json</a>).</p>",
        pct(f(a, "mean_rel_error"), 2),
        pct(f(a, "rel_l1_error"), 2)
    );
    let triple = |v: &Value| {
        let t: Vec<String> = v
            .as_array()
            .into_iter()
            .flatten()
            .map(|x| num(x.as_f64().unwrap_or(f64::NAN)))
            .collect();
        format!("[{}]", t.join(", "))
    };
    let rows: Vec<Vec<String>> = a["shapes"]
        .as_array()
        .into_iter()
        .flatten()
        .map(|sh| {
            vec![
                esc(sh["shape"].as_str().unwrap_or("")),
                sh["texels"].as_u64().unwrap_or(0).to_string(),
                pct(f(sh, "mean_rel_error"), 2),
                pct(f(sh, "rel_l1_error"), 2),
                triple(&sh["mean_kd"]),
                triple(&sh["mean_truth"]),
            ]
        })
        .collect();
    s + &table(
        &[
            "shape",
            "texels",
            "mean rel. error",
            "rel. L1",
            "mean K_d",
            "true K_d",
        ],
        &rows,
    )
}

/// The run's warnings (`true`) and notes in plain words.
pub fn notes(r: &Report) -> Vec<(bool, String)> {
    // the run's own warnings (the console's last lines) first
    let mut n: Vec<(bool, String)> = r.warnings.iter().map(|w| (true, w.clone())).collect();
    let c = &r.counts;
    if r.stopped_by == "max_iterations" {
        n.push((false, format!("The solver stopped after the most iterations allowed ({}), not because the error stopped changing.", r.iterations.len())));
    }
    let filled = ratio(c.filled_texels, c.covered_texels);
    if filled > 0.0 {
        n.push((filled > 0.5, format!("{} of the surface texels ({}) were seen by no view; their albedo is filled in from their neighbours and is a guess.", c.filled_texels, pct(filled, 1))));
    }
    for a in r
        .atlas
        .iter()
        .filter_map(|a| a.limited_by.as_ref().map(|l| (a, l)))
    {
        n.push((
            false,
            format!(
                "The texture of '{}' is coarser than the photos allow, held down by {}.",
                a.0.shape,
                a.1.replace('_', " ")
            ),
        ));
    }
    for v in &r.capture {
        if v.source == GainSource::Alone {
            n.push((true, format!("View '{}' shares too little with the others and shows no light: its exposure could not be estimated and was left at 1.", v.view)));
        }
        if let Some(ch) = v.check.as_ref().filter(|ch| ch.disagreeing > 0.05) {
            n.push((true, format!("View '{}' disagrees with the others on {} of the texels it sees (misalignment, or something moved).", v.view, pct(ch.disagreeing as f64, 1))));
        }
    }
    let k = &r.confidence;
    if k.texels_with_disagreement > 0 {
        n.push((false, format!("{} texels had a view that disagreed with the others; that view was down-weighted there.", k.texels_with_disagreement)));
    }
    if c.material_filled_shapes > 0 {
        n.push((
            false,
            format!(
                "{} shapes no photo saw took the mean albedo of the seen shapes of their material.",
                c.material_filled_shapes
            ),
        ));
    }
    if c.fill_unrelaxed_texels > 0 {
        n.push((true, format!("{} filled texels were not smoothed: their texture did not fit in the memory budget.", c.fill_unrelaxed_texels)));
    }
    n.extend(r.uv_fold.iter().map(|f| (false, f.summary())));
    n.extend(r.refinement.summary().map(|s| (false, s)));
    n
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Config;

    #[test]
    fn the_run_s_warnings_come_first_as_warnings() {
        let mut r = Report::new(Config::for_scene("s.xml".into()));
        r.warnings = vec!["photos observed 2.1% of the covered texels".into()];
        r.stopped_by = "max_iterations".into();
        let n = notes(&r);
        assert_eq!(n[0], (true, r.warnings[0].clone()));
        assert!(n.len() >= 2 && !n[1].0);
    }

    #[test]
    fn notes_name_the_iteration_limit_and_the_unseen_share() {
        let mut r = Report::new(Config::for_scene("s.xml".into()));
        r.stopped_by = "max_iterations".into();
        r.counts.covered_texels = 100;
        r.counts.filled_texels = 60;
        let n = notes(&r);
        assert!(n[0].1.contains("most iterations"), "{n:?}");
        assert!(n[1].0 && n[1].1.contains("60.0%"), "{n:?}");
        r.stopped_by = "tolerance".into();
        r.counts.filled_texels = 0;
        assert!(notes(&r).is_empty());
    }
}
