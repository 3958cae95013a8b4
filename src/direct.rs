//! Method step 3 as a stage: the direct irradiance `E_d` of every covered texel from every
//! emitter, with shadows (the physics is `crate::light`), written into the state tiles.

use crate::atlas::layout::{TexelGeom, TexelState};
use crate::atlas::tiles::{map_tiles, TileStore};
use crate::atlas::Prepared;
use crate::config::Config;
use crate::error::Result;
use crate::light::{direct_irradiance, DirectParams};
use crate::progress::{Mode, Stage};
use glam::Vec3;

/// `E_d` of every covered texel into `state`. Returns the area-weighted mean `E_d` over
/// covered texels (the solver's initial `E_i` where a texel has no direct light).
pub fn run(
    p: &Prepared,
    cfg: &Config,
    geom: &TileStore<TexelGeom>,
    state: &mut TileStore<TexelState>,
    mode: Mode,
) -> Result<Vec3> {
    let params = DirectParams {
        area_samples: cfg.area_samples,
        ..DirectParams::default()
    };
    let window = p.window::<TexelState>(cfg);
    let texels = p.layout.tile_texels() as u64;
    let stage = Stage::new(mode, "direct", state.tile_count() as u64, "tiles");
    let sums = map_tiles(state, geom, window, |t, g, st| {
        let mut sum = (Vec3::ZERO, 0.0f64);
        for (off, (g, s)) in g.iter().zip(st.iter_mut()).enumerate() {
            if !g.covered() {
                continue;
            }
            let key = (cfg.seed, t as u64 * texels + off as u64);
            let e = direct_irradiance(&p.scene, &p.accel, g.p(), g.n(), g.ng(), &params, key);
            s.e_d = e.to_array();
            sum.0 += e * g.area;
            sum.1 += g.area as f64;
        }
        stage.inc(1);
        sum
    })?;
    stage.finish();
    let (e, a) = sums
        .iter()
        .fold((Vec3::ZERO, 0.0f64), |acc, s| (acc.0 + s.0, acc.1 + s.1));
    Ok(if a > 0.0 { e / a as f32 } else { Vec3::ZERO })
}
