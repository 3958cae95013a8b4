//! Light-source physics shared by the direct-light and photon stages: each emitter's radiant
//! power (for reports and photon budgeting), direct irradiance with shadows, and photon emission.
//!
//! Conventions are Mitsuba 3's, so a scene renders the same here and there:
//! - `point`: isotropic radiant intensity `I`; irradiance `E = I cos(gamma) / d^2`.
//! - `spot`: `I` on the axis times a falloff that is 1 up to `beam_width` and falls linearly in
//!   angle to 0 at `cutoff` ([`spot_falloff`]).
//! - `directional`: irradiance `E` on a surface perpendicular to the light; `E cos`.
//! - `area`: one-sided uniform radiance `L` leaving the front side of each emitter triangle
//!   (see [`area`] for how the front side is decided and how shadows stay low-noise).
//! - `envmap`, `constant`: radiance `L(w)` from infinitely far away in every direction
//!   (`crate::scene::EnvMap`), estimated with importance-sampled shadow rays ([`env`]).
//!
//! Every receiver is one-sided: light arriving from behind the shading normal `n` contributes
//! nothing (`cos` clamped at 0). Shadow rays start from [`offset_origin`] off the geometric
//! normal and stop just short (relative `1e-4`) of the light so an emitter never shadows itself.

pub mod area;
pub mod env;
pub mod sampler;
#[cfg(test)]
mod tests;

pub use sampler::{EmittedPhoton, EmitterSampler};

use crate::base::rng::Rng;
use crate::physics::accel::{offset_origin, Accel};
use crate::scene::{Emitter, Scene};
use glam::Vec3;
use std::f32::consts::PI;

/// Shadow rays stop this fraction short of the light they aim at.
pub(crate) const SHADOW_SHORTEN: f32 = 1e-4;

/// Radiant power of emitter `e` in `scene` (per RGB channel; scene radiance units x area).
///
/// - point: `4 pi I`;
/// - spot: `I` times the solid-angle integral of Mitsuba's linear falloff (see [`spot_solid_angle`]);
/// - directional: `irradiance * pi R^2`, `R` the radius of the scene's bounding sphere (Mitsuba's
///   convention: the power that crosses the scene; a directional light has no finite power);
/// - area: `pi L A`, `A` the summed triangle area of the emitting shape (one-sided Lambertian);
/// - environment: `pi R^2 int L(w) dw` (Mitsuba's: the power crossing a disk of the bounding
///   sphere's radius `R`, summed over directions; for a constant `L`, `4 pi^2 R^2 L`).
///
/// Cheap and total: degenerate input (missing shape, empty scene) gives zero, never a panic.
pub fn emitter_power(scene: &Scene, e: &Emitter) -> Vec3 {
    match *e {
        Emitter::Point { intensity, .. } => intensity * (4.0 * PI),
        Emitter::Spot {
            intensity,
            cutoff,
            beam_width,
            ..
        } => intensity * spot_solid_angle(cutoff, beam_width),
        Emitter::Directional { irradiance, .. } => {
            let r = bounding_sphere(scene).1;
            irradiance * (PI * r * r)
        }
        Emitter::Area { shape, radiance } => match scene.shapes.get(shape) {
            Some(s) => radiance * (PI * s.mesh.area() as f32),
            None => Vec3::ZERO,
        },
        Emitter::Environment(ref env) => {
            let r = bounding_sphere(scene).1;
            env.integral() * (PI * r * r)
        }
    }
}

/// The scene's bounding sphere `(center, radius)` as Mitsuba computes it: the center of the
/// axis-aligned bounds and the distance to a corner. `(0, 0)` for a scene without geometry.
pub fn bounding_sphere(scene: &Scene) -> (Vec3, f32) {
    let (lo, hi) = scene.bounds();
    if !(lo.is_finite() && hi.is_finite()) {
        return (Vec3::ZERO, 0.0);
    }
    let c = 0.5 * (lo + hi);
    (c, (hi - c).length())
}

/// Mitsuba's spot falloff at angle `theta` from the axis: 1 up to `beam_width`, then linear in
/// angle down to 0 at `cutoff`, 0 beyond. A beam wider than the cutoff acts as the cutoff.
#[inline]
pub fn spot_falloff(theta: f32, cutoff: f32, beam_width: f32) -> f32 {
    let beam = beam_width.min(cutoff);
    if theta >= cutoff {
        0.0
    } else if theta <= beam {
        1.0
    } else {
        ((cutoff - theta) / (cutoff - beam)).clamp(0.0, 1.0)
    }
}

/// [`spot_falloff`] of a spot of unit `axis` towards a point that sees the light in unit
/// direction `to_light`.
#[inline]
pub fn spot_falloff_towards(axis: Vec3, to_light: Vec3, cutoff: f32, beam_width: f32) -> f32 {
    let theta = axis.dot(-to_light).clamp(-1.0, 1.0).acos();
    spot_falloff(theta, cutoff, beam_width)
}

/// `integral of spot_falloff over the sphere` (steradians), in closed form:
/// `2 pi [ (1 - cos b) + int_b^c (c - t)/(c - b) sin t dt ] = 2 pi [ 1 - (sin c - sin b)/(c - b) ]`,
/// written as `2 pi [1 - cos m * sin(h)/h]`, `m = (c + b)/2`, `h = (c - b)/2`, which stays
/// accurate as the transition width goes to zero (then it is the cone's `2 pi (1 - cos c)`).
pub fn spot_solid_angle(cutoff: f32, beam_width: f32) -> f32 {
    let c = (cutoff as f64).clamp(0.0, std::f64::consts::PI);
    let b = (beam_width as f64).clamp(0.0, c);
    let m = 0.5 * (c + b);
    let h = 0.5 * (c - b);
    let sinc = if h < 1e-4 {
        1.0 - h * h / 6.0
    } else {
        h.sin() / h
    };
    let v = 2.0 * std::f64::consts::PI * (1.0 - m.cos() * sinc);
    v.max(0.0) as f32
}

/// Settings of the direct-light estimate. A plain `Copy` struct with named presets.
///
/// Direct light is the mean irradiance over a texel's square on the surface ([`Footprint`]),
/// as the photos' radiance is the mean over it, so a texel cut by a shadow edge gets the
/// shadowed share right. Each emitter is estimated in two steps: a first pass of a few shadow
/// rays; only where they disagree (a shadow edge or a penumbra crosses the texel) a second,
/// dense estimate replaces it. Texels lit or shadowed throughout cost the first pass and are
/// exact (the unoccluded irradiance is analytic). Area lights pair stratified points of the
/// texel with stratified points of each emitter triangle; point, spot and directional lights
/// use stratified points of the texel. Relative noise in a penumbra falls roughly as
/// `samples^(-3/4)`: at a half-shadowed point under a two-triangle light (std over keys) it
/// is 6.1% at 16 samples, 2.5% at 64, 0.67% at 256 and 0.25% at 1024.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DirectParams {
    /// First-pass shadow rays per area-emitter triangle, rounded up to a square `k^2`
    /// (stratified over `k^2` equal sub-triangles). 0 = no shadow test for area lights (the
    /// unoccluded analytic irradiance).
    pub area_samples: u32,
    /// Shadow rays per area emitter where the first pass finds a penumbra, shared by its
    /// triangles by area (each at least `area_samples`, rounded up to a square). At most
    /// `area_samples` means no second pass.
    pub penumbra_samples: u32,
    /// Points of the texel a point, spot or directional light is tested from where its first
    /// pass (3 x 3 points) finds a shadow edge (rounded up to a square).
    pub edge_samples: u32,
    /// Sample pairs (a direction from the map, a cosine-weighted one, a point of the texel) per
    /// texel for an environment light (rounded up to a square). 0 = no shadow test (the
    /// unoccluded irradiance).
    pub env_samples: u32,
    /// Most times an area-emitter triangle is split in four where no straight shadow line
    /// fits it ([`area::FIT_DEPTH`]); 0 samples such a triangle with the penumbra rays at once.
    pub fit_depth: u32,
}

impl DirectParams {
    /// These parameters with the dense samples (an environment light's pairs, an area light's
    /// penumbra rays, a hard light's edge points) cut to `share` of theirs, at least one (0
    /// stays 0), and below 1 an area light's penumbra sampled without fitting shadow lines in
    /// its pieces (each fit costs tens of rays, and a complex shadow, balusters or chair legs,
    /// tries up to 85 of them a triangle); the first pass, which tells lit from dark, is kept.
    pub fn scaled(&self, share: f32) -> Self {
        let cut = |n: u32| match n {
            0 => 0,
            n => ((n as f64 * share as f64).round() as u32).clamp(1, n),
        };
        DirectParams {
            area_samples: self.area_samples,
            penumbra_samples: cut(self.penumbra_samples),
            edge_samples: cut(self.edge_samples),
            env_samples: cut(self.env_samples),
            fit_depth: if share < 1.0 { 0 } else { self.fit_depth },
        }
    }

    /// Previews: 9 rays per emitter triangle, 256 in penumbrae (~0.7% noise there).
    pub fn fast() -> Self {
        DirectParams {
            area_samples: 9,
            penumbra_samples: 256,
            edge_samples: 16,
            env_samples: 36,
            fit_depth: area::FIT_DEPTH,
        }
    }
    /// Wide penumbrae or thin occluders: 64 rays per emitter triangle, 4096 in penumbrae.
    pub fn high_quality() -> Self {
        DirectParams {
            area_samples: 64,
            penumbra_samples: 4096,
            edge_samples: 256,
            env_samples: 1024,
            fit_depth: area::FIT_DEPTH,
        }
    }
}

impl Default for DirectParams {
    /// 16 rays (4 x 4 strata) per emitter triangle, 2048 per emitter in penumbrae for a
    /// penumbra noise of about 0.25% (the target is < 0.3%); 8 x 8 texel points across a
    /// hard shadow edge; 144 sample pairs per texel under an environment light.
    fn default() -> Self {
        DirectParams {
            area_samples: 16,
            penumbra_samples: 2048,
            edge_samples: 64,
            env_samples: crate::config::ENV_SAMPLES,
            fit_depth: area::FIT_DEPTH,
        }
    }
}

/// A texel's square on the surface: its center, the world-space edge vectors of the square
/// (`dP/dx`, `dP/dy` of the atlas map, on the center triangle's plane) and its normals. A
/// point is a footprint with zero edges.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Footprint {
    pub p: Vec3,
    pub dx: Vec3,
    pub dy: Vec3,
    /// Unit shading normal of the receiving side (light from behind it counts 0).
    pub n: Vec3,
    /// Geometric normal (for offsetting ray origins; either orientation).
    pub ng: Vec3,
}

impl Footprint {
    /// A surface point.
    pub fn point(p: Vec3, n: Vec3, ng: Vec3) -> Footprint {
        Footprint {
            p,
            dx: Vec3::ZERO,
            dy: Vec3::ZERO,
            n,
            ng,
        }
    }

    pub(crate) fn is_point(&self) -> bool {
        self.dx == Vec3::ZERO && self.dy == Vec3::ZERO
    }

    /// The point at `(a, b)` of the unit square of the texel (`(0.5, 0.5)` is the center).
    #[inline]
    fn at(&self, a: f32, b: f32) -> Vec3 {
        self.p + self.dx * (a - 0.5) + self.dy * (b - 0.5)
    }
}

/// Direct irradiance at surface point `p` from every emitter of the scene, with shadows.
///
/// `n` is the unit shading normal of the receiving side (light from behind it counts 0), `ng`
/// the geometric normal (for offsetting shadow-ray origins; either orientation). `key` =
/// `(seed, index)` addresses the random numbers (area-light shadow samples): the result is a
/// pure function of its arguments. Per RGB channel, in scene irradiance units.
pub fn direct_irradiance(
    scene: &Scene,
    accel: &Accel,
    p: Vec3,
    n: Vec3,
    ng: Vec3,
    params: &DirectParams,
    key: (u64, u64),
) -> Vec3 {
    texel_irradiance(
        scene,
        accel,
        &Footprint::point(p, n, ng),
        params,
        key,
        false,
    )
    .0
}

/// [`direct_irradiance`] split by emitter: element `k` is emitter `k`'s contribution (the
/// same random numbers, so the elements sum to `direct_irradiance` up to rounding).
pub fn direct_irradiance_per_emitter(
    scene: &Scene,
    accel: &Accel,
    p: Vec3,
    n: Vec3,
    ng: Vec3,
    params: &DirectParams,
    key: (u64, u64),
) -> Vec<Vec3> {
    let fp = Footprint::point(p, n, ng);
    (0..scene.emitters.len())
        .map(|k| emitter_irradiance(scene, accel, k, &fp, params, key, false).0)
        .collect()
}

/// How an emitter's light reaches a texel, as its first pass found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reach {
    /// No light: the texel faces away, is outside the beam, or is wholly shadowed.
    Dark,
    /// Unoccluded over the whole texel: the irradiance is the analytic unoccluded one.
    Lit,
    /// A shadow edge or a penumbra crosses the texel: estimated densely.
    Partial,
}

/// The mean direct irradiance over texel footprint `fp` from every emitter (see
/// [`DirectParams`]), and whether some light was partly visible from it (a shadow edge or a
/// penumbra crosses it). With `dense`, every emitter skips its first pass and is estimated
/// densely.
pub fn texel_irradiance(
    scene: &Scene,
    accel: &Accel,
    fp: &Footprint,
    params: &DirectParams,
    key: (u64, u64),
    dense: bool,
) -> (Vec3, bool) {
    (0..scene.emitters.len()).fold((Vec3::ZERO, false), |(e, edge), k| {
        let (ek, reach) = emitter_irradiance(scene, accel, k, fp, params, key, dense);
        (e + ek, edge || reach == Reach::Partial)
    })
}

/// The mean direct irradiance over `fp` from emitter `k` alone, and how it reaches the texel
/// (see [`texel_irradiance`]). An index out of range gives zero.
#[allow(clippy::too_many_arguments)]
pub fn emitter_irradiance(
    scene: &Scene,
    accel: &Accel,
    k: usize,
    fp: &Footprint,
    params: &DirectParams,
    key: (u64, u64),
    dense: bool,
) -> (Vec3, Reach) {
    let (e, reach, _) = emitter_irradiance_var(scene, accel, k, fp, params, key, dense);
    (e, reach)
}

/// [`emitter_irradiance`], with the variance of the luminance of the estimate where its
/// sampling noise is stated: an environment light's ([`env::irradiance_var`], an upper
/// bound). Point, spot and directional light give 0 (exact but for the texel's stratified
/// shadow points), and so does an area light (its stratified shadow rays are not counted).
#[allow(clippy::too_many_arguments)]
pub fn emitter_irradiance_var(
    scene: &Scene,
    accel: &Accel,
    k: usize,
    fp: &Footprint,
    params: &DirectParams,
    key: (u64, u64),
    dense: bool,
) -> (Vec3, Reach, f32) {
    let Some(e) = scene.emitters.get(k) else {
        return (Vec3::ZERO, Reach::Dark, 0.0);
    };
    if let Emitter::Area { shape, radiance } = *e {
        let Some(s) = scene.shapes.get(shape) else {
            return (Vec3::ZERO, Reach::Dark, 0.0);
        };
        let stream = (key.0, k as u64, key.1);
        let (f, reach) = area::irradiance_factor(&s.mesh, accel, fp, params, stream, dense);
        return (radiance * f as f32, reach, 0.0);
    }
    if let Emitter::Environment(env) = e {
        let (e, var) = match params.env_samples {
            0 => env::irradiance_var(env, None, fp, ENV_UNOCCLUDED, (0, k as u64, 0)),
            n => env::irradiance_var(env, Some(accel), fp, n, (key.0, k as u64, key.1)),
        };
        // always sampled: nothing analytic to stand for a lit texel
        return (e, Reach::Partial, var);
    }
    let mut rng = Rng::new(key.0 ^ HARD_TAG, k as u64, key.1, 0);
    let (e, reach) = hard_irradiance(accel, fp, params, &mut rng, dense, &|q| {
        hard_light(e, fp.n, q)
    });
    (e, reach, 0.0)
}

/// The unoccluded irradiance of emitter `k` at `fp`'s center (what a [`Reach::Lit`] texel
/// receives): analytic, no rays.
pub fn emitter_unoccluded(scene: &Scene, k: usize, fp: &Footprint) -> Vec3 {
    match scene.emitters.get(k) {
        None => Vec3::ZERO,
        Some(Emitter::Area { shape, radiance }) => match scene.shapes.get(*shape) {
            Some(s) => *radiance * area::unoccluded_factor(&s.mesh, fp.p, fp.n) as f32,
            None => Vec3::ZERO,
        },
        Some(Emitter::Environment(env)) => {
            env::irradiance(env, None, fp, ENV_UNOCCLUDED, (0, k as u64, 0))
        }
        Some(e) => hard_light(e, fp.n, fp.p).map_or(Vec3::ZERO, |(e, _)| e),
    }
}

/// Sample pairs of the unoccluded irradiance of an environment light (no rays, a fixed key).
const ENV_UNOCCLUDED: u32 = 1024;

/// A point, spot or directional light at point `q` (receiving normal `n`): its unoccluded
/// irradiance and where it comes from, or `None` where `q` faces away or is outside the beam.
fn hard_light(e: &Emitter, n: Vec3, q: Vec3) -> Option<(Vec3, Toward)> {
    match *e {
        Emitter::Point {
            position,
            intensity,
        } => {
            let (_, d2, cos) = towards(q, n, position)?;
            Some((intensity * (cos / d2), Toward::Point(position)))
        }
        Emitter::Spot {
            position,
            axis,
            intensity,
            cutoff,
            beam_width,
            ..
        } => {
            let (dir, d2, cos) = towards(q, n, position)?;
            let f = spot_falloff_towards(axis.normalize_or_zero(), dir, cutoff, beam_width);
            (f > 0.0).then(|| (intensity * (f * cos / d2), Toward::Point(position)))
        }
        Emitter::Directional {
            direction,
            irradiance,
        } => {
            let dir = -direction.normalize_or_zero();
            let cos = n.dot(dir);
            (cos > 0.0).then(|| (irradiance * cos, Toward::Direction(dir)))
        }
        Emitter::Area { .. } | Emitter::Environment(_) => None,
    }
}

/// Mixed into the seed of the texel points of point, spot and directional lights.
const HARD_TAG: u64 = 0x5ad0_ed9e_0000_0001;

/// Where the light of a point, spot or directional emitter comes from.
#[derive(Clone, Copy)]
enum Toward {
    Point(Vec3),
    /// A unit direction towards the light.
    Direction(Vec3),
}

/// The mean over `fp` of a point, spot or directional light (`light(q)`: see
/// [`hard_light`]). 3 x 3 stratified points first: all lit gives the unoccluded irradiance at
/// the center, none lit 0; where some see the light and some do not (a shadow edge),
/// `edge_samples` points.
fn hard_irradiance(
    accel: &Accel,
    fp: &Footprint,
    params: &DirectParams,
    rng: &mut Rng,
    dense: bool,
    light: &dyn Fn(Vec3) -> Option<(Vec3, Toward)>,
) -> (Vec3, Reach) {
    let seen = |q: Vec3| -> (Vec3, bool) {
        match light(q) {
            None => (Vec3::ZERO, false),
            Some((e, Toward::Point(target))) => (e, visible_to(accel, q, fp.ng, target)),
            Some((e, Toward::Direction(dir))) => {
                let o = offset_origin(q, fp.ng, dir);
                (e, !accel.occluded(o, dir, f32::INFINITY))
            }
        }
    };
    if fp.is_point() {
        return match seen(fp.p) {
            (e, true) => (e, Reach::Lit),
            _ => (Vec3::ZERO, Reach::Dark),
        };
    }
    let mean = |k: u32, rng: &mut Rng| -> (Vec3, u32, u32) {
        let (mut sum, mut lit, mut facing) = (Vec3::ZERO, 0, 0);
        for j in 0..k {
            for i in 0..k {
                let a = (i as f32 + rng.f32()) / k as f32;
                let b = (j as f32 + rng.f32()) / k as f32;
                let (e, v) = seen(fp.at(a, b));
                facing += (e != Vec3::ZERO) as u32;
                if v {
                    sum += e;
                    lit += 1;
                }
            }
        }
        (sum / (k * k) as f32, lit, facing)
    };
    if !dense {
        let (_, lit, facing) = mean(FIRST_HARD, rng);
        if lit == 0 {
            return (Vec3::ZERO, Reach::Dark);
        }
        if lit == facing && facing == FIRST_HARD * FIRST_HARD {
            return (light(fp.p).map_or(Vec3::ZERO, |(e, _)| e), Reach::Lit);
        }
    }
    (mean(strata(params.edge_samples), rng).0, Reach::Partial)
}

/// Texel points per side of the first pass of point, spot and directional lights: 3 x 3
/// finds an edge crossing a texel unless it cuts off under a ninth of it (and then the
/// neighbours' dense estimates usually have; see `crate::stages::direct`).
const FIRST_HARD: u32 = 3;

/// Strata per side for `samples` samples.
pub(crate) fn strata(samples: u32) -> u32 {
    ((samples.max(1) as f64).sqrt().ceil() as u32).max(1)
}

/// Unit direction from `p` to `q`, squared distance and receiver cosine, if `q` is in front of
/// the receiver (`cos > 0`) and not at `p`.
#[inline]
fn towards(p: Vec3, n: Vec3, q: Vec3) -> Option<(Vec3, f32, f32)> {
    let v = q - p;
    let d2 = v.length_squared();
    if d2.is_nan() || d2 <= 0.0 || d2.is_infinite() {
        return None;
    }
    let dir = v / d2.sqrt();
    let cos = n.dot(dir);
    (cos > 0.0).then_some((dir, d2, cos))
}

/// Whether the point `target` is visible from surface point `p` (geometric normal `ng`): a
/// shadow ray from the offset origin that stops [`SHADOW_SHORTEN`] short of the target.
#[inline]
pub(crate) fn visible_to(accel: &Accel, p: Vec3, ng: Vec3, target: Vec3) -> bool {
    let o = offset_origin(p, ng, target - p);
    let v = target - o;
    let len = v.length();
    if len.is_nan() || len <= 0.0 {
        return true;
    }
    !accel.occluded(o, v / len, len * (1.0 - SHADOW_SHORTEN))
}
