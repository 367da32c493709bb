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
//! more than one due component step on scoped threads, spawned for every step. That costs tens of microseconds per step (measured: the study's SEA loop
//! ~116 us per step with `--parallel`, 60x slower than sequential, on a 2-core VM), so it
//! pays only for FMUs whose steps take milliseconds. It requires FMUs whose instances share no
//! mutable state.

use std::collections::HashMap;
use std::fmt;
use std::sync::Arc;

use model_description::{Causality, ModelDescription, ScalarVariable, VariableKind};

pub use crate::control::{RunControl, StopReason};
use crate::instance::{FmuError, Instance, InstanceOptions, Status};
use crate::load::Fmu;
use crate::num::num;
use crate::results::{ColumnKind, ResultSink, Results, ResultsError};
use crate::time::{Grid, GridError};

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
        let n = self.times.len();
        if n == 0 {
            return 0.0;
        }
        // Sample times written as decimals (0.001*k) and grid times computed from integer
        // ticks may differ in the last bit: a sample within this tolerance of t counts as at t.
        let tolerance = 1e-9 * t.abs().max(1.0);
        // Index of the first sample with time > t.
        let i = self.times.partition_point(|&x| x <= t + tolerance);
        if i == 0 {
            return self.values[0];
        }
        if i == n || !self.interpolate || (t - self.times[i - 1]).abs() <= tolerance {
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

struct ComponentSpec {
    name: String,
    fmu: Fmu,
    step_multiple: u64,
    values: Vec<(VarRef, Value)>,
}

/// A system: named components (instances of loaded FMUs), connections, parameter values,
/// input signals and the variables to record.
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
                problem: format!("a connection starts at an output, not a {src_c:?} variable"),
            });
        }
        if dst_c != Causality::Input {
            return Err(MasterError::BadEndpoint {
                reference: to.to_string(),
                problem: format!("a connection ends at an input, not a {dst_c:?} variable"),
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
    pub fn set_value(&mut self, reference: &str, value: Value) -> Result<(), MasterError> {
        let (r, _) = self.resolve(reference)?;
        if r.ty != value.ty() {
            return Err(MasterError::BadValue {
                reference: reference.to_string(),
                problem: format!("the variable is {:?}, the value {:?}", r.ty, value.ty()),
            });
        }
        let comp = r.comp;
        self.components[comp].values.push((r, value));
        Ok(())
    }

    /// Parses `text` as a value of the variable's type and sets it (see
    /// [`set_value`](Self::set_value)).
    pub fn set_value_str(&mut self, reference: &str, text: &str) -> Result<(), MasterError> {
        let (r, _) = self.resolve(reference)?;
        let value = Value::parse(r.ty, text).ok_or_else(|| MasterError::BadValue {
            reference: reference.to_string(),
            problem: format!("'{text}' is not a {:?}", r.ty),
        })?;
        self.set_value(reference, value)
    }

    /// Feeds an input from a time series, applied at the start of every step of its component.
    pub fn add_signal(&mut self, to: &str, signal: Signal) -> Result<(), MasterError> {
        let (dst, c) = self.resolve(to)?;
        if c != Causality::Input {
            return Err(MasterError::BadEndpoint {
                reference: to.to_string(),
                problem: format!("a signal feeds an input, not a {c:?} variable"),
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
        let mut out = Vec::new();
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
        self.record = Some(out);
        Ok(())
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
    pub fn run_into(
        &self,
        config: &RunConfig,
        sink: &mut dyn ResultSink,
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
                    rts.push(Rt::new(inst, c.step_multiple, h, ports));
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
            row: plan.row,
            row_buf: Vec::with_capacity(names.len()),
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

/// Flushes `sink` at the end of a run; a failed flush fails a run that had not failed.
fn flushed(sink: &mut dyn ResultSink, outcome: Outcome) -> Outcome {
    match (sink.flush(), outcome) {
        (Err(e), Outcome::Completed { .. } | Outcome::Terminated { .. }) => {
            Outcome::Failed(MasterError::Sink(e))
        }
        (_, outcome) => outcome,
    }
}

/// The thread that asks for a flush every second and marks the time limit as passed; it ends
/// when dropped.
struct Ticker {
    stop: Option<std::sync::mpsc::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Ticker {
    /// Starts the thread if there is anything to do (periodic flushes or a deadline).
    fn start(
        control: &RunControl,
        flush: bool,
        deadline: Option<std::time::Instant>,
    ) -> Result<Ticker, MasterError> {
        use std::sync::mpsc::RecvTimeoutError;
        use std::time::{Duration, Instant};
        if !flush && deadline.is_none() {
            return Ok(Ticker {
                stop: None,
                thread: None,
            });
        }
        const PERIOD: Duration = Duration::from_secs(1);
        let (tx, rx) = std::sync::mpsc::channel::<()>();
        let control = control.clone();
        let thread = std::thread::Builder::new()
            .name("kneebench-ticker".into())
            .spawn(move || {
                loop {
                    let now = Instant::now();
                    let wait = match deadline {
                        Some(d) if d <= now => {
                            control.request_timeout();
                            return;
                        }
                        Some(d) if !flush => d - now,
                        Some(d) => PERIOD.min(d - now),
                        None => PERIOD,
                    };
                    match rx.recv_timeout(wait) {
                        Err(RecvTimeoutError::Timeout) => {
                            if flush {
                                control.request_flush();
                            }
                        }
                        _ => return,
                    }
                }
            });
        match thread {
            Ok(t) => Ok(Ticker {
                stop: Some(tx),
                thread: Some(t),
            }),
            Err(e) => Err(MasterError::Thread(e)),
        }
    }
}

impl Drop for Ticker {
    fn drop(&mut self) {
        drop(self.stop.take());
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The index of a type's buffer: 0 `Real`, 1 `Integer` (and `Enumeration`), 2 `Boolean`.
fn ty_index(ty: VarType) -> usize {
    match ty {
        VarType::Real => 0,
        VarType::Integer => 1,
        _ => 2,
    }
}

/// The values the master reads after each step, one flat buffer per type (the "bus"): the
/// values a component's `fmi2Get*` call of one type returns occupy one contiguous range of that
/// type's buffer ([`Ports::out`]); the components' ranges follow each other in declaration
/// order. Booleans are kept as the FMU's `fmi2Boolean` (a C int).
#[derive(Debug, Clone, Default, PartialEq)]
struct Bus {
    real: Vec<f64>,
    int: Vec<i32>,
    boolean: Vec<i32>,
}

/// One component's part of the [`Bus`], per type.
struct Outs<'a> {
    real: &'a mut [f64],
    int: &'a mut [i32],
    boolean: &'a mut [i32],
}

impl Bus {
    /// A bus of `len` values per type (`Real`, `Integer`, `Boolean`), all zero.
    fn new(len: [usize; 3]) -> Bus {
        Bus {
            real: vec![0.0; len[0]],
            int: vec![0; len[1]],
            boolean: vec![0; len[2]],
        }
    }

    /// Every component's part at once (for stepping on threads): `ranges` are the components'
    /// [`Ports::out`] in declaration order, which tile the bus.
    fn split(&mut self, ranges: impl Iterator<Item = [(usize, usize); 3]>) -> Vec<Outs<'_>> {
        let (mut real, mut int, mut boolean) = (
            self.real.as_mut_slice(),
            self.int.as_mut_slice(),
            self.boolean.as_mut_slice(),
        );
        ranges
            .map(|out| {
                let (r, rest) = std::mem::take(&mut real).split_at_mut(out[0].1 - out[0].0);
                real = rest;
                let (i, rest) = std::mem::take(&mut int).split_at_mut(out[1].1 - out[1].0);
                int = rest;
                let (b, rest) = std::mem::take(&mut boolean).split_at_mut(out[2].1 - out[2].0);
                boolean = rest;
                Outs {
                    real: r,
                    int: i,
                    boolean: b,
                }
            })
            .collect()
    }
}

/// A run of consecutive recorded columns that are consecutive values of one type on the
/// [`Bus`] (start, end): a recorded row is built with one copy per run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum RowRun {
    /// `Real` values, copied as they are.
    Real(usize, usize),
    /// `Integer` values, converted to `f64`.
    Integer(usize, usize),
    /// `Boolean` values, recorded as 0.0 or 1.0.
    Boolean(usize, usize),
}

/// Groups recorded columns, given as (type index, bus index), into [`RowRun`]s.
fn row_runs(columns: &[(usize, usize)]) -> Vec<RowRun> {
    let mut runs: Vec<(usize, usize, usize)> = Vec::new();
    for &(t, k) in columns {
        match runs.last_mut() {
            Some((rt, _, end)) if *rt == t && *end == k => *end += 1,
            _ => runs.push((t, k, k + 1)),
        }
    }
    runs.into_iter()
        .map(|(t, a, b)| match t {
            0 => RowRun::Real(a, b),
            1 => RowRun::Integer(a, b),
            _ => RowRun::Boolean(a, b),
        })
        .collect()
}

/// What one component reads and writes, as indices (built once per run by [`Plan::new`]).
#[derive(Debug, Clone, Default, PartialEq)]
struct Ports {
    /// Value references read after each step, per type (recorded ones first, in recording
    /// order, then the connected ones; each once).
    out_vrs: [Vec<u32>; 3],
    /// Where their values go on the bus, per type: (start, end).
    out: [(usize, usize); 3],
    /// Value references of the inputs set before each step, per type: the connected ones in
    /// connection order, then the signal-fed ones.
    in_vrs: [Vec<u32>; 3],
    /// The bus index of each connected input's source, per type (the first `in_from[t].len()`
    /// entries of `in_vrs[t]`).
    in_from: [Vec<usize>; 3],
    /// The signal-fed inputs: (type index, position in `in_vrs[type]`, signal index).
    in_signals: Vec<(usize, usize, usize)>,
    /// Whether there are `Integer` or `Boolean` outputs to read (the hot path reads `Real`s
    /// only).
    out_other: bool,
    /// Whether there are `Integer` or `Boolean` inputs to set.
    in_other: bool,
    /// Whether there are `Integer` or `Boolean` inputs or signal-fed inputs to gather.
    in_rare: bool,
}

/// The layout of a run: every component's [`Ports`], the bus size and the recorded row.
#[derive(Debug, Clone, PartialEq)]
struct Plan {
    /// Per component, in declaration order.
    ports: Vec<Ports>,
    /// Bus length per type.
    bus_len: [usize; 3],
    /// The recorded columns, as runs of bus values.
    row: Vec<RowRun>,
}

impl Plan {
    /// The layout for `n` components recording `recorded`, with `connections` (source,
    /// destination) and the inputs `fed` by signals (in signal order).
    fn new(
        n: usize,
        recorded: &[VarRef],
        connections: &[(VarRef, VarRef)],
        fed: &[&VarRef],
    ) -> Plan {
        let mut ports: Vec<Ports> = vec![Ports::default(); n];
        // Position of each value read per component, type and value reference, in order of
        // first use.
        let mut slots: Vec<HashMap<(usize, u32), usize>> = vec![HashMap::new(); n];
        let mut slot_of = |ports: &mut [Ports], comp: usize, ty: VarType, vr: u32| -> usize {
            let t = ty_index(ty);
            *slots[comp].entry((t, vr)).or_insert_with(|| {
                ports[comp].out_vrs[t].push(vr);
                ports[comp].out_vrs[t].len() - 1
            })
        };
        let rec: Vec<(usize, usize, usize)> = recorded
            .iter()
            .map(|r| {
                (
                    r.comp,
                    ty_index(r.ty),
                    slot_of(&mut ports, r.comp, r.ty, r.vr),
                )
            })
            .collect();
        let sources: Vec<usize> = connections
            .iter()
            .map(|(s, _)| slot_of(&mut ports, s.comp, s.ty, s.vr))
            .collect();
        let mut bus_len = [0; 3];
        for p in &mut ports {
            for ((out, vrs), len) in p.out.iter_mut().zip(&p.out_vrs).zip(&mut bus_len) {
                *out = (*len, *len + vrs.len());
                *len = out.1;
            }
        }
        for ((s, d), slot) in connections.iter().zip(sources) {
            let t = ty_index(s.ty);
            let from = ports[s.comp].out[t].0 + slot;
            let p = &mut ports[d.comp];
            p.in_vrs[t].push(d.vr);
            p.in_from[t].push(from);
        }
        for (k, d) in fed.iter().enumerate() {
            let t = ty_index(d.ty);
            let p = &mut ports[d.comp];
            p.in_signals.push((t, p.in_vrs[t].len(), k));
            p.in_vrs[t].push(d.vr);
        }
        for p in &mut ports {
            p.out_other = !(p.out_vrs[1].is_empty() && p.out_vrs[2].is_empty());
            p.in_other = !(p.in_vrs[1].is_empty() && p.in_vrs[2].is_empty());
            p.in_rare = p.in_other || !p.in_signals.is_empty();
        }
        let columns: Vec<(usize, usize)> = rec
            .iter()
            .map(|&(c, t, slot)| (t, ports[c].out[t].0 + slot))
            .collect();
        let row = row_runs(&columns);
        Plan {
            ports,
            bus_len,
            row,
        }
    }
}

/// The input values of one component, set before each of its steps (same layout as
/// [`Ports::in_vrs`]).
#[derive(Debug, Clone, Default, PartialEq)]
struct InValues {
    real: Vec<f64>,
    int: Vec<i32>,
    boolean: Vec<i32>,
}

impl InValues {
    /// Zeroed buffers for the inputs of `ports`.
    fn for_ports(ports: &Ports) -> InValues {
        InValues {
            real: vec![0.0; ports.in_vrs[0].len()],
            int: vec![0; ports.in_vrs[1].len()],
            boolean: vec![0; ports.in_vrs[2].len()],
        }
    }

    /// Takes the connected inputs from the bus and the signal-fed ones from their signals at
    /// time `t`.
    #[inline(always)]
    fn gather(&mut self, ports: &Ports, bus: &Bus, signals: &[Signal], t: f64) {
        for (v, &k) in self.real.iter_mut().zip(&ports.in_from[0]) {
            *v = bus.real[k];
        }
        if ports.in_rare {
            self.gather_rare(ports, bus, signals, t);
        }
    }

    /// The `Integer` and `Boolean` part of [`gather`](Self::gather) and the signal-fed inputs.
    #[inline(never)]
    fn gather_rare(&mut self, ports: &Ports, bus: &Bus, signals: &[Signal], t: f64) {
        for (v, &k) in self.int.iter_mut().zip(&ports.in_from[1]) {
            *v = bus.int[k];
        }
        for (v, &k) in self.boolean.iter_mut().zip(&ports.in_from[2]) {
            *v = (bus.boolean[k] != 0) as i32;
        }
        if !ports.in_signals.is_empty() {
            self.sample_signals(ports, signals, t);
        }
    }

    /// The signal-fed inputs at time `t` (rare: single-FMU runs with an input file).
    #[cold]
    #[inline(never)]
    fn sample_signals(&mut self, ports: &Ports, signals: &[Signal], t: f64) {
        for &(ty, k, s) in &ports.in_signals {
            let x = signals[s].at(t);
            match ty {
                0 => self.real[k] = x,
                1 => self.int[k] = x.round() as i32,
                _ => self.boolean[k] = (x != 0.0) as i32,
            }
        }
    }
}

/// One component at run time: its instance, its [`Ports`] and its input values.
struct Rt {
    inst: Instance,
    multiple: u64,
    h: f64,
    ports: Ports,
    inputs: InValues,
    steps: u64,
}

enum StepEnd {
    Done,
    Discard,
}

impl Rt {
    fn new(inst: Instance, multiple: u64, h: f64, ports: Ports) -> Rt {
        Rt {
            inst,
            multiple,
            h,
            inputs: InValues::for_ports(&ports),
            ports,
            steps: 0,
        }
    }

    /// Takes the input values (see [`InValues::gather`]).
    #[inline(always)]
    fn gather(&mut self, bus: &Bus, signals: &[Signal], t: f64) {
        self.inputs.gather(&self.ports, bus, signals, t);
    }

    /// Reads the outputs into the component's part of the bus.
    #[inline(always)]
    fn read(&mut self, bus: &mut Bus) -> Result<(), FmuError> {
        let (a, b) = self.ports.out[0];
        self.inst
            .get_real(&self.ports.out_vrs[0], &mut bus.real[a..b])?;
        if self.ports.out_other {
            self.read_other(bus)?;
        }
        Ok(())
    }

    /// The `Integer` and `Boolean` part of [`read`](Self::read).
    #[inline(never)]
    fn read_other(&mut self, bus: &mut Bus) -> Result<(), FmuError> {
        let [_, (a, b), (c, d)] = self.ports.out;
        self.inst
            .get_integer(&self.ports.out_vrs[1], &mut bus.int[a..b])?;
        self.inst
            .get_boolean_raw(&self.ports.out_vrs[2], &mut bus.boolean[c..d])?;
        Ok(())
    }

    /// Reads the outputs into `out` (the component's part of the bus).
    fn read_into(&mut self, out: Outs<'_>) -> Result<(), FmuError> {
        self.inst.get_real(&self.ports.out_vrs[0], out.real)?;
        self.inst.get_integer(&self.ports.out_vrs[1], out.int)?;
        self.inst
            .get_boolean_raw(&self.ports.out_vrs[2], out.boolean)?;
        Ok(())
    }

    /// Sets the input values.
    #[inline(always)]
    fn write(&mut self) -> Result<(), FmuError> {
        self.inst
            .set_real(&self.ports.in_vrs[0], &self.inputs.real)?;
        if self.ports.in_other {
            self.write_other()?;
        }
        Ok(())
    }

    /// The `Integer` and `Boolean` part of [`write`](Self::write).
    #[inline(never)]
    fn write_other(&mut self) -> Result<(), FmuError> {
        self.inst
            .set_integer(&self.ports.in_vrs[1], &self.inputs.int)?;
        self.inst
            .set_boolean_raw(&self.ports.in_vrs[2], &self.inputs.boolean)?;
        Ok(())
    }

    /// Sets the inputs and steps from `t`.
    #[inline(always)]
    fn write_step(&mut self, t: f64) -> Result<StepEnd, FmuError> {
        self.write()?;
        self.steps += 1;
        match self.inst.do_step(t, self.h)? {
            Status::Discard => Ok(StepEnd::Discard),
            Status::Ok | Status::Warning => Ok(StepEnd::Done),
        }
    }

    /// Sets the inputs, steps from `t` and reads the outputs onto the bus.
    #[inline(always)]
    fn step_read(&mut self, bus: &mut Bus, t: f64) -> Result<StepEnd, FmuError> {
        match self.write_step(t)? {
            StepEnd::Discard => Ok(StepEnd::Discard),
            StepEnd::Done => self.read(bus).map(|_| StepEnd::Done),
        }
    }

    /// [`step_read`](Self::step_read) into the component's part of the bus (on a thread).
    fn step_read_into(&mut self, out: Outs<'_>, t: f64) -> Result<StepEnd, FmuError> {
        match self.write_step(t)? {
            StepEnd::Discard => Ok(StepEnd::Discard),
            StepEnd::Done => self.read_into(out).map(|_| StepEnd::Done),
        }
    }
}

/// Whether a component stepping every `multiple` base steps steps at base step `n` (no
/// division for the common `multiple == 1`: a 64-bit division per component and step is a
/// measurable part of a small system's step).
#[inline(always)]
fn steps_at(n: u64, multiple: u64) -> bool {
    multiple == 1 || n.is_multiple_of(multiple)
}

struct Run<'a> {
    sys: &'a System,
    grid: Grid,
    rts: Vec<Rt>,
    bus: Bus,
    signals: Vec<Signal>,
    row: Vec<RowRun>,
    /// The row being recorded (values only).
    row_buf: Vec<f64>,
    /// Rows handed to the sink.
    rows: u64,
    /// The time of the last row handed to the sink.
    last_row_time: Option<f64>,
    control: RunControl,
    allow_nonfinite: bool,
}

enum Stop {
    Terminated { comp: usize, time: f64 },
    Failed(MasterError),
}

/// Fills `values` with the recorded values on `bus` (the columns in `row`).
#[inline]
fn fill_row(values: &mut Vec<f64>, row: &[RowRun], bus: &Bus) {
    values.clear();
    for run in row {
        match *run {
            RowRun::Real(a, b) => values.extend_from_slice(&bus.real[a..b]),
            RowRun::Integer(a, b) => values.extend(bus.int[a..b].iter().map(|&v| v as f64)),
            RowRun::Boolean(a, b) => {
                values.extend(bus.boolean[a..b].iter().map(|&v| (v != 0) as i32 as f64))
            }
        }
    }
}

impl Run<'_> {
    #[cold]
    #[inline(never)]
    fn fail(&self, comp: usize, time: f64, e: FmuError) -> Stop {
        Stop::Failed(MasterError::Fmu {
            component: self.sys.components[comp].name.clone(),
            time,
            source: e,
        })
    }

    #[inline]
    fn record(&mut self, sink: &mut dyn ResultSink, t: f64) -> Result<(), Stop> {
        self.record_row(sink, t).map_err(Stop::Failed)
    }

    /// Hands the row at `t` to the sink.
    #[inline]
    fn record_row(&mut self, sink: &mut dyn ResultSink, t: f64) -> Result<(), MasterError> {
        fill_row(&mut self.row_buf, &self.row, &self.bus);
        sink.push_row(t, &self.row_buf)?;
        self.rows += 1;
        self.last_row_time = Some(t);
        Ok(())
    }

    /// Acts on the pending requests of the control (a flush, a stop) at communication point
    /// `t`, after its row.
    #[cold]
    #[inline(never)]
    fn attend(&mut self, sink: &mut dyn ResultSink, t: f64) -> Result<(), Stop> {
        if self.control.take_flush()
            && let Err(e) = sink.flush()
        {
            return Err(Stop::Failed(MasterError::Sink(e)));
        }
        match self.control.stop_reason() {
            Some(reason) => Err(Stop::Failed(MasterError::Stopped {
                reason,
                time: self.last_row_time.unwrap_or(t),
            })),
            None => Ok(()),
        }
    }

    /// Fails with [`MasterError::NonFinite`] when an output of component `i` just read
    /// (values for time `t`) is not finite, unless allowed.
    #[inline(always)]
    fn check_finite(&self, i: usize, t: f64) -> Result<(), Stop> {
        let (a, b) = self.rts[i].ports.out[0];
        if self.allow_nonfinite || self.bus.real[a..b].iter().all(|v| v.is_finite()) {
            Ok(())
        } else {
            Err(Stop::Failed(self.nonfinite(i, t)))
        }
    }

    #[cold]
    #[inline(never)]
    fn nonfinite(&self, i: usize, t: f64) -> MasterError {
        let (a, b) = self.rts[i].ports.out[0];
        let k = self.bus.real[a..b]
            .iter()
            .position(|v| !v.is_finite())
            .unwrap_or(0);
        let vr = self.rts[i].ports.out_vrs[0][k];
        let md = self.sys.components[i].fmu.model_description();
        let variable = md
            .model_variables
            .iter()
            .find(|v| v.value_reference == vr && VarType::of(v) == VarType::Real)
            .map(|v| v.name.clone())
            .unwrap_or_else(|| format!("(value reference {vr})"));
        MasterError::NonFinite {
            component: self.sys.components[i].name.clone(),
            variable,
            value: self.bus.real[a + k],
            time: t,
        }
    }

    fn execute(
        &mut self,
        config: &RunConfig,
        order: &[usize],
        groups: &[Vec<usize>],
        sink: &mut dyn ResultSink,
        record_every: u64,
    ) -> Outcome {
        let t0 = self.grid.start;
        if let Err(stop) = self.initialize(config, order) {
            return self.finish(stop, sink);
        }
        if let Err(stop) = self.record(sink, t0).and_then(|_| {
            if self.control.pending() != 0 {
                self.attend(sink, t0)
            } else {
                Ok(())
            }
        }) {
            return self.finish(stop, sink);
        }
        // The step loop is chosen once per run.
        let r = match (config.parallel, config.algorithm) {
            (true, _) => self.step_loop(config, sink, record_every, |run, n, t| {
                run.step_parallel(groups, n, t)
            }),
            (false, Algorithm::GaussSeidel) => {
                self.step_loop(config, sink, record_every, |run, n, t| {
                    run.step_gauss_seidel(order, n, t)
                })
            }
            (false, Algorithm::Jacobi) => {
                self.step_loop(config, sink, record_every, |run, n, t| {
                    run.step_jacobi(order, n, t)
                })
            }
        };
        if let Err(stop) = r {
            return self.finish(stop, sink);
        }
        for i in 0..self.rts.len() {
            let _ = self.rts[i].inst.terminate();
        }
        Outcome::Completed {
            stop_time: self.grid.stop(),
        }
    }

    /// Every macro step with `step`, recording every `record_every`-th row and reporting
    /// progress.
    #[inline(always)]
    fn step_loop(
        &mut self,
        config: &RunConfig,
        sink: &mut dyn ResultSink,
        record_every: u64,
        mut step: impl FnMut(&mut Self, u64, f64) -> Result<(), Stop>,
    ) -> Result<(), Stop> {
        let total = self.grid.n_steps;
        let stride = (total / 200).max(1);
        // The next step counts (n + 1) to record at and to report progress at.
        let mut next_row = record_every;
        let mut next_progress = stride;
        let mut t = self.grid.time(0);
        for n in 0..total {
            step(self, n, t)?;
            let done = n + 1;
            t = self.grid.time(done);
            if done == next_row {
                next_row = next_row.saturating_add(record_every);
                self.record(sink, t)?;
            }
            if self.control.pending() != 0 {
                self.attend(sink, t)?;
            }
            if done == next_progress {
                next_progress = next_progress.saturating_add(stride);
                if let Some(p) = &config.progress {
                    p(done, total);
                }
            }
        }
        Ok(())
    }

    fn finish(&mut self, stop: Stop, sink: &mut dyn ResultSink) -> Outcome {
        // The row at the terminating component's last successful time, read before any
        // instance is terminated.
        let last_row = match &stop {
            Stop::Terminated { comp, time } => self.last_row(*comp, *time, sink),
            Stop::Failed(_) => Ok(()),
        };
        // Terminate the healthy instances; Drop frees every instance.
        for rt in &mut self.rts {
            if rt.inst.phase() == crate::instance::Phase::StepComplete {
                let _ = rt.inst.terminate();
            }
        }
        match (stop, last_row) {
            (Stop::Terminated { comp, time }, Ok(())) => Outcome::Terminated {
                component: self.sys.components[comp].name.clone(),
                last_successful_time: time,
                last_row_time: self.last_row_time.unwrap_or(self.grid.start),
                messages: self.rts[comp]
                    .inst
                    .take_messages()
                    .into_iter()
                    .map(|m| m.message)
                    .collect(),
            },
            (Stop::Terminated { .. }, Err(e)) | (Stop::Failed(e), _) => Outcome::Failed(e),
        }
    }

    /// Records the row at `time`, the last successful time of component `comp` that ended
    /// the run, when it is after the last row: `comp`'s outputs read now, the others' as
    /// they are.
    fn last_row(
        &mut self,
        comp: usize,
        time: f64,
        sink: &mut dyn ResultSink,
    ) -> Result<(), MasterError> {
        if self.last_row_time.is_some_and(|last| time <= last) || !time.is_finite() {
            return Ok(());
        }
        if let Err(source) = self.rts[comp].read(&mut self.bus) {
            return Err(MasterError::Fmu {
                component: self.sys.components[comp].name.clone(),
                time,
                source,
            });
        }
        let (a, b) = self.rts[comp].ports.out[0];
        if !self.allow_nonfinite && !self.bus.real[a..b].iter().all(|v| v.is_finite()) {
            return Err(self.nonfinite(comp, time));
        }
        self.record_row(sink, time)
    }

    fn initialize(&mut self, config: &RunConfig, order: &[usize]) -> Result<(), Stop> {
        let t0 = self.grid.start;
        let stop = self.grid.stop();
        for i in 0..self.rts.len() {
            let r = self.rts[i]
                .inst
                .setup_experiment(config.tolerance, t0, Some(stop))
                .and_then(|_| self.apply_values(i));
            r.map_err(|e| self.fail(i, t0, e))?;
        }
        for i in 0..self.rts.len() {
            let r = self.rts[i].inst.enter_initialization_mode();
            r.map_err(|e| self.fail(i, t0, e))?;
        }
        for i in 0..self.rts.len() {
            let r = self.rts[i].read(&mut self.bus);
            r.map_err(|e| self.fail(i, t0, e))?;
        }
        for &i in order {
            let rt = &mut self.rts[i];
            rt.gather(&self.bus, &self.signals, t0);
            let r = rt.write().and_then(|_| rt.read(&mut self.bus));
            r.map_err(|e| self.fail(i, t0, e))?;
        }
        for i in 0..self.rts.len() {
            let r = self.rts[i].inst.exit_initialization_mode();
            r.map_err(|e| self.fail(i, t0, e))?;
        }
        for &i in order {
            let r = self.rts[i].read(&mut self.bus);
            r.map_err(|e| self.fail(i, t0, e))?;
            self.check_finite(i, t0)?;
        }
        Ok(())
    }

    fn apply_values(&mut self, i: usize) -> Result<(), FmuError> {
        let inst = &mut self.rts[i].inst;
        for (r, v) in &self.sys.components[i].values {
            match v {
                Value::Real(x) => inst.set_real(&[r.vr], &[*x])?,
                Value::Integer(x) => inst.set_integer(&[r.vr], &[*x])?,
                Value::Boolean(x) => inst.set_boolean_raw(&[r.vr], &[*x as i32])?,
                Value::String(x) => inst.set_string(&[r.vr], &[x.as_str()])?,
            };
        }
        Ok(())
    }

    #[cold]
    #[inline(never)]
    fn discarded(&mut self, i: usize, t: f64) -> Stop {
        let inst = &mut self.rts[i].inst;
        if inst.terminated() {
            let time = inst.last_successful_time().unwrap_or(t);
            Stop::Terminated { comp: i, time }
        } else {
            let messages = inst.take_messages();
            Stop::Failed(MasterError::StepDiscarded {
                component: self.sys.components[i].name.clone(),
                time: t,
                messages,
            })
        }
    }

    /// Steps component `i` from `t` (its inputs gathered): outputs onto the bus.
    #[inline(always)]
    fn step_one(&mut self, i: usize, n: u64, t: f64) -> Result<(), Stop> {
        match self.rts[i].step_read(&mut self.bus, t) {
            Ok(StepEnd::Done) => self.check_finite_after_step(i, n),
            Ok(StepEnd::Discard) => Err(self.discarded(i, t)),
            Err(e) => Err(self.fail(i, t, e)),
        }
    }

    /// [`check_finite`](Self::check_finite) for component `i` after its step from base step
    /// `n`.
    #[inline(always)]
    fn check_finite_after_step(&self, i: usize, n: u64) -> Result<(), Stop> {
        let (a, b) = self.rts[i].ports.out[0];
        if self.allow_nonfinite || self.bus.real[a..b].iter().all(|v| v.is_finite()) {
            Ok(())
        } else {
            let end = self.grid.time(n + self.rts[i].multiple);
            Err(Stop::Failed(self.nonfinite(i, end)))
        }
    }

    #[inline(always)]
    fn step_gauss_seidel(&mut self, order: &[usize], n: u64, t: f64) -> Result<(), Stop> {
        for &i in order {
            let rt = &mut self.rts[i];
            if !steps_at(n, rt.multiple) {
                continue;
            }
            rt.gather(&self.bus, &self.signals, t);
            self.step_one(i, n, t)?;
        }
        Ok(())
    }

    #[inline(always)]
    fn step_jacobi(&mut self, order: &[usize], n: u64, t: f64) -> Result<(), Stop> {
        for &i in order {
            let rt = &mut self.rts[i];
            if steps_at(n, rt.multiple) {
                rt.gather(&self.bus, &self.signals, t);
            }
        }
        for &i in order {
            if !steps_at(n, self.rts[i].multiple) {
                continue;
            }
            self.step_one(i, n, t)?;
        }
        Ok(())
    }

    fn step_parallel(&mut self, groups: &[Vec<usize>], n: u64, t: f64) -> Result<(), Stop> {
        for group in groups {
            let due: Vec<usize> = group
                .iter()
                .copied()
                .filter(|&i| steps_at(n, self.rts[i].multiple))
                .collect();
            for &i in &due {
                self.rts[i].gather(&self.bus, &self.signals, t);
            }
            let results: Vec<(usize, Result<StepEnd, FmuError>)> = if due.len() <= 1 {
                due.iter()
                    .map(|&i| (i, self.rts[i].step_read(&mut self.bus, t)))
                    .collect()
            } else {
                let ranges: Vec<[(usize, usize); 3]> =
                    self.rts.iter().map(|rt| rt.ports.out).collect();
                let outs = self.bus.split(ranges.into_iter());
                let mut work: Vec<(usize, &mut Rt, Outs<'_>)> = self
                    .rts
                    .iter_mut()
                    .zip(outs)
                    .enumerate()
                    .filter(|(i, _)| due.contains(i))
                    .map(|(i, (rt, out))| (i, rt, out))
                    .collect();
                std::thread::scope(|s| {
                    let handles: Vec<_> = work
                        .drain(..)
                        .map(|(i, rt, out)| s.spawn(move || (i, rt.step_read_into(out, t))))
                        .collect();
                    handles
                        .into_iter()
                        .map(|h| h.join().expect("a stepping thread panicked"))
                        .collect()
                })
            };
            for (i, r) in results {
                match r {
                    Ok(StepEnd::Done) => self.check_finite_after_step(i, n)?,
                    Ok(StepEnd::Discard) => return Err(self.discarded(i, t)),
                    Err(e) => return Err(self.fail(i, t, e)),
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
