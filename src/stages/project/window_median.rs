//! Exact medians of the overlapping windows the noise estimator reads (a block of pixel pairs
//! and the eight blocks around it), without gathering and selecting every window's pairs anew.
//!
//! Each pair lies in nine windows, so selecting each window's median among its own copy of its
//! pairs handles every pair nine times, and was a quarter of the refinement passes on a room of
//! 512x384 photos. Here each block's pairs are counted once by a monotone key (the float's
//! exponent and top mantissa bits, [`KEYS_PER_OCTAVE`] keys per octave) and grouped by it; a
//! window's median key is found from its nine blocks' cumulative counts, and the median is
//! selected among the few pairs of that key alone. The key only narrows the search: the value
//! is the window's median exactly, bit for bit. Written here because it is a few lines over a
//! layout of this module's own; no crate selects order statistics of overlapping windows.

use rayon::prelude::*;

/// Keys a pair's value maps to (the lowest and highest take everything beyond them).
const KEYS: usize = 256;
/// Keys per doubling of a pair's value: `2^(23 - KEY_SHIFT)`.
const KEYS_PER_OCTAVE: u32 = 8;
/// The bits of a non-negative float below its key.
const KEY_SHIFT: u32 = 23 - KEYS_PER_OCTAVE.trailing_zeros();

/// The pairs of an image, block by block: per block the count of its pairs below each key and
/// its pairs grouped by key.
pub struct BlockPairs {
    /// The image's width and height, pixels.
    size: (usize, usize),
    /// A block's side, pixels.
    block: usize,
    /// Blocks per row and per column.
    grid: (usize, usize),
    /// Pairs a block holds at most.
    cap: usize,
    /// Per block, whether it holds its pairs.
    needed: Vec<bool>,
    /// Per block, `KEYS + 1` counts: its pairs whose key is below `k`.
    below: Vec<u8>,
    /// Per block, `cap` slots: its pairs in order of key.
    values: Vec<u32>,
    /// The raw key of key 0 (`bits >> KEY_SHIFT`).
    base: u32,
}

impl BlockPairs {
    /// Room for the pairs of an image `width x height` in blocks of `block x block` pixels,
    /// of the blocks `needed` takes (by block index, row by row; the others hold no pair);
    /// none yet.
    pub fn new((width, height): (usize, usize), block: usize, needed: Vec<bool>) -> BlockPairs {
        let cap = block * block;
        assert!(cap <= u8::MAX as usize, "a block's count fits a byte");
        let grid = (width.div_ceil(block), height.div_ceil(block));
        assert_eq!(needed.len(), grid.0 * grid.1, "one flag per block");
        BlockPairs {
            size: (width, height),
            block,
            grid,
            cap,
            needed,
            below: vec![0u8; grid.0 * grid.1 * (KEYS + 1)],
            values: vec![0u32; grid.0 * grid.1 * cap],
            base: 0,
        }
    }

    /// The pairs of `pairs` (the image's, the bits of non-negative floats, `none` where a
    /// pixel holds no pair), in place of those held.
    pub fn fill(&mut self, pairs: &[u32], none: u32) {
        let ((width, height), block, cap, gw) = (self.size, self.block, self.cap, self.grid.0);
        assert_eq!(pairs.len(), width * height, "one pair per pixel");
        let base = median_raw_key(pairs, none).saturating_sub(KEYS as u32 / 2);
        let needed = &self.needed;
        (self.below.par_chunks_mut(gw * (KEYS + 1)))
            .zip(self.values.par_chunks_mut(gw * cap))
            .enumerate()
            .for_each(|(by, (below, values))| {
                let ys = by * block..((by + 1) * block).min(height);
                for bx in (0..gw).filter(|bx| needed[by * gw + bx]) {
                    let xs = bx * block..((bx + 1) * block).min(width);
                    let rows = ys
                        .clone()
                        .map(|y| &pairs[y * width + xs.start..y * width + xs.end]);
                    let mine = rows.flatten().copied().filter(|&b| b != none);
                    let below = &mut below[bx * (KEYS + 1)..(bx + 1) * (KEYS + 1)];
                    group(mine, base, below, &mut values[bx * cap..(bx + 1) * cap]);
                }
            });
        self.base = base;
    }

    /// The median (the value of rank `n / 2` of the `n`) of the pairs of the window around
    /// block `(bx, by)`: the block and the eight around it within the grid; `None` under
    /// `min_pairs` pairs. `scratch` is scratch space.
    pub fn window_median(
        &self,
        (bx, by): (usize, usize),
        min_pairs: usize,
        scratch: &mut Vec<u32>,
    ) -> Option<u32> {
        let mut blocks = [0usize; 9];
        let mut k = 0;
        for b in window_blocks((bx, by), self.grid) {
            (blocks[k], k) = (b, k + 1);
        }
        let blocks = &blocks[..k];
        let below = |b: usize, key: usize| self.below[b * (KEYS + 1) + key] as usize;
        let count = |key: usize| blocks.iter().map(|&b| below(b, key)).sum::<usize>();
        let n = count(KEYS);
        if n < min_pairs || n == 0 {
            return None;
        }
        let rank = n / 2;
        // the least key with more than `rank` pairs at or below it holds the median
        let (mut lo, mut hi) = (0, KEYS - 1);
        while lo < hi {
            let mid = (lo + hi) / 2;
            match count(mid + 1) > rank {
                true => hi = mid,
                false => lo = mid + 1,
            }
        }
        let before = count(lo);
        scratch.clear();
        for &b in blocks {
            let slots = &self.values[b * self.cap..(b + 1) * self.cap];
            scratch.extend_from_slice(&slots[below(b, lo)..below(b, lo + 1)]);
        }
        Some(*scratch.select_nth_unstable(rank - before).1)
    }

    /// The key of a pair's bits: monotone in the value.
    #[cfg(test)]
    fn key(&self, bits: u32) -> usize {
        key(bits, self.base)
    }
}

/// The blocks (by index, row by row) of the window around block `(bx, by)` of a `gw x gh`
/// grid: the block and the eight around it within the grid.
fn window_blocks(
    (bx, by): (usize, usize),
    (gw, gh): (usize, usize),
) -> impl Iterator<Item = usize> {
    (by.saturating_sub(1)..(by + 2).min(gh))
        .flat_map(move |y| (bx.saturating_sub(1)..(bx + 2).min(gw)).map(move |x| y * gw + x))
}

/// Per block of a `gw x gh` grid, whether it lies in the window of a block `wanted` takes:
/// the blocks a [`BlockPairs`] must hold for the windows of those.
pub fn needed_for((gw, gh): (usize, usize), wanted: &(dyn Fn(usize) -> bool + Sync)) -> Vec<bool> {
    let mut needed = vec![false; gw * gh];
    for b in (0..gw * gh).filter(|&b| wanted(b)) {
        for n in window_blocks((b % gw, b / gw), (gw, gh)) {
            needed[n] = true;
        }
    }
    needed
}

/// The key of `bits` (a non-negative float's) above `base`: one per `1 / KEYS_PER_OCTAVE` of
/// an octave, clamped into `0..KEYS`; never decreasing as the value grows.
#[inline]
fn key(bits: u32, base: u32) -> usize {
    ((bits >> KEY_SHIFT).saturating_sub(base) as usize).min(KEYS - 1)
}

/// A block's pairs `mine` counted below each key (`below`, `KEYS + 1` counts) and written into
/// `slots` in order of key. Only the keys between the block's least and greatest are counted
/// one by one; the counts below and above them are 0 and all.
fn group(mine: impl Iterator<Item = u32>, base: u32, below: &mut [u8], slots: &mut [u32]) {
    let mut keys = [0u8; u8::MAX as usize];
    let mut count = [0u8; KEYS];
    let (mut n, mut lo, mut hi) = (0, KEYS - 1, 0);
    for b in mine {
        let k = key(b, base);
        (slots[n], keys[n]) = (b, k as u8);
        count[k] += 1;
        (lo, hi, n) = (lo.min(k), hi.max(k), n + 1);
    }
    if n == 0 {
        below.fill(0);
        return;
    }
    below[..=lo].fill(0);
    let mut sum = 0u8;
    for k in lo..=hi {
        below[k] = sum;
        sum += count[k];
    }
    below[hi + 1..].fill(sum);
    // in order of key: a counting sort from the block's own copy
    let mut mine = [0u32; u8::MAX as usize];
    mine[..n].copy_from_slice(&slots[..n]);
    let mut at: [u8; KEYS] = [0; KEYS];
    at[lo..=hi].copy_from_slice(&below[lo..=hi]);
    for (&b, &k) in mine[..n].iter().zip(&keys[..n]) {
        slots[at[k as usize] as usize] = b;
        at[k as usize] += 1;
    }
}

/// The median raw key (`bits >> KEY_SHIFT`) of the pairs of `pairs` (0 if there are none):
/// where the keys are centred, so that windows rougher or smoother by up to 2^16 fall on keys
/// of their own.
fn median_raw_key(pairs: &[u32], none: u32) -> u32 {
    let mut hist = vec![0u64; (u32::MAX >> KEY_SHIFT) as usize + 1];
    let mut n = 0u64;
    for &b in pairs.iter().filter(|&&b| b != none) {
        hist[(b >> KEY_SHIFT) as usize] += 1;
        n += 1;
    }
    let mut seen = 0;
    for (k, &h) in hist.iter().enumerate() {
        seen += h;
        if 2 * seen > n {
            return k as u32;
        }
    }
    0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::rng::Rng;

    const NONE: u32 = u32::MAX;

    /// The median of the window by sorting its pairs.
    fn brute(
        pairs: &[u32],
        (w, h): (usize, usize),
        block: usize,
        (bx, by): (usize, usize),
    ) -> Option<u32> {
        let ys = (by * block).saturating_sub(block)..((by + 2) * block).min(h);
        let xs = (bx * block).saturating_sub(block)..((bx + 2) * block).min(w);
        let mut v: Vec<u32> = ys
            .flat_map(|y| xs.clone().map(move |x| pairs[y * w + x]))
            .filter(|&b| b != NONE)
            .collect();
        v.sort_unstable();
        (!v.is_empty()).then(|| v[v.len() / 2])
    }

    /// Against sorting each window: values over many octaves (some beyond the keys' range at
    /// both ends), repeated values (zeros and a few levels, as 8-bit photos give), missing
    /// pairs, sides that are not whole blocks, and blocks not needed.
    #[test]
    fn window_medians_are_those_of_sorting_each_window() {
        for (case, (w, h)) in [(37usize, 29usize), (8, 8), (5, 40), (64, 17), (48, 40)]
            .into_iter()
            .enumerate()
        {
            let pairs: Vec<u32> = (0..w * h)
                .map(|i| {
                    let mut r = Rng::new(3, case as u64, 0, i as u64);
                    let g = r.normal().abs();
                    match i % 7 {
                        0 => NONE,
                        1 => 0,
                        2 => ((g * 4.0).round() / 4.0).to_bits(),
                        3 => (g * 1e-30).to_bits(),
                        4 => (g * 1e30).to_bits(),
                        _ => (g * 0.01 * (1 + i % w) as f32).to_bits(),
                    }
                })
                .collect();
            let (gw, gh) = (w.div_ceil(8), h.div_ceil(8));
            let needed: Vec<bool> = (0..gw * gh).map(|b| b % 4 != 3).collect();
            let mut bp = BlockPairs::new((w, h), 8, needed.clone());
            // filled twice: what the first held leaves nothing behind
            let other: Vec<u32> = pairs.iter().rev().copied().collect();
            bp.fill(&other, NONE);
            bp.fill(&pairs, NONE);
            // a window sees only needed blocks: compare where all nine are
            let masked: Vec<u32> = (0..w * h)
                .map(|i| match needed[(i / w / 8) * gw + (i % w) / 8] {
                    true => pairs[i],
                    false => NONE,
                })
                .collect();
            let mut scratch = Vec::new();
            for by in 0..gh {
                for bx in 0..gw {
                    let got = bp.window_median((bx, by), 1, &mut scratch);
                    assert_eq!(
                        got,
                        brute(&masked, (w, h), 8, (bx, by)),
                        "{w}x{h} ({bx},{by})"
                    );
                }
            }
            let few = bp.window_median((0, 0), 10_000, &mut scratch);
            assert_eq!(few, None, "under the fewest pairs");
        }
    }

    /// Keys never decrease as the value grows, and span a range around the pairs' median.
    #[test]
    fn keys_are_monotone_and_centred_on_the_median() {
        let pairs: Vec<u32> = (0..1000)
            .map(|i| (1.0 + i as f32 * 1e-3).to_bits())
            .collect();
        let mut bp = BlockPairs::new((1000, 1), 8, vec![true; 125]);
        bp.fill(&pairs, NONE);
        assert_eq!(bp.key(1.5f32.to_bits()), KEYS / 2);
        let mut last = 0;
        for v in [
            0.0f32,
            1e-30,
            1e-3,
            0.5,
            1.0,
            1.0001,
            1.5,
            2.0,
            4.0,
            1e3,
            1e30,
            f32::MAX,
        ] {
            let k = bp.key(v.to_bits());
            assert!(k >= last && k < KEYS, "{v}: {k} after {last}");
            last = k;
        }
        assert_eq!(
            bp.key(4.0f32.to_bits()) - bp.key(2.0f32.to_bits()),
            KEYS_PER_OCTAVE as usize
        );
    }
}
