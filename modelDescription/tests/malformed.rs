//! Documents that must be refused, one test per case, with the expected error.

use model_description::{ModelDescription, ParseError};

/// A valid document with `{vars}` inside ModelVariables and `{root}` extra root attributes.
fn doc(root_attrs: &str, body: &str) -> String {
    format!(
        "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n\
         <fmiModelDescription fmiVersion=\"2.0\" {root_attrs}>\n\
         <CoSimulation modelIdentifier=\"m\"/>\n\
         {body}\n\
         </fmiModelDescription>\n"
    )
}

fn vars(variables: &str) -> String {
    doc(
        "modelName=\"m\" guid=\"g\"",
        &format!("<ModelVariables>\n{variables}\n</ModelVariables>\n<ModelStructure/>"),
    )
}

fn err(xml: &str) -> ParseError {
    match ModelDescription::from_xml(xml) {
        Ok(md) => panic!("accepted:\n{xml}\n{md:#?}"),
        Err(e) => e,
    }
}

fn assert_missing(xml: &str, element: &str, attribute: &str) {
    match err(xml) {
        ParseError::MissingAttribute {
            element: e,
            attribute: a,
            ..
        } => assert_eq!((e.as_str(), a.as_str()), (element, attribute)),
        other => panic!("expected MissingAttribute {element}@{attribute}, got {other:?}"),
    }
}

fn assert_invalid(xml: &str, element: &str, attribute: &str) {
    match err(xml) {
        ParseError::InvalidValue {
            element: e,
            attribute: a,
            ..
        } => assert_eq!((e.as_str(), a.as_str()), (element, attribute)),
        other => panic!("expected InvalidValue {element}@{attribute}, got {other:?}"),
    }
}

fn assert_xml_error(xml: &str) {
    match err(xml) {
        ParseError::Xml { .. } => {}
        other => panic!("expected Xml, got {other:?}"),
    }
}

#[test]
fn valid_base_document_is_accepted() {
    let xml = vars("<ScalarVariable name=\"x\" valueReference=\"0\"><Real/></ScalarVariable>");
    ModelDescription::from_xml(&xml).unwrap();
}

#[test]
fn mismatched_end_tag() {
    assert_xml_error(&doc(
        "modelName=\"m\" guid=\"g\"",
        "<ModelVariables></ModelStructure>",
    ));
}

#[test]
fn unclosed_root() {
    assert_xml_error(
        "<fmiModelDescription fmiVersion=\"2.0\" modelName=\"m\" guid=\"g\"><ModelVariables/>",
    );
}

#[test]
fn truncated_document() {
    let xml = vars("<ScalarVariable name=\"x\" valueReference=\"0\"><Real/></ScalarVariable>");
    assert_xml_error(&xml[..xml.len() / 2]);
}

#[test]
fn element_after_root() {
    let xml = format!(
        "{}<other/>",
        vars("<ScalarVariable name=\"x\" valueReference=\"0\"><Real/></ScalarVariable>")
    );
    assert_xml_error(&xml);
}

#[test]
fn empty_document() {
    assert_xml_error("");
    assert_xml_error("<?xml version=\"1.0\"?>\n<!-- nothing -->\n");
}

#[test]
fn unquoted_attribute() {
    assert_xml_error("<fmiModelDescription fmiVersion=2.0 modelName=\"m\" guid=\"g\"/>");
}

#[test]
fn duplicate_attribute() {
    assert_xml_error(&doc("modelName=\"m\" modelName=\"n\" guid=\"g\"", ""));
}

#[test]
fn undefined_entity_in_attribute() {
    assert_xml_error(&doc("modelName=\"a &nbsp; b\" guid=\"g\"", ""));
}

#[test]
fn wrong_root_element() {
    match err("<?xml version=\"1.0\"?>\n<fmiModelDescriptionX fmiVersion=\"2.0\"/>") {
        ParseError::WrongRoot { element, line } => {
            assert_eq!(element, "fmiModelDescriptionX");
            assert_eq!(line, 2);
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn unsupported_versions() {
    for version in ["1.0", "3.0", "2.0.1", ""] {
        let xml = format!(
            "<fmiModelDescription fmiVersion=\"{version}\" modelName=\"m\" guid=\"g\">\
             <ModelVariables/><ModelStructure/></fmiModelDescription>"
        );
        assert_eq!(
            err(&xml),
            ParseError::UnsupportedVersion(version.to_owned())
        );
    }
}

/// Tags the XML reader lets through but no well-formed document holds are malformed XML, with
/// the line: they were reported as an unsupported version (`fmiVersion="2.0<"`) or a missing
/// `fmiVersion` (read as an attribute named `<fmiVersion`).
#[test]
fn malformed_tags_are_malformed_xml_not_a_bad_version() {
    for (root, reason) in [
        ("fmiVersion=\"2.0<\"", "the value of fmiVersion holds a '<'"),
        (
            "<fmiVersion=\"2.0\"",
            "'<fmiVersion' is not an attribute name",
        ),
        (
            "fmi<Version=\"2.0\"",
            "'fmi<Version' is not an attribute name",
        ),
        (
            "fmiVersion=\"2.0\"modelName=\"m\"",
            "no white space after the value of fmiVersion",
        ),
    ] {
        let xml = format!(
            "<?xml version=\"1.0\"?>\n<fmiModelDescription {root} guid=\"g\">\
             <ModelVariables/><ModelStructure/></fmiModelDescription>"
        );
        match err(&xml) {
            ParseError::Xml { message, line, .. } => {
                assert_eq!(line, 2, "{root}");
                assert!(message.contains(reason), "{root}: {message}");
            }
            other => panic!("{root}: expected Xml, got {other:?}"),
        }
    }
    // The same in a child element, on its line.
    let xml = vars("<ScalarVariable name=\"x<\" valueReference=\"0\"><Real/></ScalarVariable>");
    match err(&xml) {
        ParseError::Xml { message, line, .. } => {
            assert_eq!(line, 5, "{xml}");
            assert!(
                message.contains("the value of name holds a '<'"),
                "{message}"
            );
        }
        other => panic!("expected Xml, got {other:?}"),
    }
}

#[test]
fn malformed_tag_accepts_well_formed_tags() {
    use model_description::read::malformed_tag;
    for tag in [
        "a",
        "a ",
        "ssd:Component name=\"x\" source='y.fmu'",
        "a b = \"1\"\tc='>' d=\"&amp;\"",
        "\u{e9}l\u{e9}ment \u{e9}=\"\u{fc}\"",
    ] {
        assert_eq!(malformed_tag(tag), None, "{tag}");
    }
    for tag in [
        "1a",
        "a <b=\"1\"",
        "a b=\"<\"",
        "a b=\"1\"c=\"2\"",
        "a b='1'/c='2'",
    ] {
        assert!(malformed_tag(tag).is_some(), "{tag}");
    }
}

#[test]
fn missing_fmi_version() {
    assert_missing(
        "<fmiModelDescription modelName=\"m\" guid=\"g\"/>",
        "fmiModelDescription",
        "fmiVersion",
    );
}

#[test]
fn missing_model_name() {
    assert_missing(&doc("guid=\"g\"", ""), "fmiModelDescription", "modelName");
}

#[test]
fn missing_guid() {
    assert_missing(&doc("modelName=\"m\"", ""), "fmiModelDescription", "guid");
}

#[test]
fn missing_model_identifier() {
    let xml = "<fmiModelDescription fmiVersion=\"2.0\" modelName=\"m\" guid=\"g\">\
               <ModelExchange/><ModelVariables/><ModelStructure/></fmiModelDescription>";
    assert_missing(xml, "ModelExchange", "modelIdentifier");
}

#[test]
fn missing_variable_name() {
    assert_missing(
        &vars("<ScalarVariable valueReference=\"0\"><Real/></ScalarVariable>"),
        "ScalarVariable",
        "name",
    );
}

#[test]
fn missing_value_reference() {
    assert_missing(
        &vars("<ScalarVariable name=\"x\"><Real/></ScalarVariable>"),
        "ScalarVariable",
        "valueReference",
    );
}

#[test]
fn missing_enumeration_declared_type() {
    assert_missing(
        &vars("<ScalarVariable name=\"x\" valueReference=\"0\"><Enumeration/></ScalarVariable>"),
        "Enumeration",
        "declaredType",
    );
}

#[test]
fn missing_unknown_index() {
    let xml = doc(
        "modelName=\"m\" guid=\"g\"",
        "<ModelVariables/><ModelStructure><Outputs><Unknown/></Outputs></ModelStructure>",
    );
    assert_missing(&xml, "Unknown", "index");
}

#[test]
fn missing_item_value_and_unit_name() {
    let xml = doc(
        "modelName=\"m\" guid=\"g\"",
        "<TypeDefinitions><SimpleType name=\"E\"><Enumeration><Item name=\"a\"/></Enumeration>\
         </SimpleType></TypeDefinitions><ModelVariables/><ModelStructure/>",
    );
    assert_missing(&xml, "Item", "value");
    let xml = doc(
        "modelName=\"m\" guid=\"g\"",
        "<UnitDefinitions><Unit/></UnitDefinitions><ModelVariables/><ModelStructure/>",
    );
    assert_missing(&xml, "Unit", "name");
    let xml = doc(
        "modelName=\"m\" guid=\"g\"",
        "<VendorAnnotations><Tool/></VendorAnnotations><ModelVariables/><ModelStructure/>",
    );
    assert_missing(&xml, "Tool", "name");
}

#[test]
fn non_numeric_value_reference() {
    assert_invalid(
        &vars("<ScalarVariable name=\"x\" valueReference=\"abc\"><Real/></ScalarVariable>"),
        "ScalarVariable",
        "valueReference",
    );
}

#[test]
fn negative_value_reference() {
    assert_invalid(
        &vars("<ScalarVariable name=\"x\" valueReference=\"-1\"><Real/></ScalarVariable>"),
        "ScalarVariable",
        "valueReference",
    );
}

#[test]
fn value_reference_out_of_range() {
    assert_invalid(
        &vars("<ScalarVariable name=\"x\" valueReference=\"4294967296\"><Real/></ScalarVariable>"),
        "ScalarVariable",
        "valueReference",
    );
}

#[test]
fn non_numeric_real_start() {
    for bad in ["1.2.3", "0x10", "", "one", "1,5", "inf inity"] {
        assert_invalid(
            &vars(&format!(
                "<ScalarVariable name=\"x\" valueReference=\"0\"><Real start=\"{bad}\"/></ScalarVariable>"
            )),
            "Real",
            "start",
        );
    }
}

#[test]
fn non_integer_integer_start() {
    assert_invalid(
        &vars(
            "<ScalarVariable name=\"x\" valueReference=\"0\"><Integer start=\"1.5\"/></ScalarVariable>",
        ),
        "Integer",
        "start",
    );
}

#[test]
fn bad_causality() {
    match err(&vars(
        "<ScalarVariable name=\"x\" valueReference=\"0\" causality=\"foo\"><Real/></ScalarVariable>",
    )) {
        ParseError::InvalidValue {
            element,
            attribute,
            value,
            expected,
            line,
        } => {
            assert_eq!(element, "ScalarVariable");
            assert_eq!(attribute, "causality");
            assert_eq!(value, "foo");
            assert!(expected.contains("calculatedParameter"));
            assert_eq!(line, 5);
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn bad_variability_and_initial() {
    assert_invalid(
        &vars(
            "<ScalarVariable name=\"x\" valueReference=\"0\" variability=\"Continuous\"><Real/></ScalarVariable>",
        ),
        "ScalarVariable",
        "variability",
    );
    assert_invalid(
        &vars(
            "<ScalarVariable name=\"x\" valueReference=\"0\" initial=\"guess\"><Real/></ScalarVariable>",
        ),
        "ScalarVariable",
        "initial",
    );
    assert_invalid(
        &doc(
            "modelName=\"m\" guid=\"g\" variableNamingConvention=\"tree\"",
            "<ModelVariables/><ModelStructure/>",
        ),
        "fmiModelDescription",
        "variableNamingConvention",
    );
}

#[test]
fn bad_booleans() {
    for bad in ["yes", "TRUE", "True", "2", ""] {
        assert_invalid(
            &vars(&format!(
                "<ScalarVariable name=\"x\" valueReference=\"0\" variability=\"discrete\">\
                 <Boolean start=\"{bad}\"/></ScalarVariable>"
            )),
            "Boolean",
            "start",
        );
    }
    let xml = "<fmiModelDescription fmiVersion=\"2.0\" modelName=\"m\" guid=\"g\">\
               <CoSimulation modelIdentifier=\"m\" canHandleVariableCommunicationStepSize=\"yes\"/>\
               <ModelVariables/><ModelStructure/></fmiModelDescription>";
    assert_invalid(
        xml,
        "CoSimulation",
        "canHandleVariableCommunicationStepSize",
    );
}

#[test]
fn bad_dependencies() {
    let structure = |attrs: &str| {
        doc(
            "modelName=\"m\" guid=\"g\"",
            &format!(
                "<ModelVariables/><ModelStructure><Outputs><Unknown index=\"1\" {attrs}/>\
                 </Outputs></ModelStructure>"
            ),
        )
    };
    assert_invalid(
        &structure("dependencies=\"1 x\""),
        "Unknown",
        "dependencies",
    );
    assert_invalid(
        &structure("dependencies=\"1,2\""),
        "Unknown",
        "dependencies",
    );
    assert_invalid(
        &structure("dependencies=\"1\" dependenciesKind=\"sometimes\""),
        "Unknown",
        "dependenciesKind",
    );
    let xml = doc(
        "modelName=\"m\" guid=\"g\"",
        "<ModelVariables/><ModelStructure><Outputs><Unknown index=\"0x1\"/></Outputs></ModelStructure>",
    );
    assert_invalid(&xml, "Unknown", "index");
}

#[test]
fn variable_without_type_element() {
    match err(&vars(
        "<ScalarVariable name=\"x\" valueReference=\"0\"><Annotations/></ScalarVariable>",
    )) {
        // Annotations before the type element is out of schema order.
        ParseError::UnexpectedElement { element, .. } => assert_eq!(element, "Annotations"),
        other => panic!("{other:?}"),
    }
    match err(&vars("<ScalarVariable name=\"x\" valueReference=\"0\"/>")) {
        ParseError::Structure { message, line } => {
            assert!(message.contains("no type element"), "{message}");
            assert_eq!(line, 5);
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn variable_with_two_type_elements() {
    match err(&vars(
        "<ScalarVariable name=\"x\" valueReference=\"0\"><Real/><Integer/></ScalarVariable>",
    )) {
        ParseError::Structure { message, .. } => {
            assert!(message.contains("more than one type element"), "{message}")
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn simple_type_without_or_with_two_type_elements() {
    let types = |inner: &str| {
        doc(
            "modelName=\"m\" guid=\"g\"",
            &format!(
                "<TypeDefinitions><SimpleType name=\"T\">{inner}</SimpleType></TypeDefinitions>\
                 <ModelVariables/><ModelStructure/>"
            ),
        )
    };
    assert!(matches!(err(&types("")), ParseError::Structure { .. }));
    assert!(matches!(
        err(&types("<Real/><Real/>")),
        ParseError::Structure { .. }
    ));
}

#[test]
fn unknown_element() {
    match err(&vars(
        "<ScalarVariable name=\"x\" valueReference=\"0\"><Real/></ScalarVariable><Foo/>",
    )) {
        ParseError::UnexpectedElement {
            element, parent, ..
        } => {
            assert_eq!(element, "Foo");
            assert_eq!(parent, "ModelVariables");
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn repeated_singleton_element() {
    let xml = doc(
        "modelName=\"m\" guid=\"g\"",
        "<CoSimulation modelIdentifier=\"n\"/><ModelVariables/><ModelStructure/>",
    );
    match err(&xml) {
        ParseError::UnexpectedElement {
            element, parent, ..
        } => {
            assert_eq!(element, "CoSimulation");
            assert_eq!(parent, "fmiModelDescription");
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn missing_model_variables_or_structure() {
    assert!(matches!(
        err(&doc("modelName=\"m\" guid=\"g\"", "<ModelStructure/>")),
        ParseError::Structure { .. }
    ));
    assert!(matches!(
        err(&doc("modelName=\"m\" guid=\"g\"", "<ModelVariables/>")),
        ParseError::Structure { .. }
    ));
}

#[test]
fn invalid_utf8() {
    let mut bytes =
        vars("<ScalarVariable name=\"x\" valueReference=\"0\"><Real/></ScalarVariable>")
            .into_bytes();
    let at = bytes.len() - 30;
    bytes[at] = 0xFF;
    match ModelDescription::from_bytes(&bytes) {
        Err(ParseError::NotUtf8 { position, .. }) => assert_eq!(position, at),
        other => panic!("{other:?}"),
    }
}

#[test]
fn errors_say_where() {
    let e = err(&vars(
        "<ScalarVariable name=\"x\" valueReference=\"0\">\n<Real start=\"x\"/></ScalarVariable>",
    ));
    assert_eq!(e.line(), Some(6));
    let text = e.to_string();
    assert!(text.contains("line 6"), "{text}");
    assert!(text.contains("start"), "{text}");
    assert!(text.contains("Real"), "{text}");
}

/// A malformed XML declaration is malformed XML (quick-xml does not check it): a misspelt
/// version, a version that is not 1.x, an attribute out of place; a well-formed one passes.
#[test]
fn malformed_xml_declarations_are_malformed_xml() {
    let body = vars("<ScalarVariable name=\"x\" valueReference=\"0\"><Real/></ScalarVariable>");
    let body = body.split_once('\n').unwrap().1;
    for decl in [
        "<?xml versio=\"1.0\"?>",
        "<?xml version=\"2.0\"?>",
        "<?xml encoding=\"UTF-8\" version=\"1.0\"?>",
        "<?xml version=\"1.0\" name=\"x\"?>",
        "<?xml?>",
    ] {
        assert_xml_error(&format!("{decl}\n{body}"));
    }
    for decl in [
        "<?xml version=\"1.0\"?>",
        "<?xml version='1.1' encoding='utf-8' standalone='yes'?>",
    ] {
        ModelDescription::from_xml(&format!("{decl}\n{body}")).unwrap();
    }
}
