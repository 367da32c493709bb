//! The PythonFMU export used as the foreign FMU of the tests (`tests/tests/foreign_fmu.rs`) and
//! of the peer comparison (`tests/peers/benches/peers.rs`): its Python source, the build through the
//! venv's `pythonfmu`, and the Python runtime a non-Python host must provide (see the module
//! documentation of `foreign_fmu.rs` for why).

use std::path::{Path, PathBuf};
use std::process::Command;

/// The foreign model: a first-order lag `y' = (k u - y) / tau` (exact discretisation per step)
/// with a step counter and a Boolean threshold output. (PythonFMU gives every variable
/// `continuous` variability unless told otherwise, which fmpy rejects for Integer and Boolean.)
pub const FIRST_ORDER: &str = r#"
import math

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Boolean, Integer, Real
from pythonfmu.default_experiment import DefaultExperiment


class FirstOrder(Fmi2Slave):
    author = "kneebench tests"
    description = "First-order lag y' = (k u - y) / tau, exact discretisation per step"
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=2.0, step_size=0.001)

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.k = 2.0
        self.tau = 0.125
        self.limit = 1.5
        self.u = 0.0
        self.y = 0.0
        self.steps = 0
        self.saturated = False
        self.register_variable(Real("k", causality=Fmi2Causality.parameter, variability=Fmi2Variability.tunable))
        self.register_variable(Real("tau", causality=Fmi2Causality.parameter, variability=Fmi2Variability.tunable))
        self.register_variable(Real("limit", causality=Fmi2Causality.parameter, variability=Fmi2Variability.tunable))
        self.register_variable(Real("u", causality=Fmi2Causality.input))
        self.register_variable(Real("y", causality=Fmi2Causality.output))
        self.register_variable(Integer("steps", causality=Fmi2Causality.output, variability=Fmi2Variability.discrete))
        self.register_variable(Boolean("saturated", causality=Fmi2Causality.output, variability=Fmi2Variability.discrete))

    def do_step(self, current_time, step_size):
        a = math.exp(-step_size / self.tau)
        self.y = a * self.y + (1.0 - a) * self.k * self.u
        self.steps += 1
        self.saturated = self.y > self.limit
        return True
"#;

/// The Python runtime a host must provide to a PythonFMU export built by `python`.
pub struct PythonRuntime {
    /// The shared libpython (`sysconfig`: `LIBDIR/LDLIBRARY`), to preload globally.
    pub libpython: PathBuf,
    /// `sys.base_prefix`, for `PYTHONHOME`.
    pub home: PathBuf,
}

/// Runs `python -c script args...`; its stdout, or a message with its stderr.
fn python_output(python: &Path, script: &str, args: &[&std::ffi::OsStr]) -> Result<String, String> {
    let out = Command::new(python)
        .arg("-c")
        .arg(script)
        .args(args)
        .output()
        .map_err(|e| format!("cannot run {}: {e}", python.display()))?;
    if !out.status.success() {
        return Err(format!(
            "{} failed:\n{}{}",
            python.display(),
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    String::from_utf8(out.stdout).map_err(|e| format!("python printed non-UTF-8: {e}"))
}

/// The shared runtime and `sys.base_prefix` of `python`; an error if that Python has no shared
/// libpython (built without `--enable-shared`: PythonFMU binaries cannot be hosted outside it).
pub fn runtime(python: &Path) -> Result<PythonRuntime, String> {
    let out = python_output(
        python,
        "import os, sys, sysconfig\n\
         print(os.path.join(sysconfig.get_config_var('LIBDIR'), sysconfig.get_config_var('LDLIBRARY')))\n\
         print(sys.base_prefix)",
        &[],
    )?;
    let mut lines = out.lines();
    let (Some(lib), Some(home)) = (lines.next(), lines.next()) else {
        return Err(format!("unexpected sysconfig answer: {out:?}"));
    };
    let libpython = PathBuf::from(lib);
    if !libpython.is_file() {
        return Err(format!(
            "{}: not a file; PythonFMU needs a Python built with --enable-shared",
            libpython.display()
        ));
    }
    Ok(PythonRuntime {
        libpython,
        home: PathBuf::from(home),
    })
}

/// Runs `pythonfmu build -f FirstOrder.py --dest DIR` (as `python -m pythonfmu`, i.e. the
/// venv's entry point) on [`FIRST_ORDER`] and returns `DIR/FirstOrder.fmu`.
pub fn build_first_order(python: &Path, dir: &Path) -> Result<PathBuf, String> {
    let src = dir.join("src");
    std::fs::create_dir_all(&src).map_err(|e| format!("{}: {e}", src.display()))?;
    let script = src.join("FirstOrder.py");
    std::fs::write(&script, FIRST_ORDER).map_err(|e| format!("{}: {e}", script.display()))?;
    let out = Command::new(python)
        .args(["-m", "pythonfmu", "build", "-f"])
        .arg(&script)
        .arg("--dest")
        .arg(dir)
        .output()
        .map_err(|e| format!("cannot run {}: {e}", python.display()))?;
    if !out.status.success() {
        return Err(format!(
            "pythonfmu build failed:\n{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    let fmu = dir.join("FirstOrder.fmu");
    if !fmu.is_file() {
        return Err(format!("pythonfmu wrote no {}", fmu.display()));
    }
    Ok(fmu)
}
