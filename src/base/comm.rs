//! The processes of one run and the few collective operations the pipeline needs to share the
//! heavy stages between them: one process ([`World::solo`], the default build and every run
//! not started by an MPI launcher) or the ranks of an MPI job (`--features mpi`: rsmpi over
//! the system's MPI, when `mpirun` or `srun` started the process; see [`init`]).
//!
//! The operations move bytes in rank order and nothing else. Which rank computes which tile,
//! photon batch or gather chunk, and in which order the pieces are combined, is decided by
//! `pipeline` from the data (unit `u` belongs to rank `u mod N`, results are combined in unit
//! order), so a job's results are the same bits for every rank count.
//!
//! Every operation is collective: every rank calls the same operations in the same order,
//! from its main thread only. [`world`] is process-global, as MPI's world communicator is.
//! The time spent inside the operations (waiting for slower ranks included) and the bytes this
//! rank sent and received are counted ([`World::traffic`]) for the report.
//!
//! Hand-written because what it wraps is small: rsmpi's collectives take fixed-size element
//! counts (`i32`) and no error values; this module splits large messages and adds the counts.

#[cfg(feature = "mpi")]
mod mpi_job;

use crate::base::error::{Error, Result};
use serde::de::DeserializeOwned;
use serde::Serialize;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::OnceLock;
use std::time::Instant;

/// The processes of this run.
pub struct World {
    backend: Backend,
    bytes: AtomicU64,
    nanos: AtomicU64,
}

enum Backend {
    Solo,
    #[cfg(feature = "mpi")]
    Mpi(mpi_job::Job),
}

/// Bytes this rank sent and received, and seconds inside collective operations, so far.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Traffic {
    pub bytes: u64,
    pub seconds: f64,
}

static WORLD: OnceLock<World> = OnceLock::new();

/// The processes of this run: the MPI job's ranks after [`init`] found a launcher, else this
/// process alone.
pub fn world() -> &'static World {
    WORLD.get_or_init(World::solo)
}

/// Keeps MPI initialized while it lives; dropping it finalizes MPI (a successful end only:
/// see [`Guard::exit`]).
pub struct Guard {
    #[cfg(feature = "mpi")]
    _job: Option<mpi_job::Universe>,
}

impl Guard {
    /// End the process with `code` after a failure or a stop. Under MPI without finalizing:
    /// another rank may still wait inside a collective, and `MPI_Finalize` would wait for it
    /// forever; a rank that exits without it makes the launcher end the whole job.
    pub fn exit(self, code: u8) -> ! {
        std::process::exit(i32::from(code))
    }
}

/// Join the MPI job if a launcher started this process (the environment of `mpirun`, or of
/// `srun` with PMI or PMIx), else stay alone. Call once, first thing in `main`. A build
/// without the `mpi` feature started as one of several ranks is refused: each rank would run
/// the whole reconstruction into the same directory.
pub fn init() -> Result<Guard, String> {
    let launched = ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK"]
        .iter()
        .any(|v| std::env::var_os(v).is_some());
    if !launched {
        return Ok(Guard::solo());
    }
    join(launcher_size())
}

/// The job size the launcher announced (1 if it did not say).
fn launcher_size() -> usize {
    ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE"]
        .iter()
        .find_map(|v| std::env::var(v).ok()?.parse().ok())
        .unwrap_or(1)
}

impl Guard {
    fn solo() -> Guard {
        Guard {
            #[cfg(feature = "mpi")]
            _job: None,
        }
    }
}

#[cfg(feature = "mpi")]
fn join(_size: usize) -> Result<Guard, String> {
    let (universe, job) = mpi_job::start()?;
    let world = World::with(Backend::Mpi(job));
    if WORLD.set(world).is_err() {
        return Err("MPI initialized twice".into());
    }
    Ok(Guard {
        _job: Some(universe),
    })
}

#[cfg(not(feature = "mpi"))]
fn join(size: usize) -> Result<Guard, String> {
    match size {
        0 | 1 => Ok(Guard::solo()),
        n => Err(format!(
            "started as one of {n} MPI ranks, but this kdmap was built without MPI: build it \
             with `cargo build --release --features mpi`, or run one process"
        )),
    }
}

impl World {
    /// This process alone.
    pub fn solo() -> World {
        World::with(Backend::Solo)
    }

    fn with(backend: Backend) -> World {
        World {
            backend,
            bytes: AtomicU64::new(0),
            nanos: AtomicU64::new(0),
        }
    }

    /// This process's rank, `0..size`.
    pub fn rank(&self) -> usize {
        match &self.backend {
            Backend::Solo => 0,
            #[cfg(feature = "mpi")]
            Backend::Mpi(j) => j.rank,
        }
    }

    /// The number of ranks.
    pub fn size(&self) -> usize {
        match &self.backend {
            Backend::Solo => 1,
            #[cfg(feature = "mpi")]
            Backend::Mpi(j) => j.size,
        }
    }

    /// Whether this is rank 0: the one that writes outputs and checkpoints and talks to the
    /// user.
    pub fn is_root(&self) -> bool {
        self.rank() == 0
    }

    /// The rank that computes work unit `unit` (a tile, a photon batch, a gather chunk).
    pub fn owner(&self, unit: u64) -> usize {
        (unit % self.size() as u64) as usize
    }

    /// Whether this rank computes work unit `unit`.
    pub fn owns(&self, unit: u64) -> bool {
        self.owner(unit) == self.rank()
    }

    /// Every rank's `mine`, in rank order, on every rank (collective).
    pub fn all_gather(&self, mine: &[u8]) -> Vec<Vec<u8>> {
        self.counted(|| match &self.backend {
            Backend::Solo => vec![mine.to_vec()],
            #[cfg(feature = "mpi")]
            Backend::Mpi(j) => j.all_gather(mine),
        })
    }

    /// Part `r` of `parts` to rank `r` (one part per rank): the part each rank sent to this
    /// one, in rank order (collective).
    pub fn all_to_all(&self, parts: Vec<Vec<u8>>) -> Vec<Vec<u8>> {
        self.counted(|| match &self.backend {
            Backend::Solo => parts,
            #[cfg(feature = "mpi")]
            Backend::Mpi(j) => j.all_to_all(&parts),
        })
    }

    /// Rank 0's `bytes` on every rank (collective; the other ranks' argument is ignored).
    pub fn broadcast(&self, bytes: Vec<u8>) -> Vec<u8> {
        self.counted(|| match &self.backend {
            Backend::Solo => vec![bytes],
            #[cfg(feature = "mpi")]
            Backend::Mpi(j) => vec![j.broadcast(bytes)],
        })
        .swap_remove(0)
    }

    /// Waits until every rank has come here (collective).
    pub fn barrier(&self) {
        if self.size() > 1 {
            self.all_gather(&[]);
        }
    }

    /// Whether `flag` holds on any rank (collective).
    pub fn any(&self, flag: bool) -> bool {
        if self.size() == 1 {
            return flag;
        }
        self.all_gather(&[flag as u8]).iter().any(|b| b == &[1])
    }

    /// The sum of `v` over the ranks (collective; integers, so exact in any order).
    pub fn sum(&self, v: u64) -> u64 {
        self.gather_u64(v).into_iter().sum()
    }

    /// The largest `v` of the ranks (collective).
    pub fn max(&self, v: u64) -> u64 {
        self.gather_u64(v).into_iter().max().unwrap_or(v)
    }

    fn gather_u64(&self, v: u64) -> Vec<u64> {
        if self.size() == 1 {
            return vec![v];
        }
        self.all_gather(&v.to_le_bytes())
            .iter()
            .map(|b| u64::from_le_bytes(b[..8].try_into().unwrap_or([0; 8])))
            .collect()
    }

    /// The outcome of a step every rank took (loading the scene, say), agreed: `Ok` where it
    /// succeeded on every rank, else every rank fails with the error of the lowest rank that
    /// failed: rank 0 keeps its own error as it is, the others get an [`Error::Rank`] (which
    /// only rank 0 prints). Collective.
    pub fn agree<T>(&self, r: Result<T>) -> Result<T> {
        if self.size() == 1 {
            return r;
        }
        let mine = match &r {
            Ok(_) => vec![0],
            Err(e) => [vec![1, e.exit_code()], e.to_string().into_bytes()].concat(),
        };
        let all = self.all_gather(&mine);
        match all.iter().position(|b| b.first() == Some(&1)) {
            None => r,
            Some(0) if self.is_root() => r,
            Some(k) => Err(rank_error(k, &all[k][1..])),
        }
    }

    /// A step rank 0 takes alone (reading the checkpoint, say) and its outcome on every rank:
    /// its value, or its error (an [`Error::Rank`] on the other ranks). Collective.
    pub fn decide<T: Serialize + DeserializeOwned>(
        &self,
        f: impl FnOnce() -> Result<T>,
    ) -> Result<T> {
        if self.size() == 1 {
            return f();
        }
        if self.is_root() {
            let r = f();
            let bytes = match &r {
                Ok(v) => [vec![0], encode(v)?].concat(),
                Err(e) => [vec![1, e.exit_code()], e.to_string().into_bytes()].concat(),
            };
            self.broadcast(bytes);
            return r;
        }
        let bytes = self.broadcast(Vec::new());
        match bytes.split_first() {
            Some((0, v)) => decode(v),
            Some((_, e)) => Err(rank_error(0, e)),
            None => Err(Error::internal("rank 0 sent an empty decision")),
        }
    }

    /// What this rank has communicated so far.
    pub fn traffic(&self) -> Traffic {
        Traffic {
            bytes: self.bytes.load(Ordering::Relaxed),
            seconds: self.nanos.load(Ordering::Relaxed) as f64 * 1e-9,
        }
    }

    /// Runs one operation, counting its time and the bytes that crossed: what it returns, all
    /// ranks' parts (this rank's own sent, the others' received); nothing in one process.
    fn counted(&self, op: impl FnOnce() -> Vec<Vec<u8>>) -> Vec<Vec<u8>> {
        let t = Instant::now();
        let out = op();
        if self.size() > 1 {
            let moved: usize = out.iter().map(Vec::len).sum();
            self.bytes.fetch_add(moved as u64, Ordering::Relaxed);
        }
        self.nanos
            .fetch_add(t.elapsed().as_nanos() as u64, Ordering::Relaxed);
        out
    }
}

/// An [`Error::Rank`] from `[exit code, message...]`.
fn rank_error(rank: usize, bytes: &[u8]) -> Error {
    Error::Rank {
        rank,
        code: bytes
            .first()
            .copied()
            .unwrap_or(crate::base::error::exit::INTERNAL),
        msg: String::from_utf8_lossy(bytes.get(1..).unwrap_or_default()).into_owned(),
    }
}

fn encode<T: Serialize>(v: &T) -> Result<Vec<u8>> {
    bincode::serde::encode_to_vec(v, bincode::config::standard())
        .map_err(|e| Error::internal(format!("sending to the other ranks: {e}")))
}

fn decode<T: DeserializeOwned>(b: &[u8]) -> Result<T> {
    bincode::serde::decode_from_slice(b, bincode::config::standard())
        .map(|(v, _)| v)
        .map_err(|e| Error::internal(format!("receiving from rank 0: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_process_owns_every_unit_and_gathers_its_own_bytes() {
        let w = World::solo();
        assert_eq!((w.rank(), w.size()), (0, 1));
        assert!((0..100).all(|u| w.owns(u)));
        assert_eq!(w.all_gather(b"abc"), vec![b"abc".to_vec()]);
        assert_eq!(w.broadcast(b"xy".to_vec()), b"xy".to_vec());
        assert!(w.any(true) && !w.any(false));
        assert_eq!(w.sum(7), 7);
        assert_eq!(w.traffic().bytes, 0, "nothing crosses in one process");
    }
}
