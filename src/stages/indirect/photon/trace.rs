//! One photon's path, a pure function of (seed, iteration, batch, index): emission, diffuse
//! bounces with Russian roulette on `K_d`, and a deposit at every hit after the first diffuse
//! bounce ([`Paths::Indirect`]), or only the first diffuse hit after mirrors and glass
//! ([`Paths::Caustic`]). Kept apart from the batching so a single photon can be replayed and
//! tested.

use super::{Deposit, PassContext, Paths};
use crate::atlas::uv::NONE;
use crate::base::rng::Rng;
use crate::physics::accel::offset_origin;
use crate::physics::bsdf_sampling;
use std::ops::AddAssign;

/// Lowest Russian-roulette survival probability: a dark surface still passes a few photons
/// on (with a larger weight) instead of making its neighbours' `E_i` rest on rare events.
pub const MIN_SURVIVAL: f32 = 0.05;

/// Counters of one or more photon paths.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PathCounts {
    /// Closest-hit rays cast.
    pub rays: u64,
    /// Hits after a bounce dropped because their texel is not on the hit's chart.
    pub dropped: u64,
}

impl AddAssign for PathCounts {
    fn add_assign(&mut self, o: Self) {
        self.rays += o.rays;
        self.dropped += o.dropped;
    }
}

/// Traces photon `index` of batch `batch` and appends its deposits to `out`, in path order.
///
/// At each hit, in order:
/// 1. A known material (mirror, glass, ...) scatters the photon on (`bsdf_sampling::sample`,
///    Russian roulette on its weight; it counts as a bounce); an emitter absorbs. So does a
///    one-sided (`Sides::Front`) surface hit from behind its shading normal, and any hit
///    where the shading and geometric normals disagree about the side (grazing; a
///    shading-normal artifact).
/// 2. [`Paths::Indirect`]: after at least one diffuse bounce, the flux is deposited into the
///    texel under the hit (if that texel's center is on the hit's chart; dropped otherwise).
///    Light that reached the surface by mirrors and glass alone is the caustic pass's.
///    [`Paths::Caustic`]: the first diffuse hit ends the path, with a deposit if mirrors or
///    glass came before it.
/// 3. After `max_depth` bounces the path ends.
/// 4. Russian roulette with survival `q = clamp(max K_d, MIN_SURVIVAL, 1)`, flux `*= K_d / q`.
/// 5. A cosine-weighted direction about the shading normal on the incident side; a direction
///    that would cross the geometric surface ends the path (absorbed).
pub fn trace_photon(
    ctx: &PassContext,
    batch: u64,
    index: u64,
    out: &mut Vec<Deposit>,
) -> PathCounts {
    let mut counts = PathCounts::default();
    let mut rng = Rng::new(ctx.seed, ctx.iteration, batch, index);
    let Some(ph) = ctx.sampler.sample_photon(&mut rng) else {
        return counts;
    };
    let mut flux = ph.flux * (1.0 / ctx.photons as f64) as f32;
    let (mut o, mut d) = (ph.origin, ph.dir);
    let (mut bounces, mut diffuse) = (0u32, 0u32);
    loop {
        counts.rays += 1;
        let Some((hit, prim)) = ctx.hits.trace(ctx.accel, o, d, f32::INFINITY) else {
            break;
        };
        if prim.slot == NONE {
            // known materials scatter (mirrors, glass: caustics are `E_i`); emitters absorb
            let Some(b) = ctx.hits.known(prim) else {
                break;
            };
            if bounces >= ctx.max_depth || (prim.one_sided && d.dot(hit.ns) >= 0.0) {
                break;
            }
            let Some(sc) = bsdf_sampling::sample(b, d, hit.ns, &mut rng) else {
                break;
            };
            let q = sc.weight.max_element().clamp(MIN_SURVIVAL, 1.0);
            if positive(q).is_none() || rng.f32() >= q {
                break;
            }
            flux *= sc.weight / q;
            o = offset_origin(hit.p, prim.ng, sc.dir);
            d = sc.dir;
            bounces += 1;
            continue;
        }
        let slot = prim.slot as usize;
        let (ng, ns) = (prim.ng, hit.ns);
        let (cg, cs) = (d.dot(ng), d.dot(ns));
        // Same side by both normals (also rejects zeros and NaN).
        if positive(cg * cs).is_none() {
            break;
        }
        if prim.one_sided && cs >= 0.0 {
            break;
        }
        let (texel, inside) = ctx.albedo.texel(slot, hit.uv);
        let deposit = match ctx.paths {
            Paths::Indirect => diffuse > 0,
            Paths::Caustic => bounces > 0,
        };
        if deposit {
            // Binned only where the texel's center is on the hit's chart (module doc of
            // `photon`, "Unbiased bins").
            if inside && prim.chart != NONE && texel.chart == prim.chart {
                let (tile, offset) = ctx.layout.locate(slot, hit.uv.x as u32, hit.uv.y as u32);
                let flux = flux.to_array();
                out.push(Deposit { tile, offset, flux });
            } else {
                counts.dropped += 1;
            }
        }
        if bounces >= ctx.max_depth || ctx.paths == Paths::Caustic {
            break;
        }
        let kd = texel.kd;
        let Some(kmax) = positive(kd.max_element()) else {
            break;
        };
        let q = kmax.clamp(MIN_SURVIVAL, 1.0);
        if rng.f32() >= q {
            break;
        }
        flux *= kd / q;
        let n_in = if cs < 0.0 { ns } else { -ns };
        let dir = bsdf_sampling::cosine_dir(n_in, &mut rng);
        // Leaving on the incident side of the geometric surface: dir.ng has cg's opposite sign.
        if positive(-dir.dot(ng) * cg).is_none() {
            break;
        }
        o = offset_origin(hit.p, ng, dir);
        d = dir;
        bounces += 1;
        diffuse += 1;
    }
    counts
}

/// `Some(x)` if `x > 0` (so not NaN).
#[inline]
fn positive(x: f32) -> Option<f32> {
    (x > 0.0).then_some(x)
}
