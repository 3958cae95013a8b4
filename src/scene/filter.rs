//! The film's pixel (reconstruction) filter, as Mitsuba 3 defines it: a photo pixel is the
//! filter-weighted mean of the radiance around the pixel's center, so a `tent` or `gaussian`
//! film blurs the photo and the projection has to know by how much.
//!
//! Mitsuba 3's filters are separable (`f(x) f(y)`, `x`, `y` in pixels from the pixel center):
//! `box` is 1 on `[-0.5, 0.5)`; `tent` is `max(0, 1 - |x| / radius)` (radius 1 by default);
//! `gaussian` is `exp(-x^2 / (2 stddev^2))` shifted down to reach zero at its radius
//! `4 stddev` (stddev 0.5 by default, so radius 2). A film without an `<rfilter>` uses the
//! default `gaussian` (`src/rfilters/*.cpp` and `src/render/film.cpp` of Mitsuba 3.9).

/// A film's reconstruction filter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PixelFilter {
    Box,
    Tent { radius: f32 },
    Gaussian { stddev: f32 },
}

/// Mitsuba's default `tent` radius, pixels.
pub const DEFAULT_TENT_RADIUS: f32 = 1.0;
/// Mitsuba's default `gaussian` standard deviation, pixels.
pub const DEFAULT_GAUSSIAN_STDDEV: f32 = 0.5;

impl Default for PixelFilter {
    /// Mitsuba's film default: a gaussian of standard deviation 0.5 pixel.
    fn default() -> Self {
        PixelFilter::Gaussian {
            stddev: DEFAULT_GAUSSIAN_STDDEV,
        }
    }
}

impl PixelFilter {
    /// The Mitsuba plugin name.
    pub fn plugin(&self) -> &'static str {
        match self {
            PixelFilter::Box => "box",
            PixelFilter::Tent { .. } => "tent",
            PixelFilter::Gaussian { .. } => "gaussian",
        }
    }

    /// Half-width of the support, pixels.
    pub fn radius(&self) -> f32 {
        match *self {
            PixelFilter::Box => 0.5,
            PixelFilter::Tent { radius } => radius,
            PixelFilter::Gaussian { stddev } => 4.0 * stddev,
        }
    }

    /// The 1-D kernel at `x` pixels from the pixel center (not normalized: Mitsuba divides
    /// each pixel's weighted sum by its sum of weights).
    pub fn eval(&self, x: f32) -> f32 {
        match *self {
            PixelFilter::Box => {
                if (-0.5..0.5).contains(&x) {
                    1.0
                } else {
                    0.0
                }
            }
            PixelFilter::Tent { radius } => (1.0 - x.abs() / radius).max(0.0),
            PixelFilter::Gaussian { stddev } => {
                let g = |x: f32| (-x * x / (2.0 * stddev * stddev)).exp();
                (g(x) - g(4.0 * stddev)).max(0.0)
            }
        }
    }

    /// Whether a pixel is the plain mean over its own square (a box), so that the photo is
    /// not blurred beyond the pixel.
    pub fn is_box(&self) -> bool {
        matches!(self, PixelFilter::Box)
    }

    /// How far, in whole pixels, a pixel's value reaches into its neighbours: the pixels
    /// `-n..=n` around it overlap the filter's support (0 for a box).
    pub fn reach(&self) -> u32 {
        if self.is_box() {
            return 0;
        }
        (self.radius() - 0.5).max(0.0).ceil() as u32
    }

    /// Per-pixel weights of the filter, for offsets `-n..=n` with `n = reach()`: the kernel
    /// integrated over each neighbour pixel's square, normalized to sum 1. Convolving an
    /// image of pixel means (a box-filtered render) with them along x then y gives the photo
    /// this film would record, to the extent the radiance is flat within each pixel.
    pub fn pixel_weights(&self) -> Vec<f32> {
        let n = self.reach() as i32;
        const STEPS: i32 = 64;
        let mut w: Vec<f64> = (-n..=n)
            .map(|k| {
                (0..STEPS)
                    .map(|s| {
                        let x = k as f32 - 0.5 + (s as f32 + 0.5) / STEPS as f32;
                        self.eval(x) as f64
                    })
                    .sum()
            })
            .collect();
        let total: f64 = w.iter().sum();
        for v in &mut w {
            *v /= total;
        }
        w.into_iter().map(|v| v as f32).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The integral of the kernel over `[-r, r]` by the midpoint rule.
    fn integral(f: PixelFilter, lo: f32, hi: f32) -> f64 {
        let n = 200_000;
        let h = (hi - lo) as f64 / n as f64;
        (0..n)
            .map(|i| f.eval((lo as f64 + (i as f64 + 0.5) * h) as f32) as f64 * h)
            .sum()
    }

    #[test]
    fn kernels_have_mitsubas_support_and_area() {
        let tent = PixelFilter::Tent { radius: 1.0 };
        assert_eq!(tent.radius(), 1.0);
        // The unit tent integrates to exactly 1 and vanishes outside [-1, 1].
        assert!((integral(tent, -3.0, 3.0) - 1.0).abs() < 1e-6);
        assert_eq!(tent.eval(1.0), 0.0);
        assert_eq!(tent.eval(-1.5), 0.0);
        assert_eq!(tent.eval(0.0), 1.0);
        assert_eq!(tent.eval(0.5), 0.5);
        // A wider tent: area = radius.
        let wide = PixelFilter::Tent { radius: 2.5 };
        assert!((integral(wide, -4.0, 4.0) - 2.5).abs() < 1e-5);
        // Box: 1 on [-0.5, 0.5), area 1.
        let b = PixelFilter::Box;
        assert_eq!((b.eval(-0.5), b.eval(0.4999), b.eval(0.5)), (1.0, 1.0, 0.0));
        assert!((integral(b, -2.0, 2.0) - 1.0).abs() < 1e-6);
        // Gaussian: radius 4 stddev, zero there, and its area is the truncated gaussian's
        // minus the shift: sqrt(2 pi) s erf(2 sqrt 2) - 8 s exp(-8).
        let g = PixelFilter::default();
        assert_eq!(g, PixelFilter::Gaussian { stddev: 0.5 });
        assert_eq!(g.radius(), 2.0);
        assert_eq!(g.eval(2.0), 0.0);
        assert_eq!(g.eval(2.5), 0.0);
        let s = 0.5f64;
        let erf_2sqrt2 = 0.999_936_657_516_334_2; // erf(2.828427...)
        let want = (2.0 * std::f64::consts::PI).sqrt() * s * erf_2sqrt2 - 8.0 * s * (-8.0f64).exp();
        assert!((integral(g, -3.0, 3.0) - want).abs() < 1e-5);
    }

    #[test]
    fn pixel_weights_are_normalized_and_symmetric() {
        assert_eq!(PixelFilter::Box.pixel_weights(), vec![1.0]);
        let t = PixelFilter::Tent { radius: 1.0 }.pixel_weights();
        // Tent over pixel squares: the neighbours get 2 * (1/2)(1/2)^2 / 1 ... = 1/8 each.
        assert_eq!(t.len(), 3);
        assert!(
            (t[0] - 0.125).abs() < 1e-4 && (t[1] - 0.75).abs() < 1e-4,
            "{t:?}"
        );
        assert_eq!(t[0], t[2]);
        let g = PixelFilter::default().pixel_weights();
        assert_eq!(g.len(), 5);
        assert!((g.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        assert!(g[2] > g[1] && g[1] > g[0] && g[0] > 0.0);
        assert_eq!(PixelFilter::Tent { radius: 0.4 }.reach(), 0);
    }
}
