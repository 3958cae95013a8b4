//! A photo as the projection reads it: its pixels classified with primary rays (clean pixels
//! see one plane of one shape, away from emitters) and sampled only where they are clean.
//!
//! The rays are cast once per view: one through every pixel corner (kept, for rendering flat
//! pixels without rays) and one through every pixel center. A clean pixel sees nothing but
//! one plane of one shape, so a surface point that projects into it and lies on that plane is
//! visible from the camera: the projection needs no occlusion rays of its own. Processes that
//! share the projection cast the rays of their own bands of rows and gather the others'
//! ([`View::new_shared`]), the same bits as one process.

use super::one_surface::{self, Span};
use super::{Shard, ROW_BAND};
use crate::atlas::context::HitTable;
use crate::atlas::uv::NONE;
use crate::base::error::Result;
use crate::image::Image;
use crate::physics::accel::{Accel, Hit};
use crate::physics::camera::Camera;
use crate::physics::render::FlatPixel;
use crate::scene::Scene;
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use std::sync::Arc;

/// What the primary ray through a pixel center found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelInfo {
    /// Shape index hit at the pixel center, `u32::MAX` for none.
    pub shape: u32,
    /// Unit geometric normal there.
    pub normal: Vec3,
    /// `normal . point` of the hit point: the plane the pixel sees.
    pub plane: f32,
    /// Whether the whole pixel lies on one plane of one shape and its value is valid.
    pub clean: bool,
}

/// The hit of the ray through a pixel corner: BVH primitive ([`NONE`] for a miss) and
/// barycentrics.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Corner {
    prim: u32,
    b1: f32,
    b2: f32,
}

/// One photo with its per-pixel classification, ready to be sampled. What the rays found is
/// shared (`Arc`) by the views of other photos from the same camera ([`View::with_image`]: the
/// exposed photos, the noise probe's perturbed ones), not copied: 7 MB per view of 512x384.
pub struct View<'a> {
    pub camera: Camera,
    pub image: &'a Image,
    pub pixels: Arc<Vec<PixelInfo>>,
    traced: Arc<Traced>,
}

/// What a view's rays found, without its photo: kept while the photo changes in place (the
/// noise probe's), and made a view of a photo again with [`Rays::with_image`].
pub struct Rays {
    camera: Camera,
    pixels: Arc<Vec<PixelInfo>>,
    traced: Arc<Traced>,
}

impl Rays {
    /// The view of `image`, a photo of the same size, with these rays: a pixel `image` masks
    /// (the coat's: see `coat`) is not read, so a shared classification is copied only when
    /// it masks a clean one.
    pub fn with_image(self, image: &Image) -> View<'_> {
        let masks = |(p, ok): (&PixelInfo, &bool)| p.clean && !*ok;
        let mut pixels = self.pixels;
        if pixels.iter().zip(&image.valid).any(masks) {
            // copied only if other views share it
            for (p, ok) in Arc::make_mut(&mut pixels).iter_mut().zip(&image.valid) {
                p.clean &= *ok;
            }
        }
        View {
            camera: self.camera,
            image,
            pixels,
            traced: self.traced,
        }
    }
}

/// A view's ray results besides its pixels' classification.
struct Traced {
    /// `(w + 1) x (h + 1)` pixel corners, row-major.
    corners: Vec<Corner>,
    /// Per pixel, the one surface of one shape it sees, planar or not (`one_surface`).
    spans: Vec<Option<Span>>,
    /// Per pixel, whether an emitter lies within reach of it.
    hot: Vec<bool>,
}

/// Tolerance of "on the same plane" at distance `t` from the camera (relative `1e-3`, as the
/// camera's own precision allows).
fn plane_tol(t: f32) -> f32 {
    1e-3 * t + 1e-6
}

/// Which rows (of pixels, or of pixel corners) a process casts rays for.
type Rows<'r> = &'r (dyn Fn(u32) -> bool + Sync);

/// The rays through every pixel corner of `camera` on the corner rows `mine` accepts:
/// `(hit, hit point)`, row-major (`None` on the other rows).
fn trace_corners(accel: &Accel, camera: &Camera, mine: Rows) -> Vec<Option<(Hit, Vec3)>> {
    let (w, h) = (camera.width(), camera.height());
    (0..=h)
        .into_par_iter()
        .flat_map_iter(|gy| {
            let here = mine(gy);
            (0..=w).map(move |gx| {
                if !here {
                    return None;
                }
                let (o, d) = camera.ray(gx as f32, gy as f32);
                accel
                    .intersect(o, d, f32::INFINITY)
                    .map(|hit| (hit, o + d * hit.t))
            })
        })
        .collect()
}

/// Classify every pixel of `image` as seen by `camera`, given the hits of its corner rays
/// (`corners`, `(w + 1) x (h + 1)`). A pixel is clean when its four corners land on the plane
/// of the shape hit at its center, no corner within one pixel of it lands on an emitter, and
/// its value is valid. The emitter guard is there because an emitter is orders of magnitude
/// brighter than what borders it, so even a sliver of it between the rays ruins the pixel: in
/// both fixtures' cam_train_0 a corner of the light falls between the corner rays of a
/// ceiling pixel (1.3 against 0.09 around it), which would streak the ceiling's luminance map.
fn classify(
    scene: &Scene,
    accel: &Accel,
    camera: &Camera,
    image: &Image,
    corners: &[Option<(Hit, Vec3)>],
) -> Vec<PixelInfo> {
    erode_to_filter(
        center_rays(scene, accel, camera, image, corners, &|_| true),
        camera,
    )
}

impl PixelInfo {
    /// The `shape` of a pixel whose centre ray hits nothing.
    pub const NO_SHAPE: u32 = u32::MAX;

    /// The shape the pixel's centre sees, `None` where its ray hits nothing.
    pub fn seen_shape(&self) -> Option<u32> {
        (self.shape != PixelInfo::NO_SHAPE).then_some(self.shape)
    }
}

/// What a pixel that is not classified (here) holds.
const MISS: PixelInfo = PixelInfo {
    shape: PixelInfo::NO_SHAPE,
    normal: Vec3::ZERO,
    plane: 0.0,
    clean: false,
};

/// [`classify`] before the film filter's erosion, on the pixel rows `mine` accepts ([`MISS`]
/// on the others); `corners` must be whole.
fn center_rays(
    scene: &Scene,
    accel: &Accel,
    camera: &Camera,
    image: &Image,
    corners: &[Option<(Hit, Vec3)>],
    mine: Rows,
) -> Vec<PixelInfo> {
    let (w, h) = (camera.width(), camera.height());
    let gw = (w + 1) as usize;
    let at = |gx: u32, gy: u32| corners[gy as usize * gw + gx as usize];
    let emits = |s: u32| scene.shapes[s as usize].emission.is_some();
    // per pixel: whether any of its corners hits an emitter
    let touches: Vec<bool> = (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            (0..w).map(move |x| {
                [(x, y), (x + 1, y), (x, y + 1), (x + 1, y + 1)]
                    .iter()
                    .any(|&(gx, gy)| at(gx, gy).is_some_and(|(hit, _)| emits(hit.shape)))
            })
        })
        .collect();
    // A blurring film spreads an emitter over `reach` more pixels.
    let r = 1 + camera.filter().reach();
    let near_emitter = |x: u32, y: u32| {
        (y.saturating_sub(r)..(y + r + 1).min(h)).any(|ny| {
            (x.saturating_sub(r)..(x + r + 1).min(w)).any(|nx| touches[(ny * w + nx) as usize])
        })
    };
    let infos: Vec<PixelInfo> = (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            let here = mine(y);
            (0..w).map(move |x| {
                if !here {
                    return MISS;
                }
                let (o, d) = camera.ray(x as f32 + 0.5, y as f32 + 0.5);
                let Some(hit) = accel.intersect(o, d, f32::INFINITY) else {
                    return MISS;
                };
                let mesh = &scene.shapes[hit.shape as usize].mesh;
                let nrm = mesh.face_normal_raw(hit.tri as usize).normalize_or_zero();
                let c = o + d * hit.t;
                let tol = plane_tol(hit.t);
                let coplanar = [(x, y), (x + 1, y), (x, y + 1), (x + 1, y + 1)].iter().all(
                    |&(gx, gy)| match at(gx, gy) {
                        Some((h2, p)) => h2.shape == hit.shape && (p - c).dot(nrm).abs() <= tol,
                        None => false,
                    },
                );
                PixelInfo {
                    shape: hit.shape,
                    normal: nrm,
                    plane: nrm.dot(c),
                    clean: coplanar && !near_emitter(x, y) && image.is_valid(x, y),
                }
            })
        })
        .collect();
    infos
}

/// 32-bit words of one pixel corner's hit as processes exchange it: present, shape, triangle,
/// primitive, `b1`, `b2`, `t`, the hit point.
const CORNER_WORDS: usize = 10;

/// 32-bit words of one pixel's [`PixelInfo`]: shape, normal, plane, clean.
const PIXEL_WORDS: usize = 6;

fn encode_corners(hits: &[Option<(Hit, Vec3)>]) -> Vec<u32> {
    let mut out = Vec::with_capacity(hits.len() * CORNER_WORDS);
    for h in hits {
        match h {
            Some((hit, p)) => out.extend_from_slice(&[
                1,
                hit.shape,
                hit.tri,
                hit.prim,
                hit.b1.to_bits(),
                hit.b2.to_bits(),
                hit.t.to_bits(),
                p.x.to_bits(),
                p.y.to_bits(),
                p.z.to_bits(),
            ]),
            None => out.extend_from_slice(&[0; CORNER_WORDS]),
        }
    }
    out
}

fn decode_corners(words: &[u32]) -> Vec<Option<(Hit, Vec3)>> {
    let f = f32::from_bits;
    (words.chunks_exact(CORNER_WORDS))
        .map(|c| {
            (c[0] == 1).then(|| {
                let hit = Hit {
                    shape: c[1],
                    tri: c[2],
                    prim: c[3],
                    b1: f(c[4]),
                    b2: f(c[5]),
                    t: f(c[6]),
                };
                (hit, Vec3::new(f(c[7]), f(c[8]), f(c[9])))
            })
        })
        .collect()
}

fn encode_pixels(infos: &[PixelInfo]) -> Vec<u32> {
    infos.iter().flat_map(pixel_words).collect()
}

/// One pixel's [`PIXEL_WORDS`] words.
fn pixel_words(p: &PixelInfo) -> [u32; PIXEL_WORDS] {
    let (n, f) = (p.normal, f32::to_bits);
    [
        p.shape,
        f(n.x),
        f(n.y),
        f(n.z),
        f(p.plane),
        u32::from(p.clean),
    ]
}

fn decode_pixels(words: &[u32]) -> Vec<PixelInfo> {
    let f = f32::from_bits;
    (words.chunks_exact(PIXEL_WORDS))
        .map(|c| PixelInfo {
            shape: c[0],
            normal: Vec3::new(f(c[1]), f(c[2]), f(c[3])),
            plane: f(c[4]),
            clean: c[5] == 1,
        })
        .collect()
}

/// `words` computed in bands of [`ROW_BAND`] rows of `per_row` words made whole by `shard`.
fn sync_rows(shard: &Shard, mut words: Vec<u32>, per_row: usize) -> Result<Vec<u32>> {
    let unit = ROW_BAND as usize * per_row * 4;
    (shard.sync_bytes)(bytemuck::cast_slice_mut(&mut words), unit)?;
    Ok(words)
}

/// With a film filter that reaches `n > 0` pixels beyond the pixel (tent, gaussian), a pixel's
/// value mixes its neighbours': it stays clean only if every pixel within `n` is clean and
/// sees the same plane of the same shape. A box filter changes nothing.
fn erode_to_filter(infos: Vec<PixelInfo>, camera: &Camera) -> Vec<PixelInfo> {
    let n = camera.filter().reach() as i64;
    if n == 0 {
        return infos;
    }
    let (w, h) = (camera.width() as i64, camera.height() as i64);
    let eye = camera.position();
    (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            let infos = &infos;
            (0..w).map(move |x| {
                let mut p = infos[(y * w + x) as usize];
                if !p.clean {
                    return p;
                }
                let tol = plane_tol((p.normal.dot(eye) - p.plane).abs());
                let same = |q: &PixelInfo| {
                    q.clean
                        && q.shape == p.shape
                        && q.normal.dot(p.normal) > 0.99
                        && (q.plane - p.plane).abs() <= tol
                };
                p.clean = (-n..=n).all(|dy| {
                    (-n..=n).all(|dx| {
                        let (nx, ny) = (x + dx, y + dy);
                        nx >= 0
                            && ny >= 0
                            && nx < w
                            && ny < h
                            && same(&infos[(ny * w + nx) as usize])
                    })
                });
                p
            })
        })
        .collect()
}

impl<'a> View<'a> {
    /// Cast the view's corner and center rays and classify its pixels.
    pub fn new(scene: &Scene, accel: &Accel, camera: Camera, image: &'a Image) -> View<'a> {
        View::new_with(scene, accel, camera, image, false)
    }

    /// [`View::new`], and with `loose` also what the loose reading of non-planar pixels needs
    /// ([`View::sample_loose`], [`View::usable`]: `[projection] fine_geometry`); without it
    /// those two must not be called.
    pub fn new_with(
        scene: &Scene,
        accel: &Accel,
        camera: Camera,
        image: &'a Image,
        loose: bool,
    ) -> View<'a> {
        let hits = trace_corners(accel, &camera, &|_| true);
        let pixels = classify(scene, accel, &camera, image, &hits);
        View::assemble(scene, camera, image, loose, hits, pixels)
    }

    /// [`View::new_with`] shared by the processes of `shard`: each casts the corner and
    /// center rays of the bands of [`ROW_BAND`] rows it owns (band `y / ROW_BAND`), and the
    /// hits and classifications are gathered, so every process ends with the view one
    /// process makes, bit for bit, for a share of its rays.
    pub fn new_shared(
        scene: &Scene,
        accel: &Accel,
        camera: Camera,
        image: &'a Image,
        loose: bool,
        shard: &Shard,
    ) -> Result<View<'a>> {
        if shard.alone {
            return Ok(View::new_with(scene, accel, camera, image, loose));
        }
        let owns = shard.owns;
        let mine = move |y: u32| owns((y / ROW_BAND) as usize);
        let (w, gw) = (camera.width() as usize, camera.width() as usize + 1);
        let hits = trace_corners(accel, &camera, &mine);
        let hits = decode_corners(&sync_rows(shard, encode_corners(&hits), gw * CORNER_WORDS)?);
        let infos = center_rays(scene, accel, &camera, image, &hits, &mine);
        let infos = decode_pixels(&sync_rows(shard, encode_pixels(&infos), w * PIXEL_WORDS)?);
        let pixels = erode_to_filter(infos, &camera);
        Ok(View::assemble(scene, camera, image, loose, hits, pixels))
    }

    /// The view from its corner hits and classified pixels (and, with `loose`, what the loose
    /// reading needs of them).
    fn assemble(
        scene: &Scene,
        camera: Camera,
        image: &'a Image,
        loose: bool,
        hits: Vec<Option<(Hit, Vec3)>>,
        pixels: Vec<PixelInfo>,
    ) -> View<'a> {
        let (hot, spans) = match loose {
            true => {
                let hot = one_surface::near_emitters(scene, &camera, &hits);
                let spans = one_surface::spans(&camera, image, &hits, &hot);
                (hot, spans)
            }
            false => (Vec::new(), Vec::new()),
        };
        let corners = hits
            .iter()
            .map(|h| match h {
                Some((hit, _)) => Corner {
                    prim: hit.prim,
                    b1: hit.b1,
                    b2: hit.b2,
                },
                None => Corner {
                    prim: NONE,
                    b1: 0.0,
                    b2: 0.0,
                },
            })
            .collect();
        View {
            camera,
            image,
            pixels: Arc::new(pixels),
            traced: Arc::new(Traced {
                corners,
                spans,
                hot,
            }),
        }
    }

    /// The view's classified pixels and corner hits as words, made as they are read (a view
    /// of 512 x 384 is 7 MB of them): [`View::from_words`] makes the view again (without the
    /// loose reading's parts) for no rays.
    pub fn words(&self) -> impl Iterator<Item = u32> + '_ {
        let f = f32::to_bits;
        let corners = (self.traced.corners.iter()).flat_map(move |c| [c.prim, f(c.b1), f(c.b2)]);
        self.pixels.iter().flat_map(pixel_words).chain(corners)
    }

    /// How many [`View::words`] a view of `camera` has.
    pub fn word_count(camera: &Camera) -> usize {
        let (w, h) = (camera.width() as usize, camera.height() as usize);
        w * h * PIXEL_WORDS + (w + 1) * (h + 1) * 3
    }

    /// The view [`View::words`] wrote, of `camera` (the one it was made with) and `image`:
    /// what [`View::new`] makes of them, bit for bit, when `image` masks the pixels the
    /// view's own photo masked (a pixel `image` masks is made unclean, as
    /// [`View::with_image`] does). `None` if the words do not fit the camera's size.
    pub fn from_words(camera: Camera, image: &'a Image, words: &[u32]) -> Option<View<'a>> {
        let (w, h) = (camera.width() as usize, camera.height() as usize);
        let np = w * h * PIXEL_WORDS;
        if words.len() != View::word_count(&camera)
            || (image.width, image.height) != (w as u32, h as u32)
        {
            return None;
        }
        let f = f32::from_bits;
        let corners = (words[np..].chunks_exact(3))
            .map(|c| Corner {
                prim: c[0],
                b1: f(c[1]),
                b2: f(c[2]),
            })
            .collect();
        let rays = Rays {
            camera,
            pixels: Arc::new(decode_pixels(&words[..np])),
            traced: Arc::new(Traced {
                corners,
                spans: Vec::new(),
                hot: Vec::new(),
            }),
        };
        Some(rays.with_image(image))
    }

    /// The same view (camera, pixel classification, corners) of another photo of the same
    /// size: no rays are cast again.
    pub fn with_image<'b>(&self, image: &'b Image) -> View<'b> {
        self.rays().with_image(image)
    }

    /// What the view's rays found, without its photo (shared, not copied).
    pub fn rays(&self) -> Rays {
        Rays {
            camera: self.camera.clone(),
            pixels: Arc::clone(&self.pixels),
            traced: Arc::clone(&self.traced),
        }
    }

    /// Per pixel, whether a clean pixel lies within `n` pixels of it (the clean mask for
    /// `n = 0`).
    pub fn near_clean(&self, n: u32) -> Vec<bool> {
        let (w, h) = (self.camera.width() as i64, self.camera.height() as i64);
        let n = n as i64;
        let clean = |x: i64, y: i64| {
            x >= 0 && y >= 0 && x < w && y < h && self.pixels[(y * w + x) as usize].clean
        };
        (0..h)
            .flat_map(|y| {
                (0..w).map(move |x| (-n..=n).any(|dy| (-n..=n).any(|dx| clean(x + dx, y + dy))))
            })
            .collect()
    }

    /// A clean pixel whose four corners lie on one chart, with their texel coordinates (see
    /// [`FlatPixel`]); `None` for every other pixel.
    pub fn flat(&self, hits: &HitTable, x: u32, y: u32) -> Option<FlatPixel> {
        let w = self.camera.width();
        let px = &self.pixels[(y * w + x) as usize];
        if !px.clean {
            return None;
        }
        let gw = (w + 1) as usize;
        let mut uv = [Vec2::ZERO; 4];
        let mut chart = None;
        for (k, (gx, gy)) in [(x, y), (x + 1, y), (x, y + 1), (x + 1, y + 1)]
            .into_iter()
            .enumerate()
        {
            let c = self.traced.corners[gy as usize * gw + gx as usize];
            if c.prim == NONE {
                return None;
            }
            let pr = hits.prim(c.prim);
            if pr.shape != px.shape || pr.chart == NONE || chart.is_some_and(|ch| ch != pr.chart) {
                return None;
            }
            chart = Some(pr.chart);
            uv[k] = pr.uv[0] * (1.0 - c.b1 - c.b2) + pr.uv[1] * c.b1 + pr.uv[2] * c.b2;
        }
        Some(FlatPixel {
            shape: px.shape,
            uv,
        })
    }

    /// Whether pixel `(x, y)` is a clean pixel seeing point `q` of `shape` (geometric normal
    /// `n`): the plane it sees is `q`'s, within `tol`.
    fn sees(&self, x: i64, y: i64, q: Vec3, shape: u32, n: Vec3, tol: f32) -> bool {
        let (w, h) = (self.camera.width() as i64, self.camera.height() as i64);
        if x < 0 || y < 0 || x >= w || y >= h {
            return false;
        }
        let p = &self.pixels[(y * w + x) as usize];
        p.clean
            && p.shape == shape
            && p.normal.dot(n).abs() > 0.99
            && (p.normal.dot(q) - p.plane).abs() <= tol
    }

    /// Whether pixel `(x, y)` sees point `q` of `shape` (geometric normal `n`) first, from the
    /// classification alone: `Some` where the pixel is clean (it sees one plane of one shape,
    /// and `q` lies in the pixel's cone: seen exactly when `q` lies on that plane), `None`
    /// where it is not (an edge, a masked pixel: only a ray can tell).
    pub fn sees_first(&self, (x, y): (u32, u32), q: Vec3, shape: u32, n: Vec3) -> Option<bool> {
        let w = self.camera.width();
        let p = self.pixels.get((y * w + x) as usize)?;
        let tol = plane_tol((q - self.camera.position()).length());
        p.clean
            .then(|| self.sees(x as i64, y as i64, q, shape, n, tol))
    }

    /// The photo's radiance at surface point `q` of `shape` (geometric normal `n`), projected
    /// to continuous pixel coordinates `pix`, if the view sees it: bilinear when the four
    /// nearest pixels are clean pixels seeing `q`'s plane, else the containing pixel if it is,
    /// else `None` (occluded, on an edge, off the film).
    pub fn sample(&self, pix: Vec2, q: Vec3, shape: u32, n: Vec3) -> Option<Vec3> {
        self.sample_from(pix, q, shape, n, &|x, y| self.image.get(x, y))
    }

    /// [`View::sample`] reading pixel values from `get` instead of the photo (a residual of
    /// the same size, say), with the same lookups.
    pub fn sample_from<T: Value>(
        &self,
        pix: Vec2,
        q: Vec3,
        shape: u32,
        n: Vec3,
        get: &dyn Fn(u32, u32) -> T,
    ) -> Option<T> {
        Some(self.tap(pix, q, shape, n)?.read(self.camera.width(), get))
    }

    /// Which pixels [`View::sample`] reads for `q` and with what weights, without reading
    /// them (`None` where it reads none).
    pub fn tap(&self, pix: Vec2, q: Vec3, shape: u32, n: Vec3) -> Option<Tap> {
        let tol = plane_tol((q - self.camera.position()).length());
        let sees = |x: i64, y: i64| self.sees(x, y, q, shape, n, tol);
        let w = self.camera.width() as i64;
        let fx = pix.x - 0.5;
        let fy = pix.y - 0.5;
        let (x0, y0) = (fx.floor() as i64, fy.floor() as i64);
        let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
        let quad = [(x0, y0), (x0 + 1, y0), (x0, y0 + 1), (x0 + 1, y0 + 1)];
        if quad.iter().all(|&(x, y)| sees(x, y)) {
            let base = (y0 * w + x0) as u32;
            return Some(Tap { base, tx, ty });
        }
        let (x, y) = (pix.x.floor() as i64, pix.y.floor() as i64);
        sees(x, y).then(|| Tap {
            base: (y * w + x) as u32,
            tx: Tap::ONE_PIXEL,
            ty: 0.0,
        })
    }
}

/// Where one look-up reads a photo: bilinear over the four pixels from `base` (row-major
/// index; `base + 1`, `base + width`, `base + width + 1`) with fractions `tx`, `ty`, or the
/// pixel `base` alone (`tx` = [`Tap::ONE_PIXEL`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tap {
    pub base: u32,
    pub tx: f32,
    pub ty: f32,
}

impl Tap {
    /// The `tx` of a tap that reads one pixel.
    pub const ONE_PIXEL: f32 = -1.0;

    /// The bilinear tap at continuous pixel coordinates `q` of a `width x height` image, if
    /// the four pixels around `q` are all on it.
    pub fn inside(q: Vec2, width: usize, height: usize) -> Option<Tap> {
        let (fx, fy) = (q.x - 0.5, q.y - 0.5);
        if !(fx >= 0.0 && fy >= 0.0) {
            return None;
        }
        let (x0, y0) = (fx as usize, fy as usize);
        if x0 + 1 >= width || y0 + 1 >= height {
            return None;
        }
        let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
        let base = (y0 * width + x0) as u32;
        Some(Tap { base, tx, ty })
    }

    /// The value at this tap of an image `width` pixels wide read through `get(x, y)`.
    #[inline(always)]
    pub fn read<T: Value>(&self, width: u32, get: &dyn Fn(u32, u32) -> T) -> T {
        let (x, y) = (self.base % width, self.base / width);
        if self.tx == Tap::ONE_PIXEL {
            return get(x, y);
        }
        let (tx, ty) = (self.tx, self.ty);
        let top = get(x, y) * (1.0 - tx) + get(x + 1, y) * tx;
        let bot = get(x, y + 1) * (1.0 - tx) + get(x + 1, y + 1) * tx;
        top * (1.0 - ty) + bot * ty
    }

    /// [`Tap::read`] from a row-major image `width` pixels wide held in `values`.
    #[inline(always)]
    pub fn read_slice<T: Value>(&self, width: u32, values: &[T]) -> T {
        self.read_index(width, |i| values[i])
    }

    /// [`Tap::read`] from a row-major image `width` pixels wide whose pixel `i` is `at(i)`.
    #[inline(always)]
    pub fn read_index<T: Value>(&self, width: u32, at: impl Fn(usize) -> T) -> T {
        let b = self.base as usize;
        if self.tx == Tap::ONE_PIXEL {
            return at(b);
        }
        let (tx, ty, w) = (self.tx, self.ty, width as usize);
        let top = at(b) * (1.0 - tx) + at(b + 1) * tx;
        let bot = at(b + w) * (1.0 - tx) + at(b + w + 1) * tx;
        top * (1.0 - ty) + bot * ty
    }
}

impl View<'_> {
    /// Whether the view was built for the loose reading ([`View::new_with`]).
    pub fn is_loose(&self) -> bool {
        !self.traced.spans.is_empty()
    }

    /// Whether the photo's pixel `(x, y)` holds a valid value with no emitter within reach.
    pub fn usable(&self, x: u32, y: u32) -> bool {
        self.image.is_valid(x, y) && !self.traced.hot[(y * self.camera.width() + x) as usize]
    }

    /// The photo's radiance at point `q` of `shape`, projected to `pix`, read from pixels that
    /// see one surface of the shape at `q`'s distance, planar or not (`one_surface`): bilinear
    /// when the four nearest do, else the containing pixel if it does, else `None`.
    pub fn sample_loose(&self, pix: Vec2, q: Vec3, shape: u32) -> Option<Vec3> {
        let (w, h) = (self.camera.width() as i64, self.camera.height() as i64);
        let d = (q - self.camera.position()).length();
        let tol = plane_tol(d);
        let holds = |x: i64, y: i64| {
            x >= 0
                && y >= 0
                && x < w
                && y < h
                && self.traced.spans[(y * w + x) as usize].is_some_and(|s| s.holds(shape, d, tol))
        };
        let get = |x: i64, y: i64| self.image.get(x as u32, y as u32);
        let (fx, fy) = (pix.x - 0.5, pix.y - 0.5);
        let (x0, y0) = (fx.floor() as i64, fy.floor() as i64);
        let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
        let quad = [(x0, y0), (x0 + 1, y0), (x0, y0 + 1), (x0 + 1, y0 + 1)];
        if quad.iter().all(|&(x, y)| holds(x, y)) {
            let top = get(x0, y0) * (1.0 - tx) + get(x0 + 1, y0) * tx;
            let bot = get(x0, y0 + 1) * (1.0 - tx) + get(x0 + 1, y0 + 1) * tx;
            return Some(top * (1.0 - ty) + bot * ty);
        }
        let (x, y) = (pix.x.floor() as i64, pix.y.floor() as i64);
        holds(x, y).then(|| get(x, y))
    }
}

/// What a view's pixels can hold for sampling: values that mix linearly (radiance, or a
/// radiance with a second image's value beside it, [`Pair`]).
pub trait Value:
    Copy
    + Default
    + std::ops::Add<Output = Self>
    + std::ops::AddAssign
    + std::ops::Mul<f32, Output = Self>
    + std::ops::Div<f32, Output = Self>
{
}

impl<T> Value for T where
    T: Copy
        + Default
        + std::ops::Add<Output = T>
        + std::ops::AddAssign
        + std::ops::Mul<f32, Output = T>
        + std::ops::Div<f32, Output = T>
{
}

/// Two images' values at one pixel, a level (the photo's relative noise there) and the
/// shrinkage's keep factor, sampled together (one set of lookups for all four).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Pair(pub Vec3, pub Vec3, pub f32, pub f32);

impl std::ops::Add for Pair {
    type Output = Pair;
    fn add(self, o: Pair) -> Pair {
        Pair(self.0 + o.0, self.1 + o.1, self.2 + o.2, self.3 + o.3)
    }
}

impl std::ops::AddAssign for Pair {
    fn add_assign(&mut self, o: Pair) {
        self.0 += o.0;
        self.1 += o.1;
        self.2 += o.2;
        self.3 += o.3;
    }
}

impl std::ops::Mul<f32> for Pair {
    type Output = Pair;
    fn mul(self, k: f32) -> Pair {
        Pair(self.0 * k, self.1 * k, self.2 * k, self.3 * k)
    }
}

impl std::ops::Div<f32> for Pair {
    type Output = Pair;
    fn div(self, k: f32) -> Pair {
        Pair(self.0 / k, self.1 / k, self.2 / k, self.3 / k)
    }
}

/// Classify every pixel of `image` as seen by `camera` (see [`View::new`]).
pub fn classify_pixels(
    scene: &Scene,
    accel: &Accel,
    camera: &Camera,
    image: &Image,
) -> Vec<PixelInfo> {
    classify(
        scene,
        accel,
        camera,
        image,
        &trace_corners(accel, camera, &|_| true),
    )
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::atlas::store::{TexelState, TileStore};
    use std::sync::{Barrier, Mutex};

    /// What a view holds, comparable.
    type Parts = (Vec<u32>, Vec<Corner>, Vec<Option<Span>>, Vec<bool>);

    fn parts(v: &View) -> Parts {
        let pixels = encode_pixels(&v.pixels);
        let t = &v.traced;
        (pixels, t.corners.clone(), t.spans.clone(), t.hot.clone())
    }

    /// `n` processes as threads: each casts the rays of its own bands of rows and the bands
    /// are exchanged through shared memory as `ranks::share_bytes` exchanges them over MPI.
    fn shared_views(
        n: usize,
        scene: &Scene,
        accel: &Accel,
        cam: &Camera,
        img: &Image,
    ) -> Vec<Parts> {
        let slots = Mutex::new(vec![Vec::new(); n]);
        let barrier = Barrier::new(n);
        std::thread::scope(|s| {
            let handles: Vec<_> = (0..n)
                .map(|r| {
                    let (slots, barrier) = (&slots, &barrier);
                    s.spawn(move || {
                        let owns = move |u: usize| u % n == r;
                        let sync = |_: &mut TileStore<TexelState>| -> Result<()> { Ok(()) };
                        let pixels = |_: &mut [Option<Vec3>], _: usize| -> Result<()> { Ok(()) };
                        let bytes = |buf: &mut [u8], unit: usize| -> Result<()> {
                            slots.lock().unwrap()[r] = buf.to_vec();
                            barrier.wait();
                            let all = slots.lock().unwrap().clone();
                            for (u, b) in buf.chunks_mut(unit).enumerate() {
                                let at = u * unit;
                                b.copy_from_slice(&all[u % n][at..at + b.len()]);
                            }
                            barrier.wait();
                            Ok(())
                        };
                        let sum = |v: u64| v;
                        let shard = Shard {
                            owns: &owns,
                            sync: &sync,
                            sync_pass: &|_| Ok(()),
                            sync_pixels: &pixels,
                            sync_bytes: &bytes,
                            sum: &sum,
                            alone: false,
                        };
                        let v = View::new_shared(scene, accel, cam.clone(), img, true, &shard);
                        parts(&v.unwrap())
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        })
    }

    /// The Cornell box fixture, its BVH and its first camera.
    pub(in crate::stages::project) fn cbox_first_camera() -> (Scene, Accel, Camera) {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let scene =
            crate::scene::mitsuba::load(&root.join("tests/fixtures/cbox/input.xml")).unwrap();
        let accel = Accel::build(&scene);
        let cam = Camera::from_sensor(&scene.sensors[0]);
        (scene, accel, cam)
    }

    /// A grey photo of `cam`'s size with one pixel masked (NaN), as pixel values.
    pub(in crate::stages::project) fn grey_with_a_masked_pixel(cam: &Camera) -> Vec<Vec3> {
        let w = cam.width();
        let mut px = vec![Vec3::splat(0.4); (w * cam.height()) as usize];
        px[(37 * w + 101) as usize] = Vec3::NAN;
        px
    }

    /// Whether a clean pixel sees a surface point, read from the classification, is what a
    /// ray from the camera to the point finds, for random points of every shape (in view,
    /// occluded, behind a box, on the emitter); edges and the masked pixel leave it to a ray.
    #[test]
    fn sees_first_is_what_a_ray_from_the_camera_finds() {
        let (scene, accel, cam) = cbox_first_camera();
        let img = Image::from_raw(cam.width(), cam.height(), grey_with_a_masked_pixel(&cam));
        let view = View::new_with(&scene, &accel, cam.clone(), &img, false);
        let mut rng = crate::base::rng::Rng::new(5, 0, 0, 0);
        let (mut seen, mut hidden, mut unknown) = (0, 0, 0);
        for _ in 0..20_000 {
            let s = (rng.f32() * scene.shapes.len() as f32) as usize % scene.shapes.len();
            let mesh = &scene.shapes[s].mesh;
            let t = (rng.f32() * mesh.triangles.len() as f32) as usize % mesh.triangles.len();
            let [a, b, c] = mesh.triangles[t].map(|i| mesh.positions[i as usize]);
            let (u, v) = (rng.f32(), rng.f32());
            let (u, v) = if u + v > 1.0 {
                (1.0 - u, 1.0 - v)
            } else {
                (u, v)
            };
            let q = a + (b - a) * u + (c - a) * v;
            let n = mesh.face_normal_raw(t).normalize_or_zero();
            let Some(pix) = cam.project(q).filter(|p| cam.on_film(*p)) else {
                continue;
            };
            let (x, y) = (pix.x as u32, pix.y as u32);
            let Some(got) = view.sees_first((x, y), q, s as u32, n) else {
                unknown += 1;
                continue;
            };
            let from = cam.position();
            let dist = (q - from).length();
            let hit = accel.intersect(from, (q - from) / dist, f32::INFINITY);
            // seen: the ray's first hit lies on q's plane of q's shape
            let want = hit.is_some_and(|h| {
                let m = &scene.shapes[h.shape as usize].mesh;
                let hn = m.face_normal_raw(h.tri as usize).normalize_or_zero();
                h.shape == s as u32 && hn.dot(n) > 0.99 && (h.t - dist).abs() < 1e-3 * dist
            });
            assert_eq!(got, want, "{q} of shape {s} at pixel {x} {y}");
            (seen, hidden) = (seen + got as u32, hidden + !got as u32);
        }
        assert!(
            seen > 3000 && hidden > 1000 && unknown > 50,
            "{seen} {hidden} {unknown}"
        );
    }

    /// The classification split among 2 and 3 processes by bands of rows and gathered is the
    /// one process's, bit for bit, on every process (with a masked pixel, an emitter in view
    /// and the loose reading's spans).
    #[test]
    fn rays_split_among_processes_and_gathered_classify_as_one_process() {
        let (scene, accel, cam) = cbox_first_camera();
        let (w, h) = (cam.width(), cam.height());
        let img = Image::from_raw(w, h, grey_with_a_masked_pixel(&cam));
        let one = parts(&View::new_with(&scene, &accel, cam.clone(), &img, true));
        assert!(one.0.chunks(PIXEL_WORDS).any(|p| p[5] == 1), "clean pixels");
        assert!(one.3.iter().any(|&b| b), "an emitter in view");
        for n in [2, 3] {
            for (r, got) in shared_views(n, &scene, &accel, &cam, &img)
                .iter()
                .enumerate()
            {
                assert!(got == &one, "{n} processes, rank {r}");
            }
        }
    }

    /// Another photo of the same camera shares the view's ray results; one that masks clean
    /// pixels gets its own classification with exactly those pixels unclean, and the result
    /// is the view built on that photo from scratch.
    #[test]
    fn a_view_of_another_photo_shares_its_rays_and_masks_what_the_photo_masks() {
        let (scene, accel, cam) = cbox_first_camera();
        let (w, h) = (cam.width(), cam.height());
        let img = Image::from_raw(w, h, vec![Vec3::splat(0.4); (w * h) as usize]);
        let view = View::new_with(&scene, &accel, cam.clone(), &img, true);
        let brighter = Image::from_raw(w, h, vec![Vec3::splat(0.8); (w * h) as usize]);
        let same = view.with_image(&brighter);
        assert!(
            Arc::ptr_eq(&same.pixels, &view.pixels),
            "nothing masked: shared"
        );
        assert!(Arc::ptr_eq(&same.traced, &view.traced));
        assert!(std::ptr::eq(same.image, &brighter));
        let masked_at = (0..(w * h) as usize)
            .find(|&i| view.pixels[i].clean)
            .unwrap();
        let mut px = vec![Vec3::splat(0.4); (w * h) as usize];
        px[masked_at] = Vec3::NAN;
        let masking = Image::from_raw(w, h, px);
        let own = view.with_image(&masking);
        assert!(!Arc::ptr_eq(&own.pixels, &view.pixels));
        assert!(Arc::ptr_eq(&own.traced, &view.traced));
        let changed: Vec<usize> = (0..(w * h) as usize)
            .filter(|&i| own.pixels[i] != view.pixels[i])
            .collect();
        assert_eq!(changed, vec![masked_at]);
        assert!(!own.pixels[masked_at].clean);
        let fresh = View::new_with(&scene, &accel, cam, &masking, true);
        assert!(
            own.pixels == fresh.pixels,
            "as if built on the masking photo"
        );
        assert!(parts(&own).1 == parts(&fresh).1, "corners");
    }
}
