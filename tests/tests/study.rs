//! The closed-loop actuator study end to end, through the exported FMUs:
//!
//! - the default gait (2.5 s, 60 deg / 50 deg for CSEA, 9 N m, 4 cycles) on DA, SEA and CSEA
//!   completes without an interlock trip, tracks within the bounds measured with the tuned
//!   gains (stated in `harness/src/study.rs`, "Measured tracking and margins") and keeps the
//!   interlock quantities clear of their thresholds;
//! - scaling the gait up trips an interlock: the plant ends the run with `fmi2Discard` at the
//!   trip instant and the report names the interlock;
//! - the same closed-loop SSP (SEA, one cycle) run by this harness and by fmpy's
//!   `simulate_ssp` agrees. fmpy's loop (fmpy 0.3.32, `fmpy/ssp/simulation.py`) steps every
//!   component with the inputs it holds, then copies every output to the connected inputs: a
//!   Jacobi scheme, which our master runs with [`Algorithm::Jacobi`] (set the inputs from the
//!   outputs at the start of the macro step, step all). The remaining differences are
//!   bookkeeping: fmpy labels a row with the step's start time (its row k is our row k + 1),
//!   accumulates `time += step` (exact with the 2^-9 s step used here, also a whole number of
//!   nanoseconds for our time grid; every controller's `samplePeriod` is set to that step as
//!   well; SEA under Jacobi at 1.95 ms still tracks and trips nothing), ignores the SSP's parameter bindings (they
//!   are passed as its `parameter_set`, Booleans as 0/1) and starts every connection at 0.0
//!   where our master propagates the initial outputs in initialization mode. The plant's
//!   transducer reads -0.048 N m at rest (its calibration phase); with `transducerPhase` = 0
//!   every connected output is exactly 0 at t = 0, and the two runs are the same sequence of
//!   FMI calls with the same values. Tolerance: none. The same floating-point operations on
//!   the same inputs give the same bits, and a closed loop with quantised encoders either
//!   agrees exactly or drifts by whole counts (2e-5 rad) once anything differs, so no small
//!   tolerance would be meaningful. Measured: bit-identical over the 1280 steps, every output.
//!   (The first attempt, with the transducer's rest reading, differed from the first step on:
//!   the torque loop saw -0.048 N m in our run and 0.0 in fmpy's.)

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use kneebench_harness::master::Value;
use kneebench_harness::package::export_all;
use kneebench_harness::ssp;
use kneebench_harness::study::{
    Actuator, Gait, StudyConfig, StudyGains, gait_scenario, interlock_name, run_study, write_ssp,
};
use kneebench_harness::{Algorithm, LoadOptions, Outcome, Results};
use kneebench_tests::{fmu_library, run_python};

/// The exported FMUs, once per test binary.
fn fmus() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = tempfile::Builder::new()
            .prefix("kneebench-study-fmus")
            .tempdir()
            .unwrap()
            .keep();
        export_all(&fmu_library(), &dir).expect("export");
        dir
    })
}

fn config(out: &Path, actuators: Vec<Actuator>, cycles: u32, scale: f64) -> StudyConfig {
    StudyConfig {
        fmu_dir: fmus().to_path_buf(),
        out_dir: out.to_path_buf(),
        cycles,
        scale,
        gains: None,
        actuators,
    }
}

fn peak(results: &Results, column: &str) -> f64 {
    results
        .column(column)
        .unwrap_or_else(|| panic!("no column {column}"))
        .iter()
        .fold(0.0f64, |m, x| m.max(x.abs()))
}

/// Bounds on one actuator's run [deg]: (RMS, max) of the actuation side and of the knee.
struct Bounds {
    actuation: (f64, f64),
    knee: (f64, f64),
}

#[test]
fn default_gait_completes_without_trips_and_tracks() {
    let out = tempfile::tempdir().unwrap();
    let runs = run_study(&config(out.path(), Actuator::ALL.to_vec(), 4, 1.0)).unwrap();
    // Measured (deg): DA 0.630/1.300 actuation, 0.604/1.251 knee; SEA 1.983/3.280 (the
    // actuation side leads the knee by the planned spring deflection), 0.576/1.219; CSEA
    // 2.513/4.086, 1.457/2.936. Bounds: about 20 % headroom.
    let bounds = [
        Bounds {
            actuation: (0.75, 1.6),
            knee: (0.75, 1.5),
        },
        Bounds {
            actuation: (2.4, 4.0),
            knee: (0.7, 1.5),
        },
        Bounds {
            actuation: (3.0, 5.0),
            knee: (1.8, 3.5),
        },
    ];
    let deg = 180.0 / std::f64::consts::PI;
    for (run, b) in runs.iter().zip(&bounds) {
        let r = &run.report;
        assert!(
            matches!(run.outcome, Outcome::Completed { .. }),
            "{}: {:?}",
            r.name,
            run.outcome
        );
        assert_eq!(r.trip, None, "{}", r.name);
        assert_eq!(r.cycles, 3, "{}", r.name);
        let check = |what: &str, value: f64, bound: f64| {
            assert!(
                value * deg <= bound,
                "{} {what}: {:.3} deg > {bound} deg",
                r.name,
                value * deg
            );
        };
        check("RMS actuation error", r.rms_error_actuation, b.actuation.0);
        check("max actuation error", r.max_error_actuation, b.actuation.1);
        check("RMS knee error", r.rms_error_knee, b.knee.0);
        check("max knee error", r.max_error_knee, b.knee.1);
        // The interlock quantities over the whole run, start-up included (measured: shaft
        // torque 18.25 / 18.32 / 17.23 N m, load-motor torque 18.03 / 17.74 / 16.24 N m,
        // regenerated power 2.30 / 2.05 / 3.58 W, deflection 0.08 / 3.08 / 2.90 deg).
        let res = &run.results;
        let shaft = peak(res, "plant.springTorque");
        let load = peak(res, "plant.loadOutputTorque");
        let regen = peak(res, "plant.loadRegeneratedPower");
        let deflection = peak(res, "plant.springDeflection") * deg;
        assert!(shaft < 18.8, "{} shaft torque {shaft} N m", r.name);
        assert!(load < 18.8, "{} load-motor torque {load} N m", r.name);
        assert!(regen < 4.2, "{} regenerated power {regen} W", r.name);
        assert!(deflection < 4.0, "{} deflection {deflection} deg", r.name);
    }
}

#[test]
fn scaling_the_gait_up_trips_an_interlock_with_discard_at_the_trip() {
    let out = tempfile::tempdir().unwrap();
    let cycles = 2;
    let stop = Gait::bench_default(Actuator::Sea).period * f64::from(cycles);
    let mut tripped = None;
    for step in 0..8 {
        let scale = 1.0 + 0.05 * f64::from(step);
        let runs = run_study(&config(out.path(), vec![Actuator::Sea], cycles, scale)).unwrap();
        let run = runs.into_iter().next().unwrap();
        match &run.outcome {
            Outcome::Completed { .. } => assert_eq!(run.report.trip, None),
            Outcome::Terminated { .. } => {
                tripped = Some((scale, run));
                break;
            }
            Outcome::Failed(e) => panic!("scale {scale}: {e}"),
        }
    }
    let (scale, run) = tripped.expect("no trip up to 1.35 x the bench gait");
    // Measured: the SEA first trips at 1.10 x (test-motor (shaft) torque, 2.79 s).
    assert!(scale > 1.0 && scale <= 1.15, "first trip at {scale} x");
    let Outcome::Terminated {
        component,
        last_successful_time,
        last_row_time,
        messages,
    } = &run.outcome
    else {
        unreachable!()
    };
    assert_eq!(component, "plant");
    assert!(
        *last_successful_time > 0.0 && *last_successful_time < stop,
        "trip at {last_successful_time}"
    );
    // The trip is located inside the step: it is not on the 1 ms grid, and the last row is
    // the communication point before it.
    assert!(*last_row_time <= *last_successful_time);
    assert!(*last_successful_time - *last_row_time < 1e-3 + 1e-12);
    let (name, at) = run.report.trip.clone().expect("the report names the trip");
    assert_eq!(at, *last_successful_time);
    let interlocks: Vec<&str> = (1..=7).map(interlock_name).collect();
    let logged = messages.join("\n");
    assert!(
        logged.contains("outside limit") || logged.contains("above limit"),
        "the plant's log names the interlock: {logged}"
    );
    assert!(
        name.starts_with("plant: ")
            && (name.contains("torque")
                || name.contains("power")
                || name.contains("deflection")
                || name.contains("current")),
        "report names the interlock: {name} (interlocks: {interlocks:?})"
    );
}

/// Runs an `.ssp` with fmpy's `simulate_ssp`; the components' bindings become its
/// `parameter_set` (Booleans as 0/1, which its `set_value` compares with 0.0).
const FMPY_SIMULATE: &str = r#"
import sys
from fmpy.ssp.ssd import read_ssd, ParameterSet, Parameter
from fmpy.ssp.simulation import simulate_ssp
path, stop, step, out = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
ssd = read_ssd(path)
ps = ParameterSet(name="bindings")
outputs = []
for c in ssd.system.elements:
    outputs += [c.name + "." + k.name for k in c.connectors if k.kind == "output"]
    for b in c.parameterBindings:
        for s in b.parameterValues:
            for p in s.parameters:
                q = Parameter(name=c.name + "." + p.name)
                q.type, q.value = p.type, p.value
                if p.type == "Boolean":
                    q.value = 1.0 if str(p.value).lower() in ("true", "1") else 0.0
                ps.parameters.append(q)
r = simulate_ssp(path, stop_time=stop, step_size=step, parameter_set=ps)
with open(out, "w") as f:
    f.write(",".join(["time"] + outputs) + "\n")
    for row in r:
        f.write(",".join(repr(float(row[n])) for n in ["time"] + outputs) + "\n")
"#;

#[test]
fn closed_loop_sea_agrees_with_fmpy_simulate_ssp() {
    let dir = tempfile::tempdir().unwrap();
    let step = 1.0 / 512.0;
    let gait = Gait::bench_default(Actuator::Sea);
    let mut scenario = gait_scenario(
        Actuator::Sea,
        gait,
        StudyGains::for_actuator(Actuator::Sea),
        1,
    );
    scenario.step_size = step;
    for c in &mut scenario.components {
        if c.fmu == "PidController.fmu" {
            c.parameters
                .push(("samplePeriod".into(), Value::Real(step)));
        }
        if c.name == "plant" {
            // The transducer reads -0.048 N m at rest through its calibration phase (module
            // docs): zero it, so that every connected output is 0 at t = 0.
            c.parameters
                .push(("transducerPhase".into(), Value::Real(0.0)));
        }
    }
    let path = dir.path().join("SEA.ssp");
    write_ssp(&scenario, fmus(), &path).unwrap();

    let mut loaded = ssp::load_system(&path, &LoadOptions::default()).unwrap();
    loaded.config.algorithm = Algorithm::Jacobi;
    let out = loaded.system.run(&loaded.config).unwrap();
    assert!(
        matches!(out.outcome, Outcome::Completed { .. }),
        "{:?}",
        out.outcome
    );
    let ours = out.results;
    // The loop under Jacobi (a step's delay on every connection) still tracks: a sanity
    // check that the comparison is of a working closed loop.
    assert!(peak(&ours, "plant.loadAngle") > 0.9);

    let csv = dir.path().join("fmpy.csv");
    run_python(
        FMPY_SIMULATE,
        &[
            &path.display().to_string(),
            &scenario.stop_time.to_string(),
            &step.to_string(),
            &csv.display().to_string(),
        ],
    );
    let theirs = Results::read_csv_file(&csv).unwrap();
    let steps = (scenario.stop_time / step).round() as usize;
    assert_eq!(theirs.len(), steps, "fmpy records one row per step");
    assert_eq!(ours.len(), steps + 1);
    let (our_t, their_t) = (ours.times(), theirs.times());
    let mut worst = (0.0f64, String::new());
    for name in theirs.names() {
        let (a, b) = (ours.column(name).unwrap(), theirs.column(name).unwrap());
        for k in 0..b.len() {
            assert_eq!(their_t[k] + step, our_t[k + 1], "row {k}");
            let (x, y) = (a[k + 1], b[k]);
            let d = (x - y).abs() / (1.0 + x.abs().max(y.abs()));
            if d > worst.0 {
                worst = (
                    d,
                    format!("{name} at t = {}: ours {x}, fmpy {y}", our_t[k + 1]),
                );
            }
        }
    }
    eprintln!("largest relative difference: {:e} ({})", worst.0, worst.1);
    assert!(
        worst.0 == 0.0,
        "largest difference {:e}: {}",
        worst.0,
        worst.1
    );
}
