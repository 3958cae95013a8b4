//! UV layout and texel geometry: each shape's atlas (its own UVs or a fresh unwrap), the
//! density of texels the photos call for, the map from every texel to the surface it stands
//! for, and the charts (UV islands) that texture-space filters must not cross.

mod charts;
pub mod density;
pub mod orient;
mod shape_atlas;
mod texels;
mod unwrap;

pub use charts::{ChartValue, Charts, SlotCharts};
pub use density::{effective_area, DensityPlan, ShapeDensity, LEVELS, OVERSAMPLE};
pub use shape_atlas::{AtlasSettings, ShapeAtlas};
pub use texels::{rasterize, texel_subsamples, TexelMap, TexelSample, MAX_SUBSAMPLES, NONE};
#[cfg(test)]
pub(crate) use unwrap::testutil;
pub use unwrap::{build_atlas, build_atlas_with_progress};
