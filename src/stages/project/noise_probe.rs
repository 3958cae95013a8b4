//! The photos' noise through the whole projection, measured instead of only propagated: the
//! projection (weighted mean and refinement passes) runs a second time on the photos with a
//! little synthetic noise added at their own estimated level, and the change of each texel's
//! luminance, scaled back and averaged in square over a small window of its chart, is the
//! variance its photo noise gives it (a finite-difference parametric bootstrap).
//!
//! Why: the propagation through the views' weights (`photo_variance`) sees the weighted mean
//! only. The refinement passes amplify noise where they deconvolve (a grazing ceiling, a dim
//! textured wall) and the sub-pixel texels share their pixels' noise, so propagation is off
//! by a factor that depends on the surface (on cbox-tex the actual per-texel noise is about
//! half the propagated one on the back wall and floor, three times it on the grazing
//! ceiling). The probe follows the passes' shrinkage, robust weights and clamps as they act
//! on these photos, because it is the same code run on them.
//!
//! The added noise is [`PROBE_SCALE`] of the photos' own (each pixel's level: the roughness of
//! the last pass's residual there), so the probe's residuals hold nearly the noise the real
//! ones hold (6% more variance) and the shrinkage acts on it as on theirs; its draws are a pure
//! function of (seed, view, pixel). With the noise itself the measurement is exact (two
//! renders of cbox-tex's photos: this finite difference with their actual difference gives
//! 0.97-1.00 of the measured texel noise on the ceiling, the boxes, floor and back wall).
//!
//! The measured variance goes into `l_var` (what the confidence maps report), not into
//! `l_noise` (what the sigma filter judges by): judged by it, the filter would average noisy
//! textured surfaces (cbox-tex's ceiling) more and lose their detail.

use crate::atlas::store::{map_tiles, TileStore};
use crate::atlas::store::{Layout, TexelGeom, TexelState};
use crate::atlas::texture::window;
use crate::atlas::texture::{Scratch, SlotTexture};
use crate::atlas::uv::NONE;
use crate::atlas::uv::{ChartValue, Charts};
use crate::base::error::{Error, Result};
use crate::base::rng::Rng;
use crate::image::Image;
use crate::scene::luminance;
use glam::Vec3;
use rayon::prelude::*;

/// The probe's noise as a fraction of the photos' estimated noise.
pub const PROBE_SCALE: f32 = 0.25;
/// Radius in texels of the window (within a chart) a texel's variance is averaged over.
pub const PROBE_RADIUS: u32 = 3;
/// Stream tag of the probe's draws.
const STREAM_TAG: u64 = 0x70_726f_6265;

/// A view's noise as the last refinement pass saw it: the view's relative level (the median)
/// and each pixel's local level, the roughness of its residual (0 where there is none).
#[derive(Debug, Clone, Default)]
pub struct ViewNoise {
    pub sigma: f32,
    pub level: Vec<f32>,
    /// The view against its re-render, in the last pass (see `diagnose`).
    pub check: Option<crate::report::ViewCheck>,
}

/// `image` given relative noise `PROBE_SCALE * level` (`sigma` where the level is 0) at every
/// valid pixel, in place (one standard normal per pixel, scaling all three channels: the
/// noise is relative, the same in every channel); draw `i` of view `view` is
/// `Rng::new(seed ^ tag, view, 0, i)`. What the image masks is left as it was.
pub fn perturb(image: &mut Image, noise: &ViewNoise, seed: u64, view: u64) {
    let valid = &image.valid;
    (image.pixels.par_iter_mut().enumerate()).for_each(|(i, v)| {
        if !valid[i] {
            return;
        }
        let level = noise.level.get(i).copied().filter(|&l| l > 0.0);
        let level = level.unwrap_or(noise.sigma);
        let n = Rng::new(seed ^ STREAM_TAG, view, 0, i as u64).normal();
        *v = (*v * (1.0 + PROBE_SCALE * level * n)).max(Vec3::ZERO);
    });
}

/// Per texel of a row-major `width x height` texture, the mean of `v` over the texels of its
/// own chart within `[x - r, x + r] x [y - r, y + r]` (0 for a texel with no chart). Cost
/// `O(texels x (2r + 1)^2)`.
pub fn chart_window_mean(t: &[ChartValue], width: u32, height: u32, r: u32) -> Result<Vec<f32>> {
    let (w, h) = (width as usize, height as usize);
    if t.len() != w * h {
        return Err(Error::internal(format!(
            "probe: {} texels for a {width}x{height} texture",
            t.len()
        )));
    }
    let mut out = vec![0.0f32; t.len()];
    out.par_chunks_mut(w.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            for (x, o) in row.iter_mut().enumerate() {
                let c = t[y * w + x].chart;
                if c == NONE {
                    continue;
                }
                let (mut sum, mut n) = (0.0f64, 0u32);
                for span in window(w, h, (x, y), r as usize) {
                    for nb in t[span].iter().filter(|nb| nb.chart == c) {
                        sum += nb.v as f64;
                        n += 1;
                    }
                }
                *o = (sum / n as f64) as f32;
            }
        });
    Ok(out)
}

/// Per observed texel, the variance of its luminance from the photos' noise, from `probe`
/// (the projection of the perturbed photos) against `state` (of the photos): the squared
/// luminance change over [`PROBE_SCALE`]^2, averaged by [`chart_window_mean`]. It becomes
/// `l_var` where the propagated photo noise (`l_noise`) was what `l_var` held; where the views'
/// scatter was larger, `l_var` keeps it unless the measured noise is larger still. `l_noise`,
/// what the sigma filter judges by, is left as propagated (see the module notes). `probe` is
/// overwritten with the squares.
pub fn apply(
    layout: &Layout,
    charts: &Charts,
    geom: &TileStore<TexelGeom>,
    state: &mut TileStore<TexelState>,
    probe: &mut TileStore<TexelState>,
    window_texels: usize,
    scratch: &Scratch,
) -> Result<()> {
    map_tiles(probe, state, window_texels, |_, st, pr| {
        for (p, s) in pr.iter_mut().zip(st) {
            let d = luminance(Vec3::from_array(p.l_orig)) - luminance(Vec3::from_array(s.l_orig));
            p.l_noise = if s.weight > 0.0 {
                (d / PROBE_SCALE).powi(2)
            } else {
                0.0
            };
        }
    })?;
    for slot in 0..layout.slots.len() {
        let c = &charts.slots[slot];
        let sq = SlotTexture::read(layout, slot, probe, geom, scratch, "probe", |s, g| {
            ChartValue {
                v: s.l_noise,
                chart: if s.weight > 0.0 { c.texel(g) } else { NONE },
            }
        })?;
        let var = sq.map_windows(PROBE_RADIUS, scratch, "probe-var", |v, w, h| {
            chart_window_mean(v, w, h, PROBE_RADIUS)
        })?;
        drop(sq);
        var.write(state, |s, &v| {
            if s.weight <= 0.0 {
                return false;
            }
            s.l_var = if s.l_var > s.l_noise {
                s.l_var.max(v)
            } else {
                v
            };
            true
        })?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(n: usize, v: Vec3) -> Image {
        let mut valid = vec![true; n];
        valid[3] = false;
        let mut pixels = vec![v; n];
        pixels[3] = Vec3::ZERO;
        Image {
            width: n as u32,
            height: 1,
            pixels,
            valid,
            masked: 1,
        }
    }

    /// The added noise is relative, `PROBE_SCALE` of the pixel's level (never below the
    /// view's), the same draw in every channel, masked pixels untouched, and a pure function
    /// of (seed, view, pixel).
    #[test]
    fn perturbed_photos_carry_the_scaled_level_as_relative_noise() {
        let n = 40_000;
        let v = Vec3::new(2.0, 1.0, 0.5);
        let img = image(n, v);
        let level: Vec<f32> = (0..n).map(|i| if i < n / 2 { 0.08 } else { 0.0 }).collect();
        // the level where there is one, even below the view's; the view's where there is none
        let noise = ViewNoise {
            sigma: 0.02,
            level,
            check: None,
        };
        let perturbed = |img: &Image, noise: &ViewNoise, seed: u64, view: u64| {
            let mut a = img.clone();
            perturb(&mut a, noise, seed, view);
            a
        };
        let a = perturbed(&img, &noise, 1, 0);
        assert_eq!(a.pixels[3], Vec3::ZERO, "masked");
        assert_eq!(
            (a.masked, &a.valid),
            (1, &img.valid),
            "masks what it masked"
        );
        let rel = |p: &Vec3| (p.x / v.x - 1.0, p.y / v.y - 1.0);
        let std = |r: &[Vec3]| {
            let e: Vec<f32> = r.iter().map(|p| rel(p).0).collect();
            let m = e.iter().sum::<f32>() / e.len() as f32;
            (e.iter().map(|x| (x - m).powi(2)).sum::<f32>() / e.len() as f32).sqrt()
        };
        let (noisy, quiet) = (&a.pixels[4..n / 2], &a.pixels[n / 2..]);
        let (s1, s2) = (std(noisy), std(quiet));
        assert!((s1 / (PROBE_SCALE * 0.08) - 1.0).abs() < 0.05, "{s1}");
        assert!((s2 / (PROBE_SCALE * 0.02) - 1.0).abs() < 0.05, "{s2}");
        for p in &a.pixels[4..] {
            let (r, g) = rel(p);
            assert!((r - g).abs() < 1e-5, "one draw for every channel");
        }
        assert_eq!(a.pixels, perturbed(&img, &noise, 1, 0).pixels);
        assert_ne!(a.pixels, perturbed(&img, &noise, 1, 1).pixels, "per view");
        assert_ne!(a.pixels, perturbed(&img, &noise, 2, 0).pixels, "per seed");
    }

    /// The window mean against a brute-force one, with two charts side by side and texels
    /// with no chart.
    #[test]
    fn chart_window_mean_stays_within_the_chart() {
        let (w, h, r) = (9u32, 7u32, 2u32);
        let t: Vec<ChartValue> = (0..w * h)
            .map(|i| ChartValue {
                v: (i * 7 % 11) as f32,
                chart: match i % w {
                    0 => NONE,
                    x if x < 5 => 1,
                    _ => 2,
                },
            })
            .collect();
        let got = chart_window_mean(&t, w, h, r).unwrap();
        for y in 0..h as i64 {
            for x in 0..w as i64 {
                let c = t[(y * w as i64 + x) as usize].chart;
                let mut vals = vec![];
                for yy in (y - 2).max(0)..=(y + 2).min(h as i64 - 1) {
                    for xx in (x - 2).max(0)..=(x + 2).min(w as i64 - 1) {
                        let n = t[(yy * w as i64 + xx) as usize];
                        if n.chart == c {
                            vals.push(n.v);
                        }
                    }
                }
                let want = if c == NONE {
                    0.0
                } else {
                    vals.iter().sum::<f32>() / vals.len() as f32
                };
                let g = got[(y * w as i64 + x) as usize];
                assert!((g - want).abs() < 1e-5, "({x},{y}): {g} vs {want}");
            }
        }
        assert!(chart_window_mean(&t, w + 1, h, r).is_err());
    }
}
