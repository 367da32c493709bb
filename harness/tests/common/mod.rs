//! Test support: a tiny C FMU (`kbtest.c`, against the official FMI 2.0 headers) compiled with
//! the system C compiler and packed into `.fmu` archives with a hand-written model description.

#![allow(dead_code)]

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use zip::write::SimpleFileOptions;

pub const GUID: &str = "{kbtest-0001}";

/// The model description of kbtest.
pub fn model_description(guid: &str) -> String {
    format!(
        r#"<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="kbtest" guid="{guid}" variableNamingConvention="flat" numberOfEventIndicators="0">
  <CoSimulation modelIdentifier="kbtest" canHandleVariableCommunicationStepSize="true" canGetAndSetFMUstate="true" canSerializeFMUstate="true" canNotUseMemoryManagementFunctions="true"/>
  <DefaultExperiment startTime="0" stopTime="1" stepSize="0.1"/>
  <ModelVariables>
    <ScalarVariable name="u" valueReference="0" causality="input" variability="continuous"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="y" valueReference="1" causality="output" variability="continuous" initial="calculated"><Real/></ScalarVariable>
    <ScalarVariable name="k" valueReference="2" causality="parameter" variability="tunable" initial="exact"><Real start="1"/></ScalarVariable>
    <ScalarVariable name="b" valueReference="3" causality="parameter" variability="tunable" initial="exact"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="x" valueReference="4" causality="output" variability="continuous" initial="exact"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="t" valueReference="5" causality="output" variability="continuous" initial="exact"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="discard_at" valueReference="6" causality="parameter" variability="fixed" initial="exact"><Real start="-1"/></ScalarVariable>
    <ScalarVariable name="error_at" valueReference="7" causality="parameter" variability="fixed" initial="exact"><Real start="-1"/></ScalarVariable>
    <ScalarVariable name="steps" valueReference="0" causality="output" variability="discrete" initial="exact"><Integer start="0"/></ScalarVariable>
    <ScalarVariable name="i_in" valueReference="1" causality="input" variability="discrete"><Integer start="0"/></ScalarVariable>
    <ScalarVariable name="i_out" valueReference="2" causality="output" variability="discrete" initial="calculated"><Integer/></ScalarVariable>
    <ScalarVariable name="b_in" valueReference="0" causality="input" variability="discrete"><Boolean start="false"/></ScalarVariable>
    <ScalarVariable name="b_out" valueReference="1" causality="output" variability="discrete" initial="calculated"><Boolean/></ScalarVariable>
  </ModelVariables>
  <ModelStructure>
    <Outputs>
      <Unknown index="2" dependencies="1"/>
      <Unknown index="5" dependencies=""/>
      <Unknown index="6" dependencies=""/>
      <Unknown index="9" dependencies=""/>
      <Unknown index="11" dependencies="10"/>
      <Unknown index="13" dependencies="12"/>
    </Outputs>
    <InitialUnknowns>
      <Unknown index="2" dependencies="1 3 4"/>
      <Unknown index="11" dependencies="10"/>
      <Unknown index="13" dependencies="12"/>
    </InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"#
    )
}

fn build_dir() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let d =
            std::env::temp_dir().join(format!("kneebench-harness-tests-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    })
}

/// The harness crate's directory, from this crate or from the tests crate, which includes this
/// module by path (`tests/tests/end_of_run.rs`): `<crate>/../harness` is the harness in both.
fn harness_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../harness")
}

/// Compiles kbtest.c against the official FMI 2.0 headers (vendored in
/// `tests/hostile_fmu/fmi2/`) into a shared library, once per test binary, with every warning
/// an error; returns its path.
pub fn kbtest_so() -> &'static Path {
    static SO: OnceLock<PathBuf> = OnceLock::new();
    SO.get_or_init(|| compile_kbtest(&[]))
}

/// kbtest compiled with the given preprocessor symbols defined (e.g.
/// `KBTEST_WITHOUT_DIRECTIONAL_DERIVATIVE`), into a library of its own.
pub fn compile_kbtest(defines: &[&str]) -> PathBuf {
    let tests = harness_dir().join("tests");
    let out = build_dir().join(format!("kbtest{}.so", defines.join("-")));
    let cc = std::env::var("CC").unwrap_or_else(|_| "cc".into());
    let o = Command::new(cc)
        .args(["-std=c99", "-shared", "-fPIC", "-O2", "-fvisibility=hidden"])
        .args(["-Wall", "-Wextra", "-Werror"])
        .args(defines.iter().map(|d| format!("-D{d}")))
        .arg(format!("-I{}", tests.join("hostile_fmu/fmi2").display()))
        .arg("-o")
        .arg(&out)
        .arg(tests.join("common/kbtest.c"))
        .output()
        .expect("run the C compiler");
    assert!(
        o.status.success(),
        "compiling kbtest.c failed:\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    out
}

/// What to put into a test archive.
pub struct FmuSpec {
    pub model_description: Option<String>,
    pub binary: bool,
    /// The binary to pack instead of [`kbtest_so`].
    pub binary_path: Option<PathBuf>,
    pub extra: Vec<(String, Vec<u8>)>,
}

impl Default for FmuSpec {
    fn default() -> Self {
        FmuSpec {
            model_description: Some(model_description(GUID)),
            binary: true,
            binary_path: None,
            extra: vec![("resources/readme.txt".into(), b"test resource".to_vec())],
        }
    }
}

/// Writes an FMU archive at `path`.
pub fn write_fmu(path: &Path, spec: &FmuSpec) {
    let f = std::fs::File::create(path).unwrap();
    let mut z = zip::ZipWriter::new(f);
    let o = SimpleFileOptions::default().compression_method(zip::CompressionMethod::Deflated);
    if let Some(md) = &spec.model_description {
        z.start_file("modelDescription.xml", o).unwrap();
        z.write_all(md.as_bytes()).unwrap();
    }
    if spec.binary {
        z.add_directory("binaries/linux64/", o).unwrap();
        z.start_file("binaries/linux64/kbtest.so", o).unwrap();
        let so = spec.binary_path.as_deref().unwrap_or(kbtest_so());
        z.write_all(&std::fs::read(so).unwrap()).unwrap();
    }
    for (name, bytes) in &spec.extra {
        z.start_file(name.as_str(), o).unwrap();
        z.write_all(bytes).unwrap();
    }
    z.finish().unwrap();
}

/// A valid kbtest FMU in `dir`.
pub fn kbtest_fmu(dir: &Path) -> PathBuf {
    let p = dir.join("kbtest.fmu");
    if !p.exists() {
        write_fmu(&p, &FmuSpec::default());
    }
    p
}

/// The bench's FMUs exported by the `kneebench` binary `bin` into `dir/fmus` (the FMU library
/// is built next to it, or under `deps/` in the workspace's test build).
pub fn exported_fmus(bin: &Path, dir: &Path) -> PathBuf {
    let lib = ["libkneebench_fmu.so", "deps/libkneebench_fmu.so"]
        .iter()
        .map(|f| bin.parent().unwrap().join(f))
        .find(|p| p.is_file())
        .expect("libkneebench_fmu.so built next to kneebench");
    let out = dir.join("fmus");
    let e = Command::new(bin)
        .args(["export", "--out"])
        .arg(&out)
        .arg("--library")
        .arg(lib)
        .output()
        .unwrap();
    assert!(e.status.success(), "{}", String::from_utf8_lossy(&e.stderr));
    out
}
