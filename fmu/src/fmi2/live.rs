//! The registries of live instances and live FMU states: the addresses `fmi2Instantiate`
//! returned and `fmi2FreeInstance` has not freed yet, and the states `fmi2GetFMUstate` or
//! `fmi2DeSerializeFMUstate` made and `fmi2FreeFMUstate` has not freed yet.
//!
//! The instance registry is consulted by those two functions only (under one lock), so
//! `fmi2FreeInstance` can tell an instance it may free from a pointer it must not touch (one
//! already freed, or never returned by this binary). Every other function trusts its component
//! pointer: the get, set and step path pays no lock (see the `export` module documentation for
//! what is and is not guarded). The state registry is consulted by every state function before
//! it reads, overwrites or frees a state, so a state freed already (through a copy of its
//! pointer) or a pointer that was never a state is refused without being dereferenced.

use std::collections::BTreeSet;
use std::sync::{Mutex, MutexGuard, PoisonError};

/// A set of live addresses. Empty (and then holding no heap memory) when nothing is live, so a
/// library unloaded after everything it handed out was freed leaks nothing.
pub(super) struct Registry(Mutex<BTreeSet<usize>>);

/// The addresses of the live instances.
pub(super) static INSTANCES: Registry = Registry::new();

/// The addresses of the live FMU states.
pub(super) static STATES: Registry = Registry::new();

impl Registry {
    /// An empty registry.
    const fn new() -> Self {
        Self(Mutex::new(BTreeSet::new()))
    }

    /// The set, locked. A panic while it was held cannot leave it inconsistent (an insert or
    /// removal either happened or did not), so a poisoned lock is used as it is.
    fn lock(&self) -> MutexGuard<'_, BTreeSet<usize>> {
        self.0.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Records `address` as live.
    pub(super) fn register(&self, address: usize) {
        self.lock().insert(address);
    }

    /// Removes `address` from the live addresses: whether it was one (then, and only then, the
    /// caller owns it and frees it; of two concurrent calls for one address only one sees
    /// `true`).
    pub(super) fn unregister(&self, address: usize) -> bool {
        let mut live = self.lock();
        let was_live = live.remove(&address);
        if live.is_empty() {
            // A set emptied by removals keeps its root node: release it.
            *live = BTreeSet::new();
        }
        was_live
    }

    /// Whether `address` is live.
    pub(super) fn contains(&self, address: usize) -> bool {
        self.lock().contains(&address)
    }

    /// How many addresses are live.
    #[cfg(test)]
    pub(super) fn count(&self) -> usize {
        self.lock().len()
    }
}
