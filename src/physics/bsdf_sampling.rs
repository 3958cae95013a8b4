//! Sampling a known material: given the direction a ray or photon arrives along, one
//! outgoing direction and the weight `f cos / pdf` it carries. Photons, gather rays and the
//! re-renders all continue their paths through mirrors and glass with this one function.
//!
//! Written by hand: the transport needs only importance sampling of a handful of Mitsuba's
//! lobes (no crate offers Mitsuba's parametrisation), and the physics is tested against
//! closed forms here. Approximations (documented in docs/guide.md, "Known materials"): the
//! radiance scaling by `eta^2` across a refraction is left out (it cancels for light that
//! enters and leaves a closed object); microfacet lobes sample the distribution of normals
//! `D(m) (m.n)` with the Smith shadowing of that distribution; `plastic` is Mitsuba's
//! smooth-coat model (`roughplastic` uses the rough lobe for its coat's reflection).

use crate::base::rng::Rng;
use crate::scene::material::{fresnel_conductor, fresnel_dielectric, KnownBsdf, Rough};
use crate::scene::Rgb;
use glam::Vec3;
use std::f32::consts::TAU;

/// Most known-material bounces a gather or re-render ray follows before it gives up
/// (mirror-in-glass chains beyond this add too little to pay).
pub const MAX_SPECULAR: u32 = 8;

/// One sampled continuation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scatter {
    /// Unit outgoing direction.
    pub dir: Vec3,
    /// Throughput factor `f cos / pdf` (per channel).
    pub weight: Rgb,
}

/// Samples `b` for a path arriving along unit `d` at a point with unit shading normal `n`
/// (not oriented: the side is taken from `d`). `None` when the path is absorbed (or sampled
/// a direction below the surface).
pub fn sample(b: &KnownBsdf, d: Vec3, n: Vec3, rng: &mut Rng) -> Option<Scatter> {
    let wi = -d;
    let cos_i = wi.dot(n);
    if cos_i == 0.0 || !cos_i.is_finite() {
        return None;
    }
    // normal on the arrival side
    let ns = if cos_i > 0.0 { n } else { -n };
    let u = rng.f32();
    match b {
        KnownBsdf::Diffuse(rho) => Some(Scatter {
            dir: cosine_dir(ns, rng),
            weight: *rho,
        }),
        KnownBsdf::Conductor {
            eta,
            k,
            tint,
            rough,
        } => {
            let (dir, m) = reflection(wi, ns, *rough, rng)?;
            let f = fresnel_conductor(wi.dot(m), *eta, *k);
            Some(Scatter {
                dir,
                weight: *tint * f * shadowing(wi, dir, ns, m, *rough),
            })
        }
        KnownBsdf::Dielectric {
            eta,
            reflect,
            transmit,
            rough,
            thin,
        } => dielectric(
            wi,
            n,
            ns,
            (*eta, *reflect, *transmit, *rough, *thin),
            u,
            rng,
        ),
        KnownBsdf::Plastic {
            eta,
            diffuse,
            specular,
            rough,
            nonlinear,
            fdr_int,
        } => plastic(
            wi,
            ns,
            (*eta, *diffuse, *specular, *rough, *nonlinear, *fdr_int),
            u,
            rng,
        ),
        KnownBsdf::Blend { weight, a, b } => sample(if u < *weight { b } else { a }, d, n, rng),
        KnownBsdf::Mask { opacity, inner } if u < *opacity => sample(inner, d, n, rng),
        KnownBsdf::Mask { .. } | KnownBsdf::Null => Some(Scatter {
            dir: d,
            weight: Vec3::ONE,
        }),
    }
}

/// Mirror reflection about `ns` (smooth) or about a sampled microfacet normal: the
/// direction and the normal it reflected about.
fn reflection(wi: Vec3, ns: Vec3, rough: Option<Rough>, rng: &mut Rng) -> Option<(Vec3, Vec3)> {
    let m = match rough {
        Some(r) => microfacet_normal(ns, r, rng),
        None => ns,
    };
    let dir = reflect(wi, m);
    (dir.dot(ns) > 0.0 && wi.dot(m) > 0.0).then_some((dir, m))
}

/// The microfacet sampling weight `G |wi.m| / (|wi.n| |m.n|)` (1 for a smooth surface).
pub fn shadowing(wi: Vec3, wo: Vec3, ns: Vec3, m: Vec3, rough: Option<Rough>) -> f32 {
    let Some(r) = rough else {
        return 1.0;
    };
    let g = smith_g1(wi, ns, r) * smith_g1(wo, ns, r);
    (g * wi.dot(m).abs() / (wi.dot(ns).abs() * m.dot(ns).abs())).max(0.0)
}

#[allow(clippy::type_complexity)]
fn dielectric(
    wi: Vec3,
    n: Vec3,
    ns: Vec3,
    (eta, reflect_tint, transmit, rough, thin): (f32, Rgb, Rgb, Option<Rough>, bool),
    u: f32,
    rng: &mut Rng,
) -> Option<Scatter> {
    if thin {
        let r = fresnel_dielectric(wi.dot(ns), eta);
        let r2 = if r < 1.0 { 2.0 * r / (1.0 + r) } else { 1.0 };
        return Some(match u < r2 {
            true => Scatter {
                dir: reflect(wi, ns),
                weight: reflect_tint,
            },
            false => Scatter {
                dir: -wi,
                weight: transmit,
            },
        });
    }
    let m = match rough {
        Some(r) => microfacet_normal(ns, r, rng),
        None => ns,
    };
    let cos_m = wi.dot(m);
    if cos_m <= 0.0 {
        return None;
    }
    // relative index across the interface, seen from the arrival side
    let eta_rel = if wi.dot(n) > 0.0 { eta } else { 1.0 / eta };
    let f = fresnel_dielectric(cos_m, eta_rel);
    let (dir, tint) = match u < f {
        true => (reflect(wi, m), reflect_tint),
        false => (refract(wi, m, eta_rel)?, transmit),
    };
    // a reflection must stay on the arrival side, a refraction cross
    let reflected = u < f;
    if (dir.dot(ns) > 0.0) != reflected {
        return None;
    }
    let g = match rough {
        Some(r) => {
            let g = smith_g1(wi, ns, r) * smith_g1(dir, ns, r);
            g * cos_m / (wi.dot(ns) * m.dot(ns))
        }
        None => 1.0,
    };
    Some(Scatter {
        dir,
        weight: tint * g.max(0.0),
    })
}

#[allow(clippy::type_complexity)]
fn plastic(
    wi: Vec3,
    ns: Vec3,
    (eta, diffuse, specular, rough, nonlinear, fdr): (f32, Rgb, Rgb, Option<Rough>, bool, f32),
    u: f32,
    rng: &mut Rng,
) -> Option<Scatter> {
    let fi = fresnel_dielectric(wi.dot(ns), eta);
    if u < fi {
        let (dir, m) = reflection(wi, ns, rough, rng)?;
        return Some(Scatter {
            dir,
            weight: specular * shadowing(wi, dir, ns, m, rough),
        });
    }
    let dir = cosine_dir(ns, rng);
    let fo = fresnel_dielectric(dir.dot(ns), eta);
    let base = match nonlinear {
        true => diffuse / (Vec3::ONE - diffuse * fdr),
        false => diffuse / (1.0 - fdr),
    };
    Some(Scatter {
        dir,
        weight: base * ((1.0 - fo) / (eta * eta)),
    })
}

/// `wi` mirrored about unit `m`.
#[inline]
pub fn reflect(wi: Vec3, m: Vec3) -> Vec3 {
    2.0 * wi.dot(m) * m - wi
}

/// `wi` (on `m`'s side) refracted through an interface of relative index `eta`
/// (transmitted side over arrival side); `None` under total internal reflection.
#[inline]
pub fn refract(wi: Vec3, m: Vec3, eta: f32) -> Option<Vec3> {
    let c = wi.dot(m);
    let s2 = (1.0 - c * c).max(0.0) / (eta * eta);
    if s2 >= 1.0 {
        return None;
    }
    let ct = (1.0 - s2).sqrt();
    Some((-wi / eta + m * (c / eta - ct)).normalize())
}

/// A microfacet normal about `n` with density `D(m) (m.n)`.
fn microfacet_normal(n: Vec3, r: Rough, rng: &mut Rng) -> Vec3 {
    let (u1, u2) = (rng.f32(), rng.f32());
    microfacet_normal_at(n, r, u1, u2)
}

/// The microfacet normal of [`microfacet_normal`] for the uniform pair `(u1, u2)`.
pub fn microfacet_normal_at(n: Vec3, r: Rough, u1: f32, u2: f32) -> Vec3 {
    let a2 = r.alpha * r.alpha;
    let tan2 = match r.ggx {
        true => a2 * u1 / (1.0 - u1).max(1e-7),
        false => -a2 * (1.0 - u1).max(1e-7).ln(),
    };
    let cos = 1.0 / (1.0 + tan2).sqrt();
    let sin = (1.0 - cos * cos).max(0.0).sqrt();
    let phi = TAU * u2;
    let (t, b) = n.any_orthonormal_pair();
    (t * (sin * phi.cos()) + b * (sin * phi.sin()) + n * cos).normalize()
}

/// Smith's masking term of one direction `v` for roughness `r` about `n`.
pub fn smith_g1(v: Vec3, n: Vec3, r: Rough) -> f32 {
    let c = v.dot(n).abs().min(1.0);
    if c >= 1.0 {
        return 1.0;
    }
    let tan = (1.0 - c * c).sqrt() / c;
    match r.ggx {
        true => 2.0 / (1.0 + (1.0 + (r.alpha * tan).powi(2)).sqrt()),
        false => {
            let a = 1.0 / (r.alpha * tan);
            if a >= 1.6 {
                1.0
            } else {
                (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a)
            }
        }
    }
}

/// A cosine-weighted unit direction about unit `n` (Malley's method).
pub fn cosine_dir(n: Vec3, rng: &mut Rng) -> Vec3 {
    let r2 = rng.f32();
    let phi = TAU * rng.f32();
    let r = r2.sqrt();
    let (u, v) = n.any_orthonormal_pair();
    (u * (r * phi.cos()) + v * (r * phi.sin()) + n * (1.0 - r2).max(0.0).sqrt()).normalize()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rng(i: u64) -> Rng {
        Rng::new(7, 0, 0, i)
    }

    fn glass(rough: Option<Rough>, thin: bool) -> KnownBsdf {
        KnownBsdf::Dielectric {
            eta: 1.5,
            reflect: Vec3::ONE,
            transmit: Vec3::ONE,
            rough,
            thin,
        }
    }

    /// A smooth mirror reflects about the normal with the conductor's Fresnel factor.
    #[test]
    fn mirror_reflects_with_fresnel() {
        let n = Vec3::Z;
        let d = Vec3::new(0.6, 0.0, -0.8);
        let (eta, k) = (Vec3::splat(0.2), Vec3::splat(3.9));
        let b = KnownBsdf::Conductor {
            eta,
            k,
            tint: Vec3::new(1.0, 0.5, 0.25),
            rough: None,
        };
        let s = sample(&b, d, n, &mut rng(0)).unwrap();
        assert!((s.dir - Vec3::new(0.6, 0.0, 0.8)).length() < 1e-6);
        let f = fresnel_conductor(0.8, eta, k);
        assert!((s.weight - f * Vec3::new(1.0, 0.5, 0.25)).length() < 1e-6);
        // hit from behind: the normal is flipped to the arrival side (a one-sided surface's
        // back is the caller's business)
        let s = sample(&b, -d, n, &mut rng(0)).unwrap();
        assert!((s.dir - Vec3::new(-0.6, 0.0, -0.8)).length() < 1e-6);
    }

    /// Smooth glass: the fraction reflected is Fresnel's, the refracted direction obeys
    /// Snell's law both ways, and a path through a slab leaves parallel to how it came in.
    #[test]
    fn glass_splits_by_fresnel_and_refracts_by_snell() {
        let n = Vec3::Z;
        let d = Vec3::new(0.6, 0.0, -0.8);
        let want = fresnel_dielectric(0.8, 1.5);
        let trials = 20000;
        let mut reflected = 0;
        for i in 0..trials {
            let s = sample(&glass(None, false), d, n, &mut rng(i)).unwrap();
            if s.dir.z > 0.0 {
                reflected += 1;
            } else {
                // sin_t = sin_i / 1.5
                assert!((s.dir.x - 0.6 / 1.5).abs() < 1e-5, "{:?}", s.dir);
                // leaving through the parallel face from inside restores the direction
                let back = refract(-s.dir, n, 1.0 / 1.5).unwrap();
                assert!((back - d).length() < 1e-5);
            }
        }
        let frac = reflected as f32 / trials as f32;
        let sigma = (want * (1.0 - want) / trials as f32).sqrt();
        assert!((frac - want).abs() < 4.0 * sigma, "{frac} vs {want}");
        // beyond the critical angle from inside: always reflected
        let d_in = Vec3::new(0.8, 0.0, 0.6); // inside, going up at 53 deg > 41.8
        for i in 0..100 {
            let s = sample(&glass(None, false), d_in, n, &mut rng(i)).unwrap();
            assert!(s.dir.z < 0.0);
        }
    }

    /// A thin sheet reflects `2R / (1 + R)` and passes the rest straight on.
    #[test]
    fn thin_sheet_reflects_the_closed_form() {
        let d = Vec3::new(0.0, 0.6, -0.8);
        let r = fresnel_dielectric(0.8, 1.5);
        let want = 2.0 * r / (1.0 + r);
        let trials = 20000;
        let mut refl = 0;
        for i in 0..trials {
            let s = sample(&glass(None, true), d, Vec3::Z, &mut rng(i)).unwrap();
            match s.dir.z > 0.0 {
                true => refl += 1,
                false => assert!((s.dir - d).length() < 1e-6),
            }
        }
        let frac = refl as f32 / trials as f32;
        assert!(
            (frac - want).abs() < 4.0 * (want / trials as f32).sqrt(),
            "{frac} {want}"
        );
    }

    /// Energy: a rough mirror of the ideal conductor (F = 1) reflects at most what arrives,
    /// and nearly all of it at normal incidence for small roughness (both distributions);
    /// a lossless rough glass neither creates energy.
    #[test]
    fn rough_lobes_conserve_energy() {
        for ggx in [false, true] {
            for alpha in [0.05f32, 0.3] {
                let r = Some(Rough { alpha, ggx });
                let mirror = KnownBsdf::Conductor {
                    eta: Vec3::ZERO,
                    k: Vec3::ONE,
                    tint: Vec3::ONE,
                    rough: r,
                };
                for (b, floor) in [(mirror, 0.85f32), (glass(r, false), 0.8)] {
                    let d = Vec3::new(0.0, 0.0, -1.0);
                    let n = 20000;
                    let e: f32 = (0..n)
                        .filter_map(|i| sample(&b, d, Vec3::Z, &mut rng(i)))
                        .map(|s| s.weight.x)
                        .sum::<f32>()
                        / n as f32;
                    assert!(e <= 1.02 && e >= floor, "ggx {ggx} alpha {alpha}: {e}");
                }
            }
        }
    }

    /// Mitsuba's smooth plastic: coat reflection with probability F, and a diffuse part whose
    /// mean weight follows its closed form, so a white base with the linear model returns
    /// `(1 - F_o) / (eta^2 (1 - F_dr))` on average over cosine directions.
    #[test]
    fn plastic_splits_coat_and_base() {
        let b = KnownBsdf::plastic(1.5, Vec3::splat(0.5), Vec3::ONE, None, false);
        let d = Vec3::new(0.0, 0.0, -1.0);
        let f0 = fresnel_dielectric(1.0, 1.5);
        let fdr = crate::scene::material::diffuse_fresnel_inside(1.5);
        let n = 40000;
        let (mut spec, mut diff_w, mut diff_n) = (0, 0.0f64, 0);
        for i in 0..n {
            let s = sample(&b, d, Vec3::Z, &mut rng(i)).unwrap();
            if (s.dir - Vec3::Z).length() < 1e-6 {
                spec += 1;
            } else {
                let fo = fresnel_dielectric(s.dir.z, 1.5);
                let want = 0.5 * (1.0 - fo) / (2.25 * (1.0 - fdr));
                assert!((s.weight.x - want).abs() < 1e-5);
                diff_w += s.weight.x as f64;
                diff_n += 1;
            }
        }
        let frac = spec as f32 / n as f32;
        assert!(
            (frac - f0).abs() < 4.0 * (f0 / n as f32).sqrt(),
            "{frac} {f0}"
        );
        assert!(diff_n > 0 && diff_w > 0.0);
    }

    #[test]
    fn blend_mask_and_null() {
        let black = KnownBsdf::Diffuse(Vec3::ZERO);
        let white = KnownBsdf::Diffuse(Vec3::ONE);
        let b = KnownBsdf::Blend {
            weight: 0.25,
            a: Box::new(black.clone()),
            b: Box::new(white),
        };
        let d = Vec3::new(0.0, 0.0, -1.0);
        let n = 20000;
        let mean: f32 = (0..n)
            .map(|i| sample(&b, d, Vec3::Z, &mut rng(i)).unwrap().weight.x)
            .sum::<f32>()
            / n as f32;
        assert!((mean - 0.25).abs() < 0.015, "{mean}");
        let m = KnownBsdf::Mask {
            opacity: 0.3,
            inner: Box::new(black),
        };
        let through = (0..n)
            .filter(|&i| sample(&m, d, Vec3::Z, &mut rng(i)).unwrap().dir == d)
            .count() as f32
            / n as f32;
        assert!((through - 0.7).abs() < 0.015, "{through}");
        let s = sample(&KnownBsdf::Null, d, Vec3::Z, &mut rng(0)).unwrap();
        assert_eq!((s.dir, s.weight), (d, Vec3::ONE));
    }
}
