//! `kneebench`: run, validate, inspect and plot FMI 2.0 co-simulation FMUs and SSP systems.
//!
//! Exit codes (also in `kneebench --help` and the README): 0 success; 1 a run, validation or
//! I/O error; 2 a usage error; 3 `run` was ended by an FMU (fmi2Discard with fmi2Terminated;
//! results written); 4 `run --timeout` passed; 128 + the signal's number when `run` was
//! stopped by SIGHUP, SIGINT or SIGTERM.

mod cli;

use clap::Parser;

/// Restores the default action of SIGPIPE (terminate quietly), which the Rust runtime sets to
/// "ignore": otherwise `kneebench info X | head` panics on the closed pipe instead of ending the
/// way every Unix filter does.
#[cfg(unix)]
fn default_sigpipe() {
    use std::ffi::c_int;
    unsafe extern "C" {
        // `sighandler_t signal(int, sighandler_t)`; handlers passed as addresses.
        fn signal(signum: c_int, handler: usize) -> usize;
    }
    const SIGPIPE: c_int = 13;
    const SIG_DFL: usize = 0;
    // SAFETY: called first thing in main, before any thread is spawned; SIG_DFL is a valid
    // disposition for SIGPIPE.
    unsafe {
        signal(SIGPIPE, SIG_DFL);
    }
}

/// An error and its causes on one line, each text once: a cause whose text the message
/// already contains (an OS error that a path error formats into its own text) is not
/// repeated.
fn message(e: &anyhow::Error) -> String {
    let mut out = e.to_string();
    for cause in e.chain().skip(1) {
        let text = cause.to_string();
        if !out.contains(&text) {
            out.push_str(": ");
            out.push_str(&text);
        }
    }
    out
}

fn main() {
    #[cfg(unix)]
    default_sigpipe();
    let args = cli::Cli::parse();
    let code = match cli::dispatch(args) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {}", message(&e));
            cli::exit_code_of(&e)
        }
    };
    std::process::exit(code);
}
