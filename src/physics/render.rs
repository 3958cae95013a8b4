//! Looking at texture-space results through a camera: sub-pixel primary rays, the hit's atlas
//! coordinates, a bilinear texture lookup. Used to re-render the input views from recovered
//! maps (outputs), by the projection's refinement, and to check projection (a luminance map
//! re-projected must give back the photo).

use crate::base::rng::Rng;
use crate::image::Image;
use crate::physics::accel::{offset_origin, Accel, Hit};
use crate::physics::bsdf_sampling;
use crate::physics::camera::Camera;
use crate::scene::{Emitter, PixelFilter, Scene, Sides};
use glam::{Vec2, Vec3, Vec3A};
use rayon::prelude::*;

/// Texels a renderer can look up: `width x height` linear RGB, row 0 = top. Implemented by
/// the atlas's slot textures (whole or tiled) and by a plain row-major slice ([`RowMajor`]).
pub trait Texels: Sync {
    fn width(&self) -> u32;
    fn height(&self) -> u32;
    /// Texel `(x, y)`, inside the texture.
    fn texel(&self, x: u32, y: u32) -> Vec3;
    /// Every texel, row-major, where they are held that way (lookups then index the slice).
    fn row_major(&self) -> Option<&[Vec3]> {
        None
    }
    /// A block of held texels that includes columns `x0..=x1` of rows `y0..=y1`, where the
    /// texture keeps its texels in blocks (tiles) and those lie in one: one look-up for the
    /// texels around a point instead of one per texel. `None` otherwise (the default).
    fn held_block(&self, _x0: u32, _y0: u32, _x1: u32, _y1: u32) -> Option<Block> {
        None
    }
}

/// Texels `(ox + i, oy + j)` at `texels[j * stride + i]`, `stride` columns and as many rows
/// as `texels` holds (see [`Texels::held_block`]).
pub struct Block {
    pub texels: std::sync::Arc<Vec<Vec3>>,
    pub stride: u32,
    pub origin: (u32, u32),
}

impl Block {
    /// Texel `(x, y)` if the block holds it.
    #[inline]
    fn get(&self, x: u32, y: u32) -> Option<Vec3> {
        let (i, j) = (x.wrapping_sub(self.origin.0), y.wrapping_sub(self.origin.1));
        let at = j as usize * self.stride as usize + i as usize;
        (i < self.stride).then(|| self.texels.get(at).copied())?
    }
}

/// Texel `(x, y)` of `texels`, from `block` when it holds it (the same value either way).
#[inline]
fn texel_via(texels: &dyn Texels, block: Option<&Block>, x: u32, y: u32) -> Vec3 {
    match block.and_then(|b| b.get(x, y)) {
        Some(v) => v,
        None => texels.texel(x, y),
    }
}

/// A row-major `width x height` slice as [`Texels`].
pub struct RowMajor<'a> {
    pub width: u32,
    pub height: u32,
    pub texels: &'a [Vec3],
}

impl Texels for RowMajor<'_> {
    fn width(&self) -> u32 {
        self.width
    }
    fn height(&self) -> u32 {
        self.height
    }
    #[inline]
    fn texel(&self, x: u32, y: u32) -> Vec3 {
        self.texels[(y * self.width + x) as usize]
    }
    fn row_major(&self) -> Option<&[Vec3]> {
        Some(self.texels)
    }
}

impl Texels for Image {
    fn width(&self) -> u32 {
        self.width
    }
    fn height(&self) -> u32 {
        self.height
    }
    #[inline]
    fn texel(&self, x: u32, y: u32) -> Vec3 {
        self.pixels[(y * self.width + x) as usize]
    }
    fn row_major(&self) -> Option<&[Vec3]> {
        Some(&self.pixels)
    }
}

/// A per-shape texture and the shape's atlas coordinates.
pub struct Texture<'a> {
    pub texels: &'a dyn Texels,
    /// Per-triangle corner coordinates in texel units (the shape's atlas).
    pub corner_uv: &'a [[Vec2; 3]],
}

/// Bilinear lookup at continuous texel coordinates (texel (i, j) has its center at
/// (i + 0.5, j + 0.5)), clamped to the texture.
pub fn bilinear(texels: &dyn Texels, uv: Vec2) -> Vec3 {
    let (width, height) = (texels.width(), texels.height());
    match texels.row_major() {
        Some(v) => bilinear_with(width, height, uv, |x, y| v[(y * width + x) as usize]),
        None => {
            let at = taps(width, height, uv);
            let (_, (x0, y0, x1, y1)) = at;
            let block = texels.held_block(x0, y0, x1, y1);
            bilinear_at(at, |x, y| texel_via(texels, block.as_ref(), x, y))
        }
    }
}

/// The clamped position of a bilinear look-up in texel centres and its four texels' columns
/// and rows, `(x0, y0, x1, y1)` ([`taps`]).
type Taps = ((f32, f32), (u32, u32, u32, u32));

/// Where a bilinear look-up at `uv` reads: the clamped position in texel centres and the
/// columns and rows of its four texels, `(x0, y0, x1, y1)`.
#[inline(always)]
fn taps(width: u32, height: u32, uv: Vec2) -> Taps {
    let fx = (uv.x - 0.5).clamp(0.0, (width - 1) as f32);
    let fy = (uv.y - 0.5).clamp(0.0, (height - 1) as f32);
    // non-negative after the clamp (or NaN, which both casts make 0): truncation is the floor
    let (x0, y0) = (fx as u32, fy as u32);
    let (x1, y1) = ((x0 + 1).min(width - 1), (y0 + 1).min(height - 1));
    ((fx, fy), (x0, y0, x1, y1))
}

/// [`bilinear`] over texels read by `g`, as `Vec3` or as `Vec3A` (the same arithmetic per
/// channel, so the same bits, in one SIMD register).
#[inline(always)]
fn bilinear_with<V>(width: u32, height: u32, uv: Vec2, g: impl Fn(u32, u32) -> V) -> V
where
    V: Copy + std::ops::Mul<f32, Output = V> + std::ops::Add<Output = V>,
{
    bilinear_at(taps(width, height, uv), g)
}

/// [`bilinear_with`] at the [`Taps`] of its position.
#[inline(always)]
fn bilinear_at<V>(((fx, fy), (x0, y0, x1, y1)): Taps, g: impl Fn(u32, u32) -> V) -> V
where
    V: Copy + std::ops::Mul<f32, Output = V> + std::ops::Add<Output = V>,
{
    let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
    let top = g(x0, y0) * (1.0 - tx) + g(x1, y0) * tx;
    let bot = g(x0, y1) * (1.0 - tx) + g(x1, y1) * tx;
    top * (1.0 - ty) + bot * ty
}

/// How a rendered pixel treats its sub-pixel rays that do not see a texture.
#[derive(Clone, Copy)]
pub enum Film<'a> {
    /// The mean over the sub-pixel rays that hit a textured shape; `None` where none does
    /// (projection refinement compares only what the maps cover).
    HitsOnly,
    /// Mitsuba's box-filtered film: every sub-pixel ray counts in the mean; a ray that hits
    /// an emitter shape sees its radiance from the front and black from behind, a miss sees
    /// the environment emitters (black without one). Pixels that lie wholly on emitters or
    /// the environment take `photo`'s value (the light is not reconstructed, so it never
    /// shows as error). Always `Some`.
    Box { scene: &'a Scene, photo: &'a Image },
}

/// What one sub-pixel ray sees.
enum Seen {
    Texture(Vec3),
    Emitter(Vec3),
    /// Radiance through (or absorbed by) known materials: counts in a box film's mean.
    Known(Vec3),
    Nothing,
}

/// A pixel known to lie on one plane of one shape, within one chart of its atlas: the texel
/// coordinates where its four corners land (top-left, top-right, bottom-left, bottom-right),
/// so it renders with no rays (texture coordinates vary affinely across a pixel on a plane
/// to well within a texel).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlatPixel {
    pub shape: u32,
    pub uv: [Vec2; 4],
}

/// Render one view: each pixel from `k x k` stratified sub-pixel rays reading the texture of
/// the shape they hit (`textures[shape]`, bilinear), combined as `film` says. The one renderer
/// of texture-space maps: the re-rendered views of the outputs and the projection's
/// refinement both use it.
pub fn render_view(
    accel: &Accel,
    camera: &Camera,
    textures: &[Option<Texture>],
    k: u32,
    film: Film,
) -> Vec<Option<Vec3>> {
    render_view_with(accel, camera, textures, k, film, &|_, _| Plan::Trace)
}

/// How [`render_view_with`] renders one pixel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Plan<'a> {
    /// Sub-pixel rays.
    Trace,
    /// No rays: what the sub-pixel rays hit, found before ([`sub_hits`]); for
    /// [`Film::HitsOnly`] (another film traces the pixel).
    Hits(&'a [SubHit]),
    /// No rays: the pixel lies wholly on one chart of a textured shape (texture coordinates
    /// interpolated from its corners).
    Flat(FlatPixel),
    /// Not at all (`None`): the caller has no use for it.
    Skip,
}

/// [`render_view`] where `plan(x, y)` says how to render each pixel: flat pixels read the
/// texture at the same `k x k` sub-pixel positions with their texture coordinates
/// interpolated from the pixel's corners instead of traced.
pub fn render_view_with<'h>(
    accel: &Accel,
    camera: &Camera,
    textures: &[Option<Texture>],
    k: u32,
    film: Film,
    plan: &(dyn Fn(u32, u32) -> Plan<'h> + Sync),
) -> Vec<Option<Vec3>> {
    let (w, h) = (camera.width(), camera.height());
    let hits_only = matches!(film, Film::HitsOnly);
    let k = k.max(1);
    (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            (0..w).map(move |x| match plan(x, y) {
                Plan::Skip => None,
                Plan::Flat(f) => flat_pixel(textures, k, &f)
                    .or_else(|| pixel(accel, camera, textures, k, film, x, y)),
                Plan::Hits(h) if hits_only => hits_pixel(textures, h),
                Plan::Trace | Plan::Hits(_) => pixel(accel, camera, textures, k, film, x, y),
            })
        })
        .collect()
}

/// What one sub-pixel ray of a [`Film::HitsOnly`] render hits: a textured shape at texture
/// coordinates `uv`, or no texture (`shape` [`SubHit::NONE`]). It depends on the camera and
/// on which shapes have a texture, not on the textures' values: a caller that re-renders a
/// view from changing maps finds them once ([`sub_hits`]) and renders the pixel from them
/// ([`Plan::Hits`]), with the same result as tracing it again.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SubHit {
    pub shape: u32,
    pub uv: Vec2,
}

impl SubHit {
    /// The `shape` of a sub-pixel ray that sees no texture.
    pub const NONE: u32 = u32::MAX;
}

/// The `k x k` sub-pixel rays of pixel `(x, y)` (row-major), traced as a
/// [`Film::HitsOnly`] render traces them.
pub fn sub_hits(
    (accel, camera, textures): (&Accel, &Camera, &[Option<Texture>]),
    k: u32,
    (x, y): (u32, u32),
) -> Vec<SubHit> {
    let mut out = Vec::with_capacity((k * k) as usize);
    for j in 0..k {
        for i in 0..k {
            let (px, py) = sub_pixel(k, (x, y), (i, j));
            let (o, d) = camera.ray(px, py);
            let hit = accel.intersect(o, d, f32::INFINITY);
            let seen = hit.and_then(|h| Some((h.shape, textured_uv(textures, &h)?.1)));
            out.push(match seen {
                Some((shape, uv)) => SubHit { shape, uv },
                None => SubHit {
                    shape: SubHit::NONE,
                    uv: Vec2::ZERO,
                },
            });
        }
    }
    out
}

/// The continuous pixel coordinates of sub-pixel `(i, j)` of pixel `(x, y)` on a `k x k`
/// grid: where [`pixel`], [`pixel_samples`] and [`sub_hits`] all cast their rays.
#[inline]
fn sub_pixel(k: u32, (x, y): (u32, u32), (i, j): (u32, u32)) -> (f32, f32) {
    let px = x as f32 + (i as f32 + 0.5) / k as f32;
    let py = y as f32 + (j as f32 + 0.5) / k as f32;
    (px, py)
}

/// A sub-pixel hit's texture value (`None`: no texture).
#[inline]
fn hit_value(textures: &[Option<Texture>], h: &SubHit) -> Option<Vec3> {
    let tex = textures.get(h.shape as usize)?.as_ref()?;
    Some(bilinear(tex.texels, h.uv))
}

/// A pixel from its sub-pixel hits as [`pixel`] makes it for [`Film::HitsOnly`]: the mean
/// over the hits that see a texture, `None` if none does.
fn hits_pixel(textures: &[Option<Texture>], hits: &[SubHit]) -> Option<Vec3> {
    let (mut sum, mut n) = (Vec3::ZERO, 0u32);
    for v in hits.iter().filter_map(|h| hit_value(textures, h)) {
        sum += v;
        n += 1;
    }
    (n > 0).then(|| sum / n as f32)
}

/// The texture a hit lands on and its texture coordinates there, if its shape has one.
#[inline]
fn textured_uv<'t>(
    textures: &'t [Option<Texture<'t>>],
    hit: &Hit,
) -> Option<(&'t Texture<'t>, Vec2)> {
    let tex = textures.get(hit.shape as usize)?.as_ref()?;
    let c = tex.corner_uv[hit.tri as usize];
    Some((
        tex,
        c[0] * (1.0 - hit.b1 - hit.b2) + c[1] * hit.b1 + c[2] * hit.b2,
    ))
}

/// The mean of the texture over `k x k` sub-pixel positions of a flat pixel (`None` if its
/// shape has no texture).
fn flat_pixel(textures: &[Option<Texture>], k: u32, f: &FlatPixel) -> Option<Vec3> {
    let tex = textures.get(f.shape as usize)?.as_ref()?;
    let (w, h) = (tex.texels.width(), tex.texels.height());
    // the texture resolved once per pixel, not per sub-pixel look-up
    Some(match tex.texels.row_major() {
        Some(v) => Vec3::from(flat_mean(k, f, |uv| {
            bilinear_with(w, h, uv, |x, y| Vec3A::from(v[(y * w + x) as usize]))
        })),
        None => {
            // the sub-pixel positions lie within the corners' box: one block for them all
            let block = flat_block(tex.texels, f);
            Vec3::from(flat_mean(k, f, |uv| {
                let g = |x, y| Vec3A::from(texel_via(tex.texels, block.as_ref(), x, y));
                bilinear_with(w, h, uv, g)
            }))
        }
    })
}

/// The block of `texels` holding every tap of a flat pixel's look-ups: the taps of its
/// corners' bounding box, a texel wider on each side (the sub-pixel positions, interpolated
/// between the corners, may round past them); `None` for corners that are not finite.
fn flat_block(texels: &dyn Texels, f: &FlatPixel) -> Option<Block> {
    let (lo, hi) =
        f.uv.iter()
            .fold((f.uv[0], f.uv[0]), |(lo, hi), &c| (lo.min(c), hi.max(c)));
    if !(lo.is_finite() && hi.is_finite()) {
        return None;
    }
    let (w, h) = (texels.width(), texels.height());
    let (_, (x0, y0, _, _)) = taps(w, h, lo);
    let (_, (_, _, x1, y1)) = taps(w, h, hi);
    let grow = |v: u32, n: u32| (v + 1).min(n - 1);
    texels.held_block(
        x0.saturating_sub(1),
        y0.saturating_sub(1),
        grow(x1, w),
        grow(y1, h),
    )
}

/// The mean of `look(uv)` over `k x k` sub-pixel positions of a flat pixel (in `Vec3A`:
/// the same bits as in `Vec3`, fewer instructions).
#[inline(always)]
fn flat_mean(k: u32, f: &FlatPixel, look: impl Fn(Vec2) -> Vec3A) -> Vec3A {
    let [a, b, c, d] = f.uv;
    let mut sum = Vec3A::ZERO;
    for j in 0..k {
        let ty = (j as f32 + 0.5) / k as f32;
        let (l, r) = (a.lerp(c, ty), b.lerp(d, ty));
        for i in 0..k {
            let tx = (i as f32 + 0.5) / k as f32;
            sum += look(l.lerp(r, tx));
        }
    }
    sum / (k * k) as f32
}

/// Apply a film's pixel filter to an image of pixel means (what [`render_view`] makes: a box
/// film): every pixel becomes the mean of its neighbours within the filter's reach weighted
/// by the filter integrated over each neighbour's square ([`PixelFilter::pixel_weights`]),
/// over the neighbours that have a value (`None` stays `None`). A box filter returns the
/// image as it is. This is the photo a `tent` or `gaussian` film records, to the extent the
/// radiance is flat within each pixel.
pub fn apply_pixel_filter(
    pixels: &[Option<Vec3>],
    width: u32,
    height: u32,
    filter: PixelFilter,
) -> Vec<Option<Vec3>> {
    if filter.is_box() {
        return pixels.to_vec();
    }
    let wts = filter.pixel_weights();
    let n = filter.reach() as i64;
    let (w, h) = (width as i64, height as i64);
    (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            let wts = &wts;
            (0..w).map(move |x| {
                pixels[(y * w + x) as usize]?;
                let (mut sum, mut total) = (Vec3::ZERO, 0.0f32);
                for dy in -n..=n {
                    for dx in -n..=n {
                        let (nx, ny) = (x + dx, y + dy);
                        if nx < 0 || ny < 0 || nx >= w || ny >= h {
                            continue;
                        }
                        if let Some(v) = pixels[(ny * w + nx) as usize] {
                            let k = wts[(dx + n) as usize] * wts[(dy + n) as usize];
                            sum += v * k;
                            total += k;
                        }
                    }
                }
                Some(sum / total)
            })
        })
        .collect()
}

/// One pixel of [`render_view`].
fn pixel(
    accel: &Accel,
    camera: &Camera,
    textures: &[Option<Texture>],
    k: u32,
    film: Film,
    x: u32,
    y: u32,
) -> Option<Vec3> {
    let scene = match film {
        Film::Box { scene, .. } => Some(scene),
        Film::HitsOnly => None,
    };
    let (mut sum, mut hits, mut on_emitter) = (Vec3::ZERO, 0u32, 0u32);
    for j in 0..k {
        for i in 0..k {
            let (px, py) = sub_pixel(k, (x, y), (i, j));
            let stream = ((y as u64 * camera.width() as u64 + x as u64) * k as u64 + j as u64)
                * k as u64
                + i as u64;
            match trace(accel, camera, textures, scene, (px, py), stream) {
                Seen::Texture(v) => {
                    sum += v;
                    hits += 1;
                }
                Seen::Emitter(v) => {
                    sum += v;
                    on_emitter += 1;
                }
                Seen::Known(v) => sum += v,
                Seen::Nothing => {}
            }
        }
    }
    match film {
        Film::HitsOnly => (hits > 0).then(|| sum / hits as f32),
        Film::Box { photo, .. } if on_emitter == k * k && photo.is_valid(x, y) => {
            Some(photo.get(x, y))
        }
        Film::Box { .. } => Some(sum / (k * k) as f32),
    }
}

/// The `k x k` sub-pixel values of pixel `(x, y)` as [`render_view_with`] with
/// [`Film::HitsOnly`] finds them (row-major into `out`; `None` where a sub-pixel ray sees no
/// texture), before they are averaged: what a film's filter weighs one by one.
pub fn pixel_samples(
    (accel, camera, textures): (&Accel, &Camera, &[Option<Texture>]),
    k: u32,
    plan: Plan,
    (x, y): (u32, u32),
    out: &mut [Option<Vec3>],
) {
    out.fill(None);
    let flat = match plan {
        Plan::Skip => return,
        Plan::Hits(h) => {
            for (o, h) in out.iter_mut().zip(h) {
                *o = hit_value(textures, h);
            }
            return;
        }
        Plan::Flat(f) => textures
            .get(f.shape as usize)
            .and_then(|t| t.as_ref().map(|t| (t, f))),
        Plan::Trace => None,
    };
    for j in 0..k {
        let ty = (j as f32 + 0.5) / k as f32;
        for i in 0..k {
            let tx = (i as f32 + 0.5) / k as f32;
            out[(j * k + i) as usize] = match flat {
                Some((tex, f)) => {
                    let [a, b, c, d] = f.uv;
                    let (l, r) = (a.lerp(c, ty), b.lerp(d, ty));
                    Some(bilinear(tex.texels, l.lerp(r, tx)))
                }
                None => {
                    let stream = ((y as u64 * camera.width() as u64 + x as u64) * k as u64
                        + j as u64)
                        * k as u64
                        + i as u64;
                    let at = sub_pixel(k, (x, y), (i, j));
                    match trace(accel, camera, textures, None, at, stream) {
                        Seen::Texture(v) => Some(v),
                        _ => None,
                    }
                }
            };
        }
    }
}

/// Mixed into the seed of the re-renders' paths through known materials.
const RENDER_TAG: u64 = 0x7e4d_e5ca_77e2_0001;

/// What the ray through continuous pixel coordinates `(px, py)` sees; emitters and known
/// materials (mirrors, glass: one path sampled through them, its random numbers a function
/// of `stream`) only with `scene` (else they are `Nothing`).
fn trace(
    accel: &Accel,
    camera: &Camera,
    textures: &[Option<Texture>],
    scene: Option<&Scene>,
    (px, py): (f32, f32),
    stream: u64,
) -> Seen {
    let (mut o, mut d) = camera.ray(px, py);
    let mut weight = Vec3::ONE;
    let mut rng = None;
    for bounce in 0..=bsdf_sampling::MAX_SPECULAR {
        let Some(hit) = accel.intersect(o, d, f32::INFINITY) else {
            return match (bounce, scene.map(|s| environment(s, d))) {
                (_, None) => Seen::Nothing,
                (0, Some(seen)) => seen,
                (_, Some(Seen::Emitter(v))) => Seen::Known(v * weight),
                (_, Some(_)) => Seen::Known(Vec3::ZERO),
            };
        };
        let si = hit.shape as usize;
        if let Some((tex, uv)) = textured_uv(textures, &hit) {
            let v = bilinear(tex.texels, uv) * weight;
            return match bounce {
                0 => Seen::Texture(v),
                _ => Seen::Known(v),
            };
        }
        let Some(shape) = scene.map(|s| &s.shapes[si]) else {
            return Seen::Nothing;
        };
        let n = shape.mesh.shading_normal(hit.tri as usize, hit.b1, hit.b2);
        if let Some(radiance) = shape.emission {
            let v = if n.dot(d) < 0.0 {
                radiance * weight
            } else {
                Vec3::ZERO
            };
            return match bounce {
                0 => Seen::Emitter(v),
                _ => Seen::Known(v),
            };
        }
        let Some(known) = shape.known() else {
            return Seen::Nothing;
        };
        if shape.sides == Sides::Front && n.dot(d) >= 0.0 {
            return Seen::Known(Vec3::ZERO);
        }
        let rng = rng.get_or_insert_with(|| Rng::new(RENDER_TAG, 0, stream, 0));
        let Some(sc) = bsdf_sampling::sample(&known.bsdf, d, n, rng) else {
            return Seen::Known(Vec3::ZERO);
        };
        weight *= sc.weight;
        let ng = shape
            .mesh
            .face_normal_raw(hit.tri as usize)
            .normalize_or_zero();
        o = offset_origin(o + d * hit.t, ng, sc.dir);
        d = sc.dir;
    }
    Seen::Known(Vec3::ZERO)
}

/// What a ray along `d` that leaves the scene sees: the environment emitters' radiance.
fn environment(scene: &Scene, d: Vec3) -> Seen {
    let envs = scene.emitters.iter().filter_map(|e| match e {
        Emitter::Environment(env) => Some(env.eval(d)),
        _ => None,
    });
    envs.reduce(|a, b| a + b)
        .map_or(Seen::Nothing, Seen::Emitter)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicU32, Ordering};

    /// Row-major texels that also hand out tiles of `ts x ts` as blocks (as a tiled slot
    /// texture does), counting the blocks handed out.
    struct Tiled {
        width: u32,
        height: u32,
        ts: u32,
        texels: Vec<Vec3>,
        handed: AtomicU32,
    }

    impl Texels for Tiled {
        fn width(&self) -> u32 {
            self.width
        }
        fn height(&self) -> u32 {
            self.height
        }
        fn texel(&self, x: u32, y: u32) -> Vec3 {
            self.texels[(y * self.width + x) as usize]
        }
        fn held_block(&self, x0: u32, y0: u32, x1: u32, y1: u32) -> Option<Block> {
            let ts = self.ts;
            if (x0 / ts, y0 / ts) != (x1 / ts, y1 / ts) {
                return None;
            }
            let origin = (x0 / ts * ts, y0 / ts * ts);
            let mut tile = vec![Vec3::ZERO; (ts * ts) as usize];
            for j in 0..ts.min(self.height - origin.1) {
                for i in 0..ts.min(self.width - origin.0) {
                    tile[(j * ts + i) as usize] = self.texel(origin.0 + i, origin.1 + j);
                }
            }
            self.handed.fetch_add(1, Ordering::Relaxed);
            Some(Block {
                texels: std::sync::Arc::new(tile),
                stride: ts,
                origin,
            })
        }
    }

    /// Look-ups through blocks (single bilinear taps and flat pixels' sub-pixel means) give
    /// the same bits as reading texel by texel from a row-major slice: inside tiles, across
    /// tile borders, at and beyond the texture's edges, and with corners that are not finite.
    #[test]
    fn lookups_through_blocks_are_those_of_the_texels() {
        let (width, height) = (37u32, 29u32);
        let mut rng = Rng::new(7, 0, 0, 0);
        let texels: Vec<Vec3> = (0..width * height)
            .map(|_| Vec3::new(rng.f32(), rng.f32(), rng.f32()))
            .collect();
        let plain = RowMajor {
            width,
            height,
            texels: &texels,
        };
        let tiled = Tiled {
            width,
            height,
            ts: 8,
            texels: texels.clone(),
            handed: AtomicU32::new(0),
        };
        let at = |rng: &mut Rng| {
            Vec2::new(
                rng.f32() * (width + 4) as f32 - 2.0,
                rng.f32() * (height + 4) as f32 - 2.0,
            )
        };
        for _ in 0..2000 {
            let uv = at(&mut rng);
            let (a, b) = (bilinear(&plain, uv), bilinear(&tiled, uv));
            assert_eq!(
                a.to_array().map(f32::to_bits),
                b.to_array().map(f32::to_bits)
            );
        }
        let cases = (0..2000).map(|i| {
            let c = at(&mut rng);
            let d = |rng: &mut Rng| Vec2::new(rng.f32(), rng.f32()) * 3.0;
            let mut uv = [c, c + d(&mut rng), c + d(&mut rng), c + d(&mut rng)];
            if i % 97 == 0 {
                uv[i % 4].x = f32::NAN;
            }
            FlatPixel { shape: 0, uv }
        });
        let tp = [Some(Texture {
            texels: &plain,
            corner_uv: &[],
        })];
        let tt = [Some(Texture {
            texels: &tiled,
            corner_uv: &[],
        })];
        let before = tiled.handed.load(Ordering::Relaxed);
        for f in cases {
            let (a, b) = (
                flat_pixel(&tp, 4, &f).unwrap(),
                flat_pixel(&tt, 4, &f).unwrap(),
            );
            assert!(
                a.to_array().map(f32::to_bits) == b.to_array().map(f32::to_bits)
                    || (a.is_nan() && b.is_nan()),
                "{f:?}: {a} against {b}"
            );
        }
        let used = tiled.handed.load(Ordering::Relaxed) - before;
        assert!(
            used > 300,
            "flat pixels read through blocks: {used} of 2000"
        );
    }

    /// A plain shape of `mesh` seen from `sides`: no emission, no known material.
    fn test_shape(id: &str, mesh: crate::scene::Mesh, sides: Sides) -> crate::scene::Shape {
        crate::scene::Shape::plain(id, mesh, sides)
    }

    /// A one-pixel impulse spreads by the tent's per-pixel weights (1/8, 3/4, 1/8 per
    /// axis); a box leaves it alone; missing pixels drop out of the weighted mean.
    #[test]
    fn pixel_filter_spreads_an_impulse_by_the_kernel() {
        let mut img = vec![Some(Vec3::ZERO); 25];
        img[12] = Some(Vec3::ONE);
        assert_eq!(apply_pixel_filter(&img, 5, 5, PixelFilter::Box), img);
        let t = apply_pixel_filter(&img, 5, 5, PixelFilter::Tent { radius: 1.0 });
        let v = |i: usize| t[i].unwrap().x;
        assert!((v(12) - 0.75 * 0.75).abs() < 1e-4, "{}", v(12));
        assert!((v(11) - 0.75 * 0.125).abs() < 1e-4);
        assert!((v(6) - 0.125 * 0.125).abs() < 1e-4);
        assert_eq!(v(0), 0.0);
        let sum: f32 = (0..25).map(v).sum();
        assert!((sum - 1.0).abs() < 1e-4);
        // A hole: the center's neighbours renormalize over what is there.
        img[11] = None;
        let t = apply_pixel_filter(&img, 5, 5, PixelFilter::Tent { radius: 1.0 });
        assert!(t[11].is_none());
        assert!((t[12].unwrap().x - 0.5625 / (1.0 - 0.09375)).abs() < 1e-4);
    }

    /// A ray that leaves the scene sees the environment (in a box film, through the same
    /// lookup as the light); without one, nothing.
    #[test]
    fn escaping_rays_see_the_environment() {
        use crate::scene::{EnvMap, FovAxis, Sensor};
        let px: Vec<Vec3> = (0..8 * 5).map(|i| Vec3::splat(i as f32)).collect();
        let env = EnvMap::from_pixels(None, 1.0, glam::Mat4::IDENTITY, 8, 5, px);
        let sensor = Sensor::simple(
            "c",
            glam::Mat4::IDENTITY,
            40.0,
            FovAxis::X,
            (4, 4),
            PixelFilter::Box,
        );
        // one triangle behind the camera, out of view
        let mesh = crate::scene::Mesh {
            positions: vec![
                -Vec3::Z * 5.0,
                Vec3::new(1.0, 0.0, -5.0),
                Vec3::new(0.0, 1.0, -5.0),
            ],
            triangles: vec![[0, 1, 2]],
            ..Default::default()
        };
        let shape = test_shape("t", mesh, Sides::Front);
        let mut scene = Scene {
            path: "t.xml".into(),
            shapes: vec![shape],
            emitters: vec![Emitter::Environment(std::sync::Arc::new(env.clone()))],
            sensors: vec![sensor.clone()],
            files: vec![],
        };
        let accel = Accel::build(&scene);
        let cam = Camera::from_sensor(&sensor);
        let (_, d) = cam.ray(1.3, 2.6);
        match trace(&accel, &cam, &[], Some(&scene), (1.3, 2.6), 0) {
            Seen::Emitter(v) => assert_eq!(v, env.eval(d)),
            _ => panic!("the sky is not seen"),
        }
        assert!(matches!(
            trace(&accel, &cam, &[], None, (1.3, 2.6), 0),
            Seen::Nothing
        ));
        scene.emitters.clear();
        assert!(matches!(
            trace(&accel, &cam, &[], Some(&scene), (1.3, 2.6), 0),
            Seen::Nothing
        ));
    }

    /// Pixels rendered from their kept sub-pixel hits ([`sub_hits`], [`Plan::Hits`]) are the
    /// traced ones bit for bit, pixel means and filtered samples alike, whatever the texture
    /// holds: a textured quad partly covered by an untextured triangle, some pixels half off
    /// both.
    #[test]
    fn kept_sub_pixel_hits_render_as_tracing_does() {
        use crate::scene::{FovAxis, Sensor};
        let sensor = Sensor::simple(
            "c",
            glam::Mat4::IDENTITY,
            50.0,
            FovAxis::X,
            (12, 9),
            PixelFilter::Box,
        );
        let shape = |id: &str, positions: Vec<Vec3>, triangles| {
            let mesh = crate::scene::Mesh {
                positions,
                triangles,
                ..Default::default()
            };
            test_shape(id, mesh, Sides::Both)
        };
        let quad = [(-1.0, -0.7), (0.9, -0.8), (1.1, 0.6), (-0.8, 0.9)]
            .map(|(x, y)| Vec3::new(x, y, 3.0))
            .to_vec();
        let tri = [(-0.2, -0.1), (0.6, 0.0), (0.1, 0.5)]
            .map(|(x, y)| Vec3::new(x, y, 2.0))
            .to_vec();
        let scene = Scene {
            path: "t.xml".into(),
            shapes: vec![
                shape("quad", quad, vec![[0, 1, 2], [0, 2, 3]]),
                shape("tri", tri, vec![[0, 1, 2]]),
            ],
            emitters: vec![],
            sensors: vec![sensor.clone()],
            files: vec![],
        };
        let accel = Accel::build(&scene);
        let cam = Camera::from_sensor(&sensor);
        let texels: Vec<Vec3> = (0..20)
            .map(|i| Vec3::new(i as f32, (i * 7 % 5) as f32, 0.3 * i as f32))
            .collect();
        let map = RowMajor {
            width: 5,
            height: 4,
            texels: &texels,
        };
        let corner_uv = [
            [
                Vec2::new(0.2, 0.3),
                Vec2::new(4.9, 0.1),
                Vec2::new(4.7, 3.8),
            ],
            [
                Vec2::new(0.2, 0.3),
                Vec2::new(4.7, 3.8),
                Vec2::new(0.1, 3.9),
            ],
        ];
        let textures = [
            Some(Texture {
                texels: &map,
                corner_uv: &corner_uv,
            }),
            None,
        ];
        let k = 3;
        let parts = (&accel, &cam, &textures[..]);
        let hits: Vec<Vec<SubHit>> = (0..9 * 12)
            .map(|i| sub_hits(parts, k, (i % 12, i / 12)))
            .collect();
        let seen = |h: &Vec<SubHit>| h.iter().filter(|h| h.shape != SubHit::NONE).count();
        assert!(
            hits.iter().any(|h| seen(h) == 0),
            "some pixel sees no texture"
        );
        assert!(
            hits.iter().any(|h| (1..9).contains(&seen(h))),
            "some pixel is mixed"
        );
        let traced = render_view_with(&accel, &cam, &textures, k, Film::HitsOnly, &|_, _| {
            Plan::Trace
        });
        let kept = render_view_with(&accel, &cam, &textures, k, Film::HitsOnly, &|x, y| {
            Plan::Hits(&hits[(y * 12 + x) as usize])
        });
        assert_eq!(kept, traced);
        assert!(traced.iter().flatten().count() > 50);
        let (mut a, mut b) = (vec![None; 9], vec![None; 9]);
        for (i, h) in hits.iter().enumerate() {
            let xy = (i as u32 % 12, i as u32 / 12);
            pixel_samples(parts, k, Plan::Trace, xy, &mut a);
            pixel_samples(parts, k, Plan::Hits(h), xy, &mut b);
            assert_eq!(a, b, "pixel {xy:?}");
        }
    }

    #[test]
    fn bilinear_is_exact_at_centers_and_linear_between() {
        let v = vec![
            Vec3::splat(0.0),
            Vec3::splat(1.0),
            Vec3::splat(2.0),
            Vec3::splat(3.0),
        ];
        let t = RowMajor {
            width: 2,
            height: 2,
            texels: &v,
        };
        let bilinear = |_: &RowMajor, _w: u32, _h: u32, uv: Vec2| bilinear(&t, uv);
        assert_eq!(bilinear(&t, 2, 2, Vec2::new(0.5, 0.5)), Vec3::splat(0.0));
        assert_eq!(bilinear(&t, 2, 2, Vec2::new(1.5, 1.5)), Vec3::splat(3.0));
        assert_eq!(bilinear(&t, 2, 2, Vec2::new(1.0, 0.5)), Vec3::splat(0.5));
        assert_eq!(bilinear(&t, 2, 2, Vec2::new(1.0, 1.0)), Vec3::splat(1.5));
        // clamped outside
        assert_eq!(bilinear(&t, 2, 2, Vec2::new(-3.0, 0.5)), Vec3::splat(0.0));
    }
}
