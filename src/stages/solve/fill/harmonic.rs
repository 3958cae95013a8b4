//! Harmonic relaxation of the filled texels: the wave ([`super`]) gives every unobserved texel
//! a first value; this replaces those values by the solution of Laplace's equation over the
//! unobserved texels of each chart, the observed texels held fixed as boundary values (the
//! 5-point stencil; a chart's edge and the gutter are free, zero-flux boundaries).
//!
//! **Why.** The wave copies each border texel straight inwards, so a hole is filled with
//! streaks and X-shaped seams carrying single border texels' noise and colour casts. Such holes
//! are what relit views show: the ceiling above an area light, which no camera can see but
//! which a view relit without that light does. The harmonic fill is the smoothest interpolant
//! of the whole border (least Dirichlet energy), stays within the border's range (maximum
//! principle), and reproduces a linear gradient exactly, so a relit view shows such a hole
//! as a smooth continuation of its border.
//!
//! **How.** Conjugate gradients over the unobserved texels of the texture at once (the system is
//! symmetric positive definite on every hole that touches an observed texel; a connected set
//! that touches none, such as a chart nobody saw, which holds the shape's mean, is left out),
//! started from the wave's values, per RGB channel. The product runs in parallel per texel
//! and the dot products in f64 in the texels' row-major order, so the result is bit-identical
//! for any thread count and for a texture held whole or in tiles (the system is assembled the
//! same way from either). Written by hand because the system is a masked stencil over
//! chart-aware atlas texels: assembling it for a sparse-solver crate would take the same code
//! as the solver itself.
//!
//! **Cost.** At most [`BYTES_PER_UNKNOWN`] bytes per texel the wave filled while the solve runs
//! (the texture itself stays in its tiles); a texture whose system would not fit in the run's
//! scratch budget (`memory_budget_mib / 4`: 1.7M such texels at the default) keeps the wave's
//! values. CG needs on the order of a hole's width in iterations, capped at [`MAX_ITERATIONS`];
//! each costs a few nanoseconds per unknown (`cargo bench --bench update -- fill`).

use super::{FillTexel, FILLED_MARK, MEAN_MARK};
use crate::atlas::texture::{Block, Grid, SlotTexture};
use crate::base::error::Result;
use crate::stages::solve::KD_MAX;
use glam::Vec3;
use rayon::prelude::*;

/// Most conjugate-gradient iterations per texture.
pub const MAX_ITERATIONS: usize = 1000;

/// Stop when every channel's residual norm is this fraction of its right side's norm.
const TOLERANCE: f64 = 1e-5;

/// No neighbour in this direction (or a fixed one).
const NO: u32 = u32::MAX;

/// The linear system over the unobserved texels, in row-major order.
struct System {
    /// Texel index `y * width + x` of each unknown, ascending.
    index: Vec<u64>,
    /// Unknown neighbours (positions in `index`), [`NO`] where none.
    nbr: Vec<[u32; 4]>,
    /// Same-chart neighbours, unknown or observed (the diagonal).
    diag: Vec<f32>,
    /// Sum of the observed same-chart neighbours' `K_d` (the right side).
    b: Vec<Vec3>,
    /// The wave's values (the start).
    x0: Vec<Vec3>,
}

/// Bytes per unknown at the peak (the rows as assembled beside their sorted copy, then the
/// system and the four vectors of the solve), a bound used against the budget.
const BYTES_PER_UNKNOWN: u64 = 160;

/// Relaxes the texels of `tex` the wave filled (marked [`FILLED_MARK`]) to the harmonic fill,
/// if their system fits in `budget` bytes; returns false if it did not fit (the texture keeps
/// the wave's values), true otherwise (also when there was nothing to relax).
pub(super) fn relax(tex: &mut SlotTexture<FillTexel>, budget: u64) -> Result<bool> {
    let g = tex.grid;
    let counts: Vec<u64> = (0..g.tiles())
        .into_par_iter()
        .map(|t| {
            Ok(tex
                .tile(t)?
                .iter()
                .filter(|v| v.round == FILLED_MARK)
                .count() as u64)
        })
        .collect::<Result<_>>()?;
    let unknowns: u64 = counts.iter().sum();
    if unknowns.saturating_mul(BYTES_PER_UNKNOWN) > budget {
        return Ok(false);
    }
    // only the tiles that hold unknowns are read again and written back
    let busy: Vec<u32> = (0..g.tiles()).filter(|&t| counts[t as usize] > 0).collect();
    if busy.is_empty() {
        return Ok(true);
    }
    let sys = assemble(tex, &busy)?;
    let x = solve(&sys);
    write_back(tex, &busy, &sys.index, &x)?;
    Ok(true)
}

/// One unknown as a tile sees it: its index, start, diagonal, right side and the indices of
/// its unknown neighbours (`u64::MAX` where none).
type Row = (u64, Vec3, f32, Vec3, [u64; 4]);

/// The system over the unknowns of tiles `busy`.
fn assemble(tex: &SlotTexture<FillTexel>, busy: &[u32]) -> Result<System> {
    let g = tex.grid;
    let per_tile: Vec<Vec<Row>> = busy
        .par_iter()
        .map(|&t| tile_rows(&g, &tex.block(t, 1), t))
        .collect();
    tex.check()?;
    let mut rows: Vec<Row> = per_tile.into_iter().flatten().collect();
    rows.sort_unstable_by_key(|r| r.0);
    let index: Vec<u64> = rows.iter().map(|r| r.0).collect();
    let nbr = rows
        .iter()
        .map(|r| {
            r.4.map(|j| match index.binary_search(&j) {
                Ok(p) if j != u64::MAX => p as u32,
                _ => NO,
            })
        })
        .collect();
    let mut sys = System {
        nbr,
        diag: rows.iter().map(|r| r.2).collect(),
        b: rows.iter().map(|r| r.3).collect(),
        x0: rows.iter().map(|r| r.1).collect(),
        index,
    };
    freeze_unanchored(&mut sys);
    Ok(sys)
}

/// Takes out of the system every connected set of unknowns that touches no observed texel (a
/// chart nobody saw, which holds the shape's mean; a texel joined to its chart only across a
/// corner): its equations only say "constant", already true, and in floating point their
/// rounding residue is not in the range of the matrix, so conjugate gradients would drift
/// along the constant they leave free (a grey chart turned magenta). Their rows become empty
/// and their values stay as the wave left them.
fn freeze_unanchored(sys: &mut System) {
    let n = sys.nbr.len();
    let mut parent: Vec<u32> = (0..n as u32).collect();
    fn root(parent: &mut [u32], mut i: u32) -> u32 {
        while parent[i as usize] != i {
            parent[i as usize] = parent[parent[i as usize] as usize];
            i = parent[i as usize];
        }
        i
    }
    for i in 0..n {
        for &j in &sys.nbr[i] {
            if j != NO {
                let (a, b) = (root(&mut parent, i as u32), root(&mut parent, j));
                parent[a.max(b) as usize] = a.min(b);
            }
        }
    }
    let mut anchored = vec![false; n];
    for i in 0..n {
        let unknown = sys.nbr[i].iter().filter(|&&j| j != NO).count() as f32;
        if sys.diag[i] > unknown {
            anchored[root(&mut parent, i as u32) as usize] = true;
        }
    }
    for i in 0..n {
        if !anchored[root(&mut parent, i as u32) as usize] {
            (sys.nbr[i], sys.diag[i], sys.b[i]) = ([NO; 4], 0.0, Vec3::ZERO);
        }
    }
}

/// The rows of tile `t`'s unknowns, read from its block (halo 1).
fn tile_rows(g: &Grid, block: &Block<FillTexel>, t: u32) -> Vec<Row> {
    let w = g.width as u64;
    let mut rows = Vec::new();
    for (_, x, y) in g.texels_of(t) {
        let v = block.at(x, y);
        if v.round != FILLED_MARK {
            continue;
        }
        let (mut diag, mut b, mut unknown) = (0.0f32, Vec3::ZERO, [u64::MAX; 4]);
        let around = [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)];
        for (k, (dx, dy)) in around.into_iter().enumerate() {
            let (nx, ny) = (x as i64 + dx, y as i64 + dy);
            if nx < 0 || ny < 0 || nx >= g.width as i64 || ny >= g.height as i64 {
                continue;
            }
            let m = block.at(nx as u32, ny as u32);
            if m.chart != v.chart || m.round == MEAN_MARK {
                continue;
            }
            diag += 1.0;
            match m.round {
                FILLED_MARK => unknown[k] = ny as u64 * w + nx as u64,
                _ => b += m.kd,
            }
        }
        rows.push((y as u64 * w + x as u64, v.kd, diag, b, unknown));
    }
    rows
}

/// `A p`: the diagonal times `p` minus the unknown neighbours' `p`.
fn apply(sys: &System, p: &[Vec3], out: &mut Vec<Vec3>) {
    (0..p.len())
        .into_par_iter()
        .map(|i| {
            let mut s = p[i] * sys.diag[i];
            for &j in &sys.nbr[i] {
                if j != NO {
                    s -= p[j as usize];
                }
            }
            s
        })
        .collect_into_vec(out);
}

/// Texels per partial sum of [`dot`]: fixed, so the sums do not depend on the thread count.
const DOT_CHUNK: usize = 4096;

/// Per-channel dot product in f64: partial sums over fixed chunks in parallel, added in order.
fn dot(a: &[Vec3], b: &[Vec3]) -> [f64; 3] {
    let partial: Vec<[f64; 3]> = a
        .par_chunks(DOT_CHUNK)
        .zip(b.par_chunks(DOT_CHUNK))
        .map(|(a, b)| {
            let mut s = [0.0f64; 3];
            for (a, b) in a.iter().zip(b) {
                for c in 0..3 {
                    s[c] += a[c] as f64 * b[c] as f64;
                }
            }
            s
        })
        .collect();
    partial
        .iter()
        .fold([0.0; 3], |s, p| [s[0] + p[0], s[1] + p[1], s[2] + p[2]])
}

/// `y += k * x` per channel, in parallel.
fn axpy(y: &mut [Vec3], k: Vec3, x: &[Vec3]) {
    y.par_iter_mut().zip(x).for_each(|(y, x)| *y += k * *x);
}

/// Conjugate gradients from the wave's values; returns the relaxed values, clamped to the
/// bounds of `K_d`.
fn solve(sys: &System) -> Vec<Vec3> {
    let n = sys.index.len();
    let mut x = sys.x0.clone();
    let mut q = Vec::with_capacity(n);
    apply(sys, &x, &mut q);
    let mut r: Vec<Vec3> = sys.b.iter().zip(&q).map(|(b, q)| *b - *q).collect();
    let mut p = r.clone();
    let bb = dot(&sys.b, &sys.b);
    let floor = 1e-14 * n as f64;
    let done = |rr: &[f64; 3]| (0..3).all(|c| rr[c] <= (TOLERANCE * TOLERANCE * bb[c]).max(floor));
    let mut rr = dot(&r, &r);
    for _ in 0..MAX_ITERATIONS {
        if done(&rr) {
            break;
        }
        apply(sys, &p, &mut q);
        let pq = dot(&p, &q);
        let alpha = Vec3::from_array(std::array::from_fn(|c| match pq[c] > 0.0 {
            true => (rr[c] / pq[c]) as f32,
            false => 0.0,
        }));
        axpy(&mut x, alpha, &p);
        axpy(&mut r, -alpha, &q);
        let next = dot(&r, &r);
        let beta = Vec3::from_array(std::array::from_fn(|c| match rr[c] > 0.0 {
            true => (next[c] / rr[c]) as f32,
            false => 0.0,
        }));
        p.par_iter_mut()
            .zip(&r)
            .for_each(|(p, r)| *p = *r + beta * *p);
        rr = next;
    }
    x.into_iter()
        .map(|v| v.clamp(Vec3::ZERO, Vec3::splat(KD_MAX)))
        .collect()
}

/// Writes the relaxed values into the tiles `busy` (those that hold unknowns).
fn write_back(
    tex: &mut SlotTexture<FillTexel>,
    busy: &[u32],
    index: &[u64],
    x: &[Vec3],
) -> Result<()> {
    let g = tex.grid;
    for &t in busy {
        let mut tile = tex.tile(t)?;
        for (off, px, py) in g.texels_of(t) {
            if tile[off].round != FILLED_MARK {
                continue;
            }
            if let Ok(i) = index.binary_search(&(py as u64 * g.width as u64 + px as u64)) {
                tile[off].kd = x[i];
            }
        }
        tex.set_tile(t, tile)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atlas::texture::Scratch;
    use crate::atlas::uv::NONE;

    use crate::atlas::testing::grid;

    /// A texture holding `vals` (row-major).
    fn texture(g: Grid, s: &Scratch, vals: &[FillTexel]) -> SlotTexture<FillTexel> {
        crate::atlas::testing::texture(g, s, |x, y| vals[(y * g.width + x) as usize])
    }

    fn texel(kd: Vec3, chart: u32, filled: bool) -> FillTexel {
        FillTexel {
            kd,
            chart,
            round: if filled { FILLED_MARK } else { 0 },
        }
    }

    /// Closed form: the 5-point Laplacian of a linear function is zero, so a hole inside
    /// observed texels that hold a linear gradient is filled with that gradient exactly
    /// (whatever the wave left there), held whole or in tiles.
    #[test]
    fn a_hole_in_a_linear_gradient_is_filled_with_the_gradient() {
        let (w, h) = (40u32, 30u32);
        let f = |x: u32, y: u32| {
            let (x, y) = (x as f32, y as f32);
            Vec3::new(0.1 + 0.015 * x, 0.8 - 0.02 * y, 0.2 + 0.01 * x + 0.005 * y)
        };
        // an L-shaped hole; the wave's guess is a constant far from the truth
        let hole = |x: u32, y: u32| {
            (5..30).contains(&x) && (4..12).contains(&y)
                || (5..14).contains(&x) && (4..26).contains(&y)
        };
        let vals: Vec<FillTexel> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                match hole(x, y) {
                    true => texel(Vec3::splat(0.9), 0, true),
                    false => texel(f(x, y), 0, false),
                }
            })
            .collect();
        let dir = tempfile::tempdir().unwrap();
        for budget in [1u64 << 30, 1] {
            let mut tex = texture(grid(w, h, 8), &Scratch::new(dir.path(), budget), &vals);
            assert!(relax(&mut tex, u64::MAX).unwrap());
            let out = tex.to_vec();
            let worst = (0..w * h)
                .filter(|&i| hole(i % w, i / w))
                .map(|i| (out[i as usize].kd - f(i % w, i / w)).abs().max_element())
                .fold(0.0f32, f32::max);
            assert!(worst < 1e-4, "budget {budget}: worst {worst}");
        }
    }

    /// A strip between two observed columns of different charts' neighbours: each chart's
    /// unknowns interpolate only their own chart's border (a ramp along the strip), the gutter
    /// and the other chart do not pull them, and observed texels never change.
    #[test]
    fn the_relaxation_keeps_to_each_chart_and_leaves_observed_texels() {
        // rows 0..3: chart 0, observed 0.2 at x = 0 and 0.8 at x = 10, unknown between;
        // row 3: gutter; rows 4..6: chart 1, all unknown but x = 0 observed 1.0
        let (w, h) = (11u32, 7u32);
        let vals: Vec<FillTexel> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                match (y, x) {
                    (3, _) => texel(Vec3::splat(5.0), NONE, false),
                    (0..=2, 0) => texel(Vec3::splat(0.2), 0, false),
                    (0..=2, 10) => texel(Vec3::splat(0.8), 0, false),
                    (0..=2, _) => texel(Vec3::splat(0.5), 0, true),
                    (_, 0) => texel(Vec3::ONE, 1, false),
                    _ => texel(Vec3::splat(0.3), 1, true),
                }
            })
            .collect();
        let dir = tempfile::tempdir().unwrap();
        let mut tex = texture(grid(w, h, 4), &Scratch::new(dir.path(), 1 << 30), &vals);
        assert!(relax(&mut tex, u64::MAX).unwrap());
        let out = tex.to_vec();
        for y in 0..3 {
            for x in 0..w {
                let want = 0.2 + 0.6 * x as f32 / 10.0;
                let got = out[(y * w + x) as usize].kd.x;
                assert!((got - want).abs() < 1e-4, "({x}, {y}): {got} vs {want}");
            }
        }
        for x in 0..w {
            assert_eq!(out[(3 * w + x) as usize].kd, Vec3::splat(5.0), "gutter");
            for y in 4..7 {
                let got = out[(y * w + x) as usize].kd;
                assert!(
                    (got - Vec3::ONE).abs().max_element() < 1e-4,
                    "({x}, {y}): {got}"
                );
            }
        }
    }

    /// A chart nobody saw holds the shape's mean, and must keep it bit for bit while a hole of
    /// another chart is relaxed beside it (regression: inside the system, CG drifts along such
    /// a set's free constant and a grey face turns magenta).
    #[test]
    fn a_chart_nobody_saw_keeps_the_shapes_mean() {
        let (w, h) = (24u32, 12u32);
        let mean = Vec3::new(0.3137, 0.4711, 0.0917);
        let vals: Vec<FillTexel> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                match (x, y) {
                    (12.., _) => texel(mean, 1, true),
                    (0, _) => texel(Vec3::splat(0.05 + 0.07 * y as f32), 0, false),
                    (11, _) => texel(Vec3::new(0.9, 0.1, 0.6), 0, false),
                    _ => texel(Vec3::splat(0.5), 0, true),
                }
            })
            .collect();
        let dir = tempfile::tempdir().unwrap();
        let mut tex = texture(grid(w, h, 5), &Scratch::new(dir.path(), 1 << 30), &vals);
        assert!(relax(&mut tex, u64::MAX).unwrap());
        let out = tex.to_vec();
        for (i, v) in out.iter().enumerate() {
            let (x, y) = (i as u32 % w, i as u32 / w);
            if x >= 12 {
                assert_eq!(v.kd, mean, "({x}, {y})");
            }
        }
        assert_ne!(
            out[(5 * w + 5) as usize].kd,
            Vec3::splat(0.5),
            "the hole was relaxed"
        );
    }

    /// A texture whose system does not fit in the budget keeps the wave's values, bit for bit;
    /// one byte more per unknown than the bound relaxes it.
    #[test]
    fn a_system_over_the_budget_keeps_the_waves_values() {
        let (w, h) = (10u32, 3u32);
        let vals: Vec<FillTexel> = (0..w * h)
            .map(|i| match i % w {
                0 => texel(Vec3::splat(0.2), 0, false),
                _ => texel(Vec3::splat(0.7), 0, true),
            })
            .collect();
        let unknowns = (w - 1) as u64 * h as u64;
        let dir = tempfile::tempdir().unwrap();
        let s = Scratch::new(dir.path(), 1 << 30);
        let mut tex = texture(grid(w, h, 4), &s, &vals);
        assert!(!relax(&mut tex, unknowns * BYTES_PER_UNKNOWN - 1).unwrap());
        assert_eq!(tex.to_vec(), vals);
        assert!(relax(&mut tex, unknowns * BYTES_PER_UNKNOWN).unwrap());
        let out = tex.to_vec();
        assert!(
            (out[5].kd - Vec3::splat(0.2)).abs().max_element() < 1e-4,
            "{}",
            out[5].kd
        );
    }
}
