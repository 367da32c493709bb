//! `fmi2FreeInstance` through the exported C functions: a component freed twice, or a pointer
//! that was never a component, is ignored without being dereferenced (`export` module docs),
//! and instances created and freed concurrently are each registered and unregistered. Likewise
//! for FMU states: a state freed twice (through a copy of its pointer), or a pointer that was
//! never a state, is refused by every state function without being dereferenced.

use std::ffi::{CString, c_int};
use std::ptr::null_mut;

use super::export::{
    fmi2DeSerializeFMUstate, fmi2FreeFMUstate, fmi2FreeInstance, fmi2GetFMUstate, fmi2Instantiate,
    fmi2SerializeFMUstate, fmi2SerializedFMUstateSize, fmi2SetFMUstate, fmi2SetupExperiment,
};
use super::live;
use super::types::fmi2Status::{fmi2Error, fmi2OK};
use super::types::{fmi2CallbackFunctions, fmi2Component, fmi2FMUstate, fmi2Type};

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
    assert!(live::INSTANCES.contains(c as usize));
    assert_usable(c);
    // SAFETY: `c` is a live instance; the second call is the misuse under test.
    unsafe {
        fmi2FreeInstance(c);
        assert!(!live::INSTANCES.contains(c as usize));
        fmi2FreeInstance(c);
    }
    assert!(!live::INSTANCES.contains(c as usize));
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
    assert!(!live::INSTANCES.contains(c as usize));
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
    let before = live::INSTANCES.count();
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
                        assert!(
                            live::INSTANCES.contains(c as usize),
                            "thread {t} round {round}"
                        );
                        // SAFETY: `c` is a live instance of this thread, freed once.
                        unsafe { fmi2FreeInstance(c) };
                    }
                }
            });
        }
    });
    assert_eq!(live::INSTANCES.count(), before);
}

/// A new state of `c`, through `fmi2GetFMUstate`.
fn get_state(c: fmi2Component) -> fmi2FMUstate {
    let mut state: fmi2FMUstate = null_mut();
    // SAFETY: `c` is a live instance; `state` is a valid out-pointer holding NULL.
    assert_eq!(unsafe { fmi2GetFMUstate(c, &mut state) }, fmi2OK);
    assert!(!state.is_null());
    state
}

/// Every state function refuses `state` (freed already, or never a state) with `fmi2Error`
/// and leaves the pointer as it is.
fn assert_refused_everywhere(c: fmi2Component, state: fmi2FMUstate) {
    // A live state's bytes, which deserialize, to be refused for where they would go.
    let mut live_state = get_state(c);
    let mut size = 0usize;
    // SAFETY: `live_state` is a live state of `c`; `size` a valid out-pointer.
    assert_eq!(
        unsafe { fmi2SerializedFMUstateSize(c, live_state, &mut size) },
        fmi2OK
    );
    let mut bytes = vec![0u8; size];
    // SAFETY: `bytes` holds `size` bytes; then `live_state` is freed once.
    unsafe {
        assert_eq!(
            fmi2SerializeFMUstate(c, live_state, bytes.as_mut_ptr().cast(), size),
            fmi2OK
        );
        assert_eq!(fmi2FreeFMUstate(c, &mut live_state), fmi2OK);
    }
    let mut copy = state;
    let mut size = 0usize;
    let mut buffer = [0u8; 8];
    // SAFETY: `c` is a live instance and every out-pointer is valid; `state` is the misuse
    // under test.
    unsafe {
        assert_eq!(fmi2SetFMUstate(c, state), fmi2Error);
        assert_eq!(fmi2SerializedFMUstateSize(c, state, &mut size), fmi2Error);
        assert_eq!(size, 0);
        assert_eq!(
            fmi2SerializeFMUstate(c, state, buffer.as_mut_ptr().cast(), buffer.len()),
            fmi2Error
        );
        assert_eq!(fmi2GetFMUstate(c, &mut copy), fmi2Error);
        assert_eq!(copy, state);
        assert_eq!(
            fmi2DeSerializeFMUstate(c, bytes.as_ptr().cast(), bytes.len(), &mut copy),
            fmi2Error
        );
        assert_eq!(copy, state);
        assert_eq!(fmi2FreeFMUstate(c, &mut copy), fmi2Error);
        assert_eq!(copy, state);
    }
    assert_eq!(buffer, [0; 8]);
}

#[test]
fn a_state_freed_twice_through_a_copy_is_freed_once() {
    let _alone = alone();
    let c = instantiate("state twice");
    let mut state = get_state(c);
    let copy = state;
    assert!(live::STATES.contains(state as usize));
    // SAFETY: `state` is a live state of `c`.
    assert_eq!(unsafe { fmi2SetFMUstate(c, state) }, fmi2OK);
    // SAFETY: `state` is a live state of `c`, freed once here.
    assert_eq!(unsafe { fmi2FreeFMUstate(c, &mut state) }, fmi2OK);
    assert!(state.is_null());
    assert!(!live::STATES.contains(copy as usize));
    // The copy still points at the freed state: refused, not freed again nor read.
    assert_refused_everywhere(c, copy);
    // The instance is still usable and still makes states.
    assert_usable(c);
    let mut again = get_state(c);
    // SAFETY: `again` is a live state of `c`, freed once.
    assert_eq!(unsafe { fmi2FreeFMUstate(c, &mut again) }, fmi2OK);
    // SAFETY: `c` is a live instance.
    unsafe { fmi2FreeInstance(c) };
}

#[test]
fn a_pointer_that_was_never_a_state_is_not_touched() {
    let _alone = alone();
    let c = instantiate("not a state");
    // Read as a state it would be an empty Vec: freeing it would free stack memory.
    let mut not_a_state = [0usize; 4];
    let state: fmi2FMUstate = not_a_state.as_mut_ptr().cast();
    assert!(!live::STATES.contains(state as usize));
    assert_refused_everywhere(c, state);
    assert_eq!(not_a_state, [0; 4]);
    // SAFETY: `c` is a live instance.
    unsafe { fmi2FreeInstance(c) };
}

/// A state got, then overwritten in place by a second get and by a deserialization, stays one
/// live state, and freeing it empties the registry of this test's states.
#[test]
fn a_state_overwritten_in_place_stays_one_live_state() {
    let _alone = alone();
    let before = live::STATES.count();
    let c = instantiate("overwrite");
    let mut state = get_state(c);
    let first = state;
    // SAFETY: `c` is a live instance; `state` a live state of it, overwritten in place.
    assert_eq!(unsafe { fmi2GetFMUstate(c, &mut state) }, fmi2OK);
    assert_eq!(state, first);
    let mut size = 0usize;
    // SAFETY: as above; `size` is a valid out-pointer.
    assert_eq!(
        unsafe { fmi2SerializedFMUstateSize(c, state, &mut size) },
        fmi2OK
    );
    let mut bytes = vec![0u8; size];
    // SAFETY: `bytes` holds `size` bytes.
    unsafe {
        assert_eq!(
            fmi2SerializeFMUstate(c, state, bytes.as_mut_ptr().cast(), size),
            fmi2OK
        );
        assert_eq!(
            fmi2DeSerializeFMUstate(c, bytes.as_ptr().cast(), size, &mut state),
            fmi2OK
        );
    }
    assert_eq!(state, first);
    assert_eq!(live::STATES.count(), before + 1);
    // SAFETY: `state` is a live state of `c`, freed once.
    assert_eq!(unsafe { fmi2FreeFMUstate(c, &mut state) }, fmi2OK);
    assert_eq!(live::STATES.count(), before);
    // SAFETY: `c` is a live instance.
    unsafe { fmi2FreeInstance(c) };
}
