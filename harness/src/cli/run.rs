//! `kneebench run`.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context;
use kneebench_harness::instance::{LogStatus, stderr_log_handler};
use kneebench_harness::master::{Signal, VarType};
use kneebench_harness::num::Num;
use kneebench_harness::results::csv::CsvFile;
use kneebench_harness::results::{RunningSummary, Tee, summary_table};
use kneebench_harness::{
    Algorithm, Fmu, InstanceOptions, LoadOptions, MasterError, Outcome, Results, RunConfig,
    RunControl, StopReason, System, ssp,
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
  kneebench run out/fmus/GaitReference.fmu --stop-time 5 --step 0.001 --output gait.csv
  kneebench run out/fmus/GaitReference.fmu --stop-time 5 --output knee.csv --variables kneeAngleReference,gaitPhase
  kneebench run out/study/scenarios/SEA.ssp --stop-time 2.5 --output sea.csv --timeout 600
  printf 'time,setpoint,measurement\\n0,0,0\\n0.1,1,0\\n' > steps.csv
  kneebench run out/fmus/PidController.fmu --inputs steps.csv --param kp=120 --param ki=3 --output pid.csv

Time is an integer count of nanoseconds: the step must be a whole number of ns and the stop
time on the grid (stop - start a multiple of the step); otherwise it is a usage error. With
--inputs, each CSV column named like an input of the FMU feeds it (first column: time,
strictly increasing; every value finite); Real continuous inputs are interpolated linearly,
others hold the last sample. Each row of the results is recorded after every component
finished the step that ends at its time, before inputs for the next step are set. --param
takes `var=value` for a single FMU, `component.var=value` for a system.

Results are streamed to OUTPUT.partial (flushed at least every second) and renamed to OUTPUT
when the run completes or an FMU ends it; a run that fails or is stopped keeps its rows in
OUTPUT.partial and leaves an earlier OUTPUT untouched. SIGINT, SIGTERM and SIGHUP stop the run
at the next communication point (a second SIGINT/SIGTERM ends the process at once).

Exit codes:
  0    completed; OUTPUT written
  1    error (an FMU failed, a non-finite output, an I/O error); rows so far in OUTPUT.partial
  2    usage error (bad arguments, stop time off the step grid, unusable --inputs file, an
       FMU that `kneebench validate` rejects, without --force)
  3    an FMU ended the run (fmi2Discard + fmi2Terminated); OUTPUT written up to and
       including its last successful time
  4    --timeout passed; rows so far in OUTPUT.partial
  129  stopped by SIGHUP, 130 by SIGINT, 143 by SIGTERM; rows so far in OUTPUT.partial")]
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
    /// Results CSV to write (streamed to OUTPUT.partial, renamed at the end).
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
    /// Keep every N-th row only.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    pub record_every: u64,
    /// Step independent FMUs in parallel threads, spawned per step (tens of microseconds per
    /// step: only for FMUs whose steps take milliseconds). The results are identical to the
    /// sequential run's.
    #[arg(long)]
    pub parallel: bool,
    /// Wall-time limit of the whole run in seconds: past it, the run stops at the next
    /// communication point (exit code 4).
    #[arg(long, value_name = "SECONDS", value_parser = parse_timeout)]
    pub timeout: Option<Duration>,
    /// Record NaN and infinite outputs instead of failing the run.
    #[arg(long)]
    pub allow_nonfinite: bool,
    /// Run FMUs that `kneebench validate` rejects (model description or binary problems).
    #[arg(long)]
    pub force: bool,
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

/// Parses `--timeout`: a positive, finite number of seconds.
fn parse_timeout(text: &str) -> Result<Duration, String> {
    let s: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("'{text}' is not a number of seconds"))?;
    if !(s.is_finite() && s > 0.0) {
        return Err(format!("{s} must be a positive, finite number of seconds"));
    }
    Duration::try_from_secs_f64(s).map_err(|e| format!("{s} s: {e}"))
}

/// A usage error: printed, exit code 2.
fn usage(message: impl std::fmt::Display) -> anyhow::Result<i32> {
    eprintln!("error: {message}");
    Ok(super::EXIT_USAGE)
}

/// Runs `kneebench run`.
pub fn run(a: Args) -> anyhow::Result<i32> {
    // Stop requests (signals) are honoured from the start; until the run begins they end the
    // command at its next check.
    let control = RunControl::new();
    control
        .stop_on_signals()
        .context("installing the signal handlers")?;
    let ext = a
        .system
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    if !matches!(ext.as_str(), "ssp" | "ssd" | "fmu") {
        return usage(format_args!(
            "{}: expected an .ssp, .ssd or .fmu file",
            a.system.display()
        ));
    }
    if a.inputs.is_some() && ext != "fmu" {
        return usage("--inputs is for a single FMU; connect inputs in the system instead");
    }
    // The output is checked (and its partial file created) before anything is loaded.
    let file = CsvFile::create(&a.output)?;
    let mut guard = PartialGuard(Some(file.partial_path().to_path_buf()));
    let load = LoadOptions {
        preload: a.preload.clone(),
        ..LoadOptions::default()
    };
    let (mut system, mut config) = match ext.as_str() {
        "fmu" => {
            let fmu = Fmu::load(&a.system, &load)?;
            match single_fmu(&a, fmu)? {
                Ok(x) => x,
                Err(message) => return usage(message),
            }
        }
        _ => {
            let loaded = ssp::load_system(&a.system, &load)?;
            (loaded.system, loaded.config)
        }
    };
    if !a.force {
        let mut problems = Vec::new();
        for (name, fmu) in system.components() {
            for p in super::validate::description_problems(fmu.model_description())
                .into_iter()
                .chain(super::validate::binary_problems(fmu))
            {
                problems.push(format!("{name}: {p}"));
            }
        }
        if !problems.is_empty() {
            for p in &problems {
                eprintln!("problem: {p}");
            }
            return usage(format_args!(
                "{} problem(s) that `kneebench validate` reports; fix the FMU or pass --force",
                problems.len()
            ));
        }
    }
    let single = ext == "fmu";
    let first = system_component(&system);
    let prefix = |name: &str| {
        if single {
            format!("{first}.{name}")
        } else {
            name.to_string()
        }
    };
    for p in &a.params {
        let Some((name, value)) = p.split_once('=') else {
            return usage(format_args!("--param '{p}': expected NAME=VALUE"));
        };
        if let Err(e) = system.set_value_str(&prefix(name.trim()), value.trim()) {
            return usage(format_args!("--param '{p}': {e}"));
        }
    }
    if !a.variables.is_empty() {
        let refs: Vec<String> = a.variables.iter().map(|v| prefix(v.trim())).collect();
        let refs: Vec<&str> = refs.iter().map(String::as_str).collect();
        if let Err(e) = system.record(&refs) {
            return usage(format_args!("--variables: {e}"));
        }
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
    config.record_every = a.record_every;
    config.timeout = a.timeout;
    config.allow_nonfinite = a.allow_nonfinite;
    config.control = Some(control.clone());
    let grid = match system.check_config(&config) {
        Ok(g) => g,
        Err(e @ (MasterError::Grid(_) | MasterError::StepOverflow { .. })) => return usage(e),
        Err(e) => return Err(e.into()),
    };
    system.set_instance_options(InstanceOptions {
        log_handler: Some(stderr_log_handler(if a.verbose {
            LogStatus::Ok
        } else {
            LogStatus::Warning
        })),
        logging_on: a.verbose,
        ..InstanceOptions::default()
    });

    let bar = if std::io::stderr().is_terminal() && grid.n_steps >= 10_000 {
        let pb = indicatif::ProgressBar::new(grid.n_steps);
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
    let mut sink = Tee(file, RunningSummary::new());
    let summary = system.run_into(&config, &mut sink)?;
    if let Some(pb) = bar {
        pb.finish_and_clear();
    }
    let elapsed = started.elapsed().as_secs_f64();
    let Tee(file, table) = sink;
    let complete = matches!(
        summary.outcome,
        Outcome::Completed { .. } | Outcome::Terminated { .. }
    );
    let written = if complete {
        file.commit()?
    } else {
        file.keep_partial()?
    };
    guard.0 = None;
    if !a.quiet && summary.rows > 0 {
        println!("{}", summary_table(table.summaries()));
    }
    eprintln!(
        "{} {} rows to {} ({elapsed:.3} s wall time)",
        if complete { "wrote" } else { "kept" },
        summary.rows,
        written.display(),
    );
    Ok(match summary.outcome {
        Outcome::Completed { stop_time } => {
            eprintln!("completed at t = {}", Num(stop_time));
            super::EXIT_OK
        }
        Outcome::Terminated {
            component,
            last_successful_time,
            last_row_time,
            messages,
        } => {
            eprintln!(
                "ended by an FMU: component '{component}' terminated the simulation at t = {} (its last successful time); last row at t = {}",
                Num(last_successful_time),
                Num(last_row_time)
            );
            for m in messages {
                eprintln!("  {component}: {m}");
            }
            super::EXIT_TERMINATED
        }
        Outcome::Failed(MasterError::Stopped { reason, time }) => {
            eprintln!("stopped: {reason}; last row at t = {}", Num(time));
            match reason {
                StopReason::Timeout => super::EXIT_TIMEOUT,
                StopReason::Signal(n) => 128 + n,
                StopReason::Requested => super::EXIT_ERROR,
            }
        }
        Outcome::Failed(e) => {
            eprintln!("error: {e}");
            super::EXIT_ERROR
        }
    })
}

/// Removes the partial file of a run that never started (a setup error).
struct PartialGuard(Option<PathBuf>);

impl Drop for PartialGuard {
    fn drop(&mut self) {
        if let Some(p) = self.0.take() {
            let _ = std::fs::remove_file(p);
        }
    }
}

fn system_component(system: &System) -> String {
    system
        .component_names()
        .first()
        .map(|s| s.to_string())
        .unwrap_or_default()
}

/// A system of one FMU with its default experiment and `--inputs`; `Ok(Err(message))` for a
/// usage error (an unusable inputs file).
fn single_fmu(a: &Args, fmu: Fmu) -> anyhow::Result<Result<(System, RunConfig), String>> {
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
        let csv = match Results::read_csv_file(path).and_then(|c| {
            c.check_series(path)?;
            Ok(c)
        }) {
            Ok(c) => c,
            Err(e) => return Ok(Err(format!("--inputs: {e}"))),
        };
        let times = csv.times();
        for col in csv.names() {
            let Some(v) = md.model_variables.iter().find(|v| &v.name == col) else {
                return Ok(Err(format!(
                    "--inputs {}: column '{col}' is not a variable of the FMU",
                    path.display()
                )));
            };
            if v.causality != Some(Causality::Input) {
                return Ok(Err(format!(
                    "--inputs {}: column '{col}' is not an input of the FMU",
                    path.display()
                )));
            }
            let ty = VarType::of(v);
            let continuous = ty == VarType::Real
                && v.variability.unwrap_or(Variability::Continuous) == Variability::Continuous;
            let values = csv.column(col).unwrap_or_default();
            system.add_signal(
                &format!("{name}.{col}"),
                Signal {
                    times: times.clone(),
                    values,
                    interpolate: continuous,
                },
            )?;
        }
    }
    Ok(Ok((system, config)))
}
