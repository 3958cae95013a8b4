//! Indirect light `E_i`: the light a texel receives from the other reconstructed surfaces. Two
//! estimators write it into the same place, each texel's `accum` of the state store, which the
//! solve's update reads: the [`gather`] (the default: rays from gather points to the observed
//! radiance, `L_orig`) and the paper's [`photon`] tracing (light paths through the current
//! `K_d`, deposited per tile).

pub mod gather;
pub mod photon;
