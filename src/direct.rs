//! Method step 3 as a stage: the direct irradiance `E_d` of every covered texel from every
//! emitter, with shadows, as the mean over the texel's square (the physics is
//! `crate::light`), written into the state tiles.
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

use crate::atlas::charts::Charts;
use crate::atlas::layout::{TexelGeom, TexelState};
use crate::atlas::texels::NONE;
use crate::atlas::tiles::{map_tiles, TileStore};
use crate::atlas::Prepared;
use crate::config::Config;
use crate::error::Result;
use crate::interrupt;
use crate::light::{emitter_irradiance, emitter_unoccluded, DirectParams, Footprint, Reach};
use crate::progress::{Mode, Stage};
use crate::scene::Emitter;
use glam::Vec3;

/// Lattice spacing of the first pass, texels. 2 keeps shadows of features down to about two
/// texels (3 cm at 64 texels per unit) from slipping between lattice texels.
pub const LATTICE: u32 = 2;

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
}

/// `E_d` of every covered texel into `state`.
pub fn run(
    p: &Prepared,
    cfg: &Config,
    charts: &Charts,
    geom: &TileStore<TexelGeom>,
    state: &mut TileStore<TexelState>,
    mode: Mode,
) -> Result<DirectStats> {
    let params = DirectParams {
        area_samples: cfg.area_samples,
        ..DirectParams::default()
    };
    let window = p.window::<TexelState>(cfg);
    let stage = Stage::new(mode, "direct", state.tile_count() as u64, "tiles");
    let sums = map_tiles(state, geom, window, |t, g, st| {
        // a stop was asked for: skip the rest, the stage's result is not used
        if interrupt::requested() {
            return TileSums::default();
        }
        let ctx = TileCtx::new(p, charts, cfg.seed, &params, t, g);
        let s = ctx.run(st);
        stage.inc(1);
        s
    })?;
    interrupt::check(interrupt::NOTHING_SAVED)?;
    stage.finish();
    let (mut e, mut a, mut stats) = (Vec3::ZERO, 0.0f64, DirectStats::default());
    for s in &sums {
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
    Ok(stats)
}

/// One tile's sums.
#[derive(Debug, Clone, Default)]
struct TileSums {
    sum: Vec3,
    area: f64,
    texels: u64,
    first_pass: u64,
    dense: u64,
    dense_k: Vec<u64>,
}

/// One tile being lit: its geometry, footprints, charts and random keys.
struct TileCtx<'a> {
    p: &'a Prepared,
    params: &'a DirectParams,
    g: &'a [TexelGeom],
    /// Per texel of the tile, its footprint (centers only where uncovered) and chart.
    fps: Vec<Footprint>,
    chart: Vec<u32>,
    seed: u64,
    first_key: u64,
    ts: usize,
}

impl<'a> TileCtx<'a> {
    fn new(
        p: &'a Prepared,
        charts: &Charts,
        seed: u64,
        params: &'a DirectParams,
        t: usize,
        g: &'a [TexelGeom],
    ) -> TileCtx<'a> {
        let slot = p.layout.slot_of_tile(t as u32);
        let shape = p.shape_ref(slot);
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
            g,
            fps,
            chart,
            seed,
            first_key: t as u64 * p.layout.tile_texels() as u64,
            ts: p.layout.tile_size as usize,
        }
    }

    /// Every covered texel's `E_d` into `st`.
    fn run(&self, st: &mut [TexelState]) -> TileSums {
        let lights = self.p.scene.emitters.len();
        let n = self.g.len();
        // per texel and light: the first pass's irradiance and verdict (None: not run)
        let mut first: Vec<Option<(Vec3, Reach)>> = vec![None; n * lights];
        let mut sums = TileSums {
            dense_k: vec![0; lights],
            ..Default::default()
        };
        for off in (0..n).filter(|&o| self.on_lattice(o) && self.g[o].covered()) {
            self.first_pass(off, &mut first[off * lights..(off + 1) * lights]);
            sums.first_pass += 1;
        }
        for off in (0..n).filter(|&o| !self.on_lattice(o) && self.g[o].covered()) {
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
            let mut dense = false;
            for k in 0..lights {
                let (ek, reach) = first[off * lights + k].expect("every covered texel is lit");
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
                e += if redo {
                    dense = true;
                    sums.dense_k[k] += 1;
                    self.estimate(off, k, true).0
                } else {
                    ek
                };
            }
            st[off].e_d = e.to_array();
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

    fn on_lattice(&self, off: usize) -> bool {
        let (x, y) = self.xy(off);
        let s = LATTICE as usize;
        let on = |v: usize| v % s == 0 || v == self.ts - 1;
        on(x) && on(y)
    }

    /// Light `k` at texel `off`: the first pass, or with `dense` the dense estimate.
    fn estimate(&self, off: usize, k: usize, dense: bool) -> (Vec3, Reach) {
        let key = (self.seed, self.first_key + off as u64);
        let p = self.p;
        emitter_irradiance(
            &p.scene,
            &p.accel,
            k,
            &self.fps[off],
            self.params,
            key,
            dense,
        )
    }

    fn first_pass(&self, off: usize, row: &mut [Option<(Vec3, Reach)>]) {
        for (k, r) in row.iter_mut().enumerate() {
            *r = Some(self.estimate(off, k, false));
        }
    }

    /// Per light, the verdict of the four lattice texels around `off` if they are all
    /// covered, on `off`'s chart, and agree on lit or dark; else `None`.
    fn lattice_verdict(
        &self,
        off: usize,
        first: &[Option<(Vec3, Reach)>],
        lights: usize,
    ) -> Option<Vec<Reach>> {
        let (x, y) = self.xy(off);
        let s = LATTICE as usize;
        let (x0, y0) = (x / s * s, y / s * s);
        let (x1, y1) = ((x0 + s).min(self.ts - 1), (y0 + s).min(self.ts - 1));
        let corners = [(x0, y0), (x1, y0), (x0, y1), (x1, y1)].map(|(a, b)| b * self.ts + a);
        let chart = self.chart[off];
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
    fn take_verdict(&self, off: usize, verdict: &[Reach], row: &mut [Option<(Vec3, Reach)>]) {
        for (k, (r, v)) in row.iter_mut().zip(verdict).enumerate() {
            let e = match v {
                Reach::Lit => emitter_unoccluded(&self.p.scene, k, &self.fps[off]),
                _ => Vec3::ZERO,
            };
            *r = Some((e, *v));
        }
    }

    /// Whether a neighbour of `off` in the tile found a hard shadow edge of light `k` (a
    /// point, spot or directional light).
    fn near_hard_edge(
        &self,
        off: usize,
        k: usize,
        first: &[Option<(Vec3, Reach)>],
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
