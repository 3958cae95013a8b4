//! kdmap: recover diffuse reflectance (albedo, `K_d`) textures from HDR photos of a scene
//! whose geometry, lights and cameras are known (Zhdanov & Kupriyanov's method).
//!
//! Data flows one way through the stages, and only [`pipeline`] knows their order:
//!
//! ```text
//! scene (Mitsuba XML or glTF, meshes) -> atlas (run context, geometry store)
//!   -> project (L_orig) -> denoise (L_orig) -> direct (E_d, caustics included)
//!   -> [ solve: K_d (eqs. 3-5) -> indirect: E_i (gather or photons) -> update (eqs. 6-9) ]
//!   -> one colour (K_d) -> confidence -> output / checkpoint
//! ```
//!
//! # Layers
//!
//! The folders are the layers. Each module uses only modules of lower layers, or earlier
//! modules of its own layer where the layer's order allows it; nothing but `main.rs` uses
//! [`pipeline`]. The same rule holds inside every folder (`tests/it/layers.rs` checks it at
//! every depth, with each folder's layers).
//!
//! ```text
//! L4  pipeline                       the order of the stages; start, resume, finish; MPI ranks
//! L3  checkpoint  output/  accuracy  what a run leaves: checkpoints, results, scores
//! L2  stages/                        project/ denoise direct/ indirect/ solve/ (independent),
//!                                    then one_colour confidence: plain functions over tiles
//! L1  config report scene/ image physics/ atlas/
//!                                    settings, the immutable scene, light transport, the atlas
//! L0  base/                          error rng progress fsio comm interrupt mem
//! ```
//!
//! Within L1 the order is as listed: `report` uses `config`; `scene` uses `config` (the run's
//! photos and units for glTF scenes); `image` reads photos for `scene`'s sensors; `physics`
//! (ray casting, camera, known materials, lights, the renderer) works on the scene; `atlas`
//! uses all of them. A stage's state lives in the tile stores of `atlas`, not in another stage.

pub mod base;

pub mod atlas;
pub mod config;
pub mod image;
pub mod physics;
pub mod report;
pub mod scene;

pub mod stages;

pub mod accuracy;
pub mod checkpoint;
pub mod output;

pub mod pipeline;

pub use base::error::{Error, Result};
