//! Unit tests of the master's run-time tables (plan, bus, rows).

use super::Signal;

use super::plan::{Bus, InValues, Plan, RowCopies, RowRun, fill_row, row_runs, steps_at, ty_index};
use super::{VarRef, VarType};
use crate::results::{ColumnKind, Results};
use std::collections::{BTreeMap, HashMap};

/// Appends the row at `t` built from `bus` by `row` to `out`, as the master hands it to its sink.
fn record_row(out: &mut Results, row: &RowCopies, bus: &Bus, t: f64) {
    let mut values = vec![0.0; row.len];
    fill_row(&mut values, row, bus);
    out.push_row(t, &values);
}

const R: VarType = VarType::Real;
const I: VarType = VarType::Integer;
const B: VarType = VarType::Boolean;

fn var(comp: usize, vr: u32, ty: VarType) -> VarRef {
    VarRef {
        comp,
        vr,
        ty,
        name: format!("c{comp}.v{vr}"),
    }
}

/// Three components with `Real`, `Integer` and `Boolean` outputs, connections of every
/// type (one of them backwards: 2 -> 0), signal-fed inputs of every type, and a recorded
/// list in mixed order with a duplicate and an input.
struct Case {
    recorded: Vec<VarRef>,
    connections: Vec<(VarRef, VarRef)>,
    signals: Vec<(VarRef, Signal)>,
    multiples: Vec<u64>,
}

fn case() -> Case {
    let conn = |s: (usize, u32, VarType), d: (usize, u32)| (var(s.0, s.1, s.2), var(d.0, d.1, s.2));
    let ramp = Signal {
        times: vec![0.0, 1.0],
        values: vec![-1.5, 2.5],
        interpolate: true,
    };
    let steps = Signal {
        times: vec![0.0, 0.25, 0.6],
        values: vec![0.0, 3.0, 0.0],
        interpolate: false,
    };
    Case {
        recorded: vec![
            var(0, 1, R),
            var(0, 2, R),
            var(0, 10, I),
            var(0, 20, B),
            var(1, 1, R),
            var(1, 2, R),
            var(0, 3, R),
            var(1, 21, B),
            var(1, 11, I),
            var(0, 1, R),
            var(2, 100, R),
            var(2, 5, R),
            var(2, 22, B),
            var(1, 11, I),
        ],
        connections: vec![
            conn((0, 1, R), (1, 100)),
            conn((2, 5, R), (0, 100)),
            conn((0, 10, I), (1, 110)),
            conn((0, 3, R), (1, 101)),
            conn((0, 20, B), (1, 120)),
            conn((1, 11, I), (2, 110)),
            conn((1, 2, R), (2, 101)),
        ],
        signals: vec![
            (var(2, 100, R), ramp.clone()),
            (var(2, 120, B), steps.clone()),
            (var(2, 111, I), ramp),
        ],
        multiples: vec![1, 2, 3],
    }
}

fn plan(c: &Case) -> Plan {
    let fed: Vec<&VarRef> = c.signals.iter().map(|(d, _)| d).collect();
    Plan::new(c.multiples.len(), &c.recorded, &c.connections, &fed)
}

/// A stand-in for an FMU: the value of output `vr` of type `ty` after step `n`, from the
/// inputs (keyed by type index and value reference, booleans as 0/1). Booleans come out
/// as 0 or 5 (any non-zero `fmi2Boolean` is true).
fn output(ty: usize, vr: u32, n: u64, inputs: &BTreeMap<(usize, u32), f64>) -> f64 {
    let sum: f64 = inputs.values().sum();
    match ty {
        0 => vr as f64 + n as f64 * 0.5 + sum * 0.25,
        1 => (vr as i64 + n as i64 + sum.floor() as i64) as i32 as f64,
        _ => {
            if (u64::from(vr) + n + sum.abs() as u64).is_multiple_of(3) {
                0.0
            } else {
                5.0
            }
        }
    }
}

fn results(c: &Case) -> Results {
    let kinds = c
        .recorded
        .iter()
        .map(|r| match r.ty {
            VarType::Real => ColumnKind::Real,
            VarType::Integer => ColumnKind::Integer,
            _ => ColumnKind::Boolean,
        })
        .collect();
    Results::with_capacity(
        c.recorded.iter().map(|r| r.name.clone()).collect(),
        kinds,
        0,
    )
}

fn bits(r: &Results) -> Vec<Vec<u64>> {
    r.rows()
        .map(|row| row.iter().map(|v| v.to_bits()).collect())
        .collect()
}

/// Writes component `c`'s outputs after step `n` onto the bus, as the master's `read`.
fn step_on_bus(plan: &Plan, bus: &mut Bus, c: usize, n: u64, inputs: &InValues) {
    let p = &plan.ports[c];
    let mut ins = BTreeMap::new();
    for (&vr, &x) in p.in_vrs[0].iter().zip(&inputs.real) {
        ins.insert((0, vr), x);
    }
    for (&vr, &x) in p.in_vrs[1].iter().zip(&inputs.int) {
        ins.insert((1, vr), x as f64);
    }
    for (&vr, &x) in p.in_vrs[2].iter().zip(&inputs.boolean) {
        ins.insert((2, vr), x as f64);
    }
    for (k, &vr) in p.out_vrs[0].iter().enumerate() {
        bus.real[p.out[0].0 + k] = output(0, vr, n, &ins);
    }
    for (k, &vr) in p.out_vrs[1].iter().enumerate() {
        bus.int[p.out[1].0 + k] = output(1, vr, n, &ins) as i32;
    }
    for (k, &vr) in p.out_vrs[2].iter().enumerate() {
        bus.boolean[p.out[2].0 + k] = output(2, vr, n, &ins) as i32;
    }
}

/// The rows of a run through the plan: inputs gathered by bus index, rows by runs.
fn run_on_bus(c: &Case, jacobi: bool, steps: u64) -> Results {
    let plan = plan(c);
    let signals: Vec<Signal> = c.signals.iter().map(|(_, s)| s.clone()).collect();
    let mut bus = Bus::new(plan.bus_len);
    let mut inputs: Vec<InValues> = plan
        .ports
        .iter()
        .map(|q| InValues::for_ports(q, &signals))
        .collect();
    for (i, v) in inputs.iter().enumerate() {
        step_on_bus(&plan, &mut bus, i, 0, v);
    }
    let mut out = results(c);
    record_row(&mut out, &plan.copies, &bus, 0.0);
    for n in 0..steps {
        let t = n as f64 * 0.1;
        let due: Vec<usize> = (0..c.multiples.len())
            .filter(|&i| steps_at(n, c.multiples[i]))
            .collect();
        if jacobi {
            for &i in &due {
                inputs[i].gather(&plan.ports[i], &bus, &signals, t);
            }
            for &i in &due {
                step_on_bus(&plan, &mut bus, i, n + 1, &inputs[i]);
            }
        } else {
            for &i in &due {
                inputs[i].gather(&plan.ports[i], &bus, &signals, t);
                step_on_bus(&plan, &mut bus, i, n + 1, &inputs[i]);
            }
        }
        record_row(&mut out, &plan.copies, &bus, (n + 1) as f64 * 0.1);
    }
    out
}

/// The same run the naive way: every value looked up by (component, type, value
/// reference), every input per connection, every recorded value pushed on its own.
fn run_naive(c: &Case, jacobi: bool, steps: u64) -> Results {
    let n_comps = c.multiples.len();
    // What each component reads after a step: its recorded and connected outputs.
    let mut reads: Vec<Vec<(usize, u32)>> = vec![Vec::new(); n_comps];
    for r in c
        .recorded
        .iter()
        .chain(c.connections.iter().map(|(s, _)| s))
    {
        let key = (ty_index(r.ty), r.vr);
        if !reads[r.comp].contains(&key) {
            reads[r.comp].push(key);
        }
    }
    let mut values: HashMap<(usize, usize, u32), f64> = HashMap::new();
    let step = |values: &mut HashMap<_, _>, i: usize, n: u64, ins: &BTreeMap<_, _>| {
        for &(ty, vr) in &reads[i] {
            values.insert((i, ty, vr), output(ty, vr, n, ins));
        }
    };
    let inputs_of = |values: &HashMap<(usize, usize, u32), f64>, i: usize, t: f64| {
        let mut ins = BTreeMap::new();
        for (s, d) in c.connections.iter().filter(|(_, d)| d.comp == i) {
            let ty = ty_index(s.ty);
            let v = values[&(s.comp, ty, s.vr)];
            ins.insert(
                (ty, d.vr),
                if ty == 2 { (v != 0.0) as i32 as f64 } else { v },
            );
        }
        for (d, s) in c.signals.iter().filter(|(d, _)| d.comp == i) {
            let x = s.at(t);
            let v = match d.ty {
                VarType::Real => x,
                VarType::Integer => x.round() as i32 as f64,
                _ => (x != 0.0) as i32 as f64,
            };
            ins.insert((ty_index(d.ty), d.vr), v);
        }
        ins
    };
    let record = |out: &mut Results, values: &HashMap<(usize, usize, u32), f64>, t: f64| {
        out.push_time(t);
        for r in &c.recorded {
            let ty = ty_index(r.ty);
            let v = values[&(r.comp, ty, r.vr)];
            out.push_value(if ty == 2 { (v != 0.0) as i32 as f64 } else { v });
        }
    };
    // Initial values: every input still at zero.
    let zeros = |i: usize| -> BTreeMap<(usize, u32), f64> {
        c.connections
            .iter()
            .map(|(_, d)| d)
            .chain(c.signals.iter().map(|(d, _)| d))
            .filter(|d| d.comp == i)
            .map(|d| ((ty_index(d.ty), d.vr), 0.0))
            .collect()
    };
    for i in 0..n_comps {
        step(&mut values, i, 0, &zeros(i));
    }
    let mut out = results(c);
    record(&mut out, &values, 0.0);
    for n in 0..steps {
        let t = n as f64 * 0.1;
        let due: Vec<usize> = (0..n_comps)
            .filter(|&i| n.is_multiple_of(c.multiples[i]))
            .collect();
        if jacobi {
            let ins: Vec<_> = due.iter().map(|&i| inputs_of(&values, i, t)).collect();
            for (&i, ins) in due.iter().zip(&ins) {
                step(&mut values, i, n + 1, ins);
            }
        } else {
            for &i in &due {
                let ins = inputs_of(&values, i, t);
                step(&mut values, i, n + 1, &ins);
            }
        }
        record(&mut out, &values, (n + 1) as f64 * 0.1);
    }
    out
}

#[test]
fn row_runs_join_consecutive_bus_values_of_one_type() {
    let columns = [
        (0, 0),
        (0, 1),
        (0, 2),
        (1, 0),
        (0, 3),
        (0, 3),
        (2, 0),
        (2, 1),
        (1, 1),
    ];
    assert_eq!(
        row_runs(&columns),
        [
            RowRun::Real(0, 3),
            RowRun::Integer(0, 1),
            RowRun::Real(3, 4),
            RowRun::Real(3, 4),
            RowRun::Boolean(0, 2),
            RowRun::Integer(1, 2),
        ]
    );
    assert_eq!(row_runs(&[]), []);
}

#[test]
fn the_plan_reads_each_value_once_and_lays_components_out_in_order() {
    let c = case();
    let p = plan(&c);
    // Recorded first (in recording order), then connected; each once.
    assert_eq!(p.ports[0].out_vrs, [vec![1, 2, 3], vec![10], vec![20]]);
    assert_eq!(p.ports[1].out_vrs, [vec![1, 2], vec![11], vec![21]]);
    assert_eq!(p.ports[2].out_vrs, [vec![100, 5], vec![], vec![22]]);
    assert_eq!(p.ports[0].out, [(0, 3), (0, 1), (0, 1)]);
    assert_eq!(p.ports[1].out, [(3, 5), (1, 2), (1, 2)]);
    assert_eq!(p.ports[2].out, [(5, 7), (2, 2), (2, 3)]);
    assert_eq!(p.bus_len, [7, 2, 3]);
    // Connected inputs in connection order, then the signal-fed ones.
    assert_eq!(p.ports[1].in_vrs, [vec![100, 101], vec![110], vec![120]]);
    assert_eq!(p.ports[1].in_from, [vec![0, 2], vec![0], vec![0]]);
    assert_eq!(
        p.ports[2].in_vrs,
        [vec![101, 100], vec![110, 111], vec![120]]
    );
    assert_eq!(p.ports[2].in_from, [vec![4], vec![1], vec![]]);
    assert_eq!(p.ports[2].in_signals, [(0, 1, 0), (2, 0, 1), (1, 1, 2)]);
    assert_eq!(p.ports[0].in_from, [vec![6], vec![], vec![]]);
    assert!(!p.ports[0].in_rare && p.ports[1].in_rare && p.ports[2].in_rare);
    assert_eq!(
        p.row,
        [
            RowRun::Real(0, 2),
            RowRun::Integer(0, 1),
            RowRun::Boolean(0, 1),
            RowRun::Real(3, 5),
            RowRun::Real(2, 3),
            RowRun::Boolean(1, 2),
            RowRun::Integer(1, 2),
            RowRun::Real(0, 1),
            RowRun::Real(5, 7),
            RowRun::Boolean(2, 3),
            RowRun::Integer(1, 2),
        ]
    );
}

#[test]
fn gathered_inputs_are_the_sources_values() {
    let c = case();
    let p = plan(&c);
    let signals: Vec<Signal> = c.signals.iter().map(|(_, s)| s.clone()).collect();
    let mut bus = Bus::new(p.bus_len);
    let mut naive: HashMap<(usize, usize, u32), f64> = HashMap::new();
    for (i, q) in p.ports.iter().enumerate() {
        for (k, &vr) in q.out_vrs[0].iter().enumerate() {
            let v = 0.5 + (i * 100 + k) as f64;
            bus.real[q.out[0].0 + k] = v;
            naive.insert((i, 0, vr), v);
        }
        for (k, &vr) in q.out_vrs[1].iter().enumerate() {
            let v = -7 - (i * 10 + k) as i32;
            bus.int[q.out[1].0 + k] = v;
            naive.insert((i, 1, vr), v as f64);
        }
        for (k, &vr) in q.out_vrs[2].iter().enumerate() {
            let v = 3 * (i + k) as i32;
            bus.boolean[q.out[2].0 + k] = v;
            naive.insert((i, 2, vr), v as f64);
        }
    }
    let t = 0.3;
    for (i, q) in p.ports.iter().enumerate() {
        let mut v = InValues::for_ports(q, &signals);
        v.gather(q, &bus, &signals, t);
        let value = |ty: usize, vr: u32| -> f64 {
            let k = q.in_vrs[ty].iter().position(|&x| x == vr).unwrap();
            match ty {
                0 => v.real[k],
                1 => v.int[k] as f64,
                _ => v.boolean[k] as f64,
            }
        };
        for (s, d) in c.connections.iter().filter(|(_, d)| d.comp == i) {
            let ty = ty_index(s.ty);
            let x = naive[&(s.comp, ty, s.vr)];
            let want = if ty == 2 { (x != 0.0) as i32 as f64 } else { x };
            assert_eq!(value(ty, d.vr).to_bits(), want.to_bits(), "{}", d.name);
        }
        for (d, s) in c.signals.iter().filter(|(d, _)| d.comp == i) {
            let want = match d.ty {
                VarType::Real => s.at(t),
                VarType::Integer => s.at(t).round() as i32 as f64,
                _ => (s.at(t) != 0.0) as i32 as f64,
            };
            assert_eq!(
                value(ty_index(d.ty), d.vr).to_bits(),
                want.to_bits(),
                "{}",
                d.name
            );
        }
    }
}

#[test]
fn rows_from_runs_match_per_value_pushes_gauss_seidel_and_jacobi_multi_rate() {
    let c = case();
    for jacobi in [false, true] {
        let bus = run_on_bus(&c, jacobi, 12);
        let naive = run_naive(&c, jacobi, 12);
        assert_eq!(bus.len(), 13);
        assert_eq!(bits(&bus), bits(&naive), "jacobi = {jacobi}");
    }
    // Single-rate too.
    let mut single = case();
    single.multiples = vec![1, 1, 1];
    for jacobi in [false, true] {
        assert_eq!(
            bits(&run_on_bus(&single, jacobi, 7)),
            bits(&run_naive(&single, jacobi, 7))
        );
    }
}

#[test]
fn the_bus_splits_into_the_components_ranges() {
    let p = plan(&case());
    let mut bus = Bus::new(p.bus_len);
    let outs = bus.split(p.ports.iter().map(|q| q.out));
    assert_eq!(outs.len(), 3);
    for (i, o) in outs.into_iter().enumerate() {
        assert_eq!(o.real.len(), p.ports[i].out_vrs[0].len());
        assert_eq!(o.int.len(), p.ports[i].out_vrs[1].len());
        assert_eq!(o.boolean.len(), p.ports[i].out_vrs[2].len());
        o.real.fill(i as f64);
        o.int.fill(i as i32);
        o.boolean.fill(i as i32);
    }
    for (i, q) in p.ports.iter().enumerate() {
        assert!(
            bus.real[q.out[0].0..q.out[0].1]
                .iter()
                .all(|&x| x == i as f64)
        );
        assert!(
            bus.int[q.out[1].0..q.out[1].1]
                .iter()
                .all(|&x| x == i as i32)
        );
        assert!(
            bus.boolean[q.out[2].0..q.out[2].1]
                .iter()
                .all(|&x| x == i as i32)
        );
    }
}

#[test]
fn a_sample_one_ulp_after_the_grid_time_counts_as_at_it() {
    // 0.001 * 9 is 0.009000000000000001, the grid time 9/1000 is 0.009 (1 ulp less).
    let t_grid = 9.0 / 1000.0;
    let t_sample = 0.001 * 9.0;
    assert!(t_sample > t_grid);
    for interpolate in [false, true] {
        let s = Signal {
            times: vec![0.0, 0.002, t_sample, 0.01],
            values: vec![0.0, 2.0, 9.0, 10.0],
            interpolate,
        };
        assert_eq!(s.at(t_grid), 9.0, "interpolate = {interpolate}");
        assert_eq!(s.at(0.001), if interpolate { 1.0 } else { 0.0 });
    }
}

/// `RunConfig::with_times` (the one copy of a default experiment's times, an FMU's or an
/// SSP's): each time given replaces the configuration's, the others and every other setting
/// are kept.
#[test]
fn a_default_experiment_replaces_only_the_times_it_gives() {
    use super::{Algorithm, RunConfig};
    let base = RunConfig {
        algorithm: Algorithm::Jacobi,
        tolerance: Some(1e-6),
        ..RunConfig::default()
    };
    let c = base.clone().with_times(Some(-1.0), None, Some(0.25));
    assert_eq!(
        (c.start_time, c.stop_time, c.step_size),
        (-1.0, base.stop_time, 0.25)
    );
    assert_eq!((c.algorithm, c.tolerance), (Algorithm::Jacobi, Some(1e-6)));
    let c = base.clone().with_times(None, Some(5.0), None);
    assert_eq!(
        (c.start_time, c.stop_time, c.step_size),
        (base.start_time, 5.0, base.step_size)
    );
    let c = base.clone().with_times(None, None, None);
    assert_eq!(
        (c.start_time, c.stop_time, c.step_size),
        (base.start_time, base.stop_time, base.step_size)
    );
}

/// `Value::to_text` reads back as the same value (`Value::parse`): Reals exactly.
#[test]
fn a_value_as_text_reads_back_as_itself() {
    use super::Value;
    for v in [
        Value::Real(0.1 + 0.2),
        Value::Real(-1e-300),
        Value::Real(1e5),
        Value::Integer(-7),
        Value::Boolean(true),
        Value::Boolean(false),
        Value::String(" a b ".into()),
    ] {
        let ty = match v {
            Value::Real(_) => VarType::Real,
            Value::Integer(_) => VarType::Integer,
            Value::Boolean(_) => VarType::Boolean,
            Value::String(_) => VarType::String,
        };
        assert_eq!(Value::parse(ty, &v.to_text()), Some(v.clone()), "{v:?}");
    }
}

/// `RunConfig::of_fmu` (a single FMU's run, the CLI's and the Python package's): the default
/// experiment's times and its tolerance, the defaults for what it leaves out.
#[test]
fn a_single_fmus_run_takes_its_default_experiments_times_and_tolerance() {
    use super::RunConfig;
    use model_description::{DefaultExperiment, ModelDescription};
    let mut md = ModelDescription::new("m", "{g}");
    let c = RunConfig::of_fmu(&md);
    assert_eq!(
        (c.start_time, c.stop_time, c.step_size, c.tolerance),
        (0.0, 1.0, 1e-3, None)
    );
    md.default_experiment = Some(DefaultExperiment {
        start_time: None,
        stop_time: Some(2.0),
        tolerance: Some(1e-5),
        step_size: Some(0.01),
    });
    let c = RunConfig::of_fmu(&md);
    assert_eq!(
        (c.start_time, c.stop_time, c.step_size, c.tolerance),
        (0.0, 2.0, 0.01, Some(1e-5))
    );
}

#[test]
fn all_finite_is_every_value_finite() {
    use super::step::all_finite;
    let specials = [
        0.0,
        -0.0,
        1.0,
        -1.5,
        f64::MAX,
        f64::MIN,
        f64::MIN_POSITIVE,
        f64::from_bits(1),
        f64::from_bits(0x7fef_ffff_ffff_ffff),
        f64::from_bits(0xffef_ffff_ffff_ffff),
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NAN,
        -f64::NAN,
        f64::from_bits(0x7ff0_0000_0000_0001),
        f64::from_bits(0xfff8_0000_0000_0001),
    ];
    // Every special value alone and at every place of a longer run of finite values (the
    // vectorized loop's body and its remainder).
    for &x in &specials {
        assert_eq!(all_finite(&[x]), x.is_finite(), "{x:?}");
        for len in 1..20 {
            for at in 0..len {
                let mut v: Vec<f64> = (0..len).map(|k| k as f64 * 0.75 - 3.0).collect();
                v[at] = x;
                assert_eq!(all_finite(&v), x.is_finite(), "{x:?} at {at} of {len}");
            }
        }
    }
    assert!(all_finite(&[]));
}

/// A fixed-seed generator for the signal tests (`fastrand`'s, already tempfile's dependency).
type Rng = fastrand::Rng;

/// Sorted series as input files give them: decimal times on a grid (some repeated, a
/// discontinuity), times a last bit off the grid, irregular gaps, one sample, none.
fn sorted_signals(rng: &mut Rng) -> Vec<Signal> {
    let mut out = Vec::new();
    for case in 0..40 {
        let n = match case {
            0 => 0,
            1 => 1,
            _ => 2 + rng.u64(..300) as usize,
        };
        let mut times = Vec::with_capacity(n);
        let mut t = if case % 5 == 0 { -1.5 } else { 0.0 };
        for k in 0..n {
            match rng.u64(..10) {
                // A discontinuity: the same time twice.
                0 if k > 0 => {}
                // Within the tolerance of the previous sample.
                1 if k > 0 => t += 1e-12,
                2 => t += 0.001 * (1 + rng.u64(..7)) as f64,
                _ => t = (t * 1000.0).round() / 1000.0 + 0.001,
            }
            times.push(t);
        }
        let values = (0..n)
            .map(|_| (rng.u64(..2001) as f64 - 1000.0) * 0.37)
            .collect();
        out.push(Signal {
            times,
            values,
            interpolate: case % 3 != 0,
        });
    }
    out
}

#[test]
fn the_cursor_search_is_the_whole_search_bit_for_bit() {
    let mut rng = Rng::with_seed(0x9e37_79b9_7f4a_7c15);
    for signal in sorted_signals(&mut rng) {
        assert!(signal.has_sorted_times());
        // The run's grid (times from integer ticks) at steps finer than, equal to and coarser
        // than the series', from before its start to past its end; then random times, mostly
        // forward, sometimes back, sometimes far ahead, and a NaN.
        for h in [0.0003, 0.001, 0.0025, 0.04] {
            let mut cursor = 0;
            for k in -5..((0.5 / h) as i64) {
                let t = k as f64 * h;
                let (fast, plain) = (signal.at_from(t, &mut cursor), signal.at(t));
                assert_eq!(fast.to_bits(), plain.to_bits(), "t = {t}, h = {h}");
            }
        }
        let mut cursor = 0;
        let mut t = -2.0;
        for _ in 0..2000 {
            t = match rng.u64(..20) {
                0 => t - 0.001 * rng.u64(..100) as f64,
                1 => t + 0.01 * rng.u64(..100) as f64,
                2 => f64::NAN,
                _ if t.is_nan() => 0.0,
                _ => t + 0.0005 * rng.u64(..4) as f64,
            };
            let (fast, plain) = (signal.at_from(t, &mut cursor), signal.at(t));
            assert_eq!(fast.to_bits(), plain.to_bits(), "t = {t}");
        }
    }
}

#[test]
fn an_unsorted_signal_is_sampled_by_the_whole_search() {
    let unsorted = [
        Signal {
            times: vec![0.0, 0.002, 0.001, 0.003],
            values: vec![1.0, 2.0, 3.0, 4.0],
            interpolate: true,
        },
        Signal {
            times: vec![0.0, f64::NAN, 0.002],
            values: vec![1.0, 2.0, 3.0],
            interpolate: false,
        },
    ];
    for signal in &unsorted {
        assert!(!signal.has_sorted_times());
    }
    assert!(
        Signal {
            times: vec![0.0, 0.001, 0.001, 0.002],
            values: vec![0.0; 4],
            interpolate: true
        }
        .has_sorted_times()
    );
    // Through the master's gather: the case's signal-fed inputs, their signals replaced by
    // the unsorted ones, take exactly `at`'s values at every time.
    let c = case();
    let p = plan(&c);
    let q = &p.ports[2];
    let mut signals: Vec<Signal> = c.signals.iter().map(|(_, s)| s.clone()).collect();
    signals[0] = unsorted[0].clone();
    signals[1] = unsorted[1].clone();
    let bus = Bus::new(p.bus_len);
    let mut v = InValues::for_ports(q, &signals);
    for k in 0..5 {
        let t = k as f64 * 0.0007;
        v.gather(q, &bus, &signals, t);
        for &(ty, k, s) in &q.in_signals {
            let want = signals[s].at(t);
            let got = match ty {
                0 => v.real[k],
                1 => v.int[k] as f64,
                _ => v.boolean[k] as f64,
            };
            let want = match ty {
                0 => want,
                1 => want.round(),
                _ => (want != 0.0) as i32 as f64,
            };
            assert_eq!(got.to_bits(), want.to_bits(), "t = {t}, signal {s}");
        }
    }
}
