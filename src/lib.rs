//! kdmap: recover diffuse reflectance (albedo, `K_d`) textures from HDR photos of a scene
//! whose geometry, lights and cameras are known (Zhdanov & Kupriyanov's method).
//!
//! Data flows one way through the stages, and only [`pipeline`] knows their order:
//!
//! ```text
//! scene (Mitsuba XML or glTF, meshes) -> atlas (geometry store) -> projection (L_orig)
//!   -> denoise (L_orig) -> direct light (E_d, caustics included) -> E_i (photon tracing) -> per-texel update (K_d)
//!   -> shapes of one colour kept to one colour (K_d) -> outputs / checkpoint
//! ```
//!
//! # Layers
//!
//! Each module imports only modules of its own layer listed before it or of the layers
//! below; nothing imports [`pipeline`] but `main.rs`.
//!
//! ```text
//! L4  pipeline                       the order of the stages, start / resume / finish
//! L3  uniform  checkpoint  confidence  output/  accuracy   what a run leaves: the final
//!                                    K_d of one-colour shapes, checkpoints, results,
//!                                    confidence, scores
//! L2  project/  denoise  direct  gather  photon/  solve   the stages, plain functions
//!                                    over tiles
//! L1  config  report  scene/  scatter  image  camera  accel  light/  render  atlas/
//!                                    settings, the scene and its physics, tiles
//! L0  error  rng  progress  fsio  comm  interrupt  mem   no kdmap imports but L0
//! ```
//!
//! Within L1 the order is as listed: `report` uses `config`; `scene` uses `config` (the run's
//! photos and units for glTF scenes); `scatter` samples `scene`'s known materials; `image`,
//! `camera`, `accel` use
//! `scene`; `light` uses `accel`; `render` uses `camera`, `accel`, `image`; `atlas` uses all
//! of them. The L2 stages are independent of each other. A stage's state lives in the tile stores of `atlas`, not in another stage.

pub mod comm;
pub mod error;
pub mod fsio;
pub mod interrupt;
pub mod mem;
pub mod progress;
pub mod rng;

pub mod accel;
pub mod atlas;
pub mod camera;
pub mod config;
pub mod image;
pub mod light;
pub mod render;
pub mod report;
pub mod scatter;
pub mod scene;

pub mod denoise;
pub mod direct;
pub mod gather;
pub mod photon;
pub mod project;
pub mod solve;

pub mod accuracy;
pub mod checkpoint;
pub mod confidence;
pub mod output;
pub mod uniform;

pub mod pipeline;

pub use error::{Error, Result};
