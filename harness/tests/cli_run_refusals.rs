//! `kneebench run` refuses what it can check before anything runs, and a refusal changes no
//! file: a `--param` value outside the variable's declared range, not finite, not one of its
//! items, or for a variable that takes no value before initialization is a usage error (exit
//! 2) named with its bounds; a usage error leaves an earlier run's partial file where it is;
//! a run that fails before its first row leaves no empty partial file behind; an `--inputs`
//! file naming a column twice is refused naming the file and the column.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

fn kneebench() -> Command {
    Command::new(env!("CARGO_BIN_EXE_kneebench"))
}

fn run(dir: &Path, fmu: &Path, args: &[&str]) -> (Option<i32>, String) {
    let o: Output = kneebench()
        .current_dir(dir)
        .arg("run")
        .arg(fmu)
        .args(["-q", "--output", "r.csv", "--stop-time", "0.01"])
        .args(args)
        .output()
        .unwrap();
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// The bench's FMUs, exported once for every test of this file (under the target directory:
/// a static is never dropped, so a temporary directory would be left behind).
fn fmus() -> &'static Path {
    static FMUS: OnceLock<PathBuf> = OnceLock::new();
    FMUS.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("cli_run_refusals");
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        common::exported_fmus(Path::new(env!("CARGO_BIN_EXE_kneebench")), &dir)
    })
}

/// The files of `dir` whose names start with `r.csv`, sorted.
fn outputs(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("r.csv"))
        .collect();
    names.sort();
    names
}

#[test]
fn param_values_the_fmu_would_refuse_are_usage_errors_and_change_no_file() {
    let d = tempfile::tempdir().unwrap();
    let fmus = fmus();
    let earlier = "time,x\n0,1\n";
    std::fs::write(d.path().join("r.csv.partial"), earlier).unwrap();
    let gait = fmus.join("GaitReference.fmu");
    let pid = fmus.join("PidController.fmu");
    let plant = fmus.join("BenchPlant.fmu");
    for (fmu, param, says) in [
        (&gait, "gaitPeriod=-1", "-1 is outside [0.01, 10000]"),
        (&gait, "gaitPeriod=nan", "NaN is not a finite number"),
        (&plant, "configuration=7", "7 is outside [0, 2]"),
        (&plant, "actuationInertia=0", "is outside"),
        (
            &pid,
            "u=1",
            "u (causality output, variability continuous) takes no value",
        ),
        // Not NAME=VALUE at all: refused by the parser, also before any file is touched.
        (&gait, "gaitPeriod", "expected NAME=VALUE"),
    ] {
        let (code, err) = run(d.path(), fmu, &["--param", param]);
        assert_eq!(code, Some(2), "{param}: {err}");
        assert!(err.contains(says), "{param}: {err}");
        assert!(
            err.contains(&format!("--param '{param}'")),
            "{param}: {err}"
        );
        // The earlier run's partial file is untouched, no new file appeared.
        assert_eq!(outputs(d.path()), ["r.csv.partial"], "{param}");
        assert_eq!(
            std::fs::read_to_string(d.path().join("r.csv.partial")).unwrap(),
            earlier
        );
    }
    // Values inside the range, an item by its name, an input's start value: they run.
    for (fmu, param) in [
        (&gait, "gaitPeriod=2"),
        (&plant, "configuration=SEA"),
        (&pid, "setpoint=1"),
    ] {
        std::fs::remove_file(d.path().join("r.csv")).ok();
        let (code, err) = run(d.path(), fmu, &["--param", param]);
        assert_eq!(code, Some(0), "{param}: {err}");
        assert!(d.path().join("r.csv").is_file(), "{param}");
    }
}

#[test]
fn a_run_failing_before_its_first_row_leaves_no_partial_file() {
    let d = tempfile::tempdir().unwrap();
    let fmus = fmus();
    // A combination only the FMU's own consistency check refuses, at the end of
    // initialization: the Udp backend without real-time pacing.
    let (code, err) = run(
        d.path(),
        &fmus.join("BenchHardware.fmu"),
        &["--param", "backend=Udp"],
    );
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("needs real-time pacing"), "{err}");
    assert!(
        err.contains("recorded no rows: r.csv.partial removed"),
        "{err}"
    );
    assert!(outputs(d.path()).is_empty(), "{:?}", outputs(d.path()));
    // Twice: nothing piles up.
    let (code, _) = run(
        d.path(),
        &fmus.join("BenchHardware.fmu"),
        &["--param", "backend=Udp"],
    );
    assert_eq!(code, Some(1));
    assert!(outputs(d.path()).is_empty(), "{:?}", outputs(d.path()));
}

#[test]
fn an_inputs_file_naming_a_column_twice_is_refused_naming_it() {
    let d = tempfile::tempdir().unwrap();
    let fmus = fmus();
    std::fs::write(
        d.path().join("in.csv"),
        "time,setpoint,setpoint\n0,1,5\n1,2,6\n",
    )
    .unwrap();
    let (code, err) = run(
        d.path(),
        &fmus.join("PidController.fmu"),
        &["--inputs", "in.csv"],
    );
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("--inputs in.csv: column 'setpoint' appears twice"),
        "{err}"
    );
    assert!(outputs(d.path()).is_empty(), "{:?}", outputs(d.path()));
}
