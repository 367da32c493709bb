//! Every example the user is shown works when copied into a shell, in order: the README's
//! "Using it" block (all but `cargo build`, which built what the test uses), then the
//! "Examples:" of every subcommand's `--help`, all in one fresh directory laid out like the
//! repository after the build (`target/release/kneebench` and the FMU library next to it).
//!
//! Each line runs through `sh -c` as written, with two substitutions for a shared test
//! machine: the emulator's fixed port 47000 becomes port 0 (any free port) and its `--duration
//! 60` becomes 1 s. A line is expected to exit 0 unless its comment says `exit code N`.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The FMU library built with the binary (`cargo build --release --workspace`, or the
/// workspace's test build, which puts it under `deps/`).
fn fmu_library(bin: &Path) -> PathBuf {
    let dir = bin.parent().unwrap();
    [
        dir.join("libkneebench_fmu.so"),
        dir.join("deps/libkneebench_fmu.so"),
    ]
    .into_iter()
    .find(|p| p.is_file())
    .unwrap_or_else(|| {
        panic!(
            "libkneebench_fmu.so is not built next to {} (cargo build --release --workspace)",
            bin.display()
        )
    })
}

/// The example lines of the README's "Using it" block.
fn readme_lines() -> Vec<String> {
    let readme =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../README.md"))
            .unwrap();
    let block = readme
        .split("## Using it")
        .nth(1)
        .and_then(|s| s.split("```sh\n").nth(1))
        .and_then(|s| s.split("```").next())
        .expect("a ```sh block under ## Using it");
    let lines: Vec<String> = block.lines().map(str::to_string).collect();
    assert_eq!(lines[0], "cargo build --release --workspace");
    assert!(
        lines[1..]
            .iter()
            .all(|l| l.starts_with("target/release/kneebench "))
    );
    lines[1..].to_vec()
}

/// The lines under "Examples:" in `help` (indented by two spaces, up to the first line that
/// is not).
fn help_examples(help: &str) -> Vec<String> {
    let Some(rest) = help.split("\nExamples:\n").nth(1) else {
        return Vec::new();
    };
    rest.lines()
        .take_while(|l| l.starts_with("  "))
        .map(|l| l.trim().to_string())
        .collect()
}

/// The exit code a line documents in its comment (`# ... exit code N`), else 0.
fn expected_code(line: &str) -> i32 {
    line.split_once('#')
        .and_then(|(_, comment)| comment.split("exit code ").nth(1))
        .and_then(|c| c.split(|ch: char| !ch.is_ascii_digit()).next())
        .and_then(|c| c.parse().ok())
        .unwrap_or(0)
}

/// Runs `line` in `dir` with `bin_dir` first on PATH; checks the exit code.
fn run_line(dir: &Path, bin_dir: &Path, line: &str) {
    let shell = line
        .replace("127.0.0.1:47000", "127.0.0.1:0")
        .replace("--duration 60", "--duration 1");
    let path = format!(
        "{}:{}",
        bin_dir.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let o = Command::new("sh")
        .arg("-c")
        .arg(&shell)
        .current_dir(dir)
        .env("PATH", path)
        .output()
        .unwrap();
    assert_eq!(
        o.status.code(),
        Some(expected_code(line)),
        "`{line}`\nstdout: {}\nstderr: {}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
}

#[test]
fn every_example_of_the_readme_and_the_help_texts_works_in_order() {
    let bin = Path::new(env!("CARGO_BIN_EXE_kneebench"));
    let d = tempfile::tempdir().unwrap();
    let release = d.path().join("target/release");
    std::fs::create_dir_all(&release).unwrap();
    std::fs::copy(bin, release.join("kneebench")).unwrap();
    std::fs::copy(fmu_library(bin), release.join("libkneebench_fmu.so")).unwrap();

    let readme = readme_lines();
    assert!(readme.len() >= 10, "{readme:?}");
    for line in &readme {
        run_line(d.path(), &release, line);
    }
    // What the later examples rely on.
    for file in ["gait.csv", "out/study/SEA.csv", "open-loop.csv", "sea.csv"] {
        assert!(d.path().join(file).is_file(), "{file}");
    }

    let subcommands = [
        "export",
        "info",
        "validate",
        "run",
        "plot",
        "study",
        "metrics",
        "tune",
        "emulate",
        "key",
        "experiment",
    ];
    let mut ran = 0;
    for sub in subcommands {
        let help = Command::new(release.join("kneebench"))
            .args([sub, "--help"])
            .output()
            .unwrap();
        assert!(help.status.success(), "{sub} --help");
        let examples = help_examples(&String::from_utf8_lossy(&help.stdout));
        assert!(
            !examples.is_empty(),
            "`kneebench {sub} --help` shows no example"
        );
        for line in &examples {
            assert!(
                line.starts_with("kneebench ") || line.starts_with("printf "),
                "{sub}: {line}"
            );
            run_line(d.path(), &release, line);
            ran += 1;
        }
    }
    assert!(ran >= 18, "{ran} help examples");
    // The run examples recorded the variables they name.
    let pid = std::fs::read_to_string(d.path().join("pid.csv")).unwrap();
    assert!(pid.starts_with("time,"), "{pid}");
}

#[test]
fn the_example_parsers_see_what_they_should() {
    assert_eq!(
        help_examples("x\nExamples:\n  kneebench a\n  kneebench b   # c\nText\n  kneebench no\n"),
        ["kneebench a", "kneebench b   # c"]
    );
    assert_eq!(expected_code("kneebench study   # trips: exit code 3"), 3);
    assert_eq!(expected_code("kneebench study"), 0);
    assert_eq!(expected_code("kneebench run x   # a comment"), 0);
}
