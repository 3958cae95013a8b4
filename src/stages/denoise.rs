//! Edge-preserving noise reduction of the projected luminance (`L_orig`), between the
//! projection and the direct light: a sigma filter (Lee 1983) in texture space that averages
//! each observed texel with the neighbours of its own chart whose values lie within `z`
//! standard errors of its own, the standard errors being the projection's per-texel estimate
//! (`TexelState::l_var`). Uniform surfaces lose most of the photos' noise; an edge (texture,
//! shadow) is a step larger than the noise, so texels across it are not mixed. Texels with no
//! noise estimate (noise-free photos) are left as they are.
//!
//! Written by hand: image denoisers (bilateral, non-local means, OIDN) work on images with one
//! noise level and know nothing of charts; here every texel has its own standard error and the
//! filter must not cross a chart border (texels adjacent in the atlas, apart on the surface).

use crate::atlas::store::TileStore;
use crate::atlas::store::{Layout, TexelGeom, TexelState};
use crate::atlas::texture::window;
use crate::atlas::texture::{Scratch, SlotTexture};
use crate::atlas::uv::Charts;
use crate::atlas::uv::NONE;
use crate::atlas::uv::OVERSAMPLE;
use crate::base::error::{Error, Result};
use crate::scene::luminance;
use glam::Vec3;
use rayon::prelude::*;
use std::cell::Cell;

/// What the filter reads of a texel.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Noisy {
    /// Radiance per channel.
    pub l: Vec3,
    /// Variance of its luminance from the photos' noise (`TexelState::l_noise`).
    pub var: f32,
    /// Its chart, [`NONE`] for a texel not observed (never read, never changed).
    pub chart: u32,
}

/// What the filter makes of a texel: its radiance, the factor its noise variance shrinks by,
/// and how many texels it averaged (0: not filtered).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct Filtered {
    pub l: Vec3,
    pub factor: f32,
    pub n: u32,
}

/// What the filter did, for the report.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct DenoiseStats {
    /// Observed texels averaged with at least one neighbour.
    pub averaged: u64,
    /// Mean over the observed texels with a noise estimate of the factor their noise's
    /// standard deviation shrank by (1: nothing removed).
    pub sigma_ratio: f64,
}

/// Per channel, the standard error of a texel's value: its luminance's, scaled by the
/// channel's share (the photos' noise is relative, the same in every channel).
fn channel_sigma(t: &Noisy) -> Vec3 {
    let y = luminance(t.l);
    if y > 0.0 {
        t.l * (t.var.max(0.0).sqrt() / y)
    } else {
        Vec3::ZERO
    }
}

/// Whether neighbour `n` agrees with `c` within `z` standard errors of their difference in
/// every channel.
fn agrees(c: &Noisy, sc: Vec3, n: &Noisy, z: f32) -> bool {
    let sn = channel_sigma(n);
    let d = (c.l - n.l).abs();
    let tol = (sc * sc + sn * sn).map(f32::sqrt) * z;
    d.cmple(tol).all()
}

/// The sigma filter of radius `radius` over one row-major `width x height` texture: every
/// texel with a chart and a noise estimate becomes the mean of the texels of its chart within
/// `[x - r, x + r] x [y - r, y + r]` that agree with it within `z` standard errors
/// ([`agrees`]), itself included, and its noise variance shrinks by the independent
/// measurements among them ([`independent`]). Others keep their value (factor 1). Cost
/// `O(texels x (2r + 1)^2)`.
pub fn sigma_filter(
    texels: &[Noisy],
    width: u32,
    height: u32,
    radius: u32,
    z: f32,
) -> Result<Vec<Filtered>> {
    let (w, h) = (width as usize, height as usize);
    if texels.len() != w * h {
        return Err(Error::internal(format!(
            "denoise: {} texels for a {width}x{height} texture",
            texels.len()
        )));
    }
    let keep = |t: &Noisy| Filtered {
        l: t.l,
        factor: 1.0,
        n: 0,
    };
    let mut out: Vec<Filtered> = texels.iter().map(keep).collect();
    if radius == 0 || w == 0 {
        return Ok(out);
    }
    let r = radius as usize;
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let c = &texels[y * w + x];
            if c.chart == NONE || c.var.is_nan() || c.var <= 0.0 {
                continue;
            }
            let sc = channel_sigma(c);
            let (mut sum, mut n) = (Vec3::ZERO, 0u32);
            for span in window(w, h, (x, y), r) {
                for nb in &texels[span] {
                    if nb.chart == c.chart && agrees(c, sc, nb, z) {
                        sum += nb.l;
                        n += 1;
                    }
                }
            }
            // `n >= 1`: the texel agrees with itself
            *o = Filtered {
                l: sum / n as f32,
                factor: 1.0 / independent(n),
                n,
            };
        }
    });
    Ok(out)
}

/// How many independent measurements a mean of `n` neighbouring texels holds: a photo's
/// pixel spans [`OVERSAMPLE`]^2 texels of the finest view (more in the others), so their
/// noise is shared; at least one.
fn independent(n: u32) -> f32 {
    (n as f32 / (OVERSAMPLE * OVERSAMPLE)).max(1.0)
}

/// The filter applied to every slot's observed texels: `l_orig` filtered, judged against
/// `l_noise`, which shrinks by the filter's factor. `l_var` (what the confidence maps report)
/// is left as the projection made it: the error of a denoised texel is mostly what the noise
/// model does not cover (detail one view resolves and another blurs), so shrinking it with the
/// noise would make the standard errors overconfident on textured scenes, while on uniform
/// boxes, where the filter does most, they stay on the safe side as they are. A slot's texture
/// is filtered whole if it fits in `scratch`'s budget, else tile by tile with a halo of
/// `radius` texels (the same values: a texel's window lies within its tile's halo).
/// `radius = 0` does nothing; slots `skip` marks are left as they are (`skip` may be shorter
/// than the slots: the rest are filtered).
#[inline(never)] // a stage entry tools/icount.py measures
pub fn denoise_luminance(
    layout: &Layout,
    charts: &Charts,
    geom: &TileStore<TexelGeom>,
    state: &mut TileStore<TexelState>,
    (radius, z): (u32, f32),
    scratch: &Scratch,
    skip: &[bool],
) -> Result<DenoiseStats> {
    let (averaged, judged, ratio_sum) = (Cell::new(0u64), Cell::new(0u64), Cell::new(0f64));
    if radius == 0 {
        return Ok(DenoiseStats::default());
    }
    for slot in 0..layout.slots.len() {
        if skip.get(slot).copied().unwrap_or(false) {
            continue;
        }
        let c = &charts.slots[slot];
        let tex = SlotTexture::read(layout, slot, state, geom, scratch, "noisy", |s, g| Noisy {
            l: Vec3::from_array(s.l_orig),
            var: s.l_noise,
            chart: if s.weight > 0.0 { c.texel(g) } else { NONE },
        })?;
        let filtered = tex.map_windows(radius, scratch, "denoised", |v, w, h| {
            sigma_filter(v, w, h, radius, z)
        })?;
        drop(tex);
        filtered.write(state, |s, f| {
            if s.weight <= 0.0 {
                return false;
            }
            s.l_orig = f.l.to_array();
            s.l_noise *= f.factor;
            if f.n > 0 {
                judged.set(judged.get() + 1);
                ratio_sum.set(ratio_sum.get() + (f.factor as f64).sqrt());
                averaged.set(averaged.get() + (f.n > 1) as u64);
            }
            true
        })?;
    }
    Ok(DenoiseStats {
        averaged: averaged.get(),
        sigma_ratio: match judged.get() {
            0 => 1.0,
            j => ratio_sum.get() / j as f64,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atlas::testing::{all_records, jitter, Built};

    fn texel(l: Vec3, rel_sigma: f32, chart: u32) -> Noisy {
        Noisy {
            l,
            var: (rel_sigma * luminance(l)).powi(2),
            chart,
        }
    }

    /// Closed form: a uniform texture with a noise estimate keeps its value; an interior
    /// texel averages 25 texels at radius 2 (its variance shrinks 25 times), a corner 9.
    #[test]
    fn a_uniform_texture_keeps_its_value_and_its_variance_shrinks_by_the_count() {
        let t = vec![texel(Vec3::new(0.4, 0.5, 0.6), 0.05, 0); 8 * 6];
        let f = sigma_filter(&t, 8, 6, 2, 2.0).unwrap();
        for (i, o) in f.iter().enumerate() {
            assert!((o.l - t[i].l).abs().max_element() < 1e-6, "{i}: {}", o.l);
        }
        assert_eq!(f[2 * 8 + 3].factor, 4.0 / 25.0, "25 texels, 4 to a pixel");
        assert_eq!(f[0].factor, 4.0 / 9.0);
        assert_eq!(sigma_filter(&t, 8, 6, 0, 2.0).unwrap()[9].factor, 1.0);
        assert!(sigma_filter(&t, 8, 5, 2, 2.0).is_err());
    }

    /// A step of 20 noise standard deviations: no texel takes anything from across it, and
    /// the flat sides lose most of their noise.
    #[test]
    fn an_edge_is_kept_and_the_flat_sides_lose_their_noise() {
        let (w, h, sigma) = (24u32, 12u32, 0.05f32);
        let truth = |x: u32| if x < w / 2 { 1.0 } else { 2.0 };
        let t: Vec<Noisy> = (0..w * h)
            .map(|i| {
                let v = truth(i % w) * (1.0 + sigma * jitter(i as usize));
                texel(Vec3::splat(v), sigma, 0)
            })
            .collect();
        let f = sigma_filter(&t, w, h, 2, 2.0).unwrap();
        let (mut before, mut after) = (0.0f32, 0.0f32);
        for (i, o) in f.iter().enumerate() {
            let want = truth(i as u32 % w);
            assert!(
                (o.l.x / want - 1.0).abs() <= sigma,
                "texel {i} mixed across the edge: {} for {want}",
                o.l.x
            );
            before += (t[i].l.x / want - 1.0).powi(2);
            after += (o.l.x / want - 1.0).powi(2);
        }
        assert!(after < 0.25 * before, "noise {after} of {before}");
    }

    /// Two colours of the same luminance are an edge too: every channel is judged.
    #[test]
    fn colours_of_equal_luminance_are_not_mixed() {
        let red = Vec3::new(1.0, 0.0, 0.0);
        let green = Vec3::new(0.0, 0.2126 / 0.7152, 0.0);
        assert!((luminance(red) - luminance(green)).abs() < 1e-6);
        let t: Vec<Noisy> = (0..6)
            .map(|x| texel(if x < 3 { red } else { green }, 0.05, 0))
            .collect();
        let f = sigma_filter(&t, 6, 1, 2, 2.0).unwrap();
        for (a, b) in f.iter().zip(&t) {
            assert_eq!(a.l, b.l);
        }
    }

    /// A chart border is not crossed even where values agree; texels without a chart or
    /// without a noise estimate are left as they are (the latter may be averaged into a
    /// neighbour that has one).
    #[test]
    fn charts_and_texels_without_noise_are_respected() {
        let mut t: Vec<Noisy> = (0..8)
            .map(|x| texel(Vec3::splat(if x < 4 { 1.0 } else { 1.02 }), 0.05, x / 4))
            .collect();
        t[7].chart = NONE;
        t[6].var = 0.0;
        let f = sigma_filter(&t, 8, 1, 2, 2.0).unwrap();
        assert_eq!(f[3].l, Vec3::ONE, "chart 0 takes nothing from chart 1");
        assert!((f[4].l.x - 1.02).abs() < 1e-6);
        assert!(
            (f[4].l.x - 1.02).abs() < 1e-6 && f[4].factor == 1.0,
            "fewer than a pixel"
        );
        assert_eq!((f[6].factor, f[7].factor), (1.0, 1.0));
        // 5 texels of one chart around texel 2; texel 4's window has 4 (texel 6: own chart)
        let t2: Vec<Noisy> = (0..7).map(|x| texel(Vec3::ONE, 0.05, 1 + x / 6)).collect();
        let f = sigma_filter(&t2, 7, 1, 2, 2.0).unwrap();
        assert_eq!((f[2].factor, f[4].factor), (4.0 / 5.0, 1.0));
    }

    /// On a store: observed texels are filtered (`l_noise` shrinks, `l_var` stays), others
    /// untouched, and the result is the same bits whether a slot's texture is held
    /// whole or tile by tile.
    #[test]
    fn the_store_filter_is_the_same_whole_or_in_tiles() {
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
                    // some covered texels unobserved; in odd tiles most, so that many
                    // observed texels there average fewer than a pixel's worth
                    let seen = if t % 2 == 0 { k % 7 != 0 } else { k % 9 == 0 };
                    if !g.covered() || !seen {
                        continue;
                    }
                    let l = 0.5 + 0.5 * (g.position[0] > 0.0) as u32 as f32;
                    s.l_orig = [l * (1.0 + 0.05 * jitter(k)); 3];
                    s.weight = 1.0;
                    s.l_noise = (0.05 * l).powi(2);
                    s.l_var = s.l_noise * if k % 3 == 0 { 2.0 } else { 1.0 };
                }
                st.write_tile(t, &recs).unwrap();
            }
            let before = all_records(&st);
            let scratch = Scratch::new(dir.path(), budget);
            let stats =
                denoise_luminance(&p.layout, &charts, &geom, &mut st, (2, 2.0), &scratch, &[])
                    .unwrap();
            let after = all_records(&st);
            let (mut shrunk, mut changed) = (0, 0);
            let (mut ratio, mut judged) = (0.0f64, 0);
            for (b, a) in before.iter().zip(&after) {
                if b.weight == 0.0 {
                    assert_eq!(a, b, "an unobserved texel changed");
                    continue;
                }
                ratio += (a.l_noise as f64 / b.l_noise as f64).sqrt();
                judged += 1;
                assert_eq!(a.l_var, b.l_var);
                shrunk += (a.l_noise < b.l_noise) as u32;
                changed += (a.l_orig != b.l_orig) as u32;
            }
            assert!(shrunk > 1000, "{shrunk} texels' noise shrunk");
            assert!(
                changed > shrunk,
                "{changed} texels filtered, {shrunk} shrunk"
            );
            // the report's figures, against a count over the stores
            let (changed, judged) = (changed as u64, judged as u64);
            assert!(
                stats.averaged >= changed && stats.averaged < judged,
                "{stats:?}"
            );
            let want = ratio / judged as f64;
            assert!(
                (stats.sigma_ratio - want).abs() < 1e-5,
                "{stats:?} vs {want}"
            );
            assert!(stats.sigma_ratio < 0.8, "{stats:?}");
            runs.push(after);
        }
        assert!(runs[0] == runs[1], "whole and tiled differ");
    }
}
