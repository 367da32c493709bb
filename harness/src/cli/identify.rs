//! `kneebench identify`, and the `--params SET.ssv` helpers the experiment command shares.

use std::path::Path;

use anyhow::Context;
use kneebench_harness::load::{ArchiveLimits, extract_and_parse};
use kneebench_harness::params::ParameterSet;

/// Reads the parameter set at `path` (if any) and checks it against the FMU at `fmu`.
pub fn read_set_for(path: Option<&Path>, fmu: &Path) -> anyhow::Result<Option<ParameterSet>> {
    let Some(path) = path else { return Ok(None) };
    let (_dir, md) = extract_and_parse(fmu, &ArchiveLimits::default())
        .with_context(|| format!("reading {}", fmu.display()))?;
    Ok(Some(ParameterSet::read_for(path, &md)?))
}

/// Appends "Parameter set: name vN (sha256 ...)" to a Markdown section.
pub fn append_set_line(markdown: &Path, set: &ParameterSet) -> anyhow::Result<()> {
    use std::io::Write;
    let mut f = std::fs::OpenOptions::new()
        .append(true)
        .open(markdown)
        .with_context(|| format!("opening {}", markdown.display()))?;
    writeln!(f, "\nParameter set: {}", set.label())
        .with_context(|| format!("writing {}", markdown.display()))?;
    Ok(())
}
