//! `kneebench export`.

use std::path::PathBuf;

use anyhow::Context;
use kneebench_harness::package;

/// Arguments of `kneebench export`.
#[derive(Debug, clap::Args)]
#[command(after_help = "\
Examples:
  kneebench export --out out/fmus
  kneebench export --out fmus --library target/release/libkneebench_fmu.so

Each model of the binary becomes <out>/<modelIdentifier>.fmu with modelDescription.xml,
binaries/linux64/<modelIdentifier>.so, documentation/index.html, and under extra/ the inputs
and outputs of a documented reference run (the model's default experiment, run by this
harness). The same sources give byte-identical archives.")]
pub struct Args {
    /// Directory for the .fmu files (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// The kneebench FMU binary (default: libkneebench_fmu.so next to this executable).
    #[arg(long)]
    pub library: Option<PathBuf>,
}

/// Runs `kneebench export`.
pub fn run(a: Args) -> anyhow::Result<i32> {
    let library = match a.library {
        Some(l) => l,
        None => package::default_library().context(
            "libkneebench_fmu.so not found next to the kneebench executable; \
             build it (cargo build --release -p kneebench-fmu) or pass --library",
        )?,
    };
    let written = package::export_all(&library, &a.out)?;
    for fmu in &written {
        println!("{}", fmu.path.display());
    }
    Ok(super::EXIT_OK)
}
