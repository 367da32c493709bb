//! The hostile FMU through `kneebench run`: isolated by default (it is not a kneebench FMU), so
//! a segfault, abort, exit(0) or hang is an error of the run (exit code 1) that names the FMU,
//! the instance, the call and the signal or exit code, with every row up to the failure in
//! `OUTPUT.partial`; in process and isolated, every status and NaN/Inf outputs give the
//! documented exit code and files; in process (`--isolate never`) a segfault takes kneebench
//! down, leaving only the rows flushed so far (which is why isolation is the default for it).

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
            assert!(err.contains("kept 4 rows to "), "{err}");
            assert!(!d.path().join("r.csv").exists());
            assert_eq!(
                std::fs::read_to_string(d.path().join("r.csv.partial")).unwrap(),
                FOUR_ROWS
            );
            std::fs::remove_file(d.path().join("r.csv.partial")).unwrap();
        }
    }
}

#[test]
fn every_status_and_nonfinite_output_gives_the_documented_exit_code_and_file() {
    for (mode, extra, code, needle) in [
        (0, None, 0, None),
        (MODE_WARNING, None, 0, Some("hostile: warning at t=0.3")),
        (MODE_DISCARD, None, 3, Some("hostile: discard at t=0.3")),
        (
            MODE_ERROR,
            None,
            1,
            Some("fmi2DoStep returned Error (instance 'hostile')"),
        ),
        (
            MODE_FATAL,
            None,
            1,
            Some("fmi2DoStep returned Fatal (instance 'hostile')"),
        ),
        (
            MODE_PENDING,
            None,
            1,
            Some("fmi2DoStep returned Pending (instance 'hostile')"),
        ),
        (
            MODE_NAN,
            None,
            1,
            Some("component 'hostile': output 'y' is NaN at t = 0.4"),
        ),
        (
            MODE_INF,
            None,
            1,
            Some("component 'hostile': output 'y' is inf at t = 0.4"),
        ),
        (MODE_NAN, Some("--allow-nonfinite"), 0, None),
        (MODE_INF, Some("--allow-nonfinite"), 0, None),
    ] {
        for isolate in ["never", "always"] {
            let d = tempfile::tempdir().unwrap();
            let mut args = vec!["--isolate", isolate];
            args.extend(extra);
            let o = run(d.path(), mode, &args);
            let err = stderr(&o);
            let what = format!("mode {mode} {args:?}");
            assert_eq!(o.status.code(), Some(code), "{what}: {err}");
            if let Some(n) = needle {
                assert!(err.contains(n), "{what}: {err}");
            }
            // Completed or ended by the FMU: OUTPUT; failed: OUTPUT.partial, never OUTPUT.
            let (file, other) = if code == 1 {
                ("r.csv.partial", "r.csv")
            } else {
                ("r.csv", "r.csv.partial")
            };
            assert!(!d.path().join(other).exists(), "{what}");
            let csv = std::fs::read_to_string(d.path().join(file)).unwrap();
            match (mode, code) {
                (_, 1) | (MODE_DISCARD, _) => assert_eq!(csv, FOUR_ROWS, "{what}"),
                (MODE_NAN, 0) => {
                    assert_eq!(csv.lines().count(), 12, "{what}");
                    assert!(
                        csv.ends_with(
                            "0.4,NaN\n0.5,NaN\n0.6,NaN\n0.7,NaN\n0.8,NaN\n0.9,NaN\n1.0,NaN\n"
                        ),
                        "{csv}"
                    );
                }
                (MODE_INF, 0) => {
                    assert_eq!(csv.lines().count(), 12, "{what}");
                    assert!(csv.ends_with("0.9,inf\n1.0,inf\n"), "{csv}");
                }
                _ => assert_eq!(csv.lines().count(), 12, "{what}"),
            }
        }
    }
}

#[test]
fn in_process_a_segfault_takes_kneebench_down() {
    let d = tempfile::tempdir().unwrap();
    let o = run(d.path(), MODE_SEGFAULT, &["--isolate", "never"]);
    assert_eq!(o.status.signal(), Some(11), "{}", stderr(&o));
    assert!(!d.path().join("r.csv").exists());
}
