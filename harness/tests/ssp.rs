//! SSP 1.0: write -> read round trip, archives with FMUs, and running what was read.

mod common;

use kneebench_harness::master::Value;
use kneebench_harness::ssp::{
    self, ConnectorKind, ConnectorType, Ssd, SspComponent, SspConnection, SspConnector,
    SspExperiment, SspParameter, SspSystem,
};
use kneebench_harness::{Algorithm, Fmu, LoadOptions, Outcome};

fn sample(md: &model_description::ModelDescription) -> Ssd {
    let mut a = SspComponent::from_model_description("a", "resources/kbtest.fmu", md);
    a.parameters = vec![SspParameter {
        name: "u".into(),
        value: Value::Real(1.0),
    }];
    let mut b = SspComponent::from_model_description("b", "resources/kbtest.fmu", md);
    b.parameters = vec![
        SspParameter {
            name: "k".into(),
            value: Value::Real(2.0),
        },
        SspParameter {
            name: "b".into(),
            value: Value::Real(0.5),
        },
        SspParameter {
            name: "i_in".into(),
            value: Value::Integer(-3),
        },
        SspParameter {
            name: "b_in".into(),
            value: Value::Boolean(true),
        },
    ];
    b.step_multiple = Some(1);
    let mut ssd = Ssd {
        name: "two <gains> & \"quotes\"".into(),
        version: "1.0".into(),
        system: SspSystem {
            name: "root".into(),
            components: vec![a, b],
            connections: vec![SspConnection {
                start_element: Some("a".into()),
                start_connector: "x".into(),
                end_element: Some("b".into()),
                end_connector: "u".into(),
            }],
        },
        default_experiment: Some(SspExperiment {
            start_time: Some(0.0),
            stop_time: Some(0.5),
            step_size: Some(0.1),
            algorithm: Some(Algorithm::GaussSeidel),
        }),
    };
    ssd.system.drop_unconnected_inputs();
    ssd
}

#[test]
fn ssd_write_read_round_trip_is_identical() {
    let d = tempfile::tempdir().unwrap();
    let fmu = Fmu::load(common::kbtest_fmu(d.path()), &LoadOptions::default()).unwrap();
    let ssd = sample(fmu.model_description());
    let xml = ssd.to_xml();
    assert!(xml.contains("version=\"1.0\""));
    assert!(xml.contains("xmlns:ssd=\"http://ssp-standard.org/SSP1/SystemStructureDescription\""));
    let back = ssp::read_ssd(&xml).unwrap();
    assert_eq!(back, ssd);
    // Writing what was read gives the same bytes.
    assert_eq!(back.to_xml(), xml);
    // Connector types written are Real/Integer/Boolean only.
    let b = &back.system.components[1];
    assert!(b.connectors.iter().any(|c| c.name == "u"
        && c.kind == ConnectorKind::Input
        && c.ty == Some(ConnectorType::Real { unit: None })));
    assert!(b.connectors.iter().any(|c| c.name == "steps"
        && c.kind == ConnectorKind::Output
        && c.ty == Some(ConnectorType::Integer)));
}

#[test]
fn ssp_archive_loads_and_runs_like_the_hand_built_system() {
    let d = tempfile::tempdir().unwrap();
    let fmu_path = common::kbtest_fmu(d.path());
    let fmu = Fmu::load(&fmu_path, &LoadOptions::default()).unwrap();
    let ssd = sample(fmu.model_description());
    let ssp_path = d.path().join("system.ssp");
    ssp::write_ssp(
        &ssd,
        &[("resources/kbtest.fmu".into(), fmu_path.clone())],
        &ssp_path,
    )
    .unwrap();
    let loaded = ssp::load_system(&ssp_path, &LoadOptions::default()).unwrap();
    assert_eq!(loaded.ssd, ssd);
    assert_eq!(loaded.config.stop_time, 0.5);
    assert_eq!(loaded.config.step_size, 0.1);
    let mut system = loaded.system;
    system.record(&["a.x", "b.u", "b.y", "b.i_out"]).unwrap();
    let out = system.run(&loaded.config).unwrap();
    assert!(matches!(out.outcome, Outcome::Completed { .. }));
    for n in 0..6 {
        let x = n as f64;
        assert_eq!(
            out.results.row(n),
            [x / 10.0, x, x, 2.0 * x + 0.5, -6.0],
            "row {n}"
        );
    }

    // The same description as a bare .ssd next to the FMU.
    std::fs::create_dir_all(d.path().join("resources")).unwrap();
    std::fs::copy(&fmu_path, d.path().join("resources/kbtest.fmu")).unwrap();
    let ssd_path = d.path().join("system.ssd");
    ssp::write_ssd_file(&ssd, &ssd_path).unwrap();
    let loaded = ssp::load_system(&ssd_path, &LoadOptions::default()).unwrap();
    assert_eq!(loaded.ssd, ssd);
}

#[test]
fn foreign_ssd_with_external_parameter_file_is_read() {
    let d = tempfile::tempdir().unwrap();
    let ssv = r#"<?xml version="1.0" encoding="UTF-8"?>
<ssv:ParameterSet xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues" version="1.0" name="p">
  <ssv:Parameters>
    <ssv:Parameter name="k"><ssv:Real value="3.5" unit="1"/></ssv:Parameter>
  </ssv:Parameters>
</ssv:ParameterSet>"#;
    std::fs::write(d.path().join("params.ssv"), ssv).unwrap();
    let xml = r#"<?xml version="1.0" encoding="UTF-8"?>
<SystemStructureDescription xmlns="http://ssp-standard.org/SSP1/SystemStructureDescription" version="1.0" name="foreign">
  <System name="sys">
    <Elements>
      <Component name="g" source="kbtest.fmu">
        <ParameterBindings><ParameterBinding source="params.ssv"/></ParameterBindings>
      </Component>
    </Elements>
  </System>
  <DefaultExperiment startTime="0.0" stopTime="2.0"/>
</SystemStructureDescription>"#;
    let p = d.path().join("foreign.ssd");
    std::fs::write(&p, xml).unwrap();
    let (ssd, _, _) = ssp::read_file(&p, &Default::default()).unwrap();
    assert_eq!(
        ssd.system.components[0].parameters[0].value,
        Value::Real(3.5)
    );
    assert_eq!(ssd.default_experiment.unwrap().stop_time, Some(2.0));

    let bad = ssp::read_ssd("<SystemStructureDescription version=\"2.0\" name=\"x\"><System name=\"s\"/></SystemStructureDescription>")
        .unwrap_err();
    assert!(bad.to_string().contains("not an SSP 1.x version"), "{bad}");
    let nested = ssp::read_ssd("<SystemStructureDescription version=\"1.0\" name=\"x\"><System name=\"s\"><Elements><System name=\"t\"/></Elements></System></SystemStructureDescription>")
        .unwrap_err();
    assert!(nested.to_string().contains("nested systems"), "{nested}");
}

#[test]
fn connector_types_other_than_real_integer_boolean_are_not_written() {
    let ssd = Ssd {
        name: "s".into(),
        version: "1.0".into(),
        system: SspSystem {
            name: "root".into(),
            components: vec![SspComponent {
                name: "c".into(),
                source: "resources/c.fmu".into(),
                connectors: vec![SspConnector {
                    name: "label".into(),
                    kind: ConnectorKind::Parameter,
                    ty: Some(ConnectorType::String),
                }],
                ..SspComponent::default()
            }],
            connections: vec![],
        },
        default_experiment: None,
    };
    let xml = ssd.to_xml();
    assert!(!xml.contains("ssc:String"), "{xml}");
}

/// Writes a sample `.ssp` to `$KNEEBENCH_SSP_OUT` for an external check with fmpy's
/// `fmpy.ssp.ssd.read_ssd` (which validates against the SSP 1.0 schema); a no-op otherwise.
#[test]
fn write_sample_ssp_for_fmpy() {
    let Some(out) = std::env::var_os("KNEEBENCH_SSP_OUT") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let fmu_path = common::kbtest_fmu(d.path());
    let fmu = Fmu::load(&fmu_path, &LoadOptions::default()).unwrap();
    ssp::write_ssp(
        &sample(fmu.model_description()),
        &[("resources/kbtest.fmu".into(), fmu_path)],
        std::path::Path::new(&out),
    )
    .unwrap();
}

/// A parameter binding's Boolean that is not xs:boolean, and a master annotation naming an
/// unknown algorithm, are refused with their text (they were read as false and as the
/// default algorithm, silently); xs:boolean's four spellings are read.
#[test]
fn a_malformed_boolean_or_algorithm_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let fmu = Fmu::load(common::kbtest_fmu(d.path()), &LoadOptions::default()).unwrap();
    let xml = sample(fmu.model_description()).to_xml();
    let boolean = "<ssv:Boolean value=\"true\"/>";
    let algorithm = "algorithm=\"gauss-seidel\"";
    assert!(xml.contains(boolean) && xml.contains(algorithm), "{xml}");
    for (spelling, value) in [("true", true), ("1", true), ("false", false), ("0", false)] {
        let ssd =
            ssp::read_ssd(&xml.replace(boolean, &format!("<ssv:Boolean value=\"{spelling}\"/>")))
                .unwrap();
        let read = ssd
            .system
            .components
            .iter()
            .flat_map(|c| &c.parameters)
            .find(|p| matches!(p.value, Value::Boolean(_)))
            .unwrap();
        assert_eq!(read.value, Value::Boolean(value), "{spelling}");
    }
    let e = ssp::read_ssd(&xml.replace(boolean, "<ssv:Boolean value=\"maybe\"/>")).unwrap_err();
    assert!(e.to_string().contains("'maybe' is not a Boolean"), "{e}");
    let e = ssp::read_ssd(&xml.replace(algorithm, "algorithm=\"magic\"")).unwrap_err();
    assert!(e.to_string().contains("algorithm 'magic'"), "{e}");
}
