//! FMU isolation: each instance of an FMU in a child process of its own.
//!
//! With [`Isolation::Process`] (or [`Isolation::Auto`] for an FMU that kneebench did not
//! generate) [`Fmu::load`](crate::Fmu::load) still extracts the archive and parses the model
//! description in the master, but the binary is loaded by a **host process**, and every
//! [`Instance`](crate::Instance) of the FMU runs in a host of its own. The master keeps calling
//! the same `Instance` API; a crash (`SIGSEGV`, `abort()`), an `exit()` or a hang of the FMU
//! becomes an [`FmuError::Host`](crate::FmuError::Host) naming the FMU, the instance, the call
//! and the signal or exit code, and the master carries on (it stops the run and keeps the rows
//! recorded so far). Each call is bounded by [`HostOptions::call_timeout`] (60 s by default,
//! or [`CALL_TIMEOUT_VAR`] seconds): past it the host is killed and the call fails.
//!
//! The master and a host talk over a Unix socket pair with a compact binary protocol (see the
//! `protocol` module's source); a master step (set inputs, `fmi2DoStep`, get outputs) is one
//! round trip: sets are queued and sent with the next call, and the reads made after the last
//! step are made again right after this one, in the same request.
//!
//! # The host executable
//!
//! A host is an executable that calls [`host_main`] when started with the argument
//! [`HOST_ARG`]. kneebench ships one, `kneebench-fmu-host` (installed next to `kneebench`). The
//! library finds it, in this order:
//!
//! 1. [`HostOptions::helper`], when set;
//! 2. the environment variable `KNEEBENCH_FMU_HOST`;
//! 3. `kneebench-fmu-host` in the directory of the running executable, then in its parent
//!    (cargo puts test and bench executables in `target/<profile>/deps`).
//!
//! A program of your own can be its own host: call [`serve_if_host`] first thing in `main`, and
//! set [`HostOptions::helper`] to [`std::env::current_exe`].

mod host;
mod protocol;
pub(crate) mod remote;

use std::ffi::OsStr;
use std::fmt;
use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::load::LoadError;

pub(crate) use protocol::{
    CALL_CANCEL_STEP, CALL_DESERIALIZE_FMU_STATE, CALL_DO_STEP, CALL_ENTER_INITIALIZATION,
    CALL_EXIT_INITIALIZATION, CALL_FREE_FMU_STATE, CALL_GET_BOOLEAN, CALL_GET_BOOLEAN_STATUS,
    CALL_GET_FMU_STATE, CALL_GET_INTEGER, CALL_GET_INTEGER_STATUS, CALL_GET_OUTPUT_DERIVATIVES,
    CALL_GET_REAL_STATUS, CALL_GET_STATUS, CALL_GET_STRING, CALL_GET_STRING_STATUS, CALL_RESET,
    CALL_SERIALIZE_FMU_STATE, CALL_SET_BOOLEAN, CALL_SET_DEBUG_LOGGING, CALL_SET_FMU_STATE,
    CALL_SET_INPUT_DERIVATIVES, CALL_SET_INTEGER, CALL_SET_REAL, CALL_SET_STRING,
    CALL_SETUP_EXPERIMENT, CALL_TERMINATE,
};
pub(crate) use protocol::{Dec, Enc, ProtocolError};

/// The argument a host executable is started with.
pub const HOST_ARG: &str = "--kneebench-fmu-host";

/// The host executable kneebench ships.
pub const HOST_EXECUTABLE: &str = "kneebench-fmu-host";

/// Where an FMU's binary runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Isolation {
    /// In the master's process: the fastest, but a crash of the FMU is a crash of the master.
    #[default]
    InProcess,
    /// Each instance in a host process of its own.
    Process,
    /// [`Process`](Self::Process) for FMUs that kneebench did not generate (their
    /// `generationTool` does not start with "kneebench"), [`InProcess`](Self::InProcess) for
    /// kneebench's own.
    Auto,
}

impl Isolation {
    /// The isolation named as on the command line (`kneebench run --isolate`) and in the
    /// Python package: `auto`, `always` (in a process) or `never` (in process).
    pub fn from_name(name: &str) -> Option<Isolation> {
        match name {
            "auto" => Some(Isolation::Auto),
            "always" => Some(Isolation::Process),
            "never" => Some(Isolation::InProcess),
            _ => None,
        }
    }

    /// Whether an FMU with this `generationTool` runs in a host process.
    pub fn isolates(self, generation_tool: Option<&str>) -> bool {
        match self {
            Isolation::InProcess => false,
            Isolation::Process => true,
            Isolation::Auto => !is_kneebench_tool(generation_tool),
        }
    }
}

/// Whether a `generationTool` is kneebench's (`"kneebench"` or `"kneebench <version>"`).
pub fn is_kneebench_tool(generation_tool: Option<&str>) -> bool {
    generation_tool.is_some_and(|t| t == "kneebench" || t.starts_with("kneebench "))
}

/// How host processes are started and watched.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HostOptions {
    /// The host executable (default: found as described in the [module docs](self)).
    pub helper: Option<PathBuf>,
    /// The longest any one request to a host may take (a step with its reads and sets, or one
    /// other call); past it the host is killed and the call fails.
    pub call_timeout: Duration,
}

/// The environment variable that sets the default call timeout, in seconds.
pub const CALL_TIMEOUT_VAR: &str = "KNEEBENCH_FMU_CALL_TIMEOUT";

impl Default for HostOptions {
    /// No explicit helper; the call timeout from `KNEEBENCH_FMU_CALL_TIMEOUT` (seconds, a
    /// positive number; anything else is ignored), else 60 s.
    fn default() -> Self {
        let call_timeout = std::env::var(CALL_TIMEOUT_VAR)
            .ok()
            .and_then(|v| v.trim().parse::<f64>().ok())
            .and_then(|s| Duration::try_from_secs_f64(s).ok())
            .filter(|d| !d.is_zero())
            .unwrap_or(Duration::from_secs(60));
        HostOptions {
            helper: None,
            call_timeout,
        }
    }
}

/// Finds the host executable (see the [module docs](self)).
pub fn find_helper(explicit: Option<&Path>) -> Result<PathBuf, LoadError> {
    if let Some(p) = explicit {
        return Ok(p.to_path_buf());
    }
    if let Some(p) = std::env::var_os("KNEEBENCH_FMU_HOST") {
        return Ok(PathBuf::from(p));
    }
    let mut tried = Vec::new();
    if let Ok(exe) = std::env::current_exe() {
        let mut dir = exe.parent();
        for _ in 0..2 {
            let Some(d) = dir else { break };
            let candidate = d.join(HOST_EXECUTABLE);
            if candidate.is_file() {
                return Ok(candidate);
            }
            tried.push(candidate);
            dir = d.parent();
        }
    }
    Err(LoadError::HelperNotFound {
        tried: tried
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", "),
    })
}

/// How a host process failed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum HostFailure {
    /// The process was killed by a signal (a crash: `SIGSEGV`, `SIGABRT`, ...).
    Signal(i32),
    /// The process exited (the FMU called `exit()`), with this code.
    Exit(i32),
    /// The call did not return within the timeout; the process was killed.
    Timeout(Duration),
    /// The process could not be started.
    Start(String),
    /// The process sent something that is not the protocol.
    Protocol(String),
}

/// The name of a signal number (Linux numbering).
pub fn signal_name(signal: i32) -> &'static str {
    match signal {
        1 => "SIGHUP",
        2 => "SIGINT",
        3 => "SIGQUIT",
        4 => "SIGILL",
        5 => "SIGTRAP",
        6 => "SIGABRT",
        7 => "SIGBUS",
        8 => "SIGFPE",
        9 => "SIGKILL",
        11 => "SIGSEGV",
        13 => "SIGPIPE",
        15 => "SIGTERM",
        24 => "SIGXCPU",
        25 => "SIGXFSZ",
        31 => "SIGSYS",
        _ => "an unnamed signal",
    }
}

impl fmt::Display for HostFailure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            HostFailure::Signal(s) => write!(
                f,
                "the FMU's process crashed (signal {s}, {})",
                signal_name(*s)
            ),
            HostFailure::Exit(c) => write!(f, "the FMU ended its process (exit code {c})"),
            HostFailure::Timeout(t) => write!(
                f,
                "no answer within {} s (call timeout); the FMU's process was killed",
                t.as_secs_f64()
            ),
            HostFailure::Start(m) => write!(f, "the FMU's process could not start: {m}"),
            HostFailure::Protocol(m) => write!(f, "the FMU's process broke the protocol: {m}"),
        }
    }
}

/// Runs the FMU host on standard input and output and exits the process (the entry point of a
/// host executable; see the [module docs](self)).
pub fn host_main() -> ! {
    match host::serve() {
        Ok(()) => std::process::exit(0),
        Err(e) => {
            eprintln!("kneebench FMU host: {e}");
            std::process::exit(70)
        }
    }
}

/// Runs [`host_main`] (never returning) when this process was started as an FMU host, i.e.
/// with [`HOST_ARG`] as its first argument; otherwise returns at once.
pub fn serve_if_host() {
    if std::env::args_os().nth(1).as_deref() == Some(OsStr::new(HOST_ARG)) {
        host_main();
    }
}
