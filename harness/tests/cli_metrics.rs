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
    // A missing column is a usage error (exit code 2; it was 1), for the reference too.
    let out = kneebench()
        .args(["metrics", csv.to_str().unwrap(), "--signal", "nope"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("no column 'nope'"));
    let out = kneebench()
        .args([
            "metrics",
            csv.to_str().unwrap(),
            "--signal",
            "y",
            "--reference",
            "nope",
        ])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
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
        text.contains("kp = 6\n") && text.contains("ki = 24\n") && text.contains("kd = 0.375\n"),
        "{text}"
    );
    // Inputs whose gains overflow a double (or underflow to zero) are usage errors naming the
    // gain, its rule and the inputs: ki = inf was printed, and kp with 300 digits, exit 0.
    for (ku, tu, needle) in [
        (
            "1e308",
            "1e-308",
            "ki = 0.6 Ku / (Tu/2) is inf (overflow) for Ku = 1e308, Tu = 1e-308",
        ),
        (
            "1e308",
            "1e308",
            "kd = 0.6 Ku Tu/8 is inf (overflow) for Ku = 1e308, Tu = 1e308",
        ),
        ("1e-308", "1e308", "ki = 0.6 Ku / (Tu/2) is 0 (underflow)"),
    ] {
        let out = kneebench()
            .args(["tune", "--ku", ku, "--tu", tu])
            .output()
            .unwrap();
        let e = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{ku} {tu}: {e}");
        assert!(e.contains("--ku, --tu") && e.contains(needle), "{e}");
        assert!(out.stdout.is_empty(), "{ku} {tu}");
    }
    // Large finite gains print compactly.
    let out = kneebench()
        .args(["tune", "--ku", "1e300", "--tu", "1"])
        .output()
        .unwrap();
    let text = String::from_utf8(out.stdout).unwrap();
    assert_eq!(out.status.code(), Some(0));
    assert!(
        text.contains("kp = 6e299\n")
            && text.contains("ki = 1.2e300\n")
            && text.contains("kd = 7.5e298\n"),
        "{text}"
    );
    // A negative gain is a usage error, refused while parsing (it exited with 1).
    let out = kneebench()
        .args(["tune", "--ku=-1", "--tu", "0.5"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let out = kneebench().args(["tune", "--ku", "1"]).output().unwrap();
    assert_eq!(out.status.code(), Some(2), "usage error");
}

/// A CSV whose data rows are not its lines: a comment, the header and a blank line before them.
fn csv_with_a_bad_sample(dir: &std::path::Path, bad: &str) -> std::path::PathBuf {
    let path = dir.join("bad.csv");
    let mut text = String::from("# recorded by hand\ntime,y,other\n\n");
    for k in 0..50 {
        let t = k as f64 * 0.01;
        let y = if k == 30 {
            bad.to_string()
        } else {
            format!("{:?}", 1.0 - (-t / 0.1).exp())
        };
        text.push_str(&format!("{t:?},{y},nan\n"));
    }
    std::fs::write(&path, text).unwrap();
    path
}

/// `metrics` and `tune` of the signal `y` of the results file `name`.
fn metrics_and_tune_of_y(name: &str) -> Vec<Vec<&str>> {
    vec![
        vec!["metrics", name, "--signal", "y"],
        vec![
            "tune",
            "--step-response",
            name,
            "--signal",
            "y",
            "--input-step",
            "1",
        ],
    ]
}

/// A non-finite sample in the signal metrics or tune reads is named by the file and its line
/// (row 31 is line 34 of the file: a comment, the header and a blank line come first); a
/// non-finite time too. A column neither reads (`other`, all NaN) does not matter.
#[test]
fn metrics_and_tune_name_the_file_and_line_of_a_non_finite_sample() {
    let dir = tempfile::tempdir().unwrap();
    for bad in ["nan", "inf", "-inf"] {
        let csv = csv_with_a_bad_sample(dir.path(), bad);
        let name = csv.display().to_string();
        let mut commands = metrics_and_tune_of_y(&name);
        commands.push(vec!["metrics", &name, "--signal", "y", "--reference", "y"]);
        for args in commands {
            let out = kneebench().args(&args).output().unwrap();
            let e = String::from_utf8_lossy(&out.stderr);
            assert_eq!(out.status.code(), Some(1), "{args:?}: {e}");
            assert!(
                e.contains(&format!("{name}, line 34: y = ")) && e.contains("is not finite"),
                "{args:?}: {e}"
            );
        }
        // Rows before --from are not read.
        let out = kneebench()
            .args(["metrics", &name, "--signal", "y", "--from", "0.31"])
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    // A time that is not finite, or not increasing, whatever --from says.
    let path = dir.path().join("time.csv");
    std::fs::write(&path, "time,y\n0,0\n0.1,1\nnan,1\n0.3,1\n").unwrap();
    let out = kneebench()
        .args([
            "metrics",
            path.to_str().unwrap(),
            "--signal",
            "y",
            "--from",
            "0.2",
        ])
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{e}");
    assert!(
        e.contains(&format!("{}, line 4: the time NaN", path.display())),
        "{e}"
    );
}

/// `--from` and `--target` must be finite, and the window from `--from` to the end must hold
/// two rows: usage errors (exit code 2), not run errors (1).
#[test]
fn metrics_refuses_non_finite_and_empty_windows_as_usage_errors() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("ok.csv");
    std::fs::write(&csv, "time,y\n0,0\n1,1\n2,1\n").unwrap();
    let csv = csv.to_str().unwrap();
    for (args, needle) in [
        (vec!["--from", "nan"], "--from"),
        (vec!["--from", "inf"], "--from"),
        (vec!["--from=-inf"], "--from"),
        (vec!["--target", "NaN"], "--target"),
        (vec!["--from", "1.5"], "fewer than two rows"),
        (vec!["--from", "7"], "the last is at t = 2"),
    ] {
        let out = kneebench()
            .args(["metrics", csv, "--signal", "y"])
            .args(&args)
            .output()
            .unwrap();
        let e = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {e}");
        assert!(e.contains(needle), "{args:?}: {e}");
    }
    // A negative --from is a time like any other.
    let out = kneebench()
        .args(["metrics", csv, "--signal", "y", "--from", "-1"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// `metrics` and `tune` read the Parquet that `kneebench run` writes (by its content, any
/// name), with the same figures as its CSV twin; a non-finite sample is named by its row.
#[test]
fn metrics_and_tune_read_parquet_and_name_the_row_of_a_bad_sample() {
    use kneebench_harness::Results;
    let dir = tempfile::tempdir().unwrap();
    let csv = csv_with_a_bad_sample(dir.path(), "0.5");
    let parquet = dir.path().join("good.parquet");
    Results::read_csv_file(&csv)
        .unwrap()
        .write_parquet_file(&parquet, Vec::new())
        .unwrap();
    let stdout = |path: &std::path::Path| {
        let out = kneebench()
            .args(["metrics", path.to_str().unwrap(), "--signal", "y"])
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    assert_eq!(stdout(&parquet), stdout(&csv));
    let bad = csv_with_a_bad_sample(dir.path(), "nan");
    let parquet = dir.path().join("bad.parquet");
    Results::read_csv_file(&bad)
        .unwrap()
        .write_parquet_file(&parquet, Vec::new())
        .unwrap();
    let name = parquet.display().to_string();
    for args in metrics_and_tune_of_y(&name) {
        let out = kneebench().args(&args).output().unwrap();
        let e = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {e}");
        assert!(
            e.contains(&format!("{name}: row 31: y = NaN is not finite")),
            "{args:?}: {e}"
        );
    }
}
