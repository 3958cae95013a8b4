//! Texel density from the photos (`texels_per_unit = "auto"`, the default): per shape, the
//! density of [`OVERSAMPLE`] texels per edge of the finest pixel footprint any photo gives the
//! shape, capped by the largest texture and a total texel budget. It needs kdmap's cameras, BVH and
//! atlas sizes together, which no library has, so it is written here.
//!
//! A view's footprint on a shape is the median, over a sparse grid of its pixels (every
//! [`STRIDE`]-th in x and y) whose primary ray hits the shape, of the edge of the pixel's
//! footprint on the surface (`sqrt` of its area: a grazing view's long, thin footprint counts
//! by its area); the shape's finest footprint is the smallest of its views' (views with at
//! least [`MIN_SAMPLES`] such pixels). Medians are taken by rank after sorting, so the result
//! does not depend on the order rays finish in.
//!
//! Within a shape the density follows the photos per triangle: a triangle's footprint is the
//! finest any view that sees the shape gives it, at its corners and centre (to first order,
//! [`Camera::pixel_footprint_area`], where they fall on the film and face the camera) and at
//! the sampled pixels that hit it. A triangle that the photos resolve `2^k` times coarser than
//! the shape's footprint above gets density level `k` (`2^-k` times the shape's density, at
//! most [`LEVELS`] levels down; triangles no photo sees take the coarsest). A 20 m ground seen
//! closely near the cameras and at a grazing angle far away thus spends its texels near the
//! cameras, instead of one density over all of it. Occlusion is not traced for the corners:
//! a triangle hidden from a view that sees its shape counts as seen (finer than needed, never
//! coarser).

use crate::physics::accel::Accel;
use crate::physics::camera::Camera;
use crate::scene::{Mesh, Scene, Sides};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Every `STRIDE`-th pixel in x and y is sampled.
pub const STRIDE: u32 = 4;
/// A view counts for a shape only if at least this many sampled pixels see it.
pub const MIN_SAMPLES: usize = 16;
/// Texels per finest pixel footprint, along each axis: 2, so that the projection's refinement
/// can place detail that several views see at different sub-pixel offsets (one texel per
/// footprint cannot hold it; three resolve no more than two).
pub const OVERSAMPLE: f32 = 2.0;
/// The default texel budget is [`TEXELS_PER_PIXEL`] times the photos' pixel count, at most
/// this many: beyond it a run's time and memory grow faster than its accuracy (set
/// `max_texels` to go further).
pub const DEFAULT_MAX_TEXELS: u64 = 1 << 20;
/// Texels per photo pixel in the default budget: 2. The photos see the surfaces unevenly (a
/// large ground near one camera and far from the rest, small objects close up), so one texel
/// per pixel leaves shapes below what the photos resolve where they look closest; at 4 each
/// texel holds fewer pixels, so more photo noise, for little gain in detail.
pub const TEXELS_PER_PIXEL: u64 = 2;

/// The default texel budget for photos of `pixels` pixels in all.
pub fn default_budget(pixels: u64) -> u64 {
    (TEXELS_PER_PIXEL * pixels).min(DEFAULT_MAX_TEXELS)
}
/// Packing overhead of an atlas: its side is about `density * sqrt(PACKING * area)`.
const PACKING: f64 = 1.6;
/// Density of shapes no photo sees when no shape is seen at all: a moderate fixed density.
pub const FALLBACK: f32 = 64.0;
/// Density levels below a shape's density (level `k`: `2^-k` times it): 3, so triangles far
/// from every camera, or unseen, still get an eighth of the near ones' density (linear).
pub const LEVELS: u8 = 3;

/// The density chosen for one reconstructed shape.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShapeDensity {
    /// Texels per scene unit of length.
    pub texels_per_unit: f32,
    /// Scene units per pixel in the view that sees the shape finest (`None`: unseen).
    pub finest_footprint: Option<f32>,
    /// What lowered the density below the photos' (`"max_texture_size"`, `"max_texels"`), or
    /// `"unseen"` when no photo sees the shape.
    pub limited_by: Option<String>,
    /// Per triangle, its density level (`2^-level` times `texels_per_unit`); empty: every
    /// triangle at level 0.
    #[serde(skip)]
    pub levels: Vec<u8>,
}

impl ShapeDensity {
    /// The surface area of `mesh` weighted by its triangles' texel share at their levels:
    /// `sum(area * 4^-level)`, so that the shape needs `effective_area * density^2` texels.
    pub fn effective_area(&self, mesh: &Mesh) -> f64 {
        effective_area(mesh, &self.levels)
    }

    /// The share of `mesh`'s area at each density level `0..=LEVELS`; `None` if the shape has
    /// one density.
    pub fn level_shares(&self, mesh: &Mesh) -> Option<[f64; LEVELS as usize + 1]> {
        if self.levels.is_empty() {
            return None;
        }
        let mut by = [0.0; LEVELS as usize + 1];
        for (t, &l) in self.levels.iter().enumerate() {
            by[usize::from(l.min(LEVELS))] += mesh.triangle_area(t) as f64;
        }
        let total: f64 = by.iter().sum();
        Some(by.map(|a| if total > 0.0 { a / total } else { 0.0 }))
    }
}

/// `sum(area * 4^-level)` over `mesh`'s triangles (`levels` empty: the area).
pub fn effective_area(mesh: &Mesh, levels: &[u8]) -> f64 {
    if levels.is_empty() {
        return mesh.area();
    }
    (0..mesh.triangles.len())
        .map(|t| mesh.triangle_area(t) as f64 * 0.25f64.powi(i32::from(levels[t])))
        .sum()
}

/// Densities of every shape (`None` for shapes that are not reconstructed) and the budget.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DensityPlan {
    pub shapes: Vec<Option<ShapeDensity>>,
    /// The texel budget (`max_texels`, or [`default_budget`] of the photos' pixel count).
    pub budget: u64,
    /// Surface texels the densities give, estimated as `sum(area * density^2)`.
    pub estimated_texels: u64,
    /// One line per cap applied, for the user.
    pub notes: Vec<String>,
}

impl DensityPlan {
    /// `texels_per_unit` on every reconstructed shape of `scene` (`texels_per_unit = N`).
    pub fn fixed(scene: &Scene, texels_per_unit: f32) -> DensityPlan {
        let shapes: Vec<Option<ShapeDensity>> = scene
            .shapes
            .iter()
            .map(|s| {
                s.in_atlas().then_some(ShapeDensity {
                    texels_per_unit,
                    finest_footprint: None,
                    limited_by: None,
                    levels: Vec::new(),
                })
            })
            .collect();
        let estimated_texels = estimate(scene, &shapes).round() as u64;
        DensityPlan {
            shapes,
            budget: 0,
            estimated_texels,
            notes: Vec::new(),
        }
    }
}

/// Pixels in the photos of `sensors` (the default texel budget).
pub fn photo_pixels(scene: &Scene, sensors: &[usize]) -> u64 {
    sensors
        .iter()
        .map(|&i| scene.sensors[i].width as u64 * scene.sensors[i].height as u64)
        .sum()
}

/// What a run will need, estimated before it starts (for `kdmap inspect`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Needs {
    /// Texels in the tile stores (surface texels plus gutters and tile rounding, estimated).
    pub store_texels: u64,
    /// Disk: geometry and state stores, two checkpoint snapshots, the output textures and maps.
    pub disk_bytes: u64,
    /// Peak memory: meshes and BVH, photos and their cached rays, the gather's tables, and the
    /// mapped tiles (at most `memory_budget_mib`).
    pub memory_bytes: u64,
}

/// Stored texels per surface texel (chart gutters, tile rounding): about 1.1 on a room of
/// large charts, 2.2 on boxes of small ones.
const STORE_OVERHEAD: f64 = 1.5;

/// Gather points per (surface area / spacing^2): one per chart per cell, and a cell holds
/// more than one chart along seams and on small parts (a room of 1.1M triangles and 157 m^2
/// has about 2.3 points per cell at spacing 0.13).
const GATHER_POINTS_PER_CELL: f64 = 2.5;

/// Bytes the gather's ray cache can take at most (`crate::stages::indirect::gather::GatherCache`): per point its
/// fixed part and offsets, and a 32-byte record per ray that could hit an unobserved texel
/// (all of them, at worst). It follows the scene's area over the spacing squared, not the
/// texel count: a finer atlas does not grow it.
pub fn gather_bytes(area: f64, spacing: f32, rays: u32) -> u64 {
    let s = f64::from(spacing.max(1e-6));
    let points = (area / (s * s) * GATHER_POINTS_PER_CELL).ceil() as u64;
    points * (12 + 8 + u64::from(rays) * 32)
}

/// [`Needs`] of a run over `plan` with `pixels` photo pixels, a tile budget in bytes and a
/// gather cache of at most `gather` bytes ([`gather_bytes`]; 0 for photon tracing).
pub fn needs(
    scene: &Scene,
    plan: &DensityPlan,
    pixels: u64,
    (budget_bytes, gather): (u64, u64),
) -> Needs {
    use crate::atlas::store::{TexelGeom, TexelState};
    let (geom, state) = (
        std::mem::size_of::<TexelGeom>() as u64,
        std::mem::size_of::<TexelState>() as u64,
    );
    let store_texels = (plan.estimated_texels as f64 * STORE_OVERHEAD) as u64;
    let stores = store_texels * (geom + state);
    // textures and maps: about ten float RGB(A) EXRs and PNG previews per texel
    let outputs = plan.estimated_texels * 10 * 14;
    let tris = scene.triangle_count() as u64;
    let verts: u64 = scene
        .shapes
        .iter()
        .map(|s| s.mesh.positions.len() as u64)
        .sum();
    let scene_bytes = tris * (12 + 64 + 48) + verts * 32;
    // photos (RGB f32 and a mask), the projection's rays per pixel (classification and
    // corner), and every view's residual (raw, noise level, keep factor) and render, which
    // the refinement passes hold at once
    let photo_bytes = pixels * (13 + 36 + 20 + 16);
    Needs {
        store_texels,
        disk_bytes: stores + 2 * store_texels * state + outputs,
        memory_bytes: scene_bytes + photo_bytes + gather + stores.min(budget_bytes),
    }
}

/// What the photos resolve (scene units per pixel, the edge of a pixel's footprint).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Footprints {
    /// Per shape, the median footprint of the view that sees it finest, or `None` if no view
    /// sees it with [`MIN_SAMPLES`] sampled pixels.
    pub shapes: Vec<Option<f32>>,
    /// Per shape, per triangle, the finest footprint any view that sees the shape gives the
    /// triangle (`f32::INFINITY`: none); empty for shapes outside the atlas.
    pub triangles: Vec<Vec<f32>>,
}

/// [`Footprints`] of `scene` in the photos of `views` (sensor indices).
pub fn finest_footprints(scene: &Scene, accel: &Accel, views: &[usize]) -> Footprints {
    let mut out = Footprints {
        shapes: vec![None; scene.shapes.len()],
        triangles: scene
            .shapes
            .iter()
            .map(|s| match s.in_atlas() {
                true => vec![f32::INFINITY; s.mesh.triangles.len()],
                false => Vec::new(),
            })
            .collect(),
    };
    for &v in views {
        let cam = Camera::from_sensor(&scene.sensors[v]);
        let mut per: Vec<Vec<f32>> = vec![Vec::new(); scene.shapes.len()];
        for (s, t, e) in view_samples(scene, accel, &cam) {
            per[s as usize].push(e);
            let f = &mut out.triangles[s as usize][t as usize];
            *f = f.min(e);
        }
        for (s, mut e) in per.into_iter().enumerate() {
            if e.len() < MIN_SAMPLES {
                continue;
            }
            e.sort_by(f32::total_cmp);
            let m = e[e.len() / 2];
            out.shapes[s] = Some(out.shapes[s].map_or(m, |b| b.min(m)));
            corner_footprints(&scene.shapes[s], &cam, &mut out.triangles[s]);
        }
    }
    out
}

/// `(shape, triangle, footprint edge)` of every sampled pixel of `cam` whose primary ray hits
/// a reconstructed shape, in pixel order.
fn view_samples(scene: &Scene, accel: &Accel, cam: &Camera) -> Vec<(u32, u32, f32)> {
    sampled_pixels(cam, |x, y| pixel_footprint(scene, accel, cam, x, y))
}

/// `f(x, y)` of every `STRIDE`-th pixel of `cam` in x and y where it gives a value, in pixel
/// order (rows in parallel).
pub(super) fn sampled_pixels<T: Send>(
    cam: &Camera,
    f: impl Fn(u32, u32) -> Option<T> + Sync,
) -> Vec<T> {
    let rows: Vec<Vec<T>> = (0..cam.height())
        .into_par_iter()
        .step_by(STRIDE as usize)
        .map(|y| {
            (0..cam.width())
                .step_by(STRIDE as usize)
                .filter_map(|x| f(x, y))
                .collect()
        })
        .collect();
    rows.into_iter().flatten().collect()
}

/// Lowers each triangle's entry of `fine` to the footprint `cam` gives its corners and centre
/// where they fall on the film on a side of `shape` that reflects.
fn corner_footprints(shape: &crate::scene::Shape, cam: &Camera, fine: &mut [f32]) {
    let (mesh, eye) = (&shape.mesh, cam.position());
    fine.par_iter_mut().enumerate().for_each(|(t, f)| {
        let n = mesh.face_normal_raw(t);
        let [a, b, c] = mesh.triangle(t);
        for p in [a, b, c, (a + b + c) / 3.0] {
            if shape.sides == Sides::Front && n.dot(eye - p) <= 0.0 {
                continue;
            }
            if !cam.project(p).is_some_and(|q| cam.on_film(q)) {
                continue;
            }
            let area = cam.pixel_footprint_area(p, n);
            if area.is_finite() && area > 0.0 {
                *f = f.min(area.sqrt());
            }
        }
    });
}

/// `(shape, triangle, footprint edge)` of pixel `(x, y)`'s primary ray, if it hits a
/// reconstructed shape.
fn pixel_footprint(
    scene: &Scene,
    accel: &Accel,
    cam: &Camera,
    x: u32,
    y: u32,
) -> Option<(u32, u32, f32)> {
    let (o, d) = cam.ray(x as f32 + 0.5, y as f32 + 0.5);
    let hit = accel.intersect(o, d, f32::INFINITY)?;
    let shape = &scene.shapes[hit.shape as usize];
    if !shape.in_atlas() {
        return None;
    }
    let n = shape.mesh.face_normal_raw(hit.tri as usize);
    let area = cam.pixel_footprint_area(o + d * hit.t, n);
    (area.is_finite() && area > 0.0).then(|| (hit.shape, hit.tri, area.sqrt()))
}

/// Every triangle's density level for a shape whose finest view has median footprint
/// `median` (empty if all are at level 0): `round(log2(footprint / median))` within
/// `0..=LEVELS`, so triangles seen as finely as the shape's median pixel or finer keep the
/// shape's density and coarser ones step down; unseen triangles take `LEVELS`.
///
/// The shape's density is set by the median, not by its finest triangle: the finest would
/// give a Cornell box's walls more texels than their pixels' noise supports, and gains
/// nothing on large open scenes.
fn shape_levels(tris: &[f32], median: f32) -> Vec<u8> {
    let levels: Vec<u8> = tris
        .iter()
        .map(|&f| match f.is_finite() {
            true => (f / median).log2().round().clamp(0.0, f32::from(LEVELS)) as u8,
            false => LEVELS,
        })
        .collect();
    one_density_as_empty(levels)
}

/// `levels`, or no levels if they are all 0 (one density: [`ShapeDensity::levels`] empty).
fn one_density_as_empty(levels: Vec<u8>) -> Vec<u8> {
    match levels.iter().all(|&l| l == 0) {
        true => Vec::new(),
        false => levels,
    }
}

/// The note on the shapes whose density `max_size` capped, `(id, cap, what the photos
/// resolve)` each: in full for one, counted for several (each is in the report's atlas).
fn size_cap_note(capped: &[(&str, f32, f32)], max_size: u32) -> Option<String> {
    match capped {
        [] => None,
        [(id, cap, want)] => Some(format!(
            "shape '{id}': texel density capped at {cap:.1}/unit (the photos resolve {want:.1}) \
             to fit max_texture_size {max_size}"
        )),
        _ => Some(format!(
            "texel density capped below what the photos resolve to fit max_texture_size \
             {max_size} for {} shapes: {}",
            capped.len(),
            crate::report::summary::some_ids(capped.iter().map(|c| c.0))
        )),
    }
}

/// The densities for `fine` (from [`finest_footprints`]): per seen shape `OVERSAMPLE /` the
/// median footprint of its finest view, with per-triangle levels below it
/// ([`shape_levels`]); the coarsest seen density for unseen shapes; each capped so its atlas fits `max_size`, then all scaled down together
/// if they exceed `budget` texels.
pub fn plan(scene: &Scene, fine: &Footprints, max_size: u32, budget: u64) -> DensityPlan {
    let coarsest = fine
        .shapes
        .iter()
        .flatten()
        .map(|&e| OVERSAMPLE / e)
        .fold(None, |m: Option<f32>, d| Some(m.map_or(d, |m| m.min(d))))
        .unwrap_or(FALLBACK);
    let mut notes = Vec::new();
    let mut shapes: Vec<Option<ShapeDensity>> = scene
        .shapes
        .iter()
        .enumerate()
        .map(|(i, s)| {
            s.in_atlas().then(|| match fine.shapes[i] {
                Some(median) => ShapeDensity {
                    texels_per_unit: OVERSAMPLE / median,
                    finest_footprint: Some(median),
                    limited_by: None,
                    levels: shape_levels(&fine.triangles[i], median),
                },
                None => ShapeDensity {
                    texels_per_unit: coarsest,
                    finest_footprint: None,
                    limited_by: Some("unseen".to_string()),
                    levels: Vec::new(),
                },
            })
        })
        .collect();
    let mut capped = Vec::new();
    for (s, d) in scene.shapes.iter().zip(shapes.iter_mut()) {
        let Some(d) = d else { continue };
        let cap = size_cap(d.effective_area(&s.mesh), max_size);
        if d.texels_per_unit > cap {
            capped.push((s.id.as_str(), cap, d.texels_per_unit));
            d.texels_per_unit = cap;
            d.limited_by = Some("max_texture_size".into());
        }
    }
    notes.extend(size_cap_note(&capped, max_size));
    cap_levels(scene, &mut shapes);
    let total = estimate(scene, &shapes);
    if total > budget as f64 {
        // Coarser texels may lower a shape's level cap, which adds texels: a second, small
        // scaling takes those back.
        let mut k = 1.0f32;
        for _ in 0..2 {
            let now = estimate(scene, &shapes);
            if now <= budget as f64 {
                break;
            }
            let step = (budget as f64 / now).sqrt() as f32;
            k *= step;
            for d in shapes.iter_mut().flatten() {
                d.texels_per_unit *= step;
                d.limited_by.get_or_insert_with(|| "max_texels".into());
            }
            cap_levels(scene, &mut shapes);
        }
        notes.push(format!(
            "texel density capped by the texel budget: the photos resolve about {:.0} texels, \
             max_texels is {budget}; every shape's density x{k:.3} (set [atlas] max_texels or \
             texels_per_unit to change it)",
            total
        ));
    }
    for d in shapes.iter_mut().flatten() {
        d.texels_per_unit = round3(d.texels_per_unit);
    }
    DensityPlan {
        estimated_texels: estimate(scene, &shapes).round() as u64,
        shapes,
        budget,
        notes,
    }
}

/// A texel at any density level spans at most this share of its shape's bounding radius
/// (1/16, as the gather's points on small shapes). The projection samples a texel on its
/// tangent plane, so a texel much larger than a curved shape's triangles reads other parts
/// of the shape: on the envmap fixture's torus, texels 4 and 8 times the base size make
/// noise-free photos of a uniform albedo come out 13% too bright on average (up to 3.9x);
/// 1 and 2 times are exact.
const MAX_TEXEL_OF_RADIUS: f32 = 1.0 / 16.0;

/// Lowers every triangle's level to its shape's cap: the largest level whose texels
/// (`2^level / density`) are at most [`MAX_TEXEL_OF_RADIUS`] of the shape's bounding radius
/// (level 0 always stays).
fn cap_levels(scene: &Scene, shapes: &mut [Option<ShapeDensity>]) {
    for (s, d) in scene.shapes.iter().zip(shapes.iter_mut()) {
        let Some(d) = d.as_mut().filter(|d| !d.levels.is_empty()) else {
            continue;
        };
        let largest = s.mesh.bounding_radius() * MAX_TEXEL_OF_RADIUS * d.texels_per_unit;
        let cap = match largest >= 1.0 {
            true => largest.log2().floor().min(f32::from(LEVELS)) as u8,
            false => 0,
        };
        let capped = d.levels.iter().map(|&l| l.min(cap)).collect();
        d.levels = one_density_as_empty(capped);
    }
}

/// Surface texels at `shapes`' densities: `sum(area * density^2)`.
fn estimate(scene: &Scene, shapes: &[Option<ShapeDensity>]) -> f64 {
    scene
        .shapes
        .iter()
        .zip(shapes)
        .filter_map(|(s, d)| {
            d.as_ref()
                .map(|d| d.effective_area(&s.mesh) * (d.texels_per_unit as f64).powi(2))
        })
        .sum()
}

/// The highest density whose atlas of a surface of `area` fits in `max_size` texels a side.
fn size_cap(area: f64, max_size: u32) -> f32 {
    (0.95 * max_size as f64 / (PACKING * area.max(1e-12)).sqrt()) as f32
}

/// `d` to three significant digits (densities read better, and nothing depends on more).
fn round3(d: f32) -> f32 {
    if !(d.is_finite() && d > 0.0) {
        return d;
    }
    let mag = 10f32.powi(d.log10().floor() as i32 - 2);
    (d / mag).round() * mag
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::mitsuba::parse;
    use glam::Vec3;
    use std::path::Path;

    /// A 2 x 2 rectangle at z = 0 (and, with `far`, a second one at x = 10) and a camera at
    /// `z = dist` looking at it, 90 degrees fov, `w x w` pixels.
    fn scene(dist: f32, w: u32, far: bool) -> Scene {
        let second = match far {
            true => {
                "<shape type=\"rectangle\" id=\"far\"><transform name=\"to_world\">\
                     <translate x=\"10\"/></transform></shape>"
            }
            false => "",
        };
        let xml = format!(
            "<scene version=\"3.0.0\"><shape type=\"rectangle\" id=\"near\"/>{second}\
             <emitter type=\"point\"><point name=\"position\" x=\"0\" y=\"0\" z=\"1\"/></emitter>\
             <sensor type=\"perspective\" id=\"cam\"><float name=\"fov\" value=\"90\"/>\
             <transform name=\"to_world\"><lookat origin=\"0, 0, {dist}\" target=\"0, 0, 0\" \
             up=\"0, 1, 0\"/></transform><film type=\"hdrfilm\"><integer name=\"width\" \
             value=\"{w}\"/><integer name=\"height\" value=\"{w}\"/></film></sensor></scene>"
        );
        parse(&xml, Path::new("t/scene.xml")).unwrap()
    }

    #[test]
    fn head_on_footprint_is_the_closed_form() {
        // fov 90 at distance 2: the image spans 4 units over 64 pixels = 1/16 unit per pixel
        // at the center; off-axis pixels are larger, but the median is within a few percent
        // of the axis (the 2 x 2 rectangle fills the middle half of the image)
        let sc = scene(2.0, 64, false);
        let accel = Accel::build(&sc);
        let fine = finest_footprints(&sc, &accel, &[0]);
        let e = fine.shapes[0].expect("the camera sees the rectangle");
        assert!((e - 1.0 / 16.0).abs() < 0.03 / 16.0, "{e}");
        let plan = plan(&sc, &fine, 8192, u64::MAX);
        let d = plan.shapes[0].as_ref().unwrap();
        assert!(
            (d.texels_per_unit - 16.0 * OVERSAMPLE).abs() < 0.5 * OVERSAMPLE,
            "{d:?}"
        );
        assert_eq!(d.limited_by, None);
        // sum(area * d^2) = 4 * (16 * OVERSAMPLE)^2
        let want = 4.0 * (16.0 * OVERSAMPLE as f64).powi(2);
        assert!((plan.estimated_texels as f64 / want - 1.0).abs() < 0.07);
    }

    #[test]
    fn closer_or_sharper_photos_give_proportionally_finer_texels() {
        let at = |dist: f32, w: u32| {
            let sc = scene(dist, w, false);
            finest_footprints(&sc, &Accel::build(&sc), &[0]).shapes[0].unwrap()
        };
        let base = at(2.0, 64);
        assert!((at(2.0, 128) / base - 0.5).abs() < 0.02);
        assert!((at(4.0, 64) / base - 2.0).abs() < 0.08);
    }

    #[test]
    fn unseen_shapes_take_the_coarsest_seen_density_and_caps_apply_and_say_so() {
        let sc = scene(2.0, 64, true);
        let fine = finest_footprints(&sc, &Accel::build(&sc), &[0]);
        assert!(fine.shapes[0].is_some() && fine.shapes[1].is_none());
        let p = plan(&sc, &fine, 8192, u64::MAX);
        let far = p.shapes[1].as_ref().unwrap();
        assert_eq!(far.limited_by.as_deref(), Some("unseen"));
        assert_eq!(
            far.texels_per_unit,
            p.shapes[0].as_ref().unwrap().texels_per_unit
        );
        // a budget of a quarter of the texels halves every density
        let q = plan(&sc, &fine, 8192, p.estimated_texels / 4);
        for (a, b) in p.shapes.iter().flatten().zip(q.shapes.iter().flatten()) {
            assert!((b.texels_per_unit / a.texels_per_unit - 0.5).abs() < 0.01);
        }
        assert!(
            q.notes.iter().any(|n| n.contains("max_texels")),
            "{:?}",
            q.notes
        );
        assert!(q.estimated_texels <= p.estimated_texels / 4 + 8);
        // a 16-texel texture holds a 2 x 2 rectangle at no more than 16 * 0.95 / sqrt(6.4)
        let r = plan(&sc, &fine, 16, u64::MAX);
        let near = r.shapes[0].as_ref().unwrap();
        assert_eq!(near.limited_by.as_deref(), Some("max_texture_size"));
        assert!(near.texels_per_unit <= 16.0 * 0.95 / 6.4f32.sqrt() + 0.01);
        assert!(r.notes[0].contains("'near'"), "{:?}", r.notes);
    }

    /// A 16 x 16 ground of 2 x 2 cells (triangles in rows of `y`) at z = 0 and a camera 1
    /// unit above it at y = -7, looking along it at the origin.
    fn ground() -> Scene {
        let xml = "<scene version=\"3.0.0\"><shape type=\"rectangle\" id=\"ground\"/>\
             <emitter type=\"point\"><point name=\"position\" x=\"0\" y=\"0\" z=\"1\"/></emitter>\
             <sensor type=\"perspective\"><float name=\"fov\" value=\"60\"/>\
             <transform name=\"to_world\"><lookat origin=\"0, -7, 1\" target=\"0, 0, 0\" \
             up=\"0, 0, 1\"/></transform><film type=\"hdrfilm\"><integer name=\"width\" \
             value=\"128\"/><integer name=\"height\" value=\"128\"/></film></sensor></scene>";
        let mut sc = parse(xml, Path::new("t/scene.xml")).unwrap();
        let (n, half) = (8u32, 8.0f32);
        let mesh = &mut sc.shapes[0].mesh;
        mesh.positions = (0..=n)
            .flat_map(|j| (0..=n).map(move |i| (i, j)))
            .map(|(i, j)| Vec3::new(-half + 2.0 * i as f32, -half + 2.0 * j as f32, 0.0))
            .collect();
        mesh.triangles = (0..n)
            .flat_map(|j| (0..n).map(move |i| (i, j)))
            .flat_map(|(i, j)| {
                let v = |i: u32, j: u32| j * (n + 1) + i;
                [
                    [v(i, j), v(i + 1, j), v(i + 1, j + 1)],
                    [v(i, j), v(i + 1, j + 1), v(i, j + 1)],
                ]
            })
            .collect();
        mesh.normals = None;
        mesh.uvs = None;
        sc
    }

    #[test]
    fn a_ground_seen_along_its_length_gets_coarser_levels_away_from_the_camera() {
        let sc = ground();
        let fine = finest_footprints(&sc, &Accel::build(&sc), &[0]);
        let plan = plan(&sc, &fine, 8192, u64::MAX);
        let d = plan.shapes[0].as_ref().unwrap();
        let mesh = &sc.shapes[0].mesh;
        // per row of cells (2 units of y), the levels of its triangles in view (|x| < 2)
        let row = |j: usize| -> Vec<u8> {
            (0..mesh.triangles.len())
                .filter(|&t| t / 16 == j && ((t % 16) / 2 == 3 || (t % 16) / 2 == 4))
                .map(|t| d.levels[t])
                .collect()
        };
        // the row behind the camera (y in -8..-6 holds the camera; in front of it the
        // ground is seen from about y = -5.3 on): nothing sees it
        assert!(row(0).iter().all(|&l| l == LEVELS), "{:?}", row(0));
        // nearest seen rows at level 0, and coarser with distance: the footprint of a ground
        // point at distance r from a camera h above grows about as r^1.5 / sqrt(h) (the
        // pixel's edge grows as r, and as sqrt(r / h) more along the line of sight)
        assert!(row(1).contains(&0), "{:?}", row(1));
        let mean = |j: usize| row(j).iter().map(|&l| f32::from(l)).sum::<f32>() / 4.0;
        for j in 2..8 {
            assert!(
                mean(j) >= mean(j - 1),
                "row {j}: {:?} {:?}",
                row(j - 1),
                row(j)
            );
        }
        assert!(mean(7) >= 2.0, "{:?}", row(7));
        // the estimate follows the levels: far fewer texels than one density everywhere
        let uniform = mesh.area() * (d.texels_per_unit as f64).powi(2);
        assert!(
            (plan.estimated_texels as f64) < uniform / 4.0,
            "{} of {uniform}",
            plan.estimated_texels
        );
        // the density is the median pixel's: rows seen that finely or finer are at level 0
        assert_eq!(d.finest_footprint, fine.shapes[0]);
        assert_eq!(
            d.texels_per_unit,
            round3(OVERSAMPLE / fine.shapes[0].unwrap())
        );
    }

    #[test]
    fn levels_stop_where_texels_would_exceed_a_sixteenth_of_the_shape() {
        // a unit sphere: bounding radius sqrt(3) (half its box's diagonal), so texels may be
        // up to 0.108 units: at 64 texels per unit that is level 2 (4/64), at 20 level 1,
        // at 16 level 0 (the levels are dropped)
        let xml = "<scene version=\"3.0.0\"><shape type=\"sphere\" id=\"s\"/>\
            <emitter type=\"point\"><point name=\"position\" x=\"0\" y=\"0\" z=\"3\"/></emitter>\
            </scene>";
        let sc = parse(xml, Path::new("t/scene.xml")).unwrap();
        let n = sc.shapes[0].mesh.triangles.len();
        for (density, cap) in [(64.0, Some(2u8)), (20.0, Some(1)), (16.0, None)] {
            let mut shapes = vec![Some(ShapeDensity {
                texels_per_unit: density,
                finest_footprint: Some(0.1),
                limited_by: None,
                levels: (0..n).map(|t| (t % 4) as u8).collect(),
            })];
            cap_levels(&sc, &mut shapes);
            let levels = &shapes[0].as_ref().unwrap().levels;
            match cap {
                Some(c) => {
                    assert_eq!(levels.iter().max(), Some(&c), "{density}");
                    assert!(levels
                        .iter()
                        .enumerate()
                        .all(|(t, &l)| l == (t % 4).min(c as usize) as u8));
                }
                None => assert!(levels.is_empty(), "{density}: {levels:?}"),
            }
        }
    }

    #[test]
    fn needs_count_the_stores_on_disk_and_at_most_the_budget_in_memory() {
        let sc = scene(2.0, 64, false);
        let plan = DensityPlan::fixed(&sc, 100.0); // 4 units^2 -> 40,000 surface texels
        assert_eq!(plan.estimated_texels, 40_000);
        let big = needs(&sc, &plan, 4096, (u64::MAX, 0));
        assert_eq!(big.store_texels, 60_000);
        // geometry (52 B) and state (92 B) stores, two state snapshots, outputs
        let stores = 60_000 * (52 + 92);
        assert_eq!(big.disk_bytes, stores + 2 * 60_000 * 92 + 40_000 * 140);
        let small = needs(&sc, &plan, 4096, (1000, 0));
        assert_eq!(big.memory_bytes - small.memory_bytes, stores - 1000);
        // the gather's cache adds its bytes to memory and nothing to disk
        let gathered = needs(&sc, &plan, 4096, (1000, 5000));
        assert_eq!(gathered.memory_bytes - small.memory_bytes, 5000);
        assert_eq!(gathered.disk_bytes, small.disk_bytes);
        // the memory a run needs does not follow the atlas beyond the budget
        let finer = needs(&sc, &DensityPlan::fixed(&sc, 400.0), 4096, (1000, 5000));
        assert_eq!(finer.memory_bytes, gathered.memory_bytes);
        assert!(finer.disk_bytes > 15 * gathered.disk_bytes);
    }

    #[test]
    fn gather_bytes_follow_area_over_spacing_squared_not_texels() {
        let a = gather_bytes(100.0, 0.5, 256);
        assert_eq!(a, 1000 * (20 + 256 * 32)); // 400 cells x 2.5 points
        assert_eq!(gather_bytes(100.0, 0.25, 256), 4 * a);
        assert_eq!(gather_bytes(400.0, 0.5, 256), 4 * a);
    }

    #[test]
    fn round3_keeps_three_digits() {
        assert_eq!(round3(123.456), 123.0);
        assert!((round3(0.012345) - 0.0123).abs() < 1e-7);
        assert_eq!(round3(88.04), 88.0);
    }
}
