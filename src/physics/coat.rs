//! A known coat over a reconstructed diffuse base (Mitsuba 3's `plastic` and `roughplastic`
//! with `nonlinear = false`): the share of light the coat lets through to and from the base,
//! and the coat's own reflection as a few deterministic lobe samples.
//!
//! Mitsuba's diffuse part is `rho / pi * t(cos_i) t(cos_o) / (eta^2 (1 - R_int))`: for the
//! smooth coat `t = 1 - F` and `R_int` the diffuse Fresnel reflectance seen from inside; for the
//! rough coat `t(mu)` the light refracted through the rough interface that its microfacets do
//! not shadow (`(1 - F) G1` over the visible normals, Mitsuba's `eval_transmittance`, a little
//! under `1 - R(mu)`, `R` the directional albedo of the rough reflection), tabulated at 64
//! cosines and interpolated linearly as Mitsuba does, and `R_int = 2 mean(mu R(mu, 1/eta))`
//! over the same cosines. So a camera sees
//! `L = L_coat + rho T_o E' / pi` with `T_o = t(cos_o) / (eta^2 (1 - R_int))` and
//! `E' = integral t(cos_i) L_i cos_i`, and kdmap reconstructs `rho` as a Lambertian albedo
//! under `E'` from `(L - L_coat) / T_o`. `t` and `R` are estimated here on a stratified grid
//! of microfacet normals (Mitsuba integrates them by quadrature).

use super::bsdf_sampling::{microfacet_normal_at, reflect, refract, shadowing, smith_g1};
use crate::base::rng::Rng;
use crate::scene::material::fresnel_dielectric;
use crate::scene::{Emitter, KnownBsdf, Rgb, Rough, Scene};
use glam::Vec3;

/// Cosines of the rough transmittance table (Mitsuba's `MI_ROUGH_TRANSMITTANCE_RES`).
const RES: usize = 64;
/// Side of the stratified grid of microfacet normals that estimates a rough albedo.
const ALBEDO_GRID: usize = 48;
/// Side of the stratified grid of a rough coat's reflection samples at one pixel: 64 samples.
/// A varnished floor under a sky seen through windows (Bitterli's living room) had held-out
/// albedo error 33.1% with 16 samples and 22.9% with 64.
pub const LOBE_GRID: usize = 8;

/// One coat's factors, settled once per run.
#[derive(Debug, Clone)]
pub struct Coat {
    pub eta: f32,
    pub specular: Rgb,
    pub rough: Option<Rough>,
    /// Rough coats: `t` at `mu = i / (RES - 1)`; empty for a smooth coat.
    table: Vec<f32>,
    /// `1 / (eta^2 (1 - R_int))`.
    out_scale: f32,
    /// The cosine-weighted mean of `t` over the hemisphere.
    mean_t: f32,
}

/// One sampled direction of the coat's reflection and its weight (`f cos / pdf`, per channel).
pub type Lobe = (Vec3, Rgb);

impl Coat {
    /// The coat of a coated material (see [`KnownBsdf::coat`]), `None` for any other.
    pub fn of(b: &KnownBsdf) -> Option<Coat> {
        let KnownBsdf::Plastic {
            eta,
            specular,
            rough,
            fdr_int,
            ..
        } = b.coat()?
        else {
            return None;
        };
        let (table, r_int) = match rough {
            Some(r) => rough_tables(*eta, *r),
            None => (Vec::new(), *fdr_int),
        };
        let mut c = Coat {
            eta: *eta,
            specular: *specular,
            rough: *rough,
            table,
            out_scale: 1.0 / (eta * eta * (1.0 - r_int)),
            mean_t: 0.0,
        };
        c.mean_t = hemisphere_mean(|mu| c.transmittance(mu));
        Some(c)
    }

    /// `t(cos)`: the share of light arriving at cosine `cos` that enters the coat (and, by
    /// reciprocity, of the base's light that leaves it at that cosine).
    pub fn transmittance(&self, cos: f32) -> f32 {
        let c = cos.clamp(0.0, 1.0);
        if self.table.is_empty() {
            return 1.0 - fresnel_dielectric(c, self.eta);
        }
        let x = c * (RES - 1) as f32;
        let i = (x as usize).min(RES - 2);
        let w = x - i as f32;
        (1.0 - w) * self.table[i] + w * self.table[i + 1]
    }

    /// `T_o`: the base's radiance leaving at cosine `cos_o`, over that of a Lambertian
    /// surface of the same albedo under the transmitted irradiance `E'`.
    pub fn base_out(&self, cos_o: f32) -> f32 {
        self.transmittance(cos_o) * self.out_scale
    }

    /// The share of a uniform hemisphere of light the coat lets in (`E' / E` for it).
    pub fn mean_transmittance(&self) -> f32 {
        self.mean_t
    }

    /// The coat's reflection seen along `wi` (unit, towards the viewer) at a point of unit
    /// normal `ns` on the viewer's side: the mirror direction for a smooth coat, a
    /// `LOBE_GRID^2` stratified set (offset by `rng`) for a rough one.
    pub fn reflection(&self, wi: Vec3, ns: Vec3, rng: &mut Rng) -> Vec<Lobe> {
        let all = self.reflection_split(wi, ns, rng);
        all.into_iter().map(|(lobe, _)| lobe).collect()
    }

    /// [`Coat::reflection`], each sample with its weight in an estimate made from the coarse
    /// sub-grid alone (every other row and column of the grid, a stratified subset): the
    /// grid's size over the sub-grid's on the sub-grid (4 for the 8x8 grid), 0 off it, 1 for
    /// the smooth coat's one direction. What costs too much to read on every sample is read
    /// on the sub-grid at that weight.
    pub fn reflection_split(&self, wi: Vec3, ns: Vec3, rng: &mut Rng) -> Vec<(Lobe, f32)> {
        let Some(r) = self.rough else {
            let f = fresnel_dielectric(wi.dot(ns), self.eta);
            return vec![((reflect(wi, ns), self.specular * f), 1.0)];
        };
        let (o1, o2) = (rng.f32(), rng.f32());
        let n = LOBE_GRID;
        let coarse = (n * n) as f32 / n.div_ceil(2).pow(2) as f32;
        let mut out = Vec::with_capacity(n * n);
        for k in 0..n * n {
            let u1 = ((k / n) as f32 + o1) / n as f32;
            let u2 = ((k % n) as f32 + o2) / n as f32;
            if let Some((wo, w)) = rough_sample(wi, ns, r, self.eta, (u1, u2)) {
                let on = (k / n) % 2 == 0 && (k % n) % 2 == 0;
                let sub = if on { coarse } else { 0.0 };
                out.push(((wo, self.specular * (w / (n * n) as f32)), sub));
            }
        }
        out
    }
}

impl Coat {
    /// A rough coat's reflection `f cos_o` from direction `wo` towards `wi` (unit, both on
    /// the side of unit normal `ns`): `specular F D G / (4 cos_i)`, Mitsuba's `roughplastic`
    /// specular term; zero for a smooth coat (its reflection is a delta).
    pub fn glossy(&self, wi: Vec3, wo: Vec3, ns: Vec3) -> Rgb {
        let Some(r) = self.rough else {
            return Rgb::ZERO;
        };
        let (ci, co) = (wi.dot(ns), wo.dot(ns));
        if ci <= 0.0 || co <= 0.0 {
            return Rgb::ZERO;
        }
        let h = (wi + wo).normalize_or_zero();
        let d = normal_density(h.dot(ns), r);
        let g = smith_g1(wi, ns, r) * smith_g1(wo, ns, r);
        let f = fresnel_dielectric(wi.dot(h), self.eta);
        self.specular * (f * d * g / (4.0 * ci))
    }
}

/// The microfacet distribution `D(m)` at `cos = m.n` (Beckmann or GGX, Mitsuba's forms).
fn normal_density(cos: f32, r: Rough) -> f32 {
    if cos <= 0.0 {
        return 0.0;
    }
    let (a2, c2) = (r.alpha * r.alpha, cos * cos);
    let tan2 = (1.0 - c2) / c2;
    match r.ggx {
        true => a2 / (std::f32::consts::PI * c2 * c2 * (a2 + tan2).powi(2)),
        false => (-tan2 / a2).exp() / (std::f32::consts::PI * a2 * c2 * c2),
    }
}

impl Coat {
    /// One path's step at the coat, for a path arriving along unit `d` at a point of unit
    /// normal `ns` (on the arrival side) and uniform `u`: `Ok((dir, weight))` reflected by the
    /// coat (probability `1 - t(cos)`), else `Err(weight)`: it sees the base, whose radiance
    /// (as a Lambertian surface under `E'`) it carries times `weight = T_o / t(cos)`. Each
    /// branch's weight is divided by its probability, so the mean is the coat's radiance.
    pub fn step(&self, d: Vec3, ns: Vec3, u: f32, rng: &mut Rng) -> Result<Lobe, Rgb> {
        let wi = -d;
        let cos = wi.dot(ns);
        let t = self.transmittance(cos);
        if u >= 1.0 - t {
            return Err(Rgb::splat(self.base_out(cos) / t.max(1e-6)));
        }
        let p = (1.0 - t).max(1e-6);
        match self.rough {
            None => Ok((
                reflect(wi, ns),
                self.specular * (fresnel_dielectric(cos, self.eta) / p),
            )),
            Some(r) => rough_sample(wi, ns, r, self.eta, (rng.f32(), rng.f32()))
                .map(|(dir, w)| (dir, self.specular * (w / p)))
                .ok_or(Rgb::ZERO),
        }
    }
}

/// One rough-reflection sample: the direction and its weight `F G |wi.m| / (|wi.n| |m.n|)`.
fn rough_sample(wi: Vec3, ns: Vec3, r: Rough, eta: f32, (u1, u2): (f32, f32)) -> Option<Lobe1> {
    let m = microfacet_normal_at(ns, r, u1, u2);
    let c = wi.dot(m);
    let wo = reflect(wi, m);
    if c <= 0.0 || wo.dot(ns) <= 0.0 {
        return None;
    }
    Some((
        wo,
        fresnel_dielectric(c, eta) * shadowing(wi, wo, ns, m, Some(r)),
    ))
}

type Lobe1 = (Vec3, f32);

/// The mean of `f(wi, u)` (0 where `None`) over a stratified `ALBEDO_GRID`-squared grid of
/// points `u` in the unit square, `wi` the direction at cosine `mu` (in the x-z plane).
fn grid_mean(mu: f32, f: impl Fn(Vec3, (f32, f32)) -> Option<f32>) -> f32 {
    let mu = mu.max(1e-6);
    let wi = Vec3::new((1.0 - mu * mu).max(0.0).sqrt(), 0.0, mu);
    let n = ALBEDO_GRID;
    let sum: f32 = (0..n * n)
        .filter_map(|k| {
            let u = (
                ((k / n) as f32 + 0.5) / n as f32,
                ((k % n) as f32 + 0.5) / n as f32,
            );
            f(wi, u)
        })
        .sum();
    sum / (n * n) as f32
}

/// The directional albedo of a rough dielectric reflection of relative index `eta` at
/// cosine `mu` (a stratified grid of microfacet normals).
fn rough_albedo(mu: f32, eta: f32, r: Rough) -> f32 {
    grid_mean(mu, |wi, u| {
        rough_sample(wi, Vec3::Z, r, eta, u).map(|s| s.1)
    })
}

/// The directional transmittance of a rough dielectric interface of relative index `eta` at
/// cosine `mu`: the light refracted through it that its microfacets do not shadow, Mitsuba's
/// `eval_transmittance` (`(1 - F) G1(w_t)` over the visible normals), on the same grid.
fn rough_transmittance(mu: f32, eta: f32, r: Rough) -> f32 {
    grid_mean(mu, |wi, u| {
        let m = microfacet_normal_at(Vec3::Z, r, u.0, u.1);
        let c = wi.dot(m);
        let wt = refract(wi, m, eta).filter(|w| w.z < 0.0)?;
        // the visible normals' weight of a normal drawn from `D(m) (m.n)`
        let visible = smith_g1(wi, Vec3::Z, r) * c.max(0.0) / (wi.z * m.z);
        Some(visible * (1.0 - fresnel_dielectric(c, eta)) * smith_g1(wt, Vec3::Z, r))
    })
}

/// Mitsuba's rough tables: `t(mu_i)` ([`rough_transmittance`]) and
/// `R_int = 2 mean(mu R(mu, 1/eta))`.
fn rough_tables(eta: f32, r: Rough) -> (Vec<f32>, f32) {
    let mus: Vec<f32> = (0..RES).map(|i| i as f32 / (RES - 1) as f32).collect();
    let table = mus
        .iter()
        .map(|&mu| rough_transmittance(mu, eta, r))
        .collect();
    let inside: f32 = mus
        .iter()
        .map(|&mu| mu.max(1e-6) * rough_albedo(mu, 1.0 / eta, r))
        .sum();
    (table, 2.0 * inside / RES as f32)
}

/// `2 integral_0^1 f(mu) mu dmu` by the midpoint rule.
fn hemisphere_mean(f: impl Fn(f32) -> f32) -> f32 {
    const N: usize = 256;
    (0..N)
        .map(|i| {
            let mu = (i as f32 + 0.5) / N as f32;
            f(mu) * 2.0 * mu / N as f32
        })
        .sum()
}

/// A point of an area emitter: position, unit normal (its emitting side), area it stands for.
pub type Patch = (Vec3, Vec3, f32);

/// Barycentric centres of the 16 triangles of a triangle cut in four twice.
fn sixteen() -> Vec<(f32, f32)> {
    let mut out = Vec::with_capacity(16);
    for i in 0..4 {
        for j in 0..4 - i {
            out.push(((i as f32 + 1.0 / 3.0) / 4.0, (j as f32 + 1.0 / 3.0) / 4.0));
            if i + j < 3 {
                out.push(((i as f32 + 2.0 / 3.0) / 4.0, (j as f32 + 2.0 / 3.0) / 4.0));
            }
        }
    }
    out
}

/// An area emitter's points for the coat's integrals over it: 16 per triangle for emitters
/// of at most 16 triangles, else one per triangle (its centre); none for the other kinds.
pub fn patches(scene: &Scene, e: &Emitter) -> Vec<Patch> {
    let Emitter::Area { shape, .. } = e else {
        return Vec::new();
    };
    let mesh = &scene.shapes[*shape].mesh;
    let pattern = match mesh.triangles.len() <= 16 {
        true => sixteen(),
        false => vec![(1.0 / 3.0, 1.0 / 3.0)],
    };
    let mut out = Vec::new();
    for t in 0..mesh.triangles.len() {
        let [a, b, c] = mesh.triangle(t);
        let n = mesh.face_normal_raw(t).normalize_or_zero();
        let area = mesh.triangle_area(t) / pattern.len() as f32;
        for &(b1, b2) in &pattern {
            out.push((a + (b - a) * b1 + (c - a) * b2, n, area));
        }
    }
    out
}

/// Every shape's coat, by shape index: `Some` for a coated shape whose base is reconstructed.
pub fn coats(scene: &Scene) -> Vec<Option<Coat>> {
    scene
        .shapes
        .iter()
        .map(|s| s.coated().and_then(|k| Coat::of(&k.bsdf)))
        .collect()
}

/// Whether the scene has a coated shape at all (the coat's passes are skipped otherwise).
pub fn any(coats: &[Option<Coat>]) -> bool {
    coats.iter().any(Option::is_some)
}

#[cfg(test)]
mod tests;
