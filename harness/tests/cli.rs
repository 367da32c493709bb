//! The `kneebench` binary: exit codes and files written.

mod common;

use std::path::Path;
use std::process::{Command, Output};

fn kneebench() -> Command {
    Command::new(env!("CARGO_BIN_EXE_kneebench"))
}

/// `kneebench run` of the test FMU `fmu` for 1 s at 0.1 s with `u = 1`, into `csv`.
fn run_kbtest(fmu: &Path, csv: &Path, extra: &[&str]) -> Output {
    run_kbtest_until("1", fmu, csv, extra)
}

/// [`run_kbtest`] for `stop_time` seconds, into `output` (CSV, or Parquet by its extension).
fn run_kbtest_until(stop_time: &str, fmu: &Path, output: &Path, extra: &[&str]) -> Output {
    kneebench()
        .arg("run")
        .arg(fmu)
        .args([
            "--stop-time",
            stop_time,
            "--step",
            "0.1",
            "--param",
            "u=1",
            "--output",
        ])
        .arg(output)
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn exit_codes_and_partial_results() {
    let d = tempfile::tempdir().unwrap();
    let fmu = common::kbtest_fmu(d.path());
    let csv = d.path().join("r.csv");
    let run = |extra: &[&str]| run_kbtest(&fmu, &csv, &[&["-q"], extra].concat());
    let ok = run(&[]);
    assert_eq!(
        ok.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );
    assert_eq!(std::fs::read_to_string(&csv).unwrap().lines().count(), 12);

    let term = run(&["--param", "discard_at=0.45", "--variables", "x"]);
    assert_eq!(term.status.code(), Some(3));
    assert_eq!(
        std::fs::read_to_string(&csv).unwrap(),
        "time,x\n0.0,0.0\n0.1,1.0\n0.2,2.0\n0.3,3.0\n0.4,4.0\n0.45,4.5\n"
    );

    let before = std::fs::read_to_string(&csv).unwrap();
    let err = run(&["--param", "error_at=0.25", "--variables", "x"]);
    assert_eq!(err.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&err.stderr).contains("error requested"));
    // The failed run keeps its rows in the partial file; the earlier results are untouched.
    assert_eq!(std::fs::read_to_string(&csv).unwrap(), before);
    assert_eq!(
        std::fs::read_to_string(d.path().join("r.csv.partial")).unwrap(),
        "time,x\n0.0,0.0\n0.1,1.0\n0.2,2.0\n"
    );

    let usage = kneebench().args(["run", "--bogus"]).output().unwrap();
    assert_eq!(usage.status.code(), Some(2));

    let valid = kneebench().arg("validate").arg(&fmu).output().unwrap();
    assert_eq!(valid.status.code(), Some(0));
    let bad = d.path().join("guid.fmu");
    common::write_fmu(
        &bad,
        &common::FmuSpec {
            model_description: Some(common::model_description("{other}")),
            ..common::FmuSpec::default()
        },
    );
    let invalid = kneebench().arg("validate").arg(&bad).output().unwrap();
    assert_eq!(invalid.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&invalid.stdout).contains("GUID mismatch"));

    let svg = d.path().join("p.svg");
    let plot = kneebench()
        .arg("plot")
        .arg(&csv)
        .args(["--signals", "x", "--out"])
        .arg(&svg)
        .output()
        .unwrap();
    assert_eq!(plot.status.code(), Some(0));
    assert!(std::fs::read_to_string(&svg).unwrap().contains("<svg"));
}

/// `kneebench ... | head`: the closed pipe ends the process quietly (SIGPIPE), no panic.
#[cfg(unix)]
#[test]
fn a_closed_stdout_pipe_ends_quietly() {
    use std::io::Read;
    use std::os::unix::process::ExitStatusExt;
    use std::process::Stdio;
    let d = tempfile::tempdir().unwrap();
    let fmu = common::kbtest_fmu(d.path());
    let mut child = kneebench()
        .arg("info")
        .arg(&fmu)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Close our end of the pipe at once: the program's first line meets a closed pipe (it takes
    // milliseconds to start and load the FMU before it prints anything).
    drop(child.stdout.take());
    let mut stderr = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut stderr)
        .unwrap();
    let status = child.wait().unwrap();
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(
        status.success() || status.signal() == Some(13),
        "{status:?}: {stderr}"
    );
}

/// `kneebench study --bench` needs the bench's key and one actuator, refused before anything
/// runs (no FMU is read, nothing is written): usage errors (exit code 2) naming the rule. A
/// study of several actuators (or of all, none named) on a bench exited with 1, refused only
/// as its first run began.
#[test]
fn a_bench_study_without_its_key_or_its_actuator_is_refused() {
    let out = tempfile::tempdir().unwrap();
    let o = kneebench()
        .args(["study", "--fmus", "no-such-dir", "--bench", "127.0.0.1:9"])
        .arg("--out")
        .arg(out.path())
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("--key"), "{e}");
    let key = out.path().join("bench.key");
    for (actuators, given) in [
        (&[][..], "(given: all)"),
        (&["--actuators", "sea,csea"], "(given: SEA, CSEA)"),
        (
            &["--scenario", "bench-clutch", "--actuators", "sea,csea"],
            "(given: SEA, CSEA)",
        ),
    ] {
        let o = kneebench()
            .args([
                "study",
                "--fmus",
                "no-such-dir",
                "--bench",
                "127.0.0.1:9",
                "--key",
            ])
            .arg(&key)
            .args(actuators)
            .arg("--out")
            .arg(out.path().join("study"))
            .output()
            .unwrap();
        let e = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{actuators:?}: {e}");
        assert!(
            e.contains("--bench: on a bench the study runs one actuator")
                && e.contains("--actuators sea")
                && e.contains(given),
            "{actuators:?}: {e}"
        );
        assert!(!out.path().join("study").exists(), "{actuators:?}");
    }
    // One actuator, named twice, is one actuator: refused next for the missing FMUs.
    let o = kneebench()
        .args([
            "study",
            "--fmus",
            "no-such-dir",
            "--bench",
            "127.0.0.1:9",
            "--key",
        ])
        .arg(&key)
        .args(["--actuators", "sea,SEA", "--out"])
        .arg(out.path().join("study"))
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!e.contains("one actuator"), "{e}");
}

/// A study run that fails (here the torque loop's FMU refuses outputMin > outputMax when the
/// run starts, a combination no single bound catches) is reported as a failed run, not as an
/// interlock trip: the command exits with 1 (3 is for trips), names the failed runs, and
/// report.md says why each failed, with no column of NaN for it in the table and no
/// "run failed" in its interlock row.
#[test]
fn a_failed_study_run_is_reported_as_failed_not_as_a_trip() {
    let d = tempfile::tempdir().unwrap();
    let fmus = common::exported_fmus(
        std::path::Path::new(env!("CARGO_BIN_EXE_kneebench")),
        d.path(),
    );
    let out = d.path().join("study");
    let o = kneebench()
        .args([
            "study",
            "--scenario",
            "bench-full",
            "--actuators",
            "da",
            "--cycles",
            "2",
            "--param",
            "torque.outputMin=100",
            "--fmus",
        ])
        .arg(&fmus)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(e.contains("1 run(s) failed (bench-full DA)"), "{e}");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(
        report.contains("**DA: the run failed** at t = 0 s")
            && report.contains("outputMin 100 is above outputMax"),
        "{report}"
    );
    assert!(!report.contains("NaN"), "{report}");
    assert!(!report.contains("| interlock trip |"), "{report}");
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("**DA: the run failed**"), "{stdout}");
    assert!(!stdout.contains("NaN"), "{stdout}");
}

/// `kneebench emulate` refuses a heartbeat timeout outside the protocol's range (above 0.1 s,
/// docs/bench-protocol.md section 7; zero, negative, NaN) and a duration that is not a finite
/// number of seconds above 0 and up to a year, before it opens a socket or loads the plant (the FMU path
/// named here does not exist, so a refusal that came later would name it instead).
#[test]
fn emulate_refuses_arguments_outside_the_protocols_limits() {
    let d = tempfile::tempdir().unwrap();
    let fmu = d.path().join("missing/BenchPlant.fmu");
    for (args, needle) in [
        (
            &["--heartbeat-timeout", "0.2"][..],
            "must not exceed 0.1 s (docs/bench-protocol.md, §7)",
        ),
        (
            &["--heartbeat-timeout", "0.10001"][..],
            "must not exceed 0.1 s",
        ),
        (
            &["--heartbeat-timeout", "0"][..],
            "must be a positive number of seconds",
        ),
        (
            &["--heartbeat-timeout", "NaN"][..],
            "must be a positive number of seconds",
        ),
        (&["--duration", "NaN"][..], "--duration"),
        (&["--duration", "1e300"][..], "--duration"),
        // 0 served for no time and exited 0; without --duration it runs until interrupted.
        (&["--duration", "0"][..], "above 0"),
    ] {
        let o = kneebench()
            .args(["emulate", "--bind", "127.0.0.1:0", "--fmu"])
            .arg(&fmu)
            .args(args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        // A usage error, refused while the command line is parsed.
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(err.contains(needle), "{args:?}: {err}");
        assert!(err.contains(args[0]), "{args:?}: {err}");
        assert!(!err.contains("missing"), "{args:?}: {err}");
    }
    // At the limit it is accepted: the run gets as far as the missing FMU.
    let o = kneebench()
        .args([
            "emulate",
            "--bind",
            "127.0.0.1:0",
            "--heartbeat-timeout",
            "0.1",
        ])
        .args(["--duration", "1", "--fmu"])
        .arg(&fmu)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("missing"), "{err}");
}

/// An output that names one of the command's inputs (however spelled) is refused before
/// anything runs, and the input is left as it was: the results renamed into place would
/// have replaced the FMU, the inputs CSV or the sweep's spec.
#[test]
fn an_output_that_is_an_input_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let fmu = common::kbtest_fmu(d.path());
    let before = std::fs::read(&fmu).unwrap();
    let inputs = d.path().join("inputs.csv");
    std::fs::write(&inputs, "time,u\n0,1\n1,1\n").unwrap();
    let spelled_otherwise = d.path().join(".").join(fmu.file_name().unwrap());
    for (output, extra) in [
        (&spelled_otherwise, vec![]),
        (
            &inputs,
            vec!["--inputs".to_string(), inputs.display().to_string()],
        ),
    ] {
        let out = kneebench()
            .arg("run")
            .arg(&fmu)
            .args(["--stop-time", "1", "--step", "0.1", "-q"])
            .args(&extra)
            .arg("--output")
            .arg(output)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{stderr}");
        assert!(stderr.contains("the results would replace it"), "{stderr}");
    }
    assert_eq!(std::fs::read(&fmu).unwrap(), before);
    assert_eq!(
        std::fs::read_to_string(&inputs).unwrap(),
        "time,u\n0,1\n1,1\n"
    );
    let spec = d.path().join("spec.toml");
    std::fs::write(&spec, "not read: the output is checked first\n").unwrap();
    for command in ["sweep", "optimize"] {
        let out = kneebench()
            .arg(command)
            .arg(&spec)
            .arg("--output")
            .arg(&spec)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{command}: {stderr}");
        assert!(stderr.contains("the results would replace it"), "{stderr}");
    }
    assert_eq!(
        std::fs::read_to_string(&spec).unwrap(),
        "not read: the output is checked first\n"
    );
}

/// `kneebench sweep` refuses an output that is one of the sweep's inputs besides its spec (the
/// design CSV, a scenario's FMU), with exit code 2, and leaves it as it was: the table
/// replaced it before (only the spec was checked).
#[test]
fn a_sweep_output_that_is_its_design_or_an_fmu_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let fmus = common::exported_fmus(
        std::path::Path::new(env!("CARGO_BIN_EXE_kneebench")),
        d.path(),
    );
    let csv = d.path().join("points.csv");
    std::fs::write(&csv, "plant.springStiffness\n300\n").unwrap();
    let spec = d.path().join("s.toml");
    std::fs::write(
        &spec,
        format!(
            "system = \"SEA\"\nfmus = \"{}\"\ncycles = 2\n[design]\nkind = \"csv\"\n\
             file = \"points.csv\"\n[[parameters]]\nname = \"plant.springStiffness\"\n",
            fmus.display()
        ),
    )
    .unwrap();
    let plant = fmus.join("BenchPlant.fmu");
    let fmu_before = std::fs::read(&plant).unwrap();
    for output in [&csv, &plant] {
        let out = kneebench()
            .arg("sweep")
            .arg(&spec)
            .arg("--output")
            .arg(output)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{stderr}");
        assert!(stderr.contains("the results would replace it"), "{stderr}");
    }
    assert_eq!(
        std::fs::read_to_string(&csv).unwrap(),
        "plant.springStiffness\n300\n"
    );
    assert_eq!(std::fs::read(&plant).unwrap(), fmu_before);
}

/// Ctrl-C during `kneebench sweep` stops it with exit code 130 and says how many points are
/// done and that `--resume` continues; the journal keeps those rows, and `--resume` finishes
/// the table. Before, the process died of the signal without a word.
#[test]
fn an_interrupted_sweep_says_how_far_it_got_and_resumes() {
    let d = tempfile::tempdir().unwrap();
    let fmus = common::exported_fmus(
        std::path::Path::new(env!("CARGO_BIN_EXE_kneebench")),
        d.path(),
    );
    let spec = d.path().join("s.toml");
    let values: Vec<String> = (0..40).map(|k| format!("{}.0", 250 + k)).collect();
    std::fs::write(
        &spec,
        format!(
            "system = \"SEA\"\nfmus = \"{}\"\ncycles = 4\n[design]\nkind = \"grid\"\n\
             [[parameters]]\nname = \"plant.springStiffness\"\nvalues = [{}]\n",
            fmus.display(),
            values.join(", ")
        ),
    )
    .unwrap();
    let out = d.path().join("t.parquet");
    let journal = d.path().join("t.parquet.journal");
    let child = kneebench()
        .arg("sweep")
        .arg(&spec)
        .args(["--workers", "1", "--output"])
        .arg(&out)
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    interrupt_once_journaled(child, &journal, "sweep", "points");
    assert!(!out.exists());
    let r = kneebench()
        .arg("sweep")
        .arg(&spec)
        .args(["--workers", "2", "--resume", "--output"])
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(0), "{stderr}");
    assert!(stderr.contains("wrote 40 rows"), "{stderr}");
    assert!(!journal.exists());
}

/// Sends SIGINT to `child` (a sweep or an optimisation, `what`, of 40 `unit`) once its
/// journal holds a row, and checks how it stops: exit code 130, how many are done (journaled,
/// between 1 and 39) and that `--resume` continues.
fn interrupt_once_journaled(
    mut child: std::process::Child,
    journal: &std::path::Path,
    what: &str,
    unit: &str,
) {
    // Until the journal holds a row (the header and one line), or the child ends.
    loop {
        let rows = std::fs::read_to_string(journal).map_or(0, |j| j.matches('\n').count());
        if rows >= 2 || child.try_wait().unwrap().is_some() {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    assert!(
        child.try_wait().unwrap().is_none(),
        "the {what} ended before it was interrupted"
    );
    // SAFETY: kill(2) on the child's pid, which has not been waited for.
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGINT) }, 0);
    let o = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(130), "{stderr}");
    let done = std::fs::read_to_string(journal)
        .unwrap()
        .matches('\n')
        .count()
        - 1;
    assert!((1..40).contains(&done), "{done}");
    assert!(
        stderr.contains(&format!(
            "interrupted (SIGINT): {done} of 40 {unit} done (journaled in {}); run again with \
             --resume",
            journal.display()
        )),
        "{stderr}"
    );
}

/// Ctrl-C during `kneebench optimize` stops it as it stops `sweep`: exit code 130, how many
/// runs are done and that `--resume` continues, the journal keeping those rows and no table
/// written; `--resume` finishes the table. Before, the process died of the signal without a
/// word.
#[test]
fn an_interrupted_optimisation_says_how_far_it_got_and_resumes() {
    let d = tempfile::tempdir().unwrap();
    let fmus = common::exported_fmus(
        std::path::Path::new(env!("CARGO_BIN_EXE_kneebench")),
        d.path(),
    );
    let spec = d.path().join("o.toml");
    std::fs::write(
        &spec,
        format!(
            "system = \"SEA\"\nfmus = \"{}\"\ncycles = 4\n[design]\nkind = \"random\"\n\
             points = 4\nseed = 1\n[[parameters]]\nname = \"plant.springStiffness\"\n\
             min = 250.0\nmax = 450.0\n[metrics]\nstudy = true\n[optimize]\n\
             objective = \"all_electrical_energy\"\ndirection = \"minimize\"\n\
             generations = 9\nseed = 2\n",
            fmus.display(),
        ),
    )
    .unwrap();
    let out = d.path().join("t.parquet");
    let journal = d.path().join("t.parquet.journal");
    let child = kneebench()
        .arg("optimize")
        .arg(&spec)
        .args(["--workers", "1", "--quiet", "--output"])
        .arg(&out)
        .stderr(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    interrupt_once_journaled(child, &journal, "optimisation", "runs");
    assert!(!out.exists());
    let r = kneebench()
        .arg("optimize")
        .arg(&spec)
        .args(["--workers", "2", "--quiet", "--resume", "--output"])
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(0), "{stderr}");
    assert!(stderr.contains("wrote 40 rows"), "{stderr}");
    assert!(String::from_utf8_lossy(&r.stdout).starts_with("best: point "));
    assert!(!journal.exists());
}

/// `identify --name` names the file OUT/NAME.ssv: a name with a path in it (which wrote
/// outside OUT) is refused before anything is read, with exit code 2.
#[test]
fn an_identified_set_name_with_a_path_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("out");
    for name in ["../escaped", "..", "", "a/b"] {
        let refused = kneebench()
            .args(["identify", "--defaults", "--fmu", "missing.fmu", "--out"])
            .arg(&out)
            .args(["--name", name])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&refused.stderr);
        assert_eq!(refused.status.code(), Some(2), "{name}: {stderr}");
        assert!(
            stderr.contains("must be a plain file name"),
            "{name}: {stderr}"
        );
    }
    assert!(!out.exists() && !d.path().join("escaped.ssv").exists());
}

/// `run` prints the recorded signals' min, max and final values, and `-q` prints nothing
/// (the summary is then not kept at all).
#[test]
fn run_prints_the_summary_unless_quiet() {
    let d = tempfile::tempdir().unwrap();
    let fmu = common::kbtest_fmu(d.path());
    let csv = d.path().join("r.csv");
    let run = |extra: &[&str]| run_kbtest(&fmu, &csv, &[&["--variables", "x"], extra].concat());
    let loud = run(&[]);
    assert_eq!(loud.status.code(), Some(0));
    let stdout = String::from_utf8_lossy(&loud.stdout);
    let lines: Vec<Vec<&str>> = stdout
        .lines()
        .map(|l| l.split_whitespace().collect())
        .collect();
    // x rises from 0 by 1 per 0.1 s step (`exit_codes_and_partial_results`): min 0, max and
    // final 10.
    assert_eq!(
        lines,
        [
            vec!["signal", "min", "max", "final"],
            vec!["x", "0.000000", "10.000000", "10.000000"],
            vec![],
        ],
        "{stdout}"
    );
    let quiet = run(&["-q"]);
    assert_eq!(quiet.status.code(), Some(0));
    assert!(quiet.stdout.is_empty(), "{quiet:?}");
}

/// `kneebench run` tells its output file how many rows the run will record: a Parquet file of
/// 10,001 rows is then two even row groups (the groups of an announced run,
/// `results::parquet::group_rows`), not a full group of 8,192 and the rest. The output file
/// once dropped the announcement, and its Parquet writer then also made its second row-group
/// buffer on the run's thread (up to 20 ms of the run's wall time on this machine).
#[test]
fn run_announces_its_rows_to_the_parquet_file() {
    use parquet::file::reader::{FileReader, SerializedFileReader};
    let d = tempfile::tempdir().unwrap();
    let fmu = common::kbtest_fmu(d.path());
    let out = d.path().join("r.parquet");
    // 1,000 s at 0.1 s: 10,001 rows.
    let run = run_kbtest_until("1000", &fmu, &out, &["-q"]);
    assert_eq!(run.status.code(), Some(0), "{run:?}");
    let reader = SerializedFileReader::new(std::fs::File::open(&out).unwrap()).unwrap();
    let groups: Vec<i64> = reader
        .metadata()
        .row_groups()
        .iter()
        .map(|g| g.num_rows())
        .collect();
    assert_eq!(groups, [5001, 5000]);
}
