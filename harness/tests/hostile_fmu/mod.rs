//! Test support: the hostile FMU (`hostile.c`, compiled against the official FMI 2.0 headers
//! vendored in `fmi2/`) packed into an `.fmu` with a hand-written model description.
//!
//! The behaviour is chosen by the Integer parameter `mode` (one of the `MODE_*` constants, the
//! same numbers as in `hostile.c`) and fires in the first `fmi2DoStep` whose end passes the
//! Real parameter `at`.

#![allow(dead_code)]

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use zip::write::SimpleFileOptions;

/// Writes through a NULL pointer.
pub const MODE_SEGFAULT: i32 = 1;
/// `abort()`.
pub const MODE_ABORT: i32 = 2;
/// `exit(0)`.
pub const MODE_EXIT: i32 = 3;
/// An infinite loop.
pub const MODE_HANG: i32 = 4;
/// `y` becomes NaN with fmi2OK.
pub const MODE_NAN: i32 = 5;
/// `y` becomes +Inf with fmi2OK.
pub const MODE_INF: i32 = 6;
/// fmi2Warning (the step is done).
pub const MODE_WARNING: i32 = 7;
/// fmi2Discard, terminated, lastSuccessfulTime = the step's start.
pub const MODE_DISCARD: i32 = 8;
/// fmi2Error.
pub const MODE_ERROR: i32 = 9;
/// fmi2Fatal.
pub const MODE_FATAL: i32 = 10;
/// fmi2Pending.
pub const MODE_PENDING: i32 = 11;
/// Garbage on standard output, then fmi2OK.
pub const MODE_STDOUT: i32 = 12;
/// fmi2OK, and a thread ends the process with `_exit(7)` 200 ms later.
pub const MODE_EXIT_LATER: i32 = 13;

/// The model description of the hostile FMU (`generation_tool` as given).
pub fn model_description(generation_tool: &str) -> String {
    format!(
        r#"<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="Hostile" guid="{{kneebench-hostile-0001}}" generationTool="{generation_tool}" variableNamingConvention="flat" numberOfEventIndicators="0">
  <CoSimulation modelIdentifier="hostile" canHandleVariableCommunicationStepSize="true"/>
  <DefaultExperiment startTime="0" stopTime="1" stepSize="0.1"/>
  <ModelVariables>
    <ScalarVariable name="u" valueReference="0" causality="input" variability="continuous"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="y" valueReference="1" causality="output" variability="continuous" initial="calculated"><Real/></ScalarVariable>
    <ScalarVariable name="t" valueReference="2" causality="output" variability="continuous" initial="exact"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="at" valueReference="3" causality="parameter" variability="fixed" initial="exact"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="mode" valueReference="0" causality="parameter" variability="fixed" initial="exact"><Integer start="0"/></ScalarVariable>
    <ScalarVariable name="steps" valueReference="1" causality="output" variability="discrete" initial="exact"><Integer start="0"/></ScalarVariable>
    <ScalarVariable name="pace" valueReference="4" causality="parameter" variability="fixed" initial="exact"><Real start="0"/></ScalarVariable>
  </ModelVariables>
  <ModelStructure>
    <Outputs>
      <Unknown index="2" dependencies="1"/>
      <Unknown index="3" dependencies=""/>
      <Unknown index="6" dependencies=""/>
    </Outputs>
    <InitialUnknowns>
      <Unknown index="2" dependencies="1"/>
    </InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"#
    )
}

fn build_dir() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        // Inside the target directory (removed by `cargo clean`), one per test process.
        let d =
            Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("hostile-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    })
}

/// Compiles hostile.c against the official headers (once per test binary), with every warning
/// an error; returns the shared library.
pub fn hostile_so() -> &'static Path {
    static SO: OnceLock<PathBuf> = OnceLock::new();
    SO.get_or_init(|| {
        let here = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/hostile_fmu");
        let out = build_dir().join("hostile.so");
        let cc = std::env::var("CC").unwrap_or_else(|_| "cc".into());
        let o = Command::new(cc)
            .args([
                "-std=c99",
                "-D_POSIX_C_SOURCE=200809L",
                "-shared",
                "-fPIC",
                "-O2",
            ])
            .args(["-Wall", "-Wextra", "-Werror"])
            .arg(format!("-I{}", here.join("fmi2").display()))
            .arg("-o")
            .arg(&out)
            .arg(here.join("hostile.c"))
            .arg("-lm")
            .output()
            .expect("run the C compiler");
        assert!(
            o.status.success(),
            "compiling hostile.c failed:\n{}",
            String::from_utf8_lossy(&o.stderr)
        );
        out
    })
}

/// Writes `Hostile.fmu` (generationTool "hostile-tests": a foreign FMU) into `dir`.
pub fn hostile_fmu(dir: &Path) -> PathBuf {
    hostile_fmu_by(dir, "hostile-tests")
}

/// Writes `Hostile.fmu` with the given generationTool into `dir`.
pub fn hostile_fmu_by(dir: &Path, generation_tool: &str) -> PathBuf {
    let p = dir.join("Hostile.fmu");
    let f = std::fs::File::create(&p).unwrap();
    let mut z = zip::ZipWriter::new(f);
    let o = SimpleFileOptions::default().compression_method(zip::CompressionMethod::Deflated);
    z.start_file("modelDescription.xml", o).unwrap();
    z.write_all(model_description(generation_tool).as_bytes())
        .unwrap();
    z.start_file("binaries/linux64/hostile.so", o).unwrap();
    z.write_all(&std::fs::read(hostile_so()).unwrap()).unwrap();
    z.finish().unwrap();
    p
}
