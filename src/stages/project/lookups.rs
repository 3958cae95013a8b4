//! Each view's look-ups per texel, found once and read by every refinement pass and the noise
//! probe: which pixels a texel reads in a view, with what bilinear fractions, and its weight.
//!
//! The passes read the same pixels with the same weights; only the values (the residual)
//! change. Finding them (the texel's footprint in the view, its sub-samples' projections, the
//! clean-pixel tests) cost more than the back-projection itself (on cbox-tex: 14% of the run's
//! CPU time, in every pass and again in the probe). So a tile's look-ups are kept after its
//! first use, within a byte budget; a tile beyond it finds them afresh in every pass, which
//! gives the same bits (the same taps read in the same order), so the budget never changes a
//! result.

use super::view::{Tap, Value, View};
use super::{observe_with, ShapeRef};
use crate::atlas::store::TexelGeom;
use crate::base::error::Result;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::OnceLock;

/// One texel's look-ups in one view: its index in the tile, its weight, its taps.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Texel {
    index: u32,
    weight: f32,
    start: u32,
    count: u32,
}

/// One tile's look-ups in one view: the texels the view observes, in texel order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TileLookups {
    texels: Vec<Texel>,
    taps: Vec<Tap>,
}

impl TileLookups {
    /// The look-ups of `view` for the covered texels of a tile of `shape` (what
    /// [`super::observe_texel_from`] reads, without reading it).
    pub fn find(view: &View, shape: &ShapeRef, geom: &[TexelGeom]) -> TileLookups {
        let mut out = TileLookups::default();
        for (i, g) in geom.iter().enumerate() {
            if !g.covered() {
                continue;
            }
            let start = out.taps.len();
            let ng = g.ng();
            let taps = &mut out.taps;
            let seen = observe_with(view, shape, g, |pix, q| {
                let t = view.tap(pix, q, shape.index, ng)?;
                taps.push(t);
                Some(0.0f32)
            });
            match seen {
                Some((_, weight)) => out.texels.push(Texel {
                    index: i as u32,
                    weight,
                    start: start as u32,
                    count: (out.taps.len() - start) as u32,
                }),
                None => out.taps.truncate(start),
            }
        }
        out
    }

    /// Per observed texel, `(index in the tile, mean value over its taps, weight)`, the values
    /// read from a row-major image `width` pixels wide: what [`super::observe_texel_from`]
    /// gives, to the bit.
    pub fn read<'a, T: Value>(
        &'a self,
        width: u32,
        values: &'a [T],
    ) -> impl Iterator<Item = (usize, T, f32)> + 'a {
        self.texels.iter().map(move |t| {
            let taps = &self.taps[t.start as usize..(t.start + t.count) as usize];
            let mut sum = T::default();
            for tap in taps {
                sum += tap.read_slice(width, values);
            }
            (t.index as usize, sum / t.count as f32, t.weight)
        })
    }

    /// Bytes this holds.
    fn bytes(&self) -> u64 {
        (self.texels.capacity() * std::mem::size_of::<Texel>()
            + self.taps.capacity() * std::mem::size_of::<Tap>()) as u64
    }
}

/// The look-ups of a set of views, per view and tile, kept as tiles are first used while
/// their bytes fit `budget`.
pub struct Lookups {
    tiles: usize,
    /// Boxed: most of a large run's (view, tile) pairs hold nothing.
    kept: Vec<OnceLock<Option<Box<TileLookups>>>>,
    budget: u64,
    used: AtomicU64,
}

impl Lookups {
    /// Room for `views` views over `tiles` tiles, keeping at most `budget` bytes.
    pub fn new(views: usize, tiles: usize, budget: u64) -> Lookups {
        Lookups {
            tiles,
            kept: (0..views * tiles).map(|_| OnceLock::new()).collect(),
            budget,
            used: AtomicU64::new(0),
        }
    }

    /// Tile `tile`'s look-ups in view `view`: kept ones, else from `find` (kept if they fit).
    pub fn with<R>(
        &self,
        view: usize,
        tile: usize,
        find: impl Fn() -> Result<TileLookups>,
        use_them: impl FnOnce(&TileLookups) -> R,
    ) -> Result<R> {
        let Some(slot) = self.kept.get(view * self.tiles + tile) else {
            return Ok(use_them(&find()?));
        };
        if slot.get().is_none() {
            let found = find()?;
            let bytes = found.bytes();
            if self.used.fetch_add(bytes, Ordering::Relaxed) + bytes > self.budget {
                self.used.fetch_sub(bytes, Ordering::Relaxed);
                let _ = slot.set(None);
                return Ok(use_them(&found));
            }
            let _ = slot.set(Some(Box::new(found)));
        }
        match slot.get() {
            Some(Some(kept)) => Ok(use_them(kept)),
            _ => Ok(use_them(&find()?)),
        }
    }

    /// Bytes kept.
    pub fn bytes(&self) -> u64 {
        self.used.load(Ordering::Relaxed)
    }
}
