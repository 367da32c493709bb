//! The hostile FMU (`tests/hostile/hostile.c`, built against the official FMI 2.0 headers)
//! through the library, in this process where that is survivable (NaN/Inf outputs, every
//! status) and isolated in a host process (the same, plus segfault, abort, exit(0), a hang and
//! garbage on standard output): the outcome, the error message (FMU, instance, call, signal or
//! exit code, the FMU's last log line) and the rows recorded up to the failure.

mod hostile_fmu;

use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use hostile_fmu::*;
use kneebench_harness::isolate::{HostFailure, HostOptions, Isolation, find_helper};
use kneebench_harness::{
    Fmu, FmuError, InstanceOptions, LoadOptions, LogMessage, Outcome, RunConfig, RunOutput, System,
    Value, master::MasterError,
};

const HOST: &str = env!("CARGO_BIN_EXE_kneebench-fmu-host");

fn options(isolation: Isolation, timeout: Duration) -> LoadOptions {
    LoadOptions {
        isolation,
        host: HostOptions {
            helper: Some(HOST.into()),
            call_timeout: timeout,
        },
        ..LoadOptions::default()
    }
}

/// Runs Hostile.fmu as component `h` from 0 to 1 s in steps of 0.1 s with `mode` firing in the
/// step that passes `at` (0.3: the step from 0.3 to 0.4), input u = 1.5.
fn run(dir: &Path, isolation: Isolation, mode: i32, timeout: Duration) -> (RunOutput, Vec<String>) {
    run_with(dir, isolation, mode, timeout, false)
}

/// [`run`], recording non-finite outputs when `allow_nonfinite`.
fn run_with(
    dir: &Path,
    isolation: Isolation,
    mode: i32,
    timeout: Duration,
    allow_nonfinite: bool,
) -> (RunOutput, Vec<String>) {
    let fmu = Fmu::load(hostile_fmu(dir), &options(isolation, timeout)).unwrap();
    assert_eq!(fmu.is_isolated(), isolation == Isolation::Process);
    let logs = Arc::new(Mutex::new(Vec::new()));
    let sink = logs.clone();
    let mut system = System::new();
    system.add_component("h", fmu).unwrap();
    system.set_value("h.mode", Value::Integer(mode)).unwrap();
    system.set_value("h.at", Value::Real(0.3)).unwrap();
    system.set_value("h.u", Value::Real(1.5)).unwrap();
    system.set_instance_options(InstanceOptions {
        log_handler: Some(Arc::new(move |m: &LogMessage| {
            sink.lock().unwrap().push(m.message.clone())
        })),
        ..InstanceOptions::default()
    });
    let config = RunConfig {
        stop_time: 1.0,
        step_size: 0.1,
        allow_nonfinite,
        ..RunConfig::default()
    };
    let out = system.run(&config).unwrap();
    let logs = logs.lock().unwrap().clone();
    (out, logs)
}

fn fmu_error(out: &RunOutput) -> (&FmuError, String) {
    match &out.outcome {
        Outcome::Failed(e @ MasterError::Fmu { source, .. }) => (source, e.to_string()),
        other => panic!("expected an FMU error, got {other:?}"),
    }
}

const MINUTE: Duration = Duration::from_secs(60);

/// The rows' bits (NaN compared by its bits).
fn bits(o: &RunOutput) -> Vec<Vec<u64>> {
    o.results
        .rows()
        .map(|r| r.iter().map(|x| x.to_bits()).collect())
        .collect()
}

#[test]
fn survivable_behaviours_give_the_same_outcome_and_rows_in_process_and_isolated() {
    let d = tempfile::tempdir().unwrap();
    for mode in [
        0,
        MODE_NAN,
        MODE_INF,
        MODE_WARNING,
        MODE_DISCARD,
        MODE_ERROR,
        MODE_FATAL,
        MODE_PENDING,
    ] {
        let (local, local_logs) = run(d.path(), Isolation::InProcess, mode, MINUTE);
        let (remote, remote_logs) = run(d.path(), Isolation::Process, mode, MINUTE);
        // Bit for bit the same rows (NaN compared by its bits).
        assert_eq!(bits(&local), bits(&remote), "mode {mode}");
        assert_eq!(local.results.names(), remote.results.names(), "mode {mode}");
        assert_eq!(local_logs, remote_logs, "mode {mode}");
        assert_eq!(
            format!("{:?}", local.outcome),
            format!("{:?}", remote.outcome),
            "mode {mode}"
        );
        assert_eq!(local.steps_per_component, remote.steps_per_component);
        let y = local.results.column("h.y").unwrap();
        let times = local.results.times();
        match mode {
            0 | MODE_WARNING => {
                assert!(matches!(local.outcome, Outcome::Completed { .. }), "{mode}");
                assert_eq!(times.len(), 11);
                assert!(y.iter().all(|&v| v == 3.0), "{y:?}");
                if mode == MODE_WARNING {
                    assert_eq!(local_logs, vec!["hostile: warning at t=0.3"]);
                }
            }
            MODE_NAN | MODE_INF => {
                // A non-finite output ends the run with an error naming it, after the rows
                // before it.
                match &local.outcome {
                    Outcome::Failed(MasterError::NonFinite {
                        component,
                        variable,
                        value,
                        time,
                    }) => {
                        assert_eq!((component.as_str(), variable.as_str()), ("h", "y"));
                        assert_eq!(value.is_nan(), mode == MODE_NAN);
                        assert!((time - 0.4).abs() < 1e-12, "{time}");
                    }
                    o => panic!("{o:?}"),
                }
                assert_eq!(times.len(), 4, "{times:?}");
                // Recorded as they come when allowed, the same in process and isolated.
                let (a, _) = run_with(d.path(), Isolation::InProcess, mode, MINUTE, true);
                let (b, _) = run_with(d.path(), Isolation::Process, mode, MINUTE, true);
                assert_eq!(bits(&a), bits(&b));
                assert!(matches!(a.outcome, Outcome::Completed { .. }), "{mode}");
                let y = a.results.column("h.y").unwrap();
                assert!(y[..4].iter().all(|&v| v == 3.0), "{y:?}");
                assert!(
                    y[4..].iter().all(|v| if mode == MODE_NAN {
                        v.is_nan()
                    } else {
                        *v == f64::INFINITY
                    }),
                    "{y:?}"
                );
            }
            MODE_DISCARD => match &local.outcome {
                Outcome::Terminated {
                    component,
                    last_successful_time,
                    messages,
                    ..
                } => {
                    assert_eq!(component, "h");
                    assert!((last_successful_time - 0.3).abs() < 1e-12);
                    assert!(
                        messages
                            .iter()
                            .any(|m| m.contains("hostile: discard at t=0.3")),
                        "{messages:?}"
                    );
                    assert_eq!(times.len(), 4, "{times:?}");
                }
                o => panic!("{o:?}"),
            },
            MODE_ERROR | MODE_FATAL | MODE_PENDING => {
                let (e, text) = fmu_error(&local);
                let status = match mode {
                    MODE_ERROR => "Error",
                    MODE_FATAL => "Fatal",
                    _ => "Pending",
                };
                assert!(
                    matches!(
                        e,
                        FmuError::Call {
                            function: "fmi2DoStep",
                            ..
                        }
                    ),
                    "{e:?}"
                );
                assert!(
                    text.contains(&format!("fmi2DoStep returned {status} (instance 'h')")),
                    "{text}"
                );
                assert!(
                    text.contains(&format!("hostile: {} at t=0.3", status.to_lowercase())),
                    "{text}"
                );
                // The rows up to the failed step: 0, 0.1, 0.2, 0.3.
                assert_eq!(times.len(), 4, "{times:?}");
            }
            _ => unreachable!(),
        }
    }
}

/// Runs an isolated crash and checks the error and the rows up to it.
fn crash(mode: i32, timeout: Duration, failure: HostFailure, log: &str) {
    let d = tempfile::tempdir().unwrap();
    let (out, _) = run(d.path(), Isolation::Process, mode, timeout);
    let (e, text) = fmu_error(&out);
    match e {
        FmuError::Host(h) => {
            assert_eq!(h.model, "Hostile");
            assert_eq!(h.instance, "h");
            assert_eq!(h.function, "fmi2DoStep");
            assert_eq!(h.queued, 0);
            assert_eq!(h.failure, failure);
            // The message logged right before the crash reached the master.
            assert!(
                h.messages.iter().any(|m| m.message == log),
                "{:?}",
                h.messages
            );
        }
        other => panic!("{other:?}"),
    }
    assert!(
        text.starts_with("component 'h' at t = 0.3: FMU 'Hostile', instance 'h': fmi2DoStep"),
        "{text}"
    );
    assert!(text.contains(&failure.to_string()), "{text}");
    assert!(text.contains(log), "{text}");
    assert_eq!(out.results.times(), vec![0.0, 0.1, 0.2, 0.3]);
    assert_eq!(out.results.column("h.y").unwrap(), vec![3.0; 4]);
}

#[test]
fn an_isolated_segfault_is_an_error_naming_the_fmu_the_call_and_the_signal() {
    crash(
        MODE_SEGFAULT,
        MINUTE,
        HostFailure::Signal(11),
        "hostile: segfault at t=0.3",
    );
    assert_eq!(
        HostFailure::Signal(11).to_string(),
        "the FMU's process crashed (signal 11, SIGSEGV)"
    );
}

#[test]
fn an_isolated_abort_is_an_error_naming_the_signal() {
    crash(
        MODE_ABORT,
        MINUTE,
        HostFailure::Signal(6),
        "hostile: abort at t=0.3",
    );
}

#[test]
fn an_isolated_exit_is_an_error_naming_the_exit_code() {
    crash(
        MODE_EXIT,
        MINUTE,
        HostFailure::Exit(0),
        "hostile: exit(0) at t=0.3",
    );
    assert_eq!(
        HostFailure::Exit(0).to_string(),
        "the FMU ended its process (exit code 0)"
    );
}

#[test]
fn an_isolated_hang_is_killed_by_the_call_timeout() {
    // Bounds every call of this run (not only the hang): generous for a loaded machine.
    let timeout = Duration::from_millis(3500);
    let start = Instant::now();
    crash(
        MODE_HANG,
        timeout,
        HostFailure::Timeout(timeout),
        "hostile: hang at t=0.3",
    );
    // Not a timing assertion: only that the watchdog, not a test timeout, ended it.
    assert!(start.elapsed() < Duration::from_secs(50));
    assert_eq!(
        HostFailure::Timeout(timeout).to_string(),
        "no answer within 3.5 s (call timeout); the FMU's process was killed"
    );
}

#[test]
fn garbage_on_the_fmus_stdout_does_not_reach_the_protocol() {
    let d = tempfile::tempdir().unwrap();
    let (out, logs) = run(d.path(), Isolation::Process, MODE_STDOUT, MINUTE);
    assert!(
        matches!(out.outcome, Outcome::Completed { .. }),
        "{:?}",
        out.outcome
    );
    assert_eq!(out.results.column("h.y").unwrap(), vec![3.0; 11]);
    assert_eq!(logs, vec!["hostile: garbage on stdout at t=0.3"]);
}

#[test]
fn auto_isolates_only_fmus_kneebench_did_not_generate() {
    let d = tempfile::tempdir().unwrap();
    let foreign = Fmu::load(hostile_fmu(d.path()), &options(Isolation::Auto, MINUTE)).unwrap();
    assert!(foreign.is_isolated());
    let ours = Fmu::load(
        hostile_fmu_by(d.path(), "kneebench 0.1.0"),
        &options(Isolation::Auto, MINUTE),
    )
    .unwrap();
    assert!(!ours.is_isolated());
    let forced = Fmu::load(
        hostile_fmu_by(d.path(), "kneebench 0.1.0"),
        &options(Isolation::Process, MINUTE),
    )
    .unwrap();
    assert!(forced.is_isolated());
    // A tool whose name merely starts with the word is foreign.
    let other = Fmu::load(
        hostile_fmu_by(d.path(), "kneebenchmark 2"),
        &options(Isolation::Auto, MINUTE),
    )
    .unwrap();
    assert!(other.is_isolated());
}

#[test]
fn the_host_executable_is_found_next_to_the_running_executable() {
    // SAFETY-free: the variable is only read by find_helper; tests in this binary that load
    // isolated FMUs pass the helper explicitly.
    if std::env::var_os("KNEEBENCH_FMU_HOST").is_some() {
        return;
    }
    // Test executables live in target/<profile>/deps; the host is in target/<profile>.
    let found = find_helper(None).unwrap();
    assert_eq!(
        found.canonicalize().unwrap(),
        Path::new(HOST).canonicalize().unwrap()
    );
    let explicit = find_helper(Some(Path::new("/x/y"))).unwrap();
    assert_eq!(explicit, Path::new("/x/y"));
}

#[test]
fn a_missing_host_executable_is_a_load_error() {
    let d = tempfile::tempdir().unwrap();
    let mut o = options(Isolation::Process, MINUTE);
    o.host.helper = Some(d.path().join("no-such-host"));
    let e = Fmu::load(hostile_fmu(d.path()), &o).unwrap_err();
    let text = e.to_string();
    assert!(text.contains("could not start"), "{text}");
    assert!(text.contains("no-such-host"), "{text}");
}

#[test]
fn an_isolated_instance_serves_every_call_of_the_api() {
    let d = tempfile::tempdir().unwrap();
    let fmu = Fmu::load(hostile_fmu(d.path()), &options(Isolation::Process, MINUTE)).unwrap();
    let mut i = fmu
        .instantiate("direct", &InstanceOptions::default())
        .unwrap();
    assert!(i.is_isolated());
    i.setup_experiment(None, 0.0, Some(1.0)).unwrap();
    i.enter_initialization_mode().unwrap();
    i.set_real(&[0], &[2.0]).unwrap();
    i.exit_initialization_mode().unwrap();
    let mut y = [0.0];
    for k in 0..5 {
        let t = k as f64 * 0.1;
        i.set_real(&[0], &[t]).unwrap();
        i.do_step(t, 0.1).unwrap();
        i.get_real(&[1, 2], &mut [0.0, 0.0]).unwrap();
        i.get_real(&[1], &mut y).unwrap();
        assert_eq!(y[0], 2.0 * t);
        let mut steps = [0];
        i.get_integer(&[1], &mut steps).unwrap();
        assert_eq!(steps[0], k + 1);
    }
    // The step prefetches the reads above; a read after a set is not answered from that copy.
    i.do_step(0.5, 0.1).unwrap();
    i.set_real(&[0], &[7.0]).unwrap();
    let mut yt = [0.0; 2];
    i.get_real(&[1, 2], &mut yt).unwrap();
    assert_eq!(yt, [14.0, 0.6]);
    assert!(!i.terminated());
    assert!((i.last_successful_time().unwrap() - 0.6).abs() < 1e-12);
    // A queued set the FMU refuses is reported by the next call, named after the set.
    i.set_real(&[9], &[1.0]).unwrap();
    let e = i.do_step(0.6, 0.1).unwrap_err();
    assert!(
        matches!(
            e,
            FmuError::Call {
                function: "fmi2SetReal",
                ..
            }
        ),
        "{e:?}"
    );
    assert!(e.to_string().contains("cannot set Real 9"), "{e}");
    // Not exported by the binary: refused without a round trip.
    assert!(matches!(
        i.get_fmu_state(),
        Err(FmuError::Unsupported("fmi2GetFMUstate"))
    ));
    i.reset().unwrap();
    assert_eq!(i.get_string(&[]).unwrap(), Vec::<String>::new());
    assert!(i.get_string(&[0]).is_err());
}
