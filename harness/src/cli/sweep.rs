//! `kneebench sweep`.

use std::io::IsTerminal;
use std::path::PathBuf;

use kneebench_harness::sweep::{Prepared, SweepError, SweepOptions, SweepSpec, run_sweep};

/// Arguments of `kneebench sweep`.
#[derive(Debug, clap::Args)]
#[command(after_help = "\
Examples:
  kneebench sweep examples/stiffness-sweep/sweep.toml --output out/sweep.parquet
  kneebench sweep examples/stiffness-sweep/sweep.toml --output sweep.csv --workers 1
  kneebench sweep examples/stiffness-sweep/sweep.toml --output out/sweep.parquet --resume

The spec (TOML) names the system (DA, SEA, CSEA or an .ssp/.ssd), the parameters, the design
(grid, latin-hypercube, sobol, random, csv) and the metrics; see the README. It is checked
against the system's FMUs before anything runs; every problem is printed with its line (exit
code 2). Every point is a row: a run that trips an interlock or fails has its status and
message. Finished rows are journaled to OUTPUT.journal; after an interruption, --resume runs
only the points the journal lacks. The table is identical whatever the number of workers.")]
pub struct Args {
    /// The sweep specification (TOML).
    pub spec: PathBuf,
    /// The table to write: Parquet for `.parquet`, CSV otherwise.
    #[arg(long, short, default_value = "sweep.parquet")]
    pub output: PathBuf,
    /// Worker threads (default: every local core).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    pub workers: Option<u64>,
    /// Continue an interrupted sweep from OUTPUT.journal, skipping its finished points.
    #[arg(long)]
    pub resume: bool,
}

/// Runs `kneebench sweep`.
pub fn run(a: Args) -> anyhow::Result<i32> {
    kneebench_harness::tempdirs::remove_stale();
    let prepared = match SweepSpec::from_file(&a.spec).and_then(Prepared::new) {
        Ok(p) => p,
        Err(SweepError::Invalid(problems)) => {
            for p in &problems {
                eprintln!("error: {p}");
            }
            return Ok(super::EXIT_USAGE);
        }
        Err(e) => return Err(e.into()),
    };
    let mut options = SweepOptions {
        progress: std::io::stderr().is_terminal(),
        resume: a.resume,
        ..SweepOptions::default()
    };
    if let Some(w) = a.workers {
        options.workers = w as usize;
    }
    let started = std::time::Instant::now();
    let table = run_sweep(&prepared, Some(&a.output), &options)?;
    let (ok, tripped, failed) = kneebench_harness::sweep::runner::status_counts(&table);
    eprintln!(
        "wrote {} rows to {} ({ok} ok, {tripped} tripped, {failed} failed; {} workers, {:.3} s wall time)",
        table.rows.len(),
        a.output.display(),
        options.workers,
        started.elapsed().as_secs_f64()
    );
    Ok(super::EXIT_OK)
}
