//! The co-simulation master: a [`System`] of FMU instances and connections, run on a fixed
//! integer time grid (see [`crate::time`]).
//!
//! # Algorithms
//!
//! - **Gauss-Seidel** ([`Algorithm::GaussSeidel`], the default): in each macro step the
//!   components are stepped one after the other in *dependency order*; right before its step a
//!   component's inputs are set from the current outputs of its sources, so a component
//!   downstream of another sees the value its source computed for the end of this step. The
//!   order is a topological sort of the connection graph (ties: declaration order). Cycles are
//!   broken by ignoring, for the ordering, connections whose source output has no direct
//!   feedthrough (its `ModelStructure` dependencies name no input; an output missing from
//!   `ModelStructure/Outputs`, or without a `dependencies` attribute, counts as feedthrough):
//!   the component reading such an output gets its value from the previous communication
//!   point. A cycle that remains runs through direct-feedthrough outputs only: an algebraic
//!   loop, refused with [`MasterError::AlgebraicLoop`] (the master does not iterate).
//! - **Jacobi** ([`Algorithm::Jacobi`]): all inputs are set from the outputs at the start of
//!   the macro step, then every component steps; each connection therefore delays by one step.
//!   Cycles of any kind are allowed (initialization uses the Gauss-Seidel order when one exists,
//!   declaration order otherwise).
//!
//! # Multi-rate
//!
//! Each component has a step multiple `m` (default 1) of the base step `h`. It steps at the
//! macro steps `n` with `n % m == 0`, from `t(n)` with step size `m * h`; between its
//! communication points its outputs hold their last value and its inputs are not set. The run
//! length must be a multiple of every `m`.
//!
//! # When rows are recorded (the recording rule)
//!
//! - Row 0, at the start time, is recorded after `fmi2ExitInitializationMode` of every
//!   component (initial values were propagated along the connections in initialization mode,
//!   in dependency order).
//! - After macro step `n` (`t(n) -> t(n+1)`), when every component due at `n` has completed its
//!   `fmi2DoStep` and its values have been read with `fmi2Get*`, the row for `t(n+1)` is
//!   recorded, *before* any input is set for the next step. So each recorded input shows the
//!   value the component used during the step that ended at that time, and each output the
//!   value the component computed for that time.
//! - Every value comes from one `fmi2Get*` call per component and type after its step
//!   (components not due keep their previous values). Only every `record_every`-th row is kept
//!   (counting from row 0); row 0 is always kept.
//!
//! With a source `a` whose output is `x(n)` and a direct-feedthrough `b` with `y = k * u` fed by
//! `a.x`, Gauss-Seidel records `b.u(n) = x(n)`, `b.y(n) = k * x(n)`; Jacobi records
//! `b.u(n) = x(n-1)`, `b.y(n) = k * x(n-1)` for `n >= 1` (and the initial values at row 0).
//!
//! # Ends of a run
//!
//! - [`Outcome::Completed`]: every step done; every instance is terminated.
//! - [`Outcome::Terminated`]: a component's `fmi2DoStep` returned `fmi2Discard` and its
//!   `fmi2GetBooleanStatus(fmi2Terminated)` is true: the run ends cleanly; the results keep
//!   every row up to the last complete communication point, and the outcome reports the
//!   component's `fmi2LastSuccessfulTime`.
//! - [`Outcome::Failed`]: any other failure (an error status, a discard without termination,
//!   which a fixed-step master cannot retry); the error carries the FMU's log messages and the
//!   results keep every row recorded so far.
//!
//! - [`Outcome::Failed`] with [`MasterError::Stopped`]: a stop request (a signal, the
//!   [`RunConfig::timeout`], a [`RunControl`]) was seen at a communication point; the rows up
//!   to that point are recorded and flushed.
//! - [`Outcome::Failed`] with [`MasterError::NonFinite`]: an output the master read (recorded
//!   or connected) was NaN or infinite, unless [`RunConfig::allow_nonfinite`].
//!
//! When a component ends the run (fmi2Discard with fmi2Terminated) at an
//! `fmi2LastSuccessfulTime` after the last recorded row, its outputs are read there and
//! recorded as the last row, at that time, as fmpy does (the other components' columns keep
//! their last values). A `fmi2LastSuccessfulTime` at the last row's time adds no row.
//!
//! # Where rows go
//!
//! [`System::run`] keeps the rows in memory ([`Results`]); [`System::run_into`] hands them to
//! any [`ResultSink`] (a streamed CSV file, for example), flushing it every second of wall
//! time when the sink asks for it, and once at the end of every run.
//!
//! # Parallel stepping
//!
//! Off by default. With [`RunConfig::parallel`], the components step in groups that the
//! sequential order allows to run concurrently: walking the Gauss-Seidel order, a component
//! joins the current group unless a member of the group feeds it through any connection
//! (direct feedthrough or not: the sequential master passes every fresh output along), so each
//! component gathers exactly the values it gets sequentially and the results are
//! bit-identical to the sequential run's. Jacobi runs all components as one group. Groups of
//! more than one due component step on scoped threads, spawned for every step. That costs
//! tens of microseconds per step (measured: the study's SEA loop ~116 us per step with
//! `--parallel`, 60x slower than sequential, on a 2-core VM), so it pays only for FMUs whose
//! steps take milliseconds. It requires FMUs whose instances share no
//! mutable state.

use std::fmt;
use std::sync::Arc;

use model_description::{Causality, ModelDescription, ScalarVariable, VariableKind};

pub use crate::control::{RunControl, StopReason};
use crate::instance::{FmuError, InstanceOptions};
use crate::load::Fmu;
use crate::results::{ColumnKind, ResultSink, Results, ResultsError};
use crate::time::{Grid, GridError};
use model_description::num::num;

/// The base type of a variable, which decides the `fmi2Get*`/`fmi2Set*` family.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum VarType {
    /// `Real`.
    Real,
    /// `Integer` and `Enumeration`.
    Integer,
    /// `Boolean`.
    Boolean,
    /// `String`.
    String,
}

impl VarType {
    /// The type's name with its article, for messages: "a Real", "an Integer".
    pub fn with_article(self) -> &'static str {
        match self {
            VarType::Real => "a Real",
            VarType::Integer => "an Integer",
            VarType::Boolean => "a Boolean",
            VarType::String => "a String",
        }
    }

    /// The type of a model-description variable.
    pub fn of(v: &ScalarVariable) -> VarType {
        match v.kind {
            VariableKind::Real { .. } => VarType::Real,
            VariableKind::Integer { .. } | VariableKind::Enumeration { .. } => VarType::Integer,
            VariableKind::Boolean { .. } => VarType::Boolean,
            VariableKind::String { .. } => VarType::String,
        }
    }
}

/// A causality as the model description spells it, with its article, for messages: "an
/// input", "a parameter".
fn causality_with_article(c: Causality) -> &'static str {
    match c {
        Causality::Parameter => "a parameter",
        Causality::CalculatedParameter => "a calculatedParameter",
        Causality::Input => "an input",
        Causality::Output => "an output",
        Causality::Local => "a local",
        Causality::Independent => "an independent",
    }
}

/// A value to set (parameters, start values).
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// A `Real`.
    Real(f64),
    /// An `Integer` or `Enumeration`.
    Integer(i32),
    /// A `Boolean`.
    Boolean(bool),
    /// A `String`.
    String(String),
}

impl Value {
    /// Parses text as a value of type `ty` (`true`/`false`/`1`/`0` for booleans).
    pub fn parse(ty: VarType, text: &str) -> Option<Value> {
        let t = text.trim();
        match ty {
            VarType::Real => t.parse().ok().map(Value::Real),
            VarType::Integer => t.parse().ok().map(Value::Integer),
            VarType::Boolean => match t {
                "true" | "1" => Some(Value::Boolean(true)),
                "false" | "0" => Some(Value::Boolean(false)),
                _ => None,
            },
            VarType::String => Some(Value::String(text.to_string())),
        }
    }

    /// The value as text that [`Value::parse`] reads back to it (`--param NAME=VALUE` form;
    /// Reals exact, shortest round trip).
    pub fn to_text(&self) -> String {
        match self {
            Value::Real(v) => format!("{v:?}"),
            Value::Integer(v) => v.to_string(),
            Value::Boolean(v) => v.to_string(),
            Value::String(v) => v.clone(),
        }
    }

    fn ty(&self) -> VarType {
        match self {
            Value::Real(_) => VarType::Real,
            Value::Integer(_) => VarType::Integer,
            Value::Boolean(_) => VarType::Boolean,
            Value::String(_) => VarType::String,
        }
    }
}

/// The master's algorithm.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Algorithm {
    /// Sequential in dependency order; inputs from the freshest outputs.
    #[default]
    GaussSeidel,
    /// All inputs from the outputs at the start of the step.
    Jacobi,
}

/// Reports progress: `(macro steps done, total)`.
pub type ProgressFn = Arc<dyn Fn(u64, u64) + Send + Sync>;

/// How to run a [`System`].
#[derive(Clone)]
pub struct RunConfig {
    /// Start time in seconds.
    pub start_time: f64,
    /// Stop time in seconds (on the grid).
    pub stop_time: f64,
    /// Base step in seconds (a whole number of nanoseconds).
    pub step_size: f64,
    /// The algorithm.
    pub algorithm: Algorithm,
    /// Step independent components on threads (see the module documentation).
    pub parallel: bool,
    /// Keep every `record_every`-th row (1: every macro step).
    pub record_every: u64,
    /// The `tolerance` passed to `fmi2SetupExperiment`, if any.
    pub tolerance: Option<f64>,
    /// Called about 200 times during a run.
    pub progress: Option<ProgressFn>,
    /// Wall-time limit of the whole run (instantiation included): past it, the run stops at
    /// the next communication point with [`MasterError::Stopped`] ([`StopReason::Timeout`]).
    /// A call into an FMU that never returns is not interrupted (that needs a process of its
    /// own per FMU).
    pub timeout: Option<std::time::Duration>,
    /// Stop requests from outside (signals, a watchdog), checked at every communication point.
    pub control: Option<RunControl>,
    /// Record NaN and infinite outputs instead of failing with [`MasterError::NonFinite`].
    pub allow_nonfinite: bool,
}

impl Default for RunConfig {
    fn default() -> Self {
        RunConfig {
            start_time: 0.0,
            stop_time: 1.0,
            step_size: 1e-3,
            algorithm: Algorithm::GaussSeidel,
            parallel: false,
            record_every: 1,
            tolerance: None,
            progress: None,
            timeout: None,
            control: None,
            allow_nonfinite: false,
        }
    }
}

impl RunConfig {
    /// This configuration with the times of a default experiment (an FMU's or an SSP's
    /// `DefaultExperiment`) or of a run's own settings (`kneebench run --stop-time`, a sweep
    /// spec's `stop_time`): each of `start_time`, `stop_time` and `step_size` that is given
    /// replaces this configuration's, the others are kept.
    pub fn with_times(
        mut self,
        start_time: Option<f64>,
        stop_time: Option<f64>,
        step_size: Option<f64>,
    ) -> RunConfig {
        if let Some(t) = start_time {
            self.start_time = t;
        }
        if let Some(t) = stop_time {
            self.stop_time = t;
        }
        if let Some(h) = step_size {
            self.step_size = h;
        }
        self
    }

    /// The configuration of a run of the FMU that `md` describes by itself, as `kneebench run
    /// FMU` and the Python package's `run` make it: its `DefaultExperiment`'s times
    /// ([`with_times`](Self::with_times)) and tolerance (passed to `fmi2SetupExperiment`),
    /// the defaults for what it leaves out.
    pub fn of_fmu(md: &ModelDescription) -> RunConfig {
        let config = RunConfig::default();
        match &md.default_experiment {
            Some(d) => RunConfig {
                tolerance: d.tolerance,
                ..config.with_times(d.start_time, d.stop_time, d.step_size)
            },
            None => config,
        }
    }
}

impl fmt::Debug for RunConfig {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("RunConfig")
            .field("start_time", &self.start_time)
            .field("stop_time", &self.stop_time)
            .field("step_size", &self.step_size)
            .field("algorithm", &self.algorithm)
            .field("parallel", &self.parallel)
            .field("record_every", &self.record_every)
            .field("tolerance", &self.tolerance)
            .field("timeout", &self.timeout)
            .field("allow_nonfinite", &self.allow_nonfinite)
            .finish()
    }
}

/// Errors of building or running a system.
#[derive(Debug, thiserror::Error)]
pub enum MasterError {
    /// Two components with the same name.
    #[error("a component named '{0}' already exists")]
    DuplicateComponent(String),
    /// A component name that is empty or contains '.'.
    #[error("invalid component name '{0}' (must be non-empty and contain no '.')")]
    BadComponentName(String),
    /// No such component.
    #[error("no component named '{0}'")]
    UnknownComponent(String),
    /// No such variable.
    #[error("component '{component}' has no variable '{variable}'")]
    UnknownVariable {
        /// The component.
        component: String,
        /// The variable.
        variable: String,
    },
    /// A reference that is not `component.variable`.
    #[error("'{0}' is not of the form component.variable")]
    BadReference(String),
    /// A connection endpoint with the wrong causality.
    #[error("cannot connect '{reference}': {problem}")]
    BadEndpoint {
        /// The reference.
        reference: String,
        /// What is wrong.
        problem: String,
    },
    /// Connected variables of different types.
    #[error("cannot connect '{from}' ({from_ty:?}) to '{to}' ({to_ty:?}): types differ")]
    TypeMismatch {
        /// Source.
        from: String,
        /// Its type.
        from_ty: VarType,
        /// Destination.
        to: String,
        /// Its type.
        to_ty: VarType,
    },
    /// An input fed twice.
    #[error("input '{0}' already has a source")]
    InputAlreadyConnected(String),
    /// A parameter value of the wrong type or unparsable.
    #[error("bad value for '{reference}': {problem}")]
    BadValue {
        /// The reference.
        reference: String,
        /// What is wrong.
        problem: String,
    },
    /// A step multiple that is zero or does not divide the run.
    #[error("component '{component}': step multiple {multiple} {problem}")]
    BadStepMultiple {
        /// The component.
        component: String,
        /// The multiple.
        multiple: u64,
        /// What is wrong.
        problem: &'static str,
    },
    /// The time grid is invalid.
    #[error(transparent)]
    Grid(#[from] GridError),
    /// An algebraic loop (Gauss-Seidel only).
    #[error(
        "algebraic loop: components {} form a cycle through direct-feedthrough outputs; the Gauss-Seidel master does not iterate (use Jacobi, or break the loop)",
        .0.join(", ")
    )]
    AlgebraicLoop(Vec<String>),
    /// The system has no component.
    #[error("the system has no component")]
    Empty,
    /// An FMU call failed.
    #[error("component '{component}' at t = {}: {source}", num(.time))]
    Fmu {
        /// The component.
        component: String,
        /// The communication point.
        time: f64,
        /// The FMU error.
        source: FmuError,
    },
    /// The run was stopped from outside at a communication point (its rows are recorded).
    #[error("run stopped at t = {}: {reason}", num(.time))]
    Stopped {
        /// Why.
        reason: StopReason,
        /// The communication point of the last recorded row.
        time: f64,
    },
    /// An output was NaN or infinite (see [`RunConfig::allow_nonfinite`]).
    #[error(
        "component '{component}': output '{variable}' is {value} at t = {} (use --allow-nonfinite to record it)",
        num(.time)
    )]
    NonFinite {
        /// The component.
        component: String,
        /// The output.
        variable: String,
        /// The value.
        value: f64,
        /// The time the value belongs to.
        time: f64,
    },
    /// The thread that keeps the time limit and the periodic flushes could not start.
    #[error("cannot start the run's timer thread: {0}")]
    Thread(std::io::Error),
    /// A thread to step components in parallel (`--parallel`) could not start.
    #[error("cannot start a thread to step components in parallel: {0}")]
    SteppingThread(std::io::Error),
    /// Writing the results failed.
    #[error("writing the results: {0}")]
    Sink(#[from] ResultsError),
    /// A component's step does not fit the master's integer time base.
    #[error(
        "component '{component}': step multiple {multiple} times the base step overflows the master's time base"
    )]
    StepOverflow {
        /// The component.
        component: String,
        /// The multiple.
        multiple: u64,
    },
    /// `fmi2DoStep` returned `fmi2Discard` without terminating: a fixed-step master cannot retry.
    #[error(
        "component '{component}' discarded the step at t = {} without terminating (a fixed-step master cannot retry){}",
        num(.time),
        messages.iter().map(|m| format!("; {}", m.message)).collect::<String>()
    )]
    StepDiscarded {
        /// The component.
        component: String,
        /// The communication point.
        time: f64,
        /// The FMU's recent log messages.
        messages: Vec<crate::LogMessage>,
    },
}

/// How a run ended.
#[derive(Debug)]
pub enum Outcome {
    /// Every step was done.
    Completed {
        /// The final time.
        stop_time: f64,
    },
    /// A component ended the run (`fmi2Discard` with `fmi2Terminated`).
    Terminated {
        /// The component.
        component: String,
        /// Its `fmi2LastSuccessfulTime` (or the start of the discarded step if it cannot tell).
        last_successful_time: f64,
        /// The time of the last recorded row.
        last_row_time: f64,
        /// What the component logged last (the reason it ended the run, when it says).
        messages: Vec<String>,
    },
    /// The run failed; the results keep the rows recorded before the failure.
    Failed(MasterError),
}

/// What [`System::run_into`] returns: how the run ended, beside the rows in the sink.
#[derive(Debug)]
pub struct RunSummary {
    /// How the run ended.
    pub outcome: Outcome,
    /// Rows handed to the sink.
    pub rows: u64,
    /// Number of `fmi2DoStep` calls per component, in declaration order.
    pub steps_per_component: Vec<u64>,
}

/// What [`System::run`] returns: the results (complete or up to the end of the run) and how
/// the run ended.
#[derive(Debug)]
pub struct RunOutput {
    /// The recorded rows.
    pub results: Results,
    /// How the run ended.
    pub outcome: Outcome,
    /// Number of `fmi2DoStep` calls per component, in declaration order.
    pub steps_per_component: Vec<u64>,
}

#[derive(Debug, Clone)]
struct VarRef {
    comp: usize,
    vr: u32,
    ty: VarType,
    name: String,
}

/// How close to `t` a sample counts as at `t`: sample times written as decimals (0.001*k) and
/// grid times computed from integer ticks may differ in the last bit.
fn tolerance(t: f64) -> f64 {
    1e-9 * t.abs().max(1.0)
}

/// The latest sample time that counts as at or before `t`.
fn reach(t: f64) -> f64 {
    t + tolerance(t)
}

/// A time series fed into an input (from a CSV file, for example).
#[derive(Debug, Clone, PartialEq)]
pub struct Signal {
    /// Sample times, non-decreasing.
    pub times: Vec<f64>,
    /// Values.
    pub values: Vec<f64>,
    /// Linear interpolation between samples (otherwise: the value of the last sample at or
    /// before the time). Beyond the ends the first/last value holds.
    pub interpolate: bool,
}

impl Signal {
    /// The value at time `t`. At a time that appears twice (a discontinuity) the later sample
    /// wins.
    pub fn at(&self, t: f64) -> f64 {
        if self.times.is_empty() {
            return 0.0;
        }
        // Index of the first sample with time > t.
        let i = self.times.partition_point(|&x| x <= reach(t));
        self.value_after(i, t)
    }

    /// [`Signal::at`] for a run that samples at non-decreasing times, its search starting at
    /// `cursor`, the index this signal's previous sample found (0 at first), which it updates:
    /// a step or two forward instead of a binary search over the whole series every step.
    /// Equals `at(t)` bit for bit whenever [`Signal::has_sorted_times`] (the index searched for,
    /// the first sample after `t`, is then unique; a time earlier than the cursor's falls back
    /// to the whole search).
    pub(crate) fn at_from(&self, t: f64, cursor: &mut usize) -> f64 {
        let times = &self.times[..];
        if times.is_empty() {
            return 0.0;
        }
        let limit = reach(t);
        let mut i = (*cursor).min(times.len());
        // A NaN time takes the whole search too, as in `at`.
        if i > 0 && (times[i - 1] > limit || limit.is_nan()) {
            i = times.partition_point(|&x| x <= limit);
        } else {
            // A few samples by hand (one per step when the series has the run's grid), the
            // rest of a long jump by bisection.
            let mut walked = 0;
            while i < times.len() && times[i] <= limit {
                i += 1;
                walked += 1;
                if walked == 4 {
                    i += times[i..].partition_point(|&x| x <= limit);
                    break;
                }
            }
        }
        *cursor = i;
        self.value_after(i, t)
    }

    /// Whether the sample times are non-decreasing and none is NaN: the condition under which
    /// [`Signal::at_from`] equals [`Signal::at`].
    pub(crate) fn has_sorted_times(&self) -> bool {
        self.times.is_sorted_by(|a, b| a <= b)
    }

    /// The value at `t`, `i` being the index of the first sample with time after `t` (within
    /// the tolerance of [`reach`]).
    fn value_after(&self, i: usize, t: f64) -> f64 {
        let n = self.times.len();
        if i == 0 {
            return self.values[0];
        }
        if i == n || !self.interpolate || (t - self.times[i - 1]).abs() <= tolerance(t) {
            return self.values[i - 1];
        }
        let (t0, t1) = (self.times[i - 1], self.times[i]);
        let (v0, v1) = (self.values[i - 1], self.values[i]);
        if t1 == t0 {
            return v1;
        }
        let x = v0 + (v1 - v0) * (t - t0) / (t1 - t0);
        if x.is_finite() {
            x
        } else {
            // Samples near the largest double: their difference or its product with the time
            // overflows, the weighted mean (between the two samples) does not.
            let w = (t - t0) / (t1 - t0);
            v0 * (1.0 - w) + v1 * w
        }
    }
}

#[derive(Clone)]
struct ComponentSpec {
    name: String,
    fmu: Fmu,
    step_multiple: u64,
    values: Vec<(VarRef, Value)>,
}

/// A system: named components (instances of loaded FMUs), connections, parameter values,
/// input signals and the variables to record. A clone shares the loaded FMUs (each run
/// instantiates its own instances) and copies the rest: a sweep runs each point on a clone of
/// the loaded system with the point's values set.
#[derive(Clone)]
pub struct System {
    components: Vec<ComponentSpec>,
    connections: Vec<(VarRef, VarRef)>,
    signals: Vec<(VarRef, Signal)>,
    record: Option<Vec<VarRef>>,
    instance_options: InstanceOptions,
    column_prefix: bool,
}

impl Default for System {
    fn default() -> Self {
        System::new()
    }
}

impl fmt::Debug for System {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("System")
            .field(
                "components",
                &self.components.iter().map(|c| &c.name).collect::<Vec<_>>(),
            )
            .field("connections", &self.connections.len())
            .finish()
    }
}

fn causality(v: &ScalarVariable) -> Causality {
    v.causality.unwrap_or(Causality::Local)
}

fn find_var<'a>(md: &'a ModelDescription, name: &str) -> Option<(usize, &'a ScalarVariable)> {
    md.model_variables
        .iter()
        .enumerate()
        .find(|(_, v)| v.name == name)
}

impl System {
    /// An empty system.
    pub fn new() -> System {
        System {
            components: Vec::new(),
            connections: Vec::new(),
            signals: Vec::new(),
            record: None,
            instance_options: InstanceOptions::default(),
            column_prefix: true,
        }
    }

    /// Options for every instance (log handler, debug logging).
    pub fn set_instance_options(&mut self, options: InstanceOptions) {
        self.instance_options = options;
    }

    /// Name result columns `variable` instead of `component.variable` (for single-FMU runs).
    pub fn set_column_prefix(&mut self, prefix: bool) {
        self.column_prefix = prefix;
    }

    /// Adds a component (an instance of `fmu` named `name`). Returns its index.
    pub fn add_component(&mut self, name: &str, fmu: Fmu) -> Result<usize, MasterError> {
        if name.is_empty() || name.contains('.') {
            return Err(MasterError::BadComponentName(name.to_string()));
        }
        if self.components.iter().any(|c| c.name == name) {
            return Err(MasterError::DuplicateComponent(name.to_string()));
        }
        self.components.push(ComponentSpec {
            name: name.to_string(),
            fmu,
            step_multiple: 1,
            values: Vec::new(),
        });
        Ok(self.components.len() - 1)
    }

    /// Names of the components, in declaration order.
    pub fn component_names(&self) -> Vec<&str> {
        self.components.iter().map(|c| c.name.as_str()).collect()
    }

    /// The components and their FMUs, in declaration order.
    pub fn components(&self) -> impl Iterator<Item = (&str, &Fmu)> {
        self.components.iter().map(|c| (c.name.as_str(), &c.fmu))
    }

    fn comp_index(&self, name: &str) -> Result<usize, MasterError> {
        self.components
            .iter()
            .position(|c| c.name == name)
            .ok_or_else(|| MasterError::UnknownComponent(name.to_string()))
    }

    fn resolve(&self, reference: &str) -> Result<(VarRef, Causality), MasterError> {
        let (c, v) = reference
            .split_once('.')
            .ok_or_else(|| MasterError::BadReference(reference.to_string()))?;
        self.resolve_in(c, v)
    }

    fn resolve_in(&self, component: &str, var: &str) -> Result<(VarRef, Causality), MasterError> {
        let comp = self.comp_index(component)?;
        let md = self.components[comp].fmu.model_description();
        let (_, v) = find_var(md, var).ok_or_else(|| MasterError::UnknownVariable {
            component: component.to_string(),
            variable: var.to_string(),
        })?;
        Ok((
            VarRef {
                comp,
                vr: v.value_reference,
                ty: VarType::of(v),
                name: format!("{component}.{var}"),
            },
            causality(v),
        ))
    }

    /// Sets the step multiple of a component (its step is `multiple` base steps).
    pub fn set_step_multiple(&mut self, component: &str, multiple: u64) -> Result<(), MasterError> {
        let i = self.comp_index(component)?;
        if multiple == 0 {
            return Err(MasterError::BadStepMultiple {
                component: component.to_string(),
                multiple,
                problem: "must be at least 1",
            });
        }
        self.components[i].step_multiple = multiple;
        Ok(())
    }

    /// Connects output `from` (`component.variable`) to input `to`. Both must have the same
    /// type, `String` is not allowed, and an input has at most one source.
    pub fn connect(&mut self, from: &str, to: &str) -> Result<(), MasterError> {
        let (src, src_c) = self.resolve(from)?;
        let (dst, dst_c) = self.resolve(to)?;
        if src_c != Causality::Output {
            return Err(MasterError::BadEndpoint {
                reference: from.to_string(),
                problem: format!(
                    "a connection starts at an output, not {} variable",
                    causality_with_article(src_c)
                ),
            });
        }
        if dst_c != Causality::Input {
            return Err(MasterError::BadEndpoint {
                reference: to.to_string(),
                problem: format!(
                    "a connection ends at an input, not {} variable",
                    causality_with_article(dst_c)
                ),
            });
        }
        if src.ty != dst.ty {
            return Err(MasterError::TypeMismatch {
                from: from.to_string(),
                from_ty: src.ty,
                to: to.to_string(),
                to_ty: dst.ty,
            });
        }
        if src.ty == VarType::String {
            return Err(MasterError::BadEndpoint {
                reference: from.to_string(),
                problem: "String connections are not supported".into(),
            });
        }
        if self.is_fed(&dst) {
            return Err(MasterError::InputAlreadyConnected(to.to_string()));
        }
        self.connections.push((src, dst));
        Ok(())
    }

    fn is_fed(&self, dst: &VarRef) -> bool {
        self.connections
            .iter()
            .map(|(_, d)| d)
            .chain(self.signals.iter().map(|(d, _)| d))
            .any(|d| d.comp == dst.comp && d.vr == dst.vr && d.ty == dst.ty)
    }

    /// Sets a variable before initialization (parameters, start values of inputs).
    ///
    /// A later value of a variable (or of an alias: the same value reference and type)
    /// replaces the earlier one: a run applies each variable's last value once, in the order
    /// of those last sets (the order in which they would otherwise have been applied last).
    pub fn set_value(&mut self, reference: &str, value: Value) -> Result<(), MasterError> {
        let (r, _) = self.resolve(reference)?;
        if r.ty != value.ty() {
            return Err(MasterError::BadValue {
                reference: reference.to_string(),
                problem: format!("the variable is {:?}, the value {:?}", r.ty, value.ty()),
            });
        }
        let values = &mut self.components[r.comp].values;
        values.retain(|(earlier, _)| earlier.vr != r.vr || earlier.ty != r.ty);
        values.push((r, value));
        Ok(())
    }

    /// Parses `text` as a value of the variable's type and sets it (see
    /// [`set_value`](Self::set_value)).
    ///
    /// A variable with named values also takes an item's name (`plant.backend=Udp`): an
    /// Enumeration, or an Integer whose items the model description names
    /// ([`ModelDescription::items_of`](model_description::ModelDescription::items_of): our
    /// FMUs' modes).
    pub fn set_value_str(&mut self, reference: &str, text: &str) -> Result<(), MasterError> {
        let value = self.parse_value_str(reference, text)?;
        self.set_value(reference, value)
    }

    /// Parses `text` as a value of the variable `reference` as
    /// [`set_value_str`](Self::set_value_str) reads it (its type, or an item's name), without
    /// setting it.
    pub fn parse_value_str(&self, reference: &str, text: &str) -> Result<Value, MasterError> {
        let (r, _) = self.resolve(reference)?;
        match Value::parse(r.ty, text) {
            Some(v) => Ok(v),
            None => self
                .item_value(reference, text)?
                .ok_or_else(|| MasterError::BadValue {
                    reference: reference.to_string(),
                    problem: format!("'{text}' is not {}", r.ty.with_article()),
                }),
        }
    }

    /// The value of item `name` when `reference` has named values (`None` when it has not);
    /// an unknown item is an error listing the items.
    fn item_value(&self, reference: &str, name: &str) -> Result<Option<Value>, MasterError> {
        let (c, v) = reference
            .split_once('.')
            .ok_or_else(|| MasterError::BadReference(reference.to_string()))?;
        let md = self.components[self.comp_index(c)?].fmu.model_description();
        let Some((_, var)) = find_var(md, v) else {
            return Ok(None);
        };
        let Some((type_name, items)) = md.items_of(var) else {
            return Ok(None);
        };
        match items.iter().find(|i| i.name == name.trim()) {
            Some(item) => Ok(Some(Value::Integer(item.value))),
            None => Err(MasterError::BadValue {
                reference: reference.to_string(),
                problem: format!(
                    "'{name}' is no item of {type_name} ({})",
                    items
                        .iter()
                        .map(|i| format!("{} = {}", i.name, i.value))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            }),
        }
    }

    /// Feeds an input from a time series, applied at the start of every step of its component.
    pub fn add_signal(&mut self, to: &str, signal: Signal) -> Result<(), MasterError> {
        let (dst, c) = self.resolve(to)?;
        if c != Causality::Input {
            return Err(MasterError::BadEndpoint {
                reference: to.to_string(),
                problem: format!(
                    "a signal feeds an input, not {} variable",
                    causality_with_article(c)
                ),
            });
        }
        if dst.ty == VarType::String {
            return Err(MasterError::BadEndpoint {
                reference: to.to_string(),
                problem: "String inputs cannot be fed from a signal".into(),
            });
        }
        if self.is_fed(&dst) {
            return Err(MasterError::InputAlreadyConnected(to.to_string()));
        }
        self.signals.push((dst, signal));
        Ok(())
    }

    /// Chooses the recorded variables (`component.variable`, any causality, not `String`).
    /// Without a call, every output of every component is recorded.
    pub fn record(&mut self, references: &[&str]) -> Result<(), MasterError> {
        self.record = Some(self.resolve_recorded(Vec::new(), references)?);
        Ok(())
    }

    /// Records `references` after the variables recorded now (every output of the components
    /// added so far, without an earlier [`Self::record`]): a local variable next to the outputs,
    /// for example. A component added later is not recorded.
    pub fn record_also(&mut self, references: &[&str]) -> Result<(), MasterError> {
        self.record = Some(self.resolve_recorded(self.recorded(), references)?);
        Ok(())
    }

    /// `out` followed by the recordable variables `references`.
    fn resolve_recorded(
        &self,
        mut out: Vec<VarRef>,
        references: &[&str],
    ) -> Result<Vec<VarRef>, MasterError> {
        for r in references {
            let (v, _) = self.resolve(r)?;
            if v.ty == VarType::String {
                return Err(MasterError::BadValue {
                    reference: r.to_string(),
                    problem: "String variables cannot be recorded".into(),
                });
            }
            out.push(v);
        }
        Ok(out)
    }

    fn recorded(&self) -> Vec<VarRef> {
        if let Some(r) = &self.record {
            return r.clone();
        }
        let mut out = Vec::new();
        for (ci, c) in self.components.iter().enumerate() {
            for v in &c.fmu.model_description().model_variables {
                if causality(v) == Causality::Output && VarType::of(v) != VarType::String {
                    out.push(VarRef {
                        comp: ci,
                        vr: v.value_reference,
                        ty: VarType::of(v),
                        name: format!("{}.{}", c.name, v.name),
                    });
                }
            }
        }
        out
    }

    /// Whether output `vr` of component `comp` depends directly on an input of its component.
    fn feedthrough(&self, comp: usize, vr: u32, ty: VarType) -> bool {
        let md = self.components[comp].fmu.model_description();
        let Some(index) = md.model_variables.iter().position(|v| {
            v.value_reference == vr && VarType::of(v) == ty && causality(v) == Causality::Output
        }) else {
            return true;
        };
        let Some(unknown) = md
            .model_structure
            .outputs
            .iter()
            .find(|u| u.index as usize == index + 1)
        else {
            return true;
        };
        match &unknown.dependencies {
            None => md
                .model_variables
                .iter()
                .any(|v| causality(v) == Causality::Input),
            Some(deps) => deps.iter().any(|&d| {
                md.model_variables
                    .get((d as usize).wrapping_sub(1))
                    .is_some_and(|v| causality(v) == Causality::Input)
            }),
        }
    }

    /// The Gauss-Seidel order and its dependency levels, or the components of an algebraic loop.
    pub fn dependency_order(&self) -> Result<(Vec<usize>, Vec<usize>), Vec<String>> {
        let n = self.components.len();
        let all: Vec<(usize, usize, bool)> = self
            .connections
            .iter()
            .filter(|(s, d)| s.comp != d.comp)
            .map(|(s, d)| (s.comp, d.comp, self.feedthrough(s.comp, s.vr, s.ty)))
            .collect();
        // A component fed by its own direct-feedthrough output is an algebraic loop.
        for (s, d) in &self.connections {
            if s.comp == d.comp && self.feedthrough(s.comp, s.vr, s.ty) {
                return Err(vec![self.components[s.comp].name.clone()]);
            }
        }
        let kahn = |edges: &[(usize, usize)]| -> Result<Vec<usize>, Vec<usize>> {
            let mut indeg = vec![0usize; n];
            for &(_, d) in edges {
                indeg[d] += 1;
            }
            let mut done = vec![false; n];
            let mut order = Vec::with_capacity(n);
            while order.len() < n {
                let Some(next) = (0..n).find(|&i| !done[i] && indeg[i] == 0) else {
                    return Err((0..n).filter(|&i| !done[i]).collect());
                };
                done[next] = true;
                order.push(next);
                for &(s, d) in edges {
                    if s == next {
                        indeg[d] -= 1;
                    }
                }
            }
            Ok(order)
        };
        let every: Vec<(usize, usize)> = all.iter().map(|&(s, d, _)| (s, d)).collect();
        let (order, edges) = match kahn(&every) {
            Ok(o) => (o, every),
            Err(_) => {
                let ft: Vec<(usize, usize)> = all
                    .iter()
                    .filter(|e| e.2)
                    .map(|&(s, d, _)| (s, d))
                    .collect();
                match kahn(&ft) {
                    Ok(o) => (o, ft),
                    Err(cycle) => {
                        return Err(cycle
                            .into_iter()
                            .map(|i| self.components[i].name.clone())
                            .collect());
                    }
                }
            }
        };
        let mut level = vec![0usize; n];
        for &i in &order {
            for &(s, d) in &edges {
                if s == i {
                    level[d] = level[d].max(level[i] + 1);
                }
            }
        }
        Ok((order, level))
    }

    /// Runs the system, keeping the rows in memory. `Err` only for a configuration that
    /// cannot start (bad grid, algebraic loop, bad step multiple); everything that happens once
    /// FMUs are instantiated is reported in [`RunOutput::outcome`] with the rows recorded so far.
    pub fn run(&self, config: &RunConfig) -> Result<RunOutput, MasterError> {
        let mut results = Results::with_capacity(Vec::new(), Vec::new(), 0);
        let summary = self.run_into(config, &mut results)?;
        Ok(RunOutput {
            results,
            outcome: summary.outcome,
            steps_per_component: summary.steps_per_component,
        })
    }

    /// The grid of a run with `config`, checked: what [`run_into`](Self::run_into) refuses
    /// before instantiating anything (time base, step multiples, algebraic loop).
    pub fn check_config(&self, config: &RunConfig) -> Result<Grid, MasterError> {
        if self.components.is_empty() {
            return Err(MasterError::Empty);
        }
        let grid = Grid::new(config.start_time, config.stop_time, config.step_size)?;
        for c in &self.components {
            // `set_step_multiple` refuses 0; checked again because the step loop divides by it.
            if c.step_multiple == 0 {
                return Err(MasterError::BadStepMultiple {
                    component: c.name.clone(),
                    multiple: c.step_multiple,
                    problem: "must be at least 1",
                });
            }
            if c.step_multiple.checked_mul(grid.step_ticks).is_none() {
                return Err(MasterError::StepOverflow {
                    component: c.name.clone(),
                    multiple: c.step_multiple,
                });
            }
            if !grid.n_steps.is_multiple_of(c.step_multiple) {
                return Err(MasterError::BadStepMultiple {
                    component: c.name.clone(),
                    multiple: c.step_multiple,
                    problem: "does not divide the number of base steps of the run",
                });
            }
        }
        if config.algorithm == Algorithm::GaussSeidel
            && let Err(cycle) = self.dependency_order()
        {
            return Err(MasterError::AlgebraicLoop(cycle));
        }
        Ok(grid)
    }

    /// The groups of components that may step concurrently, in order (see the module
    /// documentation, "Parallel stepping"): consecutive runs of `order` in which no member
    /// feeds a later member through any connection. Jacobi: one group.
    pub fn parallel_groups(&self, order: &[usize], algorithm: Algorithm) -> Vec<Vec<usize>> {
        if algorithm == Algorithm::Jacobi {
            return vec![order.to_vec()];
        }
        let mut groups: Vec<Vec<usize>> = Vec::new();
        for &c in order {
            let fed_by_group = groups.last().is_some_and(|g| {
                self.connections
                    .iter()
                    .any(|(s, d)| d.comp == c && s.comp != c && g.contains(&s.comp))
            });
            match groups.last_mut() {
                Some(g) if !fed_by_group => g.push(c),
                _ => groups.push(vec![c]),
            }
        }
        groups
    }

    /// Runs the system, handing every recorded row to `sink` (see [`ResultSink`]). `Err` only
    /// for a configuration that cannot start (as [`check_config`](Self::check_config));
    /// everything after is in [`RunSummary::outcome`], and every row recorded up to the end of
    /// the run is in the sink, flushed.
    pub fn run_into<S: ResultSink + ?Sized>(
        &self,
        config: &RunConfig,
        sink: &mut S,
    ) -> Result<RunSummary, MasterError> {
        let started = std::time::Instant::now();
        let grid = self.check_config(config)?;
        let n = self.components.len();
        let (order, _) = match self.dependency_order() {
            Ok(x) => x,
            // Gauss-Seidel refused a loop in `check_config`.
            Err(_) => ((0..n).collect(), vec![0; n]),
        };
        let groups = self.parallel_groups(&order, config.algorithm);

        let recorded = self.recorded();
        let names: Vec<String> = recorded
            .iter()
            .map(|r| {
                if self.column_prefix {
                    r.name.clone()
                } else {
                    r.name
                        .split_once('.')
                        .map(|(_, v)| v.to_string())
                        .unwrap_or_else(|| r.name.clone())
                }
            })
            .collect();
        let kinds: Vec<ColumnKind> = recorded
            .iter()
            .map(|r| match r.ty {
                VarType::Real => ColumnKind::Real,
                VarType::Integer => ColumnKind::Integer,
                _ => ColumnKind::Boolean,
            })
            .collect();
        let record_every = config.record_every.max(1);
        sink.begin(&names, &kinds)?;
        sink.expect_rows(grid.n_steps / record_every + 1);

        // Runtime tables: where every value the master moves lives.
        let fed: Vec<&VarRef> = self.signals.iter().map(|(d, _)| d).collect();
        let plan = Plan::new(n, &recorded, &self.connections, &fed);
        let signals: Vec<Signal> = self.signals.iter().map(|(_, s)| s.clone()).collect();
        let bus = Bus::new(plan.bus_len);
        let mut rts: Vec<Rt> = Vec::with_capacity(n);
        let control = config.control.clone().unwrap_or_default();
        let ticker = Ticker::start(
            &control,
            sink.wants_periodic_flush(),
            config.timeout.map(|d| started + d),
        )?;

        // Instantiate.
        for (c, ports) in self.components.iter().zip(plan.ports) {
            match c.fmu.instantiate(&c.name, &self.instance_options) {
                Ok(inst) => {
                    let h = (c.step_multiple * grid.step_ticks) as f64
                        / crate::time::TICKS_PER_SECOND as f64;
                    rts.push(Rt::new(inst, c.step_multiple, h, ports, &signals));
                }
                Err(e) => {
                    drop(ticker);
                    let outcome = Outcome::Failed(MasterError::Fmu {
                        component: c.name.clone(),
                        time: grid.start,
                        source: e,
                    });
                    return Ok(RunSummary {
                        outcome: flushed(sink, outcome),
                        rows: 0,
                        steps_per_component: vec![0; n],
                    });
                }
            }
        }

        let mut run = Run {
            sys: self,
            grid,
            rts,
            bus,
            signals,
            row_buf: vec![0.0; plan.copies.len],
            row: plan.copies,
            rows: 0,
            last_row_time: None,
            control,
            allow_nonfinite: config.allow_nonfinite,
        };
        let outcome = run.execute(config, &order, &groups, sink, record_every);
        drop(ticker);
        let steps_per_component = run.rts.iter().map(|r| r.steps).collect();
        Ok(RunSummary {
            outcome: flushed(sink, outcome),
            rows: run.rows,
            steps_per_component,
        })
    }
}

mod plan;
mod step;

use plan::{Bus, Plan, Rt};
use step::{Run, Ticker, flushed};

#[cfg(test)]
mod tests;
