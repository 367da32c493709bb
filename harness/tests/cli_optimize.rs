//! `kneebench optimize` and `kneebench sweep` on each other's specs: the example optimisation
//! (shortened) runs and prints its best run, and `--resume` continues its finished Parquet
//! table with one more generation; each command refuses the other's spec with exit code 2 and
//! says which command to use.

mod common;

use std::path::Path;
use std::process::Command;

fn kneebench() -> Command {
    Command::new(env!("CARGO_BIN_EXE_kneebench"))
}

#[test]
fn optimize_runs_the_example_and_each_command_refuses_the_others_spec() {
    let dir = tempfile::tempdir().unwrap();
    let fmus = common::exported_fmus(Path::new(env!("CARGO_BIN_EXE_kneebench")), dir.path());
    let example =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/stiffness-sweep/optimize.toml");
    let text = std::fs::read_to_string(example).unwrap();
    // Population 4, one generation after it: 8 runs.
    let short = text
        .replace("\"../../out/fmus\"", &format!("\"{}\"", fmus.display()))
        .replace("points = 8", "points = 4")
        .replace("generations = 20", "generations = 1");
    assert_eq!(short.matches(&fmus.display().to_string()).count(), 1);
    assert!(short.contains("points = 4") && short.contains("generations = 1"));
    let spec = dir.path().join("optimize.toml");
    std::fs::write(&spec, &short).unwrap();
    let table = dir.path().join("o.csv");
    let out = kneebench()
        .arg("optimize")
        .arg(&spec)
        .arg("--output")
        .arg(&table)
        .output()
        .unwrap();
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    assert!(
        stderr.contains("generation 0/1: best all_electrical_energy = ")
            && stderr.contains("generation 1/1: best all_electrical_energy = "),
        "{stderr}"
    );
    assert!(stdout.starts_with("best: point "), "{stdout}");
    for line in [
        "  plant.springStiffness = ",
        "  plant.harmonicDriveRatio = ",
        "  rms_error_knee = ",
    ] {
        assert!(stdout.contains(line), "{line}: {stdout}");
    }
    let csv = std::fs::read_to_string(&table).unwrap();
    assert_eq!(csv.lines().count(), 1 + 8, "{csv}");
    assert!(csv.starts_with("point,plant.springStiffness,plant.harmonicDriveRatio,"));

    // Finished to Parquet, then continued with one more generation: only its 4 runs are new
    // (tests/tests/optimize.rs shows that they alone run), and the table has all 12.
    let parquet = dir.path().join("o.parquet");
    let optimize = |spec: &Path, resume: bool| {
        let mut c = kneebench();
        c.arg("optimize").arg(spec).arg("--output").arg(&parquet);
        if resume {
            c.arg("--resume");
        }
        let out = c.output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
        assert_eq!(out.status.code(), Some(0), "{stderr}");
        stderr
    };
    optimize(&spec, false);
    let longer = dir.path().join("optimize-longer.toml");
    std::fs::write(&longer, short.replace("generations = 1", "generations = 2")).unwrap();
    let stderr = optimize(&longer, true);
    assert!(
        stderr.contains("generation 2/2: best all_electrical_energy = "),
        "{stderr}"
    );
    let table = kneebench_harness::sweep::SweepTable::read_parquet(&parquet, 2).unwrap();
    assert_eq!(table.rows.len(), 12);
    assert!(
        table
            .rows
            .iter()
            .enumerate()
            .all(|(i, r)| r.point == i as u64)
    );

    let sweep = kneebench()
        .arg("sweep")
        .arg(&spec)
        .arg("--output")
        .arg(dir.path().join("s.csv"))
        .output()
        .unwrap();
    assert_eq!(sweep.status.code(), Some(2));
    let e = String::from_utf8_lossy(&sweep.stderr);
    assert!(
        e.contains(", line 26: this spec optimises ([optimize]): run it with `kneebench optimize`"),
        "{e}"
    );
    assert!(!dir.path().join("s.csv").exists());

    let cut = short.find("[optimize]").unwrap();
    std::fs::write(&spec, &short[..cut]).unwrap();
    let optimize = kneebench()
        .arg("optimize")
        .arg(&spec)
        .arg("--output")
        .arg(dir.path().join("o2.csv"))
        .output()
        .unwrap();
    assert_eq!(optimize.status.code(), Some(2));
    let e = String::from_utf8_lossy(&optimize.stderr);
    assert!(
        e.contains("optimize.toml: no [optimize] table: `kneebench optimize` needs one"),
        "{e}"
    );
}
