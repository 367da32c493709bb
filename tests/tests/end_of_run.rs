//! An FMU that ends the run itself (fmi2Discard from `fmi2DoStep`, `fmi2Terminated` true, its
//! `fmi2LastSuccessfulTime` inside the step), with fmpy's `simulate_fmu` as the oracle: our
//! rows are fmpy's rows, every one up to and including the row at the last successful time,
//! for a single FMU and for the same FMU as the component of an SSP system.
//!
//! The FMU is the harness tests' `kbtest.c` (official FMI 2.0 headers), whose `discard_at`
//! parameter ends the run: the step that would pass it integrates up to it (`x += u` times the
//! fraction of the step done), returns fmi2Discard and reports `discard_at` as its last
//! successful time.
//!
//! fmpy 0.3.32 cannot be the oracle of the SSP run itself: its `simulate_ssp` calls
//! `fmi2DoStep` without looking at a Discard (`fmpy/ssp/simulation.py`, `do_step`), so the
//! FMU's fmi2Discard raises `FMICallException` out of the simulation; the test checks that this
//! is still so (if a later fmpy handles it, the test says so and should compare with it). The
//! system of one component must give the single FMU's rows, so the SSP run is compared with
//! fmpy's single-FMU rows (columns `kb.<variable>`).
//!
//! fmpy records the end of the run with `recorder.sample(lastSuccessfulTime, force=True)`
//! after the rows of the steps done; a `discard_at` on the step grid would make it record the
//! same time twice (the step's end and the last successful time), which our results (strictly
//! increasing time) do not: the times here are off the grid, where both mean the same rows.

#[path = "../../harness/tests/common/mod.rs"]
mod kbtest;

use std::path::Path;

use kneebench_harness::master::Value;
use kneebench_harness::ssp::{self, Ssd, SspComponent, SspExperiment, SspParameter, SspSystem};
use kneebench_harness::{Fmu, LoadOptions, Outcome, Results, RunConfig, System};
use kneebench_tests::*;

const STEP: f64 = 0.1;
const STOP: f64 = 1.0;
const U: f64 = 1.5;
/// The recorded variables (every Real and Integer output of kbtest).
const OUTPUTS: [&str; 4] = ["y", "x", "t", "steps"];

/// `simulate_fmu` of the FMU with `u` and `discard_at` set; the rows as CSV (`repr` of every
/// value, so nothing is rounded).
const FMPY_SIMULATE_FMU: &str = r#"
import sys
from fmpy import simulate_fmu
path, u, discard_at, stop, step, out = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4]), float(sys.argv[5]), sys.argv[6]
names = sys.argv[7].split(",")
r = simulate_fmu(path, start_time=0.0, stop_time=stop, step_size=step, output_interval=step,
                 start_values={"u": u, "discard_at": discard_at}, output=names, fmi_type="CoSimulation")
with open(out, "w") as f:
    f.write(",".join(["time"] + names) + "\n")
    for row in r:
        f.write(",".join(repr(float(row[n])) for n in ["time"] + names) + "\n")
"#;

/// `simulate_ssp` of the system (parameters of the bindings passed as its parameter set);
/// prints `raised <exception type>: <message>` or `completed <rows>`.
const FMPY_SIMULATE_SSP: &str = r#"
import sys
from fmpy.ssp.ssd import read_ssd, ParameterSet, Parameter
from fmpy.ssp.simulation import simulate_ssp
path, stop, step = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
ssd = read_ssd(path)
ps = ParameterSet(name="bindings")
for c in ssd.system.elements:
    for b in c.parameterBindings:
        for s in b.parameterValues:
            for p in s.parameters:
                q = Parameter(name=c.name + "." + p.name)
                q.type, q.value = p.type, p.value
                ps.parameters.append(q)
try:
    r = simulate_ssp(path, stop_time=stop, step_size=step, parameter_set=ps)
    print("completed", len(r))
except Exception as e:
    print("raised", type(e).__name__ + ":", e)
"#;

fn fmpy_rows(fmu: &Path, discard_at: f64, out: &Path) -> Results {
    run_python(
        FMPY_SIMULATE_FMU,
        &[
            &fmu.display().to_string(),
            &U.to_string(),
            &discard_at.to_string(),
            &STOP.to_string(),
            &STEP.to_string(),
            &out.display().to_string(),
            &OUTPUTS.join(","),
        ],
    );
    Results::read_csv_file(out).unwrap()
}

/// Ours and fmpy's rows are the same: count, times and every value (columns of `ours` named
/// `prefix` + fmpy's name), to 1e-12 relative: fmpy's times are `start + n * step` in floating
/// point (0.30000000000000004 for 3 * 0.1), ours an integer count of nanoseconds (0.3), and
/// the FMU's `t` and `x` follow the times it is given.
fn assert_same_rows(ours: &Results, fmpy: &Results, prefix: &str, what: &str) {
    let close = |a: &[f64], b: &[f64], name: &str| {
        assert_eq!(a.len(), b.len(), "{what}: {name}: {a:?} vs {b:?}");
        for (k, (x, y)) in a.iter().zip(b).enumerate() {
            assert!(
                (x - y).abs() <= 1e-12 * (1.0 + x.abs().max(y.abs())),
                "{what}: {name} row {k}: {x} vs {y}"
            );
        }
    };
    close(&ours.times(), &fmpy.times(), "time");
    for name in OUTPUTS {
        let a = ours
            .column(&format!("{prefix}{name}"))
            .unwrap_or_else(|| panic!("{what}: no column {prefix}{name}"));
        close(&a, &fmpy.column(name).unwrap(), name);
    }
}

/// The run ended at the FMU's last successful time, and recorded it as its last row.
fn assert_terminated_at(outcome: &Outcome, discard_at: f64, what: &str) {
    match outcome {
        Outcome::Terminated {
            last_successful_time,
            last_row_time,
            ..
        } => {
            assert_eq!(*last_successful_time, discard_at, "{what}");
            assert_eq!(*last_row_time, discard_at, "{what}");
        }
        other => panic!("{what}: {other:?}"),
    }
}

#[test]
fn an_fmu_that_ends_the_run_gives_fmpys_rows_alone_and_in_a_system() {
    let d = tempfile::tempdir().unwrap();
    let fmu_path = kbtest::kbtest_fmu(d.path());
    let fmu = Fmu::load(&fmu_path, &LoadOptions::default()).unwrap();
    let config = RunConfig {
        start_time: 0.0,
        stop_time: STOP,
        step_size: STEP,
        ..RunConfig::default()
    };
    // Inside the first step, inside a middle one, inside the last one.
    for discard_at in [0.05, 0.45, 0.95] {
        let what = format!("discard_at = {discard_at}");
        let theirs = fmpy_rows(&fmu_path, discard_at, &d.path().join("fmpy.csv"));
        // fmpy's rows: the grid up to the last step done, then the last successful time.
        let steps_done = (discard_at / STEP).floor() as usize;
        assert_eq!(theirs.len(), steps_done + 2, "{what}");
        assert_eq!(*theirs.times().last().unwrap(), discard_at, "{what}");

        // A single FMU.
        let mut system = System::new();
        system.add_component("kbtest", fmu.clone()).unwrap();
        system.set_column_prefix(false);
        system.set_value("kbtest.u", Value::Real(U)).unwrap();
        system
            .set_value("kbtest.discard_at", Value::Real(discard_at))
            .unwrap();
        let refs: Vec<String> = OUTPUTS.iter().map(|n| format!("kbtest.{n}")).collect();
        let refs: Vec<&str> = refs.iter().map(String::as_str).collect();
        system.record(&refs).unwrap();
        let ours = system.run(&config).unwrap();
        assert_terminated_at(&ours.outcome, discard_at, &what);
        assert_same_rows(&ours.results, &theirs, "", &what);

        // The same FMU as the one component of an SSP system, its values in the bindings.
        let md = fmu.model_description().clone();
        let mut kb = SspComponent::from_model_description("kb", "resources/kbtest.fmu", &md);
        kb.parameters = vec![
            SspParameter {
                name: "u".into(),
                value: Value::Real(U),
            },
            SspParameter {
                name: "discard_at".into(),
                value: Value::Real(discard_at),
            },
        ];
        let mut ssd = Ssd {
            name: "EndOfRun".into(),
            version: "1.0".into(),
            system: SspSystem {
                name: "One".into(),
                components: vec![kb],
                connections: vec![],
            },
            default_experiment: Some(SspExperiment {
                start_time: Some(0.0),
                stop_time: Some(STOP),
                step_size: Some(STEP),
                algorithm: None,
            }),
        };
        ssd.system.drop_unconnected_inputs();
        let ssp_path = d.path().join("end.ssp");
        ssp::write_ssp(
            &ssd,
            &[("resources/kbtest.fmu".into(), fmu_path.clone())],
            &ssp_path,
        )
        .unwrap();
        let mut loaded = ssp::load_system(&ssp_path, &LoadOptions::default()).unwrap();
        let refs: Vec<String> = OUTPUTS.iter().map(|n| format!("kb.{n}")).collect();
        let refs: Vec<&str> = refs.iter().map(String::as_str).collect();
        loaded.system.record(&refs).unwrap();
        let in_system = loaded.system.run(&loaded.config).unwrap();
        assert_terminated_at(&in_system.outcome, discard_at, &format!("SSP, {what}"));
        assert_same_rows(&in_system.results, &theirs, "kb.", &format!("SSP, {what}"));

        // fmpy's own SSP simulation is no oracle here (see the module documentation).
        let fmpy_ssp = run_python(
            FMPY_SIMULATE_SSP,
            &[
                &ssp_path.display().to_string(),
                &STOP.to_string(),
                &STEP.to_string(),
            ],
        );
        assert!(
            fmpy_ssp.contains("raised FMICallException: fmi2DoStep failed with status 2 (discard)"),
            "fmpy's simulate_ssp: {fmpy_ssp}"
        );
    }
}
