//! One slot's texture of per-texel values, for the passes that need a texel's neighbours or
//! look texels up at random (dilation, smoothing, the fill of unobserved texels, albedo and
//! radiance lookups, output images): whole in memory when it fits in the memory it is given,
//! else in a scratch tile store read through a bounded [`TileCache`] and processed one tile
//! and its halo at a time ([`Block`]). So memory follows the budget, not the atlas.
//!
//! Both forms give the same values bit for bit: the tiled form runs the same per-texel code on
//! each tile's neighbourhood, and a neighbourhood of `r` texels holds everything an `r`-texel
//! operation reads (see [`SlotTexture::dilated`]). Which form a texture takes therefore never
//! changes a result; the tests run every operation both ways and compare.

use crate::atlas::store::TileStore;
use crate::atlas::store::{Layout, TexelGeom};
use crate::atlas::store::{Reader, TileCache};
use crate::atlas::texture::dilate;
use crate::base::error::{Error, Result};
use crate::base::progress::Tick;
use bytemuck::Pod;
use rayon::prelude::*;
use std::ops::{Add, Mul};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Where scratch textures go and how much memory each may hold.
#[derive(Debug, Clone)]
pub struct Scratch {
    pub dir: PathBuf,
    /// Bytes a texture may hold in memory (whole, or as its tile cache).
    pub budget: u64,
}

impl Scratch {
    pub fn new(dir: impl AsRef<Path>, budget: u64) -> Scratch {
        Scratch {
            dir: dir.as_ref().to_path_buf(),
            budget,
        }
    }

    /// The same directory with `budget` bytes.
    pub fn with_budget(&self, budget: u64) -> Scratch {
        Scratch::new(&self.dir, budget)
    }

    /// The part `part / whole` of this budget (e.g. one texture's share of a set kept at once).
    pub fn share(&self, part: u64, whole: u64) -> Scratch {
        let b = (self.budget as u128 * part as u128 / whole.max(1) as u128) as u64;
        self.with_budget(b)
    }

    /// A fresh file name in the scratch directory.
    fn path(&self, name: &str) -> PathBuf {
        static NEXT: AtomicU64 = AtomicU64::new(0);
        let n = NEXT.fetch_add(1, Ordering::Relaxed);
        self.dir
            .join(format!("scratch-{}-{n}-{name}.tiles", std::process::id()))
    }
}

/// Where a slot's tiles lie: the slot's own tile grid (local tile `t` is global tile
/// `first_tile + t`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Grid {
    pub width: u32,
    pub height: u32,
    pub tile_size: u32,
    pub tiles_x: u32,
    pub tiles_y: u32,
    pub first_tile: u32,
}

impl Grid {
    pub fn of(layout: &Layout, slot: usize) -> Grid {
        let s = &layout.slots[slot];
        Grid {
            width: s.width,
            height: s.height,
            tile_size: layout.tile_size,
            tiles_x: s.tiles_x,
            tiles_y: s.tiles_y,
            first_tile: s.first_tile,
        }
    }

    pub fn tiles(&self) -> u32 {
        self.tiles_x * self.tiles_y
    }

    pub fn tile_texels(&self) -> usize {
        (self.tile_size * self.tile_size) as usize
    }

    pub fn texels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// `(local tile, offset)` of texel `(x, y)`.
    #[inline]
    pub fn locate(&self, x: u32, y: u32) -> (u32, u32) {
        let ts = self.tile_size;
        ((y / ts) * self.tiles_x + x / ts, (y % ts) * ts + x % ts)
    }

    /// The texels of local tile `t` inside the texture: `(offset, x, y)`.
    pub fn texels_of(&self, t: u32) -> impl Iterator<Item = (usize, u32, u32)> {
        let ts = self.tile_size;
        let (x0, y0) = ((t % self.tiles_x) * ts, (t / self.tiles_x) * ts);
        let (x1, y1) = ((x0 + ts).min(self.width), (y0 + ts).min(self.height));
        (y0..y1)
            .flat_map(move |y| (x0..x1).map(move |x| (((y - y0) * ts + (x - x0)) as usize, x, y)))
    }

    /// The texel rectangle `[x0, x1) x [y0, y1)` of local tile `t` grown by `r` and clipped to
    /// the texture.
    fn halo_rect(&self, t: u32, r: u32) -> (u32, u32, u32, u32) {
        let ts = self.tile_size;
        let (x0, y0) = ((t % self.tiles_x) * ts, (t / self.tiles_x) * ts);
        (
            x0.saturating_sub(r),
            y0.saturating_sub(r),
            (x0 + ts + r).min(self.width),
            (y0 + ts + r).min(self.height),
        )
    }
}

/// A tile's texels and its neighbours' within `r` texels (clipped to the texture), row-major.
#[derive(Debug, Clone)]
pub struct Block<V> {
    pub x0: u32,
    pub y0: u32,
    pub width: u32,
    pub height: u32,
    pub vals: Vec<V>,
}

impl<V: Copy> Block<V> {
    /// The value at texture texel `(x, y)`, which must lie in the block.
    #[inline]
    pub fn at(&self, x: u32, y: u32) -> V {
        self.vals[((y - self.y0) * self.width + (x - self.x0)) as usize]
    }
}

/// One slot's texture (see the module docs).
pub struct SlotTexture<V: Pod + Send + Sync> {
    pub grid: Grid,
    data: Data<V>,
}

enum Data<V: Pod + Send + Sync> {
    /// Row-major, `width x height`.
    Whole(Vec<V>),
    /// In a scratch store (deleted on drop), one tile per local tile.
    Tiled {
        cache: Box<TileCache<V>>,
        path: PathBuf,
    },
}

impl<V: Pod + Send + Sync> Drop for SlotTexture<V> {
    fn drop(&mut self) {
        if let Data::Tiled { path, .. } = &self.data {
            let _ = std::fs::remove_file(path);
        }
    }
}

impl<V: Pod + Send + Sync> SlotTexture<V> {
    /// Whether a `grid` texture of `V` is held whole in memory under `scratch`'s budget.
    pub fn fits(grid: &Grid, scratch: &Scratch) -> bool {
        (grid.texels() * std::mem::size_of::<V>()) as u64 <= scratch.budget
    }

    /// The texture whose local tile `t` holds `tile(t)` (records in tile order, `tile_texels`
    /// of them; those outside the texture are ignored). Tiles are made in parallel.
    pub fn build(
        grid: Grid,
        scratch: &Scratch,
        name: &str,
        tile: impl Fn(u32) -> Result<Vec<V>> + Sync,
    ) -> Result<Self> {
        let n = grid.tiles();
        let whole = Self::fits(&grid, scratch);
        let (mut out, mut store, path) = match whole {
            true => (vec![V::zeroed(); grid.texels()], None, PathBuf::new()),
            false => {
                let path = scratch.path(name);
                let store = TileStore::create(&path, n as usize, grid.tile_texels(), V::zeroed())?;
                (Vec::new(), Some(store), path)
            }
        };
        // tiles are made in parallel a group at a time, then stored in order
        let group = (4 * rayon::current_num_threads()).max(1) as u32;
        for g0 in (0..n).step_by(group as usize) {
            let made: Vec<Vec<V>> = (g0..(g0 + group).min(n))
                .into_par_iter()
                .map(&tile)
                .collect::<Result<_>>()?;
            for (i, recs) in made.iter().enumerate() {
                let t = g0 + i as u32;
                match &mut store {
                    Some(st) => st.write_tile(t as usize, recs)?,
                    None => {
                        for (off, x, y) in grid.texels_of(t) {
                            out[(y * grid.width + x) as usize] = recs[off];
                        }
                    }
                }
            }
        }
        let data = match store {
            None => Data::Whole(out),
            Some(st) => Data::Tiled {
                cache: Box::new(TileCache::new(st, scratch.budget)?),
                path,
            },
        };
        Ok(SlotTexture { grid, data })
    }

    /// Slot `slot`'s texture `f(record, geometry)` per texel, from `store` and the geometry
    /// store beside it.
    pub fn read<S: Pod + Send + Sync>(
        layout: &Layout,
        slot: usize,
        store: &TileStore<S>,
        geom: &TileStore<TexelGeom>,
        scratch: &Scratch,
        name: &str,
        f: impl Fn(&S, &TexelGeom) -> V + Sync,
    ) -> Result<Self> {
        let sources = (layout, slot, store, geom);
        Self::read_ticking(sources, scratch, name, f, &crate::base::progress::no_tick)
    }

    /// [`SlotTexture::read`] that gives `tick` each tile read (for a stage's progress).
    pub fn read_ticking<S: Pod + Send + Sync>(
        (layout, slot, store, geom): (&Layout, usize, &TileStore<S>, &TileStore<TexelGeom>),
        scratch: &Scratch,
        name: &str,
        f: impl Fn(&S, &TexelGeom) -> V + Sync,
        tick: Tick,
    ) -> Result<Self> {
        let grid = Grid::of(layout, slot);
        Self::build(grid, scratch, name, |t| {
            let g = (grid.first_tile + t) as usize;
            let (recs, geo) = (store.read_tile(g)?, geom.read_tile(g)?);
            tick(1);
            Ok(recs.iter().zip(&geo).map(|(s, g)| f(s, g)).collect())
        })
    }

    /// Slot `slot`'s texture `f(record)` per texel, from `store` alone (no geometry read).
    pub fn read_store<S: Pod + Send + Sync>(
        (layout, slot, store): (&Layout, usize, &TileStore<S>),
        scratch: &Scratch,
        name: &str,
        f: impl Fn(&S) -> V + Sync,
    ) -> Result<Self> {
        let grid = Grid::of(layout, slot);
        Self::build(grid, scratch, name, |t| {
            let recs = store.read_tile((grid.first_tile + t) as usize)?;
            Ok(recs.iter().map(&f).collect())
        })
    }

    /// Whether the texture is held whole in memory.
    pub fn is_whole(&self) -> bool {
        matches!(self.data, Data::Whole(_))
    }

    /// The value of texel `(x, y)` (inside the texture).
    #[inline]
    pub fn get(&self, x: u32, y: u32) -> V {
        match &self.data {
            Data::Whole(v) => v[(y * self.grid.width + x) as usize],
            Data::Tiled { cache, .. } => {
                let (t, o) = self.grid.locate(x, y);
                cache.get(t, o)
            }
        }
    }

    /// A reader for many nearby lookups (it keeps the last tile it read).
    pub fn reader(&self) -> TexReader<'_, V> {
        TexReader {
            tex: self,
            inner: match &self.data {
                Data::Whole(_) => None,
                Data::Tiled { cache, .. } => Some(cache.reader()),
            },
        }
    }

    /// The first read error of lookups since the last check (tiled textures only).
    pub fn check(&self) -> Result<()> {
        match &self.data {
            Data::Whole(_) => Ok(()),
            Data::Tiled { cache, .. } => cache.check(),
        }
    }

    /// Row `y`, left to right.
    pub fn row(&self, y: u32) -> Vec<V> {
        let mut r = self.reader();
        (0..self.grid.width).map(|x| r.get(x, y)).collect()
    }

    /// The records of local tile `t` in tile order (zero outside the texture).
    pub fn tile(&self, t: u32) -> Result<Vec<V>> {
        match &self.data {
            Data::Whole(v) => {
                let mut out = vec![V::zeroed(); self.grid.tile_texels()];
                for (off, x, y) in self.grid.texels_of(t) {
                    out[off] = v[(y * self.grid.width + x) as usize];
                }
                Ok(out)
            }
            Data::Tiled { cache, .. } => {
                let tile = cache.tile(t);
                cache.check()?;
                Ok(tile.to_vec())
            }
        }
    }

    /// Overwrites local tile `t` with `recs` (tile order).
    pub fn set_tile(&mut self, t: u32, recs: Vec<V>) -> Result<()> {
        let grid = self.grid;
        match &mut self.data {
            Data::Whole(v) => {
                for (off, x, y) in grid.texels_of(t) {
                    v[(y * grid.width + x) as usize] = recs[off];
                }
                Ok(())
            }
            Data::Tiled { cache, .. } => cache.write_tile(t, recs),
        }
    }

    /// Local tile `t` and its neighbours within `r` texels.
    pub fn block(&self, t: u32, r: u32) -> Block<V> {
        let (x0, y0, x1, y1) = self.grid.halo_rect(t, r);
        let mut rd = self.reader();
        let mut vals = Vec::with_capacity(((x1 - x0) * (y1 - y0)) as usize);
        for y in y0..y1 {
            for x in x0..x1 {
                vals.push(rd.get(x, y));
            }
        }
        Block {
            x0,
            y0,
            width: x1 - x0,
            height: y1 - y0,
            vals,
        }
    }

    /// Writes the texture into its slot's tiles of `store`: `f(record, value)` per texel
    /// returns whether it changed the record; tiles without a change are not rewritten.
    /// Returns how many records changed.
    pub fn write<S: Pod + Send + Sync>(
        &self,
        store: &mut TileStore<S>,
        f: impl Fn(&mut S, &V) -> bool,
    ) -> Result<u64> {
        self.write_ticking(store, f, &crate::base::progress::no_tick)
    }

    /// [`SlotTexture::write`] that gives `tick` each tile written (for a stage's progress).
    pub fn write_ticking<S: Pod + Send + Sync>(
        &self,
        store: &mut TileStore<S>,
        f: impl Fn(&mut S, &V) -> bool,
        tick: Tick,
    ) -> Result<u64> {
        let mut changed = 0u64;
        for t in 0..self.grid.tiles() {
            tick(1);
            let g = (self.grid.first_tile + t) as usize;
            let (mut recs, vals) = (store.read_tile(g)?, self.tile(t)?);
            let mut n = 0u64;
            for (off, _, _) in self.grid.texels_of(t) {
                n += f(&mut recs[off], &vals[off]) as u64;
            }
            if n > 0 {
                store.write_tile(g, &recs)?;
                changed += n;
            }
        }
        Ok(changed)
    }

    /// Every value, row-major (whole-texture: for tests and small textures).
    pub fn to_vec(&self) -> Vec<V> {
        (0..self.grid.height).flat_map(|y| self.row(y)).collect()
    }

    /// [`Self::map_blocks`] of one local filter `f(values, width, height)`, run on the whole
    /// texture or on each tile's block with halo `r` (the same values wherever every texel's
    /// result depends only on texels within `r` of it).
    pub fn map_windows<W: Pod + Send + Sync>(
        &self,
        r: u32,
        scratch: &Scratch,
        name: &str,
        f: impl Fn(&[V], u32, u32) -> Result<Vec<W>> + Sync,
    ) -> Result<SlotTexture<W>> {
        let grid = self.grid;
        let whole = |v: &[V]| f(v, grid.width, grid.height);
        self.map_blocks(r, scratch, name, whole, |b, _| {
            f(&b.vals, b.width, b.height)
        })
    }

    /// A new texture of `f(block of local tile t with halo r, t)` per tile: `f` gives a value
    /// per texel of the block (row-major, its size), of which the tile's own are kept;
    /// `whole(all values)` computes the same thing on a texture held whole.
    pub fn map_blocks<W: Pod + Send + Sync>(
        &self,
        r: u32,
        scratch: &Scratch,
        name: &str,
        whole: impl FnOnce(&[V]) -> Result<Vec<W>>,
        f: impl Fn(&Block<V>, u32) -> Result<Vec<W>> + Sync,
    ) -> Result<SlotTexture<W>> {
        if let (Data::Whole(v), true) = (&self.data, SlotTexture::<W>::fits(&self.grid, scratch)) {
            let out = whole(v)?;
            if out.len() != self.grid.texels() {
                return Err(Error::internal(format!(
                    "{name}: {} values for a {}x{} texture",
                    out.len(),
                    self.grid.width,
                    self.grid.height
                )));
            }
            return Ok(SlotTexture {
                grid: self.grid,
                data: Data::Whole(out),
            });
        }
        let grid = self.grid;
        let out = SlotTexture::build(grid, scratch, name, |t| {
            let b = self.block(t, r);
            let vals = f(&b, t)?;
            if vals.len() != b.vals.len() {
                return Err(Error::internal(format!(
                    "{name}: {} values for a {}x{} block",
                    vals.len(),
                    b.width,
                    b.height
                )));
            }
            let mut out = vec![W::zeroed(); grid.tile_texels()];
            for (off, x, y) in grid.texels_of(t) {
                out[off] = vals[((y - b.y0) * b.width + (x - b.x0)) as usize];
            }
            Ok(out)
        })?;
        self.check()?;
        Ok(out)
    }
}

impl<V> SlotTexture<V>
where
    V: Pod + Send + Sync + Add<Output = V> + Mul<f32, Output = V>,
{
    /// The texture with its texels outside `mask` (non-zero = set) filled by `passes` passes
    /// of [`dilate`]. Tiled, each tile is dilated within its neighbourhood of `passes` texels:
    /// a texel's value after `k` passes depends only on texels within `k` of it, so the
    /// tile's values are exactly those of the whole-texture dilation.
    pub fn dilated(
        &self,
        mask: &SlotTexture<u8>,
        passes: u32,
        scratch: &Scratch,
    ) -> Result<SlotTexture<V>> {
        let (w, h) = (self.grid.width, self.grid.height);
        let whole = |v: &[V]| -> Result<Vec<V>> {
            let mut v = v.to_vec();
            let m: Vec<bool> = mask.to_vec().iter().map(|&b| b != 0).collect();
            dilate(&mut v, &m, w, h, passes)?;
            Ok(v)
        };
        self.map_blocks(passes, scratch, "dilated", whole, |b, t| {
            let mb = mask.block(t, passes);
            let m: Vec<bool> = mb.vals.iter().map(|&x| x != 0).collect();
            let mut v = b.vals.clone();
            dilate(&mut v, &m, b.width, b.height, passes)?;
            Ok(v)
        })
        .and_then(|t| mask.check().map(|_| t))
    }
}

impl crate::physics::render::Texels for SlotTexture<glam::Vec3> {
    fn width(&self) -> u32 {
        self.grid.width
    }
    fn height(&self) -> u32 {
        self.grid.height
    }
    #[inline]
    fn texel(&self, x: u32, y: u32) -> glam::Vec3 {
        self.get(x, y)
    }
    fn row_major(&self) -> Option<&[glam::Vec3]> {
        match &self.data {
            Data::Whole(v) => Some(v),
            Data::Tiled { .. } => None,
        }
    }
    /// The tile holding the texels, when it holds them all and is not resident (a resident
    /// cache reads each texel as cheaply).
    fn held_block(
        &self,
        x0: u32,
        y0: u32,
        x1: u32,
        y1: u32,
    ) -> Option<crate::physics::render::Block> {
        let Data::Tiled { cache, .. } = &self.data else {
            return None;
        };
        if cache.all_resident() {
            return None;
        }
        let (t, o) = self.grid.locate(x0, y0);
        if self.grid.locate(x1, y1).0 != t {
            return None;
        }
        let ts = self.grid.tile_size;
        let origin = (x0 - o % ts, y0 - o / ts);
        Some(crate::physics::render::Block {
            texels: cache.tile(t),
            stride: ts,
            origin,
        })
    }
}

/// See [`SlotTexture::reader`].
pub struct TexReader<'a, V: Pod + Send + Sync> {
    tex: &'a SlotTexture<V>,
    inner: Option<Reader<'a, V>>,
}

impl<V: Pod + Send + Sync> TexReader<'_, V> {
    #[inline]
    pub fn get(&mut self, x: u32, y: u32) -> V {
        match (&mut self.inner, &self.tex.data) {
            (None, Data::Whole(v)) => v[(y * self.tex.grid.width + x) as usize],
            (Some(r), _) => {
                let (t, o) = self.tex.grid.locate(x, y);
                r.get(t, o)
            }
            (None, Data::Tiled { cache, .. }) => {
                let (t, o) = self.tex.grid.locate(x, y);
                cache.get(t, o)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    use crate::atlas::testing::{grid, texture as tex};

    /// Scratch space in `dir` that holds textures whole, and scratch space that tiles them.
    fn whole_and_tiled(dir: &std::path::Path) -> (Scratch, Scratch) {
        (Scratch::new(dir, 1 << 30), Scratch::new(dir, 1))
    }

    #[test]
    fn whole_and_tiled_textures_read_the_same() {
        let dir = tempfile::tempdir().unwrap();
        let (big, tiny) = whole_and_tiled(dir.path());
        let g = grid(37, 23, 8);
        let f = |x: u32, y: u32| x * 1000 + y;
        let (a, b) = (tex(g, &big, f), tex(g, &tiny, f));
        assert!(a.is_whole() && !b.is_whole());
        for y in 0..23 {
            assert_eq!(a.row(y), b.row(y));
            for x in 0..37 {
                assert_eq!((a.get(x, y), b.get(x, y)), (f(x, y), f(x, y)));
            }
        }
        for t in 0..g.tiles() {
            assert_eq!(a.tile(t).unwrap(), b.tile(t).unwrap());
            let (ba, bb) = (a.block(t, 3), b.block(t, 3));
            assert_eq!(
                (ba.x0, ba.y0, ba.width, ba.height),
                (bb.x0, bb.y0, bb.width, bb.height)
            );
            assert_eq!(ba.vals, bb.vals);
            assert_eq!(ba.at(ba.x0, ba.y0), f(ba.x0, ba.y0));
        }
        b.check().unwrap();
        let path = match &b.data {
            Data::Tiled { path, .. } => path.clone(),
            _ => unreachable!(),
        };
        assert!(path.exists());
        drop(b);
        assert!(!path.exists(), "scratch file removed with its texture");
    }

    /// A tiled texture hands out the tile holding a rectangle of texels (each at the texel's
    /// value), none for a rectangle across tiles; a whole texture hands out none.
    #[test]
    fn a_tiled_texture_hands_out_the_tile_holding_texels() {
        use crate::physics::render::Texels;
        let dir = tempfile::tempdir().unwrap();
        let (big, tiny) = whole_and_tiled(dir.path());
        let g = grid(37, 23, 8);
        let f = |x: u32, y: u32| Vec3::new(x as f32, y as f32, (x * y) as f32);
        let (whole, tiled) = (tex(g, &big, f), tex(g, &tiny, f));
        assert!(
            whole.held_block(9, 9, 10, 10).is_none(),
            "whole: indexed directly"
        );
        let b = tiled
            .held_block(9, 17, 14, 22)
            .expect("one tile (8..16, 16..24)");
        assert_eq!((b.origin, b.stride, b.texels.len()), ((8, 16), 8, 64));
        for y in 16..23 {
            for x in 8..16 {
                let i = ((y - 16) * b.stride + (x - 8)) as usize;
                assert_eq!(b.texels[i], f(x, y), "({x}, {y})");
            }
        }
        assert!(tiled.held_block(7, 9, 8, 10).is_none(), "across tiles");
        assert!(
            tiled.held_block(33, 0, 36, 7).is_some(),
            "the last, partial tile column"
        );
    }

    /// Tiled dilation is the whole-texture dilation, bit for bit, for several pass counts,
    /// including more passes than a tile is wide.
    #[test]
    fn tiled_dilation_equals_whole_dilation() {
        let dir = tempfile::tempdir().unwrap();
        let (big, tiny) = whole_and_tiled(dir.path());
        let g = grid(61, 45, 8);
        // islands of coverage with irregular values
        let on = |x: u32, y: u32| ((x / 7 + y / 5) % 3 == 0 && (x * 13 + y * 7) % 11 != 0) as u8;
        let val = |x: u32, y: u32| {
            Vec3::new(
                x as f32 * 0.37,
                (y * y) as f32 * 0.01,
                1.0 / (1.0 + x as f32),
            )
        };
        for passes in [1, 3, 8, 12] {
            let run = |s: &Scratch| {
                let m = tex(g, s, on);
                let v = tex(
                    g,
                    s,
                    |x, y| if on(x, y) != 0 { val(x, y) } else { Vec3::ZERO },
                );
                v.dilated(&m, passes, s).unwrap().to_vec()
            };
            let (a, b) = (run(&big), run(&tiny));
            assert_eq!(a, b, "{passes} passes");
            // and it did fill something beyond the mask
            let filled = (0..g.texels())
                .filter(|&i| on(i as u32 % 61, i as u32 / 61) == 0 && a[i] != Vec3::ZERO)
                .count();
            assert!(filled > 100, "{passes}: {filled}");
        }
    }
}
