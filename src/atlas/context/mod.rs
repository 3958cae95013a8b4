//! The run context: everything fixed about a run before any stage (the scene, its BVH, every
//! shape's atlas, their tile layout and the photos), the geometry store built from it, and the
//! table that turns a ray's hit into texture coordinates.

mod geometry;
mod hits;
mod prepare;

pub use geometry::build_geometry;
pub use hits::{HitTable, Prim, SurfaceHit};
pub use prepare::{
    check_lit, match_views, plan_density, prepare, prepare_layout, read_photos, state_dir,
    texel_jacobian, RunContext, ShapeRef,
};
