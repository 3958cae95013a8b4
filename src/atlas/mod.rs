//! The texture atlas: where every texel of every reconstructed shape lives and what it stands
//! for. Four concerns, bottom up: the memory-mapped tile [`store`], whole [`texture`]s of a
//! slot, the [`uv`] layout and texel geometry, and the run [`context`] built from them.

pub mod context;
pub mod sigma;
pub mod store;
#[cfg(test)]
pub mod testing;
pub mod texture;
pub mod uv;

pub use context::{
    build_geometry, check_lit, match_views, prepare, prepare_layout, read_photos, state_dir,
    RunContext, ShapeRef,
};
