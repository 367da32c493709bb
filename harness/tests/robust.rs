//! Runs that never lose data: the streamed results file, stops by signal and time limit, the
//! row at an FMU's own end, non-finite outputs, refusals with their messages and exit codes,
//! and memory that stays flat over a million rows.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use kneebench_harness::master::Value;
use kneebench_harness::results::csv::CsvFile;
use kneebench_harness::ssp::{self, Ssd, SspComponent, SspExperiment, SspParameter, SspSystem};
use kneebench_harness::{Algorithm, Fmu, LoadOptions, Results, RunConfig, System};

fn kneebench() -> Command {
    Command::new(env!("CARGO_BIN_EXE_kneebench"))
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// `kneebench run <fmu> --output <out> -q <args>` in `dir`.
fn run(dir: &Path, args: &[&str]) -> Output {
    let fmu = common::kbtest_fmu(dir);
    kneebench()
        .current_dir(dir)
        .arg("run")
        .arg(&fmu)
        .args(["-q", "--output", "r.csv"])
        .args(args)
        .output()
        .unwrap()
}

fn code_and_stderr(o: &Output) -> (Option<i32>, String) {
    (o.status.code(), text(&o.stderr))
}

/// The extraction directories of process `pid` still in the temporary directory.
fn extraction_dirs_of(pid: u32) -> Vec<PathBuf> {
    let fmu = format!("kneebench-fmu-{pid}-");
    let ssp = format!("kneebench-ssp-{pid}-");
    std::fs::read_dir(std::env::temp_dir())
        .unwrap()
        .flatten()
        .filter(|e| {
            let n = e.file_name().to_string_lossy().into_owned();
            n.starts_with(&fmu) || n.starts_with(&ssp)
        })
        .map(|e| e.path())
        .collect()
}

#[test]
fn an_fmu_that_ends_the_run_gives_the_row_at_its_last_successful_time() {
    let d = tempfile::tempdir().unwrap();
    let o = run(
        d.path(),
        &[
            "--stop-time",
            "1",
            "--step",
            "0.1",
            "--param",
            "u=1",
            "--param",
            "discard_at=0.45",
            "--variables",
            "x",
        ],
    );
    let (code, err) = code_and_stderr(&o);
    assert_eq!(code, Some(3), "{err}");
    assert!(
        err.contains("ended by an FMU: component 'kbtest' terminated the simulation at t = 0.45"),
        "{err}"
    );
    // Every row up to the FMU's end, and the row at its last successful time (0.45), where
    // it integrated half a step: x = 4.5.
    assert_eq!(
        std::fs::read_to_string(d.path().join("r.csv")).unwrap(),
        "time,x\n0.0,0.0\n0.1,1.0\n0.2,2.0\n0.3,3.0\n0.4,4.0\n0.45,4.5\n"
    );
    assert!(!d.path().join("r.csv.partial").exists());

    // Ending exactly at a communication point adds no second row at that time.
    let o = run(
        d.path(),
        &[
            "--stop-time",
            "1",
            "--step",
            "0.1",
            "--param",
            "discard_at=0.3",
            "--param",
            "u=1",
            "--variables",
            "x",
        ],
    );
    assert_eq!(o.status.code(), Some(3));
    assert_eq!(
        std::fs::read_to_string(d.path().join("r.csv")).unwrap(),
        "time,x\n0.0,0.0\n0.1,1.0\n0.2,2.0\n0.3,3.0\n"
    );
}

#[test]
fn an_fmu_that_ends_an_ssp_system_gives_the_row_and_exit_code_3() {
    let d = tempfile::tempdir().unwrap();
    let fmu_path = common::kbtest_fmu(d.path());
    let fmu = Fmu::load(&fmu_path, &LoadOptions::default()).unwrap();
    let md = fmu.model_description();
    let mut a = SspComponent::from_model_description("a", "resources/kbtest.fmu", md);
    a.parameters = vec![SspParameter {
        name: "u".into(),
        value: Value::Real(1.0),
    }];
    let mut b = SspComponent::from_model_description("b", "resources/kbtest.fmu", md);
    b.parameters = vec![SspParameter {
        name: "discard_at".into(),
        value: Value::Real(0.25),
    }];
    let mut ssd = Ssd {
        name: "ends".into(),
        version: "1.0".into(),
        system: SspSystem {
            name: "root".into(),
            components: vec![a, b],
            connections: vec![],
        },
        default_experiment: Some(SspExperiment {
            start_time: Some(0.0),
            stop_time: Some(1.0),
            step_size: Some(0.1),
            algorithm: Some(Algorithm::GaussSeidel),
        }),
    };
    ssd.system.drop_unconnected_inputs();
    let ssp_path = d.path().join("ends.ssp");
    ssp::write_ssp(
        &ssd,
        &[("resources/kbtest.fmu".into(), fmu_path)],
        &ssp_path,
    )
    .unwrap();
    let o = kneebench()
        .current_dir(d.path())
        .arg("run")
        .arg(&ssp_path)
        .args(["-q", "--output", "s.csv", "--variables", "a.x,b.t"])
        .output()
        .unwrap();
    let (code, err) = code_and_stderr(&o);
    assert_eq!(code, Some(3), "{err}");
    assert!(err.contains("component 'b' terminated the simulation at t = 0.25"));
    // b's columns at its end; a's as last read (a stepped to 0.3 before b's step ended it).
    assert_eq!(
        std::fs::read_to_string(d.path().join("s.csv")).unwrap(),
        "time,a.x,b.t\n0.0,0.0,0.0\n0.1,1.0,0.1\n0.2,2.0,0.2\n0.25,3.0,0.25\n"
    );
}

/// A run of about 1e8 steps that a signal or the time limit must stop.
const LONG: [&str; 6] = ["--stop-time", "100000", "--step", "0.001", "--param", "u=1"];

/// Waits until the partial file holds at least one row (it is flushed every second).
fn wait_for_rows(partial: &Path) {
    let start = Instant::now();
    loop {
        let rows = std::fs::read_to_string(partial)
            .map(|t| t.lines().count())
            .unwrap_or(0);
        if rows >= 2 {
            return;
        }
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "no row flushed to {} in 120 s",
            partial.display()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Checks a partial results file: it parses, its times are on the 1 ms grid from 0 and
/// strictly increasing, x counts the steps.
fn check_partial(partial: &Path) -> usize {
    let r = Results::read_csv_file(partial).unwrap();
    assert!(r.len() >= 2, "{} rows", r.len());
    r.check_series(partial).unwrap();
    let x = r.column("x").unwrap();
    for (k, (row_t, x)) in r.times().iter().zip(x).enumerate() {
        assert_eq!(*row_t, k as f64 / 1000.0, "row {k}");
        assert_eq!(x, k as f64, "row {k}");
    }
    r.len()
}

#[test]
fn sigint_and_sigterm_stop_the_run_with_every_row_on_disk_and_the_temp_dirs_gone() {
    let d = tempfile::tempdir().unwrap();
    let fmu = common::kbtest_fmu(d.path());
    std::fs::write(d.path().join("r.csv"), "earlier results\n").unwrap();
    for (signal, code, says) in [
        ("INT", 130, "interrupted (SIGINT)"),
        ("TERM", 143, "terminated (SIGTERM)"),
    ] {
        let child = kneebench()
            .current_dir(d.path())
            .arg("run")
            .arg(&fmu)
            .args(["-q", "--output", "r.csv", "--variables", "x"])
            .args(LONG)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let pid = child.id();
        let partial = d.path().join("r.csv.partial");
        wait_for_rows(&partial);
        assert!(!extraction_dirs_of(pid).is_empty(), "the FMU is extracted");
        let kill = Command::new("kill")
            .args([format!("-{signal}"), pid.to_string()])
            .status()
            .unwrap();
        assert!(kill.success());
        let o = child.wait_with_output().unwrap();
        let (got, err) = code_and_stderr(&o);
        assert_eq!(got, Some(code), "SIG{signal}: {err}");
        assert!(err.contains(&format!("stopped: {says}")), "{err}");
        assert!(err.contains("kept "), "{err}");
        let rows = check_partial(&partial);
        assert!(err.contains(&format!("kept {rows} rows")), "{rows}: {err}");
        assert_eq!(
            std::fs::read_to_string(d.path().join("r.csv")).unwrap(),
            "earlier results\n",
            "a stopped run leaves the earlier results alone"
        );
        assert_eq!(extraction_dirs_of(pid), Vec::<PathBuf>::new());
        std::fs::remove_file(&partial).unwrap();
    }
}

/// A run whose results cannot be renamed into place (a directory took the output's name
/// during the run) fails with that error and keeps every row in its partial file.
#[test]
fn a_failed_commit_keeps_every_row_in_the_partial_file() {
    let d = tempfile::tempdir().unwrap();
    let fmu = common::kbtest_fmu(d.path());
    // 2e8 steps, a row every 1000: seconds of work, so that the directory below is made
    // while the run goes (its first rows reach the partial file within a tenth of it).
    let child = kneebench()
        .current_dir(d.path())
        .arg("run")
        .arg(&fmu)
        .args([
            "-q",
            "--output",
            "r.csv",
            "--variables",
            "x",
            "--isolate",
            "never",
        ])
        .args(["--stop-time", "200000", "--step", "0.001", "--param", "u=1"])
        .args(["--record-every", "1000"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let partial = d.path().join("r.csv.partial");
    wait_for_rows(&partial);
    std::fs::create_dir(d.path().join("r.csv")).unwrap();
    std::fs::write(d.path().join("r.csv").join("taken"), "").unwrap();
    let o = child.wait_with_output().unwrap();
    let (code, err) = code_and_stderr(&o);
    assert_ne!(code, Some(0), "{err}");
    assert!(err.contains("r.csv"), "{err}");
    let r = Results::read_csv_file(&partial).unwrap();
    assert_eq!(r.len(), 200_001, "{err}");
    assert_eq!(r.times().last(), Some(&200_000.0));
    assert_eq!(r.column("x").unwrap().last(), Some(&200_000_000.0));
}

/// Rows reach the disk every second even when they are far too few to fill the write buffer
/// (64 KiB; here about 20 bytes a row, one row per 100,000 steps): the flush is timed, not
/// triggered by a full buffer.
#[test]
fn rows_are_flushed_every_second_of_wall_time() {
    let d = tempfile::tempdir().unwrap();
    let fmu = common::kbtest_fmu(d.path());
    let mut child = kneebench()
        .current_dir(d.path())
        .arg("run")
        .arg(&fmu)
        .args(["-q", "--output", "r.csv", "--variables", "x"])
        .args(["--record-every", "100000"])
        .args(LONG)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let partial = d.path().join("r.csv.partial");
    let start = Instant::now();
    let mut seen = 0;
    // A buffer-full flush would need about 3,000 rows, minutes of this run.
    while start.elapsed() < Duration::from_secs(60) && seen < 4 {
        std::thread::sleep(Duration::from_millis(100));
        seen = std::fs::read_to_string(&partial)
            .map(|t| t.lines().count())
            .unwrap_or(0);
    }
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(seen >= 4, "{seen} lines in {:?}", start.elapsed());
    let text = std::fs::read_to_string(&partial).unwrap();
    assert!(text.len() < 64 * 1024, "{} bytes", text.len());
    assert!(
        text.starts_with("time,x\n0.0,0.0\n100.0,100000.0\n"),
        "{text}"
    );
}

#[test]
fn the_time_limit_stops_the_run_with_exit_code_4() {
    let d = tempfile::tempdir().unwrap();
    let mut args = vec!["--variables", "x", "--timeout", "1.5"];
    args.extend(LONG);
    let started = Instant::now();
    let o = run(d.path(), &args);
    let (code, err) = code_and_stderr(&o);
    assert_eq!(code, Some(4), "{err}");
    assert!(started.elapsed() >= Duration::from_millis(1500));
    assert!(err.contains("stopped: the time limit passed"), "{err}");
    check_partial(&d.path().join("r.csv.partial"));
    assert!(!d.path().join("r.csv").exists());
}

#[test]
fn refusals_name_the_problem_with_the_documented_exit_code() {
    let d = tempfile::tempdir().unwrap();
    let cases: &[(&[&str], i32, &str)] = &[
        (
            &["--stop-time", "1", "--step", "0.3"],
            2,
            "stop time 1 is not on the grid",
        ),
        (
            &["--stop-time", "1e300", "--step", "0.1"],
            2,
            "beyond the master's time range",
        ),
        (
            &["--stop-time", "1e10", "--step", "1e10"],
            2,
            "beyond the master's time range",
        ),
        (
            &["--step", "1e-10"],
            2,
            "is not a whole number of nanoseconds",
        ),
        (&["--timeout=-1"], 2, "must be a positive, finite"),
        (&["--timeout", "nan"], 2, "must be a positive, finite"),
        (&["--record-every", "0"], 2, "record-every"),
        (
            &["--param", "nope"],
            2,
            "--param 'nope': expected NAME=VALUE",
        ),
        (
            &["--param", "k=abc"],
            2,
            "bad value for 'kbtest.k': 'abc' is not a Real",
        ),
        (
            &["--param", "i_in=1.5"],
            2,
            "bad value for 'kbtest.i_in': '1.5' is not an Integer",
        ),
        (
            &["--variables", "nothing"],
            2,
            "component 'kbtest' has no variable 'nothing'",
        ),
    ];
    for (args, code, message) in cases {
        let o = run(d.path(), args);
        let (got, err) = code_and_stderr(&o);
        assert_eq!(got, Some(*code), "{args:?}: {err}");
        assert!(err.contains(message), "{args:?}: {err}");
        assert!(
            !d.path().join("r.csv.partial").exists(),
            "{args:?}: a run that never started leaves no partial file"
        );
    }

    // The output is checked before anything is loaded; the OS error is printed once.
    let fmu = common::kbtest_fmu(d.path());
    let to = |output: &str| {
        kneebench()
            .current_dir(d.path())
            .arg("run")
            .arg(&fmu)
            .args(["--output", output])
            .output()
            .unwrap()
    };
    let o = to("missing/r.csv");
    let (got, err) = code_and_stderr(&o);
    assert_eq!(got, Some(1), "{err}");
    assert!(err.contains("missing"), "{err}");
    assert_eq!(err.matches("os error 2").count(), 1, "{err}");
    let o = to(".");
    assert_eq!(o.status.code(), Some(1));
    assert!(text(&o.stderr).contains("directory"));
    let o = kneebench()
        .current_dir(d.path())
        .args(["run", "nothing.fmu", "--output", "r.csv"])
        .output()
        .unwrap();
    let (got, err) = code_and_stderr(&o);
    assert_eq!(got, Some(1), "{err}");
    assert_eq!(err.matches("os error 2").count(), 1, "{err}");
    assert!(!d.path().join("r.csv.partial").exists());
}

#[test]
fn inputs_are_validated_like_metrics_does() {
    let d = tempfile::tempdir().unwrap();
    let cases = [
        (
            "time,u\n0,1\n0.2,2\n0.1,3\n",
            "data row 3 (t = 0.1): time is not strictly increasing (previous row: t = 0.2)",
        ),
        (
            "time,u\n0,1\n0.1,1\n0.1,2\n",
            "time is not strictly increasing",
        ),
        (
            "time,u\n0,1\n0.1,nan\n",
            "data row 2 (t = 0.1): u = NaN is not finite",
        ),
        ("time,u\n0,1\ninf,2\n", "data row 2: time inf is not finite"),
        ("time,u\n", "no data rows"),
        ("time,y\n0,1\n", "column 'y' is not an input of the FMU"),
        (
            "time,nope\n0,1\n",
            "column 'nope' is not a variable of the FMU",
        ),
    ];
    for (csv, message) in cases {
        std::fs::write(d.path().join("in.csv"), csv).unwrap();
        let o = run(d.path(), &["--inputs", "in.csv"]);
        let (code, err) = code_and_stderr(&o);
        assert_eq!(code, Some(2), "{csv}: {err}");
        assert!(err.contains(message), "{csv}: {err}");
    }
    // Samples near the largest double interpolate between them, never to -inf.
    std::fs::write(d.path().join("in.csv"), "time,u\n0,1.7e308\n1,-1.7e308\n").unwrap();
    let o = run(
        d.path(),
        &[
            "--inputs",
            "in.csv",
            "--stop-time",
            "1",
            "--step",
            "0.25",
            "--variables",
            "y",
        ],
    );
    assert_eq!(o.status.code(), Some(0), "{}", text(&o.stderr));
    let r = Results::read_csv_file(d.path().join("r.csv")).unwrap();
    let y = r.column("y").unwrap();
    assert_eq!(y.len(), 5);
    assert!(y.iter().all(|v| v.is_finite()), "{y:?}");
    assert!(y.windows(2).all(|w| w[1] <= w[0]), "{y:?}");
    // Each row shows the input used during the step that ended there: u(0.5) at 0.75.
    assert_eq!(y[0], 1.7e308);
    assert_eq!(y[3], 0.0);
}

#[test]
fn a_non_finite_output_fails_the_run_unless_allowed() {
    let d = tempfile::tempdir().unwrap();
    // y = k u + b with k = inf, u = 0: NaN from the start.
    let args = ["--stop-time", "0.3", "--step", "0.1", "--param", "k=inf"];
    let o = run(d.path(), &args);
    let (code, err) = code_and_stderr(&o);
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains(
            "component 'kbtest': output 'y' is NaN at t = 0 (use --allow-nonfinite to record it)"
        ),
        "{err}"
    );
    // From t = 0.2 on (u set by the inputs file): +inf at the step's end time.
    std::fs::write(d.path().join("in.csv"), "time,u\n0,0\n0.15,0\n0.2,1\n").unwrap();
    let o = run(
        d.path(),
        &[
            "--stop-time",
            "0.5",
            "--step",
            "0.1",
            "--param",
            "b=1e308",
            "--param",
            "k=1e308",
            "--inputs",
            "in.csv",
        ],
    );
    let (code, err) = code_and_stderr(&o);
    assert_eq!(code, Some(1), "{err}");
    assert!(err.contains("output 'y' is inf at t = 0.3"), "{err}");
    let partial = Results::read_csv_file(d.path().join("r.csv.partial")).unwrap();
    assert_eq!(partial.len(), 3, "rows at 0, 0.1, 0.2");

    let mut allowed = args.to_vec();
    allowed.push("--allow-nonfinite");
    let o = run(d.path(), &allowed);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o.stderr));
    let r = Results::read_csv_file(d.path().join("r.csv")).unwrap();
    assert!(r.column("y").unwrap().iter().all(|v| v.is_nan()));
}

#[test]
fn run_refuses_what_validate_rejects_unless_forced() {
    let d = tempfile::tempdir().unwrap();
    // The capability flags promise directional derivatives the binary (built without them)
    // does not export.
    let md = common::model_description(common::GUID).replace(
        "canNotUseMemoryManagementFunctions=\"true\"",
        "canNotUseMemoryManagementFunctions=\"true\" providesDirectionalDerivative=\"true\"",
    );
    let bad = d.path().join("promises.fmu");
    common::write_fmu(
        &bad,
        &common::FmuSpec {
            model_description: Some(md),
            binary_path: Some(common::compile_kbtest(&[
                "KBTEST_WITHOUT_DIRECTIONAL_DERIVATIVE",
            ])),
            ..common::FmuSpec::default()
        },
    );
    let validate = kneebench().arg("validate").arg(&bad).output().unwrap();
    assert_eq!(validate.status.code(), Some(1));
    let problem = "the capability flags promise fmi2GetDirectionalDerivative, which the binary does not export";
    assert!(text(&validate.stdout).contains(problem));
    let go = |extra: &[&str]| {
        kneebench()
            .current_dir(d.path())
            .arg("run")
            .arg(&bad)
            .args(["-q", "--output", "r.csv"])
            .args(extra)
            .output()
            .unwrap()
    };
    let o = go(&[]);
    let (code, err) = code_and_stderr(&o);
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains(&format!("problem: kbtest: {problem}")),
        "{err}"
    );
    assert!(err.contains("pass --force"), "{err}");
    assert!(!d.path().join("r.csv").exists());
    let o = go(&["--force"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o.stderr));
    assert!(d.path().join("r.csv").exists());
}

/// The peak resident memory (VmHWM, kB) of this process.
fn peak_rss_kb() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .expect("VmHWM in /proc/self/status")
}

/// Run by [`memory_stays_flat_over_a_million_rows`] in a child process: a run of
/// `KB_STEPS` 1 ms steps of the test FMU into `KB_OUT` (a CSV file) or into memory (`KB_OUT`
/// empty); prints `VmHWM <kB>`.
#[test]
#[ignore = "helper of memory_stays_flat_over_a_million_rows, run in a child process"]
fn memory_child() {
    let fmu = std::env::var("KB_FMU").unwrap();
    let steps: u64 = std::env::var("KB_STEPS").unwrap().parse().unwrap();
    let out = std::env::var("KB_OUT").unwrap();
    let fmu = Fmu::load(&fmu, &LoadOptions::default()).unwrap();
    let mut system = System::new();
    system.add_component("a", fmu).unwrap();
    system.set_value_str("a.u", "1").unwrap();
    let config = RunConfig {
        stop_time: steps as f64 / 1000.0,
        step_size: 1e-3,
        ..RunConfig::default()
    };
    let rows = if out.is_empty() {
        let o = system.run(&config).unwrap();
        assert!(matches!(
            o.outcome,
            kneebench_harness::Outcome::Completed { .. }
        ));
        o.results.len() as u64
    } else {
        let mut file = CsvFile::create(Path::new(&out)).unwrap();
        let s = system.run_into(&config, &mut file).unwrap();
        assert!(matches!(
            s.outcome,
            kneebench_harness::Outcome::Completed { .. }
        ));
        file.commit().unwrap();
        s.rows
    };
    assert_eq!(rows, steps + 1);
    println!("VmHWM {}", peak_rss_kb());
}

#[test]
fn memory_stays_flat_over_a_million_rows() {
    let d = tempfile::tempdir().unwrap();
    let fmu = common::kbtest_fmu(d.path());
    let peak = |steps: u64, out: &str| -> u64 {
        let o = Command::new(std::env::current_exe().unwrap())
            .args(["--ignored", "--exact", "memory_child", "--nocapture"])
            .env("KB_FMU", &fmu)
            .env("KB_STEPS", steps.to_string())
            .env("KB_OUT", out)
            .output()
            .unwrap();
        let stdout = text(&o.stdout);
        assert!(o.status.success(), "{stdout}{}", text(&o.stderr));
        stdout
            .lines()
            .find_map(|l| l.strip_prefix("VmHWM "))
            .and_then(|v| v.trim().parse().ok())
            .unwrap_or_else(|| panic!("no VmHWM line in {stdout}"))
    };
    let file = d.path().join("r.csv");
    let file = file.to_str().unwrap();
    let short = peak(1_000, file);
    let long = peak(1_000_000, file);
    let rows = Results::read_csv_file(file).unwrap();
    assert_eq!(rows.len(), 1_000_001);
    assert_eq!(rows.last_time(), Some(1000.0));
    // Streamed: a million rows (7 values each, 56 MB in memory) add almost nothing.
    assert!(
        long < short + 16 * 1024,
        "peak RSS {long} kB for 1e6 rows vs {short} kB for 1e3"
    );
    // The measure sees row memory: the same run kept in memory peaks 40 MB higher or more.
    let in_memory = peak(1_000_000, "");
    eprintln!(
        "peak RSS: 1e3 rows streamed {short} kB, 1e6 rows streamed {long} kB, 1e6 rows in memory {in_memory} kB"
    );
    assert!(
        in_memory > short + 40 * 1024,
        "in memory: {in_memory} kB vs {short} kB"
    );
}

/// An earlier run's partial file (its rows) is set aside as `r.csv.partial.1`, named on
/// standard error, never overwritten by the next run; a Parquet output likewise.
#[test]
fn a_rerun_keeps_an_earlier_runs_partial_file() {
    let d = tempfile::tempdir().unwrap();
    let earlier = "time,x\n0.0,0.0\n0.1,1.0\n";
    std::fs::write(d.path().join("r.csv.partial"), earlier).unwrap();
    let o = run(d.path(), &["--stop-time", "0.2", "--step", "0.1"]);
    let (code, err) = code_and_stderr(&o);
    assert_eq!(code, Some(0), "{err}");
    assert!(
        err.contains("kept an earlier run's rows: r.csv.partial is now r.csv.partial.1"),
        "{err}"
    );
    assert_eq!(
        std::fs::read_to_string(d.path().join("r.csv.partial.1")).unwrap(),
        earlier
    );
    assert!(d.path().join("r.csv").is_file());
    assert!(!d.path().join("r.csv.partial").exists());

    std::fs::write(d.path().join("r.parquet.partial"), "PAR1 rows").unwrap();
    let fmu = common::kbtest_fmu(d.path());
    let o = kneebench()
        .current_dir(d.path())
        .arg("run")
        .arg(&fmu)
        .args(["-q", "--output", "r.parquet", "--stop-time", "0.2"])
        .output()
        .unwrap();
    let (code, err) = code_and_stderr(&o);
    assert_eq!(code, Some(0), "{err}");
    assert!(
        err.contains("r.parquet.partial is now r.parquet.partial.1"),
        "{err}"
    );
    assert_eq!(
        std::fs::read(d.path().join("r.parquet.partial.1")).unwrap(),
        b"PAR1 rows"
    );
}
