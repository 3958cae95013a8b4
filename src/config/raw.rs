//! The run config as written in TOML: every key optional but `scene`, unknown keys refused
//! (serde's `deny_unknown_fields`), and each section applied over the preset's values.

use super::views::RawViews;
use super::{Config, Density, Preset, UpdateRule};
use crate::base::error::{Error, Location, Result};
use serde::Deserialize;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The run config as written in TOML. Every field is optional except `scene`.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawConfig {
    /// Mitsuba 3 scene file or glTF 2.0 file (`.gltf`/`.glb`), relative to the config file.
    pub scene: Option<PathBuf>,
    /// The named preset the other keys start from (see [`Preset`]); default `"default"`.
    pub preset: Option<String>,
    /// Sensor id -> photo (relative to the config file), and the capture settings.
    #[serde(default)]
    pub views: RawViews,
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
    pub fine_geometry: Option<bool>,
    pub refine_step: Option<f32>,
    pub refine_gate: Option<f32>,
    pub refine_gated_from: Option<u32>,
    pub refine_settle: Option<f32>,
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
    pub min_observed_share: Option<f64>,
    pub unobserved_share: Option<f32>,
}

/// `texels_per_unit` as written in a run config: a number or `"auto"`.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
pub enum RawDensity {
    PerUnit(f32),
    Named(String),
}

/// What the `[shapes.<id>]` tables say: shapes of known diffuse reflectance, and coated shapes
/// whose base is kept as the scene states it.
type ShapeSettings = (BTreeMap<String, [f32; 3]>, BTreeSet<String>);

/// The `[shapes.<id>]` tables: shapes marked `reconstruct = false` with their reflectance in
/// [0, 1], or without one (a coated shape that keeps its stated base; checked against the
/// scene when it is loaded); anything else is refused.
fn shape_settings(path: &Path, raw: BTreeMap<String, RawShape>) -> Result<ShapeSettings> {
    let (mut known, mut kept) = (BTreeMap::new(), BTreeSet::new());
    for (id, s) in raw {
        let rho = match s.reflectance {
            Some(RawColor::Grey(v)) => Some([v; 3]),
            Some(RawColor::Rgb(v)) => Some(v),
            None => None,
        };
        let bad = |m: &str| Error::config_in(path, format!("[shapes.{id}]: {m}"));
        match (s.reconstruct, rho) {
            (Some(false), Some(r)) if r.iter().all(|v| (0.0..=1.0).contains(v)) => {
                known.insert(id, r);
            }
            (Some(false), Some(_)) => return Err(bad("reflectance must lie in [0, 1]")),
            (Some(false), None) => {
                kept.insert(id);
            }
            (_, Some(_)) => return Err(bad("reflectance is only read with reconstruct = false")),
            (_, None) => {}
        }
    }
    Ok((known, kept))
}

impl Config {
    /// Parse a TOML run config; relative paths resolve against the config file's directory.
    pub fn from_toml(path: &Path, text: &str) -> Result<Config> {
        Self::from_toml_with(path, text, None)
    }

    /// [`Config::from_toml`] starting from `preset` (a command-line flag) instead of the
    /// file's own `preset` key.
    pub(super) fn from_toml_with(
        path: &Path,
        text: &str,
        preset: Option<Preset>,
    ) -> Result<Config> {
        let raw = parse(path, text)?;
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
        raw.views.apply(base, &mut c);
        c.source = Some(path.to_path_buf());
        (c.known_shapes, c.kept_coats) = shape_settings(path, raw.shapes)?;
        raw.atlas.apply(path, &mut c)?;
        raw.projection.apply(&mut c);
        set(&mut c.area_samples, raw.direct.area_samples);
        set(&mut c.env_samples, raw.direct.env_samples);
        set(&mut c.photometric_scale, raw.units.photometric_scale);
        raw.photons.apply(path, &mut c)?;
        raw.solver.apply_method(path, &mut c)?;
        set(&mut c.gather_rays, raw.gather.rays);
        set(&mut c.gather_spacing, raw.gather.spacing);
        raw.solver.apply(path, &mut c)?;
        raw.run.apply(&mut c);
        raw.output.apply(path, &mut c)?;
        Ok(c)
    }
}

/// The TOML text as a [`RawConfig`]; a syntax error or unknown key names its line.
fn parse(path: &Path, text: &str) -> Result<RawConfig> {
    toml::from_str(text).map_err(|e| {
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
    })
}

impl RawAtlas {
    fn apply(self, path: &Path, c: &mut Config) -> Result<()> {
        if let Some(d) = self.texels_per_unit {
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
        set(&mut c.atlas.max_texels, self.max_texels);
        set(&mut c.atlas.padding, self.padding);
        set(&mut c.atlas.use_mesh_uvs, self.use_mesh_uvs);
        set(&mut c.atlas.tile_size, self.tile_size);
        set(&mut c.atlas.max_texture_size, self.max_texture_size);
        Ok(())
    }
}

impl RawProjection {
    fn apply(self, c: &mut Config) {
        set(&mut c.refine_passes, self.refine_passes);
        set(&mut c.fine_geometry, self.fine_geometry);
        set(&mut c.refine_step, self.refine_step);
        set(&mut c.refine_gate, self.refine_gate);
        set(&mut c.refine_gated_from, self.refine_gated_from);
        set(&mut c.refine_settle, self.refine_settle);
        set(&mut c.denoise_radius, self.denoise_radius);
        set(&mut c.denoise_z, self.denoise_z);
        set(&mut c.tv_weight, self.tv_weight);
        set(&mut c.noise_probe, self.noise_probe);
    }
}

impl RawPhotons {
    fn apply(self, path: &Path, c: &mut Config) -> Result<()> {
        if let Some(n) = self.per_iteration {
            c.set_photons(n);
        }
        if self.per_iteration.is_some() && self.per_texel.is_some() {
            return Err(Error::config(format!(
                "{}: photons.per_iteration and photons.per_texel both given: use one",
                path.display()
            )));
        }
        if let Some(k) = self.per_texel {
            c.photons_per_texel = Some(k);
        }
        set(&mut c.batch_size, self.batch_size);
        set(&mut c.max_depth, self.max_depth);
        set(&mut c.smoothing_radius, self.smoothing_radius);
        Ok(())
    }
}

impl RawSolver {
    /// The method first: choosing one sets its default iteration count, which an explicit
    /// `iterations` then overrides.
    fn apply_method(&self, path: &Path, c: &mut Config) -> Result<()> {
        if let Some(m) = &self.method {
            c.method = m.parse().map_err(|_| {
                Error::config_in(
                    path,
                    format!("solver.method = \"{m}\": expected \"gather\" or \"photons\""),
                )
            })?;
            c.iterations = c.method.default_iterations();
        }
        Ok(())
    }

    fn apply(self, path: &Path, c: &mut Config) -> Result<()> {
        set(&mut c.iterations, self.iterations);
        set(&mut c.tolerance, self.tolerance);
        set(&mut c.alpha0, self.alpha0);
        set(&mut c.initial_indirect_share, self.initial_indirect_share);
        set(&mut c.relaxation, self.relaxation);
        if let Some(u) = self.update {
            c.update = match u.as_str() {
                "paper" => UpdateRule::Paper,
                "fixed_point" => UpdateRule::FixedPoint,
                "relaxed" => UpdateRule::Relaxed,
                "secant" => UpdateRule::Secant,
                other => {
                    return Err(Error::config_in(
                        path,
                        format!(
                            "solver.update = \"{other}\": expected \"relaxed\", \"secant\", \
                             \"paper\" or \"fixed_point\""
                        ),
                    ))
                }
            };
        }
        Ok(())
    }
}

impl RawRun {
    fn apply(self, c: &mut Config) {
        set(&mut c.seed, self.seed);
        set(&mut c.threads, self.threads);
        set(
            &mut c.checkpoint_every_batches,
            self.checkpoint_every_batches,
        );
        set(
            &mut c.checkpoint_every_seconds,
            self.checkpoint_every_seconds,
        );
        set(&mut c.memory_budget_mib, self.memory_budget_mib);
        set(&mut c.min_observed_share, self.min_observed_share);
        set(&mut c.unobserved_share, self.unobserved_share);
    }
}

impl RawOutput {
    fn apply(self, path: &Path, c: &mut Config) -> Result<()> {
        set(&mut c.uniform_radius, self.uniform_radius);
        set(&mut c.uniform_tolerance, self.uniform_tolerance);
        if let Some(f) = self.uv_fold {
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
        Ok(())
    }
}

fn set<T>(slot: &mut T, v: Option<T>) {
    if let Some(v) = v {
        *slot = v;
    }
}
