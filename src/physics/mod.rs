//! Light transport over the immutable scene: the BVH ray caster, Mitsuba's perspective camera,
//! sampling of known materials (mirrors, glass, coats), the light sources' physics, and the
//! renderer of texture-space maps through a camera. No texel state: the atlas and the stages
//! build on these.

pub mod accel;
pub mod bsdf_sampling;
pub mod camera;
pub mod coat;
pub mod film_filter;
pub mod light;
pub mod render;
