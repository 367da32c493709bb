//! The steady-state map (bench-model.md section 5): the test motor in velocity control at
//! constant speeds, the load motor at constant torques; at each point the harmonic drive's loss
//! torque and efficiency, compared with the loss surface (`hd-loss-surface.csv`).
//!
//! **Schedule.** For each load torque, each speed `v` of the list is run as `+v` then `-v` (the
//! angle returns), each point held `settle + measure` seconds; the speed moves between points
//! on ramps of `acceleration` (a speed step would ring the SEA spring past its 5 deg
//! interlock), and the load torque changes only at rest (the speed ramps to 0, the torque
//! ramps at `torque_rate`, the speed ramps to the next point). The velocity loop is a
//! `PidController` on `actuationVelocity` (current out); the load motor gets the current
//! `T / (i_RED Km2)`.
//!
//! **The braking limit.** Where the load motor's torque opposes the motion it brakes, and its
//! driver absorbs the regenerated power `P = -(R2 i2 + Ke2 i_RED omega) i2` (steady state,
//! `i2 = T / (i_RED Km2)`), which the armed hardware limits to 5 W (`loadRegenPowerLimit`,
//! bench-model.md section 7): at 9 N m and 150 deg/s the map would regenerate about 22 W. A
//! point whose predicted power exceeds `regen_fraction` of the bench's `loadRegenPowerLimit`
//! (the margin covers the velocity loop's transients) is skipped and listed as such; every
//! ramp stays within the limit too, since at constant torque the power is linear in the speed
//! (bounded by the two points it joins) and at rest it is `-R2 i2^2 <= 0`. On the plant the
//! limit is a parameter like any other: raise it to map the whole braking quadrant.
//!
//! **Quantities** (means over the last `measure` seconds of each point):
//! * loss torque `tau_loss = tau_shaft - tau_test` [N m]: the shaft torque past the drive
//!   (`springTorque`, `k (theta1 - theta2)` from the encoders; the transducer reading carries
//!   its calibration bias) minus the test motor's output torque `i_HD Km1 i1`
//!   (`testOutputTorque`). In steady state the actuation side's balance gives
//!   `tau_loss = F1 - c1 omega1`: the torque the drive applies to its output, signed like the
//!   loss surface (negative for positive speed). With the plant's `HdLossSurface` friction and
//!   `actuationDamping` = 0 it is the surface itself; with c1 > 0 the map includes the viscous
//!   part the plant models separately.
//! * efficiency of the drive: forward (test motor drives, `P_test = tau_test omega1 > 0` and
//!   the shaft power `P_shaft = tau_shaft omega1 > 0`): `P_shaft / P_test`; back-driven (both
//!   negative): `P_test / P_shaft`; otherwise both ends feed the drive and it is 0. Undefined
//!   at rest.
//! * the surface `tau_HD,ss(x, y)` at the measured `x` = load-motor output torque
//!   (`loadOutputTorque`) and `y` = `omega1`, clamped to the box the plant clamps to
//!   (`hdSurfaceMaxSpeed`, `hdSurfaceMinLoadTorque`, `hdSurfaceMaxLoadTorque`, when the bench
//!   FMU has them), and the relative difference. The zero-speed points are not compared: at
//!   rest the drive's friction is static, any torque inside its stiction band.

use std::path::Path;

use super::{
    Bench, ExperimentError, RunEnd, Table, Written, analysis::mean, column, num, run, schedule,
    set_reals, write_outputs,
};
use crate::results::plot::PlotLabels;

/// The loss surface shipped with the project (`shared/data/hd-loss-surface.csv`).
pub const DEFAULT_SURFACE: &str = include_str!("../../../../shared/data/hd-loss-surface.csv");

/// The speeds of the bench's map \[deg/s\], each run in both directions (0 once).
pub const BENCH_SPEEDS: [f64; 12] = [
    0.0, 3.0, 6.0, 10.0, 20.0, 30.0, 50.0, 70.0, 90.0, 110.0, 130.0, 150.0,
];

/// The default load torques [N m]: the gait's ground reaction (9 N m peak external torque, so
/// -4.7 ... 9 N m, or its mirror with the opposite sign convention) covered in both signs in
/// steps of 4.5 N m.
pub const DEFAULT_TORQUES: [f64; 5] = [-9.0, -4.5, 0.0, 4.5, 9.0];

/// The default largest predicted regenerated power of a point, as a fraction of the bench's
/// `loadRegenPowerLimit`.
pub const DEFAULT_REGEN_FRACTION: f64 = 0.8;

/// Settings of the map.
#[derive(Debug, Clone, PartialEq)]
pub struct MapConfig {
    /// Speed magnitudes \[deg/s\] (each run as +v and -v).
    pub speeds: Vec<f64>,
    /// Load-motor output torques [N m].
    pub torques: Vec<f64>,
    /// Settling time of each point \[s\].
    pub settle: f64,
    /// Averaging time of each point \[s\].
    pub measure: f64,
    /// Ramp rate of the speed between points [rad/s^2].
    pub acceleration: f64,
    /// Ramp rate of the load torque between points [N m/s].
    pub torque_rate: f64,
    /// Velocity loop: kp [A/(rad/s)], ki [A/rad].
    pub gains: (f64, f64),
    /// The loss surface (CSV text in the format of `hd-loss-surface.csv`).
    pub surface: String,
    /// A point is run only if its predicted steady regenerated power is at most this fraction
    /// of the bench's `loadRegenPowerLimit` (in (0, 1]).
    pub regen_fraction: f64,
}

impl Default for MapConfig {
    fn default() -> Self {
        MapConfig {
            speeds: BENCH_SPEEDS.to_vec(),
            torques: DEFAULT_TORQUES.to_vec(),
            settle: 1.5,
            measure: 1.0,
            acceleration: 2.0,
            torque_rate: 10.0,
            gains: (5.0, 50.0),
            surface: DEFAULT_SURFACE.to_string(),
            regen_fraction: DEFAULT_REGEN_FRACTION,
        }
    }
}

/// The loss surface: coefficients `p_ij` of `x^i y^j` for each sign of `y`.
#[derive(Debug, Clone, PartialEq)]
pub struct LossSurface {
    /// ((i, j), positive-speed coefficient, negative-speed coefficient).
    pub terms: Vec<((u32, u32), f64, f64)>,
}

impl LossSurface {
    /// Parses the CSV format of `hd-loss-surface.csv` (`#` comments, a header
    /// `term,positive_speed,negative_speed`, rows `pIJ,value,value`).
    pub fn parse(text: &str) -> Result<LossSurface, ExperimentError> {
        let bad = |line: &str| ExperimentError::Invalid(format!("loss surface: bad line '{line}'"));
        let mut terms = Vec::new();
        for line in text.lines().map(str::trim) {
            if line.is_empty() || line.starts_with('#') || line.starts_with("term") {
                continue;
            }
            let f: Vec<&str> = line.split(',').map(str::trim).collect();
            if f.len() != 3 || f[0].len() != 3 || !f[0].starts_with('p') {
                return Err(bad(line));
            }
            let digit = |k: usize| f[0][k..k + 1].parse::<u32>().map_err(|_| bad(line));
            let pos: f64 = f[1].parse().map_err(|_| bad(line))?;
            let neg: f64 = f[2].parse().map_err(|_| bad(line))?;
            terms.push(((digit(1)?, digit(2)?), pos, neg));
        }
        if terms.is_empty() {
            return Err(ExperimentError::Invalid(
                "loss surface: no coefficients".into(),
            ));
        }
        Ok(LossSurface { terms })
    }

    /// `tau_HD,ss(x, y)` [N m]: `x` load torque [N m], `y` actuation-side speed [rad/s].
    pub fn value(&self, x: f64, y: f64) -> f64 {
        self.terms
            .iter()
            .map(|&((i, j), p, n)| {
                let c = if y >= 0.0 { p } else { n };
                c * x.powi(i as i32) * y.powi(j as i32)
            })
            .sum()
    }
}

/// One point of the map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapPoint {
    /// Commanded speed [deg/s].
    pub speed_command: f64,
    /// Commanded load torque [N m].
    pub torque_command: f64,
    /// Measured actuation-side speed omega1 [rad/s].
    pub speed: f64,
    /// Measured load-motor output torque x [N m].
    pub load_torque: f64,
    /// Test-motor output torque [N m].
    pub test_torque: f64,
    /// Shaft torque [N m].
    pub shaft_torque: f64,
    /// Loss torque `tau_shaft - tau_test` [N m].
    pub loss_torque: f64,
    /// Drive efficiency (NaN at rest).
    pub efficiency: f64,
    /// The loss surface at the measured point (clamped to the plant's box) [N m].
    pub surface: f64,
    /// (loss - surface) / |surface| (NaN at rest: not compared).
    pub relative_difference: f64,
}

/// A point of the schedule left out because the load driver would regenerate too much.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SkippedPoint {
    /// Commanded speed [deg/s].
    pub speed_command: f64,
    /// Commanded load torque [N m].
    pub torque_command: f64,
    /// Predicted steady regenerated power of the load driver \[W\].
    pub regenerated_power: f64,
}

/// The map's points and how the run ended.
#[derive(Debug, Clone, PartialEq)]
pub struct MapResult {
    /// Measured points, in schedule order (only those completed before a trip).
    pub points: Vec<MapPoint>,
    /// Points of the configured grid not run: their braking would exceed the regenerated-power
    /// budget (`regen_fraction` of `loadRegenPowerLimit`).
    pub skipped: Vec<SkippedPoint>,
    /// How the run ended.
    pub end: RunEnd,
    /// What was written.
    pub written: Written,
}

/// Runs the map on `bench` and writes its files into `out`.
pub fn run_map(
    bench: &Bench,
    config: &MapConfig,
    out: &Path,
) -> Result<MapResult, ExperimentError> {
    bench.check_armed()?;
    let positive = |v: f64| v.is_finite() && v > 0.0;
    if config.speeds.is_empty()
        || config.torques.is_empty()
        || config
            .speeds
            .iter()
            .chain(&config.torques)
            .any(|v| !v.is_finite())
        || config.speeds.iter().any(|v| *v < 0.0)
        || !(positive(config.settle)
            && positive(config.measure)
            && positive(config.acceleration)
            && positive(config.torque_rate)
            && config.regen_fraction > 0.0
            && config.regen_fraction <= 1.0)
    {
        return Err(ExperimentError::Invalid(
            "map: give speeds >= 0 and torques, positive settle, measure, acceleration and torque rate, and a regen fraction in (0, 1]".into(),
        ));
    }
    let surface = LossSurface::parse(&config.surface)?;
    let per_amp = bench.load_torque_per_ampere()?;
    let regen = RegenModel::of(bench)?;
    let budget = config.regen_fraction * bench.real("loadRegenPowerLimit")?;
    // The points: (speed rad/s, torque), those within the braking budget, and the schedule of
    // ramps and holds.
    let mut points = Vec::new();
    let mut skipped = Vec::new();
    for &torque in &config.torques {
        for &v in &config.speeds {
            let w = v.to_radians();
            let signs: &[f64] = if v == 0.0 { &[1.0] } else { &[1.0, -1.0] };
            for &sign in signs {
                let power = regen.power(sign * w, torque);
                if power > budget {
                    skipped.push(SkippedPoint {
                        speed_command: sign * v,
                        torque_command: torque,
                        regenerated_power: power,
                    });
                } else {
                    points.push((sign * w, torque));
                }
            }
        }
    }
    if points.is_empty() {
        return Err(ExperimentError::Invalid(format!(
            "map: every point would regenerate more than {budget} W in the load driver"
        )));
    }
    let hold = config.settle + config.measure;
    let (mut t, mut w_prev, mut tq_prev): (f64, f64, f64) = (0.0, 0.0, 0.0);
    let (mut speed_schedule, mut current_schedule) = (vec![(0.0, 0.0)], vec![(0.0, 0.0)]);
    let mut windows = Vec::new();
    for &(w, torque) in &points {
        let mut knot = |t: f64, w: f64, torque: f64| {
            speed_schedule.push((t, w));
            current_schedule.push((t, torque / per_amp));
        };
        if torque != tq_prev {
            // The torque changes at rest: no braking on the way.
            t += w_prev.abs() / config.acceleration;
            knot(t, 0.0, tq_prev);
            t += (torque - tq_prev).abs() / config.torque_rate;
            knot(t, 0.0, torque);
            w_prev = 0.0;
        }
        t += (w - w_prev).abs() / config.acceleration;
        knot(t, w, torque);
        windows.push((t + config.settle, t + hold));
        t += hold;
        knot(t, w, torque);
        (w_prev, tq_prev) = (w, torque);
    }
    let stop = (t / super::STEP).ceil() * super::STEP;

    let mut system = bench.system()?;
    system.add_component("velocity", bench.companion("PidController")?)?;
    set_reals(
        &mut system,
        "velocity",
        &[
            ("kp", config.gains.0),
            ("ki", config.gains.1),
            ("kd", 0.0),
            ("outputMin", -bench.real("testCurrentLimit")?),
            ("outputMax", bench.real("testCurrentLimit")?),
        ],
    )?;
    system.add_signal("velocity.setpoint", schedule(speed_schedule, true))?;
    system.connect("plant.actuationVelocity", "velocity.measurement")?;
    system.connect("velocity.u", "plant.testCurrentCommand")?;
    system.add_signal("plant.loadCurrentCommand", schedule(current_schedule, true))?;
    let (output, end) = run(bench, &mut system, stop)?;
    let r = &output.results;
    let times = r.times();
    let c = |n: &str| column(r, &format!("plant.{n}"));
    let (w1, x, t1, shaft) = (
        c("actuationVelocity")?,
        c("loadOutputTorque")?,
        c("testOutputTorque")?,
        c("springTorque")?,
    );
    let clamp = MapClamp::of(bench);
    let last = times.last().copied().unwrap_or(0.0);
    let mut measured = Vec::new();
    for (&(w_cmd, torque), &(a, b)) in points.iter().zip(&windows) {
        if b > last + 1e-9 {
            break;
        }
        let rows: Vec<usize> = (0..times.len())
            .filter(|&i| times[i] > a + 1e-9 && times[i] <= b + 1e-9)
            .collect();
        let avg = |v: &[f64]| mean(&rows.iter().map(|&i| v[i]).collect::<Vec<_>>());
        let (w, load, test, sh) = (avg(&w1), avg(&x), avg(&t1), avg(&shaft));
        let loss = sh - test;
        let (p_test, p_shaft) = (test * w, sh * w);
        let efficiency = if w_cmd == 0.0 {
            f64::NAN
        } else if p_test > 0.0 && p_shaft > 0.0 {
            p_shaft / p_test
        } else if p_test < 0.0 && p_shaft < 0.0 {
            p_test / p_shaft
        } else {
            0.0
        };
        let (cx, cy) = clamp.apply(load, w);
        let s = surface.value(cx, cy);
        measured.push(MapPoint {
            speed_command: w_cmd.to_degrees(),
            torque_command: torque,
            speed: w,
            load_torque: load,
            test_torque: test,
            shaft_torque: sh,
            loss_torque: loss,
            efficiency,
            surface: s,
            relative_difference: if w_cmd == 0.0 {
                f64::NAN
            } else {
                (loss - s) / s.abs()
            },
        });
    }
    if measured.is_empty() {
        return Err(ExperimentError::Run(format!(
            "map: no point completed ({end})"
        )));
    }
    let written = write_map(bench, config, &measured, &skipped, budget, &end, r, out)?;
    Ok(MapResult {
        points: measured,
        skipped,
        end,
        written,
    })
}

/// The load driver's steady regenerated power at a map point.
struct RegenModel {
    resistance: f64,
    back_emf_per_ampere: f64,
    torque_per_ampere: f64,
}

impl RegenModel {
    fn of(bench: &Bench) -> Result<RegenModel, ExperimentError> {
        Ok(RegenModel {
            resistance: bench.real("loadMotorResistance")?,
            back_emf_per_ampere: bench.real("loadMotorBackEmfConstant")?
                * bench.real("reductionRatio")?,
            torque_per_ampere: bench.load_torque_per_ampere()?,
        })
    }

    /// `-(R2 i2 + Ke2 i_RED omega) i2` with `i2 = T / (i_RED Km2)`, at least 0 \[W\].
    fn power(&self, omega: f64, torque: f64) -> f64 {
        let current = torque / self.torque_per_ampere;
        (-(self.resistance * current + self.back_emf_per_ampere * omega) * current).max(0.0)
    }
}

/// The box the plant clamps the surface's arguments to (none on an FMU without it).
struct MapClamp {
    speed: Option<f64>,
    torque: Option<(f64, f64)>,
}

impl MapClamp {
    fn of(bench: &Bench) -> MapClamp {
        MapClamp {
            speed: bench.real("hdSurfaceMaxSpeed").ok(),
            torque: bench
                .real("hdSurfaceMinLoadTorque")
                .ok()
                .zip(bench.real("hdSurfaceMaxLoadTorque").ok()),
        }
    }

    fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        let y = self.speed.map_or(y, |m| y.clamp(-m, m));
        let x = self.torque.map_or(x, |(lo, hi)| x.clamp(lo, hi));
        (x, y)
    }
}

#[allow(clippy::too_many_arguments)]
fn write_map(
    bench: &Bench,
    config: &MapConfig,
    points: &[MapPoint],
    skipped: &[SkippedPoint],
    budget: f64,
    end: &RunEnd,
    run: &crate::Results,
    out: &Path,
) -> Result<Written, ExperimentError> {
    // The analysed table, sorted by speed; the figure draws the loss torque against speed, one
    // series per load torque (NaN where a series has no point), and the surface.
    let mut sorted = points.to_vec();
    sorted.sort_by(|a, b| a.speed.total_cmp(&b.speed));
    let mut names = vec![
        "speedCommand [deg/s]".to_string(),
        "torqueCommand [N m]".into(),
        "loadTorque [N m]".into(),
        "testTorque [N m]".into(),
        "shaftTorque [N m]".into(),
        "lossTorque [N m]".into(),
        "efficiency [-]".into(),
        "surface [N m]".into(),
        "relativeDifference [-]".into(),
    ];
    let fixed = names.len();
    for &tq in &config.torques {
        names.push(format!("loss at {tq} N m"));
        names.push(format!("surface at {tq} N m"));
    }
    let rows = sorted
        .iter()
        .map(|p| {
            let mut row = vec![
                p.speed_command,
                p.torque_command,
                p.load_torque,
                p.test_torque,
                p.shaft_torque,
                p.loss_torque,
                p.efficiency,
                p.surface,
                p.relative_difference,
            ];
            for &tq in &config.torques {
                let mine = p.torque_command == tq;
                row.push(if mine { p.loss_torque } else { f64::NAN });
                row.push(if mine { p.surface } else { f64::NAN });
            }
            (p.speed.to_degrees(), row)
        })
        .collect();
    let table = Table {
        x: "speed [deg/s]".into(),
        names: names.clone(),
        rows,
    };
    let series: Vec<&str> = names[fixed..].iter().map(String::as_str).collect();
    let compared: Vec<&MapPoint> = points
        .iter()
        .filter(|p| p.relative_difference.is_finite())
        .collect();
    let worst = compared
        .iter()
        .map(|p| p.relative_difference.abs())
        .fold(0.0, f64::max);
    let mut body = format!(
        "Steady-state map on `{}`: {} speeds (each both ways) x {} load torques, {} s settling + {} s averaging per point, velocity PI kp {} A/(rad/s), ki {} A/rad.\n\nLoss torque `tau_loss = springTorque - testOutputTorque` (the torque the drive applies to its output side, signed like the surface: negative for positive speed); efficiency forward `P_shaft/P_test`, back-driven `P_test/P_shaft`, 0 when both ends feed the drive. Compared with the loss surface at the measured load torque and speed (clamped to the plant's box): largest relative difference {} over {} points (zero speed not compared).\n\n",
        bench.path().display(),
        config.speeds.len(),
        config.torques.len(),
        config.settle,
        config.measure,
        config.gains.0,
        config.gains.1,
        num(100.0 * worst, 2) + " %",
        compared.len(),
    );
    if let RunEnd::Tripped { time, reason } = end {
        body.push_str(&format!(
            "**The run was ended at {time:.3} s: {reason}.** Only the points completed before are listed.\n\n"
        ));
    }
    if !skipped.is_empty() {
        body.push_str(&format!(
            "**{} points not run**: the load motor would brake them, its driver regenerating more than {} W ({} of `loadRegenPowerLimit` = {} W; predicted steady power `-(R2 i2 + Ke2 i_RED omega) i2`). Raise the limit (plant only: the armed hardware refuses more than 5 W) to map them.\n\n| speed [deg/s] | load torque [N m] | predicted regenerated power [W] |\n|---:|---:|---:|\n",
            skipped.len(),
            num(budget, 2),
            config.regen_fraction,
            num(bench.real("loadRegenPowerLimit")?, 2),
        ));
        for s in skipped {
            body.push_str(&format!(
                "| {} | {} | {} |\n",
                num(s.speed_command, 2),
                num(s.torque_command, 3),
                num(s.regenerated_power, 2)
            ));
        }
        body.push('\n');
    }
    body.push_str("| speed [deg/s] | load torque [N m] | test torque [N m] | shaft torque [N m] | loss torque [N m] | surface [N m] | difference [%] | efficiency |\n|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    for p in points {
        body.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} |\n",
            num(p.speed.to_degrees(), 2),
            num(p.load_torque, 3),
            num(p.test_torque, 3),
            num(p.shaft_torque, 3),
            num(p.loss_torque, 3),
            num(p.surface, 3),
            num(100.0 * p.relative_difference, 2),
            num(p.efficiency, 3),
        ));
    }
    write_outputs(
        bench,
        out,
        "map",
        "Steady-state map of the harmonic drive",
        run,
        &table,
        &series,
        &PlotLabels {
            x: "actuation-side speed [deg/s]".into(),
            y: "loss torque [N m]".into(),
            title: "Harmonic-drive loss torque: measured and loss surface".into(),
        },
        &body,
    )
}
