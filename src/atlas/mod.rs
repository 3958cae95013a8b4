//! The texture atlas: per-shape UV charts, the texel <-> surface map, and the memory-mapped
//! tile store that holds per-texel state.

pub mod layout;
pub mod texels;
pub mod tiles;
pub mod unwrap;
