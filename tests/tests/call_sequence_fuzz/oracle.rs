//! The oracle: the FMI 2.0 co-simulation call-sequence table and the instance's state.

// ---------------------------------------------------------------------------------------------
// The oracle: the call-sequence table and the instance's state.

/// The states of the co-simulation state machine (`stepCanceled` only through a forged FMU
/// state: steps are synchronous).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum S {
    Instantiated,
    Initialization,
    StepComplete,
    StepFailed,
    StepCanceled,
    Terminated,
    Error,
}

impl S {
    /// The state a serialized FMU state's code stands for (`instance::State`).
    pub(crate) fn from_code(code: u8) -> Option<S> {
        Some(match code {
            0 => S::Instantiated,
            1 => S::Initialization,
            2 => S::StepComplete,
            3 => S::StepFailed,
            4 => S::StepCanceled,
            5 => S::Terminated,
            6 => S::Error,
            _ => return None,
        })
    }

    /// The set phase (0 instantiated, 1 initialization, 2 stepping).
    pub(crate) fn phase(self) -> usize {
        match self {
            S::Instantiated => 0,
            S::Initialization => 1,
            _ => 2,
        }
    }
}

/// The functions of the table, grouped as the standard's table groups them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum F {
    SetDebugLogging,
    SetupExperiment,
    EnterInitializationMode,
    ExitInitializationMode,
    Terminate,
    Reset,
    Get,
    Set,
    FmuState,
    GetDirectionalDerivative,
    SetRealInputDerivatives,
    GetRealOutputDerivatives,
    DoStep,
    CancelStep,
    GetStatus,
}

/// Whether `f` may be called in `s`: the FMI 2.0 co-simulation table (section 4.2.4), with the
/// glue's documented choices (`fmu/src/fmi2/instance.rs`, `Func::allowed`): the status
/// functions only at a communication point, after a discarded step or after terminate (not in
/// the error state), no `fmi2CancelStep` (no step is ever in progress), the derivative
/// functions where the gets are (output derivatives not in initialization mode), and
/// `fmi2Reset`, `fmi2SetDebugLogging` and the FMU-state functions in every state.
pub(crate) fn allowed(f: F, s: S) -> bool {
    use S::*;
    match f {
        F::SetDebugLogging | F::Reset | F::FmuState => true,
        F::SetupExperiment | F::EnterInitializationMode => s == Instantiated,
        F::ExitInitializationMode => s == Initialization,
        F::Terminate => matches!(s, StepComplete | StepFailed),
        F::Get | F::GetDirectionalDerivative => s != Instantiated,
        F::Set | F::SetRealInputDerivatives => {
            matches!(s, Instantiated | Initialization | StepComplete)
        }
        F::GetRealOutputDerivatives => {
            matches!(
                s,
                StepComplete | StepFailed | StepCanceled | Terminated | Error
            )
        }
        F::DoStep => s == StepComplete,
        F::CancelStep => false,
        F::GetStatus => matches!(s, StepComplete | StepFailed | Terminated),
    }
}

/// What the oracle knows of an instance (or of the instance a state was taken from).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Machine {
    pub(crate) s: S,
    pub(crate) stop: Option<f64>,
    /// The last communication point (= `fmi2LastSuccessfulTime`).
    pub(crate) time: f64,
    pub(crate) terminated: bool,
}

impl Machine {
    pub(crate) fn fresh() -> Machine {
        Machine {
            s: S::Instantiated,
            stop: None,
            time: 0.0,
            terminated: false,
        }
    }
}

/// The glue's tolerance on communication points (`instance::TIME_TOLERANCE`).
const TIME_TOLERANCE: f64 = 1e-9;

fn same_time(a: f64, b: f64) -> bool {
    (a - b).abs() <= TIME_TOLERANCE * a.abs().max(b.abs()).max(1.0)
}

/// Whether `fmi2DoStep(t, h)` has arguments the glue refuses whatever the model: not finite,
/// a step size not positive, an end `t + h` not finite, not the last communication point,
/// past the stop time (the model's largest step is the model's: a step the oracle passes may
/// still be refused).
pub(crate) fn bad_step(m: &Machine, t: f64, h: f64) -> bool {
    !(t.is_finite() && h.is_finite() && h > 0.0 && (t + h).is_finite() && same_time(t, m.time))
        || m.stop
            .is_some_and(|stop| t + h > stop && !same_time(t + h, stop))
}
