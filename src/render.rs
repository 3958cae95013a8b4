//! Looking at texture-space results through a camera: a primary ray per pixel, the hit's atlas
//! coordinates, a bilinear texture lookup. Used to re-render the input views from recovered
//! maps and to check projection (a luminance map re-projected must give back the photo).

use crate::accel::Accel;
use crate::camera::Camera;
use glam::{Vec2, Vec3};
use rayon::prelude::*;

/// A per-shape texture: `width x height` linear RGB, row-major, row 0 = top.
pub struct Texture<'a> {
    pub width: u32,
    pub height: u32,
    pub texels: &'a [Vec3],
    /// Per-triangle corner coordinates in texel units (the shape's atlas).
    pub corner_uv: &'a [[Vec2; 3]],
}

/// Bilinear lookup at continuous texel coordinates (texel (i, j) has its center at
/// (i + 0.5, j + 0.5)), clamped to the texture.
pub fn bilinear(texels: &[Vec3], width: u32, height: u32, uv: Vec2) -> Vec3 {
    let fx = (uv.x - 0.5).clamp(0.0, (width - 1) as f32);
    let fy = (uv.y - 0.5).clamp(0.0, (height - 1) as f32);
    let (x0, y0) = (fx.floor() as u32, fy.floor() as u32);
    let (x1, y1) = ((x0 + 1).min(width - 1), (y0 + 1).min(height - 1));
    let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
    let g = |x: u32, y: u32| texels[(y * width + x) as usize];
    let top = g(x0, y0) * (1.0 - tx) + g(x1, y0) * tx;
    let bot = g(x0, y1) * (1.0 - tx) + g(x1, y1) * tx;
    top * (1.0 - ty) + bot * ty
}

/// Render one view as Mitsuba's box-filtered film does: each pixel is the mean over `k x k`
/// stratified sub-pixel rays of the texture value where the ray hits a textured shape
/// (`textures[shape]`). `None` where no sub-pixel ray hits a textured shape.
pub fn render_view(
    accel: &Accel,
    camera: &Camera,
    textures: &[Option<Texture>],
    k: u32,
) -> Vec<Option<Vec3>> {
    let (w, h) = (camera.width(), camera.height());
    let k = k.max(1);
    (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            (0..w).map(move |x| {
                let mut sum = Vec3::ZERO;
                let mut n = 0u32;
                for j in 0..k {
                    for i in 0..k {
                        let px = x as f32 + (i as f32 + 0.5) / k as f32;
                        let py = y as f32 + (j as f32 + 0.5) / k as f32;
                        if let Some(v) = shade(accel, camera, textures, px, py) {
                            sum += v;
                            n += 1;
                        }
                    }
                }
                (n > 0).then(|| sum / n as f32)
            })
        })
        .collect()
}

/// The texture value seen along the ray through continuous pixel coordinates `(px, py)`.
fn shade(
    accel: &Accel,
    camera: &Camera,
    textures: &[Option<Texture>],
    px: f32,
    py: f32,
) -> Option<Vec3> {
    let (o, d) = camera.ray(px, py);
    let hit = accel.intersect(o, d, f32::INFINITY)?;
    let tex = textures.get(hit.shape as usize)?.as_ref()?;
    let c = tex.corner_uv[hit.tri as usize];
    let uv = c[0] * (1.0 - hit.b1 - hit.b2) + c[1] * hit.b1 + c[2] * hit.b2;
    Some(bilinear(tex.texels, tex.width, tex.height, uv))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_is_exact_at_centers_and_linear_between() {
        let t = vec![
            Vec3::splat(0.0),
            Vec3::splat(1.0),
            Vec3::splat(2.0),
            Vec3::splat(3.0),
        ];
        assert_eq!(bilinear(&t, 2, 2, Vec2::new(0.5, 0.5)), Vec3::splat(0.0));
        assert_eq!(bilinear(&t, 2, 2, Vec2::new(1.5, 1.5)), Vec3::splat(3.0));
        assert_eq!(bilinear(&t, 2, 2, Vec2::new(1.0, 0.5)), Vec3::splat(0.5));
        assert_eq!(bilinear(&t, 2, 2, Vec2::new(1.0, 1.0)), Vec3::splat(1.5));
        // clamped outside
        assert_eq!(bilinear(&t, 2, 2, Vec2::new(-3.0, 0.5)), Vec3::splat(0.0));
    }
}
