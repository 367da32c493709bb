//! The harness does not call an optional FMI 2.0 function that the model description's
//! capability flags do not promise: `fmi2SetRealInputDerivatives` needs
//! `canInterpolateInputs`, `fmi2GetRealOutputDerivatives` an order up to
//! `maxOutputDerivativeOrder`, `fmi2CancelStep` and the status of a pending step
//! (`fmi2DoStepStatus`, `fmi2PendingStatus`) `canRunAsynchronuously`. Each is refused before
//! the call ([`FmuError::NotPromised`], [`FmuError::DerivativeOrderNotPromised`]); the FMU's
//! log stays free of it; and so are the FMU-state functions without `canGetAndSetFMUstate`
//! and `canSerializeFMUstate` (`BenchHardware` declares both false). kneebench's FMUs declare
//! `canInterpolateInputs` and `canRunAsynchronuously` false, `maxOutputDerivativeOrder` 0 but
//! for `GaitReference` and `BenchPlant` (1).

use std::sync::{Arc, Mutex};

use kneebench_harness::fmi2::fmi2StatusKind;
use kneebench_harness::{Fmu, FmuError, Instance, InstanceOptions, LoadOptions, LogMessage};
use kneebench_tests::exported_fmu;

/// An initialized instance of `model` and its log, with the value reference of `variable`.
fn initialized(model: &str, variable: &str) -> (Instance, Arc<Mutex<Vec<String>>>, u32) {
    let log: Arc<Mutex<Vec<String>>> = Arc::default();
    let sink = Arc::clone(&log);
    let options = InstanceOptions {
        log_handler: Some(Arc::new(move |m: &LogMessage| {
            sink.lock().unwrap().push(m.message.clone())
        })),
        ..InstanceOptions::default()
    };
    let fmu = Fmu::load(exported_fmu(model), &LoadOptions::default()).unwrap();
    let vr = fmu.variable(variable).unwrap().value_reference;
    let mut i = fmu.instantiate(model, &options).unwrap();
    i.setup_experiment(None, 0.0, None).unwrap();
    i.enter_initialization_mode().unwrap();
    i.exit_initialization_mode().unwrap();
    (i, log, vr)
}

/// Asserts the FMU's log does not name `function` (it was not called).
fn not_called(log: &Mutex<Vec<String>>, function: &str) {
    let logged = log.lock().unwrap().join("\n");
    assert!(!logged.contains(function), "the FMU was called: {logged}");
}

#[test]
fn set_real_input_derivatives_needs_can_interpolate_inputs() {
    let (mut i, log, setpoint) = initialized("PidController", "setpoint");
    let e = i
        .set_real_input_derivatives(&[setpoint], &[1], &[0.5])
        .unwrap_err();
    assert!(
        matches!(
            e,
            FmuError::NotPromised {
                function: "fmi2SetRealInputDerivatives",
                flag: "canInterpolateInputs"
            }
        ),
        "{e:?}"
    );
    assert!(
        e.to_string()
            .contains("does not declare canInterpolateInputs=\"true\""),
        "{e}"
    );
    not_called(&log, "fmi2SetRealInputDerivatives");
}

#[test]
fn get_real_output_derivatives_needs_max_output_derivative_order() {
    const NAME: &str = "fmi2GetRealOutputDerivatives";
    // PidController declares maxOutputDerivativeOrder="0": no order at all.
    let (mut i, log, u) = initialized("PidController", "u");
    let e = i
        .get_real_output_derivatives(&[u], &[1], &mut [0.0])
        .unwrap_err();
    assert!(
        matches!(
            e,
            FmuError::DerivativeOrderNotPromised {
                function: NAME,
                order: 1,
                max: 0
            }
        ),
        "{e:?}"
    );
    assert!(
        e.to_string()
            .contains("of order 1: its model description declares maxOutputDerivativeOrder=\"0\""),
        "{e}"
    );
    not_called(&log, NAME);
    // GaitReference declares 1: the first order is called, the second and order 0 are not.
    let (mut g, log, knee) = initialized("GaitReference", "kneeAngleReference");
    g.do_step(0.0, 0.001).unwrap();
    let mut d = [f64::NAN];
    g.get_real_output_derivatives(&[knee], &[1], &mut d)
        .unwrap();
    assert!(d[0].is_finite(), "{d:?}");
    for (orders, order) in [(&[1, 2][..], 2), (&[0][..], 0)] {
        let e = g
            .get_real_output_derivatives(
                &[knee; 2][..orders.len()],
                orders,
                &mut [0.0; 2][..orders.len()],
            )
            .unwrap_err();
        assert!(
            matches!(
                e,
                FmuError::DerivativeOrderNotPromised { order: o, max: 1, .. } if o == order
            ),
            "{orders:?}: {e:?}"
        );
    }
    not_called(&log, NAME);
}

#[test]
fn cancel_step_needs_can_run_asynchronuously() {
    let (mut i, log, _) = initialized("GaitReference", "kneeAngleReference");
    let e = i.cancel_step().unwrap_err();
    assert!(
        matches!(
            e,
            FmuError::NotPromised {
                function: "fmi2CancelStep",
                flag: "canRunAsynchronuously"
            }
        ),
        "{e:?}"
    );
    not_called(&log, "fmi2CancelStep");
    // The instance goes on.
    i.do_step(0.0, 0.001).unwrap();
}

#[test]
fn the_status_of_a_pending_step_needs_can_run_asynchronuously() {
    let (mut i, log, _) = initialized("GaitReference", "kneeAngleReference");
    i.do_step(0.0, 0.001).unwrap();
    let e = i.get_status(fmi2StatusKind::fmi2DoStepStatus).unwrap_err();
    assert!(
        matches!(
            e,
            FmuError::NotPromised {
                function: "fmi2GetStatus(fmi2DoStepStatus)",
                flag: "canRunAsynchronuously"
            }
        ),
        "{e:?}"
    );
    let e = i
        .get_string_status(fmi2StatusKind::fmi2PendingStatus)
        .unwrap_err();
    assert!(
        matches!(
            e,
            FmuError::NotPromised {
                function: "fmi2GetStringStatus(fmi2PendingStatus)",
                flag: "canRunAsynchronuously"
            }
        ),
        "{e:?}"
    );
    not_called(&log, "Status");
    // The status kinds of a synchronous step are asked as before.
    assert_eq!(
        i.get_real_status(fmi2StatusKind::fmi2LastSuccessfulTime)
            .unwrap(),
        0.001
    );
    assert!(
        !i.get_boolean_status(fmi2StatusKind::fmi2Terminated)
            .unwrap()
    );
}

/// The FMU-state functions need `canGetAndSetFMUstate` and `canSerializeFMUstate`:
/// `BenchHardware`'s are refused before any call (its log stays free of the FMU's refusal),
/// another model's work as before.
#[test]
fn fmu_state_functions_need_their_flags() {
    let (mut i, log, _) = initialized("BenchHardware", "testCurrentCommand");
    let e = i.get_fmu_state().unwrap_err();
    assert!(
        matches!(
            e,
            FmuError::NotPromised {
                function: "fmi2GetFMUstate",
                flag: "canGetAndSetFMUstate"
            }
        ),
        "{e:?}"
    );
    assert!(e.to_string().contains("canGetAndSetFMUstate"), "{e}");
    let e = i.deserialize_fmu_state(&[0; 16]).unwrap_err();
    assert!(
        matches!(
            e,
            FmuError::NotPromised {
                function: "fmi2DeSerializeFMUstate",
                flag: "canSerializeFMUstate"
            }
        ),
        "{e:?}"
    );
    not_called(&log, "FMUstate");
    i.do_step(0.0, 0.001).unwrap();

    let (mut g, _, _) = initialized("GaitReference", "gaitPeriod");
    let s = g.get_fmu_state().unwrap();
    let bytes = g.serialize_fmu_state(&s).unwrap();
    let copy = g.deserialize_fmu_state(&bytes).unwrap();
    g.set_fmu_state(&copy).unwrap();
    g.free_fmu_state(copy).unwrap();
    g.free_fmu_state(s).unwrap();
}
