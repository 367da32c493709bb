//! `kneebench run SYSTEM --replace plant=BenchHardware.fmu`: the study's schedule on the
//! hardware FMU (its in-process simulated backend here), the interface checked, enumeration
//! parameters by item name.

use std::path::{Path, PathBuf};

use kneebench_harness::ssp::{self, SspError};
use kneebench_harness::study::{Actuator, StudyScenario, gait_scenario, write_ssp};
use kneebench_harness::{LoadOptions, MasterError, Outcome};

fn fmus() -> &'static Path {
    kneebench_tests::exported_fmus().0.path()
}

fn sea_ssp(dir: &Path) -> PathBuf {
    let study = StudyScenario::BenchFull;
    let scenario = gait_scenario(Actuator::Sea, study.gait(), study.gains(Actuator::Sea), 1);
    let path = dir.join("SEA.ssp");
    write_ssp(&scenario, fmus(), &path).unwrap();
    path
}

#[test]
fn the_study_schedule_runs_on_the_hardware_fmu_and_tracks_like_the_plant() {
    let d = tempfile::tempdir().unwrap();
    let path = sea_ssp(d.path());
    let hardware = fmus().join("BenchHardware.fmu");
    let replaced = ssp::load_system_replacing(
        &path,
        &LoadOptions::default(),
        &[("plant".into(), hardware)],
    )
    .unwrap();
    let mut system = replaced.system;
    let model = |s: &kneebench_harness::System| {
        s.components()
            .find(|(n, _)| *n == "plant")
            .map(|(_, f)| f.model_description().model_name.clone())
            .unwrap()
    };
    assert_eq!(model(&system), "BenchHardware");
    system.set_value_str("plant.backend", "Simulated").unwrap();
    system.set_value_str("plant.pacing", "None").unwrap();
    let out = system.run(&replaced.config).unwrap();
    assert!(
        matches!(out.outcome, Outcome::Completed { .. }),
        "{:?}",
        out.outcome
    );
    let plant = ssp::load_system(&path, &LoadOptions::default()).unwrap();
    assert_eq!(model(&plant.system), "BenchPlant");
    let reference = plant.system.run(&plant.config).unwrap();
    let knee = |r: &kneebench_harness::Results| r.column("plant.loadAngle").unwrap();
    let (a, b) = (knee(&out.results), knee(&reference.results));
    assert_eq!(a.len(), b.len());
    let worst = a
        .iter()
        .zip(&b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0f64, f64::max);
    // Same schedule, same physics behind the hardware's calibrated sensors: the knee angles
    // agree to well under a degree over the whole cycle.
    assert!(worst < 0.5f64.to_radians(), "{} deg", worst.to_degrees());
}

#[test]
fn a_replacement_that_does_not_fit_or_names_no_component_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let path = sea_ssp(d.path());
    let wrong = ssp::load_system_replacing(
        &path,
        &LoadOptions::default(),
        &[("plant".into(), fmus().join("GaitReference.fmu"))],
    )
    .err()
    .unwrap_or_else(|| panic!("GaitReference is no plant"));
    let text = wrong.to_string();
    assert!(matches!(wrong, SspError::Replacement { .. }), "{text}");
    assert!(
        text.contains("does not fit") && text.contains("no variable 'testCurrentCommand' (input)"),
        "{text}"
    );
    let unknown = ssp::load_system_replacing(
        &path,
        &LoadOptions::default(),
        &[("plantx".into(), fmus().join("BenchHardware.fmu"))],
    )
    .err()
    .unwrap_or_else(|| panic!("no such component"))
    .to_string();
    assert!(
        unknown.contains("no such component (it has gait, torque, position, plant)"),
        "{unknown}"
    );
}

/// A study SSP carrying the twin's whole parameter set (what `kneebench study --params` writes,
/// e.g. an identified set) runs on the hardware FMU: the parameters BenchHardware has are applied,
/// the twin's own (friction, loss surface, winding inductances, ...) are listed as not applied,
/// and the interface check still refuses a replacement that lacks a signal.
#[test]
fn a_twin_parameter_set_runs_on_the_hardware_with_its_own_parameters_listed_as_not_applied() {
    use kneebench_harness::params::ParameterSet;
    let d = tempfile::tempdir().unwrap();
    let (_x, plant_md) = kneebench_harness::load::extract_and_parse(
        &fmus().join("BenchPlant.fmu"),
        &kneebench_harness::ArchiveLimits::default(),
    )
    .unwrap();
    let mut set = ParameterSet::defaults_of(&plant_md, "twin", "1");
    set.set_real("springStiffness", 300.0, Some("N.m/rad"));
    set.set_real("actuationStaticFriction", 6.5, Some("N.m"));
    let study = StudyScenario::BenchFull;
    let scenario = gait_scenario(Actuator::Sea, study.gait(), study.gains(Actuator::Sea), 1);
    let path = d.path().join("SEA.ssp");
    kneebench_harness::study::write_ssp_with_set(&scenario, fmus(), &path, "plant", &set).unwrap();
    let hardware = fmus().join("BenchHardware.fmu");
    let loaded = ssp::load_system_replacing(
        &path,
        &LoadOptions::default(),
        &[("plant".into(), hardware.clone())],
    )
    .unwrap();
    let (_y, hardware_md) = kneebench_harness::load::extract_and_parse(
        &hardware,
        &kneebench_harness::ArchiveLimits::default(),
    )
    .unwrap();
    let has = |name: &str| hardware_md.model_variables.iter().any(|v| v.name == name);
    // Exactly the set's parameters the hardware lacks, none it has.
    let expected: Vec<String> = set
        .parameters
        .iter()
        .filter(|p| !has(&p.name))
        .map(|p| format!("plant.{}", p.name))
        .collect();
    assert!(
        expected.contains(&"plant.actuationStaticFriction".to_string())
            && expected.contains(&"plant.hdLossPositiveSpeed[1]".to_string()),
        "{expected:?}"
    );
    let mut unapplied = loaded.unapplied.clone();
    unapplied.sort();
    let mut want = expected.clone();
    want.sort();
    assert_eq!(unapplied, want);
    // A parameter both have takes the set's value on the hardware (read back from a short run
    // on its simulated backend).
    assert!(has("springStiffness"));
    let mut system = loaded.system;
    system.set_value_str("plant.backend", "Simulated").unwrap();
    system.set_value_str("plant.pacing", "None").unwrap();
    system.record(&["plant.springStiffness"]).unwrap();
    let mut config = loaded.config.clone();
    config.stop_time = 0.01;
    let out = system.run(&config).unwrap();
    assert!(
        matches!(out.outcome, Outcome::Completed { .. }),
        "{:?}",
        out.outcome
    );
    let stiffness = out.results.column("plant.springStiffness").unwrap();
    assert!(stiffness.iter().all(|k| *k == 300.0), "{stiffness:?}");
    // Without a replacement nothing is left out.
    let plain = ssp::load_system(&path, &LoadOptions::default()).unwrap();
    assert!(plain.unapplied.is_empty());
}

#[test]
fn enumeration_parameters_take_item_names() {
    let d = tempfile::tempdir().unwrap();
    let path = sea_ssp(d.path());
    let mut loaded = ssp::load_system_replacing(
        &path,
        &LoadOptions::default(),
        &[("plant".into(), fmus().join("BenchHardware.fmu"))],
    )
    .unwrap();
    loaded.system.set_value_str("plant.backend", "Udp").unwrap();
    loaded.system.set_value_str("plant.backend", "1").unwrap();
    // The modes are FMI Integers (for importers without Enumeration support); their items'
    // names still work here.
    loaded
        .system
        .set_value_str("plant.configuration", "DA")
        .unwrap();
    match loaded.system.set_value_str("plant.configuration", "Rigid") {
        Err(MasterError::BadValue { problem, .. }) => {
            assert!(problem.contains("DA = 0, SEA = 1, CSEA = 2"), "{problem}")
        }
        other => panic!("{other:?}"),
    }
    match loaded.system.set_value_str("plant.backend", "Serial") {
        Err(MasterError::BadValue { problem, .. }) => {
            assert!(problem.contains("Simulated = 0, Udp = 1"), "{problem}")
        }
        other => panic!("{other:?}"),
    }
    // A plain Integer variable still wants a number.
    assert!(
        loaded
            .system
            .set_value_str("plant.realtimePriority", "High")
            .is_err()
    );
}
