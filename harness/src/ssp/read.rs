//! Reading SSP 1.0: `SystemStructure.ssd` and inline or `.ssv` parameter sets, every error
//! naming its file and line (see the module above).

use quick_xml::events::{BytesStart, Event};

use super::{
    ConnectorKind, ConnectorType, Ssd, SspComponent, SspConnection, SspConnector, SspError,
    SspParameter,
};
use crate::master::{Algorithm, Value};

/// The 1-based line of byte `position` of `xml` (of its end, past it): counted only for an
/// error message, so from the start each time.
fn line_of(xml: &str, position: u64) -> usize {
    let end = usize::try_from(position)
        .unwrap_or(usize::MAX)
        .min(xml.len());
    1 + xml.as_bytes()[..end]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
}

/// Where an event the reader reads from byte `position` of `xml` starts: after the blanks it
/// skips (ASCII, so counted in bytes: `position` need not be a character boundary).
fn skip_blanks(xml: &str, position: u64) -> u64 {
    let skipped = usize::try_from(position)
        .ok()
        .and_then(|p| xml.as_bytes().get(p..))
        .map_or(0, |rest| {
            rest.iter().take_while(|b| b.is_ascii_whitespace()).count()
        });
    position + skipped as u64
}

/// A malformed-XML error of `file` at byte `position` of `xml`.
fn xml_error(xml: &str, file: &str, position: u64, message: String) -> SspError {
    SspError::Xml {
        file: file.to_string(),
        position,
        line: line_of(xml, position),
        message,
    }
}

/// The attributes of a tag by local name, borrowed from the tag (a value is copied only when
/// normalizing it changes it); a local name given twice (under two prefixes) reads as its
/// last value.
struct Attrs<'e>(Vec<(&'e str, std::borrow::Cow<'e, str>)>);

impl Attrs<'_> {
    /// The value of the attribute with local name `key`.
    fn get(&self, key: &str) -> Option<&str> {
        self.0
            .iter()
            .rev()
            .find(|(k, _)| *k == key)
            .map(|(_, v)| v.as_ref())
    }

    /// [`Self::get`], copied.
    fn owned(&self, key: &str) -> Option<String> {
        self.get(key).map(str::to_string)
    }
}

/// The attributes of the tag `e`, which starts at byte `position` of `xml`, by local name. A
/// tag that no well-formed document holds (a bad attribute name, an unquoted or duplicated
/// attribute, a `<` or a bad reference in a value) is malformed XML.
fn attrs<'e>(
    xml: &str,
    e: &'e BytesStart<'_>,
    position: u64,
    file: &str,
) -> Result<Attrs<'e>, SspError> {
    let malformed = |message: String| xml_error(xml, file, position, message);
    let element = || e.name().as_ref().to_string();
    if let Some(problem) = model_description::read::malformed_tag(e.as_ref()) {
        return Err(malformed(format!("in <{}>: {problem}", element())));
    }
    let mut m = Vec::new();
    for a in e.attributes() {
        let a = a.map_err(|err| malformed(format!("in <{}>: {err}", element())))?;
        let key = a.key.local_name().into_inner();
        let v = a
            .normalized_value(quick_xml::XmlVersion::Implicit1_0)
            .map_err(|err| malformed(format!("in <{}>: {err}", element())))?;
        m.push((key, v));
    }
    Ok(Attrs(m))
}

/// `s` as an `xs:double`; `file` labels the error.
fn parse_f64(
    file: impl FnOnce() -> String,
    what: impl std::fmt::Display,
    s: &str,
) -> Result<f64, SspError> {
    match s.trim() {
        "INF" => Ok(f64::INFINITY),
        "-INF" => Ok(f64::NEG_INFINITY),
        t => t.parse().map_err(|_| SspError::Invalid {
            file: file(),
            problem: format!("{what}: '{s}' is not a number"),
        }),
    }
}

/// Reads parameter values from an `ssv:ParameterSet` document, or a fragment of one: the bytes
/// `span` of `doc` (errors give positions and lines in `doc`).
fn read_parameter_set(
    doc: &str,
    span: std::ops::Range<usize>,
    file: &str,
) -> Result<Vec<SspParameter>, SspError> {
    let offset = span.start as u64;
    let xml = &doc[span];
    let xml_error =
        |position: u64, message: String| xml_error(doc, file, offset + position, message);
    let mut r = quick_xml::Reader::from_str(xml);
    r.config_mut().trim_text(true);
    let mut out = Vec::new();
    let mut current: Option<String> = None;
    // Open elements: one still open at the end is malformed XML (the reader does not say).
    let mut open: Vec<(Vec<u8>, u64)> = Vec::new();
    loop {
        let pos = skip_blanks(xml, r.buffer_position());
        let ev = r
            .read_event()
            .map_err(|e| xml_error(r.error_position(), e.to_string()))?;
        if let Event::Start(e) = &ev {
            open.push((e.name().as_ref().as_bytes().to_vec(), offset + pos));
        }
        match ev {
            Event::Start(e) | Event::Empty(e) => {
                let local = e.local_name();
                let a = attrs(doc, &e, offset + pos, file)?;
                // The file and the line of the element, for errors about its value (counted
                // only for an error).
                let here = || format!("{file} line {}", line_of(doc, offset + pos));
                match local.as_ref().as_bytes() {
                    b"Parameter" => current = a.owned("name"),
                    t @ (b"Real" | b"Integer" | b"Boolean" | b"String" | b"Enumeration") => {
                        let Some(name) = current.clone() else {
                            continue;
                        };
                        let v = a.owned("value").unwrap_or_default();
                        let value = match t {
                            b"Real" => {
                                Value::Real(parse_f64(here, format_args!("parameter {name}"), &v)?)
                            }
                            b"Integer" => {
                                Value::Integer(v.trim().parse().map_err(|_| SspError::Invalid {
                                    file: here(),
                                    problem: format!("parameter {name}: '{v}' is not an Integer"),
                                })?)
                            }
                            // xs:boolean, as in a parameter set (.ssv): anything else was
                            // read as false.
                            b"Boolean" => Value::Boolean(match v.trim() {
                                "true" | "1" => true,
                                "false" | "0" => false,
                                _ => {
                                    return Err(SspError::Invalid {
                                        file: here(),
                                        problem: format!(
                                            "parameter {name}: '{v}' is not a Boolean (true, \
                                             false, 1 or 0)"
                                        ),
                                    });
                                }
                            }),
                            b"String" => Value::String(v),
                            _ => {
                                return Err(SspError::Unsupported {
                                    file: here(),
                                    what: format!("Enumeration parameter value ({name})"),
                                });
                            }
                        };
                        out.push(SspParameter { name, value });
                    }
                    _ => {}
                }
            }
            Event::End(e) => {
                open.pop();
                if e.local_name().as_ref().as_bytes() == b"Parameter" {
                    current = None;
                }
            }
            Event::Eof => break,
            Event::Decl(d) => {
                if let Some(problem) = model_description::read::malformed_declaration(&d) {
                    return Err(xml_error(pos, problem));
                }
            }
            _ => {}
        }
    }
    if let Some((name, at)) = open.last() {
        return Err(unclosed(doc, file, name, *at));
    }
    Ok(out)
}

/// The error of an element `name` opened at byte `at` of `xml` and not closed by the end.
fn unclosed(xml: &str, file: &str, name: &[u8], at: u64) -> SspError {
    xml_error(
        xml,
        file,
        xml.len() as u64,
        format!(
            "the document ends inside <{}> (opened at line {})",
            String::from_utf8_lossy(name),
            line_of(xml, at)
        ),
    )
}

/// Reads an SSD document. `read_file` resolves `source` references of parameter bindings
/// (relative to the SSD's location).
pub fn read_ssd_with(
    xml: &str,
    file: &str,
    read_file: &mut dyn FnMut(&str) -> Result<String, SspError>,
) -> Result<Ssd, SspError> {
    read_ssd_labelled(xml, file, &|src| src.to_string(), read_file)
}

/// [`read_ssd_with`], errors in a referenced file naming it as `source_label` names the
/// reference (for an archive: the archive's path with the name inside it).
pub(super) fn read_ssd_labelled(
    xml: &str,
    file: &str,
    source_label: &dyn Fn(&str) -> String,
    read_file: &mut dyn FnMut(&str) -> Result<String, SspError>,
) -> Result<Ssd, SspError> {
    let xml = xml.strip_prefix('\u{feff}').unwrap_or(xml);
    // The XML parser would skip a second mark too and count its positions from after it, so
    // that inline parameter sets were cut three bytes off.
    if xml.starts_with('\u{feff}') {
        return Err(xml_error(xml, file, 0, "a second byte order mark".into()));
    }
    let mut r = quick_xml::Reader::from_str(xml);
    r.config_mut().trim_text(true);
    let mut ssd = Ssd::default();
    // The open elements' local names, and where each starts (the reader does not say when the
    // document ends inside one).
    let mut stack: Vec<Vec<u8>> = Vec::new();
    let mut opened: Vec<(Vec<u8>, u64)> = Vec::new();
    // Where the root element starts, once read.
    let mut root: Option<u64> = None;
    let mut system_depth: Option<usize> = None;
    let mut comp: Option<SspComponent> = None;
    let mut connector: Option<SspConnector> = None;
    let mut binding_prefix = String::new();
    let invalid = |here: String, p: String| SspError::Invalid {
        file: here,
        problem: p,
    };
    loop {
        let pos = r.buffer_position();
        let ev = r
            .read_event()
            .map_err(|e| xml_error(xml, file, r.error_position(), e.to_string()))?;
        let start = skip_blanks(xml, pos);
        // The file and the line of the element, for errors about it (counted only for an
        // error).
        let here = || format!("{file} line {}", line_of(xml, start));
        let (e, empty) = match ev {
            Event::Start(e) => (e, false),
            Event::Empty(e) => (e, true),
            Event::End(e) => {
                stack.pop();
                opened.pop();
                let parent = stack.last().map(Vec::as_slice).unwrap_or_default();
                match e.local_name().as_ref().as_bytes() {
                    b"Component" if parent == b"Elements" => {
                        if let Some(c) = comp.take() {
                            ssd.system.components.push(c);
                        }
                    }
                    b"Connector" => {
                        if let (Some(k), Some(c)) = (connector.take(), comp.as_mut()) {
                            c.connectors.push(k);
                        }
                    }
                    _ => {}
                }
                continue;
            }
            Event::Eof => {
                if let Some((name, at)) = opened.last() {
                    return Err(unclosed(xml, file, name, *at));
                }
                break;
            }
            Event::Decl(d) => {
                if let Some(problem) = model_description::read::malformed_declaration(&d) {
                    return Err(xml_error(xml, file, start, problem));
                }
                continue;
            }
            _ => continue,
        };
        let local = e.local_name().as_ref().as_bytes().to_vec();
        // One root element, SystemStructureDescription: the components of another element
        // before or after it would be silently added.
        if stack.is_empty() && (root.is_some() || local != b"SystemStructureDescription") {
            let name = String::from_utf8_lossy(&local);
            return Err(invalid(
                here(),
                if root.is_some() {
                    format!("an element <{name}> after the root element")
                } else {
                    format!("the root element is <{name}>, not SystemStructureDescription")
                },
            ));
        }
        let a = attrs(xml, &e, start, file)?;
        let parent = stack.last().map(Vec::as_slice).unwrap_or_default();
        let in_annotation = parent == b"Annotation";
        let in_elements = parent == b"Elements";
        let in_connector = parent == b"Connector";
        match local.as_slice() {
            // kb:Component in a component's annotation: the step multiple.
            b"Component" if in_annotation => {
                if let (Some(c), Some(m)) = (comp.as_mut(), a.get("stepMultiple")) {
                    c.step_multiple = Some(m.trim().parse().map_err(|_| {
                        invalid(
                            here(),
                            format!("stepMultiple '{m}' is not a positive integer"),
                        )
                    })?);
                }
            }
            b"SystemStructureDescription" if stack.is_empty() => {
                root = Some(start);
                ssd.name = a.owned("name").unwrap_or_default();
                ssd.version = a.owned("version").unwrap_or_default();
                if !ssd.version.starts_with("1.") {
                    return Err(invalid(
                        here(),
                        format!("version '{}' is not an SSP 1.x version", ssd.version),
                    ));
                }
            }
            b"System" => {
                if system_depth.is_some() {
                    return Err(SspError::Unsupported {
                        file: here(),
                        what: "nested systems".into(),
                    });
                }
                system_depth = Some(stack.len());
                ssd.system.name = a.owned("name").unwrap_or_default();
            }
            b"Component" if in_elements => {
                let name = a
                    .owned("name")
                    .ok_or_else(|| invalid(here(), "a Component has no name".into()))?;
                let source = a
                    .owned("source")
                    .ok_or_else(|| invalid(here(), format!("Component '{name}' has no source")))?;
                if let Some(t) = a.get("type")
                    && t != "application/x-fmu-sharedlibrary"
                {
                    return Err(SspError::Unsupported {
                        file: here(),
                        what: format!("component '{name}' of type '{t}' (only FMUs)"),
                    });
                }
                let c = SspComponent {
                    name,
                    source,
                    ..SspComponent::default()
                };
                if empty {
                    ssd.system.components.push(c);
                } else {
                    comp = Some(c);
                }
            }
            b"Connector" => {
                let name = a.owned("name").unwrap_or_default();
                let kind = a
                    .get("kind")
                    .and_then(ConnectorKind::parse)
                    .ok_or_else(|| {
                        invalid(here(), format!("connector '{name}' has no valid kind"))
                    })?;
                let k = SspConnector {
                    name,
                    kind,
                    ty: None,
                };
                if let Some(c) = comp.as_mut() {
                    if empty {
                        c.connectors.push(k);
                    } else {
                        connector = Some(k);
                    }
                }
            }
            t @ (b"Real" | b"Integer" | b"Boolean" | b"String" | b"Enumeration")
                if in_connector =>
            {
                if let Some(k) = connector.as_mut() {
                    k.ty = Some(match t {
                        b"Real" => ConnectorType::Real {
                            unit: a.owned("unit"),
                        },
                        b"Integer" => ConnectorType::Integer,
                        b"Boolean" => ConnectorType::Boolean,
                        b"String" => ConnectorType::String,
                        _ => ConnectorType::Enumeration,
                    });
                }
            }
            b"ParameterBinding" => {
                binding_prefix = a.owned("prefix").unwrap_or_default();
                if let Some(src) = a.get("source") {
                    if let Some(c) = comp.as_mut() {
                        c.parameter_sources.push(src.to_string());
                    }
                    let text = read_file(src)?;
                    let params = read_parameter_set(&text, 0..text.len(), &source_label(src))?;
                    push_params(comp.as_mut(), params, &binding_prefix, here)?;
                }
            }
            b"ParameterSet" if !empty => {
                // Inline: parse the fragment from here to its end.
                let start = pos as usize;
                let end_tag = r
                    .read_to_end(e.name())
                    .map_err(|err| xml_error(xml, file, r.error_position(), err.to_string()))?;
                let _ = end_tag;
                let end = r.buffer_position() as usize;
                // Checked, not sliced: the reader's positions need not be character
                // boundaries (a second byte order mark).
                xml.get(start..end).ok_or_else(|| {
                    invalid(
                        here(),
                        format!("a ParameterSet at byte {start} the reader cannot cut out"),
                    )
                })?;
                let params = read_parameter_set(xml, start..end, file)?;
                push_params(comp.as_mut(), params, &binding_prefix, here)?;
                continue; // the end tag was consumed
            }
            b"Connection" => {
                let c = SspConnection {
                    start_element: a.owned("startElement"),
                    start_connector: a.owned("startConnector").unwrap_or_default(),
                    end_element: a.owned("endElement"),
                    end_connector: a.owned("endConnector").unwrap_or_default(),
                };
                ssd.system.connections.push(c);
            }
            b"DefaultExperiment" => {
                let d = ssd.default_experiment.get_or_insert_with(Default::default);
                if let Some(v) = a.get("startTime") {
                    d.start_time = Some(parse_f64(here, "startTime", v)?);
                }
                if let Some(v) = a.get("stopTime") {
                    d.stop_time = Some(parse_f64(here, "stopTime", v)?);
                }
            }
            b"Master" => {
                let d = ssd.default_experiment.get_or_insert_with(Default::default);
                if let Some(v) = a.get("stepSize") {
                    d.step_size = Some(parse_f64(here, "stepSize", v)?);
                }
                d.algorithm = match a.get("algorithm") {
                    Some("jacobi") => Some(Algorithm::Jacobi),
                    Some("gauss-seidel") => Some(Algorithm::GaussSeidel),
                    None => d.algorithm,
                    // A misspelt algorithm ran the default silently.
                    Some(other) => {
                        return Err(invalid(
                            here(),
                            format!(
                                "kb:Master algorithm '{other}' is not one of jacobi, gauss-seidel"
                            ),
                        ));
                    }
                };
            }
            _ => {}
        }
        if !empty {
            opened.push((e.name().as_ref().as_bytes().to_vec(), start));
            stack.push(local);
        }
    }
    // Whole-document problems, found at the end: the line of the element concerned (the
    // root), or of the end of the document where there is no element at all.
    let Some(root) = root else {
        return Err(invalid(
            format!("{file} line {}", line_of(xml, xml.len() as u64)),
            "the document has no root element (SystemStructureDescription)".into(),
        ));
    };
    if system_depth.is_none() {
        return Err(invalid(
            format!("{file} line {}", line_of(xml, root)),
            "no System element in the SystemStructureDescription".into(),
        ));
    }
    Ok(ssd)
}

fn push_params(
    comp: Option<&mut SspComponent>,
    params: Vec<SspParameter>,
    prefix: &str,
    file: impl FnOnce() -> String,
) -> Result<(), SspError> {
    let Some(c) = comp else {
        return Err(SspError::Unsupported {
            file: file(),
            what: "parameter bindings on the system (only on components)".into(),
        });
    };
    for mut p in params {
        if !prefix.is_empty() {
            p.name = format!("{prefix}{}", p.name);
        }
        c.parameters.push(p);
    }
    Ok(())
}

/// Reads an SSD document whose parameter bindings are all inline.
pub fn read_ssd(xml: &str) -> Result<Ssd, SspError> {
    read_ssd_with(xml, "SystemStructure.ssd", &mut |src| {
        Err(SspError::Unsupported {
            file: "SystemStructure.ssd".into(),
            what: format!("parameter binding source '{src}' (no file access)"),
        })
    })
}

#[cfg(test)]
mod tests {
    use super::line_of;

    #[test]
    fn lines_are_counted_from_the_start_to_the_byte() {
        let xml = "<a>\n<b/>\n\n<c x=\"1\"/>\r\n</a>\n";
        let len = xml.len() as u64;
        // On a newline and just past it, past the end.
        let expected = [
            (0, 1),
            (3, 1),
            (4, 2),
            (5, 2),
            (9, 3),
            (10, 4),
            (11, 4),
            (2, 1),
            (20, 4),
            (len, 6),
            (len + 7, 6),
            (1, 1),
            (u64::MAX, 6),
        ];
        for (p, line) in expected {
            assert_eq!(line_of(xml, p), line, "byte {p}");
        }
    }
}
