//! Which covered texels a photo could see at all (inside its frame, facing it, nothing in
//! between): what the projection's observed texels are measured against.

use super::MIN_COS;
use crate::atlas::store::TexelGeom;
use crate::atlas::ShapeRef;
use crate::physics::accel::{offset_origin, Accel};
use crate::physics::camera::Camera;
use crate::scene::Sides;

/// Whether `camera` could see texel `g` of `shape`: its center projects into the frame, faces
/// the camera by at least [`MIN_COS`] and the segment to the camera is unoccluded.
pub fn sees(camera: &Camera, accel: &Accel, shape: &ShapeRef, g: &TexelGeom) -> bool {
    let (p, eye) = (g.p(), camera.position());
    let to_cam = eye - p;
    let dist = to_cam.length();
    if dist <= 0.0 {
        return false;
    }
    let dir = to_cam / dist;
    let cos = g.n().dot(dir);
    let facing = match shape.sides {
        Sides::Front => cos,
        Sides::Both => cos.abs(),
    };
    let Some(pix) = camera.project(p) else {
        return false;
    };
    let (w, h) = (camera.width() as f32, camera.height() as f32);
    if facing < MIN_COS || pix.x < 0.0 || pix.y < 0.0 || pix.x >= w || pix.y >= h {
        return false;
    }
    let o = offset_origin(p, g.ng(), dir);
    !accel.occluded(o, dir, (eye - o).length() * (1.0 - 1e-4))
}
