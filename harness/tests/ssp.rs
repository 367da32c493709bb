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

/// Writes an `.ssp` at `path` holding `entries` (name, text).
fn write_ssp_entries(path: &std::path::Path, entries: &[(&str, &str)]) {
    use std::io::Write;
    let mut z = zip::ZipWriter::new(std::fs::File::create(path).unwrap());
    for (name, text) in entries {
        z.start_file(*name, zip::write::SimpleFileOptions::default())
            .unwrap();
        z.write_all(text.as_bytes()).unwrap();
    }
    z.finish().unwrap();
}

/// Errors in an `.ssp` name the archive the user gave and the file inside it, with the line,
/// never the temporary directory it was extracted into (gone when the message is read).
#[test]
fn errors_in_an_ssp_name_the_archive_and_the_line() {
    let d = tempfile::tempdir().unwrap();
    let ssp_path = d.path().join("Foo.ssp");
    let ssp_name = ssp_path.display().to_string();
    let mut ssd = String::from(
        "<?xml version=\"1.0\"?>\n<ssd:SystemStructureDescription xmlns:ssd=\"x\" version=\"1.0\" name=\"x\">\n<ssd:System name=\"s\">\n",
    );
    for _ in 0..8 {
        ssd.push('\n');
    }
    // Line 12.
    ssd.push_str("<ssd:Elements></ssd:Foo>\n</ssd:System>\n</ssd:SystemStructureDescription>\n");
    let read = |entries: &[(&str, &str)]| {
        write_ssp_entries(&ssp_path, entries);
        ssp::read_file(&ssp_path, &Default::default())
            .unwrap_err()
            .to_string()
    };
    let e = read(&[("SystemStructure.ssd", &ssd)]);
    assert!(
        e.starts_with(&format!(
            "{ssp_name}: SystemStructure.ssd line 12: malformed XML"
        )),
        "{e}"
    );
    assert!(!e.contains("kneebench-ssp"), "{e}");
    // Valid XML, not a usable SSD: the line of the element too.
    let e = read(&[(
        "SystemStructure.ssd",
        "<?xml version=\"1.0\"?>\n<SystemStructureDescription version=\"2.0\" name=\"x\"><System name=\"s\"/></SystemStructureDescription>",
    )]);
    assert_eq!(
        e,
        format!("{ssp_name}: SystemStructure.ssd line 2: version '2.0' is not an SSP 1.x version")
    );
    // No description in the archive.
    let e = read(&[("other.txt", "x")]);
    assert_eq!(
        e,
        format!("{ssp_name}: the archive has no SystemStructure.ssd")
    );
    // A parameter file it references: missing, then malformed.
    let binding = "<?xml version=\"1.0\"?>\n<SystemStructureDescription version=\"1.0\" name=\"x\"><System name=\"s\"><Elements><Component name=\"c\" source=\"resources/c.fmu\"><ParameterBindings><ParameterBinding source=\"resources/p.ssv\"/></ParameterBindings></Component></Elements></System></SystemStructureDescription>";
    let e = read(&[("SystemStructure.ssd", binding)]);
    assert_eq!(e, format!("{ssp_name}: the archive has no resources/p.ssv"));
    let e = read(&[
        ("SystemStructure.ssd", binding),
        (
            "resources/p.ssv",
            "<ssv:ParameterSet version=\"1.0\" name=\"p\">\n<ssv:Parameters>\n<ssv:Parameter name=\"k\"><ssv:Real value=\"1\"/></ssv:Parameter>\n</ssv:Parameters>",
        ),
    ]);
    assert!(
        e.starts_with(&format!(
            "{ssp_name}: resources/p.ssv line 4: malformed XML"
        )) && e.contains("ends inside <ssv:ParameterSet> (opened at line 1)"),
        "{e}"
    );
    // A bad tag is on its own line, not on the line of the blanks before it.
    let e = read(&[
        ("SystemStructure.ssd", binding),
        (
            "resources/p.ssv",
            "<ssv:ParameterSet version=\"1.0\" name=\"p\">\n<ssv:Parameters>\n\n  <ssv:Parameter name=\"k<\"/>\n</ssv:Parameters>\n</ssv:ParameterSet>",
        ),
    ]);
    assert!(
        e.starts_with(&format!(
            "{ssp_name}: resources/p.ssv line 4: malformed XML"
        )) && e.contains("the value of name holds a '<'"),
        "{e}"
    );
}

/// Malformed XML in an SSD is reported as malformed XML with the parser's position and reason,
/// not as what the reader made of it: a tag with `<` in it read as an attribute named
/// `<version` (so: "version '' is not an SSP 1.x version"), a `<` in a value, and a document
/// that ends inside its root (accepted).
#[test]
fn malformed_xml_in_an_ssd_is_not_a_bad_version() {
    for (xml, line, reason) in [
        (
            "<?xml version=\"1.0\"?>\n<SystemStructureDescription <version=\"1.0\" name=\"x\"><System name=\"s\"/></SystemStructureDescription>",
            2,
            "'<version' is not an attribute name",
        ),
        (
            "<SystemStructureDescription versi<on=\"1.0\" name=\"x\"><System name=\"s\"/></SystemStructureDescription>",
            1,
            "'versi<on' is not an attribute name",
        ),
        (
            "<SystemStructureDescription version=\"1.0<\" name=\"x\"><System name=\"s\"/></SystemStructureDescription>",
            1,
            "the value of version holds a '<'",
        ),
        (
            "<SystemStructureDescription version=\"1.0\" name=\"x\">\n<System name=\"s\"/>\n",
            3,
            "ends inside <SystemStructureDescription> (opened at line 1)",
        ),
        (
            "<SystemStructureDescription version=\"1.0\" name=\"x\">\n<System name=\"s\">\n</Elements>\n</SystemStructureDescription>",
            3,
            "expected `</System>`",
        ),
        (
            "\n<?xml version=\"1.0\" standalone=\"maybe\"?>\n<SystemStructureDescription version=\"1.0\" name=\"x\"><System name=\"s\"/></SystemStructureDescription>",
            2,
            "standalone 'maybe' is not a valid one",
        ),
    ] {
        let e = ssp::read_ssd(xml).unwrap_err();
        match &e {
            ssp::SspError::Xml {
                line: l, message, ..
            } => {
                assert_eq!(*l, line, "{xml}: {e}");
                assert!(message.contains(reason), "{xml}: {e}");
            }
            other => panic!("{xml}: expected malformed XML, got {other:?}"),
        }
        assert!(!e.to_string().contains("version '"), "{e}");
    }
}

/// Errors found after the document is read (no System element, no root element at all) name
/// the line of the element concerned, and so do a parameter set's bad values, inline in the
/// SSD or in a referenced .ssv: they named the file alone.
#[test]
fn whole_document_and_parameter_value_errors_name_the_line() {
    // No System: the root element's line.
    let e = ssp::read_ssd(
        "<?xml version=\"1.0\"?>\n\n<SystemStructureDescription version=\"1.0\" name=\"x\">\n</SystemStructureDescription>\n",
    )
    .unwrap_err()
    .to_string();
    assert_eq!(
        e,
        "SystemStructure.ssd line 3: no System element in the SystemStructureDescription"
    );
    // No element at all: the end of the document.
    let e = ssp::read_ssd("<?xml version=\"1.0\"?>\n<!-- nothing -->\n")
        .unwrap_err()
        .to_string();
    assert_eq!(
        e,
        "SystemStructure.ssd line 3: the document has no root element (SystemStructureDescription)"
    );
    // Inline parameter values: the line of the value's element in the SSD.
    let inline = |value: &str| {
        format!(
            "<?xml version=\"1.0\"?>\n<SystemStructureDescription version=\"1.0\" name=\"x\">\n\
             <System name=\"s\"><Elements>\n<Component name=\"c\" source=\"c.fmu\">\n\
             <ParameterBindings><ParameterBinding><ParameterValues>\n\
             <ParameterSet version=\"1.0\" name=\"p\"><Parameters>\n\
             <Parameter name=\"k\">\n  {value}\n</Parameter>\n\
             </Parameters></ParameterSet>\n\
             </ParameterValues></ParameterBinding></ParameterBindings>\n\
             </Component></Elements></System>\n</SystemStructureDescription>\n"
        )
    };
    assert_eq!(
        ssp::read_ssd(&inline("<Real value=\"1.5\"/>"))
            .unwrap()
            .system
            .components[0]
            .parameters[0]
            .value,
        Value::Real(1.5)
    );
    for (value, problem) in [
        (
            "<Real value=\"fast\"/>",
            "parameter k: 'fast' is not a number",
        ),
        (
            "<Integer value=\"1.5\"/>",
            "parameter k: '1.5' is not an Integer",
        ),
        (
            "<Boolean value=\"yes\"/>",
            "parameter k: 'yes' is not a Boolean (true, false, 1 or 0)",
        ),
        (
            "<Enumeration value=\"A\"/>",
            "unsupported: Enumeration parameter value (k)",
        ),
    ] {
        let e = ssp::read_ssd(&inline(value)).unwrap_err().to_string();
        assert_eq!(
            e,
            format!("SystemStructure.ssd line 8: {problem}"),
            "{value}"
        );
    }
    // A referenced .ssv: its own name and line.
    let bound = "<?xml version=\"1.0\"?>\n<SystemStructureDescription version=\"1.0\" name=\"x\"><System name=\"s\"><Elements><Component name=\"c\" source=\"c.fmu\"><ParameterBindings><ParameterBinding source=\"p.ssv\"/></ParameterBindings></Component></Elements></System></SystemStructureDescription>";
    #[allow(clippy::result_large_err)] // read_ssd_with's callback returns the SSP reader's error
    fn bad_set(_source: &str) -> Result<String, ssp::SspError> {
        Ok(
            "<ssv:ParameterSet version=\"1.0\" name=\"p\">\n<ssv:Parameters>\n\n\
            <ssv:Parameter name=\"k\"><ssv:Integer value=\"x\"/></ssv:Parameter>\n\
            </ssv:Parameters>\n</ssv:ParameterSet>\n"
                .into(),
        )
    }
    let e = ssp::read_ssd_with(bound, "s.ssd", &mut bad_set)
        .unwrap_err()
        .to_string();
    assert_eq!(e, "p.ssv line 4: parameter k: 'x' is not an Integer");
}

/// A bare `.ssd` on disk may refer to FMUs in a sibling directory (`../fmus/kbtest.fmu`, a
/// relative URI like any other); the same description inside an `.ssp` may not leave the
/// archive, and an absolute path is refused in both.
#[test]
fn a_bare_ssd_may_refer_to_a_sibling_directory_an_archive_may_not() {
    let d = tempfile::tempdir().unwrap();
    let fmu_path = common::kbtest_fmu(d.path());
    let fmu = Fmu::load(&fmu_path, &LoadOptions::default()).unwrap();
    let mut ssd = sample(fmu.model_description());
    for c in &mut ssd.system.components {
        c.source = "../fmus/kbtest.fmu".into();
    }
    std::fs::create_dir_all(d.path().join("fmus")).unwrap();
    std::fs::create_dir_all(d.path().join("systems")).unwrap();
    std::fs::copy(&fmu_path, d.path().join("fmus/kbtest.fmu")).unwrap();
    let ssd_path = d.path().join("systems/two.ssd");
    ssp::write_ssd_file(&ssd, &ssd_path).unwrap();
    let loaded = ssp::load_system(&ssd_path, &LoadOptions::default()).unwrap();
    let out = loaded.system.run(&loaded.config).unwrap();
    assert!(matches!(out.outcome, Outcome::Completed { .. }));

    let ssp_path = d.path().join("two.ssp");
    ssp::write_ssp(&ssd, &[], &ssp_path).unwrap();
    let e = ssp::load_system(&ssp_path, &LoadOptions::default())
        .expect_err("an archive's reference may not leave it")
        .to_string();
    assert!(
        e.contains("'../fmus/kbtest.fmu'") && e.contains("'..'"),
        "{e}"
    );

    for c in &mut ssd.system.components {
        c.source = format!("{}", d.path().join("fmus/kbtest.fmu").display());
    }
    ssp::write_ssd_file(&ssd, &ssd_path).unwrap();
    let e = ssp::load_system(&ssd_path, &LoadOptions::default())
        .expect_err("an absolute path is no relative reference")
        .to_string();
    assert!(e.contains("absolute path"), "{e}");
}
