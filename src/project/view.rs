//! A photo as the projection reads it: its pixels classified with primary rays (clean pixels
//! see one plane of one shape, away from emitters) and sampled only where they are clean.

use crate::accel::Accel;
use crate::camera::Camera;
use crate::image::Image;
use crate::scene::Scene;
use glam::{Vec2, Vec3};
use rayon::prelude::*;

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
}
/// Primary-ray grid points per pixel side used to classify pixels (the grid has spacing
/// `1 / CLASSIFY_SUBDIV` pixel and includes every pixel's corners). 2 (adding edge midpoints
/// and centers) changed nothing measurable on the fixtures, so the corners suffice.
pub const CLASSIFY_SUBDIV: u32 = 1;
/// Pixel rows classified per band (bounds the grid held in memory to a band).
const CLASSIFY_BAND: u32 = 64;

/// Classify every pixel of `image` as seen by `camera`. A pixel is clean when every point of
/// a `CLASSIFY_SUBDIV`-per-pixel grid over it (its four corners for 1) lands on the plane of
/// the shape hit at its center, no grid point within one pixel of it lands on an emitter, and
/// its value is valid. The emitter guard is there because an emitter is orders of magnitude
/// brighter than what borders it, so even a sliver of it between the rays ruins the pixel: in
/// both fixtures' cam_train_0 a corner of the light slipped between the corner rays of a
/// ceiling pixel (1.3 against 0.09 around it) and streaked the ceiling's luminance map.
pub fn classify_pixels(
    scene: &Scene,
    accel: &Accel,
    camera: &Camera,
    image: &Image,
) -> Vec<PixelInfo> {
    let (w, h) = (camera.width(), camera.height());
    let n = CLASSIFY_SUBDIV;
    let gw = (w * n + 1) as usize;
    let emits = |s: u32| scene.shapes[s as usize].emission.is_some();
    let mut out = Vec::with_capacity((w * h) as usize);
    for y0 in (0..h).step_by(CLASSIFY_BAND as usize) {
        let y1 = (y0 + CLASSIFY_BAND).min(h);
        // grid rows of pixel rows y0 - 1 .. y1 + 1 (the emitter guard looks one pixel out)
        let (py0, py1) = (y0.saturating_sub(1), (y1 + 1).min(h));
        let (gy0, gy1) = (py0 * n, py1 * n);
        let grid: Vec<Option<(u32, Vec3)>> = (gy0..=gy1)
            .into_par_iter()
            .flat_map_iter(|gy| {
                (0..gw).map(move |gx| {
                    let (o, d) = camera.ray(gx as f32 / n as f32, gy as f32 / n as f32);
                    accel
                        .intersect(o, d, f32::INFINITY)
                        .map(|hit| (hit.shape, o + d * hit.t))
                })
            })
            .collect();
        let at = |gx: u32, gy: u32| grid[(gy - gy0) as usize * gw + gx as usize];
        // per pixel of rows py0..py1: whether any of its grid points hits an emitter
        let touches: Vec<bool> = (py0..py1)
            .into_par_iter()
            .flat_map_iter(|y| {
                (0..w).map(move |x| {
                    (y * n..=(y + 1) * n).any(|gy| {
                        (x * n..=(x + 1) * n).any(|gx| at(gx, gy).is_some_and(|(s, _)| emits(s)))
                    })
                })
            })
            .collect();
        let near_emitter = |x: u32, y: u32| {
            (y.saturating_sub(1)..(y + 2).min(h)).any(|ny| {
                (x.saturating_sub(1)..(x + 2).min(w))
                    .any(|nx| touches[((ny - py0) * w + nx) as usize])
            })
        };
        let band: Vec<PixelInfo> = (y0..y1)
            .into_par_iter()
            .flat_map_iter(|y| {
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
                    let nrm = mesh.face_normal_raw(hit.tri as usize).normalize_or_zero();
                    let c = o + d * hit.t;
                    let tol = 1e-3 * hit.t + 1e-6;
                    let coplanar = (y * n..=(y + 1) * n).all(|gy| {
                        (x * n..=(x + 1) * n).all(|gx| match at(gx, gy) {
                            Some((s, p)) => s == hit.shape && (p - c).dot(nrm).abs() <= tol,
                            None => false,
                        })
                    });
                    PixelInfo {
                        shape: hit.shape,
                        normal: nrm,
                        clean: coplanar && !near_emitter(x, y) && image.is_valid(x, y),
                    }
                })
            })
            .collect();
        out.extend(band);
    }
    out
}

impl<'a> View<'a> {
    pub fn new(scene: &Scene, accel: &Accel, camera: Camera, image: &'a Image) -> View<'a> {
        let pixels = classify_pixels(scene, accel, &camera, image);
        View {
            camera,
            image,
            pixels,
        }
    }

    /// The same camera and pixel classification reading the values of `image` (same size),
    /// e.g. a residual, which may be negative.
    pub fn with_image<'b>(&self, image: &'b Image) -> View<'b> {
        assert_eq!(image.pixels.len(), self.pixels.len());
        View {
            camera: self.camera.clone(),
            image,
            pixels: self.pixels.clone(),
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
        let fx = pix.x - 0.5;
        let fy = pix.y - 0.5;
        let (x0, y0) = (fx.floor() as i64, fy.floor() as i64);
        let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
        let quad = [(x0, y0), (x0 + 1, y0), (x0, y0 + 1), (x0 + 1, y0 + 1)];
        if quad.iter().all(|&(x, y)| self.usable(x, y, shape, n)) {
            let g = |x: i64, y: i64| self.image.get(x as u32, y as u32);
            let top = g(x0, y0) * (1.0 - tx) + g(x0 + 1, y0) * tx;
            let bot = g(x0, y0 + 1) * (1.0 - tx) + g(x0 + 1, y0 + 1) * tx;
            return Some(top * (1.0 - ty) + bot * ty);
        }
        let (x, y) = (pix.x.floor() as i64, pix.y.floor() as i64);
        self.usable(x, y, shape, n)
            .then(|| self.image.get(x as u32, y as u32))
    }
}
