//! Every example the user is shown works when copied into a shell, in order: the README's
//! "Using it" block (all but `cargo build`, which built what the test uses), the README's
//! experiment block and its identification block, then the "Examples:" of every subcommand's
//! `--help`, all in one fresh directory laid out like the repository after the build
//! (`target/release/kneebench` and the FMU library next to it, `examples/`).
//!
//! Each line runs through `sh -c` as written (a line continued with `\` joined to the next;
//! a line that only sets shell variables, `K=... F=...`, is kept and put before the lines after
//! it, as an interactive shell keeps them), with substitutions for a shared test machine: the
//! emulator's fixed port 47000 becomes port 0 (any free port) and its `--duration 60` becomes
//! 1 s; a line that talks to a bench at 127.0.0.1:47000 gets an emulator of its own, started
//! for it on a free port. A line is expected to exit 0 unless its comment says `exit code N`.

use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

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

/// The README.
fn readme() -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../README.md")).unwrap()
}

/// The lines of the first ```sh block after `marker` in `text`, a line ending in `\`
/// joined with the next.
fn sh_block(text: &str, marker: &str) -> Vec<String> {
    let block = text
        .split(marker)
        .nth(1)
        .and_then(|s| s.split("```sh\n").nth(1))
        .and_then(|s| s.split("```").next())
        .unwrap_or_else(|| panic!("a ```sh block after {marker:?}"));
    join_continuations(block.lines())
}

/// Joins every line that ends in `\` with the next one.
fn join_continuations<'a>(lines: impl Iterator<Item = &'a str>) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    let mut open = false;
    for line in lines {
        if open {
            let last = out.last_mut().unwrap();
            last.push(' ');
            last.push_str(line.trim_start());
        } else {
            out.push(line.to_string());
        }
        open = out.last().unwrap().ends_with('\\');
        if open {
            let last = out.last_mut().unwrap();
            last.pop();
            let kept = last.trim_end().len();
            last.truncate(kept);
        }
    }
    out
}

/// Whether `line` only sets shell variables (`K=target/release/kneebench F=out/fmus`).
fn sets_variables(line: &str) -> bool {
    !line.is_empty()
        && line.split_whitespace().all(|word| {
            word.split_once('=').is_some_and(|(name, _)| {
                !name.is_empty() && name.chars().all(|c| c.is_ascii_uppercase() || c == '_')
            })
        })
}

/// The example lines of the README's "Using it" block.
fn readme_lines() -> Vec<String> {
    let lines = sh_block(&readme(), "## Using it");
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

/// An emulator of the bench (BenchPlant behind the protocol, on a free port) for one example
/// line; killed when dropped.
struct Emulator {
    child: std::process::Child,
    address: String,
}

impl Emulator {
    fn start(dir: &Path, bin_dir: &Path) -> Emulator {
        let mut child = Command::new(bin_dir.join("kneebench"))
            .args(["emulate", "--bind", "127.0.0.1:0", "--duration", "600"])
            .args(["--fmu", "out/fmus/BenchPlant.fmu"])
            .current_dir(dir)
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let mut first = String::new();
        let mut stderr = std::io::BufReader::new(child.stderr.take().unwrap());
        stderr.read_line(&mut first).unwrap();
        // Keep reading what it logs: with the pipe closed, its next line (a refused frame, say)
        // would end it by SIGPIPE in the middle of the example.
        std::thread::spawn(move || std::io::copy(&mut stderr, &mut std::io::sink()));
        let address = first
            .trim()
            .strip_prefix("kneebench emulate: serving the bench protocol on ")
            .unwrap_or_else(|| panic!("the emulator said {first:?}"))
            .to_string();
        Emulator { child, address }
    }
}

impl Drop for Emulator {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Runs `line` in `dir` with `bin_dir` first on PATH, after the shell variables `prelude`
/// sets; checks the exit code. A line on the emulated bench runs in real time against a server
/// on this (shared, loaded) machine: a run the host disturbed enough to trip the link (the
/// master's link watchdog, or the bench's own, which stops the bench) is run again on a fresh
/// emulator, three attempts in all (as the hardware tests do).
fn run_line(dir: &Path, bin_dir: &Path, prelude: &str, line: &str) {
    let on_bench = line.contains("serverAddress=127.0.0.1:47000");
    let attempts = if on_bench { 3 } else { 1 };
    for attempt in 1..=attempts {
        let bench = on_bench.then(|| Emulator::start(dir, bin_dir));
        let mut shell = line
            .replace("127.0.0.1:47000", "127.0.0.1:0")
            .replace("--duration 60", "--duration 1");
        if let Some(e) = &bench {
            shell = shell.replace(
                "serverAddress=127.0.0.1:0",
                &format!("serverAddress={}", e.address),
            );
        }
        if !prelude.is_empty() {
            shell = format!("{prelude}; {shell}");
        }
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
        let stderr = String::from_utf8_lossy(&o.stderr);
        if o.status.code() != Some(expected_code(line))
            && attempt < attempts
            && (stderr.contains("link watchdog") || stderr.contains("the bench stopped itself"))
        {
            eprintln!("`{shell}`: the link tripped (attempt {attempt}), again: {stderr}");
            continue;
        }
        assert_eq!(
            o.status.code(),
            Some(expected_code(line)),
            "`{shell}`\nstdout: {}\nstderr: {stderr}",
            String::from_utf8_lossy(&o.stdout),
        );
        return;
    }
}

/// Runs the lines of a block in order; a line that only sets shell variables joins `prelude`
/// (kept for the blocks after it). Returns how many commands ran.
fn run_block(dir: &Path, bin_dir: &Path, prelude: &mut String, lines: &[String]) -> usize {
    let mut ran = 0;
    for line in lines {
        assert!(!line.contains("..."), "an elided example: {line}");
        if sets_variables(line) {
            if !prelude.is_empty() {
                prelude.push(' ');
            }
            prelude.push_str(line);
        } else {
            run_line(dir, bin_dir, prelude, line);
            ran += 1;
        }
    }
    ran
}

#[test]
fn every_example_of_the_readme_and_the_help_texts_works_in_order() {
    let bin = Path::new(env!("CARGO_BIN_EXE_kneebench"));
    let d = tempfile::tempdir().unwrap();
    let release = d.path().join("target/release");
    std::fs::create_dir_all(&release).unwrap();
    std::fs::copy(bin, release.join("kneebench")).unwrap();
    std::fs::copy(fmu_library(bin), release.join("libkneebench_fmu.so")).unwrap();
    // The examples the README and the help texts name (the sweep's spec).
    let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/stiffness-sweep");
    let copy = d.path().join("examples/stiffness-sweep");
    std::fs::create_dir_all(&copy).unwrap();
    for f in std::fs::read_dir(&examples).unwrap() {
        let f = f.unwrap().path();
        std::fs::copy(&f, copy.join(f.file_name().unwrap())).unwrap();
    }

    let mut prelude = String::new();
    let readme_lines = readme_lines();
    assert!(readme_lines.len() >= 10, "{readme_lines:?}");
    run_block(d.path(), &release, &mut prelude, &readme_lines);
    // What the later examples rely on.
    for file in ["gait.csv", "out/study/SEA.csv", "open-loop.csv", "sea.csv"] {
        assert!(d.path().join(file).is_file(), "{file}");
    }
    // The bench experiments (one on an emulated bench), then the identification from logs.
    let text = readme();
    let experiments = sh_block(&text, "The bench's experiments");
    assert!(experiments[0].starts_with("K=target/release/kneebench "));
    assert_eq!(
        run_block(d.path(), &release, &mut prelude, &experiments),
        6,
        "{experiments:?}"
    );
    let identify = sh_block(&text, "`kneebench identify` fits the plant");
    assert_eq!(
        run_block(d.path(), &release, &mut prelude, &identify),
        4,
        "{identify:?}"
    );
    assert!(d.path().join("out/identify/identified.ssv").is_file());
    // The loss surface's identification from a map and two sweeps recorded with it.
    let surface = sh_block(&text, "On the plant, as a user would run it");
    assert_eq!(
        run_block(d.path(), &release, &mut prelude, &surface),
        4,
        "{surface:?}"
    );
    let report = std::fs::read_to_string(d.path().join("out/hdidentify/identify.md")).unwrap();
    assert!(
        report.contains("| p00+ | hdLossPositiveSpeed[1] |"),
        "{report}"
    );

    let subcommands = [
        "export",
        "info",
        "validate",
        "run",
        "plot",
        "study",
        "sweep",
        "optimize",
        "metrics",
        "tune",
        "experiment",
        "identify",
        "emulate",
        "key",
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
                line.starts_with("kneebench ")
                    || line.starts_with("printf ")
                    || line.starts_with("$K ")
                    || sets_variables(line),
                "{sub}: {line}"
            );
        }
        // Each help text's shell variables are its own.
        let mut prelude = String::new();
        ran += run_block(d.path(), &release, &mut prelude, &examples);
    }
    assert!(ran >= 28, "{ran} help examples");
    // The run examples recorded the variables they name.
    let pid = std::fs::read_to_string(d.path().join("pid.csv")).unwrap();
    assert!(pid.starts_with("time,"), "{pid}");
    // The sweeps and the optimisation wrote their tables.
    for file in ["out/sweep.parquet", "sweep.csv", "out/optimize.parquet"] {
        assert!(d.path().join(file).is_file(), "{file}");
    }
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
    assert_eq!(
        join_continuations("a \\\n    b # c\nd\n".lines()),
        ["a b # c", "d"]
    );
    assert!(sets_variables("K=target/release/kneebench F=out/fmus"));
    assert!(!sets_variables("$K experiment step"));
    assert!(!sets_variables("kneebench x=1"));
}

/// The repository's source paths that `text` cites: each run of path characters starting at
/// one of the top-level directories (`harness/src/study/mod.rs`, `examples/stiffness-sweep`),
/// not inside a longer path or word, without a trailing `.` or `/`.
fn cited_paths(text: &str) -> Vec<String> {
    const ROOTS: [&str; 9] = [
        "harness/",
        "fmu/",
        "python/",
        "tests/",
        "scripts/",
        "examples/",
        "docs/",
        "modelDescription/",
        "fuzz/",
    ];
    let path_char = |c: char| c.is_ascii_alphanumeric() || "_./-".contains(c);
    let mut out = Vec::new();
    for (i, _) in text.char_indices() {
        let before = text[..i].chars().next_back();
        if before.is_some_and(path_char) || !ROOTS.iter().any(|r| text[i..].starts_with(r)) {
            continue;
        }
        let end = text[i..]
            .find(|c: char| !path_char(c))
            .map_or(text.len(), |n| i + n);
        let path = text[i..end].trim_end_matches(['.', '/', '-']);
        if !out.iter().any(|p| p == path) {
            out.push(path.to_string());
        }
    }
    out
}

/// Every source path that the README, `docs/` and the examples' READMEs cite exists (a file
/// moved into a module directory, `harness/src/study.rs` -> `harness/src/study/mod.rs`, left
/// the examples' README pointing at nothing).
#[test]
fn every_source_path_the_docs_cite_exists() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut docs = vec![root.join("README.md")];
    for dir in ["docs", "examples"] {
        for entry in std::fs::read_dir(root.join(dir)).unwrap() {
            let p = entry.unwrap().path();
            if p.extension().is_some_and(|e| e == "md") {
                docs.push(p);
            } else if p.join("README.md").is_file() {
                docs.push(p.join("README.md"));
            }
        }
    }
    let mut missing = Vec::new();
    let mut cited = 0;
    for doc in &docs {
        let text = std::fs::read_to_string(doc).unwrap();
        for path in cited_paths(&text) {
            cited += 1;
            if !root.join(&path).exists() {
                missing.push(format!("{}: {path}", doc.display()));
            }
        }
    }
    assert!(cited > 40, "only {cited} paths found: the scan is broken");
    assert!(
        missing.is_empty(),
        "cited paths that do not exist:\n{}",
        missing.join("\n")
    );
    assert_eq!(
        cited_paths("see `harness/src/study/mod.rs`, tests/tests/sweep.rs. and examples/x/"),
        [
            "harness/src/study/mod.rs",
            "tests/tests/sweep.rs",
            "examples/x"
        ]
    );
}
