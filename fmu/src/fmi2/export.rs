//! The exported C functions: every common and co-simulation function of FMI 2.0.
//!
//! Each entry point checks its pointers, runs the call inside `catch_unwind` (a panic must
//! never cross `extern "C"`: it would abort the importer), checks the call sequence, and
//! converts C arguments into slices and `&str`s before the generic [`FmiInstance`] sees them.
//! The gets, sets and `fmi2DoStep` leave the sequence check to the instance (see
//! [`FmiInstance`]), which makes it after the arguments are converted, and the `catch_unwind`
//! too: their instance methods never unwind, so a call with valid pointers is a jump into the
//! instance (a NULL pointer takes the checking path that names it).
//! This is the only module with `unsafe` pointer handling.
//!
//! # Freed and foreign component pointers
//!
//! `fmi2Instantiate` records each instance it returns in a registry of live instances, and
//! `fmi2FreeInstance` frees a component only if it removes it from there. Freeing an instance
//! a second time, or freeing a non-NULL pointer this binary never returned, is therefore
//! harmless: the call returns without touching the pointer (so does NULL). Of two concurrent
//! frees of one instance exactly one frees it.
//!
//! Nothing else is guarded. Every other function trusts its (non-NULL) component pointer
//! without a look-up, so that the gets, sets and `fmi2DoStep`, the per-step path, pay no lock:
//! calling any function but `fmi2FreeInstance` on a freed instance (or on a pointer that was
//! never an instance) remains the importer's undefined behaviour, as in the FMI standard. Nor
//! can a pointer freed twice be told from a new instance that the allocator placed at the same
//! address: its second free frees that instance.
//!
//! # Freed and foreign FMU states
//!
//! FMU states have a registry of their own: `fmi2GetFMUstate` and `fmi2DeSerializeFMUstate`
//! record each state they make, `fmi2FreeFMUstate` frees a state only if it removes it from
//! there, and every state function (get and deserialize overwriting an existing state, set,
//! the serialized size, serialize, free) refuses a non-NULL state that is not live with
//! `fmi2Error` and a log line, without dereferencing it. A state freed a second time (through
//! a copy of its pointer), or a pointer this binary never made, is therefore harmless. The
//! states are not the per-step path, so the lock costs nothing that matters.
//!
//! What stays undefined: a freed state's address that the allocator gave to a new state is that
//! new state (a stale copy of the old pointer reaches it); a state is not bound to the instance
//! that made it (a state of another instance of the same model is restored if its bytes check
//! out, one of another model is refused by the GUID in its bytes); the out-pointer itself
//! (`FMUstate` of the get, free and deserialize functions) must be valid memory; and a state
//! used from two threads at once is a data race, as for an instance. States the importer never
//! frees stay allocated (and registered) until the process ends: freeing an instance does not
//! free its states.

#![allow(non_snake_case, clippy::missing_safety_doc)]

use std::borrow::Cow;
use std::ffi::{CStr, c_char, c_int};
use std::panic::{AssertUnwindSafe, catch_unwind};

use super::instance::{FmiInstance, Func, answer_panic};
use super::live;
use super::logging::{Category, Logger};
use super::types::*;
use crate::registry;

use fmi2Status::{fmi2Discard, fmi2Error, fmi2OK};

/// The component handed to the importer: a thin pointer to the boxed instance.
type Component = Box<dyn FmiInstance>;

/// Runs `body` on the instance behind `c`, unless `c` is NULL or (with `func` given) the call
/// is out of sequence; with `func` None the instance checks the sequence itself.
/// A panic is caught, logged, and answered with `fmi2Error` (the instance enters the error
/// state, from which `fmi2Reset` recovers).
fn with_instance(
    c: fmi2Component,
    name: &'static str,
    func: Option<Func>,
    body: impl FnOnce(&mut dyn FmiInstance) -> fmi2Status,
) -> fmi2Status {
    if c.is_null() {
        return fmi2Error;
    }
    // SAFETY: a non-NULL component was returned by fmi2Instantiate (a leaked Box<Component>)
    // and not yet freed; the importer calls an instance from one thread at a time.
    let component: &mut Component = unsafe { &mut *c.cast::<Component>() };
    let result = catch_unwind(AssertUnwindSafe(|| {
        if let Some(func) = func
            && !component.allow(func, name)
        {
            return fmi2Error;
        }
        body(component.as_mut())
    }));
    match result {
        Ok(status) => status,
        Err(payload) => answer_panic(component.as_mut(), name, payload),
    }
}

/// The file name, without extension, of the shared library this code was loaded from
/// (`binaries/<platform>/<modelIdentifier>.so` inside an FMU), once per process.
fn library_stem() -> Option<&'static str> {
    static STEM: crate::release::Once<Option<String>> = crate::release::Once::new();
    STEM.get_or_init(|| {
        let path = loaded_from()?;
        let stem = std::path::Path::new(&path).file_stem()?.to_str()?;
        Some(stem.to_string())
    })
    .as_deref()
}

/// The `modelIdentifier` of the co-simulation FMU whose resources are at `location` (a `file:`
/// URI, as fmi2Instantiate receives it): read from the head of the `modelDescription.xml`
/// beside them. Only a hint (the GUID decides), so anything unexpected is `None`.
fn identifier_beside(location: fmi2String) -> Option<String> {
    use std::io::Read;
    if location.is_null() {
        return None;
    }
    // SAFETY: non-NULL, NUL-terminated by the FMI contract.
    let uri = unsafe { CStr::from_ptr(location) }.to_str().ok()?;
    let resources = file_uri_path(uri)?;
    let description = resources.parent()?.join("modelDescription.xml");
    let mut head = Vec::new();
    std::fs::File::open(description)
        .ok()?
        .take(16 * 1024)
        .read_to_end(&mut head)
        .ok()?;
    let text = String::from_utf8_lossy(&head);
    let element = &text[text.find("<CoSimulation")?..];
    let element = &element[..element.find('>')?];
    const ATTRIBUTE: &str = "modelIdentifier=\"";
    let value = &element[element.find(ATTRIBUTE)? + ATTRIBUTE.len()..];
    Some(value[..value.find('"')?].to_string())
}

/// The absolute path of a `file:` URI (`file:///p`, `file://localhost/p`, `file:/p`;
/// percent-encoded bytes decoded).
fn file_uri_path(uri: &str) -> Option<std::path::PathBuf> {
    use std::os::unix::ffi::OsStringExt;
    let rest = match uri.strip_prefix("file://") {
        Some(r) => r.strip_prefix("localhost").unwrap_or(r),
        None => uri.strip_prefix("file:")?,
    };
    if !rest.starts_with('/') {
        return None;
    }
    let bytes = rest.as_bytes();
    let mut path = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'%' {
            let hex = std::str::from_utf8(bytes.get(i + 1..i + 3)?).ok()?;
            path.push(u8::from_str_radix(hex, 16).ok()?);
            i += 3;
        } else {
            path.push(bytes[i]);
            i += 1;
        }
    }
    Some(std::ffi::OsString::from_vec(path).into())
}

/// The path of the object that holds this function, from the dynamic loader.
#[cfg(target_os = "linux")]
fn loaded_from() -> Option<String> {
    /// glibc's and musl's `Dl_info`.
    #[repr(C)]
    struct DlInfo {
        dli_fname: *const c_char,
        dli_fbase: *mut std::ffi::c_void,
        dli_sname: *const c_char,
        dli_saddr: *mut std::ffi::c_void,
    }
    unsafe extern "C" {
        fn dladdr(address: *const std::ffi::c_void, info: *mut DlInfo) -> c_int;
    }
    let mut info = DlInfo {
        dli_fname: std::ptr::null(),
        dli_fbase: std::ptr::null_mut(),
        dli_sname: std::ptr::null(),
        dli_saddr: std::ptr::null_mut(),
    };
    let address = loaded_from as fn() -> Option<String> as *const std::ffi::c_void;
    // SAFETY: `dladdr` only reads the loader's tables for an address of this object and fills
    // `info`; on success `dli_fname` points to a NUL-terminated path owned by the loader,
    // valid while this object stays loaded, and copied at once.
    unsafe {
        if dladdr(address, &mut info) == 0 || info.dli_fname.is_null() {
            return None;
        }
        Some(
            CStr::from_ptr(info.dli_fname)
                .to_string_lossy()
                .into_owned(),
        )
    }
}

/// Elsewhere every model is tried in turn.
#[cfg(not(target_os = "linux"))]
fn loaded_from() -> Option<String> {
    None
}

/// A slice from a C array; NULL is accepted only for an empty array.
///
/// # Safety
/// `ptr` must point to `n` valid elements when it is not NULL.
unsafe fn slice<'a, T>(ptr: *const T, n: usize) -> Option<&'a [T]> {
    if n == 0 {
        Some(&[])
    } else if ptr.is_null() {
        None
    } else {
        // SAFETY: guaranteed by the caller (the FMI contract on array arguments).
        Some(unsafe { std::slice::from_raw_parts(ptr, n) })
    }
}

/// A mutable slice from a C array; NULL is accepted only for an empty array.
///
/// # Safety
/// `ptr` must point to `n` writable elements when it is not NULL.
unsafe fn slice_mut<'a, T>(ptr: *mut T, n: usize) -> Option<&'a mut [T]> {
    if n == 0 {
        Some(&mut [])
    } else if ptr.is_null() {
        None
    } else {
        // SAFETY: guaranteed by the caller (the FMI contract on array arguments).
        Some(unsafe { std::slice::from_raw_parts_mut(ptr, n) })
    }
}

fn null_arg(inst: &dyn FmiInstance, function: &str, what: &str) -> fmi2Status {
    inst.refuse(function, &format!("{what} is NULL"))
}

/// The FMI 2.0 function `fmi2GetTypesPlatform`: see the module documentation.
#[unsafe(no_mangle)]
pub extern "C" fn fmi2GetTypesPlatform() -> *const c_char {
    fmi2TypesPlatform.as_ptr()
}

/// The FMI 2.0 function `fmi2GetVersion`: see the module documentation.
#[unsafe(no_mangle)]
pub extern "C" fn fmi2GetVersion() -> *const c_char {
    fmi2Version.as_ptr()
}

/// The FMI 2.0 function `fmi2SetDebugLogging`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2SetDebugLogging(
    c: fmi2Component,
    loggingOn: fmi2Boolean,
    nCategories: usize,
    categories: *const fmi2String,
) -> fmi2Status {
    let f = "fmi2SetDebugLogging";
    with_instance(c, f, Some(Func::SetDebugLogging), |inst| {
        // SAFETY: FMI contract: `categories` holds nCategories strings.
        let Some(raw) = (unsafe { slice(categories, nCategories) }) else {
            return null_arg(inst, f, "categories");
        };
        let mut names = Vec::with_capacity(raw.len());
        for &p in raw {
            if p.is_null() {
                return null_arg(inst, f, "a category name");
            }
            // SAFETY: non-NULL, NUL-terminated by the FMI contract.
            match unsafe { CStr::from_ptr(p) }.to_str() {
                Ok(s) => names.push(s),
                Err(_) => return inst.refuse(f, "a category name is not UTF-8"),
            }
        }
        inst.set_debug_logging(loggingOn != 0, &names)
    })
}

/// The FMI 2.0 function `fmi2Instantiate`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2Instantiate(
    instanceName: fmi2String,
    fmuType: c_int,
    fmuGUID: fmi2String,
    fmuResourceLocation: fmi2String,
    functions: *const fmi2CallbackFunctions,
    _visible: fmi2Boolean,
    loggingOn: fmi2Boolean,
) -> fmi2Component {
    let result = catch_unwind(|| {
        if functions.is_null() {
            return std::ptr::null_mut();
        }
        // SAFETY: non-NULL; points to the importer's callback struct for this call.
        let callbacks = unsafe { *functions };
        let name = if instanceName.is_null() {
            c"(unnamed)"
        } else {
            // SAFETY: non-NULL, NUL-terminated by the FMI contract.
            unsafe { CStr::from_ptr(instanceName) }
        };
        let logger = Logger::new(
            callbacks.logger,
            callbacks.componentEnvironment,
            name,
            loggingOn != 0,
        );
        let refuse = |why: &str| {
            logger.log(
                fmi2Error,
                Category::Error,
                &format!("fmi2Instantiate: {why}"),
            );
            std::ptr::null_mut()
        };
        if instanceName.is_null() || name.is_empty() {
            return refuse("instanceName must be a non-empty string");
        }
        if fmuType != fmi2Type::fmi2CoSimulation as c_int {
            return refuse(&format!(
                "fmuType {fmuType} requested; this FMU implements co-simulation ({}) only",
                fmi2Type::fmi2CoSimulation as c_int
            ));
        }
        if fmuGUID.is_null() {
            return refuse("fmuGUID is NULL");
        }
        // SAFETY: non-NULL, NUL-terminated by the FMI contract.
        let guid = unsafe { CStr::from_ptr(fmuGUID) }.to_string_lossy();
        // The packager names each FMU's copy of this binary after its model: that model is
        // tried first, so an instantiation builds only its own description and GUID. An
        // importer that loads one copy for several FMUs (kneebench does) passes each FMU's
        // resources, next to its model description: the model named there is tried next.
        let hints =
            std::iter::once(library_stem().map(Cow::Borrowed)).chain(std::iter::once_with(|| {
                identifier_beside(fmuResourceLocation).map(Cow::Owned)
            }));
        let Some(entry) = registry::find_by_guid_with_hints(&guid, hints) else {
            return refuse(&format!(
                "no model with GUID {guid} in this binary (models: {})",
                crate::MODELS
                    .iter()
                    .map(|m| format!("{} {}", m.identifier, m.info().guid))
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
        };
        let component: Box<Component> = Box::new(entry.instantiate(logger));
        let c: fmi2Component = Box::into_raw(component).cast();
        live::INSTANCES.register(c as usize);
        c
    });
    result.unwrap_or(std::ptr::null_mut())
}

/// The FMI 2.0 function `fmi2FreeInstance`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2FreeInstance(c: fmi2Component) {
    if c.is_null() {
        return;
    }
    let _ = catch_unwind(|| {
        // Only the one call that removes a live instance frees it: a pointer freed already, or
        // never returned by fmi2Instantiate, is not dereferenced.
        if live::INSTANCES.unregister(c as usize) {
            // SAFETY: c was live, so it came from Box::into_raw in fmi2Instantiate, and only
            // this call removed it from the registry (the importer must not use it afterwards).
            drop(unsafe { Box::from_raw(c.cast::<Component>()) });
        }
    });
}

/// The FMI 2.0 function `fmi2SetupExperiment`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2SetupExperiment(
    c: fmi2Component,
    toleranceDefined: fmi2Boolean,
    tolerance: fmi2Real,
    startTime: fmi2Real,
    stopTimeDefined: fmi2Boolean,
    stopTime: fmi2Real,
) -> fmi2Status {
    with_instance(
        c,
        "fmi2SetupExperiment",
        Some(Func::SetupExperiment),
        |inst| {
            inst.setup_experiment(
                startTime,
                (stopTimeDefined != 0).then_some(stopTime),
                (toleranceDefined != 0).then_some(tolerance),
            )
        },
    )
}

/// The FMI 2.0 function `fmi2EnterInitializationMode`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2EnterInitializationMode(c: fmi2Component) -> fmi2Status {
    with_instance(
        c,
        "fmi2EnterInitializationMode",
        Some(Func::EnterInitializationMode),
        |inst| inst.enter_initialization_mode(),
    )
}

/// The FMI 2.0 function `fmi2ExitInitializationMode`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2ExitInitializationMode(c: fmi2Component) -> fmi2Status {
    with_instance(
        c,
        "fmi2ExitInitializationMode",
        Some(Func::ExitInitializationMode),
        |inst| inst.exit_initialization_mode(),
    )
}

/// The FMI 2.0 function `fmi2Terminate`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2Terminate(c: fmi2Component) -> fmi2Status {
    with_instance(c, "fmi2Terminate", Some(Func::Terminate), |inst| {
        inst.terminate()
    })
}

/// The FMI 2.0 function `fmi2Reset`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2Reset(c: fmi2Component) -> fmi2Status {
    with_instance(c, "fmi2Reset", Some(Func::Reset), |inst| inst.reset())
}

/// The instance behind a non-NULL component, for the per-step functions' direct calls.
///
/// # Safety
/// As in [`with_instance`]: `c` was returned by fmi2Instantiate and not yet freed, and the
/// importer calls an instance from one thread at a time.
unsafe fn component<'a>(c: fmi2Component) -> &'a mut dyn FmiInstance {
    // SAFETY: the caller's contract.
    unsafe { &mut **c.cast::<Component>() }
}

/// A get or set's answer when the fast path of [`per_step_access`] did not apply: a NULL
/// component (`fmi2Error`) or a NULL array for a non-empty call (refused, named).
#[cold]
#[inline(never)]
fn refuse_null(c: fmi2Component, function: &'static str) -> fmi2Status {
    with_instance(c, function, None, |inst| {
        null_arg(inst, function, "vr or value")
    })
}

/// A get or set whose value array is a `$ptr` (`$slice` turns it into a slice).
macro_rules! per_step_access {
    ($name:ident, $method:ident, $ptr:ty, $slice:ident) => {
        #[doc = concat!("The FMI 2.0 function `", stringify!($name), "`: see the module documentation.")]
        #[unsafe(no_mangle)]
        pub unsafe extern "C" fn $name(
            c: fmi2Component,
            vr: *const fmi2ValueReference,
            nvr: usize,
            value: $ptr,
        ) -> fmi2Status {
            // The per-step path: a component and both arrays (or none, nvr = 0) go straight to
            // the instance, which checks the call sequence and catches its own panics
            // ([`FmiInstance`]); a NULL takes `refuse_null`.
            // SAFETY: FMI contract: vr and value hold nvr elements.
            if !c.is_null()
                && let (Some(vrs), Some(values)) =
                    (unsafe { slice(vr, nvr) }, unsafe { $slice(value, nvr) })
            {
                // SAFETY: a non-NULL component (see `component`).
                return unsafe { component(c) }.$method(vrs, values);
            }
            refuse_null(c, stringify!($name))
        }
    };
}

per_step_access!(fmi2GetReal, get_real, *mut fmi2Real, slice_mut);
per_step_access!(fmi2GetInteger, get_integer, *mut fmi2Integer, slice_mut);
per_step_access!(fmi2GetBoolean, get_boolean, *mut fmi2Boolean, slice_mut);
per_step_access!(fmi2GetString, get_string, *mut fmi2String, slice_mut);
per_step_access!(fmi2SetReal, set_real, *const fmi2Real, slice);
per_step_access!(fmi2SetInteger, set_integer, *const fmi2Integer, slice);
per_step_access!(fmi2SetBoolean, set_boolean, *const fmi2Boolean, slice);

/// The FMI 2.0 function `fmi2SetString`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2SetString(
    c: fmi2Component,
    vr: *const fmi2ValueReference,
    nvr: usize,
    value: *const fmi2String,
) -> fmi2Status {
    let f = "fmi2SetString";
    // The instance checks the call sequence itself (inlined there).
    with_instance(c, f, None, |inst| {
        // SAFETY: FMI contract: vr and value hold nvr elements.
        let (Some(vrs), Some(raw)) = (unsafe { slice(vr, nvr) }, unsafe { slice(value, nvr) })
        else {
            return null_arg(inst, f, "vr or value");
        };
        let mut values = Vec::with_capacity(raw.len());
        for &p in raw {
            if p.is_null() {
                return null_arg(inst, f, "a string value");
            }
            // SAFETY: non-NULL, NUL-terminated by the FMI contract.
            match unsafe { CStr::from_ptr(p) }.to_str() {
                Ok(s) => values.push(s),
                Err(_) => return inst.refuse(f, "a string value is not UTF-8"),
            }
        }
        inst.set_string(vrs, &values)
    })
}

/// The bytes behind an `fmi2FMUstate`.
type SavedState = Vec<u8>;

/// Why `state` is refused: freed already, or never made by this binary.
fn not_a_state(state: fmi2FMUstate) -> String {
    format!(
        "FMUstate {state:p} is not a live state of this FMU (freed already, or never made by it)"
    )
}

/// Whether `state` may be read: a live state of this binary (or NULL, where `null_ok`, which
/// asks for a new one). The pointer is only compared, never dereferenced.
fn check_live_state(state: fmi2FMUstate, null_ok: bool) -> Result<(), String> {
    if (null_ok && state.is_null()) || live::STATES.contains(state as usize) {
        Ok(())
    } else {
        Err(not_a_state(state))
    }
}

/// Stores `bytes` in `existing` (a live state) or, when it is NULL, in a new state, registered
/// and written to `out`.
///
/// # Safety
/// `out` is a valid out-pointer; `existing` is NULL or a live state ([`check_live_state`]).
unsafe fn store_state(out: *mut fmi2FMUstate, existing: fmi2FMUstate, bytes: SavedState) {
    if existing.is_null() {
        let state: fmi2FMUstate = Box::into_raw(Box::new(bytes)).cast();
        live::STATES.register(state as usize);
        // SAFETY: a valid out-pointer (the caller's contract).
        unsafe { *out = state };
    } else {
        // SAFETY: a live state: a SavedState made by this function (the caller's contract).
        unsafe { *existing.cast::<SavedState>() = bytes };
    }
}

/// The FMI 2.0 function `fmi2GetFMUstate`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2GetFMUstate(
    c: fmi2Component,
    FMUstate: *mut fmi2FMUstate,
) -> fmi2Status {
    let f = "fmi2GetFMUstate";
    with_instance(c, f, Some(Func::FmuState), |inst| {
        if FMUstate.is_null() {
            return null_arg(inst, f, "FMUstate");
        }
        // SAFETY: FMUstate is a valid out-pointer (the importer's variable).
        let existing = unsafe { *FMUstate };
        if let Err(why) = check_live_state(existing, true) {
            return inst.refuse(f, &why);
        }
        // A non-NULL state is overwritten in place, as the standard says; NULL asks for a new one.
        // SAFETY: `existing` is NULL or a live state (checked), FMUstate a valid out-pointer.
        unsafe { store_state(FMUstate, existing, inst.save_state()) };
        fmi2OK
    })
}

/// The FMI 2.0 function `fmi2SetFMUstate`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2SetFMUstate(c: fmi2Component, FMUstate: fmi2FMUstate) -> fmi2Status {
    let f = "fmi2SetFMUstate";
    with_instance(c, f, Some(Func::FmuState), |inst| {
        if FMUstate.is_null() {
            return null_arg(inst, f, "FMUstate");
        }
        if let Err(why) = check_live_state(FMUstate, false) {
            return inst.refuse(f, &why);
        }
        // SAFETY: a live state (checked), made by fmi2GetFMUstate or fmi2DeSerializeFMUstate.
        let bytes: &SavedState = unsafe { &*FMUstate.cast::<SavedState>() };
        match inst.restore_state(bytes) {
            Ok(()) => fmi2OK,
            Err(e) => inst.refuse(f, &e.to_string()),
        }
    })
}

/// The FMI 2.0 function `fmi2FreeFMUstate`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2FreeFMUstate(
    c: fmi2Component,
    FMUstate: *mut fmi2FMUstate,
) -> fmi2Status {
    let f = "fmi2FreeFMUstate";
    with_instance(c, f, Some(Func::FmuState), |inst| {
        if FMUstate.is_null() {
            return null_arg(inst, f, "FMUstate");
        }
        // SAFETY: FMUstate is a valid out-pointer (the importer's variable).
        let state = unsafe { *FMUstate };
        if state.is_null() {
            return fmi2OK;
        }
        // Only the call that removes a live state frees it: one freed already (through a copy
        // of its pointer), or never made by this binary, is refused without being touched.
        if !live::STATES.unregister(state as usize) {
            return inst.refuse(f, &not_a_state(state));
        }
        // SAFETY: the state was live, so it came from Box::into_raw in store_state, and only
        // this call removed it from the registry; FMUstate is a valid out-pointer.
        unsafe {
            drop(Box::from_raw(state.cast::<SavedState>()));
            *FMUstate = std::ptr::null_mut();
        }
        fmi2OK
    })
}

/// The FMI 2.0 function `fmi2SerializedFMUstateSize`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2SerializedFMUstateSize(
    c: fmi2Component,
    FMUstate: fmi2FMUstate,
    size: *mut usize,
) -> fmi2Status {
    let f = "fmi2SerializedFMUstateSize";
    with_instance(c, f, Some(Func::SerializeFmuState), |inst| {
        if FMUstate.is_null() || size.is_null() {
            return null_arg(inst, f, "FMUstate or size");
        }
        if let Err(why) = check_live_state(FMUstate, false) {
            return inst.refuse(f, &why);
        }
        // SAFETY: a live state of ours (checked); size is a valid out-pointer.
        unsafe { *size = (*FMUstate.cast::<SavedState>()).len() };
        fmi2OK
    })
}

/// The FMI 2.0 function `fmi2SerializeFMUstate`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2SerializeFMUstate(
    c: fmi2Component,
    FMUstate: fmi2FMUstate,
    serializedState: *mut fmi2Byte,
    size: usize,
) -> fmi2Status {
    let f = "fmi2SerializeFMUstate";
    with_instance(c, f, Some(Func::SerializeFmuState), |inst| {
        if FMUstate.is_null() || serializedState.is_null() {
            return null_arg(inst, f, "FMUstate or serializedState");
        }
        if let Err(why) = check_live_state(FMUstate, false) {
            return inst.refuse(f, &why);
        }
        // SAFETY: a live state of ours (checked).
        let bytes: &SavedState = unsafe { &*FMUstate.cast::<SavedState>() };
        if size < bytes.len() {
            return inst.refuse(
                f,
                &format!(
                    "buffer of {size} bytes is too small: the state needs {}",
                    bytes.len()
                ),
            );
        }
        // SAFETY: the buffer holds at least `size` >= bytes.len() bytes.
        unsafe {
            std::ptr::copy_nonoverlapping(bytes.as_ptr(), serializedState.cast::<u8>(), bytes.len())
        };
        fmi2OK
    })
}

/// The FMI 2.0 function `fmi2DeSerializeFMUstate`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2DeSerializeFMUstate(
    c: fmi2Component,
    serializedState: *const fmi2Byte,
    size: usize,
    FMUstate: *mut fmi2FMUstate,
) -> fmi2Status {
    let f = "fmi2DeSerializeFMUstate";
    with_instance(c, f, Some(Func::SerializeFmuState), |inst| {
        if FMUstate.is_null() {
            return null_arg(inst, f, "FMUstate");
        }
        // SAFETY: FMI contract: serializedState holds `size` bytes.
        let Some(bytes) = (unsafe { slice(serializedState.cast::<u8>(), size) }) else {
            return null_arg(inst, f, "serializedState");
        };
        if let Err(e) = inst.check_state(bytes) {
            return inst.refuse(f, &e.to_string());
        }
        // SAFETY: FMUstate is a valid out-pointer (the importer's variable).
        let existing = unsafe { *FMUstate };
        if let Err(why) = check_live_state(existing, true) {
            return inst.refuse(f, &why);
        }
        // SAFETY: `existing` is NULL or a live state (checked), FMUstate a valid out-pointer.
        unsafe { store_state(FMUstate, existing, bytes.to_vec()) };
        fmi2OK
    })
}

/// The FMI 2.0 function `fmi2GetDirectionalDerivative`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2GetDirectionalDerivative(
    c: fmi2Component,
    _vUnknown_ref: *const fmi2ValueReference,
    _nUnknown: usize,
    _vKnown_ref: *const fmi2ValueReference,
    _nKnown: usize,
    _dvKnown: *const fmi2Real,
    _dvUnknown: *mut fmi2Real,
) -> fmi2Status {
    let f = "fmi2GetDirectionalDerivative";
    with_instance(c, f, Some(Func::GetDirectionalDerivative), |inst| {
        inst.refuse(f, "not provided (providesDirectionalDerivative=\"false\")")
    })
}

/// The FMI 2.0 function `fmi2SetRealInputDerivatives`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2SetRealInputDerivatives(
    c: fmi2Component,
    _vr: *const fmi2ValueReference,
    _nvr: usize,
    _order: *const fmi2Integer,
    _value: *const fmi2Real,
) -> fmi2Status {
    let f = "fmi2SetRealInputDerivatives";
    with_instance(c, f, Some(Func::SetRealInputDerivatives), |inst| {
        inst.refuse(
            f,
            "inputs are held constant over a step (canInterpolateInputs=\"false\")",
        )
    })
}

/// The FMI 2.0 function `fmi2GetRealOutputDerivatives`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2GetRealOutputDerivatives(
    c: fmi2Component,
    vr: *const fmi2ValueReference,
    nvr: usize,
    order: *const fmi2Integer,
    value: *mut fmi2Real,
) -> fmi2Status {
    let f = "fmi2GetRealOutputDerivatives";
    with_instance(c, f, Some(Func::GetRealOutputDerivatives), |inst| {
        // SAFETY: FMI contract: vr, order and value hold nvr elements.
        let (Some(vrs), Some(orders), Some(out)) = (
            unsafe { slice(vr, nvr) },
            unsafe { slice(order, nvr) },
            unsafe { slice_mut(value, nvr) },
        ) else {
            return null_arg(inst, f, "vr, order or value");
        };
        inst.get_real_output_derivatives(vrs, orders, out)
    })
}

/// The FMI 2.0 function `fmi2DoStep`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2DoStep(
    c: fmi2Component,
    currentCommunicationPoint: fmi2Real,
    communicationStepSize: fmi2Real,
    _noSetFMUStatePriorToCurrentPoint: fmi2Boolean,
) -> fmi2Status {
    if c.is_null() {
        return fmi2Error;
    }
    // The instance checks the call sequence itself and catches its own panics
    // ([`FmiInstance`]).
    // SAFETY: a non-NULL component (see `component`).
    unsafe { component(c) }.do_step(currentCommunicationPoint, communicationStepSize)
}

/// The FMI 2.0 function `fmi2CancelStep`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2CancelStep(c: fmi2Component) -> fmi2Status {
    // Allowed only while a step is in progress, which never happens: the sequence check
    // answers fmi2Error with the reason.
    with_instance(c, "fmi2CancelStep", Some(Func::CancelStep), |_| fmi2Error)
}

fn status_kind_name(s: c_int) -> String {
    match s {
        0 => "fmi2DoStepStatus".into(),
        1 => "fmi2PendingStatus".into(),
        2 => "fmi2LastSuccessfulTime".into(),
        3 => "fmi2Terminated".into(),
        other => format!("status kind {other}"),
    }
}

fn discard_kind(inst: &dyn FmiInstance, function: &str, s: c_int) -> fmi2Status {
    inst.logger().log(
        fmi2Discard,
        Category::Discard,
        &format!(
            "{function}: {} is not available here (steps are synchronous)",
            status_kind_name(s)
        ),
    );
    fmi2Discard
}

/// The FMI 2.0 function `fmi2GetStatus`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2GetStatus(
    c: fmi2Component,
    s: c_int,
    value: *mut fmi2Status,
) -> fmi2Status {
    let f = "fmi2GetStatus";
    with_instance(c, f, Some(Func::GetStatus), |inst| {
        if value.is_null() {
            return null_arg(inst, f, "value");
        }
        discard_kind(inst, f, s)
    })
}

/// The FMI 2.0 function `fmi2GetRealStatus`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2GetRealStatus(
    c: fmi2Component,
    s: c_int,
    value: *mut fmi2Real,
) -> fmi2Status {
    let f = "fmi2GetRealStatus";
    with_instance(c, f, Some(Func::GetStatus), |inst| {
        if value.is_null() {
            return null_arg(inst, f, "value");
        }
        if s == fmi2StatusKind::fmi2LastSuccessfulTime as c_int {
            // SAFETY: non-NULL out-pointer.
            unsafe { *value = inst.last_successful_time() };
            fmi2OK
        } else {
            discard_kind(inst, f, s)
        }
    })
}

/// The FMI 2.0 function `fmi2GetIntegerStatus`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2GetIntegerStatus(
    c: fmi2Component,
    s: c_int,
    value: *mut fmi2Integer,
) -> fmi2Status {
    let f = "fmi2GetIntegerStatus";
    with_instance(c, f, Some(Func::GetStatus), |inst| {
        if value.is_null() {
            return null_arg(inst, f, "value");
        }
        discard_kind(inst, f, s)
    })
}

/// The FMI 2.0 function `fmi2GetBooleanStatus`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2GetBooleanStatus(
    c: fmi2Component,
    s: c_int,
    value: *mut fmi2Boolean,
) -> fmi2Status {
    let f = "fmi2GetBooleanStatus";
    with_instance(c, f, Some(Func::GetStatus), |inst| {
        if value.is_null() {
            return null_arg(inst, f, "value");
        }
        if s == fmi2StatusKind::fmi2Terminated as c_int {
            // SAFETY: non-NULL out-pointer.
            unsafe { *value = fmi2Boolean::from(inst.terminated()) };
            fmi2OK
        } else {
            discard_kind(inst, f, s)
        }
    })
}

/// The FMI 2.0 function `fmi2GetStringStatus`: see the module documentation.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn fmi2GetStringStatus(
    c: fmi2Component,
    s: c_int,
    value: *mut fmi2String,
) -> fmi2Status {
    let f = "fmi2GetStringStatus";
    with_instance(c, f, Some(Func::GetStatus), |inst| {
        if value.is_null() {
            return null_arg(inst, f, "value");
        }
        discard_kind(inst, f, s)
    })
}

// The catalog the packager reads (not part of FMI; harmless extra symbols).

/// Number of models this binary serves.
#[unsafe(no_mangle)]
pub extern "C" fn kneebench_model_count() -> usize {
    crate::MODELS.len()
}

/// A generated file of model `index`: 0 identifier, 1 modelDescription.xml,
/// 2 documentation/index.html, 3 reference-run inputs CSV (NULL if none). NULL when out of
/// range. The strings live as long as the library is loaded.
#[unsafe(no_mangle)]
pub extern "C" fn kneebench_model_file(index: usize, kind: c_int) -> *const c_char {
    catch_unwind(|| catalog_file(index, kind)).unwrap_or(std::ptr::null())
}

fn catalog_file(index: usize, kind: c_int) -> *const c_char {
    use std::ffi::CString;
    static FILES: crate::release::Once<Vec<[Option<CString>; 4]>> = crate::release::Once::new();
    let files = FILES.get_or_init(|| {
        crate::MODELS
            .iter()
            .map(|m| {
                let info = m.info();
                let c = |s: &str| CString::new(s).ok();
                [
                    c(m.identifier),
                    c(&info.xml),
                    c(info.documentation()),
                    (m.reference_inputs)().and_then(|s| c(&s)),
                ]
            })
            .collect()
    });
    files
        .get(index)
        .and_then(|f| usize::try_from(kind).ok().and_then(|k| f.get(k)))
        .and_then(|s| s.as_ref())
        .map_or(std::ptr::null(), |s| s.as_ptr())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_model_beside_the_resources_is_read_from_any_form_of_their_uri() {
        let d = tempfile::tempdir().unwrap();
        let fmu = d.path().join("an fmu");
        std::fs::create_dir_all(fmu.join("resources")).unwrap();
        std::fs::write(
            fmu.join("modelDescription.xml"),
            "<?xml version=\"1.0\"?>\n<fmiModelDescription fmiVersion=\"2.0\" modelName=\"M\" \
             guid=\"{g}\">\n  <CoSimulation modelIdentifier=\"PidController\" \
             canHandleVariableCommunicationStepSize=\"true\"/>\n</fmiModelDescription>",
        )
        .unwrap();
        let path = fmu.join("resources").display().to_string();
        let encoded = path.replace(' ', "%20");
        for uri in [
            format!("file://{encoded}"),
            format!("file://localhost{encoded}/"),
            format!("file:{encoded}"),
        ] {
            let c = std::ffi::CString::new(uri.clone()).unwrap();
            assert_eq!(
                identifier_beside(c.as_ptr()).as_deref(),
                Some("PidController"),
                "{uri}"
            );
        }
        for bad in [
            "relative/resources",
            "http://x/resources",
            "file://%zz/resources",
        ] {
            let c = std::ffi::CString::new(bad).unwrap();
            assert_eq!(identifier_beside(c.as_ptr()), None, "{bad}");
        }
        assert_eq!(identifier_beside(std::ptr::null()), None);
        // No model description there: no hint.
        let c = std::ffi::CString::new(format!("file://{}", d.path().display())).unwrap();
        assert_eq!(identifier_beside(c.as_ptr()), None);
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn the_loader_names_the_object_this_code_runs_from() {
        // In a unit test the code is linked into the test executable itself.
        let path = loaded_from().expect("dladdr answers for our own function");
        let here = std::env::current_exe().unwrap();
        assert_eq!(
            std::fs::canonicalize(&path).unwrap(),
            std::fs::canonicalize(&here).unwrap()
        );
        assert_eq!(
            library_stem(),
            here.file_stem().and_then(|s| s.to_str()),
            "{path}"
        );
    }
}
