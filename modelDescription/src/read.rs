//! Reading `modelDescription.xml` into a [`ModelDescription`].
//!
//! Tolerant where real exporters differ, strict where the document would be meaningless:
//!
//! - Ignored: unknown attributes (for example `xmlns:xsi`, vendor extensions), comments,
//!   processing instructions, the XML declaration, a DOCTYPE, whitespace and stray text, the
//!   order of the root's children, a UTF-8 byte order mark.
//! - Kept verbatim: the inner XML of `VendorAnnotations/Tool` and
//!   `ScalarVariable/Annotations/Tool`, so writing back keeps it.
//! - Refused, with the element, attribute and line: XML that is not well-formed, a root other
//!   than `fmiModelDescription`, `fmiVersion` other than `2.0`, a missing required attribute,
//!   a number, boolean or enumeration value that does not parse, an unknown element where the
//!   schema allows none, a repeated singleton element, a `ScalarVariable` or `SimpleType`
//!   without (or with two) type elements, a missing `ModelVariables` or `ModelStructure`.
//!
//! Sizes are bounded before anything is copied, so that a hostile document cannot make the
//! reader (or a tool printing what it read) hold huge strings: the document
//! ([`MAX_DOCUMENT_BYTES`]), element and attribute names ([`MAX_NAME_BYTES`]), the number of
//! attributes of an element ([`MAX_ATTRIBUTES`]), an attribute value ([`MAX_ATTRIBUTE_BYTES`])
//! and the verbatim inner XML of a `Tool` annotation ([`MAX_ANNOTATION_BYTES`]). Past a bound
//! the document is refused with [`ParseError::TooLarge`].
//!
//! Values are taken as the XML attribute-value normalization gives them (entities and character
//! references resolved, literal tabs and newlines turned into spaces). Numbers, booleans and
//! enumeration values may carry surrounding whitespace (the XSD types collapse it); strings are
//! kept exactly.

use std::borrow::Cow;

use quick_xml::Reader;
use quick_xml::XmlVersion;
use quick_xml::events::attributes::Attributes;
use quick_xml::events::{BytesStart, Event};
use quick_xml::name::QName;

use crate::types::*;

/// The largest document read, in bytes (512 MiB).
pub const MAX_DOCUMENT_BYTES: usize = 512 << 20;
/// The longest element or attribute name, in bytes.
pub const MAX_NAME_BYTES: usize = 4 << 10;
/// The most attributes one element may have.
pub const MAX_ATTRIBUTES: usize = 1024;
/// The longest attribute value, in bytes before normalization (4 MiB: room for the
/// `dependencies` list of a model with a few hundred thousand variables).
pub const MAX_ATTRIBUTE_BYTES: usize = 4 << 20;
/// The longest verbatim inner XML of a `Tool` annotation, in bytes (16 MiB).
pub const MAX_ANNOTATION_BYTES: usize = 16 << 20;

/// Why a document could not be read. Lines are 1-based and count from the start of the
/// document.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ParseError {
    /// The input is not UTF-8 (only [`ModelDescription::from_bytes`] returns this).
    #[error("the document is not valid UTF-8 (byte {position}, line {line})")]
    NotUtf8 {
        /// Byte offset of the first invalid byte.
        position: usize,
        /// Line of the first invalid byte.
        line: usize,
    },
    /// The document is not well-formed XML (or is empty, or has content after the root).
    #[error("malformed XML at line {line} (byte {position}): {message}")]
    Xml {
        /// What is wrong, as quick-xml or this reader says it.
        message: String,
        /// Byte offset where the problem was found.
        position: usize,
        /// Line where the problem was found.
        line: usize,
    },
    /// The root element is not `fmiModelDescription`.
    #[error("line {line}: the root element is <{element}>, expected <fmiModelDescription>")]
    WrongRoot {
        /// The root element found.
        element: String,
        /// Its line.
        line: usize,
    },
    /// `fmiVersion` is not `2.0`.
    #[error("unsupported fmiVersion \"{0}\": only FMI 2.0 is supported")]
    UnsupportedVersion(String),
    /// A required attribute is missing.
    #[error("line {line}: <{element}> lacks the required attribute \"{attribute}\"")]
    MissingAttribute {
        /// The element.
        element: String,
        /// The missing attribute.
        attribute: String,
        /// The element's line.
        line: usize,
    },
    /// An attribute value does not parse as its schema type.
    #[error(
        "line {line}: <{element}> attribute {attribute}=\"{value}\" is invalid: expected {expected}"
    )]
    InvalidValue {
        /// The element.
        element: String,
        /// The attribute.
        attribute: String,
        /// The value found.
        value: String,
        /// What the schema allows.
        expected: String,
        /// The element's line.
        line: usize,
    },
    /// An element where the schema allows none of that name, or a second one of a singleton.
    #[error("line {line}: unexpected element <{element}> inside <{parent}>")]
    UnexpectedElement {
        /// The element found.
        element: String,
        /// The element it was found in.
        parent: String,
        /// Its line.
        line: usize,
    },
    /// Something is larger than the reader's bound for it (see the module documentation).
    #[error("line {line}: {what} is {size} bytes long (limit {limit})")]
    TooLarge {
        /// What is too large (for example `"the value of attribute description of
        /// <fmiModelDescription>"`).
        what: String,
        /// Its size (bytes, or a count for the number of attributes).
        size: usize,
        /// The bound.
        limit: usize,
        /// The line where it starts.
        line: usize,
    },
    /// A structural rule of the schema is broken (no type element in a variable, two type
    /// elements, a missing `ModelVariables`...).
    #[error("line {line}: {message}")]
    Structure {
        /// What is wrong.
        message: String,
        /// The line of the element concerned.
        line: usize,
    },
}

impl ParseError {
    /// The 1-based line the error refers to, when it refers to one.
    pub fn line(&self) -> Option<usize> {
        match self {
            ParseError::NotUtf8 { line, .. }
            | ParseError::Xml { line, .. }
            | ParseError::WrongRoot { line, .. }
            | ParseError::MissingAttribute { line, .. }
            | ParseError::InvalidValue { line, .. }
            | ParseError::UnexpectedElement { line, .. }
            | ParseError::TooLarge { line, .. }
            | ParseError::Structure { line, .. } => Some(*line),
            ParseError::UnsupportedVersion(_) => None,
        }
    }
}

impl ModelDescription {
    /// Reads a model description from XML text. A leading byte order mark is skipped.
    pub fn from_xml(xml: &str) -> Result<ModelDescription, ParseError> {
        let xml = xml.strip_prefix('\u{feff}').unwrap_or(xml);
        // The XML parser would skip a second mark too and count its positions from after it,
        // so that the verbatim annotations were cut three bytes off.
        if xml.starts_with('\u{feff}') {
            return Err(ParseError::Xml {
                message: "a second byte order mark".into(),
                position: 0,
                line: 1,
            });
        }
        if xml.len() > MAX_DOCUMENT_BYTES {
            return Err(ParseError::TooLarge {
                what: "the document".into(),
                size: xml.len(),
                limit: MAX_DOCUMENT_BYTES,
                line: 1,
            });
        }
        Parser::new(xml).document()
    }

    /// Reads a model description from the bytes of `modelDescription.xml` (UTF-8, with or
    /// without a byte order mark).
    pub fn from_bytes(bytes: &[u8]) -> Result<ModelDescription, ParseError> {
        // The mark is left to `from_xml` (stripping it here too took two).
        match std::str::from_utf8(bytes) {
            Ok(s) => ModelDescription::from_xml(s),
            Err(e) => {
                let position = e.valid_up_to();
                let line = 1 + bytes[..position].iter().filter(|&&b| b == b'\n').count();
                Err(ParseError::NotUtf8 { position, line })
            }
        }
    }
}

/// A start (or empty) tag with its attributes already normalized.
/// Borrowed from the document: the name, the attribute names, and the values that need no
/// normalizing.
struct Elem<'a> {
    name: &'a str,
    attrs: Vec<(&'a str, Cow<'a, str>)>,
    line: usize,
    empty: bool,
}

enum Item<'a> {
    Start(Elem<'a>),
    End,
    Eof,
}

struct Parser<'a> {
    src: &'a str,
    reader: Reader<&'a [u8]>,
    /// Line-counting cache: `line` is the line of byte `line_pos`.
    line_pos: usize,
    line: usize,
}

impl<'a> Parser<'a> {
    fn new(src: &'a str) -> Self {
        let mut reader = Reader::from_str(src);
        let config = reader.config_mut();
        config.check_end_names = true;
        config.expand_empty_elements = false;
        config.trim_text(false);
        Parser {
            src,
            reader,
            line_pos: 0,
            line: 1,
        }
    }

    /// The 1-based line of byte `pos` (positions are mostly asked for in increasing order).
    fn line_at(&mut self, pos: usize) -> usize {
        let pos = pos.min(self.src.len());
        let bytes = self.src.as_bytes();
        if pos >= self.line_pos {
            self.line += bytes[self.line_pos..pos]
                .iter()
                .filter(|&&b| b == b'\n')
                .count();
        } else {
            self.line = 1 + bytes[..pos].iter().filter(|&&b| b == b'\n').count();
        }
        self.line_pos = pos;
        self.line
    }

    fn xml_error(&mut self, message: String, position: usize) -> ParseError {
        let line = self.line_at(position);
        ParseError::Xml {
            message,
            position,
            line,
        }
    }

    fn next(&mut self) -> Result<Item<'a>, ParseError> {
        loop {
            let pos = to_usize(self.reader.buffer_position());
            let event = match self.reader.read_event() {
                Ok(event) => event,
                Err(e) => {
                    let at = to_usize(self.reader.error_position());
                    return Err(self.xml_error(e.to_string(), at));
                }
            };
            match event {
                Event::Start(e) => return Ok(Item::Start(self.elem(&e, pos, false)?)),
                Event::Empty(e) => return Ok(Item::Start(self.elem(&e, pos, true)?)),
                Event::End(_) => return Ok(Item::End),
                Event::Eof => return Ok(Item::Eof),
                Event::Decl(d) => {
                    if let Some(problem) = malformed_declaration(&d) {
                        return Err(self.xml_error(problem, pos));
                    }
                }
                // Text, CDATA, references, comments, PIs, DOCTYPE: not part of the model
                // description's content.
                _ => {}
            }
        }
    }

    fn elem(
        &mut self,
        e: &BytesStart<'_>,
        pos: usize,
        empty: bool,
    ) -> Result<Elem<'a>, ParseError> {
        let line = self.line_at(pos);
        let raw_name = e.name();
        let too_large = |what: String, size: usize, limit: usize| ParseError::TooLarge {
            what,
            size,
            limit,
            line,
        };
        if raw_name.as_ref().len() > MAX_NAME_BYTES {
            return Err(too_large(
                "an element name".into(),
                raw_name.as_ref().len(),
                MAX_NAME_BYTES,
            ));
        }
        // The tag as the document's own text (the reader lends it from there), so that the
        // name, the attribute names and the values that need no normalizing are borrowed.
        let Some(tag) = within(self.src, e.as_ref()) else {
            let name = raw_name.as_ref().to_owned();
            return Err(self.xml_error(format!("bad tag span in <{name}>"), pos));
        };
        let name = &tag[..raw_name.as_ref().len()];
        if let Some(problem) = malformed_tag(tag) {
            return Err(self.xml_error(format!("in <{name}>: {problem}"), pos));
        }
        let mut attrs = Vec::new();
        for attr in Attributes::new(tag, name.len()) {
            let attr = match attr {
                Ok(a) => a,
                Err(err) => return Err(self.xml_error(format!("in <{name}>: {err}"), pos)),
            };
            if attrs.len() == MAX_ATTRIBUTES {
                return Err(ParseError::TooLarge {
                    what: format!("the attribute list of <{name}> (count)"),
                    size: e.attributes().count(),
                    limit: MAX_ATTRIBUTES,
                    line,
                });
            }
            let key = attr.key.into_inner();
            if key.len() > MAX_NAME_BYTES {
                return Err(too_large(
                    format!("an attribute name in <{name}>"),
                    key.len(),
                    MAX_NAME_BYTES,
                ));
            }
            if attr.value.len() > MAX_ATTRIBUTE_BYTES {
                return Err(too_large(
                    format!("the value of attribute {key} of <{name}>"),
                    attr.value.len(),
                    MAX_ATTRIBUTE_BYTES,
                ));
            }
            let value = match attr.normalized_value(XmlVersion::Implicit1_0) {
                Ok(v) => v,
                Err(err) => return Err(self.xml_error(format!("in <{name}>: {err}"), pos)),
            };
            attrs.push((key, value));
        }
        Ok(Elem {
            name,
            attrs,
            line,
            empty,
        })
    }

    /// Calls `f` for each child element of `parent`, then consumes `parent`'s end tag.
    /// `f` must consume the child completely.
    fn children(
        &mut self,
        parent: &Elem<'a>,
        mut f: impl FnMut(&mut Self, Elem<'a>) -> Result<(), ParseError>,
    ) -> Result<(), ParseError> {
        if parent.empty {
            return Ok(());
        }
        loop {
            match self.next()? {
                Item::Start(child) => f(self, child)?,
                Item::End => return Ok(()),
                Item::Eof => {
                    let pos = self.src.len();
                    return Err(self.xml_error(
                        format!(
                            "unexpected end of document inside <{}> (line {})",
                            parent.name, parent.line
                        ),
                        pos,
                    ));
                }
            }
        }
    }

    /// Consumes an element that must have no child elements.
    fn leaf(&mut self, e: &Elem<'a>) -> Result<(), ParseError> {
        self.children(e, |_, child| Err(unexpected(&child, e.name)))
    }

    /// Consumes an element and returns its inner XML verbatim.
    fn raw_content(&mut self, e: &Elem<'a>) -> Result<String, ParseError> {
        if e.empty {
            return Ok(String::new());
        }
        let span = match self.reader.read_to_end(QName(e.name)) {
            Ok(span) => span,
            Err(err) => {
                let at = to_usize(self.reader.error_position());
                return Err(self.xml_error(format!("inside <{}>: {err}", e.name), at));
            }
        };
        let (start, end) = (to_usize(span.start), to_usize(span.end));
        if end.saturating_sub(start) > MAX_ANNOTATION_BYTES {
            return Err(ParseError::TooLarge {
                what: format!("the content of <{}>", e.name),
                size: end - start,
                limit: MAX_ANNOTATION_BYTES,
                line: e.line,
            });
        }
        match self.src.get(start..end) {
            Some(s) => Ok(s.to_owned()),
            None => Err(self.xml_error(format!("bad content span in <{}>", e.name), start)),
        }
    }

    fn document(mut self) -> Result<ModelDescription, ParseError> {
        let root = match self.next()? {
            Item::Start(e) => e,
            Item::End => {
                let pos = to_usize(self.reader.buffer_position());
                return Err(self.xml_error("end tag without start tag".into(), pos));
            }
            Item::Eof => {
                let pos = self.src.len();
                return Err(self.xml_error("the document has no root element".into(), pos));
            }
        };
        if root.name != "fmiModelDescription" {
            return Err(ParseError::WrongRoot {
                element: root.name.to_owned(),
                line: root.line,
            });
        }
        let md = self.model_description(root)?;
        match self.next()? {
            Item::Eof => Ok(md),
            Item::Start(e) => Err(self.xml_error(
                format!("element <{}> after the root element", e.name),
                to_usize(self.reader.buffer_position()),
            )),
            Item::End => {
                let pos = to_usize(self.reader.buffer_position());
                Err(self.xml_error("end tag after the root element".into(), pos))
            }
        }
    }

    fn model_description(&mut self, root: Elem<'a>) -> Result<ModelDescription, ParseError> {
        let a = Attrs::new(&root);
        let fmi_version = a.req("fmiVersion")?.to_owned();
        if fmi_version.trim() != "2.0" {
            return Err(ParseError::UnsupportedVersion(fmi_version));
        }
        let mut md = ModelDescription {
            fmi_version,
            model_name: a.req("modelName")?.to_owned(),
            guid: a.req("guid")?.to_owned(),
            description: a.string("description"),
            author: a.string("author"),
            version: a.string("version"),
            copyright: a.string("copyright"),
            license: a.string("license"),
            generation_tool: a.string("generationTool"),
            generation_date_and_time: a.string("generationDateAndTime"),
            variable_naming_convention: a.enumeration(
                "variableNamingConvention",
                VariableNamingConvention::from_xml_str,
                "flat or structured",
            )?,
            number_of_event_indicators: a.u32("numberOfEventIndicators")?,
            ..ModelDescription::default()
        };
        let mut seen: Vec<&str> = Vec::new();
        self.children(&root, |p, e| {
            if seen.contains(&e.name) {
                return Err(unexpected(&e, "fmiModelDescription"));
            }
            seen.push(e.name);
            match e.name {
                "ModelExchange" => md.model_exchange = Some(p.model_exchange(e)?),
                "CoSimulation" => md.co_simulation = Some(p.co_simulation(e)?),
                "UnitDefinitions" => p.children(&e, |p, c| match c.name {
                    "Unit" => {
                        md.unit_definitions.push(p.unit(c)?);
                        Ok(())
                    }
                    _ => Err(unexpected(&c, e.name)),
                })?,
                "TypeDefinitions" => p.children(&e, |p, c| match c.name {
                    "SimpleType" => {
                        md.type_definitions.push(p.simple_type(c)?);
                        Ok(())
                    }
                    _ => Err(unexpected(&c, e.name)),
                })?,
                "LogCategories" => p.children(&e, |p, c| match c.name {
                    "Category" => {
                        let a = Attrs::new(&c);
                        md.log_categories.push(LogCategory {
                            name: a.req("name")?.to_owned(),
                            description: a.string("description"),
                        });
                        p.leaf(&c)
                    }
                    _ => Err(unexpected(&c, e.name)),
                })?,
                "DefaultExperiment" => {
                    let a = Attrs::new(&e);
                    md.default_experiment = Some(DefaultExperiment {
                        start_time: a.f64("startTime")?,
                        stop_time: a.f64("stopTime")?,
                        tolerance: a.f64("tolerance")?,
                        step_size: a.f64("stepSize")?,
                    });
                    p.leaf(&e)?;
                }
                "VendorAnnotations" => md.vendor_annotations = p.annotations(&e)?,
                "ModelVariables" => p.children(&e, |p, c| match c.name {
                    "ScalarVariable" => {
                        md.model_variables.push(p.scalar_variable(c)?);
                        Ok(())
                    }
                    _ => Err(unexpected(&c, e.name)),
                })?,
                "ModelStructure" => md.model_structure = p.model_structure(&e)?,
                _ => return Err(unexpected(&e, "fmiModelDescription")),
            }
            Ok(())
        })?;
        for required in ["ModelVariables", "ModelStructure"] {
            if !seen.contains(&required) {
                return Err(ParseError::Structure {
                    message: format!("<fmiModelDescription> has no <{required}> element"),
                    line: root.line,
                });
            }
        }
        Ok(md)
    }

    fn source_files(&mut self, e: &Elem<'a>) -> Result<Vec<String>, ParseError> {
        let mut files = Vec::new();
        let mut seen = false;
        self.children(e, |p, c| match c.name {
            "SourceFiles" if !seen => {
                seen = true;
                p.children(&c, |p, f| match f.name {
                    "File" => {
                        files.push(Attrs::new(&f).req("name")?.to_owned());
                        p.leaf(&f)
                    }
                    _ => Err(unexpected(&f, "SourceFiles")),
                })
            }
            _ => Err(unexpected(&c, e.name)),
        })?;
        Ok(files)
    }

    fn model_exchange(&mut self, e: Elem<'a>) -> Result<ModelExchange, ParseError> {
        let a = Attrs::new(&e);
        let mut me = ModelExchange {
            model_identifier: a.req("modelIdentifier")?.to_owned(),
            needs_execution_tool: a.bool("needsExecutionTool")?,
            completed_integrator_step_not_needed: a.bool("completedIntegratorStepNotNeeded")?,
            can_be_instantiated_only_once_per_process: a
                .bool("canBeInstantiatedOnlyOncePerProcess")?,
            can_not_use_memory_management_functions: a
                .bool("canNotUseMemoryManagementFunctions")?,
            can_get_and_set_fmu_state: a.bool("canGetAndSetFMUstate")?,
            can_serialize_fmu_state: a.bool("canSerializeFMUstate")?,
            provides_directional_derivative: a.bool("providesDirectionalDerivative")?,
            source_files: Vec::new(),
        };
        me.source_files = self.source_files(&e)?;
        Ok(me)
    }

    fn co_simulation(&mut self, e: Elem<'a>) -> Result<CoSimulation, ParseError> {
        let a = Attrs::new(&e);
        let mut cs = CoSimulation {
            model_identifier: a.req("modelIdentifier")?.to_owned(),
            needs_execution_tool: a.bool("needsExecutionTool")?,
            can_handle_variable_communication_step_size: a
                .bool("canHandleVariableCommunicationStepSize")?,
            can_interpolate_inputs: a.bool("canInterpolateInputs")?,
            max_output_derivative_order: a.u32("maxOutputDerivativeOrder")?,
            can_run_asynchronuously: a.bool("canRunAsynchronuously")?,
            can_be_instantiated_only_once_per_process: a
                .bool("canBeInstantiatedOnlyOncePerProcess")?,
            can_not_use_memory_management_functions: a
                .bool("canNotUseMemoryManagementFunctions")?,
            can_get_and_set_fmu_state: a.bool("canGetAndSetFMUstate")?,
            can_serialize_fmu_state: a.bool("canSerializeFMUstate")?,
            provides_directional_derivative: a.bool("providesDirectionalDerivative")?,
            source_files: Vec::new(),
        };
        cs.source_files = self.source_files(&e)?;
        Ok(cs)
    }

    fn unit(&mut self, e: Elem<'a>) -> Result<Unit, ParseError> {
        let mut unit = Unit {
            name: Attrs::new(&e).req("name")?.to_owned(),
            base_unit: None,
            display_units: Vec::new(),
        };
        self.children(&e, |p, c| {
            let a = Attrs::new(&c);
            match c.name {
                "BaseUnit" if unit.base_unit.is_none() => {
                    unit.base_unit = Some(BaseUnit {
                        kg: a.i32("kg")?,
                        m: a.i32("m")?,
                        s: a.i32("s")?,
                        a: a.i32("A")?,
                        k: a.i32("K")?,
                        mol: a.i32("mol")?,
                        cd: a.i32("cd")?,
                        rad: a.i32("rad")?,
                        factor: a.f64("factor")?,
                        offset: a.f64("offset")?,
                    });
                }
                "DisplayUnit" => unit.display_units.push(DisplayUnit {
                    name: a.req("name")?.to_owned(),
                    factor: a.f64("factor")?,
                    offset: a.f64("offset")?,
                }),
                _ => return Err(unexpected(&c, "Unit")),
            }
            p.leaf(&c)
        })?;
        Ok(unit)
    }

    fn simple_type(&mut self, e: Elem<'a>) -> Result<SimpleType, ParseError> {
        let a = Attrs::new(&e);
        let name = a.req("name")?.to_owned();
        let description = a.string("description");
        let mut kind: Option<SimpleTypeKind> = None;
        self.children(&e, |p, c| {
            let a = Attrs::new(&c);
            let k = match c.name {
                "Real" => SimpleTypeKind::Real(a.real_attributes()?),
                "Integer" => SimpleTypeKind::Integer(a.integer_attributes()?),
                "Boolean" => SimpleTypeKind::Boolean,
                "String" => SimpleTypeKind::String,
                "Enumeration" => {
                    let quantity = a.string("quantity");
                    let mut items = Vec::new();
                    p.children(&c, |p, i| match i.name {
                        "Item" => {
                            let a = Attrs::new(&i);
                            items.push(EnumerationItem {
                                name: a.req("name")?.to_owned(),
                                value: a.req_i32("value")?,
                                description: a.string("description"),
                            });
                            p.leaf(&i)
                        }
                        _ => Err(unexpected(&i, "Enumeration")),
                    })?;
                    SimpleTypeKind::Enumeration { quantity, items }
                }
                _ => return Err(unexpected(&c, "SimpleType")),
            };
            if !matches!(k, SimpleTypeKind::Enumeration { .. }) {
                p.leaf(&c)?;
            }
            if kind.is_some() {
                return Err(ParseError::Structure {
                    message: format!("<SimpleType name=\"{name}\"> has more than one type element"),
                    line: c.line,
                });
            }
            kind = Some(k);
            Ok(())
        })?;
        match kind {
            Some(kind) => Ok(SimpleType {
                name,
                description,
                kind,
            }),
            None => Err(ParseError::Structure {
                message: format!("<SimpleType name=\"{name}\"> has no type element"),
                line: e.line,
            }),
        }
    }

    fn annotations(&mut self, e: &Elem<'a>) -> Result<Vec<ToolAnnotation>, ParseError> {
        let mut tools = Vec::new();
        self.children(e, |p, c| match c.name {
            "Tool" => {
                let name = Attrs::new(&c).req("name")?.to_owned();
                let content = p.raw_content(&c)?;
                tools.push(ToolAnnotation { name, content });
                Ok(())
            }
            _ => Err(unexpected(&c, e.name)),
        })?;
        Ok(tools)
    }

    fn scalar_variable(&mut self, e: Elem<'a>) -> Result<ScalarVariable, ParseError> {
        let a = Attrs::new(&e);
        let name = a.req("name")?.to_owned();
        let value_reference = a.req_u32("valueReference")?;
        let description = a.string("description");
        let causality = a.enumeration(
            "causality",
            Causality::from_xml_str,
            "parameter, calculatedParameter, input, output, local or independent",
        )?;
        let variability = a.enumeration(
            "variability",
            Variability::from_xml_str,
            "constant, fixed, tunable, discrete or continuous",
        )?;
        let initial = a.enumeration(
            "initial",
            Initial::from_xml_str,
            "exact, approx or calculated",
        )?;
        let can_handle_multiple_set_per_time_instant =
            a.bool("canHandleMultipleSetPerTimeInstant")?;
        let mut kind: Option<VariableKind> = None;
        let mut annotations: Option<Vec<ToolAnnotation>> = None;
        self.children(&e, |p, c| {
            if c.name == "Annotations" {
                if annotations.is_some() || kind.is_none() {
                    return Err(unexpected(&c, "ScalarVariable"));
                }
                annotations = Some(p.annotations(&c)?);
                return Ok(());
            }
            let a = Attrs::new(&c);
            let k = match c.name {
                "Real" => VariableKind::Real {
                    declared_type: a.string("declaredType"),
                    attributes: a.real_attributes()?,
                    start: a.f64("start")?,
                    derivative: a.u32("derivative")?,
                    reinit: a.bool("reinit")?,
                },
                "Integer" => VariableKind::Integer {
                    declared_type: a.string("declaredType"),
                    attributes: a.integer_attributes()?,
                    start: a.i32("start")?,
                },
                "Boolean" => VariableKind::Boolean {
                    declared_type: a.string("declaredType"),
                    start: a.bool("start")?,
                },
                "String" => VariableKind::String {
                    declared_type: a.string("declaredType"),
                    start: a.string("start"),
                },
                "Enumeration" => VariableKind::Enumeration {
                    declared_type: a.req("declaredType")?.to_owned(),
                    quantity: a.string("quantity"),
                    min: a.i32("min")?,
                    max: a.i32("max")?,
                    start: a.i32("start")?,
                },
                _ => return Err(unexpected(&c, "ScalarVariable")),
            };
            if kind.is_some() {
                return Err(ParseError::Structure {
                    message: format!(
                        "<ScalarVariable name=\"{name}\"> has more than one type element"
                    ),
                    line: c.line,
                });
            }
            kind = Some(k);
            p.leaf(&c)
        })?;
        let Some(kind) = kind else {
            return Err(ParseError::Structure {
                message: format!(
                    "<ScalarVariable name=\"{name}\"> has no type element \
                     (Real, Integer, Boolean, String or Enumeration)"
                ),
                line: e.line,
            });
        };
        Ok(ScalarVariable {
            name,
            value_reference,
            description,
            causality,
            variability,
            initial,
            can_handle_multiple_set_per_time_instant,
            kind,
            annotations: annotations.unwrap_or_default(),
        })
    }

    fn model_structure(&mut self, e: &Elem<'a>) -> Result<ModelStructure, ParseError> {
        let mut ms = ModelStructure::default();
        let mut seen: Vec<&str> = Vec::new();
        self.children(e, |p, c| {
            if seen.contains(&c.name) {
                return Err(unexpected(&c, "ModelStructure"));
            }
            seen.push(c.name);
            let list = match c.name {
                "Outputs" => &mut ms.outputs,
                "Derivatives" => &mut ms.derivatives,
                "InitialUnknowns" => &mut ms.initial_unknowns,
                _ => return Err(unexpected(&c, "ModelStructure")),
            };
            p.children(&c, |p, u| match u.name {
                "Unknown" => {
                    list.push(unknown(&u)?);
                    p.leaf(&u)
                }
                _ => Err(unexpected(&u, c.name)),
            })
        })?;
        Ok(ms)
    }
}

fn unknown(e: &Elem<'_>) -> Result<Unknown, ParseError> {
    let a = Attrs::new(e);
    let index = a.req_u32("index")?;
    let dependencies = match a.get("dependencies") {
        None => None,
        Some(v) => Some(
            v.split_ascii_whitespace()
                .map(|d| {
                    d.parse::<u32>()
                        .map_err(|_| a.invalid("dependencies", v, "a list of unsigned integers"))
                })
                .collect::<Result<Vec<u32>, ParseError>>()?,
        ),
    };
    let dependencies_kind = match a.get("dependenciesKind") {
        None => None,
        Some(v) => Some(
            v.split_ascii_whitespace()
                .map(|d| {
                    DependencyKind::from_xml_str(d).ok_or_else(|| {
                        a.invalid(
                            "dependenciesKind",
                            v,
                            "a list of dependent, constant, fixed, tunable, discrete",
                        )
                    })
                })
                .collect::<Result<Vec<DependencyKind>, ParseError>>()?,
        ),
    };
    Ok(Unknown {
        index,
        dependencies,
        dependencies_kind,
    })
}

fn unexpected(e: &Elem<'_>, parent: &str) -> ParseError {
    ParseError::UnexpectedElement {
        element: e.name.to_owned(),
        parent: parent.to_owned(),
        line: e.line,
    }
}

/// Whether `name` is an XML name (of an element or attribute; namespace prefixes included).
/// Non-ASCII characters are taken as name characters.
///
/// Checked byte by byte: every byte of a non-ASCII character is a non-ASCII byte, so a byte
/// taken as a name byte when it is not ASCII takes the character as a name character.
fn is_xml_name(name: &str) -> bool {
    let start = |b: u8| !b.is_ascii() || b.is_ascii_alphabetic() || b == b'_' || b == b':';
    match name.as_bytes() {
        [] => false,
        [first, rest @ ..] => {
            start(*first)
                && rest
                    .iter()
                    .all(|&b| start(b) || b.is_ascii_digit() || b == b'-' || b == b'.')
        }
    }
}

/// Why the text of a start tag (between `<` and `>`, without an empty element's closing `/`)
/// is not well-formed XML, in the ways the XML reader (quick-xml) lets through: an element or
/// attribute name that is not an XML name (`<a <b="1">` read as an attribute `<b`, and so
/// the attribute looked for as missing), a `<` in an attribute value (`fmiVersion="2.0<"`
/// read as an unsupported version), or attributes without white space between them. `None`
/// when it has none of these; what the reader itself refuses (an unquoted value, a missing
/// `=`, a value not closed) is left to it.
pub fn malformed_tag(tag: &str) -> Option<String> {
    let b = tag.as_bytes();
    let blank = |i: usize| b.get(i).is_some_and(u8::is_ascii_whitespace);
    let mut i = b
        .iter()
        .position(u8::is_ascii_whitespace)
        .unwrap_or(b.len());
    // Every index below stops at an ASCII byte: slicing there is on a character boundary.
    let name = &tag[..i];
    if !is_xml_name(name) {
        return Some(format!("'{name}' is not an element name"));
    }
    loop {
        while blank(i) {
            i += 1;
        }
        if i == b.len() {
            return None;
        }
        let start = i;
        while i < b.len() && b[i] != b'=' && !blank(i) {
            i += 1;
        }
        let key = &tag[start..i];
        if !is_xml_name(key) {
            return Some(format!("'{key}' is not an attribute name"));
        }
        while blank(i) {
            i += 1;
        }
        if b.get(i) != Some(&b'=') {
            return None;
        }
        i += 1;
        while blank(i) {
            i += 1;
        }
        let quote = match b.get(i) {
            Some(q @ (b'"' | b'\'')) => *q,
            _ => return None,
        };
        i += 1;
        let value_start = i;
        while i < b.len() && b[i] != quote {
            i += 1;
        }
        if i == b.len() {
            return None;
        }
        if tag[value_start..i].contains('<') {
            return Some(format!("the value of {key} holds a '<'"));
        }
        i += 1;
        if i < b.len() && !blank(i) {
            return Some(format!("no white space after the value of {key}"));
        }
    }
}

/// Why the text of an XML declaration (between `<?` and `?>`, `xml version="1.0" ...`) is
/// not a well-formed one, which the XML reader (quick-xml) does not check: its version first
/// (`1.` and digits), then at most an encoding and `standalone` (`yes` or `no`), in that
/// order, each once (`<?xml versio="1.0"?>` was read as a document without a version).
/// `None` when it is well-formed.
pub fn malformed_declaration(text: &str) -> Option<String> {
    let text = text.strip_suffix('?').unwrap_or(text);
    if let Some(problem) = malformed_tag(text) {
        return Some(format!("in the XML declaration: {problem}"));
    }
    let declaration = quick_xml::events::BytesStart::from_content(text, 3);
    let mut allowed = ["version", "encoding", "standalone"].into_iter();
    let mut any = false;
    for a in declaration.attributes() {
        let a = match a {
            Ok(a) => a,
            Err(e) => return Some(format!("in the XML declaration: {e}")),
        };
        let key = a.key.as_ref().to_string();
        let value = a.value.to_string();
        if !any && key != "version" {
            return Some(format!(
                "the XML declaration starts with '{key}', not its version"
            ));
        }
        any = true;
        if !allowed.any(|k| k == key) {
            return Some(format!(
                "'{key}' is not an attribute of the XML declaration here (version, encoding, \
                 standalone, in that order, each once)"
            ));
        }
        let ok = match key.as_str() {
            "version" => value
                .strip_prefix("1.")
                .is_some_and(|d| !d.is_empty() && d.bytes().all(|b| b.is_ascii_digit())),
            "standalone" => value == "yes" || value == "no",
            _ => !value.is_empty(),
        };
        if !ok {
            return Some(format!(
                "the XML declaration's {key} '{value}' is not a valid one"
            ));
        }
    }
    (!any).then(|| "the XML declaration has no version".to_string())
}

/// `part` as the slice of `src` it is (the same bytes, borrowed for `src`'s lifetime), or
/// `None` when it does not lie within `src`.
fn within<'a>(src: &'a str, part: &str) -> Option<&'a str> {
    let start = (part.as_ptr() as usize).checked_sub(src.as_ptr() as usize)?;
    src.get(start..start.checked_add(part.len())?)
}

fn to_usize(pos: u64) -> usize {
    usize::try_from(pos).unwrap_or(usize::MAX)
}

/// Typed access to an element's attributes.
struct Attrs<'e, 'a> {
    e: &'e Elem<'a>,
}

impl<'e, 'a> Attrs<'e, 'a> {
    fn new(e: &'e Elem<'a>) -> Self {
        Attrs { e }
    }

    fn get(&self, key: &str) -> Option<&'e str> {
        self.e
            .attrs
            .iter()
            .find(|(k, _)| *k == key)
            .map(|(_, v)| v.as_ref())
    }

    fn req(&self, key: &str) -> Result<&'e str, ParseError> {
        self.get(key).ok_or_else(|| ParseError::MissingAttribute {
            element: self.e.name.to_owned(),
            attribute: key.to_owned(),
            line: self.e.line,
        })
    }

    fn invalid(&self, key: &str, value: &str, expected: &str) -> ParseError {
        ParseError::InvalidValue {
            element: self.e.name.to_owned(),
            attribute: key.to_owned(),
            value: value.to_owned(),
            expected: expected.to_owned(),
            line: self.e.line,
        }
    }

    fn string(&self, key: &str) -> Option<String> {
        self.get(key).map(str::to_owned)
    }

    fn parsed<T>(
        &self,
        key: &str,
        expected: &str,
        parse: impl Fn(&str) -> Option<T>,
    ) -> Result<Option<T>, ParseError> {
        match self.get(key) {
            None => Ok(None),
            Some(v) => match parse(v.trim_matches(is_xml_space)) {
                Some(x) => Ok(Some(x)),
                None => Err(self.invalid(key, v, expected)),
            },
        }
    }

    fn enumeration<T>(
        &self,
        key: &str,
        parse: impl Fn(&str) -> Option<T>,
        expected: &str,
    ) -> Result<Option<T>, ParseError> {
        self.parsed(key, expected, parse)
    }

    fn bool(&self, key: &str) -> Result<Option<bool>, ParseError> {
        self.parsed(key, "a boolean (true, false, 1 or 0)", |s| match s {
            "true" | "1" => Some(true),
            "false" | "0" => Some(false),
            _ => None,
        })
    }

    fn u32(&self, key: &str) -> Result<Option<u32>, ParseError> {
        self.parsed(key, "an unsigned 32-bit integer", |s| s.parse().ok())
    }

    fn i32(&self, key: &str) -> Result<Option<i32>, ParseError> {
        self.parsed(key, "a 32-bit integer", |s| s.parse().ok())
    }

    fn f64(&self, key: &str) -> Result<Option<f64>, ParseError> {
        self.parsed(key, "a double (e.g. 1.5, -2e-3, INF, -INF, NaN)", parse_f64)
    }

    fn req_u32(&self, key: &str) -> Result<u32, ParseError> {
        self.req(key)?;
        self.u32(key)?.ok_or_else(|| self.invalid(key, "", ""))
    }

    fn req_i32(&self, key: &str) -> Result<i32, ParseError> {
        self.req(key)?;
        self.i32(key)?.ok_or_else(|| self.invalid(key, "", ""))
    }

    fn real_attributes(&self) -> Result<RealAttributes, ParseError> {
        Ok(RealAttributes {
            quantity: self.string("quantity"),
            unit: self.string("unit"),
            display_unit: self.string("displayUnit"),
            relative_quantity: self.bool("relativeQuantity")?,
            min: self.f64("min")?,
            max: self.f64("max")?,
            nominal: self.f64("nominal")?,
            unbounded: self.bool("unbounded")?,
        })
    }

    fn integer_attributes(&self) -> Result<IntegerAttributes, ParseError> {
        Ok(IntegerAttributes {
            quantity: self.string("quantity"),
            min: self.i32("min")?,
            max: self.i32("max")?,
        })
    }
}

fn is_xml_space(c: char) -> bool {
    matches!(c, ' ' | '\t' | '\n' | '\r')
}

/// Parses an `xs:double`: decimal or scientific notation, `INF`, `-INF`, `+INF`, `NaN`.
/// Spellings some exporters use instead (`inf`, `Infinity`, `nan`) are accepted too; hexadecimal
/// and other non-XSD forms are refused.
pub fn parse_f64(s: &str) -> Option<f64> {
    let body = s.strip_prefix(['+', '-']).unwrap_or(s);
    let numeric = !body.is_empty()
        && body.bytes().any(|b| b.is_ascii_digit())
        && body
            .bytes()
            .all(|b| b.is_ascii_digit() || matches!(b, b'.' | b'e' | b'E' | b'+' | b'-'));
    let special = matches!(
        body.to_ascii_lowercase().as_str(),
        "inf" | "infinity" | "nan"
    );
    if numeric || special {
        s.parse().ok()
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn xs_double_parsing() {
        for (s, v) in [
            ("1", 1.0),
            ("-2.5", -2.5),
            ("+3", 3.0),
            (".5", 0.5),
            ("1.", 1.0),
            ("1E-06", 1e-6),
            ("INF", f64::INFINITY),
            ("-INF", f64::NEG_INFINITY),
            ("inf", f64::INFINITY),
            ("Infinity", f64::INFINITY),
        ] {
            assert_eq!(parse_f64(s), Some(v), "{s}");
        }
        assert!(parse_f64("NaN").is_some_and(f64::is_nan));
        for bad in [
            "", "-", "e5", "0x1p3", "1_000", "1,5", "one", "1e", "infinit",
        ] {
            assert_eq!(parse_f64(bad), None, "{bad}");
        }
    }

    #[test]
    fn line_numbers_forward_and_backward() {
        let mut p = Parser::new("a\nb\nc\n");
        assert_eq!(p.line_at(0), 1);
        assert_eq!(p.line_at(2), 2);
        assert_eq!(p.line_at(5), 3);
        assert_eq!(p.line_at(1), 1);
        assert_eq!(p.line_at(100), 4);
    }

    #[test]
    fn error_line_accessor() {
        assert_eq!(ParseError::UnsupportedVersion("1.0".into()).line(), None);
        let e = ModelDescription::from_xml("\n\n<other/>").unwrap_err();
        assert_eq!(e.line(), Some(3));
    }
}
