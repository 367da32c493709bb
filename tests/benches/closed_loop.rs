//! The SEA (and CSEA) closed loop of the study, one gait cycle at 1 kHz: `cargo bench -p kneebench-tests
//! --bench closed_loop`.
//!
//! The system is the study's SEA scenario (`gait_scenario(Sea, ...)` with the tuned gains): the
//! gait reference, the position loop, the torque loop and the plant, 4 FMU instances (the
//! loops take the reference velocity, acceleration and torque on their auxiliary inputs, so no
//! summing blocks), 2500 steps of 1 ms. Measured twice: recording the 13 signals the study's
//! analysis reads (`Columns::names`, what a tuning loop needs), and recording every output of
//! every component (what `kneebench study` writes to its CSV).
//!
//! - **harness**: `System::run` of the scenario's `.ssp`, loaded once (FMUs extracted, binaries
//!   opened), Gauss-Seidel, sequential; the whole call: instantiate, initialize, step, record,
//!   terminate, free. The median over the repeats is the steady state; the first run after
//!   loading is reported on its own (it also pays the binaries' one-time lazy initialization:
//!   model tables, GUIDs, the plant's shared discretisations). The steady-state real-time
//!   factor is the headline figure (target > 1000x).
//! - **plain**: a Rust loop calling the same C functions of the same extracted binaries in the
//!   same order: instantiate, set the parameters, initialize; per step and component (in
//!   declaration order, which is the master's Gauss-Seidel order here) `fmi2SetReal` of the
//!   connected inputs, `fmi2DoStep`, the gets of the same outputs the master reads (connected
//!   and recorded) into a preallocated row buffer. Run twice per repeat: untimed (the floor a
//!   master could reach with these FMUs), and with each `fmi2SetReal`, `fmi2DoStep` and each
//!   component's gets timed on their own (`Instant` pairs), which gives the FMUs' own time in
//!   the same run, less the clock reads' cost (the mean of an empty timed interval, ~23 ns
//!   here, measured in the same run).
//!
//! Reported (medians of [`REPEATS`] interleaved repeats): the real-time factors, the sums of the
//! FMUs' `fmi2DoStep` time, of their output gets (the FMUs compute outputs lazily on the first
//! get after a step, so that is FMU time too) and of the input sets, the plant's part, and the
//! master's share: harness - untimed plain loop; also harness - (doStep + gets + sets), which
//! holds the loop around the calls as well (row copies, call entry and exit).
//!
//! Measured (AMD EPYC, 2 shared cores, the machine otherwise idle), recording the analysed
//! signals: **1.44-1.63 ms per 2.5 s cycle, 1533-1731x real time** in five runs (target 1000x);
//! the build this session started from (3694a7c), interleaved in the same runs: 1.86-1.92 ms,
//! 1305-1341x (958-991x on the slower machine of the session before). First run after loading:
//! 2.22-2.52 ms, 991-1126x (was 3.76-4.03 ms: every model's description and GUID were built
//! to find one). FMU time: doStep 0.71-0.79 ms, gets 0.43-0.48 ms, sets 0.09-0.10 ms, the plant
//! 0.66-0.77 ms of it; the master's share -0.04 to +0.02 ms, i.e. `System::run` is as fast as
//! the hand-written loop within the noise; harness - FMU calls 0.21-0.25 ms. Recording every
//! output (about 160 columns): 2.77-2.91 ms, 860-902x, master's share 0.04-0.10 ms (1-4 %); the
//! plant's gets of all its outputs then cost twice its step. Instructions per step (callgrind,
//! below): 9640 at 3694a7c, 7185 now (gait 775 fewer, FMI glue 492, the plant's AVX2 build
//! 465, the master's output bus ~700).
//!
//! **Against a previous build**: `KNEEBENCH_CLOSED_LOOP_BASELINE=<dir>` names a directory of
//! the previous build's FMUs (`kneebench export --out <dir> --library <its
//! libkneebench_fmu.so>`); the same scenarios are then also run on them (by this build's
//! master), interleaved with this build's runs, and must record the same rows bit for bit. The
//! ratio of the two medians is the FMUs' speed-up in the same run. The master's own changes
//! show against the plain C-call loop (same run), or by running the previous build's bench
//! binary alternately with this one (copy it and its `libkneebench_fmu.so` into `<d>/deps/`
//! first: the bench finds the library beside itself).
//!
//! Instructions per step (repeatable on a noisy machine), recording the analysed signals:
//! `KNEEBENCH_PROFILE_RUNS=3 valgrind --tool=callgrind --toggle-collect='*closed_loop*profiled*'
//! <bench binary>` counts only three steady `System::run`s (divide by 3 x 2500); build the bench
//! with `CARGO_PROFILE_RELEASE_STRIP=none` for function names. With
//! `KNEEBENCH_PROFILE_EVERY_OUTPUT=1` the runs record every output.
use std::collections::HashMap;
use std::ffi::c_void;
use std::path::Path;
use std::time::Instant;

use kneebench_harness::master::Value;
use kneebench_harness::package::export_all;
use kneebench_harness::study::{
    Actuator, Columns, Gait, Scenario, StudyGains, gait_scenario, write_ssp,
};
use kneebench_harness::{Fmu, LoadOptions, Outcome, ssp};
use kneebench_tests::*;
use model_description::{Causality, VariableKind};

/// Repeats of each measurement.
const REPEATS: usize = 9;

fn ok(s: fmi2StatusCode, what: &str) {
    assert_eq!(s, fmi2Status::fmi2OK, "{what}");
}

/// One component of the plain loop.
struct Component<'a> {
    name: String,
    inst: RawInstance<'a>,
    real_out: Vec<u32>,
    int_out: Vec<u32>,
    bool_out: Vec<u32>,
    reals: Vec<f64>,
    ints: Vec<i32>,
    bools: Vec<i32>,
    /// Inputs: (value reference, source component, index in the source's real outputs).
    inputs: Vec<(u32, usize, usize)>,
    input_vrs: Vec<u32>,
    input_values: Vec<f64>,
}

fn vr(fmu: &Fmu, name: &str) -> u32 {
    fmu.variable(name)
        .unwrap_or_else(|| panic!("no variable {name}"))
        .value_reference
}

/// The plain loop; with `timed` false the per-call timers are left out (and only the elapsed
/// time is measured).
#[inline(never)]
fn plain(
    scenario: &Scenario,
    fmus: &HashMap<String, (Fmu, Raw)>,
    record: Option<&[String]>,
    steps: u64,
    step: f64,
    timed: bool,
) -> Plain {
    // Outputs read after each step: every output, or (like the master) the connected ones
    // and the recorded ones.
    let read = |component: &str, variable: &str| -> bool {
        let name = format!("{component}.{variable}");
        match record {
            None => true,
            Some(list) => {
                list.contains(&name) || scenario.connections.iter().any(|(from, _)| *from == name)
            }
        }
    };
    let start = Instant::now();
    let mut comps: Vec<Component<'_>> = Vec::new();
    for c in &scenario.components {
        let (fmu, raw) = &fmus[&c.fmu];
        let md = fmu.model_description();
        let inst = RawInstance::new(raw, &c.name, &md.guid);
        assert!(!inst.c.is_null());
        for (name, value) in &c.parameters {
            let r = [vr(fmu, name)];
            // SAFETY: a valid instance, one value.
            let s = unsafe {
                match value {
                    Value::Real(v) => (raw.set_real)(inst.c, r.as_ptr(), 1, [*v].as_ptr()),
                    Value::Integer(v) => (raw.set_integer)(inst.c, r.as_ptr(), 1, [*v].as_ptr()),
                    Value::Boolean(v) => {
                        (raw.set_boolean)(inst.c, r.as_ptr(), 1, [i32::from(*v)].as_ptr())
                    }
                    Value::String(_) => unreachable!("no string parameters"),
                }
            };
            ok(s, name);
        }
        let (mut real_out, mut int_out, mut bool_out) = (vec![], vec![], vec![]);
        for v in &md.model_variables {
            if v.causality != Some(Causality::Output) || !read(&c.name, &v.name) {
                continue;
            }
            match v.kind {
                VariableKind::Real { .. } => real_out.push(v.value_reference),
                VariableKind::Integer { .. } | VariableKind::Enumeration { .. } => {
                    int_out.push(v.value_reference)
                }
                VariableKind::Boolean { .. } => bool_out.push(v.value_reference),
                VariableKind::String { .. } => {}
            }
        }
        comps.push(Component {
            name: c.name.clone(),
            inst,
            reals: vec![0.0; real_out.len()],
            ints: vec![0; int_out.len()],
            bools: vec![0; bool_out.len()],
            real_out,
            int_out,
            bool_out,
            inputs: vec![],
            input_vrs: vec![],
            input_values: vec![],
        });
    }
    let index = |name: &str| comps.iter().position(|c| c.name == name).unwrap();
    let mut wiring = Vec::new();
    for (from, to) in &scenario.connections {
        let (fc, fv) = from.split_once('.').unwrap();
        let (tc, tv) = to.split_once('.').unwrap();
        let (fi, ti) = (index(fc), index(tc));
        let src = &fmus[&scenario.components[fi].fmu].0;
        let dst = &fmus[&scenario.components[ti].fmu].0;
        let out_vr = vr(src, fv);
        let k = comps[fi]
            .real_out
            .iter()
            .position(|&v| v == out_vr)
            .expect("Real connections only");
        wiring.push((ti, vr(dst, tv), fi, k));
    }
    for (ti, v, fi, k) in wiring {
        comps[ti].inputs.push((v, fi, k));
        comps[ti].input_vrs.push(v);
        comps[ti].input_values.push(0.0);
    }
    for c in &mut comps {
        c.inst.initialize(0.0, Some(scenario.stop_time));
    }
    let width: usize = comps
        .iter()
        .map(|c| c.reals.len() + c.ints.len() + c.bools.len())
        .sum();
    let mut rows: Vec<f64> = Vec::with_capacity(width * (steps as usize + 1));
    let mut do_step = vec![0.0; comps.len()];
    let mut gets = vec![0.0; comps.len()];
    let mut sets = vec![0.0; comps.len()];
    let mut set_calls = 0u64;
    for n in 0..steps {
        let t = n as f64 * step;
        for i in 0..comps.len() {
            for j in 0..comps[i].inputs.len() {
                let (_, fi, k) = comps[i].inputs[j];
                comps[i].input_values[j] = comps[fi].reals[k];
            }
            let c = &mut comps[i];
            let raw = c.inst.f;
            let h: *mut c_void = c.inst.c;
            // SAFETY: a valid, initialized instance; buffers of the right lengths.
            unsafe {
                if !c.input_vrs.is_empty() {
                    let ts = timed.then(Instant::now);
                    ok(
                        (raw.set_real)(
                            h,
                            c.input_vrs.as_ptr(),
                            c.input_vrs.len(),
                            c.input_values.as_ptr(),
                        ),
                        "fmi2SetReal",
                    );
                    if let Some(ts) = ts {
                        sets[i] += ts.elapsed().as_secs_f64();
                        set_calls += 1;
                    }
                }
                let t0 = timed.then(Instant::now);
                let s = (raw.do_step)(h, t, step, fmi2True);
                if let Some(t0) = t0 {
                    do_step[i] += t0.elapsed().as_secs_f64();
                }
                ok(s, "fmi2DoStep");
                let t1 = timed.then(Instant::now);
                if !c.reals.is_empty() {
                    ok(
                        (raw.get_real)(h, c.real_out.as_ptr(), c.reals.len(), c.reals.as_mut_ptr()),
                        "fmi2GetReal",
                    );
                }
                if !c.ints.is_empty() {
                    ok(
                        (raw.get_integer)(h, c.int_out.as_ptr(), c.ints.len(), c.ints.as_mut_ptr()),
                        "fmi2GetInteger",
                    );
                }
                if !c.bools.is_empty() {
                    ok(
                        (raw.get_boolean)(
                            h,
                            c.bool_out.as_ptr(),
                            c.bools.len(),
                            c.bools.as_mut_ptr(),
                        ),
                        "fmi2GetBoolean",
                    );
                }
                if let Some(t1) = t1 {
                    gets[i] += t1.elapsed().as_secs_f64();
                }
            }
        }
        for c in &comps {
            rows.extend_from_slice(&c.reals);
            rows.extend(c.ints.iter().map(|&v| f64::from(v)));
            rows.extend(c.bools.iter().map(|&v| f64::from(v)));
        }
    }
    for c in &mut comps {
        // SAFETY: a valid instance.
        unsafe { ok((c.inst.f.terminate)(c.inst.c), "fmi2Terminate") };
    }
    drop(comps);
    let elapsed = start.elapsed().as_secs_f64();
    std::hint::black_box(&rows);
    Plain {
        elapsed,
        do_step,
        gets,
        sets: sets.iter().sum(),
        set_calls,
    }
}

/// What one plain loop measured (seconds).
struct Plain {
    /// The whole loop.
    elapsed: f64,
    /// `fmi2DoStep` per component.
    do_step: Vec<f64>,
    /// The output gets per component.
    gets: Vec<f64>,
    /// All `fmi2SetReal` calls.
    sets: f64,
    /// Number of `fmi2SetReal` calls timed.
    set_calls: u64,
}

/// The scenario's `.ssp`, loaded (FMUs extracted and their binaries opened), recording `record`
/// (every output if `None`).
fn load(path: &Path, record: Option<&[String]>) -> ssp::LoadedSystem {
    let mut loaded = ssp::load_system(path, &LoadOptions::default()).unwrap();
    if let Some(list) = record {
        let names: Vec<&str> = list.iter().map(String::as_str).collect();
        loaded.system.record(&names).unwrap();
    }
    loaded
}

/// One `System::run` of a loaded system (instantiate, initialize, step, record, terminate,
/// free); elapsed seconds.
#[inline(never)]
fn harness(loaded: &ssp::LoadedSystem) -> f64 {
    let start = Instant::now();
    let out = loaded.system.run(&loaded.config).unwrap();
    let elapsed = start.elapsed().as_secs_f64();
    assert!(
        matches!(out.outcome, Outcome::Completed { .. }),
        "{:?}",
        out.outcome
    );
    std::hint::black_box(&out.results);
    elapsed
}

/// The rows one run of `loaded` records (to compare two builds bit for bit).
fn recorded_rows(loaded: &ssp::LoadedSystem) -> Vec<u64> {
    let out = loaded.system.run(&loaded.config).unwrap();
    out.results
        .rows()
        .flat_map(|r| r.iter().map(|v| v.to_bits()))
        .collect()
}

/// The environment variable naming the previous build's FMUs (see the header).
const BASELINE_VAR: &str = "KNEEBENCH_CLOSED_LOOP_BASELINE";

/// The `.ssp` of `scenario` on the previous build's FMUs, when [`BASELINE_VAR`] names them.
fn baseline_ssp(scenario: &Scenario, dir: &Path, name: &str) -> Option<std::path::PathBuf> {
    let fmus = std::env::var_os(BASELINE_VAR)?;
    let path = dir.join(name);
    write_ssp(scenario, Path::new(&fmus), &path)
        .unwrap_or_else(|e| panic!("{BASELINE_VAR}={}: {e}", Path::new(&fmus).display()));
    Some(path)
}

/// Runs the previous build's system (`base`) next to this build's (`loaded`): the same rows
/// bit for bit, then `repeats` interleaved pairs of runs; the medians (this, previous).
fn against_baseline(loaded: &ssp::LoadedSystem, base: &ssp::LoadedSystem) -> (f64, f64) {
    assert!(
        recorded_rows(loaded) == recorded_rows(base),
        "the previous build's FMUs record other values than this build's"
    );
    let (mut this, mut previous) = (vec![], vec![]);
    for _ in 0..REPEATS {
        previous.push(harness(base));
        this.push(harness(loaded));
    }
    (median(this), median(previous))
}

/// Prints the comparison with the previous build (see [`against_baseline`]).
fn print_baseline(sim: f64, (this, previous): (f64, f64)) {
    println!(
        "  previous build's FMUs    {:7.2} ms   real-time factor {:6.0}x  (this build's in the same run {:.2} ms, {:.0}x: speed-up {:.3}; rows bit-identical)",
        previous * 1e3,
        sim / previous,
        this * 1e3,
        sim / this,
        previous / this
    );
}

/// `runs` steady harness runs (the instruction-counting mode).
#[inline(never)]
fn profiled(loaded: &ssp::LoadedSystem, runs: usize) {
    for _ in 0..runs {
        harness(loaded);
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    // `cargo bench` passes `--bench`; nothing to parse.
    let dir = tempfile::tempdir().unwrap();
    let fmu_dir = dir.path().join("fmus");
    export_all(&fmu_library(), &fmu_dir).expect("export");
    let gait = Gait::bench_full();
    let scenario = gait_scenario(
        Actuator::Sea,
        gait,
        StudyGains::for_actuator(Actuator::Sea),
        1,
    );
    let path = dir.path().join("SEA.ssp");
    write_ssp(&scenario, &fmu_dir, &path).unwrap();
    let mut fmus: HashMap<String, (Fmu, Raw)> = HashMap::new();
    for c in &scenario.components {
        if !fmus.contains_key(&c.fmu) {
            let fmu = Fmu::load(fmu_dir.join(&c.fmu), &LoadOptions::default()).unwrap();
            let raw = Raw::load(fmu.binary_path());
            fmus.insert(c.fmu.clone(), (fmu, raw));
        }
    }
    let step = scenario.step_size;
    let steps = (scenario.stop_time / step).round() as u64;

    if let Ok(runs) = std::env::var("KNEEBENCH_PROFILE_RUNS") {
        // Instruction counting: one run to load everything, then `runs` steady runs inside
        // `profiled` (the function callgrind is told to count; see the header).
        let runs: usize = runs
            .parse()
            .expect("KNEEBENCH_PROFILE_RUNS is a number of runs");
        // KNEEBENCH_PROFILE_EVERY_OUTPUT=1: recording every output instead.
        let analysed = Columns::default().names();
        let every = std::env::var_os("KNEEBENCH_PROFILE_EVERY_OUTPUT").is_some();
        let loaded = load(&path, (!every).then_some(analysed.as_slice()));
        harness(&loaded);
        profiled(&loaded, runs);
        return;
    }
    // Warm up.
    plain(&scenario, &fmus, None, steps, step, true);
    harness(&load(&path, None));
    let analysed = Columns::default().names();
    report(
        "the study's SEA loop, recording the signals the study analyses",
        &scenario,
        &path,
        &fmus,
        Some(&analysed),
    );
    report(
        "the study's SEA loop, recording every output",
        &scenario,
        &path,
        &fmus,
        None,
    );
    csea(&dir.path().join("CSEA.ssp"), &fmu_dir);
}

/// The study's CSEA loop (gait, impedance controller, clutch scheduler, torque loop, plant: 5
/// FMU instances, Boolean connections too, so no plain loop), recording the analysed signals:
/// the harness's steady real-time factor.
fn csea(path: &Path, fmu_dir: &Path) {
    let scenario = gait_scenario(
        Actuator::Csea,
        Gait::bench_full(),
        StudyGains::for_actuator(Actuator::Csea),
        1,
    );
    write_ssp(&scenario, fmu_dir, path).unwrap();
    let analysed = Columns::default().names();
    let loaded = load(path, Some(&analysed));
    let first = harness(&loaded);
    let runs: Vec<f64> = (0..REPEATS).map(|_| harness(&loaded)).collect();
    let h = median(runs);
    let sim = scenario.stop_time;
    let baseline = baseline_ssp(&scenario, path.parent().unwrap(), "CSEA-baseline.ssp")
        .map(|base| against_baseline(&loaded, &load(&base, Some(&analysed))));
    println!(
        "the study's CSEA loop, recording the signals the study analyses: {} FMU instances, {} steps; medians of {REPEATS}",
        scenario.components.len(),
        (sim / scenario.step_size).round()
    );
    println!(
        "  harness System::run      {:7.2} ms   real-time factor {:6.0}x  (first run after loading {:.2} ms)",
        h * 1e3,
        sim / h,
        first * 1e3
    );
    if let Some(b) = baseline {
        print_baseline(sim, b);
    }
}

/// Measures and prints one scenario.
fn report(
    title: &str,
    scenario: &Scenario,
    path: &Path,
    fmus: &HashMap<String, (Fmu, Raw)>,
    record: Option<&[String]>,
) {
    let step = scenario.step_size;
    let steps = (scenario.stop_time / step).round() as u64;
    let n = scenario.components.len();
    let plant = scenario
        .components
        .iter()
        .position(|c| c.name == "plant")
        .unwrap();
    let (mut h, mut p, mut d, mut g, mut dp) = (vec![], vec![], vec![], vec![], vec![]);
    let (mut timers, mut sets) = (vec![], vec![]);
    // The first run after loading also pays the binaries' one-time lazy initialization (model
    // tables, the plant's shared discretisations); later runs are the steady state a study or
    // a tuning loop sees.
    let loaded = load(path, record);
    let first = harness(&loaded);
    // Each timed interval of the plain loop also holds the clock reads around it: their cost,
    // measured here in the same run, is taken off the FMU sums.
    let intervals = (steps * n as u64) as f64;
    for _ in 0..REPEATS {
        let bias = timer_bias();
        timers.push(bias);
        let timed = plain(scenario, fmus, record, steps, step, true);
        d.push(timed.do_step.iter().sum::<f64>() - intervals * bias);
        g.push(timed.gets.iter().sum::<f64>() - intervals * bias);
        sets.push(timed.sets - timed.set_calls as f64 * bias);
        dp.push(timed.do_step[plant] + timed.gets[plant] - 2.0 * steps as f64 * bias);
        p.push(plain(scenario, fmus, record, steps, step, false).elapsed);
        h.push(harness(&loaded));
    }
    let baseline = baseline_ssp(scenario, path.parent().unwrap(), "SEA-baseline.ssp")
        .map(|base| against_baseline(&loaded, &load(&base, record)));
    let (h, p, d, g, dp) = (median(h), median(p), median(d), median(g), median(dp));
    let bias = median(timers);
    let sets = median(sets);
    let sim = scenario.stop_time;
    let per = |s: f64| s / (steps as f64 * n as f64) * 1e9;
    let recorded = record.map_or("every output".to_string(), |r| {
        format!("{} signals", r.len())
    });
    println!(
        "{title}: {n} FMU instances, {steps} steps of {} ms ({sim} s, one gait cycle), {recorded} recorded; medians of {REPEATS}",
        step * 1e3
    );
    println!(
        "  harness System::run      {:7.2} ms   real-time factor {:6.0}x",
        h * 1e3,
        sim / h
    );
    println!(
        "    (first run after loading {:.2} ms, {:.0}x: one-time initialization of the binaries)",
        first * 1e3,
        sim / first
    );
    println!(
        "  plain C-call loop        {:7.2} ms   real-time factor {:6.0}x  (the same C calls, no master around them)",
        p * 1e3,
        sim / p
    );
    println!(
        "    sum of fmi2DoStep      {:7.2} ms   ({:.0} % of the harness run, {:.0} ns per FMU per step; timed on their own, less {:.0} ns of clock reads per call)",
        d * 1e3,
        100.0 * d / h,
        per(d),
        bias * 1e9
    );
    println!(
        "    sum of output gets     {:7.2} ms   (the FMUs compute their outputs lazily on the first get after a step)",
        g * 1e3
    );
    println!("    sum of input sets      {:7.2} ms", sets * 1e3);
    println!(
        "    plant's doStep + gets  {:7.2} ms;  the other {} instances {:.2} ms",
        dp * 1e3,
        n - 1,
        (d + g - dp) * 1e3
    );
    println!(
        "  master's share           {:7.2} ms   harness - plain loop ({:.0} % of the run, {:.0} ns per FMU per step); harness - (doStep + gets + sets) {:.2} ms",
        (h - p) * 1e3,
        100.0 * (h - p) / h,
        per(h - p),
        (h - d - g - sets) * 1e3
    );
    if let Some(b) = baseline {
        print_baseline(sim, b);
    }
}

/// The mean length an empty timed interval of the plain loop measures (`Instant::now()`, then
/// `elapsed()`): what each timed call's figure holds besides the call.
#[inline(never)]
fn timer_bias() -> f64 {
    let n = 100_000;
    let mut total = 0.0;
    for _ in 0..n {
        let t0 = Instant::now();
        total += std::hint::black_box(t0).elapsed().as_secs_f64();
    }
    total / n as f64
}
