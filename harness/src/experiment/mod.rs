//! The bench's experiments (bench-model.md sections 5, 6 and 8) as runs of this harness, on the
//! `BenchPlant` FMU or, unchanged, on `BenchHardware` (the physical bench, or `kneebench
//! emulate`): the same schedule, controllers and analysis on both.
//!
//! | experiment | what it runs | what it gives |
//! |---|---|---|
//! | [`map`] | test motor in velocity control at constant speeds x load motor at constant torques | the harmonic drive's steady-state loss torque and efficiency, against the loss surface |
//! | [`bode`] | stepped-sine torque on one motor (`GaitReference` sweep) | gain and phase of the velocities per torque with their uncertainty, against the two-mass H1-H4 |
//! | [`triangle`] | triangle position wave, load torque raised each cycle | the load torque at which the load driver's braking limit trips |
//! | [`calibration`] | the pendulum torque `m g Lg sin(theta)` held at a series of angles | a, b, c of `V = a + b sin(theta + c)` for the torque transducer and the load cell |
//! | [`step`] | open-loop current step and a closed-loop position step | the velocity loop's reaction curve (gain, time constant, Ziegler-Nichols gains) and the position step's rise, settling, overshoot and peak time |
//!
//! Every experiment writes `<name>.csv` (every recorded signal of the run), `<name>-result.csv`
//! (the analysed table), `<name>.svg` and `<name>.png` (its figure) and `<name>.md` (a
//! Markdown section linking the figure by relative path).
//!
//! The system of a run: the bench FMU is the component `plant` (so columns read `plant.x` on
//! both FMUs); references come from `GaitReference` (`gait`) or from schedules fed as input
//! signals; loops are `PidController`s. All FMUs are loaded from one directory (by default the
//! bench FMU's). Motor torques are converted to current set values with the bench FMU's own
//! parameters (`harmonicDriveRatio`, `testMotorTorqueConstant`, `reductionRatio`,
//! `loadMotorTorqueConstant`), so both drivers run in current mode.
//!
//! **Interlocks.** On `BenchHardware` an experiment refuses to start unless every interlock of
//! section 7 is armed at or inside the bench's limits ([`Bench::check_armed`]). On the plant
//! the interlocks are the model's own (parameters of the same names).

pub mod analysis;
pub mod bode;
pub mod calibration;
pub mod map;
mod pacing;
pub mod step;
pub mod triangle;

pub(crate) use pacing::record_pacing;
pub use pacing::{LATE_LOG_USE, Pacing};

use std::path::{Path, PathBuf};

use crate::master::{MasterError, Outcome, RunConfig, RunOutput, Signal, System};
use crate::results::plot::PlotLabels;
use crate::results::{ColumnKind, Results, ResultsError};
use crate::{Fmu, LoadError, LoadOptions};

/// Errors of the experiments.
#[derive(Debug, thiserror::Error)]
pub enum ExperimentError {
    /// An FMU could not be loaded.
    #[error("{path}: {source}")]
    Load {
        /// The FMU.
        path: PathBuf,
        /// Why.
        source: LoadError,
    },
    /// Building or running the system failed.
    #[error(transparent)]
    Master(#[from] MasterError),
    /// Writing results or figures failed.
    #[error(transparent)]
    Results(#[from] ResultsError),
    /// A file could not be written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The hardware's interlocks are not armed: the experiment does not start.
    #[error(
        "refusing to start on the hardware: interlocks not armed ({})",
        .0.join("; ")
    )]
    NotArmed(Vec<String>),
    /// An option or parameter is invalid.
    #[error("{0}")]
    Invalid(String),
    /// The run ended before the experiment could be analysed.
    #[error("{0}")]
    Run(String),
    /// The analysis failed.
    #[error("analysis: {0}")]
    Analysis(String),
}

/// Which bench FMU an experiment runs on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BenchKind {
    /// `BenchPlant`, the simulated bench.
    Plant,
    /// `BenchHardware`, the physical bench (or the emulator behind it).
    Hardware,
}

/// The bench under test: its FMU, the parameter values set on it, and the directory of the
/// other FMUs (`GaitReference.fmu`, `PidController.fmu`).
#[derive(Debug, Clone)]
pub struct Bench {
    fmu: Fmu,
    path: PathBuf,
    kind: BenchKind,
    parameters: Vec<(String, String)>,
    fmu_dir: PathBuf,
    raw_format: RawFormat,
    /// The parameter set's label (`name vN (sha256 ...)`) when one was applied.
    parameter_set: Option<String>,
}

/// The format of an experiment's raw run file (`<name>.csv` or `<name>.parquet`); the analysed
/// table stays CSV (a few hundred rows).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum RawFormat {
    /// CSV, every signal as text.
    #[default]
    Csv,
    /// Parquet, float64 columns with the bench FMU and its parameters as metadata.
    Parquet,
}

/// The interlock limits of bench-model.md section 7: (parameter, largest armed value, what).
pub const ARMED_LIMITS: [(&str, f64, &str); 5] = [
    (
        "springDeflectionLimit",
        0.087_266_462_599_716_48,
        "spring deflection 5 deg",
    ),
    ("motorTorqueLimit", 20.0, "motor torque 20 N m"),
    (
        "loadRegenPowerLimit",
        5.0,
        "load driver regenerated power 5 W",
    ),
    ("testCurrentLimit", 15.0, "test driver current 15 A"),
    ("loadCurrentLimit", 6.0, "load driver current 6 A"),
];

impl Bench {
    /// Loads the bench FMU at `path` (a `BenchPlant` or `BenchHardware` FMU) with `parameters`
    /// (name, value as text) to set on it; `fmu_dir` holds the other FMUs (default: the bench
    /// FMU's directory). A name that is not a parameter of the FMU, or a value not of its type
    /// or outside its declared `[min, max]`, is [`ExperimentError::Invalid`]
    /// ([`check_assignments`](crate::params::check_assignments)).
    pub fn load(
        path: &Path,
        parameters: Vec<(String, String)>,
        fmu_dir: Option<PathBuf>,
    ) -> Result<Bench, ExperimentError> {
        let fmu = load(path)?;
        let id = fmu
            .model_description()
            .co_simulation
            .as_ref()
            .map(|c| c.model_identifier.clone())
            .unwrap_or_default();
        let kind = match id.as_str() {
            "BenchPlant" => BenchKind::Plant,
            "BenchHardware" => BenchKind::Hardware,
            other => {
                return Err(ExperimentError::Invalid(format!(
                    "{}: model '{other}' is not a bench FMU (BenchPlant or BenchHardware)",
                    path.display()
                )));
            }
        };
        // Each name a parameter, each value of its type and inside its declared range, before
        // anything runs: a value the FMU would refuse while the experiment starts is an invalid
        // setting, not a failed run.
        crate::params::check_assignments(&fmu, &parameters).map_err(|problem| {
            ExperimentError::Invalid(format!("{}: {problem}", path.display()))
        })?;
        let fmu_dir = fmu_dir.unwrap_or_else(|| {
            path.parent()
                .map(Path::to_path_buf)
                .unwrap_or_else(|| PathBuf::from("."))
        });
        Ok(Bench {
            fmu,
            path: path.to_path_buf(),
            kind,
            parameters,
            fmu_dir,
            raw_format: RawFormat::Csv,
            parameter_set: None,
        })
    }

    /// The same bench writing its experiments' raw runs in `format`.
    pub fn with_raw_format(mut self, format: RawFormat) -> Bench {
        self.raw_format = format;
        self
    }

    /// The same bench, its parameters coming from the set labelled `label` (named in the raw
    /// run's Parquet metadata as `kneebench.parameter_set`).
    pub fn with_parameter_set(mut self, label: String) -> Bench {
        self.parameter_set = Some(label);
        self
    }

    /// Plant or hardware.
    pub fn kind(&self) -> BenchKind {
        self.kind
    }

    /// The FMU's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The value of a parameter as the run sets it: the value given, else the FMU's start value.
    pub fn real(&self, name: &str) -> Result<f64, ExperimentError> {
        let given = self
            .parameters
            .iter()
            .rev()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.clone());
        let text = match given {
            Some(v) => v,
            None => self
                .fmu
                .variable(name)
                .and_then(|v| v.kind.start_string())
                .ok_or_else(|| {
                    ExperimentError::Invalid(format!(
                        "{}: no value for parameter '{name}'",
                        self.path.display()
                    ))
                })?,
        };
        text.trim().parse::<f64>().map_err(|_| {
            ExperimentError::Invalid(format!("parameter '{name}' = '{text}' is not a number"))
        })
    }

    /// Output torque per ampere of the test motor, `i_HD Km1` [N m/A].
    pub fn test_torque_per_ampere(&self) -> Result<f64, ExperimentError> {
        Ok(self.real("harmonicDriveRatio")? * self.real("testMotorTorqueConstant")?)
    }

    /// Output torque per ampere of the load motor, `i_RED Km2` [N m/A].
    pub fn load_torque_per_ampere(&self) -> Result<f64, ExperimentError> {
        Ok(self.real("reductionRatio")? * self.real("loadMotorTorqueConstant")?)
    }

    /// On `BenchHardware`: every interlock of [`ARMED_LIMITS`] set above zero and at or below
    /// the bench's limit, and the sensor-consistency checks on (`consistencyPersistence` > 0).
    /// Lists every interlock that is not. On the plant: always Ok.
    pub fn check_armed(&self) -> Result<(), ExperimentError> {
        if self.kind == BenchKind::Plant {
            return Ok(());
        }
        let mut problems = Vec::new();
        for (name, limit, what) in ARMED_LIMITS {
            match self.real(name) {
                Ok(v) if v > 0.0 && v <= limit * (1.0 + 1e-12) => {}
                Ok(v) => problems.push(format!(
                    "{name} = {v} (armed: 0 < value <= {limit}, {what})"
                )),
                Err(e) => problems.push(e.to_string()),
            }
        }
        match self.real("consistencyPersistence") {
            Ok(v) if v >= 1.0 => {}
            Ok(v) => problems.push(format!(
                "consistencyPersistence = {v} turns the sensor-consistency interlocks off"
            )),
            Err(e) => problems.push(e.to_string()),
        }
        if problems.is_empty() {
            Ok(())
        } else {
            Err(ExperimentError::NotArmed(problems))
        }
    }

    /// A system holding the bench as component `plant` with its parameters set.
    fn system(&self) -> Result<System, ExperimentError> {
        let mut system = System::new();
        system.add_component("plant", self.fmu.clone())?;
        for (name, value) in &self.parameters {
            system.set_value_str(&format!("plant.{name}"), value)?;
        }
        Ok(system)
    }

    /// Loads another kneebench FMU (`GaitReference`, `PidController`) from the FMU directory.
    fn companion(&self, identifier: &str) -> Result<Fmu, ExperimentError> {
        load(&self.fmu_dir.join(format!("{identifier}.fmu")))
    }

    /// Adds the experiments' position loop to `system` as component `position`: a
    /// `PidController` with `gains` (kp, ki, kd), the derivative filter of
    /// [`POSITION_DERIVATIVE_FILTER_TIME`], its output (the test motor's current command)
    /// limited to the bench's `testCurrentLimit`, and the settings of `extra`. The caller
    /// connects it.
    fn add_position_loop(
        &self,
        system: &mut System,
        gains: (f64, f64, f64),
        extra: &[(&str, f64)],
    ) -> Result<(), ExperimentError> {
        system.add_component("position", self.companion("PidController")?)?;
        let limit = self.real("testCurrentLimit")?;
        set_reals(
            system,
            "position",
            &[
                ("kp", gains.0),
                ("ki", gains.1),
                ("kd", gains.2),
                ("derivativeFilterTime", POSITION_DERIVATIVE_FILTER_TIME),
                ("outputMin", -limit),
                ("outputMax", limit),
            ],
        )?;
        set_reals(system, "position", extra)
    }
}

/// The derivative filter time constant of the experiments' position loop \[s\]: one place
/// for the step, triangle and calibration experiments, whose identification reads their
/// logs together.
const POSITION_DERIVATIVE_FILTER_TIME: f64 = 0.002;

fn load(path: &Path) -> Result<Fmu, ExperimentError> {
    Fmu::load(path, &LoadOptions::default()).map_err(|source| ExperimentError::Load {
        path: path.to_path_buf(),
        source,
    })
}

/// Sets real parameters `(name, value)` of component `component`.
fn set_reals(
    system: &mut System,
    component: &str,
    values: &[(&str, f64)],
) -> Result<(), ExperimentError> {
    for (name, v) in values {
        set_checked(system, component, name, crate::master::Value::Real(*v))?;
    }
    Ok(())
}

/// Sets integer (enumeration) parameters of component `component`.
fn set_integers(
    system: &mut System,
    component: &str,
    values: &[(&str, i32)],
) -> Result<(), ExperimentError> {
    for (name, v) in values {
        set_checked(system, component, name, crate::master::Value::Integer(*v))?;
    }
    Ok(())
}

/// Sets `component.name` to `value` once the model description accepts it
/// ([`check_system_start_value`](crate::params::check_system_start_value)): a value an option gives that
/// the FMU would refuse as the run starts (`bode --start-frequency 1e6`, past the gait's
/// `sweepStartFrequency` bound) is a refusal of the settings ([`ExperimentError::Invalid`],
/// a usage error), not a failed run.
fn set_checked(
    system: &mut System,
    component: &str,
    name: &str,
    value: crate::master::Value,
) -> Result<(), ExperimentError> {
    let reference = format!("{component}.{name}");
    crate::params::check_system_start_value(system, &reference, &value)
        .map_err(|problem| ExperimentError::Invalid(format!("{reference}: {problem}")))?;
    system.set_value(&reference, value)?;
    Ok(())
}

/// A piecewise-constant (or, with `interpolate`, piecewise-linear) schedule as an input signal.
fn schedule(points: Vec<(f64, f64)>, interpolate: bool) -> Signal {
    let (times, values) = points.into_iter().unzip();
    Signal {
        times,
        values,
        interpolate,
    }
}

/// How a run of an experiment ended.
#[derive(Debug, Clone, PartialEq)]
pub enum RunEnd {
    /// The whole schedule ran.
    Completed,
    /// An interlock (or another cause the bench FMU names) ended the run at `time`.
    Tripped {
        /// The last successful time \[s\].
        time: f64,
        /// What the bench logged.
        reason: String,
    },
}

impl std::fmt::Display for RunEnd {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RunEnd::Completed => f.write_str("the run completed"),
            RunEnd::Tripped { time, reason } => {
                write!(f, "the run was ended at {time:.3} s: {reason}")
            }
        }
    }
}

/// Runs `system` (holding `bench` as `plant`) to `stop_time` at 1 ms steps (Gauss-Seidel),
/// recording the [`Pacing`] locals after the outputs on the hardware. A run ended by the bench
/// keeps its rows and says why; a failure is an error.
fn run(
    bench: &Bench,
    system: &mut System,
    stop_time: f64,
) -> Result<(RunOutput, RunEnd), ExperimentError> {
    check_length("the schedule", stop_time)?;
    if bench.kind() == BenchKind::Hardware {
        record_pacing(system)?;
    }
    let config = RunConfig {
        stop_time,
        step_size: STEP,
        ..RunConfig::default()
    };
    let output = system.run(&config)?;
    let end = match &output.outcome {
        Outcome::Completed { .. } => RunEnd::Completed,
        Outcome::Terminated {
            component,
            last_successful_time,
            messages,
            ..
        } => RunEnd::Tripped {
            time: *last_successful_time,
            reason: format!(
                "{component}: {}",
                messages.last().map(String::as_str).unwrap_or("terminated")
            ),
        },
        Outcome::Failed(e) => {
            // The error names its own time where it has one; the last row says how far the
            // run got (none: it failed before recording its first row, while starting).
            return Err(ExperimentError::Run(match output.results.last_time() {
                Some(t) => format!(
                    "the run failed after its row at t = {}: {e}",
                    model_description::num::Num(t)
                ),
                None => format!("the run failed before its first row: {e}"),
            }));
        }
    };
    Ok((output, end))
}

/// The control period of every experiment \[s\] (the myRIO's 1 ms).
pub const STEP: f64 = 1e-3;

/// The most rows one run of an experiment records: 2 million, 2000 s (33 min) of bench time at
/// the 1 ms [`STEP`], above the default Bode sweep's 1.4 million (70 stages of 20 s), the
/// longest default schedule.
///
/// Every row of a run stays in memory until the analysis: the bench records about 90 columns
/// (every output of the bench FMU and its companions) of 8 bytes, about 1.5 GB at this bound,
/// and the raw run file is about as large as CSV. A longer schedule grew until the machine ran
/// out of memory; it is refused before it starts, as an invalid setting
/// ([`ExperimentError::Invalid`]).
pub const MAX_RUN_ROWS: u64 = 2_000_000;

/// Refuses a run of `seconds` (the schedule of `what`) longer than [`MAX_RUN_ROWS`] rows.
pub(crate) fn check_length(what: &str, seconds: f64) -> Result<(), ExperimentError> {
    let rows = (seconds / STEP).round();
    // Written so that NaN is refused too.
    if rows <= MAX_RUN_ROWS as f64 {
        return Ok(());
    }
    Err(ExperimentError::Invalid(format!(
        "{what} lasts {} s: {} rows at the {} ms step, more than the {MAX_RUN_ROWS} rows \
         ({} s) a run of an experiment records (they are kept in memory)",
        model_description::num::Num(seconds),
        model_description::num::Num(rows),
        STEP * 1e3,
        MAX_RUN_ROWS as f64 * STEP
    )))
}

/// A column of the results, or an error naming it.
fn column(results: &Results, name: &str) -> Result<Vec<f64>, ExperimentError> {
    results
        .column(name)
        .ok_or_else(|| ExperimentError::Analysis(format!("the results lack column '{name}'")))
}

/// What an experiment wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct Written {
    /// Data files (CSV).
    pub data: Vec<PathBuf>,
    /// Figures (SVG and PNG).
    pub figures: Vec<PathBuf>,
    /// The Markdown section.
    pub markdown: PathBuf,
    /// How the run kept its schedule, on the hardware (`None` on the simulated bench).
    pub pacing: Option<Pacing>,
}

/// A table of analysed rows: `x` column name, other column names, rows.
struct Table {
    x: String,
    names: Vec<String>,
    rows: Vec<(f64, Vec<f64>)>,
}

impl Table {
    fn to_results(&self) -> Results {
        let mut r = Results::with_capacity(
            self.names.clone(),
            vec![ColumnKind::Real; self.names.len()],
            self.rows.len(),
        );
        for (x, row) in &self.rows {
            r.push_row(*x, row);
        }
        r
    }

    /// Writes the table as CSV, its first column renamed from `time` to the table's x.
    fn write_csv(&self, path: &Path) -> Result<(), ExperimentError> {
        let mut bytes = Vec::new();
        self.to_results()
            .write_csv(&mut bytes)
            .map_err(|source| ExperimentError::Io {
                path: path.to_path_buf(),
                source,
            })?;
        let text = String::from_utf8_lossy(&bytes);
        let body = text.split_once('\n').map_or("", |(_, b)| b);
        let header = std::iter::once(csv_field(&self.x))
            .chain(self.names.iter().map(|n| csv_field(n)))
            .collect::<Vec<_>>()
            .join(",");
        write_file(path, &format!("{header}\n{body}"))
    }
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

fn write_file(path: &Path, text: &str) -> Result<(), ExperimentError> {
    std::fs::write(path, text).map_err(|source| ExperimentError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Draws `series` of `results` (x = its first column) as `<out>/<name>.svg` and `.png`.
fn figure(
    results: &Results,
    series: &[&str],
    out: &Path,
    name: &str,
    labels: &PlotLabels,
) -> Result<Vec<PathBuf>, ExperimentError> {
    std::fs::create_dir_all(out).map_err(|source| ExperimentError::Io {
        path: out.to_path_buf(),
        source,
    })?;
    let mut files = Vec::new();
    for ext in ["svg", "png"] {
        let path = out.join(format!("{name}.{ext}"));
        crate::results::plot::plot_signals_with(results, series, &path, (1024, 560), labels)?;
        files.push(path);
    }
    Ok(files)
}

/// Writes the common files of an experiment: the raw run, the analysed table, the figure (of
/// `series` of the table) and the Markdown section (`body` after a heading, the figure linked).
#[allow(clippy::too_many_arguments)]
fn write_outputs(
    bench: &Bench,
    out: &Path,
    name: &str,
    title: &str,
    run: &Results,
    table: &Table,
    series: &[&str],
    labels: &PlotLabels,
    body: &str,
) -> Result<Written, ExperimentError> {
    std::fs::create_dir_all(out).map_err(|source| ExperimentError::Io {
        path: out.to_path_buf(),
        source,
    })?;
    let raw = match bench.raw_format {
        RawFormat::Csv => {
            let raw = out.join(format!("{name}.csv"));
            run.write_csv_file(&raw)?;
            raw
        }
        RawFormat::Parquet => {
            let raw = out.join(format!("{name}.parquet"));
            let mut metadata = vec![
                ("kneebench.experiment".to_string(), name.to_string()),
                (
                    "kneebench.bench_fmu".to_string(),
                    bench.path.display().to_string(),
                ),
                (
                    "kneebench.bench_guid".to_string(),
                    bench.fmu.model_description().guid.clone(),
                ),
            ];
            if let Some(label) = &bench.parameter_set {
                metadata.push(("kneebench.parameter_set".to_string(), label.clone()));
            }
            metadata.extend(
                bench
                    .parameters
                    .iter()
                    .map(|(n, v)| (format!("kneebench.parameter.{n}"), v.clone())),
            );
            run.write_parquet_file(&raw, metadata)?;
            raw
        }
    };
    let raw_name = raw
        .file_name()
        .map(|f| f.to_string_lossy().into_owned())
        .unwrap_or_default();
    let analysed = out.join(format!("{name}-result.csv"));
    table.write_csv(&analysed)?;
    let figures = figure(&table.to_results(), series, out, name, labels)?;
    let markdown = out.join(format!("{name}.md"));
    let pacing = Pacing::of(run);
    let pacing_text = match &pacing {
        None => String::new(),
        Some(p) => match p.schedule_warning() {
            None => format!("\n**Pacing on the hardware.** {p}.\n"),
            Some(w) => format!(
                "\n**Pacing on the hardware.** {p}. **Warning: {w}. Where the results matter, \
                 run the experiment again on a quieter host (or a real-time one)**; \
                 {LATE_LOG_USE}.\n"
            ),
        },
    };
    write_file(
        &markdown,
        &format!(
            "## {title}\n\n![{title}]({name}.png)\n\n(vector: [{name}.svg]({name}.svg); data: [{name}-result.csv]({name}-result.csv), every signal of the run: [{raw_name}]({raw_name}))\n\n{body}{pacing_text}\n"
        ),
    )?;
    Ok(Written {
        data: vec![raw, analysed],
        figures,
        markdown,
        pacing,
    })
}

/// Formats a number for a Markdown table (NaN as a dash).
fn num(v: f64, decimals: usize) -> String {
    if v.is_finite() {
        format!("{v:.decimals$}")
    } else {
        "-".into()
    }
}
