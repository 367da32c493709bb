//! The study's settings checked before anything runs or is written: what `kneebench study`
//! refuses as a usage error (exit code 2) and [`run_study`](super::run_study) refuses first.
//! A [`CheckedStudy`] is a configuration checked once ([`CheckedStudy::new`]), each FMU's
//! model description read once for it; [`run_checked`](super::run_checked) runs it without
//! checking again.

use std::path::Path;

use model_description::ModelDescription;

use super::{HARDWARE_FMU, PLANT_FMU, Scenario, StudyConfig, StudyError, gait_scenario};
use crate::master::Value;

/// A study configuration whose settings were checked ([`CheckedStudy::new`]), with its
/// overrides converted to their variables' types: what [`run_checked`](super::run_checked)
/// runs, checked once however many times the caller checks and runs.
#[derive(Debug)]
pub struct CheckedStudy<'a> {
    config: &'a StudyConfig,
    overrides: Vec<(String, Value)>,
}

impl<'a> CheckedStudy<'a> {
    /// Checks every setting of `config` that can be checked before anything runs, in this
    /// order: at least two cycles per run ([`StudyError::Cycles`]: the first is the start-up,
    /// not analysed), a study on a bench names one actuator ([`StudyError::BenchActuators`]), the
    /// plant's parameter set is one the plant FMU takes
    /// ([`ParameterSet::check`](crate::params::ParameterSet::check):
    /// [`StudyError::ParameterSet`]), the overrides ([`checked_overrides`], kept typed) and the
    /// bench's parameters ([`BenchLink::parameters`](super::BenchLink::parameters), checked
    /// against `BenchHardware.fmu` as the overrides are: [`StudyError::BenchParameter`]). Each
    /// FMU's model description is read once. What [`run_study`](super::run_study) checks
    /// first, and what the CLI checks for every scenario before the first one runs.
    pub fn new(config: &'a StudyConfig) -> Result<CheckedStudy<'a>, StudyError> {
        if config.cycles < 2 {
            return Err(StudyError::Cycles(config.cycles));
        }
        check_bench_actuators(config)?;
        let mut descriptions = Descriptions::new(&config.fmu_dir);
        if let Some(set) = &config.parameter_set {
            set.check(
                descriptions.get(PLANT_FMU)?,
                &format!("parameter set '{}'", set.name),
            )
            .map_err(StudyError::ParameterSet)?;
        }
        let overrides = overrides_checked_with(config, &mut descriptions)?;
        if let Some(link) = config.bench.as_ref().filter(|l| !l.parameters.is_empty()) {
            let md = descriptions.get(HARDWARE_FMU)?;
            for (name, value) in &link.parameters {
                crate::params::parameter_value(md, name, value)
                    .map_err(|e| StudyError::BenchParameter(e.to_string()))?;
            }
        }
        Ok(CheckedStudy { config, overrides })
    }

    /// The configuration checked.
    pub fn config(&self) -> &'a StudyConfig {
        self.config
    }

    /// The overrides ([`StudyConfig::overrides`]), each value of its variable's type.
    pub fn overrides(&self) -> &[(String, Value)] {
        &self.overrides
    }
}

/// The model descriptions of the FMUs of one directory, each read (its archive extracted) once.
struct Descriptions<'a> {
    fmu_dir: &'a Path,
    read: Vec<(String, ModelDescription)>,
}

impl<'a> Descriptions<'a> {
    fn new(fmu_dir: &'a Path) -> Self {
        Descriptions {
            fmu_dir,
            read: Vec::new(),
        }
    }

    /// The model description of the FMU `file` of the directory.
    fn get(&mut self, file: &str) -> Result<&ModelDescription, StudyError> {
        let i = match self.read.iter().position(|(f, _)| f == file) {
            Some(i) => i,
            None => {
                let path = self.fmu_dir.join(file);
                let limits = crate::load::ArchiveLimits::default();
                let (_dir, md) = crate::load::extract_and_parse(&path, &limits).map_err(|e| {
                    StudyError::Fmu {
                        path: path.clone(),
                        message: e.to_string(),
                    }
                })?;
                self.read.push((file.to_string(), md));
                self.read.len() - 1
            }
        };
        Ok(&self.read[i].1)
    }
}

/// A study on a bench ([`StudyConfig::bench`]) runs one actuator, the one the bench is built
/// as: [`StudyConfig::actuators`] must name it (once or more, and no other).
fn check_bench_actuators(config: &StudyConfig) -> Result<(), StudyError> {
    let one = config
        .actuators
        .first()
        .is_some_and(|first| config.actuators.iter().all(|a| a == first));
    if config.bench.is_none() || one {
        return Ok(());
    }
    Err(StudyError::BenchActuators {
        given: if config.actuators.is_empty() {
            "all".to_string()
        } else {
            config
                .actuators
                .iter()
                .map(|a| a.name())
                .collect::<Vec<_>>()
                .join(", ")
        },
    })
}

/// The overrides of `config` ([`StudyConfig::overrides`]) checked against the scenario's FMUs
/// before anything runs, each value converted to its variable's declared type (an Integer
/// given for a Real, an item's name as `Value::String` for a mode): every reference must be
/// `component.name` of a component in every run the study makes (each selected actuator's
/// scenario), the name a parameter of the component's FMU and the value finite, inside the
/// declared `[min, max]` and one of the named items ([`crate::params::parameter_value`]). A
/// refusal is a [`StudyError::Parameter`] naming the reference, and the bounds or items.
pub fn checked_overrides(config: &StudyConfig) -> Result<Vec<(String, Value)>, StudyError> {
    overrides_checked_with(config, &mut Descriptions::new(&config.fmu_dir))
}

/// [`checked_overrides`] with the model descriptions read so far.
fn overrides_checked_with(
    config: &StudyConfig,
    descriptions: &mut Descriptions<'_>,
) -> Result<Vec<(String, Value)>, StudyError> {
    if config.overrides.is_empty() {
        return Ok(Vec::new());
    }
    let gait = config.scenario.gait();
    let scenarios: Vec<Scenario> = config
        .scenario
        .actuators()
        .iter()
        .filter(|a| config.actuators.is_empty() || config.actuators.contains(a))
        .map(|&a| {
            let gains = config.gains.unwrap_or_else(|| config.scenario.gains(a));
            gait_scenario(a, gait, gains, 1)
        })
        .collect();
    let mut checked = Vec::new();
    for (reference, value) in &config.overrides {
        let bad = |problem: String| StudyError::Parameter(format!("'{reference}': {problem}"));
        let (component, name) = reference
            .split_once('.')
            .ok_or_else(|| bad("not component.name (e.g. plant.actuationDamping)".into()))?;
        let mut typed = None;
        for scenario in &scenarios {
            let Some(c) = scenario.components.iter().find(|c| c.name == component) else {
                return Err(bad(format!(
                    "the {} run of {} has no component '{component}' (its components: {})",
                    scenario.name,
                    config.scenario.name(),
                    scenario
                        .components
                        .iter()
                        .map(|c| c.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                )));
            };
            let md = descriptions.get(&c.fmu)?;
            let v = crate::params::parameter_value(md, name, &value.to_text()).map_err(
                |e| match e {
                    crate::params::ParameterError::BadValue { problem, .. } => bad(problem),
                    not_a_parameter => bad(not_a_parameter.to_string()),
                },
            )?;
            typed.get_or_insert(v);
        }
        if let Some(v) = typed {
            checked.push((reference.clone(), v));
        }
    }
    Ok(checked)
}
