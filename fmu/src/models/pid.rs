//! # PidController: the bench's discrete PID (bench model facts, section 6)
//!
//! A PID controller sampled at a fixed period `samplePeriod` (default 1 ms, the myRIO's control
//! period) for the position, velocity or torque loops of the bench. Inputs `setpoint`,
//! `measurement`, `feedForward` (Real) and `hold` (Boolean); output `u`, saturated, plus the
//! diagnostic outputs `error`, `pTerm`, `iTerm`, `dTerm`, `feedForwardTerm`, `uUnsaturated` and
//! `saturated`.
//!
//! ## The law, at sample instant k (period Ts)
//!
//! ```text
//! e_k  = s (r_k - y_k)                        s = -1 when reverseActing, else +1
//! x_k  = (Tf x_{k-1} + y_k - y_{k-1}) / (Tf + Ts)   filtered dy/dt (backward Euler of
//!                                                    Tf x' + x = dy/dt); x_0 = 0 (y_{-1} = y_0)
//! P_k  = kp e_k
//! D_k  = -s kd x_k                            derivative on the measurement: no setpoint kick
//! F_k  = feedForwardGain * feedForward_k
//! v_k  = P_k + I_k + D_k + F_k                uUnsaturated
//! u_k  = min(max(v_k, outputMin), outputMax)  u; saturated = (u_k != v_k)
//! ```
//!
//! `I_k` is the integral term's **value** (in output units), not the integral of the error:
//! the integrator advances after the sample (forward Euler) by
//!
//! * `None`: `I_{k+1} = I_k + ki Ts e_k`;
//! * `Clamping` (conditional integration, the default): as `None`, except that the step is
//!   skipped when the output is saturated and the step would drive it further into the same
//!   limit (`v_k > outputMax` and `ki e_k > 0`, or `v_k < outputMin` and `ki e_k < 0`);
//! * `BackCalculation`: `I_{k+1} = I_k + Ts (ki e_k + (u_k - v_k) / trackingTime)`: the
//!   saturation excess bleeds the integral off with time constant `trackingTime`.
//!
//! With `Tf = 0` the derivative is the plain backward difference `(y_k - y_{k-1}) / Ts`.
//!
//! ## Bumpless gain changes
//! `kp`, `ki`, `kd` (and `preset`) are tunable. Because the integral is stored as the I-term's
//! value, a change of `ki` only changes the integral's future increments: the output does not
//! jump. A change of `kp` or `kd` would make `P` or `D` jump; at the first sample with the new
//! gains, when the (new) `ki` is non-zero, the difference is moved into the integral,
//! `I_k += (kp_old - kp_new) e_k + s (kd_new - kd_old) x_k`, so `u_k` equals the value the old
//! gains would have given, and the integral action then works the offset off. With `ki = 0`
//! there is no integrator to absorb it and the output of a P/PD controller follows its new gain
//! at once.
//!
//! ## `hold`
//! At a sample where `hold` is true the integrator is frozen (`I_{k+1} = I_k`) and the output is
//! held: `u_k = u_{k-1}` (`holdAction = HoldLastOutput`, the default: the value of the last
//! sample, 0 before the first) or `u_k = 0` (`ZeroOutput`: e.g. let the clutch alone hold the
//! actuation side, saving the motor current). The measurement history and the derivative
//! filter keep running so that release gives no derivative kick; `saturated` is false while
//! holding; `error`, `pTerm`, `iTerm`, `dTerm` and `uUnsaturated` still show the law's values.
//! On release the law resumes with the frozen integral (no transfer): the output then shows the
//! error accumulated while held. The clutch scheduler's `holdPosition` drives this input while
//! the clutch locks the actuation side.
//!
//! ## Sampling, communication steps and direct feedthrough
//! Sample instants are `t_n = startTime + n Ts`. `fmi2DoStep(t, h)` executes every sample
//! instant in `[t, t + h)` (an instant within 1e-6 Ts of `t + h` belongs to the next step),
//! each with the inputs held at their values of `t`. A step is accepted when
//!
//! * it spans whole sample periods from the sample grid (`t` and `t + h` on the grid, any
//!   number of samples: variable steps are fine as long as they are multiples of Ts), or
//! * it stays inside one sample period (no sample instant strictly between `t` and `t + h`):
//!   communication steps shorter than Ts, e.g. a plant stepped at 0.5 ms.
//!
//! Any other step (for instance 1.5 ms with Ts = 1 ms, or 0.3 ms steps that eventually straddle
//! an instant) would run a sample with inputs stale by a fraction of a period and drift off the
//! communication grid: it is refused with `fmi2Error` and a message naming Ts, t and h.
//!
//! The output changes at sample instants only (zero-order hold between them). At a
//! communication point that **is** a sample instant not executed yet, the outputs are
//! `f(inputs now, state)`: the sample that the next `fmi2DoStep` will execute, computed from
//! the inputs just set (direct feedthrough: `u` depends on `setpoint`, `measurement`,
//! `feedForward` and `hold` in the `ModelStructure`). This is what a myRIO does — read the
//! sensors, compute, write the command in the same period — and lets a Gauss-Seidel master
//! (plant step, set the controller's inputs, get `u`, step the plant) apply the command
//! computed from the measurement of the same instant. At a communication point between sample
//! instants the outputs are those of the last executed sample. With a Jacobi master the output
//! read before the new inputs are set is the sample computed from the previous inputs; the
//! step then executes the sample with the inputs set at its start.
//!
//! ## Presets and the units question
//! `preset` selects a gain set the bench used (section 6 of the bench facts); `Custom` uses the
//! `kp`, `ki`, `kd` parameters, any other item ignores them. The study does **not** state the
//! units of its gains. The interpretation implemented and documented here: the error is in SI
//! units of the loop's measured quantity **at the output (knee) axis** (rad for the position
//! loops, rad/s for velocity loops, N m for the load torque loop), and `u` is the driver's
//! command in the unit of the plant's driver mode (A with the default current-mode drivers, V in
//! voltage mode, like the study's simulation that fed voltages through a current saturation).
//! Under that reading the simulation gains are very stiff: `kp = 6300` A/rad saturates the test
//! driver (15 A) at 0.14 deg of error, and `kp = 100` A/(N m) saturates the load driver (6 A)
//! at 0.06 N m. A user must check, before trusting a preset on the simulated bench: the driver
//! mode of the plant (A or V), whether the error should be in degrees or motor-side radians
//! (then scale `kp`, `ki`, `kd` by the factor, or use `Custom`), and the sign of the loop
//! (`reverseActing` for a plant whose measurement falls when `u` rises, e.g. the spring torque
//! measured by the transducer against the load-motor current). The presets carry no output
//! limits: set `outputMin`/`outputMax` to the driver's range (default +-15 A, the test driver).
//!
//! ## Feed-forward and reference shaping
//! `feedForward` enters scaled by `feedForwardGain` (default 1), so a reference can be wired
//! directly: e.g. `loadTorqueReference` with gain `1/(i_RED Km2)` = 0.13291 A/(N m) on the load
//! loop, or `kneeVelocityReference` with gain `c1/(i_HD Km1)` = 2.027 A s/rad on the position
//! loop (viscous-torque feed-forward).
//!
//! Three auxiliary inputs `auxiliary1..3` (reference signals such as the reference velocity,
//! acceleration or torque) enter both the setpoint and the feed-forward through their own
//! weights, so a loop that tracks a planned quantity needs no summing blocks around it:
//!
//! ```text
//! r_k = setpoint_k + sum_i setpointWeight_i * auxiliary_i,k      (the loop's reference)
//! F_k = feedForwardGain * feedForward_k + sum_i feedForwardWeight_i * auxiliary_i,k
//! ```
//!
//! and `e_k = s (r_k - y_k)`; the output `reference` shows `r_k`. The weights default to 0.
//! Example (the study's SEA position loop): `setpoint` = knee-angle reference, auxiliaries =
//! knee velocity, acceleration and torque references, setpoint weights = the planned spring
//! deflection per unit of each (shaft torque / k), feed-forward weights = the motor current
//! per unit of each (damping, inertia and torque over i_HD Km1).

use crate::release::Lazy;

use crate::model::{
    EnumerationType, Model, ModelError, Start, StateError, StateReader, StateWriter, StepOutcome,
    Variable,
};
use crate::registry::ReferenceInputs;

/// A sample instant is "at" a time within this fraction of the sample period.
pub const SAMPLE_TOLERANCE: f64 = 1e-6;

/// The sample grid of a discrete controller: instants `start + n period`, and the index of the
/// next instant not executed yet. Shared by the bench's controllers.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SampleClock {
    /// Sample period Ts \[s\].
    pub period: f64,
    /// Time of sample 0 \[s\].
    pub start: f64,
    /// Index of the next sample instant to execute.
    pub next: u64,
    /// `1 / period`, set by [`SampleClock::new`] and [`SampleClock::load`] (a multiplication on
    /// every step instead of divisions; 0 means "divide").
    pub rate: f64,
}

impl SampleClock {
    /// A clock of period `period` whose sample 0 is at `start`.
    pub fn new(period: f64, start: f64) -> Self {
        Self {
            period,
            start,
            next: 0,
            rate: 1.0 / period,
        }
    }

    /// Position of `t` on the grid, in sample periods.
    fn position(&self, t: f64) -> f64 {
        if self.rate != 0.0 {
            (t - self.start) * self.rate
        } else {
            (t - self.start) / self.period
        }
    }

    /// The largest step whose samples [`SampleClock::run_step`] executes in one call:
    /// [`MAX_INTERNAL_STEPS_PER_CALL`](crate::model::MAX_INTERNAL_STEPS_PER_CALL) periods
    /// (unbounded before the clock has a period).
    pub fn max_step_size(&self) -> f64 {
        if self.period > 0.0 {
            crate::model::MAX_INTERNAL_STEPS_PER_CALL * self.period
        } else {
            f64::INFINITY
        }
    }

    /// Whether `t` is the next sample instant (to be executed by the next step).
    #[inline]
    pub fn is_next_sample_instant(&self, t: f64) -> bool {
        (self.position(t) - self.next as f64).abs() <= SAMPLE_TOLERANCE
    }

    /// The outputs at communication point `t`: a fresh sample from the inputs now when `t` is
    /// the next sample instant (or before initialization, when the clock has no period),
    /// else `held`, the outputs of the last executed sample. `sample` gets the sample index.
    pub fn outputs_at<S>(&self, t: f64, held: S, sample: impl FnOnce(u64) -> S) -> S {
        if self.period == 0.0 || self.is_next_sample_instant(t) {
            sample(self.next)
        } else {
            held
        }
    }

    /// Executes the samples of the step `[t, t + h)` in order: `sample(index, state)` gives
    /// the sample's outputs and the next state; the last outputs become `held`. Refuses a step
    /// off the sample grid without changing anything.
    pub fn run_step<S, X>(
        &mut self,
        t: f64,
        h: f64,
        state: &mut X,
        held: &mut S,
        mut sample: impl FnMut(u64, &X) -> (S, X),
    ) -> Result<(), ModelError> {
        let count = self.samples_in_step(t, h)?;
        for _ in 0..count {
            let (signals, next) = sample(self.next, state);
            *state = next;
            *held = signals;
            self.next += 1;
        }
        Ok(())
    }

    /// How many sample instants the step `[t, t + h)` executes, or why the step is refused
    /// (module docs, "Sampling").
    #[inline]
    pub fn samples_in_step(&self, t: f64, h: f64) -> Result<u64, ModelError> {
        let a = self.position(t);
        let b = self.position(t + h);
        // The common case, one period from the next instant (inside the grid's range): the
        // general rule gives 1.
        let next = self.next as f64;
        if (a - next).abs() <= SAMPLE_TOLERANCE
            && (b - next - 1.0).abs() <= SAMPLE_TOLERANCE
            && b <= 2f64.powi(52)
        {
            return Ok(1);
        }
        self.samples_in_general_step(a, b, t, h)
    }

    /// [`Self::samples_in_step`] for any step, at grid positions `a` and `b` of its ends.
    fn samples_in_general_step(&self, a: f64, b: f64, t: f64, h: f64) -> Result<u64, ModelError> {
        if !(a.is_finite() && b.is_finite()) || b > 2f64.powi(52) || a < -SAMPLE_TOLERANCE {
            return Err(ModelError::new(format!(
                "the step from t = {t} s by h = {h} s is outside the sample grid of period {} s starting at {} s",
                self.period, self.start
            )));
        }
        let on_grid = |x: f64| (x - x.round()).abs() <= SAMPLE_TOLERANCE;
        // First instant at or after the end: executed instants are next..end_index.
        let end_index = (b - SAMPLE_TOLERANCE).ceil().max(0.0) as u64;
        let count = end_index.saturating_sub(self.next);
        // Instants strictly inside (t, t + h).
        let first_after_start = (a + SAMPLE_TOLERANCE).floor().max(-1.0) as i64 + 1;
        let interior = (end_index as i64 - first_after_start).max(0);
        let whole_periods = on_grid(a) && on_grid(b);
        if interior > 0 && !whole_periods {
            return Err(ModelError::new(format!(
                "communication step h = {h} s from t = {t} s does not fit the sample period Ts = {} s: \
                 a step must either span whole sample periods from a sample instant or stay within \
                 one sample period (no sample instant strictly inside the step); this one crosses \
                 {interior} sample instant(s) and {}",
                self.period,
                if on_grid(a) {
                    "ends between two instants"
                } else {
                    "starts between two instants"
                }
            )));
        }
        Ok(count)
    }

    /// Writes the clock.
    pub fn save(&self, w: &mut StateWriter) {
        w.f64(self.period);
        w.f64(self.start);
        w.u64(self.next);
    }

    /// Reads what [`SampleClock::save`] wrote.
    pub fn load(r: &mut StateReader<'_>) -> Result<Self, StateError> {
        let period = r.f64()?;
        let start = r.f64()?;
        let next = r.u64()?;
        Ok(Self {
            period,
            start,
            next,
            rate: 1.0 / period,
        })
    }
}

/// The items of the `AntiWindup` enumeration (the values of [`AntiWindup`]), for every model
/// whose integrator offers the schemes.
pub const ANTI_WINDUP_ITEMS: &[(&str, i32, &str)] = &[
    ("None", AntiWindup::None as i32, "Plain integration"),
    (
        "Clamping",
        AntiWindup::Clamping as i32,
        "Conditional integration: skip integrator steps that drive a saturated output further",
    ),
    (
        "BackCalculation",
        AntiWindup::BackCalculation as i32,
        "Back-calculation: the saturation excess bleeds the integral off with trackingTime",
    ),
];

/// Anti-windup scheme of the integrator (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AntiWindup {
    /// Plain integration.
    None = 0,
    /// Conditional integration: no step that drives a saturated output further.
    Clamping = 1,
    /// Back-calculation with the tracking time constant.
    BackCalculation = 2,
}

impl AntiWindup {
    /// From the FMU's enumeration value.
    pub fn from_i32(v: i32) -> Option<Self> {
        match v {
            0 => Some(Self::None),
            1 => Some(Self::Clamping),
            2 => Some(Self::BackCalculation),
            _ => None,
        }
    }
}

/// What the output does while `hold` is true.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HoldAction {
    /// Keep the output of the last sample.
    HoldLastOutput = 1,
    /// Output zero.
    ZeroOutput = 2,
}

impl HoldAction {
    /// From the FMU's enumeration value.
    pub fn from_i32(v: i32) -> Option<Self> {
        match v {
            1 => Some(Self::HoldLastOutput),
            2 => Some(Self::ZeroOutput),
            _ => None,
        }
    }
}

/// One gain set of the bench, an item of the `preset` enumeration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GainPreset {
    /// Item name.
    pub name: &'static str,
    /// Item value.
    pub value: i32,
    /// Item description.
    pub description: &'static str,
    /// (kp, ki, kd).
    pub gains: (f64, f64, f64),
}

/// The gain sets of the bench (bench facts, section 6) as the `preset` enumeration; value 0 is
/// `Custom`.
pub const PRESETS: [GainPreset; 10] = [
    GainPreset {
        name: "SteadyStateVelocityTestMotor",
        value: 1,
        description: "Steady-state velocity tests, test motor (velocity loop): kp 350, ki 100, kd 0",
        gains: (350.0, 100.0, 0.0),
    },
    GainPreset {
        name: "SteadyStateVelocityLoadMotor",
        value: 2,
        description: "Steady-state velocity tests, load motor (torque loop): kp 1.5, ki 0.5, kd 0.2",
        gains: (1.5, 0.5, 0.2),
    },
    GainPreset {
        name: "GaitExperimentTestMotor",
        value: 3,
        description: "Gait experiment on the bench, test motor (position loop): kp 2000, ki 300, kd 100",
        gains: (2000.0, 300.0, 100.0),
    },
    GainPreset {
        name: "GaitExperimentLoadMotor",
        value: 4,
        description: "Gait experiment on the bench, load motor (torque loop): kp 1, ki 10, kd 0.3",
        gains: (1.0, 10.0, 0.3),
    },
    GainPreset {
        name: "GaitSimulationDaTestMotor",
        value: 5,
        description: "Gait simulation DA, test motor (position loop): kp 6300, ki 0.22, kd 0.05",
        gains: (6300.0, 0.22, 0.05),
    },
    GainPreset {
        name: "GaitSimulationSeaTestMotor",
        value: 6,
        description: "Gait simulation SEA, test motor (position loop): kp 6210, ki 0.19, kd 0.045",
        gains: (6210.0, 0.19, 0.045),
    },
    GainPreset {
        name: "GaitSimulationCseaTestMotor",
        value: 7,
        description: "Gait simulation CSEA, test motor (position loop): kp 6210, ki 0.27, kd 0",
        gains: (6210.0, 0.27, 0.0),
    },
    GainPreset {
        name: "GaitSimulationDaLoadMotor",
        value: 8,
        description: "Gait simulation DA, load motor (torque loop): kp 100, ki 1, kd 0",
        gains: (100.0, 1.0, 0.0),
    },
    GainPreset {
        name: "GaitSimulationSeaLoadMotor",
        value: 9,
        description: "Gait simulation SEA, load motor (torque loop): kp 100, ki 1, kd 0",
        gains: (100.0, 1.0, 0.0),
    },
    GainPreset {
        name: "GaitSimulationCseaLoadMotor",
        value: 10,
        description: "Gait simulation CSEA, load motor (torque loop): kp 100, ki 1, kd 0",
        gains: (100.0, 1.0, 0.0),
    },
];

/// The gains (kp, ki, kd) of preset `value`, `None` for `Custom` (0) or an unknown value.
pub fn preset_gains(value: i32) -> Option<(f64, f64, f64)> {
    PRESETS.iter().find(|p| p.value == value).map(|p| p.gains)
}

/// Everything that shapes one PID sample (parameters, after the preset is applied).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PidSettings {
    /// Proportional gain.
    pub kp: f64,
    /// Integral gain [1/s].
    pub ki: f64,
    /// Derivative gain \[s\].
    pub kd: f64,
    /// Derivative filter time constant Tf \[s\] (0: plain backward difference).
    pub derivative_filter_time: f64,
    /// Sample period Ts \[s\].
    pub sample_period: f64,
    /// Lower output limit.
    pub output_min: f64,
    /// Upper output limit.
    pub output_max: f64,
    /// Anti-windup scheme.
    pub anti_windup: AntiWindup,
    /// Back-calculation tracking time constant \[s\].
    pub tracking_time: f64,
    /// Factor of the feed-forward input.
    pub feed_forward_gain: f64,
    /// Weights of the auxiliary inputs in the reference.
    pub setpoint_weights: [f64; AUXILIARIES],
    /// Weights of the auxiliary inputs in the feed-forward term.
    pub feed_forward_weights: [f64; AUXILIARIES],
    /// Output while held.
    pub hold_action: HoldAction,
    /// Error = measurement - setpoint (a plant whose measurement falls when u rises).
    pub reverse_acting: bool,
}

impl PidSettings {
    /// Checks the settings together.
    pub fn validate(&self) -> Result<(), ModelError> {
        let finite = [
            self.kp,
            self.ki,
            self.kd,
            self.derivative_filter_time,
            self.sample_period,
            self.output_min,
            self.output_max,
            self.tracking_time,
            self.feed_forward_gain,
        ]
        .iter()
        .chain(&self.setpoint_weights)
        .chain(&self.feed_forward_weights)
        .all(|x| x.is_finite());
        if !finite {
            return Err(ModelError::new("PID settings must be finite"));
        }
        if self.sample_period <= 0.0 {
            return Err(ModelError::new(format!(
                "samplePeriod {} must be positive",
                self.sample_period
            )));
        }
        if self.output_min > self.output_max {
            return Err(ModelError::new(format!(
                "outputMin {} is above outputMax {}",
                self.output_min, self.output_max
            )));
        }
        if self.derivative_filter_time < 0.0 {
            return Err(ModelError::new(format!(
                "derivativeFilterTime {} must not be negative",
                self.derivative_filter_time
            )));
        }
        if self.anti_windup == AntiWindup::BackCalculation && self.tracking_time <= 0.0 {
            return Err(ModelError::new(format!(
                "trackingTime {} must be positive for back-calculation",
                self.tracking_time
            )));
        }
        Ok(())
    }
}

/// The PID's state between samples.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PidState {
    /// The integral term's value (output units).
    pub integral: f64,
    /// Filtered derivative of the measurement [measurement unit / s].
    pub filtered_derivative: f64,
    /// Measurement of the previous sample (`None` before the first).
    pub previous_measurement: Option<f64>,
    /// Output of the previous sample.
    pub last_output: f64,
    /// (kp, kd) of the previous sample, for bumpless gain changes (`None` before the first).
    pub applied_gains: Option<(f64, f64)>,
}

impl PidState {
    /// Writes the state.
    pub fn save(&self, w: &mut StateWriter) {
        w.f64(self.integral);
        w.f64(self.filtered_derivative);
        w.bool(self.previous_measurement.is_some());
        w.f64(self.previous_measurement.unwrap_or(0.0));
        w.f64(self.last_output);
        w.bool(self.applied_gains.is_some());
        let (kp, kd) = self.applied_gains.unwrap_or((0.0, 0.0));
        w.f64(kp);
        w.f64(kd);
    }

    /// Reads what [`PidState::save`] wrote.
    pub fn load(r: &mut StateReader<'_>) -> Result<Self, StateError> {
        let integral = r.f64()?;
        let filtered_derivative = r.f64()?;
        let has_previous = r.bool()?;
        let previous = r.f64()?;
        let last_output = r.f64()?;
        let has_gains = r.bool()?;
        let kp = r.f64()?;
        let kd = r.f64()?;
        Ok(Self {
            integral,
            filtered_derivative,
            previous_measurement: has_previous.then_some(previous),
            last_output,
            applied_gains: has_gains.then_some((kp, kd)),
        })
    }
}

/// The PID's inputs at one sample.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PidInputs {
    /// Setpoint r.
    pub setpoint: f64,
    /// Measurement y.
    pub measurement: f64,
    /// Feed-forward input (scaled by the feed-forward gain).
    pub feed_forward: f64,
    /// Auxiliary reference signals (weighted into the reference and the feed-forward).
    pub auxiliary: [f64; AUXILIARIES],
    /// Hold: freeze the integrator and hold the output.
    pub hold: bool,
}

/// Number of auxiliary inputs of the PID.
pub const AUXILIARIES: usize = 3;

/// What one sample computes: the output and its parts.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PidSignals {
    /// The output u (saturated, or held).
    pub output: f64,
    /// The reference r: the setpoint plus the weighted auxiliaries.
    pub reference: f64,
    /// The error e.
    pub error: f64,
    /// P term.
    pub proportional: f64,
    /// I term (the integral's value used at this sample).
    pub integral: f64,
    /// D term.
    pub derivative: f64,
    /// Feed-forward term.
    pub feed_forward: f64,
    /// P + I + D + feed-forward before saturation.
    pub unsaturated: f64,
    /// The output was clipped at a limit.
    pub saturated: bool,
}

impl PidSignals {
    /// Fails naming the first output (by its FMI name) that is NaN or infinite at time `t`:
    /// gains or inputs so large that the law overflows never pass as fmi2OK.
    pub fn check_finite(&self, t: f64) -> Result<(), ModelError> {
        const EXPONENT: u64 = 0x7ff0_0000_0000_0000;
        let values = [
            self.output,
            self.reference,
            self.error,
            self.proportional,
            self.integral,
            self.derivative,
            self.feed_forward,
            self.unsaturated,
        ];
        // Every sample: one OR over the exponent tests (no early exit, no names); the names
        // only when one is not finite.
        let any = values.iter().fold(0u64, |any, v| {
            any | u64::from(v.to_bits() & EXPONENT == EXPONENT)
        });
        if any == 0 { Ok(()) } else { self.not_finite(t) }
    }

    /// The error of [`check_finite`](Self::check_finite), naming the first output that is NaN
    /// or infinite.
    #[cold]
    #[inline(never)]
    fn not_finite(&self, t: f64) -> Result<(), ModelError> {
        let values = [
            ("u", self.output),
            ("reference", self.reference),
            ("error", self.error),
            ("pTerm", self.proportional),
            ("iTerm", self.integral),
            ("dTerm", self.derivative),
            ("feedForwardTerm", self.feed_forward),
            ("uUnsaturated", self.unsaturated),
        ];
        match values.iter().find(|(_, v)| !v.is_finite()) {
            None => Ok(()),
            Some((name, v)) => Err(ModelError::new(format!(
                "output {name} is {v} at t = {t} s: the gains or inputs overflow the control law"
            ))),
        }
    }
}

/// One PID sample: the signals at this instant and the state for the next (module docs).
pub fn pid_sample(s: &PidSettings, state: &PidState, input: &PidInputs) -> (PidSignals, PidState) {
    let sign = if s.reverse_acting { -1.0 } else { 1.0 };
    let ts = s.sample_period;
    let mut reference = input.setpoint;
    let mut f = s.feed_forward_gain * input.feed_forward;
    for ((x, a), b) in input
        .auxiliary
        .iter()
        .zip(&s.setpoint_weights)
        .zip(&s.feed_forward_weights)
    {
        reference += a * x;
        f += b * x;
    }
    let e = sign * (reference - input.measurement);
    let dy = state
        .previous_measurement
        .map_or(0.0, |prev| input.measurement - prev);
    let x = (s.derivative_filter_time * state.filtered_derivative + dy)
        / (s.derivative_filter_time + ts);
    let mut integral = state.integral;
    if let Some((kp_old, kd_old)) = state.applied_gains
        && s.ki != 0.0
        && !input.hold
        && (kp_old != s.kp || kd_old != s.kd)
    {
        integral += (kp_old - s.kp) * e + sign * (s.kd - kd_old) * x;
    }
    let p = s.kp * e;
    let d = -sign * s.kd * x;
    let v = p + integral + d + f;
    let limited = v.max(s.output_min).min(s.output_max);
    let (output, saturated, next_integral) = if input.hold {
        let held = match s.hold_action {
            HoldAction::HoldLastOutput => state.last_output,
            HoldAction::ZeroOutput => 0.0,
        };
        (held, false, integral)
    } else {
        let increment = s.ki * ts * e;
        let next = match s.anti_windup {
            AntiWindup::None => integral + increment,
            AntiWindup::Clamping => {
                let winding_up =
                    (v > s.output_max && increment > 0.0) || (v < s.output_min && increment < 0.0);
                if winding_up {
                    integral
                } else {
                    integral + increment
                }
            }
            AntiWindup::BackCalculation => {
                integral + increment + ts * (limited - v) / s.tracking_time
            }
        };
        (limited, limited != v, next)
    };
    let signals = PidSignals {
        output,
        reference,
        error: e,
        proportional: p,
        integral,
        derivative: d,
        feed_forward: f,
        unsaturated: v,
        saturated,
    };
    let next = PidState {
        integral: next_integral,
        filtered_derivative: x,
        previous_measurement: Some(input.measurement),
        last_output: output,
        applied_gains: Some((s.kp, s.kd)),
    };
    (signals, next)
}

/// The PID controller FMU. Fields are its variables (see [`Model::variables`]) and state.
#[derive(Debug, Clone, Default)]
pub struct PidController {
    preset: i32,
    kp: f64,
    ki: f64,
    kd: f64,
    derivative_filter_time: f64,
    sample_period: f64,
    output_min: f64,
    output_max: f64,
    anti_windup: i32,
    tracking_time: f64,
    feed_forward_gain: f64,
    setpoint_weights: [f64; AUXILIARIES],
    feed_forward_weights: [f64; AUXILIARIES],
    hold_action: i32,
    reverse_acting: bool,

    inputs: PidInputs,
    signals: PidSignals,

    clock: SampleClock,
    state: PidState,
    /// Signals of the last executed sample (zero-order hold between samples).
    held: PidSignals,
    /// The checked settings of the current parameters (cleared by every parameter setter).
    cached_settings: Option<PidSettings>,
}

/// Value references (stable; never reuse a retired number).
mod vr {
    pub const PRESET: u32 = 1;
    pub const KP: u32 = 2;
    pub const KI: u32 = 3;
    pub const KD: u32 = 4;
    pub const DERIVATIVE_FILTER_TIME: u32 = 5;
    pub const SAMPLE_PERIOD: u32 = 6;
    pub const OUTPUT_MIN: u32 = 7;
    pub const OUTPUT_MAX: u32 = 8;
    pub const ANTI_WINDUP: u32 = 9;
    pub const TRACKING_TIME: u32 = 10;
    pub const FEED_FORWARD_GAIN: u32 = 11;
    pub const HOLD_ACTION: u32 = 12;
    pub const REVERSE_ACTING: u32 = 13;
    /// `setpointWeight1..3`.
    pub const SETPOINT_WEIGHT: [u32; 3] = [14, 15, 16];
    /// `feedForwardWeight1..3`.
    pub const FEED_FORWARD_WEIGHT: [u32; 3] = [17, 18, 19];
    pub const SETPOINT: u32 = 100;
    pub const MEASUREMENT: u32 = 101;
    pub const FEED_FORWARD: u32 = 102;
    pub const HOLD: u32 = 103;
    /// `auxiliary1..3`.
    pub const AUXILIARY: [u32; 3] = [104, 105, 106];
    pub const U: u32 = 200;
    pub const ERROR: u32 = 201;
    pub const P_TERM: u32 = 202;
    pub const I_TERM: u32 = 203;
    pub const D_TERM: u32 = 204;
    pub const FEED_FORWARD_TERM: u32 = 205;
    pub const U_UNSATURATED: u32 = 206;
    pub const SATURATED: u32 = 207;
    pub const REFERENCE: u32 = 208;
}

/// Inputs and parameters every output depends on.
const KNOWNS: &[&str] = &[
    "setpoint",
    "measurement",
    "feedForward",
    "hold",
    "preset",
    "kp",
    "ki",
    "kd",
    "derivativeFilterTime",
    "samplePeriod",
    "outputMin",
    "outputMax",
    "antiWindup",
    "trackingTime",
    "feedForwardGain",
    "holdAction",
    "reverseActing",
    "auxiliary1",
    "auxiliary2",
    "auxiliary3",
    "setpointWeight1",
    "setpointWeight2",
    "setpointWeight3",
    "feedForwardWeight1",
    "feedForwardWeight2",
    "feedForwardWeight3",
];

// SAFETY: a static (Lazy registers its address for the release at unload).
static PRESET_ITEMS: Lazy<Vec<(&'static str, i32, &'static str)>> = unsafe {
    Lazy::new(|| {
        let mut items = vec![(
            "Custom",
            0,
            "Use the kp, ki and kd parameters (the default)",
        )];
        items.extend(PRESETS.iter().map(|p| (p.name, p.value, p.description)));
        items
    })
};

// SAFETY: a static (Lazy registers its address for the release at unload).
static ENUMERATIONS: Lazy<Vec<EnumerationType>> = unsafe {
    Lazy::new(|| {
        vec![
            EnumerationType {
                name: "PidPreset",
                description: "Gain sets the bench used (bench facts, section 6); units: see the documentation",
                items: PRESET_ITEMS.as_slice(),
            },
            EnumerationType {
                name: "AntiWindup",
                description: "Anti-windup scheme of the PID's integrator",
                items: ANTI_WINDUP_ITEMS,
            },
            EnumerationType {
                name: "HoldAction",
                description: "What the PID's output does while hold is true",
                items: &[
                    ("HoldLastOutput", 1, "Keep the output of the last sample"),
                    ("ZeroOutput", 2, "Output zero"),
                ],
            },
        ]
    })
};

// SAFETY: a static (Lazy registers its address for the release at unload).
static VARIABLES: Lazy<Vec<Variable<PidController>>> = unsafe {
    Lazy::new(|| {
        use Start::{Boolean, Integer, Real};
        type V = Variable<PidController>;
        // A parameter of the settings: its setter also drops the cached checked settings.
        macro_rules! setting {
        (enumeration $name:literal, $vr:expr, $type_name:literal, $($field:tt)+) => {
            V::enumeration($name, $vr, $type_name, |m| m.$($field)+, |m, v| {
                m.$($field)+ = v;
                m.cached_settings = None;
            })
        };
        ($kind:ident, $name:literal, $vr:expr, $($field:tt)+) => {
            V::$kind($name, $vr, |m| m.$($field)+, |m, v| {
                m.$($field)+ = v;
                m.cached_settings = None;
            })
        };
    }
        vec![
        setting!(enumeration "preset", vr::PRESET, "PidPreset", preset)
            .tunable(Integer(0))
            .describe("Gain set: Custom uses kp, ki, kd; any other item is a gain set of the bench and ignores them"),
        setting!(real, "kp", vr::KP, kp)
            .tunable(Real(1.0))
            .describe("Proportional gain (Custom preset); output unit per error unit"),
        setting!(real, "ki", vr::KI, ki)
            .tunable(Real(1.0))
            .describe("Integral gain (Custom preset); output unit per error unit and second"),
        setting!(real, "kd", vr::KD, kd)
            .tunable(Real(0.01))
            .describe("Derivative gain on the measurement (Custom preset); output unit times second per measurement unit"),
        setting!(real, "derivativeFilterTime", vr::DERIVATIVE_FILTER_TIME, derivative_filter_time)
            .tunable(Real(0.005))
            .unit("s")
            .range(0.0, 1e3)
            .describe("Time constant Tf of the first-order filter of the measurement's derivative (0: backward difference)"),
        setting!(real, "samplePeriod", vr::SAMPLE_PERIOD, sample_period)
            .parameter(Real(1e-3))
            .unit("s")
            .display("ms")
            .range(1e-6, 10.0)
            .describe("Sample period Ts (the myRIO's control period); communication steps must nest with it"),
        setting!(real, "outputMin", vr::OUTPUT_MIN, output_min)
            .tunable(Real(-15.0))
            .describe("Lower output limit (default: the test driver's -15 A)"),
        setting!(real, "outputMax", vr::OUTPUT_MAX, output_max)
            .tunable(Real(15.0))
            .describe("Upper output limit (default: the test driver's 15 A)"),
        setting!(enumeration "antiWindup", vr::ANTI_WINDUP, "AntiWindup", anti_windup)
            .tunable(Integer(AntiWindup::Clamping as i32))
            .describe("Anti-windup scheme"),
        setting!(real, "trackingTime", vr::TRACKING_TIME, tracking_time)
            .tunable(Real(0.05))
            .unit("s")
            .range(1e-9, 1e6)
            .describe("Back-calculation tracking time constant Tt"),
        setting!(real, "feedForwardGain", vr::FEED_FORWARD_GAIN, feed_forward_gain)
            .tunable(Real(1.0))
            .describe("Factor of the feedForward input (e.g. 1/(i_RED Km2) for a torque reference in N m to A)"),
        setting!(real, "setpointWeight1", vr::SETPOINT_WEIGHT[0], setpoint_weights[0])
            .tunable(Real(0.0))
            .describe("Weight of auxiliary1 in the reference r (setpoint unit per auxiliary unit)"),
        setting!(real, "setpointWeight2", vr::SETPOINT_WEIGHT[1], setpoint_weights[1])
            .tunable(Real(0.0))
            .describe("Weight of auxiliary2 in the reference r"),
        setting!(real, "setpointWeight3", vr::SETPOINT_WEIGHT[2], setpoint_weights[2])
            .tunable(Real(0.0))
            .describe("Weight of auxiliary3 in the reference r"),
        setting!(real, "feedForwardWeight1", vr::FEED_FORWARD_WEIGHT[0], feed_forward_weights[0])
            .tunable(Real(0.0))
            .describe("Weight of auxiliary1 in the feed-forward term (output unit per auxiliary unit)"),
        setting!(real, "feedForwardWeight2", vr::FEED_FORWARD_WEIGHT[1], feed_forward_weights[1])
            .tunable(Real(0.0))
            .describe("Weight of auxiliary2 in the feed-forward term"),
        setting!(real, "feedForwardWeight3", vr::FEED_FORWARD_WEIGHT[2], feed_forward_weights[2])
            .tunable(Real(0.0))
            .describe("Weight of auxiliary3 in the feed-forward term"),
        setting!(enumeration "holdAction", vr::HOLD_ACTION, "HoldAction", hold_action)
            .tunable(Integer(HoldAction::HoldLastOutput as i32))
            .describe("Output while hold is true"),
        setting!(boolean, "reverseActing", vr::REVERSE_ACTING, reverse_acting)
            .tunable(Boolean(false))
            .describe("Error = measurement - setpoint, for a plant whose measurement falls when u rises"),
        V::real("setpoint", vr::SETPOINT, |m| m.inputs.setpoint, |m, v| m.inputs.setpoint = v)
            .input(Real(0.0))
            .describe("Setpoint r (the loop's quantity: rad, rad/s or N m at the knee axis)"),
        V::real("measurement", vr::MEASUREMENT, |m| m.inputs.measurement, |m, v| m.inputs.measurement = v)
            .input(Real(0.0))
            .describe("Measurement y, same unit as the setpoint"),
        V::real("feedForward", vr::FEED_FORWARD, |m| m.inputs.feed_forward, |m, v| m.inputs.feed_forward = v)
            .input(Real(0.0))
            .describe("Feed-forward input, added to the output times feedForwardGain"),
        V::real("auxiliary1", vr::AUXILIARY[0], |m| m.inputs.auxiliary[0], |m, v| m.inputs.auxiliary[0] = v)
            .input(Real(0.0))
            .describe("Auxiliary reference signal 1, weighted into the reference and the feed-forward"),
        V::real("auxiliary2", vr::AUXILIARY[1], |m| m.inputs.auxiliary[1], |m, v| m.inputs.auxiliary[1] = v)
            .input(Real(0.0))
            .describe("Auxiliary reference signal 2"),
        V::real("auxiliary3", vr::AUXILIARY[2], |m| m.inputs.auxiliary[2], |m, v| m.inputs.auxiliary[2] = v)
            .input(Real(0.0))
            .describe("Auxiliary reference signal 3"),
        V::boolean("hold", vr::HOLD, |m| m.inputs.hold, |m, v| m.inputs.hold = v)
            .input(Boolean(false))
            .describe("While true at a sample: integrator frozen and output held (holdAction)"),
        V::real("u", vr::U, |m| m.signals.output, |m, v| m.signals.output = v)
            .output(KNOWNS)
            .describe("Controller output (driver command: A in current mode, V in voltage mode), saturated, updated at sample instants"),
        V::real("reference", vr::REFERENCE, |m| m.signals.reference, |m, v| m.signals.reference = v)
            .output(KNOWNS)
            .describe("Reference r = setpoint + weighted auxiliaries, the quantity the loop tracks"),
        V::real("error", vr::ERROR, |m| m.signals.error, |m, v| m.signals.error = v)
            .output(KNOWNS)
            .describe("Error e = setpoint - measurement (negated when reverseActing)"),
        V::real("pTerm", vr::P_TERM, |m| m.signals.proportional, |m, v| m.signals.proportional = v)
            .output(KNOWNS)
            .describe("Proportional term kp e"),
        V::real("iTerm", vr::I_TERM, |m| m.signals.integral, |m, v| m.signals.integral = v)
            .output(KNOWNS)
            .describe("Integral term (its value, in output units)"),
        V::real("dTerm", vr::D_TERM, |m| m.signals.derivative, |m, v| m.signals.derivative = v)
            .output(KNOWNS)
            .describe("Derivative term on the filtered measurement derivative"),
        V::real("feedForwardTerm", vr::FEED_FORWARD_TERM, |m| m.signals.feed_forward, |m, v| m.signals.feed_forward = v)
            .output(KNOWNS)
            .describe("feedForwardGain times feedForward"),
        V::real("uUnsaturated", vr::U_UNSATURATED, |m| m.signals.unsaturated, |m, v| m.signals.unsaturated = v)
            .output(KNOWNS)
            .describe("P + I + D + feed-forward before saturation"),
        V::boolean("saturated", vr::SATURATED, |m| m.signals.saturated, |m, v| m.signals.saturated = v)
            .output(KNOWNS)
            .describe("The output was clipped at outputMin or outputMax at the last sample"),
    ]
    })
};

impl PidController {
    /// [`Self::settings`], computed once per parameter change.
    fn checked_settings(&mut self) -> Result<PidSettings, ModelError> {
        match self.cached_settings {
            Some(s) => Ok(s),
            None => {
                let s = self.settings()?;
                self.cached_settings = Some(s);
                Ok(s)
            }
        }
    }

    /// The settings with the preset applied.
    pub fn settings(&self) -> Result<PidSettings, ModelError> {
        let (kp, ki, kd) = match self.preset {
            0 => (self.kp, self.ki, self.kd),
            p => preset_gains(p).ok_or_else(|| {
                ModelError::new(format!("preset {p} is not an item of PidPreset"))
            })?,
        };
        let s = PidSettings {
            kp,
            ki,
            kd,
            derivative_filter_time: self.derivative_filter_time,
            sample_period: self.sample_period,
            output_min: self.output_min,
            output_max: self.output_max,
            anti_windup: AntiWindup::from_i32(self.anti_windup).ok_or_else(|| {
                ModelError::new(format!("antiWindup {} is not an item", self.anti_windup))
            })?,
            tracking_time: self.tracking_time,
            feed_forward_gain: self.feed_forward_gain,
            setpoint_weights: self.setpoint_weights,
            feed_forward_weights: self.feed_forward_weights,
            hold_action: HoldAction::from_i32(self.hold_action).ok_or_else(|| {
                ModelError::new(format!("holdAction {} is not an item", self.hold_action))
            })?,
            reverse_acting: self.reverse_acting,
        };
        s.validate()?;
        Ok(s)
    }
}

impl ReferenceInputs for PidController {
    fn reference_inputs() -> Option<String> {
        // A documented open-loop run of the default controller (Custom kp 1, ki 1, kd 0.01,
        // Tf 5 ms, +-15 limits, clamping): setpoint 0.5 rad steps at 0.5 s and 20 rad from 1.0 s
        // to 2.0 s (deep saturation, exercising the anti-windup), then a 0.5 Hz sine of 1 rad;
        // the measurement is a 0.3 Hz sine of 0.4 rad; feed-forward 0.2 cos(2 pi 0.2 t); hold
        // from 3.0 s to 3.5 s. Sampled at every 1 ms communication point.
        let mut csv = String::from("time,setpoint,measurement,feedForward,hold\n");
        for k in 0..=5000 {
            let t = k as f64 / 1000.0;
            let tau = std::f64::consts::TAU;
            let r = if k < 500 {
                0.0
            } else if k < 1000 {
                0.5
            } else if k < 2000 {
                20.0
            } else {
                (tau * 0.5 * t).sin()
            };
            let y = 0.4 * (tau * 0.3 * t).sin();
            let ff = 0.2 * (tau * 0.2 * t).cos();
            let hold = u8::from((3000..3500).contains(&k));
            csv.push_str(&format!("{t:?},{r:?},{y:?},{ff:?},{hold}\n"));
        }
        Some(csv)
    }
}

impl Model for PidController {
    const IDENTIFIER: &'static str = "PidController";
    const DESCRIPTION: &'static str = "Discrete PID controller of the knee-actuator bench (position, velocity or torque loops): derivative on the filtered measurement, output saturation, clamping or back-calculation anti-windup, bumpless gain changes, hold input, feed-forward, presets of the bench's gain sets";
    const DEFAULT_EXPERIMENT: (f64, f64, f64) = (0.0, 5.0, 1e-3);

    fn variables() -> &'static [Variable<Self>] {
        &VARIABLES
    }

    fn enumerations() -> &'static [EnumerationType] {
        &ENUMERATIONS
    }

    fn initialize(&mut self, start_time: f64) -> Result<(), ModelError> {
        self.settings()?;
        self.clock = SampleClock::new(self.sample_period, start_time);
        self.state = PidState::default();
        self.held = PidSignals::default();
        Ok(())
    }

    fn calculate(&mut self, t: f64) -> Result<(), ModelError> {
        self.checked_settings()?;
        // Disjoint fields: the cached settings are used in place, not copied.
        let Self {
            cached_settings: Some(settings),
            clock,
            held,
            state,
            inputs,
            signals,
            ..
        } = self
        else {
            return Err(ModelError::new("the PID settings are not available"));
        };
        *signals = clock.outputs_at(t, *held, |_| pid_sample(settings, state, inputs).0);
        signals.check_finite(t)
    }

    fn max_step_size(&self) -> f64 {
        self.clock.max_step_size()
    }

    fn do_step(&mut self, t: f64, h: f64) -> Result<StepOutcome, ModelError> {
        self.checked_settings()?;
        let Self {
            cached_settings: Some(settings),
            clock,
            held,
            state,
            inputs,
            signals,
            ..
        } = self
        else {
            return Err(ModelError::new("the PID settings are not available"));
        };
        clock.run_step(t, h, state, held, |_, state| {
            pid_sample(settings, state, inputs)
        })?;
        *signals = *held;
        signals.check_finite(t + h)?;
        Ok(StepOutcome::Completed)
    }

    fn save_internal(&self, w: &mut StateWriter) {
        self.clock.save(w);
        self.state.save(w);
        save_signals(&self.held, w);
    }

    fn load_internal(&mut self, r: &mut StateReader<'_>) -> Result<(), StateError> {
        self.clock = SampleClock::load(r)?;
        self.state = PidState::load(r)?;
        self.held = load_signals(r)?;
        Ok(())
    }

    fn documentation() -> &'static str {
        // SAFETY: a static (Lazy registers its address for the release at unload).
        static HTML: Lazy<String> =
            unsafe { Lazy::new(|| crate::model::module_doc_html(include_str!("pid.rs"))) };
        &HTML
    }
}

fn save_signals(s: &PidSignals, w: &mut StateWriter) {
    for x in [
        s.output,
        s.reference,
        s.error,
        s.proportional,
        s.integral,
        s.derivative,
        s.feed_forward,
        s.unsaturated,
    ] {
        w.f64(x);
    }
    w.bool(s.saturated);
}

fn load_signals(r: &mut StateReader<'_>) -> Result<PidSignals, StateError> {
    Ok(PidSignals {
        output: r.f64()?,
        reference: r.f64()?,
        error: r.f64()?,
        proportional: r.f64()?,
        integral: r.f64()?,
        derivative: r.f64()?,
        feed_forward: r.f64()?,
        unsaturated: r.f64()?,
        saturated: r.bool()?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fmi2::instance::fresh_model;

    const TS: f64 = 1e-3;

    fn settings() -> PidSettings {
        PidSettings {
            kp: 0.0,
            ki: 0.0,
            kd: 0.0,
            derivative_filter_time: 0.0,
            sample_period: TS,
            output_min: -100.0,
            output_max: 100.0,
            anti_windup: AntiWindup::None,
            tracking_time: 0.1,
            feed_forward_gain: 1.0,
            setpoint_weights: [0.0; AUXILIARIES],
            feed_forward_weights: [0.0; AUXILIARIES],
            hold_action: HoldAction::HoldLastOutput,
            reverse_acting: false,
        }
    }

    /// Runs the law over (setpoint, measurement) pairs; returns the outputs.
    fn run(s: &PidSettings, samples: &[(f64, f64)]) -> Vec<PidSignals> {
        let mut state = PidState::default();
        samples
            .iter()
            .map(|&(r, y)| {
                let (sig, next) = pid_sample(
                    s,
                    &state,
                    &PidInputs {
                        setpoint: r,
                        measurement: y,
                        ..PidInputs::default()
                    },
                );
                state = next;
                sig
            })
            .collect()
    }

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-12 * (1.0 + a.abs().max(b.abs()))
    }

    fn assert_outputs(got: &[PidSignals], want: &[f64]) {
        assert_eq!(got.len(), want.len());
        for (k, (g, w)) in got.iter().zip(want).enumerate() {
            assert!(close(g.output, *w), "sample {k}: {} vs {w}", g.output);
        }
    }

    #[test]
    fn proportional_sequence() {
        let s = PidSettings {
            kp: 2.0,
            ..settings()
        };
        let got = run(&s, &[(1.0, 0.0), (1.0, 0.25), (-1.0, 0.5)]);
        assert_outputs(&got, &[2.0, 1.5, -3.0]);
        // Reverse acting negates the error.
        let got = run(
            &PidSettings {
                reverse_acting: true,
                ..s
            },
            &[(1.0, 0.0)],
        );
        assert_outputs(&got, &[-2.0]);
    }

    #[test]
    fn integral_sequence_is_forward_euler_of_the_i_term() {
        // ki = 10/s, Ts = 1 ms: u_k = sum_{j<k} 10 * 0.001 * e_j.
        let s = PidSettings {
            ki: 10.0,
            ..settings()
        };
        let got = run(&s, &[(1.0, 0.0), (1.0, 0.0), (3.0, 0.0), (0.0, 0.0)]);
        assert_outputs(&got, &[0.0, 0.01, 0.02, 0.05]);
    }

    #[test]
    fn derivative_on_measurement_with_filter_sequence() {
        // kd = 0.5 s, Tf = 3 ms, Ts = 1 ms: x_k = (3e-3 x_{k-1} + dy_k) / 4e-3, D = -kd x.
        let s = PidSettings {
            kd: 0.5,
            derivative_filter_time: 3e-3,
            ..settings()
        };
        // Measurement ramps 0, 0.001, 0.002, then stays; a setpoint step gives no kick.
        let got = run(&s, &[(0.0, 0.0), (5.0, 0.001), (5.0, 0.002), (5.0, 0.002)]);
        let x1 = 0.001 / 4e-3; // 0.25
        let x2 = (3e-3 * x1 + 0.001) / 4e-3; // 0.4375
        let x3 = (3e-3 * x2) / 4e-3; // 0.328125
        assert_outputs(&got, &[0.0, -0.5 * x1, -0.5 * x2, -0.5 * x3]);
        assert!(close(got[3].output, -0.1640625));
        // Without filter: the backward difference.
        let got = run(
            &PidSettings {
                derivative_filter_time: 0.0,
                ..s
            },
            &[(0.0, 0.0), (0.0, 0.002)],
        );
        assert_outputs(&got, &[0.0, -0.5 * 2.0]);
    }

    #[test]
    fn saturation_clips_and_flags() {
        let s = PidSettings {
            kp: 10.0,
            output_min: -1.0,
            output_max: 2.0,
            ..settings()
        };
        let got = run(&s, &[(0.1, 0.0), (1.0, 0.0), (-1.0, 0.0)]);
        assert_outputs(&got, &[1.0, 2.0, -1.0]);
        assert_eq!(
            got.iter().map(|g| g.saturated).collect::<Vec<_>>(),
            [false, true, true]
        );
        assert!(close(got[1].unsaturated, 10.0));
    }

    /// kp = 1, ki = 100/s, limits +-1, Ts 1 ms; error 2 for 3 samples, then -0.5.
    fn windup_case(anti_windup: AntiWindup) -> Vec<PidSignals> {
        let s = PidSettings {
            kp: 1.0,
            ki: 100.0,
            output_min: -1.0,
            output_max: 1.0,
            anti_windup,
            tracking_time: 0.01,
            ..settings()
        };
        run(
            &s,
            &[(2.0, 0.0), (2.0, 0.0), (2.0, 0.0), (-0.5, 0.0), (-0.5, 0.0)],
        )
    }

    #[test]
    fn without_anti_windup_the_integral_winds_up() {
        let got = windup_case(AntiWindup::None);
        let i: Vec<f64> = got.iter().map(|g| g.integral).collect();
        // I += 100 * 0.001 * e = 0.2 per sample at e = 2.
        for (g, w) in i.iter().zip([0.0, 0.2, 0.4, 0.6, 0.55]) {
            assert!(close(*g, w), "{i:?}");
        }
        // Sample 3: v = -0.5 + 0.6 = 0.1: the wound-up integral still drives positive.
        assert!(close(got[3].output, 0.1));
    }

    #[test]
    fn clamping_stops_integrating_into_the_limit() {
        let got = windup_case(AntiWindup::Clamping);
        let i: Vec<f64> = got.iter().map(|g| g.integral).collect();
        // Sample 0: v = 2 > 1 and e > 0: no integration; likewise samples 1, 2.
        // Sample 3: v = -0.5 inside the limits: integrates -0.05.
        for (g, w) in i.iter().zip([0.0, 0.0, 0.0, 0.0, -0.05]) {
            assert!(close(*g, w), "{i:?}");
        }
        assert_outputs(&got, &[1.0, 1.0, 1.0, -0.5, -0.55]);
    }

    #[test]
    fn back_calculation_bleeds_the_excess() {
        let got = windup_case(AntiWindup::BackCalculation);
        // I_{k+1} = I_k + Ts (ki e + (u - v)/Tt), Ts/Tt = 0.1.
        // k0: v = 2, u = 1: I1 = 0 + 0.2 + 0.1 * (-1) = 0.1
        // k1: v = 2.1, u = 1: I2 = 0.1 + 0.2 - 0.11 = 0.19
        // k2: v = 2.19, u = 1: I3 = 0.19 + 0.2 - 0.119 = 0.271
        // k3: v = -0.5 + 0.271 = -0.229, unsaturated: I4 = 0.271 - 0.05 = 0.221
        let want_i = [0.0, 0.1, 0.19, 0.271, 0.221];
        for (g, w) in got.iter().zip(want_i) {
            assert!(close(g.integral, w), "{} vs {w}", g.integral);
        }
        assert_outputs(&got, &[1.0, 1.0, 1.0, -0.229, -0.279]);
    }

    #[test]
    fn gain_changes_are_bumpless() {
        let base = PidSettings {
            kp: 2.0,
            ki: 5.0,
            kd: 0.1,
            derivative_filter_time: 2e-3,
            ..settings()
        };
        let inputs = |k: usize| PidInputs {
            setpoint: 1.0,
            measurement: 0.3 * (1.0 - (k as f64 * 0.01).cos()),
            ..PidInputs::default()
        };
        for change in [
            PidSettings { ki: 20.0, ..base },
            PidSettings { kp: 7.0, ..base },
            PidSettings { kd: 0.4, ..base },
            PidSettings {
                kp: 0.5,
                ki: 5.0,
                kd: 0.0,
                ..base
            },
        ] {
            let mut state = PidState::default();
            let mut previous = 0.0;
            for k in 0..200 {
                let s = if k < 100 { base } else { change };
                let (sig, next) = pid_sample(&s, &state, &inputs(k));
                if k >= 1 {
                    // Between samples the output moves by far less than the P-term's jump
                    // (e.g. 5 * 0.7 = 3.5 for the kp change).
                    assert!(
                        (sig.output - previous).abs() < 0.05,
                        "{change:?}: jump {} at sample {k}",
                        sig.output - previous
                    );
                }
                if k == 100 {
                    // The output at the change equals what the old gains would have given.
                    let (old, _) = pid_sample(&base, &state, &inputs(k));
                    assert!(close(sig.output, old.output), "{change:?}");
                }
                previous = sig.output;
                state = next;
            }
        }
        // With ki = 0 there is nothing to absorb a kp change: the output follows it.
        let p = PidSettings {
            kp: 1.0,
            ..settings()
        };
        let mut state = PidState::default();
        let input = PidInputs {
            setpoint: 1.0,
            ..PidInputs::default()
        };
        state = pid_sample(&p, &state, &input).1;
        let (sig, _) = pid_sample(&PidSettings { kp: 3.0, ..p }, &state, &input);
        assert!(close(sig.output, 3.0));
    }

    #[test]
    fn hold_freezes_integrator_and_output() {
        for action in [HoldAction::HoldLastOutput, HoldAction::ZeroOutput] {
            let s = PidSettings {
                kp: 1.0,
                ki: 100.0,
                hold_action: action,
                ..settings()
            };
            let mut state = PidState::default();
            let mut out = Vec::new();
            for k in 0..6 {
                let input = PidInputs {
                    setpoint: 1.0,
                    measurement: 0.0,
                    feed_forward: 0.0,
                    auxiliary: [0.0; AUXILIARIES],
                    hold: (2..4).contains(&k),
                };
                let (sig, next) = pid_sample(&s, &state, &input);
                out.push(sig);
                state = next;
            }
            // I: 0, 0.1, 0.2 (held at samples 2, 3), 0.2, 0.3
            let held = match action {
                HoldAction::HoldLastOutput => 1.1,
                HoldAction::ZeroOutput => 0.0,
            };
            assert_outputs(&out, &[1.0, 1.1, held, held, 1.2, 1.3]);
            assert!(!out[2].saturated);
        }
    }

    #[test]
    fn feed_forward_is_scaled_and_added() {
        let s = PidSettings {
            kp: 1.0,
            feed_forward_gain: 0.5,
            ..settings()
        };
        let (sig, _) = pid_sample(
            &s,
            &PidState::default(),
            &PidInputs {
                setpoint: 1.0,
                measurement: 0.0,
                feed_forward: 4.0,
                auxiliary: [0.0; AUXILIARIES],
                hold: false,
            },
        );
        assert!(close(sig.output, 3.0) && close(sig.feed_forward, 2.0));
    }

    #[test]
    fn auxiliaries_enter_the_reference_and_the_feed_forward_by_their_weights() {
        // kp = 2, reverse acting: e = -(r - y) with r = 1 + 0.5*3 - 2*(-1) + 0.25*4 = 5.5,
        // y = 0.5 -> e = -5; P = -10; F = 0.5*2 + (1*3 + 0*(-1) - 3*4) = 1 - 9 = -8; u = -18.
        let s = PidSettings {
            kp: 2.0,
            feed_forward_gain: 0.5,
            setpoint_weights: [0.5, -2.0, 0.25],
            feed_forward_weights: [1.0, 0.0, -3.0],
            reverse_acting: true,
            ..settings()
        };
        let (sig, _) = pid_sample(
            &s,
            &PidState::default(),
            &PidInputs {
                setpoint: 1.0,
                measurement: 0.5,
                feed_forward: 2.0,
                auxiliary: [3.0, -1.0, 4.0],
                hold: false,
            },
        );
        assert!(close(sig.reference, 5.5), "{}", sig.reference);
        assert!(close(sig.error, -5.0) && close(sig.proportional, -10.0));
        assert!(close(sig.feed_forward, -8.0), "{}", sig.feed_forward);
        assert!(close(sig.output, -18.0), "{}", sig.output);
        // Zero weights: the auxiliaries change nothing.
        let (plain, _) = pid_sample(
            &settings(),
            &PidState::default(),
            &PidInputs {
                setpoint: 1.0,
                auxiliary: [3.0, -1.0, 4.0],
                ..Default::default()
            },
        );
        assert!(close(plain.reference, 1.0) && close(plain.output, 0.0));
    }

    #[test]
    fn presets_are_the_published_gain_sets() {
        assert_eq!(preset_gains(0), None);
        assert_eq!(preset_gains(3), Some((2000.0, 300.0, 100.0)));
        assert_eq!(preset_gains(6), Some((6210.0, 0.19, 0.045)));
        let mut m = fresh_model::<PidController>();
        m.preset = 5;
        let s = m.settings().unwrap();
        assert_eq!((s.kp, s.ki, s.kd), (6300.0, 0.22, 0.05));
        m.preset = 99;
        assert!(m.settings().is_err());
    }

    #[test]
    fn sample_clock_accepts_nesting_steps_and_refuses_others() {
        let c = SampleClock::new(1e-3, 0.0);
        assert_eq!(c.samples_in_step(0.0, 1e-3).unwrap(), 1);
        assert_eq!(c.samples_in_step(0.0, 5e-3).unwrap(), 5);
        // Sub-steps: the first half executes the instant at its start, the second none.
        assert_eq!(c.samples_in_step(0.0, 0.5e-3).unwrap(), 1);
        let c1 = SampleClock { next: 1, ..c };
        assert_eq!(c1.samples_in_step(0.5e-3, 0.5e-3).unwrap(), 0);
        // 1.5 ms from a sample instant crosses 1 ms and ends off the grid.
        let e = c.samples_in_step(0.0, 1.5e-3).unwrap_err();
        assert!(e.message.contains("does not fit the sample period"), "{e}");
        // From off the grid across an instant.
        assert!(c1.samples_in_step(0.5e-3, 1e-3).is_err());
        // Decimal times count as on the grid.
        let c3 = SampleClock { next: 3, ..c };
        assert_eq!(c3.samples_in_step(0.003, 0.002).unwrap(), 2);
    }

    #[test]
    fn a_parameter_set_through_the_variable_table_takes_effect_at_once() {
        use crate::model::Access;
        let set = |m: &mut PidController, name: &str, value: f64| {
            let v = PidController::variables()
                .iter()
                .find(|v| v.name == name)
                .unwrap();
            let Access::Real(_, setter) = v.access else {
                panic!("{name} is not a Real")
            };
            setter(m, value);
        };
        let mut m = fresh_model::<PidController>();
        set(&mut m, "ki", 0.0);
        set(&mut m, "kd", 0.0);
        m.initialize(0.0).unwrap();
        m.inputs.setpoint = 2.0;
        m.do_step(0.0, 1e-3).unwrap();
        assert_eq!(m.signals.output, 2.0, "kp 1");
        // The settings are cached between steps; a setter must refresh them.
        set(&mut m, "kp", 3.0);
        m.do_step(1e-3, 1e-3).unwrap();
        assert_eq!(m.signals.output, 6.0, "kp 3");
        set(&mut m, "outputMax", 5.0);
        m.do_step(2e-3, 1e-3).unwrap();
        assert_eq!(m.signals.output, 5.0, "limit 5");
    }

    #[test]
    fn the_finiteness_check_agrees_with_the_naming_one() {
        let specials = [
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::MAX,
            f64::MIN_POSITIVE / 2.0,
            -0.0,
            1.5,
        ];
        for field in 0..8 {
            for x in specials {
                let mut s = PidSignals::default();
                let slot = match field {
                    0 => &mut s.output,
                    1 => &mut s.reference,
                    2 => &mut s.error,
                    3 => &mut s.proportional,
                    4 => &mut s.integral,
                    5 => &mut s.derivative,
                    6 => &mut s.feed_forward,
                    _ => &mut s.unsaturated,
                };
                *slot = x;
                let fast = s.check_finite(1.0).map_err(|e| e.message);
                let plain = s.not_finite(1.0).map_err(|e| e.message);
                assert_eq!(fast, plain, "field {field}, {x}");
                assert_eq!(fast.is_ok(), x.is_finite(), "field {field}, {x}");
            }
        }
    }

    #[test]
    fn an_overflowing_law_answers_an_error_naming_the_output() {
        let mut m = fresh_model::<PidController>();
        m.kp = 1.0;
        m.ki = 0.0;
        m.kd = 0.0;
        m.initialize(0.0).unwrap();
        m.inputs.setpoint = 1e308;
        m.inputs.measurement = -1e308;
        let e = m.calculate(0.0).unwrap_err();
        assert!(e.message.contains("output error is inf at t = 0 s"), "{e}");
        let e = m.do_step(0.0, 1e-3).unwrap_err();
        assert!(
            e.message.contains("output error is inf at t = 0.001 s"),
            "{e}"
        );
    }

    #[test]
    fn model_steps_samples_and_holds_between_them() {
        let mut m = fresh_model::<PidController>();
        m.kp = 1.0;
        m.ki = 0.0;
        m.kd = 0.0;
        m.initialize(0.0).unwrap();
        m.inputs.setpoint = 2.0;
        m.calculate(0.0).unwrap();
        assert_eq!(m.signals.output, 2.0, "feedthrough at a sample instant");
        m.do_step(0.0, 0.5e-3).unwrap();
        m.inputs.setpoint = 3.0;
        m.calculate(0.5e-3).unwrap();
        assert_eq!(m.signals.output, 2.0, "held between instants");
        m.do_step(0.5e-3, 0.5e-3).unwrap();
        m.calculate(1e-3).unwrap();
        assert_eq!(m.signals.output, 3.0, "feedthrough at the next instant");
        m.do_step(1e-3, 2e-3).unwrap();
        assert_eq!(m.clock.next, 3);
        let e = m.do_step(3e-3, 1.5e-3).unwrap_err();
        assert!(e.message.contains("Ts = 0.001"), "{e}");
    }

    #[test]
    fn model_refuses_inconsistent_limits() {
        let mut m = fresh_model::<PidController>();
        m.output_min = 5.0;
        m.output_max = 1.0;
        assert!(m.initialize(0.0).is_err());
    }

    #[test]
    fn state_round_trips() {
        let mut m = fresh_model::<PidController>();
        m.initialize(0.0).unwrap();
        m.inputs.setpoint = 1.0;
        m.do_step(0.0, 3e-3).unwrap();
        let mut w = StateWriter::default();
        m.save_internal(&mut w);
        let mut n = fresh_model::<PidController>();
        n.load_internal(&mut StateReader::new(&w.bytes)).unwrap();
        assert_eq!(n.state, m.state);
        assert_eq!(n.clock, m.clock);
        assert_eq!(n.held, m.held);
    }
}
