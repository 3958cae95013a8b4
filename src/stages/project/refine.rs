//! Iterative back-projection (SIRT) after the weighted mean: re-render every view from the
//! current maps, back-project the residuals `photo - render` with the projection's own lookups
//! and weights, add their weighted mean (see the module notes of [`super`]).

use super::diagnose;
use super::noise_probe::ViewNoise;
use super::pass_texel::{self, PassRecord, PassTexel};
use super::shrinkage::relative;
use super::total_variation::tv_luminance;
use super::view::View;
use super::{
    apply_refinement, backproject_tile, noise_levels, Agreement, Lookups, Moved, Residual,
    ResidualPixel, ResidualViews, Shard, TileLookups, ViewHits, ROW_BAND,
};
use crate::atlas::context::HitTable;
use crate::atlas::store::TileStore;
use crate::atlas::store::{TexelGeom, TexelState};
use crate::atlas::texture::{Scratch, SlotTexture};
use crate::atlas::uv::Charts;
use crate::atlas::RunContext;
use crate::base::error::{Error, Result};
use crate::base::progress::{note, Mode, Stage};
use crate::physics::film_filter::render_filtered;
use crate::physics::render::{render_view_with, sub_hits, Film, Plan, Texture};
use glam::Vec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

/// Sub-pixel rays per side when a view is re-rendered for refinement (pixel means, then the
/// film's filter over them).
pub const REFINE_SUPERSAMPLE: u32 = 4;
/// Texels of dilation around observed texels before re-rendering, as for written maps.
const REFINE_DILATE: u32 = 4;

/// Every reconstructed shape's current luminance map (unobserved and gutter texels filled by
/// dilation, as written maps are), indexed by shape; together within `scratch`'s budget
/// (each its share), the rest in tiles.
pub(super) fn current_maps<T: PassRecord>(
    p: &RunContext,
    state: &TileStore<T>,
    scratch: &Scratch,
) -> Result<Vec<Option<SlotTexture<Vec3>>>> {
    let mut maps: Vec<Option<SlotTexture<Vec3>>> =
        (0..p.scene.shapes.len()).map(|_| None).collect();
    let total: u64 = p
        .layout
        .slots
        .iter()
        .map(|s| s.width as u64 * s.height as u64)
        .sum();
    for (slot, st) in p.layout.slots.iter().enumerate() {
        let from = (&p.layout, slot, state);
        let vals = SlotTexture::read_store(from, scratch, "lum", |s| Vec3::from_array(s.l_orig()))?;
        let mask = SlotTexture::read_store(from, scratch, "obs", |s| (s.weight() > 0.0) as u8)?;
        let keep = scratch.share(st.width as u64 * st.height as u64, total);
        maps[st.shape] = Some(vals.dilated(&mask, REFINE_DILATE, &keep)?);
    }
    Ok(maps)
}

/// How far a view's render is from its photo: the mean of `|sum_c r| / sum_c photo` (`r` =
/// `photo - render`, the shrinkage's [`relative`] residual) over the clean pixels with light
/// that have a render, 0 where there are none. What the passes drive down: the weighted mean's
/// blur, then what the maps cannot explain (the photos' noise, texture finer than the atlas or
/// the views resolve).
pub fn mean_relative_residual(
    residual: &[Vec3],
    render: &[Option<Vec3>],
    photo: &[Vec3],
    pixels: &[crate::stages::project::PixelInfo],
) -> f64 {
    let (mut sum, mut n) = (0.0f64, 0u64);
    for (e, re) in relative(residual, photo, pixels).zip(render) {
        if let (Some(e), Some(_)) = (e, re) {
            sum += e.abs() as f64;
            n += 1;
        }
    }
    if n == 0 {
        0.0
    } else {
        sum / n as f64
    }
}

/// What the refinement passes do (from the config's `[projection]`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Passes {
    /// How many.
    pub count: u32,
    /// The step after the first ([`Passes::step`]).
    pub step: f32,
    /// The TV step's weight (0 = none).
    pub tv: f32,
    /// The gate of [`apply_refinement`] (0 = none) ...
    pub gate: f32,
    /// ... from this pass on (from 0).
    pub gated_from: u32,
    /// The settling threshold ([`Passes::settled`]; 0 = every pass).
    pub settle: f32,
}

impl Passes {
    /// The passes a config asks for.
    pub fn of(cfg: &crate::config::Config) -> Passes {
        Passes {
            count: cfg.refine_passes,
            step: cfg.refine_step,
            tv: cfg.tv_weight,
            gate: cfg.refine_gate,
            gated_from: cfg.refine_gated_from,
            settle: cfg.refine_settle,
        }
    }

    /// These passes, `count` of them and no settling: what the noise probe runs, the passes
    /// the projection of the photos ran.
    pub fn exactly(self, count: u32) -> Passes {
        Passes {
            count,
            settle: 0.0,
            ..self
        }
    }

    /// Whether the passes have settled with pass `pass` (from 0), which `moved` texels: it
    /// was gated and changed under `settle` of the texels it updated by more than
    /// [`super::MOVED_BY`] of their luminance. The next pass is then the last.
    fn settled(&self, moved: Moved, pass: u32) -> bool {
        self.settle > 0.0
            && pass >= self.gated_from
            && moved.updated > 0
            && (moved.changed as f64) < self.settle as f64 * moved.updated as f64
    }

    /// The step of pass `pass` (from 0): 1 in the first, whose robust weights are judged
    /// against the plain weighted mean (a view with a highlight is still in it), `step` after.
    /// Over-relaxing the first pass too leaves the highlight test's texels 6.0% off instead of
    /// 4.7% (three passes; 4.5% over four).
    fn step(&self, pass: u32) -> f32 {
        if pass == 0 {
            1.0
        } else {
            self.step
        }
    }

    /// The gate of pass `pass` (from 0): 0 before `gated_from`.
    fn gate(&self, pass: u32) -> f32 {
        if pass >= self.gated_from {
            self.gate
        } else {
            0.0
        }
    }
}

/// What every [`Refine`] of a projection reads besides its views, label and look-ups.
#[derive(Clone, Copy)]
pub struct Ground<'a> {
    pub p: &'a RunContext,
    pub hits: &'a HitTable,
    pub charts: &'a Charts,
    pub geom: &'a TileStore<TexelGeom>,
    pub bounds: &'a [Option<(Vec3, Vec3)>],
    pub window: usize,
    pub scratch: &'a Scratch,
    pub shard: &'a Shard<'a>,
}

impl<'a> Ground<'a> {
    /// The refinement of `views`, its progress named `label`, its look-ups kept in `lookups`.
    pub fn refine<'v>(
        &self,
        views: &'v [View<'v>],
        label: &'static str,
        lookups: &'v Lookups,
    ) -> Refine<'v>
    where
        'a: 'v,
    {
        Refine {
            p: self.p,
            hits: self.hits,
            charts: self.charts,
            geom: self.geom,
            views,
            bounds: self.bounds,
            window: self.window,
            scratch: self.scratch,
            shard: self.shard,
            label,
            lookups,
        }
    }
}

/// Iterative back-projection after the weighted mean, over views prepared once.
pub struct Refine<'a> {
    pub p: &'a RunContext,
    pub hits: &'a HitTable,
    /// Each texel's chart (for the TV step).
    pub charts: &'a Charts,
    pub geom: &'a TileStore<TexelGeom>,
    /// Every view, its photo and pixel classification.
    pub views: &'a [View<'a>],
    /// Per tile, the bounds of its texels (see [`super::tile_bounds`]).
    pub bounds: &'a [Option<(Vec3, Vec3)>],
    pub window: usize,
    /// Where the maps live, and their memory.
    pub scratch: &'a Scratch,
    /// The tiles refined here, and how the others' reach this process after each pass.
    pub shard: &'a Shard<'a>,
    /// The progress stage's name.
    pub label: &'static str,
    /// Each view's look-ups per tile, kept across the passes (and shared with the noise
    /// probe, whose views are these with other photos).
    pub lookups: &'a Lookups,
}

impl Refine<'_> {
    /// `passes.count` times: re-render every view from the current maps, back-project the
    /// residuals `photo - render` (clean pixels only) and add `step` times their weighted
    /// mean to `l_orig` (1 times in the first pass, [`Passes::step`]; none where the pass's
    /// gate finds only noise, [`apply_refinement`]) (see the module notes). Every pass is
    /// robust (a view that departs from the estimate by
    /// more than its noise is down-weighted, see [`backproject_tile`]: from the first pass on,
    /// as it takes the default passes to outvote a highlight), and the last one's
    /// residuals give each texel's `l_var` and `disagree`. With `tv > 0` each pass ends with
    /// the TV step of [`tv_luminance`] at `tv` times the views' mean relative noise. The maps
    /// and the residuals live in scratch textures and tiles within the memory budget; casts
    /// rays only for clean pixels that straddle a chart seam. Returns each view's noise as
    /// the last pass estimated it (none without passes), and per pass each view's
    /// [`mean_relative_residual`] before the pass's update. The passes run on a working store
    /// of [`PassTexel`]s (see [`super::pass_texel`]), written back into `state` after the last.
    #[inline(never)] // a stage entry tools/icount.py measures
    pub fn run(
        &self,
        state: &mut TileStore<TexelState>,
        passes: Passes,
        mode: Mode,
    ) -> Result<(Vec<ViewNoise>, Vec<Vec<f64>>)> {
        if passes.count == 0 || self.views.is_empty() {
            return Ok((Vec::new(), Vec::new()));
        }
        let name = format!("passes-{}.tiles", self.label.replace(' ', "-"));
        let path = self.scratch.dir.join(name);
        let mut work = self.p.create_store(&path, PassTexel::default())?;
        let done = pass_texel::copy_in(&mut work, state, self.window)
            .and_then(|_| self.passes(&mut work, passes, mode))
            .and_then(|out| pass_texel::copy_back(state, &work, self.window).map(|_| out));
        drop(work);
        let removed = std::fs::remove_file(&path).map_err(|e| Error::io(&path, e));
        done.and_then(|out| removed.map(|_| out))
    }

    /// [`Refine::run`]'s passes on its working store `state`.
    fn passes(
        &self,
        state: &mut TileStore<PassTexel>,
        passes: Passes,
        mode: Mode,
    ) -> Result<(Vec<ViewNoise>, Vec<Vec<f64>>)> {
        let mut noise = Vec::new();
        let mut residuals = Vec::new();
        let (mut count, tv) = (passes.count, passes.tv);
        let total = count as u64 * self.views.len() as u64;
        let stage = Stage::new(mode, self.label, total, "views");
        let mut pass = 0;
        while pass < count {
            let maps = current_maps(self.p, state, self.scratch)?;
            let textures = self.textures(&maps);
            let last = pass + 1 == count;
            let renders = self.render_all(&textures, &stage)?;
            for m in maps.iter().flatten() {
                m.check()?;
            }
            drop(textures);
            drop(maps);
            // each render dropped once its residual is made
            let prepared: Vec<Prepared> = (self.views.par_iter().zip(renders))
                .map(|(view, render)| prepare(view, render, last))
                .collect();
            let (step, gate) = (passes.step(pass), passes.gate(pass));
            let (seen, moved) = self.backproject_and_apply(&prepared, state, (last, step, gate))?;
            (self.shard.sync_pass)(state)?;
            residuals.push(prepared.iter().map(|v| v.mean).collect());
            noise = self.noise(prepared, seen);
            if tv > 0.0 {
                let sigma = noise.iter().fold(0.0, |s, n| s + n.sigma);
                let rel = tv * sigma / self.views.len() as f32;
                tv_luminance(
                    &self.p.layout,
                    self.charts,
                    self.geom,
                    state,
                    rel,
                    self.scratch,
                )?;
            }
            if !last && passes.settled(moved, pass) {
                count = pass + 2;
                note(
                    mode,
                    &format!(
                        "{}: settled, {count} of at most {} passes (pass {pass} changed {} of \
                         {} texels by more than {}%)",
                        self.label,
                        passes.count,
                        moved.changed,
                        moved.updated,
                        100.0 * super::MOVED_BY
                    ),
                );
            }
            pass += 1;
        }
        stage.finish();
        Ok((noise, residuals))
    }

    /// Every view rendered from the current maps (`textures`), one after the other (each
    /// render is parallel over its rows, and a shared run syncs each as a whole).
    fn render_all(
        &self,
        textures: &[Option<Texture>],
        stage: &Stage,
    ) -> Result<Vec<Vec<Option<Vec3>>>> {
        let mut renders = Vec::with_capacity(self.views.len());
        for (vi, view) in self.views.iter().enumerate() {
            renders.push(self.render((vi, view), textures)?);
            stage.inc(1);
            crate::base::interrupt::check(crate::base::interrupt::NOTHING_SAVED)?;
        }
        Ok(renders)
    }

    /// One view rendered from the current maps, through its film's filter, at the pixels
    /// that are clean or within the filter's reach of a clean one (`None` elsewhere); pixels
    /// that do not lie flat on one chart from their sub-pixel hits, found in the first pass
    /// and kept ([`Lookups::with_hits`]).
    fn render(
        &self,
        (vi, view): (usize, &View),
        textures: &[Option<Texture>],
    ) -> Result<Vec<Option<Vec3>>> {
        let p = self.p;
        let w = view.image.width;
        // A blurring film needs the neighbours of clean pixels within its reach too.
        let filter = view.camera.filter();
        let needed = view.near_clean(filter.reach());
        let owns = self.shard.owns;
        let wanted = |x: u32, y: u32| needed[(y * w + x) as usize] && owns((y / ROW_BAND) as usize);
        let k = REFINE_SUPERSAMPLE;
        let traced = |x: u32, y: u32| wanted(x, y) && view.flat(self.hits, x, y).is_none();
        let parts = (&p.accel, &view.camera, textures);
        let size = (w, view.image.height);
        let find = || {
            ViewHits::find(size, (k * k) as usize, &traced, &|x, y| {
                sub_hits(parts, k, (x, y))
            })
        };
        self.lookups.with_hits(vi, find, |hits| {
            let plan = |x: u32, y: u32| {
                if !wanted(x, y) {
                    return Plan::Skip;
                }
                match view.flat(self.hits, x, y) {
                    Some(f) => Plan::Flat(f),
                    None => (hits.and_then(|h| h.get((y * w + x) as usize)))
                        .map_or(Plan::Trace, Plan::Hits),
                }
            };
            // The photo is the scene seen through the film's filter: so is what it is compared with.
            match filter.is_box() {
                true => {
                    let mut r = render_view_with(
                        &p.accel,
                        &view.camera,
                        textures,
                        k,
                        Film::HitsOnly,
                        &plan,
                    );
                    (self.shard.sync_pixels)(&mut r, (ROW_BAND * w) as usize)?;
                    Ok(r)
                }
                false => {
                    render_filtered(parts, k, filter, &plan, (self.shard.sync_pixels, ROW_BAND))
                }
            }
        })
    }

    /// Every view's residual (`prepared`, in view order) back-projected into each tile and
    /// the tile's texels updated at once ([`apply_refinement`] with `(stats, step, gate)`),
    /// tile by tile: each texel sums its views in view order, as one view after the other
    /// would, and no tile of residuals is stored. Each view's residual is judged against the
    /// tile's state before the update. Returns per view the texels it saw and at how many it
    /// disagreed, summed over the processes.
    fn backproject_and_apply(
        &self,
        prepared: &[Prepared],
        state: &mut TileStore<PassTexel>,
        (stats, step, gate): (bool, f32, f32),
    ) -> Result<(Vec<Agreement>, Moved)> {
        let p = self.p;
        let err: Mutex<Option<Error>> = Mutex::new(None);
        let (updated, changed) = (AtomicU64::new(0), AtomicU64::new(0));
        let counts: Vec<(AtomicU64, AtomicU64)> = (self.views.iter())
            .map(|_| (AtomicU64::new(0), AtomicU64::new(0)))
            .collect();
        state.for_each_tile_mut(self.window, |t, st| {
            let Some((lo, hi)) = self.bounds[t].filter(|_| (self.shard.owns)(t)) else {
                return;
            };
            let slot = p.layout.slot_of_tile(t as u32);
            let shape = p.shape_ref(slot);
            let mut acc = vec![Residual::default(); st.len()];
            let mut touched = false;
            for (vi, (view, rv)) in self.views.iter().zip(prepared).enumerate() {
                if !view.camera.may_see(lo, hi) {
                    continue;
                }
                let rv = ResidualViews {
                    view,
                    residual: &rv.pairs,
                    sigma: rv.sigma,
                };
                let find = || Ok(TileLookups::find(view, &shape, &self.geom.read_tile(t)?));
                let found = (self.lookups).with(vi, t, find, |looks| {
                    backproject_tile(&rv, looks, st, &mut acc)
                });
                match found {
                    Ok(a) => {
                        counts[vi].0.fetch_add(a.texels, Ordering::Relaxed);
                        counts[vi].1.fetch_add(a.disagreeing, Ordering::Relaxed);
                        touched = true;
                    }
                    Err(e) => {
                        *err.lock().unwrap_or_else(|e| e.into_inner()) = Some(e);
                        return;
                    }
                }
            }
            if touched {
                let m = apply_refinement(st, &acc, stats, step, gate);
                updated.fetch_add(m.updated, Ordering::Relaxed);
                changed.fetch_add(m.changed, Ordering::Relaxed);
            }
        })?;
        if let Some(e) = err.into_inner().unwrap_or_else(|e| e.into_inner()) {
            return Err(e);
        }
        let sum = self.shard.sum;
        let agree = counts
            .into_iter()
            .map(|(a, b)| Agreement {
                texels: sum(a.into_inner()),
                disagreeing: sum(b.into_inner()),
            })
            .collect();
        let moved = Moved {
            updated: sum(updated.into_inner()),
            changed: sum(changed.into_inner()),
        };
        Ok((agree, moved))
    }

    /// Each view's noise as this pass estimated it (its relative level; in the `last` pass
    /// also its residual's local roughness per pixel and its check against its render, with
    /// `seen` its texels and disagreements).
    fn noise(&self, prepared: Vec<Prepared>, seen: Vec<Agreement>) -> Vec<ViewNoise> {
        let all = prepared.into_iter().zip(seen);
        all.map(|(v, a)| ViewNoise {
            sigma: v.sigma,
            level: v.rough,
            check: (v.check).map(|c| diagnose::with_agreement(c, (a.texels, a.disagreeing))),
        })
        .collect()
    }

    /// The maps as textures by shape.
    pub(super) fn textures<'m>(
        &'m self,
        maps: &'m [Option<SlotTexture<Vec3>>],
    ) -> Vec<Option<Texture<'m>>> {
        let p = self.p;
        maps.iter()
            .enumerate()
            .map(|(i, m)| {
                Some(Texture {
                    texels: m.as_ref()?,
                    corner_uv: &p.atlases[i].as_ref()?.corner_uv,
                })
            })
            .collect()
    }
}

/// One view's residual for a pass per pixel ([`ResidualPixel`]s), the photo's noise level and
/// (in the last pass) its local roughness per pixel and its check against its render (see
/// [`diagnose`]; the render itself is not kept), and the residual's
/// [`mean_relative_residual`].
struct Prepared {
    pairs: Vec<ResidualPixel>,
    sigma: f32,
    rough: Vec<f32>,
    check: Option<crate::report::ViewCheck>,
    mean: f64,
}

/// `photo - render` over a view's clean pixels (0 elsewhere), judged with the photo's noise
/// levels and the shrinkage's keep factors ([`noise_levels`]; the shrunk residual is made as
/// it is read, [`ResidualPixel::pair`]).
fn prepare(view: &View, render: Vec<Option<Vec3>>, last: bool) -> Prepared {
    let photo = view.image;
    let residual: Vec<Vec3> = (photo.pixels.iter().zip(&render).zip(view.pixels.iter()))
        .map(|((ph, r), px)| match r {
            Some(r) if px.clean => *ph - *r,
            _ => Vec3::ZERO,
        })
        .collect();
    let mean = mean_relative_residual(&residual, &render, &photo.pixels, &view.pixels);
    let w = photo.width as usize;
    let levels = noise_levels(&residual, &photo.pixels, &view.pixels, w);
    let pairs = (residual.into_iter().zip(levels.level).zip(levels.keep))
        .map(|((raw, level), keep)| ResidualPixel { raw, level, keep })
        .collect();
    Prepared {
        pairs,
        sigma: levels.sigma,
        rough: if last { levels.rough } else { Vec::new() },
        check: last.then(|| diagnose::check(photo, &render, &view.pixels)),
        mean,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stages::project::PixelInfo;

    fn px(clean: bool) -> PixelInfo {
        PixelInfo {
            shape: 0,
            normal: Vec3::Z,
            plane: 0.0,
            clean,
        }
    }

    /// The passes settle once a gated pass changed under `settle` of the texels it updated by
    /// more than 1%: not before the gate, not with nothing updated, never with `settle` 0; the
    /// probe's passes are the count the photos' took, without settling.
    #[test]
    fn passes_settle_when_a_gated_pass_moves_few_texels() {
        let passes = Passes {
            count: 16,
            step: 1.8,
            tv: 0.0,
            gate: 0.7,
            gated_from: 4,
            settle: 0.005,
        };
        let few = Moved {
            updated: 10_000,
            changed: 49,
        };
        let many = Moved { changed: 50, ..few };
        assert!(passes.settled(few, 4));
        assert!(!passes.settled(many, 4), "0.5% is not under 0.5%");
        assert!(!passes.settled(few, 3), "pass 3 was not gated");
        assert!(!passes.settled(Moved::default(), 4), "nothing updated");
        let every = Passes {
            settle: 0.0,
            ..passes
        };
        assert!(!every.settled(few, 4));
        assert_eq!(passes.exactly(5), Passes { count: 5, ..every });
    }

    /// The mean of `|sum r| / sum photo` over clean pixels with light and a render, by hand.
    #[test]
    fn mean_relative_residual_counts_clean_lit_rendered_pixels_only() {
        let photo = [
            Vec3::ONE,
            Vec3::splat(2.0),
            Vec3::ONE,
            Vec3::ZERO,
            Vec3::ONE,
        ];
        let residual = [
            Vec3::new(0.3, 0.0, 0.0),
            Vec3::new(-0.6, 0.0, 0.0),
            Vec3::splat(5.0),
            Vec3::splat(5.0),
            Vec3::splat(5.0),
        ];
        let render = [
            Some(Vec3::ONE),
            Some(Vec3::ONE),
            Some(Vec3::ONE),
            Some(Vec3::ONE),
            None,
        ];
        let pixels = [px(true), px(true), px(false), px(true), px(true)];
        // pixel 0: 0.3 / 3, pixel 1: 0.6 / 6; not clean, dark, no render: left out
        let got = mean_relative_residual(&residual, &render, &photo, &pixels);
        assert!((got - 0.1).abs() < 1e-7, "{got}");
        assert_eq!(mean_relative_residual(&[], &[], &[], &[]), 0.0, "no pixels");
    }
}
