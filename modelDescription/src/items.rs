//! Named values of `Integer` types: modes declared as `Integer` for importers without
//! `Enumeration` support, with their items' names kept for the tools that show or parse them.
//!
//! libcosim (and other importers built on it) ignores FMI 2.0 `Enumeration` variables
//! altogether: it neither lists them nor lets an SSP parameter binding set one. kneebench's FMUs
//! therefore declare their modes (the plant's `configuration`, a controller's `antiWindup`, ...)
//! as `Integer` variables whose `declaredType` is an `Integer` `SimpleType`, bounded by the
//! items' values and naming the items in its description. The items themselves (name, value,
//! description) go into one `VendorAnnotations/Tool` named [`ITEMS_TOOL`], per type:
//!
//! ```xml
//! <Tool name="org.kneebench.items">
//!   <IntegerItems>
//!     <Type name="Configuration">
//!       <Item name="DA" value="0" description="Direct actuation ..."/>
//!       ...
//!     </Type>
//!   </IntegerItems>
//! </Tool>
//! ```
//!
//! (The schema allows one element inside a `Tool`, any content, processed laxly; importers
//! skip vendor annotations they do not know.) [`ModelDescription::items_of`] answers a
//! variable's items from either form: an `Enumeration`'s type definition, or an `Integer`'s
//! declared type named in this annotation.

use quick_xml::XmlVersion;
use quick_xml::events::Event;

use crate::types::{
    EnumerationItem, ModelDescription, ScalarVariable, SimpleTypeKind, ToolAnnotation, VariableKind,
};
use crate::write::escape_attribute;

/// The `name` of the `VendorAnnotations/Tool` holding the items of `Integer` types.
pub const ITEMS_TOOL: &str = "org.kneebench.items";

/// One `Integer` type's items, as [`items_annotation`] writes them.
#[derive(Debug, Clone, PartialEq)]
pub struct IntegerItems {
    /// The type's name (the `declaredType` of its variables).
    pub type_name: String,
    /// The items, in declaration order.
    pub items: Vec<EnumerationItem>,
}

/// The `VendorAnnotations/Tool` ([`ITEMS_TOOL`]) listing the items of `types`.
pub fn items_annotation(types: &[IntegerItems]) -> ToolAnnotation {
    let mut content = String::from("<IntegerItems>");
    for t in types {
        content.push_str(&format!(
            "<Type name=\"{}\">",
            escape_attribute(&t.type_name)
        ));
        for item in &t.items {
            content.push_str(&format!(
                "<Item name=\"{}\" value=\"{}\"",
                escape_attribute(&item.name),
                item.value
            ));
            if let Some(d) = &item.description {
                content.push_str(&format!(" description=\"{}\"", escape_attribute(d)));
            }
            content.push_str("/>");
        }
        content.push_str("</Type>");
    }
    content.push_str("</IntegerItems>");
    ToolAnnotation {
        name: ITEMS_TOOL.to_string(),
        content,
    }
}

/// The types listed by an [`ITEMS_TOOL`] annotation's content; `None` when the content is not
/// such a list (malformed XML, an item without a name or an integer value).
pub fn parse_items_annotation(content: &str) -> Option<Vec<IntegerItems>> {
    let mut reader = quick_xml::Reader::from_str(content);
    let mut types: Vec<IntegerItems> = Vec::new();
    loop {
        match reader.read_event().ok()? {
            Event::Start(e) | Event::Empty(e) => {
                let mut name = None;
                let mut value = None;
                let mut description = None;
                for a in e.attributes() {
                    let a = a.ok()?;
                    let v = a
                        .normalized_value(XmlVersion::Implicit1_0)
                        .ok()?
                        .into_owned();
                    match a.key.as_ref() {
                        "name" => name = Some(v),
                        "value" => value = Some(v),
                        "description" => description = Some(v),
                        _ => {}
                    }
                }
                match e.local_name().as_ref() {
                    "Type" => types.push(IntegerItems {
                        type_name: name?,
                        items: Vec::new(),
                    }),
                    "Item" => types.last_mut()?.items.push(EnumerationItem {
                        name: name?,
                        value: value?.trim().parse().ok()?,
                        description,
                    }),
                    _ => {}
                }
            }
            Event::Eof => return Some(types),
            _ => {}
        }
    }
}

impl ModelDescription {
    /// The named values of `variable` as (type name, items): an `Enumeration`'s items from its
    /// type definition, or an `Integer`'s whose `declaredType` an [`ITEMS_TOOL`] annotation
    /// lists; `None` for any other variable.
    pub fn items_of(&self, variable: &ScalarVariable) -> Option<(String, Vec<EnumerationItem>)> {
        match &variable.kind {
            VariableKind::Enumeration { declared_type, .. } => {
                match &self.type_definition(declared_type)?.kind {
                    SimpleTypeKind::Enumeration { items, .. } => {
                        Some((declared_type.clone(), items.clone()))
                    }
                    _ => None,
                }
            }
            VariableKind::Integer {
                declared_type: Some(declared_type),
                ..
            } => self
                .vendor_annotations
                .iter()
                .filter(|t| t.name == ITEMS_TOOL)
                .filter_map(|t| parse_items_annotation(&t.content))
                .flatten()
                .find(|t| &t.type_name == declared_type)
                .map(|t| (t.type_name, t.items)),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn items() -> Vec<IntegerItems> {
        vec![
            IntegerItems {
                type_name: "Configuration".into(),
                items: vec![
                    EnumerationItem {
                        name: "DA".into(),
                        value: 0,
                        description: Some("Direct \"actuation\" & <blocked> spring".into()),
                    },
                    EnumerationItem {
                        name: "SEA".into(),
                        value: 1,
                        description: None,
                    },
                ],
            },
            IntegerItems {
                type_name: "HoldAction".into(),
                items: vec![EnumerationItem {
                    name: "ZeroOutput".into(),
                    value: -2,
                    description: Some("Output zero".into()),
                }],
            },
        ]
    }

    #[test]
    fn the_annotation_round_trips() {
        let tool = items_annotation(&items());
        assert_eq!(tool.name, ITEMS_TOOL);
        assert_eq!(parse_items_annotation(&tool.content), Some(items()));
    }

    /// A description with an `Enumeration` (as other exporters write modes), a mode declared as
    /// `Integer` with the items annotation (as ours), and a plain `Integer`.
    const DESCRIPTION: &str = r#"<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="m" guid="{g}">
  <CoSimulation modelIdentifier="m"/>
  <TypeDefinitions>
    <SimpleType name="Law"><Enumeration><Item name="Off" value="0"/><Item name="On" value="1"/></Enumeration></SimpleType>
    <SimpleType name="Configuration" description="(0 = DA, 1 = SEA)"><Integer min="0" max="1"/></SimpleType>
  </TypeDefinitions>
  <VendorAnnotations>
    <Tool name="other"><Anything/></Tool>
    <Tool name="org.kneebench.items"><IntegerItems><Type name="Configuration"><Item name="DA" value="0"/><Item name="SEA" value="1" description="Series elastic"/></Type></IntegerItems></Tool>
  </VendorAnnotations>
  <ModelVariables>
    <ScalarVariable name="law" valueReference="1" causality="parameter" variability="fixed"><Enumeration declaredType="Law" start="0"/></ScalarVariable>
    <ScalarVariable name="configuration" valueReference="2" causality="parameter" variability="fixed"><Integer declaredType="Configuration" start="1"/></ScalarVariable>
    <ScalarVariable name="count" valueReference="3" causality="parameter" variability="fixed"><Integer start="1"/></ScalarVariable>
  </ModelVariables>
  <ModelStructure/>
</fmiModelDescription>
"#;

    #[test]
    fn items_of_answers_enumerations_and_annotated_integers_only() {
        let md = ModelDescription::from_xml(DESCRIPTION).unwrap();
        let names = |v: &str| {
            md.items_of(md.variable_by_name(v).unwrap())
                .map(|(t, items)| (t, items.into_iter().map(|i| (i.name, i.value)).collect()))
        };
        assert_eq!(
            names("law"),
            Some(("Law".into(), vec![("Off".into(), 0), ("On".into(), 1)]))
        );
        assert_eq!(
            names("configuration"),
            Some((
                "Configuration".into(),
                vec![("DA".into(), 0), ("SEA".into(), 1)]
            ))
        );
        assert_eq!(names("count"), None);
    }

    #[test]
    fn malformed_annotations_give_no_items() {
        for bad in [
            "<IntegerItems><Item name=\"A\" value=\"0\"/></IntegerItems>", // no Type
            "<IntegerItems><Type name=\"T\"><Item value=\"0\"/></Type></IntegerItems>",
            "<IntegerItems><Type name=\"T\"><Item name=\"A\" value=\"x\"/></Type></IntegerItems>",
            "<IntegerItems><Type><Item name=\"A\" value=\"0\"/></Type></IntegerItems>",
            "<IntegerItems><Type name=\"T\"><Item name=\"A\" value=\"0\"></Type>",
        ] {
            assert_eq!(parse_items_annotation(bad), None, "{bad}");
        }
    }
}
