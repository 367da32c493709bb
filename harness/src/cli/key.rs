//! `kneebench key`: the bench's secret key file.

use std::path::PathBuf;

use anyhow::Context;
use kneebench_harness::bench_protocol::Key;

/// Arguments of `kneebench key`.
#[derive(Debug, clap::Args)]
#[command(after_help = "\
Examples:
  kneebench key new lab-bench.key      # 32 random bytes as hex, mode 0600
  kneebench key check lab-bench.key
The bench server uses it (kneebench emulate --key FILE); the same file goes to every master
(the BenchHardware parameter keyFile). A key file that its group or others may read,
that another user owns or could replace (its directory), or that holds a key that is no
secret (the public loopback key, 64 zeros) is refused.")]
pub struct Args {
    /// What to do.
    #[command(subcommand)]
    pub action: Action,
}

/// The key actions.
#[derive(Debug, clap::Subcommand)]
pub enum Action {
    /// Write a new random key to FILE (created with mode 0600; an existing file is kept).
    New {
        /// The key file to create.
        file: PathBuf,
    },
    /// Check that FILE holds a secret key, is owned by this user, only they may read it, and
    /// no other user can replace it; says what is wrong otherwise.
    Check {
        /// The key file.
        file: PathBuf,
    },
}

/// Runs `kneebench key`.
pub fn run(args: Args) -> anyhow::Result<i32> {
    match args.action {
        Action::New { file } => {
            Key::create_file(&file).with_context(|| "kneebench key new".to_string())?;
            eprintln!(
                "kneebench key: wrote a new bench key to {} (mode 0600); give the same file to the bench server and its masters",
                file.display()
            );
        }
        Action::Check { file } => {
            Key::load_file(&file)?;
            eprintln!(
                "kneebench key: {} holds a key, private to its owner",
                file.display()
            );
        }
    }
    Ok(super::EXIT_OK)
}
