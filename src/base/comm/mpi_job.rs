//! The MPI backend of [`super::World`] (`--features mpi`): rsmpi's world communicator, used
//! from the main thread only (`MPI_THREAD_FUNNELED`), and a watchdog for ranks that die.
//!
//! **A rank that dies.** Without fault-tolerant MPI, the other ranks block forever in their
//! next collective, until the launcher kills them, and the launcher's own report of it is a
//! banner among others. So every rank learns at start where its peers run (host name and
//! process id), and a watchdog thread looks, while this rank waits inside a collective, whether
//! a peer on its own host has gone (`/proc/<pid>` missing or a zombie). The lowest surviving
//! rank of that host prints one line naming the dead rank, and every survivor exits at once
//! without finalizing MPI (the launcher then ends the job). Checkpoints are written atomically
//! by rank 0 alone, so the last one stays intact. A peer on another host is not watched: there
//! the launcher's own message names it (`mpirun noticed that process rank 1 ... exited`).

use mpi::datatype::{Partition, PartitionMut};
use mpi::topology::SimpleCommunicator;
use mpi::traits::*;
use mpi::Threading;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

pub use mpi::environment::Universe;

/// Largest message of one MPI call (MPI counts and displacements are `i32`).
const PIECE: usize = 1 << 30;
/// How often the watchdog looks, and how long a collective must have waited before it does.
const WATCH_EVERY: Duration = Duration::from_millis(200);

/// This rank's view of the job.
pub struct Job {
    pub rank: usize,
    pub size: usize,
    /// When the current collective began (ns since `epoch`, plus one), 0 outside collectives.
    busy_since: Arc<AtomicU64>,
    epoch: Instant,
}

/// Where a rank runs.
#[derive(Debug, Clone, PartialEq)]
struct Peer {
    host: String,
    pid: u32,
}

/// Initialize MPI and learn the job: rank, size, where every rank runs; start the watchdog.
pub fn start() -> Result<(Universe, Job), String> {
    let (universe, _) = mpi::initialize_with_threading(Threading::Funneled)
        .ok_or("MPI could not be initialized (or was already)")?;
    let w = universe.world();
    let (rank, size) = (w.rank() as usize, w.size() as usize);
    let job = Job {
        rank,
        size,
        busy_since: Arc::new(AtomicU64::new(0)),
        epoch: Instant::now(),
    };
    let me = format!(
        "{}\n{}",
        mpi::environment::processor_name().unwrap_or_default(),
        std::process::id()
    );
    let peers: Vec<Peer> = job
        .all_gather(me.as_bytes())
        .iter()
        .map(|b| {
            let s = String::from_utf8_lossy(b);
            let (host, pid) = s.rsplit_once('\n').unwrap_or(("", "0"));
            Peer {
                host: host.to_string(),
                pid: pid.parse().unwrap_or(0),
            }
        })
        .collect();
    watch(rank, peers, Arc::clone(&job.busy_since), job.epoch);
    Ok((universe, job))
}

impl Job {
    /// Every rank's bytes in rank order.
    pub fn all_gather(&self, mine: &[u8]) -> Vec<Vec<u8>> {
        let _busy = self.busy();
        let w = SimpleCommunicator::world();
        let mut lens = vec![0u64; self.size];
        w.all_gather_into(&(mine.len() as u64), &mut lens[..]);
        let mut out: Vec<Vec<u8>> = lens
            .iter()
            .map(|&l| Vec::with_capacity(l as usize))
            .collect();
        let piece_len = self.piece();
        let rounds = lens.iter().map(|&l| (l as usize).div_ceil(piece_len)).max();
        for k in 0..rounds.unwrap_or(0) {
            let piece = |l: usize| (l.saturating_sub(k * piece_len)).min(piece_len);
            let (counts, displs) = layout(lens.iter().map(|&l| piece(l as usize)));
            let total = counts.iter().map(|&c| c as usize).sum();
            let mut buf = vec![0u8; total];
            let start = (k * piece_len).min(mine.len());
            let send = &mine[start..start + piece(mine.len())];
            let mut part = PartitionMut::new(&mut buf[..], &counts[..], &displs[..]);
            w.all_gather_varcount_into(send, &mut part);
            for (r, o) in out.iter_mut().enumerate() {
                let d = displs[r] as usize;
                o.extend_from_slice(&buf[d..d + counts[r] as usize]);
            }
        }
        out
    }

    /// Part `r` of `parts` to rank `r`; the parts the ranks sent here, in rank order.
    pub fn all_to_all(&self, parts: &[Vec<u8>]) -> Vec<Vec<u8>> {
        let _busy = self.busy();
        let w = SimpleCommunicator::world();
        let sent: Vec<u64> = parts.iter().map(|p| p.len() as u64).collect();
        let mut got = vec![0u64; self.size];
        w.all_to_all_into(&sent[..], &mut got[..]);
        let longest = sent
            .iter()
            .chain(&got)
            .map(|&l| l as usize)
            .max()
            .unwrap_or(0);
        let mut rounds = vec![0u64; self.size];
        let piece_len = self.piece();
        w.all_gather_into(&(longest.div_ceil(piece_len) as u64), &mut rounds[..]);
        let mut out: Vec<Vec<u8>> = got
            .iter()
            .map(|&l| Vec::with_capacity(l as usize))
            .collect();
        for k in 0..rounds.iter().max().copied().unwrap_or(0) as usize {
            let piece = |l: u64| (l as usize).saturating_sub(k * piece_len).min(piece_len);
            let (sc, sd) = layout(sent.iter().map(|&l| piece(l)));
            let (rc, rd) = layout(got.iter().map(|&l| piece(l)));
            let mut send = Vec::with_capacity(sc.iter().map(|&c| c as usize).sum());
            for (p, &c) in parts.iter().zip(&sc) {
                let rest = p.get(k * piece_len..).unwrap_or_default();
                send.extend_from_slice(&rest[..c as usize]);
            }
            let mut recv = vec![0u8; rc.iter().map(|&c| c as usize).sum()];
            let sbuf = Partition::new(&send[..], &sc[..], &sd[..]);
            let mut rbuf = PartitionMut::new(&mut recv[..], &rc[..], &rd[..]);
            w.all_to_all_varcount_into(&sbuf, &mut rbuf);
            for (r, o) in out.iter_mut().enumerate() {
                let d = rd[r] as usize;
                o.extend_from_slice(&recv[d..d + rc[r] as usize]);
            }
        }
        out
    }

    /// Rank 0's bytes on every rank.
    pub fn broadcast(&self, mut bytes: Vec<u8>) -> Vec<u8> {
        let _busy = self.busy();
        let w = SimpleCommunicator::world();
        let root = w.process_at_rank(0);
        let mut len = bytes.len() as u64;
        root.broadcast_into(&mut len);
        bytes.resize(len as usize, 0);
        for chunk in bytes.chunks_mut(PIECE) {
            root.broadcast_into(chunk);
        }
        bytes
    }

    /// Largest part of one rank in one gather or all-to-all call: the parts of all ranks
    /// together must fit an `i32`.
    fn piece(&self) -> usize {
        (i32::MAX as usize / self.size.max(1)).clamp(1, PIECE)
    }

    /// Marks this rank as waiting inside a collective until the guard drops.
    fn busy(&self) -> Busy<'_> {
        let t = self.epoch.elapsed().as_nanos() as u64 + 1;
        self.busy_since.store(t, Ordering::SeqCst);
        Busy(&self.busy_since)
    }
}

/// MPI counts and displacements of consecutive parts of the given lengths (together at most
/// `i32::MAX`, see [`Job::piece`]).
fn layout(lens: impl Iterator<Item = usize>) -> (Vec<i32>, Vec<i32>) {
    let counts: Vec<i32> = lens.map(|l| l as i32).collect();
    let displs = counts
        .iter()
        .scan(0i32, |at, &c| {
            let d = *at;
            *at += c;
            Some(d)
        })
        .collect();
    (counts, displs)
}

struct Busy<'a>(&'a AtomicU64);

impl Drop for Busy<'_> {
    fn drop(&mut self) {
        self.0.store(0, Ordering::SeqCst);
    }
}

/// The watchdog thread (module notes).
fn watch(rank: usize, peers: Vec<Peer>, busy: Arc<AtomicU64>, epoch: Instant) {
    let Some(me) = peers.get(rank).cloned() else {
        return;
    };
    let local: Vec<usize> = (0..peers.len())
        .filter(|&r| r != rank && peers[r].host == me.host && peers[r].pid != 0)
        .collect();
    if local.is_empty() {
        return;
    }
    let spawned = std::thread::Builder::new()
        .name("kdmap-mpi-watchdog".into())
        .spawn(move || loop {
            std::thread::sleep(WATCH_EVERY);
            let since = busy.load(Ordering::SeqCst);
            let waited = epoch.elapsed().as_nanos() as u64;
            if since == 0 || waited.saturating_sub(since) < WATCH_EVERY.as_nanos() as u64 {
                continue;
            }
            let Some(&dead) = local.iter().find(|&&r| !alive(peers[r].pid)) else {
                continue;
            };
            let survivors = local.iter().filter(|&&r| r != dead && alive(peers[r].pid));
            if survivors.min().is_none_or(|&r| rank < r) {
                let p = &peers[dead];
                crate::base::progress::line(&format!(
                    "error: rank {dead} (pid {} on {}) died; the job stops (the last \
                     checkpoint stays intact: run again with --resume, under any number of ranks)",
                    p.pid, p.host
                ));
            }
            std::process::exit(i32::from(crate::base::error::exit::RANK_DIED));
        });
    // Without the watchdog a dead peer still ends the job (the launcher kills it).
    drop(spawned);
}

/// Whether process `pid` of this host is still running (not gone, not a zombie).
fn alive(pid: u32) -> bool {
    match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
        // the state follows the parenthesized command name
        Ok(s) => s
            .rsplit_once(") ")
            .is_some_and(|(_, rest)| !rest.starts_with('Z') && !rest.starts_with('X')),
        Err(_) => false,
    }
}
