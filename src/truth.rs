//! Ground-truth albedo for measuring accuracy (tests, benchmarks, the nightly harness): the
//! `reflectance` of each shape's diffuse BSDF in a Mitsuba `truth.xml`, either a constant RGB
//! or an sRGB-encoded bitmap on the mesh's own UVs, evaluated where a texel lies. Never an
//! input of a reconstruction.

use crate::error::{Error, Result};
use crate::scene::{Mesh, Rgb};
use glam::{Vec2, Vec3};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// One shape's true reflectance.
#[derive(Debug, Clone)]
pub enum Reflectance {
    Constant(Rgb),
    /// Linear RGB texels (decoded from sRGB), row 0 = top, looked up at the mesh UVs.
    Bitmap {
        width: u32,
        height: u32,
        texels: Vec<Vec3>,
    },
}

/// The true reflectance of every shape id that has one.
#[derive(Debug, Clone, Default)]
pub struct Truth {
    pub shapes: HashMap<String, Reflectance>,
}

fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

fn parse_rgb(path: &Path, s: &str) -> Result<Rgb> {
    let v: Vec<f32> = s
        .split([',', ' '])
        .filter(|t| !t.is_empty())
        .map(|t| t.parse::<f32>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|e| Error::input(path, format!("bad rgb value '{s}': {e}")))?;
    match v.as_slice() {
        [x] => Ok(Vec3::splat(*x)),
        [r, g, b] => Ok(Vec3::new(*r, *g, *b)),
        _ => Err(Error::input(path, format!("bad rgb value '{s}'"))),
    }
}

fn load_bitmap(path: &Path) -> Result<Reflectance> {
    let pm = tiny_skia::Pixmap::load_png(path)
        .map_err(|e| Error::input(path, format!("cannot read PNG: {e}")))?;
    let texels = pm
        .pixels()
        .iter()
        .map(|p| {
            let c = p.demultiply();
            Vec3::new(
                srgb_to_linear(c.red() as f32 / 255.0),
                srgb_to_linear(c.green() as f32 / 255.0),
                srgb_to_linear(c.blue() as f32 / 255.0),
            )
        })
        .collect();
    Ok(Reflectance::Bitmap {
        width: pm.width(),
        height: pm.height(),
        texels,
    })
}

impl Truth {
    /// Read the diffuse reflectance of every `<shape id>` in a Mitsuba truth file.
    pub fn load(path: &Path) -> Result<Truth> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let doc = roxmltree::Document::parse(&text)
            .map_err(|e| Error::input(path, format!("malformed XML: {e}")))?;
        let dir = path
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_else(|| PathBuf::from("."));
        let mut shapes = HashMap::new();
        for shape in doc.descendants().filter(|n| n.has_tag_name("shape")) {
            let Some(id) = shape.attribute("id") else {
                continue;
            };
            let Some(bsdf) = shape
                .descendants()
                .find(|n| n.has_tag_name("bsdf") && n.attribute("type") == Some("diffuse"))
            else {
                continue;
            };
            for c in bsdf
                .children()
                .filter(|c| c.attribute("name") == Some("reflectance"))
            {
                let r = match c.tag_name().name() {
                    "rgb" | "spectrum" | "float" => {
                        Reflectance::Constant(parse_rgb(path, c.attribute("value").unwrap_or(""))?)
                    }
                    "texture" => {
                        let f = c
                            .children()
                            .find(|n| n.attribute("name") == Some("filename"))
                            .and_then(|n| n.attribute("value"))
                            .ok_or_else(|| {
                                Error::input(path, format!("shape '{id}': bitmap without filename"))
                            })?;
                        load_bitmap(&dir.join(f))?
                    }
                    _ => continue,
                };
                shapes.insert(id.to_string(), r);
            }
        }
        Ok(Truth { shapes })
    }
}

impl Reflectance {
    /// The true albedo at barycentrics `(b1, b2)` of triangle `tri` of `mesh` (whose UVs,
    /// v up, are the ones the truth texture was painted on). Bilinear, repeating, like
    /// Mitsuba's bitmap texture.
    pub fn eval(&self, mesh: &Mesh, tri: usize, b1: f32, b2: f32) -> Rgb {
        match self {
            Reflectance::Constant(c) => *c,
            Reflectance::Bitmap {
                width,
                height,
                texels,
            } => {
                let Some(uvs) = &mesh.uvs else {
                    return Vec3::ZERO;
                };
                let [a, b, c] = mesh.triangles[tri];
                let uv: Vec2 =
                    uvs[a as usize] * (1.0 - b1 - b2) + uvs[b as usize] * b1 + uvs[c as usize] * b2;
                let (w, h) = (*width as i64, *height as i64);
                let fx = uv.x * w as f32 - 0.5;
                let fy = (1.0 - uv.y) * h as f32 - 0.5;
                let (x0, y0) = (fx.floor() as i64, fy.floor() as i64);
                let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
                let g = |x: i64, y: i64| texels[(y.rem_euclid(h) * w + x.rem_euclid(w)) as usize];
                let top = g(x0, y0) * (1.0 - tx) + g(x0 + 1, y0) * tx;
                let bot = g(x0, y0 + 1) * (1.0 - tx) + g(x0 + 1, y0 + 1) * tx;
                top * (1.0 - ty) + bot * ty
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atlas::unwrap::ShapeAtlas;

    #[test]
    fn srgb_decode_endpoints() {
        assert_eq!(srgb_to_linear(0.0), 0.0);
        assert!((srgb_to_linear(1.0) - 1.0).abs() < 1e-6);
        assert!((srgb_to_linear(0.5) - 0.21404).abs() < 1e-4);
    }

    /// A unit square (two triangles) whose mesh UVs equal its positions, unwrapped onto a
    /// `n x n` atlas flipped vertically (atlas y down, UV v up), and a `m x m` bitmap.
    fn square(n: u32, m: u32, texel: impl Fn(u32, u32) -> f32) -> (Mesh, ShapeAtlas, Reflectance) {
        let pts = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)];
        let mesh = Mesh {
            positions: pts.iter().map(|&(x, y)| Vec3::new(x, y, 0.0)).collect(),
            uvs: Some(pts.iter().map(|&(x, y)| Vec2::new(x, y)).collect()),
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            ..Default::default()
        };
        let atlas = ShapeAtlas {
            width: n,
            height: n,
            corner_uv: mesh
                .triangles
                .iter()
                .map(|t| {
                    t.map(|i| {
                        let (x, y) = pts[i as usize];
                        Vec2::new(x * n as f32, (1.0 - y) * n as f32)
                    })
                })
                .collect(),
            charts: 1,
            texel_density: n as f32,
        };
        let texels = (0..m * m)
            .map(|i| Vec3::splat(texel(i % m, i / m)))
            .collect();
        let r = Reflectance::Bitmap {
            width: m,
            height: m,
            texels,
        };
        (mesh, atlas, r)
    }

    #[test]
    fn footprint_mean_of_a_fine_checkerboard_is_its_average() {
        // Each atlas texel covers 4 x 4 bitmap texels of a 1-texel checkerboard: a point
        // sample sees 0 or 1 (or a bilinear blend), the texel's mean is 1/2.
        let (mesh, atlas, r) = square(8, 32, |x, y| ((x + y) % 2) as f32);
        for (x, y) in [(0, 0), (3, 5), (7, 7), (5, 1)] {
            let tri = if x > 7 - y { 0 } else { 1 };
            let m = footprint_mean(&r, &mesh, &atlas, tri, x, y);
            assert!((m.x - 0.5).abs() < 1e-6, "({x}, {y}): {m}");
        }
    }

    #[test]
    fn footprint_mean_matches_brute_force_over_the_texel_square() {
        // A smooth pattern: the 4 x 4 sample mean must match a dense brute-force average of
        // the bilinear texture over the same square, located through plain barycentrics.
        let (mesh, atlas, r) = square(5, 16, |x, y| (x as f32 * 0.3).sin() + 0.1 * y as f32);
        for (x, y) in [(0, 0), (2, 3), (4, 1)] {
            let tri = 0; // the affine extension makes either triangle's map the same here
            let fast = footprint_mean(&r, &mesh, &atlas, tri, x, y).x;
            let k = 64;
            let mut sum = 0.0f64;
            for j in 0..k {
                for i in 0..k {
                    let u = (x as f32 + (i as f32 + 0.5) / k as f32) / 5.0;
                    let v = 1.0 - (y as f32 + (j as f32 + 0.5) / k as f32) / 5.0;
                    let (b1, b2) = barycentrics(&mesh, tri, Vec3::new(u, v, 0.0));
                    sum += r.eval(&mesh, tri, b1, b2).x as f64;
                }
            }
            let brute = (sum / (k * k) as f64) as f32;
            assert!((fast - brute).abs() < 0.02, "({x}, {y}): {fast} vs {brute}");
        }
        // Constant reflectances are returned as they are.
        let c = Reflectance::Constant(Vec3::new(0.1, 0.2, 0.3));
        assert_eq!(
            footprint_mean(&c, &mesh, &atlas, 0, 1, 1),
            Vec3::new(0.1, 0.2, 0.3)
        );
    }

    #[test]
    fn reads_constants_and_bitmaps_of_the_fixture() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures");
        let t = Truth::load(&root.join("cbox/truth.xml")).unwrap();
        match &t.shapes["left"] {
            Reflectance::Constant(c) => assert_eq!(*c, Vec3::new(0.63, 0.065, 0.05)),
            other => panic!("{other:?}"),
        }
        let t = Truth::load(&root.join("cbox-tex/truth.xml")).unwrap();
        match &t.shapes["right"] {
            Reflectance::Bitmap { width, height, .. } => assert_eq!((*width, *height), (256, 171)),
            other => panic!("{other:?}"),
        }
    }
}

/// Accuracy of one shape's recovered albedo against the truth, over its observed texels.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ShapeAccuracy {
    pub shape: String,
    pub texels: u64,
    /// Mean over texels of `sum_c |K_d - K_true| / sum_c K_true`. Dominated by dark texels
    /// on textured shapes, where a small absolute error is a large relative one.
    pub mean_rel_error: f64,
    /// Relative L1 error of the whole texture: `sum |K_d - K_true| / sum K_true` over texels
    /// and channels.
    pub rel_l1_error: f64,
    /// Mean recovered and true RGB over the texels.
    pub mean_kd: [f64; 3],
    pub mean_truth: [f64; 3],
}

/// Barycentrics `(b1, b2)` of point `p` in triangle `tri` of `mesh`.
fn barycentrics(mesh: &Mesh, tri: usize, p: Vec3) -> (f32, f32) {
    let [a, b, c] = mesh.triangle(tri);
    let (e1, e2, d) = (b - a, c - a, p - a);
    let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let den = d11 * d22 - d12 * d12;
    if den == 0.0 {
        return (0.0, 0.0);
    }
    let (p1, p2) = (d.dot(e1), d.dot(e2));
    ((d22 * p1 - d12 * p2) / den, (d11 * p2 - d12 * p1) / den)
}

/// Samples per axis of a texel's square when averaging the truth over it.
const FOOTPRINT_SAMPLES: u32 = 4;

/// The true albedo averaged over texel `(x, y)`'s square of the atlas, mapped onto the
/// plane of triangle `tri` (the affine extension of the triangle's atlas -> mesh-UV map):
/// a texel stands for the mean albedo over its square, so this is what it should hold.
/// Texture detail finer than a texel is averaged, as any texture of that resolution must.
fn footprint_mean(
    r: &Reflectance,
    mesh: &Mesh,
    atlas: &crate::atlas::unwrap::ShapeAtlas,
    tri: usize,
    x: u32,
    y: u32,
) -> Rgb {
    if let Reflectance::Constant(c) = r {
        return *c;
    }
    let [a0, a1, a2] = atlas.corner_uv[tri];
    let (e1, e2) = (a1 - a0, a2 - a0);
    let det = e1.perp_dot(e2);
    if det == 0.0 {
        return r.eval(mesh, tri, 0.0, 0.0);
    }
    let n = FOOTPRINT_SAMPLES;
    let mut sum = Vec3::ZERO;
    for j in 0..n {
        for i in 0..n {
            let q = Vec2::new(
                x as f32 + (i as f32 + 0.5) / n as f32,
                y as f32 + (j as f32 + 0.5) / n as f32,
            ) - a0;
            let b1 = q.perp_dot(e2) / det;
            let b2 = e1.perp_dot(q) / det;
            sum += r.eval(mesh, tri, b1, b2);
        }
    }
    sum / (n * n) as f32
}

impl Truth {
    /// The true albedo of every covered texel of layout slot `slot`, averaged over the
    /// texel's square (row-major, `None` where uncovered), or `None` if the slot's shape has
    /// no truth.
    pub fn bake_slot(
        &self,
        p: &crate::pipeline::Prepared,
        geom: &crate::atlas::tiles::TileStore<crate::atlas::layout::TexelGeom>,
        slot: usize,
    ) -> Result<Option<Vec<Option<Rgb>>>> {
        let st = p.layout.slots[slot];
        let shape = &p.scene.shapes[st.shape];
        let Some(r) = self.shapes.get(&shape.id) else {
            return Ok(None);
        };
        let atlas = p.atlases[st.shape].as_ref();
        let mut out = vec![None; (st.width * st.height) as usize];
        let ts = p.layout.tile_size;
        for ty in 0..st.tiles_y {
            for tx in 0..st.tiles_x {
                let tile = st.first_tile + ty * st.tiles_x + tx;
                let g = geom.read_tile(tile as usize)?;
                for (off, g) in g.iter().enumerate() {
                    let (x, y) = (tx * ts + off as u32 % ts, ty * ts + off as u32 / ts);
                    if x >= st.width || y >= st.height || !g.covered() {
                        continue;
                    }
                    let tri = g.tri as usize;
                    out[(y * st.width + x) as usize] = Some(match atlas {
                        Some(a) => footprint_mean(r, &shape.mesh, a, tri, x, y),
                        None => {
                            let (b1, b2) = barycentrics(&shape.mesh, tri, g.p());
                            r.eval(&shape.mesh, tri, b1, b2)
                        }
                    });
                }
            }
        }
        Ok(Some(out))
    }

    /// Compare the recovered `K_d` of every reconstructed shape that has a truth with it,
    /// over observed texels (those a camera saw), shape by shape. The truth of a texel is
    /// the true albedo averaged over the texel's square ([`Truth::bake_slot`]).
    pub fn accuracy(
        &self,
        p: &crate::pipeline::Prepared,
        geom: &crate::atlas::tiles::TileStore<crate::atlas::layout::TexelGeom>,
        state: &crate::atlas::tiles::TileStore<crate::atlas::layout::TexelState>,
    ) -> Result<Vec<ShapeAccuracy>> {
        let mut out = Vec::new();
        for slot in 0..p.layout.slots.len() {
            if let Some(s) = self.score_slot(p, geom, state, slot)? {
                out.push(s.accuracy);
            }
        }
        Ok(out)
    }

    /// [`Truth::accuracy`] of one layout slot, with the baked truth and the recovered `K_d`
    /// of every texel it was computed from (row-major), or `None` if the slot's shape has no
    /// truth.
    pub fn score_slot(
        &self,
        p: &crate::pipeline::Prepared,
        geom: &crate::atlas::tiles::TileStore<crate::atlas::layout::TexelGeom>,
        state: &crate::atlas::tiles::TileStore<crate::atlas::layout::TexelState>,
        slot: usize,
    ) -> Result<Option<SlotScore>> {
        use crate::atlas::layout::flags;
        let Some(truth) = self.bake_slot(p, geom, slot)? else {
            return Ok(None);
        };
        let (k_d, _) = crate::pipeline::gather(p, slot, state, geom, |s| Vec3::from_array(s.k_d))?;
        let (observed, _) = crate::pipeline::gather(p, slot, state, geom, |s| {
            Vec3::splat((s.flags & flags::OBSERVED != 0) as u8 as f32)
        })?;
        let mut acc = ShapeAccuracy {
            shape: p.scene.shapes[p.layout.slots[slot].shape].id.clone(),
            ..Default::default()
        };
        let mut sum_true = 0.0f64;
        for ((kd, k_true), obs) in k_d.iter().zip(&truth).zip(&observed) {
            let Some(k_true) = k_true else { continue };
            let den = k_true.element_sum() as f64;
            if obs.x == 0.0 || den <= 0.0 {
                continue;
            }
            let diff = (*kd - *k_true).abs().element_sum() as f64;
            acc.mean_rel_error += diff / den;
            acc.rel_l1_error += diff;
            sum_true += den;
            for c in 0..3 {
                acc.mean_kd[c] += kd[c] as f64;
                acc.mean_truth[c] += k_true[c] as f64;
            }
            acc.texels += 1;
        }
        let n = acc.texels.max(1) as f64;
        acc.mean_rel_error /= n;
        acc.rel_l1_error /= sum_true.max(f64::MIN_POSITIVE);
        for c in 0..3 {
            acc.mean_kd[c] /= n;
            acc.mean_truth[c] /= n;
        }
        Ok(Some(SlotScore {
            accuracy: acc,
            truth,
            k_d,
        }))
    }
}

/// One slot scored by [`Truth::score_slot`].
#[derive(Debug, Clone)]
pub struct SlotScore {
    pub accuracy: ShapeAccuracy,
    /// The true albedo per texel, averaged over its square (`None` where uncovered).
    pub truth: Vec<Option<Rgb>>,
    /// The recovered `K_d` per texel (observed or filled).
    pub k_d: Vec<Vec3>,
}
