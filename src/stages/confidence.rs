//! Per-texel confidence of the recovered `K_d`: its estimated standard error from the
//! variance of the fused luminance (`TexelState::l_var`: photo noise through the views, or
//! their scatter where larger, see `project`) and of the gathered secondary light (`e_var`),
//! the run's summary of it for `report.json`, and its calibration against a known truth
//! (`kdmap accuracy`: does the error the run predicts match the error it makes?).
//!
//! `K_d = pi L / (E_d + E_i)`, so to first order its relative variance is the sum of the
//! relative variances of `L` and of `E`, judged on luminance; `E`'s is the gathered `E_i`'s
//! (`e_var`) plus, under an environment light, `E_d`'s sampling noise (`ed_var`, see
//! `direct::sampling`). Point, spot and directional light are exact; an area light's
//! stratified shadow rays are not counted, and neither is `E_i` where it was not gathered
//! (photons).

use crate::atlas::store::{flags, TexelState};
use crate::report::Confidence;
use crate::scene::luminance;
use glam::Vec3;
use serde::{Deserialize, Serialize};

/// The relative standard error of the luminance of a texel's `K_d`, for observed texels with
/// light and luminance; `None` elsewhere.
pub fn kd_rel_stderr(s: &TexelState) -> Option<f32> {
    if s.flags & flags::OBSERVED == 0 {
        return None;
    }
    let l = luminance(Vec3::from_array(s.l_orig));
    let e = luminance(Vec3::from_array(s.e_d) + Vec3::from_array(s.e_i));
    if !(l > 0.0 && e > 0.0) {
        return None;
    }
    let rel2 = s.l_var / (l * l) + (s.e_var + s.ed_var) / (e * e);
    rel2.is_finite().then(|| rel2.sqrt())
}

/// The standard error of a texel's `K_d` per channel (0 where [`kd_rel_stderr`] is `None`).
pub fn kd_stderr(s: &TexelState) -> Vec3 {
    kd_rel_stderr(s).map_or(Vec3::ZERO, |r| Vec3::from_array(s.k_d) * r)
}

/// Bins of a log histogram of relative standard errors: [`HIST_LO`] x 2^(k / 8).
const HIST_BINS: usize = 160;
const HIST_LO: f32 = 1e-5;
const HIST_PER_OCTAVE: f32 = 8.0;

fn hist_bin(r: f32) -> usize {
    let k = ((r.max(HIST_LO) / HIST_LO).log2() * HIST_PER_OCTAVE) as usize;
    k.min(HIST_BINS - 1)
}

fn hist_value(k: usize) -> f32 {
    HIST_LO * ((k as f32 + 0.5) / HIST_PER_OCTAVE).exp2()
}

/// Running sums for [`Confidence`], added up texel by texel in tile order (any texel may be
/// added: only observed ones count, and only covered ones have `e_var`).
#[derive(Debug, Clone)]
pub struct ConfidenceSums {
    hist: Vec<u64>,
    photo: u64,
    c: Confidence,
}

impl Default for ConfidenceSums {
    fn default() -> Self {
        ConfidenceSums {
            hist: vec![0; HIST_BINS],
            photo: 0,
            c: Confidence::default(),
        }
    }
}

impl ConfidenceSums {
    /// Count one texel.
    pub fn add(&mut self, s: &TexelState) {
        if s.flags & flags::OBSERVED != 0 && s.disagree > 0.0 {
            self.c.texels_with_disagreement += 1;
            self.c.disagreeing_views += s.disagree as u64;
        }
        self.c.e_i_noise_estimated |= s.e_var > 0.0;
        self.c.e_d_noise_estimated |= s.ed_var > 0.0;
        let Some(r) = kd_rel_stderr(s) else { return };
        let l = luminance(Vec3::from_array(s.l_orig));
        let e = luminance(Vec3::from_array(s.e_d) + Vec3::from_array(s.e_i));
        self.c.texels += 1;
        self.hist[hist_bin(r)] += 1;
        self.photo += (s.l_var / (l * l) >= (s.e_var + s.ed_var) / (e * e)) as u64;
    }

    /// The summary.
    pub fn finish(&self) -> Confidence {
        let n = self.c.texels;
        let quantile = |q: f64| {
            let want = (q * n as f64).ceil().max(1.0) as u64;
            let mut seen = 0;
            for (k, c) in self.hist.iter().enumerate() {
                seen += c;
                if seen >= want {
                    return hist_value(k) as f64;
                }
            }
            0.0
        };
        Confidence {
            kd_rel_stderr_median: if n > 0 { quantile(0.5) } else { 0.0 },
            kd_rel_stderr_p90: if n > 0 { quantile(0.9) } else { 0.0 },
            photo_dominated: self.photo as f64 / n.max(1) as f64,
            ..self.c.clone()
        }
    }
}

/// Edges of the calibration bins of predicted relative standard error.
pub const CALIBRATION_EDGES: [f64; 7] = [0.0, 0.005, 0.01, 0.02, 0.04, 0.08, 0.16];

/// One bin of the calibration: texels whose predicted relative standard error lies in
/// `[lo, hi)`, their mean prediction, and the shares of them whose actual error lies within
/// one and two predicted standard errors: 68% and 95% for a calibrated confidence; fewer means
/// error the noise model does not know of (bias: resolution, lighting). Shares, not RMS
/// ratios: a few dark texels with relative errors of several hundred percent would decide
/// those.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct CalibrationBin {
    pub lo: f64,
    /// `f64::INFINITY` is written as `null`.
    pub hi: Option<f64>,
    pub texels: u64,
    pub mean_predicted: f64,
    pub within_one: f64,
    pub within_two: f64,
}

/// Predicted against actual relative errors of `K_d`'s luminance, binned.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Calibration {
    pub bins: Vec<CalibrationBin>,
    /// Over every texel with a prediction: the shares within one and two standard errors.
    pub within_one: f64,
    pub within_two: f64,
    pub texels: u64,
}

/// Sums for [`Calibration`].
#[derive(Debug, Clone, Default)]
pub struct CalibrationSums {
    /// Per bin `(texels, sum pred, within one, within two)`.
    bins: [(u64, f64, u64, u64); CALIBRATION_EDGES.len()],
}

impl CalibrationSums {
    /// One texel: predicted relative standard error `pred`, actual relative error `err`.
    pub fn add(&mut self, pred: f64, err: f64) {
        let k = CALIBRATION_EDGES
            .iter()
            .rposition(|e| pred >= *e)
            .unwrap_or(0);
        let b = &mut self.bins[k];
        b.0 += 1;
        b.1 += pred;
        b.2 += (err.abs() <= pred) as u64;
        b.3 += (err.abs() <= 2.0 * pred) as u64;
    }

    pub fn finish(&self) -> Calibration {
        let share = |k: u64, n: u64| k as f64 / n.max(1) as f64;
        let bins = self
            .bins
            .iter()
            .enumerate()
            .map(|(k, b)| CalibrationBin {
                lo: CALIBRATION_EDGES[k],
                hi: CALIBRATION_EDGES.get(k + 1).copied(),
                texels: b.0,
                mean_predicted: b.1 / b.0.max(1) as f64,
                within_one: share(b.2, b.0),
                within_two: share(b.3, b.0),
            })
            .collect();
        let (n, one, two) = self
            .bins
            .iter()
            .fold((0, 0, 0), |a, b| (a.0 + b.0, a.1 + b.2, a.2 + b.3));
        Calibration {
            bins,
            within_one: share(one, n),
            within_two: share(two, n),
            texels: n,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::rng::Rng;

    fn observed(l: f32, l_var: f32, e: f32, e_var: f32) -> TexelState {
        TexelState {
            l_orig: [l; 3],
            e_d: [e; 3],
            k_d: [0.5; 3],
            l_var,
            e_var,
            weight: 1.0,
            flags: flags::OBSERVED,
            ..Default::default()
        }
    }

    /// Closed form: relative variances add, `(0.03)^2 + (0.04)^2 = (0.05)^2`.
    #[test]
    fn relative_variances_of_l_and_e_add() {
        let s = observed(2.0, (0.03f32 * 2.0).powi(2), 10.0, (0.04f32 * 10.0).powi(2));
        let r = kd_rel_stderr(&s).unwrap();
        assert!((r - 0.05).abs() < 1e-6, "{r}");
        assert!((kd_stderr(&s) - Vec3::splat(0.025)).abs().max_element() < 1e-6);
        // E_d's sampling noise adds to E_i's: 0.03^2 + 0.04^2 + 0.12^2 = 0.13^2
        let mut s2 = s;
        s2.ed_var = (0.12f32 * 10.0).powi(2);
        let r2 = kd_rel_stderr(&s2).unwrap();
        assert!((r2 - 0.13).abs() < 1e-6, "{r2}");
        let mut sums = ConfidenceSums::default();
        sums.add(&s2);
        let c = sums.finish();
        assert!(c.e_d_noise_estimated && c.photo_dominated == 0.0, "{c:?}");
        assert_eq!(kd_rel_stderr(&TexelState::default()), None, "unobserved");
        assert_eq!(
            kd_rel_stderr(&observed(1.0, 0.1, 0.0, 0.0)),
            None,
            "no light"
        );
    }

    #[test]
    fn summary_quantiles_follow_the_texels() {
        let mut sums = ConfidenceSums::default();
        // 90 texels at 1%, 10 at 10%: median 1%, p90 1%, p91+ 10%
        for i in 0..100 {
            let r = if i < 90 { 0.01f32 } else { 0.1 };
            let mut s = observed(1.0, r * r, 1.0, 0.0);
            s.disagree = (i == 0) as u32 as f32 * 2.0;
            sums.add(&s);
        }
        let c = sums.finish();
        assert_eq!(c.texels, 100);
        assert!((c.kd_rel_stderr_median / 0.01 - 1.0).abs() < 0.09, "{c:?}");
        assert!((c.kd_rel_stderr_p90 / 0.01 - 1.0).abs() < 0.09, "{c:?}");
        assert!((c.photo_dominated - 1.0).abs() < 1e-9);
        assert_eq!((c.texels_with_disagreement, c.disagreeing_views), (1, 2));
        assert!(!c.e_i_noise_estimated);
    }

    /// Errors drawn with the predicted spread are calibrated (68% within one standard error, 95%
    /// within two); errors twice as large are not (38%, 68%).
    #[test]
    fn calibration_of_gaussian_errors_with_the_predicted_spread_is_one() {
        let normal = |rng: &mut Rng| {
            let (u1, u2) = (rng.f32().max(1e-7) as f64, rng.f32() as f64);
            (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
        };
        let (mut good, mut bad) = (CalibrationSums::default(), CalibrationSums::default());
        for i in 0..20_000u64 {
            let mut rng = Rng::new(7, 0, i, 0);
            let pred = [0.003, 0.015, 0.05, 0.3][(i % 4) as usize];
            let z = normal(&mut rng);
            good.add(pred, pred * z);
            bad.add(pred, 2.0 * pred * z);
        }
        let (g, b) = (good.finish(), bad.finish());
        assert!((g.within_one - 0.683).abs() < 0.02, "{g:?}");
        assert!((g.within_two - 0.954).abs() < 0.01, "{g:?}");
        assert!((b.within_one - 0.383).abs() < 0.02, "{b:?}");
        assert!((b.within_two - 0.683).abs() < 0.02, "{b:?}");
        assert!((g.bins[6].mean_predicted - 0.3).abs() < 1e-9);
        assert_eq!(g.texels, 20_000);
        assert_eq!(
            g.bins[0].texels, 5000,
            "0.003 lies in [0, 0.005): {:?}",
            g.bins
        );
    }
}
