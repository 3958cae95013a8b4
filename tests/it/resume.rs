//! Checkpoint and resume, end to end on the real binary: runs killed with SIGKILL at several
//! moments and resumed end with textures and maps bit-identical to an uninterrupted run;
//! resuming with other settings is refused, a finished run resumed is a no-op, and a corrupt
//! manifest is reported in one line and the run falls back to the previous checkpoint. Runs
//! killed exactly inside a checkpoint write (paused there by the `KDMAP_FAULT` test hook, half
//! of the snapshot or of the manifest written) resume bit-identically too.

use kdmap::checkpoint::{decode, Manifest, MANIFEST};
use kdmap::pipeline::{Progress, RunStage};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

fn scene() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/cbox/input.xml")
}

/// A small run config of the photon method (the one with mid-pass checkpoints): coarse
/// atlas, few area samples, small batches and a checkpoint after every group of batches, so a
/// photon pass has many checkpoints.
fn write_config(dir: &Path) -> PathBuf {
    let p = dir.join("run.toml");
    let text = format!(
        "scene = {:?}\n[atlas]\ntexels_per_unit = 24.0\n[direct]\narea_samples = 4\n\
         [photons]\nbatch_size = 1024\n[solver]\nmethod = \"photons\"\n\
         [run]\ncheckpoint_every_batches = 1\ncheckpoint_every_seconds = 0\n",
        scene().to_str().unwrap()
    );
    std::fs::write(&p, text).unwrap();
    p
}

/// [`write_config`] without projection refinement (3 passes that dominate a small run and
/// that checkpoints never see): a run takes about 2 s in release.
pub(super) fn write_fast_config(dir: &Path) -> PathBuf {
    let p = write_config(dir);
    let text = std::fs::read_to_string(&p).unwrap();
    let text = text.replace("[direct]", "[projection]\nrefine_passes = 0\n[direct]");
    std::fs::write(&p, text).unwrap();
    p
}

/// The arguments of the fault tests: 20 photon batches per pass, 2 threads (photon groups of
/// 16 batches), so the checkpoints are, in order: 1 after direct light, then per iteration
/// one mid-pass (16 batches) and one at its end (2..=7), and 8 when finished.
pub(super) fn fast_args<'a>(cfg: &'a Path, out: &'a Path) -> Vec<&'a str> {
    let mut a = args(cfg, out, "20000");
    a.extend(["--threads", "2"]);
    a
}

fn args<'a>(cfg: &'a Path, out: &'a Path, photons: &'a str) -> Vec<&'a str> {
    vec![
        "reconstruct",
        cfg.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--photons",
        photons,
        "--iterations",
        "3",
    ]
}

pub(super) fn run(a: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kdmap"))
        .args(a)
        .output()
        .expect("run kdmap")
}

fn spawn(a: &[&str]) -> Child {
    Command::new(env!("CARGO_BIN_EXE_kdmap"))
        .args(a)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn kdmap")
}

pub(super) fn manifest(out: &Path) -> Option<Manifest<Progress>> {
    let bytes = std::fs::read(out.join("checkpoint").join(MANIFEST)).ok()?;
    decode::<Progress>(&bytes).ok()
}

/// Runs kdmap with `a` and SIGKILLs it as soon as `when(out)` holds (or lets it finish).
/// Returns whether it was killed.
fn kill_when(a: &[&str], out: &Path, when: impl Fn(&Path) -> bool) -> bool {
    let mut child = spawn(a);
    let t0 = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            assert!(status.success(), "kdmap failed: {status}");
            return false;
        }
        if when(out) {
            child.kill().unwrap(); // SIGKILL
            child.wait().unwrap();
            return true;
        }
        assert!(t0.elapsed() < Duration::from_secs(120), "kdmap hangs");
        std::thread::sleep(Duration::from_millis(2));
    }
}

use super::cli::files;

pub(super) fn assert_same_outputs(a: &Path, b: &Path) {
    assert_same_files(a, b, &["textures", "maps"]);
}

/// The files of each of `subs` in run directories `a` and `b`: the same names, byte for byte
/// (and at least one).
pub(super) fn assert_same_files(a: &Path, b: &Path, subs: &[&str]) {
    for sub in subs {
        let (fa, fb) = (files(a, sub), files(b, sub));
        assert!(!fa.is_empty());
        assert_eq!(
            fa.iter().map(|f| &f.0).collect::<Vec<_>>(),
            fb.iter().map(|f| &f.0).collect::<Vec<_>>()
        );
        for (x, y) in fa.iter().zip(&fb) {
            assert!(
                x.1 == y.1,
                "{sub}/{} differs: {} vs {}",
                x.0,
                a.display(),
                b.display()
            );
        }
    }
}

#[test]
fn killed_and_resumed_runs_match_an_uninterrupted_run_bit_for_bit() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = write_config(tmp.path());
    let full = tmp.path().join("full");
    let o = run(&args(&cfg, &full, "200000"));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    let out = tmp.path().join("killed");
    let a = args(&cfg, &out, "200000");
    let mut resume = a.clone();
    resume.push("--resume");

    // 1. During projection / direct light: the geometry exists, no checkpoint yet.
    let ck = out.join("checkpoint");
    let mut kills = Vec::new();
    kills.push(kill_when(&a, &out, |_| {
        ck.join("state.tiles").exists() && !ck.join(MANIFEST).exists()
    }));

    // 2. During iteration 1's photon pass (a mid-pass checkpoint was just written).
    let mid_pass = |o: &Path| {
        matches!(
            manifest(o).map(|m| m.payload.stage),
            Some(RunStage::Pass { iteration: 0, batches_done, .. }) if batches_done >= 32
        )
    };
    kills.push(kill_when(&resume, &out, mid_pass));
    let seq = manifest(&out).map_or(0, |m| m.seq);

    // Resuming with a setting that changes the result is refused, leaving the checkpoint.
    let mut other = args(&cfg, &out, "300000");
    other.push("--resume");
    let o = run(&other);
    assert_eq!(o.status.code(), Some(65));
    let err = String::from_utf8_lossy(&o.stderr);
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(lines[0].contains("other inputs or settings"), "{err}");
    assert!(manifest(&out).is_some_and(|m| m.seq == seq));

    // 3. Right after a checkpoint write (the end-of-iteration one), with 1 thread.
    let mut one = resume.clone();
    one.extend(["--threads", "1"]);
    kills.push(kill_when(&one, &out, |o| {
        manifest(o).is_some_and(|m| matches!(m.payload.stage, RunStage::Iterations { .. }))
    }));

    // 4. Soon after a checkpoint during iteration 3's pass.
    kills.push(kill_when(&resume, &out, |o| {
        manifest(o).is_some_and(|m| matches!(m.payload.stage, RunStage::Pass { iteration: 2, .. }))
    }));
    // Every moment is reached long before the run ends (projection and each pass take
    // hundreds of milliseconds; the manifest is polled every 2 ms).
    assert_eq!(kills, [true; 4], "a run ended before its kill moment");

    // A corrupt manifest: one line about it, then the previous checkpoint is used.
    let mpath = ck.join(MANIFEST);
    if mpath.exists() {
        let mut bytes = std::fs::read(&mpath).unwrap();
        let n = bytes.len();
        bytes[n - 10] ^= 0x55;
        std::fs::write(&mpath, bytes).unwrap();
        let o = run(&resume);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let err = String::from_utf8_lossy(&o.stderr);
        let notes: Vec<&str> = err
            .lines()
            .filter(|l| l.contains("unusable checkpoint"))
            .collect();
        assert_eq!(notes.len(), 1, "{err}");
        assert!(notes[0].contains("checksum"), "{err}");
        assert!(err.contains("resuming from checkpoint"), "{err}");
    } else {
        let o = run(&resume);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    assert!(manifest(&out).is_some_and(|m| m.payload.stage == RunStage::Finished));
    assert_same_outputs(&full, &out);

    // A finished run resumed is a no-op.
    let before = std::fs::metadata(out.join("report.json"))
        .unwrap()
        .modified()
        .unwrap();
    let o = run(&resume);
    assert!(o.status.success());
    assert!(String::from_utf8_lossy(&o.stdout).contains("already finished"));
    let after = std::fs::metadata(out.join("report.json"))
        .unwrap()
        .modified()
        .unwrap();
    assert_eq!(before, after);
    assert_same_outputs(&full, &out);
}

#[test]
fn resume_without_a_checkpoint_starts_fresh_with_a_note() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = write_config(tmp.path());
    let out = tmp.path().join("out");
    let mut a = args(&cfg, &out, "20000");
    a.push("--resume");
    let o = run(&a);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("no usable checkpoint"), "{err}");
    let o = run(&["inspect-checkpoint", out.to_str().unwrap()]);
    assert!(o.status.success());
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(text.contains("finished"), "{text}");
    assert!(text.contains("iteration 3: relative error"), "{text}");
}

/// Runs kdmap with `KDMAP_FAULT=fault`, waits until the hook has paused it inside a checkpoint
/// write (its marker file appears) and SIGKILLs it there.
fn kill_paused(a: &[&str], out: &Path, fault: &str) {
    let marker = out.join("checkpoint").join("fault.paused");
    let mut child = Command::new(env!("CARGO_BIN_EXE_kdmap"))
        .args(a)
        .env("KDMAP_FAULT", fault)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn kdmap");
    let t0 = Instant::now();
    while !marker.exists() {
        if let Some(status) = child.try_wait().unwrap() {
            panic!("kdmap ended ({status}) without pausing at {fault}");
        }
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "kdmap never paused at {fault}"
        );
        std::thread::sleep(Duration::from_millis(2));
    }
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
}

#[test]
fn runs_killed_inside_a_checkpoint_write_resume_bit_for_bit() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = write_fast_config(tmp.path());
    let full = tmp.path().join("full");
    let o = run(&fast_args(&cfg, &full));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let state_len = std::fs::metadata(full.join("checkpoint/state.tiles"))
        .unwrap()
        .len();

    // (hook, checkpoint the kill leaves current): checkpoint 4 is iteration 2's mid-pass one,
    // checkpoint 3 the end of iteration 1 (resuming from 2 continues a photon pass).
    for (fault, last_good) in [("pause-in-checkpoint:4", 3), ("pause-in-manifest:3", 2)] {
        let out = tmp.path().join(fault.replace(':', "-"));
        let a = fast_args(&cfg, &out);
        kill_paused(&a, &out, fault);

        // What the kill left: the last good checkpoint and a half-written temporary file.
        let ck = out.join("checkpoint");
        assert_eq!(manifest(&out).map(|m| m.seq), Some(last_good), "{fault}");
        if fault.starts_with("pause-in-checkpoint") {
            let half = std::fs::metadata(ck.join("state.4.tmp")).unwrap().len();
            assert_eq!(half, state_len / 2, "{fault}");
            assert!(!ck.join("state.4.tiles").exists());
        } else {
            let torn = std::fs::read(ck.join("progress.new")).unwrap();
            assert!(
                decode::<Progress>(&torn).is_err(),
                "{fault}: progress.new is whole"
            );
            assert!(ck.join("state.3.tiles").exists());
        }

        // Resume without the hook, removing nothing.
        let mut resume = a.clone();
        resume.push("--resume");
        let o = run(&resume);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{fault}: {err}");
        assert!(
            err.contains(&format!("resuming from checkpoint {last_good} ")),
            "{fault}: {err}"
        );
        assert!(!err.contains("unusable checkpoint"), "{fault}: {err}");
        assert!(manifest(&out).is_some_and(|m| m.payload.stage == RunStage::Finished));
        assert_same_outputs(&full, &out);
        // Later checkpoints removed the half-written copy.
        assert!(!ck.join("state.4.tmp").exists(), "{fault}");
    }
}

/// The `secant` update steps from the sums of the previous iteration, which live in the
/// checkpointed report: a run killed inside iteration 3's photon pass (after two secant
/// steps' worth of history) resumes to the same bits, and the secant step did run.
#[test]
fn secant_update_resumes_bit_for_bit() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = write_fast_config(tmp.path());
    let text = std::fs::read_to_string(&cfg)
        .unwrap()
        .replace("[solver]", "[solver]\nupdate = \"secant\"");
    std::fs::write(&cfg, text).unwrap();
    let full = tmp.path().join("full");
    let o = run(&fast_args(&cfg, &full));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report: kdmap::report::Report =
        serde_json::from_str(&std::fs::read_to_string(full.join("report.json")).unwrap()).unwrap();
    assert_eq!(report.settings.update, kdmap::config::UpdateRule::Secant);
    assert!(
        report.iterations[1..]
            .iter()
            .any(|it| it.beta.iter().any(|b| (b - 0.5).abs() > 1e-6)),
        "no secant step taken: {:?}",
        report.iterations
    );

    // Checkpoint 7 would be iteration 3's end; 6 is its mid-pass one.
    let out = tmp.path().join("killed");
    let a = fast_args(&cfg, &out);
    kill_paused(&a, &out, "pause-in-checkpoint:7");
    assert_eq!(manifest(&out).map(|m| m.seq), Some(6));
    let mut resume = a.clone();
    resume.push("--resume");
    let o = run(&resume);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_same_outputs(&full, &out);
}

/// The gather (the default method): a run killed after its first iteration's checkpoint casts
/// the same rays again on resume and ends bit-identical to an uninterrupted run.
#[test]
fn gather_run_resumes_bit_for_bit() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("run.toml");
    let text = format!(
        "scene = {:?}\n[atlas]\ntexels_per_unit = 24.0\n[projection]\nrefine_passes = 0\n\
         [direct]\narea_samples = 4\n[gather]\nrays = 64\n[run]\ncheckpoint_every_seconds = 0\n",
        scene().to_str().unwrap()
    );
    std::fs::write(&cfg, text).unwrap();
    let a = |out: &Path| -> Vec<String> {
        [
            "reconstruct",
            cfg.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--iterations",
            "3",
        ]
        .map(String::from)
        .to_vec()
    };
    let full = tmp.path().join("full");
    let o = run(&a(&full).iter().map(String::as_str).collect::<Vec<_>>());
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = tmp.path().join("killed");
    let args = a(&out);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    // checkpoint 2 is iteration 1's end: pause inside checkpoint 3 (iteration 2's end)
    kill_paused(&args, &out, "pause-in-checkpoint:3");
    assert!(matches!(
        manifest(&out).map(|m| m.payload.stage),
        Some(RunStage::Iterations {
            iterations_done: 1,
            ..
        })
    ));
    let mut resume = args.clone();
    resume.push("--resume");
    let o = run(&resume);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_same_outputs(&full, &out);
}
