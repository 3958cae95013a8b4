//! The page's plots, from `report.json`: the error per solver iteration, the refinement's
//! residual per pass and view, the time per stage and the peak memory after each stage.

use super::html::esc;
use super::svg::{bar_chart, line_chart, Series};
use crate::report::Report;

/// The plots section's body.
pub fn figures(r: &Report) -> String {
    let mut s = String::new();
    let it = |f: fn(&crate::report::IterationStats) -> f64| -> Vec<(f64, f64)> {
        r.iterations
            .iter()
            .map(|i| (i.iteration as f64 + 1.0, f(i)))
            .collect()
    };
    if !r.iterations.is_empty() {
        let series = [
            Series {
                name: "RMS".into(),
                points: it(|i| i.rms_rel_error),
            },
            Series {
                name: "mean".into(),
                points: it(|i| i.mean_rel_error),
            },
        ];
        s += &fig(
            line_chart("relative error per iteration", "iteration", "relative error", &series, true),
            "The re-rendered luminance's relative error over observed texels, per solver iteration (largest: see the table above).",
        );
    }
    if !r.refinement.residual.is_empty() {
        let series: Vec<Series> = r
            .refinement
            .views
            .iter()
            .enumerate()
            .map(|(k, v)| Series {
                name: v.clone(),
                points: r
                    .refinement
                    .residual
                    .iter()
                    .enumerate()
                    .map(|(p, res)| (p as f64, res.get(k).copied().unwrap_or(f64::NAN)))
                    .collect(),
            })
            .collect();
        s += &fig(
            line_chart("projection residual per refinement pass", "pass", "mean relative residual", &series, true),
            "How far each view's render of the projected maps was from its photo before each refinement pass (pass 0: the weighted mean).",
        );
    }
    s += &fig(
        bar_chart("time per stage", "s", &stage_times(r)),
        "Wall time per stage (the projection includes its noise probe and the calibration).",
    );
    let rays: Vec<(String, f64)> = (r.rays.per_core_second(&r.timings).into_iter())
        .map(|(k, _, v)| (k.to_string(), v / 1e6))
        .collect();
    if !rays.is_empty() {
        s += &fig(
            bar_chart("rays cast per second per core", "M rays/s", &rays),
            "Each stage's rays over its wall time and the run's cores. Ray casting alone runs at \
             about 5-10 M rays/s per core on small scenes: a stage far below spends its time \
             elsewhere.",
        );
    }
    let mem: Vec<(String, f64)> = r.resources.peak_rss_mib.clone();
    if !mem.is_empty() {
        s += &fig(
            bar_chart("peak memory after each stage", "MiB", &mem),
            "The process's peak resident memory so far, after each stage.",
        );
    }
    s
}

/// The stages that took time, in run order.
fn stage_times(r: &Report) -> Vec<(String, f64)> {
    let t = &r.timings;
    [
        ("load", t.load),
        ("atlas", t.atlas),
        ("projection", t.projection),
        ("  noise probe", t.noise_probe),
        ("  calibration", t.calibration),
        ("direct light", t.direct),
        ("caustics", t.caustics),
        ("gather", t.gather),
        ("photons", t.photons),
        ("update", t.update),
        ("uniform filter", t.uniform),
        ("output", t.output),
    ]
    .into_iter()
    .filter(|(_, v)| *v >= 0.005)
    .map(|(k, v)| (k.to_string(), v))
    .collect()
}

/// A figure around an inline SVG.
fn fig(svg: String, caption: &str) -> String {
    format!(
        "<figure class=\"plot\">{svg}<figcaption>{}</figcaption></figure>\n",
        esc(caption)
    )
}
