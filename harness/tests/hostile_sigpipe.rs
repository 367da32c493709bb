//! A host that dies between two calls (here a thread of the FMU calls `_exit(7)` while the
//! master is idle) is an error of the next call, also in a process that, like `kneebench`,
//! keeps SIGPIPE at its default action (terminate): the master's requests go over a socket with
//! MSG_NOSIGNAL. With pipes, writing the next request killed this test process.
//!
//! A file of its own: it changes the process's SIGPIPE disposition.

mod hostile_fmu;

use std::time::Duration;

use hostile_fmu::*;
use kneebench_harness::isolate::{HostFailure, HostOptions, Isolation};
use kneebench_harness::{Fmu, FmuError, InstanceOptions, LoadOptions};

#[test]
fn a_host_that_died_between_calls_is_an_error_of_the_next_call_not_a_sigpipe() {
    // SAFETY: setting a signal's disposition to its default; no handler involved.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let d = tempfile::tempdir().unwrap();
    let options = LoadOptions {
        isolation: Isolation::Process,
        host: HostOptions {
            helper: Some(env!("CARGO_BIN_EXE_kneebench-fmu-host").into()),
            call_timeout: Duration::from_secs(60),
        },
        ..LoadOptions::default()
    };
    let fmu = Fmu::load(hostile_fmu(d.path()), &options).unwrap();
    let mut i = fmu
        .instantiate("late", &InstanceOptions::default())
        .unwrap();
    i.set_integer(&[0], &[MODE_EXIT_LATER]).unwrap();
    i.setup_experiment(None, 0.0, None).unwrap();
    i.enter_initialization_mode().unwrap();
    i.exit_initialization_mode().unwrap();
    i.do_step(0.0, 0.1).unwrap();
    // The FMU's thread ends the host meanwhile.
    std::thread::sleep(Duration::from_millis(1500));
    i.set_real(&[0], &[1.0]).unwrap();
    let e = i.do_step(0.1, 0.1).unwrap_err();
    match &e {
        FmuError::Host(h) => {
            assert_eq!(h.failure, HostFailure::Exit(7));
            assert_eq!(h.function, "fmi2DoStep");
            assert_eq!(h.queued, 1);
        }
        other => panic!("{other:?}"),
    }
    assert!(
        e.to_string().starts_with(
            "FMU 'Hostile', instance 'late': fmi2DoStep (sent with 1 queued set before it): \
             the FMU ended its process (exit code 7)"
        ),
        "{e}"
    );
    // Further calls report the same failure without touching the dead host.
    let again = i.do_step(0.1, 0.1).unwrap_err();
    assert!(again.to_string().contains("exit code 7"), "{again}");
}
