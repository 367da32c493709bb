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

const HEAD: &str = "system = \"SEA\"\nfmus = \"FMUS\"\ncycles = 2\n";

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
    // A value that is no finite number (it read "NaN is outside [-inf, inf]").
    for x in ["nan", "inf", "-inf"] {
        let m = refusal(&format!(
            "{HEAD}[design]\nkind = \"grid\"\n[[parameters]]\nname = \"plant.springStiffness\"\nvalues = [300.0, {x}]\n"
        ));
        assert_eq!(
            m,
            [format!(
                "spec.toml, line 8: parameter 'plant.springStiffness': value {} is not a finite number",
                x.replace("nan", "NaN")
            )]
        );
    }
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
    let digests: Vec<String> = p.file_digests.iter().map(|(_, d)| d.clone()).collect();
    assert_eq!(
        p.fingerprint,
        fingerprint(&p.spec.text, &p.design, &p.guids, &digests),
        "the sweep's fingerprint is the documented function of its inputs"
    );
    // Another GUID of one FMU (a rebuilt plant, say) is another sweep.
    let mut guids = p.guids.clone();
    guids[1].1.push('x');
    assert_ne!(
        fingerprint(&p.spec.text, &p.design, &guids, &digests),
        p.fingerprint
    );
    let mut design = p.design.clone();
    design.points[5][0] = f64::from_bits(design.points[5][0].to_bits() + 1);
    assert_ne!(
        fingerprint(&p.spec.text, &design, &p.guids, &digests),
        p.fingerprint
    );
    assert_ne!(
        fingerprint(&format!("{} ", p.spec.text), &p.design, &p.guids, &digests),
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

/// A scenario sweeping the gait's period runs `cycles` of each point's own period and analyses
/// every cycle but the first, the start-up: runs were `cycles x 2.5 s` whatever the point's
/// period, so that a 4 or 6 s period analysed the start-up cycle alone (or read as `tripped`,
/// "ended before one cycle", with no interlock tripped). A run that
/// ends before its second cycle (a system file's stop time here) is `failed`, its message
/// saying why: `tripped` is for an interlock.
#[test]
fn a_swept_gait_period_sets_the_runs_and_the_start_up_is_never_analysed() {
    use kneebench_harness::study::{Actuator, StudyScenario, gait_scenario, write_ssp};
    let dir = tempfile::tempdir().unwrap();
    let p = prepared(
        "system = \"SEA\"\nfmus = \"FMUS\"\ncycles = 3\n[design]\nkind = \"grid\"\n\
         [[parameters]]\nname = \"gait.gaitPeriod\"\nvalues = [2.0, 4.0, 6.0]\n",
        dir.path(),
    )
    .unwrap();
    let cycles = p.metric_names.iter().position(|n| n == "cycles").unwrap();
    let t = run_sweep(&p, None, &options(2)).unwrap();
    for r in &t.rows {
        assert_eq!(r.status, RunStatus::Ok, "{r:?}");
        assert_eq!(r.metrics[cycles], 2.0, "{r:?}");
    }
    // A system file of the scenario (2 x 2.5 s) stopped at 3 s: one cycle, the start-up.
    let bench = StudyScenario::BenchFull;
    let scenario = gait_scenario(Actuator::Sea, bench.gait(), bench.gains(Actuator::Sea), 2);
    let ssp = dir.path().join("SEA.ssp");
    write_ssp(&scenario, fmus(), &ssp).unwrap();
    let text = format!(
        "system = \"{}\"\nstop_time = 3.0\n[design]\nkind = \"grid\"\n[[parameters]]\n\
         name = \"plant.springStiffness\"\nvalues = [300.0]\n[metrics]\nstudy = true\n",
        ssp.display()
    );
    let t = run_sweep(&prepared(&text, dir.path()).unwrap(), None, &options(1)).unwrap();
    let r = &t.rows[0];
    assert_eq!(r.status, RunStatus::Failed, "{r:?}");
    assert_eq!(
        r.message,
        "no gait cycle to analyse: the run ended at 3 s, before the end of its second gait cycle \
         at 5 s (period 2.5 s; the first cycle, the start-up, is not analysed)"
    );
    assert!(r.metrics[cycles].is_nan(), "{r:?}");
    // A csv design's periods are only known once it is read: its longest run is within the
    // bound on a run's values, or the spec is refused at the line of cycles.
    std::fs::write(dir.path().join("points.csv"), "gait.gaitPeriod\n2.5\n300\n").unwrap();
    let csv = |c: u32| {
        format!(
            "system = \"SEA\"\nfmus = \"FMUS\"\ncycles = {c}\n[design]\nkind = \"csv\"\n\
             file = \"points.csv\"\n[[parameters]]\nname = \"gait.gaitPeriod\"\n"
        )
    };
    prepared(&csv(2), dir.path()).unwrap();
    match prepared(&csv(3), dir.path()) {
        Err(SweepError::Invalid(p)) => {
            assert_eq!(p.len(), 1, "{p:?}");
            assert_eq!(p[0].line, 3);
            assert!(
                p[0].message
                    .starts_with("each run would record 900001 rows"),
                "{}",
                p[0].message
            );
        }
        other => panic!("{other:?}"),
    }
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

/// The study's SEA scenario of `cycles` gait cycles as an `.ssp` at `path`, `edit` applied to
/// it first.
fn sea_ssp(path: &Path, cycles: u32, edit: impl FnOnce(&mut kneebench_harness::study::Scenario)) {
    use kneebench_harness::study::{Actuator, StudyScenario, gait_scenario, write_ssp};
    let bench = StudyScenario::BenchFull;
    let mut s = gait_scenario(
        Actuator::Sea,
        bench.gait(),
        bench.gains(Actuator::Sea),
        cycles,
    );
    edit(&mut s);
    write_ssp(&s, fmus(), path).unwrap();
}

/// A spec of the SEA system file `SEA.ssp` beside it, one signal metric of `window`.
fn ssp_spec(window: &str) -> String {
    format!(
        "system = \"SEA.ssp\"\n[design]\nkind = \"grid\"\n[[parameters]]\n\
         name = \"plant.springStiffness\"\nvalues = [300.0, 400.0]\n[metrics]\nstudy = false\n\
         [[metrics.signals]]\nsignal = \"plant.springDeflection\"\nstats = [\"max\"]\n{window}"
    )
}

/// The fingerprint covers the bytes of the system file (and of a scenario's FMUs, which a
/// rebuild changes while keeping their GUIDs) and the version: an SSP whose bindings were
/// edited (the torque loop's kp) is another sweep, so `--resume` refuses its journal instead
/// of keeping the stale rows, and a Dask worker that sees other files at the same path is
/// refused (that case needs a cluster: `python/tests/test_kneebench.py`,
/// `test_rows_of_a_worker_that_sees_other_fmus_are_refused`). Before, the fingerprint hashed
/// only the spec text, points and GUIDs.
#[test]
fn the_fingerprint_covers_the_system_file_and_the_fmus_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let ssp = dir.path().join("SEA.ssp");
    sea_ssp(&ssp, 2, |_| {});
    let text = ssp_spec("");
    let p = prepared(&text, dir.path()).unwrap();
    assert_eq!(p.file_digests.len(), 1, "{:?}", p.file_digests);
    assert_eq!(p.file_digests[0].0, ssp);
    let out = dir.path().join("t.parquet");
    run_sweep(&p, Some(&out), &options(1)).unwrap();
    sea_ssp(&ssp, 2, |s| {
        let torque = s
            .components
            .iter_mut()
            .find(|c| c.name == "torque")
            .unwrap();
        let kp = torque
            .parameters
            .iter_mut()
            .find(|(n, _)| n == "kp")
            .unwrap();
        kp.1 = kneebench_harness::master::Value::Real(0.05);
    });
    let edited = prepared(&text, dir.path()).unwrap();
    assert_ne!(edited.fingerprint, p.fingerprint);
    let e = run_sweep(
        &edited,
        Some(&out),
        &SweepOptions {
            resume: true,
            ..options(1)
        },
    )
    .unwrap_err();
    assert!(e.to_string().contains("belongs to another sweep"), "{e}");
    // A scenario's FMUs are digested, in the order the input files list them.
    let s = prepared(DETERMINISM, dir.path()).unwrap();
    let files: Vec<_> = s.file_digests.iter().map(|(f, _)| f.clone()).collect();
    assert_eq!(files, s.input_files[1..]);
    let mut digests: Vec<String> = s.file_digests.iter().map(|(_, d)| d.clone()).collect();
    assert_eq!(
        fingerprint(&s.spec.text, &s.design, &s.guids, &digests),
        s.fingerprint
    );
    let first = if digests[0].starts_with('0') {
        "1"
    } else {
        "0"
    };
    digests[0].replace_range(0..1, first);
    assert_ne!(
        fingerprint(&s.spec.text, &s.design, &s.guids, &digests),
        s.fingerprint
    );
}

/// A sweep's output that is one of its inputs (however spelled) is refused when the sweep
/// starts, whatever the entry point (the library's start, which the CLI, Python and Dask
/// paths all go through), and the input is left as it was: the system file, the design CSV,
/// the spec, a scenario's FMU. Before, only the CLI checked, and only the spec.
#[test]
fn an_output_that_is_one_of_the_sweeps_inputs_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let ssp = dir.path().join("SEA.ssp");
    sea_ssp(&ssp, 1, |_| {});
    let csv = dir.path().join("points.csv");
    std::fs::write(&csv, "plant.springStiffness\n300\n").unwrap();
    let spec_file = dir.path().join("s.toml");
    std::fs::write(
        &spec_file,
        ssp_spec("")
            .replace("kind = \"grid\"", "kind = \"csv\"\nfile = \"points.csv\"")
            .replace("values = [300.0, 400.0]\n", ""),
    )
    .unwrap();
    let p = SweepSpec::from_file(&spec_file)
        .and_then(Prepared::new)
        .unwrap();
    let before: Vec<Vec<u8>> = [&ssp, &csv, &spec_file]
        .iter()
        .map(|f| std::fs::read(f).unwrap())
        .collect();
    let spelled = dir.path().join(".").join("points.csv");
    for output in [&ssp, &csv, &spec_file, &spelled] {
        match kneebench_harness::sweep::JournaledSweep::start(&p, Some(output), &options(1)) {
            Err(e @ SweepError::OutputIsInput { .. }) => {
                assert!(
                    e.to_string().contains("the results would replace it"),
                    "{e}"
                );
            }
            Err(e) => panic!("{}: another error: {e}", output.display()),
            Ok(_) => panic!("{}: accepted as the output", output.display()),
        }
        assert!(!journal_path(output).exists());
    }
    let after: Vec<Vec<u8>> = [&ssp, &csv, &spec_file]
        .iter()
        .map(|f| std::fs::read(f).unwrap())
        .collect();
    assert_eq!(before, after);
    // A scenario's FMU.
    let s = prepared(DETERMINISM, dir.path()).unwrap();
    let plant = fmus().join("BenchPlant.fmu");
    let e = run_sweep(&s, Some(&plant), &options(1)).unwrap_err();
    assert!(matches!(e, SweepError::OutputIsInput { .. }), "{e}");
    assert!(plant.is_file());
}

/// An input that a connection drives is refused at its line, naming the connection:
/// sweeping it had no effect (every row the same, status ok).
#[test]
fn an_input_driven_by_a_connection_is_refused_at_its_line() {
    // Driven by the position loop's output.
    let m = refusal(&format!(
        "{HEAD}[design]\nkind = \"grid\"\n[[parameters]]\nname = \"plant.testCurrentCommand\"\nvalues = [0.0, 5.0]\n"
    ));
    assert_eq!(m.len(), 1, "{m:?}");
    assert!(
        m[0].starts_with(
            "spec.toml, line 6: 'plant.testCurrentCommand' is an input driven by the connection from position.u:"
        ),
        "{m:?}"
    );
}

/// A metric window that holds no recorded row is refused at its line, where the runs' times
/// are known (a system file's once it is loaded): it gave NaN with status ok.
#[test]
fn a_window_without_a_recorded_row_is_refused_at_its_line() {
    // Windows without a row: before the start, between two samples (1 ms steps).
    let signals = "[[metrics.signals]]\nsignal = \"plant.springDeflection\"\nstats = [\"max\"]\n";
    let head = format!(
        "{HEAD}[design]\nkind = \"grid\"\n[[parameters]]\nname = \"plant.springStiffness\"\nvalues = [300.0]\n"
    );
    let m = refusal(&format!("{head}{signals}to = -1.0\n"));
    assert_eq!(m.len(), 1, "{m:?}");
    assert!(
        m[0].starts_with("spec.toml, line 9: the window [start, -1] s of 'plant.springDeflection' holds no recorded row"),
        "{m:?}"
    );
    let m = refusal(&format!("{head}{signals}from = 1.0005\nto = 1.0008\n"));
    assert_eq!(m.len(), 1, "{m:?}");
    assert!(
        m[0].starts_with("spec.toml, line 9: the window [1.0005, 1.0008] s"),
        "{m:?}"
    );
    // One sample is enough.
    prepared(
        &format!("{head}{signals}from = 1.0005\nto = 1.001\n"),
        tempfile::tempdir().unwrap().path(),
    )
    .unwrap();
    // A system file's stop time is known once it is loaded (1 cycle: 2.5 s).
    let dir = tempfile::tempdir().unwrap();
    sea_ssp(&dir.path().join("SEA.ssp"), 1, |_| {});
    match prepared(&ssp_spec("from = 20.0\n"), dir.path()) {
        Err(SweepError::Invalid(p)) => {
            assert_eq!(p.len(), 1, "{p:?}");
            assert_eq!(p[0].line, 9, "{p:?}");
            assert!(p[0].message.contains("to 2.5 s every 0.001 s"), "{p:?}");
        }
        other => panic!("{other:?}"),
    }
}

/// A system file that does not exist is refused at `system`'s line (it was always "line 1").
#[test]
fn a_missing_system_file_is_refused_at_its_line() {
    // A missing system file at its line (3), not line 1.
    let m = refusal(&format!(
        "# my sweep\n\n{}",
        ssp_spec("").replace("SEA.ssp", "missing.ssp")
    ));
    assert_eq!(m.len(), 1, "{m:?}");
    assert!(m[0].starts_with("spec.toml, line 3: system file "), "{m:?}");
}

/// A stop time off the step grid is refused at `stop_time`'s line (it had no line).
#[test]
fn a_stop_time_off_the_grid_is_refused_at_its_line() {
    // A stop time off the 1 ms grid: at stop_time's line.
    let m = refusal(&format!(
        "{}stop_time = 5.0005\n[design]\nkind = \"grid\"\n[[parameters]]\nname = \"plant.springStiffness\"\nvalues = [300.0]\n",
        HEAD
    ));
    assert_eq!(m.len(), 1, "{m:?}");
    assert!(
        m[0].starts_with("spec.toml, line 4: stop_time and step: "),
        "{m:?}"
    );
}

/// A scenario's FMU directory that does not exist is refused at `fmus` (a refusal, exit 2),
/// not a raw I/O error of writing the scenario (exit 1, no line).
#[test]
fn a_missing_fmu_directory_is_refused_at_fmus() {
    // A missing FMU directory: at `fmus`, a refusal (exit 2), not an I/O error.
    let m = refusal(
        &format!("{HEAD}[design]\nkind = \"grid\"\n[[parameters]]\nname = \"plant.springStiffness\"\nvalues = [300.0]\n")
            .replace("FMUS", "/nonexistent/fmus"),
    );
    assert_eq!(m.len(), 1, "{m:?}");
    assert!(
        m[0].starts_with("spec.toml, line 2: the FMU directory /nonexistent/fmus does not exist"),
        "{m:?}"
    );
}

/// Two windows of one signal are two columns, each named with its window; the same
/// statistic of the same signal and window twice is refused (it gave columns of one name:
/// pyarrow could not read the table).
#[test]
fn two_windows_of_a_signal_are_columns_of_their_own() {
    let dir = tempfile::tempdir().unwrap();
    let p = prepared(
        &format!(
            "{HEAD}[design]\nkind = \"grid\"\n[[parameters]]\nname = \"plant.springStiffness\"\nvalues = [300.0]\n\
             [metrics]\nstudy = false\n\
             [[metrics.signals]]\nsignal = \"plant.springDeflection\"\nstats = [\"max\", \"min\"]\nto = 1.25\n\
             [[metrics.signals]]\nsignal = \"plant.springDeflection\"\nstats = [\"max\"]\nfrom = 1.25\n\
             [[metrics.signals]]\nsignal = \"plant.loadOutputTorque\"\nstats = [\"max\"]\n"
        ),
        dir.path(),
    )
    .unwrap();
    assert_eq!(
        p.metric_names,
        [
            "max(plant.springDeflection)[:1.25]",
            "min(plant.springDeflection)[:1.25]",
            "max(plant.springDeflection)[1.25:]",
            "max(plant.loadOutputTorque)",
        ]
    );
    let t = run_sweep(&p, None, &options(1)).unwrap();
    assert!(t.rows[0].metrics.iter().all(|m| m.is_finite()), "{t:?}");
    assert_eq!(p.column_units().len(), 5);
}

/// The study metrics of a system file without the gait period (no `gait.gaitPeriod` binding,
/// no `[metrics] period`, not swept) are refused at `study`'s line (they had no line).
#[test]
fn study_metrics_without_a_gait_period_are_refused_at_study() {
    let dir = tempfile::tempdir().unwrap();
    sea_ssp(&dir.path().join("SEA.ssp"), 1, |s| {
        for c in &mut s.components {
            c.parameters.retain(|(n, _)| n != "gaitPeriod");
        }
    });
    let text = ssp_spec("").replace("study = false", "study = true");
    match prepared(&text, dir.path()) {
        Err(SweepError::Invalid(p)) => {
            assert_eq!(p.len(), 1, "{p:?}");
            assert_eq!(p[0].line, 8, "{p:?}");
            assert!(p[0].message.contains("need the gait period"), "{p:?}");
        }
        other => panic!("{other:?}"),
    }
    prepared(
        &text.replace("study = true", "study = true\nperiod = 2.5"),
        dir.path(),
    )
    .unwrap();
}

/// A scenario's SSP (a sweep's, the study's) reads only each FMU's model description
/// (`load::read_model_description`): the description is the one the whole archive, extracted,
/// gives, for every exported FMU, and an archive refused whole is refused as well.
#[test]
fn model_descriptions_read_alone_are_those_of_the_whole_archives() {
    use kneebench_harness::load::{ArchiveLimits, extract_and_parse, read_model_description};
    let limits = ArchiveLimits::default();
    let mut fmus: Vec<_> = std::fs::read_dir(fmus())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "fmu"))
        .collect();
    fmus.sort();
    assert!(fmus.len() >= 6, "{fmus:?}");
    for fmu in &fmus {
        let alone = read_model_description(fmu, &limits).unwrap();
        let (_dir, whole) = extract_and_parse(fmu, &limits).unwrap();
        assert_eq!(alone, whole, "{}", fmu.display());
    }
    // Refused alike: an archive with more entries than allowed, and one that is no archive.
    let few = ArchiveLimits {
        max_entries: 2,
        ..limits
    };
    let (a, b) = (
        read_model_description(&fmus[0], &few).unwrap_err(),
        extract_and_parse(&fmus[0], &few).unwrap_err(),
    );
    assert_eq!(a.to_string(), b.to_string());
    let dir = tempfile::tempdir().unwrap();
    let junk = dir.path().join("junk.fmu");
    std::fs::write(&junk, b"not a zip").unwrap();
    assert_eq!(
        read_model_description(&junk, &limits)
            .unwrap_err()
            .to_string(),
        extract_and_parse(&junk, &limits).unwrap_err().to_string()
    );
}

/// An Integer parameter's value that is not a whole number in the 32-bit range (a point that
/// a caller hands to `run_batch`, as Python's `optimize_points` does) is a failed row naming
/// the parameter: it was cast (1.5 ran as 1, NaN as 0, 1e10 as 2147483647) while the row showed
/// the value given.
#[test]
fn an_integer_parameter_runs_only_whole_values() {
    let dir = tempfile::tempdir().unwrap();
    let p = prepared(
        &format!(
            "{HEAD}[design]\nkind = \"grid\"\n[[parameters]]\nname = \"plant.frictionModel\"\n\
             values = [1.0]\n"
        ),
        dir.path(),
    )
    .unwrap();
    let mut rows = Vec::new();
    let points = [
        (0, vec![1.5]),
        (1, vec![f64::NAN]),
        (2, vec![1e10]),
        (3, vec![-0.5]),
        (4, vec![1.0]),
    ];
    p.run_batch(&points, 1, &mut |r| {
        rows.push(r);
        Ok(())
    })
    .unwrap();
    rows.sort_by_key(|r| r.point);
    for r in &rows[..4] {
        assert_eq!(r.status, RunStatus::Failed, "{r:?}");
        assert!(
            r.message
                .contains("plant.frictionModel is an Integer variable, not "),
            "{}",
            r.message
        );
        assert!(r.metrics.iter().all(|m| m.is_nan()), "{r:?}");
    }
    assert_eq!(rows[4].status, RunStatus::Ok, "{:?}", rows[4]);
}
