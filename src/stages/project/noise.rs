//! Where a photo is noisier than its overall level: a local noise level for the residual
//! shrinkage ([`super::shrink_residual`]), raised above the view's level only where the
//! residual is rough and the surface the render shows there is smooth.
//!
//! A view's noise level (the median relative residual) is one number, but a rendered or shot
//! photo's relative noise is not uniform: a dim ceiling lit only by interreflection is two or
//! three times as noisy as a lit wall. Under the one level the shrinkage takes that noise for
//! signal and every refinement pass fits more of it (a grazing ceiling's per-texel error
//! triples over eight passes, its mean pulled down as the spread hits `K_d <= 1`).
//! Unresolved texture looks as rough as noise in a single residual (lights' grass: 1.4-2.7
//! times the view's level), so the level is raised only where the current render is smoother
//! than the residual: there the maps hold no detail the residual could be the rest of. The
//! roughness estimator is a median of pixel differences over a block's window, the least of
//! four directions: differences drop what is smooth, the median the pixels of a few edges,
//! the least direction a straight edge. It is a few medians, so it is written here.

use super::window_median::{needed_for, BlockPairs};
use rayon::prelude::*;

/// Side of the square blocks of pixels that share one local level.
const NOISE_BLOCK: usize = 8;
/// Pixels beyond a block's sides on each side of the window its level is taken over
/// (24 x 24 pixels in all).
const NOISE_REACH: usize = 8;
// A window is its block and the eight around it (see `BlockPairs`).
const _: () = assert!(NOISE_REACH == NOISE_BLOCK);
/// Fewest pixel pairs a direction needs to give a level.
const MIN_PAIRS: usize = 32;
/// The four pixel directions whose differences are compared.
const DIRECTIONS: [(i64, i64); 4] = [(1, 0), (0, 1), (1, 1), (1, -1)];

/// Per pixel, the relative noise level the shrinkage judges the residual against: `sigma`
/// (the view's level), or the residual's local roughness `rough` (per block, from
/// [`block_roughness`]) where that is larger and the render's local roughness is smaller than
/// it. `log_render` is the logarithm of the render (so its differences are relative too), per
/// pixel and `None` where there is none; `width` pixels per row. The render's roughness is
/// taken only for blocks whose residual is rougher than `sigma` (elsewhere the level is
/// `sigma` anyway).
pub fn pixel_noise(
    rough: &[f32],
    log_render: &[Option<f32>],
    width: usize,
    sigma: f32,
) -> Vec<f32> {
    let smooth = roughness(log_render, width, &|b| rough[b] > sigma);
    let level: Vec<f32> = rough
        .iter()
        .zip(&smooth)
        .map(|(&r, &s)| if r > sigma && s < r { r } else { sigma })
        .collect();
    per_pixel(&level, log_render.len(), width)
}

/// Per block of [`NOISE_BLOCK`] x [`NOISE_BLOCK`] pixels, the roughness of the relative
/// residual `e` (`None` where there is none; `width` pixels per row) over the block's window
/// (see [`roughness`]): the residual's local noise level, 0 where too few pixels have a value.
pub fn block_roughness(e: &[Option<f32>], width: usize) -> Vec<f32> {
    roughness(e, width, &|_| true)
}

/// Per pixel of an image of `len` pixels, `width` per row, the value of its block.
pub fn per_pixel(blocks: &[f32], len: usize, width: usize) -> Vec<f32> {
    let bw = width.div_ceil(NOISE_BLOCK);
    (0..len)
        .map(|i| blocks[(i / width / NOISE_BLOCK) * bw + (i % width) / NOISE_BLOCK])
        .collect()
}

/// Per block of [`NOISE_BLOCK`] x [`NOISE_BLOCK`] pixels (row by row), the roughness of `v`
/// (an image `width` wide) over the window around it: for each of [`DIRECTIONS`] the median
/// `|v(p) - v(p + d)|` over the pairs that both have a value, as a standard deviation of `v`
/// (`1.4826 / sqrt 2` x, exact for Gaussian noise), and the least of the four. 0 where no
/// direction has [`MIN_PAIRS`] pairs, and for the blocks `wanted` refuses.
///
/// Each pair lies in the windows of nine blocks, so its difference is taken once per
/// direction ([`pair_diffs`]), counted once by its block ([`BlockPairs`]) and the windows'
/// medians found from the counts; a direction at a time, so the pairs held are one image's
/// worth.
fn roughness(v: &[Option<f32>], width: usize, wanted: &(dyn Fn(usize) -> bool + Sync)) -> Vec<f32> {
    let height = v.len() / width.max(1);
    let (bw, bh) = (width.div_ceil(NOISE_BLOCK), height.div_ceil(NOISE_BLOCK));
    let mut best = vec![f32::INFINITY; bw * bh];
    let needed = needed_for((bw, bh), wanted);
    let mut pairs = BlockPairs::new((width, height), NOISE_BLOCK, needed);
    let mut diffs = vec![NO_PAIR; v.len()];
    for d in DIRECTIONS {
        pair_diffs(v, width, height, d, &mut diffs);
        pairs.fill(&diffs, NO_PAIR);
        let pairs = &pairs;
        // rows of blocks in parallel, each block on its own: the same numbers for any threads
        best.par_chunks_mut(bw.max(1))
            .enumerate()
            .for_each(|(by, row)| {
                let mut scratch = Vec::new();
                for (bx, b) in row.iter_mut().enumerate() {
                    if wanted(by * bw + bx) {
                        let m = pairs.window_median((bx, by), MIN_PAIRS, &mut scratch);
                        let m = m.map(|m| 1.4826 * f32::from_bits(m) / std::f32::consts::SQRT_2);
                        *b = m.map_or(*b, |m| b.min(m));
                    }
                }
            });
    }
    best.into_iter()
        .map(|b| if b.is_finite() { b } else { 0.0 })
        .collect()
}

/// A pair of [`pair_diffs`] that is not one: a pixel without a value, or the second pixel
/// outside the image. Above the bits of every finite difference.
const NO_PAIR: u32 = u32::MAX;

/// Per pixel `p` of an image `width x height`, into `out`, the bits of `|v(p) - v(p + d)|` (a
/// non-negative float's bits order as the float does), [`NO_PAIR`] where `p + d` lies outside
/// the image or either pixel has no value.
fn pair_diffs(
    v: &[Option<f32>],
    width: usize,
    height: usize,
    (dx, dy): (i64, i64),
    out: &mut [u32],
) {
    let (w, h) = (width as i64, height as i64);
    out.par_chunks_mut(width.max(1))
        .enumerate()
        .for_each(|(y, row)| {
            row.fill(NO_PAIR);
            let y2 = y as i64 + dy;
            if !(0..h).contains(&y2) {
                return;
            }
            let (a, b) = (y * width, (y2 * w) as usize);
            let (xa, xb) = ((-dx).max(0), (w - dx).min(w));
            for x in xa..xb {
                let (x, x2) = (x as usize, (x + dx) as usize);
                if let (Some(p), Some(q)) = (v[a + x], v[b + x2]) {
                    row[x] = (p - q).abs().to_bits();
                }
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::rng::Rng;

    /// The pixel range of block `b`'s window along an axis of `n` pixels.
    fn window(b: usize, n: usize) -> (i64, i64) {
        let lo = (b * NOISE_BLOCK).saturating_sub(NOISE_REACH);
        let hi = ((b + 1) * NOISE_BLOCK + NOISE_REACH).min(n);
        (lo as i64, hi as i64)
    }

    /// Standard normal numbers, a pure function of `stream` and the index.
    fn gauss(stream: u64, n: usize) -> Vec<f32> {
        (0..n)
            .map(|i| Rng::new(11, stream, 0, i as u64).normal())
            .collect()
    }

    const N: usize = 64;

    /// `sigma` times white noise on an N x N image.
    fn noise(stream: u64, sigma: f32) -> Vec<Option<f32>> {
        gauss(stream, N * N)
            .iter()
            .map(|g| Some(sigma * g))
            .collect()
    }

    fn spread(v: &[f32]) -> (f32, f32) {
        let lo = v.iter().copied().fold(f32::INFINITY, f32::min);
        let hi = v.iter().copied().fold(0.0, f32::max);
        (lo, hi)
    }

    /// The roughness of one block by its definition: every pair of its window gathered
    /// and its median taken, per direction.
    fn brute_roughness(v: &[Option<f32>], width: usize, block: (usize, usize)) -> f32 {
        let height = v.len() / width;
        let (xs, ys) = (window(block.0, width), window(block.1, height));
        let mut best = f32::INFINITY;
        for (dx, dy) in DIRECTIONS {
            let mut d = vec![];
            for y in ys.0..ys.1 {
                for x in xs.0..xs.1 {
                    let (x2, y2) = (x + dx, y + dy);
                    if x2 < 0 || y2 < 0 || x2 >= width as i64 || y2 >= height as i64 {
                        continue;
                    }
                    let a = v[y as usize * width + x as usize];
                    if let (Some(a), Some(b)) = (a, v[y2 as usize * width + x2 as usize]) {
                        d.push((a - b).abs());
                    }
                }
            }
            if d.len() >= MIN_PAIRS {
                d.sort_by(f32::total_cmp);
                best = best.min(1.4826 * d[d.len() / 2] / std::f32::consts::SQRT_2);
            }
        }
        if best.is_finite() {
            best
        } else {
            0.0
        }
    }

    /// Against the definition, bit for bit, on images whose sides are not whole blocks,
    /// with pixels missing at random and in a stripe, blocks refused (all but one of them, in
    /// one case), and values quantized to a few levels, as an 8-bit photo's are (many equal
    /// differences around the median).
    #[test]
    fn roughness_is_the_median_of_each_window_bit_for_bit() {
        let sizes = [(37usize, 29usize), (8, 8), (5, 40), (64, 17), (48, 40)];
        for ((width, height), step) in sizes.into_iter().flat_map(|s| [(s, 0.0), (s, 0.01)]) {
            let v: Vec<Option<f32>> = gauss(7, width * height)
                .iter()
                .enumerate()
                .map(|(i, g)| {
                    let gone = (i * 7919) % 13 == 0 || (i % width == 3 && i / width > 9);
                    let v = 0.02 * g + (i % width) as f32 * 1e-3;
                    let v = if step > 0.0 {
                        (v / step).round() * step
                    } else {
                        v
                    };
                    (!gone).then_some(v)
                })
                .collect();
            let bw = width.div_ceil(NOISE_BLOCK);
            let wanted = |b: usize| match (width, height) {
                (48, 40) => b == 9,
                _ => b % 5 != 2,
            };
            let got = roughness(&v, width, &wanted);
            assert_eq!(got.len(), bw * height.div_ceil(NOISE_BLOCK));
            for (b, &g) in got.iter().enumerate() {
                let want = match wanted(b) {
                    true => brute_roughness(&v, width, (b % bw, b / bw)),
                    false => 0.0,
                };
                assert_eq!(g.to_bits(), want.to_bits(), "{width}x{height} block {b}");
            }
        }
    }

    #[test]
    fn white_noise_gives_its_standard_deviation() {
        let r = roughness(&noise(1, 0.03), N, &|_| true);
        let (lo, hi) = spread(&r);
        // the least of four medians of 300-576 pairs sits a little below the truth
        assert!(lo > 0.8 * 0.03 && hi < 1.1 * 0.03, "{lo} {hi}");
    }

    #[test]
    fn smooth_ramps_and_straight_edges_are_not_noise() {
        // noise of 1%, plus a ramp of 2% per pixel across the rows and a step of 50% along a
        // column: the plain median |v| would be dominated by both, the vertical differences
        // hold neither
        let mut v = noise(2, 0.01);
        for (i, x) in v.iter_mut().enumerate() {
            let px = i % N;
            let step = if px >= 29 { 0.5 } else { 0.0 };
            *x = x.map(|x| x + 0.02 * px as f32 + step);
        }
        let (lo, hi) = spread(&roughness(&v, N, &|_| true));
        assert!(lo > 0.008 && hi < 0.012, "{lo} {hi}");
    }

    #[test]
    fn pixels_without_a_value_are_skipped_and_an_empty_window_has_no_level() {
        let mut v = noise(3, 0.02);
        for x in v.iter_mut().step_by(2) {
            *x = None;
        }
        // only the vertical pairs are left, so the least of four is no longer biased low
        let (lo, hi) = spread(&roughness(&v, N, &|_| true));
        assert!(lo > 0.75 * 0.02 && hi < 1.25 * 0.02, "{lo} {hi}");
        assert!(roughness(&[None; 100], 10, &|_| true)
            .iter()
            .all(|&s| s == 0.0));
    }

    #[test]
    fn the_level_rises_only_where_the_render_is_smooth() {
        // the residual is 3% noise everywhere; the render is flat (with 0.1% noise) on the
        // left half and textured (10% noise) on the right; the view's level is 1%
        let e = noise(4, 0.03);
        let render: Vec<Option<f32>> = noise(5, 1.0)
            .iter()
            .enumerate()
            .map(|(i, g)| g.map(|g| g * if i % N < N / 2 { 0.001 } else { 0.1 }))
            .collect();
        let level = pixel_noise(&block_roughness(&e, N), &render, N, 0.01);
        for y in 0..N {
            let (left, right) = (level[y * N + 8], level[y * N + N - 8]);
            assert!(left > 0.024 && left < 0.033, "{left}");
            assert_eq!(right, 0.01);
        }
        // and never falls below the view's level
        let quiet = noise(6, 0.001);
        assert!(pixel_noise(&block_roughness(&quiet, N), &render, N, 0.01)
            .iter()
            .all(|&s| s == 0.01));
    }
}
