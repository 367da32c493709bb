//! `kneebench study`: the DA/SEA/CSEA gait study (the main job).

use std::path::{Path, PathBuf};

use kneebench_harness::bench_protocol::Key;
use kneebench_harness::master::Value;
use kneebench_harness::params::ParamsError;
use kneebench_harness::study::{
    Actuator, BenchLink, CheckedStudy, ScenarioSection, StudyConfig, StudyError, StudyScenario,
    plot_study, run_checked, runs_markdown, write_report,
};

/// Arguments of `kneebench study`.
#[derive(Debug, clap::Args)]
#[command(after_help = "\
Examples:
  kneebench export --out out/fmus && kneebench study --fmus out/fmus --out out/study
  kneebench study --fmus out/fmus --out out/clutch --scenario bench-clutch
  kneebench study --fmus out/fmus --out out/big --scenario bench-full --scale 1.7 --actuators sea   # trips an interlock: exit code 3
On the bench (or the emulator: kneebench emulate --key bench.key --param configuration=1), the same
schedule through BenchHardware, one actuator, in real time:
  kneebench study --fmus out/fmus --out out/bench --scenario bench-full --actuators sea \\
      --bench 192.168.1.20:47000 --key bench.key

Scenarios, each run as on the bench for one of its published tables (gait 2.5 s, peak external
torque 9 N m):
  bench-full    DA, SEA and CSEA at 60 deg (Tables 13 and 14); DA and SEA under position
                control, CSEA under impedance control with its clutch by low speed
  bench-clutch  SEA and CSEA at 50 deg, both under impedance control, the CSEA's clutch locked
                in stance (Table 15)
Each run is GaitReference -> test-motor controller -> test motor, ground-reaction reference ->
torque loop -> load motor, written as an SSP file (<out>/scenarios/*.ssp) that this tool, fmpy
and other SSP tools can run. The first cycle is the start-up and is not analysed. Written: one
CSV per run (every signal), per scenario a tracking, torque and power figure (PNG and SVG, the
last cycle) and report.md with the measured-vs-twin table.
Exit code 3 when an interlock ended a run (the report names it); 1 when a run failed (an FMU's
error: report.md says why, and has no results for that run); 2 for bad arguments: a --param
that names no parameter of the scenario's FMUs, or whose value is not finite, outside the
parameter's [min, max] or none of its items, a --params set or --bench-param value refused
the same way, --bench without one actuator named (checked before anything runs).")]
pub struct Args {
    /// Directory of the exported FMUs (kneebench export).
    #[arg(long)]
    pub fmus: PathBuf,
    /// Output directory.
    #[arg(long, default_value = "out/study")]
    pub out: PathBuf,
    /// Scenarios to run (comma-separated: bench-full, bench-clutch, each at most once).
    #[arg(long, value_delimiter = ',', default_value = "bench-full,bench-clutch")]
    pub scenario: Vec<String>,
    /// Gait cycles per run, at least 2 (the first, the start-up, is not analysed).
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u32).range(1..))]
    pub cycles: u32,
    /// Multiplies the gait's angle and torque amplitudes.
    #[arg(long, default_value_t = 1.0, value_parser = super::values::positive)]
    pub scale: f64,
    /// Actuators to run (comma-separated: da, sea, csea, each at most once; default: each
    /// scenario's); a scenario with none of them is left out, with a note.
    #[arg(long, value_delimiter = ',')]
    pub actuators: Vec<String>,
    /// Set a scenario parameter, `component.name=value` (repeatable; a mode by its item name),
    /// e.g. `--param plant.actuationDamping=10` for another bench (the controllers stay
    /// built on the study's bench: report.md names each plant parameter they were not built
    /// for); checked against the FMUs (name, finite value inside [min, max], item) before
    /// anything runs.
    #[arg(long = "param", value_name = "NAME=VALUE")]
    pub params: Vec<String>,
    /// A parameter set (.ssv) for the plant (e.g. from `kneebench identify`): checked against
    /// BenchPlant.fmu, embedded in every scenario SSP, named in report.md; --param wins over it.
    #[arg(long = "params", value_name = "SET.ssv")]
    pub parameter_set: Option<PathBuf>,
    /// Run on a bench (or `kneebench emulate`) at host:port instead of the plant: the plant
    /// replaced by BenchHardware.fmu from --fmus, in real time; needs --key and one actuator.
    #[arg(long, value_name = "ADDRESS", requires = "key")]
    pub bench: Option<String>,
    /// The bench's key file (kneebench key new), with --bench.
    #[arg(long, value_name = "FILE", requires = "bench")]
    pub key: Option<PathBuf>,
    /// A BenchHardware parameter with --bench, NAME=VALUE (repeatable; a mode by its
    /// item name), e.g. --bench-param replyTimeout=0.005.
    #[arg(long = "bench-param", value_name = "NAME=VALUE", requires = "bench")]
    pub bench_params: Vec<String>,
}

/// Reads `--param component.name=value`: an Integer, a Real or a Boolean by its text, any other
/// text as a String (an item's name, e.g. `plant.frictionModel=HdLossSurface`). The value is
/// checked against the scenario's FMUs, and converted to the variable's type, before anything
/// runs ([`CheckedStudy::new`]).
fn parse_override(text: &str) -> anyhow::Result<(String, Value)> {
    let (name, value) = super::name_value(text)?;
    let value = value.as_str();
    let parsed = if let Ok(i) = value.parse::<i32>() {
        Value::Integer(i)
    } else if let Ok(x) = value.parse::<f64>() {
        Value::Real(x)
    } else if let Ok(b) = value.parse::<bool>() {
        Value::Boolean(b)
    } else {
        Value::String(value.to_string())
    };
    Ok((name, parsed))
}

/// The first item of `list` that an earlier one equals.
fn first_repeated<T: PartialEq>(list: &[T]) -> Option<&T> {
    list.iter()
        .enumerate()
        .find(|(k, x)| list[..*k].contains(x))
        .map(|(_, x)| x)
}

/// Runs `kneebench study`.
pub fn run(a: Args) -> anyhow::Result<i32> {
    let actuators = a
        .actuators
        .iter()
        .map(|s| match s.to_ascii_lowercase().as_str() {
            "da" => Ok(Actuator::Da),
            "sea" => Ok(Actuator::Sea),
            "csea" => Ok(Actuator::Csea),
            other => Err(super::Usage(format!(
                "--actuators: unknown actuator '{other}' (da, sea, csea)"
            ))),
        })
        .collect::<Result<Vec<_>, _>>()?;
    // One given twice would be merged (an actuator run once) or run twice (a scenario into the
    // same files): refused, as a list of names given twice is elsewhere.
    if let Some(twice) = first_repeated(&actuators) {
        return Err(super::Usage(format!("--actuators: {} is given twice", twice.name())).into());
    }
    let scenarios = a
        .scenario
        .iter()
        .map(|s| {
            StudyScenario::from_name(&s.to_ascii_lowercase()).ok_or_else(|| {
                super::Usage(format!(
                    "--scenario: unknown scenario '{s}' (bench-full, bench-clutch)"
                ))
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    if let Some(twice) = first_repeated(&scenarios) {
        return Err(super::Usage(format!("--scenario: {} is given twice", twice.name())).into());
    }
    let overrides = a
        .params
        .iter()
        .map(|p| parse_override(p))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let parameter_set = a
        .parameter_set
        .as_deref()
        .map(|path| {
            kneebench_harness::params::ParameterSet::read_file(path)
                .map_err(super::identify::set_error)
        })
        .transpose()?;
    let bench = match (&a.bench, &a.key) {
        (Some(address), Some(key)) => Some(BenchLink {
            address: address.clone(),
            key_file: key.clone(),
            parameters: a
                .bench_params
                .iter()
                .map(|p| super::name_value(p))
                .collect::<anyhow::Result<Vec<_>>>()?,
        }),
        _ => None,
    };
    // A scenario with none of the chosen actuators (--actuators da: bench-clutch has no DA)
    // is left out with a note; it wrote an empty section. None left is a usage error.
    let names = |list: &[Actuator]| list.iter().map(|a| a.name()).collect::<Vec<_>>().join(", ");
    let (scenarios, without): (Vec<StudyScenario>, Vec<StudyScenario>) = scenarios
        .into_iter()
        .partition(|s| actuators.is_empty() || s.actuators().iter().any(|a| actuators.contains(a)));
    for s in &without {
        eprintln!(
            "note: the {} scenario has none of {} (its actuators: {}): left out",
            s.name(),
            names(&actuators),
            names(s.actuators())
        );
    }
    if scenarios.is_empty() {
        return Err(super::Usage(format!(
            "--actuators {}: no chosen scenario has them",
            names(&actuators)
        ))
        .into());
    }
    let configs: Vec<StudyConfig> = scenarios
        .into_iter()
        .map(|scenario| StudyConfig {
            fmu_dir: a.fmus.clone(),
            out_dir: a.out.clone(),
            scenario,
            cycles: a.cycles,
            scale: a.scale,
            gains: None,
            actuators: actuators.clone(),
            overrides: overrides.clone(),
            parameter_set: parameter_set.clone(),
            bench: bench.clone(),
        })
        .collect();
    // Every scenario's settings (one actuator on a bench, the --params set, the --param and
    // --bench-param values) are checked before the first run (a later scenario's were found
    // only after the earlier ones had run; a bench study of several actuators, a set's values
    // only as its first run began, a --bench-param's when the bench refused it). Each is run
    // as checked here, not checked again.
    let mut checked = Vec::new();
    for config in &configs {
        checked.push(CheckedStudy::new(config).map_err(|e| match e {
            StudyError::BenchActuators { .. } => super::Usage(format!("--bench: {e}")).into(),
            StudyError::Cycles(_) => super::Usage(format!("--cycles: {e}")).into(),
            StudyError::Parameter(m) => super::Usage(format!("--param {m}")).into(),
            StudyError::ParameterSet(ParamsError::Invalid { line, problem, .. }) => {
                let file = a.parameter_set.as_deref().unwrap_or(Path::new("SET.ssv"));
                super::Usage(format!("--params {}:{line}: {problem}", file.display())).into()
            }
            StudyError::BenchParameter(m) => super::Usage(format!("--bench-param {m}")).into(),
            e => anyhow::Error::from(e),
        })?);
    }
    // The bench's key file, read as the bench link will read it: a file it would refuse (one
    // others may read, a key that is no secret, none at all) is a usage error, as for `emulate
    // --key`, before anything runs (each run failed on it, exit code 1, after the scenario
    // and its report were written).
    if let Some(key) = a.bench.as_ref().and(a.key.as_ref()) {
        Key::load_file(key).map_err(|e| super::Usage(format!("--key {e}")))?;
    }
    let mut all = Vec::new();
    for study in &checked {
        let runs = run_checked(study, None)?;
        let figures = plot_study(&runs, &a.out)?;
        all.push((study.config().scenario, runs, figures));
    }
    let sections: Vec<ScenarioSection<'_>> = all
        .iter()
        .map(|(scenario, runs, figures)| ScenarioSection {
            scenario: *scenario,
            runs,
            figures,
        })
        .collect();
    let command = std::env::args().collect::<Vec<_>>().join(" ");
    let report = write_report(&a.out, &sections, &command)?;
    let (mut tripped, mut failed) = (false, Vec::new());
    for (scenario, runs, figures) in &all {
        tripped |= runs
            .iter()
            .any(|r| r.failure().is_none() && r.report.trip.is_some());
        failed.extend(
            runs.iter()
                .filter(|r| r.failure().is_some())
                .map(|r| format!("{} {}", scenario.name(), r.report.name)),
        );
        println!("## {}\n\n{}", scenario.name(), runs_markdown(runs));
        for r in runs {
            println!("results: {}", r.csv.display());
        }
        for f in figures {
            println!("figure:  {}", f.png.display());
        }
        println!();
    }
    println!("report:  {}", report.display());
    Ok(if !failed.is_empty() {
        eprintln!(
            "error: {} run(s) failed ({}): see {}",
            failed.len(),
            failed.join(", "),
            report.display()
        );
        super::EXIT_ERROR
    } else if tripped {
        super::EXIT_TERMINATED
    } else {
        super::EXIT_OK
    })
}
