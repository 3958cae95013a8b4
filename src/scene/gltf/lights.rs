//! `KHR_lights_punctual` lights -> [`Emitter`]s in scene units.
//!
//! Units: glTF's are photometric: point and spot intensity in candela (lm/sr), directional
//! illuminance in lux (lm/m^2), and kdmap reads emissive materials as luminance in nits
//! (cd/m^2). Scene units are radiometric-like RGB (Mitsuba's intensity, irradiance and
//! radiance), so one factor converts all three consistently: `value x color x s`, with
//! `s = [units] photometric_scale` (scene units per lumen; default 1). A point light of
//! `I` cd at distance `d` then gives `s I / d^2` scene irradiance units, exactly as a Mitsuba
//! point light of intensity `s I` does.
//!
//! Spot cone: glTF fades from `innerConeAngle` to `outerConeAngle` smoothly (the square of a
//! ramp linear in the cosine); Mitsuba's `spot` fades linearly in angle from `beam_width` to
//! `cutoff_angle`. No Mitsuba spot is the same; kdmap keeps the full intensity inside the
//! inner cone (`beam_width = inner`) and picks the `cutoff` that emits the same total power
//! as the glTF light ([`spot_cone`]): the two falloffs then differ inside the fade band only,
//! by at most 0.06 to 0.13 of the on-axis intensity for the cones of its test.

use super::sensor::gltf_camera_to_world;
use super::{at, node_label, Builder};
use crate::scene::Emitter;
use crate::Result;
use ::gltf::khr_lights_punctual::Kind;
use glam::{DMat4, DVec3, Vec3};

/// glTF's spot falloff at angle `theta` from the axis (the spec's reference implementation).
pub fn gltf_spot_falloff(theta: f64, inner: f64, outer: f64) -> f64 {
    let scale = 1.0 / (inner.cos() - outer.cos()).max(1e-3);
    let t = ((theta.cos() - outer.cos()) * scale).clamp(0.0, 1.0);
    t * t
}

/// Mitsuba's spot falloff at angle `theta`: 1 inside `beam`, linear in angle to 0 at `cutoff`.
pub fn mitsuba_spot_falloff(theta: f64, beam: f64, cutoff: f64) -> f64 {
    if theta <= beam {
        1.0
    } else if theta >= cutoff {
        0.0
    } else {
        (cutoff - theta) / (cutoff - beam)
    }
}

/// `integral_0^outer f(theta) sin(theta) dtheta` by the midpoint rule (the power of a spot
/// over 2 pi, for unit intensity).
pub(super) fn power(f: impl Fn(f64) -> f64, outer: f64) -> f64 {
    const N: usize = 2048;
    let h = outer / N as f64;
    (0..N)
        .map(|k| {
            let th = (k as f64 + 0.5) * h;
            f(th) * th.sin() * h
        })
        .sum()
}

/// Mitsuba's `(beam_width, cutoff_angle)` (radians) for a glTF spot cone `(inner, outer)`:
/// the beam is the inner cone, the cutoff (between inner and outer) is the one that emits the
/// same power as glTF's falloff.
pub fn spot_cone(inner: f32, outer: f32) -> (f32, f32) {
    let (i, o) = (inner as f64, outer as f64);
    if o - i < 1e-6 {
        return (inner, outer);
    }
    let target = power(|t| gltf_spot_falloff(t, i, o), o);
    let (mut lo, mut hi) = (i, o);
    for _ in 0..50 {
        let c = 0.5 * (lo + hi);
        if power(|t| mitsuba_spot_falloff(t, i, c), o) < target {
            lo = c;
        } else {
            hi = c;
        }
    }
    (inner, (0.5 * (lo + hi)) as f32)
}

/// The emitter of `light` on `node` at `world`.
pub(super) fn emitter(
    b: &Builder,
    node: &::gltf::Node,
    light: &::gltf::khr_lights_punctual::Light,
    world: &DMat4,
) -> Result<Emitter> {
    let here = format!(
        "{} (KHR_lights_punctual light {})",
        node_label(node),
        light.index()
    );
    if light.range().is_some() {
        return Err(at(
            b.path,
            &here,
            "'range' is not supported: kdmap lights fall off with the inverse square only",
        ));
    }
    let value = Vec3::from(light.color()) * light.intensity();
    if !(value.is_finite() && value.min_element() >= 0.0) {
        return Err(at(
            b.path,
            &here,
            "color and intensity must be finite and not negative",
        ));
    }
    let value = value * b.opts.photometric_scale;
    let position = world.transform_point3(DVec3::ZERO).as_vec3();
    let frame = gltf_camera_to_world(world).ok_or_else(|| {
        at(
            b.path,
            &here,
            "the node's transform is degenerate or shears",
        )
    })?;
    // glTF lights shine down local -Z: Mitsuba's +z of the turned frame.
    let axis = frame.z_axis.truncate().normalize();
    Ok(match light.kind() {
        Kind::Point => Emitter::Point {
            position,
            intensity: value,
        },
        Kind::Directional => Emitter::Directional {
            direction: axis,
            irradiance: value,
        },
        Kind::Spot {
            inner_cone_angle,
            outer_cone_angle,
        } => {
            let ok = inner_cone_angle >= 0.0
                && inner_cone_angle < outer_cone_angle
                && outer_cone_angle <= std::f32::consts::FRAC_PI_2;
            if !ok {
                return Err(at(
                    b.path,
                    &here,
                    "spot cone: need 0 <= innerConeAngle < outerConeAngle <= pi/2",
                ));
            }
            let (beam_width, cutoff) = spot_cone(inner_cone_angle, outer_cone_angle);
            Emitter::Spot {
                position,
                axis,
                to_world: frame,
                intensity: value,
                cutoff,
                beam_width,
            }
        }
    })
}
