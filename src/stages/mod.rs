//! The stages of a reconstruction, plain functions over the tile stores, in the order the
//! pipeline runs them: projection of the photos (`L_orig`), its denoising, direct light
//! (`E_d`), indirect light (`E_i`, gathered or photon-traced), the per-texel solve (`K_d`);
//! then, on the solved state, shapes of one colour and the confidence of `K_d`. The solving
//! stages are independent of each other; the last two may use them.

pub mod denoise;
pub mod direct;
pub mod indirect;
pub mod project;
pub mod solve;

pub mod confidence;
pub mod one_colour;
