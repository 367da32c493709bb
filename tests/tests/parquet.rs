//! Parquet results read back by pyarrow (the pinned venv): the same values, bit for bit, as
//! the in-memory rows of the same run; a float64 column per signal after `time`; the run's
//! metadata (version, system, parameters, GUID) in the file; a sweep table with its strings.

use kneebench_harness::package::export_all;
use kneebench_harness::results::parquet::ParquetFile;
use kneebench_harness::results::{ResultSink, Tee};
use kneebench_harness::{Fmu, LoadOptions, Results, RunConfig, System};
use kneebench_tests::{fmu_library, run_python};

/// Prints `name` and the hex bits of every value, per column, and the metadata.
const READ: &str = r#"
import struct, sys
import pyarrow.parquet as pq
t = pq.read_table(sys.argv[1])
for f in t.schema:
    print("column", f.name, f.type)
for name in t.column_names:
    col = t.column(name).to_pylist()
    print("bits", name, ",".join(struct.pack(">d", v).hex() for v in col))
for k, v in sorted(t.schema.metadata.items()):
    print("meta", k.decode(), v.decode())
"#;

fn bits(v: &[f64]) -> String {
    v.iter()
        .map(|x| format!("{:016x}", x.to_bits()))
        .collect::<Vec<_>>()
        .join(",")
}

#[test]
fn run_results_round_trip_through_pyarrow_with_metadata() {
    let dir = tempfile::tempdir().unwrap();
    export_all(&fmu_library(), dir.path()).unwrap();
    let fmu = Fmu::load(
        dir.path().join("GaitReference.fmu"),
        &LoadOptions::default(),
    )
    .unwrap();
    let guid = fmu.model_description().guid.clone();
    let mut system = System::new();
    system.add_component("gait", fmu).unwrap();
    system.set_value_str("gait.gaitPeriod", "1.25").unwrap();
    let config = RunConfig {
        stop_time: 3.0,
        step_size: 1e-3,
        ..RunConfig::default()
    };
    let out = dir.path().join("gait.parquet");
    let mut file = ParquetFile::create(&out).unwrap();
    file.set_metadata(vec![
        ("kneebench.system".into(), "GaitReference.fmu".into()),
        (
            "kneebench.parameters".into(),
            r#"{"gaitPeriod":"1.25"}"#.into(),
        ),
        ("kneebench.guid.gait".into(), guid.clone()),
    ]);
    let mut sink = Tee(file, Results::with_capacity(Vec::new(), Vec::new(), 0));
    system.run_into(&config, &mut sink).unwrap();
    let Tee(file, rows) = sink;
    assert!(!out.exists(), "nothing at the output before commit");
    file.commit().unwrap();
    let text = run_python(READ, &[out.to_str().unwrap()]);
    let lines: Vec<&str> = text.lines().collect();
    let columns: Vec<&str> = lines
        .iter()
        .filter(|l| l.starts_with("column "))
        .copied()
        .collect();
    assert_eq!(columns.len(), rows.names().len() + 1);
    assert_eq!(columns[0], "column time double");
    assert!(
        columns.iter().all(|c| c.ends_with(" double")),
        "{columns:?}"
    );
    assert_eq!(rows.times().len(), 3001);
    let want = |name: &str, values: &[f64]| format!("bits {name} {}", bits(values));
    assert!(lines.contains(&want("time", &rows.times()).as_str()));
    for name in rows.names() {
        let col = rows.column(name).unwrap();
        assert!(
            lines.contains(&want(name, &col).as_str()),
            "column {name} differs"
        );
    }
    for m in [
        format!("meta kneebench.version {}", env!("CARGO_PKG_VERSION")),
        "meta kneebench.system GaitReference.fmu".to_string(),
        r#"meta kneebench.parameters {"gaitPeriod":"1.25"}"#.to_string(),
        format!("meta kneebench.guid.gait {guid}"),
    ] {
        assert!(lines.contains(&m.as_str()), "missing {m}:\n{text}");
    }
}

#[test]
fn a_stopped_run_keeps_a_readable_partial_file() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r.parquet");
    let mut file = ParquetFile::create(&out).unwrap();
    file.begin(
        &["a".into()],
        &[kneebench_harness::results::ColumnKind::Real],
    )
    .unwrap();
    for i in 0..70_000 {
        file.push_row(i as f64 * 1e-3, &[i as f64]).unwrap();
    }
    let partial = file.keep_partial().unwrap();
    assert!(!out.exists());
    let text = run_python(
        "import sys, pyarrow.parquet as pq; t = pq.read_table(sys.argv[1]); print(t.num_rows, t.column('a')[69999].as_py(), t.column('time')[1].as_py())",
        &[partial.to_str().unwrap()],
    );
    assert_eq!(text.trim(), "70000 69999.0 0.001");
}
