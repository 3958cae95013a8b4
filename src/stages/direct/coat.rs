//! Direct light under a coat: a coated texel's base receives `E_d'`, each emitter's
//! irradiance times the coat's transmittance `t(cos)` towards it (see `physics::coat`): exact
//! for point, spot and directional lights; for an area light the share is the unoccluded
//! irradiance's mean of `t` over a fixed set of points of the emitter (up to 16 per triangle,
//! area-weighted), for an environment light the hemisphere's mean `t` (documented
//! approximations: the shadowed part of an area light is taken to pass the coat as the whole).

use crate::physics::coat::{self, Coat, Patch};
use crate::physics::light::Footprint;
use crate::scene::{Emitter, Scene};
use glam::Vec3;

/// The scene's coats by shape, and every area emitter's points (empty for the others).
pub struct Coats<'a> {
    scene: &'a Scene,
    coats: Vec<Option<Coat>>,
    patches: Vec<Vec<Patch>>,
}

/// One coated shape's view of the emitters.
pub struct TileCoat<'a> {
    scene: &'a Scene,
    coat: &'a Coat,
    patches: &'a [Vec<Patch>],
}

impl<'a> Coats<'a> {
    pub fn of(scene: &'a Scene) -> Coats<'a> {
        let patches = scene
            .emitters
            .iter()
            .map(|e| coat::patches(scene, e))
            .collect();
        Coats {
            scene,
            coats: coat::coats(scene),
            patches,
        }
    }

    /// The coat of shape `shape`, if it has one.
    pub fn of_shape(&self, shape: usize) -> Option<TileCoat<'_>> {
        let coat = self.coats.get(shape)?.as_ref()?;
        Some(TileCoat {
            scene: self.scene,
            coat,
            patches: &self.patches,
        })
    }
}

impl TileCoat<'_> {
    /// The share of emitter `k`'s irradiance at `fp` that the coat lets through.
    pub fn share(&self, fp: &Footprint, k: usize) -> f32 {
        let towards = |q: Vec3| (q - fp.p).normalize_or_zero().dot(fp.n);
        let cos = match &self.scene.emitters[k] {
            Emitter::Point { position, .. } | Emitter::Spot { position, .. } => towards(*position),
            Emitter::Directional { direction, .. } => -direction.dot(fp.n),
            Emitter::Area { .. } => return self.area_share(fp, &self.patches[k]),
            Emitter::Environment(_) => return self.coat.mean_transmittance(),
        };
        self.coat.transmittance(cos)
    }

    /// The mean of `t` over an area emitter's points, weighted by their unoccluded irradiance.
    fn area_share(&self, fp: &Footprint, patches: &[Patch]) -> f32 {
        let (mut sum, mut weight) = (0.0f32, 0.0f32);
        for &(q, nq, a) in patches {
            let d = q - fp.p;
            let r2 = d.length_squared();
            if r2 <= 0.0 {
                continue;
            }
            let w = d / r2.sqrt();
            let (ci, cl) = (w.dot(fp.n), -w.dot(nq));
            if ci > 0.0 && cl > 0.0 {
                let e = ci * cl * a / r2;
                sum += e * self.coat.transmittance(ci);
                weight += e;
            }
        }
        match weight > 0.0 {
            true => sum / weight,
            false => self.coat.mean_transmittance(),
        }
    }
}
