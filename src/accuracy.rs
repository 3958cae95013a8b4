//! Scoring a finished run against a ground-truth albedo (`kdmap accuracy`, the tests, the
//! nightly harness): the true reflectance of each shape (`scene::truth`) baked into the run's
//! atlas, averaged over each texel's square, compared with the recovered `K_d` over the texels
//! a camera saw. Reads the run's settings from `report.json` and its final state from the
//! checkpoint directory, and writes `<out>/accuracy/`: `accuracy.json` (with the calibration
//! of the run's predicted standard errors, see `confidence`), and per shape
//! `<id>_truth.exr|png` (the true albedo in the run's atlas; the PNG in sRGB at exposure 0,
//! comparable with `textures/<id>_albedo.png`) and `<id>_diff.png` (`|K_d - K_true|` per
//! channel, x4).

use crate::atlas::store::TileStore;
use crate::atlas::store::{flags, TexelGeom, TexelState};
use crate::atlas::texture::read_slot;
use crate::atlas::uv::ShapeAtlas;
use crate::atlas::{prepare_layout, state_dir, RunContext};
use crate::base::error::{Error, Result};
use crate::base::fsio;
use crate::base::progress::Mode;
use crate::image::{write_exr_rgb, write_png_srgb};
use crate::report::Report;
use crate::scene::truth::{Reflectance, Truth};
use crate::scene::{luminance, Mesh, Rgb};
use crate::stages::confidence::{kd_rel_stderr, Calibration, CalibrationSums};
use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Accuracy of one shape's recovered albedo against the truth, over its observed texels.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ShapeAccuracy {
    pub shape: String,
    pub texels: u64,
    /// Mean over texels of `sum_c |K_d - K_true| / sum_c K_true`. Dominated by dark texels
    /// on textured shapes, where a small absolute error is a large relative one.
    pub mean_rel_error: f64,
    /// Relative L1 error of the whole texture: `sum |K_d - K_true| / sum K_true` over texels
    /// and channels.
    pub rel_l1_error: f64,
    /// Mean recovered and true RGB over the texels.
    pub mean_kd: [f64; 3],
    pub mean_truth: [f64; 3],
}

/// Samples per axis of a texel's square when averaging the truth over it.
const FOOTPRINT_SAMPLES: u32 = 4;

/// The true albedo averaged over texel `(x, y)`'s square of the atlas, mapped onto the
/// plane of triangle `tri` (the affine extension of the triangle's atlas -> mesh-UV map):
/// a texel stands for the mean albedo over its square, so this is what it should hold.
/// Texture detail finer than a texel is averaged, as any texture of that resolution must.
fn footprint_mean(
    r: &Reflectance,
    mesh: &Mesh,
    atlas: &ShapeAtlas,
    tri: usize,
    x: u32,
    y: u32,
) -> Rgb {
    if let Reflectance::Constant(c) = r {
        return *c;
    }
    let [a0, a1, a2] = atlas.corner_uv[tri];
    let (e1, e2) = (a1 - a0, a2 - a0);
    let det = e1.perp_dot(e2);
    if det == 0.0 {
        return r.eval(mesh, tri, 0.0, 0.0);
    }
    let n = FOOTPRINT_SAMPLES;
    let mut sum = Vec3::ZERO;
    for j in 0..n {
        for i in 0..n {
            let q = Vec2::new(
                x as f32 + (i as f32 + 0.5) / n as f32,
                y as f32 + (j as f32 + 0.5) / n as f32,
            ) - a0;
            let b1 = q.perp_dot(e2) / det;
            let b2 = e1.perp_dot(q) / det;
            sum += r.eval(mesh, tri, b1, b2);
        }
    }
    sum / (n * n) as f32
}

/// The true albedo of every covered texel of layout slot `slot`, averaged over the texel's
/// square (row-major, `None` where uncovered), or `None` if the slot's shape has no truth.
pub fn bake_slot(
    truth: &Truth,
    p: &RunContext,
    geom: &TileStore<TexelGeom>,
    slot: usize,
) -> Result<Option<Vec<Option<Rgb>>>> {
    let st = p.layout.slots[slot];
    let shape = &p.scene.shapes[st.shape];
    let Some(r) = truth.shapes.get(&shape.id) else {
        return Ok(None);
    };
    let atlas = p.atlases[st.shape].as_ref();
    let mut out = vec![None; (st.width * st.height) as usize];
    for tile in p.layout.slot_tiles(slot) {
        let g = geom.read_tile(tile as usize)?;
        for (off, x, y) in p.layout.span(tile).texels() {
            let g = &g[off];
            if !g.covered() {
                continue;
            }
            let tri = g.tri as usize;
            out[(y * st.width + x) as usize] = Some(match atlas {
                Some(a) => footprint_mean(r, &shape.mesh, a, tri, x, y),
                None => {
                    let (b1, b2) = shape.mesh.barycentric(tri, g.p());
                    r.eval(&shape.mesh, tri, b1, b2)
                }
            });
        }
    }
    Ok(Some(out))
}

/// Compare the recovered `K_d` of every reconstructed shape that has a truth with it, over
/// observed texels (those a camera saw), shape by shape. The truth of a texel is the true
/// albedo averaged over the texel's square ([`bake_slot`]).
pub fn accuracy(
    truth: &Truth,
    p: &RunContext,
    geom: &TileStore<TexelGeom>,
    state: &TileStore<TexelState>,
) -> Result<Vec<ShapeAccuracy>> {
    let mut out = Vec::new();
    for slot in 0..p.layout.slots.len() {
        if let Some(s) = score_slot(truth, p, geom, state, slot)? {
            out.push(s.accuracy);
        }
    }
    Ok(out)
}

/// [`accuracy`] of one layout slot, with the baked truth and the recovered `K_d` of every
/// texel it was computed from (row-major), or `None` if the slot's shape has no truth.
pub fn score_slot(
    truth: &Truth,
    p: &RunContext,
    geom: &TileStore<TexelGeom>,
    state: &TileStore<TexelState>,
    slot: usize,
) -> Result<Option<SlotScore>> {
    let Some(truth) = bake_slot(truth, p, geom, slot)? else {
        return Ok(None);
    };
    let per_texel = read_slot(&p.layout, slot, state, geom, |s, _| {
        (
            Vec3::from_array(s.k_d),
            s.flags & flags::OBSERVED != 0,
            kd_rel_stderr(s),
        )
    })?;
    let k_d: Vec<Vec3> = per_texel.iter().map(|t| t.0).collect();
    let observed: Vec<bool> = per_texel.iter().map(|t| t.1).collect();
    let stderr: Vec<Option<f32>> = per_texel.iter().map(|t| t.2).collect();
    let mut acc = ShapeAccuracy {
        shape: p.slot_id(slot).to_string(),
        ..Default::default()
    };
    let mut sum_true = 0.0f64;
    for ((kd, k_true), obs) in k_d.iter().zip(&truth).zip(&observed) {
        let Some(k_true) = k_true else { continue };
        let den = k_true.element_sum() as f64;
        if !obs || den <= 0.0 {
            continue;
        }
        let diff = (*kd - *k_true).abs().element_sum() as f64;
        acc.mean_rel_error += diff / den;
        acc.rel_l1_error += diff;
        sum_true += den;
        for c in 0..3 {
            acc.mean_kd[c] += kd[c] as f64;
            acc.mean_truth[c] += k_true[c] as f64;
        }
        acc.texels += 1;
    }
    let n = acc.texels.max(1) as f64;
    acc.mean_rel_error /= n;
    acc.rel_l1_error /= sum_true.max(f64::MIN_POSITIVE);
    for c in 0..3 {
        acc.mean_kd[c] /= n;
        acc.mean_truth[c] /= n;
    }
    Ok(Some(SlotScore {
        accuracy: acc,
        truth,
        k_d,
        stderr,
    }))
}

/// One slot scored by [`score_slot`].
#[derive(Debug, Clone)]
pub struct SlotScore {
    pub accuracy: ShapeAccuracy,
    /// The true albedo per texel, averaged over its square (`None` where uncovered).
    pub truth: Vec<Option<Rgb>>,
    /// The recovered `K_d` per texel (observed or filled).
    pub k_d: Vec<Vec3>,
    /// The predicted relative standard error of its luminance (observed texels).
    pub stderr: Vec<Option<f32>>,
}

impl SlotScore {
    /// Add every texel with a prediction and a truth to `sums`: predicted relative standard
    /// error of `K_d`'s luminance against its actual relative error.
    pub fn calibrate(&self, sums: &mut CalibrationSums) {
        for ((kd, t), pred) in self.k_d.iter().zip(&self.truth).zip(&self.stderr) {
            let (Some(t), Some(pred)) = (t, pred) else {
                continue;
            };
            let yt = luminance(*t) as f64;
            if yt > 0.0 {
                sums.add(*pred as f64, (luminance(*kd) as f64 - yt) / yt);
            }
        }
    }
}
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
    /// The run's predicted standard errors of `K_d` against its actual errors (see
    /// `confidence`).
    #[serde(default)]
    pub calibration: Calibration,
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
            calibration: Calibration::default(),
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
    let p = prepare_layout(&report.settings, Mode::Quiet)?;
    let dir = state_dir(out);
    let geom: TileStore<TexelGeom> = p.open_store(dir.join("geometry.tiles"))?;
    let state: TileStore<TexelState> = p.open_store(dir.join("state.tiles"))?;
    let mut scores = Vec::new();
    for slot in 0..p.layout.slots.len() {
        if let Some(score) = score_slot(&truth, &p, &geom, &state, slot)? {
            scores.push((slot, score));
        }
    }
    // A truth that scores no texel would print a meaningless 0.00%: refuse it, naming the
    // shapes it could have covered.
    if scores.iter().all(|(_, s)| s.accuracy.texels == 0) {
        let ids: Vec<&str> = (0..p.layout.slots.len()).map(|s| p.slot_id(s)).collect();
        let what = if scores.is_empty() {
            "states the reflectance of none of the run's reconstructed shapes"
        } else {
            "states the reflectance only of shapes no camera observed"
        };
        return Err(Error::input(
            truth_xml,
            format!("{what} (by shape id: {})", ids.join(", ")),
        ));
    }
    let adir = out.join("accuracy");
    fsio::create_dir(&adir)?;
    let mut acc = Vec::new();
    let mut calibration = CalibrationSums::default();
    for (slot, score) in scores {
        score.calibrate(&mut calibration);
        let st = p.layout.slots[slot];
        let id = p.slot_id(slot);
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
    let mut rep = AccuracyReport::new(acc);
    rep.calibration = calibration.finish();
    let json = serde_json::to_vec_pretty(&rep)
        .map_err(|e| Error::internal(format!("cannot encode accuracy: {e}")))?;
    fsio::write_atomic(&adir.join("accuracy.json"), &json)?;
    Ok(rep)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit square (two triangles) whose mesh UVs equal its positions, unwrapped onto a
    /// `n x n` atlas flipped vertically (atlas y down, UV v up), and a `m x m` bitmap.
    fn square(n: u32, m: u32, texel: impl Fn(u32, u32) -> f32) -> (Mesh, ShapeAtlas, Reflectance) {
        let pts = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)];
        let mesh = Mesh {
            positions: pts.iter().map(|&(x, y)| Vec3::new(x, y, 0.0)).collect(),
            uvs: Some(pts.iter().map(|&(x, y)| Vec2::new(x, y)).collect()),
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            ..Default::default()
        };
        let atlas = ShapeAtlas {
            width: n,
            height: n,
            corner_uv: mesh
                .triangles
                .iter()
                .map(|t| {
                    t.map(|i| {
                        let (x, y) = pts[i as usize];
                        Vec2::new(x * n as f32, (1.0 - y) * n as f32)
                    })
                })
                .collect(),
            charts: 1,
            texel_density: n as f32,
            levels: 0,
        };
        let texels = (0..m * m)
            .map(|i| Vec3::splat(texel(i % m, i / m)))
            .collect();
        let r = Reflectance::Bitmap {
            width: m,
            height: m,
            texels,
        };
        (mesh, atlas, r)
    }

    #[test]
    fn footprint_mean_of_a_fine_checkerboard_is_its_average() {
        // Each atlas texel covers 4 x 4 bitmap texels of a 1-texel checkerboard: a point
        // sample sees 0 or 1 (or a bilinear blend), the texel's mean is 1/2.
        let (mesh, atlas, r) = square(8, 32, |x, y| ((x + y) % 2) as f32);
        for (x, y) in [(0, 0), (3, 5), (7, 7), (5, 1)] {
            let tri = if x > 7 - y { 0 } else { 1 };
            let m = footprint_mean(&r, &mesh, &atlas, tri, x, y);
            assert!((m.x - 0.5).abs() < 1e-6, "({x}, {y}): {m}");
        }
    }

    #[test]
    fn footprint_mean_matches_brute_force_over_the_texel_square() {
        // A smooth pattern: the 4 x 4 sample mean must match a dense brute-force average of
        // the bilinear texture over the same square, located through plain barycentrics.
        let (mesh, atlas, r) = square(5, 16, |x, y| (x as f32 * 0.3).sin() + 0.1 * y as f32);
        for (x, y) in [(0, 0), (2, 3), (4, 1)] {
            let tri = 0; // the affine extension makes either triangle's map the same here
            let fast = footprint_mean(&r, &mesh, &atlas, tri, x, y).x;
            let k = 64;
            let mut sum = 0.0f64;
            for j in 0..k {
                for i in 0..k {
                    let u = (x as f32 + (i as f32 + 0.5) / k as f32) / 5.0;
                    let v = 1.0 - (y as f32 + (j as f32 + 0.5) / k as f32) / 5.0;
                    let (b1, b2) = mesh.barycentric(tri, Vec3::new(u, v, 0.0));
                    sum += r.eval(&mesh, tri, b1, b2).x as f64;
                }
            }
            let brute = (sum / (k * k) as f64) as f32;
            assert!((fast - brute).abs() < 0.02, "({x}, {y}): {fast} vs {brute}");
        }
        // Constant reflectances are returned as they are.
        let c = Reflectance::Constant(Vec3::new(0.1, 0.2, 0.3));
        assert_eq!(
            footprint_mean(&c, &mesh, &atlas, 0, 1, 1),
            Vec3::new(0.1, 0.2, 0.3)
        );
    }
}
