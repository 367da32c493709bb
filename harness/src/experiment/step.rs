//! Step responses (bench-model.md section 6): the quality measures the study tuned with (rise
//! time to 90 %, settling time in the 5 % band, overshoot, peak time) and Ziegler-Nichols
//! starting gains.
//!
//! Two runs, each a fresh instance of the bench:
//! 1. **Open loop**: a test-motor current step of `current` A at `step_time`; the
//!    actuation-side speed's reaction curve (`crate::metrics::reaction_curve`, the code of
//!    `kneebench tune --step-response`) gives the static gain K [(rad/s)/A], dead time L and
//!    time constant T, and the Ziegler-Nichols PID of a velocity loop
//!    (`crate::metrics::ziegler_nichols_reaction`); on `BenchHardware`, whose speed is an
//!    encoder difference, only when the response moves by 10 counts per sample or more (see
//!    `unresolved_tangent`: at 1 kHz this bench's never does). The mean residence time
//!    `T_ar = integral (w_end - w) dt / (w_end - w_0)` (`w_end` the mean of the record's last
//!    tenth, `crate::metrics::final_value`, as for K) identifies the plant: without friction the
//!    two-mass speed response has `K = i_HD Km1 / (c1 + c2)` and `T_ar = (I1 + I2)/(c1 + c2) -
//!    c2^2 / (k (c1 + c2)) + tau_c` (current loop), so `c = i_HD Km1 / K` and
//!    `I = c T_ar` are the bench's total damping and inertia (friction lowers K: on the plant,
//!    `frictionModel` = 0 isolates them).
//! 2. **Closed loop**: a position step of `angle` (`GaitReference` Step) into a
//!    `PidController` on `actuationEncoderAngle`; the metrics of `actuationAngle`
//!    (`crate::metrics::step_metrics`, the code of `kneebench metrics`).

use std::path::Path;

use super::{
    Bench, ExperimentError, RunEnd, Table, Written, column, num, run, schedule, set_integers,
    set_reals, write_outputs,
};
use crate::metrics::{
    PidGains, ReactionCurve, StepMetrics, final_value, reaction_curve, step_metrics,
    ziegler_nichols_reaction,
};
use crate::results::plot::PlotLabels;
use model_description::num::Num;

/// Settings of the step experiment.
#[derive(Debug, Clone, PartialEq)]
pub struct StepConfig {
    /// Open-loop test-motor current step \[A\].
    pub current: f64,
    /// Closed-loop position step \[rad\].
    pub angle: f64,
    /// Time of both steps \[s\].
    pub step_time: f64,
    /// Record after the step \[s\].
    pub duration: f64,
    /// Position loop: kp [A/rad], ki [A/(rad s)], kd [A s/rad].
    pub gains: (f64, f64, f64),
}

impl Default for StepConfig {
    fn default() -> Self {
        StepConfig {
            current: 2.0,
            angle: 5f64.to_radians(),
            step_time: 0.2,
            duration: 1.5,
            // A 10 deg step, or stiffer gains, trips the SEA's shaft-torque interlock on the
            // plant (the loop saturates at 15 A and the spring passes 20 N m).
            gains: (60.0, 30.0, 4.0),
        }
    }
}

/// The step experiment's result.
#[derive(Debug, Clone, PartialEq)]
pub struct StepResult {
    /// Reaction curve of the open-loop speed response.
    pub reaction: ReactionCurve,
    /// Mean residence time T_ar \[s\].
    pub residence_time: f64,
    /// Identified total damping `i_HD Km1 / K` [N m s/rad].
    pub damping: f64,
    /// Identified total inertia `damping x T_ar` [kg m^2].
    pub inertia: f64,
    /// Ziegler-Nichols PID of a velocity loop (current per rad/s), if the reaction curve has a
    /// positive dead time.
    pub ziegler_nichols: Result<PidGains, String>,
    /// The closed-loop position step's metrics.
    pub position: StepMetrics,
    /// How the two runs ended.
    pub ends: [RunEnd; 2],
    /// What was written.
    pub written: Written,
}

/// Runs both steps on `bench` and writes the files into `out`.
pub fn run_step(
    bench: &Bench,
    config: &StepConfig,
    out: &Path,
) -> Result<StepResult, ExperimentError> {
    bench.check_armed()?;
    let limit = bench.real("testCurrentLimit")?;
    let ok = |v: f64| v.is_finite() && v > 0.0;
    if !(config.current.is_finite()
        && config.current != 0.0
        && config.current.abs() <= limit
        && ok(config.angle)
        && ok(config.step_time)
        && ok(config.duration))
    {
        return Err(ExperimentError::Invalid(format!(
            "step: the current must be non-zero and within the driver's {limit} A, the angle positive (GaitReference's step amplitude), step time and duration positive"
        )));
    }
    let stop = ((config.step_time + config.duration) / super::STEP).round() * super::STEP;
    let after = |times: &[f64], v: &[f64]| -> (Vec<f64>, Vec<f64>) {
        times
            .iter()
            .zip(v)
            .filter(|(t, _)| **t >= config.step_time - 1e-9)
            .map(|(t, v)| (*t, *v))
            .unzip()
    };

    // 1. Open loop.
    let mut system = bench.system()?;
    system.add_signal(
        "plant.testCurrentCommand",
        schedule(vec![(0.0, 0.0), (config.step_time, config.current)], false),
    )?;
    let (open, open_end) = run(bench, &mut system, stop)?;
    if let RunEnd::Tripped { time, reason } = &open_end {
        return Err(ExperimentError::Run(format!(
            "step: the open-loop run was ended at {time:.3} s: {reason}"
        )));
    }
    let (t_open, w) = after(
        &open.results.times(),
        &column(&open.results, "plant.actuationVelocity")?,
    );
    check_settled(&t_open, &w, config.duration)?;
    let reaction = reaction_curve(&t_open, &w, config.current)
        .map_err(|e| ExperimentError::Analysis(e.to_string()))?;
    let (w0, w_end) = (w[0], final_value(&w));
    let area: f64 = t_open
        .windows(2)
        .zip(w.windows(2))
        .map(|(t, v)| (t[1] - t[0]) * (w_end - 0.5 * (v[0] + v[1])))
        .sum();
    let residence_time = area / (w_end - w0);
    let damping = bench.test_torque_per_ampere()? / reaction.gain;
    let inertia = damping * residence_time;
    let ziegler_nichols = match unresolved_tangent(bench, (w_end - w0) / residence_time)? {
        Some(why) => Err(why),
        None => ziegler_nichols_reaction(&reaction).map_err(|e| e.to_string()),
    };

    // 2. Closed loop.
    let mut system = bench.system()?;
    system.add_component("gait", bench.companion("GaitReference")?)?;
    set_integers(&mut system, "gait", &[("motionWaveform", 3)])?;
    set_reals(
        &mut system,
        "gait",
        &[
            ("kneeAngleAmplitude", config.angle),
            ("stepTime", config.step_time),
        ],
    )?;
    bench.add_position_loop(&mut system, config.gains, &[])?;
    system.connect("gait.kneeAngleReference", "position.setpoint")?;
    system.connect("plant.actuationEncoderAngle", "position.measurement")?;
    system.connect("position.u", "plant.testCurrentCommand")?;
    let (closed, closed_end) = run(bench, &mut system, stop)?;
    let (t_closed, theta) = after(
        &closed.results.times(),
        &column(&closed.results, "plant.actuationAngle")?,
    );
    let position = step_metrics(&t_closed, &theta, Some(config.angle))
        .map_err(|e| ExperimentError::Analysis(e.to_string()))?;

    // The raw run: both records side by side on the common time grid.
    let n = open.results.len().min(closed.results.len());
    let mut names: Vec<String> = open
        .results
        .names()
        .iter()
        .map(|c| format!("open.{c}"))
        .collect();
    names.extend(closed.results.names().iter().map(|c| format!("closed.{c}")));
    let mut raw = crate::Results::with_capacity(
        names,
        vec![
            crate::results::ColumnKind::Real;
            open.results.names().len() + closed.results.names().len()
        ],
        n,
    );
    for i in 0..n {
        let mut row = open.results.row(i)[1..].to_vec();
        row.extend_from_slice(&closed.results.row(i)[1..]);
        raw.push_row(open.results.row(i)[0], &row);
    }
    let ends = [open_end, closed_end];
    let written = write_step(
        bench,
        config,
        (&t_open, &w),
        (&t_closed, &theta),
        &StepSummary {
            reaction: &reaction,
            residence_time,
            damping,
            inertia,
            zn: &ziegler_nichols,
            position: &position,
            ends: &ends,
        },
        &raw,
        out,
    )?;
    Ok(StepResult {
        reaction,
        residence_time,
        damping,
        inertia,
        ziegler_nichols,
        position,
        ends,
        written,
    })
}

/// Why the tangent of the reaction curve cannot be read from this bench's speed, if it cannot.
///
/// The tangent is one sample-to-sample slope of the speed. `BenchPlant` gives the speed
/// itself; `BenchHardware` (the physical bench) the difference of two encoder readings over
/// the period, in counts of `2 pi / (encoderCountsPerRevolution x harmonicDriveRatio) / h`
/// (0.0196 rad/s at the bench's 2,000 counts, 160:1 and 1 ms). When the response changes by
/// fewer than 10 counts per sample (`typical_slope`, the change over the mean residence time,
/// is an estimate of its steepest slope from below), one count is more than 10 % of the
/// slope, and the steepest sample slope is a count edge anywhere in the record: six runs
/// through the emulator gave dead times from 0.05 to 1.5 s against 0.4 ms on the plant, and
/// Ziegler-Nichols kp 2,000 to 80,000 times below the plant's. Those gains are refused, with this
/// reason, rather than printed.
fn unresolved_tangent(
    bench: &Bench,
    typical_slope: f64,
) -> Result<Option<String>, ExperimentError> {
    if bench.kind() != super::BenchKind::Hardware {
        return Ok(None);
    }
    let count = std::f64::consts::TAU
        / (bench.real("encoderCountsPerRevolution")? * bench.real("harmonicDriveRatio")?)
        / super::STEP;
    let per_sample = (typical_slope * super::STEP / count).abs();
    // A NaN count (a residence time of zero) is unresolved too.
    let resolved = per_sample >= 10.0;
    Ok((!resolved).then(|| {
        format!(
            "the speed is an encoder difference in counts of {count:.4} rad/s, and the response \
             changes by about {per_sample:.2} counts per sample: its tangent (so L and T above) \
             is not resolved; identify the bench's model from its Bode and map logs \
             (`kneebench identify`) and tune on the twin instead"
        )
    }))
}

/// Samples the open-loop record must hold after the step for its tail to say whether the
/// speed has settled.
const MIN_SETTLING_SAMPLES: usize = 50;
/// How fast the speed may still change over the record's last tenth, as a fraction of its
/// steepest rate, for the record to count as settled: a first-order response gets there
/// after 3.9 time constants, within 2 % of its final value.
const SETTLED_RATE: f64 = 0.02;
/// How far the mean speed of the record's last tenth may lie from that of the tenth before
/// it, as a fraction of the speed's change over the step, for the record to count as settled.
/// The residence time integrates the final value's error over the whole record, so a small
/// error becomes a large one in the inertia: the SEA plant's spring mode still swings by a few
/// per cent 0.8 s after the step, its last two tenths' means differ by 2.5 % there, and its
/// identified inertia was 7.8 % low (1.2 s: 0.08 % and 0.8 % low; the default 1.5 s: 0.12 %
/// and 0.5 % low). The rate test above misses such a swing when the record ends on its crest.
const SETTLED_MEAN_CHANGE: f64 = 0.005;

/// Refuses an open-loop record whose speed `w` has not settled by its end: the reaction curve
/// takes the mean of the last tenth as the final value, and the damping, residence time and
/// inertia follow from it, so a record cut short (`--duration 0.0005` gave two samples and an
/// "identified" inertia of 1.2 kg m^2) would be reported as identified values.
fn check_settled(times: &[f64], w: &[f64], duration: f64) -> Result<(), ExperimentError> {
    let lengthen = |why: String| {
        Err(ExperimentError::Analysis(format!(
            "step: {why}: the open-loop speed has not settled by the end of the record, so \
             no gain, damping or inertia can be read from it; lengthen --duration (now {} s)",
            Num(duration)
        )))
    };
    if w.len() < MIN_SETTLING_SAMPLES {
        return lengthen(format!(
            "{} samples after the step, fewer than {MIN_SETTLING_SAMPLES}",
            w.len()
        ));
    }
    let steepest = times
        .windows(2)
        .zip(w.windows(2))
        .map(|(t, v)| ((v[1] - v[0]) / (t[1] - t[0])).abs())
        .fold(0.0, f64::max);
    let n = w.len();
    let k = (n / 10).max(1);
    let end_rate = ((w[n - 1] - w[n - 1 - k]) / (times[n - 1] - times[n - 1 - k])).abs();
    // NaN (a non-finite sample) counts as unsettled.
    if end_rate.is_nan() || end_rate > SETTLED_RATE * steepest {
        return lengthen(format!(
            "over its last {:.3} s it still changes at {:.1} % of its steepest rate",
            times[n - 1] - times[n - 1 - k],
            100.0 * end_rate / steepest
        ));
    }
    if steepest == 0.0 {
        // A record that never moves is settled; the reaction curve then says that it does not
        // move (not "lengthen --duration").
        return Ok(());
    }
    // The final value the reaction curve reads (the last tenth's mean) against the tenth before.
    let (last, before) = (final_value(w), super::analysis::mean(&w[n - 2 * k..n - k]));
    let mean_change = ((last - before) / (last - w[0])).abs();
    if mean_change.is_nan() || mean_change > SETTLED_MEAN_CHANGE {
        return lengthen(format!(
            "the mean of its last {:.3} s differs from that of the {:.3} s before by {:.2} % of \
             the step's change",
            times[n - 1] - times[n - 1 - k],
            times[n - 1 - k] - times[n - 1 - 2 * k],
            100.0 * mean_change
        ));
    }
    Ok(())
}

struct StepSummary<'a> {
    reaction: &'a ReactionCurve,
    residence_time: f64,
    damping: f64,
    inertia: f64,
    zn: &'a Result<PidGains, String>,
    position: &'a StepMetrics,
    ends: &'a [RunEnd; 2],
}

fn write_step(
    bench: &Bench,
    config: &StepConfig,
    open: (&[f64], &[f64]),
    closed: (&[f64], &[f64]),
    s: &StepSummary<'_>,
    raw: &crate::Results,
    out: &Path,
) -> Result<Written, ExperimentError> {
    // Figure: both responses normalised to their final values, against time after the step.
    let names = vec![
        "open loop: speed / final speed".to_string(),
        "closed loop: angle / step".into(),
        "open-loop speed [rad/s]".into(),
        "closed-loop angle [rad]".into(),
    ];
    let w_end = final_value(open.1);
    let n = open.0.len().min(closed.0.len());
    let table = Table {
        x: "time after the step [s]".into(),
        names: names.clone(),
        rows: (0..n)
            .map(|i| {
                (
                    open.0[i] - config.step_time,
                    vec![
                        (open.1[i] - open.1[0]) / (w_end - open.1[0]),
                        closed.1[i] / config.angle,
                        open.1[i],
                        closed.1[i],
                    ],
                )
            })
            .collect(),
    };
    let opt = |v: Option<f64>| v.map_or("not reached".to_string(), |x| format!("{x:.4} s"));
    let mut body = format!(
        "Step responses on `{}`.\n\n**Open loop**: test-motor current step of {} A at {} s. Reaction curve of the actuation-side speed: K = {} (rad/s)/A, L = {} s, T = {} s; mean residence time T_ar = {} s; identified total damping i_HD Km1 / K = {} N m s/rad and inertia c T_ar = {} kg m^2. ",
        bench.path().display(),
        config.current,
        config.step_time,
        num(s.reaction.gain, 5),
        num(s.reaction.dead_time, 5),
        num(s.reaction.time_constant, 5),
        num(s.residence_time, 5),
        num(s.damping, 4),
        num(s.inertia, 4),
    );
    match s.zn {
        Ok(g) => body.push_str(&format!(
            "Ziegler-Nichols starting gains of a velocity loop (A per rad/s, parallel form): kp = {}, ki = {}, kd = {}.\n\n",
            num(g.kp, 4),
            num(g.ki, 4),
            num(g.kd, 6)
        )),
        Err(e) => body.push_str(&format!("No Ziegler-Nichols gains: {e}.\n\n")),
    }
    body.push_str(&format!(
        "**Closed loop**: position step of {:.2} deg with kp {} A/rad, ki {} A/(rad s), kd {} A s/rad: rise time (90 %) {}, settling time (5 %) {}, overshoot {} %, peak time {} s.\n\n",
        config.angle.to_degrees(),
        config.gains.0,
        config.gains.1,
        config.gains.2,
        opt(s.position.rise_time),
        opt(s.position.settling_time),
        num(100.0 * s.position.overshoot, 2),
        num(s.position.peak_time, 4),
    ));
    for (what, end) in ["open-loop", "closed-loop"].iter().zip(s.ends) {
        if let RunEnd::Tripped { time, reason } = end {
            body.push_str(&format!(
                "**The {what} run was ended at {time:.3} s: {reason}.**\n\n"
            ));
        }
    }
    write_outputs(
        bench,
        out,
        "step",
        "Step responses and Ziegler-Nichols starting gains",
        raw,
        &table,
        &[names[0].as_str(), names[1].as_str()],
        &PlotLabels {
            x: "time after the step [s]".into(),
            y: "normalised response [-]".into(),
            title: "Open-loop speed and closed-loop position step responses".into(),
        },
        &body,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A first-order speed response `1 - e^(-t/tau)` sampled every millisecond for `length` s.
    fn response(tau: f64, length: f64) -> (Vec<f64>, Vec<f64>) {
        let n = (length / 1e-3).round() as usize + 1;
        let times: Vec<f64> = (0..n).map(|k| k as f64 * 1e-3).collect();
        let w = times.iter().map(|t| 1.0 - (-t / tau).exp()).collect();
        (times, w)
    }

    #[test]
    fn a_record_cut_before_the_speed_settles_is_refused() {
        // Settled: ten time constants.
        let (t, w) = response(0.1, 1.0);
        assert!(check_settled(&t, &w, 1.0).is_ok());
        // Two time constants: over the last tenth it still changes at 15 % of its steepest rate.
        let (t, w) = response(0.1, 0.2);
        let e = check_settled(&t, &w, 0.2).unwrap_err().to_string();
        assert!(e.contains("still changes at"), "{e}");
        assert!(e.contains("lengthen --duration (now 0.2 s)"), "{e}");
        // Flat over the last tenth, so the rate test passes, but the tenth before is 1 % higher:
        // a swing that the record ended on its crest.
        let (t, mut w) = response(0.05, 1.0);
        for v in &mut w[801..901] {
            *v += 0.01;
        }
        let e = check_settled(&t, &w, 1.0).unwrap_err().to_string();
        assert!(e.contains("differs from that of the"), "{e}");
        assert!(e.contains("by 1.00 % of the step's change"), "{e}");
        // The bound is half a per cent: 0.49 % passes, 0.51 % is refused.
        for (offset, settled) in [(0.0049, true), (0.0051, false)] {
            let (t, mut w) = response(0.05, 1.0);
            for v in &mut w[801..901] {
                *v += offset;
            }
            assert_eq!(check_settled(&t, &w, 1.0).is_ok(), settled, "{offset}");
        }
        // A record that never moves passes here, and the reaction curve says it does not move.
        let (t, w) = (response(0.05, 1.0).0, vec![0.25; 1001]);
        assert!(check_settled(&t, &w, 1.0).is_ok());
        let e = reaction_curve(&t, &w, 2.0).unwrap_err().to_string();
        assert!(e.contains("does not move") && e.contains("0.25"), "{e}");
        // Two samples (`--duration 0.0005`).
        let (t, w) = response(0.1, 0.001);
        let e = check_settled(&t, &w, 0.0005).unwrap_err().to_string();
        assert!(e.contains("2 samples after the step, fewer than 50"), "{e}");
    }
}
