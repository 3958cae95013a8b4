//! One shape's texture: a slot's tiles read whole or one tile and its halo at a time, written
//! back, and dilated into the gutter, for the passes that need a texel's neighbours.

mod dilate;
mod slot;
mod whole;

pub use dilate::dilate;
pub use slot::{Block, Grid, Scratch, SlotTexture, TexReader};
pub use whole::{read_slot, window, write_slot};
