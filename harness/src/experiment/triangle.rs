//! The triangle test (bench-model.md section 5): the test motor follows a triangle position
//! wave of constant amplitude while the load motor's torque is raised by an increment each
//! cycle, until the load driver's braking (regenerated-power) limit trips; the torque of the
//! cycle that tripped is the result.
//!
//! The triangle comes from `GaitReference` (`motionWaveform` Triangle); the position loop is a
//! `PidController` on `actuationEncoderAngle` with the viscous feed-forward `c1 omega_ref /
//! (i_HD Km1)` (the triangle's constant speed `4 A / P` needs `c1 omega` of steady torque); the
//! load current is the staircase `(T0 + n dT) / (i_RED Km2)` in cycle `n`. The load motor
//! brakes in the half cycle where its torque opposes the motion; its driver then absorbs
//! `Ke2 i_RED omega i2 - R2 i2^2`, which grows with the torque until the interlock
//! (`loadRegenPowerLimit`, 5 W) ends the run. Reported per cycle: the load torque, the largest
//! regenerated power (`loadRegeneratedPower`) and the largest shaft torque.

use std::path::Path;

use super::{
    Bench, ExperimentError, RunEnd, Table, Written, column, num, run, schedule, set_integers,
    set_reals, write_outputs,
};
use crate::results::plot::PlotLabels;

/// Settings of the triangle test.
#[derive(Debug, Clone, PartialEq)]
pub struct TriangleConfig {
    /// Triangle amplitude \[rad\].
    pub amplitude: f64,
    /// Triangle period \[s\].
    pub period: f64,
    /// Load torque of the first cycle [N m].
    pub start_torque: f64,
    /// Increment per cycle [N m].
    pub increment: f64,
    /// Largest number of cycles.
    pub max_cycles: u32,
    /// Position loop: kp [A/rad], ki [A/(rad s)], kd [A s/rad].
    pub gains: (f64, f64, f64),
}

impl Default for TriangleConfig {
    fn default() -> Self {
        TriangleConfig {
            amplitude: 30f64.to_radians(),
            period: 3.0,
            start_torque: 0.0,
            increment: 0.5,
            max_cycles: 40,
            gains: (60.0, 30.0, 4.0),
        }
    }
}

/// One cycle of the test.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TriangleCycle {
    /// Cycle number (from 0).
    pub cycle: u32,
    /// Load torque of the cycle [N m].
    pub torque: f64,
    /// Largest regenerated power in the cycle \[W\].
    pub peak_regenerated_power: f64,
    /// Largest |shaft torque| in the cycle [N m].
    pub peak_shaft_torque: f64,
    /// Whether the cycle ran to its end.
    pub complete: bool,
}

/// The test's result.
#[derive(Debug, Clone, PartialEq)]
pub struct TriangleResult {
    /// The cycles run.
    pub cycles: Vec<TriangleCycle>,
    /// The trip: (load torque of the tripping cycle [N m], time \[s\], reason); `None` if no
    /// trip within `max_cycles`.
    pub trip: Option<(f64, f64, String)>,
    /// The braking limit bracketed by the test \[W\]: the largest regenerated power of the
    /// last complete cycle, and the peak the tripping cycle would have reached by the fit
    /// `P = alpha |T| + beta T^2` of the complete cycles' peaks (NaN without a trip or with
    /// fewer than two loaded complete cycles).
    pub limit_bracket: (f64, f64),
    /// What was written.
    pub written: Written,
}

/// Runs the triangle test on `bench` and writes its files into `out`.
pub fn run_triangle(
    bench: &Bench,
    config: &TriangleConfig,
    out: &Path,
) -> Result<TriangleResult, ExperimentError> {
    bench.check_armed()?;
    let ok = |v: f64| v.is_finite() && v > 0.0;
    if !(ok(config.amplitude)
        && ok(config.period)
        && config.start_torque.is_finite()
        && config.increment.is_finite()
        && config.increment != 0.0
        && config.max_cycles >= 1)
    {
        return Err(ExperimentError::Invalid(
            "triangle: amplitude and period must be positive, the increment non-zero, at least one cycle".into(),
        ));
    }
    // Before the schedule (two points a cycle) is built.
    super::check_length(
        &format!(
            "the triangle test ({} cycles of {} s)",
            config.max_cycles,
            model_description::num::Num(config.period)
        ),
        config.period * f64::from(config.max_cycles),
    )?;
    let per_amp = bench.load_torque_per_ampere()?;
    let torque_of = |n: u32| config.start_torque + f64::from(n) * config.increment;
    let stairs: Vec<(f64, f64)> = (0..config.max_cycles)
        .flat_map(|n| {
            let t = f64::from(n) * config.period;
            let i = torque_of(n) / per_amp;
            [(t, i), (t + config.period, i)]
        })
        .collect();
    let mut system = bench.system()?;
    system.add_component("gait", bench.companion("GaitReference")?)?;
    set_integers(&mut system, "gait", &[("motionWaveform", 6)])?;
    set_reals(
        &mut system,
        "gait",
        &[
            ("gaitPeriod", config.period),
            ("kneeAngleAmplitude", config.amplitude),
            // The first cycle fades in (from rest, a full-speed start rings the spring).
            ("fadeInTime", config.period),
        ],
    )?;
    // The velocity feed-forward gives the current for the actuation damping's torque at the
    // reference velocity (amperes per rad/s).
    let feed_forward_gain = bench.real("actuationDamping")? / bench.test_torque_per_ampere()?;
    bench.add_position_loop(
        &mut system,
        config.gains,
        &[("feedForwardGain", feed_forward_gain)],
    )?;
    system.connect("gait.kneeAngleReference", "position.setpoint")?;
    system.connect("gait.kneeVelocityReference", "position.feedForward")?;
    system.connect("plant.actuationEncoderAngle", "position.measurement")?;
    system.connect("position.u", "plant.testCurrentCommand")?;
    system.add_signal("plant.loadCurrentCommand", schedule(stairs, false))?;
    let stop = config.period * f64::from(config.max_cycles);
    let (output, end) = run(bench, &mut system, stop)?;
    let r = &output.results;
    let times = r.times();
    let regen = column(r, "plant.loadRegeneratedPower")?;
    let shaft = column(r, "plant.springTorque")?;
    let last = times.last().copied().unwrap_or(0.0);
    let mut cycles = Vec::new();
    for n in 0..config.max_cycles {
        let (a, b) = (
            f64::from(n) * config.period,
            f64::from(n + 1) * config.period,
        );
        let rows: Vec<usize> = (0..times.len())
            .filter(|&i| times[i] > a + 1e-9 && times[i] <= b + 1e-9)
            .collect();
        if rows.is_empty() {
            break;
        }
        let peak = |v: &[f64]| rows.iter().map(|&i| v[i].abs()).fold(0.0, f64::max);
        cycles.push(TriangleCycle {
            cycle: n,
            torque: torque_of(n),
            peak_regenerated_power: peak(&regen),
            peak_shaft_torque: peak(&shaft),
            complete: b <= last + 1e-9,
        });
    }
    let trip = match &end {
        RunEnd::Completed => None,
        RunEnd::Tripped { time, reason } => {
            let n = ((time - 1e-9) / config.period).floor().max(0.0) as u32;
            Some((torque_of(n), *time, reason.clone()))
        }
    };
    let limit_bracket = match &trip {
        None => (f64::NAN, f64::NAN),
        Some((torque, _, _)) => {
            let complete: Vec<&TriangleCycle> = cycles
                .iter()
                .filter(|c| c.complete && c.torque != 0.0)
                .collect();
            let below = complete
                .last()
                .map_or(f64::NAN, |c| c.peak_regenerated_power);
            let rows: Vec<Vec<f64>> = complete
                .iter()
                .map(|c| vec![c.torque.abs(), c.torque * c.torque])
                .collect();
            let p: Vec<f64> = complete.iter().map(|c| c.peak_regenerated_power).collect();
            let above = if rows.len() >= 2 {
                let fit = super::analysis::least_squares(&rows, &p)?;
                fit.coefficients[0] * torque.abs() + fit.coefficients[1] * torque * torque
            } else {
                f64::NAN
            };
            (below, above)
        }
    };
    let written = write_triangle(bench, config, &cycles, &trip, limit_bracket, r, out)?;
    Ok(TriangleResult {
        cycles,
        trip,
        limit_bracket,
        written,
    })
}

fn write_triangle(
    bench: &Bench,
    config: &TriangleConfig,
    cycles: &[TriangleCycle],
    trip: &Option<(f64, f64, String)>,
    limit_bracket: (f64, f64),
    run: &crate::Results,
    out: &Path,
) -> Result<Written, ExperimentError> {
    let names = vec![
        "load torque [N m]".to_string(),
        "peak regenerated power [W]".into(),
        "peak shaft torque [N m]".into(),
        "regenerated power limit [W]".into(),
    ];
    let regen_limit = bench.real("loadRegenPowerLimit")?;
    let table = Table {
        x: "cycle".into(),
        names: names.clone(),
        rows: cycles
            .iter()
            .map(|c| {
                (
                    f64::from(c.cycle),
                    vec![
                        c.torque,
                        c.peak_regenerated_power,
                        c.peak_shaft_torque,
                        regen_limit,
                    ],
                )
            })
            .collect(),
    };
    let mut body = format!(
        "Triangle test on `{}`: +-{:.1} deg triangle of {} s (speed {:.3} rad/s), load torque {} N m + {} N m per cycle, at most {} cycles; load driver's braking limit `loadRegenPowerLimit` = {} W.\n\n",
        bench.path().display(),
        config.amplitude.to_degrees(),
        config.period,
        4.0 * config.amplitude / config.period,
        config.start_torque,
        config.increment,
        config.max_cycles,
        regen_limit,
    );
    match trip {
        Some((torque, time, reason)) => body.push_str(&format!(
            "**Tripped at {time:.3} s with the load torque at {torque} N m** ({reason}). The braking limit lies between {} W (largest regenerated power of the last complete cycle) and {} W (the tripping cycle's peak extrapolated by the fit `P = alpha |T| + beta T^2` of the complete cycles).\n\n",
            num(limit_bracket.0, 3),
            num(limit_bracket.1, 3)
        )),
        None => body.push_str("No trip within the cycles run.\n\n"),
    }
    body.push_str("| cycle | load torque [N m] | peak regenerated power [W] | peak shaft torque [N m] | complete |\n|---:|---:|---:|---:|---|\n");
    for c in cycles {
        body.push_str(&format!(
            "| {} | {} | {} | {} | {} |\n",
            c.cycle,
            num(c.torque, 2),
            num(c.peak_regenerated_power, 3),
            num(c.peak_shaft_torque, 3),
            if c.complete { "yes" } else { "no (trip)" }
        ));
    }
    let series: Vec<&str> = names.iter().map(String::as_str).collect();
    write_outputs(
        bench,
        out,
        "triangle",
        "Triangle test: load torque raised until the braking limit trips",
        run,
        &table,
        &series,
        &PlotLabels {
            x: "cycle".into(),
            y: "N m, W".into(),
            title: "Triangle test: load torque, peak regenerated power, peak shaft torque".into(),
        },
        &body,
    )
}
