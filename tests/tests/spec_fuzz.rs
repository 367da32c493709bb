//! The sweep and optimisation spec reader under generated edits (a bounded fuzzing run in the
//! suite): the example specs (`examples/stiffness-sweep/*.toml`) with lines dropped,
//! duplicated or swapped, values replaced by hostile ones (NaN, infinities, huge, negative,
//! wrong types, empty strings), keys misspelt and the text truncated. Properties:
//! `SweepSpec::parse` never panics and either accepts the text or refuses it with problems
//! whose lines are in the file; an accepted `[optimize]` table gives an optimiser (or a refusal
//! naming lines) that runs every generation to its end on synthetic rows, NaN metrics and
//! tripped or failed runs among them, with every trial within the parameters' bounds.

use std::path::Path;

use kneebench_harness::sweep::runner::STUDY_METRICS;
use kneebench_harness::sweep::{Optimizer, Row, RunStatus, SweepError, SweepSpec};
use proptest::prelude::*;
use proptest::sample::{Index, select};
use proptest::strategy::ValueTree;

fn examples() -> [String; 2] {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/stiffness-sweep");
    ["sweep.toml", "optimize.toml"].map(|f| std::fs::read_to_string(dir.join(f)).unwrap())
}

#[derive(Debug, Clone)]
enum Edit {
    Drop(Index),
    Duplicate(Index),
    Swap(Index, Index),
    /// The value of a `key = value` line replaced.
    Value(Index, String),
    /// A key misspelt.
    Key(Index),
    Truncate(Index),
}

fn hostile_value() -> impl Strategy<Value = String> {
    prop_oneof![
        select(vec![
            "nan",
            "inf",
            "-inf",
            "1e308",
            "-1e308",
            "0",
            "-1",
            "-0.0",
            "1e-320",
            "\"\"",
            "\"x\"",
            "[]",
            "[1.0, nan]",
            "true",
            "{}",
            "99999999999999999999",
            "0.5",
            "\"minimize\"",
            "\"maximize\"",
            "\"rms_error_knee\"",
            "\"unknown\"",
            "3",
            "4",
        ])
        .prop_map(str::to_string),
        any::<f64>().prop_map(|x| format!("{x:?}")),
        (-5i64..50).prop_map(|n| n.to_string()),
    ]
}

fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        any::<Index>().prop_map(Edit::Drop),
        any::<Index>().prop_map(Edit::Duplicate),
        (any::<Index>(), any::<Index>()).prop_map(|(a, b)| Edit::Swap(a, b)),
        (any::<Index>(), hostile_value()).prop_map(|(i, v)| Edit::Value(i, v)),
        any::<Index>().prop_map(Edit::Key),
        any::<Index>().prop_map(Edit::Truncate),
    ]
}

fn apply(text: &str, edits: &[Edit]) -> String {
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    for e in edits {
        if lines.is_empty() {
            break;
        }
        let n = lines.len();
        match e {
            Edit::Drop(i) => {
                lines.remove(i.index(n));
            }
            Edit::Duplicate(i) => {
                let k = i.index(n);
                lines.insert(k, lines[k].clone());
            }
            Edit::Swap(a, b) => lines.swap(a.index(n), b.index(n)),
            Edit::Value(i, v) => {
                let values: Vec<usize> = (0..n).filter(|&k| lines[k].contains(" = ")).collect();
                if !values.is_empty() {
                    let k = values[i.index(values.len())];
                    let key = lines[k].split(" = ").next().unwrap_or("").to_string();
                    lines[k] = format!("{key} = {v}");
                }
            }
            Edit::Key(i) => {
                let k = i.index(n);
                if let Some(at) = lines[k].find(" = ") {
                    lines[k].insert(at, 's');
                }
            }
            Edit::Truncate(i) => lines.truncate(i.index(n)),
        }
    }
    lines.join("\n")
}

/// Checks one edited spec (see the module documentation); returns the generations an
/// optimiser of it was told.
fn check(text: &str, seed: u64) -> usize {
    let lines = text.lines().count() + 1;
    let spec = match SweepSpec::parse(text, Path::new("spec.toml"), Path::new(".")) {
        Ok(spec) => spec,
        Err(SweepError::Invalid(problems)) => {
            assert!(!problems.is_empty());
            for p in &problems {
                assert!(p.line <= lines, "{p} beyond the {lines} lines of\n{text}");
                assert!(!p.message.is_empty());
            }
            return 0;
        }
        Err(e) => panic!("refused with another error: {e}\n{text}"),
    };
    if spec.optimize.is_none() {
        return 0;
    }
    let bounds: Vec<(f64, f64)> = spec
        .parameters
        .iter()
        .map(|p| (p.min.unwrap_or(0.0), p.max.unwrap_or(1.0)))
        .collect();
    let mut rng = seed | 1;
    let mut next = move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        (rng >> 11) as f64 / (1u64 << 53) as f64
    };
    let initial: Vec<Vec<f64>> = (0..6)
        .map(|_| {
            bounds
                .iter()
                .map(|(lo, hi)| lo + (hi - lo) * next())
                .collect()
        })
        .collect();
    let mut metric_names: Vec<String> = STUDY_METRICS.iter().map(|s| s.to_string()).collect();
    metric_names.push("max(plant.springDeflection)".into());
    let mut o = match Optimizer::from_spec(&spec, initial, &metric_names) {
        Ok(o) => o,
        Err(SweepError::Invalid(problems)) => {
            for p in &problems {
                assert!(p.line <= lines, "{p} beyond the {lines} lines of\n{text}");
            }
            return 0;
        }
        Err(e) => panic!("refused with another error: {e}\n{text}"),
    };
    // Cap the work of a huge (but accepted) number of generations.
    for _ in 0..8 {
        let asked = o.ask();
        if asked.is_empty() {
            break;
        }
        let rows = asked
            .into_iter()
            .map(|(point, parameters)| {
                for (v, (lo, hi)) in parameters.iter().zip(&bounds) {
                    assert!(v >= lo && v <= hi, "{v} outside [{lo}, {hi}]\n{text}");
                }
                let r = next();
                let status = if r < 0.1 {
                    RunStatus::Tripped
                } else if r < 0.15 {
                    RunStatus::Failed
                } else {
                    RunStatus::Ok
                };
                let metrics = (0..metric_names.len())
                    .map(|_| {
                        if next() < 0.05 {
                            f64::NAN
                        } else {
                            next() * 100.0
                        }
                    })
                    .collect();
                Row {
                    point,
                    parameters,
                    metrics,
                    status,
                    message: String::new(),
                }
            })
            .collect();
        o.tell(rows).unwrap();
        assert!(o.best().is_some());
    }
    o.history().len()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1500, ..ProptestConfig::default() })]

    #[test]
    fn edited_specs_are_read_or_refused_naming_lines_in_the_file(
        which in 0usize..2,
        edits in prop::collection::vec(edit(), 0..4),
        seed in any::<u64>(),
    ) {
        let text = apply(&examples()[which], &edits);
        check(&text, seed);
    }

    #[test]
    fn arbitrary_text_is_refused_without_a_panic(text in "\\PC{0,200}") {
        check(&text, 1);
    }
}

#[test]
fn the_examples_are_read_and_the_edits_both_accept_and_refuse() {
    // Not vacuous: the unedited examples are accepted (one an optimisation), and the edits
    // give both outcomes.
    let [sweep, optimize] = examples();
    let read = |t: &str| SweepSpec::parse(t, Path::new("spec.toml"), Path::new("."));
    assert!(read(&sweep).unwrap().optimize.is_none());
    assert!(read(&optimize).unwrap().optimize.is_some());
    let mut runner = proptest::test_runner::TestRunner::deterministic();
    let (mut accepted, mut refused, mut optimised) = (0, 0, 0);
    for k in 0..400 {
        let edits = prop::collection::vec(edit(), 1..4)
            .new_tree(&mut runner)
            .unwrap()
            .current();
        let text = apply(&optimize, &edits);
        match read(&text) {
            Ok(s) if s.optimize.is_some() => accepted += 1,
            Ok(_) => {}
            Err(_) => refused += 1,
        }
        if check(&text, k) > 1 {
            optimised += 1;
        }
    }
    assert!(
        accepted > 40 && refused > 40 && optimised > 40,
        "{accepted} accepted, {refused} refused, {optimised} optimised"
    );
}
