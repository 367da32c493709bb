//! `kneebench run`.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context, bail};
use kneebench_harness::instance::{LogStatus, stderr_log_handler};
use kneebench_harness::master::{Signal, VarType};
use kneebench_harness::{
    Algorithm, Fmu, InstanceOptions, LoadOptions, Outcome, Results, RunConfig, System, ssp,
};
use model_description::{Causality, Variability};

/// The master algorithm, as a command-line value.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum AlgorithmArg {
    /// Sequential, in connection-dependency order; inputs from the freshest outputs.
    GaussSeidel,
    /// All inputs from the outputs at the start of the step.
    Jacobi,
}

/// Arguments of `kneebench run`.
#[derive(Debug, clap::Args)]
#[command(after_help = "\
Examples:
  kneebench run bench.ssp                                  # default experiment of the SSP
  kneebench run bench.ssd --stop-time 10 --step 0.001 --algorithm jacobi
  kneebench run GaitReference.fmu --stop-time 5 --output gait.csv --variables phase,angle
  kneebench run Controller.fmu --inputs inputs.csv --param kp=120 --param ki=3
  kneebench run PythonSlave.fmu --preload /usr/lib/x86_64-linux-gnu/libpython3.11.so.1.0

Time is an integer count of nanoseconds: the step must be a whole number of ns and the stop
time on the grid (stop - start a multiple of the step). With --inputs, each CSV column named
like an input of the FMU feeds it (first column: time); Real continuous inputs are
interpolated linearly, others hold the last sample. Each row of the results is recorded after
every component finished the step that ends at its time, before inputs for the next step are
set. --param takes `var=value` for a single FMU, `component.var=value` for a system.

Exit codes: 0 completed, 1 error (rows up to the failure are still written),
2 usage error, 3 ended early by an FMU (fmi2Discard + terminated).")]
pub struct Args {
    /// An SSP archive (.ssp), a bare SSD (.ssd) or a single FMU (.fmu).
    pub system: PathBuf,
    /// Start time in seconds (default: the default experiment's, or 0).
    #[arg(long)]
    pub start_time: Option<f64>,
    /// Stop time in seconds (default: the default experiment's, or 1).
    #[arg(long)]
    pub stop_time: Option<f64>,
    /// Base communication step in seconds (default: the default experiment's, or 0.001).
    #[arg(long)]
    pub step: Option<f64>,
    /// Master algorithm (default: the SSP's annotation, or gauss-seidel).
    #[arg(long, value_enum)]
    pub algorithm: Option<AlgorithmArg>,
    /// Results CSV to write.
    #[arg(long, short, default_value = "results.csv")]
    pub output: PathBuf,
    /// Comma-separated variables to record (default: every output). For a system:
    /// `component.variable`.
    #[arg(long, value_delimiter = ',')]
    pub variables: Vec<String>,
    /// Time-varying inputs for a single FMU: a CSV whose first column is time.
    #[arg(long)]
    pub inputs: Option<PathBuf>,
    /// Set a parameter or start value before initialization (repeatable).
    #[arg(long = "param", value_name = "NAME=VALUE")]
    pub params: Vec<String>,
    /// A parameter set (.ssv) to apply before the --param values: SET.ssv for a single FMU
    /// or the system's `plant`, COMPONENT=SET.ssv for another component (repeatable).
    #[arg(long = "params", value_name = "[COMPONENT=]SET.ssv")]
    pub parameter_sets: Vec<String>,
    /// Keep every N-th row only.
    #[arg(long, default_value_t = 1)]
    pub record_every: u64,
    /// Step independent FMUs in parallel threads, spawned per step (tens of microseconds per
    /// step: only for FMUs whose steps take milliseconds).
    #[arg(long)]
    pub parallel: bool,
    /// Shared libraries to load globally before the FMUs (host runtimes such as libpython).
    #[arg(long)]
    pub preload: Vec<PathBuf>,
    /// Print every FMU log message (default: warnings and errors).
    #[arg(long, short)]
    pub verbose: bool,
    /// Do not print the summary table.
    #[arg(long, short)]
    pub quiet: bool,
}

/// Runs `kneebench run`.
pub fn run(a: Args) -> anyhow::Result<i32> {
    let load = LoadOptions {
        preload: a.preload.clone(),
        ..LoadOptions::default()
    };
    let ext = a
        .system
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    let (mut system, mut config, ()) = match ext.as_str() {
        "ssp" | "ssd" => {
            if a.inputs.is_some() {
                bail!("--inputs is for a single FMU; connect inputs in the system instead");
            }
            let loaded = ssp::load_system(&a.system, &load)
                .with_context(|| format!("loading {}", a.system.display()))?;
            // Each FMU was extracted into its own directory: the SSP's can go.
            (loaded.system, loaded.config, ())
        }
        "fmu" => {
            let fmu = Fmu::load(&a.system, &load)
                .with_context(|| format!("loading {}", a.system.display()))?;
            single_fmu(&a, fmu)?
        }
        _ => bail!(
            "{}: expected an .ssp, .ssd or .fmu file",
            a.system.display()
        ),
    };
    let single = ext == "fmu";
    let first = system_component(&system);
    let prefix = |name: &str| {
        if single {
            format!("{first}.{name}")
        } else {
            name.to_string()
        }
    };
    for spec in &a.parameter_sets {
        let set = kneebench_harness::params::apply_spec(
            &mut system,
            &a.system,
            single.then_some(first.as_str()),
            spec,
        )?;
        eprintln!("parameter set: {}", set.label());
    }
    for p in &a.params {
        let (name, value) = p
            .split_once('=')
            .with_context(|| format!("--param '{p}': expected NAME=VALUE"))?;
        system.set_value_str(&prefix(name.trim()), value.trim())?;
    }
    if !a.variables.is_empty() {
        let refs: Vec<String> = a.variables.iter().map(|v| prefix(v.trim())).collect();
        let refs: Vec<&str> = refs.iter().map(String::as_str).collect();
        system.record(&refs)?;
    }
    if let Some(t) = a.start_time {
        config.start_time = t;
    }
    if let Some(t) = a.stop_time {
        config.stop_time = t;
    }
    if let Some(h) = a.step {
        config.step_size = h;
    }
    if let Some(alg) = a.algorithm {
        config.algorithm = match alg {
            AlgorithmArg::GaussSeidel => Algorithm::GaussSeidel,
            AlgorithmArg::Jacobi => Algorithm::Jacobi,
        };
    }
    config.parallel = a.parallel;
    config.record_every = a.record_every.max(1);
    system.set_instance_options(InstanceOptions {
        log_handler: Some(stderr_log_handler(if a.verbose {
            LogStatus::Ok
        } else {
            LogStatus::Warning
        })),
        logging_on: a.verbose,
        ..InstanceOptions::default()
    });

    let steps = ((config.stop_time - config.start_time) / config.step_size).round();
    let bar = if std::io::stderr().is_terminal() && steps >= 10_000.0 {
        let pb = indicatif::ProgressBar::new(steps as u64);
        pb.set_draw_target(indicatif::ProgressDrawTarget::stderr());
        if let Ok(style) = indicatif::ProgressStyle::with_template(
            "{elapsed_precise} [{bar:40}] {pos}/{len} steps ({eta} left)",
        ) {
            pb.set_style(style.progress_chars("=> "));
        }
        let pb2 = pb.clone();
        config.progress = Some(Arc::new(move |done, _total| pb2.set_position(done)));
        Some(pb)
    } else {
        None
    };
    let started = std::time::Instant::now();
    let out = system.run(&config)?;
    if let Some(pb) = bar {
        pb.finish_and_clear();
    }
    let elapsed = started.elapsed();
    out.results
        .write_csv_file(&a.output)
        .with_context(|| format!("writing {}", a.output.display()))?;
    if !a.quiet {
        println!("{}", out.results.summary_table());
    }
    eprintln!(
        "wrote {} rows to {} ({:.3} s wall time)",
        out.results.len(),
        a.output.display(),
        elapsed.as_secs_f64()
    );
    Ok(match out.outcome {
        Outcome::Completed { stop_time } => {
            eprintln!("completed at t = {stop_time}");
            super::EXIT_OK
        }
        Outcome::Terminated {
            component,
            last_successful_time,
            last_row_time,
            messages,
        } => {
            eprintln!(
                "ended early: component '{component}' terminated the simulation (last successful time {last_successful_time}); last row at t = {last_row_time}"
            );
            for m in messages {
                eprintln!("  {component}: {m}");
            }
            super::EXIT_TERMINATED
        }
        Outcome::Failed(e) => {
            eprintln!("error: {e}");
            eprintln!(
                "(the {} rows recorded before the failure were written)",
                out.results.len()
            );
            super::EXIT_ERROR
        }
    })
}

fn system_component(system: &System) -> String {
    system
        .component_names()
        .first()
        .map(|s| s.to_string())
        .unwrap_or_default()
}

fn single_fmu(a: &Args, fmu: Fmu) -> anyhow::Result<(System, RunConfig, ())> {
    let md = fmu.model_description().clone();
    let name = md
        .co_simulation
        .as_ref()
        .map(|c| c.model_identifier.clone())
        .unwrap_or_else(|| "fmu".into());
    let mut system = System::new();
    system.add_component(&name, fmu)?;
    system.set_column_prefix(false);
    let mut config = RunConfig::default();
    if let Some(d) = &md.default_experiment {
        if let Some(t) = d.start_time {
            config.start_time = t;
        }
        if let Some(t) = d.stop_time {
            config.stop_time = t;
        }
        if let Some(h) = d.step_size {
            config.step_size = h;
        }
        config.tolerance = d.tolerance;
    }
    if let Some(path) = &a.inputs {
        let csv = Results::read_csv_file(path)?;
        let times = csv.times();
        for col in csv.names() {
            let v = md
                .model_variables
                .iter()
                .find(|v| &v.name == col)
                .with_context(|| {
                    format!(
                        "{}: column '{col}' is not a variable of the FMU",
                        path.display()
                    )
                })?;
            if v.causality != Some(Causality::Input) {
                bail!(
                    "{}: column '{col}' is not an input of the FMU",
                    path.display()
                );
            }
            let ty = kneebench_harness::master::VarType::of(v);
            let continuous = ty == VarType::Real
                && v.variability.unwrap_or(Variability::Continuous) == Variability::Continuous;
            system.add_signal(
                &format!("{name}.{col}"),
                Signal {
                    times: times.clone(),
                    values: csv.column(col).expect("a column of the file"),
                    interpolate: continuous,
                },
            )?;
        }
    }
    Ok((system, config, ()))
}
