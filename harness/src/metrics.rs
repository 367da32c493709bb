//! Controller quality from recorded responses, as the bench study measured it: rise time
//! (to 90 % of the step), settling time (5 % band), overshoot and peak time of a step response,
//! RMS and maximum tracking error; and Ziegler-Nichols starting gains, from the ultimate gain
//! and period or from a step response's reaction curve.

use model_description::num::Num;

/// Errors of the metric computations.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MetricsError {
    /// Times and values differ in length, or there are fewer than two samples.
    #[error(
        "need at least two samples with one value per time (got {times} times, {values} values)"
    )]
    Samples {
        /// Number of times.
        times: usize,
        /// Number of values.
        values: usize,
    },
    /// Times are not strictly increasing.
    #[error("times must increase strictly (sample {0})")]
    Time(usize),
    /// The step has no size (final value equals initial value).
    #[error("the response does not move: initial and final value are both {0}")]
    NoStep(f64),
    /// A value is NaN or infinite.
    #[error("sample {0} is not finite")]
    NotFinite(usize),
    /// A parameter is out of its domain.
    #[error("{0}")]
    Domain(String),
    /// A gain the tuning rule gives is not a finite, non-zero number: its inputs' combination
    /// overflows (or underflows to zero) a double.
    #[error("{gain} = {formula} is {result} for {inputs}: no usable gain")]
    Gain {
        /// The gain (`kp`, `ki`, `kd`).
        gain: &'static str,
        /// Its rule, e.g. `0.6 Ku / (Tu/2)`.
        formula: &'static str,
        /// What came out: `inf (overflow)`, `0 (underflow)`, `NaN`.
        result: String,
        /// The inputs, e.g. `Ku = 1e308, Tu = 1e-308`.
        inputs: String,
    },
}

/// Quality of a step response.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepMetrics {
    /// Time of the step (first sample) \[s\].
    pub step_time: f64,
    /// Value before the step.
    pub initial_value: f64,
    /// Target of the step (the final value unless given).
    pub final_value: f64,
    /// Time from the step to the first crossing of 90 % of the change \[s\] (`None` if never).
    pub rise_time: Option<f64>,
    /// Time from the step after which the response stays within 5 % of the change around the
    /// final value \[s\] (`None` if it never settles within the record).
    pub settling_time: Option<f64>,
    /// Largest excursion beyond the final value, as a fraction of the change (0 if none).
    pub overshoot: f64,
    /// Time from the step to the largest excursion \[s\].
    pub peak_time: f64,
}

fn check(times: &[f64], values: &[f64]) -> Result<(), MetricsError> {
    if times.len() != values.len() || times.len() < 2 {
        return Err(MetricsError::Samples {
            times: times.len(),
            values: values.len(),
        });
    }
    for (i, w) in times.windows(2).enumerate() {
        if w[1].partial_cmp(&w[0]) != Some(std::cmp::Ordering::Greater) {
            return Err(MetricsError::Time(i + 1));
        }
    }
    if let Some(i) = times
        .iter()
        .zip(values)
        .position(|(t, v)| !t.is_finite() || !v.is_finite())
    {
        return Err(MetricsError::NotFinite(i));
    }
    Ok(())
}

/// The time at which the response crosses `level` between samples i-1 and i (linear).
fn crossing(times: &[f64], values: &[f64], i: usize, level: f64) -> f64 {
    let (t0, t1, v0, v1) = (times[i - 1], times[i], values[i - 1], values[i]);
    if v1 == v0 {
        t1
    } else {
        t0 + (level - v0) * (t1 - t0) / (v1 - v0)
    }
}

/// Step metrics of a response that starts at the step (the first sample) and should reach
/// `target` (default: the last sample). Crossing times are interpolated linearly between
/// samples.
pub fn step_metrics(
    times: &[f64],
    values: &[f64],
    target: Option<f64>,
) -> Result<StepMetrics, MetricsError> {
    check(times, values)?;
    let start = times[0];
    let initial = values[0];
    let final_value = target.unwrap_or(values[values.len() - 1]);
    let change = final_value - initial;
    if change == 0.0 {
        return Err(MetricsError::NoStep(initial));
    }
    // Work in the normalised response y = (v - initial)/change, which rises from 0 to 1.
    let y: Vec<f64> = values.iter().map(|v| (v - initial) / change).collect();
    let rise_time = (1..y.len())
        .find(|&i| y[i] >= 0.9)
        .map(|i| crossing(times, &y, i, 0.9) - start);
    let outside = |v: f64| (v - 1.0).abs() > 0.05;
    let settling_time = match (0..y.len()).rev().find(|&i| outside(y[i])) {
        None => Some(0.0),
        Some(last) if last + 1 == y.len() => None,
        Some(last) => {
            let level = if y[last] > 1.0 { 1.05 } else { 0.95 };
            Some(crossing(times, &y, last + 1, level) - start)
        }
    };
    let (peak_index, peak) =
        y.iter()
            .copied()
            .enumerate()
            .fold((0, f64::NEG_INFINITY), |best, (i, v)| {
                if v > best.1 { (i, v) } else { best }
            });
    Ok(StepMetrics {
        step_time: start,
        initial_value: initial,
        final_value,
        rise_time,
        settling_time,
        overshoot: (peak - 1.0).max(0.0),
        peak_time: times[peak_index] - start,
    })
}

/// RMS and maximum absolute difference between a reference and a response.
pub fn tracking_error(reference: &[f64], response: &[f64]) -> Result<(f64, f64), MetricsError> {
    if reference.len() != response.len() || reference.is_empty() {
        return Err(MetricsError::Samples {
            times: reference.len(),
            values: response.len(),
        });
    }
    let mut sum = 0.0;
    let mut max: f64 = 0.0;
    for (i, (r, y)) in reference.iter().zip(response).enumerate() {
        let e = r - y;
        if !e.is_finite() {
            return Err(MetricsError::NotFinite(i));
        }
        sum += e * e;
        max = max.max(e.abs());
    }
    Ok(((sum / reference.len() as f64).sqrt(), max))
}

/// PID gains in parallel form, u = kp e + ki ∫e + kd de/dt.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PidGains {
    /// Proportional gain.
    pub kp: f64,
    /// Integral gain [1/s].
    pub ki: f64,
    /// Derivative gain \[s\].
    pub kd: f64,
}

/// The classic Ziegler-Nichols PID from the ultimate gain `ku` (the proportional gain at which
/// the loop oscillates steadily) and the oscillation period `tu` \[s\]: kp = 0.6 ku,
/// Ti = tu/2, Td = tu/8.
pub fn ziegler_nichols_ultimate(ku: f64, tu: f64) -> Result<PidGains, MetricsError> {
    if !(ku.is_finite() && ku > 0.0 && tu.is_finite() && tu > 0.0) {
        return Err(MetricsError::Domain(format!(
            "ultimate gain {ku} and period {tu} must be finite and positive"
        )));
    }
    let kp = 0.6 * ku;
    usable(
        PidGains {
            kp,
            ki: kp / (tu / 2.0),
            kd: kp * tu / 8.0,
        },
        ["0.6 Ku", "0.6 Ku / (Tu/2)", "0.6 Ku Tu/8"],
        || format!("Ku = {}, Tu = {}", Num(ku), Num(tu)),
    )
}

/// `gains` when each is a finite, non-zero number; otherwise [`MetricsError::Gain`] naming the
/// first that is not, its rule (`formulas`: kp, ki, kd) and the inputs (`inputs`).
fn usable(
    gains: PidGains,
    formulas: [&'static str; 3],
    inputs: impl Fn() -> String,
) -> Result<PidGains, MetricsError> {
    let named = [("kp", gains.kp), ("ki", gains.ki), ("kd", gains.kd)];
    for ((gain, value), formula) in named.into_iter().zip(formulas) {
        let result = if value.is_nan() {
            "NaN".to_string()
        } else if value.is_infinite() {
            format!("{} (overflow)", Num(value))
        } else if value == 0.0 {
            "0 (underflow)".to_string()
        } else {
            continue;
        };
        return Err(MetricsError::Gain {
            gain,
            formula,
            result,
            inputs: inputs(),
        });
    }
    Ok(gains)
}

/// A first-order-plus-dead-time fit of a step response (the reaction curve).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReactionCurve {
    /// Static gain: change of the response per unit change of the input.
    pub gain: f64,
    /// Apparent dead time L \[s\]: where the tangent at the steepest point crosses the initial
    /// value.
    pub dead_time: f64,
    /// Apparent time constant T \[s\]: from L to where that tangent reaches the final value.
    pub time_constant: f64,
}

/// The final value of a step response: the mean of the record's last tenth (at least its last
/// sample; NaN for an empty record, which [`reaction_curve`] refuses before). One last sample
/// carries its noise whole: a speed differenced from encoder counts is off by up to a count
/// per sample, 2 % of the bench's open-loop step (0.0196 rad/s in 0.91 rad/s), and the damping
/// identified from it moved by that much between runs.
pub fn final_value(values: &[f64]) -> f64 {
    let k = (values.len() / 10).max(1);
    let tail = &values[values.len().saturating_sub(k)..];
    tail.iter().sum::<f64>() / tail.len() as f64
}

/// Fits the reaction curve (tangent at the point of steepest slope) of the response to an
/// input step of size `input_step` applied at the first sample; the response's change is its
/// [`final_value`] less its first sample.
pub fn reaction_curve(
    times: &[f64],
    values: &[f64],
    input_step: f64,
) -> Result<ReactionCurve, MetricsError> {
    check(times, values)?;
    if !(input_step.is_finite() && input_step != 0.0) {
        return Err(MetricsError::Domain(format!(
            "input step {input_step} must be finite and non-zero"
        )));
    }
    let initial = values[0];
    let change = final_value(values) - initial;
    if change == 0.0 {
        return Err(MetricsError::NoStep(initial));
    }
    let (i, slope) = (1..values.len())
        .map(|i| (i, (values[i] - values[i - 1]) / (times[i] - times[i - 1])))
        .fold((1, 0.0), |best, (i, s)| {
            if s * change.signum() > best.1 * change.signum() {
                (i, s)
            } else {
                best
            }
        });
    let t_mid = 0.5 * (times[i] + times[i - 1]);
    let v_mid = 0.5 * (values[i] + values[i - 1]);
    let dead_time = t_mid - (v_mid - initial) / slope - times[0];
    let time_constant = change / slope;
    // A response that rises at once (a ramp from the first sample) has no dead time; the
    // rounding of the tangent left ~1e-17 s, which the Ziegler-Nichols rules turned into
    // gains of 1e15 and more. Below a billionth of the record it is zero.
    let resolvable = 1e-9 * (times[times.len() - 1] - times[0]);
    let dead_time = if dead_time > resolvable {
        dead_time
    } else {
        0.0
    };
    Ok(ReactionCurve {
        gain: change / input_step,
        dead_time,
        time_constant,
    })
}

/// The Ziegler-Nichols reaction-curve PID: kp = 1.2 T/(K L), Ti = 2 L, Td = L/2.
pub fn ziegler_nichols_reaction(curve: &ReactionCurve) -> Result<PidGains, MetricsError> {
    let ReactionCurve {
        gain,
        dead_time,
        time_constant,
    } = *curve;
    if !(dead_time > 0.0 && gain != 0.0 && time_constant > 0.0) {
        return Err(MetricsError::Domain(format!(
            "the reaction curve needs a positive dead time and time constant and a non-zero gain (K = {gain}, L = {dead_time}, T = {time_constant})"
        )));
    }
    let kp = 1.2 * time_constant / (gain * dead_time);
    usable(
        PidGains {
            kp,
            ki: kp / (2.0 * dead_time),
            kd: kp * dead_time / 2.0,
        },
        ["1.2 T/(K L)", "1.2 T/(K L) / (2 L)", "1.2 T/(K L) L/2"],
        || {
            format!(
                "K = {}, L = {} s, T = {} s",
                Num(gain),
                Num(dead_time),
                Num(time_constant)
            )
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Gains that overflow a double, or underflow to zero, are refused naming the gain, its
    /// rule and the inputs (`ki = inf` was returned for Ku = 1e308, Tu = 1e-308).
    #[test]
    fn ziegler_nichols_gains_that_overflow_are_refused() {
        let e = ziegler_nichols_ultimate(1e308, 1e-308).unwrap_err();
        assert_eq!(
            e.to_string(),
            "ki = 0.6 Ku / (Tu/2) is inf (overflow) for Ku = 1e308, Tu = 1e-308: no usable gain"
        );
        let e = ziegler_nichols_ultimate(1e308, 1e308).unwrap_err();
        assert!(matches!(e, MetricsError::Gain { gain: "kd", .. }), "{e}");
        let e = ziegler_nichols_ultimate(1e-308, 1e308).unwrap_err();
        assert!(
            e.to_string()
                .contains("ki = 0.6 Ku / (Tu/2) is 0 (underflow)"),
            "{e}"
        );
        let curve = ReactionCurve {
            gain: 1e-300,
            dead_time: 1e-10,
            time_constant: 1e10,
        };
        let e = ziegler_nichols_reaction(&curve).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("kp = 1.2 T/(K L) is inf (overflow) for K = 1e-300"),
            "{e}"
        );
        let g = ziegler_nichols_ultimate(1e300, 1.0).unwrap();
        assert_eq!((g.kp, g.ki, g.kd), (6e299, 1.2e300, 7.5e298));
    }

    fn grid(n: usize, dt: f64) -> Vec<f64> {
        (0..n).map(|i| i as f64 * dt).collect()
    }

    #[test]
    fn first_order_step_matches_the_closed_forms() {
        let tau = 0.2;
        let t = grid(20_001, 1e-4);
        let y: Vec<f64> = t.iter().map(|t| 3.0 * (1.0 - (-t / tau).exp())).collect();
        let m = step_metrics(&t, &y, Some(3.0)).unwrap();
        // 90 % at tau ln 10, inside 5 % from tau ln 20.
        assert!((m.rise_time.unwrap() - tau * 10f64.ln()).abs() < 1e-6);
        assert!((m.settling_time.unwrap() - tau * 20f64.ln()).abs() < 1e-6);
        assert_eq!(m.overshoot, 0.0);
    }

    #[test]
    fn second_order_overshoot_and_peak_time_match_the_closed_forms() {
        let (zeta, wn): (f64, f64) = (0.3, 10.0);
        let wd = wn * (1.0 - zeta * zeta).sqrt();
        let t = grid(100_001, 5e-5);
        let y: Vec<f64> = t
            .iter()
            .map(|&t| {
                1.0 - (-zeta * wn * t).exp()
                    * ((wd * t).cos() + zeta / (1.0 - zeta * zeta).sqrt() * (wd * t).sin())
            })
            .collect();
        let m = step_metrics(&t, &y, Some(1.0)).unwrap();
        let overshoot = (-zeta * std::f64::consts::PI / (1.0 - zeta * zeta).sqrt()).exp();
        assert!((m.overshoot - overshoot).abs() < 1e-6, "{}", m.overshoot);
        assert!((m.peak_time - std::f64::consts::PI / wd).abs() < 1e-4);
        // The 5 % envelope bound: settling no later than ln(20/sqrt(1-zeta^2))/(zeta wn).
        let bound = (20.0 / (1.0 - zeta * zeta).sqrt()).ln() / (zeta * wn);
        assert!(m.settling_time.unwrap() <= bound + 1e-9);
        assert!(m.rise_time.unwrap() < m.peak_time);
    }

    #[test]
    fn a_response_that_never_settles_says_so() {
        let t = grid(100, 0.01);
        let y: Vec<f64> = t.iter().map(|t| (t * 50.0).sin() + t).collect();
        let m = step_metrics(&t, &y, Some(0.5)).unwrap();
        assert_eq!(m.settling_time, None);
    }

    #[test]
    fn bad_inputs_are_refused() {
        assert!(matches!(
            step_metrics(&[0.0], &[1.0], None),
            Err(MetricsError::Samples { .. })
        ));
        assert!(matches!(
            step_metrics(&[0.0, 0.0], &[1.0, 2.0], None),
            Err(MetricsError::Time(1))
        ));
        assert!(matches!(
            step_metrics(&[0.0, 1.0], &[1.0, 1.0], None),
            Err(MetricsError::NoStep(_))
        ));
        assert!(matches!(
            step_metrics(&[0.0, 1.0], &[1.0, f64::NAN], None),
            Err(MetricsError::NotFinite(1))
        ));
        assert!(ziegler_nichols_ultimate(-1.0, 1.0).is_err());
        assert!(tracking_error(&[1.0], &[]).is_err());
    }

    #[test]
    fn ziegler_nichols_tables() {
        let g = ziegler_nichols_ultimate(10.0, 0.5).unwrap();
        assert_eq!((g.kp, g.ki, g.kd), (6.0, 24.0, 0.375));
        let c = ReactionCurve {
            gain: 2.0,
            dead_time: 0.1,
            time_constant: 1.0,
        };
        let g = ziegler_nichols_reaction(&c).unwrap();
        assert!(
            (g.kp - 6.0).abs() < 1e-12 && (g.ki - 30.0).abs() < 1e-9 && (g.kd - 0.3).abs() < 1e-12
        );
    }

    #[test]
    fn reaction_curve_of_a_first_order_lag_with_dead_time() {
        // K = 2, L = 0.3, T = 1: y = 2 (1 - exp(-(t - L)/T)) after L. The tangent at the
        // steepest point (just after L) recovers L and T.
        let (k, l, tau) = (2.0, 0.3, 1.0);
        let t = grid(100_001, 1e-4);
        let y: Vec<f64> = t
            .iter()
            .map(|&t| {
                if t < l {
                    0.0
                } else {
                    k * (1.0 - (-(t - l) / tau).exp())
                }
            })
            .collect();
        let c = reaction_curve(&t, &y, 1.0).unwrap();
        assert!((c.dead_time - l).abs() < 1e-3, "{c:?}");
        // The record ends at 10 s: the final value (its last second's mean) is within 3e-4 of K.
        assert!(
            (c.gain - k).abs() < 1e-3 && (c.time_constant - tau).abs() < 1e-3,
            "{c:?}"
        );
    }

    /// The gain is read from the record's settled tail, not from its last sample alone: a
    /// speed quantised to encoder counts alternates by a count (here 2 % of the step) from
    /// sample to sample, which the last sample passed on whole to the gain.
    #[test]
    fn the_reaction_curve_gain_is_the_tail_mean_not_the_last_sample() {
        let (k, tau, count) = (2.0, 0.1, 0.04);
        let t = grid(1501, 1e-3);
        let y: Vec<f64> = t
            .iter()
            .enumerate()
            .map(|(i, &t)| {
                let dither = if i % 2 == 0 { 0.5 } else { -0.5 };
                k * (1.0 - (-t / tau).exp()) + dither * count
            })
            .collect();
        assert_eq!(final_value(&y), {
            let tail = &y[1501 - 150..];
            tail.iter().sum::<f64>() / 150.0
        });
        let c = reaction_curve(&t, &y, 1.0).unwrap();
        // The last sample is half a count high (1 %); the tail's 150 samples average out.
        assert!((y[1500] - k - 0.5 * count).abs() < 1e-5);
        assert!((c.gain - (k - y[0])).abs() < 1e-4 * k, "{c:?}");
        // A record of one sample's tail is that sample.
        assert_eq!(final_value(&[3.0, 5.0]), 5.0);
    }

    /// A response rising from its first sample (a ramp) has no dead time, not the rounding
    /// of its tangent; the Ziegler-Nichols rules then refuse it instead of giving gains of
    /// 1e15.
    #[test]
    fn a_ramp_from_the_first_sample_has_no_dead_time() {
        let (t, y) = ([0.0, 0.1, 0.2, 0.3], [0.0, 1.0, 2.0, 3.0]);
        let c = reaction_curve(&t, &y, 1.0).unwrap();
        assert_eq!(c.dead_time, 0.0, "{c:?}");
        let e = ziegler_nichols_reaction(&c).unwrap_err();
        assert!(e.to_string().contains("positive dead time"), "{e}");
    }

    #[test]
    fn tracking_error_is_rms_and_max() {
        let (rms, max) = tracking_error(&[0.0, 0.0, 0.0, 0.0], &[1.0, -1.0, 1.0, -1.0]).unwrap();
        assert_eq!((rms, max), (1.0, 1.0));
    }
}
