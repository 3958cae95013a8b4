//! The one place that knows the order of the stages:
//!
//! ```text
//! scene -> atlas (geometry store) -> projection (L_orig) -> denoise (L_orig)
//!   -> direct light (E_d) -> caustics (E_d += light by way of mirrors and glass, photons)
//!   -> [ K_d (eqs. 3-5) -> E_i (gather or photons) -> compare and update (eqs. 6-9) ] x iterations
//!   -> final K_d -> outputs
//! ```
//!
//! Each stage is a plain function over tiles in its own module; this module calls them in
//! order, decides where their state lives (`<out>/checkpoint/*.tiles`), when a checkpoint is
//! taken and how a resumed run picks up where it stopped. Nothing below it imports it.
//!
//! After SIGINT / SIGTERM (`interrupt`), a run stops at its next safe point: after a batch
//! group of a photon pass or an iteration with a checkpoint of where it stands, or in
//! projection / direct light with nothing saved; it returns `Error::Interrupted`.
//!
//! **Several processes** (an MPI job, `comm`): every rank loads the scene and builds the
//! geometry (deterministic, so they agree) in its own working directory (rank 0 in
//! `<out>/checkpoint`, rank `r` in `<out>/checkpoint/rank-<r>`). This module decides who
//! computes what: tiles of the projection (and bands of rows of its refinement renders) and of
//! the direct light, batches of a photon pass, chunks of gather points, unit `u` by rank
//! `u mod N`; `ranks` combines the results in unit order (a photon batch's deposits go to the
//! rank of their tile, whose tiles are shared after the pass and before a checkpoint), so
//! every rank's state is the same bits after each stage, whatever N. The rest (the denoising
//! of L_orig, the per-texel update, smoothing, fill) runs
//! on every rank alike. Rank 0 alone writes checkpoints and outputs; a resumed run restores
//! rank 0's checkpoint and sends it to the others, so it continues under any N.

mod ranks;

use crate::atlas::context::HitTable;
use crate::atlas::store::{check_geometry, check_state};
use crate::atlas::store::{map_tiles, TileStore};
use crate::atlas::store::{TexelGeom, TexelState};
use crate::atlas::texture::{Scratch, SlotTexture};
use crate::atlas::uv::Charts;
use crate::atlas::{build_geometry, prepare, state_dir, RunContext};
use crate::base::comm::{self, World};
use crate::base::error::{Error, Result};
use crate::base::fsio;
use crate::base::interrupt;
use crate::base::progress::{self, note, Mode, Stage};
use crate::checkpoint::{self as ck, Manifest, Writer};
use crate::config::{Config, Method, UpdateRule};
use crate::output::maps::shape_facts;
use crate::output::{check_out_dir, output_units, page, uv_fold, write_map, write_outputs};
use crate::physics::light::EmitterSampler;
use crate::report::{Counts, IterationStats, Refinement, Report};
use crate::stages::indirect::gather::{
    self, trace_points_where, write_accum, GatherCache, GatherContext, GatherPoints, Radiance,
    POINT_FILTER_Z,
};
use crate::stages::indirect::photon::{
    begin_pass, finish_pass, photon_pass_shared, smooth_accum, AlbedoTextures, PassContext, Paths,
};
use crate::stages::one_colour::{smooth_uniform, UniformStats};
use crate::stages::project::pass_texel::PassTexel;
use crate::stages::project::{keep, ProjectionStats, Shard};
use crate::stages::solve::{init_indirect_tile, kd_step, update_step, Filled};
use crate::stages::{direct, project};
use ranks::GATHER_CHUNK;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::Instant;

/// Where a run stands: what the state store holds at a checkpoint.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum RunStage {
    /// Projection, direct light and the initial E_i are done; iteration 0 not begun.
    Direct,
    /// Inside iteration `iteration`'s photon pass: K_d was computed and filled for it, and
    /// batches `0..batches_done` are in `accum`.
    Pass {
        iteration: u32,
        batches_done: u64,
        /// Clamped texels counted by this iteration's K_d step.
        clamped: u64,
        /// Photons and seconds of the pass so far.
        photons: u64,
        photon_seconds: f64,
        update_seconds: f64,
    },
    /// Iterations `0..iterations_done` are complete; `stopped` if the solver stopped
    /// (tolerance reached or last iteration), so only the final step and outputs remain.
    Iterations { iterations_done: u32, stopped: bool },
    /// Outputs written: resuming is a no-op.
    Finished,
}

/// A checkpoint's stage must be one these settings can reach (its checksum only says the bytes
/// are the ones written, not that they came from this build's logic).
fn check_stage(stage: &RunStage, cfg: &Config, manifest: &Path) -> Result<()> {
    let batches = cfg.photons.div_ceil(u64::from(cfg.batch_size.max(1)));
    let bad = match *stage {
        RunStage::Pass {
            iteration,
            batches_done,
            photons,
            ..
        } => {
            cfg.method != Method::Photons
                || iteration >= cfg.iterations
                || batches_done > batches
                || photons > cfg.photons
        }
        RunStage::Iterations {
            iterations_done, ..
        } => iterations_done > cfg.iterations,
        RunStage::Direct | RunStage::Finished => false,
    };
    match bad {
        true => Err(Error::corrupt(
            manifest,
            format!("checkpoint stage {stage:?} is impossible with these settings"),
        )),
        false => Ok(()),
    }
}

/// The projection counts the report needs at the end.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct ProjCounts {
    pub views: usize,
    pub masked_pixels: usize,
    pub covered_texels: u64,
    pub observed_texels: u64,
    /// Covered texels some view could see (see [`Counts::visible_texels`]).
    pub visible_texels: u64,
    /// What `denoise` did (see [`Counts::denoised_texels`]).
    pub denoised_texels: u64,
    pub denoise_sigma_ratio: f64,
}

/// What a checkpoint of a reconstruction stores beside the state snapshot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Progress {
    pub stage: RunStage,
    pub projection: ProjCounts,
    /// The report so far: per-iteration statistics, timings (seconds spent so far).
    pub report: Report,
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

/// The newest usable checkpoint of the run in `out` (with notes on unusable ones).
pub fn load_checkpoint(out: &Path) -> (Option<Manifest<Progress>>, Vec<String>) {
    ck::load(&state_dir(out))
}

/// The whole method, steps 1-9, then every output of the contract, from scratch. Returns the
/// report.
pub fn reconstruct(cfg: &Config, out: &Path, mode: Mode) -> Result<Report> {
    reconstruct_resumable(cfg, out, mode, false).map(|(r, _)| r)
}

/// [`reconstruct`] with checkpoints in `<out>/checkpoint` (after projection and direct light,
/// after each iteration, every `checkpoint_every_batches` photon batches) and, if `resume`,
/// continuing from the newest good checkpoint there. A resumed run's outputs are
/// bit-identical to an uninterrupted run's; a checkpoint of other inputs or settings is
/// refused.
#[inline(never)] // a stage entry tools/icount.py measures
pub fn reconstruct_resumable(
    cfg: &Config,
    out: &Path,
    mode: Mode,
    resume: bool,
) -> Result<(Report, Start)> {
    let clock = Instant::now();
    let world = comm::world();
    world.decide(|| check_out_dir(out))?;
    let run = world.agree(Run::open(cfg, out, mode))?;
    let found = match resume {
        true => world.decide(|| run.find_checkpoint())?,
        false => None,
    };
    let mut r = match found {
        Some(m) if m.payload.stage == RunStage::Finished => {
            return Ok((m.payload.report, Start::AlreadyFinished))
        }
        Some(m) => run.resume(m, clock)?,
        None => run.start(clock)?,
    };
    run.iterate(&mut r)?;
    let start = r.start;
    Ok((run.finish(r)?, start))
}

/// Steps 1-2 on their own: atlas, projection, and the luminance and coverage maps in
/// `<out>/maps/`. Returns the projection statistics.
pub fn run_projection(
    cfg: &Config,
    out: &Path,
    mode: Mode,
) -> Result<(RunContext, ProjectionStats)> {
    let world = comm::world();
    world.decide(|| check_out_dir(out))?;
    let opened = || -> Result<_> {
        let p = prepare(cfg, mode)?;
        let dir = work_dir(out, world);
        fsio::create_dir(&dir)?;
        let geom = build_geometry(&p, &dir.join("geometry.tiles"), mode)?;
        let state = p.create_store(dir.join("state.tiles"), TexelState::default())?;
        Ok((p, dir, geom, state))
    };
    let (p, dir, geom, mut state) = world.agree(opened())?;
    let charts = Charts::new(&p.scene, &p.layout, &p.atlases)?;
    let hits = HitTable::new(&p, &charts);
    let scratch = open_scratch(&dir, cfg.memory_budget_mib << 20)?;
    let stats = with_shard(world, |sh| {
        project::run_shard(
            &p,
            cfg,
            (&hits, &charts),
            &geom,
            &mut state,
            mode,
            (&scratch, None),
            sh,
        )
    })?;
    denoise(&p, cfg, (&charts, &geom), &mut state, &scratch, false)?;
    debug_check(&geom, &state)?;
    if !world.is_root() {
        return Ok((p, stats));
    }
    gain_notes(mode, &stats.gains);
    let maps = out.join("maps");
    let mut facts = projection_facts(cfg, &stats);
    for slot in 0..p.layout.slots.len() {
        let (l, id) = (&p.layout, p.slot_id(slot));
        let g = |name: &str, f: &(dyn Fn(&TexelState) -> glam::Vec3 + Sync)| {
            SlotTexture::read(l, slot, &state, &geom, &scratch, name, |s, _| f(s))
        };
        let lum = g("lum", &|s| glam::Vec3::from_array(s.l_orig))?;
        let wt = g("weight", &|s| glam::Vec3::splat(s.weight))?;
        let obs = SlotTexture::read(l, slot, &state, &geom, &scratch, "obs", |s, _| {
            (s.weight > 0.0) as u8
        })?;
        let cov = SlotTexture::read(l, slot, &state, &geom, &scratch, "cov", |_, g| {
            g.covered() as u8
        })?;
        let mut f = shape_facts(&p, slot, None, (&cov, &obs));
        f.maps.push(write_map(
            &maps,
            id,
            "luminance",
            &lum,
            &obs,
            true,
            &scratch,
        )?);
        f.maps
            .push(write_map(&maps, id, "coverage", &wt, &cov, true, &scratch)?);
        facts.shapes.push(f);
    }
    page::write_page(out, None, &facts)?;
    Ok((p, stats))
}

/// The photos' gains and what the capture check found, as notes.
fn gain_notes(mode: Mode, capture: &[crate::report::ViewCapture]) {
    for line in crate::stages::project::exposure::notes(capture) {
        note(mode, &line);
    }
    let (ids, checks): (Vec<String>, Vec<_>) = (capture.iter())
        .filter_map(|c| Some((c.view.clone(), c.check.clone()?)))
        .unzip();
    for line in project::capture_notes(&ids, &checks) {
        note(mode, &line);
    }
}

/// The report page's summary of a projection on its own.
fn projection_facts(cfg: &Config, stats: &ProjectionStats) -> page::Facts {
    let share = stats.observed_texels as f64 / stats.covered_texels.max(1) as f64;
    page::Facts {
        command: "project".into(),
        summary: vec![
            format!("Scene: {}", cfg.scene.display()),
            format!(
                "The photos of {} views projected onto the surfaces (steps 1-2 of the method); no albedo was solved for.",
                stats.views
            ),
            format!(
                "{} of {} surface texels seen by a view ({:.1}%); {} pixels masked.",
                stats.observed_texels,
                stats.covered_texels,
                100.0 * share,
                stats.masked_pixels
            ),
            format!("Time: {:.1} s", stats.seconds),
        ],
        ..Default::default()
    }
}

/// The projected luminance's noise reduced (`denoise`), after the projection. Every rank runs
/// it whole on the same synced state, so they stay the same bits. With `fold` (a
/// reconstruction whose output folds tiled textures, `[output] uv_fold`), the shapes the fold
/// may take are left unfiltered: the fold averages their noise over the repeats, and the
/// filter would only blur their detail (see `uv_fold::foldable_slots`).
#[inline(never)] // a stage entry tools/icount.py measures
fn denoise(
    p: &RunContext,
    cfg: &Config,
    (charts, geom): (&Charts, &TileStore<TexelGeom>),
    state: &mut TileStore<TexelState>,
    scratch: &Scratch,
    fold: bool,
) -> Result<crate::stages::denoise::DenoiseStats> {
    let params = (cfg.denoise_radius, cfg.denoise_z);
    let skip = match fold && cfg.uv_fold && cfg.denoise_radius > 0 {
        true => {
            let budget = uv_fold::fold_budget(cfg.memory_budget_mib);
            uv_fold::foldable_slots(p, (geom, state), budget)?
        }
        false => Vec::new(),
    };
    crate::stages::denoise::denoise_luminance(
        &p.layout, charts, geom, state, params, scratch, &skip,
    )
}

/// The working directory of this rank: rank 0's is the run's checkpoint directory, the
/// others' a `rank-<r>` directory inside it (their stores and scratch; never checkpoints).
fn work_dir(out: &Path, world: &World) -> PathBuf {
    match world.rank() {
        0 => state_dir(out),
        r => state_dir(out).join(format!("rank-{r}")),
    }
}

/// `f` with the projection's share of the work on this rank: tiles and row bands `u mod N`,
/// synced through `ranks::share_tiles`.
fn with_shard<R>(world: &World, f: impl FnOnce(&Shard) -> R) -> R {
    let owns = |u: usize| world.owns(u as u64);
    let sync = |s: &mut TileStore<TexelState>| ranks::share_tiles(world, s);
    let sync_pass = |s: &mut TileStore<PassTexel>| ranks::share_tiles(world, s);
    let pixels = |img: &mut [Option<glam::Vec3>], unit| ranks::share_pixels(world, img, unit);
    let bytes = |buf: &mut [u8], unit| ranks::share_bytes(world, buf, unit);
    let sum = |v: u64| world.sum(v);
    f(&Shard {
        owns: &owns,
        sync: &sync,
        sync_pass: &sync_pass,
        sync_pixels: &pixels,
        sync_bytes: &bytes,
        sum: &sum,
        alone: world.size() == 1,
    })
}

/// The stores' invariants after a stage, in debug builds (`atlas::store::check`).
fn debug_check(geom: &TileStore<TexelGeom>, state: &TileStore<TexelState>) -> Result<()> {
    if cfg!(debug_assertions) {
        check_state(state, geom)?;
    }
    Ok(())
}

/// What is fixed about one reconstruction: the prepared scene, where its state lives, the
/// fingerprint of its inputs, the geometry store.
struct Run<'a> {
    /// The run's settings, the photon budget resolved for this atlas.
    cfg: Config,
    /// Per reconstructed shape, its texel density and covered texels.
    atlas: Vec<crate::report::ShapeTexels>,
    out: &'a Path,
    mode: Mode,
    /// The processes of the run (one, or the ranks of an MPI job).
    world: &'static World,
    p: RunContext,
    /// This rank's working directory (see [`work_dir`]); rank 0's holds the checkpoints.
    dir: PathBuf,
    state_path: PathBuf,
    hash: u64,
    geom: TileStore<TexelGeom>,
    charts: Charts,
    /// Made on first use by the gather.
    hits: OnceLock<HitTable>,
    points: OnceLock<GatherPoints>,
    gather: OnceLock<GatherCache>,
    window: usize,
    /// Scratch textures (a quarter of the memory budget each).
    scratch: Scratch,
    load_s: f64,
    /// Peak RSS after loading the scene (MiB).
    load_rss: f64,
    atlas_s: f64,
    /// Rays the atlas cast (this process).
    atlas_rays: u64,
}

/// A reconstruction under way: its state store, report and checkpoint writer.
struct Running {
    state: TileStore<TexelState>,
    report: Report,
    proj: ProjCounts,
    stage: RunStage,
    writer: Writer,
    start: Start,
    /// When this attempt began, and the seconds spent by earlier attempts.
    clock: Instant,
    prior_s: f64,
    /// Whether this process writes the checkpoints (rank 0).
    root: bool,
    /// Where notes go (the checkpoint cadence's).
    mode: Mode,
}

impl Running {
    /// Seconds spent by the run so far, over every attempt.
    fn elapsed(&self) -> f64 {
        self.prior_s + self.clock.elapsed().as_secs_f64()
    }

    /// Checkpoint at `stage` if it is due: always after the direct light and when finished,
    /// else once the writer's period has passed since the last one (`checkpoint::cadence`).
    /// Returns whether it wrote one.
    fn checkpoint_if_due(&mut self, state_path: &Path, stage: RunStage) -> Result<bool> {
        let forced = matches!(stage, RunStage::Direct | RunStage::Finished);
        let due = forced || self.writer.due();
        if due {
            self.checkpoint(state_path, stage)?;
        }
        Ok(due)
    }

    /// A stop asked for by a signal, at a safe point where the run stands at `stage`: a
    /// checkpoint of it (unless `saved`: one was just written), and the error to stop with.
    fn interrupted(&mut self, state_path: &Path, stage: RunStage, saved: bool) -> Result<Error> {
        if !saved {
            self.checkpoint(state_path, stage)?;
        }
        // the other ranks wait for rank 0's checkpoint: a rank that ended sooner would make
        // the launcher kill the job while rank 0 still writes
        comm::world().barrier();
        let dir = state_path.parent().unwrap_or(state_path);
        Ok(interrupted(dir, self.writer.seq()))
    }

    /// Checkpoint: the state (unless finished) and where the run stands (rank 0 only).
    fn checkpoint(&mut self, state_path: &Path, stage: RunStage) -> Result<()> {
        if !self.root {
            return Ok(());
        }
        let progress = Progress {
            stage,
            projection: self.proj,
            report: self.report.clone(),
        };
        let snapshot = (stage != RunStage::Finished).then_some(state_path);
        let seconds = self.elapsed();
        self.writer.write(snapshot, &progress, seconds)?;
        if let Some(line) = self.writer.cadence_note() {
            note(self.mode, &line);
        }
        Ok(())
    }
}

impl<'a> Run<'a> {
    /// Load and prepare the scene, fingerprint the inputs and build the geometry store.
    fn open(cfg: &Config, out: &'a Path, mode: Mode) -> Result<Run<'a>> {
        let t = Instant::now();
        let world = comm::world();
        let p = prepare(cfg, mode)?;
        let load_s = t.elapsed().as_secs_f64();
        // the scene itself (meshes, BVH, photos): what a run needs beside the budget
        let load_rss = crate::base::mem::peak_mib();
        let dir = work_dir(out, world);
        fsio::create_dir(&dir)?;
        let hash = p.fingerprint(cfg)?;
        let t = Instant::now();
        let geom = build_geometry(&p, &dir.join("geometry.tiles"), mode)?;
        if cfg!(debug_assertions) {
            check_geometry(&geom)?;
        }
        let charts = Charts::new(&p.scene, &p.layout, &p.atlases)?;
        let scratch = open_scratch(&dir, cfg.memory_budget_mib << 20)?;
        let atlas = p.texel_report(&geom, p.window::<TexelGeom>(cfg))?;
        let covered = atlas.iter().map(|a| a.covered_texels).sum();
        let cfg = cfg.with_photon_budget_for(covered);
        let atlas_rays = p.accel.rays();
        Ok(Run {
            charts,
            scratch,
            atlas,
            hits: OnceLock::new(),
            points: OnceLock::new(),
            gather: OnceLock::new(),
            window: p.window::<TexelState>(&cfg),
            state_path: dir.join("state.tiles"),
            cfg,
            out,
            mode,
            world,
            p,
            dir,
            hash,
            geom,
            load_s,
            load_rss,
            atlas_s: t.elapsed().as_secs_f64(),
            atlas_rays,
        })
    }

    /// The checkpoint to resume from, if a usable one of these inputs exists; a checkpoint of
    /// other inputs is refused.
    fn find_checkpoint(&self) -> Result<Option<Manifest<Progress>>> {
        let (m, notes) = ck::load_for_resume::<Progress>(&self.dir)?;
        for n in &notes {
            note(self.mode, n);
        }
        match m {
            Some(m) if m.inputs_hash != self.hash => Err(Error::input(
                self.dir.join(ck::MANIFEST),
                "--resume: this checkpoint was made with other inputs or settings \
                 (scene, meshes, photos, or a setting that changes the result); resume \
                 with the original ones, or run without --resume to start over",
            )),
            None => {
                let msg = format!(
                    "no usable checkpoint in {}: starting fresh",
                    self.dir.display()
                );
                note(self.mode, &msg);
                Ok(None)
            }
            m => Ok(m),
        }
    }

    /// A fresh start: projection, direct light, the initial E_i, and the first checkpoint.
    fn start(&self, clock: Instant) -> Result<Running> {
        let (cfg, p, mode, world) = (&self.cfg, &self.p, self.mode, self.world);
        if world.is_root() {
            Writer::clear(&self.dir)?;
        }
        let mut report = Report::new(cfg.clone());
        report.timings.load = self.load_s;
        report.timings.atlas = self.atlas_s;
        report.rays.atlas = world.sum(self.atlas_rays);
        report.rays.cores = world.size() * rayon::current_num_threads();
        let rays = p.accel.rays();
        report.atlas = self.atlas.clone();
        report.resources.memory_budget_mib = cfg.memory_budget_mib;
        let res = &mut report.resources;
        res.peak_rss_mib.push(("load".into(), self.load_rss));
        res.after("load + atlas");
        let mut state = p.create_store(&self.state_path, TexelState::default())?;
        let t = Instant::now();
        let ps = with_shard(world, |sh| {
            let (hits, geom, scratch) = ((self.hits(), &self.charts), &self.geom, &self.scratch);
            // the root's outputs re-render the views from what the projection traced
            let kept = keep::dir(&scratch.dir);
            let keep = world.is_root().then_some(kept.as_path());
            project::run_shard(p, cfg, hits, geom, &mut state, mode, (scratch, keep), sh)
        })?;
        let dn = denoise(
            p,
            cfg,
            (&self.charts, &self.geom),
            &mut state,
            &self.scratch,
            true,
        )?;
        report.timings.projection = t.elapsed().as_secs_f64();
        report.rays.projection = self.rays_since(rays);
        report.timings.noise_probe = ps.probe_seconds;
        report.timings.calibration = ps.calibration_seconds;
        let ids = p
            .views
            .iter()
            .map(|(si, _)| p.scene.sensors[*si].id.clone());
        report.refinement = Refinement::new(ids.collect(), ps.refine_residual.clone());
        report.poses = ps.pose.clone();
        report.capture = ps.gains.clone();
        gain_notes(mode, &report.capture);
        if let Some(line) = report.refinement.summary() {
            note(mode, &line);
        }
        report.resources.after("projection");
        debug_check(&self.geom, &state)?;
        let proj = ProjCounts {
            views: ps.views,
            masked_pixels: ps.masked_pixels,
            covered_texels: ps.covered_texels,
            observed_texels: ps.observed_texels,
            visible_texels: ps.visible_texels,
            denoised_texels: dn.averaged,
            denoise_sigma_ratio: dn.sigma_ratio,
        };
        let (t, rays) = (Instant::now(), p.accel.rays());
        let direct = self.direct(&mut state)?;
        report.timings.direct = t.elapsed().as_secs_f64();
        report.rays.direct = self.rays_since(rays);
        report.resources.after("direct");
        let (t, rays) = (Instant::now(), p.accel.rays());
        let caustic = self.caustics(&mut state)?;
        report.timings.caustics = t.elapsed().as_secs_f64();
        report.rays.caustics = self.rays_since(rays);
        report.counts.caustic_photons = caustic.photons;
        report.counts.dense_direct_texels = direct.dense;
        report.counts.direct_first_pass_texels = direct.first_pass;
        report.counts.dense_direct_texels_per_emitter = direct.dense_per_emitter.clone();
        report.counts.smoothed_direct_texels = direct.smoothed;
        let mean_e = direct.mean;
        let share = cfg.initial_indirect_share;
        map_tiles(&mut state, &self.geom, self.window, |_, g, s| {
            init_indirect_tile(s, g, share, mean_e)
        })?;
        debug_check(&self.geom, &state)?;
        report.stopped_by = "max_iterations".into();
        let mut r = Running {
            state,
            report,
            proj,
            stage: RunStage::Direct,
            writer: Writer::new(&self.dir, self.hash, 0, cfg.checkpoint_every_seconds),
            start: Start::Fresh,
            clock,
            prior_s: 0.0,
            root: world.is_root(),
            mode,
        };
        r.checkpoint(&self.state_path, RunStage::Direct)?;
        Ok(r)
    }

    /// The direct light, each rank its tiles, their E_d and sums shared in tile order.
    #[inline(never)] // a stage entry tools/icount.py measures
    fn direct(&self, state: &mut TileStore<TexelState>) -> Result<direct::DirectStats> {
        let (p, cfg, world) = (&self.p, &self.cfg, self.world);
        let owns = |t: usize| world.owns(t as u64);
        let sums = direct::run_tiles(p, cfg, &self.charts, &self.geom, state, self.mode, &owns)?;
        ranks::share_tiles(world, state)?;
        // every rank holds every tile now, and measures the same noise on it
        direct::sampling::estimate(p, &self.charts, &self.geom, state, &self.scratch)?;
        let smoothed = direct::smooth::smooth(p, &self.charts, &self.geom, state, &self.scratch)?;
        let mine = sums.into_iter().enumerate().map(|(t, s)| (t as u64, s));
        let mine = mine.filter(|(t, _)| world.owns(*t)).collect();
        let all = ranks::share_serde(world, mine)?;
        let sums: Vec<_> = all.into_iter().map(|(_, s)| s).collect();
        Ok(direct::DirectStats {
            smoothed,
            ..direct::DirectStats::from_tiles(&sums)
        })
    }

    /// Light by way of mirrors and glass (caustics), added to `E_d`: a photon pass of
    /// [`Paths::Caustic`] (a [`CAUSTIC_SHARE`] of the solver's photon budget, its own random
    /// stream), its irradiance
    /// smoothed like a photon `E_i`. It depends on no `K_d`, so it is traced once, here; a
    /// scene without such materials skips it. Nothing is saved if it is interrupted.
    #[inline(never)] // a stage entry tools/icount.py measures
    fn caustics(
        &self,
        state: &mut TileStore<TexelState>,
    ) -> Result<crate::stages::indirect::photon::PassStats> {
        let (cfg, p, world, charts) = (&self.cfg, &self.p, self.world, &self.charts);
        if !p.scene.shapes.iter().any(|s| s.known().is_some()) {
            return Ok(Default::default());
        }
        let sampler = EmitterSampler::new(&p.scene);
        let keep = self.scratch.with_budget(2 * self.scratch.budget);
        // only the charts are read: the first diffuse hit ends every path, whatever its K_d
        let albedo =
            AlbedoTextures::uniform(&p.layout, charts, &self.geom, glam::Vec3::ZERO, &keep)?;
        let hits = self.hits();
        let mut ctx = PassContext::new(p, cfg, (&sampler, charts, hits, &albedo), CAUSTIC_PASS);
        ctx.paths = Paths::Caustic;
        ctx.photons = cfg.photons.div_ceil(CAUSTIC_SHARE).max(1);
        ctx.group_batches = self.group_batches();
        begin_pass(state, self.window)?;
        let (mode, n) = (self.mode, ctx.photons);
        let stage = Stage::after(mode, "caustics", n, "photons", progress::SHOW_AFTER);
        let mut last = 0;
        let owns = |b: u64| world.owns(b);
        let mut route = |traced| ranks::route_batches(world, traced);
        let stats = photon_pass_shared(&ctx, state, 0, &owns, &mut route, |done, _| {
            let photons = ctx.photons_in(done);
            stage.inc(photons - last);
            last = photons;
            interrupt::check(interrupt::NOTHING_SAVED)
        })?;
        stage.finish();
        self.finish_accum(state)?;
        map_tiles(state, &self.geom, self.window, |_, _, recs| {
            for s in recs.iter_mut() {
                for c in 0..3 {
                    s.e_d[c] += s.accum[c];
                }
            }
        })?;
        Ok(stats)
    }

    /// Continue from checkpoint `m`: its state snapshot restored, its report and stage.
    fn resume(&self, m: Manifest<Progress>, clock: Instant) -> Result<Running> {
        let world = self.world;
        world.agree(check_stage(
            &m.payload.stage,
            &self.cfg,
            &self.dir.join(ck::MANIFEST),
        ))?;
        // no projection: the photos `prepare` checked are not needed
        self.p.release_photos();
        // rank 0 restores its checkpoint and sends it to the others
        let mut state = world.agree(match world.is_root() {
            true => ck::restore(&self.dir, &m, &self.state_path)
                .and_then(|()| self.p.open_store(&self.state_path)),
            false => self.p.create_store(&self.state_path, TexelState::default()),
        })?;
        ranks::broadcast_store(world, &mut state)?;
        let mut report = m.payload.report;
        report.settings = self.cfg.clone();
        let at = match m.payload.stage {
            RunStage::Pass {
                iteration,
                batches_done,
                ..
            } => format!("iteration {}, batch {batches_done}", iteration + 1),
            RunStage::Iterations {
                iterations_done, ..
            } => format!("after iteration {iterations_done}"),
            _ => "after projection and direct light".into(),
        };
        note(
            self.mode,
            &format!("resuming from checkpoint {} ({at})", m.seq),
        );
        Ok(Running {
            state,
            report,
            proj: m.payload.projection,
            stage: m.payload.stage,
            writer: Writer::new(
                &self.dir,
                self.hash,
                m.seq,
                self.cfg.checkpoint_every_seconds,
            ),
            start: Start::Resumed(m.seq),
            clock,
            prior_s: m.seconds,
            root: world.is_root(),
            mode: self.mode,
        })
    }

    /// The solver's iterations from where `r` stands, each checkpointed.
    fn iterate(&self, r: &mut Running) -> Result<()> {
        let sampler = EmitterSampler::new(&self.p.scene);
        let (first, mut in_pass, stopped) = match r.stage {
            RunStage::Direct | RunStage::Finished => (0, None, false),
            RunStage::Pass {
                iteration,
                batches_done,
                clamped,
                photon_seconds,
                update_seconds,
                ..
            } => (
                iteration,
                Some(PassResume {
                    batches_done,
                    clamped,
                    photon_seconds,
                    update_seconds,
                }),
                false,
            ),
            RunStage::Iterations {
                iterations_done,
                stopped,
            } => (iterations_done, None, stopped),
        };
        let last = if stopped { first } else { self.cfg.iterations };
        for n in first..last {
            let done = self.iteration(r, n, in_pass.take(), &sampler)?;
            debug_check(&self.geom, &r.state)?;
            if done {
                break;
            }
        }
        Ok(())
    }

    /// Iteration `n`: K_d from the current E_i, an E_i estimate (a gather pass, or a photon
    /// pass from `resume` if the run stopped inside one), the update; checkpointed at its end.
    /// Returns whether the solver stops here (tolerance reached).
    fn iteration(
        &self,
        r: &mut Running,
        n: u32,
        resume: Option<PassResume>,
        sampler: &EmitterSampler,
    ) -> Result<bool> {
        let (cfg, window) = (&self.cfg, self.window);
        let t = Instant::now();
        let mut pass = match resume {
            Some(r) => r,
            None => {
                let (clamped, _) = self.kd_step(r, &format!("K_d {}/{}", n + 1, cfg.iterations))?;
                PassResume {
                    batches_done: 0,
                    clamped,
                    photon_seconds: 0.0,
                    update_seconds: t.elapsed().as_secs_f64(),
                }
            }
        };
        let rays = self.p.accel.rays();
        let (est, rule) = match cfg.method {
            Method::Photons => (self.photon_estimate(r, n, &mut pass, sampler)?, cfg.update),
            Method::Gather => (self.gather_estimate(r)?, UpdateRule::FixedPoint),
        };
        r.report.rays.estimate += self.rays_since(rays);
        if cfg.method == Method::Photons {
            crate::stages::indirect::through_coats(&self.p, &self.geom, (&mut r.state, window))?;
        }
        let t = Instant::now();
        let prev = r
            .report
            .iterations
            .last()
            .map(|it| (it.sum_e_i, it.sum_traced));
        let stage = self.tile_stage(&format!("update {}/{}", n + 1, cfg.iterations), 1);
        let tick = |k| stage.inc(k);
        let u = update_step(
            cfg,
            rule,
            n,
            prev,
            &self.geom,
            (&mut r.state, window),
            &tick,
        )?;
        stage.finish();
        pass.update_seconds += t.elapsed().as_secs_f64();
        let it = IterationStats {
            iteration: n,
            rms_rel_error: u.errors.rms_rel(),
            mean_rel_error: u.errors.mean_rel(),
            max_rel_error: u.errors.max_rel,
            rms_residual: u.errors.rms_residual(),
            clamped_texels: pass.clamped,
            photons: est.photons,
            photon_seconds: est.photon_seconds,
            photons_per_second: est.photons as f64 / est.photon_seconds.max(1e-9),
            gather_rays: est.gather_rays,
            gather_seconds: est.gather_seconds,
            gather_cached_hits: est.gather_cached_hits,
            update_seconds: pass.update_seconds,
            sum_e_i: u.sum_e_i,
            sum_traced: u.sum_traced,
            beta: u.beta.to_array().map(f64::from),
        };
        r.report.timings.photons += est.photon_seconds;
        r.report.timings.gather += est.gather_seconds;
        r.report.timings.update += pass.update_seconds;
        let text = format!(
            "[iteration {}] relative error: rms {:.3}%, mean {:.3}%, max {:.2}%",
            n + 1,
            100.0 * it.rms_rel_error,
            100.0 * it.mean_rel_error,
            100.0 * it.max_rel_error,
        );
        let json = serde_json::json!({
            "stage": "iteration",
            "iteration": n + 1,
            "rms_rel_error": it.rms_rel_error,
            "mean_rel_error": it.mean_rel_error,
            "max_rel_error": it.max_rel_error,
        });
        progress::report(self.mode, &text, json);
        let done = it.rms_rel_error < cfg.tolerance as f64;
        r.report.iterations.push(it);
        r.report.resources.after(&format!("iteration {}", n + 1));
        if done {
            r.report.stopped_by = "tolerance".into();
        }
        let stage = RunStage::Iterations {
            iterations_done: n + 1,
            stopped: done || n + 1 == cfg.iterations,
        };
        r.stage = stage;
        let saved = r.checkpoint_if_due(&self.state_path, stage)?;
        if interrupt::agreed() {
            return Err(r.interrupted(&self.state_path, stage, saved)?);
        }
        Ok(done)
    }

    /// E_i by photon tracing into `accum` (the rest of `pass` from where it stands), smoothed.
    #[inline(never)] // a stage entry tools/icount.py measures
    fn photon_estimate(
        &self,
        r: &mut Running,
        n: u32,
        pass: &mut PassResume,
        sampler: &EmitterSampler,
    ) -> Result<Estimate> {
        let (cfg, p, charts) = (&self.cfg, &self.p, &self.charts);
        let t = Instant::now();
        let padding = cfg.atlas.padding + 2;
        // the textures stay through the pass, beside the pass's own mapped window
        let keep = self.scratch.with_budget(2 * self.scratch.budget);
        let albedo = AlbedoTextures::read(&p.layout, charts, &r.state, &self.geom, padding, &keep)?;
        pass.update_seconds += t.elapsed().as_secs_f64();
        let mut ctx = PassContext::new(p, cfg, (sampler, charts, self.hits(), &albedo), n as u64);
        ctx.group_batches = self.group_batches();
        let traced = self.photon_pass(r, &ctx, n, pass)?;
        self.finish_accum(&mut r.state)?;
        Ok(Estimate {
            photons: ctx.photons_in(pass.batches_done) + traced.photons,
            photon_seconds: pass.photon_seconds + traced.seconds,
            ..Default::default()
        })
    }

    /// A photon pass's `accum` (summed flux) made the irradiance it deposited: the deposits
    /// went to their tiles' ranks, so every tile is first made current everywhere; then
    /// flux / bin area ([`finish_pass`]) and the box filter of `smoothing_radius`.
    fn finish_accum(&self, state: &mut TileStore<TexelState>) -> Result<()> {
        let (p, r) = (&self.p, self.cfg.smoothing_radius);
        ranks::share_tiles(self.world, state)?;
        finish_pass(&self.geom, state, self.window)?;
        if r > 0 {
            smooth_accum(&p.layout, &self.charts, &self.geom, state, r, &self.scratch)?;
        }
        Ok(())
    }

    /// E_i gathered from the observed radiance into `accum`: the rays are cast in the first
    /// gather of a run (or of a resumed attempt), later iterations re-read their hits.
    #[inline(never)] // a stage entry tools/icount.py measures
    fn gather_estimate(&self, r: &mut Running) -> Result<Estimate> {
        let p = &self.p;
        let t = Instant::now();
        let path = self.scratch.dir.join("gather-radiance.tiles");
        // half the budget: the state's window takes the other half when E_i is written
        let budget = (self.cfg.memory_budget_mib << 20) / 2;
        let stage = self.tile_stage("radiance", 1);
        let tick = |k| stage.inc(k);
        let radiance = Radiance::from_state(
            &p.layout,
            &self.charts,
            &r.state,
            &self.geom,
            &path,
            budget,
            &tick,
        )?;
        stage.finish();
        let (mut rays, mut cached) = (0, 0);
        let cache = match self.gather.get() {
            Some(c) => c,
            None => {
                let cache = self.trace_gather(&radiance, &r.state)?;
                radiance.check()?;
                rays = self.world.sum(cache.stats.rays);
                cached = self.world.sum(cache.stats.cached_hits);
                self.gather.get_or_init(|| cache)
            }
        };
        // each rank evaluates the chunks of points it traced; then every rank has every value
        let points = self.gather_points(&r.state)?;
        let ctx = self.gather_context(&radiance, points);
        let (mut values, mut variance) = cache.evaluate(&ctx, points);
        radiance.check()?;
        ranks::share_points(self.world, &mut values)?;
        ranks::share_points(self.world, &mut variance)?;
        drop(radiance);
        std::fs::remove_file(&path).map_err(|e| crate::Error::io(&path, e))?;
        let (layout, charts, geom) = (&p.layout, &self.charts, &self.geom);
        let (values, variance) = points.filtered(&values, &variance, POINT_FILTER_Z);
        let stage = self.tile_stage("E_i", 1);
        let tick = |k| stage.inc(k);
        write_accum(
            layout,
            points,
            (&values, &variance),
            charts,
            geom,
            (&mut r.state, self.window),
            &tick,
        )?;
        stage.finish();
        Ok(Estimate {
            gather_rays: rays,
            gather_cached_hits: cached,
            gather_seconds: t.elapsed().as_secs_f64(),
            ..Default::default()
        })
    }

    /// The gather's rays from every point (see `gather::GatherCache`).
    fn trace_gather(
        &self,
        radiance: &Radiance,
        state: &TileStore<TexelState>,
    ) -> Result<GatherCache> {
        let points = self.gather_points(state)?;
        let ctx = self.gather_context(radiance, points);
        let world = self.world;
        let owns = |i: usize| world.owns((i / GATHER_CHUNK) as u64);
        let mine = (0..points.points.len()).filter(|&i| owns(i)).count();
        let stage = Stage::new(self.mode, "gather rays", mine as u64, "points");
        let limit = gather::budget::cache_bytes(self.cfg.memory_budget_mib);
        let cache = trace_points_where(&ctx, points, (&owns, limit), &|k| stage.inc(k));
        stage.finish();
        let again = self.world.sum(cache.stats.retraced_points);
        if again > 0 && self.world.is_root() {
            note(
                self.mode,
                &format!(
                    "gather: the hits of {again} of {} points left out of the ray cache \
                     (half of memory_budget_mib = {}): their rays are cast again each iteration",
                    points.points.len(),
                    self.cfg.memory_budget_mib
                ),
            );
        }
        Ok(cache)
    }

    /// What the gather's rays read, with this iteration's `radiance`.
    fn gather_context<'g>(
        &'g self,
        radiance: &'g Radiance,
        pts: &GatherPoints,
    ) -> GatherContext<'g> {
        let rays = self.gather_rays(pts);
        GatherContext {
            accel: &self.p.accel,
            hits: self.hits(),
            radiance,
            seed: self.cfg.seed,
            rays,
            lean_rays: gather::lean_rays(rays, self.cfg.unobserved_share),
        }
    }

    /// Steps 3-5 (`solve::kd_step`) with a progress stage `name` over the tiles: `(clamped
    /// texels, what the fill filled)`.
    #[inline(never)] // a stage entry tools/icount.py measures
    fn kd_step(&self, r: &mut Running, name: &str) -> Result<(u64, Filled)> {
        // the K_d pass, then the fill's read and write of every tile
        let stage = self.tile_stage(name, 3);
        let p = &self.p;
        let got = kd_step(
            &p.layout,
            &self.charts,
            &self.geom,
            (&mut r.state, self.window),
            (&p.pinned(), &p.material_groups()),
            &self.scratch,
            &|k| stage.inc(k),
        )?;
        stage.finish();
        Ok(got)
    }

    /// A stage of `passes` passes over every tile, shown once it runs for a while.
    fn tile_stage(&self, name: &str, passes: u64) -> Stage {
        let tiles = self.p.layout.tile_count as u64;
        Stage::after(
            self.mode,
            name,
            passes * tiles,
            "tiles",
            progress::SHOW_AFTER,
        )
    }

    /// The gather points of this run (made on first use, after the projection: they are placed
    /// on observed texels where a cell has any, read from `state`).
    fn gather_points(&self, state: &TileStore<TexelState>) -> Result<&GatherPoints> {
        if let Some(p) = self.points.get() {
            return Ok(p);
        }
        let spacing = gather::shape_spacing(&self.cfg, &self.p.scene);
        let texels = self.p.layout.slots.iter();
        let total = texels.map(|s| s.width as u64 * s.height as u64).sum();
        let stage = Stage::after(
            self.mode,
            "gather points",
            total,
            "texels",
            progress::SHOW_AFTER,
        );
        let tick = |k| stage.inc(k);
        let stores = (&self.geom, state, &self.charts);
        let cap = self.gather_cap();
        let (pts, floor) =
            gather::budget::capped_points(&self.p, stores, &spacing, cap, &self.scratch, &tick)?;
        stage.finish();
        if floor > 0.0 && self.world.is_root() {
            let rays = self.gather_rays(&pts);
            note(
                self.mode,
                &format!(
                    "gather: {} points for {} covered texels (at most one per {} texels): \
                     spacing raised to at least {floor:.4} scene units on the smallest shapes{}",
                    pts.points.len(),
                    self.covered_texels(),
                    gather::budget::TEXELS_PER_POINT,
                    match rays < self.cfg.gather_rays {
                        true => format!(", {rays} rays per point (one per chart and cell)"),
                        false => String::new(),
                    }
                ),
            );
        }
        Ok(self.points.get_or_init(|| pts))
    }

    /// The covered texels of every shape's atlas.
    fn covered_texels(&self) -> u64 {
        self.atlas.iter().map(|a| a.covered_texels).sum()
    }

    /// The most gather points this run places ([`gather::budget::point_cap`]).
    fn gather_cap(&self) -> usize {
        gather::budget::point_cap(self.covered_texels())
    }

    /// Rays per gather point: `[gather] rays`, fewer where the points are over their cap.
    fn gather_rays(&self, points: &GatherPoints) -> u32 {
        gather::budget::rays_for(self.cfg.gather_rays, points.points.len(), self.gather_cap())
    }

    /// The hit table of this run (made on first use).
    fn hits(&self) -> &HitTable {
        self.hits
            .get_or_init(|| HitTable::new(&self.p, &self.charts))
    }

    /// The photon pass of iteration `n` from batch `pass.batches_done`, with its progress
    /// bar and a checkpoint every `checkpoint_every_batches` batches.
    fn photon_pass(
        &self,
        r: &mut Running,
        ctx: &PassContext,
        n: u32,
        pass: &PassResume,
    ) -> Result<crate::stages::indirect::photon::PassStats> {
        let cfg = &self.cfg;
        if pass.batches_done == 0 {
            begin_pass(&mut r.state, self.window)?;
        }
        let name = format!("photons {}/{}", n + 1, cfg.iterations);
        let stage = Stage::new(self.mode, &name, cfg.photons, "photons");
        let batches = ctx.batch_count();
        let every = cfg.checkpoint_every_batches.max(1) as u64;
        let mut last = ctx.photons_in(pass.batches_done);
        stage.inc(last);
        let mut last_ck = pass.batches_done;
        let t_pass = Instant::now();
        let (state_path, world) = (&self.state_path, self.world);
        let Running {
            state,
            report,
            proj,
            writer,
            clock,
            prior_s,
            root,
            ..
        } = r;
        let owns = |b: u64| world.owns(b);
        let mut route = |traced| ranks::route_batches(world, traced);
        let first = pass.batches_done;
        let traced = photon_pass_shared(ctx, state, first, &owns, &mut route, |done, state| {
            let photons = ctx.photons_in(done);
            stage.inc(photons - last);
            last = photons;
            let due = *root && done - last_ck >= every && writer.due();
            // a signal (on any rank): stop after this group, with a checkpoint of it
            let stop = done < batches && interrupt::agreed();
            // rank 0's clock decides; every rank first makes its tiles current there
            if done < batches && (stop || world.any(due)) {
                ranks::share_tiles(world, state)?;
            }
            if *root && done < batches && (due || stop) {
                let progress = Progress {
                    stage: RunStage::Pass {
                        iteration: n,
                        batches_done: done,
                        clamped: pass.clamped,
                        photons,
                        photon_seconds: pass.photon_seconds + t_pass.elapsed().as_secs_f64(),
                        update_seconds: pass.update_seconds,
                    },
                    projection: *proj,
                    report: report.clone(),
                };
                let seconds = *prior_s + clock.elapsed().as_secs_f64();
                writer.write(Some(state_path), &progress, seconds)?;
                if let Some(line) = writer.cadence_note() {
                    note(self.mode, &line);
                }
                last_ck = done;
            }
            if stop {
                world.barrier(); // as in `Running::interrupted`
                return Err(interrupted(&self.dir, writer.seq()));
            }
            Ok(())
        })?;
        stage.finish();
        Ok(traced)
    }

    /// Batches per group of a photon pass: the default of one process (which decides where a
    /// pass can checkpoint); in an MPI job the same on every rank, about as many per rank.
    fn group_batches(&self) -> usize {
        let world = self.world;
        match world.size() {
            1 => 0,
            n => {
                let mine = (2 * rayon::current_num_threads()).max(16) as u64;
                world.max(mine) as usize * n
            }
        }
    }

    /// K_d consistent with the final E_i, the counts, every output, the last checkpoint (rank
    /// 0; the other ranks are done).
    fn finish(&self, mut r: Running) -> Result<Report> {
        if interrupt::agreed() {
            return Err(r.interrupted(&self.state_path, r.stage, false)?);
        }
        if !self.world.is_root() {
            return Ok(r.report);
        }
        let (_, filled) = self.kd_step(&mut r, "final K_d")?;
        let uniform = self.one_colour(&mut r)?;
        r.state.flush()?;
        debug_check(&self.geom, &r.state)?;
        r.report.counts = self.counts(&r, &filled, &uniform);
        if filled.shared_shapes > 0 {
            let line = format!(
                "{} shapes no photo saw took the mean albedo of the seen shapes of their material",
                filled.shared_shapes
            );
            note(self.mode, &line);
        }
        let c = &r.report.counts;
        let coverage = crate::report::summary::Coverage {
            covered: c.covered_texels,
            observed: c.observed_texels,
            visible: c.visible_texels,
            filled: Some(c.filled_texels),
        };
        let (share, fine) = (self.cfg.min_observed_share, self.cfg.fine_geometry);
        r.report.warnings = crate::report::summary::coverage_warning(&coverage, share, fine)
            .into_iter()
            .collect();
        r.report.timings.total = r.elapsed();
        let res = &mut r.report.resources;
        res.memory_budget_mib = self.cfg.memory_budget_mib;
        res.store_bytes = self.geom.data_bytes() + r.state.data_bytes();
        res.checkpoint_bytes = r.writer.bytes_written;
        self.write_outputs(&mut r)?;
        r.checkpoint(&self.state_path, RunStage::Finished)?;
        self.closing_notes(&r);
        Ok(r.report)
    }

    /// Shapes of one colour kept to one colour (`stages::one_colour`), timed.
    #[inline(never)] // a stage entry tools/icount.py measures
    fn one_colour(&self, r: &mut Running) -> Result<UniformStats> {
        let (p, t) = (&self.p, Instant::now());
        let known: Vec<bool> = (p.layout.slots.iter())
            .map(|st| !p.scene.shapes[st.shape].is_reconstructed())
            .collect();
        let uniform = smooth_uniform(
            (&p.layout, &known),
            &self.charts,
            &self.geom,
            &mut r.state,
            (self.cfg.uniform_radius, self.cfg.uniform_tolerance),
            &self.scratch,
        )?;
        r.report.timings.uniform = t.elapsed().as_secs_f64();
        Ok(uniform)
    }

    /// The report's counts at the end of a run.
    fn counts(&self, r: &Running, filled: &Filled, uniform: &UniformStats) -> Counts {
        let (p, proj, before) = (&self.p, &r.proj, &r.report.counts);
        Counts {
            shapes: p.scene.shapes.len(),
            reconstructed_shapes: p
                .scene
                .shapes
                .iter()
                .filter(|s| s.is_reconstructed())
                .count(),
            triangles: p.scene.triangle_count(),
            emitters: p.scene.emitters.len(),
            views: proj.views,
            masked_pixels: proj.masked_pixels,
            tiles: p.layout.tile_count,
            covered_texels: proj.covered_texels,
            observed_texels: proj.observed_texels,
            visible_texels: proj.visible_texels,
            denoised_texels: proj.denoised_texels,
            denoise_sigma_ratio: proj.denoise_sigma_ratio,
            uniform_shapes: uniform.shapes,
            uniform_texels: uniform.texels,
            filled_texels: filled.texels,
            fill_unrelaxed_texels: filled.unrelaxed,
            material_filled_shapes: filled.shared_shapes,
            dense_direct_texels: before.dense_direct_texels,
            caustic_photons: before.caustic_photons,
            direct_first_pass_texels: before.direct_first_pass_texels,
            dense_direct_texels_per_emitter: before.dense_direct_texels_per_emitter.clone(),
            smoothed_direct_texels: before.smoothed_direct_texels,
            lean_gather_points: self.points.get().map_or(0, |p| p.lean_points() as u64),
        }
    }

    /// Every output file, with its progress stage and the fold's notes (one per kind).
    fn write_outputs(&self, r: &mut Running) -> Result<()> {
        let p = &self.p;
        let stage = Stage::after(
            self.mode,
            "outputs",
            output_units(p),
            "texels+pixels",
            progress::SHOW_AFTER,
        );
        write_outputs(
            p,
            self.hits(),
            (&self.geom, &r.state),
            &mut r.report,
            self.out,
            &self.scratch,
            &|k| stage.inc(k),
        )?;
        stage.finish();
        if let Some(line) = r.report.rays.summary(&r.report.timings) {
            note(self.mode, &line);
        }
        for line in crate::report::summary::fold_lines(&r.report.uv_fold) {
            note(self.mode, &line);
        }
        Ok(())
    }

    /// Rays this run's processes cast since this process had cast `before` (a collective:
    /// every process calls it at the same point).
    fn rays_since(&self, before: u64) -> u64 {
        self.world.sum(self.p.accel.rays() - before)
    }

    /// What the run wrote and held: checkpoints, memory, and under MPI the ranks' traffic.
    fn closing_notes(&self, r: &Running) {
        note(
            self.mode,
            &format!(
                "checkpoints: {:.1} MB written in {:.2} s; peak memory {:.0} MiB (budget {} MiB \
                 for per-texel data); working state on disk {:.1} GB",
                r.writer.bytes_written as f64 / 1e6,
                r.writer.seconds,
                crate::base::mem::peak_mib(),
                self.cfg.memory_budget_mib,
                r.report.resources.store_bytes as f64 / 1e9
            ),
        );
        if self.world.size() > 1 {
            let t = self.world.traffic();
            note(
                self.mode,
                &format!(
                    "{} ranks; rank 0 exchanged {:.1} MB with the others, {:.2} s inside \
                     collective operations (waiting for them included)",
                    self.world.size(),
                    t.bytes as f64 / 1e6,
                    t.seconds
                ),
            );
        }
    }
}

/// The scratch directory of a run (`<state dir>/scratch`, emptied of an earlier attempt's
/// leftovers), its textures a quarter of `budget` each.
fn open_scratch(state_dir: &Path, budget: u64) -> Result<Scratch> {
    let dir = state_dir.join("scratch");
    if dir.exists() {
        std::fs::remove_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    }
    fsio::create_dir(&dir)?;
    Ok(Scratch::new(dir, budget / 4))
}

/// The solver iteration key of the caustic pass's photons (the solver's passes count from 0).
const CAUSTIC_PASS: u64 = u64::MAX;

/// The caustic pass traces the solver's photon budget over this (25 per covered texel by
/// default): at that count its noise is not what limits mirror-cbox's walls, and four or
/// sixteen times the photons cost three or fourteen times the pass's time for almost no gain.
const CAUSTIC_SHARE: u64 = 4;

/// The error of a run stopped by a signal after checkpoint `seq` was written in `dir`.
fn interrupted(dir: &Path, seq: u64) -> Error {
    Error::Interrupted(format!(
        "checkpoint {seq} written in {}; run the same command with --resume to continue",
        dir.display()
    ))
}

/// What an iteration's E_i estimate cost.
#[derive(Debug, Clone, Copy, Default)]
struct Estimate {
    photons: u64,
    photon_seconds: f64,
    gather_rays: u64,
    gather_cached_hits: u64,
    gather_seconds: f64,
}

/// Where an iteration's photon pass stands: from a checkpoint inside it, or fresh.
#[derive(Debug, Clone, Copy)]
struct PassResume {
    batches_done: u64,
    clamped: u64,
    photon_seconds: f64,
    update_seconds: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pass(iteration: u32, batches_done: u64, photons: u64) -> RunStage {
        RunStage::Pass {
            iteration,
            batches_done,
            clamped: 0,
            photons,
            photon_seconds: 0.0,
            update_seconds: 0.0,
        }
    }

    #[test]
    fn a_checkpoint_stage_these_settings_cannot_reach_is_corrupt() {
        let mut cfg = Config::for_scene("s.xml".into());
        cfg.method = Method::Photons;
        cfg.photons = 1000;
        cfg.batch_size = 100;
        cfg.iterations = 4;
        let m = Path::new("out/checkpoint/progress.kdm");
        let ok = |s: RunStage| check_stage(&s, &cfg, m).is_ok();
        assert!(ok(pass(3, 10, 1000)));
        assert!(ok(RunStage::Iterations {
            iterations_done: 4,
            stopped: true
        }));
        assert!(!ok(pass(4, 0, 0)), "iteration beyond the last");
        assert!(!ok(pass(0, 11, 1000)), "more batches than a pass has");
        assert!(!ok(pass(0, 1, 1001)), "more photons than a pass has");
        assert!(!ok(RunStage::Iterations {
            iterations_done: 5,
            stopped: false
        }));
        let e = check_stage(&pass(9, 0, 0), &cfg, m).unwrap_err();
        assert!(matches!(e, Error::Corrupt { .. }), "{e}");
        assert!(e.to_string().contains("progress.kdm"), "{e}");
        cfg.method = Method::Gather;
        assert!(
            check_stage(&pass(0, 1, 100), &cfg, m).is_err(),
            "a photon pass in a gather run"
        );
    }
}
