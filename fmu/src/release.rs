//! Statics built lazily on the heap, and released when the library is unloaded.
//!
//! The binary builds its tables on first use (model descriptions, GUIDs, variable tables,
//! documentation, shared discretisations). With `std::sync::LazyLock`/`OnceLock` that heap
//! memory is never freed; when an importer unloads the library (`dlclose`) and loads it again
//! (every FMU load of fmpy, of our harness, of most importers), each cycle leaked it: about
//! 38 KB per cycle for GaitReference, 330 KB on average over the six models (measured by
//! `tests/tests/leak.rs`, RSS over 10,000 cycles). [`Lazy`] and [`Once`] are the same cells,
//! but each one that was initialized registers a release function, and the destructor of the
//! shared object ([`release_all`], from `.fini_array`) drops every value.
//!
//! At that point no instance may exist any more (the importer freed them before unloading, as
//! the standard requires). When the crate is linked into an executable (the tests link it as an
//! rlib) the values are left alone at exit: only a shared object releases them.

use std::cell::UnsafeCell;
use std::mem::MaybeUninit;
use std::ops::Deref;
use std::sync::Mutex;

/// An initialized cell: its address and its release function.
type Registered = (usize, unsafe fn(usize));

/// The initialized cells, in initialization order.
static REGISTERED: Mutex<Vec<Registered>> = Mutex::new(Vec::new());

/// A cell written once (like `std::sync::OnceLock`) whose value is dropped when the library
/// is unloaded. Only for `static`s.
pub(crate) struct Once<T> {
    once: std::sync::Once,
    value: UnsafeCell<MaybeUninit<T>>,
}

// SAFETY: the value is written once under `std::sync::Once` and then only read (released at
// unload, when nothing else runs), as for `OnceLock<T>`.
unsafe impl<T: Send + Sync> Sync for Once<T> {}
// SAFETY: as for `OnceLock<T>`.
unsafe impl<T: Send> Send for Once<T> {}

impl<T> Once<T> {
    /// An empty cell.
    pub(crate) const fn new() -> Self {
        Once {
            once: std::sync::Once::new(),
            value: UnsafeCell::new(MaybeUninit::uninit()),
        }
    }

    /// The value, built by `f` on first use.
    #[inline]
    pub(crate) fn get_or_init(&'static self, f: impl FnOnce() -> T) -> &'static T {
        if !self.once.is_completed() {
            self.init(f);
        }
        // SAFETY: the Once completed, so the value was written (a panicking initializer
        // poisons the Once, and `call_once` then panics instead of returning).
        unsafe { (*self.value.get()).assume_init_ref() }
    }

    /// The value, if it was built.
    pub(crate) fn get(&self) -> Option<&T> {
        // SAFETY: completed means written (see get_or_init).
        self.once
            .is_completed()
            .then(|| unsafe { (*self.value.get()).assume_init_ref() })
    }

    #[cold]
    fn init(&'static self, f: impl FnOnce() -> T) {
        self.once.call_once(|| {
            // SAFETY: inside call_once: no reader before completion, one writer.
            unsafe { (*self.value.get()).write(f()) };
            let mut r = REGISTERED.lock().unwrap_or_else(|p| p.into_inner());
            r.push((self as *const Self as usize, release::<T>));
        });
    }
}

impl<T> Default for Once<T> {
    fn default() -> Self {
        Self::new()
    }
}

/// Drops the value of the initialized `Once<T>` at `addr`.
///
/// # Safety
/// `addr` is a registered, initialized `Once<T>` that nothing reads any more.
unsafe fn release<T>(addr: usize) {
    // SAFETY: per the contract.
    unsafe {
        let cell = &*(addr as *const Once<T>);
        (*cell.value.get()).assume_init_drop();
    }
}

/// A value built on first access (like `std::sync::LazyLock`), dropped when the library is
/// unloaded. Only for `static`s.
pub(crate) struct Lazy<T> {
    cell: Once<T>,
    init: fn() -> T,
}

impl<T> Lazy<T> {
    /// A value built by `init` on first access.
    ///
    /// # Safety
    /// The `Lazy` must be a `static` (it registers its address for the release at unload, and
    /// dereferencing it treats it as `'static`).
    pub(crate) const unsafe fn new(init: fn() -> T) -> Self {
        Lazy {
            cell: Once::new(),
            init,
        }
    }

    /// The value (built now if needed).
    pub(crate) fn force(this: &'static Self) -> &'static T {
        this.cell.get_or_init(this.init)
    }
}

impl<T: 'static> Deref for Lazy<T>
where
    Self: 'static,
{
    type Target = T;
    #[inline]
    fn deref(&self) -> &T {
        // SAFETY: a `Lazy` is a static (the contract of `Lazy::new`), so `self` lives for
        // 'static.
        let this: &'static Self = unsafe { &*(self as *const Self) };
        Lazy::force(this)
    }
}

/// Functions run at release besides the cells (caches behind a mutex).
static EXTRA: [fn(); 1] = [crate::models::bench::plant::release_shared_discretizations];

/// Drops every initialized value (the library is being unloaded), then the registry itself.
pub(crate) fn release_all() {
    let cells = std::mem::take(&mut *REGISTERED.lock().unwrap_or_else(|p| p.into_inner()));
    for (addr, f) in cells {
        // SAFETY: each entry is a registered, initialized cell; at unload nothing reads them.
        unsafe { f(addr) };
    }
    for f in EXTRA {
        f();
    }
}

/// Whether this code lives in a shared object (not in the main executable).
#[cfg(target_os = "linux")]
fn in_shared_object() -> bool {
    #[repr(C)]
    struct DlInfo {
        dli_fname: *const std::ffi::c_char,
        dli_fbase: *mut std::ffi::c_void,
        dli_sname: *const std::ffi::c_char,
        dli_saddr: *mut std::ffi::c_void,
    }
    unsafe extern "C" {
        fn dladdr(address: *const std::ffi::c_void, info: *mut DlInfo) -> std::ffi::c_int;
        fn getauxval(kind: std::ffi::c_ulong) -> std::ffi::c_ulong;
    }
    const AT_ENTRY: std::ffi::c_ulong = 9;
    let base = |address: *const std::ffi::c_void| {
        let mut info = DlInfo {
            dli_fname: std::ptr::null(),
            dli_fbase: std::ptr::null_mut(),
            dli_sname: std::ptr::null(),
            dli_saddr: std::ptr::null_mut(),
        };
        // SAFETY: dladdr only reads the loader's tables and fills `info`.
        let ok = unsafe { dladdr(address, &mut info) } != 0;
        ok.then_some(info.dli_fbase)
    };
    // SAFETY: getauxval reads the auxiliary vector; AT_ENTRY is the executable's entry point.
    let entry = unsafe { getauxval(AT_ENTRY) } as *const std::ffi::c_void;
    let ours = base(in_shared_object as fn() -> bool as *const std::ffi::c_void);
    match (ours, base(entry)) {
        (Some(a), Some(b)) => a != b,
        // Unknown: keep the values (a leak is safer than a release too early).
        _ => false,
    }
}

#[cfg(not(target_os = "linux"))]
fn in_shared_object() -> bool {
    false
}

/// The shared object's destructor: releases the statics when the library is unloaded.
extern "C" fn at_unload() {
    // Nothing may unwind out of a destructor called by the loader.
    let _ = std::panic::catch_unwind(|| {
        if in_shared_object() {
            release_all();
        }
    });
}

#[cfg(target_os = "linux")]
#[used]
#[unsafe(link_section = ".fini_array")]
static AT_UNLOAD: extern "C" fn() = at_unload;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_are_built_once_and_registered() {
        static CELL: Once<Vec<u32>> = Once::new();
        // SAFETY: a static.
        static LAZY: Lazy<String> = unsafe { Lazy::new(|| "built".repeat(2)) };
        let a = CELL.get_or_init(|| vec![1, 2, 3]);
        let b = CELL.get_or_init(|| unreachable!("built twice"));
        assert!(std::ptr::eq(a, b));
        assert_eq!(*LAZY, "builtbuilt");
        let addrs: Vec<usize> = REGISTERED.lock().unwrap().iter().map(|e| e.0).collect();
        assert!(addrs.contains(&(&CELL as *const _ as usize)));
        assert!(addrs.contains(&(&LAZY.cell as *const _ as usize)));
        // The test executable links the crate statically: nothing is released at exit.
        assert!(!in_shared_object());
    }
}
