//! Round trips: Rust value -> XML -> value, XML -> value -> XML -> value, and the exact format.

mod common;

use common::*;
use model_description::*;

#[test]
fn full_description_round_trips() {
    let md = full();
    let xml = md.to_xml();
    let back = ModelDescription::from_xml(&xml).unwrap_or_else(|e| panic!("{e}\n{xml}"));
    assert_eq!(back, md);
    // Deterministic: writing the value read back gives the same bytes.
    assert_eq!(back.to_xml(), xml);
}

#[test]
fn full_description_is_valid() {
    let problems = full().check();
    assert!(problems.is_empty(), "{problems:#?}");
}

#[test]
fn minimal_description_round_trips() {
    let mut md = ModelDescription::new("m", "g");
    md.co_simulation = Some(CoSimulation {
        model_identifier: "m".into(),
        ..CoSimulation::default()
    });
    let xml = md.to_xml();
    assert_eq!(ModelDescription::from_xml(&xml).unwrap(), md);
    assert_eq!(
        xml,
        "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n\
         <fmiModelDescription fmiVersion=\"2.0\" modelName=\"m\" guid=\"g\">\n  \
         <CoSimulation modelIdentifier=\"m\"/>\n  \
         <ModelVariables/>\n  \
         <ModelStructure/>\n\
         </fmiModelDescription>\n"
    );
}

#[test]
fn exact_format_of_a_small_description() {
    let mut md = ModelDescription::new("m", "g");
    md.co_simulation = Some(CoSimulation {
        model_identifier: "m".into(),
        can_handle_variable_communication_step_size: Some(true),
        ..CoSimulation::default()
    });
    md.model_variables = vec![
        real("u", 0, Some(Causality::Input), None, None, Some(1e-5)),
        real("y", 1, Some(Causality::Output), None, None, None),
    ];
    md.vendor_annotations = vec![ToolAnnotation {
        name: "t".into(),
        content: "<a b=\"1\"/>".into(),
    }];
    md.model_structure.outputs = vec![unknown(2, Some(vec![1]))];
    md.model_structure.initial_unknowns = vec![unknown(2, Some(vec![]))];
    let expected = r#"<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="m" guid="g">
  <CoSimulation modelIdentifier="m" canHandleVariableCommunicationStepSize="true"/>
  <VendorAnnotations>
    <Tool name="t"><a b="1"/></Tool>
  </VendorAnnotations>
  <ModelVariables>
    <ScalarVariable name="u" valueReference="0" causality="input">
      <Real start="1e-5"/>
    </ScalarVariable>
    <ScalarVariable name="y" valueReference="1" causality="output">
      <Real/>
    </ScalarVariable>
  </ModelVariables>
  <ModelStructure>
    <Outputs>
      <Unknown index="2" dependencies="1"/>
    </Outputs>
    <InitialUnknowns>
      <Unknown index="2" dependencies=""/>
    </InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"#;
    assert_eq!(md.to_xml(), expected);
    assert_eq!(ModelDescription::from_xml(expected).unwrap(), md);
    assert!(md.check().is_empty(), "{:#?}", md.check());
}

#[test]
fn third_party_description_reads_and_round_trips() {
    let md = ModelDescription::from_xml(THIRD_PARTY).unwrap();
    assert_eq!(md.model_name, "Knee.Plant");
    assert_eq!(md.description.as_deref(), Some("Knee plant & actuator"));
    assert_eq!(md.number_of_event_indicators, Some(2));
    assert_eq!(
        md.variable_naming_convention,
        Some(VariableNamingConvention::Structured)
    );
    let me = md.model_exchange.as_ref().unwrap();
    assert_eq!(me.model_identifier, "Knee_Plant");
    assert_eq!(me.can_serialize_fmu_state, Some(true));
    assert_eq!(me.provides_directional_derivative, Some(false));
    assert_eq!(me.source_files, vec!["all.c".to_owned()]);
    let cs = md.co_simulation.as_ref().unwrap();
    assert_eq!(cs.max_output_derivative_order, Some(1));
    assert_eq!(cs.needs_execution_tool, None);
    assert_eq!(md.unit_definitions.len(), 3);
    assert_eq!(
        md.unit_definitions[1].base_unit,
        Some(BaseUnit {
            s: Some(-1),
            rad: Some(1),
            ..BaseUnit::default()
        })
    );
    let SimpleTypeKind::Enumeration { items, quantity } = &md.type_definitions[2].kind else {
        panic!("expected an enumeration type");
    };
    assert_eq!(quantity, &None);
    assert_eq!(items.len(), 3);
    assert_eq!(items[2].name, "trip");
    assert_eq!(items[2].description.as_deref(), Some("safety trip"));
    let de = md.default_experiment.as_ref().unwrap();
    assert_eq!(de.tolerance, Some(1e-6));
    assert_eq!(de.step_size, Some(1e-3));

    // Vendor annotations: verbatim inner XML, comments and entities included.
    assert_eq!(md.vendor_annotations.len(), 2);
    assert_eq!(md.vendor_annotations[0].name, "Dymola");
    assert!(
        md.vendor_annotations[0]
            .content
            .contains("<!-- nested comment -->")
    );
    assert!(
        md.vendor_annotations[0]
            .content
            .contains("<Inner a='1'>text &amp; more</Inner>")
    );
    assert!(
        md.vendor_annotations[0]
            .content
            .starts_with("\n      <Settings>")
    );
    assert_eq!(md.vendor_annotations[1].content, "");

    assert_eq!(md.model_variables.len(), 8);
    let phi = md.variable_by_name("phi").unwrap();
    assert_eq!(phi.annotations[0].content, "<Hidden value=\"false\"/>");
    assert_eq!(md.variable_index("der(phi)"), Some(2));
    assert_eq!(
        md.variable_by_index(5).unwrap().kind.base_type_name(),
        "Enumeration"
    );
    assert_eq!(
        md.model_structure.outputs[0],
        Unknown {
            index: 1,
            dependencies: Some(vec![]),
            dependencies_kind: Some(vec![]),
        }
    );
    assert_eq!(md.model_structure.outputs[2].dependencies_kind, None);
    assert_eq!(md.model_structure.initial_unknowns[1].dependencies, None);
    assert!(md.check().is_empty(), "{:#?}", md.check());

    // XML -> value -> XML -> value.
    let xml = md.to_xml();
    let back = ModelDescription::from_xml(&xml).unwrap();
    assert_eq!(back, md);
    assert_eq!(back.to_xml(), xml);
    // The annotations are still there, verbatim.
    assert!(xml.contains("<Inner a='1'>text &amp; more</Inner>"));
}

#[test]
fn floats_round_trip_bit_identically() {
    let values = [
        0.1,
        0.2 + 0.1,
        1e-5,
        1e-7,
        1.5e-7,
        1e300,
        -1e-300,
        5e-324,
        f64::MAX,
        f64::MIN,
        f64::MIN_POSITIVE,
        f64::EPSILON,
        0.0,
        -0.0,
        1.0,
        -2.5,
        123456789012345680.0,
        1.0 / 3.0,
        std::f64::consts::PI,
        f64::INFINITY,
        f64::NEG_INFINITY,
    ];
    let mut md = ModelDescription::new("m", "g");
    md.model_variables = values
        .iter()
        .enumerate()
        .map(|(i, &v)| real(&format!("v{i}"), i as u32, None, None, None, Some(v)))
        .collect();
    md.default_experiment = Some(DefaultExperiment {
        start_time: Some(-0.0),
        stop_time: Some(f64::MAX),
        tolerance: Some(5e-324),
        step_size: Some(0.1),
    });
    let xml = md.to_xml();
    let back = ModelDescription::from_xml(&xml).unwrap();
    for (a, b) in md.model_variables.iter().zip(&back.model_variables) {
        let (VariableKind::Real { start: Some(x), .. }, VariableKind::Real { start: Some(y), .. }) =
            (&a.kind, &b.kind)
        else {
            panic!("lost a start value");
        };
        assert_eq!(x.to_bits(), y.to_bits(), "{x} became {y}");
    }
    assert_eq!(
        back.default_experiment
            .unwrap()
            .start_time
            .unwrap()
            .to_bits(),
        (-0.0f64).to_bits()
    );
    assert!(xml.contains("start=\"1e-5\""));
    assert!(xml.contains("start=\"INF\""));
    assert!(xml.contains("start=\"-INF\""));
    assert!(xml.contains("start=\"2.5\"") || xml.contains("start=\"-2.5\""));
    assert!(xml.contains("start=\"1\""));

    // NaN is written as NaN and read back as a NaN.
    md.model_variables = vec![real("nan", 0, None, None, None, Some(f64::NAN))];
    let xml = md.to_xml();
    assert!(xml.contains("start=\"NaN\""));
    let back = ModelDescription::from_xml(&xml).unwrap();
    let VariableKind::Real { start: Some(s), .. } = back.model_variables[0].kind else {
        panic!("lost NaN");
    };
    assert!(s.is_nan());
}

#[test]
fn float_formatting_is_valid_xs_double() {
    for (value, text) in [
        (1e-5, "1e-5"),
        (2.5, "2.5"),
        (1.0, "1"),
        (-0.0, "-0"),
        (1e21, "1e21"),
        (f64::INFINITY, "INF"),
        (f64::NEG_INFINITY, "-INF"),
        (f64::NAN, "NaN"),
        (0.001, "0.001"),
    ] {
        assert_eq!(model_description::write::format_f64(value), text);
    }
}

#[test]
fn special_characters_round_trip() {
    let mut md = ModelDescription::new("a\"b'c<d>e&f", "g\r\nh");
    md.description = Some("tab\there\nnewline\r\ncrlf  two spaces ünïcödé 🦵".into());
    md.model_variables = vec![ScalarVariable {
        name: "s".into(),
        value_reference: 0,
        description: Some(" leading and trailing ".into()),
        causality: None,
        variability: Some(Variability::Discrete),
        initial: None,
        can_handle_multiple_set_per_time_instant: None,
        kind: VariableKind::String {
            declared_type: None,
            start: Some("]]> <![CDATA[ &amp; \u{7f}".into()),
        },
        annotations: Vec::new(),
    }];
    let xml = md.to_xml();
    assert!(xml.contains("modelName=\"a&quot;b&apos;c&lt;d&gt;e&amp;f\""));
    assert!(xml.contains("&#9;") && xml.contains("&#10;") && xml.contains("&#13;"));
    assert_eq!(ModelDescription::from_xml(&xml).unwrap(), md);
}

#[test]
fn empty_containers_are_omitted_and_present_dependencies_kept() {
    let mut md = ModelDescription::new("m", "g");
    md.model_variables = vec![real("y", 0, Some(Causality::Output), None, None, None)];
    md.model_structure.outputs = vec![Unknown {
        index: 1,
        dependencies: Some(vec![]),
        dependencies_kind: Some(vec![]),
    }];
    let xml = md.to_xml();
    for absent in [
        "UnitDefinitions",
        "TypeDefinitions",
        "LogCategories",
        "DefaultExperiment",
        "VendorAnnotations",
        "Annotations",
        "Derivatives",
        "InitialUnknowns",
        "SourceFiles",
        "ModelExchange",
        "CoSimulation",
    ] {
        assert!(!xml.contains(absent), "{absent} written:\n{xml}");
    }
    assert!(xml.contains("<Unknown index=\"1\" dependencies=\"\" dependenciesKind=\"\"/>"));
    assert_eq!(ModelDescription::from_xml(&xml).unwrap(), md);
}

#[test]
fn from_bytes_accepts_a_byte_order_mark() {
    let md = full();
    let mut bytes = vec![0xEF, 0xBB, 0xBF];
    bytes.extend_from_slice(md.to_xml().as_bytes());
    assert_eq!(ModelDescription::from_bytes(&bytes).unwrap(), md);
    let with_bom = format!("\u{feff}{}", md.to_xml());
    assert_eq!(ModelDescription::from_xml(&with_bom).unwrap(), md);
}

#[test]
fn tolerant_reading() {
    // Whitespace around numbers and booleans, 1/0 booleans, "+" signs, attributes in any
    // order, root children in any order, CRLF line ends, CDATA and text where not expected.
    let xml = "<?xml version=\"1.0\"?>\r\n<!DOCTYPE fmiModelDescription>\r\n\
        <fmiModelDescription guid=\"g\" modelName=\"m\" fmiVersion=\"2.0\">\r\n\
        <ModelStructure><Outputs><Unknown dependencies=\" 1  \" index=\" 1\"/></Outputs></ModelStructure>\r\n\
        stray text <![CDATA[ cdata ]]>\r\n\
        <ModelVariables>\r\n\
        <ScalarVariable valueReference=\"+7\" name=\"y\" causality=\"output\">\
        <Real start=\" 1.5 \" reinit=\"1\" unbounded=\"0\" min=\"-inf\" max=\"Infinity\"/>\
        </ScalarVariable>\r\n\
        </ModelVariables>\r\n\
        <CoSimulation modelIdentifier=\"m\" canInterpolateInputs=\" true \"/>\r\n\
        </fmiModelDescription>\r\n<!-- trailing comment -->\r\n";
    let md = ModelDescription::from_xml(xml).unwrap();
    let y = &md.model_variables[0];
    assert_eq!(y.value_reference, 7);
    let VariableKind::Real {
        start,
        reinit,
        attributes,
        ..
    } = &y.kind
    else {
        panic!()
    };
    assert_eq!(*start, Some(1.5));
    assert_eq!(*reinit, Some(true));
    assert_eq!(attributes.unbounded, Some(false));
    assert_eq!(attributes.min, Some(f64::NEG_INFINITY));
    assert_eq!(attributes.max, Some(f64::INFINITY));
    assert_eq!(md.model_structure.outputs[0].dependencies, Some(vec![1]));
    assert_eq!(
        md.co_simulation.as_ref().unwrap().can_interpolate_inputs,
        Some(true)
    );
    let again = ModelDescription::from_xml(&md.to_xml()).unwrap();
    assert_eq!(again, md);
}

/// The schema's order of attributes per element and of children per parent
/// (fmi2ModelDescription.xsd and its includes).
fn schema_attributes(element: &str, parent: &str) -> &'static [&'static str] {
    const REAL_ATTRS: &[&str] = &[
        "quantity",
        "unit",
        "displayUnit",
        "relativeQuantity",
        "min",
        "max",
        "nominal",
        "unbounded",
    ];
    match (element, parent) {
        ("fmiModelDescription", _) => &[
            "fmiVersion",
            "modelName",
            "guid",
            "description",
            "author",
            "version",
            "copyright",
            "license",
            "generationTool",
            "generationDateAndTime",
            "variableNamingConvention",
            "numberOfEventIndicators",
        ],
        ("ModelExchange", _) => &[
            "modelIdentifier",
            "needsExecutionTool",
            "completedIntegratorStepNotNeeded",
            "canBeInstantiatedOnlyOncePerProcess",
            "canNotUseMemoryManagementFunctions",
            "canGetAndSetFMUstate",
            "canSerializeFMUstate",
            "providesDirectionalDerivative",
        ],
        ("CoSimulation", _) => &[
            "modelIdentifier",
            "needsExecutionTool",
            "canHandleVariableCommunicationStepSize",
            "canInterpolateInputs",
            "maxOutputDerivativeOrder",
            "canRunAsynchronuously",
            "canBeInstantiatedOnlyOncePerProcess",
            "canNotUseMemoryManagementFunctions",
            "canGetAndSetFMUstate",
            "canSerializeFMUstate",
            "providesDirectionalDerivative",
        ],
        ("File", _) | ("Unit", _) | ("Tool", _) => &["name"],
        ("BaseUnit", _) => &[
            "kg", "m", "s", "A", "K", "mol", "cd", "rad", "factor", "offset",
        ],
        ("DisplayUnit", _) => &["name", "factor", "offset"],
        ("SimpleType", _) | ("Category", _) => &["name", "description"],
        ("Real", "SimpleType") => REAL_ATTRS,
        ("Integer", "SimpleType") => &["quantity", "min", "max"],
        ("Enumeration", "SimpleType") => &["quantity"],
        ("Item", _) => &["name", "value", "description"],
        ("DefaultExperiment", _) => &["startTime", "stopTime", "tolerance", "stepSize"],
        ("ScalarVariable", _) => &[
            "name",
            "valueReference",
            "description",
            "causality",
            "variability",
            "initial",
            "canHandleMultipleSetPerTimeInstant",
        ],
        ("Real", "ScalarVariable") => &[
            "declaredType",
            "quantity",
            "unit",
            "displayUnit",
            "relativeQuantity",
            "min",
            "max",
            "nominal",
            "unbounded",
            "start",
            "derivative",
            "reinit",
        ],
        ("Integer", "ScalarVariable") => &["declaredType", "quantity", "min", "max", "start"],
        ("Boolean", "ScalarVariable") | ("String", "ScalarVariable") => &["declaredType", "start"],
        ("Enumeration", "ScalarVariable") => &["declaredType", "quantity", "min", "max", "start"],
        ("Unknown", _) => &["index", "dependencies", "dependenciesKind"],
        _ => &[],
    }
}

fn schema_children(parent: &str) -> &'static [&'static str] {
    match parent {
        "fmiModelDescription" => &[
            "ModelExchange",
            "CoSimulation",
            "UnitDefinitions",
            "TypeDefinitions",
            "LogCategories",
            "DefaultExperiment",
            "VendorAnnotations",
            "ModelVariables",
            "ModelStructure",
        ],
        "ModelExchange" | "CoSimulation" => &["SourceFiles"],
        "SourceFiles" => &["File"],
        "UnitDefinitions" => &["Unit"],
        "Unit" => &["BaseUnit", "DisplayUnit"],
        "TypeDefinitions" => &["SimpleType"],
        "SimpleType" => &["Real", "Integer", "Boolean", "String", "Enumeration"],
        "Enumeration" => &["Item"],
        "LogCategories" => &["Category"],
        "VendorAnnotations" | "Annotations" => &["Tool"],
        "ModelVariables" => &["ScalarVariable"],
        "ScalarVariable" => &[
            "Real",
            "Integer",
            "Boolean",
            "String",
            "Enumeration",
            "Annotations",
        ],
        "ModelStructure" => &["Outputs", "Derivatives", "InitialUnknowns"],
        "Outputs" | "Derivatives" | "InitialUnknowns" => &["Unknown"],
        _ => &[],
    }
}

/// Every element and attribute of `to_xml()` output is allowed by the schema and in its order.
fn assert_schema_order(xml: &str) {
    use quick_xml::events::Event;
    let mut reader = quick_xml::Reader::from_str(xml);
    // Stack of (element name, position of the last child in the schema's child order).
    let mut stack: Vec<(String, usize)> = Vec::new();
    loop {
        let event = reader.read_event().unwrap();
        let (e, empty) = match event {
            Event::Start(e) => (e, false),
            Event::Empty(e) => (e, true),
            Event::End(_) => {
                stack.pop();
                continue;
            }
            Event::Eof => break,
            _ => continue,
        };
        let name = e.name().as_ref().to_owned();
        let parent = stack.last().map(|(p, _)| p.clone()).unwrap_or_default();
        if parent == "Tool" {
            // Vendor content: anything goes; skip it.
            if !empty {
                reader.read_to_end(e.name()).unwrap();
            }
            continue;
        }
        if let Some((p, last)) = stack.last_mut() {
            let order = schema_children(p);
            let pos = order
                .iter()
                .position(|c| *c == name)
                .unwrap_or_else(|| panic!("<{name}> not allowed in <{p}>"));
            // Repeatable children keep the same position; others must strictly advance.
            assert!(pos >= *last, "<{name}> out of schema order inside <{p}>");
            *last = pos;
        }
        let allowed = schema_attributes(&name, &parent);
        let mut last = 0;
        for attr in e.attributes() {
            let attr = attr.unwrap();
            let key = attr.key.as_ref();
            let pos = allowed
                .iter()
                .position(|a| *a == key)
                .unwrap_or_else(|| panic!("attribute {key} not allowed on <{name}> in <{parent}>"));
            assert!(
                pos >= last,
                "attribute {key} of <{name}> out of schema order"
            );
            last = pos + 1;
        }
        if !empty {
            stack.push((name, 0));
        }
    }
}

#[test]
fn output_follows_schema_order() {
    assert_schema_order(&full().to_xml());
    let third = ModelDescription::from_xml(THIRD_PARTY).unwrap();
    assert_schema_order(&third.to_xml());
}

#[test]
fn unknown_attributes_and_namespaces_are_dropped_on_write() {
    let md = ModelDescription::from_xml(THIRD_PARTY).unwrap();
    let xml = md.to_xml();
    assert!(!xml.contains("vendorExtension"));
    assert!(!xml.contains("hideResult"));
    assert!(!xml.contains("someFutureFlag"));
    assert!(!xml.contains("xmlns:xsi"));
}

/// The writer gives the bytes of the quick-xml writer it replaced (`common/plain_writer.rs`)
/// on every fixture: the full and minimal descriptions, the third-party one, and variants
/// with escaped characters, every kind of float and tool annotations at both levels.
#[test]
fn the_writer_gives_the_reference_writers_bytes() {
    let minimal = ModelDescription::new("m", "g");
    let mut escaped = full();
    escaped.model_name = "a&b<c>d\"e'f\tg\nh\ri \u{e9}\u{1F600}".into();
    escaped.description = Some(" two  spaces & <tags> ".into());
    for (i, v) in escaped.model_variables.iter_mut().enumerate() {
        v.description = Some(format!("variable {i}: \"quoted\" & 'single'\n"));
    }
    let mut floats = full();
    let values = [
        0.0,
        -0.0,
        1.0,
        -1.0,
        0.1,
        1e-5,
        1e-7,
        1e15,
        1e16,
        1e17,
        123.456,
        5e-324,
        f64::MAX,
        f64::MIN_POSITIVE,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NAN,
        0.1 + 0.2,
        -2.5e-300,
    ];
    let mut extra = Vec::new();
    for (i, &x) in values.iter().enumerate() {
        let mut v = real(&format!("f{i}"), 1000 + i as u32, None, None, None, Some(x));
        if let VariableKind::Real { attributes, .. } = &mut v.kind {
            attributes.min = Some(x);
            attributes.max = Some(-x);
            attributes.nominal = Some(x * 3.0);
        }
        v.annotations = vec![
            ToolAnnotation {
                name: format!("tool{i}"),
                content: format!("<x v=\"{i}\"/>"),
            },
            ToolAnnotation {
                name: "empty".into(),
                content: String::new(),
            },
        ];
        extra.push(v);
    }
    floats.model_variables.extend(extra);
    floats.default_experiment = Some(DefaultExperiment {
        start_time: Some(-0.0),
        stop_time: Some(1e300),
        tolerance: Some(f64::NAN),
        step_size: Some(1e-9),
    });
    floats.vendor_annotations.push(ToolAnnotation {
        name: "nested".into(),
        content: "\n  <a>\n    <b c=\"&amp;\"/>\n  </a>\n".into(),
    });
    let third = ModelDescription::from_xml(THIRD_PARTY).unwrap();
    for (name, md) in [
        ("full", full()),
        ("minimal", minimal),
        ("third party", third),
        ("escaped", escaped),
        ("floats", floats),
    ] {
        assert_eq!(md.to_xml(), plain_writer::to_xml(&md), "{name}");
    }
}
