//! The cost of FMU isolation (`kneebench_harness::isolate`): `cargo bench -p kneebench-tests
//! --bench isolation`.
//!
//! Two systems, each run in this process and isolated (every instance in a host process of its
//! own), interleaved, [`REPEATS`] times; the medians are compared in the same run:
//!
//! - **GaitReference** alone, 2.5 s at 1 kHz, every output recorded (1 FMU);
//! - **the study's SEA closed loop** (gait, position PID, torque PID, plant: 4 FMUs), one gait
//!   cycle at 1 kHz, recording the 13 signals the study analyses.
//!
//! Each run is a whole `System::run` (instantiate, initialize, step, terminate, free); for the
//! isolated runs that includes starting the host processes (the figure "start" below: one
//! isolated run of 1 step). Reported: the real-time factors, and the overhead per step and per
//! FMU and step, `(isolated - in process) / steps / FMUs` after subtracting the start cost. The
//! isolated rows are asserted bit-identical to the in-process rows.
//!
//! This executable is its own host process ([`serve_if_host`] first thing in `main`, the helper
//! set to itself), so it needs no other binary built.
//!
//! Measured (AMD EPYC, 2 shared cores): see the README's performance table.

use std::path::Path;
use std::time::{Duration, Instant};

use kneebench_harness::isolate::{HostOptions, Isolation, serve_if_host};
use kneebench_harness::package::export_all;
use kneebench_harness::study::Columns;
use kneebench_harness::{Fmu, LoadOptions, Outcome, RunConfig, RunOutput, System, ssp};
use kneebench_tests::*;

/// Interleaved repeats of each measurement.
const REPEATS: usize = 7;

fn options(isolation: Isolation) -> LoadOptions {
    LoadOptions {
        isolation,
        host: HostOptions {
            helper: Some(std::env::current_exe().expect("the bench's own path")),
            call_timeout: Duration::from_secs(60),
        },
        ..LoadOptions::default()
    }
}

fn run(system: &System, config: &RunConfig) -> (f64, RunOutput) {
    let start = Instant::now();
    let out = system.run(config).unwrap();
    let t = start.elapsed().as_secs_f64();
    assert!(
        matches!(out.outcome, Outcome::Completed { .. }),
        "{:?}",
        out.outcome
    );
    (t, out)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn bits(o: &RunOutput) -> Vec<Vec<u64>> {
    o.results
        .rows()
        .map(|r| r.iter().map(|x| x.to_bits()).collect())
        .collect()
}

/// Measures one system both ways and prints the comparison.
fn compare(title: &str, local: &System, isolated: &System, config: &RunConfig, fmus: usize) {
    let steps = ((config.stop_time - config.start_time) / config.step_size).round();
    let one_step = RunConfig {
        stop_time: config.start_time + config.step_size,
        ..config.clone()
    };
    // Warm up both (lazy initialization in the binaries, page cache).
    let (_, a) = run(local, config);
    let (_, b) = run(isolated, config);
    assert_eq!(bits(&a), bits(&b), "{title}: isolated rows differ");
    let (mut tl, mut ti, mut ts) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..REPEATS {
        tl.push(run(local, config).0);
        ti.push(run(isolated, config).0);
        ts.push(run(isolated, &one_step).0);
    }
    let (l, i, s) = (median(tl), median(ti), median(ts));
    let sim = config.stop_time - config.start_time;
    let per = (i - s - l) / steps / fmus as f64;
    println!("{title} ({fmus} FMUs, {steps} steps; medians of {REPEATS})");
    println!(
        "  in process: {:8.2} ms  {:7.0}x real time",
        l * 1e3,
        sim / l
    );
    println!(
        "  isolated:   {:8.2} ms  {:7.0}x real time  (start and stop of the hosts: {:.2} ms)",
        i * 1e3,
        sim / i,
        s * 1e3
    );
    println!(
        "  overhead:   {:.2} us per step, {:.2} us per FMU and step",
        per * fmus as f64 * 1e6,
        per * 1e6
    );
}

fn main() {
    serve_if_host();
    let dir = tempfile::tempdir().unwrap();
    let fmu_dir = dir.path().join("fmus");
    export_all(&fmu_library(), &fmu_dir).expect("export");

    // GaitReference alone, every output.
    let gait = |isolation| {
        let fmu = Fmu::load(fmu_dir.join("GaitReference.fmu"), &options(isolation)).unwrap();
        assert_eq!(fmu.is_isolated(), isolation == Isolation::Process);
        let mut s = System::new();
        s.add_component("gait", fmu).unwrap();
        s
    };
    let config = RunConfig {
        stop_time: 2.5,
        step_size: 1e-3,
        ..RunConfig::default()
    };
    compare(
        "GaitReference, every output",
        &gait(Isolation::InProcess),
        &gait(Isolation::Process),
        &config,
        1,
    );

    // The study's SEA loop.
    let (scenario, path) = write_sea_ssp(&fmu_dir, dir.path());
    let analysed = Columns::default().names();
    let names: Vec<&str> = analysed.iter().map(String::as_str).collect();
    let load = |path: &Path, isolation| {
        let mut l = ssp::load_system(path, &options(isolation)).unwrap();
        l.system.record(&names).unwrap();
        l
    };
    let local = load(&path, Isolation::InProcess);
    let isolated = load(&path, Isolation::Process);
    compare(
        "the study's SEA loop, the analysed signals",
        &local.system,
        &isolated.system,
        &local.config,
        scenario.components.len(),
    );
}
