//! The command line: one module per subcommand, each with an `Args` struct and a `run`
//! function returning the process exit code.

use clap::{Parser, Subcommand};

pub mod emulate;
pub mod experiment;
pub mod export;
pub mod identify;
pub mod info;
pub mod key;
pub mod last_resort;
pub mod metrics;
pub mod optimize;
pub mod output;
pub mod plot;
pub mod run;
pub mod study;
pub mod sweep;
pub mod tune;
pub mod validate;

/// Success.
pub const EXIT_OK: i32 = 0;
/// A run, validation or I/O error.
pub const EXIT_ERROR: i32 = 1;
/// A usage error (bad arguments, a stop time off the grid, an unusable input file).
pub const EXIT_USAGE: i32 = 2;
/// The run was ended by an FMU (fmi2Discard with fmi2Terminated).
pub const EXIT_TERMINATED: i32 = 3;
/// The run's `--timeout` passed.
pub const EXIT_TIMEOUT: i32 = 4;

const EXIT_CODES: &str = "\
Exit codes:
  0    success
  1    error (an FMU failed, a non-finite output, a file could not be read or written), or
       validation problems
  2    usage error (bad arguments, a stop time off the step grid, an unusable --inputs file,
       an FMU that validate rejects without --force)
  3    `run`: an FMU ended the run (fmi2Discard with fmi2Terminated); the results are written
       up to and including its last successful time. `study`: an interlock ended a run
  4    `run`: the --timeout passed; the rows so far are in OUTPUT.partial
  129  `run` stopped by SIGHUP, 130 by SIGINT, 143 by SIGTERM; the rows so far are in
       OUTPUT.partial. `sweep` and `optimize` stopped by a signal (the same codes): the rows so
       far are in OUTPUT.journal for --resume. `sweep` exits 0 when its rows tripped or failed (each is
       a row with its status)";

/// kneebench: a co-simulation harness for FMI 2.0 FMUs and SSP 1.0 systems.
#[derive(Debug, Parser)]
#[command(name = "kneebench", version, about, long_about = None, after_help = EXIT_CODES)]
pub struct Cli {
    /// The subcommand.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Write one .fmu per kneebench model (binary, model description, documentation, reference run).
    Export(export::Args),
    /// Run an SSP system (.ssp, .ssd) or a single FMU (.fmu) and write the results as CSV.
    Run(run::Args),
    /// Check an FMU archive: safe extraction, model description, binary, symbols, GUID.
    Validate(validate::Args),
    /// Show an FMU's model description: capabilities, default experiment, variables.
    Info(info::Args),
    /// Plot signals of a results CSV against time (SVG or PNG).
    Plot(plot::Args),
    /// Run the DA/SEA/CSEA gait study: scenarios, results, figures and the comparison table.
    Study(study::Args),
    /// Run a parameter sweep (TOML spec) on every local core; one table row per run (Parquet or CSV).
    Sweep(sweep::Args),
    /// Optimise a metric over a sweep spec's parameters (differential evolution, constraints).
    Optimize(optimize::Args),
    /// Step-response quality (rise, settling, overshoot, peak) or tracking error of a signal.
    Metrics(metrics::Args),
    /// Ziegler-Nichols starting gains from the ultimate gain or a step response.
    Tune(tune::Args),
    /// Run a bench experiment (map, bode, triangle, calibration, step) on BenchPlant or BenchHardware.
    Experiment(experiment::Args),
    /// Fit the plant's parameters to experiment logs; write them as an SSP parameter set (.ssv).
    Identify(identify::Args),
    /// Serve the UDP bench protocol with the BenchPlant FMU running in real time behind it.
    Emulate(emulate::Args),
    /// Make or check the bench's secret key file (authenticates the bench protocol).
    Key(key::Args),
}

/// Value parsers of numeric options: a bad value is refused while the command line is parsed,
/// as a usage error (exit code 2) naming the option, instead of failing later with exit code 1
/// (or being accepted: NaN passes every `<` and `>` test).
pub mod values {
    /// Parses a number (Rust's `f64` syntax, surrounding blanks allowed).
    fn number(text: &str) -> Result<f64, String> {
        text.trim()
            .parse()
            .map_err(|_| format!("'{text}' is not a number"))
    }

    /// A finite number (not NaN, not infinite).
    pub fn finite(text: &str) -> Result<f64, String> {
        let v = number(text)?;
        if v.is_finite() {
            Ok(v)
        } else {
            Err(format!("{v} is not a finite number"))
        }
    }

    /// A finite number greater than zero.
    pub fn positive(text: &str) -> Result<f64, String> {
        let v = finite(text)?;
        if v > 0.0 {
            Ok(v)
        } else {
            Err(format!("{v} is not greater than zero"))
        }
    }

    /// A finite number other than zero.
    pub fn non_zero(text: &str) -> Result<f64, String> {
        let v = finite(text)?;
        if v != 0.0 {
            Ok(v)
        } else {
            Err("must not be zero".into())
        }
    }

    /// A finite number at least zero.
    pub fn non_negative(text: &str) -> Result<f64, String> {
        let v = finite(text)?;
        if v >= 0.0 {
            Ok(v)
        } else {
            Err(format!("{v} is negative"))
        }
    }

    #[cfg(test)]
    mod tests {
        use super::*;

        #[test]
        fn non_finite_zero_and_negative_values_are_refused_by_the_right_parsers() {
            for bad in ["nan", "NaN", "inf", "-inf", "infinity", "x", ""] {
                assert!(finite(bad).is_err(), "{bad}");
                assert!(positive(bad).is_err(), "{bad}");
                assert!(non_negative(bad).is_err(), "{bad}");
                assert!(non_zero(bad).is_err(), "{bad}");
            }
            assert_eq!(finite(" -1.5 "), Ok(-1.5));
            assert!(positive("0").is_err() && positive("-1").is_err());
            assert_eq!(positive("1e-3"), Ok(1e-3));
            assert!(non_negative("-1e-300").is_err());
            assert_eq!(non_negative("0"), Ok(0.0));
            assert!(non_zero("0").is_err() && non_zero("-0").is_err());
            assert_eq!(non_zero("-2"), Ok(-2.0));
        }
    }
}

/// A usage error found after parsing (a value that only the input files show to be wrong, a
/// malformed `--param`): `main` prints it and exits with [`EXIT_USAGE`] instead of
/// [`EXIT_ERROR`].
#[derive(Debug)]
pub struct Usage(pub String);

impl std::fmt::Display for Usage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Usage {}

/// The exit code of an error `dispatch` returned: [`EXIT_USAGE`] for a [`Usage`] error,
/// [`EXIT_ERROR`] for any other.
pub fn exit_code_of(e: &anyhow::Error) -> i32 {
    if e.chain().any(|c| c.is::<Usage>()) {
        EXIT_USAGE
    } else {
        EXIT_ERROR
    }
}

/// Splits a `--param NAME=VALUE` argument into its trimmed name and value (every subcommand's
/// `--param` reads this way; `run` reports the same failure as a usage error itself).
pub fn name_value(text: &str) -> anyhow::Result<(String, String)> {
    text.split_once('=')
        .map(|(n, v)| (n.trim().to_string(), v.trim().to_string()))
        .ok_or_else(|| Usage(format!("--param '{text}': expected NAME=VALUE")).into())
}

/// Runs a parsed command line; returns the exit code.
pub fn dispatch(cli: Cli) -> anyhow::Result<i32> {
    // Extraction directories that crashed or killed runs left behind.
    kneebench_harness::tempdirs::remove_stale();
    match cli.command {
        Command::Export(a) => export::run(a),
        Command::Run(a) => run::run(a),
        Command::Validate(a) => validate::run(a),
        Command::Info(a) => info::run(a),
        Command::Plot(a) => plot::run(a),
        Command::Metrics(a) => metrics::run(a),
        Command::Study(a) => study::run(a),
        Command::Sweep(a) => sweep::run(a),
        Command::Optimize(a) => optimize::run(a),
        Command::Tune(a) => tune::run(a),
        Command::Emulate(a) => emulate::run(a),
        Command::Experiment(a) => experiment::run(a),
        Command::Key(a) => key::run(a),
        Command::Identify(a) => identify::run(a),
    }
}

/// The input among `inputs` that `output` names (the same file, however spelled), with a
/// message: the results, renamed into place at the end, would replace it.
pub(crate) fn output_replaces_input(
    output: &std::path::Path,
    inputs: &[&std::path::Path],
) -> Option<String> {
    let out = std::fs::canonicalize(output).ok()?;
    inputs
        .iter()
        .find(|i| std::fs::canonicalize(i).ok().as_ref() == Some(&out))
        .map(|i| {
            format!(
                "the output {} is the input {}: the results would replace it",
                output.display(),
                i.display()
            )
        })
}
