//! `kneebench optimize`.

use std::io::IsTerminal;
use std::path::PathBuf;

use kneebench_harness::control::RunControl;
use kneebench_harness::sweep::optimize::GenerationBest;
use kneebench_harness::sweep::spec::OptimizeSpec;
use kneebench_harness::sweep::{Row, RunStatus, SweepOptions, run_optimization};
use model_description::num::Num;

use super::sweep::{DaskCall, run_on_dask};

/// Arguments of `kneebench optimize`.
#[derive(Debug, clap::Args)]
#[command(after_help = "\
Examples:
  kneebench optimize examples/stiffness-sweep/optimize.toml --output out/optimize.parquet
  kneebench optimize examples/stiffness-sweep/optimize.toml --output out/optimize.parquet --resume

The spec is a sweep spec (see the README) with an [optimize] table: the objective (a metric
column), its direction, the generations, and optional constraints on metrics. Its design is
the first generation (at least 4 points); differential evolution (DE/rand/1/bin) then makes
one trial per member and generation within the parameters' [min, max]. A run that trips an
interlock or fails, or breaks a constraint, loses against one that does not. Every run is a
row of the table (generation = point / population); the best run is printed and named in the
table's metadata (kneebench.optimize.best_point). Finished rows are journaled to
OUTPUT.journal; Ctrl-C stops the runs (exit code 130, the journal kept, no table written, the
runs done counted); --resume replays them and runs the rest. --resume with no journal continues a
finished Parquet table: raise the spec's generations (nothing else) and only the new
generations run; the result equals a run with that many generations from the start. The
result is identical whatever the number of workers.

--dask ADDRESS runs each generation's points in batches on a Dask cluster's workers through
the kneebench Python package (kneebench.optimize(spec, client=...)), as kneebench sweep
--dask does (KNEEBENCH_PYTHON, the same absolute paths on the workers; see the README); the
table and the printed result are the same as the local run's, the rows journaled as the
batches come back (--resume as for a local run):
  kneebench optimize examples/stiffness-sweep/optimize.toml --output out/optimize.parquet \\
      --dask tcp://scheduler:8786")]
pub struct Args {
    /// The specification (TOML) with an `[optimize]` table.
    pub spec: PathBuf,
    /// The table of every run: Parquet for `.parquet`, CSV otherwise.
    #[arg(long, short, default_value = "optimize.parquet")]
    pub output: PathBuf,
    /// Worker threads, 1 to 1024 (default: every local core).
    #[arg(long, value_parser = super::sweep::workers)]
    pub workers: Option<usize>,
    /// Continue an interrupted optimisation from OUTPUT.journal, replaying its finished runs;
    /// without a journal, continue the finished Parquet table at OUTPUT (more generations).
    #[arg(long)]
    pub resume: bool,
    /// Do not print each generation's best (on a terminal: a progress bar instead).
    #[arg(long, short)]
    pub quiet: bool,
    /// Run the generations on the Dask cluster whose scheduler is at ADDRESS (e.g.
    /// tcp://scheduler:8786) instead of local threads.
    #[arg(long, value_name = "ADDRESS", conflicts_with = "workers")]
    pub dask: Option<String>,
    /// With --dask: points per Dask task (default: about four tasks per worker and generation).
    #[arg(long, requires = "dask", value_parser = clap::value_parser!(u64).range(1..))]
    pub batch_size: Option<u64>,
}

/// `--dask`'s call of the Python package: it reports each generation's best (`generation G
/// POINT OBJECTIVE VIOLATION`) and the best run (`best POINT VIOLATION STATUS` and its
/// parameters' and metrics' values in spec order, then `message TEXT` if it has one); the
/// reals as Python's `repr`, which parses back to the same value.
const OPTIMIZE_CALL: DaskCall<'static> = DaskCall {
    what: "optimisation",
    source: r#"
def call(client, spec, output, batch_size, resume):
    def show(g):
        emit("generation", g["generation"], g["point"], repr(g["objective"]),
             repr(g["violation"]))
    table = kneebench.optimize(spec, client=client, output=output, batch_size=batch_size,
                               resume=resume, on_generation=show)
    best = table.attrs["best"]
    emit("best", best["point"], repr(best["violation"]), best["status"],
         *(repr(v) for v in best["parameters"].values()),
         *(repr(v) for v in best["metrics"].values()))
    if best["message"]:
        emit("message", *best["message"].split())
    return table
"#,
};

/// `objective = value` and how the run stands against the constraints.
fn describe(settings: &OptimizeSpec, objective: f64, violation: f64) -> String {
    let standing = if violation == 0.0 {
        String::new()
    } else if violation.is_infinite() {
        " (tripped or failed)".to_string()
    } else {
        format!(" (constraints violated by {})", Num(violation))
    };
    format!("{} = {}{standing}", settings.objective, Num(objective))
}

/// Prints a generation's best (stderr).
fn print_generation(settings: &OptimizeSpec, g: &GenerationBest) {
    eprintln!(
        "generation {}/{}: best {} at point {}",
        g.generation,
        settings.generations,
        describe(settings, g.objective, g.violation),
        g.point
    );
}

/// Prints the best run (stdout): its point, objective, parameters, constrained metrics and
/// message.
fn print_best(
    settings: &OptimizeSpec,
    parameter_names: &[String],
    metric_names: &[String],
    population: usize,
    best: &Row,
    violation: f64,
) {
    if violation != 0.0 {
        eprintln!("warning: no run met every constraint without a trip or failure");
    }
    let objective = metric_names
        .iter()
        .position(|m| *m == settings.objective)
        .map_or(f64::NAN, |k| best.metrics[k]);
    println!(
        "best: point {} (generation {}), {}",
        best.point,
        best.point / population.max(1) as u64,
        describe(settings, objective, violation)
    );
    for (name, v) in parameter_names.iter().zip(&best.parameters) {
        println!("  {name} = {}", Num(*v));
    }
    for c in &settings.constraints {
        if let Some(k) = metric_names.iter().position(|m| *m == c.metric) {
            let bound = match (c.min, c.max) {
                (Some(lo), Some(hi)) => format!("in [{}, {}]", Num(lo), Num(hi)),
                (Some(lo), None) => format!(">= {}", Num(lo)),
                (None, Some(hi)) => format!("<= {}", Num(hi)),
                (None, None) => String::new(),
            };
            println!("  {} = {} ({bound})", c.metric, Num(best.metrics[k]));
        }
    }
    if !best.message.is_empty() {
        println!("  {}: {}", best.status.name(), best.message);
    }
}

/// A report of [`OPTIMIZE_CALL`] (its words after the tag).
enum Report {
    Generation(GenerationBest),
    Best(Row, f64),
    Message(String),
}

fn parse_report(words: &[&str], parameters: usize, metrics: usize) -> Option<Report> {
    let real = |w: &str| w.parse::<f64>().ok();
    match words {
        ["generation", g, point, objective, violation] => {
            Some(Report::Generation(GenerationBest {
                generation: g.parse().ok()?,
                point: point.parse().ok()?,
                objective: real(objective)?,
                violation: real(violation)?,
            }))
        }
        ["best", point, violation, status, values @ ..] if values.len() == parameters + metrics => {
            let values = values
                .iter()
                .map(|w| real(w))
                .collect::<Option<Vec<f64>>>()?;
            let row = Row {
                point: point.parse().ok()?,
                parameters: values[..parameters].to_vec(),
                metrics: values[parameters..].to_vec(),
                status: RunStatus::from_name(status)?,
                message: String::new(),
            };
            Some(Report::Best(row, real(violation)?))
        }
        ["message", text @ ..] => Some(Report::Message(text.join(" "))),
        _ => None,
    }
}

/// Runs the optimisation on a Dask cluster (`--dask`) through the Python package.
fn run_on_cluster(
    a: &Args,
    address: &str,
    prepared: kneebench_harness::sweep::Prepared,
) -> anyhow::Result<i32> {
    let Some(settings) = prepared.spec.optimize.clone() else {
        unreachable!("prepare(.., true) refuses a spec without [optimize]")
    };
    let population = prepared.design.points.len();
    let parameter_names = prepared.design.names.clone();
    let metric_names = prepared.metric_names.clone();
    // The Python package prepares the spec itself.
    drop(prepared);
    let started = std::time::Instant::now();
    let mut best: Option<(Row, f64)> = None;
    let mut message = String::new();
    let mut on_report =
        |words: &[&str]| match parse_report(words, parameter_names.len(), metric_names.len()) {
            Some(Report::Generation(g)) if !a.quiet => print_generation(&settings, &g),
            Some(Report::Best(row, violation)) => best = Some((row, violation)),
            Some(Report::Message(m)) => message = m,
            _ => {}
        };
    let [rows, ..] = run_on_dask(
        &OPTIMIZE_CALL,
        &a.spec,
        address,
        &a.output,
        a.batch_size,
        a.resume,
        &mut on_report,
    )?;
    eprintln!(
        "wrote {rows} rows to {} (Dask cluster {address}, {:.3} s wall time)",
        a.output.display(),
        started.elapsed().as_secs_f64()
    );
    let Some((mut best, violation)) = best else {
        anyhow::bail!("the Dask optimisation ended without its best run");
    };
    best.message = message;
    print_best(
        &settings,
        &parameter_names,
        &metric_names,
        population,
        &best,
        violation,
    );
    Ok(super::EXIT_OK)
}

/// Runs `kneebench optimize`.
pub fn run(a: Args) -> anyhow::Result<i32> {
    kneebench_harness::tempdirs::remove_stale();
    if let Some(message) = super::output_replaces_input(&a.output, &[a.spec.as_path()]) {
        eprintln!("error: {message}");
        return Ok(super::EXIT_USAGE);
    }
    let mut prepared = match super::sweep::prepare(&a.spec, &a.output, true)? {
        Ok(p) => p,
        Err(code) => return Ok(code),
    };
    if let Some(address) = &a.dask {
        return run_on_cluster(&a, address, prepared);
    }
    let Some(settings) = prepared.spec.optimize.clone() else {
        unreachable!("prepare(.., true) refuses a spec without [optimize]")
    };
    let mut options = SweepOptions {
        progress: std::io::stderr().is_terminal() && a.quiet,
        resume: a.resume,
        ..SweepOptions::default()
    };
    if let Some(w) = a.workers {
        options.workers = w;
    }
    let started = std::time::Instant::now();
    let quiet = a.quiet;
    let mut on_generation = |g: &GenerationBest| {
        if !quiet {
            print_generation(&settings, g);
        }
        Ok(())
    };
    // Ctrl-C (SIGINT, SIGTERM, SIGHUP) stops the runs at their next step, as in `sweep`: the
    // rows before it stay journaled, no table is written, and the exit code is 128 + the
    // signal (130 for Ctrl-C) with the hint to resume. A second Ctrl-C ends the process at once.
    let control = RunControl::new();
    control.stop_on_signals()?;
    prepared.config.control = Some(control.clone());
    let total = (prepared.design.points.len() * (settings.generations + 1)) as u64;
    let result = match run_optimization(&prepared, Some(&a.output), &options, &mut on_generation) {
        Ok(r) => r,
        Err(e) => {
            return super::sweep::stopped(&control, &a.output, total, "runs")
                .ok_or_else(|| e.into());
        }
    };
    eprintln!(
        "wrote {} rows to {} ({} workers, {:.3} s wall time)",
        result.table.rows.len(),
        a.output.display(),
        options.workers,
        started.elapsed().as_secs_f64()
    );
    print_best(
        &settings,
        &prepared.design.names,
        &prepared.metric_names,
        prepared.design.points.len(),
        &result.best,
        result.violation,
    );
    Ok(super::EXIT_OK)
}
