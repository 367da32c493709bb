//! The last resort of `kneebench run` against an FMU in kneebench's own process that ends the
//! process or never returns (`--isolate` turns both into ordinary errors; these cover
//! `--isolate never` and kneebench's own FMUs):
//!
//! - **exit()**: an `atexit` hook, armed while a run is in progress, reports "an FMU called
//!   exit() during CALL" (naming the call in progress, `inflight::latest`) and
//!   ends the process with exit code 1 instead of the code the FMU chose (often 0, which would
//!   pass for success with no results). The rows flushed so far stay in `OUTPUT.partial`; the
//!   rows buffered since the last flush (at most about one second's) are lost: the sink is
//!   in the middle of a call on the same thread and cannot be touched.
//! - **a call that never returns**: with `--timeout`, a watchdog thread waits for the run's
//!   end until [`GRACE`] past the limit (the master stops at the first communication point
//!   after it); if the run is still going, an FMU call is stuck, which cannot be interrupted
//!   in process: the watchdog prints the call and ends the process with exit code 4 (the rows
//!   flushed so far stay in `OUTPUT.partial`).
//!
//! Both end with `_exit`, so nothing else runs: the extraction directories left behind are
//! removed when `kneebench` next starts (`tempdirs::remove_stale`).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{RecvTimeoutError, Sender};
use std::sync::{Mutex, Once};
use std::thread::JoinHandle;
use std::time::Duration;

use kneebench_harness::inflight;

// Declared here rather than through the libc crate: these sources are also compiled into the
// tests crate (tests/tests/foreign_fmu.rs), which does not depend on it.
unsafe extern "C" {
    /// `int atexit(void (*)(void))`.
    fn atexit(hook: extern "C" fn()) -> std::ffi::c_int;
    /// `void _exit(int)`: ends the process without running exit handlers.
    fn _exit(code: std::ffi::c_int) -> !;
}

/// How long past `--timeout` the watchdog waits for the run to stop by itself.
pub const GRACE: Duration = Duration::from_secs(5);

/// Whether a run is in progress (the hook reports only then; `kneebench`'s own exit passes).
static IN_PROGRESS: AtomicBool = AtomicBool::new(false);
/// The partial results file of the run in progress.
static PARTIAL: Mutex<Option<PathBuf>> = Mutex::new(None);
/// Registers the hook once per process.
static HOOK: Once = Once::new();

/// "the rows flushed so far are in X" (or without the path if its lock is taken).
fn where_rows_are() -> String {
    match PARTIAL.try_lock().ok().and_then(|p| p.clone()) {
        Some(p) => format!("the rows flushed so far are in {}", p.display()),
        None => "the rows flushed so far are in OUTPUT.partial".to_string(),
    }
}

/// The `atexit` hook.
extern "C" fn on_exit() {
    if !IN_PROGRESS.load(Ordering::SeqCst) {
        return;
    }
    let call = inflight::latest()
        .unwrap_or_else(|| "no FMU call (from a thread of its own, or while loading)".into());
    // Not eprintln!: it panics if stderr is gone, and a panic here (an extern "C" fn) aborts.
    let _ = writeln!(
        std::io::stderr(),
        "error: an FMU called exit() during {call}; the run did not finish; {}",
        where_rows_are()
    );
    // SAFETY: _exit ends the process at once (calling exit() again from a hook is undefined).
    unsafe { _exit(super::EXIT_ERROR) };
}

/// The run in progress: the hook reports while it lives, the watchdog (if started) watches
/// until it is dropped.
pub struct Armed {
    watchdog: Option<(Sender<()>, JoinHandle<()>)>,
}

/// Arms the hook for a run whose rows go to `partial`.
pub fn arm(partial: &Path) -> Armed {
    if let Ok(mut p) = PARTIAL.lock() {
        *p = Some(partial.to_path_buf());
    }
    // SAFETY: `on_exit` is an `extern "C" fn()` that lives for the whole program; atexit
    // only records it. It fails only when out of memory, and then the run goes on unguarded.
    HOOK.call_once(|| unsafe {
        atexit(on_exit);
    });
    IN_PROGRESS.store(true, Ordering::SeqCst);
    inflight::track(true);
    Armed { watchdog: None }
}

impl Armed {
    /// Starts the watchdog for a run limited to `timeout` (from now).
    pub fn watch(&mut self, timeout: Duration) -> std::io::Result<()> {
        let (tx, rx) = std::sync::mpsc::channel::<()>();
        let thread = std::thread::Builder::new()
            .name("kneebench-watchdog".into())
            .spawn(move || {
                if rx.recv_timeout(timeout + GRACE) != Err(RecvTimeoutError::Timeout)
                    || !IN_PROGRESS.load(Ordering::SeqCst)
                {
                    return;
                }
                let call =
                    inflight::latest().unwrap_or_else(|| "an FMU call (on another thread)".into());
                // Not eprintln!: a panic on a closed stderr would end this thread, not the
                // stuck process.
                let _ = writeln!(
                    std::io::stderr(),
                    "error: --timeout ({} s) passed {} s ago and {call} has not returned \
                     (a call in kneebench's process cannot be interrupted; --isolate always \
                     can); ending the process; {}",
                    timeout.as_secs_f64(),
                    GRACE.as_secs(),
                    where_rows_are()
                );
                // SAFETY: _exit ends the process at once; the stuck call holds the sink.
                unsafe { _exit(super::EXIT_TIMEOUT) };
            })?;
        self.watchdog = Some((tx, thread));
        Ok(())
    }
}

impl Drop for Armed {
    fn drop(&mut self) {
        IN_PROGRESS.store(false, Ordering::SeqCst);
        inflight::track(false);
        if let Some((tx, thread)) = self.watchdog.take() {
            drop(tx);
            let _ = thread.join();
        }
    }
}
