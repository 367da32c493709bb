//! `kneebench._native`: the Rust side of the `kneebench` Python package (see
//! `python/kneebench/__init__.py` for the public API, which wraps these functions and builds
//! pandas DataFrames).
//!
//! Every function runs its simulation with the GIL released (`Python::detach`) and raises
//! `kneebench.KneebenchError` (`SpecError` for a refused sweep spec) with the Rust message.
//! Columns cross as little-endian float64 bytes (read with `numpy.frombuffer`, no copy per
//! value).

use std::path::{Path, PathBuf};

use kneebench_harness::master::{Outcome, RunConfig, System};
use kneebench_harness::study::{Actuator, ActuatorReport, StudyConfig, StudyScenario, run_study};
use kneebench_harness::sweep::runner::{STUDY_METRIC_UNITS, STUDY_METRICS, study_metric_values};
use kneebench_harness::sweep::{
    Prepared, Row, RunStatus, SweepError, SweepOptions, SweepSpec, run_sweep,
};
use kneebench_harness::{Fmu, LoadOptions, Results, ssp};
use model_description::VariableKind;
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

fn f64_bytes(values: &[f64]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// A system from an `.fmu` (columns named by variable) or an `.ssp`/`.ssd`.
fn load(path: &Path) -> Result<(System, RunConfig, bool), String> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    match ext.as_str() {
        "fmu" => {
            let fmu = Fmu::load(path, &LoadOptions::default()).map_err(|e| e.to_string())?;
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
            let mut config = RunConfig::default();
            if let Some(d) = &md.default_experiment {
                if let Some(t) = d.start_time {
                    config.start_time = t;
                }
                if let Some(t) = d.stop_time {
                    config.stop_time = t;
                }
                if let Some(h) = d.step_size {
                    config.step_size = h;
                }
            }
            Ok((system, config, true))
        }
        "ssp" | "ssd" => {
            let loaded =
                ssp::load_system(path, &LoadOptions::default()).map_err(|e| e.to_string())?;
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
    columns: Vec<Vec<u8>>,
    units: Vec<String>,
    status: &'static str,
    message: String,
}

fn run_inner(
    system: PathBuf,
    params: Vec<(String, String)>,
    variables: Vec<String>,
    stop_time: Option<f64>,
    step: Option<f64>,
) -> Result<RunResult, String> {
    let (mut sys, mut config, single) = load(&system)?;
    let first = sys.component_names()[0].to_string();
    let prefix = |n: &str| {
        if single {
            format!("{first}.{n}")
        } else {
            n.to_string()
        }
    };
    for (name, value) in &params {
        sys.set_value_str(&prefix(name), value)
            .map_err(|e| format!("params['{name}']: {e}"))?;
    }
    if !variables.is_empty() {
        let refs: Vec<String> = variables.iter().map(|v| prefix(v)).collect();
        let refs: Vec<&str> = refs.iter().map(String::as_str).collect();
        sys.record(&refs).map_err(|e| format!("variables: {e}"))?;
    }
    if let Some(t) = stop_time {
        config.stop_time = t;
    }
    if let Some(h) = step {
        config.step_size = h;
    }
    let mut results = Results::with_capacity(Vec::new(), Vec::new(), 0);
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
    let mut columns = vec![f64_bytes(&results.times())];
    let mut units = vec!["s".to_string()];
    for n in results.names() {
        columns.push(f64_bytes(&results.column(n).unwrap_or_default()));
        units.push(unit_of(&sys, single, n));
        names.push(n.clone());
    }
    Ok(RunResult {
        names,
        columns,
        units,
        status,
        message,
    })
}

/// Runs an FMU or SSP system; returns `{"names", "columns" (float64 bytes), "units",
/// "status", "message"}`.
#[pyfunction]
#[pyo3(signature = (system, params, variables, stop_time=None, step=None))]
fn run<'py>(
    py: Python<'py>,
    system: PathBuf,
    params: Vec<(String, String)>,
    variables: Vec<String>,
    stop_time: Option<f64>,
    step: Option<f64>,
) -> PyResult<Bound<'py, PyDict>> {
    let r = py
        .detach(|| run_inner(system, params, variables, stop_time, step))
        .map_err(err)?;
    let d = PyDict::new(py);
    d.set_item("names", r.names)?;
    let cols: Vec<Bound<'py, PyBytes>> = r.columns.iter().map(|c| PyBytes::new(py, c)).collect();
    d.set_item("columns", PyList::new(py, cols)?)?;
    d.set_item("units", r.units)?;
    d.set_item("status", r.status)?;
    d.set_item("message", r.message)?;
    Ok(d)
}

fn report_dict<'py>(py: Python<'py>, r: &ActuatorReport) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("actuator", &r.name)?;
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
/// dict per actuator.
#[pyfunction]
#[pyo3(signature = (fmus, out, actuators, cycles, scale, scenario))]
fn study<'py>(
    py: Python<'py>,
    fmus: PathBuf,
    out: PathBuf,
    actuators: Vec<String>,
    cycles: u32,
    scale: f64,
    scenario: String,
) -> PyResult<Vec<Bound<'py, PyDict>>> {
    let mut list = Vec::new();
    for a in &actuators {
        let found = Actuator::ALL
            .into_iter()
            .find(|x| x.name().eq_ignore_ascii_case(a))
            .ok_or_else(|| err(format!("unknown actuator '{a}' (DA, SEA, CSEA)")))?;
        list.push(found);
    }
    if cycles == 0 || !(scale.is_finite() && scale > 0.0) {
        return Err(err(
            "cycles must be at least 1 and scale positive and finite",
        ));
    }
    let config = StudyConfig {
        fmu_dir: fmus,
        out_dir: out,
        scenario: StudyScenario::from_name(&scenario).ok_or_else(|| {
            err(format!(
                "unknown scenario '{scenario}' (bench-full, bench-clutch)"
            ))
        })?,
        cycles,
        scale,
        gains: None,
        actuators: list,
        overrides: Vec::new(),
        parameter_set: None,
        bench: None,
    };
    let runs = py.detach(|| run_study(&config)).map_err(err)?;
    runs.iter().map(|r| report_dict(py, &r.report)).collect()
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

/// Runs a whole sweep on local threads; returns the table as a dict of columns (see
/// `rows_dict`), also written to `output` when given.
#[pyfunction]
#[pyo3(signature = (spec, workers=None, output=None, resume=false))]
fn sweep<'py>(
    py: Python<'py>,
    spec: PathBuf,
    workers: Option<usize>,
    output: Option<PathBuf>,
    resume: bool,
) -> PyResult<Bound<'py, PyDict>> {
    let (prepared, table) = py
        .detach(|| {
            let prepared = prepare(&spec)?;
            let mut options = SweepOptions {
                resume,
                ..SweepOptions::default()
            };
            if let Some(w) = workers {
                options.workers = w.max(1);
            }
            let table = run_sweep(&prepared, output.as_deref(), &options)?;
            Ok((prepared, table))
        })
        .map_err(sweep_err)?;
    rows_dict(py, &prepared, &table.rows)
}

/// The sweep's size and columns: `{"points", "parameters", "metrics", "fingerprint"}` (the
/// spec is checked in full).
#[pyfunction]
fn sweep_info<'py>(py: Python<'py>, spec: PathBuf) -> PyResult<Bound<'py, PyDict>> {
    let p = py.detach(|| prepare(&spec)).map_err(sweep_err)?;
    let d = PyDict::new(py);
    d.set_item("points", p.design.points.len())?;
    d.set_item("parameters", p.design.names.clone())?;
    d.set_item("metrics", p.metric_names.clone())?;
    d.set_item("fingerprint", p.fingerprint.clone())?;
    d.set_item("units", p.column_units())?;
    d.set_item(
        "files",
        p.input_files
            .iter()
            .map(|f| std::path::absolute(f).unwrap_or_else(|_| f.clone()))
            .collect::<Vec<_>>(),
    )?;
    Ok(d)
}

/// Writes a sweep's table (rows from `kneebench.sweep`, e.g. gathered from a Dask cluster) to
/// `output` as the local sweep does: Parquet for `.parquet`, CSV otherwise, with the sweep's
/// metadata. `columns` holds one float64 column (bytes) per parameter, then per metric, in the
/// spec's order; `point`, `status` and `message` one entry per row.
#[pyfunction]
#[pyo3(signature = (spec, output, point, columns, status, message))]
fn write_sweep_table(
    py: Python<'_>,
    spec: PathBuf,
    output: PathBuf,
    point: Vec<u64>,
    columns: Vec<Vec<u8>>,
    status: Vec<String>,
    message: Vec<String>,
) -> PyResult<()> {
    py.detach(|| {
        let p = prepare(&spec).map_err(sweep_err)?;
        let (np, nm) = (p.design.names.len(), p.metric_names.len());
        let n = point.len();
        if columns.len() != np + nm || status.len() != n || message.len() != n {
            return Err(err(format!(
                "write_sweep_table: {} columns, {} statuses and {} messages for {} parameters + \
                 {} metrics and {n} rows",
                columns.len(),
                status.len(),
                message.len(),
                np,
                nm
            )));
        }
        let mut values: Vec<Vec<f64>> = Vec::with_capacity(columns.len());
        for c in &columns {
            if c.len() != 8 * n {
                return Err(err(format!(
                    "write_sweep_table: a column of {} bytes for {n} rows",
                    c.len()
                )));
            }
            values.push(
                c.chunks_exact(8)
                    .map(|b| f64::from_le_bytes(b.try_into().unwrap_or([0; 8])))
                    .collect(),
            );
        }
        let mut table = p.empty_table();
        for k in 0..n {
            let status = RunStatus::from_name(&status[k])
                .ok_or_else(|| err(format!("write_sweep_table: status '{}'", status[k])))?;
            table.rows.push(Row {
                point: point[k],
                parameters: values[..np].iter().map(|c| c[k]).collect(),
                metrics: values[np..].iter().map(|c| c[k]).collect(),
                status,
                message: message[k].clone(),
            });
        }
        table.rows.sort_by_key(|r| r.point);
        table.write(&output).map_err(sweep_err)
    })
}

/// What identifies a prepared sweep in [`CACHE`]: the spec's path and text, and the size and
/// modification time of every file it reads. Another text, or a rewritten FMU, prepares anew.
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

/// The last sweep prepared by `sweep_points` in this process, with its loaded systems not in
/// use: the batches of a Dask sweep that land on one worker prepare the sweep (parse the spec,
/// write the scenario, load the FMUs) once, not once per batch.
struct Cached {
    key: CacheKey,
    prepared: std::sync::Arc<Prepared>,
    idle: Vec<ssp::LoadedSystem>,
}

static CACHE: std::sync::Mutex<Option<Cached>> = std::sync::Mutex::new(None);

/// The prepared sweep of `spec` and a loaded system for one batch (from [`CACHE`] when the
/// spec and its files are unchanged).
fn prepared_for_batch(
    spec: &Path,
) -> Result<(std::sync::Arc<Prepared>, ssp::LoadedSystem), SweepError> {
    let hit = {
        let mut cache = CACHE.lock().unwrap_or_else(|e| e.into_inner());
        cache.as_mut().and_then(|c| {
            (CacheKey::of(spec, &c.prepared.input_files).as_ref() == Some(&c.key))
                .then(|| (c.prepared.clone(), c.idle.pop()))
        })
    };
    if let Some((prepared, idle)) = hit {
        // A new system is loaded outside the lock: the worker's other threads keep taking and
        // giving back theirs meanwhile.
        let loaded = match idle {
            Some(l) => l,
            None => prepared.worker_system()?,
        };
        return Ok((prepared, loaded));
    }
    let prepared = std::sync::Arc::new(prepare(spec)?);
    let loaded = prepared.worker_system()?;
    if let Some(key) = CacheKey::of(spec, &prepared.input_files) {
        *CACHE.lock().unwrap_or_else(|e| e.into_inner()) = Some(Cached {
            key,
            prepared: prepared.clone(),
            idle: Vec::new(),
        });
    }
    Ok((prepared, loaded))
}

/// Gives a batch's loaded system back to [`CACHE`] (if the sweep is still the cached one).
fn batch_done(prepared: &std::sync::Arc<Prepared>, loaded: ssp::LoadedSystem) {
    let mut cache = CACHE.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(c) = cache.as_mut()
        && std::sync::Arc::ptr_eq(&c.prepared, prepared)
    {
        c.idle.push(loaded);
    }
}

/// Drops the cached sweep of `sweep_points` (its scenario and extracted FMUs are removed);
/// registered with `atexit` by the package, so a worker that exits leaves no directories.
#[pyfunction]
fn clear_cache(py: Python<'_>) {
    py.detach(|| {
        let cached = CACHE.lock().unwrap_or_else(|e| e.into_inner()).take();
        drop(cached);
    });
}

/// Runs the points `ids` of a sweep (a batch of a distributed sweep) one after the other;
/// returns their rows sorted by point id, with the sweep's fingerprint (a worker whose spec
/// or FMUs differ gives another one). The prepared sweep and its loaded system are kept for
/// the next batch of the same sweep in this process.
#[pyfunction]
fn sweep_points<'py>(
    py: Python<'py>,
    spec: PathBuf,
    ids: Vec<u64>,
) -> PyResult<Bound<'py, PyDict>> {
    let (p, rows) = py
        .detach(|| {
            let (p, loaded) = prepared_for_batch(&spec)?;
            let n = p.design.points.len();
            if let Some(bad) = ids.iter().find(|&&i| i as usize >= n) {
                return Err(SweepError::System(format!(
                    "point {bad} is not in the design ({n} points)"
                )));
            }
            let mut rows: Vec<Row> = ids.iter().map(|&id| p.run_point(&loaded, id)).collect();
            batch_done(&p, loaded);
            rows.sort_by_key(|r| r.point);
            Ok::<_, SweepError>((p, rows))
        })
        .map_err(sweep_err)?;
    rows_dict(py, &p, &rows)
}

/// The module.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("KneebenchError", m.py().get_type::<KneebenchError>())?;
    m.add("SpecError", m.py().get_type::<SpecError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(run, m)?)?;
    m.add_function(wrap_pyfunction!(study, m)?)?;
    m.add_function(wrap_pyfunction!(sweep, m)?)?;
    m.add_function(wrap_pyfunction!(sweep_info, m)?)?;
    m.add_function(wrap_pyfunction!(sweep_points, m)?)?;
    m.add_function(wrap_pyfunction!(write_sweep_table, m)?)?;
    m.add_function(wrap_pyfunction!(clear_cache, m)?)?;
    let units = PyDict::new(m.py());
    for (k, u) in STUDY_METRICS.iter().zip(STUDY_METRIC_UNITS) {
        units.set_item(k, u)?;
    }
    m.add("STUDY_METRIC_UNITS", units)?;
    Ok(())
}
