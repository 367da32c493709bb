//! Tests of the sweep specification (`spec.rs`): every refusal names its line.

use super::*;

const SPEC: &str = r#"system = "SEA"
fmus = "/nowhere"
cycles = 2
[design]
kind = "grid"
[[parameters]]
name = "plant.springStiffness"
values = [300.0, 400.0]
[[metrics.signals]]
signal = "plant.springDeflection"
stats = ["max"]
from = FROM
"#;

fn parse(text: &str) -> Result<SweepSpec, SweepError> {
    SweepSpec::parse(text, Path::new("/nowhere/s.toml"), Path::new("/nowhere"))
}

/// The study's metrics of runs shorter than two gait cycles (the first, the start-up, is not
/// analysed) are refused at the line that makes them short, `stop_time` or `cycles`: their
/// one cycle, the start-up, was analysed silently (or, shorter than one, the rows read as
/// tripped); with `study = false`, or a cycle after the start-up, accepted.
#[test]
fn study_metrics_of_runs_shorter_than_two_cycles_are_refused() {
    let spec = SPEC.replace("from = FROM\n", "");
    let no_study = |s: &str| {
        s.replace(
            "[[metrics.signals]]",
            "[metrics]\nstudy = false\n\n[[metrics.signals]]",
        )
    };
    for (short, line, needle) in [
        (
            "cycles = 2\nstop_time = 0.2",
            4,
            "end at 0.2 s, before two periods",
        ),
        (
            "cycles = 2\nstop_time = 2.5",
            4,
            "end at 2.5 s, before two periods",
        ),
        (
            "cycles = 1",
            3,
            "cycles = 1: the study's metrics need at least 2 gait cycles",
        ),
    ] {
        let text = spec.replace("cycles = 2", short);
        let p = refused(&text);
        assert_eq!(p.len(), 1, "{short}: {p:?}");
        assert_eq!(p[0].0, line, "{short}");
        assert!(p[0].1.contains(needle), "{short}: {}", p[0].1);
        parse(&no_study(&text)).unwrap();
    }
    parse(&spec.replace("cycles = 2", "cycles = 2\nstop_time = 5.0")).unwrap();
    parse(&spec).unwrap();
}

/// A scenario sweeping the gait's period runs `cycles` of each point's period: the runs'
/// longest stop time, for the window and the bound on a run's values, is that of the
/// longest period (`values` or `max`); the default 2.5 s period was assumed.
#[test]
fn a_swept_gait_period_sets_the_runs_length() {
    let spec = SPEC
        .replace("plant.springStiffness", "gait.gaitPeriod")
        .replace("values = [300.0, 400.0]", "values = [2.0, 6.0]");
    // Two cycles of 6 s: a window from 11 s holds rows, one from 12.5 s none.
    parse(&spec.replace("FROM", "11.0")).unwrap();
    let p = refused(&spec.replace("FROM", "12.5"));
    assert_eq!(p.len(), 1, "{p:?}");
    assert!(
        p[0].1.contains("starts after the run ends at 12 s"),
        "{}",
        p[0].1
    );
    let ranged = spec
        .replace("kind = \"grid\"", "kind = \"random\"\npoints = 3")
        .replace("values = [2.0, 6.0]", "min = 2.0\nmax = 6.0");
    parse(&ranged.replace("FROM", "11.0")).unwrap();
    assert!(
        refused(&ranged.replace("FROM", "12.5"))[0]
            .1
            .contains("ends at 12 s")
    );
    // 100 cycles of 2.5 s fit the bound on a run's values, 100 of 10 s do not: refused at
    // cycles' line.
    let long = spec
        .replace("from = FROM\n", "")
        .replace("cycles = 2", "cycles = 100");
    parse(&long).unwrap();
    let p = refused(&long.replace("values = [2.0, 6.0]", "values = [2.0, 10.0]"));
    assert_eq!(p.len(), 1, "{p:?}");
    assert_eq!(p[0].0, 3);
    assert!(
        p[0].1.starts_with("each run would record 1000001 rows"),
        "{}",
        p[0].1
    );
}

/// The problems of a refused spec as (line, message).
fn refused(text: &str) -> Vec<(usize, String)> {
    match parse(text) {
        Err(SweepError::Invalid(problems)) => {
            problems.into_iter().map(|p| (p.line, p.message)).collect()
        }
        other => panic!("not refused: {other:?}"),
    }
}

/// Runs longer than MAX_RUN_VALUES allows (rows x recorded signals) are refused at the
/// line that makes them long: `cycles`, `stop_time`, or `step` when the scenario's own step
/// would have fitted; `cycles` beyond MAX_CYCLES (which no longer wraps in the scenario's
/// 32-bit count). Before, each was accepted and grew the workers' memory without bound.
#[test]
fn runs_recording_too_much_are_refused_at_the_line_that_makes_them_long() {
    let spec = SPEC.replace("from = FROM\n", "");
    // The study's 20 signals, plant.springDeflection and the time: 22 values a row, 2500
    // rows a gait cycle at 1 ms; 300 cycles fit in 2^24 values, 400 do not.
    parse(&spec.replace("cycles = 2", "cycles = 300")).unwrap();
    let p = refused(&spec.replace("cycles = 2", "cycles = 400"));
    assert_eq!(p.len(), 1, "{p:?}");
    assert_eq!(p[0].0, 3);
    assert!(
        p[0].1
            .starts_with("each run would record 1000001 rows of 21 signals"),
        "{}",
        p[0].1
    );
    assert!(
        p[0].1.contains("more than 16777216 values (128 MiB)"),
        "{}",
        p[0].1
    );
    // A cycle count that wrapped in the scenario's u32 (2^32 + 1 ran one cycle).
    let p = refused(&spec.replace("cycles = 2", "cycles = 4294967297"));
    assert_eq!(
        p,
        [(
            3,
            "cycles must be at most 10000, not 4294967297".to_string()
        )]
    );
    // stop_time sets the length.
    let p = refused(&spec.replace("cycles = 2", "cycles = 2\nstop_time = 1e6"));
    assert_eq!(p.len(), 1, "{p:?}");
    assert_eq!(p[0].0, 4);
    assert!(p[0].1.contains("shorten the runs"), "{}", p[0].1);
    // A step far below the scenario's 1 ms: its line.
    let p = refused(&spec.replace("cycles = 2", "cycles = 2\nstep = 1e-7"));
    assert_eq!(p.len(), 1, "{p:?}");
    assert_eq!(p[0].0, 4);
    // Fewer signals record less: without the study's, 400 cycles fit.
    parse(&spec.replace("cycles = 2", "cycles = 400").replace(
        "[[metrics.signals]]",
        "[metrics]\nstudy = false\n\n[[metrics.signals]]",
    ))
    .unwrap();
}

/// The one check of a run's recorded values, as both the spec (`SweepSpec::parse`) and a
/// loaded system file (`Prepared::new`) make it: at the bound accepted, a row over it
/// refused, the spec's step blamed only when the system's own would have fitted, and the
/// rows counted with every `record_every`-th step kept.
#[test]
fn the_run_values_check_bounds_rows_times_columns_and_blames_the_step_only_when_it_matters() {
    // 15 signals and the time: 2^20 rows exactly fill 2^24 values.
    let rows = (1u64 << 20) as f64;
    assert_eq!(check_run_values(rows, None, 15), Ok(()));
    let (blame, message) = check_run_values(rows + 1.0, None, 15).unwrap_err();
    assert_eq!(blame, TooLong::Length);
    assert!(
        message.starts_with("each run would record 1048577 rows of 15 signals")
            && message.contains("more than 16777216 values (128 MiB)"),
        "{message}"
    );
    assert_eq!(
        check_run_values(rows + 1.0, Some(rows), 15).unwrap_err().0,
        TooLong::Step
    );
    assert_eq!(
        check_run_values(rows + 1.0, Some(rows + 1.0), 15)
            .unwrap_err()
            .0,
        TooLong::Length
    );
    // 10 s at 1 ms: 10001 rows; every 10th kept: 1001.
    assert_eq!(run_rows(10.0, 1e-3, 1), 10_001.0);
    assert_eq!(run_rows(10.0, 1e-3, 10), 1_001.0);
    assert_eq!(run_rows(10.0, 1e-3, 0), 10_001.0);
}

/// `points` and a grid's `levels` beyond the design's MAX_POINTS are refused at their
/// line while the spec is read: `levels` made its axis (a value per level) before the
/// grid's size was checked, so `levels = 10^12` asked the allocator for 8 TB.
#[test]
fn design_sizes_beyond_the_most_points_are_refused_at_their_line() {
    let spec = SPEC.replace("from = FROM\n", "");
    let p = refused(&spec.replace(
        "values = [300.0, 400.0]",
        "min = 300.0\nmax = 400.0\nlevels = 1000000000000",
    ));
    assert_eq!(
        p,
        [(
            10,
            "parameter 'plant.springStiffness': levels must be at most 10000000, not \
             1000000000000"
                .to_string()
        )]
    );
    let p = refused(
        &spec
            .replace("kind = \"grid\"", "kind = \"random\"\npoints = 20000000")
            .replace("values = [300.0, 400.0]", "min = 300.0\nmax = 400.0"),
    );
    assert_eq!(
        p,
        [(
            6,
            "points must be at most 10000000, not 20000000".to_string()
        )]
    );
}

/// A metric column given twice (a statistic twice in one `stats`, or two entries of a
/// signal with the same window) is refused at the `stats` line; entries of other windows
/// are columns named with their window. Before, each made columns of one name.
#[test]
fn a_metric_column_given_twice_is_refused_at_its_stats_line() {
    let base = SPEC.replace("from = FROM\n", "");
    let p = refused(&base.replace("stats = [\"max\"]", "stats = [\"max\", \"max\"]"));
    assert_eq!(
        p,
        [(
            11,
            "column 'max(plant.springDeflection)' is given twice in these stats".to_string()
        )]
    );
    let twice = format!(
        "{base}[[metrics.signals]]\nsignal = \"plant.springDeflection\"\n\
         stats = [\"mean\", \"max\"]\n"
    );
    let p = refused(&twice);
    assert_eq!(
        p,
        [(
            14,
            "column 'max(plant.springDeflection)' is given twice: the signal, statistic \
             and window of line 9"
                .to_string()
        )]
    );
    let s = parse(&format!("{twice}from = 1.0\n")).unwrap();
    assert_eq!(
        signal_columns(&s.signals, 0),
        ["max(plant.springDeflection)[:]"]
    );
    assert_eq!(
        signal_columns(&s.signals, 1),
        [
            "mean(plant.springDeflection)[1:]",
            "max(plant.springDeflection)[1:]"
        ]
    );
}

/// A random design's points x parameters beyond MAX_DESIGN_VALUES are refused at `points`,
/// naming the bound (10,000,000 points of 20 parameters took 4.3 GB before the first run).
#[test]
fn a_design_of_too_many_values_is_refused_at_points() {
    let mut spec = SPEC
        .replace("from = FROM\n", "")
        .replace("kind = \"grid\"", "kind = \"random\"\npoints = 10000000");
    spec = spec.replace("values = [300.0, 400.0]", "min = 300.0\nmax = 400.0");
    parse(&spec).unwrap();
    for k in 0..19 {
        spec.push_str(&format!(
            "[[parameters]]\nname = \"plant.p{k}\"\nmin = 1.0\nmax = 2.0\n"
        ));
    }
    let p = refused(&spec);
    assert_eq!(p.len(), 1, "{p:?}");
    assert_eq!(p[0].0, 6);
    assert!(
        p[0].1.starts_with(
            "10000000 points of 20 parameters are 200000000 values, more than 33554432"
        ),
        "{}",
        p[0].1
    );
}

/// A grid of more points than MAX_POINTS, or of more values (points x parameters) than
/// MAX_DESIGN_VALUES, is refused at the design's `kind` line while the spec is read, naming
/// the bounds. Before, it passed the reading and was refused when the design was made,
/// without a line.
#[test]
fn a_grid_of_too_many_values_is_refused_at_its_kind_line() {
    let base = SPEC.replace("from = FROM\n", "").replace(
        "values = [300.0, 400.0]",
        "values = [300.0, 350.0, 400.0, 450.0]",
    );
    // 19 more parameters of 2 levels: 4 x 2^19 = 2097152 points of 20 parameters, more
    // than the 1677721 points of 20 parameters that MAX_DESIGN_VALUES allows.
    let mut spec = base.clone();
    for k in 0..19 {
        spec.push_str(&format!(
            "[[parameters]]\nname = \"plant.p{k}\"\nmin = 1.0\nmax = 2.0\nlevels = 2\n"
        ));
    }
    let p = refused(&spec);
    assert_eq!(
        p,
        [(
            5,
            "the grid has 2097152 points of 20 parameters, 41943040 values: more than \
             1677721 points (at most 10000000 points and 33554432 values, points x \
             parameters)"
                .to_string()
        )]
    );
    // One point fewer per axis fits: 2^20 points.
    parse(&spec.replacen(
        "values = [300.0, 350.0, 400.0, 450.0]",
        "values = [300.0, 400.0]",
        1,
    ))
    .unwrap();
    // Beyond MAX_POINTS, and beyond 64 bits when multiplied: still at `kind`.
    let mut spec = base;
    for k in 0..3 {
        spec.push_str(&format!(
            "[[parameters]]\nname = \"plant.p{k}\"\nmin = 1.0\nmax = 2.0\nlevels = 10000000\n"
        ));
    }
    let p = refused(&spec);
    assert_eq!(p.len(), 1, "{p:?}");
    assert_eq!(p[0].0, 5);
    assert!(
        p[0].1
            .starts_with("the grid has 4000000000000000000000 points of 4 parameters"),
        "{}",
        p[0].1
    );
}

/// A Sobol seed beyond 32 bits is refused at its line: it was folded into 32 bits, so
/// seeds 0 and 2^32 + 1 gave the same design. Other designs take any 64-bit seed.
#[test]
fn a_sobol_seed_beyond_32_bits_is_refused_at_its_line() {
    let spec = SPEC.replace("from = FROM\n", "").replace(
        "kind = \"grid\"",
        "kind = \"sobol\"\npoints = 4\nseed = SEED",
    );
    let spec = spec.replace("values = [300.0, 400.0]", "min = 300.0\nmax = 400.0");
    parse(&spec.replace("SEED", "4294967295")).unwrap();
    let p = refused(&spec.replace("SEED", "4294967297"));
    assert_eq!(
        p,
        [(
            7,
            "the Sobol design's seed is at most 4294967295 (its scramble takes 32 bits), \
             not 4294967297"
                .to_string()
        )]
    );
    parse(
        &spec
            .replace("SEED", "4294967297")
            .replace("\"sobol\"", "\"random\""),
    )
    .unwrap();
}

/// A window that starts after the runs end (a scenario's cycles of the gait, or the
/// spec's stop time) would give NaN with status ok: refused, naming its line.
#[test]
fn a_window_after_the_run_is_refused_where_the_stop_time_is_known() {
    let period = crate::study::StudyScenario::BenchFull.gait().period;
    let after = SPEC.replace("FROM", &format!("{}", 2.0 * period + 0.5));
    match parse(&after) {
        Err(SweepError::Invalid(problems)) => {
            assert_eq!(problems.len(), 1, "{problems:?}");
            assert_eq!(problems[0].line, 12);
            assert!(
                problems[0].message.contains("starts after the run ends"),
                "{}",
                problems[0].message
            );
        }
        other => panic!("{other:?}"),
    }
    // Within the run, or the run made longer: accepted.
    parse(&SPEC.replace("FROM", &format!("{}", period - 0.5))).unwrap();
    parse(&after.replace("cycles = 2", "cycles = 3")).unwrap();
    let stopped = after.replace("cycles = 2", "cycles = 4\nstop_time = 1.0");
    assert!(matches!(parse(&stopped), Err(SweepError::Invalid(_))));
    // A system file's stop time is not known before it is loaded.
    let file = after
        .replace("system = \"SEA\"", "system = \"x.ssp\"")
        .replace("fmus = \"/nowhere\"\n", "");
    parse(&file).unwrap();
}
