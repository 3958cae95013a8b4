//! The recovered albedo in the input mesh's own UVs, every repeat of a tiled texture averaged
//! into one: `textures/<id>_albedo_uv.exr` on `meshes/<id>_uv.obj`, which `scene.xml` then uses.
//!
//! **Why.** kdmap's atlas gives every point of a surface its own texels. Scenes from Mitsuba,
//! Blender and game engines paint a surface through its UVs, and a ground or a wall usually
//! tiles one texture many times (UVs running over `[0, 20]`: 400 repeats). Where that holds,
//! every repeat is a fresh look at the same texels: folding the atlas into the UV square
//! averages the photos' noise over the repeats, and the repeats are seen at different
//! sub-pixel phases, so the sharpest looks at each texel resolve its edges finer than any one
//! training pixel. Mitsuba 3's own inverse rendering optimises a bitmap over those UVs and
//! does better than an atlas on tiled grounds for exactly this reason.
//!
//! **How.** Every observed atlas texel of the shape is one sample: its `K_d`, the UV of its
//! centre (barycentric on its triangle), and a weight `(w / area / max)^`[`SHARPNESS`] (`w`
//! the projection's observation weight, pixels' worth; over the texel's area, pixels per unit
//! area: how finely a camera saw it). Samples are splatted bilinearly into an `R x R` texture
//! that wraps (Mitsuba's bitmaps repeat by default), `R` the largest power of two giving
//! [`SAMPLES_PER_TEXEL`] samples per UV texel; UV texels no sample reached take the mean of
//! their filled neighbours, ring by ring.
//!
//! **When.** `[output] uv_fold = "auto"` (the default) folds a reconstructed shape whose UVs
//! cover the texture at least [`MIN_REPEATS`] times, often enough for the fold to be finer
//! than the atlas ([`finer_than_the_atlas`]), and keeps the fold only where it explains the
//! atlas: independent repeats must agree. The samples are split by the parity of their repeat
//! (`floor(u) + floor(v)`), each half folded alone, and the two halves' luminances correlated
//! over the texels both reach ([`agreement`]); the fold is kept above [`MIN_AGREEMENT`]. A
//! repeat's blur or noise does not decide it (both halves share them), only whether the
//! repeats show the same texture. An albedo that is not a function of the
//! UVs (UVs made for something else) leaves the atlas in `scene.xml`. The atlas texture and
//! its mesh are written either way; `report.json` `uv_fold` says what was decided per shape.
//!
//! **Cost.** Two streaming passes over the shape's tiles (count, splat), one tile of each
//! store at a time; the fold holds 92 bytes a texel while it is made, its side capped to
//! a quarter of `memory_budget_mib` (1024 x 1024 at the default). Folding the open scene's
//! 593k observed ground texels costs less than the output stage's run-to-run spread.
//!
//! Written by hand: a weighted scatter into a wrapping grid is a few lines, and no crate
//! resamples between an atlas and a mesh's UVs.

use crate::atlas::store::TileStore;
use crate::atlas::store::{Layout, TexelGeom, TexelState};
use crate::atlas::RunContext;
use crate::base::error::Result;
use crate::image::{write_exr_rgb, write_png_srgb};
use crate::report::UvFold;
use crate::scene::{luminance, Mesh};
use glam::{Vec2, Vec3};
use std::path::Path;

/// Fold every reconstructed shape whose UVs tile its texture (see the module docs): writes
/// `textures/<id>_albedo_uv.exr|png` and `meshes/<id>_uv.obj` under `out` for each fold kept.
/// Streams the stores twice per shape (census, splat), so it holds one tile of
/// each and the fold itself, whose side is capped so that it takes at most `budget` bytes.
/// Returns, per shape, whether `scene.xml` is to use its fold, and what each fold found.
pub fn fold_shapes(
    p: &RunContext,
    stores: (&TileStore<TexelGeom>, &TileStore<TexelState>),
    out: &Path,
    budget: u64,
) -> Result<(Vec<bool>, Vec<UvFold>)> {
    let mut used = vec![false; p.scene.shapes.len()];
    let mut found = Vec::new();
    for (slot, st) in p.layout.slots.iter().enumerate() {
        let Some((repeats, census)) = tiled_census(p, slot, stores)? else {
            continue;
        };
        let shape = &p.scene.shapes[st.shape];
        let mut f = UvFold {
            shape: shape.id.clone(),
            repeats,
            samples: census.n,
            decision: "few samples".into(),
            ..Default::default()
        };
        if let Some(res) = census.resolution(budget) {
            f.resolution = res;
            f.decision = "coarse".into();
            if finer_than_the_atlas(res, census.n, repeats) {
                let mut halves = Halves::new(res, census.top);
                for_each_sample(&p.layout, slot, &shape.mesh, stores, |s| halves.add(s))?;
                f.agreement = halves.agreement();
                f.used = f.agreement > MIN_AGREEMENT;
                f.decision = if f.used { "folded" } else { "disagree" }.into();
                if f.used {
                    write_fold(out, shape, &halves.finish())?;
                    used[st.shape] = true;
                }
            }
        }
        found.push(f);
    }
    Ok((used, found))
}

/// The bytes a fold may take: a quarter of the run's memory budget.
pub fn fold_budget(memory_budget_mib: u64) -> u64 {
    (memory_budget_mib << 20) / 4
}

/// Per slot, whether its shape is one `auto` may fold: reconstructed, its UVs tiling the
/// texture [`MIN_REPEATS`] times or more, with observed texels enough for a fold finer than
/// the atlas (the tests of [`fold_shapes`] but the last, the repeats' agreement, which needs
/// `K_d`). Read after the projection: the sigma filter leaves these shapes alone, since the
/// fold averages their noise over the repeats and the filter would only take detail.
/// One streaming pass over each such shape's tiles.
pub fn foldable_slots(
    p: &RunContext,
    stores: (&TileStore<TexelGeom>, &TileStore<TexelState>),
    budget: u64,
) -> Result<Vec<bool>> {
    (0..p.layout.slots.len())
        .map(|slot| {
            Ok(tiled_census(p, slot, stores)?.is_some_and(|(repeats, c)| {
                c.resolution(budget)
                    .is_some_and(|res| finer_than_the_atlas(res, c.n, repeats))
            }))
        })
        .collect()
}

/// For a reconstructed shape whose UVs tile its texture [`MIN_REPEATS`] times or more (the
/// shapes a fold is tried on), its repeats and the census of its samples (one streaming pass
/// over its tiles); `None` for any other slot.
fn tiled_census(
    p: &RunContext,
    slot: usize,
    stores: (&TileStore<TexelGeom>, &TileStore<TexelState>),
) -> Result<Option<(f32, Census)>> {
    let shape = &p.scene.shapes[p.layout.slots[slot].shape];
    let repeats = uv_repeats(&shape.mesh);
    if !shape.is_reconstructed() || repeats < MIN_REPEATS {
        return Ok(None);
    }
    let mut census = Census::default();
    for_each_sample(&p.layout, slot, &shape.mesh, stores, |s| census.add(s))?;
    Ok(Some((repeats, census)))
}

/// The largest power-of-two side whose fold (two [`Splat`]s of [`SPLAT_BYTES`] a texel while
/// it is made, and the texture beside it) fits in `budget` bytes, at least [`MIN_RES`].
pub fn max_res(budget: u64) -> u32 {
    let per_texel = 2 * SPLAT_BYTES + 16 + 12;
    let mut r = MAX_RES;
    while r > MIN_RES && (r as u64).pow(2) * per_texel > budget {
        r /= 2;
    }
    r
}

/// `textures/<id>_albedo_uv.exr|png` and `meshes/<id>_uv.obj` for a kept fold.
fn write_fold(out: &Path, shape: &crate::scene::Shape, tex: &UvTexture) -> Result<()> {
    let dir = out.join("textures");
    crate::base::fsio::create_dir(&dir)?;
    // names built whole: an id may hold a dot (Blender's "Plane.001")
    let name = |ext: &str| dir.join(format!("{}_albedo_uv.{ext}", shape.id));
    let r = tex.res;
    write_exr_rgb(name("exr"), r, r, &tex.texels, false)?;
    write_png_srgb(name("png"), r, r, &tex.texels, 0.0)?;
    super::obj::write_shape_uv_mesh(&out.join("meshes"), shape)
}

/// Fewest times a shape's UVs must cover the texture (the sum of its triangles' UV areas)
/// for `auto` to fold it. A texture used once or twice (a sphere's or a box's own layout)
/// gains little from folding and loses resolution.
pub const MIN_REPEATS: f32 = 4.0;

/// Smallest agreement of independent repeats ([`agreement`]) at which a fold is kept: 0.3.
/// Grounds whose albedo follows their UVs score about 0.6 (bricks) to 0.93 (a checker); the
/// same atlases folded through UVs the albedo does not follow score about 0. (The repeats are
/// compared with each other, not the fold with each atlas texel: thin detail such as mortar
/// lines is blurred in far texels and sharp in the fold.)
pub const MIN_AGREEMENT: f32 = 0.3;

/// Samples per UV texel the resolution is chosen for: 8. A coarser fold blurs the texture; a
/// finer one leaves UV texels to a few noisy samples, and below one sample per texel the
/// error grows several-fold.
pub const SAMPLES_PER_TEXEL: f64 = 8.0;

/// Power of the samples' relative resolution in their weight: the finest looks dominate.
/// Folded grounds come out sharper, and closer to the truth, as the power rises up to 8.
pub const SHARPNESS: i32 = 8;

/// How much finer per side than the atlas's texels of one repeat a fold must be
/// ([`finer_than_the_atlas`]): at 1 its bilinear splat blurs as much as the atlas does.
pub const FINER: f64 = 2.0;

/// Smallest and largest fold resolutions.
pub const MIN_RES: u32 = 16;
pub const MAX_RES: u32 = 4096;

/// One observed atlas texel, seen from the UV square.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// UV of its centre (OBJ convention, `v` up; not wrapped).
    pub uv: Vec2,
    pub kd: Vec3,
    /// Pixels' worth of observation per unit area ([`SHARPNESS`] is applied in [`Splat::add`]).
    pub density: f32,
}

/// A folded texture: `res x res` texels, row 0 at the top (`v = 1`), wrapping.
#[derive(Debug, Clone, PartialEq)]
pub struct UvTexture {
    pub res: u32,
    pub texels: Vec<Vec3>,
    /// Texels no sample reached (filled from their neighbours).
    pub filled: u64,
}

/// How many times `mesh`'s UVs cover the unit square: the sum of its triangles' UV areas (0
/// without UVs).
pub fn uv_repeats(mesh: &Mesh) -> f32 {
    let Some(uv) = mesh
        .uvs
        .as_ref()
        .filter(|u| u.len() == mesh.positions.len())
    else {
        return 0.0;
    };
    let area: f64 = mesh
        .triangles
        .iter()
        .map(|&[a, b, c]| {
            let (a, b, c) = (uv[a as usize], uv[b as usize], uv[c as usize]);
            0.5 * ((b - a).perp_dot(c - a) as f64).abs()
        })
        .sum();
    area as f32
}

/// The UV of point `p` on triangle `t` of `mesh` (barycentric in the triangle's plane), if the
/// mesh has UVs and the triangle an area.
pub fn uv_at(mesh: &Mesh, t: usize, p: Vec3) -> Option<Vec2> {
    let uv = mesh.uvs.as_ref()?;
    let [ia, ib, ic] = *mesh.triangles.get(t)?;
    let [a, b, c] = mesh.triangle(t);
    let (e1, e2, d) = (b - a, c - a, p - a);
    let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let den = d11 * d22 - d12 * d12;
    if den.abs() <= f32::MIN_POSITIVE || !den.is_finite() {
        return None;
    }
    let (d1, d2) = (d.dot(e1), d.dot(e2));
    let s = (d22 * d1 - d12 * d2) / den;
    let r = (d11 * d2 - d12 * d1) / den;
    let (ua, ub, uc) = (uv[ia as usize], uv[ib as usize], uv[ic as usize]);
    Some(ua + (ub - ua) * s + (uc - ua) * r)
}

/// Calls `f` with every observed texel of `slot` as a [`Sample`] of `mesh` (the slot's
/// shape), in tile order, reading one tile of each store at a time.
pub fn for_each_sample(
    layout: &Layout,
    slot: usize,
    mesh: &Mesh,
    (geom, state): (&TileStore<TexelGeom>, &TileStore<TexelState>),
    mut f: impl FnMut(&Sample),
) -> Result<()> {
    for t in layout.slot_tiles(slot) {
        let (g, st) = (geom.read_tile(t as usize)?, state.read_tile(t as usize)?);
        for (off, _, _) in layout.span(t).texels() {
            let (g, s) = (&g[off], &st[off]);
            if !g.covered() || s.weight <= 0.0 || g.area <= 0.0 {
                continue;
            }
            if let Some(uv) = uv_at(mesh, g.tri as usize, g.p()) {
                f(&Sample {
                    uv,
                    kd: Vec3::from_array(s.k_d),
                    density: s.weight / g.area,
                });
            }
        }
    }
    Ok(())
}

/// What the first pass over the samples learns: how many, and the largest density (the
/// weights' scale).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Census {
    pub n: u64,
    pub top: f32,
}

impl Census {
    pub fn add(&mut self, s: &Sample) {
        self.n += 1;
        self.top = self.top.max(s.density);
    }

    /// The fold's side for these samples ([`resolution`]) within a `budget` of bytes
    /// ([`max_res`]); `None` with too few samples.
    pub fn resolution(&self, budget: u64) -> Option<u32> {
        resolution(self.n).map(|r| r.min(max_res(budget)))
    }
}

/// The fold's resolution for `n` samples: the largest power of two `R` with
/// `n / R^2 >= SAMPLES_PER_TEXEL`, within [`MIN_RES`, `MAX_RES`]; `None` when even
/// [`MIN_RES`] would get fewer.
pub fn resolution(n: u64) -> Option<u32> {
    let fits = |r: u32| n as f64 / (r as f64 * r as f64) >= SAMPLES_PER_TEXEL;
    if !fits(MIN_RES) {
        return None;
    }
    let mut r = MIN_RES;
    while r < MAX_RES && fits(r * 2) {
        r *= 2;
    }
    Some(r)
}

/// Whether a fold of `res x res` texels is at least [`FINER`] times as fine per side as the
/// atlas's own texels of one repeat (`samples / repeats` of them). With few repeats the fold
/// would be coarser than the atlas and lose its detail: folded, the `lights` example's grass
/// ground (4 repeats, 128 x 128 against about 200 x 200 atlas texels a repeat) and its crate
/// (6 faces, 64 x 64 against 75 x 75) would have several times the atlas's albedo error.
pub fn finer_than_the_atlas(res: u32, samples: u64, repeats: f32) -> bool {
    let per_repeat = samples as f64 / (repeats as f64).max(1.0);
    (res as f64).powi(2) >= FINER * FINER * per_repeat
}

/// The weighted bilinear splat of samples into a `res x res` wrapping grid (see the module
/// docs). Sums in f64 in the samples' order, so the same samples give the same bits.
pub struct Splat {
    res: u32,
    top: f64,
    sum: Vec<[f64; 3]>,
    wsum: Vec<f64>,
}

/// Bytes a [`Splat`] holds per texel.
pub const SPLAT_BYTES: u64 = 32;

impl Splat {
    /// An empty grid for samples whose largest density is `top`.
    pub fn new(res: u32, top: f32) -> Splat {
        let n = res as usize * res as usize;
        Splat {
            res,
            top: top as f64,
            sum: vec![[0.0; 3]; n],
            wsum: vec![0.0; n],
        }
    }

    pub fn add(&mut self, s: &Sample) {
        let (n, r) = (self.res as i64, self.res as f64);
        let w = if self.top > 0.0 {
            (s.density as f64 / self.top).powi(SHARPNESS)
        } else {
            1.0
        };
        let (x, y) = (s.uv.x as f64 * r - 0.5, (1.0 - s.uv.y as f64) * r - 0.5);
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        for (dx, dy, b) in [
            (0, 0, (1.0 - fx) * (1.0 - fy)),
            (1, 0, fx * (1.0 - fy)),
            (0, 1, (1.0 - fx) * fy),
            (1, 1, fx * fy),
        ] {
            let xi = (x0 as i64 + dx).rem_euclid(n) as usize;
            let yi = (y0 as i64 + dy).rem_euclid(n) as usize;
            let i = yi * n as usize + xi;
            let wb = w * b;
            for (acc, k) in self.sum[i].iter_mut().zip(s.kd.to_array()) {
                *acc += wb * k as f64;
            }
            self.wsum[i] += wb;
        }
    }

    /// The weighted means, holes filled ([`fill_holes`]).
    pub fn finish(self) -> UvTexture {
        let mut texels: Vec<Option<Vec3>> = self
            .sum
            .iter()
            .zip(&self.wsum)
            .map(|(s, &w)| {
                (w > 0.0)
                    .then(|| Vec3::new((s[0] / w) as f32, (s[1] / w) as f32, (s[2] / w) as f32))
            })
            .collect();
        let filled = fill_holes(&mut texels, self.res as usize);
        UvTexture {
            res: self.res,
            texels: texels
                .into_iter()
                .map(|t| t.unwrap_or(Vec3::ZERO))
                .collect(),
            filled,
        }
    }
}

/// Gives every empty texel of a wrapping `n x n` grid the mean of its filled 8-neighbours,
/// ring by ring inwards; returns how many were empty. All empty stays all empty.
fn fill_holes(t: &mut [Option<Vec3>], n: usize) -> u64 {
    let empty = t.iter().filter(|v| v.is_none()).count() as u64;
    while t.iter().any(Option::is_none) && t.iter().any(Option::is_some) {
        let prev = t.to_vec();
        for y in 0..n {
            for x in 0..n {
                if prev[y * n + x].is_some() {
                    continue;
                }
                let (mut s, mut k) = (Vec3::ZERO, 0u32);
                for (dx, dy) in [
                    (-1i64, -1i64),
                    (0, -1),
                    (1, -1),
                    (-1, 0),
                    (1, 0),
                    (-1, 1),
                    (0, 1),
                    (1, 1),
                ] {
                    let xi = (x as i64 + dx).rem_euclid(n as i64) as usize;
                    let yi = (y as i64 + dy).rem_euclid(n as i64) as usize;
                    if let Some(v) = prev[yi * n + xi] {
                        s += v;
                        k += 1;
                    }
                }
                if k > 0 {
                    t[y * n + x] = Some(s / k as f32);
                }
            }
        }
    }
    empty
}

/// A fold made as two halves: the samples of even and of odd repeats (`floor(u) + floor(v)`),
/// each splatted alone; the fold is their sum.
pub struct Halves {
    half: [Splat; 2],
}

impl Halves {
    pub fn new(res: u32, top: f32) -> Halves {
        Halves {
            half: [Splat::new(res, top), Splat::new(res, top)],
        }
    }

    pub fn add(&mut self, s: &Sample) {
        let parity = (s.uv.x.floor() as i64 + s.uv.y.floor() as i64).rem_euclid(2);
        self.half[parity as usize].add(s);
    }

    /// [`agreement`] of the two halves.
    pub fn agreement(&self) -> f32 {
        agreement(&self.half[0], &self.half[1])
    }

    /// The whole fold.
    pub fn finish(self) -> UvTexture {
        let [mut a, b] = self.half;
        for (x, y) in a.sum.iter_mut().zip(&b.sum) {
            for (p, q) in x.iter_mut().zip(y) {
                *p += q;
            }
        }
        for (x, y) in a.wsum.iter_mut().zip(&b.wsum) {
            *x += y;
        }
        a.finish()
    }
}

/// How alike two folds of the same texels are: the correlation of their luminances over the
/// texels both reached (each half's weighted mean). Near 1 when independent repeats show the
/// same texture, near 0 when the albedo does not follow the UVs; 0 when fewer than 16 texels
/// are shared or either is flat.
pub fn agreement(a: &Splat, b: &Splat) -> f32 {
    let y = |s: &[f64; 3], w: f64| {
        luminance(Vec3::new(
            (s[0] / w) as f32,
            (s[1] / w) as f32,
            (s[2] / w) as f32,
        )) as f64
    };
    let pairs: Vec<(f64, f64)> = (0..a.wsum.len())
        .filter(|&i| a.wsum[i] > 0.0 && b.wsum[i] > 0.0)
        .map(|i| (y(&a.sum[i], a.wsum[i]), y(&b.sum[i], b.wsum[i])))
        .collect();
    if pairs.len() < 16 {
        return 0.0;
    }
    let n = pairs.len() as f64;
    let (ma, mb) = pairs
        .iter()
        .fold((0.0, 0.0), |(x, y), (p, q)| (x + p / n, y + q / n));
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (p, q) in &pairs {
        let (da, db) = (p - ma, q - mb);
        sab += da * db;
        saa += da * da;
        sbb += db * db;
    }
    if saa > 0.0 && sbb > 0.0 {
        (sab / (saa * sbb).sqrt()) as f32
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::mesh;

    /// `samples` splatted at `res` as [`fold_shapes`] does it (a census, then the halves).
    fn halves_of(samples: &[Sample], res: u32) -> Halves {
        let mut c = Census::default();
        samples.iter().for_each(|s| c.add(s));
        let mut h = Halves::new(res, c.top);
        samples.iter().for_each(|s| h.add(s));
        h
    }

    /// The whole fold of `samples` at `res`.
    fn fold(samples: &[Sample], res: u32) -> UvTexture {
        halves_of(samples, res).finish()
    }

    /// The [`agreement`] of the even and odd repeats of `samples` folded at `res`.
    fn split_agreement(samples: &[Sample], res: u32) -> f32 {
        halves_of(samples, res).agreement()
    }

    /// A periodic albedo: a 4 x 4 checker of two colours over each UV repeat.
    fn checker(uv: Vec2) -> Vec3 {
        let (u, v) = (uv.x.rem_euclid(1.0), uv.y.rem_euclid(1.0));
        if ((u * 4.0) as u32 + (v * 4.0) as u32) % 2 == 0 {
            Vec3::new(0.7, 0.6, 0.5)
        } else {
            Vec3::new(0.1, 0.2, 0.05)
        }
    }

    /// Deterministic noise in [-1, 1].
    fn noise(i: u64) -> f32 {
        let mut x = i.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0xD1B5_4A32_D192_ED03;
        x ^= x >> 31;
        x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        x ^= x >> 29;
        (x as f64 / u64::MAX as f64 * 2.0 - 1.0) as f32
    }

    /// Samples on a grid over `reps x reps` repeats, `per` per repeat and side, with relative
    /// noise `amp` and phase offsets that differ per repeat (as a camera's pixels do).
    fn tiled(reps: u32, per: u32, amp: f32, f: impl Fn(Vec2) -> Vec3) -> Vec<Sample> {
        let mut out = Vec::new();
        let mut i = 0u64;
        for ry in 0..reps {
            for rx in 0..reps {
                let phase = Vec2::new(noise(i * 7 + 1), noise(i * 7 + 2)) * 0.5;
                for y in 0..per {
                    for x in 0..per {
                        let uv = Vec2::new(rx as f32, ry as f32)
                            + (Vec2::new(x as f32, y as f32) + 0.5 + phase) / per as f32;
                        i += 1;
                        out.push(Sample {
                            uv,
                            kd: f(uv) * (1.0 + amp * noise(i)),
                            density: 1.0,
                        });
                    }
                }
            }
        }
        out
    }

    /// Mean relative luminance error of `tex` against `f` at the centres of the texels
    /// `(x, y)` that `which` accepts.
    fn error(tex: &UvTexture, f: impl Fn(Vec2) -> Vec3, which: impl Fn(u32, u32) -> bool) -> f32 {
        let r = tex.res as f32;
        let (mut e, mut n) = (0.0, 0);
        for y in 0..tex.res {
            for x in (0..tex.res).filter(|&x| which(x, y)) {
                let uv = Vec2::new((x as f32 + 0.5) / r, 1.0 - (y as f32 + 0.5) / r);
                let (a, b) = (
                    luminance(tex.texels[(y * tex.res + x) as usize]),
                    luminance(f(uv)),
                );
                e += (a - b).abs() / b;
                n += 1;
            }
        }
        e / n as f32
    }

    #[test]
    fn repeats_are_the_uv_area() {
        let mut m = mesh::rectangle(); // UVs over [0, 1]^2
        assert!((uv_repeats(&m) - 1.0).abs() < 1e-6);
        for uv in m.uvs.as_mut().unwrap() {
            *uv *= 20.0;
        }
        assert!((uv_repeats(&m) - 400.0).abs() < 1e-3);
        m.uvs = None;
        assert_eq!(uv_repeats(&m), 0.0);
    }

    /// The UV of a point is the barycentric mix of its triangle's corners' UVs: the corners
    /// give their own UVs, a point a third of the way along an edge a third of the way.
    #[test]
    fn uv_at_interpolates_the_corners() {
        let m = mesh::rectangle();
        let uv = m.uvs.as_ref().unwrap();
        for t in 0..m.triangles.len() {
            let tri = m.triangles[t];
            let p = m.triangle(t);
            for k in 0..3 {
                let got = uv_at(&m, t, p[k]).unwrap();
                assert!((got - uv[tri[k] as usize]).length() < 1e-5, "{got}");
            }
            let q = p[0] + (p[1] - p[0]) / 3.0;
            let want = uv[tri[0] as usize] + (uv[tri[1] as usize] - uv[tri[0] as usize]) / 3.0;
            assert!((uv_at(&m, t, q).unwrap() - want).length() < 1e-5);
        }
    }

    /// Row 0 is `v = 1` (the top of the image, as Mitsuba reads a bitmap through OBJ UVs),
    /// and UVs wrap: a sample at a texel's centre (`uv` given as that centre plus whole
    /// repeats) puts all its weight on that texel of the splat.
    #[test]
    fn texels_are_laid_out_as_mitsuba_reads_them() {
        let landed = |uv: Vec2| {
            let mut sp = Splat::new(16, 1.0);
            sp.add(&Sample {
                uv,
                kd: Vec3::ONE,
                density: 1.0,
            });
            let i = sp
                .wsum
                .iter()
                .position(|&w| w == 1.0)
                .expect("one texel takes it all");
            ((i % 16) as u32, (i / 16) as u32)
        };
        let centre = |x: f32, y: f32| Vec2::new((x + 0.5) / 16.0, 1.0 - (y + 0.5) / 16.0);
        assert_eq!(landed(centre(1.0, 0.0)), (1, 0));
        assert_eq!(landed(centre(1.0, 15.0)), (1, 15));
        assert_eq!(landed(centre(1.0, 0.0) + Vec2::new(3.0, -2.0)), (1, 0));
        assert_eq!(landed(centre(-1.0, 8.0)), (15, 8));
    }

    /// The example scenes' cases: the open scene's and envmap's grounds fold, `lights`'
    /// ground and crate (4 and 6 repeats) would be coarser than their atlas and do not.
    #[test]
    fn a_fold_must_be_finer_than_the_atlas() {
        assert!(finer_than_the_atlas(256, 593_463, 400.0));
        assert!(finer_than_the_atlas(128, 131_236, 144.0));
        assert!(!finer_than_the_atlas(128, 158_811, 4.0));
        assert!(!finer_than_the_atlas(64, 34_117, 6.0));
        // exactly twice as fine per side passes
        assert!(finer_than_the_atlas(64, 64 * 64 * 10 / 4, 10.0));
        assert!(!finer_than_the_atlas(64, 64 * 64 * 10 / 4 + 10, 10.0));
    }

    /// Which shapes the sigma filter leaves to the fold: of three 2 x 2 rectangles at 64
    /// texels per unit (16384 observed texels each: a 32 x 32 fold), the one whose UVs tile
    /// 256 times, not the one mapped once, nor the one tiled 4 times (a fold of its 4096
    /// atlas texels a repeat would be coarser than they are).
    #[test]
    fn only_shapes_the_fold_may_take_skip_the_filter() {
        use crate::atlas::store::TexelState;
        use crate::atlas::testing::Built;
        let rect = |id: &str, scale: f32| {
            let mut m = mesh::rectangle();
            for uv in m.uvs.as_mut().unwrap() {
                *uv *= scale;
            }
            crate::scene::Shape::plain(id, m, crate::scene::Sides::Front)
        };
        let shapes = vec![rect("once", 1.0), rect("tiled", 16.0), rect("coarse", 2.0)];
        let b = Built::new(shapes, vec![], 64.0, vec![]);
        let seen = TexelState {
            weight: 1.0,
            ..Default::default()
        };
        let state =
            b.p.create_store(b.dir.path().join("state.tiles"), seen)
                .unwrap();
        let foldable = foldable_slots(&b.p, (&b.geom, &state), fold_budget(1024)).unwrap();
        let by_shape: Vec<(&str, bool)> = (b.p.layout.slots.iter().zip(&foldable))
            .map(|(st, &f)| (b.p.scene.shapes[st.shape].id.as_str(), f))
            .collect();
        assert_eq!(by_shape.len(), 3);
        for (id, f) in by_shape {
            assert_eq!(f, id == "tiled", "{id}");
        }
        // the output reads "left to the fold" off the fold's decisions (report.json's
        // `atlas_filtered`): the shapes decided "folded" or "disagree" are those skipped
        let out = tempfile::tempdir().unwrap();
        let budget = fold_budget(1024);
        let (_, found) = fold_shapes(&b.p, (&b.geom, &state), out.path(), budget).unwrap();
        let taken: Vec<&str> = (found.iter())
            .filter(|f| matches!(f.decision.as_str(), "folded" | "disagree"))
            .map(|f| f.shape.as_str())
            .collect();
        assert_eq!(taken, vec!["tiled"]);
        // unobserved, nothing is left to the fold
        let dark =
            b.p.create_store(b.dir.path().join("dark.tiles"), TexelState::default());
        let none = foldable_slots(&b.p, (&b.geom, &dark.unwrap()), fold_budget(1024)).unwrap();
        assert_eq!(none, vec![false; 3]);
    }

    /// A kept fold's files carry the whole shape id, dots included (Blender's `Plane.001`).
    #[test]
    fn fold_files_keep_a_dotted_id() {
        let dir = tempfile::tempdir().unwrap();
        let shape = crate::scene::Shape {
            kind: "obj".into(),
            ..crate::scene::Shape::plain("Plane.001", mesh::rectangle(), crate::scene::Sides::Front)
        };
        let tex = UvTexture {
            res: 16,
            texels: vec![Vec3::splat(0.5); 256],
            filled: 0,
        };
        write_fold(dir.path(), &shape, &tex).unwrap();
        for f in [
            "textures/Plane.001_albedo_uv.exr",
            "textures/Plane.001_albedo_uv.png",
            "meshes/Plane.001_uv.obj",
        ] {
            assert!(dir.path().join(f).is_file(), "{f}");
        }
    }

    /// The fold's side is capped by the memory it may take (92 bytes a texel): the default
    /// budget's quarter (256 MiB) holds 1024 x 1024; 1 MiB holds 64 x 64; nothing goes under
    /// 16 x 16.
    #[test]
    fn the_fold_fits_its_budget() {
        assert_eq!(max_res(256 << 20), 1024);
        assert_eq!(max_res(1 << 20), 64);
        assert_eq!(max_res(0), MIN_RES);
        assert_eq!(max_res(u64::MAX), MAX_RES);
    }

    #[test]
    fn resolution_gives_each_texel_its_samples() {
        assert_eq!(resolution(8 * 16 * 16 - 1), None);
        assert_eq!(resolution(8 * 16 * 16), Some(16));
        assert_eq!(resolution(625_025), Some(256)); // the open scene's ground
        assert_eq!(resolution(142_396), Some(128)); // envmap's
        assert_eq!(resolution(u64::MAX), Some(MAX_RES));
    }

    /// A smooth periodic albedo.
    fn waves(uv: Vec2) -> Vec3 {
        let (u, v) = (uv.x * std::f32::consts::TAU, uv.y * std::f32::consts::TAU);
        Vec3::new(0.5, 0.4, 0.3) * (1.0 + 0.5 * u.sin() * v.cos())
    }

    /// 64 repeats of a smooth albedo, each seen through 24 x 24 samples with 10% noise (mean
    /// |noise| 5%) at its own phase: every texel of the fold gets about 36 samples, so its
    /// error falls about 6-fold, under 1.5%; the even and the odd repeats agree (well over
    /// `MIN_AGREEMENT`). A checker folds back too, sharp but for the bilinear splat's
    /// one-texel blur at its edges: its texels away from an edge are within 1.5%.
    #[test]
    fn a_tiled_albedo_folds_back_with_its_noise_averaged() {
        let s = tiled(8, 24, 0.1, waves);
        let res = resolution(s.len() as u64).unwrap();
        assert_eq!(res, 64);
        let tex = fold(&s, res);
        assert_eq!(tex.filled, 0);
        let e = error(&tex, waves, |_, _| true);
        let single = s
            .iter()
            .map(|s| (luminance(s.kd) / luminance(waves(s.uv)) - 1.0).abs())
            .sum::<f32>()
            / s.len() as f32;
        eprintln!("smooth: one sample {single:.4}, fold {e:.4}");
        assert!(
            e < 0.015 && e < single / 3.0,
            "fold error {e}, one sample {single}"
        );
        let a = split_agreement(&s, res);
        assert!(a > 0.8, "agreement {a}");

        let s = tiled(8, 24, 0.1, checker);
        let tex = fold(&s, res);
        // a 4 x 4 checker at 64 texels: edges every 8 texels
        let inner = |x: u32, y: u32| (2..6).contains(&(x % 8)) && (2..6).contains(&(y % 8));
        let e = error(&tex, checker, inner);
        eprintln!(
            "checker: fold {e:.4} away from the edges, agreement {:.3}",
            split_agreement(&s, res)
        );
        assert!(e < 0.015, "fold error {e}");
        assert!(split_agreement(&s, res) > 0.8);
    }

    /// The same samples with an albedo that is not a function of the UVs (a pattern that
    /// drifts from repeat to repeat) do not fold: the even and odd repeats' folds are
    /// unrelated, their agreement under `MIN_AGREEMENT`.
    #[test]
    fn an_albedo_that_is_not_periodic_in_uv_is_refused() {
        let drift = |uv: Vec2| checker(uv * 1.37);
        let s = tiled(8, 24, 0.1, drift);
        let a = split_agreement(&s, resolution(s.len() as u64).unwrap());
        assert!(a.abs() < MIN_AGREEMENT, "agreement {a}");
    }

    /// The sharpest samples dominate: of two samples at a texel, one four times as dense
    /// weighs `4^SHARPNESS` times as much.
    #[test]
    fn denser_samples_dominate() {
        let uv = Vec2::new(0.5 / 16.0, 1.0 - 0.5 / 16.0); // texel (0, 0)'s centre
        let s = |kd: f32, density: f32| Sample {
            uv,
            kd: Vec3::splat(kd),
            density,
        };
        let tex = fold(&[s(1.0, 4.0), s(0.0, 1.0)], 16);
        let want = 1.0 / (1.0 + 0.25f64.powi(SHARPNESS)) as f32;
        assert!((tex.texels[0].x - want).abs() < 1e-6, "{}", tex.texels[0]);
        // every other texel was empty and took its neighbours' value
        assert_eq!(tex.filled, 16 * 16 - 1);
        assert!(tex
            .texels
            .iter()
            .all(|t| (t.x - tex.texels[0].x).abs() < 1e-6));
    }
}
