//! The base layer: what every other module may use and that uses nothing of kdmap's but itself.
//! Error kinds and exit codes, atomic file writes, counter-based random numbers, progress and
//! notes, the processes of a run (one, or an MPI job's ranks), interrupts, memory readings.

pub mod comm;
pub mod error;
pub mod fsio;
pub mod interrupt;
pub mod mem;
pub mod progress;
pub mod rng;
