//! The `kdmap` command line: parses arguments (clap), runs one subcommand, and turns any
//! error into a single `error: ...` line on stderr with exit code 1 (clap's usage errors exit
//! with 2). Library code never prints; only this file talks to the terminal.

use anyhow::Context;
use clap::{Parser, Subcommand};
use glam::Vec3;
use kdmap::scene::{luminance, mitsuba, Emitter, Scene, Sides};
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
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Load a Mitsuba 3 scene and summarize its shapes, emitters and sensors.
    Inspect {
        /// The scene file (Mitsuba 3 XML).
        scene: PathBuf,
    },
    /// Recover the albedo textures: the whole method, steps 1-9, and every output.
    Reconstruct {
        /// A Mitsuba 3 scene (photos in `<scene dir>/images/<sensor id>.exr`) or a run config (TOML).
        input: PathBuf,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
        /// Light paths (photons) per iteration.
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
    },
    /// Print where a run's checkpoint stands: stage, iteration, batch, errors so far, time.
    InspectCheckpoint {
        /// The run's output directory (the one given to `reconstruct --out`).
        out: PathBuf,
    },
    /// Score a finished run against the true albedo (a Mitsuba `truth.xml`): per shape, the
    /// mean relative and relative L1 albedo error over observed texels; writes
    /// `<out>/accuracy/` (accuracy.json, truth and difference PNGs).
    Accuracy {
        /// The run's output directory.
        out: PathBuf,
        /// The Mitsuba scene holding the true reflectances.
        truth: PathBuf,
    },
    /// Steps 1-2 of the method on their own: unwrap the atlas, project every photo onto it and
    /// write the luminance and coverage maps to `<out>/maps/` (with PNG previews).
    Project {
        /// A Mitsuba 3 scene (photos in `<scene dir>/images/<sensor id>.exr`) or a run config (TOML).
        input: PathBuf,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
        /// Worker threads (0 = all cores); never changes the result.
        #[arg(long)]
        threads: Option<usize>,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli.command) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            let _ = writeln!(std::io::stderr(), "error: {}", one_line(&e));
            ExitCode::from(1)
        }
    }
}

/// The error and its causes joined by ": " on one line, skipping a cause whose text the
/// message already holds (our I/O errors print their source themselves).
fn one_line(e: &anyhow::Error) -> String {
    let mut msg = String::new();
    for cause in e.chain() {
        let t = cause.to_string();
        if !msg.contains(&t) {
            if !msg.is_empty() {
                msg.push_str(": ");
            }
            msg.push_str(&t);
        }
    }
    msg.replace(['\n', '\r'], " ")
}

fn run(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Inspect { scene } => inspect(&scene),
        Command::Reconstruct {
            input,
            out,
            photons,
            iterations,
            seed,
            threads,
            resume,
        } => {
            let ov = kdmap::config::Overrides {
                photons,
                iterations,
                seed,
                threads,
            };
            reconstruct(&input, &out, &ov, resume)
        }
        Command::Project {
            input,
            out,
            threads,
        } => project(&input, &out, threads),
        Command::InspectCheckpoint { out } => inspect_checkpoint(&out),
        Command::Accuracy { out, truth } => accuracy(&out, &truth),
    }
}

fn inspect(path: &Path) -> anyhow::Result<()> {
    let scene = mitsuba::load(path)?;
    let text = summary(&scene);
    let mut out = std::io::stdout().lock();
    out.write_all(text.as_bytes())
        .and_then(|()| out.flush())
        .context("writing to stdout")?;
    Ok(())
}

fn reconstruct(
    input: &Path,
    out: &Path,
    ov: &kdmap::config::Overrides,
    resume: bool,
) -> anyhow::Result<()> {
    let cfg = kdmap::config::Config::load(input, ov)?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(cfg.threads)
        .build()
        .context("starting worker threads")?;
    let (report, start) = pool.install(|| {
        kdmap::pipeline::reconstruct_resumable(&cfg, out, kdmap::progress::Mode::Auto, resume)
    })?;
    if start == kdmap::pipeline::Start::AlreadyFinished {
        println!(
            "already finished ({} iterations, {}): nothing to do; results: {}",
            report.iterations.len(),
            report.stopped_by,
            out.display()
        );
        return Ok(());
    }
    let last = report.iterations.last();
    println!(
        "reconstructed {} shapes from {} views in {} iterations ({}): relative error rms {:.3}%, max {:.2}%; {:.1} s",
        report.counts.reconstructed_shapes,
        report.counts.views,
        report.iterations.len(),
        report.stopped_by,
        100.0 * last.map_or(0.0, |i| i.rms_rel_error),
        100.0 * last.map_or(0.0, |i| i.max_rel_error),
        report.timings.total
    );
    println!("results: {}", out.display());
    Ok(())
}

fn accuracy(out: &Path, truth: &Path) -> anyhow::Result<()> {
    let rep = kdmap::output::accuracy::score_run(out, truth)?;
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
    let mut o = std::io::stdout().lock();
    o.write_all(t.as_bytes())
        .and_then(|()| o.flush())
        .context("writing to stdout")?;
    Ok(())
}

fn inspect_checkpoint(out: &Path) -> anyhow::Result<()> {
    use kdmap::checkpoint::Stage;
    let dir = kdmap::pipeline::state_dir(out);
    let (m, notes) = kdmap::checkpoint::load(&dir);
    for n in &notes {
        eprintln!("note: {n}");
    }
    let Some(m) = m else {
        anyhow::bail!("{}: no usable checkpoint", dir.display());
    };
    let s = &m.report.settings;
    let mut t = String::new();
    let _ = writeln!(t, "checkpoint {} in {}", m.seq, dir.display());
    let _ = writeln!(t, "inputs hash {:016x}", m.inputs_hash);
    let stage = match m.stage {
        Stage::Direct => "projection and direct light done; iteration 1 not begun".to_string(),
        Stage::Pass {
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
        Stage::Iterations {
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
        Stage::Finished => format!("finished ({})", m.report.stopped_by),
    };
    let _ = writeln!(t, "stage: {stage}");
    for it in &m.report.iterations {
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
    print!("{t}");
    Ok(())
}

fn project(input: &Path, out: &Path, threads: Option<usize>) -> anyhow::Result<()> {
    let ov = kdmap::config::Overrides {
        threads,
        ..Default::default()
    };
    let cfg = kdmap::config::Config::load(input, &ov)?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(cfg.threads)
        .build()
        .context("starting worker threads")?;
    let (p, stats) =
        pool.install(|| kdmap::pipeline::run_projection(&cfg, out, kdmap::progress::Mode::Auto))?;
    println!(
        "projected {} views onto {} shapes: {} of {} surface texels observed ({:.1}%), {} pixels masked, {:.2} s",
        stats.views,
        p.layout.slots.len(),
        stats.observed_texels,
        stats.covered_texels,
        100.0 * stats.observed_texels as f64 / stats.covered_texels.max(1) as f64,
        stats.masked_pixels,
        stats.seconds
    );
    println!("maps: {}", out.join("maps").display());
    Ok(())
}

fn v3(v: Vec3) -> String {
    format!("({}, {}, {})", v.x, v.y, v.z)
}

fn v3p(v: Vec3) -> String {
    format!("({:.4}, {:.4}, {:.4})", v.x, v.y, v.z)
}

/// The human-readable summary printed by `inspect`.
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
        let sides = match sh.sides {
            Sides::Front => "front",
            Sides::Both => "both",
        };
        let _ = write!(
            s,
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
        s.push('\n');
    }
    let _ = writeln!(s, "emitters: {}", scene.emitters.len());
    for e in &scene.emitters {
        let p = kdmap::light::emitter_power(scene, e);
        let what = match e {
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
        };
        let _ = writeln!(
            s,
            "  {what}  power {} (luminance {:.4})",
            v3p(p),
            luminance(p)
        );
    }
    let _ = writeln!(s, "sensors: {}", scene.sensors.len());
    let images = scene.dir().join("images");
    for c in &scene.sensors {
        let image = images.join(format!("{}.exr", c.id));
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
    }
    s
}
