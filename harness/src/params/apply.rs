//! Applying a parameter set to what `kneebench run` runs: a single FMU or one component of an
//! SSP system, checked against that component's model description first.

use std::path::{Path, PathBuf};

use super::{ParameterSet, ParamsError};
use crate::load::{ArchiveLimits, extract_and_parse};
use crate::master::System;

/// The component a `--params` set applies to when an SSP system is run and the option does
/// not name one (`COMPONENT=SET.ssv`): the bench's plant.
pub const DEFAULT_COMPONENT: &str = "plant";

fn target(what: &str, message: String) -> ParamsError {
    ParamsError::Target(format!("{what}: {message}"))
}

/// Applies the set named by `spec` (`SET.ssv`, or `COMPONENT=SET.ssv` for a system) to
/// `system`, which was built from `source` (an `.fmu`, `.ssp` or `.ssd`). `single` is the
/// component name of a single-FMU run. The set is checked against the component's FMU (names,
/// types, units, ranges; errors carry the set's line) before any value is set. Returns the set.
pub fn apply_spec(
    system: &mut System,
    source: &Path,
    single: Option<&str>,
    spec: &str,
) -> Result<ParameterSet, ParamsError> {
    let limits = ArchiveLimits::default();
    let (component, set_path, fmu_path, _keep) = match single {
        Some(c) => (
            c.to_string(),
            PathBuf::from(spec),
            source.to_path_buf(),
            None,
        ),
        None => {
            let (component, path) = match spec.split_once('=') {
                Some((c, p)) => (c.trim().to_string(), PathBuf::from(p.trim())),
                None => (DEFAULT_COMPONENT.to_string(), PathBuf::from(spec)),
            };
            let (ssd, base, dir) = crate::ssp::read_file(source, &limits)
                .map_err(|e| target(&source.display().to_string(), e.to_string()))?;
            let c = ssd
                .system
                .components
                .iter()
                .find(|c| c.name == component)
                .ok_or_else(|| {
                    target(
                        &source.display().to_string(),
                        format!("no component '{component}' for the parameter set {spec}"),
                    )
                })?;
            let fmu = base.join(c.source.strip_prefix("./").unwrap_or(&c.source));
            (component, path, fmu, dir)
        }
    };
    let (_dir, md) = extract_and_parse(&fmu_path, &limits)
        .map_err(|e| target(&fmu_path.display().to_string(), e.to_string()))?;
    let set = ParameterSet::read_for(&set_path, &md)?;
    for (name, value) in set.assignments() {
        system
            .set_value(&format!("{component}.{name}"), value)
            .map_err(|e| target(&set_path.display().to_string(), e.to_string()))?;
    }
    Ok(set)
}
