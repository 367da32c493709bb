//! Parameter sets: named, versioned values of an FMU's parameters with their units, carried as
//! SSP 1.0 parameter-value files (`.ssv`).
//!
//! A [`ParameterSet`] is what `kneebench run/study/experiment --params set.ssv` applies and
//! what `kneebench identify` writes. It is checked against the FMU it is applied to
//! ([`ParameterSet::check`]): every name must be a parameter of the FMU, a Real's unit must be
//! the variable's declared unit, and a value must lie in the variable's `[min, max]`; each
//! refusal names the file and the line. [`ParameterSet::content_hash`] is the SHA-256 of the
//! values alone (names, types, values and units, sorted by name), so two files with the same
//! values have the same hash whatever their formatting, name or version; results record the
//! set as [`ParameterSet::label`] (name, version and hash).
//!
//! The default set ([`ParameterSet::defaults_of`]) is generated from the FMU's declared
//! parameters (every Real parameter's start value, with its unit): for `BenchPlant.fmu`, the
//! bench facts of bench-model.md, with no second copy of the numbers.

mod apply;
mod ssv;

pub use apply::{DEFAULT_COMPONENT, apply_spec};

use std::path::{Path, PathBuf};

use model_description::{
    Causality, Initial, ModelDescription, ScalarVariable, Variability, VariableKind,
};

use crate::load::Fmu;
use crate::master::{Value, VarType};
use model_description::num::Num;

/// Errors of reading, writing and checking parameter sets.
#[derive(Debug, thiserror::Error)]
pub enum ParamsError {
    /// The file could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// Malformed XML.
    #[error("{file}:{line}: malformed XML: {message}")]
    Syntax {
        /// The file.
        file: String,
        /// 1-based line.
        line: usize,
        /// The parser's message.
        message: String,
    },
    /// Well-formed but not a usable parameter set, or refused by the FMU it is applied to.
    #[error("{file}:{line}: {problem}")]
    Invalid {
        /// The file.
        file: String,
        /// 1-based line (of the parameter's element).
        line: usize,
        /// What is wrong.
        problem: String,
    },
    /// `COMPONENT=SET.ssv` names a component the system does not have.
    #[error("{spec}: {system} has no component '{component}' (its components: {})", .components.join(", "))]
    NoComponent {
        /// The option's value as given.
        spec: String,
        /// The system (its file).
        system: String,
        /// The component named.
        component: String,
        /// The system's components.
        components: Vec<String>,
    },
    /// The FMU or system the set is applied to could not be read, or refused a value.
    #[error("{0}")]
    Target(String),
}

/// A parameter's value.
#[derive(Debug, Clone, PartialEq)]
pub enum ParamValue {
    /// `ssv:Real`.
    Real(f64),
    /// `ssv:Integer`.
    Integer(i32),
    /// `ssv:Boolean`.
    Boolean(bool),
    /// `ssv:String`.
    String(String),
}

impl ParamValue {
    /// The value as the master sets it.
    pub fn to_value(&self) -> Value {
        match self {
            ParamValue::Real(v) => Value::Real(*v),
            ParamValue::Integer(v) => Value::Integer(*v),
            ParamValue::Boolean(v) => Value::Boolean(*v),
            ParamValue::String(v) => Value::String(v.clone()),
        }
    }

    /// The value as text (`--param NAME=VALUE` form; Reals exact).
    pub fn to_text(&self) -> String {
        match self {
            ParamValue::Real(v) => ssv::xs_double(*v),
            ParamValue::Integer(v) => v.to_string(),
            ParamValue::Boolean(v) => v.to_string(),
            ParamValue::String(v) => v.clone(),
        }
    }
}

/// One parameter of a set.
#[derive(Debug, Clone, PartialEq)]
pub struct Parameter {
    /// The FMU variable's name.
    pub name: String,
    /// The value.
    pub value: ParamValue,
    /// The unit of a Real value (`None`: the variable's declared unit is assumed).
    pub unit: Option<String>,
    /// The line it was read from (0 for a set built in memory).
    pub line: usize,
}

/// A unit definition (`ssc:Unit` with its `ssc:BaseUnit`): SI exponents, factor and offset.
#[derive(Debug, Clone, PartialEq)]
pub struct UnitDefinition {
    /// The unit's name as the parameters use it.
    pub name: String,
    /// Exponents of kg, m, s, A, K, mol, cd, rad.
    pub exponents: [i32; 8],
    /// Factor to SI.
    pub factor: f64,
    /// Offset to SI.
    pub offset: f64,
}

const EXPONENT_NAMES: [&str; 8] = ["kg", "m", "s", "A", "K", "mol", "cd", "rad"];

impl UnitDefinition {
    /// A unit with all exponents 0, factor 1, offset 0.
    pub fn dimensionless(name: &str) -> UnitDefinition {
        UnitDefinition {
            name: name.to_string(),
            exponents: [0; 8],
            factor: 1.0,
            offset: 0.0,
        }
    }

    fn exponents(&self) -> impl Iterator<Item = (&'static str, i32)> + '_ {
        EXPONENT_NAMES.iter().copied().zip(self.exponents)
    }

    fn exponent_mut(&mut self, key: &str) -> Option<&mut i32> {
        let i = EXPONENT_NAMES.iter().position(|n| *n == key)?;
        Some(&mut self.exponents[i])
    }

    fn from_model_description(u: &model_description::Unit) -> UnitDefinition {
        let mut d = UnitDefinition::dimensionless(&u.name);
        if let Some(b) = &u.base_unit {
            d.exponents = [b.kg, b.m, b.s, b.a, b.k, b.mol, b.cd, b.rad].map(|e| e.unwrap_or(0));
            d.factor = b.factor.unwrap_or(1.0);
            d.offset = b.offset.unwrap_or(0.0);
        }
        d
    }
}

/// A named, versioned set of parameter values (one `.ssv` file).
#[derive(Debug, Clone, PartialEq)]
pub struct ParameterSet {
    /// The set's name (`name`).
    pub name: String,
    /// The set's own version (`fileversion`).
    pub version: String,
    /// What it is (`description`).
    pub description: Option<String>,
    /// The values, in file order.
    pub parameters: Vec<Parameter>,
    /// The definitions of the units the values use.
    pub units: Vec<UnitDefinition>,
}

impl ParameterSet {
    /// An empty set.
    pub fn new(name: &str, version: &str) -> ParameterSet {
        ParameterSet {
            name: name.to_string(),
            version: version.to_string(),
            description: None,
            parameters: Vec::new(),
            units: Vec::new(),
        }
    }

    /// The default set of an FMU: every Real parameter (causality `parameter`) with its start
    /// value and unit, the units defined as the model description defines them.
    pub fn defaults_of(md: &ModelDescription, name: &str, version: &str) -> ParameterSet {
        let mut set = ParameterSet::new(name, version);
        set.description = Some(format!(
            "start values of the parameters of {} (GUID {})",
            md.model_name, md.guid
        ));
        for v in &md.model_variables {
            if v.causality != Some(Causality::Parameter) {
                continue;
            }
            if let VariableKind::Real {
                attributes,
                start: Some(start),
                ..
            } = &v.kind
            {
                set.parameters.push(Parameter {
                    name: v.name.clone(),
                    value: ParamValue::Real(*start),
                    unit: attributes.unit.clone(),
                    line: 0,
                });
            }
        }
        set.define_units(md);
        set
    }

    /// Adds the definitions (from `md`) of every unit the values use and `units` lacks.
    pub fn define_units(&mut self, md: &ModelDescription) {
        for p in &self.parameters {
            let Some(u) = &p.unit else { continue };
            if self.units.iter().any(|d| &d.name == u) {
                continue;
            }
            let def = md
                .unit_definitions
                .iter()
                .find(|d| &d.name == u)
                .map(UnitDefinition::from_model_description)
                .unwrap_or_else(|| UnitDefinition::dimensionless(u));
            self.units.push(def);
        }
    }

    /// Sets (or adds) a Real value with its unit.
    pub fn set_real(&mut self, name: &str, value: f64, unit: Option<&str>) {
        match self.parameters.iter_mut().find(|p| p.name == name) {
            Some(p) => {
                p.value = ParamValue::Real(value);
                p.unit = unit.map(str::to_string);
            }
            None => self.parameters.push(Parameter {
                name: name.to_string(),
                value: ParamValue::Real(value),
                unit: unit.map(str::to_string),
                line: 0,
            }),
        }
    }

    /// A Real value by name.
    pub fn real(&self, name: &str) -> Option<f64> {
        self.parameters
            .iter()
            .find(|p| p.name == name)
            .and_then(|p| match p.value {
                ParamValue::Real(v) => Some(v),
                _ => None,
            })
    }

    /// Reads an `.ssv` document (`file` names it in errors).
    pub fn from_xml(text: &str, file: &str) -> Result<ParameterSet, ParamsError> {
        ssv::read(text, file)
    }

    /// Reads an `.ssv` file.
    pub fn read_file(path: &Path) -> Result<ParameterSet, ParamsError> {
        let text = std::fs::read_to_string(path).map_err(|source| ParamsError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        ParameterSet::from_xml(&text, &path.display().to_string())
    }

    /// Reads an `.ssv` file and checks it against `md` ([`Self::check`]).
    pub fn read_for(path: &Path, md: &ModelDescription) -> Result<ParameterSet, ParamsError> {
        let set = ParameterSet::read_file(path)?;
        set.check(md, &path.display().to_string())?;
        Ok(set)
    }

    /// The set as SSV 1.0 XML.
    pub fn to_xml(&self) -> String {
        ssv::to_xml(self)
    }

    /// Writes the set as an `.ssv` file.
    pub fn write_file(&self, path: &Path) -> Result<(), ParamsError> {
        std::fs::write(path, self.to_xml()).map_err(|source| ParamsError::Io {
            path: path.to_path_buf(),
            source,
        })
    }

    /// SHA-256 (hex) of the values: `name type value [unit]` per parameter, sorted by name.
    pub fn content_hash(&self) -> String {
        use sha2::Digest;
        let mut lines: Vec<String> = self
            .parameters
            .iter()
            .map(|p| {
                let ty = match p.value {
                    ParamValue::Real(_) => "Real",
                    ParamValue::Integer(_) => "Integer",
                    ParamValue::Boolean(_) => "Boolean",
                    ParamValue::String(_) => "String",
                };
                let value = match &p.value {
                    ParamValue::String(s) => format!("{s:?}"),
                    v => v.to_text(),
                };
                format!(
                    "{} {ty} {value} {}",
                    p.name,
                    p.unit.as_deref().unwrap_or("")
                )
            })
            .collect();
        lines.sort();
        let mut h = sha2::Sha256::new();
        for l in &lines {
            h.update(l.as_bytes());
            h.update(b"\n");
        }
        h.finalize().iter().map(|b| format!("{b:02x}")).collect()
    }

    /// `name version (sha256 hash)`: how result files name the set.
    pub fn label(&self) -> String {
        let version = if self.version.is_empty() {
            String::new()
        } else {
            format!(" v{}", self.version)
        };
        format!("{}{version} (sha256 {})", self.name, self.content_hash())
    }

    /// Checks the set against the FMU it is applied to: every name a parameter of the FMU,
    /// the value of its type, a Real's unit the declared unit, the value inside the declared
    /// `[min, max]`. `file` names the set in errors (with each parameter's line).
    pub fn check(&self, md: &ModelDescription, file: &str) -> Result<(), ParamsError> {
        for p in &self.parameters {
            let bad = |problem: String| ParamsError::Invalid {
                file: file.to_string(),
                line: p.line,
                problem: format!("parameter '{}': {problem}", p.name),
            };
            let Some(v) = md.model_variables.iter().find(|v| v.name == p.name) else {
                return Err(bad(format!(
                    "{} has no variable of this name",
                    md.model_name
                )));
            };
            if v.causality != Some(Causality::Parameter) {
                return Err(bad(format!(
                    "is not a parameter of {} (causality {:?})",
                    md.model_name, v.causality
                )));
            }
            check_value(md, v, &p.value, p.unit.as_deref()).map_err(bad)?;
        }
        Ok(())
    }

    /// The values as `(name, value)` for the master.
    pub fn assignments(&self) -> Vec<(String, Value)> {
        self.parameters
            .iter()
            .map(|p| (p.name.clone(), p.value.to_value()))
            .collect()
    }
}

/// Checks the value `value` (with its unit, if any) of the parameter `v` of `md`: of the
/// variable's type, a Real's unit the declared unit, then [`value_problem`]'s checks (finite,
/// inside the declared `[min, max]`, one of the items). Says what is wrong.
fn check_value(
    md: &ModelDescription,
    v: &ScalarVariable,
    value: &ParamValue,
    unit: Option<&str>,
) -> Result<(), String> {
    match (&v.kind, value) {
        (VariableKind::Real { attributes, .. }, ParamValue::Real(_)) => {
            let declared = attributes.unit.as_deref();
            if let Some(u) = unit
                && Some(u) != declared
            {
                return Err(format!(
                    "unit '{u}' is not the declared unit '{}'",
                    declared.unwrap_or("(none)")
                ));
            }
        }
        (
            VariableKind::Integer { .. } | VariableKind::Enumeration { .. },
            ParamValue::Integer(_),
        )
        | (VariableKind::Boolean { .. }, ParamValue::Boolean(_))
        | (VariableKind::String { .. }, ParamValue::String(_)) => {}
        (kind, value) => {
            let declared = match kind {
                VariableKind::Real { .. } => "Real",
                VariableKind::Integer { .. } => "Integer",
                VariableKind::Boolean { .. } => "Boolean",
                VariableKind::String { .. } => "String",
                VariableKind::Enumeration { .. } => "Enumeration",
            };
            return Err(format!(
                "{} value for a {declared} variable",
                match value {
                    ParamValue::Real(_) => "a Real",
                    ParamValue::Integer(_) => "an Integer",
                    ParamValue::Boolean(_) => "a Boolean",
                    ParamValue::String(_) => "a String",
                }
            ));
        }
    }
    value_problem(md, v, &value.to_value()).map_or(Ok(()), Err)
}

/// Checks parameter values given as text, `(name, value)` as `--param NAME=VALUE` gives them,
/// against the FMU `fmu` they are to be set on, before anything runs ([`parameter_value`]:
/// each name a parameter of the FMU, each value of its type, finite, inside the declared
/// `[min, max]`, one of the items). Says what is wrong with the first value refused.
pub fn check_assignments(fmu: &Fmu, assignments: &[(String, String)]) -> Result<(), String> {
    let md = fmu.model_description();
    for (name, text) in assignments {
        parameter_value(md, name, text).map_err(|e| e.to_string())?;
    }
    Ok(())
}

/// Checks a value about to be set on variable `name` of `md` before the FMU is initialized
/// (`kneebench run --param`): the variable can take a value then (not a constant; an input,
/// or `initial` exact or approx: a parameter, a start value), and the value passes the checks
/// of [`ParameterSet::check`] (its type, inside the declared `[min, max]`, one of the items).
/// Says what is wrong, so that the FMU never has to refuse the value as the run starts.
pub fn check_start_value(md: &ModelDescription, name: &str, value: &Value) -> Result<(), String> {
    let Some(v) = md.model_variables.iter().find(|v| v.name == name) else {
        return Err(format!("'{name}' is not a variable of {}", md.model_name));
    };
    let settable = v.variability != Some(Variability::Constant)
        && (v.causality == Some(Causality::Input)
            || matches!(
                v.initial_or_default(),
                Some(Initial::Exact | Initial::Approx)
            ));
    if !settable {
        return Err(format!(
            "{name} (causality {}, variability {}) takes no value before initialization: \
             only parameters, inputs and start values do",
            v.causality
                .map_or("local".into(), |c| format!("{c:?}").to_lowercase()),
            v.variability
                .map_or("continuous".into(), |c| format!("{c:?}").to_lowercase()),
        ));
    }
    // An infinity for a Real that declares no bound on its side is left to the FMU: the
    // standard does not forbid it, and a foreign FMU may take it (our FMUs refuse it at
    // fmi2SetReal, and the run then fails naming the value).
    if let (VariableKind::Real { attributes, .. }, Value::Real(x)) = (&v.kind, value)
        && x.is_infinite()
        && (if *x > 0.0 {
            attributes.max
        } else {
            attributes.min
        })
        .is_none()
    {
        return Ok(());
    }
    value_problem(md, v, value).map_or(Ok(()), Err)
}

/// [`check_start_value`] for `reference` (`component.variable`) of `system`, the component's
/// model description found in the system (a reference it cannot resolve is left to
/// [`System::set_value`](crate::master::System::set_value), which names it).
pub fn check_system_start_value(
    system: &crate::master::System,
    reference: &str,
    value: &Value,
) -> Result<(), String> {
    let Some((component, variable)) = reference.split_once('.') else {
        return Ok(());
    };
    match system.components().find(|(c, _)| *c == component) {
        Some((_, fmu)) => check_start_value(fmu.model_description(), variable, value),
        None => Ok(()),
    }
}

/// Why `x` cannot be the value of `v` when `v` has named values (an Enumeration, or one of our
/// FMUs' modes declared as Integer) and `x` is none of them; `None` otherwise.
fn not_an_item(md: &ModelDescription, v: &ScalarVariable, x: i32) -> Option<String> {
    let (type_name, items) = md.items_of(v)?;
    (!items.iter().any(|i| i.value == x)).then(|| {
        format!(
            "{x} is no item of {type_name} ({})",
            items
                .iter()
                .map(|i| format!("{} = {}", i.value, i.name))
                .collect::<Vec<_>>()
                .join(", ")
        )
    })
}

/// Why `value` cannot be the value of `v` (a value of `v`'s type): a Real that is not finite,
/// a fraction for a Real that takes whole numbers only
/// ([`ScalarVariable::is_integer_valued`]), a number outside the declared `[min, max]`, an
/// integer that is no item of `v`'s named values; `None` when it can.
fn value_problem(md: &ModelDescription, v: &ScalarVariable, value: &Value) -> Option<String> {
    match (&v.kind, value) {
        (VariableKind::Real { attributes, .. }, Value::Real(x)) => {
            let min = attributes.min.unwrap_or(f64::NEG_INFINITY);
            let max = attributes.max.unwrap_or(f64::INFINITY);
            if !x.is_finite() {
                Some(format!("{} is not a finite number", Num(*x)))
            } else if v.is_integer_valued() && x.fract() != 0.0 {
                Some(format!(
                    "{} is not an integer (a Real that takes whole numbers only)",
                    Num(*x)
                ))
            } else if !(min..=max).contains(x) {
                Some(format!(
                    "{} is outside [{}, {}]",
                    Num(*x),
                    Num(min),
                    Num(max)
                ))
            } else {
                None
            }
        }
        (VariableKind::Integer { attributes, .. }, Value::Integer(x)) => {
            let min = attributes.min.unwrap_or(i32::MIN);
            let max = attributes.max.unwrap_or(i32::MAX);
            if (min..=max).contains(x) {
                not_an_item(md, v, *x)
            } else {
                Some(format!("{x} is outside [{min}, {max}]"))
            }
        }
        (VariableKind::Enumeration { min, max, .. }, Value::Integer(x)) => {
            if min.is_some_and(|m| *x < m) || max.is_some_and(|m| *x > m) {
                Some(format!("{x} is not an item of the enumeration"))
            } else {
                not_an_item(md, v, *x)
            }
        }
        _ => None,
    }
}

/// Why a parameter given as `NAME=VALUE` text ([`parameter_value`]) is refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ParameterError {
    /// The FMU has no parameter of this name.
    #[error("'{name}' is not a parameter of {model} (its parameters: {})", .parameters.join(", "))]
    NotAParameter {
        /// The name given.
        name: String,
        /// The FMU's model name.
        model: String,
        /// The FMU's parameters (causality `parameter`), in the model description's order.
        parameters: Vec<String>,
    },
    /// The value does not read as the parameter's type, is not finite, lies outside the
    /// declared `[min, max]` or is none of the parameter's named values.
    #[error("{name} = '{text}': {problem}")]
    BadValue {
        /// The parameter.
        name: String,
        /// The value as given.
        text: String,
        /// What is wrong (with the bounds or the items).
        problem: String,
    },
}

/// The value of the parameter `name` of the FMU that `md` describes, read from `text` as the
/// parameter's type (a number; `true`/`false` for a Boolean; an item's name or value for an
/// Enumeration or an Integer with named values) and checked as [`ParameterSet::check`]
/// checks a set's values: finite, inside the declared `[min, max]`, one of the items. What
/// `--param NAME=VALUE` of `kneebench identify` and `study` is checked with before anything
/// runs.
pub fn parameter_value(
    md: &ModelDescription,
    name: &str,
    text: &str,
) -> Result<Value, ParameterError> {
    let is_parameter = |v: &&ScalarVariable| v.causality == Some(Causality::Parameter);
    let Some(v) = md
        .model_variables
        .iter()
        .filter(is_parameter)
        .find(|v| v.name == name)
    else {
        return Err(ParameterError::NotAParameter {
            name: name.to_string(),
            model: md.model_name.clone(),
            parameters: md
                .model_variables
                .iter()
                .filter(is_parameter)
                .map(|v| v.name.clone())
                .collect(),
        });
    };
    let bad = |problem: String| ParameterError::BadValue {
        name: name.to_string(),
        text: text.to_string(),
        problem,
    };
    // Read as the master reads a value (`Value::parse`), then an item's name.
    let t = text.trim();
    let value = match Value::parse(VarType::of(v), text) {
        Some(value) => value,
        None => match (&v.kind, md.items_of(v)) {
            (VariableKind::Real { .. }, _) => {
                return Err(bad(format!("'{t}' is not a number (a Real)")));
            }
            (VariableKind::Boolean { .. }, _) => {
                return Err(bad(format!("'{t}' is not a Boolean (true or false)")));
            }
            (_, Some((type_name, items))) => match items.iter().find(|i| i.name == t) {
                Some(item) => Value::Integer(item.value),
                None => {
                    return Err(bad(format!(
                        "'{t}' is no item of {type_name} ({})",
                        items
                            .iter()
                            .map(|i| format!("{} = {}", i.value, i.name))
                            .collect::<Vec<_>>()
                            .join(", ")
                    )));
                }
            },
            (_, None) => return Err(bad(format!("'{t}' is not an Integer"))),
        },
    };
    match value_problem(md, v, &value) {
        Some(problem) => Err(bad(problem)),
        None => Ok(value),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> ParameterSet {
        let mut s = ParameterSet::new("bench-a", "3");
        s.description = Some("a <test> & \"set\"".into());
        s.set_real("actuationInertia", 0.825, Some("kg.m2"));
        s.set_real("loadDamping", 1.0 / 3.0, None);
        s.parameters.push(Parameter {
            name: "configuration".into(),
            value: ParamValue::Integer(2),
            unit: None,
            line: 0,
        });
        s.parameters.push(Parameter {
            name: "flag".into(),
            value: ParamValue::Boolean(true),
            unit: None,
            line: 0,
        });
        s.units.push(UnitDefinition {
            exponents: [1, 2, 0, 0, 0, 0, 0, 0],
            ..UnitDefinition::dimensionless("kg.m2")
        });
        s
    }

    #[test]
    fn round_trip_is_exact_and_lines_are_recorded() {
        let s = sample();
        let xml = s.to_xml();
        let back = ParameterSet::from_xml(&xml, "t.ssv").unwrap();
        assert_eq!(back.name, s.name);
        assert_eq!(back.version, s.version);
        assert_eq!(back.description, s.description);
        assert_eq!(back.units, s.units);
        assert_eq!(back.content_hash(), s.content_hash());
        for (a, b) in back.parameters.iter().zip(&s.parameters) {
            assert_eq!((&a.name, &a.value, &a.unit), (&b.name, &b.value, &b.unit));
        }
        // Lines: the XML declaration, the root, <ssv:Parameters>, then one per parameter.
        assert_eq!(back.parameters[0].line, 4, "{xml}");
        assert_eq!(back.parameters[3].line, 7);
    }

    #[test]
    fn hash_depends_on_values_only() {
        let s = sample();
        let mut renamed = s.clone();
        renamed.name = "other".into();
        renamed.version = "9".into();
        renamed.parameters.reverse();
        assert_eq!(renamed.content_hash(), s.content_hash());
        let mut changed = s.clone();
        changed.set_real("loadDamping", 1.0 / 3.0 + 1e-15, None);
        assert_ne!(changed.content_hash(), s.content_hash());
        assert!(s.label().starts_with("bench-a v3 (sha256 "));
    }

    #[test]
    fn malformed_files_are_refused_with_the_line() {
        let cases = [
            ("<a/>", 1, "root element"),
            (
                "<ssv:ParameterSet xmlns:ssv=\"x\" version=\"1.0\" name=\"n\">\n<ssv:Parameters>\n<ssv:Parameter name=\"p\">\n<ssv:Real value=\"abc\"/></ssv:Parameter></ssv:Parameters></ssv:ParameterSet>",
                4,
                "not a number",
            ),
            (
                "<ssv:ParameterSet xmlns:ssv=\"x\" version=\"1.0\" name=\"n\">\n<ssv:Parameters>\n<ssv:Parameter name=\"p\"><ssv:Real value=\"1\"/></ssv:Parameter>\n<ssv:Parameter name=\"p\"><ssv:Real value=\"2\"/></ssv:Parameter></ssv:Parameters></ssv:ParameterSet>",
                4,
                "twice",
            ),
            (
                "<ssv:ParameterSet xmlns:ssv=\"x\" version=\"1.0\" name=\"n\">\n<ssv:Parameters>\n<ssv:Parameter name=\"p\"><ssv:Real value=\"1\" unit=\"Nm\"/></ssv:Parameter></ssv:Parameters></ssv:ParameterSet>",
                3,
                "not defined",
            ),
            (
                "<ssv:ParameterSet xmlns:ssv=\"x\" version=\"2.0\" name=\"n\"/>",
                1,
                "version",
            ),
            (
                "<ssv:ParameterSet xmlns:ssv=\"x\" version=\"1.0\" name=\"n\">\n<ssv:Parameters>\n<ssv:Parameter name=\"p\"><ssv:Real value=\"NaN\"/></ssv:Parameter></ssv:Parameters></ssv:ParameterSet>",
                3,
                "not finite",
            ),
        ];
        for (xml, line, what) in cases {
            let e = ParameterSet::from_xml(xml, "f.ssv").unwrap_err();
            let text = e.to_string();
            assert!(text.starts_with(&format!("f.ssv:{line}:")), "{text}");
            assert!(text.contains(what), "{text}");
        }
    }

    /// Malformed XML the XML reader lets through is malformed XML, not a bad version (a tag
    /// `<ssv:ParameterSet <version="1.0">` read as an attribute `<version`) or an accepted
    /// document (one that ends inside its root).
    #[test]
    fn malformed_xml_is_not_a_bad_version() {
        for (xml, line, what) in [
            (
                "<ssv:ParameterSet xmlns:ssv=\"x\"\n <version=\"1.0\" name=\"n\"/>",
                1,
                "'<version' is not an attribute name",
            ),
            (
                "<ssv:ParameterSet xmlns:ssv=\"x\" version=\"1.0<\" name=\"n\"/>",
                1,
                "the value of version holds a '<'",
            ),
            (
                "<ssv:ParameterSet xmlns:ssv=\"x\" version=\"1.0\" name=\"n\">\n<ssv:Parameters>\n",
                3,
                "ends inside",
            ),
            (
                "<?xml versio=\"1.0\"?>\n<ssv:ParameterSet xmlns:ssv=\"x\" version=\"1.0\" name=\"n\"/>",
                1,
                "starts with 'versio', not its version",
            ),
        ] {
            let e = ParameterSet::from_xml(xml, "f.ssv").unwrap_err();
            assert!(matches!(e, ParamsError::Syntax { .. }), "{e:?}");
            let text = e.to_string();
            assert!(
                text.starts_with(&format!("f.ssv:{line}: malformed XML")),
                "{text}"
            );
            assert!(text.contains(what), "{text}");
        }
    }

    /// A Real with bounds, a mode declared as Integer with named items, an Enumeration, a
    /// Boolean and an output, as `parameter_value` sees them.
    const DESCRIPTION: &str = r#"<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="m" guid="{g}">
  <CoSimulation modelIdentifier="m"/>
  <TypeDefinitions>
    <SimpleType name="Law"><Enumeration><Item name="Off" value="0"/><Item name="On" value="1"/></Enumeration></SimpleType>
    <SimpleType name="Configuration"><Integer min="0" max="2"/></SimpleType>
  </TypeDefinitions>
  <VendorAnnotations>
    <Tool name="org.kneebench.items"><IntegerItems><Type name="Configuration"><Item name="DA" value="0"/><Item name="SEA" value="1"/><Item name="CSEA" value="2"/></Type></IntegerItems></Tool>
  </VendorAnnotations>
  <ModelVariables>
    <ScalarVariable name="inertia" valueReference="1" causality="parameter" variability="fixed"><Real start="1" min="0.001" max="100"/></ScalarVariable>
    <ScalarVariable name="configuration" valueReference="2" causality="parameter" variability="fixed"><Integer declaredType="Configuration" start="1" min="0" max="2"/></ScalarVariable>
    <ScalarVariable name="law" valueReference="3" causality="parameter" variability="fixed"><Enumeration declaredType="Law" start="0"/></ScalarVariable>
    <ScalarVariable name="enabled" valueReference="4" causality="parameter" variability="fixed"><Boolean start="false"/></ScalarVariable>
    <ScalarVariable name="y" valueReference="5" causality="output" variability="continuous" initial="exact"><Real start="0"/></ScalarVariable>
  </ModelVariables>
  <ModelStructure><Outputs><Unknown index="5" dependencies=""/></Outputs></ModelStructure>
</fmiModelDescription>
"#;

    #[test]
    fn parameter_values_are_read_as_their_type_and_checked_against_the_bounds_and_items() {
        let md = ModelDescription::from_xml(DESCRIPTION).unwrap();
        let ok = |name: &str, text: &str| parameter_value(&md, name, text).unwrap();
        assert_eq!(ok("inertia", " 2 "), Value::Real(2.0));
        assert_eq!(ok("inertia", "100"), Value::Real(100.0));
        assert_eq!(ok("configuration", "CSEA"), Value::Integer(2));
        assert_eq!(ok("configuration", "1"), Value::Integer(1));
        assert_eq!(ok("law", "On"), Value::Integer(1));
        assert_eq!(ok("enabled", "true"), Value::Boolean(true));
        let problem = |name: &str, text: &str| match parameter_value(&md, name, text) {
            Err(ParameterError::BadValue { problem, .. }) => problem,
            other => panic!("{name} = {text}: {other:?}"),
        };
        assert_eq!(problem("inertia", "-1"), "-1 is outside [0.001, 100]");
        assert_eq!(
            problem("inertia", "1e-308"),
            "1e-308 is outside [0.001, 100]"
        );
        for bad in ["nan", "inf", "-inf", "1e400"] {
            assert!(
                problem("inertia", bad).contains("is not a finite number"),
                "{bad}"
            );
        }
        assert_eq!(
            problem("inertia", "heavy"),
            "'heavy' is not a number (a Real)"
        );
        assert_eq!(problem("configuration", "3"), "3 is outside [0, 2]");
        assert!(
            problem("configuration", "ESA")
                .starts_with("'ESA' is no item of Configuration (0 = DA,"),
            "{}",
            problem("configuration", "ESA")
        );
        assert_eq!(
            problem("configuration", "1.5"),
            "'1.5' is no item of Configuration (0 = DA, 1 = SEA, 2 = CSEA)"
        );
        assert_eq!(problem("law", "2"), "2 is no item of Law (0 = Off, 1 = On)");
        assert!(problem("enabled", "yes").contains("not a Boolean"));
        // The whole message names the parameter and the value as given.
        let e = parameter_value(&md, "inertia", "-1")
            .unwrap_err()
            .to_string();
        assert_eq!(e, "inertia = '-1': -1 is outside [0.001, 100]");
        // An output is no parameter; the message lists the parameters.
        let e = parameter_value(&md, "y", "1").unwrap_err();
        assert!(matches!(e, ParameterError::NotAParameter { .. }), "{e}");
        assert_eq!(
            e.to_string(),
            "'y' is not a parameter of m (its parameters: inertia, configuration, law, enabled)"
        );
    }
}
