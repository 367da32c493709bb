//! Loading an FMU: safe extraction, model description, binary and FMI functions.
//!
//! An FMU archive is untrusted input. [`Fmu::load`] extracts it into a private temporary
//! directory (mode 0700, removed when the last handle to the FMU is dropped) and refuses, with a
//! [`LoadError`] that names the entry:
//!
//! - entry names that could escape the directory: `..` components, absolute paths, Windows drive
//!   prefixes (`C:`), backslashes, NUL bytes;
//! - symbolic links (Unix mode `S_IFLNK` in the entry's external attributes);
//! - more than [`ArchiveLimits::max_entries`] entries, an entry larger than
//!   [`ArchiveLimits::max_entry_bytes`] or a total larger than [`ArchiveLimits::max_total_bytes`]:
//!   the limits are checked against the bytes actually decompressed, not only the sizes the
//!   archive claims (a zip bomb is stopped after `limit + 1` bytes);
//! - duplicate entries (files are created with `O_EXCL`, so nothing is ever overwritten and no
//!   pre-existing link is followed).
//!
//! Then `modelDescription.xml` is parsed with the `model_description` crate, a `CoSimulation`
//! element is required, and `binaries/linux64/<modelIdentifier>.so` is loaded with
//! `RTLD_NOW | RTLD_LOCAL` (as fmpy's ctypes does). Every common and co-simulation function is
//! resolved; the FMU-state, serialization and derivative functions are optional.
//!
//! FMUs whose binary needs symbols of a host runtime (PythonFMU exports need libpython) can be
//! loaded after preloading that runtime globally: [`LoadOptions::preload`].

use std::ffi::{CStr, CString, c_void};
use std::fs;
use std::io::{self, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};

use model_description::ModelDescription;
use zip::CompressionMethod;

use crate::fmi2::*;
use crate::isolate::remote::RemoteFmu;

mod shared;
use crate::isolate::{HostFailure, HostOptions, Isolation};

/// Bounds on what an archive may contain.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ArchiveLimits {
    /// Maximum number of entries (files and directories).
    pub max_entries: usize,
    /// Maximum decompressed size of one entry, in bytes.
    pub max_entry_bytes: u64,
    /// Maximum decompressed size of all entries together, in bytes.
    pub max_total_bytes: u64,
}

impl Default for ArchiveLimits {
    /// 10 000 entries, 1 GiB per entry, 2 GiB in total.
    fn default() -> Self {
        ArchiveLimits {
            max_entries: 10_000,
            max_entry_bytes: 1 << 30,
            max_total_bytes: 2 << 30,
        }
    }
}

/// What one run may still extract: the [`ArchiveLimits`] counted across every archive the run
/// opens (an SSP and the FMUs inside it share one budget, so an archive inside an archive gets
/// what is left, not a fresh allowance). The per-entry limit applies to each entry.
#[derive(Debug)]
pub struct ArchiveBudget {
    limits: ArchiveLimits,
    entries: AtomicUsize,
    bytes: AtomicU64,
}

impl ArchiveBudget {
    /// A full budget of `limits`.
    pub fn new(limits: ArchiveLimits) -> Arc<ArchiveBudget> {
        Arc::new(ArchiveBudget {
            limits,
            entries: AtomicUsize::new(0),
            bytes: AtomicU64::new(0),
        })
    }
    /// The limits.
    pub fn limits(&self) -> &ArchiveLimits {
        &self.limits
    }
    /// Entries extracted so far.
    pub fn used_entries(&self) -> usize {
        self.entries.load(Ordering::Relaxed)
    }
    /// Decompressed bytes written so far.
    pub fn used_bytes(&self) -> u64 {
        self.bytes.load(Ordering::Relaxed)
    }
}

/// Options of [`Fmu::load`].
#[derive(Debug, Clone, Default)]
pub struct LoadOptions {
    /// Bounds on the archive.
    pub limits: ArchiveLimits,
    /// The budget of the run this load belongs to (see [`ArchiveBudget`]); `None`: a fresh one
    /// of [`limits`](Self::limits) for this archive alone. [`crate::ssp::load_system`] sets one
    /// for the SSP and its FMUs.
    pub budget: Option<Arc<ArchiveBudget>>,
    /// Shared libraries opened with `RTLD_NOW | RTLD_GLOBAL` before the FMU's binary, so that
    /// their symbols resolve the binary's undefined ones (for example the `libpython3.x.so` a
    /// PythonFMU export expects from its host). They stay loaded while the FMU is. With
    /// isolation, the host process loads them.
    pub preload: Vec<PathBuf>,
    /// Where the binary runs: in this process (the default) or in host processes
    /// ([`crate::isolate`]).
    pub isolation: Isolation,
    /// How host processes are found, started and watched (with isolation).
    pub host: HostOptions,
    /// What is extracted and how binaries are loaded: only what a run needs and each distinct
    /// binary once per process (the default), or everything and a copy per FMU.
    pub binaries: Binaries,
    /// For a binary with an embedded CPython (a PythonFMU export): whether the thread that
    /// calls it keeps a Python thread state (the default) or each call makes its own (in this
    /// process and in host processes alike).
    pub python_thread_state: PythonThreadState,
}

/// How the FMI calls of a binary with an embedded CPython (a PythonFMU export, which takes the
/// GIL with `PyGILState_Ensure` in every call) get their Python thread state; module
/// [`embedded_python`](crate::embedded_python). Other binaries are not affected.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum PythonThreadState {
    /// Each thread that calls such a binary and has no Python thread state gets one, kept while
    /// instances of the binary called from that thread live (the GIL released between calls),
    /// so that the binary's `PyGILState_Ensure` only takes the GIL: about ten times less per
    /// call for a PythonFMU export.
    #[default]
    Kept,
    /// The binary's own behaviour: in a thread without a Python thread state each call creates
    /// one and destroys it again (the baseline [`Kept`](Self::Kept) is tested against).
    PerCall,
}

/// How [`Fmu::load`] extracts an FMU and loads its binary.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Binaries {
    /// The model description and `resources/` are extracted into the FMU's directory; the
    /// binary is extracted and loaded once per process for every FMU that carries the same
    /// one (compared byte for byte), and an FMU stored uncompressed in an SSP is read in place
    /// (module `load::shared`). FMUs that declare `canBeInstantiatedOnlyOncePerProcess`, run
    /// isolated or need preloaded libraries get their own copy of the binary.
    #[default]
    Shared,
    /// Every entry extracted into the FMU's directory and its own copy of the binary loaded
    /// (what loading did before [`Shared`](Self::Shared); the baseline it is tested against).
    Private,
}

/// Why an FMU could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    /// Reading or writing a file failed.
    #[error("{context} '{}': {source}", path.display())]
    Io {
        /// What was being done.
        context: &'static str,
        /// The file.
        path: PathBuf,
        /// The cause.
        source: io::Error,
    },
    /// The file is not a readable zip archive, or an entry could not be read.
    #[error("'{}' is not a valid FMU archive{}: {source}", archive.display(), entry.as_ref().map(|e| format!(" (entry '{e}')")).unwrap_or_default())]
    Zip {
        /// The archive.
        archive: PathBuf,
        /// The entry being read, if any.
        entry: Option<String>,
        /// The cause.
        source: zip::result::ZipError,
    },
    /// An entry name that could escape the extraction directory.
    #[error("refusing archive entry '{entry}': {reason}")]
    UnsafeEntryName {
        /// The entry name as stored (lossily decoded).
        entry: String,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// A file entry compressed with a method other than store or deflate.
    #[error(
        "refusing archive entry '{entry}': it is compressed with {method}; kneebench reads \
         stored and deflated entries (zip the FMU again with deflate)"
    )]
    UnsupportedCompression {
        /// The entry name.
        entry: String,
        /// The method's name and number ("Bzip2 (method 12)"), or its number alone for a
        /// number no method was given ("method 77").
        method: String,
    },
    /// A symbolic link entry.
    #[error("refusing archive entry '{entry}': symbolic links are not allowed in an FMU")]
    Symlink {
        /// The entry name.
        entry: String,
    },
    /// An entry that decompresses to more than the per-entry limit.
    #[error("refusing archive entry '{entry}': it decompresses to more than {limit} bytes")]
    EntryTooLarge {
        /// The entry name.
        entry: String,
        /// The limit in bytes.
        limit: u64,
    },
    /// The entries together (of every archive of the run) decompress to more than the total
    /// limit.
    #[error(
        "refusing archive: entries up to '{entry}' decompress to more than {limit} bytes in total (counting every archive of this run, nested ones included)"
    )]
    TotalTooLarge {
        /// The entry at which the limit was passed.
        entry: String,
        /// The limit in bytes.
        limit: u64,
    },
    /// Too many entries (in every archive of the run together).
    #[error(
        "refusing archive: {count} entries (limit {limit}, counting every archive of this run, nested ones included)"
    )]
    TooManyEntries {
        /// Number of entries in the archive.
        count: usize,
        /// The limit.
        limit: usize,
    },
    /// The same path appears twice (or a file and a directory share a path).
    #[error("refusing archive entry '{entry}': duplicate path")]
    DuplicateEntry {
        /// The entry name.
        entry: String,
    },
    /// No `modelDescription.xml` at the root of the archive.
    #[error("the archive has no modelDescription.xml at its root")]
    MissingModelDescription,
    /// `modelDescription.xml` could not be parsed.
    #[error("modelDescription.xml: {0}")]
    ModelDescription(String),
    /// The model description has no `CoSimulation` element.
    #[error(
        "the FMU does not support co-simulation (no CoSimulation element in modelDescription.xml)"
    )]
    NoCoSimulation,
    /// The binary for this platform is not in the archive.
    #[error("the FMU has no binary for linux64: expected '{expected}' in the archive")]
    MissingBinary {
        /// The path inside the archive.
        expected: String,
    },
    /// `dlopen` failed (of the FMU binary or of a preloaded library).
    #[error("cannot load shared library '{}': {}{hint}", path.display(), with_cause(source))]
    Library {
        /// The library.
        path: PathBuf,
        /// The cause.
        source: libloading::Error,
        /// A hint for the user.
        hint: &'static str,
    },
    /// A required FMI function is not exported by the binary.
    #[error("the FMU binary does not export the required function {name}")]
    MissingFunction {
        /// The function name.
        name: &'static str,
    },
    /// `fmi2GetVersion` does not return "2.0".
    #[error("the FMU binary reports FMI version '{0}', expected '2.0'")]
    WrongVersion(String),
    /// The host process that loads an isolated FMU's binary failed.
    #[error("loading '{}' in a host process: {failure}", binary.display())]
    Host {
        /// The binary.
        binary: PathBuf,
        /// How the host failed.
        failure: HostFailure,
    },
    /// The host process could not load an isolated FMU's binary.
    #[error("the host process cannot load '{}': {message}", binary.display())]
    HostLoad {
        /// The binary.
        binary: PathBuf,
        /// The host's error.
        message: String,
    },
    /// Isolation was asked for and no host executable was found.
    #[error(
        "FMU isolation needs the host executable 'kneebench-fmu-host' (built with kneebench; \
         set KNEEBENCH_FMU_HOST or LoadOptions::host.helper); tried: {tried}"
    )]
    HelperNotFound {
        /// The paths tried.
        tried: String,
    },
}

/// `libloading::Error` displays as "dlopen failed" and keeps `dlerror()`'s text (the missing
/// file or the undefined symbol) in its `source()`: show both.
fn with_cause(e: &libloading::Error) -> String {
    match std::error::Error::source(e) {
        Some(cause) => format!("{e}: {cause}"),
        None => e.to_string(),
    }
}

fn io_err<'a>(context: &'static str, path: &'a Path) -> impl FnOnce(io::Error) -> LoadError + 'a {
    move |source| LoadError::Io {
        context,
        path: path.to_path_buf(),
        source,
    }
}

/// Checks one archive entry name and returns the relative path it maps to (`None` for the
/// archive root, e.g. an entry `./`).
///
/// Refuses `..` components, absolute paths, drive prefixes, backslashes and NUL bytes.
pub fn sanitize_entry_name(name: &str) -> Result<Option<PathBuf>, LoadError> {
    let refuse = |reason| LoadError::UnsafeEntryName {
        entry: name.to_string(),
        reason,
    };
    if name.is_empty() {
        return Err(refuse("empty name"));
    }
    if name.contains('\0') {
        return Err(refuse("NUL byte in the name"));
    }
    if name.contains('\\') {
        return Err(refuse("backslash in the name (Windows path separator)"));
    }
    if name.starts_with('/') {
        return Err(refuse("absolute path"));
    }
    let bytes = name.as_bytes();
    if bytes.len() >= 2 && bytes[0].is_ascii_alphabetic() && bytes[1] == b':' {
        return Err(refuse("drive prefix (absolute Windows path)"));
    }
    let mut out = PathBuf::new();
    for component in name.split('/') {
        match component {
            "" | "." => {}
            ".." => return Err(refuse("'..' component escapes the extraction directory")),
            c => out.push(c),
        }
    }
    Ok(if out.as_os_str().is_empty() {
        None
    } else {
        Some(out)
    })
}

const S_IFMT: u32 = 0o170000;
const S_IFLNK: u32 = 0o120000;

/// Extracts `archive` into `dest` (an existing, empty, private directory) within `limits`.
///
/// Returns the relative paths of the extracted files.
pub fn extract_archive(
    archive: &Path,
    dest: &Path,
    limits: &ArchiveLimits,
) -> Result<Vec<PathBuf>, LoadError> {
    extract_archive_within(archive, dest, &ArchiveBudget::new(*limits))
}

/// Extracts `archive` into `dest` (an existing, empty, private directory), counting its entries
/// and bytes against `budget` (which other archives of the same run share).
///
/// Returns the relative paths of the extracted files.
pub fn extract_archive_within(
    archive: &Path,
    dest: &Path,
    budget: &ArchiveBudget,
) -> Result<Vec<PathBuf>, LoadError> {
    let mut zip = open_archive(&ArchiveSource::File(archive.to_path_buf()), budget)?;
    Ok(extract_entries(&mut zip, archive, dest, budget, &|_| true)?.extracted)
}

/// An archive opened for reading: a file, or a window of one (an FMU stored uncompressed in an
/// SSP, read in place).
pub(crate) type OpenArchive = zip::ZipArchive<io::BufReader<shared::Window>>;

/// Where an archive's bytes are.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum ArchiveSource {
    /// A file of its own.
    File(PathBuf),
    /// The bytes `start..start + len` of `container` (an entry stored uncompressed there),
    /// known as `name` (the container's path followed by the entry's name).
    Nested {
        container: PathBuf,
        start: u64,
        len: u64,
        name: PathBuf,
    },
}

impl ArchiveSource {
    /// The path errors and [`Fmu::source_path`] name.
    pub(crate) fn name(&self) -> &Path {
        match self {
            ArchiveSource::File(p) => p,
            ArchiveSource::Nested { name, .. } => name,
        }
    }
}

/// Opens the archive at `source` and counts its entries against `budget`.
pub(crate) fn open_archive(
    source: &ArchiveSource,
    budget: &ArchiveBudget,
) -> Result<OpenArchive, LoadError> {
    let archive = source.name();
    let window = shared::Window::open(source).map_err(io_err("cannot open", archive))?;
    let zip =
        zip::ZipArchive::new(io::BufReader::new(window)).map_err(|source| LoadError::Zip {
            archive: archive.to_path_buf(),
            entry: None,
            source,
        })?;
    let before = budget.entries.fetch_add(zip.len(), Ordering::Relaxed);
    if before + zip.len() > budget.limits.max_entries {
        return Err(LoadError::TooManyEntries {
            count: before + zip.len(),
            limit: budget.limits.max_entries,
        });
    }
    Ok(zip)
}

/// What [`extract_entries`] did.
pub(crate) struct Extracted {
    /// The relative paths of the files written.
    pub(crate) extracted: Vec<PathBuf>,
    /// The files checked and left in the archive: (relative path, entry index).
    pub(crate) left: Vec<(PathBuf, usize)>,
}

/// Checks every entry of `zip` (names, links, duplicates, sizes) and extracts the files whose
/// relative path `wanted` accepts into `dest` (an existing, empty, private directory). An
/// extracted file counts the bytes it decompresses to against `budget` (a zip bomb is stopped
/// after `limit + 1` bytes); a file left in the archive counts the size its entry declares
/// (whoever reads it later must find exactly that size: [`read_declared`]).
pub(crate) fn extract_entries<R: Read + io::Seek>(
    zip: &mut zip::ZipArchive<R>,
    archive: &Path,
    dest: &Path,
    budget: &ArchiveBudget,
    wanted: &dyn Fn(&Path) -> bool,
) -> Result<Extracted, LoadError> {
    let limits = &budget.limits;
    let zip_err = |entry: Option<String>| {
        move |source| LoadError::Zip {
            archive: archive.to_path_buf(),
            entry,
            source,
        }
    };
    let mut extracted = Vec::new();
    let mut left: Vec<(PathBuf, usize)> = Vec::new();
    // Every file's path, extracted or left: a second entry of one path is refused (an
    // extracted file is also opened with `create_new`, so nothing is ever overwritten).
    let mut files = std::collections::HashSet::new();
    for i in 0..zip.len() {
        let mut entry = zip.by_index(i).map_err(zip_err(None))?;
        let name = String::from_utf8_lossy(entry.name_raw()).into_owned();
        let Some(rel) = sanitize_entry_name(&name)? else {
            continue;
        };
        if let Some(mode) = entry.unix_mode()
            && mode & S_IFMT == S_IFLNK
        {
            return Err(LoadError::Symlink { entry: name });
        }
        let target = dest.join(&rel);
        let is_dir = entry.is_dir() || name.ends_with('/');
        if is_dir && !wanted(&rel) {
            continue;
        }
        if is_dir {
            fs::create_dir_all(&target).map_err(io_err("cannot create directory", &target))?;
            continue;
        }
        // The zip crate is built with the deflate codec only, as FMU tools write them: another
        // method (bzip2, LZMA, zstd...) is refused by name before anything is written, not
        // met later as an I/O error of the target file ("cannot extract to ...").
        let method = entry.compression();
        if !matches!(
            method,
            CompressionMethod::Stored | CompressionMethod::Deflated
        ) {
            let number = shared::method_code(method);
            return Err(LoadError::UnsupportedCompression {
                entry: name,
                method: match CompressionMethod::name_from_u16(number) {
                    "Unknown" => format!("method {number}"),
                    known => format!("{known} (method {number})"),
                },
            });
        }
        if entry.size() > limits.max_entry_bytes {
            return Err(LoadError::EntryTooLarge {
                entry: name,
                limit: limits.max_entry_bytes,
            });
        }
        if !files.insert(rel.clone()) {
            return Err(LoadError::DuplicateEntry { entry: name });
        }
        if !wanted(&rel) {
            // Left in the archive: checked like the others, counted at its declared size.
            let total = budget.bytes.fetch_add(entry.size(), Ordering::Relaxed) + entry.size();
            if total > limits.max_total_bytes {
                return Err(LoadError::TotalTooLarge {
                    entry: name,
                    limit: limits.max_total_bytes,
                });
            }
            left.push((rel, i));
            continue;
        }
        if let Some(parent) = target.parent() {
            fs::create_dir_all(parent).map_err(io_err("cannot create directory", parent))?;
        }
        let out = fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&target)
            .map_err(|e| {
                if e.kind() == io::ErrorKind::AlreadyExists {
                    LoadError::DuplicateEntry {
                        entry: name.clone(),
                    }
                } else {
                    LoadError::Io {
                        context: "cannot create",
                        path: target.clone(),
                        source: e,
                    }
                }
            })?;
        let mut out = io::BufWriter::new(out);
        // Copy at most limit + 1 bytes: more means the entry is too large, whatever it claims.
        let remaining_total = limits.max_total_bytes.saturating_sub(budget.used_bytes());
        let cap = limits.max_entry_bytes.min(remaining_total);
        let copied = copy_bounded(&mut entry, &mut out, cap + 1).map_err(|e| {
            if e.kind() == io::ErrorKind::InvalidData || e.kind() == io::ErrorKind::UnexpectedEof {
                LoadError::Zip {
                    archive: archive.to_path_buf(),
                    entry: Some(name.clone()),
                    source: zip::result::ZipError::Io(e),
                }
            } else {
                LoadError::Io {
                    context: "cannot extract to",
                    path: target.clone(),
                    source: e,
                }
            }
        })?;
        if copied > cap {
            drop(out);
            let _ = fs::remove_file(&target);
            return Err(if copied > limits.max_entry_bytes {
                LoadError::EntryTooLarge {
                    entry: name,
                    limit: limits.max_entry_bytes,
                }
            } else {
                LoadError::TotalTooLarge {
                    entry: name,
                    limit: limits.max_total_bytes,
                }
            });
        }
        out.flush().map_err(io_err("cannot write", &target))?;
        budget.bytes.fetch_add(copied, Ordering::Relaxed);
        extracted.push(rel);
    }
    Ok(Extracted { extracted, left })
}

/// The bytes of entry `index` of `zip` (left in the archive by [`extract_entries`], which
/// counted its declared size): decompressed, checked against its CRC, and refused unless it
/// decompresses to exactly the size it declares.
pub(crate) fn read_declared<R: Read + io::Seek>(
    zip: &mut zip::ZipArchive<R>,
    archive: &Path,
    index: usize,
) -> Result<Vec<u8>, LoadError> {
    let mut entry = zip.by_index(index).map_err(|source| LoadError::Zip {
        archive: archive.to_path_buf(),
        entry: None,
        source,
    })?;
    let name = String::from_utf8_lossy(entry.name_raw()).into_owned();
    let declared = entry.size();
    let mut bytes = Vec::with_capacity(declared as usize);
    let read = copy_bounded(&mut entry, &mut bytes, declared + 1);
    let zip_err = |e: io::Error| LoadError::Zip {
        archive: archive.to_path_buf(),
        entry: Some(name.clone()),
        source: zip::result::ZipError::Io(e),
    };
    let n = read.map_err(zip_err)?;
    if n != declared {
        return Err(zip_err(io::Error::new(
            io::ErrorKind::InvalidData,
            format!("the entry decompresses to a size other than the {declared} bytes it declares"),
        )));
    }
    Ok(bytes)
}

/// Extracts entry `index` of `zip` (left in the archive by [`extract_entries`]) to `target`,
/// checked as [`read_declared`] checks it, creating the directories on the way.
pub(crate) fn extract_declared<R: Read + io::Seek>(
    zip: &mut zip::ZipArchive<R>,
    archive: &Path,
    index: usize,
    target: &Path,
) -> Result<(), LoadError> {
    let bytes = read_declared(zip, archive, index)?;
    if let Some(parent) = target.parent() {
        fs::create_dir_all(parent).map_err(io_err("cannot create directory", parent))?;
    }
    fs::write(target, bytes).map_err(io_err("cannot extract to", target))
}

fn copy_bounded(r: &mut impl Read, w: &mut impl Write, max: u64) -> io::Result<u64> {
    let mut buf = [0u8; 64 * 1024];
    let mut n: u64 = 0;
    loop {
        let want = (max - n).min(buf.len() as u64) as usize;
        if want == 0 {
            return Ok(n);
        }
        let got = match r.read(&mut buf[..want]) {
            Ok(0) => return Ok(n),
            Ok(k) => k,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        };
        w.write_all(&buf[..got])?;
        n += got as u64;
    }
}

/// Percent-encodes an absolute path as a `file://` URI, as Python's `pathlib.Path.as_uri`
/// does: unreserved characters and `/` stay, every other byte becomes `%XX`.
pub fn file_uri(path: &Path) -> String {
    use std::os::unix::ffi::OsStrExt;
    let mut uri = String::from("file://");
    for &b in path.as_os_str().as_bytes() {
        if b.is_ascii_alphanumeric() || matches!(b, b'/' | b'-' | b'_' | b'.' | b'~') {
            uri.push(b as char);
        } else {
            uri.push_str(&format!("%{b:02X}"));
        }
    }
    uri
}

/// The resolved FMI 2.0 functions of a binary.
///
/// Required functions are plain function pointers (loading fails without them); the FMU-state,
/// serialization and derivative functions are `Option`s.
#[allow(missing_docs)]
#[derive(Clone, Copy)]
pub struct Functions {
    pub get_types_platform: fmi2GetTypesPlatformTYPE,
    pub get_version: fmi2GetVersionTYPE,
    pub set_debug_logging: fmi2SetDebugLoggingTYPE,
    pub instantiate: fmi2InstantiateTYPE,
    pub free_instance: fmi2FreeInstanceTYPE,
    pub setup_experiment: fmi2SetupExperimentTYPE,
    pub enter_initialization_mode: fmi2ComponentOnlyTYPE,
    pub exit_initialization_mode: fmi2ComponentOnlyTYPE,
    pub terminate: fmi2ComponentOnlyTYPE,
    pub reset: fmi2ComponentOnlyTYPE,
    pub get_real: fmi2GetRealTYPE,
    pub get_integer: fmi2GetIntegerTYPE,
    pub get_boolean: fmi2GetBooleanTYPE,
    pub get_string: fmi2GetStringTYPE,
    pub set_real: fmi2SetRealTYPE,
    pub set_integer: fmi2SetIntegerTYPE,
    pub set_boolean: fmi2SetBooleanTYPE,
    pub set_string: fmi2SetStringTYPE,
    pub do_step: fmi2DoStepTYPE,
    pub cancel_step: fmi2ComponentOnlyTYPE,
    pub get_status: fmi2GetStatusTYPE,
    pub get_real_status: fmi2GetRealStatusTYPE,
    pub get_integer_status: fmi2GetIntegerStatusTYPE,
    pub get_boolean_status: fmi2GetBooleanStatusTYPE,
    pub get_string_status: fmi2GetStringStatusTYPE,
    pub get_fmu_state: Option<fmi2GetFMUstateTYPE>,
    pub set_fmu_state: Option<fmi2SetFMUstateTYPE>,
    pub free_fmu_state: Option<fmi2GetFMUstateTYPE>,
    pub serialized_fmu_state_size: Option<fmi2SerializedFMUstateSizeTYPE>,
    pub serialize_fmu_state: Option<fmi2SerializeFMUstateTYPE>,
    pub deserialize_fmu_state: Option<fmi2DeSerializeFMUstateTYPE>,
    pub get_directional_derivative: Option<fmi2GetDirectionalDerivativeTYPE>,
    pub set_real_input_derivatives: Option<fmi2SetRealInputDerivativesTYPE>,
    pub get_real_output_derivatives: Option<fmi2GetRealOutputDerivativesTYPE>,
}

impl std::fmt::Debug for Functions {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Functions").finish_non_exhaustive()
    }
}

/// Names of the functions every FMI 2.0 co-simulation binary must export.
pub const REQUIRED_FUNCTIONS: &[&str] = &[
    "fmi2GetTypesPlatform",
    "fmi2GetVersion",
    "fmi2SetDebugLogging",
    "fmi2Instantiate",
    "fmi2FreeInstance",
    "fmi2SetupExperiment",
    "fmi2EnterInitializationMode",
    "fmi2ExitInitializationMode",
    "fmi2Terminate",
    "fmi2Reset",
    "fmi2GetReal",
    "fmi2GetInteger",
    "fmi2GetBoolean",
    "fmi2GetString",
    "fmi2SetReal",
    "fmi2SetInteger",
    "fmi2SetBoolean",
    "fmi2SetString",
    "fmi2DoStep",
    "fmi2CancelStep",
    "fmi2GetStatus",
    "fmi2GetRealStatus",
    "fmi2GetIntegerStatus",
    "fmi2GetBooleanStatus",
    "fmi2GetStringStatus",
];

/// Names of the optional functions (FMU state, serialization, derivatives).
pub const OPTIONAL_FUNCTIONS: &[&str] = &[
    "fmi2GetFMUstate",
    "fmi2SetFMUstate",
    "fmi2FreeFMUstate",
    "fmi2SerializedFMUstateSize",
    "fmi2SerializeFMUstate",
    "fmi2DeSerializeFMUstate",
    "fmi2GetDirectionalDerivative",
    "fmi2SetRealInputDerivatives",
    "fmi2GetRealOutputDerivatives",
];

impl Functions {
    fn resolve(lib: &libloading::Library) -> Result<Functions, LoadError> {
        /// # Safety
        /// `T` must be the function-pointer type of the symbol `name`.
        unsafe fn req<T: Copy>(
            lib: &libloading::Library,
            name: &'static str,
        ) -> Result<T, LoadError> {
            let cname = format!("{name}\0");
            // SAFETY: the caller names the FMI function whose typedef is T.
            unsafe { lib.get::<T>(cname.as_bytes()) }
                .map(|s| *s)
                .map_err(|_| LoadError::MissingFunction { name })
        }
        /// # Safety
        /// As for `req`.
        unsafe fn opt<T: Copy>(lib: &libloading::Library, name: &'static str) -> Option<T> {
            // SAFETY: as for `req`.
            unsafe { req(lib, name) }.ok()
        }
        // SAFETY: every symbol is read with the function-pointer type of fmi2FunctionTypes.h.
        unsafe {
            Ok(Functions {
                get_types_platform: req(lib, "fmi2GetTypesPlatform")?,
                get_version: req(lib, "fmi2GetVersion")?,
                set_debug_logging: req(lib, "fmi2SetDebugLogging")?,
                instantiate: req(lib, "fmi2Instantiate")?,
                free_instance: req(lib, "fmi2FreeInstance")?,
                setup_experiment: req(lib, "fmi2SetupExperiment")?,
                enter_initialization_mode: req(lib, "fmi2EnterInitializationMode")?,
                exit_initialization_mode: req(lib, "fmi2ExitInitializationMode")?,
                terminate: req(lib, "fmi2Terminate")?,
                reset: req(lib, "fmi2Reset")?,
                get_real: req(lib, "fmi2GetReal")?,
                get_integer: req(lib, "fmi2GetInteger")?,
                get_boolean: req(lib, "fmi2GetBoolean")?,
                get_string: req(lib, "fmi2GetString")?,
                set_real: req(lib, "fmi2SetReal")?,
                set_integer: req(lib, "fmi2SetInteger")?,
                set_boolean: req(lib, "fmi2SetBoolean")?,
                set_string: req(lib, "fmi2SetString")?,
                do_step: req(lib, "fmi2DoStep")?,
                cancel_step: req(lib, "fmi2CancelStep")?,
                get_status: req(lib, "fmi2GetStatus")?,
                get_real_status: req(lib, "fmi2GetRealStatus")?,
                get_integer_status: req(lib, "fmi2GetIntegerStatus")?,
                get_boolean_status: req(lib, "fmi2GetBooleanStatus")?,
                get_string_status: req(lib, "fmi2GetStringStatus")?,
                get_fmu_state: opt(lib, "fmi2GetFMUstate"),
                set_fmu_state: opt(lib, "fmi2SetFMUstate"),
                free_fmu_state: opt(lib, "fmi2FreeFMUstate"),
                serialized_fmu_state_size: opt(lib, "fmi2SerializedFMUstateSize"),
                serialize_fmu_state: opt(lib, "fmi2SerializeFMUstate"),
                deserialize_fmu_state: opt(lib, "fmi2DeSerializeFMUstate"),
                get_directional_derivative: opt(lib, "fmi2GetDirectionalDerivative"),
                set_real_input_derivatives: opt(lib, "fmi2SetRealInputDerivatives"),
                get_real_output_derivatives: opt(lib, "fmi2GetRealOutputDerivatives"),
            })
        }
    }
}

/// A binary loaded into this process: its library (and the libraries preloaded for it) and
/// its resolved functions.
pub(crate) struct LocalBinary {
    pub(crate) functions: Functions,
    pub(crate) version: String,
    pub(crate) types_platform: String,
    pub(crate) missing_optional: Vec<&'static str>,
    /// The binary's embedded CPython, if it has one.
    pub(crate) python: Option<crate::embedded_python::PythonApi>,
    // Drop order: the binary first, then the preloaded libraries.
    _library: libloading::Library,
    _preloaded: Vec<libloading::os::unix::Library>,
}

impl LocalBinary {
    /// Preloads `preload` globally, loads `binary` with `RTLD_NOW | RTLD_LOCAL` and resolves
    /// the FMI functions (the version is not checked here).
    pub(crate) fn open(binary: &Path, preload: &[PathBuf]) -> Result<LocalBinary, LoadError> {
        let mut preloaded = Vec::new();
        for lib in preload {
            // SAFETY: loading a library runs its initializers; the user asked for it.
            let handle = unsafe {
                libloading::os::unix::Library::open(
                    Some(lib),
                    libloading::os::unix::RTLD_NOW | libloading::os::unix::RTLD_GLOBAL,
                )
            }
            .map_err(|source| LoadError::Library {
                path: lib.clone(),
                source,
                hint: "",
            })?;
            preloaded.push(handle);
        }
        // SAFETY: loading the FMU's binary runs its initializers; this is what importing an FMU
        // means. RTLD_LOCAL keeps its symbols from clashing with other FMUs.
        let library: libloading::Library = unsafe {
            libloading::os::unix::Library::open(
                Some(binary),
                libloading::os::unix::RTLD_NOW | libloading::os::unix::RTLD_LOCAL,
            )
        }
        .map_err(|source| LoadError::Library {
            path: binary.to_path_buf(),
            source,
            hint: " (if the binary expects symbols from a host runtime such as libpython, preload \
                   that library: LoadOptions::preload / --preload)",
        })?
        .into();
        let functions = Functions::resolve(&library)?;
        // SAFETY: fmi2GetVersion and fmi2GetTypesPlatform take no arguments and return static
        // strings.
        let (version, types_platform) = unsafe {
            (
                cstr_lossy((functions.get_version)()),
                cstr_lossy((functions.get_types_platform)()),
            )
        };
        let python = crate::embedded_python::PythonApi::detect(&library, binary);
        let missing_optional = OPTIONAL_FUNCTIONS
            .iter()
            .copied()
            .filter(|name| {
                let cname = format!("{name}\0");
                // SAFETY: only checks that the symbol exists.
                unsafe { library.get::<*const c_void>(cname.as_bytes()) }.is_err()
            })
            .collect();
        Ok(LocalBinary {
            functions,
            version,
            types_platform,
            missing_optional,
            python,
            _library: library,
            _preloaded: preloaded,
        })
    }
}

/// Where an FMU's binary runs.
pub(crate) enum Exec {
    /// Loaded into this process.
    Local(LocalExec),
    /// Loaded by host processes, one per instance.
    Remote(Box<RemoteFmu>),
}

/// A binary loaded into this process: the FMU's own copy, or one shared with the other FMUs
/// that carry the same binary ([`Binaries::Shared`]).
pub(crate) enum LocalExec {
    Own(Box<LocalBinary>),
    Shared(Arc<shared::SharedBinary>),
}

impl std::ops::Deref for LocalExec {
    type Target = LocalBinary;
    fn deref(&self) -> &LocalBinary {
        match self {
            LocalExec::Own(b) => b,
            LocalExec::Shared(s) => &s.local,
        }
    }
}

/// What an instance keeps alive: the binary (or its host's description) and the extraction
/// directory with its resources.
pub(crate) struct FmuShared {
    pub(crate) md: ModelDescription,
    pub(crate) resource_uri: CString,
    pub(crate) guid: CString,
    pub(crate) source: PathBuf,
    pub(crate) binary: PathBuf,
    /// The in-process binary's embedded CPython, if it has one.
    pub(crate) python: Option<crate::embedded_python::PythonApi>,
    /// Whether its thread states are kept ([`PythonThreadState::Kept`]).
    pub(crate) keep_python_thread_state: bool,
    // Drop order: the binary first, then the directory.
    pub(crate) exec: Exec,
    dir: tempfile::TempDir,
}

impl FmuShared {
    pub(crate) fn missing_optional(&self) -> &[&'static str] {
        match &self.exec {
            Exec::Local(b) => &b.missing_optional,
            Exec::Remote(r) => &r.probe.missing_optional,
        }
    }
}

/// A loaded FMU: extracted archive, parsed model description and resolved functions.
///
/// Cheap to clone (a shared handle). The extraction directory and the binary stay alive while
/// any clone or any [`Instance`](crate::Instance) of it exists.
#[derive(Clone)]
pub struct Fmu {
    pub(crate) shared: Arc<FmuShared>,
}

impl std::fmt::Debug for Fmu {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Fmu")
            .field("source", &self.shared.source)
            .field("model_name", &self.shared.md.model_name)
            .field("dir", &self.shared.dir.path())
            .finish()
    }
}

/// Extracts an archive into a fresh private directory and parses its model description,
/// without loading the binary. Used by [`Fmu::load`] and by validation.
pub fn extract_and_parse(
    path: &Path,
    limits: &ArchiveLimits,
) -> Result<(tempfile::TempDir, ModelDescription), LoadError> {
    extract_and_parse_within(path, &ArchiveBudget::new(*limits))
}

/// [`extract_and_parse`] counting against a run's `budget`.
pub fn extract_and_parse_within(
    path: &Path,
    budget: &ArchiveBudget,
) -> Result<(tempfile::TempDir, ModelDescription), LoadError> {
    let source = ArchiveSource::File(path.to_path_buf());
    let mut zip = open_archive(&source, budget)?;
    let (dir, md, _) = extract_and_parse_selected(&mut zip, path, budget, &|_| true)?;
    Ok((dir, md))
}

/// The model description of the FMU archive at `path`, without extracting the rest: every entry
/// is checked as [`extract_and_parse`] checks it (names, links, duplicates, sizes, `limits`),
/// only `modelDescription.xml` is written out and parsed, and the description is
/// [`extract_and_parse`]'s (tested in `tests/tests/sweep.rs`,
/// `model_descriptions_read_alone_are_those_of_the_whole_archives`). What a scenario's SSD
/// needs of its FMUs: their binaries, megabytes, were extracted for it and removed again.
pub fn read_model_description(
    path: &Path,
    limits: &ArchiveLimits,
) -> Result<ModelDescription, LoadError> {
    let budget = ArchiveBudget::new(*limits);
    let source = ArchiveSource::File(path.to_path_buf());
    let mut zip = open_archive(&source, &budget)?;
    let description = Path::new("modelDescription.xml");
    let (_dir, md, _) =
        extract_and_parse_selected(&mut zip, path, &budget, &|rel| rel == description)?;
    Ok(md)
}

/// Extracts the entries `wanted` accepts into a fresh private directory and parses the model
/// description (which `wanted` must accept); also returns what was left in the archive.
pub(crate) fn extract_and_parse_selected<R: Read + io::Seek>(
    zip: &mut zip::ZipArchive<R>,
    path: &Path,
    budget: &ArchiveBudget,
    wanted: &dyn Fn(&Path) -> bool,
) -> Result<(tempfile::TempDir, ModelDescription, Extracted), LoadError> {
    let dir = crate::tempdirs::create("fmu")
        .map_err(io_err("cannot create a temporary directory for", path))?;
    {
        use std::os::unix::fs::PermissionsExt;
        fs::set_permissions(dir.path(), fs::Permissions::from_mode(0o700))
            .map_err(io_err("cannot restrict permissions of", dir.path()))?;
    }
    let extracted = extract_entries(zip, path, dir.path(), budget, wanted)?;
    let md_path = dir.path().join("modelDescription.xml");
    // Refused unread past the reader's bound (the archive may hold up to the entry limit).
    if let Ok(meta) = fs::metadata(&md_path) {
        let limit = model_description::read::MAX_DOCUMENT_BYTES;
        if meta.len() > limit as u64 {
            return Err(LoadError::ModelDescription(format!(
                "the document is {} bytes long (limit {limit})",
                meta.len()
            )));
        }
    }
    let bytes = match fs::read(&md_path) {
        Ok(b) => b,
        Err(e) if e.kind() == io::ErrorKind::NotFound => {
            return Err(LoadError::MissingModelDescription);
        }
        Err(e) => return Err(io_err("cannot read", &md_path)(e)),
    };
    let md = parse_model_description(&bytes)?;
    Ok((dir, md, extracted))
}

/// Parses `modelDescription.xml` bytes (UTF-8, a leading byte-order mark is skipped).
pub fn parse_model_description(bytes: &[u8]) -> Result<ModelDescription, LoadError> {
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    let text = std::str::from_utf8(bytes)
        .map_err(|e| LoadError::ModelDescription(format!("not UTF-8: {e}")))?;
    ModelDescription::from_xml(text).map_err(|e| LoadError::ModelDescription(e.to_string()))
}

impl Fmu {
    /// Extracts, parses and loads the FMU at `path`: into this process, or (with
    /// [`LoadOptions::isolation`]) into a host process that reports the binary's functions and
    /// version and then serves the first instance.
    pub fn load(path: impl AsRef<Path>, options: &LoadOptions) -> Result<Fmu, LoadError> {
        Fmu::load_from(&ArchiveSource::File(path.as_ref().to_path_buf()), options)
    }

    /// [`load`](Self::load) of the archive at `source`.
    pub(crate) fn load_from(
        source: &ArchiveSource,
        options: &LoadOptions,
    ) -> Result<Fmu, LoadError> {
        let budget = options
            .budget
            .clone()
            .unwrap_or_else(|| ArchiveBudget::new(options.limits));
        let path = source.name();
        let mut zip = open_archive(source, &budget)?;
        let sharing = options.binaries == Binaries::Shared && options.preload.is_empty();
        let wanted = |rel: &Path| !sharing || shared::needed_at_run_time(rel);
        let (dir, md, extracted) = extract_and_parse_selected(&mut zip, path, &budget, &wanted)?;
        let cs = md.co_simulation.as_ref().ok_or(LoadError::NoCoSimulation)?;
        let rel = format!("binaries/linux64/{}.so", cs.model_identifier);
        let missing = || LoadError::MissingBinary {
            expected: rel.clone(),
        };
        let rel_path = sanitize_entry_name(&rel)
            .ok()
            .flatten()
            .ok_or_else(missing)?;
        let isolated = options.isolation.isolates(md.generation_tool.as_deref());
        let mut shared_binary = None;
        let binary = if sharing {
            let index = extracted
                .left
                .iter()
                .find(|(p, _)| *p == rel_path)
                .map(|(_, i)| *i)
                .ok_or_else(missing)?;
            if !isolated && cs.can_be_instantiated_only_once_per_process != Some(true) {
                let b = shared::binary(&mut zip, path, index, &cs.model_identifier)?;
                let p = b.path.clone();
                shared_binary = Some(b);
                p
            } else {
                // Its own copy, in the FMU's directory as the plain path puts it.
                let binary = dir.path().join(&rel_path);
                extract_declared(&mut zip, path, index, &binary)?;
                binary
            }
        } else {
            let binary = dir.path().join(&rel_path);
            if !binary.is_file() {
                return Err(missing());
            }
            binary
        };
        let keep = options.python_thread_state == PythonThreadState::Kept;
        let exec = if isolated {
            let helper = crate::isolate::find_helper(options.host.helper.as_deref())?;
            let timeout = options.host.call_timeout;
            let (process, probe) =
                crate::isolate::remote::load(&helper, timeout, &binary, &options.preload, keep)?;
            if probe.version != "2.0" {
                return Err(LoadError::WrongVersion(probe.version));
            }
            Exec::Remote(Box::new(RemoteFmu {
                helper,
                timeout,
                binary: binary.clone(),
                preload: options.preload.clone(),
                keep_python_thread_state: keep,
                probe,
                spare: std::sync::Mutex::new(Some(process)),
            }))
        } else {
            let local = match shared_binary {
                Some(b) => LocalExec::Shared(b),
                None => LocalExec::Own(Box::new(LocalBinary::open(&binary, &options.preload)?)),
            };
            if local.version != "2.0" {
                return Err(LoadError::WrongVersion(local.version.clone()));
            }
            Exec::Local(local)
        };
        let python = match &exec {
            Exec::Local(b) => b.python,
            Exec::Remote(_) => None,
        };
        let resource_uri =
            CString::new(file_uri(&dir.path().join("resources"))).expect("a path has no NUL byte");
        let guid = CString::new(md.guid.clone())
            .map_err(|_| LoadError::ModelDescription("the guid contains a NUL byte".into()))?;
        Ok(Fmu {
            shared: Arc::new(FmuShared {
                md,
                resource_uri,
                guid,
                source: path.to_path_buf(),
                binary,
                python,
                keep_python_thread_state: keep,
                exec,
                dir,
            }),
        })
    }

    /// Whether the binary runs in host processes ([`crate::isolate`]).
    pub fn is_isolated(&self) -> bool {
        matches!(self.shared.exec, Exec::Remote(_))
    }

    /// The parsed model description.
    pub fn model_description(&self) -> &ModelDescription {
        &self.shared.md
    }

    /// The directory the archive was extracted to (removed when the FMU is dropped): with
    /// [`Binaries::Shared`] only the model description and `resources/`.
    pub fn directory(&self) -> &Path {
        self.shared.dir.path()
    }

    /// The path of the loaded binary: inside [`directory`](Self::directory), or (a binary
    /// shared with other FMUs, [`Binaries::Shared`]) in a private directory of its own.
    pub fn binary_path(&self) -> &Path {
        &self.shared.binary
    }

    /// The `fmuResourceLocation` passed to `fmi2Instantiate`: a percent-encoded `file://` URI of
    /// the extracted `resources` directory (no trailing slash, as fmpy passes it).
    pub fn resource_uri(&self) -> &str {
        self.shared
            .resource_uri
            .to_str()
            .expect("built from a String")
    }

    /// The archive this FMU was loaded from (an FMU read in place from inside an SSP: the
    /// SSP's path followed by the entry's name).
    pub fn source_path(&self) -> &Path {
        &self.shared.source
    }

    /// The resolved functions (`None` when the binary runs in host processes).
    pub fn functions(&self) -> Option<&Functions> {
        match &self.shared.exec {
            Exec::Local(b) => Some(&b.functions),
            Exec::Remote(_) => None,
        }
    }

    /// Optional FMI functions the binary does not export.
    pub fn missing_optional_functions(&self) -> &[&'static str] {
        self.shared.missing_optional()
    }

    /// What `fmi2GetTypesPlatform` returns (should be `"default"`).
    pub fn types_platform(&self) -> String {
        match &self.shared.exec {
            Exec::Local(b) => b.types_platform.clone(),
            Exec::Remote(r) => r.probe.types_platform.clone(),
        }
    }

    /// Looks up a variable by name.
    pub fn variable(&self, name: &str) -> Option<&model_description::ScalarVariable> {
        self.shared
            .md
            .model_variables
            .iter()
            .find(|v| v.name == name)
    }
}

/// Copies a C string (NULL gives an empty string).
///
/// # Safety
/// `p` is NULL or points to a NUL-terminated string.
pub(crate) unsafe fn cstr_lossy(p: *const std::ffi::c_char) -> String {
    if p.is_null() {
        String::new()
    } else {
        // SAFETY: per the contract.
        unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned()
    }
}
