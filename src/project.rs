//! Projection of the photos onto the atlas (method step 2, eq. 1): for every texel a camera
//! sees, a weighted mean of the photo's radiance, `L_orig = sum w_i L_i / sum w_i`.
//!
//! Per view we first classify the photo's pixels with primary rays: a pixel is *clean* when its
//! four corners and its center all land on one plane of one shape (so it straddles no
//! silhouette, depth edge or crease) and its value is finite. A texel is then observed through
//! k x k sub-samples of its footprint (k grows with texel size / pixel footprint, so a texel
//! much larger than a pixel gets an area average, not a point sample). Each sub-sample must be
//! front-facing, unoccluded (a ray from the camera reaches it first) and land on clean pixels
//! of the same surface; it reads the photo bilinearly, or the nearest pixel at the edge of a
//! clean region. The weight `w = (accepted fraction) * A_texel / A_pixel` counts how many
//! pixels' worth of measurement the texel received, so it accounts for distance, viewing angle
//! and pixel footprint together.

use crate::accel::Accel;
use crate::atlas::layout::{flags, TexelGeom, TexelState};
use crate::camera::Camera;
use crate::image::Image;
use crate::scene::{Mesh, Scene, Sides};
use glam::{Vec2, Vec3};
use rayon::prelude::*;

/// The largest sub-sample grid per texel and view (k x k).
pub const MAX_SUBSAMPLES: u32 = 8;
/// Texels seen more grazing than this cosine are not used.
pub const MIN_COS: f32 = 0.05;

/// What the primary ray through a pixel center found.
#[derive(Debug, Clone, Copy)]
pub struct PixelInfo {
    /// Shape index hit at the pixel center, `u32::MAX` for none.
    pub shape: u32,
    /// Unit geometric normal there.
    pub normal: Vec3,
    /// Whether the whole pixel lies on one plane of one shape and its value is valid.
    pub clean: bool,
}

/// One photo with its per-pixel classification, ready to be sampled.
pub struct View<'a> {
    pub camera: Camera,
    pub image: &'a Image,
    pub pixels: Vec<PixelInfo>,
    /// Values the lookups interpolate (EXPERIMENT).
    pub q: Vec<Vec3>,
}

fn env_mode() -> &'static str {
    static M: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    M.get_or_init(|| std::env::var("KDMAP_LOOKUP").unwrap_or_else(|_| "bilinear".into()))
}
fn env_f(name: &str, d: f32) -> f32 {
    std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(d)
}

/// Solve the tridiagonal (1/8, 3/4, 1/8) system (7/8 at the ends) in place.
fn solve_run(d: &mut [Vec3]) {
    let n = d.len();
    if n < 2 {
        return;
    }
    let a = 0.125f32;
    let mut cp = vec![0f32; n];
    let b0 = 0.875;
    cp[0] = a / b0;
    d[0] /= b0;
    for i in 1..n {
        let b = if i == n - 1 { 0.875 } else { 0.75 };
        let m = b - a * cp[i - 1];
        cp[i] = a / m;
        let prev = d[i - 1];
        d[i] = (d[i] - prev * a) / m;
    }
    for i in (0..n - 1).rev() {
        let next = d[i + 1];
        d[i] -= next * cp[i];
    }
}

fn prefilter(w: usize, h: usize, px: &[PixelInfo], img: &[Vec3]) -> Vec<Vec3> {
    let mut q = img.to_vec();
    let same = |a: &PixelInfo, b: &PixelInfo| {
        a.clean && b.clean && a.shape == b.shape && a.normal.dot(b.normal) > 0.99
    };
    for pass in 0..2 {
        let (outer, inner) = if pass == 0 { (h, w) } else { (w, h) };
        let idx = |o: usize, i: usize| if pass == 0 { o * w + i } else { i * w + o };
        for o in 0..outer {
            let mut start = 0;
            while start < inner {
                if !px[idx(o, start)].clean {
                    start += 1;
                    continue;
                }
                let mut end = start + 1;
                while end < inner && same(&px[idx(o, end - 1)], &px[idx(o, end)]) {
                    end += 1;
                }
                let mut run: Vec<Vec3> = (start..end).map(|i| q[idx(o, i)]).collect();
                solve_run(&mut run);
                for (k, i) in (start..end).enumerate() {
                    q[idx(o, i)] = run[k];
                }
                start = end;
            }
        }
    }
    q
}

/// Classify every pixel of `image` as seen by `camera` (corner + center primary rays).
pub fn classify_pixels(
    scene: &Scene,
    accel: &Accel,
    camera: &Camera,
    image: &Image,
) -> Vec<PixelInfo> {
    let (w, h) = (camera.width(), camera.height());
    // Corner rays on the (W+1) x (H+1) grid.
    let corners: Vec<Option<(u32, Vec3)>> = (0..(h + 1))
        .into_par_iter()
        .flat_map_iter(|y| {
            (0..(w + 1)).map(move |x| {
                let (o, d) = camera.ray(x as f32, y as f32);
                accel
                    .intersect(o, d, f32::INFINITY)
                    .map(|hit| (hit.shape, o + d * hit.t))
            })
        })
        .collect();
    (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            let corners = &corners;
            (0..w).map(move |x| {
                let (o, d) = camera.ray(x as f32 + 0.5, y as f32 + 0.5);
                let Some(hit) = accel.intersect(o, d, f32::INFINITY) else {
                    return PixelInfo {
                        shape: u32::MAX,
                        normal: Vec3::ZERO,
                        clean: false,
                    };
                };
                let mesh = &scene.shapes[hit.shape as usize].mesh;
                let n = mesh.face_normal_raw(hit.tri as usize).normalize_or_zero();
                let c = o + d * hit.t;
                let tol = 1e-3 * hit.t + 1e-6;
                let stride = (w + 1) as usize;
                let idx = [
                    y as usize * stride + x as usize,
                    y as usize * stride + x as usize + 1,
                    (y as usize + 1) * stride + x as usize,
                    (y as usize + 1) * stride + x as usize + 1,
                ];
                let coplanar = idx.iter().all(|&i| match corners[i] {
                    Some((s, p)) => s == hit.shape && (p - c).dot(n).abs() <= tol,
                    None => false,
                });
                PixelInfo {
                    shape: hit.shape,
                    normal: n,
                    clean: coplanar && image.is_valid(x, y),
                }
            })
        })
        .collect()
}

impl<'a> View<'a> {
    pub fn new(scene: &Scene, accel: &Accel, camera: Camera, image: &'a Image) -> View<'a> {
        let pixels = classify_pixels(scene, accel, &camera, image);
        let q = if env_mode() == "consistent" {
            prefilter(
                camera.width() as usize,
                camera.height() as usize,
                &pixels,
                &image.pixels,
            )
        } else {
            image.pixels.clone()
        };
        let neg = q.iter().filter(|v| v.min_element() < 0.0).count();
        eprintln!("view {}: {neg} prefiltered pixels with a negative channel", camera.id);
        let q = if std::env::var("KDMAP_CLAMP").is_ok() {
            q.into_iter().map(|v| v.max(Vec3::ZERO)).collect()
        } else {
            q
        };
        View {
            camera,
            image,
            pixels,
            q,
        }
    }

    fn usable(&self, x: i64, y: i64, shape: u32, n: Vec3) -> bool {
        let (w, h) = (self.camera.width() as i64, self.camera.height() as i64);
        if x < 0 || y < 0 || x >= w || y >= h {
            return false;
        }
        let p = &self.pixels[(y * w + x) as usize];
        p.clean && p.shape == shape && p.normal.dot(n).abs() > 0.99
    }

    /// The photo's radiance at continuous pixel coordinates `pix` for a point of `shape` with
    /// geometric normal `n`: bilinear when the four nearest pixels are clean pixels of that
    /// surface, else the containing pixel if it is, else `None`.
    pub fn sample(&self, pix: Vec2, shape: u32, n: Vec3) -> Option<Vec3> {
        let wd = self.camera.width() as i64;
        if env_mode() == "nearest" {
            let (x, y) = (pix.x.floor() as i64, pix.y.floor() as i64);
            return self
                .usable(x, y, shape, n)
                .then(|| self.q[(y * wd + x) as usize]);
        }
        let fx = pix.x - 0.5;
        let fy = pix.y - 0.5;
        let (x0, y0) = (fx.floor() as i64, fy.floor() as i64);
        let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
        let quad = [(x0, y0), (x0 + 1, y0), (x0, y0 + 1), (x0 + 1, y0 + 1)];
        if quad.iter().all(|&(x, y)| self.usable(x, y, shape, n)) {
            let g = |x: i64, y: i64| self.q[(y * wd + x) as usize];
            let top = g(x0, y0) * (1.0 - tx) + g(x0 + 1, y0) * tx;
            let bot = g(x0, y0 + 1) * (1.0 - tx) + g(x0 + 1, y0 + 1) * tx;
            return Some(top * (1.0 - ty) + bot * ty);
        }
        let (x, y) = (pix.x.floor() as i64, pix.y.floor() as i64);
        self.usable(x, y, shape, n)
            .then(|| self.q[(y * wd + x) as usize])
    }
}

/// World-space edge vectors of one texel on triangle `tri` of `mesh`, whose corners sit at
/// texel coordinates `uv`: `(dP/dx, dP/dy)`.
pub fn texel_jacobian(mesh: &Mesh, tri: usize, uv: &[Vec2; 3]) -> (Vec3, Vec3) {
    let [p0, p1, p2] = mesh.triangle(tri);
    let (e1, e2) = (p1 - p0, p2 - p0);
    let (d1, d2) = (uv[1] - uv[0], uv[2] - uv[0]);
    let det = d1.x * d2.y - d1.y * d2.x;
    if det == 0.0 || !det.is_finite() {
        return (Vec3::ZERO, Vec3::ZERO);
    }
    let dpdx = (e1 * d2.y - e2 * d1.y) / det;
    let dpdy = (e2 * d1.x - e1 * d2.x) / det;
    (dpdx, dpdy)
}

/// Everything projection needs about one shape.
pub struct ShapeRef<'a> {
    pub index: u32,
    pub mesh: &'a Mesh,
    pub sides: Sides,
    /// Per-triangle corner UVs in texel units.
    pub corner_uv: &'a [[Vec2; 3]],
}

/// Observe one texel in one view: `(mean radiance, weight)`, or `None` if the view does not
/// see it usefully.
pub fn observe_texel(
    view: &View,
    accel: &Accel,
    shape: &ShapeRef,
    g: &TexelGeom,
) -> Option<(Vec3, f32)> {
    let cam = view.camera.position();
    let p = g.p();
    let n = g.n();
    let ng = g.ng();
    let to_cam = cam - p;
    let dist = to_cam.length();
    if dist <= 0.0 {
        return None;
    }
    let cos = n.dot(to_cam) / dist;
    let facing = match shape.sides {
        Sides::Front => cos,
        Sides::Both => cos.abs(),
    };
    if facing < MIN_COS {
        return None;
    }
    let a_pix = view.camera.pixel_footprint_area(p, ng);
    if !(a_pix.is_finite() && a_pix > 0.0) {
        return None;
    }
    let ratio = g.area / a_pix;
    let (dx, dy) = texel_jacobian(shape.mesh, g.tri as usize, &shape.corner_uv[g.tri as usize]);
    let kmul = env_f("KDMAP_KMUL", 1.0);
    let (kx, ky) = if env_f("KDMAP_KAXIS", 0.0) > 0.0 {
        let pp = view.camera.project(p)?;
        let ex = view.camera.project(p + dx * 0.5).map(|v| (v - pp).length() * 2.0).unwrap_or(1.0);
        let ey = view.camera.project(p + dy * 0.5).map(|v| (v - pp).length() * 2.0).unwrap_or(1.0);
        (
            ((ex * kmul).ceil() as u32).clamp(1, 4 * MAX_SUBSAMPLES),
            ((ey * kmul).ceil() as u32).clamp(1, 4 * MAX_SUBSAMPLES),
        )
    } else {
        let k = ((ratio.sqrt() * kmul).ceil() as u32).clamp(1, MAX_SUBSAMPLES);
        (k, k)
    };
    let mut sum = Vec3::ZERO;
    let mut accepted = 0u32;
    for j in 0..ky {
        for i in 0..kx {
            let ox = (i as f32 + 0.5) / kx as f32 - 0.5;
            let oy = (j as f32 + 0.5) / ky as f32 - 0.5;
            let q = if kx * ky == 1 { p } else { p + dx * ox + dy * oy };
            let v = q - cam;
            let d = v.length();
            if d <= 0.0 {
                continue;
            }
            let dir = v / d;
            // Unoccluded: the first surface along the camera ray is this shape, at q.
            match accel.intersect(cam, dir, d * (1.0 + 1e-3) + 1e-4) {
                Some(h) if h.shape == shape.index && (h.t - d).abs() <= 1e-3 * d + 1e-4 => {}
                _ => continue,
            }
            let Some(pix) = view.camera.project(q) else {
                continue;
            };
            if let Some(l) = view.sample(pix, shape.index, ng) {
                sum += l;
                accepted += 1;
            }
        }
    }
    if accepted == 0 {
        return None;
    }
    let frac = accepted as f32 / (kx * ky) as f32;
    Some((sum / accepted as f32, frac * ratio))
}

/// Accumulate one view into one tile: `state.l_orig += w L`, `state.weight += w`.
pub fn project_tile(
    view: &View,
    accel: &Accel,
    shape: &ShapeRef,
    geom: &[TexelGeom],
    state: &mut [TexelState],
) {
    for (g, s) in geom.iter().zip(state.iter_mut()) {
        if !g.covered() {
            continue;
        }
        if let Some((l, w)) = observe_texel(view, accel, shape, g) {
            for c in 0..3 {
                s.l_orig[c] += w * l[c];
            }
            s.weight += w;
        }
    }
}

/// After all views: turn the weighted sums into means and flag observed texels.
pub fn finish_tile(state: &mut [TexelState]) {
    for s in state.iter_mut() {
        if s.weight > 0.0 {
            for c in 0..3 {
                s.l_orig[c] /= s.weight;
            }
            s.flags |= flags::OBSERVED;
        } else {
            s.l_orig = [0.0; 3];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jacobian_maps_texel_steps_to_world_steps() {
        let mesh = Mesh {
            positions: vec![
                Vec3::ZERO,
                Vec3::new(2.0, 0.0, 0.0),
                Vec3::new(0.0, 0.0, 3.0),
            ],
            normals: None,
            uvs: None,
            triangles: vec![[0, 1, 2]],
        };
        // 10 texels along x cover 2 units; 30 texels along y cover 3 units
        let uv = [
            Vec2::new(5.0, 5.0),
            Vec2::new(15.0, 5.0),
            Vec2::new(5.0, 35.0),
        ];
        let (dx, dy) = texel_jacobian(&mesh, 0, &uv);
        assert!((dx - Vec3::new(0.2, 0.0, 0.0)).length() < 1e-6, "{dx}");
        assert!((dy - Vec3::new(0.0, 0.0, 0.1)).length() < 1e-6, "{dy}");
    }
}
