//! What an FMI call gives: its non-error [`Status`], or an [`FmuError`] carrying the
//! instance's last log messages.

use super::LogMessage;
use crate::isolate::HostFailure;

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
    /// The model description does not promise the capability of this optional function
    /// (e.g. `canGetAndSetFMUstate` is not `true`): the call is not made.
    #[error(
        "the FMU does not provide {function}: its model description does not declare {flag}=\"true\""
    )]
    NotPromised {
        /// The FMI function.
        function: &'static str,
        /// The capability flag of the model description that would promise it.
        flag: &'static str,
    },
    /// `fmi2GetRealOutputDerivatives` asked for an order the model description's
    /// `maxOutputDerivativeOrder` (absent: 0) does not reach, or an order below 1: the call is
    /// not made.
    #[error(
        "the FMU does not provide {function} of order {order}: its model description declares maxOutputDerivativeOrder=\"{max}\""
    )]
    DerivativeOrderNotPromised {
        /// The FMI function.
        function: &'static str,
        /// The order asked for (the first one refused).
        order: i32,
        /// The model description's `maxOutputDerivativeOrder` (0 when absent).
        max: u32,
    },
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
    /// The host process of an isolated instance crashed, exited, hung or broke the protocol
    /// during a call ([`crate::isolate`]). The instance is unusable afterwards.
    #[error("{0}")]
    Host(Box<HostError>),
}

/// The details of [`FmuError::Host`].
#[derive(Debug, thiserror::Error)]
#[error("FMU '{model}', instance '{instance}': {function}{}: {failure}{}", queued_note(*.queued), format_messages(.messages))]
pub struct HostError {
    /// The model name of the FMU.
    pub model: String,
    /// The instance name.
    pub instance: String,
    /// The FMI function the master was waiting for.
    pub function: &'static str,
    /// How many queued calls (sets) were sent in the same request before it.
    pub queued: usize,
    /// How the host failed.
    pub failure: HostFailure,
    /// The instance's last log messages, oldest first (those logged before a crash included).
    pub messages: Vec<LogMessage>,
}

fn queued_note(queued: usize) -> String {
    match queued {
        0 => String::new(),
        1 => " (sent with 1 queued set before it)".into(),
        n => format!(" (sent with {n} queued sets before it)"),
    }
}

impl FmuError {
    /// The FMU's log messages attached to this error.
    pub fn messages(&self) -> &[LogMessage] {
        match self {
            FmuError::Call { messages, .. } | FmuError::Instantiate { messages, .. } => messages,
            FmuError::Host(h) => &h.messages,
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
