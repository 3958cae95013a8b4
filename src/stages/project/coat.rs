//! The coat's reflection taken out of the photos of coated shapes before they are projected:
//! per pixel whose centre sees a coated shape, `(photo - L_coat) / T_o`, the base's radiance
//! as a Lambertian surface under the light its coat lets in (see `physics::coat`); a pixel
//! whose value is mostly a smooth coat's reflection is masked instead.
//!
//! `L_coat` is the coat's reflection of the scene along the pixel's ray: the mirror direction
//! of a smooth coat, a stratified set of lobe samples of a rough one (random numbers keyed by
//! view and pixel). Each direction sees an emitter (its radiance), the environment, or a
//! surface, whose radiance is read from the photos: the mean of the (calibrated) pixels of the
//! views that see that point unoccluded, else the mean of the pixels that see its shape (a
//! rough coat reads surfaces on a stratified quarter of its samples, see [`incoming`]). A
//! rough coat's glossy image of the lights is integrated over them instead (the area lights'
//! points of `physics::coat::patches` with shadow rays, point, spot and directional lights
//! exactly), which a few lobe samples would make noisy. So the coat's reflection is predicted
//! once, from the photos rather than from the current albedo.
//!
//! Which views see a surface point is read from the views' classification (a clean pixel sees
//! one plane of one shape: the point is seen where it lies on that plane), and a ray is cast
//! only where the pixel it falls in is not clean (an edge, a masked pixel); which shape a
//! pixel's centre sees, likewise. Living room: projection rays 132.6M -> 76.9M, held-out albedo
//! unchanged (20.45%).

use super::view::View;
use crate::atlas::RunContext;
use crate::base::rng::Rng;
use crate::image::Image;
use crate::physics::accel::{offset_origin, Hit};
use crate::physics::camera::Camera;
use crate::physics::coat::{self, Coat, Patch};
use crate::physics::light::spot_falloff_towards;
use crate::scene::{luminance, Emitter, Scene};
use glam::{Vec2, Vec3};
use rayon::prelude::*;

/// Mixed into the seed of the rough coats' lobe samples.
const COAT_TAG: u64 = 0xc0a7_5eed_0000_0001;

/// What the coat's reflection needs to see the scene: the run, its views (cameras and
/// classified pixels) and calibrated photos, and per shape the mean of the pixels that see it.
struct Seen<'a> {
    p: &'a RunContext,
    views: &'a [View<'a>],
    photos: &'a [Image],
    shape_mean: Vec<Vec3>,
    /// Per emitter, its points (area lights; see `physics::coat::patches`).
    patches: Vec<Vec<Patch>>,
}

/// `photos` (calibrated, one per view of `p`; `views` classify them) with the coat's
/// reflection removed from the pixels that see a coated shape; `None` when the scene has no
/// coated shape.
pub fn remove(p: &RunContext, photos: &[Image], views: &[View], seed: u64) -> Option<Vec<Image>> {
    let coats = coat::coats(&p.scene);
    if !coat::any(&coats) {
        return None;
    }
    let shape_mean = shape_means(p, views, photos);
    let patches = (p.scene.emitters.iter())
        .map(|e| coat::patches(&p.scene, e))
        .collect();
    let seen = Seen {
        p,
        views,
        photos,
        shape_mean,
        patches,
    };
    let out = (0..photos.len())
        .map(|v| view(&seen, &coats, v, seed))
        .collect();
    Some(out)
}

/// The closest hit of the ray through the centre of pixel `(x, y)` of `camera`.
fn centre_hit(p: &RunContext, camera: &Camera, x: u32, y: u32) -> (Vec3, Vec3, Option<Hit>) {
    let (o, d) = camera.ray(x as f32 + 0.5, y as f32 + 0.5);
    (o, d, p.accel.intersect(o, d, f32::INFINITY))
}

/// Per shape, the mean of the valid pixels whose centre sees it (the views' classification),
/// over every view.
fn shape_means(p: &RunContext, views: &[View], photos: &[Image]) -> Vec<Vec3> {
    let n = p.scene.shapes.len();
    let mut sum = vec![(Vec3::ZERO, 0u64); n];
    for (view, ph) in views.iter().zip(photos) {
        let w = ph.width as usize;
        for (i, px) in view.pixels.iter().enumerate() {
            let (x, y) = ((i % w) as u32, (i / w) as u32);
            if let Some(s) = px.seen_shape().filter(|_| ph.is_valid(x, y)) {
                sum[s as usize].0 += ph.get(x, y);
                sum[s as usize].1 += 1;
            }
        }
    }
    sum.iter()
        .map(|(s, c)| if *c > 0 { *s / *c as f32 } else { Vec3::ZERO })
        .collect()
}

/// A smooth coat's pixel whose predicted reflection is more than this share of its value is
/// left out (masked): its base is a small difference of two large numbers, and the
/// prediction, made at the pixel's centre, misses where a sharp reflection (a lamp's image in
/// a gloss coat) covers only part of the pixel. A rough coat's pixels are never masked: its
/// prediction is a few lobe samples, and masking the pixels where it came out high keeps
/// those where it came out low (a bright window the samples missed), whose base then reads
/// too bright: a varnished floor under a sky came out speckled white.
const DOMINANT: f32 = 0.5;

/// One view's photo with the coat's reflection removed from its coated pixels.
fn view(seen: &Seen, coats: &[Option<Coat>], v: usize, seed: u64) -> Image {
    let ph = &seen.photos[v];
    let (cam, pixels) = (&seen.views[v].camera, &seen.views[v].pixels);
    // the shape a pixel's centre sees, as the centre ray of `base` finds it
    let coated = |i: usize| (pixels[i].seen_shape()).is_some_and(|s| coats[s as usize].is_some());
    let mut out = ph.clone();
    let w = ph.width as usize;
    (out.pixels.par_chunks_mut(w))
        .zip(out.valid.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, (row, valid))| {
            for (x, (px, ok)) in row.iter_mut().zip(valid.iter_mut()).enumerate() {
                if !*ok || !coated(y * w + x) {
                    continue;
                }
                let key = (y * w + x) as u64;
                let mut rng = Rng::new(seed ^ COAT_TAG, v as u64, 0, key);
                let Some((l_coat, t_o, smooth)) =
                    base(seen, coats, cam, (x as u32, y as u32), &mut rng)
                else {
                    continue;
                };
                if smooth && luminance(l_coat) > DOMINANT * luminance(*px) {
                    (*px, *ok) = (Vec3::ZERO, false);
                } else {
                    *px = (*px - l_coat).max(Vec3::ZERO) / t_o;
                }
            }
        });
    out.masked = out.valid.iter().filter(|v| !**v).count();
    out
}

/// The coat's reflection, `T_o` and whether the coat is smooth at pixel `(x, y)`, if its
/// centre sees the front of a coated shape.
fn base(
    seen: &Seen,
    coats: &[Option<Coat>],
    cam: &Camera,
    (x, y): (u32, u32),
    rng: &mut Rng,
) -> Option<(Vec3, f32, bool)> {
    let (o, d, hit) = centre_hit(seen.p, cam, x, y);
    let hit = hit?;
    let c = coats[hit.shape as usize].as_ref()?;
    let mesh = &seen.p.scene.shapes[hit.shape as usize].mesh;
    let ns = mesh.shading_normal(hit.tri as usize, hit.b1, hit.b2);
    let ng = mesh.face_normal_raw(hit.tri as usize).normalize_or_zero();
    let wi = -d;
    if wi.dot(ns) <= 0.0 || wi.dot(ng) <= 0.0 {
        return None;
    }
    let at = o + d * hit.t;
    let rough = c.rough.is_some();
    let mut l_coat = Vec3::ZERO;
    // surfaces cost a look-up in each view: read on the coarse sub-grid only, at its weight
    for ((dir, w), surface) in c.reflection_split(wi, ns, rng) {
        l_coat += w * incoming(seen, offset_origin(at, ng, dir), dir, rough, surface);
    }
    if rough {
        l_coat += lights(seen, c, (at, ng, ns), wi);
    }
    Some((l_coat, c.base_out(wi.dot(ns)).max(1e-3), !rough))
}

/// The radiance arriving at `o` from direction `dir`: an emitter's (zero with `no_area`: it is
/// integrated apart), the environment's, or a surface's as the photos saw it times `surface`
/// (not read at all when 0). A rough coat reads surfaces on the coarse quarter of its lobe
/// samples ([`Coat::reflection_split`]), the environment and the emitters on all: the bright
/// sky through a window is what the samples must not miss, while a surface costs a look-up
/// in each view (and a ray where its pixel there is not clean). Living room, when a surface
/// cost a ray to each camera: held-out albedo 22.9% with every sample reading surfaces, 23.1%
/// with a quarter, for 334M and 133M projection rays (16 samples: 33.1%, 93M).
fn incoming(seen: &Seen, o: Vec3, dir: Vec3, no_area: bool, surface: f32) -> Vec3 {
    let scene = &seen.p.scene;
    let Some(hit) = seen.p.accel.intersect(o, dir, f32::INFINITY) else {
        return environment(scene, dir);
    };
    let shape = &scene.shapes[hit.shape as usize];
    let n = shape.mesh.shading_normal(hit.tri as usize, hit.b1, hit.b2);
    if let Some(radiance) = shape.emission {
        return match n.dot(dir) < 0.0 && !no_area {
            true => radiance,
            false => Vec3::ZERO,
        };
    }
    if surface == 0.0 {
        return Vec3::ZERO;
    }
    let at = o + dir * hit.t;
    let ng = shape
        .mesh
        .face_normal_raw(hit.tri as usize)
        .normalize_or_zero();
    let l = photographed(seen, at, hit.shape, ng).unwrap_or(seen.shape_mean[hit.shape as usize]);
    surface * l
}

/// A rough coat's glossy reflection towards `wi` of the point, spot, directional and area
/// lights at point `at` (geometric normal `ng`, shading normal `ns`), with shadow rays.
fn lights(seen: &Seen, c: &Coat, (at, ng, ns): (Vec3, Vec3, Vec3), wi: Vec3) -> Vec3 {
    let accel = &seen.p.accel;
    let lit =
        |w: Vec3, dist: f32| !accel.occluded(offset_origin(at, ng, w), w, dist * (1.0 - 1e-4));
    let mut sum = Vec3::ZERO;
    for (k, e) in seen.p.scene.emitters.iter().enumerate() {
        match e {
            Emitter::Point {
                position,
                intensity,
            } => {
                let (w, r) = unit_and_length(*position - at);
                if lit(w, r) {
                    sum += c.glossy(wi, w, ns) * *intensity / (r * r);
                }
            }
            Emitter::Spot {
                position,
                axis,
                intensity,
                cutoff,
                beam_width,
                ..
            } => {
                let (w, r) = unit_and_length(*position - at);
                let fall = spot_falloff_towards(*axis, w, *cutoff, *beam_width);
                if fall > 0.0 && lit(w, r) {
                    sum += c.glossy(wi, w, ns) * *intensity * fall / (r * r);
                }
            }
            Emitter::Directional {
                direction,
                irradiance,
            } => {
                if lit(-*direction, f32::INFINITY) {
                    sum += c.glossy(wi, -*direction, ns) * *irradiance;
                }
            }
            Emitter::Area { radiance, .. } => {
                for &(q, nq, a) in &seen.patches[k] {
                    let (w, r) = unit_and_length(q - at);
                    let cl = -w.dot(nq);
                    if cl > 0.0 && w.dot(ns) > 0.0 && lit(w, r) {
                        sum += c.glossy(wi, w, ns) * *radiance * (cl * a / (r * r));
                    }
                }
            }
            Emitter::Environment(_) => {}
        }
    }
    sum
}

/// `v` as a unit direction and its length.
fn unit_and_length(v: Vec3) -> (Vec3, f32) {
    let r = v.length().max(1e-12);
    (v / r, r)
}

/// The mean calibrated pixel of the views that see point `at` of shape `shape` (geometric
/// normal `n`) first: from the view's classification where the pixel it falls in is clean,
/// else by a ray from the camera.
fn photographed(seen: &Seen, at: Vec3, shape: u32, n: Vec3) -> Option<Vec3> {
    let (mut sum, mut count) = (Vec3::ZERO, 0u32);
    for (view, ph) in seen.views.iter().zip(seen.photos) {
        let cam = &view.camera;
        let Some(px) = cam.project(at).filter(|q| cam.on_film(*q)) else {
            continue;
        };
        let (x, y) = pixel(px, ph);
        let first = view
            .sees_first((x, y), at, shape, n)
            .unwrap_or_else(|| traced_first(seen, cam, at, shape));
        if first && ph.is_valid(x, y) {
            sum += ph.get(x, y);
            count += 1;
        }
    }
    (count > 0).then(|| sum / count as f32)
}

/// Whether the ray from `cam` to point `at` first meets `shape` there.
fn traced_first(seen: &Seen, cam: &Camera, at: Vec3, shape: u32) -> bool {
    let from = cam.position();
    let dist = (at - from).length();
    let hit = (seen.p.accel).intersect(from, (at - from) / dist, f32::INFINITY);
    hit.is_some_and(|h| h.shape == shape && (h.t - dist).abs() < 1e-3 * dist + 1e-4)
}

/// The pixel continuous coordinates `q` fall in, clamped to the photo.
fn pixel(q: Vec2, ph: &Image) -> (u32, u32) {
    let x = (q.x.max(0.0) as u32).min(ph.width - 1);
    let y = (q.y.max(0.0) as u32).min(ph.height - 1);
    (x, y)
}

/// The environment emitters' radiance along `dir`.
fn environment(scene: &Scene, dir: Vec3) -> Vec3 {
    (scene.emitters.iter())
        .filter_map(|e| match e {
            Emitter::Environment(env) => Some(env.eval(dir)),
            _ => None,
        })
        .fold(Vec3::ZERO, |a, b| a + b)
}
