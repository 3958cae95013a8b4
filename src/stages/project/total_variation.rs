//! Opt-in total-variation (TV) step between refinement passes (`[projection] tv_weight`):
//! after each pass the luminance map is replaced by its TV proximal point,
//! `argmin_u 1/2 |u - l|^2 + sum_x lambda_x |grad u|_x`, so that the passes become a proximal
//! gradient method for the least-squares fit of the photos plus a TV prior: uniform surfaces
//! lose the noise the passes would otherwise build up, steps (edges, shadow boundaries) stay.
//! `lambda_x = tv_weight * sigma * l_x` per channel, `sigma` the photos' relative noise in
//! that pass (mean over the views of [`super::shrink_residual`]'s estimate).
//!
//! At weights of 0.1-0.2 it lowers the albedo error of scenes of uniform surfaces (cbox,
//! mirror-cbox), but fine textures lose contrast (envmap, lights, open). Hence off by
//! default: it is for scenes of mostly uniform surfaces.
//!
//! Written by hand: the TV denoisers of image crates work on one rectangular image with one
//! weight; here the weight varies per texel and no difference is taken across a chart border
//! or to a texel no photo saw. Chambolle's dual projection (projected gradient on the dual
//! field, step [`TAU`] < 1/4), [`ITERATIONS`] steps.

use super::pass_texel::PassRecord;
use crate::atlas::store::TileStore;
use crate::atlas::store::{Layout, TexelGeom};
use crate::atlas::texture::{Scratch, SlotTexture};
use crate::atlas::uv::Charts;
use crate::atlas::uv::NONE;
use crate::base::error::{Error, Result};
use glam::Vec3;

/// Dual steps per proximal point.
pub const ITERATIONS: u32 = 50;
/// Dual step: below `2 / |grad|^2 = 1/4` (forward differences in 2-D).
const TAU: f32 = 0.24;

/// A texel as the step reads it.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct TvTexel {
    /// Radiance per channel.
    pub l: Vec3,
    /// TV weight per channel.
    pub lambda: Vec3,
    /// Its chart, [`NONE`] for a texel not observed (kept as it is).
    pub chart: u32,
}

/// Texels a proximal point of `iters` steps reads around a texel: each step spreads the dual
/// field one texel and the primal one more.
pub fn reach(iters: u32) -> u32 {
    2 * iters + 2
}

/// The forward-difference neighbours of texel `i` that count: right and down, when both are
/// of the same chart.
struct Links {
    right: Vec<bool>,
    down: Vec<bool>,
    w: usize,
}

impl Links {
    fn new(t: &[TvTexel], w: usize) -> Links {
        let n = t.len();
        let same = |i: usize, j: usize| j < n && t[i].chart != NONE && t[j].chart == t[i].chart;
        Links {
            right: (0..n).map(|i| i % w + 1 < w && same(i, i + 1)).collect(),
            down: (0..n).map(|i| same(i, i + w)).collect(),
            w,
        }
    }

    /// `(D^T p)_i` of the dual field `(px, py)`.
    fn div_t(&self, px: &[Vec3], py: &[Vec3], i: usize) -> Vec3 {
        let w = self.w;
        let mut d = Vec3::ZERO;
        if self.right[i] {
            d -= px[i];
        }
        if self.down[i] {
            d -= py[i];
        }
        if i % w > 0 && self.right[i - 1] {
            d += px[i - 1];
        }
        if i >= w && self.down[i - w] {
            d += py[i - w];
        }
        d
    }
}

/// The TV proximal point of a row-major `width x height` texture, per channel (isotropic TV;
/// see the module notes), by `iters` dual steps; texels without a chart keep their value and
/// the result is clamped at zero.
pub fn tv_prox(t: &[TvTexel], width: u32, height: u32, iters: u32) -> Result<Vec<Vec3>> {
    let (w, h) = (width as usize, height as usize);
    if t.len() != w * h {
        return Err(Error::internal(format!(
            "tv: {} texels for a {width}x{height} texture",
            t.len()
        )));
    }
    let links = Links::new(t, w);
    let (mut px, mut py) = (vec![Vec3::ZERO; t.len()], vec![Vec3::ZERO; t.len()]);
    let mut u: Vec<Vec3> = t.iter().map(|x| x.l).collect();
    for _ in 0..iters {
        for (i, ui) in u.iter_mut().enumerate() {
            *ui = t[i].l - links.div_t(&px, &py, i);
        }
        for i in 0..t.len() {
            let gx = if links.right[i] {
                u[i + 1] - u[i]
            } else {
                Vec3::ZERO
            };
            let gy = if links.down[i] {
                u[i + w] - u[i]
            } else {
                Vec3::ZERO
            };
            let (nx, ny) = (px[i] + TAU * gx, py[i] + TAU * gy);
            let norm = (nx * nx + ny * ny).map(f32::sqrt);
            let lam = t[i].lambda;
            let s = Vec3::select(
                norm.cmpgt(lam),
                lam / norm.max(Vec3::splat(1e-30)),
                Vec3::ONE,
            );
            (px[i], py[i]) = (nx * s, ny * s);
        }
    }
    Ok((0..t.len())
        .map(|i| match t[i].chart {
            NONE => t[i].l,
            _ => (t[i].l - links.div_t(&px, &py, i)).max(Vec3::ZERO),
        })
        .collect())
}

/// The TV step on every slot's observed texels, `lambda = rel * l_orig`: a slot's texture
/// whole if it fits in `scratch`'s budget, else tile by tile with a halo of [`reach`] texels
/// (the same bits). `rel <= 0` does nothing.
pub fn tv_luminance(
    layout: &Layout,
    charts: &Charts,
    geom: &TileStore<TexelGeom>,
    state: &mut TileStore<impl PassRecord>,
    rel: f32,
    scratch: &Scratch,
) -> Result<()> {
    if rel <= 0.0 {
        return Ok(());
    }
    for slot in 0..layout.slots.len() {
        let c = &charts.slots[slot];
        let tex = SlotTexture::read(layout, slot, state, geom, scratch, "tv", |s, g| {
            let l = Vec3::from_array(s.l_orig());
            TvTexel {
                l,
                lambda: l * rel,
                chart: if s.weight() > 0.0 { c.texel(g) } else { NONE },
            }
        })?;
        let out = tex.map_windows(reach(ITERATIONS), scratch, "tv-out", |v, w, h| {
            tv_prox(v, w, h, ITERATIONS)
        })?;
        drop(tex);
        out.write(state, |s, v| {
            if s.weight() <= 0.0 {
                return false;
            }
            s.set_l_orig(v.to_array());
            true
        })?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atlas::store::TexelState;
    use crate::atlas::testing::{all_records, jitter, Built};

    /// `w x h` texels, left half `a` and right half `b`, charts from `chart(x)`.
    fn halves(
        w: u32,
        h: u32,
        (a, b): (f32, f32),
        lambda: f32,
        chart: impl Fn(u32) -> u32,
    ) -> Vec<TvTexel> {
        (0..w * h)
            .map(|i| TvTexel {
                l: Vec3::splat(if i % w < w / 2 { a } else { b }),
                lambda: Vec3::splat(lambda),
                chart: chart(i % w),
            })
            .collect()
    }

    /// Closed form: two flat halves meeting along a straight edge of `h` texels. TV charges
    /// `lambda` per unit of jump along the edge, so each half moves towards the other by
    /// `lambda h / (its area w/2 h) = 2 lambda / w`, and stays flat (the edge stays sharp).
    #[test]
    fn two_halves_move_together_by_the_closed_form_and_the_edge_stays_sharp() {
        let (w, h, lambda) = (8u32, 4u32, 0.05f32);
        let u = tv_prox(&halves(w, h, (1.0, 2.0), lambda, |_| 0), w, h, 2000).unwrap();
        let shift = 2.0 * lambda / w as f32;
        for (i, v) in u.iter().enumerate() {
            let want = if i as u32 % w < w / 2 {
                1.0 + shift
            } else {
                2.0 - shift
            };
            assert!((v.x - want).abs() < 1e-4, "texel {i}: {} for {want}", v.x);
        }
        assert!(tv_prox(&halves(w, h, (1.0, 2.0), lambda, |_| 0), w, h + 1, 5).is_err());
    }

    /// Nothing is taken across a chart border, and texels without a chart keep their value.
    #[test]
    fn chart_borders_and_unobserved_texels_are_left_alone() {
        let (w, h) = (8u32, 4u32);
        let t = halves(w, h, (1.0, 2.0), 0.05, |x| if x < w / 2 { 3 } else { 7 });
        assert_eq!(
            tv_prox(&t, w, h, 200).unwrap(),
            t.iter().map(|x| x.l).collect::<Vec<_>>()
        );
        let t = halves(w, h, (1.0, 2.0), 0.05, |x| if x == 5 { NONE } else { 0 });
        let u = tv_prox(&t, w, h, 200).unwrap();
        assert_eq!(u[5], Vec3::splat(2.0));
        assert_ne!(u[4], Vec3::splat(2.0), "the rest is still smoothed");
    }

    /// A uniform texture with relative noise of 5% loses most of it at a weight of its noise
    /// level; zero weight leaves every bit.
    #[test]
    fn noise_on_a_flat_texture_shrinks_and_zero_weight_is_the_identity() {
        let (w, h) = (24u32, 16u32);
        let t: Vec<TvTexel> = (0..(w * h) as usize)
            .map(|i| TvTexel {
                l: Vec3::new(0.5, 0.6, 0.7) * (1.0 + 0.05 * jitter(i)),
                lambda: Vec3::new(0.5, 0.6, 0.7) * 0.05,
                chart: 0,
            })
            .collect();
        let err = |u: &[Vec3]| u.iter().map(|v| (v.y / 0.6 - 1.0).powi(2)).sum::<f32>();
        let before = err(&t.iter().map(|x| x.l).collect::<Vec<_>>());
        let after = err(&tv_prox(&t, w, h, ITERATIONS).unwrap());
        assert!(after < 0.2 * before, "{after} of {before}");
        let zero: Vec<TvTexel> = t
            .iter()
            .map(|x| TvTexel {
                lambda: Vec3::ZERO,
                ..*x
            })
            .collect();
        assert_eq!(
            tv_prox(&zero, w, h, ITERATIONS).unwrap(),
            t.iter().map(|x| x.l).collect::<Vec<_>>()
        );
    }

    /// On a store: observed texels change, unobserved ones do not, and the result is the same
    /// bits whether a slot's texture is held whole or tile by tile (halo [`reach`]).
    #[test]
    fn the_store_step_is_the_same_whole_or_in_tiles() {
        let Built {
            p,
            dir,
            geom,
            charts,
        } = Built::cube(24.0);
        let mut runs = Vec::new();
        for budget in [1u64 << 30, 1] {
            let path = dir.path().join(format!("state-{budget}.tiles"));
            let mut st = p.create_store(&path, TexelState::default()).unwrap();
            let mut k = 0usize;
            for t in 0..st.tile_count() {
                let g = geom.read_tile(t).unwrap();
                let mut recs = st.read_tile(t).unwrap();
                for (s, g) in recs.iter_mut().zip(&g) {
                    k += 1;
                    if !g.covered() || k % 11 == 0 {
                        continue;
                    }
                    let l = 0.5 + 0.5 * (g.position[0] > 0.0) as u32 as f32;
                    s.l_orig = [l * (1.0 + 0.05 * jitter(k)); 3];
                    s.weight = 1.0;
                }
                st.write_tile(t, &recs).unwrap();
            }
            let before = all_records(&st);
            let scratch = Scratch::new(dir.path(), budget);
            tv_luminance(&p.layout, &charts, &geom, &mut st, 0.05, &scratch).unwrap();
            let after = all_records(&st);
            let mut changed = 0;
            for (b, a) in before.iter().zip(&after) {
                if b.weight == 0.0 {
                    assert_eq!(a, b, "an unobserved texel changed");
                }
                changed += (a.l_orig != b.l_orig) as u32;
            }
            assert!(changed > 1000, "{changed} texels changed");
            runs.push(after);
        }
        assert!(runs[0] == runs[1], "whole and tiled differ");
    }
}
