//! FMU binaries with an embedded CPython (PythonFMU exports): the thread that calls such a
//! binary keeps one Python thread state, instead of the binary creating and destroying one in
//! every FMI call.
//!
//! # Why
//!
//! A PythonFMU binary wraps every FMI function in `PyGILState_Ensure()` ...
//! `PyGILState_Release()`. In a thread that has no Python thread state (any thread of a host
//! that is not Python: `kneebench run`, a sweep's workers, the isolated host process),
//! `PyGILState_Ensure` creates one and `PyGILState_Release` destroys it again, in every call:
//! for the peer comparison's `FirstOrder` that is about 90 % of the cost of a step (37-44 us
//! per step against 3.3-4.2 us with a thread state kept; `tests/peers/benches/peers.rs`). In a Python
//! host (fmpy) the calling thread has a thread state of its own and the pair is cheap.
//!
//! # What
//!
//! `PythonApi::detect` recognises such a binary when it is loaded: its dynamic symbol table
//! names `PyGILState_Ensure` (imported, as PythonFMU does, leaving libpython to the host; or
//! defined, an interpreter linked in), and the functions it needs (`Py_IsInitialized`,
//! `PyGILState_{Ensure,Release,Check,GetThisThreadState}`, `PyEval_{Save,Restore}Thread`)
//! resolve in the binary's own scope or in the process's global one (a preloaded libpython, or
//! the Python executable that hosts us). Anything else (no such symbol, an ELF file it cannot read, a missing function)
//! is "no embedded Python": the binary runs as it always did, each call fending for itself.
//!
//! Each in-process [`Instance`](crate::Instance) of such a binary, and the isolated host's one
//! instance, carries a `ThreadStateUser`. Before each FMI call it checks that it is counted on
//! the calling thread (one thread-local read and a compare); the first call from a thread
//! counts it there: if the thread has no Python thread state, one is created with
//! `PyGILState_Ensure` and the GIL is released at once with `PyEval_SaveThread` (a **hold**, one
//! per thread, shared by every instance counted there). Every later `PyGILState_Ensure` of the
//! binary on that thread then finds the thread state and only takes the GIL; its
//! `PyGILState_Release` only releases it. The hold is released (`PyEval_RestoreThread`, then
//! `PyGILState_Release`, which destroys the thread state) on its own thread, as soon as no
//! instance is counted there any more:
//!
//! - an instance freed on the thread it was counted on leaves at once (after `fmi2FreeInstance`,
//!   which still benefits), and the hold goes with its last instance;
//! - an instance called from another thread (moved to a worker, `--parallel` stepping) leaves
//!   its old thread's count (an atomic decrement) and is counted on the new one; the old
//!   thread releases its hold when it next counts or frees an instance, or when it ends (the
//!   thread-local's destructor);
//! - a hold keeps the binaries of the instances counted on it loaded (an `Arc`): a PythonFMU
//!   binary finalizes the interpreter when it is unloaded, and a thread state must never
//!   outlive its interpreter.
//!
//! # What it never does
//!
//! - **Initialise Python**: a hold is made only once `Py_IsInitialized()` (PythonFMU starts the
//!   interpreter in `fmi2Instantiate`, before any instance exists here); before that the
//!   instance is not counted and tries again at its next call.
//! - **Take a thread state that is not its own**: a thread that already has one (a Python
//!   thread, for example one of the `kneebench` Python package's callers, which run the harness
//!   with the GIL released) is left as it is; its thread state already makes the binary's calls
//!   cheap.
//! - **Hold the GIL between calls**: a hold keeps a thread state, not the lock; other threads
//!   (other workers, the Python caller) run Python freely between this thread's calls.
//! - **Wait for a GIL its own thread holds**: a hold is not released while its thread holds
//!   the GIL (`PyGILState_Check`; code on that thread that entered Python with
//!   `PyGILState_Ensure` and freed an instance there); it goes at the thread's next count or
//!   free, or its end.
//!
//! [`PythonThreadState::PerCall`](crate::load::PythonThreadState::PerCall) turns the
//! accommodation off (the baseline it is tested against, bit for bit:
//! `tests/tests/python_thread_state.rs`).

use std::any::Any;
use std::cell::{Cell, RefCell};
use std::ffi::{c_int, c_void};
use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};

/// `PyGILState_STATE` (a C enum) and `PyThreadState *`.
type GilState = c_int;
type ThreadState = *mut c_void;

/// The CPython functions an embedded interpreter's thread states are managed with, resolved
/// where the binary's own references resolve.
#[derive(Clone, Copy)]
pub(crate) struct PythonApi {
    is_initialized: unsafe extern "C" fn() -> c_int,
    gil_ensure: unsafe extern "C" fn() -> GilState,
    gil_release: unsafe extern "C" fn(GilState),
    gil_check: unsafe extern "C" fn() -> c_int,
    this_thread_state: unsafe extern "C" fn() -> ThreadState,
    save_thread: unsafe extern "C" fn() -> ThreadState,
    restore_thread: unsafe extern "C" fn(ThreadState),
}

impl std::fmt::Debug for PythonApi {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PythonApi").finish_non_exhaustive()
    }
}

/// The symbol whose presence in a binary's dynamic symbol table marks an embedded CPython.
const MARKER: &[u8] = b"PyGILState_Ensure";

impl PythonApi {
    /// The CPython functions of `library` (loaded from the file `binary`), if it embeds
    /// CPython (see the [module documentation](self)); `None` otherwise.
    pub(crate) fn detect(library: &libloading::Library, binary: &Path) -> Option<PythonApi> {
        if !dynamic_symbols_name(binary, MARKER) {
            return None;
        }
        let global = libloading::os::unix::Library::this();
        /// # Safety
        /// `T` must be the C type of the function `name`.
        unsafe fn find<T: Copy>(
            library: &libloading::Library,
            global: &libloading::os::unix::Library,
            name: &[u8],
        ) -> Option<T> {
            // SAFETY: per the contract. The binary's own scope first (an interpreter linked in
            // or a libpython it depends on), then the global scope its undefined references
            // were bound from (a preloaded libpython, or the Python executable hosting us).
            unsafe {
                library
                    .get::<T>(name)
                    .map(|s| *s)
                    .or_else(|_| global.get::<T>(name).map(|s| *s))
                    .ok()
            }
        }
        // SAFETY: each symbol is read with its signature in CPython's stable ABI
        // (`pylifecycle.h`, `pystate.h`, `ceval.h`).
        unsafe {
            Some(PythonApi {
                is_initialized: find(library, &global, b"Py_IsInitialized\0")?,
                gil_ensure: find(library, &global, b"PyGILState_Ensure\0")?,
                gil_release: find(library, &global, b"PyGILState_Release\0")?,
                gil_check: find(library, &global, b"PyGILState_Check\0")?,
                this_thread_state: find(library, &global, b"PyGILState_GetThisThreadState\0")?,
                save_thread: find(library, &global, b"PyEval_SaveThread\0")?,
                restore_thread: find(library, &global, b"PyEval_RestoreThread\0")?,
            })
        }
    }

    /// Which interpreter: one per libpython loaded.
    fn key(&self) -> usize {
        self.gil_ensure as usize
    }
}

/// Whether the ELF file `path` (64-bit little-endian, as `binaries/linux64` is) has a dynamic
/// symbol (imported or defined) named `name`. Any file it cannot read this way gives `false`.
fn dynamic_symbols_name(path: &Path, name: &[u8]) -> bool {
    elf_dynamic_symbols_name(path, name).unwrap_or(false)
}

/// Section headers and their tables are read with positioned reads, each bounded by the file.
fn elf_dynamic_symbols_name(path: &Path, name: &[u8]) -> Option<bool> {
    const SHT_DYNSYM: u32 = 11;
    const SHDR: u64 = 64;
    const SYM: usize = 24;
    let file = File::open(path).ok()?;
    let len = file.metadata().ok()?.len();
    let read = |offset: u64, size: u64| -> Option<Vec<u8>> {
        if offset.checked_add(size)? > len {
            return None;
        }
        let mut buf = vec![0u8; usize::try_from(size).ok()?];
        file.read_exact_at(&mut buf, offset).ok()?;
        Some(buf)
    };
    let u16_at = |b: &[u8], o: usize| Some(u16::from_le_bytes(b.get(o..o + 2)?.try_into().ok()?));
    let u32_at = |b: &[u8], o: usize| Some(u32::from_le_bytes(b.get(o..o + 4)?.try_into().ok()?));
    let u64_at = |b: &[u8], o: usize| Some(u64::from_le_bytes(b.get(o..o + 8)?.try_into().ok()?));
    let header = read(0, 64)?;
    // ELF magic, ELFCLASS64, ELFDATA2LSB.
    if header[..4] != *b"\x7fELF" || header[4] != 2 || header[5] != 1 {
        return None;
    }
    let shoff = u64_at(&header, 0x28)?;
    let shentsize = u64::from(u16_at(&header, 0x3a)?);
    let shnum = u64::from(u16_at(&header, 0x3c)?);
    if shentsize < SHDR {
        return None;
    }
    let sections = read(shoff, shnum.checked_mul(shentsize)?)?;
    let section = |i: u64| sections.get((i * shentsize) as usize..(i * shentsize + SHDR) as usize);
    for i in 0..shnum {
        let sh = section(i)?;
        if u32_at(sh, 4)? != SHT_DYNSYM {
            continue;
        }
        let symbols = read(u64_at(sh, 0x18)?, u64_at(sh, 0x20)?)?;
        let strtab = section(u64::from(u32_at(sh, 0x28)?))?;
        let strings = read(u64_at(strtab, 0x18)?, u64_at(strtab, 0x20)?)?;
        let found = symbols.chunks_exact(SYM).any(|sym| {
            let Some(at) = u32_at(sym, 0) else {
                return false;
            };
            strings
                .get(at as usize..)
                .and_then(|s| s.split(|&b| b == 0).next())
                .is_some_and(|s| s == name)
        });
        return Some(found);
    }
    Some(false)
}

/// This thread's number: unique for the life of the process (never reused by a later thread,
/// unlike a thread-local's address), never 0.
fn thread_number() -> u64 {
    static NEXT: AtomicU64 = AtomicU64::new(1);
    thread_local!(static NUMBER: Cell<u64> = const { Cell::new(0) });
    NUMBER.with(|n| match n.get() {
        0 => {
            let v = NEXT.fetch_add(1, Ordering::Relaxed);
            n.set(v);
            v
        }
        v => v,
    })
}

/// What keeps an instance's binary (and the libpython preloaded for it) loaded.
pub(crate) type KeepLoaded = Arc<dyn Any + Send + Sync>;

/// A Python thread state this thread made and keeps, the GIL released.
struct Hold {
    api: PythonApi,
    /// What `PyGILState_Ensure` returned (`PyGILState_UNLOCKED`: the thread state is new).
    gil: GilState,
    /// What `PyEval_SaveThread` returned: this thread's thread state.
    saved: ThreadState,
    /// The instances counted on this hold.
    users: Arc<AtomicUsize>,
    /// The binaries of the instances ever counted here (one `Arc` each).
    keep: Vec<KeepLoaded>,
}

impl Hold {
    /// Whether it can be released now: not while this thread holds the GIL (through a
    /// `PyGILState_Ensure` of its own on the kept thread state, say a Rust callback that
    /// entered Python and dropped an instance there), which `PyEval_RestoreThread` would wait
    /// for forever. (`PyGILState_Check` answers "yes" whenever it cannot tell, with
    /// sub-interpreters: the hold is then kept, never a deadlock.)
    fn releasable(&self) -> bool {
        // SAFETY: `PyGILState_Check` may be called from any thread, with or without the GIL.
        unsafe { (self.api.gil_check)() == 0 }
    }

    /// Takes the GIL back and destroys the thread state.
    ///
    /// Called only on the thread that made the hold (holds live in a thread-local), with the
    /// interpreter alive (`keep` is dropped after).
    fn release(self) {
        // SAFETY: `saved` is this thread's thread state, made by `PyGILState_Ensure` and
        // detached by `PyEval_SaveThread` on this thread, and the interpreter it belongs to
        // is alive: the binaries that would finalize it at unload are in `keep`. Restoring it
        // takes the GIL (waiting for another thread's call to end: never for this thread,
        // which does not hold it, `releasable`); releasing with the state `PyGILState_Ensure` gave undoes that
        // call, and destroys the thread state it created (no other user of it on this thread:
        // a thread state found on a thread is never held).
        unsafe {
            (self.api.restore_thread)(self.saved);
            (self.api.gil_release)(self.gil);
        }
        drop(self.keep);
    }
}

/// This thread's holds, released when the thread ends.
struct Holds(Vec<Hold>);

impl Drop for Holds {
    fn drop(&mut self) {
        for hold in self.0.drain(..) {
            if hold.releasable() {
                hold.release();
            } else {
                // The thread ends holding the GIL: its thread state cannot be taken back, and
                // unloading the binary now would finalize the interpreter under it. Both are
                // left as they are (a leak at the end of a thread, never a deadlock).
                std::mem::forget(hold);
            }
        }
    }
}

thread_local!(static HOLDS: RefCell<Holds> = const { RefCell::new(Holds(Vec::new())) });

/// Releases this thread's holds that no instance is counted on and that can be released now
/// ([`Hold::releasable`]; none while the thread-local is being destroyed: its destructor
/// releases them all).
fn release_unused() {
    let unused: Vec<Hold> = HOLDS
        .try_with(|holds| {
            let mut holds = holds.borrow_mut();
            let (unused, used) = std::mem::take(&mut holds.0)
                .into_iter()
                .partition(|h| h.users.load(Ordering::Acquire) == 0 && h.releasable());
            holds.0 = used;
            unused
        })
        .unwrap_or_default();
    // Outside the borrow: releasing runs Python (thread-state cleanup).
    for hold in unused {
        hold.release();
    }
}

/// One instance's place in the holds: on which thread it is counted (see the
/// [module documentation](self)). Dropping it (after the instance is freed) leaves the count.
pub(crate) struct ThreadStateUser {
    api: PythonApi,
    keep: KeepLoaded,
    /// The thread it is counted on ([`thread_number`]); 0: none yet.
    thread: u64,
    /// The count of the hold it is counted in (`None` on a thread with a thread state of its
    /// own, or none yet).
    users: Option<Arc<AtomicUsize>>,
}

impl std::fmt::Debug for ThreadStateUser {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ThreadStateUser")
            .field("thread", &self.thread)
            .field("held", &self.users.is_some())
            .finish()
    }
}

impl ThreadStateUser {
    /// The user for a new instance of a binary with the embedded interpreter `api` (if any),
    /// whose thread states are kept when `keep_thread_state` (`PythonThreadState::Kept`), and
    /// which `binary` keeps loaded; `None` when there is nothing to keep. The one rule for
    /// in-process instances and the host's. Not counted anywhere until its first
    /// [`enter`](Self::enter).
    pub(crate) fn for_instance(
        api: Option<PythonApi>,
        keep_thread_state: bool,
        binary: KeepLoaded,
    ) -> Option<ThreadStateUser> {
        let api = api.filter(|_| keep_thread_state)?;
        Some(ThreadStateUser {
            api,
            keep: binary,
            thread: 0,
            users: None,
        })
    }

    /// Called before each FMI call of the instance: counts it on the calling thread, with a
    /// hold there if the thread has no Python thread state.
    #[inline]
    pub(crate) fn enter(&mut self) {
        if self.thread != thread_number() {
            self.count_here();
        }
    }

    #[cold]
    fn count_here(&mut self) {
        self.leave();
        // SAFETY: `Py_IsInitialized` may be called at any time, from any thread.
        if unsafe { (self.api.is_initialized)() } == 0 {
            // Not counted: the next call tries again (never initialise it ourselves).
            return;
        }
        let key = self.api.key();
        let here = thread_number();
        // A hold of this thread for this interpreter: counted there.
        let joined = HOLDS.try_with(|holds| {
            let mut holds = holds.borrow_mut();
            let hold = holds.0.iter_mut().find(|h| h.api.key() == key)?;
            hold.users.fetch_add(1, Ordering::AcqRel);
            if !hold.keep.iter().any(|k| Arc::ptr_eq(k, &self.keep)) {
                hold.keep.push(self.keep.clone());
            }
            Some(hold.users.clone())
        });
        let joined = match joined {
            // The thread is ending: its holds are gone; plain calls.
            Err(_) => return,
            Ok(j) => j,
        };
        release_unused();
        if let Some(users) = joined {
            self.users = Some(users);
            self.thread = here;
            return;
        }
        // SAFETY: the interpreter is initialised (checked above); asking for this thread's
        // thread state needs no GIL.
        if !unsafe { (self.api.this_thread_state)() }.is_null() {
            // A thread state of its own (a Python thread): the binary's calls are cheap already.
            self.thread = here;
            return;
        }
        let api = self.api;
        let keep = self.keep.clone();
        let made = HOLDS.try_with(|holds| {
            // SAFETY: this thread has no thread state and holds no GIL (it would have a thread
            // state), so `PyGILState_Ensure` creates one and takes the GIL (waiting for
            // another thread's call to end; this thread holds nothing another waits for), and
            // `PyEval_SaveThread` releases the GIL and detaches the new thread state, which
            // stays this thread's: the binary's `PyGILState_Ensure` finds it. Neither runs
            // Python code. `Hold::release` undoes both, on this thread.
            let (gil, saved) = unsafe {
                let gil = (api.gil_ensure)();
                (gil, (api.save_thread)())
            };
            let users = Arc::new(AtomicUsize::new(1));
            holds.borrow_mut().0.push(Hold {
                api,
                gil,
                saved,
                users: users.clone(),
                keep: vec![keep],
            });
            users
        });
        if let Ok(users) = made {
            self.users = Some(users);
            self.thread = here;
        }
    }

    /// Leaves the count it is in (the hold is released by its own thread).
    fn leave(&mut self) {
        if let Some(users) = self.users.take() {
            users.fetch_sub(1, Ordering::AcqRel);
        }
        self.thread = 0;
    }
}

impl Drop for ThreadStateUser {
    fn drop(&mut self) {
        let here = self.thread == thread_number();
        self.leave();
        if here {
            release_unused();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_marker_is_found_in_an_elf_symbol_table_and_nothing_else_is_read_as_one() {
        // This test executable is an ELF file whose dynamic symbols name libc's functions,
        // not CPython's.
        let exe = std::env::current_exe().unwrap();
        assert!(dynamic_symbols_name(&exe, b"malloc"));
        assert!(!dynamic_symbols_name(&exe, MARKER));
        // Not ELF, cut short, empty, missing: no embedded Python, no panic.
        let dir = tempfile::tempdir().unwrap();
        let bytes = std::fs::read(&exe).unwrap();
        for (name, content) in [
            ("text", b"not an ELF file at all".to_vec()),
            ("empty", Vec::new()),
            ("header-only", bytes[..64].to_vec()),
            ("half", bytes[..bytes.len() / 2].to_vec()),
        ] {
            let p = dir.path().join(name);
            std::fs::write(&p, content).unwrap();
            assert!(!dynamic_symbols_name(&p, b"malloc"), "{name}");
        }
        assert!(!dynamic_symbols_name(
            &dir.path().join("missing"),
            b"malloc"
        ));
    }

    #[test]
    fn thread_numbers_are_unique_and_stable() {
        let a = thread_number();
        assert_eq!(a, thread_number());
        let b = std::thread::spawn(thread_number).join().unwrap();
        let c = std::thread::spawn(thread_number).join().unwrap();
        assert!(a != b && b != c && a != c && a != 0);
    }
}
