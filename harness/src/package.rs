//! Packaging: turns the kneebench FMU binary into one `.fmu` archive per model.
//!
//! The binary (`libkneebench_fmu.so`) serves every model and carries a small catalog
//! (`kneebench_model_count`, `kneebench_model_file`) with each model's identifier, generated
//! `modelDescription.xml`, documentation page and reference-run inputs. The packager reads that
//! catalog through `libloading` (it never links the models), copies the binary into each archive
//! as `binaries/linux64/<modelIdentifier>.so`, runs the documented reference run of the packaged
//! FMU with the harness's own master, and stores its inputs and results under `extra/`.
//!
//! Archives are reproducible: entries in a fixed order, fixed timestamps (1980-01-01) and
//! permissions, so the same sources give byte-identical files.

use std::ffi::{CStr, c_char, c_int};
use std::io::Write as _;
use std::path::{Path, PathBuf};

use zip::write::SimpleFileOptions;
use zip::{CompressionMethod, DateTime, ZipWriter};

/// Errors of the packager.
#[derive(Debug, thiserror::Error)]
pub enum PackageError {
    /// The binary could not be loaded or lacks the catalog.
    #[error("cannot read the model catalog of {path}: {message}")]
    Library {
        /// The binary.
        path: PathBuf,
        /// Why.
        message: String,
    },
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// Writing the archive failed.
    #[error("writing {path}: {source}")]
    Zip {
        /// The archive.
        path: PathBuf,
        /// The zip error.
        source: zip::result::ZipError,
    },
    /// The reference run of a packaged FMU failed.
    #[error("reference run of {model}: {message}")]
    ReferenceRun {
        /// The model.
        model: String,
        /// Why.
        message: String,
    },
}

/// One model of the catalog.
#[derive(Debug, Clone, PartialEq)]
pub struct CatalogEntry {
    /// `modelIdentifier`.
    pub identifier: String,
    /// The generated `modelDescription.xml`.
    pub model_description: String,
    /// The generated `documentation/index.html`.
    pub documentation: String,
    /// CSV of the reference run's inputs (`time,<inputs>`), if the model has inputs.
    pub reference_inputs: Option<String>,
}

/// Reads the model catalog of a kneebench FMU binary.
pub fn read_catalog(library: &Path) -> Result<Vec<CatalogEntry>, PackageError> {
    let err = |message: String| PackageError::Library {
        path: library.to_path_buf(),
        message,
    };
    // SAFETY: loading runs the library's initialisers; the kneebench binary has none beyond
    // Rust's, and this is the binary the user asked us to package.
    let lib = unsafe { libloading::Library::new(library) }.map_err(|e| err(e.to_string()))?;
    // SAFETY: the symbols have exactly these signatures in fmu/src/fmi2/export.rs.
    let (count, file) = unsafe {
        let count: libloading::Symbol<unsafe extern "C" fn() -> usize> = lib
            .get(b"kneebench_model_count\0")
            .map_err(|e| err(format!("not a kneebench FMU binary: {e}")))?;
        let file: libloading::Symbol<unsafe extern "C" fn(usize, c_int) -> *const c_char> = lib
            .get(b"kneebench_model_file\0")
            .map_err(|e| err(format!("not a kneebench FMU binary: {e}")))?;
        (*count, *file)
    };
    let text = |index: usize, kind: c_int| -> Option<String> {
        // SAFETY: the catalog returns NULL or a NUL-terminated string that lives as long as
        // the library, which outlives this call.
        let p = unsafe { file(index, kind) };
        (!p.is_null()).then(|| unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned())
    };
    // SAFETY: plain call without arguments.
    let n = unsafe { count() };
    (0..n)
        .map(|i| {
            Ok(CatalogEntry {
                identifier: text(i, 0)
                    .ok_or_else(|| err(format!("model {i} has no identifier")))?,
                model_description: text(i, 1)
                    .ok_or_else(|| err(format!("model {i} has no model description")))?,
                documentation: text(i, 2)
                    .ok_or_else(|| err(format!("model {i} has no documentation")))?,
                reference_inputs: text(i, 3),
            })
        })
        .collect()
}

/// Writes a reproducible zip of `files` (archive path, contents, executable bit) to `path`.
pub fn write_archive(path: &Path, files: &[(String, Vec<u8>, bool)]) -> Result<(), PackageError> {
    let zerr = |source| PackageError::Zip {
        path: path.to_path_buf(),
        source,
    };
    let ioerr = |source| PackageError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut sorted: Vec<&(String, Vec<u8>, bool)> = files.iter().collect();
    sorted.sort_by(|a, b| a.0.cmp(&b.0));
    let mut buffer = std::io::Cursor::new(Vec::new());
    {
        let mut zip = ZipWriter::new(&mut buffer);
        let mut dirs: Vec<String> = Vec::new();
        for (name, data, executable) in sorted {
            // Directory entries first, for tools that expect them.
            let mut prefix = String::new();
            for part in name
                .split('/')
                .rev()
                .skip(1)
                .collect::<Vec<_>>()
                .into_iter()
                .rev()
            {
                prefix.push_str(part);
                prefix.push('/');
                if !dirs.contains(&prefix) {
                    dirs.push(prefix.clone());
                    zip.add_directory(prefix.as_str(), options(0o755))
                        .map_err(zerr)?;
                }
            }
            zip.start_file(
                name.as_str(),
                options(if *executable { 0o755 } else { 0o644 }),
            )
            .map_err(zerr)?;
            zip.write_all(data).map_err(ioerr)?;
        }
        zip.finish().map_err(zerr)?;
    }
    std::fs::write(path, buffer.into_inner()).map_err(ioerr)
}

fn options(mode: u32) -> SimpleFileOptions {
    SimpleFileOptions::default()
        .compression_method(CompressionMethod::Deflated)
        .compression_level(Some(6))
        .last_modified_time(DateTime::default())
        .unix_permissions(mode)
}

/// The default location of the FMU binary: next to the running executable (both are built
/// into the same cargo target directory).
pub fn default_library() -> Option<PathBuf> {
    let exe = std::env::current_exe().ok()?;
    let dir = exe.parent()?;
    [
        dir.join("libkneebench_fmu.so"),
        dir.join("../libkneebench_fmu.so"),
    ]
    .into_iter()
    .find(|p| p.is_file())
}

/// The files of one FMU archive without `extra/`.
pub fn fmu_files(entry: &CatalogEntry, binary: &[u8]) -> Vec<(String, Vec<u8>, bool)> {
    vec![
        (
            "modelDescription.xml".into(),
            entry.model_description.as_bytes().to_vec(),
            false,
        ),
        (
            format!("binaries/linux64/{}.so", entry.identifier),
            binary.to_vec(),
            true,
        ),
        (
            "documentation/index.html".into(),
            entry.documentation.as_bytes().to_vec(),
            false,
        ),
    ]
}

/// Reads a file, with the path in the error.
pub fn read_file(path: &Path) -> Result<Vec<u8>, PackageError> {
    std::fs::read(path).map_err(|source| PackageError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// What [`export_all`] wrote for one model.
#[derive(Debug, Clone)]
pub struct ExportedFmu {
    /// `modelIdentifier`.
    pub identifier: String,
    /// The `.fmu` file.
    pub path: PathBuf,
}

/// Writes one `.fmu` per model of `library` into `out`, each with the reference results of its
/// documented run (the model's default experiment, run by this harness's master at the default
/// step size, recorded at every step) under `extra/`.
pub fn export_all(library: &Path, out: &Path) -> Result<Vec<ExportedFmu>, PackageError> {
    let catalog = read_catalog(library)?;
    let binary = read_file(library)?;
    std::fs::create_dir_all(out).map_err(|source| PackageError::Io {
        path: out.to_path_buf(),
        source,
    })?;
    let mut written = Vec::new();
    for entry in &catalog {
        let path = out.join(format!("{}.fmu", entry.identifier));
        let mut files = fmu_files(entry, &binary);
        // First the archive without extra/, which the reference run loads like any importer.
        write_archive(&path, &files)?;
        files.extend(reference_run(entry, &path)?);
        write_archive(&path, &files)?;
        written.push(ExportedFmu {
            identifier: entry.identifier.clone(),
            path,
        });
    }
    Ok(written)
}

/// Runs the documented reference run of a packaged FMU; returns the `extra/` files.
fn reference_run(
    entry: &CatalogEntry,
    fmu_path: &Path,
) -> Result<Vec<(String, Vec<u8>, bool)>, PackageError> {
    use crate::master::{RunConfig, Signal, System};
    let fail = |message: String| PackageError::ReferenceRun {
        model: entry.identifier.clone(),
        message,
    };
    let fmu = crate::Fmu::load(fmu_path, &crate::LoadOptions::default())
        .map_err(|e| fail(e.to_string()))?;
    let md = fmu.model_description().clone();
    let config = RunConfig::of_fmu(&md);
    let (start, stop, step) = (config.start_time, config.stop_time, config.step_size);
    let mut system = System::new();
    system.set_column_prefix(false);
    system
        .add_component(&entry.identifier, fmu)
        .map_err(|e| fail(e.to_string()))?;
    let mut extra = Vec::new();
    if let Some(csv) = &entry.reference_inputs {
        let inputs = crate::results::Results::read_csv(csv.as_bytes(), Path::new("inputs.csv"))
            .map_err(|e| fail(e.to_string()))?;
        let times = inputs.times();
        for name in inputs.names() {
            let values = inputs.column(name).unwrap_or_default();
            system
                .add_signal(
                    &format!("{}.{name}", entry.identifier),
                    Signal {
                        times: times.clone(),
                        values,
                        interpolate: false,
                    },
                )
                .map_err(|e| fail(e.to_string()))?;
        }
        extra.push((
            "extra/reference-inputs.csv".to_string(),
            csv.as_bytes().to_vec(),
            false,
        ));
    }
    let outputs: Vec<String> = md
        .model_variables
        .iter()
        .filter(|v| v.causality == Some(model_description::Causality::Output))
        .map(|v| format!("{}.{}", entry.identifier, v.name))
        .collect();
    let refs: Vec<&str> = outputs.iter().map(String::as_str).collect();
    system.record(&refs).map_err(|e| fail(e.to_string()))?;
    let output = system.run(&config).map_err(|e| fail(e.to_string()))?;
    if let crate::Outcome::Failed(e) = &output.outcome {
        return Err(fail(e.to_string()));
    }
    let mut csv = Vec::new();
    output
        .results
        .write_csv(&mut csv)
        .map_err(|e| fail(e.to_string()))?;
    extra.push(("extra/reference-outputs.csv".to_string(), csv, false));
    let readme = format!(
        "Reference run of {id}\n\n\
         Tool: {tool} (this repository's harness), fixed-step co-simulation master.\n\
         Grid: start {start} s, stop {stop} s, communication step {step} s; one row per step,\n\
         outputs recorded after each fmi2DoStep, start values as in modelDescription.xml.\n\
         Inputs: {inputs}.\n\
         Files: reference-outputs.csv (time and every output){more}.\n",
        id = entry.identifier,
        tool = concat!("kneebench ", env!("CARGO_PKG_VERSION")),
        inputs = if entry.reference_inputs.is_some() {
            "reference-inputs.csv, held constant between samples (sample-and-hold)"
        } else {
            "none (the model has no inputs)"
        },
        more = if entry.reference_inputs.is_some() {
            ", reference-inputs.csv"
        } else {
            ""
        },
    );
    extra.push(("extra/README.txt".to_string(), readme.into_bytes(), false));
    Ok(extra)
}
