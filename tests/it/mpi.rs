//! MPI runs (`--features mpi`, Open MPI's `mpirun`): 2 and 3 ranks end with textures, maps,
//! renders and report figures bit-identical to one process, for the gather and for photons,
//! whatever the threads per rank, and with the projection's rays shared among ranks (fine
//! geometry on); a run whose rank is killed fails with one line naming it and an intact
//! checkpoint; a job stopped by SIGTERM checkpoints and exits 130; both resume under another
//! number of ranks (3, then 1) bit-identically; an input error is one line, once.

use super::resume::{assert_same_files, manifest};
use kdmap::pipeline::RunStage;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// A small cbox run: coarse atlas, few area samples, two refinement passes, the second gated
/// (so the sharded refinement renders and the gate are checked too; the gate holds texels
/// here: with `refine_gate = 0` the textures differ), `extra` appended to the config.
fn write_config(dir: &Path, name: &str, extra: &str) -> PathBuf {
    write_config_of("cbox", dir, name, extra)
}

/// [`write_config`] for the fixture `fixture`.
fn write_config_of(fixture: &str, dir: &Path, name: &str, extra: &str) -> PathBuf {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(fixture)
        .join("input.xml");
    let p = dir.join(name);
    let text = format!(
        "scene = {:?}\n[atlas]\ntexels_per_unit = 24.0\n[projection]\nrefine_passes = 2\n\
         refine_gated_from = 1\n\
         [direct]\narea_samples = 4\n{extra}",
        scene.to_str().unwrap()
    );
    std::fs::write(&p, text).unwrap();
    p
}

/// Photons (`photons` per iteration), with a checkpoint after every group of batches.
fn photon_config(dir: &Path, photons: u64) -> PathBuf {
    let extra = format!(
        "[photons]\nbatch_size = 1024\nper_iteration = {photons}\n[solver]\nmethod = \"photons\"\n\
         [run]\ncheckpoint_every_batches = 1\ncheckpoint_every_seconds = 0\n"
    );
    write_config(dir, "photons.toml", &extra)
}

fn args<'a>(cfg: &'a Path, out: &'a Path, threads: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec![
        "reconstruct",
        cfg.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--iterations",
        "2",
        "--threads",
        threads,
    ];
    a.extend_from_slice(extra);
    a
}

/// `kdmap` under `mpirun -np ranks` (or alone for 1 rank).
fn command(ranks: usize, a: &[&str]) -> Command {
    let exe = env!("CARGO_BIN_EXE_kdmap");
    if ranks == 1 {
        let mut c = Command::new(exe);
        c.args(a);
        return c;
    }
    let mut c = Command::new("mpirun");
    let np = ranks.to_string();
    // root may run Open MPI only when told so; 3 ranks on 2 cores oversubscribe
    c.args([
        "--allow-run-as-root",
        "--oversubscribe",
        "--bind-to",
        "none",
    ])
    .args(["-np", &np, exe])
    .args(a);
    c
}

fn run(ranks: usize, a: &[&str]) -> Output {
    let o = command(ranks, a).output().expect("run mpirun");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{ranks} ranks: {err}");
    assert!(!err.contains("panicked"), "{err}");
    o
}

/// Textures, maps and renders byte for byte, and report.json but for what measures the run
/// (timings, rays and cores, resources, seconds and rates per iteration: every rank casts some
/// rays of its own, the atlas's and the gather points' among them).
fn assert_same_results(a: &Path, b: &Path) {
    assert_same_files(a, b, &["textures", "maps", "renders"]);
    let figures = |d: &Path| {
        let text = std::fs::read_to_string(d.join("report.json")).unwrap();
        let mut r: serde_json::Value = serde_json::from_str(&text).unwrap();
        let o = r.as_object_mut().unwrap();
        for k in ["timings", "rays", "resources", "settings"] {
            o.remove(k);
        }
        for it in o["iterations"].as_array_mut().unwrap() {
            let it = it.as_object_mut().unwrap();
            it.retain(|k, _| !k.ends_with("seconds") && !k.ends_with("per_second"));
        }
        r
    };
    assert_eq!(figures(a), figures(b), "report figures differ");
}

fn same_under_ranks(cfg: &Path, dir: &Path) {
    let solo = dir.join("solo");
    run(1, &args(cfg, &solo, "2", &[]));
    for (ranks, threads) in [(2, "1"), (3, "2")] {
        let out = dir.join(format!("np{ranks}"));
        let o = run(ranks, &args(cfg, &out, threads, &[]));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(&format!("{ranks} ranks;")), "{err}");
        assert_same_results(&solo, &out);
        // only rank 0 writes: one working directory per other rank, no checkpoints there
        let r1 = out.join("checkpoint/rank-1");
        assert!(r1.join("geometry.tiles").exists());
        assert!(!r1.join("progress.kdm").exists());
        let report: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
        assert_eq!(report["resources"]["ranks"], ranks);
        let comm = report["resources"]["communication"].as_array().unwrap();
        assert!(comm.last().unwrap()[1].as_u64().unwrap() > 0, "{comm:?}");
    }
}

#[test]
fn gather_under_2_and_3_ranks_matches_one_process_bit_for_bit() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = write_config(tmp.path(), "gather.toml", "");
    same_under_ranks(&cfg, tmp.path());
}

/// The projection's primary rays are shared: each rank casts those of its bands of rows and
/// the hits and pixel classes are gathered. With fine geometry on (the loose reading uses the
/// corner hits too), 2 ranks end with the one process's results, bit for bit.
#[test]
fn projection_rays_shared_by_2_ranks_match_one_process_bit_for_bit() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = write_config(tmp.path(), "fine.toml", "");
    let text = std::fs::read_to_string(&cfg).unwrap();
    let text = text.replace("[projection]\n", "[projection]\nfine_geometry = true\n");
    std::fs::write(&cfg, text).unwrap();
    let solo = tmp.path().join("solo");
    run(1, &args(&cfg, &solo, "2", &[]));
    let two = tmp.path().join("np2");
    run(2, &args(&cfg, &two, "1", &[]));
    assert_same_results(&solo, &two);
}

/// A tent film's re-render weighs sub-pixel samples along rows, shares the row sums in bands
/// and weighs them down the columns (`physics::film_filter`): 2 ranks end with the one
/// process's results, bit for bit (mirror-cbox's films are tents).
#[test]
fn tent_film_refinement_under_2_ranks_matches_one_process_bit_for_bit() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = write_config_of("mirror-cbox", tmp.path(), "tent.toml", "");
    let solo = tmp.path().join("solo");
    run(1, &args(&cfg, &solo, "2", &[]));
    let two = tmp.path().join("np2");
    run(2, &args(&cfg, &two, "1", &[]));
    assert_same_results(&solo, &two);
}

#[test]
fn photons_under_2_and_3_ranks_match_one_process_bit_for_bit() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = photon_config(tmp.path(), 40_000);
    same_under_ranks(&cfg, tmp.path());
}

/// The process ids of the ranks `mpirun` (pid `launcher`) started, by rank.
fn rank_pids(launcher: u32, ranks: usize) -> Vec<u32> {
    let t0 = Instant::now();
    loop {
        let mut found = vec![0; ranks];
        for e in std::fs::read_dir("/proc").unwrap().flatten() {
            let Ok(pid) = e.file_name().to_string_lossy().parse::<u32>() else {
                continue;
            };
            let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
            let ppid = stat.rsplit_once(") ").map(|(_, r)| r.split(' ').nth(1));
            if ppid.flatten() != Some(&launcher.to_string()) {
                continue;
            }
            let env = std::fs::read(format!("/proc/{pid}/environ")).unwrap_or_default();
            for var in env.split(|&b| b == 0) {
                if let Some(r) = var.strip_prefix(b"OMPI_COMM_WORLD_RANK=") {
                    let r: usize = String::from_utf8_lossy(r).parse().unwrap();
                    found[r] = pid;
                }
            }
        }
        if found.iter().all(|&p| p != 0) {
            return found;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "no ranks of {launcher}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Starts `a` under `ranks` ranks, waits until rank 0's checkpoint is inside a photon pass at
/// sequence `seq` or later, sends `sig` to the rank(s) `to` and returns the job's output.
fn stop_at(ranks: usize, a: &[&str], out: &Path, seq: u64, sig: &str, to: &[usize]) -> Output {
    let child: Child = command(ranks, a)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn mpirun");
    let pids = rank_pids(child.id(), ranks);
    let t0 = Instant::now();
    while !manifest(out)
        .is_some_and(|m| m.seq >= seq && matches!(m.payload.stage, RunStage::Pass { .. }))
    {
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "no checkpoint {seq}"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    for &r in to {
        let s = Command::new("kill")
            .args([&format!("-{sig}"), &pids[r].to_string()])
            .status()
            .unwrap();
        assert!(s.success());
    }
    let o = child.wait_with_output().unwrap();
    assert!(t0.elapsed() < Duration::from_secs(120), "the job hangs");
    o
}

#[test]
fn a_killed_rank_and_a_terminated_job_resume_under_other_rank_counts_bit_for_bit() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = photon_config(tmp.path(), 150_000);
    let (full, out) = (tmp.path().join("full"), tmp.path().join("out"));
    run(1, &args(&cfg, &full, "2", &[]));

    // 2 ranks, rank 1 killed: one line names it, the job fails, the checkpoint is intact
    let o = stop_at(2, &args(&cfg, &out, "1", &[]), &out, 3, "KILL", &[1]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    let ours: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(ours.len(), 1, "{err}");
    assert!(
        ours[0].contains("rank 1 (pid") && ours[0].contains("died"),
        "{err}"
    );
    let seq = manifest(&out).expect("an intact checkpoint").seq;

    // resumed under 3 ranks, stopped by SIGTERM to every rank (what `scancel` does)
    let mut resume = args(&cfg, &out, "1", &[]);
    resume.push("--resume");
    let o = stop_at(3, &resume, &out, seq + 3, "TERM", &[0, 1, 2]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(130), "{err}");
    let stops: Vec<&str> = err
        .lines()
        .filter(|l| l.starts_with("interrupted:"))
        .collect();
    let last = manifest(&out).expect("a checkpoint after the stop");
    assert_eq!(stops.len(), 1, "{err}");
    assert!(
        stops[0].contains(&format!("checkpoint {} ", last.seq)),
        "{err}"
    );

    // and finished by one process
    let o = run(1, &resume);
    assert!(String::from_utf8_lossy(&o.stdout).contains("reconstructed"));
    assert_same_results(&full, &out);
}

#[test]
fn an_input_error_under_mpi_is_one_line_once() {
    let tmp = tempfile::tempdir().unwrap();
    let missing = tmp.path().join("missing.xml");
    let out = tmp.path().join("out");
    let a = [
        "reconstruct",
        missing.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    let o = command(2, &a).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(66), "{err}");
    let ours: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(ours.len(), 1, "{err}");
    assert!(ours[0].contains("missing.xml"), "{err}");
}
