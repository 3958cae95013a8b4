//! The one place that orders the stages. Each stage is a plain function over tiles in its own
//! module; this module only wires them: scene -> atlas -> texel samples -> projection -> ...
//! and decides where their state lives (`<out>/checkpoint/*.tiles`).

use crate::accel::Accel;
use crate::atlas::layout::{flags, Layout, TexelGeom, TexelState};
use crate::atlas::texels::{dilate, TexelMap, TexelSample, NONE};
use crate::atlas::tiles::{window_tiles_for_budget, TileStore};
use crate::atlas::unwrap::{build_atlas, AtlasSettings, ShapeAtlas};
use crate::camera::Camera;
use crate::config::Config;
use crate::error::{Error, Result};
use crate::image::{read_sensor_image, write_exr_rgb, write_png_srgb};
use crate::light::{direct_irradiance, DirectParams, EmitterSampler};

use crate::photon::{
    begin_pass, finish_pass, photon_pass, smooth_accum, AlbedoTextures, PassContext, Receivers,
};
use crate::progress::{note, Mode, Stage};
use crate::project::{finish_tile, project_tile, ShapeRef, View};
use crate::report::{Counts, IterationStats, Report};
use crate::scene::{luminance, mitsuba, Scene};
use crate::solve::{
    alpha, channel_sums, compare_update_tile, fill_unobserved, init_indirect_tile, kd_tile,
    secant_beta, ErrorSums,
};
use glam::Vec3;
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::time::Duration;
use std::time::Instant;

/// The scene with its acceleration structure, atlases and tile layout: everything fixed.
pub struct Prepared {
    pub scene: Scene,
    pub accel: Accel,
    /// Per shape: its atlas if reconstructed (emitters have none).
    pub atlases: Vec<Option<ShapeAtlas>>,
    pub layout: Layout,
    /// Sensor index -> photo path, for the sensors that have a photo.
    pub views: Vec<(usize, PathBuf)>,
}

/// Load the scene, pick the views, unwrap every reconstructed shape and lay out the tiles.
pub fn prepare(cfg: &Config, mode: Mode) -> Result<Prepared> {
    let scene = mitsuba::load(&cfg.scene)?;
    let views = match_views(&scene, cfg, mode)?;
    let accel = Accel::build(&scene);
    let settings = AtlasSettings {
        texels_per_unit: cfg.atlas.texels_per_unit,
        padding: cfg.atlas.padding,
        use_mesh_uvs: cfg.atlas.use_mesh_uvs,
        max_size: cfg.atlas.max_texture_size,
    };
    let mut atlases = Vec::with_capacity(scene.shapes.len());
    let mut textures = Vec::new();
    for (i, s) in scene.shapes.iter().enumerate() {
        if !s.is_reconstructed() {
            atlases.push(None);
            continue;
        }
        let a = build_atlas(&s.mesh, &settings).map_err(|e| match e {
            Error::Config(m) | Error::Input { msg: m, .. } => {
                Error::input(&cfg.scene, format!("shape '{}': {m}", s.id))
            }
            other => other,
        })?;
        textures.push((i, a.width, a.height));
        atlases.push(Some(a));
    }
    let layout = Layout::new(cfg.atlas.tile_size, &textures);
    Ok(Prepared {
        scene,
        accel,
        atlases,
        layout,
        views,
    })
}

/// The (sensor, photo) pairs of a run: the config's `views`, or every sensor with an
/// `images/<id>.exr` beside the scene (sensors without one are skipped with a note).
pub fn match_views(scene: &Scene, cfg: &Config, mode: Mode) -> Result<Vec<(usize, PathBuf)>> {
    let mut views = Vec::new();
    if cfg.views.is_empty() {
        let dir = scene.dir().join("images");
        for (i, s) in scene.sensors.iter().enumerate() {
            let p = dir.join(format!("{}.exr", s.id));
            if p.is_file() {
                views.push((i, p));
            } else {
                note(
                    mode,
                    &format!("sensor '{}' has no photo {}: skipped", s.id, p.display()),
                );
            }
        }
    } else {
        for (id, p) in &cfg.views {
            let i = scene
                .sensors
                .iter()
                .position(|s| &s.id == id)
                .ok_or_else(|| {
                    Error::input(
                        &cfg.scene,
                        format!("views names sensor '{id}', which the scene does not have"),
                    )
                })?;
            views.push((i, p.clone()));
        }
    }
    if views.is_empty() {
        return Err(Error::input(
            &cfg.scene,
            "no photos: no sensor has an images/<sensor id>.exr and the config names no views",
        ));
    }
    Ok(views)
}

impl Prepared {
    pub fn shape_ref(&self, slot: usize) -> ShapeRef<'_> {
        let si = self.layout.slots[slot].shape;
        let s = &self.scene.shapes[si];
        ShapeRef {
            index: si as u32,
            mesh: &s.mesh,
            sides: s.sides,
            corner_uv: &self.atlases[si]
                .as_ref()
                .expect("reconstructed shape has an atlas")
                .corner_uv,
        }
    }

    /// A new tile store at `path` shaped like this layout (every tile, every texel), each
    /// record `fill`.
    pub fn create_store<T: bytemuck::Pod + Send + Sync>(
        &self,
        path: impl AsRef<Path>,
        fill: T,
    ) -> Result<TileStore<T>> {
        TileStore::create(
            path,
            self.layout.tile_count as usize,
            self.layout.tile_texels(),
            fill,
        )
    }

    /// Tiles per mapped window for a store of `T` under the configured memory budget.
    pub fn window<T>(&self, cfg: &Config) -> usize {
        let tile_bytes = (self.layout.tile_texels() * std::mem::size_of::<T>()) as u64;
        window_tiles_for_budget(cfg.memory_budget_mib << 20, tile_bytes).max(1)
    }
}

/// Where a run keeps its tile stores.
pub fn state_dir(out: &Path) -> PathBuf {
    out.join("checkpoint")
}

/// Sub-samples per texel side used to measure a border texel's area on its chart.
const BIN_SUBSAMPLES: u32 = 8;

/// Rasterize every atlas into the geometry store (texel -> surface point), one row band of
/// tiles at a time so memory stays bounded by a band, not a texture.
pub fn build_geometry(p: &Prepared, path: &Path, mode: Mode) -> Result<TileStore<TexelGeom>> {
    let mut store = p.create_store(path, TexelGeom::default())?;
    let total: u64 = p
        .layout
        .slots
        .iter()
        .map(|s| s.width as u64 * s.height as u64)
        .sum();
    let stage = Stage::new(mode, "atlas", total, "texels");
    let ts = p.layout.tile_size;
    for st in &p.layout.slots {
        let shape = &p.scene.shapes[st.shape];
        let atlas = p.atlases[st.shape].as_ref().expect("atlas");
        let map = TexelMap::new(&shape.mesh, atlas);
        for ty in 0..st.tiles_y {
            // one band of rows, with a row of margin each side for the border test
            let y0 = (ty * ts).saturating_sub(1);
            let y1 = ((ty + 1) * ts + 1).min(st.height);
            let band = map.sample_rows(y0..y1);
            let at = |x: u32, y: u32| -> Option<&TexelSample> {
                band.get(((y - y0) * st.width + x) as usize)?.as_ref()
            };
            let geo: Vec<Vec<TexelGeom>> = (0..st.tiles_x)
                .into_par_iter()
                .map(|tx| {
                    let mut recs = vec![TexelGeom::default(); p.layout.tile_texels()];
                    for (off, r) in recs.iter_mut().enumerate() {
                        let (x, y) = (tx * ts + off as u32 % ts, ty * ts + off as u32 / ts);
                        if x >= st.width || y >= st.height {
                            continue;
                        }
                        let Some(s) = at(x, y) else { continue };
                        let interior = (-1i32..=1).all(|dy| {
                            (-1i32..=1).all(|dx| {
                                let (nx, ny) = (x as i32 + dx, y as i32 + dy);
                                nx >= 0
                                    && ny >= 0
                                    && (nx as u32) < st.width
                                    && (ny as u32) < st.height
                                    && at(nx as u32, ny as u32).is_some()
                            })
                        });
                        let bin_area = if interior {
                            s.area
                        } else {
                            map.subsamples(x, y, BIN_SUBSAMPLES)
                                .iter()
                                .map(|q| q.area)
                                .sum()
                        };
                        let ng = shape
                            .mesh
                            .face_normal_raw(s.tri as usize)
                            .normalize_or_zero();
                        *r = TexelGeom {
                            position: s.position.to_array(),
                            normal: s.normal.to_array(),
                            geo_normal: ng.to_array(),
                            area: s.area,
                            bin_area,
                            tri: s.tri,
                            flags: flags::COVERED,
                        };
                    }
                    recs
                })
                .collect();
            for (tx, recs) in geo.iter().enumerate() {
                let tile = st.first_tile + ty * st.tiles_x + tx as u32;
                store.write_tile(tile as usize, recs)?;
            }
            stage.inc(st.width as u64 * (((ty + 1) * ts).min(st.height) - ty * ts) as u64);
        }
    }
    stage.finish();
    Ok(store)
}

/// Statistics of the projection stage.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct ProjectionStats {
    pub views: usize,
    pub masked_pixels: usize,
    pub covered_texels: u64,
    pub observed_texels: u64,
    pub seconds: f64,
}

/// Project every photo onto the atlas into `state` (L_orig, weight, OBSERVED), streaming the
/// photos one at a time.
pub fn project_all(
    p: &Prepared,
    cfg: &Config,
    geom: &TileStore<TexelGeom>,
    state: &mut TileStore<TexelState>,
    mode: Mode,
) -> Result<ProjectionStats> {
    let mut stats = ProjectionStats {
        views: p.views.len(),
        ..Default::default()
    };
    let window = p.window::<TexelState>(cfg);
    let stage = Stage::new(mode, "projection", p.views.len() as u64, "views");
    let mut time = Duration::ZERO;
    for (si, path) in &p.views {
        let sensor = &p.scene.sensors[*si];
        let image = read_sensor_image(path, sensor)?;
        if image.masked > 0 {
            note(
                mode,
                &format!(
                    "{}: {} non-finite or negative pixels masked",
                    path.display(),
                    image.masked
                ),
            );
        }
        stats.masked_pixels += image.masked;
        let t0 = std::time::Instant::now();
        let view = View::new(&p.scene, &p.accel, Camera::from_sensor(sensor), &image);
        map_tiles(state, geom, window, |t, g, st| {
            let slot = p.layout.slot_of_tile(t as u32);
            project_tile(&view, &p.accel, &p.shape_ref(slot), g, st);
        })?;
        time += t0.elapsed();
        stage.inc(1);
    }
    state.for_each_tile_mut(window, |_, st| finish_tile(st))?;
    crate::project::refine(p, geom, state, window, cfg.refine_passes, mode)?;
    stage.finish();
    let counts = map_tiles(state, geom, window, |_, g, st| {
        let c = g.iter().filter(|g| g.covered()).count() as u64;
        let o = st.iter().filter(|s| s.flags & flags::OBSERVED != 0).count() as u64;
        (c, o)
    })?;
    let (c, o) = counts.iter().fold((0, 0), |(a, b), (c, o)| (a + c, b + o));
    stats.covered_texels = c;
    stats.observed_texels = o;
    stats.seconds = time.as_secs_f64();
    Ok(stats)
}

pub use crate::atlas::tiles::map_tiles;

/// The photon pass of iteration `iteration` as `cfg` sets it (seed, photons, batch size,
/// depth, tile window), over `p`'s scene with the given emitter sampler, receivers and
/// current albedo.
pub fn pass_context<'a>(
    p: &'a Prepared,
    cfg: &Config,
    (sampler, receivers, albedo): (&'a EmitterSampler, &'a Receivers, &'a AlbedoTextures),
    iteration: u64,
) -> PassContext<'a> {
    PassContext {
        scene: &p.scene,
        accel: &p.accel,
        sampler,
        layout: &p.layout,
        atlases: &p.atlases,
        receivers,
        albedo,
        seed: cfg.seed,
        iteration,
        photons: cfg.photons,
        batch_size: cfg.batch_size,
        max_depth: cfg.max_depth,
        window: p.window::<TexelState>(cfg),
        group_batches: 0,
    }
}

/// One slot's texture assembled from tiles: `(values, covered)` row-major.
pub fn gather<T: bytemuck::Pod + Send + Sync>(
    p: &Prepared,
    slot: usize,
    store: &TileStore<T>,
    geom: &TileStore<TexelGeom>,
    value: impl Fn(&T) -> Vec3,
) -> Result<(Vec<Vec3>, Vec<bool>)> {
    let st = p.layout.slots[slot];
    let n = (st.width * st.height) as usize;
    let mut vals = vec![Vec3::ZERO; n];
    let mut cov = vec![false; n];
    let ts = p.layout.tile_size;
    for ty in 0..st.tiles_y {
        for tx in 0..st.tiles_x {
            let tile = (st.first_tile + ty * st.tiles_x + tx) as usize;
            let recs = store.read_tile(tile)?;
            let g = geom.read_tile(tile)?;
            for (off, r) in recs.iter().enumerate() {
                let (x, y) = (tx * ts + off as u32 % ts, ty * ts + off as u32 / ts);
                if x < st.width && y < st.height {
                    let i = (y * st.width + x) as usize;
                    vals[i] = value(r);
                    cov[i] = g[off].covered();
                }
            }
        }
    }
    Ok((vals, cov))
}

/// Exposure (stops) that maps the 99th percentile luminance of `vals` to 0.9.
pub fn auto_exposure(vals: &[Vec3], mask: &[bool]) -> f32 {
    let mut ys: Vec<f32> = vals
        .iter()
        .zip(mask)
        .filter(|(_, &m)| m)
        .map(|(v, _)| luminance(*v))
        .filter(|y| y.is_finite() && *y > 0.0)
        .collect();
    if ys.is_empty() {
        return 0.0;
    }
    let k = ((ys.len() as f64 * 0.99) as usize).min(ys.len() - 1);
    let (_, v, _) = ys.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
    (0.9 / *v).log2()
}

/// Write a per-shape map `<dir>/<id>_<name>.exr` (gutter dilated) and, if asked, a PNG preview.
pub fn write_map(
    dir: &Path,
    id: &str,
    name: &str,
    (width, height): (u32, u32),
    mut vals: Vec<Vec3>,
    cov: &[bool],
    png: bool,
) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let exposure = auto_exposure(&vals, cov);
    dilate(&mut vals, cov, width, height, 4)?;
    write_exr_rgb(
        dir.join(format!("{id}_{name}.exr")),
        width,
        height,
        &vals,
        false,
    )?;
    if png {
        write_png_srgb(
            dir.join(format!("{id}_{name}.png")),
            width,
            height,
            &vals,
            exposure,
        )?;
    }
    Ok(())
}

/// Steps 1-2 on their own: atlas, projection, and the luminance and coverage maps in
/// `<out>/maps/`. Returns the projection statistics.
pub fn run_projection(cfg: &Config, out: &Path, mode: Mode) -> Result<(Prepared, ProjectionStats)> {
    let p = prepare(cfg, mode)?;
    let dir = state_dir(out);
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    let geom = build_geometry(&p, &dir.join("geometry.tiles"), mode)?;
    let mut state = p.create_store(dir.join("state.tiles"), TexelState::default())?;
    let stats = project_all(&p, cfg, &geom, &mut state, mode)?;
    let maps = out.join("maps");
    for slot in 0..p.layout.slots.len() {
        let st = p.layout.slots[slot];
        let id = &p.scene.shapes[st.shape].id;
        let (lum, cov) = gather(&p, slot, &state, &geom, |s| Vec3::from_array(s.l_orig))?;
        let (wt, _) = gather(&p, slot, &state, &geom, |s| Vec3::splat(s.weight))?;
        let observed: Vec<bool> = wt.iter().map(|v| v.x > 0.0).collect();
        write_map(
            &maps,
            id,
            "luminance",
            (st.width, st.height),
            lum,
            &observed,
            true,
        )?;
        write_map(&maps, id, "coverage", (st.width, st.height), wt, &cov, true)?;
    }
    Ok((p, stats))
}

/// Step 3: direct irradiance E_d of every covered texel, from every emitter, with shadows.
/// Returns the area-weighted mean E_d over covered texels (for the initial E_i).
pub fn direct_all(
    p: &Prepared,
    cfg: &Config,
    geom: &TileStore<TexelGeom>,
    state: &mut TileStore<TexelState>,
    mode: Mode,
) -> Result<Vec3> {
    let params = DirectParams {
        area_samples: cfg.area_samples,
        ..DirectParams::default()
    };
    let window = p.window::<TexelState>(cfg);
    let texels = p.layout.tile_texels() as u64;
    let stage = Stage::new(mode, "direct", state.tile_count() as u64, "tiles");
    let sums = map_tiles(state, geom, window, |t, g, st| {
        let mut sum = (Vec3::ZERO, 0.0f64);
        for (off, (g, s)) in g.iter().zip(st.iter_mut()).enumerate() {
            if !g.covered() {
                continue;
            }
            let key = (cfg.seed, t as u64 * texels + off as u64);
            let e = direct_irradiance(&p.scene, &p.accel, g.p(), g.n(), g.ng(), &params, key);
            s.e_d = e.to_array();
            sum.0 += e * g.area;
            sum.1 += g.area as f64;
        }
        stage.inc(1);
        sum
    })?;
    stage.finish();
    let (e, a) = sums
        .iter()
        .fold((Vec3::ZERO, 0.0f64), |acc, s| (acc.0 + s.0, acc.1 + s.1));
    Ok(if a > 0.0 { e / a as f32 } else { Vec3::ZERO })
}

/// Unobserved texels: K_d from observed neighbours of the same chart (else the shape's mean),
/// flagged FILLED. Works one texture at a time.
pub fn fill_unobserved_all(
    p: &Prepared,
    receivers: &Receivers,
    geom: &TileStore<TexelGeom>,
    state: &mut TileStore<TexelState>,
) -> Result<u64> {
    let mut filled_total = 0u64;
    for slot in 0..p.layout.slots.len() {
        let st = p.layout.slots[slot];
        let (mut kd, cov) = gather(p, slot, state, geom, |s| Vec3::from_array(s.k_d))?;
        let (obs, _) = gather(p, slot, state, geom, |s| {
            Vec3::splat((s.flags & flags::OBSERVED != 0) as u32 as f32)
        })?;
        let observed: Vec<bool> = obs.iter().zip(&cov).map(|(o, &c)| c && o.x > 0.0).collect();
        let chart: Vec<Option<u32>> = receivers.slots[slot]
            .texel_chart
            .iter()
            .zip(&cov)
            .map(|(&c, &cv)| (cv && c != NONE).then_some(c))
            .collect();
        let filled = fill_unobserved(&mut kd, &observed, &chart, st.width, st.height);
        let ts = p.layout.tile_size;
        for ty in 0..st.tiles_y {
            for tx in 0..st.tiles_x {
                let tile = (st.first_tile + ty * st.tiles_x + tx) as usize;
                let mut recs = state.read_tile(tile)?;
                let mut changed = false;
                for (off, r) in recs.iter_mut().enumerate() {
                    let (x, y) = (tx * ts + off as u32 % ts, ty * ts + off as u32 / ts);
                    if x < st.width && y < st.height {
                        let i = (y * st.width + x) as usize;
                        if filled[i] {
                            r.k_d = kd[i].to_array();
                            r.flags |= flags::FILLED;
                            changed = true;
                            filled_total += 1;
                        }
                    }
                }
                if changed {
                    state.write_tile(tile, &recs)?;
                }
            }
        }
    }
    Ok(filled_total)
}

/// The whole method, steps 1-9, then every output of the contract, from scratch. Returns the
/// report.
pub fn reconstruct(cfg: &Config, out: &Path, mode: Mode) -> Result<Report> {
    reconstruct_resumable(cfg, out, mode, false).map(|(r, _)| r)
}

/// How a run started (see [`reconstruct_resumable`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Start {
    /// From scratch.
    Fresh,
    /// From a checkpoint (its sequence number).
    Resumed(u64),
    /// The checkpoint says the run had finished: nothing was done, the report is the
    /// finished run's.
    AlreadyFinished,
}

/// [`reconstruct`] with checkpoints in `<out>/checkpoint` (after projection and direct light,
/// after each iteration, every `checkpoint_every_batches` photon batches) and, if `resume`,
/// continuing from the newest good checkpoint there. A resumed run's outputs are
/// bit-identical to an uninterrupted run's; a checkpoint of other inputs or settings is
/// refused.
pub fn reconstruct_resumable(
    cfg: &Config,
    out: &Path,
    mode: Mode,
    resume: bool,
) -> Result<(Report, Start)> {
    use crate::checkpoint::{self as ck, ProjCounts, Stage as Ck, Writer};
    let t_total = Instant::now();
    let t = Instant::now();
    let p = prepare(cfg, mode)?;
    let load_s = t.elapsed().as_secs_f64();
    let dir = state_dir(out);
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    let photos: Vec<PathBuf> = p.views.iter().map(|v| v.1.clone()).collect();
    let hash = ck::inputs_hash(cfg, &photos)?;
    let mut loaded = None;
    if resume {
        let (m, notes) = ck::load_for_resume(&dir)?;
        for n in &notes {
            note(mode, n);
        }
        match m {
            Some(m) if m.inputs_hash != hash => {
                return Err(Error::input(
                    dir.join(ck::MANIFEST),
                    "--resume: this checkpoint was made with other inputs or settings \
                     (scene, meshes, photos, or a setting that changes the result); resume \
                     with the original ones, or run without --resume to start over",
                ));
            }
            Some(m) if m.stage == Ck::Finished => {
                return Ok((m.report, Start::AlreadyFinished));
            }
            Some(m) => loaded = Some(m),
            None => note(
                mode,
                &format!("no usable checkpoint in {}: starting fresh", dir.display()),
            ),
        }
    }
    if loaded.is_none() {
        Writer::clear(&dir)?;
    }

    let t = Instant::now();
    let geom = build_geometry(&p, &dir.join("geometry.tiles"), mode)?;
    let atlas_s = t.elapsed().as_secs_f64();
    let state_path = dir.join("state.tiles");
    let window = p.window::<TexelState>(cfg);
    let (mut report, mut state, proj, stage, prior_s, mut writer, start);
    match loaded {
        None => {
            report = Report::new(cfg.clone());
            report.timings.load = load_s;
            report.timings.atlas = atlas_s;
            state = p.create_store(&state_path, TexelState::default())?;
            let t = Instant::now();
            let ps = project_all(&p, cfg, &geom, &mut state, mode)?;
            report.timings.projection = t.elapsed().as_secs_f64();
            proj = ProjCounts {
                views: ps.views,
                masked_pixels: ps.masked_pixels,
                covered_texels: ps.covered_texels,
                observed_texels: ps.observed_texels,
            };

            let t = Instant::now();
            let mean_e = direct_all(&p, cfg, &geom, &mut state, mode)?;
            report.timings.direct = t.elapsed().as_secs_f64();
            let share = cfg.initial_indirect_share;
            map_tiles(&mut state, &geom, window, |_, g, s| {
                init_indirect_tile(s, g, share, mean_e)
            })?;
            report.stopped_by = "max_iterations".into();
            stage = Ck::Direct;
            prior_s = 0.0;
            writer = Writer::new(&dir, hash, 0);
            writer.write(
                &state_path,
                stage,
                proj,
                &report,
                t_total.elapsed().as_secs_f64(),
            )?;
            start = Start::Fresh;
        }
        Some(m) => {
            ck::restore(&dir, &m, &state_path)?;
            state = TileStore::open(&state_path)?;
            if state.tile_count() != p.layout.tile_count as usize
                || state.tile_texels() != p.layout.tile_texels()
            {
                return Err(Error::input(
                    &state_path,
                    "checkpoint state does not match the atlas layout",
                ));
            }
            report = m.report.clone();
            report.settings = cfg.clone();
            proj = m.projection;
            stage = m.stage;
            prior_s = m.seconds;
            writer = Writer::new(&dir, hash, m.seq);
            let at = match stage {
                Ck::Pass {
                    iteration,
                    batches_done,
                    ..
                } => format!("iteration {}, batch {batches_done}", iteration + 1),
                Ck::Iterations {
                    iterations_done, ..
                } => format!("after iteration {iterations_done}"),
                _ => "after projection and direct light".into(),
            };
            note(mode, &format!("resuming from checkpoint {} ({at})", m.seq));
            start = Start::Resumed(m.seq);
        }
    }
    let elapsed = |t: &Instant| prior_s + t.elapsed().as_secs_f64();

    let receivers = Receivers::new(&p.scene, &p.layout, &p.atlases)?;
    let sampler = EmitterSampler::new(&p.scene);
    let (first_iteration, mut in_pass, stopped) = match stage {
        Ck::Direct | Ck::Finished => (0, None, false),
        Ck::Pass {
            iteration,
            batches_done,
            clamped,
            photon_seconds,
            update_seconds,
            ..
        } => (
            iteration,
            Some((batches_done, clamped, photon_seconds, update_seconds)),
            false,
        ),
        Ck::Iterations {
            iterations_done,
            stopped,
        } => (iterations_done, None, stopped),
    };
    let every = cfg.checkpoint_every_batches.max(1) as u64;
    let n_end = if stopped {
        first_iteration
    } else {
        cfg.iterations
    };
    for n in first_iteration..n_end {
        let t = Instant::now();
        let (clamped, mut update_s, first_batch, prior_photon_s) = match in_pass.take() {
            Some((b, clamped, ps, us)) => (clamped, us, b, ps),
            None => {
                let clamped: u64 = map_tiles(&mut state, &geom, window, |_, g, s| kd_tile(s, g))?
                    .iter()
                    .sum();
                fill_unobserved_all(&p, &receivers, &geom, &mut state)?;
                (clamped, 0.0, 0, 0.0)
            }
        };
        let albedo = AlbedoTextures::gather(&p.layout, &receivers, &state, cfg.atlas.padding + 2)?;
        update_s += t.elapsed().as_secs_f64();

        let ctx = pass_context(&p, cfg, (&sampler, &receivers, &albedo), n as u64);
        if first_batch == 0 {
            begin_pass(&mut state, window)?;
        }
        let stage = Stage::new(
            mode,
            &format!("photons {}/{}", n + 1, cfg.iterations),
            cfg.photons,
            "photons",
        );
        let batch = cfg.batch_size as u64;
        let batches = ctx.batch_count();
        let photons_of = |done: u64| done.saturating_mul(batch).min(cfg.photons);
        let mut last = photons_of(first_batch);
        stage.inc(last);
        let mut last_ck = first_batch;
        let t_pass = Instant::now();
        let pass = photon_pass(&ctx, &mut state, first_batch, |done| {
            let photons = photons_of(done);
            stage.inc(photons - last);
            last = photons;
            if done < batches && done - last_ck >= every {
                writer.write(
                    &state_path,
                    Ck::Pass {
                        iteration: n,
                        batches_done: done,
                        clamped,
                        photons,
                        photon_seconds: prior_photon_s + t_pass.elapsed().as_secs_f64(),
                        update_seconds: update_s,
                    },
                    proj,
                    &report,
                    elapsed(&t_total),
                )?;
                last_ck = done;
            }
            Ok(())
        })?;
        stage.finish();
        finish_pass(&geom, &mut state, window)?;
        if cfg.smoothing_radius > 0 {
            smooth_accum(
                &p.layout,
                &receivers,
                &geom,
                &mut state,
                cfg.smoothing_radius,
            )?;
        }

        let t = Instant::now();
        let a = alpha(cfg.alpha0, n);
        let rule = cfg.update;
        let (mut sum_e_i, mut sum_traced) = ([0.0f64; 3], [0.0f64; 3]);
        let beta = if rule == crate::config::UpdateRule::Secant {
            for (e, t) in map_tiles(&mut state, &geom, window, |_, g, s| channel_sums(s, g))? {
                for c in 0..3 {
                    sum_e_i[c] += e[c];
                    sum_traced[c] += t[c];
                }
            }
            let prev = report
                .iterations
                .last()
                .map(|it| (it.sum_e_i, it.sum_traced));
            secant_beta(prev, (sum_e_i, sum_traced), cfg.relaxation)
        } else {
            Vec3::splat(cfg.relaxation)
        };
        let sums = map_tiles(&mut state, &geom, window, |_, g, s| {
            compare_update_tile(s, g, rule, a, beta)
        })?;
        let mut e = ErrorSums::default();
        for s in &sums {
            e.add(s);
        }
        update_s += t.elapsed().as_secs_f64();
        let photons = photons_of(first_batch) + pass.photons;
        let photon_seconds = prior_photon_s + pass.seconds;
        let it = IterationStats {
            iteration: n,
            rms_rel_error: e.rms_rel(),
            mean_rel_error: e.mean_rel(),
            max_rel_error: e.max_rel,
            rms_residual: e.rms_residual(),
            clamped_texels: clamped,
            photons,
            photon_seconds,
            photons_per_second: photons as f64 / photon_seconds.max(1e-9),
            update_seconds: update_s,
            sum_e_i,
            sum_traced,
            beta: beta.to_array().map(f64::from),
        };
        report.timings.photons += photon_seconds;
        report.timings.update += update_s;
        if mode == Mode::Auto {
            eprintln!(
                "[iteration {}] relative error: rms {:.3}%, mean {:.3}%, max {:.2}%; {:.3e} photons/s",
                n + 1,
                100.0 * it.rms_rel_error,
                100.0 * it.mean_rel_error,
                100.0 * it.max_rel_error,
                it.photons_per_second
            );
        }
        let done = it.rms_rel_error < cfg.tolerance as f64;
        report.iterations.push(it);
        if done {
            report.stopped_by = "tolerance".into();
        }
        writer.write(
            &state_path,
            Ck::Iterations {
                iterations_done: n + 1,
                stopped: done || n + 1 == cfg.iterations,
            },
            proj,
            &report,
            elapsed(&t_total),
        )?;
        if done {
            break;
        }
    }
    // K_d consistent with the final E_i.
    map_tiles(&mut state, &geom, window, |_, g, s| kd_tile(s, g))?;
    let filled = fill_unobserved_all(&p, &receivers, &geom, &mut state)?;
    state.flush()?;

    report.counts = Counts {
        shapes: p.scene.shapes.len(),
        reconstructed_shapes: p.layout.slots.len(),
        triangles: p.scene.triangle_count(),
        emitters: p.scene.emitters.len(),
        views: proj.views,
        masked_pixels: proj.masked_pixels,
        tiles: p.layout.tile_count,
        covered_texels: proj.covered_texels,
        observed_texels: proj.observed_texels,
        filled_texels: filled,
    };
    report.timings.total = elapsed(&t_total);
    crate::output::write_outputs(&p, &geom, &state, &mut report, out)?;
    writer.write(&state_path, Ck::Finished, proj, &report, elapsed(&t_total))?;
    note(
        mode,
        &format!(
            "checkpoints: {:.1} MB written in {:.2} s",
            writer.bytes_written as f64 / 1e6,
            writer.seconds
        ),
    );
    Ok((report, start))
}
