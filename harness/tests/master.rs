//! The master: algorithms against hand-computed sequences, the recording rule, multi-rate,
//! the time grid, early termination and errors, and the instance API.

mod common;

use std::path::Path;

use kneebench_harness::master::Signal;
use kneebench_harness::{
    Algorithm, Fmu, InstanceOptions, LoadOptions, Outcome, RunConfig, System, Value,
};

fn fmu() -> (tempfile::TempDir, Fmu) {
    let dir = tempfile::tempdir().unwrap();
    let path = common::kbtest_fmu(dir.path());
    let fmu = Fmu::load(&path, &LoadOptions::default()).unwrap();
    (dir, fmu)
}

/// `a.x` (a counter: x += u with u = 1, no direct feedthrough) feeds `b.u`; `b.y = 2 u + 0.5`
/// has direct feedthrough. `b` is declared first so the order must come from the connections.
fn two_fmu_system(fmu: &Fmu) -> System {
    let mut s = System::new();
    s.add_component("b", fmu.clone()).unwrap();
    s.add_component("a", fmu.clone()).unwrap();
    s.set_value_str("a.u", "1").unwrap();
    s.set_value_str("b.k", "2").unwrap();
    s.set_value_str("b.b", "0.5").unwrap();
    s.connect("a.x", "b.u").unwrap();
    s.record(&["a.x", "b.u", "b.y", "b.steps"]).unwrap();
    s
}

fn config(algorithm: Algorithm, stop: f64) -> RunConfig {
    RunConfig {
        stop_time: stop,
        step_size: 0.1,
        algorithm,
        ..RunConfig::default()
    }
}

#[test]
fn gauss_seidel_matches_hand_computed_sequence() {
    let (_d, fmu) = fmu();
    let s = two_fmu_system(&fmu);
    let out = s.run(&config(Algorithm::GaussSeidel, 0.5)).unwrap();
    assert!(matches!(out.outcome, Outcome::Completed { stop_time } if stop_time == 0.5));
    let r = &out.results;
    assert_eq!(r.names(), ["a.x", "b.u", "b.y", "b.steps"]);
    assert_eq!(r.len(), 6);
    for n in 0..6 {
        let row = r.row(n);
        let x = n as f64;
        // Row n is recorded after the step ending at t(n): a stepped first (x = n), then b
        // read it (u = n) and computed y = 2 n + 0.5.
        assert_eq!(
            row,
            [n as f64 / 10.0, x, x, 2.0 * x + 0.5, n as f64],
            "row {n}"
        );
    }
    assert_eq!(out.steps_per_component, vec![5, 5]);
}

#[test]
fn jacobi_matches_hand_computed_sequence() {
    let (_d, fmu) = fmu();
    let s = two_fmu_system(&fmu);
    let out = s.run(&config(Algorithm::Jacobi, 0.5)).unwrap();
    assert!(matches!(out.outcome, Outcome::Completed { .. }));
    let r = &out.results;
    assert_eq!(r.len(), 6);
    for n in 0..6 {
        let row = r.row(n);
        // Jacobi: b's input for the step ending at t(n) was a.x at t(n-1).
        let u = n.saturating_sub(1) as f64;
        assert_eq!(
            row,
            [n as f64 / 10.0, n as f64, u, 2.0 * u + 0.5, n as f64],
            "row {n}"
        );
    }
}

#[test]
fn parallel_stepping_gives_the_same_rows() {
    let (_d, fmu) = fmu();
    let s = two_fmu_system(&fmu);
    for alg in [Algorithm::GaussSeidel, Algorithm::Jacobi] {
        let seq = s.run(&config(alg, 1.0)).unwrap();
        let par = s
            .run(&RunConfig {
                parallel: true,
                ..config(alg, 1.0)
            })
            .unwrap();
        assert_eq!(seq.results, par.results, "{alg:?}");
    }
}

#[test]
fn multi_rate_holds_values_between_communication_points() {
    let (_d, fmu) = fmu();
    let mut s = two_fmu_system(&fmu);
    s.set_step_multiple("b", 2).unwrap();
    s.record(&["a.x", "b.u", "b.steps", "b.t"]).unwrap();
    let out = s.run(&config(Algorithm::GaussSeidel, 0.6)).unwrap();
    assert!(matches!(out.outcome, Outcome::Completed { .. }));
    let r = &out.results;
    assert_eq!(r.len(), 7);
    assert_eq!(out.steps_per_component, vec![3, 6]);
    for n in 0..7usize {
        let row = r.row(n);
        let b_steps = n.div_ceil(2);
        assert_eq!(row[1], n as f64, "a.x row {n}");
        assert_eq!(row[3], b_steps as f64, "b.steps row {n}");
        // b steps at n = 0, 2, 4 over 0.2 s, after a: it reads a.x = n + 1.
        let u = if n == 0 {
            0.0
        } else {
            (2 * ((n - 1) / 2) + 1) as f64
        };
        assert_eq!(row[2], u, "b.u row {n}");
        assert!((row[4] - 0.2 * b_steps as f64).abs() < 1e-12, "b.t row {n}");
    }
    // A multiple that does not divide the run is refused before anything runs.
    assert!(s.run(&config(Algorithm::GaussSeidel, 0.5)).is_err());
}

#[test]
fn algebraic_loop_is_refused_by_gauss_seidel_and_run_by_jacobi() {
    let (_d, fmu) = fmu();
    let mut s = System::new();
    s.add_component("a", fmu.clone()).unwrap();
    s.add_component("b", fmu.clone()).unwrap();
    s.connect("a.y", "b.u").unwrap();
    s.connect("b.y", "a.u").unwrap();
    let err = s.run(&config(Algorithm::GaussSeidel, 0.3)).unwrap_err();
    assert!(err.to_string().contains("algebraic loop"), "{err}");
    let out = s.run(&config(Algorithm::Jacobi, 0.3)).unwrap();
    assert!(matches!(out.outcome, Outcome::Completed { .. }));
}

#[test]
fn feedback_through_a_non_feedthrough_output_is_ordered() {
    let (_d, fmu) = fmu();
    let mut s = System::new();
    s.add_component("a", fmu.clone()).unwrap();
    s.add_component("b", fmu.clone()).unwrap();
    s.set_value_str("b.b", "1").unwrap();
    // a.x has no direct feedthrough: the cycle a -> b -> a is not an algebraic loop.
    s.connect("a.x", "b.u").unwrap();
    s.connect("b.y", "a.u").unwrap();
    let (order, _) = s.dependency_order().unwrap();
    assert_eq!(
        order,
        vec![1, 0],
        "b (fed by the delayed a.x) first, then a"
    );
    s.record(&["a.x", "b.y"]).unwrap();
    let out = s.run(&config(Algorithm::GaussSeidel, 0.3)).unwrap();
    // b first: y = x(n) + 1; then a: x(n+1) = x(n) + y.  x: 0, 1, 3, 7; y recorded = x(n-1) + 1.
    let xs = out.results.column("a.x").unwrap();
    let ys = out.results.column("b.y").unwrap();
    assert_eq!(xs, [0.0, 1.0, 3.0, 7.0]);
    assert_eq!(ys, [1.0, 1.0, 2.0, 4.0]);
}

#[test]
fn integer_and_boolean_connections_and_signals() {
    let (_d, fmu) = fmu();
    let mut s = System::new();
    s.add_component("a", fmu.clone()).unwrap();
    s.add_component("b", fmu.clone()).unwrap();
    s.connect("a.i_out", "b.i_in").unwrap();
    s.connect("a.b_out", "b.b_in").unwrap();
    s.add_signal(
        "a.i_in",
        Signal {
            times: vec![0.0, 0.2],
            values: vec![1.0, 5.0],
            interpolate: false,
        },
    )
    .unwrap();
    s.add_signal(
        "a.u",
        Signal {
            times: vec![0.0, 1.0],
            values: vec![0.0, 10.0],
            interpolate: true,
        },
    )
    .unwrap();
    s.record(&["a.i_out", "b.i_out", "b.b_out", "a.y"]).unwrap();
    let out = s.run(&config(Algorithm::GaussSeidel, 0.3)).unwrap();
    let r = &out.results;
    assert_eq!(r.column("a.i_out").unwrap(), [2.0, 2.0, 2.0, 10.0]);
    assert_eq!(r.column("b.i_out").unwrap(), [4.0, 4.0, 4.0, 20.0]);
    // a.b_out = !false = true, b.b_out = !true = false.
    assert_eq!(r.column("b.b_out").unwrap(), [0.0; 4]);
    // a.u is the interpolated signal at the start of the step: y(row n) = u(t(n-1)).
    let y = r.column("a.y").unwrap();
    assert_eq!(y[0], 0.0);
    assert!(
        (y[2] - 1.0).abs() < 1e-12 && (y[3] - 2.0).abs() < 1e-12,
        "{y:?}"
    );
}

#[test]
fn a_million_millisecond_steps_end_exactly_at_1000_s() {
    let (_d, fmu) = fmu();
    let mut s = System::new();
    s.add_component("a", fmu).unwrap();
    s.record(&["a.steps", "a.t"]).unwrap();
    let out = s
        .run(&RunConfig {
            stop_time: 1000.0,
            step_size: 1e-3,
            record_every: 1000,
            ..RunConfig::default()
        })
        .unwrap();
    assert!(matches!(out.outcome, Outcome::Completed { stop_time } if stop_time == 1000.0));
    assert_eq!(out.steps_per_component, vec![1_000_000]);
    let r = &out.results;
    assert_eq!(r.len(), 1001);
    let last = r.row(r.len() - 1);
    assert_eq!(last[0], 1000.0, "the last row is at exactly 1000 s");
    assert_eq!(last[1], 1_000_000.0, "the FMU counted 1e6 doStep calls");
    assert!(
        (last[2] - 1000.0).abs() < 1e-9,
        "the FMU's own time {}",
        last[2]
    );
    // Every row time is the double nearest to the decimal time.
    for (k, row) in r.rows().enumerate() {
        assert_eq!(row[0], k as f64, "row {k}");
    }
}

#[test]
fn discard_with_terminated_ends_the_run_cleanly_and_keeps_every_row() {
    let (d, fmu) = fmu();
    let mut s = two_fmu_system(&fmu);
    s.set_value_str("b.discard_at", "0.35").unwrap();
    let out = s.run(&config(Algorithm::GaussSeidel, 1.0)).unwrap();
    match &out.outcome {
        Outcome::Terminated {
            component,
            last_successful_time,
            last_row_time,
            ..
        } => {
            assert_eq!(component, "b");
            assert_eq!(*last_successful_time, 0.35);
            assert_eq!(*last_row_time, 0.35);
        }
        o => panic!("expected Terminated, got {o:?}"),
    }
    assert_eq!(
        out.results.len(),
        5,
        "rows at 0, 0.1, 0.2, 0.3 and b's end, 0.35"
    );
    let csv = d.path().join("terminated.csv");
    out.results.write_csv_file(&csv).unwrap();
    let text = std::fs::read_to_string(&csv).unwrap();
    assert_eq!(text.lines().count(), 6);
    assert!(text.starts_with("time,a.x,b.u,b.y,b.steps\n"));
    // b's values at its end (its input was set from a.x = 4 before the step that it ended);
    // a.x as last read (a stepped to 0.4 first, in Gauss-Seidel order).
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines[4], "0.3,3.0,3.0,6.5,3");
    assert_eq!(lines[5], "0.35,4.0,4.0,8.5,3");
}

#[test]
fn error_mid_run_stops_with_the_fmu_message_and_keeps_every_row() {
    let (d, fmu) = fmu();
    let mut s = two_fmu_system(&fmu);
    s.set_value_str("a.error_at", "0.25").unwrap();
    let out = s.run(&config(Algorithm::Jacobi, 1.0)).unwrap();
    match &out.outcome {
        Outcome::Failed(e) => {
            let m = e.to_string();
            assert!(m.contains("component 'a'"), "{m}");
            assert!(m.contains("fmi2DoStep returned Error"), "{m}");
            assert!(
                m.contains("error requested: t + h = 0.3 passes error_at = 0.25"),
                "{m}"
            );
        }
        o => panic!("expected Failed, got {o:?}"),
    }
    assert_eq!(out.results.len(), 3, "rows at 0, 0.1, 0.2");
    let csv = d.path().join("failed.csv");
    out.results.write_csv_file(&csv).unwrap();
    let back = kneebench_harness::Results::read_csv_file(&csv).unwrap();
    assert_eq!(back.len(), 3);
    assert_eq!(back.row(2), out.results.row(2));
}

#[test]
fn csv_round_trips_every_float_exactly() {
    let mut r = kneebench_harness::Results::with_capacity(
        vec!["a".into(), "n".into()],
        vec![
            kneebench_harness::results::ColumnKind::Real,
            kneebench_harness::results::ColumnKind::Integer,
        ],
        4,
    );
    let vals = [0.1 + 0.2, 1e-300, -2.5e17, std::f64::consts::PI];
    for (i, v) in vals.iter().enumerate() {
        r.push_row(i as f64 * 0.1, &[*v, i as f64]);
    }
    let mut buf = Vec::new();
    r.write_csv(&mut buf).unwrap();
    let back = kneebench_harness::Results::read_csv(&buf[..], std::path::Path::new("mem")).unwrap();
    assert_eq!(back, r);
    let table = r.summary_table();
    assert!(
        table.contains("signal") && table.contains("final"),
        "{table}"
    );
}

#[test]
fn instance_api_state_serialization_and_logging() {
    use std::sync::{Arc, Mutex};
    let (_d, fmu) = fmu();
    assert!(fmu.resource_uri().starts_with("file:///"));
    assert!(fmu.resource_uri().ends_with("/resources"));
    let seen = Arc::new(Mutex::new(Vec::new()));
    let seen2 = seen.clone();
    let opts = InstanceOptions {
        log_handler: Some(Arc::new(move |m: &kneebench_harness::LogMessage| {
            seen2.lock().unwrap().push(m.message.clone())
        })),
        ..InstanceOptions::default()
    };
    let mut i = fmu.instantiate("one", &opts).unwrap();
    {
        let log = seen.lock().unwrap();
        assert!(
            log[0].starts_with("instantiated one with resources at file:///"),
            "{log:?}"
        );
    }
    i.setup_experiment(None, 0.0, None).unwrap();
    i.set_real(&[0], &[2.0]).unwrap();
    i.enter_initialization_mode().unwrap();
    i.exit_initialization_mode().unwrap();
    i.do_step(0.0, 0.1).unwrap();
    let state = i.get_fmu_state().unwrap();
    let bytes = i.serialize_fmu_state(&state).unwrap();
    i.do_step(0.1, 0.1).unwrap();
    let mut x = [0.0];
    i.get_real(&[4], &mut x).unwrap();
    assert_eq!(x[0], 4.0);
    i.set_fmu_state(&state).unwrap();
    i.get_real(&[4], &mut x).unwrap();
    assert_eq!(x[0], 2.0);
    i.free_fmu_state(state).unwrap();
    i.do_step(0.1, 0.1).unwrap();
    let restored = i.deserialize_fmu_state(&bytes).unwrap();
    i.set_fmu_state(&restored).unwrap();
    i.get_real(&[4], &mut x).unwrap();
    assert_eq!(x[0], 2.0);
    i.free_fmu_state(restored).unwrap();
    let mut n = [0];
    i.get_integer(&[0], &mut n).unwrap();
    assert_eq!(n[0], 1);
    // Output derivatives are not exported by kbtest: a typed error, not a crash.
    assert!(
        i.get_real_output_derivatives(&[1], &[1], &mut [0.0])
            .is_err()
    );
    assert!(!i.terminated());
    assert_eq!(i.last_successful_time(), Some(0.1));
    // A wrong value reference is an fmi2Error with the instance name.
    let e = i.get_real(&[99], &mut x).unwrap_err();
    assert!(
        e.to_string()
            .contains("fmi2GetReal returned Error (instance 'one')"),
        "{e}"
    );
}

/// Three components where two stand side by side (so the parallel run steps them on threads)
/// in both algorithms, one at half the rate, with Real, Integer and Boolean connections and
/// records: the threaded path (each thread reading into its own part of the output buffers)
/// gives the same rows as the sequential one.
#[test]
fn parallel_multi_rate_run_with_every_type_gives_the_same_rows() {
    let (_d, fmu) = fmu();
    let mut s = System::new();
    for name in ["sink", "a", "b"] {
        s.add_component(name, fmu.clone()).unwrap();
    }
    s.set_value_str("a.u", "1").unwrap();
    s.set_value_str("b.u", "2").unwrap();
    s.set_value_str("sink.k", "3").unwrap();
    s.set_step_multiple("b", 2).unwrap();
    // a and b are independent: one level, stepped side by side; sink reads both.
    s.connect("a.x", "sink.u").unwrap();
    s.connect("b.steps", "sink.i_in").unwrap();
    s.connect("a.b_out", "sink.b_in").unwrap();
    s.set_value_str("a.i_in", "4").unwrap();
    s.record(&[
        "sink.y",
        "a.x",
        "b.x",
        "b.steps",
        "sink.i_out",
        "a.i_out",
        "sink.b_out",
        "a.b_out",
        "b.t",
    ])
    .unwrap();
    for alg in [Algorithm::GaussSeidel, Algorithm::Jacobi] {
        for record_every in [1, 3] {
            let config = RunConfig {
                record_every,
                ..config(alg, 1.2)
            };
            let seq = s.run(&config).unwrap();
            assert!(matches!(seq.outcome, Outcome::Completed { .. }));
            let par = s
                .run(&RunConfig {
                    parallel: true,
                    ..config.clone()
                })
                .unwrap();
            assert_eq!(seq.results, par.results, "{alg:?}, every {record_every}");
            assert_eq!(seq.steps_per_component, par.steps_per_component);
            assert_eq!(seq.steps_per_component, vec![12, 12, 6]);
            // The Integer and Boolean values moved: sink.i_out = 2 b.steps (held between b's
            // steps), sink.b_out = !a.b_out.
            let r = &seq.results;
            let col = |name: &str| r.column(name).unwrap();
            assert!(col("b.steps").iter().any(|&v| v > 0.0));
            assert!(
                col("sink.b_out")
                    .iter()
                    .zip(col("a.b_out"))
                    .all(|(s, a)| s + a == 1.0)
            );
        }
    }
}

/// A cycle through outputs without direct feedthrough (`a.x -> b.u`, `b.x -> a.u`) has no
/// dependency level between `a` and `b`, yet the sequential order (a, then b) hands b the `x`
/// that a computed in the same step. `--parallel` must step them one after the other (and
/// may step `c`, fed by neither, with `a`): the rows are the sequential ones, bit for bit.
#[test]
fn parallel_follows_every_connection_and_equals_sequential() {
    let (_d, fmu) = fmu();
    let mut s = System::new();
    for name in ["a", "b", "c"] {
        s.add_component(name, fmu.clone()).unwrap();
    }
    s.set_value_str("a.b", "0.25").unwrap();
    s.set_value_str("c.u", "2").unwrap();
    s.connect("a.x", "b.u").unwrap();
    s.connect("b.x", "a.u").unwrap();
    s.connect("a.y", "c.i_in").unwrap_err();
    s.connect("b.i_out", "c.i_in").unwrap();
    s.set_value_str("b.i_in", "3").unwrap();
    // a.x starts at 1 so the loop moves: x_a += u_a = x_b, x_b += u_b = x_a.
    s.set_value_str("a.x", "1").unwrap();
    let (order, _) = s.dependency_order().unwrap();
    assert_eq!(order, [0, 1, 2]);
    assert_eq!(
        s.parallel_groups(&order, Algorithm::GaussSeidel),
        [vec![0], vec![1], vec![2]],
        "b is fed by a, c by b"
    );
    // Without the b -> c connection, c joins b's group.
    let mut free = System::new();
    for name in ["a", "b", "c"] {
        free.add_component(name, fmu.clone()).unwrap();
    }
    free.connect("a.x", "b.u").unwrap();
    free.connect("b.x", "a.u").unwrap();
    assert_eq!(
        free.parallel_groups(&[0, 1, 2], Algorithm::GaussSeidel),
        [vec![0], vec![1, 2]]
    );
    assert_eq!(
        free.parallel_groups(&[0, 1, 2], Algorithm::Jacobi),
        [vec![0, 1, 2]]
    );

    let bits = |r: &kneebench_harness::Results| -> Vec<Vec<u64>> {
        r.rows()
            .map(|row| row.iter().map(|v| v.to_bits()).collect())
            .collect()
    };
    for algorithm in [Algorithm::GaussSeidel, Algorithm::Jacobi] {
        let sequential = s.run(&config(algorithm, 2.0)).unwrap();
        let parallel = s
            .run(&RunConfig {
                parallel: true,
                ..config(algorithm, 2.0)
            })
            .unwrap();
        assert!(matches!(sequential.outcome, Outcome::Completed { .. }));
        assert!(matches!(parallel.outcome, Outcome::Completed { .. }));
        assert_eq!(sequential.results.len(), 21);
        assert!(
            bits(&sequential.results) == bits(&parallel.results),
            "{algorithm:?}: parallel rows differ from the sequential ones"
        );
    }
    // Gauss-Seidel: b sees a's fresh x (with a's x from the start of the step it would
    // be 2 at row 2, as the dependency-level grouping had it).
    let gs = s.run(&config(Algorithm::GaussSeidel, 2.0)).unwrap();
    let bx = gs.results.column("b.x").unwrap();
    let ax = gs.results.column("a.x").unwrap();
    assert_eq!([ax[1], bx[1], ax[2], bx[2]], [1.0, 1.0, 2.0, 3.0]);
}

/// Connections and signals with the wrong end name the variable's causality as the model
/// description spells it, with its article ("not an input variable"); a value that does not
/// parse names the variable's type likewise ("not an Integer"). They read "not a Input
/// variable" and "not a Integer".
#[test]
fn wrong_ends_and_values_are_named_with_their_article() {
    let (_d, fmu) = fmu();
    let mut s = System::new();
    s.add_component("a", fmu.clone()).unwrap();
    s.add_component("b", fmu).unwrap();
    for (result, needle) in [
        (
            s.connect("a.u", "b.u"),
            "a connection starts at an output, not an input variable",
        ),
        (
            s.connect("a.y", "b.y"),
            "a connection ends at an input, not an output variable",
        ),
        (
            s.connect("a.y", "b.k"),
            "a connection ends at an input, not a parameter variable",
        ),
        (
            s.add_signal(
                "a.x",
                Signal {
                    times: vec![0.0],
                    values: vec![1.0],
                    interpolate: false,
                },
            ),
            "a signal feeds an input, not an output variable",
        ),
        (s.set_value_str("a.i_in", "1.5"), "'1.5' is not an Integer"),
        (s.set_value_str("a.k", "x"), "'x' is not a Real"),
        (s.set_value_str("a.b_in", "yes"), "'yes' is not a Boolean"),
    ] {
        let e = result.unwrap_err().to_string();
        assert!(e.contains(needle), "{e}");
    }
}

/// A later value of a variable replaces the earlier one instead of joining it: only the last
/// is applied, so a long-lived system set again and again keeps one value per variable and a
/// value the FMU refused is not applied again once it is replaced. (The values used to pile
/// up, every run applying all of them in order: a refused one failed every later run.)
#[test]
fn a_later_value_replaces_the_earlier_one() {
    let dir = tempfile::tempdir().unwrap();
    let fmus = common::exported_fmus(Path::new(env!("CARGO_BIN_EXE_kneebench")), dir.path());
    let pid = Fmu::load(fmus.join("PidController.fmu"), &LoadOptions::default()).unwrap();
    let mut s = System::new();
    s.add_component("pid", pid).unwrap();
    // u = kp (setpoint - measurement) = kp: a proportional controller, error 1.
    for (name, value) in [("ki", 0.0), ("kd", 0.0), ("setpoint", 1.0)] {
        s.set_value(&format!("pid.{name}"), Value::Real(value))
            .unwrap();
    }
    s.record(&["pid.u"]).unwrap();
    let config = RunConfig {
        stop_time: 0.01,
        step_size: 1e-3,
        ..RunConfig::default()
    };
    let u = |out: &kneebench_harness::RunOutput| {
        assert!(
            matches!(out.outcome, Outcome::Completed { .. }),
            "{:?}",
            out.outcome
        );
        out.results.row(out.results.len() - 1)[1]
    };

    // A value the FMU refuses (not finite) fails the run at its set...
    s.set_value("pid.kp", Value::Real(f64::NAN)).unwrap();
    let out = s.run(&config).unwrap();
    let Outcome::Failed(e) = &out.outcome else {
        panic!("expected Failed, got {:?}", out.outcome)
    };
    assert!(e.to_string().contains("kp"), "{e}");
    // ...and once replaced it is not applied again: the next run has only the new value.
    s.set_value("pid.kp", Value::Real(2.0)).unwrap();
    assert_eq!(u(&s.run(&config).unwrap()), 2.0);

    // Set many times (refused values in between): one value, the last, is applied.
    for n in 0..1000 {
        s.set_value("pid.kp", Value::Real(f64::NAN)).unwrap();
        s.set_value("pid.kp", Value::Real(f64::from(n % 7) + 1.0))
            .unwrap();
        s.set_value("pid.kp", Value::Real(f64::INFINITY)).unwrap();
    }
    s.set_value("pid.kp", Value::Real(3.0)).unwrap();
    assert_eq!(u(&s.run(&config).unwrap()), 3.0);
}

#[test]
fn record_also_appends_to_the_outputs_or_to_the_chosen_variables() {
    let (_d, fmu) = fmu();
    let mut s = System::new();
    s.add_component("a", fmu.clone()).unwrap();
    s.set_value_str("a.u", "1").unwrap();
    s.set_value_str("a.k", "3").unwrap();
    // Without an earlier choice: every output, then the parameter and the input.
    s.record_also(&["a.k", "a.u"]).unwrap();
    let out = s.run(&config(Algorithm::GaussSeidel, 0.2)).unwrap();
    let r = &out.results;
    assert_eq!(
        r.names(),
        [
            "a.y", "a.x", "a.t", "a.steps", "a.i_out", "a.b_out", "a.k", "a.u"
        ]
    );
    assert_eq!(r.column("a.k").unwrap(), [3.0; 3]);
    assert_eq!(r.column("a.u").unwrap(), [1.0; 3]);
    // After a choice: appended to it. A bad reference is refused and changes nothing.
    s.record(&["a.x"]).unwrap();
    assert!(s.record_also(&["a.k", "a.nope"]).is_err());
    s.record_also(&["a.steps"]).unwrap();
    let out = s.run(&config(Algorithm::GaussSeidel, 0.2)).unwrap();
    assert_eq!(out.results.names(), ["a.x", "a.steps"]);
}
