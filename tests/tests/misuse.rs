//! Misuse of the C API: every answer is the documented status with a log line, never a crash,
//! and a refused call changes nothing.

use std::ffi::c_int;
use std::ptr::{null, null_mut};

use kneebench_tests::*;

use fmi2Status::{fmi2Discard, fmi2Error, fmi2OK};

const ANGLE: u32 = 100;
const PERIOD: u32 = 1;
const AMPLITUDE: u32 = 2;
const MOTION_WAVEFORM: u32 = 7;
const HARMONICS: u32 = 200;
const STANCE: u32 = 106;

fn gait() -> String {
    guid_of("GaitReference")
}

fn raw() -> Raw {
    Raw::load(&fmu_library())
}

/// The co-simulation states of the standard's call-sequence table that GaitReference reaches.
#[derive(Debug, Clone, Copy, PartialEq)]
enum S {
    Instantiated,
    Initialization,
    StepComplete,
    StepFailed,
    Terminated,
}

/// Drives a new instance into state `s`.
fn instance_in<'a>(f: &'a Raw, s: S) -> RawInstance<'a> {
    let mut i = RawInstance::new(f, "seq", &gait());
    assert!(!i.c.is_null());
    // SAFETY: valid component; arrays of the right size.
    unsafe {
        match s {
            S::Instantiated => {}
            S::Initialization => {
                assert_eq!((f.setup_experiment)(i.c, 0, 0.0, 0.0, 0, 0.0), fmi2OK);
                assert_eq!((f.enter_initialization_mode)(i.c), fmi2OK);
            }
            S::StepComplete => i.initialize(0.0, None),
            S::StepFailed => {
                // A stepped sine that ends at t = 1: the step over it is discarded.
                let vrs = [MOTION_WAVEFORM];
                assert_eq!((f.set_integer)(i.c, vrs.as_ptr(), 1, [7].as_ptr()), fmi2OK);
                let vrs = [11, 12, 13, 14];
                let vals = [1.0, 2.0, 1.0, 1.5];
                assert_eq!((f.set_real)(i.c, vrs.as_ptr(), 4, vals.as_ptr()), fmi2OK);
                i.initialize(0.0, None);
                assert_eq!(i.step(0.0, 2.0), fmi2Discard, "{}", i.log_text());
            }
            S::Terminated => {
                i.initialize(0.0, None);
                assert_eq!((f.terminate)(i.c), fmi2OK);
            }
        }
    }
    i.log.clear();
    i
}

/// One call of a function in the table, with valid arguments.
fn call(i: &mut RawInstance, name: &str) -> fmi2StatusCode {
    let f = i.f;
    let c = i.c;
    let vr = [PERIOD];
    let out_vr = [ANGLE];
    let mut real = [0.0];
    // SAFETY: valid component and arrays; the state pointer is freed when made.
    unsafe {
        match name {
            "fmi2SetupExperiment" => (f.setup_experiment)(c, 0, 0.0, 0.0, 0, 0.0),
            "fmi2EnterInitializationMode" => (f.enter_initialization_mode)(c),
            "fmi2ExitInitializationMode" => (f.exit_initialization_mode)(c),
            "fmi2Terminate" => (f.terminate)(c),
            "fmi2Reset" => (f.reset)(c),
            "fmi2GetReal" => (f.get_real)(c, vr.as_ptr(), 1, real.as_mut_ptr()),
            "fmi2SetReal" => (f.set_real)(c, vr.as_ptr(), 1, [2.0].as_ptr()),
            "fmi2GetInteger" => (f.get_integer)(c, [HARMONICS].as_ptr(), 1, [0].as_mut_ptr()),
            "fmi2SetInteger" => (f.set_integer)(c, [MOTION_WAVEFORM].as_ptr(), 1, [1].as_ptr()),
            "fmi2GetBoolean" => (f.get_boolean)(c, [STANCE].as_ptr(), 1, [0].as_mut_ptr()),
            // The gait has no settable Boolean or any String: in an allowed state these are
            // refused for the variable ("cannot be set", "unknown value reference"), never for
            // the state.
            "fmi2SetBoolean" => (f.set_boolean)(c, [STANCE].as_ptr(), 1, [0].as_ptr()),
            "fmi2GetString" => (f.get_string)(c, vr.as_ptr(), 1, [null()].as_mut_ptr()),
            "fmi2SetString" => (f.set_string)(c, vr.as_ptr(), 1, [c"x".as_ptr()].as_ptr()),
            "fmi2GetRealOutputDerivatives" => (f.get_real_output_derivatives)(
                c,
                out_vr.as_ptr(),
                1,
                [1].as_ptr(),
                real.as_mut_ptr(),
            ),
            "fmi2DoStep" => (f.do_step)(c, 0.0, 0.001, fmi2True),
            "fmi2CancelStep" => (f.cancel_step)(c),
            "fmi2GetBooleanStatus" => {
                let mut b = 0;
                (f.get_boolean_status)(c, fmi2StatusKind::fmi2Terminated as c_int, &mut b)
            }
            "fmi2GetFMUstate" => {
                let mut s = null_mut();
                let st = (f.get_fmu_state)(c, &mut s);
                if !s.is_null() {
                    (f.free_fmu_state)(c, &mut s);
                }
                st
            }
            "fmi2SetDebugLogging" => (f.set_debug_logging)(c, fmi2True, 0, null()),
            other => panic!("no call for {other}"),
        }
    }
}

#[test]
fn call_sequence_table_is_enforced() {
    use S::*;
    // The standard's table (FMI 2.0, section 4.2.4), written out independently of the code.
    let table: &[(&str, &[S])] = &[
        ("fmi2SetupExperiment", &[Instantiated]),
        ("fmi2EnterInitializationMode", &[Instantiated]),
        ("fmi2ExitInitializationMode", &[Initialization]),
        ("fmi2Terminate", &[StepComplete, StepFailed]),
        (
            "fmi2Reset",
            &[
                Instantiated,
                Initialization,
                StepComplete,
                StepFailed,
                Terminated,
            ],
        ),
        (
            "fmi2GetReal",
            &[Initialization, StepComplete, StepFailed, Terminated],
        ),
        ("fmi2SetReal", &[Instantiated, Initialization, StepComplete]),
        (
            "fmi2GetInteger",
            &[Initialization, StepComplete, StepFailed, Terminated],
        ),
        (
            "fmi2SetInteger",
            &[Instantiated, Initialization, StepComplete],
        ),
        (
            "fmi2GetBoolean",
            &[Initialization, StepComplete, StepFailed, Terminated],
        ),
        (
            "fmi2SetBoolean",
            &[Instantiated, Initialization, StepComplete],
        ),
        (
            "fmi2GetString",
            &[Initialization, StepComplete, StepFailed, Terminated],
        ),
        (
            "fmi2SetString",
            &[Instantiated, Initialization, StepComplete],
        ),
        (
            "fmi2GetRealOutputDerivatives",
            &[StepComplete, StepFailed, Terminated],
        ),
        ("fmi2DoStep", &[StepComplete]),
        ("fmi2CancelStep", &[]),
        (
            "fmi2GetBooleanStatus",
            &[StepComplete, StepFailed, Terminated],
        ),
        (
            "fmi2GetFMUstate",
            &[
                Instantiated,
                Initialization,
                StepComplete,
                StepFailed,
                Terminated,
            ],
        ),
        (
            "fmi2SetDebugLogging",
            &[
                Instantiated,
                Initialization,
                StepComplete,
                StepFailed,
                Terminated,
            ],
        ),
    ];
    let f = raw();
    let mut checked = 0;
    for (name, allowed) in table {
        for s in [
            Instantiated,
            Initialization,
            StepComplete,
            StepFailed,
            Terminated,
        ] {
            let mut i = instance_in(&f, s);
            let status = call(&mut i, name);
            let log = i.log_text();
            if allowed.contains(&s) {
                assert_ne!(
                    (status, log.contains("not allowed in state")),
                    (fmi2Error.into(), true),
                    "{name} must be allowed in {s:?}: {log}"
                );
            } else {
                assert_eq!(status, fmi2Error, "{name} in {s:?} must be refused");
                assert!(
                    log.contains(name)
                        && log.contains("not allowed in state")
                        && log.contains("expected"),
                    "{name} in {s:?}: log must say expected vs actual: {log}"
                );
                checked += 1;
            }
        }
    }
    assert_eq!(checked, 40, "illegal calls checked");
}

#[test]
fn refused_call_leaves_the_instance_usable() {
    let f = raw();
    let mut i = RawInstance::new(&f, "usable", &gait());
    i.initialize(0.0, Some(1.0));
    // Not at the last communication point.
    assert_eq!(i.step(0.5, 0.1), fmi2Error);
    assert!(
        i.log_text().contains("not the last communication point"),
        "{}",
        i.log_text()
    );
    // Past the stop time.
    assert_eq!(i.step(0.0, 1.5), fmi2Error);
    assert!(i.log_text().contains("stopTime"), "{}", i.log_text());
    // Zero, negative and NaN step sizes.
    assert_eq!(i.step(0.0, 0.0), fmi2Error);
    assert_eq!(i.step(0.0, -0.1), fmi2Error);
    assert_eq!(i.step(0.0, f64::NAN), fmi2Error);
    // A communication point off by rounding (as importers send) is accepted, and the last
    // step may end exactly at the stop time.
    assert_eq!(i.step(0.0, 0.2), fmi2OK);
    assert_eq!(i.step(0.20000000000000107, 0.8), fmi2OK, "{}", i.log_text());
    assert_eq!(i.reals(&[ANGLE]).len(), 1);
}

#[test]
fn null_pointers_are_refused_without_a_crash() {
    let f = raw();
    // SAFETY: deliberately NULL arguments; the FMU must check them.
    unsafe {
        let n = null_mut();
        assert_eq!((f.do_step)(n, 0.0, 0.1, 1), fmi2Error);
        assert_eq!((f.get_real)(n, null(), 0, null_mut()), fmi2Error);
        assert_eq!((f.enter_initialization_mode)(n), fmi2Error);
        assert_eq!((f.reset)(n), fmi2Error);
        (f.free_instance)(n);
        let guid = cstr(&gait());
        // NULL callbacks.
        let c = (f.instantiate)(c"x".as_ptr(), 1, guid.as_ptr(), null(), null(), 0, 0);
        assert!(c.is_null());
        // NULL logger inside the callbacks: works, silently.
        let cb = fmi2CallbackFunctions {
            logger: None,
            allocateMemory: None,
            freeMemory: None,
            stepFinished: None,
            componentEnvironment: null_mut(),
        };
        let c = (f.instantiate)(c"x".as_ptr(), 1, guid.as_ptr(), null(), &cb, 0, 0);
        assert!(!c.is_null());
        assert_eq!(
            (f.do_step)(c, 0.0, 0.1, 1),
            fmi2Error,
            "out of sequence, no logger"
        );
        (f.free_instance)(c);
    }
    let mut i = RawInstance::new(&f, "nulls", &gait());
    i.initialize(0.0, None);
    // SAFETY: deliberately NULL arrays with a non-zero length.
    unsafe {
        let vr = [ANGLE];
        let mut v = [0.0];
        assert_eq!((f.get_real)(i.c, null(), 1, v.as_mut_ptr()), fmi2Error);
        assert_eq!((f.get_real)(i.c, vr.as_ptr(), 1, null_mut()), fmi2Error);
        assert_eq!((f.set_real)(i.c, null(), 1, null()), fmi2Error);
        assert_eq!((f.get_fmu_state)(i.c, null_mut()), fmi2Error);
        assert_eq!((f.set_fmu_state)(i.c, null_mut()), fmi2Error);
        assert_eq!((f.deserialize)(i.c, null(), 10, null_mut()), fmi2Error);
        assert_eq!((f.get_boolean_status)(i.c, 3, null_mut()), fmi2Error);
        assert_eq!(
            (f.set_string)(i.c, [1u32].as_ptr(), 1, [null()].as_ptr()),
            fmi2Error
        );
        // Zero-length arrays may be NULL.
        assert_eq!((f.get_real)(i.c, null(), 0, null_mut()), fmi2OK);
    }
    assert!(
        i.log_text().matches("is NULL").count() >= 7,
        "{}",
        i.log_text()
    );
}

#[test]
fn wrong_guid_and_model_exchange_are_refused_with_a_log_line() {
    let f = raw();
    let i = RawInstance::new(&f, "wrong", "{00000000-0000-0000-0000-000000000000}");
    assert!(i.c.is_null());
    assert!(
        i.log_text().contains("no model with GUID"),
        "{}",
        i.log_text()
    );
    let i = RawInstance::with_type(&f, "me", &gait(), fmi2Type::fmi2ModelExchange as c_int);
    assert!(i.c.is_null());
    assert!(i.log_text().contains("co-simulation"), "{}", i.log_text());
    let i = RawInstance::with_type(&f, "bad", &gait(), 7);
    assert!(i.c.is_null());
    let i = RawInstance::new(&f, "", &gait());
    assert!(i.c.is_null());
    assert!(i.log_text().contains("instanceName"), "{}", i.log_text());
}

/// The GUID selects the model; the binary serves any of the six whatever its file name (README
/// "FMI behaviour, documented"): the harness loads one byte-identical binary once for every FMU
/// that carries it, and instantiates each component through it with that FMU's GUID. So a
/// copy named `PidController.so` instantiated with `BenchPlant`'s GUID is a `BenchPlant`.
#[test]
fn the_guid_selects_the_model_whatever_the_binary_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let copy = dir.path().join("PidController.so");
    std::fs::copy(fmu_library(), &copy).unwrap();
    let f = Raw::load(&copy);
    let mut plant = RawInstance::new(&f, "plant", &guid_of("BenchPlant"));
    assert!(!plant.c.is_null(), "{}", plant.log_text());
    // The plant's encoderCountsPerRevolution (VR 52; the PID has no Real 52).
    // SAFETY: valid component.
    unsafe {
        assert_eq!((f.setup_experiment)(plant.c, 0, 0.0, 0.0, 0, 0.0), fmi2OK);
        assert_eq!((f.enter_initialization_mode)(plant.c), fmi2OK);
    }
    assert_eq!(plant.reals(&[52]), [2000.0]);
    let pid = RawInstance::new(&f, "pid", &guid_of("PidController"));
    assert!(!pid.c.is_null(), "{}", pid.log_text());
    let mut out = [0.0];
    // SAFETY: valid component and arrays.
    unsafe {
        assert_eq!((f.setup_experiment)(pid.c, 0, 0.0, 0.0, 0, 0.0), fmi2OK);
        assert_eq!((f.enter_initialization_mode)(pid.c), fmi2OK);
        assert_eq!(
            (f.get_real)(pid.c, [52u32].as_ptr(), 1, out.as_mut_ptr()),
            fmi2Error
        );
    }
}

#[test]
fn bad_values_are_refused_and_change_nothing() {
    let f = raw();
    let mut i = RawInstance::new(&f, "values", &gait());
    i.initialize(0.0, None);
    let before = i.reals(&[PERIOD, AMPLITUDE]);
    // SAFETY: valid component and arrays.
    unsafe {
        let set =
            |vrs: &[u32], vals: &[f64]| (f.set_real)(i.c, vrs.as_ptr(), vrs.len(), vals.as_ptr());
        assert_eq!(set(&[PERIOD], &[f64::NAN]), fmi2Error);
        assert_eq!(set(&[PERIOD], &[f64::INFINITY]), fmi2Error);
        assert_eq!(set(&[PERIOD], &[-1.0]), fmi2Error, "below min");
        // All or nothing: a good value next to a bad one is not applied either.
        assert_eq!(
            set(&[PERIOD, AMPLITUDE], &[3.0, 10.0]),
            fmi2Error,
            "above max"
        );
        assert_eq!(set(&[9999], &[1.0]), fmi2Error, "unknown value reference");
        assert_eq!(set(&[ANGLE], &[1.0]), fmi2Error, "calculated output");
        let vrs = [HARMONICS];
        assert_eq!(
            (f.set_integer)(i.c, vrs.as_ptr(), 1, [3].as_ptr()),
            fmi2Error,
            "constant"
        );
        let vrs = [MOTION_WAVEFORM];
        assert_eq!(
            (f.set_integer)(i.c, vrs.as_ptr(), 1, [42].as_ptr()),
            fmi2Error,
            "enum item"
        );
        let mut v = [0.0];
        assert_eq!(
            (f.get_real)(i.c, [9999u32].as_ptr(), 1, v.as_mut_ptr()),
            fmi2Error
        );
        assert_eq!(
            (f.set_debug_logging)(i.c, 1, 1, [c"noSuchCategory".as_ptr()].as_ptr()),
            fmi2Error
        );
        let mut st = 0;
        assert_eq!(
            (f.get_integer_status)(i.c, 0, &mut st),
            fmi2Discard,
            "no integer status kinds"
        );
        let mut s = fmi2Status::fmi2OK;
        assert_eq!(
            (f.get_status)(i.c, 0, &mut s),
            fmi2Discard,
            "no asynchronous steps"
        );
        assert_eq!(
            (f.set_real_input_derivatives)(i.c, [PERIOD].as_ptr(), 1, [1].as_ptr(), [0.0].as_ptr()),
            fmi2Error
        );
    }
    assert_eq!(i.reals(&[PERIOD, AMPLITUDE]), before);
    let log = i.log_text();
    for needle in [
        "must be finite",
        "outside",
        "unknown value reference 9999",
        "cannot be set",
        "not an item",
        "unknown log category",
        "canInterpolateInputs",
    ] {
        assert!(log.contains(needle), "log lacks {needle:?}:\n{log}");
    }
    // Still usable.
    assert_eq!(i.step(0.0, 0.01), fmi2OK);
}

#[test]
fn tunable_parameter_takes_effect_at_once() {
    let f = raw();
    let mut i = RawInstance::new(&f, "tune", &gait());
    i.initialize(0.0, None);
    assert_eq!(i.step(0.0, 0.3), fmi2OK);
    let a = i.reals(&[ANGLE])[0];
    // SAFETY: valid component and arrays.
    unsafe {
        assert_eq!(
            (f.set_real)(i.c, [AMPLITUDE].as_ptr(), 1, [0.5].as_ptr()),
            fmi2OK
        );
    }
    let b = i.reals(&[ANGLE])[0];
    assert!(
        (b / a - 0.5 / 60f64.to_radians()).abs() < 1e-12,
        "{a} -> {b}"
    );
}

#[test]
fn debug_logging_categories_are_honoured() {
    let f = raw();
    let mut i = RawInstance::new(&f, "cats", &gait());
    // SAFETY: valid component and arrays.
    unsafe {
        assert_eq!(
            (f.set_debug_logging)(i.c, 1, 1, [c"logCalls".as_ptr()].as_ptr()),
            fmi2OK
        );
    }
    i.initialize(0.0, None);
    assert!(i.log_text().contains("logCalls"), "{}", i.log_text());
    assert!(i.log.last_environment == (&mut *i.log as *mut LogBuffer).cast());
    // SAFETY: as above.
    unsafe {
        assert_eq!((f.set_debug_logging)(i.c, 0, 0, null()), fmi2OK);
    }
    i.log.clear();
    i.step(0.0, 0.1);
    assert_eq!(i.log.count, 0, "logging off: {}", i.log_text());
    // Errors are reported even with logging off.
    i.step(5.0, 0.1);
    assert_eq!(i.log.count, 1);
}

#[test]
fn two_instances_and_two_loads_do_not_interfere() {
    let f = raw();
    let dir = tempfile::tempdir().unwrap();
    let copy = dir.path().join("GaitReference.so");
    std::fs::copy(fmu_library(), &copy).unwrap();
    let g = Raw::load(&copy);
    let mut a = RawInstance::new(&f, "a", &gait());
    let mut b = RawInstance::new(&f, "b", &gait());
    let mut c = RawInstance::new(&g, "c", &gait());
    // SAFETY: valid component and arrays.
    unsafe {
        assert_eq!(
            (f.set_real)(b.c, [PERIOD].as_ptr(), 1, [1.0].as_ptr()),
            fmi2OK
        );
    }
    a.initialize(0.0, None);
    b.initialize(0.0, None);
    c.initialize(0.0, None);
    let mut alone = RawInstance::new(&f, "alone", &gait());
    alone.initialize(0.0, None);
    // A different FMU in the same process, stepped in between.
    let mut plant = RawInstance::new(&g, "plant", &guid_of("BenchPlant"));
    plant.initialize(0.0, None);
    for k in 0..100 {
        let t = k as f64 * 0.01;
        for i in [&mut a, &mut plant, &mut b, &mut c, &mut alone] {
            assert_eq!(i.step(t, 0.01), fmi2OK);
        }
        let (va, vb, vc, v) = (
            a.reals(&[ANGLE]),
            b.reals(&[ANGLE]),
            c.reals(&[ANGLE]),
            alone.reals(&[ANGLE]),
        );
        assert_eq!(va, v);
        assert_eq!(vc, v);
        if k > 10 {
            assert_ne!(vb, v);
        }
    }
}
