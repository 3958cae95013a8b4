//! File-backed per-texel state split into fixed-size tiles and memory-mapped a window at a
//! time, so a scene whose state exceeds RAM still runs with a bounded working set.
//!
//! A [`TileStore<T>`] holds `tile_count` tiles of `tile_texels` records of a plain-old-data
//! type `T` in ONE file. Stages are plain functions over tiles:
//! [`TileStore::for_each_tile_mut`] maps `window_tiles` tiles, runs the stage over them in
//! parallel (rayon, one task per tile), then unmaps them before mapping the next window, so
//! the resident set stays near `window_tiles * tile_stride_bytes()` whatever the file size.
//! Each tile is handed to exactly one call of the stage function and windows run in tile
//! order, so results are bit-identical whatever the thread count or window size, as long as
//! the stage function itself only depends on its tile index and tile contents.
//! [`window_tiles_for_budget`] picks a window from an RSS budget.
//!
//! # On-disk format (version 1)
//!
//! ```text
//! offset  size  field
//! 0       8     magic  b"KDMTILES"
//! 8       4     format version, u32 little-endian (= 1)
//! 12      4     byte-order mark 0x01020304, u32 in the writer's native order
//! 16      4     record size in bytes, u32 LE (= size_of::<T>())
//! 20      4     reserved, zero
//! 24      8     tile_texels (records per tile), u64 LE, > 0
//! 32      8     tile_count, u64 LE
//! 40      8     tile_stride in bytes, u64 LE
//!                 = record_size * tile_texels rounded up to a multiple of 4096
//! 48      8     user tag, u64 LE (e.g. a hash of the scene and settings; 0 if unset)
//! 56      4040  zero
//! 4096    ...   tile 0 .. tile_count-1, back to back, each tile_stride bytes:
//!               tile_texels records (native byte order, `T`'s in-memory layout),
//!               then zero padding up to tile_stride
//! ```
//!
//! The file length is exactly `4096 + tile_count * tile_stride`. Every tile starts on a
//! 4096-byte boundary, so a window of tiles maps at a page-aligned offset and each tile's
//! records are aligned for any `T` whose alignment is at most 4096. Records are stored in
//! native byte order; the byte-order mark makes a file written on a machine of the other
//! endianness fail to open instead of reading garbage. [`TileStore::open`] refuses a wrong
//! magic, version, byte order or record size, and a file whose length disagrees with its
//! header (truncated or extended), with a one-line error naming the file.
//!
//! Durability: windows are unmapped after use with their dirty pages left to the kernel's
//! write-back (which throttles writers when too much is dirty). Call [`TileStore::flush`] or
//! [`TileStore::sync_all`] when the state must be on disk, e.g. at a checkpoint.
//!
//! # Safety
//!
//! This is the only module of the crate that contains `unsafe`: creating memory maps
//! (`memmap2::MmapOptions::map`/`map_mut`). A mapping of a file is only sound while nothing
//! else changes or truncates the mapped range behind Rust's back. The store guarantees this
//! within the process:
//!
//! - maps exist only inside [`TileStore::for_each_tile_mut`] / [`TileStore::for_each_tile`]
//!   and are dropped (unmapped) before those return; no reference into a map escapes,
//!   because the callbacks only borrow the tile slices for the duration of the call;
//! - the mutable walk takes `&mut self`, and every method that writes the file
//!   ([`TileStore::write_tile`], [`TileStore::set_tag`]) takes `&mut self` too, so no read or
//!   write of the file through this store can overlap a mapping of it;
//! - the mapped range is checked against the file's current length before each walk, so a
//!   file shortened since `open` gives an error rather than a fault;
//! - each mutable window is split into disjoint per-tile slices (`par_chunks_mut`), so no
//!   two threads ever alias a tile.
//!
//! What the store cannot enforce is exclusive access to the file across processes (or
//! across two `TileStore`s opened on the same path): while a store is in use, nothing else
//! may write, truncate or re-`create` its file. kdmap keeps its stores in a private work
//! directory, which callers must not share between concurrent runs.

use std::fs::{File, OpenOptions};
use std::marker::PhantomData;
use std::mem::{align_of, size_of};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use bytemuck::Pod;
use memmap2::{MmapMut, MmapOptions};
use rayon::prelude::*;

use crate::{Error, Result};

/// First 8 bytes of every tile-store file.
pub const MAGIC: [u8; 8] = *b"KDMTILES";
/// The on-disk format version this build reads and writes.
pub const FORMAT_VERSION: u32 = 1;
/// Size of the header; tile 0 starts here.
pub const HEADER_BYTES: u64 = 4096;
/// Every tile starts at a multiple of this (the common page size) from the file start.
pub const TILE_ALIGN: u64 = 4096;

const BYTE_ORDER_MARK: u32 = 0x0102_0304;

/// How many tiles of `tile_bytes` bytes (use [`TileStore::tile_stride_bytes`], which
/// includes the padding) fit in an RSS budget of `budget_bytes`; never less than 1, so a
/// budget smaller than one tile still makes progress. The budget covers the mapped window
/// only, not the rest of the process.
pub fn window_tiles_for_budget(budget_bytes: u64, tile_bytes: u64) -> usize {
    let n = (budget_bytes / tile_bytes.max(1)).max(1);
    usize::try_from(n).unwrap_or(usize::MAX)
}

/// Tile stride in bytes for `tile_texels` records of `record_size` bytes: the record bytes
/// rounded up to [`TILE_ALIGN`]. `None` on overflow.
fn tile_stride(record_size: u64, tile_texels: u64) -> Option<u64> {
    let bytes = record_size.checked_mul(tile_texels)?;
    bytes.checked_next_multiple_of(TILE_ALIGN)
}

/// The decoded fixed part of the header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Header {
    record_size: u32,
    tile_texels: u64,
    tile_count: u64,
    tile_stride: u64,
    tag: u64,
}

const TAG_OFFSET: u64 = 48;

impl Header {
    fn encode(&self) -> Vec<u8> {
        let mut h = vec![0u8; HEADER_BYTES as usize];
        h[0..8].copy_from_slice(&MAGIC);
        h[8..12].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
        h[12..16].copy_from_slice(&BYTE_ORDER_MARK.to_ne_bytes());
        h[16..20].copy_from_slice(&self.record_size.to_le_bytes());
        h[24..32].copy_from_slice(&self.tile_texels.to_le_bytes());
        h[32..40].copy_from_slice(&self.tile_count.to_le_bytes());
        h[40..48].copy_from_slice(&self.tile_stride.to_le_bytes());
        h[48..56].copy_from_slice(&self.tag.to_le_bytes());
        h
    }

    /// Decodes and checks the header on its own (not against `T` or the file length).
    /// `h` holds at least 56 bytes.
    fn decode(h: &[u8]) -> std::result::Result<Header, String> {
        let u32_at = |o: usize| u32::from_le_bytes([h[o], h[o + 1], h[o + 2], h[o + 3]]);
        let u64_at = |o: usize| {
            let mut b = [0u8; 8];
            b.copy_from_slice(&h[o..o + 8]);
            u64::from_le_bytes(b)
        };
        if h[0..8] != MAGIC {
            return Err("not a kdmap tile store (bad magic)".into());
        }
        let version = u32_at(8);
        if version != FORMAT_VERSION {
            return Err(format!(
                "unsupported tile-store format version {version} (this build reads {FORMAT_VERSION})"
            ));
        }
        if u32::from_ne_bytes([h[12], h[13], h[14], h[15]]) != BYTE_ORDER_MARK {
            return Err("tile store written on a machine with the other byte order".into());
        }
        let hd = Header {
            record_size: u32_at(16),
            tile_texels: u64_at(24),
            tile_count: u64_at(32),
            tile_stride: u64_at(40),
            tag: u64_at(48),
        };
        if hd.record_size == 0 || hd.tile_texels == 0 {
            return Err(format!(
                "corrupt header: record size {} and tile_texels {} must both be > 0",
                hd.record_size, hd.tile_texels
            ));
        }
        match tile_stride(u64::from(hd.record_size), hd.tile_texels) {
            Some(s) if s == hd.tile_stride => Ok(hd),
            _ => Err(format!(
                "corrupt header: tile stride {} does not match {} records of {} bytes",
                hd.tile_stride, hd.tile_texels, hd.record_size
            )),
        }
    }

    /// Total file length the header implies.
    fn file_len(&self) -> Option<u64> {
        self.tile_count
            .checked_mul(self.tile_stride)?
            .checked_add(HEADER_BYTES)
    }
}

/// A file of `tile_count` tiles, each `tile_texels` records of `T`, accessed through
/// bounded windows of memory-mapped tiles or by whole-tile reads and writes.
pub struct TileStore<T: Pod> {
    file: File,
    path: PathBuf,
    tile_count: usize,
    tile_texels: usize,
    /// Bytes from one tile's start to the next (records plus padding), multiple of TILE_ALIGN.
    tile_stride: usize,
    tag: u64,
    _record: PhantomData<T>,
}

/// Allocate the disk blocks of the first `len` bytes of `file` now, so that a full disk is an
/// `ENOSPC` error here, with a path in the message, rather than a `SIGBUS` later when a page
/// of the memory map is first written (a sparse file has no blocks behind its zero pages).
/// Filesystems that cannot preallocate keep the sparse file.
#[cfg(unix)]
fn reserve(file: &File, len: u64) -> std::io::Result<()> {
    use std::os::fd::AsRawFd;
    let Ok(len) = libc::off_t::try_from(len) else {
        return Err(std::io::Error::from_raw_os_error(libc::EFBIG));
    };
    // SAFETY: `posix_fallocate` only reads its integer arguments; the descriptor is open and
    // owned by `file` for the duration of the call.
    let rc = unsafe { libc::posix_fallocate(file.as_raw_fd(), 0, len) };
    match rc {
        0 => Ok(()),
        libc::EOPNOTSUPP | libc::EINVAL => Ok(()),
        e => Err(std::io::Error::from_raw_os_error(e)),
    }
}

#[cfg(not(unix))]
fn reserve(_file: &File, _len: u64) -> std::io::Result<()> {
    Ok(())
}

impl<T: Pod> std::fmt::Debug for TileStore<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TileStore")
            .field("path", &self.path)
            .field("record", &std::any::type_name::<T>())
            .field("tile_count", &self.tile_count)
            .field("tile_texels", &self.tile_texels)
            .field("tile_stride", &self.tile_stride)
            .field("tag", &self.tag)
            .finish()
    }
}

impl<T: Pod + Send + Sync> TileStore<T> {
    /// Creates (or truncates) `path` as a store of `tile_count` tiles of `tile_texels`
    /// records, every record set to `fill`. The file is sized with `set_len` (sparse) and,
    /// unless `fill` is all zero bytes, written one tile at a time with positioned writes,
    /// so creating a store larger than RAM needs only one tile of memory.
    pub fn create(
        path: impl AsRef<Path>,
        tile_count: usize,
        tile_texels: usize,
        fill: T,
    ) -> Result<Self> {
        let path = path.as_ref();
        let bad = |msg: String| Error::internal(format!("tile store {}: {msg}", path.display()));
        let record_size = record_size::<T>().map_err(bad)?;
        if tile_texels == 0 {
            return Err(bad("tile_texels must be > 0".into()));
        }
        let header = Header {
            record_size,
            tile_texels: tile_texels as u64,
            tile_count: tile_count as u64,
            tile_stride: tile_stride(u64::from(record_size), tile_texels as u64)
                .ok_or_else(|| bad(format!("{tile_texels} texels per tile is too many")))?,
            tag: 0,
        };
        let stride = usize::try_from(header.tile_stride)
            .map_err(|_| bad("tile too large for this platform".into()))?;
        let len = header.file_len().ok_or_else(|| {
            Error::config(format!(
                "tile store {}: {tile_count} tiles is too many",
                path.display()
            ))
        })?;

        let io = |e| Error::io(path, e);
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(path)
            .map_err(io)?;
        file.set_len(len).map_err(io)?;
        reserve(&file, len).map_err(io)?;
        write_all_at(&file, &header.encode(), 0).map_err(io)?;

        let fill_bytes = bytemuck::bytes_of(&fill);
        if fill_bytes.iter().any(|&b| b != 0) {
            // Padding stays zero from set_len; only the records are written.
            let tile = vec![fill; tile_texels];
            let bytes: &[u8] = bytemuck::cast_slice(&tile);
            for i in 0..tile_count as u64 {
                write_all_at(&file, bytes, HEADER_BYTES + i * header.tile_stride).map_err(io)?;
            }
        }
        Ok(TileStore {
            file,
            path: path.to_path_buf(),
            tile_count,
            tile_texels,
            tile_stride: stride,
            tag: 0,
            _record: PhantomData,
        })
    }

    /// Opens an existing store read-write, checking its header against `T` and its length
    /// against the header. Any mismatch is a one-line [`Error::Corrupt`] naming the file.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let io = |e| Error::io(path, e);
        let bad = |msg: String| Error::corrupt(path, msg);
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .open(path)
            .map_err(io)?;
        let len = file.metadata().map_err(io)?.len();
        if len < HEADER_BYTES {
            return Err(bad(format!(
                "truncated tile store: {len} bytes, shorter than its {HEADER_BYTES}-byte header"
            )));
        }
        let mut h = [0u8; 64];
        read_exact_at(&file, &mut h, 0).map_err(io)?;
        let header = Header::decode(&h).map_err(bad)?;

        let want = size_of::<T>();
        if header.record_size as usize != want {
            return Err(bad(format!(
                "tile store holds {}-byte records, expected {want} bytes ({})",
                header.record_size,
                std::any::type_name::<T>()
            )));
        }
        record_size::<T>().map_err(bad)?;
        match header.file_len() {
            Some(expect) if expect == len => {}
            Some(expect) => {
                return Err(bad(format!(
                    "tile store is {len} bytes but its header implies {expect} \
                     ({} tiles of {} bytes after a {HEADER_BYTES}-byte header): {}",
                    header.tile_count,
                    header.tile_stride,
                    if len < expect {
                        "truncated"
                    } else {
                        "trailing data"
                    }
                )))
            }
            None => return Err(bad("corrupt header: tile count overflows".into())),
        }
        let too_big = || bad("tile store too large for this platform".into());
        Ok(TileStore {
            file,
            path: path.to_path_buf(),
            tile_count: usize::try_from(header.tile_count).map_err(|_| too_big())?,
            tile_texels: usize::try_from(header.tile_texels).map_err(|_| too_big())?,
            tile_stride: usize::try_from(header.tile_stride).map_err(|_| too_big())?,
            tag: header.tag,
            _record: PhantomData,
        })
    }

    /// The file backing this store.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Number of tiles.
    pub fn tile_count(&self) -> usize {
        self.tile_count
    }

    /// Records per tile.
    pub fn tile_texels(&self) -> usize {
        self.tile_texels
    }

    /// Bytes each tile occupies in the file and in a mapped window (records plus padding
    /// to [`TILE_ALIGN`]); the `tile_bytes` to give [`window_tiles_for_budget`].
    pub fn tile_stride_bytes(&self) -> u64 {
        self.tile_stride as u64
    }

    /// Bytes of tile data in the file (everything after the header).
    pub fn data_bytes(&self) -> u64 {
        self.tile_count as u64 * self.tile_stride as u64
    }

    /// The user tag from the header (0 until [`TileStore::set_tag`]).
    pub fn tag(&self) -> u64 {
        self.tag
    }

    /// Stores a user tag in the header, e.g. a hash identifying the scene and settings, so
    /// a resumed run can tell whether a checkpoint belongs to it.
    pub fn set_tag(&mut self, tag: u64) -> Result<()> {
        write_all_at(&self.file, &tag.to_le_bytes(), TAG_OFFSET)
            .map_err(|e| Error::io(&self.path, e))?;
        self.tag = tag;
        Ok(())
    }

    /// Copies tile `i` out of the file.
    pub fn read_tile(&self, i: usize) -> Result<Vec<T>> {
        let off = self.tile_offset(i)?;
        let mut v = vec![T::zeroed(); self.tile_texels];
        read_exact_at(&self.file, bytemuck::cast_slice_mut(&mut v), off)
            .map_err(|e| Error::io(&self.path, e))?;
        Ok(v)
    }

    /// Overwrites tile `i` with `data`, which must hold exactly `tile_texels` records.
    pub fn write_tile(&mut self, i: usize, data: &[T]) -> Result<()> {
        let off = self.tile_offset(i)?;
        if data.len() != self.tile_texels {
            return Err(Error::internal(format!(
                "tile store {}: write_tile got {} records, tiles hold {}",
                self.path.display(),
                data.len(),
                self.tile_texels
            )));
        }
        write_all_at(&self.file, bytemuck::cast_slice(data), off)
            .map_err(|e| Error::io(&self.path, e))
    }

    /// Makes all tile data written so far durable on disk (`fdatasync`).
    pub fn flush(&self) -> Result<()> {
        self.file.sync_data().map_err(|e| Error::io(&self.path, e))
    }

    /// Makes tile data and file metadata durable on disk (`fsync`); use at checkpoints.
    pub fn sync_all(&self) -> Result<()> {
        self.file.sync_all().map_err(|e| Error::io(&self.path, e))
    }

    /// Runs `f(tile_index, records)` over every tile, mapping `window_tiles` tiles at a
    /// time read-write and running `f` over a window's tiles in parallel on the current
    /// rayon pool. Each window is unmapped before the next is mapped, so the resident set
    /// stays near `window_tiles * tile_stride_bytes()`. Changes reach the file (page cache)
    /// immediately; call [`TileStore::flush`] for durability. Use a window of at least the
    /// thread count to keep every thread busy.
    pub fn for_each_tile_mut<F>(&mut self, window_tiles: usize, f: F) -> Result<()>
    where
        F: Fn(usize, &mut [T]) + Sync + Send,
    {
        let window = self.check_walk(window_tiles)?;
        let (stride, rec_bytes) = (self.tile_stride, self.tile_texels * size_of::<T>());
        let mut start = 0;
        while start < self.tile_count {
            let n = window.min(self.tile_count - start);
            let (offset, len) = self.window_range(start, n)?;
            // SAFETY: the range lies inside the file (checked against its current length by
            // `check_walk`), this store has exclusive access to the file for the duration of
            // `&mut self` (module `# Safety`), and the map is dropped at the end of this loop
            // iteration, before any other access to the file through this store.
            let mut map: MmapMut = unsafe {
                MmapOptions::new()
                    .offset(offset)
                    .len(len)
                    .map_mut(&self.file)
            }
            .map_err(|e| Error::io(&self.path, e))?;
            advise_willneed(&map);
            map.par_chunks_mut(stride)
                .enumerate()
                .try_for_each(|(j, chunk)| -> Result<()> {
                    let recs = bytemuck::try_cast_slice_mut(&mut chunk[..rec_bytes])
                        .map_err(|e| self.cast_error(e))?;
                    f(start + j, recs);
                    Ok(())
                })?;
            // Start write-back (a no-op hint on Linux, which tracks dirty pages anyway) and
            // unmap: the dirty pages stay in the page cache for the kernel to write, and the
            // process's resident set drops by the window.
            map.flush_async().map_err(|e| Error::io(&self.path, e))?;
            drop(map);
            start += n;
        }
        Ok(())
    }

    /// Runs `f(tile_index, records)` over every tile read-only, mapping `window_tiles`
    /// tiles at a time and running `f` over a window's tiles in parallel.
    pub fn for_each_tile<F>(&self, window_tiles: usize, f: F) -> Result<()>
    where
        F: Fn(usize, &[T]) + Sync,
    {
        let window = self.check_walk(window_tiles)?;
        let (stride, rec_bytes) = (self.tile_stride, self.tile_texels * size_of::<T>());
        let mut start = 0;
        while start < self.tile_count {
            let n = window.min(self.tile_count - start);
            let (offset, len) = self.window_range(start, n)?;
            // SAFETY: the range lies inside the file (checked by `check_walk`); every write
            // to the file through this store needs `&mut self`, which cannot coexist with
            // this `&self` borrow, and other writers are excluded by the module's contract;
            // the map is dropped before this loop iteration ends.
            let map = unsafe { MmapOptions::new().offset(offset).len(len).map(&self.file) }
                .map_err(|e| Error::io(&self.path, e))?;
            map.par_chunks(stride)
                .enumerate()
                .try_for_each(|(j, chunk)| -> Result<()> {
                    let recs = bytemuck::try_cast_slice(&chunk[..rec_bytes])
                        .map_err(|e| self.cast_error(e))?;
                    f(start + j, recs);
                    Ok(())
                })?;
            drop(map);
            start += n;
        }
        Ok(())
    }

    /// Validates a walk: window > 0 and the file still as long as the header says.
    fn check_walk(&self, window_tiles: usize) -> Result<usize> {
        if window_tiles == 0 {
            return Err(Error::internal(format!(
                "tile store {}: window of 0 tiles",
                self.path.display()
            )));
        }
        let len = self
            .file
            .metadata()
            .map_err(|e| Error::io(&self.path, e))?
            .len();
        let expect = HEADER_BYTES + self.data_bytes();
        if len < expect {
            return Err(Error::corrupt(
                &self.path,
                format!("tile store shrank to {len} bytes since it was opened (expected {expect})"),
            ));
        }
        Ok(window_tiles)
    }

    /// File offset and length of the window of `n` tiles starting at tile `start`.
    fn window_range(&self, start: usize, n: usize) -> Result<(u64, usize)> {
        let len = n.checked_mul(self.tile_stride).ok_or_else(|| {
            Error::internal(format!(
                "tile store {}: window of {n} tiles overflows the address space",
                self.path.display()
            ))
        })?;
        Ok((HEADER_BYTES + start as u64 * self.tile_stride as u64, len))
    }

    /// File offset of tile `i`, or an error if it is out of range.
    fn tile_offset(&self, i: usize) -> Result<u64> {
        if i >= self.tile_count {
            return Err(Error::internal(format!(
                "tile store {}: tile {i} out of range ({} tiles)",
                self.path.display(),
                self.tile_count
            )));
        }
        Ok(HEADER_BYTES + i as u64 * self.tile_stride as u64)
    }

    fn cast_error(&self, e: bytemuck::PodCastError) -> Error {
        // Unreachable in practice: tiles start on 4096-byte boundaries of a page-aligned map
        // and `record_size` refuses alignments above that.
        Error::internal(format!(
            "tile store {}: cannot view mapped tile as {}: {e:?}",
            self.path.display(),
            std::any::type_name::<T>()
        ))
    }
}

/// `size_of::<T>()` as a header field, refusing records the format cannot hold.
fn record_size<T: Pod>() -> std::result::Result<u32, String> {
    let name = std::any::type_name::<T>();
    if size_of::<T>() == 0 {
        return Err(format!("zero-sized record type {name}"));
    }
    if align_of::<T>() as u64 > TILE_ALIGN {
        return Err(format!(
            "record type {name} needs alignment above {TILE_ALIGN}"
        ));
    }
    u32::try_from(size_of::<T>()).map_err(|_| format!("record type {name} is too large"))
}

/// Hints the kernel to read a freshly mapped window ahead (fewer, larger reads from disk).
fn advise_willneed(map: &MmapMut) {
    #[cfg(unix)]
    {
        // Only a hint: failure changes nothing but speed.
        let _ = map.advise(memmap2::Advice::WillNeed);
    }
    #[cfg(not(unix))]
    let _ = map;
}

#[cfg(unix)]
fn read_exact_at(file: &File, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
    std::os::unix::fs::FileExt::read_exact_at(file, buf, offset)
}

#[cfg(unix)]
fn write_all_at(file: &File, buf: &[u8], offset: u64) -> std::io::Result<()> {
    std::os::unix::fs::FileExt::write_all_at(file, buf, offset)
}

#[cfg(windows)]
fn read_exact_at(file: &File, mut buf: &mut [u8], mut offset: u64) -> std::io::Result<()> {
    use std::os::windows::fs::FileExt;
    while !buf.is_empty() {
        match file.seek_read(buf, offset)? {
            0 => return Err(std::io::ErrorKind::UnexpectedEof.into()),
            n => {
                buf = &mut buf[n..];
                offset += n as u64;
            }
        }
    }
    Ok(())
}

#[cfg(windows)]
fn write_all_at(file: &File, mut buf: &[u8], mut offset: u64) -> std::io::Result<()> {
    use std::os::windows::fs::FileExt;
    while !buf.is_empty() {
        match file.seek_write(buf, offset)? {
            0 => return Err(std::io::ErrorKind::WriteZero.into()),
            n => {
                buf = &buf[n..];
                offset += n as u64;
            }
        }
    }
    Ok(())
}

/// Run `f(tile, other's tile, tile)` over every tile of `store` (in parallel, `window` tiles
/// mapped at a time), with the same tile of `other` (read-only, e.g. the geometry beside the
/// solver state), and return the results in tile order, so sums over them are deterministic.
/// The first read error of `other` is returned.
pub fn map_tiles<S, G, R>(
    store: &mut TileStore<S>,
    other: &TileStore<G>,
    window: usize,
    f: impl Fn(usize, &[G], &mut [S]) -> R + Sync + Send,
) -> Result<Vec<R>>
where
    S: Pod + Send + Sync,
    G: Pod + Send + Sync,
    R: Send,
{
    let n = store.tile_count();
    let results: Mutex<Vec<Option<R>>> = Mutex::new((0..n).map(|_| None).collect());
    let err: Mutex<Option<Error>> = Mutex::new(None);
    store.for_each_tile_mut(window, |t, st| match other.read_tile(t) {
        Ok(g) => {
            let r = f(t, &g, st);
            results.lock().unwrap_or_else(|e| e.into_inner())[t] = Some(r);
        }
        Err(e) => *err.lock().unwrap_or_else(|e| e.into_inner()) = Some(e),
    })?;
    if let Some(e) = err.into_inner().unwrap_or_else(|e| e.into_inner()) {
        return Err(e);
    }
    Ok(results
        .into_inner()
        .unwrap_or_else(|e| e.into_inner())
        .into_iter()
        .flatten()
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(name: &str) -> (tempfile::TempDir, PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join(name);
        (dir, p)
    }

    #[test]
    fn stride_pads_to_page() {
        assert_eq!(tile_stride(72, 64 * 64), Some(72 * 4096));
        assert_eq!(tile_stride(4, 10), Some(4096));
        assert_eq!(tile_stride(4, 1025), Some(8192));
        assert_eq!(tile_stride(u64::MAX, 2), None);
    }

    #[test]
    fn budget_to_window() {
        assert_eq!(window_tiles_for_budget(64 << 20, 288 << 10), 227);
        assert_eq!(window_tiles_for_budget(10, 4096), 1);
        assert_eq!(window_tiles_for_budget(8192, 0), 8192);
    }

    #[test]
    fn header_round_trip() {
        let h = Header {
            record_size: 72,
            tile_texels: 4096,
            tile_count: 7,
            tile_stride: 72 * 4096,
            tag: 0xdead_beef,
        };
        let bytes = h.encode();
        assert_eq!(bytes.len(), HEADER_BYTES as usize);
        assert_eq!(Header::decode(&bytes), Ok(h));
        assert_eq!(h.file_len(), Some(4096 + 7 * 72 * 4096));
        let mut bad = bytes.clone();
        bad[8] = 2;
        assert!(Header::decode(&bad).unwrap_err().contains("version 2"));
        let mut bad = bytes;
        bad[40] ^= 1;
        assert!(Header::decode(&bad).unwrap_err().contains("stride"));
    }

    #[test]
    fn create_open_tag_and_tiles() {
        let (_d, p) = tmp("s.tiles");
        let mut s = TileStore::<u32>::create(&p, 3, 5, 7).unwrap();
        assert_eq!(std::fs::metadata(&p).unwrap().len(), 4096 + 3 * 4096);
        assert_eq!(s.read_tile(2).unwrap(), vec![7; 5]);
        s.write_tile(1, &[1, 2, 3, 4, 5]).unwrap();
        s.set_tag(42).unwrap();
        assert!(s.write_tile(1, &[1]).is_err());
        assert!(s.read_tile(3).is_err());
        assert!(s.for_each_tile(0, |_, _| {}).is_err());
        drop(s);
        let s = TileStore::<u32>::open(&p).unwrap();
        assert_eq!((s.tile_count(), s.tile_texels(), s.tag()), (3, 5, 42));
        assert_eq!(s.read_tile(1).unwrap(), vec![1, 2, 3, 4, 5]);
        assert_eq!(s.read_tile(0).unwrap(), vec![7; 5]);
    }

    #[test]
    fn zero_fill_and_empty_store() {
        let (_d, p) = tmp("z.tiles");
        let mut s = TileStore::<[f32; 2]>::create(&p, 0, 16, [0.0; 2]).unwrap();
        s.for_each_tile_mut(4, |_, _| unreachable!()).unwrap();
        let mut s = TileStore::<[f32; 2]>::create(&p, 2, 16, [0.0; 2]).unwrap();
        s.for_each_tile_mut(4, |i, t| t.iter_mut().for_each(|r| r[0] = i as f32))
            .unwrap();
        assert_eq!(s.read_tile(1).unwrap(), vec![[1.0, 0.0]; 16]);
    }
}
