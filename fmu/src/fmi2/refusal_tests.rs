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

/// A step that does not fit the sample grid is refused before anything changes, like a step
/// larger than the model's largest: the valid step from the same point then runs.
#[test]
fn a_step_off_the_sample_grid_is_refused_and_the_instance_stays_usable() {
    for (model, output) in [
        ("PidController", "u"),
        ("ImpedanceController", "currentCommand"),
        ("ClutchScheduler", "timeInState"),
    ] {
        let y = vr(model, output);
        let mut i = stepping(model);
        assert_eq!(i.do_step(0.0, 0.5e-3), fmi2OK, "{model}");
        let before = get(&mut i, y);
        // From between two instants across the next one.
        assert_eq!(i.do_step(0.5e-3, 1e-3), fmi2Error, "{model}");
        assert_eq!(i.last_successful_time(), 0.5e-3, "{model}");
        assert_eq!(get(&mut i, y), before, "{model}: the outputs are unchanged");
        assert_eq!(i.do_step(0.5e-3, 0.5e-3), fmi2OK, "{model}");
        // From an instant, ending between two.
        assert_eq!(i.do_step(1e-3, 1.5e-3), fmi2Error, "{model}");
        assert_eq!(i.do_step(1e-3, 2e-3), fmi2OK, "{model}");
        assert_eq!(i.last_successful_time(), 3e-3, "{model}");
    }
}
