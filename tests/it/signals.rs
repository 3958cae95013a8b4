//! SIGINT and SIGTERM on the real binary: a signal at any moment stops the run at its next safe
//! point with exit code 130 and a line telling how to continue, and `--resume` then ends
//! bit-identical to an uninterrupted run; a second signal ends the process at once (130) and
//! leaves the last checkpoint intact.

use super::resume::{assert_same_outputs, fast_args, manifest, run, write_fast_config};
use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

/// A reconstruction of a few seconds: the fast config, 200k photons x 3 iterations.
fn long_args<'a>(cfg: &'a Path, out: &'a Path) -> Vec<&'a str> {
    let (cfg, out) = (cfg.to_str().unwrap(), out.to_str().unwrap());
    vec![
        "reconstruct",
        cfg,
        "--out",
        out,
        "--photons",
        "200000",
        "--iterations",
        "3",
        "--threads",
        "2",
    ]
}

fn spawn(a: &[&str], fault: Option<&str>) -> Child {
    let mut c = Command::new(env!("CARGO_BIN_EXE_kdmap"));
    c.args(a).stdout(Stdio::null()).stderr(Stdio::piped());
    if let Some(f) = fault {
        c.env("KDMAP_FAULT", f);
    }
    c.spawn().expect("spawn kdmap")
}

fn signal(child: &Child, sig: &str) {
    let s = Command::new("kill")
        .args([&format!("-{sig}"), &child.id().to_string()])
        .status()
        .expect("run kill");
    assert!(s.success(), "kill -{sig} failed");
}

/// Waits for `child` (at most two minutes) and returns its output.
fn finish(child: Child) -> Output {
    let t0 = Instant::now();
    let out = child.wait_with_output().expect("wait for kdmap");
    assert!(t0.elapsed() < Duration::from_secs(120), "kdmap hangs");
    out
}

/// Deterministic pseudo-random delays in `[lo, hi)` milliseconds (xorshift, fixed seed).
fn delays(n: usize, lo: u64, hi: u64) -> Vec<u64> {
    let mut x: u64 = 0x9e37_79b9_7f4a_7c15;
    (0..n)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            lo + x % (hi - lo)
        })
        .collect()
}

/// Runs `a`, sends `sig` when the `k`-th photon progress line reaches stderr, and returns
/// the exit status with the whole of stderr.
fn signal_at_photon_line(a: &[&str], k: usize, sig: &str) -> (Output, String) {
    use std::io::BufRead;
    let mut child = spawn(a, None);
    let stderr = child.stderr.take().expect("piped stderr");
    let (mut seen, mut err) = (0, String::new());
    for line in std::io::BufReader::new(stderr).lines() {
        let line = line.expect("utf-8 stderr");
        if line.starts_with("[photons") {
            seen += 1;
            if seen == k {
                signal(&child, sig);
            }
        }
        err.push_str(&line);
        err.push('\n');
    }
    (finish(child), err)
}

#[test]
fn runs_interrupted_at_random_moments_resume_bit_identically() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = write_fast_config(tmp.path());
    let full = tmp.path().join("full");
    let o = run(&long_args(&cfg, &full));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    // One run, stopped again and again: the first attempt from scratch, later ones resumed.
    let out = tmp.path().join("interrupted");
    let fresh = long_args(&cfg, &out);
    let mut resume = fresh.clone();
    resume.push("--resume");
    let (mut stopped, mut saved) = (0, 0);
    // Signalled at pseudo-random moments of the photon passes, told by the progress lines
    // on stderr (not by wall time: the machine's load must not decide what is tested).
    for (i, k) in delays(4, 1, 12).into_iter().enumerate() {
        let a = if i == 0 { &fresh } else { &resume };
        let sig = if i % 2 == 0 { "INT" } else { "TERM" };
        let (o, err) = signal_at_photon_line(a, k as usize, sig);
        assert!(!err.contains("panicked"), "{err}");
        if o.status.success() {
            continue; // finished before the k-th photon line: nothing to stop
        }
        assert_eq!(o.status.code(), Some(130), "at photon line {k}: {err}");
        let last = err.lines().last().unwrap_or("");
        assert!(
            last.starts_with("interrupted: "),
            "at photon line {k}: {err}"
        );
        stopped += 1;
        if last.contains("--resume") {
            let seq = manifest(&out).expect("a checkpoint after the stop").seq;
            assert!(last.contains(&format!("checkpoint {seq} ")), "{last}");
            saved += 1;
        } else {
            assert!(last.contains("start over"), "{last}");
        }
    }
    assert!(
        stopped >= 2 && saved >= 1,
        "{stopped} stopped, {saved} with a checkpoint"
    );
    let o = run(&resume);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_same_outputs(&full, &out);
}

#[test]
fn a_second_signal_exits_at_once_leaving_the_last_checkpoint_intact() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = write_fast_config(tmp.path());
    let full = tmp.path().join("full");
    let o = run(&fast_args(&cfg, &full));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    // Held inside checkpoint 4's snapshot write (the test hook), so the run cannot reach a
    // safe point: the first signal only asks it to stop, the second ends it.
    let out = tmp.path().join("twice");
    let a = fast_args(&cfg, &out);
    let mut child = spawn(&a, Some("pause-in-checkpoint:4"));
    let paused = out.join("checkpoint").join("fault.paused");
    let t0 = Instant::now();
    while !paused.exists() {
        assert!(child.try_wait().unwrap().is_none(), "kdmap ended early");
        assert!(t0.elapsed() < Duration::from_secs(120), "never paused");
        std::thread::sleep(Duration::from_millis(5));
    }
    signal(&child, "INT");
    std::thread::sleep(Duration::from_millis(300));
    assert!(
        child.try_wait().unwrap().is_none(),
        "the first signal must not end the run at once"
    );
    signal(&child, "TERM");
    let o = finish(child);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(130), "{err}");
    assert!(
        !err.contains("interrupted:"),
        "no safe point was reached: {err}"
    );
    assert_eq!(
        manifest(&out).map(|m| m.seq),
        Some(3),
        "last good checkpoint"
    );

    let mut resume = a.clone();
    resume.push("--resume");
    let o = run(&resume);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("resuming from checkpoint 3 "), "{err}");
    assert_same_outputs(&full, &out);
}
