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
//!
//! The same holds for the re-render's side: a pixel that does not lie flat on one chart is
//! re-rendered by tracing its sub-pixel rays in every pass, though what they hit (shape and
//! texture coordinates) never changes; on a room of 1.1M triangles those rays were most of the
//! refinement's time. So each view's sub-pixel hits ([`ViewHits`]) are kept too, from the same
//! budget, and the pixel is rendered from them with the same bits.

use super::view::{Tap, Value, View};
use super::{observe_with, ShapeRef};
use crate::atlas::store::TexelGeom;
use crate::base::error::Result;
use crate::physics::render::SubHit;
use rayon::prelude::*;
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
    /// read from a row-major image `width` pixels wide whose pixel `i` is `at(i)`: what
    /// [`super::observe_texel_from`] gives, to the bit.
    pub fn read<'a, T: Value>(
        &'a self,
        width: u32,
        at: impl Fn(usize) -> T + Copy + 'a,
    ) -> impl Iterator<Item = (usize, T, f32)> + 'a {
        self.texels.iter().map(move |t| {
            let taps = &self.taps[t.start as usize..(t.start + t.count) as usize];
            let mut sum = T::default();
            for tap in taps {
                sum += tap.read_index(width, at);
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
    /// Per view, its traced pixels' sub-pixel hits.
    hits: Vec<OnceLock<Option<ViewHits>>>,
    budget: u64,
    used: AtomicU64,
}

impl Lookups {
    /// Room for `views` views over `tiles` tiles, keeping at most `budget` bytes.
    pub fn new(views: usize, tiles: usize, budget: u64) -> Lookups {
        Lookups {
            tiles,
            kept: (0..views * tiles).map(|_| OnceLock::new()).collect(),
            hits: (0..views).map(|_| OnceLock::new()).collect(),
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
            if !self.admit(found.bytes()) {
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

    /// View `view`'s sub-pixel hits: kept ones, else from `find` (kept if they fit the budget,
    /// else used once and `None` from then on).
    pub fn with_hits<R>(
        &self,
        view: usize,
        find: impl FnOnce() -> ViewHits,
        use_them: impl FnOnce(Option<&ViewHits>) -> R,
    ) -> R {
        let Some(slot) = self.hits.get(view) else {
            return use_them(None);
        };
        if slot.get().is_none() {
            let found = find();
            if !self.admit(found.bytes()) {
                let _ = slot.set(None);
                return use_them(Some(&found));
            }
            let _ = slot.set(Some(found));
        }
        use_them(slot.get().and_then(Option::as_ref))
    }

    /// Whether `bytes` more fit the budget: if so they are counted as kept, else nothing is.
    fn admit(&self, bytes: u64) -> bool {
        if self.used.fetch_add(bytes, Ordering::Relaxed) + bytes > self.budget {
            self.used.fetch_sub(bytes, Ordering::Relaxed);
            return false;
        }
        true
    }

    /// Bytes kept.
    pub fn bytes(&self) -> u64 {
        self.used.load(Ordering::Relaxed)
    }
}

/// One view's sub-pixel hits ([`SubHit`], `k x k` per pixel) of the pixels it re-renders by
/// tracing.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ViewHits {
    /// Per pixel, the index of its first hit in `hits` over `k x k`, or `u32::MAX`.
    at: Vec<u32>,
    hits: Vec<SubHit>,
    per_pixel: usize,
}

impl ViewHits {
    /// The hits of the pixels of a `width x height` view for which `traced(x, y)` holds, from
    /// `trace(x, y)` (`per_pixel` each).
    pub fn find(
        (width, height): (u32, u32),
        per_pixel: usize,
        traced: &(dyn Fn(u32, u32) -> bool + Sync),
        trace: &(dyn Fn(u32, u32) -> Vec<SubHit> + Sync),
    ) -> ViewHits {
        let rows: Vec<Vec<(u32, Vec<SubHit>)>> = (0..height)
            .into_par_iter()
            .map(|y| {
                (0..width)
                    .filter(|&x| traced(x, y))
                    .map(|x| (y * width + x, trace(x, y)))
                    .collect()
            })
            .collect();
        let mut out = ViewHits {
            at: vec![u32::MAX; width as usize * height as usize],
            hits: Vec::new(),
            per_pixel,
        };
        for (i, h) in rows.into_iter().flatten() {
            out.at[i as usize] = (out.hits.len() / per_pixel.max(1)) as u32;
            out.hits.extend(h);
        }
        out
    }

    /// Pixel `i`'s hits, if it has them.
    pub fn get(&self, i: usize) -> Option<&[SubHit]> {
        let a = *self.at.get(i)?;
        (a != u32::MAX).then(|| &self.hits[a as usize * self.per_pixel..][..self.per_pixel])
    }

    /// Bytes held.
    pub fn bytes(&self) -> u64 {
        (self.at.capacity() * std::mem::size_of::<u32>()
            + self.hits.capacity() * std::mem::size_of::<SubHit>()) as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec2;

    fn fake(x: u32, y: u32) -> Vec<SubHit> {
        (0..4)
            .map(|i| SubHit {
                shape: x * 100 + y,
                uv: Vec2::new(i as f32, 0.0),
            })
            .collect()
    }

    /// Each traced pixel gets its own hits back, the others none; within the budget they are
    /// kept (found once), beyond it used once and then not kept.
    #[test]
    fn view_hits_are_found_once_and_kept_within_the_budget() {
        let traced = |x: u32, y: u32| (x + y) % 3 == 0;
        let h = ViewHits::find((5, 4), 4, &traced, &fake);
        for y in 0..4 {
            for x in 0..5 {
                let got = h.get((y * 5 + x) as usize).map(<[SubHit]>::to_vec);
                assert_eq!(got, traced(x, y).then(|| fake(x, y)), "({x}, {y})");
            }
        }
        assert_eq!(h.get(20), None, "outside the view");
        let finds = AtomicU64::new(0);
        let find = || {
            finds.fetch_add(1, Ordering::Relaxed);
            ViewHits::find((5, 4), 4, &traced, &fake)
        };
        let roomy = Lookups::new(2, 1, 1 << 20);
        for _ in 0..3 {
            assert!(roomy.with_hits(1, find, |h| h
                == Some(&ViewHits::find((5, 4), 4, &traced, &fake))));
        }
        assert_eq!(finds.load(Ordering::Relaxed), 1, "found once");
        assert!(roomy.bytes() > 0);
        let tight = Lookups::new(2, 1, 8);
        assert!(tight.with_hits(0, find, |h| h.is_some()), "used once");
        assert!(tight.with_hits(0, find, |h| h.is_none()), "then not kept");
        assert_eq!(finds.load(Ordering::Relaxed), 2);
        assert_eq!(tight.bytes(), 0);
    }
}
