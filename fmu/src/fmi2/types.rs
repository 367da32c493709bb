//! The FMI 2.0 C types, written by hand.
//!
//! FMI 2.0 is frozen, so these ~40 declarations never change; writing them by hand avoids a
//! bindgen/libclang build dependency. A test in `tests/` compiles a C file against the official
//! headers shipped with fmpy and checks every exported symbol against the header's
//! function-pointer typedefs, so a mistake here fails the suite.
//!
//! This file is the only copy: the harness includes it with `#[path]` so that it can call FMUs
//! without linking the models.

#![allow(
    non_camel_case_types,
    non_snake_case,
    non_upper_case_globals,
    dead_code
)]

use std::ffi::{c_char, c_int, c_uint, c_void};

/// `fmi2Component`: the instance pointer handed to the importer.
pub type fmi2Component = *mut c_void;
/// `fmi2ComponentEnvironment`: the importer's context pointer, passed back to callbacks.
pub type fmi2ComponentEnvironment = *mut c_void;
/// `fmi2FMUstate`: an opaque saved state.
pub type fmi2FMUstate = *mut c_void;
/// `fmi2ValueReference`.
pub type fmi2ValueReference = c_uint;
/// `fmi2Real`.
pub type fmi2Real = f64;
/// `fmi2Integer`.
pub type fmi2Integer = c_int;
/// `fmi2Boolean`: a C int, 0 or 1.
pub type fmi2Boolean = c_int;
/// `fmi2Char`.
pub type fmi2Char = c_char;
/// `fmi2String`.
pub type fmi2String = *const fmi2Char;
/// `fmi2Byte`.
pub type fmi2Byte = c_char;

/// `fmi2True`.
pub const fmi2True: fmi2Boolean = 1;
/// `fmi2False`.
pub const fmi2False: fmi2Boolean = 0;

/// `fmi2Status`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum fmi2Status {
    /// All well.
    fmi2OK = 0,
    /// Something is not right, but the computation can continue.
    fmi2Warning = 1,
    /// The step was not done; the master may retry or stop.
    fmi2Discard = 2,
    /// The instance is in error; only free/reset/get-status calls are allowed.
    fmi2Error = 3,
    /// The instance is unusable; only free is allowed.
    fmi2Fatal = 4,
    /// Asynchronous step still running.
    fmi2Pending = 5,
}

/// An `fmi2Status` as an importer receives it from an FMU: a C int that a foreign (or broken)
/// FMU may set to any value, so it is not read as the Rust enum (an out-of-range enum value is
/// undefined behaviour). [`fmi2StatusCode::status`] names it when it is a valid status. The
/// importer function types below return it.
#[repr(transparent)]
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct fmi2StatusCode(pub c_int);

impl fmi2StatusCode {
    /// The status, or `None` for a value outside the enumeration.
    pub fn status(self) -> Option<fmi2Status> {
        Some(match self.0 {
            0 => fmi2Status::fmi2OK,
            1 => fmi2Status::fmi2Warning,
            2 => fmi2Status::fmi2Discard,
            3 => fmi2Status::fmi2Error,
            4 => fmi2Status::fmi2Fatal,
            5 => fmi2Status::fmi2Pending,
            _ => return None,
        })
    }
}

impl From<fmi2Status> for fmi2StatusCode {
    fn from(s: fmi2Status) -> Self {
        fmi2StatusCode(s as c_int)
    }
}

impl PartialEq<fmi2Status> for fmi2StatusCode {
    fn eq(&self, other: &fmi2Status) -> bool {
        self.0 == *other as c_int
    }
}

impl PartialEq<fmi2StatusCode> for fmi2Status {
    fn eq(&self, other: &fmi2StatusCode) -> bool {
        *self as c_int == other.0
    }
}

impl std::fmt::Debug for fmi2StatusCode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.status() {
            Some(s) => write!(f, "{s:?}"),
            None => write!(f, "invalid fmi2Status {}", self.0),
        }
    }
}

/// `fmi2Type`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum fmi2Type {
    /// Model exchange.
    fmi2ModelExchange = 0,
    /// Co-simulation.
    fmi2CoSimulation = 1,
}

/// `fmi2StatusKind`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum fmi2StatusKind {
    /// Status of an asynchronous `fmi2DoStep`.
    fmi2DoStepStatus = 0,
    /// Description of a pending step.
    fmi2PendingStatus = 1,
    /// Last time at which a step succeeded.
    fmi2LastSuccessfulTime = 2,
    /// Whether the slave wants the simulation to end.
    fmi2Terminated = 3,
}

/// `fmi2CallbackLogger`: printf-style and variadic. Callers always pass `"%s"` and the message.
pub type fmi2CallbackLogger = Option<
    unsafe extern "C" fn(
        componentEnvironment: fmi2ComponentEnvironment,
        instanceName: fmi2String,
        status: fmi2Status,
        category: fmi2String,
        message: fmi2String,
        ...
    ),
>;
/// `fmi2CallbackAllocateMemory`.
pub type fmi2CallbackAllocateMemory =
    Option<unsafe extern "C" fn(nobj: usize, size: usize) -> *mut c_void>;
/// `fmi2CallbackFreeMemory`.
pub type fmi2CallbackFreeMemory = Option<unsafe extern "C" fn(obj: *mut c_void)>;
/// `fmi2StepFinished`.
pub type fmi2StepFinished = Option<
    unsafe extern "C" fn(componentEnvironment: fmi2ComponentEnvironment, status: fmi2Status),
>;

/// `fmi2CallbackFunctions`.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct fmi2CallbackFunctions {
    /// Logger (required by the standard; kneebench tolerates NULL and stays silent).
    pub logger: fmi2CallbackLogger,
    /// Allocator (unused: `canNotUseMemoryManagementFunctions="true"`).
    pub allocateMemory: fmi2CallbackAllocateMemory,
    /// Deallocator (unused).
    pub freeMemory: fmi2CallbackFreeMemory,
    /// Asynchronous step callback (unused: no asynchronous stepping).
    pub stepFinished: fmi2StepFinished,
    /// Passed back as the first argument of every callback.
    pub componentEnvironment: fmi2ComponentEnvironment,
}

/// `fmi2EventInfo` (model exchange; declared for completeness of the header).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default)]
pub struct fmi2EventInfo {
    /// `newDiscreteStatesNeeded`.
    pub newDiscreteStatesNeeded: fmi2Boolean,
    /// `terminateSimulation`.
    pub terminateSimulation: fmi2Boolean,
    /// `nominalsOfContinuousStatesChanged`.
    pub nominalsOfContinuousStatesChanged: fmi2Boolean,
    /// `valuesOfContinuousStatesChanged`.
    pub valuesOfContinuousStatesChanged: fmi2Boolean,
    /// `nextEventTimeDefined`.
    pub nextEventTimeDefined: fmi2Boolean,
    /// `nextEventTime`.
    pub nextEventTime: fmi2Real,
}

/// The string `fmi2GetTypesPlatform` returns.
pub const fmi2TypesPlatform: &std::ffi::CStr = c"default";
/// The string `fmi2GetVersion` returns.
pub const fmi2Version: &std::ffi::CStr = c"2.0";

// Function-pointer types of the common and co-simulation API (the header's `fmi2...TYPE`s).

/// `fmi2GetTypesPlatformTYPE`.
pub type fmi2GetTypesPlatformTYPE = unsafe extern "C" fn() -> *const c_char;
/// `fmi2GetVersionTYPE`.
pub type fmi2GetVersionTYPE = unsafe extern "C" fn() -> *const c_char;
/// `fmi2SetDebugLoggingTYPE`.
pub type fmi2SetDebugLoggingTYPE =
    unsafe extern "C" fn(fmi2Component, fmi2Boolean, usize, *const fmi2String) -> fmi2StatusCode;
/// `fmi2InstantiateTYPE`.
pub type fmi2InstantiateTYPE = unsafe extern "C" fn(
    fmi2String,
    fmi2Type,
    fmi2String,
    fmi2String,
    *const fmi2CallbackFunctions,
    fmi2Boolean,
    fmi2Boolean,
) -> fmi2Component;
/// `fmi2FreeInstanceTYPE`.
pub type fmi2FreeInstanceTYPE = unsafe extern "C" fn(fmi2Component);
/// `fmi2SetupExperimentTYPE`.
pub type fmi2SetupExperimentTYPE = unsafe extern "C" fn(
    fmi2Component,
    fmi2Boolean,
    fmi2Real,
    fmi2Real,
    fmi2Boolean,
    fmi2Real,
) -> fmi2StatusCode;
/// `fmi2EnterInitializationModeTYPE`, `fmi2ExitInitializationModeTYPE`, `fmi2TerminateTYPE`,
/// `fmi2ResetTYPE` and `fmi2CancelStepTYPE` share this shape.
pub type fmi2ComponentOnlyTYPE = unsafe extern "C" fn(fmi2Component) -> fmi2StatusCode;
/// `fmi2GetRealTYPE`.
pub type fmi2GetRealTYPE = unsafe extern "C" fn(
    fmi2Component,
    *const fmi2ValueReference,
    usize,
    *mut fmi2Real,
) -> fmi2StatusCode;
/// `fmi2GetIntegerTYPE`.
pub type fmi2GetIntegerTYPE = unsafe extern "C" fn(
    fmi2Component,
    *const fmi2ValueReference,
    usize,
    *mut fmi2Integer,
) -> fmi2StatusCode;
/// `fmi2GetBooleanTYPE`.
pub type fmi2GetBooleanTYPE = unsafe extern "C" fn(
    fmi2Component,
    *const fmi2ValueReference,
    usize,
    *mut fmi2Boolean,
) -> fmi2StatusCode;
/// `fmi2GetStringTYPE`.
pub type fmi2GetStringTYPE = unsafe extern "C" fn(
    fmi2Component,
    *const fmi2ValueReference,
    usize,
    *mut fmi2String,
) -> fmi2StatusCode;
/// `fmi2SetRealTYPE`.
pub type fmi2SetRealTYPE = unsafe extern "C" fn(
    fmi2Component,
    *const fmi2ValueReference,
    usize,
    *const fmi2Real,
) -> fmi2StatusCode;
/// `fmi2SetIntegerTYPE`.
pub type fmi2SetIntegerTYPE = unsafe extern "C" fn(
    fmi2Component,
    *const fmi2ValueReference,
    usize,
    *const fmi2Integer,
) -> fmi2StatusCode;
/// `fmi2SetBooleanTYPE`.
pub type fmi2SetBooleanTYPE = unsafe extern "C" fn(
    fmi2Component,
    *const fmi2ValueReference,
    usize,
    *const fmi2Boolean,
) -> fmi2StatusCode;
/// `fmi2SetStringTYPE`.
pub type fmi2SetStringTYPE = unsafe extern "C" fn(
    fmi2Component,
    *const fmi2ValueReference,
    usize,
    *const fmi2String,
) -> fmi2StatusCode;
/// `fmi2GetFMUstateTYPE` and `fmi2FreeFMUstateTYPE`.
pub type fmi2GetFMUstateTYPE =
    unsafe extern "C" fn(fmi2Component, *mut fmi2FMUstate) -> fmi2StatusCode;
/// `fmi2SetFMUstateTYPE`.
pub type fmi2SetFMUstateTYPE = unsafe extern "C" fn(fmi2Component, fmi2FMUstate) -> fmi2StatusCode;
/// `fmi2SerializedFMUstateSizeTYPE`.
pub type fmi2SerializedFMUstateSizeTYPE =
    unsafe extern "C" fn(fmi2Component, fmi2FMUstate, *mut usize) -> fmi2StatusCode;
/// `fmi2SerializeFMUstateTYPE`.
pub type fmi2SerializeFMUstateTYPE =
    unsafe extern "C" fn(fmi2Component, fmi2FMUstate, *mut fmi2Byte, usize) -> fmi2StatusCode;
/// `fmi2DeSerializeFMUstateTYPE`.
pub type fmi2DeSerializeFMUstateTYPE = unsafe extern "C" fn(
    fmi2Component,
    *const fmi2Byte,
    usize,
    *mut fmi2FMUstate,
) -> fmi2StatusCode;
/// `fmi2GetDirectionalDerivativeTYPE`.
pub type fmi2GetDirectionalDerivativeTYPE = unsafe extern "C" fn(
    fmi2Component,
    *const fmi2ValueReference,
    usize,
    *const fmi2ValueReference,
    usize,
    *const fmi2Real,
    *mut fmi2Real,
) -> fmi2StatusCode;
/// `fmi2SetRealInputDerivativesTYPE`.
pub type fmi2SetRealInputDerivativesTYPE = unsafe extern "C" fn(
    fmi2Component,
    *const fmi2ValueReference,
    usize,
    *const fmi2Integer,
    *const fmi2Real,
) -> fmi2StatusCode;
/// `fmi2GetRealOutputDerivativesTYPE`.
pub type fmi2GetRealOutputDerivativesTYPE = unsafe extern "C" fn(
    fmi2Component,
    *const fmi2ValueReference,
    usize,
    *const fmi2Integer,
    *mut fmi2Real,
) -> fmi2StatusCode;
/// `fmi2DoStepTYPE`.
pub type fmi2DoStepTYPE =
    unsafe extern "C" fn(fmi2Component, fmi2Real, fmi2Real, fmi2Boolean) -> fmi2StatusCode;
/// `fmi2GetStatusTYPE`.
pub type fmi2GetStatusTYPE =
    unsafe extern "C" fn(fmi2Component, fmi2StatusKind, *mut fmi2StatusCode) -> fmi2StatusCode;
/// `fmi2GetRealStatusTYPE`.
pub type fmi2GetRealStatusTYPE =
    unsafe extern "C" fn(fmi2Component, fmi2StatusKind, *mut fmi2Real) -> fmi2StatusCode;
/// `fmi2GetIntegerStatusTYPE`.
pub type fmi2GetIntegerStatusTYPE =
    unsafe extern "C" fn(fmi2Component, fmi2StatusKind, *mut fmi2Integer) -> fmi2StatusCode;
/// `fmi2GetBooleanStatusTYPE`.
pub type fmi2GetBooleanStatusTYPE =
    unsafe extern "C" fn(fmi2Component, fmi2StatusKind, *mut fmi2Boolean) -> fmi2StatusCode;
/// `fmi2GetStringStatusTYPE`.
pub type fmi2GetStringStatusTYPE =
    unsafe extern "C" fn(fmi2Component, fmi2StatusKind, *mut fmi2String) -> fmi2StatusCode;

#[cfg(test)]
mod status_code_tests {
    use super::*;

    #[test]
    fn status_codes_outside_the_enumeration_are_named_not_transmuted() {
        for s in [
            fmi2Status::fmi2OK,
            fmi2Status::fmi2Warning,
            fmi2Status::fmi2Discard,
            fmi2Status::fmi2Error,
            fmi2Status::fmi2Fatal,
            fmi2Status::fmi2Pending,
        ] {
            let code = fmi2StatusCode::from(s);
            assert_eq!(code.status(), Some(s));
            assert_eq!(code, s);
            assert_eq!(s, code);
        }
        for raw in [-1, 6, 42, c_int::MAX] {
            let code = fmi2StatusCode(raw);
            assert_eq!(code.status(), None);
            assert_ne!(code, fmi2Status::fmi2OK);
            assert_eq!(format!("{code:?}"), format!("invalid fmi2Status {raw}"));
        }
        assert_eq!(format!("{:?}", fmi2StatusCode(2)), "fmi2Discard");
    }
}
