//! `kneebench experiment`: a run the bench ended early says why on stderr (the reason is in its
//! section too) and exits with code 3.

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

/// A run that fails before its first row (the bench FMU refuses a parameter while starting)
/// says so: the message said "the run failed at t = None".
#[test]
fn a_run_that_fails_while_starting_says_so_without_none() {
    let dir = tempfile::tempdir().unwrap();
    let fmus = common::exported_fmus(Path::new(env!("CARGO_BIN_EXE_kneebench")), dir.path());
    let out = Command::new(env!("CARGO_BIN_EXE_kneebench"))
        .args(["experiment", "step", "--fmu"])
        .arg(fmus.join("BenchPlant.fmu"))
        .args(["--param", "actuationInertia=0", "--out"])
        .arg(dir.path().join("step"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("the run failed before its first row")
            && stderr.contains("actuationInertia"),
        "{stderr}"
    );
    assert!(!stderr.contains("None"), "{stderr}");
}
