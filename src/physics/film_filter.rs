//! A `tent` or `gaussian` film's filter applied to the re-render's sub-pixel samples one by
//! one, as Mitsuba's film applies it to its samples: each pixel is the filter-weighted mean of
//! the samples around its center, each sample weighted where it lies.
//!
//! Why not the pixel means: filtering an image of pixel means weighs everything within a
//! neighbour pixel alike, as if the radiance were flat within it; a tent's weight falls from 1
//! to 0.5 across the center pixel alone, so texture detail at the pixel's scale came out of
//! the model differently filtered than out of the photo, and the refinement fitted the
//! difference into the maps. Weighing the `k x k` sub-pixel samples the re-render takes anyway
//! costs a few multiply-adds per sample.
//!
//! The filter is separable (`f(x) f(y)`), so it runs in two passes: along each row of sub-pixel
//! samples, to per pixel and sub-row sums (what a process shares with the others under MPI,
//! rows in bands), then down the columns.

use super::camera::Camera;
use super::render::{pixel_samples, Plan, Texture};
use crate::base::error::Result;
use crate::physics::accel::Accel;
use crate::scene::PixelFilter;
use glam::Vec3;
use rayon::prelude::*;

/// Makes an image computed in units of consecutive values whole (see `Shard::sync_pixels`).
pub type SyncRows<'a> = dyn Fn(&mut [Option<Vec3>], usize) -> Result<()> + 'a;

/// The views' re-render through `filter` from `k x k` sub-pixel samples per pixel (rendered
/// as `plan` says; `None` for a pixel none of whose own samples sees a texture): the samples
/// of the pixels within the filter's reach, each weighted by the filter at its offset from the
/// pixel's center, normalized by the weights of the samples that see a texture. `sync` makes
/// the per-row sums whole in units of `band` rows (see `Shard::sync_pixels`).
pub fn render_filtered<'h>(
    parts: (&Accel, &Camera, &[Option<Texture>]),
    k: u32,
    filter: PixelFilter,
    plan: &(dyn Fn(u32, u32) -> Plan<'h> + Sync),
    (sync, band): (&SyncRows, u32),
) -> Result<Vec<Option<Vec3>>> {
    let camera = parts.1;
    let (w, h) = (camera.width(), camera.height());
    let weights = sample_weights(filter, k);
    let per = 2 * k as usize;
    let mut rows: Vec<Option<Vec3>> = (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            let (samples, skipped) = row_samples(parts, k, plan, y);
            row_sums(&samples, &skipped, k, &weights)
        })
        .collect();
    sync(&mut rows, band as usize * w as usize * per)?;
    Ok(columns(&rows, &weights, (w, h), k))
}

/// Every pixel from the row sums of [`row_sums`], down the columns.
fn columns(
    rows: &[Option<Vec3>],
    weights: &[Vec<f32>],
    (w, h): (u32, u32),
    k: u32,
) -> Vec<Option<Vec3>> {
    (0..h)
        .into_par_iter()
        .flat_map_iter(|y| (0..w).map(move |x| column(rows, weights, (w, h), k, (x, y))))
        .collect()
}

/// One row's `k x k` sub-pixel samples per pixel (pixel-major, row-major within a pixel) and
/// which pixels the plan skips.
fn row_samples<'h>(
    parts: (&Accel, &Camera, &[Option<Texture>]),
    k: u32,
    plan: &(dyn Fn(u32, u32) -> Plan<'h> + Sync),
    y: u32,
) -> (Vec<Option<Vec3>>, Vec<bool>) {
    let w = parts.1.width() as usize;
    let kk = (k * k) as usize;
    let mut samples = vec![None; w * kk];
    let mut skipped = vec![false; w];
    for x in 0..w {
        let p = plan(x as u32, y);
        skipped[x] = p == Plan::Skip;
        pixel_samples(parts, k, p, (x as u32, y), &mut samples[x * kk..][..kk]);
    }
    (samples, skipped)
}

/// Per neighbour offset `-n..=n` (`n` the filter's reach) and sub-sample index `0..k`, the
/// 1-D filter at the sample's offset from the pixel's center.
fn sample_weights(filter: PixelFilter, k: u32) -> Vec<Vec<f32>> {
    let n = filter.reach() as i32;
    (-n..=n)
        .map(|d| {
            (0..k)
                .map(|i| filter.eval(d as f32 + (i as f32 + 0.5) / k as f32 - 0.5))
                .collect()
        })
        .collect()
}

/// One row of pixels: per pixel, per sub-row `j`, the filter-weighted sum along the row of
/// the samples that see a texture (`k` values), then per sub-row the sum of their weights
/// with, in the second component, whether the pixel's own samples see one (`k` values); all
/// `None` for a pixel the plan skips.
fn row_sums(
    samples: &[Option<Vec3>],
    skipped: &[bool],
    k: u32,
    weights: &[Vec<f32>],
) -> Vec<Option<Vec3>> {
    let w = skipped.len();
    let (ku, n) = (k as usize, (weights.len() / 2) as i64);
    let kk = ku * ku;
    let mut out = vec![None; w * 2 * ku];
    for x in 0..w {
        if skipped[x] {
            continue;
        }
        let own = samples[x * kk..][..kk].iter().any(Option::is_some) as u32 as f32;
        for j in 0..ku {
            let (mut sum, mut total) = (Vec3::ZERO, 0.0f32);
            for (d, wd) in (-n..=n).zip(weights) {
                let xn = x as i64 + d;
                if xn < 0 || xn >= w as i64 {
                    continue;
                }
                let row = &samples[xn as usize * kk + j * ku..][..ku];
                for (s, &f) in row.iter().zip(wd) {
                    if let Some(v) = s {
                        sum += *v * f;
                        total += f;
                    }
                }
            }
            out[x * 2 * ku + j] = Some(sum);
            out[x * 2 * ku + ku + j] = Some(Vec3::new(total, own, 0.0));
        }
    }
    out
}

/// Pixel `(x, y)` from the row sums of the rows within reach, weighted down the column.
fn column(
    rows: &[Option<Vec3>],
    weights: &[Vec<f32>],
    (w, h): (u32, u32),
    k: u32,
    (x, y): (u32, u32),
) -> Option<Vec3> {
    let (ku, n) = (k as usize, (weights.len() / 2) as i64);
    let at = |yy: u32, i: usize| rows[(yy as usize * w as usize + x as usize) * 2 * ku + i];
    if at(y, ku)?.y == 0.0 {
        return None;
    }
    let (mut sum, mut total) = (Vec3::ZERO, 0.0f32);
    for (d, wd) in (-n..=n).zip(weights) {
        let yn = y as i64 + d;
        if yn < 0 || yn >= h as i64 {
            continue;
        }
        for (j, &f) in wd.iter().enumerate() {
            if let (Some(s), Some(t)) = (at(yn as u32, j), at(yn as u32, ku + j)) {
                sum += s * f;
                total += t.x * f;
            }
        }
    }
    (total > 0.0).then(|| sum / total)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::render::apply_pixel_filter;

    /// The filtered image of a `w x h` grid of `k x k` samples per pixel, through the same
    /// two passes as [`render_filtered`] (no rendering, no processes).
    fn two_pass(
        samples: &[Option<Vec3>],
        (w, h): (u32, u32),
        k: u32,
        f: PixelFilter,
    ) -> Vec<Option<Vec3>> {
        let weights = sample_weights(f, k);
        let kk = (k * k) as usize;
        let row = w as usize * kk;
        let rows: Vec<Option<Vec3>> = (0..h as usize)
            .flat_map(|y| {
                let r = &samples[y * row..][..row];
                let skipped: Vec<bool> = r
                    .chunks(kk)
                    .map(|p| p.iter().all(Option::is_none))
                    .collect();
                row_sums(r, &skipped, k, &weights)
            })
            .collect();
        columns(&rows, &weights, (w, h), k)
    }

    /// Brute force: every sample within reach weighted by `f(dx) f(dy)` at its offset from
    /// the pixel's center, over the samples that have a value.
    fn brute(
        samples: &[Option<Vec3>],
        (w, h): (u32, u32),
        k: u32,
        f: PixelFilter,
    ) -> Vec<Option<Vec3>> {
        let kk = (k * k) as usize;
        let at = |x: u32, y: u32, i: u32, j: u32| {
            samples[(y as usize * w as usize + x as usize) * kk + (j * k + i) as usize]
        };
        let mut out = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let own = (0..kk as u32).any(|s| at(x, y, s % k, s / k).is_some());
                let (mut sum, mut total) = (Vec3::ZERO, 0.0f64);
                for (yy, xx) in (0..h).flat_map(|yy| (0..w).map(move |xx| (yy, xx))) {
                    for s in 0..kk as u32 {
                        let (i, j) = (s % k, s / k);
                        let dx = xx as f32 + (i as f32 + 0.5) / k as f32 - (x as f32 + 0.5);
                        let dy = yy as f32 + (j as f32 + 0.5) / k as f32 - (y as f32 + 0.5);
                        let wgt = f.eval(dx) * f.eval(dy);
                        if let Some(v) = at(xx, yy, i, j) {
                            sum += v * wgt;
                            total += wgt as f64;
                        }
                    }
                }
                out.push((own && total > 0.0).then(|| sum / total as f32));
            }
        }
        out
    }

    /// A sample grid with detail finer than a pixel and a few samples that see no texture.
    fn grid((w, h): (u32, u32), k: u32) -> Vec<Option<Vec3>> {
        let kk = (k * k) as usize;
        (0..(w * h) as usize * kk)
            .map(|s| {
                let (p, q) = (s / kk, (s % kk) as u32);
                let v = ((p * 7 + q as usize * 13) % 17) as f32 / 17.0;
                (s % 23 != 5).then(|| Vec3::new(v, 1.0 - v, 0.5 * v + 0.1))
            })
            .collect()
    }

    fn close(a: &[Option<Vec3>], b: &[Option<Vec3>], tol: f32) {
        assert_eq!(a.len(), b.len());
        for (i, (x, y)) in a.iter().zip(b).enumerate() {
            match (x, y) {
                (Some(x), Some(y)) => assert!(
                    (*x - *y).abs().max_element() <= tol,
                    "pixel {i}: {x} vs {y}"
                ),
                (None, None) => {}
                _ => panic!("pixel {i}: {x:?} vs {y:?}"),
            }
        }
    }

    /// The separable two passes give the 2-D filtered sum exactly, for the tent and the
    /// gaussian (whose reach is 2 pixels), on samples with sub-pixel detail and holes.
    #[test]
    fn two_passes_equal_the_brute_force_sum() {
        let (wh, k) = ((9, 7), 4);
        let g = grid(wh, k);
        for f in [
            PixelFilter::Tent { radius: 1.0 },
            PixelFilter::Gaussian { stddev: 0.5 },
            PixelFilter::Box,
        ] {
            close(&two_pass(&g, wh, k, f), &brute(&g, wh, k, f), 1e-5);
        }
    }

    /// Radiance flat within each pixel: the sample-wise tent equals the pixel-mean filter
    /// ([`apply_pixel_filter`], exact for it); with detail within pixels the two differ.
    #[test]
    fn flat_pixels_match_the_pixel_mean_filter_and_detail_does_not() {
        let (w, h, k) = (8u32, 6u32, 4u32);
        let kk = (k * k) as usize;
        let means: Vec<Option<Vec3>> = (0..w * h)
            .map(|p| Some(Vec3::splat(((p * 5) % 11) as f32)))
            .collect();
        let flat: Vec<Option<Vec3>> = means
            .iter()
            .flat_map(|m| std::iter::repeat_n(*m, kk))
            .collect();
        let tent = PixelFilter::Tent { radius: 1.0 };
        close(
            &two_pass(&flat, (w, h), k, tent),
            &apply_pixel_filter(&means, w, h, tent),
            1e-4,
        );
        let g = grid((w, h), k);
        let g_means: Vec<Option<Vec3>> = g
            .chunks(kk)
            .map(|p| {
                let v: Vec<Vec3> = p.iter().flatten().copied().collect();
                (!v.is_empty()).then(|| v.iter().sum::<Vec3>() / v.len() as f32)
            })
            .collect();
        let a = two_pass(&g, (w, h), k, tent);
        let b = apply_pixel_filter(&g_means, w, h, tent);
        let most = a
            .iter()
            .zip(&b)
            .map(|(a, b)| (a.unwrap() - b.unwrap()).abs().max_element())
            .fold(0.0, f32::max);
        assert!(
            most > 0.01,
            "detail within pixels changes the filtered value: {most}"
        );
    }
}
