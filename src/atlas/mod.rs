//! The texture atlas: per-shape UV charts, the texel <-> surface map, the global tile layout,
//! the memory-mapped tile stores that hold per-texel state, and what is fixed about a run
//! before any stage ([`Prepared`]): everything a stage needs to address a texel.

pub mod charts;
pub mod check;
pub mod density;
pub mod geometry;
pub mod hits;
pub mod layout;
pub mod prepared;
pub mod slot_texture;
#[cfg(test)]
pub mod testing;
pub mod texels;
pub mod texture;
pub mod tile_cache;
pub mod tiles;
pub mod unwrap;

pub use geometry::build_geometry;
pub use prepared::{
    check_lit, match_views, prepare, prepare_layout, read_photos, state_dir, Prepared, ShapeRef,
};
