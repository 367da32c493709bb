//! The hostile FMU through `kneebench run`: isolated by default (it is not a kneebench FMU), so
//! a segfault, abort, exit(0) or hang is an error of the run (exit code 1) that names the FMU,
//! the instance, the call and the signal or exit code, with the rows up to the failure on disk;
//! in process (`--isolate never`) every status and NaN/Inf outputs give the documented exit
//! code, and a segfault takes kneebench down (which is why isolation is the default for it).

mod hostile_fmu;

use std::os::unix::process::ExitStatusExt;
use std::path::Path;
use std::process::{Command, Output};

use hostile_fmu::*;

fn kneebench() -> Command {
    Command::new(env!("CARGO_BIN_EXE_kneebench"))
}

/// `kneebench run Hostile.fmu` 0..1 s in steps of 0.1 s with `mode` firing in the step from
/// 0.3, u = 1.5, writing `r.csv` in `dir`.
fn run(dir: &Path, mode: i32, extra: &[&str]) -> Output {
    let fmu = hostile_fmu(dir);
    kneebench()
        .arg("run")
        .arg(&fmu)
        .args(["--stop-time", "1", "--step", "0.1", "-q"])
        .args(["--param", &format!("mode={mode}"), "--param", "at=0.3"])
        .args(["--param", "u=1.5", "--variables", "y"])
        .arg("--output")
        .arg(dir.join("r.csv"))
        .args(extra)
        // Every call of these runs is bounded by this (the hang ends after it); generous for a
        // loaded machine.
        .env("KNEEBENCH_FMU_CALL_TIMEOUT", "4")
        .output()
        .unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

const FOUR_ROWS: &str = "time,y\n0.0,3.0\n0.1,3.0\n0.2,3.0\n0.3,3.0\n";

#[test]
fn isolated_crashes_exits_and_hangs_are_errors_with_the_rows_on_disk() {
    for (mode, what, log) in [
        (
            MODE_SEGFAULT,
            "the FMU's process crashed (signal 11, SIGSEGV)",
            "hostile: segfault at t=0.3",
        ),
        (
            MODE_ABORT,
            "the FMU's process crashed (signal 6, SIGABRT)",
            "hostile: abort at t=0.3",
        ),
        (
            MODE_EXIT,
            "the FMU ended its process (exit code 0)",
            "hostile: exit(0) at t=0.3",
        ),
        (
            MODE_HANG,
            "no answer within 4 s (call timeout); the FMU's process was killed",
            "hostile: hang at t=0.3",
        ),
    ] {
        let d = tempfile::tempdir().unwrap();
        // The default is isolation for an FMU kneebench did not generate; `always` is the same.
        for extra in [&[][..], &["--isolate", "always"][..]] {
            let o = run(d.path(), mode, extra);
            let err = stderr(&o);
            assert_eq!(o.status.code(), Some(1), "mode {mode} {extra:?}: {err}");
            assert!(
                err.contains(
                    "component 'hostile' at t = 0.3: FMU 'Hostile', instance 'hostile': fmi2DoStep: "
                ),
                "{err}"
            );
            assert!(err.contains(what), "{err}");
            assert!(err.contains(log), "{err}");
            // A failed run keeps its rows in the partial file and writes no results file.
            assert_eq!(
                std::fs::read_to_string(d.path().join("r.csv.partial")).unwrap(),
                FOUR_ROWS
            );
            assert!(!d.path().join("r.csv").exists());
        }
    }
}

#[test]
fn in_process_every_status_gives_the_documented_exit_code() {
    for (mode, code, needle) in [
        (0, 0, None),
        (MODE_WARNING, 0, Some("hostile: warning at t=0.3")),
        (MODE_DISCARD, 3, Some("hostile: discard at t=0.3")),
        (
            MODE_ERROR,
            1,
            Some("fmi2DoStep returned Error (instance 'hostile')"),
        ),
        (
            MODE_FATAL,
            1,
            Some("fmi2DoStep returned Fatal (instance 'hostile')"),
        ),
        (
            MODE_PENDING,
            1,
            Some("fmi2DoStep returned Pending (instance 'hostile')"),
        ),
        // A non-finite output ends the run with an error naming it (issue 14 item 6).
        (MODE_NAN, 1, Some("output 'y' is NaN at t = 0.4")),
        (MODE_INF, 1, Some("output 'y' is")),
    ] {
        for isolate in ["never", "always"] {
            let d = tempfile::tempdir().unwrap();
            let o = run(d.path(), mode, &["--isolate", isolate]);
            let err = stderr(&o);
            assert_eq!(o.status.code(), Some(code), "mode {mode} {isolate}: {err}");
            if let Some(n) = needle {
                assert!(err.contains(n), "mode {mode} {isolate}: {err}");
            }
            let file = if code == 1 { "r.csv.partial" } else { "r.csv" };
            let csv = std::fs::read_to_string(d.path().join(file)).unwrap();
            let rows = csv.lines().count() - 1;
            match mode {
                MODE_ERROR | MODE_FATAL | MODE_PENDING | MODE_NAN | MODE_INF => {
                    assert_eq!(csv, FOUR_ROWS, "mode {mode} {isolate}")
                }
                // The FMU ended the run at 0.3: its row at the last successful time is the last.
                MODE_DISCARD => assert_eq!(csv, FOUR_ROWS, "mode {mode} {isolate}"),
                _ => assert_eq!(rows, 11, "mode {mode} {isolate}"),
            }
        }
    }
    // --allow-nonfinite records them instead.
    for (mode, last) in [(MODE_NAN, "1.0,NaN\n"), (MODE_INF, "1.0,inf\n")] {
        let d = tempfile::tempdir().unwrap();
        let o = run(d.path(), mode, &["--isolate", "never", "--allow-nonfinite"]);
        assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
        let csv = std::fs::read_to_string(d.path().join("r.csv")).unwrap();
        assert_eq!(csv.lines().count() - 1, 11);
        assert!(csv.ends_with(last), "{csv}");
    }
}

#[test]
fn in_process_a_segfault_takes_kneebench_down() {
    let d = tempfile::tempdir().unwrap();
    let o = run(d.path(), MODE_SEGFAULT, &["--isolate", "never"]);
    assert_eq!(o.status.signal(), Some(11), "{}", stderr(&o));
    assert!(!d.path().join("r.csv").exists());
}
