//! Parameter sweeps end to end through the exported FMUs: every refusal of a bad spec names
//! its line; the table is bit-identical whatever the number of workers or the order of the
//! points; a tripped or failed run is a row with its status and message; `--resume` skips
//! the journal's points and runs only the others.

use std::path::Path;

use kneebench_harness::sweep::journal::journal_path;
use kneebench_harness::sweep::runner::fingerprint;
use kneebench_harness::sweep::{
    Prepared, RunStatus, SweepError, SweepOptions, SweepSpec, SweepTable, run_sweep,
};

/// The exported FMUs, once per test binary.
fn fmus() -> &'static Path {
    kneebench_tests::exported_fmus().0.path()
}

fn spec(text: &str, dir: &Path) -> Result<SweepSpec, SweepError> {
    let text = text.replace("FMUS", &fmus().display().to_string());
    SweepSpec::parse(&text, Path::new("spec.toml"), dir)
}

fn prepared(text: &str, dir: &Path) -> Result<Prepared, SweepError> {
    spec(text, dir).and_then(Prepared::new)
}

/// The messages of a refused spec, one per problem.
fn refusal(text: &str) -> Vec<String> {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("points.csv"),
        "plant.springStiffness\n300\n-5\nabc\n",
    )
    .unwrap();
    match prepared(text, dir.path()) {
        Err(SweepError::Invalid(p)) => p.iter().map(|p| p.to_string()).collect(),
        Err(e) => panic!("refused with another error: {e}"),
        Ok(_) => panic!("accepted:\n{text}"),
    }
}

const HEAD: &str = "system = \"SEA\"\nfmus = \"FMUS\"\ncycles = 1\n";

#[test]
fn bad_specs_are_refused_naming_the_line() {
    // Unknown variable: checked against the FMUs' model descriptions.
    let m = refusal(&format!(
        "{HEAD}[design]\nkind = \"grid\"\n[[parameters]]\nname = \"plant.springStifness\"\nvalues = [300.0]\n"
    ));
    assert_eq!(
        m,
        [
            "spec.toml, line 6: unknown variable 'plant.springStifness': component 'plant' (BenchPlant) has no variable 'springStifness'"
        ]
    );
    let m = refusal(&format!(
        "{HEAD}[design]\nkind = \"grid\"\n[[parameters]]\nname = \"knee.x\"\nvalues = [1.0]\n"
    ));
    assert_eq!(
        m,
        ["spec.toml, line 6: unknown variable 'knee.x': the system has no component 'knee'"]
    );
    // Outside the variable's [min, max] (springStiffness: [0, 1e5]).
    let m = refusal(&format!(
        "{HEAD}[design]\nkind = \"random\"\npoints = 3\n[[parameters]]\nname = \"plant.springStiffness\"\nmin = -1.0\nmax = 400.0\n"
    ));
    assert_eq!(
        m,
        [
            "spec.toml, line 7: 'plant.springStiffness': -1 is outside the variable's [min, max] = [0, 100000]"
        ]
    );
    // A value outside the spec's own [min, max].
    let m = refusal(&format!(
        "{HEAD}[design]\nkind = \"grid\"\n[[parameters]]\nname = \"plant.springStiffness\"\nmin = 100.0\nmax = 400.0\nvalues = [50.0]\n"
    ));
    assert_eq!(
        m,
        ["spec.toml, line 10: parameter 'plant.springStiffness': value 50 is outside [100, 400]"]
    );
    // min above max.
    let m = refusal(&format!(
        "{HEAD}[design]\nkind = \"sobol\"\npoints = 4\n[[parameters]]\nname = \"plant.springStiffness\"\nmin = 500.0\nmax = 400.0\n"
    ));
    assert_eq!(
        m,
        ["spec.toml, line 7: parameter 'plant.springStiffness': min 500 is greater than max 400"]
    );
    // Empty designs: no parameters, no values, zero points.
    let m = refusal(&format!("{HEAD}[design]\nkind = \"grid\"\n"));
    assert_eq!(
        m,
        ["spec.toml, line 4: empty design: no [[parameters]] to vary"]
    );
    let m = refusal(&format!(
        "{HEAD}[design]\nkind = \"grid\"\n[[parameters]]\nname = \"plant.springStiffness\"\nvalues = []\n"
    ));
    assert_eq!(
        m,
        ["spec.toml, line 8: empty design: parameter 'plant.springStiffness' has no values"]
    );
    let m = refusal(&format!(
        "{HEAD}[design]\nkind = \"latin-hypercube\"\npoints = 0\n[[parameters]]\nname = \"plant.springStiffness\"\nmin = 1.0\nmax = 2.0\n"
    ));
    assert_eq!(m, ["spec.toml, line 6: points must be at least 1, not 0"]);
    // Wrong types: found by the TOML reader, with the line.
    let m = refusal(&format!(
        "{HEAD}[design]\nkind = \"grid\"\n[[parameters]]\nname = \"plant.springStiffness\"\nmin = \"stiff\"\nmax = 2.0\nlevels = 2\n"
    ));
    assert_eq!(m.len(), 1);
    assert!(
        m[0].starts_with("spec.toml, line 8: invalid type: string \"stiff\", expected f64"),
        "{m:?}"
    );
    // A Boolean variable cannot be swept; an Integer one takes whole numbers only.
    let m = refusal(&format!(
        "{HEAD}[design]\nkind = \"grid\"\n[[parameters]]\nname = \"plant.configuration\"\nvalues = [1.5]\n"
    ));
    assert_eq!(
        m,
        [
            "spec.toml, line 6: 'plant.configuration' is an Integer variable; 1.5 is not a whole number"
        ]
    );
    // A mode (an Integer bounded by its items, 0 = DA ... 2 = CSEA) refuses a value that is no
    // item before any run.
    let m = refusal(&format!(
        "{HEAD}[design]\nkind = \"grid\"\n[[parameters]]\nname = \"plant.configuration\"\nvalues = [0.0, 3.0]\n"
    ));
    assert_eq!(
        m,
        [
            "spec.toml, line 6: 'plant.configuration': 3 is outside the variable's [min, max] = [0, 2]"
        ]
    );
    // Not a parameter.
    let m = refusal(&format!(
        "{HEAD}[design]\nkind = \"grid\"\n[[parameters]]\nname = \"plant.loadAngle\"\nvalues = [1.0]\n"
    ));
    assert_eq!(
        m,
        [
            "spec.toml, line 6: 'plant.loadAngle' is an output variable; only parameters and inputs can be set"
        ]
    );
    // Unknown design kind, unknown statistic, unknown signal.
    let m = refusal(&format!(
        "{HEAD}[design]\nkind = \"halton\"\n[[parameters]]\nname = \"plant.springStiffness\"\nvalues = [1.0]\n"
    ));
    assert_eq!(
        m,
        [
            "spec.toml, line 5: unknown design kind 'halton' (grid, latin-hypercube, sobol, random, csv)"
        ]
    );
    let m = refusal(&format!(
        "{HEAD}[design]\nkind = \"grid\"\n[[parameters]]\nname = \"plant.springStiffness\"\nvalues = [300.0]\n[[metrics.signals]]\nsignal = \"plant.nothing\"\nstats = [\"max\"]\n"
    ));
    assert_eq!(m.len(), 1);
    assert!(
        m[0].starts_with("spec.toml, line 9: signal 'plant.nothing': "),
        "{m:?}"
    );
    // Sobol: at most 2^16 points (the sequence's length in sobol_burley), refused at `points`.
    let m = refusal(&format!(
        "{HEAD}[design]\nkind = \"sobol\"\npoints = 65537\n[[parameters]]\nname = \"plant.springStiffness\"\nmin = 1.0\nmax = 2.0\n"
    ));
    assert_eq!(m.len(), 1, "{m:?}");
    assert!(
        m[0].starts_with(
            "spec.toml, line 6: the Sobol design has at most 65536 points (2^16, the sequence's length in sobol_burley), not 65537"
        ),
        "{m:?}"
    );
    // The CSV design without a range in the spec: its points are checked against the
    // variable's declared [min, max] ([0, 1e5]), by CSV line.
    let m = refusal(&format!(
        "{HEAD}[design]\nkind = \"csv\"\nfile = \"points.csv\"\n[[parameters]]\nname = \"plant.springStiffness\"\n"
    ));
    assert_eq!(m.len(), 2, "{m:?}");
    assert!(
        m[0].ends_with(
            "points.csv, line 3: plant.springStiffness = -5 is outside the variable's [min, max] = [0, 100000]"
        ),
        "{m:?}"
    );
    // The CSV design: a value outside the variable's range and a non-number, by CSV line.
    let m = refusal(&format!(
        "{HEAD}[design]\nkind = \"csv\"\nfile = \"points.csv\"\n[[parameters]]\nname = \"plant.springStiffness\"\nmin = 0.0\nmax = 1000.0\n"
    ));
    assert_eq!(m.len(), 3, "{m:?}");
    assert!(
        m[0].ends_with("points.csv, line 3: plant.springStiffness = -5 is outside [0, 1000]"),
        "{m:?}"
    );
    assert!(
        m[1].ends_with(
            "points.csv, line 3: plant.springStiffness = -5 is outside the variable's [min, max] = [0, 100000]"
        ),
        "{m:?}"
    );
    assert!(
        m[2].ends_with(
            "points.csv, line 4: 'abc' for plant.springStiffness is not a finite number"
        ),
        "{m:?}"
    );
}

#[test]
fn the_fingerprint_covers_spec_points_and_the_fmus_guids() {
    let dir = tempfile::tempdir().unwrap();
    let p = prepared(DETERMINISM, dir.path()).unwrap();
    assert_eq!(p.guids.len(), 4, "{:?}", p.guids);
    assert_eq!(
        p.fingerprint,
        fingerprint(&p.spec.text, &p.design, &p.guids),
        "the sweep's fingerprint is the documented function of its inputs"
    );
    // Another GUID of one FMU (a rebuilt plant, say) is another sweep.
    let mut guids = p.guids.clone();
    guids[1].1.push('x');
    assert_ne!(fingerprint(&p.spec.text, &p.design, &guids), p.fingerprint);
    let mut design = p.design.clone();
    design.points[5][0] = f64::from_bits(design.points[5][0].to_bits() + 1);
    assert_ne!(fingerprint(&p.spec.text, &design, &p.guids), p.fingerprint);
    assert_ne!(
        fingerprint(&format!("{} ", p.spec.text), &p.design, &p.guids),
        p.fingerprint
    );
    // The units of the columns: the variables' and the signals'.
    let units = p.column_units();
    assert_eq!(&units[..2], ["N.m/rad", ""], "{units:?}");
    let k = 2 + p
        .metric_names
        .iter()
        .position(|n| n == "rms_error_knee")
        .unwrap();
    assert_eq!(units[k], "rad");
    let k = 2 + p
        .metric_names
        .iter()
        .position(|n| n == "rms(plant.loadOutputTorque)")
        .unwrap();
    assert_eq!(units[k], "N.m");
    // The files a worker without a shared file system needs: the spec and the three FMUs
    // (both loops are PidController instances).
    assert_eq!(p.input_files.len(), 4, "{:?}", p.input_files);
    assert!(p.input_files[1..].iter().all(|f| f.is_file()));
}

const DETERMINISM: &str = "system = \"SEA\"\nfmus = \"FMUS\"\ncycles = 2\n\
[design]\nkind = \"latin-hypercube\"\npoints = 6\nseed = 11\n\
[[parameters]]\nname = \"plant.springStiffness\"\nmin = 250.0\nmax = 450.0\n\
[[parameters]]\nname = \"plant.harmonicDriveRatio\"\nmin = 140.0\nmax = 180.0\n\
[[metrics.signals]]\nsignal = \"plant.loadOutputTorque\"\nstats = [\"min\", \"max\", \"mean\", \"rms\"]\nfrom = 2.5\n";

fn options(workers: usize) -> SweepOptions {
    SweepOptions {
        workers,
        progress: false,
        resume: false,
    }
}

#[test]
fn tables_are_bit_identical_whatever_the_workers_and_the_order() {
    let dir = tempfile::tempdir().unwrap();
    let p = prepared(DETERMINISM, dir.path()).unwrap();
    let one = run_sweep(&p, None, &options(1)).unwrap();
    let two = run_sweep(&p, None, &options(2)).unwrap();
    let four = run_sweep(&p, None, &options(4)).unwrap();
    assert_eq!(one.rows.len(), 6);
    assert!(
        one.rows.iter().all(|r| r.status == RunStatus::Ok),
        "{one:?}"
    );
    // Metrics that vary with the point (the test would be vacuous otherwise).
    let knee: Vec<f64> = one.rows.iter().map(|r| r.metrics[3]).collect();
    assert!(knee.windows(2).any(|w| w[0] != w[1]), "{knee:?}");
    assert!(one.bit_identical(&two));
    assert!(one.bit_identical(&four));
    // The points in reverse order, two workers: the same rows once sorted.
    let mut rows = Vec::new();
    let ids: Vec<u64> = (0..6).rev().collect();
    p.run_points(&ids, 2, &mut |r| {
        rows.push(r);
        Ok(())
    })
    .unwrap();
    rows.sort_by_key(|r| r.point);
    let reversed = SweepTable {
        rows,
        ..p.empty_table()
    };
    assert!(one.bit_identical(&reversed));
}

#[test]
fn a_tripped_and_a_failed_run_are_rows_with_status_and_message() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("points.csv"),
        "plant.loadRegenPowerLimit,position.outputMin\n5,-15\n0.5,-15\n5,20\n",
    )
    .unwrap();
    let p = prepared(
        &format!(
            "{HEAD}[design]\nkind = \"csv\"\nfile = \"points.csv\"\n\
             [[parameters]]\nname = \"plant.loadRegenPowerLimit\"\n\
             [[parameters]]\nname = \"position.outputMin\"\n"
        ),
        dir.path(),
    )
    .unwrap();
    let t = run_sweep(&p, None, &options(2)).unwrap();
    let status: Vec<RunStatus> = t.rows.iter().map(|r| r.status).collect();
    assert_eq!(
        status,
        [RunStatus::Ok, RunStatus::Tripped, RunStatus::Failed],
        "{t:?}"
    );
    assert_eq!(t.rows[0].message, "");
    assert!(
        t.rows[1]
            .message
            .starts_with("plant: load driver regenerated power above limit at t = "),
        "{}",
        t.rows[1].message
    );
    let trip_time = t
        .metric_names
        .iter()
        .position(|n| n == "trip_time")
        .unwrap();
    assert!(t.rows[1].metrics[trip_time] > 0.0 && t.rows[1].metrics[trip_time] < 2.5);
    assert!(
        t.rows[2]
            .message
            .contains("outputMin 20 is above outputMax 15"),
        "{}",
        t.rows[2].message
    );
}

#[test]
fn resume_runs_only_the_points_the_journal_lacks() {
    let dir = tempfile::tempdir().unwrap();
    let p = prepared(DETERMINISM, dir.path()).unwrap();
    let out = dir.path().join("table.parquet");
    let full = run_sweep(&p, Some(&out), &options(2)).unwrap();
    assert!(out.is_file());
    assert!(
        !journal_path(&out).exists(),
        "the journal is removed at the end"
    );
    // An interrupted sweep: three rows journaled (marked, so that a rerun would show), the
    // fourth torn mid-line by a kill.
    let mut journal = p.journal_header();
    let mut marked = full.clone();
    for r in &mut marked.rows[..3] {
        r.message = "from the journal".into();
        journal.push_str(&kneebench_harness::sweep::journal::journal_line(r));
    }
    let torn = kneebench_harness::sweep::journal::journal_line(&full.rows[3]);
    journal.push_str(&torn[..torn.len() / 2]);
    std::fs::write(journal_path(&out), &journal).unwrap();
    // Without --resume the journal is not overwritten.
    let e = run_sweep(&p, Some(&out), &options(2)).unwrap_err();
    assert!(e.to_string().contains("pass --resume"), "{e}");
    let resumed = run_sweep(
        &p,
        Some(&out),
        &SweepOptions {
            resume: true,
            ..options(2)
        },
    )
    .unwrap();
    assert!(resumed.bit_identical(&marked), "only points 3.. ran again");
    // --resume of the finished table (no journal): every point is in it, nothing runs, and
    // the table is written again as it was (its marks kept).
    assert!(!journal_path(&out).exists());
    let again = run_sweep(
        &p,
        Some(&out),
        &SweepOptions {
            resume: true,
            ..options(1)
        },
    )
    .unwrap();
    assert!(again.bit_identical(&marked));
    // A second row for a point: ignored when it equals the first, refused otherwise.
    let mut sweep = kneebench_harness::sweep::JournaledSweep::start(&p, None, &options(1)).unwrap();
    sweep.record(full.rows[0].clone()).unwrap();
    sweep.record(full.rows[0].clone()).unwrap();
    let mut other = full.rows[0].clone();
    other.message = "another run".into();
    let e = sweep.record(other).unwrap_err();
    assert_eq!(
        e.to_string(),
        "point 0: a second row that differs from the first"
    );
    // A journal of another sweep is refused.
    std::fs::write(
        journal_path(&out),
        "kneebench-sweep-journal 1 0123\n0\tok\t\t\n",
    )
    .unwrap();
    let e = run_sweep(
        &p,
        Some(&out),
        &SweepOptions {
            resume: true,
            ..options(1)
        },
    )
    .unwrap_err();
    assert!(e.to_string().contains("belongs to another sweep"), "{e}");
}

/// Two sweeps into one output at once (two Python `sweep(..., resume=True)` calls, or a CLI
/// sweep and a Python one): the second is refused while the first holds the journal's lock,
/// instead of taking the journal's rows as done and running every other point again beside
/// the first. Once the first is gone (dropped, as a killed process's lock goes with it) the
/// output can be resumed: only the missing points run.
#[test]
fn a_second_sweep_into_the_same_output_is_refused_while_the_first_runs() {
    let dir = tempfile::tempdir().unwrap();
    let p = prepared(DETERMINISM, dir.path()).unwrap();
    let out = dir.path().join("table.parquet");
    let resume = SweepOptions {
        resume: true,
        ..options(1)
    };
    let mut first = kneebench_harness::sweep::JournaledSweep::start(&p, Some(&out), &resume)
        .unwrap_or_else(|e| panic!("{e}"));
    let mut rows = Vec::new();
    p.run_points(&[0], 1, &mut |row| {
        rows.push(row);
        Ok(())
    })
    .unwrap();
    let mut row = rows.pop().unwrap();
    row.message = "from the first sweep".into();
    first.record(row).unwrap();
    for options in [&resume, &options(1)] {
        let e = match kneebench_harness::sweep::JournaledSweep::start(&p, Some(&out), options) {
            Err(e) => e,
            Ok(_) => panic!("a second sweep into the output was started"),
        };
        assert!(matches!(e, SweepError::Busy { .. }), "{e}");
        assert!(
            e.to_string()
                .contains("another sweep is running into this output"),
            "{e}"
        );
    }
    // The refusals left the first's journal alone.
    let journal = std::fs::read_to_string(journal_path(&out)).unwrap();
    assert_eq!(journal.lines().count(), 2, "{journal}");
    drop(first);
    let table = run_sweep(&p, Some(&out), &resume).unwrap();
    assert_eq!(table.rows.len(), 6);
    assert_eq!(table.rows[0].message, "from the first sweep");
    assert!(table.rows[1..].iter().all(|r| r.message.is_empty()));
    assert!(!journal_path(&out).exists());
}

/// A sweep that ended before its first row (an error, a kill) leaves a journal of its header
/// alone: it holds nothing to resume, so the next run, with or without --resume, starts
/// afresh instead of being refused ("an unfinished sweep's journal exists").
#[test]
fn a_journal_without_a_row_does_not_block_the_next_run() {
    let dir = tempfile::tempdir().unwrap();
    let p = prepared(DETERMINISM, dir.path()).unwrap();
    let out = dir.path().join("table.parquet");
    let started =
        kneebench_harness::sweep::JournaledSweep::start(&p, Some(&out), &options(1)).unwrap();
    drop(started);
    let journal = std::fs::read_to_string(journal_path(&out)).unwrap();
    assert_eq!(journal, p.journal_header());
    // A torn first row is no row either.
    std::fs::write(journal_path(&out), format!("{journal}0\tok")).unwrap();
    let mut again = kneebench_harness::sweep::JournaledSweep::start(&p, Some(&out), &options(1))
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(again.pending().len(), 6);
    let mut rows = Vec::new();
    p.run_points(&[0], 1, &mut |row| {
        rows.push(row);
        Ok(())
    })
    .unwrap();
    again.record(rows.pop().unwrap()).unwrap();
    drop(again);
    // A journal with a row is still refused without --resume.
    match kneebench_harness::sweep::JournaledSweep::start(&p, Some(&out), &options(1)) {
        Err(e) => assert!(e.to_string().contains("pass --resume"), "{e}"),
        Ok(_) => panic!("a journal with a row was overwritten"),
    }
}
