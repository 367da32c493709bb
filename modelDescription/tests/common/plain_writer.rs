//! The reference for `ModelDescription::to_xml`: the writer it replaced, through quick-xml's
//! indenting writer (elements as `BytesStart` events, attributes pushed one by one). The
//! library writes the same bytes straight into one `String`; `roundtrip.rs` checks the two
//! agree on every fixture.
#![allow(dead_code)]

use std::borrow::Cow;

use quick_xml::Writer;
use quick_xml::events::attributes::Attribute;
use quick_xml::events::{BytesDecl, BytesEnd, BytesStart, BytesText, Event};
use quick_xml::name::QName;

use model_description::*;

type W = Writer<Vec<u8>>;
type IoResult = std::io::Result<()>;

/// The document quick-xml's indenting writer gives for `md`.
pub fn to_xml(md: &ModelDescription) -> String {
    {
        let mut writer = Writer::new_with_indent(Vec::new(), b' ', 2);
        // Writing into a Vec<u8> cannot fail: the io::Error branch is unreachable.
        if write_document(&mut writer, md).is_err() {
            return String::new();
        }
        let mut bytes = writer.into_inner();
        bytes.push(b'\n');
        // Every piece written comes from a `String`, so the bytes are UTF-8.
        match String::from_utf8(bytes) {
            Ok(s) => s,
            Err(e) => String::from_utf8_lossy(e.as_bytes()).into_owned(),
        }
    }
}

/// Formats an `f64` as an `xs:double` that parses back to the same value (NaN payloads aside).
pub fn format_f64(value: f64) -> String {
    if value.is_nan() {
        return "NaN".to_owned();
    }
    if value.is_infinite() {
        return if value > 0.0 { "INF" } else { "-INF" }.to_owned();
    }
    let s = format!("{value:?}");
    match s.strip_suffix(".0") {
        Some(stripped) => stripped.to_owned(),
        None => s,
    }
}

/// Escapes a string for use inside a double-quoted XML attribute value.
///
/// Besides the five predefined entities, tab, line feed and carriage return are written as
/// character references, because a reader normalizes literal ones to spaces.
pub fn escape_attribute(value: &str) -> Cow<'_, str> {
    if !value
        .bytes()
        .any(|b| matches!(b, b'&' | b'<' | b'>' | b'"' | b'\'' | b'\t' | b'\n' | b'\r'))
    {
        return Cow::Borrowed(value);
    }
    let mut out = String::with_capacity(value.len() + 16);
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
    Cow::Owned(out)
}

/// An element under construction: attributes are pushed in call order.
struct El(BytesStart<'static>);

impl El {
    fn new(name: &'static str) -> Self {
        El(BytesStart::new(name))
    }

    fn raw(mut self, key: &'static str, value: &str) -> Self {
        self.0.push_attribute(Attribute {
            key: QName(key),
            value: escape_attribute(value),
        });
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

    fn u(self, key: &'static str, value: Option<u32>) -> Self {
        match value {
            Some(v) => self.raw(key, &v.to_string()),
            None => self,
        }
    }

    fn i(self, key: &'static str, value: Option<i32>) -> Self {
        match value {
            Some(v) => self.raw(key, &v.to_string()),
            None => self,
        }
    }

    fn f(self, key: &'static str, value: Option<f64>) -> Self {
        match value {
            Some(v) => self.raw(key, &format_f64(v)),
            None => self,
        }
    }

    fn empty(self, w: &mut W) -> IoResult {
        w.write_event(Event::Empty(self.0))
    }

    fn start(self, w: &mut W) -> IoResult {
        w.write_event(Event::Start(self.0))
    }
}

fn end(w: &mut W, name: &'static str) -> IoResult {
    w.write_event(Event::End(BytesEnd::new(name)))
}

/// Writes `el` with the children written by `children`, or as an empty element when
/// `has_children` is false.
fn element(
    w: &mut W,
    el: El,
    name: &'static str,
    has_children: bool,
    children: impl FnOnce(&mut W) -> IoResult,
) -> IoResult {
    if has_children {
        el.start(w)?;
        children(w)?;
        end(w, name)
    } else {
        el.empty(w)
    }
}

fn write_document(w: &mut W, md: &ModelDescription) -> IoResult {
    w.write_event(Event::Decl(BytesDecl::new("1.0", Some("UTF-8"), None)))?;
    let root = El::new("fmiModelDescription")
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
    root.start(w)?;

    if let Some(me) = &md.model_exchange {
        let el = El::new("ModelExchange")
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
        write_with_source_files(w, el, "ModelExchange", &me.source_files)?;
    }

    if let Some(cs) = &md.co_simulation {
        let el = El::new("CoSimulation")
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
        write_with_source_files(w, el, "CoSimulation", &cs.source_files)?;
    }

    if !md.unit_definitions.is_empty() {
        El::new("UnitDefinitions").start(w)?;
        for unit in &md.unit_definitions {
            write_unit(w, unit)?;
        }
        end(w, "UnitDefinitions")?;
    }

    if !md.type_definitions.is_empty() {
        El::new("TypeDefinitions").start(w)?;
        for simple_type in &md.type_definitions {
            write_simple_type(w, simple_type)?;
        }
        end(w, "TypeDefinitions")?;
    }

    if !md.log_categories.is_empty() {
        El::new("LogCategories").start(w)?;
        for category in &md.log_categories {
            El::new("Category")
                .raw("name", &category.name)
                .s("description", category.description.as_deref())
                .empty(w)?;
        }
        end(w, "LogCategories")?;
    }

    if let Some(de) = &md.default_experiment {
        El::new("DefaultExperiment")
            .f("startTime", de.start_time)
            .f("stopTime", de.stop_time)
            .f("tolerance", de.tolerance)
            .f("stepSize", de.step_size)
            .empty(w)?;
    }

    write_annotations(w, "VendorAnnotations", &md.vendor_annotations)?;

    element(
        w,
        El::new("ModelVariables"),
        "ModelVariables",
        !md.model_variables.is_empty(),
        |w| {
            for variable in &md.model_variables {
                write_variable(w, variable)?;
            }
            Ok(())
        },
    )?;

    let ms = &md.model_structure;
    let has_structure =
        !(ms.outputs.is_empty() && ms.derivatives.is_empty() && ms.initial_unknowns.is_empty());
    element(
        w,
        El::new("ModelStructure"),
        "ModelStructure",
        has_structure,
        |w| {
            write_unknowns(w, "Outputs", &ms.outputs)?;
            write_unknowns(w, "Derivatives", &ms.derivatives)?;
            write_unknowns(w, "InitialUnknowns", &ms.initial_unknowns)
        },
    )?;

    end(w, "fmiModelDescription")
}

fn write_with_source_files(w: &mut W, el: El, name: &'static str, files: &[String]) -> IoResult {
    element(w, el, name, !files.is_empty(), |w| {
        El::new("SourceFiles").start(w)?;
        for file in files {
            El::new("File").raw("name", file).empty(w)?;
        }
        end(w, "SourceFiles")
    })
}

fn write_unit(w: &mut W, unit: &Unit) -> IoResult {
    let el = El::new("Unit").raw("name", &unit.name);
    let has_children = unit.base_unit.is_some() || !unit.display_units.is_empty();
    element(w, el, "Unit", has_children, |w| {
        if let Some(bu) = &unit.base_unit {
            El::new("BaseUnit")
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
                .empty(w)?;
        }
        for du in &unit.display_units {
            El::new("DisplayUnit")
                .raw("name", &du.name)
                .f("factor", du.factor)
                .f("offset", du.offset)
                .empty(w)?;
        }
        Ok(())
    })
}

fn real_attributes(el: El, a: &RealAttributes) -> El {
    el.s("quantity", a.quantity.as_deref())
        .s("unit", a.unit.as_deref())
        .s("displayUnit", a.display_unit.as_deref())
        .b("relativeQuantity", a.relative_quantity)
        .f("min", a.min)
        .f("max", a.max)
        .f("nominal", a.nominal)
        .b("unbounded", a.unbounded)
}

fn integer_attributes(el: El, a: &IntegerAttributes) -> El {
    el.s("quantity", a.quantity.as_deref())
        .i("min", a.min)
        .i("max", a.max)
}

fn write_simple_type(w: &mut W, t: &SimpleType) -> IoResult {
    El::new("SimpleType")
        .raw("name", &t.name)
        .s("description", t.description.as_deref())
        .start(w)?;
    match &t.kind {
        SimpleTypeKind::Real(a) => real_attributes(El::new("Real"), a).empty(w)?,
        SimpleTypeKind::Integer(a) => integer_attributes(El::new("Integer"), a).empty(w)?,
        SimpleTypeKind::Boolean => El::new("Boolean").empty(w)?,
        SimpleTypeKind::String => El::new("String").empty(w)?,
        SimpleTypeKind::Enumeration { quantity, items } => {
            let el = El::new("Enumeration").s("quantity", quantity.as_deref());
            element(w, el, "Enumeration", !items.is_empty(), |w| {
                for item in items {
                    El::new("Item")
                        .raw("name", &item.name)
                        .raw("value", &item.value.to_string())
                        .s("description", item.description.as_deref())
                        .empty(w)?;
                }
                Ok(())
            })?;
        }
    }
    end(w, "SimpleType")
}

fn write_variable(w: &mut W, v: &ScalarVariable) -> IoResult {
    El::new("ScalarVariable")
        .raw("name", &v.name)
        .raw("valueReference", &v.value_reference.to_string())
        .s("description", v.description.as_deref())
        .s("causality", v.causality.map(|c| c.as_str()))
        .s("variability", v.variability.map(|c| c.as_str()))
        .s("initial", v.initial.map(|c| c.as_str()))
        .b(
            "canHandleMultipleSetPerTimeInstant",
            v.can_handle_multiple_set_per_time_instant,
        )
        .start(w)?;
    let type_element = match &v.kind {
        VariableKind::Real {
            declared_type,
            attributes,
            start,
            derivative,
            reinit,
        } => real_attributes(
            El::new("Real").s("declaredType", declared_type.as_deref()),
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
            El::new("Integer").s("declaredType", declared_type.as_deref()),
            attributes,
        )
        .i("start", *start),
        VariableKind::Boolean {
            declared_type,
            start,
        } => El::new("Boolean")
            .s("declaredType", declared_type.as_deref())
            .b("start", *start),
        VariableKind::String {
            declared_type,
            start,
        } => El::new("String")
            .s("declaredType", declared_type.as_deref())
            .s("start", start.as_deref()),
        VariableKind::Enumeration {
            declared_type,
            quantity,
            min,
            max,
            start,
        } => El::new("Enumeration")
            .raw("declaredType", declared_type)
            .s("quantity", quantity.as_deref())
            .i("min", *min)
            .i("max", *max)
            .i("start", *start),
    };
    type_element.empty(w)?;
    write_annotations(w, "Annotations", &v.annotations)?;
    end(w, "ScalarVariable")
}

fn write_annotations(w: &mut W, container: &'static str, tools: &[ToolAnnotation]) -> IoResult {
    if tools.is_empty() {
        return Ok(());
    }
    El::new(container).start(w)?;
    for tool in tools {
        let el = El::new("Tool").raw("name", &tool.name);
        if tool.content.is_empty() {
            el.empty(w)?;
        } else {
            el.start(w)?;
            // Raw inner XML, verbatim: a Text event suppresses the indentation of `</Tool>`.
            w.write_event(Event::Text(BytesText::from_escaped(tool.content.as_str())))?;
            end(w, "Tool")?;
        }
    }
    end(w, container)
}

fn write_unknowns(w: &mut W, name: &'static str, unknowns: &[Unknown]) -> IoResult {
    if unknowns.is_empty() {
        return Ok(());
    }
    El::new(name).start(w)?;
    for unknown in unknowns {
        let mut el = El::new("Unknown").raw("index", &unknown.index.to_string());
        if let Some(deps) = &unknown.dependencies {
            let list: Vec<String> = deps.iter().map(u32::to_string).collect();
            el = el.raw("dependencies", &list.join(" "));
        }
        if let Some(kinds) = &unknown.dependencies_kind {
            let list: Vec<&str> = kinds.iter().map(|k| k.as_str()).collect();
            el = el.raw("dependenciesKind", &list.join(" "));
        }
        el.empty(w)?;
    }
    end(w, name)
}
