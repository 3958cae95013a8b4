//! The sampling noise of `E_d`, measured on the `E_d` map itself: an environment light's
//! irradiance is a Monte Carlo estimate per texel (stratified sample pairs, each texel its own
//! draws), and its noise goes into `K_d`'s standard error (`TexelState::ed_var`).
//!
//! The estimator is the roughness of the map: per texel, the second differences
//! `E(x - 1) - 2 E(x) + E(x + 1)` (rows and columns) over a window of its own chart, whose
//! spread is `6 var` for independent noise, zero for light that changes linearly, and a common
//! offset where a curved surface bends it (taken out with each direction's median). A median
//! (`1.4826 x` the median absolute deviation) keeps the few at a shadow edge out. It needs
//! nothing of the sampler, so it holds for stratified samples, whose variance the pairs' own
//! spread overstates 1.4-2.4x (measured on envmap's shapes); but it takes light that changes
//! from texel to texel for noise, so the smaller of the two is kept. Medians over texture
//! windows are not something a crate offers, so it is written here.

use crate::atlas::store::TileStore;
use crate::atlas::store::{TexelGeom, TexelState};
use crate::atlas::texture::{Scratch, SlotTexture};
use crate::atlas::uv::NONE;
use crate::atlas::uv::{ChartValue, Charts};
use crate::atlas::RunContext;
use crate::base::error::{Error, Result};
use crate::scene::luminance;
use glam::Vec3;
use rayon::prelude::*;

/// Half the side of the window a texel's noise is measured over (7 x 7 texels).
pub const RADIUS: u32 = 3;
/// Fewest second differences a window needs for an estimate (else 0: not stated).
const MIN_DIFFS: usize = 8;

/// Per covered texel, `ed_var`: the smaller of what the direct stage left there (the sample
/// pairs' spread, an upper bound) and the roughness of the map around it
/// ([`window_variance`], an upper bound where the light itself changes from texel to texel,
/// as across a faceted or small curved mesh: 2-4x on envmap's torus, cylinder and sphere).
/// Both bound the noise from above, so the smaller is the tighter. A scene without an
/// environment light has no sampled `E_d` whose noise is stated: nothing to do.
pub fn estimate(
    p: &RunContext,
    charts: &Charts,
    geom: &TileStore<TexelGeom>,
    state: &mut TileStore<TexelState>,
    scratch: &Scratch,
) -> Result<()> {
    if !p.scene.has_environment() {
        return Ok(());
    }
    let layout = &p.layout;
    for slot in 0..layout.slots.len() {
        let c = &charts.slots[slot];
        let cells = SlotTexture::read(layout, slot, state, geom, scratch, "ed", |s, g| {
            ChartValue {
                v: luminance(Vec3::from_array(s.e_d)),
                chart: super::sample_class(c.texel(g), s),
            }
        })?;
        let var = cells.map_windows(RADIUS, scratch, "ed-var", |v, w, h| {
            window_variance(v, w, h, RADIUS)
        })?;
        drop(cells);
        var.write(state, |s, &v| {
            let v = if v > 0.0 { v.min(s.ed_var) } else { s.ed_var };
            let changed = s.ed_var != v;
            s.ed_var = v;
            changed
        })?;
    }
    Ok(())
}

/// Per texel of a row-major `width x height` texture, the noise variance of `v` from the second
/// differences (along rows and along columns) whose three texels lie in the texel's own chart
/// within `[x - r, x + r] x [y - r, y + r]`, as [`spread`] makes it. 0 for a texel with no
/// chart, or fewer than [`MIN_DIFFS`] differences.
pub fn window_variance(t: &[ChartValue], width: u32, height: u32, r: u32) -> Result<Vec<f32>> {
    let (w, h) = (width as usize, height as usize);
    if t.len() != w * h {
        return Err(Error::internal(format!(
            "E_d noise: {} texels for a {width}x{height} texture",
            t.len()
        )));
    }
    let r = r as usize;
    let mut out = vec![0.0f32; t.len()];
    out.par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            let mut d = [Vec::new(), Vec::new()];
            for (x, o) in row.iter_mut().enumerate() {
                let c = t[y * w + x].chart;
                if c == NONE {
                    continue;
                }
                d.iter_mut().for_each(Vec::clear);
                let at = |x: usize, y: usize| Some(t[y * w + x]).filter(|n| n.chart == c);
                for ny in y.saturating_sub(r)..(y + r + 1).min(h) {
                    for nx in x.saturating_sub(r)..(x + r + 1).min(w) {
                        let Some(m) = at(nx, ny) else { continue };
                        let pairs = [
                            (nx > 0 && nx + 1 < w).then(|| (at(nx - 1, ny), at(nx + 1, ny))),
                            (ny > 0 && ny + 1 < h).then(|| (at(nx, ny - 1), at(nx, ny + 1))),
                        ];
                        for (k, p) in pairs.into_iter().enumerate() {
                            if let Some((Some(a), Some(b))) = p {
                                d[k].push(a.v - 2.0 * m.v + b.v);
                            }
                        }
                    }
                }
                *o = spread(&mut d);
            }
        });
    Ok(out)
}

/// `(1.4826 MAD)^2 / 6` of the second differences `d` (along rows, along columns), each
/// direction's taken about its own median: a surface's curvature bends the light smoothly, so
/// its second differences share a value the median removes, where noise scatters about 0.
/// 0 with fewer than [`MIN_DIFFS`] differences.
fn spread(d: &mut [Vec<f32>; 2]) -> f32 {
    let mut dev = Vec::with_capacity(d[0].len() + d[1].len());
    for v in d.iter_mut().filter(|v| !v.is_empty()) {
        let med = median(v);
        dev.extend(v.iter().map(|x| (x - med).abs()));
    }
    if dev.len() < MIN_DIFFS {
        return 0.0;
    }
    (1.4826 * median(&mut dev)).powi(2) / 6.0
}

fn median(v: &mut [f32]) -> f32 {
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f32::total_cmp).1
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::rng::Rng;

    /// Independent noise of known variance on a curved ramp (a quadratic in x, as light across
    /// a curved surface), with a step (a shadow edge) across it: the estimate is the noise's
    /// variance (mean over the texels away from the edge within 10%; with the edge in the
    /// window, at most twice it), the noise-free ramp gives 0, and another chart's texels do
    /// not count.
    #[test]
    fn the_variance_is_the_noise_s_not_the_gradient_s_or_the_edge_s() {
        let (w, h, sigma) = (40u32, 40u32, 0.05f32);
        let mut rng = Rng::new(3, 0, 0, 0);
        let ramp =
            |x: u32, y: u32| 1.0 + 0.02 * x as f32 + 0.01 * y as f32 + 0.002 * (x * x) as f32;
        let field = |x: u32, y: u32| ramp(x, y) + 0.5 * (x >= 20) as u32 as f32;
        let noisy: Vec<ChartValue> = (0..w * h)
            .map(|i| ChartValue {
                v: field(i % w, i / w) + sigma * rng.normal(),
                chart: 1,
            })
            .collect();
        let var = window_variance(&noisy, w, h, RADIUS).unwrap();
        let (mut far, mut near) = (Vec::new(), Vec::new());
        for y in 4..h - 4 {
            for x in 4..w - 4 {
                let v = var[(y * w + x) as usize] as f64;
                if x.abs_diff(20) > RADIUS + 1 {
                    far.push(v)
                } else {
                    near.push(v)
                }
            }
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        let want = (sigma * sigma) as f64;
        assert!(
            (mean(&far) / want - 1.0).abs() < 0.1,
            "{} vs {want}",
            mean(&far)
        );
        let near = mean(&near) / want;
        assert!(
            (0.8..2.0).contains(&near),
            "at the edge {near} x the variance"
        );

        let clean: Vec<ChartValue> = (0..w * h)
            .map(|i| ChartValue {
                v: ramp(i % w, i / w),
                chart: 1,
            })
            .collect();
        let var = window_variance(&clean, w, h, RADIUS).unwrap();
        assert!(var.iter().all(|&v| v < 1e-9), "a curved ramp is not noise");

        // a noisy chart beside a quiet one: the quiet one's texels stay at 0
        let two: Vec<ChartValue> = (0..w * h)
            .map(|i| match i % w < 20 {
                true => ChartValue {
                    v: 1.0 + sigma * rng.normal(),
                    chart: 1,
                },
                false => ChartValue { v: 1.0, chart: 2 },
            })
            .collect();
        let var = window_variance(&two, w, h, RADIUS).unwrap();
        assert!((0..w * h)
            .filter(|i| i % w >= 20)
            .all(|i| var[i as usize] == 0.0));
        assert!(window_variance(&two, w + 1, h, RADIUS).is_err());
    }

    /// Texels with no chart get none, and a window with too few differences none either.
    #[test]
    fn texels_without_a_chart_or_enough_neighbours_get_zero() {
        let t = vec![
            ChartValue {
                v: 1.0,
                chart: NONE,
            },
            ChartValue { v: 2.0, chart: 1 },
            ChartValue { v: 5.0, chart: 1 },
        ];
        assert_eq!(window_variance(&t, 3, 1, RADIUS).unwrap(), vec![0.0; 3]);
    }
}
