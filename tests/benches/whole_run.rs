//! The whole `kneebench run` process on the study's SEA system, as a user runs it:
//! `cargo bench -p kneebench-tests --bench whole_run`.
//!
//! Three runs of `target/release/kneebench run SEA.ssp` (the study's SEA scenario, written
//! here from the exported FMUs), each a whole process:
//!
//! - **one signal**: 100 s at 1 ms recording `plant.loadAngle` every 1,000 rows into a CSV file
//!   (the README's "whole run" target: 3,000x real time);
//! - **every signal**: 100 s recording every output after every step into a Parquet file (the
//!   "every signal" target: 1,000x);
//! - **one step**: the fixed cost (start-up, loading, the files), `--stop-time 0.001`.
//!
//! Each output goes to a new file in `TMPDIR` (put it on a RAM file system, e.g.
//! `TMPDIR=/dev/shm`, to leave the disk out), removed after its repeat outside the timing:
//! replacing the file of the previous repeat would free its pages inside the timed run.
//!
//! Figures: the minimum and median of [`DEFAULT_REPEATS`] repeats (`KNEEBENCH_WHOLE_RUN_REPEATS`)
//! of wall and CPU time (user + system of the process, every thread), and real-time factors
//! (simulated seconds over wall or CPU seconds). **Baseline**: set
//! `KNEEBENCH_WHOLE_RUN_BASELINE` to another build's `kneebench` binary (e.g. a copy of the
//! previous commit's `target/release/kneebench`) and every repeat runs both, interleaved, and
//! prints baseline / this build (above 1: this build is faster). That binary runs this build's
//! FMUs: set `KNEEBENCH_WHOLE_RUN_BASELINE_FMUS` to a directory of another build's exported FMUs
//! (`kneebench export --out <dir> --library <its libkneebench_fmu.so>`) and the baseline runs
//! the same scenario written with those (with this build's binary unless
//! `KNEEBENCH_WHOLE_RUN_BASELINE` names another), so that a change of the FMUs shows too.
//! Without either, the one-step run is the baseline: the loop's own cost is a run's cost less
//! the fixed cost.
//!
//! The bench builds `kneebench` first (`cargo build --release -p kneebench-harness --bins`).

use std::path::{Path, PathBuf};
use std::process::Command;

use kneebench_harness::package::export_all;
use kneebench_tests::{fmu_library, write_sea_ssp};

#[path = "shared/process.rs"]
mod process;
use process::{Timing, build_kneebench, time_process};

/// Repeats of each run unless `KNEEBENCH_WHOLE_RUN_REPEATS` says otherwise.
const DEFAULT_REPEATS: usize = 7;

/// Simulated seconds of the long runs.
const STOP_TIME: f64 = 100.0;

/// One kind of run: its name, simulated seconds, output extension and extra arguments.
struct Case {
    name: &'static str,
    simulated: f64,
    extension: &'static str,
    args: &'static [&'static str],
}

const CASES: [Case; 3] = [
    Case {
        name: "one signal every 1,000 rows, CSV, 100 s",
        simulated: STOP_TIME,
        extension: "csv",
        args: &[
            "--stop-time",
            "100",
            "--variables",
            "plant.loadAngle",
            "--record-every",
            "1000",
        ],
    },
    Case {
        name: "every signal after every step, Parquet, 100 s",
        simulated: STOP_TIME,
        extension: "parquet",
        args: &["--stop-time", "100"],
    },
    Case {
        name: "one step (the fixed cost)",
        simulated: 0.001,
        extension: "csv",
        args: &["--stop-time", "0.001"],
    },
];

/// One whole `kneebench run` of `ssp` by `exe` into a new file of `dir`; the file is removed
/// after the timing.
fn run(exe: &Path, ssp: &Path, case: &Case, dir: &Path, repeat: usize) -> Timing {
    let output = dir.join(format!("out-{repeat}.{}", case.extension));
    let _ = std::fs::remove_file(&output);
    let mut cmd = Command::new(exe);
    cmd.arg("run")
        .arg(ssp)
        .args(case.args)
        .arg("--output")
        .arg(&output)
        .arg("-q");
    let (timing, _) = time_process(&mut cmd).unwrap_or_else(|e| panic!("{}: {e}", case.name));
    std::fs::remove_file(&output).expect("the run wrote its output");
    timing
}

/// Minimum and median.
fn min_median(mut v: Vec<f64>) -> (f64, f64) {
    v.sort_by(f64::total_cmp);
    (v[0], v[v.len() / 2])
}

/// Wall and CPU times of the repeats of one case, for one binary.
#[derive(Default)]
struct Times {
    wall: Vec<f64>,
    cpu: Vec<f64>,
}

impl Times {
    fn push(&mut self, t: Timing) {
        self.wall.push(t.wall);
        self.cpu.push(t.cpu);
    }

    /// ((min, median) wall, (min, median) CPU).
    fn summary(&self) -> ((f64, f64), (f64, f64)) {
        (min_median(self.wall.clone()), min_median(self.cpu.clone()))
    }
}

fn print_times(label: &str, times: &Times, simulated: f64) {
    let ((wall_min, wall_med), (cpu_min, cpu_med)) = times.summary();
    println!(
        "  {label:<9} wall {:8.1} ms (median {:8.1})  CPU {:8.1} ms (median {:8.1})  \
         median {:7.0}x real time (wall), {:7.0}x (CPU)",
        wall_min * 1e3,
        wall_med * 1e3,
        cpu_min * 1e3,
        cpu_med * 1e3,
        simulated / wall_med,
        simulated / cpu_med,
    );
}

fn main() {
    // `cargo bench` passes `--bench`; nothing to parse.
    let exe = build_kneebench().unwrap_or_else(|e| panic!("{e}"));
    let baseline = std::env::var_os("KNEEBENCH_WHOLE_RUN_BASELINE").map(PathBuf::from);
    if let Some(b) = &baseline {
        assert!(
            b.is_file(),
            "KNEEBENCH_WHOLE_RUN_BASELINE: {} is not a file",
            b.display()
        );
    }
    let baseline_fmus = std::env::var_os("KNEEBENCH_WHOLE_RUN_BASELINE_FMUS").map(PathBuf::from);
    if let Some(d) = &baseline_fmus {
        assert!(
            d.join("BenchPlant.fmu").is_file(),
            "KNEEBENCH_WHOLE_RUN_BASELINE_FMUS: {} has no BenchPlant.fmu",
            d.display()
        );
    }
    // Other FMUs alone: this build's binary runs them.
    let baseline = baseline.or_else(|| baseline_fmus.as_ref().map(|_| exe.clone()));
    let repeats = std::env::var("KNEEBENCH_WHOLE_RUN_REPEATS")
        .ok()
        .map(|r| {
            r.parse::<usize>()
                .ok()
                .filter(|&r| r > 0)
                .expect("KNEEBENCH_WHOLE_RUN_REPEATS is a positive number")
        })
        .unwrap_or(DEFAULT_REPEATS);

    let dir = tempfile::tempdir().unwrap();
    let fmus = dir.path().join("fmus");
    export_all(&fmu_library(), &fmus).expect("export");
    let (_, ssp) = write_sea_ssp(&fmus, dir.path());
    // The baseline's scenario: the same one, written with its FMUs when they differ.
    let base_ssp = match &baseline_fmus {
        Some(d) => {
            let base_dir = dir.path().join("baseline");
            std::fs::create_dir_all(&base_dir).unwrap();
            write_sea_ssp(d, &base_dir).1
        }
        None => ssp.clone(),
    };

    println!(
        "kneebench run SEA.ssp, whole process: {} (baseline: {}{}); {repeats} repeats, outputs in {}",
        exe.display(),
        baseline
            .as_deref()
            .map_or("none".into(), |b| b.display().to_string()),
        baseline_fmus.as_deref().map_or(String::new(), |d| format!(
            " with the FMUs of {}",
            d.display()
        )),
        dir.path().display()
    );
    let mut fixed_cpu = None;
    for case in CASES.iter().rev() {
        // Warm up: the page cache, the per-user binary cache.
        run(&exe, &ssp, case, dir.path(), 0);
        if let Some(b) = &baseline {
            run(b, &base_ssp, case, dir.path(), 0);
        }
        let (mut this, mut base) = (Times::default(), Times::default());
        for repeat in 0..repeats {
            // Which binary goes first alternates, so neither always follows the other.
            if let Some(b) = baseline.as_deref().filter(|_| repeat % 2 == 1) {
                base.push(run(b, &base_ssp, case, dir.path(), repeat));
            }
            this.push(run(&exe, &ssp, case, dir.path(), repeat));
            if let Some(b) = baseline.as_deref().filter(|_| repeat % 2 == 0) {
                base.push(run(b, &base_ssp, case, dir.path(), repeat));
            }
        }
        println!("{}:", case.name);
        print_times("this", &this, case.simulated);
        let ((_, this_wall), (_, this_cpu)) = this.summary();
        if baseline.is_some() {
            print_times("baseline", &base, case.simulated);
            let ((_, base_wall), (_, base_cpu)) = base.summary();
            println!(
                "  baseline / this (medians): wall {:.3}, CPU {:.3}",
                base_wall / this_wall,
                base_cpu / this_cpu
            );
        }
        match fixed_cpu {
            None => fixed_cpu = Some(this_cpu),
            Some(fixed) => println!(
                "  less the fixed cost ({:.1} ms CPU): the loop and its recording {:.1} ms CPU, \
                 {:.0}x real time",
                fixed * 1e3,
                (this_cpu - fixed) * 1e3,
                case.simulated / (this_cpu - fixed)
            ),
        }
    }
}
