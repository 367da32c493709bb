//! Hostile and malformed archives: each is refused with a clear error, and nothing is written
//! outside the extraction directory.

mod common;

use std::io::Write;
use std::path::Path;

use common::FmuSpec;
use kneebench_harness::load::{ArchiveLimits, extract_archive};
use kneebench_harness::{Fmu, LoadError, LoadOptions};
use zip::write::SimpleFileOptions;

fn opts() -> SimpleFileOptions {
    SimpleFileOptions::default().compression_method(zip::CompressionMethod::Deflated)
}

/// Writes an archive with a valid FMU's content plus whatever `extra` adds.
fn archive(path: &Path, extra: impl FnOnce(&mut zip::ZipWriter<std::fs::File>)) {
    let f = std::fs::File::create(path).unwrap();
    let mut z = zip::ZipWriter::new(f);
    z.start_file("modelDescription.xml", opts()).unwrap();
    z.write_all(common::model_description(common::GUID).as_bytes())
        .unwrap();
    extra(&mut z);
    z.start_file("binaries/linux64/kbtest.so", opts()).unwrap();
    z.write_all(&std::fs::read(common::kbtest_so()).unwrap())
        .unwrap();
    z.finish().unwrap();
}

/// Extracts into `sandbox/dest` and checks that nothing but `dest` appeared in the sandbox
/// (and nothing named `evil*` anywhere in it).
fn extract_in_sandbox(fmu: &Path, limits: &ArchiveLimits) -> Result<(), LoadError> {
    let sandbox = tempfile::tempdir().unwrap();
    let dest = sandbox.path().join("dest");
    std::fs::create_dir(&dest).unwrap();
    let r = extract_archive(fmu, &dest, limits).map(|_| ());
    let top: Vec<_> = std::fs::read_dir(sandbox.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(top, vec![std::ffi::OsString::from("dest")]);
    fn walk(p: &Path) {
        for e in std::fs::read_dir(p).unwrap() {
            let e = e.unwrap();
            let name = e.file_name().to_string_lossy().into_owned();
            assert!(
                !name.starts_with("evil"),
                "{} was written",
                e.path().display()
            );
            let ft = e.file_type().unwrap();
            assert!(
                !ft.is_symlink(),
                "a symlink was created: {}",
                e.path().display()
            );
            if ft.is_dir() {
                walk(&e.path());
            }
        }
    }
    walk(sandbox.path());
    r
}

fn load_err(path: &Path) -> LoadError {
    Fmu::load(path, &LoadOptions::default()).unwrap_err()
}

#[test]
fn dotdot_path_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("dotdot.fmu");
    archive(&p, |z| {
        z.start_file("resources/../../evil.txt", opts()).unwrap();
        z.write_all(b"escaped").unwrap();
    });
    let e = extract_in_sandbox(&p, &ArchiveLimits::default()).unwrap_err();
    assert!(matches!(e, LoadError::UnsafeEntryName { .. }), "{e}");
    let msg = load_err(&p).to_string();
    assert!(
        msg.contains("'resources/../../evil.txt'") && msg.contains("'..'"),
        "{msg}"
    );
    assert!(!d.path().join("evil.txt").exists());
}

#[test]
fn absolute_paths_backslashes_and_drive_prefixes_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let abs = std::env::temp_dir().join(format!("evil-kneebench-{}.txt", std::process::id()));
    for (i, name) in [
        abs.to_string_lossy().into_owned(),
        "..\\evil.txt".to_string(),
        "C:/evil.txt".to_string(),
        "resources\\..\\..\\evil.txt".to_string(),
    ]
    .into_iter()
    .enumerate()
    {
        let p = d.path().join(format!("bad{i}.fmu"));
        archive(&p, |z| {
            z.start_file(name.as_str(), opts()).unwrap();
            z.write_all(b"escaped").unwrap();
        });
        let e = extract_in_sandbox(&p, &ArchiveLimits::default()).unwrap_err();
        assert!(
            matches!(&e, LoadError::UnsafeEntryName { entry, .. } if *entry == name),
            "{name}: {e}"
        );
    }
    assert!(!abs.exists(), "the absolute path was written");
}

#[test]
fn symlink_entry_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("symlink.fmu");
    archive(&p, |z| {
        z.add_symlink("resources/evil-link", "/etc/passwd", opts())
            .unwrap();
    });
    let e = extract_in_sandbox(&p, &ArchiveLimits::default()).unwrap_err();
    assert!(matches!(e, LoadError::Symlink { .. }), "{e}");
    assert!(load_err(&p).to_string().contains("symbolic link"));
}

/// Sets the compression method of entry `name` of the archive at `path` to `method`, in its
/// local header and its central directory record (the zip crate here writes only the methods
/// it reads: store and deflate).
fn set_method(path: &Path, name: &str, method: u16) {
    let mut bytes = std::fs::read(path).unwrap();
    let u16_at = |b: &[u8], at: usize| usize::from(u16::from_le_bytes([b[at], b[at + 1]]));
    let mut patched = 0;
    // (signature, offset of the method, offset of the name's length, offset of the name)
    for (signature, method_at, length_at, name_at) in
        [(b"PK\x03\x04", 8, 26, 30), (b"PK\x01\x02", 10, 28, 46)]
    {
        for start in 0..bytes.len().saturating_sub(name_at) {
            if &bytes[start..start + 4] != signature {
                continue;
            }
            let length = u16_at(&bytes, start + length_at);
            let here = bytes.get(start + name_at..start + name_at + length);
            if here == Some(name.as_bytes()) {
                bytes[start + method_at..start + method_at + 2]
                    .copy_from_slice(&method.to_le_bytes());
                patched += 1;
            }
        }
    }
    assert_eq!(
        patched, 2,
        "{name}: one local header and one central record"
    );
    std::fs::write(path, bytes).unwrap();
}

/// An entry compressed with a method the harness does not read (bzip2, as `zip -Z bzip2` or
/// Python's `zipfile` writes it) is refused by name before anything of it is written, not
/// reported as an I/O error of the file it was being extracted to.
#[test]
fn an_entry_compressed_with_another_method_is_refused_by_name() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("bzip2.fmu");
    let stored = SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
    archive(&p, |z| {
        z.start_file("resources/table.csv", stored).unwrap();
        z.write_all(b"t,v\n0,1\n").unwrap();
    });
    set_method(&p, "resources/table.csv", 12);
    let sandbox = tempfile::tempdir().unwrap();
    let e = extract_archive(&p, sandbox.path(), &ArchiveLimits::default()).unwrap_err();
    assert!(
        matches!(&e, LoadError::UnsupportedCompression { entry, method }
            if entry == "resources/table.csv" && method == "Bzip2 (method 12)"),
        "{e}"
    );
    // Refused before anything of it was written (the entries before it were extracted).
    assert!(sandbox.path().join("modelDescription.xml").is_file());
    assert!(!sandbox.path().join("resources/table.csv").exists());
    // So is an entry that a run leaves in the archive (a binary, read later from there).
    let binary = d.path().join("bzip2-binary.fmu");
    archive(&binary, |_| {});
    set_method(&binary, "binaries/linux64/kbtest.so", 12);
    let e = load_err(&binary);
    assert!(
        matches!(&e, LoadError::UnsupportedCompression { entry, .. }
            if entry == "binaries/linux64/kbtest.so"),
        "{e}"
    );
    let e = load_err(&p).to_string();
    assert!(
        e.contains("'resources/table.csv': it is compressed with Bzip2 (method 12)")
            && e.contains("deflate"),
        "{e}"
    );
    // A method number nobody assigned is named as such.
    set_method(&p, "resources/table.csv", 77);
    let e = extract_in_sandbox(&p, &ArchiveLimits::default()).unwrap_err();
    assert!(e.to_string().contains("compressed with method 77;"), "{e}");
}

#[test]
fn zip_bomb_entry_is_stopped_by_the_decompressed_size() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("bomb.fmu");
    // 64 MiB of zeros compress to about 64 KiB.
    archive(&p, |z| {
        z.start_file("resources/evil-bomb.bin", opts()).unwrap();
        let chunk = vec![0u8; 1 << 20];
        for _ in 0..64 {
            z.write_all(&chunk).unwrap();
        }
    });
    assert!(std::fs::metadata(&p).unwrap().len() < 2 << 20);
    let limits = ArchiveLimits {
        max_entry_bytes: 16 << 20,
        ..ArchiveLimits::default()
    };
    let e = extract_in_sandbox(&p, &limits).unwrap_err();
    assert!(
        matches!(&e, LoadError::EntryTooLarge { entry, .. } if entry == "resources/evil-bomb.bin"),
        "{e}"
    );
    let total = ArchiveLimits {
        max_total_bytes: 32 << 20,
        ..ArchiveLimits::default()
    };
    let e = extract_in_sandbox(&p, &total).unwrap_err();
    assert!(matches!(e, LoadError::TotalTooLarge { .. }), "{e}");
    let many = ArchiveLimits {
        max_entries: 2,
        ..ArchiveLimits::default()
    };
    let e = extract_in_sandbox(&p, &many).unwrap_err();
    assert!(
        matches!(e, LoadError::TooManyEntries { count: 3, .. }),
        "{e}"
    );
    let e = Fmu::load(
        &p,
        &LoadOptions {
            limits,
            ..LoadOptions::default()
        },
    )
    .unwrap_err();
    assert!(e.to_string().contains("decompresses to more than"), "{e}");
}

#[test]
fn missing_binary_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("nobinary.fmu");
    common::write_fmu(
        &p,
        &FmuSpec {
            binary: false,
            ..FmuSpec::default()
        },
    );
    let e = load_err(&p);
    assert!(
        matches!(&e, LoadError::MissingBinary { expected } if expected == "binaries/linux64/kbtest.so"),
        "{e}"
    );
}

#[test]
fn malformed_or_missing_model_description_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("badxml.fmu");
    common::write_fmu(
        &p,
        &FmuSpec {
            model_description: Some("<fmiModelDescription fmiVersion=\"2.0\" <<".into()),
            ..FmuSpec::default()
        },
    );
    let e = load_err(&p);
    assert!(matches!(e, LoadError::ModelDescription(_)), "{e}");
    assert!(e.to_string().starts_with("modelDescription.xml: "), "{e}");

    let p = d.path().join("nomd.fmu");
    common::write_fmu(
        &p,
        &FmuSpec {
            model_description: None,
            ..FmuSpec::default()
        },
    );
    assert!(matches!(load_err(&p), LoadError::MissingModelDescription));

    let p = d.path().join("notazip.fmu");
    std::fs::write(&p, b"this is not a zip archive").unwrap();
    let e = load_err(&p);
    assert!(matches!(e, LoadError::Zip { .. }), "{e}");
}

#[test]
fn guid_mismatch_is_refused_at_instantiation() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("guid.fmu");
    common::write_fmu(
        &p,
        &FmuSpec {
            model_description: Some(common::model_description("{another-guid}")),
            ..FmuSpec::default()
        },
    );
    let fmu = Fmu::load(&p, &LoadOptions::default()).unwrap();
    let e = fmu
        .instantiate("x", &kneebench_harness::InstanceOptions::default())
        .unwrap_err();
    let m = e.to_string();
    assert!(m.contains("fmi2Instantiate returned NULL"), "{m}");
    assert!(
        m.contains("GUID mismatch: the binary expects {kbtest-0001} but got {another-guid}"),
        "{m}"
    );
}

#[test]
fn extraction_directory_is_private_and_removed() {
    let d = tempfile::tempdir().unwrap();
    let p = common::kbtest_fmu(d.path());
    let fmu = Fmu::load(&p, &LoadOptions::default()).unwrap();
    let dir = fmu.directory().to_path_buf();
    use std::os::unix::fs::PermissionsExt;
    let mode = std::fs::metadata(&dir).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode, 0o700);
    assert!(dir.join("resources/readme.txt").is_file());
    drop(fmu);
    assert!(!dir.exists());
}

#[test]
fn entries_left_in_the_archive_are_checked_like_extracted_ones() {
    // Loading for runs (the default) leaves `documentation/` in the archive: its entries are
    // refused for whatever extraction would refuse.
    let d = tempfile::tempdir().unwrap();
    let dup = d.path().join("dup.fmu");
    archive(&dup, |z| {
        for name in ["documentation/a.txt", "./documentation/a.txt"] {
            z.start_file(name, opts()).unwrap();
            z.write_all(b"x").unwrap();
        }
    });
    let e = load_err(&dup);
    assert!(matches!(e, LoadError::DuplicateEntry { .. }), "{e}");
    // The same for extracted entries: a second `resources/` file of one path is refused, not
    // written over the first.
    let dup_extracted = d.path().join("dup-resources.fmu");
    archive(&dup_extracted, |z| {
        for (name, text) in [
            ("resources/a.txt", b"first"),
            ("resources/./a.txt", b"other"),
        ] {
            z.start_file(name, opts()).unwrap();
            z.write_all(text).unwrap();
        }
    });
    let e = load_err(&dup_extracted);
    assert!(
        matches!(&e, LoadError::DuplicateEntry { entry } if entry == "resources/./a.txt"),
        "{e}"
    );

    let dotdot = d.path().join("dotdot-doc.fmu");
    archive(&dotdot, |z| {
        z.start_file("documentation/../../evil.txt", opts())
            .unwrap();
        z.write_all(b"x").unwrap();
    });
    let e = load_err(&dotdot);
    assert!(matches!(e, LoadError::UnsafeEntryName { .. }), "{e}");

    // Too large by the size it declares (it is never decompressed).
    let large = d.path().join("large-doc.fmu");
    archive(&large, |z| {
        z.start_file("documentation/large.bin", opts()).unwrap();
        z.write_all(&vec![0u8; 2 << 20]).unwrap();
    });
    let limits = ArchiveLimits {
        max_entry_bytes: 1 << 20,
        ..ArchiveLimits::default()
    };
    let e = Fmu::load(
        &large,
        &LoadOptions {
            limits,
            ..LoadOptions::default()
        },
    )
    .unwrap_err();
    assert!(
        matches!(&e, LoadError::EntryTooLarge { entry, .. } if entry == "documentation/large.bin"),
        "{e}"
    );
    // Within the limits it loads, and nothing of it is extracted.
    let fmu = Fmu::load(&large, &LoadOptions::default()).unwrap();
    assert!(!fmu.directory().join("documentation").exists());
}
