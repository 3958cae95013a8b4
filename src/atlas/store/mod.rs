//! The memory-mapped tile store: the global tile layout over every shape's texture, the two
//! per-texel records it holds (fixed geometry, evolving solver state), the file-backed
//! [`TileStore`] mapped a window at a time, a bounded cache for random reads, and the
//! invariants checked between stages.

mod cache;
mod check;
mod layout;
mod tiles;

pub use cache::{Reader, TileCache};
pub use check::{check_geometry, check_state};
pub use layout::{flags, Layout, ShapeTiles, TexelGeom, TexelState, TileSpan};
pub use tiles::{
    map_tiles, window_tiles_for_budget, TileStore, FORMAT_VERSION, HEADER_BYTES, MAGIC, TILE_ALIGN,
};
