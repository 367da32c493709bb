//! `kneebench._native`: the Rust side of the `kneebench` Python package (see
//! `python/kneebench/__init__.py` for the public API, which wraps these functions and builds
//! pandas DataFrames).
//!
//! Every function runs its simulation with the GIL released (`Python::detach`) and raises
//! `kneebench.KneebenchError` (`SpecError` for a refused sweep spec) with the Rust message.
//! Sweeps: `sweep` (local), `sweep_info`, `sweep_points` and `SweepJournal` (Dask);
//! optimisations: `optimize` (local), `optimize_info`, the ask/tell `Optimizer` and
//! `optimize_points` (Dask). A sweep refuses a spec with `[optimize]`, an optimisation one
//! without.
//! Columns cross as little-endian float64 bytes (read with `numpy.frombuffer`, no copy per
//! value).

use std::path::{Path, PathBuf};

use kneebench_harness::master::{Outcome, RunConfig, RunControl, System, Value};
use kneebench_harness::params::check_system_start_value;
use kneebench_harness::results::columns::{ColumnMajor, Columns};
use kneebench_harness::study::{
    Actuator, ActuatorReport, StudyConfig, StudyScenario, run_study_with,
};
use kneebench_harness::sweep::optimize::GenerationBest;
use kneebench_harness::sweep::optimize::run_optimization;
use kneebench_harness::sweep::runner::run_sweep;
use kneebench_harness::sweep::runner::{STUDY_METRIC_UNITS, STUDY_METRICS, study_metric_values};
use kneebench_harness::sweep::{
    JournaledOptimization, JournaledSweep, Optimization, Optimizer, Prepared, Row, RunStatus,
    SweepError, SweepOptions, SweepSpec,
};
use kneebench_harness::{Fmu, Isolation, LoadOptions, conformance, ssp};
use model_description::VariableKind;
use numpy::{PyArray1, PyArrayMethods};
use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyList};

// Created in the `kneebench` module (re-exported there by `__init__.py`): an exception raised
// on a Dask worker is pickled by its module and name, and unpickled on the client as
// `kneebench.KneebenchError`, not as an unimportable `_native.KneebenchError`.
pyo3::create_exception!(
    kneebench,
    KneebenchError,
    PyRuntimeError,
    "An error of the kneebench harness (the message is the Rust error's)."
);
pyo3::create_exception!(
    kneebench,
    SpecError,
    KneebenchError,
    "A sweep spec refused before anything ran (one line per problem, each naming its line)."
);

fn err(e: impl std::fmt::Display) -> PyErr {
    KneebenchError::new_err(e.to_string())
}

fn sweep_err(e: SweepError) -> PyErr {
    match e {
        SweepError::Invalid(_) => SpecError::new_err(e.to_string()),
        e => err(e),
    }
}

/// How often a native call waiting for its work checks for Python signals (Ctrl-C).
const SIGNAL_POLL: std::time::Duration = std::time::Duration::from_millis(50);

/// Runs `work` on a thread of its own while this thread waits with the GIL released, taking
/// it back every [`SIGNAL_POLL`] to run Python's signal handlers (`py.check_signals`). A
/// handler that raises (`KeyboardInterrupt` on Ctrl-C) asks `control` to stop: the work ends
/// at its next communication point, and the handler's exception is returned once it has ended
/// (whatever the work returned). A panic of the work is a `KneebenchError`, not an abort, and
/// so is a thread that cannot start (a process or memory limit): the work is then not run.
fn interruptible<T: Send>(
    py: Python<'_>,
    control: &RunControl,
    work: impl FnOnce() -> T + Send,
) -> PyResult<T> {
    use std::sync::mpsc::RecvTimeoutError;
    let (tx, rx) = std::sync::mpsc::channel();
    // Behind a mutex to be `Sync` (`detach` needs it); only this thread takes it.
    let rx = std::sync::Mutex::new(rx);
    std::thread::scope(|scope| {
        // `scope.spawn` would panic when the thread cannot start.
        let worker = std::thread::Builder::new()
            .name("kneebench-run".into())
            .spawn_scoped(scope, move || {
                let _ = tx.send(work());
            })
            .map_err(|e| err(format!("cannot start a thread for the run: {e}")))?;
        let mut raised: Option<PyErr> = None;
        loop {
            let received = py.detach(|| match rx.lock() {
                Ok(rx) => rx.recv_timeout(SIGNAL_POLL),
                Err(_) => Err(RecvTimeoutError::Disconnected),
            });
            match received {
                Ok(value) => {
                    let _ = worker.join();
                    return match raised {
                        Some(e) => Err(e),
                        None => Ok(value),
                    };
                }
                Err(RecvTimeoutError::Timeout) => {
                    if raised.is_none()
                        && let Err(e) = py.check_signals()
                    {
                        control.request_stop();
                        raised = Some(e);
                    }
                }
                Err(RecvTimeoutError::Disconnected) => {
                    let _ = py.detach(|| worker.join());
                    return Err(raised.unwrap_or_else(|| err("internal error: the run panicked")));
                }
            }
        }
    })
}

fn f64_bytes(values: &[f64]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// Where `run` runs an FMU's binary: `isolate` is `"never"` (in this process), `"auto"` (a
/// host process for an FMU kneebench did not generate, as `kneebench run` does by default) or
/// `"always"`; `host` the host executable (`None`: found as the harness finds it, e.g.
/// `KNEEBENCH_FMU_HOST`); `preload` the libraries a host loads first (the interpreter's
/// libpython, for a PythonFMU export).
fn load_options(
    isolate: &str,
    host: Option<PathBuf>,
    preload: Vec<PathBuf>,
) -> Result<LoadOptions, String> {
    let isolation = Isolation::from_name(isolate).ok_or_else(|| {
        format!(
            "isolate must be {}, not {isolate:?}",
            Isolation::names_text()
        )
    })?;
    let mut options = LoadOptions {
        isolation,
        ..LoadOptions::default()
    };
    if isolation != Isolation::InProcess {
        options.host.helper = host;
        options.preload = preload;
    }
    Ok(options)
}

/// A system from an `.fmu` (columns named by variable) or an `.ssp`/`.ssd`, loaded with
/// `options`.
fn load(path: &Path, options: &LoadOptions) -> Result<(System, RunConfig, bool), String> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    match ext.as_str() {
        "fmu" => {
            let fmu = Fmu::load(path, options).map_err(|e| e.to_string())?;
            let md = fmu.model_description().clone();
            let name = md
                .co_simulation
                .as_ref()
                .map(|c| c.model_identifier.clone())
                .unwrap_or_else(|| "fmu".into());
            let mut system = System::new();
            system
                .add_component(&name, fmu)
                .map_err(|e| e.to_string())?;
            system.set_column_prefix(false);
            // The default experiment's times and tolerance, as `kneebench run` takes them.
            let config = RunConfig::of_fmu(&md);
            Ok((system, config, true))
        }
        "ssp" | "ssd" => {
            let loaded = ssp::load_system(path, options).map_err(|e| e.to_string())?;
            Ok((loaded.system, loaded.config, false))
        }
        _ => Err(format!(
            "{}: expected an .fmu, .ssp or .ssd file",
            path.display()
        )),
    }
}

fn unit_of(system: &System, single: bool, column: &str) -> String {
    let (comp, var) = if single {
        (system.component_names()[0].to_string(), column.to_string())
    } else {
        match column.split_once('.') {
            Some((c, v)) => (c.to_string(), v.to_string()),
            None => return String::new(),
        }
    };
    system
        .components()
        .find(|(n, _)| *n == comp)
        .and_then(|(_, f)| f.variable(&var))
        .and_then(|v| match &v.kind {
            VariableKind::Real { attributes, .. } => attributes.unit.clone(),
            _ => None,
        })
        .unwrap_or_default()
}

struct RunResult {
    names: Vec<String>,
    /// `time`'s values, then each named column's (`rows` each).
    columns: ColumnMajor,
    units: Vec<String>,
    status: &'static str,
    message: String,
}

/// The problems `kneebench validate` reports of a loaded FMU, which `kneebench run` refuses
/// without `--force` (`kneebench_harness::conformance`, shared with the CLI).
fn fmu_problems(fmu: &Fmu) -> Vec<String> {
    let mut problems = conformance::description_problems(fmu.model_description());
    problems.extend(conformance::binary_problems(fmu));
    problems
}

#[allow(clippy::too_many_arguments)]
fn run_inner(
    system: PathBuf,
    params: Vec<(String, String, bool)>,
    variables: Vec<String>,
    stop_time: Option<f64>,
    step: Option<f64>,
    force: bool,
    options: LoadOptions,
    control: RunControl,
) -> Result<RunResult, String> {
    let (mut sys, mut config, single) = load(&system, &options)?;
    if !force {
        let problems: Vec<String> = sys
            .components()
            .flat_map(|(name, fmu)| {
                fmu_problems(fmu)
                    .into_iter()
                    .map(move |p| format!("{name}: {p}"))
            })
            .collect();
        if !problems.is_empty() {
            return Err(format!(
                "{}: {} problem(s) that `kneebench validate` reports ({}); fix the FMU or pass \
                 force=True",
                system.display(),
                problems.len(),
                problems.join("; ")
            ));
        }
    }
    config.control = Some(control);
    let first = sys.component_names()[0].to_string();
    let prefix = |n: &str| {
        if single {
            format!("{first}.{n}")
        } else {
            n.to_string()
        }
    };
    for (name, value, number) in &params {
        let reference = prefix(name);
        let parsed = sys
            .parse_value_str(&reference, value)
            .map_err(|e| format!("params['{name}']: {e}"))?;
        // A number (or bool) would be set as its text ("1" for 1.0): a String takes a str.
        if *number && matches!(parsed, Value::String(_)) {
            return Err(format!(
                "params['{name}']: {value} is a number (or bool) and '{reference}' is a String \
                 variable: give its value as a str"
            ));
        }
        // What `kneebench run --param` refuses before the run (NaN, outside [min, max], no
        // item, not settable before initialization), refused here too: the FMU would refuse
        // it only as the run starts, with a message that does not name the parameter.
        check_system_start_value(&sys, &reference, &parsed)
            .map_err(|problem| format!("params['{name}']: {problem}"))?;
        sys.set_value(&reference, parsed)
            .map_err(|e| format!("params['{name}']: {e}"))?;
    }
    if !variables.is_empty() {
        let refs: Vec<String> = variables.iter().map(|v| prefix(v)).collect();
        let refs: Vec<&str> = refs.iter().map(String::as_str).collect();
        sys.record(&refs).map_err(|e| format!("variables: {e}"))?;
    }
    let config = config.with_times(None, stop_time, step);
    // Column by column: the layout of the data frame, handed over without a copy.
    let mut results = Columns::new();
    let summary = sys
        .run_into(&config, &mut results)
        .map_err(|e| e.to_string())?;
    let (status, message) = match summary.outcome {
        Outcome::Completed { .. } => ("completed", String::new()),
        Outcome::Terminated {
            component,
            last_successful_time,
            messages,
            ..
        } => (
            "terminated",
            format!(
                "component '{component}' ended the run at t = {last_successful_time}: {}",
                messages.join("; ")
            ),
        ),
        Outcome::Failed(e) => return Err(e.to_string()),
    };
    let mut names = vec!["time".to_string()];
    let mut units = vec!["s".to_string()];
    for n in results.names() {
        units.push(unit_of(&sys, single, n));
        names.push(n.clone());
    }
    Ok(RunResult {
        names,
        columns: results.into_column_major(),
        units,
        status,
        message,
    })
}

/// Runs an FMU or SSP system; returns `{"names", "values" (a float64 array of one row per
/// name, `time` first: column-major, the frame's block), "units",
/// "status", "message"}`. `params` are `(name, text, number)`: `number` when the caller gave
/// a number or a bool (its text as the package's `_text` writes it), which a String variable
/// refuses. An FMU with problems `kneebench validate` reports is refused unless `force`.
/// Ctrl-C stops the run at its next communication point and raises `KeyboardInterrupt`
/// ([`interruptible`]). `isolate`, `host` and `preload`: where the FMUs' binaries run
/// ([`load_options`]); a crash of an isolated one is a `KneebenchError`.
#[pyfunction]
#[pyo3(signature = (
    system, params, variables, stop_time=None, step=None, force=false, isolate="never",
    host=None, preload=Vec::new()
))]
#[allow(clippy::too_many_arguments)]
fn run<'py>(
    py: Python<'py>,
    system: PathBuf,
    params: Vec<(String, String, bool)>,
    variables: Vec<String>,
    stop_time: Option<f64>,
    step: Option<f64>,
    force: bool,
    isolate: &str,
    host: Option<PathBuf>,
    preload: Vec<PathBuf>,
) -> PyResult<Bound<'py, PyDict>> {
    let options = load_options(isolate, host, preload).map_err(err)?;
    let control = RunControl::new();
    let c = control.clone();
    let r = interruptible(py, &control, move || {
        run_inner(
            system, params, variables, stop_time, step, force, options, c,
        )
    })?
    .map_err(err)?;
    let d = PyDict::new(py);
    d.set_item("names", r.names)?;
    // One array of `columns x rows` owning the run's buffer (no copy): its transpose is the
    // frame's one block of floats.
    let (width, rows) = (r.columns.names.len() + 1, r.columns.rows);
    let values = PyArray1::from_vec(py, r.columns.values).reshape([width, rows])?;
    d.set_item("values", values)?;
    d.set_item("units", r.units)?;
    d.set_item("status", r.status)?;
    d.set_item("message", r.message)?;
    Ok(d)
}

/// A study run's report: `actuator`, the study metrics, `trip` (the interlock, or `None`),
/// `status` (`ok`, `tripped`: an interlock ended it, `failed`: the run failed, its error in
/// `message`, its trip `None` and `trip_time` NaN) and `message`.
fn report_dict<'py>(
    py: Python<'py>,
    r: &ActuatorReport,
    outcome: &Outcome,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("actuator", &r.name)?;
    let (status, message, r) = match outcome {
        Outcome::Failed(e) => {
            let mut r = r.clone();
            r.trip = None;
            (
                "failed",
                format!("run failed: {e}"),
                std::borrow::Cow::Owned(r),
            )
        }
        Outcome::Terminated { .. } => (
            "tripped",
            r.trip.as_ref().map(|t| t.0.clone()).unwrap_or_default(),
            std::borrow::Cow::Borrowed(r),
        ),
        Outcome::Completed { .. } if r.trip.is_some() => (
            "tripped",
            r.trip.as_ref().map(|t| t.0.clone()).unwrap_or_default(),
            std::borrow::Cow::Borrowed(r),
        ),
        Outcome::Completed { .. } => ("ok", String::new(), std::borrow::Cow::Borrowed(r)),
    };
    let r = r.as_ref();
    d.set_item("status", status)?;
    d.set_item("message", message)?;
    let values = study_metric_values(r);
    for (k, v) in STUDY_METRICS.iter().zip(values) {
        if *k == "cycles" {
            d.set_item(k, r.cycles)?;
        } else {
            d.set_item(k, v)?;
        }
    }
    d.set_item("trip", r.trip.as_ref().map(|t| t.0.clone()))?;
    Ok(d)
}

/// Runs the DA/SEA/CSEA study (`scenario`: bench-full or bench-clutch); returns one report
/// dict per actuator. `actuators` `None`: the scenario's own.
#[pyfunction]
#[pyo3(signature = (fmus, out, actuators, cycles, scale, scenario))]
fn study<'py>(
    py: Python<'py>,
    fmus: PathBuf,
    out: PathBuf,
    actuators: Option<Vec<String>>,
    cycles: u32,
    scale: f64,
    scenario: String,
) -> PyResult<Vec<Bound<'py, PyDict>>> {
    let study_scenario = StudyScenario::from_name(&scenario).ok_or_else(|| {
        err(format!(
            "unknown scenario '{scenario}' (bench-full, bench-clutch)"
        ))
    })?;
    let names = |list: &[Actuator]| list.iter().map(|a| a.name()).collect::<Vec<_>>().join(", ");
    let actuators = actuators.unwrap_or_else(|| {
        study_scenario
            .actuators()
            .iter()
            .map(|a| a.name().to_string())
            .collect()
    });
    let mut list = Vec::new();
    for a in &actuators {
        let found = Actuator::ALL
            .into_iter()
            .find(|x| x.name().eq_ignore_ascii_case(a))
            .ok_or_else(|| err(format!("unknown actuator '{a}' (DA, SEA, CSEA)")))?;
        if list.contains(&found) {
            return Err(err(format!("actuator {} given twice", found.name())));
        }
        if !study_scenario.actuators().contains(&found) {
            return Err(err(format!(
                "the {scenario} scenario has no {} (its actuators: {})",
                found.name(),
                names(study_scenario.actuators())
            )));
        }
        list.push(found);
    }
    if list.is_empty() {
        return Err(err(format!(
            "no actuator given (the {scenario} scenario's: {})",
            names(study_scenario.actuators())
        )));
    }
    if cycles == 0 || !(scale.is_finite() && scale > 0.0) {
        return Err(err(
            "cycles must be at least 1 and scale positive and finite",
        ));
    }
    let config = StudyConfig {
        fmu_dir: fmus,
        out_dir: out,
        scenario: study_scenario,
        cycles,
        scale,
        gains: None,
        actuators: list,
        overrides: Vec::new(),
        parameter_set: None,
        bench: None,
    };
    let control = RunControl::new();
    let runs =
        interruptible(py, &control, || run_study_with(&config, Some(&control)))?.map_err(err)?;
    runs.iter()
        .map(|r| report_dict(py, &r.report, &r.outcome))
        .collect()
}

fn prepare(spec: &Path) -> Result<Prepared, SweepError> {
    SweepSpec::from_file(spec).and_then(Prepared::new)
}

fn rows_dict<'py>(py: Python<'py>, p: &Prepared, rows: &[Row]) -> PyResult<Bound<'py, PyDict>> {
    let (parameter_names, metric_names) = (&p.design.names, &p.metric_names);
    let d = PyDict::new(py);
    d.set_item("point", rows.iter().map(|r| r.point).collect::<Vec<_>>())?;
    let column = |k: usize, params: bool| -> Vec<f64> {
        rows.iter()
            .map(|r| {
                if params {
                    r.parameters[k]
                } else {
                    r.metrics[k]
                }
            })
            .collect()
    };
    let mut names = Vec::new();
    let mut cols = Vec::new();
    for (k, n) in parameter_names.iter().enumerate() {
        names.push(n.clone());
        cols.push(PyBytes::new(py, &f64_bytes(&column(k, true))));
    }
    for (k, n) in metric_names.iter().enumerate() {
        names.push(n.clone());
        cols.push(PyBytes::new(py, &f64_bytes(&column(k, false))));
    }
    d.set_item("names", names)?;
    d.set_item("columns", PyList::new(py, cols)?)?;
    d.set_item(
        "status",
        rows.iter().map(|r| r.status.name()).collect::<Vec<_>>(),
    )?;
    d.set_item(
        "message",
        rows.iter().map(|r| r.message.clone()).collect::<Vec<_>>(),
    )?;
    d.set_item("parameters", parameter_names.to_vec())?;
    d.set_item("metrics", metric_names.to_vec())?;
    d.set_item("units", p.column_units())?;
    d.set_item("fingerprint", p.fingerprint.clone())?;
    Ok(d)
}

/// Rows from columns as `rows_dict` gives them: `columns` holds one float64 column (bytes) per
/// parameter, then per metric, in the spec's order; `point`, `status` and `message` one entry
/// per row. `what` names the caller in the errors.
fn decode_rows(
    what: &str,
    p: &Prepared,
    point: &[u64],
    columns: &[Vec<u8>],
    status: &[String],
    message: &[String],
) -> Result<Vec<Row>, String> {
    let (np, nm) = (p.design.names.len(), p.metric_names.len());
    let n = point.len();
    if columns.len() != np + nm || status.len() != n || message.len() != n {
        return Err(format!(
            "{what}: {} columns, {} statuses and {} messages for {np} parameters + {nm} metrics \
             and {n} rows",
            columns.len(),
            status.len(),
            message.len(),
        ));
    }
    let mut values: Vec<Vec<f64>> = Vec::with_capacity(columns.len());
    for c in columns {
        if c.len() != 8 * n {
            return Err(format!(
                "{what}: a column of {} bytes for {n} rows",
                c.len()
            ));
        }
        values.push(
            c.chunks_exact(8)
                .map(|b| f64::from_le_bytes(b.try_into().unwrap_or([0; 8])))
                .collect(),
        );
    }
    (0..n)
        .map(|k| {
            Ok(Row {
                point: point[k],
                parameters: values[..np].iter().map(|c| c[k]).collect(),
                metrics: values[np..].iter().map(|c| c[k]).collect(),
                status: RunStatus::from_name(&status[k])
                    .ok_or_else(|| format!("{what}: status '{}'", status[k]))?,
                message: message[k].clone(),
            })
        })
        .collect()
}

/// Rows from a dict of `rows_dict` (a batch's rows gathered from a Dask worker): an error if
/// its fingerprint is missing or not `p`'s (the worker prepared another spec, points or FMUs).
fn rows_of_dict(what: &str, p: &Prepared, d: &Bound<'_, PyAny>) -> PyResult<Vec<Row>> {
    let item = |key: &str| {
        d.get_item(key)
            .map_err(|_| err(format!("{what}: rows without '{key}'")))
    };
    // Required: rows that do not say which sweep they are of cannot be checked against it.
    let f: String = item("fingerprint")?.extract()?;
    if f != p.fingerprint {
        return Err(err(format!(
            "{what}: rows of another sweep (the spec, its points or the FMUs' GUIDs \
             differ): fingerprint {f} != {}",
            p.fingerprint
        )));
    }
    let point: Vec<u64> = item("point")?.extract()?;
    let columns: Vec<Vec<u8>> = item("columns")?.extract()?;
    let status: Vec<String> = item("status")?.extract()?;
    let message: Vec<String> = item("message")?.extract()?;
    decode_rows(what, p, &point, &columns, &status, &message).map_err(err)
}

/// Rows from a dict of `rows_dict` or a list of them ([`rows_of_dict`] each).
fn rows_of(what: &str, p: &Prepared, rows: &Bound<'_, PyAny>) -> PyResult<Vec<Row>> {
    if rows.is_instance_of::<PyDict>() {
        return rows_of_dict(what, p, rows);
    }
    let mut all = Vec::new();
    for d in rows.try_iter()? {
        all.extend(rows_of_dict(what, p, &d?)?);
    }
    Ok(all)
}

/// What `sweep_info` and `optimize_info` say of a prepared spec.
fn info_dict<'py>(py: Python<'py>, p: &Prepared) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("points", p.design.points.len())?;
    d.set_item("parameters", p.design.names.clone())?;
    d.set_item("metrics", p.metric_names.clone())?;
    d.set_item("fingerprint", p.fingerprint.clone())?;
    d.set_item("units", p.column_units())?;
    d.set_item("files", absolute_input_files(p))?;
    Ok(d)
}

fn absolute_input_files(p: &Prepared) -> Vec<PathBuf> {
    p.input_files
        .iter()
        .map(|f| std::path::absolute(f).unwrap_or_else(|_| f.clone()))
        .collect()
}

/// Runs a whole sweep on local threads; returns the table as a dict of columns (see
/// `rows_dict`), also written to `output` when given. A spec with `[optimize]` is refused.
#[pyfunction]
#[pyo3(signature = (spec, workers=None, output=None, resume=false))]
fn sweep<'py>(
    py: Python<'py>,
    spec: PathBuf,
    workers: Option<usize>,
    output: Option<PathBuf>,
    resume: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let control = RunControl::new();
    let (prepared, table) = interruptible(py, &control, || {
        let options = local_options(workers, resume)?;
        let mut prepared = prepare(&spec)?;
        prepared.refuse_optimization()?;
        // Every point's run takes the control; a row after a stop is not journaled
        // (`Prepared::unless_stopped`), so the journal keeps the rows before it for `resume`.
        prepared.config.control = Some(control.clone());
        let table = run_sweep(&prepared, output.as_deref(), &options)?;
        Ok((prepared, table))
    })?
    .map_err(sweep_err)?;
    rows_dict(py, &prepared, &table.rows)
}

/// The options of a local sweep or optimisation: `workers` threads (default: every core), at
/// most [`MAX_WORKERS`](kneebench_harness::sweep::MAX_WORKERS) (more is refused here, before the
/// spec is read).
fn local_options(workers: Option<usize>, resume: bool) -> Result<SweepOptions, SweepError> {
    let mut options = SweepOptions {
        resume,
        ..SweepOptions::default()
    };
    if let Some(w) = workers {
        kneebench_harness::sweep::check_workers(w)?;
        options.workers = w;
    }
    Ok(options)
}

/// The sweep's size and columns: `{"points", "parameters", "metrics", "units",
/// "fingerprint", "files"}` (the spec is checked in full; one with `[optimize]` is refused).
#[pyfunction]
fn sweep_info<'py>(py: Python<'py>, spec: PathBuf) -> PyResult<Bound<'py, PyDict>> {
    let p = py
        .detach(|| {
            let p = prepare(&spec)?;
            p.refuse_optimization()?;
            Ok(p)
        })
        .map_err(sweep_err)?;
    info_dict(py, &p)
}

/// The absolute paths of the files a spec (a sweep's or an optimisation's) reads: the spec,
/// its design CSV, the system file or the scenario's FMUs (what `kneebench.ship` sends).
#[pyfunction]
fn input_files(py: Python<'_>, spec: PathBuf) -> PyResult<Vec<PathBuf>> {
    let p = py.detach(|| prepare(&spec)).map_err(sweep_err)?;
    Ok(absolute_input_files(&p))
}

/// A sweep whose points run elsewhere (the package's Dask sweep), with the local sweep's
/// journal and table: `pending` gives the points without a row (all of them, or after
/// `resume` those the journal, or a finished Parquet table of the same sweep, lacks),
/// `record(rows)` journals rows as batches come back (dicts of `sweep_points`, their
/// fingerprint checked), and `finish()` writes the table to `output`, removes the journal and
/// returns the rows as `sweep` does (points still without a row are an error naming them,
/// the journal kept for `resume`).
#[pyclass(module = "kneebench._native", name = "SweepJournal")]
struct PySweepJournal {
    prepared: std::sync::Arc<Prepared>,
    output: PathBuf,
    inner: Option<JournaledSweep<std::sync::Arc<Prepared>>>,
}

impl PySweepJournal {
    fn inner(&mut self) -> PyResult<&mut JournaledSweep<std::sync::Arc<Prepared>>> {
        self.inner
            .as_mut()
            .ok_or_else(|| err("SweepJournal: finished already"))
    }
}

#[pymethods]
impl PySweepJournal {
    /// The journal of the sweep `spec` (checked in full; one with `[optimize]` is refused)
    /// written to `output`: an existing journal is refused without `resume`.
    #[new]
    #[pyo3(signature = (spec, output, resume=false))]
    fn new(py: Python<'_>, spec: PathBuf, output: PathBuf, resume: bool) -> PyResult<Self> {
        py.detach(|| {
            let prepared = std::sync::Arc::new(prepare(&spec)?);
            let inner = JournaledSweep::start(
                prepared.clone(),
                Some(&output),
                &SweepOptions {
                    resume,
                    ..SweepOptions::default()
                },
            )?;
            Ok(PySweepJournal {
                prepared,
                output,
                inner: Some(inner),
            })
        })
        .map_err(sweep_err)
    }

    /// The points without a row, in id order.
    fn pending(&self) -> PyResult<Vec<u64>> {
        self.inner
            .as_ref()
            .map(|i| i.pending())
            .ok_or_else(|| err("SweepJournal: finished already"))
    }

    /// Journals the rows of a dict of `sweep_points` (or a list of them).
    fn record(&mut self, rows: &Bound<'_, PyAny>) -> PyResult<()> {
        let all = rows_of("SweepJournal.record", &self.prepared, rows)?;
        let inner = self.inner()?;
        for row in all {
            inner.record(row).map_err(sweep_err)?;
        }
        Ok(())
    }

    /// Lets the journal go without a table: it is kept for `resume`, and its lock released at
    /// once (not when the object is collected, which a traceback holding it can put off), so
    /// that the output can be resumed. The object is finished; closing it again does nothing.
    fn close(&mut self) {
        self.inner = None;
    }

    /// Writes the table and removes the journal; returns the rows as `sweep` does. Points
    /// without a row are an error naming them (the journal kept, the journal object usable).
    fn finish<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let missing = self.pending()?;
        if !missing.is_empty() {
            return Err(sweep_err(SweepError::Missing(missing)));
        }
        let inner = self
            .inner
            .take()
            .ok_or_else(|| err("SweepJournal: finished already"))?;
        let output = self.output.clone();
        let table = py
            .detach(|| inner.finish(Some(&output)))
            .map_err(sweep_err)?;
        rows_dict(py, &self.prepared, &table.rows)
    }
}

/// The optimisation's settings in `d`: `objective`, `direction`, `population`, `generations`
/// (nothing for a spec without `[optimize]`).
fn set_settings(d: &Bound<'_, PyDict>, p: &Prepared) -> PyResult<()> {
    if let Some(o) = &p.spec.optimize {
        d.set_item("objective", &o.objective)?;
        d.set_item("direction", o.direction.name())?;
        d.set_item("population", p.design.points.len())?;
        d.set_item("generations", o.generations)?;
    }
    Ok(())
}

/// One `(generation, point, objective, violation)` per generation told.
fn history_tuples(h: &[GenerationBest]) -> Vec<(usize, u64, f64, f64)> {
    h.iter()
        .map(|g| (g.generation, g.point, g.objective, g.violation))
        .collect()
}

/// A finished optimisation: its rows as `rows_dict` gives them (sorted by point), the
/// settings (`set_settings`), `best_point`, `violation` (the best run's; 0: it meets every
/// constraint) and `history` (`history_tuples`).
fn optimization_dict<'py>(
    py: Python<'py>,
    p: &Prepared,
    o: &Optimization,
) -> PyResult<Bound<'py, PyDict>> {
    let d = rows_dict(py, p, &o.table.rows)?;
    set_settings(&d, p)?;
    d.set_item("best_point", o.best.point)?;
    d.set_item("violation", o.violation)?;
    d.set_item("history", history_tuples(&o.history))?;
    Ok(d)
}

/// The optimisation's size, columns and settings: `sweep_info`'s keys and `objective`,
/// `direction`, `population`, `generations` (a spec without `[optimize]` is refused).
#[pyfunction]
fn optimize_info<'py>(py: Python<'py>, spec: PathBuf) -> PyResult<Bound<'py, PyDict>> {
    let p = py
        .detach(|| {
            let p = prepare(&spec)?;
            Optimizer::new(&p)?;
            Ok(p)
        })
        .map_err(sweep_err)?;
    let d = info_dict(py, &p)?;
    set_settings(&d, &p)?;
    Ok(d)
}

/// Runs a whole optimisation on local threads (`kneebench optimize`), every run's row written
/// to `output` when given (with a journal for `resume`); returns `optimization_dict`.
/// `on_generation(generation, point, objective, violation)` is called after each generation
/// with its best member; an exception it raises stops the optimisation (the journal kept for
/// `resume`) and is raised.
#[pyfunction]
#[pyo3(signature = (spec, workers=None, output=None, resume=false, on_generation=None))]
fn optimize<'py>(
    py: Python<'py>,
    spec: PathBuf,
    workers: Option<usize>,
    output: Option<PathBuf>,
    resume: bool,
    on_generation: Option<Py<PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let mut raised: Option<PyErr> = None;
    let control = RunControl::new();
    let outcome = interruptible(py, &control, || {
        let options = local_options(workers, resume)?;
        let mut prepared = prepare(&spec)?;
        // `run_optimization` with the control, as `sweep` runs `run_sweep`.
        prepared.config.control = Some(control.clone());
        let mut report = |g: &GenerationBest| {
            if let Some(f) = &on_generation {
                raised = Python::attach(|py| {
                    f.call1(py, (g.generation, g.point, g.objective, g.violation))
                        .err()
                });
                if raised.is_some() {
                    // Stops the optimisation; the exception is raised below.
                    return Err(SweepError::System("on_generation raised".into()));
                }
            }
            Ok(())
        };
        let optimization = run_optimization(&prepared, output.as_deref(), &options, &mut report)?;
        Ok((prepared, optimization))
    })?;
    if let Some(e) = raised {
        return Err(e);
    }
    let (prepared, optimization) = outcome.map_err(sweep_err)?;
    optimization_dict(py, &prepared, &optimization)
}

/// Differential evolution as ask and tell, for a driver that runs the points elsewhere (the
/// package's Dask optimisation), with the local optimisation's journal when given an `output`:
/// `ask()` gives the current generation's points without a row (generations whose rows the
/// journal, or a finished Parquet table continued with `resume`, already holds are told on the
/// way), `tell(rows)` journals rows (dicts of `optimize_points`, a batch at a time as they come
/// back) and selects the next members once a generation's rows are all there, and `finish()`
/// gives the result of the local `optimize` and writes the same table to `output`, removing
/// the journal.
#[pyclass(module = "kneebench._native", name = "Optimizer")]
struct PyOptimizer {
    prepared: std::sync::Arc<Prepared>,
    output: Option<PathBuf>,
    inner: Option<JournaledOptimization<std::sync::Arc<Prepared>>>,
}

impl PyOptimizer {
    fn inner(&self) -> PyResult<&JournaledOptimization<std::sync::Arc<Prepared>>> {
        self.inner
            .as_ref()
            .ok_or_else(|| err("Optimizer: finished already"))
    }

    fn inner_mut(&mut self) -> PyResult<&mut JournaledOptimization<std::sync::Arc<Prepared>>> {
        self.inner
            .as_mut()
            .ok_or_else(|| err("Optimizer: finished already"))
    }
}

#[pymethods]
impl PyOptimizer {
    /// The optimiser of the spec at `spec` (checked in full; one without `[optimize]` is
    /// refused), journaling its rows next to `output` when given (an existing journal is
    /// refused without `resume`).
    #[new]
    #[pyo3(signature = (spec, output=None, resume=false))]
    fn new(py: Python<'_>, spec: PathBuf, output: Option<PathBuf>, resume: bool) -> PyResult<Self> {
        py.detach(|| {
            let prepared = std::sync::Arc::new(prepare(&spec)?);
            let inner = JournaledOptimization::start(
                prepared.clone(),
                output.as_deref(),
                &SweepOptions {
                    resume,
                    ..SweepOptions::default()
                },
            )?;
            Ok(PyOptimizer {
                prepared,
                output,
                inner: Some(inner),
            })
        })
        .map_err(sweep_err)
    }

    /// The current generation's points without a row, `[(id, [value per parameter])]`;
    /// empty once every generation is told.
    fn ask(&mut self) -> PyResult<Vec<(u64, Vec<f64>)>> {
        self.inner_mut()?
            .pending(&mut |_| Ok(()))
            .map_err(sweep_err)
    }

    /// Journals the rows of asked points: a dict of `optimize_points` or a list of them (in
    /// any order; each with the asked values; the fingerprint must be the spec's); the
    /// generation is told once all its rows are there.
    fn tell(&mut self, rows: &Bound<'_, PyAny>) -> PyResult<()> {
        let all = rows_of("Optimizer.tell", &self.prepared, rows)?;
        let inner = self.inner_mut()?;
        for row in all {
            inner.record(row).map_err(sweep_err)?;
        }
        inner.pending(&mut |_| Ok(())).map_err(sweep_err)?;
        Ok(())
    }

    /// Whether every generation has been told.
    #[getter]
    fn finished(&self) -> PyResult<bool> {
        Ok(self.inner()?.optimizer().finished())
    }

    /// The best member after each generation told: `[(generation, point, objective,
    /// violation)]`.
    #[getter]
    fn history(&self) -> PyResult<Vec<(usize, u64, f64, f64)>> {
        Ok(history_tuples(self.inner()?.optimizer().history()))
    }

    /// Runs of the whole optimisation (population x (generations + 1)).
    #[getter]
    fn total_runs(&self) -> PyResult<u64> {
        Ok(self.inner()?.optimizer().total_runs())
    }

    /// `optimize_info` of the spec.
    #[getter]
    fn info<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = info_dict(py, &self.prepared)?;
        set_settings(&d, &self.prepared)?;
        Ok(d)
    }

    /// Lets the journal (if any) go without a table: it is kept for `resume`, and its lock
    /// released at once (not when the object is collected). The optimiser is finished;
    /// closing it again does nothing.
    fn close(&mut self) {
        self.inner = None;
    }

    /// The finished optimisation (every generation told): `optimize`'s dict, the table
    /// written to the `output` given (`.parquet`, else CSV) the same as the local `optimize`
    /// writes it, and the journal removed. Before the end it is an error, and the journal is
    /// kept for `resume`.
    fn finish<'py>(&mut self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        if !self.inner()?.optimizer().finished() {
            let o = self.inner()?.optimizer();
            return Err(err(format!(
                "optimisation: {} of {} generations told",
                o.history().len(),
                o.settings().generations + 1
            )));
        }
        let inner = self
            .inner
            .take()
            .ok_or_else(|| err("Optimizer: finished already"))?;
        let output = self.output.clone();
        let optimization = py
            .detach(|| inner.finish(output.as_deref()))
            .map_err(sweep_err)?;
        optimization_dict(py, &self.prepared, &optimization)
    }
}

/// What identifies a prepared sweep in [`CACHE`]: the spec's path and text, and the size and
/// modification time of every file it reads ([`watched_files`]). Another text, or a rewritten
/// FMU, prepares anew.
#[derive(Debug, Clone, PartialEq)]
struct CacheKey {
    spec: PathBuf,
    text: Vec<u8>,
    files: Vec<(PathBuf, Option<(u64, std::time::SystemTime)>)>,
}

fn file_stamp(path: &Path) -> Option<(u64, std::time::SystemTime)> {
    let m = std::fs::metadata(path).ok()?;
    Some((m.len(), m.modified().ok()?))
}

impl CacheKey {
    fn of(spec: &Path, files: &[PathBuf]) -> Option<CacheKey> {
        Some(CacheKey {
            spec: spec.to_path_buf(),
            text: std::fs::read(spec).ok()?,
            files: files.iter().map(|f| (f.clone(), file_stamp(f))).collect(),
        })
    }
}

/// The files a prepared sweep was made of, which a change of prepares it anew: those it names
/// ([`Prepared::input_files`]: the spec, its design CSV, the system file or the scenario's FMUs)
/// and those its fingerprint covers ([`Prepared::file_digests`]: also a bare `.ssd`'s own FMUs
/// and parameter files, which the input files leave out: a rebuilt FMU next to an `.ssd` was
/// run from the cached sweep).
fn watched_files(p: &Prepared) -> Vec<PathBuf> {
    let mut files = p.input_files.clone();
    for (f, _) in &p.file_digests {
        if !files.contains(f) {
            files.push(f.clone());
        }
    }
    files
}

/// The last sweep (or optimisation) prepared by `sweep_points` or `optimize_points` in this
/// process: the batches of a Dask sweep (or of every generation of an optimisation) that land
/// on one worker prepare the spec (parse it, write the scenario, load the FMUs) once, not once
/// per batch; the loaded systems of finished batches wait in the prepared spec for the next
/// ([`Prepared::give_back`]).
struct Cached {
    key: CacheKey,
    prepared: std::sync::Arc<Prepared>,
}

static CACHE: std::sync::Mutex<Option<Cached>> = std::sync::Mutex::new(None);

/// The prepared spec of `spec` (from [`CACHE`] when the spec and its files are unchanged) and
/// a loaded system for one batch, to give back to it when the batch ends.
fn prepared_for_batch(
    spec: &Path,
) -> Result<(std::sync::Arc<Prepared>, ssp::LoadedSystem), SweepError> {
    let hit = {
        let cache = CACHE.lock().unwrap_or_else(|e| e.into_inner());
        cache.as_ref().and_then(|c| {
            (CacheKey::of(spec, &watched_files(&c.prepared)).as_ref() == Some(&c.key))
                .then(|| c.prepared.clone())
        })
    };
    let prepared = match hit {
        Some(p) => p,
        None => {
            let p = std::sync::Arc::new(prepare(spec)?);
            if let Some(key) = CacheKey::of(spec, &watched_files(&p)) {
                *CACHE.lock().unwrap_or_else(|e| e.into_inner()) = Some(Cached {
                    key,
                    prepared: p.clone(),
                });
            }
            p
        }
    };
    // An idle system, or a new one loaded outside the lock: the worker's other threads keep
    // taking and giving back theirs meanwhile.
    let loaded = prepared.worker_system()?;
    Ok((prepared, loaded))
}

/// Drops the cached sweep of `sweep_points` or `optimize_points` (its scenario and extracted FMUs are removed);
/// registered with `atexit` by the package, so a worker that exits leaves no directories.
#[pyfunction]
fn clear_cache(py: Python<'_>) {
    py.detach(|| {
        let cached = CACHE.lock().unwrap_or_else(|e| e.into_inner()).take();
        drop(cached);
    });
}

/// Runs a batch on this worker process: `batch` gives its rows with the prepared spec and a
/// loaded system ([`prepared_for_batch`], the system given back after); returns them sorted
/// by point as `rows_dict` does, with the spec's fingerprint.
fn run_on_worker<'py>(
    py: Python<'py>,
    spec: &Path,
    batch: impl Send + FnOnce(&Prepared, &ssp::LoadedSystem) -> Result<Vec<Row>, SweepError>,
) -> PyResult<Bound<'py, PyDict>> {
    let (p, rows) = py
        .detach(|| {
            let (p, loaded) = prepared_for_batch(spec)?;
            let rows = batch(&p, &loaded);
            p.give_back(loaded);
            let mut rows = rows?;
            rows.sort_by_key(|r| r.point);
            Ok::<_, SweepError>((p, rows))
        })
        .map_err(sweep_err)?;
    rows_dict(py, &p, &rows)
}

/// Runs the points `ids` of a sweep (a batch of a distributed sweep) one after the other;
/// returns their rows sorted by point id, with the sweep's fingerprint (a worker whose spec
/// or FMUs differ gives another one). The prepared sweep and its loaded system are kept for
/// the next batch of the same sweep in this process. A spec with `[optimize]` is refused.
#[pyfunction]
fn sweep_points<'py>(
    py: Python<'py>,
    spec: PathBuf,
    ids: Vec<u64>,
) -> PyResult<Bound<'py, PyDict>> {
    run_on_worker(py, &spec, |p, loaded| {
        p.refuse_optimization()?;
        let n = p.design.points.len();
        if let Some(bad) = ids.iter().find(|&&i| i as usize >= n) {
            return Err(SweepError::System(format!(
                "point {bad} is not in the design ({n} points)"
            )));
        }
        Ok(ids.iter().map(|&id| p.run_point(loaded, id)).collect())
    })
}

/// Runs the points `(id, values)` of an optimisation (a batch of a generation that
/// `Optimizer.ask` gave) one after the other; returns their rows as `sweep_points` does (sorted
/// by point id, with the spec's fingerprint), from the same per-process cache. A spec without
/// `[optimize]` is refused.
#[pyfunction]
fn optimize_points<'py>(
    py: Python<'py>,
    spec: PathBuf,
    points: Vec<(u64, Vec<f64>)>,
) -> PyResult<Bound<'py, PyDict>> {
    run_on_worker(py, &spec, |p, loaded| {
        Optimizer::new(p)?;
        let n = p.design.names.len();
        if let Some((id, v)) = points.iter().find(|(_, v)| v.len() != n) {
            return Err(SweepError::System(format!(
                "point {id} has {} values for {n} parameters",
                v.len()
            )));
        }
        Ok(points
            .iter()
            .map(|(id, values)| p.run_values(loaded, *id, values))
            .collect())
    })
}

/// The module.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("KneebenchError", m.py().get_type::<KneebenchError>())?;
    m.add("SpecError", m.py().get_type::<SpecError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("MAX_WORKERS", kneebench_harness::sweep::MAX_WORKERS)?;
    m.add(
        "ISOLATE_NAMES",
        Isolation::NAMED.map(|(name, _, _)| name).to_vec(),
    )?;
    m.add_function(wrap_pyfunction!(run, m)?)?;
    m.add_function(wrap_pyfunction!(study, m)?)?;
    m.add_function(wrap_pyfunction!(sweep, m)?)?;
    m.add_function(wrap_pyfunction!(sweep_info, m)?)?;
    m.add_function(wrap_pyfunction!(sweep_points, m)?)?;
    m.add_class::<PySweepJournal>()?;
    m.add_function(wrap_pyfunction!(input_files, m)?)?;
    m.add_function(wrap_pyfunction!(optimize, m)?)?;
    m.add_function(wrap_pyfunction!(optimize_info, m)?)?;
    m.add_function(wrap_pyfunction!(optimize_points, m)?)?;
    m.add_class::<PyOptimizer>()?;
    m.add_function(wrap_pyfunction!(clear_cache, m)?)?;
    let units = PyDict::new(m.py());
    for (k, u) in STUDY_METRICS.iter().zip(STUDY_METRIC_UNITS) {
        units.set_item(k, u)?;
    }
    m.add("STUDY_METRIC_UNITS", units)?;
    Ok(())
}
