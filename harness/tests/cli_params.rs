//! `kneebench run --params SET.ssv`: the result file records which set produced it (the
//! set's label, `name vN (sha256 ...)`, in the Parquet metadata), and a set that the FMU
//! refuses stops the run before anything runs, naming the file and line.

use std::path::{Path, PathBuf};
use std::process::Command;

use parquet::file::reader::{FileReader, SerializedFileReader};

fn kneebench() -> Command {
    Command::new(env!("CARGO_BIN_EXE_kneebench"))
}

/// The FMU library built with the binary (`cargo build --release --workspace`, or the
/// workspace's test build, which puts it under `deps/`).
fn fmu_library() -> PathBuf {
    let dir = Path::new(env!("CARGO_BIN_EXE_kneebench")).parent().unwrap();
    [
        dir.join("libkneebench_fmu.so"),
        dir.join("deps/libkneebench_fmu.so"),
    ]
    .into_iter()
    .find(|p| p.is_file())
    .expect("libkneebench_fmu.so is not built next to kneebench")
}

/// A one-parameter set for the plant: twice the actuation inertia.
const HEAVY: &str = r#"<?xml version="1.0" encoding="UTF-8"?>
<ssv:ParameterSet xmlns:ssc="http://ssp-standard.org/SSP1/SystemStructureCommon" xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues" version="1.0" name="heavy">
  <ssv:Parameters>
    <ssv:Parameter name="actuationInertia">
      <ssv:Real value="VALUE" unit="kg.m2"/>
    </ssv:Parameter>
  </ssv:Parameters>
  <ssv:Units>
    <ssc:Unit name="kg.m2">
      <ssc:BaseUnit kg="1" m="2"/>
    </ssc:Unit>
  </ssv:Units>
</ssv:ParameterSet>
"#;

fn metadata(path: &Path) -> Vec<(String, String)> {
    let reader = SerializedFileReader::new(std::fs::File::open(path).unwrap()).unwrap();
    reader
        .metadata()
        .file_metadata()
        .key_value_metadata()
        .map(|kv| {
            kv.iter()
                .map(|e| (e.key.clone(), e.value.clone().unwrap_or_default()))
                .collect()
        })
        .unwrap_or_default()
}

#[test]
fn a_run_with_a_parameter_set_names_it_in_its_results_and_a_refused_set_runs_nothing() {
    let d = tempfile::tempdir().unwrap();
    let fmus = d.path().join("fmus");
    let export = kneebench()
        .args(["export", "--out"])
        .arg(&fmus)
        .arg("--library")
        .arg(fmu_library())
        .output()
        .unwrap();
    assert!(
        export.status.success(),
        "{}",
        String::from_utf8_lossy(&export.stderr)
    );
    let set = d.path().join("heavy.ssv");
    std::fs::write(&set, HEAVY.replace("VALUE", "1.65")).unwrap();
    let out = d.path().join("r.parquet");
    let run = |set: &Path| {
        kneebench()
            .arg("run")
            .arg(fmus.join("BenchPlant.fmu"))
            .args(["--stop-time", "0.05", "--step", "0.001", "-q", "--params"])
            .arg(set)
            .arg("--output")
            .arg(&out)
            .output()
            .unwrap()
    };
    let ok = run(&set);
    let stderr = String::from_utf8_lossy(&ok.stderr).into_owned();
    assert_eq!(ok.status.code(), Some(0), "{stderr}");
    let meta = metadata(&out);
    let sets = meta
        .iter()
        .find(|(k, _)| k == "kneebench.parameter_sets")
        .map(|(_, v)| v.clone())
        .unwrap_or_else(|| panic!("no parameter set in the metadata: {meta:?}"));
    assert!(sets.starts_with("heavy "), "{sets}");
    assert!(sets.contains("(sha256 "), "{sets}");
    // The label printed is the label recorded.
    assert!(
        stderr.contains(&format!("parameter set: {sets}")),
        "{stderr}"
    );

    // Another value, another hash.
    std::fs::write(&set, HEAVY.replace("VALUE", "1.7")).unwrap();
    assert_eq!(run(&set).status.code(), Some(0));
    let other = metadata(&out)
        .into_iter()
        .find(|(k, _)| k == "kneebench.parameter_sets")
        .unwrap()
        .1;
    assert_ne!(other, sets);

    // Out of the declared range: refused with the file and line, the earlier results kept.
    std::fs::write(&set, HEAVY.replace("VALUE", "-1")).unwrap();
    // A usage error (exit code 2), found before anything runs.
    let bad = run(&set);
    assert_eq!(bad.status.code(), Some(2));
    let e = String::from_utf8_lossy(&bad.stderr);
    assert!(e.contains("heavy.ssv:5:"), "{e}");
    assert!(e.contains("actuationInertia"), "{e}");
    assert_eq!(
        metadata(&out)
            .into_iter()
            .find(|(k, _)| k == "kneebench.parameter_sets")
            .unwrap()
            .1,
        other
    );
}
