//! Semantic checks beyond the schema (FMI 2.0.x specification, section 2.2), and helpers that
//! answer the questions importers ask (defaults, look-ups by name and index).
//!
//! [`ModelDescription::check`] returns every problem found, not just the first. The rules:
//!
//! - Document: `fmiVersion` is `2.0`; `ModelExchange` or `CoSimulation` is present; every
//!   `modelIdentifier` is a C identifier; unit, type and log category names are unique;
//!   enumeration types have items with unique names and values; `DefaultExperiment` has
//!   `startTime < stopTime`, positive `stepSize` and `tolerance`; tool annotations are well-formed
//!   XML content (they are written verbatim).
//! - Variables: unique names; at most one `independent` variable; legal
//!   causality/variability combination (table of section 2.2.7); only `Real` variables are
//!   `continuous` (the default variability!); `initial` legal for the combination; `start`
//!   present when `initial` is `exact`/`approx` or causality is `input`/`parameter`, and absent
//!   when `initial` is `calculated` (explicit or by default) or causality is `independent`;
//!   the independent variable is a `Real`; `min <= max`, `min <= start <= max` (bounds from the
//!   variable or its declared type); `declaredType` names a type definition of the same kind;
//!   `unit`/`displayUnit` are defined in `UnitDefinitions` (display units under their unit);
//!   `derivative` names an existing `Real` variable.
//! - Value references (the alias rule): FMI 2.0 keeps one value-reference space per base type
//!   (`Real`, `Integer` shared with `Enumeration`, `Boolean`, `String`); variables of the same
//!   base type with the same value reference are *aliases* and are legal. So equal value
//!   references are only a problem when the aliases contradict each other: two members of an
//!   alias set that both carry different `start` values, or an `Enumeration` aliased with a
//!   variable of another enumeration type. Equal value references of different base types are
//!   independent and never flagged.
//! - `ModelStructure`: every index (of `Unknown`s and of `dependencies`) in `1..=n`; no `Unknown`
//!   twice in a list; `Outputs` lists exactly the `output` variables; `Derivatives` only with
//!   `ModelExchange`, and each refers to a `Real` with a `derivative` attribute;
//!   `InitialUnknowns` is exactly the set the spec demands (outputs with `initial` `approx` or
//!   `calculated`, all calculated parameters, and the states and derivatives of `Derivatives`
//!   whose `initial` is `approx` or `calculated`), sorted ascending; `dependenciesKind` only with
//!   `dependencies` and of the same length; `dependencies` of `Outputs` and `Derivatives` only
//!   refer to inputs, the independent variable and continuous states (the variables named by the
//!   `derivative` attributes of `Derivatives`; without `Derivatives`, any continuous local Real
//!   counts as a possible state); those of `InitialUnknowns`
//!   only to inputs, the independent variable and variables with `initial="exact"`.

use std::collections::{BTreeSet, HashMap, HashSet};
use std::fmt;

use crate::types::*;

/// One semantic problem found by [`ModelDescription::check`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Problem {
    /// What is wrong, naming the variable, unit, type or index concerned.
    pub message: String,
}

impl Problem {
    fn new(message: impl Into<String>) -> Self {
        Problem {
            message: message.into(),
        }
    }
}

impl fmt::Display for Problem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.message)
    }
}

/// The value-reference space of a variable: `Enumeration` shares the `Integer` space.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum BaseType {
    /// `fmi2Real` (`fmi2GetReal`/`fmi2SetReal`).
    Real,
    /// `fmi2Integer`, used by `Integer` and `Enumeration` variables.
    Integer,
    /// `fmi2Boolean`.
    Boolean,
    /// `fmi2String`.
    String,
}

impl BaseType {
    /// `"Real"`, `"Integer"`, `"Boolean"` or `"String"`.
    pub fn as_str(self) -> &'static str {
        match self {
            BaseType::Real => "Real",
            BaseType::Integer => "Integer",
            BaseType::Boolean => "Boolean",
            BaseType::String => "String",
        }
    }
}

impl VariableKind {
    /// The name of the type element: `"Real"`, `"Integer"`, `"Boolean"`, `"String"` or
    /// `"Enumeration"`. For the value-reference space (where `Enumeration` is an `Integer`), use
    /// [`VariableKind::base_type`].
    pub fn base_type_name(&self) -> &'static str {
        match self {
            VariableKind::Real { .. } => "Real",
            VariableKind::Integer { .. } => "Integer",
            VariableKind::Boolean { .. } => "Boolean",
            VariableKind::String { .. } => "String",
            VariableKind::Enumeration { .. } => "Enumeration",
        }
    }

    /// The FMI base type whose get/set functions access the variable (`Enumeration` is
    /// `Integer`).
    pub fn base_type(&self) -> BaseType {
        match self {
            VariableKind::Real { .. } => BaseType::Real,
            VariableKind::Integer { .. } | VariableKind::Enumeration { .. } => BaseType::Integer,
            VariableKind::Boolean { .. } => BaseType::Boolean,
            VariableKind::String { .. } => BaseType::String,
        }
    }

    /// `declaredType`, if any.
    pub fn declared_type(&self) -> Option<&str> {
        match self {
            VariableKind::Real { declared_type, .. }
            | VariableKind::Integer { declared_type, .. }
            | VariableKind::Boolean { declared_type, .. }
            | VariableKind::String { declared_type, .. } => declared_type.as_deref(),
            VariableKind::Enumeration { declared_type, .. } => Some(declared_type),
        }
    }

    /// Whether a `start` attribute is present.
    pub fn has_start(&self) -> bool {
        match self {
            VariableKind::Real { start, .. } => start.is_some(),
            VariableKind::Integer { start, .. } | VariableKind::Enumeration { start, .. } => {
                start.is_some()
            }
            VariableKind::Boolean { start, .. } => start.is_some(),
            VariableKind::String { start, .. } => start.is_some(),
        }
    }

    /// The `start` value as it is written in XML, if present.
    pub fn start_string(&self) -> Option<String> {
        match self {
            VariableKind::Real { start, .. } => start.map(crate::write::format_f64),
            VariableKind::Integer { start, .. } | VariableKind::Enumeration { start, .. } => {
                start.map(|s| s.to_string())
            }
            VariableKind::Boolean { start, .. } => start.map(|s| s.to_string()),
            VariableKind::String { start, .. } => start.clone(),
        }
    }
}

impl ScalarVariable {
    /// `causality`, or its schema default `local`.
    pub fn causality_or_default(&self) -> Causality {
        self.causality.unwrap_or(Causality::Local)
    }

    /// `variability`, or its schema default `continuous` (note: only legal for `Real`).
    pub fn variability_or_default(&self) -> Variability {
        self.variability.unwrap_or(Variability::Continuous)
    }

    /// `initial`, or its default from the spec's table (section 2.2.7): `exact` for constants
    /// and parameters, `calculated` for calculated parameters and for the other outputs and
    /// locals, and `None` for inputs and the independent variable (which have no `initial`).
    pub fn initial_or_default(&self) -> Option<Initial> {
        if self.initial.is_some() {
            return self.initial;
        }
        match self.causality_or_default() {
            Causality::Parameter => Some(Initial::Exact),
            Causality::CalculatedParameter => Some(Initial::Calculated),
            Causality::Input | Causality::Independent => None,
            Causality::Output | Causality::Local => {
                if self.variability_or_default() == Variability::Constant {
                    Some(Initial::Exact)
                } else {
                    Some(Initial::Calculated)
                }
            }
        }
    }
}

impl ModelDescription {
    /// A new description with `fmiVersion="2.0"`, the given name and GUID, and nothing else.
    pub fn new(model_name: impl Into<String>, guid: impl Into<String>) -> Self {
        ModelDescription {
            fmi_version: "2.0".to_owned(),
            model_name: model_name.into(),
            guid: guid.into(),
            ..ModelDescription::default()
        }
    }

    /// The variable called `name`.
    pub fn variable_by_name(&self, name: &str) -> Option<&ScalarVariable> {
        self.model_variables.iter().find(|v| v.name == name)
    }

    /// The FMI index of the variable called `name`: **1-based** (position in `ModelVariables`
    /// plus one), as used by `ModelStructure` and [`ModelDescription::variable_by_index`].
    pub fn variable_index(&self, name: &str) -> Option<usize> {
        self.model_variables
            .iter()
            .position(|v| v.name == name)
            .map(|i| i + 1)
    }

    /// The variable with the **1-based** FMI index `index` (as in `Unknown@index`).
    pub fn variable_by_index(&self, index: u32) -> Option<&ScalarVariable> {
        let i = usize::try_from(index).ok()?.checked_sub(1)?;
        self.model_variables.get(i)
    }

    /// The variables of a base type with value reference `vr` (more than one when aliased).
    pub fn variables_by_value_reference(
        &self,
        base_type: BaseType,
        vr: u32,
    ) -> impl Iterator<Item = &ScalarVariable> {
        self.model_variables
            .iter()
            .filter(move |v| v.value_reference == vr && v.kind.base_type() == base_type)
    }

    /// The type definition called `name`.
    pub fn type_definition(&self, name: &str) -> Option<&SimpleType> {
        self.type_definitions.iter().find(|t| t.name == name)
    }

    /// The unit definition called `name`.
    pub fn unit(&self, name: &str) -> Option<&Unit> {
        self.unit_definitions.iter().find(|u| u.name == name)
    }

    /// The 1-based indices `InitialUnknowns` must list, ascending, as section 2.2.8 demands:
    /// outputs with `initial` `approx` or `calculated`, calculated parameters, and the states
    /// and state derivatives named by `Derivatives` whose `initial` is `approx` or `calculated`.
    pub fn expected_initial_unknowns(&self) -> Vec<u32> {
        let mut set = BTreeSet::new();
        let not_exact = |v: &ScalarVariable| {
            matches!(
                v.initial_or_default(),
                Some(Initial::Approx | Initial::Calculated)
            )
        };
        for (i, v) in self.model_variables.iter().enumerate() {
            let Ok(index) = u32::try_from(i + 1) else {
                break;
            };
            match v.causality_or_default() {
                Causality::Output if not_exact(v) => {
                    set.insert(index);
                }
                Causality::CalculatedParameter => {
                    set.insert(index);
                }
                _ => {}
            }
        }
        for unknown in &self.model_structure.derivatives {
            if let Some(der) = self.variable_by_index(unknown.index) {
                if not_exact(der) {
                    set.insert(unknown.index);
                }
                if let VariableKind::Real {
                    derivative: Some(state),
                    ..
                } = der.kind
                    && let Some(sv) = self.variable_by_index(state)
                    && not_exact(sv)
                {
                    set.insert(state);
                }
            }
        }
        set.into_iter().collect()
    }

    /// Checks the rules the schema cannot express (see the [module docs](crate::check)) and
    /// returns every problem found; an empty vector means the description is consistent.
    pub fn check(&self) -> Vec<Problem> {
        let mut p = Vec::new();
        self.check_document(&mut p);
        self.check_variables(&mut p);
        self.check_aliases(&mut p);
        self.check_structure(&mut p);
        p
    }

    fn check_document(&self, p: &mut Vec<Problem>) {
        if self.fmi_version != "2.0" {
            p.push(Problem::new(format!(
                "fmiVersion is \"{}\", expected \"2.0\"",
                self.fmi_version
            )));
        }
        if self.model_exchange.is_none() && self.co_simulation.is_none() {
            p.push(Problem::new(
                "neither ModelExchange nor CoSimulation is present",
            ));
        }
        let identifiers = [
            (
                "ModelExchange",
                self.model_exchange
                    .as_ref()
                    .map(|m| m.model_identifier.as_str()),
            ),
            (
                "CoSimulation",
                self.co_simulation
                    .as_ref()
                    .map(|c| c.model_identifier.as_str()),
            ),
        ];
        for (element, id) in identifiers {
            if let Some(id) = id
                && !is_c_identifier(id)
            {
                p.push(Problem::new(format!(
                    "{element} modelIdentifier \"{id}\" is not a valid C identifier"
                )));
            }
        }
        duplicates(
            p,
            "unit",
            self.unit_definitions.iter().map(|u| u.name.as_str()),
        );
        duplicates(
            p,
            "type definition",
            self.type_definitions.iter().map(|t| t.name.as_str()),
        );
        duplicates(
            p,
            "log category",
            self.log_categories.iter().map(|c| c.name.as_str()),
        );
        for unit in &self.unit_definitions {
            duplicates(
                p,
                &format!("display unit of unit \"{}\"", unit.name),
                unit.display_units.iter().map(|d| d.name.as_str()),
            );
        }
        for t in &self.type_definitions {
            match &t.kind {
                SimpleTypeKind::Enumeration { items, .. } => {
                    if items.is_empty() {
                        p.push(Problem::new(format!(
                            "enumeration type \"{}\" has no items",
                            t.name
                        )));
                    }
                    duplicates(
                        p,
                        &format!("item name of enumeration type \"{}\"", t.name),
                        items.iter().map(|i| i.name.as_str()),
                    );
                    let values: Vec<String> = items.iter().map(|i| i.value.to_string()).collect();
                    duplicates(
                        p,
                        &format!("item value of enumeration type \"{}\"", t.name),
                        values.iter().map(String::as_str),
                    );
                }
                SimpleTypeKind::Real(a) => {
                    if let (Some(min), Some(max)) = (a.min, a.max)
                        && min > max
                    {
                        p.push(Problem::new(format!(
                            "type definition \"{}\" has min {min} > max {max}",
                            t.name
                        )));
                    }
                    self.check_units(p, &format!("type definition \"{}\"", t.name), a);
                }
                SimpleTypeKind::Integer(a) => {
                    if let (Some(min), Some(max)) = (a.min, a.max)
                        && min > max
                    {
                        p.push(Problem::new(format!(
                            "type definition \"{}\" has min {min} > max {max}",
                            t.name
                        )));
                    }
                }
                SimpleTypeKind::Boolean | SimpleTypeKind::String => {}
            }
        }
        if let Some(de) = &self.default_experiment {
            if let (Some(start), Some(stop)) = (de.start_time, de.stop_time)
                && start.partial_cmp(&stop) != Some(std::cmp::Ordering::Less)
            {
                p.push(Problem::new(format!(
                    "DefaultExperiment startTime {start} is not before stopTime {stop}"
                )));
            }
            if let Some(h) = de.step_size
                && !(h > 0.0 && h.is_finite())
            {
                p.push(Problem::new(format!(
                    "DefaultExperiment stepSize {h} is not a positive number"
                )));
            }
            if let Some(tol) = de.tolerance
                && !(tol > 0.0 && tol.is_finite())
            {
                p.push(Problem::new(format!(
                    "DefaultExperiment tolerance {tol} is not a positive number"
                )));
            }
        }
        for tool in &self.vendor_annotations {
            if let Err(e) = check_xml_content(&tool.content) {
                p.push(Problem::new(format!(
                    "VendorAnnotations Tool \"{}\": content is not well-formed XML: {e}",
                    tool.name
                )));
            }
        }
    }

    /// `unit`/`displayUnit` of a Real (variable or type definition) must be defined.
    fn check_units(&self, p: &mut Vec<Problem>, what: &str, a: &RealAttributes) {
        if let Some(unit_name) = &a.unit {
            match self.unit(unit_name) {
                None => p.push(Problem::new(format!(
                    "{what}: unit \"{unit_name}\" is not defined in UnitDefinitions"
                ))),
                Some(unit) => {
                    if let Some(du) = &a.display_unit
                        && !unit.display_units.iter().any(|d| &d.name == du)
                    {
                        p.push(Problem::new(format!(
                            "{what}: displayUnit \"{du}\" is not defined for unit \"{unit_name}\""
                        )));
                    }
                }
            }
        } else if let Some(du) = &a.display_unit
            && !self
                .unit_definitions
                .iter()
                .any(|u| u.display_units.iter().any(|d| &d.name == du))
        {
            p.push(Problem::new(format!(
                "{what}: displayUnit \"{du}\" is not defined in UnitDefinitions"
            )));
        }
    }

    fn check_variables(&self, p: &mut Vec<Problem>) {
        duplicates(
            p,
            "variable name",
            self.model_variables.iter().map(|v| v.name.as_str()),
        );
        let independents: Vec<&str> = self
            .model_variables
            .iter()
            .filter(|v| v.causality_or_default() == Causality::Independent)
            .map(|v| v.name.as_str())
            .collect();
        if independents.len() > 1 {
            p.push(Problem::new(format!(
                "more than one independent variable: {}",
                independents.join(", ")
            )));
        }
        for v in &self.model_variables {
            self.check_variable(p, v);
        }
    }

    fn check_variable(&self, p: &mut Vec<Problem>, v: &ScalarVariable) {
        use Causality as C;
        use Variability as V;
        let name = &v.name;
        let causality = v.causality_or_default();
        let variability = v.variability_or_default();
        let is_real = matches!(v.kind, VariableKind::Real { .. });

        let legal_pair = match causality {
            C::Parameter | C::CalculatedParameter => matches!(variability, V::Fixed | V::Tunable),
            C::Input => matches!(variability, V::Discrete | V::Continuous),
            C::Output => matches!(variability, V::Constant | V::Discrete | V::Continuous),
            C::Local => true,
            C::Independent => variability == V::Continuous,
        };
        if !legal_pair {
            p.push(Problem::new(format!(
                "variable \"{name}\": causality=\"{causality}\" with variability=\"{variability}\" \
                 is not allowed"
            )));
        }
        if variability == V::Continuous && !is_real {
            p.push(Problem::new(format!(
                "variable \"{name}\": only Real variables can be continuous, this one is {} \
                 (give variability explicitly: the default is continuous)",
                v.kind.base_type_name()
            )));
        }
        if causality == C::Independent && !is_real {
            p.push(Problem::new(format!(
                "variable \"{name}\": the independent variable must be Real"
            )));
        }

        // Allowed `initial` values for the (causality, variability) pair (section 2.2.7).
        if let Some(initial) = v.initial {
            let allowed: &[Initial] = match (causality, variability) {
                (C::Input | C::Independent, _) => &[],
                (C::Parameter, _) => &[Initial::Exact],
                (C::CalculatedParameter, _) => &[Initial::Approx, Initial::Calculated],
                (C::Output | C::Local, V::Constant) => &[Initial::Exact],
                (C::Local, V::Fixed | V::Tunable) => &[Initial::Approx, Initial::Calculated],
                (C::Output | C::Local, _) => Initial::ALL,
            };
            if !allowed.contains(&initial) {
                p.push(Problem::new(format!(
                    "variable \"{name}\": initial=\"{initial}\" is not allowed with \
                     causality=\"{causality}\" and variability=\"{variability}\""
                )));
            }
        }

        let has_start = v.kind.has_start();
        let initial = v.initial_or_default();
        let start_required = matches!(initial, Some(Initial::Exact | Initial::Approx))
            || matches!(causality, C::Input | C::Parameter);
        if start_required && !has_start {
            p.push(Problem::new(format!(
                "variable \"{name}\": start is required (causality=\"{causality}\", initial={})",
                initial.map_or("none".to_owned(), |i| format!("\"{i}\""))
            )));
        }
        if has_start && initial == Some(Initial::Calculated) {
            p.push(Problem::new(format!(
                "variable \"{name}\": start is not allowed with initial=\"calculated\"{}",
                if v.initial.is_none() {
                    " (the default for this causality and variability)"
                } else {
                    ""
                }
            )));
        }
        if has_start && causality == C::Independent {
            p.push(Problem::new(format!(
                "variable \"{name}\": the independent variable must not have a start value"
            )));
        }

        self.check_declared_type(p, v);
        self.check_bounds(p, v);

        if let VariableKind::Real {
            attributes,
            declared_type,
            derivative,
            ..
        } = &v.kind
        {
            let what = format!("variable \"{name}\"");
            self.check_units(p, &what, attributes);
            if attributes.unit.is_none()
                && let Some(du) = &attributes.display_unit
                && let Some(SimpleTypeKind::Real(ta)) = declared_type
                    .as_deref()
                    .and_then(|t| self.type_definition(t))
                    .map(|t| &t.kind)
                && let Some(unit) = ta.unit.as_deref().and_then(|u| self.unit(u))
                && !unit.display_units.iter().any(|d| &d.name == du)
            {
                p.push(Problem::new(format!(
                    "{what}: displayUnit \"{du}\" is not defined for unit \"{}\"",
                    unit.name
                )));
            }
            if let Some(state) = derivative {
                match self.variable_by_index(*state) {
                    None => p.push(Problem::new(format!(
                        "variable \"{name}\": derivative=\"{state}\" is not a variable index \
                         (1..={})",
                        self.model_variables.len()
                    ))),
                    Some(s) if !matches!(s.kind, VariableKind::Real { .. }) => {
                        p.push(Problem::new(format!(
                            "variable \"{name}\": derivative=\"{state}\" refers to \"{}\", \
                             which is not Real",
                            s.name
                        )))
                    }
                    Some(_) => {}
                }
            }
        }

        for tool in &v.annotations {
            if let Err(e) = check_xml_content(&tool.content) {
                p.push(Problem::new(format!(
                    "variable \"{name}\": annotation Tool \"{}\" is not well-formed XML: {e}",
                    tool.name
                )));
            }
        }
    }

    fn check_declared_type(&self, p: &mut Vec<Problem>, v: &ScalarVariable) {
        let Some(type_name) = v.kind.declared_type() else {
            return;
        };
        match self.type_definition(type_name) {
            None => p.push(Problem::new(format!(
                "variable \"{}\": declaredType \"{type_name}\" is not defined in TypeDefinitions",
                v.name
            ))),
            Some(t) => {
                let matches = matches!(
                    (&v.kind, &t.kind),
                    (VariableKind::Real { .. }, SimpleTypeKind::Real(_))
                        | (VariableKind::Integer { .. }, SimpleTypeKind::Integer(_))
                        | (VariableKind::Boolean { .. }, SimpleTypeKind::Boolean)
                        | (VariableKind::String { .. }, SimpleTypeKind::String)
                        | (
                            VariableKind::Enumeration { .. },
                            SimpleTypeKind::Enumeration { .. }
                        )
                );
                if !matches {
                    p.push(Problem::new(format!(
                        "variable \"{}\": declaredType \"{type_name}\" is not {} {} type",
                        v.name,
                        if v.kind.base_type_name().starts_with(['E', 'I']) {
                            "an"
                        } else {
                            "a"
                        },
                        v.kind.base_type_name()
                    )));
                }
            }
        }
    }

    fn check_bounds(&self, p: &mut Vec<Problem>, v: &ScalarVariable) {
        let declared = v
            .kind
            .declared_type()
            .and_then(|t| self.type_definition(t))
            .map(|t| &t.kind);
        let name = &v.name;
        match &v.kind {
            VariableKind::Real {
                attributes, start, ..
            } => {
                let (tmin, tmax) = match declared {
                    Some(SimpleTypeKind::Real(a)) => (a.min, a.max),
                    _ => (None, None),
                };
                let min = attributes.min.or(tmin);
                let max = attributes.max.or(tmax);
                bounds(p, name, min, max, *start);
            }
            VariableKind::Integer {
                attributes, start, ..
            } => {
                let (tmin, tmax) = match declared {
                    Some(SimpleTypeKind::Integer(a)) => (a.min, a.max),
                    _ => (None, None),
                };
                let min = attributes.min.or(tmin);
                let max = attributes.max.or(tmax);
                bounds(p, name, min, max, *start);
            }
            VariableKind::Enumeration {
                min, max, start, ..
            } => {
                bounds(p, name, *min, *max, *start);
                if let (Some(s), Some(SimpleTypeKind::Enumeration { items, .. })) =
                    (start, declared)
                    && !items.iter().any(|i| i.value == *s)
                {
                    p.push(Problem::new(format!(
                        "variable \"{name}\": start {s} is not a value of enumeration type \"{}\"",
                        v.kind.declared_type().unwrap_or_default()
                    )));
                }
            }
            VariableKind::Boolean { .. } | VariableKind::String { .. } => {}
        }
    }

    fn check_aliases(&self, p: &mut Vec<Problem>) {
        let mut sets: HashMap<(BaseType, u32), Vec<&ScalarVariable>> = HashMap::new();
        for v in &self.model_variables {
            sets.entry((v.kind.base_type(), v.value_reference))
                .or_default()
                .push(v);
        }
        let mut keys: Vec<_> = sets.keys().copied().collect();
        keys.sort();
        for key in keys {
            let Some(members) = sets.get(&key) else {
                continue;
            };
            if members.len() < 2 {
                continue;
            }
            let names = || {
                members
                    .iter()
                    .map(|v| format!("\"{}\"", v.name))
                    .collect::<Vec<_>>()
                    .join(", ")
            };
            let starts: BTreeSet<String> = members
                .iter()
                .filter_map(|v| v.kind.start_string())
                .collect();
            if starts.len() > 1 {
                p.push(Problem::new(format!(
                    "alias variables {} ({} valueReference {}) have different start values",
                    names(),
                    key.0.as_str(),
                    key.1
                )));
            }
            let enum_types: BTreeSet<Option<&str>> = members
                .iter()
                .map(|v| match &v.kind {
                    VariableKind::Enumeration { declared_type, .. } => Some(declared_type.as_str()),
                    _ => None,
                })
                .collect();
            if enum_types.len() > 1 && enum_types.iter().any(Option::is_some) {
                p.push(Problem::new(format!(
                    "variables {} share Integer valueReference {} but are not of the same \
                     enumeration type",
                    names(),
                    key.1
                )));
            }
        }
    }

    fn check_structure(&self, p: &mut Vec<Problem>) {
        let n = self.model_variables.len();
        let ms = &self.model_structure;
        let states: HashSet<u32> = ms
            .derivatives
            .iter()
            .filter_map(|u| match self.variable_by_index(u.index).map(|v| &v.kind) {
                Some(VariableKind::Real {
                    derivative: Some(s),
                    ..
                }) => Some(*s),
                _ => None,
            })
            .collect();
        // Without a Derivatives list (co-simulation only), the states are not declared: any
        // continuous local Real may be one.
        let states_unknown = ms.derivatives.is_empty();
        let dynamic_known = |v: &ScalarVariable, index: u32| {
            matches!(
                v.causality_or_default(),
                Causality::Input | Causality::Independent
            ) || states.contains(&index)
                || (states_unknown
                    && v.causality_or_default() == Causality::Local
                    && v.variability_or_default() == Variability::Continuous
                    && matches!(v.kind, VariableKind::Real { .. }))
        };
        let initial_known = |v: &ScalarVariable, _index: u32| {
            matches!(
                v.causality_or_default(),
                Causality::Input | Causality::Independent
            ) || v.initial_or_default() == Some(Initial::Exact)
        };
        type IsKnown<'f> = &'f dyn Fn(&ScalarVariable, u32) -> bool;
        let lists: [(&str, &[Unknown], IsKnown<'_>, &str); 3] = [
            (
                "Outputs",
                &ms.outputs,
                &dynamic_known,
                "an input, the independent variable or a continuous state",
            ),
            (
                "Derivatives",
                &ms.derivatives,
                &dynamic_known,
                "an input, the independent variable or a continuous state",
            ),
            (
                "InitialUnknowns",
                &ms.initial_unknowns,
                &initial_known,
                "an input, the independent variable or a variable with initial=\"exact\"",
            ),
        ];
        for (list_name, list, known, known_text) in lists {
            let mut seen = HashSet::new();
            for u in list {
                let Some(v) = self.variable_by_index(u.index) else {
                    p.push(Problem::new(format!(
                        "ModelStructure/{list_name}: Unknown index {} is out of range 1..={n}",
                        u.index
                    )));
                    continue;
                };
                if !seen.insert(u.index) {
                    p.push(Problem::new(format!(
                        "ModelStructure/{list_name}: variable \"{}\" (index {}) is listed twice",
                        v.name, u.index
                    )));
                }
                if let Some(deps) = &u.dependencies {
                    for &d in deps {
                        match self.variable_by_index(d) {
                            None => p.push(Problem::new(format!(
                                "ModelStructure/{list_name}: dependency {d} of \"{}\" is out of \
                                 range 1..={n}",
                                v.name
                            ))),
                            Some(dv) if !known(dv, d) => p.push(Problem::new(format!(
                                "ModelStructure/{list_name}: \"{}\" depends on \"{}\" (index \
                                 {d}), which is not {known_text}",
                                v.name, dv.name
                            ))),
                            Some(_) => {}
                        }
                    }
                }
                match (&u.dependencies, &u.dependencies_kind) {
                    (None, Some(_)) => p.push(Problem::new(format!(
                        "ModelStructure/{list_name}: \"{}\" has dependenciesKind without \
                         dependencies",
                        v.name
                    ))),
                    (Some(d), Some(k)) if d.len() != k.len() => p.push(Problem::new(format!(
                        "ModelStructure/{list_name}: \"{}\" has {} dependencies but {} \
                         dependenciesKind entries",
                        v.name,
                        d.len(),
                        k.len()
                    ))),
                    _ => {}
                }
            }
        }

        // Outputs: exactly the variables with causality="output".
        let listed: BTreeSet<u32> = ms.outputs.iter().map(|u| u.index).collect();
        for (i, v) in self.model_variables.iter().enumerate() {
            let Ok(index) = u32::try_from(i + 1) else {
                break;
            };
            let is_output = v.causality_or_default() == Causality::Output;
            if is_output && !listed.contains(&index) {
                p.push(Problem::new(format!(
                    "ModelStructure/Outputs: output \"{}\" (index {index}) is not listed",
                    v.name
                )));
            }
            if !is_output && listed.contains(&index) {
                p.push(Problem::new(format!(
                    "ModelStructure/Outputs: \"{}\" (index {index}) is listed but its causality \
                     is \"{}\", not \"output\"",
                    v.name,
                    v.causality_or_default()
                )));
            }
        }

        // Derivatives.
        if !ms.derivatives.is_empty() && self.model_exchange.is_none() {
            p.push(Problem::new(
                "ModelStructure/Derivatives is only allowed with ModelExchange",
            ));
        }
        for u in &ms.derivatives {
            if let Some(v) = self.variable_by_index(u.index)
                && !matches!(
                    v.kind,
                    VariableKind::Real {
                        derivative: Some(_),
                        ..
                    }
                )
            {
                p.push(Problem::new(format!(
                    "ModelStructure/Derivatives: \"{}\" (index {}) is not a Real with a \
                     derivative attribute",
                    v.name, u.index
                )));
            }
        }

        // InitialUnknowns: the exact set, ascending.
        let expected = self.expected_initial_unknowns();
        let actual: BTreeSet<u32> = ms.initial_unknowns.iter().map(|u| u.index).collect();
        let describe = |i: &u32| match self.variable_by_index(*i) {
            Some(v) => format!("\"{}\" (index {i})", v.name),
            None => format!("index {i}"),
        };
        let missing: Vec<String> = expected
            .iter()
            .filter(|i| !actual.contains(i))
            .map(describe)
            .collect();
        let extra: Vec<String> = actual
            .iter()
            .filter(|i| !expected.contains(i))
            .map(describe)
            .collect();
        if !missing.is_empty() {
            p.push(Problem::new(format!(
                "ModelStructure/InitialUnknowns: missing {}",
                missing.join(", ")
            )));
        }
        if !extra.is_empty() {
            p.push(Problem::new(format!(
                "ModelStructure/InitialUnknowns: must not list {}",
                extra.join(", ")
            )));
        }
        if ms
            .initial_unknowns
            .windows(2)
            .any(|w| w[0].index >= w[1].index)
        {
            p.push(Problem::new(
                "ModelStructure/InitialUnknowns: indices are not sorted ascending",
            ));
        }
    }
}

fn bounds<T: PartialOrd + fmt::Display + Copy>(
    p: &mut Vec<Problem>,
    name: &str,
    min: Option<T>,
    max: Option<T>,
    start: Option<T>,
) {
    if let (Some(min), Some(max)) = (min, max)
        && min > max
    {
        p.push(Problem::new(format!(
            "variable \"{name}\": min {min} > max {max}"
        )));
    }
    if let Some(start) = start {
        if let Some(min) = min
            && start < min
        {
            p.push(Problem::new(format!(
                "variable \"{name}\": start {start} < min {min}"
            )));
        }
        if let Some(max) = max
            && start > max
        {
            p.push(Problem::new(format!(
                "variable \"{name}\": start {start} > max {max}"
            )));
        }
    }
}

fn duplicates<'a>(p: &mut Vec<Problem>, what: &str, names: impl Iterator<Item = &'a str>) {
    let mut seen = HashSet::new();
    let mut reported = HashSet::new();
    for name in names {
        if !seen.insert(name) && reported.insert(name) {
            p.push(Problem::new(format!("{what} \"{name}\" is not unique")));
        }
    }
}

fn is_c_identifier(s: &str) -> bool {
    let mut chars = s.chars();
    matches!(chars.next(), Some(c) if c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
}

/// Checks that `content` is well-formed XML content (elements balanced, attributes valid).
fn check_xml_content(content: &str) -> Result<(), String> {
    use quick_xml::events::Event;
    let mut reader = quick_xml::Reader::from_str(content);
    let mut depth = 0usize;
    loop {
        match reader.read_event() {
            Err(e) => return Err(e.to_string()),
            Ok(Event::Start(e)) => {
                for a in e.attributes() {
                    let a = a.map_err(|e| e.to_string())?;
                    a.normalized_value(quick_xml::XmlVersion::Implicit1_0)
                        .map_err(|e| e.to_string())?;
                }
                depth += 1;
            }
            Ok(Event::Empty(e)) => {
                for a in e.attributes() {
                    let a = a.map_err(|e| e.to_string())?;
                    a.normalized_value(quick_xml::XmlVersion::Implicit1_0)
                        .map_err(|e| e.to_string())?;
                }
            }
            Ok(Event::End(_)) => {
                depth = depth
                    .checked_sub(1)
                    .ok_or_else(|| "end tag without start tag".to_owned())?;
            }
            Ok(Event::Eof) => {
                return if depth == 0 {
                    Ok(())
                } else {
                    Err("unclosed element".to_owned())
                };
            }
            Ok(Event::Decl(_)) => return Err("XML declaration inside content".to_owned()),
            Ok(_) => {}
        }
    }
}
