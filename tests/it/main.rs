//! The integration tests, in one binary (as ripgrep does): each module is one area; one binary
//! links once, which keeps `cargo test --release` (full LTO per test binary) fast enough for CI.

mod accuracy;
mod budget;
mod camera;
mod capture;
mod cli;
mod coat;
mod colmap;
mod diskfull;
mod failfast;
mod fuzz_regressions;
mod gltf;
mod import;
mod known;
mod layers;
mod ldr;
#[cfg(feature = "mpi")]
mod mpi;
mod output;
mod projection;
mod resume;
mod scripting;
mod signals;
mod tiles;
mod truth_refs;
