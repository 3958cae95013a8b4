//! Pixels that see one surface of one shape without lying on one plane (studs, bevels,
//! curved and creased parts): a texel that no clean pixel of a view sees is read from these,
//! at a lower weight, so a scene of fine geometry is observed rather than filled.
//!
//! A pixel's *span* is the shape its four corner rays all hit and the range of their
//! distances from the camera; there is none where a corner misses, hits another shape or
//! lands within reach of an emitter, where the distances spread over more than
//! [`MAX_SPREAD`] pixel widths (a part of the shape in front of another), or where the
//! photo's value is invalid. A film filter that reaches `n` pixels makes a pixel's span the
//! union of its neighbours' within `n`, and none unless they all see the same shape.

use crate::image::Image;
use crate::physics::accel::Hit;
use crate::physics::camera::Camera;
use crate::scene::Scene;
use glam::Vec3;

/// What the corner rays of a pixel found on one surface of one shape.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Span {
    pub shape: u32,
    /// Least and greatest distance from the camera of the corner hits.
    pub near: f32,
    pub far: f32,
}

/// Distance spread allowed within a pixel, in pixel widths at its distance: a surface seen at
/// 18 degrees or steeper stays within it, a depth edge does not.
pub const MAX_SPREAD: f32 = 3.0;

/// A view's value of a texel read from spans, against one read from clean pixels: the spans'
/// pixels mix parts of the surface at other angles, so where any view sees the texel cleanly
/// it dominates.
pub const LOOSE_WEIGHT: f32 = 0.1;

impl Span {
    /// Whether this span holds a point of `shape` at distance `d` from the camera, within
    /// `tol`.
    pub fn holds(&self, shape: u32, d: f32, tol: f32) -> bool {
        self.shape == shape && d >= self.near - tol && d <= self.far + tol
    }
}

/// Per pixel (row-major), whether a corner ray within reach of it (one pixel and the film
/// filter's reach) hits an emitter: an emitter is far brighter than what borders it, so even a
/// sliver of it ruins a pixel.
pub fn near_emitters(scene: &Scene, camera: &Camera, corners: &[Option<(Hit, Vec3)>]) -> Vec<bool> {
    let (w, h) = (camera.width(), camera.height());
    let gw = (w + 1) as usize;
    let emits = |gx: u32, gy: u32| {
        corners[gy as usize * gw + gx as usize]
            .is_some_and(|(hit, _)| scene.shapes[hit.shape as usize].emission.is_some())
    };
    let r = 1 + camera.filter().reach();
    let near = |x: u32, y: u32| {
        let (x0, y0) = (x.saturating_sub(r), y.saturating_sub(r));
        let (x1, y1) = ((x + r + 2).min(w + 1), (y + r + 2).min(h + 1));
        (y0..y1).any(|gy| (x0..x1).any(|gx| emits(gx, gy)))
    };
    (0..h)
        .flat_map(|y| (0..w).map(move |x| near(x, y)))
        .collect()
}

/// Every pixel's span (row-major), from the `(w + 1) x (h + 1)` corner hits of `camera` and
/// the pixels near an emitter ([`near_emitters`]).
pub fn spans(
    camera: &Camera,
    image: &Image,
    corners: &[Option<(Hit, Vec3)>],
    hot: &[bool],
) -> Vec<Option<Span>> {
    let (w, h) = (camera.width(), camera.height());
    let gw = (w + 1) as usize;
    let eye = camera.position();
    let one = |x: u32, y: u32| -> Option<Span> {
        let mut span: Option<Span> = None;
        for (gx, gy) in [(x, y), (x + 1, y), (x, y + 1), (x + 1, y + 1)] {
            let (hit, p) = corners[gy as usize * gw + gx as usize]?;
            let d = (p - eye).length();
            span = match span {
                None => Some(Span {
                    shape: hit.shape,
                    near: d,
                    far: d,
                }),
                Some(s) if s.shape == hit.shape => Some(Span {
                    near: s.near.min(d),
                    far: s.far.max(d),
                    ..s
                }),
                Some(_) => return None,
            };
        }
        let s = span?;
        let width = pixel_width(camera, x, y) * s.near;
        let ok = s.far - s.near <= MAX_SPREAD * width
            && image.is_valid(x, y)
            && !hot[(y * w + x) as usize];
        ok.then_some(s)
    };
    let spans: Vec<Option<Span>> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| one(x, y))
        .collect();
    widen_to_filter(spans, w, h, camera.filter().reach())
}

/// The width of pixel `(x, y)` at unit distance: the angle between its corner rays.
fn pixel_width(camera: &Camera, x: u32, y: u32) -> f32 {
    let a = camera.ray(x as f32, y as f32).1.normalize_or_zero();
    let b = camera.ray(x as f32 + 1.0, y as f32).1.normalize_or_zero();
    (a - b).length()
}

/// Per pixel, the union of the spans within `n` pixels if they all see the same shape, else
/// none (the pixel's value mixes theirs).
fn widen_to_filter(spans: Vec<Option<Span>>, w: u32, h: u32, n: u32) -> Vec<Option<Span>> {
    if n == 0 {
        return spans;
    }
    let (w, h, n) = (w as i64, h as i64, n as i64);
    let inside = |x: i64, y: i64| x >= 0 && y >= 0 && x < w && y < h;
    (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| {
            let mut out = spans[(y * w + x) as usize]?;
            for (dx, dy) in (-n..=n).flat_map(|dy| (-n..=n).map(move |dx| (dx, dy))) {
                let (nx, ny) = (x + dx, y + dy);
                if !inside(nx, ny) {
                    continue;
                }
                let s = spans[(ny * w + nx) as usize].filter(|s| s.shape == out.shape)?;
                out.near = out.near.min(s.near);
                out.far = out.far.max(s.far);
            }
            Some(out)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn span(shape: u32, near: f32, far: f32) -> Option<Span> {
        Some(Span { shape, near, far })
    }

    #[test]
    fn a_span_holds_points_of_its_shape_within_its_distances() {
        let s = span(3, 1.0, 1.1).unwrap();
        assert!(s.holds(3, 1.05, 0.0));
        assert!(s.holds(3, 0.999, 0.002));
        assert!(!s.holds(3, 1.2, 0.002), "behind it");
        assert!(!s.holds(2, 1.05, 0.002), "another shape");
    }

    #[test]
    fn a_filter_widens_spans_and_drops_those_beside_another_shape() {
        // 3 x 1 pixels: shape 0, shape 0, shape 1
        let s = vec![span(0, 1.0, 1.0), span(0, 2.0, 2.0), span(1, 1.0, 1.0)];
        let out = widen_to_filter(s.clone(), 3, 1, 1);
        assert_eq!(out[0], span(0, 1.0, 2.0));
        assert_eq!(out[1], None, "its neighbour sees shape 1");
        assert_eq!(out[2], None);
        assert_eq!(widen_to_filter(s.clone(), 3, 1, 0), s, "a box filter");
    }
}
