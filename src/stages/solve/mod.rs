//! The per-texel solver, method steps 4-9: initial E_i, K_d from eqs. (3)-(5) with the bound
//! correction, the comparison (6)-(7) and the update (8)-(9). Every texel is an independent
//! one-parameter problem, so each function here is a pure pass over one tile's records;
//! statistics come back per tile and are summed in tile order (bit-identical for any thread
//! count). Unobserved texels get K_d from observed neighbours of the same chart.

use crate::atlas::store::{flags, Layout, TexelGeom, TexelState};
use crate::atlas::store::{map_tiles, TileStore};
use crate::atlas::texture::Scratch;
use crate::atlas::uv::Charts;
use crate::base::error::Result;
use crate::base::progress::Tick;
use crate::config::{Config, UpdateRule};
use crate::scene::luminance;
use glam::Vec3;
use std::f32::consts::PI;

mod fill;
pub use fill::{fill_unobserved, fill_unobserved_all, Filled};

/// The physical upper bound of K_d used by the correction of eq. (5).
pub const KD_MAX: f32 = 1.0;

fn v(a: [f32; 3]) -> Vec3 {
    Vec3::from_array(a)
}

/// Step 4: the initial secondary irradiance, a share of the direct irradiance, or where a
/// texel has no direct light, a share of the scene's mean irradiance `mean_e`.
pub fn init_indirect_tile(state: &mut [TexelState], geom: &[TexelGeom], share: f32, mean_e: Vec3) {
    for (s, g) in state.iter_mut().zip(geom) {
        if !g.covered() {
            continue;
        }
        let ed = v(s.e_d);
        let ei = if ed.max_element() > 0.0 {
            ed * share
        } else {
            mean_e * share
        };
        s.e_i = ei.to_array();
    }
}

/// Eqs. (3)-(5) for one channel: `K_d = pi L / (E_d + E_i)`, and where that exceeds the bound
/// `K_d0`, `K_d = K_d0` with `E_i = (pi L - K_d0 E_d) / K_d0`. Returns `(K_d, E_i, clamped)`.
pub fn kd_channel(l: f32, e_d: f32, e_i: f32) -> (f32, f32, bool) {
    let pl = PI * l.max(0.0);
    let e_i = e_i.max(0.0);
    let e = e_d + e_i;
    if pl == 0.0 {
        return (0.0, e_i, false);
    }
    if e > 0.0 && pl / e <= KD_MAX {
        return (pl / e, e_i, false);
    }
    (KD_MAX, ((pl - KD_MAX * e_d) / KD_MAX).max(0.0), true)
}

/// K_d of every observed texel of a tile from its current E_i (eqs. 3-5); E_i is corrected
/// where the bound applies. Returns how many texels were clamped.
pub fn kd_tile(state: &mut [TexelState], geom: &[TexelGeom]) -> u64 {
    let mut clamped = 0;
    for (s, g) in state.iter_mut().zip(geom) {
        if !g.covered() || s.flags & flags::OBSERVED == 0 {
            continue;
        }
        let mut any = false;
        for c in 0..3 {
            let (kd, ei, cl) = kd_channel(s.l_orig[c], s.e_d[c], s.e_i[c]);
            s.k_d[c] = kd;
            s.e_i[c] = ei;
            any |= cl;
        }
        clamped += any as u64;
    }
    clamped
}

/// Error statistics of one tile, summed over observed texels.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ErrorSums {
    pub texels: u64,
    pub sum_rel: f64,
    pub sum_rel2: f64,
    pub max_rel: f64,
    pub sum_f2: f64,
}

impl ErrorSums {
    pub fn add(&mut self, o: &ErrorSums) {
        self.texels += o.texels;
        self.sum_rel += o.sum_rel;
        self.sum_rel2 += o.sum_rel2;
        self.max_rel = self.max_rel.max(o.max_rel);
        self.sum_f2 += o.sum_f2;
    }
    pub fn rms_rel(&self) -> f64 {
        (self.sum_rel2 / self.texels.max(1) as f64).sqrt()
    }
    pub fn mean_rel(&self) -> f64 {
        self.sum_rel / self.texels.max(1) as f64
    }
    pub fn rms_residual(&self) -> f64 {
        (self.sum_f2 / self.texels.max(1) as f64).sqrt()
    }
}

/// Steps 7 and 9 for one tile. `accum` holds the photon-traced secondary irradiance of this
/// iteration. Compares `L_render = K_d/pi (E_d + E_i_traced)` with `L_orig` (eqs. 6-7: the
/// per-texel relative luminance error goes to `error`), then sets the next E_i:
/// `Paper`: `E_i = E_i_traced + alpha_n K_d/pi F` (eqs. 8-9 with `F = L_orig - L_render`);
/// `FixedPoint`: `E_i = E_i_traced`; `Relaxed`: `E_i += beta (E_i_traced - E_i)`.
/// Unobserved texels just take the traced E_i.
pub fn compare_update_tile(
    state: &mut [TexelState],
    geom: &[TexelGeom],
    rule: UpdateRule,
    alpha_n: f32,
    beta: Vec3,
) -> ErrorSums {
    let mut sums = ErrorSums::default();
    for (s, g) in state.iter_mut().zip(geom) {
        if !g.covered() {
            continue;
        }
        let traced = v(s.accum);
        let kd = v(s.k_d);
        let l_render = kd / PI * (v(s.e_d) + traced);
        let l_orig = v(s.l_orig);
        let f = l_orig - l_render;
        if s.flags & flags::OBSERVED != 0 {
            let yo = luminance(l_orig) as f64;
            let fy = luminance(f) as f64;
            let rel = if yo > 0.0 { fy.abs() / yo } else { 0.0 };
            s.error = rel as f32;
            sums.texels += 1;
            sums.sum_rel += rel;
            sums.sum_rel2 += rel * rel;
            sums.max_rel = sums.max_rel.max(rel);
            sums.sum_f2 += fy * fy;
            let next = match rule {
                UpdateRule::Paper => traced + alpha_n * kd / PI * f,
                UpdateRule::FixedPoint => traced,
                UpdateRule::Relaxed | UpdateRule::Secant => v(s.e_i) + beta * (traced - v(s.e_i)),
            };
            s.e_i = next.max(Vec3::ZERO).to_array();
        } else {
            s.error = 0.0;
            s.e_i = traced.to_array();
        }
    }
    sums
}

/// Per channel, the sums over observed covered texels of the current E_i and of the traced
/// E_i (`accum` after a finished pass): one point `(E, T(E))` of the scene-wide map.
pub fn channel_sums(state: &[TexelState], geom: &[TexelGeom]) -> ([f64; 3], [f64; 3]) {
    let (mut e, mut t) = ([0.0f64; 3], [0.0f64; 3]);
    for (s, g) in state.iter().zip(geom) {
        if g.covered() && s.flags & flags::OBSERVED != 0 {
            for c in 0..3 {
                e[c] += s.e_i[c] as f64;
                t[c] += s.accum[c] as f64;
            }
        }
    }
    (e, t)
}

/// Smallest and largest step [`secant_beta`] returns.
pub const SECANT_BETA: (f32, f32) = (0.2, 1.0);

/// The secant step per channel (see [`UpdateRule::Secant`]): from the points `(E, T)` of the
/// previous and the current iteration, the slope `g = dT / dE` and `beta = 1 / (1 - g)`,
/// clamped to [`SECANT_BETA`]; `fallback` where there is no previous point or the slope is
/// undefined or says the map is not contracting (`g >= 1`).
pub fn secant_beta(
    prev: Option<([f64; 3], [f64; 3])>,
    cur: ([f64; 3], [f64; 3]),
    fallback: f32,
) -> Vec3 {
    let Some((pe, pt)) = prev else {
        return Vec3::splat(fallback);
    };
    let (ce, ct) = cur;
    let mut b = [fallback; 3];
    for c in 0..3 {
        let de = ce[c] - pe[c];
        // A flat (or NaN) step says nothing about the slope.
        if de.is_nan() || de.abs() <= 1e-9 * ce[c].abs().max(1e-30) {
            continue;
        }
        let g = (ct[c] - pt[c]) / de;
        if g.is_finite() && g < 1.0 {
            b[c] = ((1.0 / (1.0 - g)) as f32).clamp(SECANT_BETA.0, SECANT_BETA.1);
        }
    }
    Vec3::from_array(b)
}

/// `alpha_n = alpha_0 / (1 + n)`.
pub fn alpha(alpha0: f32, n: u32) -> f32 {
    alpha0 / (1.0 + n as f32)
}

/// Steps 3-5 over every tile, then the fill of unobserved texels: `K_d` from the current
/// `E_i` everywhere, except in the slots `pinned` gives an albedo (known diffuse shapes),
/// which keep it; a slot no photo saw takes the mean of the observed slots of its material
/// (`groups`, see [`fill::shared_fill`]). Returns `(clamped texels, what the fill filled)`.
pub fn kd_step(
    layout: &Layout,
    charts: &Charts,
    geom: &TileStore<TexelGeom>,
    (state, window): (&mut TileStore<TexelState>, usize),
    (pinned, groups): (&[Option<Vec3>], &[Option<u32>]),
    scratch: &Scratch,
    tick: Tick,
) -> Result<(u64, Filled)> {
    let clamped: u64 = map_tiles(state, geom, window, |_, g, s| {
        let c = kd_tile(s, g);
        tick(1);
        c
    })?
    .iter()
    .sum();
    let (mut filled, observed) = fill_unobserved_all(layout, charts, geom, state, scratch, tick)?;
    let shared = fill::shared_fill(groups, &observed);
    filled.shared_shapes = shared.iter().flatten().count() as u64;
    let set: Vec<Option<Vec3>> = (pinned.iter().zip(&shared))
        .map(|(p, s)| p.or(*s))
        .collect();
    if set.iter().any(Option::is_some) {
        map_tiles(state, geom, window, |t, g, s| {
            if let Some(k) = set[layout.slot_of_tile(t as u32)] {
                for (g, s) in g.iter().zip(s.iter_mut()) {
                    if g.covered() {
                        s.k_d = k.to_array();
                    }
                }
            }
        })?;
    }
    Ok((clamped, filled))
}

/// What one update step (steps 7 and 9) did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Update {
    pub errors: ErrorSums,
    /// The relaxation step used per channel.
    pub beta: Vec3,
    /// Per channel, the sums over observed texels of E_i before the update and of the traced
    /// E_i (computed for the `secant` rule only; zero otherwise).
    pub sum_e_i: [f64; 3],
    pub sum_traced: [f64; 3],
}

/// Steps 7 and 9 over every tile for iteration `n`, after `accum` holds the estimated `E_i`:
/// compare and update `E_i` by `rule` (with `cfg`'s step sizes). `prev` is the previous
/// iteration's `(sum_e_i, sum_traced)` (the secant rule steps from it).
#[inline(never)] // a stage entry tools/icount.py measures
pub fn update_step(
    cfg: &Config,
    rule: UpdateRule,
    n: u32,
    prev: Option<([f64; 3], [f64; 3])>,
    geom: &TileStore<TexelGeom>,
    (state, window): (&mut TileStore<TexelState>, usize),
    tick: Tick,
) -> Result<Update> {
    let a = alpha(cfg.alpha0, n);
    let (mut sum_e_i, mut sum_traced) = ([0.0f64; 3], [0.0f64; 3]);
    let beta = if rule == UpdateRule::Secant {
        for (e, t) in map_tiles(state, geom, window, |_, g, s| channel_sums(s, g))? {
            for c in 0..3 {
                sum_e_i[c] += e[c];
                sum_traced[c] += t[c];
            }
        }
        secant_beta(prev, (sum_e_i, sum_traced), cfg.relaxation)
    } else {
        Vec3::splat(cfg.relaxation)
    };
    let sums = map_tiles(state, geom, window, |_, g, s| {
        let e = compare_update_tile(s, g, rule, a, beta);
        tick(1);
        e
    })?;
    let mut errors = ErrorSums::default();
    for s in &sums {
        errors.add(s);
    }
    Ok(Update {
        errors,
        beta,
        sum_e_i,
        sum_traced,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn secant_step_lands_a_linear_map_on_its_fixed_point() {
        // Per channel T(E) = a + g E, fixed point E* = a / (1 - g). Two points give the slope,
        // and E + beta (T(E) - E) must be E* whenever beta is not clamped.
        let (a, g) = ([3.0, 1.0, 2.0], [-0.5, -0.25, -2.0]);
        let t = |e: [f64; 3]| [0, 1, 2].map(|c| a[c] + g[c] * e[c]);
        let (e0, e1) = ([1.0, 1.0, 1.0], [2.0, 1.5, 0.5]);
        let beta = secant_beta(Some((e0, t(e0))), (e1, t(e1)), 0.5);
        for c in 0..3 {
            let want = 1.0 / (1.0 - g[c]);
            assert!((beta[c] as f64 - want).abs() < 1e-6, "{c}: {beta}");
            let next = e1[c] + beta[c] as f64 * (t(e1)[c] - e1[c]);
            assert!((next - a[c] / (1.0 - g[c])).abs() < 1e-5, "{c}: {next}");
        }
        // No previous point, a flat step, or a non-contracting slope: the fallback; steep
        // slopes are clamped.
        assert_eq!(secant_beta(None, (e1, t(e1)), 0.5), Vec3::splat(0.5));
        assert_eq!(
            secant_beta(Some((e1, t(e1))), (e1, t(e1)), 0.4),
            Vec3::splat(0.4)
        );
        let up = |e: [f64; 3]| e.map(|x| 1.0 + 1.5 * x);
        assert_eq!(
            secant_beta(Some((e0, up(e0))), (e1, up(e1)), 0.3),
            Vec3::splat(0.3)
        );
        let steep = |e: [f64; 3]| e.map(|x| 1.0 - 20.0 * x);
        assert_eq!(
            secant_beta(Some((e0, steep(e0))), (e1, steep(e1)), 0.5),
            Vec3::splat(SECANT_BETA.0)
        );
    }

    #[test]
    fn kd_inverts_the_rendering_equation_and_respects_the_bound() {
        // L = K_d/pi (E_d + E_i) with K_d = 0.4
        let (ed, ei) = (3.0, 1.0);
        let l = 0.4 / PI * (ed + ei);
        let (kd, e, c) = kd_channel(l, ed, ei);
        assert!((kd - 0.4).abs() < 1e-6 && e == ei && !c);
        // too little irradiance for what is seen: K_d lands on the bound, E_i corrected
        let l = 2.0 / PI * (ed + ei);
        let (kd, e, c) = kd_channel(l, ed, ei);
        assert!(c && kd == KD_MAX);
        assert!(
            (KD_MAX / PI * (ed + e) - l).abs() < 1e-5,
            "corrected E_i must reproduce L"
        );
        // black texel
        assert_eq!(kd_channel(0.0, ed, ei), (0.0, ei, false));
        // no light at all but seen lit: bound, E_i = pi L
        let (kd, e, c) = kd_channel(0.5, 0.0, 0.0);
        assert!(c && kd == KD_MAX && (e - PI * 0.5).abs() < 1e-6);
    }

    fn texel(l: Vec3, ed: Vec3, traced: Vec3, kd: Vec3) -> (TexelState, TexelGeom) {
        let s = TexelState {
            l_orig: l.to_array(),
            e_d: ed.to_array(),
            accum: traced.to_array(),
            k_d: kd.to_array(),
            weight: 1.0,
            flags: flags::OBSERVED,
            ..Default::default()
        };
        let g = TexelGeom {
            flags: flags::COVERED,
            area: 1.0,
            bin_area: 1.0,
            ..Default::default()
        };
        (s, g)
    }

    #[test]
    fn fixed_point_converges_to_the_true_albedo_in_a_furnace() {
        // A closed furnace of albedo rho lit by E_d: the traced secondary irradiance given
        // the current K_d is E_d * K_d / (1 - K_d); the photo shows rho/pi (E_d + E_i*).
        // The fixed-point map E_i -> traced(K_d(E_i)) has slope -rho/(1-rho) here, so it
        // contracts for rho < 1/2 (open scenes feed back far less than a furnace).
        let rho = 0.3f32;
        let ed = Vec3::splat(2.0);
        let ei_true = ed * rho / (1.0 - rho);
        let l = Vec3::splat(rho / PI) * (ed + ei_true);
        let (mut s, g) = texel(l, ed, Vec3::ZERO, Vec3::ZERO);
        let mut st = [s];
        init_indirect_tile(&mut st, &[g], 0.5, Vec3::ZERO);
        let mut errs = Vec::new();
        for n in 0..12 {
            kd_tile(&mut st, &[g]);
            let kd = st[0].k_d[0];
            st[0].accum = (ed * kd / (1.0 - kd)).to_array(); // the exact "photon pass"
            let e = compare_update_tile(
                &mut st,
                &[g],
                UpdateRule::FixedPoint,
                alpha(2.0, n),
                Vec3::ONE,
            );
            errs.push(e.max_rel);
        }
        kd_tile(&mut st, &[g]);
        s = st[0];
        assert!((s.k_d[0] - rho).abs() < 1e-4, "K_d {} vs {rho}", s.k_d[0]);
        assert!(errs.last().unwrap() < &1e-4, "{errs:?}");
        assert!(errs[0] > errs[3], "error must shrink: {errs:?}");
    }

    #[test]
    fn paper_update_moves_e_i_along_the_residual() {
        let (mut s, g) = texel(
            Vec3::splat(1.0),
            Vec3::splat(1.0),
            Vec3::splat(2.0),
            Vec3::splat(0.5),
        );
        s.e_i = [9.0; 3];
        let mut st = [s];
        let sums = compare_update_tile(&mut st, &[g], UpdateRule::Paper, 2.0, Vec3::ONE);
        let l_render = 0.5 / PI * (1.0 + 2.0);
        let f = 1.0 - l_render;
        let want = 2.0 + 2.0 * 0.5 / PI * f;
        assert!(
            (st[0].e_i[0] - want).abs() < 1e-5,
            "{} vs {want}",
            st[0].e_i[0]
        );
        assert!((sums.max_rel - f.abs() as f64).abs() < 1e-5);
        assert_eq!(sums.texels, 1);
    }
}
