//! Parameter sweeps: many runs of one system over a design of parameter values, one table row
//! per run.
//!
//! - [`spec`]: the TOML specification ([`SweepSpec`]), refused with the line of every problem.
//! - [`design`]: the points (grid, Latin hypercube, Sobol, random, CSV).
//! - [`runner`]: checks the spec against the system's FMUs ([`Prepared`]), runs points on
//!   worker threads (each with its own loaded FMUs and a fresh system per point), computes the
//!   metrics, journals finished points for `--resume`.
//! - [`optimize`]: differential evolution over the parameters (a spec with `[optimize]`), each
//!   generation a batch of points run as a sweep's.
//! - [`table`]: the rows ([`SweepTable`]) written as Parquet or CSV.
//!
//! Every point is run by a fresh system whose values depend on the point alone, and rows are
//! sorted by point id: the table is the same, bit for bit, whatever the number of workers and
//! the order in which they take points.

pub mod design;
pub mod journal;
pub mod optimize;
pub mod runner;
pub mod spec;
pub mod table;

use std::path::PathBuf;

pub use design::Design;
pub use optimize::{JournaledOptimization, Optimization, Optimizer, run_optimization};
pub use runner::{JournaledSweep, MAX_WORKERS, Prepared, SweepOptions, check_workers, run_sweep};
pub use spec::{SpecProblem, SweepSpec};
pub use table::{Row, RunStatus, SweepTable};

/// Errors of a sweep.
#[derive(Debug, thiserror::Error)]
pub enum SweepError {
    /// The spec (or its design CSV) is refused; one problem per entry, each with its line.
    #[error("{}", .0.iter().map(ToString::to_string).collect::<Vec<_>>().join("\n"))]
    Invalid(Vec<SpecProblem>),
    /// A file could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The system could not be built or loaded.
    #[error("{0}")]
    System(String),
    /// Writing or reading the table failed.
    #[error("{}: {message}", path.display())]
    Table {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// The journal of an earlier sweep does not fit this one, or is unreadable.
    #[error("{}: {message}", path.display())]
    Journal {
        /// The journal.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// Another sweep (or optimisation), in this process or another, is writing to the same
    /// output: it holds the lock on the journal (see [`journal`]). The lock goes with that
    /// sweep's end, however it ends.
    #[error(
        "{}: another sweep is running into this output (it holds the journal's lock); wait for \
         it to end, or write to another output",
        path.display()
    )]
    Busy {
        /// The journal.
        path: PathBuf,
    },
    /// A number of worker threads outside `1..=`[`MAX_WORKERS`].
    #[error("{0} worker threads: a sweep or an optimisation runs on 1 to {MAX_WORKERS}")]
    Workers(usize),
    /// The output (or its journal) is one of the sweep's inputs ([`Prepared::check_output`]):
    /// the table would replace it. Refused before anything is written.
    #[error(
        "the output {} is the input {}: the results would replace it",
        output.display(),
        input.display()
    )]
    OutputIsInput {
        /// The output (or its journal) as given.
        output: PathBuf,
        /// The input it is.
        input: PathBuf,
    },
    /// A worker ended without returning every point it took.
    #[error("points without a row: {0:?}")]
    Missing(Vec<u64>),
}
