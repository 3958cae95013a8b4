//! kdmap: recover diffuse reflectance (albedo, `K_d`) textures from HDR photos of a scene
//! whose geometry, lights and cameras are known (Zhdanov & Kupriyanov's method).
//!
//! Data flows one way through the stages (only `pipeline` knows their order):
//!
//! ```text
//! scene (XML, meshes) -> atlas -> texel samples -> projection (L_orig)
//!   -> direct light (E_d) -> photon tracing (E_i) -> per-texel update (K_d) -> outputs / checkpoint
//! ```

pub mod accel;
pub mod atlas;
pub mod camera;
pub mod checkpoint;
pub mod config;
pub mod error;
pub mod image;
pub mod light;
pub mod output;
pub mod photon;
pub mod pipeline;
pub mod progress;
pub mod project;
pub mod render;
pub mod report;
pub mod rng;
pub mod scene;
pub mod solve;
pub mod truth;

pub use error::{Error, Result};
