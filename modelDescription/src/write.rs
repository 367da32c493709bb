//! Writing a [`ModelDescription`] as `modelDescription.xml`.
//!
//! The output is deterministic: the same value always gives the same bytes.
//!
//! - `<?xml version="1.0" encoding="UTF-8"?>`, then one element per line, indented by two spaces,
//!   and a final newline.
//! - Elements and attributes in the order of the FMI 2.0 schema; absent optional attributes are
//!   not written, present ones are written even when they equal the schema default.
//! - Empty optional containers (`UnitDefinitions`, `TypeDefinitions`, `LogCategories`,
//!   `VendorAnnotations`, `SourceFiles`, `Annotations`, and the lists of `ModelStructure`) are
//!   omitted; `ModelVariables` and `ModelStructure` are always written.
//! - Floats use the shortest representation that parses back to the same `f64` (Rust's
//!   round-trip formatting, with a trailing `.0` dropped: `2.5`, `1`, `1e-5`, `1e300`), and
//!   `INF`, `-INF`, `NaN` for non-finite values (the NaN payload is not kept).
//! - Attribute values escape `& < > " '` and also tab, line feed and carriage return (as
//!   character references), so that attribute-value normalization on reading gives back exactly
//!   the written string.
//! - Tool annotations (`VendorAnnotations/Tool`, `ScalarVariable/Annotations/Tool`) hold raw
//!   inner XML and are written verbatim between `<Tool name="...">` and `</Tool>`. The content
//!   must be well-formed XML content; [`ModelDescription::check`] reports it when it is not.

//!
//! The document is written straight into one `String`, in the layout quick-xml's indenting
//! writer gives (which wrote it before, and which the tests keep as the reference it must
//! equal byte for byte: `tests/common/plain_writer.rs`): a line break and two spaces per
//! level before every tag, except the end tag right after a tool annotation's raw content.

use std::borrow::Cow;
use std::fmt::Write as _;

use crate::types::*;

impl ModelDescription {
    /// Writes the description as a `modelDescription.xml` document (see the [module
    /// docs](crate::write) for the exact format).
    pub fn to_xml(&self) -> String {
        let mut w = W {
            out: String::with_capacity(256 + 256 * self.model_variables.len()),
            depth: 0,
            line_break: false,
        };
        write_document(&mut w, self);
        w.out.push('\n');
        w.out
    }
}

/// Formats an `f64` as an `xs:double` that parses back to the same value (NaN payloads aside).
pub fn format_f64(value: f64) -> String {
    let mut s = String::new();
    push_f64(&mut s, value);
    s
}

/// Appends [`format_f64`] of `value` to `out`.
fn push_f64(out: &mut String, value: f64) {
    if value.is_nan() {
        out.push_str("NaN");
    } else if value.is_infinite() {
        out.push_str(if value > 0.0 { "INF" } else { "-INF" });
    } else {
        let start = out.len();
        // Writing into a String cannot fail.
        let _ = write!(out, "{value:?}");
        if out[start..].ends_with(".0") {
            out.truncate(out.len() - 2);
        }
    }
}

/// Whether `value` holds a character that [`escape_attribute`] replaces.
fn needs_escape(value: &str) -> bool {
    value
        .bytes()
        .any(|b| matches!(b, b'&' | b'<' | b'>' | b'"' | b'\'' | b'\t' | b'\n' | b'\r'))
}

/// Escapes a string for use inside a double-quoted XML attribute value.
///
/// Besides the five predefined entities, tab, line feed and carriage return are written as
/// character references, because a reader normalizes literal ones to spaces.
pub fn escape_attribute(value: &str) -> Cow<'_, str> {
    if !needs_escape(value) {
        return Cow::Borrowed(value);
    }
    let mut out = String::with_capacity(value.len() + 16);
    push_escaped_chars(&mut out, value);
    Cow::Owned(out)
}

/// Appends `value` to `out`, escaped as [`escape_attribute`] does.
fn push_escaped(out: &mut String, value: &str) {
    if needs_escape(value) {
        push_escaped_chars(out, value);
    } else {
        out.push_str(value);
    }
}

/// Appends `value` to `out` character by character, each one [`needs_escape`] names replaced
/// (the callers have already scanned `value` once).
fn push_escaped_chars(out: &mut String, value: &str) {
    for c in value.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            '\t' => out.push_str("&#9;"),
            '\n' => out.push_str("&#10;"),
            '\r' => out.push_str("&#13;"),
            c => out.push(c),
        }
    }
}

/// The document being written.
struct W {
    out: String,
    /// Open elements.
    depth: usize,
    /// Whether the next tag starts a new line (not after raw text).
    line_break: bool,
}

impl W {
    /// The line break and indentation before a tag.
    fn indent(&mut self) {
        if self.line_break {
            self.out.push('\n');
            for _ in 0..self.depth {
                self.out.push_str("  ");
            }
        }
    }
}

/// An element whose start tag is being written: attributes are appended in call order, then
/// [`El::empty`] or [`El::start`] closes the tag.
struct El<'w>(&'w mut W);

impl<'w> El<'w> {
    fn new(w: &'w mut W, name: &'static str) -> Self {
        w.indent();
        w.out.push('<');
        w.out.push_str(name);
        El(w)
    }

    /// ` key="`, the value to be appended, then [`Self::close`].
    fn key(&mut self, key: &'static str) -> &mut String {
        let out = &mut self.0.out;
        out.push(' ');
        out.push_str(key);
        out.push_str("=\"");
        out
    }

    fn raw(mut self, key: &'static str, value: &str) -> Self {
        push_escaped(self.key(key), value);
        self.0.out.push('"');
        self
    }

    fn s(self, key: &'static str, value: Option<&str>) -> Self {
        match value {
            Some(v) => self.raw(key, v),
            None => self,
        }
    }

    fn b(self, key: &'static str, value: Option<bool>) -> Self {
        self.s(key, value.map(|v| if v { "true" } else { "false" }))
    }

    /// A number, written by `Display` (never escaped: digits and a sign).
    fn num(mut self, key: &'static str, value: Option<impl std::fmt::Display>) -> Self {
        if let Some(v) = value {
            let _ = write!(self.key(key), "{v}\"");
        }
        self
    }

    fn u(self, key: &'static str, value: Option<u32>) -> Self {
        self.num(key, value)
    }

    fn i(self, key: &'static str, value: Option<i32>) -> Self {
        self.num(key, value)
    }

    fn f(mut self, key: &'static str, value: Option<f64>) -> Self {
        if let Some(v) = value {
            push_f64(self.key(key), v);
            self.0.out.push('"');
        }
        self
    }

    /// A space-separated list of `items`.
    fn list<T>(
        mut self,
        key: &'static str,
        items: &[T],
        mut item: impl FnMut(&mut String, &T),
    ) -> Self {
        let out = self.key(key);
        for (n, x) in items.iter().enumerate() {
            if n > 0 {
                out.push(' ');
            }
            item(out, x);
        }
        out.push('"');
        self
    }

    /// Closes the tag as an empty element.
    fn empty(self) {
        self.0.out.push_str("/>");
        self.0.line_break = true;
    }

    /// Closes the start tag; the element's content follows.
    fn start(self) -> &'w mut W {
        let w = self.0;
        w.out.push('>');
        w.depth += 1;
        w.line_break = true;
        w
    }
}

fn end(w: &mut W, name: &'static str) {
    w.depth = w.depth.saturating_sub(1);
    w.indent();
    w.out.push_str("</");
    w.out.push_str(name);
    w.out.push('>');
    w.line_break = true;
}

/// Writes `el` with the children written by `children`, or as an empty element when
/// `has_children` is false.
fn element(el: El<'_>, name: &'static str, has_children: bool, children: impl FnOnce(&mut W)) {
    if has_children {
        let w = el.start();
        children(w);
        end(w, name)
    } else {
        el.empty()
    }
}

fn write_document(w: &mut W, md: &ModelDescription) {
    w.out.push_str("<?xml version=\"1.0\" encoding=\"UTF-8\"?>");
    w.line_break = true;
    let root = El::new(w, "fmiModelDescription")
        .raw("fmiVersion", &md.fmi_version)
        .raw("modelName", &md.model_name)
        .raw("guid", &md.guid)
        .s("description", md.description.as_deref())
        .s("author", md.author.as_deref())
        .s("version", md.version.as_deref())
        .s("copyright", md.copyright.as_deref())
        .s("license", md.license.as_deref())
        .s("generationTool", md.generation_tool.as_deref())
        .s(
            "generationDateAndTime",
            md.generation_date_and_time.as_deref(),
        )
        .s(
            "variableNamingConvention",
            md.variable_naming_convention.map(|c| c.as_str()),
        )
        .u("numberOfEventIndicators", md.number_of_event_indicators);
    let w = root.start();

    if let Some(me) = &md.model_exchange {
        let el = El::new(w, "ModelExchange")
            .raw("modelIdentifier", &me.model_identifier)
            .b("needsExecutionTool", me.needs_execution_tool)
            .b(
                "completedIntegratorStepNotNeeded",
                me.completed_integrator_step_not_needed,
            )
            .b(
                "canBeInstantiatedOnlyOncePerProcess",
                me.can_be_instantiated_only_once_per_process,
            )
            .b(
                "canNotUseMemoryManagementFunctions",
                me.can_not_use_memory_management_functions,
            )
            .b("canGetAndSetFMUstate", me.can_get_and_set_fmu_state)
            .b("canSerializeFMUstate", me.can_serialize_fmu_state)
            .b(
                "providesDirectionalDerivative",
                me.provides_directional_derivative,
            );
        write_with_source_files(el, "ModelExchange", &me.source_files);
    }

    if let Some(cs) = &md.co_simulation {
        let el = El::new(w, "CoSimulation")
            .raw("modelIdentifier", &cs.model_identifier)
            .b("needsExecutionTool", cs.needs_execution_tool)
            .b(
                "canHandleVariableCommunicationStepSize",
                cs.can_handle_variable_communication_step_size,
            )
            .b("canInterpolateInputs", cs.can_interpolate_inputs)
            .u("maxOutputDerivativeOrder", cs.max_output_derivative_order)
            .b("canRunAsynchronuously", cs.can_run_asynchronuously)
            .b(
                "canBeInstantiatedOnlyOncePerProcess",
                cs.can_be_instantiated_only_once_per_process,
            )
            .b(
                "canNotUseMemoryManagementFunctions",
                cs.can_not_use_memory_management_functions,
            )
            .b("canGetAndSetFMUstate", cs.can_get_and_set_fmu_state)
            .b("canSerializeFMUstate", cs.can_serialize_fmu_state)
            .b(
                "providesDirectionalDerivative",
                cs.provides_directional_derivative,
            );
        write_with_source_files(el, "CoSimulation", &cs.source_files);
    }

    if !md.unit_definitions.is_empty() {
        El::new(w, "UnitDefinitions").start();
        for unit in &md.unit_definitions {
            write_unit(w, unit);
        }
        end(w, "UnitDefinitions");
    }

    if !md.type_definitions.is_empty() {
        El::new(w, "TypeDefinitions").start();
        for simple_type in &md.type_definitions {
            write_simple_type(w, simple_type);
        }
        end(w, "TypeDefinitions");
    }

    if !md.log_categories.is_empty() {
        El::new(w, "LogCategories").start();
        for category in &md.log_categories {
            El::new(w, "Category")
                .raw("name", &category.name)
                .s("description", category.description.as_deref())
                .empty();
        }
        end(w, "LogCategories");
    }

    if let Some(de) = &md.default_experiment {
        El::new(w, "DefaultExperiment")
            .f("startTime", de.start_time)
            .f("stopTime", de.stop_time)
            .f("tolerance", de.tolerance)
            .f("stepSize", de.step_size)
            .empty();
    }

    write_annotations(w, "VendorAnnotations", &md.vendor_annotations);

    element(
        El::new(w, "ModelVariables"),
        "ModelVariables",
        !md.model_variables.is_empty(),
        |w| {
            for variable in &md.model_variables {
                write_variable(w, variable);
            }
        },
    );

    let ms = &md.model_structure;
    let has_structure =
        !(ms.outputs.is_empty() && ms.derivatives.is_empty() && ms.initial_unknowns.is_empty());
    element(
        El::new(w, "ModelStructure"),
        "ModelStructure",
        has_structure,
        |w| {
            write_unknowns(w, "Outputs", &ms.outputs);
            write_unknowns(w, "Derivatives", &ms.derivatives);
            write_unknowns(w, "InitialUnknowns", &ms.initial_unknowns)
        },
    );

    end(w, "fmiModelDescription")
}

fn write_with_source_files(el: El<'_>, name: &'static str, files: &[String]) {
    element(el, name, !files.is_empty(), |w| {
        El::new(w, "SourceFiles").start();
        for file in files {
            El::new(w, "File").raw("name", file).empty();
        }
        end(w, "SourceFiles")
    })
}

fn write_unit(w: &mut W, unit: &Unit) {
    let el = El::new(w, "Unit").raw("name", &unit.name);
    let has_children = unit.base_unit.is_some() || !unit.display_units.is_empty();
    element(el, "Unit", has_children, |w| {
        if let Some(bu) = &unit.base_unit {
            El::new(w, "BaseUnit")
                .i("kg", bu.kg)
                .i("m", bu.m)
                .i("s", bu.s)
                .i("A", bu.a)
                .i("K", bu.k)
                .i("mol", bu.mol)
                .i("cd", bu.cd)
                .i("rad", bu.rad)
                .f("factor", bu.factor)
                .f("offset", bu.offset)
                .empty();
        }
        for du in &unit.display_units {
            El::new(w, "DisplayUnit")
                .raw("name", &du.name)
                .f("factor", du.factor)
                .f("offset", du.offset)
                .empty();
        }
    })
}

fn real_attributes<'w>(el: El<'w>, a: &RealAttributes) -> El<'w> {
    el.s("quantity", a.quantity.as_deref())
        .s("unit", a.unit.as_deref())
        .s("displayUnit", a.display_unit.as_deref())
        .b("relativeQuantity", a.relative_quantity)
        .f("min", a.min)
        .f("max", a.max)
        .f("nominal", a.nominal)
        .b("unbounded", a.unbounded)
}

fn integer_attributes<'w>(el: El<'w>, a: &IntegerAttributes) -> El<'w> {
    el.s("quantity", a.quantity.as_deref())
        .i("min", a.min)
        .i("max", a.max)
}

fn write_simple_type(w: &mut W, t: &SimpleType) {
    El::new(w, "SimpleType")
        .raw("name", &t.name)
        .s("description", t.description.as_deref())
        .start();
    match &t.kind {
        SimpleTypeKind::Real(a) => real_attributes(El::new(w, "Real"), a).empty(),
        SimpleTypeKind::Integer(a) => integer_attributes(El::new(w, "Integer"), a).empty(),
        SimpleTypeKind::Boolean => El::new(w, "Boolean").empty(),
        SimpleTypeKind::String => El::new(w, "String").empty(),
        SimpleTypeKind::Enumeration { quantity, items } => {
            let el = El::new(w, "Enumeration").s("quantity", quantity.as_deref());
            element(el, "Enumeration", !items.is_empty(), |w| {
                for item in items {
                    El::new(w, "Item")
                        .raw("name", &item.name)
                        .num("value", Some(item.value))
                        .s("description", item.description.as_deref())
                        .empty();
                }
            });
        }
    }
    end(w, "SimpleType")
}

fn write_variable(w: &mut W, v: &ScalarVariable) {
    El::new(w, "ScalarVariable")
        .raw("name", &v.name)
        .num("valueReference", Some(v.value_reference))
        .s("description", v.description.as_deref())
        .s("causality", v.causality.map(|c| c.as_str()))
        .s("variability", v.variability.map(|c| c.as_str()))
        .s("initial", v.initial.map(|c| c.as_str()))
        .b(
            "canHandleMultipleSetPerTimeInstant",
            v.can_handle_multiple_set_per_time_instant,
        )
        .start();
    let type_element = match &v.kind {
        VariableKind::Real {
            declared_type,
            attributes,
            start,
            derivative,
            reinit,
        } => real_attributes(
            El::new(w, "Real").s("declaredType", declared_type.as_deref()),
            attributes,
        )
        .f("start", *start)
        .u("derivative", *derivative)
        .b("reinit", *reinit),
        VariableKind::Integer {
            declared_type,
            attributes,
            start,
        } => integer_attributes(
            El::new(w, "Integer").s("declaredType", declared_type.as_deref()),
            attributes,
        )
        .i("start", *start),
        VariableKind::Boolean {
            declared_type,
            start,
        } => El::new(w, "Boolean")
            .s("declaredType", declared_type.as_deref())
            .b("start", *start),
        VariableKind::String {
            declared_type,
            start,
        } => El::new(w, "String")
            .s("declaredType", declared_type.as_deref())
            .s("start", start.as_deref()),
        VariableKind::Enumeration {
            declared_type,
            quantity,
            min,
            max,
            start,
        } => El::new(w, "Enumeration")
            .raw("declaredType", declared_type)
            .s("quantity", quantity.as_deref())
            .i("min", *min)
            .i("max", *max)
            .i("start", *start),
    };
    type_element.empty();
    write_annotations(w, "Annotations", &v.annotations);
    end(w, "ScalarVariable")
}

fn write_annotations(w: &mut W, container: &'static str, tools: &[ToolAnnotation]) {
    if tools.is_empty() {
        return;
    }
    El::new(w, container).start();
    for tool in tools {
        let el = El::new(w, "Tool").raw("name", &tool.name);
        if tool.content.is_empty() {
            el.empty();
        } else {
            let w = el.start();
            // Raw inner XML, verbatim: no indentation before `</Tool>` after it.
            w.out.push_str(&tool.content);
            w.line_break = false;
            end(w, "Tool");
        }
    }
    end(w, container)
}

fn write_unknowns(w: &mut W, name: &'static str, unknowns: &[Unknown]) {
    if unknowns.is_empty() {
        return;
    }
    El::new(w, name).start();
    for unknown in unknowns {
        let mut el = El::new(w, "Unknown").num("index", Some(unknown.index));
        if let Some(deps) = &unknown.dependencies {
            el = el.list("dependencies", deps, |out, d| {
                let _ = write!(out, "{d}");
            });
        }
        if let Some(kinds) = &unknown.dependencies_kind {
            el = el.list("dependenciesKind", kinds, |out, k| out.push_str(k.as_str()));
        }
        el.empty();
    }
    end(w, name)
}

macro_rules! xml_names {
    ($ty:ident { $($variant:ident => $name:literal),* $(,)? }) => {
        impl $ty {
            /// Every value, in schema order.
            pub const ALL: &'static [$ty] = &[$($ty::$variant),*];

            /// The attribute value as written in XML.
            pub fn as_str(self) -> &'static str {
                match self {
                    $($ty::$variant => $name),*
                }
            }

            /// Parses the attribute value as written in XML (exact spelling, no whitespace).
            pub fn from_xml_str(s: &str) -> Option<Self> {
                match s {
                    $($name => Some($ty::$variant),)*
                    _ => None,
                }
            }
        }

        impl std::fmt::Display for $ty {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str(self.as_str())
            }
        }
    };
}

xml_names!(VariableNamingConvention {
    Flat => "flat",
    Structured => "structured",
});
xml_names!(Causality {
    Parameter => "parameter",
    CalculatedParameter => "calculatedParameter",
    Input => "input",
    Output => "output",
    Local => "local",
    Independent => "independent",
});
xml_names!(Variability {
    Constant => "constant",
    Fixed => "fixed",
    Tunable => "tunable",
    Discrete => "discrete",
    Continuous => "continuous",
});
xml_names!(Initial {
    Exact => "exact",
    Approx => "approx",
    Calculated => "calculated",
});
xml_names!(DependencyKind {
    Dependent => "dependent",
    Constant => "constant",
    Fixed => "fixed",
    Tunable => "tunable",
    Discrete => "discrete",
});

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn attribute_escaping() {
        assert!(matches!(escape_attribute("plain"), Cow::Borrowed("plain")));
        assert_eq!(
            escape_attribute("a&b<c>d\"e'f\tg\nh\ri"),
            "a&amp;b&lt;c&gt;d&quot;e&apos;f&#9;g&#10;h&#13;i"
        );
    }

    #[test]
    fn enum_names_round_trip() {
        for c in Causality::ALL {
            assert_eq!(Causality::from_xml_str(c.as_str()), Some(*c));
        }
        for v in Variability::ALL {
            assert_eq!(Variability::from_xml_str(v.as_str()), Some(*v));
        }
        for i in Initial::ALL {
            assert_eq!(Initial::from_xml_str(i.as_str()), Some(*i));
        }
        for k in DependencyKind::ALL {
            assert_eq!(DependencyKind::from_xml_str(k.as_str()), Some(*k));
        }
        assert_eq!(Causality::from_xml_str("Output"), None);
    }

    #[test]
    fn float_format_round_trips() {
        for v in [0.1, 1e-5, 1e-7, 1e16, 1e17, 123.456, -0.0, 5e-324, f64::MAX] {
            let s = format_f64(v);
            assert_eq!(
                crate::read::parse_f64(&s).map(f64::to_bits),
                Some(v.to_bits()),
                "{s}"
            );
        }
    }
}
