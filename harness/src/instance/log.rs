//! The callbacks an instance hands its FMU in `fmi2Instantiate`: the logger (a small C shim
//! that formats the C-variadic message, then [`LogContext::deliver`]) and libc's allocator; the
//! messages, kept in a bounded ring and forwarded to the instance's [`LogHandler`].

use std::collections::VecDeque;
use std::ffi::{c_char, c_int, c_void};
use std::fmt;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::{Arc, Mutex};

use crate::fmi2::*;
use crate::load::cstr_lossy;

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
    /// The status of a logger call's `fmi2Status` argument (also what an isolated FMU's host
    /// sends for it).
    pub(crate) fn from_c(s: c_int) -> LogStatus {
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

/// The per-instance context the FMU's `componentEnvironment` points to.
pub(crate) struct LogContext {
    handler: Option<LogHandler>,
    debug_print: bool,
    recent: Mutex<VecDeque<LogMessage>>,
}

impl LogContext {
    pub(crate) fn new(handler: Option<LogHandler>, debug_print: bool) -> Box<LogContext> {
        Box::new(LogContext {
            handler,
            debug_print,
            recent: Mutex::new(VecDeque::with_capacity(RECENT_MESSAGES)),
        })
    }
    pub(super) fn take_recent(&self) -> Vec<LogMessage> {
        match self.recent.lock() {
            Ok(mut r) => r.drain(..).collect(),
            Err(p) => p.into_inner().drain(..).collect(),
        }
    }
    pub(super) fn clear(&self) {
        match self.recent.lock() {
            Ok(mut r) => r.clear(),
            Err(p) => p.into_inner().clear(),
        }
    }
    /// Prints (with `KNEEBENCH_DEBUG`), hands to the handler and keeps one message.
    pub(crate) fn deliver(&self, msg: LogMessage) {
        if self.debug_print {
            eprintln!("{msg}");
        }
        if let Some(h) = &self.handler {
            h(&msg);
        }
        let mut recent = match self.recent.lock() {
            Ok(r) => r,
            Err(p) => p.into_inner(),
        };
        if recent.len() == RECENT_MESSAGES {
            recent.pop_front();
        }
        recent.push_back(msg);
    }
}

/// The callbacks passed to `fmi2Instantiate`: the logging shim with `ctx` as the environment,
/// libc's allocator. Boxed: the FMU may keep the pointer.
pub(crate) fn callbacks_for(ctx: &LogContext) -> Box<fmi2CallbackFunctions> {
    // SAFETY: kneebench_logger has the C signature of fmi2CallbackLogger (the status is a C
    // enum, passed as int).
    let logger: fmi2CallbackLogger = Some(kneebench_logger);
    Box::new(fmi2CallbackFunctions {
        logger,
        allocateMemory: Some(fmi_calloc),
        freeMemory: Some(fmi_free),
        stepFinished: None,
        componentEnvironment: ctx as *const LogContext as *mut c_void,
    })
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
        // owned by the Instance (or the host) until after fmi2FreeInstance returns. The strings
        // are NUL-terminated or NULL (cstr_lossy checks NULL).
        let ctx = unsafe { &*(env as *const LogContext) };
        let msg = unsafe {
            LogMessage {
                instance: cstr_lossy(instance_name),
                status: LogStatus::from_c(status),
                category: cstr_lossy(category),
                message: cstr_lossy(formatted),
            }
        };
        ctx.deliver(msg);
    }));
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
