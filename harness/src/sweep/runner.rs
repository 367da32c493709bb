//! Running a sweep: the spec checked against the system's FMUs ([`Prepared::new`]), the points
//! run on worker threads ([`Prepared::run_points`]), and the whole sweep with its journal
//! ([`run_sweep`], [`JournaledSweep`]; the journal and `--resume`: [`super::journal`]).
//!
//! Each worker loads the system once (its own extracted FMUs) and runs each point on a copy of
//! the loaded [`System`](crate::master::System) (components, step multiples, the SSP's parameter values, connections)
//! with the point's values set after the SSP's. A point's row depends on the point alone.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc;

use model_description::{Causality, ModelDescription, Variability, VariableKind};
use sha2::{Digest, Sha256};

use super::SweepError;
use super::design::{self, Design};
use super::journal::{Finished, JOURNAL_MAGIC};
use super::spec::{
    DesignKind, ParameterType, SpecProblem, Stat, SweepSpec, SystemSource, TooLong,
    check_run_values, run_rows,
};
use super::table::{Row, RunStatus, SweepTable, same_bits};
use crate::LoadOptions;
use crate::master::{Outcome, RunConfig, Value};
use crate::results::Results;
use crate::ssp::{self, LoadedSystem};
use crate::study::{self, Columns};

/// The study metrics' column names, in table order: [`study::ActuatorReport`] (but its
/// whole-run peaks, which only the study's table gives) and its [`study::EnergyTerms`] (angles in rad, torques in N m, energies in J per gait cycle, the
/// clutch's engaged fraction of the cycle, `trip_time` in s, NaN without a trip).
pub const STUDY_METRICS: [&str; 25] = [
    "cycles",
    "rms_error_actuation",
    "max_error_actuation",
    "rms_error_knee",
    "max_error_knee",
    "peak_test_torque",
    "peak_shaft_torque",
    "peak_load_torque",
    "test_mechanical_energy",
    "test_mechanical_energy_consumed",
    "test_electrical_energy",
    "bench_electrical_energy",
    "clutch_energy",
    "clutch_engaged_fraction",
    "drive_loss_energy",
    "load_mechanical_energy",
    "load_electrical_energy",
    "load_loss_energy",
    "all_electrical_energy",
    "kinetic_energy_change",
    "potential_energy_change",
    "kinetic_energy_stored",
    "potential_energy_stored",
    "balance_residual",
    "trip_time",
];

/// The units of [`STUDY_METRICS`], in that order (the FMUs' unit names; `1` for a count or a
/// fraction).
pub const STUDY_METRIC_UNITS: [&str; STUDY_METRICS.len()] = [
    "1", "rad", "rad", "rad", "rad", "N.m", "N.m", "N.m", "J", "J", "J", "J", "J", "1", "J", "J",
    "J", "J", "J", "J", "J", "J", "J", "J", "s",
];

/// The sweep's fingerprint: a SHA-256 (hex) of the kneebench version, the spec text (as
/// [`SweepSpec::fingerprint_text`] gives it: an optimisation's `generations` left out), the
/// parameter names, every point's bits, every component's FMU GUID (`component`, GUID) and the
/// digests of the files the system is made of (`digests`: those of
/// [`Prepared::file_digests`], in order), so that an edited SSP binding or a rebuilt FMU, which
/// keeps its GUID, is another sweep. A journal, or a Dask worker's batch, with another
/// fingerprint belongs to another sweep: the spec, its points, the system's files or kneebench
/// differ.
pub fn fingerprint(
    text: &str,
    design: &Design,
    guids: &[(String, String)],
    digests: &[String],
) -> String {
    let mut h = Sha256::new();
    h.update(env!("CARGO_PKG_VERSION").as_bytes());
    h.update([0]);
    h.update(text.as_bytes());
    for n in &design.names {
        h.update(n.as_bytes());
        h.update([0]);
    }
    for p in &design.points {
        for v in p {
            h.update(v.to_bits().to_le_bytes());
        }
    }
    for (component, guid) in guids {
        h.update(component.as_bytes());
        h.update([0]);
        h.update(guid.as_bytes());
        h.update([0]);
    }
    for d in digests {
        h.update(d.as_bytes());
        h.update([0]);
    }
    hex(&h.finalize())
}

/// `v` as an `i32` when it is a whole number of that range (NaN, fractions and values beyond
/// it: `None`).
fn whole_i32(v: f64) -> Option<i32> {
    (v.fract() == 0.0 && v >= f64::from(i32::MIN) && v <= f64::from(i32::MAX)).then_some(v as i32)
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// The SHA-256 (hex) of the bytes of the file at `path`, read in blocks.
pub fn file_digest(path: &Path) -> Result<String, SweepError> {
    let io = |source| SweepError::Io {
        path: path.to_path_buf(),
        source,
    };
    use std::io::Read;
    let mut f = std::fs::File::open(path).map_err(io)?;
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        match f.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => h.update(&buf[..n]),
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(io(e)),
        }
    }
    Ok(hex(&h.finalize()))
}

/// The values of [`STUDY_METRICS`] for one analysed run, in that order.
pub fn study_metric_values(r: &study::ActuatorReport) -> [f64; STUDY_METRICS.len()] {
    let trip_time = r.trip.as_ref().map_or(f64::NAN, |t| t.1);
    let e = &r.energy;
    [
        r.cycles as f64,
        r.rms_error_actuation,
        r.max_error_actuation,
        r.rms_error_knee,
        r.max_error_knee,
        r.peak_test_torque,
        r.peak_shaft_torque,
        r.peak_load_torque,
        e.test_mechanical,
        e.test_mechanical_consumed,
        e.test_electrical,
        e.bench_electrical,
        e.clutch,
        e.clutch_engaged_fraction,
        e.drive_loss,
        e.load_mechanical,
        e.load_electrical,
        e.load_loss,
        e.all_electrical,
        e.kinetic_change,
        e.potential_change,
        e.kinetic_stored,
        e.potential_stored,
        e.balance_residual,
        trip_time,
    ]
}

/// The gait reference's period parameter (`gait.gaitPeriod`): when swept, each point's study
/// metrics use its value, and in a scenario its run lasts `cycles` of it and fades in over
/// half of it.
pub const GAIT_PERIOD: &str = study::GAIT_PERIOD;

/// The most worker threads a sweep or an optimisation runs on ([`SweepOptions::workers`]):
/// each worker is a thread with its own loaded copy of the system, so a count without a bound
/// (`--workers 100000000`) tried to start that many. More is refused ([`check_workers`]).
pub const MAX_WORKERS: usize = 1024;

/// Refuses a number of worker threads outside `1..=`[`MAX_WORKERS`]
/// ([`SweepError::Workers`]); `kneebench sweep/optimize --workers` and the Python package's
/// `workers=` are checked against the same bound.
pub fn check_workers(workers: usize) -> Result<(), SweepError> {
    if (1..=MAX_WORKERS).contains(&workers) {
        Ok(())
    } else {
        Err(SweepError::Workers(workers))
    }
}

/// How a sweep runs.
#[derive(Debug, Clone)]
pub struct SweepOptions {
    /// Worker threads, 1 to [`MAX_WORKERS`] (checked by [`check_workers`] before anything
    /// runs).
    pub workers: usize,
    /// Show a progress bar on stderr.
    pub progress: bool,
    /// Continue an interrupted sweep from its journal.
    pub resume: bool,
}

impl Default for SweepOptions {
    fn default() -> Self {
        SweepOptions {
            workers: std::thread::available_parallelism()
                .map_or(1, |n| n.get())
                .min(MAX_WORKERS),
            progress: false,
            resume: false,
        }
    }
}

/// A spec checked against its system, with its points: ready to run.
#[derive(Debug)]
pub struct Prepared {
    /// The spec (parameter types set from the FMUs).
    pub spec: SweepSpec,
    /// The points.
    pub design: Design,
    /// The system file every worker loads (the spec's, or the scenario written as `.ssp`).
    pub system_file: PathBuf,
    /// The run configuration (stop time and step from the spec where it gives them).
    pub config: RunConfig,
    /// The gait period of the study metrics, unless each point sets it.
    pub period: Option<f64>,
    /// The metric columns.
    pub metric_names: Vec<String>,
    /// The recorded columns.
    pub recorded: Vec<String>,
    /// The unit of every metric column (the FMUs' unit names, empty where a signal has none).
    pub metric_units: Vec<String>,
    /// The files the sweep reads, as the spec names them: the spec, its design CSV, and the
    /// system file or the scenario's FMUs (what a Dask worker without a shared file system
    /// needs, see the Python package's `ship`). An `.ssd`'s own resources are not listed.
    pub input_files: Vec<PathBuf>,
    /// The GUID of every component's FMU (`component` -> GUID).
    pub guids: Vec<(String, String)>,
    /// The files the system is made of, each with the SHA-256 (hex) of its bytes: a system
    /// file (and, for a bare `.ssd`, the FMUs and parameter files it references), or a
    /// scenario's FMUs. The fingerprint covers them, and the output may not be one of them.
    pub file_digests: Vec<(PathBuf, String)>,
    /// The sweep's fingerprint ([`fingerprint`]: the version, the spec text but for an
    /// optimisation's `generations`, the points, the FMUs' GUIDs, the system's files' digests).
    pub fingerprint: String,
    /// Loaded systems not in use: the one loaded to check the spec (one loading of every FMU
    /// less per sweep), then those the workers of a batch give back when it ends, so that the
    /// next batch (an optimisation's next generation) does not load the FMUs again.
    idle: std::sync::Mutex<Vec<LoadedSystem>>,
    _dir: Option<tempfile::TempDir>,
}

fn system_error(e: impl std::fmt::Display) -> SweepError {
    SweepError::System(e.to_string())
}

fn variable_problems(
    spec: &mut SweepSpec,
    component_md: &dyn Fn(&str) -> Option<ModelDescription>,
    connections: &[ssp::SspConnection],
) -> Vec<SpecProblem> {
    let mut problems = Vec::new();
    let file = spec.file.clone();
    for p in &mut spec.parameters {
        let at = |m: String| SpecProblem {
            file: file.clone(),
            line: p.line,
            message: m,
        };
        let Some((comp, var)) = p.name.split_once('.') else {
            continue;
        };
        let Some(md) = component_md(comp) else {
            problems.push(at(format!(
                "unknown variable '{}': the system has no component '{comp}'",
                p.name
            )));
            continue;
        };
        let Some(v) = md.model_variables.iter().find(|v| v.name == var) else {
            problems.push(at(format!(
                "unknown variable '{}': component '{comp}' ({}) has no variable '{var}'",
                p.name, md.model_name
            )));
            continue;
        };
        let causality = v.causality.unwrap_or(Causality::Local);
        if !matches!(causality, Causality::Parameter | Causality::Input) {
            let what = match causality {
                Causality::Output => "an output variable",
                Causality::Independent => "the independent variable",
                Causality::CalculatedParameter => "a calculated parameter",
                _ => "a local variable",
            };
            problems.push(at(format!(
                "'{}' is {what}; only parameters and inputs can be set",
                p.name
            )));
        }
        if v.variability == Some(Variability::Constant) {
            problems.push(at(format!("'{}' is a constant", p.name)));
        }
        // A connection sets the input at every step: the point's value would have no effect
        // (every row the same, status ok).
        if causality == Causality::Input
            && let Some(c) = connections
                .iter()
                .find(|c| c.end_element.as_deref() == Some(comp) && c.end_connector == var)
        {
            let from = match &c.start_element {
                Some(e) => format!("{e}.{}", c.start_connector),
                None => format!("the system's connector {}", c.start_connector),
            };
            problems.push(at(format!(
                "'{}' is an input driven by the connection from {from}: the connection sets it \
                 at every step, so a swept value would have no effect",
                p.name
            )));
        }
        let (ty, lo, hi) = match &v.kind {
            VariableKind::Real { attributes, .. } => {
                p.unit = attributes.unit.clone().unwrap_or_default();
                (ParameterType::Real, attributes.min, attributes.max)
            }
            VariableKind::Integer { attributes, .. } => (
                ParameterType::Integer,
                attributes.min.map(f64::from),
                attributes.max.map(f64::from),
            ),
            VariableKind::Enumeration { min, max, .. } => (
                ParameterType::Integer,
                min.map(f64::from),
                max.map(f64::from),
            ),
            VariableKind::Boolean { .. } | VariableKind::String { .. } => {
                problems.push(at(format!(
                    "'{}' is a Boolean or String variable; sweeps vary Real and Integer ones",
                    p.name
                )));
                continue;
            }
        };
        p.ty = ty;
        p.declared_min = lo;
        p.declared_max = hi;
        let mut values: Vec<f64> = [p.min, p.max].into_iter().flatten().collect();
        values.extend(p.values.iter().flatten());
        for x in values {
            if lo.is_some_and(|lo| x < lo) || hi.is_some_and(|hi| x > hi) {
                problems.push(at(format!(
                    "'{}': {x} is outside the variable's [min, max] = [{}, {}]",
                    p.name,
                    lo.unwrap_or(f64::NEG_INFINITY),
                    hi.unwrap_or(f64::INFINITY)
                )));
            }
            if ty == ParameterType::Integer && x.fract() != 0.0 {
                problems.push(at(format!(
                    "'{}' is an Integer variable; {x} is not a whole number",
                    p.name
                )));
            }
        }
    }
    problems
}

/// The unit of `component.variable` in the FMUs' descriptions (empty when it has none).
fn signal_unit(descriptions: &HashMap<String, ModelDescription>, reference: &str) -> String {
    reference
        .split_once('.')
        .and_then(|(c, v)| {
            let md = descriptions.get(c)?;
            let var = md.model_variables.iter().find(|x| x.name == v)?;
            match &var.kind {
                VariableKind::Real { attributes, .. } => attributes.unit.clone(),
                _ => None,
            }
        })
        .unwrap_or_default()
}

fn ssd_parameter(loaded: &LoadedSystem, reference: &str) -> Option<f64> {
    let (comp, var) = reference.split_once('.')?;
    let c = loaded
        .ssd
        .system
        .components
        .iter()
        .find(|c| c.name == comp)?;
    c.parameters
        .iter()
        .find(|p| p.name == var)
        .and_then(|p| match p.value {
            Value::Real(v) => Some(v),
            Value::Integer(v) => Some(f64::from(v)),
            _ => None,
        })
}

/// The spec's signal windows that hold no recorded row of a run on `grid` keeping every
/// `every`-th step (the rows at `grid.time(k * every)`, as the master records them): each
/// would give NaN with status ok. Refused at the signal's line.
fn window_problems(spec: &SweepSpec, grid: &crate::time::Grid, every: u64) -> Vec<SpecProblem> {
    let last = grid.n_steps / every;
    let time = |k: u64| grid.time(k * every);
    let mut problems = Vec::new();
    for s in &spec.signals {
        let from = s.from.unwrap_or(f64::NEG_INFINITY);
        let to = s.to.unwrap_or(f64::INFINITY);
        // The first recorded row at or after `from` (times increase with k).
        let (mut lo, mut hi) = (0u64, last + 1);
        while lo < hi {
            let mid = lo + (hi - lo) / 2;
            if time(mid) >= from {
                hi = mid;
            } else {
                lo = mid + 1;
            }
        }
        if lo > last || time(lo) > to {
            let bound = |b: Option<f64>, open: &str| b.map_or(open.to_string(), |x| format!("{x}"));
            problems.push(spec.problem(
                s.line,
                format!(
                    "the window [{}, {}] s of '{}' holds no recorded row: the runs record from \
                     {} s to {} s every {} s",
                    bound(s.from, "start"),
                    bound(s.to, "end"),
                    s.signal,
                    time(0),
                    time(last),
                    grid.step() * every as f64
                ),
            ));
        }
    }
    problems
}

impl Prepared {
    /// An error once the runs' control (`config.control`, the Python package's Ctrl-C) has
    /// stopped: a row that comes after the stop (its run stopped, or it just ended) is not
    /// journaled, so the journal keeps the rows before it for `--resume`.
    pub fn unless_stopped(&self) -> Result<(), SweepError> {
        match self.config.control.as_ref().and_then(|c| c.stop_reason()) {
            Some(reason) => Err(SweepError::System(format!("stopped: {reason}"))),
            None => Ok(()),
        }
    }

    /// Checks `spec` against its system (every problem with its line: unknown variables,
    /// values outside a variable's `[min, max]`, wrong types, unknown signals, a missing gait
    /// period) and computes its points. Nothing runs.
    pub fn new(mut spec: SweepSpec) -> Result<Prepared, SweepError> {
        let mut input_files = vec![spec.file.clone()];
        if let DesignKind::Csv(csv) = &spec.design {
            input_files.push(csv.clone());
        }
        let (system_file, dir) = match &spec.system {
            SystemSource::File(p) => {
                input_files.push(p.clone());
                if !p.is_file() {
                    return Err(SweepError::Invalid(vec![spec.problem(
                        spec.system_line,
                        format!("system file {} does not exist", p.display()),
                    )]));
                }
                (p.clone(), None)
            }
            SystemSource::Scenario {
                actuator,
                fmu_dir,
                cycles,
            } => {
                let dir = crate::tempdirs::create("sweep").map_err(|source| SweepError::Io {
                    path: std::env::temp_dir(),
                    source,
                })?;
                // The study's bench-full scenario: its gait and the actuator's tuned gains.
                let bench = study::StudyScenario::BenchFull;
                let scenario =
                    study::gait_scenario(*actuator, bench.gait(), bench.gains(*actuator), *cycles);
                // A missing directory or FMU is the spec's `fmus` (a usage error at its line),
                // not an I/O error of writing the scenario.
                let fmus_line = spec.fmus_line.unwrap_or(spec.system_line);
                if !fmu_dir.is_dir() {
                    return Err(SweepError::Invalid(vec![spec.problem(
                        fmus_line,
                        format!(
                            "the FMU directory {} does not exist (export the FMUs with \
                             `kneebench export --out DIR`)",
                            fmu_dir.display()
                        ),
                    )]));
                }
                let mut missing = Vec::new();
                for c in &scenario.components {
                    let fmu = fmu_dir.join(&c.fmu);
                    if !fmu.is_file() {
                        missing.push(spec.problem(
                            fmus_line,
                            format!(
                                "{} has no {} (the {} scenario's {})",
                                fmu_dir.display(),
                                c.fmu,
                                actuator.name(),
                                c.name
                            ),
                        ));
                    } else if !input_files.contains(&fmu) {
                        input_files.push(fmu);
                    }
                }
                if !missing.is_empty() {
                    missing.dedup();
                    return Err(SweepError::Invalid(missing));
                }
                let path = dir.path().join(format!("{}.ssp", actuator.name()));
                study::write_ssp(&scenario, fmu_dir, &path).map_err(system_error)?;
                (path, Some(dir))
            }
        };
        let loaded =
            ssp::load_system(&system_file, &LoadOptions::default()).map_err(system_error)?;
        let descriptions: HashMap<String, ModelDescription> = loaded
            .system
            .components()
            .map(|(n, f)| (n.to_string(), f.model_description().clone()))
            .collect();
        let mut problems = variable_problems(
            &mut spec,
            &|c| descriptions.get(c).cloned(),
            &loaded.ssd.system.connections,
        );

        let mut recorded: Vec<String> = Vec::new();
        let mut metric_names: Vec<String> = Vec::new();
        if spec.study_metrics {
            recorded.extend(Columns::default().names());
            metric_names.extend(STUDY_METRICS.iter().map(|s| s.to_string()));
        }
        for (k, s) in spec.signals.iter().enumerate() {
            if !recorded.contains(&s.signal) {
                recorded.push(s.signal.clone());
            }
            metric_names.extend(super::spec::signal_columns(&spec.signals, k));
        }
        let mut probe = loaded.system.clone();
        for r in &recorded {
            if let Err(e) = probe.record(&[r.as_str()]) {
                let line = spec
                    .signals
                    .iter()
                    .find(|s| &s.signal == r)
                    .map_or(0, |s| s.line);
                let what = if line == 0 {
                    "the study metrics need"
                } else {
                    "signal"
                };
                problems.push(spec.problem(line, format!("{what} '{r}': {e}")));
            }
        }
        let swept_period = spec.parameters.iter().any(|p| p.name == GAIT_PERIOD);
        let period = spec.period.or_else(|| ssd_parameter(&loaded, GAIT_PERIOD));
        if spec.study_metrics && period.is_none() && !swept_period {
            problems.push(spec.problem(
                spec.study_line.unwrap_or(spec.system_line),
                format!(
                    "the study metrics need the gait period: set [metrics] period or {GAIT_PERIOD}"
                ),
            ));
        }
        let mut config = loaded
            .config
            .clone()
            .with_times(None, spec.stop_time, spec.step);
        config.progress = None;
        match probe.check_config(&config) {
            // The spec's stop_time (or what sets the length) when it gives one, else its step.
            Err(e) => problems.push(spec.problem(
                match (spec.stop_time, spec.step_line) {
                    (None, Some(step)) => step,
                    _ => spec.length_line,
                },
                format!("stop_time and step: {e}"),
            )),
            // The bound on a run's recorded values (the spec checked it where it tells the
            // length and the step; a system file's experiment is only known here).
            Ok(grid) => {
                let every = config.record_every.max(1);
                let rows = (grid.n_steps / every).saturating_add(1) as f64;
                // The spec's step is to blame when the system's own would have fitted.
                let own_rows = spec.step_line.map(|_| {
                    run_rows(
                        config.stop_time - config.start_time,
                        loaded.config.step_size,
                        every,
                    )
                });
                if let Err((blame, message)) = check_run_values(rows, own_rows, recorded.len()) {
                    let line = match (blame, spec.step_line) {
                        (TooLong::Step, Some(line)) => line,
                        _ => spec.length_line,
                    };
                    problems.push(spec.problem(line, message));
                }
                problems.extend(window_problems(&spec, &grid, every));
            }
        }
        if !problems.is_empty() {
            return Err(SweepError::Invalid(problems));
        }
        let design = design::generate(&spec)?;
        if let Some(o) = &spec.optimize {
            let problems =
                super::optimize::problems(o, &metric_names, design.points.len(), &|line, m| {
                    spec.problem(line, m)
                });
            if !problems.is_empty() {
                return Err(SweepError::Invalid(problems));
            }
        }
        // A scenario sweeping the gait's period runs each point for `cycles` of its own period
        // (`run_values`): the longest run, a csv design's too, within the bound on its values.
        if let (SystemSource::Scenario { cycles, .. }, None, Some(i)) = (
            &spec.system,
            spec.stop_time,
            spec.parameters.iter().position(|p| p.name == GAIT_PERIOD),
        ) {
            let longest = design.points.iter().map(|v| v[i]).fold(0.0, f64::max);
            let stop = study::gait_stop_time(longest, *cycles, config.step_size);
            let rows = run_rows(
                stop - config.start_time,
                config.step_size,
                config.record_every,
            );
            if let Err((_, message)) = check_run_values(rows, None, recorded.len()) {
                return Err(SweepError::Invalid(vec![
                    spec.problem(spec.length_line, message),
                ]));
            }
        }
        let guids: Vec<(String, String)> = loaded
            .system
            .components()
            .map(|(n, f)| (n.to_string(), f.model_description().guid.clone()))
            .collect();
        let mut files: Vec<PathBuf> = Vec::new();
        match &spec.system {
            SystemSource::File(p) => {
                files.push(p.clone());
                // A bare .ssd's FMUs and parameter files are beside it (an archive holds its
                // own, and its bytes are the system file's).
                if p.extension().is_some_and(|e| e.eq_ignore_ascii_case("ssd")) {
                    let base = p.parent().map(Path::to_path_buf).unwrap_or_default();
                    for c in &loaded.ssd.system.components {
                        for r in std::iter::once(&c.source).chain(&c.parameter_sources) {
                            let f = base.join(r.strip_prefix("./").unwrap_or(r));
                            if f.is_file() && !files.contains(&f) {
                                files.push(f);
                            }
                        }
                    }
                }
            }
            SystemSource::Scenario { .. } => {
                files.extend(input_files.iter().skip(1).cloned());
            }
        }
        let file_digests = files
            .into_iter()
            .map(|f| file_digest(&f).map(|d| (f, d)))
            .collect::<Result<Vec<_>, _>>()?;
        let digests: Vec<String> = file_digests.iter().map(|(_, d)| d.clone()).collect();
        let fingerprint = fingerprint(&spec.fingerprint_text(), &design, &guids, &digests);
        let mut metric_units: Vec<String> = Vec::new();
        if spec.study_metrics {
            metric_units.extend(STUDY_METRIC_UNITS.iter().map(|u| u.to_string()));
        }
        for s in &spec.signals {
            let unit = signal_unit(&descriptions, &s.signal);
            metric_units.extend(s.stats.iter().map(|_| unit.clone()));
        }
        Ok(Prepared {
            spec,
            design,
            system_file,
            config,
            period,
            metric_names,
            recorded,
            metric_units,
            input_files,
            guids,
            file_digests,
            fingerprint,
            idle: std::sync::Mutex::new(vec![loaded]),
            _dir: dir,
        })
    }

    /// Refuses an `output` that is one of the sweep's inputs, however spelled: the spec, its
    /// design CSV, the system file or the scenario's FMUs ([`input_files`](Self::input_files)),
    /// an `.ssd`'s FMUs and parameter files ([`file_digests`](Self::file_digests)); and so is
    /// an output whose journal (`<output>.journal`, written first) is one. Every sweep and
    /// optimisation into a file is checked when it starts (`JournaledSweep::start`, the
    /// optimisation's start), whatever its entry point: the command line, Python, Dask.
    pub fn check_output(&self, output: &Path) -> Result<(), SweepError> {
        let inputs = self
            .input_files
            .iter()
            .chain(self.file_digests.iter().map(|(f, _)| f));
        let canonical: Vec<(PathBuf, &PathBuf)> = inputs
            .filter_map(|i| std::fs::canonicalize(i).ok().map(|c| (c, i)))
            .collect();
        for out in [output.to_path_buf(), super::journal::journal_path(output)] {
            let Ok(c) = std::fs::canonicalize(&out) else {
                continue;
            };
            if let Some((_, input)) = canonical.iter().find(|(i, _)| *i == c) {
                return Err(SweepError::OutputIsInput {
                    output: out,
                    input: (*input).clone(),
                });
            }
        }
        Ok(())
    }

    /// The table's metadata: the sweep's fingerprint, system, version and FMU GUIDs.
    pub fn metadata(&self) -> Vec<(String, String)> {
        let mut out = vec![
            (
                "kneebench.version".to_string(),
                env!("CARGO_PKG_VERSION").to_string(),
            ),
            (
                "kneebench.sweep.fingerprint".into(),
                self.fingerprint.clone(),
            ),
            (
                "kneebench.system".into(),
                match &self.spec.system {
                    SystemSource::Scenario { actuator, .. } => actuator.name().to_string(),
                    SystemSource::File(p) => p.display().to_string(),
                },
            ),
            ("kneebench.sweep.spec".into(), self.spec.text.clone()),
        ];
        for (c, g) in &self.guids {
            out.push((format!("kneebench.guid.{c}"), g.clone()));
        }
        out
    }

    /// The unit of every column after `point`: the parameters' (their variables'), then the
    /// metrics' ([`metric_units`](Self::metric_units)); empty where there is none.
    pub fn column_units(&self) -> Vec<String> {
        let mut out: Vec<String> = self
            .spec
            .parameters
            .iter()
            .map(|p| p.unit.clone())
            .collect();
        out.extend(self.metric_units.iter().cloned());
        out
    }

    /// An error if the spec is an optimisation (`[optimize]`): its design is only the first
    /// generation, so running it as a sweep would silently do something else.
    pub fn refuse_optimization(&self) -> Result<(), SweepError> {
        match &self.spec.optimize {
            Some(o) => Err(SweepError::Invalid(vec![self.spec.problem(
                o.line,
                "this spec optimises ([optimize]): run it with `kneebench optimize` (or \
                 kneebench.optimize in Python), or remove [optimize] to sweep its design",
            )])),
            None => Ok(()),
        }
    }

    /// The first line of this sweep's journal (with its newline).
    pub fn journal_header(&self) -> String {
        format!("{JOURNAL_MAGIC} {}\n", self.fingerprint)
    }

    /// An empty table with this sweep's columns and metadata.
    pub fn empty_table(&self) -> SweepTable {
        SweepTable {
            parameter_names: self.design.names.clone(),
            metric_names: self.metric_names.clone(),
            rows: Vec::new(),
            metadata: self.metadata(),
        }
    }

    /// Runs the points `ids` of the design on `workers` threads (one: the calling thread),
    /// handing each row to `on_row` as it comes (in completion order). Every id gets a row; an id outside the design is an
    /// error.
    pub fn run_points(
        &self,
        ids: &[u64],
        workers: usize,
        on_row: &mut dyn FnMut(Row) -> Result<(), SweepError>,
    ) -> Result<(), SweepError> {
        let points = ids
            .iter()
            .map(|&id| match self.design.points.get(id as usize) {
                Some(values) => Ok((id, values.to_vec())),
                None => Err(SweepError::System(format!(
                    "point {id} is not in the design ({} points)",
                    self.design.points.len()
                ))),
            })
            .collect::<Result<Vec<_>, _>>()?;
        self.run_batch(&points, workers, on_row)
    }

    /// Runs `points` (an id and the parameters' values, in spec order, each) on `workers`
    /// threads (one: the calling thread, without a thread of its own), handing each
    /// row to `on_row` as it comes (in completion order): the design's
    /// points ([`run_points`](Self::run_points)) or an optimiser's (see
    /// [`optimize`](super::optimize)). Every point gets a row; a point whose number of values
    /// is not the number of parameters is an error, and so is a number of workers outside
    /// `1..=`[`MAX_WORKERS`].
    pub fn run_batch(
        &self,
        points: &[(u64, Vec<f64>)],
        workers: usize,
        on_row: &mut dyn FnMut(Row) -> Result<(), SweepError>,
    ) -> Result<(), SweepError> {
        if let Some((id, values)) = points
            .iter()
            .find(|(_, v)| v.len() != self.spec.parameters.len())
        {
            return Err(SweepError::System(format!(
                "point {id} has {} values for {} parameters",
                values.len(),
                self.spec.parameters.len()
            )));
        }
        check_workers(workers)?;
        let workers = workers.min(points.len().max(1));
        if workers == 1 {
            return self.run_on_caller(points, on_row);
        }
        let next = AtomicUsize::new(0);
        let (tx, rx) = mpsc::channel::<Result<Row, SweepError>>();
        let mut done = vec![false; points.len()];
        let mut outcome = Ok(());
        let mut started = 0;
        let mut not_started = None;
        std::thread::scope(|scope| {
            for _ in 0..workers {
                let tx = tx.clone();
                let next = &next;
                // A worker that cannot start (a process limit) leaves the points to the
                // others; none at all is an error below (`spawn` would panic).
                let spawned = std::thread::Builder::new().spawn_scoped(scope, move || {
                    let loaded = match self.worker_system() {
                        Ok(l) => l,
                        Err(e) => {
                            let _ = tx.send(Err(e));
                            return;
                        }
                    };
                    loop {
                        let k = next.fetch_add(1, Ordering::Relaxed);
                        let Some((id, values)) = points.get(k) else {
                            break;
                        };
                        let row = self.run_values(&loaded, *id, values);
                        if tx.send(Ok(row)).is_err() {
                            break;
                        }
                    }
                    self.give_back(loaded);
                });
                match spawned {
                    Ok(_) => started += 1,
                    Err(e) => {
                        not_started.get_or_insert(e);
                    }
                }
            }
            drop(tx);
            let index: HashMap<u64, usize> = points
                .iter()
                .enumerate()
                .map(|(k, (id, _))| (*id, k))
                .collect();
            for msg in rx {
                let r = msg.and_then(|row| {
                    if let Some(&k) = index.get(&row.point) {
                        done[k] = true;
                    }
                    on_row(row)
                });
                if let Err(e) = r {
                    // Stop handing out points; the workers finish the one they hold.
                    next.store(usize::MAX / 2, Ordering::Relaxed);
                    if outcome.is_ok() {
                        outcome = Err(e);
                    }
                }
            }
        });
        outcome?;
        if let (0, Some(e)) = (started, not_started) {
            return Err(SweepError::System(format!(
                "cannot start a sweep worker thread: {e}"
            )));
        }
        let missing: Vec<u64> = points
            .iter()
            .zip(&done)
            .filter(|(_, d)| !**d)
            .map(|((id, _), _)| *id)
            .collect();
        if !missing.is_empty() {
            return Err(SweepError::Missing(missing));
        }
        Ok(())
    }

    /// [`run_batch`](Self::run_batch) on one worker: the points run on the calling thread, in
    /// order, each row handed to `on_row` as it ends. The rows are those of a worker thread (a
    /// thread and a channel's hand-over per row saved: most of a point's cost beyond its run,
    /// context switches); the test `tables_are_bit_identical_whatever_the_workers_and_the_order`
    /// compares the tables of one worker with those of two and four threads bit for bit. An
    /// error of `on_row` stops the batch at once.
    fn run_on_caller(
        &self,
        points: &[(u64, Vec<f64>)],
        on_row: &mut dyn FnMut(Row) -> Result<(), SweepError>,
    ) -> Result<(), SweepError> {
        let loaded = self.worker_system()?;
        let mut outcome = Ok(());
        for (id, values) in points {
            let row = self.run_values(&loaded, *id, values);
            if let Err(e) = on_row(row) {
                outcome = Err(e);
                break;
            }
        }
        self.give_back(loaded);
        outcome
    }

    /// A loaded system for a worker: an idle one (the one loaded to check the spec, or one a
    /// finished batch gave back) if there is one, else a fresh loading of
    /// [`system_file`](Self::system_file).
    pub fn worker_system(&self) -> Result<LoadedSystem, SweepError> {
        let idle = self.idle.lock().ok().and_then(|mut p| p.pop());
        match idle {
            Some(l) => Ok(l),
            None => {
                ssp::load_system(&self.system_file, &LoadOptions::default()).map_err(system_error)
            }
        }
    }

    /// Gives a worker's loaded system back for the next batch (see
    /// [`worker_system`](Self::worker_system)); every point runs on a copy of its system and
    /// leaves it as it was, so nothing of one batch's runs is left in it.
    pub fn give_back(&self, loaded: LoadedSystem) {
        if let Ok(mut idle) = self.idle.lock() {
            idle.push(loaded);
        }
    }

    /// Runs point `id` of the design on a loaded system: its row, whatever happens (an id
    /// outside the design is a failed row).
    pub fn run_point(&self, loaded: &LoadedSystem, id: u64) -> Row {
        match self.design.points.get(id as usize) {
            Some(values) => self.run_values(loaded, id, values),
            None => Row {
                point: id,
                parameters: Vec::new(),
                metrics: vec![f64::NAN; self.metric_names.len()],
                status: RunStatus::Failed,
                message: format!(
                    "point {id} is not in the design ({} points)",
                    self.design.points.len()
                ),
            },
        }
    }

    /// Runs the parameter values `values` (in spec order) as point `id` on a copy of the loaded
    /// system (`loaded.system`, as the SSP built it; left as it was), the values set after the
    /// SSP's: its row, whatever happens (values of another number than the parameters' give a
    /// failed row).
    pub fn run_values(&self, loaded: &LoadedSystem, id: u64, values: &[f64]) -> Row {
        let mut row = Row {
            point: id,
            parameters: values.to_vec(),
            metrics: vec![f64::NAN; self.metric_names.len()],
            status: RunStatus::Ok,
            message: String::new(),
        };
        let fail = |mut row: Row, message: String| {
            row.status = RunStatus::Failed;
            row.message = message;
            row
        };
        if values.len() != self.spec.parameters.len() {
            let message = format!(
                "point {id} has {} values for {} parameters",
                values.len(),
                self.spec.parameters.len()
            );
            return fail(row, message);
        }
        // The system as the SSP built it (components, step multiples, its parameter values,
        // connections), copied: nothing of one point's values is left for the next.
        let mut system = loaded.system.clone();
        for (p, &v) in self.spec.parameters.iter().zip(values) {
            let value = match p.ty {
                ParameterType::Real => Value::Real(v),
                // A whole number of the 32-bit range only: a cast ran 1.5 as 1 and NaN as 0
                // while the row showed the value given.
                ParameterType::Integer => match whole_i32(v) {
                    Some(i) => Value::Integer(i),
                    None => {
                        let message =
                            format!("point {id}: {} is an Integer variable, not {v}", p.name);
                        return fail(row, message);
                    }
                },
            };
            if let Err(e) = system.set_value(&p.name, value) {
                return fail(row, e.to_string());
            }
        }
        // A scenario's run follows the point's gait period as the study's runs follow theirs
        // (`study::gait_scenario`): `cycles` periods, the fade-in over half the first.
        let mut config = std::borrow::Cow::Borrowed(&self.config);
        if let (SystemSource::Scenario { cycles, .. }, Some(i)) = (
            &self.spec.system,
            self.spec
                .parameters
                .iter()
                .position(|p| p.name == GAIT_PERIOD),
        ) {
            let period = values[i];
            if self.spec.stop_time.is_none() {
                let h = config.step_size;
                config.to_mut().stop_time = study::gait_stop_time(period, *cycles, h);
            }
            let fade_in = Value::Real(study::gait_fade_in(period));
            if !self
                .spec
                .parameters
                .iter()
                .any(|p| p.name == study::GAIT_FADE_IN)
                && let Err(e) = system.set_value(study::GAIT_FADE_IN, fade_in)
            {
                return fail(row, e.to_string());
            }
        }
        let refs: Vec<&str> = self.recorded.iter().map(String::as_str).collect();
        if let Err(e) = system.record(&refs) {
            return fail(row, e.to_string());
        }
        let output = match system.run(&config) {
            Ok(o) => o,
            Err(e) => return fail(row, e.to_string()),
        };
        match &output.outcome {
            Outcome::Completed { .. } => {}
            Outcome::Terminated {
                component,
                last_successful_time,
                messages,
                ..
            } => {
                let reason = messages
                    .last()
                    .and_then(|m| m.rsplit(": ").next())
                    .unwrap_or("terminated");
                row.status = RunStatus::Tripped;
                row.message = format!(
                    "{component}: {reason} at t = {}",
                    model_description::num::Num(*last_successful_time)
                );
            }
            Outcome::Failed(e) => {
                row.status = RunStatus::Failed;
                row.message = e.to_string();
            }
        }
        // A run that tripped or failed keeps its own message; metrics it could not give stay NaN.
        if let Err(message) = self.metrics(&output.results, values, &mut row)
            && row.status == RunStatus::Ok
        {
            row.status = RunStatus::Failed;
            row.message = message;
        }
        row
    }

    fn metrics(&self, results: &Results, values: &[f64], row: &mut Row) -> Result<(), String> {
        let mut k = 0;
        if self.spec.study_metrics {
            let period = self
                .spec
                .parameters
                .iter()
                .position(|p| p.name == GAIT_PERIOD)
                .map(|i| values[i])
                .or(self.period)
                .unwrap_or(f64::NAN);
            if results.is_empty() {
                return Err("no rows recorded".into());
            }
            let r = study::analyse("run", results, period, &Columns::default())
                .map_err(|e| e.to_string())?;
            let m = study_metric_values(&r);
            row.metrics[..m.len()].copy_from_slice(&m);
            k = m.len();
            if let Some((name, t)) = &r.trip
                && row.status == RunStatus::Ok
            {
                row.status = RunStatus::Tripped;
                row.message = format!("{name} at t = {}", model_description::num::Num(*t));
            }
        }
        let mut empty = None;
        for s in &self.spec.signals {
            let col = results
                .column_index(&s.signal)
                .ok_or_else(|| format!("no column '{}'", s.signal))?;
            let from = s.from.unwrap_or(f64::NEG_INFINITY);
            let to = s.to.unwrap_or(f64::INFINITY);
            // The window's values, read in place.
            let window = || {
                results
                    .rows()
                    .filter(move |r| r[0] >= from && r[0] <= to)
                    .map(move |r| r[col])
            };
            let n = window().count();
            if n == 0 && empty.is_none() {
                empty = Some(format!(
                    "the window of '{}' (spec line {}) holds no recorded row",
                    s.signal, s.line
                ));
            }
            for st in &s.stats {
                row.metrics[k] = if n == 0 {
                    f64::NAN
                } else {
                    let n = n as f64;
                    match st {
                        Stat::Min => window().fold(f64::INFINITY, f64::min),
                        Stat::Max => window().fold(f64::NEG_INFINITY, f64::max),
                        Stat::Mean => window().sum::<f64>() / n,
                        Stat::Rms => (window().map(|x| x * x).sum::<f64>() / n).sqrt(),
                    }
                };
                k += 1;
            }
        }
        // Checked before the runs (`window_problems`); a run that ended early (tripped) keeps
        // its own status and message.
        empty.map_or(Ok(()), Err)
    }
}

/// Runs a whole sweep, writing the table to `output` (`.parquet`, else CSV) when given, with a
/// journal next to it for `--resume`. Returns the table (rows sorted by point id). A number of
/// workers outside `1..=`[`MAX_WORKERS`] is refused before anything is written.
pub fn run_sweep(
    prepared: &Prepared,
    output: Option<&Path>,
    options: &SweepOptions,
) -> Result<SweepTable, SweepError> {
    check_workers(options.workers)?;
    let mut sweep = JournaledSweep::start(prepared, output, options)?;
    let todo = sweep.pending();
    prepared.run_points(&todo, options.workers, &mut |row| {
        prepared.unless_stopped()?;
        sweep.record(row)
    })?;
    sweep.finish(output)
}

/// A sweep's rows as they come, journaled when the table goes to a file: the local
/// [`run_sweep`], or a driver that runs the points elsewhere (the Python package's Dask
/// sweep), with the same journal, `--resume` and table. `P` holds the prepared sweep (a
/// reference, or an `Arc` for a driver that keeps it).
pub struct JournaledSweep<P: std::borrow::Borrow<Prepared>> {
    prepared: P,
    finished: Finished,
}

impl<P: std::borrow::Borrow<Prepared>> JournaledSweep<P> {
    /// Starts the sweep of `prepared` (a spec with `[optimize]` is refused): with `output`, its
    /// journal, whose rows (or, with `options.resume` and no journal, a finished Parquet
    /// table's) are taken as done.
    pub fn start(
        prepared: P,
        output: Option<&Path>,
        options: &SweepOptions,
    ) -> Result<JournaledSweep<P>, SweepError> {
        let p: &Prepared = prepared.borrow();
        p.refuse_optimization()?;
        let points = &p.design.points;
        let mut finished = Finished::start(p, output, options, points.len() as u64, &|id| {
            (id as usize) < points.len()
        })?;
        for row in finished.rows.values_mut() {
            row.parameters = points[row.point as usize].to_vec();
        }
        Ok(JournaledSweep { prepared, finished })
    }

    /// The design's points without a row yet, in id order.
    pub fn pending(&self) -> Vec<u64> {
        (0..self.prepared.borrow().design.points.len() as u64)
            .filter(|i| !self.finished.rows.contains_key(i))
            .collect()
    }

    /// Keeps a point's row (journaled first). A row of a point outside the design, or whose
    /// parameters are not its point's (bit for bit), is refused.
    pub fn record(&mut self, row: Row) -> Result<(), SweepError> {
        let points = &self.prepared.borrow().design.points;
        match points.get(row.point as usize) {
            Some(values) if same_bits(values, &row.parameters) => self.finished.record(row),
            Some(_) => Err(SweepError::System(format!(
                "point {}: a row with other parameter values than the design's",
                row.point
            ))),
            None => Err(SweepError::System(format!(
                "point {} is not in the design ({} points)",
                row.point,
                points.len()
            ))),
        }
    }

    /// The table (rows sorted by point id), written to `output` when given, and the journal
    /// removed. Points without a row are an error naming them ([`SweepError::Missing`]), the
    /// journal kept for `--resume`.
    pub fn finish(mut self, output: Option<&Path>) -> Result<SweepTable, SweepError> {
        let missing = self.pending();
        if !missing.is_empty() {
            return Err(SweepError::Missing(missing));
        }
        let mut table = self.prepared.borrow().empty_table();
        table.rows = std::mem::take(&mut self.finished.rows)
            .into_values()
            .collect();
        self.finished.end(&table, output)?;
        Ok(table)
    }
}

/// Rows of `table` as `(point, status)` counts: (ok, tripped, failed).
pub fn status_counts(table: &SweepTable) -> (usize, usize, usize) {
    let count = |s| table.rows.iter().filter(|r| r.status == s).count();
    (
        count(RunStatus::Ok),
        count(RunStatus::Tripped),
        count(RunStatus::Failed),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn worker_counts_outside_one_to_the_bound_are_refused() {
        for ok in [1, 2, MAX_WORKERS] {
            assert!(check_workers(ok).is_ok(), "{ok}");
        }
        for bad in [0, MAX_WORKERS + 1, usize::MAX] {
            let e = check_workers(bad).unwrap_err().to_string();
            assert!(
                e.contains(&bad.to_string()) && e.contains("1 to 1024"),
                "{e}"
            );
        }
        // The default (every core) is within the bound whatever the machine.
        assert!(check_workers(SweepOptions::default().workers).is_ok());
    }
}
