//! Where every texel lives: the global tile numbering over all shapes' textures, and the two
//! per-texel records the tile stores hold (fixed geometry, evolving solver state).
//!
//! Each reconstructed shape has its own `width x height` texture, cut into `tile_size`
//! square tiles (edge tiles hang over the texture; their outside texels are never covered).
//! Tiles of all shapes are numbered consecutively, shape by shape, row-major within a shape,
//! so a texel is addressed either as (slot, x, y) or as (tile, offset within tile).

use bytemuck::{Pod, Zeroable};
use glam::Vec3;

/// The smallest tile edge [`Layout::fitted`] goes down to.
pub const MIN_TILE: u32 = 16;
/// How many times the textures' own texels their tiles may hold before [`Layout::fitted`]
/// halves the tiles.
pub const MAX_PADDING: u64 = 2;

/// One shape's texture in the global tiling.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ShapeTiles {
    /// Index into `Scene::shapes`.
    pub shape: usize,
    pub width: u32,
    pub height: u32,
    pub tiles_x: u32,
    pub tiles_y: u32,
    pub first_tile: u32,
}

/// The global tile layout of all reconstructed shapes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Layout {
    pub tile_size: u32,
    /// One entry per reconstructed shape ("slot"), in scene order.
    pub slots: Vec<ShapeTiles>,
    pub tile_count: u32,
}

impl Layout {
    /// Lay out textures `(shape index, width, height)` in order.
    pub fn new(tile_size: u32, textures: &[(usize, u32, u32)]) -> Layout {
        assert!(tile_size > 0);
        let mut slots = Vec::with_capacity(textures.len());
        let mut next = 0u32;
        for &(shape, width, height) in textures {
            let tiles_x = width.div_ceil(tile_size);
            let tiles_y = height.div_ceil(tile_size);
            slots.push(ShapeTiles {
                shape,
                width,
                height,
                tiles_x,
                tiles_y,
                first_tile: next,
            });
            next += tiles_x * tiles_y;
        }
        Layout {
            tile_size,
            slots,
            tile_count: next,
        }
    }

    /// [`Layout::new`] with tiles of `max_tile`, halved (down to [`MIN_TILE`]) while the tiles
    /// would hold more than [`MAX_PADDING`] times the textures' own texels: a texture is
    /// rounded up to whole tiles, so a scene of thousands of small textures (8 x 8 texels
    /// each) would otherwise take 64 times its texels on disk and in every pass over tiles.
    /// Scenes of large textures keep `max_tile`.
    pub fn fitted(max_tile: u32, textures: &[(usize, u32, u32)]) -> Layout {
        let own: u64 = textures
            .iter()
            .map(|&(_, w, h)| u64::from(w) * u64::from(h))
            .sum();
        let padded = |ts: u32| -> u64 {
            let t = u64::from(ts);
            textures
                .iter()
                .map(|&(_, w, h)| u64::from(w.div_ceil(ts)) * u64::from(h.div_ceil(ts)) * t * t)
                .sum()
        };
        let mut ts = max_tile;
        while ts / 2 >= MIN_TILE && padded(ts) > MAX_PADDING * own {
            ts /= 2;
        }
        Layout::new(ts, textures)
    }

    pub fn tile_texels(&self) -> usize {
        (self.tile_size * self.tile_size) as usize
    }

    /// The slot of a shape index, if that shape is reconstructed.
    pub fn slot_of_shape(&self, shape: usize) -> Option<usize> {
        self.slots.iter().position(|s| s.shape == shape)
    }

    /// `(tile, offset)` of texel `(x, y)` of slot `slot`.
    #[inline]
    pub fn locate(&self, slot: usize, x: u32, y: u32) -> (u32, u32) {
        let s = &self.slots[slot];
        let ts = self.tile_size;
        let tile = s.first_tile + (y / ts) * s.tiles_x + x / ts;
        let off = (y % ts) * ts + x % ts;
        (tile, off)
    }

    /// The slot that owns `tile`.
    pub fn slot_of_tile(&self, tile: u32) -> usize {
        // slots are sorted by first_tile
        self.slots.partition_point(|s| s.first_tile <= tile) - 1
    }

    /// Where tile `tile` lies in its slot's texture.
    pub fn span(&self, tile: u32) -> TileSpan {
        let slot = self.slot_of_tile(tile);
        let s = &self.slots[slot];
        let local = tile - s.first_tile;
        let ts = self.tile_size;
        let (x0, y0) = ((local % s.tiles_x) * ts, (local / s.tiles_x) * ts);
        TileSpan {
            slot,
            tile_size: ts,
            x0,
            y0,
            width: (s.width - x0).min(ts),
            height: (s.height - y0).min(ts),
            texture_width: s.width,
        }
    }

    /// The tiles of `slot` (global tile indices), row-major.
    pub fn slot_tiles(&self, slot: usize) -> std::ops::Range<u32> {
        let s = &self.slots[slot];
        s.first_tile..s.first_tile + s.tiles_x * s.tiles_y
    }

    /// `(slot, x, y)` of a texel given as `(tile, offset)`, or `None` if it hangs outside its
    /// texture.
    #[inline]
    pub fn texel_of(&self, tile: u32, off: u32) -> Option<(usize, u32, u32)> {
        let slot = self.slot_of_tile(tile);
        let s = &self.slots[slot];
        let local = tile - s.first_tile;
        let ts = self.tile_size;
        let x = (local % s.tiles_x) * ts + off % ts;
        let y = (local / s.tiles_x) * ts + off / ts;
        (x < s.width && y < s.height).then_some((slot, x, y))
    }
}

/// The part of a slot's texture one tile holds: the one place that turns a tile record's
/// offset into texel coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TileSpan {
    pub slot: usize,
    pub tile_size: u32,
    /// The tile's top-left texel.
    pub x0: u32,
    pub y0: u32,
    /// Texels of the tile inside the texture (less than `tile_size` on the right and bottom
    /// edges).
    pub width: u32,
    pub height: u32,
    /// Width of the whole texture.
    pub texture_width: u32,
}

impl TileSpan {
    /// Every texel of the tile inside its texture, row-major: `(offset in the tile, x, y)`.
    pub fn texels(&self) -> impl Iterator<Item = (usize, u32, u32)> + '_ {
        (0..self.height).flat_map(move |j| {
            (0..self.width).map(move |i| {
                let off = (j * self.tile_size + i) as usize;
                (off, self.x0 + i, self.y0 + j)
            })
        })
    }

    /// `(offset in the tile, index in the row-major texture)` of every texel inside it.
    pub fn indices(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        self.texels()
            .map(|(off, x, y)| (off, y as usize * self.texture_width as usize + x as usize))
    }
}

/// Texel flags.
pub mod flags {
    /// The texel's center lies on the surface (not gutter, not outside the texture).
    pub const COVERED: u32 = 1;
    /// At least one view observed it.
    pub const OBSERVED: u32 = 2;
    /// Its K_d was filled from neighbours (unobserved).
    pub const FILLED: u32 = 4;
}

/// Fixed per-texel geometry: where on the surface a texel's center lies. 52 bytes.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct TexelGeom {
    pub position: [f32; 3],
    /// Unit shading normal.
    pub normal: [f32; 3],
    /// Unit geometric normal (for ray offsets).
    pub geo_normal: [f32; 3],
    /// World area of one texel on this triangle, scene units^2.
    pub area: f32,
    /// The part of the texel's square that lies on its chart, scene units^2: the area over
    /// which photon hits landing in this texel are collected (less than `area` on chart borders).
    pub bin_area: f32,
    pub tri: u32,
    pub flags: u32,
}

impl TexelGeom {
    pub fn covered(&self) -> bool {
        self.flags & flags::COVERED != 0
    }
    pub fn p(&self) -> Vec3 {
        Vec3::from_array(self.position)
    }
    pub fn n(&self) -> Vec3 {
        Vec3::from_array(self.normal)
    }
    pub fn ng(&self) -> Vec3 {
        Vec3::from_array(self.geo_normal)
    }
}

/// The solver's per-texel state. 92 bytes. Radiance in scene units per channel, irradiance in
/// scene units x sr.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct TexelState {
    /// Observed radiance: a weighted sum during projection, the weighted mean after it.
    pub l_orig: [f32; 3],
    /// Total observation weight (0 = unobserved).
    pub weight: f32,
    /// Direct irradiance E_d.
    pub e_d: [f32; 3],
    /// Secondary (indirect) irradiance E_i.
    pub e_i: [f32; 3],
    /// Recovered albedo.
    pub k_d: [f32; 3],
    /// Relative error |L_orig - L_render| / L_orig (luminance).
    pub error: f32,
    /// Photon accumulator (flux / area summed over the current pass).
    pub accum: [f32; 3],
    pub flags: u32,
    /// Estimated variance of the luminance of `l_orig` (photo noise through the views that
    /// saw the texel, or their scatter where larger; see `project`), scene units squared.
    pub l_var: f32,
    /// Estimated variance of the luminance of the gathered `E_i` (Monte Carlo noise of the
    /// gather rays; 0 when not estimated).
    pub e_var: f32,
    /// Views whose value for this texel departed from the others by more than their noise
    /// and were down-weighted (robust fusion, see `project`).
    pub disagree: f32,
    /// The part of `l_var` that is the photos' noise alone (propagated through the views'
    /// weights, without their scatter): what [`crate::stages::denoise`] judges differences against.
    pub l_noise: f32,
    /// Estimated variance of the luminance of `e_d` from its sampling (an environment light's
    /// sample pairs, measured on the map: `direct::sampling`; 0 where not estimated), scene
    /// units squared.
    pub ed_var: f32,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_textures_get_smaller_tiles_and_large_ones_keep_theirs() {
        let large = [(0, 512, 300), (1, 256, 256)];
        assert_eq!(Layout::fitted(64, &large).tile_size, 64);
        // 5,000 textures of 10 x 10 texels: 64 x 64 tiles would hold 41x their texels
        let small: Vec<_> = (0..5000).map(|i| (i, 10, 10)).collect();
        let l = Layout::fitted(64, &small);
        assert_eq!(l.tile_size, MIN_TILE);
        assert!(l.tile_count as u64 * 256 <= 3 * 5000 * 100);
        // a few small ones beside large ones change nothing
        let mixed: Vec<_> = large
            .iter()
            .copied()
            .chain((2..12).map(|i| (i, 10, 10)))
            .collect();
        assert_eq!(Layout::fitted(64, &mixed).tile_size, 64);
        // never below MIN_TILE, never above what was asked
        assert_eq!(Layout::fitted(8, &small).tile_size, 8);
    }

    #[test]
    fn locate_and_texel_of_are_inverse_over_every_texel() {
        let l = Layout::new(4, &[(0, 5, 3), (2, 8, 8), (5, 1, 9)]);
        assert_eq!(l.tile_count, 2 + 4 + 3);
        let mut seen = std::collections::HashSet::new();
        for (slot, s) in l.slots.iter().enumerate() {
            for y in 0..s.height {
                for x in 0..s.width {
                    let (t, o) = l.locate(slot, x, y);
                    assert!(t < l.tile_count && (o as usize) < l.tile_texels());
                    assert!(seen.insert((t, o)), "two texels share ({t},{o})");
                    assert_eq!(l.texel_of(t, o), Some((slot, x, y)));
                }
            }
        }
        // texels hanging outside a texture map to nothing
        let outside = (0..l.tile_count)
            .flat_map(|t| (0..16).map(move |o| (t, o)))
            .filter(|&(t, o)| l.texel_of(t, o).is_none())
            .count();
        assert_eq!(outside, l.tile_count as usize * 16 - seen.len());
    }

    #[test]
    fn spans_visit_every_texel_once_like_texel_of() {
        let l = Layout::new(4, &[(0, 5, 3), (2, 8, 8), (5, 1, 9)]);
        let mut n = 0;
        for (slot, s) in l.slots.iter().enumerate() {
            let mut seen = vec![0u8; (s.width * s.height) as usize];
            for t in l.slot_tiles(slot) {
                let span = l.span(t);
                assert_eq!(span.slot, slot);
                for ((off, x, y), (off2, i)) in span.texels().zip(span.indices()) {
                    assert_eq!(l.texel_of(t, off as u32), Some((slot, x, y)));
                    assert_eq!((off, i), (off2, (y * s.width + x) as usize));
                    seen[i] += 1;
                    n += 1;
                }
            }
            assert!(seen.iter().all(|&c| c == 1), "slot {slot}: {seen:?}");
        }
        assert_eq!(n, 5 * 3 + 8 * 8 + 9);
    }

    #[test]
    fn records_have_the_documented_sizes() {
        assert_eq!(std::mem::size_of::<TexelGeom>(), 52);
        assert_eq!(std::mem::size_of::<TexelState>(), 92);
    }
}
