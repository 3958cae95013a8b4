//! The fill of unobserved texels (method step 5 for texels no photo saw): `K_d` from observed
//! neighbours of the same chart, wave by wave, then the shape's mean for charts nobody saw.
//!
//! A texture that fits in the memory given is filled whole ([`fill_unobserved`]). A larger one
//! is filled tile by tile ([`fill_tiled`]) with the same result bit for bit: round `d` of the
//! wave gives a texel the mean of its same-chart neighbours filled in round `d - 1`, so a
//! texel's round is its distance (8-connected, within its chart) from the nearest observed
//! texel and its value depends only on its neighbours one round closer. Each pass recomputes
//! a tile from its own observed texels and the ring of texels around it as the last pass left
//! them (distance and value); a tile is recomputed only when its ring changed, and passes
//! repeat until nothing changes. Distances only decrease from pass to pass, so this ends, and
//! where it ends every texel satisfies the wave's equations, whose solution is unique.
//!
//! The wave's values are then relaxed to the harmonic fill ([`harmonic`]): the smoothest
//! interpolant of each hole's observed border, in place of the wave's streaks.

use crate::atlas::store::TileStore;
use crate::atlas::store::{flags, Layout, TexelGeom, TexelState};
use crate::atlas::texture::{Block, Grid, Scratch, SlotTexture};
use crate::atlas::uv::Charts;
use crate::atlas::uv::NONE;
use crate::base::error::Result;
use crate::base::progress::Tick;
use glam::Vec3;
use rayon::prelude::*;
use std::collections::BTreeMap;

mod harmonic;

/// Fill the K_d of unobserved surface texels of one texture from observed neighbours of the
/// same chart (repeated 8-neighbour averaging, chart by chart), and any texel still without a
/// value from the mean of the observed texels (the shape's mean). `chart[i]` is the texel's
/// chart (None for gutter); `observed[i]` marks texels with a measured K_d. Returns the mask
/// of texels that were filled.
///
/// Round `k` gives every still-unknown texel that touches a texel known before round `k` the
/// mean of those neighbours (one wave of a breadth-first fill). Only the neighbours of the
/// previous round's texels can change in a round, so each round visits just those: the cost
/// is proportional to the filled area, not to the texture's area times the fill's depth (a
/// wide unobserved floor would take thousands of whole-texture sweeps).
pub fn fill_unobserved(
    kd: &mut [Vec3],
    observed: &[bool],
    chart: &[Option<u32>],
    width: u32,
    height: u32,
) -> Vec<bool> {
    let (known, mut filled) = wave_fill(kd, observed, chart, width, height);
    fill_with_mean(kd, observed, chart, &known, &mut filled);
    filled
}

/// The waves of [`fill_unobserved`]: returns which texels are known after them (observed or
/// reached) and which of those were filled.
fn wave_fill(
    kd: &mut [Vec3],
    observed: &[bool],
    chart: &[Option<u32>],
    width: u32,
    height: u32,
) -> (Vec<bool>, Vec<bool>) {
    let (w, h) = (width as i64, height as i64);
    let mut known: Vec<bool> = observed.to_vec();
    let mut filled = vec![false; kd.len()];
    let neighbours = |i: usize| {
        let (x, y) = (i as i64 % w, i as i64 / w);
        (-1..=1i64)
            .flat_map(move |dy| (-1..=1i64).map(move |dx| (x + dx, y + dy)))
            .filter(move |&(nx, ny)| nx >= 0 && ny >= 0 && nx < w && ny < h)
            .map(move |(nx, ny)| (ny * w + nx) as usize)
    };
    // Round 0's candidates: unknown surface texels next to an observed one.
    let mut front: Vec<usize> = (0..kd.len()).filter(|&i| known[i]).collect();
    let mut queued = vec![false; kd.len()];
    loop {
        let mut candidates = Vec::new();
        for &i in &front {
            for j in neighbours(i) {
                if !known[j] && !queued[j] && chart[j].is_some() {
                    queued[j] = true;
                    candidates.push(j);
                }
            }
        }
        // Row-major order, as a sweep would visit them (the values do not depend on it).
        candidates.sort_unstable();
        let changes: Vec<(usize, Vec3)> = candidates
            .iter()
            .filter_map(|&i| {
                let c = chart[i];
                let (mut sum, mut n) = (Vec3::ZERO, 0u32);
                for j in neighbours(i) {
                    if known[j] && chart[j] == c {
                        sum += kd[j];
                        n += 1;
                    }
                }
                (n > 0).then(|| (i, sum / n as f32))
            })
            .collect();
        for &i in &candidates {
            queued[i] = false;
        }
        if changes.is_empty() {
            break;
        }
        for &(i, val) in &changes {
            kd[i] = val;
            known[i] = true;
            filled[i] = true;
        }
        front = changes.into_iter().map(|(i, _)| i).collect();
    }
    (known, filled)
}

/// Charts with no observed texel at all: the shape's mean (0.5 if nothing is observed).
/// Returns the observed texels' sum and count.
fn fill_with_mean(
    kd: &mut [Vec3],
    observed: &[bool],
    chart: &[Option<u32>],
    known: &[bool],
    filled: &mut [bool],
) -> Observed {
    let (mut sum, mut n) = (Vec3::ZERO, 0u32);
    for (i, &o) in observed.iter().enumerate() {
        if o {
            sum += kd[i];
            n += 1;
        }
    }
    let obs = Observed { sum, n };
    let mean = obs.mean();
    for i in 0..kd.len() {
        if chart[i].is_some() && !known[i] {
            kd[i] = mean;
            filled[i] = true;
        }
    }
    obs
}

/// The sum and count of a texture's observed `K_d`, summed in row-major order.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Observed {
    pub sum: Vec3,
    pub n: u32,
}

impl Observed {
    /// The observed texels' mean, 0.5 when there are none.
    fn mean(&self) -> Vec3 {
        match self.n {
            0 => Vec3::splat(0.5),
            n => self.sum / n as f32,
        }
    }
}

/// What the fill knows of a texel: its `K_d`, chart ([`NONE`] = not fillable) and wave round
/// (0 = observed, [`FAR`] = not reached yet).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct FillTexel {
    pub kd: Vec3,
    pub chart: u32,
    pub round: u32,
}

/// Not reached by the wave (yet).
const FAR: u32 = u32::MAX;

/// What [`fill_unobserved_all`] filled.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Filled {
    /// Covered texels no view saw, given a `K_d`.
    pub texels: u64,
    /// Of those, the ones in textures whose harmonic relaxation did not fit in the scratch
    /// budget (they keep the wave's values).
    pub unrelaxed: u64,
    /// Shapes no photo saw that took the mean of their material's observed shapes.
    pub shared_shapes: u64,
}

/// [`fill_unobserved`] over every texture of the layout, one texture at a time: unobserved
/// covered texels get `K_d` from observed neighbours of their chart (else the shape's mean)
/// and the `FILLED` flag, a texture whole if it fits in `scratch`'s budget, else tile by tile
/// (the same values), then the harmonic relaxation. `tick` gets every tile read and every
/// tile written back (two per tile in all; the waves between are not counted). Returns what
/// was filled and, per slot, its observed texels (see [`shared_fill`]).
#[inline(never)] // a stage entry tools/icount.py measures
pub fn fill_unobserved_all(
    layout: &Layout,
    charts: &Charts,
    geom: &TileStore<TexelGeom>,
    state: &mut TileStore<TexelState>,
    scratch: &Scratch,
    tick: Tick,
) -> Result<(Filled, Vec<Observed>)> {
    // A texture filled whole is copied about five times over (its records, K_d, masks,
    // charts, the result); the budget is for all of them, the tiled path keeps three caches.
    // The relaxation's system lives beside the texture: it may take the whole scratch budget.
    let relax_budget = scratch.budget;
    let scratch = &scratch.share(1, FILL_COPIES);
    let mut filled = Filled::default();
    let mut observed = Vec::with_capacity(layout.slots.len());
    for slot in 0..layout.slots.len() {
        let c = &charts.slots[slot];
        let sources = (layout, slot, &*state, geom);
        let read = |s: &TexelState, g: &TexelGeom| {
            let observed = g.covered() && s.flags & flags::OBSERVED != 0;
            FillTexel {
                kd: Vec3::from_array(s.k_d),
                chart: c.texel(g),
                round: if observed { 0 } else { FAR },
            }
        };
        let tex = SlotTexture::read_ticking(sources, scratch, "fill", read, tick)?;
        let (out, relaxed, obs) = match tex.is_whole() {
            true => fill_whole(&tex, scratch, relax_budget)?,
            false => fill_tiled(tex, scratch, relax_budget)?,
        };
        observed.push(obs);
        let write = |r: &mut TexelState, v: &FillTexel| match v.round {
            FILLED_MARK | MEAN_MARK => {
                r.k_d = v.kd.to_array();
                r.flags |= flags::FILLED;
                true
            }
            _ => false,
        };
        let n = out.write_ticking(state, write, tick)?;
        filled.texels += n;
        if !relaxed {
            filled.unrelaxed += n;
        }
    }
    Ok((filled, observed))
}

/// Per slot, the `K_d` a shape no photo saw takes from the shapes of its material: `groups`
/// gives each slot's material (shapes the scene gives one named material, see
/// `Shape::material_name`), `observed` each slot's observed texels. A slot with no observed
/// texel whose material has some gets their mean (summed in slot order, in f64); every other
/// slot `None`. One material is one colour more often than not, and its mean is a better
/// guess than the grey the shape's own (empty) mean leaves.
pub fn shared_fill(groups: &[Option<u32>], observed: &[Observed]) -> Vec<Option<Vec3>> {
    let mut by_group: BTreeMap<u32, (glam::DVec3, u64)> = BTreeMap::new();
    for (g, o) in groups.iter().zip(observed) {
        if let Some(g) = g {
            let e = by_group.entry(*g).or_default();
            e.0 += o.sum.as_dvec3();
            e.1 += o.n as u64;
        }
    }
    (groups.iter().zip(observed))
        .map(|(g, o)| {
            let (sum, n) = by_group.get(g.as_ref()?)?;
            (o.n == 0 && *n > 0).then(|| (*sum / *n as f64).as_vec3())
        })
        .collect()
}

/// Share of the scratch budget a texture may take as one copy in [`fill_unobserved_all`]:
/// [`fill_whole`] holds about 102 bytes per texel at its peak, five copies of a 20-byte
/// [`FillTexel`] (a 12M-texel wall held whole once took 1.4 GB beside a 256 MB budget).
const FILL_COPIES: u64 = 6;

/// Marks a texel filled by the wave in the fill's result.
const FILLED_MARK: u32 = FAR - 1;

/// Marks a texel the wave never reached, filled with the shape's mean (its chart nobody saw).
const MEAN_MARK: u32 = FAR - 2;

/// A texture held whole: [`fill_unobserved`] on its arrays, then the harmonic relaxation.
fn fill_whole(
    tex: &SlotTexture<FillTexel>,
    scratch: &Scratch,
    relax_budget: u64,
) -> Result<(SlotTexture<FillTexel>, bool, Observed)> {
    let g = tex.grid;
    let v = tex.to_vec();
    let mut kd: Vec<Vec3> = v.iter().map(|t| t.kd).collect();
    let observed: Vec<bool> = v.iter().map(|t| t.round == 0).collect();
    let chart: Vec<Option<u32>> = v
        .iter()
        .map(|t| (t.chart != NONE).then_some(t.chart))
        .collect();
    let (known, mut filled) = wave_fill(&mut kd, &observed, &chart, g.width, g.height);
    let obs = fill_with_mean(&mut kd, &observed, &chart, &known, &mut filled);
    let result: Vec<FillTexel> = (0..v.len())
        .map(|i| FillTexel {
            kd: kd[i],
            chart: v[i].chart,
            round: match (filled[i], known[i]) {
                (false, _) => 0,
                (true, true) => FILLED_MARK,
                (true, false) => MEAN_MARK,
            },
        })
        .collect();
    let mut out = SlotTexture::build(g, scratch, "filled", |t| {
        let mut out = vec![FillTexel::default(); g.tile_texels()];
        for (off, x, y) in g.texels_of(t) {
            out[off] = result[(y * g.width + x) as usize];
        }
        Ok(out)
    })?;
    let relaxed = harmonic::relax(&mut out, relax_budget)?;
    Ok((out, relaxed, obs))
}

/// A texture held in tiles: passes over the tiles whose ring changed until nothing changes,
/// then the shape's mean for what the wave never reached and the harmonic relaxation (see the
/// module docs).
pub fn fill_tiled(
    mut cur: SlotTexture<FillTexel>,
    scratch: &Scratch,
    relax_budget: u64,
) -> Result<(SlotTexture<FillTexel>, bool, Observed)> {
    let g = cur.grid;
    let obs = observed_sum(&cur);
    let mean = obs.mean();
    let mut next = SlotTexture::build(g, scratch, "fill-next", |_| {
        Ok(vec![FillTexel::default(); g.tile_texels()])
    })?;
    let mut active: Vec<u32> = (0..g.tiles()).collect();
    while !active.is_empty() {
        // compute every active tile from `cur`, keep the changed ones in `next`
        let group = (4 * rayon::current_num_threads()).max(1);
        let mut changed = Vec::new();
        for chunk in active.chunks(group) {
            let made: Vec<(u32, Vec<FillTexel>, bool, bool)> = chunk
                .par_iter()
                .map(|&t| {
                    let old = cur.tile(t)?;
                    let new = fill_tile(&g, &cur.block(t, 1), t, &old);
                    let border = border_changed(&g, t, &old, &new);
                    Ok((t, new.clone(), new != old, border))
                })
                .collect::<Result<_>>()?;
            cur.check()?;
            for (t, new, any, border) in made {
                if any {
                    next.set_tile(t, new)?;
                    changed.push((t, border));
                }
            }
        }
        let mut again = std::collections::BTreeSet::new();
        for &(t, border) in &changed {
            cur.set_tile(t, next.tile(t)?)?;
            if border {
                again.extend(neighbour_tiles(&g, t));
            }
        }
        active = again.into_iter().collect();
    }
    // the unreached take the mean; every reached unobserved texel is marked filled
    let mut out = SlotTexture::build(g, scratch, "filled", |t| {
        Ok(cur
            .tile(t)?
            .into_iter()
            .map(|v| match (v.chart, v.round) {
                (NONE, _) | (_, 0) => FillTexel { round: 0, ..v },
                (_, FAR) => FillTexel {
                    kd: mean,
                    round: MEAN_MARK,
                    ..v
                },
                _ => FillTexel {
                    round: FILLED_MARK,
                    ..v
                },
            })
            .collect())
    })?;
    cur.check()?;
    let relaxed = harmonic::relax(&mut out, relax_budget)?;
    Ok((out, relaxed, obs))
}

/// The observed texels' `K_d` summed in row-major order (as [`fill_with_mean`] sums).
fn observed_sum(tex: &SlotTexture<FillTexel>) -> Observed {
    let (mut sum, mut n) = (Vec3::ZERO, 0u32);
    for y in 0..tex.grid.height {
        for v in tex.row(y) {
            if v.round == 0 {
                sum += v.kd;
                n += 1;
            }
        }
    }
    Observed { sum, n }
}

/// Tile `t` recomputed from its observed texels and the ring of `block` (halo 1): rounds by a
/// bucketed breadth-first search within the tile, then values in round order.
fn fill_tile(g: &Grid, block: &Block<FillTexel>, t: u32, old: &[FillTexel]) -> Vec<FillTexel> {
    let (bw, bh) = (block.width as i64, block.height as i64);
    let (x0, y0) = (block.x0 as i64, block.y0 as i64);
    let mut b = block.vals.clone();
    let inside = |x: i64, y: i64| -> bool {
        let (tx, ty) = ((t % g.tiles_x) * g.tile_size, (t / g.tiles_x) * g.tile_size);
        x >= tx as i64
            && y >= ty as i64
            && x < (tx + g.tile_size) as i64
            && y < (ty + g.tile_size) as i64
    };
    let idx = |x: i64, y: i64| ((y - y0) * bw + (x - x0)) as usize;
    // the tile's unobserved texels start unreached; the ring keeps what the last pass left
    let mut buckets: BTreeMap<u32, Vec<(i64, i64)>> = BTreeMap::new();
    for y in y0..y0 + bh {
        for x in x0..x0 + bw {
            let v = &mut b[idx(x, y)];
            if inside(x, y) && v.round != 0 {
                v.round = FAR;
            }
            if v.chart != NONE && v.round != FAR {
                buckets.entry(v.round).or_default().push((x, y));
            }
        }
    }
    let mut order = Vec::new();
    while let Some((d, list)) = buckets.pop_first() {
        for (x, y) in list {
            let (c, r) = (b[idx(x, y)].chart, b[idx(x, y)].round);
            if r != d {
                continue; // reached earlier at a smaller round
            }
            if inside(x, y) && d > 0 {
                order.push((x, y));
            }
            for (nx, ny) in neighbours(x, y, x0, y0, bw, bh) {
                let n = &mut b[idx(nx, ny)];
                if inside(nx, ny) && n.chart == c && n.round != 0 && n.round > d + 1 {
                    n.round = d + 1;
                    buckets.entry(d + 1).or_default().push((nx, ny));
                }
            }
        }
    }
    // values in round order: the mean of the same-chart neighbours one round closer
    for (x, y) in order {
        let (c, d) = (b[idx(x, y)].chart, b[idx(x, y)].round);
        let (mut sum, mut n) = (Vec3::ZERO, 0u32);
        for (nx, ny) in neighbours(x, y, x0, y0, bw, bh) {
            let m = &b[idx(nx, ny)];
            if m.chart == c && m.round == d - 1 {
                sum += m.kd;
                n += 1;
            }
        }
        b[idx(x, y)].kd = sum / n as f32;
    }
    let mut out = old.to_vec();
    for (off, x, y) in g.texels_of(t) {
        out[off] = b[idx(x as i64, y as i64)];
    }
    out
}

/// The 8 neighbours of `(x, y)` inside the block, row by row (the order the wave sums in).
fn neighbours(
    x: i64,
    y: i64,
    x0: i64,
    y0: i64,
    bw: i64,
    bh: i64,
) -> impl Iterator<Item = (i64, i64)> {
    (-1..=1i64)
        .flat_map(move |dy| (-1..=1i64).map(move |dx| (x + dx, y + dy)))
        .filter(move |&(nx, ny)| {
            (nx, ny) != (x, y) && nx >= x0 && ny >= y0 && nx < x0 + bw && ny < y0 + bh
        })
}

/// Whether a texel on the edge of tile `t` changed (what its neighbours' rings see).
fn border_changed(g: &Grid, t: u32, old: &[FillTexel], new: &[FillTexel]) -> bool {
    let ts = g.tile_size;
    let (tx, ty) = ((t % g.tiles_x) * ts, (t / g.tiles_x) * ts);
    let (w, h) = ((tx + ts).min(g.width) - tx, (ty + ts).min(g.height) - ty);
    g.texels_of(t).any(|(off, x, y)| {
        let edge = x == tx || y == ty || x == tx + w - 1 || y == ty + h - 1;
        edge && old[off] != new[off]
    })
}

/// The tiles around tile `t` (not `t` itself), in the slot's grid.
fn neighbour_tiles(g: &Grid, t: u32) -> Vec<u32> {
    let (tx, ty) = ((t % g.tiles_x) as i64, (t / g.tiles_x) as i64);
    (-1..=1i64)
        .flat_map(|dy| (-1..=1i64).map(move |dx| (tx + dx, ty + dy)))
        .filter(|&(x, y)| {
            (x, y) != (tx, ty) && x >= 0 && y >= 0 && x < g.tiles_x as i64 && y < g.tiles_y as i64
        })
        .map(|(x, y)| (y * g.tiles_x as i64 + x) as u32)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fill as first written: whole-texture sweeps until nothing changes.
    fn fill_by_sweeps(
        kd: &mut [Vec3],
        observed: &[bool],
        chart: &[Option<u32>],
        w: i64,
        h: i64,
    ) -> Vec<bool> {
        let mut known: Vec<bool> = observed.to_vec();
        let mut filled = vec![false; kd.len()];
        loop {
            let mut changes = Vec::new();
            for i in 0..(w * h) as usize {
                let (x, y) = (i as i64 % w, i as i64 / w);
                if chart[i].is_none() || known[i] {
                    continue;
                }
                let (mut sum, mut n) = (Vec3::ZERO, 0u32);
                for (dx, dy) in (-1..=1).flat_map(|dy| (-1..=1).map(move |dx| (dx, dy))) {
                    let (nx, ny) = (x + dx, y + dy);
                    let j = (ny * w + nx) as usize;
                    if nx >= 0 && ny >= 0 && nx < w && ny < h && known[j] && chart[j] == chart[i] {
                        sum += kd[j];
                        n += 1;
                    }
                }
                if n > 0 {
                    changes.push((i, sum / n as f32));
                }
            }
            if changes.is_empty() {
                break;
            }
            for (i, v) in changes {
                (kd[i], known[i], filled[i]) = (v, true, true);
            }
        }
        fill_with_mean(kd, observed, chart, &known, &mut filled);
        filled
    }

    #[test]
    fn a_shape_no_photo_saw_takes_its_materials_mean() {
        let o = |sum: f32, n: u32| Observed {
            sum: Vec3::new(sum, 2.0 * sum, 0.0),
            n,
        };
        // material 0: slots 0, 3 and 5 observed (texel sums 1, 1 and 3 over 4, 1 and 3
        // texels), slot 1 unseen: it takes their texels' mean, 5 / 8; slot 2 has no name,
        // slot 4's material has nothing observed, and the observed keep their own
        let groups = [Some(0), Some(0), None, Some(0), Some(1), Some(0)];
        let observed = [
            o(1.0, 4),
            o(0.0, 0),
            o(0.0, 0),
            o(1.0, 1),
            o(0.0, 0),
            o(3.0, 3),
        ];
        let got = shared_fill(&groups, &observed);
        assert_eq!(got.len(), 6);
        let want = Vec3::new(0.625, 1.25, 0.0);
        assert!(got[1].unwrap().abs_diff_eq(want, 1e-7), "{:?}", got[1]);
        assert_eq!([got[0], got[2], got[3], got[4], got[5]], [None; 5]);
    }

    #[test]
    fn the_wavefront_fill_equals_whole_texture_sweeps_bit_for_bit() {
        let mut rng = crate::base::rng::Rng::new(7, 0, 0, 0);
        for case in 0..40 {
            let (w, h) = (3 + (case % 7) * 5, 2 + (case % 5) * 7);
            let n = (w * h) as usize;
            // blobs of charts, gutter here and there, sparse observations (some charts none)
            let chart: Vec<Option<u32>> = (0..n)
                .map(|i| {
                    let (x, y) = (i as u32 % w, i as u32 / w);
                    (rng.f32() > 0.1).then_some(x / 6 + 4 * (y / 5))
                })
                .collect();
            let observed: Vec<bool> = (0..n)
                .map(|i| chart[i].is_some() && rng.f32() < 0.03 * (1 + case % 4) as f32)
                .collect();
            let kd0: Vec<Vec3> = (0..n)
                .map(|_| Vec3::new(rng.f32(), rng.f32(), rng.f32()))
                .collect();
            let (mut a, mut b) = (kd0.clone(), kd0.clone());
            let fa = fill_unobserved(&mut a, &observed, &chart, w, h);
            let fb = fill_by_sweeps(&mut b, &observed, &chart, w as i64, h as i64);
            assert_eq!(fa, fb, "case {case}: filled masks differ");
            let bits = |v: &[Vec3]| {
                v.iter()
                    .map(|k| k.to_array().map(f32::to_bits))
                    .collect::<Vec<_>>()
            };
            assert_eq!(bits(&a), bits(&b), "case {case}: values differ");
            assert!(fa.iter().any(|&f| f), "case {case} fills nothing");
        }
    }

    #[test]
    fn unobserved_texels_fill_from_their_own_chart_only() {
        // 4x1 texture: two charts [0,1] and [2,3]; texel 0 observed red, texel 3 observed blue
        let mut kd = vec![Vec3::X, Vec3::ZERO, Vec3::ZERO, Vec3::Z];
        let observed = [true, false, false, true];
        let chart = [Some(0), Some(0), Some(1), Some(1)];
        let filled = fill_unobserved(&mut kd, &observed, &chart, 4, 1);
        assert_eq!(kd, vec![Vec3::X, Vec3::X, Vec3::Z, Vec3::Z]);
        assert_eq!(filled, vec![false, true, true, false]);
        // a chart nobody saw takes the shape's mean
        let mut kd = vec![Vec3::X, Vec3::ZERO, Vec3::ZERO];
        let filled = fill_unobserved(
            &mut kd,
            &[true, false, false],
            &[Some(0), None, Some(1)],
            3,
            1,
        );
        assert_eq!(kd[2], Vec3::X);
        assert_eq!(kd[1], Vec3::ZERO, "gutter untouched");
        assert_eq!(filled, vec![false, false, true]);
    }

    /// Whole-texture fill and the tile-by-tile fill agree bit for bit (values and masks), on
    /// textures with many tiles, waves that cross several tiles and charts nobody saw.
    #[test]
    fn the_tiled_fill_equals_the_whole_texture_fill() {
        let dir = tempfile::tempdir().unwrap();
        let (big, tiny) = (
            Scratch::new(dir.path(), 1 << 30),
            Scratch::new(dir.path(), 1),
        );
        let mut rng = crate::base::rng::Rng::new(11, 0, 0, 0);
        let mut by_mean = 0;
        for case in 0..12u32 {
            let (w, h, ts) = (17 + case * 9, 11 + (case % 4) * 13, 4 + (case % 3) * 4);
            let g = crate::atlas::testing::grid(w, h, ts);
            let n = (w * h) as usize;
            let vals: Vec<FillTexel> = (0..n)
                .map(|i| {
                    let (x, y) = (i as u32 % w, i as u32 / w);
                    let chart = if rng.f32() > 0.08 {
                        x / 9 + 7 * (y / 6)
                    } else {
                        NONE
                    };
                    let obs = rng.f32() < 0.02 * (1 + case % 3) as f32;
                    FillTexel {
                        kd: Vec3::new(rng.f32(), rng.f32(), rng.f32()),
                        chart,
                        round: if obs { 0 } else { FAR },
                    }
                })
                .collect();
            let make = |s: &Scratch| {
                crate::atlas::testing::texture(g, s, |x, y| vals[(y * w + x) as usize])
            };
            let (a, b) = (make(&big), make(&tiny));
            assert!(a.is_whole() && !b.is_whole());
            let a = fill_whole(&a, &big, u64::MAX).unwrap().0.to_vec();
            let b = fill_tiled(b, &tiny, u64::MAX).unwrap().0.to_vec();
            let bits = |v: &[FillTexel]| {
                v.iter()
                    .map(|t| (t.kd.to_array().map(f32::to_bits), t.round))
                    .collect::<Vec<_>>()
            };
            assert_eq!(bits(&a), bits(&b), "case {case}");
            assert!(
                a.iter().filter(|t| t.round == FILLED_MARK).count() > n / 4,
                "case {case}"
            );
            by_mean += a.iter().filter(|t| t.round == MEAN_MARK).count();
        }
        assert!(by_mean > 0, "no chart left to the shape's mean");
    }

    /// The fill over a prepared atlas ticks every tile twice (read and written back), in a
    /// texture held whole and in one filled tile by tile, and fills every covered texel no
    /// photo saw; a progress stage of `2 x tiles` therefore ends at its total.
    #[test]
    fn the_fill_of_an_atlas_ticks_each_tile_read_and_written() {
        use crate::atlas::store::map_tiles;
        use crate::atlas::testing::Built;
        use std::sync::atomic::{AtomicU64, Ordering};
        let Built {
            p,
            dir,
            geom,
            charts,
        } = Built::cube(24.0);
        let tiles = p.layout.tile_count as u64;
        assert!(tiles > 4, "{tiles} tiles");
        for budget in [1u64 << 30, 1] {
            let mut state = p
                .create_store(dir.path().join(format!("s{budget}")), TexelState::default())
                .unwrap();
            // every 7th covered texel observed with K_d 0.5
            let observed: u64 = map_tiles(&mut state, &geom, 4, |_, g, s| {
                let mut n = 0;
                for (i, (g, s)) in g.iter().zip(s.iter_mut()).enumerate() {
                    if g.covered() && i % 7 == 0 {
                        s.flags |= flags::OBSERVED;
                        s.k_d = [0.5; 3];
                        n += 1;
                    }
                }
                n
            })
            .unwrap()
            .iter()
            .sum();
            let covered: u64 = (0..tiles as usize)
                .map(|t| {
                    geom.read_tile(t)
                        .unwrap()
                        .iter()
                        .filter(|g| g.covered())
                        .count() as u64
                })
                .sum();
            let ticks = AtomicU64::new(0);
            let scratch = Scratch::new(dir.path(), budget);
            let tick = |k: u64| {
                ticks.fetch_add(k, Ordering::Relaxed);
            };
            let (filled, _) =
                fill_unobserved_all(&p.layout, &charts, &geom, &mut state, &scratch, &tick)
                    .unwrap();
            assert_eq!(ticks.load(Ordering::Relaxed), 2 * tiles, "budget {budget}");
            assert_eq!(filled.texels, covered - observed, "budget {budget}");
            // a 1-byte budget holds no relaxation: the wave's values stay, and are counted
            match budget {
                1 => assert!(filled.unrelaxed > 0, "nothing counted unrelaxed"),
                _ => assert_eq!(filled.unrelaxed, 0, "budget {budget}"),
            }
        }
    }
}
