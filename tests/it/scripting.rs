//! The command line for scripts: `--json` documents on stdout that parse back, JSON lines of
//! progress on stderr, `--quiet`, `--progress always|never`, and a closed stdout
//! (`kdmap ... | head`) ending the output quietly with exit code 0, never a panic.

use super::resume::{fast_args, write_fast_config};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

fn kdmap(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kdmap"))
        .args(args)
        .output()
        .expect("run kdmap")
}

fn cbox() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/cbox/input.xml")
}

fn json(bytes: &[u8]) -> serde_json::Value {
    serde_json::from_slice(bytes)
        .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(bytes)))
}

/// Runs `args` with stdout closed before kdmap writes to it, as `| head -c 0` would.
fn with_closed_stdout(args: &[&str]) -> Output {
    let mut child = Command::new(env!("CARGO_BIN_EXE_kdmap"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn kdmap");
    drop(child.stdout.take());
    child.wait_with_output().expect("wait for kdmap")
}

#[test]
fn inspect_json_parses_back_and_matches_the_scene() {
    let scene = cbox();
    let o = kdmap(&["inspect", scene.to_str().unwrap(), "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v = json(&o.stdout);
    let shapes = v["shapes"].as_array().unwrap();
    assert_eq!(shapes.len(), 8, "7 walls and boxes, 1 light");
    let light = shapes.iter().find(|s| s["id"] == "light").unwrap();
    assert_eq!(light["emission"], serde_json::json!([17.0, 12.0, 4.0]));
    let tris: u64 = shapes
        .iter()
        .map(|s| s["triangles"].as_u64().unwrap())
        .sum();
    assert_eq!(v["triangles"].as_u64(), Some(tris));
    let emitters = v["emitters"].as_array().unwrap();
    assert_eq!(emitters.len(), 1);
    assert_eq!(emitters[0]["type"], "area");
    assert_eq!(emitters[0]["shape"], "light");
    assert!(emitters[0]["power_luminance"].as_f64().unwrap() > 0.0);
    let sensors = v["sensors"].as_array().unwrap();
    assert_eq!(sensors.len(), 3);
    for s in sensors {
        assert_eq!(
            (s["width"].as_u64(), s["height"].as_u64()),
            (Some(256), Some(256))
        );
        assert_eq!(s["image_present"], true, "{s}");
    }
    // the automatic texel density: one per reconstructed shape, held to twice the 3 x 256 x 256
    // photo pixels, and what a run needs
    let atlas = &v["atlas"];
    assert_eq!(atlas["budget"].as_u64(), Some(2 * 3 * 256 * 256));
    let densities: Vec<f64> = atlas["shapes"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|d| d["texels_per_unit"].as_f64())
        .collect();
    assert_eq!(densities.len(), 7, "{atlas}");
    assert!(
        densities.iter().all(|&d| d > 16.0 && d < 512.0),
        "{densities:?}"
    );
    let est = atlas["estimated_texels"].as_u64().unwrap();
    assert!(est <= 2 * 3 * 256 * 256 && est > 300_000, "{est}");
    assert!(v["needs"]["disk_bytes"].as_u64().unwrap() > est * 124);
}

#[test]
fn a_closed_stdout_ends_quietly() {
    let scene = cbox();
    for json in [false, true] {
        let mut a = vec!["inspect", scene.to_str().unwrap()];
        if json {
            a.push("--json");
        }
        let o = with_closed_stdout(&a);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(0), "{err}");
        assert!(err.is_empty(), "{err}");
    }
}

#[test]
fn a_run_for_scripts_json_progress_checkpoint_json_and_a_closed_pipe() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = write_fast_config(tmp.path());
    let out = tmp.path().join("run");
    let mut a = fast_args(&cfg, &out);
    a.extend(["--progress", "json"]);
    let o = kdmap(&a);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    // Every stderr line is one JSON object: progress events, notes, iteration results.
    let lines: Vec<serde_json::Value> = err.lines().map(|l| json(l.as_bytes())).collect();
    let progress: Vec<_> = lines.iter().filter(|v| v.get("event").is_some()).collect();
    for key in ["stage", "done", "total", "unit", "rate", "eta_s"] {
        assert!(
            progress.iter().all(|v| v.get(key).is_some()),
            "{key}: {err}"
        );
    }
    let done = |stage: &str| {
        progress
            .iter()
            .any(|v| v["stage"] == stage && v["event"] == "done" && v["done"] == v["total"])
    };
    assert!(
        done("atlas") && done("projection") && done("photons 3/3"),
        "{err}"
    );
    let iterations = lines.iter().filter(|v| v["stage"] == "iteration").count();
    assert_eq!(iterations, 3, "{err}");
    assert!(lines.iter().any(|v| v.get("note").is_some()), "{err}");

    // The checkpoint as a JSON document.
    let o = kdmap(&["inspect-checkpoint", out.to_str().unwrap(), "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v = json(&o.stdout);
    assert_eq!(v["stage"], "Finished");
    assert_eq!(v["iterations"].as_array().unwrap().len(), 3);
    assert_eq!(v["iterations_planned"], 3);
    assert!(v["checkpoint"].as_u64().unwrap() > 1);
    assert_eq!(v["inputs_hash"].as_str().unwrap().len(), 16);

    // `kdmap inspect-checkpoint DIR | head -c 0`, text and JSON
    for extra in [None, Some("--json")] {
        let mut a = vec!["inspect-checkpoint", out.to_str().unwrap()];
        a.extend(extra);
        let o = with_closed_stdout(&a);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(0), "{err}");
        assert!(!err.contains("panicked"), "{err}");
    }

    // An error in JSON mode is a JSON line too, with the exit code.
    let o = kdmap(&[
        "inspect-checkpoint",
        tmp.path().to_str().unwrap(),
        "--progress",
        "json",
    ]);
    assert_eq!(o.status.code(), Some(65));
    let v = json(&o.stderr);
    assert_eq!(v["exit_code"], 65);
    assert!(v["error"].as_str().unwrap().starts_with("error: "), "{v}");
}

#[test]
fn quiet_and_progress_modes_choose_what_stderr_gets() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("run.toml");
    let text = format!(
        "scene = {:?}\n[atlas]\ntexels_per_unit = 16.0\n[projection]\nrefine_passes = 0\n",
        cbox()
    );
    std::fs::write(&cfg, text).unwrap();
    let project = |extra: &[&str]| -> String {
        let out = tmp.path().join("out");
        let mut a = vec![
            "project",
            cfg.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ];
        a.extend(extra);
        let o = kdmap(&a);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        assert!(String::from_utf8_lossy(&o.stdout).contains("projected 3 views"));
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    // Not a terminal: plain lines by default.
    let auto = project(&[]);
    assert!(auto.contains("[projection] done"), "{auto}");
    assert!(!auto.contains('\x1b'), "{auto}");
    let always = project(&["--progress", "always"]);
    assert!(
        always.contains('\x1b'),
        "bars drawn with ANSI escapes: {always:?}"
    );
    let never = project(&["--progress", "never"]);
    assert!(
        !never.contains("[projection]") && !never.contains('\x1b'),
        "{never}"
    );
    let quiet = project(&["--quiet"]);
    assert!(quiet.is_empty(), "{quiet}");
    // Errors are still printed when quiet.
    let o = kdmap(&["inspect", "/nonexistent/scene.xml", "--quiet"]);
    assert_eq!(o.status.code(), Some(66));
    assert!(String::from_utf8_lossy(&o.stderr).starts_with("error: "));
    // --quiet and --progress together are a usage error.
    let o = kdmap(&[
        "inspect",
        cbox().to_str().unwrap(),
        "--quiet",
        "--progress",
        "json",
    ]);
    assert_eq!(o.status.code(), Some(2));
}
