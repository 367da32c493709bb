//! Parameter sets as SSP 1.0 `.ssv` files (`kneebench_harness::params`): the default set is
//! the plant's declared parameters (the bench facts), a set survives a file round trip, bad
//! sets are refused with their line, a set applied to an FMU or a system changes its run, and
//! an SSP binding a set as an `.ssv` resource is read by fmpy's SSP reader (which validates the
//! `.ssv` against the SSP 1.0 schema) with the set's values.

use std::path::Path;

use kneebench_fmu::models::bench::BenchParameters;
use kneebench_harness::load::{ArchiveLimits, extract_and_parse};
use kneebench_harness::master::Value;
use kneebench_harness::params::{ParamValue, ParameterSet, apply_spec};
use kneebench_harness::study::{Actuator, Gait, StudyGains, gait_scenario, write_ssp_with_set};
use kneebench_harness::{Fmu, LoadOptions, Outcome, RunConfig, System, ssp};
use kneebench_tests::*;

fn fmus() -> &'static Path {
    kneebench_tests::exported_fmus().0.path()
}

fn plant_md() -> model_description::ModelDescription {
    extract_and_parse(&fmus().join("BenchPlant.fmu"), &ArchiveLimits::default())
        .unwrap()
        .1
}

/// The FMU's name of a field of `BenchParameters` (camel case; one field is renamed).
fn camel(snake: &str) -> String {
    if snake == "clutch_power" {
        return "clutchRatedPower".into();
    }
    let mut out = String::new();
    let mut up = false;
    for c in snake.chars() {
        if c == '_' {
            up = true;
        } else if up {
            out.extend(c.to_uppercase());
            up = false;
        } else {
            out.push(c);
        }
    }
    out
}

#[test]
fn default_set_is_the_bench_facts_from_the_fmu() {
    let md = plant_md();
    let set = ParameterSet::defaults_of(&md, "bench-facts", "1");
    let facts = BenchParameters::default();
    for (name, _, _) in BenchParameters::PARAMETER_LIMITS {
        let v = set
            .real(&camel(name))
            .unwrap_or_else(|| panic!("{} missing", camel(name)));
        assert_eq!(v, facts.real(name).unwrap(), "{name}");
    }
    assert!(set.parameters.len() >= BenchParameters::PARAMETER_LIMITS.len());
    // Units come with the values and every unit used is defined.
    let inertia = set
        .parameters
        .iter()
        .find(|p| p.name == "actuationInertia")
        .unwrap();
    assert!(inertia.unit.is_some());
    for p in &set.parameters {
        if let Some(u) = &p.unit {
            assert!(set.units.iter().any(|d| &d.name == u), "{u}");
        }
    }
    set.check(&md, "defaults").unwrap();
}

#[test]
fn file_round_trip_keeps_values_units_and_hash() {
    let md = plant_md();
    let mut set = ParameterSet::defaults_of(&md, "bench-facts", "1");
    set.set_real("actuationStaticFriction", 6.5, Some("N.m"));
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("set.ssv");
    set.write_file(&path).unwrap();
    let back = ParameterSet::read_for(&path, &md).unwrap();
    assert_eq!(back.content_hash(), set.content_hash());
    assert_eq!(back.name, "bench-facts");
    assert_eq!(back.version, "1");
    assert_eq!(back.units, set.units);
    assert_eq!(back.real("actuationStaticFriction"), Some(6.5));
    assert_ne!(
        back.content_hash(),
        ParameterSet::defaults_of(&md, "bench-facts", "1").content_hash()
    );
}

/// A set file with one parameter on line 4.
fn one_parameter(body: &str) -> String {
    format!(
        "<?xml version=\"1.0\"?>\n<ssv:ParameterSet xmlns:ssv=\"http://ssp-standard.org/SSP1/SystemStructureParameterValues\" xmlns:ssc=\"http://ssp-standard.org/SSP1/SystemStructureCommon\" version=\"1.0\" name=\"t\">\n  <ssv:Parameters>\n    {body}\n  </ssv:Parameters>\n  <ssv:Units><ssc:Unit name=\"N.m\"><ssc:BaseUnit kg=\"1\" m=\"2\" s=\"-2\"/></ssc:Unit><ssc:Unit name=\"kg.m2\"><ssc:BaseUnit kg=\"1\" m=\"2\"/></ssc:Unit></ssv:Units>\n</ssv:ParameterSet>\n"
    )
}

#[test]
fn unknown_names_wrong_units_and_out_of_range_values_are_refused_with_the_line() {
    let md = plant_md();
    let cases = [
        (
            "<ssv:Parameter name=\"actuationInertiaa\"><ssv:Real value=\"1\"/></ssv:Parameter>",
            "has no variable",
        ),
        (
            "<ssv:Parameter name=\"actuationInertia\"><ssv:Real value=\"1\" unit=\"N.m\"/></ssv:Parameter>",
            "unit 'N.m' is not the declared unit 'kg.m2'",
        ),
        (
            "<ssv:Parameter name=\"actuationInertia\"><ssv:Real value=\"1000\" unit=\"kg.m2\"/></ssv:Parameter>",
            "outside [0.001, 100]",
        ),
        (
            "<ssv:Parameter name=\"actuationInertia\"><ssv:Boolean value=\"true\"/></ssv:Parameter>",
            "a Boolean value for a Real variable",
        ),
        (
            "<ssv:Parameter name=\"actuationAngle\"><ssv:Real value=\"0\"/></ssv:Parameter>",
            "is not a parameter",
        ),
    ];
    for (body, what) in cases {
        let set = ParameterSet::from_xml(&one_parameter(body), "bad.ssv").unwrap();
        let e = set.check(&md, "bad.ssv").unwrap_err().to_string();
        assert!(e.starts_with("bad.ssv:4: "), "{e}");
        assert!(e.contains(what), "{e}");
    }
    // The well-formed value passes.
    let ok = one_parameter(
        "<ssv:Parameter name=\"actuationInertia\"><ssv:Real value=\"0.9\" unit=\"kg.m2\"/></ssv:Parameter>",
    );
    ParameterSet::from_xml(&ok, "ok.ssv")
        .unwrap()
        .check(&md, "ok.ssv")
        .unwrap();
}

fn run_plant(system: &System) -> Vec<f64> {
    let out = system
        .run(&RunConfig {
            stop_time: 0.3,
            step_size: 1e-3,
            ..RunConfig::default()
        })
        .unwrap();
    assert!(matches!(out.outcome, Outcome::Completed { .. }));
    out.results.column("plant.actuationAngle").unwrap()
}

#[test]
fn a_set_applied_to_an_fmu_changes_its_run_and_a_bad_one_is_refused() {
    let fmu = Fmu::load(fmus().join("BenchPlant.fmu"), &LoadOptions::default()).unwrap();
    let build = || {
        let mut s = System::new();
        s.add_component("plant", fmu.clone()).unwrap();
        s.set_value("plant.testCurrentCommand", Value::Real(2.0))
            .unwrap();
        s
    };
    let base = run_plant(&build());
    let dir = tempfile::tempdir().unwrap();
    let mut set = ParameterSet::new("heavy", "1");
    set.set_real("actuationInertia", 1.65, Some("kg.m2"));
    set.define_units(&plant_md());
    let path = dir.path().join("heavy.ssv");
    set.write_file(&path).unwrap();
    let mut system = build();
    let applied = apply_spec(
        &mut system,
        &fmus().join("BenchPlant.fmu"),
        Some("plant"),
        path.to_str().unwrap(),
    )
    .unwrap();
    assert_eq!(applied.content_hash(), set.content_hash());
    let heavy = run_plant(&system);
    // Twice the inertia: the actuation side accelerates visibly slower.
    let (a, b) = (base.last().unwrap(), heavy.last().unwrap());
    assert!(b.abs() < 0.8 * a.abs(), "{a} vs {b}");

    set.set_real("actuationInertia", -1.0, Some("kg.m2"));
    set.write_file(&path).unwrap();
    let e = apply_spec(
        &mut build(),
        &fmus().join("BenchPlant.fmu"),
        Some("plant"),
        path.to_str().unwrap(),
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains(":4: parameter 'actuationInertia': -1 is outside"),
        "{e}"
    );
}

const FMPY_READ_BINDINGS: &str = r#"
import sys
from fmpy.ssp.ssd import read_ssd
ssd = read_ssd(sys.argv[1])
for c in ssd.system.elements:
    for b in c.parameterBindings:
        for ps in b.parameterValues:
            for p in ps.parameters:
                print(c.name, b.source, ps.name, p.name, p.type, p.value, p.unit if p.type == "Real" else "")
"#;

#[test]
fn ssp_with_a_binding_to_an_ssv_resource_is_read_by_us_and_by_fmpy() {
    let md = plant_md();
    let mut set = ParameterSet::defaults_of(&md, "bench-b", "2");
    set.set_real("actuationDamping", 14.0, Some("N.m.s/rad"));
    set.define_units(&md);
    set.check(&md, "set").unwrap();
    let mut scenario = gait_scenario(
        Actuator::Sea,
        Gait::bench_full(),
        StudyGains::for_actuator(Actuator::Sea),
        1,
    );
    scenario.stop_time = 0.2;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("SEA.ssp");
    write_ssp_with_set(&scenario, fmus(), &path, "plant", &set).unwrap();

    // Ours: the binding is recorded, its values reach the plant.
    let (ssd, _base, _dir) = ssp::read_file(&path, &ArchiveLimits::default()).unwrap();
    let plant = ssd
        .system
        .components
        .iter()
        .find(|c| c.name == "plant")
        .unwrap();
    assert_eq!(
        plant.parameter_sources,
        vec!["resources/plant.ssv".to_string()]
    );
    let damping: Vec<&Value> = plant
        .parameters
        .iter()
        .filter(|p| p.name == "actuationDamping")
        .map(|p| &p.value)
        .collect();
    assert_eq!(damping, vec![&Value::Real(14.0)]);
    let loaded = ssp::load_system(&path, &LoadOptions::default()).unwrap();
    let out = loaded.system.run(&loaded.config).unwrap();
    assert!(matches!(out.outcome, Outcome::Completed { .. }));

    // fmpy: validates the SSD and the .ssv against the SSP 1.0 schemas and reads the values.
    let text = run_python(FMPY_READ_BINDINGS, &[path.to_str().unwrap()]);
    let from_file: Vec<&str> = text
        .lines()
        .filter(|l| l.starts_with("plant resources/plant.ssv bench-b "))
        .collect();
    assert_eq!(from_file.len(), set.parameters.len(), "{text}");
    for p in &set.parameters {
        let ParamValue::Real(v) = p.value else {
            unreachable!("defaults are Real")
        };
        let line = from_file
            .iter()
            .find(|l| l.split(' ').nth(3) == Some(p.name.as_str()))
            .unwrap_or_else(|| panic!("{} not read by fmpy:\n{text}", p.name));
        let fields: Vec<&str> = line.split(' ').collect();
        assert_eq!(fields[4], "Real", "{line}");
        assert_eq!(fields[5].parse::<f64>().unwrap(), v, "{line}");
        assert_eq!(
            Some(fields[6]),
            p.unit.as_deref().or(Some("None")),
            "{line}"
        );
    }
}

#[test]
fn the_study_embeds_a_plant_set_and_names_it_in_its_report() {
    use kneebench_harness::study::{
        ScenarioSection, StudyConfig, StudyScenario, run_study, write_report,
    };
    let md = plant_md();
    let mut set = ParameterSet::new("bench-c", "4");
    set.set_real("actuationDamping", 12.5, Some("N.m.s/rad"));
    set.set_real("loadStaticFriction", 0.4, Some("N.m"));
    set.define_units(&md);
    let out = tempfile::tempdir().unwrap();
    let config = StudyConfig {
        fmu_dir: fmus().to_path_buf(),
        out_dir: out.path().to_path_buf(),
        scenario: StudyScenario::BenchFull,
        cycles: 2,
        scale: 1.0,
        gains: None,
        actuators: vec![Actuator::Sea],
        // --param wins over the set.
        overrides: vec![("plant.loadStaticFriction".into(), Value::Real(0.38))],
        parameter_set: Some(set.clone()),
        bench: None,
    };
    let runs = run_study(&config).unwrap();
    let run = &runs[0];
    assert_eq!(run.plant_set.as_deref(), Some(set.label().as_str()));
    assert!(
        run.parameters
            .contains(&"plant.actuationDamping = 12.5".to_string())
    );
    assert!(
        run.parameters
            .contains(&"plant.loadStaticFriction = 0.38".to_string())
    );
    // The SSP binds the set as a resource; what our reader applies is the record's value.
    let (ssd, _base, _dir) = ssp::read_file(&run.scenario, &ArchiveLimits::default()).unwrap();
    let plant = ssd
        .system
        .components
        .iter()
        .find(|c| c.name == "plant")
        .unwrap();
    assert_eq!(
        plant.parameter_sources,
        vec!["resources/plant.ssv".to_string()]
    );
    let last = |name: &str| {
        plant
            .parameters
            .iter()
            .rev()
            .find(|p| p.name == name)
            .map(|p| p.value.clone())
    };
    assert_eq!(last("actuationDamping"), Some(Value::Real(12.5)));
    assert_eq!(last("loadStaticFriction"), Some(Value::Real(0.38)));
    let report = write_report(
        out.path(),
        &[ScenarioSection {
            scenario: StudyScenario::BenchFull,
            runs: &runs,
            figures: &[],
        }],
        "test",
    )
    .unwrap();
    let text = std::fs::read_to_string(report).unwrap();
    assert!(
        text.contains(&format!("plant parameter set: {}", set.label())),
        "{text}"
    );
    // The set's damping is not the one the study's controllers were built on: the report says
    // so under the run (a friction the controllers do not model is not named).
    assert_eq!(
        kneebench_harness::study::tuning_differences(Actuator::Sea, &run.parameters),
        vec![("actuationDamping".to_string(), 12.0, 12.5)]
    );
    assert!(
        text.contains(
            "  - **this plant differs from the one the study's controller weights were derived \
             for, in `plant.actuationDamping` 12.5 (tuned for 12).**"
        ),
        "{text}"
    );
    // A set the plant refuses stops the study before anything runs.
    let mut bad = set.clone();
    bad.set_real("actuationDamping", -1.0, Some("N.m.s/rad"));
    let e = run_study(&StudyConfig {
        parameter_set: Some(bad),
        ..config
    })
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("actuationDamping") && e.contains("outside"),
        "{e}"
    );
}

/// The plant's `configuration` (a mode: an FMI Integer bounded by its items, so that importers
/// without Enumeration support can set it) is set by value in a parameter set; a value that is
/// no item is refused with the line, naming the items.
#[test]
fn a_mode_is_set_by_value_and_a_value_that_is_no_item_is_refused() {
    let md = plant_md();
    let doc = |value: &str| {
        format!(
            "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n\
             <ssv:ParameterSet xmlns:ssv=\"http://ssp-standard.org/SSP1/SystemStructureParameterValues\" version=\"1.0\" name=\"da\">\n\
             <ssv:Parameters>\n\
             <ssv:Parameter name=\"configuration\"><ssv:Integer value=\"{value}\"/></ssv:Parameter>\n\
             </ssv:Parameters>\n\
             </ssv:ParameterSet>\n"
        )
    };
    let set = ParameterSet::from_xml(&doc("0"), "da.ssv").unwrap();
    set.check(&md, "da.ssv").unwrap();
    assert_eq!(
        set.assignments(),
        [("configuration".to_string(), Value::Integer(0))]
    );
    let e = ParameterSet::from_xml(&doc("3"), "da.ssv")
        .unwrap()
        .check(&md, "da.ssv")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains(":4: parameter 'configuration': 3 is outside [0, 2]"),
        "{e}"
    );
}

/// What the study's controllers are built on ([`kneebench_harness::study::tuned_for`]) is the
/// plant's declared default of each parameter: the study's own plant differs in none, so its
/// report carries no warning, and a change of a default shows here.
#[test]
fn the_controllers_assumptions_are_the_plants_defaults() {
    use kneebench_harness::study::{tuned_for, tuning_differences};
    use model_description::VariableKind;
    let md = plant_md();
    // A run whose position loop leads the knee by the planned deflection (the coupling
    // stiffness is then assumed too) and one without a position loop (the impedance law).
    let leading = vec!["position.setpointWeight3 = 0.0029".to_string()];
    assert_eq!(tuned_for(Actuator::Sea, &leading).len(), 11);
    assert_eq!(tuned_for(Actuator::Sea, &[]).len(), 10);
    assert!(tuned_for(Actuator::Da, &leading).contains(&("directCouplingStiffness", 1.3e4)));
    for actuator in [Actuator::Da, Actuator::Sea, Actuator::Csea] {
        let mut lines = leading.clone();
        for (name, assumed) in tuned_for(actuator, &leading) {
            let variable = md
                .model_variables
                .iter()
                .find(|v| v.name == name)
                .unwrap_or_else(|| panic!("BenchPlant declares {name}"));
            let VariableKind::Real {
                start: Some(start), ..
            } = variable.kind
            else {
                panic!("{name} is a Real with a start value");
            };
            assert!(
                (start - assumed).abs() <= 1e-12 * assumed.abs(),
                "{name}: the plant's default {start}, the study assumes {assumed}"
            );
            lines.push(format!("plant.{name} = {start}"));
        }
        assert_eq!(tuning_differences(actuator, &lines), Vec::new());
        // Another value of each is named.
        let mut other: Vec<String> = tuned_for(actuator, &leading)
            .iter()
            .map(|(name, assumed)| format!("plant.{name} = {}", assumed * 1.5))
            .collect();
        other.extend(leading.iter().cloned());
        assert_eq!(
            tuning_differences(actuator, &other).len(),
            tuned_for(actuator, &leading).len()
        );
    }
}
