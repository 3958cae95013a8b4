//! Shapes of one colour kept to one colour. After the final `K_d`, a shape whose observed
//! texels nearly all share one albedo (the median absolute deviation of their luminance under
//! [`UNIFORM_MAD`] of its median) is taken to be painted in one colour, and its `K_d` goes
//! through the sigma filter of `denoise` once more, now in `K_d` and with a wide relative
//! tolerance (`[output] uniform_tolerance`, `uniform_radius`): each texel becomes the mean of
//! the texels of its chart around it whose `K_d` lies within that share of its own. What is
//! left on such a face after the solve is error, not texture: speckle where the refinement
//! passes deconvolve grazing views, bands where `E_i` bends fast (a contact, the edge of a
//! box's face), the gather's blotches. A step larger than the tolerance (a stain, a decal) is
//! kept.
//!
//! Why the gate is per shape: in `K_d` a textured surface's detail and this error look alike
//! locally (the filter on every shape, or gated by a local noise estimate such as the median
//! absolute deviation around each texel, blurs textured walls and ceilings), while over a
//! whole shape they do not. [`UNIFORM_MAD`] lies between the example scenes' shapes of one
//! colour (relative median absolute deviation 0.25-1.9% before this step) and their textured
//! ones (3.6% and up). A shape of one colour that is much noisier, such as a ceiling lit only
//! by interreflection (12% relative standard error), is left as it is.
//!
//! Written here, not taken from a crate: it is `atlas::sigma::sigma_filter` (charts, tiles,
//! budget) with a relative tolerance; the only new part is the gate.

use crate::atlas::sigma::{sigma_filter, Noisy};
use crate::atlas::store::TileStore;
use crate::atlas::store::{Layout, TexelGeom, TexelState};
use crate::atlas::texture::{Scratch, SlotTexture};
use crate::atlas::uv::Charts;
use crate::atlas::uv::NONE;
use crate::base::error::Result;
use crate::scene::luminance;
use glam::Vec3;

/// A shape is uniform when the median absolute deviation of its observed texels' `K_d`
/// luminance is under this share of their median (see the module doc for why 2.5%).
pub const UNIFORM_MAD: f32 = 0.025;
/// Fewer observed texels than this say too little about a shape to call it uniform.
const MIN_TEXELS: usize = 64;

/// What the step did, for the report.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct UniformStats {
    /// Shapes found uniform.
    pub shapes: u32,
    /// Their observed texels, each averaged with its agreeing neighbours.
    pub texels: u64,
}

/// The relative median absolute deviation of `ys` about their median (`None` when fewer than
/// [`MIN_TEXELS`] or a median that is not positive).
pub fn relative_mad(ys: &mut [f32]) -> Option<f32> {
    if ys.len() < MIN_TEXELS {
        return None;
    }
    let mid = ys.len() / 2;
    let m = *ys.select_nth_unstable_by(mid, f32::total_cmp).1;
    if !(m > 0.0 && m.is_finite()) {
        return None;
    }
    for y in ys.iter_mut() {
        *y = (*y / m - 1.0).abs();
    }
    Some(*ys.select_nth_unstable_by(mid, f32::total_cmp).1)
}

/// The luminance of an observed texel's `K_d`, when finite and positive (the texels the
/// gate counts and the filter reads).
fn observed_albedo(s: &TexelState) -> Option<f32> {
    let y = luminance(Vec3::from_array(s.k_d));
    (s.weight > 0.0 && y.is_finite() && y > 0.0).then_some(y)
}

/// [`observed_albedo`] of every texel of `slot`, read straight from the store: the gate needs
/// no texture of the slot, so a textured shape costs one read of its tiles.
fn slot_albedos(layout: &Layout, state: &TileStore<TexelState>, slot: usize) -> Result<Vec<f32>> {
    let mut ys = Vec::new();
    for t in layout.slot_tiles(slot) {
        for (off, s) in state.read_tile(t as usize)?.iter().enumerate() {
            if layout.texel_of(t, off as u32).is_some() {
                ys.extend(observed_albedo(s));
            }
        }
    }
    Ok(ys)
}

/// Every uniform slot's observed `K_d` filtered (see the module doc), but the slots `known`
/// marks (shapes whose reflectance the config gives; `known` may be shorter than the slots:
/// the rest are reconstructed): texels of one chart
/// within `tolerance` of each other (relative, per channel) in a `(2 radius + 1)^2` window are
/// averaged. `radius = 0` does nothing. Cost `O(texels x (2 radius + 1)^2)` on the uniform
/// slots, one pass over the others.
pub fn smooth_uniform(
    (layout, known): (&Layout, &[bool]),
    charts: &Charts,
    geom: &TileStore<TexelGeom>,
    state: &mut TileStore<TexelState>,
    (radius, tolerance): (u32, f32),
    scratch: &Scratch,
) -> Result<UniformStats> {
    let mut stats = UniformStats::default();
    if radius == 0 {
        return Ok(stats);
    }
    // the sigma filter accepts a neighbour within z sqrt(s_c^2 + s_n^2) per channel: with
    // z = 1 and each texel's s = k K_d, that is `tolerance` of two equal values
    let k = tolerance / std::f32::consts::SQRT_2;
    for slot in 0..layout.slots.len() {
        if known.get(slot).copied().unwrap_or(false) {
            continue;
        }
        match relative_mad(&mut slot_albedos(layout, state, slot)?) {
            Some(mad) if mad < UNIFORM_MAD => {}
            _ => continue,
        }
        let c = &charts.slots[slot];
        let tex = SlotTexture::read(layout, slot, state, geom, scratch, "kd", |s, g| {
            let y = observed_albedo(s);
            Noisy {
                l: Vec3::from_array(s.k_d),
                var: (k * y.unwrap_or(0.0)).powi(2),
                chart: if y.is_some() { c.texel(g) } else { NONE },
            }
        })?;
        let filtered = tex.map_windows(radius, scratch, "uniform", |v, w, h| {
            sigma_filter(v, w, h, radius, 1.0)
        })?;
        drop(tex);
        stats.shapes += 1;
        stats.texels += filtered.write(state, |s, f| {
            if s.weight <= 0.0 || f.n == 0 {
                return false;
            }
            s.k_d = f.l.to_array();
            true
        })?;
    }
    Ok(stats)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atlas::testing::{all_records, jitter, Built};
    use crate::scene::{mesh, Shape, Sides};

    fn rect(id: &str) -> Shape {
        Shape::plain(id, mesh::rectangle(), Sides::Front)
    }

    /// The true albedo of the test's two shapes at `x`, `y` (scene units on the rectangle):
    /// "paint", one grey with a darker stain (a step of 60%, over the tolerance) on a quarter
    /// of it; "checker", squares of 0.2 and 0.8.
    fn truth(shape: usize, x: f32, y: f32) -> f32 {
        match shape {
            0 if x > 0.5 => 0.2,
            0 => 0.5,
            _ => [0.2, 0.8][((x * 2.0).floor() + (y * 2.0).floor()).rem_euclid(2.0) as usize],
        }
    }

    /// A painted shape loses its noise and keeps its stain; a textured one is not touched, nor
    /// a known one; whole or in tiles the same bits.
    #[test]
    fn a_painted_shape_is_averaged_and_a_textured_one_left_alone() {
        let Built {
            p,
            dir,
            geom,
            charts,
        } = Built::new(vec![rect("paint"), rect("checker")], vec![], 48.0, vec![]);
        let state = |name: &str| {
            let path = dir.path().join(name);
            let mut st = p.create_store(&path, TexelState::default()).unwrap();
            let mut k = 0usize;
            for t in 0..st.tile_count() {
                let shape = p.layout.slots[p.layout.slot_of_tile(t as u32)].shape;
                let g = geom.read_tile(t).unwrap();
                let mut recs = st.read_tile(t).unwrap();
                for (s, g) in recs.iter_mut().zip(&g) {
                    k += 1;
                    if g.covered() {
                        let kd = truth(shape, g.position[0], g.position[1]);
                        s.k_d = [kd * (1.0 + 0.03 * jitter(k)); 3];
                        s.weight = 1.0;
                    }
                }
                st.write_tile(t, &recs).unwrap();
            }
            st
        };
        // a shape whose reflectance the config gives is not touched
        let mut st = state("known.tiles");
        let before = all_records(&st);
        let paint = p.layout.slot_of_shape(0).unwrap();
        let known: Vec<bool> = (0..p.layout.slots.len()).map(|s| s == paint).collect();
        let scratch = Scratch::new(dir.path(), 1 << 30);
        let none = smooth_uniform(
            (&p.layout, &known),
            &charts,
            &geom,
            &mut st,
            (8, 0.25),
            &scratch,
        );
        assert_eq!(none.unwrap(), UniformStats::default());
        assert!(all_records(&st) == before, "a known shape changed");
        let mut runs = Vec::new();
        for budget in [1u64 << 30, 1] {
            let mut st = state(&format!("state-{budget}.tiles"));
            let before = all_records(&st);
            let scratch = Scratch::new(dir.path(), budget);
            let params = (8, 0.25);
            let slots = (&p.layout, &[][..]);
            let stats = smooth_uniform(slots, &charts, &geom, &mut st, params, &scratch);
            let after = all_records(&st);
            let g = all_records(&geom);
            let (mut err_before, mut err_after, mut n) = (0.0f64, 0.0f64, 0);
            for t in 0..st.tile_count() {
                let shape = p.layout.slots[p.layout.slot_of_tile(t as u32)].shape;
                let ts = p.layout.tile_size as usize * p.layout.tile_size as usize;
                for i in t * ts..(t + 1) * ts {
                    let (b, a) = (&before[i], &after[i]);
                    if shape == 1 || b.weight == 0.0 {
                        assert_eq!(a, b, "a texel of the checker or an unobserved one changed");
                        continue;
                    }
                    let kd = truth(shape, g[i].position[0], g[i].position[1]);
                    err_before += ((b.k_d[0] / kd - 1.0) as f64).powi(2);
                    err_after += ((a.k_d[0] / kd - 1.0) as f64).powi(2);
                    n += 1;
                }
            }
            let (rb, ra) = (
                (err_before / n as f64).sqrt(),
                (err_after / n as f64).sqrt(),
            );
            // 3% uniform noise is 1.7% RMS; a mean over the window's ~200 agreeing texels of
            // its side of the stain leaves a few tenths of that, and nothing crosses the step
            // (a texel pulled across it would be tens of per cent off)
            assert!(rb > 0.015 && ra < 0.004, "RMS relative error {rb} -> {ra}");
            let stats = stats.unwrap();
            assert_eq!(stats.shapes, 1, "{stats:?}");
            assert_eq!(stats.texels, n as u64, "{stats:?}");
            runs.push(after);
        }
        assert!(runs[0] == runs[1], "whole and tiled differ");
    }

    #[test]
    fn the_relative_mad_is_about_the_median() {
        let mut ys: Vec<f32> = (0..100).map(|i| 1.0 + 0.001 * (i % 21) as f32).collect();
        ys.extend([5.0; 10]); // outliers move neither median much
        let mad = relative_mad(&mut ys).unwrap();
        assert!(mad > 0.004 && mad < 0.007, "{mad}");
        assert_eq!(relative_mad(&mut vec![1.0; MIN_TEXELS - 1]), None);
        assert_eq!(relative_mad(&mut vec![0.0; MIN_TEXELS]), None);
    }
}
