//! fmpy is the oracle: every FMU we ship passes `fmpy validate` with no problems, and fmpy's
//! co-simulation of it gives the same values as our harness (through the C ABI), as the
//! reference results packed in the FMU, and as a plain Rust call of the model.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use kneebench_harness::Results;
use kneebench_harness::package::{ExportedFmu, export_all};
use kneebench_tests::*;

/// FMUs exported once for this test binary.
fn exported() -> &'static (tempfile::TempDir, Vec<ExportedFmu>) {
    static FMUS: OnceLock<(tempfile::TempDir, Vec<ExportedFmu>)> = OnceLock::new();
    FMUS.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let fmus = export_all(&fmu_library(), dir.path()).expect("export");
        (dir, fmus)
    })
}

fn fmpy_check(args: &[&str]) -> std::process::Output {
    Command::new(python())
        .arg(repo_root().join("scripts/fmpy_check.py"))
        .args(args)
        .output()
        .unwrap()
}

fn read_csv(path: &Path) -> Results {
    Results::read_csv_file(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn assert_close(ours: &Results, theirs: &Results, what: &str) {
    assert_eq!(ours.len(), theirs.len(), "{what}: row count");
    for name in theirs.names() {
        let a = ours
            .column(name)
            .unwrap_or_else(|| panic!("{what}: no column {name}"));
        let b = theirs.column(name).unwrap();
        for (k, (x, y)) in a.iter().zip(&b).enumerate() {
            assert!(
                (x - y).abs() <= 1e-12 * (1.0 + x.abs().max(y.abs())),
                "{what}: {name} row {k}: {x} vs {y}"
            );
        }
    }
    let (ta, tb) = (ours.times(), theirs.times());
    for (x, y) in ta.iter().zip(&tb) {
        assert!(
            (x - y).abs() <= 1e-12 * (1.0 + x.abs()),
            "{what}: time {x} vs {y}"
        );
    }
}

fn extra_file(fmu: &Path, name: &str) -> Option<Vec<u8>> {
    let mut zip = zip::ZipArchive::new(std::fs::File::open(fmu).unwrap()).unwrap();
    let mut f = zip.by_name(name).ok()?;
    let mut v = Vec::new();
    std::io::Read::read_to_end(&mut f, &mut v).unwrap();
    Some(v)
}

#[test]
fn fmpy_validates_every_fmu_with_no_problems() {
    let (_, fmus) = exported();
    assert!(!fmus.is_empty());
    let paths: Vec<String> = fmus.iter().map(|f| f.path.display().to_string()).collect();
    let mut args = vec!["validate"];
    args.extend(paths.iter().map(String::as_str));
    let out = fmpy_check(&args);
    assert!(
        out.status.success(),
        "fmpy found problems:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn fmpy_simulation_matches_our_runs() {
    let (dir, fmus) = exported();
    for fmu in fmus {
        let md = kneebench_harness::Fmu::load(&fmu.path, &Default::default())
            .unwrap()
            .model_description()
            .clone();
        let exp = md.default_experiment.clone().unwrap();
        let (stop, step) = (exp.stop_time.unwrap(), exp.step_size.unwrap());
        let theirs_path: PathBuf = dir.path().join(format!("{}-fmpy.csv", fmu.identifier));
        let inputs_path = dir.path().join(format!("{}-inputs.csv", fmu.identifier));
        let mut args = vec![
            "simulate".to_string(),
            fmu.path.display().to_string(),
            stop.to_string(),
            step.to_string(),
            theirs_path.display().to_string(),
        ];
        if let Some(inputs) = extra_file(&fmu.path, "extra/reference-inputs.csv") {
            std::fs::write(&inputs_path, inputs).unwrap();
            args.push(inputs_path.display().to_string());
        }
        let argv: Vec<&str> = args.iter().map(String::as_str).collect();
        let out = fmpy_check(&argv);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let theirs = read_csv(&theirs_path);
        // The reference results packed in the FMU were made by our harness on the same grid.
        let packed = extra_file(&fmu.path, "extra/reference-outputs.csv").expect("extra/");
        let ours = Results::read_csv(packed.as_slice(), Path::new("packed")).unwrap();
        assert_close(&ours, &theirs, &fmu.identifier);
    }
}

#[test]
fn gait_reference_through_fmpy_matches_the_plain_rust_model() {
    use kneebench_fmu::model::Model;
    use kneebench_fmu::models::gait::GaitReference;
    let (_, fmus) = exported();
    let fmu = fmus
        .iter()
        .find(|f| f.identifier == "GaitReference")
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("fmpy.csv");
    let o = fmpy_check(&[
        "simulate",
        &fmu.path.display().to_string(),
        "2.5",
        "0.001",
        &out.display().to_string(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let theirs = read_csv(&out);
    let mut model = kneebench_fmu::fmi2::instance::fresh_model::<GaitReference>();
    let angle = theirs.column("kneeAngleReference").unwrap();
    let torque = theirs.column("loadTorqueReference").unwrap();
    let vars = GaitReference::variables();
    let get = |m: &GaitReference, name: &str| match vars
        .iter()
        .find(|v| v.name == name)
        .unwrap()
        .access
    {
        kneebench_fmu::model::Access::Real(g, _) => g(m),
        _ => unreachable!(),
    };
    for (k, t) in theirs.times().iter().enumerate() {
        model.calculate(*t).unwrap();
        assert!(
            (get(&model, "kneeAngleReference") - angle[k]).abs() < 1e-12,
            "row {k}"
        );
        assert!(
            (get(&model, "loadTorqueReference") - torque[k]).abs() < 1e-12,
            "row {k}"
        );
    }
}

/// Every FMU that declares `maxOutputDerivativeOrder` >= 1 answers order 1 for every Real output
/// through fmpy's own `fmi2GetRealOutputDerivatives` call, and each answer agrees with a central
/// difference of the output (`scripts/fmpy_check.py derivatives`); the plant driven by both
/// motors, so that it moves.
#[test]
fn fmpy_gets_every_promised_output_derivative() {
    let (_, fmus) = exported();
    for fmu in fmus {
        let path = fmu.path.display().to_string();
        let mut args = vec!["derivatives", path.as_str()];
        if fmu.identifier == "BenchPlant" {
            args.extend(["testCurrentCommand=3", "loadCurrentCommand=-0.5"]);
        }
        let o = fmpy_check(&args);
        let stdout = String::from_utf8_lossy(&o.stdout);
        assert!(
            o.status.success(),
            "{}: {stdout}{}",
            fmu.identifier,
            String::from_utf8_lossy(&o.stderr)
        );
        let expected = match fmu.identifier.as_str() {
            "BenchPlant" => "maxOutputDerivativeOrder=1: 67 Real outputs, 0 problems",
            "GaitReference" => "maxOutputDerivativeOrder=1: 7 Real outputs, 0 problems",
            _ => "maxOutputDerivativeOrder=0: none promised",
        };
        assert!(stdout.contains(expected), "{}: {stdout}", fmu.identifier);
    }
}

#[test]
fn the_same_sources_give_byte_identical_archives() {
    let (_, first) = exported();
    let dir = tempfile::tempdir().unwrap();
    let second = export_all(&fmu_library(), dir.path()).unwrap();
    for (a, b) in first.iter().zip(&second) {
        assert_eq!(
            std::fs::read(&a.path).unwrap(),
            std::fs::read(&b.path).unwrap(),
            "{}",
            a.identifier
        );
    }
}

#[test]
fn archives_hold_description_binary_documentation_and_reference_run() {
    let (_, fmus) = exported();
    for fmu in fmus {
        let id = &fmu.identifier;
        for name in [
            "modelDescription.xml".to_string(),
            format!("binaries/linux64/{id}.so"),
            "documentation/index.html".to_string(),
            "extra/reference-outputs.csv".to_string(),
            "extra/README.txt".to_string(),
        ] {
            assert!(
                extra_file(&fmu.path, &name).is_some(),
                "{id}: {name} missing"
            );
        }
        let xml =
            String::from_utf8(extra_file(&fmu.path, "modelDescription.xml").unwrap()).unwrap();
        let md = model_description::ModelDescription::from_xml(&xml).unwrap();
        assert_eq!(md.license.as_deref(), Some("MIT OR Apache-2.0"));
        assert_eq!(md.author.as_deref(), Some("The kneebench developers"));
        assert!(
            md.generation_tool
                .as_deref()
                .unwrap()
                .starts_with("kneebench ")
        );
        assert_eq!(md.version.as_deref(), Some(env!("CARGO_PKG_VERSION")));
        let doc =
            String::from_utf8(extra_file(&fmu.path, "documentation/index.html").unwrap()).unwrap();
        for v in &md.model_variables {
            assert!(
                doc.contains(&v.name),
                "{id}: documentation lacks {}",
                v.name
            );
        }
    }
}
