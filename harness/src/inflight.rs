//! Which in-process FMU call is running, for the last-resort reports of a process that an FMU
//! takes down: an FMU that calls `exit()` (reported by an `atexit` hook, which runs on the
//! thread that called `exit()`, so [`on_this_thread`] names the call exactly) and a call that
//! never returns (reported by a watchdog thread, which reads [`latest`]: the last call that
//! started and has not returned; with `--parallel`, another thread's call may have replaced it,
//! and then it names none).
//!
//! Every in-process call of [`Instance`](crate::instance::Instance) brackets the FMU's function
//! with a call mark: a few relaxed stores, no lock and no allocation on the hot path. Instances
//! register their label ("FMU 'X', instance 'y'") once, under a lock, when instantiated.
//! Isolated instances are not tracked here: their host process is theirs to lose.

use std::cell::Cell;
use std::collections::BTreeMap;
use std::sync::Mutex;
use std::sync::atomic::{AtomicPtr, AtomicU32, Ordering};

/// The labels of live in-process instances, by id.
static LABELS: Mutex<BTreeMap<u32, String>> = Mutex::new(BTreeMap::new());
/// The next instance id (0 means "none").
static NEXT_ID: AtomicU32 = AtomicU32::new(1);
/// The instance of the latest call in progress (0: none).
static LATEST_ID: AtomicU32 = AtomicU32::new(0);
/// The function of the latest call in progress (points to a `'static` name).
static LATEST_FUNCTION: AtomicPtr<&'static str> = AtomicPtr::new(std::ptr::null_mut());

thread_local! {
    // Copy data with a const initializer: no destructor, so it is readable in an atexit hook
    // (glibc runs thread-local destructors before atexit handlers).
    static ON_THIS_THREAD: Cell<(u32, *const &'static str)> =
        const { Cell::new((0, std::ptr::null())) };
}

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
pub(crate) struct Call {
    id: u32,
}

impl Call {
    /// Marks `function` of instance `id` as running on this thread.
    #[inline(always)]
    pub(crate) fn enter(id: u32, function: &'static &'static str) -> Call {
        let f = function as *const &'static str;
        ON_THIS_THREAD.set((id, f));
        LATEST_FUNCTION.store(f.cast_mut(), Ordering::Relaxed);
        LATEST_ID.store(id, Ordering::Relaxed);
        Call { id }
    }
}

impl Drop for Call {
    #[inline(always)]
    fn drop(&mut self) {
        ON_THIS_THREAD.set((0, std::ptr::null()));
        // Only our own mark: a call another thread started since stays named.
        let _ = LATEST_ID.compare_exchange(self.id, 0, Ordering::Relaxed, Ordering::Relaxed);
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

/// The FMU call running on the calling thread, if any.
pub fn on_this_thread() -> Option<String> {
    let (id, f) = ON_THIS_THREAD.get();
    describe(id, f)
}

/// The latest FMU call that started (on any thread) and has not returned, if any.
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
        let id = register("FMU 'M', instance 'm'".into());
        assert_eq!(on_this_thread(), None);
        {
            let _c = Call::enter(id, &"fmi2DoStep");
            assert_eq!(
                on_this_thread().as_deref(),
                Some("fmi2DoStep of FMU 'M', instance 'm'")
            );
            // Another thread has no call of its own.
            std::thread::spawn(|| assert_eq!(on_this_thread(), None))
                .join()
                .unwrap();
        }
        assert_eq!(on_this_thread(), None);
        unregister(id);
        let _c = Call::enter(id, &"fmi2GetReal");
        assert_eq!(on_this_thread().as_deref(), Some("fmi2GetReal"));
    }
}
