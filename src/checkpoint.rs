//! Crash-safe checkpoints of a reconstruction so `kdmap reconstruct --resume` continues an
//! interrupted run and ends with bit-identical outputs.
//!
//! A checkpoint is two files in `<out>/checkpoint/`:
//!
//! - `state.<seq>.tiles`: a byte copy of the working `state.tiles` (the per-texel state of
//!   every stage: L_orig, E_d, E_i, K_d, error, the photon accumulator, flags) taken at a
//!   point where it is consistent, fsynced before the manifest names it;
//! - `progress.json`: the manifest, written atomically (tmp file, fsync, rename, fsync of
//!   the directory). Its first line is a header `KDMCKPT <version> <fnv1a64 hex> <bytes>`
//!   over the JSON payload that follows; the payload holds a hash of the inputs and of the
//!   result-affecting settings, where the run stands ([`Stage`]), the report so far and the
//!   snapshot's name, length and hash.
//!
//! The previous manifest is kept as `progress.prev.json` with its snapshot, so a torn or
//! corrupt manifest or snapshot (bad header, checksum or length) is reported in one line
//! and the run falls back to the checkpoint before it. Older snapshots are deleted.
//!
//! The geometry store is not checkpointed: it is a pure function of the scene and settings
//! and is rebuilt on resume. All randomness is keyed by (seed, iteration, batch, index), so
//! restoring the state exactly restores the run.
//!
//! Checksums are hand-written 64-bit FNV-1a: they guard against torn writes and bit rot, not
//! adversaries, and the crate needs no extra dependency for them.
//!
//! A write that fails (disk full, unwritable directory) removes its temporary file and
//! returns a one-line [`Error::Io`] naming the file; the previous checkpoint is untouched
//! (snapshots are deleted only after the new manifest is durable), so `--resume` continues
//! from it once there is room.
//!
//! # Fault injection (test hook)
//!
//! The environment variable `KDMAP_FAULT` is read once per process, at the first
//! checkpoint or output write; unset (or with an unknown value) it has no effect. It exists
//! for the crash and disk-full tests (`tests/it/resume.rs`, `tests/it/diskfull.rs`):
//!
//! - `pause-in-checkpoint:N`: during the N-th checkpoint write of the process (1-based),
//!   once half of the snapshot's bytes are in its temporary file (before fsync and rename),
//!   create `<checkpoint dir>/fault.paused` and sleep forever (the test then SIGKILLs);
//! - `pause-in-manifest:N`: the same, once half of the N-th manifest is in `progress.new`;
//! - `enospc-after-bytes:N`: once the process has written N bytes in total through
//!   checkpoint snapshots (and their restore on resume), manifests and output files
//!   (`output::write_file_atomic`, the EXR/PNG writers of [`crate::image`]), every such
//!   write fails with `ENOSPC` (os error 28) as a full disk would.

use crate::config::Config;
use crate::error::{Error, Result};
use crate::report::Report;
use serde::{Deserialize, Serialize};
use std::fs::File;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::OnceLock;

/// A fault injected by `KDMAP_FAULT` (module doc, "Fault injection").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Fault {
    PauseInCheckpoint(u64),
    PauseInManifest(u64),
    EnospcAfterBytes(u64),
}

/// The fault `KDMAP_FAULT` asks for, parsed once.
fn fault() -> Option<Fault> {
    static FAULT: OnceLock<Option<Fault>> = OnceLock::new();
    *FAULT.get_or_init(|| {
        let v = std::env::var("KDMAP_FAULT").ok()?;
        let (kind, n) = v.trim().split_once(':')?;
        let n: u64 = n.trim().parse().ok()?;
        match kind.trim() {
            "pause-in-checkpoint" => Some(Fault::PauseInCheckpoint(n)),
            "pause-in-manifest" => Some(Fault::PauseInManifest(n)),
            "enospc-after-bytes" => Some(Fault::EnospcAfterBytes(n)),
            _ => None,
        }
    })
}

/// Checkpoint writes ([`Writer::write`] calls) begun by this process.
static CHECKPOINT_WRITES: AtomicU64 = AtomicU64::new(0);
/// Bytes written through [`write_counted`] and [`count_written`] by this process (counted
/// only under `enospc-after-bytes`).
static BYTES_WRITTEN: AtomicU64 = AtomicU64::new(0);

/// The error a full disk gives.
fn enospc() -> std::io::Error {
    std::io::Error::from_raw_os_error(28) // ENOSPC
}

/// `w.write_all(bytes)` for checkpoint and output files: under `enospc-after-bytes:N`, the
/// bytes beyond the process's N-th are not written and the write fails with `ENOSPC`.
pub(crate) fn write_counted(w: &mut impl Write, bytes: &[u8]) -> std::io::Result<()> {
    if let Some(Fault::EnospcAfterBytes(limit)) = fault() {
        let len = bytes.len() as u64;
        let before = BYTES_WRITTEN.fetch_add(len, Ordering::SeqCst);
        if before.saturating_add(len) > limit {
            let room = limit.saturating_sub(before).min(len) as usize;
            w.write_all(&bytes[..room])?;
            return Err(enospc());
        }
    }
    w.write_all(bytes)
}

/// For a file of `len` bytes written by a library (the EXR encoder) rather than through
/// [`write_counted`]: counts it, and under `enospc-after-bytes:N` fails with `ENOSPC` if
/// it takes the process past N bytes. The caller removes the file on error.
pub(crate) fn count_written(len: u64) -> std::io::Result<()> {
    if let Some(Fault::EnospcAfterBytes(limit)) = fault() {
        let before = BYTES_WRITTEN.fetch_add(len, Ordering::SeqCst);
        if before.saturating_add(len) > limit {
            return Err(enospc());
        }
    }
    Ok(())
}

/// Under a pause fault: create `<dir>/fault.paused` and sleep forever.
fn pause_forever(dir: &Path) -> ! {
    let _ = std::fs::write(dir.join("fault.paused"), b"");
    loop {
        std::thread::sleep(std::time::Duration::from_secs(3600));
    }
}

/// Manifest format version this build reads and writes.
pub const VERSION: u32 = 1;
const MAGIC: &str = "KDMCKPT";
/// The current manifest.
pub const MANIFEST: &str = "progress.json";
/// The manifest before it, kept for fallback.
pub const PREV_MANIFEST: &str = "progress.prev.json";

/// 64-bit FNV-1a, incrementally.
#[derive(Debug, Clone, Copy)]
pub struct Fnv(u64);

impl Default for Fnv {
    fn default() -> Self {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv {
    pub fn update(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 ^= u64::from(b);
            self.0 = self.0.wrapping_mul(0x0100_0000_01b3);
        }
    }
    pub fn finish(&self) -> u64 {
        self.0
    }
}

/// FNV-1a 64 of `bytes`.
pub fn fnv1a(bytes: &[u8]) -> u64 {
    let mut h = Fnv::default();
    h.update(bytes);
    h.finish()
}

/// Where a run stands. Each variant names the state `state.tiles` holds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Stage {
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

/// The projection counts the report needs at the end.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct ProjCounts {
    pub views: usize,
    pub masked_pixels: usize,
    pub covered_texels: u64,
    pub observed_texels: u64,
}

/// The manifest payload.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Hash of the inputs and the result-affecting settings ([`inputs_hash`]).
    pub inputs_hash: u64,
    /// Checkpoint sequence number (1, 2, ...).
    pub seq: u64,
    pub stage: Stage,
    pub projection: ProjCounts,
    /// The report so far: per-iteration statistics, timings (seconds spent so far).
    pub report: Report,
    /// Seconds spent by the run so far, over every attempt.
    pub seconds: f64,
    /// The state snapshot (file name in the checkpoint dir), its length and FNV-1a; `None`
    /// once finished.
    pub snapshot: Option<Snapshot>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Snapshot {
    pub file: String,
    pub bytes: u64,
    pub fnv1a: u64,
}

/// Hash of everything that changes the result: the scene file, every file its XML names
/// (`filename` attributes: meshes, textures), the photos, and the config without `threads`,
/// `checkpoint_every_batches` and `memory_budget_mib` (which never change results).
pub fn inputs_hash(cfg: &Config, photos: &[PathBuf]) -> Result<u64> {
    let mut h = Fnv::default();
    let mut c = cfg.clone();
    c.threads = 0;
    c.checkpoint_every_batches = 1;
    c.memory_budget_mib = 0;
    let json = serde_json::to_vec(&c).map_err(|e| Error::Config(format!("settings: {e}")))?;
    h.update(&json);
    let xml = std::fs::read(&cfg.scene).map_err(|e| Error::io(&cfg.scene, e))?;
    h.update(&xml);
    let dir = cfg.scene.parent().unwrap_or(Path::new("."));
    if let Ok(text) = std::str::from_utf8(&xml) {
        if let Ok(doc) = roxmltree::Document::parse(text) {
            for n in doc.descendants() {
                if let Some(f) = n.attribute("filename") {
                    let p = dir.join(f);
                    h.update(f.as_bytes());
                    if let Ok(bytes) = std::fs::read(&p) {
                        h.update(&bytes);
                    }
                }
            }
        }
    }
    for p in photos {
        h.update(p.to_string_lossy().as_bytes());
        let bytes = std::fs::read(p).map_err(|e| Error::io(p, e))?;
        h.update(&(bytes.len() as u64).to_le_bytes());
        h.update(&bytes);
    }
    Ok(h.finish())
}

/// Encodes a manifest: header line, then the JSON payload.
pub fn encode(m: &Manifest) -> Result<Vec<u8>> {
    let payload =
        serde_json::to_vec_pretty(m).map_err(|e| Error::Config(format!("checkpoint: {e}")))?;
    let mut out = format!(
        "{MAGIC} {VERSION} {:016x} {}\n",
        fnv1a(&payload),
        payload.len()
    )
    .into_bytes();
    out.extend_from_slice(&payload);
    Ok(out)
}

/// Decodes and verifies a manifest; the error says what is wrong in a few words.
pub fn decode(bytes: &[u8]) -> std::result::Result<Manifest, String> {
    let nl = bytes
        .iter()
        .position(|&b| b == b'\n')
        .ok_or("no header line (torn or not a checkpoint)")?;
    let header = std::str::from_utf8(&bytes[..nl]).map_err(|_| "header is not text")?;
    let f: Vec<&str> = header.split(' ').collect();
    if f.len() != 4 || f[0] != MAGIC {
        return Err("bad header (not a kdmap checkpoint)".into());
    }
    let version: u32 = f[1].parse().map_err(|_| "bad header version")?;
    if version != VERSION {
        return Err(format!(
            "checkpoint format version {version}, this build reads {VERSION}"
        ));
    }
    let sum = u64::from_str_radix(f[2], 16).map_err(|_| "bad header checksum")?;
    let len: usize = f[3].parse().map_err(|_| "bad header length")?;
    let payload = &bytes[nl + 1..];
    if payload.len() != len {
        return Err(format!(
            "payload is {} bytes, header says {len} (torn write)",
            payload.len()
        ));
    }
    if fnv1a(payload) != sum {
        return Err("checksum mismatch (corrupt)".into());
    }
    serde_json::from_slice(payload).map_err(|e| format!("bad payload: {e}"))
}

/// Fsync a directory so renames in it are durable.
fn sync_dir(dir: &Path) -> Result<()> {
    File::open(dir)
        .and_then(|d| d.sync_all())
        .map_err(|e| Error::io(dir, e))
}

/// Copy `from` to `to` (through `<to>.tmp`, fsynced, renamed), returning its length and
/// FNV-1a. On error the temporary file is removed. With `pause_dir`, pause (test hook) once
/// half of the bytes are written.
fn copy_hashed(from: &Path, to: &Path, pause_dir: Option<&Path>) -> Result<(u64, u64)> {
    let tmp = to.with_extension("tmp");
    let mut src = File::open(from).map_err(|e| Error::io(from, e))?;
    let pause = match pause_dir {
        Some(dir) => {
            let len = src.metadata().map_err(|e| Error::io(from, e))?.len();
            Some((dir, len / 2))
        }
        None => None,
    };
    let copied = (|| {
        let mut dst = File::create(&tmp).map_err(|e| Error::io(&tmp, e))?;
        let (len, sum) = pump(&mut src, from, Some((&mut dst, &tmp)), pause)?;
        dst.sync_all().map_err(|e| Error::io(&tmp, e))?;
        drop(dst);
        std::fs::rename(&tmp, to).map_err(|e| Error::io(to, e))?;
        Ok((len, sum))
    })();
    if copied.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    copied
}

/// Read `src` to its end, hashing, optionally writing everything to `dst` (through
/// [`write_counted`]); with `pause = Some((dir, at))`, [`pause_forever`] once `at` bytes
/// are written.
fn pump(
    src: &mut File,
    from: &Path,
    mut dst: Option<(&mut File, &Path)>,
    pause: Option<(&Path, u64)>,
) -> Result<(u64, u64)> {
    let mut buf = vec![0u8; 1 << 20];
    let mut h = Fnv::default();
    let mut len = 0u64;
    loop {
        let n = src.read(&mut buf).map_err(|e| Error::io(from, e))?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
        if let Some((d, p)) = dst.as_mut() {
            let chunk = &buf[..n];
            if let Some((dir, at)) = pause {
                if at < len + n as u64 {
                    let half = &chunk[..at.saturating_sub(len) as usize];
                    write_counted(*d, half).map_err(|e| Error::io(*p, e))?;
                    pause_forever(dir);
                }
            }
            write_counted(*d, chunk).map_err(|e| Error::io(*p, e))?;
        }
        len += n as u64;
    }
    Ok((len, h.finish()))
}

/// Writes checkpoints of one run into its checkpoint directory.
#[derive(Debug)]
pub struct Writer {
    dir: PathBuf,
    inputs_hash: u64,
    seq: u64,
    /// Bytes written by checkpoints so far (snapshots and manifests).
    pub bytes_written: u64,
    /// Seconds spent writing checkpoints so far.
    pub seconds: f64,
}

impl Writer {
    /// A writer continuing after checkpoint `seq` (0 for a fresh run).
    pub fn new(dir: &Path, inputs_hash: u64, seq: u64) -> Writer {
        Writer {
            dir: dir.to_path_buf(),
            inputs_hash,
            seq,
            bytes_written: 0,
            seconds: 0.0,
        }
    }

    /// Removes every checkpoint file of an earlier run (a fresh start).
    pub fn clear(dir: &Path) -> Result<()> {
        let Ok(rd) = std::fs::read_dir(dir) else {
            return Ok(());
        };
        for e in rd.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if name.starts_with("progress.")
                || snapshot_seq(&name).is_some()
                || (name.starts_with("state.") && name.ends_with(".tmp"))
            {
                let p = e.path();
                std::fs::remove_file(&p).map_err(|e| Error::io(&p, e))?;
            }
        }
        Ok(())
    }

    /// Checkpoint: snapshot `state_path` (which must hold the state `stage` names, its
    /// writes done) unless finished, then replace the manifest atomically, keeping the
    /// previous one, and delete snapshots neither manifest names.
    pub fn write(
        &mut self,
        state_path: &Path,
        stage: Stage,
        projection: ProjCounts,
        report: &Report,
        seconds: f64,
    ) -> Result<()> {
        let t0 = std::time::Instant::now();
        let nth = CHECKPOINT_WRITES.fetch_add(1, Ordering::SeqCst) + 1;
        let seq = self.seq + 1;
        let snapshot = if stage == Stage::Finished {
            None
        } else {
            let file = format!("state.{seq}.tiles");
            let pause = (fault() == Some(Fault::PauseInCheckpoint(nth))).then_some(&*self.dir);
            let (bytes, fnv1a) = copy_hashed(state_path, &self.dir.join(&file), pause)?;
            self.bytes_written += bytes;
            Some(Snapshot { file, bytes, fnv1a })
        };
        let m = Manifest {
            inputs_hash: self.inputs_hash,
            seq,
            stage,
            projection,
            report: report.clone(),
            seconds,
            snapshot,
        };
        let bytes = encode(&m)?;
        self.bytes_written += bytes.len() as u64;
        let cur = self.dir.join(MANIFEST);
        let tmp = self.dir.join("progress.new");
        let pause = fault() == Some(Fault::PauseInManifest(nth));
        let written = File::create(&tmp).and_then(|mut f| {
            if pause {
                write_counted(&mut f, &bytes[..bytes.len() / 2])?;
                pause_forever(&self.dir);
            }
            write_counted(&mut f, &bytes)?;
            f.sync_all()
        });
        if let Err(e) = written {
            let _ = std::fs::remove_file(&tmp);
            return Err(Error::io(&tmp, e));
        }
        // A kill between these renames leaves only progress.prev.json: loading falls back.
        if cur.exists() {
            let prev = self.dir.join(PREV_MANIFEST);
            std::fs::rename(&cur, &prev).map_err(|e| Error::io(&prev, e))?;
        }
        std::fs::rename(&tmp, &cur).map_err(|e| Error::io(&cur, e))?;
        sync_dir(&self.dir)?;
        self.seq = seq;
        // Keep the snapshots of this checkpoint and the previous one.
        if let Ok(rd) = std::fs::read_dir(&self.dir) {
            for e in rd.flatten() {
                let name = e.file_name().to_string_lossy().into_owned();
                // Older snapshots, and copies a kill left half-written.
                let stale = snapshot_seq(&name).is_some_and(|s| s + 1 < seq)
                    || (name.starts_with("state.") && name.ends_with(".tmp"));
                if stale {
                    let _ = std::fs::remove_file(e.path());
                }
            }
        }
        self.seconds += t0.elapsed().as_secs_f64();
        Ok(())
    }
}

/// `Some(seq)` for a file named `state.<seq>.tiles`.
fn snapshot_seq(name: &str) -> Option<u64> {
    name.strip_prefix("state.")?
        .strip_suffix(".tiles")?
        .parse()
        .ok()
}

/// Reads a manifest file and checks its snapshot's length and hash.
fn load_one(dir: &Path, name: &str) -> std::result::Result<Manifest, String> {
    let path = dir.join(name);
    let bytes = std::fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let m = decode(&bytes).map_err(|e| format!("{}: {e}", path.display()))?;
    if let Some(s) = &m.snapshot {
        let p = dir.join(&s.file);
        let mut f = File::open(&p).map_err(|e| format!("{}: {e}", p.display()))?;
        let (len, sum) = pump(&mut f, &p, None, None).map_err(|e| e.to_string())?;
        if len != s.bytes || sum != s.fnv1a {
            return Err(format!(
                "{}: snapshot does not match its manifest ({len} bytes, checksum {sum:016x}; expected {} bytes, {:016x})",
                p.display(),
                s.bytes,
                s.fnv1a
            ));
        }
    }
    Ok(m)
}

/// The newest good checkpoint in `dir`: the current manifest, else the previous one. `None`
/// if neither is usable (or there is none); the notes say, one line each, which checkpoint
/// was unusable and why.
pub fn load(dir: &Path) -> (Option<Manifest>, Vec<String>) {
    let (m, notes, _) = load_which(dir);
    (m, notes)
}

/// [`load`] for a run about to continue: if the current manifest is unusable and the
/// previous one is used, the bad one is renamed `progress.bad.json`, so the next checkpoint
/// does not rotate it into `progress.prev.json` over the good one.
pub fn load_for_resume(dir: &Path) -> Result<(Option<Manifest>, Vec<String>)> {
    let (m, notes, from_prev) = load_which(dir);
    let cur = dir.join(MANIFEST);
    if from_prev && cur.exists() {
        let bad = dir.join("progress.bad.json");
        std::fs::rename(&cur, &bad).map_err(|e| Error::io(&bad, e))?;
        sync_dir(dir)?;
    }
    Ok((m, notes))
}

fn load_which(dir: &Path) -> (Option<Manifest>, Vec<String>, bool) {
    let mut notes = Vec::new();
    for name in [MANIFEST, PREV_MANIFEST] {
        if !dir.join(name).exists() {
            continue;
        }
        match load_one(dir, name) {
            Ok(m) => return (Some(m), notes, name == PREV_MANIFEST),
            Err(e) => notes.push(format!("unusable checkpoint: {e}; falling back")),
        }
    }
    (None, notes, false)
}

/// Restores the working state file from a manifest's snapshot.
pub fn restore(dir: &Path, m: &Manifest, state_path: &Path) -> Result<()> {
    let s = m
        .snapshot
        .as_ref()
        .ok_or_else(|| Error::Config("checkpoint has no state snapshot".into()))?;
    let (len, sum) = copy_hashed(&dir.join(&s.file), state_path, None)?;
    if len != s.bytes || sum != s.fnv1a {
        return Err(Error::input(
            dir.join(&s.file),
            "snapshot changed while being restored",
        ));
    }
    Ok(())
}
