//! Method step 3 as a stage: the direct irradiance `E_d` of every covered texel from every
//! emitter, with shadows, as the mean over the texel's square (the physics is
//! `crate::physics::light`), written into the state tiles.
//!
//! Shadow rays only where they can change the answer. Each light's first pass (a few rays)
//! classifies a texel as lit throughout, dark throughout, or crossed by a shadow edge or a
//! penumbra ([`Reach`]); only the last needs a dense estimate, and lit texels get the analytic
//! unoccluded irradiance. Within a tile the first pass runs on a lattice of every
//! [`LATTICE`]-th texel (and the tile's last row and column); a texel between four lattice
//! texels of its own chart that agree, light by light, on lit or dark takes that verdict
//! without rays, so on large scenes the rays follow the shadow boundaries rather than the
//! texel count. A texel next to a hard shadow edge (point, spot, directional light) is
//! estimated densely too, in case its own few rays missed an edge that just touches it.
//!
//! Dense samples where a photo needs them. A texel's `E_d` divides its photographed radiance
//! into `K_d`; a texel no photo observed takes its `K_d` from the fill, and its `E_d` only feeds
//! the light it passes on to others, an average over many texels in which its sampling noise
//! washes out. Such texels draw `[run] unobserved_share` of the dense samples (an environment
//! light's pairs, an area light's penumbra rays, a hard light's edge points), and an
//! area-emitter triangle no shadow line fits is sampled at once rather than split and fitted
//! again (`DirectParams::scaled`). The first pass's verdict, lit, dark or partly lit, is the
//! same for all, so the lattice verdicts observed texels take do not change. On interiors and
//! scenes of small parts most covered texels are unobserved, and the direct light costs in
//! proportion to what the photos saw.

mod coat;
pub mod sampling;
pub mod smooth;

use crate::atlas::store::{flags, map_tiles, TileStore};
use crate::atlas::store::{TexelGeom, TexelState};
use crate::atlas::uv::Charts;
use crate::atlas::uv::NONE;
use crate::atlas::RunContext;
use crate::base::error::Result;
use crate::base::interrupt;
use crate::base::progress::{Mode, Stage};
use crate::config::Config;
use crate::physics::light::{
    emitter_irradiance_var, emitter_unoccluded, DirectParams, Footprint, Reach,
};
use crate::scene::Emitter;
use glam::Vec3;

/// Lattice spacing of the first pass, texels. 2 keeps shadows of features down to about two
/// texels (3 cm at 64 texels per unit) from slipping between lattice texels.
pub const LATTICE: u32 = 2;

/// The smallest shadow the coarse lattice levels must not miss, as a fraction of the scene's
/// bounding radius (3.3 cm in the 6 x 3 x 5 m room, about two texels at its automatic
/// density; the first pass's 2-texel lattice guards the same size there).
pub const FEATURE_OF_RADIUS: f32 = 1.0 / 128.0;

/// The spacing, in texels, of the coarsest first-pass lattice of a texture of `density`
/// texels per unit where the smallest shadow to keep is `feature` units wide: the largest
/// power of two whose cells (`spacing / density` units) are no wider than it, at least
/// [`LATTICE`] and at most a quarter tile. Fine atlases get coarse lattice levels first, so
/// lit and dark regions cost rays per unit of area rather than per texel; coarse atlases keep
/// the 2-texel lattice alone.
pub fn coarse_spacing(density: f32, feature: f32, tile_size: u32) -> usize {
    let texels = (density * feature).max(LATTICE as f32);
    let mut s = LATTICE as usize;
    while ((s * 2) as f32) <= texels && s * 2 <= (tile_size / 4).max(LATTICE) as usize {
        s *= 2;
    }
    s
}

/// A texel's chart split by whether a photo observed it ([`NONE`] stays [`NONE`]): observed and
/// unobserved texels draw different numbers of samples, so their noise is measured and smoothed
/// apart ([`sampling`], [`smooth`]), and an observed texel never averages in a noisier one.
pub fn sample_class(chart: u32, s: &TexelState) -> u32 {
    match chart {
        c if c >= NONE / 2 => NONE,
        c => 2 * c + u32::from(s.flags & flags::OBSERVED != 0),
    }
}

/// Statistics of the stage.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DirectStats {
    /// Area-weighted mean `E_d` over covered texels (the solver's initial `E_i` where a texel
    /// has no direct light).
    pub mean: Vec3,
    pub texels: u64,
    /// Texels that ran a first pass (the rest took their lattice neighbours' verdict).
    pub first_pass: u64,
    /// Texels estimated densely for some light (edges, penumbrae, their neighbours).
    pub dense: u64,
    /// Per emitter, the texels estimated densely for it.
    pub dense_per_emitter: Vec<u64>,
    /// Texels whose sampled environment light was averaged with neighbours
    /// ([`smooth::smooth`]).
    pub smoothed: u64,
}

/// `E_d` of the covered texels of the tiles `owns` accepts (the share of one process when
/// several run the stage), and per tile its sums (zero for the others), in tile order.
pub fn run_tiles(
    p: &RunContext,
    cfg: &Config,
    charts: &Charts,
    geom: &TileStore<TexelGeom>,
    state: &mut TileStore<TexelState>,
    mode: Mode,
    owns: &(dyn Fn(usize) -> bool + Sync),
) -> Result<Vec<TileSums>> {
    let shared = (charts, geom, owns);
    light_tiles(p, cfg, shared, state, mode, FEATURE_OF_RADIUS)
}

/// [`run_tiles`] with the coarse lattices' feature size `feature` (a fraction of the scene's
/// bounding radius; 0 keeps the 2-texel lattice alone).
fn light_tiles(
    p: &RunContext,
    cfg: &Config,
    (charts, geom, owns): (
        &Charts,
        &TileStore<TexelGeom>,
        &(dyn Fn(usize) -> bool + Sync),
    ),
    state: &mut TileStore<TexelState>,
    mode: Mode,
    feature: f32,
) -> Result<Vec<TileSums>> {
    let params = DirectParams {
        area_samples: cfg.area_samples,
        env_samples: cfg.env_samples,
        ..DirectParams::default()
    };
    let lean = params.scaled(cfg.unobserved_share);
    let window = p.window::<TexelState>(cfg);
    let feature = crate::physics::light::bounding_sphere(&p.scene).1 * feature;
    let mine = (0..state.tile_count()).filter(|&t| owns(t)).count();
    let stage = Stage::new(mode, "direct", mine as u64, "tiles");
    let coats = coat::Coats::of(&p.scene);
    let sums = map_tiles(state, geom, window, |t, g, st| {
        // a stop was asked for: skip the rest, the stage's result is not used
        if !owns(t) || interrupt::requested() {
            return TileSums::default();
        }
        let mut ctx = TileCtx::new(p, charts, (cfg.seed, feature), [&params, &lean], t, (g, st));
        ctx.coat = coats.of_shape(ctx.shape);
        let s = ctx.run(st);
        stage.inc(1);
        s
    })?;
    interrupt::check(interrupt::NOTHING_SAVED)?;
    stage.finish();
    Ok(sums)
}

impl DirectStats {
    /// The stage's statistics from every tile's sums, added in tile order.
    pub fn from_tiles(sums: &[TileSums]) -> DirectStats {
        let (mut e, mut a, mut stats) = (Vec3::ZERO, 0.0f64, DirectStats::default());
        for s in sums {
            e += s.sum;
            a += s.area;
            stats.texels += s.texels;
            stats.first_pass += s.first_pass;
            stats.dense += s.dense;
            stats.dense_per_emitter.resize(s.dense_k.len(), 0);
            for (a, b) in stats.dense_per_emitter.iter_mut().zip(&s.dense_k) {
                *a += b;
            }
        }
        stats.mean = if a > 0.0 { e / a as f32 } else { Vec3::ZERO };
        stats
    }
}

/// Whether texel `off` has its first-pass values (rows of `lights` per texel).
fn valued(first: &[Option<(Vec3, Reach, f32)>], off: usize, lights: usize) -> bool {
    first.get(off * lights).is_some_and(Option::is_some)
}

/// One tile's sums.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TileSums {
    sum: Vec3,
    area: f64,
    texels: u64,
    first_pass: u64,
    dense: u64,
    dense_k: Vec<u64>,
}

/// One tile being lit: its geometry, footprints, charts and random keys.
struct TileCtx<'a> {
    p: &'a RunContext,
    /// The samples of an observed texel, and of one no photo observed.
    params: [&'a DirectParams; 2],
    /// Per texel of the tile, whether a photo observed it.
    observed: Vec<bool>,
    g: &'a [TexelGeom],
    /// Per texel of the tile, its footprint (centers only where uncovered) and chart.
    fps: Vec<Footprint>,
    chart: Vec<u32>,
    seed: u64,
    first_key: u64,
    ts: usize,
    /// The coarsest first-pass lattice spacing ([`coarse_spacing`]).
    coarse: usize,
    /// The tile's shape, and its coat with the emitters' centres if it has one.
    shape: usize,
    coat: Option<coat::TileCoat<'a>>,
}

impl<'a> TileCtx<'a> {
    fn new(
        p: &'a RunContext,
        charts: &Charts,
        (seed, feature): (u64, f32),
        params: [&'a DirectParams; 2],
        t: usize,
        (g, st): (&'a [TexelGeom], &[TexelState]),
    ) -> TileCtx<'a> {
        let slot = p.layout.slot_of_tile(t as u32);
        let shape = p.shape_ref(slot);
        let density = p.atlases[shape.index as usize]
            .as_ref()
            .map_or(0.0, |a| a.coarsest_density());
        let tri_chart = &charts.slots[slot].tri_chart;
        let fps = g
            .iter()
            .map(|g| {
                let (dx, dy) = match g.covered() {
                    true => shape.texel_edges(g.tri as usize),
                    false => (Vec3::ZERO, Vec3::ZERO),
                };
                Footprint {
                    p: g.p(),
                    dx,
                    dy,
                    n: g.n(),
                    ng: g.ng(),
                }
            })
            .collect();
        let chart = g
            .iter()
            .map(|g| match g.covered() {
                true => tri_chart.get(g.tri as usize).copied().unwrap_or(NONE),
                false => NONE,
            })
            .collect();
        TileCtx {
            p,
            params,
            observed: st.iter().map(|s| s.flags & flags::OBSERVED != 0).collect(),
            g,
            fps,
            chart,
            seed,
            first_key: t as u64 * p.layout.tile_texels() as u64,
            ts: p.layout.tile_size as usize,
            coarse: coarse_spacing(density, feature, p.layout.tile_size),
            shape: shape.index as usize,
            coat: None,
        }
    }

    /// Every covered texel's `E_d` into `st`.
    fn run(&self, st: &mut [TexelState]) -> TileSums {
        let lights = self.p.scene.emitters.len();
        let n = self.g.len();
        // per texel and light: the first pass's irradiance and verdict (None: not run)
        let mut first: Vec<Option<(Vec3, Reach, f32)>> = vec![None; n * lights];
        let mut sums = TileSums {
            dense_k: vec![0; lights],
            ..Default::default()
        };
        let mut s = self.coarse;
        while s > LATTICE as usize {
            sums.first_pass += self.first_passes(s, &mut first, lights);
            self.fill_agreeing_cells(s, &mut first, lights);
            s /= 2;
        }
        sums.first_pass += self.first_passes(LATTICE as usize, &mut first, lights);
        for off in 0..n {
            let pending = !self.on_grid(off, LATTICE as usize) && self.g[off].covered();
            if !pending || valued(first.as_slice(), off, lights) {
                continue;
            }
            let verdict = self.lattice_verdict(off, &first, lights);
            let row = &mut first[off * lights..(off + 1) * lights];
            match verdict {
                Some(v) => self.take_verdict(off, &v, row),
                None => {
                    self.first_pass(off, row);
                    sums.first_pass += 1;
                }
            }
        }
        for off in (0..n).filter(|&o| self.g[o].covered()) {
            let mut e = Vec3::ZERO;
            let mut var = 0.0;
            let mut dense = false;
            for k in 0..lights {
                let (ek, reach, vk) = first[off * lights + k].expect("every covered texel is lit");
                // an area or environment light's first pass already integrated its penumbra
                let area = matches!(
                    self.p.scene.emitters[k],
                    Emitter::Area { .. } | Emitter::Environment(_)
                );
                let redo = (reach == Reach::Partial && !area)
                    || self.near_hard_edge(off, k, &first, lights);
                if reach == Reach::Partial && area {
                    dense = true;
                    sums.dense_k[k] += 1;
                }
                let (ek, vk) = if redo {
                    dense = true;
                    sums.dense_k[k] += 1;
                    let (e, _, v) = self.estimate(off, k, true);
                    (e, v)
                } else {
                    (ek, vk)
                };
                let share = self
                    .coat
                    .as_ref()
                    .map_or(1.0, |c| c.share(&self.fps[off], k));
                e += ek * share;
                var += vk * share * share;
            }
            st[off].e_d = e.to_array();
            // the sample pairs' own spread: `sampling::estimate` keeps the smaller of it and
            // the map's roughness
            st[off].ed_var = var;
            sums.sum += e * self.g[off].area;
            sums.area += self.g[off].area as f64;
            sums.texels += 1;
            sums.dense += dense as u64;
        }
        sums
    }

    fn xy(&self, off: usize) -> (usize, usize) {
        (off % self.ts, off / self.ts)
    }

    /// Whether `off` is a point of the lattice of spacing `s` (the tile's last row and
    /// column included).
    fn on_grid(&self, off: usize, s: usize) -> bool {
        let (x, y) = self.xy(off);
        let on = |v: usize| v % s == 0 || v == self.ts - 1;
        on(x) && on(y)
    }

    /// The first pass at every covered point of the lattice of spacing `s` that has no value
    /// yet; returns how many ran.
    fn first_passes(
        &self,
        s: usize,
        first: &mut [Option<(Vec3, Reach, f32)>],
        lights: usize,
    ) -> u64 {
        let mut ran = 0;
        for off in 0..self.g.len() {
            if self.on_grid(off, s) && self.g[off].covered() && !valued(first, off, lights) {
                self.first_pass(off, &mut first[off * lights..(off + 1) * lights]);
                ran += 1;
            }
        }
        ran
    }

    /// Every cell of the lattice of spacing `s` whose four corners are covered, on one chart
    /// and agree, light by light, on lit or dark, and none of whose eight neighbour cells in
    /// the tile is crossed by a shadow boundary (corners on one chart that disagree): its
    /// texels of that chart without a value take the verdict. The neighbours guard against
    /// the tip of a shadow's corner reaching into a cell between its corners; shadows smaller
    /// than a cell are the risk [`FEATURE_OF_RADIUS`] bounds. Other cells are left to the
    /// finer levels.
    fn fill_agreeing_cells(
        &self,
        s: usize,
        first: &mut [Option<(Vec3, Reach, f32)>],
        lights: usize,
    ) {
        let last = self.ts - 1;
        let n = last.div_ceil(s);
        let span = |c: usize| [c * s, ((c + 1) * s).min(last)];
        // per cell: Some(Some(verdict)) agreeing, Some(None) crossed by a boundary, None else
        let cells: Vec<Option<Option<Vec<Reach>>>> = (0..n * n)
            .map(|c| self.cell_state(span(c % n), span(c / n), first, lights))
            .collect();
        for (c, state) in cells.iter().enumerate() {
            let Some(Some(verdict)) = state else {
                continue;
            };
            let (cx, cy) = ((c % n) as i64, (c / n) as i64);
            let crossed = (-1..=1).any(|dy| {
                (-1..=1).any(|dx| {
                    let (x, y) = (cx + dx, cy + dy);
                    let inside = x >= 0 && y >= 0 && x < n as i64 && y < n as i64;
                    inside && matches!(cells[(y * n as i64 + x) as usize], Some(None))
                })
            });
            if !crossed {
                self.fill_cell(span(c % n), span(c / n), verdict, first, lights);
            }
        }
    }

    /// Cell `xs x ys`: `None` if its corners are not all covered and on one chart, else
    /// `Some` of their common verdict per light (`None` if they disagree or see a penumbra).
    fn cell_state(
        &self,
        [x0, x1]: [usize; 2],
        [y0, y1]: [usize; 2],
        first: &[Option<(Vec3, Reach, f32)>],
        lights: usize,
    ) -> Option<Option<Vec<Reach>>> {
        let corners = [(x0, y0), (x1, y0), (x0, y1), (x1, y1)].map(|(a, b)| b * self.ts + a);
        let chart = self.chart[corners[0]];
        let one_chart = corners
            .iter()
            .all(|&c| self.chart[c] == chart && self.g[c].covered());
        one_chart.then(|| self.cell_verdict([x0, x1], [y0, y1], first, lights))
    }

    /// Gives the texels of cell `xs x ys` on its corners' chart that have no value yet the
    /// `verdict`.
    fn fill_cell(
        &self,
        [x0, x1]: [usize; 2],
        [y0, y1]: [usize; 2],
        verdict: &[Reach],
        first: &mut [Option<(Vec3, Reach, f32)>],
        lights: usize,
    ) {
        let chart = self.chart[y0 * self.ts + x0];
        for y in y0..=y1 {
            for x in x0..=x1 {
                let off = y * self.ts + x;
                if !valued(first, off, lights) && self.g[off].covered() && self.chart[off] == chart
                {
                    self.take_verdict(off, verdict, &mut first[off * lights..(off + 1) * lights]);
                }
            }
        }
    }

    /// Light `k` at texel `off`: the first pass, or with `dense` the dense estimate.
    fn estimate(&self, off: usize, k: usize, dense: bool) -> (Vec3, Reach, f32) {
        let key = (self.seed, self.first_key + off as u64);
        let p = self.p;
        let params = self.params[usize::from(!self.observed[off])];
        emitter_irradiance_var(&p.scene, &p.accel, k, &self.fps[off], params, key, dense)
    }

    fn first_pass(&self, off: usize, row: &mut [Option<(Vec3, Reach, f32)>]) {
        for (k, r) in row.iter_mut().enumerate() {
            *r = Some(self.estimate(off, k, false));
        }
    }

    /// Per light, the verdict of the four lattice texels around `off` if they are all
    /// covered, on `off`'s chart, and agree on lit or dark; else `None`.
    fn lattice_verdict(
        &self,
        off: usize,
        first: &[Option<(Vec3, Reach, f32)>],
        lights: usize,
    ) -> Option<Vec<Reach>> {
        let (x, y) = self.xy(off);
        let s = LATTICE as usize;
        let (x0, y0) = (x / s * s, y / s * s);
        let (x1, y1) = ((x0 + s).min(self.ts - 1), (y0 + s).min(self.ts - 1));
        if self.chart[y0 * self.ts + x0] != self.chart[off] {
            return None;
        }
        self.cell_verdict([x0, x1], [y0, y1], first, lights)
    }

    /// Per light, the verdict of the cell `xs x ys`'s four corners if they are all covered,
    /// on one chart, and agree on lit or dark; else `None`.
    fn cell_verdict(
        &self,
        [x0, x1]: [usize; 2],
        [y0, y1]: [usize; 2],
        first: &[Option<(Vec3, Reach, f32)>],
        lights: usize,
    ) -> Option<Vec<Reach>> {
        let corners = [(x0, y0), (x1, y0), (x0, y1), (x1, y1)].map(|(a, b)| b * self.ts + a);
        let chart = self.chart[corners[0]];
        if corners
            .iter()
            .any(|&c| self.chart[c] != chart || !self.g[c].covered())
        {
            return None;
        }
        (0..lights)
            .map(|k| {
                let v = first[corners[0] * lights + k]?.1;
                let agree = corners
                    .iter()
                    .all(|&c| first[c * lights + k].map(|f| f.1) == Some(v));
                (agree && v != Reach::Partial).then_some(v)
            })
            .collect()
    }

    /// First-pass values from lattice verdicts: the analytic unoccluded irradiance where lit.
    fn take_verdict(&self, off: usize, verdict: &[Reach], row: &mut [Option<(Vec3, Reach, f32)>]) {
        for (k, (r, v)) in row.iter_mut().zip(verdict).enumerate() {
            let e = match v {
                Reach::Lit => emitter_unoccluded(&self.p.scene, k, &self.fps[off]),
                _ => Vec3::ZERO,
            };
            *r = Some((e, *v, 0.0));
        }
    }

    /// Whether a neighbour of `off` in the tile found a hard shadow edge of light `k` (a
    /// point, spot or directional light).
    fn near_hard_edge(
        &self,
        off: usize,
        k: usize,
        first: &[Option<(Vec3, Reach, f32)>],
        lights: usize,
    ) -> bool {
        if matches!(
            self.p.scene.emitters[k],
            Emitter::Area { .. } | Emitter::Environment(_)
        ) {
            return false;
        }
        let (x, y) = (off as i64 % self.ts as i64, off as i64 / self.ts as i64);
        let ts = self.ts as i64;
        (-1..=1).any(|dy| {
            (-1..=1).any(|dx| {
                let (nx, ny) = (x + dx, y + dy);
                nx >= 0
                    && ny >= 0
                    && nx < ts
                    && ny < ts
                    && first[(ny * ts + nx) as usize * lights + k]
                        .is_some_and(|f| f.1 == Reach::Partial)
            })
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atlas::build_geometry;
    use crate::atlas::uv::AtlasSettings;
    use crate::scene::mitsuba::parse;
    use std::path::Path;

    #[test]
    fn coarse_spacing_follows_the_feature_in_texels() {
        assert_eq!(
            coarse_spacing(64.0, 0.033, 64),
            2,
            "2 texels a feature: the lattice alone"
        );
        assert_eq!(coarse_spacing(820.0, 0.033, 64), 16, "27 texels a feature");
        assert_eq!(
            coarse_spacing(8000.0, 0.033, 64),
            16,
            "at most a quarter tile"
        );
        assert_eq!(
            coarse_spacing(820.0, 0.0, 64),
            2,
            "no feature: the lattice alone"
        );
    }

    /// A 1 x 1 floor under a small box, lit by a point light and a square area light.
    fn scene() -> crate::scene::Scene {
        scene_with("")
    }

    /// [`scene`] with the emitter `extra` added.
    fn scene_with(extra: &str) -> crate::scene::Scene {
        let xml = "<scene version=\"3.0.0\">\
            <shape type=\"rectangle\" id=\"floor\"><transform name=\"to_world\">\
              <scale value=\"0.5\"/></transform></shape>\
            <shape type=\"cube\" id=\"box\"><transform name=\"to_world\">\
              <scale x=\"0.08\" y=\"0.15\" z=\"0.08\"/><translate x=\"0.1\" z=\"0.15\"/>\
            </transform></shape>\
            <shape type=\"rectangle\" id=\"lamp\"><transform name=\"to_world\">\
              <scale value=\"0.1\"/><rotate x=\"1\" angle=\"180\"/>\
              <translate x=\"-0.3\" z=\"0.9\"/></transform>\
              <emitter type=\"area\"><rgb name=\"radiance\" value=\"5\"/></emitter></shape>\
            <emitter type=\"point\"><point name=\"position\" x=\"0.4\" y=\"0.1\" z=\"0.8\"/>\
              <rgb name=\"intensity\" value=\"1\"/></emitter>"
            .to_string()
            + extra
            + "</scene>";
        parse(&xml, Path::new("t/scene.xml")).unwrap()
    }

    /// `E_d` of the floor's texels with the coarse lattices of `feature` (0: none).
    fn floor_e_d(feature: f32) -> (Vec<[f32; 3]>, DirectStats) {
        let (e, stats, _) = floor_e_d_seen((scene(), 512.0), feature, 1.0, &|_| true);
        (e.into_iter().map(|(e, _)| e).collect(), stats)
    }

    /// [`floor_e_d`] of `scene` at `density` texels per unit, where the texels at the points
    /// `seen` accepts are observed by a photo and the others draw `share` of the dense samples;
    /// per floor texel its `E_d` and whether it was observed, and the shadow rays cast.
    fn floor_e_d_seen(
        (scene, density): (crate::scene::Scene, f32),
        feature: f32,
        share: f32,
        seen: &(dyn Fn(Vec3) -> bool + Sync),
    ) -> (Vec<([f32; 3], bool)>, DirectStats, u64) {
        let settings = AtlasSettings {
            texels_per_unit: density,
            ..Default::default()
        };
        let p = RunContext::new(scene, vec![], &settings, 64).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let geom = build_geometry(&p, &dir.path().join("g"), Mode::Quiet).unwrap();
        let charts = Charts::new(&p.scene, &p.layout, &p.atlases).unwrap();
        let mut state = p
            .create_store(dir.path().join("s"), TexelState::default())
            .unwrap();
        let cfg = Config {
            unobserved_share: share,
            ..Config::for_scene("t/scene.xml".into())
        };
        let window = p.window::<TexelState>(&cfg);
        map_tiles(&mut state, &geom, window, |_, g, st| {
            for (g, s) in g.iter().zip(st.iter_mut()) {
                if g.covered() && seen(g.p()) {
                    s.flags |= flags::OBSERVED;
                }
            }
        })
        .unwrap();
        let all = |_: usize| true;
        let shared = (&charts, &geom, &all as &(dyn Fn(usize) -> bool + Sync));
        let rays = p.accel.rays();
        let sums = light_tiles(&p, &cfg, shared, &mut state, Mode::Quiet, feature).unwrap();
        let rays = p.accel.rays() - rays;
        let stats = DirectStats::from_tiles(&sums);
        let mut e = Vec::new();
        for t in 0..state.tile_count() {
            if p.layout.slot_of_tile(t as u32) == 0 {
                let (g, s) = (geom.read_tile(t).unwrap(), state.read_tile(t).unwrap());
                e.extend(
                    g.iter()
                        .zip(&s)
                        .filter(|(g, _)| g.covered())
                        .map(|(_, s)| (s.e_d, s.flags & flags::OBSERVED != 0)),
                );
            }
        }
        (e, stats, rays)
    }

    /// Texels no photo observed draw a quarter of the dense samples: the observed ones come out
    /// bit-identical (their own samples and streams), the others close to the full estimate
    /// on average (the area light's penumbra, the point light's shadow edge and the sky's
    /// shadows fall on both halves of the floor), and the stage casts markedly fewer rays
    /// (under the sky every texel is sampled densely).
    #[test]
    fn unobserved_texels_draw_a_share_of_the_dense_samples() {
        let sky = "<emitter type=\"constant\"><rgb name=\"radiance\" value=\"0.2\"/></emitter>";
        let left = |p: Vec3| p.x < 0.0;
        let (full, _, full_rays) = floor_e_d_seen((scene_with(sky), 128.0), 0.0, 1.0, &left);
        let (lean, stats, lean_rays) = floor_e_d_seen((scene_with(sky), 128.0), 0.0, 0.25, &left);
        assert!(stats.dense > 100, "{} dense texels", stats.dense);
        let observed = full.iter().filter(|(_, o)| *o).count();
        assert!(observed > 100 && observed < full.len() - 100, "{observed}");
        let lum = |e: &[f32; 3]| Vec3::from_array(*e).dot(Vec3::splat(1.0 / 3.0));
        let (mut a, mut b) = (0.0f64, 0.0f64);
        for ((fe, fo), (le, lo)) in full.iter().zip(&lean) {
            assert_eq!(fo, lo);
            match fo {
                true => assert_eq!(fe, le, "an observed texel changed"),
                false => (a, b) = (a + lum(fe) as f64, b + lum(le) as f64),
            }
        }
        assert!((b / a - 1.0).abs() < 0.01, "unobserved mean E_d x{}", b / a);
        assert!(
            lean_rays * 10 < full_rays * 7,
            "rays {full_rays} -> {lean_rays}"
        );
    }

    #[test]
    fn coarse_lattices_agree_with_the_two_texel_lattice_for_fewer_first_passes() {
        // the box's shadows (16 cm wide and more) are far above a feature of 4 cm (20 texels:
        // lattices of 16, 8, 4, 2)
        let radius = crate::physics::light::bounding_sphere(&scene()).1;
        let (fine, fine_stats) = floor_e_d(0.0);
        let (coarse, coarse_stats) = floor_e_d(0.04 / radius);
        assert_eq!(fine.len(), coarse.len());
        let lum = |e: &[f32; 3]| Vec3::from_array(*e).dot(Vec3::splat(1.0 / 3.0));
        let mean = fine.iter().map(lum).sum::<f32>() / fine.len() as f32;
        let differ = fine.iter().zip(&coarse).filter(|(a, b)| a != b).count();
        let worst = fine
            .iter()
            .zip(&coarse)
            .map(|(a, b)| (lum(a) - lum(b)).abs() / mean)
            .fold(0.0f32, f32::max);
        eprintln!(
            "{} texels, {differ} differ, worst {worst:.2e} of the mean; first passes {} -> {}",
            fine.len(),
            fine_stats.first_pass,
            coarse_stats.first_pass
        );
        assert_eq!(differ, 0, "worst texel {worst:.2e} of the mean E_d");
        assert!(
            coarse_stats.first_pass * 5 < fine_stats.first_pass * 2,
            "first passes {} vs {}",
            coarse_stats.first_pass,
            fine_stats.first_pass
        );
    }
}
