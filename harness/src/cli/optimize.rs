//! `kneebench optimize`.

use std::io::IsTerminal;
use std::path::PathBuf;

use kneebench_harness::num::Num;
use kneebench_harness::sweep::optimize::GenerationBest;
use kneebench_harness::sweep::{SweepOptions, run_optimization};

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
OUTPUT.journal; --resume replays them and runs the rest. The result is identical whatever the
number of workers. From Python: kneebench.optimize(spec, client=...) runs the generations on a
Dask cluster.")]
pub struct Args {
    /// The specification (TOML) with an [optimize] table.
    pub spec: PathBuf,
    /// The table of every run: Parquet for `.parquet`, CSV otherwise.
    #[arg(long, short, default_value = "optimize.parquet")]
    pub output: PathBuf,
    /// Worker threads (default: every local core).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    pub workers: Option<u64>,
    /// Continue an interrupted optimisation from OUTPUT.journal, replaying its finished runs.
    #[arg(long)]
    pub resume: bool,
    /// Do not print each generation's best (on a terminal: a progress bar instead).
    #[arg(long, short)]
    pub quiet: bool,
}

/// Runs `kneebench optimize`.
pub fn run(a: Args) -> anyhow::Result<i32> {
    kneebench_harness::tempdirs::remove_stale();
    let prepared = match super::sweep::prepare(&a.spec, true)? {
        Ok(p) => p,
        Err(code) => return Ok(code),
    };
    let Some(settings) = prepared.spec.optimize.clone() else {
        unreachable!("prepare(.., true) refuses a spec without [optimize]")
    };
    let mut options = SweepOptions {
        progress: std::io::stderr().is_terminal() && a.quiet,
        resume: a.resume,
        ..SweepOptions::default()
    };
    if let Some(w) = a.workers {
        options.workers = w as usize;
    }
    let describe = |objective: f64, violation: f64| {
        let standing = if violation == 0.0 {
            String::new()
        } else if violation.is_infinite() {
            " (tripped or failed)".to_string()
        } else {
            format!(" (constraints violated by {})", Num(violation))
        };
        format!("{} = {}{standing}", settings.objective, Num(objective))
    };
    let started = std::time::Instant::now();
    let quiet = a.quiet;
    let mut on_generation = |g: &GenerationBest| {
        if !quiet {
            eprintln!(
                "generation {}/{}: best {} at point {}",
                g.generation,
                settings.generations,
                describe(g.objective, g.violation),
                g.point
            );
        }
    };
    let result = run_optimization(&prepared, Some(&a.output), &options, &mut on_generation)?;
    let best = &result.best;
    let population = result.table.rows.len() as u64 / (settings.generations as u64 + 1);
    eprintln!(
        "wrote {} rows to {} ({} workers, {:.3} s wall time)",
        result.table.rows.len(),
        a.output.display(),
        options.workers,
        started.elapsed().as_secs_f64()
    );
    if result.violation != 0.0 {
        eprintln!("warning: no run met every constraint without a trip or failure");
    }
    let objective = prepared
        .metric_names
        .iter()
        .position(|m| *m == settings.objective)
        .map_or(f64::NAN, |k| best.metrics[k]);
    println!(
        "best: point {} (generation {}), {}",
        best.point,
        best.point / population.max(1),
        describe(objective, result.violation)
    );
    for (name, v) in prepared.design.names.iter().zip(&best.parameters) {
        println!("  {name} = {}", Num(*v));
    }
    for c in &settings.constraints {
        if let Some(k) = prepared.metric_names.iter().position(|m| *m == c.metric) {
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
    Ok(super::EXIT_OK)
}
