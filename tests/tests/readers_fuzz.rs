//! The file readers under a bounded fuzzing run in the test suite: the model-description
//! reader, the SSD reader, the SSP archive reader and the parameter-set (`.ssv`) reader each get
//! thousands of generated inputs. Random bytes die at the first byte, so most inputs are valid
//! documents (the committed seeds, written by our writers) under a few structural edits:
//! attribute values replaced by hostile ones (empty, NaN, out-of-range numbers, entity and
//! character references, path escapes), attributes and lines (our writers put one element on
//! a line) dropped, duplicated or swapped, known elements inserted where they do not belong,
//! truncation, content after the root, byte overwrites; archives are built from such
//! documents with hostile entry names, oversized and too many entries, symlinks and corrupted
//! bytes. Values generated as typed structures are written and read back.
//!
//! The properties are those of the cargo-fuzz targets (`fuzz/properties/readers.rs`): no
//! panic, what is read is written and read back equal, no extraction past the budget. Every
//! committed seed of `fuzz/seeds/<target>/` is replayed.
//!
//! `KNEEBENCH_WRITE_FUZZ_SEEDS=1 cargo test -p kneebench-tests --test readers_fuzz` rewrites
//! the seeds our writers produce (the models' descriptions, the study's SEA system and the
//! plant's default parameter set); the hand-written ones (`style_*`: documents as other tools
//! write them) and the regressions (`regression_*`) stay.

#[path = "../../fuzz/properties/readers.rs"]
#[allow(dead_code)]
mod readers;

use std::io::Write as _;
use std::path::PathBuf;
use std::sync::OnceLock;

use kneebench_harness::master::{Algorithm, Value};
use kneebench_harness::params::{ParamValue, Parameter, ParameterSet, UnitDefinition};
use kneebench_harness::ssp::{
    self, ConnectorKind, ConnectorType, Ssd, SspComponent, SspConnection, SspConnector,
    SspExperiment, SspParameter, SspSystem,
};
use model_description::ModelDescription;
use proptest::prelude::*;
use proptest::sample::{Index, select};

// ---------------------------------------------------------------------------------------------
// Seeds

fn seeds_dir(target: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../fuzz/seeds")
        .join(target)
}

/// Every committed seed of `target`, by file name.
fn committed(target: &str) -> Vec<(String, Vec<u8>)> {
    let mut out: Vec<(String, Vec<u8>)> = std::fs::read_dir(seeds_dir(target))
        .unwrap_or_else(|e| panic!("{}: {e}", seeds_dir(target).display()))
        .map(|entry| {
            let path = entry.unwrap().path();
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            (name, std::fs::read(&path).unwrap())
        })
        .collect();
    out.sort();
    out
}

/// The seeds of `target` that are valid documents (the base of the edits), as text.
fn valid_documents(target: &str) -> &'static [String] {
    static MODEL_DESCRIPTIONS: OnceLock<Vec<String>> = OnceLock::new();
    static SSDS: OnceLock<Vec<String>> = OnceLock::new();
    static SSVS: OnceLock<Vec<String>> = OnceLock::new();
    let cell = match target {
        "model_description" => &MODEL_DESCRIPTIONS,
        "ssd_reader" => &SSDS,
        "ssv_reader" => &SSVS,
        other => panic!("no text seeds for {other}"),
    };
    cell.get_or_init(|| {
        let docs: Vec<String> = committed(target)
            .into_iter()
            .filter(|(name, _)| !name.starts_with("regression_"))
            .map(|(_, bytes)| String::from_utf8(bytes).expect("a text seed"))
            .collect();
        assert!(!docs.is_empty(), "no seeds for {target}");
        docs
    })
}

/// The models' descriptions, the study's SEA system (with a parameter set bound by file), the
/// plant's default parameter set, a set of every value type, and an archive of the system and
/// its set: what our writers write.
fn written_seeds() -> Vec<(&'static str, String, Vec<u8>)> {
    let mut seeds = Vec::new();
    for entry in kneebench_fmu::MODELS.iter() {
        seeds.push((
            "model_description",
            format!("{}.xml", entry.identifier),
            entry.info().xml.clone().into_bytes(),
        ));
    }
    let plant = &kneebench_fmu::registry::find_by_identifier("BenchPlant")
        .expect("BenchPlant")
        .info()
        .description;
    let defaults = ParameterSet::defaults_of(plant, "BenchPlant defaults", "1");
    let mut every_type = ParameterSet::new("every type", "2 & <3>");
    every_type.description = Some("one value of each type, with characters to escape".into());
    for (name, value, unit) in [
        ("k", ParamValue::Real(-1.25e-7), Some("N.m/rad")),
        ("n", ParamValue::Integer(-2147483648), None),
        ("on", ParamValue::Boolean(true), None),
        (
            "label",
            ParamValue::String("a \"b\" <c> & 'd'\n\té".into()),
            None,
        ),
    ] {
        every_type.parameters.push(Parameter {
            name: name.into(),
            value,
            unit: unit.map(str::to_string),
            line: 0,
        });
    }
    every_type.units.push(UnitDefinition {
        name: "N.m/rad".into(),
        exponents: [1, 2, -2, 0, 0, 0, 0, -1],
        factor: 1.0,
        offset: 0.0,
    });
    seeds.push((
        "ssv_reader",
        "BenchPlant-defaults.ssv".into(),
        defaults.to_xml().into_bytes(),
    ));
    seeds.push((
        "ssv_reader",
        "every-type.ssv".into(),
        every_type.to_xml().into_bytes(),
    ));

    use kneebench_harness::study::{Actuator, Gait, StudyGains, gait_scenario};
    let scenario = gait_scenario(
        Actuator::Sea,
        Gait::bench_full(),
        StudyGains::for_actuator(Actuator::Sea),
        1,
    );
    let fmus = kneebench_tests::exported_fmus();
    let mut ssd = scenario.to_ssd(fmus.0.path()).expect("the study's SSD");
    ssd.system
        .components
        .iter_mut()
        .find(|c| c.name == "plant")
        .expect("a plant")
        .parameter_sources
        .push("resources/plant.ssv".into());
    seeds.push(("ssd_reader", "sea.ssd".into(), ssd.to_xml().into_bytes()));
    let dir = tempfile::tempdir().unwrap();
    let ssv = dir.path().join("plant.ssv");
    defaults.write_file(&ssv).unwrap();
    let archive = dir.path().join("sea.ssp");
    ssp::write_ssp(&ssd, &[("resources/plant.ssv".into(), ssv)], &archive).unwrap();
    seeds.push((
        "ssp_archive",
        "sea.ssp".into(),
        std::fs::read(&archive).unwrap(),
    ));
    // The hand-written SSD and set in an archive as another tool lays it out: a directory
    // entry, the set stored, the description deflated.
    let style = |target: &str, name: &str| std::fs::read(seeds_dir(target).join(name)).unwrap();
    let mut z = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    let deflated = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated);
    let stored = deflated.compression_method(zip::CompressionMethod::Stored);
    z.add_directory("resources/", stored).unwrap();
    z.start_file("resources/motor.ssv", stored).unwrap();
    z.write_all(&style("ssv_reader", "style_other_tool.ssv"))
        .unwrap();
    z.start_file("SystemStructure.ssd", deflated).unwrap();
    z.write_all(&style("ssd_reader", "style_default_namespace.ssd"))
        .unwrap();
    seeds.push((
        "ssp_archive",
        "style_other_tool.ssp".into(),
        z.finish().unwrap().into_inner(),
    ));
    seeds
}

const TARGETS: [&str; 4] = [
    "model_description",
    "ssd_reader",
    "ssp_archive",
    "ssv_reader",
];

fn property(target: &str) -> fn(&[u8]) {
    match target {
        "model_description" => readers::model_description,
        "ssd_reader" => readers::ssd_text,
        "ssp_archive" => readers::ssp_archive,
        "ssv_reader" => readers::ssv_text,
        other => panic!("no target {other}"),
    }
}

/// Whether `bytes` reads as a document of `target` (seeds other than regressions must).
fn reads(target: &str, bytes: &[u8]) -> Result<(), String> {
    let text = || std::str::from_utf8(bytes).map_err(|e| e.to_string());
    match target {
        "model_description" => ModelDescription::from_bytes(bytes)
            .map(drop)
            .map_err(|e| e.to_string()),
        "ssd_reader" => ssp::read_ssd_with(text()?, "seed.ssd", &mut readers::empty_set)
            .map(drop)
            .map_err(|e| e.to_string()),
        "ssp_archive" => {
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join("seed.ssp");
            std::fs::write(&path, bytes).unwrap();
            let budget = kneebench_harness::ArchiveBudget::new(readers::FUZZ_LIMITS);
            ssp::read_file_within(&path, &budget)
                .map(drop)
                .map_err(|e| e.to_string())
        }
        "ssv_reader" => ParameterSet::from_xml(text()?, "seed.ssv")
            .map(drop)
            .map_err(|e| e.to_string()),
        other => panic!("no target {other}"),
    }
}

#[test]
fn the_committed_seeds_replay_and_read() {
    if std::env::var("KNEEBENCH_WRITE_FUZZ_SEEDS").is_ok_and(|v| v == "1") {
        for (target, name, bytes) in written_seeds() {
            let path = seeds_dir(target).join(name);
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(&path, &bytes).unwrap();
        }
    }
    let mut total_bytes = 0;
    for target in TARGETS {
        let seeds = committed(target);
        assert!(seeds.len() >= 2, "{target}: {} seeds", seeds.len());
        for (name, bytes) in &seeds {
            property(target)(bytes);
            if !name.starts_with("regression_") {
                reads(target, bytes).unwrap_or_else(|e| panic!("{target}/{name}: {e}"));
            }
            total_bytes += bytes.len();
        }
    }
    // The corpus stays small (it is committed).
    assert!(total_bytes < 1 << 20, "{total_bytes} bytes of seeds");
}

// ---------------------------------------------------------------------------------------------
// Structural edits of valid documents

/// Attribute values worth trying anywhere: the edges of every type the readers parse, entity
/// and character references, path escapes, the enumerations' own words.
const HOSTILE_VALUES: &[&str] = &[
    "",
    " ",
    "0",
    "-0",
    "1",
    "-1",
    " 2 ",
    "1e308",
    "1e309",
    "-1e309",
    "4.9e-324",
    "NaN",
    "nan",
    "INF",
    "-INF",
    "inf",
    "Infinity",
    "+1",
    "0x10",
    "1_0",
    "1.5.2",
    "2147483647",
    "2147483648",
    "-2147483649",
    "4294967295",
    "18446744073709551616",
    "true",
    "false",
    "yes",
    "&amp;",
    "&lt;&gt;",
    "&#0;",
    "&#1;",
    "&#xD800;",
    "&#x110000;",
    "&#10;",
    "&unknown;",
    "&",
    "<",
    "a\tb",
    "\u{1}",
    "é",
    "\u{feff}",
    "..",
    "../x.fmu",
    "/etc/passwd",
    "resources/../../x.ssv",
    "resources\\x.ssv",
    "file:///etc/passwd",
    "http://example.org/a.fmu",
    "input",
    "output",
    "parameter",
    "calculatedParameter",
    "inout",
    "local",
    "independent",
    "continuous",
    "exact",
    "gauss-seidel",
    "jacobi",
    "application/x-ssp-package",
    "1.0",
    "1.1",
    "2.0",
    "3.0",
];

fn hostile_value() -> impl Strategy<Value = String> {
    prop_oneof![
        4 => select(HOSTILE_VALUES).prop_map(str::to_string),
        1 => "\\PC{0,12}",
        1 => any::<f64>().prop_map(|v| v.to_string()),
        1 => any::<i64>().prop_map(|v| v.to_string()),
        1 => (1usize..5000).prop_map(|n| "x".repeat(n)),
    ]
}

/// Fragments that are elements the readers know, markup in odd places, and broken markup.
const FRAGMENTS: &[&str] = &[
    "<ScalarVariable name=\"x\" valueReference=\"0\"><Real/></ScalarVariable>",
    "<ScalarVariable name=\"y\" valueReference=\"1\"><Real/><Integer/></ScalarVariable>",
    "<Unknown index=\"4294967295\" dependencies=\"0 1\" dependenciesKind=\"fixed\"/>",
    "<Unknown index=\"0\"/>",
    "<ModelVariables/>",
    "<ModelStructure/>",
    "<CoSimulation modelIdentifier=\"m\"/>",
    "<DefaultExperiment startTime=\"1\" stopTime=\"0\" stepSize=\"0\"/>",
    "<SimpleType name=\"t\"/>",
    "<Tool name=\"t\"><a><b/></a></Tool>",
    "<VendorAnnotations><Tool name=\"t\">x</Tool></VendorAnnotations>",
    "<ssd:System name=\"s\"/>",
    "<System/>",
    "<Elements><Component name=\"c\" source=\"c.fmu\"/></Elements>",
    "<ssd:Component name=\"c\" source=\"resources/c.fmu\" type=\"application/x-fmu-sharedlibrary\"/>",
    "<ssd:Connector name=\"u\" kind=\"input\"><ssc:Real unit=\"m\"/></ssd:Connector>",
    "<ssd:Connector name=\"v\" kind=\"output\"><ssc:String/></ssd:Connector>",
    "<ssd:Connection startElement=\"a\" startConnector=\"y\" endConnector=\"u\"/>",
    "<ssd:ParameterBinding source=\"resources/p.ssv\"/>",
    "<ssd:ParameterBinding prefix=\"p.\"><ssd:ParameterValues><ssv:ParameterSet version=\"1.0\" name=\"i\"><ssv:Parameters><ssv:Parameter name=\"k\"><ssv:Real value=\"2\"/></ssv:Parameter></ssv:Parameters></ssv:ParameterSet></ssd:ParameterValues></ssd:ParameterBinding>",
    "<ssv:ParameterSet version=\"1.0\" name=\"i\"><ssv:Parameter name=\"e\"><ssv:Enumeration value=\"1\"/></ssv:Parameter></ssv:ParameterSet>",
    "<ssd:DefaultExperiment startTime=\"NaN\"/>",
    "<ssc:Annotation type=\"org.kneebench.master\"><kb:Component stepMultiple=\"0\"/><kb:Master stepSize=\"-1\" algorithm=\"x\"/></ssc:Annotation>",
    "<ssv:Parameter name=\"p\"><ssv:Real value=\"1\" unit=\"undefined\"/></ssv:Parameter>",
    "<ssv:Parameter name=\"q\"><ssv:Integer value=\"1\"/><ssv:Real value=\"2\"/></ssv:Parameter>",
    "<ssv:Parameter name=\"r\"/>",
    "<ssv:Parameter name=\"s\"><ssv:Binary value=\"00\"/></ssv:Parameter>",
    "<ssc:Unit name=\"u\"><ssc:BaseUnit kg=\"99999999999\" factor=\"NaN\" offset=\"inf\"/></ssc:Unit>",
    "<ssc:Unit name=\"u\"/>",
    "<ssv:Units><ssc:Unit name=\"N.m/rad\"><ssc:BaseUnit kg=\"1\"/></ssc:Unit></ssv:Units>",
    "<![CDATA[<Real/>]]>",
    "<!-- <Real/> -->",
    "<?pi x?>",
    "<!DOCTYPE x [<!ENTITY e \"<Real/>\">]>",
    "&e;",
    "</x>",
    "<a>",
    "<a b=\"1\" b=\"2\"/>",
    "<a b='1\"/>",
    "<a xmlns:b=\"urn:x\" b:name=\"n\"/>",
    "\u{feff}",
    "\u{feff}\u{feff}",
    "&#0;",
    "text é",
];

#[derive(Debug, Clone)]
enum Edit {
    /// Replace an attribute's value.
    Value(Index, String),
    /// Remove an attribute (name and value).
    DropAttribute(Index),
    /// Duplicate a line (our writers put one element on a line).
    DuplicateLine(Index),
    /// Remove a line.
    DropLine(Index),
    /// Swap two lines.
    SwapLines(Index, Index),
    /// Insert a fragment at the start of a line.
    Insert(Index, String),
    /// Cut the document.
    Truncate(Index),
    /// Append something after the root element.
    AfterRoot(String),
    /// Overwrite a byte (applied last: may break UTF-8).
    Byte(Index, u8),
}

fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        6 => (any::<Index>(), hostile_value()).prop_map(|(i, v)| Edit::Value(i, v)),
        2 => any::<Index>().prop_map(Edit::DropAttribute),
        1 => any::<Index>().prop_map(Edit::DuplicateLine),
        2 => any::<Index>().prop_map(Edit::DropLine),
        1 => (any::<Index>(), any::<Index>()).prop_map(|(a, b)| Edit::SwapLines(a, b)),
        3 => (any::<Index>(), select(FRAGMENTS)).prop_map(|(i, f)| Edit::Insert(i, f.to_string())),
        1 => any::<Index>().prop_map(Edit::Truncate),
        1 => select(FRAGMENTS).prop_map(|f| Edit::AfterRoot(f.to_string())),
        2 => (any::<Index>(), prop_oneof![any::<u8>(), select(b"<>&\"'=/ \n?!:".to_vec())])
            .prop_map(|(i, b)| Edit::Byte(i, b)),
    ]
}

fn edits() -> impl Strategy<Value = Vec<Edit>> {
    proptest::collection::vec(edit(), 1..5)
}

/// Byte ranges of the attribute values of `doc` (between the quotes of `="..."`), and of each
/// whole attribute (from the space before its name to its closing quote).
fn attributes(doc: &str) -> Vec<(std::ops::Range<usize>, std::ops::Range<usize>)> {
    let bytes = doc.as_bytes();
    let mut out = Vec::new();
    let mut from = 0;
    while let Some(i) = doc[from..].find("=\"").map(|i| i + from) {
        let start = i + 2;
        let Some(len) = doc[start..].find('"') else {
            break;
        };
        let end = start + len;
        let mut name = i;
        while name > 0 && !bytes[name - 1].is_ascii_whitespace() && bytes[name - 1] != b'<' {
            name -= 1;
        }
        if name > 0 && bytes[name - 1].is_ascii_whitespace() {
            out.push((start..end, name - 1..end + 1));
        }
        from = end + 1;
    }
    out
}

fn lines(doc: &str) -> Vec<String> {
    doc.split_inclusive('\n').map(str::to_string).collect()
}

fn floor_boundary(s: &str, mut i: usize) -> usize {
    i = i.min(s.len());
    while !s.is_char_boundary(i) {
        i -= 1;
    }
    i
}

/// `doc` with `edits` applied in order (byte overwrites last).
fn apply(doc: &str, edits: &[Edit]) -> Vec<u8> {
    let mut d = doc.to_string();
    let mut bytes = Vec::new();
    for e in edits {
        match e {
            Edit::Value(i, v) => {
                let a = attributes(&d);
                if !a.is_empty() {
                    let (value, _) = a[i.index(a.len())].clone();
                    d.replace_range(value, v);
                }
            }
            Edit::DropAttribute(i) => {
                let a = attributes(&d);
                if !a.is_empty() {
                    let (_, whole) = a[i.index(a.len())].clone();
                    d.replace_range(whole, "");
                }
            }
            Edit::DuplicateLine(i) => {
                let mut l = lines(&d);
                let k = i.index(l.len());
                l.insert(k, l[k].clone());
                d = l.concat();
            }
            Edit::DropLine(i) => {
                let mut l = lines(&d);
                l.remove(i.index(l.len()));
                d = l.concat();
            }
            Edit::SwapLines(a, b) => {
                let mut l = lines(&d);
                let n = l.len();
                l.swap(a.index(n), b.index(n));
                d = l.concat();
            }
            Edit::Insert(i, f) => {
                let mut l = lines(&d);
                let k = i.index(l.len() + 1);
                l.insert(k, f.clone());
                d = l.concat();
            }
            Edit::Truncate(i) => {
                let k = floor_boundary(&d, i.index(d.len() + 1));
                d.truncate(k);
            }
            Edit::AfterRoot(f) => d.push_str(f),
            Edit::Byte(..) => {}
        }
        if d.is_empty() {
            break;
        }
    }
    bytes.extend_from_slice(d.as_bytes());
    for e in edits {
        if let Edit::Byte(i, b) = e
            && !bytes.is_empty()
        {
            let k = i.index(bytes.len());
            bytes[k] = *b;
        }
    }
    bytes
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn the_model_description_reader_takes_edited_descriptions(
        doc in any::<Index>(), edits in edits()
    ) {
        let docs = valid_documents("model_description");
        readers::model_description(&apply(&docs[doc.index(docs.len())], &edits));
    }

    #[test]
    fn the_ssd_reader_takes_edited_descriptions(doc in any::<Index>(), edits in edits()) {
        let docs = valid_documents("ssd_reader");
        readers::ssd_text(&apply(&docs[doc.index(docs.len())], &edits));
    }

    #[test]
    fn the_ssv_reader_takes_edited_sets(doc in any::<Index>(), edits in edits()) {
        let docs = valid_documents("ssv_reader");
        readers::ssv_text(&apply(&docs[doc.index(docs.len())], &edits));
    }

    #[test]
    fn every_reader_takes_any_bytes(data in proptest::collection::vec(any::<u8>(), 0..600)) {
        readers::model_description(&data);
        readers::ssd_text(&data);
        readers::ssv_text(&data);
    }
}

// ---------------------------------------------------------------------------------------------
// Archives

/// Entry names worth trying: the ones the reader looks for, directories, and escapes.
const ENTRY_NAMES: &[&str] = &[
    "SystemStructure.ssd",
    "./SystemStructure.ssd",
    "resources/plant.ssv",
    "resources/p.ssv",
    "resources/",
    "resources",
    "./",
    "",
    "../evil",
    "/abs",
    "C:/x",
    "a\\b",
    "resources/../../x",
    "resources/./plant.ssv",
    "nul\0byte",
    "SystemStructure.ssd/x",
];

#[derive(Debug, Clone)]
enum EntryBody {
    /// An edited seed document (SSD or SSV).
    Document(Index, bool, Vec<Edit>),
    /// `n` zero bytes (compresses to almost nothing, inflates past the budget).
    Zeros(usize),
    /// A directory.
    Directory,
    /// A symbolic link to a target.
    Symlink(String),
}

fn entry() -> impl Strategy<Value = (String, EntryBody, bool)> {
    let body = prop_oneof![
        6 => (any::<Index>(), any::<bool>(), proptest::collection::vec(edit(), 0..3))
            .prop_map(|(i, ssd, e)| EntryBody::Document(i, ssd, e)),
        1 => prop_oneof![Just(300usize << 10), Just(100 << 10), 0usize..4096].prop_map(EntryBody::Zeros),
        1 => Just(EntryBody::Directory),
        1 => select(&["/etc/passwd", "..", "resources/plant.ssv"][..])
            .prop_map(|t| EntryBody::Symlink(t.to_string())),
    ];
    (
        prop_oneof![4 => select(ENTRY_NAMES).prop_map(str::to_string), 1 => "[a-z/.]{1,12}"],
        body,
        any::<bool>(),
    )
}

/// The entries of an archive: a system and the sets its seeds bind by file (each edited at
/// most a little, so that many archives still read), then up to three entries of any kind.
fn archive() -> impl Strategy<Value = Vec<(String, EntryBody, bool)>> {
    let light_edits = || proptest::collection::vec(edit(), 0..2);
    (
        (any::<Index>(), light_edits(), any::<bool>()),
        (any::<Index>(), light_edits(), any::<bool>()),
        proptest::collection::vec(entry(), 0..3),
    )
        .prop_map(|((ssd, ssd_edits, z1), (ssv, ssv_edits, z2), extra)| {
            let mut entries = vec![(
                "SystemStructure.ssd".to_string(),
                EntryBody::Document(ssd, true, ssd_edits),
                z1,
            )];
            for name in ["resources/plant.ssv", "resources/motor.ssv"] {
                entries.push((
                    name.to_string(),
                    EntryBody::Document(ssv, false, ssv_edits.clone()),
                    z2,
                ));
            }
            entries.extend(extra);
            entries
        })
}

/// A zip of `entries` (name, body, deflated?); entries the writer refuses are left out.
fn zip_of(entries: &[(String, EntryBody, bool)]) -> Vec<u8> {
    use zip::write::SimpleFileOptions;
    let mut z = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    for (name, body, deflate) in entries {
        let method = if *deflate {
            zip::CompressionMethod::Deflated
        } else {
            zip::CompressionMethod::Stored
        };
        let opts = SimpleFileOptions::default().compression_method(method);
        let _ = match body {
            EntryBody::Document(i, is_ssd, e) => {
                let docs = valid_documents(if *is_ssd { "ssd_reader" } else { "ssv_reader" });
                let bytes = apply(&docs[i.index(docs.len())], e);
                z.start_file(name.as_str(), opts)
                    .map(|_| z.write_all(&bytes))
            }
            EntryBody::Zeros(n) => z
                .start_file(name.as_str(), opts)
                .map(|_| z.write_all(&vec![0; *n])),
            EntryBody::Directory => z.add_directory(name.as_str(), opts).map(|_| Ok(())),
            EntryBody::Symlink(t) => z
                .add_symlink(name.as_str(), t.as_str(), opts)
                .map(|_| Ok(())),
        };
    }
    z.finish().map(|c| c.into_inner()).unwrap_or_default()
}

#[derive(Debug, Clone)]
enum Corruption {
    None,
    Bytes(Vec<(Index, u8)>),
    Truncate(Index),
}

fn corruption() -> impl Strategy<Value = Corruption> {
    prop_oneof![
        4 => Just(Corruption::None),
        2 => proptest::collection::vec((any::<Index>(), any::<u8>()), 1..8).prop_map(Corruption::Bytes),
        1 => any::<Index>().prop_map(Corruption::Truncate),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1000, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn the_ssp_archive_reader_takes_edited_archives(
        entries in archive(),
        many in prop_oneof![9 => Just(0usize), 1 => Just(40usize)],
        corrupt in corruption(),
    ) {
        let mut entries = entries;
        for k in 0..many {
            entries.push((format!("resources/f{k}"), EntryBody::Zeros(1), false));
        }
        let mut bytes = zip_of(&entries);
        match corrupt {
            Corruption::None => {}
            Corruption::Bytes(b) => {
                for (i, v) in b {
                    if !bytes.is_empty() {
                        let k = i.index(bytes.len());
                        bytes[k] = v;
                    }
                }
            }
            Corruption::Truncate(i) => bytes.truncate(i.index(bytes.len() + 1)),
        }
        readers::ssp_archive(&bytes);
    }
}

// ---------------------------------------------------------------------------------------------
// Typed values written and read back

/// Names: identifiers, any printable text, and text with every character the writers escape.
fn text() -> impl Strategy<Value = String> {
    prop_oneof![
        3 => "[a-zA-Z_][a-zA-Z0-9_.\\[\\]]{0,12}",
        2 => "\\PC{0,10}",
        2 => select(&["a&b", "<x>", "\"q\"", "it's", "tab\there", "new\nline", "cr\rx", " lead",
            "trail ", "é", "\u{feff}x", "&amp;", "]]>", "\u{1}"][..]).prop_map(str::to_string),
    ]
}

fn finite() -> impl Strategy<Value = f64> {
    prop_oneof![
        any::<f64>().prop_filter("finite", |v| v.is_finite()),
        select(
            &[
                0.0,
                -0.0,
                f64::MIN_POSITIVE,
                5e-324,
                f64::MAX,
                f64::MIN,
                0.1,
                1e21
            ][..]
        ),
    ]
}

fn parameter_set() -> impl Strategy<Value = ParameterSet> {
    let value = prop_oneof![
        finite().prop_map(ParamValue::Real),
        any::<i32>().prop_map(ParamValue::Integer),
        any::<bool>().prop_map(ParamValue::Boolean),
        text().prop_map(ParamValue::String),
    ];
    let unit_def = (
        proptest::array::uniform8(-4i32..=4),
        prop_oneof![Just(1.0), finite()],
        prop_oneof![Just(0.0), finite()],
    );
    (
        text(),
        text(),
        proptest::option::of(text()),
        proptest::collection::vec(
            (text(), value, proptest::option::of(text()), unit_def),
            0..8,
        ),
    )
        .prop_map(|(name, version, description, params)| {
            let mut set = ParameterSet::new(&name, &version);
            set.description = description;
            for (name, value, unit, (exponents, factor, offset)) in params {
                if set.parameters.iter().any(|p| p.name == name) {
                    continue;
                }
                let unit = match value {
                    ParamValue::Real(_) => unit,
                    _ => None,
                };
                if let Some(u) = &unit
                    && !set.units.iter().any(|d| &d.name == u)
                {
                    set.units.push(UnitDefinition {
                        name: u.clone(),
                        exponents,
                        factor,
                        offset,
                    });
                }
                set.parameters.push(Parameter {
                    name,
                    value,
                    unit,
                    line: 0,
                });
            }
            set
        })
}

fn connector() -> impl Strategy<Value = SspConnector> {
    let kind = select(
        &[
            ConnectorKind::Input,
            ConnectorKind::Output,
            ConnectorKind::Parameter,
            ConnectorKind::CalculatedParameter,
            ConnectorKind::Inout,
        ][..],
    );
    let ty = proptest::option::of(prop_oneof![
        proptest::option::of(text()).prop_map(|unit| ConnectorType::Real { unit }),
        Just(ConnectorType::Integer),
        Just(ConnectorType::Boolean),
        Just(ConnectorType::String),
        Just(ConnectorType::Enumeration),
    ]);
    (text(), kind, ty).prop_map(|(name, kind, ty)| SspConnector { name, kind, ty })
}

fn ssp_value() -> impl Strategy<Value = Value> {
    prop_oneof![
        any::<f64>().prop_map(Value::Real),
        any::<i32>().prop_map(Value::Integer),
        any::<bool>().prop_map(Value::Boolean),
        text().prop_map(Value::String),
    ]
}

fn component() -> impl Strategy<Value = SspComponent> {
    (
        text(),
        text(),
        proptest::collection::vec(connector(), 0..4),
        proptest::collection::vec(text(), 0..2),
        proptest::collection::vec((text(), ssp_value()), 0..4),
        proptest::option::of(any::<u64>()),
    )
        .prop_map(
            |(name, source, connectors, sources, params, step_multiple)| SspComponent {
                name,
                source,
                connectors,
                parameter_sources: sources,
                parameters: params
                    .into_iter()
                    .map(|(name, value)| SspParameter { name, value })
                    .collect(),
                step_multiple,
            },
        )
}

fn ssd() -> impl Strategy<Value = Ssd> {
    let connection = (
        proptest::option::of(text()),
        text(),
        proptest::option::of(text()),
        text(),
    )
        .prop_map(|(a, b, c, d)| SspConnection {
            start_element: a,
            start_connector: b,
            end_element: c,
            end_connector: d,
        });
    let experiment = proptest::option::of(
        (
            proptest::option::of(any::<f64>()),
            proptest::option::of(any::<f64>()),
            proptest::option::of(any::<f64>()),
            proptest::option::of(select(&[Algorithm::Jacobi, Algorithm::GaussSeidel][..])),
        )
            .prop_map(|(s, e, h, a)| SspExperiment {
                start_time: s,
                stop_time: e,
                step_size: h,
                algorithm: a,
            }),
    );
    (
        text(),
        text(),
        proptest::collection::vec(component(), 0..4),
        proptest::collection::vec(connection, 0..4),
        experiment,
    )
        .prop_map(
            |(name, system, components, connections, default_experiment)| Ssd {
                name,
                version: "1.0".into(),
                system: SspSystem {
                    name: system,
                    components,
                    connections,
                },
                default_experiment,
            },
        )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1500, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn any_parameter_set_written_reads_back(set in parameter_set()) {
        readers::ssv_round_trip(&set);
    }

    #[test]
    fn any_system_written_reads_back(ssd in ssd()) {
        readers::ssd_round_trip(&ssd);
    }
}

#[test]
fn a_document_with_an_element_before_or_after_its_root_is_refused() {
    let elements = [
        "<x/>",
        "<SystemStructureDescription version=\"1.0\"><System/></SystemStructureDescription>",
        "<Elements><Component name=\"extra\" source=\"extra.fmu\"/></Elements>",
        "<ssv:ParameterSet version=\"1.0\" name=\"second\"/>",
        "<fmiModelDescription/>",
    ];
    for target in ["model_description", "ssd_reader", "ssv_reader"] {
        for doc in valid_documents(target) {
            // After the root, and before it (after the XML declaration, if any).
            let body = doc.find("?>").map_or(0, |i| i + 2);
            for element in elements {
                let after = format!("{doc}{element}");
                let before = format!("{}{element}{}", &doc[..body], &doc[body..]);
                for (place, text) in [("after", after), ("before", before)] {
                    assert!(
                        reads(target, text.as_bytes()).is_err(),
                        "{target} accepted a document with {element} {place} its root"
                    );
                }
            }
        }
    }
}

/// The edits must leave the readers both documents to accept (so that the round trip is
/// exercised) and documents to refuse: a generator that only ever breaks the document, or never
/// does, would make the runs above test little.
#[test]
fn the_edited_documents_are_both_accepted_and_refused() {
    use proptest::strategy::ValueTree;
    use proptest::test_runner::TestRunner;
    for target in ["model_description", "ssd_reader", "ssv_reader"] {
        let docs = valid_documents(target);
        let mut runner = TestRunner::deterministic();
        let strategy = (any::<Index>(), edits());
        let cases = 300;
        let mut accepted = 0;
        for _ in 0..cases {
            let (doc, edits) = strategy.new_tree(&mut runner).unwrap().current();
            if reads(target, &apply(&docs[doc.index(docs.len())], &edits)).is_ok() {
                accepted += 1;
            }
        }
        eprintln!("{target}: {accepted} of {cases} edited documents read");
        assert!(
            (cases / 20..=cases * 9 / 10).contains(&accepted),
            "{target}: {accepted} of {cases} edited documents read"
        );
    }
    let mut runner = TestRunner::deterministic();
    let strategy = archive();
    let cases = 200;
    let mut accepted = 0;
    for _ in 0..cases {
        let entries = strategy.new_tree(&mut runner).unwrap().current();
        if reads("ssp_archive", &zip_of(&entries)).is_ok() {
            accepted += 1;
        }
    }
    eprintln!("ssp_archive: {accepted} of {cases} archives read");
    assert!(
        (cases / 20..=cases * 9 / 10).contains(&accepted),
        "{accepted} of {cases} archives read"
    );
}

/// Found by cargo fuzz (`ssv_reader`, after 182,088 runs): a document starting with two byte
/// order marks panicked the `.ssv` reader, which cut its text at the XML parser's position,
/// inside the second mark (`seeds/*/regression_two_byte_order_marks.*`): the parser skips a
/// mark the reader left and counts its positions from after it. The same made the
/// model-description reader cut `Tool` annotations three bytes off (found by this test) and
/// the SSD reader its inline parameter sets. One mark is allowed; more are refused.
#[test]
fn one_byte_order_mark_is_read_and_more_are_refused() {
    for target in ["model_description", "ssd_reader", "ssv_reader"] {
        let docs = valid_documents(target).iter().map(String::as_str);
        for doc in docs.chain(["1", "", "<x/>"]) {
            for prefix in [
                "\u{feff}",
                "\u{feff}\u{feff}",
                "\u{feff} \u{feff}",
                "\u{feff}\u{feff}\u{feff}",
            ] {
                property(target)(format!("{prefix}{doc}").as_bytes());
            }
        }
        for doc in valid_documents(target) {
            reads(target, format!("\u{feff}{doc}").as_bytes())
                .unwrap_or_else(|e| panic!("{target}: {e}"));
            for marks in ["\u{feff}\u{feff}", "\u{feff}\u{feff}\u{feff}"] {
                let err = reads(target, format!("{marks}{doc}").as_bytes())
                    .expect_err("two byte order marks are refused");
                assert!(err.contains("a second byte order mark"), "{target}: {err}");
            }
        }
    }
}
