//! The sweep specification: a TOML file read with `serde`, every value kept with its place in
//! the file so that each refusal names its line.
//!
//! ```toml
//! system = "SEA"          # DA, SEA, CSEA (the study's scenarios) or a path to an .ssp/.ssd
//! fmus = "../out/fmus"    # where the scenario's FMUs are (relative to this file)
//! cycles = 2              # scenario: gait cycles per run (the first is the start-up)
//! stop_time = 5.0         # optional: default cycles x gait period, or the SSP's experiment
//! step = 0.001            # optional
//!
//! [design]
//! kind = "latin-hypercube"  # grid, latin-hypercube, sobol, random, csv
//! points = 20               # all but grid and csv
//! seed = 7                  # latin-hypercube, random; sobol: at most 2^32 - 1
//! # file = "points.csv"     # csv: a header naming each parameter once, one row per point
//!
//! [[parameters]]
//! name = "plant.springStiffness"
//! min = 200.0
//! max = 500.0
//! levels = 3                # grid: evenly spaced values from min to max ...
//! # values = [250.0, 340.54] # ... or the values themselves
//!
//! [metrics]
//! study = true              # the study's per-cycle energy terms, tracking errors, peaks
//! # period = 2.5            # gait period for the study metrics (default: the system's gait)
//! [[metrics.signals]]
//! signal = "plant.shaftTorque"
//! stats = ["min", "max", "mean", "rms"]
//! from = 2.5                # window start [s] (default: start of the run)
//! to = 5.0                  # window end [s] (default: end of the run)
//! ```

use std::ops::Range;
use std::path::{Path, PathBuf};

use serde::Deserialize;
use toml::Spanned;

use super::SweepError;

/// One problem of a spec: where it is and what is wrong.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SpecProblem {
    /// The file the problem is in (the spec, or a design CSV).
    pub file: PathBuf,
    /// 1-based line (0 when the problem concerns the file as a whole).
    pub line: usize,
    /// What is wrong.
    pub message: String,
}

impl std::fmt::Display for SpecProblem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if self.line == 0 {
            write!(f, "{}: {}", self.file.display(), self.message)
        } else {
            write!(
                f,
                "{}, line {}: {}",
                self.file.display(),
                self.line,
                self.message
            )
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSpec {
    system: Spanned<String>,
    fmus: Option<Spanned<String>>,
    cycles: Option<Spanned<i64>>,
    stop_time: Option<Spanned<f64>>,
    step: Option<Spanned<f64>>,
    design: Spanned<RawDesign>,
    #[serde(default)]
    parameters: Vec<Spanned<RawParameter>>,
    #[serde(default)]
    metrics: Option<RawMetrics>,
    optimize: Option<Spanned<RawOptimize>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawOptimize {
    objective: Spanned<String>,
    direction: Option<Spanned<String>>,
    generations: Spanned<i64>,
    seed: Option<Spanned<i64>>,
    differential_weight: Option<Spanned<f64>>,
    crossover: Option<Spanned<f64>>,
    #[serde(default)]
    constraints: Vec<Spanned<RawConstraint>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConstraint {
    metric: Spanned<String>,
    min: Option<Spanned<f64>>,
    max: Option<Spanned<f64>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawDesign {
    kind: Spanned<String>,
    points: Option<Spanned<i64>>,
    seed: Option<Spanned<i64>>,
    file: Option<Spanned<String>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawParameter {
    name: Spanned<String>,
    min: Option<Spanned<f64>>,
    max: Option<Spanned<f64>>,
    levels: Option<Spanned<i64>>,
    values: Option<Spanned<Vec<f64>>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMetrics {
    study: Option<Spanned<bool>>,
    period: Option<Spanned<f64>>,
    #[serde(default)]
    signals: Vec<Spanned<RawSignalMetric>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSignalMetric {
    signal: Spanned<String>,
    stats: Spanned<Vec<String>>,
    from: Option<Spanned<f64>>,
    to: Option<Spanned<f64>>,
}

/// The most values one run of a sweep (or of an optimisation) may record: rows x (recorded
/// signals + the time column); 2^24 values, 128 MiB of 8-byte floats. A spec whose runs would
/// record more is refused at the line that makes them so long (`stop_time`, `cycles`, `step`, or
/// `system` for a system file's own experiment: [`SweepSpec::length_line`]).
///
/// Why a bound: a sweep's worker keeps every row of the run it is on in memory (the metrics
/// need the whole run), so a sweep holds rows recorded x (signals + 1) x 8 bytes per worker,
/// times the workers at once (one per core by default), and nothing else limits it: `cycles =
/// 1000000`, a long `stop_time` or a tiny `step` grew the workers' buffers until the machine ran
/// out of memory (the kernel killing a process, not an error naming the spec's line).
///
/// Why this bound: at it, a run records 128 MiB; with the slack of its growing buffer and the
/// columns the metrics copy, a worker peaks at about 1.5 times that, some 200 MB (measured: a
/// SEA sweep of 300 gait cycles, 16.5 million values or 126 MiB a run, peaked at 194 MB
/// resident with one worker and 365 MB with two, README "Parameter sweeps"). With one worker
/// per core that is 400 MB on 2 cores, 3.2 GB on 16 and 13 GB on 64: what a machine with that
/// many cores has to spare. For the study's scenarios (20 recorded signals and the time, a 1 ms
/// step, a 2.5 s gait cycle) the bound is 798,915 rows: 798 s of bench time, 319 gait cycles a
/// run (305 with one more signal), far beyond a sweep's usual 2 to 10. A longer run is
/// `kneebench run`, which streams its rows to a file.
pub const MAX_RUN_VALUES: u64 = 1 << 24;

/// The most gait cycles of a scenario's run (a typo guard, and `cycles` fits the scenario's
/// 32-bit count): at the scenario's 1 ms step far fewer cycles already exceed
/// [`MAX_RUN_VALUES`], which bounds the run's length whatever its step.
pub const MAX_CYCLES: usize = 10_000;

/// Rows a run of `duration` seconds records at base step `step`, keeping every
/// `record_every`-th step: one per kept step and the initial one. Saturating (a float): for
/// bounds only.
pub fn run_rows(duration: f64, step: f64, record_every: u64) -> f64 {
    ((duration / step).floor() / record_every.max(1) as f64).floor() + 1.0
}

/// What makes a run record more than [`MAX_RUN_VALUES`] ([`check_run_values`]), and so whose
/// line a refusal names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum TooLong {
    /// The spec's `step`: at the system's own step the run would have fitted.
    Step,
    /// What sets the runs' length (`stop_time`, `cycles`, or the system file's experiment).
    Length,
}

/// The bound on a run's recorded values, the one check of it: made where the spec tells the
/// runs' length and step ([`SweepSpec::parse`]) and, for a system file's own experiment, once
/// the system is loaded ([`Prepared::new`](super::Prepared::new)). `rows` are the rows a run
/// records at the step it runs at ([`run_rows`]), `own_rows` those it would record at the
/// system's own step when the spec sets another (`None` otherwise), `columns` the recorded
/// signals (the time column is added). A run within [`MAX_RUN_VALUES`] is Ok; one over it gives
/// what to blame and the message.
pub(crate) fn check_run_values(
    rows: f64,
    own_rows: Option<f64>,
    columns: usize,
) -> Result<(), (TooLong, String)> {
    let over = |rows: f64| rows * (columns as f64 + 1.0) > MAX_RUN_VALUES as f64;
    if !over(rows) {
        return Ok(());
    }
    let blame = match own_rows {
        Some(own) if !over(own) => TooLong::Step,
        _ => TooLong::Length,
    };
    let values = rows * (columns as f64 + 1.0);
    Err((
        blame,
        format!(
            "each run would record {rows:.0} rows of {columns} signals and the time ({values:.0} \
             values, {:.0} MiB), more than {MAX_RUN_VALUES} values ({} MiB) per run: shorten the \
             runs (stop_time, cycles), take a longer step, or record fewer signals",
            values * 8.0 / f64::from(1u32 << 20),
            (MAX_RUN_VALUES * 8) >> 20
        ),
    ))
}

/// The most points of a Sobol design: `sobol_burley` gives 2^16 points per sequence (beyond
/// that its samples are unspecified).
pub const SOBOL_MAX_POINTS: usize = 1 << 16;

/// What system a sweep runs.
#[derive(Debug, Clone, PartialEq)]
pub enum SystemSource {
    /// One of the study's gait scenarios, built from the FMUs in `fmu_dir`.
    Scenario {
        /// The actuator.
        actuator: crate::study::Actuator,
        /// The directory of the exported FMUs.
        fmu_dir: PathBuf,
        /// Gait cycles per run.
        cycles: u32,
    },
    /// An `.ssp` archive or `.ssd` file.
    File(PathBuf),
}

/// How the points are chosen.
#[derive(Debug, Clone, PartialEq)]
pub enum DesignKind {
    /// Every combination of the parameters' levels (the last parameter varies fastest).
    Grid,
    /// A Latin hypercube of `points` points.
    LatinHypercube {
        /// Number of points.
        points: usize,
        /// Random seed.
        seed: u64,
    },
    /// The first `points` points of an Owen-scrambled Sobol sequence.
    Sobol {
        /// Number of points.
        points: usize,
        /// Scrambling seed.
        seed: u64,
    },
    /// Independent uniform points.
    Random {
        /// Number of points.
        points: usize,
        /// Random seed.
        seed: u64,
    },
    /// The rows of a CSV file.
    Csv(PathBuf),
}

/// The type of a swept variable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParameterType {
    /// `Real`: any value.
    Real,
    /// `Integer` or `Enumeration`: whole values only.
    Integer,
}

/// One swept variable.
#[derive(Debug, Clone, PartialEq)]
pub struct Parameter {
    /// `component.variable`.
    pub name: String,
    /// Lower bound of the design (inclusive).
    pub min: Option<f64>,
    /// Upper bound of the design (inclusive).
    pub max: Option<f64>,
    /// Grid: number of evenly spaced levels from `min` to `max`.
    pub levels: Option<usize>,
    /// Grid: the levels themselves.
    pub values: Option<Vec<f64>>,
    /// The variable's type (known after [`Prepared::new`](super::Prepared::new)).
    pub ty: ParameterType,
    /// The variable's declared `min` (known after [`Prepared::new`](super::Prepared::new)):
    /// every point's value must respect it, whatever the design.
    pub declared_min: Option<f64>,
    /// The variable's declared `max` (known after [`Prepared::new`](super::Prepared::new)).
    pub declared_max: Option<f64>,
    /// The variable's unit (empty when it declares none; known after
    /// [`Prepared::new`](super::Prepared::new)).
    pub unit: String,
    /// 1-based line of the parameter in the spec.
    pub line: usize,
}

/// One statistic of a signal over a window.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stat {
    /// Smallest value.
    Min,
    /// Largest value.
    Max,
    /// Mean of the samples.
    Mean,
    /// Root mean square of the samples.
    Rms,
}

impl Stat {
    /// The name used in the spec and in column names.
    pub fn name(self) -> &'static str {
        match self {
            Stat::Min => "min",
            Stat::Max => "max",
            Stat::Mean => "mean",
            Stat::Rms => "rms",
        }
    }
}

/// Statistics of one recorded signal.
#[derive(Debug, Clone, PartialEq)]
pub struct SignalMetric {
    /// `component.variable`.
    pub signal: String,
    /// The statistics, each a column `<stat>(<signal>)` (with the window when the signal has
    /// entries of other windows: [`signal_columns`]).
    pub stats: Vec<Stat>,
    /// Window start \[s\] (default: the run's start).
    pub from: Option<f64>,
    /// Window end \[s\] (default: the run's end).
    pub to: Option<f64>,
    /// 1-based line in the spec.
    pub line: usize,
}

/// A parsed, checked sweep specification.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepSpec {
    /// The spec file (for messages) or `<string>`.
    pub file: PathBuf,
    /// The system.
    pub system: SystemSource,
    /// Stop time \[s\] (`None`: cycles x period for a scenario, the SSP's experiment otherwise).
    pub stop_time: Option<f64>,
    /// Base step \[s\] (`None`: the system's).
    pub step: Option<f64>,
    /// The design.
    pub design: DesignKind,
    /// The swept variables, in spec order.
    pub parameters: Vec<Parameter>,
    /// Whether the study's metrics are computed.
    pub study_metrics: bool,
    /// The gait period for the study metrics, if given.
    pub period: Option<f64>,
    /// Statistics of recorded signals.
    pub signals: Vec<SignalMetric>,
    /// The optimisation, if the spec has an `[optimize]` table (the design is then its first
    /// generation): see [`optimize`](super::optimize).
    pub optimize: Option<OptimizeSpec>,
    /// 1-based line of the value that sets how long the runs are: `stop_time`, else a
    /// scenario's `cycles`, else `system` (a scenario's default cycles, or a system file's own
    /// experiment). A run over [`MAX_RUN_VALUES`] is refused there, unless the spec's `step`
    /// is to blame ([`step_line`](Self::step_line)).
    pub length_line: usize,
    /// 1-based line of `step`, if the spec gives one: a run over [`MAX_RUN_VALUES`] that the
    /// system's own step would have kept within it is refused there.
    pub step_line: Option<usize>,
    /// 1-based line of `system` (a system file that does not exist is refused there).
    pub system_line: usize,
    /// 1-based line of `fmus`, if the spec gives it (a scenario's FMU directory that does not
    /// exist, or lacks an FMU, is refused there, else at [`system_line`](Self::system_line)).
    pub fmus_line: Option<usize>,
    /// 1-based line of `[metrics] study`, if the spec gives it (the study metrics without a
    /// gait period are refused there, else at [`system_line`](Self::system_line)).
    pub study_line: Option<usize>,
    /// The spec's text (its fingerprint identifies a sweep's journal).
    pub text: String,
}

/// 1-based line of a byte offset.
pub(crate) fn line_of(text: &str, offset: usize) -> usize {
    text.as_bytes()[..offset.min(text.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

struct Problems<'a> {
    file: &'a Path,
    text: &'a str,
    list: Vec<SpecProblem>,
}

impl Problems<'_> {
    fn at(&mut self, span: Range<usize>, message: impl Into<String>) {
        self.list.push(SpecProblem {
            file: self.file.to_path_buf(),
            line: line_of(self.text, span.start),
            message: message.into(),
        });
    }
}

fn count(p: &mut Problems<'_>, v: &Spanned<i64>, what: &str) -> Option<usize> {
    let n = *v.get_ref();
    if n < 1 {
        p.at(v.span(), format!("{what} must be at least 1, not {n}"));
        return None;
    }
    Some(n as usize)
}

/// [`count`], at most `max` (a larger one is refused at its line: a typo guard, and a bound
/// on what is allocated from it).
fn count_at_most(p: &mut Problems<'_>, v: &Spanned<i64>, what: &str, max: usize) -> Option<usize> {
    let n = count(p, v, what)?;
    if n > max {
        p.at(v.span(), format!("{what} must be at most {max}, not {n}"));
        return None;
    }
    Some(n)
}

fn seed(p: &mut Problems<'_>, d: &RawDesign) -> u64 {
    match &d.seed {
        Some(s) if *s.get_ref() < 0 => {
            p.at(s.span(), "seed must not be negative");
            0
        }
        Some(s) => *s.get_ref() as u64,
        None => 0,
    }
}

/// Whether the objective is minimised or maximised.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// Smaller is better.
    Minimize,
    /// Larger is better.
    Maximize,
}

impl Direction {
    /// The spec's name of the direction: `minimize` or `maximize`.
    pub fn name(self) -> &'static str {
        match self {
            Direction::Minimize => "minimize",
            Direction::Maximize => "maximize",
        }
    }
}

/// A bound on a metric that an optimum must respect.
#[derive(Debug, Clone, PartialEq)]
pub struct Constraint {
    /// The metric's column name.
    pub metric: String,
    /// Smallest allowed value.
    pub min: Option<f64>,
    /// Largest allowed value.
    pub max: Option<f64>,
    /// Line of the constraint in the spec.
    pub line: usize,
}

/// The `[optimize]` table: differential evolution over the parameters' `[min, max]`, the
/// design as its first generation.
#[derive(Debug, Clone, PartialEq)]
pub struct OptimizeSpec {
    /// The metric column to optimise.
    pub objective: String,
    /// Line of `objective`.
    pub objective_line: usize,
    /// Minimise or maximise.
    pub direction: Direction,
    /// Generations after the first (the design).
    pub generations: usize,
    /// Byte range of the `generations` value in the spec's text: the one part of the text the
    /// fingerprint leaves out ([`SweepSpec::fingerprint_text`]), so that a finished
    /// optimisation can be continued with more generations.
    pub generations_span: std::ops::Range<usize>,
    /// Seed of the mutation and crossover draws.
    pub seed: u64,
    /// The differential weight `F` (scale of a mutation), in (0, 2].
    pub differential_weight: f64,
    /// The crossover probability `CR`, in [0, 1].
    pub crossover: f64,
    /// Bounds on metrics.
    pub constraints: Vec<Constraint>,
    /// Line of the `[optimize]` table.
    pub line: usize,
}

/// The most generations of an optimisation (a typo guard: each generation is a whole batch of
/// runs).
pub const MAX_GENERATIONS: usize = 10_000;

fn optimize_spec(
    p: &mut Problems<'_>,
    raw: &Spanned<RawOptimize>,
    parameters: &[Parameter],
) -> OptimizeSpec {
    let o = raw.get_ref();
    let named = |n: &str| {
        [Direction::Minimize, Direction::Maximize]
            .into_iter()
            .find(|d| d.name() == n)
    };
    let direction = match o.direction.as_ref().map(|d| d.get_ref().as_str()) {
        None => Direction::Minimize,
        Some(n) if named(n).is_some() => named(n).unwrap_or(Direction::Minimize),
        Some(other) => {
            if let Some(d) = &o.direction {
                p.at(
                    d.span(),
                    format!("unknown direction '{other}' (minimize, maximize)"),
                );
            }
            Direction::Minimize
        }
    };
    let generations = match count(p, &o.generations, "generations") {
        Some(n) if n > MAX_GENERATIONS => {
            p.at(
                o.generations.span(),
                format!("generations must be at most {MAX_GENERATIONS}, not {n}"),
            );
            n
        }
        Some(n) => n,
        None => 1,
    };
    let seed = match &o.seed {
        Some(s) if *s.get_ref() < 0 => {
            p.at(s.span(), "seed must not be negative");
            0
        }
        Some(s) => *s.get_ref() as u64,
        None => 0,
    };
    let mut in_range = |v: &Option<Spanned<f64>>, what: &str, lo: f64, hi: f64, lo_open: bool| {
        let Some(v) = v else { return None };
        let x = *v.get_ref();
        let above = if lo_open { x > lo } else { x >= lo };
        if !(x.is_finite() && above && x <= hi) {
            let open = if lo_open { "(" } else { "[" };
            p.at(
                v.span(),
                format!("{what} must be in {open}{lo}, {hi}], not {x}"),
            );
        }
        Some(x)
    };
    let differential_weight = in_range(
        &o.differential_weight,
        "differential_weight",
        0.0,
        2.0,
        true,
    )
    .unwrap_or(0.7);
    let crossover = in_range(&o.crossover, "crossover", 0.0, 1.0, false).unwrap_or(0.9);
    let mut constraints = Vec::new();
    for c in &o.constraints {
        let r = c.get_ref();
        let metric = r.metric.get_ref().trim().to_string();
        let min = r.min.as_ref().map(|v| *v.get_ref());
        let max = r.max.as_ref().map(|v| *v.get_ref());
        for v in [&r.min, &r.max].into_iter().flatten() {
            if v.get_ref().is_nan() {
                p.at(v.span(), format!("constraint on '{metric}': bound is NaN"));
            }
        }
        match (min, max) {
            (None, None) => p.at(
                c.span(),
                format!("constraint on '{metric}' needs min, max or both"),
            ),
            (Some(lo), Some(hi)) if lo > hi => p.at(
                c.span(),
                format!("constraint on '{metric}': min {lo} is greater than max {hi}"),
            ),
            _ => {}
        }
        constraints.push(Constraint {
            metric,
            min,
            max,
            line: line_of(p.text, c.span().start),
        });
    }
    for q in parameters {
        if q.min.is_none() || q.max.is_none() {
            p.at(
                raw.span(),
                format!(
                    "the optimisation needs min and max for every parameter; '{}' (line {}) \
                     has not both",
                    q.name, q.line
                ),
            );
        }
    }
    OptimizeSpec {
        objective: o.objective.get_ref().trim().to_string(),
        objective_line: line_of(p.text, o.objective.span().start),
        direction,
        generations,
        generations_span: o.generations.span(),
        seed,
        differential_weight,
        crossover,
        constraints,
        line: line_of(p.text, raw.span().start),
    }
}

/// The metric columns of `signals[k]`, one per statistic: `<stat>(<signal>)`, and when the
/// same signal has entries of other windows, `<stat>(<signal>)[<from>:<to>]` (a bound left
/// out is empty: `[:2.5]`, `[2.5:]`, `[:]` for the whole run), so that two windows of a signal
/// are two columns of their own.
pub fn signal_columns(signals: &[SignalMetric], k: usize) -> Vec<String> {
    let s = &signals[k];
    let windowed = signals
        .iter()
        .any(|o| o.signal == s.signal && (o.from, o.to) != (s.from, s.to));
    let bound = |b: Option<f64>| b.map_or(String::new(), |x| x.to_string());
    s.stats
        .iter()
        .map(|st| {
            if windowed {
                format!(
                    "{}({})[{}:{}]",
                    st.name(),
                    s.signal,
                    bound(s.from),
                    bound(s.to)
                )
            } else {
                format!("{}({})", st.name(), s.signal)
            }
        })
        .collect()
}

impl SweepSpec {
    /// The text the sweep's fingerprint covers: the spec's text, with an optimisation's
    /// `generations` value replaced by `*`. The first `g` generations of an optimisation do not
    /// depend on how many follow them (a generation's draws come from the seed and its own
    /// number), so a finished optimisation continued with more generations is the same sweep;
    /// any other change to the text makes another one.
    pub fn fingerprint_text(&self) -> std::borrow::Cow<'_, str> {
        match &self.optimize {
            Some(o) => {
                let r = &o.generations_span;
                format!("{}*{}", &self.text[..r.start], &self.text[r.end..]).into()
            }
            None => self.text.as_str().into(),
        }
    }

    /// Reads and parses a spec file (paths in it are relative to its directory). The result is
    /// not yet checked against the system's FMUs: see [`Prepared::new`](super::Prepared::new).
    pub fn from_file(path: &Path) -> Result<SweepSpec, SweepError> {
        let text = std::fs::read_to_string(path).map_err(|source| SweepError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
        SweepSpec::parse(&text, path, &base)
    }

    /// Parses spec text; `file` names it in messages, `base` resolves relative paths.
    pub fn parse(text: &str, file: &Path, base: &Path) -> Result<SweepSpec, SweepError> {
        let raw: RawSpec = toml::from_str(text).map_err(|e| {
            let line = e.span().map(|s| line_of(text, s.start)).unwrap_or(0);
            SweepError::Invalid(vec![SpecProblem {
                file: file.to_path_buf(),
                line,
                message: e.message().trim().to_string(),
            }])
        })?;
        let mut p = Problems {
            file,
            text,
            list: Vec::new(),
        };
        let resolve = |s: &str| {
            let path = PathBuf::from(s);
            if path.is_absolute() {
                path
            } else {
                base.join(path)
            }
        };
        let cycles = match &raw.cycles {
            // At most MAX_CYCLES: the count fits the scenario's u32.
            Some(c) => count_at_most(&mut p, c, "cycles", MAX_CYCLES).map_or(1, |n| n as u32),
            None => 2,
        };
        let name = raw.system.get_ref().trim();
        let system = match crate::study::Actuator::ALL
            .into_iter()
            .find(|a| a.name().eq_ignore_ascii_case(name))
        {
            Some(actuator) => {
                let fmu_dir = raw
                    .fmus
                    .as_ref()
                    .map(|f| resolve(f.get_ref()))
                    .unwrap_or_else(|| resolve("out/fmus"));
                SystemSource::Scenario {
                    actuator,
                    fmu_dir,
                    cycles,
                }
            }
            None => {
                let lower = name.to_ascii_lowercase();
                if !(lower.ends_with(".ssp") || lower.ends_with(".ssd")) {
                    p.at(
                        raw.system.span(),
                        format!(
                            "system '{name}' is neither a scenario (DA, SEA, CSEA) nor an .ssp/.ssd file"
                        ),
                    );
                }
                if let Some(f) = &raw.fmus {
                    p.at(f.span(), "fmus is for a scenario system (DA, SEA, CSEA)");
                }
                SystemSource::File(resolve(name))
            }
        };
        let positive = |p: &mut Problems<'_>, v: &Option<Spanned<f64>>, what: &str| match v {
            Some(s) if !(s.get_ref().is_finite() && *s.get_ref() > 0.0) => {
                p.at(
                    s.span(),
                    format!("{what} must be positive and finite, not {}", s.get_ref()),
                );
                None
            }
            Some(s) => Some(*s.get_ref()),
            None => None,
        };
        let stop_time = positive(&mut p, &raw.stop_time, "stop_time");
        let step = positive(&mut p, &raw.step, "step");
        // The runs' stop time where the spec tells it: its own, or a scenario's cycles of the
        // bench's gait (a system file's experiment is only known once it is loaded).
        let known_stop = stop_time.or(match &system {
            SystemSource::Scenario { cycles, .. } => {
                Some(crate::study::StudyScenario::BenchFull.gait().period * f64::from(*cycles))
            }
            SystemSource::File(_) => None,
        });

        let d = raw.design.get_ref();
        let points = |p: &mut Problems<'_>| match &d.points {
            Some(n) => count_at_most(p, n, "points", super::design::MAX_POINTS).unwrap_or(1),
            None => {
                p.at(
                    raw.design.span(),
                    format!("design '{}' needs points", d.kind.get_ref()),
                );
                1
            }
        };
        let design = match d.kind.get_ref().as_str() {
            "grid" => DesignKind::Grid,
            "latin-hypercube" => DesignKind::LatinHypercube {
                points: points(&mut p),
                seed: seed(&mut p, d),
            },
            "sobol" => {
                let n = points(&mut p);
                // The Sobol scramble takes a 32-bit seed: a larger one was folded into 32 bits,
                // so seeds 0 and 2^32 + 1 gave the same points.
                if let Some(s) = &d.seed
                    && *s.get_ref() > i64::from(u32::MAX)
                {
                    p.at(
                        s.span(),
                        format!(
                            "the Sobol design's seed is at most {} (its scramble takes 32 bits), \
                             not {}",
                            u32::MAX,
                            s.get_ref()
                        ),
                    );
                }
                if n > SOBOL_MAX_POINTS
                    && let Some(at) = &d.points
                {
                    p.at(
                        at.span(),
                        format!(
                            "the Sobol design has at most {SOBOL_MAX_POINTS} points (2^16, the \
                             sequence's length in sobol_burley), not {n}; use latin-hypercube \
                             or random for more"
                        ),
                    );
                }
                DesignKind::Sobol {
                    points: n,
                    seed: seed(&mut p, d),
                }
            }
            "random" => DesignKind::Random {
                points: points(&mut p),
                seed: seed(&mut p, d),
            },
            "csv" => match &d.file {
                Some(f) => DesignKind::Csv(resolve(f.get_ref())),
                None => {
                    p.at(raw.design.span(), "design 'csv' needs file");
                    DesignKind::Csv(PathBuf::new())
                }
            },
            other => {
                p.at(
                    d.kind.span(),
                    format!(
                        "unknown design kind '{other}' (grid, latin-hypercube, sobol, random, csv)"
                    ),
                );
                DesignKind::Grid
            }
        };
        let random_kind = matches!(
            design,
            DesignKind::LatinHypercube { .. }
                | DesignKind::Sobol { .. }
                | DesignKind::Random { .. }
        );
        if !random_kind && let Some(s) = &d.seed {
            p.at(
                s.span(),
                "seed is for latin-hypercube, sobol and random designs",
            );
        }
        if !matches!(design, DesignKind::Csv(_))
            && let Some(f) = &d.file
        {
            p.at(f.span(), "file is for the csv design");
        }
        if matches!(design, DesignKind::Grid | DesignKind::Csv(_))
            && let Some(n) = &d.points
        {
            p.at(
                n.span(),
                "points is for latin-hypercube, sobol and random designs",
            );
        }

        if raw.parameters.is_empty() {
            p.at(raw.design.span(), "empty design: no [[parameters]] to vary");
        }
        let mut parameters: Vec<Parameter> = Vec::new();
        for sp in &raw.parameters {
            let r = sp.get_ref();
            let line = line_of(text, sp.span().start);
            let name = r.name.get_ref().trim().to_string();
            if !name.contains('.') {
                p.at(
                    r.name.span(),
                    format!("parameter '{name}': expected component.variable"),
                );
            }
            if parameters.iter().any(|q| q.name == name) {
                p.at(r.name.span(), format!("parameter '{name}' is given twice"));
            }
            let min = r.min.as_ref().map(|v| *v.get_ref());
            let max = r.max.as_ref().map(|v| *v.get_ref());
            for v in [&r.min, &r.max].into_iter().flatten() {
                if !v.get_ref().is_finite() {
                    p.at(
                        v.span(),
                        format!("parameter '{name}': bound must be finite"),
                    );
                }
            }
            if let (Some(lo), Some(hi)) = (min, max)
                && lo > hi
            {
                p.at(
                    sp.span(),
                    format!("parameter '{name}': min {lo} is greater than max {hi}"),
                );
            }
            let levels = match &r.levels {
                // More levels than a design's points: refused here, before the grid's axes
                // (one value per level) are made.
                Some(l) => count_at_most(
                    &mut p,
                    l,
                    &format!("parameter '{name}': levels"),
                    super::design::MAX_POINTS,
                ),
                None => None,
            };
            let values = r.values.as_ref().map(|v| v.get_ref().clone());
            if let Some(v) = &r.values {
                if v.get_ref().is_empty() {
                    p.at(
                        v.span(),
                        format!("empty design: parameter '{name}' has no values"),
                    );
                }
                for x in v.get_ref() {
                    if !x.is_finite() {
                        p.at(
                            v.span(),
                            format!("parameter '{name}': value {x} is not a finite number"),
                        );
                        continue;
                    }
                    let out = min.is_some_and(|lo| *x < lo) || max.is_some_and(|hi| *x > hi);
                    if out {
                        p.at(
                            v.span(),
                            format!(
                                "parameter '{name}': value {x} is outside [{}, {}]",
                                min.map_or("-inf".into(), |x| x.to_string()),
                                max.map_or("inf".into(), |x| x.to_string())
                            ),
                        );
                    }
                }
            }
            match design {
                DesignKind::Grid => match (&r.levels, &r.values) {
                    (Some(_), Some(v)) => p.at(
                        v.span(),
                        format!("parameter '{name}': give levels or values, not both"),
                    ),
                    (None, None) => p.at(
                        sp.span(),
                        format!(
                            "parameter '{name}': the grid needs levels (with min and max) or values"
                        ),
                    ),
                    (Some(l), None) if min.is_none() || max.is_none() => p.at(
                        l.span(),
                        format!("parameter '{name}': levels need min and max"),
                    ),
                    _ => {}
                },
                DesignKind::Csv(_) => {
                    if let Some(l) = &r.levels {
                        p.at(
                            l.span(),
                            format!("parameter '{name}': levels is for the grid design"),
                        );
                    }
                    if let Some(v) = &r.values {
                        p.at(
                            v.span(),
                            format!("parameter '{name}': values is for the grid design"),
                        );
                    }
                }
                _ => {
                    if min.is_none() || max.is_none() {
                        p.at(
                            sp.span(),
                            format!("parameter '{name}': this design needs min and max"),
                        );
                    }
                    if let Some(l) = &r.levels {
                        p.at(
                            l.span(),
                            format!("parameter '{name}': levels is for the grid design"),
                        );
                    }
                    if let Some(v) = &r.values {
                        p.at(
                            v.span(),
                            format!("parameter '{name}': values is for the grid design"),
                        );
                    }
                }
            }
            parameters.push(Parameter {
                name,
                min,
                max,
                levels,
                values,
                ty: ParameterType::Real,
                declared_min: None,
                declared_max: None,
                unit: String::new(),
                line,
            });
        }

        let metrics = raw.metrics.as_ref();
        let study_metrics = metrics
            .and_then(|m| m.study.as_ref().map(|s| *s.get_ref()))
            .unwrap_or(matches!(system, SystemSource::Scenario { .. }));
        let period = positive(&mut p, &metrics.and_then(|m| m.period.clone()), "period");
        // A scenario that sweeps the gait's period runs each point for `cycles` of its own
        // period (`Prepared::run_values`): the runs' longest stop time is that of the longest
        // period, where the spec tells it (a csv design's values are only read later).
        let swept = parameters
            .iter()
            .find(|q| q.name == crate::study::GAIT_PERIOD);
        let longest = swept.and_then(|q| {
            q.values
                .as_ref()
                .map(|v| v.iter().copied().fold(f64::NEG_INFINITY, f64::max))
                .or(q.max)
        });
        let scenario_cycles = match &system {
            SystemSource::Scenario { cycles, .. } => Some(*cycles),
            SystemSource::File(_) => None,
        };
        let known_stop = match (stop_time, scenario_cycles, swept) {
            (None, Some(cycles), Some(_)) => longest.map(|t| {
                crate::study::gait_stop_time(
                    t,
                    cycles,
                    step.unwrap_or(crate::study::GAIT_SCENARIO_STEP),
                )
            }),
            _ => known_stop,
        };
        // The study's metrics are per gait cycle after the first, the start-up: a run shorter
        // than two cycles has none to analyse (its rows would fail).
        let gait_period = longest.or(period).or(match &system {
            SystemSource::Scenario { .. } => {
                Some(crate::study::StudyScenario::BenchFull.gait().period)
            }
            SystemSource::File(_) => None,
        });
        if study_metrics
            && stop_time.is_none()
            && let (Some(cycles), Some(at)) = (scenario_cycles.filter(|c| *c < 2), &raw.cycles)
            // (0 is refused as a count.)
            && *at.get_ref() == i64::from(cycles)
        {
            p.at(
                at.span(),
                format!(
                    "cycles = {cycles}: the study's metrics need at least 2 gait cycles per run \
                     (the first, the start-up, is not analysed); set study = false or run longer"
                ),
            );
        } else if study_metrics
            && let (Some(stop), Some(cycle)) = (known_stop, gait_period)
            && stop < 2.0 * cycle
        {
            let span = raw
                .stop_time
                .as_ref()
                .map(|s| s.span())
                .or_else(|| metrics.and_then(|m| m.period.as_ref()).map(|s| s.span()));
            if let Some(span) = span {
                p.at(
                    span,
                    format!(
                        "the study's metrics need a gait cycle after the start-up one: the runs \
                         end at {stop} s, before two periods ({cycle} s each); set study = false \
                         or run longer"
                    ),
                );
            }
        }
        let mut signals = Vec::new();
        let mut stats_lines = Vec::new();
        for s in metrics.map(|m| m.signals.as_slice()).unwrap_or_default() {
            let r = s.get_ref();
            let mut stats = Vec::new();
            for name in r.stats.get_ref() {
                match name.as_str() {
                    "min" => stats.push(Stat::Min),
                    "max" => stats.push(Stat::Max),
                    "mean" => stats.push(Stat::Mean),
                    "rms" => stats.push(Stat::Rms),
                    other => p.at(
                        r.stats.span(),
                        format!("unknown statistic '{other}' (min, max, mean, rms)"),
                    ),
                }
            }
            if r.stats.get_ref().is_empty() {
                p.at(r.stats.span(), "stats is empty");
            }
            let from = r.from.as_ref().map(|v| *v.get_ref());
            let to = r.to.as_ref().map(|v| *v.get_ref());
            for v in [&r.from, &r.to].into_iter().flatten() {
                if !v.get_ref().is_finite() {
                    p.at(v.span(), "window bounds must be finite");
                }
            }
            if let (Some(r_from), Some(a), Some(stop)) = (&r.from, from, known_stop)
                && a > stop
            {
                p.at(
                    r_from.span(),
                    format!(
                        "window from {a} s starts after the run ends at {stop} s: it holds no row"
                    ),
                );
            }
            if let (Some(a), Some(b)) = (from, to)
                && a > b
            {
                p.at(
                    s.span(),
                    format!("window from {a} s is after its end {b} s"),
                );
            }
            stats_lines.push(line_of(text, r.stats.span().start));
            signals.push(SignalMetric {
                signal: r.signal.get_ref().trim().to_string(),
                stats,
                from,
                to,
                line: line_of(text, s.span().start),
            });
        }
        // Every metric column once: a statistic given twice for a signal and window (in one
        // `stats`, or in two entries of the same window) made columns of the same name, which
        // pyarrow cannot read and pandas keeps one of.
        let mut seen: Vec<(String, usize)> = Vec::new();
        for (k, s) in signals.iter().enumerate() {
            for name in signal_columns(&signals, k) {
                match seen.iter().find(|(n, _)| *n == name) {
                    Some((_, first)) => p.list.push(SpecProblem {
                        file: file.to_path_buf(),
                        line: stats_lines[k],
                        message: if *first == s.line {
                            format!("column '{name}' is given twice in these stats")
                        } else {
                            format!(
                                "column '{name}' is given twice: the signal, statistic and \
                                 window of line {first}"
                            )
                        },
                    }),
                    None => seen.push((name, s.line)),
                }
            }
        }
        // The runs' recorded values, where the spec tells their length and step (a system
        // file's experiment is checked once it is loaded, in `Prepared::new`): at most
        // MAX_RUN_VALUES, refused at the line that sets the length.
        let scenario = matches!(system, SystemSource::Scenario { .. });
        let length_span = raw
            .stop_time
            .as_ref()
            .map(|s| s.span())
            .or_else(|| raw.cycles.as_ref().filter(|_| scenario).map(|c| c.span()))
            .unwrap_or_else(|| raw.system.span());
        let length_line = line_of(text, length_span.start);
        let step_line = raw.step.as_ref().map(|s| line_of(text, s.span().start));
        let mut columns: Vec<String> = if study_metrics {
            crate::study::Columns::default().names()
        } else {
            Vec::new()
        };
        for s in &signals {
            if !columns.contains(&s.signal) {
                columns.push(s.signal.clone());
            }
        }
        let own_step = scenario.then_some(crate::study::GAIT_SCENARIO_STEP);
        if let (Some(stop), Some(h)) = (known_stop, step.or(own_step)) {
            let own_rows = raw
                .step
                .as_ref()
                .and(own_step)
                .map(|own| run_rows(stop, own, 1));
            if let Err((blame, message)) =
                check_run_values(run_rows(stop, h, 1), own_rows, columns.len())
            {
                let span = match (blame, &raw.step) {
                    (TooLong::Step, Some(s)) => s.span(),
                    _ => length_span,
                };
                p.at(span, message);
            }
        }
        // The design's values (points x parameters) within MAX_DESIGN_VALUES, refused at
        // `points` (the design is made whole before the first run).
        let max = super::design::max_points(parameters.len());
        if let (
            Some(n),
            DesignKind::LatinHypercube { points, .. }
            | DesignKind::Sobol { points, .. }
            | DesignKind::Random { points, .. },
        ) = (&d.points, &design)
            && *points > max
        {
            p.at(
                n.span(),
                format!(
                    "{points} points of {} parameters are {} values, more than {} (points x \
                     parameters): at most {max} points of {} parameters",
                    parameters.len(),
                    *points as u128 * parameters.len() as u128,
                    super::design::MAX_DESIGN_VALUES,
                    parameters.len()
                ),
            );
        }
        // A grid's points (the product of its axes) likewise, refused at `kind` (no line gives
        // the count): only when every axis is known, a parameter without one is refused above.
        let axes: Option<Vec<usize>> = parameters
            .iter()
            .map(|q| q.values.as_ref().map(Vec::len).or(q.levels))
            .collect();
        if matches!(design, DesignKind::Grid)
            && let Some(axes) = axes
        {
            let points = axes
                .iter()
                .try_fold(1u128, |n, &a| n.checked_mul(a as u128));
            if points.is_none_or(|n| n > max as u128) {
                let dims = parameters.len();
                let count = match points {
                    Some(n) => format!(
                        "{n} points of {dims} parameters, {} values",
                        n.saturating_mul(dims as u128)
                    ),
                    None => format!("more than 2^128 points of {dims} parameters"),
                };
                p.at(
                    d.kind.span(),
                    format!(
                        "the grid has {count}: more than {max} points (at most {} points and \
                         {} values, points x parameters)",
                        super::design::MAX_POINTS,
                        super::design::MAX_DESIGN_VALUES,
                    ),
                );
            }
        }
        let optimize = raw
            .optimize
            .as_ref()
            .map(|o| optimize_spec(&mut p, o, &parameters));
        if !study_metrics && signals.is_empty() {
            p.at(
                0..0,
                "no metrics: set [metrics] study = true or add [[metrics.signals]]",
            );
        }
        if !p.list.is_empty() {
            return Err(SweepError::Invalid(p.list));
        }
        Ok(SweepSpec {
            file: file.to_path_buf(),
            system,
            stop_time,
            step,
            design,
            parameters,
            study_metrics,
            period,
            signals,
            optimize,
            length_line,
            step_line,
            system_line: line_of(text, raw.system.span().start),
            fmus_line: raw.fmus.as_ref().map(|f| line_of(text, f.span().start)),
            study_line: metrics
                .and_then(|m| m.study.as_ref())
                .map(|s| line_of(text, s.span().start)),
            text: text.to_string(),
        })
    }

    /// A problem at `line` of the spec.
    pub fn problem(&self, line: usize, message: impl Into<String>) -> SpecProblem {
        SpecProblem {
            file: self.file.clone(),
            line,
            message: message.into(),
        }
    }
}

#[cfg(test)]
#[path = "spec_tests.rs"]
mod tests;
