//! A safe wrapper of one FMI 2.0 co-simulation instance.
//!
//! Every call maps the FMU's `fmi2Status`: `fmi2OK` and `fmi2Warning` are `Ok`
//! ([`Status::Ok`], [`Status::Warning`]); `fmi2Discard` is `Ok(`[`Status::Discard`]`)`, a
//! distinct outcome the caller must look at (for [`Instance::do_step`] it means the step was not
//! done; query [`Instance::get_boolean_status`] for `fmi2Terminated`); `fmi2Error`, `fmi2Fatal`
//! and `fmi2Pending` are an [`FmuError`] that carries the instance's last log messages.
//!
//! Log messages reach the instance through a small C shim (the FMI logger is C-variadic): it
//! formats the message and calls a Rust sink that records it in a bounded ring (the last
//! [`RECENT_MESSAGES`]) and forwards it to the instance's [`LogHandler`]. A panic in a handler is
//! caught; it never unwinds into the FMU.

use std::collections::VecDeque;
use std::ffi::{CString, c_char, c_int, c_void};
use std::fmt;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::{Arc, Mutex};

use crate::fmi2::*;
use crate::load::{Fmu, FmuShared, cstr_lossy};

/// How many of an instance's most recent log messages are kept (and attached to errors).
pub const RECENT_MESSAGES: usize = 32;

/// The status an FMU passed to the logger.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum LogStatus {
    /// `fmi2OK`.
    Ok,
    /// `fmi2Warning`.
    Warning,
    /// `fmi2Discard`.
    Discard,
    /// `fmi2Error`.
    Error,
    /// `fmi2Fatal`.
    Fatal,
    /// `fmi2Pending` or a value outside the enumeration.
    Other,
}

impl LogStatus {
    fn from_c(s: c_int) -> LogStatus {
        match s {
            0 => LogStatus::Ok,
            1 => LogStatus::Warning,
            2 => LogStatus::Discard,
            3 => LogStatus::Error,
            4 => LogStatus::Fatal,
            _ => LogStatus::Other,
        }
    }
}

/// One message an FMU sent to the logger, already formatted.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LogMessage {
    /// The instance name the FMU passed.
    pub instance: String,
    /// The status it passed.
    pub status: LogStatus,
    /// The category it passed.
    pub category: String,
    /// The formatted message.
    pub message: String,
}

impl fmt::Display for LogMessage {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "[{}] {:?} {}: {}",
            self.instance, self.status, self.category, self.message
        )
    }
}

/// Receives every log message of an instance (from any thread the FMU logs on).
pub type LogHandler = Arc<dyn Fn(&LogMessage) + Send + Sync>;

/// A handler that prints messages with at least `min` status to standard error.
pub fn stderr_log_handler(min: LogStatus) -> LogHandler {
    Arc::new(move |m: &LogMessage| {
        if m.status >= min {
            eprintln!("{m}");
        }
    })
}

/// Options of [`Fmu::instantiate`].
#[derive(Clone, Default)]
pub struct InstanceOptions {
    /// The `visible` argument of `fmi2Instantiate`.
    pub visible: bool,
    /// The `loggingOn` argument of `fmi2Instantiate` (debug logging in the FMU).
    pub logging_on: bool,
    /// Where log messages go, besides the ring of recent messages kept for errors.
    /// `None`: they are only kept (and printed to standard error when the environment variable
    /// `KNEEBENCH_DEBUG` is set).
    pub log_handler: Option<LogHandler>,
}

impl fmt::Debug for InstanceOptions {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("InstanceOptions")
            .field("visible", &self.visible)
            .field("logging_on", &self.logging_on)
            .field("log_handler", &self.log_handler.is_some())
            .finish()
    }
}

/// The non-error outcomes of an FMI call.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Status {
    /// `fmi2OK`.
    Ok,
    /// `fmi2Warning`: done, with a warning (see the log).
    Warning,
    /// `fmi2Discard`: not done (for `fmi2DoStep`: the step was rejected; the FMU may have
    /// terminated, see `fmi2GetBooleanStatus(fmi2Terminated)`).
    Discard,
}

/// Which error status an FMU returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorStatus {
    /// `fmi2Error`: the instance can only be reset or freed.
    Error,
    /// `fmi2Fatal`: no further call is allowed (not even free).
    Fatal,
    /// `fmi2Pending`: an asynchronous step, which this harness never requests.
    Pending,
    /// A value that is not an `fmi2Status` at all (a broken FMU); handled like `fmi2Error`.
    Invalid(i32),
}

/// An FMI call that failed.
#[derive(Debug, thiserror::Error)]
pub enum FmuError {
    /// The FMU returned an error status.
    #[error("{function} returned {status:?} (instance '{instance}'){}", format_messages(.messages))]
    Call {
        /// The FMI function.
        function: &'static str,
        /// The instance name.
        instance: String,
        /// The status.
        status: ErrorStatus,
        /// The instance's last log messages, oldest first.
        messages: Vec<LogMessage>,
    },
    /// `fmi2Instantiate` returned NULL.
    #[error("fmi2Instantiate returned NULL for instance '{instance}'{}", format_messages(.messages))]
    Instantiate {
        /// The instance name.
        instance: String,
        /// The FMU's log messages.
        messages: Vec<LogMessage>,
    },
    /// The binary does not export an optional function this call needs.
    #[error("the FMU does not export {0}")]
    Unsupported(&'static str),
    /// The instance is unusable after an earlier `fmi2Fatal`.
    #[error("instance '{0}' returned fmi2Fatal earlier; no further call is allowed")]
    AfterFatal(String),
    /// Value references and values of different lengths.
    #[error("{function}: {refs} value references but {values} values")]
    LengthMismatch {
        /// The FMI function.
        function: &'static str,
        /// Number of value references.
        refs: usize,
        /// Number of values.
        values: usize,
    },
    /// A string to pass contains a NUL byte.
    #[error("string value contains a NUL byte")]
    NulInString,
}

impl FmuError {
    /// The FMU's log messages attached to this error.
    pub fn messages(&self) -> &[LogMessage] {
        match self {
            FmuError::Call { messages, .. } | FmuError::Instantiate { messages, .. } => messages,
            _ => &[],
        }
    }
}

fn format_messages(messages: &[LogMessage]) -> String {
    if messages.is_empty() {
        return String::new();
    }
    let mut s = String::from("; FMU log: ");
    // The last few are what explains an error.
    let skip = messages.len().saturating_sub(5);
    for (i, m) in messages.iter().skip(skip).enumerate() {
        if i > 0 {
            s.push_str(" | ");
        }
        s.push_str(&format!("{:?} {}: {}", m.status, m.category, m.message));
    }
    s
}

/// The per-instance context the FMU's `componentEnvironment` points to.
struct LogContext {
    handler: Option<LogHandler>,
    debug_print: bool,
    recent: Mutex<VecDeque<LogMessage>>,
}

impl LogContext {
    fn take_recent(&self) -> Vec<LogMessage> {
        match self.recent.lock() {
            Ok(mut r) => r.drain(..).collect(),
            Err(p) => p.into_inner().drain(..).collect(),
        }
    }
    fn clear(&self) {
        match self.recent.lock() {
            Ok(mut r) => r.clear(),
            Err(p) => p.into_inner().clear(),
        }
    }
}

unsafe extern "C" {
    // The C shim (src/logger_shim.c): formats and calls kneebench_log_sink.
    fn kneebench_logger(
        env: fmi2ComponentEnvironment,
        instance_name: fmi2String,
        status: fmi2Status,
        category: fmi2String,
        message: fmi2String,
        ...
    );
}

/// Called by the C shim with the formatted message. Never unwinds.
#[unsafe(no_mangle)]
extern "C" fn kneebench_log_sink(
    env: *mut c_void,
    instance_name: *const c_char,
    status: c_int,
    category: *const c_char,
    formatted: *const c_char,
) {
    let _ = catch_unwind(AssertUnwindSafe(|| {
        if env.is_null() {
            return;
        }
        // SAFETY: env is the LogContext we passed as componentEnvironment; it lives in a Box
        // owned by the Instance until after fmi2FreeInstance returns. The strings are
        // NUL-terminated or NULL (cstr_lossy checks NULL).
        let ctx = unsafe { &*(env as *const LogContext) };
        let msg = unsafe {
            LogMessage {
                instance: cstr_lossy(instance_name),
                status: LogStatus::from_c(status),
                category: cstr_lossy(category),
                message: cstr_lossy(formatted),
            }
        };
        if ctx.debug_print {
            eprintln!("{msg}");
        }
        if let Some(h) = &ctx.handler {
            h(&msg);
        }
        let mut recent = match ctx.recent.lock() {
            Ok(r) => r,
            Err(p) => p.into_inner(),
        };
        if recent.len() == RECENT_MESSAGES {
            recent.pop_front();
        }
        recent.push_back(msg);
    }));
}

/// Where an instance is in the FMI 2.0 co-simulation state machine (as far as the harness
/// needs to know for cleanup).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// After `fmi2Instantiate` (or `fmi2Reset`).
    Instantiated,
    /// Between `fmi2EnterInitializationMode` and `fmi2ExitInitializationMode`.
    Initialization,
    /// Stepping.
    StepComplete,
    /// After `fmi2Terminate`.
    Terminated,
    /// After an `fmi2Error`.
    Error,
    /// After an `fmi2Fatal`: only leaking the instance is safe.
    Fatal,
}

/// A saved FMU state (`fmi2FMUstate`), valid for the instance that made it until freed with
/// [`Instance::free_fmu_state`] or the instance is dropped.
#[derive(Debug)]
pub struct FmuState {
    ptr: fmi2FMUstate,
}

/// One FMI 2.0 co-simulation instance. Dropping it terminates it when it is initialized and
/// frees it (except after `fmi2Fatal`, when freeing is not allowed and the instance is leaked).
pub struct Instance {
    fmu: Arc<FmuShared>,
    c: fmi2Component,
    name: String,
    phase: Phase,
    // Boxed so that their addresses stay fixed: the FMU may keep both pointers.
    _callbacks: Box<fmi2CallbackFunctions>,
    ctx: Box<LogContext>,
    _name_c: CString,
}

// SAFETY: an fmi2Component may be used from any thread as long as calls are not concurrent,
// which &mut self guarantees. FMUs are expected not to share mutable state between instances
// (parallel stepping is opt-in and documented as requiring that).
unsafe impl Send for Instance {}

impl fmt::Debug for Instance {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Instance")
            .field("name", &self.name)
            .field("phase", &self.phase)
            .finish()
    }
}

impl Fmu {
    /// Instantiates the FMU for co-simulation (`fmi2Instantiate` with the GUID of the model
    /// description; an FMU whose binary was built for another description refuses here).
    pub fn instantiate(&self, name: &str, options: &InstanceOptions) -> Result<Instance, FmuError> {
        let name_c = CString::new(name).map_err(|_| FmuError::NulInString)?;
        let ctx = Box::new(LogContext {
            handler: options.log_handler.clone(),
            debug_print: std::env::var_os("KNEEBENCH_DEBUG").is_some(),
            recent: Mutex::new(VecDeque::with_capacity(RECENT_MESSAGES)),
        });
        // SAFETY: kneebench_logger has the C signature of fmi2CallbackLogger (the status is a
        // C enum, passed as int).
        let logger: fmi2CallbackLogger = Some(kneebench_logger);
        let callbacks = Box::new(fmi2CallbackFunctions {
            logger,
            allocateMemory: Some(fmi_calloc),
            freeMemory: Some(fmi_free),
            stepFinished: None,
            componentEnvironment: &*ctx as *const LogContext as *mut c_void,
        });
        let f = &self.shared.functions;
        // SAFETY: all pointers are valid NUL-terminated strings / a callbacks struct that live
        // as long as the instance.
        let c = unsafe {
            (f.instantiate)(
                name_c.as_ptr(),
                fmi2Type::fmi2CoSimulation,
                self.shared.guid.as_ptr(),
                self.shared.resource_uri.as_ptr(),
                &*callbacks,
                options.visible as fmi2Boolean,
                options.logging_on as fmi2Boolean,
            )
        };
        if c.is_null() {
            return Err(FmuError::Instantiate {
                instance: name.to_string(),
                messages: ctx.take_recent(),
            });
        }
        Ok(Instance {
            fmu: self.shared.clone(),
            c,
            name: name.to_string(),
            phase: Phase::Instantiated,
            _callbacks: callbacks,
            ctx,
            _name_c: name_c,
        })
    }
}

unsafe extern "C" fn fmi_calloc(nobj: usize, size: usize) -> *mut c_void {
    // SAFETY: plain libc calloc.
    unsafe { libc_calloc(nobj, size) }
}
unsafe extern "C" fn fmi_free(obj: *mut c_void) {
    // SAFETY: plain libc free of memory from fmi_calloc.
    unsafe { libc_free(obj) }
}
unsafe extern "C" {
    #[link_name = "calloc"]
    fn libc_calloc(nobj: usize, size: usize) -> *mut c_void;
    #[link_name = "free"]
    fn libc_free(obj: *mut c_void);
}

impl Instance {
    /// The instance name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Where the instance is in its life cycle.
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// The FMU this is an instance of.
    pub fn fmu(&self) -> Fmu {
        Fmu {
            shared: self.fmu.clone(),
        }
    }

    /// The instance's recent log messages (they are also attached to errors), oldest first;
    /// reading them empties the ring.
    pub fn take_messages(&mut self) -> Vec<LogMessage> {
        self.ctx.take_recent()
    }

    #[inline]
    fn check(&mut self, function: &'static str, s: fmi2StatusCode) -> Result<Status, FmuError> {
        // The FMU's return value is a C int: read as a number, never as the Rust enum.
        match s.0 {
            0 => Ok(Status::Ok),
            1 => Ok(Status::Warning),
            2 => Ok(Status::Discard),
            _ => Err(self.error(function, s)),
        }
    }

    #[cold]
    fn error(&mut self, function: &'static str, s: fmi2StatusCode) -> FmuError {
        let status = match s.status() {
            Some(fmi2Status::fmi2Fatal) => {
                self.phase = Phase::Fatal;
                ErrorStatus::Fatal
            }
            Some(fmi2Status::fmi2Pending) => ErrorStatus::Pending,
            Some(_) => {
                self.phase = Phase::Error;
                ErrorStatus::Error
            }
            None => {
                self.phase = Phase::Error;
                ErrorStatus::Invalid(s.0)
            }
        };
        FmuError::Call {
            function,
            instance: self.name.clone(),
            status,
            messages: self.ctx.take_recent(),
        }
    }

    #[inline]
    fn alive(&self) -> Result<(), FmuError> {
        if self.phase == Phase::Fatal {
            Err(FmuError::AfterFatal(self.name.clone()))
        } else {
            Ok(())
        }
    }

    /// `fmi2SetDebugLogging` with the given categories (empty: all).
    pub fn set_debug_logging(&mut self, on: bool, categories: &[&str]) -> Result<Status, FmuError> {
        self.alive()?;
        let owned: Vec<CString> = categories
            .iter()
            .map(|c| CString::new(*c).map_err(|_| FmuError::NulInString))
            .collect::<Result<_, _>>()?;
        let ptrs: Vec<fmi2String> = owned.iter().map(|c| c.as_ptr()).collect();
        // SAFETY: valid component and an array of valid strings.
        let s = unsafe {
            (self.fmu.functions.set_debug_logging)(
                self.c,
                on as fmi2Boolean,
                ptrs.len(),
                ptrs.as_ptr(),
            )
        };
        self.check("fmi2SetDebugLogging", s)
    }

    /// `fmi2SetupExperiment`.
    pub fn setup_experiment(
        &mut self,
        tolerance: Option<f64>,
        start_time: f64,
        stop_time: Option<f64>,
    ) -> Result<Status, FmuError> {
        self.alive()?;
        // SAFETY: valid component.
        let s = unsafe {
            (self.fmu.functions.setup_experiment)(
                self.c,
                tolerance.is_some() as fmi2Boolean,
                tolerance.unwrap_or(0.0),
                start_time,
                stop_time.is_some() as fmi2Boolean,
                stop_time.unwrap_or(0.0),
            )
        };
        self.check("fmi2SetupExperiment", s)
    }

    /// `fmi2EnterInitializationMode`.
    pub fn enter_initialization_mode(&mut self) -> Result<Status, FmuError> {
        self.alive()?;
        // SAFETY: valid component.
        let s = unsafe { (self.fmu.functions.enter_initialization_mode)(self.c) };
        let r = self.check("fmi2EnterInitializationMode", s)?;
        self.phase = Phase::Initialization;
        Ok(r)
    }

    /// `fmi2ExitInitializationMode`.
    pub fn exit_initialization_mode(&mut self) -> Result<Status, FmuError> {
        self.alive()?;
        // SAFETY: valid component.
        let s = unsafe { (self.fmu.functions.exit_initialization_mode)(self.c) };
        let r = self.check("fmi2ExitInitializationMode", s)?;
        self.phase = Phase::StepComplete;
        Ok(r)
    }

    /// `fmi2DoStep` (with `noSetFMUStatePriorToCurrentPoint = true`).
    ///
    /// `Ok(Status::Discard)` means the step was not done: see
    /// [`terminated`](Self::terminated) and [`last_successful_time`](Self::last_successful_time).
    #[inline]
    pub fn do_step(&mut self, current_time: f64, step_size: f64) -> Result<Status, FmuError> {
        // SAFETY: valid component (a Fatal instance is refused by the caller's phase check in
        // `alive`, kept out of this hot path: after fmi2Fatal the master stops).
        let s = unsafe { (self.fmu.functions.do_step)(self.c, current_time, step_size, fmi2True) };
        self.check("fmi2DoStep", s)
    }

    /// `fmi2CancelStep`.
    pub fn cancel_step(&mut self) -> Result<Status, FmuError> {
        self.alive()?;
        // SAFETY: valid component.
        let s = unsafe { (self.fmu.functions.cancel_step)(self.c) };
        self.check("fmi2CancelStep", s)
    }

    /// `fmi2Terminate`.
    pub fn terminate(&mut self) -> Result<Status, FmuError> {
        self.alive()?;
        // SAFETY: valid component.
        let s = unsafe { (self.fmu.functions.terminate)(self.c) };
        let r = self.check("fmi2Terminate", s)?;
        self.phase = Phase::Terminated;
        Ok(r)
    }

    /// `fmi2Reset`: back to the state after instantiation.
    pub fn reset(&mut self) -> Result<Status, FmuError> {
        self.alive()?;
        // SAFETY: valid component.
        let s = unsafe { (self.fmu.functions.reset)(self.c) };
        let r = self.check("fmi2Reset", s)?;
        self.phase = Phase::Instantiated;
        self.ctx.clear();
        Ok(r)
    }

    /// `fmi2GetReal` into `values` (same length as `vrs`).
    #[inline]
    pub fn get_real(&mut self, vrs: &[u32], values: &mut [f64]) -> Result<Status, FmuError> {
        if vrs.len() != values.len() {
            return Err(mismatch("fmi2GetReal", vrs.len(), values.len()));
        }
        if vrs.is_empty() {
            return Ok(Status::Ok);
        }
        // SAFETY: arrays of the given length.
        let s = unsafe {
            (self.fmu.functions.get_real)(self.c, vrs.as_ptr(), vrs.len(), values.as_mut_ptr())
        };
        self.check("fmi2GetReal", s)
    }

    /// `fmi2GetInteger` into `values`.
    #[inline]
    pub fn get_integer(&mut self, vrs: &[u32], values: &mut [i32]) -> Result<Status, FmuError> {
        if vrs.len() != values.len() {
            return Err(mismatch("fmi2GetInteger", vrs.len(), values.len()));
        }
        if vrs.is_empty() {
            return Ok(Status::Ok);
        }
        // SAFETY: arrays of the given length.
        let s = unsafe {
            (self.fmu.functions.get_integer)(self.c, vrs.as_ptr(), vrs.len(), values.as_mut_ptr())
        };
        self.check("fmi2GetInteger", s)
    }

    /// `fmi2GetBoolean` into `values` (`fmi2Boolean` is a C int: 0 false, anything else true).
    #[inline]
    pub fn get_boolean_raw(
        &mut self,
        vrs: &[u32],
        values: &mut [fmi2Boolean],
    ) -> Result<Status, FmuError> {
        if vrs.len() != values.len() {
            return Err(mismatch("fmi2GetBoolean", vrs.len(), values.len()));
        }
        if vrs.is_empty() {
            return Ok(Status::Ok);
        }
        // SAFETY: arrays of the given length.
        let s = unsafe {
            (self.fmu.functions.get_boolean)(self.c, vrs.as_ptr(), vrs.len(), values.as_mut_ptr())
        };
        self.check("fmi2GetBoolean", s)
    }

    /// `fmi2GetBoolean` into `bool`s.
    pub fn get_boolean(&mut self, vrs: &[u32], values: &mut [bool]) -> Result<Status, FmuError> {
        let mut raw = vec![0; vrs.len()];
        if vrs.len() != values.len() {
            return Err(mismatch("fmi2GetBoolean", vrs.len(), values.len()));
        }
        let s = self.get_boolean_raw(vrs, &mut raw)?;
        for (v, r) in values.iter_mut().zip(raw) {
            *v = r != 0;
        }
        Ok(s)
    }

    /// `fmi2GetString`: the strings are copied before the next FMI call.
    pub fn get_string(&mut self, vrs: &[u32]) -> Result<Vec<String>, FmuError> {
        let mut ptrs: Vec<fmi2String> = vec![std::ptr::null(); vrs.len()];
        if vrs.is_empty() {
            return Ok(Vec::new());
        }
        // SAFETY: arrays of the given length.
        let s = unsafe {
            (self.fmu.functions.get_string)(self.c, vrs.as_ptr(), vrs.len(), ptrs.as_mut_ptr())
        };
        self.check("fmi2GetString", s)?;
        // SAFETY: the FMU returned NUL-terminated strings (or NULL) valid until the next call.
        Ok(ptrs.iter().map(|&p| unsafe { cstr_lossy(p) }).collect())
    }

    /// `fmi2SetReal`.
    #[inline]
    pub fn set_real(&mut self, vrs: &[u32], values: &[f64]) -> Result<Status, FmuError> {
        if vrs.len() != values.len() {
            return Err(mismatch("fmi2SetReal", vrs.len(), values.len()));
        }
        if vrs.is_empty() {
            return Ok(Status::Ok);
        }
        // SAFETY: arrays of the given length.
        let s = unsafe {
            (self.fmu.functions.set_real)(self.c, vrs.as_ptr(), vrs.len(), values.as_ptr())
        };
        self.check("fmi2SetReal", s)
    }

    /// `fmi2SetInteger`.
    #[inline]
    pub fn set_integer(&mut self, vrs: &[u32], values: &[i32]) -> Result<Status, FmuError> {
        if vrs.len() != values.len() {
            return Err(mismatch("fmi2SetInteger", vrs.len(), values.len()));
        }
        if vrs.is_empty() {
            return Ok(Status::Ok);
        }
        // SAFETY: arrays of the given length.
        let s = unsafe {
            (self.fmu.functions.set_integer)(self.c, vrs.as_ptr(), vrs.len(), values.as_ptr())
        };
        self.check("fmi2SetInteger", s)
    }

    /// `fmi2SetBoolean` from C ints (0 false, 1 true).
    #[inline]
    pub fn set_boolean_raw(
        &mut self,
        vrs: &[u32],
        values: &[fmi2Boolean],
    ) -> Result<Status, FmuError> {
        if vrs.len() != values.len() {
            return Err(mismatch("fmi2SetBoolean", vrs.len(), values.len()));
        }
        if vrs.is_empty() {
            return Ok(Status::Ok);
        }
        // SAFETY: arrays of the given length.
        let s = unsafe {
            (self.fmu.functions.set_boolean)(self.c, vrs.as_ptr(), vrs.len(), values.as_ptr())
        };
        self.check("fmi2SetBoolean", s)
    }

    /// `fmi2SetBoolean` from `bool`s.
    pub fn set_boolean(&mut self, vrs: &[u32], values: &[bool]) -> Result<Status, FmuError> {
        let raw: Vec<fmi2Boolean> = values.iter().map(|&b| b as fmi2Boolean).collect();
        self.set_boolean_raw(vrs, &raw)
    }

    /// `fmi2SetString`.
    pub fn set_string(&mut self, vrs: &[u32], values: &[&str]) -> Result<Status, FmuError> {
        if vrs.len() != values.len() {
            return Err(mismatch("fmi2SetString", vrs.len(), values.len()));
        }
        let owned: Vec<CString> = values
            .iter()
            .map(|v| CString::new(*v).map_err(|_| FmuError::NulInString))
            .collect::<Result<_, _>>()?;
        let ptrs: Vec<fmi2String> = owned.iter().map(|c| c.as_ptr()).collect();
        if vrs.is_empty() {
            return Ok(Status::Ok);
        }
        // SAFETY: arrays of the given length of valid strings.
        let s = unsafe {
            (self.fmu.functions.set_string)(self.c, vrs.as_ptr(), vrs.len(), ptrs.as_ptr())
        };
        self.check("fmi2SetString", s)
    }

    /// `fmi2GetRealOutputDerivatives`: derivatives of the given `orders` of outputs `vrs`.
    pub fn get_real_output_derivatives(
        &mut self,
        vrs: &[u32],
        orders: &[i32],
        values: &mut [f64],
    ) -> Result<Status, FmuError> {
        let f = self
            .fmu
            .functions
            .get_real_output_derivatives
            .ok_or(FmuError::Unsupported("fmi2GetRealOutputDerivatives"))?;
        if vrs.len() != values.len() || vrs.len() != orders.len() {
            return Err(mismatch(
                "fmi2GetRealOutputDerivatives",
                vrs.len(),
                values.len().min(orders.len()),
            ));
        }
        // SAFETY: arrays of the given length.
        let s = unsafe {
            f(
                self.c,
                vrs.as_ptr(),
                vrs.len(),
                orders.as_ptr(),
                values.as_mut_ptr(),
            )
        };
        self.check("fmi2GetRealOutputDerivatives", s)
    }

    /// `fmi2SetRealInputDerivatives`.
    pub fn set_real_input_derivatives(
        &mut self,
        vrs: &[u32],
        orders: &[i32],
        values: &[f64],
    ) -> Result<Status, FmuError> {
        let f = self
            .fmu
            .functions
            .set_real_input_derivatives
            .ok_or(FmuError::Unsupported("fmi2SetRealInputDerivatives"))?;
        if vrs.len() != values.len() || vrs.len() != orders.len() {
            return Err(mismatch(
                "fmi2SetRealInputDerivatives",
                vrs.len(),
                values.len().min(orders.len()),
            ));
        }
        // SAFETY: arrays of the given length.
        let s = unsafe {
            f(
                self.c,
                vrs.as_ptr(),
                vrs.len(),
                orders.as_ptr(),
                values.as_ptr(),
            )
        };
        self.check("fmi2SetRealInputDerivatives", s)
    }

    /// `fmi2GetFMUstate`: a new saved state.
    pub fn get_fmu_state(&mut self) -> Result<FmuState, FmuError> {
        self.alive()?;
        let f = self
            .fmu
            .functions
            .get_fmu_state
            .ok_or(FmuError::Unsupported("fmi2GetFMUstate"))?;
        let mut ptr: fmi2FMUstate = std::ptr::null_mut();
        // SAFETY: valid component, out pointer initialized to NULL (asks for a new state).
        let s = unsafe { f(self.c, &mut ptr) };
        self.check("fmi2GetFMUstate", s)?;
        Ok(FmuState { ptr })
    }

    /// `fmi2GetFMUstate` into an existing state (overwrites it).
    pub fn update_fmu_state(&mut self, state: &mut FmuState) -> Result<Status, FmuError> {
        self.alive()?;
        let f = self
            .fmu
            .functions
            .get_fmu_state
            .ok_or(FmuError::Unsupported("fmi2GetFMUstate"))?;
        // SAFETY: valid component and a state made by this instance.
        let s = unsafe { f(self.c, &mut state.ptr) };
        self.check("fmi2GetFMUstate", s)
    }

    /// `fmi2SetFMUstate`.
    pub fn set_fmu_state(&mut self, state: &FmuState) -> Result<Status, FmuError> {
        self.alive()?;
        let f = self
            .fmu
            .functions
            .set_fmu_state
            .ok_or(FmuError::Unsupported("fmi2SetFMUstate"))?;
        // SAFETY: valid component and a state made by this instance.
        let s = unsafe { f(self.c, state.ptr) };
        self.check("fmi2SetFMUstate", s)
    }

    /// `fmi2FreeFMUstate`.
    pub fn free_fmu_state(&mut self, state: FmuState) -> Result<Status, FmuError> {
        self.alive()?;
        let f = self
            .fmu
            .functions
            .free_fmu_state
            .ok_or(FmuError::Unsupported("fmi2FreeFMUstate"))?;
        let mut ptr = state.ptr;
        // SAFETY: valid component and a state made by this instance.
        let s = unsafe { f(self.c, &mut ptr) };
        self.check("fmi2FreeFMUstate", s)
    }

    /// `fmi2SerializedFMUstateSize` + `fmi2SerializeFMUstate`.
    pub fn serialize_fmu_state(&mut self, state: &FmuState) -> Result<Vec<u8>, FmuError> {
        self.alive()?;
        let size_f = self
            .fmu
            .functions
            .serialized_fmu_state_size
            .ok_or(FmuError::Unsupported("fmi2SerializedFMUstateSize"))?;
        let ser_f = self
            .fmu
            .functions
            .serialize_fmu_state
            .ok_or(FmuError::Unsupported("fmi2SerializeFMUstate"))?;
        let mut size = 0usize;
        // SAFETY: valid component and state.
        let s = unsafe { size_f(self.c, state.ptr, &mut size) };
        self.check("fmi2SerializedFMUstateSize", s)?;
        let mut buf = vec![0u8; size];
        // SAFETY: buffer of the announced size.
        let s = unsafe { ser_f(self.c, state.ptr, buf.as_mut_ptr() as *mut fmi2Byte, size) };
        self.check("fmi2SerializeFMUstate", s)?;
        Ok(buf)
    }

    /// `fmi2DeSerializeFMUstate`: a new state from bytes made by
    /// [`serialize_fmu_state`](Self::serialize_fmu_state).
    pub fn deserialize_fmu_state(&mut self, bytes: &[u8]) -> Result<FmuState, FmuError> {
        self.alive()?;
        let f = self
            .fmu
            .functions
            .deserialize_fmu_state
            .ok_or(FmuError::Unsupported("fmi2DeSerializeFMUstate"))?;
        let mut ptr: fmi2FMUstate = std::ptr::null_mut();
        // SAFETY: buffer of the given length, out pointer NULL (asks for a new state).
        let s = unsafe {
            f(
                self.c,
                bytes.as_ptr() as *const fmi2Byte,
                bytes.len(),
                &mut ptr,
            )
        };
        self.check("fmi2DeSerializeFMUstate", s)?;
        Ok(FmuState { ptr })
    }

    /// `fmi2GetStatus(fmi2DoStepStatus)`.
    pub fn get_status(&mut self, kind: fmi2StatusKind) -> Result<fmi2Status, FmuError> {
        self.alive()?;
        let mut v = fmi2StatusCode(0);
        // SAFETY: valid component and out pointer (a C int).
        let s = unsafe { (self.fmu.functions.get_status)(self.c, kind, &mut v) };
        self.check("fmi2GetStatus", s)?;
        v.status().ok_or(FmuError::Call {
            function: "fmi2GetStatus",
            instance: self.name.clone(),
            status: ErrorStatus::Invalid(v.0),
            messages: Vec::new(),
        })
    }

    /// `fmi2GetRealStatus` (e.g. `fmi2LastSuccessfulTime`).
    pub fn get_real_status(&mut self, kind: fmi2StatusKind) -> Result<f64, FmuError> {
        self.alive()?;
        let mut v = 0.0;
        // SAFETY: valid component and out pointer.
        let s = unsafe { (self.fmu.functions.get_real_status)(self.c, kind, &mut v) };
        match self.check("fmi2GetRealStatus", s)? {
            Status::Discard => Err(FmuError::Unsupported("fmi2GetRealStatus for this kind")),
            _ => Ok(v),
        }
    }

    /// `fmi2GetIntegerStatus`.
    pub fn get_integer_status(&mut self, kind: fmi2StatusKind) -> Result<i32, FmuError> {
        self.alive()?;
        let mut v = 0;
        // SAFETY: valid component and out pointer.
        let s = unsafe { (self.fmu.functions.get_integer_status)(self.c, kind, &mut v) };
        match self.check("fmi2GetIntegerStatus", s)? {
            Status::Discard => Err(FmuError::Unsupported("fmi2GetIntegerStatus for this kind")),
            _ => Ok(v),
        }
    }

    /// `fmi2GetBooleanStatus` (e.g. `fmi2Terminated`).
    pub fn get_boolean_status(&mut self, kind: fmi2StatusKind) -> Result<bool, FmuError> {
        self.alive()?;
        let mut v = fmi2False;
        // SAFETY: valid component and out pointer.
        let s = unsafe { (self.fmu.functions.get_boolean_status)(self.c, kind, &mut v) };
        match self.check("fmi2GetBooleanStatus", s)? {
            Status::Discard => Err(FmuError::Unsupported("fmi2GetBooleanStatus for this kind")),
            _ => Ok(v != 0),
        }
    }

    /// `fmi2GetStringStatus`.
    pub fn get_string_status(&mut self, kind: fmi2StatusKind) -> Result<String, FmuError> {
        self.alive()?;
        let mut v: fmi2String = std::ptr::null();
        // SAFETY: valid component and out pointer.
        let s = unsafe { (self.fmu.functions.get_string_status)(self.c, kind, &mut v) };
        self.check("fmi2GetStringStatus", s)?;
        // SAFETY: NUL-terminated or NULL.
        Ok(unsafe { cstr_lossy(v) })
    }

    /// Whether the FMU asks to end the simulation (`fmi2GetBooleanStatus(fmi2Terminated)`);
    /// false when the FMU cannot tell.
    pub fn terminated(&mut self) -> bool {
        self.get_boolean_status(fmi2StatusKind::fmi2Terminated)
            .unwrap_or(false)
    }

    /// `fmi2GetRealStatus(fmi2LastSuccessfulTime)`, if the FMU answers.
    pub fn last_successful_time(&mut self) -> Option<f64> {
        self.get_real_status(fmi2StatusKind::fmi2LastSuccessfulTime)
            .ok()
    }
}

fn mismatch(function: &'static str, refs: usize, values: usize) -> FmuError {
    FmuError::LengthMismatch {
        function,
        refs,
        values,
    }
}

impl Drop for Instance {
    fn drop(&mut self) {
        let f = &self.fmu.functions;
        // SAFETY: the component is valid; the callbacks and context outlive the free call.
        unsafe {
            match self.phase {
                Phase::Fatal => return, // no call allowed: leak
                Phase::Initialization | Phase::StepComplete => {
                    let _ = (f.terminate)(self.c);
                }
                _ => {}
            }
            (f.free_instance)(self.c);
        }
    }
}
