//! Crash-safe file writes shared by images, outputs and checkpoints: a file appears under its
//! name only once it is complete and durable (temporary file, fsync, rename), a failed write
//! leaves nothing behind, and directories are synced when a rename must survive a crash.
//!
//! # Fault injection (test hook)
//!
//! The environment variable `KDMAP_FAULT` is read once per process, at the first write that
//! consults it; unset (or with an unknown value) it has no effect. It exists for the crash and
//! disk-full tests (`tests/it/resume.rs`, `tests/it/diskfull.rs`):
//!
//! - `pause-in-checkpoint:N`: during the N-th checkpoint write of the process (1-based),
//!   once half of the snapshot's bytes are in its temporary file (before fsync and rename),
//!   create `<checkpoint dir>/fault.paused` and sleep forever (the test then SIGKILLs);
//! - `pause-in-manifest:N`: the same, once half of the N-th manifest is in its temporary file;
//! - `enospc-after-bytes:N`: once the process has written N bytes in total through this
//!   module (checkpoint snapshots and their restore on resume, manifests, every output file),
//!   every such write fails with `ENOSPC` (os error 28) as a full disk would.

use crate::base::error::{Error, Result};
use std::ffi::OsString;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, OnceLock};

/// A fault injected by `KDMAP_FAULT` (module doc, "Fault injection").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fault {
    PauseInCheckpoint(u64),
    PauseInManifest(u64),
    EnospcAfterBytes(u64),
}

/// The fault `KDMAP_FAULT` asks for, parsed once.
pub fn fault() -> Option<Fault> {
    static FAULT: OnceLock<Option<Fault>> = OnceLock::new();
    *FAULT.get_or_init(|| parse_fault(&std::env::var("KDMAP_FAULT").ok()?))
}

fn parse_fault(v: &str) -> Option<Fault> {
    let (kind, n) = v.trim().split_once(':')?;
    let n: u64 = n.trim().parse().ok()?;
    match kind.trim() {
        "pause-in-checkpoint" => Some(Fault::PauseInCheckpoint(n)),
        "pause-in-manifest" => Some(Fault::PauseInManifest(n)),
        "enospc-after-bytes" => Some(Fault::EnospcAfterBytes(n)),
        _ => None,
    }
}

/// Bytes written through [`write_counted`] and [`count_written`] by this process (counted
/// only under `enospc-after-bytes`).
static BYTES_WRITTEN: AtomicU64 = AtomicU64::new(0);

/// The error a full disk gives.
fn enospc() -> std::io::Error {
    std::io::Error::from_raw_os_error(28) // ENOSPC
}

/// `w.write_all(bytes)`: under `enospc-after-bytes:N`, the bytes beyond the process's N-th
/// are not written and the write fails with `ENOSPC`.
pub fn write_counted(w: &mut impl Write, bytes: &[u8]) -> std::io::Result<()> {
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
/// [`write_counted`]: counts it, and under `enospc-after-bytes:N` fails with `ENOSPC` if it
/// takes the process past N bytes.
pub fn count_written(len: u64) -> std::io::Result<()> {
    if let Some(Fault::EnospcAfterBytes(limit)) = fault() {
        let before = BYTES_WRITTEN.fetch_add(len, Ordering::SeqCst);
        if before.saturating_add(len) > limit {
            return Err(enospc());
        }
    }
    Ok(())
}

/// Under a pause fault: create `<dir>/fault.paused` and sleep forever.
pub fn pause_forever(dir: &Path) -> ! {
    let _ = std::fs::write(dir.join("fault.paused"), b"");
    loop {
        std::thread::sleep(std::time::Duration::from_secs(3600));
    }
}

/// `<path>.tmp`, the name a file is written under before it is renamed into place.
pub fn tmp_path(path: &Path) -> PathBuf {
    let mut s = OsString::from(path.as_os_str());
    s.push(".tmp");
    PathBuf::from(s)
}

/// Write `bytes` to `path` atomically: `<path>.tmp`, fsync, rename. On error (a full disk
/// included) the temporary file is removed and the error names `path`.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic_with(path, |tmp| {
        let mut f = File::create(tmp).map_err(|e| Error::io(path, e))?;
        write_counted(&mut f, bytes).map_err(|e| Error::io(path, e))
    })
}

/// [`write_atomic`] for a file streamed through a buffered writer by `write` (an encoder that
/// writes as it goes, so the whole file is never held): the buffer is flushed before the file
/// is counted, fsynced and renamed, so a write that fails at the flush (a full disk) is an
/// error, not a truncated file dropped into place.
pub fn write_atomic_buffered(
    path: &Path,
    write: impl FnOnce(&mut std::io::BufWriter<File>) -> Result<()>,
) -> Result<()> {
    write_atomic_with(path, |tmp| {
        let file = File::create(tmp).map_err(|e| Error::io(path, e))?;
        let mut w = std::io::BufWriter::new(file);
        write(&mut w)?;
        w.flush().map_err(|e| Error::io(path, e))
    })
}

/// [`write_atomic`] for a file that `write` produces at the temporary path it is given (a
/// library encoder); the file is then counted by the fault hook, fsynced and renamed.
pub fn write_atomic_with(path: &Path, write: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let tmp = tmp_path(path);
    let done = write(&tmp).and_then(|()| {
        let f = File::options()
            .append(true)
            .open(&tmp)
            .map_err(|e| Error::io(path, e))?;
        let len = f.metadata().map_err(|e| Error::io(path, e))?.len();
        count_written(len)
            .and_then(|()| match unsynced(path) {
                true => Ok(()),
                false => f.sync_all(),
            })
            .map_err(|e| Error::io(path, e))
    });
    if let Err(e) = done {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    rename_into_place(&tmp, path)
}

/// Directories whose files [`write_atomic_with`] writes without a per-file fsync, until
/// their [`Unsynced::commit`] makes them durable together (one `syncfs`).
static UNSYNCED: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// A directory whose files are written, renamed into place at once, and made durable
/// together at [`Unsynced::commit`]: thousands of small outputs (a scene of 5,000 shapes
/// writes 90,000 maps) took two minutes of fsyncs one by one. Until the commit a crash may
/// leave files in it that are not durable, so whatever marks the directory complete (a
/// run's `report.json`) is written after the commit.
pub struct Unsynced {
    root: PathBuf,
}

impl Unsynced {
    /// Files under `root` skip their own fsync from now until [`Unsynced::commit`].
    pub fn begin(root: &Path) -> Unsynced {
        let root = root.to_path_buf();
        UNSYNCED
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(root.clone());
        Unsynced { root }
    }

    /// Every file written under the root made durable (its file system synced), and the
    /// root's files fsynced one by one again from now on.
    pub fn commit(self) -> Result<()> {
        let dir = File::open(&self.root).map_err(|e| Error::io(&self.root, e))?;
        rustix::fs::syncfs(&dir).map_err(|e| Error::io(&self.root, e.into()))
    }
}

impl Drop for Unsynced {
    fn drop(&mut self) {
        let mut roots = UNSYNCED.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(i) = roots.iter().position(|r| *r == self.root) {
            roots.remove(i);
        }
    }
}

/// Whether `path` lies under a root of an open [`Unsynced`].
fn unsynced(path: &Path) -> bool {
    let roots = UNSYNCED.lock().unwrap_or_else(|e| e.into_inner());
    roots.iter().any(|r| path.starts_with(r))
}

/// Rename the finished temporary file `tmp` to `path`; on failure remove `tmp` and name
/// `path` in the error.
pub fn rename_into_place(tmp: &Path, path: &Path) -> Result<()> {
    std::fs::rename(tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(tmp);
        Error::io(path, e)
    })
}

/// Fsync a directory so renames in it are durable.
pub fn sync_dir(dir: &Path) -> Result<()> {
    File::open(dir)
        .and_then(|d| d.sync_all())
        .map_err(|e| Error::io(dir, e))
}

/// 64-bit FNV-1a, incrementally: the checksum of checkpoints and the fingerprint of inputs.
/// Written by hand (a dozen lines): it guards against torn writes and changed files, not
/// adversaries, and needs no dependency.
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

/// The bytes free to an unprivileged process on the file system holding `dir`, if known.
pub fn free_bytes(dir: &Path) -> Option<u64> {
    let s = rustix::fs::statvfs(dir).ok()?;
    Some(s.f_bavail.saturating_mul(s.f_frsize))
}

/// `create_dir_all` with the usual error.
pub fn create_dir(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_buffered_file_is_whole_when_written_and_absent_when_its_writer_fails() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.bin");
        // more than the buffer holds, so part is written before the flush and part by it
        let bytes: Vec<u8> = (0..20_001u32).map(|i| (i % 251) as u8).collect();
        write_atomic_buffered(&path, |w| {
            w.write_all(&bytes).map_err(|e| Error::io(&path, e))
        })
        .unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), bytes);
        assert!(!tmp_path(&path).exists());
        let failed = dir.path().join("b.bin");
        let e = write_atomic_buffered(&failed, |w| {
            w.write_all(&bytes).map_err(|e| Error::io(&failed, e))?;
            Err(Error::internal("the encoder failed"))
        });
        assert!(e.unwrap_err().to_string().contains("the encoder failed"));
        assert!(!failed.exists() && !tmp_path(&failed).exists());
    }

    #[test]
    fn files_under_an_unsynced_root_are_in_place_at_once_and_synced_at_the_commit() {
        let dir = tempfile::tempdir().unwrap();
        let (root, other) = (dir.path().join("out"), dir.path().join("other"));
        create_dir(&root).unwrap();
        let batch = Unsynced::begin(&root);
        assert!(unsynced(&root.join("maps/a.exr")) && !unsynced(&other.join("a.exr")));
        write_atomic(&root.join("a.txt"), b"kept").unwrap();
        assert_eq!(std::fs::read(root.join("a.txt")).unwrap(), b"kept");
        assert!(!tmp_path(&root.join("a.txt")).exists());
        batch.commit().unwrap();
        assert!(!unsynced(&root.join("a.txt")));
        // dropped without a commit (an error on the way): the root is released too
        drop(Unsynced::begin(&root));
        assert!(!unsynced(&root.join("a.txt")));
    }

    #[test]
    fn fault_values_parse_and_unknown_ones_do_nothing() {
        assert_eq!(
            parse_fault("pause-in-checkpoint:3"),
            Some(Fault::PauseInCheckpoint(3))
        );
        assert_eq!(
            parse_fault(" enospc-after-bytes : 100 "),
            Some(Fault::EnospcAfterBytes(100))
        );
        assert_eq!(parse_fault("pause-in-manifest:x"), None);
        assert_eq!(parse_fault("explode:1"), None);
        assert_eq!(parse_fault(""), None);
    }

    #[test]
    fn fnv1a_matches_the_reference_values() {
        assert_eq!(fnv1a(b""), 0xcbf2_9ce4_8422_2325);
        assert_eq!(fnv1a(b"a"), 0xaf63_dc4c_8601_ec8c);
        assert_eq!(fnv1a(b"foobar"), 0x8594_4171_f739_67e8);
    }

    #[test]
    fn atomic_write_replaces_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.txt");
        write_atomic(&p, b"one").unwrap();
        write_atomic(&p, b"two").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"two");
        assert!(!tmp_path(&p).exists());
        // a failing producer leaves neither the file nor its temporary
        let q = dir.path().join("b.bin");
        let e = write_atomic_with(&q, |tmp| {
            std::fs::write(tmp, b"half").unwrap();
            Err(Error::io(&q, enospc()))
        })
        .unwrap_err();
        assert!(e.to_string().contains("b.bin"), "{e}");
        assert!(!q.exists() && !tmp_path(&q).exists());
        // a write into a missing directory names the file
        let r = dir.path().join("nope/c.txt");
        let e = write_atomic(&r, b"x").unwrap_err().to_string();
        assert!(e.starts_with(&r.display().to_string()), "{e}");
    }
}
