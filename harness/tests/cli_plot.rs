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
