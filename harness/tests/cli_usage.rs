//! Bad argument values are usage errors: exit code 2 with a message naming the option,
//! refused before any work (most while the command line is parsed), not run errors (exit code
//! 1) found after loading FMUs or reading logs, and not accepted (NaN passes every `<` test).

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

fn kneebench() -> Command {
    Command::new(env!("CARGO_BIN_EXE_kneebench"))
}

/// `kneebench study --fmus FMUS --cycles 2 --actuators sea --bench 127.0.0.1:9 --key KEY`
/// (nothing listens there: each use is refused before it connects), for more options.
fn study_on_bench(fmus_dir: &str, key: &Path) -> Command {
    let mut command = kneebench();
    command
        .args([
            "study",
            "--fmus",
            fmus_dir,
            "--cycles",
            "2",
            "--actuators",
            "sea",
        ])
        .args(["--bench", "127.0.0.1:9", "--key"])
        .arg(key);
    command
}

/// `kneebench emulate --bind BIND --duration DURATION --fmu PLANT`, for more options.
fn emulate_command(bind: &str, duration: &str, plant: &Path) -> Command {
    let mut command = kneebench();
    command
        .args(["emulate", "--bind", bind, "--duration", duration, "--fmu"])
        .arg(plant);
    command
}

/// The bench's FMUs, exported once for the whole test binary.
fn fmus() -> &'static Path {
    static DIR: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    &DIR.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let fmus = common::exported_fmus(Path::new(env!("CARGO_BIN_EXE_kneebench")), dir.path());
        (dir, fmus)
    })
    .1
}

/// A bare SSD in `dir` of one component, `plant`, the bench's `BenchPlant.fmu` (copied next
/// to it).
fn plant_system(dir: &Path) -> PathBuf {
    std::fs::copy(fmus().join("BenchPlant.fmu"), dir.join("BenchPlant.fmu")).unwrap();
    let ssd = dir.join("plant.ssd");
    std::fs::write(
        &ssd,
        r#"<?xml version="1.0" encoding="UTF-8"?>
<ssd:SystemStructureDescription xmlns:ssd="http://ssp-standard.org/SSP1/SystemStructureDescription" version="1.0" name="plant">
  <ssd:System name="plant">
    <ssd:Elements>
      <ssd:Component name="plant" source="BenchPlant.fmu" type="application/x-fmu-sharedlibrary"/>
    </ssd:Elements>
  </ssd:System>
</ssd:SystemStructureDescription>
"#,
    )
    .unwrap();
    ssd
}

/// Runs `command` and asserts it is a usage error (exit code 2) whose message contains every
/// one of `needles`; returns its output.
fn assert_usage(what: &str, command: &mut Command, needles: &[&str]) -> Output {
    let out = command.output().unwrap();
    let e = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{what}: {e}");
    for n in needles {
        assert!(e.contains(n), "{what}: no '{n}' in: {e}");
    }
    out
}

#[test]
fn identify_refuses_bad_windows_and_durations() {
    let dir = tempfile::tempdir().unwrap();
    let fmu = dir.path().join("missing.fmu");
    for (args, option) in [
        (&["--window", "0"][..], "--window"),
        (&["--window", "1"], "--window"),
        (&["--window=-3"], "--window"),
        (&["--surface-window", "0"], "--surface-window"),
        (&["--drive-window", "1"], "--drive-window"),
        (&["--refine-seconds", "0"], "--refine-seconds"),
        (&["--refine-seconds", "nan"], "--refine-seconds"),
        (&["--refine-seconds", "inf"], "--refine-seconds"),
    ] {
        assert_usage(
            &format!("{args:?}"),
            kneebench()
                .args(["identify", "log.csv", "--fmu"])
                .arg(&fmu)
                .args(args),
            &[option],
        );
    }
}

/// `identify --param` names (and values) are checked against the plant FMU before the logs are
/// read or anything is fitted, with `--no-refine` too (there they were not checked at all): the
/// log named here does not exist, so a check that came later would fail on it instead.
#[test]
fn identify_checks_param_names_up_front_and_lists_the_valid_ones() {
    let plant = fmus().join("BenchPlant.fmu");
    for refine in [false, true] {
        for (param, needles) in [
            (
                "nosuchParameter=1",
                &[
                    "--param",
                    "'nosuchParameter' is not a parameter of BenchPlant",
                    "actuationInertia",
                    "frictionModel",
                ][..],
            ),
            (
                "frictionModel=abc",
                &["--param", "frictionModel = 'abc'"][..],
            ),
            (
                "frictionModel",
                &["--param 'frictionModel': expected NAME=VALUE"][..],
            ),
            // Bounds too (the study's check, shared): the FMU refused it only in the
            // refinement's simulation, after the fit.
            (
                "actuationInertia=-1",
                &[
                    "--param",
                    "actuationInertia = '-1': -1 is outside [0.001, 100]",
                ][..],
            ),
        ] {
            let mut cmd = kneebench();
            cmd.args(["identify", "missing-log.csv", "--fmu"])
                .arg(&plant)
                .args(["--param", param, "--out"])
                .arg(std::env::temp_dir().join("kneebench-cli-usage-identify"));
            if !refine {
                cmd.arg("--no-refine");
            }
            let out = assert_usage(&format!("{param} (refine {refine})"), &mut cmd, needles);
            let e = String::from_utf8_lossy(&out.stderr);
            assert!(!e.contains("missing-log.csv"), "{e}");
        }
    }
}

#[test]
fn experiment_refuses_bad_values_before_running() {
    let dir = tempfile::tempdir().unwrap();
    let plant = fmus().join("BenchPlant.fmu");
    for (name, args, needles) in [
        ("bode", &["--stages", "0"][..], &["--stages"][..]),
        ("bode", &["--dwell", "0"], &["--dwell"]),
        ("bode", &["--dwell", "nan"], &["--dwell"]),
        ("bode", &["--start-frequency=-1"], &["--start-frequency"]),
        ("bode", &["--ratio", "0.5"], &["--ratio"]),
        ("bode", &["--amplitude", "inf"], &["--amplitude"]),
        ("bode", &["--input", "both"], &["--input 'both'"]),
        // Past a bound of the FMU the option sets, or too short for the analysis: refused
        // before the run (they ran and failed with exit code 1).
        (
            "bode",
            &["--stages", "1", "--start-frequency", "1e6"],
            &["gait.sweepStartFrequency", "is outside"],
        ),
        (
            "bode",
            &["--stages", "1", "--dwell", "0.001"],
            &["fit window", "lengthen --dwell"],
        ),
        ("map", &["--regen-fraction", "1.5"], &["--regen-fraction"]),
        ("map", &["--speeds", "3,-5"], &["--speeds"]),
        ("map", &["--torques", "1,nan"], &["--torques"]),
        ("map", &["--settle", "0"], &["--settle"]),
        ("triangle", &["--max-cycles", "0"], &["--max-cycles"]),
        ("triangle", &["--increment", "0"], &["--increment"]),
        ("triangle", &["--period=-3"], &["--period"]),
        (
            "triangle",
            &["--gains", "1,2"],
            &["--gains takes three values"],
        ),
        ("calibration", &["--hold", "0"], &["--hold"]),
        ("calibration", &["--angles", "1,nan,3"], &["--angles"]),
        ("step", &["--current", "0"], &["--current"]),
        ("step", &["--duration", "nan"], &["--duration"]),
        ("step", &["--step-angle", "0"], &["--step-angle"]),
        // Found by the experiment (the bench's limits): a usage error too.
        ("step", &["--current", "1000"], &["within the driver's"]),
        (
            "step",
            &["--param", "nosuchParameter=1"],
            &[
                "'nosuchParameter' is not a parameter of BenchPlant",
                "actuationInertia",
            ],
        ),
        ("step", &["--param", "noequals"], &["expected NAME=VALUE"]),
        ("nosuch", &[], &["unrecognized subcommand 'nosuch'"]),
        // Each experiment has its own options: another one's is refused, not ignored.
        (
            "step",
            &["--dwell", "5"],
            &["unexpected argument '--dwell'"],
        ),
        (
            "map",
            &["--gains", "1,2,3"],
            &["unexpected argument '--gains'"],
        ),
        (
            "bode",
            &["--speeds", "3"],
            &["unexpected argument '--speeds'"],
        ),
    ] {
        assert_usage(
            &format!("{name} {args:?}"),
            &mut experiment(name, &plant, &dir.path().join("out"), args),
            needles,
        );
    }
    assert!(!dir.path().join("out").exists());
}

/// `kneebench experiment NAME --fmu PLANT --out OUT ARGS`.
fn experiment(name: &str, plant: &Path, out: &Path, args: &[&str]) -> Command {
    let mut command = kneebench();
    command
        .args(["experiment", name, "--fmu"])
        .arg(plant)
        .arg("--out")
        .arg(out)
        .args(args);
    command
}

/// `experiment bode --stages` is bounded (its rows are kept in memory: the process grew until
/// the machine ran out), and so is the length of any schedule (dwell x stages here, cycles x
/// period for the triangle): refused as usage errors before anything runs.
#[test]
fn experiment_runs_are_bounded() {
    let dir = tempfile::tempdir().unwrap();
    let plant = fmus().join("BenchPlant.fmu");
    for (name, args, needles) in [
        (
            "bode",
            &["--stages", "101"][..],
            &["--stages", "1..=100"][..],
        ),
        ("bode", &["--stages", "4294967295"], &["--stages"]),
        (
            "bode",
            &["--stages", "100", "--dwell", "1000"],
            &["100 stages of 1000 s", "more than the 2000000 rows"],
        ),
        (
            "triangle",
            &["--max-cycles", "4000000000", "--period", "3"],
            &["4000000000 cycles of 3 s", "more than the 2000000 rows"],
        ),
    ] {
        let started = std::time::Instant::now();
        assert_usage(
            &format!("{name} {args:?}"),
            &mut experiment(name, &plant, &dir.path().join("out"), args),
            needles,
        );
        assert!(started.elapsed().as_secs() < 30, "{name} {args:?}");
    }
}

#[test]
fn tune_study_and_plot_refuse_bad_values_while_parsing() {
    for (args, option) in [
        (&["tune", "--ku", "0", "--tu", "1"][..], "--ku"),
        (&["tune", "--ku", "nan", "--tu", "1"], "--ku"),
        (&["tune", "--ku", "1", "--tu", "inf"], "--tu"),
        (
            &[
                "tune",
                "--step-response",
                "x.csv",
                "--signal",
                "y",
                "--input-step",
                "0",
            ],
            "--input-step",
        ),
        (&["study", "--cycles", "0"], "--cycles"),
        (&["study", "--scale", "0"], "--scale"),
        (&["study", "--scale", "nan"], "--scale"),
        (&["plot", "x.csv", "--height", "0"], "--height"),
    ] {
        assert_usage(&format!("{args:?}"), kneebench().args(args), &[option]);
    }
}

/// `sweep --workers` and `optimize --workers` are bounded (1 to `MAX_WORKERS`, 1024): a huge
/// count tried to start that many threads, each loading the system. Above it is a usage error
/// while the command line is parsed, before the spec is read or anything written (the spec
/// here is a valid one-point sweep that ran with any count).
#[test]
fn sweep_and_optimize_refuse_more_workers_than_the_bound() {
    let dir = tempfile::tempdir().unwrap();
    let spec = dir.path().join("spec.toml");
    std::fs::write(
        &spec,
        format!(
            "system = \"SEA\"\nfmus = \"{}\"\ncycles = 2\n\n[design]\nkind = \"grid\"\n\n\
             [[parameters]]\nname = \"plant.springStiffness\"\nvalues = [340.54]\n",
            fmus().display()
        ),
    )
    .unwrap();
    let output = dir.path().join("sweep.csv");
    for command in ["sweep", "optimize"] {
        for workers in ["1025", "100000000", "99999999999999999999999", "0"] {
            assert_usage(
                &format!("{command} --workers {workers}"),
                kneebench()
                    .args([command, "--workers", workers, "--output"])
                    .arg(&output)
                    .arg(&spec),
                &["--workers", "1 to 1024"],
            );
            assert!(!output.exists(), "{command} --workers {workers}");
        }
    }
    // The bound itself runs.
    let out = kneebench()
        .args(["sweep", "--workers", "1024", "--output"])
        .arg(&output)
        .arg(&spec)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// `study --param` names and values are checked against the scenario's FMUs before anything
/// runs or is written: a value the FMU refuses (outside its [min, max], not finite, no item of
/// its enumeration), a name that is no parameter, a component a run lacks. Each refusal is a
/// usage error naming the parameter and its bounds (or the valid names); an out-of-range
/// value was passed on, failed every run at t = 0, and was reported as an interlock trip
/// (exit code 3).
#[test]
fn study_checks_param_names_and_values_against_the_fmus_before_running() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("study");
    for (param, needles) in [
        (
            "plant.actuationInertia=-1",
            &[
                "--param 'plant.actuationInertia'",
                "-1 is outside [0.001, 100]",
            ][..],
        ),
        (
            "plant.actuationInertia=1e400",
            &["'plant.actuationInertia'", "not a finite number"],
        ),
        (
            "torque.outputMin=nan",
            &["'torque.outputMin'", "not a finite"],
        ),
        ("plant.configuration=7", &["7 is outside [0, 2]"]),
        (
            "plant.frictionModel=Nope",
            &["'Nope' is no item of FrictionModel", "HdLossSurface"],
        ),
        (
            "plant.nope=1",
            &[
                "'nope' is not a parameter of BenchPlant",
                "actuationInertia",
            ],
        ),
        (
            "impedance.virtualStiffness=100",
            &["the DA run of bench-full has no component 'impedance'"],
        ),
        ("nodot=1", &["'nodot': not component.name"]),
    ] {
        assert_usage(
            param,
            kneebench()
                .args(["study", "--cycles", "2", "--param", param, "--fmus"])
                .arg(fmus())
                .arg("--out")
                .arg(&out),
            needles,
        );
        assert!(!out.exists(), "{param}: wrote {}", out.display());
    }
    // One cycle is the start-up alone, never analysed: refused before anything runs (it was
    // analysed silently).
    assert_usage(
        "--cycles 1",
        kneebench()
            .args(["study", "--cycles", "1", "--fmus"])
            .arg(fmus())
            .arg("--out")
            .arg(&out),
        &["--cycles: cycles must be at least 2 (given: 1): the first gait cycle, the start-up"],
    );
    assert!(!out.exists(), "--cycles 1: wrote {}", out.display());
}

/// A parameter set's values the FMU would refuse (outside the declared `[min, max]`, none of
/// a mode's items, NaN) are usage errors of every command that takes `--params` (exit code 2,
/// naming the option, the file, the line and the bounds), before anything runs or is
/// written: each exited with 1.
#[test]
fn parameter_sets_the_fmu_would_refuse_are_usage_errors() {
    let dir = tempfile::tempdir().unwrap();
    let plant = fmus().join("BenchPlant.fmu");
    let fmus_dir = fmus().to_str().unwrap();
    let set = |name: &str, element: &str| {
        let path = dir.path().join(format!("{name}.ssv"));
        std::fs::write(
            &path,
            format!(
                r#"<?xml version="1.0" encoding="UTF-8"?>
<ssv:ParameterSet xmlns:ssv="http://ssp-standard.org/SSP1/SystemStructureParameterValues" version="1.0" name="{name}">
  <ssv:Parameters>
    <ssv:Parameter name="actuationDamping"><ssv:Real value="10"/></ssv:Parameter>
    {element}
  </ssv:Parameters>
</ssv:ParameterSet>
"#
            ),
        )
        .unwrap();
        path
    };
    let cases = [
        (
            set(
                "range",
                r#"<ssv:Parameter name="actuationInertia"><ssv:Real value="-1"/></ssv:Parameter>"#,
            ),
            "parameter 'actuationInertia': -1 is outside [0.001, 100]",
        ),
        (
            set(
                "item",
                r#"<ssv:Parameter name="frictionModel"><ssv:Integer value="9"/></ssv:Parameter>"#,
            ),
            "parameter 'frictionModel': 9 is outside [0, 3]",
        ),
        (
            set(
                "nan",
                r#"<ssv:Parameter name="actuationInertia"><ssv:Real value="NaN"/></ssv:Parameter>"#,
            ),
            "parameter 'actuationInertia': NaN is not finite",
        ),
        (
            set(
                "fraction",
                r#"<ssv:Parameter name="encoderCountsPerRevolution"><ssv:Real value="1000.5"/></ssv:Parameter>"#,
            ),
            "parameter 'encoderCountsPerRevolution': 1000.5 is not an integer",
        ),
    ];
    let out = dir.path().join("out");
    let out_csv = dir.path().join("out.csv");
    for (path, problem) in &cases {
        let file = path.to_str().unwrap();
        let name = path.file_name().unwrap().to_str().unwrap();
        let needle = format!("--params {file}:5: {problem}");
        for args in [
            &[
                "run",
                plant.to_str().unwrap(),
                "--stop-time",
                "0.01",
                "--output",
                out_csv.to_str().unwrap(),
            ][..],
            &[
                "study",
                "--fmus",
                fmus_dir,
                "--cycles",
                "2",
                "--actuators",
                "sea",
                "--scenario",
                "bench-full",
                "--out",
                out.to_str().unwrap(),
            ],
            &[
                "experiment",
                "step",
                "--fmu",
                plant.to_str().unwrap(),
                "--duration",
                "1",
                "--out",
                out.to_str().unwrap(),
            ],
            &[
                "identify",
                "missing-log.csv",
                "--fmu",
                plant.to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
            ],
        ] {
            assert_usage(
                &format!("{name} {args:?}"),
                kneebench().args(args).args(["--params", file]),
                &[&needle],
            );
            assert!(!out.exists() && !out_csv.exists(), "{name} {args:?}");
        }
    }
    // `run SYSTEM --params COMPONENT=SET.ssv` naming a component the system does not have
    // (it was a run error, exit code 1), and the set's values refused for a component it has.
    let system = plant_system(dir.path());
    let good = set("good", "");
    for (spec, needle) in [
        (
            format!("nope={}", good.display()),
            format!(
                "--params nope={}: {} has no component 'nope' (its components: plant)",
                good.display(),
                system.display()
            ),
        ),
        (
            format!("plant={}", cases[0].0.display()),
            format!("--params {}:5: {}", cases[0].0.display(), cases[0].1),
        ),
    ] {
        assert_usage(
            &spec,
            kneebench()
                .arg("run")
                .arg(&system)
                .args(["--stop-time", "0.01", "--output"])
                .arg(&out_csv)
                .args(["--params", &spec]),
            &[&needle],
        );
        assert!(!out_csv.exists(), "{spec}");
    }
}

/// A fraction for a Real that takes whole numbers only (its description ends with "; an
/// integer": the plant's `encoderCountsPerRevolution`) is a usage error of `run`, `study` and
/// `emulate --param`, naming the option and the parameter, before anything runs or is
/// written: the check of bounds let it through, and the FMU refused it in `fmi2SetReal` as
/// the run started (exit code 1).
#[test]
fn a_fraction_for_an_integer_valued_parameter_is_a_usage_error() {
    let dir = tempfile::tempdir().unwrap();
    let plant = fmus().join("BenchPlant.fmu");
    let out = dir.path().join("out");
    let key = dir.path().join("new.key");
    assert_usage(
        "run",
        kneebench()
            .arg("run")
            .arg(&plant)
            .args(["--stop-time", "0.01", "--param"])
            .arg("encoderCountsPerRevolution=1000.5")
            .arg("--output")
            .arg(dir.path().join("r.csv")),
        &[
            "--param 'encoderCountsPerRevolution=1000.5'",
            "1000.5 is not an integer",
        ],
    );
    assert!(std::fs::read_dir(dir.path()).unwrap().next().is_none());
    let system = plant_system(dir.path());
    assert_usage(
        "run (system)",
        kneebench()
            .arg("run")
            .arg(&system)
            .args(["--stop-time", "0.01", "--param"])
            .arg("plant.encoderCountsPerRevolution=1000.5")
            .arg("--output")
            .arg(dir.path().join("r.csv")),
        &[
            "--param 'plant.encoderCountsPerRevolution=1000.5'",
            "1000.5 is not an integer",
        ],
    );
    assert!(!dir.path().join("r.csv").exists());
    assert!(!dir.path().join("r.csv.partial").exists());
    assert_usage(
        "study",
        kneebench()
            .args(["study", "--cycles", "2", "--actuators", "sea", "--fmus"])
            .arg(fmus())
            .args([
                "--param",
                "plant.encoderCountsPerRevolution=1000.5",
                "--out",
            ])
            .arg(&out),
        &[
            "--param 'plant.encoderCountsPerRevolution'",
            "1000.5 is not an integer",
        ],
    );
    assert!(!out.exists());
    assert_usage(
        "emulate",
        emulate_command("127.0.0.1:0", "5", &plant)
            .arg("--new-key")
            .arg(&key)
            .args(["--param", "encoderCountsPerRevolution=1000.5"]),
        &["--param encoderCountsPerRevolution = '1000.5': 1000.5 is not an integer"],
    );
    assert!(!key.exists());
}

/// `study --bench-param` values that `BenchHardware` would refuse (outside its `[min, max]`,
/// NaN, none of a mode's items, no parameter of it) are usage errors before anything runs or
/// is written: they failed the run (exit code 1) after the scenario and its results were
/// written.
#[test]
fn bench_params_the_fmu_would_refuse_are_usage_errors() {
    let dir = tempfile::tempdir().unwrap();
    let fmus_dir = fmus().to_str().unwrap();
    let out = dir.path().join("out");
    let key = dir.path().join("bench.key");
    for (param, needles) in [
        (
            "replyTimeout=-1",
            &["--bench-param replyTimeout = '-1': -1 is outside [0.00001, 1]"][..],
        ),
        (
            "replyTimeout=nan",
            &["--bench-param replyTimeout = 'nan': NaN is not a finite number"],
        ),
        (
            "pacing=7",
            &["--bench-param pacing = '7': 7 is outside [0, 2]"],
        ),
        (
            "backend=Serial",
            &[
                "--bench-param backend = 'Serial': 'Serial' is no item of Backend (0 = Simulated, 1 = Udp)",
            ],
        ),
        (
            "nope=1",
            &[
                "--bench-param 'nope' is not a parameter of BenchHardware",
                "replyTimeout",
            ],
        ),
    ] {
        assert_usage(
            param,
            study_on_bench(fmus_dir, &key)
                .args(["--bench-param", param, "--out"])
                .arg(&out),
            needles,
        );
        assert!(!out.exists(), "{param}: wrote {}", out.display());
    }
}

/// Key files the bench link refuses, made in `dir`, each with what its refusal says: one
/// readable by others, one whose key is no secret, and one that does not exist.
fn refused_key_files(dir: &Path) -> [(PathBuf, &'static str); 3] {
    use std::os::unix::fs::PermissionsExt;
    let loose = dir.join("loose.key");
    std::fs::write(&loose, format!("{}\n", "5a".repeat(32))).unwrap();
    std::fs::set_permissions(&loose, std::fs::Permissions::from_mode(0o644)).unwrap();
    let zeros = dir.join("zeros.key");
    std::fs::write(&zeros, format!("{}\n", "0".repeat(64))).unwrap();
    std::fs::set_permissions(&zeros, std::fs::Permissions::from_mode(0o600)).unwrap();
    [
        (loose, "accessible to its group or to others (mode 644)"),
        (zeros, "all its 32 bytes are 0x00: not a random key"),
        (dir.join("missing.key"), "No such file"),
    ]
}

/// `study --bench --key FILE` with a key file the bench link would refuse (readable by others,
/// a key that is no secret, no file at all): a usage error naming the option and why, before
/// anything runs or is written, as `emulate --key` refuses it.
#[test]
fn a_refused_study_key_file_is_a_usage_error() {
    let dir = tempfile::tempdir().unwrap();
    let fmus_dir = fmus().to_str().unwrap();
    let out = dir.path().join("out");
    for (file, needle) in refused_key_files(dir.path()) {
        assert_usage(
            needle,
            study_on_bench(fmus_dir, &file)
                .args(["--scenario", "bench-full"])
                .arg("--out")
                .arg(&out),
            &[&format!("--key key file {}", file.display()), needle],
        );
        assert!(!out.exists(), "{needle}: wrote {}", out.display());
    }
}

/// `emulate --param` names and values are checked against the plant FMU before the emulator
/// starts or anything is written (here a new key file): a value the FMU refuses, a name that
/// is no parameter, an item that is none of the mode's, each a usage error naming the
/// parameter and the bounds or items. The FMU refused them as the emulator prepared its plant
/// (exit code 1), and an item's name was not read at all; it now serves with one.
#[test]
fn emulate_checks_param_names_and_values_before_starting() {
    let dir = tempfile::tempdir().unwrap();
    let plant = fmus().join("BenchPlant.fmu");
    let key = dir.path().join("new.key");
    let emulate = |param: &str, duration: &str| {
        let mut command = emulate_command("127.0.0.1:0", duration, &plant);
        command.arg("--new-key").arg(&key).args(["--param", param]);
        command
    };
    for (param, needles) in [
        (
            "actuationInertia=-1",
            &["--param actuationInertia = '-1': -1 is outside [0.001, 100]"][..],
        ),
        (
            "actuationInertia=nan",
            &["--param actuationInertia = 'nan': NaN is not a finite number"],
        ),
        (
            "configuration=7",
            &["--param configuration = '7': 7 is outside [0, 2]"],
        ),
        (
            "frictionModel=Nope",
            &["'Nope' is no item of FrictionModel", "3 = HdLossSurface"],
        ),
        (
            "nope=1",
            &[
                "--param 'nope' is not a parameter of BenchPlant",
                "actuationInertia",
            ],
        ),
        (
            "configuration",
            &["--param 'configuration': expected NAME=VALUE"],
        ),
    ] {
        assert_usage(param, &mut emulate(param, "5"), needles);
        assert!(!key.exists(), "{param}: wrote {}", key.display());
    }
    // A fault that does not parse is a usage error too, read before the new key is written
    // (it was exit code 1, after the key file).
    for (fault, needle) in [
        ("stuck", "--fault fault `stuck`: missing field 1"),
        ("nope:1", "--fault unknown fault `nope`"),
    ] {
        assert_usage(
            fault,
            emulate_command("127.0.0.1:0", "5", &plant)
                .arg("--new-key")
                .arg(&key)
                .args(["--fault", fault]),
            &[needle],
        );
        assert!(!key.exists(), "{fault}: wrote {}", key.display());
    }
    // A --key file the emulator refuses (readable by others, a key that is no secret, no
    // file at all): a usage error naming the option and why, before anything starts (it was
    // exit 1).
    for (file, needle) in refused_key_files(dir.path()) {
        let o = assert_usage(
            needle,
            emulate_command("127.0.0.1:0", "5", &plant)
                .arg("--key")
                .arg(&file),
            &[&format!("--key key file {}", file.display()), needle],
        );
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!e.contains("serving"), "{e}");
    }
    // Serving off loopback without a key: a usage error naming the remedy (it was exit 1).
    assert_usage(
        "--bind 0.0.0.0:0",
        &mut emulate_command("0.0.0.0:0", "5", &plant),
        &[
            "--bind 0.0.0.0:0: refusing to serve on 0.0.0.0:0 without a key",
            "--key FILE",
        ],
    );
    // A mode by its item's name: the emulator starts with it.
    let o = emulate("frictionModel=HdLossSurface", "0.2")
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(0), "{e}");
    assert!(e.contains("serving the bench protocol"), "{e}");
}

/// Names that are no scenario, actuator, parameter or column, a missing log and an output of
/// an unknown format are usage errors (exit code 2) with their message: each exited with 1.
/// None needs the bench's FMUs (each is refused before they are read) but `--param`.
#[test]
fn unknown_names_and_missing_inputs_are_usage_errors() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("step.csv");
    let mut text = String::from("time,y\n");
    for k in 0..50 {
        let t = k as f64 * 0.01;
        text.push_str(&format!("{t:?},{:?}\n", 1.0 - (-t / 0.1).exp()));
    }
    std::fs::write(&csv, text).unwrap();
    let csv = csv.to_str().unwrap();
    let missing = dir.path().join("missing");
    let missing = missing.to_str().unwrap();
    let plant = fmus().join("BenchPlant.fmu");
    let plant = plant.to_str().unwrap();
    let out = dir.path().join("out");
    let out = out.to_str().unwrap();
    // 13 signals: more than plot draws without --signals.
    let wide = dir.path().join("wide.csv");
    let names: Vec<String> = (0..13).map(|k| format!("s{k}")).collect();
    std::fs::write(
        &wide,
        format!(
            "time,{}
0,{}
",
            names.join(","),
            vec!["1"; 13].join(",")
        ),
    )
    .unwrap();
    let wide = wide.to_str().unwrap();
    let wide_out = format!("{out}.svg");
    for (args, needles) in [
        (
            &["plot", wide, "--out", wide_out.as_str()][..],
            &[
                "has 13 columns, too many for one readable chart",
                "--signals s0,s1,s2",
            ][..],
        ),
        (
            &["study", "--fmus", missing, "--scenario", "nope"],
            &["unknown scenario 'nope' (bench-full, bench-clutch)"],
        ),
        (
            &["study", "--fmus", missing, "--actuators", "foo"],
            &["unknown actuator 'foo' (da, sea, csea)"],
        ),
        // An actuator or a scenario given twice (however spelled): the actuator was run once,
        // the scenario twice, without a word.
        (
            &["study", "--fmus", missing, "--actuators", "SEA,csea,sea"],
            &["--actuators: SEA is given twice"],
        ),
        (
            &[
                "study",
                "--fmus",
                missing,
                "--scenario",
                "bench-full,Bench-Full",
            ],
            &["--scenario: bench-full is given twice"],
        ),
        // The one scenario chosen has none of the actuators (it wrote an empty section).
        (
            &[
                "study",
                "--fmus",
                missing,
                "--scenario",
                "bench-clutch",
                "--actuators",
                "da",
                "--out",
                out,
            ],
            &[
                "the bench-clutch scenario has none of DA (its actuators: SEA, CSEA)",
                "--actuators DA: no chosen scenario has them",
            ],
        ),
        (
            &[
                "study",
                "--fmus",
                fmus().to_str().unwrap(),
                "--param",
                "plant.nope=1",
            ],
            &["'nope' is not a parameter of BenchPlant"],
        ),
        (
            &["identify", "--fmu", plant, "--out", out],
            &["no log given"],
        ),
        (
            &["identify", "--fmu", missing, "--out", out],
            &["no log given"],
        ),
        (
            &[
                "plot",
                csv,
                "--signals",
                "nope",
                "--out",
                &format!("{out}.svg"),
            ],
            &["no column named 'nope'", "available: y"],
        ),
        (
            &["plot", csv, "--out", &format!("{out}.txt")],
            &["--out", "unknown plot format", "use .svg or .png"],
        ),
        // The format is checked before the results file is read.
        (
            &["plot", missing, "--out", &format!("{out}.txt")],
            &["unknown plot format"],
        ),
        (
            &["metrics", csv, "--signal", "nope"],
            &["no column 'nope' in"],
        ),
        (
            &[
                "tune",
                "--step-response",
                csv,
                "--signal",
                "nope",
                "--input-step",
                "1",
            ],
            &["no column 'nope' in"],
        ),
    ] {
        assert_usage(&format!("{args:?}"), kneebench().args(args), needles);
    }
    assert!(!Path::new(out).exists());
}
