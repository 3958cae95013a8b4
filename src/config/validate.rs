//! The run config's settings checked before any work: each impossible value is refused with
//! a message naming its key and the accepted range.

use super::*;

type Check = std::result::Result<(), String>;

impl Config {
    /// Check that the settings can work; the message names the offending setting.
    pub fn validate(&self) -> Check {
        self.validate_atlas()?;
        self.validate_projection()?;
        self.validate_light()?;
        self.validate_solver()?;
        self.validate_run()?;
        super::views::validate(self)?;
        Ok(())
    }

    /// `[atlas]`.
    fn validate_atlas(&self) -> Check {
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
        Ok(())
    }

    /// `[projection]` and the filters of `[output]`.
    fn validate_projection(&self) -> Check {
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
        if !(0.0..1.0).contains(&self.refine_settle) {
            return Err(format!(
                "projection.refine_settle = {}: must be at least 0 and under 1 (0 = every pass)",
                self.refine_settle
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
        Ok(())
    }

    /// `[direct]`, `[photons]` and `[gather]`.
    fn validate_light(&self) -> Check {
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
        Ok(())
    }

    /// `[solver]`.
    fn validate_solver(&self) -> Check {
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
        Ok(())
    }

    /// `[run]` and `[units]`.
    fn validate_run(&self) -> Check {
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
        if !(0.0..=1.0).contains(&self.min_observed_share) {
            return Err(format!(
                "run.min_observed_share = {}: must be a share in [0, 1]",
                self.min_observed_share
            ));
        }
        let share = self.unobserved_share;
        if !(share.is_finite() && share > 0.0 && share <= 1.0) {
            return Err(format!(
                "run.unobserved_share = {share}: must be a share in (0, 1] of the samples"
            ));
        }
        Ok(())
    }
}
