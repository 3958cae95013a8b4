//! Secondary irradiance `E_i` gathered from the observed radiance (`[solver] method =
//! "gather"`, the default). The light arriving at a surface point from other surfaces is their
//! outgoing radiance, and wherever a photo saw a surface that radiance is in the luminance map
//! already, every bounce included (the idea of Inverse Global Illumination, Yu, Debevec, Malik
//! and Hawkins, SIGGRAPH 1999). So from a point, cosine-weighted rays: a hit on an observed
//! texel returns its observed radiance `L_orig`, a hit on an unobserved one its current
//! estimate `K_d (E_d + E_i) / pi`, a hit on an emitter, on nothing, or on the back of a
//! one-sided surface returns 0; `E_i = pi * mean`. A ray that meets a known material (mirror,
//! glass) goes on through it (`bsdf_sampling::sample`, at most [`bsdf_sampling::MAX_SPECULAR`] times) with
//! its throughput to the surface it sees there; an emitter seen through them returns 0 too:
//! that light (a caustic) is in `E_d`, from the caustic photon pass (`photon::Paths::Caustic`),
//! because a small bright light in a mirror or through glass is a rare, heavy hit for a gather
//! ray (it would blotch mirror-cbox's walls) and a point or directional one is never hit.
//! Observed surfaces need no `K_d`, so it converges in one or two passes where photon tracing
//! needs many.
//!
//! `E_i` varies slowly, so it is gathered on a coarser set of points and interpolated: each
//! texture is cut into cells of `stride x stride` texels (`stride` from the scene-unit
//! `spacing` and the shape's texel density), each chart present in a cell gets one point (its
//! observed texel nearest the cell's center, or its covered one where no photo saw any), and a
//! texel interpolates bilinearly between the points of its own chart in the four cells around
//! it. Observed first because a covered texel may be buried: the floor under a box resting on
//! it sees only the box's inside, `E_i = 0`, and a point there would pull down the `E_i` of
//! the observed texels around it (cbox's floor beside its boxes would come out 4% too
//! bright). Cells are `spacing` across, so the rays, and the noise, per unit of surface do
//! not depend on the atlas resolution. An atlas with density levels
//! (`atlas::density`) has one grid of cells per level, each `spacing` across on the charts of
//! its level, so coarser texels do not spread the points further apart.
//!
//! Rays where a photo needs them. An observed texel's `E_i` divides its photographed radiance
//! into `K_d`; an unobserved one's only feeds the light it passes on. A point none of whose
//! chart's points within [`LEAN_REACH`] cells lies on an observed texel is *lean*: no observed
//! texel reads it, through the interpolation or the points' filter, and it casts
//! `[run] unobserved_share` of the rays ([`GatherContext::lean_rays`]). Observed texels gather
//! exactly what they would with every point at full rays.
//!
//! Radiance at a hit is read bilinearly from the hit texel's neighbourhood, using only texels
//! of the hit triangle's chart (so light never leaks across a chart seam or the gutter).
//!
//! Each point's `E_i` is a Monte Carlo estimate with a known variance (`pair_variance`), and
//! where a face is lit only by interreflection that noise is the texels' `K_d` noise, in
//! blotches a cell wide. So before the interpolation the points are filtered
//! ([`GatherPoints::filtered`]): each becomes the value at its place of the plane fitted
//! through it and the points of its chart around it that agree with it within their noise.
//! It helps most on faces lit only by interreflection, and costs no rays: quadrupling the
//! rays instead would cost four times the gather's time and 2.7 times its peak memory.
//!
//! The rays are cast once ([`trace_points`]): what they see of observed surfaces is final,
//! and only the hits on unobserved texels are kept and re-read with each iteration's estimates
//! ([`GatherCache::evaluate`]), so iterations after the first cost lookups, not rays. Every
//! random number is `Rng::new(seed ^ tag, 0, point, 0)`: results do not depend on threads or
//! chunking, and a resumed run casts the same rays again.

use crate::atlas::context::{HitTable, Prim};
use crate::atlas::store::{flags, Layout, TexelGeom, TexelState};
use crate::atlas::store::{map_tiles, window_tiles_for_budget, TileStore};
use crate::atlas::store::{Reader, TileCache};
use crate::atlas::texture::{Scratch, SlotTexture};
use crate::atlas::uv::Charts;
use crate::atlas::uv::ShapeAtlas;
use crate::atlas::uv::NONE;
use crate::atlas::RunContext;
use crate::base::error::Result;
use crate::base::progress::Tick;
use crate::base::rng::Rng;
use crate::config::Config;
use crate::physics::accel::{offset_origin, Accel};
use crate::physics::bsdf_sampling;
use crate::scene::{luminance, Mesh, Scene};
use bytemuck::{Pod, Zeroable};
use glam::{DMat3, DVec3, Vec2, Vec3};
use rayon::prelude::*;
use std::f32::consts::{PI, TAU};
use std::path::Path;
use std::time::Instant;

/// Agreement threshold of the gather points' filter ([`GatherPoints::filtered`]), in
/// standard errors of two points' difference: 2. Larger thresholds let points across a real
/// slope or step count as agreeing, and the filter gains less over none.
pub const POINT_FILTER_Z: f32 = 2.0;

/// Mixed into the seed so gather rays never share a stream with photons or shadow rays.
const STREAM_TAG: u64 = 0x6a7e_5ca1_ab1e_0001;

/// One gather point: a covered texel standing for the chart's part of its cell.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Point {
    pub x: u32,
    pub y: u32,
    pub chart: u32,
    /// Index into `Scene::shapes` of the point's shape.
    pub shape: u32,
    pub p: Vec3,
    /// Unit shading normal (light is gathered over its hemisphere).
    pub n: Vec3,
    /// Unit geometric normal (ray origins are offset along it).
    pub ng: Vec3,
    /// No observed texel's `E_i` depends on it ([`GatherPoints::mark_lean`]): it casts
    /// [`GatherContext::lean_rays`].
    pub lean: bool,
}

/// Cells around a point (each way) within which an observed texel's `E_i` may depend on it:
/// a texel interpolates the points of the cells around it, and each of those is filtered with
/// the points of the cells around its own.
pub const LEAN_REACH: i64 = 2;

/// One slot's cells: a grid per density level of its charts, each `spacing` scene units
/// across on the charts of its level.
#[derive(Debug, Clone, PartialEq)]
struct SlotCells {
    levels: Vec<LevelCells>,
    /// Per chart of the slot, its density level (see [`ShapeAtlas::triangle_level`]).
    chart_level: Vec<u8>,
}

/// The cells of one density level of a slot.
#[derive(Debug, Clone, PartialEq)]
struct LevelCells {
    stride: u32,
    cells_x: u32,
    cells_y: u32,
    /// Per cell (row-major) the range of its points in `GatherPoints::points`:
    /// `start[c]..start[c + 1]`, one point per chart of the level present, in chart order.
    start: Vec<u32>,
}

/// A texel's geometry and its chart, for placing gather points.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, Pod, Zeroable)]
struct GeomChart {
    g: TexelGeom,
    chart: u32,
    /// 1 when a photo saw the texel (`TexelState::weight > 0`), else 0.
    observed: u32,
}

/// The gather points of every slot.
#[derive(Debug, Clone, PartialEq)]
pub struct GatherPoints {
    slots: Vec<SlotCells>,
    pub points: Vec<Point>,
}

impl GatherPoints {
    /// Points for every slot of `p`'s layout, `spacing(shape)` scene units apart (at least one
    /// texel: `stride = max(1, round(spacing * texel density))`). Each texture's geometry is
    /// read through a [`SlotTexture`] (whole if it fits in `scratch`'s budget); `tick` gets
    /// each texture's texels once its points are placed.
    pub fn new(
        p: &RunContext,
        geom: &TileStore<TexelGeom>,
        state: &TileStore<TexelState>,
        charts: &Charts,
        spacing: &dyn Fn(usize) -> f32,
        scratch: &Scratch,
        tick: Tick,
    ) -> Result<GatherPoints> {
        let mut out = GatherPoints {
            slots: Vec::with_capacity(p.layout.slots.len()),
            points: Vec::new(),
        };
        for (slot, st) in p.layout.slots.iter().enumerate() {
            let atlas = p.atlases[st.shape].as_ref();
            let sc = &charts.slots[slot];
            let chart_level = chart_levels(p.shape_ref(slot).mesh, atlas, &sc.tri_chart);
            let top = atlas.map_or(0, |a| a.levels);
            let density = atlas.map_or(1.0, |a| a.texel_density);
            let strides: Vec<u32> = (0..=top)
                .map(|k| {
                    ((spacing(st.shape) * density / f32::from(1u16 << k)).round() as u32).max(1)
                })
                .collect();
            let g = SlotTexture::read(&p.layout, slot, state, geom, scratch, "points", |s, g| {
                GeomChart {
                    g: *g,
                    chart: sc.texel(g),
                    observed: (s.weight > 0.0) as u32,
                }
            })?;
            let levels = strides
                .iter()
                .enumerate()
                .map(|(k, &s)| {
                    let of_level = |c: u32| chart_level[c as usize] as usize == k;
                    out.add_level(&g, (s, st.shape as u32), of_level)
                })
                .collect();
            g.check()?;
            out.slots.push(SlotCells {
                levels,
                chart_level,
            });
            tick(st.width as u64 * st.height as u64);
        }
        out.mark_lean();
        Ok(out)
    }

    /// Cuts one texture into cells of `s x s` texels and adds the points of the charts that
    /// `of_level` accepts.
    fn add_level(
        &mut self,
        tex: &SlotTexture<GeomChart>,
        (s, shape): (u32, u32),
        of_level: impl Fn(u32) -> bool,
    ) -> LevelCells {
        let (w, h) = (tex.grid.width, tex.grid.height);
        let (cells_x, cells_y) = (w.div_ceil(s), h.div_ceil(s));
        let mut start = Vec::with_capacity((cells_x * cells_y + 1) as usize);
        let center = (s as f32) * 0.5;
        let mut rd = tex.reader();
        for cy in 0..cells_y {
            for cx in 0..cells_x {
                start.push(self.points.len() as u32);
                // (chart, (unobserved, squared distance to the cell center), x, y) of the best
                // texel per chart
                let mut best: Vec<(u32, (u32, f32), u32, u32)> = Vec::new();
                for y in cy * s..((cy + 1) * s).min(h) {
                    for x in cx * s..((cx + 1) * s).min(w) {
                        let t = rd.get(x, y);
                        let c = t.chart;
                        if c == NONE || !t.g.covered() || !of_level(c) {
                            continue;
                        }
                        let dx = (x - cx * s) as f32 + 0.5 - center;
                        let dy = (y - cy * s) as f32 + 0.5 - center;
                        let d2 = (1 - t.observed, dx * dx + dy * dy);
                        match best.iter_mut().find(|b| b.0 == c) {
                            Some(b) if d2 < b.1 => *b = (c, d2, x, y),
                            Some(_) => {}
                            None => best.push((c, d2, x, y)),
                        }
                    }
                }
                best.sort_by_key(|b| b.0);
                for (c, (unobserved, _), x, y) in best {
                    let g = rd.get(x, y).g;
                    self.points.push(Point {
                        x,
                        y,
                        chart: c,
                        shape,
                        p: g.p(),
                        n: g.n(),
                        ng: g.ng(),
                        // on no observed texel so far; `mark_lean` looks at its neighbours
                        lean: unobserved == 1,
                    });
                }
            }
        }
        start.push(self.points.len() as u32);
        LevelCells {
            stride: s,
            cells_x,
            cells_y,
            start,
        }
    }

    /// Keeps a point lean (on an unobserved texel) only where no point of its chart within
    /// [`LEAN_REACH`] cells lies on an observed one: the texels whose `E_i` divides a photo's
    /// radiance into `K_d` then never read a lean point, through the interpolation or the
    /// points' filter.
    fn mark_lean(&mut self) {
        let mut lean = vec![false; self.points.len()];
        for cells in self.slots.iter().flat_map(|s| &s.levels) {
            for cell in 0..(cells.cells_x * cells.cells_y) as usize {
                let cx = (cell as u32 % cells.cells_x) as i64;
                let cy = (cell as u32 / cells.cells_x) as i64;
                let range = cells.start[cell] as usize..cells.start[cell + 1] as usize;
                for (l, p) in lean[range.clone()].iter_mut().zip(&self.points[range]) {
                    let r = -LEAN_REACH..=LEAN_REACH;
                    *l = r.clone().all(|dy| {
                        r.clone().all(|dx| {
                            self.point_in(cells, cx + dx, cy + dy, p.chart)
                                .is_none_or(|j| self.points[j].lean)
                        })
                    });
                }
            }
        }
        for (p, l) in self.points.iter_mut().zip(lean) {
            p.lean = l;
        }
    }

    /// Points that cast [`GatherContext::lean_rays`].
    pub fn lean_points(&self) -> usize {
        self.points.iter().filter(|p| p.lean).count()
    }

    /// Texels per cell side in slot `slot` on its charts of density level 0.
    pub fn stride(&self, slot: usize) -> u32 {
        self.slots[slot].levels[0].stride
    }

    /// The cells of `slot` that chart `chart` lies on.
    fn cells(&self, slot: usize, chart: u32) -> &LevelCells {
        let c = &self.slots[slot];
        let level = c.chart_level.get(chart as usize).copied().unwrap_or(0);
        &c.levels[level as usize]
    }

    /// The point of chart `chart` in cell `(cx, cy)` of `cells`, if any.
    fn point_in(&self, c: &LevelCells, cx: i64, cy: i64, chart: u32) -> Option<usize> {
        if cx < 0 || cy < 0 || cx >= c.cells_x as i64 || cy >= c.cells_y as i64 {
            return None;
        }
        let cell = (cy as u32 * c.cells_x + cx as u32) as usize;
        (c.start[cell]..c.start[cell + 1])
            .map(|i| i as usize)
            .find(|&i| self.points[i].chart == chart)
    }

    /// The points `E_i` at texel `(x, y)` of chart `chart` in `slot` is interpolated from,
    /// with their weights (not normalized; weight 0 for a cell with no point): bilinear
    /// between the points of its chart in the four cells around it, renormalized over the
    /// cells that have one (the texel's own cell always does, with a weight of at least 1/4).
    fn weights(&self, slot: usize, x: u32, y: u32, chart: u32) -> [(usize, f32); 4] {
        let cells = self.cells(slot, chart);
        let s = cells.stride as f32;
        let fx = (x as f32 + 0.5) / s - 0.5;
        let fy = (y as f32 + 0.5) / s - 0.5;
        let (x0, y0) = (fx.floor(), fy.floor());
        let (tx, ty) = (fx - x0, fy - y0);
        [
            (0, 0, (1.0 - tx) * (1.0 - ty)),
            (1, 0, tx * (1.0 - ty)),
            (0, 1, (1.0 - tx) * ty),
            (1, 1, tx * ty),
        ]
        .map(|(dx, dy, w)| match w > 0.0 {
            true => self
                .point_in(cells, x0 as i64 + dx, y0 as i64 + dy, chart)
                .map_or((0, 0.0), |i| (i, w)),
            false => (0, 0.0),
        })
    }

    /// `E_i` at texel `(x, y)` of chart `chart` in `slot` (see [`GatherPoints::weights`]; 0
    /// with no point around it).
    pub fn interpolate(&self, values: &[Vec3], slot: usize, x: u32, y: u32, chart: u32) -> Vec3 {
        let (mut sum, mut wsum) = (Vec3::ZERO, 0.0f32);
        for (i, w) in self.weights(slot, x, y, chart) {
            if w > 0.0 {
                sum += values[i] * w;
                wsum += w;
            }
        }
        if wsum > 0.0 {
            sum / wsum
        } else {
            Vec3::ZERO
        }
    }

    /// Every point's `E_i` (`values`) and the variance of its luminance (`var`, in `x`) after
    /// the points' filter: each point becomes the value at its own place of the plane fitted
    /// (least squares, in texel coordinates) through it and the points of its chart in the
    /// eight cells around its own whose luminance agrees with its own within `z` standard
    /// errors of the difference (`sqrt(var_i + var_j)`); its variance becomes the fit's,
    /// `sum a_j^2 var_j` (`a_j` the weights of the intercept). A plane, not a mean, so that the
    /// slow slopes of `E_i` (towards a corner, away from a light) come through as they are, at a
    /// chart's border too; a step larger than the noise (a contact, the edge of a penumbra of
    /// indirect light) keeps its sides apart. Points with fewer than three agreeing points
    /// around them, or all on a line, are left as they are. `z <= 0` leaves every point.
    pub fn filtered(&self, values: &[Vec3], var: &[Vec3], z: f32) -> (Vec<Vec3>, Vec<Vec3>) {
        let (mut out, mut out_var) = (values.to_vec(), var.to_vec());
        if z <= 0.0 {
            return (out, out_var);
        }
        let mut near = Vec::with_capacity(9);
        for cells in self.slots.iter().flat_map(|s| &s.levels) {
            for cell in 0..(cells.cells_x * cells.cells_y) as usize {
                let (cx, cy) = (
                    (cell as u32 % cells.cells_x) as i64,
                    (cell as u32 / cells.cells_x) as i64,
                );
                for i in cells.start[cell] as usize..cells.start[cell + 1] as usize {
                    let (pi, yi) = (&self.points[i], luminance(values[i]));
                    near.clear();
                    for (dx, dy) in (-1..=1).flat_map(|dy| (-1..=1).map(move |dx| (dx, dy))) {
                        let Some(j) = self.point_in(cells, cx + dx, cy + dy, pi.chart) else {
                            continue;
                        };
                        let tol = z * (var[i].x + var[j].x).max(0.0).sqrt();
                        if (luminance(values[j]) - yi).abs() <= tol {
                            let pj = &self.points[j];
                            near.push((j, pj.x as f64 - pi.x as f64, pj.y as f64 - pi.y as f64));
                        }
                    }
                    if let Some(a) = intercept_weights(&near) {
                        out[i] = near
                            .iter()
                            .zip(&a)
                            .map(|(&(j, _, _), &w)| values[j] * w as f32)
                            .sum::<Vec3>()
                            .max(Vec3::ZERO);
                        let v: f64 = near
                            .iter()
                            .zip(&a)
                            .map(|(&(j, _, _), w)| w * w * var[j].x as f64)
                            .sum();
                        out_var[i] = Vec3::new(v as f32, 0.0, 0.0);
                    }
                }
            }
        }
        (out, out_var)
    }

    /// The variance of that interpolation from the points' variances (in `x` of `var`):
    /// `sum w^2 var` (the points' rays are independent). A linear interpolation of the
    /// variances overstated it up to 4x, midway between four points.
    pub fn interpolate_variance(
        &self,
        var: &[Vec3],
        slot: usize,
        x: u32,
        y: u32,
        chart: u32,
    ) -> f32 {
        let w = self.weights(slot, x, y, chart);
        let total: f32 = w.iter().map(|c| c.1).sum();
        if total <= 0.0 {
            return 0.0;
        }
        w.iter().map(|&(i, w)| (w / total).powi(2) * var[i].x).sum()
    }
}

/// The weights `a_j` of the intercept of the least-squares plane `v = c0 + c1 dx + c2 dy`
/// through the points `(j, dx_j, dy_j)`: `c0 = sum a_j v_j`. `None` with fewer than three
/// points or with all of them (nearly) on a line.
fn intercept_weights(pts: &[(usize, f64, f64)]) -> Option<Vec<f64>> {
    if pts.len() < 3 {
        return None;
    }
    let row = |x: f64, y: f64| DVec3::new(1.0, x, y);
    // the normal matrix, sum r r^T
    let m = pts.iter().fold(DMat3::ZERO, |m, &(_, x, y)| {
        let r = row(x, y);
        m + DMat3::from_cols(r * r.x, r * r.y, r * r.z)
    });
    // scale-free test: the spread of the points in both directions against their number
    let scale = (m.y_axis.y * m.z_axis.z).max(f64::MIN_POSITIVE) * m.x_axis.x;
    let det = m.determinant();
    // (NaN fails the test too)
    if det.is_nan() || det <= 1e-6 * scale {
        return None;
    }
    let first = m.inverse().row(0);
    Some(pts.iter().map(|&(_, x, y)| first.dot(row(x, y))).collect())
}

/// Per chart (numbered as in `tri_chart`), the density level of its triangles (charts never
/// mix levels); all 0 for a uniform atlas.
fn chart_levels(mesh: &Mesh, atlas: Option<&ShapeAtlas>, tri_chart: &[u32]) -> Vec<u8> {
    let charts = tri_chart
        .iter()
        .filter(|&&c| c != NONE)
        .map(|&c| c as usize + 1)
        .max()
        .unwrap_or(0);
    let mut levels = vec![0u8; charts];
    let Some(a) = atlas.filter(|a| a.levels > 0) else {
        return levels;
    };
    for (t, &c) in tri_chart.iter().enumerate() {
        if c != NONE {
            levels[c as usize] = a.triangle_level(mesh, t);
        }
    }
    levels
}

/// Every slot's outgoing radiance for a gather pass: `L_orig` where observed, the current
/// `K_d (E_d + E_i) / pi` elsewhere on the surface, 0 off it; with which texels are observed.
/// Held in a tile store beside the run's state and read through a bounded cache, so its memory
/// is set by the budget, not by the atlas (rays land anywhere, so reads are random).
pub struct Radiance {
    layout: Layout,
    texels: TileCache<RadianceTexel>,
}

/// One texel of [`Radiance`]: its outgoing radiance, and its chart with whether it is
/// observed packed in one word (bit 31 = observed, the rest the chart; [`NONE`] off the
/// surface), so a bilinear lookup reads one record per texel.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Pod, Zeroable)]
pub struct RadianceTexel {
    pub rgb: [f32; 3],
    pub tag: u32,
}

const OBSERVED_BIT: u32 = 1 << 31;

impl RadianceTexel {
    fn new(rgb: Vec3, chart: u32, observed: bool) -> Self {
        let tag = match chart {
            NONE => NONE,
            c => (c & !OBSERVED_BIT) | if observed { OBSERVED_BIT } else { 0 },
        };
        RadianceTexel {
            rgb: rgb.to_array(),
            tag,
        }
    }

    /// The chart under the texel's center, or [`NONE`].
    #[inline]
    pub fn chart(&self) -> u32 {
        match self.tag {
            NONE => NONE,
            t => t & !OBSERVED_BIT,
        }
    }

    #[inline]
    pub fn observed(&self) -> bool {
        self.tag != NONE && self.tag & OBSERVED_BIT != 0
    }
}

impl Radiance {
    /// Writes the radiance of every texel to a tile store at `path` (one state and geometry
    /// tile at a time) and opens it for lookups through a cache of `budget_bytes`.
    pub fn from_state(
        layout: &Layout,
        charts: &Charts,
        state: &TileStore<TexelState>,
        geom: &TileStore<TexelGeom>,
        path: &Path,
        budget_bytes: u64,
        tick: Tick,
    ) -> Result<Radiance> {
        let (n, texels) = (layout.tile_count as usize, layout.tile_texels());
        let mut store = TileStore::create(path, n, texels, RadianceTexel::default())?;
        let window = window_tiles_for_budget(budget_bytes, store.tile_stride_bytes());
        map_tiles(&mut store, geom, window, |t, g, out| {
            let s = state.read_tile(t)?;
            let sc = &charts.slots[layout.slot_of_tile(t as u32)];
            for ((o, s), g) in out.iter_mut().zip(&s).zip(g) {
                let observed = g.covered() && s.flags & flags::OBSERVED != 0;
                *o = RadianceTexel::new(outgoing(s, g), sc.texel(g), observed);
            }
            tick(1);
            Ok::<(), crate::Error>(())
        })?
        .into_iter()
        .collect::<Result<()>>()?;
        Ok(Radiance {
            layout: layout.clone(),
            texels: TileCache::new(store, budget_bytes)?,
        })
    }

    /// The first read error of the lookups since the last check (see [`TileCache::check`]).
    pub fn check(&self) -> Result<()> {
        self.texels.check()
    }

    /// Texel `(x, y)` of `slot` (inside the texture), through `reader`.
    #[inline]
    fn texel(
        &self,
        reader: &mut Reader<RadianceTexel>,
        slot: usize,
        x: i64,
        y: i64,
    ) -> RadianceTexel {
        let (t, o) = self.layout.locate(slot, x as u32, y as u32);
        reader.get(t, o)
    }

    /// Radiance of `slot` at continuous texel coordinates `uv` on chart `chart`: bilinear over
    /// the four nearest texels of that chart (renormalized), else the nearest texel of that
    /// chart in the 3 x 3 around `uv`, else 0; and whether every texel it read is observed
    /// (so the value will not change as the solver goes on).
    pub fn lookup(&self, slot: usize, uv: Vec2, chart: u32) -> (Vec3, bool) {
        let st = &self.layout.slots[slot];
        let (w, h) = (st.width as i64, st.height as i64);
        let mut reader = self.texels.reader();
        let mut on = |x: i64, y: i64| {
            if x < 0 || y < 0 || x >= w || y >= h {
                return None;
            }
            let r = self.texel(&mut reader, slot, x, y);
            (r.chart() == chart).then_some(r)
        };
        let (fx, fy) = (uv.x - 0.5, uv.y - 0.5);
        let (x0, y0) = (fx.floor(), fy.floor());
        let (tx, ty) = (fx - x0, fy - y0);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let (mut sum, mut wsum, mut fixed) = (Vec3::ZERO, 0.0f32, true);
        for (dx, dy, wt) in [
            (0, 0, (1.0 - tx) * (1.0 - ty)),
            (1, 0, tx * (1.0 - ty)),
            (0, 1, (1.0 - tx) * ty),
            (1, 1, tx * ty),
        ] {
            if let Some(r) = on(x0 + dx, y0 + dy) {
                sum += Vec3::from_array(r.rgb) * wt;
                wsum += wt;
                fixed &= r.observed();
            }
        }
        if wsum > 0.0 {
            return (sum / wsum, fixed);
        }
        let (cx, cy) = (uv.x.floor() as i64, uv.y.floor() as i64);
        (-1..=1)
            .flat_map(|dy| (-1..=1).map(move |dx| (dx, dy)))
            .find_map(|(dx, dy)| on(cx + dx, cy + dy))
            .map_or((Vec3::ZERO, true), |r| {
                (Vec3::from_array(r.rgb), r.observed())
            })
    }
}

/// A texel's outgoing radiance for gathering (see [`Radiance`]).
fn outgoing(s: &TexelState, g: &TexelGeom) -> Vec3 {
    if !g.covered() {
        Vec3::ZERO
    } else if s.flags & flags::OBSERVED != 0 {
        Vec3::from_array(s.l_orig)
    } else {
        Vec3::from_array(s.k_d) / PI * (Vec3::from_array(s.e_d) + Vec3::from_array(s.e_i))
    }
}

/// Everything the gather's ray pass reads.
#[derive(Clone, Copy)]
pub struct GatherContext<'a> {
    pub accel: &'a Accel,
    pub hits: &'a HitTable,
    pub radiance: &'a Radiance,
    pub seed: u64,
    /// Rays per point (rounded up to a square: stratified `k x k`).
    pub rays: u32,
    /// Rays per lean point ([`Point::lean`]; rounded up to a square): its `E_i` reaches no
    /// observed texel, only the light unobserved ones pass on.
    pub lean_rays: u32,
}

impl GatherContext<'_> {
    /// Strata per side of point `pt`.
    fn strata_of(&self, pt: &Point) -> u32 {
        strata(if pt.lean { self.lean_rays } else { self.rays })
    }
}

/// What a gather ray pass did.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct GatherStats {
    pub points: u64,
    pub rays: u64,
    /// Rays whose radiance depends on the solver's estimates (hits on unobserved texels),
    /// kept for re-evaluation.
    pub cached_hits: u64,
    /// Points whose hits did not fit the cache's byte limit (cast again at every evaluation).
    pub retraced_points: u64,
    pub seconds: f64,
}

/// A hit whose radiance is re-evaluated every iteration.
#[derive(Debug, Clone, Copy, PartialEq)]
struct CachedHit {
    slot: u32,
    chart: u32,
    uv: Vec2,
    /// Throughput of the known materials on the way (1 for a direct hit).
    weight: Vec3,
    /// The ray of the neighbouring stratum it is paired with for the variance.
    mate: Mate,
}

/// The pair partner of a cached hit's ray ([`pair_variance`]).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Mate {
    /// A ray whose luminance was known when cast (an observed texel, or nothing: 0).
    Known(f32),
    /// The next cached hit.
    Next,
    /// The previous cached hit (already counted with it).
    Previous,
    /// None (the unpaired stratum of a row when the strata per side are odd).
    Unpaired,
}

/// The rays of a gather, cast once: per point, the part of `E_i` from observed surfaces
/// (fixed: it needs no `K_d`) and the hits on unobserved texels, whose radiance is the
/// solver's current estimate and is re-read every iteration ([`GatherCache::evaluate`]).
/// Every iteration after the first thus costs lookups, not rays.
#[derive(Debug, Clone, PartialEq)]
pub struct GatherCache {
    /// Per point, `pi / N` times the radiance summed over its rays that saw observed texels.
    fixed: Vec<Vec3>,
    /// Per point, the squared luminance differences of its paired rays that both saw
    /// observed texels or nothing, summed (the rest come with the cached hits' mates).
    known_pairs: Vec<f32>,
    /// Per point, its strata per side `k` (lean points have fewer).
    strata: Vec<u32>,
    /// Per point, its cached hits: one exact-size slice each, kept as traced (concatenating
    /// them would hold every hit twice at the peak, and a `Vec` grown by pushes up to twice
    /// over).
    hits: Vec<Box<[CachedHit]>>,
    /// Per point, whether its hits were left out of the cache (over its byte limit): its rays
    /// are cast again at every evaluation, with the same random numbers.
    retrace: Vec<bool>,
    pub stats: GatherStats,
}

/// Cast every point's rays (see [`GatherCache`]), keeping every hit. A pure function of the
/// scene, the observed radiance and `ctx.seed`: a resumed run recomputes it bit for bit.
pub fn trace_points(ctx: &GatherContext, points: &GatherPoints, tick: Tick) -> GatherCache {
    trace_points_where(ctx, points, (&|_| true, u64::MAX), tick)
}

/// Points traced between two looks at the cache's size (the limit is overshot by at most one
/// such chunk's hits while it is traced).
const TRACE_CHUNK: usize = 1024;

/// [`trace_points`] for the points `owns` accepts (the share of one process when several run
/// the gather; the others get no rays and evaluate to 0), keeping hits up to `limit` bytes:
/// points are taken in index order and a point whose hits would pass the limit keeps none and
/// is traced again at each evaluation. `tick` gets each traced point.
pub fn trace_points_where(
    ctx: &GatherContext,
    points: &GatherPoints,
    (owns, limit): (&(dyn Fn(usize) -> bool + Sync), u64),
    tick: Tick,
) -> GatherCache {
    let t0 = Instant::now();
    let n = points.points.len();
    let mut c = GatherCache {
        fixed: Vec::with_capacity(n),
        known_pairs: Vec::with_capacity(n),
        strata: points.points.iter().map(|p| ctx.strata_of(p)).collect(),
        hits: Vec::with_capacity(n),
        retrace: vec![false; n],
        stats: GatherStats::default(),
    };
    let mut used = 0u64;
    for start in (0..n).step_by(TRACE_CHUNK) {
        let end = (start + TRACE_CHUNK).min(n);
        let traced: Vec<(Vec3, f32, Box<[CachedHit]>)> = (start..end)
            .into_par_iter()
            .map(|i| match owns(i) {
                true => {
                    let (f, pairs, h) = trace_point(ctx, i as u64, &points.points[i]);
                    tick(1);
                    (f, pairs, h.into_boxed_slice())
                }
                false => (Vec3::ZERO, 0.0, Box::default()),
            })
            .collect();
        for (i, (f, pairs, h)) in (start..).zip(traced) {
            let bytes = budget::hit_bytes(h.len());
            if used + bytes <= limit {
                used += bytes;
                c.stats.cached_hits += h.len() as u64;
                c.hits.push(h);
            } else {
                c.retrace[i] = true;
                c.stats.retraced_points += 1;
                c.hits.push(Box::default());
            }
            let k = c.strata[i];
            c.fixed.push(f * (PI / (k * k) as f32));
            c.known_pairs.push(pairs);
        }
    }
    let traced = (0..n).filter(|&i| owns(i));
    c.stats.points = traced.clone().count() as u64;
    c.stats.rays = traced.map(|i| (c.strata[i] * c.strata[i]) as u64).sum();
    c.stats.seconds = t0.elapsed().as_secs_f64();
    c
}

impl GatherCache {
    /// `E_i` at every point with the radiance of this iteration for the cached hits, and the
    /// Monte Carlo variance of its luminance (in `x`; `y`, `z` are 0; [`pair_variance`], the
    /// cached hits at this iteration's radiance too). One lookup per cached hit serves both.
    /// The points left out of the cache cast their rays again through `ctx` (whose radiance
    /// is this iteration's): the hits they find are the ones they found before.
    pub fn evaluate(&self, ctx: &GatherContext, points: &GatherPoints) -> (Vec<Vec3>, Vec<Vec3>) {
        let radiance = ctx.radiance;
        self.fixed
            .par_iter()
            .enumerate()
            .map(|(i, f)| {
                let (mut sum, mut pairs, mut first) = (Vec3::ZERO, self.known_pairs[i], 0.0f32);
                let again;
                let hits: &[CachedHit] = match self.retrace[i] {
                    true => {
                        again = trace_point(ctx, i as u64, &points.points[i]).2;
                        &again
                    }
                    false => &self.hits[i],
                };
                for h in hits {
                    let l = radiance.lookup(h.slot as usize, h.uv, h.chart).0 * h.weight;
                    sum += l;
                    let y = luminance(l);
                    match h.mate {
                        Mate::Known(m) => pairs += (y - m).powi(2),
                        Mate::Next => first = y,
                        Mate::Previous => pairs += (y - first).powi(2),
                        Mate::Unpaired => {}
                    }
                }
                let k = self.strata[i];
                let var = pair_variance(pairs, k);
                (*f + sum * (PI / (k * k) as f32), Vec3::new(var, 0.0, 0.0))
            })
            .unzip()
    }
}

/// The distance between gather points on each shape of `scene`, by shape index (see
/// [`Config::gather_spacing_for`]).
pub fn shape_spacing(cfg: &Config, scene: &Scene) -> Vec<f32> {
    let radius = crate::physics::light::bounding_sphere(scene).1;
    scene
        .shapes
        .iter()
        .map(|s| cfg.gather_spacing_for(radius, s.mesh.bounding_radius()))
        .collect()
}

/// The variance of the luminance of a gather's `E_i = pi / N sum y` over `N = k x k`
/// stratified rays, from `pairs`: the squared luminance differences of the rays of
/// neighbouring strata `(i, 2j)` and `(i, 2j + 1)`, summed (the collapsed-strata estimator:
/// each pair's squared difference estimates its two strata's variances; an odd `k` leaves a
/// stratum per row unpaired, counted at the pairs' mean). Stratified rays vary far less than
/// independent ones: the sample variance over the rays overstates it 2.7x at 64 rays and more
/// with more rays, as stratification gains with their number.
pub fn pair_variance(pairs: f32, k: u32) -> f32 {
    let paired = k * (k / 2);
    if paired == 0 {
        return 0.0;
    }
    let n = (k * k) as f32;
    PI * PI * pairs * (n / (2 * paired) as f32) / (n * n)
}

/// Rays per lean point ([`GatherContext::lean_rays`]): `share` of `rays`, at least one.
pub fn lean_rays(rays: u32, share: f32) -> u32 {
    ((rays as f64 * share as f64).round() as u32).clamp(1, rays.max(1))
}

/// Strata per side for `rays` rays.
fn strata(rays: u32) -> u32 {
    ((rays.max(1) as f64).sqrt().ceil() as u32).max(1)
}

/// One point's `k x k` stratified cosine-weighted rays about its shading normal: the radiance
/// summed over the rays that saw observed texels, the squared luminance differences of the
/// rays of neighbouring strata `(i, 2j)`, `(i, 2j + 1)` that both saw observed texels or
/// nothing, summed ([`pair_variance`]), and the hits on unobserved texels, each with its mate.
fn trace_point(ctx: &GatherContext, index: u64, pt: &Point) -> (Vec3, f32, Vec<CachedHit>) {
    let mut rng = Rng::new(ctx.seed ^ STREAM_TAG, 0, index, 0);
    let k = ctx.strata_of(pt);
    let (u, v) = pt.n.any_orthonormal_pair();
    // Rays must leave on the side of the geometric surface the shading normal is on.
    let side = pt.n.dot(pt.ng).signum();
    let coat = ctx.hits.coat(pt.shape);
    let (mut sum, mut pairs, mut cached) = (Vec3::ZERO, 0.0f32, Vec::new());
    for i in 0..k {
        // the first ray of the current pair: its luminance, or its cached hit
        let mut first: Option<Result<f32, CachedHit>> = None;
        for j in 0..k {
            let r2 = (i as f32 + rng.f32()) / k as f32;
            let phi = TAU * (j as f32 + rng.f32()) / k as f32;
            let r = r2.sqrt();
            let d = (u * (r * phi.cos()) + v * (r * phi.sin()) + pt.n * (1.0 - r2).max(0.0).sqrt())
                .normalize();
            let mut ray: Result<f32, CachedHit> = Ok(0.0);
            // a coated point's base receives what its coat lets in
            let t = coat.map_or(1.0, |c| c.transmittance((1.0 - r2).max(0.0).sqrt()));
            if d.dot(pt.ng) * side > 0.0 {
                match walk(ctx, offset_origin(pt.p, pt.ng, d), d, &mut rng) {
                    Seen::Surface(mut h) => {
                        h.weight *= t;
                        ray = match ctx.radiance.lookup(h.slot as usize, h.uv, h.chart) {
                            (l, true) => {
                                sum += l * h.weight;
                                Ok(luminance(l * h.weight))
                            }
                            (_, false) => Err(h),
                        };
                    }
                    Seen::Light(l) => {
                        sum += l * t;
                        ray = Ok(luminance(l * t));
                    }
                    Seen::Nothing => {}
                }
            }
            match (first.take(), ray) {
                (None, r) if j + 1 == k => {
                    if let Err(h) = r {
                        cached.push(CachedHit {
                            mate: Mate::Unpaired,
                            ..h
                        });
                    }
                }
                (None, r) => first = Some(r),
                (Some(Ok(a)), Ok(b)) => pairs += (a - b).powi(2),
                (Some(Ok(a)), Err(h)) => cached.push(CachedHit {
                    mate: Mate::Known(a),
                    ..h
                }),
                (Some(Err(h)), Ok(b)) => cached.push(CachedHit {
                    mate: Mate::Known(b),
                    ..h
                }),
                (Some(Err(a)), Err(b)) => {
                    cached.push(CachedHit {
                        mate: Mate::Next,
                        ..a
                    });
                    cached.push(CachedHit {
                        mate: Mate::Previous,
                        ..b
                    });
                }
            }
        }
    }
    (sum, pairs, cached)
}

/// What a gather ray brings back.
enum Seen {
    /// A reconstructed surface (directly, or through mirrors, glass and coats: `weight`).
    Surface(CachedHit),
    /// Light of known radiance: an emitter or the environment seen by way of a coat (the
    /// caustic pass follows mirrors and glass only, so this light is nowhere else).
    Light(Vec3),
    Nothing,
}

/// Follows a gather ray from `o` along `d` through known materials (sampled by `bsdf_sampling`)
/// and coats (reflected with the coat's probability, else seeing the base, see
/// `physics::coat::Coat::step`) to the reconstructed surface it sees. Emitters (seen directly:
/// `E_d`; through mirrors and glass: the caustic pass's, also in `E_d`), misses and the back
/// of one-sided surfaces bring nothing, unless a coat reflected the ray on its way.
fn walk(ctx: &GatherContext, mut o: Vec3, mut d: Vec3, rng: &mut Rng) -> Seen {
    let mut weight = Vec3::ONE;
    let mut coated = false;
    for _ in 0..=bsdf_sampling::MAX_SPECULAR {
        let Some((hit, prim)) = ctx.hits.trace(ctx.accel, o, d, f32::INFINITY) else {
            return light(coated, ctx.hits.environment(d) * weight);
        };
        let back = d.dot(hit.ns) >= 0.0;
        if let Some(e) = ctx.hits.emitted(prim, hit.ns, d) {
            return light(coated, e * weight);
        }
        let dir = match (prim.slot != NONE, ctx.hits.coat(prim.shape)) {
            (true, _) if prim.chart == NONE || (prim.one_sided && back) => return Seen::Nothing,
            (true, Some(c)) if !back => match c.step(d, hit.ns, rng.f32(), rng) {
                Ok((dir, w)) => {
                    coated = true;
                    weight *= w;
                    dir
                }
                Err(w) => return surface(prim, hit.uv, weight * w),
            },
            (true, _) => return surface(prim, hit.uv, weight),
            (false, _) => {
                let Some(b) = ctx.hits.known(prim) else {
                    return Seen::Nothing;
                };
                if prim.one_sided && back {
                    return Seen::Nothing;
                }
                let Some(sc) = bsdf_sampling::sample(b, d, hit.ns, rng) else {
                    return Seen::Nothing;
                };
                weight *= sc.weight;
                sc.dir
            }
        };
        if weight.max_element() < 1e-4 {
            return Seen::Nothing;
        }
        o = offset_origin(hit.p, prim.ng, dir);
        d = dir;
    }
    Seen::Nothing
}

/// A reconstructed surface's texel seen with throughput `weight`.
fn surface(prim: &Prim, uv: Vec2, weight: Vec3) -> Seen {
    Seen::Surface(CachedHit {
        slot: prim.slot,
        chart: prim.chart,
        uv,
        weight,
        mate: Mate::Unpaired,
    })
}

/// Light seen at the end of a path: counted only when a coat reflected it (see [`Seen`]).
fn light(coated: bool, l: Vec3) -> Seen {
    match coated {
        true => Seen::Light(l),
        false => Seen::Nothing,
    }
}

/// Writes the gathered `E_i` into `TexelState::accum` of every covered texel (interpolated
/// between points, see [`GatherPoints::interpolate`]), and its variance into `e_var`
/// ([`GatherPoints::interpolate_variance`]); 0 elsewhere. After it
/// `accum` holds this pass's `E_i`, as after a photon pass.
pub fn write_accum(
    layout: &Layout,
    points: &GatherPoints,
    (values, variance): (&[Vec3], &[Vec3]),
    charts: &Charts,
    geom: &TileStore<TexelGeom>,
    (state, window): (&mut TileStore<TexelState>, usize),
    tick: Tick,
) -> Result<()> {
    map_tiles(state, geom, window, |t, g, st| {
        let span = layout.span(t as u32);
        let sc = &charts.slots[span.slot];
        for s in st.iter_mut() {
            s.accum = [0.0; 3];
            s.e_var = 0.0;
        }
        for (off, x, y) in span.texels() {
            let c = sc.texel(&g[off]);
            if !g[off].covered() || c == NONE {
                continue;
            }
            st[off].accum = points.interpolate(values, span.slot, x, y, c).to_array();
            st[off].e_var = points
                .interpolate_variance(variance, span.slot, x, y, c)
                .max(0.0);
        }
        tick(1);
    })?;
    Ok(())
}

pub mod budget;

#[cfg(test)]
mod tests;
