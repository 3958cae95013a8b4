//! Projection of the photos onto the atlas (method step 2, eq. 1): for every texel a camera
//! sees, a weighted mean of the photo's radiance, `L_orig = sum w_i L_i / sum w_i`, then a few
//! refinement passes that make the map agree with every photo at once.
//!
//! Per view we first classify the photo's pixels with primary rays, one through every pixel
//! corner and one through every center (see [`View`]): a pixel is *clean* when its corners all
//! land on the plane of the shape hit at its center (so it straddles no silhouette, depth
//! edge or crease), no emitter lies within a pixel of it, and its value is valid. A texel is
//! then observed through k x k sub-samples of its footprint (k grows with texel size / pixel
//! footprint, so a texel much larger than a pixel gets an area average, not a point sample).
//! Each sub-sample must be front-facing and land on clean pixels that see its plane (a clean
//! pixel sees nothing else, so the sub-sample is unoccluded: the projection casts no rays of
//! its own); it reads the photo bilinearly, or the nearest pixel at the edge of a clean
//! region. Tiles whose texels a view cannot see (outside its frustum) are skipped, so a view
//! costs its pixels and the texels in front of it. The weight
//! `w = (accepted fraction) * A_texel / A_pixel` counts how many pixels' worth of measurement
//! the texel received, so it accounts for distance, viewing angle and pixel footprint together.
//! With `fine_geometry`, a texel no view sees cleanly is read from pixels that see one surface of its shape
//! (`one_surface`, weight x0.1), else from the pixel its center falls in if a ray shows it
//! visible (`visible`, weight x0.01): fine geometry is observed, not filled.
//!
//! **Why refinement.** The weighted mean is a blurred estimate of the surface radiance, and
//! differently blurred in each view: the bilinear lookup adds a one-pixel tent to each pixel's
//! box footprint, the map's own texels (area means, read back bilinearly) add their size, and a
//! view seeing the surface at a grazing angle or from afar averages many texels per pixel, which
//! the mean mixes into the sharper views' detail. Re-rendered, such a map agrees with no photo
//! exactly: on cbox-tex (textured walls and ceiling, 128 texels per unit) its 8x8-block means
//! differ from the photos by 1-2%, by about 1% even with a single view projected and
//! re-rendered into itself, and as much with noise-free synthetic photos of the true textures,
//! so neither noise nor lighting is the cause. [`refine`] runs iterative back-projection
//! (SIRT): render every view from the current map, back-project the residual
//! `photo - render` with the same lookups and weights, add `sum w_i r_i / sum w_i`, clamp at
//! zero. Each pass moves the map towards the least-squares solution of "render(map) =
//! photo in every view": detail that some view resolves is restored, averaging stays where
//! views agree. Residuals are shrunk first where their 7 x 7-pixel neighbourhood holds no more
//! than the photo's noise ([`shrink_residual`], James-Stein over the window), so the passes do
//! not fit each photo's noise into the map, yet pass a blurred edge's residual almost whole
//! even where each of its pixels is within the noise; what noise they still fit (more at the
//! over-relaxed default step) the next stage, `denoise`, averages away where neighbouring
//! texels agree within it.
//!
//! **Views that disagree.** The passes are also a robust fusion: each view's residual at a
//! texel is judged against that view's noise there (the photo's local relative noise level,
//! as [`noise_levels`] estimates it, interpolated over the pixels the texel covers,
//! never below the view's median level: [`texel_noise_variance`]) plus a [`MODEL_FLOOR`] for
//! differences that are expected; a view more than [`DISAGREE_Z`] such deviations away (a
//! specular highlight, a misregistered pixel, something that moved) is down-weighted
//! ([`robust_weight`]) and, in the last pass, counted (`TexelState::disagree`, the
//! `maps/<shape>_disagreement` map). The last pass's residuals also give the variance of the
//! fused luminance ([`fused_variance`]: the photo noise through the weights, or the views'
//! scatter where larger), from which `confidence` makes the standard error of `K_d`; its
//! photo-noise part is then measured by running the projection again on perturbed photos
//! ([`noise_probe`]).
//!
//! **Where the poses are refined.** With `[views] refine_pose`, the views are first built
//! with the scene's cameras, each camera's pose is refined against the other views' projection
//! ([`pose`]: photometric alignment, coarse to fine, at most 2 degrees and 2% of the viewing
//! distance), and the views are built again from the refined cameras (their pixels classified
//! by rays from there) before the weighted mean and the refinement passes, which then see only
//! the refined poses; so do the noise probe and, through `report.json`, the outputs.

mod coat;
mod diagnose;
mod edges;
pub mod exposure;
pub mod keep;
mod lookups;
mod noise;
pub mod noise_probe;
mod one_surface;
pub mod pass_texel;
pub mod pose;
mod refine;
mod shrinkage;
pub mod total_variation;
mod view;
mod visible;
mod window_median;

pub use diagnose::notes as capture_notes;
pub use lookups::{Lookups, TileLookups, ViewHits};
pub use refine::{Refine, REFINE_SUPERSAMPLE};
pub use shrinkage::{noise_levels, shrink_residual, shrink_residual_levels, NoiseLevels};
pub use view::{classify_pixels, Pair, PixelInfo, Rays, Value, View};

use crate::atlas::context::HitTable;
use crate::atlas::store::{flags, TexelGeom, TexelState};
use crate::atlas::store::{map_tiles, TileStore};
use crate::atlas::texture::Scratch;
use crate::atlas::uv::Charts;
use crate::atlas::{read_photos as read_photos_checked, RunContext, ShapeRef};
use crate::base::error::Result;
use crate::base::interrupt;
use crate::base::progress::{note, Mode, Stage};
use crate::config::Config;
use crate::image::Image;
use crate::physics::camera::Camera;
use crate::report::PoseCorrection;
use crate::scene::{luminance, Sides};
use glam::Vec3;
use pass_texel::{PassRecord, PassTexel};
use std::path::Path;
use std::time::Instant;

/// The largest sub-sample grid per texel and view (k x k).
pub const MAX_SUBSAMPLES: u32 = 8;
/// Sub-samples per pixel side a texel covers.
const SUBSAMPLES_PER_PIXEL: f32 = 1.0;
/// Texels seen more grazing than this cosine are not used.
pub const MIN_COS: f32 = 0.05;

/// Statistics of the projection stage.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct ProjectionStats {
    pub views: usize,
    pub masked_pixels: usize,
    pub covered_texels: u64,
    pub observed_texels: u64,
    /// Covered texels some view could see (in its frame, facing it, unoccluded).
    pub visible_texels: u64,
    /// The whole stage, the noise probe included.
    pub seconds: f64,
    /// The noise probe's part of it (0 when off).
    pub probe_seconds: f64,
    /// The photos' calibration's part of it (gains, poses).
    pub calibration_seconds: f64,
    /// Per refinement pass, each view's mean relative residual `|photo - render| / photo`
    /// over its clean pixels before the pass's update (pass 0: the weighted mean's; see
    /// [`refine::mean_relative_residual`]).
    pub refine_residual: Vec<Vec<f64>>,
    /// Per view, its pose as refined against the others ([`pose`]; empty when
    /// `refine_pose` is off).
    pub pose: Vec<PoseCorrection>,
    /// The pose refinement's part of `seconds` (0 when off).
    pub pose_seconds: f64,
    /// Per view, its photo's gain and what fixed it.
    pub gains: Vec<crate::report::ViewCapture>,
    /// Bytes of the views' look-ups the refinement kept ([`Lookups`]).
    pub lookup_bytes: u64,
}

/// How the stage is shared with the other processes of a run (decided by `pipeline`): this
/// process computes the work units `owns` accepts (tiles, and bands of [`ROW_BAND`] rows of a
/// re-rendered view), `sync` makes every tile of the state current after a step that changed
/// it, `sync_pixels` makes an image computed in units of `n` consecutive pixels whole, `sum`
/// adds a count over the processes; so every process goes on from the same state.
/// `sync_bytes` makes a buffer computed in units of `n` consecutive bytes whole (a view's
/// primary rays, [`View::new_shared`]), unit `u` by the process that owns `u`; `alone` says
/// no other process shares the work (nothing to sync). [`Shard::whole`]: one process.
pub struct Shard<'a> {
    pub owns: &'a (dyn Fn(usize) -> bool + Sync),
    pub sync: &'a dyn Fn(&mut TileStore<TexelState>) -> Result<()>,
    /// [`Shard::sync`] for the refinement passes' working store.
    pub sync_pass: &'a dyn Fn(&mut TileStore<PassTexel>) -> Result<()>,
    pub sync_pixels: &'a SyncPixels<'a>,
    pub sync_bytes: &'a SyncBytes<'a>,
    pub sum: &'a dyn Fn(u64) -> u64,
    pub alone: bool,
}

/// See [`Shard::sync_pixels`].
pub type SyncPixels<'a> = dyn Fn(&mut [Option<Vec3>], usize) -> Result<()> + 'a;

/// See [`Shard::sync_bytes`].
pub type SyncBytes<'a> = dyn Fn(&mut [u8], usize) -> Result<()> + 'a;

/// Rows of a re-rendered view per work unit (see [`Shard`]).
pub const ROW_BAND: u32 = 8;

impl Shard<'static> {
    /// Everything here, nothing elsewhere.
    pub fn whole() -> Self {
        fn every(_: usize) -> bool {
            true
        }
        fn tiles(_: &mut TileStore<TexelState>) -> Result<()> {
            Ok(())
        }
        fn pass_tiles(_: &mut TileStore<PassTexel>) -> Result<()> {
            Ok(())
        }
        fn pixels(_: &mut [Option<Vec3>], _: usize) -> Result<()> {
            Ok(())
        }
        fn bytes(_: &mut [u8], _: usize) -> Result<()> {
            Ok(())
        }
        fn alone(v: u64) -> u64 {
            v
        }
        Shard {
            owns: &every,
            sync: &tiles,
            sync_pass: &pass_tiles,
            sync_pixels: &pixels,
            sync_bytes: &bytes,
            sum: &alone,
            alone: true,
        }
    }
}

/// The stage: project every photo onto the atlas into `state` (L_orig, weight, OBSERVED),
/// then refine (`cfg.refine_passes`). Each view's rays are cast once; the photos and their
/// classification stay in memory through the refinement passes, which cast no rays where a
/// pixel lies flat on one chart.
pub fn run(
    p: &RunContext,
    cfg: &Config,
    lookups: (&HitTable, &Charts),
    geom: &TileStore<TexelGeom>,
    state: &mut TileStore<TexelState>,
    mode: Mode,
    scratch: &Scratch,
) -> Result<ProjectionStats> {
    run_shard(
        p,
        cfg,
        lookups,
        geom,
        state,
        mode,
        (scratch, None),
        &Shard::whole(),
    )
}

/// [`run`] shared by several processes: only the tiles `shard` owns are projected and refined
/// here, and the store is synced after the weighted mean and after each refinement pass. With
/// `keep`, the views' classifications and corner rays are written there for the outputs'
/// re-renders, up to `memory_budget_mib` of them and what the disk can spare
/// ([`keep::allowance`]).
#[allow(clippy::too_many_arguments)]
#[inline(never)] // a stage entry tools/icount.py measures
pub fn run_shard(
    p: &RunContext,
    cfg: &Config,
    (hits, charts): (&HitTable, &Charts),
    geom: &TileStore<TexelGeom>,
    state: &mut TileStore<TexelState>,
    mode: Mode,
    (scratch, keep): (&Scratch, Option<&Path>),
    shard: &Shard,
) -> Result<ProjectionStats> {
    let mut stats = ProjectionStats {
        views: p.views.len(),
        ..Default::default()
    };
    let window = p.window::<TexelState>(cfg);
    let stage = Stage::new(mode, "projection", p.views.len() as u64, "views");
    let t0 = Instant::now();
    let raw = read_photos(p, mode)?;
    stats.masked_pixels = raw.iter().map(|ph| ph.masked).sum();
    let bounds = tile_bounds(geom)?;
    let mut nominal = Vec::with_capacity(raw.len());
    let mut keeper = keep.map(|dir| {
        let free = crate::base::fsio::free_bytes(&scratch.dir);
        let stores = geom.data_bytes() + state.data_bytes();
        keep::Keeper::new(
            dir,
            keep::allowance(cfg.memory_budget_mib << 20, free, stores),
        )
    });
    for (i, ((si, _), photo)) in p.views.iter().zip(&raw).enumerate() {
        let view = View::new_shared(
            &p.scene,
            &p.accel,
            Camera::from_sensor(&p.scene.sensors[*si]),
            photo,
            cfg.fine_geometry,
            shard,
        )?;
        if let Some(k) = &mut keeper {
            k.offer(i, &view);
        }
        nominal.push(view);
        stage.inc(1);
        interrupt::check(interrupt::NOTHING_SAVED)?;
    }
    let ids: Vec<String> = (p.views.iter())
        .map(|(si, _)| p.scene.sensors[*si].id.clone())
        .collect();
    let t = Instant::now();
    stats.gains = exposure::estimate(p, cfg, &nominal, &ids, geom)?;
    stats.calibration_seconds = t.elapsed().as_secs_f64();
    let photos: Vec<Image> = (raw.iter().zip(&stats.gains))
        .map(|(ph, g)| exposure::apply(ph, g.gain))
        .collect();
    let mut photos = coat::remove(p, &photos, &nominal, cfg.seed).unwrap_or(photos);
    let views: Vec<View> = (nominal.iter().zip(&photos))
        .map(|(v, ph)| v.with_image(ph))
        .collect();
    drop(nominal);
    drop(raw);
    let cameras: Vec<Camera> = views.iter().map(|v| v.camera.clone()).collect();
    let ground = refine::Ground {
        p,
        hits,
        charts,
        geom,
        bounds: &bounds,
        window,
        scratch,
        shard,
    };
    let lookups = Lookups::new(
        views.len(),
        p.layout.tile_count as usize,
        lookup_budget(cfg),
    );
    let (noise, rays, passes) =
        refine_views(&ground, &views, &lookups, state, (cfg, mode), &mut stats)?;
    drop(views);
    if cfg.noise_probe && !noise.is_empty() {
        let t = Instant::now();
        let photos = (&mut photos[..], rays, &noise[..]);
        probe_noise(&ground, cfg, state, photos, (passes, &lookups), mode)?;
        stats.probe_seconds = t.elapsed().as_secs_f64();
    }
    drop(photos);
    stage.finish();
    let counts = map_tiles(state, geom, window, |t, g, st| {
        let shape = p.shape_ref(p.layout.slot_of_tile(t as u32));
        let seen = |g: &TexelGeom| (cameras.iter()).any(|c| visible::sees(c, &p.accel, &shape, g));
        let c = g.iter().filter(|g| g.covered()).count() as u64;
        let o = st.iter().filter(|s| s.flags & flags::OBSERVED != 0).count() as u64;
        let v = match (shard.owns)(t) {
            true => g.iter().filter(|g| g.covered() && seen(g)).count() as u64,
            false => 0,
        };
        (c, o, v)
    })?;
    let (c, o, v) = (counts.iter()).fold((0, 0, 0), |(a, b, d), (c, o, v)| (a + c, b + o, d + v));
    stats.covered_texels = c;
    stats.observed_texels = o;
    stats.visible_texels = (shard.sum)(v);
    stats.seconds = t0.elapsed().as_secs_f64();
    Ok(stats)
}

/// Bytes the refinement may keep of its look-ups ([`Lookups`]): a quarter of the memory
/// budget.
fn lookup_budget(cfg: &Config) -> u64 {
    (cfg.memory_budget_mib << 20) / 4
}

/// The views' poses refined (`refine_pose`), then the weighted mean and the refinement passes
/// into `state`, their figures into `stats`. Returns the views' noise as the last pass
/// estimated it, the rays of the views the passes read (at the refined poses) and the passes
/// they took (what the noise probe repeats).
fn refine_views(
    ground: &refine::Ground,
    views: &[View],
    lookups: &Lookups,
    state: &mut TileStore<TexelState>,
    (cfg, mode): (&Config, Mode),
    stats: &mut ProjectionStats,
) -> Result<(Vec<noise_probe::ViewNoise>, Vec<Rays>, refine::Passes)> {
    let none = Lookups::new(0, 0, 0);
    let ctx = ground.refine(views, "refinement", &none);
    let posed;
    let ctx = match cfg.refine_pose {
        true => {
            let t = Instant::now();
            let (refined, poses) = pose::refine(&ctx, mode)?;
            for c in &poses {
                note(mode, &c.summary());
            }
            (stats.pose, stats.pose_seconds) = (poses, t.elapsed().as_secs_f64());
            posed = refined;
            refine::Refine {
                views: &posed,
                ..ctx
            }
        }
        false => ctx,
    };
    let ctx = refine::Refine { lookups, ..ctx };
    let passes = refine::Passes::of(cfg);
    let (noise, residual) = project_and_refine(&ctx, state, passes, mode, cfg.fine_geometry)?;
    // the probe measures the passes these photos took, settled or not
    let passes = passes.exactly(residual.len() as u32);
    stats.refine_residual = residual;
    stats.lookup_bytes = lookups.bytes();
    for (g, n) in stats.gains.iter_mut().zip(&noise) {
        g.check = n.check.clone();
    }
    Ok((noise, ctx.views.iter().map(View::rays).collect(), passes))
}

/// The noise probe (see [`noise_probe`]): the photos perturbed in place by their own noise,
/// projected and refined again with the views' `rays` into a scratch store, and the
/// difference made each texel's photo noise. The perturbation leaves what a photo masks as
/// it was, so the probe's views classify their pixels as the views did and share their
/// look-ups. A function of its own so the instruction-count guard (`tools/icount.py`) can
/// find it.
#[inline(never)]
fn probe_noise(
    ground: &refine::Ground,
    cfg: &Config,
    state: &mut TileStore<TexelState>,
    (photos, rays, noise): (&mut [Image], Vec<Rays>, &[noise_probe::ViewNoise]),
    (passes, lookups): (refine::Passes, &Lookups),
    mode: Mode,
) -> Result<()> {
    let p = ground.p;
    for (i, (ph, n)) in photos.iter_mut().zip(noise).enumerate() {
        noise_probe::perturb(ph, n, cfg.seed, i as u64);
    }
    let views: Vec<View> = (rays.into_iter().zip(photos.iter()))
        .map(|(r, ph)| r.with_image(ph))
        .collect();
    let path = ground.scratch.dir.join("probe-state.tiles");
    let mut probe_state = p.create_store(&path, TexelState::default())?;
    let ctx = ground.refine(&views, "noise probe", lookups);
    project_and_refine(&ctx, &mut probe_state, passes, mode, cfg.fine_geometry)?;
    noise_probe::apply(
        &p.layout,
        ground.charts,
        ground.geom,
        state,
        &mut probe_state,
        ground.window,
        ground.scratch,
    )?;
    drop(probe_state);
    std::fs::remove_file(&path).map_err(|e| crate::base::error::Error::io(&path, e))
}

/// The weighted mean of every view of `ctx` into `state` (L_orig, weight, OBSERVED; synced),
/// then (with `fine_geometry`) the texels no clean pixel saw from the others
/// ([`project_tile`]), then the refinement passes; returns the views' noise as the last pass estimated it and
/// the passes' residuals (see [`refine::Refine::run`]).
fn project_and_refine(
    ctx: &refine::Refine,
    state: &mut TileStore<TexelState>,
    passes: refine::Passes,
    mode: Mode,
    fine_geometry: bool,
) -> Result<(Vec<noise_probe::ViewNoise>, Vec<Vec<f64>>)> {
    let (p, shard, bounds) = (ctx.p, ctx.shard, ctx.bounds);
    let rounds: &[bool] = match fine_geometry {
        true => &[false, true],
        false => &[false],
    };
    for &loose in rounds {
        for view in ctx.views {
            map_tiles(state, ctx.geom, ctx.window, |t, g, st| {
                let seen = bounds[t].is_some_and(|(lo, hi)| view.camera.may_see(lo, hi));
                if !(shard.owns)(t) || !seen {
                    return;
                }
                let slot = p.layout.slot_of_tile(t as u32);
                project_tile(view, &p.accel, &p.shape_ref(slot), g, st, loose);
            })?;
            interrupt::check(interrupt::NOTHING_SAVED)?;
        }
        state.for_each_tile_mut(ctx.window, |_, st| finish_tile(st))?;
    }
    (shard.sync)(state)?;
    ctx.run(state, passes, mode)
}

/// Every view's photo: as `prepare` decoded and checked it, else read again (checked the
/// same way).
fn read_photos(p: &RunContext, mode: Mode) -> Result<Vec<Image>> {
    let taken: Option<Vec<Image>> = (0..p.views.len()).map(|i| p.take_photo(i)).collect();
    match taken {
        Some(photos) => Ok(photos),
        None => {
            p.release_photos();
            read_photos_checked(&p.scene, &p.views, &p.response, mode)
        }
    }
}

/// Per tile, the bounding box of its covered texels' squares (`None` if it has none): what a
/// view must see for the tile to be worth projecting.
pub fn tile_bounds(geom: &TileStore<TexelGeom>) -> Result<Vec<Option<(Vec3, Vec3)>>> {
    (0..geom.tile_count())
        .map(|t| {
            let g = geom.read_tile(t)?;
            Ok(g.iter().filter(|g| g.covered()).fold(None, |b, g| {
                // a texel's square reaches at most about its diagonal from its center
                let r = Vec3::splat(2.0 * g.area.sqrt());
                let (lo, hi) = (g.p() - r, g.p() + r);
                Some(match b {
                    None => (lo, hi),
                    Some((a, b)) => (lo.min(a), hi.max(b)),
                })
            }))
        })
        .collect()
}

/// Observe one texel in one view: `(mean radiance, weight)`, or `None` if the view does not
/// see it usefully. Its `k x k` sub-samples (k grows with the texel's footprint in pixels) are
/// read where they land on clean pixels that see their plane (so unoccluded: no rays).
pub fn observe_texel(view: &View, shape: &ShapeRef, g: &TexelGeom) -> Option<(Vec3, f32)> {
    observe_texel_from(view, shape, g, &|x, y| view.image.get(x, y))
}

/// [`observe_texel`] reading pixel values from `get` (see [`View::sample_from`]).
pub fn observe_texel_from<T: Value>(
    view: &View,
    shape: &ShapeRef,
    g: &TexelGeom,
    get: &dyn Fn(u32, u32) -> T,
) -> Option<(T, f32)> {
    let ng = g.ng();
    observe_with(view, shape, g, |pix, q| {
        view.sample_from(pix, q, shape.index, ng, get)
    })
}

/// [`observe_texel`] from the pixels that see one surface of the texel's shape, planar or not
/// ([`View::sample_loose`]), its weight [`one_surface::LOOSE_WEIGHT`] of a clean one's: for a
/// texel no clean pixel of the view sees.
pub fn observe_texel_loose(view: &View, shape: &ShapeRef, g: &TexelGeom) -> Option<(Vec3, f32)> {
    let (l, w) = observe_with(view, shape, g, |pix, q| {
        view.sample_loose(pix, q, shape.index)
    })?;
    Some((l, w * one_surface::LOOSE_WEIGHT))
}

/// A texel's center as the pixel it projects into shows it, when the view sees that center
/// ([`visible::sees`]: a ray), whatever else the pixel holds; weight
/// [`one_surface::LOOSE_WEIGHT`] squared of a clean pixel's.
pub fn observe_texel_seen(
    view: &View,
    accel: &crate::physics::accel::Accel,
    shape: &ShapeRef,
    g: &TexelGeom,
) -> Option<(Vec3, f32)> {
    if !visible::sees(&view.camera, accel, shape, g) {
        return None;
    }
    let pix = view.camera.project(g.p())?;
    let (x, y) = (pix.x as u32, pix.y as u32);
    if !view.usable(x, y) {
        return None;
    }
    let a_pix = view.camera.pixel_footprint_area(g.p(), g.ng());
    let ratio = (g.area / a_pix).min(1.0);
    let w = ratio * one_surface::LOOSE_WEIGHT * one_surface::LOOSE_WEIGHT;
    (w.is_finite() && w > 0.0).then(|| (view.image.get(x, y), w))
}

/// One texel in one view through `sample` (a projected point's value, if the view sees it):
/// `(mean value, weight)` of its sub-samples (see [`observe_texel`]).
#[inline(always)] // generic, not `dyn`: the clean path's sampling inlines as before
fn observe_with<T: Value>(
    view: &View,
    shape: &ShapeRef,
    g: &TexelGeom,
    mut sample: impl FnMut(glam::Vec2, Vec3) -> Option<T>,
) -> Option<(T, f32)> {
    let cam = view.camera.position();
    let p = g.p();
    let n = g.n();
    let ng = g.ng();
    let to_cam = cam - p;
    let dist = to_cam.length();
    if dist <= 0.0 {
        return None;
    }
    let cos = n.dot(to_cam) / dist;
    let facing = match shape.sides {
        Sides::Front => cos,
        Sides::Both => cos.abs(),
    };
    if facing < MIN_COS {
        return None;
    }
    let a_pix = view.camera.pixel_footprint_area(p, ng);
    if !(a_pix.is_finite() && a_pix > 0.0) {
        return None;
    }
    let ratio = g.area / a_pix;
    let (dx, dy) = shape.texel_edges(g.tri as usize);
    // Sub-samples per side: about one per pixel the texel covers. (Per-axis counts from the
    // projected texel edges do no better than this area rule.)
    let k = ((ratio.sqrt() * SUBSAMPLES_PER_PIXEL).ceil() as u32).clamp(1, MAX_SUBSAMPLES);
    let mut sum = T::default();
    let mut accepted = 0u32;
    for j in 0..k {
        for i in 0..k {
            let ox = (i as f32 + 0.5) / k as f32 - 0.5;
            let oy = (j as f32 + 0.5) / k as f32 - 0.5;
            let q = if k == 1 { p } else { p + dx * ox + dy * oy };
            let Some(pix) = view.camera.project(q) else {
                continue;
            };
            if let Some(l) = sample(pix, q) {
                sum += l;
                accepted += 1;
            }
        }
    }
    if accepted == 0 {
        return None;
    }
    let frac = accepted as f32 / (k * k) as f32;
    Some((sum / accepted as f32, frac * ratio))
}

/// Accumulate one view into one tile: `state.l_orig += w L`, `state.weight += w`, from clean
/// pixels; with `loose`, only into texels no view saw cleanly ([`finish_tile`] has not flagged
/// them), from pixels that see one surface of its shape ([`observe_texel_loose`]), else, if
/// the view sees its center at all, from the pixel there ([`observe_texel_seen`]): a shape of
/// a few pixels takes what it gets, at a low weight.
pub fn project_tile(
    view: &View,
    accel: &crate::physics::accel::Accel,
    shape: &ShapeRef,
    geom: &[TexelGeom],
    state: &mut [TexelState],
    loose: bool,
) {
    for (g, s) in geom.iter().zip(state.iter_mut()) {
        if !g.covered() || (loose && s.flags & flags::OBSERVED != 0) {
            continue;
        }
        let seen = match loose {
            false => observe_texel(view, shape, g),
            true => observe_texel_loose(view, shape, g)
                .or_else(|| observe_texel_seen(view, accel, shape, g)),
        };
        if let Some((l, w)) = seen {
            for c in 0..3 {
                s.l_orig[c] += w * l[c];
            }
            s.weight += w;
        }
    }
}

/// After all views: turn the weighted sums into means and flag observed texels (those
/// flagged already are done).
pub fn finish_tile(state: &mut [TexelState]) {
    for s in state.iter_mut().filter(|s| s.flags & flags::OBSERVED == 0) {
        if s.weight > 0.0 {
            for c in 0..3 {
                s.l_orig[c] /= s.weight;
            }
            s.flags |= flags::OBSERVED;
        } else {
            s.l_orig = [0.0; 3];
        }
    }
}

/// Disagreement threshold of the robust fusion, in standard deviations of a view's value for
/// a texel: a view further than this from the current estimate is down-weighted by
/// `(c / z)^4` and counted as disagreeing.
pub const DISAGREE_Z: f32 = 3.0;
/// Relative spread between views that is not noise but expected (pixel footprints, filtering,
/// registration to a fraction of a pixel, texture detail one view resolves and another
/// blurs): added to a view's noise before judging it. 0.25: at 0.05-0.15 detail that differs
/// between views is taken for disagreement and textured walls lose detail.
pub const MODEL_FLOOR: f32 = 0.25;

/// Per texel, one refinement pass's residuals summed over the views (per tile, while the tile
/// is updated).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Residual {
    /// `sum_v h_v w_v r_v`: the back-projected residuals, robust-weighted.
    pub d: [f32; 3],
    /// `sum_v h_v w_v y_v^2`, `y_v` the luminance of the raw (unshrunk) residual.
    pub wr2: f32,
    /// `sum_v w_v^2 var_v`, `var_v` the predicted noise variance of view `v`'s value.
    pub w2var: f32,
    /// Views that saw the texel.
    pub views: f32,
    /// Views that disagreed (`z > DISAGREE_Z`).
    pub out: f32,
    /// `sum_v h_v w_v`: the robust-weighted total weight.
    pub hw: f32,
    /// `sum_v h_v w_v k_v`, `k_v` the shrinkage's keep factor at the texel in view `v`
    /// ([`noise_levels`]): `hwk / hw` is the share of the texel's residual that is
    /// signal, what the gate of [`apply_refinement`] reads.
    pub hwk: f32,
}

/// Predicted noise variance of the luminance of one view's value for a texel: the photo's
/// relative per-pixel noise `sigma` at luminance `l`, averaged over the `w` pixels' worth the
/// texel covers (a texel smaller than a pixel gets one pixel's noise).
pub fn view_variance(sigma: f32, l: f32, w: f32) -> f32 {
    (sigma * l).powi(2) / w.max(1.0)
}

/// The weight of a view whose value lies `z` standard deviations from the estimate: 1 within
/// [`DISAGREE_Z`], `(DISAGREE_Z / z)^4` beyond. It falls off much faster than Huber's `c / z`,
/// because the estimate it is judged against still holds the outlier: with three views, one
/// of them 4x too bright, Huber's weight leaves the texel 66% off after the refinement's
/// passes, this one outvotes it (see the projection tests).
pub fn robust_weight(z: f32) -> f32 {
    if z > DISAGREE_Z {
        (DISAGREE_Z / z).powi(4)
    } else {
        1.0
    }
}

/// The noise variance of one view's luminance `l` at a texel it observes with weight `w`:
/// the photo's relative noise where the texel's pixels are (`level`, interpolated like the
/// residual) or the view's `sigma` if that is larger. The view's level alone (its median)
/// understates dim, noisy regions (cbox-tex's short box: 5-7% per pixel against 1-2% on the
/// back wall), and judged by it the sigma filter would average too few texels there.
pub fn texel_noise_variance(level: f32, sigma: f32, l: f32, w: f32) -> f32 {
    view_variance(level.max(sigma), l, w)
}

/// The residual of one view for back-projection, per pixel of its photo
/// ([`ResidualPixel`]); with the view (its camera and pixel classification) and the photo's
/// relative noise `sigma` (its median level; each pixel carries the local level).
pub struct ResidualViews<'a> {
    pub view: &'a View<'a>,
    pub residual: &'a [ResidualPixel],
    pub sigma: f32,
}

/// One pixel's residual as it is kept for back-projection: raw (`photo - render`, judged
/// against the noise), the photo's relative noise level there and the shrinkage's keep factor
/// ([`shrink_residual`]). The shrunk residual (what is added) is `raw * keep`, to the bit, so
/// it is not kept: [`ResidualPixel::pair`] makes it as a pixel is read.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ResidualPixel {
    pub raw: Vec3,
    pub level: f32,
    pub keep: f32,
}

impl ResidualPixel {
    /// Raw and shrunk residual as one [`Pair`] with the level and keep factor, so a texel's
    /// sub-samples are looked up once for all four.
    #[inline(always)]
    pub fn pair(self) -> Pair {
        Pair(self.raw, self.raw * self.keep, self.level, self.keep)
    }
}

/// Back-project one view's residual into one tile: per texel the view observes, `d += h w r`
/// (`w` the projection's weight, `r` the shrunk residual, `h` the robust weight
/// ([`robust_weight`]) of the raw residual against the view's noise plus [`MODEL_FLOOR`] at the
/// current `l_orig`), and the statistics of [`Residual`].
pub fn backproject_tile<T: PassRecord>(
    rv: &ResidualViews,
    looks: &TileLookups,
    state: &[T],
    acc: &mut [Residual],
) -> Agreement {
    let mut seen = Agreement::default();
    let width = rv.view.camera.width();
    let at = |i: usize| rv.residual[i].pair();
    for (i, Pair(raw, r, level, keep), w) in looks.read(width, at) {
        let (s, a) = (&state[i], &mut acc[i]);
        let l = luminance(Vec3::from_array(s.l_orig())).max(0.0);
        let var = texel_noise_variance(level, rv.sigma, l, w);
        let y = luminance(raw);
        let spread = (var + (MODEL_FLOOR * l).powi(2)).sqrt();
        let z = if spread > 0.0 { y.abs() / spread } else { 0.0 };
        let h = robust_weight(z);
        for c in 0..3 {
            a.d[c] += h * w * r[c];
        }
        a.hw += h * w;
        a.hwk += h * w * keep;
        a.wr2 += h * w * y * y;
        a.w2var += w * w * var;
        a.views += 1.0;
        a.out += (z > DISAGREE_Z) as u32 as f32;
        seen.texels += 1;
        seen.disagreeing += (z > DISAGREE_Z) as u64;
    }
    seen
}

/// How many texels a view saw in a pass, and at how many it disagreed with the estimate by
/// more than [`DISAGREE_Z`] of its noise and the expected spread.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Agreement {
    pub texels: u64,
    pub disagreeing: u64,
}

/// The variance of a fused luminance from one pass's [`Residual`] and the total weight:
/// the photo noise propagated through the weights (`sum w^2 var / W^2`), or where two or more
/// views saw the texel and scatter more than that, their weighted scatter about the estimate
/// (`sum h w y^2 / ((n - 1) W)`, the variance of a weighted mean).
pub fn fused_variance(a: &Residual, weight: f32) -> f32 {
    if weight <= 0.0 {
        return 0.0;
    }
    let noise = photo_variance(a, weight);
    let scatter = if a.views >= 2.0 {
        a.wr2 / ((a.views - 1.0) * weight)
    } else {
        0.0
    };
    noise.max(scatter)
}

/// The variance of a fused luminance from the photos' noise alone: `sum w^2 var / W^2` (0 for
/// no weight).
pub fn photo_variance(a: &Residual, weight: f32) -> f32 {
    if weight <= 0.0 {
        return 0.0;
    }
    a.w2var / (weight * weight)
}

/// A texel's luminance change in a pass that counts as a move ([`Moved`]): 1%.
pub const MOVED_BY: f32 = 0.01;

/// How many texels a refinement pass updated, and how many of them it changed by more than
/// [`MOVED_BY`] of their luminance (what the passes' settling reads).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Moved {
    pub updated: u64,
    pub changed: u64,
}

/// After a pass over all views: `l_orig += step * d / hw` (the weighted mean of the views'
/// residuals, robust-weighted: an iteratively reweighted least-squares step towards the robust
/// estimate; where every view agrees `hw` is `weight`), clamped at zero; after the last pass
/// (`stats`) also the texel's `l_var`, `l_noise` and `disagree`. `step` over-relaxes the passes where
/// every view agrees with the estimate within its noise (steps below 2 converge, as in
/// SIRT); where a view is being outvoted the step stays 1, since an over-relaxed reweighting
/// overshoots (at 1.8 the highlight test's texels end 14% off with the step everywhere, 6.0%
/// without it where a view is outvoted, 4.5% at step 1).
///
/// With `gate > 0`, a texel whose views agree and whose residuals are mostly noise (the mean
/// keep factor of the shrinkage, `hwk / hw`, under `gate`) keeps its value: the passes stop
/// where the photos hold nothing more to fit, texel by texel, and go on where unresolved detail
/// remains (see [`crate::config::REFINE_GATE`]). A texel where a view is being outvoted is not
/// gated, so the reweighting runs its course. The statistics are updated either way.
pub fn apply_refinement<T: PassRecord>(
    state: &mut [T],
    acc: &[Residual],
    stats: bool,
    step: f32,
    gate: f32,
) -> Moved {
    let mut moved = Moved::default();
    for (s, a) in state.iter_mut().zip(acc) {
        if s.weight() > 0.0 && a.hw > 0.0 {
            let quiet = gate > 0.0 && a.hwk < gate * a.hw;
            let k = if a.out > 0.0 {
                1.0
            } else if quiet {
                0.0
            } else {
                step
            };
            let mut l = s.l_orig();
            let before = luminance(Vec3::from_array(l));
            for (l, d) in l.iter_mut().zip(a.d) {
                *l = (*l + k * d / a.hw).max(0.0);
            }
            s.set_l_orig(l);
            let change = (luminance(Vec3::from_array(l)) - before).abs();
            moved.updated += 1;
            moved.changed += (change > MOVED_BY * before) as u64;
            if stats {
                s.set_stats(a);
            }
        }
    }
    moved
}

#[cfg(test)]
mod tests {
    use super::*;

    fn acc(d: Vec3, hw: f32) -> Residual {
        Residual {
            d: d.to_array(),
            hw,
            ..Default::default()
        }
    }

    #[test]
    fn refinement_adds_the_weighted_mean_residual_and_clamps_at_zero() {
        let mut st = [TexelState::default(); 3];
        st[0].l_orig = [1.0, 1.0, 1.0];
        st[0].weight = 2.0;
        st[1].l_orig = [0.1, 0.1, 0.1];
        st[1].weight = 1.0;
        let d = [
            acc(Vec3::new(1.0, -1.0, 0.0), 2.0),
            acc(Vec3::splat(-0.5), 1.0),
            acc(Vec3::splat(5.0), 0.0),
        ];
        apply_refinement(&mut st, &d, false, 1.0, 0.0);
        assert_eq!(st[0].l_orig, [1.5, 0.5, 1.0]);
        assert_eq!(st[1].l_orig, [0.0; 3]);
        assert_eq!(st[2].l_orig, [0.0; 3], "unobserved texels stay as they are");
        // a down-weighted view: the step is the mean over the weight left, 1.0 / 0.5
        let mut st = [TexelState {
            weight: 2.0,
            ..Default::default()
        }];
        apply_refinement(&mut st, &[acc(Vec3::ONE, 0.5)], false, 1.0, 0.0);
        assert_eq!(st[0].l_orig, [2.0; 3]);
        // an over-relaxed step goes `step` times as far
        let mut st = [TexelState {
            weight: 2.0,
            l_orig: [1.0; 3],
            ..Default::default()
        }];
        apply_refinement(
            &mut st,
            &[acc(Vec3::new(1.0, -0.5, 0.0), 2.0)],
            false,
            1.8,
            0.0,
        );
        assert_eq!(st[0].l_orig, [1.9, 0.55, 1.0]);
        // but not where a view disagrees
        let mut st = [TexelState {
            weight: 2.0,
            l_orig: [1.0; 3],
            ..Default::default()
        }];
        let outvoted = Residual {
            out: 1.0,
            ..acc(Vec3::new(1.0, -0.5, 0.0), 2.0)
        };
        apply_refinement(&mut st, &[outvoted], false, 1.8, 0.0);
        assert_eq!(st[0].l_orig, [1.5, 0.75, 1.0]);
    }

    /// The passes' working record takes the state's own update, bit for bit: every field of
    /// a state updated directly equals the one updated through a [`PassTexel`] written back,
    /// statistics, clamps, the gate and outvoted texels included.
    #[test]
    fn the_working_record_takes_the_state_update_bit_for_bit() {
        let states: Vec<TexelState> = (0..6)
            .map(|i| TexelState {
                weight: if i == 5 { 0.0 } else { 1.0 + i as f32 },
                l_orig: [0.3 * i as f32, 1.0, 2.0 - 0.1 * i as f32],
                k_d: [0.5; 3],
                l_var: 0.7,
                ..Default::default()
            })
            .collect();
        let accs: Vec<Residual> = (0..6)
            .map(|i| Residual {
                hwk: i as f32 * 0.4,
                out: (i % 3 == 0) as u32 as f32,
                views: 2.0,
                w2var: 0.1 * i as f32,
                wr2: 0.2,
                ..acc(Vec3::new(0.3, -2.0, 0.1 * i as f32), 1.0 + i as f32 * 0.5)
            })
            .collect();
        for (stats, step, gate) in [(false, 1.0, 0.0), (true, 1.8, 0.7)] {
            let mut direct = states.clone();
            apply_refinement(&mut direct, &accs, stats, step, gate);
            let mut work: Vec<PassTexel> = states.iter().map(PassTexel::of).collect();
            apply_refinement(&mut work, &accs, stats, step, gate);
            let mut back = states.clone();
            for (s, w) in back.iter_mut().zip(&work) {
                w.write_back(s);
            }
            assert_eq!(direct, back);
            assert_ne!(direct, states, "the update changed texels");
        }
    }

    /// The gate: a texel whose residual is mostly noise (mean keep `hwk / hw` under the gate)
    /// keeps its value, one with more signal takes the step, an outvoted one the step 1; the
    /// last pass's statistics are written either way; gate 0 is no gate.
    #[test]
    fn the_gate_holds_texels_whose_residual_is_noise() {
        let texel = || TexelState {
            weight: 2.0,
            l_orig: [1.0; 3],
            ..Default::default()
        };
        let with_keep = |keep: f32, out: f32| Residual {
            hwk: keep * 2.0,
            out,
            views: 2.0,
            w2var: 0.4,
            ..acc(Vec3::new(1.0, -0.5, 0.0), 2.0)
        };
        let run = |a: Residual, gate: f32| {
            let mut st = [texel()];
            apply_refinement(&mut st, &[a], true, 1.8, gate);
            st[0]
        };
        let held = run(with_keep(0.3, 0.0), 0.7);
        assert_eq!(held.l_orig, [1.0; 3], "noise: held");
        assert_eq!(held.l_noise, 0.1, "statistics still written");
        assert_eq!(run(with_keep(0.8, 0.0), 0.7).l_orig, [1.9, 0.55, 1.0]);
        assert_eq!(run(with_keep(0.3, 1.0), 0.7).l_orig, [1.5, 0.75, 1.0]);
        assert_eq!(run(with_keep(0.0, 0.0), 0.0).l_orig, [1.9, 0.55, 1.0]);
    }

    /// A texel's noise is the local level where that is above the view's, never below.
    #[test]
    fn texel_noise_follows_the_local_level_above_the_views() {
        let (l, w) = (2.0f32, 4.0f32);
        let v = texel_noise_variance(0.05, 0.01, l, w);
        assert!((v - (0.05f32 * 2.0).powi(2) / 4.0).abs() < 1e-8, "{v}");
        assert_eq!(
            texel_noise_variance(0.002, 0.01, l, w),
            view_variance(0.01, l, w)
        );
        assert_eq!(
            texel_noise_variance(0.0, 0.0, l, w),
            0.0,
            "noise-free photos"
        );
    }

    #[test]
    fn view_weight_is_one_within_c_and_falls_as_z_to_the_minus_4_beyond() {
        assert_eq!(robust_weight(0.0), 1.0);
        assert_eq!(robust_weight(DISAGREE_Z), 1.0);
        assert!((robust_weight(2.0 * DISAGREE_Z) - 1.0 / 16.0).abs() < 1e-6);
    }

    /// Closed forms: n views of equal weight w and per-pixel noise sigma give a fused
    /// variance of (sigma l)^2 / (n w) (w >= 1); views that scatter more than their noise give
    /// the variance of a weighted mean, sum w y^2 / ((n - 1) W).
    #[test]
    fn fused_variance_is_the_propagated_noise_or_the_scatter_of_the_views() {
        let (sigma, l, w, n) = (0.1f32, 2.0f32, 4.0f32, 3.0f32);
        let var = view_variance(sigma, l, w);
        assert!((var - 0.01).abs() < 1e-7, "{var}");
        let quiet = Residual {
            w2var: n * w * w * var,
            views: n,
            ..Default::default()
        };
        let expect = (sigma * l).powi(2) / (n * w);
        assert!((fused_variance(&quiet, n * w) - expect).abs() < 1e-7);
        // residuals +-0.3 in luminance: scatter (3 * 4 * 0.09) / (2 * 12) = 0.045
        let loud = Residual {
            wr2: n * w * 0.09,
            ..quiet
        };
        assert!((fused_variance(&loud, n * w) - 0.045).abs() < 1e-6);
        assert_eq!(
            view_variance(sigma, l, 0.25),
            (sigma * l).powi(2),
            "one pixel's noise"
        );
    }
}
