//! `kneebench experiment`: the bench's experiments on `BenchPlant` or `BenchHardware`.

use std::path::{Path, PathBuf};

use anyhow::Context;
use kneebench_harness::experiment::{
    Bench, BenchKind, ExperimentError, RawFormat, RunEnd, Written, bode, calibration, map, step,
    triangle,
};

/// The raw run file's format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// `<name>.csv`.
    Csv,
    /// `<name>.parquet`.
    Parquet,
}

/// Arguments of `kneebench experiment`.
#[derive(Debug, clap::Args)]
#[command(after_help = "\
Examples:
  kneebench experiment step --fmu out/fmus/BenchPlant.fmu --out out/experiments
  kneebench experiment map --fmu out/fmus/BenchPlant.fmu --param frictionModel=3 --param actuationDamping=0 --param loadRegenPowerLimit=1000 --speeds 3,50,150 --torques -9,0,9
  kneebench experiment bode --fmu out/fmus/BenchPlant.fmu --param frictionModel=0 --start-frequency 0.5 --stages 6
  kneebench experiment triangle --fmu out/fmus/BenchPlant.fmu
  kneebench experiment calibration --fmu out/fmus/BenchPlant.fmu --param frictionModel=0
On the bench, the same schedule through BenchHardware (refused unless its interlocks are armed):
  kneebench experiment triangle --fmu out/fmus/BenchHardware.fmu --param backend=1 --param pacing=1 \\
      --param serverAddress=127.0.0.1:47000

The experiments are bench-model.md sections 5, 6 and 8; each has its own options
(`kneebench experiment NAME --help`), and an option of another experiment is refused.

The same schedule runs on BenchPlant and on BenchHardware (which runs in real time against
the bench or `kneebench emulate`). On BenchHardware the experiment refuses to start unless
every interlock is armed at or inside the bench's limits. Written into --out: <name>.csv (the
run; <name>.parquet with --format parquet), <name>-result.csv (the analysed table), <name>.svg
and .png, <name>.md. On BenchHardware the run also records the FMU's pacing and link counts
(plant.overrunCount, plant.maxLateness, plant.rejectedFrames, plant.staleReplies), printed
as `pacing:` and written into <name>.md, with a warning when the loop fell a whole period
behind its schedule; each row's timing (plant.lastLateness, plant.lastReplyTime: where the
host held the loop up); and the bench's clock at each sample (plant.benchSampleTime, which
`kneebench identify` resamples the log on). Other FMUs (GaitReference, PidController) are taken from --fmus, default the bench FMU's directory.
Exit code 3 when an interlock ended the run (the triangle test's trip is its result: 0).")]
pub struct Args {
    /// The experiment and its options.
    #[command(subcommand)]
    pub experiment: Experiment,
}

/// An experiment, with its own options: an option of another experiment is refused (it was
/// accepted and ignored when one set of options served them all).
#[derive(Debug, clap::Subcommand)]
pub enum Experiment {
    /// Constant test-motor speeds x constant load torques: the harmonic drive's loss torque and
    /// efficiency against the loss surface.
    Map(MapArgs),
    /// Stepped-sine torque (10 N m, 0.05 Hz, x10^(1/30) every 20 s): gain and phase of both
    /// velocities per torque with their uncertainty, against H1-H4.
    Bode(BodeArgs),
    /// Triangle position wave, the load torque raised each cycle until the load driver's
    /// braking limit trips: the torque at the trip.
    Triangle(TriangleArgs),
    /// Pendulum calibration of the torque transducer and the load cell: a, b, c of
    /// V = a + b sin(theta + c).
    Calibration(CalibrationArgs),
    /// Open-loop current step (reaction curve, Ziegler-Nichols gains, identified damping and
    /// inertia) and closed-loop position step (rise, settling, overshoot, peak time).
    Step(StepArgs),
}

impl Experiment {
    /// The options every experiment has.
    fn common(&self) -> &Common {
        match self {
            Experiment::Map(a) => &a.common,
            Experiment::Bode(a) => &a.common,
            Experiment::Triangle(a) => &a.common,
            Experiment::Calibration(a) => &a.common,
            Experiment::Step(a) => &a.common,
        }
    }
}

/// The options of every experiment.
#[derive(Debug, clap::Args)]
pub struct Common {
    /// The bench FMU: BenchPlant.fmu or BenchHardware.fmu.
    #[arg(long)]
    pub fmu: PathBuf,
    /// Directory of GaitReference.fmu and PidController.fmu (default: the bench FMU's).
    #[arg(long)]
    pub fmus: Option<PathBuf>,
    /// Output directory.
    #[arg(long, default_value = "out/experiments")]
    pub out: PathBuf,
    /// A parameter of the bench FMU, NAME=VALUE (repeatable).
    #[arg(long = "param", value_name = "NAME=VALUE")]
    pub params: Vec<String>,
    /// A parameter set (.ssv) for the bench FMU, applied before --param; named in NAME.md.
    #[arg(long = "params", value_name = "SET.ssv")]
    pub parameter_set: Option<PathBuf>,
    /// Format of the raw run file `<name>.csv` or `<name>.parquet` (the bench FMU, its GUID and
    /// parameters in the Parquet file's metadata); `kneebench identify` reads both.
    #[arg(long, value_enum, default_value_t = Format::Csv)]
    pub format: Format,
}

/// `kneebench experiment map`.
#[derive(Debug, clap::Args)]
pub struct MapArgs {
    #[command(flatten)]
    #[allow(missing_docs)]
    pub common: Common,
    /// Speed magnitudes (deg/s), each run both ways (default the bench's 0, 3, 6, 10, 20, 30,
    /// 50, 70, 90, 110, 130, 150).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, value_parser = super::values::non_negative)]
    pub speeds: Option<Vec<f64>>,
    /// Load torques (N m) (default -9, -4.5, 0, 4.5, 9).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, value_parser = super::values::finite)]
    pub torques: Option<Vec<f64>>,
    /// Run only points whose predicted regenerated power in the load driver is at most this
    /// fraction of loadRegenPowerLimit (the others are listed as skipped).
    #[arg(long, default_value_t = map::DEFAULT_REGEN_FRACTION, value_parser = fraction)]
    pub regen_fraction: f64,
    /// Settling time per point (s).
    #[arg(long, default_value_t = 1.5, value_parser = super::values::positive)]
    pub settle: f64,
    /// Averaging time per point (s).
    #[arg(long, default_value_t = 1.0, value_parser = super::values::positive)]
    pub measure: f64,
    /// The loss surface CSV to compare with (default the project's
    /// shared/data/hd-loss-surface.csv).
    #[arg(long)]
    pub loss_surface: Option<PathBuf>,
}

/// `kneebench experiment bode`.
#[derive(Debug, clap::Args)]
pub struct BodeArgs {
    #[command(flatten)]
    #[allow(missing_docs)]
    pub common: Common,
    /// The driven motor (test or load).
    #[arg(long, default_value = "test")]
    pub input: String,
    /// Torque amplitude (N m).
    #[arg(long, default_value_t = 10.0, value_parser = super::values::positive)]
    pub amplitude: f64,
    /// First frequency (Hz).
    #[arg(long, default_value_t = 0.05, value_parser = super::values::positive)]
    pub start_frequency: f64,
    /// Frequency ratio between stages, at least 1 (default 10^(1/30)).
    #[arg(long, value_parser = ratio)]
    pub ratio: Option<f64>,
    /// Duration of a stage (s).
    #[arg(long, default_value_t = 20.0, value_parser = super::values::positive)]
    pub dwell: f64,
    /// Number of stages, 1 to 100 (the bound keeps the run within the rows an experiment
    /// records in memory; default 70: 0.05 ... 10 Hz).
    #[arg(long, default_value_t = 70, value_parser = clap::value_parser!(u32).range(1..=i64::from(bode::MAX_STAGES)))]
    pub stages: u32,
}

/// `kneebench experiment triangle`.
#[derive(Debug, clap::Args)]
pub struct TriangleArgs {
    #[command(flatten)]
    #[allow(missing_docs)]
    pub common: Common,
    /// Amplitude (deg).
    #[arg(long, default_value_t = 30.0, value_parser = super::values::positive)]
    pub triangle_amplitude: f64,
    /// Period (s).
    #[arg(long, default_value_t = 3.0, value_parser = super::values::positive)]
    pub period: f64,
    /// Load torque increment per cycle (N m).
    #[arg(long, default_value_t = 0.5, allow_hyphen_values = true, value_parser = super::values::non_zero)]
    pub increment: f64,
    /// Most cycles.
    #[arg(long, default_value_t = 40, value_parser = clap::value_parser!(u32).range(1..))]
    pub max_cycles: u32,
    /// Position-loop gains kp,ki,kd (A/rad, A/(rad s), A s/rad) (default 1000,1000,15).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, value_parser = super::values::finite)]
    pub gains: Option<Vec<f64>>,
}

/// `kneebench experiment calibration`.
#[derive(Debug, clap::Args)]
pub struct CalibrationArgs {
    #[command(flatten)]
    #[allow(missing_docs)]
    pub common: Common,
    /// Averaging time per angle (s).
    #[arg(long, default_value_t = 3.0, value_parser = super::values::positive)]
    pub measure: f64,
    /// Hold time at each angle (s).
    #[arg(long, default_value_t = 6.0, value_parser = super::values::positive)]
    pub hold: f64,
    /// Pendulum angles (deg) (default -45 ... 45 in steps of 9).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, value_parser = super::values::finite)]
    pub angles: Option<Vec<f64>>,
    /// The emulated pendulum's hanging direction from the encoder's zero (deg): the c the fit
    /// recovers.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true, value_parser = super::values::finite)]
    pub pendulum_offset: f64,
    /// Position-loop gains kp,ki,kd (A/rad, A/(rad s), A s/rad) (default 1000,1000,15).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, value_parser = super::values::finite)]
    pub gains: Option<Vec<f64>>,
}

/// `kneebench experiment step`.
#[derive(Debug, clap::Args)]
pub struct StepArgs {
    #[command(flatten)]
    #[allow(missing_docs)]
    pub common: Common,
    /// Position-loop gains kp,ki,kd (A/rad, A/(rad s), A s/rad) (default 60,30,4).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, value_parser = super::values::finite)]
    pub gains: Option<Vec<f64>>,
    /// Open-loop current step (A).
    #[arg(long, default_value_t = 2.0, allow_hyphen_values = true, value_parser = super::values::non_zero)]
    pub current: f64,
    /// Closed-loop position step (deg).
    #[arg(long, default_value_t = 5.0, value_parser = super::values::positive)]
    pub step_angle: f64,
    /// Record length after the step (s); the open-loop speed must settle within it (its rate
    /// over the last tenth under 2 % of its steepest, and the means of its last two tenths
    /// within 0.5 % of the step's change).
    #[arg(long, default_value_t = 1.5, value_parser = super::values::positive)]
    pub duration: f64,
}

/// Parses `--regen-fraction`: a number in (0, 1].
fn fraction(text: &str) -> Result<f64, String> {
    let v = super::values::positive(text)?;
    if v <= 1.0 {
        Ok(v)
    } else {
        Err(format!("{v} is above 1"))
    }
}

/// Parses `--ratio`: a finite number of at least 1 (1 repeats the start frequency).
fn ratio(text: &str) -> Result<f64, String> {
    let v = super::values::finite(text)?;
    if v >= 1.0 {
        Ok(v)
    } else {
        Err(format!("{v} is below 1"))
    }
}

/// An experiment's refusal of its settings ([`ExperimentError::Invalid`]: an option, a
/// parameter or the bench FMU) as a usage error (exit code 2); other errors as they are.
fn usage_if_invalid(e: ExperimentError) -> anyhow::Error {
    match e {
        ExperimentError::Invalid(problem) => super::Usage(problem).into(),
        e => e.into(),
    }
}

/// Runs `kneebench experiment`.
pub fn run(a: Args) -> anyhow::Result<i32> {
    let common = a.experiment.common();
    let set = super::identify::read_set_for(common.parameter_set.as_deref(), &common.fmu)?;
    let params = set
        .iter()
        .flat_map(|s| s.parameters.iter())
        .map(|p| Ok((p.name.clone(), p.value.to_text())))
        .chain(common.params.iter().map(|p| super::name_value(p)))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let mut bench = Bench::load(&common.fmu, params, common.fmus.clone())
        .map_err(usage_if_invalid)?
        .with_raw_format(match common.format {
            Format::Csv => RawFormat::Csv,
            Format::Parquet => RawFormat::Parquet,
        });
    if let Some(set) = &set {
        bench = bench.with_parameter_set(set.label());
    }
    if bench.kind() == BenchKind::Hardware {
        println!("bench: BenchHardware (checking the interlocks before anything moves)");
    }
    let out = &common.out;
    let (written, tripped) = match &a.experiment {
        Experiment::Map(a) => run_map(&bench, a, out)?,
        Experiment::Bode(a) => run_bode(&bench, a, out)?,
        Experiment::Triangle(a) => run_triangle(&bench, a, out)?,
        Experiment::Calibration(a) => run_calibration(&bench, a, out)?,
        Experiment::Step(a) => run_step(&bench, a, out)?,
    };
    for f in written.data.iter().chain(&written.figures) {
        println!("written: {}", f.display());
    }
    if let Some(p) = &written.pacing {
        println!("pacing: {p}");
        if let Some(w) = p.schedule_warning() {
            eprintln!(
                "warning: {w} (run it again on a quieter host where the results matter; {})",
                kneebench_harness::experiment::LATE_LOG_USE
            );
        }
    }
    if let Some(set) = &set {
        super::identify::append_set_line(&written.markdown, set)?;
    }
    println!("section: {}", written.markdown.display());
    Ok(if tripped {
        super::EXIT_TERMINATED
    } else {
        super::EXIT_OK
    })
}

/// `kneebench experiment map`: prints the largest difference to the loss surface.
fn run_map(bench: &Bench, a: &MapArgs, out: &Path) -> anyhow::Result<(Written, bool)> {
    let mut c = map::MapConfig {
        settle: a.settle,
        measure: a.measure,
        regen_fraction: a.regen_fraction,
        ..map::MapConfig::default()
    };
    if let Some(s) = &a.speeds {
        c.speeds = s.clone();
    }
    if let Some(t) = &a.torques {
        c.torques = t.clone();
    }
    if let Some(p) = &a.loss_surface {
        c.surface =
            std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
    }
    let r = map::run_map(bench, &c, out).map_err(usage_if_invalid)?;
    let worst = r
        .points
        .iter()
        .map(|p| p.relative_difference.abs())
        .filter(|d| d.is_finite())
        .fold(0.0, f64::max);
    println!(
        "map: {} points, largest difference to the loss surface {:.2} %",
        r.points.len(),
        100.0 * worst
    );
    if !r.skipped.is_empty() {
        println!(
            "map: {} points skipped (their braking would exceed the regenerated-power budget; listed in map.md)",
            r.skipped.len()
        );
    }
    let tripped = ended("map", &r.end);
    Ok((r.written, tripped))
}

/// `kneebench experiment bode`: prints each stage's gains and phases against the model's.
fn run_bode(bench: &Bench, a: &BodeArgs, out: &Path) -> anyhow::Result<(Written, bool)> {
    let input = match a.input.as_str() {
        "test" => bode::SweepInput::Test,
        "load" => bode::SweepInput::Load,
        other => {
            return Err(super::Usage(format!("--input '{other}': test or load")).into());
        }
    };
    let mut c = bode::BodeConfig {
        input,
        amplitude: a.amplitude,
        start_frequency: a.start_frequency,
        dwell: a.dwell,
        stages: a.stages,
        ..bode::BodeConfig::default()
    };
    if let Some(r) = a.ratio {
        c.ratio = r;
    }
    let r = bode::run_bode(bench, &c, out).map_err(usage_if_invalid)?;
    for p in &r.points {
        println!(
            "{:8.4} Hz  {} {:7.2} +- {:.2} dB (model {:7.2}), {:7.1} +- {:.1} deg (model {:7.1})  {} {:7.2} dB (model {:7.2}), {:7.1} deg (model {:7.1})",
            p.frequency,
            r.names[0],
            p.measured[0].gain_db(),
            p.measured[0].gain_db_std(),
            p.model[0].0,
            p.measured[0].phase.to_degrees(),
            p.measured[0].phase_std.to_degrees(),
            p.model[0].1.to_degrees(),
            r.names[1],
            p.measured[1].gain_db(),
            p.model[1].0,
            p.measured[1].phase.to_degrees(),
            p.model[1].1.to_degrees(),
        );
    }
    let tripped = ended("bode", &r.end);
    Ok((r.written, tripped))
}

/// `kneebench experiment triangle`: prints the torque at the trip (the result, not an error).
fn run_triangle(bench: &Bench, a: &TriangleArgs, out: &Path) -> anyhow::Result<(Written, bool)> {
    let mut c = triangle::TriangleConfig {
        amplitude: a.triangle_amplitude.to_radians(),
        period: a.period,
        increment: a.increment,
        max_cycles: a.max_cycles,
        ..triangle::TriangleConfig::default()
    };
    if let Some(g) = gains(&a.gains)? {
        c.gains = g;
    }
    let r = triangle::run_triangle(bench, &c, out).map_err(usage_if_invalid)?;
    match &r.trip {
        Some((torque, time, reason)) => {
            println!(
                "triangle: tripped at {time:.3} s with the load torque at {torque} N m ({reason})"
            )
        }
        None => println!("triangle: no trip within {} cycles", c.max_cycles),
    }
    // The trip is the result: not an error.
    Ok((r.written, false))
}

/// `kneebench experiment calibration`: prints the fitted a, b, c of both sensors.
fn run_calibration(
    bench: &Bench,
    a: &CalibrationArgs,
    out: &Path,
) -> anyhow::Result<(Written, bool)> {
    let mut c = calibration::CalibrationConfig {
        measure: a.measure,
        hold: a.hold,
        pendulum_offset: a.pendulum_offset.to_radians(),
        ..calibration::CalibrationConfig::default()
    };
    if let Some(angles) = &a.angles {
        c.angles = angles.iter().map(|d| d.to_radians()).collect();
    }
    if let Some(g) = gains(&a.gains)? {
        c.gains = g;
    }
    let r = calibration::run_calibration(bench, &c, out).map_err(usage_if_invalid)?;
    for (name, f) in [("transducer", &r.transducer), ("load cell", &r.load_cell)] {
        println!(
            "{name}: a = {:.6} V, b = {:.7} V, c = {:.5} rad (residual {:.2e} V)",
            f.a, f.b, f.c, f.residual_rms
        );
    }
    let tripped = ended("calibration", &r.end);
    Ok((r.written, tripped))
}

/// `kneebench experiment step`: prints the reaction curve, the gains and the position step's metrics.
fn run_step(bench: &Bench, a: &StepArgs, out: &Path) -> anyhow::Result<(Written, bool)> {
    let mut c = step::StepConfig {
        current: a.current,
        angle: a.step_angle.to_radians(),
        duration: a.duration,
        ..step::StepConfig::default()
    };
    if let Some(g) = gains(&a.gains)? {
        c.gains = g;
    }
    let r = step::run_step(bench, &c, out).map_err(usage_if_invalid)?;
    println!(
        "open loop: K = {:.5} (rad/s)/A, L = {:.5} s, T = {:.5} s; damping {:.4} N m s/rad, inertia {:.4} kg m^2",
        r.reaction.gain, r.reaction.dead_time, r.reaction.time_constant, r.damping, r.inertia
    );
    match &r.ziegler_nichols {
        Ok(g) => println!(
            "Ziegler-Nichols (velocity loop): kp = {:.4}, ki = {:.4}, kd = {:.6}",
            g.kp, g.ki, g.kd
        ),
        Err(e) => println!("no Ziegler-Nichols gains: {e}"),
    }
    let m = &r.position;
    let time = |t: Option<f64>| t.map_or("not reached".to_string(), |t| format!("{t} s"));
    println!(
        "position step: rise {}, settling {}, overshoot {:.2} %, peak {:.4} s",
        time(m.rise_time),
        time(m.settling_time),
        100.0 * m.overshoot,
        m.peak_time
    );
    let open = ended("step: the open-loop run", &r.ends[0]);
    let closed = ended("step: the closed-loop run", &r.ends[1]);
    Ok((r.written, open || closed))
}

/// `--gains kp,ki,kd`, if given.
fn gains(values: &Option<Vec<f64>>) -> anyhow::Result<Option<(f64, f64, f64)>> {
    match values.as_deref() {
        None => Ok(None),
        Some(&[kp, ki, kd]) => Ok(Some((kp, ki, kd))),
        Some(_) => Err(super::Usage("--gains takes three values: kp,ki,kd".into()).into()),
    }
}

/// Says on stderr why a run of `what` ended early (the reason is in its section too); returns
/// whether it did.
fn ended(what: &str, end: &RunEnd) -> bool {
    match end {
        RunEnd::Completed => false,
        RunEnd::Tripped { time, reason } => {
            eprintln!("{what} was ended at {time:.3} s: {reason}");
            true
        }
    }
}
