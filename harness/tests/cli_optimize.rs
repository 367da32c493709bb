//! `kneebench optimize` and `kneebench sweep` on each other's specs: the example optimisation
//! (shortened) runs and prints its best run; each command refuses the other's spec with exit
//! code 2 and says which command to use.

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
