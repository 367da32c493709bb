//! SSP 1.0 system structure: read and write `.ssp` archives and bare `.ssd` files.
//!
//! What is modelled ([`Ssd`]): one `System` with `Component`s (name, source URI, connectors,
//! inline parameter values), `Connection`s, and the `DefaultExperiment` (start and stop time).
//! SSP 1.0 has no place for the master's step size, so it is written as an annotation of the
//! default experiment (`<ssd:Annotations><ssc:Annotation type="org.kneebench.master">` holding
//! `<kb:Master stepSize="..." algorithm="..."/>`), and a component's step multiple as an
//! annotation of the component (`<kb:Component stepMultiple="..."/>`); other tools ignore both.
//!
//! Writing follows `SystemStructureDescription.xsd` version 1.0 (the `ssd:`, `ssc:` and `ssv:`
//! namespaces, `version="1.0"`, elements in schema order) and only writes `Real`, `Integer` and
//! `Boolean` connector types, so fmpy's `read_ssd` (which validates against the 1.0 schema) and
//! libcosim load it (both tested with the study's systems, `tests/tests/study_tools.rs`;
//! libcosim applies every binding: it would skip one to an FMI 2.0 Enumeration variable, which
//! it does not support, so our FMUs declare their modes as `Integer`).
//! Parameter values are written inline as an
//! `ssv:ParameterSet` inside `ssd:ParameterValues`, after one `ParameterBinding source=".."`
//! per `.ssv` file bound to the component ([`SspComponent::parameter_sources`]; the files
//! themselves go into the archive with [`write_ssp`]'s `files`).
//!
//! Reading matches elements by local name (any prefix), accepts parameter values inline or in an
//! `.ssv` file referenced by `source`, and refuses what the master cannot run (nested systems,
//! connections to system-level connectors) with a clear error. Errors name the file and the
//! line of the element concerned: a malformed or unusable element, a parameter's bad value
//! (inline or in the `.ssv`), and a problem of the whole document found at its end (no `System`:
//! the root element's line).

use std::collections::HashMap;
use std::io;
use std::path::{Path, PathBuf};

use crate::load::{ArchiveBudget, ArchiveLimits, Fmu, LoadError, LoadOptions};
use crate::master::{Algorithm, MasterError, RunConfig, System, Value, VarType};

mod read;
mod write;

use read::read_ssd_labelled;
pub use read::{read_ssd, read_ssd_with};
pub use write::{write_ssd_file, write_ssp};

/// SSD namespace.
pub const NS_SSD: &str = "http://ssp-standard.org/SSP1/SystemStructureDescription";
/// SSC (common) namespace.
pub const NS_SSC: &str = "http://ssp-standard.org/SSP1/SystemStructureCommon";
/// SSV (parameter values) namespace.
pub const NS_SSV: &str = "http://ssp-standard.org/SSP1/SystemStructureParameterValues";
/// The namespace of kneebench's annotations.
pub const NS_KB: &str = "https://github.com/kneebench/kneebench/ssp";
/// The annotation type of kneebench's annotations.
pub const ANNOTATION_TYPE: &str = "org.kneebench.master";

/// A system structure description.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Ssd {
    /// `name` of the description.
    pub name: String,
    /// `version` (written as `1.0`).
    pub version: String,
    /// The system.
    pub system: SspSystem,
    /// `DefaultExperiment` (and the master settings in its annotation).
    pub default_experiment: Option<SspExperiment>,
}

/// `DefaultExperiment` plus the master's settings.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SspExperiment {
    /// `startTime`.
    pub start_time: Option<f64>,
    /// `stopTime`.
    pub stop_time: Option<f64>,
    /// The base step (kneebench annotation).
    pub step_size: Option<f64>,
    /// The algorithm (kneebench annotation).
    pub algorithm: Option<Algorithm>,
}

/// The `System` element.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SspSystem {
    /// `name`.
    pub name: String,
    /// `Elements/Component`.
    pub components: Vec<SspComponent>,
    /// `Connections/Connection`.
    pub connections: Vec<SspConnection>,
}

/// A `Component`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SspComponent {
    /// `name`.
    pub name: String,
    /// `source`: URI of the FMU, relative to the SSD's location (e.g. `resources/a.fmu`).
    pub source: String,
    /// `Connectors/Connector`.
    pub connectors: Vec<SspConnector>,
    /// Parameter-value files (`.ssv`) bound to the component, as URIs relative to the SSD
    /// (e.g. `resources/plant.ssv`), applied before the inline values. Written as one
    /// `ParameterBinding source=".."` each; on reading, a binding's file is recorded here and
    /// its values are appended to [`Self::parameters`] (in binding order), so the values a
    /// master applies are in `parameters` either way.
    pub parameter_sources: Vec<String>,
    /// Inline parameter values.
    pub parameters: Vec<SspParameter>,
    /// The step multiple (kneebench annotation).
    pub step_multiple: Option<u64>,
}

/// A `Connector`.
#[derive(Debug, Clone, PartialEq)]
pub struct SspConnector {
    /// `name` (the FMU variable's name).
    pub name: String,
    /// `kind`.
    pub kind: ConnectorKind,
    /// The type element, if any.
    pub ty: Option<ConnectorType>,
}

/// `kind` of a connector.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ConnectorKind {
    /// `input`.
    Input,
    /// `output`.
    Output,
    /// `parameter`.
    Parameter,
    /// `calculatedParameter`.
    CalculatedParameter,
    /// `inout`.
    Inout,
}

impl ConnectorKind {
    fn as_str(self) -> &'static str {
        match self {
            ConnectorKind::Input => "input",
            ConnectorKind::Output => "output",
            ConnectorKind::Parameter => "parameter",
            ConnectorKind::CalculatedParameter => "calculatedParameter",
            ConnectorKind::Inout => "inout",
        }
    }
    fn parse(s: &str) -> Option<ConnectorKind> {
        Some(match s {
            "input" => ConnectorKind::Input,
            "output" => ConnectorKind::Output,
            "parameter" => ConnectorKind::Parameter,
            "calculatedParameter" => ConnectorKind::CalculatedParameter,
            "inout" => ConnectorKind::Inout,
            _ => return None,
        })
    }
}

/// The type of a connector (only `Real`, `Integer` and `Boolean` are written).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ConnectorType {
    /// `Real` with an optional `unit`.
    Real {
        /// `unit`.
        unit: Option<String>,
    },
    /// `Integer`.
    Integer,
    /// `Boolean`.
    Boolean,
    /// `String` (read only).
    String,
    /// `Enumeration` (read only).
    Enumeration,
}

/// A parameter value of a component.
#[derive(Debug, Clone, PartialEq)]
pub struct SspParameter {
    /// The parameter (connector / variable) name.
    pub name: String,
    /// The value.
    pub value: Value,
}

/// A `Connection`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SspConnection {
    /// `startElement` (absent: a connector of the system itself).
    pub start_element: Option<String>,
    /// `startConnector`.
    pub start_connector: String,
    /// `endElement`.
    pub end_element: Option<String>,
    /// `endConnector`.
    pub end_connector: String,
}

/// Errors of reading, writing and loading SSP files.
#[derive(Debug, thiserror::Error)]
pub enum SspError {
    /// File I/O.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: io::Error,
    },
    /// Malformed XML (not well-formed: the parser's reason, or a tag whose attribute names or
    /// values no XML document may hold, or an element not closed at the end).
    #[error("{file} line {line}: malformed XML (byte {position}): {message}")]
    Xml {
        /// The file: its path, or for a file inside an `.ssp` archive the archive's path and
        /// the file's name in it (`Foo.ssp: SystemStructure.ssd`).
        file: String,
        /// Byte offset.
        position: u64,
        /// 1-based line of `position`.
        line: usize,
        /// The parser's message.
        message: String,
    },
    /// Valid XML but not a usable SSD.
    #[error("{file}: {problem}")]
    Invalid {
        /// The file (inside an `.ssp`: the archive's path and the file's name in it), with the
        /// line of the element concerned where there is one (`Foo.ssp: SystemStructure.ssd
        /// line 12`).
        file: String,
        /// What is wrong.
        problem: String,
    },
    /// A feature the master does not run.
    #[error("{file}: unsupported: {what}")]
    Unsupported {
        /// The file.
        file: String,
        /// What.
        what: String,
    },
    /// `--replace`: the component does not exist, or the FMU does not fit its interface.
    #[error("replacing component '{component}': {problem}")]
    Replacement {
        /// The component.
        component: String,
        /// Why.
        problem: String,
    },
    /// The archive could not be extracted, or a component's FMU could not be loaded.
    #[error("{context}: {source}")]
    Load {
        /// What was being loaded.
        context: String,
        /// The cause.
        source: LoadError,
    },
    /// Building the system failed.
    #[error(transparent)]
    System(#[from] MasterError),
    /// Writing the archive failed.
    #[error("writing {}: {message}", path.display())]
    Write {
        /// The archive.
        path: PathBuf,
        /// The cause.
        message: String,
    },
}

impl SspSystem {
    /// Removes input connectors that no connection ends at. fmpy's `get_connections` (used by
    /// its SSP simulation) fails on an unconnected input connector, so call this before writing
    /// for fmpy.
    pub fn drop_unconnected_inputs(&mut self) {
        let conns = self.connections.clone();
        for c in &mut self.components {
            let name = c.name.clone();
            c.connectors.retain(|k| {
                k.kind != ConnectorKind::Input
                    || conns.iter().any(|x| {
                        (x.end_element.as_deref() == Some(name.as_str())
                            && x.end_connector == k.name)
                            || (x.start_element.as_deref() == Some(name.as_str())
                                && x.start_connector == k.name)
                    })
            });
        }
    }
}

impl SspComponent {
    /// A component for `fmu` with one connector per input, output and tunable/fixed parameter
    /// of type `Real`, `Integer` or `Boolean`.
    pub fn from_model_description(
        name: &str,
        source: &str,
        md: &model_description::ModelDescription,
    ) -> SspComponent {
        use model_description::{Causality, VariableKind};
        let connectors = md
            .model_variables
            .iter()
            .filter_map(|v| {
                let kind = match v.causality? {
                    Causality::Input => ConnectorKind::Input,
                    Causality::Output => ConnectorKind::Output,
                    Causality::Parameter => ConnectorKind::Parameter,
                    _ => return None,
                };
                let ty = match &v.kind {
                    VariableKind::Real { attributes, .. } => ConnectorType::Real {
                        unit: attributes.unit.clone(),
                    },
                    VariableKind::Integer { .. } => ConnectorType::Integer,
                    VariableKind::Boolean { .. } => ConnectorType::Boolean,
                    _ => return None,
                };
                Some(SspConnector {
                    name: v.name.clone(),
                    kind,
                    ty: Some(ty),
                })
            })
            .collect();
        SspComponent {
            name: name.to_string(),
            source: source.to_string(),
            connectors,
            parameter_sources: Vec::new(),
            parameters: Vec::new(),
            step_multiple: None,
        }
    }
}

/// The file a component's `source` (or a parameter set's) refers to, relative to `base`.
///
/// Inside an archive (`confined`, `base` the extraction directory) the reference must stay in
/// it: no `..`, as for the archive's entries. Beside a bare `.ssd` on disk a relative reference
/// may climb (`../fmus/Plant.fmu`: the FMUs in a sibling directory), as any relative URI may;
/// an absolute path or a URI with a scheme is refused in both.
fn relative_ref(
    base: &Path,
    reference: &str,
    file: &str,
    confined: bool,
) -> Result<PathBuf, SspError> {
    let r = reference.strip_prefix("./").unwrap_or(reference);
    if r.contains("://") || r.starts_with("file:") {
        return Err(SspError::Unsupported {
            file: file.to_string(),
            what: format!("source URI '{reference}' (only relative references)"),
        });
    }
    let invalid = |problem: String| SspError::Invalid {
        file: file.to_string(),
        problem: format!("source '{reference}': {problem}"),
    };
    let rel = if confined {
        crate::load::sanitize_entry_name(r).map_err(|e| invalid(e.to_string()))?
    } else {
        // The archive's rules but for '..' (an absolute or Windows path, a NUL byte stay
        // refused): each '..' checked as if it were a plain name.
        let probe: Vec<&str> = r
            .split('/')
            .map(|c| if c == ".." { "parent" } else { c })
            .collect();
        crate::load::sanitize_entry_name(&probe.join("/")).map_err(|e| match e {
            crate::load::LoadError::UnsafeEntryName { reason, .. } => invalid(reason.to_string()),
            e => invalid(e.to_string()),
        })?;
        let mut out = PathBuf::new();
        for component in r.split('/') {
            match component {
                "" | "." => {}
                c => out.push(c),
            }
        }
        (!out.as_os_str().is_empty()).then_some(out)
    };
    let rel = rel.ok_or_else(|| SspError::Invalid {
        file: file.to_string(),
        problem: format!("empty source '{reference}'"),
    })?;
    Ok(base.join(rel))
}

/// A system read from an SSP file, ready to run.
pub struct LoadedSystem {
    /// The description as read.
    pub ssd: Ssd,
    /// The system built from it (components, connections, parameter values, step multiples).
    pub system: System,
    /// A run configuration from the default experiment (fields not given keep the defaults of
    /// [`RunConfig::default`]).
    pub config: RunConfig,
    /// `component.parameter` values of the system that a replacement FMU has no variable for
    /// and so were not applied ([`load_system_replacing`]; empty without replacements).
    pub unapplied: Vec<String>,
    // The extracted archive (kept while the system may still refer to files in it).
    _dir: Option<tempfile::TempDir>,
}

impl std::fmt::Debug for LoadedSystem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LoadedSystem")
            .field("ssd", &self.ssd)
            .field("config", &self.config)
            .field("unapplied", &self.unapplied)
            .finish()
    }
}

/// Reads an `.ssp` archive (extracted safely with the limits of `options`) or a bare `.ssd`
/// file (component sources relative to its directory).
pub fn read_file(
    path: &Path,
    limits: &ArchiveLimits,
) -> Result<(Ssd, PathBuf, Option<tempfile::TempDir>), SspError> {
    read_file_within(path, &ArchiveBudget::new(*limits))
}

/// [`read_file`] counting the archive against a run's `budget`.
pub fn read_file_within(
    path: &Path,
    budget: &ArchiveBudget,
) -> Result<(Ssd, PathBuf, Option<tempfile::TempDir>), SspError> {
    let is_ssd = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("ssd"));
    let (base, dir) = if is_ssd {
        (
            path.parent().map(Path::to_path_buf).unwrap_or_default(),
            None,
        )
    } else {
        let dir = crate::tempdirs::create("ssp").map_err(|source| SspError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        crate::load::extract_archive_within(path, dir.path(), budget).map_err(|source| {
            SspError::Load {
                context: format!("extracting {}", path.display()),
                source,
            }
        })?;
        (dir.path().to_path_buf(), Some(dir))
    };
    let ssd = if is_ssd {
        read_ssd_file(path, &base, None)?
    } else {
        read_ssd_file(&base.join(SSD_NAME), &base, Some(path))?
    };
    Ok((ssd, base, dir))
}

/// The description's name inside an `.ssp` archive.
const SSD_NAME: &str = "SystemStructure.ssd";

/// Reads and parses the description `ssd_path`, its references (parameter values) relative to
/// `base`. For an `.ssp` extracted into `base`, `archive` is the archive: errors name it and
/// the file inside it (`Foo.ssp: SystemStructure.ssd line 12: ...`), never the extraction
/// directory, which is gone when the user reads them.
fn read_ssd_file(ssd_path: &Path, base: &Path, archive: Option<&Path>) -> Result<Ssd, SspError> {
    let inside = |name: &str| match archive {
        Some(a) => format!("{}: {name}", a.display()),
        None => base.join(name).display().to_string(),
    };
    let file = match archive {
        Some(_) => inside(SSD_NAME),
        None => ssd_path.display().to_string(),
    };
    let read = |path: &Path, name: &str| {
        std::fs::read_to_string(path).map_err(|source| match archive {
            Some(a) if source.kind() == io::ErrorKind::NotFound => SspError::Invalid {
                file: a.display().to_string(),
                problem: format!("the archive has no {name}"),
            },
            Some(_) => SspError::Invalid {
                file: inside(name),
                problem: source.to_string(),
            },
            None => SspError::Io {
                path: path.to_path_buf(),
                source,
            },
        })
    };
    let xml = read(ssd_path, SSD_NAME)?;
    read_ssd_labelled(&xml, &file, &inside, &mut |src| {
        read(&relative_ref(base, src, &file, archive.is_some())?, src)
    })
}

/// What [`read_file_for_run`] returns: the description, the directory its references are
/// relative to, the extraction directory, and the FMUs read in place.
type ForRun = (
    Ssd,
    PathBuf,
    Option<tempfile::TempDir>,
    HashMap<PathBuf, crate::load::ArchiveSource>,
);

/// [`read_file_within`] for a run ([`Binaries::Shared`](crate::load::Binaries::Shared)): the
/// FMUs the archive stores uncompressed are left in it, to be read in place (their paths as
/// if extracted, mapped to where their bytes are); everything else is extracted.
fn read_file_for_run(path: &Path, budget: &ArchiveBudget) -> Result<ForRun, SspError> {
    use crate::load::ArchiveSource;
    let is_ssd = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("ssd"));
    if is_ssd {
        let (ssd, base, dir) = read_file_within(path, budget)?;
        return Ok((ssd, base, dir, HashMap::new()));
    }
    let dir = crate::tempdirs::create("ssp").map_err(|source| SspError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let base = dir.path().to_path_buf();
    let extracting = |source| SspError::Load {
        context: format!("extracting {}", path.display()),
        source,
    };
    let mut zip = crate::load::open_archive(&ArchiveSource::File(path.to_path_buf()), budget)
        .map_err(extracting)?;
    let is_fmu = |rel: &Path| {
        rel.extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("fmu"))
    };
    let done = crate::load::extract_entries(&mut zip, path, &base, budget, &|rel| !is_fmu(rel))
        .map_err(extracting)?;
    let mut in_place = HashMap::new();
    for (rel, index) in done.left {
        let stored = {
            let raw = zip.by_index_raw(index).map_err(|source| {
                extracting(crate::load::LoadError::Zip {
                    archive: path.to_path_buf(),
                    entry: None,
                    source,
                })
            })?;
            match raw.data_start() {
                Some(start)
                    if raw.compression() == zip::CompressionMethod::Stored
                        && raw.compressed_size() == raw.size() =>
                {
                    Some((start, raw.size()))
                }
                _ => None,
            }
        };
        let target = base.join(&rel);
        match stored {
            Some((start, len)) => {
                in_place.insert(
                    target,
                    ArchiveSource::Nested {
                        container: path.to_path_buf(),
                        start,
                        len,
                        name: path.join(&rel),
                    },
                );
            }
            None => {
                // Compressed: extracted like the rest (its declared size already counted).
                crate::load::extract_declared(&mut zip, path, index, &target)
                    .map_err(extracting)?;
            }
        }
    }
    let ssd = read_ssd_file(&base.join(SSD_NAME), &base, Some(path))?;
    Ok((ssd, base, Some(dir), in_place))
}

/// Reads an SSP (`.ssp` or `.ssd`) and builds the [`System`]: loads each distinct FMU once,
/// adds the components, connections (component to component only) and parameter values.
///
/// The SSP archive and the FMUs in it share one [`ArchiveBudget`] (the one in `options`, or a
/// fresh one of `options.limits`).
pub fn load_system(path: &Path, options: &LoadOptions) -> Result<LoadedSystem, SspError> {
    load_system_replacing(path, options, &[])
}

/// Where an FMU's interface differs from what a component of a system needs: each input and
/// output connector of `component` must be a variable of `md` with the same causality and type,
/// and so must each parameter it binds a value to that `md` has. A bound parameter `md` lacks is
/// no mismatch but [`unapplied_parameters`]: the plant's and the hardware's parameters differ
/// (the twin's friction, inertias and loss surface are the real bench's own physics), their
/// signals do not.
pub fn interface_mismatches(
    component: &SspComponent,
    md: &model_description::ModelDescription,
) -> Vec<String> {
    use model_description::Causality;
    let mut problems = Vec::new();
    for k in &component.connectors {
        let parameter = matches!(
            k.kind,
            ConnectorKind::Parameter | ConnectorKind::CalculatedParameter
        );
        if parameter && !component.parameters.iter().any(|p| p.name == k.name) {
            continue;
        }
        let Some(v) = md.model_variables.iter().find(|v| v.name == k.name) else {
            if !parameter {
                problems.push(format!("no variable '{}' ({})", k.name, k.kind.as_str()));
            }
            continue;
        };
        // FMI 2.0: a missing causality is `local`.
        let causality = v.causality.unwrap_or(Causality::Local);
        let causality_matches = match k.kind {
            ConnectorKind::Input => causality == Causality::Input,
            ConnectorKind::Output => causality == Causality::Output,
            ConnectorKind::Parameter => causality == Causality::Parameter,
            ConnectorKind::CalculatedParameter => causality == Causality::CalculatedParameter,
            ConnectorKind::Inout => true,
        };
        if !causality_matches {
            problems.push(format!(
                "'{}' is {:?} there, the system needs {}",
                k.name,
                causality,
                k.kind.as_str()
            ));
        }
        if let Some(ty) = &k.ty {
            let (want, have) = (connector_var_type(ty), VarType::of(v));
            if want != have {
                problems.push(format!(
                    "'{}' is {have:?} there, the system needs {want:?}",
                    k.name
                ));
            }
        }
    }
    problems.dedup();
    problems
}

/// The parameters `component` binds a value to that `md` has no variable for (in binding
/// order): what a replacement FMU does not take from the replaced one's set.
pub fn unapplied_parameters(
    component: &SspComponent,
    md: &model_description::ModelDescription,
) -> Vec<String> {
    component
        .parameters
        .iter()
        .filter(|p| !md.model_variables.iter().any(|v| v.name == p.name))
        .map(|p| p.name.clone())
        .collect()
}

/// [`load_system`] with some components' FMUs replaced: `(component, FMU file)` (e.g. the plant
/// by `BenchHardware.fmu`, to run the same schedule on the bench). A replacement must offer
/// every input and output of its component with the same causality and type
/// ([`interface_mismatches`]); the component keeps its connections and the parameter values the
/// replacement has variables for. Those it has none for (a twin's parameter set on the bench)
/// are not applied and are listed in [`LoadedSystem::unapplied`], for the caller to report.
pub fn load_system_replacing(
    path: &Path,
    options: &LoadOptions,
    replacements: &[(String, PathBuf)],
) -> Result<LoadedSystem, SspError> {
    let budget = options
        .budget
        .clone()
        .unwrap_or_else(|| ArchiveBudget::new(options.limits));
    let options = &LoadOptions {
        budget: Some(budget.clone()),
        ..options.clone()
    };
    let (ssd, base, dir, in_place) = if options.binaries == crate::load::Binaries::Shared {
        read_file_for_run(path, &budget)?
    } else {
        let (ssd, base, dir) = read_file_within(path, &budget)?;
        (ssd, base, dir, HashMap::new())
    };
    let file = path.display().to_string();
    let mut system = System::new();
    let mut fmus: HashMap<String, Fmu> = HashMap::new();
    for (name, _) in replacements {
        if !ssd.system.components.iter().any(|c| &c.name == name) {
            return Err(SspError::Replacement {
                component: name.clone(),
                problem: format!(
                    "the system has no such component (it has {})",
                    ssd.system
                        .components
                        .iter()
                        .map(|c| c.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            });
        }
    }
    let mut unapplied = Vec::new();
    for c in &ssd.system.components {
        if let Some((_, replacement)) = replacements.iter().find(|(n, _)| *n == c.name) {
            let fmu = Fmu::load(replacement, options).map_err(|source| SspError::Load {
                context: format!(
                    "replacement of component '{}' ({})",
                    c.name,
                    replacement.display()
                ),
                source,
            })?;
            let problems = interface_mismatches(c, fmu.model_description());
            if !problems.is_empty() {
                return Err(SspError::Replacement {
                    component: c.name.clone(),
                    problem: format!(
                        "{} does not fit: {}",
                        replacement.display(),
                        problems.join("; ")
                    ),
                });
            }
            let skipped = unapplied_parameters(c, fmu.model_description());
            system.add_component(&c.name, fmu)?;
            set_component_values(&mut system, c, &skipped)?;
            unapplied.extend(skipped.into_iter().map(|p| format!("{}.{p}", c.name)));
            continue;
        }
        let fmu = match fmus.get(&c.source) {
            Some(f) => f.clone(),
            None => {
                let p = relative_ref(&base, &c.source, &file, dir.is_some())?;
                let loaded = match in_place.get(&p) {
                    Some(source) => Fmu::load_from(source, options),
                    None => Fmu::load(&p, options),
                };
                let f = loaded.map_err(|source| SspError::Load {
                    context: format!("component '{}' ({})", c.name, c.source),
                    source,
                })?;
                fmus.insert(c.source.clone(), f.clone());
                f
            }
        };
        system.add_component(&c.name, fmu)?;
        set_component_values(&mut system, c, &[])?;
    }
    for c in &ssd.system.connections {
        let (Some(se), Some(ee)) = (&c.start_element, &c.end_element) else {
            return Err(SspError::Unsupported {
                file: file.clone(),
                what: format!(
                    "connection {}.{} -> {}.{} to a connector of the system itself",
                    c.start_element.as_deref().unwrap_or(""),
                    c.start_connector,
                    c.end_element.as_deref().unwrap_or(""),
                    c.end_connector
                ),
            });
        };
        system.connect(
            &format!("{se}.{}", c.start_connector),
            &format!("{ee}.{}", c.end_connector),
        )?;
    }
    let mut config = RunConfig::default();
    if let Some(d) = &ssd.default_experiment {
        config = config.with_times(d.start_time, d.stop_time, d.step_size);
        if let Some(a) = d.algorithm {
            config.algorithm = a;
        }
    }
    Ok(LoadedSystem {
        ssd,
        system,
        config,
        unapplied,
        _dir: dir,
    })
}

/// A component's step multiple and parameter values.
fn set_component_values(
    system: &mut System,
    c: &SspComponent,
    skipped: &[String],
) -> Result<(), SspError> {
    if let Some(m) = c.step_multiple {
        system.set_step_multiple(&c.name, m)?;
    }
    for p in c.parameters.iter().filter(|p| !skipped.contains(&p.name)) {
        let reference = format!("{}.{}", c.name, p.name);
        // Integer parameters may be written for Real variables (and vice versa) by other
        // tools: convert through text.
        match system.set_value(&reference, p.value.clone()) {
            Ok(()) => {}
            Err(MasterError::BadValue { .. }) => {
                system.set_value_str(&reference, &p.value.to_text())?
            }
            Err(e) => return Err(e.into()),
        }
    }
    Ok(())
}

/// The variable type a connector type stands for.
pub fn connector_var_type(t: &ConnectorType) -> VarType {
    match t {
        ConnectorType::Real { .. } => VarType::Real,
        ConnectorType::Integer | ConnectorType::Enumeration => VarType::Integer,
        ConnectorType::Boolean => VarType::Boolean,
        ConnectorType::String => VarType::String,
    }
}
