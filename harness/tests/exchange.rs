//! `Instance::step_exchange` (the master's set-step-get in one call, with a fast form for an
//! in-process instance) against `Instance::step_exchange_plain` (the single calls): the same
//! output values bit for bit, the same outcome, error, phase, step count and messages, at every
//! point where the exchange can stop.

mod common;

use kneebench_harness::instance::Exchange;
use kneebench_harness::{Fmu, Instance, InstanceOptions, LoadOptions};

/// The kbtest inputs and outputs an exchange moves (value references per type); a case
/// changes some of them to make one call fail.
#[derive(Clone)]
struct Lists {
    in_vrs: [Vec<u32>; 3],
    out_vrs: [Vec<u32>; 3],
    /// Value counts of the inputs and outputs (the lists' lengths unless a case breaks them).
    in_len: [usize; 3],
    out_len: [usize; 3],
}

impl Lists {
    fn new(in_vrs: [Vec<u32>; 3], out_vrs: [Vec<u32>; 3]) -> Lists {
        Lists {
            in_len: [0, 1, 2].map(|t| in_vrs[t].len()),
            out_len: [0, 1, 2].map(|t| out_vrs[t].len()),
            in_vrs,
            out_vrs,
        }
    }
}

/// kbtest: Real u (0), y (1), x (4), t (5); Integer steps (0), i_in (1), i_out (2); Boolean
/// b_in (0), b_out (1). Every input and a mix of outputs (y has direct feedthrough).
fn every() -> Lists {
    Lists::new(
        [vec![0], vec![1], vec![0]],
        [vec![1, 4, 5], vec![0, 2], vec![1]],
    )
}

/// A case: what it is, the parameters set before initialization (discard_at = vr 6,
/// error_at = vr 7) and its lists.
type Case = (&'static str, Vec<(u32, f64)>, Lists);

/// Everything one exchange gave, to compare.
#[derive(Debug, PartialEq)]
struct Seen {
    result: String,
    real: Vec<u64>,
    int: Vec<i32>,
    boolean: Vec<i32>,
    steps: u64,
    phase: String,
    messages: String,
}

fn instance(fmu: &Fmu, params: &[(u32, f64)]) -> Instance {
    let mut i = fmu.instantiate("m", &InstanceOptions::default()).unwrap();
    i.setup_experiment(None, 0.0, Some(1.0)).unwrap();
    for &(vr, v) in params {
        i.set_real(&[vr], &[v]).unwrap();
    }
    i.enter_initialization_mode().unwrap();
    i.exit_initialization_mode().unwrap();
    i
}

/// Up to 5 exchanges of 0.1 s through `fast` or the plain calls, each compared; stops after the
/// first that does not complete a step.
fn run(fmu: &Fmu, params: &[(u32, f64)], lists: &Lists, fast: bool) -> Vec<Seen> {
    let mut inst = instance(fmu, params);
    let mut seen = Vec::new();
    let mut steps = 0;
    for n in 0..5u32 {
        let t = f64::from(n) * 0.1;
        let real_in: Vec<f64> = (0..lists.in_len[0])
            .map(|k| 0.3 * f64::from(n) - 1.0 / 3.0 + k as f64)
            .collect();
        let int_in: Vec<i32> = (0..lists.in_len[1])
            .map(|k| n as i32 * 7 - 3 + k as i32)
            .collect();
        let bool_in: Vec<i32> = (0..lists.in_len[2])
            .map(|k| ((n as usize + k) % 2) as i32)
            .collect();
        // Outputs start as a pattern the FMU overwrites (a discarded step leaves them).
        let mut real = vec![-7.25; lists.out_len[0]];
        let mut int = vec![-9; lists.out_len[1]];
        let mut boolean = vec![5; lists.out_len[2]];
        let x = Exchange {
            in_vrs: &lists.in_vrs,
            real_in: &real_in,
            int_in: &int_in,
            bool_in: &bool_in,
            out_vrs: &lists.out_vrs,
            real_out: &mut real,
            int_out: &mut int,
            bool_out: &mut boolean,
        };
        let r = if fast {
            inst.step_exchange(x, t, 0.1, &mut steps)
        } else {
            inst.step_exchange_plain(x, t, 0.1, &mut steps)
        };
        let stop = !matches!(r, Ok(kneebench_harness::Status::Ok));
        seen.push(Seen {
            result: format!("{r:?}"),
            real: real.iter().map(|v| v.to_bits()).collect(),
            int,
            boolean,
            steps,
            phase: format!("{:?}", inst.phase()),
            messages: format!("{:?}", inst.take_messages()),
        });
        if stop {
            break;
        }
    }
    seen
}

#[test]
fn the_fast_exchange_is_the_plain_one_at_every_stop() {
    let dir = tempfile::tempdir().unwrap();
    let fmu = Fmu::load(common::kbtest_fmu(dir.path()), &LoadOptions::default()).unwrap();
    assert!(
        !fmu.is_isolated(),
        "the fast form is for in-process instances"
    );
    let with = |f: &dyn Fn(&mut Lists)| {
        let mut l = every();
        f(&mut l);
        l
    };
    let cases: Vec<Case> = vec![
        ("every step done", vec![], every()),
        (
            "nothing to set or read",
            vec![],
            Lists::new(Default::default(), Default::default()),
        ),
        (
            "Real only",
            vec![],
            Lists::new([vec![0], vec![], vec![]], [vec![1, 4], vec![], vec![]]),
        ),
        ("discarded step", vec![(6, 0.25)], every()),
        ("failed step", vec![(7, 0.25)], every()),
        (
            "fmi2SetReal fails",
            vec![],
            with(&|l| l.in_vrs[0] = vec![0, 9]),
        ),
        (
            "fmi2SetInteger fails",
            vec![],
            with(&|l| l.in_vrs[1] = vec![5]),
        ),
        (
            "fmi2SetBoolean fails",
            vec![],
            with(&|l| l.in_vrs[2] = vec![4]),
        ),
        (
            "fmi2GetReal fails",
            vec![],
            with(&|l| l.out_vrs[0] = vec![1, 8]),
        ),
        (
            "fmi2GetInteger fails",
            vec![],
            with(&|l| l.out_vrs[1] = vec![3]),
        ),
        (
            "fmi2GetBoolean fails",
            vec![],
            with(&|l| l.out_vrs[2] = vec![2]),
        ),
        ("Real inputs too few", vec![], with(&|l| l.in_len[0] = 0)),
        (
            "Integer inputs too many",
            vec![],
            with(&|l| l.in_len[1] = 2),
        ),
        ("Boolean inputs too few", vec![], with(&|l| l.in_len[2] = 0)),
        ("Real outputs too many", vec![], with(&|l| l.out_len[0] = 4)),
        (
            "Integer outputs too few",
            vec![],
            with(&|l| l.out_len[1] = 1),
        ),
        (
            "Boolean outputs too many",
            vec![],
            with(&|l| l.out_len[2] = 2),
        ),
    ];
    for (what, params, lists) in &cases {
        let plain = run(&fmu, params, lists, false);
        let fast = run(&fmu, params, lists, true);
        assert_eq!(fast, plain, "{what}");
    }
    // The cases reach what they are named for (through the plain calls).
    let last = |i: usize| run(&fmu, &cases[i].1, &cases[i].2, false).pop().unwrap();
    assert_eq!(run(&fmu, &[], &every(), false).len(), 5);
    assert!(last(3).result.contains("Discard"), "{:?}", last(3));
    assert!(last(4).result.contains("fmi2DoStep"), "{:?}", last(4));
    for (i, function) in [
        (5, "fmi2SetReal"),
        (6, "fmi2SetInteger"),
        (7, "fmi2SetBoolean"),
        (8, "fmi2GetReal"),
        (9, "fmi2GetInteger"),
        (10, "fmi2GetBoolean"),
        (11, "fmi2SetReal"),
        (12, "fmi2SetInteger"),
        (13, "fmi2SetBoolean"),
        (14, "fmi2GetReal"),
        (15, "fmi2GetInteger"),
        (16, "fmi2GetBoolean"),
    ] {
        let seen = last(i);
        assert!(
            seen.result.starts_with("Err(") && seen.result.contains(function),
            "{}: {seen:?}",
            cases[i].0
        );
    }
}
