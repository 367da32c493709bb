//! `check()`: a valid description has no problems; each broken rule gives its problem.

mod common;

use common::*;
use model_description::*;

/// Asserts that `md.check()` reports exactly one problem and that it contains `needle`.
#[track_caller]
fn assert_problem(md: &ModelDescription, needle: &str) {
    let problems = md.check();
    assert!(
        problems.iter().any(|p| p.message.contains(needle)),
        "no problem containing {needle:?} in {problems:#?}"
    );
}

/// Asserts a problem containing `needle`, and that it is the only one.
#[track_caller]
fn assert_only_problem(md: &ModelDescription, needle: &str) {
    let problems = md.check();
    assert_eq!(problems.len(), 1, "{problems:#?}");
    assert!(problems[0].message.contains(needle), "{problems:#?}");
}

fn var_mut<'a>(md: &'a mut ModelDescription, name: &str) -> &'a mut ScalarVariable {
    md.model_variables
        .iter_mut()
        .find(|v| v.name == name)
        .unwrap()
}

fn set_start(v: &mut ScalarVariable, value: Option<f64>) {
    if let VariableKind::Real { start, .. } = &mut v.kind {
        *start = value;
    }
}

#[test]
fn valid_descriptions_have_no_problems() {
    assert_eq!(full().check(), vec![]);
    let third = ModelDescription::from_xml(THIRD_PARTY).unwrap();
    assert_eq!(third.check(), vec![]);
}

#[test]
fn problem_displays_its_message() {
    let p = Problem {
        message: "x".into(),
    };
    assert_eq!(p.to_string(), "x");
}

#[test]
fn fmi_version() {
    let mut md = full();
    md.fmi_version = "3.0".into();
    assert_only_problem(&md, "fmiVersion");
}

#[test]
fn neither_model_exchange_nor_co_simulation() {
    let mut md = full();
    md.model_exchange = None;
    md.co_simulation = None;
    md.model_structure.derivatives.clear();
    md.model_structure.initial_unknowns.retain(|u| u.index != 3);
    assert_only_problem(&md, "neither ModelExchange nor CoSimulation");
}

#[test]
fn model_identifier_not_c_identifier() {
    let mut md = full();
    md.co_simulation.as_mut().unwrap().model_identifier = "knee-cs".into();
    assert_only_problem(&md, "not a valid C identifier");
}

#[test]
fn duplicate_variable_names() {
    let mut md = full();
    md.model_variables[12].name = "x".into();
    assert_only_problem(&md, "variable name \"x\" is not unique");
}

#[test]
fn duplicate_unit_type_and_category_names() {
    let mut md = full();
    md.unit_definitions[2].name = "rad".into();
    assert_only_problem(&md, "unit \"rad\" is not unique");
    let mut md = full();
    md.type_definitions[3].name = "Flag".into();
    // The String variable "label" now refers to a Boolean type as well.
    assert_problem(&md, "type definition \"Flag\" is not unique");
    let mut md = full();
    md.log_categories[1].name = "logEvents".into();
    assert_only_problem(&md, "log category \"logEvents\" is not unique");
}

#[test]
fn enumeration_items() {
    let mut md = full();
    if let SimpleTypeKind::Enumeration { items, .. } = &mut md.type_definitions[4].kind {
        items[2].value = 2;
        items[2].name = "On".into();
    }
    assert_problem(
        &md,
        "item name of enumeration type \"Mode\" \"On\" is not unique",
    );
    assert_problem(
        &md,
        "item value of enumeration type \"Mode\" \"2\" is not unique",
    );
    if let SimpleTypeKind::Enumeration { items, .. } = &mut md.type_definitions[4].kind {
        items.clear();
    }
    assert_problem(&md, "has no items");
}

#[test]
fn default_experiment() {
    let mut md = full();
    md.default_experiment = Some(DefaultExperiment {
        start_time: Some(1.0),
        stop_time: Some(1.0),
        tolerance: Some(0.0),
        step_size: Some(-1.0),
    });
    let problems = md.check();
    assert_eq!(problems.len(), 3, "{problems:#?}");
}

#[test]
fn alias_rule() {
    // Same value reference, same base type, no conflicting start: a legal alias (y/yAlias in
    // the fixture). Same value reference across base types: independent (x is Real 1, mode is
    // Integer 1).
    assert!(full().check().is_empty());
    // Aliases with different start values contradict each other.
    let mut md = full();
    var_mut(&mut md, "c").value_reference = 1; // alias of x (Real 1), starts 1e-5 vs 0.1
    assert_only_problem(&md, "have different start values");
    // Aliases with the same start value are fine.
    let mut md = full();
    var_mut(&mut md, "c").value_reference = 1;
    set_start(var_mut(&mut md, "c"), Some(0.1));
    assert!(md.check().is_empty(), "{:#?}", md.check());
    // Enumeration and Integer share the Integer space: n (Integer 0) aliased with mode.
    let mut md = full();
    var_mut(&mut md, "mode").value_reference = 0;
    let problems = md.check();
    assert!(
        problems
            .iter()
            .any(|p| p.message.contains("not of the same enumeration type")),
        "{problems:#?}"
    );
}

#[test]
fn illegal_causality_variability() {
    let mut md = full();
    var_mut(&mut md, "k").variability = Some(Variability::Continuous);
    assert_problem(
        &md,
        "causality=\"parameter\" with variability=\"continuous\"",
    );
    let mut md = full();
    var_mut(&mut md, "u").variability = Some(Variability::Constant);
    assert_problem(&md, "causality=\"input\" with variability=\"constant\"");
    let mut md = full();
    var_mut(&mut md, "y").variability = Some(Variability::Tunable);
    assert_problem(&md, "causality=\"output\" with variability=\"tunable\"");
    let mut md = full();
    var_mut(&mut md, "time").variability = Some(Variability::Discrete);
    assert_problem(
        &md,
        "causality=\"independent\" with variability=\"discrete\"",
    );
}

#[test]
fn only_real_is_continuous() {
    let mut md = full();
    // No variability attribute: the default is continuous, illegal for an Integer.
    var_mut(&mut md, "n").variability = None;
    var_mut(&mut md, "n").causality = Some(Causality::Local);
    var_mut(&mut md, "n").initial = Some(Initial::Exact);
    assert_only_problem(&md, "only Real variables can be continuous");
}

#[test]
fn illegal_initial() {
    let mut md = full();
    var_mut(&mut md, "u").initial = Some(Initial::Exact);
    assert_only_problem(
        &md,
        "initial=\"exact\" is not allowed with causality=\"input\"",
    );
    let mut md = full();
    var_mut(&mut md, "k").initial = Some(Initial::Approx);
    assert_problem(
        &md,
        "initial=\"approx\" is not allowed with causality=\"parameter\"",
    );
    let mut md = full();
    var_mut(&mut md, "time").initial = Some(Initial::Exact);
    assert_problem(&md, "not allowed with causality=\"independent\"");
    let mut md = full();
    var_mut(&mut md, "c").initial = Some(Initial::Calculated);
    assert_problem(
        &md,
        "initial=\"calculated\" is not allowed with causality=\"local\" and variability=\"constant\"",
    );
}

#[test]
fn start_required() {
    let mut md = full();
    set_start(var_mut(&mut md, "u"), None);
    assert_only_problem(&md, "variable \"u\": start is required");
    let mut md = full();
    set_start(var_mut(&mut md, "k"), None);
    assert_only_problem(&md, "variable \"k\": start is required");
    let mut md = full();
    set_start(var_mut(&mut md, "x"), None);
    assert_only_problem(&md, "variable \"x\": start is required");
}

#[test]
fn start_forbidden() {
    let mut md = full();
    set_start(var_mut(&mut md, "y"), Some(1.0));
    assert_problem(
        &md,
        "variable \"y\": start is not allowed with initial=\"calculated\"",
    );
    // Through the default initial of a local continuous variable.
    let mut md = full();
    set_start(var_mut(&mut md, "der(x)"), Some(0.0));
    assert_only_problem(&md, "(the default for this causality and variability)");
    let mut md = full();
    set_start(var_mut(&mut md, "time"), Some(0.0));
    assert_only_problem(&md, "independent variable must not have a start value");
}

#[test]
fn independent_variable_rules() {
    let mut md = full();
    var_mut(&mut md, "time").kind = VariableKind::Integer {
        declared_type: None,
        attributes: IntegerAttributes::default(),
        start: None,
    };
    assert_problem(&md, "the independent variable must be Real");
    let mut md = full();
    var_mut(&mut md, "c").causality = Some(Causality::Independent);
    assert_problem(&md, "more than one independent variable");
}

#[test]
fn bounds() {
    let mut md = full();
    set_start(var_mut(&mut md, "x"), Some(5.0));
    assert_only_problem(&md, "start 5 > max 3");
    let mut md = full();
    set_start(var_mut(&mut md, "x"), Some(-5.0));
    assert_only_problem(&md, "start -5 < min -3");
    let mut md = full();
    if let VariableKind::Integer { attributes, .. } = &mut var_mut(&mut md, "n").kind {
        attributes.min = Some(5);
        attributes.max = Some(4);
    }
    assert_problem(&md, "min 5 > max 4");
    // Bounds of the declared type apply when the variable has none.
    let mut md = full();
    if let VariableKind::Real {
        attributes, start, ..
    } = &mut var_mut(&mut md, "x").kind
    {
        attributes.min = None;
        attributes.max = None;
        *start = Some(11.0);
    }
    assert_only_problem(&md, "start 11 > max 10");
    let mut md = full();
    if let VariableKind::Enumeration { start, .. } = &mut var_mut(&mut md, "mode").kind {
        *start = Some(4);
    }
    assert_problem(&md, "start 4 > max 3");
    assert_problem(&md, "start 4 is not a value of enumeration type \"Mode\"");
}

#[test]
fn declared_type() {
    let mut md = full();
    if let VariableKind::Real { declared_type, .. } = &mut var_mut(&mut md, "x").kind {
        *declared_type = Some("Nope".into());
    }
    assert_only_problem(&md, "declaredType \"Nope\" is not defined");
    let mut md = full();
    if let VariableKind::Integer { declared_type, .. } = &mut var_mut(&mut md, "n").kind {
        *declared_type = Some("Angle".into());
    }
    assert_only_problem(&md, "declaredType \"Angle\" is not an Integer type");
    let mut md = full();
    if let VariableKind::Enumeration { declared_type, .. } = &mut var_mut(&mut md, "mode").kind {
        *declared_type = "Count".into();
    }
    assert_only_problem(&md, "declaredType \"Count\" is not an Enumeration type");
}

#[test]
fn units() {
    let mut md = full();
    if let VariableKind::Real { attributes, .. } = &mut var_mut(&mut md, "x").kind {
        attributes.unit = Some("m".into());
    }
    assert_only_problem(&md, "unit \"m\" is not defined");
    let mut md = full();
    if let VariableKind::Real { attributes, .. } = &mut var_mut(&mut md, "x").kind {
        attributes.display_unit = Some("kN.m".into());
    }
    assert_only_problem(&md, "displayUnit \"kN.m\" is not defined for unit \"rad\"");
    let mut md = full();
    if let SimpleTypeKind::Real(a) = &mut md.type_definitions[0].kind {
        a.unit = Some("furlong".into());
    }
    assert_only_problem(
        &md,
        "type definition \"Angle\": unit \"furlong\" is not defined",
    );
}

#[test]
fn derivative_attribute() {
    let mut md = full();
    if let VariableKind::Real { derivative, .. } = &mut var_mut(&mut md, "der(x)").kind {
        *derivative = Some(99);
    }
    assert_problem(&md, "derivative=\"99\" is not a variable index");
    let mut md = full();
    if let VariableKind::Real { derivative, .. } = &mut var_mut(&mut md, "der(x)").kind {
        *derivative = Some(8);
    }
    assert_problem(&md, "which is not Real");
}

#[test]
fn outputs_must_be_exactly_the_outputs() {
    let mut md = full();
    md.model_structure.outputs.remove(2);
    assert_only_problem(&md, "output \"yAlias\" (index 12) is not listed");
    let mut md = full();
    md.model_structure.outputs.push(unknown(13, None));
    assert_only_problem(
        &md,
        "\"c\" (index 13) is listed but its causality is \"local\"",
    );
    let mut md = full();
    md.model_structure.outputs.push(unknown(5, None));
    assert_only_problem(&md, "is listed twice");
}

#[test]
fn unknown_index_out_of_range() {
    let mut md = full();
    md.model_structure.outputs.push(unknown(0, None));
    assert_only_problem(&md, "Unknown index 0 is out of range 1..=13");
    let mut md = full();
    md.model_structure.outputs.push(unknown(14, None));
    assert_only_problem(&md, "Unknown index 14 is out of range");
}

#[test]
fn dependencies() {
    let mut md = full();
    md.model_structure.outputs[2].dependencies = Some(vec![0]);
    md.model_structure.outputs[2].dependencies_kind = None;
    assert_only_problem(&md, "dependency 0 of \"yAlias\" is out of range");
    let mut md = full();
    md.model_structure.outputs[2].dependencies_kind = Some(vec![DependencyKind::Dependent]);
    assert_only_problem(&md, "has 0 dependencies but 1 dependenciesKind entries");
    let mut md = full();
    md.model_structure.outputs[2].dependencies = None;
    assert_only_problem(&md, "dependenciesKind without dependencies");
    // An output may not depend on a parameter (a known only during initialization).
    let mut md = full();
    md.model_structure.outputs[1].dependencies = Some(vec![6]);
    assert_only_problem(
        &md,
        "\"mode\" depends on \"k\" (index 6), which is not an input",
    );
    // An initial unknown may not depend on another calculated variable.
    let mut md = full();
    md.model_structure.initial_unknowns[3].dependencies = Some(vec![5]);
    assert_only_problem(&md, "\"yAlias\" depends on \"y\" (index 5)");
}

#[test]
fn derivatives_only_with_model_exchange() {
    let mut md = full();
    md.model_exchange = None;
    assert_only_problem(&md, "Derivatives is only allowed with ModelExchange");
    let mut md = full();
    md.model_structure.derivatives[0].index = 4;
    let problems = md.check();
    assert!(
        problems.iter().any(|p| p
            .message
            .contains("\"u\" (index 4) is not a Real with a derivative")),
        "{problems:#?}"
    );
}

#[test]
fn initial_unknowns_exact_set_and_order() {
    assert_eq!(full().expected_initial_unknowns(), vec![3, 5, 7, 12]);
    let mut md = full();
    md.model_structure.initial_unknowns.remove(2);
    assert_only_problem(&md, "InitialUnknowns: missing \"k2\" (index 7)");
    let mut md = full();
    md.model_structure.initial_unknowns.push(unknown(13, None));
    assert_only_problem(&md, "InitialUnknowns: must not list \"c\" (index 13)");
    let mut md = full();
    md.model_structure.initial_unknowns.swap(0, 1);
    assert_only_problem(&md, "not sorted ascending");
    // A state with initial="approx" joins the set.
    let mut md = full();
    var_mut(&mut md, "x").initial = Some(Initial::Approx);
    assert_problem(&md, "InitialUnknowns: missing \"x\" (index 2)");
    // ... and is then no longer a known for the other initial unknowns.
    assert_problem(
        &md,
        "\"der(x)\" depends on \"x\" (index 2), which is not an input",
    );
}

#[test]
fn annotations_must_be_well_formed() {
    let mut md = full();
    md.vendor_annotations[0].content = "<a><b></a>".into();
    assert_only_problem(&md, "VendorAnnotations Tool \"kneebench\"");
    let mut md = full();
    var_mut(&mut md, "mode").annotations[0].content = "<unclosed>".into();
    assert_only_problem(&md, "annotation Tool \"kneebench\" is not well-formed");
}

#[test]
fn defaults_and_helpers() {
    let md = full();
    let v = |n: &str| md.variable_by_name(n).unwrap();
    assert_eq!(v("der(x)").causality_or_default(), Causality::Local);
    assert_eq!(
        v("der(x)").variability_or_default(),
        Variability::Continuous
    );
    assert_eq!(v("der(x)").initial_or_default(), Some(Initial::Calculated));
    assert_eq!(v("k").initial_or_default(), Some(Initial::Exact));
    assert_eq!(v("k2").initial_or_default(), Some(Initial::Calculated));
    assert_eq!(v("u").initial_or_default(), None);
    assert_eq!(v("time").initial_or_default(), None);
    assert_eq!(v("c").initial_or_default(), Some(Initial::Exact));
    assert_eq!(v("y").initial_or_default(), Some(Initial::Calculated));
    assert_eq!(v("mode").kind.base_type_name(), "Enumeration");
    assert_eq!(v("mode").kind.base_type(), BaseType::Integer);
    assert_eq!(v("flag").kind.base_type_name(), "Boolean");
    assert_eq!(v("label").kind.base_type_name(), "String");
    assert_eq!(v("n").kind.base_type_name(), "Integer");
    assert_eq!(v("x").kind.base_type_name(), "Real");
    assert_eq!(md.variable_index("time"), Some(1));
    assert_eq!(md.variable_index("c"), Some(13));
    assert_eq!(md.variable_index("nope"), None);
    assert!(md.variable_by_name("nope").is_none());
    assert_eq!(md.variable_by_index(1).unwrap().name, "time");
    assert!(md.variable_by_index(0).is_none());
    assert!(md.variable_by_index(14).is_none());
    let aliases: Vec<&str> = md
        .variables_by_value_reference(BaseType::Real, 4)
        .map(|v| v.name.as_str())
        .collect();
    assert_eq!(aliases, ["y", "yAlias"]);
    assert_eq!(
        Causality::from_xml_str("calculatedParameter"),
        Some(Causality::CalculatedParameter)
    );
    assert_eq!(
        Causality::CalculatedParameter.to_string(),
        "calculatedParameter"
    );
}
