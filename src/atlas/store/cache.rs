//! Random reads of texels from a [`TileStore`] too large to hold in memory: a bounded,
//! thread-safe cache of whole tiles read on demand, for stages that look texels up by where a
//! ray lands (the gather's radiance) rather than walking tiles in order.
//!
//! The cache itself is `quick_cache` (a concurrent, sharded S3-FIFO cache): this module only
//! sizes it from a memory budget, reads a missing tile with a positioned read (no maps, so no
//! `unsafe` here), and keeps the first read error for the caller to collect after a parallel
//! pass ([`TileCache::check`]), so hot lookup loops need no `Result` plumbing. What is cached
//! never changes a value read, only how often the file is read: results are bit-identical
//! whatever the budget or thread count.

use crate::atlas::store::TileStore;
use crate::base::error::{Error, Result};
use bytemuck::Pod;
use std::sync::{Arc, Mutex};

/// A read-only view of a tile store through a cache of at most about `budget` bytes of tiles.
pub struct TileCache<T: Pod + Send + Sync> {
    store: TileStore<T>,
    tiles: quick_cache::sync::Cache<u32, Arc<Vec<T>>>,
    /// Handed out in place of a tile that could not be read (see [`TileCache::check`]).
    zero: Arc<Vec<T>>,
    error: Mutex<Option<Error>>,
    capacity: usize,
    /// Every tile back to back (tile `t` at `t * tile_texels`), when they all fit in the
    /// budget (no cache in the way then). One allocation, so it goes back to the system
    /// whole when the cache is dropped.
    resident: Option<Vec<T>>,
}

impl<T: Pod + Send + Sync> TileCache<T> {
    /// Caches tiles of `store`, as many as `budget_bytes` holds (at least 4 per worker thread,
    /// so each thread's working tiles stay resident). When the whole store fits in the budget
    /// it is read at once and indexed directly (the common case, and the fastest).
    pub fn new(store: TileStore<T>, budget_bytes: u64) -> Result<Self> {
        let tile_bytes = (store.tile_texels() * std::mem::size_of::<T>()).max(1) as u64;
        let floor = 4 * rayon::current_num_threads().max(1);
        let capacity = ((budget_bytes / tile_bytes) as usize)
            .max(floor)
            .min(store.tile_count().max(1));
        let zero = Arc::new(vec![T::zeroed(); store.tile_texels()]);
        let all_fit = store.tile_count() as u64 * tile_bytes <= budget_bytes;
        let resident = match all_fit {
            true => {
                let n = store.tile_texels();
                let mut all = vec![T::zeroed(); store.tile_count() * n];
                for (t, chunk) in all.chunks_mut(n.max(1)).enumerate() {
                    chunk.copy_from_slice(&store.read_tile(t)?);
                }
                Some(all)
            }
            false => None,
        };
        Ok(TileCache {
            tiles: quick_cache::sync::Cache::new(if all_fit { 1 } else { capacity }),
            store,
            zero,
            error: Mutex::new(None),
            capacity,
            resident,
        })
    }

    /// Whether every tile is held in memory (the store fits in the budget).
    pub fn all_resident(&self) -> bool {
        self.resident.is_some()
    }

    /// How many tiles the cache holds at most (approximately: the cache's own bound).
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Records per tile.
    pub fn tile_texels(&self) -> usize {
        self.store.tile_texels()
    }

    /// Tile `t`, read from the file if it is not cached. A read error is kept for
    /// [`TileCache::check`] and a tile of zeros is returned.
    pub fn tile(&self, t: u32) -> Arc<Vec<T>> {
        if let Some(all) = &self.resident {
            let n = self.store.tile_texels();
            return match all.get(t as usize * n..(t as usize + 1) * n) {
                Some(tile) => Arc::new(tile.to_vec()),
                None => {
                    let e = crate::Error::internal(format!(
                        "{}: tile {t} of {}",
                        self.store.path().display(),
                        self.store.tile_count()
                    ));
                    let mut first = self.error.lock().unwrap_or_else(|e| e.into_inner());
                    first.get_or_insert(e);
                    self.zero.clone()
                }
            };
        }
        let got = self
            .tiles
            .get_or_insert_with(&t, || self.store.read_tile(t as usize).map(Arc::new));
        match got {
            Ok(tile) => tile,
            Err(e) => {
                let mut first = self.error.lock().unwrap_or_else(|e| e.into_inner());
                first.get_or_insert(e);
                self.zero.clone()
            }
        }
    }

    /// Record `off` of tile `t`.
    #[inline]
    pub fn get(&self, t: u32, off: u32) -> T {
        match &self.resident {
            Some(all) => all[t as usize * self.store.tile_texels() + off as usize],
            None => self.tile(t)[off as usize],
        }
    }

    /// A reader that keeps the last tile it read: consecutive reads in one tile (the texels
    /// around one point) cost one cache lookup.
    pub fn reader(&self) -> Reader<'_, T> {
        Reader {
            cache: self,
            last: None,
        }
    }

    /// The first read error since the last check, if any (call after a pass of lookups).
    pub fn check(&self) -> Result<()> {
        match self.error.lock().unwrap_or_else(|e| e.into_inner()).take() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// Overwrites tile `t` in the store and in the cache (so later reads see it).
    pub fn write_tile(&mut self, t: u32, data: Vec<T>) -> Result<()> {
        self.store.write_tile(t as usize, &data)?;
        match &mut self.resident {
            Some(all) => {
                let n = self.store.tile_texels();
                all[t as usize * n..(t as usize + 1) * n].copy_from_slice(&data);
            }
            None => self.tiles.insert(t, Arc::new(data)),
        }
        Ok(())
    }

    /// The store behind the cache.
    pub fn store(&self) -> &TileStore<T> {
        &self.store
    }
}

/// See [`TileCache::reader`].
pub struct Reader<'c, T: Pod + Send + Sync> {
    cache: &'c TileCache<T>,
    last: Option<(u32, Arc<Vec<T>>)>,
}

impl<T: Pod + Send + Sync> Reader<'_, T> {
    /// Record `off` of tile `t`.
    #[inline]
    pub fn get(&mut self, t: u32, off: u32) -> T {
        if let Some(all) = &self.cache.resident {
            return all[t as usize * self.cache.store.tile_texels() + off as usize];
        }
        match &self.last {
            Some((lt, tile)) if *lt == t => tile[off as usize],
            _ => {
                let tile = self.cache.tile(t);
                let v = tile[off as usize];
                self.last = Some((t, tile));
                v
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rayon::prelude::*;

    fn store(dir: &std::path::Path, tiles: usize, texels: usize) -> TileStore<u32> {
        let mut s = TileStore::<u32>::create(dir.join("c.tiles"), tiles, texels, 0).unwrap();
        for t in 0..tiles {
            let v: Vec<u32> = (0..texels).map(|o| (t * 1000 + o) as u32).collect();
            s.write_tile(t, &v).unwrap();
        }
        s
    }

    #[test]
    fn random_reads_through_a_small_cache_see_the_file() {
        let dir = tempfile::tempdir().unwrap();
        // 64 tiles of 16 records, a budget of 2 tiles (raised to the per-thread floor)
        let cache = TileCache::new(store(dir.path(), 64, 16), 2 * 64).unwrap();
        assert!(cache.capacity() < 64 && !cache.all_resident());
        let wrong: usize = (0..20_000u32)
            .into_par_iter()
            .filter(|&i| {
                let (t, o) = ((i * 7919) % 64, (i * 31) % 16);
                let mut r = cache.reader();
                let near = ((t + i % 2) % 64, (o + 1) % 16);
                cache.get(t, o) != t * 1000 + o
                    || r.get(t, o) != t * 1000 + o
                    || r.get(near.0, near.1) != near.0 * 1000 + near.1
                    || r.get(t, o) != t * 1000 + o
            })
            .count();
        assert_eq!(wrong, 0);
        cache.check().unwrap();
    }

    #[test]
    fn a_read_error_is_kept_for_check_and_reads_as_zeros() {
        let dir = tempfile::tempdir().unwrap();
        let cache = TileCache::new(store(dir.path(), 4, 16), 64).unwrap();
        assert!(!cache.all_resident());
        // a tile index past the end cannot be read
        assert_eq!(cache.get(9, 3), 0);
        let e = cache.check().unwrap_err().to_string();
        assert!(e.contains("c.tiles") || e.contains("tile"), "{e}");
        cache.check().unwrap();
        assert_eq!(cache.get(2, 5), 2005);
    }

    #[test]
    fn a_store_within_the_budget_is_read_whole_and_reads_the_same() {
        let dir = tempfile::tempdir().unwrap();
        let cache = TileCache::new(store(dir.path(), 8, 16), 1 << 20).unwrap();
        assert!(cache.all_resident());
        let mut r = cache.reader();
        for t in 0..8 {
            for o in 0..16 {
                assert_eq!((cache.get(t, o), r.get(t, o)), (t * 1000 + o, t * 1000 + o));
            }
        }
    }
}
