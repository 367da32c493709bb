//! Which in-process FMU call is running, for the last-resort reports of a process that an FMU
//! takes down: an FMU that calls `exit()` (reported by an `atexit` hook) and a call that never
//! returns (reported by a watchdog thread). Both read [`latest`]: the last call that started,
//! unless a call has returned since. In a sequential run that is exactly the call in progress;
//! with `--parallel`, a call on another thread may have replaced or cleared the mark, and then
//! the report names another call or none.
//!
//! Every in-process call of [`Instance`](crate::instance::Instance) brackets the FMU's function
//! with a call mark: three relaxed stores (two before, one after), no lock, no thread-local and
//! no allocation on the hot path — while tracking is on ([`track`]; `kneebench run` turns it on
//! for its run). Off, a call reads one flag and stores nothing: the marks are words shared by
//! every thread, and stores to them from threads running FMUs in parallel (a sweep's workers,
//! the Python package's threads) would bounce their cache line between the cores on every
//! call. Instances register their label ("FMU 'X', instance 'y'")
//! once, under a lock, when instantiated. Isolated instances are not tracked here: their host
//! process is theirs to lose.

use std::collections::BTreeMap;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicPtr, AtomicU32, Ordering};

/// The labels of live in-process instances, by id.
static LABELS: Mutex<BTreeMap<u32, String>> = Mutex::new(BTreeMap::new());
/// Whether calls are marked ([`track`]).
static TRACKING: AtomicBool = AtomicBool::new(false);
/// The next instance id (0 means "none").
static NEXT_ID: AtomicU32 = AtomicU32::new(1);
/// The instance of the latest call in progress (0: none).
static LATEST_ID: AtomicU32 = AtomicU32::new(0);
/// The function of the latest call in progress (points to a `'static` name).
static LATEST_FUNCTION: AtomicPtr<&'static str> = AtomicPtr::new(std::ptr::null_mut());

/// Registers an instance's label; returns its id (unregister it with [`unregister`]).
pub(crate) fn register(label: String) -> u32 {
    let id = NEXT_ID.fetch_add(1, Ordering::Relaxed).max(1);
    if let Ok(mut labels) = LABELS.lock() {
        labels.insert(id, label);
    }
    id
}

/// Forgets an instance (it was freed).
pub(crate) fn unregister(id: u32) {
    if let Ok(mut labels) = LABELS.lock() {
        labels.remove(&id);
    }
}

/// One FMU call in progress; it is over when dropped.
pub(crate) struct Call;

impl Call {
    /// Marks `function` of instance `id` as running.
    #[inline(always)]
    pub(crate) fn enter(id: u32, function: &'static &'static str) -> Call {
        if TRACKING.load(Ordering::Relaxed) {
            let f = function as *const &'static str;
            LATEST_FUNCTION.store(f.cast_mut(), Ordering::Relaxed);
            LATEST_ID.store(id, Ordering::Relaxed);
        }
        Call
    }
}

impl Drop for Call {
    #[inline(always)]
    fn drop(&mut self) {
        // A plain store, not a compare-exchange (a locked instruction on every call): with
        // `--parallel`, a call ending on one thread may clear the mark of one still running on
        // another, which [`latest`] then does not name (documented there).
        if TRACKING.load(Ordering::Relaxed) {
            LATEST_ID.store(0, Ordering::Relaxed);
        }
    }
}

/// Turns the call marks on or off for the whole process (on: [`latest`] names the call in
/// progress; off, the default: nothing is stored per call).
pub fn track(on: bool) {
    TRACKING.store(on, Ordering::Relaxed);
    if !on {
        LATEST_ID.store(0, Ordering::Relaxed);
    }
}

/// "fmi2DoStep of FMU 'X', instance 'y'" for a call mark (the label is omitted when the lock
/// is taken, so that a report never waits).
fn describe(id: u32, function: *const &'static str) -> Option<String> {
    if id == 0 || function.is_null() {
        return None;
    }
    // SAFETY: every mark points to a `&'static str` that lives for the whole program
    // (`Call::enter` takes `&'static &'static str`).
    let name: &'static str = unsafe { *function };
    let label = LABELS
        .try_lock()
        .ok()
        .and_then(|labels| labels.get(&id).cloned());
    Some(match label {
        Some(l) => format!("{name} of {l}"),
        None => name.to_string(),
    })
}

/// The latest FMU call that started (on any thread), if no call has returned since (see the
/// module documentation for `--parallel`).
pub fn latest() -> Option<String> {
    let id = LATEST_ID.load(Ordering::Relaxed);
    let f = LATEST_FUNCTION.load(Ordering::Relaxed);
    describe(id, f)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_call_is_named_while_it_runs_and_forgotten_after() {
        {
            let _untracked = Call::enter(7, &"fmi2DoStep");
            assert_eq!(latest(), None, "tracking is off by default");
        }
        track(true);
        let id = register("FMU 'M', instance 'm'".into());
        {
            let _c = Call::enter(id, &"fmi2DoStep");
            assert_eq!(
                latest().as_deref(),
                Some("fmi2DoStep of FMU 'M', instance 'm'")
            );
        }
        assert_eq!(latest(), None);
        unregister(id);
        let _c = Call::enter(id, &"fmi2GetReal");
        assert_eq!(latest().as_deref(), Some("fmi2GetReal"));
    }
}
