//! `kneebench`: run, validate, inspect and plot FMI 2.0 co-simulation FMUs and SSP systems.
//!
//! Exit codes: 0 success; 1 a run, validation or I/O error; 2 a usage error (from clap);
//! 3 the run was ended early by an FMU (fmi2Discard with fmi2Terminated; results written).

mod cli;

use clap::Parser;

fn main() {
    let args = cli::Cli::parse();
    let code = match cli::dispatch(args) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            cli::EXIT_ERROR
        }
    };
    std::process::exit(code);
}
