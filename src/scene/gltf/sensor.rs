//! A glTF perspective camera -> a Mitsuba [`Sensor`]. glTF's camera looks down its local -Z
//! with +X to the image's right and +Y up; Mitsuba's looks along +z with +x to the image's
//! LEFT and +y up. The two frames differ by half a turn about y: `to_world = node world
//! matrix x diag(-1, 1, -1)`, with the node's scale divided out (glTF cameras ignore it).
//! `yfov` (radians) is Mitsuba's `fov` along y; the film is the photo's size.

use super::{at, node_label, Builder};
use crate::scene::{FovAxis, PixelFilter, Sensor};
use crate::Result;
use glam::{DMat4, DVec4, Mat4};

/// Film height (pixels) of a camera without a photo; its width follows `aspectRatio` (1 when
/// the file gives none). Only `inspect` ever sees such a camera: a run skips it.
pub const NOMINAL_HEIGHT: u32 = 512;

/// Largest relative difference accepted between a camera's `aspectRatio` and its photo's.
const ASPECT_TOLERANCE: f64 = 0.01;

/// The Mitsuba `to_world` of a glTF camera whose node has world matrix `world`: the rotation
/// part normalized (scale dropped), then turned half a turn about y. `None` if the node's
/// axes are degenerate or sheared.
pub fn gltf_camera_to_world(world: &DMat4) -> Option<Mat4> {
    let mut cols = [world.x_axis, world.y_axis, world.z_axis];
    for c in &mut cols {
        let l = c.truncate().length();
        if !(l.is_finite() && l > 1e-12) {
            return None;
        }
        *c /= l;
    }
    let [x, y, z] = cols.map(|c| c.truncate());
    if x.dot(y).abs() > 1e-4 || x.dot(z).abs() > 1e-4 || y.dot(z).abs() > 1e-4 {
        return None;
    }
    let rigid = DMat4::from_cols(cols[0], cols[1], cols[2], world.w_axis);
    let turn = DMat4::from_cols(
        DVec4::new(-1.0, 0.0, 0.0, 0.0),
        DVec4::Y,
        DVec4::new(0.0, 0.0, -1.0, 0.0),
        DVec4::W,
    );
    Some((rigid * turn).as_mat4())
}

/// The sensor of `cam` on `node` at `world`, named `id`.
pub(super) fn sensor(
    b: &Builder,
    node: &::gltf::Node,
    cam: &::gltf::Camera,
    world: &DMat4,
    id: String,
) -> Result<Sensor> {
    let here = format!("{} (cameras[{}])", node_label(node), cam.index());
    let p = match cam.projection() {
        ::gltf::camera::Projection::Perspective(p) => p,
        ::gltf::camera::Projection::Orthographic(_) => {
            return Err(at(b.path, &here, "orthographic cameras are not supported"))
        }
    };
    let yfov = p.yfov() as f64;
    if !(yfov > 0.0 && yfov < std::f64::consts::PI) {
        return Err(at(
            b.path,
            &here,
            format!("yfov = {yfov}: must be in (0, pi) radians"),
        ));
    }
    let aspect = p.aspect_ratio().map(f64::from);
    if aspect.is_some_and(|a| !(a.is_finite() && a > 0.0)) {
        return Err(at(b.path, &here, "aspectRatio must be positive"));
    }
    let to_world = gltf_camera_to_world(world).ok_or_else(|| {
        at(
            b.path,
            &here,
            "the node's transform is degenerate or shears",
        )
    })?;
    let photo = match b.opts.views.get(&id) {
        Some(p) => Some(p.clone()),
        None => crate::scene::photos::find(&b.dir.join("images"), &id)?,
    };
    let (width, height) = match &photo {
        Some(photo) if photo.is_file() => {
            let (w, h) = crate::scene::photos::size(photo)?;
            if let Some(a) = aspect {
                let pa = w as f64 / h.max(1) as f64;
                if (pa / a - 1.0).abs() > ASPECT_TOLERANCE {
                    return Err(at(
                        b.path,
                        &here,
                        format!(
                            "aspectRatio {a} does not match its photo {} ({w}x{h})",
                            photo.display()
                        ),
                    ));
                }
            }
            (w, h)
        }
        _ => {
            let w = (NOMINAL_HEIGHT as f64 * aspect.unwrap_or(1.0))
                .round()
                .max(1.0);
            (w as u32, NOMINAL_HEIGHT)
        }
    };
    Ok(Sensor::simple(
        &id,
        to_world,
        yfov.to_degrees() as f32,
        FovAxis::Y,
        (width, height),
        PixelFilter::Box,
    ))
}
