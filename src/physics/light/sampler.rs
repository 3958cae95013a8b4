//! Photon emission for the light tracer: pick an emitter in proportion to its power, then a
//! ray leaving it, with a flux weight chosen so the expected flux of one sample equals the
//! scene's total emitted power per channel (`sum of emitter_power`).
//!
//! Per type: point, uniform over the sphere; spot, uniform within the cutoff cone, weighted by
//! the falloff; directional, uniform over a disk of the scene's bounding-sphere radius `R`
//! perpendicular to the light, placed just outside that sphere (so the power is `E pi R^2`, as
//! in [`super::emitter_power`]); area, a triangle by area, a uniform point on it and a
//! cosine-weighted direction about its shading normal (Mitsuba's emitting side); environment,
//! as Mitsuba's `envmap` does: a direction `w` from the map by luminance
//! ([`crate::scene::EnvMap::sample`]), the photon travelling along `-w` from a uniform point of
//! a disk of radius `R` perpendicular to it, just outside the bounding sphere, with flux
//! `L(w) pi R^2 / p(w)` (expected: `pi R^2 int L dw`, the power of [`super::emitter_power`]).

use super::{bounding_sphere, emitter_power, spot_falloff};
use crate::base::rng::Rng;
use crate::physics::accel::offset_origin;
use crate::scene::{luminance, Emitter, EnvMap, Scene};
use glam::Vec3;
use std::f32::consts::PI;
use std::sync::Arc;

/// One emitter triangle, copied out of the scene so the sampler owns its data.
#[derive(Debug, Clone)]
struct EmitTri {
    p: [Vec3; 3],
    /// Vertex shading normals, if the mesh has them.
    n: Option<[Vec3; 3]>,
    /// Unit geometric normal.
    ng: Vec3,
}

#[derive(Debug, Clone)]
enum Kind {
    Point {
        position: Vec3,
    },
    Spot {
        position: Vec3,
        /// Orthonormal frame with `w` = axis.
        frame: [Vec3; 3],
        intensity: Vec3,
        cutoff: f32,
        beam_width: f32,
        /// `1 - cos(cutoff)`, and the cone's solid angle `2 pi (1 - cos(cutoff))`.
        one_minus_cos: f32,
        cone: f32,
    },
    Directional {
        direction: Vec3,
        frame: [Vec3; 2],
        center: Vec3,
        radius: f32,
    },
    Area {
        tris: Vec<EmitTri>,
        /// Cumulative triangle areas, normalized (last = 1).
        cdf: Vec<f64>,
    },
    Environment {
        env: Arc<EnvMap>,
        center: Vec3,
        radius: f32,
    },
}

impl Kind {
    /// How to sample emitter `e` (`sphere`: the scene's bounding sphere), `None` if it cannot
    /// emit (a zero axis or direction, an area emitter without area).
    fn of(scene: &Scene, e: &Emitter, (center, radius): (Vec3, f32)) -> Option<Kind> {
        Some(match *e {
            Emitter::Point { position, .. } => Kind::Point { position },
            Emitter::Spot {
                position,
                axis,
                intensity,
                cutoff,
                beam_width,
                ..
            } => {
                let w = axis.try_normalize()?;
                let (u, v) = w.any_orthonormal_pair();
                let c = cutoff.clamp(0.0, PI);
                let s = (0.5 * c).sin();
                let one_minus_cos = 2.0 * s * s;
                Kind::Spot {
                    position,
                    frame: [u, v, w],
                    intensity,
                    cutoff,
                    beam_width,
                    one_minus_cos,
                    cone: 2.0 * PI * one_minus_cos,
                }
            }
            Emitter::Directional { direction, .. } => {
                let d = direction.try_normalize()?;
                let (u, v) = d.any_orthonormal_pair();
                Kind::Directional {
                    direction: d,
                    frame: [u, v],
                    center,
                    radius,
                }
            }
            Emitter::Area { shape, .. } => Kind::area(&scene.shapes.get(shape)?.mesh)?,
            Emitter::Environment(ref env) if !env.is_dark() && radius > 0.0 => Kind::Environment {
                env: env.clone(),
                center,
                radius,
            },
            Emitter::Environment(_) => return None,
        })
    }

    /// An area emitter's triangles with positive area and their area CDF.
    fn area(m: &crate::scene::Mesh) -> Option<Kind> {
        let mut tris = Vec::with_capacity(m.triangles.len());
        let mut cdf = Vec::with_capacity(m.triangles.len());
        let mut acc = 0.0f64;
        for t in 0..m.triangles.len() {
            let a = m.triangle_area(t) as f64;
            if !(a.is_finite() && a > 0.0) {
                continue;
            }
            acc += a;
            cdf.push(acc);
            let [i, j, l] = m.triangles[t];
            let n = m.normals.as_ref().and_then(|ns| {
                Some([
                    *ns.get(i as usize)?,
                    *ns.get(j as usize)?,
                    *ns.get(l as usize)?,
                ])
            });
            tris.push(EmitTri {
                p: m.triangle(t),
                n,
                ng: m.face_normal_raw(t).normalize(),
            });
        }
        if tris.is_empty() {
            return None;
        }
        cdf.iter_mut().for_each(|c| *c /= acc);
        Some(Kind::Area { tris, cdf })
    }
}

#[derive(Debug, Clone)]
struct Source {
    emitter: usize,
    /// Selection probability.
    prob: f64,
    power: Vec3,
    kind: Kind,
}

/// Samples photon rays from all emitters of a scene; immutable and `Sync` (share it across
/// threads, give each photon its own [`Rng`] key).
#[derive(Debug, Clone)]
pub struct EmitterSampler {
    sources: Vec<Source>,
    /// Cumulative selection probabilities (last = 1).
    cdf: Vec<f64>,
    total_power: Vec3,
}

/// A photon leaving a light: start point (already offset off an area emitter's surface),
/// unit direction, flux weight (per channel), and the index of its emitter in `Scene::emitters`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EmittedPhoton {
    pub origin: Vec3,
    pub dir: Vec3,
    pub flux: Vec3,
    pub emitter: usize,
}

impl EmitterSampler {
    /// Emitters are chosen with probability proportional to the luminance of their power
    /// (`crate::scene::luminance`); those with no positive power luminance are never chosen.
    pub fn new(scene: &Scene) -> EmitterSampler {
        let (center, radius) = bounding_sphere(scene);
        let mut sources = Vec::new();
        let mut total_power = Vec3::ZERO;
        for (k, e) in scene.emitters.iter().enumerate() {
            let power = emitter_power(scene, e);
            let y = luminance(power);
            if !(y.is_finite() && y > 0.0) {
                continue;
            }
            let Some(kind) = Kind::of(scene, e, (center, radius)) else {
                continue;
            };
            total_power += power;
            sources.push(Source {
                emitter: k,
                prob: y as f64,
                power,
                kind,
            });
        }
        let sum: f64 = sources.iter().map(|s| s.prob).sum();
        let mut cdf = Vec::with_capacity(sources.len());
        let mut acc = 0.0;
        for s in &mut sources {
            s.prob /= sum;
            acc += s.prob;
            cdf.push(acc);
        }
        if let Some(last) = cdf.last_mut() {
            *last = 1.0;
        }
        EmitterSampler {
            sources,
            cdf,
            total_power,
        }
    }

    /// The total power of the emitters that can be sampled (the expected flux of a sample).
    pub fn total_power(&self) -> Vec3 {
        self.total_power
    }

    /// Whether there is any light to sample.
    pub fn is_empty(&self) -> bool {
        self.sources.is_empty()
    }

    /// The probability that a sample comes from emitter `k` (index into `Scene::emitters`).
    pub fn probability(&self, k: usize) -> f64 {
        self.sources
            .iter()
            .find(|s| s.emitter == k)
            .map_or(0.0, |s| s.prob)
    }

    /// One photon ray `(origin, unit direction, flux)`. The expected flux equals
    /// [`Self::total_power`] per channel. A scene without light gives zero flux.
    pub fn sample(&self, rng: &mut Rng) -> (Vec3, Vec3, Vec3) {
        match self.sample_photon(rng) {
            Some(ph) => (ph.origin, ph.dir, ph.flux),
            None => (Vec3::ZERO, Vec3::Z, Vec3::ZERO),
        }
    }

    /// Like [`Self::sample`], with the emitter's index; `None` if the scene has no light.
    /// Draws at most 6 random numbers from `rng`.
    pub fn sample_photon(&self, rng: &mut Rng) -> Option<EmittedPhoton> {
        let u = rng.f64();
        let i = self
            .cdf
            .partition_point(|&c| c <= u)
            .min(self.cdf.len().checked_sub(1)?);
        let s = &self.sources[i];
        let inv_prob = (1.0 / s.prob) as f32;
        let (origin, dir, flux) = match &s.kind {
            Kind::Point { position } => {
                let z = 1.0 - 2.0 * rng.f32();
                let r = (1.0 - z * z).max(0.0).sqrt();
                let phi = 2.0 * PI * rng.f32();
                let d = Vec3::new(r * phi.cos(), r * phi.sin(), z);
                (*position, d, s.power * inv_prob)
            }
            Kind::Spot {
                position,
                frame,
                intensity,
                cutoff,
                beam_width,
                one_minus_cos,
                cone,
            } => {
                // Uniform in the cone: 1 - cos(theta) uniform in [0, 1 - cos(cutoff)].
                let omc = rng.f32() * one_minus_cos;
                let cos_t = 1.0 - omc;
                let sin_t = (omc * (2.0 - omc)).max(0.0).sqrt();
                let phi = 2.0 * PI * rng.f32();
                let d = frame[0] * (sin_t * phi.cos())
                    + frame[1] * (sin_t * phi.sin())
                    + frame[2] * cos_t;
                let theta = sin_t.atan2(cos_t);
                let f = spot_falloff(theta, *cutoff, *beam_width);
                (*position, d.normalize(), *intensity * (f * cone * inv_prob))
            }
            Kind::Directional {
                direction,
                frame,
                center,
                radius,
            } => {
                let r = radius * rng.f32().sqrt();
                let phi = 2.0 * PI * rng.f32();
                let back = radius * 1.001 + 1e-4 * center.abs().max_element().max(1.0);
                let o = *center - *direction * back
                    + frame[0] * (r * phi.cos())
                    + frame[1] * (r * phi.sin());
                (o, *direction, s.power * inv_prob)
            }
            Kind::Area { tris, cdf } => {
                let ut = rng.f64();
                let t = &tris[cdf.partition_point(|&c| c <= ut).min(tris.len() - 1)];
                let su = rng.f32().sqrt();
                let u2 = rng.f32();
                let (b1, b2) = (su * (1.0 - u2), su * u2);
                let b0 = 1.0 - b1 - b2;
                let y = t.p[0] * b0 + t.p[1] * b1 + t.p[2] * b2;
                let ns =
                    t.n.map(|n| (n[0] * b0 + n[1] * b1 + n[2] * b2).normalize_or_zero())
                        .filter(|n| *n != Vec3::ZERO)
                        .unwrap_or(t.ng);
                // Cosine-weighted about the shading normal (Malley's method).
                let r2 = rng.f32();
                let phi = 2.0 * PI * rng.f32();
                let r = r2.sqrt();
                let (u, v) = ns.any_orthonormal_pair();
                let d =
                    (u * (r * phi.cos()) + v * (r * phi.sin()) + ns * (1.0 - r2).max(0.0).sqrt())
                        .normalize();
                (offset_origin(y, t.ng, d), d, s.power * inv_prob)
            }
            Kind::Environment {
                env,
                center,
                radius,
            } => {
                let (w, pdf) = env.sample(rng.f64(), rng.f32(), rng.f32())?;
                let d = -w;
                let r = radius * rng.f32().sqrt();
                let phi = 2.0 * PI * rng.f32();
                let (u, v) = d.any_orthonormal_pair();
                let back = radius * 1.001 + 1e-4 * center.abs().max_element().max(1.0);
                let o = *center - d * back + u * (r * phi.cos()) + v * (r * phi.sin());
                let flux = env.eval(w) * (PI * radius * radius / pdf) * inv_prob;
                (o, d, flux)
            }
        };
        Some(EmittedPhoton {
            origin,
            dir,
            flux,
            emitter: s.emitter,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::light::tests::{floor, quad, scene, shape};
    use crate::scene::EnvMap;

    /// Mean and standard error per channel of `f` over `n` samples keyed by index.
    fn stats(n: u64, mut f: impl FnMut(&mut Rng) -> Vec3) -> (Vec3, Vec3) {
        let (mut s, mut s2) = (glam::DVec3::ZERO, glam::DVec3::ZERO);
        for i in 0..n {
            let x = f(&mut Rng::new(5, 1, 0, i)).as_dvec3();
            s += x;
            s2 += x * x;
        }
        let m = s / n as f64;
        let var = s2 / n as f64 - m * m;
        (
            m.as_vec3(),
            (var.max(glam::DVec3::ZERO) / n as f64).sqrt().as_vec3(),
        )
    }

    fn all_kinds() -> Scene {
        let l = Vec3::new(0.5, 1.0, 2.0);
        let panel = shape(
            quad(Vec3::new(-1.0, -1.0, 3.0), Vec3::Y * 2.0, Vec3::X * 0.5),
            Some(l),
        );
        scene(
            vec![floor(), panel],
            vec![
                Emitter::Point {
                    position: Vec3::new(0.0, 0.0, 2.0),
                    intensity: Vec3::new(1.0, 2.0, 3.0),
                },
                Emitter::Spot {
                    position: Vec3::new(1.0, 0.0, 2.0),
                    axis: -Vec3::Z,
                    to_world: glam::Mat4::IDENTITY,
                    intensity: Vec3::new(30.0, 20.0, 10.0),
                    cutoff: 0.6,
                    beam_width: 0.2,
                },
                Emitter::Directional {
                    direction: Vec3::new(0.2, 0.1, -1.0).normalize(),
                    irradiance: Vec3::new(0.01, 0.02, 0.01),
                },
                Emitter::Area {
                    shape: 1,
                    radiance: l,
                },
            ],
        )
    }

    #[test]
    fn mean_flux_equals_total_power() {
        let sc = all_kinds();
        let es = EmitterSampler::new(&sc);
        let want: Vec3 = sc.emitters.iter().map(|e| emitter_power(&sc, e)).sum();
        assert!((es.total_power() - want).abs().max_element() <= 1e-4 * want.max_element());
        let (m, se) = stats(400_000, |r| es.sample(r).2);
        eprintln!("mean flux {m} +- {se}, total power {want}");
        for c in 0..3 {
            assert!(
                (m[c] - want[c]).abs() <= 4.0 * se[c],
                "channel {c}: {m} vs {want}"
            );
        }
        // Selection follows power luminance.
        let y: Vec<f32> = sc
            .emitters
            .iter()
            .map(|e| luminance(emitter_power(&sc, e)))
            .collect();
        let ys: f32 = y.iter().sum();
        for (k, yk) in y.iter().enumerate() {
            assert!((es.probability(k) - (yk / ys) as f64).abs() < 1e-6);
        }
        assert!(es.sample_photon(&mut Rng::new(0, 0, 0, 0)).is_some());
    }

    #[test]
    fn point_light_photons_fill_solid_angles_uniformly() {
        let i = Vec3::new(1.0, 2.0, 3.0);
        let sc = scene(
            vec![],
            vec![Emitter::Point {
                position: Vec3::ONE,
                intensity: i,
            }],
        );
        let es = EmitterSampler::new(&sc);
        let axis = Vec3::new(1.0, -2.0, 0.5).normalize();
        let alpha = 0.4f32;
        let n = 200_000;
        let (frac, se) = stats(n, |r| {
            let (o, d, f) = es.sample(r);
            assert_eq!(o, Vec3::ONE);
            assert!((f - i * 4.0 * PI).abs().max_element() < 1e-4);
            Vec3::splat((d.dot(axis) > alpha.cos()) as u32 as f32)
        });
        let want = (1.0 - alpha.cos()) / 2.0;
        eprintln!(
            "point: fraction in cone {} +- {} (want {want})",
            frac.x, se.x
        );
        assert!((frac.x - want).abs() <= 4.0 * se.x);
    }

    #[test]
    fn spot_photons_stay_in_the_cone_with_the_beam_share() {
        let sc = all_kinds();
        let Emitter::Spot {
            cutoff, beam_width, ..
        } = sc.emitters[1]
        else {
            unreachable!()
        };
        let spot = scene(vec![], vec![sc.emitters[1].clone()]);
        let es = EmitterSampler::new(&spot);
        let total = es.total_power();
        // Share of the power inside the full-intensity beam: 2 pi (1 - cos b) / Omega.
        let want = 2.0 * PI * (1.0 - beam_width.cos())
            / super::super::spot_solid_angle(cutoff, beam_width);
        let (m, se) = stats(200_000, |r| {
            let (_, d, f) = es.sample(r);
            let theta = d.dot(-Vec3::Z).clamp(-1.0, 1.0).acos();
            assert!(theta <= cutoff + 1e-4);
            Vec3::new(
                f.x * (theta < beam_width) as u32 as f32 / total.x,
                f.x / total.x,
                0.0,
            )
        });
        eprintln!(
            "spot: beam share {} +- {} (want {want}), mean {}",
            m.x, se.x, m.y
        );
        assert!((m.x - want).abs() <= 4.0 * se.x);
        assert!((m.y - 1.0).abs() <= 4.0 * se.y);
    }

    #[test]
    fn area_photons_leave_the_front_cosine_weighted() {
        let sc = all_kinds();
        let area = scene(sc.shapes.clone(), vec![sc.emitters[3].clone()]);
        let es = EmitterSampler::new(&area);
        let (m, se) = stats(200_000, |r| {
            let (o, d, _) = es.sample(r);
            assert!((o.z - 3.0).abs() < 1e-3 && o.x >= -1.0 - 1e-3 && o.x <= -0.5 + 1e-3);
            assert!(d.z < 0.0, "front of the panel faces down");
            Vec3::new(-d.z, d.z * d.z, 0.0)
        });
        // Cosine-weighted: E[cos] = 2/3, E[cos^2] = 1/2.
        assert!((m.x - 2.0 / 3.0).abs() <= 4.0 * se.x, "{m}");
        assert!((m.y - 0.5).abs() <= 4.0 * se.y, "{m}");
    }

    #[test]
    fn directional_photons_start_outside_and_carry_the_irradiance() {
        let sc = all_kinds();
        let Emitter::Directional {
            direction,
            irradiance,
        } = sc.emitters[2]
        else {
            unreachable!()
        };
        let dir = scene(sc.shapes.clone(), vec![sc.emitters[2].clone()]);
        let es = EmitterSampler::new(&dir);
        let (c, r) = bounding_sphere(&dir);
        // Flux through a centered disk of radius R/2 perpendicular to the light = E pi R^2 / 4.
        let (m, se) = stats(200_000, |rng| {
            let (o, d, f) = es.sample(rng);
            assert!((o - c).length() >= r);
            assert!((d - direction).length() < 1e-6);
            // Where the ray crosses the plane through c perpendicular to d.
            let x = o + d * (c - o).dot(d);
            f * ((x - c).length() < 0.5 * r) as u32 as f32
        });
        let want = irradiance * (PI * r * r / 4.0);
        for ch in 0..3 {
            assert!((m[ch] - want[ch]).abs() <= 4.0 * se[ch], "{m} vs {want}");
        }
    }

    /// Photons from a constant sky that cross an open floor, counted where they first land on
    /// its central square: their flux per area is the sky's irradiance `pi L` (the estimate a
    /// photon pass deposits at the first hit).
    #[test]
    fn environment_photons_give_pi_l_on_an_open_plane() {
        let l = Vec3::new(0.5, 1.0, 2.0);
        let env = EnvMap::constant(l, glam::Mat4::IDENTITY);
        let sc = scene(vec![floor()], vec![Emitter::Environment(Arc::new(env))]);
        let es = EmitterSampler::new(&sc);
        let (c, r) = bounding_sphere(&sc);
        let half = 2.0f32;
        let (m, se) = stats(400_000, |rng| {
            let (o, d, f) = es.sample(rng);
            assert!(
                (o - c).length() >= r,
                "photons start outside the bounding sphere"
            );
            if d.z >= 0.0 {
                return Vec3::ZERO;
            }
            let x = o + d * (-o.z / d.z);
            let inside = x.x.abs() < half && x.y.abs() < half;
            f * inside as u32 as f32 / (4.0 * half * half)
        });
        let want = l * PI;
        eprintln!("environment photons: E {m} +- {se} vs pi L {want}");
        for ch in 0..3 {
            assert!((m[ch] - want[ch]).abs() <= 4.0 * se[ch], "{m} vs {want}");
        }
        assert!(se.x < 0.03 * want.x);
    }

    /// A map's photons come from its bright part, weighted so the flux is the map's power.
    #[test]
    fn environment_photons_follow_the_map() {
        let (w, h) = (32u32, 17u32);
        let px = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| Vec3::splat(0.1 + 30.0 * (y == 4 && x < 3) as u32 as f32))
            .collect();
        let env = EnvMap::from_pixels(None, 2.0, glam::Mat4::IDENTITY, w, h, px);
        let sc = scene(
            vec![floor()],
            vec![Emitter::Environment(Arc::new(env.clone()))],
        );
        let es = EmitterSampler::new(&sc);
        let want = emitter_power(&sc, &sc.emitters[0]);
        let (m, se) = stats(200_000, |r| es.sample(r).2);
        for ch in 0..3 {
            assert!((m[ch] - want[ch]).abs() <= 4.0 * se[ch], "{m} vs {want}");
        }
        // every photon's flux is L(w) pi R^2 / p(w): nearly constant under importance sampling
        assert!(se.x < 0.01 * want.x, "{se} vs {want}");
    }

    #[test]
    fn no_light_gives_no_flux() {
        let es = EmitterSampler::new(&scene(vec![], vec![]));
        assert!(es.is_empty());
        assert_eq!(es.sample(&mut Rng::new(1, 0, 0, 0)).2, Vec3::ZERO);
        assert!(es.sample_photon(&mut Rng::new(1, 0, 0, 0)).is_none());
    }
}
