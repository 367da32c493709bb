//! `kneebench sweep`.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use kneebench_harness::sweep::{
    Prepared, SpecProblem, SweepError, SweepOptions, SweepSpec, run_sweep,
};

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
only the points the journal lacks. The table is identical whatever the number of workers.

--dask ADDRESS sends the points in batches to a Dask cluster's workers through the kneebench
Python package: the interpreter named by KNEEBENCH_PYTHON (default: python3 on PATH) must
import kneebench and distributed, and the workers must read the spec and the FMUs at the same
absolute paths (see the README). The table is the same as the local one:
  kneebench sweep examples/stiffness-sweep/sweep.toml --output out/sweep.parquet \\
      --dask tcp://scheduler:8786")]
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
    /// Run the points on the Dask cluster whose scheduler is at ADDRESS (e.g.
    /// tcp://scheduler:8786) instead of local threads.
    #[arg(long, value_name = "ADDRESS", conflicts_with_all = ["workers", "resume"])]
    pub dask: Option<String>,
    /// With --dask: points per Dask task (default: about four tasks per worker).
    #[arg(long, requires = "dask", value_parser = clap::value_parser!(u64).range(1..))]
    pub batch_size: Option<u64>,
}

/// The script `--dask` runs in the Python interpreter: exit status 3 when `kneebench` or
/// `distributed` cannot be imported (its stderr names which), 1 on a sweep error.
const DASK_SCRIPT: &str = r#"
import sys
for module in ("kneebench", "distributed"):
    try:
        __import__(module)
    except ImportError as e:
        sys.stderr.write(f"missing module {module}: {e}\n")
        sys.exit(3)
import kneebench
from distributed import Client
spec, address, output, batch = sys.argv[1:5]
try:
    with Client(address, timeout="30s") as client:
        table = kneebench.sweep(spec, client=client, output=output, batch_size=int(batch) or None)
except (kneebench.KneebenchError, OSError, TimeoutError) as e:
    sys.stderr.write(f"{type(e).__name__}: {e}\n")
    sys.exit(1)
counts = table["status"].value_counts()
print(len(table), *(int(counts.get(s, 0)) for s in ("ok", "tripped", "failed")))
"#;

/// The Python interpreter of `--dask`: `KNEEBENCH_PYTHON`, else `python3`.
fn python() -> PathBuf {
    std::env::var_os("KNEEBENCH_PYTHON")
        .filter(|p| !p.is_empty())
        .map_or_else(|| PathBuf::from("python3"), PathBuf::from)
}

/// Runs the sweep on a Dask cluster through the Python package; the table is written by the
/// package (the same writer as the local sweep). Returns (rows, ok, tripped, failed).
fn run_on_dask(
    spec: &std::path::Path,
    address: &str,
    output: &std::path::Path,
    batch_size: Option<u64>,
) -> anyhow::Result<[u64; 4]> {
    let python = python();
    let abs = |p: &std::path::Path| std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
    let out = std::process::Command::new(&python)
        .arg("-c")
        .arg(DASK_SCRIPT)
        .arg(abs(spec))
        .arg(address)
        .arg(abs(output))
        .arg(batch_size.unwrap_or(0).to_string())
        .stdin(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .output()
        .map_err(|e| {
            anyhow::anyhow!(
                "--dask runs the sweep through the kneebench Python package, but '{}' could not \
                 be started ({e}); set KNEEBENCH_PYTHON to a Python that has the kneebench \
                 wheel and distributed installed (e.g. the .venv of scripts/setup-python.sh)",
                python.display()
            )
        })?;
    let stderr = String::from_utf8_lossy(&out.stderr);
    match out.status.code() {
        Some(0) => {}
        Some(3) => anyhow::bail!(
            "--dask runs the sweep through the kneebench Python package, but '{}' {}; install \
             the kneebench wheel and distributed there (README: the Python package) or set \
             KNEEBENCH_PYTHON to a Python that has them",
            python.display(),
            stderr.trim().replace("missing module", "cannot import")
        ),
        _ => anyhow::bail!(
            "the Dask sweep through '{}' failed ({}): {}",
            python.display(),
            out.status,
            stderr.trim()
        ),
    }
    let stdout = String::from_utf8_lossy(&out.stdout);
    let counts: Vec<u64> = stdout
        .lines()
        .last()
        .unwrap_or("")
        .split_whitespace()
        .filter_map(|w| w.parse().ok())
        .collect();
    match counts[..] {
        [rows, ok, tripped, failed] => Ok([rows, ok, tripped, failed]),
        _ => anyhow::bail!(
            "the Dask sweep through '{}' ended without its row counts: {}",
            python.display(),
            stdout.trim()
        ),
    }
}

/// Reads and checks a spec against its system: `Ok(Err(exit code))` when it is refused (every
/// problem printed with its line), and when `optimization` differs from whether it has an
/// `[optimize]` table (`kneebench sweep` runs designs, `kneebench optimize` optimisations).
pub(crate) fn prepare(spec: &Path, optimization: bool) -> anyhow::Result<Result<Prepared, i32>> {
    let refused = |problems: &[SpecProblem]| {
        for p in problems {
            eprintln!("error: {p}");
        }
        Ok(Err(super::EXIT_USAGE))
    };
    let prepared = match SweepSpec::from_file(spec).and_then(Prepared::new) {
        Ok(p) => p,
        Err(SweepError::Invalid(problems)) => return refused(&problems),
        Err(e) => return Err(e.into()),
    };
    let mismatch = if optimization {
        prepared.spec.optimize.is_none().then(|| {
            prepared.spec.problem(
                0,
                "no [optimize] table: `kneebench optimize` needs one (the objective, the \
                 generations); run a design with `kneebench sweep`",
            )
        })
    } else {
        prepared.refuse_optimization().err().and_then(|e| match e {
            SweepError::Invalid(mut problems) => problems.pop(),
            _ => None,
        })
    };
    match mismatch {
        Some(problem) => refused(&[problem]),
        None => Ok(Ok(prepared)),
    }
}

/// Runs `kneebench sweep`.
pub fn run(a: Args) -> anyhow::Result<i32> {
    kneebench_harness::tempdirs::remove_stale();
    let prepared = match prepare(&a.spec, false)? {
        Ok(p) => p,
        Err(code) => return Ok(code),
    };
    if let Some(address) = &a.dask {
        drop(prepared);
        let started = std::time::Instant::now();
        let [rows, ok, tripped, failed] = run_on_dask(&a.spec, address, &a.output, a.batch_size)?;
        eprintln!(
            "wrote {rows} rows to {} ({ok} ok, {tripped} tripped, {failed} failed; Dask cluster \
             {address}, {:.3} s wall time)",
            a.output.display(),
            started.elapsed().as_secs_f64()
        );
        return Ok(super::EXIT_OK);
    }
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
