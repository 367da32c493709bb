//! The `.ssv` file format (SSP 1.0 `SystemStructureParameterValues`): reading with line numbers
//! and writing in schema order.
//!
//! Written: `<ssv:ParameterSet version="1.0" name=".." fileversion=".." description=".."
//! generationTool="kneebench">`, then `ssv:Parameters` (one `ssv:Parameter` with one
//! `ssv:Real unit=".."`, `ssv:Integer`, `ssv:Boolean` or `ssv:String` each) and `ssv:Units`
//! holding the definition of every unit used (`ssc:Unit` with its `ssc:BaseUnit`), as the
//! schema asks of a `unit` attribute. `fileversion` (SSP's top-level metadata) is the set's
//! own version.

use std::fmt::Write as _;

use quick_xml::events::{BytesStart, Event};

use super::{ParamValue, Parameter, ParameterSet, ParamsError, UnitDefinition};
use crate::ssp::{NS_SSC, NS_SSV};
use model_description::write::escape_attribute as esc;

/// xs:double text of a finite value, exact on reading back.
pub(super) fn xs_double(v: f64) -> String {
    format!("{v:?}")
}

/// The document as SSV 1.0 XML.
pub(super) fn to_xml(set: &ParameterSet) -> String {
    let mut x = String::new();
    x.push_str("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
    let _ = write!(
        x,
        "<ssv:ParameterSet xmlns:ssv=\"{NS_SSV}\" xmlns:ssc=\"{NS_SSC}\" version=\"1.0\" name=\"{}\"",
        esc(&set.name)
    );
    if let Some(d) = &set.description {
        let _ = write!(x, " description=\"{}\"", esc(d));
    }
    let _ = writeln!(
        x,
        " fileversion=\"{}\" generationTool=\"kneebench\">",
        esc(&set.version)
    );
    x.push_str("  <ssv:Parameters>\n");
    for p in &set.parameters {
        let _ = write!(x, "    <ssv:Parameter name=\"{}\">", esc(&p.name));
        match &p.value {
            ParamValue::Real(v) => {
                let _ = write!(x, "<ssv:Real value=\"{}\"", xs_double(*v));
                if let Some(u) = &p.unit {
                    let _ = write!(x, " unit=\"{}\"", esc(u));
                }
                x.push_str("/>");
            }
            ParamValue::Integer(v) => {
                let _ = write!(x, "<ssv:Integer value=\"{v}\"/>");
            }
            ParamValue::Boolean(v) => {
                let _ = write!(x, "<ssv:Boolean value=\"{v}\"/>");
            }
            ParamValue::String(v) => {
                let _ = write!(x, "<ssv:String value=\"{}\"/>", esc(v));
            }
        }
        x.push_str("</ssv:Parameter>\n");
    }
    x.push_str("  </ssv:Parameters>\n");
    if !set.units.is_empty() {
        x.push_str("  <ssv:Units>\n");
        for u in &set.units {
            let _ = write!(x, "    <ssc:Unit name=\"{}\"><ssc:BaseUnit", esc(&u.name));
            for (exp, v) in u.exponents() {
                if v != 0 {
                    let _ = write!(x, " {exp}=\"{v}\"");
                }
            }
            if u.factor != 1.0 {
                let _ = write!(x, " factor=\"{}\"", xs_double(u.factor));
            }
            if u.offset != 0.0 {
                let _ = write!(x, " offset=\"{}\"", xs_double(u.offset));
            }
            x.push_str("/></ssc:Unit>\n");
        }
        x.push_str("  </ssv:Units>\n");
    }
    x.push_str("</ssv:ParameterSet>\n");
    x
}

/// 1-based line of byte offset `pos` in `text`.
pub(super) fn line_of(text: &str, pos: usize) -> usize {
    text.as_bytes()[..pos.min(text.len())]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

fn attributes(
    e: &BytesStart<'_>,
    file: &str,
    line: usize,
) -> Result<Vec<(String, String)>, ParamsError> {
    let mut out = Vec::new();
    if let Some(problem) = model_description::read::malformed_tag(e.as_ref()) {
        return Err(ParamsError::Syntax {
            file: file.to_string(),
            line,
            message: format!("in <{}>: {problem}", e.name().as_ref()),
        });
    }
    for a in e.attributes() {
        let a = a.map_err(|err| ParamsError::Syntax {
            file: file.to_string(),
            line,
            message: err.to_string(),
        })?;
        let v = a
            .normalized_value(quick_xml::XmlVersion::Implicit1_0)
            .map_err(|err| ParamsError::Syntax {
                file: file.to_string(),
                line,
                message: err.to_string(),
            })?
            .into_owned();
        out.push((a.key.local_name().as_ref().to_string(), v));
    }
    Ok(out)
}

fn get<'a>(a: &'a [(String, String)], key: &str) -> Option<&'a str> {
    a.iter().find(|(k, _)| k == key).map(|(_, v)| v.as_str())
}

/// Reads an `.ssv` document; `file` names it in errors.
pub(super) fn read(text: &str, file: &str) -> Result<ParameterSet, ParamsError> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    // The XML parser would skip a second mark too and count its positions from after it.
    if text.starts_with('\u{feff}') {
        return Err(ParamsError::Syntax {
            file: file.to_string(),
            line: 1,
            message: "a second byte order mark".into(),
        });
    }
    let mut r = quick_xml::Reader::from_str(text);
    r.config_mut().trim_text(true);
    let mut set: Option<ParameterSet> = None;
    let mut current: Option<(String, usize)> = None;
    let mut unit: Option<UnitDefinition> = None;
    let mut depth = 0usize;
    let bad = |line: usize, problem: String| ParamsError::Invalid {
        file: file.to_string(),
        line,
        problem,
    };
    loop {
        let pos = r.buffer_position() as usize;
        let ev = r.read_event().map_err(|e| ParamsError::Syntax {
            file: file.to_string(),
            line: line_of(text, r.buffer_position() as usize),
            message: e.to_string(),
        })?;
        // The event starts after any (XML, so ASCII) whitespace skipped before it. Counted in
        // bytes: the reader's position need not be a character boundary (after a second byte
        // order mark it is inside it; slicing the text there panicked).
        let skipped = text.as_bytes().get(pos..).map_or(0, |rest| {
            rest.iter().take_while(|b| b.is_ascii_whitespace()).count()
        });
        let start = pos + skipped;
        let line = line_of(text, start);
        let (e, empty) = match ev {
            Event::Start(e) => (e, false),
            Event::Empty(e) => (e, true),
            Event::End(e) => {
                depth = depth.saturating_sub(1);
                match e.local_name().as_ref() {
                    "Parameter" => {
                        if let Some((name, l)) = current.take() {
                            return Err(bad(l, format!("parameter '{name}' has no value")));
                        }
                    }
                    "Unit" => {
                        if let (Some(u), Some(s)) = (unit.take(), set.as_mut()) {
                            s.units.push(u);
                        }
                    }
                    _ => {}
                }
                continue;
            }
            Event::Eof => break,
            Event::Decl(d) => {
                if let Some(message) = model_description::read::malformed_declaration(&d) {
                    return Err(ParamsError::Syntax {
                        file: file.to_string(),
                        line,
                        message,
                    });
                }
                continue;
            }
            _ => continue,
        };
        let a = attributes(&e, file, line)?;
        let local = e.local_name();
        match local.as_ref() {
            // One root element: a second set after it would silently replace the first.
            _ if depth == 0 && set.is_some() => {
                return Err(bad(line, "an element after the root element".to_string()));
            }
            "ParameterSet" if depth == 0 => {
                let version = get(&a, "version").unwrap_or_default();
                if !version.starts_with("1.") {
                    return Err(bad(
                        line,
                        format!("version '{version}' is not an SSV 1.x version"),
                    ));
                }
                let name = get(&a, "name")
                    .ok_or_else(|| bad(line, "the ParameterSet has no name".into()))?;
                set = Some(ParameterSet {
                    name: name.to_string(),
                    version: get(&a, "fileversion").unwrap_or_default().to_string(),
                    description: get(&a, "description").map(str::to_string),
                    parameters: Vec::new(),
                    units: Vec::new(),
                });
            }
            _ if depth == 0 => {
                return Err(bad(
                    line,
                    "the root element is not ssv:ParameterSet".to_string(),
                ));
            }
            "Parameter" => {
                let name =
                    get(&a, "name").ok_or_else(|| bad(line, "a Parameter has no name".into()))?;
                if set
                    .as_ref()
                    .is_some_and(|s| s.parameters.iter().any(|p| p.name == name))
                {
                    return Err(bad(line, format!("parameter '{name}' is given twice")));
                }
                if empty {
                    return Err(bad(line, format!("parameter '{name}' has no value")));
                }
                current = Some((name.to_string(), line));
            }
            t @ ("Real" | "Integer" | "Boolean" | "String" | "Enumeration" | "Binary")
                if current.is_some() =>
            {
                let (name, _) = current.take().expect("checked");
                let v = get(&a, "value")
                    .ok_or_else(|| bad(line, format!("parameter '{name}' has no value")))?;
                let mut p_unit = None;
                let value = match t {
                    "Real" => {
                        let x: f64 = v.trim().parse().map_err(|_| {
                            bad(line, format!("parameter '{name}': '{v}' is not a number"))
                        })?;
                        if !x.is_finite() {
                            return Err(bad(
                                line,
                                format!("parameter '{name}': {v} is not finite"),
                            ));
                        }
                        p_unit = get(&a, "unit").map(str::to_string);
                        ParamValue::Real(x)
                    }
                    "Integer" => ParamValue::Integer(v.trim().parse().map_err(|_| {
                        bad(line, format!("parameter '{name}': '{v}' is not an Integer"))
                    })?),
                    "Boolean" => ParamValue::Boolean(match v.trim() {
                        "true" | "1" => true,
                        "false" | "0" => false,
                        _ => {
                            return Err(bad(
                                line,
                                format!("parameter '{name}': '{v}' is not a Boolean"),
                            ));
                        }
                    }),
                    "String" => ParamValue::String(v.to_string()),
                    other => {
                        return Err(bad(
                            line,
                            format!(
                                "parameter '{name}': {} values are not supported (Real, Integer, Boolean, String)",
                                other
                            ),
                        ));
                    }
                };
                let s = set
                    .as_mut()
                    .ok_or_else(|| bad(line, "a Parameter outside ParameterSet".into()))?;
                s.parameters.push(Parameter {
                    name,
                    value,
                    unit: p_unit,
                    line,
                });
                // The closing tag of Parameter must not report "no value".
                current = None;
            }
            "Unit" => {
                let name = get(&a, "name").ok_or_else(|| bad(line, "a Unit has no name".into()))?;
                unit = Some(UnitDefinition::dimensionless(name));
                if empty && let (Some(u), Some(s)) = (unit.take(), set.as_mut()) {
                    s.units.push(u);
                }
            }
            "BaseUnit" => {
                if let Some(u) = unit.as_mut() {
                    for (k, v) in &a {
                        let bad_num = || bad(line, format!("BaseUnit {k}='{v}' is not a number"));
                        match k.as_str() {
                            "factor" => u.factor = v.trim().parse().map_err(|_| bad_num())?,
                            "offset" => u.offset = v.trim().parse().map_err(|_| bad_num())?,
                            key => {
                                if let Some(slot) = u.exponent_mut(key) {
                                    *slot = v.trim().parse().map_err(|_| bad_num())?;
                                }
                            }
                        }
                    }
                }
            }
            _ => {}
        }
        if !empty {
            depth += 1;
        }
    }
    // The reader does not say when the document ends inside an element.
    if depth > 0 {
        return Err(ParamsError::Syntax {
            file: file.to_string(),
            line: line_of(text, text.len()),
            message: format!("the document ends inside {depth} element(s) not closed"),
        });
    }
    let set = set.ok_or_else(|| bad(1, "no ssv:ParameterSet element".into()))?;
    // Every unit used must be defined (the schema's rule), so a misspelt unit is caught here.
    for p in &set.parameters {
        if let Some(u) = &p.unit
            && !set.units.iter().any(|d| &d.name == u)
        {
            return Err(bad(
                p.line,
                format!(
                    "parameter '{}': unit '{u}' is not defined in the file's Units",
                    p.name
                ),
            ));
        }
    }
    Ok(set)
}
