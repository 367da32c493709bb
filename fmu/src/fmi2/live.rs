//! The registry of live instances: the addresses `fmi2Instantiate` returned and
//! `fmi2FreeInstance` has not freed yet.
//!
//! Only those two functions consult it (under one lock), so `fmi2FreeInstance` can tell an
//! instance it may free from a pointer it must not touch (one already freed, or never returned
//! by this binary). Every other function trusts its component pointer: the get, set and step
//! path pays no lock (see the `export` module documentation for what is and is not guarded).

use std::collections::BTreeSet;
use std::sync::{Mutex, MutexGuard, PoisonError};

/// The addresses of the live instances. Empty (and then holding no heap memory) when no
/// instance exists, so a library unloaded after its instances were freed leaks nothing.
static LIVE: Mutex<BTreeSet<usize>> = Mutex::new(BTreeSet::new());

/// The registry, locked. A panic while it was held cannot leave it inconsistent (an insert or
/// removal either happened or did not), so a poisoned lock is used as it is.
fn live() -> MutexGuard<'static, BTreeSet<usize>> {
    LIVE.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Records `address` as a live instance.
pub(super) fn register(address: usize) {
    live().insert(address);
}

/// Removes `address` from the live instances: whether it was one (then, and only then, the
/// caller owns it and frees it; of two concurrent calls for one address only one sees `true`).
pub(super) fn unregister(address: usize) -> bool {
    let mut live = live();
    let was_live = live.remove(&address);
    if live.is_empty() {
        // A set emptied by removals keeps its root node: release it.
        *live = BTreeSet::new();
    }
    was_live
}

/// Whether `address` is a live instance.
#[cfg(test)]
pub(super) fn is_live(address: usize) -> bool {
    live().contains(&address)
}

/// How many instances are live.
#[cfg(test)]
pub(super) fn count() -> usize {
    live().len()
}
