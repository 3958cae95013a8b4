//! Secondary illuminance `E_i` by forward light (photon) tracing with the current `K_d`
//! (method step 6): photons leave the emitters in proportion to their power, bounce
//! diffusely off the reconstructed surfaces, and every hit after at least one diffuse bounce
//! deposits its flux into the atlas texel under it. Direct light is not traced here (step 3
//! fixed it), nor light that reached a surface by mirrors and glass alone: a caustic pass
//! ([`Paths::Caustic`], once per run) traces that into `E_d`.
//!
//! # A pass, for the caller
//!
//! ```text
//! Charts::new(..)            once per run (texel/triangle -> chart tables)
//! AlbedoTextures::read(..)    per pass: current K_d per slot, gutter dilated (in tiles when large)
//! begin_pass(state)             accum := 0
//! photon_pass(ctx, state, 0, on_group)   accum += photon flux, batch by batch
//! finish_pass(geom, state)      accum := accum / bin_area  (irradiance, "E_i traced")
//! smooth_accum(..)              optional box filter within charts (smoothing_radius)
//! ```
//!
//! Between `photon_pass` and `finish_pass`, `TexelState::accum` holds the summed photon flux
//! (scene power units) that landed in the texel's square on its chart; after `finish_pass` it
//! holds the traced secondary irradiance `E_i` (flux / `bin_area`), which the solver reads.
//! `TexelState::e_i` is left to the solver.
//!
//! # Determinism
//!
//! Photon `i` of batch `b` in iteration `it` draws every random number from
//! `Rng::new(seed, it, b, i)`. Batches are traced in parallel, each into its own deposit list
//! in photon order; a group of batches is then binned per tile and added to `accum` in batch
//! order, then photon order. Every texel therefore sees the same sequence of f32 additions
//! whatever the thread count, the group size, or where a pass was interrupted and resumed
//! (`first_batch`): the result is bit-identical.
//!
//! # Unbiased bins
//!
//! A hit is deposited into texel `floor(uv)` only if that texel is covered *and* its center
//! lies on the same chart as the hit triangle; otherwise it is dropped. `TexelGeom::bin_area`
//! is exactly the part of the texel's square on the center's chart, so `accum / bin_area` is
//! an unbiased irradiance estimate for every covered texel, borders included.

mod smooth;
mod trace;

#[cfg(test)]
mod tests;

pub use smooth::{smooth_accum, smooth_within_charts};
pub use trace::{trace_photon, PathCounts};

use crate::atlas::context::HitTable;
use crate::atlas::store::{map_tiles, TileStore};
use crate::atlas::store::{Layout, TexelGeom, TexelState};
use crate::atlas::texture::{Scratch, SlotTexture};
use crate::atlas::uv::Charts;
use crate::atlas::uv::ShapeAtlas;
use crate::atlas::uv::NONE;
use crate::atlas::RunContext;
use crate::config::Config;
use crate::physics::accel::Accel;
use crate::physics::light::EmitterSampler;
use crate::scene::Scene;
use crate::{Error, Result};
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use std::time::Instant;

/// What a photon hit reads from the texel under it, in one 16-byte record so that a hit costs
/// one cache miss, not two (the texel's chart decides the deposit, its `K_d` the bounce).
#[derive(Debug, Clone, Copy, PartialEq, Default, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C, align(16))]
pub struct PathTexel {
    /// Linear RGB `K_d`.
    pub kd: Vec3,
    /// The chart under the texel's center (`NONE` in the gutter).
    pub chart: u32,
}

/// The current `K_d` of every reconstructed shape, one texture per layout slot (row 0 = top,
/// in the slot's atlas texel coordinates), each whole in memory when it fits in the scratch
/// budget, else in tiles behind a cache ([`SlotTexture`]). Gutter texels hold dilated `K_d`
/// values (hits in the uncovered border texels of a chart read them).
///
/// Photons read the texel under the hit (nearest), not a bilinear blend: the solver's `K_d`
/// of a texel is the mean albedo over its square (it divides the texel's mean radiance by its
/// mean irradiance), so a photon reflecting anywhere in that square should see exactly that
/// value; this keeps each texel's reflected energy consistent with the solver's model, and it
/// costs one memory access instead of four (the lookups miss the cache on large textures).
pub struct AlbedoTextures {
    pub slots: Vec<SlotTexture<PathTexel>>,
}

impl AlbedoTextures {
    /// `kd[slot]` everywhere on each slot (tests, benchmarks, a first pass).
    pub fn uniform_per_slot(
        layout: &Layout,
        charts: &Charts,
        geom: &TileStore<TexelGeom>,
        kd: &[Vec3],
        scratch: &Scratch,
    ) -> Result<Self> {
        if kd.len() != layout.slots.len() {
            return Err(Error::internal(format!(
                "albedo textures: {} values for {} reconstructed shapes",
                kd.len(),
                layout.slots.len()
            )));
        }
        let total: u64 = layout
            .slots
            .iter()
            .map(|s| s.width as u64 * s.height as u64)
            .sum();
        let slots = (0..layout.slots.len())
            .map(|slot| {
                let c = &charts.slots[slot];
                let st = &layout.slots[slot];
                let keep = scratch.share(st.width as u64 * st.height as u64, total);
                SlotTexture::read(layout, slot, geom, geom, &keep, "albedo", |g, _| {
                    PathTexel {
                        kd: kd[slot],
                        chart: c.texel(g),
                    }
                })
            })
            .collect::<Result<_>>()?;
        Ok(AlbedoTextures { slots })
    }

    /// The same albedo everywhere.
    pub fn uniform(
        layout: &Layout,
        charts: &Charts,
        geom: &TileStore<TexelGeom>,
        kd: Vec3,
        scratch: &Scratch,
    ) -> Result<Self> {
        Self::uniform_per_slot(layout, charts, geom, &vec![kd; layout.slots.len()], scratch)
    }

    /// `K_d` of every slot assembled from `state` (`TexelState::k_d` of covered texels; the
    /// textures together within `scratch`'s budget, the temporaries of one slot each within
    /// it too), the gutter filled by `dilate_passes` passes of [`dilate`](crate::atlas::texture::dilate)
    /// (use the atlas padding or more).
    pub fn read(
        layout: &Layout,
        charts: &Charts,
        state: &TileStore<TexelState>,
        geom: &TileStore<TexelGeom>,
        dilate_passes: u32,
        scratch: &Scratch,
    ) -> Result<Self> {
        let mut out = Vec::with_capacity(layout.slots.len());
        let total: u64 = layout
            .slots
            .iter()
            .map(|s| s.width as u64 * s.height as u64)
            .sum();
        for (slot, st) in layout.slots.iter().enumerate() {
            // every slot's texture is kept through the pass: each gets its share of the budget
            let keep = scratch.share(st.width as u64 * st.height as u64, total);
            let c = &charts.slots[slot];
            let chart = SlotTexture::read(layout, slot, geom, geom, scratch, "chart", |g, _| {
                c.texel(g)
            })?;
            let mask = SlotTexture::read(layout, slot, geom, geom, scratch, "mask", |g, _| {
                (c.texel(g) != NONE) as u8
            })?;
            let kd = SlotTexture::read(layout, slot, state, geom, scratch, "kd", |s, g| {
                match c.texel(g) != NONE {
                    true => Vec3::from_array(s.k_d),
                    false => Vec3::ZERO,
                }
            })?;
            let kd = kd.dilated(&mask, dilate_passes, scratch)?;
            let tex = SlotTexture::build(chart.grid, &keep, "albedo", |t| {
                let (k, c) = (kd.tile(t)?, chart.tile(t)?);
                Ok(k.iter()
                    .zip(&c)
                    .map(|(&kd, &chart)| PathTexel { kd, chart })
                    .collect())
            })?;
            out.push(tex);
        }
        Ok(AlbedoTextures { slots: out })
    }

    /// `K_d` of `slot` at continuous texel coordinates `uv`: the texel containing `uv`,
    /// clamped to the texture.
    #[inline]
    pub fn lookup(&self, slot: usize, uv: Vec2) -> Vec3 {
        self.texel(slot, uv).0.kd
    }

    /// The texel of `slot` containing `uv` (clamped to the texture) and whether `uv` was
    /// inside the texture.
    #[inline]
    pub fn texel(&self, slot: usize, uv: Vec2) -> (PathTexel, bool) {
        let t = &self.slots[slot];
        let (w, h) = (t.grid.width, t.grid.height);
        let (fx, fy) = (uv.x.floor(), uv.y.floor());
        let inside = fx >= 0.0 && fy >= 0.0 && fx < w as f32 && fy < h as f32;
        let x = (fx as i64).clamp(0, w as i64 - 1) as u32;
        let y = (fy as i64).clamp(0, h as i64 - 1) as u32;
        (t.get(x, y), inside)
    }

    /// The first read error of lookups since the last check (textures held in tiles).
    pub fn check(&self) -> Result<()> {
        self.slots.iter().try_for_each(|t| t.check())
    }
}

/// Everything a photon pass reads. Borrowed, immutable and `Sync`.
#[derive(Clone, Copy)]
pub struct PassContext<'a> {
    pub scene: &'a Scene,
    pub accel: &'a Accel,
    pub sampler: &'a EmitterSampler,
    pub layout: &'a Layout,
    /// Per scene shape, its atlas (`corner_uv` maps hits to texels).
    pub atlases: &'a [Option<ShapeAtlas>],
    pub charts: &'a Charts,
    /// Per BVH primitive, what a hit on it means (slot, chart, normals, atlas coordinates).
    pub hits: &'a HitTable,
    pub albedo: &'a AlbedoTextures,
    pub seed: u64,
    /// Solver iteration: part of every photon's random key.
    pub iteration: u64,
    /// Photons in the whole pass (`N`; each carries `1/N` of its emitted flux).
    pub photons: u64,
    /// Photons per batch; the last batch may be partial.
    pub batch_size: u32,
    /// Most diffuse bounces per path (0 = nothing is deposited).
    pub max_depth: u32,
    /// Which light paths deposit (a solver pass: [`Paths::Indirect`]).
    pub paths: Paths,
    /// Tiles per mapped window of the state store.
    pub window: usize,
    /// Batches traced before their deposits are added (bounds memory; the checkpoint
    /// granularity). 0 = `max(16, 2 x threads)`. Never changes the result.
    pub group_batches: usize,
}

/// The light paths a pass deposits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Paths {
    /// Light that met at least one reconstructed (diffuse) surface on its way: `E_i`, which
    /// depends on the current `K_d`.
    Indirect,
    /// Light that reached a reconstructed surface by way of mirrors and glass alone
    /// (caustics): independent of every `K_d`, so traced once and added to `E_d`.
    Caustic,
}

impl<'a> PassContext<'a> {
    /// The photon pass of iteration `iteration` as `cfg` sets it (seed, photons, batch size,
    /// depth, tile window), over `p`'s scene with the given emitter sampler, charts and
    /// current albedo.
    pub fn new(
        p: &'a RunContext,
        cfg: &Config,
        (sampler, charts, hits, albedo): (
            &'a EmitterSampler,
            &'a Charts,
            &'a HitTable,
            &'a AlbedoTextures,
        ),
        iteration: u64,
    ) -> PassContext<'a> {
        PassContext {
            scene: &p.scene,
            accel: &p.accel,
            sampler,
            layout: &p.layout,
            atlases: &p.atlases,
            charts,
            hits,
            albedo,
            seed: cfg.seed,
            iteration,
            photons: cfg.photons,
            batch_size: cfg.batch_size,
            max_depth: cfg.max_depth,
            paths: Paths::Indirect,
            // the albedo textures hold the other half of the budget through the pass
            window: p.window::<TexelState>(cfg),
            group_batches: 0,
        }
    }

    /// Number of batches in the pass.
    pub fn batch_count(&self) -> u64 {
        self.photons.div_ceil(self.batch_size.max(1) as u64)
    }

    /// Photons in the first `batches` batches.
    pub fn photons_in(&self, batches: u64) -> u64 {
        batches
            .saturating_mul(self.batch_size as u64)
            .min(self.photons)
    }

    /// Photons in batch `b` (the last one may be partial; 0 past the end).
    pub fn batch_len(&self, b: u64) -> u64 {
        let bs = self.batch_size as u64;
        self.photons.saturating_sub(b.saturating_mul(bs)).min(bs)
    }

    fn check(&self, state: &TileStore<TexelState>, first_batch: u64) -> Result<()> {
        let bad = |m: String| Err(Error::internal(format!("photon pass: {m}")));
        if self.batch_size == 0 {
            return bad("batch_size must be > 0".into());
        }
        if self.window == 0 {
            return bad("window of 0 tiles".into());
        }
        if state.tile_count() != self.layout.tile_count as usize
            || state.tile_texels() != self.layout.tile_texels()
        {
            return bad(format!(
                "state store has {} tiles of {} texels, the layout {} of {}",
                state.tile_count(),
                state.tile_texels(),
                self.layout.tile_count,
                self.layout.tile_texels()
            ));
        }
        if self.albedo.slots.len() != self.layout.slots.len()
            || self.charts.slots.len() != self.layout.slots.len()
            || self.charts.slot_of_shape.len() != self.scene.shapes.len()
        {
            return bad("albedo textures or charts do not match the layout".into());
        }
        for st in &self.layout.slots {
            if self
                .atlases
                .get(st.shape)
                .and_then(|a| a.as_ref())
                .is_none()
            {
                return bad(format!("shape {} has no atlas", st.shape));
            }
        }
        if first_batch > self.batch_count() {
            return bad(format!(
                "first batch {first_batch} is past the last ({} batches)",
                self.batch_count()
            ));
        }
        Ok(())
    }
}

/// One photon hit's contribution: flux (scene power units, already divided by `N`) into
/// texel `offset` of tile `tile`. Plain bytes, so batches travel between processes as they are.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Deposit {
    pub tile: u32,
    pub offset: u32,
    pub flux: [f32; 3],
}

/// What a call of [`photon_pass`] did (this call only, not earlier parts of a resumed pass).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct PassStats {
    pub batches: u64,
    pub photons: u64,
    /// Closest-hit rays cast.
    pub rays: u64,
    /// Hits deposited into covered texels (by this process, when several share the pass).
    pub deposits: u64,
    /// Hits after a bounce that landed in an uncovered texel (or another chart's) and were
    /// dropped, as the bin areas require.
    pub dropped: u64,
    pub seconds: f64,
}

/// Sets `accum` of every texel to zero: call before batch 0 of a pass (not on resume).
pub fn begin_pass(state: &mut TileStore<TexelState>, window: usize) -> Result<()> {
    state.for_each_tile_mut(window, |_, recs| {
        recs.iter_mut().for_each(|r| r.accum = [0.0; 3])
    })
}

/// Traces batches `first_batch..` of the pass and adds their flux to `TexelState::accum`.
///
/// Batches run in groups of `ctx.group_batches`, in parallel on the current rayon pool;
/// after each group's deposits are added, `on_group(batches_done)` is called (batches
/// `0..batches_done` are then in `accum`: a checkpoint may save the state and resume later
/// with `first_batch = batches_done`). An error from `on_group` stops the pass. The caller
/// zeroes `accum` before batch 0 ([`begin_pass`]) and converts it to irradiance after the
/// last ([`finish_pass`]).
pub fn photon_pass(
    ctx: &PassContext,
    state: &mut TileStore<TexelState>,
    first_batch: u64,
    mut on_group: impl FnMut(u64) -> Result<()>,
) -> Result<PassStats> {
    let mut own = |traced: Vec<(u64, Traced)>| Ok(traced.into_iter().map(|t| t.1).collect());
    let on_group = |done, _: &mut TileStore<TexelState>| on_group(done);
    photon_pass_shared(ctx, state, first_batch, &|_| true, &mut own, on_group)
}

/// One batch's deposits (in photon order) and counters.
pub type Traced = (Vec<Deposit>, PathCounts);

/// [`photon_pass`] shared by several processes: this one traces the batches of each group
/// that `owns` accepts, and `share` turns them (with their batch numbers, in order) into the
/// group's batches in batch order that this process adds: every batch, or each with only the
/// deposits in the tiles this process keeps current (the caller then makes the other tiles
/// current before it reads or saves them: `on_group` gets the store). The groups must be the
/// same on every process (set `ctx.group_batches`).
pub fn photon_pass_shared(
    ctx: &PassContext,
    state: &mut TileStore<TexelState>,
    first_batch: u64,
    owns: &(dyn Fn(u64) -> bool + Sync),
    share: &mut dyn FnMut(Vec<(u64, Traced)>) -> Result<Vec<Traced>>,
    mut on_group: impl FnMut(u64, &mut TileStore<TexelState>) -> Result<()>,
) -> Result<PassStats> {
    ctx.check(state, first_batch)?;
    let t0 = Instant::now();
    let batches = ctx.batch_count();
    let group = match ctx.group_batches {
        0 => (2 * rayon::current_num_threads()).max(16),
        g => g,
    } as u64;
    let mut stats = PassStats::default();
    let mut b = first_batch;
    while b < batches {
        let end = (b + group).min(batches);
        let mine: Vec<u64> = (b..end).filter(|&i| owns(i)).collect();
        let traced = mine
            .into_par_iter()
            .map(|i| (i, trace_batch(ctx, i)))
            .collect();
        let outs = share(traced)?;
        for (d, c) in &outs {
            stats.rays += c.rays;
            stats.deposits += d.len() as u64;
            stats.dropped += c.dropped;
        }
        stats.photons += (b..end).map(|i| ctx.batch_len(i)).sum::<u64>();
        stats.batches += end - b;
        add_deposits(&outs, state, ctx.window)?;
        on_group(end, state)?;
        b = end;
    }
    stats.seconds = t0.elapsed().as_secs_f64();
    Ok(stats)
}

/// All photons of batch `b`, their deposits in photon order.
pub fn trace_batch(ctx: &PassContext, b: u64) -> (Vec<Deposit>, PathCounts) {
    let n = ctx.batch_len(b);
    let mut out = Vec::with_capacity(n as usize * 2);
    let mut counts = PathCounts::default();
    for i in 0..n {
        counts += trace_photon(ctx, b, i, &mut out);
    }
    (out, counts)
}

/// Bins a group's deposits by tile (a stable counting sort: batch order, then photon order,
/// within each tile) and adds them to `accum`, one tile per task. Public for the tile
/// accumulation benchmark (`benches/tiles.rs`).
#[doc(hidden)]
pub fn add_deposits(
    outs: &[(Vec<Deposit>, PathCounts)],
    state: &mut TileStore<TexelState>,
    window: usize,
) -> Result<()> {
    let tiles = state.tile_count();
    let mut start = vec![0usize; tiles + 1];
    for d in outs.iter().flat_map(|o| &o.0) {
        start[d.tile as usize + 1] += 1;
    }
    for i in 0..tiles {
        start[i + 1] += start[i];
    }
    let mut next = start.clone();
    let mut sorted = vec![(0u32, [0.0f32; 3]); start[tiles]];
    for d in outs.iter().flat_map(|o| &o.0) {
        let at = &mut next[d.tile as usize];
        sorted[*at] = (d.offset, d.flux);
        *at += 1;
    }
    state.for_each_tile_mut(window, |t, recs| {
        for &(off, f) in &sorted[start[t]..start[t + 1]] {
            let a = &mut recs[off as usize].accum;
            a[0] += f[0];
            a[1] += f[1];
            a[2] += f[2];
        }
    })
}

/// Converts one tile's summed flux into irradiance: `accum := accum / bin_area` for covered
/// texels with a positive bin, 0 elsewhere. Pure; see [`finish_pass`].
pub fn finish_tile(geom: &[TexelGeom], state: &mut [TexelState]) {
    for (g, s) in geom.iter().zip(state.iter_mut()) {
        s.accum = if g.covered() && g.bin_area > 0.0 {
            let inv = 1.0 / g.bin_area;
            s.accum.map(|a| a * inv)
        } else {
            [0.0; 3]
        };
    }
}

/// [`finish_tile`] over every tile: after it, `TexelState::accum` is the traced `E_i`.
pub fn finish_pass(
    geom: &TileStore<TexelGeom>,
    state: &mut TileStore<TexelState>,
    window: usize,
) -> Result<()> {
    if geom.tile_count() != state.tile_count() || geom.tile_texels() != state.tile_texels() {
        return Err(Error::internal(format!(
            "finish_pass: geometry store has {} tiles of {}, state {} of {}",
            geom.tile_count(),
            geom.tile_texels(),
            state.tile_count(),
            state.tile_texels()
        )));
    }
    map_tiles(state, geom, window, |_, g, recs| finish_tile(g, recs))?;
    Ok(())
}
