//! The hostile FMU through `kneebench run`: isolated by default (it is not a kneebench FMU), so
//! a segfault, abort, exit(0) or hang is an error of the run (exit code 1) that names the FMU,
//! the instance, the call and the signal or exit code, with every row up to the failure in
//! `OUTPUT.partial`; in process and isolated, every status and NaN/Inf outputs give the
//! documented exit code and files; in process (`--isolate never`) a segfault or abort takes
//! kneebench down, leaving only the rows flushed so far (which is why isolation is the default
//! for it), an exit() is reported as an error (exit code 1, by the atexit hook) and a call that
//! never returns ends the process after `--timeout` and its grace (exit code 4).

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

/// `kneebench run Hostile.fmu --isolate never` 0..3 s in steps of 0.1 s, every step sleeping
/// 0.1 s of wall time, with `mode` firing in the step from 2.5: at least 2.5 s of wall time
/// pass before it, so the sink (flushed at least every second) has written rows to disk.
fn run_in_process_slowly(dir: &Path, mode: i32, extra: &[&str]) -> Output {
    let fmu = hostile_fmu(dir);
    kneebench()
        .arg("run")
        .arg(&fmu)
        .args([
            "--stop-time",
            "3",
            "--step",
            "0.1",
            "-q",
            "--isolate",
            "never",
        ])
        .args(["--param", &format!("mode={mode}"), "--param", "at=2.5"])
        .args([
            "--param",
            "pace=0.1",
            "--param",
            "u=1.5",
            "--variables",
            "y",
        ])
        .arg("--output")
        .arg(dir.join("r.csv"))
        .args(extra)
        .output()
        .unwrap()
}

/// The rows the failed run left in `r.csv.partial`: a non-empty prefix of the rows up to the
/// failure (t = 0..2.5), each line whole. Their number depends on when the last flush before
/// the failure came; the lower bound is one flush: the failure comes after at least 2.5 s of
/// wall time, and the sink flushes at least every second (1.5 s of slack for a late ticker on
/// a loaded machine).
fn assert_flushed_prefix(dir: &Path, what: &str) -> usize {
    assert!(!dir.join("r.csv").exists(), "{what}");
    let csv = std::fs::read_to_string(dir.join("r.csv.partial")).unwrap();
    let expected: Vec<String> = std::iter::once("time,y".to_string())
        .chain((0..=25).map(|k| format!("{:?},3.0", k as f64 / 10.0)))
        .collect();
    let lines: Vec<&str> = csv.lines().collect();
    assert!(csv.ends_with('\n'), "{what}: a cut line\n{csv}");
    assert!(lines.len() >= 2, "{what}: no row was flushed\n{csv}");
    assert!(
        lines.len() <= expected.len(),
        "{what}: rows past the failure\n{csv}"
    );
    for (line, want) in lines.iter().zip(&expected) {
        assert_eq!(line, want, "{what}\n{csv}");
    }
    lines.len() - 1
}

#[test]
fn in_process_a_crash_takes_kneebench_down_with_the_flushed_rows_on_disk() {
    for (mode, signal, log) in [
        (MODE_SEGFAULT, 11, "hostile: segfault at t=2.5"),
        (MODE_ABORT, 6, "hostile: abort at t=2.5"),
    ] {
        let d = tempfile::tempdir().unwrap();
        let o = run_in_process_slowly(d.path(), mode, &["--verbose"]);
        let err = stderr(&o);
        assert_eq!(o.status.signal(), Some(signal), "mode {mode}: {err}");
        // The FMU's last words reach the terminal before the process dies.
        assert!(err.contains(log), "mode {mode}: {err}");
        assert_flushed_prefix(d.path(), &format!("mode {mode}"));
    }
}

#[test]
fn in_process_an_fmu_calling_exit_is_an_error_not_a_success() {
    let d = tempfile::tempdir().unwrap();
    let o = run_in_process_slowly(d.path(), MODE_EXIT, &[]);
    let err = stderr(&o);
    // The FMU called exit(0); kneebench reports it and ends with code 1.
    assert_eq!(o.status.code(), Some(1), "{err}");
    let partial = d.path().join("r.csv.partial");
    assert!(
        err.contains(&format!(
            "error: an FMU called exit() during fmi2DoStep of FMU 'Hostile', instance 'hostile'; \
             the run did not finish; the rows flushed so far are in {}",
            partial.display()
        )),
        "{err}"
    );
    assert_flushed_prefix(d.path(), "exit");
    // kneebench's own exit after a run passes the hook: a completed run ends with 0.
    let ok = run(d.path(), 0, &["--isolate", "never"]);
    assert_eq!(ok.status.code(), Some(0), "{}", stderr(&ok));
    assert!(d.path().join("r.csv").is_file());
}

#[test]
fn in_process_a_call_that_never_returns_ends_after_the_timeout_and_its_grace() {
    let d = tempfile::tempdir().unwrap();
    let started = std::time::Instant::now();
    // The hang starts after at least 2.5 s; --timeout 6 s (generous for a loaded machine: the
    // run must reach the hang before the limit), then the 5 s grace.
    let o = run_in_process_slowly(d.path(), MODE_HANG, &["--timeout", "6"]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(4), "{err}");
    assert!(
        err.contains(
            "error: --timeout (6 s) passed 5 s ago and fmi2DoStep of FMU 'Hostile', instance \
             'hostile' has not returned"
        ),
        "{err}"
    );
    assert!(err.contains("the rows flushed so far are in "), "{err}");
    // Not before the limit and its grace.
    assert!(started.elapsed() >= std::time::Duration::from_secs(11));
    assert_flushed_prefix(d.path(), "hang");
}

/// Whether any process is left in process group `pgid`.
fn group_alive(pgid: i32) -> bool {
    // SAFETY: kill with signal 0 only checks for existence and permission.
    unsafe { libc::kill(-pgid, 0) == 0 }
}

#[test]
fn a_terminal_ctrl_c_stops_an_isolated_run_with_its_rows_and_its_hosts_gone() {
    use std::os::unix::process::CommandExt;
    let d = tempfile::tempdir().unwrap();
    let fmu = hostile_fmu(d.path());
    // A 100 s run at 0.05 s of wall time per step, isolated (the default for this FMU), in a
    // process group of its own, as a shell puts a foreground job.
    let mut child = kneebench()
        .arg("run")
        .arg(&fmu)
        .args(["--stop-time", "100", "--step", "0.1", "-q"])
        .args([
            "--param",
            "pace=0.05",
            "--param",
            "u=1.5",
            "--variables",
            "y",
        ])
        .arg("--output")
        .arg(d.path().join("r.csv"))
        .process_group(0)
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let pgid = child.id() as i32;
    // Until a flush has written rows (the sink flushes every second).
    let partial = d.path().join("r.csv.partial");
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    while std::fs::read_to_string(&partial).map_or(true, |c| c.lines().count() < 3) {
        assert!(
            std::time::Instant::now() < deadline,
            "no rows flushed in 60 s"
        );
        assert!(child.try_wait().unwrap().is_none(), "the run ended early");
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    // What a terminal's Ctrl-C does: SIGINT to every process of the foreground group, the
    // FMU's host process included.
    // SAFETY: a signal to a process group this test created.
    assert_eq!(unsafe { libc::kill(-pgid, libc::SIGINT) }, 0);
    let o = child.wait_with_output().unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(130), "{err}");
    assert!(err.contains("stopped: interrupted (SIGINT)"), "{err}");
    assert!(!err.contains("crashed"), "{err}");
    assert!(!d.path().join("r.csv").exists());
    let csv = std::fs::read_to_string(&partial).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert!(lines.len() >= 3, "{csv}");
    assert_eq!(lines[0], "time,y");
    for (k, line) in lines[1..].iter().enumerate() {
        assert_eq!(*line, format!("{:?},3.0", k as f64 / 10.0), "{csv}");
    }
    // The host ended with its master (its socket closed): nothing is left in the group.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    while group_alive(pgid) {
        assert!(
            std::time::Instant::now() < deadline,
            "a process of the run's group is still alive 10 s after it ended"
        );
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
}
