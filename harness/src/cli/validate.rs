//! `kneebench validate`.

use std::path::PathBuf;

use kneebench_harness::conformance::{binary_problems, description_problems};
use kneebench_harness::load::{ArchiveLimits, extract_and_parse};
use kneebench_harness::{Binaries, Fmu, InstanceOptions, LoadOptions};

/// Arguments of `kneebench validate`.
#[derive(Debug, clap::Args)]
#[command(after_help = "\
Checks, in order (the first failing step stops):
  1. the archive extracts safely (no path escapes, no symlinks, bounded sizes)
  2. modelDescription.xml parses, and its semantic checks pass (names, value references,
     causality/variability/initial, ModelStructure)
  3. a CoSimulation element and binaries/linux64/<modelIdentifier>.so exist
  4. the binary loads and exports every required FMI 2.0 function (and the optional ones its
     capability flags promise), and reports version 2.0 and types platform 'default'
  5. fmi2Instantiate accepts the description's GUID

Examples:
  kneebench validate out/fmus/GaitReference.fmu
An FMU that needs a host runtime (a Python slave needs libpython, for example) is checked
with that library loaded first: --preload /path/to/libpython3.so.
Exit code 0 when valid, 1 when a problem was found.")]
pub struct Args {
    /// The FMU archive.
    pub fmu: PathBuf,
    /// Shared libraries to load globally first (host runtimes such as libpython).
    #[arg(long)]
    pub preload: Vec<PathBuf>,
}

/// Runs `kneebench validate`.
pub fn run(a: Args) -> anyhow::Result<i32> {
    let mut problems: Vec<String> = Vec::new();
    let limits = ArchiveLimits::default();
    let md = match extract_and_parse(&a.fmu, &limits) {
        Ok((_dir, md)) => md,
        Err(e) => {
            println!("INVALID: {e}");
            return Ok(super::EXIT_ERROR);
        }
    };
    println!("ok: archive extracted safely; modelDescription.xml parsed");
    problems.extend(description_problems(&md));
    let fmu = match Fmu::load(
        &a.fmu,
        &LoadOptions {
            limits,
            preload: a.preload.clone(),
            // The FMU as it is: its own copy of its binary, named inside its directory.
            binaries: Binaries::Private,
            ..LoadOptions::default()
        },
    ) {
        Ok(f) => f,
        Err(e) => {
            problems.push(e.to_string());
            return report(problems);
        }
    };
    println!(
        "ok: {} loaded; every required FMI 2.0 function is exported",
        fmu.binary_path()
            .strip_prefix(fmu.directory())
            .unwrap_or(fmu.binary_path())
            .display()
    );
    problems.extend(binary_problems(&fmu));
    match fmu.instantiate("validate", &InstanceOptions::default()) {
        Ok(i) => {
            drop(i);
            println!("ok: fmi2Instantiate accepted GUID {}", md.guid);
        }
        Err(e) => problems.push(e.to_string()),
    }
    report(problems)
}

fn report(problems: Vec<String>) -> anyhow::Result<i32> {
    if problems.is_empty() {
        println!("VALID");
        Ok(super::EXIT_OK)
    } else {
        for p in &problems {
            println!("problem: {p}");
        }
        println!("INVALID: {} problem(s)", problems.len());
        Ok(super::EXIT_ERROR)
    }
}
