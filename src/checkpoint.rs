//! Crash-safe checkpoints of a long run, so `kdmap reconstruct --resume` continues an
//! interrupted run and ends with bit-identical outputs. This module knows how to store and
//! find a checkpoint, not what a run's progress means: the caller gives the fingerprint of its
//! inputs and a typed payload (where the run stands, its report so far), which is stored
//! with `bincode` and handed back on load.
//!
//! A checkpoint is two files in the run's checkpoint directory:
//!
//! - `state.<seq>.tiles`: a byte copy of the working state store (every per-texel quantity of
//!   every stage), taken where it is consistent, fsynced before the manifest names it;
//! - `progress.kdm`: the manifest, written atomically (tmp file, fsync, rename, fsync of
//!   the directory). Its first line is a text header `KDMCKPT <version> <fnv1a64 hex>
//!   <bytes>` over the binary payload that follows: the inputs fingerprint, the sequence
//!   number, the seconds spent so far, the snapshot's name, length and hash, and the
//!   caller's payload.
//!
//! The previous manifest is kept as `progress.prev.kdm` with its snapshot, so a torn or
//! corrupt manifest or snapshot (bad header, checksum or length) is reported in one line
//! and the run falls back to the checkpoint before it. Older snapshots are deleted.
//!
//! Stores that are pure functions of the inputs (the geometry) are not checkpointed: they
//! are rebuilt on resume. All randomness is keyed by (seed, iteration, batch, index), so
//! restoring the state exactly restores the run.
//!
//! A write that fails (disk full, unwritable directory) removes its temporary file and
//! returns a one-line [`Error::Io`] naming the file; the previous checkpoint is untouched
//! (snapshots are deleted only after the new manifest is durable), so `--resume` continues
//! from it once there is room. The `KDMAP_FAULT` test hooks are described in
//! [`crate::base::fsio`].

use crate::base::error::{Error, Result};
use crate::base::fsio::{self, fault, fnv1a, write_counted, Fault, Fnv};
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Checkpoint writes ([`Writer::write`] calls) begun by this process (the pause hooks count
/// them).
static CHECKPOINT_WRITES: AtomicU64 = AtomicU64::new(0);

/// Manifest format version this build reads and writes; a checkpoint of another version is
/// refused. It changes with anything a checkpoint holds: the texel layout for given inputs,
/// what the state's fields mean and their size (92 bytes a texel), and the fields of the
/// config and report it carries (bincode is not self-describing, so a checkpoint with other
/// fields would not decode).
pub const VERSION: u32 = 18;
const MAGIC: &str = "KDMCKPT";
/// The current manifest.
pub const MANIFEST: &str = "progress.kdm";
/// The manifest before it, kept for fallback.
pub const PREV_MANIFEST: &str = "progress.prev.kdm";
/// An unusable manifest set aside by [`load_for_resume`].
pub const BAD_MANIFEST: &str = "progress.bad.kdm";

/// The manifest: the generic part, and the caller's payload `P`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest<P> {
    /// The fingerprint of the inputs and result-affecting settings the run was made with.
    pub inputs_hash: u64,
    /// Checkpoint sequence number (1, 2, ...).
    pub seq: u64,
    /// Seconds spent by the run so far, over every attempt.
    pub seconds: f64,
    /// The state snapshot (file name in the checkpoint dir), its length and FNV-1a; `None`
    /// when the caller said there is no state to keep (a finished run).
    pub snapshot: Option<Snapshot>,
    /// Where the run stands, as the caller describes it.
    pub payload: P,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Snapshot {
    pub file: String,
    pub bytes: u64,
    pub fnv1a: u64,
}

/// Largest payload a manifest may hold: decoding never allocates more than this, whatever a
/// damaged file claims.
const MAX_PAYLOAD: usize = 64 << 20;

fn bincode_config() -> impl bincode::config::Config {
    bincode::config::standard().with_limit::<MAX_PAYLOAD>()
}

/// Encodes a manifest: header line, then the binary payload.
pub fn encode<P: Serialize>(m: &Manifest<P>) -> Result<Vec<u8>> {
    let payload = bincode::serde::encode_to_vec(m, bincode_config())
        .map_err(|e| Error::internal(format!("checkpoint: {e}")))?;
    let mut out = format!(
        "{MAGIC} {VERSION} {:016x} {}\n",
        fnv1a(&payload),
        payload.len()
    )
    .into_bytes();
    out.extend_from_slice(&payload);
    Ok(out)
}

/// Decodes and verifies a manifest; the error says what is wrong in a few words. Never
/// trusts the content: the length and checksum are checked before the payload is decoded,
/// and decoding is bounded.
pub fn decode<P: DeserializeOwned>(bytes: &[u8]) -> std::result::Result<Manifest<P>, String> {
    let nl = bytes
        .iter()
        .take(128)
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
    let (m, used) = bincode::serde::decode_from_slice(payload, bincode_config())
        .map_err(|e| format!("bad payload: {e}"))?;
    if used != payload.len() {
        return Err(format!(
            "bad payload: {} trailing bytes",
            payload.len() - used
        ));
    }
    check_snapshot_name(&m)?;
    Ok(m)
}

/// A manifest names only its own snapshot, `state.<seq>.tiles` in its directory: never a
/// path elsewhere, whatever the (checksummed) content says.
fn check_snapshot_name<P>(m: &Manifest<P>) -> std::result::Result<(), String> {
    match &m.snapshot {
        Some(s) if s.file != snapshot_name(m.seq) => Err(format!(
            "bad payload: checkpoint {} names snapshot {:?}, not {:?}",
            m.seq,
            s.file,
            snapshot_name(m.seq)
        )),
        _ => Ok(()),
    }
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
                    fsio::pause_forever(dir);
                }
            }
            write_counted(*d, chunk).map_err(|e| Error::io(*p, e))?;
        }
        len += n as u64;
    }
    Ok((len, h.finish()))
}

/// Share of a run's time that writing its mid-run checkpoints may take.
pub const TIME_SHARE: f64 = 0.05;
/// Share of the free disk the checkpoint files may take: the two kept snapshots and the one
/// being written.
pub const DISK_SHARE: f64 = 0.5;

/// What the last checkpoint write measured: the inputs of [`cadence`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WriteCost {
    /// Bytes of one snapshot.
    pub snapshot_bytes: u64,
    /// Seconds the whole write took (copy, hash, fsync, manifest).
    pub seconds: f64,
    /// Bytes free on the checkpoint directory's disk after it, if known.
    pub free_bytes: Option<u64>,
    /// Bytes of the snapshots kept after it (the next write replaces the older one).
    pub kept_bytes: u64,
}

/// Why the period between mid-run checkpoints is what it is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Why {
    /// `checkpoint_every_seconds = 0`: at every opportunity.
    EveryChance,
    /// `checkpoint_every_seconds`, the least period (nothing measured yet, or it is enough).
    Least,
    /// Writing one takes so long that a shorter period would spend more than [`TIME_SHARE`].
    WriteTime,
    /// Three snapshots would take more than [`DISK_SHARE`] of the free disk: none mid-run.
    Disk,
}

/// The period between mid-run checkpoints and why (see [`cadence`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cadence {
    /// Seconds from the end of one checkpoint to the next; infinite: none mid-run.
    pub period_s: f64,
    pub why: Why,
}

/// The period between mid-run checkpoints: at least `least_s`, and long enough that writing
/// them takes at most [`TIME_SHARE`] of the run (a write of `w` seconds every `p` seconds
/// takes `w / (p + w)`, so `p >= w (1 / share - 1)`); none mid-run when the snapshots on disk
/// during a write (two kept, one new) would exceed [`DISK_SHARE`] of the room they have
/// (the free bytes and those the kept ones hold). `least_s = 0` checkpoints at every chance.
pub fn cadence(least_s: f64, cost: Option<&WriteCost>) -> Cadence {
    let at = |period_s, why| Cadence { period_s, why };
    if least_s <= 0.0 {
        return at(0.0, Why::EveryChance);
    }
    let Some(c) = cost else {
        return at(least_s, Why::Least);
    };
    if let Some(free) = c.free_bytes {
        let room = free.saturating_add(c.kept_bytes) as f64;
        if 3.0 * c.snapshot_bytes as f64 > DISK_SHARE * room {
            return at(f64::INFINITY, Why::Disk);
        }
    }
    let by_time = c.seconds * (1.0 / TIME_SHARE - 1.0);
    match by_time > least_s {
        true => at(by_time, Why::WriteTime),
        false => at(least_s, Why::Least),
    }
}

/// The note that says what [`cadence`] chose and why.
pub fn describe(c: &Cadence, least_s: f64, cost: &WriteCost) -> String {
    let mb = |b: u64| b as f64 / 1e6;
    let one = format!(
        "a checkpoint is {:.0} MB, written in {:.1} s ({:.0} MB/s)",
        mb(cost.snapshot_bytes),
        cost.seconds,
        mb(cost.snapshot_bytes) / cost.seconds.max(1e-9)
    );
    let pct = 100.0 * TIME_SHARE;
    match c.why {
        Why::EveryChance => format!("checkpoints at every chance (run.checkpoint_every_seconds = 0): {one}"),
        Why::Least => format!(
            "checkpoints at most every {least_s:.0} s (run.checkpoint_every_seconds): {one}, under {pct:.0}% of the run"
        ),
        Why::WriteTime => format!(
            "checkpoints every {:.0} s rather than {least_s:.0} s: {one}, so that writing them takes at most {pct:.0}% of the run",
            c.period_s
        ),
        Why::Disk => format!(
            "no more checkpoints until the run ends: {one}, and three of them would take more than {:.0}% of the {:.0} MB free",
            100.0 * DISK_SHARE,
            mb(cost.free_bytes.unwrap_or(0) + cost.kept_bytes)
        ),
    }
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
    /// When the last checkpoint was written (or the writer made).
    last: std::time::Instant,
    /// `run.checkpoint_every_seconds`: the least period between mid-run checkpoints.
    least_s: f64,
    /// What the last snapshot's write measured, and the period chosen from it.
    cost: Option<WriteCost>,
    cadence: Cadence,
    /// The cadence last described in a note.
    told: Option<Cadence>,
}

impl Writer {
    /// A writer continuing after checkpoint `seq` (0 for a fresh run), with mid-run
    /// checkpoints at least `least_s` seconds apart (see [`cadence`]).
    pub fn new(dir: &Path, inputs_hash: u64, seq: u64, least_s: f64) -> Writer {
        Writer {
            dir: dir.to_path_buf(),
            inputs_hash,
            seq,
            bytes_written: 0,
            seconds: 0.0,
            last: std::time::Instant::now(),
            least_s,
            cost: None,
            cadence: cadence(least_s, None),
            told: None,
        }
    }

    /// Whether a mid-run checkpoint is due: the period [`cadence`] chose has passed since the
    /// last one.
    pub fn due(&self) -> bool {
        self.since_last() >= self.cadence.period_s
    }

    /// What the period is and why, when it is first measured or has changed by half or more
    /// since the last such note.
    pub fn cadence_note(&mut self) -> Option<String> {
        let (c, cost) = (self.cadence, self.cost?);
        let same = self.told.is_some_and(|t| {
            let ratio = c.period_s / t.period_s;
            t.why == c.why && (c.period_s == t.period_s || (0.67..1.5).contains(&ratio))
        });
        if same {
            return None;
        }
        self.told = Some(c);
        Some(describe(&c, self.least_s, &cost))
    }

    /// Seconds since the last checkpoint this writer wrote (or since it was made).
    pub fn since_last(&self) -> f64 {
        self.last.elapsed().as_secs_f64()
    }

    /// The sequence number of the last checkpoint written (0: none yet).
    pub fn seq(&self) -> u64 {
        self.seq
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

    /// Checkpoint: snapshot `state_path` (which must hold the state `payload` describes, its
    /// writes done) if `state_path` is given, then replace the manifest atomically, keeping
    /// the previous one, and delete snapshots neither manifest names.
    pub fn write<P: Serialize>(
        &mut self,
        state_path: Option<&Path>,
        payload: &P,
        seconds: f64,
    ) -> Result<()> {
        let t0 = std::time::Instant::now();
        let nth = CHECKPOINT_WRITES.fetch_add(1, Ordering::SeqCst) + 1;
        let seq = self.seq + 1;
        let snapshot = if let Some(state_path) = state_path {
            let file = snapshot_name(seq);
            let pause = (fault() == Some(Fault::PauseInCheckpoint(nth))).then_some(&*self.dir);
            let (bytes, fnv1a) = copy_hashed(state_path, &self.dir.join(&file), pause)?;
            self.bytes_written += bytes;
            Some(Snapshot { file, bytes, fnv1a })
        } else {
            None
        };
        let m = Manifest {
            inputs_hash: self.inputs_hash,
            seq,
            seconds,
            snapshot,
            payload,
        };
        let bytes = encode(&m)?;
        self.bytes_written += bytes.len() as u64;
        let cur = self.dir.join(MANIFEST);
        let tmp = self.dir.join("progress.new");
        let pause = fault() == Some(Fault::PauseInManifest(nth));
        let written = File::create(&tmp).and_then(|mut f| {
            if pause {
                write_counted(&mut f, &bytes[..bytes.len() / 2])?;
                fsio::pause_forever(&self.dir);
            }
            write_counted(&mut f, &bytes)?;
            f.sync_all()
        });
        if let Err(e) = written {
            let _ = std::fs::remove_file(&tmp);
            return Err(Error::io(&tmp, e));
        }
        // A kill between these renames leaves only the previous manifest: loading falls back.
        if cur.exists() {
            let prev = self.dir.join(PREV_MANIFEST);
            std::fs::rename(&cur, &prev).map_err(|e| Error::io(&prev, e))?;
        }
        std::fs::rename(&tmp, &cur).map_err(|e| Error::io(&cur, e))?;
        fsio::sync_dir(&self.dir)?;
        self.seq = seq;
        let kept_bytes = self.remove_stale_snapshots();
        let seconds = t0.elapsed().as_secs_f64();
        self.seconds += seconds;
        self.last = std::time::Instant::now();
        if let Some(s) = &m.snapshot {
            self.measured(WriteCost {
                snapshot_bytes: s.bytes,
                seconds,
                free_bytes: fsio::free_bytes(&self.dir),
                kept_bytes,
            });
        }
        Ok(())
    }

    /// A snapshot's write measured: the period follows it.
    fn measured(&mut self, cost: WriteCost) {
        self.cadence = cadence(self.least_s, Some(&cost));
        self.cost = Some(cost);
    }

    /// Delete the snapshots before the previous checkpoint's, and copies a kill left
    /// half-written. Returns the bytes of the snapshots kept.
    fn remove_stale_snapshots(&self) -> u64 {
        let Ok(rd) = std::fs::read_dir(&self.dir) else {
            return 0;
        };
        let mut kept = 0;
        for e in rd.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            let seq = snapshot_seq(&name);
            let stale = seq.is_some_and(|s| s + 1 < self.seq)
                || (name.starts_with("state.") && name.ends_with(".tmp"));
            if stale {
                let _ = std::fs::remove_file(e.path());
            } else if seq.is_some() {
                kept += e.metadata().map_or(0, |m| m.len());
            }
        }
        kept
    }
}

/// The snapshot file of checkpoint `seq`.
fn snapshot_name(seq: u64) -> String {
    format!("state.{seq}.tiles")
}

/// `Some(seq)` for a file named `state.<seq>.tiles`.
fn snapshot_seq(name: &str) -> Option<u64> {
    name.strip_prefix("state.")?
        .strip_suffix(".tiles")?
        .parse()
        .ok()
}

/// Reads a manifest file and checks its snapshot's length and hash.
fn load_one<P: DeserializeOwned>(
    dir: &Path,
    name: &str,
) -> std::result::Result<Manifest<P>, String> {
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
pub fn load<P: DeserializeOwned>(dir: &Path) -> (Option<Manifest<P>>, Vec<String>) {
    let (m, notes, _) = load_which(dir);
    (m, notes)
}

/// [`load`] for a run about to continue: if the current manifest is unusable and the
/// previous one is used, the bad one is renamed [`BAD_MANIFEST`], so the next checkpoint
/// does not rotate it into [`PREV_MANIFEST`] over the good one.
pub fn load_for_resume<P: DeserializeOwned>(
    dir: &Path,
) -> Result<(Option<Manifest<P>>, Vec<String>)> {
    let (m, notes, from_prev) = load_which(dir);
    let cur = dir.join(MANIFEST);
    if from_prev && cur.exists() {
        let bad = dir.join(BAD_MANIFEST);
        std::fs::rename(&cur, &bad).map_err(|e| Error::io(&bad, e))?;
        fsio::sync_dir(dir)?;
    }
    Ok((m, notes))
}

fn load_which<P: DeserializeOwned>(dir: &Path) -> (Option<Manifest<P>>, Vec<String>, bool) {
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
pub fn restore<P>(dir: &Path, m: &Manifest<P>, state_path: &Path) -> Result<()> {
    let s = m
        .snapshot
        .as_ref()
        .ok_or_else(|| Error::corrupt(dir.join(MANIFEST), "checkpoint has no state snapshot"))?;
    let (len, sum) = copy_hashed(&dir.join(&s.file), state_path, None)?;
    if len != s.bytes || sum != s.fnv1a {
        return Err(Error::corrupt(
            dir.join(&s.file),
            "snapshot changed while being restored",
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cost(mb: u64, seconds: f64, free_mb: Option<u64>, kept_mb: u64) -> WriteCost {
        WriteCost {
            snapshot_bytes: mb << 20,
            seconds,
            free_bytes: free_mb.map(|f| f << 20),
            kept_bytes: kept_mb << 20,
        }
    }

    #[test]
    fn the_period_keeps_checkpoint_writes_to_five_percent_of_the_run() {
        // nothing measured yet, or writes fast enough: the configured period
        assert_eq!(
            cadence(60.0, None),
            Cadence {
                period_s: 60.0,
                why: Why::Least
            }
        );
        let fast = cost(100, 1.0, Some(100_000), 200);
        assert_eq!(cadence(60.0, Some(&fast)).why, Why::Least);
        // 19 x 3 s = 57 s < 60 s: still the configured period
        assert_eq!(cadence(60.0, Some(&cost(300, 3.0, None, 0))).period_s, 60.0);
        // 4.6 GB at 100 MB/s: 46 s a write, so 19 x 46 s = 874 s between writes
        let slow = cost(4600, 46.0, Some(1_000_000), 9200);
        let c = cadence(60.0, Some(&slow));
        assert_eq!(c.why, Why::WriteTime);
        assert!((c.period_s - 874.0).abs() < 1e-9, "{c:?}");
        // the share of the time spent writing is exactly 5% at that period
        assert!((46.0 / (c.period_s + 46.0) - TIME_SHARE).abs() < 1e-12);
        // 0: every chance, whatever the cost
        assert_eq!(
            cadence(0.0, Some(&slow)),
            Cadence {
                period_s: 0.0,
                why: Why::EveryChance
            }
        );
    }

    #[test]
    fn no_mid_run_checkpoints_when_three_would_take_over_half_the_free_disk() {
        // 1 GB snapshots, 2 kept: room 2 + free; 3 GB must fit in half of it
        let at = |free_mb| cadence(60.0, Some(&cost(1024, 1.0, Some(free_mb), 2048))).why;
        assert_eq!(at(4 * 1024), Why::Least, "3 GB <= (4 + 2) / 2");
        assert_eq!(
            at(4 * 1024 - 1),
            Why::Disk,
            "3 GB > (4 GB - 1 MB + 2 GB) / 2"
        );
        assert_eq!(
            cadence(60.0, Some(&cost(1024, 1.0, Some(0), 2048))).period_s,
            f64::INFINITY
        );
        // free space unknown: only the time share
        assert_eq!(
            cadence(60.0, Some(&cost(1024, 1.0, None, 0))).why,
            Why::Least
        );
    }

    #[test]
    fn the_note_says_the_period_and_why_and_only_when_it_changes() {
        let dir = tempfile::tempdir().unwrap();
        let mut w = Writer::new(dir.path(), 1, 0, 60.0);
        assert_eq!(w.cadence_note(), None, "nothing measured");
        w.measured(cost(4600, 46.0, None, 0));
        let n = w.cadence_note().unwrap();
        assert!(
            n.starts_with("checkpoints every 874 s rather than 60 s"),
            "{n}"
        );
        assert!(
            n.contains("4823 MB, written in 46.0 s (105 MB/s)") && n.contains("5%"),
            "{n}"
        );
        w.measured(cost(4600, 50.0, None, 0));
        assert_eq!(w.cadence_note(), None, "within a factor 1.5");
        w.measured(cost(4600, 1.0, Some(1000), 0));
        let n = w.cadence_note().unwrap();
        assert!(
            n.starts_with("no more checkpoints until the run ends"),
            "{n}"
        );
        assert!(!w.due(), "an infinite period is never due");
    }

    #[test]
    fn a_snapshot_write_measures_its_cost() {
        let dir = tempfile::tempdir().unwrap();
        let state = dir.path().join("state.tiles");
        std::fs::write(&state, vec![7u8; 1 << 16]).unwrap();
        let mut w = Writer::new(dir.path(), 1, 0, 60.0);
        w.write(Some(&state), &0u32, 0.0).unwrap();
        let c = w.cost.unwrap();
        assert_eq!((c.snapshot_bytes, c.kept_bytes), (1 << 16, 1 << 16));
        assert!(c.seconds > 0.0 && c.free_bytes.is_some(), "{c:?}");
        w.write(Some(&state), &0u32, 0.0).unwrap();
        w.write(Some(&state), &0u32, 0.0).unwrap();
        assert_eq!(w.cost.unwrap().kept_bytes, 2 << 16, "two snapshots kept");
        // a manifest alone (the finished run's) measures nothing
        let before = w.cost;
        w.write(None, &0u32, 0.0).unwrap();
        assert_eq!(w.cost, before);
    }

    /// The checkpoint carries the config in bincode, which is not self-describing: with a field
    /// added or removed an older checkpoint no longer decodes ("bad payload"), so the checkpoint
    /// format version must change with the config's fields. This is the list of them at
    /// [`VERSION`]: update both together.
    #[test]
    fn the_config_s_fields_change_with_the_checkpoint_version() {
        fn keys(v: &serde_json::Value, prefix: &str, out: &mut Vec<String>) {
            if let serde_json::Value::Object(m) = v {
                for (k, v) in m {
                    out.push(format!("{prefix}{k}"));
                    keys(v, &format!("{prefix}{k}."), out);
                }
            }
        }
        let mut got = Vec::new();
        let cfg = serde_json::to_value(crate::config::Config::for_scene("s.xml".into())).unwrap();
        keys(&cfg, "", &mut got);
        got.sort();
        let mut want: Vec<&str> = "scene views exposure pinned_gains refine_pose response colmap \
            colmap_to_world atlas atlas.texels_per_unit atlas.max_texels \
            atlas.padding atlas.use_mesh_uvs atlas.tile_size atlas.max_texture_size \
            refine_passes fine_geometry refine_step refine_gate refine_gated_from refine_settle denoise_radius denoise_z \
            tv_weight noise_probe area_samples env_samples unobserved_share method gather_rays gather_spacing \
            photons photons_per_texel batch_size max_depth smoothing_radius iterations \
            tolerance alpha0 update relaxation initial_indirect_share seed threads \
            checkpoint_every_batches checkpoint_every_seconds memory_budget_mib min_observed_share known_shapes kept_coats \
            photometric_scale uv_fold uniform_radius uniform_tolerance"
            .split_whitespace()
            .collect();
        want.sort();
        assert_eq!(
            (VERSION, got),
            (18, want.iter().map(|s| s.to_string()).collect::<Vec<_>>()),
            "the config's fields changed: bump VERSION and update this list"
        );
    }
}
