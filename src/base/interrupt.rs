//! Graceful interruption: SIGINT or SIGTERM sets a flag that the pipeline polls at its safe
//! points (a batch group of a photon pass, a view of the projection, a tile group of the
//! direct light, an iteration), where it writes a checkpoint and stops with
//! [`Error::Interrupted`] (exit code 130). A second signal ends the process at once with
//! exit code 130; the last checkpoint is intact since checkpoint writes are atomic.
//!
//! The handlers are only installed by [`install`] (the command line does it for the commands
//! that can stop cleanly); a library user that never calls it is never interrupted.
//!
//! In an MPI job (`comm`) the signal reaches the ranks at different moments, so a safe point
//! decides with every rank ([`agreed`], [`check`]: collective operations): a stop asked for on
//! any rank stops them all at the same safe point.

use crate::base::error::{Error, Result};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, LazyLock};

/// Set by the first SIGINT / SIGTERM once [`install`] has run.
static REQUESTED: LazyLock<Arc<AtomicBool>> = LazyLock::new(|| Arc::new(AtomicBool::new(false)));

/// Install the handlers of SIGINT and SIGTERM: the first sets the flag that [`requested`]
/// reads, the next one exits the process with code 130 at once.
pub fn install() -> Result<()> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    let exit = i32::from(crate::base::error::exit::INTERRUPTED);
    for sig in [SIGINT, SIGTERM] {
        // Registration order matters: the shutdown handler must see the flag as it was
        // before this signal, so it is registered first.
        signal_hook::flag::register_conditional_shutdown(sig, exit, Arc::clone(&REQUESTED))
            .and_then(|_| signal_hook::flag::register(sig, Arc::clone(&REQUESTED)))
            .map_err(|e| Error::internal(format!("installing the handler of signal {sig}: {e}")))?;
    }
    Ok(())
}

/// Whether a stop was asked for (a signal since [`install`], or [`request`]).
pub fn requested() -> bool {
    REQUESTED.load(Ordering::SeqCst)
}

/// Ask the safe points to stop, as a signal would (for library users with their own
/// handling).
pub fn request() {
    REQUESTED.store(true, Ordering::SeqCst);
}

/// The message of a stop before a run's first checkpoint: nothing was saved.
pub const NOTHING_SAVED: &str =
    "stopped before the first checkpoint; run the same command again to start over";

/// Whether a stop was asked for on any rank of the run: the decision of a safe point. A
/// collective operation in an MPI job: every rank calls it at the same safe points.
pub fn agreed() -> bool {
    crate::base::comm::world().any(requested())
}

/// `Err(Error::Interrupted)` with `msg` if a stop was asked for (on any rank, [`agreed`]):
/// the check of a safe point that has nothing to save.
pub fn check(msg: &str) -> Result<()> {
    match agreed() {
        true => Err(Error::Interrupted(msg.to_string())),
        false => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_interruption_is_one_line_with_exit_code_130() {
        let e = Error::Interrupted("checkpoint 3 written\nrun again with --resume".into());
        assert_eq!(e.exit_code(), 130);
        let s = e.to_string();
        assert!(s.starts_with("interrupted: checkpoint 3"), "{s}");
        assert!(!s.contains('\n'), "{s}");
    }
}
