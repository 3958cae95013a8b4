//! The inverse map from texture to scene (method step 1): which triangle, barycentrics,
//! world position, normal and world area each texel stands for, plus sub-texel samples (to
//! average photo pixels over a texel larger than a pixel) and gutter dilation (so filtered
//! lookups of output textures never read the background).
//!
//! A texel belongs to the triangle whose texel-space footprint contains its *center*
//! `(x + 0.5, y + 0.5)`. Points on an edge shared by two triangles go to exactly one of them:
//! edge functions are evaluated from the edge's lexicographically smaller endpoint, so both
//! triangles compute the same number with opposite signs, and a zero is broken by a
//! top-left style rule on the edge direction. Where triangles overlap (bad mesh UVs) the
//! lowest triangle index wins and the extra claims are counted. Everything is deterministic
//! and independent of the rayon thread count.

use crate::atlas::uv::ShapeAtlas;
use crate::scene::Mesh;
use glam::{DVec2, Vec3};
use rayon::prelude::*;
use std::ops::Range;
use std::sync::OnceLock;

/// No triangle (a gutter texel, or a triangle without a chart).
pub const NONE: u32 = u32::MAX;

/// Rows per band of the parallel rasterizer.
const BAND: usize = 16;
/// Side in texels of the blocks that index triangles for sub-sampling.
const BLOCK: usize = 8;
/// Texels: how near a triangle's bounds must come to a point or texel before its footprint is
/// tested against it ([`TexelMap::near`]).
const NEAR: f64 = 1.0 / 256.0;

/// Largest sub-sampling factor per texel side (64 x 64 samples).
pub const MAX_SUBSAMPLES: u32 = 64;

/// The surface point a texel (or a sub-texel sample) stands for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TexelSample {
    /// Triangle index in the mesh.
    pub tri: u32,
    /// Barycentric weights of the triangle's vertices 1 and 2 (as [`Mesh::shading_normal`]).
    pub b1: f32,
    pub b2: f32,
    /// World position.
    pub position: Vec3,
    /// Unit shading normal.
    pub normal: Vec3,
    /// World area (scene units^2) this sample stands for: one texel's worth on its triangle,
    /// or `1 / k^2` of it for a `k x k` sub-sample.
    pub area: f32,
}

/// Signed double area of `(a, b, p)`: positive when `p` is left of `a -> b` (y up).
#[inline]
fn orient(a: DVec2, b: DVec2, p: DVec2) -> f64 {
    (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x)
}

/// [`orient`] computed from the smaller endpoint, so `edge(a, b, p) == -edge(b, a, p)`
/// exactly: two triangles sharing an edge never both (or neither) claim a point on it.
#[inline]
fn edge(a: DVec2, b: DVec2, p: DVec2) -> f64 {
    if (a.x, a.y) <= (b.x, b.y) {
        orient(a, b, p)
    } else {
        -orient(b, a, p)
    }
}

/// A triangle's footprint in texel space.
#[derive(Clone, Copy)]
struct Footprint {
    /// Corners in mesh order.
    v: [DVec2; 3],
    /// Corners reordered to positive orientation.
    o: [DVec2; 3],
    /// Signed double area of `v`.
    area2: f64,
}

impl Footprint {
    /// Whether `p` is inside (with the shared-edge tie rule).
    #[inline]
    fn contains(&self, p: DVec2) -> bool {
        for i in 0..3 {
            let (a, b) = (self.o[i], self.o[(i + 1) % 3]);
            let e = edge(a, b, p);
            if e < 0.0 {
                return false;
            }
            if e == 0.0 {
                let d = b - a;
                if !(d.y > 0.0 || (d.y == 0.0 && d.x < 0.0)) {
                    return false;
                }
            }
        }
        true
    }

    /// Barycentric weights of vertices 1 and 2 at `p`, clamped into the triangle.
    fn barycentrics(&self, p: DVec2) -> (f64, f64) {
        let [v0, v1, v2] = self.v;
        let b1 = (orient(v2, v0, p) / self.area2).clamp(0.0, 1.0);
        let b2 = (orient(v0, v1, p) / self.area2).clamp(0.0, 1.0 - b1);
        (b1, b2)
    }

    /// Rows whose centers may be inside, clamped to `0..height`.
    fn rows(&self, height: usize) -> Option<Range<usize>> {
        let lo = self.v.iter().map(|v| v.y).fold(f64::INFINITY, f64::min);
        let hi = self.v.iter().map(|v| v.y).fold(f64::NEG_INFINITY, f64::max);
        span(lo, hi, height)
    }

    fn cols(&self, width: usize) -> Option<Range<usize>> {
        let lo = self.v.iter().map(|v| v.x).fold(f64::INFINITY, f64::min);
        let hi = self.v.iter().map(|v| v.x).fold(f64::NEG_INFINITY, f64::max);
        span(lo, hi, width)
    }
}

/// Texel indices whose centers `i + 0.5` lie in `[lo, hi]`, within `0..n`.
fn span(lo: f64, hi: f64, n: usize) -> Option<Range<usize>> {
    let a = (lo - 0.5).ceil().max(0.0);
    let b = ((hi - 0.5).floor() + 1.0).min(n as f64);
    (a < b).then_some(a as usize..b as usize)
}

/// The footprint of triangle `t`, if it can hold texels: finite corners, positive UV area
/// and positive world area.
fn footprint(mesh: &Mesh, atlas: &ShapeAtlas, t: usize) -> Option<Footprint> {
    let v = atlas.corner_uv.get(t)?.map(|c| c.as_dvec2());
    if !v.iter().all(|c| c.is_finite()) {
        return None;
    }
    let area2 = orient(v[0], v[1], v[2]);
    let world_ok = mesh
        .triangles
        .get(t)
        .is_some_and(|tri| tri.iter().all(|&i| (i as usize) < mesh.positions.len()))
        && mesh.triangle_area(t) > 0.0;
    if area2.is_nan() || area2.abs() <= 1e-12 || !world_ok {
        return None;
    }
    let o = if area2 > 0.0 { v } else { [v[0], v[2], v[1]] };
    Some(Footprint { v, o, area2 })
}

/// Triangles listed per bucket (row bands or texel blocks), in ascending triangle order.
struct Buckets {
    start: Vec<usize>,
    tris: Vec<u32>,
}

impl Buckets {
    /// `cells(t)` lists the buckets triangle `t` touches.
    fn build<I: Iterator<Item = usize>>(
        n: usize,
        tris: usize,
        cells: impl Fn(usize) -> Option<I>,
    ) -> Self {
        let mut start = vec![0usize; n + 1];
        for t in 0..tris {
            if let Some(it) = cells(t) {
                it.for_each(|c| start[c + 1] += 1);
            }
        }
        for i in 0..n {
            start[i + 1] += start[i];
        }
        let mut cursor = start.clone();
        let mut list = vec![0u32; start[n]];
        for t in 0..tris {
            if let Some(it) = cells(t) {
                for c in it {
                    list[cursor[c]] = t as u32;
                    cursor[c] += 1;
                }
            }
        }
        Buckets { start, tris: list }
    }

    fn get(&self, i: usize) -> &[u32] {
        &self.tris[self.start[i]..self.start[i + 1]]
    }
}

/// The texel -> triangle map of one atlas, with what is needed to sample it. It holds no
/// per-texel array: owners are rasterized a band of rows at a time ([`TexelMap::sample_rows`])
/// or looked up one texel at a time through a per-block triangle index
/// ([`TexelMap::owner`]), so a map of an 8192 x 8192 atlas costs its triangle lists, not
/// 256 MB of owners.
pub struct TexelMap<'a> {
    mesh: &'a Mesh,
    atlas: &'a ShapeAtlas,
    /// Triangles per band of [`BAND`] rows, ascending.
    by_band: Buckets,
    /// (covered texels, extra claims), counted over every band on first use.
    counts: OnceLock<(usize, u64)>,
    /// Per triangle, its chart (UV island) or [`NONE`].
    chart: Vec<u32>,
    charts: u32,
    /// Triangles per `BLOCK x BLOCK` texel block, built on first point query.
    blocks: OnceLock<Buckets>,
}

impl<'a> TexelMap<'a> {
    /// Indexes the triangles of `atlas` (made for `mesh`) by row band and finds its charts.
    pub fn new(mesh: &'a Mesh, atlas: &'a ShapeAtlas) -> Self {
        let (w, h) = (atlas.width as usize, atlas.height as usize);
        let ntri = atlas.corner_uv.len().min(mesh.triangles.len());
        let bands = h.div_ceil(BAND);
        let by_band = Buckets::build(bands, ntri, |t| {
            let f = footprint(mesh, atlas, t)?;
            f.cols(w)?;
            let r = f.rows(h)?;
            Some(r.start / BAND..(r.end - 1) / BAND + 1)
        });
        let (chart, charts) = uv_islands(mesh, atlas, ntri);
        TexelMap {
            mesh,
            atlas,
            by_band,
            counts: OnceLock::new(),
            chart,
            charts,
            blocks: OnceLock::new(),
        }
    }

    /// The owners of band `b`'s rows (row-major, `BAND` rows or fewer at the bottom) and the
    /// extra claims of overlapping triangles there. The lowest triangle index wins.
    fn band_owners(&self, b: usize) -> (Vec<u32>, u64) {
        let (w, h) = (self.atlas.width as usize, self.atlas.height as usize);
        let y0 = b * BAND;
        let rows = BAND.min(h.saturating_sub(y0));
        let mut chunk = vec![NONE; rows * w];
        let mut extra = 0u64;
        for &t in self.by_band.get(b) {
            let Some(f) = footprint(self.mesh, self.atlas, t as usize) else {
                continue;
            };
            let (Some(rs), Some(cols)) = (f.rows(h), f.cols(w)) else {
                continue;
            };
            for y in rs.start.max(y0)..rs.end.min(y0 + rows) {
                let py = y as f64 + 0.5;
                let row = &mut chunk[(y - y0) * w..(y - y0 + 1) * w];
                for x in cols.clone() {
                    if f.contains(DVec2::new(x as f64 + 0.5, py)) {
                        if row[x] == NONE {
                            row[x] = t;
                        } else {
                            extra += 1;
                        }
                    }
                }
            }
        }
        (chunk, extra)
    }

    fn counts(&self) -> (usize, u64) {
        *self.counts.get_or_init(|| {
            let bands = (self.atlas.height as usize).div_ceil(BAND);
            if self.atlas.width == 0 {
                return (0, 0);
            }
            (0..bands)
                .into_par_iter()
                .map(|b| {
                    let (o, extra) = self.band_owners(b);
                    (o.iter().filter(|&&t| t != NONE).count(), extra)
                })
                .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1))
        })
    }

    pub fn width(&self) -> u32 {
        self.atlas.width
    }

    /// The mesh this map was made for.
    pub fn mesh(&self) -> &'a Mesh {
        self.mesh
    }

    pub fn height(&self) -> u32 {
        self.atlas.height
    }

    /// The triangle owning texel `(x, y)`, if any: the lowest-index triangle of its block
    /// whose footprint contains the texel's center (as the band rasterizer decides).
    pub fn owner(&self, x: u32, y: u32) -> Option<u32> {
        if x >= self.atlas.width || y >= self.atlas.height {
            return None;
        }
        let bw = (self.atlas.width as usize).div_ceil(BLOCK);
        let p = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
        self.blocks()
            .get(y as usize / BLOCK * bw + x as usize / BLOCK)
            .iter()
            .copied()
            .filter(|&t| self.near(t, p, p))
            .find(|&t| footprint(self.mesh, self.atlas, t as usize).is_some_and(|f| f.contains(p)))
    }

    /// Whether triangle `t`'s texel-space bounds come within [`NEAR`] of the box `lo..=hi`.
    /// One that does not holds no point of the box (its edge tests err by far less than
    /// `NEAR`), so its footprint is not made: a block of a finely tessellated shape lists
    /// hundreds of triangles, of which a texel meets a few.
    fn near(&self, t: u32, lo: DVec2, hi: DVec2) -> bool {
        let Some(c) = self.atlas.corner_uv.get(t as usize) else {
            return false;
        };
        let (mn, mx) = (c[0].min(c[1]).min(c[2]), c[0].max(c[1]).max(c[2]));
        let (mn, mx) = (mn.as_dvec2(), mx.as_dvec2());
        !(mn.x > hi.x + NEAR || mn.y > hi.y + NEAR || mx.x < lo.x - NEAR || mx.y < lo.y - NEAR)
    }

    /// Per texel (row-major), whether it maps to the surface (a whole-texture array: for
    /// tests and small atlases).
    pub fn covered_mask(&self) -> Vec<bool> {
        let bands = (self.atlas.height as usize).div_ceil(BAND);
        (0..bands)
            .into_par_iter()
            .flat_map_iter(|b| self.band_owners(b).0.into_iter().map(|o| o != NONE))
            .collect()
    }

    /// Number of texels that map to the surface.
    pub fn covered(&self) -> usize {
        self.counts().0
    }

    /// Extra claims on texel centers by overlapping triangles (0 for a valid atlas).
    pub fn overlapped(&self) -> u64 {
        self.counts().1
    }

    /// Number of UV islands (triangles connected through edges with identical corners).
    pub fn chart_count(&self) -> u32 {
        self.charts
    }

    /// The UV island of triangle `t`, if it has texel-space area.
    pub fn chart_of(&self, t: u32) -> Option<u32> {
        self.chart.get(t as usize).copied().filter(|&c| c != NONE)
    }

    /// The surface point at texel-space point `p` of triangle `t`, standing for
    /// `area_fraction` of a texel.
    fn sample_at(&self, t: u32, f: &Footprint, p: DVec2, area_fraction: f64) -> TexelSample {
        let (b1, b2) = f.barycentrics(p);
        let (b1, b2) = (b1 as f32, b2 as f32);
        let [p0, p1, p2] = self.mesh.triangle(t as usize);
        let per_texel = self.mesh.triangle_area(t as usize) as f64 / (0.5 * f.area2.abs());
        TexelSample {
            tri: t,
            b1,
            b2,
            position: p0 * (1.0 - b1 - b2) + p1 * b1 + p2 * b2,
            normal: self.mesh.shading_normal(t as usize, b1, b2),
            area: (per_texel * area_fraction) as f32,
        }
    }

    /// The surface point at the center of texel `(x, y)`, or `None` for a gutter texel.
    pub fn sample(&self, x: u32, y: u32) -> Option<TexelSample> {
        self.sample_owned(self.owner(x, y)?, x, y)
    }

    /// [`TexelMap::sample`] for every texel of rows `rows` (row-major), in parallel.
    /// The owners come from rasterizing the bands the rows fall in.
    pub fn sample_rows(&self, rows: Range<u32>) -> Vec<Option<TexelSample>> {
        let w = self.atlas.width as usize;
        let rows =
            rows.start.min(self.atlas.height) as usize..rows.end.min(self.atlas.height) as usize;
        if rows.is_empty() || w == 0 {
            return Vec::new();
        }
        let bands = rows.start / BAND..(rows.end - 1) / BAND + 1;
        bands
            .into_par_iter()
            .flat_map_iter(|b| {
                let owners = self.band_owners(b).0;
                let y0 = b * BAND;
                let ys = y0.max(rows.start)..(y0 + BAND).min(rows.end);
                let out: Vec<Option<TexelSample>> = ys
                    .flat_map(|y| (0..w).map(move |x| (x, y)))
                    .map(|(x, y)| {
                        let t = owners[(y - y0) * w + x];
                        (t != NONE)
                            .then(|| self.sample_owned(t, x as u32, y as u32))
                            .flatten()
                    })
                    .collect();
                out
            })
            .collect()
    }

    /// The sample at the center of texel `(x, y)`, owned by triangle `t`.
    fn sample_owned(&self, t: u32, x: u32, y: u32) -> Option<TexelSample> {
        let f = footprint(self.mesh, self.atlas, t as usize)?;
        let p = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
        Some(self.sample_at(t, &f, p, 1.0))
    }

    fn blocks(&self) -> &Buckets {
        self.blocks.get_or_init(|| {
            let (w, h) = (self.atlas.width as usize, self.atlas.height as usize);
            let (bw, bh) = (w.div_ceil(BLOCK), h.div_ceil(BLOCK));
            let ntri = self.chart.len();
            Buckets::build(bw * bh, ntri, |t| {
                let f = footprint(self.mesh, self.atlas, t)?;
                let lo = f.v[0].min(f.v[1]).min(f.v[2]);
                let hi = f.v[0].max(f.v[1]).max(f.v[2]);
                let cell = |v: f64, n: usize| (v.max(0.0) as usize / BLOCK).min(n - 1);
                if hi.x < 0.0 || hi.y < 0.0 || lo.x > w as f64 || lo.y > h as f64 {
                    return None;
                }
                let (x0, x1) = (cell(lo.x, bw), cell(hi.x, bw));
                let (y0, y1) = (cell(lo.y, bh), cell(hi.y, bh));
                Some((y0..=y1).flat_map(move |by| (x0..=x1).map(move |bx| by * bw + bx)))
            })
        })
    }

    /// `k x k` sub-samples of texel `(x, y)` at `(x + (i + 0.5) / k, y + (j + 0.5) / k)`,
    /// keeping those inside a triangle of the chart that owns the texel's center, row by
    /// row. Empty for a gutter texel or `k = 0`; `k` is capped at [`MAX_SUBSAMPLES`]. Each
    /// stands for `1 / k^2` of the texel's world area on its triangle.
    pub fn subsamples(&self, x: u32, y: u32, k: u32) -> Vec<TexelSample> {
        let k = k.min(MAX_SUBSAMPLES);
        let Some(owner) = self.owner(x, y) else {
            return Vec::new();
        };
        let Some(chart) = self.chart_of(owner) else {
            return Vec::new();
        };
        let blocks = self.blocks();
        let bw = (self.atlas.width as usize).div_ceil(BLOCK);
        let (lo, hi) = (
            DVec2::new(x as f64, y as f64),
            DVec2::new(x as f64 + 1.0, y as f64 + 1.0),
        );
        let cands: Vec<(u32, Footprint)> = std::iter::once(owner)
            .chain(
                blocks
                    .get(y as usize / BLOCK * bw + x as usize / BLOCK)
                    .iter()
                    .copied()
                    .filter(|&t| t != owner && self.chart[t as usize] == chart)
                    .filter(|&t| self.near(t, lo, hi)),
            )
            .filter_map(|t| Some((t, footprint(self.mesh, self.atlas, t as usize)?)))
            .collect();
        let frac = 1.0 / (k as f64 * k as f64);
        let mut out = Vec::with_capacity((k * k) as usize);
        for j in 0..k {
            for i in 0..k {
                let p = DVec2::new(
                    x as f64 + (i as f64 + 0.5) / k as f64,
                    y as f64 + (j as f64 + 0.5) / k as f64,
                );
                if let Some((t, f)) = cands.iter().find(|(_, f)| f.contains(p)) {
                    out.push(self.sample_at(*t, f, p, frac));
                }
            }
        }
        out
    }
}

/// Connected components of triangles with a footprint, joined through edges whose two
/// texel-space endpoints are bit-identical. Ids are numbered by lowest triangle.
fn uv_islands(mesh: &Mesh, atlas: &ShapeAtlas, ntri: usize) -> (Vec<u32>, u32) {
    let key = |v: glam::Vec2| {
        // +0.0 folds -0.0 into 0.0.
        ((v.x + 0.0).to_bits() as u64) << 32 | (v.y + 0.0).to_bits() as u64
    };
    let valid: Vec<bool> = (0..ntri)
        .into_par_iter()
        .map(|t| footprint(mesh, atlas, t).is_some())
        .collect();
    let mut edges: Vec<(u64, u64, u32)> = Vec::with_capacity(3 * ntri);
    for t in (0..ntri).filter(|&t| valid[t]) {
        let c = atlas.corner_uv[t];
        for i in 0..3 {
            let (a, b) = (key(c[i]), key(c[(i + 1) % 3]));
            edges.push((a.min(b), a.max(b), t as u32));
        }
    }
    edges.par_sort_unstable();
    let mut parent: Vec<u32> = (0..ntri as u32).collect();
    fn find(p: &mut [u32], mut i: u32) -> u32 {
        while p[i as usize] != i {
            p[i as usize] = p[p[i as usize] as usize];
            i = p[i as usize];
        }
        i
    }
    for pair in edges.windows(2) {
        if (pair[0].0, pair[0].1) == (pair[1].0, pair[1].1) {
            let (a, b) = (find(&mut parent, pair[0].2), find(&mut parent, pair[1].2));
            if a != b {
                let (lo, hi) = (a.min(b), a.max(b));
                parent[hi as usize] = lo;
            }
        }
    }
    let mut id = vec![NONE; ntri];
    let mut chart = vec![NONE; ntri];
    let mut n = 0u32;
    for t in 0..ntri {
        if !valid[t] {
            continue;
        }
        let r = find(&mut parent, t as u32) as usize;
        if id[r] == NONE {
            id[r] = n;
            n += 1;
        }
        chart[t] = id[r];
    }
    (chart, n)
}

/// Every texel of `atlas` (row-major, `width * height`): the surface point at its center, or
/// `None` for gutter. That is 44 bytes per texel (about 3 GB at 8192 x 8192): for big
/// atlases keep a [`TexelMap`] (4 bytes per texel) and call [`TexelMap::sample_rows`] per
/// tile.
pub fn rasterize(mesh: &Mesh, atlas: &ShapeAtlas) -> Vec<Option<TexelSample>> {
    TexelMap::new(mesh, atlas).sample_rows(0..atlas.height)
}

/// [`TexelMap::subsamples`] for one texel. Builds the whole map: for more than one texel,
/// build a [`TexelMap`] once.
pub fn texel_subsamples(
    mesh: &Mesh,
    atlas: &ShapeAtlas,
    x: u32,
    y: u32,
    k: u32,
) -> Vec<TexelSample> {
    TexelMap::new(mesh, atlas).subsamples(x, y, k)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atlas::texture::dilate;
    use crate::atlas::uv::testutil::*;
    use crate::atlas::uv::{build_atlas, AtlasSettings};
    use glam::Vec2;

    fn settings(tpu: f32) -> AtlasSettings {
        AtlasSettings {
            texels_per_unit: tpu,
            ..Default::default()
        }
    }

    /// The cbox meshes at 64 texels/unit and a bumpy sphere at 48, unwrapped.
    fn cases() -> Vec<(String, Mesh, ShapeAtlas)> {
        let mut v: Vec<(String, Mesh, f32)> =
            all_cbox().into_iter().map(|(n, m)| (n, m, 64.0)).collect();
        v.push(("sphere".into(), bumpy_sphere(48, 24), 48.0));
        v.into_iter()
            .map(|(n, m, tpu)| {
                let a = build_atlas(&m, &settings(tpu)).unwrap();
                (n, m, a)
            })
            .collect()
    }

    #[test]
    fn texels_of_a_density_level_are_4_to_the_level_times_as_large() {
        // the bumpy sphere's triangles at levels 0..=3 in four wedges of equal area: every
        // texel's area is 4^level times the nominal 1 / density^2 of its triangle's level,
        // and the texels still cover the surface once
        let mesh = bumpy_sphere(48, 24);
        let n = mesh.triangles.len();
        let levels: Vec<u8> = (0..n).map(|t| (4 * t / n) as u8).collect();
        let a = crate::atlas::uv::build_atlas_with_progress(
            &mesh,
            &settings(48.0),
            &levels,
            |_, _, _| true,
        )
        .unwrap();
        assert_eq!((a.levels, a.texel_density), (3, 48.0));
        assert_eq!(a.coarsest_density(), 6.0);
        // each triangle's level reads back from its texel and surface areas
        for (t, &l) in levels.iter().enumerate() {
            assert_eq!(a.triangle_level(&mesh, t), l, "triangle {t}");
        }
        let samples = rasterize(&mesh, &a);
        let mut ratio = [(f64::INFINITY, 0.0f64, 0usize); 4];
        let mut sum = 0.0;
        for s in samples.iter().flatten() {
            let l = levels[s.tri as usize] as usize;
            let want = 4f64.powi(l as i32) / 48f64.powi(2);
            let r = s.area as f64 / want;
            ratio[l] = (ratio[l].0.min(r), ratio[l].1.max(r), ratio[l].2 + 1);
            sum += s.area as f64;
        }
        assert!((sum / mesh.area() - 1.0).abs() < 0.03, "{sum}");
        for (l, (lo, hi, count)) in ratio.iter().enumerate() {
            assert!(*count > 0, "level {l} has no texel");
            assert!(*lo > 0.8 && *hi < 1.25, "level {l}: {lo}..{hi}");
        }
        // a quarter of the surface at each level: each coarser level has about 1/4 the
        // texels of the one before
        for l in 1..4 {
            let q = ratio[l].2 as f64 / ratio[l - 1].2 as f64;
            assert!((0.15..0.4).contains(&q), "level {l}: {q}");
        }
    }

    #[test]
    fn texel_areas_add_up_to_the_surface_and_match_the_density() {
        for (name, mesh, atlas) in cases() {
            let samples = rasterize(&mesh, &atlas);
            assert_eq!(samples.len(), atlas.texel_count());
            let covered: Vec<&TexelSample> = samples.iter().flatten().collect();
            let sum: f64 = covered.iter().map(|s| s.area as f64).sum();
            let area = mesh.area();
            assert!(
                (sum / area - 1.0).abs() < 0.03,
                "{name}: texels cover {sum}, surface is {area}"
            );
            // Every texel is about 1/density on a side.
            let want = 1.0 / (atlas.texel_density as f64).powi(2);
            let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
            for s in &covered {
                let r = s.area as f64 / want;
                (lo, hi) = (lo.min(r), hi.max(r));
            }
            assert!(
                lo > 0.8 && hi < 1.25,
                "{name}: texel area ratios {lo}..{hi}"
            );
            println!(
                "{name}: {}x{} atlas, {} charts, fill {:.1}%, texel area {lo:.3}..{hi:.3} x nominal",
                atlas.width,
                atlas.height,
                atlas.charts,
                100.0 * covered.len() as f64 / samples.len() as f64
            );
        }
    }

    #[test]
    fn samples_lie_on_their_triangles() {
        for (name, mesh, atlas) in cases() {
            let map = TexelMap::new(&mesh, &atlas);
            for y in 0..atlas.height {
                for x in 0..atlas.width {
                    let Some(s) = map.sample(x, y) else { continue };
                    let t = s.tri as usize;
                    let (b1, b2) = (s.b1, s.b2);
                    assert!(b1 >= 0.0 && b2 >= 0.0 && b1 + b2 <= 1.0 + 1e-6, "{name}");
                    // The barycentrics reproduce the texel center in the atlas...
                    let [u0, u1, u2] = atlas.corner_uv[t];
                    let uv = u0 * (1.0 - b1 - b2) + u1 * b1 + u2 * b2;
                    let center = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
                    assert!(uv.distance(center) < 1e-3, "{name}: {uv} vs {center}");
                    // ...and the position, which lies in the triangle's plane.
                    let [p0, p1, p2] = mesh.triangle(t);
                    let p = p0 + (p1 - p0) * b1 + (p2 - p0) * b2;
                    assert!(p.distance(s.position) < 1e-5, "{name}");
                    let n = mesh.face_normal_raw(t).normalize();
                    assert!((s.position - p0).dot(n).abs() < 1e-5, "{name}");
                    assert!((s.normal.length() - 1.0).abs() < 1e-5, "{name}");
                    assert!(s.normal.dot(n) > 0.5, "{name}: shading normal");
                }
            }
        }
    }

    /// Brute force over all triangles: how many strictly contain `p` (no tie rule), and
    /// which contain it with the tie rule.
    fn brute(mesh: &Mesh, atlas: &ShapeAtlas, p: DVec2) -> (usize, Vec<u32>) {
        let mut strict = 0;
        let mut owners = Vec::new();
        for t in 0..atlas.corner_uv.len() {
            let Some(f) = footprint(mesh, atlas, t) else {
                continue;
            };
            let inside = (0..3).all(|i| orient(f.o[i], f.o[(i + 1) % 3], p) > 1e-9);
            strict += inside as usize;
            if f.contains(p) {
                owners.push(t as u32);
            }
        }
        (strict, owners)
    }

    #[test]
    fn every_center_has_at_most_one_triangle_brute_force() {
        for (name, mesh, atlas) in cases() {
            if atlas.texel_count() > 200_000 {
                continue; // brute force is quadratic; the big ones are covered elsewhere
            }
            let map = TexelMap::new(&mesh, &atlas);
            assert_eq!(map.overlapped(), 0, "{name}");
            for y in 0..atlas.height {
                for x in 0..atlas.width {
                    let p = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
                    let (strict, owners) = brute(&mesh, &atlas, p);
                    assert!(strict <= 1, "{name}: charts overlap at ({x}, {y})");
                    assert!(owners.len() <= 1, "{name}: ({x}, {y}) owned by {owners:?}");
                    assert_eq!(map.owner(x, y), owners.first().copied(), "{name}");
                }
            }
        }
    }

    #[test]
    fn shared_edges_and_vertices_on_centers_are_owned_once() {
        // A 4x4 texel square cut along the diagonal through texel centers, and a fan of six
        // triangles around the center of texel (2, 2): every center exactly once.
        let square = [(0.0, 0.0), (4.0, 0.0), (4.0, 4.0), (0.0, 4.0)];
        let c = (2.5, 2.5);
        let fan: Vec<(f32, f32)> = (0..6)
            .map(|i| {
                let a = i as f32 * std::f32::consts::TAU / 6.0;
                (c.0 + 1.7 * a.cos(), c.1 + 1.7 * a.sin())
            })
            .collect();
        let mut layouts = vec![(square.to_vec(), vec![[0, 1, 2], [0, 2, 3]], 6 * 6)];
        let mut fan_pts = fan.clone();
        fan_pts.push(c);
        layouts.push((fan_pts, (0..6).map(|i| [6, i, (i + 1) % 6]).collect(), 0));
        for (pts, tris, _) in &layouts {
            let mesh = Mesh {
                positions: pts.iter().map(|&(x, y)| Vec3::new(x, y, 0.0)).collect(),
                triangles: tris.clone(),
                ..Default::default()
            };
            let atlas = ShapeAtlas {
                width: 6,
                height: 6,
                corner_uv: tris
                    .iter()
                    .map(|t| t.map(|i| Vec2::new(pts[i as usize].0, pts[i as usize].1)))
                    .collect(),
                charts: 1,
                texel_density: 1.0,
                levels: 0,
            };
            let map = TexelMap::new(&mesh, &atlas);
            assert_eq!(map.overlapped(), 0);
            assert_eq!(map.chart_count(), 1);
            for y in 0..6 {
                for x in 0..6 {
                    let p = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
                    let (_, owners) = brute(&mesh, &atlas, p);
                    assert!(owners.len() <= 1, "({x}, {y}): {owners:?}");
                    assert_eq!(map.owner(x, y), owners.first().copied());
                }
            }
            assert!(
                map.owner(2, 2).is_some(),
                "the shared vertex/diagonal center"
            );
        }
        // The square: all 16 centers inside, 4 of them on the diagonal.
        let mesh = Mesh {
            positions: square.iter().map(|&(x, y)| Vec3::new(x, y, 0.0)).collect(),
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            ..Default::default()
        };
        let atlas = ShapeAtlas {
            width: 6,
            height: 6,
            corner_uv: mesh
                .triangles
                .iter()
                .map(|t| t.map(|i| mesh.positions[i as usize].truncate()))
                .collect(),
            charts: 1,
            texel_density: 1.0,
            levels: 0,
        };
        assert_eq!(TexelMap::new(&mesh, &atlas).covered(), 16);
    }

    #[test]
    fn charts_keep_their_padding() {
        for (name, mesh, atlas) in cases() {
            let map = TexelMap::new(&mesh, &atlas);
            let pad = settings(1.0).padding as i64;
            let (w, h) = (atlas.width as i64, atlas.height as i64);
            let chart =
                |x: i64, y: i64| map.owner(x as u32, y as u32).and_then(|t| map.chart_of(t));
            let mut checked = 0;
            for y in 0..h {
                for x in 0..w {
                    let Some(c) = chart(x, y) else { continue };
                    for ny in (y - pad).max(0)..(y + pad + 1).min(h) {
                        for nx in (x - pad).max(0)..(x + pad + 1).min(w) {
                            let other = chart(nx, ny);
                            assert!(
                                other.is_none() || other == Some(c),
                                "{name}: chart {c} at ({x}, {y}) next to {other:?} at ({nx}, {ny})"
                            );
                            checked += 1;
                        }
                    }
                }
            }
            assert!(checked > 0, "{name}");
            assert_eq!(map.chart_count(), atlas.charts, "{name}");
        }
    }

    #[test]
    fn same_bits_on_one_and_two_threads() {
        let meshes = [
            bumpy_sphere(64, 32),
            fixture("cbox", "tall_box"),
            fixture("cbox-tex", "floor"),
        ];
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let mut bytes: Vec<u32> = Vec::new();
                for m in &meshes {
                    let a = build_atlas(m, &settings(40.0)).unwrap();
                    bytes.extend([a.width, a.height, a.charts, a.texel_density.to_bits()]);
                    bytes.extend(
                        a.corner_uv
                            .iter()
                            .flatten()
                            .flat_map(|p| p.to_array().map(f32::to_bits)),
                    );
                    for s in rasterize(m, &a) {
                        match s {
                            None => bytes.push(u32::MAX),
                            Some(s) => {
                                bytes.extend([
                                    s.tri,
                                    s.b1.to_bits(),
                                    s.b2.to_bits(),
                                    s.area.to_bits(),
                                ]);
                                bytes.extend(s.position.to_array().map(f32::to_bits));
                                bytes.extend(s.normal.to_array().map(f32::to_bits));
                            }
                        }
                    }
                    let map = TexelMap::new(m, &a);
                    for (x, y) in [(a.width / 2, a.height / 2), (3, 3), (7, 9)] {
                        for s in map.subsamples(x, y, 3) {
                            bytes.extend([s.tri, s.b1.to_bits(), s.b2.to_bits()]);
                        }
                    }
                }
                bytes
            })
        };
        let one = run(1);
        assert!(one.len() > 100_000);
        assert_eq!(one, run(2));
        assert_eq!(one, run(2));
    }

    /// The owner and sub-samples of texel `(x, y)` by brute force: every triangle of the
    /// mesh tried in order, none skipped by its bounds or a block.
    fn brute_texel(map: &TexelMap, x: u32, y: u32, k: u32) -> (Option<u32>, Vec<TexelSample>) {
        let ntri = map.mesh.triangles.len();
        let fp = |t: usize| footprint(map.mesh, map.atlas, t);
        let p = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
        let owner = (0..ntri).find(|&t| fp(t).is_some_and(|f| f.contains(p)));
        let Some(owner) = owner.map(|t| t as u32) else {
            return (None, Vec::new());
        };
        let chart = map.chart_of(owner);
        let cands: Vec<(u32, Footprint)> = std::iter::once(owner as usize)
            .chain((0..ntri).filter(|&t| t != owner as usize))
            .filter(|&t| map.chart_of(t as u32) == chart)
            .filter_map(|t| Some((t as u32, fp(t)?)))
            .collect();
        let mut out = Vec::new();
        for j in 0..k {
            for i in 0..k {
                let (fx, fy) = ((i as f64 + 0.5) / k as f64, (j as f64 + 0.5) / k as f64);
                let p = DVec2::new(x as f64 + fx, y as f64 + fy);
                if let Some((t, f)) = cands.iter().find(|(_, f)| f.contains(p)) {
                    out.push(map.sample_at(*t, f, p, 1.0 / (k as f64 * k as f64)));
                }
            }
        }
        (Some(owner), out)
    }

    #[test]
    fn owners_and_subsamples_are_those_of_every_triangle_tried() {
        // fine triangles: a block lists many, a texel meets a few
        let mesh = bumpy_sphere(48, 24);
        let atlas = build_atlas(&mesh, &settings(6.0)).unwrap();
        let map = TexelMap::new(&mesh, &atlas);
        let key = |s: &TexelSample| (s.tri, s.b1.to_bits(), s.b2.to_bits(), s.area.to_bits());
        let (mut covered, mut shared) = (0, 0);
        for y in 0..atlas.height {
            for x in 0..atlas.width {
                let (owner, subs) = brute_texel(&map, x, y, 3);
                assert_eq!(map.owner(x, y), owner, "({x}, {y})");
                let fast = map.subsamples(x, y, 3);
                assert_eq!(fast.len(), subs.len(), "({x}, {y})");
                assert!(fast.iter().map(key).eq(subs.iter().map(key)), "({x}, {y})");
                covered += owner.is_some() as u32;
                shared += subs.iter().any(|s| Some(s.tri) != owner) as u32;
            }
        }
        assert!(covered > 100 && shared > 50, "{covered} {shared}");
    }

    #[test]
    fn subsamples_cover_the_texel_within_its_chart() {
        let mesh = bumpy_sphere(32, 16);
        let atlas = build_atlas(&mesh, &settings(24.0)).unwrap();
        let map = TexelMap::new(&mesh, &atlas);
        let (mut interior, mut partial) = (0, 0);
        for y in 0..atlas.height {
            for x in 0..atlas.width {
                let subs = map.subsamples(x, y, 4);
                let Some(center) = map.sample(x, y) else {
                    assert!(subs.is_empty());
                    continue;
                };
                let chart = map.chart_of(center.tri);
                assert!(!subs.is_empty() && subs.len() <= 16);
                for s in &subs {
                    assert_eq!(map.chart_of(s.tri), chart);
                    let [u0, u1, u2] = atlas.corner_uv[s.tri as usize];
                    let uv = u0 * (1.0 - s.b1 - s.b2) + u1 * s.b1 + u2 * s.b2;
                    let inside = uv.x >= x as f32 - 1e-3
                        && uv.x <= x as f32 + 1.0 + 1e-3
                        && uv.y >= y as f32 - 1e-3
                        && uv.y <= y as f32 + 1.0 + 1e-3;
                    assert!(inside, "sub-sample {uv} outside texel ({x}, {y})");
                }
                if subs.len() == 16 {
                    interior += 1;
                    // Full coverage: the sub-sample areas add up to about one texel's.
                    let sum: f32 = subs.iter().map(|s| s.area).sum();
                    assert!(
                        (sum / center.area - 1.0).abs() < 0.2,
                        "{sum} vs {}",
                        center.area
                    );
                } else {
                    partial += 1;
                }
            }
        }
        assert!(interior > 100 && partial > 10, "{interior} {partial}");
        // Sub-samples of every covered texel together cover the surface.
        let total: f64 = (0..atlas.height)
            .flat_map(|y| (0..atlas.width).map(move |x| (x, y)))
            .flat_map(|(x, y)| map.subsamples(x, y, 4))
            .map(|s| s.area as f64)
            .sum();
        assert!((total / mesh.area() - 1.0).abs() < 0.05, "{total}");
        assert!(map.subsamples(0, 0, 0).is_empty());
        let (cx, cy) = (0..atlas.height)
            .flat_map(|y| (0..atlas.width).map(move |x| (x, y)))
            .find(|&(x, y)| map.owner(x, y).is_some())
            .unwrap();
        assert!(map.subsamples(cx, cy, u32::MAX).len() <= 64 * 64);
        assert!(map.subsamples(atlas.width, 0, 2).is_empty());
    }

    #[test]
    fn dilation_fills_the_gutter_next_to_charts() {
        let mesh = fixture("cbox", "short_box");
        let atlas = build_atlas(&mesh, &settings(32.0)).unwrap();
        let map = TexelMap::new(&mesh, &atlas);
        let covered = map.covered_mask();
        let (w, h) = (atlas.width as usize, atlas.height as usize);
        let mut values: Vec<Vec3> = covered
            .iter()
            .map(|&c| {
                if c {
                    Vec3::new(0.25, 0.5, 1.0)
                } else {
                    Vec3::ZERO
                }
            })
            .collect();
        let grown = dilate(&mut values, &covered, atlas.width, atlas.height, 1).unwrap();
        let mut filled = 0;
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let near = (y.saturating_sub(1)..(y + 2).min(h))
                    .any(|ny| (x.saturating_sub(1)..(x + 2).min(w)).any(|nx| covered[ny * w + nx]));
                assert_eq!(grown[i], near, "({x}, {y})");
                if near {
                    assert_eq!(values[i], Vec3::new(0.25, 0.5, 1.0), "({x}, {y})");
                    filled += !covered[i] as usize;
                } else {
                    assert_eq!(values[i], Vec3::ZERO);
                }
            }
        }
        assert!(filled > 0);
        // More passes grow further; a wrong size is an error.
        let mut v2 = values.clone();
        let g2 = dilate(&mut v2, &covered, atlas.width, atlas.height, 3).unwrap();
        assert!(g2.iter().filter(|&&c| c).count() > grown.iter().filter(|&&c| c).count());
        let mut short = vec![0.0f32; 3];
        assert!(dilate(&mut short, &covered, atlas.width, atlas.height, 1).is_err());
    }

    #[test]
    fn bad_atlases_do_not_panic() {
        let mesh = fixture("cbox", "floor");
        let mut atlas = build_atlas(&mesh, &settings(8.0)).unwrap();
        atlas.corner_uv[0][1] = Vec2::new(f32::NAN, 3.0);
        atlas.corner_uv[1][2] = Vec2::new(1e30, -1e30);
        let samples = rasterize(&mesh, &atlas);
        assert_eq!(samples.len(), atlas.texel_count());
        let empty = ShapeAtlas {
            width: 0,
            height: 0,
            corner_uv: vec![],
            charts: 0,
            texel_density: 1.0,
            levels: 0,
        };
        assert!(rasterize(&mesh, &empty).is_empty());
        assert!(texel_subsamples(&mesh, &empty, 0, 0, 2).is_empty());
    }

    /// Run once in release: `cargo test --release --lib atlas::texels::tests::timing -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn timing() {
        for (segs, rings, tpu) in [(316, 159, 256.0), (1000, 501, 512.0)] {
            let mesh = bumpy_sphere(segs, rings);
            let t0 = std::time::Instant::now();
            let atlas = build_atlas(&mesh, &settings(tpu)).unwrap();
            let t1 = std::time::Instant::now();
            let map = TexelMap::new(&mesh, &atlas);
            let t2 = std::time::Instant::now();
            let samples = map.sample_rows(0..atlas.height);
            let t3 = std::time::Instant::now();
            let covered = samples.iter().flatten().count();
            let sum: f64 = samples.iter().flatten().map(|s| s.area as f64).sum();
            println!(
                "{} triangles at {tpu} texels/unit: {}x{} atlas, {} charts, fill {:.1}%, \
                 area {:.4} of {:.4}; unwrap {:.2} s, owner raster {:.2} s, samples {:.2} s",
                mesh.triangles.len(),
                atlas.width,
                atlas.height,
                atlas.charts,
                100.0 * covered as f64 / samples.len() as f64,
                sum,
                mesh.area(),
                (t1 - t0).as_secs_f64(),
                (t2 - t1).as_secs_f64(),
                (t3 - t2).as_secs_f64(),
            );
        }
    }
}
