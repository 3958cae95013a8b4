//! What a run reports about itself (`<out>/report.json`): the settings, per-iteration
//! statistics, time per stage and counts. Filled in by `pipeline`, written by `output`.

use crate::config::Config;
use serde::{Deserialize, Serialize};

pub mod summary;

/// Statistics of one solver iteration (one photon pass and one update).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct IterationStats {
    /// 0-based iteration number.
    pub iteration: u32,
    /// RMS over observed texels of the per-texel luminance relative error
    /// `|L_orig - L_render| / L_orig` (fraction, not %).
    pub rms_rel_error: f64,
    /// Mean of the same.
    pub mean_rel_error: f64,
    /// Largest per-texel relative error.
    pub max_rel_error: f64,
    /// RMS of `F = L_orig - L_render` (luminance, scene radiance units).
    pub rms_residual: f64,
    /// Texels whose K_d hit the bound (5) and whose E_i was corrected.
    pub clamped_texels: u64,
    /// Photons traced in this iteration's pass.
    pub photons: u64,
    /// Seconds in the photon pass.
    pub photon_seconds: f64,
    /// Photons per second in the pass.
    pub photons_per_second: f64,
    /// Gather rays cast in this iteration's gather pass, and its seconds.
    #[serde(default)]
    pub gather_rays: u64,
    #[serde(default)]
    pub gather_seconds: f64,
    /// Of those rays, the hits on unobserved texels, kept (36 bytes each) and re-read with
    /// every iteration's estimates: what the gather holds in memory.
    #[serde(default)]
    pub gather_cached_hits: u64,
    /// Seconds in the per-texel update.
    pub update_seconds: f64,
    /// Per channel, the sums over observed texels of E_i before the update and of the
    /// traced E_i (recorded by the `secant` update, which steps from them; zero otherwise).
    #[serde(default)]
    pub sum_e_i: [f64; 3],
    #[serde(default)]
    pub sum_traced: [f64; 3],
    /// The relaxation step used per channel (relaxed and secant updates).
    #[serde(default)]
    pub beta: [f64; 3],
}

/// Wall time per stage, seconds.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Timings {
    pub load: f64,
    pub atlas: f64,
    pub projection: f64,
    /// The projection's noise probe (part of `projection`; see `project::noise_probe`).
    #[serde(default)]
    pub noise_probe: f64,
    /// The photos' calibration (gains and poses; part of `projection`).
    #[serde(default)]
    pub calibration: f64,
    pub direct: f64,
    pub photons: f64,
    #[serde(default)]
    pub gather: f64,
    /// The caustic photon pass (light by way of mirrors and glass, part of `E_d`).
    #[serde(default)]
    pub caustics: f64,
    pub update: f64,
    /// The final filter of uniform shapes' `K_d` (`uniform`).
    #[serde(default)]
    pub uniform: f64,
    pub output: f64,
    pub total: f64,
}

/// Rays cast per stage (every process of the run together): with the stage's wall time and
/// the run's cores, how close each stage comes to the ray-casting limit
/// ([`StageRays::per_core_second`]). A stage casting few rays for its time spends it
/// elsewhere (look-ups, filters, I/O).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct StageRays {
    /// The atlas (texel geometry and hit tables).
    pub atlas: u64,
    /// The projection with its calibration and noise probe.
    pub projection: u64,
    pub direct: u64,
    pub caustics: u64,
    /// Every iteration's gather, or photons (method `photons`).
    pub estimate: u64,
    pub output: u64,
    /// Worker threads per process times processes: the cores the rays were cast on.
    pub cores: usize,
}

impl StageRays {
    /// Per stage with rays, `(name, rays, rays per second per core)` from the stages' wall
    /// times `t`.
    pub fn per_core_second(&self, t: &Timings) -> Vec<(&'static str, u64, f64)> {
        let est = t.gather + t.photons;
        [
            ("atlas", self.atlas, t.atlas),
            ("projection", self.projection, t.projection),
            ("direct", self.direct, t.direct),
            ("caustics", self.caustics, t.caustics),
            ("estimate", self.estimate, est),
            ("output", self.output, t.output),
        ]
        .into_iter()
        .filter(|(_, n, _)| *n > 0)
        .map(|(k, n, s)| (k, n, n as f64 / (s * self.cores.max(1) as f64).max(1e-9)))
        .collect()
    }

    /// One line for the console: each stage's rays and rays per second per core.
    pub fn summary(&self, t: &Timings) -> Option<String> {
        let parts: Vec<String> = (self.per_core_second(t).into_iter())
            .map(|(k, n, r)| format!("{k} {} ({}/s per core)", si(n as f64), si(r)))
            .collect();
        (!parts.is_empty()).then(|| format!("rays cast: {}", parts.join(", ")))
    }
}

/// `v` with a k / M / G suffix, three significant digits.
fn si(v: f64) -> String {
    let (d, u) = match v {
        v if v >= 1e9 => (1e9, "G"),
        v if v >= 1e6 => (1e6, "M"),
        v if v >= 1e3 => (1e3, "k"),
        _ => (1.0, ""),
    };
    let x = v / d;
    let p = if x >= 100.0 {
        0
    } else if x >= 10.0 {
        1
    } else {
        2
    };
    format!("{x:.p$}{u}")
}

/// Counts that describe the problem size.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Counts {
    pub shapes: usize,
    pub reconstructed_shapes: usize,
    pub triangles: usize,
    pub emitters: usize,
    pub views: usize,
    pub masked_pixels: usize,
    pub tiles: u32,
    /// Texels whose center lies on a surface.
    pub covered_texels: u64,
    /// Covered texels seen by at least one view.
    pub observed_texels: u64,
    /// Covered texels some view could see: inside its frame, facing it, nothing in between
    /// (what `observed_texels` is out of, for the photos taken).
    #[serde(default)]
    pub visible_texels: u64,
    /// Photons of the caustic pass (0: no mirror or glass in the scene).
    #[serde(default)]
    pub caustic_photons: u64,
    /// Observed texels whose luminance the denoiser averaged with agreeing neighbours.
    #[serde(default)]
    pub denoised_texels: u64,
    /// Their mean factor of noise reduction: the standard deviation of the photos' noise in an
    /// observed texel's luminance after the denoiser over before (1: nothing removed).
    #[serde(default)]
    pub denoise_sigma_ratio: f64,
    /// Shapes found uniform (one colour) whose final `K_d` was filtered (`uniform`), and
    /// their observed texels.
    #[serde(default)]
    pub uniform_shapes: u32,
    #[serde(default)]
    pub uniform_texels: u64,
    /// Covered texels no view saw (K_d filled from neighbours).
    pub filled_texels: u64,
    /// Of those, the ones left with the wave's fill because their texture's harmonic
    /// relaxation did not fit in the scratch budget (`run.memory_budget_mib / 4`).
    #[serde(default)]
    pub fill_unrelaxed_texels: u64,
    /// Shapes no view saw whose `K_d` is the mean of the observed shapes of their material
    /// (the shapes the scene gives one named material).
    #[serde(default)]
    pub material_filled_shapes: u64,
    /// Covered texels whose direct light was estimated densely (a shadow edge or penumbra
    /// crosses them or a neighbour).
    #[serde(default)]
    pub dense_direct_texels: u64,
    /// Covered texels that ran the direct light's first pass (the rest took the verdict of
    /// their lattice neighbours).
    #[serde(default)]
    pub direct_first_pass_texels: u64,
    /// Per emitter, the texels whose light from it was estimated densely.
    #[serde(default)]
    pub dense_direct_texels_per_emitter: Vec<u64>,
    /// Covered texels whose environment light's sampled `E_d` was averaged with agreeing
    /// neighbours of their chart (0 without an environment light).
    #[serde(default)]
    pub smoothed_direct_texels: u64,
    /// Gather points no observed texel reads, which cast `run.unobserved_share` of the rays
    /// (0 with photons).
    #[serde(default)]
    pub lean_gather_points: u64,
}

/// One row of the paper's comparison table: one shape seen from one view, over the pixels
/// where the view sees that shape cleanly (no silhouette, no depth edge).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ViewShapeRow {
    pub view: String,
    pub shape: String,
    pub pixels: u64,
    /// Mean luminance `Y`, original photo and re-render.
    pub mean_luminance: [f64; 2],
    /// Standard deviation of `Y` over the pixels, original and re-render.
    pub std_luminance: [f64; 2],
    /// Mean linear RGB, original and re-render.
    pub mean_rgb: [[f64; 3]; 2],
    /// CIE 1931 xy chromaticity of the mean RGB (linear sRGB, D65), original and re-render.
    pub xy: [[f64; 2]; 2],
}

/// Everything `report.json` holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Report {
    pub version: u32,
    pub settings: Config,
    pub iterations: Vec<IterationStats>,
    /// Why the solver stopped: "tolerance" or "max_iterations".
    pub stopped_by: String,
    pub timings: Timings,
    /// Rays cast per stage.
    #[serde(default)]
    pub rays: StageRays,
    pub counts: Counts,
    /// Per reconstructed shape, its texel density and how it was chosen.
    pub atlas: Vec<ShapeTexels>,
    pub table: Vec<ViewShapeRow>,
    /// Memory and disk the run used.
    #[serde(default)]
    pub resources: Resources,
    /// The estimated standard error of the recovered `K_d` (see `confidence`).
    #[serde(default)]
    pub confidence: Confidence,
    /// How the projection's refinement passes converged.
    #[serde(default)]
    pub refinement: Refinement,
    /// Per reconstructed shape whose UVs tile its texture, what the fold into those UVs
    /// found (`output::uv_fold`); empty when off or when no shape tiles.
    #[serde(default)]
    pub uv_fold: Vec<UvFold>,
    /// Per view, its photo's gain (exposure times white balance) and what fixed it
    /// (`stages::project::exposure`); 1 and "known" unless estimated or pinned.
    #[serde(default)]
    pub capture: Vec<ViewCapture>,
    /// Per view, its camera pose as refined against the other views (`[views] refine_pose`;
    /// empty when off). The outputs (re-renders, `scene.xml` sensors) use these poses.
    #[serde(default)]
    pub poses: Vec<PoseCorrection>,
    /// What the run's end warned of (`summary::coverage_warning`): photos that observed under
    /// `run.min_observed_share` of the covered texels; empty when nothing.
    #[serde(default)]
    pub warnings: Vec<String>,
}

/// One view's pose refinement (`project::pose`): what was found, and the camera-to-world the
/// run used.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PoseCorrection {
    /// The sensor's id.
    pub view: String,
    /// The camera-to-world the run used (rows): the refined pose when `applied`, else the
    /// scene's.
    pub to_world: [[f32; 4]; 4],
    /// Whether the refined pose was used.
    pub applied: bool,
    /// `"aligned"`; `"beyond the bound"` (the correction grew past 2 degrees or 2% of the
    /// viewing distance); `"no improvement"` (the photo agreed no better with the others at
    /// the refined pose); `"too few pixels"` or `"no other views"` (nothing to align with).
    pub status: String,
    /// Whether the last level's iterations settled (steps under a hundredth of a pixel).
    pub converged: bool,
    /// The correction found (also when refused): rotation, degrees; translation of the
    /// camera's centre, scene units and share of the viewing distance.
    pub rotation_deg: f64,
    pub translation: f64,
    pub translation_rel: f64,
    /// The mean distance, pixels, between where the view's clean pixels' surface points
    /// project at the scene's pose and at the refined one.
    pub shift_px: f64,
    /// The photo's mean relative difference from the other views' re-rendered luminance
    /// (finest level, luminance) at the scene's pose and at the refined one.
    pub residual_before: f64,
    pub residual_after: f64,
    /// The median distance, pixels, between the geometry's edges (silhouettes, creases,
    /// shape borders) as the camera projects them and the photo's edges, at the scene's pose
    /// and at the refined one (finest level), and how many edges the photo showed: how far
    /// the camera sits from the mesh, whatever the other views say.
    pub edge_px_before: f64,
    pub edge_px_after: f64,
    pub edges: u64,
    /// The photo's brightness relative to the other views' (a nuisance of the alignment).
    pub gain: f64,
    /// Gauss-Newton iterations over every round and level.
    pub iterations: u32,
    /// Seconds this view's alignment took (the shared projections and renders included).
    pub seconds: f64,
}

impl PoseCorrection {
    /// [`PoseCorrection::to_world`] as a matrix.
    pub fn matrix(&self) -> glam::Mat4 {
        glam::Mat4::from_cols_array_2d(&self.to_world).transpose()
    }

    /// One line for the console.
    pub fn summary(&self) -> String {
        let what = match self.applied {
            true => "moved".to_string(),
            false => format!("not aligned ({}), kept", self.status),
        };
        format!(
            "pose of '{}': {what} by {:.3} deg and {:.2}% of the distance, {:.2} px on average; \
             residual {:.2}% -> {:.2}%, off the mesh's {} edges {:.2} -> {:.2} px{}",
            self.view,
            self.rotation_deg,
            100.0 * self.translation_rel,
            self.shift_px,
            100.0 * self.residual_before,
            100.0 * self.residual_after,
            self.edges,
            self.edge_px_before,
            self.edge_px_after,
            if self.converged {
                ""
            } else {
                " (not converged)"
            }
        )
    }
}

impl UvFold {
    /// One line for the console.
    pub fn summary(&self) -> String {
        let (r, a) = (self.resolution, self.agreement);
        let what = match self.decision.as_str() {
            "folded" => {
                format!("repeats agree ({a:.2}): folded into a {r}x{r} texture for scene.xml")
            }
            "disagree" => format!(
                "repeats disagree ({a:.2}): kept on the atlas, the albedo does not follow the UVs"
            ),
            "coarse" => format!(
                "kept on the atlas: too few repeats for a fold ({r}x{r}) finer than the atlas"
            ),
            _ => "kept on the atlas: too few observed texels to fold".to_string(),
        };
        let what = match self.decision == "disagree" && !self.atlas_filtered {
            true => format!("{what} (unfiltered: the sigma filter had left it to the fold)"),
            false => what,
        };
        format!(
            "uv fold: '{}' tiles its UVs {:.1} times, {} observed texels, {what}",
            self.shape, self.repeats, self.samples
        )
    }
}

/// What the fold into a shape's input UVs found (`output::uv_fold`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct UvFold {
    pub shape: String,
    /// Times the UVs cover the texture (the sum of the triangles' UV areas).
    pub repeats: f32,
    /// Observed atlas texels folded.
    pub samples: u64,
    /// The folded texture's side, texels (0: too few samples to fold).
    pub resolution: u32,
    /// How alike the folds of the even and of the odd repeats are (their luminances'
    /// correlation: about 1 when the albedo follows the UVs, 0 when not; 0 when not folded).
    pub agreement: f32,
    /// Whether `scene.xml` uses the fold.
    pub used: bool,
    /// Why: `"folded"`; `"few samples"` (under 8 per texel even at 16 x 16); `"coarse"` (the
    /// fold would not be at least twice as fine per side as the atlas's own texels of one
    /// repeat); `"disagree"` (the repeats do not agree: the albedo does not follow the UVs).
    pub decision: String,
    /// Whether the shape's atlas went through the sigma filter (`denoise_radius`). A shape the
    /// fold may take is left to it unfiltered (`uv_fold::foldable_slots`: every test but the
    /// repeats' agreement), so a `"disagree"` shape's `scene.xml` texture is its unfiltered
    /// atlas.
    #[serde(default)]
    pub atlas_filtered: bool,
}

/// The projection's refinement, pass by pass: how far each view's render of the maps was
/// from its photo before the pass's update (`project::refine::mean_relative_residual`: the
/// mean relative residual over its clean pixels; pass 0 is the weighted mean's). On
/// noise-free photos it falls towards 0 as the passes deconvolve; on real ones it levels off
/// near the photos' noise.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Refinement {
    /// The views' sensor ids, in the order of each pass's figures.
    pub views: Vec<String>,
    /// Per pass, each view's mean relative residual.
    pub residual: Vec<Vec<f64>>,
    /// Per pass, the mean over the views.
    pub mean_residual: Vec<f64>,
}

impl Refinement {
    /// From the views' ids and the per-pass, per-view residuals.
    pub fn new(views: Vec<String>, residual: Vec<Vec<f64>>) -> Self {
        let mean_residual = residual
            .iter()
            .map(|r| r.iter().sum::<f64>() / r.len().max(1) as f64)
            .collect();
        Refinement {
            views,
            residual,
            mean_residual,
        }
    }

    /// One line for the console: the views' mean residual before the first and the last pass
    /// (`None` without passes).
    pub fn summary(&self) -> Option<String> {
        let (first, last) = (self.mean_residual.first()?, self.mean_residual.last()?);
        Some(format!(
            "refinement: the maps' renders were {:.1}% from the photos (mean relative residual) \
             after the weighted mean, {:.1}% before the last of {} passes",
            100.0 * first,
            100.0 * last,
            self.mean_residual.len()
        ))
    }
}

/// What a run used besides time: the peak resident set after each stage (the process's peak
/// so far, `VmHWM`, so it only grows; the stage where it jumps is the one that needed it), and
/// the bytes it wrote.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Resources {
    /// The configured `memory_budget_mib`.
    pub memory_budget_mib: u64,
    /// `(stage, peak RSS so far in MiB)`, in the order the stages ended (this attempt's: a
    /// resumed run starts its own peak).
    pub peak_rss_mib: Vec<(String, f64)>,
    /// Bytes of the geometry and state tile stores (the working state on disk).
    pub store_bytes: u64,
    /// Bytes written to checkpoints.
    pub checkpoint_bytes: u64,
    /// Processes of the run: 1, or the ranks of an MPI job (`comm`).
    #[serde(default)]
    pub ranks: usize,
    /// `(stage, bytes, seconds)`, in the order the stages ended: what this process (rank 0)
    /// had sent to and received from the other ranks so far, and the seconds it had spent
    /// inside collective operations (waiting for slower ranks included). Zeros in one process.
    #[serde(default)]
    pub communication: Vec<(String, u64, f64)>,
}

impl Resources {
    /// Records the peak RSS and the communication so far after `stage`.
    pub fn after(&mut self, stage: &str) {
        self.peak_rss_mib
            .push((stage.to_string(), crate::base::mem::peak_mib()));
        let world = crate::base::comm::world();
        let t = world.traffic();
        self.ranks = world.size();
        self.communication
            .push((stage.to_string(), t.bytes, t.seconds));
    }
}

/// One reconstructed shape's texture: its density and size.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ShapeTexels {
    pub shape: String,
    /// Texels per scene unit of length (on its triangles at density level 0).
    pub texels_per_unit: f32,
    /// The share of its area at each density level (`texels_per_unit / 2^level`), when the
    /// automatic density gave it more than one; empty otherwise. (Always written: the
    /// checkpoint's encoding is not self-describing.)
    #[serde(default)]
    pub area_by_level: Vec<f32>,
    /// Scene units per pixel in the photo that sees the shape finest (automatic density).
    pub finest_footprint: Option<f32>,
    /// What held the density below the photos' (`max_texture_size`, `max_texels`, `unseen`).
    pub limited_by: Option<String>,
    pub width: u32,
    pub height: u32,
    /// Texels on the surface (not gutters).
    pub covered_texels: u64,
}

impl Report {
    pub fn new(settings: Config) -> Report {
        Report {
            version: 1,
            settings,
            iterations: Vec::new(),
            stopped_by: String::new(),
            timings: Timings::default(),
            rays: StageRays::default(),
            counts: Counts::default(),
            atlas: Vec::new(),
            table: Vec::new(),
            resources: Resources::default(),
            confidence: Default::default(),
            refinement: Default::default(),
            uv_fold: Vec::new(),
            poses: Vec::new(),
            capture: Vec::new(),
            warnings: Vec::new(),
        }
    }
}

/// What `report.json` says of the confidence of a run's `K_d` (relative standard errors of its
/// luminance over observed texels; quantiles to within 9%, from a log histogram).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Confidence {
    /// Observed texels with an estimate.
    pub texels: u64,
    pub kd_rel_stderr_median: f64,
    pub kd_rel_stderr_p90: f64,
    /// Share of the texels where the photos' noise outweighs the light's (`E_i`'s, and
    /// `E_d`'s sampling noise under an environment light).
    pub photo_dominated: f64,
    /// Observed texels at least one view disagreed on, and the disagreeing observations.
    pub texels_with_disagreement: u64,
    pub disagreeing_views: u64,
    /// Whether `E_i`'s noise was estimated (the gather; photons: no).
    pub e_i_noise_estimated: bool,
    /// Whether `E_d`'s sampling noise was estimated (under an environment light).
    pub e_d_noise_estimated: bool,
}

#[cfg(test)]
mod tests {
    /// Rays per second per core: a stage's rays over its wall time and the run's cores; the
    /// estimate over the gather and the photons together; stages without rays left out.
    #[test]
    fn stage_rays_per_core_second() {
        let rays = StageRays {
            projection: 6_000_000,
            estimate: 9_000_000,
            cores: 2,
            ..Default::default()
        };
        let t = Timings {
            projection: 3.0,
            gather: 1.0,
            photons: 0.5,
            ..Default::default()
        };
        let got = rays.per_core_second(&t);
        assert_eq!(
            got,
            vec![("projection", 6_000_000, 1e6), ("estimate", 9_000_000, 3e6)]
        );
        assert_eq!(
            rays.summary(&t).as_deref(),
            Some(
                "rays cast: projection 6.00M (1.00M/s per core), estimate 9.00M (3.00M/s per core)"
            )
        );
        assert_eq!(StageRays::default().summary(&t), None);
        assert_eq!(si(999.0), "999");
        assert_eq!(si(12_345.0), "12.3k");
        assert_eq!(si(2.5e9), "2.50G");
    }

    use super::*;

    /// Each decision of the fold reads as what happened, and an unfolded shape quotes no
    /// agreement (none was computed).
    #[test]
    fn fold_lines_say_what_was_decided() {
        let f = |decision: &str, agreement: f32| UvFold {
            shape: "ground".into(),
            repeats: 144.0,
            samples: 131_236,
            resolution: 128,
            agreement,
            used: decision == "folded",
            decision: decision.into(),
            atlas_filtered: decision != "folded" && decision != "disagree",
        };
        let line = f("folded", 0.92).summary();
        assert!(
            line.contains("agree (0.92): folded into a 128x128"),
            "{line}"
        );
        let line = f("disagree", 0.02).summary();
        assert!(
            line.contains("disagree (0.02): kept on the atlas") && line.contains("unfiltered"),
            "{line}"
        );
        let filtered = UvFold {
            atlas_filtered: true,
            ..f("disagree", 0.02)
        };
        assert!(!filtered.summary().contains("unfiltered"));
        let line = f("coarse", 0.0).summary();
        assert!(
            line.contains("too few repeats") && !line.contains("agree"),
            "{line}"
        );
        let line = f("few samples", 0.0).summary();
        assert!(
            line.contains("too few observed texels") && !line.contains("agree"),
            "{line}"
        );
    }

    /// Per pass, the mean over the views; the console line quotes the first and the last.
    #[test]
    fn refinement_means_over_views_and_summarises_first_and_last_pass() {
        let r = Refinement::new(
            vec!["a".into(), "b".into()],
            vec![vec![0.10, 0.06], vec![0.04, 0.02]],
        );
        assert_eq!(r.mean_residual.len(), 2);
        assert!((r.mean_residual[0] - 0.08).abs() < 1e-12);
        assert!((r.mean_residual[1] - 0.03).abs() < 1e-12);
        let line = r.summary().unwrap();
        assert!(line.contains("8.0%") && line.contains("3.0%") && line.contains("2 passes"));
        assert_eq!(Refinement::new(vec![], vec![]).summary(), None);
    }

    /// A `report.json` written before the refinement section still reads, with none.
    #[test]
    fn an_older_report_without_refinement_reads() {
        let mut v = serde_json::to_value(Report::new(Config::for_scene("s.xml".into()))).unwrap();
        v.as_object_mut().unwrap().remove("refinement");
        let back: Report = serde_json::from_value(v).unwrap();
        assert_eq!(back.refinement, Refinement::default());
    }
}

/// What fixed a view's gain.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GainSource {
    /// `exposure = "known"`: the photo is in scene units.
    Known,
    /// The run config gives it.
    Pinned,
    /// Relative to the other views, the absolute scale from emitters the photos show.
    Emitters,
    /// Relative to the other views, their geometric mean taken as 1 (no absolute anchor).
    Relative,
    /// Shares too little with the other views and shows no emitter: left at 1.
    Alone,
}

/// How a view's photo was calibrated: its gain (exposure times white balance) and what it
/// rests on, and how it agrees with the others afterwards.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ViewCapture {
    /// The view's sensor id.
    pub view: String,
    /// `photo = gain x radiance`, per channel.
    pub gain: [f32; 3],
    pub source: GainSource,
    /// Sampled texels this view shares with at least one other view.
    pub shared_texels: u64,
    /// Interior emitter pixels it shows (the absolute anchor), and their photo / radiance
    /// ratio per channel (median), if enough.
    pub anchor_pixels: u64,
    pub anchor_ratio: Option<[f32; 3]>,
    /// How the view agrees with the others after calibration (the last refinement pass);
    /// `None` without refinement passes.
    #[serde(default)]
    pub check: Option<ViewCheck>,
}

/// A view against its re-render from the others after calibration (`project::diagnose`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ViewCheck {
    /// Clean pixels compared.
    pub pixels: u64,
    /// Median photo / re-render per channel (1 when the exposure is right).
    pub ratio: [f32; 3],
    /// Share of the texels it sees where it departs from the fused estimate beyond its noise
    /// and the spread views are expected to have (`project::DISAGREE_Z`).
    pub disagreeing: f32,
    /// The residual misalignment the pose refinement measured, in pixels (x right, y down),
    /// where it ran.
    pub shift: Option<[f32; 2]>,
}

impl ViewCapture {
    /// A gain given, not estimated.
    pub fn given(gain: [f32; 3], source: GainSource) -> Self {
        ViewCapture {
            view: String::new(),
            gain,
            source,
            shared_texels: 0,
            anchor_pixels: 0,
            anchor_ratio: None,
            check: None,
        }
    }

    /// The gain's luminance-weighted mean: the exposure part, white balance aside.
    pub fn exposure(&self) -> f32 {
        0.2126 * self.gain[0] + 0.7152 * self.gain[1] + 0.0722 * self.gain[2]
    }
}
