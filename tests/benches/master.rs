//! The master's own cost, in one run: `cargo bench -p kneebench-tests --bench master`.
//!
//! The FMU is `GaitReference` (exported by the packager, loaded from its `.fmu`), stepped at
//! 1 kHz for [`SECONDS`] simulated seconds, every output read after every step:
//!
//! - **plain**: a Rust loop calling the binary's C functions directly (resolved with
//!   libloading from the same extracted binary the harness loads): `fmi2DoStep` then one
//!   `fmi2GetReal` (and `fmi2GetInteger`/`fmi2GetBoolean` if the FMU has such outputs) of every
//!   output per step, values stored in a preallocated buffer. Instantiation and initialization
//!   are inside the timing, as they are for the harness.
//! - **harness**: `System::run` (Gauss-Seidel, sequential, every output recorded), the whole
//!   call: instantiate, initialize, step, record, terminate, free.
//! - **5x**: five instances: a `System` of five components vs one plain loop stepping the five
//!   instances one after the other. GaitReference has no inputs, so the five are unconnected.
//! - **fmpy**: fmpy's `FMU2Slave` loop in Python (`doStep` + `getReal`, and `getInteger`/
//!   `getBoolean` if needed, of the same outputs),
//!   timed with `time.perf_counter` around the loop only (instantiation excluded, which favours
//!   fmpy).
//!
//! Every measurement is repeated [`REPEATS`] times, plain and harness runs interleaved so that
//! they see the same machine load; the table gives medians in ns per FMU per step, and the
//! harness overhead is the median of the per-repeat differences (harness - plain). Targets
//! (issue 4): overhead < 50 ns per FMU per step, harness >= 20x faster than fmpy's loop.
//!
//! On a loaded machine wall-clock differences of tens of ns are noisy; for a deterministic
//! figure, count instructions of one case at a time and subtract the `none` case (export and
//! load only), e.g.
//! `KNEEBENCH_BENCH_CASE=harness1 valgrind --tool=callgrind target/release/deps/master-* --bench`
//! (cases: `none`, `plain1`, `harness1`, `plain5`, `harness5`).

use std::ffi::c_void;
use std::time::Instant;

use kneebench_harness::package::export_all;
use kneebench_harness::{Fmu, LoadOptions, RunConfig, System};
use kneebench_tests::*;
use model_description::{Causality, VariableKind};

/// Simulated seconds per run.
const SECONDS: f64 = 20.0;
/// Step size (1 kHz).
const STEP: f64 = 1e-3;
/// Repeats of each measurement.
const REPEATS: usize = 9;
/// Instances of the multi-FMU case.
const MANY: usize = 5;

/// Value references of the outputs, by type.
struct Outputs {
    real: Vec<u32>,
    int: Vec<u32>,
    boolean: Vec<u32>,
}

fn outputs(fmu: &Fmu) -> Outputs {
    let mut o = Outputs {
        real: vec![],
        int: vec![],
        boolean: vec![],
    };
    for v in &fmu.model_description().model_variables {
        if v.causality != Some(Causality::Output) {
            continue;
        }
        match v.kind {
            VariableKind::Real { .. } => o.real.push(v.value_reference),
            VariableKind::Integer { .. } | VariableKind::Enumeration { .. } => {
                o.int.push(v.value_reference)
            }
            VariableKind::Boolean { .. } => o.boolean.push(v.value_reference),
            VariableKind::String { .. } => {}
        }
    }
    o
}

fn ok(s: fmi2StatusCode, what: &str) {
    assert_eq!(s, fmi2Status::fmi2OK, "{what}");
}

/// The plain loop over `count` instances; returns the elapsed seconds.
#[inline(never)]
fn plain(raw: &Raw, guid: &str, out: &Outputs, count: usize, steps: u64) -> f64 {
    let start = Instant::now();
    let mut instances: Vec<RawInstance<'_>> = (0..count)
        .map(|i| {
            let mut inst = RawInstance::new(raw, &format!("g{i}"), guid);
            assert!(!inst.c.is_null());
            inst.initialize(0.0, Some(steps as f64 * STEP));
            inst
        })
        .collect();
    let width = out.real.len() + out.int.len() + out.boolean.len();
    let mut rows: Vec<f64> = Vec::with_capacity(count * width * (steps as usize + 1));
    let mut reals = vec![0.0; out.real.len()];
    let mut ints = vec![0; out.int.len()];
    let mut bools = vec![0; out.boolean.len()];
    for n in 0..steps {
        let t = n as f64 * STEP;
        for inst in &mut instances {
            let c: *mut c_void = inst.c;
            // SAFETY: a valid, initialized instance; buffers of the right lengths.
            unsafe {
                ok((raw.do_step)(c, t, STEP, fmi2True), "fmi2DoStep");
                ok(
                    (raw.get_real)(c, out.real.as_ptr(), reals.len(), reals.as_mut_ptr()),
                    "fmi2GetReal",
                );
                if !ints.is_empty() {
                    ok(
                        (raw.get_integer)(c, out.int.as_ptr(), ints.len(), ints.as_mut_ptr()),
                        "fmi2GetInteger",
                    );
                }
                if !bools.is_empty() {
                    ok(
                        (raw.get_boolean)(c, out.boolean.as_ptr(), bools.len(), bools.as_mut_ptr()),
                        "fmi2GetBoolean",
                    );
                }
            }
            rows.extend_from_slice(&reals);
            rows.extend(ints.iter().map(|&v| v as f64));
            rows.extend(bools.iter().map(|&v| v as f64));
        }
    }
    for inst in &mut instances {
        // SAFETY: a valid instance.
        unsafe { ok((raw.terminate)(inst.c), "fmi2Terminate") };
    }
    drop(instances);
    let elapsed = start.elapsed().as_secs_f64();
    std::hint::black_box(&rows);
    elapsed
}

/// `System::run` of `count` components; returns the elapsed seconds.
#[inline(never)]
fn harness(fmu: &Fmu, count: usize) -> f64 {
    let mut system = System::new();
    for i in 0..count {
        system.add_component(&format!("g{i}"), fmu.clone()).unwrap();
    }
    let config = RunConfig {
        stop_time: SECONDS,
        step_size: STEP,
        ..RunConfig::default()
    };
    let start = Instant::now();
    let out = system.run(&config).unwrap();
    let elapsed = start.elapsed().as_secs_f64();
    assert!(
        matches!(out.outcome, kneebench_harness::Outcome::Completed { .. }),
        "{:?}",
        out.outcome
    );
    std::hint::black_box(&out.results);
    elapsed
}

/// fmpy's FMU2Slave loop; returns the elapsed seconds of each repeat.
fn fmpy(fmu: &std::path::Path, steps: u64, repeats: usize) -> Vec<f64> {
    const SCRIPT: &str = r#"
import sys, time
from fmpy import read_model_description, extract
from fmpy.fmi2 import FMU2Slave
path, steps, h, repeats = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
md = read_model_description(path)
outs = [v for v in md.modelVariables if v.causality == "output"]
vrs = [v.valueReference for v in outs if v.type == "Real"]
ivrs = [v.valueReference for v in outs if v.type in ("Integer", "Enumeration")]
bvrs = [v.valueReference for v in outs if v.type == "Boolean"]
unzipdir = extract(path)
out = []
for r in range(repeats):
    # fmpy's freeInstance also unloads the library: a new FMU2Slave per repeat.
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir,
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="g")
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    rows = []
    t0 = time.perf_counter()
    for n in range(steps):
        fmu.doStep(currentCommunicationPoint=n * h, communicationStepSize=h)
        rows.append(fmu.getReal(vrs))
        if ivrs:
            rows.append(fmu.getInteger(ivrs))
        if bvrs:
            rows.append(fmu.getBoolean(bvrs))
    out.append(time.perf_counter() - t0)
    fmu.terminate()
    fmu.freeInstance()
print(" ".join(repr(x) for x in out))
"#;
    run_python(
        SCRIPT,
        &[
            &fmu.display().to_string(),
            &steps.to_string(),
            &STEP.to_string(),
            &repeats.to_string(),
        ],
    )
    .split_whitespace()
    .map(|s| s.parse().unwrap())
    .collect()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

/// Seconds to ns per FMU per step.
fn per_step(seconds: f64, count: usize, steps: u64) -> f64 {
    seconds * 1e9 / (count as f64 * steps as f64)
}

fn main() {
    // `cargo bench` passes `--bench`; nothing to parse.
    let dir = tempfile::tempdir().unwrap();
    let exported = export_all(&fmu_library(), dir.path()).expect("export");
    let path = exported
        .iter()
        .find(|f| f.identifier == "GaitReference")
        .expect("GaitReference")
        .path
        .clone();
    let fmu = Fmu::load(&path, &LoadOptions::default()).unwrap();
    let guid = fmu.model_description().guid.clone();
    let out = outputs(&fmu);
    let raw = Raw::load(fmu.binary_path());
    let steps = (SECONDS / STEP).round() as u64;

    // One case, once, for instruction counts (see the module documentation).
    if let Ok(case) = std::env::var("KNEEBENCH_BENCH_CASE") {
        match case.as_str() {
            "none" => {}
            "plain1" => drop(plain(&raw, &guid, &out, 1, steps)),
            "harness1" => drop(harness(&fmu, 1)),
            "plain5" => drop(plain(&raw, &guid, &out, MANY, steps)),
            "harness5" => drop(harness(&fmu, MANY)),
            other => panic!("KNEEBENCH_BENCH_CASE={other}: none|plain1|harness1|plain5|harness5"),
        }
        return;
    }
    // Warm up (page in, CPU frequency).
    plain(&raw, &guid, &out, 1, steps);
    harness(&fmu, 1);

    let (mut p1, mut h1, mut d1) = (vec![], vec![], vec![]);
    let (mut p5, mut h5, mut d5) = (vec![], vec![], vec![]);
    for _ in 0..REPEATS {
        let (p, h) = (
            per_step(plain(&raw, &guid, &out, 1, steps), 1, steps),
            per_step(harness(&fmu, 1), 1, steps),
        );
        p1.push(p);
        h1.push(h);
        d1.push(h - p);
        let (p, h) = (
            per_step(plain(&raw, &guid, &out, MANY, steps), MANY, steps),
            per_step(harness(&fmu, MANY), MANY, steps),
        );
        p5.push(p);
        h5.push(h);
        d5.push(h - p);
    }
    let fmpy_ns = median(
        fmpy(&path, steps, 5)
            .into_iter()
            .map(|s| per_step(s, 1, steps))
            .collect(),
    );
    let min = |v: &[f64]| v.iter().cloned().fold(f64::INFINITY, f64::min);
    // Least-disturbed runs: the minimum of each series (a second estimate on a loaded machine).
    let (m1, m5) = (min(&h1) - min(&p1), min(&h5) - min(&p5));
    let (p1, h1, d1, p5, h5, d5) = (
        median(p1),
        median(h1),
        median(d1),
        median(p5),
        median(h5),
        median(d5),
    );

    println!(
        "GaitReference, {} outputs, {steps} steps of {STEP} s, median of {REPEATS} (fmpy: 5)",
        out.real.len() + out.int.len() + out.boolean.len()
    );
    println!(
        "{:<34} {:>12} {:>10} {:>14} {:>14}",
        "case", "ns/FMU/step", "vs plain", "overhead (ns)", "min-min (ns)"
    );
    let row = |name: &str, ns: f64, base: f64, over: Option<(f64, f64)>| {
        let (a, b) = over
            .map(|(a, b)| (format!("{a:+.1}"), format!("{b:+.1}")))
            .unwrap_or_default();
        println!(
            "{:<34} {:>12.1} {:>9.3}x {:>14} {:>14}",
            name,
            ns,
            ns / base,
            a,
            b
        );
    };
    row("(a) plain C loop, 1 FMU", p1, p1, None);
    row("(b) harness System::run, 1 FMU", h1, p1, Some((d1, m1)));
    row("(c) plain C loop, 5 FMUs", p5, p5, None);
    row("(c) harness System::run, 5 FMUs", h5, p5, Some((d5, m5)));
    row("(d) fmpy FMU2Slave loop, 1 FMU", fmpy_ns, p1, None);
    println!();
    println!(
        "harness overhead per FMU per step (median of paired differences): {d1:.1} ns (1 FMU), {d5:.1} ns (5 FMUs); target < 50 ns: {}",
        if d1 < 50.0 && d5 < 50.0 {
            "met"
        } else {
            "MISSED"
        }
    );
    let speedup = fmpy_ns / h1;
    println!(
        "harness vs fmpy's loop: {speedup:.1}x faster (1 FMU, medians); target >= 20x: {}",
        if speedup >= 20.0 { "met" } else { "MISSED" }
    );
}
