//! One FMU instance: the call-sequence state machine of FMI 2.0 co-simulation, get/set by value
//! reference from the model's declaration, stepping, and FMU states.
//!
//! Error policy (documented in every FMU's page): a call that is not allowed in the current
//! state, or that carries a bad argument (unknown value reference, NaN, a value outside
//! min/max, a variable that may not be set now), answers `fmi2Error` with a log line and
//! changes nothing, so the importer loses nothing and may correct the call. So does a model
//! error that left the model unchanged: parameters that do not fit together (found when the
//! outputs are computed before a get, or at a step: parameters are set one at a time, so an
//! inconsistent set in between is legitimate), rejected inputs, a step outside a sample grid's
//! exact range ([`crate::model::ErrorKind::Refused`]). A failure of the model's own computation after it
//! changed its state answers `fmi2Error` and moves the instance to the error state.

use std::ffi::CString;
use std::panic::{AssertUnwindSafe, catch_unwind};

use super::logging::{Category, Logger};
use super::step_args;
use super::types::{fmi2Boolean, fmi2Status, fmi2String};
use super::value_tables::{
    BooleanGetter, BooleanSetter, IntegerGetter, RealGetter, RealSetter, boolean_getter_table,
    boolean_setter_table, integer_getter_table, phase_index, real_getter_table, real_setter_table,
    settable_phases,
};
use crate::model::{
    Access, Model, Phase, StateError, StateReader, StateWriter, StepOutcome, Variable,
};
use crate::registry::ModelInfo;
use model_description::num::num;

use fmi2Status::{fmi2Discard, fmi2Error, fmi2OK, fmi2Warning};

/// The states of the FMI 2.0 co-simulation state machine (standard, section 4.2.4).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum State {
    /// After `fmi2Instantiate` or `fmi2Reset`.
    Instantiated = 0,
    /// Between enter and exit initialization mode.
    InitializationMode = 1,
    /// At a communication point, ready to step.
    StepComplete = 2,
    /// After `fmi2DoStep` answered `fmi2Discard`.
    StepFailed = 3,
    /// After `fmi2CancelStep` (never reached: steps are synchronous).
    StepCanceled = 4,
    /// After `fmi2Terminate`.
    Terminated = 5,
    /// After a model computation failed.
    Error = 6,
}

impl State {
    fn from_u8(v: u8) -> Option<State> {
        Some(match v {
            0 => State::Instantiated,
            1 => State::InitializationMode,
            2 => State::StepComplete,
            3 => State::StepFailed,
            4 => State::StepCanceled,
            5 => State::Terminated,
            6 => State::Error,
            _ => return None,
        })
    }
    fn bit(self) -> u16 {
        1 << self as u16
    }
}

const INST: u16 = 1 << State::Instantiated as u16;
const INIT: u16 = 1 << State::InitializationMode as u16;
const DONE: u16 = 1 << State::StepComplete as u16;
const FAIL: u16 = 1 << State::StepFailed as u16;
const CANC: u16 = 1 << State::StepCanceled as u16;
const TERM: u16 = 1 << State::Terminated as u16;
const ERR: u16 = 1 << State::Error as u16;

/// Every function the call-sequence table governs, with the states it is allowed in
/// (the table of the FMI 2.0 standard, section 4.2.4, for co-simulation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Func {
    /// `fmi2SetDebugLogging`.
    SetDebugLogging,
    /// `fmi2SetupExperiment`.
    SetupExperiment,
    /// `fmi2EnterInitializationMode`.
    EnterInitializationMode,
    /// `fmi2ExitInitializationMode`.
    ExitInitializationMode,
    /// `fmi2Terminate`.
    Terminate,
    /// `fmi2Reset`.
    Reset,
    /// `fmi2Get{Real,Integer,Boolean,String}`.
    Get,
    /// `fmi2Set{Real,Integer,Boolean,String}`.
    Set,
    /// `fmi2{Get,Set,Free}FMUstate` (provided when the model declares
    /// `canGetAndSetFMUstate`).
    FmuState,
    /// `fmi2SerializedFMUstateSize`, `fmi2SerializeFMUstate`, `fmi2DeSerializeFMUstate`
    /// (provided when the model declares `canSerializeFMUstate`).
    SerializeFmuState,
    /// `fmi2GetDirectionalDerivative`.
    GetDirectionalDerivative,
    /// `fmi2SetRealInputDerivatives`.
    SetRealInputDerivatives,
    /// `fmi2GetRealOutputDerivatives`.
    GetRealOutputDerivatives,
    /// `fmi2DoStep`.
    DoStep,
    /// `fmi2CancelStep`.
    CancelStep,
    /// `fmi2Get*Status`.
    GetStatus,
}

impl Func {
    /// States in which the function may be called.
    pub fn allowed(self) -> u16 {
        match self {
            Func::SetDebugLogging | Func::Reset | Func::FmuState | Func::SerializeFmuState => {
                INST | INIT | DONE | FAIL | CANC | TERM | ERR
            }
            Func::SetupExperiment | Func::EnterInitializationMode => INST,
            Func::ExitInitializationMode => INIT,
            Func::Terminate => DONE | FAIL,
            Func::Get | Func::GetDirectionalDerivative => INIT | DONE | FAIL | CANC | TERM | ERR,
            Func::Set | Func::SetRealInputDerivatives => INST | INIT | DONE,
            Func::GetRealOutputDerivatives => DONE | FAIL | CANC | TERM | ERR,
            Func::DoStep => DONE,
            // Only in "step in progress", which a synchronous slave never enters.
            Func::CancelStep => 0,
            Func::GetStatus => DONE | FAIL | TERM,
        }
    }
}

fn describe_states(mask: u16) -> String {
    let names = [
        "instantiated",
        "initializationMode",
        "stepComplete",
        "stepFailed",
        "stepCanceled",
        "terminated",
        "error",
    ];
    let allowed: Vec<&str> = names
        .iter()
        .enumerate()
        .filter(|(i, _)| mask & (1 << i) != 0)
        .map(|(_, n)| *n)
        .collect();
    if allowed.is_empty() {
        "no state this FMU reaches (no asynchronous steps)".into()
    } else {
        allowed.join(" or ")
    }
}

fn state_name(s: State) -> &'static str {
    match s {
        State::Instantiated => "instantiated",
        State::InitializationMode => "initializationMode",
        State::StepComplete => "stepComplete",
        State::StepFailed => "stepFailed",
        State::StepCanceled => "stepCanceled",
        State::Terminated => "terminated",
        State::Error => "error",
    }
}

/// Relative tolerance on communication points: importers send values such as
/// 0.20000000000000107 for 0.2.
pub const TIME_TOLERANCE: f64 = 1e-9;

pub(super) fn same_time(a: f64, b: f64) -> bool {
    (a - b).abs() <= TIME_TOLERANCE * a.abs().max(b.abs()).max(1.0)
}

/// The instance operations the C functions call, independent of the model type.
///
/// The get, set and `do_step` methods check the call sequence themselves (with
/// [`FmiInstance::allow`], statically dispatched and inlined there), so the per-step calls pay
/// one dynamic dispatch, not two; the export layer checks the other functions before calling.
/// They also never unwind: a panic inside (a model's) is caught, logged and answered with
/// `fmi2Error`, and the instance enters the error state, so the export layer calls them
/// directly, without a `catch_unwind` of its own.
pub trait FmiInstance: Send {
    /// The logger (for messages the export layer produces itself).
    fn logger(&self) -> &Logger;
    /// Checks that `func` (named `name`) may be called now: provided (the model description
    /// declares its capability) and allowed in this state; logs why not.
    fn allow(&self, func: Func, name: &str) -> bool;
    /// `fmi2SetDebugLogging`.
    fn set_debug_logging(&mut self, on: bool, categories: &[&str]) -> fmi2Status;
    /// `fmi2SetupExperiment`.
    fn setup_experiment(
        &mut self,
        start: f64,
        stop: Option<f64>,
        tolerance: Option<f64>,
    ) -> fmi2Status;
    /// `fmi2EnterInitializationMode`.
    fn enter_initialization_mode(&mut self) -> fmi2Status;
    /// `fmi2ExitInitializationMode`.
    fn exit_initialization_mode(&mut self) -> fmi2Status;
    /// `fmi2Terminate`.
    fn terminate(&mut self) -> fmi2Status;
    /// `fmi2Reset`.
    fn reset(&mut self) -> fmi2Status;
    /// `fmi2GetReal`.
    fn get_real(&mut self, vrs: &[u32], out: &mut [f64]) -> fmi2Status;
    /// `fmi2GetInteger`.
    fn get_integer(&mut self, vrs: &[u32], out: &mut [i32]) -> fmi2Status;
    /// `fmi2GetBoolean`.
    fn get_boolean(&mut self, vrs: &[u32], out: &mut [fmi2Boolean]) -> fmi2Status;
    /// `fmi2GetString`: the strings stay valid until the next call on this instance.
    fn get_string(&mut self, vrs: &[u32], out: &mut [fmi2String]) -> fmi2Status;
    /// `fmi2SetReal`.
    fn set_real(&mut self, vrs: &[u32], values: &[f64]) -> fmi2Status;
    /// `fmi2SetInteger`.
    fn set_integer(&mut self, vrs: &[u32], values: &[i32]) -> fmi2Status;
    /// `fmi2SetBoolean`.
    fn set_boolean(&mut self, vrs: &[u32], values: &[fmi2Boolean]) -> fmi2Status;
    /// `fmi2SetString` (already converted from C strings).
    fn set_string(&mut self, vrs: &[u32], values: &[&str]) -> fmi2Status;
    /// `fmi2GetFMUstate` / serialization: the whole state as versioned bytes.
    fn save_state(&mut self) -> Vec<u8>;
    /// `fmi2SetFMUstate` / deserialization check: restores bytes made by [`Self::save_state`].
    fn restore_state(&mut self, bytes: &[u8]) -> Result<(), StateError>;
    /// Checks bytes without restoring them (for `fmi2DeSerializeFMUstate`).
    fn check_state(&self, bytes: &[u8]) -> Result<(), StateError>;
    /// `fmi2GetRealOutputDerivatives`.
    fn get_real_output_derivatives(
        &mut self,
        vrs: &[u32],
        orders: &[i32],
        out: &mut [f64],
    ) -> fmi2Status;
    /// `fmi2DoStep`.
    fn do_step(&mut self, t: f64, h: f64) -> fmi2Status;
    /// `fmi2Terminated` status.
    fn terminated(&self) -> bool;
    /// `fmi2LastSuccessfulTime` status.
    fn last_successful_time(&self) -> f64;
    /// Logs an error about a call and answers `fmi2Error` (state unchanged).
    fn refuse(&self, function: &str, why: &str) -> fmi2Status {
        self.logger()
            .log(fmi2Error, Category::Error, &format!("{function}: {why}"));
        fmi2Error
    }
    /// Moves the instance to the error state (after a panic inside a call).
    fn poison(&mut self);
}

/// The answer to a panic caught in the call `name`: the panic is logged as an internal error,
/// the instance enters the error state (from which `fmi2Reset` recovers) and the call answers
/// `fmi2Error`. Shared by the export layer's guard and [`Instance::guarded`].
#[cold]
#[inline(never)]
pub(super) fn answer_panic(
    inst: &mut dyn FmiInstance,
    name: &str,
    payload: Box<dyn std::any::Any + Send>,
) -> fmi2Status {
    let what = if let Some(s) = payload.downcast_ref::<&str>() {
        (*s).to_string()
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s.clone()
    } else {
        "unknown panic".into()
    };
    inst.poison();
    inst.refuse(name, &format!("internal error (panic): {what}"))
}

/// The generic instance of model `M`.
pub struct Instance<M: Model> {
    model: M,
    info: &'static ModelInfo,
    logger: Logger,
    state: State,
    start_time: f64,
    stop_time: Option<f64>,
    time: f64,
    last_successful_time: f64,
    terminated: bool,
    /// Outputs must be recomputed before the next get (after a set or a step).
    dirty: bool,
    /// Strings handed out by the last `fmi2GetString`.
    strings: Vec<CString>,
    /// Real getters by value reference: the hot path of every communication step, resolved
    /// once so a get is one table load and one call per value.
    real_getters: Vec<Option<RealGetter<M>>>,
    /// Integer (and Enumeration) getters by value reference.
    integer_getters: Vec<Option<IntegerGetter<M>>>,
    /// Boolean getters by value reference.
    boolean_getters: Vec<Option<BooleanGetter<M>>>,
    /// Real setters by value reference, with what a set must satisfy.
    real_setters: Vec<RealSetter<M>>,
    /// Boolean setters by value reference, with the phases they may be set in.
    boolean_setters: Vec<Option<BooleanSetter<M>>>,
}

/// The base-type number of a variable: 0 Real, 1 Integer/Enumeration, 2 Boolean, 3 String.
pub fn base_type_tag<M>(v: &Variable<M>) -> u8 {
    match v.access {
        Access::Real(..) => 0,
        Access::Integer(..) | Access::Enumeration(..) => 1,
        Access::Boolean(..) => 2,
        Access::String(..) => 3,
    }
}

const TYPE_NAMES: [&str; 4] = ["Real", "Integer", "Boolean", "String"];

impl<M: Model> Instance<M> {
    /// A new instance with every start value applied.
    pub fn new(info: &'static ModelInfo, logger: Logger) -> Self {
        Self {
            model: fresh_model::<M>(),
            info,
            logger,
            state: State::Instantiated,
            start_time: 0.0,
            stop_time: None,
            time: 0.0,
            last_successful_time: 0.0,
            terminated: false,
            dirty: true,
            strings: Vec::new(),
            real_getters: real_getter_table::<M>(),
            integer_getters: integer_getter_table::<M>(),
            boolean_getters: boolean_getter_table::<M>(),
            real_setters: real_setter_table::<M>(),
            boolean_setters: boolean_setter_table::<M>(),
        }
    }

    fn phase(&self) -> Phase {
        match self.state {
            State::Instantiated => Phase::Instantiated,
            State::InitializationMode => Phase::Initialization,
            _ => Phase::Stepping,
        }
    }

    fn fail(&mut self, function: &str, message: &str) -> fmi2Status {
        self.state = State::Error;
        self.logger.log(
            fmi2Error,
            Category::Error,
            &format!("{function}: {message}"),
        );
        fmi2Error
    }

    #[cold]
    #[inline(never)]
    fn log_call(&self, name: &str) {
        self.logger.log(fmi2OK, Category::Calls, name);
    }

    /// Refuses a call made in a state where the standard does not allow it.
    #[cold]
    #[inline(never)]
    fn refuse_sequence(&self, func: Func, name: &str) {
        self.refuse(
            name,
            &format!(
                "not allowed in state {}; expected {}",
                state_name(self.state),
                describe_states(func.allowed())
            ),
        );
    }

    /// Recomputes outputs if a set or a step made them stale. Inlined into the getters, so a
    /// get of outputs already computed (the second and third get of a step: Integer, Boolean)
    /// costs one test, not a call.
    #[inline(always)]
    fn refresh(&mut self, function: &str) -> Result<(), fmi2Status> {
        if self.dirty {
            self.recompute(function)
        } else {
            Ok(())
        }
    }

    /// [`Self::refresh`]'s computation: the model's outputs at the current time.
    #[inline(never)]
    fn recompute(&mut self, function: &str) -> Result<(), fmi2Status> {
        if let Err(e) = self.model.calculate(self.time) {
            // `calculate` changes no state (its contract), so whatever went wrong, the
            // instance is as it was: refuse, and compute again at the next get.
            return Err(self.refuse(function, &e.message));
        }
        self.dirty = false;
        Ok(())
    }

    /// Checks that every value reference of a get or set of type `tag` is known; all or nothing.
    fn check_known(&self, function: &str, tag: u8, vrs: &[u32]) -> Result<(), fmi2Status> {
        match vrs.iter().find(|vr| self.info.find(tag, **vr).is_none()) {
            None => Ok(()),
            Some(vr) => Err(self.refuse(
                function,
                &format!(
                    "unknown value reference {vr} for type {} in model {}",
                    TYPE_NAMES[tag as usize],
                    M::IDENTIFIER
                ),
            )),
        }
    }

    /// Checks that every variable may be set now, before anything is changed.
    fn check_settable(
        &self,
        function: &str,
        idx: impl Iterator<Item = usize>,
    ) -> Result<(), fmi2Status> {
        let phase = self.phase();
        for i in idx {
            let v = &M::variables()[i];
            if !v.settable(phase) {
                return Err(self.refuse(
                    function,
                    &format!(
                        "variable {} (causality {:?}, variability {:?}) cannot be set in state {}",
                        v.name,
                        v.causality,
                        v.variability,
                        state_name(self.state)
                    ),
                ));
            }
        }
        Ok(())
    }

    fn check_range(&self, function: &str, v: &Variable<M>, x: f64) -> Result<(), fmi2Status> {
        match range_problem(v, x) {
            None => Ok(()),
            Some(why) => Err(self.refuse(function, &why)),
        }
    }

    fn check_enumeration(&self, function: &str, v: &Variable<M>, x: i32) -> Result<(), fmi2Status> {
        match enumeration_problem(v, x) {
            None => Ok(()),
            Some(why) => Err(self.refuse(function, &why)),
        }
    }

    /// The checking path of `fmi2SetReal` (a reference that is unknown or not settable now, a
    /// value that is not finite, out of range or a fraction where a whole number is due):
    /// refuses the call naming the first problem, or sets every value.
    #[cold]
    #[inline(never)]
    fn set_real_checked(&mut self, vrs: &[u32], values: &[f64]) -> fmi2Status {
        let f = "fmi2SetReal";
        if let Err(s) = self.check_known(f, 0, vrs) {
            return s;
        }
        let info = self.info;
        let idx = vrs.iter().filter_map(move |vr| info.find(0, *vr));
        if let Err(s) = self.check_settable(f, idx.clone()) {
            return s;
        }
        let vars = M::variables();
        for (i, &x) in idx.clone().zip(values) {
            if let Err(s) = self.check_range(f, &vars[i], x) {
                return s;
            }
        }
        for (i, &x) in idx.clone().zip(values) {
            if let Access::Real(_, set) = vars[i].access {
                set(&mut self.model, x);
            }
        }
        self.after_set();
        fmi2OK
    }

    fn after_set(&mut self) {
        self.dirty = true;
    }

    fn encode(&mut self) -> Vec<u8> {
        let mut w = StateWriter::default();
        w.bytes.extend_from_slice(STATE_MAGIC);
        w.u32(STATE_FORMAT_VERSION);
        // The length, written by `seal_state` once it is known.
        w.u32(0);
        w.string(&self.info.guid);
        w.string(M::IDENTIFIER);
        w.u8(self.state as u8);
        w.f64(self.start_time);
        w.bool(self.stop_time.is_some());
        w.f64(self.stop_time.unwrap_or(0.0));
        w.f64(self.time);
        w.f64(self.last_successful_time);
        w.bool(self.terminated);
        let vars = M::variables();
        w.u32(vars.len() as u32);
        for v in vars {
            match &v.access {
                Access::Real(get, _) => w.f64(get(&self.model)),
                Access::Integer(get, _) | Access::Enumeration(get, _) => w.i32(get(&self.model)),
                Access::Boolean(get, _) => w.bool(get(&self.model)),
                Access::String(get, _) => w.string(get(&self.model)),
            }
        }
        let mut internal = StateWriter::default();
        self.model.save_internal(&mut internal);
        w.u32(internal.bytes.len() as u32);
        w.bytes.extend_from_slice(&internal.bytes);
        seal_state(&mut w.bytes);
        w.bytes
    }

    /// Decodes `bytes` into a fresh model and instance fields, without touching `self`.
    fn decode(&self, bytes: &[u8]) -> Result<Decoded<M>, StateError> {
        let mut r = StateReader::new(bytes);
        let magic = r.take(STATE_MAGIC.len())?;
        if magic != STATE_MAGIC {
            return Err(StateError("not a kneebench FMU state (bad magic)".into()));
        }
        let version = r.u32()?;
        if version != STATE_FORMAT_VERSION {
            return Err(StateError(format!(
                "state format version {version}, this binary reads version {STATE_FORMAT_VERSION}"
            )));
        }
        let mut r = StateReader::new(unsealed_state(bytes)?);
        r.take(STATE_HEADER_LEN)?;
        let guid = r.string()?;
        let identifier = r.string()?;
        if guid != self.info.guid {
            return Err(StateError(format!(
                "the state belongs to model {identifier} with GUID {guid}, this instance is {} with GUID {}",
                M::IDENTIFIER,
                self.info.guid
            )));
        }
        let state = State::from_u8(r.u8()?).ok_or_else(|| StateError("bad state code".into()))?;
        let start_time = r.f64()?;
        let has_stop = r.bool()?;
        let stop = r.f64()?;
        let time = r.f64()?;
        let last_successful_time = r.f64()?;
        let terminated = r.bool()?;
        let vars = M::variables();
        let n = r.u32()? as usize;
        if n != vars.len() {
            return Err(StateError(format!(
                "state holds {n} variables, model has {}",
                vars.len()
            )));
        }
        if ![start_time, time, last_successful_time]
            .iter()
            .all(|t| t.is_finite())
            || has_stop && !stop.is_finite()
        {
            return Err(StateError("the state's times must be finite".into()));
        }
        let mut model = fresh_model::<M>();
        let check = |v: &Variable<M>, x: StateValue| match state_value_problem(v, x) {
            None => Ok(()),
            Some(why) => Err(StateError(why)),
        };
        for v in vars {
            match &v.access {
                Access::Real(_, set) => {
                    let x = r.f64()?;
                    check(v, StateValue::Real(x))?;
                    set(&mut model, x);
                }
                Access::Integer(_, set) | Access::Enumeration(_, set) => {
                    let x = r.i32()?;
                    check(v, StateValue::Integer(x))?;
                    set(&mut model, x);
                }
                Access::Boolean(_, set) => set(&mut model, r.bool()?),
                Access::String(_, set) => set(&mut model, &r.string()?),
            }
        }
        let len = r.u32()? as usize;
        let internal = r.take(len)?;
        let mut ir = StateReader::new(internal);
        model.load_internal(&mut ir)?;
        if !ir.remaining().is_empty() || !r.remaining().is_empty() {
            return Err(StateError("trailing bytes after the state".into()));
        }
        Ok(Decoded {
            model,
            state,
            start_time,
            stop_time: has_stop.then_some(stop),
            time,
            last_successful_time,
            terminated,
        })
    }
}

/// Why `fmi2SetReal`/`fmi2SetInteger` refuses value `x` for `v` (not finite, outside its
/// min/max, a fraction for an integer-valued Real), or `None`.
pub(super) fn range_problem<M>(v: &Variable<M>, x: f64) -> Option<String> {
    if !x.is_finite() {
        return Some(format!("{} = {x} refused: values must be finite", v.name));
    }
    if v.integer_valued && x.fract() != 0.0 {
        return Some(format!(
            "{} = {} refused: must be an integer (a Real that takes whole numbers only)",
            v.name,
            num(x)
        ));
    }
    if v.min.is_some_and(|lo| x < lo) || v.max.is_some_and(|hi| x > hi) {
        return Some(format!(
            "{} = {} refused: outside [{}, {}]",
            v.name,
            num(x),
            num(v.min.unwrap_or(f64::NEG_INFINITY)),
            num(v.max.unwrap_or(f64::INFINITY))
        ));
    }
    None
}

/// Why a mode `v` may not take value `x` (no item of its enumeration), or `None`.
fn enumeration_problem<M: Model>(v: &Variable<M>, x: i32) -> Option<String> {
    let ty = v.declared_type?;
    let items = M::enumerations()
        .iter()
        .find(|e| e.name == ty)
        .map(|e| e.items)
        .unwrap_or(&[]);
    if items.iter().any(|(_, value, _)| *value == x) {
        return None;
    }
    Some(format!(
        "{} = {x} refused: not an item of {ty} ({})",
        v.name,
        items
            .iter()
            .map(|(n, val, _)| format!("{val}={n}"))
            .collect::<Vec<_>>()
            .join(", ")
    ))
}

/// Why a restored state may not hold value `x` for `v`: the checks of `fmi2Set*`, for every
/// variable an importer can set (a state is only ever made of values that passed them, so a
/// value that fails them is a corrupted or forged state, which would fail later steps).
fn state_value_problem<M: Model>(v: &Variable<M>, x: StateValue) -> Option<String> {
    if !settable_phases(v).contains(&true) {
        return None;
    }
    match (&v.access, x) {
        (Access::Real(..), StateValue::Real(x)) => range_problem(v, x),
        (Access::Integer(..), StateValue::Integer(x)) => range_problem(v, f64::from(x)),
        (Access::Enumeration(..), StateValue::Integer(x)) => enumeration_problem(v, x),
        _ => None,
    }
}

/// A numeric variable value read from a state, for [`state_value_problem`].
#[derive(Clone, Copy)]
enum StateValue {
    Real(f64),
    Integer(i32),
}

struct Decoded<M> {
    model: M,
    state: State,
    start_time: f64,
    stop_time: Option<f64>,
    time: f64,
    last_successful_time: f64,
    terminated: bool,
}

/// First bytes of every serialized FMU state.
pub const STATE_MAGIC: &[u8; 8] = b"KNEEBNCH";
/// Version of the FMU-state byte format; bumped whenever the layout changes. Version 2 added
/// the length and the CRC-32 checksum (see [`reseal_state`]).
pub const STATE_FORMAT_VERSION: u32 = 2;

/// Bytes before a state's content: the magic, the format version and the length.
const STATE_HEADER_LEN: usize = STATE_MAGIC.len() + 4 + 4;
/// Bytes after a state's content: its CRC-32.
const STATE_TRAILER_LEN: usize = 4;

/// Seals an encoded state in place (the magic, the version, a length slot, then the content):
/// writes its total length into the slot after the version and appends the CRC-32 (IEEE) of
/// every byte before the checksum.
///
/// The length tells a truncated or extended state from a corrupted one; the checksum catches a
/// byte changed anywhere, including inside a model's internal state, where a plausible wrong
/// value would pass every other check and only show in later steps. It is not a signature:
/// a deliberately edited state can be resealed ([`reseal_state`], tests do), and then still
/// meets every value check of `fmi2DeSerializeFMUstate`.
fn seal_state(bytes: &mut Vec<u8>) {
    let total = (bytes.len() + STATE_TRAILER_LEN) as u32;
    let slot = STATE_MAGIC.len() + 4;
    bytes[slot..slot + 4].copy_from_slice(&total.to_le_bytes());
    bytes.extend_from_slice(&[0; STATE_TRAILER_LEN]);
    reseal_state(bytes);
}

/// Rewrites the checksum of a sealed state whose bytes were edited in place (tests and tools
/// that forge states on purpose); the length must be unchanged.
pub fn reseal_state(bytes: &mut [u8]) {
    if let Some(end) = bytes.len().checked_sub(STATE_TRAILER_LEN) {
        let crc = crc32fast::hash(&bytes[..end]);
        bytes[end..].copy_from_slice(&crc.to_le_bytes());
    }
}

/// The bytes of a sealed state before its checksum, once its length and checksum are checked
/// (the magic and version are checked by the caller first, so that another format version is
/// named as such).
fn unsealed_state(bytes: &[u8]) -> Result<&[u8], StateError> {
    let mut r = StateReader::new(bytes);
    r.take(STATE_MAGIC.len() + 4)?;
    let declared = r.u32()? as usize;
    match bytes.len().cmp(&declared) {
        std::cmp::Ordering::Less => {
            return Err(StateError(format!(
                "truncated: {} bytes of the {declared} the state declares",
                bytes.len()
            )));
        }
        std::cmp::Ordering::Greater => {
            return Err(StateError(format!(
                "trailing bytes after the state: {} bytes, it declares {declared}",
                bytes.len()
            )));
        }
        std::cmp::Ordering::Equal => {}
    }
    if declared < STATE_HEADER_LEN + STATE_TRAILER_LEN {
        return Err(StateError(format!(
            "truncated: a state declaring {declared} bytes has no room for its content"
        )));
    }
    let (content, trailer) = bytes.split_at(declared - STATE_TRAILER_LEN);
    let stored = u32::from_le_bytes([trailer[0], trailer[1], trailer[2], trailer[3]]);
    let computed = crc32fast::hash(content);
    if stored != computed {
        return Err(StateError(format!(
            "corrupted: its checksum is {stored:#010x}, its bytes give {computed:#010x} \
             (a byte changed since it was serialized)"
        )));
    }
    Ok(content)
}

/// A model with every declared start value applied.
pub fn fresh_model<M: Model>() -> M {
    use crate::model::Start;
    let mut m = M::default();
    for v in M::variables() {
        match (&v.access, &v.start) {
            (Access::Real(_, set), Start::Real(x)) => set(&mut m, *x),
            (Access::Integer(_, set), Start::Integer(x))
            | (Access::Enumeration(_, set), Start::Integer(x)) => set(&mut m, *x),
            (Access::Boolean(_, set), Start::Boolean(x)) => set(&mut m, *x),
            (Access::String(_, set), Start::String(x)) => set(&mut m, x),
            _ => {}
        }
    }
    m
}

impl<M: Model> FmiInstance for Instance<M> {
    fn logger(&self) -> &Logger {
        &self.logger
    }

    // Inlined into the get/set/doStep methods of this type, where `func` is a constant: the
    // check is then one bit test; logging and refusing stay out of line.
    #[inline]
    fn allow(&self, func: Func, name: &str) -> bool {
        // A function the model description declares unsupported is refused in every state.
        let undeclared = match func {
            Func::FmuState if !M::CAN_GET_AND_SET_FMU_STATE => Some("canGetAndSetFMUstate"),
            Func::SerializeFmuState if !M::CAN_SERIALIZE_FMU_STATE => Some("canSerializeFMUstate"),
            _ => None,
        };
        if let Some(flag) = undeclared {
            self.refuse(
                name,
                &format!("not provided: the model description declares {flag}=\"false\""),
            );
            return false;
        }
        if func.allowed() & self.state.bit() != 0 {
            if self.logger.enabled(Category::Calls) {
                self.log_call(name);
            }
            return true;
        }
        self.refuse_sequence(func, name);
        false
    }

    fn set_debug_logging(&mut self, on: bool, categories: &[&str]) -> fmi2Status {
        match self.logger.set_debug_logging(on, categories) {
            Ok(()) => fmi2OK,
            Err(why) => self.refuse("fmi2SetDebugLogging", &why),
        }
    }

    fn setup_experiment(
        &mut self,
        start: f64,
        stop: Option<f64>,
        tolerance: Option<f64>,
    ) -> fmi2Status {
        let f = "fmi2SetupExperiment";
        if !start.is_finite() {
            return self.refuse(f, &format!("startTime {start} is not finite"));
        }
        if let Some(stop) = stop
            && !(stop.is_finite() && stop >= start)
        {
            return self.refuse(
                f,
                &format!("stopTime {stop} must be finite and >= startTime {start}"),
            );
        }
        if let Some(tol) = tolerance
            && !(tol.is_finite() && tol > 0.0)
        {
            return self.refuse(f, &format!("tolerance {tol} must be finite and positive"));
        }
        self.start_time = start;
        self.stop_time = stop;
        self.time = start;
        self.last_successful_time = start;
        self.dirty = true;
        fmi2OK
    }

    fn enter_initialization_mode(&mut self) -> fmi2Status {
        self.state = State::InitializationMode;
        self.dirty = true;
        fmi2OK
    }

    fn exit_initialization_mode(&mut self) -> fmi2Status {
        if let Err(e) = self.model.initialize(self.start_time) {
            // Parameters that do not fit together: stay in initialization mode so the
            // importer can correct them.
            return self.refuse("fmi2ExitInitializationMode", &e.message);
        }
        self.state = State::StepComplete;
        self.dirty = true;
        fmi2OK
    }

    fn terminate(&mut self) -> fmi2Status {
        self.state = State::Terminated;
        fmi2OK
    }

    fn reset(&mut self) -> fmi2Status {
        self.model = fresh_model::<M>();
        self.state = State::Instantiated;
        self.start_time = 0.0;
        self.stop_time = None;
        self.time = 0.0;
        self.last_successful_time = 0.0;
        self.terminated = false;
        self.dirty = true;
        fmi2OK
    }

    fn get_real(&mut self, vrs: &[u32], out: &mut [f64]) -> fmi2Status {
        self.guarded("fmi2GetReal", |s| s.get_real_unguarded(vrs, out))
    }

    fn get_integer(&mut self, vrs: &[u32], out: &mut [i32]) -> fmi2Status {
        self.guarded("fmi2GetInteger", |s| s.get_integer_unguarded(vrs, out))
    }

    fn get_boolean(&mut self, vrs: &[u32], out: &mut [fmi2Boolean]) -> fmi2Status {
        self.guarded("fmi2GetBoolean", |s| s.get_boolean_unguarded(vrs, out))
    }

    fn get_string(&mut self, vrs: &[u32], out: &mut [fmi2String]) -> fmi2Status {
        self.guarded("fmi2GetString", |s| s.get_string_unguarded(vrs, out))
    }

    fn set_real(&mut self, vrs: &[u32], values: &[f64]) -> fmi2Status {
        self.guarded("fmi2SetReal", |s| s.set_real_unguarded(vrs, values))
    }

    fn set_integer(&mut self, vrs: &[u32], values: &[i32]) -> fmi2Status {
        self.guarded("fmi2SetInteger", |s| s.set_integer_unguarded(vrs, values))
    }

    fn set_boolean(&mut self, vrs: &[u32], values: &[fmi2Boolean]) -> fmi2Status {
        self.guarded("fmi2SetBoolean", |s| s.set_boolean_unguarded(vrs, values))
    }

    fn set_string(&mut self, vrs: &[u32], values: &[&str]) -> fmi2Status {
        self.guarded("fmi2SetString", |s| s.set_string_unguarded(vrs, values))
    }

    fn save_state(&mut self) -> Vec<u8> {
        self.encode()
    }

    fn restore_state(&mut self, bytes: &[u8]) -> Result<(), StateError> {
        let d = self.decode(bytes)?;
        self.model = d.model;
        self.state = d.state;
        self.start_time = d.start_time;
        self.stop_time = d.stop_time;
        self.time = d.time;
        self.last_successful_time = d.last_successful_time;
        self.terminated = d.terminated;
        self.dirty = true;
        Ok(())
    }

    fn check_state(&self, bytes: &[u8]) -> Result<(), StateError> {
        self.decode(bytes).map(|_| ())
    }

    fn get_real_output_derivatives(
        &mut self,
        vrs: &[u32],
        orders: &[i32],
        out: &mut [f64],
    ) -> fmi2Status {
        let f = "fmi2GetRealOutputDerivatives";
        if let Err(s) = self.check_known(f, 0, vrs) {
            return s;
        }
        let info = self.info;
        let idx = vrs.iter().filter_map(move |vr| info.find(0, *vr));
        let vars = M::variables();
        for (i, &order) in idx.clone().zip(orders) {
            let v = &vars[i];
            if v.causality != crate::model::Causality::Output {
                return self.refuse(f, &format!("{} is not an output", v.name));
            }
            if order < 1 || order as u32 > M::MAX_OUTPUT_DERIVATIVE_ORDER {
                return self.refuse(
                    f,
                    &format!(
                        "order {order} for {} is outside 1..={} (maxOutputDerivativeOrder)",
                        v.name,
                        M::MAX_OUTPUT_DERIVATIVE_ORDER
                    ),
                );
            }
        }
        if let Err(s) = self.refresh(f) {
            return s;
        }
        for ((o, i), &order) in out.iter_mut().zip(idx.clone()).zip(orders) {
            let v = &vars[i];
            match self
                .model
                .output_derivative(v.value_reference, order as u32)
            {
                Some(d) => *o = d,
                None => {
                    return self
                        .refuse(f, &format!("{} has no derivative of order {order}", v.name));
                }
            }
        }
        fmi2OK
    }

    fn do_step(&mut self, t: f64, h: f64) -> fmi2Status {
        self.guarded("fmi2DoStep", |s| s.do_step_unguarded(t, h))
    }

    fn terminated(&self) -> bool {
        self.terminated
    }

    fn last_successful_time(&self) -> f64 {
        self.last_successful_time
    }

    fn poison(&mut self) {
        self.state = State::Error;
    }
}

/// The bodies of the gets, sets and `fmi2DoStep`, which may unwind (a model panics): the
/// [`FmiInstance`] methods run them through [`Instance::guarded`].
impl<M: Model> Instance<M> {
    /// Runs `body` (the call `name`), catching a panic: it is logged and answered with
    /// `fmi2Error`, and the instance enters the error state (from which `fmi2Reset` recovers),
    /// as the export layer does for the other functions. Inside the method, so that the
    /// exported get, set and `fmi2DoStep` functions reach it with a jump, not a frame of their
    /// own around a second call.
    #[inline(always)]
    fn guarded(
        &mut self,
        name: &'static str,
        body: impl FnOnce(&mut Self) -> fmi2Status,
    ) -> fmi2Status {
        match catch_unwind(AssertUnwindSafe(|| body(self))) {
            Ok(status) => status,
            Err(payload) => answer_panic(self, name, payload),
        }
    }

    #[inline(always)]
    fn get_real_unguarded(&mut self, vrs: &[u32], out: &mut [f64]) -> fmi2Status {
        let f = "fmi2GetReal";
        if !self.allow(Func::Get, f) {
            return fmi2Error;
        }
        if let Err(s) = self.refresh(f) {
            return s;
        }
        if self.model.read_reals(vrs, out) {
            return fmi2OK;
        }
        // One pass: an unknown reference fails the call (the output array is then unspecified,
        // as the standard allows); the model itself is not changed by a get.
        let (model, table) = (&self.model, &self.real_getters[..]);
        for (o, vr) in out.iter_mut().zip(vrs) {
            match table.get(*vr as usize) {
                Some(Some(get)) => *o = get(model),
                _ => return self.check_known(f, 0, vrs).err().unwrap_or(fmi2Error),
            }
        }
        fmi2OK
    }

    #[inline(always)]
    fn get_integer_unguarded(&mut self, vrs: &[u32], out: &mut [i32]) -> fmi2Status {
        let f = "fmi2GetInteger";
        if !self.allow(Func::Get, f) {
            return fmi2Error;
        }
        if let Err(s) = self.refresh(f) {
            return s;
        }
        // One pass: an unknown reference fails the call (the output array is then unspecified,
        // as the standard allows); the model itself is not changed by a get.
        let (model, table) = (&self.model, &self.integer_getters[..]);
        for (o, vr) in out.iter_mut().zip(vrs) {
            match table.get(*vr as usize) {
                Some(Some(get)) => *o = get(model),
                _ => return self.check_known(f, 1, vrs).err().unwrap_or(fmi2Error),
            }
        }
        fmi2OK
    }

    #[inline(always)]
    fn get_boolean_unguarded(&mut self, vrs: &[u32], out: &mut [fmi2Boolean]) -> fmi2Status {
        let f = "fmi2GetBoolean";
        if !self.allow(Func::Get, f) {
            return fmi2Error;
        }
        if let Err(s) = self.refresh(f) {
            return s;
        }
        // One pass: an unknown reference fails the call (the output array is then unspecified,
        // as the standard allows); the model itself is not changed by a get.
        let (model, table) = (&self.model, &self.boolean_getters[..]);
        for (o, vr) in out.iter_mut().zip(vrs) {
            match table.get(*vr as usize) {
                Some(Some(get)) => *o = fmi2Boolean::from(get(model)),
                _ => return self.check_known(f, 2, vrs).err().unwrap_or(fmi2Error),
            }
        }
        fmi2OK
    }

    #[inline(always)]
    fn get_string_unguarded(&mut self, vrs: &[u32], out: &mut [fmi2String]) -> fmi2Status {
        let f = "fmi2GetString";
        if !self.allow(Func::Get, f) {
            return fmi2Error;
        }
        if let Err(s) = self.refresh(f) {
            return s;
        }
        // One pass: an unknown reference fails the call (the output array is then unspecified,
        // as the standard allows); the model itself is not changed by a get.
        let info = self.info;
        let idx = vrs.iter().map(move |vr| info.find(3, *vr));
        let vars = M::variables();
        self.strings.clear();
        for i in idx {
            let Some(i) = i else {
                return self.check_known(f, 3, vrs).err().unwrap_or(fmi2Error);
            };
            if let Access::String(get, _) = vars[i].access {
                let s = get(&self.model).replace('\0', "");
                self.strings.push(CString::new(s).unwrap_or_default());
            }
        }
        for (o, s) in out.iter_mut().zip(&self.strings) {
            *o = s.as_ptr();
        }
        fmi2OK
    }

    #[inline(always)]
    fn set_real_unguarded(&mut self, vrs: &[u32], values: &[f64]) -> fmi2Status {
        let f = "fmi2SetReal";
        if !self.allow(Func::Set, f) {
            return fmi2Error;
        }
        // Fast path: every reference known, settable now, finite and in range. Anything else
        // takes the checking path, which names the problem.
        let phase = phase_index(self.phase());
        let table = &self.real_setters[..];
        let ok = vrs.iter().zip(values).all(|(vr, x)| {
            table
                .get(*vr as usize)
                .is_some_and(|e| e.accepts(phase, *x))
        });
        if !ok {
            return self.set_real_checked(vrs, values);
        }
        // The table and the model as locals: the setters' calls do not make the loop reload
        // them from the instance.
        let (model, table) = (&mut self.model, &self.real_setters[..]);
        for (vr, x) in vrs.iter().zip(values) {
            if let Some(e) = table.get(*vr as usize) {
                (e.set)(model, *x);
            }
        }
        self.after_set();
        fmi2OK
    }

    #[inline(always)]
    fn set_integer_unguarded(&mut self, vrs: &[u32], values: &[i32]) -> fmi2Status {
        let f = "fmi2SetInteger";
        if !self.allow(Func::Set, f) {
            return fmi2Error;
        }
        if let Err(s) = self.check_known(f, 1, vrs) {
            return s;
        }
        let info = self.info;
        let idx = vrs.iter().filter_map(move |vr| info.find(1, *vr));
        if let Err(s) = self.check_settable(f, idx.clone()) {
            return s;
        }
        let vars = M::variables();
        for (i, &x) in idx.clone().zip(values) {
            let v = &vars[i];
            let check = match v.access {
                Access::Enumeration(..) => self.check_enumeration(f, v, x),
                _ => self.check_range(f, v, f64::from(x)),
            };
            if let Err(s) = check {
                return s;
            }
        }
        for (i, &x) in idx.clone().zip(values) {
            if let Access::Integer(_, set) | Access::Enumeration(_, set) = vars[i].access {
                set(&mut self.model, x);
            }
        }
        self.after_set();
        fmi2OK
    }

    #[inline(always)]
    fn set_boolean_unguarded(&mut self, vrs: &[u32], values: &[fmi2Boolean]) -> fmi2Status {
        let f = "fmi2SetBoolean";
        if !self.allow(Func::Set, f) {
            return fmi2Error;
        }
        // Fast path: every reference known and settable now. Anything else takes the checking
        // path below, which names the problem.
        let phase = phase_index(self.phase());
        let ok = vrs.iter().all(
            |vr| matches!(self.boolean_setters.get(*vr as usize), Some(Some(e)) if e.phases[phase]),
        );
        if ok {
            for (vr, x) in vrs.iter().zip(values) {
                if let Some(Some(e)) = self.boolean_setters.get(*vr as usize) {
                    (e.set)(&mut self.model, *x != 0);
                }
            }
            self.after_set();
            return fmi2OK;
        }
        if let Err(s) = self.check_known(f, 2, vrs) {
            return s;
        }
        let info = self.info;
        let idx = vrs.iter().filter_map(move |vr| info.find(2, *vr));
        if let Err(s) = self.check_settable(f, idx.clone()) {
            return s;
        }
        let vars = M::variables();
        for (i, &x) in idx.clone().zip(values) {
            if let Access::Boolean(_, set) = vars[i].access {
                set(&mut self.model, x != 0);
            }
        }
        self.after_set();
        fmi2OK
    }

    #[inline(always)]
    fn set_string_unguarded(&mut self, vrs: &[u32], values: &[&str]) -> fmi2Status {
        let f = "fmi2SetString";
        if !self.allow(Func::Set, f) {
            return fmi2Error;
        }
        if let Err(s) = self.check_known(f, 3, vrs) {
            return s;
        }
        let info = self.info;
        let idx = vrs.iter().filter_map(move |vr| info.find(3, *vr));
        if let Err(s) = self.check_settable(f, idx.clone()) {
            return s;
        }
        let vars = M::variables();
        for (i, &x) in idx.clone().zip(values) {
            if let Access::String(_, set) = vars[i].access {
                set(&mut self.model, x);
            }
        }
        self.after_set();
        fmi2OK
    }

    #[inline(always)]
    fn do_step_unguarded(&mut self, t: f64, h: f64) -> fmi2Status {
        let f = "fmi2DoStep";
        if !self.allow(Func::DoStep, f) {
            return fmi2Error;
        }
        // The ordinary step passes a few comparisons; any other takes the plain checks, which
        // name the first problem (`step_args`).
        let max = self.model.max_step_size();
        if !step_args::fits(t, h, self.time, self.stop_time, max) {
            let problem = step_args::problem(t, h, self.time, self.stop_time, max);
            if let Some(why) = problem {
                return self.refuse_step(&why);
            }
        }
        let outcome = self.model.do_step(t, h);
        for warning in self.model.take_warnings() {
            self.logger
                .log(fmi2Warning, Category::Warning, &format!("{f}: {warning}"));
        }
        match outcome {
            Ok(StepOutcome::Completed) => {
                self.time = t + h;
                self.last_successful_time = self.time;
                self.dirty = true;
                fmi2OK
            }
            Ok(StepOutcome::Terminated { at, reason }) => self.step_terminated(at, reason),
            Err(e) => self.step_failed(e),
        }
    }

    /// Refuses a step whose arguments do not pass (`why`, from [`step_args::problem`]).
    #[cold]
    #[inline(never)]
    fn refuse_step(&self, why: &str) -> fmi2Status {
        self.refuse("fmi2DoStep", why)
    }

    /// The model ended the simulation inside the step, at `at`.
    #[cold]
    #[inline(never)]
    fn step_terminated(&mut self, at: f64, reason: &str) -> fmi2Status {
        self.time = at;
        self.last_successful_time = at;
        self.terminated = true;
        self.dirty = true;
        self.state = State::StepFailed;
        self.logger.log(
            fmi2Discard,
            Category::Discard,
            &format!("fmi2DoStep: simulation ended at t = {}: {reason}", num(at)),
        );
        fmi2Discard
    }

    /// The model refused the step (unchanged) or failed.
    #[cold]
    #[inline(never)]
    fn step_failed(&mut self, e: crate::model::ModelError) -> fmi2Status {
        let f = "fmi2DoStep";
        if e.is_refused() {
            self.refuse(f, &e.message)
        } else {
            self.fail(f, &e.message)
        }
    }
}

#[cfg(test)]
mod boolean_set_tests {
    use super::*;

    fn bench_plant() -> Box<dyn FmiInstance> {
        crate::registry::find_by_identifier("BenchPlant")
            .expect("BenchPlant is exported")
            .instantiate(Logger::new(None, std::ptr::null_mut(), c"test", false))
    }

    /// The values of `vrs`; `None` before initialization, where no get is allowed.
    fn read(i: &mut Box<dyn FmiInstance>, vrs: &[u32]) -> Option<Vec<fmi2Boolean>> {
        let mut out = vec![7; vrs.len()];
        (i.get_boolean(vrs, &mut out) == fmi2OK).then_some(out)
    }

    /// The table path of `fmi2SetBoolean` sets inputs in every phase (any non-zero value is
    /// true) and leaves a call with an output or an unknown reference to the checking path,
    /// which refuses it whole: nothing of the call is set.
    #[test]
    fn a_boolean_set_takes_all_or_nothing_in_every_phase() {
        // 206 clutchEngage and 204 testDriverEnable (inputs), 330 clutchEngaged (output).
        let mut i = bench_plant();
        for phase in 0..3 {
            match phase {
                1 => assert_eq!(i.enter_initialization_mode(), fmi2OK),
                2 => assert_eq!(i.exit_initialization_mode(), fmi2OK),
                _ => {}
            }
            let readable = phase > 0;
            assert_eq!(i.set_boolean(&[206, 204], &[2, 0]), fmi2OK, "phase {phase}");
            assert_eq!(read(&mut i, &[206, 204]).is_some(), readable);
            if readable {
                assert_eq!(read(&mut i, &[206, 204]), Some(vec![1, 0]), "phase {phase}");
            }
            assert_eq!(i.set_boolean(&[206, 204], &[0, 1]), fmi2OK, "phase {phase}");
            for refused in [[206, 330], [206, 999], [204, 206 + 1000]] {
                assert_eq!(i.set_boolean(&refused, &[1, 0]), fmi2Error, "{refused:?}");
                if readable {
                    assert_eq!(read(&mut i, &[206, 204]), Some(vec![0, 1]), "{refused:?}");
                }
            }
            // A Real reference is no Boolean one.
            assert_eq!(i.set_boolean(&[201], &[1]), fmi2Error);
        }
    }
}
