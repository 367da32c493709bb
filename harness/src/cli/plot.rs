//! `kneebench plot`.

use std::path::PathBuf;

use kneebench_harness::Results;
use kneebench_harness::results::ResultsError;
use kneebench_harness::results::plot::{self, plot_signals};

/// Arguments of `kneebench plot`.
#[derive(Debug, clap::Args)]
#[command(after_help = "\
Examples:
  kneebench plot gait.csv --signals kneeAngleReference,kneeVelocityReference --out knee.svg
  kneebench plot gait.csv --out all.png          # every column, when there are at most 12
The format follows the extension of --out (.svg or .png). Text uses an embedded font, so no
system font library is needed. A file with more than 12 columns is refused without --signals:
one chart of a hundred curves is unreadable.")]
pub struct Args {
    /// A results file as `kneebench run` writes it: CSV (header `time,<names>`) or Parquet.
    pub results: PathBuf,
    /// Comma-separated column names to plot (default: every column, at most 12).
    // 12 is MAX_DEFAULT_COLUMNS (a doc comment cannot name a constant's value; a test checks).
    #[arg(long, visible_alias = "variables", value_delimiter = ',')]
    pub signals: Vec<String>,
    /// Output image: .svg or .png.
    #[arg(long, default_value = "plot.svg")]
    pub out: PathBuf,
    /// Image width in pixels (1 to 16384).
    #[arg(long, default_value_t = 1024, value_parser = side())]
    pub width: u32,
    /// Image height in pixels (1 to 16384).
    #[arg(long, default_value_t = 640, value_parser = side())]
    pub height: u32,
}

/// The parser of `--width` and `--height`: 1 to [`MAX_SIDE`](plot::MAX_SIDE) pixels (refused
/// while parsing, a usage error, before the file is read).
fn side() -> clap::builder::RangedI64ValueParser<u32> {
    clap::value_parser!(u32).range(1..=i64::from(plot::MAX_SIDE))
}

/// The most columns `kneebench plot` draws when `--signals` does not choose.
pub const MAX_DEFAULT_COLUMNS: usize = 12;

/// Runs `kneebench plot`.
pub fn run(a: Args) -> anyhow::Result<i32> {
    // Usage errors (exit code 2): an --out of another format, checked before the file is read,
    // and --signals that are no columns of it.
    plot::image_format(&a.out).map_err(|e| super::Usage(format!("--out: {e}")))?;
    let r = Results::read_file(&a.results)?;
    let names: Vec<&str> = if a.signals.is_empty() {
        let names = r.names();
        // A usage error: the command needs --signals for such a file.
        if names.len() > MAX_DEFAULT_COLUMNS {
            return Err(super::Usage(format!(
                "{} has {} columns, too many for one readable chart: choose up to {MAX_DEFAULT_COLUMNS} with --signals (or --variables), e.g. --signals {}",
                a.results.display(),
                names.len(),
                names.iter().take(3).cloned().collect::<Vec<_>>().join(",")
            ))
            .into());
        }
        names.iter().map(String::as_str).collect()
    } else {
        a.signals.iter().map(String::as_str).collect()
    };
    plot_signals(&r, &names, &a.out, (a.width, a.height)).map_err(|e| {
        let message = format!("plotting into {}: {e}", a.out.display());
        match e {
            ResultsError::UnknownSignal(..) => super::Usage(message).into(),
            e => anyhow::Error::from(e).context(format!("plotting into {}", a.out.display())),
        }
    })?;
    eprintln!("wrote {}", a.out.display());
    Ok(super::EXIT_OK)
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[derive(Debug, clap::Parser)]
    struct Cli {
        #[command(flatten)]
        args: Args,
    }

    /// The help states [`MAX_DEFAULT_COLUMNS`]'s value wherever it speaks of the limit (it
    /// showed the constant's name, `MAX_DEFAULT_COLUMNS`, in backquotes).
    #[test]
    fn the_help_states_the_default_column_limit() {
        let help = Cli::command().render_long_help().to_string();
        assert!(!help.contains("MAX_DEFAULT_COLUMNS"), "{help}");
        let n = MAX_DEFAULT_COLUMNS;
        for says in [
            format!("every column, at most {n})"),
            format!("every column, when there are at most {n}"),
            format!("more than {n} columns"),
        ] {
            assert!(help.contains(&says), "no '{says}' in:\n{help}");
        }
    }
}
