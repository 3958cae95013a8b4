//! Optional smoothing of the traced `E_i` (config `smoothing_radius`): secondary light varies
//! slowly over a surface (method step 4), so averaging a texel with its neighbours trades a
//! little blur for less photon noise. The filter never crosses a chart border: texels that
//! are adjacent in the atlas but not on the surface would mix unrelated light.

use crate::atlas::store::TileStore;
use crate::atlas::store::{Layout, TexelGeom, TexelState};
use crate::atlas::texture::window;
use crate::atlas::texture::{Scratch, SlotTexture};
use crate::atlas::uv::Charts;
use crate::atlas::uv::NONE;
use crate::{Error, Result};
use glam::{DVec3, Vec3};
use rayon::prelude::*;

/// Box filter of radius `radius` texels over one slot's texture (row-major `width x height`):
/// each texel with a chart gets the `weights`-weighted mean of `values` over the texels of
/// its own chart within `[x - r, x + r] x [y - r, y + r]`. With `values` = irradiance and
/// `weights` = bin area this is total flux / total area over the window, the same estimator
/// as one texel's on a larger bin. Texels without a chart ([`NONE`]) keep their value.
/// `radius = 0` returns `values` unchanged. Cost `O(texels x (2r + 1)^2)`.
pub fn smooth_within_charts(
    values: &[Vec3],
    weights: &[f32],
    charts: &[u32],
    width: u32,
    height: u32,
    radius: u32,
) -> Result<Vec<Vec3>> {
    let (w, h) = (width as usize, height as usize);
    if values.len() != w * h || weights.len() != w * h || charts.len() != w * h {
        return Err(Error::internal(format!(
            "smoothing: {} values, {} weights and {} charts for a {width}x{height} texture",
            values.len(),
            weights.len(),
            charts.len()
        )));
    }
    let mut out = values.to_vec();
    if radius == 0 || w == 0 {
        return Ok(out);
    }
    let r = radius as usize;
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let c = charts[y * w + x];
            if c == NONE {
                continue;
            }
            let (mut s, mut sw) = (DVec3::ZERO, 0.0f64);
            for span in window(w, h, (x, y), r) {
                for j in span {
                    if charts[j] == c {
                        let wt = weights[j] as f64;
                        s += values[j].as_dvec3() * wt;
                        sw += wt;
                    }
                }
            }
            if sw > 0.0 {
                *o = (s / sw).as_vec3();
            }
        }
    });
    Ok(out)
}

/// What smoothing reads of a texel.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct SmoothTexel {
    accum: Vec3,
    weight: f32,
    chart: u32,
}

/// [`smooth_within_charts`] applied to the traced `E_i` in `TexelState::accum` (after
/// [`super::finish_pass`]), weighted by `TexelGeom::bin_area`, slot by slot: a slot's texture
/// whole if it fits in `scratch`'s budget, else tile by tile with a halo of `radius` texels
/// (the same values: a texel's window lies within its tile's halo). `radius = 0` does nothing.
pub fn smooth_accum(
    layout: &Layout,
    charts: &Charts,
    geom: &TileStore<TexelGeom>,
    state: &mut TileStore<TexelState>,
    radius: u32,
    scratch: &Scratch,
) -> Result<()> {
    if radius == 0 {
        return Ok(());
    }
    for slot in 0..layout.slots.len() {
        let c = &charts.slots[slot];
        let tex = SlotTexture::read(layout, slot, state, geom, scratch, "smooth", |s, g| {
            SmoothTexel {
                accum: Vec3::from_array(s.accum),
                weight: if g.covered() { g.bin_area } else { 0.0 },
                chart: c.texel(g),
            }
        })?;
        let split = |v: &[SmoothTexel]| -> (Vec<Vec3>, Vec<f32>, Vec<u32>) {
            (
                v.iter().map(|t| t.accum).collect(),
                v.iter().map(|t| t.weight).collect(),
                v.iter().map(|t| t.chart).collect(),
            )
        };
        let smoothed = tex.map_windows(radius, scratch, "smoothed", |v, width, height| {
            let (a, w, ch) = split(v);
            smooth_within_charts(&a, &w, &ch, width, height, radius)
        })?;
        drop(tex);
        smoothed.write(state, |s, v| {
            s.accum = v.to_array();
            true
        })?;
    }
    Ok(())
}
