//! A PythonFMU export (the `FirstOrder` lag of [`kneebench_tests::pythonfmu`]) with the calling
//! thread's Python thread state kept (`PythonThreadState::Kept`, the default; module
//! `kneebench_harness::embedded_python`) gives the same results, bit for bit, as with the
//! binary making one per call (`PythonThreadState::PerCall`): one instance, several, stepped in
//! parallel, moved between threads, in a sweep with two workers, and in the isolated host
//! process. The thread state is there while an instance lives and gone after it is freed, and
//! a thread that moved its instance away releases its own when it ends.
//!
//! Everything in process runs in a child process (this test binary re-executed on the
//! `#[ignore]`d [`child_keeps_the_python_thread_state`]), as `foreign_fmu.rs` explains: one
//! interpreter per process, started by the binary's first `fmi2Instantiate`. The child makes
//! libpython global itself (`RTLD_GLOBAL`, as `--preload` would) so that every in-process load
//! uses one copy of the binary (loaded once, `Binaries::Shared`), and it asks that libpython
//! whether the thread has a thread state (`PyGILState_GetThisThreadState`).
//!
//! The isolated runs need the host executable `kneebench-fmu-host` next to the test binary's
//! directory (built by `cargo test --workspace`; alone: `cargo build --release -p
//! kneebench-harness --bins`).

use std::ffi::{c_int, c_void};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use kneebench_harness::master::{Signal, Value};
use kneebench_harness::ssp::{self, Ssd, SspComponent, SspExperiment, SspSystem};
use kneebench_harness::sweep::{Prepared, RunStatus, SweepOptions, SweepSpec, run_sweep};
use kneebench_harness::{
    Fmu, Instance, InstanceOptions, Isolation, LoadOptions, Outcome, PythonThreadState, Results,
    RunConfig, System,
};
use kneebench_tests::*;

const ENV_DIR: &str = "KNEEBENCH_PYSTATE_DIR";
const ENV_LIBPYTHON: &str = "KNEEBENCH_PYSTATE_LIBPYTHON";

const STOP: f64 = 2.0;
const STEP: f64 = 0.001;

/// The lag's input: piecewise linear, crossing the threshold of the Boolean output.
const INPUTS: &str = "time,u\n0.0,0.0\n0.3,0.5\n0.7,1.0\n1.2,-0.25\n2.0,0.4\n";

#[test]
fn python_thread_state_kept_gives_the_same_results_as_per_call() {
    let dir = tempfile::tempdir().unwrap();
    pythonfmu::build_first_order(&python(), dir.path()).unwrap();
    let runtime = pythonfmu::runtime(&python()).unwrap();
    let child = Command::new(std::env::current_exe().unwrap())
        .args([
            "--ignored",
            "--exact",
            "child_keeps_the_python_thread_state",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(ENV_DIR, dir.path())
        .env(ENV_LIBPYTHON, &runtime.libpython)
        .env("PYTHONHOME", &runtime.home)
        .env("PYTHONNOUSERSITE", "1")
        .env_remove("PYTHONPATH")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // A deadlock is a failure, not a hung suite: the child gets ten minutes (it takes seconds).
    let pid = child.id();
    let (done, finished) = mpsc::channel();
    let watchdog = std::thread::spawn(move || {
        if finished.recv_timeout(Duration::from_secs(600)).is_err() {
            // SAFETY: kill(2) of our own child, still unreaped (the main thread is waiting).
            unsafe { libc::kill(pid as i32, libc::SIGKILL) };
        }
    });
    let out = child.wait_with_output().unwrap();
    let _ = done.send(());
    watchdog.join().unwrap();
    assert_child_test_ran(&out);
}

/// The functions of the child's libpython that tell whether this thread has a thread state.
struct Probe {
    this_thread_state: unsafe extern "C" fn() -> *mut c_void,
    gil_ensure: unsafe extern "C" fn() -> c_int,
    gil_release: unsafe extern "C" fn(c_int),
    is_initialized: unsafe extern "C" fn() -> c_int,
    _lib: libloading::os::unix::Library,
}

impl Probe {
    /// Makes `libpython` global (as `--preload` does) and resolves the probes.
    fn load(libpython: &Path) -> Probe {
        // SAFETY: loading libpython runs no Python; the symbols are read with their C types.
        unsafe {
            let lib = libloading::os::unix::Library::open(
                Some(libpython),
                libloading::os::unix::RTLD_NOW | libloading::os::unix::RTLD_GLOBAL,
            )
            .expect("load libpython globally");
            Probe {
                this_thread_state: *lib.get(b"PyGILState_GetThisThreadState\0").unwrap(),
                gil_ensure: *lib.get(b"PyGILState_Ensure\0").unwrap(),
                gil_release: *lib.get(b"PyGILState_Release\0").unwrap(),
                is_initialized: *lib.get(b"Py_IsInitialized\0").unwrap(),
                _lib: lib,
            }
        }
    }

    /// Whether the calling thread has a Python thread state.
    fn held(&self) -> bool {
        // SAFETY: needs no GIL; only called once the interpreter is initialised.
        unsafe {
            assert_ne!((self.is_initialized)(), 0, "the interpreter is not running");
            !(self.this_thread_state)().is_null()
        }
    }
}

fn options(state: PythonThreadState) -> LoadOptions {
    LoadOptions {
        python_thread_state: state,
        ..LoadOptions::default()
    }
}

fn inputs() -> Results {
    Results::read_csv(INPUTS.as_bytes(), Path::new("inputs")).unwrap()
}

fn signal() -> Signal {
    let csv = inputs();
    Signal {
        times: csv.times(),
        values: csv.column("u").unwrap(),
        interpolate: true,
    }
}

/// A system of `names` lags of `fmu` (gain `k` = 2, 2.5, 3, ...), each fed the input.
fn lags(fmu: &Fmu, names: &[&str]) -> System {
    let mut system = System::new();
    for (i, name) in names.iter().enumerate() {
        system.add_component(name, fmu.clone()).unwrap();
        system
            .set_value(&format!("{name}.k"), Value::Real(2.0 + 0.5 * i as f64))
            .unwrap();
        system.add_signal(&format!("{name}.u"), signal()).unwrap();
    }
    system
}

fn run(system: &System, parallel: bool) -> Results {
    let config = RunConfig {
        stop_time: STOP,
        step_size: STEP,
        parallel,
        ..RunConfig::default()
    };
    let out = system.run(&config).unwrap();
    assert!(
        matches!(out.outcome, Outcome::Completed { .. }),
        "{:?}",
        out.outcome
    );
    out.results
}

/// Every column equal bit for bit, and the run did something.
fn assert_bits(a: &Results, b: &Results, what: &str) {
    assert_eq!(a.names(), b.names(), "{what}: columns");
    assert_eq!(a.len(), 2001, "{what}: rows");
    assert_eq!(a.len(), b.len(), "{what}: rows");
    let bits = |v: Vec<f64>| v.into_iter().map(f64::to_bits).collect::<Vec<_>>();
    assert_eq!(bits(a.times()), bits(b.times()), "{what}: time");
    for name in a.names() {
        let (x, y) = (a.column(name).unwrap(), b.column(name).unwrap());
        assert_eq!(bits(x), bits(y), "{what}: {name}");
    }
    let first_y = a
        .names()
        .iter()
        .find(|n| n.ends_with(".y"))
        .unwrap()
        .clone();
    let y = a.column(&first_y).unwrap();
    assert!(
        y.iter().any(|&v| v > 1.5) && y.iter().any(|&v| v < 0.0),
        "{what}: {y:?}"
    );
}

fn vr(fmu: &Fmu, name: &str) -> u32 {
    fmu.variable(name).unwrap().value_reference
}

/// An instance of `fmu` initialised and stepped `steps` times with u = 1.
fn stepped(fmu: &Fmu, name: &str, steps: u32) -> Instance {
    let mut inst = fmu.instantiate(name, &InstanceOptions::default()).unwrap();
    inst.setup_experiment(None, 0.0, None).unwrap();
    inst.enter_initialization_mode().unwrap();
    inst.exit_initialization_mode().unwrap();
    step(fmu, &mut inst, 0, steps);
    inst
}

/// Steps `inst` from step `from` for `steps` steps with u = 1; y after the last.
fn step(fmu: &Fmu, inst: &mut Instance, from: u32, steps: u32) -> f64 {
    let (u, y) = (vr(fmu, "u"), vr(fmu, "y"));
    let mut out = [0.0];
    for n in from..from + steps {
        inst.set_real(&[u], &[1.0]).unwrap();
        inst.do_step(f64::from(n) * STEP, STEP).unwrap();
        inst.get_real(&[y], &mut out).unwrap();
    }
    out[0]
}

/// The child half of [`python_thread_state_kept_gives_the_same_results_as_per_call`].
#[test]
#[ignore = "run in a child process by python_thread_state_kept_gives_the_same_results_as_per_call"]
fn child_keeps_the_python_thread_state() {
    let dir = PathBuf::from(std::env::var_os(ENV_DIR).expect("run by the parent test"));
    let libpython = PathBuf::from(std::env::var_os(ENV_LIBPYTHON).unwrap());
    let fmu_path = dir.join("FirstOrder.fmu");
    let probe = Probe::load(&libpython);

    // Isolated first: each instance in a host process, which loads libpython itself.
    let isolated = |state| {
        let fmu = Fmu::load(
            &fmu_path,
            &LoadOptions {
                isolation: Isolation::Process,
                preload: vec![libpython.clone()],
                ..options(state)
            },
        )
        .unwrap();
        assert!(fmu.is_isolated());
        run(&lags(&fmu, &["lag"]), false)
    };
    let iso_kept = isolated(PythonThreadState::Kept);
    let iso_per_call = isolated(PythonThreadState::PerCall);
    assert_bits(&iso_kept, &iso_per_call, "isolated");

    // In process, after the hosts: both loads share the one binary.
    let kept = Fmu::load(&fmu_path, &options(PythonThreadState::Kept)).unwrap();
    let per_call = Fmu::load(&fmu_path, &options(PythonThreadState::PerCall)).unwrap();
    assert_eq!(kept.binary_path(), per_call.binary_path(), "one binary");
    let one_kept = run(&lags(&kept, &["lag"]), false);
    let one_per_call = run(&lags(&per_call, &["lag"]), false);
    assert_bits(&one_kept, &one_per_call, "one instance");
    assert_bits(&one_kept, &iso_kept, "in process vs isolated");
    // The run's instances are freed at its end, and the thread state with them.
    assert!(
        !probe.held(),
        "a thread state left behind by a finished run"
    );

    // A binary without an embedded CPython gets none, even with Python running in the process.
    let gait = Fmu::load(exported_fmu("GaitReference"), &LoadOptions::default()).unwrap();
    let mut g = gait
        .instantiate("gait", &InstanceOptions::default())
        .unwrap();
    g.setup_experiment(None, 0.0, None).unwrap();
    g.enter_initialization_mode().unwrap();
    g.exit_initialization_mode().unwrap();
    g.do_step(0.0, STEP).unwrap();
    assert!(!probe.held(), "a thread state for a binary without Python");
    drop(g);

    // Several instances, sequential and stepped in parallel (a thread per component and step).
    let names = ["a", "b", "c"];
    let three_per_call = run(&lags(&per_call, &names), false);
    assert_bits(&run(&lags(&kept, &names), false), &three_per_call, "three");
    assert_bits(
        &run(&lags(&kept, &names), true),
        &three_per_call,
        "parallel",
    );
    assert!(!probe.held());

    // The thread state is kept while an instance lives, shared by the thread's instances, and
    // released with the last one; per call, none is left between calls.
    let first = stepped(&kept, "first", 10);
    assert!(probe.held(), "no thread state kept between calls");
    let mut second = stepped(&kept, "second", 10);
    drop(first);
    assert!(probe.held(), "released while an instance still uses it");
    let y_kept = step(&kept, &mut second, 10, 10);
    drop(second);
    assert!(!probe.held(), "not released with the last instance");
    // An instance freed while its thread holds the GIL (entered Python on the kept thread
    // state): the thread state cannot be released then (that would wait for the GIL forever);
    // it is released at the thread's next free once the GIL is let go.
    let inside = stepped(&kept, "inside", 1);
    // SAFETY: the interpreter is running; Ensure and Release are paired on this thread.
    let gil = unsafe { (probe.gil_ensure)() };
    drop(inside);
    assert!(probe.held(), "released while this thread held the GIL");
    unsafe { (probe.gil_release)(gil) };
    assert!(probe.held(), "the thread state went with the GIL");
    drop(stepped(&kept, "after", 1));
    assert!(!probe.held(), "not released at the next free");

    let mut plain = stepped(&per_call, "plain", 0);
    let y_plain = step(&per_call, &mut plain, 0, 20);
    assert!(!probe.held(), "a thread state kept per call");
    assert_eq!(y_kept.to_bits(), y_plain.to_bits());
    drop(plain);

    // An instance moved between threads: counted on each thread it is called from; the first
    // thread, left with a thread state nobody counts, releases it when it ends.
    let (to_main, from_worker) = mpsc::channel::<Instance>();
    let (to_worker, from_main) = mpsc::channel::<()>();
    let y_moved = std::thread::scope(|s| {
        let (kept, probe) = (&kept, &probe);
        let worker = s.spawn(move || {
            let inst = stepped(kept, "moved", 10);
            let held_here = probe.held();
            to_main.send(inst).unwrap();
            from_main.recv().unwrap();
            held_here
        });
        let mut moved = from_worker.recv().unwrap();
        let y = step(kept, &mut moved, 10, 10);
        assert!(probe.held(), "no thread state on the thread it moved to");
        drop(moved);
        assert!(!probe.held());
        to_worker.send(()).unwrap();
        assert!(worker.join().unwrap(), "no thread state on the worker");
        y
    });
    assert_eq!(y_moved.to_bits(), y_kept.to_bits());

    // A sweep with two workers (each counts its instances on its own thread) against the same
    // points run per call, one by one: the lag driven by a constant input u rises
    // monotonically, so its maximum is its last value.
    let ssd_path = dir.join("lag.ssd");
    let (_, md) =
        kneebench_harness::load::extract_and_parse(&fmu_path, &Default::default()).unwrap();
    ssp::write_ssd_file(
        &Ssd {
            name: "Lag".into(),
            version: "1.0".into(),
            system: SspSystem {
                name: "Lag".into(),
                components: vec![SspComponent::from_model_description(
                    "lag",
                    "FirstOrder.fmu",
                    &md,
                )],
                connections: Vec::new(),
            },
            default_experiment: Some(SspExperiment {
                start_time: Some(0.0),
                stop_time: Some(0.5),
                step_size: Some(STEP),
                algorithm: None,
            }),
        },
        &ssd_path,
    )
    .unwrap();
    let gains = [1.0, 2.0, 3.0, 4.0];
    let spec = format!(
        "system = \"lag.ssd\"\n[design]\nkind = \"grid\"\n[[parameters]]\nname = \"lag.k\"\n\
         values = {gains:?}\n[[parameters]]\nname = \"lag.u\"\nvalues = [0.75]\n\
         [metrics]\n[[metrics.signals]]\nsignal = \"lag.y\"\nstats = [\"max\"]\n"
    );
    let prepared =
        Prepared::new(SweepSpec::parse(&spec, Path::new("spec.toml"), &dir).unwrap()).unwrap();
    let table = run_sweep(
        &prepared,
        None,
        &SweepOptions {
            workers: 2,
            ..SweepOptions::default()
        },
    )
    .unwrap();
    drop(prepared);
    assert_eq!(table.rows.len(), gains.len());
    for row in &table.rows {
        assert_eq!(row.status, RunStatus::Ok, "{}", row.message);
        let mut system = System::new();
        system.add_component("lag", per_call.clone()).unwrap();
        system
            .set_value("lag.k", Value::Real(row.parameters[0]))
            .unwrap();
        system.set_value("lag.u", Value::Real(0.75)).unwrap();
        let config = RunConfig {
            stop_time: 0.5,
            step_size: STEP,
            ..RunConfig::default()
        };
        let y = system
            .run(&config)
            .unwrap()
            .results
            .column("lag.y")
            .unwrap();
        let last = *y.last().unwrap();
        assert!(
            last > 0.5 * row.parameters[0] * 0.75,
            "the lag did not rise: {last}"
        );
        assert_eq!(row.metrics, vec![last], "k = {}", row.parameters[0]);
    }
    assert!(!probe.held());
}
