//! Projection of the photos onto the atlas (method step 2, eq. 1): for every texel a camera
//! sees, a weighted mean of the photo's radiance, `L_orig = sum w_i L_i / sum w_i`, then a few
//! refinement passes that make the map agree with every photo at once.
//!
//! Per view we first classify the photo's pixels with primary rays (see [`classify_pixels`]):
//! a pixel is *clean* when a grid of rays over it all land on one plane of one shape (so it
//! straddles no silhouette, depth edge or crease), no emitter lies within a pixel of it, and its
//! value is valid. A texel is then observed through k x k sub-samples of its footprint (k grows
//! with texel size / pixel footprint, so a texel much larger than a pixel gets an area average,
//! not a point sample). Each sub-sample must be front-facing, unoccluded (a ray from the camera
//! reaches it first) and land on clean pixels of the same surface; it reads the photo
//! bilinearly, or the nearest pixel at the edge of a clean region. The weight
//! `w = (accepted fraction) * A_texel / A_pixel` counts how many pixels' worth of measurement
//! the texel received, so it accounts for distance, viewing angle and pixel footprint together.
//!
//! **Why refinement.** The weighted mean is a blurred estimate of the surface radiance, and
//! differently blurred in each view: the bilinear lookup adds a one-pixel tent to each pixel's
//! box footprint, the map's own texels (area means, read back bilinearly) add their size, and a
//! view seeing the surface at a grazing angle or from afar averages many texels per pixel, which
//! the mean mixes into the sharper views' detail. Re-rendered, such a map agrees with no photo
//! exactly: on cbox-tex (textured walls and ceiling, 128 texels per unit) the 8x8-block means
//! differed from the photos by 2.1/1.1/1.5% in the three views, and by 1.3/0.9/0.9% even with a
//! single view projected and re-rendered into itself (noise-free synthetic photos of the true
//! textures give the same figures, so neither noise nor lighting is the cause). [`refine`] runs
//! iterative back-projection (SIRT): render every view from the current map, back-project the
//! residual `photo - render` with the same lookups and weights, add `sum w_i r_i / sum w_i`,
//! clamp at zero. Each pass moves the map towards the least-squares solution of "render(map) =
//! photo in every view": detail that some view resolves is restored, averaging stays where
//! views agree. Residuals are soft-thresholded at the photos' noise level first
//! ([`shrink_residual`]), so the passes do not fit each photo's noise into the map.

use crate::accel::Accel;
use crate::atlas::layout::{flags, TexelGeom, TexelState};
use crate::atlas::texels::dilate;
use crate::atlas::tiles::TileStore;
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::image::{read_sensor_image, Image};
use crate::pipeline::{gather, Prepared};
use crate::progress::{Mode, Stage};
use crate::render::{render_view, Texture};
use crate::scene::{Mesh, Scene, Sides};
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use std::sync::Mutex;

/// The largest sub-sample grid per texel and view (k x k).
pub const MAX_SUBSAMPLES: u32 = 8;
/// Sub-samples per pixel side a texel covers.
const SUBSAMPLES_PER_PIXEL: f32 = 1.0;
/// Texels seen more grazing than this cosine are not used.
pub const MIN_COS: f32 = 0.05;
/// Refinement passes run by [`refine`] after the weighted mean. On cbox-tex (128 texels per
/// unit) the mean 8x8-block re-projection error goes from 2.1/1.1/1.5% (no pass) to
/// 1.0/0.7/0.9% (one) and 0.7/0.6/0.6% (three); each pass costs about one projection.
pub const REFINE_PASSES: u32 = 3;
/// Sub-pixel rays per side when a view is re-rendered for refinement (a box pixel filter).
pub const REFINE_SUPERSAMPLE: u32 = 4;
/// Residuals are soft-thresholded at this many noise standard deviations before they are
/// back-projected (see [`shrink_residual`]).
pub const RESIDUAL_SHRINK: f32 = 1.0;
/// Texels of dilation around observed texels before re-rendering, as for written maps.
const REFINE_DILATE: u32 = 4;

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
    // Sub-samples per side: about one per pixel the texel covers. (Per-axis counts from the
    // projected texel edges were measured too: no change, so the area rule stays.)
    let k = ((ratio.sqrt() * SUBSAMPLES_PER_PIXEL).ceil() as u32).clamp(1, MAX_SUBSAMPLES);
    let mut sum = Vec3::ZERO;
    let mut accepted = 0u32;
    for j in 0..k {
        for i in 0..k {
            let ox = (i as f32 + 0.5) / k as f32 - 0.5;
            let oy = (j as f32 + 0.5) / k as f32 - 0.5;
            let q = if k == 1 { p } else { p + dx * ox + dy * oy };
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
    let frac = accepted as f32 / (k * k) as f32;
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

/// Back-project one view's residual into one tile: `delta += w r` over the texels the view
/// observes (`view` reads the residual image; the weights are those of [`project_tile`]).
pub fn backproject_tile(
    view: &View,
    accel: &Accel,
    shape: &ShapeRef,
    geom: &[TexelGeom],
    delta: &mut [Vec3],
) {
    for (g, d) in geom.iter().zip(delta.iter_mut()) {
        if !g.covered() {
            continue;
        }
        if let Some((r, w)) = observe_texel(view, accel, shape, g) {
            *d += w * r;
        }
    }
}

/// After a pass over all views: `l_orig += delta / weight` (the weighted mean of the views'
/// residuals, as the weights of all views sum to `weight`), clamped at zero.
pub fn apply_refinement(state: &mut [TexelState], delta: &[Vec3]) {
    for (s, d) in state.iter_mut().zip(delta) {
        if s.weight > 0.0 {
            for c in 0..3 {
                s.l_orig[c] = (s.l_orig[c] + d[c] / s.weight).max(0.0);
            }
        }
    }
}

/// Soft-threshold a residual image at `RESIDUAL_SHRINK` times its noise level: every clean
/// pixel's residual `r` (judged on its channel sum, relative to the photo's) shrinks towards
/// zero by `RESIDUAL_SHRINK * sigma * photo`, where `sigma` is the median relative residual
/// over clean pixels scaled to a standard deviation (1.4826 x MAD): a robust estimate of the
/// photo noise, since most pixels are noise-dominated. Refinement then corrects disagreements
/// larger than the noise (blurred texture edges) without fitting each photo's noise, which
/// would make the map grainier with every pass. Photos without noise get `sigma` near zero and
/// are left as they are.
pub fn shrink_residual(residual: &mut [Vec3], photo: &[Vec3], pixels: &[PixelInfo]) {
    let rel = |r: &Vec3, p: &Vec3| r.element_sum().abs() / p.element_sum();
    let mut rels: Vec<f32> = residual
        .iter()
        .zip(photo)
        .zip(pixels)
        .filter(|((_, p), px)| px.clean && p.element_sum() > 0.0)
        .map(|((r, p), _)| rel(r, p))
        .filter(|v| v.is_finite())
        .collect();
    if rels.is_empty() {
        return;
    }
    let mid = rels.len() / 2;
    let sigma = 1.4826 * *rels.select_nth_unstable_by(mid, f32::total_cmp).1;
    for (r, p) in residual.iter_mut().zip(photo) {
        let (a, t) = (
            r.element_sum().abs(),
            RESIDUAL_SHRINK * sigma * p.element_sum().abs(),
        );
        *r = if a > t && a > 0.0 {
            *r * ((a - t) / a)
        } else {
            Vec3::ZERO
        };
    }
}

/// Every reconstructed shape's current luminance map (unobserved and gutter texels filled by
/// dilation, as written maps are), indexed by shape.
fn current_maps(
    p: &Prepared,
    geom: &TileStore<TexelGeom>,
    state: &TileStore<TexelState>,
) -> Result<Vec<Option<Vec<Vec3>>>> {
    let mut maps: Vec<Option<Vec<Vec3>>> = (0..p.scene.shapes.len()).map(|_| None).collect();
    for (slot, st) in p.layout.slots.iter().enumerate() {
        let (mut vals, _) = gather(p, slot, state, geom, |s| Vec3::from_array(s.l_orig))?;
        let (wt, _) = gather(p, slot, state, geom, |s| Vec3::splat(s.weight))?;
        let observed: Vec<bool> = wt.iter().map(|v| v.x > 0.0).collect();
        dilate(&mut vals, &observed, st.width, st.height, REFINE_DILATE)?;
        maps[st.shape] = Some(vals);
    }
    Ok(maps)
}

/// Iterative back-projection after [`finish_tile`]: `passes` times, re-render every view from
/// the current maps, back-project the residuals `photo - render` (clean pixels only) and add
/// their weighted mean to `l_orig` (see the module notes). Reads each photo once per pass;
/// holds the maps and one residual per texel in memory while it runs.
pub fn refine(
    p: &Prepared,
    geom: &TileStore<TexelGeom>,
    state: &mut TileStore<TexelState>,
    window: usize,
    passes: u32,
    mode: Mode,
) -> Result<()> {
    if passes == 0 {
        return Ok(());
    }
    let stage = Stage::new(
        mode,
        "refinement",
        passes as u64 * p.views.len() as u64,
        "views",
    );
    let tile_texels = p.layout.tile_texels();
    for _ in 0..passes {
        let maps = current_maps(p, geom, state)?;
        let textures: Vec<Option<Texture>> = maps
            .iter()
            .enumerate()
            .map(|(i, m)| {
                let m = m.as_ref()?;
                let slot = p.layout.slot_of_shape(i)?;
                let st = &p.layout.slots[slot];
                Some(Texture {
                    width: st.width,
                    height: st.height,
                    texels: m,
                    corner_uv: &p.atlases[i].as_ref()?.corner_uv,
                })
            })
            .collect();
        let mut delta: Vec<Vec<Vec3>> = vec![Vec::new(); p.layout.tile_count as usize];
        for (si, path) in &p.views {
            let sensor = &p.scene.sensors[*si];
            let photo = read_sensor_image(path, sensor)?;
            let camera = Camera::from_sensor(sensor);
            let view = View::new(&p.scene, &p.accel, camera, &photo);
            let render = render_view(&p.accel, &view.camera, &textures, REFINE_SUPERSAMPLE);
            let mut residual: Vec<Vec3> = photo
                .pixels
                .iter()
                .zip(&render)
                .zip(&view.pixels)
                .map(|((ph, r), px)| match r {
                    Some(r) if px.clean => *ph - *r,
                    _ => Vec3::ZERO,
                })
                .collect();
            shrink_residual(&mut residual, &photo.pixels, &view.pixels);
            let residual = Image {
                width: photo.width,
                height: photo.height,
                pixels: residual,
                valid: photo.valid.clone(),
                masked: photo.masked,
            };
            let rview = view.with_image(&residual);
            let err: Mutex<Option<Error>> = Mutex::new(None);
            delta.par_iter_mut().enumerate().for_each(|(t, d)| {
                let g = match geom.read_tile(t) {
                    Ok(g) => g,
                    Err(e) => {
                        *err.lock().unwrap_or_else(|e| e.into_inner()) = Some(e);
                        return;
                    }
                };
                if !g.iter().any(|g| g.covered()) {
                    return;
                }
                if d.is_empty() {
                    *d = vec![Vec3::ZERO; tile_texels];
                }
                let slot = p.layout.slot_of_tile(t as u32);
                backproject_tile(&rview, &p.accel, &p.shape_ref(slot), &g, d);
            });
            if let Some(e) = err.into_inner().unwrap_or_else(|e| e.into_inner()) {
                return Err(e);
            }
            stage.inc(1);
        }
        state.for_each_tile_mut(window, |t, st| {
            if !delta[t].is_empty() {
                apply_refinement(st, &delta[t]);
            }
        })?;
    }
    stage.finish();
    Ok(())
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

    #[test]
    fn shrinking_drops_noise_sized_residuals_and_keeps_large_ones() {
        let clean = PixelInfo {
            shape: 0,
            normal: Vec3::Y,
            clean: true,
        };
        let n = 101;
        let photo = vec![Vec3::splat(2.0); n];
        // relative residuals +-1% on 100 pixels (sigma = 1.4826%), one of 50%
        let mut r: Vec<Vec3> = (0..n)
            .map(|i| Vec3::splat(if i % 2 == 0 { 0.02 } else { -0.02 }))
            .collect();
        r[7] = Vec3::splat(1.0);
        let mut pixels = vec![clean; n];
        pixels[3].clean = false;
        shrink_residual(&mut r, &photo, &pixels);
        assert_eq!(r[0], Vec3::ZERO);
        assert_eq!(r[1], Vec3::ZERO);
        let want = 1.0 - RESIDUAL_SHRINK * 0.014826 * 2.0;
        assert!((r[7].x - want).abs() < 1e-4, "{}", r[7]);
        // noise-free photos: residuals left alone
        let mut r = vec![Vec3::ZERO; n];
        r[7] = Vec3::splat(1.0);
        shrink_residual(&mut r, &photo, &pixels);
        assert_eq!(r[7], Vec3::splat(1.0));
    }

    #[test]
    fn refinement_adds_the_weighted_mean_residual_and_clamps_at_zero() {
        let mut st = [TexelState::default(); 3];
        st[0].l_orig = [1.0, 1.0, 1.0];
        st[0].weight = 2.0;
        st[1].l_orig = [0.1, 0.1, 0.1];
        st[1].weight = 1.0;
        let d = [
            Vec3::new(1.0, -1.0, 0.0),
            Vec3::splat(-0.5),
            Vec3::splat(5.0),
        ];
        apply_refinement(&mut st, &d);
        assert_eq!(st[0].l_orig, [1.5, 0.5, 1.0]);
        assert_eq!(st[1].l_orig, [0.0; 3]);
        assert_eq!(st[2].l_orig, [0.0; 3], "unobserved texels stay as they are");
    }
}
