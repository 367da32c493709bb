//! `kneebench metrics` and `kneebench tune` on recorded responses.

use std::process::Command;

fn kneebench() -> Command {
    Command::new(env!("CARGO_BIN_EXE_kneebench"))
}

#[test]
fn metrics_of_a_first_order_step_and_a_tracking_error() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("step.csv");
    let mut text = String::from("time,y,r\n");
    for k in 0..=40_000 {
        let t = k as f64 * 1e-4;
        // A step at t = 1 s of a first-order lag with tau = 0.2 s.
        let y = if t < 1.0 {
            0.0
        } else {
            2.0 * (1.0 - (-(t - 1.0) / 0.2).exp())
        };
        text.push_str(&format!("{t:?},{y:?},{:?}\n", y + 0.01));
    }
    std::fs::write(&csv, text).unwrap();
    let out = kneebench()
        .args([
            "metrics",
            csv.to_str().unwrap(),
            "--signal",
            "y",
            "--target",
            "2",
            "--from",
            "1",
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    // tau ln 10 = 0.460517 s, tau ln 20 = 0.599146 s.
    assert!(text.contains("rise time 90 %  0.4605"), "{text}");
    assert!(text.contains("settling 5 %    0.5991"), "{text}");
    assert!(text.contains("overshoot       0.00 %"), "{text}");
    let out = kneebench()
        .args([
            "metrics",
            csv.to_str().unwrap(),
            "--signal",
            "y",
            "--reference",
            "r",
        ])
        .output()
        .unwrap();
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(
        text.contains("RMS  1.0000") && text.contains("max  1.0000"),
        "{text}"
    );
    // A missing column is an error with exit code 1.
    let out = kneebench()
        .args(["metrics", csv.to_str().unwrap(), "--signal", "nope"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("no column 'nope'"));
}

#[test]
fn tune_prints_ziegler_nichols_gains_and_refuses_bad_input() {
    let out = kneebench()
        .args(["tune", "--ku", "10", "--tu", "0.5"])
        .output()
        .unwrap();
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(
        text.contains("kp = 6.000000")
            && text.contains("ki = 24.000000")
            && text.contains("kd = 0.375000"),
        "{text}"
    );
    let out = kneebench()
        .args(["tune", "--ku=-1", "--tu", "0.5"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let out = kneebench().args(["tune", "--ku", "1"]).output().unwrap();
    assert_eq!(out.status.code(), Some(2), "usage error");
}
