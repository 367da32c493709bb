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
//!
//! The modules: `log` (the callbacks handed to the FMU, the messages), `error` (what a call
//! gives), `state` (saved FMU states), `exchange` (the master's set-step-get of one component
//! in one call); the instance and its calls here.

use std::ffi::CString;
use std::fmt;
use std::sync::Arc;

use crate::embedded_python::ThreadStateUser;
use crate::fmi2::*;
use crate::isolate::remote::{RemoteFail, RemoteInstance};
use crate::isolate::{HostFailure, *};
use crate::load::{Exec, Fmu, FmuShared, Functions, LoadError, cstr_lossy};

mod error;
mod exchange;
mod log;

pub use error::{ErrorStatus, FmuError, HostError, Status};
pub use exchange::Exchange;
pub(crate) use log::{LogContext, callbacks_for};
pub use log::{LogHandler, LogMessage, LogStatus, RECENT_MESSAGES, stderr_log_handler};
pub use state::FmuState;

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

/// One FMI 2.0 co-simulation instance. Dropping it terminates it when it is initialized and
/// frees it (except after `fmi2Fatal`, when freeing is not allowed and the instance is leaked).
///
/// The instance runs in this process or, for an FMU loaded with isolation, in a host process of
/// its own ([`crate::isolate`]): the API is the same.
pub struct Instance {
    fmu: Arc<FmuShared>,
    name: String,
    phase: Phase,
    backend: Backend,
    // Boxed so that its address stays fixed: the FMU keeps the pointer.
    ctx: Box<LogContext>,
}

// The in-process variant carries the function table inline (no pointer chase on the hot
// path); there is one Instance per component, so the size does not matter.
#[allow(clippy::large_enum_variant)]
enum Backend {
    Local(Local),
    Remote(Box<RemoteInstance>),
}

/// An instance in this process.
struct Local {
    c: fmi2Component,
    f: Functions,
    /// Its id in [`crate::inflight`], which names the call in progress.
    id: u32,
    /// For a binary with an embedded CPython: the calling thread's Python thread state
    /// ([`crate::embedded_python`]). Dropped after the instance is freed.
    python: Option<ThreadStateUser>,
    // Boxed so that its address stays fixed: the FMU may keep the pointer.
    _callbacks: Box<fmi2CallbackFunctions>,
    _name_c: CString,
}

// SAFETY: an fmi2Component may be used from any thread as long as calls are not concurrent,
// which &mut self guarantees. FMUs are expected not to share mutable state between instances
// (parallel stepping is opt-in and documented as requiring that). A remote instance is pipes
// and plain data.
unsafe impl Send for Instance {}

impl fmt::Debug for Instance {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Instance")
            .field("name", &self.name)
            .field("phase", &self.phase)
            .field("isolated", &matches!(self.backend, Backend::Remote(_)))
            .finish()
    }
}

impl Fmu {
    /// Instantiates the FMU for co-simulation (`fmi2Instantiate` with the GUID of the model
    /// description; an FMU whose binary was built for another description refuses here). For
    /// an isolated FMU this starts the instance's host process.
    pub fn instantiate(&self, name: &str, options: &InstanceOptions) -> Result<Instance, FmuError> {
        let name_c = CString::new(name).map_err(|_| FmuError::NulInString)?;
        let ctx = LogContext::new(
            options.log_handler.clone(),
            std::env::var_os("KNEEBENCH_DEBUG").is_some(),
        );
        let backend = match &self.shared.exec {
            Exec::Local(b) => {
                let callbacks = callbacks_for(&ctx);
                let f = b.functions;
                let id = crate::inflight::register(format!(
                    "FMU '{}', instance '{name}'",
                    self.shared.md.model_name
                ));
                let call = crate::inflight::Call::enter(id, &"fmi2Instantiate");
                // SAFETY: all pointers are valid NUL-terminated strings / a callbacks struct
                // that live as long as the instance.
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
                drop(call);
                if c.is_null() {
                    crate::inflight::unregister(id);
                    return Err(FmuError::Instantiate {
                        instance: name.to_string(),
                        messages: ctx.take_recent(),
                    });
                }
                let python = ThreadStateUser::for_instance(
                    self.shared.python,
                    self.shared.keep_python_thread_state,
                    self.shared.clone() as crate::embedded_python::KeepLoaded,
                );
                Backend::Local(Local {
                    c,
                    f,
                    id,
                    python,
                    _callbacks: callbacks,
                    _name_c: name_c,
                })
            }
            Exec::Remote(r) => {
                let host_err = |failure| {
                    FmuError::Host(Box::new(HostError {
                        model: self.shared.md.model_name.clone(),
                        instance: name.to_string(),
                        function: "fmi2Instantiate",
                        queued: 0,
                        failure,
                        messages: ctx.take_recent(),
                    }))
                };
                let process = r.process().map_err(|e| match e {
                    LoadError::Host { failure, .. } => host_err(failure),
                    other => host_err(HostFailure::Start(other.to_string())),
                })?;
                let remote = RemoteInstance::instantiate(
                    process,
                    name,
                    &self.shared.md.guid,
                    self.resource_uri(),
                    options.visible,
                    options.logging_on,
                    &ctx,
                )
                .map_err(host_err)?;
                match remote {
                    Some(remote) => Backend::Remote(Box::new(remote)),
                    None => {
                        return Err(FmuError::Instantiate {
                            instance: name.to_string(),
                            messages: ctx.take_recent(),
                        });
                    }
                }
            }
        };
        Ok(Instance {
            fmu: self.shared.clone(),
            name: name.to_string(),
            phase: Phase::Instantiated,
            backend,
            ctx,
        })
    }
}

/// Runs `$local` (an expression over the in-process `Local` `$l`, marked as the call
/// `$function` in progress for [`crate::inflight`]) or `$remote` (over the
/// `RemoteInstance` `$r` and the `LogContext` `$ctx`, giving `Result<T, RemoteFail>`), mapping
/// a remote failure to an `FmuError` (the enclosing function returns it).
macro_rules! dispatch {
    ($self:ident, $function:expr, $l:ident => $local:expr, ($r:ident, $ctx:ident) => $remote:expr) => {
        match &mut $self.backend {
            Backend::Local($l) => {
                let _call = $l.enter($function);
                $local
            }
            Backend::Remote($r) => {
                let $ctx = &*$self.ctx;
                match $remote {
                    Ok(v) => v,
                    Err(e) => return Err($self.remote_fail(e)),
                }
            }
        }
    };
}

// After `dispatch!`, which it uses.
mod state;

impl Local {
    /// Before each FMI call: the calling thread's Python thread state for a binary with an
    /// embedded CPython, and the call's mark in [`crate::inflight`].
    #[inline(always)]
    fn enter(&mut self, function: &'static &'static str) -> crate::inflight::Call {
        if let Some(p) = &mut self.python {
            p.enter();
        }
        crate::inflight::Call::enter(self.id, function)
    }
}

/// A call of the remote instance that sends `op` with `args` and decodes nothing.
fn plain(
    r: &mut RemoteInstance,
    ctx: &LogContext,
    op: u8,
    args: impl FnOnce(&mut Enc),
) -> Result<fmi2StatusCode, RemoteFail> {
    r.call(ctx, op, args, false, |_| Ok(())).map(|x| x.0)
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

    /// Whether the instance runs in a host process ([`crate::isolate`]).
    pub fn is_isolated(&self) -> bool {
        matches!(self.backend, Backend::Remote(_))
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

    /// The error of a remote call that did not give a status: a queued set that failed, or the
    /// host process that died (the instance is then unusable: phase [`Phase::Error`]).
    #[cold]
    fn remote_fail(&mut self, e: RemoteFail) -> FmuError {
        match e {
            RemoteFail::Call { function, code } => self.error(function, code),
            RemoteFail::Host {
                function,
                queued,
                failure,
            } => {
                self.phase = Phase::Error;
                FmuError::Host(Box::new(HostError {
                    model: self.fmu.md.model_name.clone(),
                    instance: self.name.clone(),
                    function,
                    queued,
                    failure,
                    messages: self.ctx.take_recent(),
                }))
            }
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

    /// Whether the binary exports the optional function `name`.
    fn has(&self, name: &'static str) -> Result<(), FmuError> {
        if self.fmu.missing_optional().contains(&name) {
            Err(FmuError::Unsupported(name))
        } else {
            Ok(())
        }
    }

    /// Checks that the model description promises the optional function `name` through the
    /// capability flag `flag`, which `promised` reads from its `CoSimulation` element (an FMU
    /// that declares the flag false or leaves it out is not asked: [`FmuError::NotPromised`]).
    fn promises(
        &self,
        name: &'static str,
        flag: &'static str,
        promised: impl FnOnce(&model_description::CoSimulation) -> Option<bool>,
    ) -> Result<(), FmuError> {
        match self.fmu.md.co_simulation.as_ref().and_then(promised) {
            Some(true) => Ok(()),
            _ => Err(FmuError::NotPromised {
                function: name,
                flag,
            }),
        }
    }

    /// Checks that the model description promises the FMU-state function `name`: with
    /// `serialize` its `canSerializeFMUstate`, else its `canGetAndSetFMUstate` (kneebench's
    /// `BenchHardware` declares both false).
    fn promises_state(&self, name: &'static str, serialize: bool) -> Result<(), FmuError> {
        if serialize {
            self.promises(name, "canSerializeFMUstate", |c| c.can_serialize_fmu_state)
        } else {
            self.promises(name, "canGetAndSetFMUstate", |c| {
                c.can_get_and_set_fmu_state
            })
        }
    }

    /// Checks that the model description promises asynchronous steps (`canRunAsynchronuously`),
    /// which `fmi2CancelStep` and the status of a pending step (`fmi2DoStepStatus`,
    /// `fmi2PendingStatus`) are for; `function` names the call refused.
    fn promises_asynchronous(&self, function: &'static str) -> Result<(), FmuError> {
        self.promises(function, "canRunAsynchronuously", |c| {
            c.can_run_asynchronuously
        })
    }

    /// Checks a status query of `kind`: one about a pending step needs
    /// [`promises_asynchronous`](Self::promises_asynchronous); `names` are the function's
    /// name with `fmi2DoStepStatus` and with `fmi2PendingStatus`.
    fn promises_status(
        &self,
        kind: fmi2StatusKind,
        names: [&'static str; 2],
    ) -> Result<(), FmuError> {
        match kind {
            fmi2StatusKind::fmi2DoStepStatus => self.promises_asynchronous(names[0]),
            fmi2StatusKind::fmi2PendingStatus => self.promises_asynchronous(names[1]),
            _ => Ok(()),
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
        let s = dispatch!(self, &"fmi2SetDebugLogging",
            l => {
                // SAFETY: valid component and an array of valid strings.
                unsafe { (l.f.set_debug_logging)(l.c, on as fmi2Boolean, ptrs.len(), ptrs.as_ptr()) }
            },
            (r, ctx) => plain(r, ctx, CALL_SET_DEBUG_LOGGING, |e| {
                e.u8(on as u8);
                e.u32(categories.len() as u32);
                for c in categories {
                    e.str(c);
                }
            })
        );
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
        let s = dispatch!(self, &"fmi2SetupExperiment",
            l => {
                // SAFETY: valid component.
                unsafe {
                    (l.f.setup_experiment)(
                        l.c,
                        tolerance.is_some() as fmi2Boolean,
                        tolerance.unwrap_or(0.0),
                        start_time,
                        stop_time.is_some() as fmi2Boolean,
                        stop_time.unwrap_or(0.0),
                    )
                }
            },
            (r, ctx) => plain(r, ctx, CALL_SETUP_EXPERIMENT, |e| {
                e.u8(tolerance.is_some() as u8);
                e.f64(tolerance.unwrap_or(0.0));
                e.f64(start_time);
                e.u8(stop_time.is_some() as u8);
                e.f64(stop_time.unwrap_or(0.0));
            })
        );
        self.check("fmi2SetupExperiment", s)
    }

    /// A call with the component as its only argument.
    fn component_only(
        &mut self,
        op: u8,
        function: &'static &'static str,
        local: impl FnOnce(&Functions) -> fmi2ComponentOnlyTYPE,
    ) -> Result<Status, FmuError> {
        self.alive()?;
        let s = dispatch!(self, function,
            l => {
                // SAFETY: valid component.
                unsafe { local(&l.f)(l.c) }
            },
            (r, ctx) => plain(r, ctx, op, |_| {})
        );
        self.check(function, s)
    }

    /// `fmi2EnterInitializationMode`.
    pub fn enter_initialization_mode(&mut self) -> Result<Status, FmuError> {
        let r = self.component_only(
            CALL_ENTER_INITIALIZATION,
            &"fmi2EnterInitializationMode",
            |f| f.enter_initialization_mode,
        )?;
        self.phase = Phase::Initialization;
        Ok(r)
    }

    /// `fmi2ExitInitializationMode`.
    pub fn exit_initialization_mode(&mut self) -> Result<Status, FmuError> {
        let r = self.component_only(
            CALL_EXIT_INITIALIZATION,
            &"fmi2ExitInitializationMode",
            |f| f.exit_initialization_mode,
        )?;
        self.phase = Phase::StepComplete;
        Ok(r)
    }

    /// `fmi2DoStep` (with `noSetFMUStatePriorToCurrentPoint = true`).
    ///
    /// `Ok(Status::Discard)` means the step was not done: see
    /// [`terminated`](Self::terminated) and [`last_successful_time`](Self::last_successful_time).
    #[inline]
    pub fn do_step(&mut self, current_time: f64, step_size: f64) -> Result<Status, FmuError> {
        let s = dispatch!(self, &"fmi2DoStep",
            l => {
                // SAFETY: valid component (a Fatal instance is refused by the caller's phase
                // check in `alive`, kept out of this hot path: after fmi2Fatal the master stops).
                unsafe { (l.f.do_step)(l.c, current_time, step_size, fmi2True) }
            },
            (r, ctx) => r
                .call(
                    ctx,
                    CALL_DO_STEP,
                    |e| {
                        e.f64(current_time);
                        e.f64(step_size);
                    },
                    true,
                    |_| Ok(()),
                )
                .map(|x| x.0)
        );
        self.check("fmi2DoStep", s)
    }

    /// `fmi2CancelStep`: only for an FMU whose model description declares
    /// `canRunAsynchronuously="true"` ([`FmuError::NotPromised`] otherwise, the call not made).
    pub fn cancel_step(&mut self) -> Result<Status, FmuError> {
        self.promises_asynchronous("fmi2CancelStep")?;
        self.component_only(CALL_CANCEL_STEP, &"fmi2CancelStep", |f| f.cancel_step)
    }

    /// `fmi2Terminate`.
    pub fn terminate(&mut self) -> Result<Status, FmuError> {
        let r = self.component_only(CALL_TERMINATE, &"fmi2Terminate", |f| f.terminate)?;
        self.phase = Phase::Terminated;
        Ok(r)
    }

    /// `fmi2Reset`: back to the state after instantiation.
    pub fn reset(&mut self) -> Result<Status, FmuError> {
        let r = self.component_only(CALL_RESET, &"fmi2Reset", |f| f.reset)?;
        self.phase = Phase::Instantiated;
        self.ctx.clear();
        Ok(r)
    }

    /// `fmi2GetReal` into `values` (same length as `vrs`).
    #[inline]
    pub fn get_real(&mut self, vrs: &[u32], values: &mut [f64]) -> Result<Status, FmuError> {
        self.get_real_inlined(vrs, values)
    }

    /// [`get_real`](Self::get_real), inlined where it is called: in
    /// [`get_outputs`](Self::get_outputs), the master's read of every step.
    #[inline(always)]
    fn get_real_inlined(&mut self, vrs: &[u32], values: &mut [f64]) -> Result<Status, FmuError> {
        if vrs.len() != values.len() {
            return Err(mismatch("fmi2GetReal", vrs.len(), values.len()));
        }
        if vrs.is_empty() {
            return Ok(Status::Ok);
        }
        let s = dispatch!(self, &"fmi2GetReal",
            l => {
                // SAFETY: arrays of the given length.
                unsafe { (l.f.get_real)(l.c, vrs.as_ptr(), vrs.len(), values.as_mut_ptr()) }
            },
            (r, ctx) => r.get_real(ctx, vrs, values)
        );
        self.check("fmi2GetReal", s)
    }

    /// `fmi2GetInteger` into `values`.
    #[inline]
    pub fn get_integer(&mut self, vrs: &[u32], values: &mut [i32]) -> Result<Status, FmuError> {
        self.get_integer_inlined(vrs, values)
    }

    /// [`get_integer`](Self::get_integer), inlined where it is called (as
    /// [`get_real_inlined`](Self::get_real_inlined)).
    #[inline(always)]
    fn get_integer_inlined(&mut self, vrs: &[u32], values: &mut [i32]) -> Result<Status, FmuError> {
        if vrs.len() != values.len() {
            return Err(mismatch("fmi2GetInteger", vrs.len(), values.len()));
        }
        if vrs.is_empty() {
            return Ok(Status::Ok);
        }
        let s = dispatch!(self, &"fmi2GetInteger",
            l => {
                // SAFETY: arrays of the given length.
                unsafe { (l.f.get_integer)(l.c, vrs.as_ptr(), vrs.len(), values.as_mut_ptr()) }
            },
            (r, ctx) => r.get_ints(ctx, CALL_GET_INTEGER, vrs, values)
        );
        self.check("fmi2GetInteger", s)
    }

    /// `fmi2GetBoolean` into `values` (`fmi2Boolean` is a C int: 0 false, anything else true).
    #[inline]
    pub fn get_boolean_raw(
        &mut self,
        vrs: &[u32],
        values: &mut [fmi2Boolean],
    ) -> Result<Status, FmuError> {
        self.get_boolean_raw_inlined(vrs, values)
    }

    /// [`get_boolean_raw`](Self::get_boolean_raw), inlined where it is called (as
    /// [`get_real_inlined`](Self::get_real_inlined)).
    #[inline(always)]
    fn get_boolean_raw_inlined(
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
        let s = dispatch!(self, &"fmi2GetBoolean",
            l => {
                // SAFETY: arrays of the given length.
                unsafe { (l.f.get_boolean)(l.c, vrs.as_ptr(), vrs.len(), values.as_mut_ptr()) }
            },
            (r, ctx) => r.get_ints(ctx, CALL_GET_BOOLEAN, vrs, values)
        );
        self.check("fmi2GetBoolean", s)
    }

    /// The master's read of one component's outputs after a step: [`get_real`](Self::get_real)
    /// of `vrs[0]` into `real`, [`get_integer`](Self::get_integer) of `vrs[1]` into `int`,
    /// [`get_boolean_raw`](Self::get_boolean_raw) of `vrs[2]` into `boolean`, in that order
    /// (each leaves out an empty list; the first error ends the read; a status other than an
    /// error is not reported), in one function the master calls for every component and step.
    #[inline]
    pub fn get_outputs(
        &mut self,
        vrs: [&[u32]; 3],
        real: &mut [f64],
        int: &mut [i32],
        boolean: &mut [fmi2Boolean],
    ) -> Result<(), FmuError> {
        self.get_real_inlined(vrs[0], real)?;
        self.get_integer_inlined(vrs[1], int)?;
        self.get_boolean_raw_inlined(vrs[2], boolean)?;
        Ok(())
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
        if vrs.is_empty() {
            return Ok(Vec::new());
        }
        let (s, strings) = dispatch!(self, &"fmi2GetString",
            l => {
                let mut ptrs: Vec<fmi2String> = vec![std::ptr::null(); vrs.len()];
                // SAFETY: arrays of the given length.
                let s = unsafe { (l.f.get_string)(l.c, vrs.as_ptr(), vrs.len(), ptrs.as_mut_ptr()) };
                // SAFETY: after a successful call the FMU returned NUL-terminated strings (or
                // NULL) valid until the next call.
                let strings = if s.0 <= 2 {
                    ptrs.iter().map(|&p| unsafe { cstr_lossy(p) }).collect()
                } else {
                    Vec::new()
                };
                (s, strings)
            },
            (r, ctx) => r.call(ctx, CALL_GET_STRING, |e| e.u32s(vrs), false, |d| d.strings())
        );
        self.check("fmi2GetString", s)?;
        Ok(strings)
    }

    /// `fmi2SetReal`. For an isolated instance the set is queued and sent with the next call
    /// that needs an answer (which reports its error, see [`crate::isolate`]).
    #[inline]
    pub fn set_real(&mut self, vrs: &[u32], values: &[f64]) -> Result<Status, FmuError> {
        if vrs.len() != values.len() {
            return Err(mismatch("fmi2SetReal", vrs.len(), values.len()));
        }
        if vrs.is_empty() {
            return Ok(Status::Ok);
        }
        let s = match &mut self.backend {
            Backend::Local(l) => {
                let _call = l.enter(&"fmi2SetReal");
                // SAFETY: arrays of the given length.
                unsafe { (l.f.set_real)(l.c, vrs.as_ptr(), vrs.len(), values.as_ptr()) }
            }
            Backend::Remote(r) => {
                r.queue(CALL_SET_REAL, |e| {
                    e.u32s(vrs);
                    e.f64s(values);
                });
                fmi2StatusCode(0)
            }
        };
        self.check("fmi2SetReal", s)
    }

    /// `fmi2SetInteger` (queued for an isolated instance, as [`set_real`](Self::set_real)).
    #[inline]
    pub fn set_integer(&mut self, vrs: &[u32], values: &[i32]) -> Result<Status, FmuError> {
        if vrs.len() != values.len() {
            return Err(mismatch("fmi2SetInteger", vrs.len(), values.len()));
        }
        if vrs.is_empty() {
            return Ok(Status::Ok);
        }
        let s = match &mut self.backend {
            Backend::Local(l) => {
                let _call = l.enter(&"fmi2SetInteger");
                // SAFETY: arrays of the given length.
                unsafe { (l.f.set_integer)(l.c, vrs.as_ptr(), vrs.len(), values.as_ptr()) }
            }
            Backend::Remote(r) => {
                r.queue(CALL_SET_INTEGER, |e| {
                    e.u32s(vrs);
                    e.i32s(values);
                });
                fmi2StatusCode(0)
            }
        };
        self.check("fmi2SetInteger", s)
    }

    /// `fmi2SetBoolean` from C ints (0 false, 1 true; queued for an isolated instance).
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
        let s = match &mut self.backend {
            Backend::Local(l) => {
                let _call = l.enter(&"fmi2SetBoolean");
                // SAFETY: arrays of the given length.
                unsafe { (l.f.set_boolean)(l.c, vrs.as_ptr(), vrs.len(), values.as_ptr()) }
            }
            Backend::Remote(r) => {
                r.queue(CALL_SET_BOOLEAN, |e| {
                    e.u32s(vrs);
                    e.i32s(values);
                });
                fmi2StatusCode(0)
            }
        };
        self.check("fmi2SetBoolean", s)
    }

    /// `fmi2SetBoolean` from `bool`s.
    pub fn set_boolean(&mut self, vrs: &[u32], values: &[bool]) -> Result<Status, FmuError> {
        let raw: Vec<fmi2Boolean> = values.iter().map(|&b| b as fmi2Boolean).collect();
        self.set_boolean_raw(vrs, &raw)
    }

    /// `fmi2SetString` (queued for an isolated instance).
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
        let s = match &mut self.backend {
            Backend::Local(l) => {
                let _call = l.enter(&"fmi2SetString");
                // SAFETY: arrays of the given length of valid strings.
                unsafe { (l.f.set_string)(l.c, vrs.as_ptr(), vrs.len(), ptrs.as_ptr()) }
            }
            Backend::Remote(r) => {
                r.queue(CALL_SET_STRING, |e| {
                    e.u32s(vrs);
                    e.u32(values.len() as u32);
                    for v in values {
                        e.str(v);
                    }
                });
                fmi2StatusCode(0)
            }
        };
        self.check("fmi2SetString", s)
    }

    /// `fmi2GetRealOutputDerivatives`: derivatives of the given `orders` of outputs `vrs`;
    /// every order from 1 to the model description's `maxOutputDerivativeOrder`
    /// ([`FmuError::DerivativeOrderNotPromised`] otherwise, the call not made).
    pub fn get_real_output_derivatives(
        &mut self,
        vrs: &[u32],
        orders: &[i32],
        values: &mut [f64],
    ) -> Result<Status, FmuError> {
        const NAME: &str = "fmi2GetRealOutputDerivatives";
        self.has(NAME)?;
        if vrs.len() != values.len() || vrs.len() != orders.len() {
            return Err(mismatch(NAME, vrs.len(), values.len().min(orders.len())));
        }
        let max = self
            .fmu
            .md
            .co_simulation
            .as_ref()
            .and_then(|c| c.max_output_derivative_order)
            .unwrap_or(0);
        if let Some(&order) = orders
            .iter()
            .find(|&&o| o < 1 || u32::try_from(o).is_ok_and(|o| o > max))
        {
            return Err(FmuError::DerivativeOrderNotPromised {
                function: NAME,
                order,
                max,
            });
        }
        let s = dispatch!(self, &NAME,
            l => {
                let f = l.f.get_real_output_derivatives.ok_or(FmuError::Unsupported(NAME))?;
                // SAFETY: arrays of the given length.
                unsafe { f(l.c, vrs.as_ptr(), vrs.len(), orders.as_ptr(), values.as_mut_ptr()) }
            },
            (r, ctx) => r
                .call(
                    ctx,
                    CALL_GET_OUTPUT_DERIVATIVES,
                    |e| {
                        e.u32s(vrs);
                        e.i32s(orders);
                    },
                    false,
                    |d| d.f64s_into(values),
                )
                .map(|x| x.0)
        );
        self.check(NAME, s)
    }

    /// `fmi2SetRealInputDerivatives`: only for an FMU whose model description declares
    /// `canInterpolateInputs="true"` ([`FmuError::NotPromised`] otherwise, the call not made).
    pub fn set_real_input_derivatives(
        &mut self,
        vrs: &[u32],
        orders: &[i32],
        values: &[f64],
    ) -> Result<Status, FmuError> {
        const NAME: &str = "fmi2SetRealInputDerivatives";
        self.has(NAME)?;
        self.promises(NAME, "canInterpolateInputs", |c| c.can_interpolate_inputs)?;
        if vrs.len() != values.len() || vrs.len() != orders.len() {
            return Err(mismatch(NAME, vrs.len(), values.len().min(orders.len())));
        }
        let s = dispatch!(self, &NAME,
            l => {
                let f = l.f.set_real_input_derivatives.ok_or(FmuError::Unsupported(NAME))?;
                // SAFETY: arrays of the given length.
                unsafe { f(l.c, vrs.as_ptr(), vrs.len(), orders.as_ptr(), values.as_ptr()) }
            },
            (r, ctx) => plain(r, ctx, CALL_SET_INPUT_DERIVATIVES, |e| {
                e.u32s(vrs);
                e.i32s(orders);
                e.f64s(values);
            })
        );
        self.check(NAME, s)
    }

    /// A status query: `op` remotely, `local` in this process; the value decoded by `decode`.
    fn status_query<T>(
        &mut self,
        function: &'static &'static str,
        op: u8,
        kind: fmi2StatusKind,
        local: impl FnOnce(&Local) -> (fmi2StatusCode, T),
        decode: impl FnOnce(&mut Dec<'_>) -> Result<T, ProtocolError>,
    ) -> Result<(fmi2StatusCode, T), FmuError> {
        self.alive()?;
        Ok(dispatch!(self, function,
            l => local(l),
            (r, ctx) => r.call(ctx, op, |e| e.i32(kind as i32), false, decode)
        ))
    }

    /// `fmi2GetStatus`: of a pending step (`fmi2DoStepStatus`, `fmi2PendingStatus`) only for an
    /// FMU whose model description declares `canRunAsynchronuously="true"`
    /// ([`FmuError::NotPromised`] otherwise, the call not made).
    pub fn get_status(&mut self, kind: fmi2StatusKind) -> Result<fmi2Status, FmuError> {
        self.promises_status(
            kind,
            [
                "fmi2GetStatus(fmi2DoStepStatus)",
                "fmi2GetStatus(fmi2PendingStatus)",
            ],
        )?;
        let (s, v) = self.status_query(
            &"fmi2GetStatus",
            CALL_GET_STATUS,
            kind,
            |l| {
                let mut v = fmi2StatusCode(0);
                // SAFETY: valid component and out pointer (a C int).
                let s = unsafe { (l.f.get_status)(l.c, kind, &mut v) };
                (s, v)
            },
            |d| d.i32().map(fmi2StatusCode),
        )?;
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
        let (s, v) = self.status_query(
            &"fmi2GetRealStatus",
            CALL_GET_REAL_STATUS,
            kind,
            |l| {
                let mut v = 0.0;
                // SAFETY: valid component and out pointer.
                let s = unsafe { (l.f.get_real_status)(l.c, kind, &mut v) };
                (s, v)
            },
            |d| d.f64(),
        )?;
        match self.check("fmi2GetRealStatus", s)? {
            Status::Discard => Err(FmuError::Unsupported("fmi2GetRealStatus for this kind")),
            _ => Ok(v),
        }
    }

    /// `fmi2GetIntegerStatus`.
    pub fn get_integer_status(&mut self, kind: fmi2StatusKind) -> Result<i32, FmuError> {
        let (s, v) = self.status_query(
            &"fmi2GetIntegerStatus",
            CALL_GET_INTEGER_STATUS,
            kind,
            |l| {
                let mut v = 0;
                // SAFETY: valid component and out pointer.
                let s = unsafe { (l.f.get_integer_status)(l.c, kind, &mut v) };
                (s, v)
            },
            |d| d.i32(),
        )?;
        match self.check("fmi2GetIntegerStatus", s)? {
            Status::Discard => Err(FmuError::Unsupported("fmi2GetIntegerStatus for this kind")),
            _ => Ok(v),
        }
    }

    /// `fmi2GetBooleanStatus` (e.g. `fmi2Terminated`).
    pub fn get_boolean_status(&mut self, kind: fmi2StatusKind) -> Result<bool, FmuError> {
        let (s, v) = self.status_query(
            &"fmi2GetBooleanStatus",
            CALL_GET_BOOLEAN_STATUS,
            kind,
            |l| {
                let mut v = fmi2False;
                // SAFETY: valid component and out pointer.
                let s = unsafe { (l.f.get_boolean_status)(l.c, kind, &mut v) };
                (s, v)
            },
            |d| d.i32(),
        )?;
        match self.check("fmi2GetBooleanStatus", s)? {
            Status::Discard => Err(FmuError::Unsupported("fmi2GetBooleanStatus for this kind")),
            _ => Ok(v != 0),
        }
    }

    /// `fmi2GetStringStatus`: of a pending step (`fmi2PendingStatus`) only for an FMU whose
    /// model description declares `canRunAsynchronuously="true"` ([`FmuError::NotPromised`]
    /// otherwise, the call not made).
    pub fn get_string_status(&mut self, kind: fmi2StatusKind) -> Result<String, FmuError> {
        self.promises_status(
            kind,
            [
                "fmi2GetStringStatus(fmi2DoStepStatus)",
                "fmi2GetStringStatus(fmi2PendingStatus)",
            ],
        )?;
        let (s, v) = self.status_query(
            &"fmi2GetStringStatus",
            CALL_GET_STRING_STATUS,
            kind,
            |l| {
                let mut v: fmi2String = std::ptr::null();
                // SAFETY: valid component and out pointer.
                let s = unsafe { (l.f.get_string_status)(l.c, kind, &mut v) };
                // SAFETY: NUL-terminated or NULL after a successful call.
                let text = if s.0 <= 2 {
                    unsafe { cstr_lossy(v) }
                } else {
                    String::new()
                };
                (s, text)
            },
            |d| d.string(),
        )?;
        self.check("fmi2GetStringStatus", s)?;
        Ok(v)
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
        match &mut self.backend {
            Backend::Local(l) => {
                let f = l.f;
                // SAFETY: the component is valid; the callbacks and context outlive the free
                // call.
                unsafe {
                    match self.phase {
                        Phase::Fatal => {} // no call allowed: leak
                        Phase::Initialization | Phase::StepComplete => {
                            let _call = l.enter(&"fmi2Terminate");
                            let _ = (f.terminate)(l.c);
                        }
                        _ => {}
                    }
                    if self.phase != Phase::Fatal {
                        let _call = l.enter(&"fmi2FreeInstance");
                        (f.free_instance)(l.c);
                    }
                }
                crate::inflight::unregister(l.id);
                // After fmi2FreeInstance (which still found the thread state): the thread's
                // Python thread state goes with its last instance.
                drop(l.python.take());
            }
            // The host terminates (when initialized) and frees its instance when its pipe
            // closes (dropping the process), and leaves it alone after fmi2Fatal.
            Backend::Remote(_) => {}
        }
    }
}
