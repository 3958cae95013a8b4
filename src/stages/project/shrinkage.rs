//! What of a refinement residual (`photo - render`) is signal: the photo's noise level, and the
//! shrinkage of the residual towards zero where its neighbourhood holds no more than noise.
//!
//! The shrinkage is positive-part James-Stein over each pixel's neighbourhood (the clean
//! pixels of a `(2 SHRINK_RADIUS + 1)^2` window): the pixel's residual is scaled by
//! `max(0, 1 - sigma^2 / mean(e^2))`, `e` the relative residuals in the window. A blurred texture
//! edge leaves a residual that is coherent over a few pixels, so its window holds more energy
//! than noise and most of it passes, even where each pixel is within the noise; a window of
//! noise alone holds about `sigma^2` and is zeroed or nearly so. `sigma^2` is the mean over the
//! window of each pixel's noise variance ([`super::noise`]): the view's level, or more where
//! the photo is locally noisier and the render smooth. A per-pixel soft threshold (`|e|`
//! shrunk by `sigma`) would drop exactly those edge residuals, so the passes would restore
//! less detail. It is a median and a separable box sum, so it is written here.

use super::noise::{block_roughness, per_pixel, pixel_noise};
use super::view::PixelInfo;
use glam::Vec3;

/// Half the side of the window a residual is judged over (7 x 7 pixels): smaller windows hold
/// less of a blurred edge's residual and textured scenes keep less detail (most visibly at
/// 3 x 3); uniform scenes are indifferent. Shrinking harder (the noise energy scaled up) helps
/// uniform surfaces and costs textures more.
pub const SHRINK_RADIUS: usize = 3;

/// A photo's relative per-pixel noise from its relative residuals `e` ([`relative`]): the
/// median `|e|` over the pixels that have one, scaled to a standard deviation (1.4826 x MAD), a
/// robust estimate since most pixels are noise-dominated. 0 when no clean pixel has light.
fn noise_sigma(e: &[Option<f32>]) -> f32 {
    let mut rels: Vec<f32> = e.iter().flatten().map(|v| v.abs()).collect();
    if rels.is_empty() {
        return 0.0;
    }
    let mid = rels.len() / 2;
    1.4826 * *rels.select_nth_unstable_by(mid, f32::total_cmp).1
}

/// Per pixel, the residual relative to the photo (on the channel sums), for clean pixels with
/// light and a finite ratio; `None` elsewhere.
pub(super) fn relative<'a>(
    residual: &'a [Vec3],
    photo: &'a [Vec3],
    pixels: &'a [PixelInfo],
) -> impl Iterator<Item = Option<f32>> + 'a {
    residual.iter().zip(photo).zip(pixels).map(|((r, p), px)| {
        let s = p.element_sum();
        let e = r.element_sum() / s;
        (px.clean && s > 0.0 && e.is_finite()).then_some(e)
    })
}

/// Shrink a residual image of `width` pixels per row in place (see the module docs); pixels
/// that are not clean, or dark, get zero. Photos without noise (`sigma` 0) are left as they
/// are. Returns `sigma`, the photo's relative per-pixel noise (`noise_sigma`).
pub fn shrink_residual(
    residual: &mut [Vec3],
    photo: &[Vec3],
    pixels: &[PixelInfo],
    width: usize,
) -> f32 {
    shrink_residual_levels(residual, photo, pixels, width).sigma
}

/// A photo's noise as [`shrink_residual_levels`] finds it.
#[derive(Debug, Clone, Default)]
pub struct NoiseLevels {
    /// The photo's relative per-pixel noise (`noise_sigma`; 0 for a noise-free photo).
    pub sigma: f32,
    /// Per pixel, what a texel's noise variance is judged by: `sigma`, or more where the
    /// photo is locally noisier (see [`pixel_noise`]).
    pub level: Vec<f32>,
    /// Per pixel, the local roughness of the relative residual with no floor and no guard
    /// ([`block_roughness`]; 0 where too few pixels have one): the level the noise probe adds
    /// noise at.
    pub rough: Vec<f32>,
    /// Per pixel, the factor the residual was scaled by: 0 where its window holds no more
    /// than noise (or the pixel is not clean, or dark), towards 1 where it holds much more; 1
    /// everywhere for a noise-free photo. What the refinement's gate reads
    /// (`project::apply_refinement`).
    pub keep: Vec<f32>,
}

/// [`shrink_residual`], also returning the photo's noise levels ([`NoiseLevels`]; `level` is
/// `sigma` everywhere, 0, for a noise-free photo): [`noise_levels`], then each pixel's
/// residual scaled by its `keep`.
pub fn shrink_residual_levels(
    residual: &mut [Vec3],
    photo: &[Vec3],
    pixels: &[PixelInfo],
    width: usize,
) -> NoiseLevels {
    let levels = noise_levels(residual, photo, pixels, width);
    for (r, k) in residual.iter_mut().zip(&levels.keep) {
        *r *= *k;
    }
    levels
}

/// The photo's noise levels against a residual image of `width` pixels per row, and per pixel
/// the factor the shrinkage scales its residual by (`keep`; 1 everywhere for a noise-free
/// photo), the residual left as it is.
pub fn noise_levels(
    residual: &[Vec3],
    photo: &[Vec3],
    pixels: &[PixelInfo],
    width: usize,
) -> NoiseLevels {
    let e: Vec<Option<f32>> = relative(residual, photo, pixels).collect();
    let sigma = noise_sigma(&e);
    let blocks = block_roughness(&e, width);
    let rough = per_pixel(&blocks, e.len(), width);
    if sigma <= 0.0 {
        let level = vec![sigma; residual.len()];
        return NoiseLevels {
            sigma,
            level,
            rough,
            keep: vec![1.0; residual.len()],
        };
    }
    let energy: Vec<f64> = e
        .iter()
        .map(|v| v.map_or(0.0, |v| (v * v) as f64))
        .collect();
    let energy = box_sum(&energy, width, SHRINK_RADIUS);
    let (noise, level) = window_noise(residual, photo, (&e, &blocks), width, sigma);
    let keep = (0..residual.len())
        .map(|i| {
            // the window's noise energy against its residuals' energy
            let (noise, total) = (noise[i], energy[i]);
            match e[i] {
                Some(_) if total > noise => (1.0 - noise / total) as f32,
                _ => 0.0,
            }
        })
        .collect();
    NoiseLevels {
        sigma,
        level,
        rough,
        keep,
    }
}

/// Per pixel, the noise energy its window holds: the sum over the window's pixels with a
/// relative residual `e` of their local noise variance ([`pixel_noise`] from the residual's
/// block roughness `rough`: the view's `sigma`, or more where the photo is locally noisier and
/// the render smooth).
fn window_noise(
    residual: &[Vec3],
    photo: &[Vec3],
    (e, rough): (&[Option<f32>], &[f32]),
    width: usize,
    sigma: f32,
) -> (Vec<f64>, Vec<f32>) {
    let log_render: Vec<Option<f32>> = residual
        .iter()
        .zip(photo)
        .zip(e)
        .map(|((r, p), e)| {
            let v = p.element_sum() - r.element_sum();
            (e.is_some() && v > 0.0).then(|| v.ln())
        })
        .collect();
    let level = pixel_noise(rough, &log_render, width, sigma);
    let var: Vec<f64> = e
        .iter()
        .zip(&level)
        .map(|(e, s)| e.map_or(0.0, |_| (s * s) as f64))
        .collect();
    (box_sum(&var, width, SHRINK_RADIUS), level)
}

/// The sum of `v` (an image `width` wide) over the `(2 radius + 1)^2` window around every
/// pixel, clipped at the image's edges: a horizontal then a vertical pass, each summing in a
/// fixed order (the result does not depend on threads).
fn box_sum(v: &[f64], width: usize, radius: usize) -> Vec<f64> {
    let height = v.len() / width.max(1);
    let mut rows = vec![0.0; v.len()];
    for y in 0..height {
        let row = &v[y * width..(y + 1) * width];
        for x in 0..width {
            let (a, b) = (x.saturating_sub(radius), (x + radius + 1).min(width));
            rows[y * width + x] = row[a..b].iter().sum();
        }
    }
    let mut out = vec![0.0; v.len()];
    for y in 0..height {
        let (a, b) = (y.saturating_sub(radius), (y + radius + 1).min(height));
        for x in 0..width {
            out[y * width + x] = (a..b).map(|yy| rows[yy * width + x]).sum();
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn clean() -> PixelInfo {
        PixelInfo {
            shape: 0,
            normal: Vec3::Y,
            plane: 0.0,
            clean: true,
        }
    }

    /// A 20 x 20 photo of 2.0 everywhere, with residuals of +-1% in a checkerboard (relative
    /// noise sigma 1.4826%).
    fn checkerboard() -> (Vec<Vec3>, Vec<Vec3>, Vec<PixelInfo>) {
        let n = 20;
        let photo = vec![Vec3::splat(2.0); n * n];
        let r = (0..n * n)
            .map(|i| {
                Vec3::splat(if (i % n + i / n) % 2 == 0 {
                    0.02
                } else {
                    -0.02
                })
            })
            .collect();
        (r, photo, vec![clean(); n * n])
    }

    #[test]
    fn the_noise_is_the_scaled_median_absolute_residual() {
        // relative residuals -3..3% without 0: the median of |e| is 2% (the signed median,
        // 1%, would understate it)
        let photo = vec![Vec3::splat(2.0); 6];
        let mut r: Vec<Vec3> = [-3.0f32, -2.0, -1.0, 1.0, 2.0, 3.0]
            .iter()
            .map(|p| Vec3::splat(0.02 * p))
            .collect();
        let sigma = shrink_residual(&mut r, &photo, &[clean(); 6], 6);
        assert!((sigma - 1.4826 * 0.02).abs() < 1e-6, "{sigma}");
    }

    /// A flat render under a photo with 1% noise on its left half and 4% on its right: the
    /// levels are the view's `sigma` on the left and the right half's own noise there; a
    /// photo the render matches exactly has no noise and levels of zero.
    #[test]
    fn levels_follow_the_local_noise() {
        let n = 64;
        let g: Vec<f32> = (0..n * n)
            .map(|i| crate::base::rng::Rng::new(3, 1, 0, i as u64).normal())
            .collect();
        let rel = |i: usize| g[i] * if i % n < n / 2 { 0.01 } else { 0.04 };
        let photo: Vec<Vec3> = (0..n * n)
            .map(|i| Vec3::splat(2.0 * (1.0 + rel(i))))
            .collect();
        let mut r: Vec<Vec3> = (0..n * n).map(|i| Vec3::splat(2.0 * rel(i))).collect();
        let NoiseLevels { sigma, level, .. } =
            shrink_residual_levels(&mut r, &photo, &vec![clean(); n * n], n);
        assert!(sigma > 0.01 && sigma < 0.04, "{sigma}");
        for y in 0..n {
            let (left, right) = (level[y * n + 4], level[y * n + n - 4]);
            assert_eq!(left, sigma);
            assert!(right > 0.032 && right < 0.045, "{right}");
        }
        let mut quiet = vec![Vec3::ZERO; n * n];
        let NoiseLevels { sigma, level, .. } =
            shrink_residual_levels(&mut quiet, &photo, &vec![clean(); n * n], n);
        assert_eq!(sigma, 0.0);
        assert!(level.iter().all(|&l| l == 0.0));
    }

    #[test]
    fn noise_alone_is_dropped() {
        let (mut r, photo, pixels) = checkerboard();
        let sigma = shrink_residual(&mut r, &photo, &pixels, 20);
        assert!((sigma - 0.014826).abs() < 1e-6, "{sigma}");
        assert!(r.iter().all(|v| *v == Vec3::ZERO));
    }

    /// `keep` is the factor each pixel's residual was scaled by: 0 on noise alone and on a
    /// pixel that is not clean, inside (0, 1) on a coherent band, 1 for a noise-free photo.
    #[test]
    fn keep_is_the_factor_each_residual_was_scaled_by() {
        let (mut r, photo, mut pixels) = checkerboard();
        for (i, v) in r.iter_mut().enumerate() {
            if (6..11).contains(&(i % 20)) {
                *v += Vec3::splat(0.09);
            }
        }
        pixels[7].clean = false;
        let before = r.clone();
        let keep = shrink_residual_levels(&mut r, &photo, &pixels, 20).keep;
        assert_eq!(keep[7], 0.0, "not clean");
        assert_eq!(keep[0], 0.0, "noise alone");
        let mid = 10 * 20 + 8;
        assert!(keep[mid] > 0.8 && keep[mid] < 1.0, "{}", keep[mid]);
        // to the bit: the refinement keeps the raw residual and `keep` and makes the shrunk
        // one again as `raw * keep` (`ResidualPixel::pair`)
        let bits = |v: Vec3| v.to_array().map(f32::to_bits);
        for ((a, b), k) in before.iter().zip(&r).zip(&keep) {
            assert_eq!(bits(*a * *k), bits(*b));
        }
        let mut r = vec![Vec3::ZERO; 400];
        r[7] = Vec3::new(1.0, -0.0, 3e-39);
        let before = r.clone();
        let keep = shrink_residual_levels(&mut r, &photo, &pixels, 20).keep;
        assert!(keep.iter().all(|&k| k == 1.0), "noise-free: left alone");
        for ((a, b), k) in before.iter().zip(&r).zip(&keep) {
            assert_eq!(bits(*a * *k), bits(*b));
        }
    }

    #[test]
    fn a_coherent_residual_passes_almost_whole() {
        // a band 5 pixels wide, 3 sigma (relative) above the noise: a per-pixel soft
        // threshold would take sigma off every pixel of it (2/3 kept); its windows hold 5.6-6.9
        // times the noise's energy, so nearly all of it passes
        let (mut r, photo, mut pixels) = checkerboard();
        let sigma = 0.014826;
        let add = 3.0 * sigma * 2.0; // per channel: relative residuals are on the channel sums
        let band = |i: usize| (6..11).contains(&(i % 20));
        for (i, v) in r.iter_mut().enumerate() {
            if band(i) {
                *v += Vec3::splat(add);
            }
        }
        pixels[0].clean = false;
        shrink_residual(&mut r, &photo, &pixels, 20);
        assert_eq!(r[0], Vec3::ZERO);
        let inner: Vec<f32> = (0..400)
            .filter(|&i| band(i) && (3..17).contains(&(i / 20)))
            .map(|i| r[i].x)
            .collect();
        let kept = inner.iter().sum::<f32>() / inner.len() as f32 / add;
        assert!(kept > 0.8 && kept < 0.9, "{kept}");
        // pixels whose window misses the band stay at zero
        assert!((0..400)
            .filter(|&i| (i % 20) < 3 || (i % 20) > 13)
            .all(|i| r[i] == Vec3::ZERO));
    }

    #[test]
    fn a_large_residual_is_nearly_kept_and_noise_free_photos_are_left_alone() {
        let (mut r, photo, pixels) = checkerboard();
        // 34 sigma: its window's mean energy is 23.7 times the noise's, 1 - 1/23.7 passes
        r[210] = Vec3::splat(1.0);
        shrink_residual(&mut r, &photo, &pixels, 20);
        assert!((r[210].x - 0.9578).abs() < 1e-3, "{}", r[210]);
        let mut r = vec![Vec3::ZERO; 400];
        r[7] = Vec3::splat(1.0);
        shrink_residual(&mut r, &photo, &pixels, 20);
        assert_eq!(r[7], Vec3::splat(1.0));
    }

    /// A 48 x 48 view whose residual is 6% relative noise on the left half and 1% on the
    /// right, over a render that is flat (`texture` 0) or carries a random pixel texture of
    /// that relative amplitude; returns the share of the left half's residual energy the shrinkage
    /// keeps and the view's level.
    fn noisy_left_half(texture: f32) -> (f32, f32) {
        let n = 48;
        let mut r = Vec::new();
        let mut photo = Vec::new();
        for i in 0..n * n {
            let mut g = crate::base::rng::Rng::new(3, 0, 0, i as u64);
            let z = g.normal();
            let t = 1.0 + texture * (2.0 * g.f32() - 1.0);
            let e = if i % n < n / 2 { 0.06 * z } else { 0.01 * z };
            let render = Vec3::splat(t);
            r.push(render * e);
            photo.push(render * (1.0 + e));
        }
        let before: f32 = (0..n * n)
            .filter(|i| i % n < n / 2)
            .map(|i| r[i].x.powi(2))
            .sum();
        let sigma = shrink_residual(&mut r, &photo, &vec![clean(); n * n], n);
        let after: f32 = (0..n * n)
            .filter(|i| i % n < n / 2)
            .map(|i| r[i].x.powi(2))
            .sum();
        (after / before, sigma)
    }

    #[test]
    fn a_noisier_region_over_a_smooth_render_is_judged_by_its_own_noise() {
        let (kept, sigma) = noisy_left_half(0.0);
        // under the view's level alone the left half's windows would keep about
        // 1 - sigma^2 / 0.06^2 of their energy
        assert!(1.0 - (sigma / 0.06).powi(2) > 0.6, "{sigma}");
        // judged by its own 6%, noise windows keep only what chance lends them
        assert!(kept < 0.3, "{kept}");
    }

    #[test]
    fn a_rough_residual_over_a_textured_render_keeps_the_views_level() {
        // the same residual over a render with a 30% pixel texture may be unresolved texture
        let (kept, sigma) = noisy_left_half(0.3);
        assert!(kept > 0.5, "{kept} (sigma {sigma})");
    }

    #[test]
    fn box_sums_match_brute_force() {
        let (w, h) = (7, 5);
        let v: Vec<f64> = (0..w * h).map(|i| ((i * 37) % 11) as f64).collect();
        let fast = box_sum(&v, w, SHRINK_RADIUS);
        let r = SHRINK_RADIUS;
        for y in 0..h {
            for x in 0..w {
                let mut s = 0.0;
                for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                    for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                        s += v[yy * w + xx];
                    }
                }
                assert_eq!(fast[y * w + x], s, "({x}, {y})");
            }
        }
    }
}
