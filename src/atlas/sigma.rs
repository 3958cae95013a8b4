//! The sigma filter (Lee 1983) in texture space: each texel becomes the mean of the
//! neighbours of its own chart whose values lie within `z` standard errors of its own, the
//! standard errors being each texel's own. Uniform surfaces lose most of their noise; an edge
//! is a step larger than the noise, so texels across it are not mixed. Used on the projected
//! luminance (`stages::denoise`), to judge a shape of one colour (`stages::one_colour`), and
//! on an environment light's sampled `E_d` (`stages::direct::smooth`).
//!
//! Written by hand: image denoisers (bilateral, non-local means, OIDN) work on images with one
//! noise level and know nothing of charts; here every texel has its own standard error and the
//! filter must not cross a chart border (texels adjacent in the atlas, apart on the surface).

use super::texture::window;
use crate::atlas::uv::{NONE, OVERSAMPLE};
use crate::base::error::{Error, Result};
use crate::scene::luminance;
use glam::Vec3;
use rayon::prelude::*;

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
pub fn independent(n: u32) -> f32 {
    (n as f32 / (OVERSAMPLE * OVERSAMPLE)).max(1.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atlas::testing::jitter;

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
}
