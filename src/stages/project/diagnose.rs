//! Whether a view still disagrees with the others after calibration, and why: from its last
//! refinement pass (its photo against the re-render of the maps all views made), the
//! signatures of a bad capture, in figures a user can act on:
//! - an exposure left over: the photo / re-render ratio's median per channel is not 1;
//! - disagreement beyond the noise: the share of the texels it sees where the robust fusion
//!   finds it further from the estimate than [`super::DISAGREE_Z`] times its noise and the
//!   spread views are expected to have (misregistration, something that moved, highlights);
//! - a residual misalignment in pixels, where the pose refinement measured one.

use super::PixelInfo;
use crate::image::Image;
use crate::report::ViewCheck;
use crate::scene::luminance;
use glam::Vec3;

/// An exposure left over larger than this share is reported.
pub const RATIO_LIMIT: f32 = 0.02;
/// A shift larger than this many pixels is reported.
pub const SHIFT_LIMIT: f32 = 0.5;
/// A view disagreeing at more than this share of its texels is reported.
pub const DISAGREE_LIMIT: f32 = 0.03;

/// The view's check from its photo and its re-render (filtered as the photo is; `None` where
/// not rendered) over its pixels' classification; its `disagreeing` share is 0 until
/// [`with_agreement`] gives it the pass's texel counts.
pub fn check(photo: &Image, render: &[Option<Vec3>], pixels: &[PixelInfo]) -> ViewCheck {
    let mut ratios: [Vec<f32>; 3] = Default::default();
    let mut n = 0u64;
    for ((ph, r), px) in photo.pixels.iter().zip(render).zip(pixels) {
        let Some(r) = r.filter(|r| px.clean && luminance(*r) > 0.0) else {
            continue;
        };
        n += 1;
        for c in 0..3 {
            if r[c] > 0.0 {
                ratios[c].push(ph[c] / r[c]);
            }
        }
    }
    ViewCheck {
        pixels: n,
        ratio: ratios.map(|mut v| median(&mut v)),
        disagreeing: 0.0,
        shift: None,
    }
}

/// `check` with the share of the `texels` the view saw in the pass at which it was
/// `disagreeing`.
pub fn with_agreement(check: ViewCheck, (texels, disagreeing): (u64, u64)) -> ViewCheck {
    ViewCheck {
        disagreeing: if texels > 0 {
            disagreeing as f32 / texels as f32
        } else {
            0.0
        },
        ..check
    }
}

fn median(v: &mut [f32]) -> f32 {
    if v.is_empty() {
        return 1.0;
    }
    let k = v.len() / 2;
    *v.select_nth_unstable_by(k, f32::total_cmp).1
}

/// One note per view the check flags, naming the likely cause with its figures.
pub fn notes(views: &[String], checks: &[ViewCheck]) -> Vec<String> {
    let mut out = Vec::new();
    for (id, c) in views.iter().zip(checks) {
        let mut causes = Vec::new();
        let ratio = 0.2126 * c.ratio[0] + 0.7152 * c.ratio[1] + 0.0722 * c.ratio[2];
        if (ratio - 1.0).abs() > RATIO_LIMIT {
            causes.push(format!(
                "its exposure is off by {:+.1}% after calibration (photo / re-render {:.3}, \
                 per channel {:.3} {:.3} {:.3})",
                100.0 * (ratio - 1.0),
                ratio,
                c.ratio[0],
                c.ratio[1],
                c.ratio[2]
            ));
        }
        let shift = c.shift.map(|s| (s[0].powi(2) + s[1].powi(2)).sqrt());
        if let Some(s) = shift.filter(|&s| s > SHIFT_LIMIT) {
            causes.push(format!(
                "it is misaligned by about {s:.1} px: its pose or the mesh is off"
            ));
        }
        if c.disagreeing > DISAGREE_LIMIT {
            causes.push(format!(
                "it departs from the others beyond its noise at {:.1}% of the texels it sees \
                 (misregistration, something that moved, or highlights)",
                100.0 * c.disagreeing
            ));
        }
        if !causes.is_empty() {
            out.push(format!(
                "view {id} disagrees with the others: {}",
                causes.join("; ")
            ));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pixel(clean: bool) -> PixelInfo {
        PixelInfo {
            shape: 0,
            normal: Vec3::Z,
            plane: 0.0,
            clean,
        }
    }

    #[test]
    fn an_exposure_left_over_and_disagreement_are_named_with_their_figures() {
        let n = 64;
        let render: Vec<Option<Vec3>> = (0..n)
            .map(|i| Some(Vec3::new(0.5, 0.4, 0.3) * (1.0 + i as f32 / n as f32)))
            .collect();
        let photo = Image {
            width: 8,
            height: 8,
            pixels: render
                .iter()
                .map(|r| r.unwrap() * Vec3::new(1.1, 1.05, 1.0))
                .collect(),
            valid: vec![true; n],
            masked: 0,
        };
        // an unclean pixel with a wild value does not count
        let mut pixels = vec![pixel(true); n];
        pixels[3] = pixel(false);
        let mut photo = photo;
        photo.pixels[3] *= 10.0;
        let c = with_agreement(check(&photo, &render, &pixels), (1000, 80));
        assert_eq!(c.pixels, 63);
        for (got, want) in c.ratio.iter().zip([1.1, 1.05, 1.0]) {
            assert!((got - want).abs() < 1e-5, "{got} vs {want}");
        }
        assert_eq!(c.disagreeing, 0.08);
        let notes = notes(&["cam".into()], std::slice::from_ref(&c));
        assert_eq!(notes.len(), 1);
        assert!(
            notes[0].contains("+5.7%") && notes[0].contains("8.0% of the texels"),
            "{notes:?}"
        );
        // within the limits: silent
        let quiet = ViewCheck {
            ratio: [1.01; 3],
            disagreeing: 0.01,
            ..c
        };
        assert!(super::notes(&["cam".into()], &[quiet]).is_empty());
    }
}
