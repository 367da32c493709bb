//! `kneebench sweep`.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use kneebench_harness::control::{RunControl, StopReason};
use kneebench_harness::sweep::journal::journal_path;
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
message, and the exit code is 0 once the table is written, whatever the rows' status. Finished
rows are journaled to OUTPUT.journal; Ctrl-C stops the runs (exit code 130, the journal kept and
the points done counted); after an interruption, --resume runs only the points the journal
lacks (with no journal, a finished Parquet table of the same sweep is taken as done; a finished
CSV table is refused: it has no fingerprint). The table is identical whatever the number of
workers. OUTPUT may not be one of the sweep's inputs (the spec, the system file, the design
CSV, an FMU): refused with exit code 2.

--dask ADDRESS sends the points in batches to a Dask cluster's workers through the kneebench
Python package: the interpreter named by KNEEBENCH_PYTHON (default: python3 on PATH) must
import kneebench and distributed, and the workers must read the spec and the FMUs at the same
absolute paths (see the README). The table is the same as the local one, its rows journaled as
the batches come back (--resume as for a local sweep):
  kneebench sweep examples/stiffness-sweep/sweep.toml --output out/sweep.parquet \\
      --dask tcp://scheduler:8786")]
pub struct Args {
    /// The sweep specification (TOML).
    pub spec: PathBuf,
    /// The table to write: Parquet for `.parquet`, CSV otherwise.
    #[arg(long, short, default_value = "sweep.parquet")]
    pub output: PathBuf,
    /// Worker threads, 1 to 1024 (default: every local core).
    #[arg(long, value_parser = super::sweep::workers)]
    pub workers: Option<usize>,
    /// Continue an interrupted sweep from OUTPUT.journal, skipping its finished points
    /// (without a journal: the finished Parquet table at OUTPUT, if it is this sweep's); with
    /// --dask too.
    #[arg(long)]
    pub resume: bool,
    /// Run the points on the Dask cluster whose scheduler is at ADDRESS (e.g.
    /// tcp://scheduler:8786) instead of local threads.
    #[arg(long, value_name = "ADDRESS", conflicts_with = "workers")]
    pub dask: Option<String>,
    /// With --dask: points per Dask task (default: about four tasks per worker).
    #[arg(long, requires = "dask", value_parser = clap::value_parser!(u64).range(1..))]
    pub batch_size: Option<u64>,
}

/// Parses `--workers` (of `sweep` and `optimize`): a whole number of threads within the
/// library's bound, 1 to [`MAX_WORKERS`](kneebench_harness::sweep::MAX_WORKERS)
/// ([`check_workers`](kneebench_harness::sweep::check_workers)); more tried to start that many
/// threads.
pub(crate) fn workers(text: &str) -> Result<usize, String> {
    let n = text.trim().parse::<usize>().map_err(|_| {
        format!(
            "'{text}' is not a whole number of threads from 1 to {}",
            kneebench_harness::sweep::MAX_WORKERS
        )
    })?;
    kneebench_harness::sweep::check_workers(n).map_err(|e| e.to_string())?;
    Ok(n)
}

/// The script `--dask` runs in the Python interpreter, around a [`DaskCall`]'s source: exit
/// status 3 when `kneebench` or `distributed` cannot be imported (its stderr names which), 1
/// on an error of the call, and at once when the scheduler's `tcp://` address refuses the
/// connection (nothing listens; the Client's 30 s timeout stays for a scheduler slow to
/// answer). It reports on stdout, one line per `emit`, each line
/// [`DASK_TAG`] and words: the call's own, then `rows ROWS OK TRIPPED FAILED`.
const DASK_SCRIPT: [&str; 2] = [
    r#"
import sys
for module in ("kneebench", "distributed"):
    try:
        __import__(module)
    except ImportError as e:
        sys.stderr.write(f"missing module {module}: {e}\n")
        sys.exit(3)
import kneebench
from distributed import Client
spec, address, output, batch, resume, tag = sys.argv[1:7]

def emit(*words):
    print(tag, *words, flush=True)

def refused(address):
    """The error of a TCP connection to a tcp:// scheduler address that is refused (nothing
    listens: fail at once), else None (the Client's 30 s timeout is for a slow scheduler)."""
    import socket, urllib.parse
    u = urllib.parse.urlsplit(address if "://" in address else "tcp://" + address)
    try:
        if u.scheme != "tcp" or not u.hostname:
            return None
        socket.create_connection((u.hostname, u.port or 8786), timeout=10).close()
    except ConnectionRefusedError as e:
        return e
    except (OSError, ValueError):
        return None
    return None
"#,
    r#"
e = refused(address)
if e is not None:
    sys.stderr.write(f"ConnectionRefusedError: no Dask scheduler at {address}: {e}\n")
    sys.exit(1)
try:
    with Client(address, timeout="30s") as client:
        table = call(client, spec, output, int(batch) or None, resume == "1")
except (kneebench.KneebenchError, OSError, TimeoutError, ValueError) as e:
    sys.stderr.write(f"{type(e).__name__}: {e}\n")
    sys.exit(1)
counts = table["status"].value_counts()
emit("rows", len(table), *(int(counts.get(s, 0)) for s in ("ok", "tripped", "failed")))
"#,
];

/// The first word of the lines of [`DASK_SCRIPT`]'s reports (its last argument; other stdout
/// lines are ignored).
const DASK_TAG: &str = "@kneebench";

/// What `--dask` runs through the kneebench Python package.
pub(crate) struct DaskCall<'a> {
    /// What runs, for the messages: "sweep", "optimisation".
    pub what: &'a str,
    /// Python source defining `call(client, spec, output, batch_size, resume)`: runs it on the
    /// cluster of `client`, writes `output` and returns the table's DataFrame; it may report on
    /// stdout with `emit(word, ...)` (see [`run_on_dask`]).
    pub source: &'a str,
}

/// `kneebench sweep --dask`'s call.
const SWEEP_CALL: DaskCall<'static> = DaskCall {
    what: "sweep",
    source: r#"
def call(client, spec, output, batch_size, resume):
    return kneebench.sweep(spec, client=client, output=output, batch_size=batch_size,
                           resume=resume)
"#,
};

/// The Python interpreter of `--dask`: `KNEEBENCH_PYTHON`, else `python3`.
fn python() -> PathBuf {
    std::env::var_os("KNEEBENCH_PYTHON")
        .filter(|p| !p.is_empty())
        .map_or_else(|| PathBuf::from("python3"), PathBuf::from)
}

/// Runs `call` on the Dask cluster at `address` through the Python package; the table is
/// written by the package (the same writer as the local run). Every report of the call
/// (`emit(...)`: its words) is handed to `on_report` as it comes; returns (rows, ok, tripped,
/// failed).
pub(crate) fn run_on_dask(
    call: &DaskCall<'_>,
    spec: &Path,
    address: &str,
    output: &Path,
    batch_size: Option<u64>,
    resume: bool,
    on_report: &mut dyn FnMut(&[&str]),
) -> anyhow::Result<[u64; 4]> {
    use std::io::{BufRead, Read};

    let python = python();
    let what = call.what;
    let abs = |p: &Path| std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
    let mut child = std::process::Command::new(&python)
        .arg("-c")
        .arg([DASK_SCRIPT[0], call.source, DASK_SCRIPT[1]].concat())
        .arg(abs(spec))
        .arg(address)
        .arg(abs(output))
        .arg(batch_size.unwrap_or(0).to_string())
        .arg(if resume { "1" } else { "0" })
        .arg(DASK_TAG)
        .stdin(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .map_err(|e| {
            anyhow::anyhow!(
                "--dask runs the {what} through the kneebench Python package, but '{}' could not \
                 be started ({e}); set KNEEBENCH_PYTHON to a Python that has the kneebench \
                 wheel and distributed installed (e.g. the .venv of scripts/setup-python.sh)",
                python.display()
            )
        })?;
    // stderr on a thread of its own, so that neither pipe fills while the other is read.
    let mut stderr_pipe = child.stderr.take();
    let stderr_reader = std::thread::spawn(move || {
        let mut text = Vec::new();
        if let Some(e) = stderr_pipe.as_mut() {
            let _ = e.read_to_end(&mut text);
        }
        String::from_utf8_lossy(&text).into_owned()
    });
    let mut counts = None;
    let mut other = Vec::new();
    if let Some(stdout) = child.stdout.take() {
        for line in std::io::BufReader::new(stdout)
            .lines()
            .map_while(Result::ok)
        {
            let words: Vec<&str> = line.split_whitespace().collect();
            match words[..] {
                [DASK_TAG, "rows", ..] => {
                    let n: Vec<u64> = words[2..].iter().filter_map(|w| w.parse().ok()).collect();
                    if let [rows, ok, tripped, failed] = n[..] {
                        counts = Some([rows, ok, tripped, failed]);
                    }
                }
                [DASK_TAG, ..] => on_report(&words[1..]),
                _ => other.push(line),
            }
        }
    }
    let status = child.wait()?;
    let stderr = stderr_reader.join().unwrap_or_default();
    match status.code() {
        Some(0) => {}
        Some(3) => anyhow::bail!(
            "--dask runs the {what} through the kneebench Python package, but '{}' {}; install \
             the kneebench wheel and distributed there (README: the Python package) or set \
             KNEEBENCH_PYTHON to a Python that has them",
            python.display(),
            stderr.trim().replace("missing module", "cannot import")
        ),
        _ => anyhow::bail!(
            "the Dask {what} through '{}' failed ({status}): {}",
            python.display(),
            stderr.trim()
        ),
    }
    counts.ok_or_else(|| {
        anyhow::anyhow!(
            "the Dask {what} through '{}' ended without its row counts: {}",
            python.display(),
            other.join("\n").trim()
        )
    })
}

/// Reads and checks a spec against its system: `Ok(Err(exit code))` when it is refused (every
/// problem printed with its line), when `optimization` differs from whether it has an
/// `[optimize]` table (`kneebench sweep` runs designs, `kneebench optimize` optimisations), and
/// when `output` is one of the sweep's inputs ([`Prepared::check_output`]: the system file, the
/// design CSV, an FMU).
pub(crate) fn prepare(
    spec: &Path,
    output: &Path,
    optimization: bool,
) -> anyhow::Result<Result<Prepared, i32>> {
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
    if let Some(problem) = mismatch {
        return refused(&[problem]);
    }
    if let Err(e) = prepared.check_output(output) {
        eprintln!("error: {e}");
        return Ok(Err(super::EXIT_USAGE));
    }
    Ok(Ok(prepared))
}

/// The exit code of a sweep or optimisation that ended with an error, if `control` stopped it
/// (Ctrl-C, SIGTERM, SIGHUP): 128 + the signal (130 for Ctrl-C), after saying how many of the
/// `total` `what` (points, runs) the journal of `output` keeps and that `--resume` continues.
/// `None` for an error of its own.
pub(super) fn stopped(control: &RunControl, output: &Path, total: u64, what: &str) -> Option<i32> {
    let reason = control.stop_reason()?;
    let journal = journal_path(output);
    let done =
        std::fs::read_to_string(&journal).map_or(0, |j| j.matches('\n').count().saturating_sub(1));
    eprintln!(
        "{reason}: {done} of {total} {what} done (journaled in {}); run again with --resume",
        journal.display()
    );
    Some(match reason {
        StopReason::Signal(n) => 128 + n,
        _ => super::EXIT_ERROR,
    })
}

/// Runs `kneebench sweep`.
pub fn run(a: Args) -> anyhow::Result<i32> {
    kneebench_harness::tempdirs::remove_stale();
    if let Some(message) = super::output_replaces_input(&a.output, &[a.spec.as_path()]) {
        eprintln!("error: {message}");
        return Ok(super::EXIT_USAGE);
    }
    let mut prepared = match prepare(&a.spec, &a.output, false)? {
        Ok(p) => p,
        Err(code) => return Ok(code),
    };
    if let Some(address) = &a.dask {
        drop(prepared);
        let started = std::time::Instant::now();
        let [rows, ok, tripped, failed] = run_on_dask(
            &SWEEP_CALL,
            &a.spec,
            address,
            &a.output,
            a.batch_size,
            a.resume,
            &mut |_| {},
        )?;
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
        options.workers = w;
    }
    // Ctrl-C (SIGINT, SIGTERM, SIGHUP) stops the runs at their next step: the rows before it
    // stay journaled, the scenario's directory is removed, and the exit code is 128 + the
    // signal (130 for Ctrl-C) with the hint to resume. A second Ctrl-C ends the process at once.
    let control = RunControl::new();
    control.stop_on_signals()?;
    prepared.config.control = Some(control.clone());
    let started = std::time::Instant::now();
    let table = match run_sweep(&prepared, Some(&a.output), &options) {
        Ok(t) => t,
        Err(e) => {
            let total = prepared.design.points.len() as u64;
            return stopped(&control, &a.output, total, "points").ok_or_else(|| e.into());
        }
    };
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
