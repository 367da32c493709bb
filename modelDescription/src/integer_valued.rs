//! Reals that take whole numbers only: FMI 2.0 has no attribute for them, so kneebench's FMUs
//! declare such a variable a `Real` (for users' parameter files and SSPs) whose description
//! ends with [`INTEGER_NOTE`] (the plant's `encoderCountsPerRevolution`), and refuse a fraction
//! in `fmi2SetReal`. [`ScalarVariable::is_integer_valued`] reads the convention back, so that
//! an importer can refuse a fraction before the FMU would.

use crate::types::{ScalarVariable, VariableKind};

/// What the description of a Real that takes whole numbers only ends with (the whole
/// description, without the leading `"; "`, when the variable has no other).
pub const INTEGER_NOTE: &str = "; an integer";

impl ScalarVariable {
    /// Whether the variable is a `Real` that takes whole numbers only: its description ends
    /// with [`INTEGER_NOTE`] (or is `"an integer"`).
    pub fn is_integer_valued(&self) -> bool {
        let Some(d) = self.description.as_deref() else {
            return false;
        };
        matches!(self.kind, VariableKind::Real { .. })
            && (d.ends_with(INTEGER_NOTE) || d == INTEGER_NOTE.trim_start_matches("; "))
    }
}

#[cfg(test)]
mod tests {
    use crate::types::{ModelDescription, ScalarVariable};

    fn variable(xml_type: &str, description: Option<&str>) -> ScalarVariable {
        let description = description.map_or(String::new(), |d| format!(" description=\"{d}\""));
        let xml = format!(
            r#"<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="m" guid="{{g}}">
  <CoSimulation modelIdentifier="m"/>
  <ModelVariables>
    <ScalarVariable name="v" valueReference="1" causality="parameter" variability="fixed"{description}>
      <{xml_type} start="1"/>
    </ScalarVariable>
  </ModelVariables>
  <ModelStructure/>
</fmiModelDescription>"#
        );
        ModelDescription::from_xml(&xml).unwrap().model_variables[0].clone()
    }

    #[test]
    fn a_real_whose_description_ends_with_the_note_is_integer_valued() {
        assert!(
            variable("Real", Some("Encoder counts per revolution; an integer")).is_integer_valued()
        );
        assert!(variable("Real", Some("an integer")).is_integer_valued());
        assert!(!variable("Real", Some("Encoder counts per revolution")).is_integer_valued());
        assert!(!variable("Real", Some("an integer here, not at the end")).is_integer_valued());
        assert!(!variable("Real", None).is_integer_valued());
        assert!(!variable("Integer", Some("counts; an integer")).is_integer_valued());
    }
}
