//! The run configuration: raw TOML (a `configs/*.toml` file) plus command-line overrides,
//! validated once into a [`Config`] that drives the whole run. Unknown keys are errors, every
//! setting has a documented unit, and impossible combinations are refused here, not deep in a
//! stage.

use crate::base::error::{Error, Location, Result};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The run config as written in TOML. Every field is optional except `scene`.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawConfig {
    /// Mitsuba 3 scene file or glTF 2.0 file (`.gltf`/`.glb`), relative to the config file.
    pub scene: Option<PathBuf>,
    /// The named preset the other keys start from (see [`Preset`]); default `"default"`.
    pub preset: Option<String>,
    /// Sensor id -> EXR path (relative to the config file). Default: `<scene dir>/images/<id>.exr`.
    #[serde(default)]
    pub views: BTreeMap<String, PathBuf>,
    #[serde(default)]
    pub atlas: RawAtlas,
    #[serde(default)]
    pub projection: RawProjection,
    #[serde(default)]
    pub direct: RawDirect,
    #[serde(default)]
    pub photons: RawPhotons,
    #[serde(default)]
    pub gather: RawGather,
    #[serde(default)]
    pub solver: RawSolver,
    #[serde(default)]
    pub run: RawRun,
    /// Per-shape settings, by shape id: `[shapes.<id>] reconstruct = false, reflectance = ...`.
    #[serde(default)]
    pub shapes: BTreeMap<String, RawShape>,
    #[serde(default)]
    pub units: RawUnits,
    #[serde(default)]
    pub output: RawOutput,
}

/// `[output]`: what the output directory holds beyond the contract's fixed files.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawOutput {
    /// `"auto"` (default) or `"off"`: fold tiled shapes' albedo into their input UVs
    /// (`output::uv_fold`).
    pub uv_fold: Option<String>,
    /// Radius in texels of the final filter of uniform shapes' `K_d` (0 = off; `uniform`).
    pub uniform_radius: Option<u32>,
    /// Its relative tolerance: neighbours within this share of a texel's `K_d` are averaged.
    pub uniform_tolerance: Option<f32>,
}

/// `[units]`: how a scene's light values become scene radiance units.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawUnits {
    pub photometric_scale: Option<f32>,
}

/// `[shapes.<id>]`: a shape whose diffuse reflectance the user knows.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawShape {
    pub reconstruct: Option<bool>,
    pub reflectance: Option<RawColor>,
}

/// A reflectance: one number or `[r, g, b]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
pub enum RawColor {
    Grey(f32),
    Rgb([f32; 3]),
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawAtlas {
    pub texels_per_unit: Option<RawDensity>,
    pub max_texels: Option<u64>,
    pub padding: Option<u32>,
    pub use_mesh_uvs: Option<bool>,
    pub tile_size: Option<u32>,
    pub max_texture_size: Option<u32>,
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawProjection {
    pub refine_passes: Option<u32>,
    pub refine_step: Option<f32>,
    pub refine_gate: Option<f32>,
    pub refine_gated_from: Option<u32>,
    pub denoise_radius: Option<u32>,
    pub denoise_z: Option<f32>,
    pub tv_weight: Option<f32>,
    pub noise_probe: Option<bool>,
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawDirect {
    pub area_samples: Option<u32>,
    pub env_samples: Option<u32>,
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawPhotons {
    pub per_iteration: Option<u64>,
    pub per_texel: Option<f64>,
    pub batch_size: Option<u32>,
    pub max_depth: Option<u32>,
    pub smoothing_radius: Option<u32>,
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawGather {
    pub rays: Option<u32>,
    pub spacing: Option<f32>,
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawSolver {
    pub method: Option<String>,
    pub iterations: Option<u32>,
    pub tolerance: Option<f32>,
    pub alpha0: Option<f32>,
    pub update: Option<String>,
    pub relaxation: Option<f32>,
    pub initial_indirect_share: Option<f32>,
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawRun {
    pub seed: Option<u64>,
    pub threads: Option<usize>,
    pub checkpoint_every_batches: Option<u32>,
    pub checkpoint_every_seconds: Option<f64>,
    pub memory_budget_mib: Option<u64>,
}

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
    /// Gathered from the observed radiance of the surfaces around each point (crate::stages::indirect::gather):
    /// converges in one or two passes. The default.
    Gather,
    /// Traced forward from the lights with the current `K_d` (crate::stages::indirect::photon), the paper's
    /// method: the reference.
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
    /// light from unobserved surfaces (measured on the examples: no change after the third);
    /// photon tracing needs several to converge.
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

/// `texels_per_unit` as written in a run config: a number or `"auto"`.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
pub enum RawDensity {
    PerUnit(f32),
    Named(String),
}

/// Most refinement passes a config may ask for (each costs about one projection).
pub const MAX_REFINE_PASSES: u32 = 64;

/// Default refinement passes of the projection. On cbox-tex (128 texels per unit) the mean
/// 8x8-block re-projection error goes from 2.1/1.1/1.5% (no pass) to 1.0/0.7/0.9% (one) and
/// 0.7/0.6/0.6% (three); each pass costs about one projection. Eight, the last four gated
/// ([`REFINE_GATE`], [`REFINE_GATED_FROM`]): textured surfaces keep gaining detail past the
/// fourth pass, while uniform ones drift away from the truth (the same way pass after pass).
/// Sixteen since the passes past the eighth kept sharpening the photo textures seen at grazing
/// angles: cbox-tex's projection floor (noise-free photos of its albedo) at 8 / 32 / 64
/// passes 3.12 / 2.77 / 2.83%, its ceiling 9.8 / 7.8 / 7.9%; held-out albedo of the run at 8
/// / 16 / 24 / 32 / 64 passes 4.48 / 4.35 / 4.34 / 4.35 / 4.45% (with `denoise_z = 4`: 4.42
/// at 8, 4.29 at 16); the uniform boxes are unchanged (cbox 1.12 / 1.13%, mirror-cbox 2.47 /
/// 2.49% at 8 / 16). Each pass costs about one projection (cbox-tex's projection 3.9 -> 7.0
/// s).
pub const REFINE_PASSES: u32 = 16;
/// Default step of the refinement passes after the first (over-relaxation of the
/// back-projection, see `project::apply_refinement`; 1 is the plain weighted mean of the
/// residuals, and the first pass always takes 1, as its robust weights are judged against the
/// plain mean). The passes converge for steps below 2; at 1.8 three passes get about as far
/// as six at step 1. Held-out albedo / relit 8x8 (Mitsuba 3 judge), 3 passes at step 1 and
/// no denoiser (before) -> 4 passes at 1, 1.8, 1.8, 1.8 with the denoiser (now): open
/// 10.35/3.18 -> 8.94/2.71%, lights 4.91/1.47 -> 4.01/1.37%, cbox-tex 5.73/2.91 ->
/// 5.05/2.99%, envmap 5.51/0.80 -> 5.34/0.77%, cbox 1.57/2.31 -> 1.62/2.34%, mirror-cbox
/// 4.72/2.58 -> 4.79/2.64%. Without the denoiser the uniform walls fit more of the photos'
/// noise (all passes at 1.8: cbox 1.71%, mirror-cbox 5.11%).
pub const REFINE_STEP: f32 = 1.8;
/// Default gate of the refinement passes (`project::apply_refinement`): a texel keeps its value
/// in a gated pass when under this share of its views' residual is signal (the mean keep
/// factor of the residual shrinkage over the views; 0 = no gate). Held-out albedo / relit 8x8
/// (Mitsuba 3 judge, 64 spp), 4 passes -> 8 ungated -> 8 with the last four gated at 0.7:
/// cbox-tex 4.88 / 2.50 -> 4.63 / 2.53 -> 4.55 / 2.53%, lights 3.63 / 1.14 -> 3.33 -> 3.47 /
/// 1.12%, open 7.67 / 1.86 -> 7.28 -> 7.57 / 1.87%, envmap 5.11 / 0.72 -> 4.81 -> 5.09 / 0.72%,
/// mirror-cbox 3.04 / 2.21 -> 3.67 -> 3.06 / 2.21%, cbox 1.32 / 2.16 -> 1.46 -> 1.34 / 2.16%.
/// At 0.3: cbox-tex 4.60%, mirror-cbox 3.37%, envmap 5.03%, open 7.32%; at 0.5: envmap 5.09%,
/// open 7.42% (README, "Refinement gate").
pub const REFINE_GATE: f32 = 0.7;
/// Default first gated refinement pass (from 0; the passes before it are not gated). Gating
/// from the second pass (1) suits scenes of uniform surfaces and hurts fine textures seen at
/// grazing angles, whose detail is at the photos' noise level pass by pass: mirror-cbox 2.30%,
/// cbox 1.20%, cbox-tex 4.56% but envmap 6.13%, open 10.44%, lights 3.71% (8 passes, gate
/// 0.7).
pub const REFINE_GATED_FROM: u32 = 4;
/// Default radius in texels of the sigma filter of the projected luminance (`denoise`;
/// 0 = off). Held-out albedo with three passes at step 1.8, without -> with the filter at
/// radius 2: cbox 1.71 -> 1.60%, mirror-cbox 5.11 -> 4.71%, open 9.06 -> 9.04%, lights
/// 4.12 -> 4.07%, cbox-tex 5.14 -> 5.09%, envmap 5.23 -> 5.33%. With three passes at step 1,
/// radius 4 gained a little more than radius 2 on the uniform walls (mirror-cbox 4.20 ->
/// 4.03%) and lost more on the textured grounds (open 10.48 -> 10.51%, envmap 5.70 -> 5.77%).
/// Since texels are judged by their pixels' local noise level (`project::texel_noise_variance`)
/// rather than the view's median, radius 2 / 4 / 8 (four passes, Mitsuba 3 judge at 64 spp):
/// mirror-cbox 3.27 / 3.04 / 3.01%, cbox 1.33 / 1.32%, cbox-tex 4.89 / 4.88 / 4.92%, lights
/// 3.65 / 3.63%, envmap 5.11 / 5.11 / 5.11%, open 7.72 / 7.67 / 7.67%; relit 8x8 within 0.01
/// points. Hence 4.
pub const DENOISE_RADIUS: u32 = 4;
/// Default agreement threshold of the sigma filter, in standard errors of the difference
/// of two texels' values (`denoise`). The texels' standard errors are the photos' noise
/// propagated through the views' weights (`TexelState::l_noise`), which the refinement
/// passes amplify beyond (see `project::probe`): at 2 the filter barely acted on the dim
/// faces of the boxes. Held-out albedo at 2 -> 4 (16 passes, tiled grounds left to the fold):
/// cbox 1.19 -> 1.13%, mirror-cbox 3.05 -> 2.49%, cbox-tex 4.35 -> 4.29%, lights 3.39 ->
/// 3.42%, open 2.32 -> 2.34%, open-b 4.38 -> 4.42%, envmap 1.75 -> 1.75%; at 6 cbox-tex
/// 4.28% (32 passes). Before the grounds were left to the fold, 4 blurred their texture
/// (envmap 1.89 -> 2.52%, open-b 4.73 -> 5.33%).
pub const DENOISE_Z: f32 = 4.0;
/// Default radius in texels of the final filter of uniform shapes' `K_d` (`uniform`), and its
/// relative tolerance. On cbox-tex's four uniform shapes (prototype on the run's textures,
/// held-out albedo of the whole scene, 4.23% before): tolerance / radius 0.15 / 8: 4.01%,
/// 0.15 / 12: 3.97%, 0.25 / 8: 3.97%, 0.25 / 12: 3.93%, 0.4 / 8: 3.95%. The wider, the
/// closer each face to its own mean; 8 keeps the cost at 289 comparisons per texel of those
/// shapes, and 0.25 keeps steps of more than a quarter of the albedo (a stain, a decal).
pub const UNIFORM_RADIUS: u32 = 8;
pub const UNIFORM_TOLERANCE: f32 = 0.25;
/// Largest radius the uniform shapes' filter may be asked for (its cost grows as its square).
pub const MAX_UNIFORM_RADIUS: u32 = 32;
/// Largest total-variation weight a config may ask for (at 2 the checkerboard of the
/// generated open scene is washed out: held-out albedo 30%).
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
    /// A quick look: 2e6 photons x 4 iterations, one refinement pass, 16 shadow rays per
    /// emitter triangle. About a fifth of the default's time, a few points less accurate.
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

/// The `[shapes.<id>]` tables: shapes marked `reconstruct = false` with their reflectance in
/// [0, 1]; anything else is refused.
fn known_shapes(
    path: &Path,
    raw: BTreeMap<String, RawShape>,
) -> Result<BTreeMap<String, [f32; 3]>> {
    let mut out = BTreeMap::new();
    for (id, s) in raw {
        let rho = match s.reflectance {
            Some(RawColor::Grey(v)) => Some([v; 3]),
            Some(RawColor::Rgb(v)) => Some(v),
            None => None,
        };
        let bad = |m: &str| Error::config_in(path, format!("[shapes.{id}]: {m}"));
        match (s.reconstruct, rho) {
            (Some(false), Some(r)) if r.iter().all(|v| (0.0..=1.0).contains(v)) => {
                out.insert(id, r);
            }
            (Some(false), Some(_)) => return Err(bad("reflectance must lie in [0, 1]")),
            (Some(false), None) => {
                return Err(bad(
                    "reconstruct = false needs the shape's `reflectance` (a number or [r, g, b])",
                ))
            }
            (_, Some(_)) => return Err(bad("reflectance is only read with reconstruct = false")),
            (_, None) => {}
        }
    }
    Ok(out)
}

/// Every setting of a run, validated.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Config {
    pub scene: PathBuf,
    /// Sensor id -> image path. Empty means "the scene's `images/<id>.exr`".
    pub views: BTreeMap<String, PathBuf>,
    pub atlas: AtlasConfig,
    /// Iterative back-projection passes after the weighted-mean projection (0 = off).
    pub refine_passes: u32,
    /// The passes' step, in `(0, 2)` ([`REFINE_STEP`]).
    pub refine_step: f32,
    /// The passes' gate, in `[0, 1)` ([`REFINE_GATE`]; 0 = none). Reports written before it
    /// existed read as 0 (they had none).
    #[serde(default)]
    pub refine_gate: f32,
    /// The first gated pass, from 0 ([`REFINE_GATED_FROM`]).
    #[serde(default)]
    pub refine_gated_from: u32,
    /// Radius in texels of the edge-preserving filter of the projected luminance (0 = off,
    /// [`DENOISE_RADIUS`]).
    pub denoise_radius: u32,
    /// Its agreement threshold in standard errors ([`DENOISE_Z`]).
    pub denoise_z: f32,
    /// Weight of the total-variation step after each refinement pass, in units of the
    /// photos' relative noise (0 = off, the default; see `project::tv`).
    pub tv_weight: f32,
    /// Whether the photos' noise through the projection is measured by projecting them again
    /// with added noise (`project::probe`; the default), rather than only propagated through
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
    /// this much time has passed since the last. 0 = at every opportunity.
    #[serde(default)]
    pub checkpoint_every_seconds: f64,
    /// Budget for memory-mapped working sets, MiB.
    pub memory_budget_mib: u64,
    /// Shapes not reconstructed, by id, with the diffuse reflectance the user gives them
    /// (linear RGB): they keep that albedo and take part in the light transport.
    #[serde(default)]
    pub known_shapes: BTreeMap<String, [f32; 3]>,
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
    /// The final filter of uniform shapes' `K_d` (`uniform`, `[output] uniform_radius`,
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
            atlas: AtlasConfig {
                texels_per_unit: Density::Auto,
                max_texels: 0,
                padding: 2,
                use_mesh_uvs: false,
                tile_size: 64,
                max_texture_size: 8192,
            },
            refine_passes: REFINE_PASSES,
            refine_step: REFINE_STEP,
            refine_gate: REFINE_GATE,
            refine_gated_from: REFINE_GATED_FROM,
            denoise_radius: DENOISE_RADIUS,
            denoise_z: DENOISE_Z,
            tv_weight: 0.0,
            noise_probe: true,
            area_samples: 16,
            env_samples: ENV_SAMPLES,
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
            known_shapes: BTreeMap::new(),
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

    /// Parse a TOML run config; relative paths resolve against the config file's directory.
    pub fn from_toml(path: &Path, text: &str) -> Result<Config> {
        Self::from_toml_with(path, text, None)
    }

    /// [`Config::from_toml`] starting from `preset` (a command-line flag) instead of the
    /// file's own `preset` key.
    fn from_toml_with(path: &Path, text: &str, preset: Option<Preset>) -> Result<Config> {
        let raw: RawConfig = toml::from_str(text).map_err(|e| {
            let line = e
                .span()
                .map(|s| text[..s.start.min(text.len())].matches('\n').count() as u32 + 1);
            Error::Input {
                path: path.to_path_buf(),
                loc: Location {
                    line,
                    ..Default::default()
                },
                msg: e.message().to_string(),
            }
        })?;
        let base = path.parent().unwrap_or(Path::new("."));
        let scene = raw.scene.ok_or_else(|| {
            Error::input(
                path,
                "missing `scene = \"...\"` (the Mitsuba XML or glTF file)",
            )
        })?;
        let file_preset = match raw.preset.as_deref() {
            None => Preset::Default,
            Some(name) => Preset::parse(name).ok_or_else(|| {
                Error::config_in(
                    path,
                    format!("preset = \"{name}\": expected \"default\", \"fast\" or \"paper\""),
                )
            })?,
        };
        let mut c = Config::for_scene(base.join(scene)).with_preset(preset.unwrap_or(file_preset));
        c.views = raw
            .views
            .into_iter()
            .map(|(k, v)| (k, base.join(v)))
            .collect();
        c.source = Some(path.to_path_buf());
        c.known_shapes = known_shapes(path, raw.shapes)?;
        let a = raw.atlas;
        if let Some(d) = a.texels_per_unit {
            c.atlas.texels_per_unit = match d {
                RawDensity::PerUnit(v) => Density::PerUnit(v),
                RawDensity::Named(n) if n == "auto" => Density::Auto,
                RawDensity::Named(n) => {
                    return Err(Error::config_in(
                        path,
                        format!(
                            "atlas.texels_per_unit = \"{n}\": expected \"auto\" or a number \
                             of texels per scene unit"
                        ),
                    ))
                }
            };
        }
        set(&mut c.atlas.max_texels, a.max_texels);
        set(&mut c.atlas.padding, a.padding);
        set(&mut c.atlas.use_mesh_uvs, a.use_mesh_uvs);
        set(&mut c.atlas.tile_size, a.tile_size);
        set(&mut c.atlas.max_texture_size, a.max_texture_size);
        set(&mut c.refine_passes, raw.projection.refine_passes);
        set(&mut c.refine_step, raw.projection.refine_step);
        set(&mut c.refine_gate, raw.projection.refine_gate);
        set(&mut c.refine_gated_from, raw.projection.refine_gated_from);
        set(&mut c.denoise_radius, raw.projection.denoise_radius);
        set(&mut c.denoise_z, raw.projection.denoise_z);
        set(&mut c.tv_weight, raw.projection.tv_weight);
        set(&mut c.noise_probe, raw.projection.noise_probe);
        set(&mut c.area_samples, raw.direct.area_samples);
        set(&mut c.env_samples, raw.direct.env_samples);
        set(&mut c.photometric_scale, raw.units.photometric_scale);
        let p = raw.photons;
        if let Some(n) = p.per_iteration {
            c.set_photons(n);
        }
        if p.per_iteration.is_some() && p.per_texel.is_some() {
            return Err(Error::config(format!(
                "{}: photons.per_iteration and photons.per_texel both given: use one",
                path.display()
            )));
        }
        if let Some(k) = p.per_texel {
            c.photons_per_texel = Some(k);
        }
        set(&mut c.batch_size, p.batch_size);
        set(&mut c.max_depth, p.max_depth);
        set(&mut c.smoothing_radius, p.smoothing_radius);
        let s = raw.solver;
        if let Some(m) = s.method {
            c.method = m.parse().map_err(|_| {
                Error::config_in(
                    path,
                    format!("solver.method = \"{m}\": expected \"gather\" or \"photons\""),
                )
            })?;
            c.iterations = c.method.default_iterations();
        }
        set(&mut c.gather_rays, raw.gather.rays);
        set(&mut c.gather_spacing, raw.gather.spacing);
        set(&mut c.iterations, s.iterations);
        set(&mut c.tolerance, s.tolerance);
        set(&mut c.alpha0, s.alpha0);
        set(&mut c.initial_indirect_share, s.initial_indirect_share);
        set(&mut c.relaxation, s.relaxation);
        if let Some(u) = s.update {
            c.update = match u.as_str() {
                "paper" => UpdateRule::Paper,
                "fixed_point" => UpdateRule::FixedPoint,
                "relaxed" => UpdateRule::Relaxed,
                "secant" => UpdateRule::Secant,
                other => {
                    return Err(Error::config_in(
                        path,
                        format!(
                            "solver.update = \"{other}\": expected \"relaxed\", \"secant\", \"paper\" or \"fixed_point\""
                        ),
                    ))
                }
            };
        }
        let r = raw.run;
        set(&mut c.seed, r.seed);
        set(&mut c.threads, r.threads);
        set(&mut c.checkpoint_every_batches, r.checkpoint_every_batches);
        set(&mut c.checkpoint_every_seconds, r.checkpoint_every_seconds);
        set(&mut c.memory_budget_mib, r.memory_budget_mib);
        set(&mut c.uniform_radius, raw.output.uniform_radius);
        set(&mut c.uniform_tolerance, raw.output.uniform_tolerance);
        if let Some(f) = raw.output.uv_fold {
            c.uv_fold = match f.as_str() {
                "auto" => true,
                "off" => false,
                other => {
                    return Err(Error::config_in(
                        path,
                        format!("output.uv_fold = \"{other}\": expected \"auto\" or \"off\""),
                    ))
                }
            };
        }
        Ok(c)
    }

    /// Check that the settings can work; the message names the offending setting.
    pub fn validate(&self) -> std::result::Result<(), String> {
        let a = &self.atlas;
        if let Density::PerUnit(d) = a.texels_per_unit {
            if !(d.is_finite() && d > 0.0) {
                return Err(format!(
                    "atlas.texels_per_unit = {d}: must be \"auto\" or a positive number of \
                     texels per scene unit"
                ));
            }
        }
        if a.tile_size == 0 || a.tile_size > 1024 {
            return Err(format!(
                "atlas.tile_size = {}: must be 1..=1024 texels",
                a.tile_size
            ));
        }
        if a.max_texture_size == 0 || a.max_texture_size > 65536 {
            return Err(format!(
                "atlas.max_texture_size = {}: must be 1..=65536 texels",
                a.max_texture_size
            ));
        }
        if self.refine_passes > MAX_REFINE_PASSES {
            return Err(format!(
                "projection.refine_passes = {}: must be 0..={MAX_REFINE_PASSES}",
                self.refine_passes
            ));
        }
        if !(self.refine_step > 0.0 && self.refine_step < 2.0) {
            return Err(format!(
                "projection.refine_step = {}: must be between 0 and 2 (exclusive; the passes \
                 diverge at 2 and beyond)",
                self.refine_step
            ));
        }
        if !(0.0..1.0).contains(&self.refine_gate) {
            return Err(format!(
                "projection.refine_gate = {}: must be at least 0 and under 1 (0 = no gate; at 1 \
                 no texel would ever pass)",
                self.refine_gate
            ));
        }
        if self.refine_gated_from > MAX_REFINE_PASSES {
            return Err(format!(
                "projection.refine_gated_from = {}: must be 0..={MAX_REFINE_PASSES}",
                self.refine_gated_from
            ));
        }
        if self.denoise_radius > MAX_DENOISE_RADIUS {
            return Err(format!(
                "projection.denoise_radius = {}: must be 0..={MAX_DENOISE_RADIUS} texels",
                self.denoise_radius
            ));
        }
        if self.uniform_radius > MAX_UNIFORM_RADIUS {
            return Err(format!(
                "output.uniform_radius = {}: must be 0..={MAX_UNIFORM_RADIUS} texels (0 = off)",
                self.uniform_radius
            ));
        }
        if !(self.uniform_tolerance > 0.0 && self.uniform_tolerance.is_finite()) {
            return Err(format!(
                "output.uniform_tolerance = {}: must be a positive share of the albedo",
                self.uniform_tolerance
            ));
        }
        if !(self.denoise_z > 0.0 && self.denoise_z.is_finite()) {
            return Err(format!(
                "projection.denoise_z = {}: must be a positive number of standard errors",
                self.denoise_z
            ));
        }
        if !(0.0..=MAX_TV_WEIGHT).contains(&self.tv_weight) {
            return Err(format!(
                "projection.tv_weight = {}: must be 0..={MAX_TV_WEIGHT} (0 = off)",
                self.tv_weight
            ));
        }
        if self.area_samples == 0 {
            return Err(
                "direct.area_samples = 0: need at least 1 sample per emitter triangle".into(),
            );
        }
        if self.env_samples == 0 || self.env_samples > MAX_ENV_SAMPLES {
            return Err(format!(
                "direct.env_samples = {}: must be 1..={MAX_ENV_SAMPLES} sample pairs per texel",
                self.env_samples
            ));
        }
        if self.photons == 0 {
            return Err("photons = 0: need at least one light path per iteration".into());
        }
        if let Some(k) = self.photons_per_texel {
            if !(k.is_finite() && k > 0.0 && k <= 1e6) {
                return Err(format!(
                    "photons.per_texel = {k}: must be a number of photons per covered texel in \
                     (0, 1e6]"
                ));
            }
        }
        if self.gather_rays == 0 {
            return Err("gather.rays = 0: need at least one ray per gather point".into());
        }
        if !(self.gather_spacing.is_finite() && self.gather_spacing >= 0.0) {
            return Err(format!(
                "gather.spacing = {}: must be a distance in scene units >= 0 (0 = automatic)",
                self.gather_spacing
            ));
        }
        if self.batch_size == 0 {
            return Err("photons.batch_size = 0: must be at least 1".into());
        }
        if self.max_depth == 0 {
            return Err("photons.max_depth = 0: must be at least 1 bounce".into());
        }
        if self.iterations == 0 {
            return Err("iterations = 0: need at least one iteration".into());
        }
        if !(self.tolerance.is_finite() && self.tolerance >= 0.0) {
            return Err(format!(
                "solver.tolerance = {}: must be a fraction >= 0",
                self.tolerance
            ));
        }
        if !(self.alpha0.is_finite() && self.alpha0 > 0.0) {
            return Err(format!("solver.alpha0 = {}: must be > 0", self.alpha0));
        }
        if !(self.relaxation > 0.0 && self.relaxation <= 1.0) {
            return Err(format!(
                "solver.relaxation = {}: must be in (0, 1]",
                self.relaxation
            ));
        }
        if !(self.initial_indirect_share.is_finite() && self.initial_indirect_share >= 0.0) {
            return Err(format!(
                "solver.initial_indirect_share = {}: must be >= 0",
                self.initial_indirect_share
            ));
        }
        if self.threads > 1024 {
            return Err(format!("threads = {}: at most 1024", self.threads));
        }
        if self.checkpoint_every_batches == 0 {
            return Err("run.checkpoint_every_batches = 0: must be at least 1".into());
        }
        if !(self.checkpoint_every_seconds.is_finite() && self.checkpoint_every_seconds >= 0.0) {
            return Err(format!(
                "run.checkpoint_every_seconds = {}: must be a number of seconds >= 0",
                self.checkpoint_every_seconds
            ));
        }
        if !(self.photometric_scale.is_finite() && self.photometric_scale > 0.0) {
            return Err(format!(
                "units.photometric_scale = {}: must be a positive number of scene units per \
                 photometric unit",
                self.photometric_scale
            ));
        }
        if self.memory_budget_mib < 16 {
            return Err(format!(
                "run.memory_budget_mib = {}: at least 16 MiB",
                self.memory_budget_mib
            ));
        }
        Ok(())
    }
}

impl Config {
    /// The distance between gather points on a shape of bounding radius `shape_radius` in a
    /// scene of bounding-sphere radius `radius`: `gather.spacing`, or when 0, `radius / 32`
    /// (about 5.4 cm in the Cornell box, 12 cm in a 6 x 3 x 5 m room) and at most
    /// `shape_radius / 16`: secondary light changes over distances of the scene's features,
    /// texels interpolate between the points of their chart, and a small object in a large
    /// scene needs its own points to follow the light across it (on the generated open scene,
    /// a 20 m ground with a box, a sphere and a torus about a metre across, the scene's 44 cm
    /// left 3-4 points per side of the box: its shadowed faces came out 14% too bright, the
    /// box's texels 13.4% off on average; at 5 cm, 4.7%).
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

fn set<T>(slot: &mut T, v: Option<T>) {
    if let Some(v) = v {
        *slot = v;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gather_spacing_follows_the_scene_and_small_shapes_unless_set() {
        let mut c = Config::for_scene("a.xml".into());
        assert_eq!(
            c.gather_spacing_for(32.0, 100.0),
            1.0,
            "a shape as large as the scene"
        );
        assert_eq!(
            c.gather_spacing_for(32.0, 8.0),
            0.5,
            "a small shape: its own sixteenth"
        );
        assert_eq!(c.gather_spacing_for(32.0, 0.0), 1.0, "a degenerate shape");
        c.gather_spacing = 0.25;
        assert_eq!(c.gather_spacing_for(32.0, 8.0), 0.25, "as configured");
    }

    #[test]
    fn toml_overrides_defaults_and_paths_resolve_against_the_file() {
        let text = r#"
            scene = "scenes/a.xml"
            [views]
            cam0 = "photos/c0.exr"
            [atlas]
            texels_per_unit = 32.0
            [solver]
            iterations = 3
            update = "fixed_point"
        "#;
        let c = Config::from_toml(Path::new("/x/y/run.toml"), text).unwrap();
        assert_eq!(c.scene, PathBuf::from("/x/y/scenes/a.xml"));
        assert_eq!(c.views["cam0"], PathBuf::from("/x/y/photos/c0.exr"));
        assert_eq!(c.atlas.texels_per_unit, Density::PerUnit(32.0));
        assert_eq!(c.iterations, 3);
        assert_eq!(c.update, UpdateRule::FixedPoint);
        // untouched settings keep their defaults
        let d = Config::for_scene(PathBuf::new());
        assert_eq!(c.photons, d.photons);
        assert_eq!(c.alpha0, d.alpha0);
    }

    #[test]
    fn texel_density_is_auto_by_default_a_number_or_auto_and_nothing_else() {
        let d = Config::for_scene(PathBuf::new());
        assert_eq!(d.atlas.texels_per_unit, Density::Auto);
        let at = |v: &str| {
            let text = format!("scene = \"a.xml\"\n[atlas]\ntexels_per_unit = {v}\n");
            Config::from_toml(Path::new("run.toml"), &text)
        };
        assert_eq!(
            at("48").unwrap().atlas.texels_per_unit,
            Density::PerUnit(48.0)
        );
        assert_eq!(at("\"auto\"").unwrap().atlas.texels_per_unit, Density::Auto);
        let e = at("\"fine\"").unwrap_err().to_string();
        assert!(e.contains("\"fine\"") && e.contains("auto"), "{e}");
        let text = "scene = \"a.xml\"\n[atlas]\nmax_texels = 5000\n";
        let c = Config::from_toml(Path::new("run.toml"), text).unwrap();
        assert_eq!(c.atlas.max_texels, 5000);
    }

    /// `[output] uv_fold`: on by default ("auto"), "off" turns it off, anything else is refused
    /// with the key and the values it takes.
    #[test]
    fn uv_fold_is_auto_or_off() {
        let at = |v: &str| {
            let text = format!("scene = \"a.xml\"\n[output]\nuv_fold = {v}\n");
            Config::from_toml(Path::new("run.toml"), &text)
        };
        assert!(Config::for_scene("a.xml".into()).uv_fold);
        assert!(at("\"auto\"").unwrap().uv_fold);
        assert!(!at("\"off\"").unwrap().uv_fold);
        let e = at("\"on\"").unwrap_err().to_string();
        assert!(
            e.contains("output.uv_fold = \"on\"") && e.contains("\"off\""),
            "{e}"
        );
        assert!(at("true").is_err());
    }

    #[test]
    fn unknown_key_is_an_error_naming_file_and_line() {
        let text = "scene = \"a.xml\"\n[atlas]\ntexels_per_unt = 3.0\n";
        let e = Config::from_toml(Path::new("run.toml"), text)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("run.toml (line 3)"), "{e}");
        assert!(e.contains("texels_per_unt"), "{e}");
        assert!(!e.contains('\n'));
    }

    #[test]
    fn impossible_settings_are_refused() {
        let mut c = Config::for_scene("s.xml".into());
        assert!(c.validate().is_ok());
        c.photons = 0;
        assert!(c.validate().unwrap_err().contains("photons"));
        let mut c = Config::for_scene("s.xml".into());
        c.atlas.texels_per_unit = Density::PerUnit(f32::NAN);
        assert!(c.validate().unwrap_err().contains("texels_per_unit"));
        let mut c = Config::for_scene("s.xml".into());
        c.iterations = 0;
        assert!(c.validate().unwrap_err().contains("iterations"));
        let mut c = Config::for_scene("s.xml".into());
        c.refine_passes = MAX_REFINE_PASSES + 1;
        assert!(c.validate().unwrap_err().contains("refine_passes"));
        for step in [0.0, 2.0, -1.0, f32::NAN] {
            let mut c = Config::for_scene("s.xml".into());
            c.refine_step = step;
            assert!(c.validate().unwrap_err().contains("refine_step"), "{step}");
        }
        for gate in [-0.1, 1.0, f32::NAN] {
            let mut c = Config::for_scene("s.xml".into());
            c.refine_gate = gate;
            assert!(c.validate().unwrap_err().contains("refine_gate"), "{gate}");
        }
        let mut c = Config::for_scene("s.xml".into());
        c.refine_gated_from = MAX_REFINE_PASSES + 1;
        assert!(c.validate().unwrap_err().contains("refine_gated_from"));
        let mut c = Config::for_scene("s.xml".into());
        c.uniform_radius = MAX_UNIFORM_RADIUS + 1;
        assert!(c.validate().unwrap_err().contains("uniform_radius"));
        for t in [0.0, -0.1, f32::NAN, f32::INFINITY] {
            let mut c = Config::for_scene("s.xml".into());
            c.uniform_tolerance = t;
            assert!(
                c.validate().unwrap_err().contains("uniform_tolerance"),
                "{t}"
            );
        }
        let mut c = Config::for_scene("s.xml".into());
        c.denoise_radius = MAX_DENOISE_RADIUS + 1;
        assert!(c.validate().unwrap_err().contains("denoise_radius"));
        for z in [0.0, -1.0, f32::NAN, f32::INFINITY] {
            let mut c = Config::for_scene("s.xml".into());
            c.denoise_z = z;
            assert!(c.validate().unwrap_err().contains("denoise_z"), "{z}");
        }
        for w in [-0.1, MAX_TV_WEIGHT + 0.1, f32::NAN] {
            let mut c = Config::for_scene("s.xml".into());
            c.tv_weight = w;
            assert!(c.validate().unwrap_err().contains("tv_weight"), "{w}");
        }
    }

    /// `[direct] env_samples` sets the pairs per texel under an environment light; 0 and
    /// more than the cap are refused with the key named.
    #[test]
    fn direct_section_sets_env_samples() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("run.toml");
        std::fs::write(&p, "scene = \"s.xml\"\n[direct]\nenv_samples = 1024\n").unwrap();
        let c = Config::load(&p, &Overrides::default()).unwrap();
        assert_eq!(c.env_samples, 1024);
        assert_eq!(Config::for_scene("s.xml".into()).env_samples, ENV_SAMPLES);
        for bad in [0, MAX_ENV_SAMPLES + 1] {
            let mut c = Config::for_scene("s.xml".into());
            c.env_samples = bad;
            assert!(
                c.validate().unwrap_err().contains("direct.env_samples"),
                "{bad}"
            );
        }
    }

    #[test]
    fn projection_section_sets_refine_passes() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("run.toml");
        std::fs::write(
            &p,
            "scene = \"s.xml\"\n[projection]\nrefine_passes = 1\nrefine_step = 1.25\n\
             refine_gate = 0.5\nrefine_gated_from = 2\ndenoise_radius = 3\ndenoise_z = 2.5\n\
             tv_weight = 0.2\nnoise_probe = false\n",
        )
        .unwrap();
        let c = Config::load(&p, &Overrides::default()).unwrap();
        assert!(!c.noise_probe);
        assert!(
            Config::for_scene("s.xml".into()).noise_probe,
            "on by default"
        );
        assert_eq!((c.refine_passes, c.refine_step), (1, 1.25));
        assert_eq!((c.refine_gate, c.refine_gated_from), (0.5, 2));
        assert_eq!((c.denoise_radius, c.denoise_z), (3, 2.5));
        assert_eq!(c.tv_weight, 0.2);
        std::fs::write(&p, "scene = \"s.xml\"\n[projection]\nrefine = 1\n").unwrap();
        let e = Config::load(&p, &Overrides::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("refine"), "{e}");
    }

    #[test]
    fn presets_set_their_values_and_file_keys_win_over_them() {
        let d = Config::for_scene("s.xml".into());
        let f = Config::fast("s.xml".into());
        let budget = |c: &Config| c.with_photon_budget_for(1_000_000).photons;
        assert!(budget(&f) < budget(&d) && f.iterations < d.iterations);
        assert!(f.refine_passes < d.refine_passes && f.validate().is_ok());
        let p = Config::paper("s.xml".into());
        assert_eq!(
            (p.update, p.refine_passes, p.smoothing_radius),
            (UpdateRule::Paper, 0, 0)
        );
        let text = "scene = \"s.xml\"\npreset = \"fast\"\n[photons]\nper_iteration = 7\n";
        let c = Config::from_toml(Path::new("r.toml"), text).unwrap();
        assert_eq!((c.photons, c.iterations), (7, f.iterations));
        // a preset flag replaces the file's preset, the file's keys still apply
        let c = Config::from_toml_with(Path::new("r.toml"), text, Some(Preset::Paper)).unwrap();
        assert_eq!((c.photons, c.update), (7, UpdateRule::Paper));
        let e = Config::from_toml(
            Path::new("r.toml"),
            "scene = \"s.xml\"\npreset = \"turbo\"\n",
        )
        .unwrap_err();
        assert!(
            e.to_string().starts_with("r.toml: preset = \"turbo\""),
            "{e}"
        );
        assert_eq!(e.exit_code(), crate::base::error::exit::CONFIG);
    }

    #[test]
    fn photon_budgets_per_texel_resolve_with_the_atlas_and_fixed_counts_win() {
        let d = Config::for_scene("s.xml".into());
        // the default: PHOTONS_PER_TEXEL per covered texel, at least one batch
        assert_eq!(d.with_photon_budget_for(200_000).photons, 20_000_000);
        assert_eq!(d.with_photon_budget_for(10).photons, d.batch_size as u64);
        let r = Path::new("r.toml");
        let c = Config::from_toml(r, "scene = \"s.xml\"\n[photons]\nper_texel = 2.5\n").unwrap();
        assert_eq!(c.with_photon_budget_for(1_000_000).photons, 2_500_000);
        // a fixed count is kept whatever the atlas
        let c = Config::from_toml(r, "scene = \"s.xml\"\n[photons]\nper_iteration = 9\n").unwrap();
        assert_eq!(
            (
                c.photons_per_texel,
                c.with_photon_budget_for(5_000_000).photons
            ),
            (None, 9)
        );
        let both = "scene = \"s.xml\"\n[photons]\nper_iteration = 9\nper_texel = 3\n";
        let e = Config::from_toml(r, both).unwrap_err();
        assert!(e.to_string().contains("per_texel"), "{e}");
        for bad in ["0", "-1", "nan", "1e9"] {
            let t = format!("scene = \"s.xml\"\n[photons]\nper_texel = {bad}\n");
            let e = Config::from_toml(r, &t).and_then(|c| {
                c.validate().map_err(Error::config)?;
                Ok(c)
            });
            assert!(e.is_err(), "per_texel = {bad} accepted");
        }
        let mut c = d.clone();
        c.set_photons(42);
        assert_eq!(c.with_photon_budget_for(1 << 30).photons, 42);
    }

    #[test]
    fn flags_override_config() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("run.toml");
        std::fs::write(&p, "scene = \"s.xml\"\n[photons]\nper_iteration = 5\n").unwrap();
        let c = Config::load(&p, &Overrides::default()).unwrap();
        assert_eq!(c.photons, 5);
        let ov = Overrides {
            photons: Some(7),
            iterations: Some(2),
            seed: Some(9),
            threads: Some(1),
            ..Default::default()
        };
        let c = Config::load(&p, &ov).unwrap();
        assert_eq!((c.photons, c.iterations, c.seed, c.threads), (7, 2, 9, 1));
        let ov = Overrides {
            photons: Some(0),
            ..Default::default()
        };
        let e = Config::load(&p, &ov).unwrap_err();
        assert_eq!(e.exit_code(), crate::base::error::exit::CONFIG);
        let e = e.to_string();
        assert!(e.contains("run.toml") && e.contains("photons"), "{e}");
    }
}

#[cfg(test)]
mod example_config {
    use super::*;

    /// The documented example in `configs/` parses and validates.
    #[test]
    fn shipped_example_config_is_valid() {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/example.toml");
        let c = Config::load(&p, &Overrides::default()).unwrap();
        assert_eq!(c.views.len(), 3);
        assert!(c.scene.ends_with("tests/fixtures/cbox/input.xml"));
        assert!(c.scene.is_file(), "{}", c.scene.display());
    }

    /// The 100M-texel run's config (its scene is generated into the cache on demand) parses,
    /// validates and asks for the density the README's figures were measured at.
    #[test]
    fn room_100m_config_is_valid() {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/room-100m.toml");
        let c = Config::load(&p, &Overrides::default()).unwrap();
        assert!(c.scene.ends_with("cache/scenes/room-pointspot/input.xml"));
        assert_eq!(c.atlas.texels_per_unit.per_unit(), Some(820.0));
        assert_eq!(c.memory_budget_mib, 1024);
    }
}
