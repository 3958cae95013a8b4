//! The sampling noise of an environment light's `E_d` reduced without more shadow rays:
//! irradiance changes slowly across a surface except at shadow edges, so each sampled texel
//! becomes the mean of the texels of its chart nearby whose values agree with its own within
//! their noise (the sigma filter of [`crate::atlas::sigma`], judged on `ed_var` as
//! [`super::sampling::estimate`] measured it). A shadow edge is a step larger than the noise
//! and is kept. Observed texels and texels no photo observed are smoothed apart
//! ([`super::sample_class`]): the latter draw fewer samples and are noisier. `ed_var` (what
//! `K_d`'s standard error counts of `E_d`) is left as measured, as the denoised luminance's
//! `l_var` is: the noise shrinks about `n` times over `n` texels, but what the smoothing
//! removes is no longer the larger part of a texel's error (`kdmap accuracy` on envmap: 49% of
//! the texels within one predicted standard error of their true `K_d` with it left, 31% with it
//! shrunk, 43% before the smoothing, where 68% is calibrated), so shrinking it would make the
//! standard errors overconfident.
//!
//! It does not license fewer samples per observed texel: a room lit by the sky through its
//! windows gets a few bright samples among many dark ones, a spread the filter reads as
//! disagreement. Drawing a quarter of the pairs inside flat charts kept envmap's held-out albedo
//! below the unsmoothed run's (1.68% against 1.73%) but took the living room's from 20.5% to
//! 27.2%. (Texels no photo observed draw fewer, `[run] unobserved_share`: their `E_d` divides
//! no photo.)

use super::sampling::RADIUS as NOISE_RADIUS;
use crate::atlas::sigma::{sigma_filter, Noisy};
use crate::atlas::store::TileStore;
use crate::atlas::store::{TexelGeom, TexelState};
use crate::atlas::texture::{Scratch, SlotTexture};
use crate::atlas::uv::{Charts, NONE};
use crate::atlas::RunContext;
use crate::base::error::Result;
use glam::Vec3;

/// Half the side of the window a texel averages over (5 x 5 texels): within the window the
/// noise of [`super::sampling::estimate`] was measured ([`NOISE_RADIUS`]), so the light's own
/// change across it is what that estimate allowed for.
pub const RADIUS: u32 = 2;
const _: () = assert!(RADIUS <= NOISE_RADIUS);

/// Neighbours whose `E_d` lies within this many standard errors of their difference are
/// averaged: 2.5 averages 98.8% of the pairs of texels under equal light (Gaussian noise), and
/// keeps apart texels across a step of more than 3.5 times one texel's standard error.
pub const Z: f32 = 2.5;

/// Every covered texel with a stated `E_d` noise (`ed_var > 0`: lit by an environment light)
/// takes the sigma-filtered mean of its chart's texels within [`RADIUS`]. Texels with no stated
/// noise are not changed and not averaged in. Returns how many texels averaged more than
/// themselves.
pub fn smooth(
    p: &RunContext,
    charts: &Charts,
    geom: &TileStore<TexelGeom>,
    state: &mut TileStore<TexelState>,
    scratch: &Scratch,
) -> Result<u64> {
    if !p.scene.has_environment() {
        return Ok(0);
    }
    let layout = &p.layout;
    let averaged = std::cell::Cell::new(0u64);
    for slot in 0..layout.slots.len() {
        let c = &charts.slots[slot];
        let tex = SlotTexture::read(layout, slot, state, geom, scratch, "ed-noisy", |s, g| {
            let sampled = g.covered() && s.ed_var > 0.0;
            Noisy {
                l: Vec3::from_array(s.e_d),
                var: s.ed_var,
                chart: if sampled {
                    super::sample_class(c.texel(g), s)
                } else {
                    NONE
                },
            }
        })?;
        let filtered = tex.map_windows(RADIUS, scratch, "ed-smooth", |v, w, h| {
            sigma_filter(v, w, h, RADIUS, Z)
        })?;
        drop(tex);
        filtered.write(state, |s, f| {
            if f.n == 0 {
                return false;
            }
            averaged.set(averaged.get() + (f.n > 1) as u64);
            s.e_d = f.l.to_array();
            true
        })?;
    }
    Ok(averaged.get())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::rng::Rng;

    /// The filter this stage relies on, on sampled irradiance: independent noise on a flat
    /// field with a shadow step of 10 standard errors. Away from the step the spread shrinks by
    /// about the window's 25 texels (to within 2x), nothing crosses the step, and a texel with
    /// no stated noise is left out of its neighbours' means.
    #[test]
    fn noise_shrinks_by_the_window_and_a_shadow_step_is_kept() {
        let (w, h, sigma) = (40u32, 20u32, 0.02f32);
        let mut rng = Rng::new(5, 0, 0, 0);
        let field = |x: u32| if x < 20 { 1.0 } else { 1.2 };
        let mut t: Vec<Noisy> = (0..w * h)
            .map(|i| Noisy {
                l: Vec3::splat(field(i % w) + sigma * rng.normal()),
                var: sigma * sigma,
                chart: 0,
            })
            .collect();
        // an unsampled texel far off the field's value: it must not pull its neighbours
        let odd = (10 * w + 10) as usize;
        t[odd] = Noisy {
            l: Vec3::splat(5.0),
            var: 0.0,
            chart: NONE,
        };
        let f = sigma_filter(&t, w, h, RADIUS, Z).unwrap();
        let (mut sq, mut n) = (0.0f64, 0);
        for y in 3..h - 3 {
            for x in (3..17).chain(23..w - 3) {
                let i = (y * w + x) as usize;
                if i.abs_diff(odd) <= 2 + 2 * w as usize {
                    continue;
                }
                let e = (f[i].l.x - field(x)) as f64;
                (sq, n) = (sq + e * e, n + 1);
            }
        }
        let ratio = (sq / n as f64) / (sigma * sigma) as f64;
        assert!(
            (1.0 / 50.0..2.0 / 25.0).contains(&ratio),
            "variance x{ratio}"
        );
        for y in 0..h {
            for x in [19u32, 20] {
                let i = (y * w + x) as usize;
                assert!((f[i].l.x - field(x)).abs() < 4.0 * sigma, "({x}, {y})");
            }
        }
        assert_eq!(f[odd].n, 0, "an unsampled texel keeps its value");
        let mut others = f.iter().enumerate().filter(|&(i, _)| i != odd);
        assert!(
            others.all(|(_, o)| o.l.x < 2.0),
            "nothing took the unsampled value"
        );
    }
}
