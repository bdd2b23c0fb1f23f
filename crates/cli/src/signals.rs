//! SIGINT and SIGTERM for long jobs. The first asks the job to stop at its next safe point
//! (a step boundary, after its checkpoint); the job then exits 130 (SIGINT) or 143 (SIGTERM),
//! the codes shells and schedulers read as "interrupted" and "terminated". A second signal exits
//! at once with its own code: every file is written to a temporary name and renamed, so an exit
//! at any moment leaves the previous complete file.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Arc;

use anyhow::{Context, Result};
use signal_hook::consts::{SIGINT, SIGTERM};
use signal_hook::flag;

/// The stop request of a running job.
#[derive(Clone)]
pub struct StopSignal {
    any: Arc<AtomicBool>,
    which: Arc<AtomicUsize>,
}

impl StopSignal {
    /// Handle SIGINT and SIGTERM for the rest of the process.
    pub fn install() -> Result<StopSignal> {
        let s = StopSignal { any: Arc::default(), which: Arc::default() };
        for sig in [SIGINT, SIGTERM] {
            // Registered first, so it sees the flag as the previous signal left it.
            flag::register_conditional_shutdown(sig, exit_code(sig), s.any.clone())
                .and_then(|_| flag::register(sig, s.any.clone()))
                .and_then(|_| flag::register_usize(sig, s.which.clone(), sig as usize))
                .context("cannot install the SIGINT/SIGTERM handlers")?;
        }
        Ok(s)
    }

    /// Whether a signal asked the job to stop.
    pub fn requested(&self) -> bool {
        self.any.load(Ordering::SeqCst)
    }

    /// The exit status for the signal that stopped the job (128 + its number), if one did.
    pub fn exit_code(&self) -> Option<i32> {
        match self.which.load(Ordering::SeqCst) {
            0 => None,
            sig => Some(exit_code(sig as i32)),
        }
    }

    /// The signal's name, for messages.
    pub fn name(&self) -> &'static str {
        if self.which.load(Ordering::SeqCst) == SIGTERM as usize {
            "SIGTERM"
        } else {
            "SIGINT"
        }
    }
}

fn exit_code(sig: i32) -> i32 {
    128 + sig
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_follow_the_shell_convention() {
        assert_eq!(exit_code(SIGINT), 130);
        assert_eq!(exit_code(SIGTERM), 143);
    }
}
