//! A full disk or an unwritable output directory, end to end on the real binary: the run
//! stops with one line on stderr naming the file (exit code 1, no panic), leaves no temporary
//! file, keeps its last good checkpoint loadable, and `--resume` once there is room ends
//! with outputs bit-identical to an uninterrupted run. The disk is filled by the
//! `KDMAP_FAULT=enospc-after-bytes:N` test hook and, where `mount` is permitted (root, no
//! sandbox), by a real small tmpfs.

use super::resume::{assert_same_outputs, fast_args, manifest, run, write_fast_config};
use kdmap::checkpoint::{decode, load, Manifest, PREV_MANIFEST};
use kdmap::pipeline::{Progress, RunStage};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn run_with_fault(a: &[&str], fault: &str) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kdmap"))
        .args(a)
        .env("KDMAP_FAULT", fault)
        .output()
        .expect("run kdmap")
}

/// Every file under `dir`, recursively.
fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let Ok(rd) = std::fs::read_dir(dir) else {
        return out;
    };
    for e in rd.flatten() {
        let p = e.path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out
}

/// Sizes measured on an uninterrupted run.
struct Sizes {
    /// One state snapshot.
    snapshot: u64,
    /// The last manifest before the finished one (manifests only grow during a run).
    manifest: u64,
    /// Checkpoints before the outputs.
    checkpoints: u64,
    /// Every output file (everything outside `checkpoint/`).
    outputs: u64,
    /// `geometry.tiles` and `state.tiles`.
    working: u64,
}

fn sizes(full: &Path) -> Sizes {
    let ck = full.join("checkpoint");
    let prev = std::fs::read(ck.join(PREV_MANIFEST)).unwrap();
    let m = decode::<Progress>(&prev).unwrap();
    assert!(matches!(
        m.payload.stage,
        RunStage::Iterations { stopped: true, .. }
    ));
    let len = |p: &Path| std::fs::metadata(p).unwrap().len();
    Sizes {
        snapshot: m.snapshot.unwrap().bytes,
        manifest: prev.len() as u64,
        checkpoints: m.seq,
        outputs: walk(full)
            .iter()
            .filter(|p| !p.starts_with(&ck))
            .map(|p| len(p))
            .sum(),
        working: len(&ck.join("geometry.tiles")) + len(&ck.join("state.tiles")),
    }
}

/// The run failed cleanly: exit code 74 (EX_IOERR), no panic, exactly one `error:` line on
/// stderr, which contains every one of `parts`. Returns that line.
fn one_error_line(o: &Output, parts: &[&str]) -> String {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(74), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error")).collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(lines[0].starts_with("error: "), "{err}");
    if parts.contains(&"No space left on device") {
        assert_eq!(err.matches("No space left").count(), 1, "{err}");
    }
    for p in parts {
        assert!(lines[0].contains(p), "no {p:?} in {:?}", lines[0]);
    }
    eprintln!("  {}", lines[0]);
    lines[0].to_string()
}

/// The checkpoint in `out` is whole: the manifest decodes and loads (its snapshot exists with
/// the length and checksum it names), with no note about an unusable one; no temporary file
/// is left anywhere in `out`.
fn assert_checkpoint_intact(out: &Path) -> Manifest<Progress> {
    let ck = out.join("checkpoint");
    let tmps: Vec<PathBuf> = walk(out)
        .into_iter()
        .filter(|p| {
            let name = p.file_name().unwrap().to_string_lossy();
            name.ends_with(".tmp") || name == "progress.new"
        })
        .collect();
    assert!(tmps.is_empty(), "temporary files left: {tmps:?}");
    let m = manifest(out).expect("the manifest decodes");
    let s = m.snapshot.as_ref().expect("a snapshot");
    let len = std::fs::metadata(ck.join(&s.file)).unwrap().len();
    assert_eq!(len, s.bytes, "{}", s.file);
    let (loaded, notes) = load::<Progress>(&ck);
    assert!(notes.is_empty(), "{notes:?}");
    assert_eq!(loaded.as_ref(), Some(&m));
    m
}

fn resume_to_the_end(a: &[&str], full: &Path, out: &Path) {
    let mut resume = a.to_vec();
    resume.push("--resume");
    let o = run(&resume);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("resuming from checkpoint"), "{err}");
    assert!(manifest(out).is_some_and(|m| m.payload.stage == RunStage::Finished));
    assert_same_outputs(full, out);
}

#[test]
fn a_full_disk_or_unwritable_output_fails_in_one_line_and_resume_ends_bit_for_bit() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = write_fast_config(tmp.path());
    let full = tmp.path().join("full");
    let o = run(&fast_args(&cfg, &full));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let z = sizes(&full);
    assert_eq!(z.checkpoints, 7);
    assert!(z.outputs > 100 * z.manifest);

    // 1. The disk fills during the second checkpoint's snapshot (half of it fits).
    let out = tmp.path().join("ckpt");
    let a = fast_args(&cfg, &out);
    let n = z.snapshot + z.manifest + z.snapshot / 2;
    let o = run_with_fault(&a, &format!("enospc-after-bytes:{n}"));
    let dir = out.join("checkpoint");
    one_error_line(
        &o,
        &[dir.to_str().unwrap(), "state.2.", "No space left on device"],
    );
    let m = assert_checkpoint_intact(&out);
    assert_eq!((m.seq, m.payload.stage), (1, RunStage::Direct));
    resume_to_the_end(&a, &full, &out);

    // 2. The disk fills half-way through the outputs: every checkpoint was written.
    let out = tmp.path().join("outputs");
    let a = fast_args(&cfg, &out);
    let n = z.checkpoints * (z.snapshot + z.manifest) + z.outputs / 2;
    let o = run_with_fault(&a, &format!("enospc-after-bytes:{n}"));
    let line = one_error_line(&o, &[out.to_str().unwrap(), "No space left on device"]);
    assert!(!line.contains("checkpoint"), "{line}");
    let m = assert_checkpoint_intact(&out);
    assert_eq!(m.seq, 7);
    assert!(matches!(
        m.payload.stage,
        RunStage::Iterations { stopped: true, .. }
    ));
    assert!(!out.join("report.json").exists());
    resume_to_the_end(&a, &full, &out);

    // 3. An output file that cannot be written (a directory where the floor's albedo goes;
    // the directory itself passes the check before the run): the run fails at the end, the
    // last checkpoint survives, and resumes once it is fixed.
    let out = tmp.path().join("blocked");
    let blocker = out.join("textures/floor_albedo.exr");
    std::fs::create_dir_all(blocker.join("in the way")).unwrap();
    let a = fast_args(&cfg, &out);
    let o = run(&a);
    one_error_line(&o, &[blocker.to_str().unwrap()]);
    let m = assert_checkpoint_intact(&out);
    assert_eq!(m.seq, 7);
    std::fs::remove_dir_all(&blocker).unwrap();
    resume_to_the_end(&a, &full, &out);

    // 4. An output directory whose parent is a regular file: nothing can be written at all.
    let file = tmp.path().join("file");
    std::fs::write(&file, b"").unwrap();
    let out = file.join("out");
    let o = run(&fast_args(&cfg, &out));
    one_error_line(&o, &[out.to_str().unwrap(), "Not a directory"]);
}

/// Unmounts on drop (before the temporary directory holding the mount point is removed).
struct Mounted(PathBuf);

impl Drop for Mounted {
    fn drop(&mut self) {
        let ok = Command::new("umount")
            .arg(&self.0)
            .status()
            .is_ok_and(|s| s.success());
        if !ok {
            let _ = Command::new("umount").arg("-l").arg(&self.0).status();
        }
    }
}

fn mount_opts(dir: &Path, opts: &str, remount: bool) -> Result<(), String> {
    let mut c = Command::new("mount");
    if remount {
        c.args(["-o", opts]).arg(dir);
    } else {
        c.args(["-t", "tmpfs", "-o", opts, "tmpfs"]).arg(dir);
    }
    match c.output() {
        Ok(o) if o.status.success() => Ok(()),
        Ok(o) => Err(String::from_utf8_lossy(&o.stderr).trim().to_string()),
        Err(e) => Err(e.to_string()),
    }
}

#[test]
fn a_real_full_tmpfs_fails_in_one_line_and_resume_ends_bit_for_bit() {
    let tmp = tempfile::tempdir().unwrap();
    let mnt = tmp.path().join("mnt");
    std::fs::create_dir(&mnt).unwrap();
    // Room for the working files, one snapshot and a half: the second snapshot cannot fit.
    // (Measured sizes are on a regular disk; tmpfs counts whole pages, as the sizes are.)
    let cfg = write_fast_config(tmp.path());
    let full = tmp.path().join("full");
    if let Err(e) = mount_opts(&mnt, "size=64k", false) {
        eprintln!("note: skipping the real disk-full test: cannot mount a tmpfs ({e})");
        return;
    }
    let _mounted = Mounted(mnt.clone());
    let o = run(&fast_args(&cfg, &full));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let z = sizes(&full);
    let kib = (z.working + z.snapshot + z.snapshot / 2).div_ceil(1024);
    mount_opts(&mnt, &format!("remount,size={kib}k"), true).unwrap();

    let out = mnt.join("out");
    let a = fast_args(&cfg, &out);
    let o = run(&a);
    let dir = out.join("checkpoint");
    one_error_line(
        &o,
        &[dir.to_str().unwrap(), "state.", "No space left on device"],
    );
    let m = assert_checkpoint_intact(&out);
    assert!(m.seq >= 1, "{m:?}");

    // More room, then resume.
    let kib = (z.working + 4 * z.snapshot + z.outputs).div_ceil(1024) + 4096;
    mount_opts(&mnt, &format!("remount,size={kib}k"), true).unwrap();
    resume_to_the_end(&a, &full, &out);
}

/// The tile stores are memory-mapped: without preallocation a full disk would surface as a
/// SIGBUS when a page is first written. `TileStore::create` reserves the blocks up front, so
/// it is an ENOSPC error naming the file instead.
#[test]
fn a_tile_store_larger_than_the_disk_is_refused_at_creation() {
    use kdmap::atlas::store::TexelState;
    use kdmap::atlas::store::TileStore;
    let tmp = tempfile::tempdir().unwrap();
    let mnt = tmp.path().join("mnt");
    std::fs::create_dir(&mnt).unwrap();
    if let Err(e) = mount_opts(&mnt, "size=1m", false) {
        eprintln!("note: skipping the tile-store disk-full test: cannot mount a tmpfs ({e})");
        return;
    }
    let _mounted = Mounted(mnt.clone());
    let path = mnt.join("state.tiles");
    // 16 tiles x 4096 texels x 72 bytes = 4.5 MiB on a 1 MiB filesystem.
    let Err(e) = TileStore::<TexelState>::create(&path, 16, 4096, TexelState::default()) else {
        panic!("a store larger than the filesystem must be refused");
    };
    let msg = e.to_string();
    assert!(
        msg.contains("state.tiles") && msg.contains("No space left"),
        "{msg}"
    );
    // A store that fits is created and fully usable.
    let mut s = TileStore::<TexelState>::create(&path, 2, 1024, TexelState::default()).unwrap();
    s.for_each_tile_mut(2, |_, st| st[0].weight = 1.0).unwrap();
    assert_eq!(s.read_tile(1).unwrap()[0].weight, 1.0);
}
