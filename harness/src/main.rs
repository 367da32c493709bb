//! `kneebench`: run, validate, inspect and plot FMI 2.0 co-simulation FMUs and SSP systems.
//!
//! Exit codes: 0 success; 1 a run, validation or I/O error; 2 a usage error (from clap);
//! 3 the run was ended early by an FMU (fmi2Discard with fmi2Terminated; results written).

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

fn main() {
    #[cfg(unix)]
    default_sigpipe();
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
