//! The conformance problems that loading accepts but `kneebench validate` reports and
//! `kneebench run` (and the Python package's `run`) refuse unless forced: the model
//! description's semantic problems, the types platform, and optional functions that the
//! capability flags promise but the binary does not export.

use model_description::ModelDescription;

use crate::Fmu;

/// The semantic problems of a model description (`kneebench run` refuses an FMU with any
/// unless `--force`).
pub fn description_problems(md: &ModelDescription) -> Vec<String> {
    md.check()
        .into_iter()
        .map(|p| format!("model description: {}", p.message))
        .collect()
}

/// The problems of a loaded FMU that loading itself accepts: the types platform, and
/// optional functions its capability flags promise but its binary does not export
/// (`kneebench run` refuses such an FMU unless `--force`).
pub fn binary_problems(fmu: &Fmu) -> Vec<String> {
    let md = fmu.model_description();
    let mut problems = Vec::new();
    let platform = fmu.types_platform();
    if platform != "default" {
        problems.push(format!(
            "fmi2GetTypesPlatform returns '{platform}', expected 'default'"
        ));
    }
    let cs = md.co_simulation.clone().unwrap_or_default();
    let missing = fmu.missing_optional_functions();
    let mut promised: Vec<&str> = Vec::new();
    if cs.can_get_and_set_fmu_state == Some(true) {
        promised.extend(["fmi2GetFMUstate", "fmi2SetFMUstate", "fmi2FreeFMUstate"]);
    }
    if cs.can_serialize_fmu_state == Some(true) {
        promised.extend([
            "fmi2SerializedFMUstateSize",
            "fmi2SerializeFMUstate",
            "fmi2DeSerializeFMUstate",
        ]);
    }
    if cs.provides_directional_derivative == Some(true) {
        promised.push("fmi2GetDirectionalDerivative");
    }
    if cs.max_output_derivative_order.unwrap_or(0) > 0 {
        promised.push("fmi2GetRealOutputDerivatives");
    }
    if cs.can_interpolate_inputs == Some(true) {
        promised.push("fmi2SetRealInputDerivatives");
    }
    for f in promised {
        if missing.contains(&f) {
            problems.push(format!(
                "the capability flags promise {f}, which the binary does not export"
            ));
        }
    }
    problems
}
