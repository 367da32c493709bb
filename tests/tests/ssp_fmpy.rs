//! SSP written by the harness, read back identically by our reader, accepted by fmpy's SSP
//! reader (`fmpy.ssp.ssd.read_ssd`, which validates against the SSP 1.0 schema) with the same
//! components, connectors, connections and parameter values, and simulated by fmpy's
//! `simulate_ssp` with the same results as our run of the same `.ssp`.
//!
//! What fmpy 0.3.32's SSP support does and does not do (read from `fmpy/ssp/`), and how the
//! test accounts for it:
//! - `read_ssd` keeps a connector's name and kind, not its type, and does not read
//!   `DefaultExperiment`: the test compares names and kinds, and passes stop time and step
//!   to `simulate_ssp` explicitly.
//! - `simulate_ssp` does not apply the components' inline `ParameterBindings`; it applies the
//!   `parameter_set` argument, whose names are `component.variable`. The Python snippet builds
//!   that set from the bindings fmpy read, so the values that reach the FMUs are the ones fmpy
//!   parsed from our file.
//! - `get_connections` fails on an input connector no connection ends at
//!   ([`SspSystem::drop_unconnected_inputs`] exists for that; called before writing).
//! - `simulate_ssp` steps every component, then copies outputs to inputs (a Jacobi scheme), on
//!   an accumulated time `time += step_size`, and labels each row with the time at the *start*
//!   of the step although the values are those after it. The step here is 2^-9 s, so the
//!   accumulated times are exact, and fmpy's row `k` is compared with our row `k + 1`.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;

use kneebench_harness::master::Value;
use kneebench_harness::package::export_all;
use kneebench_harness::ssp::{
    self, Ssd, SspComponent, SspConnection, SspExperiment, SspParameter, SspSystem,
};
use kneebench_harness::{Algorithm, ArchiveLimits, Fmu, LoadOptions, Outcome, Results};
use kneebench_tests::*;

/// 2^-9 s: a whole number of nanoseconds, and exact when fmpy accumulates it.
const STEP: f64 = 1.0 / 512.0;
const STOP: f64 = 1.0;

/// Prints, one per line, what fmpy's reader sees in an `.ssp`: components, connectors,
/// parameter values of the bindings and connections.
const FMPY_READ: &str = r#"
import sys
from fmpy.ssp.ssd import read_ssd, get_connections
ssd = read_ssd(sys.argv[1])
print("ssd", ssd.name, ssd.version, ssd.system.name)
for c in ssd.system.elements:
    print("component", c.name, c.source, c.type)
    for k in c.connectors:
        print("connector", c.name, k.name, k.kind)
    for b in c.parameterBindings:
        for ps in b.parameterValues:
            for p in ps.parameters:
                v = repr(float(p.value)) if p.type == "Real" else p.value
                print("parameter", c.name, p.name, p.type, v)
for x in ssd.system.connections:
    print("connection", x.startElement, x.startConnector, x.endElement, x.endConnector)
# What fmpy's simulation resolves (fails on unconnected inputs).
for a, b in get_connections(ssd.system):
    print("resolved", a.parent.name, a.name, b.parent.name, b.name)
"#;

/// Simulates an `.ssp` with fmpy's `simulate_ssp`, the bindings' values as its parameter set;
/// writes `time` and every output connector (`component.connector`) as CSV.
const FMPY_SIMULATE: &str = r#"
import sys
from fmpy.ssp.ssd import read_ssd, ParameterSet, Parameter
from fmpy.ssp.simulation import simulate_ssp
path, stop, step, out = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
ssd = read_ssd(path)
ps = ParameterSet(name="bindings")
outputs = []
for c in ssd.system.elements:
    outputs += [c.name + "." + k.name for k in c.connectors if k.kind == "output"]
    for b in c.parameterBindings:
        for s in b.parameterValues:
            for p in s.parameters:
                q = Parameter(name=c.name + "." + p.name)
                q.type, q.value = p.type, p.value
                ps.parameters.append(q)
r = simulate_ssp(path, stop_time=stop, step_size=step, parameter_set=ps)
with open(out, "w") as f:
    f.write(",".join(["time"] + outputs) + "\n")
    for row in r:
        f.write(",".join(repr(float(row[n])) for n in ["time"] + outputs) + "\n")
"#;

fn gait_reference(dir: &Path) -> PathBuf {
    export_all(&fmu_library(), dir)
        .expect("export")
        .into_iter()
        .find(|f| f.identifier == "GaitReference")
        .expect("GaitReference exported")
        .path
}

fn real(name: &str, v: f64) -> SspParameter {
    SspParameter {
        name: name.into(),
        value: Value::Real(v),
    }
}

/// The lines [`FMPY_READ`] must print for `ssd`.
fn expected_view(ssd: &Ssd) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    out.insert(format!(
        "ssd {} {} {}",
        ssd.name, ssd.version, ssd.system.name
    ));
    for c in &ssd.system.components {
        out.insert(format!(
            "component {} {} application/x-fmu-sharedlibrary",
            c.name, c.source
        ));
        for k in &c.connectors {
            let kind = format!("{:?}", k.kind).to_lowercase();
            out.insert(format!("connector {} {} {kind}", c.name, k.name));
        }
        for p in &c.parameters {
            let (ty, v) = match &p.value {
                Value::Real(v) => ("Real", format!("{v:?}")),
                Value::Integer(v) => ("Integer", v.to_string()),
                Value::Boolean(v) => ("Boolean", v.to_string()),
                Value::String(v) => ("String", v.clone()),
            };
            out.insert(format!("parameter {} {} {ty} {v}", c.name, p.name));
        }
    }
    for x in &ssd.system.connections {
        let (se, ee) = (
            x.start_element.as_deref().unwrap(),
            x.end_element.as_deref().unwrap(),
        );
        let (sc, ec) = (&x.start_connector, &x.end_connector);
        out.insert(format!("connection {se} {sc} {ee} {ec}"));
        out.insert(format!("resolved {se} {sc} {ee} {ec}"));
    }
    out
}

/// Writes `ssd` with its FMUs as an `.ssp`, checks that our reader gives it back identically
/// and that fmpy's reader sees exactly its components, connectors, parameters and connections.
fn write_and_check(ssd: &Ssd, files: &[(String, PathBuf)], path: &Path) {
    ssp::write_ssp(ssd, files, path).unwrap();
    let (back, _, _extracted) = ssp::read_file(path, &ArchiveLimits::default()).unwrap();
    assert_eq!(&back, ssd, "read back differs");
    let seen: BTreeSet<String> = run_python(FMPY_READ, &[&path.display().to_string()])
        .lines()
        .map(str::to_string)
        .collect();
    assert_eq!(seen, expected_view(ssd), "what fmpy's reader sees");
}

fn fmpy_simulate(ssp_path: &Path, out: &Path) -> Results {
    run_python(
        FMPY_SIMULATE,
        &[
            &ssp_path.display().to_string(),
            &STOP.to_string(),
            &STEP.to_string(),
            &out.display().to_string(),
        ],
    );
    Results::read_csv_file(out).unwrap()
}

#[test]
fn two_gait_references_with_parameters_match_fmpy() {
    let dir = tempfile::tempdir().unwrap();
    let gait = gait_reference(dir.path());
    let md = Fmu::load(&gait, &LoadOptions::default())
        .unwrap()
        .model_description()
        .clone();
    let source = "resources/GaitReference.fmu";
    let mut left = SspComponent::from_model_description("left", source, &md);
    left.parameters = vec![real("gaitPeriod", 1.25), real("kneeAngleAmplitude", 1.125)];
    let mut right = SspComponent::from_model_description("right", source, &md);
    right.parameters = vec![
        real("kneeTorqueAmplitude", 40.5),
        real("kneeAngleOffset", -0.125),
        real("gaitPeriod", 0.75),
    ];
    let mut ssd = Ssd {
        name: "TwoGaits".into(),
        version: "1.0".into(),
        system: SspSystem {
            name: "Bench".into(),
            components: vec![left, right],
            connections: vec![],
        },
        default_experiment: Some(SspExperiment {
            start_time: Some(0.0),
            stop_time: Some(STOP),
            step_size: Some(STEP),
            algorithm: Some(Algorithm::Jacobi),
        }),
    };
    ssd.system.drop_unconnected_inputs();
    assert!(
        ssd.system.components[0]
            .connectors
            .iter()
            .any(|k| k.name == "kneeAngleReference"),
        "GaitReference lost its outputs"
    );
    let ssp_path = dir.path().join("two.ssp");
    write_and_check(&ssd, &[(source.to_string(), gait.clone())], &ssp_path);

    // Our run of the .ssp (its default experiment) against fmpy's.
    let loaded = ssp::load_system(&ssp_path, &LoadOptions::default()).unwrap();
    assert_eq!(loaded.config.step_size, STEP);
    let out = loaded.system.run(&loaded.config).unwrap();
    assert!(
        matches!(out.outcome, Outcome::Completed { .. }),
        "{:?}",
        out.outcome
    );
    let ours = out.results;
    let theirs = fmpy_simulate(&ssp_path, &dir.path().join("fmpy.csv"));
    assert_eq!(ours.len(), 513);
    assert_eq!(theirs.len(), 512, "fmpy records one row per step");
    let (our_t, their_t) = (ours.times(), theirs.times());
    for k in 0..theirs.len() {
        assert_eq!(their_t[k] + STEP, our_t[k + 1], "row {k}");
    }
    for name in theirs.names() {
        let (a, b) = (ours.column(name).unwrap(), theirs.column(name).unwrap());
        for k in 0..b.len() {
            let (x, y) = (a[k + 1], b[k]);
            assert!(
                (x - y).abs() <= 1e-12 * (1.0 + x.abs().max(y.abs())),
                "{name} at t = {}: ours {x} vs fmpy {y}",
                our_t[k + 1]
            );
        }
    }
    // The bindings reached the FMUs: different periods give different angles.
    let (l, r) = (
        ours.column("left.kneeAngleReference").unwrap(),
        ours.column("right.kneeAngleReference").unwrap(),
    );
    assert!(l.iter().zip(&r).any(|(a, b)| (a - b).abs() > 1e-3));
}

/// A PythonFMU first-order lag (see `foreign_fmu.rs`), here only read by fmpy and simulated in
/// its Python host; our run of a PythonFMU needs the Python runtime preloaded in a separate
/// process, which `foreign_fmu.rs` does.
const LAG: &str = r#"
import math
from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real

class Lag(Fmi2Slave):
    author = "kneebench tests"
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.tau = 0.125
        self.order = 1
        self.u = 0.0
        self.y = 0.0
        self.register_variable(Real("tau", causality=Fmi2Causality.parameter, variability=Fmi2Variability.tunable))
        self.register_variable(Integer("order", causality=Fmi2Causality.parameter, variability=Fmi2Variability.tunable))
        self.register_variable(Real("u", causality=Fmi2Causality.input))
        self.register_variable(Real("y", causality=Fmi2Causality.output))

    def do_step(self, current_time, step_size):
        a = math.exp(-step_size / self.tau)
        for _ in range(self.order):
            self.y = a * self.y + (1.0 - a) * self.u
        return True
"#;

#[test]
fn gait_reference_feeding_a_foreign_fmu_is_read_and_run_by_fmpy() {
    let dir = tempfile::tempdir().unwrap();
    let gait = gait_reference(dir.path());
    std::fs::write(dir.path().join("Lag.py"), LAG).unwrap();
    let built = Command::new(python())
        .args(["-m", "pythonfmu", "build", "-f"])
        .arg(dir.path().join("Lag.py"))
        .arg("--dest")
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(
        built.status.success(),
        "{}",
        String::from_utf8_lossy(&built.stderr)
    );
    let lag = dir.path().join("Lag.fmu");
    let (gait_md, lag_md) = (
        kneebench_harness::load::extract_and_parse(&gait, &ArchiveLimits::default())
            .unwrap()
            .1,
        kneebench_harness::load::extract_and_parse(&lag, &ArchiveLimits::default())
            .unwrap()
            .1,
    );
    let mut reference =
        SspComponent::from_model_description("reference", "resources/GaitReference.fmu", &gait_md);
    reference.parameters = vec![real("kneeAngleAmplitude", 1.5), real("gaitPeriod", 1.0)];
    let mut filter = SspComponent::from_model_description("filter", "resources/Lag.fmu", &lag_md);
    filter.parameters = vec![
        real("tau", 0.0625),
        SspParameter {
            name: "order".into(),
            value: Value::Integer(2),
        },
    ];
    let mut ssd = Ssd {
        name: "ReferenceFilter".into(),
        version: "1.0".into(),
        system: SspSystem {
            name: "Bench".into(),
            components: vec![reference, filter],
            connections: vec![SspConnection {
                start_element: Some("reference".into()),
                start_connector: "kneeAngleReference".into(),
                end_element: Some("filter".into()),
                end_connector: "u".into(),
            }],
        },
        default_experiment: Some(SspExperiment {
            start_time: Some(0.0),
            stop_time: Some(STOP),
            step_size: Some(STEP),
            algorithm: Some(Algorithm::Jacobi),
        }),
    };
    ssd.system.drop_unconnected_inputs();
    let ssp_path = dir.path().join("filter.ssp");
    write_and_check(
        &ssd,
        &[
            ("resources/GaitReference.fmu".into(), gait),
            ("resources/Lag.fmu".into(), lag),
        ],
        &ssp_path,
    );
    // fmpy runs it: the filter follows the reference through the connection, with the
    // bound time constant (a lag of 2 x 1/16 s at most) and one step of Jacobi delay.
    let r = fmpy_simulate(&ssp_path, &dir.path().join("fmpy.csv"));
    let (x, y) = (
        r.column("reference.kneeAngleReference").unwrap(),
        r.column("filter.y").unwrap(),
    );
    let peak = |v: &[f64]| v.iter().cloned().fold(f64::MIN, f64::max);
    assert!(
        peak(&x) > 1.4,
        "the bindings reached GaitReference: peak {}",
        peak(&x)
    );
    assert!(
        peak(&y) > 0.8 * peak(&x) && peak(&y) < peak(&x),
        "filter peak {} vs reference peak {}",
        peak(&y),
        peak(&x)
    );
}
