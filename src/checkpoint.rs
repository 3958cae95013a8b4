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
pub const VERSION: u32 = 14;
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
            last: std::time::Instant::now(),
        }
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
        self.last = std::time::Instant::now();
        Ok(())
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
            refine_passes refine_step refine_gate refine_gated_from denoise_radius denoise_z \
            tv_weight noise_probe area_samples env_samples method gather_rays gather_spacing \
            photons photons_per_texel batch_size max_depth smoothing_radius iterations \
            tolerance alpha0 update relaxation initial_indirect_share seed threads \
            checkpoint_every_batches checkpoint_every_seconds memory_budget_mib known_shapes \
            photometric_scale uv_fold uniform_radius uniform_tolerance"
            .split_whitespace()
            .collect();
        want.sort();
        assert_eq!(
            (VERSION, got),
            (14, want.iter().map(|s| s.to_string()).collect::<Vec<_>>()),
            "the config's fields changed: bump VERSION and update this list"
        );
    }
}
