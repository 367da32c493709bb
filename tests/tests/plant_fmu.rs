//! BenchPlant through its C ABI: interlock trips end the run as documented (fmi2Discard,
//! fmi2Terminated, fmi2LastSuccessfulTime, trip code, log line), FMU state continues
//! bit-identically in a fresh instance, tunable parameters act at the next step.

use std::ffi::c_int;

use kneebench_tests::*;

use fmi2Status::{fmi2Discard, fmi2Error, fmi2OK};

const TEST_CURRENT: u32 = 201;
const LOAD_CURRENT: u32 = 203;
const EMERGENCY_STOP: u32 = 207;
const LOAD_DAMPING: u32 = 13;
const ANGLES: [u32; 4] = [300, 301, 302, 303];
const TRIP_CODE: u32 = 373;
const H: f64 = 1e-3;

fn plant(f: &Raw) -> RawInstance<'_> {
    let mut i = RawInstance::new(f, "plant", &guid_of("BenchPlant"));
    assert!(!i.c.is_null(), "{}", i.log_text());
    i.initialize(0.0, None);
    i
}

fn set_reals(i: &RawInstance, vrs: &[u32], values: &[f64]) -> fmi2StatusCode {
    // SAFETY: valid component and arrays of equal length.
    unsafe { (i.f.set_real)(i.c, vrs.as_ptr(), vrs.len(), values.as_ptr()) }
}

fn commands(k: u64) -> [f64; 2] {
    let t = k as f64 * H;
    [
        1.2 * (std::f64::consts::TAU * 0.4 * t).sin(),
        -0.3 * (std::f64::consts::TAU * 0.8 * t).sin(),
    ]
}

fn run(i: &mut RawInstance, from: u64, n: u64) -> Vec<u64> {
    let mut bits = Vec::new();
    for k in from..from + n {
        assert_eq!(
            set_reals(i, &[TEST_CURRENT, LOAD_CURRENT], &commands(k)),
            fmi2OK
        );
        assert_eq!(i.step(k as f64 * H, H), fmi2OK, "{}", i.log_text());
        bits.extend(i.reals(&ANGLES).iter().map(|v| v.to_bits()));
    }
    bits
}

fn trip_status(i: &RawInstance) -> (bool, f64, i32) {
    let (mut terminated, mut last, mut code) = (0, -1.0, -1);
    // SAFETY: valid component and out-pointers.
    unsafe {
        assert_eq!(
            (i.f.get_boolean_status)(
                i.c,
                fmi2StatusKind::fmi2Terminated as c_int,
                &mut terminated
            ),
            fmi2OK
        );
        assert_eq!(
            (i.f.get_real_status)(
                i.c,
                fmi2StatusKind::fmi2LastSuccessfulTime as c_int,
                &mut last
            ),
            fmi2OK
        );
        assert_eq!(
            (i.f.get_integer)(i.c, [TRIP_CODE].as_ptr(), 1, &mut code),
            fmi2OK
        );
    }
    (terminated != 0, last, code)
}

#[test]
fn emergency_stop_ends_the_run_with_discard_at_the_step_start() {
    let f = Raw::load(&fmu_library());
    let mut i = plant(&f);
    run(&mut i, 0, 500);
    // SAFETY: valid component and arrays.
    unsafe {
        assert_eq!(
            (f.set_boolean)(i.c, [EMERGENCY_STOP].as_ptr(), 1, [1].as_ptr()),
            fmi2OK
        );
    }
    assert_eq!(i.step(0.5, H), fmi2Discard);
    let (terminated, last, code) = trip_status(&i);
    assert!(terminated);
    assert!((last - 0.5).abs() < 1e-12, "{last}");
    assert_eq!(code, 7);
    assert!(i.log_text().contains("emergency"), "{}", i.log_text());
    // The run is over: no further step; terminate is allowed.
    assert_eq!(i.step(last, H), fmi2Error);
    // SAFETY: valid component.
    assert_eq!(unsafe { (f.terminate)(i.c) }, fmi2OK);
}

#[test]
fn over_torque_trips_inside_the_step_at_the_located_time() {
    let f = Raw::load(&fmu_library());
    let mut i = plant(&f);
    // 12 A on the test motor is 71 N m at the output: it winds the spring past 20 N m within
    // a few tens of milliseconds.
    assert_eq!(set_reals(&i, &[TEST_CURRENT], &[12.0]), fmi2OK);
    let step = 0.01;
    let mut t = 0.0;
    let mut status = fmi2StatusCode::from(fmi2OK);
    for _ in 0..50 {
        status = i.step(t, step);
        if status != fmi2OK {
            break;
        }
        t += step;
    }
    assert_eq!(status, fmi2Discard, "{}", i.log_text());
    let (terminated, last, code) = trip_status(&i);
    assert!(terminated);
    assert!(
        last > t && last < t + step,
        "trip located inside the step [{t}, {}]: {last}",
        t + step
    );
    assert_eq!(code, 2, "test motor torque");
    // The interlock watches the torque past the harmonic drive: the shaft (spring) torque.
    let shaft = i.reals(&[307])[0];
    assert!(
        (shaft.abs() - 20.0).abs() < 1e-6,
        "shaft torque at the trip: {shaft}"
    );
}

#[test]
fn plant_state_continues_bit_identically_in_a_fresh_instance() {
    let f = Raw::load(&fmu_library());
    let mut i = plant(&f);
    run(&mut i, 0, 700);
    let saved = i.serialized_state();
    let expected = run(&mut i, 700, 500);
    let mut fresh = RawInstance::new(&f, "fresh", &guid_of("BenchPlant"));
    assert_eq!(fresh.restore(&saved), fmi2OK, "{}", fresh.log_text());
    assert_eq!(run(&mut fresh, 700, 500), expected);
    // A state of the gait model is refused by the plant.
    let mut gait = RawInstance::new(&f, "gait", &guid_of("GaitReference"));
    gait.initialize(0.0, None);
    let gait_state = gait.serialized_state();
    assert_eq!(fresh.restore(&gait_state), fmi2Error);
    assert!(
        fresh.log_text().contains("belongs to model GaitReference"),
        "{}",
        fresh.log_text()
    );
}

#[test]
fn tunable_parameter_takes_effect_at_the_next_step() {
    let f = Raw::load(&fmu_library());
    let mut a = plant(&f);
    let mut b = plant(&f);
    let before_a = run(&mut a, 0, 600);
    let before_b = run(&mut b, 0, 600);
    assert_eq!(before_a, before_b);
    assert_eq!(set_reals(&b, &[LOAD_DAMPING], &[2.0]), fmi2OK);
    let after_a = run(&mut a, 600, 1);
    let after_b = run(&mut b, 600, 1);
    assert_ne!(
        after_a, after_b,
        "the doubled load-side damping acts in the very next step"
    );
    // A value the plant refuses is refused at set time, with the range in the log.
    assert_eq!(set_reals(&b, &[LOAD_DAMPING], &[-1.0]), fmi2Error);
    assert!(b.log_text().contains("outside"), "{}", b.log_text());
}

/// `encoderCountsPerRevolution` is a Real that must be a whole number (kept a Real for users'
/// parameter files and SSPs): `fmi2SetReal` refuses a fraction at once, with fmi2Error, a log
/// line naming the rule and the value kept, in the plant and in the hardware FMU; the
/// description says so.
#[test]
fn a_fractional_encoder_count_is_refused_by_fmi2_set_real() {
    const ENCODER_COUNTS: u32 = 52;
    let f = Raw::load(&fmu_library());
    for model in ["BenchPlant", "BenchHardware"] {
        let d = &kneebench_fmu::registry::find_by_identifier(model)
            .unwrap()
            .info()
            .description;
        let v = d.variable_by_name("encoderCountsPerRevolution").unwrap();
        assert_eq!(v.value_reference, ENCODER_COUNTS);
        // The description says so as the harness reads it (and refuses a fraction before
        // the FMU would).
        assert!(v.is_integer_valued(), "{model}: {:?}", v.description);
        assert!(
            !d.variable_by_name("loadDamping")
                .unwrap()
                .is_integer_valued(),
            "{model}"
        );
        let mut i = RawInstance::new(&f, "encoder", &guid_of(model));
        assert!(!i.c.is_null(), "{}", i.log_text());
        // SAFETY: valid component.
        unsafe {
            assert_eq!((f.setup_experiment)(i.c, 0, 0.0, 0.0, 0, 0.0), fmi2OK);
            assert_eq!((f.enter_initialization_mode)(i.c), fmi2OK);
        }
        for bad in [2740.37, 2000.5, 1.0 + f64::EPSILON] {
            assert_eq!(
                set_reals(&i, &[ENCODER_COUNTS], &[bad]),
                fmi2Error,
                "{model}"
            );
            // Refused in a batch too, the other values with it (all or nothing).
            assert_eq!(
                set_reals(&i, &[LOAD_DAMPING, ENCODER_COUNTS], &[0.5, bad]),
                fmi2Error,
                "{model}"
            );
        }
        assert!(
            i.log_text()
                .contains("encoderCountsPerRevolution = 2740.37 refused: must be an integer"),
            "{model}: {}",
            i.log_text()
        );
        let kept = i.reals(&[ENCODER_COUNTS, LOAD_DAMPING]);
        assert_eq!(kept[0], 2000.0, "{model}");
        assert_ne!(kept[1], 0.5, "{model}");
        // A whole number is taken, written with a fraction part of zero or not.
        assert_eq!(
            set_reals(&i, &[ENCODER_COUNTS], &[2048.0]),
            fmi2OK,
            "{model}"
        );
        assert_eq!(i.reals(&[ENCODER_COUNTS])[0], 2048.0, "{model}");
        // SAFETY: valid component.
        unsafe {
            assert_eq!(
                (f.exit_initialization_mode)(i.c),
                fmi2OK,
                "{model}: {}",
                i.log_text()
            );
        }
    }
}
