//! Writing SSP 1.0: `SystemStructure.ssd` XML and `.ssp` archives (see the module above).

use std::fmt::Write as _;
use std::io::{self, Write};
use std::path::{Path, PathBuf};

use super::{
    ANNOTATION_TYPE, ConnectorType, NS_KB, NS_SSC, NS_SSD, NS_SSV, Ssd, SspComponent, SspConnector,
    SspError,
};
use crate::master::{Algorithm, Value};
use model_description::write::escape_attribute as esc;

/// Formats a double as xs:double, round-trip exact.
fn xs_double(v: f64) -> String {
    if v.is_nan() {
        "NaN".into()
    } else if v.is_infinite() {
        if v > 0.0 { "INF".into() } else { "-INF".into() }
    } else {
        format!("{v:?}")
    }
}

fn algorithm_str(a: Algorithm) -> &'static str {
    match a {
        Algorithm::GaussSeidel => "gauss-seidel",
        Algorithm::Jacobi => "jacobi",
    }
}

impl Ssd {
    /// Writes the description as `SystemStructure.ssd` XML (SSP 1.0).
    pub fn to_xml(&self) -> String {
        let mut x = String::new();
        x.push_str("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
        let _ = writeln!(
            x,
            "<ssd:SystemStructureDescription xmlns:ssd=\"{NS_SSD}\" xmlns:ssc=\"{NS_SSC}\" xmlns:ssv=\"{NS_SSV}\" xmlns:kb=\"{NS_KB}\" version=\"1.0\" name=\"{}\" generationTool=\"kneebench\">",
            esc(&self.name)
        );
        let s = &self.system;
        let _ = writeln!(x, "  <ssd:System name=\"{}\">", esc(&s.name));
        if !s.components.is_empty() {
            x.push_str("    <ssd:Elements>\n");
            for c in &s.components {
                write_component(&mut x, c);
            }
            x.push_str("    </ssd:Elements>\n");
        }
        if !s.connections.is_empty() {
            x.push_str("    <ssd:Connections>\n");
            for c in &s.connections {
                x.push_str("      <ssd:Connection");
                if let Some(e) = &c.start_element {
                    let _ = write!(x, " startElement=\"{}\"", esc(e));
                }
                let _ = write!(x, " startConnector=\"{}\"", esc(&c.start_connector));
                if let Some(e) = &c.end_element {
                    let _ = write!(x, " endElement=\"{}\"", esc(e));
                }
                let _ = writeln!(x, " endConnector=\"{}\"/>", esc(&c.end_connector));
            }
            x.push_str("    </ssd:Connections>\n");
        }
        x.push_str("  </ssd:System>\n");
        if let Some(d) = &self.default_experiment {
            x.push_str("  <ssd:DefaultExperiment");
            if let Some(t) = d.start_time {
                let _ = write!(x, " startTime=\"{}\"", xs_double(t));
            }
            if let Some(t) = d.stop_time {
                let _ = write!(x, " stopTime=\"{}\"", xs_double(t));
            }
            if d.step_size.is_none() && d.algorithm.is_none() {
                x.push_str("/>\n");
            } else {
                x.push_str(">\n    <ssd:Annotations>\n");
                let _ = write!(
                    x,
                    "      <ssc:Annotation type=\"{ANNOTATION_TYPE}\">\n        <kb:Master"
                );
                if let Some(h) = d.step_size {
                    let _ = write!(x, " stepSize=\"{}\"", xs_double(h));
                }
                if let Some(a) = d.algorithm {
                    let _ = write!(x, " algorithm=\"{}\"", algorithm_str(a));
                }
                x.push_str("/>\n      </ssc:Annotation>\n    </ssd:Annotations>\n");
                x.push_str("  </ssd:DefaultExperiment>\n");
            }
        }
        x.push_str("</ssd:SystemStructureDescription>\n");
        x
    }
}

fn write_component(x: &mut String, c: &SspComponent) {
    let _ = writeln!(
        x,
        "      <ssd:Component name=\"{}\" type=\"application/x-fmu-sharedlibrary\" source=\"{}\">",
        esc(&c.name),
        esc(&c.source)
    );
    let typed: Vec<&SspConnector> = c.connectors.iter().collect();
    if !typed.is_empty() {
        x.push_str("        <ssd:Connectors>\n");
        for k in typed {
            let _ = write!(
                x,
                "          <ssd:Connector name=\"{}\" kind=\"{}\"",
                esc(&k.name),
                k.kind.as_str()
            );
            match &k.ty {
                Some(ConnectorType::Real { unit }) => {
                    x.push_str(">\n            <ssc:Real");
                    if let Some(u) = unit {
                        let _ = write!(x, " unit=\"{}\"", esc(u));
                    }
                    x.push_str("/>\n          </ssd:Connector>\n");
                }
                Some(ConnectorType::Integer) => {
                    x.push_str(">\n            <ssc:Integer/>\n          </ssd:Connector>\n")
                }
                Some(ConnectorType::Boolean) => {
                    x.push_str(">\n            <ssc:Boolean/>\n          </ssd:Connector>\n")
                }
                // Only Real/Integer/Boolean types are written (what every SSP importer handles).
                _ => x.push_str("/>\n"),
            }
        }
        x.push_str("        </ssd:Connectors>\n");
    }
    if !c.parameters.is_empty() || !c.parameter_sources.is_empty() {
        x.push_str("        <ssd:ParameterBindings>\n");
    }
    for src in &c.parameter_sources {
        let _ = writeln!(
            x,
            "          <ssd:ParameterBinding source=\"{}\"/>",
            esc(src)
        );
    }
    if !c.parameters.is_empty() {
        x.push_str("          <ssd:ParameterBinding>\n            <ssd:ParameterValues>\n");
        let _ = writeln!(
            x,
            "              <ssv:ParameterSet version=\"1.0\" name=\"{}\">\n                <ssv:Parameters>",
            esc(&c.name)
        );
        for p in &c.parameters {
            let _ = write!(
                x,
                "                  <ssv:Parameter name=\"{}\">\n                    ",
                esc(&p.name)
            );
            match &p.value {
                Value::Real(v) => {
                    let _ = write!(x, "<ssv:Real value=\"{}\"/>", xs_double(*v));
                }
                Value::Integer(v) => {
                    let _ = write!(x, "<ssv:Integer value=\"{v}\"/>");
                }
                Value::Boolean(v) => {
                    let _ = write!(x, "<ssv:Boolean value=\"{v}\"/>");
                }
                Value::String(v) => {
                    let _ = write!(x, "<ssv:String value=\"{}\"/>", esc(v));
                }
            }
            x.push_str("\n                  </ssv:Parameter>\n");
        }
        x.push_str("                </ssv:Parameters>\n              </ssv:ParameterSet>\n            </ssd:ParameterValues>\n          </ssd:ParameterBinding>\n");
    }
    if !c.parameters.is_empty() || !c.parameter_sources.is_empty() {
        x.push_str("        </ssd:ParameterBindings>\n");
    }
    if let Some(m) = c.step_multiple {
        let _ = writeln!(
            x,
            "        <ssd:Annotations>\n          <ssc:Annotation type=\"{ANNOTATION_TYPE}\">\n            <kb:Component stepMultiple=\"{m}\"/>\n          </ssc:Annotation>\n        </ssd:Annotations>"
        );
    }
    x.push_str("      </ssd:Component>\n");
}

/// Writes a bare `.ssd` file.
pub fn write_ssd_file(ssd: &Ssd, path: &Path) -> Result<(), SspError> {
    std::fs::write(path, ssd.to_xml()).map_err(|source| SspError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Writes an `.ssp` archive: `SystemStructure.ssd` plus the given files, each as
/// `(name in the archive, file on disk)`, e.g. `("resources/a.fmu", "/tmp/a.fmu")`.
pub fn write_ssp(ssd: &Ssd, files: &[(String, PathBuf)], path: &Path) -> Result<(), SspError> {
    let werr = |m: String| SspError::Write {
        path: path.to_path_buf(),
        message: m,
    };
    let f = std::fs::File::create(path).map_err(|source| SspError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut z = zip::ZipWriter::new(io::BufWriter::new(f));
    let opts = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated)
        .unix_permissions(0o644);
    z.start_file("SystemStructure.ssd", opts)
        .map_err(|e| werr(e.to_string()))?;
    z.write_all(ssd.to_xml().as_bytes())
        .map_err(|e| werr(e.to_string()))?;
    for (name, src) in files {
        crate::load::sanitize_entry_name(name).map_err(|e| werr(e.to_string()))?;
        let bytes = std::fs::read(src).map_err(|source| SspError::Io {
            path: src.clone(),
            source,
        })?;
        // FMUs are already compressed.
        let o = opts.compression_method(zip::CompressionMethod::Stored);
        z.start_file(name.as_str(), o)
            .map_err(|e| werr(e.to_string()))?;
        z.write_all(&bytes).map_err(|e| werr(e.to_string()))?;
    }
    z.finish().map_err(|e| werr(e.to_string()))?;
    Ok(())
}
