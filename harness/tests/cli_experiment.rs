//! `kneebench experiment`: a run the bench ended early says why on stderr (the reason is in its
//! section too) and exits with code 3; a `--param` value the bench would refuse is a usage error
//! (exit code 2).

mod common;

use std::path::Path;
use std::process::Command;

#[test]
fn a_step_whose_closed_loop_trips_says_why_and_exits_3() {
    let dir = tempfile::tempdir().unwrap();
    let fmus = common::exported_fmus(Path::new(env!("CARGO_BIN_EXE_kneebench")), dir.path());
    let run = |limit: &str| {
        Command::new(env!("CARGO_BIN_EXE_kneebench"))
            .args(["experiment", "step", "--fmu"])
            .arg(fmus.join("BenchPlant.fmu"))
            .args(["--param", &format!("motorTorqueLimit={limit}"), "--out"])
            .arg(dir.path().join("step"))
            .output()
            .unwrap()
    };
    // 5 N m: the open-loop reaction curve stays inside it, the closed-loop position step's
    // first push does not.
    let tripped = run("5");
    let stderr = String::from_utf8_lossy(&tripped.stderr);
    assert_eq!(tripped.status.code(), Some(3), "{stderr}");
    assert!(
        stderr.contains("step: the closed-loop run was ended at")
            && stderr.contains("test motor torque outside limit")
            && !stderr.contains("open-loop"),
        "{stderr}"
    );
    let section = std::fs::read_to_string(dir.path().join("step/step.md")).unwrap();
    assert!(
        section.contains("test motor torque outside limit"),
        "{section}"
    );
    // The default limit: both runs complete, nothing on stderr about an end.
    let completed = run("100");
    let stderr = String::from_utf8_lossy(&completed.stderr);
    assert_eq!(completed.status.code(), Some(0), "{stderr}");
    assert!(!stderr.contains("was ended"), "{stderr}");
}

/// A run that fails before its first row (the bench FMU refuses its parameters while starting:
/// the value is inside its declared range, and the plant refuses a transducer gain under a
/// microvolt, which no calibration could give) says so: the message said "the run
/// failed at t = None".
#[test]
fn a_run_that_fails_while_starting_says_so_without_none() {
    let dir = tempfile::tempdir().unwrap();
    let fmus = common::exported_fmus(Path::new(env!("CARGO_BIN_EXE_kneebench")), dir.path());
    let out = Command::new(env!("CARGO_BIN_EXE_kneebench"))
        .args(["experiment", "step", "--fmu"])
        .arg(fmus.join("BenchPlant.fmu"))
        .args(["--param", "transducerGain=1e-9", "--out"])
        .arg(dir.path().join("step"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("the run failed before its first row")
            && stderr.contains("sensor calibration gains must be at least 1e-6 V in magnitude"),
        "{stderr}"
    );
    assert!(!stderr.contains("None"), "{stderr}");
}

/// A `--param` value the bench FMU would refuse when the experiment starts (outside the
/// parameter's declared range, not of its type, not an item of its enumeration) is a bad
/// argument: refused with exit code 2 naming the parameter, before anything runs. It failed
/// the run with exit code 1.
#[test]
fn a_param_value_the_bench_refuses_is_a_usage_error_before_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let fmus = common::exported_fmus(Path::new(env!("CARGO_BIN_EXE_kneebench")), dir.path());
    for (param, expected) in [
        ("actuationInertia=0", "0 is outside [0.001, 100]"),
        ("frictionModel=Sticky", "is no item of FrictionModel"),
        ("actuationDamping=fast", "'fast' is not a number (a Real)"),
    ] {
        let out_dir = dir.path().join("step");
        let out = Command::new(env!("CARGO_BIN_EXE_kneebench"))
            .args(["experiment", "step", "--fmu"])
            .arg(fmus.join("BenchPlant.fmu"))
            .args(["--param", param, "--out"])
            .arg(&out_dir)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{param}: {stderr}");
        let name = param.split('=').next().unwrap();
        assert!(
            stderr.contains(name) && stderr.contains(expected),
            "{param}: {stderr}"
        );
        assert!(!stderr.contains("the run failed"), "{param}: {stderr}");
        assert!(!out_dir.join("step.md").exists(), "{param}");
    }
}
