//! The study's closed-loop scenarios: components, connections and gains, written as SSP 1.0.

use std::path::{Path, PathBuf};

use super::StudyError;
use crate::master::Value;
use crate::ssp::{self, Ssd, SspComponent, SspConnection, SspExperiment, SspParameter, SspSystem};

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
            let md =
                crate::load::read_model_description(&path, &crate::load::ArchiveLimits::default())
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

/// Writes the scenario as an `.ssp` archive holding its FMUs and `set` as
/// `resources/<component>.ssv`, bound to `component` before its inline values (SSP 1.0
/// `ParameterBinding source=".."`).
pub fn write_ssp_with_set(
    scenario: &Scenario,
    fmu_dir: &Path,
    out: &Path,
    component: &str,
    set: &crate::params::ParameterSet,
) -> Result<(), StudyError> {
    let mut ssd = scenario.to_ssd(fmu_dir)?;
    let resource = format!("resources/{component}.ssv");
    let c = ssd
        .system
        .components
        .iter_mut()
        .find(|c| c.name == component)
        .ok_or_else(|| {
            StudyError::Parameter(format!(
                "the parameter set is for component '{component}', which the scenario lacks"
            ))
        })?;
    c.parameter_sources.push(resource.clone());
    let dir = tempfile::tempdir().map_err(|e| StudyError::Fmu {
        path: out.to_path_buf(),
        message: e.to_string(),
    })?;
    let ssv = dir.path().join(format!("{component}.ssv"));
    set.write_file(&ssv)
        .map_err(|e| StudyError::Parameter(e.to_string()))?;
    let mut files: Vec<(String, PathBuf)> = scenario
        .components
        .iter()
        .map(|c| (format!("resources/{}", c.fmu), fmu_dir.join(&c.fmu)))
        .collect();
    files.sort();
    files.dedup();
    files.push((resource, ssv));
    ssp::write_ssp(&ssd, &files, out)?;
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
    /// The bench's full gait (Tables 13 and 14): 2.5 s, 60 deg, 9 N m peak external torque.
    pub fn bench_full() -> Gait {
        Gait {
            period: 2.5,
            angle_amplitude: 60f64.to_radians(),
            torque_amplitude: 9.0,
        }
    }

    /// The bench's clutch comparison (Table 15): the same gait at 50 deg, the load still 9 N m.
    pub fn bench_clutch() -> Gait {
        Gait {
            angle_amplitude: 50f64.to_radians(),
            ..Gait::bench_full()
        }
    }
}

/// The study's scenarios, each run as on the bench for one of its published tables.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StudyScenario {
    /// Tables 13 and 14: DA, SEA (and CSEA, like for like) on the 60 deg gait, the test motor
    /// under position control.
    BenchFull,
    /// Table 15: SEA and CSEA on the 50 deg gait, both under impedance control, the CSEA's
    /// clutch locking the actuation side in stance.
    BenchClutch,
}

impl StudyScenario {
    /// Both, in the report's order.
    pub const ALL: [StudyScenario; 2] = [StudyScenario::BenchFull, StudyScenario::BenchClutch];

    /// The name on the command line and in the report (`bench-full`, `bench-clutch`).
    pub fn name(self) -> &'static str {
        match self {
            StudyScenario::BenchFull => "bench-full",
            StudyScenario::BenchClutch => "bench-clutch",
        }
    }

    /// By [`Self::name`].
    pub fn from_name(name: &str) -> Option<StudyScenario> {
        Self::ALL.into_iter().find(|s| s.name() == name)
    }

    /// The actuators it compares.
    pub fn actuators(self) -> &'static [Actuator] {
        match self {
            StudyScenario::BenchFull => &Actuator::ALL,
            StudyScenario::BenchClutch => &[Actuator::Sea, Actuator::Csea],
        }
    }

    /// The gait it runs.
    pub fn gait(self) -> Gait {
        match self {
            StudyScenario::BenchFull => Gait::bench_full(),
            StudyScenario::BenchClutch => Gait::bench_clutch(),
        }
    }

    /// The file stem of one actuator's scenario and results (`SEA`, `clutch-SEA`).
    pub fn file_stem(self, actuator: Actuator) -> String {
        match self {
            StudyScenario::BenchFull => actuator.name().to_string(),
            StudyScenario::BenchClutch => format!("clutch-{}", actuator.name()),
        }
    }

    /// The controllers of `actuator` in this scenario.
    pub fn gains(self, actuator: Actuator) -> StudyGains {
        match self {
            StudyScenario::BenchFull => StudyGains::for_actuator(actuator),
            StudyScenario::BenchClutch => {
                // Both under the impedance controller, as on the bench; the SEA without the
                // clutch, the CSEA with the stance-phase clutch.
                let mut gains = StudyGains::for_actuator(Actuator::Csea);
                gains.csea.damping = CLUTCH_STUDY_VIRTUAL_DAMPING;
                gains.csea.clutch = if actuator == Actuator::Csea {
                    CLUTCH_STUDY_SCHEDULE
                } else {
                    ClutchSchedule::Off
                };
                gains
            }
        }
    }
}

/// The harmonic drive's ratio i_HD (the plant's default `harmonicDriveRatio`).
pub const HARMONIC_DRIVE_RATIO: f64 = 160.0;
/// The test motor's torque constant Km1 [N m/A] (the plant's default).
pub const TEST_MOTOR_TORQUE_CONSTANT: f64 = 0.037;
/// The planetary gearbox's ratio i_RED (the plant's default `reductionRatio`).
pub const REDUCTION_RATIO: f64 = 66.0;
/// The load motor's torque constant Km2 [N m/A] (the plant's default).
pub const LOAD_MOTOR_TORQUE_CONSTANT: f64 = 0.114;
/// The test driver's current limit \[A\] (the plant's default): the test-side controllers'
/// output limit.
pub const TEST_CURRENT_LIMIT: f64 = 15.0;
/// The load driver's current limit \[A\] (the plant's default): the torque loop's output limit.
pub const LOAD_CURRENT_LIMIT: f64 = 6.0;
/// Output torque per ampere of the test motor, i_HD Km1 = 160 x 0.037 [N m/A].
pub const TEST_TORQUE_PER_AMPERE: f64 = HARMONIC_DRIVE_RATIO * TEST_MOTOR_TORQUE_CONSTANT;
/// Output torque per ampere of the load motor, i_RED Km2 = 66 x 0.114 [N m/A].
pub const LOAD_TORQUE_PER_AMPERE: f64 = REDUCTION_RATIO * LOAD_MOTOR_TORQUE_CONSTANT;

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

/// The plant's parameters whose values the study's controllers are built on in a run whose
/// scenario parameters are `parameters` (its `component.name = value` lines, as
/// [`super::parameter_set`] writes them), with the value each assumes: the plant's defaults.
/// Every run's feed-forwards and load-loop scaling use the inertias, dampings, gear ratios and
/// torque constants, and its controllers' output limits the current limits; the coupling
/// stiffness (the DA's harmonic drive, the SEA's and CSEA's spring) only where a position loop
/// leads the knee by the planned deflection (a non-zero `position.setpointWeight3`, 1/k: the
/// impedance controller's law is in its own terms). The PID gains were tuned on that plant too.
/// A run whose plant differs in one of these runs weights derived for another plant
/// ([`tuning_differences`]).
pub fn tuned_for(actuator: Actuator, parameters: &[String]) -> Vec<(&'static str, f64)> {
    let mut assumed = vec![
        ("actuationInertia", ACTUATION_INERTIA),
        ("loadInertia", LOAD_INERTIA),
        ("actuationDamping", ACTUATION_DAMPING),
        ("loadDamping", LOAD_DAMPING),
        ("harmonicDriveRatio", HARMONIC_DRIVE_RATIO),
        ("testMotorTorqueConstant", TEST_MOTOR_TORQUE_CONSTANT),
        ("reductionRatio", REDUCTION_RATIO),
        ("loadMotorTorqueConstant", LOAD_MOTOR_TORQUE_CONSTANT),
        ("testCurrentLimit", TEST_CURRENT_LIMIT),
        ("loadCurrentLimit", LOAD_CURRENT_LIMIT),
    ];
    let leads = parameter_value(parameters, "position.setpointWeight3").is_some_and(|w| w != 0.0);
    if leads {
        assumed.push(match actuator {
            Actuator::Da => ("directCouplingStiffness", DIRECT_COUPLING_STIFFNESS),
            Actuator::Sea | Actuator::Csea => ("springStiffness", SPRING_STIFFNESS),
        });
    }
    assumed
}

/// The value of `reference` (`component.name`) among `component.name = value` lines.
fn parameter_value(parameters: &[String], reference: &str) -> Option<f64> {
    let prefix = format!("{reference} = ");
    parameters
        .iter()
        .find_map(|l| l.strip_prefix(&prefix))?
        .trim()
        .parse()
        .ok()
}

/// The plant parameters among a run's `component.name = value` lines that differ from what
/// its controllers' weights were derived for ([`tuned_for`]): `(name, assumed, this run's)`.
/// Empty for the study's own plant.
pub fn tuning_differences(actuator: Actuator, parameters: &[String]) -> Vec<(String, f64, f64)> {
    tuned_for(actuator, parameters)
        .into_iter()
        .filter_map(|(name, assumed)| {
            let value = parameter_value(parameters, &format!("plant.{name}"))?;
            ((value - assumed).abs() > 1e-9 * assumed.abs())
                .then(|| (name.to_string(), assumed, value))
        })
        .collect()
}

/// The CSEA's clutch in the clutch comparison (Table 15): locked by gait phase from heel strike
/// (0) to 0.45, the low-motion part of stance: there the normalised knee angle moves by less
/// than 0.4 per cycle, and from 0.45 on it flexes fast (1.2 per cycle at 0.45, 2.0 at 0.5,
/// 5.1 at 0.6). The bench "locked about half the cycle, a bit more than stance". A window
/// reaching into the fast flexion (ending at 0.5 or later) locks the actuation side against
/// it and trips the shaft-torque interlock on release.
pub const CLUTCH_STUDY_SCHEDULE: ClutchSchedule = ClutchSchedule::GaitPhase {
    start: 0.0,
    end: 0.45,
};

/// The impedance controller's virtual damping in the clutch comparison [N m s/rad] (8 in
/// `bench-full`). The damping acts on the knee (load) velocity, on the far side of the series
/// spring from the test motor: non-collocated feedback, which takes damping from the spring
/// mode rather than adding it. With 8, the ringing after the clutch's first release brought the
/// shaft torque to 19.6 N m of the 20 N m interlock under Gauss-Seidel, and the one step more of
/// delay under Jacobi tripped it (2.29 s); 6 gives 17.3 N m under both, 4 and 2 about 17.1,
/// while 12 and 16 trip under both (module docs, "Measured tracking and margins").
pub const CLUTCH_STUDY_VIRTUAL_DAMPING: f64 = 6.0;

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
    /// setpoint). (0, 0) is the bare ground reaction (the shaft carries the load side's
    /// dynamics too: 11.1-12.1 N m peak over the analysed cycles of the bench-full gait,
    /// `kneebench study --scenario bench-full`, row "peak shaft (transducer) torque, analysed
    /// cycles"; up to 16.3 N m in the CSEA's start-up); (1, 1) makes the shaft carry exactly the knee
    /// torque, and the load driver then has to brake the load side's dynamics in swing, above
    /// its 5 W (module docs, "The budget").
    pub load_dynamics_share: (f64, f64),
    /// Which controller drives the test motor.
    pub test_controller: TestController,
    /// The impedance controller's and the clutch scheduler's settings (used with
    /// [`TestController::Impedance`]).
    pub csea: CseaGains,
}

/// The test motor's controller in a scenario.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TestController {
    /// Position PID on the actuation encoder with inverse-dynamics feed-forward.
    Position,
    /// The impedance controller (virtual spring and damper through the series spring) with the
    /// clutch scheduler.
    Impedance,
}

impl StudyGains {
    /// The tuned gains of the study for `actuator` (module docs, "Controllers and gains").
    pub fn for_actuator(actuator: Actuator) -> StudyGains {
        let mut gains = StudyGains {
            position: (1000.0, 1000.0, 15.0),
            position_derivative_filter: 0.002,
            position_limit: TEST_CURRENT_LIMIT,
            test_feed_forward: (
                ACTUATION_DAMPING / TEST_TORQUE_PER_AMPERE,
                ACTUATION_INERTIA / TEST_TORQUE_PER_AMPERE,
                1.0 / TEST_TORQUE_PER_AMPERE,
            ),
            deflection_compensation: true,
            torque: (0.2, 5.0, 0.005),
            torque_derivative_filter: 0.002,
            torque_limit: LOAD_CURRENT_LIMIT,
            load_dynamics_share: (0.0, 0.0),
            test_controller: TestController::Position,
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
            Actuator::Da => gains.torque = (0.075, 5.0, 0.0015),
            Actuator::Sea => gains.torque = (0.2, 5.0, 0.01),
            Actuator::Csea => {
                gains.torque = (0.0, 0.0, 0.0);
                gains.test_controller = TestController::Impedance;
            }
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

/// The gait scenario's fade-in \[s\] for the gait period `period`: half of it, so that the
/// soft start lies inside the first cycle, the start-up, which the analysis skips.
pub fn gait_fade_in(period: f64) -> f64 {
    period / 2.0
}

/// The stop time \[s\] of a gait run of `cycles` periods `period` on base step `step`:
/// `cycles x period`, rounded up to the next step when it falls between steps (a gait period
/// that is no multiple of the step; the master refuses a stop time off its step grid).
pub fn gait_stop_time(period: f64, cycles: u32, step: f64) -> f64 {
    let stop = period * f64::from(cycles);
    let steps = stop / step;
    if (steps - steps.round()).abs() <= 1e-9 * steps.max(1.0) {
        stop
    } else {
        steps.ceil() * step
    }
}

/// The gait component's fade-in in the scenarios, `component.name` ([`gait_fade_in`]).
pub const GAIT_FADE_IN: &str = "gait.fadeInTime";

/// The base step \[s\] of every [`gait_scenario`] (the sweep spec's bound on a run's recorded
/// values assumes it when the spec gives no `step`).
pub const GAIT_SCENARIO_STEP: f64 = 1e-3;

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
            real("fadeInTime", gait_fade_in(gait.period)),
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
    match gains.test_controller {
        TestController::Position => {
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
        TestController::Impedance => {
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
        stop_time: gait_stop_time(gait.period, cycles, GAIT_SCENARIO_STEP),
        step_size: GAIT_SCENARIO_STEP,
    }
}
