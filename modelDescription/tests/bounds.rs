//! Size bounds of the reader: a value at the bound is read, one byte more is refused with
//! `ParseError::TooLarge` naming what, its size, the bound and the line.

use model_description::read::{
    MAX_ANNOTATION_BYTES, MAX_ATTRIBUTE_BYTES, MAX_ATTRIBUTES, MAX_DOCUMENT_BYTES, MAX_NAME_BYTES,
};
use model_description::{ModelDescription, ParseError};

/// A valid document with `root` extra root attributes and `extra` before ModelVariables.
fn doc(root: &str, extra: &str) -> String {
    format!(
        "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n\
         <fmiModelDescription fmiVersion=\"2.0\" modelName=\"m\" guid=\"g\" {root}>\n\
         <CoSimulation modelIdentifier=\"m\"/>\n\
         {extra}\n\
         <ModelVariables/>\n<ModelStructure/>\n\
         </fmiModelDescription>\n"
    )
}

fn too_large(xml: &str) -> (String, usize, usize, usize) {
    match ModelDescription::from_xml(xml) {
        Err(ParseError::TooLarge {
            what,
            size,
            limit,
            line,
        }) => (what, size, limit, line),
        other => panic!("expected TooLarge, got {other:?}"),
    }
}

#[test]
fn an_attribute_value_past_the_bound_is_refused_before_it_is_copied() {
    let at = "d".repeat(MAX_ATTRIBUTE_BYTES);
    let md = ModelDescription::from_xml(&doc(&format!("description=\"{at}\""), "")).unwrap();
    assert_eq!(
        md.description.as_deref().map(str::len),
        Some(MAX_ATTRIBUTE_BYTES)
    );

    let over = format!("description=\"{at}d\"");
    let (what, size, limit, line) = too_large(&doc(&over, ""));
    assert_eq!(
        what,
        "the value of attribute description of <fmiModelDescription>"
    );
    assert_eq!(
        (size, limit, line),
        (MAX_ATTRIBUTE_BYTES + 1, MAX_ATTRIBUTE_BYTES, 2)
    );
    let e = ModelDescription::from_xml(&doc(&over, "")).unwrap_err();
    assert_eq!(
        e.to_string(),
        format!(
            "line 2: the value of attribute description of <fmiModelDescription> is {} bytes long (limit {})",
            MAX_ATTRIBUTE_BYTES + 1,
            MAX_ATTRIBUTE_BYTES
        )
    );
    assert_eq!(e.line(), Some(2));
}

#[test]
fn names_and_attribute_counts_past_the_bounds_are_refused() {
    let long = "x".repeat(MAX_NAME_BYTES + 1);
    let (what, size, ..) = too_large(&doc(&format!("{long}=\"1\""), ""));
    assert_eq!(what, "an attribute name in <fmiModelDescription>");
    assert_eq!(size, MAX_NAME_BYTES + 1);
    let (what, _, _, line) = too_large(&doc("", &format!("<{long}/>")));
    assert_eq!((what.as_str(), line), ("an element name", 4));
    // Unknown attributes are ignored, but not without bound.
    let many: String = (0..=MAX_ATTRIBUTES)
        .map(|i| format!(" a{i}=\"\""))
        .collect();
    let (what, size, limit, _) = too_large(&doc(&many, ""));
    assert_eq!(what, "the attribute list of <fmiModelDescription> (count)");
    assert_eq!((size, limit), (MAX_ATTRIBUTES + 4, MAX_ATTRIBUTES));
    let fewer: String = (0..MAX_ATTRIBUTES - 3)
        .map(|i| format!(" a{i}=\"\""))
        .collect();
    ModelDescription::from_xml(&doc(&fewer, "")).unwrap();
}

#[test]
fn tool_annotations_past_the_bound_are_refused() {
    let tool = |n: usize| {
        format!(
            "<VendorAnnotations><Tool name=\"t\"><x>{}</x></Tool></VendorAnnotations>",
            "a".repeat(n)
        )
    };
    // "<x>" + n + "</x>" is the inner XML kept verbatim.
    ModelDescription::from_xml(&doc("", &tool(MAX_ANNOTATION_BYTES - 7))).unwrap();
    let (what, size, limit, line) = too_large(&doc("", &tool(MAX_ANNOTATION_BYTES - 6)));
    assert_eq!(what, "the content of <Tool>");
    assert_eq!(
        (size, limit, line),
        (MAX_ANNOTATION_BYTES + 1, MAX_ANNOTATION_BYTES, 4)
    );
}

#[test]
fn a_document_past_the_bound_is_refused_unread() {
    let pad = " ".repeat(MAX_DOCUMENT_BYTES);
    let (what, size, limit, line) = too_large(&format!("{}{pad}", doc("", "")));
    assert_eq!(what, "the document");
    assert!(size > limit);
    assert_eq!((limit, line), (MAX_DOCUMENT_BYTES, 1));
}
