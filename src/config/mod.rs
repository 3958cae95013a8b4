//! The run configuration: raw TOML (a `configs/*.toml` file) plus command-line overrides,
//! validated once into a [`Config`] that drives the whole run. Unknown keys are errors, every
//! setting has a documented unit, and impossible combinations are refused here, not deep in a
//! stage.

pub mod keys;
mod raw;
#[cfg(test)]
mod tests;
mod validate;
mod views;

pub use raw::RawConfig;
pub use views::{Exposure, Response, Similarity};

use crate::base::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Command-line overrides (`None` = not given).
#[derive(Debug, Clone, Default)]
pub struct Overrides {
    /// A named preset; applied before the run config's own keys and the other flags.
    pub preset: Option<Preset>,
    pub method: Option<Method>,
    pub photons: Option<u64>,
    pub iterations: Option<u32>,
    pub seed: Option<u64>,
    pub threads: Option<usize>,
}

/// How the secondary irradiance `E_i` is estimated each iteration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Gathered from the observed radiance of the surfaces around each point
    /// (`stages::indirect::gather`): converges in one or two passes. The default.
    Gather,
    /// Traced forward from the lights with the current `K_d` (`stages::indirect::photon`),
    /// the paper's method: the reference.
    Photons,
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s {
            "gather" => Ok(Method::Gather),
            "photons" => Ok(Method::Photons),
            _ => Err(format!("unknown method '{s}': expected gather or photons")),
        }
    }
}

impl Method {
    /// Iterations when the config does not say: the gather's later passes only update the
    /// light from unobserved surfaces, which settles by the third; photon tracing needs
    /// several to converge.
    pub fn default_iterations(self) -> u32 {
        match self {
            Method::Gather => 3,
            Method::Photons => 6,
        }
    }
}

/// How E_i is updated between photon passes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum UpdateRule {
    /// The paper's gradient step, eqs. (8)-(9): `E_i -= -alpha_n K_d/pi F`.
    Paper,
    /// Take the photon-traced E_i as it is (a fixed-point iteration).
    FixedPoint,
    /// Move E_i part of the way to the traced value: `E_i += beta (E_i_traced - E_i)`. The
    /// fixed-point map oscillates where much of a texel's light is interreflected (its slope is
    /// about `-K_d/(1-K_d)` in a closed furnace); relaxation damps that.
    Relaxed,
    /// The relaxed update with one step per colour channel chosen by the secant method on the
    /// scene-wide sums of E_i and of the traced E_i over the last two iterations: the step
    /// that would land the sum on its fixed point if the map were linear (`beta = 1 / (1 -
    /// g)`, `g` the measured slope, clamped to [0.2, 1]). The first iteration uses `beta`.
    Secant,
}

/// Settings of the UV atlas.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AtlasConfig {
    /// Texel density: from the photos (`"auto"`, the default) or texels per scene unit.
    pub texels_per_unit: Density,
    /// With `Density::Auto`, at most this many surface texels in all (0 = twice as many as the
    /// photos have pixels, at most `atlas::density::DEFAULT_MAX_TEXELS`).
    #[serde(default)]
    pub max_texels: u64,
    /// Gutter between charts, in texels.
    pub padding: u32,
    /// Keep the meshes' own UVs instead of unwrapping.
    pub use_mesh_uvs: bool,
    /// Tile edge in texels (tiles are `tile_size x tile_size`).
    pub tile_size: u32,
    /// Largest texture edge in texels; a shape needing more is refused.
    pub max_texture_size: u32,
}

/// How dense the texels are.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Density {
    /// Per shape, the density of the finest pixel footprint the photos give it (capped by
    /// `max_texture_size` and `max_texels`; see `atlas::density`).
    Auto,
    /// The same number of texels per scene unit of length on every shape.
    PerUnit(f32),
}

impl Density {
    /// The fixed density, if any.
    pub fn per_unit(self) -> Option<f32> {
        match self {
            Density::Auto => None,
            Density::PerUnit(d) => Some(d),
        }
    }
}

/// Most refinement passes a config may ask for (each costs about one projection).
pub const MAX_REFINE_PASSES: u32 = 64;

/// Default refinement passes of the projection. Textures seen at grazing angles keep gaining
/// detail up to about sixteen passes, while the gate keeps uniform surfaces from drifting; each
/// pass costs about one projection (figures in docs/accuracy.md and docs/performance.md).
pub const REFINE_PASSES: u32 = 16;
/// Default step of the refinement passes after the first (over-relaxation of the
/// back-projection, see `project::apply_refinement`; 1 is the plain weighted mean of the
/// residuals, and the first pass always takes 1, as its robust weights are judged against the
/// plain mean). The passes converge for steps below 2; at 1.8 three passes get about as far
/// as six at step 1.
pub const REFINE_STEP: f32 = 1.8;
/// Default gate of the refinement passes (`project::apply_refinement`): a texel keeps its value
/// in a gated pass when under this share of its views' residual is signal (the mean keep
/// factor of the residual shrinkage over the views; 0 = no gate). Lower gates let uniform
/// walls drift with the photos' noise; higher ones stop textured surfaces from sharpening.
pub const REFINE_GATE: f32 = 0.7;
/// Default first gated refinement pass (from 0; the passes before it are not gated). Gating
/// from the second pass (1) suits scenes of uniform surfaces but holds back fine textures seen
/// at grazing angles, whose detail is at the photos' noise level pass by pass.
pub const REFINE_GATED_FROM: u32 = 4;
/// Default settling threshold of the refinement passes: once a gated pass changed fewer than
/// this share of the texels it updated by more than 1% of their luminance, the next pass is
/// the last (0 = always `refine_passes`). Where the gate holds nearly every texel still
/// (envmap: 0.0007% of the texels a pass from the first gated pass on; the room 0.4% by the
/// second) the passes left change nothing the held-out views show; where texture or fine
/// parts keep sharpening (cbox-tex: 4.6-10%, the lego at 768 px: 1-4.6%) they all run.
pub const REFINE_SETTLE: f32 = 0.005;
/// Default radius in texels of the sigma filter of the projected luminance (`denoise`;
/// 0 = off): wider radii gain little on uniform walls and start to blur fine textures.
pub const DENOISE_RADIUS: u32 = 4;
/// Default agreement threshold of the sigma filter, in standard errors of the difference
/// of two texels' values (`denoise`). The texels' standard errors are the photos' noise
/// propagated through the views' weights (`TexelState::l_noise`), which the refinement
/// passes amplify beyond (see `project::noise_probe`), so 2 barely acts on dim faces; tiled
/// textures, which the output folds, are left out of the filter and keep their detail.
pub const DENOISE_Z: f32 = 4.0;
/// Default radius in texels of the final filter of one-colour shapes' `K_d` (`one_colour`),
/// and its relative tolerance: 8 keeps the cost at 289 comparisons per texel of those shapes,
/// and 0.25 keeps steps of more than a quarter of the albedo (a stain, a decal).
pub const UNIFORM_RADIUS: u32 = 8;
pub const UNIFORM_TOLERANCE: f32 = 0.25;
/// Largest radius the uniform shapes' filter may be asked for (its cost grows as its square).
pub const MAX_UNIFORM_RADIUS: u32 = 32;
/// Largest total-variation weight a config may ask for (at 2 a checkerboard is washed out).
pub const MAX_TV_WEIGHT: f32 = 2.0;
/// Largest sigma-filter radius a config may ask for.
pub const MAX_DENOISE_RADIUS: u32 = 16;
/// Default photons per covered texel and iteration (method "photons"): about the 1e7 photons
/// per iteration of the paper-sized runs on the 64-texels-per-unit Cornell box.
pub const PHOTONS_PER_TEXEL: f64 = 100.0;

/// Named starting points for the settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Preset {
    /// The defaults: full accuracy at the documented cost.
    Default,
    /// A quick look: 256 gather rays, 20 photons per texel, 2 iterations, one refinement
    /// pass, 9 shadow rays per emitter triangle; a few points less accurate.
    Fast,
    /// The paper's method as published: its update rule (eqs. 8-9), no projection
    /// refinement, no E_i smoothing. For comparisons with the original.
    Paper,
}

impl Preset {
    pub fn parse(s: &str) -> Option<Preset> {
        match s {
            "default" => Some(Preset::Default),
            "fast" => Some(Preset::Fast),
            "paper" => Some(Preset::Paper),
            _ => None,
        }
    }
}

impl std::str::FromStr for Preset {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        Preset::parse(s)
            .ok_or_else(|| format!("unknown preset '{s}': expected default, fast or paper"))
    }
}

/// Every setting of a run, validated.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Config {
    pub scene: PathBuf,
    /// Sensor id -> image path. Empty means "the scene's `images/<id>.exr`".
    pub views: BTreeMap<String, PathBuf>,
    /// How each photo's gain (exposure times white balance) is found.
    pub exposure: Exposure,
    /// Views whose gain is given (`[views.<id>] exposure`): photo = gain x radiance, per
    /// channel.
    pub pinned_gains: BTreeMap<String, [f32; 3]>,
    /// Whether each camera's pose is refined against the photos before the final projection.
    pub refine_pose: bool,
    /// How 8-bit photos' code values become linear values.
    pub response: Response,
    /// A COLMAP sparse model standing for the scene's sensors, if given.
    pub colmap: Option<PathBuf>,
    /// The similarity from the COLMAP model's frame to the scene's (rows); identity if `None`.
    pub colmap_to_world: Option<[[f64; 4]; 4]>,
    pub atlas: AtlasConfig,
    /// Iterative back-projection passes after the weighted-mean projection (0 = off).
    pub refine_passes: u32,
    /// Texels no clean pixel sees read from pixels that see one surface of their shape, else
    /// from the pixel their center falls in (`stages::project::one_surface`).
    #[serde(default)]
    pub fine_geometry: bool,
    /// The passes' step, in `(0, 2)` ([`REFINE_STEP`]).
    pub refine_step: f32,
    /// The passes' gate, in `[0, 1)` ([`REFINE_GATE`]; 0 = none). Reports written before it
    /// existed read as 0 (they had none).
    #[serde(default)]
    pub refine_gate: f32,
    /// The first gated pass, from 0 ([`REFINE_GATED_FROM`]).
    #[serde(default)]
    pub refine_gated_from: u32,
    /// The passes' settling threshold, in `[0, 1)` ([`REFINE_SETTLE`]; 0 = every pass).
    /// Reports written before it existed read as 0 (they ran every pass).
    #[serde(default)]
    pub refine_settle: f32,
    /// Radius in texels of the edge-preserving filter of the projected luminance (0 = off,
    /// [`DENOISE_RADIUS`]).
    pub denoise_radius: u32,
    /// Its agreement threshold in standard errors ([`DENOISE_Z`]).
    pub denoise_z: f32,
    /// Weight of the total-variation step after each refinement pass, in units of the
    /// photos' relative noise (0 = off, the default; see `project::total_variation`).
    pub tv_weight: f32,
    /// Whether the photos' noise through the projection is measured by projecting them again
    /// with added noise (`project::noise_probe`; the default), rather than only propagated through
    /// the views' weights. Reports written before it existed read as `false` (they did not).
    #[serde(default)]
    pub noise_probe: bool,
    /// First-pass interior shadow rays per area-emitter triangle (the perimeter is searched
    /// too; see `light::DirectParams`).
    pub area_samples: u32,
    /// Sample pairs per texel for an environment light's direct irradiance (see
    /// `light::env`; `DirectParams::env_samples`). Reports written before it existed read as
    /// 144, the value they used.
    #[serde(default = "default_env_samples")]
    pub env_samples: u32,
    /// How `E_i` is estimated.
    pub method: Method,
    /// Gather rays per gather point (rounded up to a square).
    pub gather_rays: u32,
    /// Distance between gather points, scene units; 0 = automatic (see
    /// [`Config::gather_spacing_for`]).
    pub gather_spacing: f32,
    /// Light paths (photons) traced per iteration: fixed, or, while `photons_per_texel` is set,
    /// resolved at the start of a run to that many per covered texel
    /// ([`Config::with_photon_budget_for`]).
    pub photons: u64,
    /// Photons per covered texel and iteration (the default, so that E_i's noise per texel does
    /// not grow with the atlas); `None` when a fixed count was given (`per_iteration`,
    /// `--photons`).
    #[serde(default)]
    pub photons_per_texel: Option<f64>,
    /// Photons per batch: the unit of parallel work, determinism and mid-pass checkpoints.
    pub batch_size: u32,
    /// Longest photon path in bounces (Russian roulette usually ends paths earlier).
    pub max_depth: u32,
    /// Box-filter radius (texels) applied to E_i within charts; 0 = off.
    pub smoothing_radius: u32,
    /// Most solver iterations (photon passes).
    pub iterations: u32,
    /// Stop when the RMS relative error over observed texels falls below this (fraction).
    pub tolerance: f32,
    /// Step size of the paper's update, `alpha_n = alpha0 / (1 + n)`.
    pub alpha0: f32,
    pub update: UpdateRule,
    /// `beta` of the relaxed update, in (0, 1].
    pub relaxation: f32,
    /// Initial E_i as a share of E_d (step 4 of the method).
    pub initial_indirect_share: f32,
    pub seed: u64,
    /// Worker threads; 0 = all cores. Never changes results.
    pub threads: usize,
    /// Mid-pass checkpoint at most every N photon batches.
    pub checkpoint_every_batches: u32,
    /// Seconds of work between checkpoints: one is taken after the direct light and when the
    /// run finishes, and in between (after an iteration, or inside a photon pass) only once
    /// this much time has passed since the last, or longer when the checkpoints' measured
    /// write time or size calls for it (`checkpoint::cadence`). 0 = at every opportunity.
    #[serde(default)]
    pub checkpoint_every_seconds: f64,
    /// Budget for memory-mapped working sets, MiB.
    pub memory_budget_mib: u64,
    /// A run whose photos observe under this share of the covered texels (or whose textures
    /// are more than `1 -` this share fill) ends with a warning; 0 = never.
    #[serde(default)]
    pub min_observed_share: f64,
    /// The share of the samples a texel no photo observed gets, against an observed one: the
    /// direct light's dense samples (an environment light's pairs, an area light's penumbra
    /// rays, a hard light's edge points) and the gather rays of points no observed texel reads.
    /// Such a texel's `K_d` is the fill; its light only feeds what it passes on to others (see
    /// `stages::direct`, `stages::indirect::gather`). Reports written before it existed read
    /// as 1, the value they used.
    #[serde(default = "one")]
    pub unobserved_share: f32,
    /// Shapes not reconstructed, by id, with the diffuse reflectance the user gives them
    /// (linear RGB): they keep that albedo and take part in the light transport.
    #[serde(default)]
    pub known_shapes: BTreeMap<String, [f32; 3]>,
    /// Coated shapes (`plastic`, `roughplastic`, ...) marked `reconstruct = false` without a
    /// reflectance: they keep the base their scene states, as known materials. Every other
    /// coated shape has its base reconstructed.
    #[serde(default)]
    pub kept_coats: BTreeSet<String>,
    /// The run-config file these settings came from, if any (named in errors).
    #[serde(skip)]
    pub source: Option<PathBuf>,
    /// glTF scenes: scene radiance units per photometric unit (glTF lights are in candela
    /// and lux, emission read as nits): every glTF light and emission value is multiplied by
    /// it at load, and divided by it when `scene.glb` is written. Mitsuba scenes ignore it.
    #[serde(default = "one")]
    pub photometric_scale: f32,
    /// Whether a reconstructed shape whose UVs tile its texture gets its albedo folded into
    /// those UVs for `scene.xml` (`[output] uv_fold = "auto"`, the default; see
    /// `output::uv_fold`). Reports written before it existed read as `false` (they did not).
    #[serde(default)]
    pub uv_fold: bool,
    /// The final filter of one-colour shapes' `K_d` (`one_colour`, `[output] uniform_radius`,
    /// `uniform_tolerance`): radius in texels (0 = off) and relative tolerance. Reports
    /// written before it existed read as 0 (it did not run).
    #[serde(default)]
    pub uniform_radius: u32,
    #[serde(default)]
    pub uniform_tolerance: f32,
}

fn one() -> f32 {
    1.0
}

impl Config {
    /// Defaults for a scene given directly on the command line.
    pub fn for_scene(scene: PathBuf) -> Config {
        Config {
            scene,
            views: BTreeMap::new(),
            exposure: Exposure::Estimate,
            pinned_gains: BTreeMap::new(),
            refine_pose: false,
            response: Response::Srgb,
            colmap: None,
            colmap_to_world: None,
            atlas: AtlasConfig {
                texels_per_unit: Density::Auto,
                max_texels: 0,
                padding: 2,
                use_mesh_uvs: false,
                tile_size: 64,
                max_texture_size: 8192,
            },
            refine_passes: REFINE_PASSES,
            fine_geometry: false,
            refine_step: REFINE_STEP,
            refine_gate: REFINE_GATE,
            refine_gated_from: REFINE_GATED_FROM,
            refine_settle: REFINE_SETTLE,
            denoise_radius: DENOISE_RADIUS,
            denoise_z: DENOISE_Z,
            tv_weight: 0.0,
            noise_probe: true,
            area_samples: 16,
            env_samples: ENV_SAMPLES,
            unobserved_share: UNOBSERVED_SHARE,
            method: Method::Gather,
            gather_rays: 1024,
            gather_spacing: 0.0,
            photons: 10_000_000,
            photons_per_texel: Some(PHOTONS_PER_TEXEL),
            batch_size: 65_536,
            max_depth: 64,
            smoothing_radius: 1,
            iterations: Method::Gather.default_iterations(),
            tolerance: 0.005,
            alpha0: 2.0,
            update: UpdateRule::Relaxed,
            relaxation: 0.5,
            initial_indirect_share: 0.5,
            seed: 1,
            threads: 0,
            checkpoint_every_batches: 32,
            checkpoint_every_seconds: 60.0,
            memory_budget_mib: 1024,
            min_observed_share: 0.5,
            known_shapes: BTreeMap::new(),
            kept_coats: BTreeSet::new(),
            uv_fold: true,
            uniform_radius: UNIFORM_RADIUS,
            uniform_tolerance: UNIFORM_TOLERANCE,
            source: None,
            photometric_scale: 1.0,
        }
    }

    /// A fixed number of photons per iteration (no longer per texel).
    pub fn set_photons(&mut self, n: u64) {
        self.photons = n;
        self.photons_per_texel = None;
    }

    /// These settings with the photon budget of a run over `covered` texels: the per-texel
    /// budget times `covered` (at least one batch), or the fixed count.
    pub fn with_photon_budget_for(&self, covered: u64) -> Config {
        let mut c = self.clone();
        if let Some(k) = self.photons_per_texel {
            c.photons = ((k * covered as f64).ceil() as u64).max(u64::from(self.batch_size));
        }
        c
    }

    /// The [`Preset::Fast`] settings for `scene`.
    pub fn fast(scene: PathBuf) -> Config {
        Config::for_scene(scene).with_preset(Preset::Fast)
    }

    /// The [`Preset::Paper`] settings for `scene`.
    pub fn paper(scene: PathBuf) -> Config {
        Config::for_scene(scene).with_preset(Preset::Paper)
    }

    /// These settings with `preset`'s values over them.
    pub fn with_preset(mut self, preset: Preset) -> Config {
        match preset {
            Preset::Default => {}
            Preset::Fast => {
                self.gather_rays = 256;
                self.photons_per_texel = Some(PHOTONS_PER_TEXEL / 5.0);
                self.iterations = 2;
                self.refine_passes = 1;
                self.area_samples = 9;
            }
            Preset::Paper => {
                self.exposure = Exposure::Known;
                self.method = Method::Photons;
                self.iterations = Method::Photons.default_iterations();
                self.update = UpdateRule::Paper;
                self.refine_passes = 0;
                self.denoise_radius = 0;
                self.smoothing_radius = 0;
                self.uniform_radius = 0;
            }
        }
        self
    }

    /// Load `path` (a `.toml` run config, or a Mitsuba `.xml` scene for all defaults) and apply
    /// `ov`, then validate.
    pub fn load(path: &Path, ov: &Overrides) -> Result<Config> {
        let is_toml = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("toml"));
        let mut cfg = if is_toml {
            let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
            Self::from_toml_with(path, &text, ov.preset)?
        } else {
            Config::for_scene(path.to_path_buf()).with_preset(ov.preset.unwrap_or(Preset::Default))
        };
        if let Some(m) = ov.method {
            if m != cfg.method {
                cfg.method = m;
                cfg.iterations = m.default_iterations();
            }
        }
        if let Some(v) = ov.photons {
            cfg.set_photons(v);
        }
        if let Some(v) = ov.iterations {
            cfg.iterations = v;
        }
        if let Some(v) = ov.seed {
            cfg.seed = v;
        }
        if let Some(v) = ov.threads {
            cfg.threads = v;
        }
        cfg.validate().map_err(|m| Error::config_in(path, m))?;
        Ok(cfg)
    }
}

impl Config {
    /// The distance between gather points on a shape of bounding radius `shape_radius` in a
    /// scene of bounding-sphere radius `radius`: `gather.spacing`, or when 0, `radius / 32`
    /// (about 5 cm in the Cornell box, 12 cm in a 6 x 3 x 5 m room) and at most
    /// `shape_radius / 16`: secondary light changes over distances of the scene's features,
    /// texels interpolate between the points of their chart, and a small object in a large
    /// scene needs points of its own to follow the light across its faces.
    pub fn gather_spacing_for(&self, radius: f32, shape_radius: f32) -> f32 {
        if self.gather_spacing > 0.0 {
            self.gather_spacing
        } else if shape_radius > 0.0 {
            (radius / 32.0).min(shape_radius / 16.0)
        } else {
            radius / 32.0
        }
    }
}

/// Default sample pairs per texel under an environment light (`light::DirectParams`).
pub const ENV_SAMPLES: u32 = 144;
/// The most `direct.env_samples` accepts (each texel's samples are held at once).
pub const MAX_ENV_SAMPLES: u32 = 65536;

fn default_env_samples() -> u32 {
    ENV_SAMPLES
}

/// Default share of the dense direct-light samples a texel no photo observed draws.
pub const UNOBSERVED_SHARE: f32 = 0.0625;
