//! Stopping a run from outside: signals, a time limit, a caller's request.
//!
//! A [`RunControl`] is one shared word of flags. The master loads it once per macro step (a
//! relaxed atomic load, the cost of reading a variable) and acts only when it is non-zero:
//!
//! - a **stop** request ([`RunControl::request_stop`], a signal registered with
//!   [`RunControl::stop_on_signals`], or the deadline of [`RunConfig::timeout`]) ends the run at
//!   the next communication point: the rows so far are flushed and the run ends with
//!   [`MasterError::Stopped`], naming the [`StopReason`];
//! - a **flush** request (set every second by the master's ticker while a sink wants periodic
//!   flushes) makes the master flush its sink.
//!
//! The control is cheap to clone (one `Arc`) and can be shared with anything that must stop a
//! run: a watchdog of isolated FMU processes sets [`StopReason::Requested`] or a reason of its
//! own the same way.
//!
//! [`RunConfig::timeout`]: crate::master::RunConfig::timeout
//! [`MasterError::Stopped`]: crate::master::MasterError::Stopped

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Bit: the sink should be flushed.
const FLUSH: usize = 1;
/// Bit: stop, requested by the caller.
const STOP_REQUESTED: usize = 1 << 1;
/// Bit: stop, the run's time limit passed.
const STOP_TIMEOUT: usize = 1 << 2;
/// Bit: stop, SIGINT.
const STOP_SIGINT: usize = 1 << 3;
/// Bit: stop, SIGTERM.
const STOP_SIGTERM: usize = 1 << 4;
/// Bit: stop, SIGHUP.
const STOP_SIGHUP: usize = 1 << 5;
/// Every stop bit.
const STOP: usize = STOP_REQUESTED | STOP_TIMEOUT | STOP_SIGINT | STOP_SIGTERM | STOP_SIGHUP;

/// Why a run was stopped from outside.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopReason {
    /// A signal (its number: 1 SIGHUP, 2 SIGINT, 15 SIGTERM).
    Signal(i32),
    /// The run's time limit ([`RunConfig::timeout`](crate::master::RunConfig::timeout)).
    Timeout,
    /// [`RunControl::request_stop`].
    Requested,
}

impl std::fmt::Display for StopReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            StopReason::Signal(2) => write!(f, "interrupted (SIGINT)"),
            StopReason::Signal(15) => write!(f, "terminated (SIGTERM)"),
            StopReason::Signal(1) => write!(f, "hung up (SIGHUP)"),
            StopReason::Signal(n) => write!(f, "signal {n}"),
            StopReason::Timeout => write!(f, "the time limit passed"),
            StopReason::Requested => write!(f, "stop requested"),
        }
    }
}

/// The shared flags that stop a run or ask for a flush (see the module documentation).
#[derive(Debug, Clone, Default)]
pub struct RunControl {
    word: Arc<AtomicUsize>,
}

impl RunControl {
    /// A control with no request pending.
    pub fn new() -> RunControl {
        RunControl::default()
    }

    /// Asks the run to stop at the next communication point.
    pub fn request_stop(&self) {
        self.word.fetch_or(STOP_REQUESTED, Ordering::Relaxed);
    }

    /// Stops the run on SIGINT, SIGTERM and SIGHUP (from now on, for the life of the process;
    /// a second SIGINT or SIGTERM while the first is pending ends the process at once with
    /// status 130 or 143, as if unhandled).
    pub fn stop_on_signals(&self) -> std::io::Result<()> {
        use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
        for (signal, bit) in [
            (SIGINT, STOP_SIGINT),
            (SIGTERM, STOP_SIGTERM),
            (SIGHUP, STOP_SIGHUP),
        ] {
            let pending = Arc::new(std::sync::atomic::AtomicBool::new(false));
            // Registered first, so it sees the flag of an earlier delivery only.
            signal_hook::flag::register_conditional_shutdown(
                signal,
                128 + signal,
                Arc::clone(&pending),
            )?;
            signal_hook::flag::register(signal, pending)?;
            // `register_usize` stores; OR-ing is what the word needs, so the signal's own
            // bit is stored into a word whose other bits the master re-reads (a lost flush
            // bit only delays a flush to the stop, which flushes anyway).
            signal_hook::flag::register_usize(signal, Arc::clone(&self.word), bit)?;
        }
        Ok(())
    }

    /// The pending requests (zero: none). One relaxed load.
    #[inline(always)]
    pub(crate) fn pending(&self) -> usize {
        self.word.load(Ordering::Relaxed)
    }

    /// Asks for a flush of the sink.
    pub(crate) fn request_flush(&self) {
        self.word.fetch_or(FLUSH, Ordering::Relaxed);
    }

    /// Marks the run's time limit as passed.
    pub(crate) fn request_timeout(&self) {
        self.word.fetch_or(STOP_TIMEOUT, Ordering::Relaxed);
    }

    /// Takes the flush request (clearing it); returns whether one was pending.
    pub(crate) fn take_flush(&self) -> bool {
        self.word.fetch_and(!FLUSH, Ordering::Relaxed) & FLUSH != 0
    }

    /// The stop reason pending, if any (the first of signal, time limit, request).
    pub fn stop_reason(&self) -> Option<StopReason> {
        let w = self.pending();
        if w & STOP == 0 {
            None
        } else if w & STOP_SIGINT != 0 {
            Some(StopReason::Signal(2))
        } else if w & STOP_SIGTERM != 0 {
            Some(StopReason::Signal(15))
        } else if w & STOP_SIGHUP != 0 {
            Some(StopReason::Signal(1))
        } else if w & STOP_TIMEOUT != 0 {
            Some(StopReason::Timeout)
        } else {
            Some(StopReason::Requested)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_are_flags_that_a_flush_does_not_clear() {
        let c = RunControl::new();
        assert_eq!(c.pending(), 0);
        assert_eq!(c.stop_reason(), None);
        c.request_flush();
        assert_ne!(c.pending(), 0);
        assert_eq!(c.stop_reason(), None);
        assert!(c.take_flush());
        assert!(!c.take_flush());
        assert_eq!(c.pending(), 0);
        c.clone().request_timeout();
        c.request_flush();
        assert!(c.take_flush());
        assert_eq!(c.stop_reason(), Some(StopReason::Timeout));
        c.request_stop();
        assert_eq!(c.stop_reason(), Some(StopReason::Timeout));
        let d = RunControl::new();
        d.request_stop();
        assert_eq!(d.stop_reason(), Some(StopReason::Requested));
    }
}
