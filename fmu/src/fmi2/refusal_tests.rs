//! FMI-level tests of the error policy (`instance` module docs): a model error that left the
//! model unchanged refuses the call and keeps the instance usable; only a failure of the
//! model's computation moves it to the error state.

use super::instance::FmiInstance;
use super::logging::Logger;
use super::types::fmi2Status::{self, fmi2Error, fmi2OK};

fn instance(model: &str) -> Box<dyn FmiInstance> {
    crate::registry::find_by_identifier(model)
        .unwrap_or_else(|| panic!("{model} is exported"))
        .instantiate(Logger::new(None, std::ptr::null_mut(), c"test", false))
}

/// The value reference of variable `name` of `model`.
fn vr(model: &str, name: &str) -> u32 {
    crate::registry::find_by_identifier(model)
        .unwrap_or_else(|| panic!("{model} is exported"))
        .info()
        .description
        .variable_by_name(name)
        .unwrap_or_else(|| panic!("{model} has no {name}"))
        .value_reference
}

/// An instance in initialization mode, start time 0.
fn initializing(model: &str) -> Box<dyn FmiInstance> {
    let mut i = instance(model);
    assert_eq!(i.setup_experiment(0.0, None, None), fmi2OK, "{model}");
    assert_eq!(i.enter_initialization_mode(), fmi2OK, "{model}");
    i
}

/// An instance at its first communication point, t = 0.
fn stepping(model: &str) -> Box<dyn FmiInstance> {
    let mut i = initializing(model);
    assert_eq!(i.exit_initialization_mode(), fmi2OK, "{model}");
    i
}

fn get(i: &mut Box<dyn FmiInstance>, vr: u32) -> Result<f64, fmi2Status> {
    let mut out = [f64::NAN];
    match i.get_real(&[vr], &mut out) {
        fmi2OK => Ok(out[0]),
        s => Err(s),
    }
}

/// A tunable parameter set that does not fit the others, the output to read and the value
/// that makes the set consistent again.
struct Inconsistent {
    model: &'static str,
    parameter: &'static str,
    bad: f64,
    good: f64,
    output: &'static str,
}

const INCONSISTENT: [Inconsistent; 7] = [
    // outputMax is 15: a minimum above it, set before the maximum is raised.
    Inconsistent {
        model: "PidController",
        parameter: "outputMin",
        bad: 20.0,
        good: -15.0,
        output: "u",
    },
    Inconsistent {
        model: "ImpedanceController",
        parameter: "outputMin",
        bad: 20.0,
        good: -15.0,
        output: "currentCommand",
    },
    // releaseSpeed is 0.45 rad/s: an inverted hysteresis.
    Inconsistent {
        model: "ClutchScheduler",
        parameter: "engageSpeed",
        bad: 1.0,
        good: 0.3,
        output: "timeInState",
    },
    // engageStart is 0.10: an empty engagement window.
    Inconsistent {
        model: "ClutchScheduler",
        parameter: "engageEnd",
        bad: 0.10,
        good: 0.40,
        output: "timeInState",
    },
    Inconsistent {
        model: "BenchPlant",
        parameter: "loadCellGain",
        bad: 0.0,
        good: 0.001,
        output: "loadCellTorque",
    },
    Inconsistent {
        model: "BenchPlant",
        parameter: "transducerGain",
        bad: 0.0,
        good: -0.008,
        output: "transducerTorque",
    },
    // Gains below a microvolt: the torque conversion would overflow (`BenchParameters`).
    Inconsistent {
        model: "BenchPlant",
        parameter: "loadCellGain",
        bad: 5e-324,
        good: 0.001,
        output: "loadCellTorque",
    },
];

/// Parameters are set one at a time, so an inconsistent set in between is legitimate: the get
/// and the step that find it are refused, and once the parameter is corrected the run goes
/// on (a set, a get and a step are allowed again, so the instance never left its state).
#[test]
fn an_inconsistent_tunable_set_refuses_the_step_and_the_get_and_the_run_goes_on() {
    for case in INCONSISTENT {
        let Inconsistent {
            model,
            parameter,
            bad,
            good,
            output,
        } = case;
        let (p, y) = (vr(model, parameter), vr(model, output));
        let mut i = stepping(model);
        assert_eq!(i.do_step(0.0, 1e-3), fmi2OK, "{model}");
        assert_eq!(i.set_real(&[p], &[bad]), fmi2OK, "{model}.{parameter}");
        assert_eq!(i.do_step(1e-3, 1e-3), fmi2Error, "{model}.{parameter}");
        if model != "BenchPlant" {
            // The plant checks its tunable parameters at the step that applies them.
            assert_eq!(get(&mut i, y), Err(fmi2Error), "{model}.{parameter}");
        }
        assert_eq!(i.do_step(1e-3, 1e-3), fmi2Error, "{model}.{parameter}");
        assert_eq!(i.set_real(&[p], &[good]), fmi2OK, "{model}.{parameter}");
        assert!(get(&mut i, y).is_ok_and(f64::is_finite), "{model}");
        assert_eq!(i.do_step(1e-3, 1e-3), fmi2OK, "{model}.{parameter}");
        assert_eq!(i.last_successful_time(), 2e-3, "{model}.{parameter}");
    }
}

/// In initialization mode a get computes the outputs of the parameters set so far: an
/// inconsistent intermediate set refuses it and the initialization goes on.
#[test]
fn an_inconsistent_set_in_initialization_mode_refuses_the_get_only() {
    for case in INCONSISTENT {
        let Inconsistent {
            model,
            parameter,
            bad,
            good,
            output,
        } = case;
        let (p, y) = (vr(model, parameter), vr(model, output));
        let mut i = initializing(model);
        assert_eq!(i.set_real(&[p], &[bad]), fmi2OK, "{model}.{parameter}");
        assert_eq!(get(&mut i, y), Err(fmi2Error), "{model}.{parameter}");
        assert_eq!(
            i.exit_initialization_mode(),
            fmi2Error,
            "{model}.{parameter}"
        );
        assert_eq!(i.set_real(&[p], &[good]), fmi2OK, "{model}.{parameter}");
        assert!(get(&mut i, y).is_ok_and(f64::is_finite), "{model}");
        assert_eq!(i.exit_initialization_mode(), fmi2OK, "{model}.{parameter}");
        assert_eq!(i.do_step(0.0, 1e-3), fmi2OK, "{model}.{parameter}");
    }
}

/// A step off the sample grid (crossing an instant from between two, or from an instant to
/// between two) is accepted through the glue and runs the samples it reaches: the outputs at
/// its end are those of a twin instance stepped on a 0.5 ms grid. (A step the clock refuses,
/// beyond the grid's exact range, is in `tests/tests/step_bounds.rs`.)
#[test]
fn a_step_off_the_sample_grid_runs_its_samples() {
    for (model, output) in [
        ("PidController", "u"),
        ("ImpedanceController", "currentCommand"),
        ("ClutchScheduler", "timeInState"),
    ] {
        let y = vr(model, output);
        let mut i = stepping(model);
        let mut twin = stepping(model);
        let mut twin_time = 0.0;
        let mut twin_to = |end: f64| {
            while twin_time < end - 1e-12 {
                assert_eq!(twin.do_step(twin_time, 0.5e-3), fmi2OK, "{model}");
                twin_time = (twin_time * 2e3 + 1.0).round() / 2e3;
            }
            get(&mut twin, y)
        };
        let mut check = |i: &mut Box<dyn FmiInstance>, t: f64, h: f64| {
            assert_eq!(i.do_step(t, h), fmi2OK, "{model} from {t} by {h}");
            assert_eq!(i.last_successful_time(), t + h, "{model}");
            assert_eq!(get(i, y), twin_to(t + h), "{model} at {}", t + h);
        };
        check(&mut i, 0.0, 0.5e-3);
        // From between two instants across the next one.
        check(&mut i, 0.5e-3, 1e-3);
        check(&mut i, 1.5e-3, 0.5e-3);
        // From an instant, ending between two.
        check(&mut i, 2e-3, 1.5e-3);
        check(&mut i, 3.5e-3, 1.5e-3);
        check(&mut i, 5e-3, 2e-3);
    }
}

/// `bytes` with the 8 bytes of `from` (which must occur once) replaced by those of `to`.
fn patched_real(bytes: &[u8], from: f64, to: f64) -> Vec<u8> {
    let pattern = from.to_le_bytes();
    let at: Vec<usize> = (0..=bytes.len() - 8)
        .filter(|&k| bytes[k..k + 8] == pattern)
        .collect();
    assert_eq!(at.len(), 1, "{from} occurs once in the state");
    let mut out = bytes.to_vec();
    out[at[0]..at[0] + 8].copy_from_slice(&to.to_le_bytes());
    // Forged on purpose: resealed, so that the value checks, not the checksum, refuse it.
    super::instance::reseal_state(&mut out);
    out
}

/// A state holding a value `fmi2Set*` would refuse (out of range, not finite, no item of its
/// enumeration) is refused by `fmi2DeSerializeFMUstate` (its check) and `fmi2SetFMUstate`,
/// and the instance is left as it was.
#[test]
fn a_state_with_a_value_the_setters_refuse_is_refused_and_changes_nothing() {
    let mut forged = Vec::new();
    // Reals: a distinctive value set through fmi2SetReal, then replaced in the bytes.
    for (model, name, bad) in [
        ("PidController", "outputMax", f64::NAN),
        ("PidController", "outputMax", f64::INFINITY),
        ("PidController", "samplePeriod", -1e-3),
        ("ClutchScheduler", "engageStart", 2.0),
        ("BenchPlant", "loadCellGain", 50.0),
        ("GaitReference", "gaitPeriod", f64::NEG_INFINITY),
    ] {
        let mut i = initializing(model);
        let marker = 0.123_456_789_012_345_6;
        assert_eq!(
            i.set_real(&[vr(model, name)], &[marker]),
            fmi2OK,
            "{model}.{name}"
        );
        forged.push((model, name, patched_real(&i.save_state(), marker, bad)));
    }
    // An integer-valued Real holding a fraction (its setter refuses one).
    for model in ["BenchPlant", "BenchHardware"] {
        let name = "encoderCountsPerRevolution";
        let mut i = initializing(model);
        let marker = 123_457.0;
        assert_eq!(i.set_real(&[vr(model, name)], &[marker]), fmi2OK, "{model}");
        if model == "BenchPlant" {
            forged.push((model, name, patched_real(&i.save_state(), marker, 2740.37)));
        } else {
            // No state after initialization (the bench cannot rewind): the check alone.
            let bytes = patched_real(&i.save_state(), marker, 2740.37);
            let e = i.check_state(&bytes).unwrap_err();
            assert!(e.0.contains("must be an integer"), "{e}");
        }
    }
    // A mode: the bytes where two states differing only in antiWindup differ.
    let model = "PidController";
    let mode = vr(model, "antiWindup");
    let mut i = initializing(model);
    assert_eq!(i.set_integer(&[mode], &[1]), fmi2OK);
    let a = i.save_state();
    assert_eq!(i.set_integer(&[mode], &[2]), fmi2OK);
    let b = i.save_state();
    let at = (0..a.len()).find(|&k| a[k] != b[k]).unwrap();
    let mut bad = a.clone();
    bad[at..at + 4].copy_from_slice(&12345i32.to_le_bytes());
    super::instance::reseal_state(&mut bad);
    forged.push((model, "antiWindup", bad));

    for (model, name, bytes) in forged {
        let mut i = stepping(model);
        assert_eq!(i.do_step(0.0, 1e-3), fmi2OK, "{model}");
        let good = i.save_state();
        let e = i.check_state(&bytes).unwrap_err();
        assert!(e.0.contains(name), "{model}.{name}: {e}");
        assert!(i.restore_state(&bytes).is_err(), "{model}.{name}");
        // Nothing restored: the instance goes on from where it was.
        assert_eq!(i.save_state(), good, "{model}.{name}");
        assert_eq!(i.do_step(1e-3, 1e-3), fmi2OK, "{model}.{name}");
        assert_eq!(i.restore_state(&good), Ok(()), "{model}.{name}");
    }
}

/// Every value a state holds passed the setters' checks, so every model's own states restore:
/// at the start values, in each phase.
#[test]
fn the_states_of_every_model_pass_the_value_checks() {
    for entry in crate::MODELS.iter() {
        let model = entry.identifier;
        let mut i = instance(model);
        let state = i.save_state();
        assert_eq!(i.check_state(&state), Ok(()), "{model}");
        assert_eq!(i.enter_initialization_mode(), fmi2OK, "{model}");
        let state = i.save_state();
        assert_eq!(i.check_state(&state), Ok(()), "{model}");
        if model == "BenchHardware" {
            // Its states after initialization cannot be restored (the bench cannot rewind; its
            // description declares no FMU state, and the C functions refuse every state call).
            continue;
        }
        assert_eq!(i.exit_initialization_mode(), fmi2OK, "{model}");
        assert_eq!(i.do_step(0.0, 1e-3), fmi2OK, "{model}");
        let state = i.save_state();
        assert_eq!(i.restore_state(&state), Ok(()), "{model}");
    }
}

/// The messages logged since the last call of this function.
fn take_log(i: &dyn FmiInstance) -> String {
    let mut captured = i.logger().captured.lock().unwrap();
    std::mem::take(&mut *captured).join("\n")
}

/// A refusal names extreme values compactly (`5e-324`, not 324 digits) and ordinary ones as
/// before.
#[test]
fn refusals_name_extreme_values_compactly() {
    let mut i = instance("PidController");
    assert_eq!(i.setup_experiment(5e-324, None, None), fmi2OK);
    assert_eq!(i.enter_initialization_mode(), fmi2OK);
    assert_eq!(
        i.set_real(&[vr("PidController", "outputMin")], &[1e300]),
        fmi2OK
    );
    assert_eq!(get(&mut i, vr("PidController", "u")), Err(fmi2Error));
    let log = take_log(&*i);
    assert!(
        log.contains("outputMin 1e300 is above outputMax 15"),
        "{log}"
    );
    assert_eq!(
        i.set_real(&[vr("PidController", "outputMin")], &[-15.0]),
        fmi2OK
    );
    assert_eq!(i.exit_initialization_mode(), fmi2OK);
    assert_eq!(i.do_step(0.5, 1e-3), fmi2Error);
    assert_eq!(i.do_step(5e-324, -1e-300), fmi2Error);
    assert_eq!(i.do_step(5e-324, 1e300), fmi2Error);
    let log = take_log(&*i);
    for want in [
        "currentCommunicationPoint 0.5 is not the last communication point 5e-324",
        "communicationStepSize -1e-300 must be positive",
        "communicationStepSize 1e300 s exceeds this model's largest step per call, 10 s",
    ] {
        assert!(log.contains(want), "{want}: {log}");
    }

    let model = "ClutchScheduler";
    let mut i = stepping(model);
    assert_eq!(i.set_real(&[vr(model, "engageStart")], &[1e300]), fmi2Error);
    assert_eq!(i.set_real(&[vr(model, "releaseSpeed")], &[5e-324]), fmi2OK);
    assert_eq!(i.do_step(0.0, 1e-3), fmi2Error);
    let log = take_log(&*i);
    for want in [
        "engageStart = 1e300 refused: outside [0, 1]",
        "releaseSpeed 5e-324 is below engageSpeed 0.3",
    ] {
        assert!(log.contains(want), "{want}: {log}");
    }
    assert!(log.len() < 1000, "{log}");
}
