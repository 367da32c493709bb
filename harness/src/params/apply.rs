//! Applying a parameter set to what `kneebench run` runs: a single FMU or one component of an
//! SSP system, checked against that component's model description (the FMU loaded) first.

use std::path::{Path, PathBuf};

use super::{ParameterSet, ParamsError};
use crate::master::System;

/// The component a `--params` set applies to when an SSP system is run and the option does
/// not name one (`COMPONENT=SET.ssv`): the bench's plant.
pub const DEFAULT_COMPONENT: &str = "plant";

/// Applies the set named by `spec` (`SET.ssv`, or `COMPONENT=SET.ssv` for a system) to
/// `system`, which was built from `source` (an `.fmu`, `.ssp` or `.ssd`, named in errors).
/// `single` is the component name of a single-FMU run. The set is checked against the model
/// description of the component's FMU in `system` (a replacement's, when one was swapped in:
/// names, types, units, ranges; errors carry the set's line) before any value is set; a
/// component `system` does not have is [`ParamsError::NoComponent`]. Returns the set.
pub fn apply_spec(
    system: &mut System,
    source: &Path,
    single: Option<&str>,
    spec: &str,
) -> Result<ParameterSet, ParamsError> {
    let (component, set_path) = match (single, spec.split_once('=')) {
        (Some(c), _) => (c.to_string(), PathBuf::from(spec)),
        (None, Some((c, p))) => (c.trim().to_string(), PathBuf::from(p.trim())),
        (None, None) => (DEFAULT_COMPONENT.to_string(), PathBuf::from(spec)),
    };
    let Some(md) = system
        .components()
        .find(|(name, _)| *name == component)
        .map(|(_, fmu)| fmu.model_description().clone())
    else {
        return Err(ParamsError::NoComponent {
            spec: spec.to_string(),
            system: source.display().to_string(),
            component,
            components: system
                .component_names()
                .iter()
                .map(|c| c.to_string())
                .collect(),
        });
    };
    let set = ParameterSet::read_for(&set_path, &md)?;
    for (name, value) in set.assignments() {
        system
            .set_value(&format!("{component}.{name}"), value)
            .map_err(|e| ParamsError::Target(format!("{}: {e}", set_path.display())))?;
    }
    Ok(set)
}
