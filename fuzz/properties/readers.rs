//! The properties the file-reader fuzz targets (`fuzz/fuzz_targets/`) and the test suite's
//! bounded run (`tests/tests/readers_fuzz.rs`) check on arbitrary input, in one file that both
//! include, so that both check the same:
//!
//! - no input panics a reader (the model description, the SSD text, the SSP archive, the
//!   parameter set);
//! - what a reader accepts, its writer writes and the reader reads back: the same value (up to
//!   what the writer documents it leaves out), and writing that again gives the same bytes;
//! - an SSP archive never extracts past its budget.
//!
//! Floating-point values compare by their written form where a NaN may be present (NaN is not
//! equal to itself, but it is written and read back as NaN).

use std::path::Path;

use kneebench_harness::load::{ArchiveBudget, ArchiveLimits};
use kneebench_harness::params::ParameterSet;
use kneebench_harness::ssp::{self, ConnectorType, Ssd, SspError};
use model_description::ModelDescription;

/// The archive limits the SSP archive target extracts within: small, so that a fuzzed archive
/// claiming (or inflating to) gigabytes is refused after at most a few MiB written.
pub const FUZZ_LIMITS: ArchiveLimits = ArchiveLimits {
    max_entries: 32,
    max_entry_bytes: 256 << 10,
    max_total_bytes: 1 << 20,
};

/// What the SSD target's parameter bindings resolve to in its round-trip pass: a valid,
/// empty parameter set, so that a description read, written and read again has the same
/// parameter values.
pub const EMPTY_SSV: &str = r#"<ssv:ParameterSet xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues" version="1.0" name="empty"><ssv:Parameters/></ssv:ParameterSet>"#;

/// The SSD target's binding resolver in its round-trip pass: every binding is [`EMPTY_SSV`].
#[allow(clippy::result_large_err)] // read_ssd_with's callback returns the SSP reader's error
pub fn empty_set(_source: &str) -> Result<String, SspError> {
    Ok(EMPTY_SSV.to_string())
}

/// The model-description reader on `data`: no panic; a description read is checked
/// (`check()`), written, and reads back equal, and writing it again gives the same bytes.
pub fn model_description(data: &[u8]) {
    let md = match ModelDescription::from_bytes(data) {
        Ok(md) => md,
        Err(e) => {
            let _ = (e.to_string(), e.line());
            return;
        }
    };
    for problem in md.check() {
        let _ = problem.to_string();
    }
    let xml = md.to_xml();
    let back = ModelDescription::from_xml(&xml).unwrap_or_else(|e| {
        panic!("a description read does not read back once written: {e}\n{xml}")
    });
    assert_eq!(
        back.to_xml(),
        xml,
        "written, read and written again differs"
    );
    // Without a NaN (which is unequal to itself) the values themselves are equal.
    if md == md.clone() {
        assert_eq!(back, md, "read, written and read again differs");
    }
}

/// The SSD reader on `data` as text: no panic, with parameter bindings resolving to the
/// document itself (so the referenced-file reader sees arbitrary text too) and, in a second
/// pass, to an empty set; what the second pass reads round-trips ([`ssd_round_trip`]).
pub fn ssd_text(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    #[allow(clippy::result_large_err)] // read_ssd_with's callback returns the SSP reader's error
    let mut itself = |_: &str| -> Result<String, SspError> { Ok(text.to_string()) };
    if let Err(e) = ssp::read_ssd_with(text, "fuzz.ssd", &mut itself) {
        let _ = e.to_string();
    }
    match ssp::read_ssd_with(text, "fuzz.ssd", &mut empty_set) {
        Ok(ssd) => ssd_round_trip(&ssd),
        Err(e) => {
            let _ = e.to_string();
        }
    }
}

/// `ssd` as its writer writes it: version `1.0`, `String` and `Enumeration` connectors untyped
/// (the writer writes only the types every SSP importer handles).
pub fn ssd_as_written(ssd: &Ssd) -> Ssd {
    let mut s = ssd.clone();
    s.version = "1.0".into();
    for c in &mut s.system.components {
        for k in &mut c.connectors {
            if matches!(
                k.ty,
                Some(ConnectorType::String | ConnectorType::Enumeration)
            ) {
                k.ty = None;
            }
        }
    }
    s
}

/// A description read (with its bindings resolved to empty sets), written, reads back as
/// [`ssd_as_written`] says, and writing it again gives the same bytes.
pub fn ssd_round_trip(ssd: &Ssd) {
    let xml = ssd.to_xml();
    let back = ssp::read_ssd_with(&xml, "written.ssd", &mut empty_set).unwrap_or_else(|e| {
        panic!("a description read does not read back once written: {e}\n{xml}")
    });
    assert_eq!(
        back.to_xml(),
        xml,
        "written, read and written again differs"
    );
    let expected = ssd_as_written(ssd);
    if expected == expected.clone() {
        assert_eq!(back, expected, "read, written and read again differs");
    }
}

/// The SSP archive reader on `data` as the bytes of an `.ssp` file: no panic, nothing
/// extracted past [`FUZZ_LIMITS`], and the description of an archive read round-trips.
pub fn ssp_archive(data: &[u8]) {
    let dir = tempfile::tempdir().expect("a temporary directory");
    let path = dir.path().join("fuzz.ssp");
    std::fs::write(&path, data).expect("writing the archive");
    ssp_archive_file(&path);
}

/// [`ssp_archive`] on an archive already on disk.
pub fn ssp_archive_file(path: &Path) {
    let budget = ArchiveBudget::new(FUZZ_LIMITS);
    let read = ssp::read_file_within(path, &budget);
    assert!(
        budget.used_bytes() <= FUZZ_LIMITS.max_total_bytes,
        "{} bytes extracted past the budget of {}",
        budget.used_bytes(),
        FUZZ_LIMITS.max_total_bytes
    );
    match read {
        Ok((ssd, base, extracted)) => {
            let extracted = extracted.expect("an .ssp archive is extracted");
            assert_eq!(base, extracted.path());
            let on_disk = bytes_under(extracted.path());
            assert!(
                on_disk <= budget.used_bytes(),
                "{on_disk} bytes on disk, {} counted",
                budget.used_bytes()
            );
            ssd_round_trip(&ssd);
        }
        Err(e) => {
            let _ = e.to_string();
        }
    }
}

/// Bytes of the regular files under `dir`.
fn bytes_under(dir: &Path) -> u64 {
    let mut total = 0;
    for entry in std::fs::read_dir(dir).expect("reading the extraction directory") {
        let entry = entry.expect("a directory entry");
        let meta = entry.metadata().expect("its metadata");
        if meta.is_dir() {
            total += bytes_under(&entry.path());
        } else {
            total += meta.len();
        }
    }
    total
}

/// The parameter-set (`.ssv`) reader on `data` as text: no panic; a set read is written and
/// reads back equal (lines aside: they are where each value was read), with the same content
/// hash, and writing it again gives the same bytes.
pub fn ssv_text(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    match ParameterSet::from_xml(text, "fuzz.ssv") {
        Ok(set) => ssv_round_trip(&set),
        Err(e) => {
            let _ = e.to_string();
        }
    }
}

/// A set written reads back equal (lines aside), with the same hash, and writes the same
/// bytes again.
pub fn ssv_round_trip(set: &ParameterSet) {
    let xml = set.to_xml();
    let back = ParameterSet::from_xml(&xml, "written.ssv")
        .unwrap_or_else(|e| panic!("a set read does not read back once written: {e}\n{xml}"));
    assert_eq!(
        back.to_xml(),
        xml,
        "written, read and written again differs"
    );
    assert_eq!(back.content_hash(), set.content_hash());
    assert_eq!(back.label(), set.label());
    let (mut a, mut b) = (set.clone(), back);
    for p in a.parameters.iter_mut().chain(b.parameters.iter_mut()) {
        p.line = 0;
    }
    if a == a.clone() {
        assert_eq!(b, a, "read, written and read again differs");
    }
}
