//! How a model is declared: a plain Rust struct plus one table of its variables.
//!
//! From that one table come the value-reference dispatch of get/set, the
//! `modelDescription.xml` (variables, units, type definitions, `ModelStructure` with
//! dependencies), the GUID (a hash of the generated description) and the FMU-state layout.
//! Nothing about a variable is written twice.
//!
//! A model knows nothing of C: it implements [`Model`] and returns its [`Variable`] table; the
//! generic glue in [`crate::fmi2`] does the rest.
//!
//! # Modes are Integers
//!
//! A model declares its modes (the plant's `configuration`, a friction law, a driver mode, a
//! controller's anti-windup scheme, ...) as enumerations ([`Model::enumerations`],
//! [`Variable::enumeration`]): named items, with the FMU refusing a value that is no item. The
//! model description types them as FMI `Integer`, not `Enumeration`, for every model alike:
//! libcosim (libcosimpy, and the tools built on it) ignores FMI 2.0 `Enumeration` variables
//! entirely, so an SSP binding to one fails ("No such variable: plant:configuration") and a
//! study's DA would silently run the plant's default SEA; every importer handles `Integer`.
//! Each enumeration type becomes an `Integer` `SimpleType` of the same name, bounded by its
//! smallest and largest item and naming every item in its description
//! (`0 = DA, 1 = SEA, 2 = CSEA`); each mode variable is an `Integer` of that `declaredType`,
//! with the same bounds and the item list after its own description; the items themselves
//! (name, value, description) go into the [`md::items::ITEMS_TOOL`] vendor annotation, from
//! which kneebench (`--param plant.configuration=DA`, `kneebench info`) and the parameter-set
//! checks read them, and the documentation page lists them. FMI 2.0 offers no way to keep the
//! `Enumeration` and add an `Integer` view of it: an alias set may hold at most one parameter.

use std::collections::BTreeSet;
use std::fmt::Write as _;

use model_description as md;
use sha2::{Digest, Sha256};

pub use md::{Causality, Initial, Variability};

/// The license every model description declares.
pub const LICENSE: &str = "MIT OR Apache-2.0";
/// The author every model description declares.
pub const AUTHOR: &str = "The kneebench developers";
/// The model version every description declares: the crate version.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");
/// The `generationTool` string.
pub const GENERATION_TOOL: &str = concat!("kneebench ", env!("CARGO_PKG_VERSION"));

/// An error a model reports; the glue logs it and answers `fmi2Error`, and its
/// [`ErrorKind`] says whether the instance stays usable.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{message}")]
pub struct ModelError {
    /// What went wrong, for the log.
    pub message: String,
    /// Whether the model is as it was before the call.
    pub kind: ErrorKind,
}

/// What a [`ModelError`] did to the model, which decides what the glue does with the instance.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorKind {
    /// The model refused the call before changing anything (parameters that do not fit
    /// together, rejected inputs, a step size the model cannot take): the glue answers `fmi2Error`
    /// and keeps the instance's state, so the importer may correct the call and go on.
    Refused,
    /// The computation failed after the model may have changed, or the hardware behind it
    /// failed: the glue moves the instance to the error state.
    Failed,
}

impl ModelError {
    /// A failure (the instance goes to the error state) with this message.
    pub fn new(message: impl Into<String>) -> Self {
        Self {
            message: message.into(),
            kind: ErrorKind::Failed,
        }
    }

    /// A refusal that left the model unchanged (the instance stays usable) with this message.
    pub fn refused(message: impl Into<String>) -> Self {
        Self {
            message: message.into(),
            kind: ErrorKind::Refused,
        }
    }

    /// The same error as a refusal: for checks made before the model changes anything.
    pub fn into_refused(self) -> Self {
        Self {
            kind: ErrorKind::Refused,
            ..self
        }
    }

    /// Whether the model is unchanged by the call that answered this error.
    pub fn is_refused(&self) -> bool {
        self.kind == ErrorKind::Refused
    }
}

/// What a completed call to [`Model::do_step`] reports.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StepOutcome {
    /// The model advanced to the end of the step.
    Completed,
    /// The model stopped early and wants the simulation to end (a safety trip, the end of a
    /// sweep): it advanced to `at` (the last successful time, inside the step) and the glue
    /// answers `fmi2Discard` with `fmi2Terminated = true`. `reason` goes to the log.
    Terminated {
        /// The last time the model reached.
        at: f64,
        /// Why it stopped.
        reason: &'static str,
    },
}

/// Reads a model's internal (non-variable) state back from the FMU-state byte format.
#[derive(Debug)]
pub struct StateReader<'a> {
    bytes: &'a [u8],
}

/// A malformed or foreign FMU state.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("invalid FMU state: {0}")]
pub struct StateError(pub String);

impl<'a> StateReader<'a> {
    /// A reader over `bytes`.
    pub fn new(bytes: &'a [u8]) -> Self {
        Self { bytes }
    }

    /// Bytes not read yet.
    pub fn remaining(&self) -> &'a [u8] {
        self.bytes
    }

    /// Reads `n` raw bytes.
    pub fn take(&mut self, n: usize) -> Result<&'a [u8], StateError> {
        if self.bytes.len() < n {
            return Err(StateError(format!(
                "truncated: wanted {n} more bytes, {} left",
                self.bytes.len()
            )));
        }
        let (head, tail) = self.bytes.split_at(n);
        self.bytes = tail;
        Ok(head)
    }

    /// Reads a little-endian `u8`.
    pub fn u8(&mut self) -> Result<u8, StateError> {
        Ok(self.take(1)?[0])
    }

    /// Reads a little-endian `u32`.
    pub fn u32(&mut self) -> Result<u32, StateError> {
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    /// Reads a little-endian `u64`.
    pub fn u64(&mut self) -> Result<u64, StateError> {
        let b = self.take(8)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(u64::from_le_bytes(a))
    }

    /// Reads an `f64` stored by its bits.
    pub fn f64(&mut self) -> Result<f64, StateError> {
        Ok(f64::from_bits(self.u64()?))
    }

    /// Reads an `i32`.
    pub fn i32(&mut self) -> Result<i32, StateError> {
        Ok(self.u32()? as i32)
    }

    /// Reads a boolean stored as one byte (0 or 1).
    pub fn bool(&mut self) -> Result<bool, StateError> {
        match self.u8()? {
            0 => Ok(false),
            1 => Ok(true),
            other => Err(StateError(format!(
                "boolean byte {other} is neither 0 nor 1"
            ))),
        }
    }

    /// Reads a length-prefixed UTF-8 string.
    pub fn string(&mut self) -> Result<String, StateError> {
        let len = self.u32()? as usize;
        let raw = self.take(len)?;
        String::from_utf8(raw.to_vec()).map_err(|_| StateError("string is not UTF-8".into()))
    }
}

/// Writes a model's internal state in the FMU-state byte format (little endian, no pointers).
#[derive(Debug, Default)]
pub struct StateWriter {
    /// The bytes written so far.
    pub bytes: Vec<u8>,
}

impl StateWriter {
    /// Appends a `u8`.
    pub fn u8(&mut self, v: u8) {
        self.bytes.push(v);
    }
    /// Appends a `u32`.
    pub fn u32(&mut self, v: u32) {
        self.bytes.extend_from_slice(&v.to_le_bytes());
    }
    /// Appends a `u64`.
    pub fn u64(&mut self, v: u64) {
        self.bytes.extend_from_slice(&v.to_le_bytes());
    }
    /// Appends an `f64` by its bits (NaN payloads and signed zeros survive).
    pub fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }
    /// Appends an `i32`.
    pub fn i32(&mut self, v: i32) {
        self.u32(v as u32);
    }
    /// Appends a boolean as one byte.
    pub fn bool(&mut self, v: bool) {
        self.u8(u8::from(v));
    }
    /// Appends a length-prefixed UTF-8 string.
    pub fn string(&mut self, v: &str) {
        self.u32(v.len() as u32);
        self.bytes.extend_from_slice(v.as_bytes());
    }
}

/// The most internal steps (integration sub-steps, controller samples) one `fmi2DoStep` may
/// take. It bounds the work of one call: a model whose work grows with the communication
/// step declares its largest step ([`Model::max_step_size`]) as this many internal steps, and
/// the FMI glue refuses a larger step with fmi2Error and a log line (the instance is
/// unchanged and stays usable), where it would otherwise compute for minutes.
pub const MAX_INTERNAL_STEPS_PER_CALL: f64 = 1e4;

/// A model that can be exported as an FMI 2.0 co-simulation FMU.
///
/// The struct holds every variable as a plain field; [`Model::variables`] declares them once.
/// Start values come from the declaration (the glue applies them after [`Default`]).
pub trait Model: Default + Clone + Send + 'static {
    /// `modelIdentifier` and `modelName`: also the binary's name inside the FMU.
    const IDENTIFIER: &'static str;
    /// One-line description for the model description.
    const DESCRIPTION: &'static str;
    /// Highest order `fmi2GetRealOutputDerivatives` answers (0 = none).
    const MAX_OUTPUT_DERIVATIVE_ORDER: u32 = 0;
    /// The `DefaultExperiment`: (start, stop, step size).
    const DEFAULT_EXPERIMENT: (f64, f64, f64) = (0.0, 10.0, 1e-3);
    /// `canGetAndSetFMUstate`: whether `fmi2GetFMUstate`, `fmi2SetFMUstate` and
    /// `fmi2FreeFMUstate` are provided. When false the glue answers them with fmi2Error and a
    /// log line naming the flag (a call the model description says is unsupported).
    const CAN_GET_AND_SET_FMU_STATE: bool = true;
    /// `canSerializeFMUstate`: whether `fmi2SerializedFMUstateSize`, `fmi2SerializeFMUstate`
    /// and `fmi2DeSerializeFMUstate` are provided (false answered as for
    /// [`Model::CAN_GET_AND_SET_FMU_STATE`]). Serializing needs states to serialize: true
    /// requires [`Model::CAN_GET_AND_SET_FMU_STATE`] (a compile-time check of the model).
    const CAN_SERIALIZE_FMU_STATE: bool = true;

    /// The one declaration of the model's variables.
    fn variables() -> &'static [Variable<Self>];

    /// Enumeration types used by the variables (name, items as (name, value, description)).
    /// The model description types them as `Integer` (module docs, "Modes are Integers").
    fn enumerations() -> &'static [EnumerationType] {
        &[]
    }

    /// Called by `fmi2ExitInitializationMode`: check parameters together and set up internal
    /// state for the start time.
    fn initialize(&mut self, start_time: f64) -> Result<(), ModelError>;

    /// Computes the outputs at time `t` from parameters, inputs and state (no state change).
    /// The glue calls it lazily before a get that follows a set or a step. Because it changes
    /// no state, the glue refuses the get on any error (whatever its [`ErrorKind`]): the
    /// importer may correct the parameters or inputs and read again.
    fn calculate(&mut self, t: f64) -> Result<(), ModelError>;

    /// Advances the state from `t` to `t + h` with the inputs held. An error of kind
    /// [`ErrorKind::Refused`] promises that nothing was changed (the glue then keeps the
    /// instance usable); any other error moves the instance to the error state.
    fn do_step(&mut self, t: f64, h: f64) -> Result<StepOutcome, ModelError>;

    /// Reads the Real variables `vrs` into `out` (as long as each other) in one pass, where the
    /// model can do better than a getter call per value: the glue's fast path of
    /// `fmi2GetReal`, tried after [`Model::calculate`] and before the getters. It answers
    /// `true` with every value written, each bit for bit what its getter reads, or `false`
    /// with nothing promised of `out` (a reference it does not cover: the glue then reads
    /// every value through the getters). Default: `false`.
    fn read_reals(&self, _vrs: &[u32], _out: &mut [f64]) -> bool {
        false
    }

    /// The largest communication step [`Model::do_step`] accepts, in seconds, with the
    /// current parameters: [`MAX_INTERNAL_STEPS_PER_CALL`] internal steps for a model whose
    /// work grows with the step. The glue refuses a larger `communicationStepSize` before
    /// calling [`Model::do_step`]. Default: no bound (the work of a step does not depend on
    /// its size).
    fn max_step_size(&self) -> f64 {
        f64::INFINITY
    }

    /// First-order (or higher) time derivative of an output at the current communication point,
    /// `None` when the model does not provide it.
    fn output_derivative(&self, _value_reference: u32, _order: u32) -> Option<f64> {
        None
    }

    /// Messages to log as warnings after a step (the glue drains them after every
    /// `fmi2DoStep`; the step's status is unchanged).
    fn take_warnings(&mut self) -> Vec<String> {
        Vec::new()
    }

    /// Appends the state that is not a variable (integrators, latches) to `w`.
    fn save_internal(&self, _w: &mut StateWriter) {}

    /// Restores what [`Model::save_internal`] wrote.
    fn load_internal(&mut self, _r: &mut StateReader<'_>) -> Result<(), StateError> {
        Ok(())
    }

    /// Body of `documentation/index.html` (HTML), beyond the generated variable table.
    fn documentation() -> &'static str;
}

/// An enumeration type shared by mode variables: in the model description an `Integer`
/// `SimpleType` with the items in its description and in a vendor annotation (module docs,
/// "Modes are Integers").
#[derive(Debug, Clone, Copy)]
pub struct EnumerationType {
    /// The type's name (`declaredType` of its variables).
    pub name: &'static str,
    /// What it selects.
    pub description: &'static str,
    /// (name, value, description) of each item.
    pub items: &'static [(&'static str, i32, &'static str)],
}

/// How a variable's value is read from and written to the model struct.
pub enum Access<M> {
    /// A `Real`.
    Real(fn(&M) -> f64, fn(&mut M, f64)),
    /// An `Integer`.
    Integer(fn(&M) -> i32, fn(&mut M, i32)),
    /// A mode of an enumeration type (stored as an integer; the type is named in
    /// [`Variable::declared_type`]; an `Integer` in the model description).
    Enumeration(fn(&M) -> i32, fn(&mut M, i32)),
    /// A `Boolean`.
    Boolean(fn(&M) -> bool, fn(&mut M, bool)),
    /// A `String`.
    String(fn(&M) -> &str, fn(&mut M, &str)),
}

/// A start value, typed.
#[derive(Debug, Clone, PartialEq)]
pub enum Start {
    /// No start value (calculated variables).
    None,
    /// Real.
    Real(f64),
    /// Integer or enumeration.
    Integer(i32),
    /// Boolean.
    Boolean(bool),
    /// String.
    String(&'static str),
}

/// One variable of a model: everything the model description says about it, and its accessor.
pub struct Variable<M> {
    /// Name, e.g. `kneeAngleReference`.
    pub name: &'static str,
    /// Value reference: explicit and stable, never derived from field order.
    pub value_reference: u32,
    /// Description.
    pub description: &'static str,
    /// Causality.
    pub causality: Causality,
    /// Variability.
    pub variability: Variability,
    /// `initial`, when it is written explicitly.
    pub initial: Option<Initial>,
    /// Start value.
    pub start: Start,
    /// Unit (a name from [`unit_definition`]).
    pub unit: Option<&'static str>,
    /// Display unit (a display unit of that unit).
    pub display_unit: Option<&'static str>,
    /// Lower bound, enforced on set.
    pub min: Option<f64>,
    /// Upper bound, enforced on set.
    pub max: Option<f64>,
    /// `declaredType` for enumerations.
    pub declared_type: Option<&'static str>,
    /// For outputs: the inputs and parameters this variable depends on, by name; `None` means
    /// "all knowns" (the attribute is then omitted). `ModelStructure/Outputs` lists the inputs
    /// among them; `InitialUnknowns` the inputs and exact parameters, unless
    /// [`Variable::initial_on_all_knowns`] was set.
    pub depends_on: Option<&'static [&'static str]>,
    /// The initial value (in initialization mode) depends on every known: its
    /// `InitialUnknowns` entry omits `dependencies` (FMI 2.0 section 2.2.8: absent means all
    /// knowns), whatever [`Variable::depends_on`] says of communication points.
    pub initial_on_all_knowns: bool,
    /// A `Real` that only takes whole numbers: `fmi2SetReal` (and a restored FMU state) refuses
    /// a fraction, and the description says "an integer" (FMI 2.0 has no attribute for it).
    pub integer_valued: bool,
    /// Read/write access.
    pub access: Access<M>,
}

impl<M> Variable<M> {
    fn new(name: &'static str, value_reference: u32, access: Access<M>) -> Self {
        Self {
            name,
            value_reference,
            description: "",
            causality: Causality::Local,
            variability: Variability::Continuous,
            initial: None,
            start: Start::None,
            unit: None,
            display_unit: None,
            min: None,
            max: None,
            declared_type: None,
            depends_on: None,
            initial_on_all_knowns: false,
            integer_valued: false,
            access,
        }
    }

    /// A `Real` variable.
    pub fn real(name: &'static str, vr: u32, get: fn(&M) -> f64, set: fn(&mut M, f64)) -> Self {
        Self::new(name, vr, Access::Real(get, set))
    }
    /// An `Integer` variable.
    pub fn integer(name: &'static str, vr: u32, get: fn(&M) -> i32, set: fn(&mut M, i32)) -> Self {
        Self::new(name, vr, Access::Integer(get, set))
    }
    /// A mode: a variable of enumeration type `declared_type` (one of [`Model::enumerations`]),
    /// which the FMU refuses to set to a value that is no item. The model description declares
    /// it as an `Integer` (module docs, "Modes are Integers").
    pub fn enumeration(
        name: &'static str,
        vr: u32,
        declared_type: &'static str,
        get: fn(&M) -> i32,
        set: fn(&mut M, i32),
    ) -> Self {
        let mut v = Self::new(name, vr, Access::Enumeration(get, set));
        v.declared_type = Some(declared_type);
        v
    }
    /// A `Boolean` variable.
    pub fn boolean(
        name: &'static str,
        vr: u32,
        get: fn(&M) -> bool,
        set: fn(&mut M, bool),
    ) -> Self {
        Self::new(name, vr, Access::Boolean(get, set))
    }
    /// A `String` variable.
    pub fn string(name: &'static str, vr: u32, get: fn(&M) -> &str, set: fn(&mut M, &str)) -> Self {
        Self::new(name, vr, Access::String(get, set))
    }

    /// Sets the description.
    pub fn describe(mut self, description: &'static str) -> Self {
        self.description = description;
        self
    }
    /// A fixed parameter with this start value.
    pub fn parameter(mut self, start: Start) -> Self {
        self.causality = Causality::Parameter;
        self.variability = Variability::Fixed;
        self.initial = Some(Initial::Exact);
        self.start = start;
        self
    }
    /// A tunable parameter (may change between steps) with this start value.
    pub fn tunable(self, start: Start) -> Self {
        let mut v = self.parameter(start);
        v.variability = Variability::Tunable;
        v
    }
    /// An input with this start value (continuous for Real, discrete otherwise).
    pub fn input(mut self, start: Start) -> Self {
        self.causality = Causality::Input;
        self.variability = if matches!(self.access, Access::Real(..)) {
            Variability::Continuous
        } else {
            Variability::Discrete
        };
        self.start = start;
        self
    }
    /// An output computed by the model; `depends_on` names the inputs and parameters it depends
    /// on (`&[]` for none besides time and state).
    pub fn output(mut self, depends_on: &'static [&'static str]) -> Self {
        self.causality = Causality::Output;
        self.variability = if matches!(self.access, Access::Real(..)) {
            Variability::Continuous
        } else {
            Variability::Discrete
        };
        self.initial = Some(Initial::Calculated);
        self.depends_on = Some(depends_on);
        self
    }
    /// An output whose initial value depends on every known of initialization mode (a state
    /// built from the parameters: initial positions, calibrations, supply voltages), while at
    /// communication points it depends only on what [`Variable::output`] names: its
    /// `InitialUnknowns` entry omits `dependencies`, which FMI 2.0 reads as "all knowns"
    /// (conservative, and true without a second list of what the model computes from what).
    pub fn initial_on_all_knowns(mut self) -> Self {
        self.initial_on_all_knowns = true;
        self
    }
    /// A `Real` that only takes whole numbers (a count kept as a Real so parameter files that
    /// write `2000.0` keep working): `fmi2SetReal` refuses a fraction with fmi2Error, keeping the
    /// value, and the description ends with "; an integer".
    pub fn integer_valued(mut self) -> Self {
        self.integer_valued = true;
        self
    }
    /// A constant, local to the model: visible to importers, never settable.
    pub fn constant(mut self, value: Start) -> Self {
        self.causality = Causality::Local;
        self.variability = Variability::Constant;
        self.initial = Some(Initial::Exact);
        self.start = value;
        self
    }
    /// Marks a discrete-time Real output (changes only at communication points).
    pub fn discrete(mut self) -> Self {
        self.variability = Variability::Discrete;
        self
    }
    /// Sets the unit (and optionally display unit).
    pub fn unit(mut self, unit: &'static str) -> Self {
        self.unit = Some(unit);
        self
    }
    /// Sets the display unit.
    pub fn display(mut self, display_unit: &'static str) -> Self {
        self.display_unit = Some(display_unit);
        self
    }
    /// Sets the allowed range, enforced on set.
    pub fn range(mut self, min: f64, max: f64) -> Self {
        self.min = Some(min);
        self.max = Some(max);
        self
    }
    /// Sets the lower bound only.
    pub fn min(mut self, min: f64) -> Self {
        self.min = Some(min);
        self
    }

    /// The base type's name, as in `fmi2Get<Type>`.
    pub fn type_name(&self) -> &'static str {
        match self.access {
            Access::Real(..) => "Real",
            Access::Integer(..) | Access::Enumeration(..) => "Integer",
            Access::Boolean(..) => "Boolean",
            Access::String(..) => "String",
        }
    }

    /// Whether the model can be given a value for this variable in the instance's phase.
    pub fn settable(&self, phase: Phase) -> bool {
        match (self.causality, self.variability) {
            (_, Variability::Constant) => false,
            (Causality::Parameter, Variability::Fixed) => {
                matches!(phase, Phase::Instantiated | Phase::Initialization)
            }
            (Causality::Parameter, Variability::Tunable) => matches!(
                phase,
                Phase::Instantiated | Phase::Initialization | Phase::Stepping
            ),
            (Causality::Input, _) => matches!(
                phase,
                Phase::Instantiated | Phase::Initialization | Phase::Stepping
            ),
            _ => false,
        }
    }
}

/// The phase of an instance, as far as setting variables is concerned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// After `fmi2Instantiate`.
    Instantiated,
    /// Between `fmi2EnterInitializationMode` and `fmi2ExitInitializationMode`.
    Initialization,
    /// At a communication point between steps.
    Stepping,
}

/// A unit the models may use: its `BaseUnit` exponents/factor and display units.
pub fn unit_definition(name: &str) -> Option<md::Unit> {
    // (kg, m, s, A, rad) exponents; display units as (name, factor).
    let (kg, m, s, a, rad, display): (i32, i32, i32, i32, i32, &[(&str, f64)]) = match name {
        "rad" => (0, 0, 0, 0, 1, &[("deg", 180.0 / std::f64::consts::PI)]),
        "rad/s" => (0, 0, -1, 0, 1, &[("deg/s", 180.0 / std::f64::consts::PI)]),
        "rad/s2" => (0, 0, -2, 0, 1, &[("deg/s2", 180.0 / std::f64::consts::PI)]),
        "rad/s3" => (0, 0, -3, 0, 1, &[]),
        "s" => (0, 0, 1, 0, 0, &[("ms", 1e3)]),
        "Hz" => (0, 0, -1, 0, 0, &[]),
        "N.m" => (1, 2, -2, 0, 0, &[]),
        "N.m/s" => (1, 2, -3, 0, 0, &[]),
        "N.m/rad" => (1, 2, -2, 0, -1, &[]),
        "N.m.s/rad" => (1, 2, -1, 0, -1, &[]),
        "kg.m2" => (1, 2, 0, 0, 0, &[]),
        "A" => (0, 0, 0, 1, 0, &[]),
        "V" => (1, 2, -3, -1, 0, &[]),
        "V/A" | "Ohm" => (1, 2, -3, -2, 0, &[]),
        "s/rad" => (0, 0, 1, 0, -1, &[]),
        "H" => (1, 2, -2, -2, 0, &[]),
        "N.m/A" => (1, 2, -2, -1, 0, &[]),
        "V.s/rad" => (1, 2, -2, -1, -1, &[]),
        "W" => (1, 2, -3, 0, 0, &[]),
        "J" => (1, 2, -2, 0, 0, &[]),
        _ => return None,
    };
    let nz = |e: i32| (e != 0).then_some(e);
    Some(md::Unit {
        name: name.to_string(),
        base_unit: Some(md::BaseUnit {
            kg: nz(kg),
            m: nz(m),
            s: nz(s),
            a: nz(a),
            rad: nz(rad),
            ..Default::default()
        }),
        display_units: display
            .iter()
            .map(|(n, f)| md::DisplayUnit {
                name: (*n).to_string(),
                factor: Some(*f),
                offset: None,
            })
            .collect(),
    })
}

/// The log categories every kneebench FMU declares, with their meaning.
pub const LOG_CATEGORIES: &[(&str, &str)] = &[
    (
        "logEvents",
        "Events inside a step: clutch, stick/slip, sweep stages",
    ),
    (
        "logStatusWarning",
        "Messages logged with status fmi2Warning",
    ),
    (
        "logStatusDiscard",
        "Messages logged with status fmi2Discard",
    ),
    ("logStatusError", "Messages logged with status fmi2Error"),
    ("logStatusFatal", "Messages logged with status fmi2Fatal"),
    ("logCalls", "Every FMI function call with its arguments"),
];

/// Builds the model description of `M` (the `guid` is filled in: a hash of the rest).
pub fn model_description<M: Model>() -> md::ModelDescription {
    model_description_with_xml::<M>().0
}

/// [`model_description()`] and its `modelDescription.xml`, the XML written once: the GUID hashes
/// the XML with an empty `guid`, which is then filled in place (the attribute is the root's
/// only `guid`, and a GUID needs no escaping).
pub fn model_description_with_xml<M: Model>() -> (md::ModelDescription, String) {
    let mut desc = description_without_guid::<M>();
    let unsigned = desc.to_xml();
    desc.guid = guid_of_xml(&unsigned);
    let xml = unsigned.replacen(" guid=\"\"", &format!(" guid=\"{}\"", desc.guid), 1);
    (desc, xml)
}

/// The GUID of a description from its XML written with an empty `guid`: SHA-256 of it,
/// shaped as a UUID.
fn guid_of_xml(xml: &str) -> String {
    let digest = Sha256::digest(xml.as_bytes());
    let h: Vec<String> = digest.iter().take(16).map(|b| format!("{b:02x}")).collect();
    let h = h.concat();
    format!(
        "{{{}-{}-{}-{}-{}}}",
        &h[0..8],
        &h[8..12],
        &h[12..16],
        &h[16..20],
        &h[20..32]
    )
}

fn start_attr_real(start: &Start) -> Option<f64> {
    match start {
        Start::Real(v) => Some(*v),
        _ => None,
    }
}

/// The enumeration type of a mode variable (declared with [`Variable::enumeration`]).
fn enumeration_of<M: Model>(v: &Variable<M>) -> &'static EnumerationType {
    let name = v.declared_type.unwrap_or_default();
    M::enumerations()
        .iter()
        .find(|e| e.name == name)
        .unwrap_or_else(|| {
            panic!(
                "{}: {} has no enumeration type {name}",
                M::IDENTIFIER,
                v.name
            )
        })
}

/// The Integer bounds of a mode type: its smallest and largest item.
fn item_bounds(e: &EnumerationType) -> md::IntegerAttributes {
    md::IntegerAttributes {
        quantity: None,
        min: e.items.iter().map(|i| i.1).min(),
        max: e.items.iter().map(|i| i.1).max(),
    }
}

/// `description` followed by the items' values and names: `Friction law (0 = Off, 1 = ...)`.
fn with_item_list(description: &str, e: &EnumerationType) -> String {
    let list = e
        .items
        .iter()
        .map(|(n, v, _)| format!("{v} = {n}"))
        .collect::<Vec<_>>()
        .join(", ");
    if description.is_empty() {
        list
    } else {
        format!("{description} ({list})")
    }
}

/// The description of `v` in the model description and the documentation: its own text, with
/// the items of a mode listed, or "; an integer" after an integer-valued Real's.
fn full_description<M: Model>(v: &Variable<M>) -> Option<String> {
    match &v.access {
        Access::Enumeration(..) => Some(with_item_list(v.description, enumeration_of::<M>(v))),
        Access::Real(..) if v.integer_valued => Some(if v.description.is_empty() {
            INTEGER_NOTE.trim_start_matches("; ").to_string()
        } else {
            format!("{}{INTEGER_NOTE}", v.description)
        }),
        _ => (!v.description.is_empty()).then(|| v.description.to_string()),
    }
}

/// What the description of an integer-valued Real ([`Variable::integer_valued`]) ends with:
/// the model-description crate's note, by which the harness reads it back, so the two are one.
pub use md::INTEGER_NOTE;

fn description_without_guid<M: Model>() -> md::ModelDescription {
    // Checked when the model is compiled: serializing needs states to serialize.
    const {
        assert!(
            M::CAN_GET_AND_SET_FMU_STATE || !M::CAN_SERIALIZE_FMU_STATE,
            "canSerializeFMUstate needs canGetAndSetFMUstate"
        )
    };
    let vars = M::variables();
    let index_of = |name: &str| -> u32 {
        vars.iter()
            .position(|v| v.name == name)
            .map(|i| i as u32 + 1)
            .unwrap_or_else(|| panic!("{}: dependency on unknown variable {name}", M::IDENTIFIER))
    };

    let mut units: BTreeSet<&str> = BTreeSet::new();
    let mut model_variables = Vec::with_capacity(vars.len());
    for v in vars {
        if let Some(u) = v.unit {
            units.insert(u);
        }
        let kind = match &v.access {
            Access::Real(..) => md::VariableKind::Real {
                declared_type: None,
                attributes: md::RealAttributes {
                    unit: v.unit.map(str::to_string),
                    display_unit: v.display_unit.map(str::to_string),
                    min: v.min,
                    max: v.max,
                    ..Default::default()
                },
                start: start_attr_real(&v.start),
                derivative: None,
                reinit: None,
            },
            Access::Integer(..) => md::VariableKind::Integer {
                declared_type: None,
                attributes: md::IntegerAttributes {
                    quantity: None,
                    min: v.min.map(|x| x as i32),
                    max: v.max.map(|x| x as i32),
                },
                start: match v.start {
                    Start::Integer(i) => Some(i),
                    _ => None,
                },
            },
            // A mode: an Integer of its Integer type (module docs, "Modes are Integers").
            Access::Enumeration(..) => {
                let e = enumeration_of::<M>(v);
                md::VariableKind::Integer {
                    declared_type: Some(e.name.to_string()),
                    attributes: item_bounds(e),
                    start: match v.start {
                        Start::Integer(i) => Some(i),
                        _ => None,
                    },
                }
            }
            Access::Boolean(..) => md::VariableKind::Boolean {
                declared_type: None,
                start: match v.start {
                    Start::Boolean(b) => Some(b),
                    _ => None,
                },
            },
            Access::String(..) => md::VariableKind::String {
                declared_type: None,
                start: match v.start {
                    Start::String(s) => Some(s.to_string()),
                    _ => None,
                },
            },
        };
        let description = full_description(v);
        model_variables.push(md::ScalarVariable {
            name: v.name.to_string(),
            value_reference: v.value_reference,
            description,
            causality: Some(v.causality),
            variability: Some(v.variability),
            initial: v.initial,
            can_handle_multiple_set_per_time_instant: None,
            kind,
            annotations: Vec::new(),
        });
    }

    // ModelStructure: at communication points outputs depend only on inputs (the knowns of
    // co-simulation); during initialization also on parameters given with initial="exact".
    let mut outputs = Vec::new();
    let mut initial_unknowns = Vec::new();
    for (i, v) in vars.iter().enumerate() {
        let index = i as u32 + 1;
        let deps = v.depends_on.map(|names| {
            let mut idx: Vec<u32> = names.iter().map(|n| index_of(n)).collect();
            idx.sort_unstable();
            idx
        });
        let only = |pred: &dyn Fn(&Variable<M>) -> bool| {
            deps.as_ref().map(|d| {
                d.iter()
                    .copied()
                    .filter(|&j| pred(&vars[j as usize - 1]))
                    .collect::<Vec<u32>>()
            })
        };
        let kinds = |d: &Option<Vec<u32>>| {
            d.as_ref()
                .map(|d| vec![md::DependencyKind::Dependent; d.len()])
        };
        if v.causality == Causality::Output {
            let d = only(&|k| k.causality == Causality::Input);
            outputs.push(md::Unknown {
                index,
                dependencies_kind: kinds(&d),
                dependencies: d,
            });
        }
        let is_initial_unknown = (v.causality == Causality::Output
            && matches!(v.initial, Some(Initial::Calculated) | Some(Initial::Approx)))
            || v.causality == Causality::CalculatedParameter;
        if is_initial_unknown {
            let d = if v.initial_on_all_knowns {
                None
            } else {
                only(&|k| {
                    k.causality == Causality::Input
                        || (k.causality == Causality::Parameter
                            && k.initial == Some(Initial::Exact))
                })
            };
            initial_unknowns.push(md::Unknown {
                index,
                dependencies_kind: kinds(&d),
                dependencies: d,
            });
        }
    }

    let (start, stop, step) = M::DEFAULT_EXPERIMENT;
    md::ModelDescription {
        fmi_version: "2.0".into(),
        model_name: M::IDENTIFIER.into(),
        guid: String::new(),
        description: Some(M::DESCRIPTION.into()),
        author: Some(AUTHOR.into()),
        version: Some(VERSION.into()),
        copyright: Some(format!("Copyright (c) {AUTHOR}")),
        license: Some(LICENSE.into()),
        generation_tool: Some(GENERATION_TOOL.into()),
        generation_date_and_time: None,
        variable_naming_convention: Some(md::VariableNamingConvention::Flat),
        number_of_event_indicators: Some(0),
        model_exchange: None,
        co_simulation: Some(md::CoSimulation {
            model_identifier: M::IDENTIFIER.into(),
            needs_execution_tool: Some(false),
            can_handle_variable_communication_step_size: Some(true),
            can_interpolate_inputs: Some(false),
            max_output_derivative_order: Some(M::MAX_OUTPUT_DERIVATIVE_ORDER),
            can_run_asynchronuously: Some(false),
            can_be_instantiated_only_once_per_process: Some(false),
            can_not_use_memory_management_functions: Some(true),
            can_get_and_set_fmu_state: Some(M::CAN_GET_AND_SET_FMU_STATE),
            can_serialize_fmu_state: Some(M::CAN_SERIALIZE_FMU_STATE),
            provides_directional_derivative: Some(false),
            source_files: Vec::new(),
        }),
        unit_definitions: units
            .iter()
            .map(|u| {
                unit_definition(u)
                    .unwrap_or_else(|| panic!("{}: unit {u} is not defined", M::IDENTIFIER))
            })
            .collect(),
        type_definitions: M::enumerations()
            .iter()
            .map(|e| md::SimpleType {
                name: e.name.into(),
                description: Some(with_item_list(e.description, e)),
                kind: md::SimpleTypeKind::Integer(item_bounds(e)),
            })
            .collect(),
        log_categories: LOG_CATEGORIES
            .iter()
            .map(|(n, d)| md::LogCategory {
                name: (*n).into(),
                description: Some((*d).into()),
            })
            .collect(),
        default_experiment: Some(md::DefaultExperiment {
            start_time: Some(start),
            stop_time: Some(stop),
            tolerance: None,
            step_size: Some(step),
        }),
        vendor_annotations: if M::enumerations().is_empty() {
            Vec::new()
        } else {
            vec![md::items::items_annotation(
                &M::enumerations()
                    .iter()
                    .map(|e| md::IntegerItems {
                        type_name: e.name.into(),
                        items: e
                            .items
                            .iter()
                            .map(|(n, v, d)| md::EnumerationItem {
                                name: (*n).into(),
                                value: *v,
                                description: Some((*d).into()),
                            })
                            .collect(),
                    })
                    .collect::<Vec<_>>(),
            )]
        },
        model_variables,
        model_structure: md::ModelStructure {
            outputs,
            derivatives: Vec::new(),
            initial_unknowns,
        },
    }
}

/// The `documentation/index.html` of `M`: the model's own text plus a generated table of its
/// variables (from the same declaration as everything else).
pub fn documentation_html<M: Model>() -> String {
    let desc = model_description::<M>();
    let mut html = String::new();
    let _ = write!(
        html,
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>{id}</title>\n\
         <style>body{{font-family:sans-serif;max-width:60em;margin:2em auto;line-height:1.4}}\
         table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:2px 6px;text-align:left}}\
         code{{background:#f4f4f4}}</style>\n</head>\n<body>\n<h1>{id}</h1>\n<p>{d}</p>\n",
        id = M::IDENTIFIER,
        d = escape_html(M::DESCRIPTION)
    );
    html.push_str(M::documentation());
    html.push_str("\n<h2>Variables</h2>\n<table>\n<tr><th>Name</th><th>VR</th><th>Causality</th><th>Variability</th><th>Type</th><th>Start</th><th>Unit</th><th>Range</th><th>Description</th></tr>\n");
    for v in M::variables() {
        let start = match &v.start {
            Start::None => String::new(),
            Start::Real(x) => format!("{x}"),
            Start::Integer(i) => format!("{i}"),
            Start::Boolean(b) => format!("{b}"),
            Start::String(s) => escape_html(s),
        };
        let range = match (v.min, v.max) {
            (None, None) => String::new(),
            (lo, hi) => format!(
                "[{}, {}]",
                lo.map_or("-inf".into(), |x| x.to_string()),
                hi.map_or("inf".into(), |x| x.to_string())
            ),
        };
        let _ = writeln!(
            html,
            "<tr><td><code>{}</code></td><td>{}</td><td>{:?}</td><td>{:?}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            v.name,
            v.value_reference,
            v.causality,
            v.variability,
            match v.declared_type {
                Some(t) => format!("Integer ({t})"),
                None => v.type_name().to_string(),
            },
            start,
            v.unit.unwrap_or(""),
            range,
            escape_html(&full_description(v).unwrap_or_default())
        );
    }
    html.push_str("</table>\n");
    if !M::enumerations().is_empty() {
        html.push_str(
            "<h2>Modes</h2>\n<p>Each mode is an FMI <code>Integer</code> parameter of the type \
             named in the table, which takes the values of its items below (anything else is \
             refused). They are Integers, not Enumerations, because libcosim and other importers \
             ignore FMI 2.0 Enumeration variables: a tool without Enumeration support can still \
             set them, by value. kneebench also takes an item's name \
             (<code>--param plant.configuration=DA</code>).</p>\n",
        );
    }
    for e in M::enumerations() {
        let _ = writeln!(
            html,
            "<h3>{}</h3>\n<p>{}</p>\n<ul>",
            e.name,
            escape_html(e.description)
        );
        for (n, val, d) in e.items {
            let _ = writeln!(html, "<li><code>{val}</code> {n}: {}</li>", escape_html(d));
        }
        html.push_str("</ul>\n");
    }
    let fmu_state = match (M::CAN_GET_AND_SET_FMU_STATE, M::CAN_SERIALIZE_FMU_STATE) {
        (true, true) => "get/set and serialize FMU state",
        (true, false) => "get/set FMU state (not serialized)",
        _ => {
            "no FMU state (canGetAndSetFMUstate and canSerializeFMUstate false: the FMU state functions answer fmi2Error)"
        }
    };
    let _ = write!(
        html,
        "<h2>Interface facts</h2>\n<ul>\n<li>GUID: <code>{}</code></li>\n<li>FMI 2.0 co-simulation; variable communication step size; \
         {fmu_state}; output derivatives up to order {}.</li>\n<li>Generated by {}; license {}.</li>\n</ul>\n</body>\n</html>\n",
        desc.guid,
        M::MAX_OUTPUT_DERIVATIVE_ORDER,
        GENERATION_TOOL,
        LICENSE
    );
    html
}

fn escape_html(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// Renders the `//!` documentation of a Rust source file as HTML, so a model's documentation
/// page comes from the same text as its API docs. Handles what those docs use: `#` headings,
/// paragraphs, `*`/`-` lists, fenced code blocks, `inline code`, **bold**, [links](...) as
/// plain text.
pub fn module_doc_html(source: &str) -> String {
    let lines: Vec<&str> = source
        .lines()
        .take_while(|l| l.starts_with("//!") || l.trim().is_empty())
        .filter_map(|l| l.strip_prefix("//!"))
        .map(|l| l.strip_prefix(' ').unwrap_or(l))
        .collect();
    let mut html = String::new();
    let mut in_code = false;
    let mut in_list = false;
    let mut paragraph = String::new();
    let flush = |html: &mut String, paragraph: &mut String, in_list: bool| {
        if !paragraph.trim().is_empty() {
            let tag = if in_list { "li" } else { "p" };
            let _ = writeln!(html, "<{tag}>{}</{tag}>", inline_markdown(paragraph.trim()));
        }
        paragraph.clear();
    };
    for line in lines {
        if line.starts_with("```") {
            flush(&mut html, &mut paragraph, in_list);
            html.push_str(if in_code { "</pre>\n" } else { "<pre>" });
            in_code = !in_code;
            continue;
        }
        if in_code {
            html.push_str(&escape_html(line));
            html.push('\n');
            continue;
        }
        let trimmed = line.trim_start();
        if let Some(rest) = trimmed.strip_prefix('#') {
            flush(&mut html, &mut paragraph, in_list);
            if in_list {
                html.push_str("</ul>\n");
                in_list = false;
            }
            let level = 1 + rest.chars().take_while(|c| *c == '#').count();
            let text = rest.trim_start_matches('#').trim();
            let level = (level + 1).min(6);
            let _ = writeln!(html, "<h{level}>{}</h{level}>", inline_markdown(text));
        } else if let Some(item) = trimmed
            .strip_prefix("* ")
            .or_else(|| trimmed.strip_prefix("- "))
        {
            flush(&mut html, &mut paragraph, in_list);
            if !in_list {
                html.push_str("<ul>\n");
                in_list = true;
            }
            paragraph.push_str(item);
        } else if trimmed.is_empty() {
            flush(&mut html, &mut paragraph, in_list);
            if in_list {
                html.push_str("</ul>\n");
                in_list = false;
            }
        } else {
            paragraph.push(' ');
            paragraph.push_str(trimmed);
        }
    }
    flush(&mut html, &mut paragraph, in_list);
    if in_list {
        html.push_str("</ul>\n");
    }
    if in_code {
        html.push_str("</pre>\n");
    }
    html
}

/// `code`, **bold** and [text](target) of one line of Markdown, HTML-escaped.
fn inline_markdown(text: &str) -> String {
    let escaped = escape_html(text);
    let mut out = String::new();
    let mut code = false;
    let mut bold = false;
    let mut chars = escaped.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '`' => {
                out.push_str(if code { "</code>" } else { "<code>" });
                code = !code;
            }
            '*' if !code && chars.peek() == Some(&'*') => {
                chars.next();
                out.push_str(if bold { "</b>" } else { "<b>" });
                bold = !bold;
            }
            '[' if !code => {}
            ']' if !code && chars.peek() == Some(&'(') => {
                // Drop the link target: intra-doc links mean nothing in the FMU.
                for c in chars.by_ref() {
                    if c == ')' {
                        break;
                    }
                }
            }
            _ => out.push(c),
        }
    }
    if code {
        out.push_str("</code>");
    }
    if bold {
        out.push_str("</b>");
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::models::gait::GaitReference;

    #[test]
    fn the_single_pass_description_equals_the_two_pass_one() {
        fn check<M: Model>() {
            let (desc, xml) = model_description_with_xml::<M>();
            // Two passes: the description without GUID, its XML hashed, the GUID set, the
            // XML written again.
            let mut two_pass = description_without_guid::<M>();
            two_pass.guid = guid_of_xml(&two_pass.to_xml());
            assert_eq!(desc, two_pass, "{}", M::IDENTIFIER);
            assert_eq!(xml, two_pass.to_xml(), "{}", M::IDENTIFIER);
        }
        check::<GaitReference>();
        check::<crate::models::bench_plant::BenchPlantModel>();
        check::<crate::models::bench_hardware::BenchHardwareModel>();
        check::<crate::models::pid::PidController>();
        check::<crate::models::impedance::ImpedanceController>();
        check::<crate::models::clutch_scheduler::ClutchScheduler>();
    }

    #[test]
    fn every_model_description_passes_the_semantic_checks_and_parses_back() {
        for entry in crate::MODELS.iter() {
            let info = entry.info();
            let problems = info.description.check();
            assert!(problems.is_empty(), "{}: {problems:?}", entry.identifier);
            let parsed = md::ModelDescription::from_xml(&info.xml).unwrap();
            assert_eq!(parsed, info.description);
            // The XML with the GUID filled in place is the description's own XML.
            assert_eq!(info.xml, info.description.to_xml(), "{}", entry.identifier);
            assert_eq!(
                crate::registry::find_by_guid(&info.guid)
                    .unwrap()
                    .identifier,
                entry.identifier
            );
        }
    }

    #[test]
    fn every_mode_is_an_integer_with_its_items_named() {
        fn check<M: Model>() -> usize {
            let d = model_description::<M>();
            assert!(
                d.model_variables
                    .iter()
                    .all(|v| !matches!(v.kind, md::VariableKind::Enumeration { .. })),
                "{}: an Enumeration variable",
                M::IDENTIFIER
            );
            assert!(
                d.type_definitions
                    .iter()
                    .all(|t| !matches!(t.kind, md::SimpleTypeKind::Enumeration { .. })),
                "{}: an Enumeration type",
                M::IDENTIFIER
            );
            let mut modes = 0;
            for v in M::variables() {
                let Access::Enumeration(..) = v.access else {
                    continue;
                };
                modes += 1;
                let e = M::enumerations()
                    .iter()
                    .find(|e| Some(e.name) == v.declared_type)
                    .unwrap();
                let var = d.variable_by_name(v.name).unwrap();
                let md::VariableKind::Integer {
                    declared_type,
                    attributes,
                    ..
                } = &var.kind
                else {
                    panic!("{}.{} is not an Integer", M::IDENTIFIER, v.name);
                };
                assert_eq!(declared_type.as_deref(), Some(e.name));
                let mut values: Vec<i32> = e.items.iter().map(|i| i.1).collect();
                assert_eq!(attributes.min, values.iter().copied().min());
                assert_eq!(attributes.max, values.iter().copied().max());
                // The items are contiguous, so [min, max] is exactly the set of items: an
                // importer that keeps to the bounds sets an item.
                values.sort_unstable();
                assert!(
                    values.windows(2).all(|w| w[1] == w[0] + 1),
                    "{}: {values:?}",
                    e.name
                );
                let description = var.description.as_deref().unwrap();
                let ty = d.type_definition(e.name).unwrap();
                for (n, value, _) in e.items {
                    let named = format!("{value} = {n}");
                    assert!(description.contains(&named), "{description}");
                    assert!(ty.description.as_deref().unwrap().contains(&named));
                }
                let (type_name, items) = d.items_of(var).unwrap();
                assert_eq!(type_name, e.name);
                let want: Vec<(String, i32, String)> = e
                    .items
                    .iter()
                    .map(|(n, v, d)| (n.to_string(), *v, d.to_string()))
                    .collect();
                let got: Vec<(String, i32, String)> = items
                    .into_iter()
                    .map(|i| (i.name, i.value, i.description.unwrap()))
                    .collect();
                assert_eq!(got, want, "{}.{}", M::IDENTIFIER, v.name);
            }
            modes
        }
        let modes = check::<GaitReference>()
            + check::<crate::models::bench_plant::BenchPlantModel>()
            + check::<crate::models::bench_hardware::BenchHardwareModel>()
            + check::<crate::models::pid::PidController>()
            + check::<crate::models::impedance::ImpedanceController>()
            + check::<crate::models::clutch_scheduler::ClutchScheduler>();
        assert!(modes >= 15, "{modes} modes");
        // The plant's configuration, as an importer without Enumeration support reads it.
        let d = model_description::<crate::models::bench_plant::BenchPlantModel>();
        let xml = d.to_xml();
        let at = xml.find("name=\"configuration\"").unwrap();
        let var = &xml[xml[..at].rfind("<ScalarVariable").unwrap()..];
        let var = &var[..var.find("</ScalarVariable>").unwrap()];
        assert!(
            var.contains("description=\"Actuator configuration: DA, SEA or CSEA (0 = DA, 1 = SEA, 2 = CSEA)\""),
            "{var}"
        );
        assert!(
            var.contains(
                "<Integer declaredType=\"Configuration\" min=\"0\" max=\"2\" start=\"1\"/>"
            ),
            "{var}"
        );
    }

    #[test]
    fn declaration_drives_the_model_structure() {
        let d = model_description::<GaitReference>();
        let outputs: Vec<&str> = d
            .model_variables
            .iter()
            .filter(|v| v.causality == Some(Causality::Output))
            .map(|v| v.name.as_str())
            .collect();
        assert_eq!(d.model_structure.outputs.len(), outputs.len());
        // The gait has no inputs: its outputs depend on none at communication points.
        for u in &d.model_structure.outputs {
            assert_eq!(u.dependencies.as_deref(), Some(&[][..]));
        }
        // At initialization they depend on the parameters.
        let period = d.variable_index("gaitPeriod").unwrap() as u32;
        for u in &d.model_structure.initial_unknowns {
            assert!(u.dependencies.as_ref().unwrap().contains(&period));
        }
        // Units and display units come from the unit table.
        let rad = d.unit_definitions.iter().find(|u| u.name == "rad").unwrap();
        assert_eq!(rad.display_units[0].name, "deg");
    }

    #[test]
    fn guid_is_a_hash_of_the_description() {
        let d = description_without_guid::<GaitReference>();
        let g = guid_of_xml(&d.to_xml());
        assert_eq!(g, model_description::<GaitReference>().guid);
        assert_eq!(g.len(), 38);
        let mut changed = d.clone();
        changed.model_variables[0].description = Some("changed".into());
        assert_ne!(
            guid_of_xml(&changed.to_xml()),
            g,
            "any change of a variable changes the GUID"
        );
        let mut renamed = d.clone();
        renamed.model_variables[0].value_reference += 1000;
        assert_ne!(guid_of_xml(&renamed.to_xml()), g);
    }

    #[test]
    fn value_references_are_unique_per_type() {
        for entry in crate::MODELS.iter() {
            let d = &entry.info().description;
            let mut seen = std::collections::HashSet::new();
            for v in &d.model_variables {
                assert!(
                    seen.insert((v.kind.base_type(), v.value_reference)),
                    "{}: duplicate value reference {}",
                    entry.identifier,
                    v.value_reference
                );
            }
        }
    }

    #[test]
    fn module_docs_render_as_html() {
        let src = "//! # Title\n//!\n//! Text with `code` and **bold** and [link](x).\n//!\n//! * one\n//! * two\n//!\n//! ```text\n//! a < b\n//! ```\nfn main() {}\n";
        let html = module_doc_html(src);
        assert_eq!(
            html,
            "<h2>Title</h2>\n<p>Text with <code>code</code> and <b>bold</b> and link.</p>\n<ul>\n<li>one</li>\n<li>two</li>\n</ul>\n<pre>a &lt; b\n</pre>\n"
        );
    }
}
