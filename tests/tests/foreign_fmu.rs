//! An FMU from another exporter: PythonFMU (PyPI `pythonfmu`, pinned in
//! `scripts/requirements.txt`) builds an FMU from a Python class inside the test; our harness
//! loads and runs it, and fmpy runs the same FMU on the same grid with the same inputs: the
//! values agree to 1e-12 (in practice bit for bit: both drive the same Python code).
//!
//! # What a PythonFMU export needs from a non-Python host
//!
//! Read from the pythonfmu 0.7.0 wheel and the sources of its C++ export layer
//! (`pythonfmu-export/src/pythonfmu/PyState.hpp`, `PySlaveInstance.cpp`, `builder.py`):
//!
//! - **libpython, preloaded globally.** `binaries/linux64/<id>.so` leaves every `Py*` symbol
//!   undefined and does not link libpython (`ldd` shows only libstdc++, libgcc, libc, libm): the
//!   host must have made the runtime's symbols global before `dlopen`, i.e.
//!   [`LoadOptions::preload`] (`RTLD_NOW | RTLD_GLOBAL`) with the shared libpython of the Python
//!   that built the FMU (`sysconfig`: `LIBDIR/LDLIBRARY`, here pyenv's
//!   `libpython3.11.so`). Without it `dlopen` fails (`undefined symbol: _Py_NoneStruct`), which
//!   the harness reports with a hint to preload: tested below.
//! - **The standard library.** On the first `fmi2Instantiate`, if `Py_IsInitialized()` is false,
//!   a worker thread calls `Py_SetProgramName("./PythonFMU"); Py_Initialize()` and releases the
//!   GIL (every FMI call then takes it with `PyGILState_Ensure`). Python finds its standard
//!   library by the usual `getpath` rules: `PYTHONHOME` if set, else landmarks next to the
//!   program (there is none: `./PythonFMU` does not exist), else the prefix compiled into
//!   libpython. pyenv's build has its real prefix compiled in, so nothing is needed here (an
//!   empty environment works); a relocated Python (a copied or "standalone" build) needs
//!   `PYTHONHOME = sys.base_prefix`, and a wrong `PYTHONHOME` is a `Py_FatalError` ("No module
//!   named 'encodings'") that aborts the host process. The test sets `PYTHONHOME` to the venv's
//!   `sys.base_prefix` explicitly, so it does not depend on that detail.
//! - **pythonfmu and the slave module.** The builder copies the slave script and pythonfmu's own
//!   `*.py` files into `resources/` (`resources/pythonfmu/`), writes the module name to
//!   `resources/slavemodule.txt`, and the instance constructor inserts the resources directory
//!   (from `fmuResourceLocation`) at `sys.path[0]` before importing the module. So neither
//!   `PYTHONPATH` nor the venv's site-packages is needed, unless the slave imports third-party
//!   packages (numpy, ...): then `PYTHONPATH` must name a site-packages of the same Python
//!   version. The child gets `PYTHONPATH` removed and `PYTHONNOUSERSITE=1`, proving that.
//! - **One interpreter per process.** The interpreter is process-global: the binary's static
//!   `PyState` calls `Py_Finalize` when the library is unloaded, and a second copy of the
//!   binary loaded meanwhile reuses the running interpreter. A failed `Py_Initialize` aborts
//!   the process. So the harness half of the test runs in a child process (this test binary,
//!   re-executed on the `#[ignore]`d test [`child_runs_the_pythonfmu_export`]) with exactly the
//!   environment above; the parent builds the FMU, runs fmpy, and compares.
//!
//! The CLI path (`kneebench run FMU --preload LIB --inputs CSV --param k=3`) is exercised in
//! the child too, through the CLI's own sources compiled into this test (the `kneebench`
//! binary is not built by `cargo test -p kneebench-tests`).

use std::path::{Path, PathBuf};
use std::process::Command;

use clap::Parser;

use kneebench_harness::master::Signal;
use kneebench_harness::{Fmu, LoadError, LoadOptions, Outcome, Results, RunConfig, System};
use kneebench_tests::*;

#[allow(dead_code, unused_imports)]
#[path = "../../harness/src/cli/mod.rs"]
mod cli;

/// A piecewise-linear input (no repeated times, so fmpy sees no input events and keeps the
/// regular grid), interpolated linearly by both importers.
const INPUTS: &str = "time,u\n0.0,0.0\n0.3,0.5\n0.7,1.0\n1.2,-0.25\n2.0,0.4\n";

const STOP: f64 = 2.0;
const STEP: f64 = 0.001;

/// The environment variables the child reads.
const ENV_DIR: &str = "KNEEBENCH_FOREIGN_DIR";
const ENV_LIBPYTHON: &str = "KNEEBENCH_FOREIGN_LIBPYTHON";

/// The venv Python's shared runtime and `sys.base_prefix`.
fn python_runtime() -> (PathBuf, PathBuf) {
    let runtime = pythonfmu::runtime(&python()).unwrap();
    (runtime.libpython, runtime.home)
}

/// Builds the FirstOrder export ([`pythonfmu::FIRST_ORDER`]) into `dir`.
fn build_fmu(dir: &Path) -> PathBuf {
    pythonfmu::build_first_order(&python(), dir).unwrap()
}

/// fmpy's co-simulation of `fmu` on the grid 0, STEP, ..., STOP with the inputs and the given
/// start values; every output, in the format of `scripts/fmpy_check.py`.
fn fmpy_simulate(fmu: &Path, inputs: &Path, start_values: &str, out: &Path) -> Results {
    const SCRIPT: &str = r#"
import ast, sys
import numpy as np
from fmpy import read_model_description, simulate_fmu
fmu, inputs, start, out, stop, step = sys.argv[1:]
md = read_model_description(fmu)
outputs = [v.name for v in md.modelVariables if v.causality == "output"]
data = np.genfromtxt(inputs, delimiter=",", names=True, deletechars="")
r = simulate_fmu(fmu, fmi_type="CoSimulation", start_time=0.0, stop_time=float(stop),
                 step_size=float(step), output_interval=float(step), output=outputs,
                 input=data, start_values=ast.literal_eval(start))
with open(out, "w") as f:
    f.write(",".join(["time"] + outputs) + "\n")
    for row in r:
        f.write(",".join(repr(float(row[n])) for n in ["time"] + outputs) + "\n")
"#;
    run_python(
        SCRIPT,
        &[
            &fmu.display().to_string(),
            &inputs.display().to_string(),
            start_values,
            &out.display().to_string(),
            &STOP.to_string(),
            &STEP.to_string(),
        ],
    );
    Results::read_csv_file(out).unwrap()
}

fn assert_same(ours: &Results, theirs: &Results, what: &str) {
    assert_eq!(ours.len(), theirs.len(), "{what}: row count");
    assert_eq!(ours.len(), 2001, "{what}: rows");
    assert_eq!(ours.names(), theirs.names(), "{what}: columns");
    for name in theirs.names() {
        let (a, b) = (ours.column(name).unwrap(), theirs.column(name).unwrap());
        for (k, (x, y)) in a.iter().zip(&b).enumerate() {
            assert!(
                (x - y).abs() <= 1e-12 * (1.0 + x.abs().max(y.abs())),
                "{what}: {name} row {k}: ours {x} vs fmpy {y}"
            );
        }
    }
    for (k, (x, y)) in ours.times().iter().zip(theirs.times()).enumerate() {
        assert!((x - y).abs() <= 1e-12, "{what}: time row {k}: {x} vs {y}");
    }
}

#[test]
fn pythonfmu_export_runs_in_the_harness_like_in_fmpy() {
    let dir = tempfile::tempdir().unwrap();
    let fmu = build_fmu(dir.path());
    let inputs = dir.path().join("inputs.csv");
    std::fs::write(&inputs, INPUTS).unwrap();
    let (libpython, home) = python_runtime();

    // fmpy, in its own (Python) host: the defaults, and k = 3 as the CLI run sets it.
    let fmpy_default = fmpy_simulate(&fmu, &inputs, "{}", &dir.path().join("fmpy.csv"));
    let fmpy_k3 = fmpy_simulate(&fmu, &inputs, "{'k': 3.0}", &dir.path().join("fmpy-k3.csv"));
    // The run does something: the lag follows the input and crosses the threshold.
    let y = fmpy_default.column("y").unwrap();
    assert!(y.iter().any(|&v| v > 1.5) && y.iter().any(|&v| v < 0.0));
    assert_eq!(fmpy_default.column("steps").unwrap()[2000], 2000.0);

    // Our harness, in a child process with the Python environment documented above.
    let out = Command::new(std::env::current_exe().unwrap())
        .args([
            "--ignored",
            "--exact",
            "child_runs_the_pythonfmu_export",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(ENV_DIR, dir.path())
        .env(ENV_LIBPYTHON, &libpython)
        .env("PYTHONHOME", &home)
        .env("PYTHONNOUSERSITE", "1")
        .env_remove("PYTHONPATH")
        .output()
        .unwrap();
    assert_child_test_ran(&out);

    let ours = Results::read_csv_file(dir.path().join("harness.csv")).unwrap();
    assert_same(&ours, &fmpy_default, "library run");
    let cli = Results::read_csv_file(dir.path().join("cli.csv")).unwrap();
    assert_same(&cli, &fmpy_k3, "CLI run with k=3");
    assert_ne!(
        cli.column("y").unwrap()[1000],
        ours.column("y").unwrap()[1000],
        "the parameter had no effect"
    );
}

/// The harness half of [`pythonfmu_export_runs_in_the_harness_like_in_fmpy`], run by it in a
/// child process (see the module documentation).
#[test]
#[ignore = "run in a child process by pythonfmu_export_runs_in_the_harness_like_in_fmpy"]
fn child_runs_the_pythonfmu_export() {
    let dir = PathBuf::from(std::env::var_os(ENV_DIR).expect("run by the parent test"));
    let libpython = PathBuf::from(std::env::var_os(ENV_LIBPYTHON).unwrap());
    let fmu_path = dir.join("FirstOrder.fmu");

    // Without the runtime the binary cannot be loaded, and the error says what to do.
    let err = Fmu::load(&fmu_path, &LoadOptions::default()).unwrap_err();
    assert!(matches!(err, LoadError::Library { .. }), "{err:?}");
    let msg = err.to_string();
    assert!(
        msg.contains("undefined symbol") && msg.contains("preload"),
        "{msg}"
    );

    let options = LoadOptions {
        preload: vec![libpython.clone()],
        ..LoadOptions::default()
    };
    let fmu = Fmu::load(&fmu_path, &options).expect("load the PythonFMU export");
    let md = fmu.model_description();
    assert!(
        md.generation_tool
            .as_deref()
            .unwrap_or_default()
            .starts_with("PythonFMU 0.7.0"),
        "{:?}",
        md.generation_tool
    );

    // Library path: one component, the input fed from the CSV, linear interpolation.
    let csv = Results::read_csv(INPUTS.as_bytes(), Path::new("inputs")).unwrap();
    let mut system = System::new();
    system.add_component("lag", fmu.clone()).unwrap();
    system.set_column_prefix(false);
    system
        .add_signal(
            "lag.u",
            Signal {
                times: csv.times(),
                values: csv.column("u").unwrap(),
                interpolate: true,
            },
        )
        .unwrap();
    let config = RunConfig {
        stop_time: STOP,
        step_size: STEP,
        ..RunConfig::default()
    };
    let out = system.run(&config).unwrap();
    assert!(
        matches!(out.outcome, Outcome::Completed { .. }),
        "{:?}",
        out.outcome
    );
    assert_eq!(out.steps_per_component, vec![2000]);
    out.results.write_csv_file(dir.join("harness.csv")).unwrap();

    // CLI path, with the first FMU still loaded (the second copy of the binary reuses the
    // interpreter): `kneebench run FirstOrder.fmu --preload LIBPYTHON --inputs ... --param k=3`.
    // PythonFMU's description lists no InitialUnknowns for its calculated outputs, a problem
    // `kneebench validate` reports: `run` refuses it (usage error) unless `--force`.
    let inputs = dir.join("inputs.csv");
    let cli_out = dir.join("cli.csv");
    let run = |force: bool, extra: &[&str]| {
        let mut args: Vec<&std::ffi::OsStr> = vec![
            "kneebench".as_ref(),
            "run".as_ref(),
            fmu_path.as_os_str(),
            "--preload".as_ref(),
            libpython.as_os_str(),
            "--inputs".as_ref(),
            inputs.as_os_str(),
            "--param".as_ref(),
            "k=3".as_ref(),
            "--output".as_ref(),
            cli_out.as_os_str(),
            "--quiet".as_ref(),
        ];
        if force {
            args.push("--force".as_ref());
        }
        args.extend(extra.iter().map(std::ffi::OsStr::new));
        cli::dispatch(cli::Cli::try_parse_from(args).unwrap()).unwrap()
    };
    assert_eq!(run(false, &[]), cli::EXIT_USAGE);
    assert!(!cli_out.exists());
    assert_eq!(run(true, &[]), cli::EXIT_OK);
    // `--python-thread-state per-call` (the binary's own behaviour) gives the same file as the
    // default (a thread state kept), in the host process and in this one.
    let kept = std::fs::read(&cli_out).unwrap();
    for isolate in ["auto", "never"] {
        let extra = ["--python-thread-state", "per-call", "--isolate", isolate];
        assert_eq!(run(true, &extra), cli::EXIT_OK, "{extra:?}");
        assert!(std::fs::read(&cli_out).unwrap() == kept, "{extra:?}");
    }
    let e = cli::Cli::try_parse_from([
        "kneebench",
        "run",
        "x.fmu",
        "--python-thread-state",
        "sometimes",
    ])
    .unwrap_err()
    .to_string();
    assert!(e.contains("'sometimes'") && e.contains("per-call"), "{e}");
    drop(fmu);
}
