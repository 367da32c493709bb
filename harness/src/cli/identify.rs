//! `kneebench identify`, and the `--params SET.ssv` helpers the experiment command shares.

use std::path::Path;

use anyhow::Context;
use kneebench_harness::load::{ArchiveLimits, extract_and_parse};
use kneebench_harness::params::{ParameterSet, ParamsError};

/// Reads the parameter set at `path` (if any) and checks it against the FMU at `fmu`; a set
/// refused is a usage error ([`set_error`]).
pub fn read_set_for(path: Option<&Path>, fmu: &Path) -> anyhow::Result<Option<ParameterSet>> {
    let Some(path) = path else { return Ok(None) };
    let (_dir, md) = extract_and_parse(fmu, &ArchiveLimits::default())
        .with_context(|| format!("reading {}", fmu.display()))?;
    Ok(Some(ParameterSet::read_for(path, &md).map_err(set_error)?))
}

/// A `--params SET.ssv` refused as a usage error (exit code 2) naming the option, the file and
/// the line: a file that cannot be read or is malformed, a value that is not finite, a name
/// the FMU has no parameter for, a unit other than the declared one, a value outside the
/// declared `[min, max]` or none of the items ([`ParameterSet::check`]), a component the
/// system does not have ([`ParamsError::NoComponent`]). Other errors (the system refused a
/// value, [`ParamsError::Target`]) as they are.
pub fn set_error(e: ParamsError) -> anyhow::Error {
    match e {
        e @ (ParamsError::Io { .. }
        | ParamsError::Syntax { .. }
        | ParamsError::Invalid { .. }
        | ParamsError::NoComponent { .. }) => super::Usage(format!("--params {e}")).into(),
        e => e.into(),
    }
}

/// Appends "Parameter set: name vN (sha256 ...)" to a Markdown section.
pub fn append_set_line(markdown: &Path, set: &ParameterSet) -> anyhow::Result<()> {
    use std::io::Write;
    let mut f = std::fs::OpenOptions::new()
        .append(true)
        .open(markdown)
        .with_context(|| format!("opening {}", markdown.display()))?;
    writeln!(f, "\nParameter set: {}", set.label())
        .with_context(|| format!("writing {}", markdown.display()))?;
    Ok(())
}

/// Arguments of `kneebench identify`.
#[derive(Debug, clap::Args)]
#[command(after_help = "\
Examples:
  K=kneebench F=out/fmus
  $K experiment bode --fmu $F/BenchHardware.fmu --out logs/test --stages 4 --dwell 6 --ratio 2 --start-frequency 0.4
  $K experiment bode --fmu $F/BenchHardware.fmu --out logs/load --input load --amplitude 5 --stages 4 --dwell 6 --ratio 2 --start-frequency 0.4
  $K identify logs/test/bode.csv logs/load/bode.csv --fmu $F/BenchPlant.fmu --out out/identify
  $K study --fmus $F --params out/identify/identified.ssv --out out/study-identified
  $K identify --defaults --fmu $F/BenchPlant.fmu --out out/params   # the bench facts as .ssv

Fits the plant's parameters to logs of the bench's experiments (the CSV or Parquet files
`kneebench experiment` writes; a .parquet extension reads Parquet): linear least squares on the smoothed encoder signals (inertias, viscous and Coulomb
friction per side, spring stiffness, motor torque constants; resistance, inductance and
back-emf constant where the driver's voltage is logged; the transducer's torque offset), then
an output-error refinement that re-runs the plant FMU over the logged currents. A log with
the bench's clock at each sample (plant.benchSampleTime: every experiment on BenchHardware
logs it) is first resampled onto a uniform grid of that clock, as a master that fell behind
its schedule logged its rows at the schedule's times; the report notes it. Writes
<out>/<name>.ssv (the prior set with every identified value replaced), <out>/identify.md
(estimates with 95 % intervals, residuals, correlations, what is not identifiable and which
experiment to add) and the measured-vs-twin figure identify-fit.png/.svg.")]
pub struct Args {
    /// Experiment logs (CSV, or Parquet by the .parquet extension).
    pub logs: Vec<std::path::PathBuf>,
    /// The plant FMU (BenchPlant.fmu): its parameters are the prior, the refinement runs it.
    #[arg(long)]
    pub fmu: std::path::PathBuf,
    /// Output directory.
    #[arg(long, default_value = "out/identify")]
    pub out: std::path::PathBuf,
    /// A prior parameter set (.ssv) instead of the FMU's defaults.
    #[arg(long = "params", value_name = "SET.ssv")]
    pub prior: Option<std::path::PathBuf>,
    /// A plant parameter as the logs were recorded, NAME=VALUE (configuration, frictionModel,
    /// ...), for the refinement's simulation (repeatable).
    #[arg(long = "param", value_name = "NAME=VALUE")]
    pub params: Vec<String>,
    /// Name of the written set.
    #[arg(long, default_value = "identified")]
    pub name: String,
    /// Version of the written set.
    #[arg(long = "set-version", default_value = "1")]
    pub set_version: String,
    /// Skip the output-error refinement (linear least squares only).
    #[arg(long)]
    pub no_refine: bool,
    /// Seconds of each log the refinement simulates.
    #[arg(long, default_value_t = 6.0, value_parser = super::values::positive)]
    pub refine_seconds: f64,
    /// Half width of the smoothing window (samples).
    #[arg(long, default_value_t = 25, value_parser = window)]
    pub window: usize,
    /// Half width (samples) of the smoothing of the logged currents fed to the refinement's
    /// simulation.
    #[arg(long, default_value_t = 75, value_parser = window)]
    pub drive_window: usize,
    /// Half width of the smoothing window of the loss surface's regression (samples; logs
    /// recorded with frictionModel = HdLossSurface).
    #[arg(long, default_value_t = 12, value_parser = window)]
    pub surface_window: usize,
    /// Write the FMU's default parameter set (the bench facts) as OUT/NAME.ssv and stop.
    #[arg(long)]
    pub defaults: bool,
}

/// The parser of the smoothing windows' half widths: at least 2 samples (a half width of 0 or
/// 1 leaves nothing to smooth and the derivatives as noisy as the encoder's steps).
fn window(text: &str) -> Result<usize, String> {
    match text.trim().parse::<usize>() {
        Ok(n) if n >= 2 => Ok(n),
        Ok(n) => Err(format!("{n} is below 2 samples")),
        Err(_) => Err(format!("'{text}' is not a whole number of samples")),
    }
}

/// Runs `kneebench identify`.
pub fn run(a: Args) -> anyhow::Result<i32> {
    use kneebench_harness::identify::{
        IdentifyConfig, IdentifyError, Status, identify, write_outputs,
    };
    // The set is written as OUT/NAME.ssv: a name with a path in it wrote outside OUT.
    let plain = std::path::Path::new(&a.name)
        .file_name()
        .is_some_and(|f| f == a.name.as_str());
    if !plain || a.name.contains(['/', '\\', '\0']) {
        eprintln!(
            "error: --name '{}' must be a plain file name (the set is written as OUT/NAME.ssv)",
            a.name
        );
        return Ok(super::EXIT_USAGE);
    }
    if a.defaults {
        let (_dir, md) = extract_and_parse(&a.fmu, &ArchiveLimits::default())
            .with_context(|| format!("reading {}", a.fmu.display()))?;
        let name = if a.name == "identified" {
            "bench-facts"
        } else {
            a.name.as_str()
        };
        let set = ParameterSet::defaults_of(&md, name, &a.set_version);
        std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
        let path = a.out.join(format!("{name}.ssv"));
        set.write_file(&path)?;
        println!("written: {} ({})", path.display(), set.label());
        return Ok(super::EXIT_OK);
    }
    if a.logs.is_empty() {
        return Err(super::Usage(
            "no log given (kneebench identify LOG.csv ... --fmu BenchPlant.fmu)".into(),
        )
        .into());
    }
    let prior = read_set_for(a.prior.as_deref(), &a.fmu)?;
    let plant_parameters = a
        .params
        .iter()
        .map(|p| super::name_value(p))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let config = IdentifyConfig {
        window: a.window,
        drive_window: a.drive_window,
        surface_window: a.surface_window,
        refine: !a.no_refine,
        refine_seconds: a.refine_seconds,
        plant_parameters,
        name: a.name.clone(),
        version: a.set_version.clone(),
        ..IdentifyConfig::default()
    };
    // The --param names and values are checked as the FMU is loaded, before the logs are read
    // or anything is fitted (with --no-refine too).
    let id = match identify(&a.logs, &a.fmu, prior.as_ref(), &config) {
        Ok(id) => id,
        Err(IdentifyError::Parameter(problem)) => {
            eprintln!("error: --param: {problem}");
            return Ok(super::EXIT_USAGE);
        }
        Err(e) => return Err(e.into()),
    };
    for e in &id.estimates {
        let (mut v, mut ci) = e.value();
        let status = match &e.status {
            Status::Identified => String::new(),
            Status::NotIdentifiable(why) => {
                // The written set keeps the prior.
                (v, ci) = (e.prior, f64::NAN);
                format!("  NOT IDENTIFIABLE (prior kept): {why}")
            }
            Status::Conditional(why) => format!("  CONDITIONAL (written): {why}"),
        };
        println!(
            "{:32} {:>12.6} +- {:<10.4} {}{status}",
            e.quantity.parameter.unwrap_or(e.quantity.label),
            v,
            ci,
            e.quantity.unit
        );
    }
    for n in &id.notes {
        println!("note: {n}");
    }
    for f in write_outputs(&id, &a.out)? {
        println!("written: {}", f.display());
    }
    println!("set: {}", id.set.label());
    println!("identification took {:.2} s", id.seconds);
    Ok(super::EXIT_OK)
}
