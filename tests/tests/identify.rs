//! Identification (`kneebench_harness::identify`, `kneebench identify`) on synthetic logs:
//! `BenchPlant` with known perturbed parameters runs the bench's Bode experiment on each motor
//! (`kneebench_harness::experiment::bode`, shortened), sensor noise is added to the logs, and
//! the identification must return the perturbed values; a constant-velocity log must report
//! the inertias as not identifiable and name the experiment to add; bad logs are refused with
//! the file and line.
//!
//! Noise added (the bench facts give no noise figures; these are the sensors' usual levels):
//! white Gaussian, transducer torque 0.05 N m RMS, the drivers' current readings 0.02 A RMS,
//! their voltages 0.05 V RMS. The encoders' quantisation is the plant's own (2000 counts per
//! motor revolution through the gear ratios).

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use kneebench_harness::experiment::{Bench, RunEnd, bode};
use kneebench_harness::identify::{
    Identification, IdentifyConfig, Status, identify, log, write_outputs,
};
use kneebench_harness::master::Value;
use kneebench_harness::params::ParameterSet;
use kneebench_harness::results::{ColumnKind, Results};
use kneebench_harness::{Fmu, LoadOptions, Outcome, RunConfig, System};

fn fmus() -> &'static Path {
    kneebench_tests::exported_fmus().0.path()
}

fn plant_path() -> PathBuf {
    fmus().join("BenchPlant.fmu")
}

/// The identification tests' shortened Bode sweep of `input`: from 0.4 Hz, doubling, `stages`
/// stages of `dwell` seconds.
fn short_sweep(
    input: bode::SweepInput,
    amplitude: f64,
    dwell: f64,
    stages: u32,
) -> bode::BodeConfig {
    bode::BodeConfig {
        input,
        amplitude,
        start_frequency: 0.4,
        ratio: 2.0,
        dwell,
        stages,
        ..bode::BodeConfig::default()
    }
}

/// The perturbed bench: Coulomb friction +30 % on both sides, spring -10 %, inertias +20 %.
const TRUTH: [(&str, f64); 7] = [
    ("actuationStaticFriction", 5.0 * 1.3),
    ("loadStaticFriction", 0.35 * 1.3),
    ("springStiffness", 340.54 * 0.9),
    ("actuationInertia", 0.825 * 1.2),
    ("loadInertia", 0.605 * 1.2),
    ("actuationDamping", 12.0),
    ("loadDamping", 1.0),
];

/// Standard normal noise, deterministic (xorshift64 and Box-Muller).
fn noise(n: usize, seed: u64) -> Vec<f64> {
    let mut s = seed;
    let mut u = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        ((s >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    (0..n)
        .map(|_| (-2.0 * u().ln()).sqrt() * (2.0 * std::f64::consts::PI * u()).cos())
        .collect()
}

/// The channels of a log, with the noise added to each (RMS). `drive.u` is the current set
/// value the experiment's controller sent (a number in the controller, no sensor). The last
/// three (the sensors whose offsets are estimated) are written when the run has them: the load
/// cell 0.05 N m as the transducer, the current sensors 10 mV (the ACS712's output noise).
const CHANNELS: [(&str, f64); 15] = [
    ("drive.u", 0.0),
    ("plant.actuationEncoderAngle", 0.0),
    ("plant.loadEncoderAngle", 0.0),
    ("plant.testMotorCurrent", 0.02),
    ("plant.loadMotorCurrent", 0.02),
    ("plant.transducerTorque", 0.05),
    ("plant.testMotorVoltage", 0.05),
    ("plant.loadMotorVoltage", 0.05),
    ("plant.testDriverSaturated", 0.0),
    ("plant.loadDriverSaturated", 0.0),
    ("plant.tripCode", 0.0),
    ("plant.loadCellTorque", 0.05),
    ("plant.testCurrentSenseVoltage", 0.01),
    ("plant.loadCurrentSenseVoltage", 0.01),
    ("plant.benchSampleTime", 0.0),
];

/// Channels of [`CHANNELS`] a log may lack.
fn optional_channel(name: &str) -> bool {
    name.starts_with("drive.")
        || name.contains("loadCell")
        || name.contains("SenseVoltage")
        || name.ends_with("benchSampleTime")
}

/// Writes the identification's channels of `run` (rows from `from` s) with noise added.
fn noisy_log(run: &Results, path: &Path, seed: u64, from: f64) {
    let channels: Vec<(&str, f64)> = CHANNELS
        .iter()
        .copied()
        .filter(|(n, _)| run.column(n).is_some() || !optional_channel(n))
        .collect();
    let cols: Vec<Vec<f64>> = channels
        .iter()
        .enumerate()
        .map(|(k, (name, sigma))| {
            let c = run.column(name).unwrap_or_else(|| panic!("{name}"));
            let e = noise(c.len(), seed * 31 + k as u64 + 1);
            c.iter().zip(e).map(|(x, e)| x + sigma * e).collect()
        })
        .collect();
    let mut out = Results::with_capacity(
        channels.iter().map(|(n, _)| n.to_string()).collect(),
        vec![ColumnKind::Real; channels.len()],
        run.len(),
    );
    for (i, t) in run.times().iter().enumerate() {
        if *t >= from - 1e-9 {
            let row: Vec<f64> = cols.iter().map(|c| c[i]).collect();
            out.push_row(*t, &row);
        }
    }
    out.write_csv_file(path).unwrap();
}

/// The two shortened Bode sweeps of the experiment set (test motor at 10 A, load motor at 5 A)
/// run on `bench` in `dir`, each written as a noisy log `bode-<k>.csv` (noise seeds `seed`,
/// `seed + 1`).
fn noisy_bode_logs(bench: &Bench, dir: &Path, seed: u64) -> Vec<PathBuf> {
    let mut logs = Vec::new();
    for (k, (input, amplitude)) in [
        (bode::SweepInput::Test, 10.0),
        (bode::SweepInput::Load, 5.0),
    ]
    .into_iter()
    .enumerate()
    {
        let out = dir.join(format!("run{k}"));
        let r = bode::run_bode(bench, &short_sweep(input, amplitude, 6.0, 4), &out).unwrap();
        assert_eq!(r.end, RunEnd::Completed);
        let run = Results::read_csv_file(out.join("bode.csv")).unwrap();
        let path = dir.join(format!("bode-{k}.csv"));
        noisy_log(&run, &path, seed + k as u64, 0.0);
        logs.push(path);
    }
    logs
}

/// The map experiment run on `bench` with `config` in `dir`, completed, and written as the noisy
/// log `map.csv` (noise seed `seed`).
fn noisy_map_log(
    bench: &Bench,
    config: &kneebench_harness::experiment::map::MapConfig,
    dir: &Path,
    seed: u64,
) -> (kneebench_harness::experiment::map::MapResult, PathBuf) {
    let out = dir.join("map");
    let r = kneebench_harness::experiment::map::run_map(bench, config, &out).unwrap();
    assert!(
        matches!(r.end, RunEnd::Completed),
        "the map run ended early: {:?}",
        r.end
    );
    let run = Results::read_csv_file(out.join("map.csv")).unwrap();
    let path = dir.join("map.csv");
    noisy_log(&run, &path, seed, 0.0);
    (r, path)
}

/// The synthetic experiment set: a Bode sweep on each motor of the perturbed plant.
fn perturbed_logs() -> &'static Vec<PathBuf> {
    static LOGS: OnceLock<Vec<PathBuf>> = OnceLock::new();
    LOGS.get_or_init(|| {
        let dir = tempfile::Builder::new()
            .prefix("kneebench-identify-logs-")
            .tempdir()
            .unwrap()
            .keep();
        let params = TRUTH
            .iter()
            .map(|(n, v)| (n.to_string(), format!("{v:?}")))
            .collect();
        let bench = Bench::load(&plant_path(), params, None).unwrap();
        noisy_bode_logs(&bench, &dir, 1)
    })
}

#[test]
fn perturbed_parameters_are_recovered_from_noisy_bode_logs() {
    let logs = perturbed_logs();
    let id = identify(logs, &plant_path(), None, &IdentifyConfig::default()).unwrap();
    let mut report = String::new();
    for (name, truth) in TRUTH {
        let e = id
            .estimates
            .iter()
            .find(|e| e.quantity.parameter == Some(name))
            .unwrap();
        let (v, ci) = e.value();
        let err = (v - truth) / truth;
        report.push_str(&format!(
            "{name}: {v} +- {ci} (truth {truth}, {:.3} %)\n",
            100.0 * err
        ));
        assert_eq!(e.status, Status::Identified, "{name}");
        let within_3 = err.abs() <= 0.03;
        let within_ci = (v - truth).abs() <= ci && ci < 0.1 * truth;
        assert!(within_3 || within_ci, "{report}");
        assert_eq!(id.set.real(name), Some(v), "{name} in the written set");
    }
    // The motors' constants the sweeps excite.
    for (name, truth) in [
        ("testMotorTorqueConstant", 0.037),
        ("loadMotorTorqueConstant", 0.114),
        ("testMotorResistance", 0.608),
        ("loadMotorResistance", 1.1),
    ] {
        let e = id
            .estimates
            .iter()
            .find(|e| e.quantity.parameter == Some(name))
            .unwrap();
        let (v, _) = e.value();
        assert!((v - truth).abs() < 0.03 * truth, "{name}: {v}\n{report}");
    }
    let r = id.refinement.as_ref().expect("refined");
    assert!(r.residual_rms.1 < r.residual_rms.0, "{r:?}");
    // Outputs: the set reads back and is accepted by the FMU, the report has the figure.
    let out = tempfile::tempdir().unwrap();
    let written = write_outputs(&id, out.path()).unwrap();
    let (_d, md) = kneebench_harness::load::extract_and_parse(
        &plant_path(),
        &kneebench_harness::ArchiveLimits::default(),
    )
    .unwrap();
    let set = ParameterSet::read_for(&out.path().join("identified.ssv"), &md).unwrap();
    assert_eq!(set.content_hash(), id.set.content_hash());
    let md_text = std::fs::read_to_string(out.path().join("identify.md")).unwrap();
    assert!(md_text.contains("![Measured vs identified twin](identify-fit.png)"));
    assert!(md_text.contains(&id.set.content_hash()));
    assert!(written.iter().any(|p| p.ends_with("identify-fit.png")));
    eprintln!("{report}identification took {:.2} s", id.seconds);
}

/// A log at constant speed: the plant driven by a constant current, the start-up cut off.
fn constant_velocity_log(dir: &Path) -> PathBuf {
    let fmu = Fmu::load(plant_path(), &LoadOptions::default()).unwrap();
    let mut s = System::new();
    s.add_component("plant", fmu).unwrap();
    s.set_value("plant.testCurrentCommand", Value::Real(3.0))
        .unwrap();
    let out = s
        .run(&RunConfig {
            stop_time: 9.0,
            step_size: 1e-3,
            ..RunConfig::default()
        })
        .unwrap();
    assert!(matches!(out.outcome, Outcome::Completed { .. }));
    let path = dir.join("constant.csv");
    // The spring mode (damping ratio 0.035) has died out after 6 s.
    noisy_log(&out.results, &path, 9, 6.0);
    path
}

#[test]
fn inertia_from_a_constant_velocity_log_is_reported_not_identifiable() {
    let dir = tempfile::tempdir().unwrap();
    let log = constant_velocity_log(dir.path());
    let config = IdentifyConfig {
        refine: false,
        ..IdentifyConfig::default()
    };
    let id = identify(&[log], &plant_path(), None, &config).unwrap();
    let i1 = id
        .estimates
        .iter()
        .find(|e| e.quantity.parameter == Some("actuationInertia"))
        .unwrap();
    assert!(matches!(i1.status, Status::NotIdentifiable(_)), "{i1:?}");
    // The written set keeps the prior for it.
    assert_eq!(id.set.real("actuationInertia"), Some(0.825));
    write_outputs(&id, dir.path()).unwrap();
    let md = std::fs::read_to_string(dir.path().join("identify.md")).unwrap();
    assert!(md.contains("### Not identifiable from these logs"), "{md}");
    assert!(
        md.contains("- I1 (kg.m2): a log with acceleration of the actuation side: `kneebench experiment bode --input test`"),
        "{md}"
    );
}

fn write_text(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// A minimal well-formed log of `n` rows (the plant at rest with a little signal).
fn small_log(n: usize, edit: impl Fn(usize, &mut [String; 6])) -> String {
    let mut s = String::from(
        "time,plant.actuationEncoderAngle,plant.loadEncoderAngle,plant.testMotorCurrent,plant.loadMotorCurrent,plant.transducerTorque\n",
    );
    for i in 0..n {
        let t = i as f64 * 1e-3;
        let mut row = [
            format!("{t:?}"),
            format!("{:?}", (t * 3.0).sin() * 0.1),
            format!("{:?}", (t * 3.0).sin() * 0.099),
            format!("{:?}", (t * 3.0).cos()),
            "0".to_string(),
            format!("{:?}", (t * 3.0).sin() * 0.3),
        ];
        edit(i, &mut row);
        s.push_str(&row.join(","));
        s.push('\n');
    }
    s
}

#[test]
fn bad_logs_are_refused_with_the_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let config = IdentifyConfig {
        refine: false,
        ..IdentifyConfig::default()
    };
    let run = |name: &str, text: String| {
        let p = write_text(dir.path(), name, &text);
        identify(&[p], &plant_path(), None, &config)
            .map(|_| ())
            .unwrap_err()
            .to_string()
    };
    let missing = small_log(1000, |_, _| {}).replace("plant.transducerTorque", "plant.other");
    let e = run("missing.csv", missing);
    assert!(
        e.contains("missing.csv: missing channels: transducerTorque"),
        "{e}"
    );
    let e = run(
        "time.csv",
        small_log(1000, |i, r| {
            if i == 500 {
                r[0] = "0.4".into();
            }
        }),
    );
    assert!(
        e.contains("time.csv: line 502: time 0.4 does not increase"),
        "{e}"
    );
    let e = run(
        "nan.csv",
        small_log(1000, |i, r| {
            if i == 700 {
                r[4] = "NaN".into();
            }
        }),
    );
    assert!(
        e.contains("nan.csv: line 702: loadMotorCurrent is NaN"),
        "{e}"
    );
    let e = run("short.csv", small_log(100, |_, _| {}));
    assert!(e.contains("short.csv: too short: 100 rows"), "{e}");
    // The bench's clock, when logged, must increase and be finite.
    let with_clock = |edit: &dyn Fn(usize) -> Option<&'static str>| {
        small_log(1000, |_, _| {})
            .lines()
            .enumerate()
            .map(|(i, l)| match (i, edit(i)) {
                (0, _) => format!("{l},plant.benchSampleTime\n"),
                (_, Some(v)) => format!("{l},{v}\n"),
                (i, None) => format!("{l},{:?}\n", 12.0 + (i - 1) as f64 * 1e-3),
            })
            .collect::<String>()
    };
    let e = run("clock.csv", with_clock(&|i| (i == 600).then_some("12.5")));
    assert!(
        e.contains("clock.csv: line 601: benchSampleTime 12.5 does not increase"),
        "{e}"
    );
    let e = run("clock-nan.csv", with_clock(&|i| (i == 9).then_some("NaN")));
    assert!(
        e.contains("clock-nan.csv: line 10: benchSampleTime is NaN"),
        "{e}"
    );
    // A saturated segment is excluded with a note, the rest is used.
    let mut text = small_log(3000, |_, _| {});
    text = text
        .lines()
        .enumerate()
        .map(|(i, l)| match i {
            0 => format!("{l},plant.testDriverSaturated"),
            i if (1001..=1200).contains(&i) => format!("{l},1"),
            _ => format!("{l},0"),
        })
        .collect::<Vec<_>>()
        .join("\n");
    let p = write_text(dir.path(), "saturated.csv", &text);
    let id = identify(&[p], &plant_path(), None, &config).unwrap();
    assert!(
        id.notes
            .iter()
            .any(|n| n.contains("saturated.csv: lines 1002-1201")
                && n.contains("test driver saturated")),
        "{:?}",
        id.notes
    );
}

/// The same identification over logs recorded through `BenchHardware` (backend Udp, soft
/// pacing) against the emulator serving the perturbed plant, in real time: the Bode sweep on
/// each motor, shortened to 3 stages of 3 s (0.4, 0.8 and 1.6 Hz; 18 s of real time in all),
/// the sensors' noise added as for the simulated logs. The logs' time column is the nominal one
/// while the emulated bench integrated over the wall-time intervals between frames; the logs
/// carry the bench's clock (`benchSampleTime`) and are resampled on it, so that the I/O jitter
/// and the host's stalls of a few milliseconds (then steps back to back to catch up) are part
/// of what the identification must tolerate here. Before the resampling they were not: CI
/// failed on such logs (static friction off by 55 %, inertia by 78 %), and two runs with
/// pauses of 7-14 ms gave the stiffness 9 % and 200 % off; stop 37 saw the load damping's
/// interval widen from 0.04 to 0.27 with pauses of 2-5 ms. A run with a pause of more than
/// 10 ms between two frames (the bench's own measure; its rows are left out of the fit beyond
/// 5 ms) is run again, at most five attempts per sweep; when every attempt was disturbed
/// nothing is identified, and the test says so.
#[test]
fn perturbed_parameters_are_recovered_from_logs_recorded_through_the_hardware() {
    const ATTEMPTS: usize = 5;
    use kneebench_tests::experiment_over_emulator_within;
    // Resampled on the bench's clock, logs with pauses of 2.0-3.2 ms identified every
    // parameter as closely as undisturbed ones (eight runs here, five of them beside two or
    // three busy loops; the load damping +-0.039, as without pauses).
    const LARGEST_PAUSE: f64 = 10e-3;
    let _real_time = kneebench_tests::one_real_time_test_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let mut logs = Vec::new();
    for (k, (input, amplitude)) in [
        (bode::SweepInput::Test, 10.0),
        (bode::SweepInput::Load, 5.0),
    ]
    .into_iter()
    .enumerate()
    {
        // A run the host disturbed logged motion the emulated bench integrated over the
        // stall under one nominal period: it is run again, at most five attempts.
        let truth: Vec<(&str, String)> =
            TRUTH.iter().map(|(n, v)| (*n, format!("{v:?}"))).collect();
        let truth: Vec<(&str, &str)> = truth.iter().map(|(n, v)| (*n, v.as_str())).collect();
        let Some((end, run)) =
            experiment_over_emulator_within(&truth, ATTEMPTS, LARGEST_PAUSE, |bench, out| {
                let r = bode::run_bode(bench, &short_sweep(input, amplitude, 3.0, 3), out)
                    .map_err(|e| e.to_string())?;
                let reason = kneebench_tests::reason_of(&r.end);
                let run = Results::read_csv_file(out.join("bode.csv")).unwrap();
                Ok(((r.end, run), reason))
            })
        else {
            return;
        };
        assert_eq!(end, RunEnd::Completed);
        let path = dir.path().join(format!("bode-hardware-{k}.csv"));
        noisy_log(&run, &path, k as u64 + 11, 0.0);
        logs.push(path);
    }
    let id = identify(&logs, &plant_path(), None, &IdentifyConfig::default()).unwrap();
    let (estimates, mut report) = against_truth(&id);
    for note in id.notes.iter().filter(|n| n.contains("resampled")) {
        report.push_str(note);
        report.push('\n');
    }
    eprintln!("{report}");
    for ((v, ci, status), (name, truth)) in estimates.into_iter().zip(TRUTH) {
        assert_eq!(status, Status::Identified, "{name}\n{report}");
        let within_3 = ((v - truth) / truth).abs() <= 0.03;
        let within_ci = (v - truth).abs() <= ci && ci < 0.1 * truth;
        assert!(within_3 || within_ci, "{name}\n{report}");
    }
}

/// Each parameter of [`TRUTH`] as `id` estimated it (value, 95 % interval, status), in that
/// order, and one report line per parameter.
fn against_truth(id: &Identification) -> (Vec<(f64, f64, Status)>, String) {
    let mut report = String::new();
    let mut estimates = Vec::new();
    for (name, truth) in TRUTH {
        let e = id
            .estimates
            .iter()
            .find(|e| e.quantity.parameter == Some(name))
            .unwrap();
        let (v, ci) = e.value();
        report.push_str(&format!(
            "{name}: {v} +- {ci} (truth {truth}, {:.3} %) {:?}\n",
            100.0 * (v - truth) / truth,
            e.status
        ));
        estimates.push((v, ci, e.status.clone()));
    }
    (estimates, report)
}

/// The bench's clock of a master that runs late now and then, in ticks of 0.1 ms, for `rows`
/// rows logged every 1 ms. Each row's sample is read at its deadline or when the step's work
/// is done, whichever is later: the work takes 0.1 ms, except in a slow stretch of 15 steps
/// every 0.5 s (1.3 ms each: the loop falls 4.5 ms behind) and in a stall every 0.7 s (3-9
/// ms); behind its schedule the loop runs its steps back to back until it has caught up. A
/// row is 0.1 ms late every 13th. (What this VM's host did to the loop over the emulated
/// bench, stop 37.)
fn late_master_ticks(rows: usize) -> Vec<u64> {
    const STALLS: [u64; 5] = [30, 38, 45, 55, 90];
    let mut ticks: Vec<u64> = Vec::with_capacity(rows);
    for k in 0..rows {
        let deadline = 10 * k as u64 + u64::from(k % 13 == 5);
        let work = match k {
            _ if k % 700 == 350 => STALLS[(k / 700) % STALLS.len()],
            _ if (100..115).contains(&(k % 500)) => 13,
            _ => 1,
        };
        let done = ticks.last().map_or(0, |previous| previous + work);
        ticks.push(deadline.max(done));
    }
    ticks
}

/// A Bode sweep of the perturbed plant as a bench records it whose rows were sampled at the
/// bench times `ticks` (0.1 ms): the set value of row `k` (the experiment's `drive.u` at its
/// schedule time) reaches the bench at the row's bench time, the readings are the bench's at that time, and the rows are
/// labelled with the schedule's times; `plant.benchSampleTime` as `BenchHardware` logs it.
/// (The plant runs at 0.1 ms steps so that the bench's times fall on its grid.)
fn late_master_log(experiment: &Results, input: &str, ticks: &[u64]) -> Results {
    const TICK: f64 = 1e-4;
    let rows = experiment.len();
    let drive = experiment.column("drive.u").unwrap();
    let mut s = System::new();
    s.add_component(
        "plant",
        Fmu::load(plant_path(), &LoadOptions::default()).unwrap(),
    )
    .unwrap();
    for (name, v) in TRUTH {
        s.set_value(&format!("plant.{name}"), Value::Real(v))
            .unwrap();
    }
    s.add_signal(
        input,
        kneebench_harness::master::Signal {
            // Half a tick early: the 0.1 ms step that starts at the bench time takes it.
            times: ticks.iter().map(|t| (*t as f64 - 0.5) * TICK).collect(),
            values: drive.clone(),
            interpolate: false,
        },
    )
    .unwrap();
    let channels: Vec<&str> = CHANNELS
        .iter()
        .map(|(n, _)| *n)
        .filter(|n| n.starts_with("plant.") && !n.ends_with("benchSampleTime"))
        .collect();
    s.record(&channels).unwrap();
    let out = s
        .run(&RunConfig {
            stop_time: *ticks.last().unwrap() as f64 * TICK,
            step_size: TICK,
            ..RunConfig::default()
        })
        .unwrap();
    assert!(matches!(out.outcome, Outcome::Completed { .. }));
    let fine = &out.results;
    let mut names: Vec<String> = vec!["drive.u".into()];
    names.extend(channels.iter().map(|n| n.to_string()));
    names.push("plant.benchSampleTime".into());
    let mut log = Results::with_capacity(names.clone(), vec![ColumnKind::Real; names.len()], rows);
    let columns: Vec<Vec<f64>> = channels.iter().map(|n| fine.column(n).unwrap()).collect();
    for (k, tick) in ticks.iter().enumerate() {
        let i = *tick as usize;
        assert!((fine.times()[i] - *tick as f64 * TICK).abs() < 1e-9);
        let mut row = vec![drive[k]];
        row.extend(columns.iter().map(|c| c[i]));
        row.push(*tick as f64 * TICK);
        log.push_row(experiment.times()[k], &row);
    }
    log
}

/// A master that ran late (stalls of 2-8 ms, slow stretches, then steps back to back to catch
/// up) logged its rows at the schedule's times while the bench read its sensors at its own.
/// Resampled onto the bench's clock (`benchSampleTime`), such logs identify the plant as the
/// same sweeps logged by a master on time do; read on the schedule, they identify nothing.
#[test]
fn logs_of_a_late_master_are_identified_on_the_bench_clock() {
    let dir = tempfile::tempdir().unwrap();
    let params = TRUTH
        .iter()
        .map(|(n, v)| (n.to_string(), format!("{v:?}")))
        .collect();
    let bench = Bench::load(&plant_path(), params, None).unwrap();
    let mut on_time = Vec::new();
    let mut on_clock = Vec::new();
    let mut on_schedule = Vec::new();
    for (k, (input, amplitude, command)) in [
        (bode::SweepInput::Test, 10.0, "plant.testCurrentCommand"),
        (bode::SweepInput::Load, 5.0, "plant.loadCurrentCommand"),
    ]
    .into_iter()
    .enumerate()
    {
        let out = dir.path().join(format!("run{k}"));
        let r = bode::run_bode(&bench, &short_sweep(input, amplitude, 3.0, 3), &out).unwrap();
        assert_eq!(r.end, RunEnd::Completed);
        let experiment = Results::read_csv_file(out.join("bode.csv")).unwrap();
        let seed = 21 + k as u64;
        let schedule: Vec<u64> = (0..experiment.len() as u64).map(|k| 10 * k).collect();
        let path = dir.path().join(format!("on-time-{k}.csv"));
        noisy_log(
            &late_master_log(&experiment, command, &schedule),
            &path,
            seed,
            0.0,
        );
        on_time.push(path);
        let late = late_master_log(&experiment, command, &late_master_ticks(experiment.len()));
        let path = dir.path().join(format!("late-{k}.csv"));
        noisy_log(&late, &path, seed, 0.0);
        on_clock.push(path.clone());
        // The same log without the bench's clock: read on the schedule.
        let text = std::fs::read_to_string(&path).unwrap();
        let header = text.lines().next().unwrap();
        assert!(header.ends_with(",plant.benchSampleTime"), "{header}");
        let cut: String = text
            .lines()
            .map(|l| l[..l.rfind(',').unwrap()].to_string() + "\n")
            .collect();
        let path = dir.path().join(format!("late-{k}-schedule.csv"));
        std::fs::write(&path, cut).unwrap();
        on_schedule.push(path);
    }
    // The same late log as Parquet is resampled to the same rows, bit for bit.
    let parquet = dir.path().join("late-0.parquet");
    Results::read_csv_file(&on_clock[0])
        .unwrap()
        .write_parquet_file(&parquet, vec![])
        .unwrap();
    let window = IdentifyConfig::default().window;
    let (from_csv, from_parquet) = (
        log::read(&on_clock[0], window).unwrap(),
        log::read(&parquet, window).unwrap(),
    );
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&from_csv.time), bits(&from_parquet.time));
    for side in 0..2 {
        assert_eq!(bits(&from_csv.angle[side]), bits(&from_parquet.angle[side]));
        assert_eq!(
            bits(&from_csv.current[side]),
            bits(&from_parquet.current[side])
        );
    }
    assert_eq!(bits(&from_csv.torque), bits(&from_parquet.torque));
    assert_eq!(from_csv.usable, from_parquet.usable);
    assert!(
        from_parquet.notes.iter().any(|n| n.contains("resampled")),
        "{:?}",
        from_parquet.notes
    );
    let estimates = |logs: &[PathBuf]| {
        let id = identify(logs, &plant_path(), None, &IdentifyConfig::default()).unwrap();
        let (estimates, text) = against_truth(&id);
        let values: Vec<(f64, f64, bool)> = estimates
            .into_iter()
            .map(|(v, ci, status)| (v, ci, status == Status::Identified))
            .collect();
        (values, text, id.notes.join("\n"))
    };
    let (reference, reference_text, reference_notes) = estimates(&on_time);
    let (late, late_text, late_notes) = estimates(&on_clock);
    let (schedule, schedule_text, _) = estimates(&on_schedule);
    let texts = format!(
        "on time:\n{reference_text}late, on the bench's clock:\n{late_text}late, on the \
         schedule:\n{schedule_text}"
    );
    eprintln!("{texts}");
    // A clock that agrees with the schedule leaves the log as it is.
    assert!(!reference_notes.contains("resampled"), "{reference_notes}");
    assert!(
        late_notes.contains("resampled onto the bench's clock"),
        "{late_notes}"
    );
    assert!(
        late_notes.contains("rows inside gaps longer than 5 periods not used"),
        "{late_notes}"
    );
    for (((v, _, identified), (r, ci, reference_identified)), (name, _)) in
        late.iter().zip(&reference).zip(TRUTH)
    {
        assert!(*reference_identified && *identified, "{name}\n{texts}");
        assert!((v - r).abs() <= 0.5 * ci, "{name}\n{texts}");
    }
    // Without the clock the same rows identify (nearly) nothing.
    let identified = schedule.iter().filter(|(_, _, i)| *i).count();
    assert!(identified <= 2, "{texts}");
}

/// A Parquet log (`kneebench experiment --format parquet`, or any tool's table) gives the
/// identification exactly what the same log as CSV gives: the CSV text round-trips every value,
/// so the estimates are equal bit for bit.
#[test]
fn parquet_logs_identify_exactly_as_the_same_csv_logs() {
    let csv = perturbed_logs();
    let dir = tempfile::tempdir().unwrap();
    let parquet: Vec<PathBuf> = csv
        .iter()
        .enumerate()
        .map(|(k, p)| {
            let path = dir.path().join(format!("log-{k}.parquet"));
            Results::read_csv_file(p)
                .unwrap()
                .write_parquet_file(&path, vec![])
                .unwrap();
            path
        })
        .collect();
    let config = IdentifyConfig {
        refine: false,
        ..IdentifyConfig::default()
    };
    let from_csv = identify(csv, &plant_path(), None, &config).unwrap();
    let from_parquet = identify(&parquet, &plant_path(), None, &config).unwrap();
    assert_eq!(from_csv.estimates.len(), from_parquet.estimates.len());
    for (a, b) in from_csv.estimates.iter().zip(&from_parquet.estimates) {
        assert_eq!(a.quantity.parameter, b.quantity.parameter);
        assert_eq!(
            a.value().0.to_bits(),
            b.value().0.to_bits(),
            "{a:?} vs {b:?}"
        );
    }
    // A bad Parquet log is refused with its file and row.
    let mut r = Results::read_csv_file(&csv[0]).unwrap();
    let names = r.names().to_vec();
    let k = names
        .iter()
        .position(|n| n == "plant.transducerTorque")
        .unwrap();
    let mut bad =
        Results::with_capacity(names.clone(), vec![ColumnKind::Real; names.len()], r.len());
    for (i, row) in r.rows().enumerate() {
        let mut values = row[1..].to_vec();
        if i == 1500 {
            values[k] = f64::NAN;
        }
        bad.push_row(row[0], &values);
    }
    r = bad;
    let path = dir.path().join("bad.parquet");
    r.write_parquet_file(&path, vec![]).unwrap();
    let e = identify(&[path], &plant_path(), None, &config)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("bad.parquet") && e.contains("row 1501") && e.contains("NaN"),
        "{e}"
    );
}

/// The exponential friction law's truth for [`the_exponential_friction_law_is_identified_from_map_and_bode_logs`]:
/// the defaults' levels perturbed (a0 +20 %, a1 +30 %, a2 -20 %), the rates unchanged. The
/// first five are the actuation side's, the last five the load side's.
const EXPONENTIAL_TRUTH: [(&str, f64); 10] = [
    ("actuationStribeckA0", 4.0 * 1.2),
    ("actuationStribeckA1", 1.0 * 1.3),
    ("actuationStribeckB1", 20.0),
    ("actuationStribeckA2", 1.117927 * 0.8),
    ("actuationStribeckB2", 2.0),
    ("loadStribeckA0", 0.28 * 1.2),
    ("loadStribeckA1", 0.07 * 1.3),
    ("loadStribeckB1", 20.0),
    ("loadStribeckA2", 0.07825489 * 0.8),
    ("loadStribeckB2", 2.0),
];

#[test]
fn the_exponential_friction_law_is_identified_from_map_and_bode_logs() {
    use kneebench_harness::experiment::map;
    let dir = tempfile::tempdir().unwrap();
    let mut params: Vec<(String, String)> = EXPONENTIAL_TRUTH
        .iter()
        .map(|(n, v)| (n.to_string(), format!("{v:?}")))
        .collect();
    params.push(("frictionModel".into(), "2".into()));
    let bench = Bench::load(&plant_path(), params, None).unwrap();
    let map_config = map::MapConfig {
        speeds: vec![1.0, 2.0, 3.0, 6.0, 10.0, 20.0, 50.0, 100.0, 150.0],
        torques: vec![0.0],
        ..map::MapConfig::default()
    };
    let (_, map_log) = noisy_map_log(&bench, &map_config, dir.path(), 21);
    let mut logs = vec![map_log];
    logs.extend(noisy_bode_logs(&bench, dir.path(), 31));
    let config = IdentifyConfig {
        plant_parameters: vec![("frictionModel".into(), "2".into())],
        ..IdentifyConfig::default()
    };
    let id = identify(&logs, &plant_path(), None, &config).unwrap();
    let mut report = String::new();
    let estimate = |name: &str| {
        id.estimates
            .iter()
            .find(|e| e.quantity.parameter == Some(name))
            .unwrap_or_else(|| panic!("no estimate of {name}"))
    };
    for (name, truth) in EXPONENTIAL_TRUTH {
        let e = estimate(name);
        let (v, ci) = e.value();
        report.push_str(&format!(
            "{name}: {v} +- {ci} (truth {truth}, {:.2} %) {:?}\n",
            100.0 * (v - truth) / truth,
            e.status
        ));
    }
    eprintln!("{report}");
    // The actuation side's law: the levels within 3 %; the rates, which only the map's slow
    // rows (below the Stribeck speed 1/b1) and its fastest ones (beyond 1/b2) see, within 10 %.
    for (name, truth) in &EXPONENTIAL_TRUTH[..5] {
        let e = estimate(name);
        assert_eq!(e.status, Status::Identified, "{name}\n{report}");
        let (v, _) = e.value();
        let tolerance = if name.contains('B') { 0.10 } else { 0.03 };
        assert!(
            (v - truth).abs() <= tolerance * truth,
            "{name}: {v} vs {truth}\n{report}"
        );
    }
    // The load side's law is not determined by these logs (the map drives the test motor, and
    // the load side's friction, a tenth of the actuation side's, hides in the transducer's
    // noise at the slow speeds): it must be reported so, never returned as if fitted, and the
    // Coulomb level the law replaces must be reported as not used.
    for (name, _) in &EXPONENTIAL_TRUTH[5..] {
        assert!(
            matches!(estimate(name).status, Status::NotIdentifiable(_)),
            "{name} claimed identified\n{report}"
        );
    }
    for side in ["actuationStaticFriction", "loadStaticFriction"] {
        let e = estimate(side);
        assert!(
            matches!(&e.status, Status::NotIdentifiable(why) if why.contains("not used")),
            "{side}: {:?}",
            e.status
        );
    }
}

/// The bench of [`the_loss_surface_and_motor_constants_are_recovered_from_map_and_bode_logs`]:
/// the harmonic drive's loss surface scaled (positive-speed set x 1.2, negative-speed set x
/// 0.85) and, beyond [`TRUTH`], the motors' torque constants (+10 %, -10 %) and winding
/// resistances (+15 %) perturbed.
const SURFACE_SCALE: [f64; 2] = [1.2, 0.85];
const BROADER_TRUTH: [(&str, f64); 9] = [
    ("loadStaticFriction", 0.35 * 1.3),
    ("springStiffness", 340.54 * 0.9),
    ("actuationInertia", 0.825 * 1.2),
    ("loadInertia", 0.605 * 1.2),
    ("loadDamping", 1.0),
    ("testMotorTorqueConstant", 0.037 * 1.1),
    ("loadMotorTorqueConstant", 0.114 * 0.9),
    ("testMotorResistance", 0.608 * 1.15),
    ("loadMotorResistance", 1.1 * 1.15),
];

/// The default loss surface's coefficients (`hd-loss-surface.csv`): positive speed, negative.
fn default_surface() -> [Vec<f64>; 2] {
    use kneebench_harness::experiment::map::{DEFAULT_SURFACE, LossSurface};
    let s = LossSurface::parse(DEFAULT_SURFACE).unwrap();
    [
        s.terms.iter().map(|t| t.1).collect(),
        s.terms.iter().map(|t| t.2).collect(),
    ]
}

/// The FMU parameter of coefficient `k` (0-based, csv row order) of the set `side` (0
/// positive speed, 1 negative).
fn coefficient_name(side: usize, k: usize) -> String {
    let set = ["hdLossPositiveSpeed", "hdLossNegativeSpeed"][side];
    format!("{set}[{}]", k + 1)
}

/// The loss-surface round trip: the map at `torques` (the map's default load torques when
/// `None`) and a Bode sweep on each motor, recorded on the bench of [`BROADER_TRUTH`] and
/// [`SURFACE_SCALE`], identified; the motor constants and sensor offsets are checked, and every
/// surface coefficient reported as identified must contain the truth in its 95 % interval (or
/// be within 3 %), every other one be held at its prior (the default) for the map's box. Returns
/// the number of coefficients held and the largest relative error of the fitted surface at the
/// map's moving points.
fn surface_round_trip(torques: Option<Vec<f64>>) -> (Vec<(u8, u8)>, usize, f64) {
    use kneebench_harness::experiment::map;
    let dir = tempfile::tempdir().unwrap();
    let defaults = default_surface();
    let truth_surface: [Vec<f64>; 2] =
        [0, 1].map(|s| defaults[s].iter().map(|c| c * SURFACE_SCALE[s]).collect());
    let mut params: Vec<(String, String)> = BROADER_TRUTH
        .iter()
        .map(|(n, v)| (n.to_string(), format!("{v:?}")))
        .collect();
    for (side, coefficients) in truth_surface.iter().enumerate() {
        for (k, c) in coefficients.iter().enumerate() {
            params.push((coefficient_name(side, k), format!("{c:?}")));
        }
    }
    params.push(("frictionModel".into(), "3".into()));
    let bench = Bench::load(&plant_path(), params, None).unwrap();
    // The experiment set: the map (the bench's load torques, fewer speeds and shorter holds
    // than the bench's schedule) and a Bode sweep on each motor.
    let defaults_config = map::MapConfig::default();
    let map_config = map::MapConfig {
        speeds: vec![3.0, 10.0, 30.0, 60.0, 100.0, 150.0],
        settle: 1.0,
        measure: 0.5,
        torques: torques.unwrap_or(defaults_config.torques.clone()),
        ..defaults_config
    };
    let (r, map_log) = noisy_map_log(&bench, &map_config, dir.path(), 41);
    let mut logs = vec![map_log];
    logs.extend(noisy_bode_logs(&bench, dir.path(), 51));
    let config = IdentifyConfig {
        plant_parameters: vec![("frictionModel".into(), "3".into())],
        ..IdentifyConfig::default()
    };
    let id = identify(&logs, &plant_path(), None, &config).unwrap();
    let estimate = |name: &str| {
        id.estimates
            .iter()
            .find(|e| e.quantity.parameter == Some(name))
            .unwrap_or_else(|| panic!("no estimate of {name}"))
    };
    let mut report = String::new();
    let mut line = |name: &str, truth: f64| {
        let e = estimate(name);
        let (v, ci) = e.value();
        report.push_str(&format!(
            "{name}: {v} +- {ci} (truth {truth}, {:.2} %; linear {}) {:?}\n",
            100.0 * (v - truth) / truth,
            e.linear,
            e.status
        ));
    };
    for (name, truth) in BROADER_TRUTH {
        line(name, truth);
    }
    for (side, coefficients) in truth_surface.iter().enumerate() {
        for (k, truth) in coefficients.iter().enumerate() {
            line(&coefficient_name(side, k), *truth);
        }
    }
    eprintln!("{report}identification took {:.2} s", id.seconds);
    for (name, truth) in BROADER_TRUTH {
        let e = estimate(name);
        assert_eq!(e.status, Status::Identified, "{name}\n{report}");
        let (v, ci) = e.value();
        let err = (v - truth) / truth;
        let within_ci = (v - truth).abs() <= ci && ci < 0.1 * truth;
        assert!(err.abs() <= 0.03 || within_ci, "{name}\n{report}");
        assert_eq!(id.set.real(name), Some(v), "{name} in the written set");
    }
    // Every coefficient reported as identified: within 3 %, or the truth inside its 95 %
    // interval, which is narrower than 10 % (the intervals count the uncertainty of the
    // coefficients held at their prior, so they hold whatever the map's box leaves
    // undetermined). Every other one: reported as not excited by the map and held at its prior
    // (the default, not the truth) in the written set.
    let (mut held, mut conditional) = (Vec::new(), 0);
    for side in 0..2 {
        for (k, truth) in truth_surface[side].iter().enumerate() {
            let name = coefficient_name(side, k);
            let e = estimate(&name);
            match &e.status {
                Status::Identified => {
                    let (v, ci) = e.value();
                    assert!(ci.is_finite() && ci > 0.0, "{name}\n{report}");
                    assert_eq!(id.set.real(&name), Some(v), "{name} in the written set");
                    let within_ci = (v - truth).abs() <= ci && ci < 0.1 * truth.abs();
                    assert!(
                        (v - truth).abs() <= 0.03 * truth.abs() || within_ci,
                        "{name}\n{report}"
                    );
                }
                Status::Conditional(why) => {
                    // Written (the surface is one fit), not claimed on its own: its interval,
                    // which counts the held values' uncertainty, holds the truth.
                    let (v, ci) = e.value();
                    assert!(why.contains("fitted with the"), "{name}: {why}");
                    assert_eq!(id.set.real(&name), Some(v), "{name} in the written set");
                    assert!((v - truth).abs() <= ci, "{name}\n{report}");
                    conditional += 1;
                }
                Status::NotIdentifiable(why) => {
                    assert!(why.contains("does not excite"), "{name}: {why}");
                    assert_eq!(id.set.real(&name), Some(defaults[side][k]), "{name}");
                    held.push(kneebench_harness::identify::surface::TERMS[k]);
                }
            }
        }
    }
    // The fitted surface reproduces the true one within 3 % at every moving point of the map
    // (clamped to the plant's box, as the plant evaluates it).
    let fitted: [Vec<f64>; 2] = [0, 1].map(|side| {
        (0..21)
            .map(|k| id.set.real(&coefficient_name(side, k)).unwrap())
            .collect()
    });
    let surface = |c: &[Vec<f64>; 2], x: f64, y: f64| {
        use kneebench_harness::identify::surface::TERMS;
        let (x, y) = (x.clamp(-10.0, 15.0), y.clamp(-2.618, 2.618));
        let set = if y >= 0.0 { &c[0] } else { &c[1] };
        TERMS
            .iter()
            .zip(set)
            .map(|(&(i, j), p)| p * x.powi(i32::from(i)) * y.powi(i32::from(j)))
            .sum::<f64>()
    };
    let mut worst = 0.0f64;
    for p in r.points.iter().filter(|p| p.speed_command != 0.0) {
        let (f, t) = (
            surface(&fitted, p.load_torque, p.speed),
            surface(&truth_surface, p.load_torque, p.speed),
        );
        worst = worst.max((f - t).abs() / t.abs());
    }
    eprintln!("largest relative surface error at the map's points: {worst:.4}");
    assert!(worst <= 0.03, "{worst}\n{report}");
    // Sensor offsets: the load cell's (m g Lg sin c of its calibration phase), the current
    // sensors' offset and sensitivity (2.5 V, 0.1 V/A), each within its 95 % interval or 3 %;
    // the encoders' zeros reported as not identifiable.
    let moment = 1.94 * 9.81 * 0.25;
    let load_cell = id
        .estimates
        .iter()
        .find(|e| e.quantity.label == "load-cell torque offset")
        .expect("load-cell offset estimated");
    let (v, ci) = load_cell.value();
    let truth = moment * 0.019f64.sin();
    eprintln!("load-cell offset {v} +- {ci} (truth {truth})");
    assert_eq!(load_cell.status, Status::Identified);
    assert!((v - truth).abs() <= ci.max(0.03 * truth), "{v} +- {ci}");
    for (name, truth) in [
        ("currentSensorOffset", 2.5),
        ("currentSensorSensitivity", 0.1),
    ] {
        let e = estimate(name);
        let (v, ci) = e.value();
        eprintln!("{name}: {v} +- {ci} (truth {truth})");
        assert_eq!(e.status, Status::Identified, "{name}");
        assert!(
            (v - truth).abs() <= ci.max(0.03 * truth),
            "{name}: {v} +- {ci}"
        );
        assert_eq!(id.set.real(name), Some(v), "{name} in the written set");
    }
    for label in ["actuation encoder zero offset", "load encoder zero offset"] {
        let e = id
            .estimates
            .iter()
            .find(|e| e.quantity.label == label)
            .expect(label);
        assert!(
            matches!(&e.status, Status::NotIdentifiable(why) if why.contains("incremental")),
            "{label}: {:?}",
            e.status
        );
    }
    // The report lists the held coefficients under the experiment to add.
    let out = dir.path().join("identify");
    write_outputs(&id, &out).unwrap();
    let md = std::fs::read_to_string(out.join("identify.md")).unwrap();
    if !held.is_empty() {
        assert!(md.contains("more `--torques` levels"), "{md}");
    }
    if conditional > 0 {
        assert!(md.contains("### Conditional on held values"), "{md}");
        assert!(md.contains("**conditional** (written)"), "{md}");
    }
    (held, conditional, worst)
}

#[test]
fn the_loss_surface_and_motor_constants_are_recovered_from_map_and_bode_logs() {
    // The map's five default load torques cannot fix a polynomial of degree 5 in the load
    // torque: some coefficients are held, and are reported as such.
    let (held, conditional, _) = surface_round_trip(None);
    eprintln!(
        "{} coefficients held ({held:?}), {conditional} conditional with five load torques",
        held.len()
    );
    assert!(!held.is_empty() && held.len() < 21, "{held:?} held");
    assert!(held.iter().any(|&(i, j)| j == 0 && i >= 4), "{held:?} held");
}

#[test]
fn a_map_at_seven_load_torques_identifies_the_loss_surface_coefficients() {
    // Seven load torques over the gait's range (-9 ... 9 N m, the default's span) determine
    // the degree-5 polynomial in the load torque.
    let (held, conditional, _) =
        surface_round_trip(Some(vec![-9.0, -6.0, -3.0, 0.0, 3.0, 6.0, 9.0]));
    eprintln!(
        "{} coefficients held ({held:?}), {conditional} conditional with seven load torques",
        held.len()
    );
    // No term of order 4 or 5 in the load torque alone is held for want of torque levels.
    assert!(
        !held.iter().any(|&(i, j)| j == 0 && i >= 4),
        "{held:?} held"
    );
}
