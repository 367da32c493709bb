//! The pendulum calibration of the torque transducer and the load cell (bench-model.md
//! section 8): the pendulum's torque `T = m g Lg sin(theta)` is held at a series of angles and
//! `V = a + b sin(theta + c)` is fitted to each sensor's raw volts.
//!
//! **The rig on the twin.** The actuation side is held at each angle `theta_k` by a position
//! loop (`PidController` on `actuationEncoderAngle`, setpoint moved smoothly between the
//! holds, without a velocity step); the load motor applies the pendulum's gravity torque
//! `-m g Lg sin(theta + pendulum_offset)` along the way (`calibrationPendulumMoment` of the
//! bench FMU). At rest the shaft then carries
//! `m g Lg sin(theta_k)` through the transducer, and the test motor holds it (the load cell's
//! reaction torque). Static friction adds to each side's balance (up to `Tfr,static`): on the
//! plant, run it with `frictionModel` = 0 (Off) to see the sensors alone. The fit is linear in
//! `(a, p, q)`: `V = a + p sin(theta) + q cos(theta)`, `b = p / cos(c)`, `c = atan(q / p)`,
//! over the last `measure` seconds of each hold.
//!
//! **The phase c is the pendulum's mounting offset.** `T = m g Lg sin(theta)` takes the
//! pendulum's angle from its hanging direction, the fit `V = a + b sin(theta_enc + c)` the
//! encoder's angle: c is the angle between the two, the encoder's zero against the direction
//! in which the pendulum hangs (which is why the bench converts with `T = (m g Lg / b)(V - a)`,
//! without c). A sensor sees torque only, so c is observable only through the rig: the
//! emulated pendulum hangs `pendulum_offset` from the encoder's zero (its torque is
//! `-m g Lg sin(theta_enc + pendulum_offset)`), and the fit returns that offset as c. With
//! the default offset 0 the fit returns c = 0. The plant's running sensors keep their own
//! documented small-angle form `V = a + b sin(c_s) + b cos(c_s) T / (m g Lg)` with `c_s` =
//! `transducerPhase`, `loadCellPhase` (`fmu/src/models/bench/sensors.rs`), so on the plant the
//! fit's a and b are `a + b sin(c_s)` and `b cos(c_s)` (0.03 % and 5e-5 from the published
//! a and b).

use std::path::Path;

use super::analysis::{least_squares, mean};
use super::{
    Bench, ExperimentError, RunEnd, Table, Written, column, num, run, schedule, write_outputs,
};
use crate::results::plot::PlotLabels;

/// Spacing of the knots of a move between two angles \[s\].
const MOVE_KNOT: f64 = 0.01;

/// Settings of the calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationConfig {
    /// Pendulum angles \[rad\] (keep below 50 deg for the load cell).
    pub angles: Vec<f64>,
    /// Hold time at each angle \[s\].
    pub hold: f64,
    /// Averaging time at the end of each hold \[s\].
    pub measure: f64,
    /// Average speed of the (smooth) moves between angles [rad/s].
    pub speed: f64,
    /// Position loop: kp [A/rad], ki [A/(rad s)], kd [A s/rad].
    pub gains: (f64, f64, f64),
    /// The emulated pendulum's hanging direction in the encoder's frame \[rad\]: its gravity
    /// angle is `theta_enc + pendulum_offset` (the c the fit recovers).
    pub pendulum_offset: f64,
}

impl Default for CalibrationConfig {
    fn default() -> Self {
        CalibrationConfig {
            angles: (-5..=5).map(|k| f64::from(k * 9).to_radians()).collect(),
            hold: 6.0,
            measure: 3.0,
            // Slow, smooth moves: what rings the SEA's lightly damped load side (about 1.2 s
            // decay) still falls in the hold.
            speed: 5f64.to_radians(),
            gains: (1000.0, 1000.0, 15.0),
            pendulum_offset: 0.0,
        }
    }
}

/// A fitted calibration `V = a + b sin(theta + c)` with the standard deviations of a, b, c.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorFit {
    /// a \[V\].
    pub a: f64,
    /// b \[V\].
    pub b: f64,
    /// c \[rad\].
    pub c: f64,
    /// Standard deviations of (a, b, c).
    pub std: (f64, f64, f64),
    /// RMS of the residual \[V\].
    pub residual_rms: f64,
}

/// Fits `V = a + b sin(theta + c)` to `(angles, volts)`.
pub fn fit_sensor(angles: &[f64], volts: &[f64]) -> Result<SensorFit, ExperimentError> {
    let rows: Vec<Vec<f64>> = angles.iter().map(|t| vec![1.0, t.sin(), t.cos()]).collect();
    let fit = least_squares(&rows, volts)?;
    let (a, p, q) = (
        fit.coefficients[0],
        fit.coefficients[1],
        fit.coefficients[2],
    );
    if p == 0.0 {
        return Err(ExperimentError::Analysis(
            "calibration: the sensor does not respond to the pendulum".into(),
        ));
    }
    let c = (q / p).atan();
    let b = p / c.cos();
    // b = sign(p) hypot(p, q), c = atan(q / p): first-order propagation.
    let (vpp, vqq, vpq) = (fit.cov(1, 1), fit.cov(2, 2), fit.cov(1, 2));
    let r2 = p * p + q * q;
    let b_std = ((p * p * vpp + q * q * vqq + 2.0 * p * q * vpq) / r2)
        .max(0.0)
        .sqrt();
    let c_std = ((q * q * vpp + p * p * vqq - 2.0 * p * q * vpq) / (r2 * r2))
        .max(0.0)
        .sqrt();
    Ok(SensorFit {
        a,
        b,
        c,
        std: (fit.std(0), b_std, c_std),
        residual_rms: fit.residual_rms,
    })
}

/// The calibration's result.
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationResult {
    /// (angle \[rad\], transducer volts, load-cell volts) per hold.
    pub holds: Vec<(f64, f64, f64)>,
    /// The torque transducer's fit.
    pub transducer: SensorFit,
    /// The load cell's fit.
    pub load_cell: SensorFit,
    /// How the run ended.
    pub end: RunEnd,
    /// What was written.
    pub written: Written,
}

/// Runs the calibration on `bench` and writes its files into `out`.
pub fn run_calibration(
    bench: &Bench,
    config: &CalibrationConfig,
    out: &Path,
) -> Result<CalibrationResult, ExperimentError> {
    bench.check_armed()?;
    let ok = |v: f64| v.is_finite() && v > 0.0;
    if config.angles.len() < 3
        || config.angles.iter().any(|a| !a.is_finite())
        || !(ok(config.hold) && ok(config.measure) && ok(config.speed))
        || config.measure > config.hold
        || !config.pendulum_offset.is_finite()
        || config.pendulum_offset.abs() >= std::f64::consts::FRAC_PI_2
    {
        return Err(ExperimentError::Invalid(
            "calibration: give at least 3 finite angles, positive hold, measure (<= hold) and speed, and a pendulum offset within +-90 deg".into(),
        ));
    }
    let moment = bench.real("calibrationPendulumMoment")?;
    let per_amp = bench.load_torque_per_ampere()?;
    // The pendulum's gravity torque as the load motor's current at encoder angle `theta`.
    let gravity = |theta: f64| -moment * (theta + config.pendulum_offset).sin() / per_amp;
    let (mut t, mut previous): (f64, f64) = (0.0, 0.0);
    let (mut angle_schedule, mut load_schedule) = (vec![(0.0, 0.0)], vec![(0.0, gravity(0.0))]);
    let mut windows = Vec::new();
    for &theta in &config.angles {
        // A smooth move (velocity `(1 - cos(2 pi s))` times the average speed, s the move's
        // fraction, in knots of MOVE_KNOT seconds): it starts and stops without a velocity
        // step, which would ring the SEA's lightly damped load side (3.8 Hz, about 1.2 s
        // decay) into the averaging window. The gravity torque follows the angle.
        let duration = (theta - previous).abs() / config.speed;
        let knots = (duration / MOVE_KNOT).ceil().max(1.0) as usize;
        for k in 1..=knots {
            let s = k as f64 / knots as f64;
            let shape = s - (std::f64::consts::TAU * s).sin() / std::f64::consts::TAU;
            let angle = previous + (theta - previous) * shape;
            angle_schedule.push((t + s * duration, angle));
            load_schedule.push((t + s * duration, gravity(angle)));
        }
        t += duration + config.hold;
        angle_schedule.push((t, theta));
        load_schedule.push((t, gravity(theta)));
        windows.push((t - config.measure, t));
        previous = theta;
    }
    let mut system = bench.system()?;
    bench.add_position_loop(&mut system, config.gains, &[])?;
    system.add_signal("position.setpoint", schedule(angle_schedule, true))?;
    system.connect("plant.actuationEncoderAngle", "position.measurement")?;
    system.connect("position.u", "plant.testCurrentCommand")?;
    system.add_signal("plant.loadCurrentCommand", schedule(load_schedule, true))?;
    let stop = (t / super::STEP).ceil() * super::STEP;
    let (output, end) = run(bench, &mut system, stop)?;
    let r = &output.results;
    let times = r.times();
    let vt = column(r, "plant.transducerVoltage")?;
    let vl = column(r, "plant.loadCellVoltage")?;
    let last = times.last().copied().unwrap_or(0.0);
    let mut holds = Vec::new();
    for (&theta, &(a, b)) in config.angles.iter().zip(&windows) {
        if b > last + 1e-9 {
            break;
        }
        let rows: Vec<usize> = (0..times.len())
            .filter(|&i| times[i] > a + 1e-9 && times[i] <= b + 1e-9)
            .collect();
        let avg = |v: &[f64]| mean(&rows.iter().map(|&i| v[i]).collect::<Vec<_>>());
        holds.push((theta, avg(&vt), avg(&vl)));
    }
    if holds.len() < 3 {
        return Err(ExperimentError::Run(format!(
            "calibration: only {} holds completed ({end})",
            holds.len()
        )));
    }
    let angles: Vec<f64> = holds.iter().map(|h| h.0).collect();
    let transducer = fit_sensor(&angles, &holds.iter().map(|h| h.1).collect::<Vec<_>>())?;
    let load_cell = fit_sensor(&angles, &holds.iter().map(|h| h.2).collect::<Vec<_>>())?;
    let written = write_calibration(bench, config, &holds, &transducer, &load_cell, &end, r, out)?;
    Ok(CalibrationResult {
        holds,
        transducer,
        load_cell,
        end,
        written,
    })
}

#[allow(clippy::too_many_arguments)]
fn write_calibration(
    bench: &Bench,
    config: &CalibrationConfig,
    holds: &[(f64, f64, f64)],
    transducer: &SensorFit,
    load_cell: &SensorFit,
    end: &RunEnd,
    run: &crate::Results,
    out: &Path,
) -> Result<Written, ExperimentError> {
    let model = |f: &SensorFit, theta: f64| f.a + f.b * (theta + f.c).sin();
    // Figure: each sensor's deviation from its offset, measured and fitted, in mV.
    let names = vec![
        "transducer [V]".to_string(),
        "transducer fit [V]".into(),
        "load cell [V]".into(),
        "load cell fit [V]".into(),
        "transducer - a [mV]".into(),
        "transducer fit - a [mV]".into(),
        "load cell - a [mV]".into(),
        "load cell fit - a [mV]".into(),
    ];
    let table = Table {
        x: "pendulum angle [deg]".into(),
        names: names.clone(),
        rows: holds
            .iter()
            .map(|&(theta, v_t, v_l)| {
                let (m_t, m_l) = (model(transducer, theta), model(load_cell, theta));
                (
                    theta.to_degrees(),
                    vec![
                        v_t,
                        m_t,
                        v_l,
                        m_l,
                        1e3 * (v_t - transducer.a),
                        1e3 * (m_t - transducer.a),
                        1e3 * (v_l - load_cell.a),
                        1e3 * (m_l - load_cell.a),
                    ],
                )
            })
            .collect(),
    };
    let published = |a: &str, b: &str, c: &str| -> (String, String, String) {
        let v = |n: &str| bench.real(n).map(|x| format!("{x}")).unwrap_or("-".into());
        (v(a), v(b), v(c))
    };
    let pt = published("transducerOffset", "transducerGain", "transducerPhase");
    let pl = published("loadCellOffset", "loadCellGain", "loadCellPhase");
    let row = |name: &str, f: &SensorFit, p: &(String, String, String)| {
        format!(
            "| {name} | {} +- {} | {} +- {} | {} +- {} | {} | {} / {} / {} |\n",
            num(f.a, 6),
            num(f.std.0, 6),
            num(f.b, 7),
            num(f.std.1, 7),
            num(f.c, 5),
            num(f.std.2, 5),
            num(f.residual_rms, 7),
            p.0,
            p.1,
            p.2
        )
    };
    let mut body = format!(
        "Pendulum calibration on `{}`: {} angles from {:.1} to {:.1} deg, pendulum moment m g Lg = {} N m hanging {} rad from the encoder's zero (its torque `-m g Lg sin(theta + offset)`; c is that offset); fit of `V = a + b sin(theta + c)` to the raw volts (one standard deviation from the fit residual). The bench FMU's parameters are listed for comparison.\n\n",
        bench.path().display(),
        holds.len(),
        holds.first().map_or(0.0, |h| h.0.to_degrees()),
        holds.last().map_or(0.0, |h| h.0.to_degrees()),
        bench.real("calibrationPendulumMoment")?,
        config.pendulum_offset,
    );
    if let RunEnd::Tripped { time, reason } = end {
        body.push_str(&format!(
            "**The run was ended at {time:.3} s: {reason}.**\n\n"
        ));
    }
    body.push_str("| sensor | a [V] | b [V] | c [rad] | residual RMS [V] | parameters a / b / c |\n|---|---:|---:|---:|---:|---|\n");
    body.push_str(&row("torque transducer", transducer, &pt));
    body.push_str(&row("load cell", load_cell, &pl));
    body.push_str("\n| angle [deg] | transducer [V] | load cell [V] |\n|---:|---:|---:|\n");
    for (theta, v_t, v_l) in holds {
        body.push_str(&format!(
            "| {} | {} | {} |\n",
            num(theta.to_degrees(), 2),
            num(*v_t, 7),
            num(*v_l, 7)
        ));
    }
    let series: Vec<&str> = names[4..].iter().map(String::as_str).collect();
    write_outputs(
        bench,
        out,
        "calibration",
        "Pendulum calibration of the torque transducer and the load cell",
        run,
        &table,
        &series,
        &PlotLabels {
            x: "pendulum angle [deg]".into(),
            y: "V - a [mV]".into(),
            title: "Pendulum calibration: raw volts and fit".into(),
        },
        &body,
    )
}
