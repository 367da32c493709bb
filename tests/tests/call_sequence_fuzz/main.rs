//! A hostile importer against every model the binary exports: random sequences of FMI 2.0
//! co-simulation calls made through the raw C ABI, checked against an oracle of the standard's
//! call-sequence table (FMI 2.0, section 4.2.4) as the glue documents it
//! (`fmu/src/fmi2/instance.rs`, `Func::allowed`; `fmu/src/fmi2/export.rs`).
//!
//! Each case instantiates one model and makes up to [`MAX_CALLS`] calls, chosen from every
//! function of the co-simulation interface: setup, enter/exit initialization, terminate, reset,
//! get and set of every base type with known, unknown, mistyped and repeated value references,
//! empty lists, NULL arrays with a non-zero length and values that are NaN, infinite, huge, out
//! of range or fractional, `fmi2DoStep` with negative, zero, NaN, denormal and huge step sizes
//! and wrong communication points, `fmi2CancelStep`, the status functions with every kind,
//! the FMU-state functions with NULL, live, freed, never-made and other instances' or other
//! models' states, serialization into short and NULL buffers, deserialization of truncated,
//! corrupted, extended, foreign and forged bytes, the derivative functions, NULL components,
//! freeing an instance twice, and the version functions. The properties:
//!
//! 1. no call crashes or aborts the process (the test process surviving is the check);
//! 2. every status is a defined `fmi2Status`, never `fmi2Fatal` or `fmi2Pending`; a call the
//!    oracle's table does not allow answers `fmi2Error`, logs "not allowed in state" (or, for
//!    the FMU-state functions of a model that declares them unsupported, "not provided") and
//!    changes nothing: the serialized FMU state and a get of every readable variable (f64
//!    compared by bits) are the same before and after it. Every other `fmi2Error` changes
//!    nothing either (the glue's error policy), except a failed `fmi2DoStep`, which may move
//!    the instance to the error state; then a probe finds it there. No call may panic inside
//!    the FMU (its log would say "internal error (panic)");
//! 3. the oracle agrees with the instance about which calls are accepted in every state, and
//!    predicts the exact status of the calls whose answer depends only on the state and the
//!    arguments (the sets' checks against the model description, the step arguments, the
//!    status kinds, the FMU-state registry); the values a get returns are those of a get of
//!    every variable, `fmi2LastSuccessfulTime` is the time the oracle computes and
//!    `fmi2Terminated` the flag it tracks; a restored FMU state reads as it did when taken;
//! 4. after any sequence, `fmi2Reset` leaves an instance that reads as a fresh one, and a
//!    normal initialization and a few steps succeed.
//!
//! Two of the glue's choices are accepted as refusals although the state is not what they
//! name: a get or set with a NULL array, and `fmi2SetString` with a NULL or non-UTF-8 string,
//! are refused for the argument before the state is checked (`fmu/src/fmi2/export.rs`).
//! The sequences found two defects, both fixed, each with a regression test here: a stepped
//! sine summed stage by stage at every get (a hang far past the sweep; `MAX_SWEEP_STAGES` in
//! `fmu/src/models/gait.rs`), and `BenchPlant`'s FMU state taken while a tunable change waited
//! for the next step, which restored with the change already in force (the state now keeps
//! the values in force beside it, `fmu/src/models/bench_plant.rs`).
//!
//! `BenchHardware` runs on its default in-process `Simulated` backend: the sequences never set
//! the parameters that select a network link, real-time pacing, thread priority, memory locking
//! or a long tare (value references 400 to 409, 425 and 426; a set naming one names an unknown
//! value reference instead). It declares no FMU state, so every FMU-state call is refused, and
//! in the `instantiated` state (no get allowed) nothing of it can be observed.
//!
//! The cases run on a private copy of the binary, so that no other test binary's FMU states
//! share its registry of live states; within this file every call that makes or frees an
//! instance or a state holds one lock that also guards a mirror of that registry, so a freed
//! state's address is only ever passed while no live state has it.

use std::ptr::null_mut;

use kneebench_tests::*;
use proptest::prelude::*;

use fmi2Status::fmi2OK;

mod calls;
mod case;
mod dispatch;
mod fmu_states;
mod library;
mod oracle;
mod values;

use calls::{At, Buffer, Call, Categories, Damage, Nulls, Ref, StatusFn, Value, calls};
use case::{Case, instantiate};
use library::{Ty, library, live, meta};
use oracle::S;

/// The most calls of one case.
const MAX_CALLS: usize = 40;

/// Cases per model in the suite (`PROPTEST_CASES=<n>` for a longer campaign). The six models
/// run as six tests in parallel.
const CASES: u32 = 128;

/// FMU-state slots of a case (the importer's `fmi2FMUstate` variables).
const SLOTS: usize = 3;

/// Every model of the binary, each with the model whose states it must refuse as foreign.
const MODELS: [(&str, &str); 6] = [
    ("GaitReference", "PidController"),
    ("BenchPlant", "GaitReference"),
    ("BenchHardware", "GaitReference"),
    ("PidController", "GaitReference"),
    ("ImpedanceController", "GaitReference"),
    ("ClutchScheduler", "GaitReference"),
];

/// The `BenchHardware` parameters a case never sets: the network backend and its address,
/// real-time pacing, a tare of up to 100000 samples, thread priority, memory locking, the key
/// file and the safe-state acknowledgement (value references 400 to 409, 425, 426).
fn needs_a_bench_link(identifier: &str, vr: u32) -> bool {
    identifier == "BenchHardware" && ((400..=409).contains(&vr) || vr == 425 || vr == 426)
}

/// A value reference no model declares for any type.
const UNKNOWN_VR: u32 = 9999;

/// Runs one case of model `identifier`.
fn run_case(identifier: &'static str, foreign: &'static str, calls: &[Call]) {
    let mut case = Case::new(library(), identifier, foreign);
    for call in calls {
        case.run(call);
    }
    case.recover();
}

fn config() -> ProptestConfig {
    let default = ProptestConfig::default();
    ProptestConfig {
        // `PROPTEST_CASES` runs a longer campaign (proptest reads it into its default).
        cases: if std::env::var_os("PROPTEST_CASES").is_some() {
            default.cases
        } else {
            CASES
        },
        // Shrinking replays whole sequences: bounded so that a failure reports in seconds.
        max_shrink_iters: 2000,
        // A failing case's seed next to this file, `main.proptest-regressions` (as
        // `protocol_fuzz.proptest-regressions`), replayed first by every later run. proptest's
        // default looks for the crate root above a `main.rs` and took this directory for one:
        // it wrote `tests/tests/proptest-regressions/main.txt`, named after no test.
        failure_persistence: Some(Box::new(
            proptest::test_runner::FileFailurePersistence::WithSource("proptest-regressions"),
        )),
        ..default
    }
}

macro_rules! fuzz_model {
    ($test:ident, $index:expr) => {
        proptest! {
            #![proptest_config(config())]
            #[doc = concat!("Random call sequences against model ", stringify!($index), " of [`MODELS`].")]
            #[test]
            fn $test(calls in calls()) {
                let (identifier, foreign) = MODELS[$index];
                run_case(identifier, foreign, &calls);
            }
        }
    };
}

fuzz_model!(gait_reference_survives_any_call_sequence, 0);
fuzz_model!(bench_plant_survives_any_call_sequence, 1);
fuzz_model!(bench_hardware_survives_any_call_sequence, 2);
fuzz_model!(pid_controller_survives_any_call_sequence, 3);
fuzz_model!(impedance_controller_survives_any_call_sequence, 4);
fuzz_model!(clutch_scheduler_survives_any_call_sequence, 5);

/// The fuzzed models are every model the binary exports.
#[test]
fn every_exported_model_is_fuzzed() {
    let exported: Vec<&str> = kneebench_fmu::MODELS.iter().map(|m| m.identifier).collect();
    let mut fuzzed: Vec<&str> = MODELS.iter().map(|(id, _)| *id).collect();
    let mut sorted = exported.clone();
    sorted.sort_unstable();
    fuzzed.sort_unstable();
    assert_eq!(fuzzed, sorted);
}

/// The oracle's table is the glue's, deterministically: every probe in every state of the
/// table, each reached by a fixed prefix on GaitReference (`stepFailed` by a stepped sine that
/// has passed its end frequency, `stepCanceled` and `error` only through forged FMU states:
/// the slave never reaches them otherwise). The random sequences reach the later states
/// rarely; this covers each of them with every function.
#[test]
fn the_oracle_table_matches_the_instance_in_every_state() {
    let lib = library();
    let initialized = [Call::EnterInitializationMode, Call::ExitInitializationMode];
    let forged = |code: u8| {
        let mut calls = initialized.to_vec();
        calls.extend([
            Call::Deserialize {
                blob: 0,
                damage: Damage::Code(code),
                slot: 0,
                null_out: false,
            },
            Call::SetFmuState { slot: 0 },
        ]);
        calls
    };
    // motionWaveform (7) SteppedSine, sweepStartFrequency (11) 1 Hz, sweepEndFrequency (14)
    // 0.5 Hz: the first step ends the sweep.
    let mut failed = vec![
        Call::Set {
            ty: Ty::Integer,
            refs: vec![Ref::Raw(7)],
            values: vec![Value::Max],
            nulls: Nulls::None,
        },
        Call::Set {
            ty: Ty::Real,
            refs: vec![Ref::Raw(11), Ref::Raw(14)],
            values: vec![Value::One, Value::Fraction],
            nulls: Nulls::None,
        },
    ];
    failed.extend(initialized.clone());
    failed.push(Call::DoStep {
        at: At::Now,
        h: 1e-3,
    });
    let mut terminated = initialized.to_vec();
    terminated.push(Call::Terminate);
    let prefixes: [(S, Vec<Call>); 7] = [
        (S::Instantiated, vec![]),
        (S::Initialization, vec![Call::EnterInitializationMode]),
        (S::StepComplete, initialized.to_vec()),
        (S::StepFailed, failed),
        (S::Terminated, terminated),
        (S::StepCanceled, forged(4)),
        (S::Error, forged(6)),
    ];
    let probes = [
        Call::SetDebugLogging {
            on: true,
            categories: Categories::All,
        },
        Call::SetupExperiment {
            tolerance: None,
            start: 0.0,
            stop: None,
        },
        Call::EnterInitializationMode,
        Call::ExitInitializationMode,
        Call::Get {
            ty: Ty::Real,
            refs: vec![Ref::Var(0), Ref::Var(20)],
            nulls: Nulls::None,
        },
        Call::Get {
            ty: Ty::Boolean,
            refs: vec![Ref::Var(0)],
            nulls: Nulls::None,
        },
        Call::Set {
            ty: Ty::Real,
            refs: vec![Ref::Var(0)],
            values: vec![Value::Start],
            nulls: Nulls::None,
        },
        Call::GetRealOutputDerivatives {
            refs: vec![Ref::Raw(100)],
            orders: vec![1],
            nulls: Nulls::None,
        },
        Call::SetRealInputDerivatives { refs: vec![] },
        Call::GetDirectionalDerivative,
        Call::DoStep {
            at: At::Now,
            h: 1e-3,
        },
        Call::CancelStep,
        Call::Status {
            function: StatusFn::Boolean,
            kind: 3,
            null_value: false,
        },
        Call::Status {
            function: StatusFn::Real,
            kind: 2,
            null_value: false,
        },
        Call::Status {
            function: StatusFn::Status,
            kind: 0,
            null_value: false,
        },
        Call::GetFmuState {
            slot: 1,
            null_out: false,
        },
        Call::Serialize {
            slot: 1,
            buffer: Buffer::Exact,
        },
        Call::Deserialize {
            blob: 0,
            damage: Damage::None,
            slot: 2,
            null_out: false,
        },
        Call::Terminate,
        Call::Reset,
    ];
    for (state, prefix) in &prefixes {
        for probe in &probes {
            let mut case = Case::new(lib, "GaitReference", "PidController");
            for call in prefix {
                case.run(call);
            }
            assert_eq!(case.m.s, *state, "the prefix {prefix:?}");
            case.run(probe);
            case.recover();
        }
    }
}

/// Regression (found by a 150,000-case campaign, `PROPTEST_CASES=150000`): `BenchPlant` stored
/// the start time before it built its plant, so an `fmi2ExitInitializationMode` refused for
/// inconsistent parameters (a zero load-cell gain) changed the FMU state. The shrunk sequence.
#[test]
fn a_plant_refused_at_the_end_of_initialization_changes_nothing() {
    run_case(
        "BenchPlant",
        "GaitReference",
        &[
            Call::SetupExperiment {
                tolerance: None,
                start: 1.5,
                stop: None,
            },
            // loadCellGain (57) = 0.
            Call::Set {
                ty: Ty::Real,
                refs: vec![Ref::Raw(57)],
                values: vec![Value::Zero],
                nulls: Nulls::None,
            },
            Call::EnterInitializationMode,
            Call::ExitInitializationMode,
        ],
    );
}

/// Regression (found by a 250,000-case campaign): `GaitReference`, which has no largest step,
/// took a step of `f64::MAX` from 1e300, so its time became infinite and an FMU state taken
/// then could not be set again. A step whose end is not finite is refused now. The shrunk
/// sequence.
#[test]
fn a_step_whose_end_overflows_is_refused() {
    run_case(
        "GaitReference",
        "PidController",
        &[
            Call::EnterInitializationMode,
            Call::ExitInitializationMode,
            Call::DoStep {
                at: At::Now,
                h: 1e300,
            },
            Call::DoStep {
                at: At::Now,
                h: f64::MAX,
            },
            Call::GetFmuState {
                slot: 2,
                null_out: false,
            },
            Call::SetFmuState { slot: 2 },
        ],
    );
}

/// Regression (found by these sequences): `GaitReference` with a stepped sine summed its
/// integral stage by stage at every get, so a communication point far past the sweep (a
/// `startTime` or a step of `1e300` s, 4e9 stages) hung the importer in `fmi2GetReal`. Past
/// `MAX_SWEEP_STAGES` the get is refused at once, changing nothing; the instance still resets
/// and runs. (2.1e6 s with the default 20 s dwell is stage 105000.)
#[test]
fn a_stepped_sine_far_past_its_end_is_refused_not_summed() {
    for (start, h) in [(2.1e6, 1e-3), (0.0, 1e300)] {
        let mut case = Case::new(library(), "GaitReference", "PidController");
        let calls = [
            // motionWaveform (7) = 7, SteppedSine.
            Call::Set {
                ty: Ty::Integer,
                refs: vec![Ref::Raw(7)],
                values: vec![Value::Max],
                nulls: Nulls::None,
            },
            Call::SetupExperiment {
                tolerance: None,
                start,
                stop: None,
            },
            Call::EnterInitializationMode,
            Call::ExitInitializationMode,
            Call::DoStep { at: At::Now, h },
            Call::Get {
                ty: Ty::Real,
                refs: vec![Ref::Raw(100)],
                nulls: Nulls::None,
            },
        ];
        for call in &calls {
            case.run(call);
        }
        let last = case.trace.last().unwrap();
        assert!(last.ends_with("fmi2Error"), "{last}");
        assert!(
            case.inst
                .log_text()
                .contains("past its last computed stage"),
            "{}",
            case.inst.log_text()
        );
        case.recover();
    }
}

/// Regression (found by these sequences): a `BenchPlant` state taken while a tunable change
/// waits for the next step restored with the change already in force (`offsetPower` 500
/// instead of 7 after `hardwareOffsetPower` = 500). Shortest sequence: enter, exit, step
/// 0.001, set `hardwareOffsetPower` (51) = 500, get state, set state.
#[test]
fn a_plant_state_taken_with_a_pending_tunable_change_restores_bit_for_bit() {
    // offsetPower (346) is hardwareOffsetPower (51) in force.
    let offset_power = 346;
    assert!(meta("BenchPlant").find(Ty::Real, offset_power).is_some());
    let f = &library().raw;
    let mut i = instantiate(library(), "plant", "BenchPlant");
    i.initialize(0.0, None);
    assert_eq!(i.step(0.0, 1e-3), fmi2OK);
    // SAFETY: a live instance; arrays of one element; the state is freed.
    unsafe {
        assert_eq!(
            (f.set_real)(i.c, [51u32].as_ptr(), 1, [500.0].as_ptr()),
            fmi2OK
        );
        let before = i.reals(&[offset_power]);
        let mut state: fmi2FMUstate = null_mut();
        {
            let _live = live();
            assert_eq!((f.get_fmu_state)(i.c, &mut state), fmi2OK);
            assert_eq!((f.set_fmu_state)(i.c, state), fmi2OK);
            assert_eq!((f.free_fmu_state)(i.c, &mut state), fmi2OK);
        }
        assert_eq!(i.reals(&[offset_power]), before);
    }
    let _live = live();
    // SAFETY: a live instance, freed once.
    unsafe { (f.free_instance)(i.c) };
    i.c = null_mut();
}
