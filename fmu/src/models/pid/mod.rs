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
//! each with the inputs held at their values of `t`. Any step is accepted, whatever its size
//! and wherever it starts and ends: whole periods from an instant, shorter than Ts (e.g. a plant
//! stepped at 0.5 ms), or across instants ending between two (1.5 ms or 2.5 ms with Ts = 1 ms,
//! e.g. fmpy's `simulate_fmu` with such an `output_interval`). A step that ends between two
//! instants leaves the clock there: the next instant is executed by the step that reaches it.
//! Holding the inputs over the step is FMI 2.0's co-simulation semantics
//! (`canInterpolateInputs="false"`: an input is constant from one communication point to the
//! next), and it is how a step of several whole periods was already executed; a step that
//! ends off the grid runs its samples the same way, so it is not refused (earlier versions
//! refused a step crossing an instant and ending between two, and fmpy's `simulate_fmu` failed
//! at its first step). A run with 1.5 ms steps gives, at its communication points, bit for bit
//! the outputs of a run with shorter steps whose inputs are held over the same 1.5 ms (the
//! same samples from the same inputs). As with any step longer than Ts, the samples inside a
//! step see inputs that are up to one step old: a master that wants each sample from fresh
//! inputs steps on the grid.
//!
//! Refused with `fmi2Error` and a log line, before anything changes (the instance stays at
//! `t`): a step whose grid position is not finite, lies before sample 0 or beyond 2^52 periods
//! (where the grid's f64 positions no longer count instants exactly).
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

mod law;
mod sample_clock;
mod settings;
#[cfg(test)]
mod tests;
mod variables;

pub use law::{AUXILIARIES, PidInputs, PidSignals, PidState, pid_sample};
pub use sample_clock::{SAMPLE_TOLERANCE, SampleClock};
pub use settings::{
    ANTI_WINDUP_ITEMS, AntiWindup, GainPreset, HoldAction, PRESETS, PidSettings, preset_gains,
};

use crate::release::Lazy;

use crate::model::{
    EnumerationType, Model, ModelError, StateError, StateReader, StateWriter, StepOutcome, Variable,
};
use crate::registry::ReferenceInputs;
use law::{law, load_signals, save_signals};
use variables::{ENUMERATIONS, VARIABLES};

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
                ModelError::refused(format!("preset {p} is not an item of PidPreset"))
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
                ModelError::refused(format!("antiWindup {} is not an item", self.anti_windup))
            })?,
            tracking_time: self.tracking_time,
            feed_forward_gain: self.feed_forward_gain,
            setpoint_weights: self.setpoint_weights,
            feed_forward_weights: self.feed_forward_weights,
            hold_action: HoldAction::from_i32(self.hold_action).ok_or_else(|| {
                ModelError::refused(format!("holdAction {} is not an item", self.hold_action))
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
        // The cached settings are used in place, not copied (disjoint fields of `self`).
        let Some(settings) = &self.cached_settings else {
            return Err(ModelError::new("the PID settings are not available"));
        };
        self.signals = self
            .clock
            .outputs_at(t, self.held, |_| law(settings, &self.state, &self.inputs).0);
        self.signals.check_finite(t)
    }

    fn max_step_size(&self) -> f64 {
        self.clock.max_step_size()
    }

    fn do_step(&mut self, t: f64, h: f64) -> Result<StepOutcome, ModelError> {
        self.checked_settings()?;
        let Some(settings) = &self.cached_settings else {
            return Err(ModelError::new("the PID settings are not available"));
        };
        let inputs = &self.inputs;
        self.clock
            .run_step(t, h, &mut self.state, &mut self.held, |_, state| {
                law(settings, state, inputs)
            })?;
        self.signals = self.held;
        self.signals.check_finite(t + h)?;
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
            unsafe { Lazy::new(|| crate::model::module_doc_html(include_str!("mod.rs"))) };
        &HTML
    }
}
