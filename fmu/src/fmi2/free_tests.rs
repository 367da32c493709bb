//! `fmi2FreeInstance` through the exported C functions: a component freed twice, or a pointer
//! that was never a component, is ignored without being dereferenced (`export` module docs),
//! and instances created and freed concurrently are each registered and unregistered.

use std::ffi::{CString, c_int};
use std::ptr::null_mut;

use super::export::{fmi2FreeInstance, fmi2Instantiate, fmi2SetupExperiment};
use super::live;
use super::types::fmi2Status::fmi2OK;
use super::types::{fmi2CallbackFunctions, fmi2Component, fmi2Type};

/// No logger, no memory callbacks.
const CALLBACKS: fmi2CallbackFunctions = fmi2CallbackFunctions {
    logger: None,
    allocateMemory: None,
    freeMemory: None,
    stepFinished: None,
    componentEnvironment: null_mut(),
};

/// A new GaitReference instance, through `fmi2Instantiate`.
fn instantiate(name: &str) -> fmi2Component {
    let guid = crate::registry::find_by_identifier("GaitReference")
        .expect("GaitReference is exported")
        .info()
        .guid
        .clone();
    let guid = CString::new(guid).unwrap();
    let name = CString::new(name).unwrap();
    // SAFETY: valid NUL-terminated strings and callbacks, alive for the call.
    let c = unsafe {
        fmi2Instantiate(
            name.as_ptr(),
            fmi2Type::fmi2CoSimulation as c_int,
            guid.as_ptr(),
            std::ptr::null(),
            &CALLBACKS,
            0,
            0,
        )
    };
    assert!(!c.is_null());
    c
}

/// Serializes the tests of this module: the registry is the process's, and the count of live
/// instances is checked.
fn alone() -> std::sync::MutexGuard<'static, ()> {
    static ALONE: std::sync::Mutex<()> = std::sync::Mutex::new(());
    ALONE
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// `fmi2SetupExperiment` on `c` succeeds: the instance is usable.
fn assert_usable(c: fmi2Component) {
    // SAFETY: `c` is a live instance.
    let status = unsafe { fmi2SetupExperiment(c, 0, 0.0, 0.0, 0, 0.0) };
    assert_eq!(status, fmi2OK);
}

#[test]
fn an_instance_freed_twice_is_freed_once() {
    let _alone = alone();
    let c = instantiate("twice");
    assert!(live::is_live(c as usize));
    assert_usable(c);
    // SAFETY: `c` is a live instance; the second call is the misuse under test.
    unsafe {
        fmi2FreeInstance(c);
        assert!(!live::is_live(c as usize));
        fmi2FreeInstance(c);
    }
    assert!(!live::is_live(c as usize));
    // Still a working binary: a new instance comes and goes.
    let d = instantiate("after");
    assert_usable(d);
    // SAFETY: `d` is a live instance.
    unsafe { fmi2FreeInstance(d) };
}

#[test]
fn a_pointer_that_was_never_an_instance_is_not_touched() {
    let _alone = alone();
    // Read as a component it would be a NULL box with a NULL vtable: dropping it would crash.
    let mut not_an_instance = [0usize; 4];
    let c: fmi2Component = not_an_instance.as_mut_ptr().cast();
    assert!(!live::is_live(c as usize));
    // SAFETY: the misuse under test; the pointer is valid memory, but not a component.
    unsafe { fmi2FreeInstance(c) };
    assert_eq!(not_an_instance, [0; 4]);
    // NULL too.
    // SAFETY: NULL is ignored.
    unsafe { fmi2FreeInstance(null_mut()) };
}

/// Several threads instantiating and freeing at once: every instance is registered on
/// instantiation and still registered when it is freed (a lost registration would make its
/// free a no-op that leaks it), and freeing them all empties the registry again (a lost
/// removal would leave a freed address live).
#[test]
fn concurrent_instantiation_and_freeing_lose_no_registration() {
    const THREADS: usize = 4;
    const ROUNDS: usize = 40;
    const HELD: usize = 3;
    let _alone = alone();
    let before = live::count();
    let start = std::sync::Barrier::new(THREADS);
    std::thread::scope(|s| {
        for t in 0..THREADS {
            let start = &start;
            s.spawn(move || {
                start.wait();
                for round in 0..ROUNDS {
                    let held: Vec<fmi2Component> = (0..HELD)
                        .map(|k| instantiate(&format!("t{t}r{round}k{k}")))
                        .collect();
                    for &c in &held {
                        assert_usable(c);
                    }
                    for &c in &held {
                        assert!(live::is_live(c as usize), "thread {t} round {round}");
                        // SAFETY: `c` is a live instance of this thread, freed once.
                        unsafe { fmi2FreeInstance(c) };
                    }
                }
            });
        }
    });
    assert_eq!(live::count(), before);
}
