//! What bounds the gather's cost by texels and memory, not by the number of shapes: a cap on its
//! points and a memory limit on its cache of hits.
//!
//! Each shape's points are `min(scene radius / 32, shape radius / 16)` apart
//! ([`crate::config::Config::gather_spacing_for`]), so a small shape gets as many points as a
//! large one: a scene of hundreds of small parts (the lego bulldozer: 439 bricks, 530k covered
//! texels) got 325k points, one per 1.6 texels, 333M rays and 283M cached hits (10 GB). So the
//! points are capped at one per [`TEXELS_PER_POINT`] covered texels (at least
//! [`MIN_POINTS`]): where a scene's spacings would place more, the smallest spacings are raised
//! to a common floor until the points fit. Scenes of a few large shapes place far fewer
//! (cbox-tex: 10,444 points for 392,687 texels) and are not touched.
//!
//! The hits a gather keeps for re-evaluation are held within a byte limit
//! ([`GatherCache`](super::GatherCache)): the points beyond it keep no hits and cast their rays
//! again at every evaluation, with the same random numbers, so the values are the same bits;
//! only the time grows.

use super::GatherPoints;
use crate::atlas::store::{TexelGeom, TexelState, TileStore};
use crate::atlas::texture::Scratch;
use crate::atlas::uv::Charts;
use crate::atlas::RunContext;
use crate::base::error::Result;
use crate::base::progress::Tick;

/// Covered texels per gather point, at most, on average over the scene.
pub const TEXELS_PER_POINT: u64 = 32;
/// The cap never goes below this many points (coarse atlases).
pub const MIN_POINTS: u64 = 4096;
/// Rounds of raising the spacing floor before the points are taken as they are (each round
/// places the points again; one or two suffice: points fall as the floor squared).
const ROUNDS: usize = 8;

/// The most gather points for a scene of `covered` texels.
pub fn point_cap(covered: u64) -> usize {
    (covered / TEXELS_PER_POINT).max(MIN_POINTS) as usize
}

/// Rays per point for `points` points under `cap`: `rays` where they fit, else fewer in
/// proportion (at least [`MIN_RAYS`]), so the rays stay within `cap x rays` when the points
/// cannot be brought under the cap (every chart in a cell keeps its point: a shape of many
/// small charts keeps one per chart whatever the spacing).
pub fn rays_for(rays: u32, points: usize, cap: usize) -> u32 {
    if points <= cap {
        return rays;
    }
    let scaled = (u64::from(rays) * cap as u64 / points as u64) as u32;
    scaled.max(MIN_RAYS).min(rays)
}

/// The fewest rays per point [`rays_for`] gives.
pub const MIN_RAYS: u32 = 64;

/// Gather points with each shape's `spacing`, the smallest spacings raised to a common floor
/// where more than `cap` points would be placed; with the floor (0 when none was needed).
pub fn capped_points(
    p: &RunContext,
    (geom, state, charts): (&TileStore<TexelGeom>, &TileStore<TexelState>, &Charts),
    spacing: &[f32],
    cap: usize,
    scratch: &Scratch,
    tick: Tick,
) -> Result<(GatherPoints, f32)> {
    let place = |floor: f32, tick: Tick| {
        GatherPoints::new(
            p,
            geom,
            state,
            charts,
            &|s| spacing[s].max(floor),
            scratch,
            tick,
        )
    };
    let mut floor = 0.0f32;
    let mut pts = place(floor, tick)?;
    for _ in 0..ROUNDS {
        if pts.points.len() <= cap {
            break;
        }
        floor = next_floor(floor, spacing, pts.points.len(), cap);
        pts = place(floor, &|_| {})?;
    }
    Ok((pts, floor))
}

/// The floor for the next round: points fall as the spacing squared where the floor applies,
/// so from the smallest spacing in use it is raised by the square root of the excess (and a
/// little more, as the shapes above the floor keep their points).
fn next_floor(floor: f32, spacing: &[f32], placed: usize, cap: usize) -> f32 {
    let smallest = spacing
        .iter()
        .copied()
        .filter(|s| *s > 0.0)
        .fold(f32::INFINITY, f32::min);
    let from = floor.max(if smallest.is_finite() { smallest } else { 0.0 });
    from * ((placed as f32 / cap as f32).sqrt() * 1.1)
}

/// The byte limit of the ray cache for a run of `memory_budget_mib`: half of it, beside the
/// radiance lookups' half.
pub fn cache_bytes(memory_budget_mib: u64) -> u64 {
    (memory_budget_mib << 20) / 2
}

/// Bytes a point's kept hits take.
pub(super) fn hit_bytes(hits: usize) -> u64 {
    (hits * std::mem::size_of::<super::CachedHit>()) as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cap_follows_covered_texels_with_a_floor() {
        assert_eq!(point_cap(392_687), 12_271);
        assert_eq!(point_cap(1000), MIN_POINTS as usize);
    }

    #[test]
    fn rays_shrink_with_the_points_over_the_cap_down_to_a_floor() {
        assert_eq!(rays_for(1024, 10_000, 10_000), 1024);
        assert_eq!(rays_for(1024, 40_000, 10_000), 256);
        assert_eq!(rays_for(1024, 10_000_000, 10_000), MIN_RAYS);
        // never more than asked
        assert_eq!(rays_for(32, 40_000, 10_000), 32);
    }
}
