//! kneebench harness: load any FMI 2.0 co-simulation FMU as a third-party importer does, run
//! connected systems with a fixed-step master, and record, write and plot the results.
//!
//! The pieces, in the order data flows through them:
//!
//! - [`load`]: open a `.fmu` archive safely into a private directory, parse its
//!   `modelDescription.xml`, load its binary with `libloading` and resolve the FMI functions
//!   ([`Fmu::load`]).
//! - [`instance`]: a safe wrapper of one `fmi2Component` ([`Instance`]): every call maps the
//!   FMU's status to a `Result`, log messages are forwarded to a handler.
//! - [`isolate`]: the same instance in a host process of its own (opt-in by
//!   [`LoadOptions::isolation`]), so that a crash, `exit()` or hang of the FMU is an error.
//! - [`master`]: a system of components and connections ([`System`]) run by a fixed-step
//!   master on an integer time base, Gauss-Seidel or Jacobi, multi-rate, with early termination.
//! - [`ssp`]: SSP 1.0 system structure files (`.ssp` archives and bare `.ssd`), read and written.
//! - [`results`]: where recorded rows go, behind one sink interface ([`ResultSink`]): in
//!   memory ([`Results`]), or streamed into a crash-safe CSV file
//!   ([`results::csv::CsvFile`]); CSV with round-trip floats, a summary table, plots.
//! - [`control`]: stopping a run from outside (signals, a time limit, a watchdog).
//! - [`package`]: turns the kneebench FMU binary into one reproducible `.fmu` per model.
//!
//! ```no_run
//! use kneebench_harness::{Fmu, LoadOptions, System, RunConfig, Algorithm};
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let fmu = Fmu::load("Gain.fmu", &LoadOptions::default())?;
//! let mut system = System::new();
//! system.add_component("a", fmu.clone())?;
//! system.add_component("b", fmu)?;
//! system.connect("a.y", "b.u")?;
//! let config = RunConfig { stop_time: 1.0, step_size: 1e-3, algorithm: Algorithm::GaussSeidel, ..RunConfig::default() };
//! let output = system.run(&config)?;
//! output.results.write_csv_file("results.csv")?;
//!
//! // The same run streamed to disk as it goes (bounded memory, crash-safe).
//! let mut file = kneebench_harness::results::csv::CsvFile::create("streamed.csv".as_ref())?;
//! let summary = system.run_into(&config, &mut file)?;
//! if matches!(summary.outcome, kneebench_harness::Outcome::Completed { .. }) {
//!     file.commit()?;
//! }
//! # Ok(()) }
//! ```

#![warn(missing_docs)]

/// The FMI 2.0 C types, shared with the `fmu` crate by including its hand-written file (the
/// harness never links the models).
#[path = "../../fmu/src/fmi2/types.rs"]
#[allow(missing_docs, clippy::all)]
pub mod fmi2;

/// The UDP bench protocol's frame codec, shared with the `fmu` crate by including its file
/// (`docs/bench-protocol.md`).
#[path = "../../fmu/src/hardware/protocol/mod.rs"]
pub mod bench_protocol;
pub mod conformance;

pub mod control;
pub mod embedded_python;
pub mod emulator;
pub mod experiment;
pub mod identify;
pub mod inflight;
pub mod instance;
pub mod isolate;
pub mod load;
pub mod master;
pub mod metrics;
pub mod package;
pub mod params;
pub mod results;
pub mod ssp;
pub mod study;
pub mod sweep;
pub mod tempdirs;
pub mod time;

pub use instance::{
    FmuError, HostError, Instance, InstanceOptions, LogHandler, LogMessage, LogStatus, Status,
};
pub use isolate::{HostFailure, HostOptions, Isolation};
pub use load::{
    ArchiveBudget, ArchiveLimits, Binaries, Fmu, LoadError, LoadOptions, PythonThreadState,
};
pub use master::{
    Algorithm, MasterError, Outcome, RunConfig, RunControl, RunOutput, RunSummary, StopReason,
    System, Value,
};
pub use results::{ResultSink, Results};
