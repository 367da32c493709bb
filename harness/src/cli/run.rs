//! `kneebench run`.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context;
use kneebench_harness::instance::{LogStatus, stderr_log_handler};
use kneebench_harness::master::{Signal, VarType};
use kneebench_harness::params::check_system_start_value;
use kneebench_harness::results::csv::{check_output_path, partial_path};
use kneebench_harness::results::{RunningSummary, Tee, summary_table};
use kneebench_harness::{
    Algorithm, Fmu, InstanceOptions, Isolation, LoadOptions, MasterError, Outcome,
    PythonThreadState, Results, RunConfig, RunControl, StopReason, System, ssp,
};
use model_description::num::Num;
use model_description::{Causality, Variability};

/// The master algorithm, as a command-line value.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum AlgorithmArg {
    /// Sequential, in connection-dependency order; inputs from the freshest outputs.
    GaussSeidel,
    /// All inputs from the outputs at the start of the step.
    Jacobi,
}

/// The parser of `--isolate`: the names of [`Isolation::NAMED`], each listed in `--help` with
/// what it does (the library's table, which the Python package reads too).
fn isolation() -> impl clap::builder::TypedValueParser<Value = Isolation> {
    use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
    PossibleValuesParser::new(
        Isolation::NAMED.map(|(name, _, help)| PossibleValue::new(name).help(help)),
    )
    .try_map(|name| {
        Isolation::from_name(&name).ok_or_else(|| format!("'{name}': {}", Isolation::names_text()))
    })
}

/// How FMUs with an embedded Python get their Python thread state, as a command-line value
/// ([`PythonThreadState`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum PythonThreadStateArg {
    /// One per calling thread, kept while that thread's instances of the binary live.
    Kept,
    /// The binary's own behaviour: each FMI call makes one and destroys it again.
    PerCall,
}

/// Arguments of `kneebench run`.
#[derive(Debug, clap::Args)]
// A negative --start-time is valid: without this, `--start-time -1` was "unexpected argument".
#[command(allow_negative_numbers = true)]
#[command(after_help = "\
Examples:
  kneebench run out/fmus/GaitReference.fmu --stop-time 5 --step 0.001 --output gait.csv
  kneebench run out/fmus/GaitReference.fmu --stop-time 5 --output knee.csv --variables kneeAngleReference,gaitPhase
  kneebench run out/study/scenarios/SEA.ssp --stop-time 2.5 --output sea.csv --timeout 600
  kneebench run out/study/scenarios/SEA.ssp --replace plant=out/fmus/BenchHardware.fmu --param plant.backend=Simulated --param plant.pacing=None --stop-time 2.5 --output sea-hw.csv
  printf 'time,setpoint,measurement\\n0,0,0\\n0.099,0,0\\n0.1,1,0\\n' > steps.csv   # a step at 0.1 s
  kneebench run out/fmus/PidController.fmu --inputs steps.csv --param kp=120 --param ki=3 --output pid.csv

Time is an integer count of nanoseconds: the step must be a whole number of ns and the stop
time on the grid (stop - start a multiple of the step); otherwise it is a usage error. With
--inputs, each CSV column named like an input of the FMU feeds it (first column: time,
strictly increasing; every value finite); Real continuous inputs are interpolated linearly,
others hold the last sample (so a step needs a row just before it, as in steps.csv above:
without it the input ramps between the two rows). Each row of the results is recorded after every component
finished the step that ends at its time, before inputs for the next step are set. --param
takes `var=value` for a single FMU, `component.var=value` for a system.

Results are streamed to OUTPUT.partial (flushed at least every second) and renamed to OUTPUT
when the run completes or an FMU ends it; a run that fails or is stopped keeps its rows in
OUTPUT.partial and leaves an earlier OUTPUT untouched. An earlier run's OUTPUT.partial is
never overwritten: it is renamed OUTPUT.partial.1 (or the first free .partial.N). SIGINT, SIGTERM and SIGHUP stop the run
at the next communication point (a second SIGINT/SIGTERM ends the process at once). An FMU in
kneebench's process (--isolate never, or one of ours) that calls exit() ends the run with exit
code 1; one whose call never returns is ended 5 s after --timeout with exit code 4 (both keep
the rows flushed so far, up to about the last second's, in OUTPUT.partial).

Exit codes:
  0    completed; OUTPUT written
  1    error (an FMU failed or, in process, called exit(); a non-finite output, an I/O
       error); rows so far in OUTPUT.partial
  2    usage error (bad arguments, stop time off the step grid, unusable --inputs file, an
       FMU that `kneebench validate` rejects, without --force)
  3    an FMU ended the run (fmi2Discard + fmi2Terminated); OUTPUT written up to and
       including its last successful time
  4    --timeout passed (or an in-process call still running 5 s after it); rows so far in
       OUTPUT.partial
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
    /// Results file to write: CSV, or Parquet for `.parquet` (streamed to OUTPUT.partial,
    /// renamed at the end).
    #[arg(long, short, default_value = "results.csv")]
    pub output: PathBuf,
    /// Comma-separated variables to record (default: every output). For a system:
    /// `component.variable`.
    #[arg(long, value_delimiter = ',')]
    pub variables: Vec<String>,
    /// Time-varying inputs for a single FMU: a CSV whose first column is time (or a Parquet
    /// file with a `time` column).
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
    /// Hand every row to the kernel as it is recorded (CSV output only) instead of at least
    /// once a second: a kneebench killed at any instant (even SIGKILL) leaves every row it
    /// recorded in OUTPUT.partial. For runs on the bench (one write per row; 1 kHz costs
    /// little against the period).
    #[arg(long)]
    pub flush_every_row: bool,
    /// Shared libraries to load globally before the FMUs (host runtimes such as libpython).
    #[arg(long)]
    pub preload: Vec<PathBuf>,
    /// Run a system with a component's FMU replaced, `COMPONENT=FMU` (repeatable), e.g.
    /// `--replace plant=out/fmus/BenchHardware.fmu` to run the same schedule on the bench. The
    /// FMU must offer every connector of the component with the same causality and type.
    #[arg(long, value_name = "COMPONENT=FMU")]
    pub replace: Vec<String>,
    /// Run each FMU instance in a process of its own, so that a crash, exit() or hang of the
    /// FMU is an error of the run (rows so far kept) instead of the end of kneebench: `auto`
    /// for FMUs not generated by kneebench (about 2.5-13 us more per FMU and step), `always`,
    /// or `never`.
    #[arg(long, default_value = "auto", value_parser = isolation())]
    pub isolate: Isolation,
    /// FMUs with an embedded Python (PythonFMU exports): `kept` gives each thread that calls
    /// one a Python thread state kept between calls (about ten times cheaper per call),
    /// `per-call` leaves the binary to make one in every call, as it does by itself. Other
    /// FMUs are not affected.
    #[arg(long, value_enum, default_value = "kept")]
    pub python_thread_state: PythonThreadStateArg,
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
    let load = LoadOptions {
        preload: a.preload.clone(),
        isolation: a.isolate,
        python_thread_state: match a.python_thread_state {
            PythonThreadStateArg::Kept => PythonThreadState::Kept,
            PythonThreadStateArg::PerCall => PythonThreadState::PerCall,
        },
        ..LoadOptions::default()
    };
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
    if !a.replace.is_empty() && ext == "fmu" {
        return usage("--replace is for a system (.ssp, .ssd): it swaps a component's FMU");
    }
    if a.inputs.is_some() && ext != "fmu" {
        return usage("--inputs is for a single FMU; connect inputs in the system instead");
    }
    // The output is checked (and its partial file created) before anything is loaded.
    let named_files: Vec<PathBuf> = a
        .parameter_sets
        .iter()
        .chain(&a.replace)
        .map(|s| PathBuf::from(s.split_once('=').map_or(s.as_str(), |(_, file)| file)))
        .collect();
    let mut inputs: Vec<&Path> = vec![a.system.as_path()];
    inputs.extend(a.inputs.as_deref());
    inputs.extend(named_files.iter().map(PathBuf::as_path));
    if let Some(message) = super::output_replaces_input(&a.output, &inputs) {
        return usage(message);
    }
    if a.flush_every_row
        && a.output
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("parquet"))
    {
        return usage("--flush-every-row needs a CSV output (Parquet writes row groups)");
    }
    // The output is checked here, before anything is loaded; its partial file is created (an
    // earlier run's set aside) only once every argument has been accepted, so that a usage
    // error changes no file.
    check_output_path(&a.output)?;
    // From here on an FMU in this process that calls exit() (even while its binary is loaded)
    // or, with --timeout, never returns is reported (exit code 1 or 4) instead of ending
    // kneebench silently; disarmed when this function returns.
    let mut armed = super::last_resort::arm(&partial_path(&a.output));
    let (mut system, config) = match ext.as_str() {
        "fmu" => {
            let fmu = Fmu::load(&a.system, &load)?;
            match single_fmu(&a, fmu)? {
                Ok(x) => x,
                Err(message) => return usage(message),
            }
        }
        _ => {
            let mut replacements = Vec::new();
            for r in &a.replace {
                match r.split_once('=') {
                    Some((c, f)) if !c.trim().is_empty() && !f.trim().is_empty() => {
                        replacements.push((c.trim().to_string(), PathBuf::from(f.trim())))
                    }
                    _ => return usage(format_args!("--replace '{r}': expected COMPONENT=FMU")),
                }
            }
            let loaded = ssp::load_system_replacing(&a.system, &load, &replacements)?;
            if !loaded.unapplied.is_empty() {
                eprintln!(
                    "note: {} parameter value(s) of the system not applied: the replacement has no such variables ({})",
                    loaded.unapplied.len(),
                    loaded.unapplied.join(", ")
                );
            }
            (loaded.system, loaded.config)
        }
    };
    if !a.force {
        let mut problems = Vec::new();
        for (name, fmu) in system.components() {
            for p in kneebench_harness::conformance::description_problems(fmu.model_description())
                .into_iter()
                .chain(kneebench_harness::conformance::binary_problems(fmu))
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
    let mut set_labels = Vec::new();
    for spec in &a.parameter_sets {
        let set = kneebench_harness::params::apply_spec(
            &mut system,
            &a.system,
            single.then_some(first.as_str()),
            spec,
        )
        .map_err(super::identify::set_error)?;
        eprintln!("parameter set: {}", set.label());
        set_labels.push(set.label());
    }
    for p in &a.params {
        let (name, value) = match super::name_value(p) {
            Ok(pair) => pair,
            Err(e) => return usage(e),
        };
        let reference = prefix(&name);
        let parsed = match system.parse_value_str(&reference, &value) {
            Ok(parsed) => parsed,
            Err(e) => return usage(format_args!("--param '{p}': {e}")),
        };
        if let Err(problem) = check_system_start_value(&system, &reference, &parsed) {
            return usage(format_args!("--param '{p}': {problem}"));
        }
        if let Err(e) = system.set_value(&reference, parsed) {
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
    let mut config = config.with_times(a.start_time, a.stop_time, a.step);
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
    let mut file = match super::output::OutputFile::create(&a.output)? {
        super::output::OutputFile::Csv(f) => {
            super::output::OutputFile::Csv(f.write_through(a.flush_every_row))
        }
        parquet => parquet,
    };
    let mut guard = PartialGuard(Some(file.partial_path().to_path_buf()));
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
    // Parquet keeps the run's metadata: system, parameters, FMU GUIDs (and the version).
    let mut meta = vec![(
        "kneebench.system".to_string(),
        a.system.display().to_string(),
    )];
    meta.push(("kneebench.parameter_sets".into(), set_labels.join(";")));
    meta.push(("kneebench.parameters".into(), parameters_json(&a.params)));
    for (name, fmu) in system.components() {
        meta.push((
            format!("kneebench.guid.{name}"),
            fmu.model_description().guid.clone(),
        ));
    }
    file.set_metadata(meta);
    let started = std::time::Instant::now();
    // The last-resort watchdog is for calls in this process: an isolated FMU's hung call is
    // ended by its host's own call timeout, with the right message.
    if let Some(timeout) = a.timeout
        && system.components().any(|(_, fmu)| !fmu.is_isolated())
    {
        armed
            .watch(timeout)
            .context("starting the --timeout watchdog")?;
    }
    // The summary table is printed unless --quiet: only then is it kept.
    let mut sink = Tee(file, (!a.quiet).then(RunningSummary::new));
    let summary = system.run_into(&config, &mut sink);
    // Unloaded while still armed: an FMU whose unloading calls exit() is reported too.
    drop(system);
    drop(armed);
    // A run that recorded rows keeps its partial file whatever fails from here on (the run,
    // the commit's sync or rename, keep_partial): only a run that never started removes it.
    if sink.0.rows() > 0 {
        guard.0 = None;
    }
    let summary = summary?;
    if let Some(pb) = bar {
        pb.finish_and_clear();
    }
    let elapsed = started.elapsed().as_secs_f64();
    let Tee(file, table) = sink;
    let complete = matches!(
        summary.outcome,
        Outcome::Completed { .. } | Outcome::Terminated { .. }
    );
    if !complete && summary.rows == 0 {
        // Nothing was recorded (an FMU refused its values at the start, say): no partial
        // file is left behind for a later run to set aside; the guard removes it.
        drop(file);
        eprintln!(
            "recorded no rows: {} removed",
            partial_path(&a.output).display()
        );
        return Ok(report_outcome(summary.outcome));
    }
    let written = if complete {
        file.commit()?
    } else {
        file.keep_partial()?
    };
    guard.0 = None;
    if let Some(table) = table
        && summary.rows > 0
    {
        println!("{}", summary_table(&table.summaries()));
    }
    eprintln!(
        "{} {} rows to {} ({elapsed:.3} s wall time)",
        if complete { "wrote" } else { "kept" },
        summary.rows,
        written.display(),
    );
    Ok(report_outcome(summary.outcome))
}

/// Prints how the run ended and gives the exit code (0 completed, 3 ended by an FMU, 4 the
/// timeout, 128 + N a signal, 1 an error).
fn report_outcome(outcome: Outcome) -> i32 {
    match outcome {
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
    }
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
    let config = RunConfig::of_fmu(&md);
    if let Some(path) = &a.inputs {
        let csv = match Results::read_file(path).and_then(|c| {
            c.check_series(path)?;
            Ok(c)
        }) {
            Ok(c) => c,
            Err(e) => return Ok(Err(format!("--inputs: {e}"))),
        };
        let times = csv.times();
        for (k, col) in csv.names().iter().enumerate() {
            if csv.names()[..k].contains(col) {
                return Ok(Err(format!(
                    "--inputs {}: column '{col}' appears twice",
                    path.display()
                )));
            }
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

/// The `--param NAME=VALUE` list as the Parquet metadata's `kneebench.parameters`: a JSON
/// object of each name to its value's text as given, trimmed (`{"gaitPeriod":"1.25"}`; `{}`
/// without any), in the order given; a name given twice keeps its place and its last value, the one
/// the run applied. A value may hold any character (`;`, `=`, quotes): JSON escapes it.
fn parameters_json(params: &[String]) -> String {
    let mut pairs: Vec<(String, String)> = Vec::new();
    for p in params {
        // The run refused a malformed item before the metadata is written.
        let Ok((name, value)) = super::name_value(p) else {
            continue;
        };
        match pairs.iter_mut().find(|(n, _)| *n == name) {
            Some(slot) => slot.1 = value,
            None => pairs.push((name, value)),
        }
    }
    let body: Vec<String> = pairs
        .iter()
        .map(|(n, v)| format!("{}:{}", json_string(n), json_string(v)))
        .collect();
    format!("{{{}}}", body.join(","))
}

/// `s` as a JSON string literal (RFC 8259: `"` and `\` escaped, control characters as
/// `\u00XX` or their short escapes).
fn json_string(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            '\t' => out.push_str("\\t"),
            c if u32::from(c) < 0x20 => out.push_str(&format!("\\u{:04x}", u32::from(c))),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

#[cfg(test)]
mod tests {
    use clap::{CommandFactory, Parser};
    use kneebench_harness::Isolation;

    use crate::cli::{Cli, Command};

    fn isolate_of(args: &[&str]) -> Result<Isolation, clap::Error> {
        let cli = Cli::try_parse_from(["kneebench", "run", "x.fmu"].iter().chain(args))?;
        match cli.command {
            Command::Run(a) => Ok(a.isolate),
            other => panic!("{other:?}"),
        }
    }

    /// `--isolate` takes the names of the library's one table (`Isolation::NAMED`, which the
    /// Python package reads too) and gives their isolation: the CLI named and mapped the modes
    /// itself (`IsolateArg`) beside `Isolation::from_name`.
    #[test]
    fn isolate_takes_the_library_names_and_gives_their_isolation() {
        for (name, isolation, _) in Isolation::NAMED {
            assert_eq!(
                isolate_of(&["--isolate", name]).unwrap(),
                isolation,
                "{name}"
            );
            assert_eq!(Isolation::from_name(name), Some(isolation));
            assert_eq!(isolation.name(), name);
        }
        assert_eq!(isolate_of(&[]).unwrap(), Isolation::Auto);
        let e = isolate_of(&["--isolate", "sometimes"]).unwrap_err();
        assert_eq!(e.kind(), clap::error::ErrorKind::InvalidValue);
        assert_eq!(e.exit_code(), crate::cli::EXIT_USAGE);
        let text = e.to_string();
        assert!(
            text.contains("'sometimes'") && text.contains("auto, always, never"),
            "{text}"
        );
        let mut cli = Cli::command();
        let help = cli
            .find_subcommand_mut("run")
            .unwrap()
            .render_long_help()
            .to_string();
        for (name, _, what) in Isolation::NAMED {
            assert!(
                help.contains(&format!("{name}:")) && help.contains(what),
                "{help}"
            );
        }
        assert_eq!(Isolation::names_text(), "'auto', 'always' or 'never'");
    }

    /// Values holding the old separator (`;`), `=`, quotes, backslashes and control
    /// characters come back as given from the JSON object; a repeated name keeps its last
    /// value (the one applied).
    #[test]
    fn parameters_are_an_unambiguous_json_object() {
        use super::parameters_json;
        let params: Vec<String> = [
            "label=a;b=c",
            "path=C:\\x\"y\"",
            "gaitPeriod=1.25",
            "tab=x\ty\u{1}",
            "gaitPeriod=2",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        assert_eq!(
            parameters_json(&params),
            r#"{"label":"a;b=c","path":"C:\\x\"y\"","gaitPeriod":"2","tab":"x\ty\u0001"}"#
        );
        assert_eq!(parameters_json(&[]), "{}");
    }
}
