//! Indirect light `E_i`: the light a texel receives from the other reconstructed surfaces. Two
//! estimators write it into the same place, each texel's `accum` of the state store, which the
//! solve's update reads: the [`gather`] (the default: rays from gather points to the observed
//! radiance, `L_orig`) and the paper's [`photon`] tracing (light paths through the current
//! `K_d`, deposited per tile).

pub mod gather;
pub mod photon;

use crate::atlas::store::{map_tiles, TexelGeom, TexelState, TileStore};
use crate::atlas::RunContext;
use crate::base::error::Result;
use crate::physics::coat;

/// The photon-traced `E_i` of coated texels made the light their coat lets in, `E_i'`: scaled
/// by the coat's mean transmittance over the hemisphere (interreflected light taken as
/// arriving from every direction alike; documented). The gather weights each of its rays by
/// the coat's transmittance instead. Nothing happens in a scene without coats.
pub fn through_coats(
    p: &RunContext,
    geom: &TileStore<TexelGeom>,
    (state, window): (&mut TileStore<TexelState>, usize),
) -> Result<()> {
    let coats = coat::coats(&p.scene);
    if !coat::any(&coats) {
        return Ok(());
    }
    map_tiles(state, geom, window, |t, _, st| {
        let shape = p.shape_ref(p.layout.slot_of_tile(t as u32)).index as usize;
        if let Some(c) = &coats[shape] {
            let k = c.mean_transmittance();
            for s in st.iter_mut() {
                s.accum = s.accum.map(|v| v * k);
            }
        }
    })?;
    Ok(())
}
