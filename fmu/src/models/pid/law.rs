//! The PID law: one sample's signals and the next state from the settings, the state and the
//! inputs (the `pid` module docs, "The law", "Bumpless gain changes", "hold", "Feed-forward").

use super::settings::{AntiWindup, HoldAction, PidSettings};
use crate::model::{ModelError, StateError, StateReader, StateWriter};

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
        // Every sample: one sum. A sum with a NaN or infinite term is NaN or infinite (a
        // partial sum, once not finite, stays so), so a finite sum means every output is
        // finite; a sum that is not finite (or overflowed) goes to the naming check, which
        // also answers Ok when every output is finite after all.
        let sum = self.output
            + self.reference
            + self.error
            + self.proportional
            + self.integral
            + self.derivative
            + self.feed_forward
            + self.unsaturated;
        if sum.abs() <= f64::MAX {
            Ok(())
        } else {
            self.not_finite(t)
        }
    }

    /// The error of [`check_finite`](Self::check_finite), naming the first output that is NaN
    /// or infinite.
    #[cold]
    #[inline(never)]
    pub(super) fn not_finite(&self, t: f64) -> Result<(), ModelError> {
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

/// One PID sample: the signals at this instant and the state for the next (the `pid`
/// module docs).
pub fn pid_sample(s: &PidSettings, state: &PidState, input: &PidInputs) -> (PidSignals, PidState) {
    law(s, state, input)
}

/// [`pid_sample`]'s body, inlined into the controller's `calculate` and `do_step` (the one
/// law: `pid_sample` calls it too), so that a sample's signals and state are stored where
/// they go instead of returned through the stack and copied (and `calculate` leaves out the
/// next state it does not use).
#[inline(always)]
pub(super) fn law(s: &PidSettings, state: &PidState, input: &PidInputs) -> (PidSignals, PidState) {
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

/// Writes the signals of a sample (the held outputs, in the FMU state).
pub(super) fn save_signals(s: &PidSignals, w: &mut StateWriter) {
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

/// Reads what [`save_signals`] wrote.
pub(super) fn load_signals(r: &mut StateReader<'_>) -> Result<PidSignals, StateError> {
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
