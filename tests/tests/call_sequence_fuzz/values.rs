//! The calls with a NULL component and the values of a set, resolved against the variable.

use std::ffi::CString;
use std::ptr::{null, null_mut};

use kneebench_tests::*;

use fmi2Status::{fmi2Error, fmi2OK};

use crate::calls::Value;
use crate::library::Var;

/// How many functions [`null_component_call`] calls.
pub(crate) const NULL_COMPONENT_CALLS: usize = 33;

/// Function number `k` with a NULL component (or, for `fmi2Instantiate`, NULL arguments):
/// `fmi2Error` (`fmi2FreeInstance` returns nothing: answered as `fmi2Error`; an instantiation
/// with a NULL GUID, name or callbacks must return NULL).
///
/// # Safety
/// `f` is the binary's functions.
pub(crate) unsafe fn null_component_call(f: &Raw, k: usize, guid: &str) -> fmi2StatusCode {
    let n: fmi2Component = null_mut();
    let vr = [1u32];
    let mut real = [0.0];
    let mut int = [0];
    let mut string: [fmi2String; 1] = [null()];
    let mut state: fmi2FMUstate = null_mut();
    let mut size = 0usize;
    let mut st = fmi2OK;
    let guid = cstr(guid);
    let callbacks = fmi2CallbackFunctions {
        logger: None,
        allocateMemory: None,
        freeMemory: None,
        stepFinished: None,
        componentEnvironment: null_mut(),
    };
    // SAFETY: every argument is valid or deliberately NULL; the component is NULL.
    unsafe {
        match k {
            0 => (f.set_debug_logging)(n, 1, 0, null()),
            1 => (f.setup_experiment)(n, 0, 0.0, 0.0, 0, 0.0),
            2 => (f.enter_initialization_mode)(n),
            3 => (f.exit_initialization_mode)(n),
            4 => (f.terminate)(n),
            5 => (f.reset)(n),
            6 => (f.get_real)(n, vr.as_ptr(), 1, real.as_mut_ptr()),
            7 => (f.get_integer)(n, vr.as_ptr(), 1, int.as_mut_ptr()),
            8 => (f.get_boolean)(n, vr.as_ptr(), 1, int.as_mut_ptr()),
            9 => (f.get_string)(n, vr.as_ptr(), 1, string.as_mut_ptr()),
            10 => (f.set_real)(n, vr.as_ptr(), 1, real.as_ptr()),
            11 => (f.set_integer)(n, vr.as_ptr(), 1, int.as_ptr()),
            12 => (f.set_boolean)(n, vr.as_ptr(), 1, int.as_ptr()),
            13 => (f.set_string)(n, vr.as_ptr(), 1, [c"x".as_ptr()].as_ptr()),
            14 => (f.get_fmu_state)(n, &mut state),
            15 => (f.set_fmu_state)(n, null_mut()),
            16 => (f.free_fmu_state)(n, &mut state),
            17 => (f.serialized_size)(n, null_mut(), &mut size),
            18 => (f.serialize)(n, null_mut(), null_mut(), 0),
            19 => (f.deserialize)(n, null(), 0, &mut state),
            20 => {
                (f.get_real_output_derivatives)(n, vr.as_ptr(), 1, [1].as_ptr(), real.as_mut_ptr())
            }
            21 => (f.set_real_input_derivatives)(n, vr.as_ptr(), 1, [1].as_ptr(), real.as_ptr()),
            22 => (f.get_directional_derivative)(
                n,
                vr.as_ptr(),
                1,
                vr.as_ptr(),
                1,
                real.as_ptr(),
                real.as_mut_ptr(),
            ),
            23 => (f.do_step)(n, 0.0, 1e-3, fmi2True),
            24 => (f.cancel_step)(n),
            25 => (f.get_status)(n, 0, &mut st),
            26 => (f.get_real_status)(n, 2, real.as_mut_ptr()),
            27 => (f.get_integer_status)(n, 0, int.as_mut_ptr()),
            28 => (f.get_boolean_status)(n, 3, int.as_mut_ptr()),
            29 => (f.get_string_status)(n, 0, string.as_mut_ptr()),
            30 => {
                (f.free_instance)(n);
                fmi2Error.into()
            }
            31 => {
                let c = (f.instantiate)(c"x".as_ptr(), 1, guid.as_ptr(), null(), null(), 0, 0);
                assert!(c.is_null(), "an instantiation with NULL callbacks");
                let c = (f.instantiate)(c"x".as_ptr(), 1, null(), null(), &callbacks, 0, 0);
                assert!(c.is_null(), "an instantiation with a NULL GUID");
                let c = (f.instantiate)(null(), 1, guid.as_ptr(), null(), &callbacks, 0, 0);
                assert!(c.is_null(), "an instantiation with a NULL instance name");
                fmi2Error.into()
            }
            _ => {
                let c = (f.instantiate)(c"x".as_ptr(), 0, guid.as_ptr(), null(), &callbacks, 0, 0);
                assert!(c.is_null(), "a model-exchange instantiation");
                fmi2Error.into()
            }
        }
    }
}

/// A Real value for `var` (or for an unknown reference).
pub(crate) fn real_value(var: Option<&Var>, value: Value) -> f64 {
    let (start, min, max) = var.map_or((0.5, None, None), |v| (v.start_real, v.min, v.max));
    match value {
        Value::Start => start,
        Value::Min => min.unwrap_or(-1e3),
        Value::Max => max.unwrap_or(1e3),
        Value::Mid => match (min, max) {
            (Some(lo), Some(hi)) => lo + (hi - lo) / 2.0,
            _ => start,
        },
        Value::BelowMin => min.map_or(-1e6, |lo| lo - lo.abs().max(1.0)),
        Value::AboveMax => max.map_or(1e6, |hi| hi + hi.abs().max(1.0)),
        Value::Fraction => start + 0.5,
        Value::Nan => f64::NAN,
        Value::Inf => f64::INFINITY,
        Value::NegInf => f64::NEG_INFINITY,
        Value::Huge => 1e300,
        Value::NegHuge => -1e300,
        Value::Zero => 0.0,
        Value::One => 1.0,
        Value::Tiny => 5e-324,
    }
}

/// An Integer value for `var` (or for an unknown reference).
pub(crate) fn integer_value(var: Option<&Var>, value: Value) -> i32 {
    let (start, min, max) = var.map_or((1, None, None), |v| {
        (
            v.start_real as i32,
            v.min.map(|x| x as i32),
            v.max.map(|x| x as i32),
        )
    });
    match value {
        Value::Start => start,
        Value::Min => min.unwrap_or(i32::MIN),
        Value::Max => max.unwrap_or(i32::MAX),
        Value::Mid => match (min, max) {
            (Some(lo), Some(hi)) => lo + (hi - lo) / 2,
            _ => start,
        },
        Value::BelowMin => min.map_or(-1000, |lo| lo.saturating_sub(1)),
        Value::AboveMax => max.map_or(1000, |hi| hi.saturating_add(1)),
        Value::Fraction => start.saturating_add(1),
        Value::Nan | Value::NegHuge => i32::MIN,
        Value::Inf | Value::Huge => i32::MAX,
        Value::NegInf => -1,
        Value::Zero => 0,
        Value::One => 1,
        Value::Tiny => 2,
    }
}

/// A Boolean value (any int: the standard's fmi2Boolean is a C int, non-zero is true).
pub(crate) fn boolean_value(var: Option<&Var>, value: Value) -> fmi2Boolean {
    match value {
        Value::Start => var.map_or(0, |v| v.start_real as fmi2Boolean),
        Value::Zero | Value::Min | Value::BelowMin => 0,
        Value::One | Value::Max | Value::Mid => 1,
        Value::Nan | Value::Tiny => 2,
        Value::NegInf | Value::NegHuge => -1,
        Value::Inf | Value::Huge | Value::AboveMax | Value::Fraction => fmi2Boolean::MAX,
    }
}

/// A String value: `None` stands for a NULL string; some are not UTF-8.
pub(crate) fn string_value(var: Option<&Var>, value: Value) -> Option<CString> {
    let text: Vec<u8> = match value {
        Value::Start => var
            .map_or(String::new(), |v| v.start_string.clone())
            .into_bytes(),
        Value::Zero => Vec::new(),
        Value::Inf => return None,
        Value::Nan => vec![0xff, 0xfe, b'x'],
        Value::Huge => vec![b'a'; 10_000],
        Value::Fraction => b"127.0.0.1:1".to_vec(),
        _ => b"x".to_vec(),
    };
    Some(CString::new(text).unwrap())
}
