//! The actuator study: the same gait on DA, SEA and CSEA, run as SSP systems of the kneebench
//! FMUs, analysed per gait cycle as the bench study reports it.
//!
//! A [`Scenario`] is a list of components (an FMU file name and parameter values) and
//! connections; [`Scenario::to_ssd`] turns it into an SSP 1.0 system that this harness, fmpy
//! and other SSP tools can load, and [`write_ssp`] packs it with its FMUs. [`analyse`] takes
//! the results of a run and reports, per actuator: RMS and maximum tracking error, peak
//! torques, energy per cycle (mechanical, electrical, harmonic-drive loss, dE_k and dE_p), and
//! any interlock trip. [`markdown_table`] prints the comparison; [`plot_cycle`] draws one gait
//! cycle with percent of cycle on the x axis, as the study's figures do.
//!
//! # Controllers and gains ([`StudyGains::for_actuator`])
//!
//! Units: currents in A (both drivers in current mode), angles in rad, torques in N m at the
//! knee axis. `i_HD Km1` = 5.92 N m/A (test motor), `i_RED Km2` = 7.524 N m/A (load motor).
//!
//! **The budget.** Along the default gait (2.5 s, 60 deg, 9 N m) the knee torque reaches
//! -17.4 N m; the load side's own dynamics `I2 a + c2 w` add up to ~9 N m (a up to 13 rad/s^2).
//! Whoever supplies them decides two interlocks at once: if the shaft carries them (load motor
//! = bare ground reaction) the shaft torque peaks at 19.4 N m against the 20 N m test-motor
//! torque interlock; if the load motor supplies them (shaft = knee torque exactly), it has to
//! brake in swing and its driver absorbs up to 6.7 W electrical (the driver's `Ke2` = 0.145
//! V s/rad exceeds `Km2`) against the 5 W regen interlock. So perfect shaft-torque tracking of
//! the knee torque is not a feasible goal on this gait; the loops track a **planned shaft
//! torque** in between. Splitting the two terms separately widens the window: the shaft peak
//! sits where w ~ 0 and is set by the inertia share, the regen peak is in swing and falls when
//! the load motor also pushes a viscous term along the motion. Ideal-motion figures for
//! `(beta_w, beta_a)` = (4, 0.75): shaft 18.0 N m, regen 2.1 W, load-motor torque 17.0 N m.
//!
//! **Feed-forwards and setpoints.** Each loop takes the `GaitReference`'s analytic velocity,
//! acceleration (and, for the position loop, knee torque) references on its auxiliary inputs
//! and weights them into its reference and its feed-forward (`PidController`'s
//! `setpointWeight1..3` / `feedForwardWeight1..3`, `ImpedanceController`'s
//! `torqueFeedForwardWeight1..3`), so the SEA loop is four FMUs: gait, position, torque,
//! plant:
//!
//! * load loop (`torque`, all actuators): setpoint `tau_plan = tau_knee + (1 - beta_w) c2 w +
//!   (1 - beta_a) I2 a` on the transducer (shaft) torque, reverse acting, feed-forward current
//!   `(-tau_knee + beta_w c2 w + beta_a I2 a) / 7.524`, `(beta_w, beta_a)` = (4, 0.75);
//! * position loop (`position`, DA and SEA) on the actuation encoder: setpoint `theta_ref +
//!   tau_plan / k` (k = 340.54 N m/rad SEA, 1.3e4 DA): the actuation side leads the knee by the
//!   planned spring deflection, so the **knee** tracks; feed-forward current `(c1 w + I1 a +
//!   tau_plan) / 5.92` (c1 = 12, I1 = 0.825: 28 N m of the test motor's ~30 N m peak is the
//!   harmonic drive's viscous loss, which a feedback loop alone would chase with degrees of
//!   error). kp 1000 A/rad, ki 1000 A/(rad s), kd 15 A s/rad, Tf 2 ms, +-15 A: the feedback
//!   only has the 5 N m Coulomb friction and the model mismatch left (about 0.5 deg).
//! * torque loop gains: DA kp 0.2 A/(N m), ki 5 A/(N m s), kd 0.005 A s/(N m), Tf 2 ms; SEA the
//!   same with kd 0.01; +-6 A. The derivative (on the measured shaft torque) damps the SEA's
//!   spring mode (23.7 rad/s, damping ratio 0.035 on its own); the SEA trips with kd <= 0.003.
//!   The DA's stiff coupling (193 rad/s) leaves a window: kd 0.003 ... 0.008 runs, 0 and >= 0.01
//!   trip; 0.005 is its middle. Stronger integral action (ki 10, or ki 5 with smaller viscous
//!   shares) pulls the shaft torque onto the plan in swing and trips the regen or load-motor
//!   torque interlock.
//! * CSEA: the impedance controller (the bench's structure) with virtual stiffness 150 N m/rad,
//!   damping 8 N m s/rad on the knee (load) angle, torque feed-forward `tau_plan + c1 w + I1 a`
//!   (the knee-torque reference plus weighted velocity and acceleration), desired-torque limit
//!   60 N m, and its inner spring-torque PI at
//!   0: with the load loop also acting on the spring torque, two feedback loops on one quantity
//!   oscillated (every inner PI tried, 0.1 ... 2 A/(N m), tripped), so the impedance acts as a
//!   PD on the knee angle through the current feed-forward `tau_d / 5.92` and the load motor
//!   runs its feed-forward alone (torque loop gains 0: it applies the planned ground reaction;
//!   any torque feedback tripped the regen or load-torque interlock). Stiffer virtual springs
//!   (>= 250 N m/rad) go unstable through the series spring. The clutch scheduler runs in
//!   `LowSpeed` mode (engage below 0.1 rad/s for 20 ms, release above 0.2 rad/s): it locks
//!   the actuation side around the gait's turning points (about 17 % of the cycle). The
//!   published stance window (`GaitPhase` 0.10 ... 0.40) trips: during the fade-in the test
//!   motor is still held by its 5 N m friction when the clutch locks, the knee error builds up
//!   behind the lock, and on release the impedance output jumps (shaft-torque trip at 1.06 s);
//!   narrower windows trip too.
//!
//! **A harness/FMU interaction to know about.** Our Gauss-Seidel master reads a controller's
//! outputs after its `fmi2DoStep`, before its next inputs are set; the FMU then shows the next
//! sample computed from the inputs just used, whose measurement difference is zero: the D term
//! read is the filtered derivative decayed by `Tf / (Tf + Ts)` (2/3 with Tf = 2 ms), and with
//! Tf = 0 it is exactly 0. The gains above were tuned through this master, so they include that
//! factor (with another master the effective derivative is 1.5x stronger).
//!
//! # Measured tracking and margins
//!
//! Default gait, 4 cycles, the first not analysed (`kneebench study`; asserted with ~20 %
//! headroom in `tests/tests/study.rs`). Errors in deg, RMS / max:
//!
//! | | DA | SEA | CSEA |
//! |---|---|---|---|
//! | actuation side | 0.63 / 1.30 (bound 0.75 / 1.6) | 1.98 / 3.28 (2.4 / 4.0) | 2.51 / 4.09 (3.0 / 5.0) |
//! | knee (load side) | 0.60 / 1.25 (0.75 / 1.5) | 0.58 / 1.22 (0.7 / 1.5) | 1.46 / 2.94 (1.8 / 3.5) |
//!
//! The SEA's and CSEA's actuation-side error includes the planned spring deflection (up to
//! 3 deg), which is intended. Peaks over the whole run, start-up included, against the
//! interlocks: shaft torque 18.25 / 18.32 / 17.23 N m (limit 20; asserted < 18.8), load-motor
//! torque 18.03 / 17.74 / 16.24 N m (20; < 18.8), load-driver regen 2.30 / 2.05 / 3.58 W (5;
//! < 4.2), spring deflection 0.08 / 3.08 / 2.90 deg (5; < 4). Scaling the gait's amplitudes:
//! DA and SEA run at 1.05x and trip at 1.10x (DA load-motor torque at 2.82 s, SEA test-motor
//! (shaft) torque at 2.79 s), CSEA runs at 1.10x and trips at 1.15x (regen, 1.07 s).

use std::path::{Path, PathBuf};

use crate::master::Value;
use crate::results::Results;
use crate::ssp::{self, Ssd, SspComponent, SspConnection, SspExperiment, SspParameter, SspSystem};

/// Errors of the study.
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    /// A component's FMU could not be read.
    #[error("{path}: {message}")]
    Fmu {
        /// The FMU.
        path: PathBuf,
        /// Why.
        message: String,
    },
    /// Writing or reading an SSP failed.
    #[error(transparent)]
    Ssp(Box<ssp::SspError>),
    /// A column the analysis needs is missing from the results.
    #[error("the results lack column '{0}'")]
    MissingColumn(String),
    /// The run is shorter than one gait cycle.
    #[error("the run covers no complete gait cycle of {period} s (it ended at {end} s)")]
    NoCycle {
        /// The gait period.
        period: f64,
        /// The last recorded time.
        end: f64,
    },
    /// Plotting failed.
    #[error(transparent)]
    Results(#[from] crate::results::ResultsError),
}

impl From<ssp::SspError> for StudyError {
    fn from(e: ssp::SspError) -> Self {
        StudyError::Ssp(Box::new(e))
    }
}

/// One component of a scenario.
#[derive(Debug, Clone, PartialEq)]
pub struct ScenarioComponent {
    /// Component name (also the column prefix of its variables).
    pub name: String,
    /// The FMU's file name in the FMU directory, e.g. `BenchPlant.fmu`.
    pub fmu: String,
    /// Parameter values.
    pub parameters: Vec<(String, Value)>,
}

/// A closed-loop system: components and connections `("a.y", "b.u")`.
#[derive(Debug, Clone, PartialEq)]
pub struct Scenario {
    /// System name, e.g. `SEA`.
    pub name: String,
    /// Components.
    pub components: Vec<ScenarioComponent>,
    /// Connections from an output to an input, as `component.variable`.
    pub connections: Vec<(String, String)>,
    /// Stop time \[s\].
    pub stop_time: f64,
    /// Base step \[s\].
    pub step_size: f64,
}

fn split(reference: &str) -> (String, String) {
    match reference.split_once('.') {
        Some((c, v)) => (c.to_string(), v.to_string()),
        None => (String::new(), reference.to_string()),
    }
}

impl Scenario {
    /// The SSP 1.0 description of the scenario; component sources are `resources/<fmu>`.
    /// Connectors come from each FMU's model description (read from `fmu_dir`).
    pub fn to_ssd(&self, fmu_dir: &Path) -> Result<Ssd, StudyError> {
        let mut components = Vec::new();
        for c in &self.components {
            let path = fmu_dir.join(&c.fmu);
            let (_dir, md) =
                crate::load::extract_and_parse(&path, &crate::load::ArchiveLimits::default())
                    .map_err(|e| StudyError::Fmu {
                        path: path.clone(),
                        message: e.to_string(),
                    })?;
            let mut component =
                SspComponent::from_model_description(&c.name, &format!("resources/{}", c.fmu), &md);
            component.parameters = c
                .parameters
                .iter()
                .map(|(name, value)| SspParameter {
                    name: name.clone(),
                    value: value.clone(),
                })
                .collect();
            components.push(component);
        }
        let connections = self
            .connections
            .iter()
            .map(|(from, to)| {
                let (fe, fc) = split(from);
                let (te, tc) = split(to);
                SspConnection {
                    start_element: Some(fe),
                    start_connector: fc,
                    end_element: Some(te),
                    end_connector: tc,
                }
            })
            .collect();
        let mut system = SspSystem {
            name: self.name.clone(),
            components,
            connections,
        };
        // Unconnected inputs keep their start values; fmpy's SSP reader trips over them.
        system.drop_unconnected_inputs();
        Ok(Ssd {
            name: self.name.clone(),
            version: "1.0".into(),
            system,
            default_experiment: Some(SspExperiment {
                start_time: Some(0.0),
                stop_time: Some(self.stop_time),
                step_size: Some(self.step_size),
                algorithm: Some(crate::master::Algorithm::GaussSeidel),
            }),
        })
    }
}

/// Writes the scenario as an `.ssp` archive holding its FMUs.
pub fn write_ssp(scenario: &Scenario, fmu_dir: &Path, out: &Path) -> Result<(), StudyError> {
    let ssd = scenario.to_ssd(fmu_dir)?;
    let mut files: Vec<(String, PathBuf)> = scenario
        .components
        .iter()
        .map(|c| (format!("resources/{}", c.fmu), fmu_dir.join(&c.fmu)))
        .collect();
    files.sort();
    files.dedup();
    ssp::write_ssp(&ssd, &files, out)?;
    Ok(())
}

/// Which columns of the results the analysis reads (the defaults are the names of the kneebench
/// scenarios: components `gait` and `plant`).
#[derive(Debug, Clone, PartialEq)]
pub struct Columns {
    /// Knee-angle reference.
    pub reference: String,
    /// Actuation-side angle (what the test motor's encoder sees).
    pub actuation_angle: String,
    /// Load-side angle (the knee joint of the bench).
    pub load_angle: String,
    /// Test-motor torque at the output.
    pub test_torque: String,
    /// Load-motor torque at the output.
    pub load_torque: String,
    /// Integral of the test motor's mechanical power.
    pub test_mechanical_energy: String,
    /// Integral of its positive part.
    pub test_mechanical_energy_consumed: String,
    /// Integral of the total electrical power (both drivers, offset, clutch).
    pub electrical_energy: String,
    /// Integral of its positive part.
    pub electrical_energy_consumed: String,
    /// Integral of the mechanical losses (harmonic drive and friction), <= 0.
    pub loss_energy: String,
    /// E_k(t) - E_k(0).
    pub kinetic_energy_change: String,
    /// E_p(t) - E_p(0).
    pub potential_energy_change: String,
    /// The plant's trip code.
    pub trip_code: String,
}

impl Columns {
    /// Every column the analysis reads.
    pub fn names(&self) -> Vec<String> {
        [
            &self.reference,
            &self.actuation_angle,
            &self.load_angle,
            &self.test_torque,
            &self.load_torque,
            &self.test_mechanical_energy,
            &self.test_mechanical_energy_consumed,
            &self.electrical_energy,
            &self.electrical_energy_consumed,
            &self.loss_energy,
            &self.kinetic_energy_change,
            &self.potential_energy_change,
            &self.trip_code,
        ]
        .into_iter()
        .cloned()
        .collect()
    }
}

impl Default for Columns {
    fn default() -> Self {
        let p = |n: &str| format!("plant.{n}");
        Columns {
            reference: "gait.kneeAngleReference".into(),
            actuation_angle: p("actuationAngle"),
            load_angle: p("loadAngle"),
            test_torque: p("testOutputTorque"),
            load_torque: p("loadOutputTorque"),
            test_mechanical_energy: p("testMechanicalEnergy"),
            test_mechanical_energy_consumed: p("testMechanicalEnergyConsumed"),
            electrical_energy: p("totalElectricalEnergy"),
            electrical_energy_consumed: p("totalElectricalEnergyConsumed"),
            loss_energy: p("lossEnergy"),
            kinetic_energy_change: p("kineticEnergyChange"),
            potential_energy_change: p("potentialEnergyChange"),
            trip_code: p("tripCode"),
        }
    }
}

/// What one actuator's run gives, per gait cycle where it says so.
#[derive(Debug, Clone, PartialEq)]
pub struct ActuatorReport {
    /// Actuator name.
    pub name: String,
    /// Complete cycles analysed (the first cycle is the start-up and is skipped when there
    /// are more).
    pub cycles: usize,
    /// RMS error of the actuation-side angle against the reference \[rad\].
    pub rms_error_actuation: f64,
    /// Maximum error of the actuation-side angle \[rad\].
    pub max_error_actuation: f64,
    /// RMS error of the load-side (knee) angle \[rad\].
    pub rms_error_knee: f64,
    /// Maximum error of the load-side angle \[rad\].
    pub max_error_knee: f64,
    /// Peak |test-motor output torque| [N m].
    pub peak_test_torque: f64,
    /// Peak |load-motor output torque| [N m].
    pub peak_load_torque: f64,
    /// Test motor's mechanical energy per cycle, signed \[J\].
    pub test_mechanical: f64,
    /// Test motor's mechanical energy per cycle, positive part \[J\].
    pub test_mechanical_consumed: f64,
    /// Electrical energy per cycle incl. the 7 W offset and the clutch, signed \[J\].
    pub electrical: f64,
    /// Electrical energy per cycle, positive part \[J\].
    pub electrical_consumed: f64,
    /// Harmonic-drive and friction loss per cycle \[J\] (<= 0).
    pub loss: f64,
    /// Change of kinetic energy per cycle \[J\].
    pub kinetic: f64,
    /// Change of potential (spring) energy per cycle \[J\].
    pub potential: f64,
    /// The interlock that ended the run, if any, and when.
    pub trip: Option<(String, f64)>,
}

/// Interlock names by trip code (the plant's `tripCode` output).
pub fn interlock_name(code: i64) -> &'static str {
    match code {
        1 => "spring deflection",
        2 => "test motor torque",
        3 => "load motor torque",
        4 => "test motor current",
        5 => "load motor current",
        6 => "regenerated power",
        7 => "emergency stop",
        // The hardware FMU's own trips (BenchHardware's `tripCode`).
        8 => "link watchdog",
        9 => "pacing overrun",
        10 => "sensor out of range",
        11 => "bench stopped itself",
        12 => "transducer disagrees with the spring deflection",
        13 => "load cell disagrees with the test-motor current",
        _ => "unknown interlock",
    }
}

/// Analyses one run with gait period `period`.
pub fn analyse(
    name: &str,
    results: &Results,
    period: f64,
    columns: &Columns,
) -> Result<ActuatorReport, StudyError> {
    let col = |n: &str| {
        results
            .column(n)
            .ok_or_else(|| StudyError::MissingColumn(n.to_string()))
    };
    let times = results.times();
    let end = times.last().copied().unwrap_or(0.0);
    let complete = ((end + 1e-9) / period).floor() as usize;
    let trip = col(&columns.trip_code)?
        .iter()
        .zip(&times)
        .find(|(c, _)| **c != 0.0)
        .map(|(c, t)| (interlock_name(*c as i64).to_string(), *t));
    if complete == 0 {
        return Ok(ActuatorReport {
            name: name.to_string(),
            cycles: 0,
            rms_error_actuation: f64::NAN,
            max_error_actuation: f64::NAN,
            rms_error_knee: f64::NAN,
            max_error_knee: f64::NAN,
            peak_test_torque: f64::NAN,
            peak_load_torque: f64::NAN,
            test_mechanical: f64::NAN,
            test_mechanical_consumed: f64::NAN,
            electrical: f64::NAN,
            electrical_consumed: f64::NAN,
            loss: f64::NAN,
            kinetic: f64::NAN,
            potential: f64::NAN,
            trip: trip.or(Some(("ended before one cycle".into(), end))),
        });
    }
    let first = usize::from(complete > 1);
    let (t0, t1) = (first as f64 * period, complete as f64 * period);
    let tol = 1e-9 * t1.max(1.0);
    let rows: Vec<usize> = (0..times.len())
        .filter(|&i| times[i] >= t0 - tol && times[i] <= t1 + tol)
        .collect();
    let (i0, i1) = (rows[0], rows[rows.len() - 1]);
    let reference = col(&columns.reference)?;
    let errors = |angle: &[f64]| {
        let e: Vec<f64> = rows.iter().map(|&i| reference[i] - angle[i]).collect();
        let rms = (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt();
        (rms, e.iter().fold(0.0f64, |m, x| m.max(x.abs())))
    };
    let (rms_a, max_a) = errors(&col(&columns.actuation_angle)?);
    let (rms_k, max_k) = errors(&col(&columns.load_angle)?);
    let peak = |c: &[f64]| rows.iter().fold(0.0f64, |m, &i| m.max(c[i].abs()));
    let n = (complete - first) as f64;
    let per_cycle = |name: &str| -> Result<f64, StudyError> {
        let c = col(name)?;
        Ok((c[i1] - c[i0]) / n)
    };
    Ok(ActuatorReport {
        name: name.to_string(),
        cycles: complete - first,
        rms_error_actuation: rms_a,
        max_error_actuation: max_a,
        rms_error_knee: rms_k,
        max_error_knee: max_k,
        peak_test_torque: peak(&col(&columns.test_torque)?),
        peak_load_torque: peak(&col(&columns.load_torque)?),
        test_mechanical: per_cycle(&columns.test_mechanical_energy)?,
        test_mechanical_consumed: per_cycle(&columns.test_mechanical_energy_consumed)?,
        electrical: per_cycle(&columns.electrical_energy)?,
        electrical_consumed: per_cycle(&columns.electrical_energy_consumed)?,
        loss: per_cycle(&columns.loss_energy)?,
        kinetic: per_cycle(&columns.kinetic_energy_change)?,
        potential: per_cycle(&columns.potential_energy_change)?,
        trip,
    })
}

/// The comparison table in Markdown (also readable as plain text in a terminal).
pub fn markdown_table(reports: &[ActuatorReport]) -> String {
    let mut s = String::new();
    s.push_str("| | ");
    s.push_str(
        &reports
            .iter()
            .map(|r| r.name.clone())
            .collect::<Vec<_>>()
            .join(" | "),
    );
    s.push_str(" |\n|---|");
    s.push_str(&"---:|".repeat(reports.len()));
    s.push('\n');
    let deg = 180.0 / std::f64::consts::PI;
    let row = |s: &mut String, label: &str, f: &dyn Fn(&ActuatorReport) -> String| {
        s.push_str(&format!("| {label} |"));
        for r in reports {
            s.push_str(&format!(" {} |", f(r)));
        }
        s.push('\n');
    };
    row(&mut s, "cycles analysed", &|r| r.cycles.to_string());
    row(&mut s, "RMS tracking error, actuation side [deg]", &|r| {
        format!("{:.3}", r.rms_error_actuation * deg)
    });
    row(&mut s, "max tracking error, actuation side [deg]", &|r| {
        format!("{:.3}", r.max_error_actuation * deg)
    });
    row(&mut s, "RMS tracking error, knee (load side) [deg]", &|r| {
        format!("{:.3}", r.rms_error_knee * deg)
    });
    row(&mut s, "max tracking error, knee (load side) [deg]", &|r| {
        format!("{:.3}", r.max_error_knee * deg)
    });
    row(&mut s, "peak test-motor torque at the output [N m]", &|r| {
        format!("{:.2}", r.peak_test_torque)
    });
    row(&mut s, "peak load-motor torque at the output [N m]", &|r| {
        format!("{:.2}", r.peak_load_torque)
    });
    row(&mut s, "test-motor mechanical energy per cycle [J]", &|r| {
        format!("{:.3}", r.test_mechanical)
    });
    row(&mut s, "... consumed (positive part) [J]", &|r| {
        format!("{:.3}", r.test_mechanical_consumed)
    });
    row(
        &mut s,
        "electrical energy per cycle, incl. 7 W offset and clutch [J]",
        &|r| format!("{:.3}", r.electrical),
    );
    row(&mut s, "... consumed (positive part) [J]", &|r| {
        format!("{:.3}", r.electrical_consumed)
    });
    row(
        &mut s,
        "harmonic-drive and friction loss per cycle [J]",
        &|r| format!("{:.3}", r.loss),
    );
    row(&mut s, "dE_k per cycle [J]", &|r| {
        format!("{:.2e}", r.kinetic)
    });
    row(&mut s, "dE_p per cycle [J]", &|r| {
        format!("{:.2e}", r.potential)
    });
    row(&mut s, "interlock trip", &|r| match &r.trip {
        None => "none".into(),
        Some((name, t)) => format!("{name} at {t:.4} s"),
    });
    s
}

/// Plots `signals` (one per run: (legend, results, column)) over the last complete gait cycle
/// of each run, with percent of cycle on the x axis.
pub fn plot_cycle(
    signals: &[(&str, &Results, &str)],
    period: f64,
    out: &Path,
    labels: &crate::results::plot::PlotLabels,
) -> Result<(), StudyError> {
    let mut columns: Vec<(String, Vec<f64>)> = Vec::new();
    let mut percent: Vec<f64> = Vec::new();
    for (legend, results, column) in signals {
        let times = results.times();
        let end = times.last().copied().unwrap_or(0.0);
        let cycles = ((end + 1e-9) / period).floor();
        if cycles < 1.0 {
            continue;
        }
        let t0 = (cycles - 1.0) * period;
        let tol = 1e-9 * end.max(1.0);
        let rows: Vec<usize> = (0..times.len())
            .filter(|&i| times[i] >= t0 - tol && times[i] <= t0 + period + tol)
            .collect();
        let values = results
            .column(column)
            .ok_or_else(|| StudyError::MissingColumn(column.to_string()))?;
        if percent.is_empty() {
            percent = rows
                .iter()
                .map(|&i| 100.0 * (times[i] - t0) / period)
                .collect();
        }
        let n = percent.len().min(rows.len());
        columns.push((
            legend.to_string(),
            rows[..n].iter().map(|&i| values[i]).collect(),
        ));
    }
    let n = columns.iter().map(|(_, v)| v.len()).min().unwrap_or(0);
    let mut table = Results::with_capacity(
        columns.iter().map(|(l, _)| l.clone()).collect(),
        vec![crate::results::ColumnKind::Real; columns.len()],
        n,
    );
    for k in 0..n {
        let row: Vec<f64> = columns.iter().map(|(_, v)| v[k]).collect();
        table.push_row(percent[k], &row);
    }
    let names: Vec<&str> = columns.iter().map(|(l, _)| l.as_str()).collect();
    crate::results::plot::plot_signals_with(&table, &names, out, (1024, 560), labels)?;
    Ok(())
}

/// The actuator configurations of the bench.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Actuator {
    /// Direct actuation.
    Da,
    /// Series elastic actuation.
    Sea,
    /// Clutchable series elastic actuation.
    Csea,
}

impl Actuator {
    /// All three, in the study's order.
    pub const ALL: [Actuator; 3] = [Actuator::Da, Actuator::Sea, Actuator::Csea];

    /// Short name (`DA`, `SEA`, `CSEA`).
    pub fn name(self) -> &'static str {
        match self {
            Actuator::Da => "DA",
            Actuator::Sea => "SEA",
            Actuator::Csea => "CSEA",
        }
    }

    /// The plant's `configuration` value.
    pub fn configuration(self) -> i32 {
        match self {
            Actuator::Da => 0,
            Actuator::Sea => 1,
            Actuator::Csea => 2,
        }
    }
}

/// The gait of a study run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gait {
    /// Period \[s\].
    pub period: f64,
    /// Knee-angle amplitude \[rad\].
    pub angle_amplitude: f64,
    /// Knee-torque amplitude [N m].
    pub torque_amplitude: f64,
}

impl Gait {
    /// The bench's scaled gait: 2.5 s, 60 deg (50 deg for the clutch study), 9 N m.
    pub fn bench_default(actuator: Actuator) -> Gait {
        Gait {
            period: 2.5,
            angle_amplitude: if actuator == Actuator::Csea {
                50f64
            } else {
                60f64
            }
            .to_radians(),
            torque_amplitude: 9.0,
        }
    }
}

/// Output torque per ampere of the test motor, i_HD Km1 = 160 x 0.037 [N m/A].
pub const TEST_TORQUE_PER_AMPERE: f64 = 160.0 * 0.037;
/// Output torque per ampere of the load motor, i_RED Km2 = 66 x 0.114 [N m/A].
pub const LOAD_TORQUE_PER_AMPERE: f64 = 66.0 * 0.114;

/// Load-side inertia I2 at the knee axis [kg m^2] (the plant's default `load_inertia`).
pub const LOAD_INERTIA: f64 = 0.605;
/// Load-side viscous damping c2 [N m s/rad] (the plant's default `load_damping`).
pub const LOAD_DAMPING: f64 = 1.0;
/// Spring stiffness k of the SEA and CSEA [N m/rad] (the plant's default).
pub const SPRING_STIFFNESS: f64 = 340.54;
/// The DA's coupling stiffness (harmonic drive) [N m/rad] (the plant's default).
pub const DIRECT_COUPLING_STIFFNESS: f64 = 1.3e4;
/// Actuation-side inertia I1 at the knee axis [kg m^2] (the plant's default).
pub const ACTUATION_INERTIA: f64 = 0.825;
/// Actuation-side viscous damping c1 [N m s/rad] (the plant's default).
pub const ACTUATION_DAMPING: f64 = 12.0;

/// The clutch scheduler's mode and parameters (see `ClutchScheduler`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ClutchSchedule {
    /// Never engaged.
    Off,
    /// Engaged while the gait phase lies in `[start, end)`.
    GaitPhase {
        /// Window start (fraction of the cycle).
        start: f64,
        /// Window end.
        end: f64,
    },
    /// Engaged when |knee-velocity reference| stayed below `engage` [rad/s] for `delay` \[s\],
    /// released above `release` [rad/s].
    LowSpeed {
        /// Engage threshold [rad/s].
        engage: f64,
        /// Release threshold [rad/s].
        release: f64,
        /// Debounce \[s\].
        delay: f64,
    },
}

/// The CSEA's impedance controller and clutch scheduler settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CseaGains {
    /// Virtual stiffness k_d [N m/rad].
    pub stiffness: f64,
    /// Virtual damping d_d [N m s/rad].
    pub damping: f64,
    /// Inner spring-torque PI: kp [A/(N m)], ki [A/(N m s)].
    pub torque: (f64, f64),
    /// Limit of the desired torque tau_d [N m].
    pub desired_torque_limit: f64,
    /// When the clutch scheduler engages the clutch.
    pub clutch: ClutchSchedule,
    /// Test-side dynamics added to the impedance controller's torque feed-forward (velocity
    /// coefficient [N m s/rad], acceleration coefficient [kg m^2]; (c1, I1) for the model), on
    /// top of the planned shaft torque.
    pub feed_forward: (f64, f64),
    /// `holdAction` of the impedance controller while the clutch is engaged (1 hold last
    /// output, 2 zero output).
    pub hold_action: i32,
}

/// The controller gains of the study scenarios (documented with the scenarios).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StudyGains {
    /// Position loop (test motor): kp [A/rad], ki [A/(rad s)], kd [A s/rad].
    pub position: (f64, f64, f64),
    /// Derivative filter time constant of the position loop \[s\].
    pub position_derivative_filter: f64,
    /// Output limit of the position loop \[A\] (the test driver's 15 A).
    pub position_limit: f64,
    /// Test-side inverse-dynamics feed-forward of the position loop, \[A\] per unit of
    /// (knee velocity [rad/s], knee acceleration [rad/s^2], knee-torque reference [N m]):
    /// (c1, I1, 1) / (i_HD Km1) for the full model; all zero disables it.
    pub test_feed_forward: (f64, f64, f64),
    /// DA, SEA: the position loop's setpoint is the knee-angle reference plus the planned
    /// shaft torque over the coupling stiffness (the deflection the knee needs), so that the
    /// knee, not the actuation side, tracks the reference.
    pub deflection_compensation: bool,
    /// Load torque loop (on the shaft torque): kp [A/(N m)], ki [A/(N m s)], kd [A s/(N m)].
    pub torque: (f64, f64, f64),
    /// Derivative filter time constant of the torque loop \[s\].
    pub torque_derivative_filter: f64,
    /// Output limit of the torque loop \[A\] (the load driver's 6 A).
    pub torque_limit: f64,
    /// Shares `(beta_w, beta_a)` of the load side's own dynamics (`c2 w` and `I2 a` of the
    /// reference motion) that the load motor supplies. Its torque is planned as
    /// `-tau_knee + beta_w c2 w + beta_a I2 a` (the torque loop's feed-forward current) and the
    /// shaft torque the loop tracks as `tau_knee + (1 - beta_w) c2 w + (1 - beta_a) I2 a` (its
    /// setpoint). (0, 0) is the bare ground reaction (shaft torque up to 19.4 N m on the
    /// default gait); (1, 1) makes the shaft carry exactly the knee torque, and the load
    /// driver then has to absorb 6.7 W in swing (module docs).
    pub load_dynamics_share: (f64, f64),
    /// The CSEA's controllers.
    pub csea: CseaGains,
}

impl StudyGains {
    /// The tuned gains of the study for `actuator` (module docs, "Controllers and gains").
    pub fn for_actuator(actuator: Actuator) -> StudyGains {
        let mut gains = StudyGains {
            position: (1000.0, 1000.0, 15.0),
            position_derivative_filter: 0.002,
            position_limit: 15.0,
            test_feed_forward: (
                ACTUATION_DAMPING / TEST_TORQUE_PER_AMPERE,
                ACTUATION_INERTIA / TEST_TORQUE_PER_AMPERE,
                1.0 / TEST_TORQUE_PER_AMPERE,
            ),
            deflection_compensation: true,
            torque: (0.2, 5.0, 0.005),
            torque_derivative_filter: 0.002,
            torque_limit: 6.0,
            load_dynamics_share: (4.0, 0.75),
            csea: CseaGains {
                stiffness: 150.0,
                damping: 8.0,
                torque: (0.0, 0.0),
                desired_torque_limit: 60.0,
                feed_forward: (ACTUATION_DAMPING, ACTUATION_INERTIA),
                clutch: ClutchSchedule::LowSpeed {
                    engage: 0.1,
                    release: 0.2,
                    delay: 0.02,
                },
                hold_action: 1,
            },
        };
        match actuator {
            Actuator::Da => {}
            Actuator::Sea => gains.torque = (0.2, 5.0, 0.01),
            Actuator::Csea => gains.torque = (0.0, 0.0, 0.0),
        }
        gains
    }
}

const VELOCITY: &str = "gait.kneeVelocityReference";
const ACCELERATION: &str = "gait.kneeAccelerationReference";

fn real(name: &str, v: f64) -> (String, Value) {
    (name.to_string(), Value::Real(v))
}

fn integer(name: &str, v: i32) -> (String, Value) {
    (name.to_string(), Value::Integer(v))
}

fn boolean(name: &str, v: bool) -> (String, Value) {
    (name.to_string(), Value::Boolean(v))
}

fn connect(from: &str, to: &str) -> (String, String) {
    (from.to_string(), to.to_string())
}

/// The closed-loop gait scenario of one actuator: the gait reference feeds a position loop on
/// the test motor (DA, SEA: `PidController` on the actuation encoder with velocity
/// feed-forward; CSEA: `ImpedanceController` with the `ClutchScheduler` locking the actuation
/// side in stance) and a torque loop on the load motor (`PidController` on the torque
/// transducer, reverse acting, with the load-torque reference as feed-forward), both drivers
/// in current mode.
pub fn gait_scenario(actuator: Actuator, gait: Gait, gains: StudyGains, cycles: u32) -> Scenario {
    let (pk, pi, pd) = gains.position;
    let (tk, ti, td) = gains.torque;
    let mut components = vec![ScenarioComponent {
        name: "gait".into(),
        fmu: "GaitReference.fmu".into(),
        parameters: vec![
            real("gaitPeriod", gait.period),
            real("kneeAngleAmplitude", gait.angle_amplitude),
            real("kneeTorqueAmplitude", gait.torque_amplitude),
            // The bench starts at rest at 0 rad, the gait at ~7.5 deg: a soft start inside
            // the first (not analysed) cycle avoids a start-up step.
            real("fadeInTime", gait.period / 2.0),
        ],
    }];
    let mut connections = Vec::new();
    // The torque loop tracks the planned shaft torque
    // T = tau_knee + (1 - beta_w) c2 w + (1 - beta_a) I2 a (its reference: the knee-torque
    // reference plus the weighted velocity and acceleration references on its auxiliary
    // inputs), with the load motor's planned current as feed-forward:
    // (-tau_knee + beta_w c2 w + beta_a I2 a) / (i_RED Km2). See
    // `StudyGains::load_dynamics_share`.
    let (beta_w, beta_a) = gains.load_dynamics_share;
    let shaft_velocity_weight = (1.0 - beta_w) * LOAD_DAMPING;
    let shaft_acceleration_weight = (1.0 - beta_a) * LOAD_INERTIA;
    components.push(ScenarioComponent {
        name: "torque".into(),
        fmu: "PidController.fmu".into(),
        parameters: vec![
            real("kp", tk),
            real("ki", ti),
            real("kd", td),
            real("derivativeFilterTime", gains.torque_derivative_filter),
            real("outputMin", -gains.torque_limit),
            real("outputMax", gains.torque_limit),
            real("feedForwardGain", 1.0 / LOAD_TORQUE_PER_AMPERE),
            real("setpointWeight1", shaft_velocity_weight),
            real("setpointWeight2", shaft_acceleration_weight),
            real(
                "feedForwardWeight1",
                beta_w * LOAD_DAMPING / LOAD_TORQUE_PER_AMPERE,
            ),
            real(
                "feedForwardWeight2",
                beta_a * LOAD_INERTIA / LOAD_TORQUE_PER_AMPERE,
            ),
            boolean("reverseActing", true),
        ],
    });
    connections.extend([
        connect("gait.kneeTorqueReference", "torque.setpoint"),
        connect(VELOCITY, "torque.auxiliary1"),
        connect(ACCELERATION, "torque.auxiliary2"),
        connect("plant.transducerTorque", "torque.measurement"),
        connect("gait.loadTorqueReference", "torque.feedForward"),
        connect("torque.u", "plant.loadCurrentCommand"),
    ]);
    match actuator {
        Actuator::Da | Actuator::Sea => {
            let (fv, fa, ft) = gains.test_feed_forward;
            // The actuation side leads the knee by the planned spring deflection T / k; the
            // test motor's feed-forward is ft T + fv w + fa a. Both are weights of the
            // auxiliaries (velocity, acceleration, knee torque) of the position loop.
            let stiffness = if actuator == Actuator::Da {
                DIRECT_COUPLING_STIFFNESS
            } else {
                SPRING_STIFFNESS
            };
            let lead = if gains.deflection_compensation {
                1.0 / stiffness
            } else {
                0.0
            };
            components.push(ScenarioComponent {
                name: "position".into(),
                fmu: "PidController.fmu".into(),
                parameters: vec![
                    real("kp", pk),
                    real("ki", pi),
                    real("kd", pd),
                    real("derivativeFilterTime", gains.position_derivative_filter),
                    real("outputMin", -gains.position_limit),
                    real("outputMax", gains.position_limit),
                    real("feedForwardGain", 0.0),
                    real("setpointWeight1", lead * shaft_velocity_weight),
                    real("setpointWeight2", lead * shaft_acceleration_weight),
                    real("setpointWeight3", lead),
                    real("feedForwardWeight1", ft * shaft_velocity_weight + fv),
                    real("feedForwardWeight2", ft * shaft_acceleration_weight + fa),
                    real("feedForwardWeight3", ft),
                ],
            });
            connections.extend([
                connect("gait.kneeAngleReference", "position.setpoint"),
                connect(VELOCITY, "position.auxiliary1"),
                connect(ACCELERATION, "position.auxiliary2"),
                connect("gait.kneeTorqueReference", "position.auxiliary3"),
                connect("plant.actuationEncoderAngle", "position.measurement"),
                connect("position.u", "plant.testCurrentCommand"),
            ]);
        }
        Actuator::Csea => {
            let c = gains.csea;
            // The spring carries the planned shaft torque plus the actuation side's own
            // dynamics share: tau_ff = T + ff_w w + ff_a a.
            components.push(ScenarioComponent {
                name: "impedance".into(),
                fmu: "ImpedanceController.fmu".into(),
                parameters: vec![
                    real("virtualStiffness", c.stiffness),
                    real("virtualDamping", c.damping),
                    real("torqueKp", c.torque.0),
                    real("torqueKi", c.torque.1),
                    real("desiredTorqueLimit", c.desired_torque_limit),
                    real("outputMin", -gains.position_limit),
                    real("outputMax", gains.position_limit),
                    real(
                        "torqueFeedForwardWeight1",
                        shaft_velocity_weight + c.feed_forward.0,
                    ),
                    real(
                        "torqueFeedForwardWeight2",
                        shaft_acceleration_weight + c.feed_forward.1,
                    ),
                    integer("holdAction", c.hold_action),
                ],
            });
            let clutch = match c.clutch {
                ClutchSchedule::Off => vec![integer("mode", 0)],
                ClutchSchedule::GaitPhase { start, end } => vec![
                    integer("mode", 1),
                    real("engageStart", start),
                    real("engageEnd", end),
                ],
                ClutchSchedule::LowSpeed {
                    engage,
                    release,
                    delay,
                } => vec![
                    integer("mode", 2),
                    real("engageSpeed", engage),
                    real("releaseSpeed", release),
                    real("engageDelay", delay),
                ],
            };
            components.push(ScenarioComponent {
                name: "clutch".into(),
                fmu: "ClutchScheduler.fmu".into(),
                parameters: clutch,
            });
            connections.extend([
                connect("gait.kneeAngleReference", "impedance.angleReference"),
                connect("gait.kneeVelocityReference", "impedance.velocityReference"),
                connect("gait.kneeTorqueReference", "impedance.torqueFeedForward"),
                connect(VELOCITY, "impedance.auxiliary1"),
                connect(ACCELERATION, "impedance.auxiliary2"),
                connect("plant.actuationEncoderAngle", "impedance.actuationAngle"),
                connect("plant.loadEncoderAngle", "impedance.loadAngle"),
                connect("plant.loadVelocity", "impedance.loadVelocity"),
                connect("clutch.holdPosition", "impedance.hold"),
                connect("impedance.currentCommand", "plant.testCurrentCommand"),
                connect("gait.gaitPhase", "clutch.gaitPhase"),
                connect("gait.kneeVelocityReference", "clutch.velocityReference"),
                connect("clutch.clutchEngage", "plant.clutchEngage"),
            ]);
        }
    }
    components.push(ScenarioComponent {
        name: "plant".into(),
        fmu: "BenchPlant.fmu".into(),
        parameters: vec![integer("configuration", actuator.configuration())],
    });
    Scenario {
        name: actuator.name().into(),
        components,
        connections,
        stop_time: gait.period * f64::from(cycles),
        step_size: 1e-3,
    }
}

/// One actuator's run in a study.
#[derive(Debug)]
pub struct StudyRun {
    /// The analysis.
    pub report: ActuatorReport,
    /// Every recorded signal.
    pub results: Results,
    /// How the run ended.
    pub outcome: crate::master::Outcome,
    /// The scenario file written for it.
    pub scenario: PathBuf,
}

/// Settings of a study.
#[derive(Debug, Clone, PartialEq)]
pub struct StudyConfig {
    /// Directory holding the exported FMUs.
    pub fmu_dir: PathBuf,
    /// Output directory (scenarios, results, plots, report).
    pub out_dir: PathBuf,
    /// Gait cycles per run.
    pub cycles: u32,
    /// Multiplies the bench gait's angle and torque amplitudes (1 = the bench's gait).
    pub scale: f64,
    /// Controller gains for every actuator; `None`: each actuator's
    /// [`StudyGains::for_actuator`].
    pub gains: Option<StudyGains>,
    /// Actuators to run.
    pub actuators: Vec<Actuator>,
}

/// Runs the study: writes `scenarios/<A>.ssp`, runs each with this harness's master, writes
/// `<A>.csv`, and returns the runs. A run ended by an interlock keeps its rows and names the
/// interlock in its report.
pub fn run_study(config: &StudyConfig) -> Result<Vec<StudyRun>, StudyError> {
    let scenarios = config.out_dir.join("scenarios");
    std::fs::create_dir_all(&scenarios).map_err(|e| StudyError::Fmu {
        path: scenarios.clone(),
        message: e.to_string(),
    })?;
    let mut runs = Vec::new();
    for &actuator in &config.actuators {
        let mut gait = Gait::bench_default(actuator);
        gait.angle_amplitude *= config.scale;
        gait.torque_amplitude *= config.scale;
        let gains = config
            .gains
            .unwrap_or_else(|| StudyGains::for_actuator(actuator));
        let scenario = gait_scenario(actuator, gait, gains, config.cycles);
        let path = scenarios.join(format!("{}.ssp", actuator.name()));
        write_ssp(&scenario, &config.fmu_dir, &path)?;
        let loaded = ssp::load_system(&path, &crate::load::LoadOptions::default())?;
        let output = loaded
            .system
            .run(&loaded.config)
            .map_err(|e| StudyError::Fmu {
                path: path.clone(),
                message: e.to_string(),
            })?;
        let mut report = analyse(
            actuator.name(),
            &output.results,
            gait.period,
            &Columns::default(),
        )?;
        match &output.outcome {
            crate::master::Outcome::Terminated {
                component,
                last_successful_time,
                messages,
                ..
            } => {
                // The plant names the interlock in its log; the row at the trip is not on the
                // grid, so the trip code may not be in the results.
                let reason = messages
                    .last()
                    .and_then(|m| m.rsplit(": ").next())
                    .unwrap_or("terminated");
                report.trip = Some((format!("{component}: {reason}"), *last_successful_time));
            }
            crate::master::Outcome::Failed(e) => {
                let at = output.results.last_time().unwrap_or(0.0);
                report.trip = Some((format!("run failed: {e}"), at));
            }
            crate::master::Outcome::Completed { .. } => {}
        }
        let csv = config.out_dir.join(format!("{}.csv", actuator.name()));
        output.results.write_csv_file(&csv)?;
        runs.push(StudyRun {
            report,
            results: output.results,
            outcome: output.outcome,
            scenario: path,
        });
    }
    Ok(runs)
}

/// Draws the study's figures over the last gait cycle of each run: knee-angle tracking,
/// motor torques and powers. Returns the files written.
pub fn plot_study(
    runs: &[StudyRun],
    period: f64,
    out_dir: &Path,
) -> Result<Vec<PathBuf>, StudyError> {
    use crate::results::plot::PlotLabels;
    let mut written = Vec::new();
    let figure = |file: &str,
                  title: &str,
                  y: &str,
                  series: Vec<(String, &Results, String)>|
     -> Result<PathBuf, StudyError> {
        let path = out_dir.join(file);
        let refs: Vec<(&str, &Results, &str)> = series
            .iter()
            .map(|(l, r, c)| (l.as_str(), *r, c.as_str()))
            .collect();
        plot_cycle(
            &refs,
            period,
            &path,
            &PlotLabels {
                x: "gait cycle [%]".into(),
                y: y.into(),
                title: title.into(),
            },
        )?;
        Ok(path)
    };
    let complete: Vec<&StudyRun> = runs.iter().filter(|r| r.report.cycles > 0).collect();
    if complete.is_empty() {
        return Ok(written);
    }
    let mut tracking = vec![(
        "reference".to_string(),
        &complete[0].results,
        "gait.kneeAngleReference".to_string(),
    )];
    for r in &complete {
        tracking.push((
            format!("{} knee (load side)", r.report.name),
            &r.results,
            "plant.loadAngle".into(),
        ));
    }
    written.push(figure(
        "tracking.svg",
        "Knee angle over one gait cycle",
        "angle [rad]",
        tracking,
    )?);
    let mut torques = Vec::new();
    for r in &complete {
        torques.push((
            format!("{} test motor", r.report.name),
            &r.results,
            "plant.testOutputTorque".into(),
        ));
        torques.push((
            format!("{} load motor", r.report.name),
            &r.results,
            "plant.loadOutputTorque".into(),
        ));
    }
    written.push(figure(
        "torques.svg",
        "Motor torques at the output over one gait cycle",
        "torque [N m]",
        torques,
    )?);
    let mut powers = Vec::new();
    for r in &complete {
        powers.push((
            format!("{} test mechanical", r.report.name),
            &r.results,
            "plant.testMechanicalPower".into(),
        ));
        powers.push((
            format!("{} electrical total", r.report.name),
            &r.results,
            "plant.totalElectricalPower".into(),
        ));
    }
    written.push(figure(
        "powers.svg",
        "Powers over one gait cycle",
        "power [W]",
        powers,
    )?);
    Ok(written)
}
