//! Optimisation end to end through the exported FMUs: a bad `[optimize]` table is refused
//! naming its line before anything runs; the result is bit-identical whatever the number of
//! workers; the optimum is the best feasible row of the table; `--resume` replays the journal's
//! rows and runs the rest, and continues a finished Parquet table with more generations; a
//! sweep refuses an optimisation's spec (the command line: harness/tests/cli_optimize.rs).

use std::path::Path;

use kneebench_harness::sweep::journal::{journal_line, journal_path};
use kneebench_harness::sweep::{
    Prepared, RunStatus, SweepError, SweepOptions, SweepSpec, SweepTable, run_optimization,
    run_sweep,
};

fn fmus() -> &'static Path {
    kneebench_tests::exported_fmus().0.path()
}

fn spec(text: &str) -> Result<SweepSpec, SweepError> {
    let text = text.replace("FMUS", &fmus().display().to_string());
    SweepSpec::parse(&text, Path::new("spec.toml"), Path::new("."))
}

fn refusal(text: &str) -> Vec<String> {
    match spec(text).and_then(Prepared::new) {
        Err(SweepError::Invalid(p)) => p.iter().map(|p| p.to_string()).collect(),
        Err(e) => panic!("refused with another error: {e}"),
        Ok(_) => panic!("accepted:\n{text}"),
    }
}

/// Population 4, 2 generations after it: 12 runs of two gait cycles. The objective (the
/// knee's RMS tracking error) and the constraint (both motors' energy per cycle) vary with
/// both parameters (examples/stiffness-sweep).
const SPEC: &str = "system = \"SEA\"\nfmus = \"FMUS\"\ncycles = 2\n\
[design]\nkind = \"latin-hypercube\"\npoints = 4\nseed = 3\n\
[[parameters]]\nname = \"plant.springStiffness\"\nmin = 150.0\nmax = 550.0\n\
[[parameters]]\nname = \"plant.harmonicDriveRatio\"\nmin = 120.0\nmax = 200.0\n\
[metrics]\nstudy = true\n\
[optimize]\nobjective = \"rms_error_knee\"\ngenerations = 2\nseed = 5\n\
[[optimize.constraints]]\nmetric = \"all_electrical_energy\"\nmax = 85.0\n";

fn options(workers: usize) -> SweepOptions {
    SweepOptions {
        workers,
        progress: false,
        resume: false,
    }
}

#[test]
fn bad_optimize_tables_are_refused_naming_the_line() {
    let with = |optimize: &str| {
        SPEC.replace(
            "[optimize]\nobjective = \"rms_error_knee\"\ngenerations = 2\nseed = 5\n\
         [[optimize.constraints]]\nmetric = \"all_electrical_energy\"\nmax = 85.0\n",
            optimize,
        )
    };
    // Found while parsing (the [optimize] table starts on line 18).
    let m = refusal(&with(
        "[optimize]\nobjective = \"rms_error_knee\"\ndirection = \"smallest\"\ngenerations = 0\n\
         crossover = 1.5\ndifferential_weight = 0.0\nseed = -1\n\
         [[optimize.constraints]]\nmetric = \"peak_test_torque\"\n\
         [[optimize.constraints]]\nmetric = \"peak_load_torque\"\nmin = 5.0\nmax = 1.0\n",
    ));
    assert_eq!(
        m,
        [
            "spec.toml, line 20: unknown direction 'smallest' (minimize, maximize)",
            "spec.toml, line 21: generations must be at least 1, not 0",
            "spec.toml, line 24: seed must not be negative",
            "spec.toml, line 23: differential_weight must be in (0, 2], not 0",
            "spec.toml, line 22: crossover must be in [0, 1], not 1.5",
            "spec.toml, line 25: constraint on 'peak_test_torque' needs min, max or both",
            "spec.toml, line 27: constraint on 'peak_load_torque': min 5 is greater than max 1",
        ]
    );
    // A misspelt key and a missing objective: the TOML reader's message, with the line.
    let m = refusal(&with(
        "[optimize]\nobjective = \"rms_error_knee\"\ngeneration = 3\n",
    ));
    assert_eq!(m.len(), 1);
    assert!(
        m[0].starts_with("spec.toml, line 20: unknown field `generation`"),
        "{m:?}"
    );
    let m = refusal(&with("[optimize]\ngenerations = 3\n"));
    assert!(m[0].contains("missing field `objective`"), "{m:?}");
    // Found against the system: an objective or a constrained metric that is not a column,
    // a parameter without bounds (a csv design), a population under 4.
    let m = refusal(&with(
        "[optimize]\nobjective = \"energy\"\ngenerations = 3\n\
         [[optimize.constraints]]\nmetric = \"max(plant.springDeflection)\"\nmax = 0.1\n",
    ));
    assert_eq!(m.len(), 2, "{m:?}");
    assert!(
        m[0].starts_with(
            "spec.toml, line 19: objective 'energy' is not a metric of this spec (its metrics: \
             cycles, rms_error_actuation,"
        ),
        "{m:?}"
    );
    assert!(
        m[1].starts_with(
            "spec.toml, line 21: constraint on 'max(plant.springDeflection)': not a metric"
        ),
        "{m:?}"
    );
    let m = refusal(&SPEC.replace("points = 4", "points = 3"));
    assert_eq!(
        m,
        [
            "spec.toml, line 18: the optimisation's population is the design's points: at least 4, not 3"
        ]
    );
    let m = refusal(
        &SPEC
            .replace("min = 150.0\nmax = 550.0\n", "values = [300.0]\n")
            .replace(
                "kind = \"latin-hypercube\"\npoints = 4\nseed = 3",
                "kind = \"grid\"",
            ),
    );
    assert!(
        m.iter().any(|l| l
            == "spec.toml, line 15: the optimisation needs min and max for every parameter; \
                'plant.springStiffness' (line 6) has not both"),
        "{m:?}"
    );
}

#[test]
fn an_optimisation_is_bit_identical_whatever_the_workers_and_finds_the_best_feasible_row() {
    let p = spec(SPEC).and_then(Prepared::new).unwrap();
    let mut seen = Vec::new();
    let one = run_optimization(&p, None, &options(1), &mut |g| {
        seen.push(g.clone());
        Ok(())
    })
    .unwrap();
    let two = run_optimization(&p, None, &options(2), &mut |_| Ok(())).unwrap();
    assert_eq!(one.table.rows.len(), 12);
    assert!(one.table.bit_identical(&two.table));
    assert!(one.best.bit_identical(&two.best));
    assert_eq!(one.history, two.history);
    assert_eq!(
        seen, one.history,
        "each generation's best is reported as selected"
    );
    assert_eq!(
        one.table.rows.iter().map(|r| r.point).collect::<Vec<_>>(),
        (0..12).collect::<Vec<u64>>()
    );
    // The trials are new points within the bounds, not the design's again.
    for r in &one.table.rows[4..] {
        assert_eq!(r.status, RunStatus::Ok, "{r:?}");
        assert!((150.0..=550.0).contains(&r.parameters[0]), "{r:?}");
        assert!((120.0..=200.0).contains(&r.parameters[1]), "{r:?}");
        assert!(
            !p.design.points.contains(&r.parameters),
            "{r:?} repeats a design point"
        );
    }
    // The optimum, found again from the table alone: the smallest objective of the rows
    // within the constraint; some rows are outside it (the constraint is not vacuous).
    let col = |name: &str| p.metric_names.iter().position(|m| m == name).unwrap();
    let (objective, energy) = (col("rms_error_knee"), col("all_electrical_energy"));
    let feasible: Vec<_> = one
        .table
        .rows
        .iter()
        .filter(|r| r.metrics[energy] <= 85.0)
        .collect();
    assert!(
        feasible.len() < 12 && !feasible.is_empty(),
        "{:?}",
        one.table.rows
    );
    let best = feasible
        .iter()
        .min_by(|a, b| a.metrics[objective].total_cmp(&b.metrics[objective]))
        .unwrap();
    assert_eq!(best.point, one.best.point);
    assert_eq!(one.violation, 0.0);
    let meta = |k: &str| {
        one.table
            .metadata
            .iter()
            .find(|(key, _)| key == k)
            .map(|(_, v)| v.clone())
    };
    assert_eq!(
        meta("kneebench.optimize.best_point"),
        Some(best.point.to_string())
    );
    assert_eq!(meta("kneebench.optimize.population").as_deref(), Some("4"));
    assert!(meta("kneebench.sweep.fingerprint").is_some());
}

#[test]
fn resume_replays_the_journal_and_runs_the_rest() {
    let dir = tempfile::tempdir().unwrap();
    let p = spec(SPEC).and_then(Prepared::new).unwrap();
    let out = dir.path().join("optimize.parquet");
    let full = run_optimization(&p, Some(&out), &options(2), &mut |_| Ok(())).unwrap();
    assert!(out.is_file() && !journal_path(&out).exists());
    // Interrupted in the second generation: the design's rows and one trial journaled (marked,
    // so that a rerun would show), a torn line after them.
    let mut journal = p.journal_header();
    let mut marked = full.table.clone();
    for r in &mut marked.rows[..5] {
        r.message = "from the journal".into();
        journal.push_str(&journal_line(r));
    }
    let torn = journal_line(&full.table.rows[5]);
    journal.push_str(&torn[..torn.len() / 2]);
    std::fs::write(journal_path(&out), &journal).unwrap();
    let e = run_optimization(&p, Some(&out), &options(2), &mut |_| Ok(())).unwrap_err();
    assert!(e.to_string().contains("pass --resume"), "{e}");
    let resumed = run_optimization(
        &p,
        Some(&out),
        &SweepOptions {
            resume: true,
            ..options(2)
        },
        &mut |_| Ok(()),
    )
    .unwrap();
    assert!(
        resumed.table.bit_identical(&marked),
        "only points 5.. ran again"
    );
    assert_eq!(resumed.best.point, full.best.point);
    // Stopped by its caller after generation 1 (`on_generation`'s error): the error comes
    // back, the journal holds generations 0 and 1, and the resumed run ends as the full one.
    assert!(!journal_path(&out).exists());
    std::fs::remove_file(&out).unwrap();
    let e = run_optimization(&p, Some(&out), &options(2), &mut |g| {
        if g.generation == 1 {
            Err(SweepError::System("stopped by the caller".into()))
        } else {
            Ok(())
        }
    })
    .unwrap_err();
    assert_eq!(e.to_string(), "stopped by the caller");
    assert!(!out.exists());
    let journal = std::fs::read_to_string(journal_path(&out)).unwrap();
    assert_eq!(journal.lines().count(), 1 + 8, "{journal}");
    let resumed = run_optimization(
        &p,
        Some(&out),
        &SweepOptions {
            resume: true,
            ..options(1)
        },
        &mut |_| Ok(()),
    )
    .unwrap();
    assert!(resumed.table.bit_identical(&full.table));
    // A journaled point beyond the optimisation's runs is not one of its rows.
    let mut bad = p.journal_header();
    let mut beyond = full.table.rows[0].clone();
    beyond.point = 12;
    bad.push_str(&journal_line(&beyond));
    std::fs::write(journal_path(&out), &bad).unwrap();
    let e = run_optimization(
        &p,
        Some(&out),
        &SweepOptions {
            resume: true,
            ..options(1)
        },
        &mut |_| Ok(()),
    )
    .unwrap_err();
    assert!(
        e.to_string()
            .contains("line 2: point 12 is beyond this sweep (an optimisation can be continued"),
        "{e}"
    );
}

#[test]
fn a_finished_optimisation_continues_with_more_generations() {
    let dir = tempfile::tempdir().unwrap();
    let resume = SweepOptions {
        resume: true,
        ..options(2)
    };
    let one = spec(&SPEC.replace("generations = 2", "generations = 1"))
        .and_then(Prepared::new)
        .unwrap();
    let two = spec(SPEC).and_then(Prepared::new).unwrap();
    // The generations are the one part of the spec the fingerprint leaves out.
    assert_eq!(one.fingerprint, two.fingerprint);
    let reseeded = spec(&SPEC.replace("seed = 5", "seed = 6"))
        .and_then(Prepared::new)
        .unwrap();
    assert_ne!(reseeded.fingerprint, two.fingerprint);
    let fresh = run_optimization(&two, None, &options(2), &mut |_| Ok(())).unwrap();

    // Generation 1 finished; its rows marked in the table, so that a rerun would show.
    let out = dir.path().join("o.parquet");
    run_optimization(&one, Some(&out), &options(2), &mut |_| Ok(())).unwrap();
    let mut table = SweepTable::read_parquet(&out, 2).unwrap();
    assert_eq!(table.rows.len(), 8);
    assert!(table.bit_identical(&SweepTable {
        rows: fresh.table.rows[..8].to_vec(),
        ..fresh.table.clone()
    }));
    for r in &mut table.rows {
        r.message = "from the table".into();
    }
    table.write_parquet(&out).unwrap();
    // With --resume only generation 2's four runs run (afresh without it: below).
    let continued = run_optimization(&two, Some(&out), &resume, &mut |_| Ok(())).unwrap();
    let mut expected = fresh.table.clone();
    for r in &mut expected.rows[..8] {
        r.message = "from the table".into();
    }
    assert!(continued.table.bit_identical(&expected));
    assert_eq!(continued.best.point, fresh.best.point);
    assert!(!journal_path(&out).exists());
    let written = SweepTable::read_parquet(&out, 2).unwrap();
    assert!(written.bit_identical(&expected));
    let meta = |k: &str| {
        written
            .metadata
            .iter()
            .find(|(key, _)| key == k)
            .map(|(_, v)| v.clone())
    };
    assert_eq!(meta("kneebench.optimize.generations").as_deref(), Some("2"));

    // Refused: fewer generations than the table holds, another sweep's table, a CSV table.
    let e = run_optimization(&one, Some(&out), &resume, &mut |_| Ok(())).unwrap_err();
    assert!(
        e.to_string()
            .contains("point 8 of the finished table is beyond this sweep"),
        "{e}"
    );
    let e = run_optimization(&reseeded, Some(&out), &resume, &mut |_| Ok(())).unwrap_err();
    assert!(
        e.to_string()
            .contains("the finished table belongs to another sweep"),
        "{e}"
    );
    let csv = dir.path().join("o.csv");
    run_optimization(&one, Some(&csv), &options(2), &mut |_| Ok(())).unwrap();
    let e = run_optimization(&two, Some(&csv), &resume, &mut |_| Ok(())).unwrap_err();
    assert!(
        e.to_string().contains("a CSV table carries no fingerprint"),
        "{e}"
    );
    // Every refusal left the tables and wrote no journal.
    assert!(
        SweepTable::read_parquet(&out, 2)
            .unwrap()
            .bit_identical(&expected)
    );
    assert!(!journal_path(&out).exists() && !journal_path(&csv).exists());
    // Without --resume the finished table is run afresh (its marks gone).
    let afresh = run_optimization(&two, Some(&out), &options(2), &mut |_| Ok(())).unwrap();
    assert!(afresh.table.bit_identical(&fresh.table));
}

#[test]
fn points_of_the_wrong_width_are_refused_not_run_short() {
    let p = spec(SPEC).and_then(Prepared::new).unwrap();
    let e = p
        .run_batch(&[(0, vec![300.0])], 1, &mut |_| Ok(()))
        .unwrap_err();
    assert_eq!(e.to_string(), "point 0 has 1 values for 2 parameters");
    let loaded = p.worker_system().unwrap();
    let row = p.run_values(&loaded, 7, &[300.0, 160.0, 1.0]);
    assert_eq!(row.status, RunStatus::Failed);
    assert_eq!(row.message, "point 7 has 3 values for 2 parameters");
    assert!(row.metrics.iter().all(|m| m.is_nan()));
    p.give_back(loaded);
}

#[test]
fn a_sweep_refuses_an_optimisation() {
    let p = spec(SPEC).and_then(Prepared::new).unwrap();
    let e = run_sweep(&p, None, &options(1)).unwrap_err();
    assert_eq!(
        e.to_string(),
        "spec.toml, line 18: this spec optimises ([optimize]): run it with `kneebench optimize` \
         (or kneebench.optimize in Python), or remove [optimize] to sweep its design"
    );
}
