//! Loading for runs, the fast path of [`Fmu::load`](super::Fmu::load) (the default,
//! [`Binaries::Shared`](super::Binaries::Shared)): only what a run needs is extracted, and each
//! distinct binary is extracted and loaded once per process, however many FMUs carry it.
//!
//! - **What is extracted.** `modelDescription.xml` and `resources/` (what the binary may read at
//!   run time through `fmuResourceLocation`) go into the FMU's private directory as before;
//!   documentation, sources, `extra/` and other platforms' binaries stay in the archive. Every
//!   entry is still checked (names, links, duplicates, declared sizes) and counted against the
//!   run's [`ArchiveBudget`](super::ArchiveBudget): an entry left in the archive at the size
//!   it declares, the binary at the size it declares and must decompress to exactly.
//! - **One binary, loaded once.** kneebench's FMUs all carry the same library. A binary is
//!   known by its entry's compressed bytes (method, CRC, sizes, then every byte compared: equal
//!   compressed bytes decompress to equal files), so a second FMU with the same binary reuses
//!   the first one's file and `dlopen` handle instead of decompressing and loading 1.5 MB again.
//!   Sharing a handle between FMUs is what instantiating one FMU twice already does; FMUs that
//!   declare `canBeInstantiatedOnlyOncePerProcess`, those with preloaded libraries and isolated
//!   ones take the plain path ([`Binaries::Private`](super::Binaries::Private)).
//! - **Once per user.** A binary extracted by one process is kept in a per-user cache
//!   ([`cache_dir`]: `$KNEEBENCH_CACHE_DIR`, else `$XDG_CACHE_HOME/kneebench/binaries` or
//!   `~/.cache/kneebench/binaries`; mode 0700, used only if owned by the user and writable by
//!   no one else), named by the SHA-256 of its entry's compressed bytes; later processes load
//!   it from there after checking its size and CRC, instead of decompressing it. Files are
//!   written whole (renamed into place); the least recently used beyond 32 are removed.
//!   `KNEEBENCH_CACHE_DIR=` (empty) turns the cache off: each process then extracts each
//!   distinct binary once into a private directory.
//! - **In place.** An FMU stored uncompressed in an SSP is read where it is ([`Window`]), not
//!   copied out of the SSP first.
//!
//! The plain path stays available and is tested to give the same results bit for bit
//! (`harness/tests/shared_load.rs`).

use std::fs;
use std::io::{self, Read, Seek, SeekFrom};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, Weak};

use super::{ArchiveSource, LoadError, LocalBinary};
use crate::bench_protocol::user::effective_uid;

/// Whether the entry at relative path `rel` is extracted for a run: the model description and
/// the resources.
pub(crate) fn needed_at_run_time(rel: &Path) -> bool {
    rel == Path::new("modelDescription.xml") || rel.starts_with("resources")
}

/// A file, or a window of one, read with positioned reads (no shared file offset).
#[derive(Debug)]
pub(crate) struct Window {
    file: fs::File,
    start: u64,
    len: u64,
    pos: u64,
}

impl Window {
    /// The bytes of `source`.
    pub(crate) fn open(source: &ArchiveSource) -> io::Result<Window> {
        match source {
            ArchiveSource::File(path) => {
                let file = fs::File::open(path)?;
                let len = file.metadata()?.len();
                Ok(Window {
                    file,
                    start: 0,
                    len,
                    pos: 0,
                })
            }
            ArchiveSource::Nested {
                container,
                start,
                len,
                ..
            } => {
                let file = fs::File::open(container)?;
                if file.metadata()?.len() < start.saturating_add(*len) {
                    return Err(io::Error::new(
                        io::ErrorKind::UnexpectedEof,
                        "the entry ends after the end of its archive",
                    ));
                }
                Ok(Window {
                    file,
                    start: *start,
                    len: *len,
                    pos: 0,
                })
            }
        }
    }
}

impl Read for Window {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let left = self.len.saturating_sub(self.pos);
        let want = (buf.len() as u64).min(left) as usize;
        if want == 0 {
            return Ok(0);
        }
        let n = self.file.read_at(&mut buf[..want], self.start + self.pos)?;
        self.pos += n as u64;
        Ok(n)
    }
}

impl Seek for Window {
    fn seek(&mut self, to: SeekFrom) -> io::Result<u64> {
        let target = match to {
            SeekFrom::Start(p) => Some(p),
            SeekFrom::End(d) => self.len.checked_add_signed(d),
            SeekFrom::Current(d) => self.pos.checked_add_signed(d),
        };
        match target {
            Some(p) => {
                self.pos = p;
                Ok(p)
            }
            None => Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                "seek before the start of the archive",
            )),
        }
    }
}

/// What identifies a binary's entry before its bytes are compared.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Key {
    method: u16,
    crc32: u32,
    size: u64,
    compressed_size: u64,
}

/// A binary extracted and loaded once for every FMU of this process that carries it.
pub(crate) struct SharedBinary {
    key: Key,
    /// The entry's compressed bytes: another entry is this binary when its bytes are equal.
    compressed: Vec<u8>,
    /// The extracted file.
    pub(crate) path: PathBuf,
    /// The loaded library (dropped before the directory holding its file).
    pub(crate) local: LocalBinary,
    /// The private directory of the file (`None`: the file is in the per-user cache).
    _dir: Option<tempfile::TempDir>,
}

/// The binaries loaded in this process, alive while an FMU uses them.
static LOADED: Mutex<Vec<Weak<SharedBinary>>> = Mutex::new(Vec::new());

/// The binary of entry `index` of `zip` (the FMU's `binaries/linux64/<identifier>.so`, left in
/// the archive and counted at its declared size by [`super::extract_entries`]): the one
/// already loaded in this process if its compressed bytes are equal, else the per-user
/// cache's copy (extracted there if missing), else extracted into a private directory as
/// `<identifier>.so`; then loaded.
pub(crate) fn binary<R: Read + Seek>(
    zip: &mut zip::ZipArchive<R>,
    archive: &Path,
    index: usize,
    identifier: &str,
) -> Result<Arc<SharedBinary>, LoadError> {
    let zip_err = |source| LoadError::Zip {
        archive: archive.to_path_buf(),
        entry: None,
        source,
    };
    let (key, compressed) = {
        let mut raw = zip.by_index_raw(index).map_err(zip_err)?;
        let key = Key {
            method: method_code(raw.compression()),
            crc32: raw.crc32(),
            size: raw.size(),
            compressed_size: raw.compressed_size(),
        };
        let mut compressed = Vec::with_capacity(key.compressed_size as usize);
        (&mut raw)
            .take(key.compressed_size)
            .read_to_end(&mut compressed)
            .map_err(|e| zip_err(zip::result::ZipError::Io(e)))?;
        (key, compressed)
    };
    // Loads hold the lock: a second load of the same binary waits for the first and reuses it.
    let mut loaded = LOADED.lock().unwrap_or_else(|p| p.into_inner());
    loaded.retain(|w| w.strong_count() > 0);
    if let Some(found) = loaded
        .iter()
        .filter_map(Weak::upgrade)
        .find(|b| b.key == key && b.compressed == compressed)
    {
        return Ok(found);
    }
    // The per-user cache first: a binary extracted by an earlier process is not decompressed
    // again.
    if let Some(cache) = cache_dir() {
        let name = format!("{}.so", cache_key(&key, &compressed));
        let path = cache.join(name);
        let found = verified(&path, &key);
        // Not loadable from there (a cache on a `noexec` file system, say): the private copy
        // below, whose error, if any, is the binary's own.
        if (found || store(zip, archive, index, cache, &path).is_ok())
            && let Ok(local) = LocalBinary::open(&path, &[])
        {
            if !found {
                prune(cache);
            }
            let shared = Arc::new(SharedBinary {
                key,
                compressed,
                path,
                local,
                _dir: None,
            });
            loaded.push(Arc::downgrade(&shared));
            return Ok(shared);
        }
    }
    let bytes = super::read_declared(zip, archive, index)?;
    let dir = crate::tempdirs::create("fmu").map_err(super::io_err(
        "cannot create a temporary directory for",
        archive,
    ))?;
    {
        use std::os::unix::fs::PermissionsExt;
        fs::set_permissions(dir.path(), fs::Permissions::from_mode(0o700))
            .map_err(super::io_err("cannot restrict permissions of", dir.path()))?;
    }
    // Named like the FMU's copy (kneebench's binary takes the model to try first from its own
    // file name); an identifier that is not a plain file name gets a neutral one.
    let plain =
        !identifier.is_empty() && !identifier.contains(['/', '\\', '\0']) && identifier != "..";
    let stem = if plain { identifier } else { "binary" };
    let path = dir.path().join(format!("{stem}.so"));
    fs::write(&path, &bytes).map_err(super::io_err("cannot extract to", &path))?;
    let local = LocalBinary::open(&path, &[])?;
    let shared = Arc::new(SharedBinary {
        key,
        compressed,
        path,
        local,
        _dir: Some(dir),
    });
    loaded.push(Arc::downgrade(&shared));
    Ok(shared)
}

/// The environment variable naming the per-user binary cache (empty: no cache).
pub const CACHE_VARIABLE: &str = "KNEEBENCH_CACHE_DIR";

/// How many binaries the cache keeps: past that, the least recently used ones not used in the
/// last hour are removed.
const CACHE_KEEPS: usize = 32;

/// The per-user cache of extracted binaries, once per process: `$KNEEBENCH_CACHE_DIR` if set
/// (empty: no cache), else `$XDG_CACHE_HOME/kneebench/binaries`, else
/// `$HOME/.cache/kneebench/binaries`; created with mode 0700 and used only if it is a directory
/// of this user that no other user may write to.
pub(crate) fn cache_dir() -> Option<&'static Path> {
    static DIR: std::sync::OnceLock<Option<PathBuf>> = std::sync::OnceLock::new();
    DIR.get_or_init(|| {
        let dir = match std::env::var_os(CACHE_VARIABLE) {
            Some(d) if d.is_empty() => return None,
            Some(d) => PathBuf::from(d),
            None => {
                let xdg = std::env::var_os("XDG_CACHE_HOME")
                    .map(PathBuf::from)
                    .filter(|p| p.is_absolute());
                let home = || {
                    std::env::var_os("HOME")
                        .map(PathBuf::from)
                        .filter(|p| p.is_absolute())
                        .map(|h| h.join(".cache"))
                };
                xdg.or_else(home)?.join("kneebench").join("binaries")
            }
        };
        usable_cache(&dir).then_some(dir)
    })
    .as_deref()
}

/// Creates `dir` (mode 0700) if needed; whether it is a directory (not a link) owned by this
/// user and writable by no one else.
fn usable_cache(dir: &Path) -> bool {
    use std::os::unix::fs::{DirBuilderExt, MetadataExt};
    let _ = fs::DirBuilder::new()
        .recursive(true)
        .mode(0o700)
        .create(dir);
    match fs::symlink_metadata(dir) {
        Ok(m) => m.is_dir() && m.uid() == effective_uid() && m.mode() & 0o022 == 0,
        Err(_) => false,
    }
}

/// The cache file name of a binary: SHA-256 of its entry's method, CRC, size and compressed
/// bytes, in hex.
fn cache_key(key: &Key, compressed: &[u8]) -> String {
    use sha2::Digest;
    let mut h = sha2::Sha256::new();
    h.update(key.method.to_le_bytes());
    h.update(key.crc32.to_le_bytes());
    h.update(key.size.to_le_bytes());
    h.update(compressed);
    h.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

/// Whether the cache file `path` holds the binary of `key`: a regular file of this user with
/// the declared size and CRC (a file cut short or damaged is replaced). A verified file's time
/// is set to now: the cache removes the least recently used.
fn verified(path: &Path, key: &Key) -> bool {
    use std::os::unix::fs::MetadataExt;
    let Ok(mut file) = fs::File::open(path) else {
        return false;
    };
    let Ok(meta) = file.metadata() else {
        return false;
    };
    if !meta.is_file() || meta.uid() != effective_uid() || meta.len() != key.size {
        return false;
    }
    // Read through a small buffer: the CRC needs every byte once, not the whole file in
    // memory (a fresh 1.5 MB buffer is hundreds of page faults on every run).
    let mut crc = crc32fast::Hasher::new();
    let mut buffer = vec![0u8; 64 * 1024];
    let mut read = 0u64;
    loop {
        match file.read(&mut buffer) {
            Ok(0) => break,
            Ok(n) => {
                crc.update(&buffer[..n]);
                read += n as u64;
            }
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(_) => return false,
        }
    }
    if read != key.size || crc.finalize() != key.crc32 {
        return false;
    }
    let _ = file.set_modified(std::time::SystemTime::now());
    true
}

/// Decompresses entry `index` into the cache as `path` (a private temporary file renamed into
/// place: readers see a whole file or none).
fn store<R: Read + Seek>(
    zip: &mut zip::ZipArchive<R>,
    archive: &Path,
    index: usize,
    cache: &Path,
    path: &Path,
) -> Result<(), LoadError> {
    use std::io::Write;
    let bytes = super::read_declared(zip, archive, index)?;
    let io = |e| super::io_err("cannot write the binary cache", cache)(e);
    let mut tmp = tempfile::NamedTempFile::new_in(cache).map_err(io)?;
    tmp.write_all(&bytes).map_err(io)?;
    tmp.as_file().sync_all().map_err(io)?;
    tmp.persist(path).map_err(|e| io(e.error))?;
    Ok(())
}

/// Keeps the cache at [`CACHE_KEEPS`] binaries: removes the least recently used beyond that,
/// sparing those used in the last hour (another process may be about to load them), and
/// temporary files left by a process that died while writing.
fn prune(cache: &Path) {
    let Ok(entries) = fs::read_dir(cache) else {
        return;
    };
    let now = std::time::SystemTime::now();
    let hour = std::time::Duration::from_secs(3600);
    let mut binaries = Vec::new();
    for e in entries.flatten() {
        let (Ok(meta), name) = (e.metadata(), e.file_name()) else {
            continue;
        };
        let Ok(modified) = meta.modified() else {
            continue;
        };
        let age = now.duration_since(modified).unwrap_or_default();
        let name = name.to_string_lossy();
        if name.starts_with(".tmp") && age > hour {
            let _ = fs::remove_file(e.path());
        } else if name.ends_with(".so") && meta.is_file() {
            binaries.push((modified, age, e.path()));
        }
    }
    if binaries.len() <= CACHE_KEEPS {
        return;
    }
    binaries.sort_by_key(|(modified, _, _)| *modified);
    let excess = binaries.len() - CACHE_KEEPS;
    for (_, age, path) in binaries.into_iter().take(excess) {
        if age > hour {
            let _ = fs::remove_file(path);
        }
    }
}

/// The zip compression method's number (the key compares methods; `extract_entries` names a
/// method it refuses by it). The crate gives it only through a deprecated accessor.
pub(crate) fn method_code(m: zip::CompressionMethod) -> u16 {
    #[allow(deprecated)]
    m.to_u16()
}

#[cfg(test)]
mod tests {
    use super::{Key, verified};

    /// A cache file is verified only with every byte as extracted: one byte changed anywhere
    /// (first, last, either side of a read-buffer boundary), the file cut short or grown, is
    /// found out.
    #[test]
    fn a_cache_file_is_verified_only_whole_and_unchanged() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("binary.so");
        // Not a whole number of read buffers, so the last read is a partial one.
        let bytes: Vec<u8> = (0..200_003u32).map(|i| (i * 7 + i / 251) as u8).collect();
        let key = Key {
            method: 8,
            crc32: crc32fast::hash(&bytes),
            size: bytes.len() as u64,
            compressed_size: 1,
        };
        std::fs::write(&path, &bytes).unwrap();
        assert!(verified(&path, &key));
        for at in [0, 65_535, 65_536, 131_072, bytes.len() - 1] {
            let mut damaged = bytes.clone();
            damaged[at] ^= 0x01;
            std::fs::write(&path, &damaged).unwrap();
            assert!(!verified(&path, &key), "byte {at} changed");
        }
        std::fs::write(&path, &bytes[..bytes.len() - 1]).unwrap();
        assert!(!verified(&path, &key), "cut short");
        let mut grown = bytes.clone();
        grown.push(0);
        std::fs::write(&path, &grown).unwrap();
        assert!(!verified(&path, &key), "grown");
        std::fs::write(&path, &bytes).unwrap();
        assert!(verified(&path, &key));
        assert!(!verified(&dir.path().join("missing.so"), &key));
    }
}
