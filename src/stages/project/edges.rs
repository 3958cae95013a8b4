//! The geometric anchor of pose refinement: where a view's geometry has an edge, and how far
//! from it the photo's edge lies.
//!
//! Aligning photos with each other leaves free the one rigid motion of all cameras together
//! (see [`super::pose`]); on a textured Cornell box with every pose off by 0.3 degrees the
//! photometric alignment left each camera about 1 px off, nearly all of it that common
//! motion. The mesh fixes it: a silhouette against the background or a farther surface, a
//! crease, the border between two shapes or the outline of an emitter is an edge in every
//! photo (the radiance changes there: other surface, other normal, other light), at the place
//! the geometry puts it whatever the textures are. This module finds those edges as 3-D points
//! and measures, in a photo, the offset of its edge from where a camera projects them,
//! as model-based edge trackers do (RAPiD, Harris 1992; the moving edges of ViSP): along the
//! edge's image normal, the sub-pixel peak of the photo's luminance gradient. Hand-written
//! because the points come from the scene's own rays and the search from its own photos; no
//! crate does either.
//!
//! **Edge points.** Between two neighbouring pixel centres whose rays meet different surfaces
//! (one misses; other shapes; shading normals more than [`CREASE_DEG`] apart; one point off
//! the other's plane by more than [`DEPTH_STEP`] of the distance) the transition is bisected
//! with [`BISECTIONS`] more rays. It is an edge only if the two sides still differ a
//! thousandth of a pixel apart: a discontinuity survives the bisection, a smooth surface
//! that merely turns fast between pixel centres does not (the tube of a torus a few pixels
//! thick turns more than [`CREASE_DEG`] from one pixel to the next and shows no edge in a
//! photo; counted as edges, its turns were measured on whatever gradient lay near and biased
//! the camera by 0.3-0.5 px). The edge point is where the nearer side's last ray met it: the
//! near surface ends there, at a side of the triangle hit, whose direction is the edge's 3-D
//! tangent. To first order a camera move shifts an edge's image as it shifts that point,
//! smooth occluding contours included (the contour slides along the ray).
//!
//! **Measurement.** The photo's luminance (linear: a pixel the edge crosses holds the mix of
//! its two sides, so the blurred step's steepest point is the edge; in a logarithm it would
//! lean towards the darker side by up to half a pixel) is blurred over its valid pixels
//! ([`super::pose`]'s blur, about a Gaussian); its gradient is sampled every quarter pixel
//! along the image normal within `reach`, and the centroid of the strongest peak's upper half
//! is the photo's edge (a bilinear gradient peaks at pixel centres; its centroid does not). A
//! peak on the search's border, or weaker relative to the blurred luminance there than a
//! twentieth per pixel of blur (about a 12% step), is no measurement; so a gain or a shading
//! factor moves no edge.

use super::view::Tap;
use crate::image::Image;
use crate::physics::accel::Accel;
use crate::physics::camera::Camera;
use crate::scene::{luminance, Scene};
use glam::{Vec2, Vec3};
use rayon::prelude::*;

/// Shading normals further apart than this (degrees) make a crease (the facets of a
/// smooth-shaded mesh make none: its photo shows none).
pub const CREASE_DEG: f32 = 20.0;
/// A depth edge within one shape: a point off the neighbour's plane by this share of the
/// distance.
pub const DEPTH_STEP: f32 = 0.01;
/// Rays that bisect each transition (a thousandth of a pixel).
pub const BISECTIONS: u32 = 10;
/// Step of the search along the image normal, pixels.
const SEARCH_STEP: f32 = 0.25;

/// A point on an edge of the geometry, with the edge's direction there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Edge {
    pub point: Vec3,
    pub tangent: Vec3,
}

/// What the ray through a film position met: shape, unit geometric and shading normals,
/// distance.
#[derive(Debug, Clone, Copy)]
struct Seen {
    shape: u32,
    tri: u32,
    normal: Vec3,
    shading: Vec3,
    t: f32,
    point: Vec3,
}

fn look(scene: &Scene, accel: &Accel, cam: &Camera, q: Vec2) -> Option<Seen> {
    let (o, d) = cam.ray(q.x, q.y);
    let hit = accel.intersect(o, d, f32::INFINITY)?;
    let mesh = &scene.shapes[hit.shape as usize].mesh;
    let normal = mesh.face_normal_raw(hit.tri as usize).normalize_or_zero();
    Some(Seen {
        shape: hit.shape,
        tri: hit.tri,
        normal,
        shading: mesh.shading_normal(hit.tri as usize, hit.b1, hit.b2),
        t: hit.t,
        point: o + d * hit.t,
    })
}

/// Whether two rays met the same smooth surface (both missing counts as the same).
fn same(a: Option<Seen>, b: Option<Seen>) -> bool {
    match (a, b) {
        (None, None) => true,
        (Some(a), Some(b)) => {
            a.shape == b.shape
                && a.shading.dot(b.shading).abs() > CREASE_DEG.to_radians().cos()
                && a.normal.dot(b.point - a.point).abs() < DEPTH_STEP * a.t.min(b.t)
        }
        _ => false,
    }
}

/// The edge points of the geometry as `cam` sees it (every pixel pair across a transition,
/// bisected), in row-major order of the pairs' first pixel, horizontal pairs first.
pub fn edges(scene: &Scene, accel: &Accel, cam: &Camera) -> Vec<Edge> {
    let (w, h) = (cam.width(), cam.height());
    let centre = |x: u32, y: u32| Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
    let seen: Vec<Option<Seen>> = (0..w * h)
        .into_par_iter()
        .map(|i| look(scene, accel, cam, centre(i % w, i / w)))
        .collect();
    let at = |x: u32, y: u32| seen[(y * w + x) as usize];
    let mut out = Vec::new();
    for (dx, dy) in [(1u32, 0u32), (0, 1)] {
        let pairs: Vec<(u32, u32)> = (0..h - dy)
            .flat_map(|y| (0..w - dx).map(move |x| (x, y)))
            .filter(|&(x, y)| !same(at(x, y), at(x + dx, y + dy)))
            .collect();
        let step = Vec2::new(dx as f32, dy as f32);
        out.par_extend(
            pairs
                .par_iter()
                .filter_map(|&(x, y)| bisect(scene, accel, cam, (centre(x, y), step), at(x, y))),
        );
    }
    out
}

/// The edge point between `from` (seeing `a`) and `from + step`, if the two sides are still
/// different surfaces where the bisection ends.
fn bisect(
    scene: &Scene,
    accel: &Accel,
    cam: &Camera,
    (from, step): (Vec2, Vec2),
    a: Option<Seen>,
) -> Option<Edge> {
    let (mut lo, mut hi) = (0.0f32, 1.0f32);
    let (mut near_a, mut near_b) = (a, look(scene, accel, cam, from + step));
    for _ in 0..BISECTIONS {
        let m = 0.5 * (lo + hi);
        let s = look(scene, accel, cam, from + step * m);
        match same(a, s) {
            true => (lo, near_a) = (m, s),
            false => (hi, near_b) = (m, s),
        }
    }
    // A discontinuity still separates the two sides a thousandth of a pixel apart; a surface
    // that only turns or recedes fast between the pixel centres does not.
    if same(near_a, near_b) {
        return None;
    }
    let ta = near_a.map_or(f32::INFINITY, |s| s.t);
    let tb = near_b.map_or(f32::INFINITY, |s| s.t);
    let near = match ta <= tb {
        true => near_a?,
        false => near_b?,
    };
    let point = near.point;
    let tangent = nearest_side(&scene.shapes[near.shape as usize].mesh, near.tri, point);
    (tangent != Vec3::ZERO && point.is_finite()).then_some(Edge { point, tangent })
}

/// The unit direction of the side of triangle `tri` nearest to `p` (the near surface ends at
/// one of its triangles' sides: a silhouette, a crease or a shape's border).
fn nearest_side(mesh: &crate::scene::Mesh, tri: u32, p: Vec3) -> Vec3 {
    let v = mesh.triangle(tri as usize);
    let off = |a: Vec3, b: Vec3| {
        let e = b - a;
        let s = ((p - a).dot(e) / e.length_squared().max(1e-30)).clamp(0.0, 1.0);
        (p - (a + e * s)).length()
    };
    let sides = [(v[0], v[1]), (v[1], v[2]), (v[2], v[0])];
    let (a, b) = (sides.into_iter())
        .min_by(|x, y| off(x.0, x.1).total_cmp(&off(y.0, y.1)))
        .unwrap_or((v[0], v[1]));
    (b - a).normalize_or_zero()
}

/// Where `e` projects through `cam` and the unit normal of its image there.
pub fn in_image(cam: &Camera, e: &Edge) -> Option<(Vec2, Vec2)> {
    let p = cam.project(e.point)?;
    let h = 1e-3 * (e.point - cam.position()).length();
    let q = cam.project(e.point + e.tangent * h)?;
    let t = (q - p).normalize_or_zero();
    (t != Vec2::ZERO).then(|| (p, Vec2::new(-t.y, t.x)))
}

/// A photo's luminance gradient at one blur, for measuring where its edges lie.
pub struct EdgeImage {
    width: usize,
    height: usize,
    sigma: f32,
    lum: Vec<f32>,
    dx: Vec<f32>,
    dy: Vec<f32>,
}

impl EdgeImage {
    /// `image`'s luminance, blurred about a Gaussian of `sigma` px over its valid pixels by
    /// `blur`, and its central differences.
    pub fn new(image: &Image, sigma: f32, blur: impl Fn(&[Vec3], &[bool]) -> Vec<Vec3>) -> Self {
        let (w, h) = (image.width as usize, image.height as usize);
        let lum: Vec<Vec3> = (image.pixels.iter())
            .map(|p| Vec3::splat(luminance(*p)))
            .collect();
        let b: Vec<f32> = blur(&lum, &image.valid).iter().map(|v| v.x).collect();
        let grad = |i: usize, j: usize, span: usize| (b[j] - b[i]) / span.max(1) as f32;
        let (dx, dy) = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let (x0, x1) = (x.saturating_sub(1), (x + 1).min(w - 1));
                let (y0, y1) = (y.saturating_sub(1), (y + 1).min(h - 1));
                (
                    grad(y * w + x0, y * w + x1, x1 - x0),
                    grad(y0 * w + x, y1 * w + x, y1 - y0),
                )
            })
            .unzip();
        EdgeImage {
            width: w,
            height: h,
            sigma,
            dx,
            dy,
            lum: b,
        }
    }

    /// The gradient along `n` at continuous pixel coordinates `q` and the luminance there
    /// (bilinear), `None` off the image.
    fn along(&self, q: Vec2, n: Vec2) -> Option<(f32, f32)> {
        let tap = Tap::inside(q, self.width, self.height)?;
        let mix = |v: &[f32]| tap.read_slice(self.width as u32, v);
        Some((mix(&self.dx) * n.x + mix(&self.dy) * n.y, mix(&self.lum)))
    }

    /// The signed offset along `n` from `p` of the photo's strongest edge within `reach` px,
    /// sub-pixel; `None` if the peak's upper half reaches the border of the search or the peak
    /// is too weak.
    pub fn offset(&self, p: Vec2, n: Vec2, reach: f32) -> Option<f32> {
        let k = (reach / SEARCH_STEP).round() as i32;
        let gl: Vec<(f32, f32)> = (-k..=k)
            .map(|i| self.along(p + n * (i as f32 * SEARCH_STEP), n))
            .collect::<Option<_>>()?;
        let g: Vec<f32> = gl.iter().map(|x| x.0.abs()).collect();
        let (best, &peak) = g.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1))?;
        let weak = peak.is_nan() || peak <= 0.05 / self.sigma.max(1.0) * gl[best].1;
        if best == 0 || best + 1 == g.len() || weak {
            return None;
        }
        let half = 0.5 * peak;
        let lo = (0..best).rev().find(|&i| g[i] <= half)?;
        let hi = (best + 1..g.len()).find(|&i| g[i] <= half)?;
        let (mut sum, mut at) = (0.0f32, 0.0f32);
        for (i, v) in g.iter().enumerate().take(hi).skip(lo + 1) {
            sum += v - half;
            at += (v - half) * (i as i32 - k) as f32;
        }
        Some(at / sum * SEARCH_STEP)
    }
}

#[cfg(test)]
mod tests;
