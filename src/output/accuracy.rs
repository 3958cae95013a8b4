//! `kdmap accuracy`: scores a finished run against a ground-truth albedo (a Mitsuba
//! `truth.xml`, as shipped with the examples), for benchmarks and the nightly harness. Reads
//! the run's settings from `report.json` and its final state from `<out>/checkpoint`, and
//! writes `<out>/accuracy/`: `accuracy.json`, and per textured shape `<id>_truth.exr|png` (the
//! true albedo baked into the run's atlas, averaged over each texel; the PNG in sRGB at
//! exposure 0, comparable with `textures/<id>_albedo.png`) and `<id>_diff.png` (`|K_d - K_true|` per channel, x4).

use crate::atlas::layout::{TexelGeom, TexelState};
use crate::atlas::tiles::TileStore;
use crate::image::{write_exr_rgb, write_png_srgb};
use crate::pipeline::{prepare, state_dir};
use crate::progress::Mode;
use crate::report::Report;
use crate::truth::{ShapeAccuracy, Truth};
use crate::{Error, Result};
use glam::Vec3;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Gain of the difference preview.
const DIFF_GAIN: f32 = 4.0;

/// What `accuracy.json` holds.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AccuracyReport {
    /// Texel-weighted mean over shapes of the per-texel mean relative error.
    pub mean_rel_error: f64,
    /// Relative L1 error over all shapes' texels and channels.
    pub rel_l1_error: f64,
    pub shapes: Vec<ShapeAccuracy>,
}

impl AccuracyReport {
    pub fn new(shapes: Vec<ShapeAccuracy>) -> AccuracyReport {
        let n: u64 = shapes.iter().map(|a| a.texels).sum();
        let mean = shapes
            .iter()
            .map(|a| a.mean_rel_error * a.texels as f64)
            .sum::<f64>()
            / n.max(1) as f64;
        let (mut num, mut den) = (0.0, 0.0);
        for a in &shapes {
            let t = a.mean_truth.iter().sum::<f64>() * a.texels as f64;
            num += a.rel_l1_error * t;
            den += t;
        }
        AccuracyReport {
            mean_rel_error: mean,
            rel_l1_error: num / f64::max(den, f64::MIN_POSITIVE),
            shapes,
        }
    }
}

/// Score the run in `out` against `truth_xml` and write `<out>/accuracy/`.
pub fn score_run(out: &Path, truth_xml: &Path) -> Result<AccuracyReport> {
    let rp = out.join("report.json");
    let text = std::fs::read_to_string(&rp).map_err(|e| Error::io(&rp, e))?;
    let report: Report = serde_json::from_str(&text)
        .map_err(|e| Error::input(&rp, format!("not a kdmap report: {e}")))?;
    let truth = Truth::load(truth_xml)?;
    let p = prepare(&report.settings, Mode::Quiet)?;
    let dir = state_dir(out);
    let geom: TileStore<TexelGeom> = TileStore::open(dir.join("geometry.tiles"))?;
    let state: TileStore<TexelState> = TileStore::open(dir.join("state.tiles"))?;
    let adir = out.join("accuracy");
    std::fs::create_dir_all(&adir).map_err(|e| Error::io(&adir, e))?;
    let mut acc = Vec::new();
    for slot in 0..p.layout.slots.len() {
        let Some(score) = truth.score_slot(&p, &geom, &state, slot)? else {
            continue;
        };
        let st = p.layout.slots[slot];
        let id = &p.scene.shapes[st.shape].id;
        let tv: Vec<Vec3> = score
            .truth
            .iter()
            .map(|v| v.unwrap_or(Vec3::ZERO))
            .collect();
        let diff: Vec<Vec3> = score
            .k_d
            .iter()
            .zip(&score.truth)
            .map(|(k, t)| t.map_or(Vec3::ZERO, |t| (*k - t).abs() * DIFF_GAIN))
            .collect();
        let (w, h) = (st.width, st.height);
        write_exr_rgb(adir.join(format!("{id}_truth.exr")), w, h, &tv, false)?;
        write_png_srgb(adir.join(format!("{id}_truth.png")), w, h, &tv, 0.0)?;
        write_png_srgb(adir.join(format!("{id}_diff.png")), w, h, &diff, 0.0)?;
        acc.push(score.accuracy);
    }
    let rep = AccuracyReport::new(acc);
    let json = serde_json::to_vec_pretty(&rep)
        .map_err(|e| Error::input(out, format!("cannot encode accuracy: {e}")))?;
    super::write_file_atomic(&adir.join("accuracy.json"), &json)?;
    Ok(rep)
}
