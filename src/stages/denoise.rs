//! Edge-preserving noise reduction of the projected luminance (`L_orig`), between the
//! projection and the direct light: a sigma filter (Lee 1983) in texture space that averages
//! each observed texel with the neighbours of its own chart whose values lie within `z`
//! standard errors of its own, the standard errors being the projection's per-texel estimate
//! (`TexelState::l_var`), the filter being `atlas::texture::sigma`'s. Uniform surfaces lose
//! most of the photos' noise; an edge (texture, shadow) is a step larger than the noise, so
//! texels across it are not mixed. Texels with no noise estimate (noise-free photos) are left
//! as they are.

use crate::atlas::sigma::{sigma_filter, Noisy};
use crate::atlas::store::TileStore;
use crate::atlas::store::{Layout, TexelGeom, TexelState};
use crate::atlas::texture::{Scratch, SlotTexture};
use crate::atlas::uv::Charts;
use crate::atlas::uv::NONE;
use crate::base::error::Result;
use glam::Vec3;
use std::cell::Cell;

/// What the filter did, for the report.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct DenoiseStats {
    /// Observed texels averaged with at least one neighbour.
    pub averaged: u64,
    /// Mean over the observed texels with a noise estimate of the factor their noise's
    /// standard deviation shrank by (1: nothing removed).
    pub sigma_ratio: f64,
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
