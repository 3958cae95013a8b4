//! The `kdmap` command line: parses arguments (clap), runs one subcommand, and turns any
//! error into a single `error: ...` line on stderr with the exit code of its kind
//! (`kdmap::base::error::exit`; clap's usage errors exit with 2). Results go to stdout (text, or a
//! JSON document with `--json`), progress and notes to stderr in the form `--progress` and
//! `--quiet` choose; only this file and `progress` talk to the terminal. A closed stdout
//! (`kdmap inspect ... | head`) ends the output quietly with exit code 0. SIGINT / SIGTERM
//! stop `reconstruct` and `project` at a safe point (`kdmap::base::interrupt`), exit code 130.
//!
//! Started by an MPI launcher (`mpirun -np N kdmap ...`, a build with `--features mpi`), every
//! rank runs the command (`kdmap::base::comm`); rank 0 prints results, progress and errors, the
//! other ranks only errors of their own, prefixed by their rank.

use clap::{Parser, Subcommand, ValueEnum};
use glam::Vec3;
use kdmap::base::progress::Mode;
use kdmap::config::{Config, Method, Overrides, Preset};
use kdmap::pipeline::{self, RunStage, Start};
use kdmap::scene::{luminance, Emitter, Scene, Sides};
use kdmap::{Error, Result};
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Parser, Debug)]
#[command(
    name = "kdmap",
    version,
    about = "Recover diffuse albedo (Kd) textures from HDR photos of a known scene"
)]
struct Cli {
    /// No progress and no notes on stderr (errors and warnings are still printed).
    #[arg(long, global = true, conflicts_with = "progress")]
    quiet: bool,
    /// How progress goes to stderr: auto (bars on a terminal, plain lines otherwise),
    /// always (bars), never, json (one JSON object per line: progress, notes, errors).
    #[arg(long, global = true, value_enum, default_value_t = Progress::Auto)]
    progress: Progress,
    #[command(subcommand)]
    command: Command,
}

/// The values of `--progress`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Progress {
    Auto,
    Always,
    Never,
    Json,
}

impl Cli {
    fn mode(&self) -> Mode {
        match (self.quiet, self.progress) {
            (true, _) => Mode::Quiet,
            (_, Progress::Auto) => Mode::Auto,
            (_, Progress::Always) => Mode::Always,
            (_, Progress::Never) => Mode::Never,
            (_, Progress::Json) => Mode::Json,
        }
    }
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Load a Mitsuba 3 or glTF 2.0 scene and summarize its shapes, emitters and sensors, the texel
    /// density a run would choose per shape, and the disk and memory it would need.
    Inspect {
        /// The scene file (Mitsuba 3 XML, or glTF 2.0 `.gltf`/`.glb`) or a run config (TOML).
        scene: PathBuf,
        /// Print a JSON document instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Recover the albedo textures: the whole method, steps 1-9, and every output.
    Reconstruct {
        /// A Mitsuba 3 or glTF 2.0 scene (photos in `<scene dir>/images/<sensor id>.exr|png|jpg`) or a run config (TOML).
        input: PathBuf,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
        /// Start from a named preset: default, fast (a quick look) or paper (the published
        /// method); the run config and the other flags apply over it.
        #[arg(long)]
        preset: Option<Preset>,
        /// How E_i is estimated: gather (from the observed radiance) or photons (the paper's
        /// light tracing).
        #[arg(long)]
        method: Option<Method>,
        /// Light paths (photons) per iteration (method photons).
        #[arg(long)]
        photons: Option<u64>,
        /// Most solver iterations.
        #[arg(long)]
        iterations: Option<u32>,
        /// Seed of every random number.
        #[arg(long)]
        seed: Option<u64>,
        /// Worker threads (0 = all cores); never changes the result.
        #[arg(long)]
        threads: Option<usize>,
        /// Continue from `<out>/checkpoint`.
        #[arg(long)]
        resume: bool,
        /// Exit with code 3 when the run ends with a warning (its outputs are still written).
        #[arg(long)]
        strict: bool,
    },
    /// Print where a run's checkpoint stands: stage, iteration, batch, errors so far, time.
    InspectCheckpoint {
        /// The run's output directory (the one given to `reconstruct --out`).
        out: PathBuf,
        /// Print a JSON document instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Score a finished run against the true albedo (a Mitsuba `truth.xml`): per shape, the
    /// mean relative and relative L1 albedo error over observed texels; writes
    /// `<out>/accuracy/` (accuracy.json, truth and difference PNGs).
    Accuracy {
        /// The run's output directory.
        out: PathBuf,
        /// The Mitsuba scene holding the true reflectances.
        truth: PathBuf,
        /// Print the scores as a JSON document (what accuracy.json holds) instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Write `<out>/report.html` again from an output directory (after `kdmap accuracy`, or
    /// to restore it): the page a user opens in a browser, offline, with the run's summary,
    /// views, maps, plots and a 3D view.
    Report {
        /// The run's output directory.
        out: PathBuf,
    },
    /// Print the run-config keys: `--defaults` as an annotated TOML file holding every default
    /// (a config to start from), `--markdown` as the reference page `docs/config.md`.
    Config {
        /// The annotated default run config (TOML); the default output.
        #[arg(long, conflicts_with = "markdown")]
        defaults: bool,
        /// The key reference as Markdown.
        #[arg(long)]
        markdown: bool,
    },
    /// Steps 1-2 of the method on their own: unwrap the atlas, project every photo onto it and
    /// write the luminance and coverage maps to `<out>/maps/` (with PNG previews).
    Project {
        /// A Mitsuba 3 or glTF 2.0 scene (photos in `<scene dir>/images/<sensor id>.exr|png|jpg`) or a run config (TOML).
        input: PathBuf,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
        /// Start from a named preset (default, fast, paper).
        #[arg(long)]
        preset: Option<Preset>,
        /// Worker threads (0 = all cores); never changes the result.
        #[arg(long)]
        threads: Option<usize>,
        /// Exit with code 3 when the projection ends with a warning (its maps are still
        /// written).
        #[arg(long)]
        strict: bool,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let job = match kdmap::base::comm::init() {
        Ok(job) => job,
        Err(msg) => {
            let _ = writeln!(std::io::stderr(), "error: {msg}");
            return ExitCode::from(kdmap::base::error::exit::CONFIG);
        }
    };
    let world = kdmap::base::comm::world();
    let mode = match world.is_root() {
        true => cli.mode(),
        false => Mode::Quiet,
    };
    let e = match run(cli.command, mode) {
        Ok(()) => return ExitCode::SUCCESS,
        Err(e) => e,
    };
    // Another rank's error (rank 0 prints it) or an agreed stop: nothing more to say here.
    let said_elsewhere = matches!(e, Error::Rank { .. } | Error::Interrupted(_));
    if world.is_root() || !said_elsewhere {
        print_error(&e, mode, world.rank());
    }
    // An agreed stop: no rank exits before rank 0 has said so. The first rank to exit with
    // 130 makes `mpirun` signal the others, and a second signal ends rank 0 at once.
    if matches!(e, Error::Interrupted(_)) {
        world.barrier();
    }
    match world.size() {
        1 => ExitCode::from(e.exit_code()),
        _ => job.exit(e.exit_code()),
    }
}

/// The one line of an error on stderr (as JSON with `--progress json`), naming the rank
/// unless it is rank 0.
fn print_error(e: &Error, mode: Mode, rank: usize) {
    let line = match (e, rank) {
        (Error::Interrupted(_), _) => e.to_string(),
        (_, 0) => format!("error: {e}"),
        (_, r) => format!("error: rank {r}: {e}"),
    };
    let line = match mode {
        Mode::Json => serde_json::json!({"error": line, "exit_code": e.exit_code()}).to_string(),
        _ => line,
    };
    let _ = writeln!(std::io::stderr(), "{line}");
}

/// A JSON document for stdout, pretty-printed, with a final newline.
fn json_text(v: &impl serde::Serialize) -> Result<String> {
    serde_json::to_string_pretty(v)
        .map(|t| t + "\n")
        .map_err(|e| Error::internal(format!("JSON output: {e}")))
}

/// Write `text` to stdout. A closed pipe (`kdmap inspect ... | head`) is not an error: the
/// reader has what it wanted.
fn emit(text: &str) -> Result<()> {
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(Error::io("<stdout>", e)),
        _ => Ok(()),
    }
}

fn run(command: Command, mode: Mode) -> Result<()> {
    let root = kdmap::base::comm::world().is_root();
    match command {
        Command::Reconstruct {
            input,
            out,
            preset,
            method,
            photons,
            iterations,
            seed,
            threads,
            resume,
            strict,
        } => {
            let ov = Overrides {
                preset,
                method,
                photons,
                iterations,
                seed,
                threads,
            };
            kdmap::base::interrupt::install()?;
            reconstruct(&input, &out, &ov, resume, mode).and_then(|w| close(&w, strict, &out, mode))
        }
        Command::Project {
            input,
            out,
            preset,
            threads,
            strict,
        } => {
            kdmap::base::interrupt::install()?;
            project(&input, &out, preset, threads, mode).and_then(|w| close(&w, strict, &out, mode))
        }
        // the read-only commands answer once, on rank 0
        _ if !root => Ok(()),
        Command::Inspect { scene, json } => inspect(&scene, json),
        Command::InspectCheckpoint { out, json } => inspect_checkpoint(&out, json, mode),
        Command::Accuracy { out, truth, json } => accuracy(&out, &truth, json),
        Command::Report { out } => {
            kdmap::output::page::rebuild(&out)?;
            emit(&format!(
                "{}\n",
                out.join(kdmap::output::page::PAGE).display()
            ))
        }
        Command::Config { markdown, .. } => emit(&if markdown {
            kdmap::config::keys::markdown()
        } else {
            kdmap::config::keys::default_toml()
        }),
    }
}

/// A worker pool of `threads` threads (0 = all cores) for the run.
fn pool(threads: usize) -> Result<rayon::ThreadPool> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| Error::internal(format!("starting worker threads: {e}")))
}

/// The end of a run that wrote its outputs: its warnings on stderr, then, with `strict` and a
/// warning, the error of exit code 3.
fn close(warnings: &[String], strict: bool, out: &Path, mode: Mode) -> Result<()> {
    for w in warnings {
        kdmap::base::progress::warning(mode, w);
    }
    match (strict, warnings.len()) {
        (false, _) | (true, 0) => Ok(()),
        (true, n) => Err(Error::Strict(format!(
            "the run ended with {n} warning(s); its outputs are in {}",
            out.display()
        ))),
    }
}

/// Runs the method; returns the run's warnings (none on ranks other than 0).
fn reconstruct(
    input: &Path,
    out: &Path,
    ov: &Overrides,
    resume: bool,
    mode: Mode,
) -> Result<Vec<String>> {
    let cfg = kdmap::base::comm::world().agree(Config::load(input, ov))?;
    let (report, start) =
        pool(cfg.threads)?.install(|| pipeline::reconstruct_resumable(&cfg, out, mode, resume))?;
    if !kdmap::base::comm::world().is_root() {
        return Ok(Vec::new());
    }
    if start == Start::AlreadyFinished {
        emit(&format!(
            "already finished ({} iterations, {}): nothing to do; results: {}\n",
            report.iterations.len(),
            report.stopped_by,
            out.display()
        ))?;
        return Ok(report.warnings);
    }
    let last = report.iterations.last();
    emit(&format!(
        "reconstructed {} shapes from {} views in {} iterations ({}): relative error rms {:.3}%, max {:.2}%; {:.1} s\nresults: {}\n",
        report.counts.reconstructed_shapes,
        report.counts.views,
        report.iterations.len(),
        report.stopped_by,
        100.0 * last.map_or(0.0, |i| i.rms_rel_error),
        100.0 * last.map_or(0.0, |i| i.max_rel_error),
        report.timings.total,
        out.display()
    ))?;
    Ok(report.warnings)
}

fn accuracy(out: &Path, truth: &Path, json: bool) -> Result<()> {
    let rep = kdmap::accuracy::score_run(out, truth)?;
    // the page shows the scores: made again where a run wrote one
    if out.join(kdmap::output::page::PAGE).is_file() {
        kdmap::output::page::rebuild(out)?;
    }
    if json {
        return emit(&json_text(&rep)?);
    }
    let mut t = String::new();
    let _ = writeln!(
        t,
        "{:<16} {:>8} {:>10} {:>10}  mean K_d vs true",
        "shape", "texels", "mean rel", "rel L1"
    );
    for a in &rep.shapes {
        let _ = writeln!(
            t,
            "{:<16} {:>8} {:>9.2}% {:>9.2}%  [{:.4}, {:.4}, {:.4}] vs [{:.4}, {:.4}, {:.4}]",
            a.shape,
            a.texels,
            100.0 * a.mean_rel_error,
            100.0 * a.rel_l1_error,
            a.mean_kd[0],
            a.mean_kd[1],
            a.mean_kd[2],
            a.mean_truth[0],
            a.mean_truth[1],
            a.mean_truth[2]
        );
    }
    let _ = writeln!(
        t,
        "scene: mean relative albedo error {:.2}%, relative L1 {:.2}% ({})",
        100.0 * rep.mean_rel_error,
        100.0 * rep.rel_l1_error,
        out.join("accuracy").join("accuracy.json").display()
    );
    write_calibration(&mut t, &rep.calibration);
    emit(&t)
}

/// The calibration of the predicted K_d standard errors, one line per populated bin.
fn write_calibration(t: &mut String, c: &kdmap::stages::confidence::Calibration) {
    if c.texels == 0 {
        return;
    }
    let _ = writeln!(
        t,
        "confidence: {:.0}% of texels within one predicted standard error of K_d (68% if calibrated), {:.0}% within two (95%)",
        100.0 * c.within_one,
        100.0 * c.within_two
    );
    for b in c.bins.iter().filter(|b| b.texels > 0) {
        let hi =
            b.hi.map_or("inf".to_string(), |h| format!("{:.1}%", 100.0 * h));
        let _ = writeln!(
            t,
            "  predicted {:>4.1}%..{:<6} {:>8} texels, mean {:>6.2}%: within one {:>3.0}%, within two {:>3.0}%",
            100.0 * b.lo,
            hi,
            b.texels,
            100.0 * b.mean_predicted,
            100.0 * b.within_one,
            100.0 * b.within_two
        );
    }
}

fn inspect_checkpoint(out: &Path, json: bool, mode: Mode) -> Result<()> {
    let (m, notes) = pipeline::load_checkpoint(out);
    for n in &notes {
        kdmap::base::progress::note(mode, n);
    }
    let dir = kdmap::atlas::state_dir(out);
    let Some(m) = m else {
        return Err(Error::input(&dir, "no usable checkpoint"));
    };
    let (progress, s) = (&m.payload, &m.payload.report.settings);
    let stage = stage_text(&m.payload);
    if json {
        let doc = serde_json::json!({
            "dir": dir,
            "checkpoint": m.seq,
            "inputs_hash": format!("{:016x}", m.inputs_hash),
            "stage": progress.stage,
            "stage_text": stage,
            "iterations_planned": s.iterations,
            "photons_per_iteration": s.photons,
            "iterations": progress.report.iterations,
            "stopped_by": progress.report.stopped_by,
            "seconds": m.seconds,
            "notes": notes,
        });
        return emit(&json_text(&doc)?);
    }
    let mut t = String::new();
    let _ = writeln!(t, "checkpoint {} in {}", m.seq, dir.display());
    let _ = writeln!(t, "inputs hash {:016x}", m.inputs_hash);
    let _ = writeln!(t, "stage: {stage}");
    for it in &progress.report.iterations {
        let _ = writeln!(
            t,
            "  iteration {}: relative error rms {:.3}%, mean {:.3}%, max {:.2}%",
            it.iteration + 1,
            100.0 * it.rms_rel_error,
            100.0 * it.mean_rel_error,
            100.0 * it.max_rel_error
        );
    }
    let _ = writeln!(t, "time spent: {:.1} s", m.seconds);
    emit(&t)
}

/// Where a checkpointed run stands, in words.
fn stage_text(progress: &pipeline::Progress) -> String {
    let s = &progress.report.settings;
    match progress.stage {
        RunStage::Direct => "projection and direct light done; iteration 1 not begun".to_string(),
        RunStage::Pass {
            iteration,
            batches_done,
            photons,
            ..
        } => format!(
            "iteration {}/{}: photon pass at batch {batches_done}/{} ({photons} of {} photons)",
            iteration + 1,
            s.iterations,
            s.photons.div_ceil(u64::from(s.batch_size.max(1))),
            s.photons
        ),
        RunStage::Iterations {
            iterations_done,
            stopped,
        } => format!(
            "{iterations_done}/{} iterations done{}",
            s.iterations,
            if stopped {
                "; solver stopped, outputs pending"
            } else {
                ""
            }
        ),
        RunStage::Finished => format!("finished ({})", progress.report.stopped_by),
    }
}

/// Steps 1-2; returns the projection's warnings (none on ranks other than 0).
fn project(
    input: &Path,
    out: &Path,
    preset: Option<Preset>,
    threads: Option<usize>,
    mode: Mode,
) -> Result<Vec<String>> {
    let ov = Overrides {
        preset,
        threads,
        ..Default::default()
    };
    let world = kdmap::base::comm::world();
    let cfg = world.agree(Config::load(input, &ov))?;
    let (p, stats) = pool(cfg.threads)?.install(|| pipeline::run_projection(&cfg, out, mode))?;
    if !world.is_root() {
        return Ok(Vec::new());
    }
    emit(&format!(
        "projected {} views onto {} shapes: {} of {} surface texels observed ({:.1}%; {} visible from a camera), {} pixels masked, {:.2} s\nmaps: {}\n",
        stats.views,
        p.layout.slots.len(),
        stats.observed_texels,
        stats.covered_texels,
        100.0 * stats.observed_texels as f64 / stats.covered_texels.max(1) as f64,
        stats.visible_texels,
        stats.masked_pixels,
        stats.seconds,
        out.join("maps").display()
    ))?;
    let coverage = kdmap::report::summary::Coverage {
        covered: stats.covered_texels,
        observed: stats.observed_texels,
        visible: stats.visible_texels,
        filled: None,
    };
    let (share, fine) = (cfg.min_observed_share, cfg.fine_geometry);
    let w = kdmap::report::summary::coverage_warning(&coverage, share, fine);
    Ok(w.into_iter().collect())
}

fn v3(v: Vec3) -> String {
    format!("({}, {}, {})", v.x, v.y, v.z)
}

fn v3p(v: Vec3) -> String {
    format!("({:.4}, {:.4}, {:.4})", v.x, v.y, v.z)
}

/// An emitter's kind and parameters, for `inspect --json`.
fn emitter_json(scene: &Scene, e: &Emitter) -> serde_json::Value {
    use serde_json::json;
    match e {
        Emitter::Point {
            position,
            intensity,
        } => json!({"type": "point", "position": position, "intensity": intensity}),
        Emitter::Spot {
            position,
            axis,
            intensity,
            cutoff,
            beam_width,
            ..
        } => json!({
            "type": "spot", "position": position, "axis": axis, "intensity": intensity,
            "cutoff_deg": cutoff.to_degrees(), "beam_width_deg": beam_width.to_degrees(),
        }),
        Emitter::Directional {
            direction,
            irradiance,
        } => json!({"type": "directional", "direction": direction, "irradiance": irradiance}),
        Emitter::Area { shape, radiance } => {
            let id = scene.shapes.get(*shape).map(|s| s.id.as_str());
            json!({"type": "area", "shape": id, "radiance": radiance})
        }
        Emitter::Environment(env) => match &env.file {
            Some(f) => json!({
                "type": "envmap", "file": f, "width": env.width, "height": env.height,
                "scale": env.scale, "mean_radiance": env.mean_radiance(),
            }),
            None => json!({"type": "constant", "radiance": env.radiance,
                "mean_radiance": env.mean_radiance()}),
        },
    }
}

/// The document printed by `inspect --json`: what [`summary`] says, as data.
fn summary_json(scene: &Scene) -> serde_json::Value {
    use serde_json::json;
    let shapes: Vec<_> = scene
        .shapes
        .iter()
        .map(|sh| {
            json!({
                "id": sh.id,
                "type": sh.kind,
                "triangles": sh.mesh.triangles.len(),
                "area": sh.mesh.area(),
                "sides": match sh.sides { Sides::Front => "front", Sides::Both => "both" },
                "emission": sh.emission,
                "known_material": sh.known().map(|k| k.plugin.clone()),
                "reconstructed": sh.is_reconstructed(),
            })
        })
        .collect();
    let emitters: Vec<_> = scene
        .emitters
        .iter()
        .map(|e| {
            let p = kdmap::physics::light::emitter_power(scene, e);
            let mut v = emitter_json(scene, e);
            v["power"] = json!(p);
            v["power_luminance"] = json!(luminance(p));
            v
        })
        .collect();
    let sensors: Vec<_> = scene
        .sensors
        .iter()
        .map(|c| {
            let image = sensor_photo(scene, c);
            let mut v = json!({
                "id": c.id,
                "width": c.width,
                "height": c.height,
                "fov_deg": c.fov,
                "fov_axis": format!("{:?}", c.fov_axis).to_lowercase(),
                "position": c.to_world.w_axis.truncate(),
                "image": image,
                "image_present": image.is_file(),
            });
            if let Some(l) = &c.lens {
                v["colmap_camera"] = json!({"model": l.model.name(), "params": l.params});
            }
            v
        })
        .collect();
    json!({
        "scene": scene.path,
        "triangles": scene.triangle_count(),
        "shapes": shapes,
        "emitters": emitters,
        "sensors": sensors,
    })
}

/// The photo of sensor `id` in the scene's `images/` (`<id>.exr` if it has none, or several).
fn photo_of(images: &Path, id: &str) -> PathBuf {
    let found = kdmap::scene::photos::find(images, id).ok().flatten();
    found.unwrap_or_else(|| images.join(format!("{id}.exr")))
}

/// The human-readable summary printed by `inspect`.
fn inspect(input: &Path, json: bool) -> Result<()> {
    let cfg = Config::load(input, &Overrides::default())?;
    let scene = kdmap::scene::load(&cfg)?;
    let plan = plan_run(&cfg, &scene);
    if json {
        let mut doc = summary_json(&scene);
        if let Some(dir) = &cfg.colmap {
            doc["colmap"] = serde_json::json!({"model": dir, "to_world": cfg.colmap_to_world});
        }
        match &plan {
            Ok((p, n)) => {
                doc["atlas"] = serde_json::to_value(p).unwrap_or_default();
                doc["needs"] = serde_json::to_value(n).unwrap_or_default();
            }
            Err(e) => doc["atlas"] = serde_json::json!({ "not_planned": e }),
        }
        return emit(&json_text(&doc)?);
    }
    let mut text = summary(&scene);
    text.push_str(&colmap_text(&cfg));
    text.push_str(&plan_text(&cfg, &scene, &plan));
    emit(&text)
}

type RunPlan = std::result::Result<
    (
        kdmap::atlas::uv::DensityPlan,
        kdmap::atlas::uv::density::Needs,
    ),
    String,
>;

/// The texel density per shape a run with `cfg` would choose, and what the run would need;
/// an error text if the run could not start (no photos).
fn plan_run(cfg: &Config, scene: &Scene) -> RunPlan {
    let views =
        kdmap::atlas::context::match_views(scene, cfg, Mode::Quiet).map_err(|e| e.to_string())?;
    let accel = kdmap::physics::accel::Accel::build(scene);
    let plan = kdmap::atlas::context::plan_density(cfg, scene, &accel, &views);
    let sensors: Vec<usize> = views.iter().map(|v| v.0).collect();
    let pixels = kdmap::atlas::uv::density::photo_pixels(scene, &sensors);
    let gather = match cfg.method {
        kdmap::config::Method::Gather => {
            let spacing = kdmap::stages::indirect::gather::shape_spacing(cfg, scene);
            scene
                .shapes
                .iter()
                .zip(spacing)
                .filter(|(s, _)| s.in_atlas())
                .map(|(s, d)| {
                    kdmap::atlas::uv::density::gather_bytes(s.mesh.area(), d, cfg.gather_rays)
                })
                .sum::<u64>()
                // the ray cache keeps hits within its limit (the rest are cast again)
                .min(kdmap::stages::indirect::gather::budget::cache_bytes(
                    cfg.memory_budget_mib,
                ))
        }
        kdmap::config::Method::Photons => 0,
    };
    let budget = cfg.memory_budget_mib << 20;
    let needs = kdmap::atlas::uv::density::needs(scene, &plan, pixels, (budget, gather));
    Ok((plan, needs))
}

fn plan_text(cfg: &Config, scene: &Scene, plan: &RunPlan) -> String {
    let mut s = String::new();
    let (plan, n) = match plan {
        Ok(p) => p,
        Err(e) => {
            let _ = writeln!(s, "atlas: not planned ({e})");
            return s;
        }
    };
    let how = match cfg.atlas.texels_per_unit.per_unit() {
        Some(d) => format!("texels_per_unit = {d}"),
        None => format!("auto, budget {} texels", plan.budget),
    };
    let _ = writeln!(
        s,
        "atlas ({how}): about {} surface texels",
        plan.estimated_texels
    );
    for (sh, d) in scene.shapes.iter().zip(&plan.shapes) {
        let Some(d) = d else { continue };
        // a fixed density looks at no photo
        let fine = match (cfg.atlas.texels_per_unit.per_unit(), d.finest_footprint) {
            (Some(_), _) => String::new(),
            (None, Some(f)) => format!("  finest photo {f:.4} units/pixel"),
            (None, None) => "  finest photo unseen".to_string(),
        };
        let lim = d
            .limited_by
            .as_deref()
            .map_or(String::new(), |l| format!("  limited by {l}"));
        let _ = writeln!(
            s,
            "  {:<16} {:>8.1} texels/unit{fine}{lim}{}",
            sh.id,
            d.texels_per_unit,
            d.level_shares(&sh.mesh)
                .map_or(String::new(), |s| level_text(&s))
        );
    }
    for note in &plan.notes {
        let _ = writeln!(s, "  note: {note}");
    }
    let _ = writeln!(
        s,
        "a run needs about {:.0} MB of disk ({} stored texels) and {:.0} MB of memory \
         (estimates)",
        n.disk_bytes as f64 / 1e6,
        n.store_texels,
        n.memory_bytes as f64 / 1e6
    );
    s
}

/// How a shape's area spreads over its density levels: `area at 1, 1/2, 1/4, 1/8 of it: 40%
/// 30% 20% 10%`.
fn level_text(shares: &[f64]) -> String {
    let pct: Vec<String> = shares
        .iter()
        .map(|a| format!("{:.0}%", 100.0 * a))
        .collect();
    format!(
        "\n  {:<16} area at 1, 1/2, 1/4, 1/8 of it: {}",
        "",
        pct.join(" ")
    )
}

fn summary(scene: &Scene) -> String {
    let mut s = String::new();
    // Writing into a String cannot fail.
    let _ = writeln!(s, "scene {}", scene.path.display());
    let _ = writeln!(
        s,
        "shapes: {} ({} triangles)",
        scene.shapes.len(),
        scene.triangle_count()
    );
    for sh in &scene.shapes {
        s.push_str(&shape_line(sh));
    }
    let _ = writeln!(s, "emitters: {}", scene.emitters.len());
    for e in &scene.emitters {
        let p = kdmap::physics::light::emitter_power(scene, e);
        let what = emitter_text(scene, e);
        let _ = writeln!(
            s,
            "  {what}  power {} (luminance {:.4})",
            v3p(p),
            luminance(p)
        );
    }
    let _ = writeln!(s, "sensors: {}", scene.sensors.len());
    for c in &scene.sensors {
        let image = sensor_photo(scene, c);
        let state = if image.is_file() {
            "present"
        } else {
            "missing"
        };
        let _ = writeln!(
            s,
            "  {:<16} {}x{}  fov {} deg ({})  at {}  image {}: {state}",
            c.id,
            c.width,
            c.height,
            c.fov,
            format!("{:?}", c.fov_axis).to_lowercase(),
            v3(c.to_world.w_axis.truncate()),
            image.display()
        );
        if let Some(l) = &c.lens {
            let _ = writeln!(
                s,
                "  {:<16} COLMAP {}: {}",
                "",
                l.model.name(),
                l.describe()
            );
        }
    }
    s
}

/// A sensor's photo when the run config names none: the one the scene names (a COLMAP
/// image's), else `<scene dir>/images/<id>.exr`.
fn sensor_photo(scene: &Scene, c: &kdmap::scene::Sensor) -> PathBuf {
    let images = scene.dir().join("images");
    (c.photo.clone()).unwrap_or_else(|| photo_of(&images, &c.id))
}

/// Where the sensors came from when a COLMAP model stands for them: its directory and
/// format, and the similarity into the scene's frame.
fn colmap_text(cfg: &Config) -> String {
    let Some(dir) = &cfg.colmap else {
        return String::new();
    };
    let format = match kdmap::scene::colmap::model_files(dir) {
        Ok((kdmap::scene::colmap::Format::Text, ..)) => "text",
        Ok(_) => "binary",
        Err(_) => "?",
    };
    let sim = match &cfg.colmap_to_world {
        Some(m) => match kdmap::config::Similarity::from_rows(m) {
            Ok(s) => format!(
                "to_world: scale {}, translation {:?}",
                s.scale,
                s.translation.to_array()
            ),
            Err(e) => e,
        },
        None => "to_world: identity".to_string(),
    };
    format!(
        "sensors from the COLMAP {format} model {} ({sim})\n",
        dir.display()
    )
}

/// One shape's line of the summary.
fn shape_line(sh: &kdmap::scene::Shape) -> String {
    let sides = match sh.sides {
        Sides::Front => "front",
        Sides::Both => "both",
    };
    let mut s = format!(
        "  {:<16} {:<9} {:>8} triangles  area {:>10.4}  sides {:<5}",
        sh.id,
        sh.kind,
        sh.mesh.triangles.len(),
        sh.mesh.area(),
        sides
    );
    if let Some(l) = sh.emission {
        let _ = write!(s, "  emits radiance {}", v3(l));
    }
    if let Some(k) = sh.known() {
        let _ = write!(s, "  known material ({}): not reconstructed", k.plugin);
    }
    s.push('\n');
    s
}

/// What an emitter is, where, and how strong, in one phrase.
fn emitter_text(scene: &Scene, e: &Emitter) -> String {
    match e {
        Emitter::Point {
            position,
            intensity,
        } => format!("point at {} intensity {}", v3(*position), v3(*intensity)),
        Emitter::Spot {
            position,
            axis,
            intensity,
            cutoff,
            beam_width,
            ..
        } => format!(
            "spot at {} axis {} intensity {} cutoff {:.3} deg beam_width {:.3} deg",
            v3(*position),
            v3p(*axis),
            v3(*intensity),
            cutoff.to_degrees(),
            beam_width.to_degrees()
        ),
        Emitter::Directional {
            direction,
            irradiance,
        } => format!(
            "directional direction {} irradiance {}",
            v3p(*direction),
            v3(*irradiance)
        ),
        Emitter::Area { shape, radiance } => {
            let id = scene.shapes.get(*shape).map_or("?", |s| s.id.as_str());
            format!("area on '{id}' radiance {}", v3(*radiance))
        }
        Emitter::Environment(env) => match &env.file {
            Some(f) => format!(
                "envmap {} ({}x{}, scale {}) mean radiance {}",
                f.display(),
                env.width,
                env.height,
                env.scale,
                v3(env.mean_radiance())
            ),
            None => format!("constant radiance {}", v3(env.radiance)),
        },
    }
}
