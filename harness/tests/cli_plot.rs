//! `kneebench plot`: a file with many columns is refused without a choice of signals (one chart
//! of a hundred curves is unreadable); chosen columns, by `--signals` or `--variables`, plot.

use std::process::Command;

fn kneebench() -> Command {
    Command::new(env!("CARGO_BIN_EXE_kneebench"))
}

fn write_csv(path: &std::path::Path, columns: usize) {
    let mut text = String::from("time");
    for c in 0..columns {
        text.push_str(&format!(",s{c}"));
    }
    text.push('\n');
    for k in 0..50 {
        text.push_str(&format!("{}", k as f64 * 0.01));
        for c in 0..columns {
            text.push_str(&format!(",{}", (k * (c + 1)) as f64 * 0.1));
        }
        text.push('\n');
    }
    std::fs::write(path, text).unwrap();
}

#[test]
fn many_columns_are_refused_without_a_choice_and_chosen_ones_plot() {
    let dir = tempfile::tempdir().unwrap();
    let wide = dir.path().join("wide.csv");
    write_csv(&wide, 40);
    let refused = kneebench()
        .args(["plot", wide.to_str().unwrap(), "--out"])
        .arg(dir.path().join("all.png"))
        .output()
        .unwrap();
    assert!(!refused.status.success());
    let message = String::from_utf8_lossy(&refused.stderr);
    assert!(
        message.contains("40 columns") && message.contains("--signals"),
        "{message}"
    );
    assert!(!dir.path().join("all.png").exists());
    for flag in ["--signals", "--variables"] {
        let out = dir.path().join(format!("chosen{flag}.png"));
        let status = kneebench()
            .args(["plot", wide.to_str().unwrap(), flag, "s0,s7", "--out"])
            .arg(&out)
            .status()
            .unwrap();
        assert!(status.success(), "{flag}");
        let bytes = std::fs::read(&out).unwrap();
        assert_eq!(&bytes[..4], b"\x89PNG");
    }
    // Up to twelve columns plot without a choice.
    let narrow = dir.path().join("narrow.csv");
    write_csv(&narrow, 12);
    let status = kneebench()
        .args(["plot", narrow.to_str().unwrap(), "--out"])
        .arg(dir.path().join("narrow.svg"))
        .status()
        .unwrap();
    assert!(status.success());
}

/// A plot that is refused or fails leaves an earlier image at `--out` as it was (the image is
/// drawn beside it and renamed into place), and nothing beside it; values at the edge of a
/// double (an axis wider than a double, on which plotters looped for ever), an image too
/// large to allocate and a file of no rows are refused with their reason, quickly.
#[test]
fn a_refused_plot_leaves_an_earlier_image_untouched() {
    let dir = tempfile::tempdir().unwrap();
    let ok = dir.path().join("ok.csv");
    write_csv(&ok, 2);
    let huge = dir.path().join("huge.csv");
    std::fs::write(&huge, "time,y\n0,-1e308\n1,1e308\n").unwrap();
    let empty = dir.path().join("empty.csv");
    std::fs::write(&empty, "time,y\n").unwrap();
    for ext in ["svg", "png"] {
        let out = dir.path().join(format!("victim.{ext}"));
        std::fs::write(&out, "an earlier image").unwrap();
        // A size out of range is a usage error (exit code 2), refused while parsing.
        for (file, extra, reason, code) in [
            // A column the file has not is a usage error too (it exited with 1).
            (&ok, vec!["--signals", "nope"], "no column named 'nope'", 2),
            (&ok, vec!["--width", "0"], "1..=16384", 2),
            (
                &ok,
                vec!["--width", "100000", "--height", "100000"],
                "1..=16384",
                2,
            ),
            (&huge, vec![], "more than a double", 1),
            (&empty, vec![], "no rows", 1),
        ] {
            let started = std::time::Instant::now();
            let refused = kneebench()
                .arg("plot")
                .arg(file)
                .args(&extra)
                .arg("--out")
                .arg(&out)
                .output()
                .unwrap();
            let message = String::from_utf8_lossy(&refused.stderr);
            assert_eq!(refused.status.code(), Some(code), "{extra:?}: {message}");
            assert!(message.contains(reason), "{extra:?}: {message}");
            assert!(started.elapsed().as_secs() < 60, "{extra:?}");
            assert_eq!(std::fs::read_to_string(&out).unwrap(), "an earlier image");
        }
        let left: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .filter(|n| n.contains("partial"))
            .collect();
        assert!(left.is_empty(), "{left:?}");
        let plotted = kneebench()
            .arg("plot")
            .arg(&ok)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(
            plotted.status.success(),
            "{}",
            String::from_utf8_lossy(&plotted.stderr)
        );
        assert!(std::fs::read(&out).unwrap().len() > 1000);
    }
}

/// A Parquet results file (what `kneebench run --output x.parquet` writes) plots as its CSV
/// twin does; it was read as text before ("stream did not contain valid UTF-8").
#[test]
fn a_parquet_results_file_plots() {
    use kneebench_harness::Results;
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("r.csv");
    write_csv(&csv, 3);
    let parquet = dir.path().join("r.parquet");
    Results::read_csv_file(&csv)
        .unwrap()
        .write_parquet_file(&parquet, Vec::new())
        .unwrap();
    let out = dir.path().join("r.svg");
    let o = kneebench()
        .args(["plot", parquet.to_str().unwrap(), "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let svg = std::fs::read_to_string(&out).unwrap();
    assert!(svg.contains("s2"), "the legend names the columns");
}
