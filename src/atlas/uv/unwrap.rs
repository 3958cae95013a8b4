//! One UV atlas per shape: either the mesh's own UVs, checked and sized to the requested
//! texel density, or a fresh unwrap by `uvunwrap` (xatlas-style charts, LSCM/ARAP, shape
//! packing) scaled so one texel covers about `1 / texels_per_unit` scene units everywhere.
//!
//! Coordinates are texels, x right and y *down* (row 0 is the top row of the texture image),
//! so a texel `(x, y)` covers `[x, x + 1] x [y, y + 1]` and its center is `(x + 0.5, y + 0.5)`.
//! The result is a pure function of the mesh and the settings: the same bits on every run
//! and for any rayon thread count (uvunwrap guarantees this for its part; everything here is
//! sequential or order-preserving). A mesh of more than [`FAST_PACKING_TRIANGLES`] triangles
//! (a scan) is unwrapped in spatial pieces, each on its own page, and the pages are laid side
//! by side: uvunwrap's fast packing costs more than linear time in the number of charts.

use super::shape_atlas::{AtlasSettings, ShapeAtlas};
use crate::scene::Mesh;
use crate::{Error, Result};
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// Builds the atlas of one mesh (world-space positions), one density everywhere. See
/// [`build_atlas_with_progress`].
pub fn build_atlas(mesh: &Mesh, settings: &AtlasSettings) -> Result<ShapeAtlas> {
    build_atlas_with_progress(mesh, settings, &[], |_, _, _| true)
}

/// [`build_atlas`] with per-triangle density `levels` (triangle `t` at `2^-levels[t]` times
/// the density; empty: all at level 0; ignored with the mesh's own UVs), reporting unwrap
/// progress as `(stage, done, total)`; returning `false` cancels. A mesh without surface area
/// gets a 1x1 atlas with no chart (every texel is gutter) rather than an error, so one
/// degenerate shape doesn't stop a scene.
pub fn build_atlas_with_progress(
    mesh: &Mesh,
    settings: &AtlasSettings,
    levels: &[u8],
    progress: impl Fn(&str, usize, Option<usize>) -> bool + Sync,
) -> Result<ShapeAtlas> {
    check_settings(settings)?;
    check_mesh(mesh)?;
    let area = mesh.area();
    if area.is_nan() || area <= 0.0 {
        return Ok(ShapeAtlas::empty(mesh, settings.texels_per_unit));
    }
    if settings.use_mesh_uvs {
        return from_mesh_uvs(mesh, settings, area);
    }
    if !levels.is_empty() && levels.len() != mesh.triangles.len() {
        return Err(Error::internal(format!(
            "{} density levels for {} triangles",
            levels.len(),
            mesh.triangles.len()
        )));
    }
    unwrap(mesh, settings, levels, progress)
}

fn check_settings(s: &AtlasSettings) -> Result<()> {
    if !(s.texels_per_unit > 0.0 && s.texels_per_unit.is_finite()) {
        return Err(Error::config(format!(
            "atlas texels_per_unit must be finite and > 0, got {}",
            s.texels_per_unit
        )));
    }
    if s.max_size == 0 {
        return Err(Error::config("atlas max_size must be > 0"));
    }
    if s.padding > 256 {
        return Err(Error::config(format!(
            "atlas padding of {} texels is unreasonable (at most 256)",
            s.padding
        )));
    }
    Ok(())
}

fn check_mesh(mesh: &Mesh) -> Result<()> {
    let n = mesh.positions.len();
    for (t, tri) in mesh.triangles.iter().enumerate() {
        if let Some(&i) = tri.iter().find(|&&i| i as usize >= n) {
            return Err(Error::internal(format!(
                "mesh triangle {t} refers to vertex {i} but the mesh has {n} vertices"
            )));
        }
    }
    if let Some(v) = mesh.positions.iter().position(|p| !p.is_finite()) {
        return Err(Error::internal(format!(
            "mesh vertex {v} has a non-finite position {}",
            mesh.positions[v]
        )));
    }
    Ok(())
}

/// The refusal for an atlas larger than `max_size`, with the density that would fit.
fn too_large(w: u64, h: u64, s: &AtlasSettings, what: &str) -> Error {
    let side = w.max(h).max(1) as f64;
    let fit = s.texels_per_unit as f64 * s.max_size as f64 / side * 0.97;
    Error::config(format!(
        "{what} needs a {w}x{h} texture at {} texels per unit, more than max_size {}; \
         lower texels_per_unit to about {fit:.2} or raise max_size",
        s.texels_per_unit, s.max_size
    ))
}

/// Keeps the mesh's UVs: a square texture whose side gives the requested density on average
/// (`side = density * sqrt(world area / uv area)`).
fn from_mesh_uvs(mesh: &Mesh, s: &AtlasSettings, area: f64) -> Result<ShapeAtlas> {
    let uvs = mesh.uvs.as_ref().ok_or_else(|| {
        Error::config("use_mesh_uvs is set but the mesh has no texture coordinates")
    })?;
    if uvs.len() != mesh.positions.len() {
        return Err(Error::config(format!(
            "mesh has {} texture coordinates for {} vertices",
            uvs.len(),
            mesh.positions.len()
        )));
    }
    if let Some(v) = uvs.iter().position(|uv| !uv.is_finite()) {
        return Err(Error::config(format!(
            "mesh vertex {v} has a non-finite texture coordinate {}",
            uvs[v]
        )));
    }
    // Only UVs that triangles use matter.
    let tol = 1e-4;
    let outside = mesh.triangles.iter().flatten().find(|&&i| {
        let uv = uvs[i as usize];
        uv.x < -tol || uv.y < -tol || uv.x > 1.0 + tol || uv.y > 1.0 + tol
    });
    if let Some(&i) = outside {
        return Err(Error::config(format!(
            "mesh texture coordinates leave [0, 1] (vertex {i} at {}): tiled or wrapped UVs \
             can't hold one albedo per surface point; unwrap instead (use_mesh_uvs = false)",
            uvs[i as usize]
        )));
    }
    let uv_area: f64 = mesh
        .triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| uvs[i as usize].as_dvec2());
            0.5 * (b - a).perp_dot(c - a).abs()
        })
        .sum();
    if uv_area.is_nan() || uv_area <= 1e-12 {
        return Err(Error::config(
            "mesh texture coordinates have no area (all triangles collapse in UV space)",
        ));
    }
    let side = (s.texels_per_unit as f64 * (area / uv_area).sqrt()).ceil();
    let side = side.clamp(1.0, u32::MAX as f64) as u64;
    if side > s.max_size as u64 {
        return Err(too_large(side, side, s, "the mesh's UV layout"));
    }
    let side_f = side as f64;
    let corner_uv: Vec<[Vec2; 3]> = mesh
        .triangles
        .iter()
        .map(|t| {
            t.map(|i| {
                let uv = uvs[i as usize].clamp(Vec2::ZERO, Vec2::ONE).as_dvec2();
                Vec2::new((uv.x * side_f) as f32, ((1.0 - uv.y) * side_f) as f32)
            })
        })
        .collect();
    let mut atlas = ShapeAtlas {
        width: side as u32,
        height: side as u32,
        corner_uv,
        charts: 0,
        texel_density: (side_f * (uv_area / area).sqrt()) as f32,
        levels: 0,
    };
    let (charts, covered, overlapped) = {
        let map = crate::atlas::uv::TexelMap::new(mesh, &atlas);
        (map.chart_count(), map.covered(), map.overlapped())
    };
    atlas.charts = charts;
    // A few shared texel centers can come from rounding in hand-made UVs; more is a layout
    // that maps two surface points to one texel.
    if overlapped as f64 > 0.01 * covered.max(1) as f64 {
        return Err(Error::config(format!(
            "mesh texture coordinates overlap: {overlapped} of {covered} covered texel centers \
             lie in more than one triangle; unwrap instead (use_mesh_uvs = false)"
        )));
    }
    Ok(atlas)
}

/// Largest ratio between a triangle's share of its chart's UV area and its share of the
/// chart's surface area (uvunwrap splits charts beyond it). uvunwrap's default of 4 let
/// texels on a bumpy sphere vary from 0.72 to 1.38 times the nominal area; 1.25 keeps them
/// within about 0.88..1.21 for a few more charts and no loss of fill or speed.
const MAX_AREA_DISTORTION: f32 = 1.25;

/// Triangles beyond which a mesh is unwrapped in pieces of at most [`PIECE_TRIANGLES`],
/// their charts packed in rows (`Packing::Fast`) rather than by shape: a scan-like mesh (a
/// displaced sphere of 1M triangles, `tools/gen_scan_mesh.py`) unwraps into tens of thousands
/// of charts; shape packing spent over 10 minutes on them, and fast packing of them all on one
/// page about two thirds of the unwrap's 165 s (it tries every remaining chart in the gap above
/// every row). Smaller meshes, every fixture among them, are unwrapped whole with the denser
/// packing.
const FAST_PACKING_TRIANGLES: usize = 100_000;

/// Most triangles of one piece of a mesh unwrapped in pieces.
const PIECE_TRIANGLES: usize = 32_768;

/// The mesh's triangles in spatially coherent pieces of at most `most`: halved at
/// the median of their centroids along the longest side of the centroids' bounds (ties by
/// triangle index), recursively, lower half first; each piece's triangles in mesh order.
fn pieces(mesh: &Mesh, most: usize) -> Vec<Vec<u32>> {
    let centroid: Vec<Vec3> = (0..mesh.triangles.len())
        .map(|t| {
            let [a, b, c] = mesh.triangle(t);
            (a + b + c) / 3.0
        })
        .collect();
    let mut out = Vec::new();
    let mut todo = vec![(0..mesh.triangles.len() as u32).collect::<Vec<u32>>()];
    while let Some(mut tris) = todo.pop() {
        if tris.len() <= most.max(1) {
            tris.sort_unstable();
            out.push(tris);
            continue;
        }
        let (lo, hi) = tris.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), &t| (lo.min(centroid[t as usize]), hi.max(centroid[t as usize])),
        );
        let e = hi - lo;
        let axis = match (e.x >= e.y, e.x >= e.z, e.y >= e.z) {
            (true, true, _) => 0,
            (false, _, true) => 1,
            _ => 2,
        };
        let mid = tris.len() / 2;
        tris.select_nth_unstable_by(mid, |&a, &b| {
            (centroid[a as usize][axis].total_cmp(&centroid[b as usize][axis])).then(a.cmp(&b))
        });
        let upper = tris.split_off(mid);
        todo.push(upper);
        todo.push(tris);
    }
    out
}

/// The triangles `tris` of `mesh` as a mesh of their own (positions only).
fn piece_mesh(mesh: &Mesh, tris: &[u32]) -> Mesh {
    let mut used: Vec<u32> = tris
        .iter()
        .flat_map(|&t| mesh.triangles[t as usize])
        .collect();
    used.sort_unstable();
    used.dedup();
    let at = |v: u32| used.binary_search(&v).unwrap_or(0) as u32;
    Mesh {
        positions: used.iter().map(|&v| mesh.positions[v as usize]).collect(),
        normals: None,
        uvs: None,
        triangles: tris
            .iter()
            .map(|&t| mesh.triangles[t as usize].map(at))
            .collect(),
        flipped: Vec::new(),
    }
}

/// Unwraps a large mesh in [`pieces`] of at most `most` triangles, in parallel, each with fast packing on its own page,
/// then lays the pages side by side ([`shelves`]); progress in triangles of finished pieces.
fn unwrap_pieces(
    mesh: &Mesh,
    s: &AtlasSettings,
    levels: &[u8],
    most: usize,
    progress: impl Fn(&str, usize, Option<usize>) -> bool + Sync,
) -> Result<ShapeAtlas> {
    let pieces = pieces(mesh, most);
    let total = mesh.triangles.len();
    let (done, cancelled) = (AtomicUsize::new(0), AtomicBool::new(false));
    let parts: Vec<Result<ShapeAtlas>> = pieces
        .par_iter()
        .map(|tris| {
            let m = piece_mesh(mesh, tris);
            let lv: Vec<u8> = match levels.is_empty() {
                true => Vec::new(),
                false => tris.iter().map(|&t| levels[t as usize]).collect(),
            };
            let go = |_: &str, _: usize, _: Option<usize>| !cancelled.load(Ordering::Relaxed);
            let a = unwrap_one(&m, s, &lv, uvunwrap::Packing::Fast, go)?;
            let n = done.fetch_add(tris.len(), Ordering::Relaxed) + tris.len();
            if !progress("parameterizing", n, Some(total)) {
                cancelled.store(true, Ordering::Relaxed);
            }
            Ok(a)
        })
        .collect();
    let parts = parts.into_iter().collect::<Result<Vec<_>>>()?;
    let sizes: Vec<(u32, u32)> = parts.iter().map(|a| (a.width, a.height)).collect();
    let (width, height, at) = shelves(&sizes);
    if width > s.max_size || height > s.max_size {
        return Err(too_large(
            width as u64,
            height as u64,
            s,
            "the unwrapped mesh",
        ));
    }
    let mut corner_uv = vec![[Vec2::ZERO; 3]; total];
    for ((tris, part), &(x, y)) in pieces.iter().zip(&parts).zip(&at) {
        let o = Vec2::new(x as f32, y as f32);
        for (&t, uv) in tris.iter().zip(&part.corner_uv) {
            corner_uv[t as usize] = uv.map(|p| p + o);
        }
    }
    Ok(ShapeAtlas {
        width,
        height,
        corner_uv,
        charts: parts.iter().map(|a| a.charts).sum(),
        texel_density: parts.first().map_or(s.texels_per_unit, |a| a.texel_density),
        levels: parts.iter().map(|a| a.levels).max().unwrap_or(0),
    })
}

/// Rectangles of `sizes` laid in shelves (tallest first, ties by index) on a page of the
/// smallest area among eight widths around the square that holds them: the page's width and
/// height, and each rectangle's top-left corner. Each page already has its padding inside,
/// so the pages touch.
fn shelves(sizes: &[(u32, u32)]) -> (u32, u32, Vec<(u32, u32)>) {
    let area: f64 = sizes.iter().map(|&(w, h)| w as f64 * h as f64).sum();
    let widest = sizes.iter().map(|s| s.0).max().unwrap_or(1);
    let mut order: Vec<usize> = (0..sizes.len()).collect();
    order.sort_by_key(|&i| (std::cmp::Reverse(sizes[i].1), i));
    let lay = |limit: u32| {
        let mut at = vec![(0, 0); sizes.len()];
        let (mut x, mut y, mut row, mut width) = (0u32, 0u32, 0u32, 0u32);
        for &i in &order {
            let (w, h) = sizes[i];
            if x > 0 && x + w > limit {
                (x, y, row) = (0, y + row, 0);
            }
            at[i] = (x, y);
            x += w;
            row = row.max(h);
            width = width.max(x);
        }
        (width.max(1), (y + row).max(1), at)
    };
    (0..8)
        .map(|k| lay(widest.max((area.sqrt() * (0.85 + 0.05 * k as f64)).ceil() as u32)))
        .min_by_key(|(w, h, _)| (*w as u64 * *h as u64, (*w).max(*h)))
        .unwrap_or((1, 1, Vec::new()))
}

/// The triangles of one density level, with their own copy of the vertices they use: one
/// uvunwrap input (charts never span inputs, so a chart has one density).
struct LevelMesh {
    level: u8,
    positions: Vec<[f32; 3]>,
    indices: Vec<u32>,
    /// The mesh triangle of each of its triangles.
    tris: Vec<u32>,
}

/// The mesh split by density level (`levels` empty: one input, the whole mesh at level 0).
fn level_meshes(mesh: &Mesh, levels: &[u8]) -> Vec<LevelMesh> {
    if levels.is_empty() {
        return vec![LevelMesh {
            level: 0,
            positions: mesh.positions.iter().map(|p| p.to_array()).collect(),
            indices: mesh.triangles.iter().flatten().copied().collect(),
            tris: (0..mesh.triangles.len() as u32).collect(),
        }];
    }
    let top = levels.iter().copied().max().unwrap_or(0);
    let mut remap = vec![u32::MAX; mesh.positions.len()];
    (0..=top)
        .filter_map(|level| {
            let mut m = LevelMesh {
                level,
                positions: Vec::new(),
                indices: Vec::new(),
                tris: Vec::new(),
            };
            remap.fill(u32::MAX);
            for (t, tri) in mesh.triangles.iter().enumerate() {
                if levels[t] != level {
                    continue;
                }
                m.tris.push(t as u32);
                for &v in tri {
                    if remap[v as usize] == u32::MAX {
                        remap[v as usize] = m.positions.len() as u32;
                        m.positions.push(mesh.positions[v as usize].to_array());
                    }
                    m.indices.push(remap[v as usize]);
                }
            }
            (!m.tris.is_empty()).then_some(m)
        })
        .collect()
}

/// Unwraps with uvunwrap at a fixed density (per triangle `2^-level` of it) on one page that
/// grows to fit; a large mesh in pieces ([`unwrap_pieces`]).
fn unwrap(
    mesh: &Mesh,
    s: &AtlasSettings,
    levels: &[u8],
    progress: impl Fn(&str, usize, Option<usize>) -> bool + Sync,
) -> Result<ShapeAtlas> {
    if mesh.triangles.len() > FAST_PACKING_TRIANGLES {
        check_area(mesh, s, levels)?;
        return unwrap_pieces(mesh, s, levels, PIECE_TRIANGLES, progress);
    }
    unwrap_one(mesh, s, levels, uvunwrap::Packing::Shape, progress)
}

/// Refuses early, before the packer rasterizes anything: the charts alone need this many
/// texels, and packing never does better than full coverage.
fn check_area(mesh: &Mesh, s: &AtlasSettings, levels: &[u8]) -> Result<()> {
    let density = s.texels_per_unit as f64;
    let area = crate::atlas::uv::effective_area(mesh, levels);
    let lower_bound = (area * density * density).sqrt().ceil() as u64;
    if lower_bound > s.max_size as u64 {
        return Err(too_large(lower_bound, lower_bound, s, "the unwrapped mesh"));
    }
    Ok(())
}

/// One uvunwrap call over the whole mesh, its charts packed by `packing`.
fn unwrap_one(
    mesh: &Mesh,
    s: &AtlasSettings,
    levels: &[u8],
    packing: uvunwrap::Packing,
    progress: impl Fn(&str, usize, Option<usize>) -> bool + Sync,
) -> Result<ShapeAtlas> {
    check_area(mesh, s, levels)?;
    let groups = level_meshes(mesh, levels);
    let inputs: Vec<uvunwrap::MeshInput> = groups
        .iter()
        .map(|g| uvunwrap::MeshInput {
            scale: 0.5f32.powi(i32::from(g.level)),
            ..uvunwrap::MeshInput::new(&g.positions, &g.indices)
        })
        .collect();
    let options = uvunwrap::Options {
        density: uvunwrap::Density::Fixed {
            texels_per_unit: s.texels_per_unit,
            page_size: None,
        },
        // uvunwrap keeps charts 2 x padding apart.
        padding: s.padding.div_ceil(2),
        max_area_distortion: MAX_AREA_DISTORTION,
        packing,
        ..Default::default()
    };
    let result = uvunwrap::generate_with_progress(&inputs, &options, |p| {
        let stage = match p.stage {
            uvunwrap::Stage::Segmenting => "segmenting",
            uvunwrap::Stage::Parameterizing => "parameterizing",
            uvunwrap::Stage::Packing => "packing",
            _ => "assembling",
        };
        progress(stage, p.done, p.total)
    });
    let atlas = match result {
        Ok(a) => a,
        Err(uvunwrap::Error::Cancelled) => return Err(Error::internal("atlas unwrap cancelled")),
        Err(uvunwrap::Error::AtlasTooLarge { texels }) => {
            let side = (texels as f64).sqrt().ceil() as u64;
            return Err(too_large(side, side, s, "the unwrapped mesh"));
        }
        Err(e) => return Err(Error::internal(format!("unwrapping the mesh failed: {e}"))),
    };
    if atlas.page_count > 1 {
        return Err(Error::internal(format!(
            "unwrapping the mesh gave {} pages, expected one",
            atlas.page_count
        )));
    }
    if atlas.width > s.max_size || atlas.height > s.max_size {
        return Err(too_large(
            atlas.width as u64,
            atlas.height as u64,
            s,
            "the unwrapped mesh",
        ));
    }
    if atlas.meshes.len() != groups.len() {
        return Err(Error::internal(format!(
            "unwrapping gave {} meshes for {} inputs",
            atlas.meshes.len(),
            groups.len()
        )));
    }
    let (w, h) = (atlas.width as f64, atlas.height as f64);
    let mut corner_uv = vec![[Vec2::ZERO; 3]; mesh.triangles.len()];
    for (g, out) in groups.iter().zip(&atlas.meshes) {
        if out.indices.len() != g.indices.len() {
            return Err(Error::internal(
                "unwrapping the mesh changed its triangle count",
            ));
        }
        for (t, c) in g.tris.iter().zip(out.indices.chunks_exact(3)) {
            corner_uv[*t as usize] = [0, 1, 2].map(|k| {
                let uv = out.vertices.get(c[k] as usize).map_or([0.0; 2], |v| v.uv);
                Vec2::new((uv[0] as f64 * w) as f32, (uv[1] as f64 * h) as f32)
            });
        }
    }
    Ok(ShapeAtlas {
        width: atlas.width,
        height: atlas.height,
        corner_uv,
        charts: atlas.chart_count,
        texel_density: atlas.texels_per_unit,
        levels: groups.last().map_or(0, |g| g.level),
    })
}

/// Meshes for the atlas tests: the Cornell box fixtures and generated bumpy spheres.
#[cfg(test)]
pub(crate) mod testutil {
    use crate::scene::Mesh;
    use glam::{Vec2, Vec3};
    use std::path::PathBuf;

    /// `tests/fixtures/<set>/meshes/<name>.obj`, vertices split per distinct `v/vt/vn`.
    pub fn fixture(set: &str, name: &str) -> Mesh {
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("tests/fixtures")
            .join(set)
            .join("meshes")
            .join(format!("{name}.obj"));
        let opts = tobj::LoadOptions {
            single_index: true,
            triangulate: true,
            ..Default::default()
        };
        let (models, _) = tobj::load_obj(&path, &opts).expect("fixture loads");
        let m = &models[0].mesh;
        let v3 = |s: &[f32]| s.chunks_exact(3).map(Vec3::from_slice).collect::<Vec<_>>();
        Mesh {
            positions: v3(&m.positions),
            normals: (!m.normals.is_empty()).then(|| v3(&m.normals)),
            uvs: (!m.texcoords.is_empty())
                .then(|| m.texcoords.chunks_exact(2).map(Vec2::from_slice).collect()),
            triangles: m
                .indices
                .chunks_exact(3)
                .map(|t| [t[0], t[1], t[2]])
                .collect(),
            flipped: Vec::new(),
        }
    }

    pub const CBOX: [&str; 8] = [
        "back",
        "ceiling",
        "floor",
        "left",
        "light",
        "right",
        "short_box",
        "tall_box",
    ];

    /// Every Cornell box mesh of both fixtures, named `set/name`.
    pub fn all_cbox() -> Vec<(String, Mesh)> {
        ["cbox", "cbox-tex"]
            .iter()
            .flat_map(|set| {
                CBOX.iter()
                    .map(move |n| (format!("{set}/{n}"), fixture(set, n)))
            })
            .collect()
    }

    /// A unit sphere with bumps, `segs` around and `rings` from pole to pole (welded
    /// vertices, fans at the poles): `2 * segs * (rings - 1)` triangles, outward winding.
    pub fn bumpy_sphere(segs: u32, rings: u32) -> Mesh {
        let point = |theta: f32, phi: f32| {
            let r = 1.0 + 0.08 * (5.0 * theta).sin() * (4.0 * phi).sin();
            r * Vec3::new(
                theta.sin() * phi.cos(),
                theta.cos(),
                theta.sin() * phi.sin(),
            )
        };
        let mut positions = vec![Vec3::Y];
        for i in 1..rings {
            let theta = std::f32::consts::PI * i as f32 / rings as f32;
            for j in 0..segs {
                positions.push(point(theta, std::f32::consts::TAU * j as f32 / segs as f32));
            }
        }
        positions.push(-Vec3::Y);
        let south = (positions.len() - 1) as u32;
        let at = |i: u32, j: u32| 1 + (i - 1) * segs + j % segs;
        let mut triangles = Vec::new();
        for j in 0..segs {
            triangles.push([0, at(1, j + 1), at(1, j)]);
            for i in 1..rings - 1 {
                let (a, b, c, d) = (at(i, j), at(i, j + 1), at(i + 1, j), at(i + 1, j + 1));
                triangles.push([a, b, d]);
                triangles.push([a, d, c]);
            }
            triangles.push([south, at(rings - 1, j), at(rings - 1, j + 1)]);
        }
        let mut mesh = Mesh {
            positions,
            normals: None,
            uvs: None,
            triangles,
            flipped: Vec::new(),
        };
        // Make the winding outward whatever the conventions above.
        let [p0, ..] = mesh.triangle(1);
        if mesh.face_normal_raw(1).dot(p0) < 0.0 {
            for t in &mut mesh.triangles {
                t.swap(1, 2);
            }
        }
        mesh
    }
}

#[cfg(test)]
mod tests {
    use super::testutil::*;
    use super::*;
    use glam::Vec3;

    fn settings(tpu: f32) -> AtlasSettings {
        AtlasSettings {
            texels_per_unit: tpu,
            ..Default::default()
        }
    }

    /// Corners of all triangles, with bounds.
    fn bounds(a: &ShapeAtlas) -> (Vec2, Vec2) {
        let pts = a.corner_uv.iter().flatten();
        let lo = pts.clone().fold(Vec2::splat(f32::MAX), |m, p| m.min(*p));
        let hi = pts.fold(Vec2::splat(f32::MIN), |m, p| m.max(*p));
        (lo, hi)
    }

    #[test]
    fn quads_unwrap_to_one_axis_aligned_rectangle() {
        // 2-triangle planes and cbox-tex's 8-triangle planes.
        for set in ["cbox", "cbox-tex"] {
            for name in ["floor", "back", "left", "light"] {
                let mesh = fixture(set, name);
                let a = build_atlas(&mesh, &settings(64.0)).unwrap();
                assert_eq!(a.charts, 1, "{set}/{name}");
                // The chart's UV area is the surface's at this density and so is its
                // bounding box's: a chart that fills its axis-aligned bounding rectangle.
                let (lo, hi) = bounds(&a);
                let side = hi - lo;
                let texel_area = mesh.area() * 64.0 * 64.0;
                let rect = (side.x * side.y) as f64;
                let uv: f64 = a
                    .corner_uv
                    .iter()
                    .map(|[p, q, r]| 0.5 * (*q - *p).perp_dot(*r - *p).abs() as f64)
                    .sum();
                assert!(
                    (rect / texel_area - 1.0).abs() < 1e-3,
                    "{set}/{name}: {side}"
                );
                assert!((uv / texel_area - 1.0).abs() < 1e-3, "{set}/{name}: {uv}");
                // One padding texel (uvunwrap padding 1) around it.
                assert!(lo.x >= 1.0 - 1e-3 && lo.y >= 1.0 - 1e-3, "{lo}");
                assert!(hi.x <= a.width as f32 - 1.0 + 1e-3, "{hi} {}", a.width);
                assert!(hi.y <= a.height as f32 - 1.0 + 1e-3, "{hi} {}", a.height);
            }
        }
    }

    #[test]
    fn boxes_unwrap_to_six_charts() {
        for set in ["cbox", "cbox-tex"] {
            for name in ["short_box", "tall_box"] {
                let a = build_atlas(&fixture(set, name), &settings(64.0)).unwrap();
                assert_eq!(a.charts, 6, "{set}/{name}");
                assert_eq!(a.corner_uv.len(), 12);
            }
        }
    }

    #[test]
    fn density_is_reported_and_refused_when_too_large() {
        let mesh = fixture("cbox", "floor");
        let a = build_atlas(&mesh, &settings(64.0)).unwrap();
        assert_eq!(a.texel_density, 64.0);
        // Early refusal: 2x2 units at 10000 texels/unit needs 20000 texels a side.
        let e = build_atlas(&mesh, &settings(10000.0))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("20000x20000") && e.contains("max_size 8192"),
            "{e}"
        );
        assert!(e.contains("lower texels_per_unit to about 39"), "{e}");
        // Refusal after packing: the chart fits 128 texels but padding needs 130.
        let s = AtlasSettings {
            max_size: 129,
            ..settings(64.0)
        };
        let e = build_atlas(&mesh, &s).unwrap_err().to_string();
        assert!(e.contains("130x130") && e.contains("max_size 129"), "{e}");
    }

    #[test]
    fn mesh_uvs_are_kept_with_v_flipped() {
        for set in ["cbox", "cbox-tex"] {
            let mesh = fixture(set, "floor");
            let s = AtlasSettings {
                use_mesh_uvs: true,
                ..settings(64.0)
            };
            let a = build_atlas(&mesh, &s).unwrap();
            // 2x2 units of surface on the whole [0,1]^2: 128 texels a side.
            assert_eq!((a.width, a.height, a.charts), (128, 128, 1));
            assert!((a.texel_density - 64.0).abs() < 1e-4);
            let uvs = mesh.uvs.as_ref().unwrap();
            for (t, tri) in mesh.triangles.iter().enumerate() {
                for c in 0..3 {
                    let uv = uvs[tri[c] as usize];
                    let want = Vec2::new(uv.x * 128.0, (1.0 - uv.y) * 128.0);
                    assert_eq!(a.corner_uv[t][c], want);
                }
            }
        }
    }

    #[test]
    fn bad_mesh_uvs_are_refused() {
        let s = AtlasSettings {
            use_mesh_uvs: true,
            ..settings(64.0)
        };
        // The box's six faces all use [0,1]^2.
        let e = build_atlas(&fixture("cbox", "short_box"), &s)
            .unwrap_err()
            .to_string();
        assert!(e.contains("overlap"), "{e}");

        let mut mesh = fixture("cbox", "floor");
        mesh.uvs.as_mut().unwrap()[3] = Vec2::new(2.0, 1.0);
        let e = build_atlas(&mesh, &s).unwrap_err().to_string();
        assert!(e.contains("leave [0, 1]") && e.contains("vertex 3"), "{e}");

        mesh.uvs.as_mut().unwrap()[3] = Vec2::new(f32::NAN, 1.0);
        let e = build_atlas(&mesh, &s).unwrap_err().to_string();
        assert!(e.contains("non-finite texture coordinate"), "{e}");

        mesh.uvs = None;
        let e = build_atlas(&mesh, &s).unwrap_err().to_string();
        assert!(e.contains("no texture coordinates"), "{e}");
    }

    #[test]
    fn bad_meshes_and_settings_are_errors_not_panics() {
        let mut mesh = fixture("cbox", "floor");
        mesh.positions[2] = Vec3::new(f32::NAN, 0.0, 0.0);
        let e = build_atlas(&mesh, &settings(8.0)).unwrap_err().to_string();
        assert!(e.contains("vertex 2 has a non-finite position"), "{e}");

        let mut mesh = fixture("cbox", "floor");
        mesh.triangles.push([0, 1, 99]);
        let e = build_atlas(&mesh, &settings(8.0)).unwrap_err().to_string();
        assert!(e.contains("triangle 2 refers to vertex 99"), "{e}");

        for tpu in [0.0, -1.0, f32::NAN, f32::INFINITY] {
            let e = build_atlas(&fixture("cbox", "floor"), &settings(tpu));
            assert!(e.unwrap_err().to_string().contains("texels_per_unit"));
        }
    }

    #[test]
    fn degenerate_geometry_is_tolerated() {
        // Zero-area meshes: one empty texel, no chart.
        let flat = Mesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::X * 2.0],
            triangles: vec![[0, 1, 2], [0, 0, 1]],
            ..Default::default()
        };
        for m in [flat, Mesh::default()] {
            let a = build_atlas(&m, &settings(64.0)).unwrap();
            assert_eq!((a.width, a.height, a.charts), (1, 1, 0));
            assert_eq!(a.corner_uv.len(), m.triangles.len());
        }
        // Degenerate triangles beside good ones collapse to a point.
        let mut mesh = fixture("cbox", "floor");
        mesh.triangles.push([0, 0, 1]);
        mesh.triangles.push([0, 1, 2]);
        mesh.triangles.push([1, 2, 1]);
        let a = build_atlas(&mesh, &settings(16.0)).unwrap();
        assert!(
            a.charts >= 2,
            "the floor and the triangle [0, 1, 2] over it"
        );
        for t in [2, 4] {
            let [p, q, r] = a.corner_uv[t];
            assert!((q - p).perp_dot(r - p).abs() < 1e-6, "triangle {t}");
        }
    }

    /// A large mesh's pieces hold every triangle once, each at most the size asked, and
    /// their pages laid side by side give one atlas: every triangle's texels on it, none
    /// shared by two triangles, each piece's charts where its page was put (the same UVs up
    /// to that offset), the charts of all pieces counted.
    #[test]
    fn a_mesh_unwrapped_in_pieces_is_one_atlas_without_overlap() {
        let mesh = bumpy_sphere(64, 48);
        let n = mesh.triangles.len();
        let parts = pieces(&mesh, 1500);
        assert!(parts.len() >= 4 && parts.iter().all(|p| p.len() <= 1500));
        let mut seen = vec![0; n];
        for &t in parts.iter().flatten() {
            seen[t as usize] += 1;
        }
        assert!(seen.iter().all(|&k| k == 1));
        let s = settings(40.0);
        let a = unwrap_pieces(&mesh, &s, &[], 1500, |_, _, _| true).unwrap();
        assert!(a.width <= s.max_size && a.height <= s.max_size);
        let (lo, hi) = bounds(&a);
        assert!(lo.min_element() >= 0.0);
        assert!(hi.x <= a.width as f32 && hi.y <= a.height as f32);
        let map = crate::atlas::uv::TexelMap::new(&mesh, &a);
        assert_eq!(map.overlapped(), 0);
        // at least as many texels as the surface needs, and pages that pack well
        let need = mesh.area() * 40.0 * 40.0;
        assert!(
            map.covered() as f64 > 0.9 * need,
            "{} {need}",
            map.covered()
        );
        let mut charts = 0;
        for p in &parts {
            let one = unwrap_one(
                &piece_mesh(&mesh, p),
                &s,
                &[],
                uvunwrap::Packing::Fast,
                |_, _, _| true,
            )
            .unwrap();
            charts += one.charts;
            let d = a.corner_uv[p[0] as usize][0] - one.corner_uv[0][0];
            assert_eq!(d, d.round(), "a whole texel offset");
            for (k, &t) in p.iter().enumerate() {
                assert_eq!(a.corner_uv[t as usize], one.corner_uv[k].map(|c| c + d));
            }
        }
        assert_eq!(a.charts, charts);
    }

    #[test]
    fn shelves_hold_rectangles_apart_on_a_near_square_page() {
        let sizes: Vec<(u32, u32)> = (0..23)
            .map(|i| (90 + 7 * (i % 5), 80 + 11 * (i % 3)))
            .collect();
        let (w, h, at) = shelves(&sizes);
        let area: u64 = sizes.iter().map(|&(a, b)| a as u64 * b as u64).sum();
        assert!((w as u64 * h as u64) < area * 13 / 10, "{w}x{h} for {area}");
        for (i, (&(x, y), &(sw, sh))) in at.iter().zip(&sizes).enumerate() {
            assert!(x + sw <= w && y + sh <= h);
            for (&(x2, y2), &(w2, h2)) in at[i + 1..].iter().zip(&sizes[i + 1..]) {
                assert!(x + sw <= x2 || x2 + w2 <= x || y + sh <= y2 || y2 + h2 <= y);
            }
        }
    }
}
