//! Identification: fit the twin's parameters to a bench's own experiment logs
//! (`kneebench identify`).
//!
//! **Input.** The CSV or Parquet logs `kneebench experiment` writes (on `BenchHardware`, or on
//! `BenchPlant` for testing; Parquet by the `.parquet` extension, from any tool): encoder angles, motor currents, transducer torque, and when
//! logged the drivers' voltages ([`log::REQUIRED`], [`log::OPTIONAL`]). Each log is checked
//! ([`log::read`]): missing channels, non-monotonic or non-uniform time, NaN and too-short logs
//! are refused with the file and line (row in Parquet); rows with a saturated driver or a tripped interlock are
//! excluded with a note in the report. A log that carries the bench's clock at each sample
//! (`benchSampleTime`, which `BenchHardware` records) is resampled onto it ([`resample`]): a
//! master that ran late logged its rows at the schedule's times, not at the readings' times.
//!
//! **Stage 1, linear least squares** (the bench's own method: inverse dynamics on smoothed
//! encoder signals, [`smooth`]). With `tau` the transducer's shaft torque, `w`, `a` the
//! smoothed velocity and acceleration, `i` the smoothed currents (signs of the plant's
//! equations, positive = extension):
//!
//! ```text
//! spring:     tau = k (theta1 - theta2) + tau0                                  (k, tau0)
//! actuation:  tau - tau0 = Km1 (i_HD i1) - I1 a1 - c1 w1 - Tfr1 sign(w1)          (Km1, I1, c1, Tfr1)
//! load:       tau - tau0 = -Km2 (i_RED i2) + I2 a2 + c2 w2 + Tfr2 sign(w2)        (Km2, I2, c2, Tfr2)
//! test motor: V1 = R1 i1 + Ke1 (i_HD w1)                                        (R1, Ke1)
//! load motor: V2 = R2 i2 + Ke2 (i_RED w2)                                        (R2, Ke2)
//! ```
//!
//! The inductances are reported as not identifiable: the armature time constant L/R (about
//! 0.8 ms) is shorter than the 1 ms logs resolve, and in the plant's current mode the L di/dt
//! term is the current loop's, not a free one.
//!
//! The friction rows use only samples moving faster than [`IdentifyConfig::min_speed`] (a
//! stuck body's friction is a reaction, not the law); the electrical rows need the voltage
//! logged. `tau0` is the transducer's torque offset (a sensor offset, reported, not a plant
//! parameter). The gear ratios are not identified (they are the bench's construction) and
//! are read from the FMU's parameters.
//!
//! **Sensor offsets** (`offsets`): besides `tau0`, the load cell's torque offset and the
//! current sensors' offset and sensitivity (against the drivers' current readings) when those
//! channels are logged; the encoders' zeros are reported as not identifiable (incremental
//! encoders, no absolute reference in the logs).
//!
//! **Stage 2, output-error refinement** (`refine`): the plant FMU (loaded once) is re-run
//! in-process over the first [`IdentifyConfig::refine_seconds`] of each log with the logged
//! currents as its current set values, and the mechanical parameters (Km, I, c, Tfr on both
//! sides, k) are adjusted by Levenberg-Marquardt ([`lm`]) to match the smoothed velocities and
//! the shaft torque. This removes what the smoothing costs the regressions (its lag of the
//! acceleration, the Coulomb term near zero speed).
//!
//! **Uncertainty.** Each estimate gets a 95 % interval, `1.96` standard errors, the variance
//! inflated by the residuals' integrated autocorrelation time (smoothed and simulated
//! residuals are not white; without it the intervals would be several times too narrow). A
//! parameter is **not identifiable** from the logs given when its regressor is not excited or
//! is a combination of others (rank), or when its interval is wider than
//! [`IdentifyConfig::max_relative_ci`] (25 %) of the estimate; it keeps its prior value in the written set and the report names the experiment
//! to add. Pairs of estimates correlated beyond 0.9 are listed.
//!
//! **Exponential friction.** When the logs were recorded with the exponential (Stribeck-like)
//! law (`frictionModel` = Exponential given as `--param` or in the prior set), each side's
//! Coulomb column is replaced by the law `[a0 + a1 e^{-b1|w|} + a2 (1 - e^{-b2|w|})] sign(w)`,
//! fitted by variable projection over its two rates ([`stribeck`]); the Coulomb level
//! `Tfr,static` is then reported as not used.
//!
//! **Loss surface.** When the logs were recorded with the harmonic drive's loss surface
//! (`frictionModel` = HdLossSurface), the actuation side's Coulomb and viscous columns are
//! replaced by the surface's 2 x 21 polynomial terms (the FMU parameters
//! `hdLossPositiveSpeed[k]`, `hdLossNegativeSpeed[k]`), fitted with Km1 and I1 by linear least
//! squares over the logs' moving rows ([`surface`]: the steady-state map `kneebench experiment
//! map` excites them, a Bode sweep of the test motor fixes Km1 and I1); the coefficients the
//! map's box does not excite are reported as such and held at their prior. The others'
//! intervals count the held priors' uncertainty (a held prior's error moves the coefficients
//! correlated with it); one that leans on the held values beyond
//! [`IdentifyConfig::surface_max_relative_ci`] (10 %) is [`Status::Conditional`]: written to the
//! set as part of the fitted surface, not claimed on its own, not refined.

pub mod lm;
pub mod log;
pub mod lsq;
mod offsets;
mod refine;
mod report;
pub mod resample;
pub mod smooth;
pub mod stribeck;
pub mod surface;

use std::path::{Path, PathBuf};

pub use report::write_outputs;

use crate::params::ParameterSet;
use crate::{Fmu, LoadOptions};

/// Errors of the identification.
#[derive(Debug, thiserror::Error)]
pub enum IdentifyError {
    /// A log is unusable.
    #[error("{}: {problem}", path.display())]
    Log {
        /// The log.
        path: PathBuf,
        /// What is wrong.
        problem: String,
    },
    /// The bench FMU could not be loaded or read.
    #[error("{0}")]
    Fmu(String),
    /// The simulation of the refinement failed.
    #[error("refinement: {0}")]
    Simulation(String),
    /// Writing the outputs failed.
    #[error("{}: {message}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        message: String,
    },
    /// No log given.
    #[error("no log given")]
    NoLog,
    /// A plant parameter of [`IdentifyConfig::plant_parameters`] that the bench FMU has not,
    /// or whose value does not read as its type or lies outside its declared bounds.
    #[error("{0}")]
    Parameter(String),
}

/// Settings of an identification.
#[derive(Debug, Clone, PartialEq)]
pub struct IdentifyConfig {
    /// Half width of the smoothing window in samples (the cubic fit spans `2 m + 1`).
    pub window: usize,
    /// Half width (samples) of the smoothing of the logged currents the refinement feeds to
    /// the plant.
    pub drive_window: usize,
    /// Half width of the smoothing window of the loss surface's regression (samples; see
    /// [`surface`]: narrower than [`Self::window`], whose attenuation of the acceleration at a
    /// Bode sweep's top frequency would bias Km1 and, four times larger, the surface).
    pub surface_window: usize,
    /// Friction rows use samples moving faster than this \[rad/s\].
    pub min_speed: f64,
    /// Run the output-error refinement.
    pub refine: bool,
    /// Seconds of each log the refinement simulates (from its start).
    pub refine_seconds: f64,
    /// An estimate whose 95 % half width exceeds this fraction of its value is reported as
    /// not identifiable (and the prior kept).
    pub max_relative_ci: f64,
    /// A loss-surface coefficient is reported as identified only when its 95 % half width,
    /// counting the uncertainty of the coefficients held at their priors, is within this
    /// fraction of its value (10 %, the issue's bar for a recovered parameter); a wider one
    /// within [`Self::max_relative_ci`] is fitted and written but reported as
    /// [`Status::Conditional`] (see [`surface`]). The surface has 42 correlated coefficients:
    /// their value at the map's points is what the logs determine, not each of them.
    pub surface_max_relative_ci: f64,
    /// Parameters set on the plant for the refinement's simulation (`configuration`,
    /// `frictionModel`, ...: how the logs were recorded), as `(name, value)` text.
    pub plant_parameters: Vec<(String, String)>,
    /// Name of the written set.
    pub name: String,
    /// Version of the written set.
    pub version: String,
}

impl IdentifyConfig {
    /// The value given last for the plant parameter `name` in [`Self::plant_parameters`] (a
    /// later `--param` overrides an earlier one), if any.
    fn plant_parameter(&self, name: &str) -> Option<&str> {
        self.plant_parameters
            .iter()
            .rev()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_str())
    }
}

/// Checks [`IdentifyConfig::plant_parameters`] against the bench FMU `fmu` before any work: each
/// name must be a parameter of the FMU (the error lists them) and each value must read as the
/// parameter's type (a number, or an item of its enumeration), as the refinement's simulation
/// will set it, inside the parameter's declared `[min, max]`
/// ([`check_assignments`](crate::params::check_assignments)).
pub fn check_plant_parameters(
    fmu: &Fmu,
    parameters: &[(String, String)],
) -> Result<(), IdentifyError> {
    crate::params::check_assignments(fmu, parameters).map_err(IdentifyError::Parameter)
}

impl Default for IdentifyConfig {
    fn default() -> Self {
        IdentifyConfig {
            window: 25,
            drive_window: 75,
            surface_window: 12,
            min_speed: 0.05,
            refine: true,
            refine_seconds: 6.0,
            max_relative_ci: 0.25,
            surface_max_relative_ci: 0.10,
            plant_parameters: Vec::new(),
            name: "identified".into(),
            version: "1".into(),
        }
    }
}

/// What an estimated quantity is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Quantity {
    /// The FMU parameter it sets (`None`: a sensor offset, reported only).
    pub parameter: Option<&'static str>,
    /// Display name.
    pub label: &'static str,
    /// Unit.
    pub unit: &'static str,
    /// The experiment that excites it, for the report when it is not identifiable.
    pub experiment: &'static str,
}

const fn q(
    parameter: Option<&'static str>,
    label: &'static str,
    unit: &'static str,
    experiment: &'static str,
) -> Quantity {
    Quantity {
        parameter,
        label,
        unit,
        experiment,
    }
}

const SPRING: [Quantity; 2] = [
    q(
        Some("springStiffness"),
        "k",
        "N.m/rad",
        "a log with spring deflection in SEA/CSEA: `kneebench experiment bode` (either input)",
    ),
    q(
        None,
        "transducer torque offset tau0",
        "N.m",
        "any log (the transducer's reading at zero deflection)",
    ),
];
const ACTUATION: [Quantity; 4] = [
    q(
        Some("testMotorTorqueConstant"),
        "Km1",
        "N.m/A",
        "a log driving the test motor: `kneebench experiment bode --input test`",
    ),
    q(
        Some("actuationInertia"),
        "I1",
        "kg.m2",
        "a log with acceleration of the actuation side: `kneebench experiment bode --input test` or `step`",
    ),
    q(
        Some("actuationDamping"),
        "c1",
        "N.m.s/rad",
        "a log over a range of actuation speeds: `kneebench experiment bode --input test` or `map`",
    ),
    q(
        Some("actuationStaticFriction"),
        "Tfr1",
        "N.m",
        "a log moving the actuation side both ways: `kneebench experiment bode --input test`",
    ),
];
const LOAD: [Quantity; 4] = [
    q(
        Some("loadMotorTorqueConstant"),
        "Km2",
        "N.m/A",
        "a log driving the load motor: `kneebench experiment bode --input load`",
    ),
    q(
        Some("loadInertia"),
        "I2",
        "kg.m2",
        "a log with acceleration of the load side: `kneebench experiment bode --input load`",
    ),
    q(
        Some("loadDamping"),
        "c2",
        "N.m.s/rad",
        "a log over a range of load speeds: `kneebench experiment bode --input load`",
    ),
    q(
        Some("loadStaticFriction"),
        "Tfr2",
        "N.m",
        "a log moving the load side both ways: `kneebench experiment bode --input load`",
    ),
];
/// The exponential friction law's coefficients of one side (`frictionModel` = Exponential),
/// in [`stribeck::LawFit`]'s order after Km, I, c.
const fn law(side: usize) -> [Quantity; 5] {
    let experiment = "slow steady motion both ways, below and above the Stribeck speed: `kneebench experiment map` (its 3 deg/s holds) with the law active";
    let growth = "steady speeds beyond 1/b2 (0.5 rad/s) both ways: `kneebench experiment map` or a Bode sweep of larger amplitude";
    if side == 0 {
        [
            q(Some("actuationStribeckA0"), "a0,1", "N.m", experiment),
            q(Some("actuationStribeckA1"), "a1,1", "N.m", experiment),
            q(Some("actuationStribeckB1"), "b1,1", "s/rad", experiment),
            q(Some("actuationStribeckA2"), "a2,1", "N.m", growth),
            q(Some("actuationStribeckB2"), "b2,1", "s/rad", growth),
        ]
    } else {
        [
            q(Some("loadStribeckA0"), "a0,2", "N.m", experiment),
            q(Some("loadStribeckA1"), "a1,2", "N.m", experiment),
            q(Some("loadStribeckB1"), "b1,2", "s/rad", experiment),
            q(Some("loadStribeckA2"), "a2,2", "N.m", growth),
            q(Some("loadStribeckB2"), "b2,2", "s/rad", growth),
        ]
    }
}

/// Whether the logs were recorded with the friction law `(value, name)` (the plant's
/// `frictionModel` mode, given by value or by name) among the simulation's parameters or,
/// failing that, in the prior set: the law decides which friction terms the regressions carry.
fn friction_model_is(
    config: &IdentifyConfig,
    prior: Option<&ParameterSet>,
    (value, name): (i64, &str),
) -> bool {
    let is = |v: &str| v.trim() == value.to_string() || v.trim().eq_ignore_ascii_case(name);
    if let Some(v) = config.plant_parameter("frictionModel") {
        return is(v);
    }
    prior
        .and_then(|p| p.parameters.iter().find(|q| q.name == "frictionModel"))
        .is_some_and(
            |q| matches!(q.value, crate::params::ParamValue::Integer(v) if i64::from(v) == value),
        )
}

const TEST_MOTOR: [Quantity; 3] = [
    q(
        Some("testMotorResistance"),
        "R1",
        "Ohm",
        "a log with the test driver's voltage and a varying current",
    ),
    q(
        Some("testMotorInductance"),
        "L1",
        "H",
        "current and voltage sampled well above 1 / (L/R), about 1.3 kHz (an oscilloscope on a voltage step; `kneebench experiment` logs at the 1 ms control period)",
    ),
    q(
        Some("testMotorBackEmfConstant"),
        "Ke1",
        "V.s/rad",
        "a log with the test driver's voltage while the actuation side moves",
    ),
];
const LOAD_MOTOR: [Quantity; 3] = [
    q(
        Some("loadMotorResistance"),
        "R2",
        "Ohm",
        "a log with the load driver's voltage and a varying current",
    ),
    q(
        Some("loadMotorInductance"),
        "L2",
        "H",
        "current and voltage sampled well above 1 / (L/R), about 1.3 kHz (an oscilloscope on a voltage step; `kneebench experiment` logs at the 1 ms control period)",
    ),
    q(
        Some("loadMotorBackEmfConstant"),
        "Ke2",
        "V.s/rad",
        "a log with the load driver's voltage while the load side moves",
    ),
];

/// Status of an estimate.
#[derive(Debug, Clone, PartialEq)]
pub enum Status {
    /// Determined by the logs.
    Identified,
    /// Not determined by the logs; the reason. The written set keeps the prior value.
    NotIdentifiable(String),
    /// Fitted together with others held at their priors, and written to the set (the fit is
    /// one consistent function, as the loss surface's), but its value leans on the held ones
    /// beyond the limit: not identified on its own; the reason. Its interval counts the held
    /// values' uncertainty.
    Conditional(String),
}

impl Status {
    /// Whether the estimate goes into the written set (identified, or fitted conditionally on
    /// held values); otherwise the set keeps the prior.
    pub fn is_written(&self) -> bool {
        matches!(self, Status::Identified | Status::Conditional(_))
    }
}

/// One estimated quantity.
#[derive(Debug, Clone, PartialEq)]
pub struct Estimate {
    /// What it is.
    pub quantity: Quantity,
    /// The value before identification (the FMU's or the prior set's; NaN for offsets).
    pub prior: f64,
    /// The least-squares estimate (NaN when not determined).
    pub linear: f64,
    /// Half width of its 95 % interval.
    pub linear_ci: f64,
    /// The refined estimate and its 95 % half width, when refined.
    pub refined: Option<(f64, f64)>,
    /// Identified or not.
    pub status: Status,
}

impl Estimate {
    /// A quantity the logs do not identify, with the reason; its value stays `prior`.
    pub(crate) fn not_identifiable(quantity: Quantity, prior: f64, why: &str) -> Estimate {
        Estimate {
            quantity,
            prior,
            linear: f64::NAN,
            linear_ci: f64::NAN,
            refined: None,
            status: Status::NotIdentifiable(why.into()),
        }
    }

    /// Every quantity of `quantities` as not identifiable for the same reason, each keeping
    /// its `prior` value.
    pub(crate) fn none_identifiable<'a>(
        quantities: impl IntoIterator<Item = &'a Quantity>,
        prior: &dyn Fn(&Quantity) -> f64,
        why: &str,
    ) -> Vec<Estimate> {
        quantities
            .into_iter()
            .map(|qn| Estimate::not_identifiable(*qn, prior(qn), why))
            .collect()
    }

    /// The final value and its 95 % half width (refined if refined, else linear).
    pub fn value(&self) -> (f64, f64) {
        self.refined.unwrap_or((self.linear, self.linear_ci))
    }
}

/// One regression's fit quality.
#[derive(Debug, Clone, PartialEq)]
pub struct Regression {
    /// Which (spring, actuation, ...).
    pub name: &'static str,
    /// Rows used.
    pub rows: usize,
    /// Residual RMS and its unit.
    pub residual_rms: (f64, &'static str),
    /// The variance inflation applied (autocorrelation time, samples).
    pub inflation: f64,
    /// Pairs of its estimates correlated beyond 0.9: (label, label, correlation).
    pub correlated: Vec<(&'static str, &'static str, f64)>,
}

/// The result of an identification.
#[derive(Debug, Clone)]
pub struct Identification {
    /// Every estimate.
    pub estimates: Vec<Estimate>,
    /// The regressions.
    pub regressions: Vec<Regression>,
    /// The refinement, if run.
    pub refinement: Option<refine::Refinement>,
    /// Notes (excluded segments, skipped regressions).
    pub notes: Vec<String>,
    /// The identified set (the prior with every identified parameter replaced).
    pub set: ParameterSet,
    /// The logs used.
    pub logs: Vec<PathBuf>,
    /// Wall time of the identification \[s\].
    pub seconds: f64,
}

pub use refine::Refinement;

/// A regressor or target: its value for row `i` of a log.
type Column<'a> = &'a dyn Fn(&log::Log, usize) -> f64;

/// Rows of all logs where `keep` holds, stacked: one column per regressor, and the target.
fn stack(
    logs: &[log::Log],
    keep: &dyn Fn(&log::Log, usize) -> bool,
    columns: &[Column<'_>],
    target: Column<'_>,
) -> (Vec<Vec<f64>>, Vec<f64>) {
    let mut x = vec![Vec::new(); columns.len()];
    let mut y = Vec::new();
    for l in logs {
        for i in 0..l.time.len() {
            if l.usable[i] && keep(l, i) {
                for (c, f) in x.iter_mut().zip(columns) {
                    c.push(f(l, i));
                }
                y.push(target(l, i));
            }
        }
    }
    (x, y)
}

fn estimates_of(
    quantities: &[Quantity],
    fit: &lsq::LinearFit,
    prior: &dyn Fn(&Quantity) -> f64,
    max_relative_ci: f64,
) -> Vec<Estimate> {
    quantities
        .iter()
        .enumerate()
        .map(|(j, qn)| {
            let value = fit.values[j];
            let ci = 1.96 * fit.stats.std[j];
            let status = if !fit.stats.determined[j] {
                Status::NotIdentifiable(
                    "its regressor is not excited by these logs, or is a combination of the others"
                        .into(),
                )
            } else if qn.parameter.is_some() && (ci.is_nan() || ci > max_relative_ci * value.abs())
            {
                // (A sensor offset may well be near zero: only its rank decides.)
                Status::NotIdentifiable(format!(
                    "its 95 % interval (+-{}) is wider than {} % of the estimate",
                    fmt(ci),
                    100.0 * max_relative_ci
                ))
            } else {
                Status::Identified
            };
            Estimate {
                quantity: *qn,
                prior: prior(qn),
                linear: value,
                linear_ci: ci,
                refined: None,
                status,
            }
        })
        .collect()
}

fn regression(
    name: &'static str,
    unit: &'static str,
    qs: &[Quantity],
    f: &lsq::LinearFit,
) -> Regression {
    let mut correlated = Vec::new();
    for i in 0..qs.len() {
        for j in i + 1..qs.len() {
            let c = f.stats.correlation[i][j];
            if c.abs() > 0.9 {
                correlated.push((qs[i].label, qs[j].label, c));
            }
        }
    }
    Regression {
        name,
        rows: f.stats.rows,
        residual_rms: (f.stats.residual_rms, unit),
        inflation: f.stats.inflation,
        correlated,
    }
}

/// Per sample: whether every smoothed velocity within `m` samples is faster than `min_speed`
/// (a stick or a reversal inside the smoothing window biases the derivatives there).
fn moving(v: &[f64], min_speed: f64, m: usize) -> Vec<bool> {
    let mut slow = vec![0usize; v.len() + 1];
    for (i, x) in v.iter().enumerate() {
        slow[i + 1] = slow[i] + usize::from(x.is_nan() || x.abs() <= min_speed);
    }
    (0..v.len())
        .map(|i| {
            let (a, b) = (i.saturating_sub(m), (i + m + 1).min(v.len()));
            slow[b] - slow[a] == 0
        })
        .collect()
}

/// Formats a number with 4 significant digits.
pub(crate) fn fmt(v: f64) -> String {
    if !v.is_finite() {
        return "-".into();
    }
    if v == 0.0 {
        return "0".into();
    }
    let digits = (3 - v.abs().log10().floor() as i32).max(0) as usize;
    if v.abs() >= 1e5 || v.abs() < 1e-3 {
        format!("{v:.3e}")
    } else {
        format!("{v:.digits$}")
    }
}

/// Identifies the bench's parameters from `logs`. `bench` is the bench FMU (its parameters'
/// start values, or `prior` when given, are the prior; the refinement simulates it).
pub fn identify(
    logs: &[PathBuf],
    bench: &Path,
    prior: Option<&ParameterSet>,
    config: &IdentifyConfig,
) -> Result<Identification, IdentifyError> {
    let started = std::time::Instant::now();
    if logs.is_empty() {
        return Err(IdentifyError::NoLog);
    }
    let fmu = Fmu::load(bench, &LoadOptions::default())
        .map_err(|e| IdentifyError::Fmu(format!("{}: {e}", bench.display())))?;
    check_plant_parameters(&fmu, &config.plant_parameters)?;
    let md = fmu.model_description().clone();
    let mut set = ParameterSet::defaults_of(&md, &config.name, &config.version);
    if let Some(p) = prior {
        p.check(&md, &format!("prior set '{}'", p.name))
            .map_err(|e| IdentifyError::Fmu(e.to_string()))?;
        for q in &p.parameters {
            if let crate::params::ParamValue::Real(v) = q.value {
                set.set_real(&q.name, v, q.unit.as_deref());
            }
        }
    }
    set.description = Some(format!(
        "identified by kneebench identify from {}",
        logs.iter()
            .map(|l| l
                .file_name()
                .map(|f| f.to_string_lossy().into_owned())
                .unwrap_or_default())
            .collect::<Vec<_>>()
            .join(", ")
    ));
    let real = |name: &str| -> Result<f64, IdentifyError> {
        // A --param given for the simulation also fixes the regressions' constants.
        if let Some(v) = config.plant_parameter(name) {
            return v.trim().parse().map_err(|_| {
                IdentifyError::Fmu(format!("parameter {name} = '{v}' is not a number"))
            });
        }
        set.real(name)
            .ok_or_else(|| IdentifyError::Fmu(format!("{} has no parameter {name}", md.model_name)))
    };
    let i_hd = real("harmonicDriveRatio")?;
    let i_red = real("reductionRatio")?;
    let prior_of = |q: &Quantity| q.parameter.and_then(|p| set.real(p)).unwrap_or(f64::NAN);
    let exponential = friction_model_is(config, prior, (2, "Exponential"));
    let loss_surface = friction_model_is(config, prior, (3, "HdLossSurface"));

    let logs_read: Vec<log::Log> = logs
        .iter()
        .map(|p| log::read(p, config.window))
        .collect::<Result<_, _>>()?;
    let mut notes: Vec<String> = logs_read.iter().flat_map(|l| l.notes.clone()).collect();
    let mut estimates = Vec::new();
    let mut regressions = Vec::new();

    // Spring.
    let (x, y) = stack(
        &logs_read,
        &|_, _| true,
        &[&|l, i| l.angle[0][i] - l.angle[1][i], &|_, _| 1.0],
        &|l, i| l.torque[i],
    );
    let spring = lsq::fit(&x, &y);
    let tau0 = if spring.stats.determined[1] {
        spring.values[1]
    } else {
        0.0
    };
    estimates.extend(estimates_of(
        &SPRING,
        &spring,
        &prior_of,
        config.max_relative_ci,
    ));
    regressions.push(regression(
        "spring: tau = k (theta1 - theta2) + tau0",
        "N.m",
        &SPRING,
        &spring,
    ));

    // Both sides.
    let min_speed = config.min_speed;
    let mut sides: [(usize, &'static str, &[Quantity; 4], f64, f64); 2] = [
        (
            0,
            "actuation side (inverse dynamics)",
            &ACTUATION,
            i_hd,
            -1.0,
        ),
        (1, "load side (inverse dynamics)", &LOAD, i_red, 1.0),
    ];
    let masks: Vec<[Vec<bool>; 2]> = logs_read
        .iter()
        .map(|l| [0, 1].map(|side| moving(&l.velocity[side], min_speed, config.window)))
        .collect();
    let mask_of = |l: &log::Log, side: usize, i: usize| {
        let k = logs_read
            .iter()
            .position(|x| std::ptr::eq(x, l))
            .expect("a log of the list");
        masks[k][side][i]
    };
    if loss_surface {
        // The surface's load torque x needs Km2: the load side first.
        sides.reverse();
    }
    for (side, name, qs, ratio, sign) in sides {
        if loss_surface && side == 0 {
            let km2 = estimates
                .iter()
                .find(|e| e.quantity.parameter == Some("loadMotorTorqueConstant"))
                .filter(|e| e.status == Status::Identified)
                .map_or(prior_of(&LOAD[0]), |e| e.linear);
            let surface_box = surface::SurfaceBox {
                max_speed: real("hdSurfaceMaxSpeed")?,
                min_load_torque: real("hdSurfaceMinLoadTorque")?,
                max_load_torque: real("hdSurfaceMaxLoadTorque")?,
                load_torque_per_ampere: i_red * km2,
            };
            let rows = |k: usize, i: usize| masks[k][0][i];
            match surface::fit_actuation(
                &logs_read,
                &rows,
                qs,
                &surface_box,
                i_hd,
                tau0,
                config.surface_window,
                &prior_of,
                config.max_relative_ci,
                config.surface_max_relative_ci,
            ) {
                Some((e, r)) => {
                    estimates.extend(e);
                    regressions.push(r);
                }
                None => {
                    notes.push(format!(
                        "{name}: too few samples move faster than {min_speed} rad/s throughout their smoothing window; the loss surface is not fitted"
                    ));
                    estimates.extend(Estimate::none_identifiable(
                        qs.iter().chain(&surface::COEFFICIENTS),
                        &prior_of,
                        "the logs hardly move this side",
                    ));
                }
            }
            continue;
        }
        let (x, y) = stack(
            &logs_read,
            &|l, i| mask_of(l, side, i),
            &[
                &|l, i| -sign * ratio * l.current_smooth[side][i],
                &|l, i| sign * l.acceleration[side][i],
                &|l, i| sign * l.velocity[side][i],
                &|l, i| sign * l.velocity[side][i].signum(),
            ],
            &|l, i| l.torque[i] - tau0,
        );
        if y.len() < 100 {
            notes.push(format!(
                "{name}: only {} samples move faster than {min_speed} rad/s throughout their smoothing window; not fitted",
                y.len()
            ));
            estimates.extend(Estimate::none_identifiable(
                qs,
                &prior_of,
                "the logs hardly move this side",
            ));
            continue;
        }
        if exponential {
            let (velocity, _) = stack(
                &logs_read,
                &|l, i| mask_of(l, side, i),
                &[&|l, i| l.velocity[side][i]],
                &|l, i| l.torque[i] - tau0,
            );
            let rows = stribeck::SideRows {
                current: &x[0],
                acceleration: &x[1],
                velocity: &velocity[0],
                sign,
                target: &y,
            };
            if let Some(f) = stribeck::fit(&rows) {
                let quantities: Vec<Quantity> =
                    [qs[0], qs[1], qs[2]].into_iter().chain(law(side)).collect();
                let fit = lsq::LinearFit {
                    values: f.values.to_vec(),
                    stats: f.stats,
                };
                let mut side_estimates =
                    estimates_of(&quantities, &fit, &prior_of, config.max_relative_ci);
                // The levels are solved for the rates found: when a rate is not determined,
                // neither are they (their intervals, conditional on the rates, would claim a
                // precision they do not have).
                if let Some(rate) = [5, 7]
                    .into_iter()
                    .find(|&k| side_estimates[k].status != Status::Identified)
                {
                    let why = format!(
                        "the law's rate {} is not determined by these logs, and the law's levels depend on it",
                        side_estimates[rate].quantity.label
                    );
                    for e in &mut side_estimates[3..] {
                        if e.status == Status::Identified {
                            e.status = Status::NotIdentifiable(why.clone());
                        }
                    }
                }
                estimates.extend(side_estimates);
                estimates.push(Estimate::not_identifiable(qs[3], prior_of(&qs[3]), "not used by the exponential friction law the logs were recorded with (its a0 + a1 is the stiction)"));
                let label = if side == 0 {
                    "actuation side (inverse dynamics, exponential friction law)"
                } else {
                    "load side (inverse dynamics, exponential friction law)"
                };
                regressions.push(regression(label, "N.m", &quantities, &fit));
                continue;
            }
            notes.push(format!(
                "{name}: the exponential friction law could not be fitted (its columns are not excited); the Coulomb level is fitted instead"
            ));
        }
        let f = lsq::fit(&x, &y);
        estimates.extend(estimates_of(qs, &f, &prior_of, config.max_relative_ci));
        regressions.push(regression(name, "N.m", qs, &f));
    }

    // Motors, where the voltage is logged.
    let motors: [(usize, &'static str, &[Quantity; 3], f64); 2] = [
        (0, "test motor (armature circuit)", &TEST_MOTOR, i_hd),
        (1, "load motor (armature circuit)", &LOAD_MOTOR, i_red),
    ];
    for (side, name, qs, ratio) in motors {
        let with_voltage: Vec<log::Log> = logs_read
            .iter()
            .filter(|l| l.voltage[side].is_some())
            .cloned()
            .collect();
        if with_voltage.is_empty() {
            notes.push(format!(
                "{name}: no log has the driver's voltage; not fitted"
            ));
            estimates.extend(Estimate::none_identifiable(
                qs,
                &prior_of,
                "the driver's voltage is not logged",
            ));
            continue;
        }
        let (x, y) = stack(
            &with_voltage,
            &|_, _| true,
            &[&|l, i| l.current_smooth[side][i], &|l, i| {
                ratio * l.velocity[side][i]
            }],
            &|l, i| l.voltage[side].as_ref().expect("filtered")[i],
        );
        let fitted = [qs[0], qs[2]];
        let f = lsq::fit(&x, &y);
        let mut e = estimates_of(&fitted, &f, &prior_of, config.max_relative_ci);
        // The armature's time constant L/R (about 0.8 ms) is shorter than the logs' sample
        // period, so the smoothed current's rate does not carry it (a regression on it
        // returns a tight but meaningless value).
        e.insert(
            1,
            Estimate::not_identifiable(
                qs[1],
                prior_of(&qs[1]),
                "the armature time constant L/R is below what logs at the control rate resolve",
            ),
        );
        estimates.extend(e);
        regressions.push(regression(name, "V", &fitted, &f));
    }

    // Sensor offsets beyond tau0.
    let (offset_estimates, offset_regressions, offset_notes) =
        offsets::sensor_offsets(&logs_read, i_hd, &prior_of, config.max_relative_ci);
    estimates.extend(offset_estimates);
    regressions.extend(offset_regressions);
    notes.extend(offset_notes);

    // Stage 2.
    let refinement = if config.refine {
        Some(refine::refine(
            &fmu,
            &logs_read,
            &mut estimates,
            &set,
            tau0,
            config,
        )?)
    } else {
        None
    };

    for e in &mut estimates {
        let (Some(p), true) = (e.quantity.parameter, e.status.is_written()) else {
            continue;
        };
        let Some(model_description::VariableKind::Real { attributes, .. }) = md
            .model_variables
            .iter()
            .find(|v| v.name == p)
            .map(|v| &v.kind)
        else {
            continue;
        };
        let value = e.value().0;
        let (min, max) = (
            attributes.min.unwrap_or(f64::NEG_INFINITY),
            attributes.max.unwrap_or(f64::INFINITY),
        );
        if !(min..=max).contains(&value) {
            e.status = Status::NotIdentifiable(format!(
                "the estimate {} lies outside the FMU's admissible [{min}, {max}]",
                fmt(value)
            ));
            continue;
        }
        set.set_real(p, value, attributes.unit.as_deref());
    }
    set.define_units(&md);
    Ok(Identification {
        estimates,
        regressions,
        refinement,
        notes,
        set,
        logs: logs.to_vec(),
        seconds: started.elapsed().as_secs_f64(),
    })
}
