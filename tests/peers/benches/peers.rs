//! The peer comparison, one command, one run: `cargo bench -p kneebench-peers --bench peers`.
//!
//! For each FMU of the table (our `GaitReference`, `PidController`, `BenchPlant` in its default
//! SEA configuration, and the PythonFMU export `FirstOrder` of [`kneebench_tests::pythonfmu`])
//! every engine runs the same steps of 1 ms, feeds the same recorded inputs (a CSV with one row
//! per step: the gait angle for the controller and the lag, sinusoidal current commands for the
//! plant) and records every output of the FMU after every step:
//!
//! - **bare C-call loop**: not a peer but the floor, the FMU's own cost: a Rust loop calling the
//!   binary's `fmi2SetReal`, `fmi2DoStep` and one `fmi2Get*` per output type, values stored in a
//!   preallocated buffer. For the PythonFMU export also the same loop with a Python thread
//!   state held by the stepping thread (see below).
//! - **kneebench run, whole process**: `target/release/kneebench run X.fmu --stop-time T
//!   --step 0.001 --inputs in.csv --output out.csv --quiet`, as a user types it (the bench
//!   builds the binaries first with `cargo build --release -p kneebench-harness --bins`). For the
//!   PythonFMU export also `--preload libpython --force`, and a second row with
//!   `--isolate never` (the default runs a foreign FMU in a host process).
//! - **kneebench System::run, in process**: the harness API, results kept in memory.
//! - **fmpy simulate_fmu, whole process**: `python -c` with `simulate_fmu(..., step_size=h,
//!   output_interval=h, input=np.genfromtxt(in.csv))` and `fmpy.util.write_csv(out.csv)`, which
//!   is what `fmpy simulate --output-file` does.
//! - **fmpy FMU2Slave loop, in process**: `setReal`, `doStep` and one `get*` per output type,
//!   rows appended to a list.
//! - **fmi-rs FMU2 loop, in process**: the same loop through fmi-rs's `FMU2<CS>` (the Rust FMI
//!   engine of fmpy's authors), values stored in a preallocated buffer.
//!
//! Every engine runs at two step counts (default 2 000 and 42 000 steps, 2 s and 42 s of
//! simulated time; `KNEEBENCH_PEERS_STEPS=N1,N2`). The same input file (42 001 rows) serves
//! both, so reading it is start-up. A whole process costs start-up (process, extraction,
//! loading, interpreter and imports, the input file) plus a per-step cost: the per-step cost is
//! the slope `(t(N2) - t(N1)) / (N2 - N1)` and the start-up `t(N1) - N1 * slope`, for wall time
//! and CPU time (user + system of the child processes; in-process engines run in a child
//! process of this bench too, the process CPU clock around the run). Each engine runs
//! [`DEFAULT_REPEATS`] times (`KNEEBENCH_PEERS_REPEATS`), the engines interleaved within a
//! repeat so that they see the same machine load; the table takes the minimum of each time.
//!
//! The figure of merit is the **per-step CPU time**: a peer / ours ratio above 1 means ours is
//! faster. The issue's target is `kneebench run`, whole process, at >= 3x the fastest peer per
//! step on every FMU of the table; the table says for which FMUs it holds. No master is faster
//! than the bare C-call loop, so against a peer that runs at the FMU's own cost (on our FMUs,
//! fmi-rs's loop) the target cannot hold: the bare loop's row shows that floor.
//!
//! A PythonFMU binary takes the GIL with `PyGILState_Ensure` in every FMI call. In a Python host
//! (fmpy) the calling thread already has a thread state, so that is cheap; in any other host
//! the call creates a thread state and destroys it again at `PyGILState_Release`, every call.
//! The row "bare C-call loop, Python thread state held" first calls `PyGILState_Ensure` and
//! `PyEval_SaveThread` on the stepping thread (a thread state kept, the GIL released), which
//! makes every later `PyGILState_Ensure` of that thread reuse it: the cost a non-Python host
//! can reach. The harness does the same for such a binary (module
//! `kneebench_harness::embedded_python`, in process and in the isolated host), so its rows are
//! measured against both bare loops.
//!
//! Each engine's last recorded row is compared with the bare C-call loop's (largest relative
//! difference over the outputs), so that the table compares the same work.
//!
//! Without the venv's Python (or without fmpy or pythonfmu in it) the bench prints what is
//! missing and how to install it (`bash scripts/setup-python.sh`), and runs the rest.
//! `KNEEBENCH_PYTHON` names another Python; `KNEEBENCH_PEERS_ONLY=BenchPlant,FirstOrder` runs
//! those FMUs only.

use std::collections::BTreeMap;
use std::ffi::{CString, c_void};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use kneebench_harness::master::Signal;
use kneebench_harness::package::export_all;
use kneebench_harness::{Fmu, LoadOptions, Outcome, RunConfig, System};
use kneebench_tests::pythonfmu::{self, PythonRuntime};
use kneebench_tests::*;

#[path = "../../benches/shared/process.rs"]
mod process;
use model_description::{Causality, ModelDescription, VariableKind};
use process::{Timing, build_kneebench, time_process};

/// Communication step (1 kHz).
const H: f64 = 1e-3;
/// The two step counts of the slope.
const DEFAULT_STEPS: [u64; 2] = [2_000, 42_000];
/// Repeats of every measurement (the table takes the minimum).
const DEFAULT_REPEATS: usize = 3;
/// Set in the child processes that run one in-process engine: the engine's name.
const CHILD_ENGINE: &str = "KNEEBENCH_PEERS_CHILD";
/// The child's FMU, input file (empty: none), step count and libpython to preload (optional).
const CHILD_FMU: &str = "KNEEBENCH_PEERS_FMU";
const CHILD_INPUTS: &str = "KNEEBENCH_PEERS_INPUTS";
const CHILD_STEPS: &str = "KNEEBENCH_PEERS_CHILD_STEPS";
const CHILD_PRELOAD: &str = "KNEEBENCH_PEERS_PRELOAD";

// ---------------------------------------------------------------------------------------------
// Inputs
// ---------------------------------------------------------------------------------------------

/// The inputs of an FMU: names and a function of time giving their values.
struct InputSpec {
    names: &'static [&'static str],
    values: fn(f64) -> Vec<f64>,
}

/// The gait's knee angle reference (rad) at `t`.
fn gait_angle(t: f64) -> f64 {
    use kneebench_fmu::models::gait::{ANGLE_SERIES, fourier};
    fourier(&ANGLE_SERIES, t, 2.5).value * 60f64.to_radians()
}

/// PidController: the gait angle as setpoint, a lagged and scaled copy as measurement.
fn pid_inputs(t: f64) -> Vec<f64> {
    vec![gait_angle(t), 0.95 * gait_angle(t - 0.02)]
}

/// BenchPlant: sinusoidal current commands at the gait period, the load motor against the
/// test motor (2.5 A: 14.8 N m at the output, beyond the 5 N m of static friction, so the run
/// sticks and slips every half period). Without the position loop the gait-shaped currents of
/// the `plant_abi` bench drift and trip the torque interlock after one cycle; these stay
/// bounded for any length of run.
fn plant_inputs(t: f64) -> Vec<f64> {
    let w = 2.0 * std::f64::consts::PI / 2.5;
    vec![2.5 * (w * t).sin(), -0.5 * (w * t + 0.3).sin()]
}

/// FirstOrder: the normalised gait angle (crosses the model's threshold of 1.5 with k = 2).
fn first_order_inputs(t: f64) -> Vec<f64> {
    vec![gait_angle(t) / 60f64.to_radians()]
}

/// Writes `time,<names>` and one row per step `k = 0..=steps` at `t = k h`.
fn write_inputs(path: &Path, spec: &InputSpec, steps: u64) -> std::io::Result<()> {
    use std::io::Write;
    let mut w = std::io::BufWriter::new(std::fs::File::create(path)?);
    writeln!(w, "time,{}", spec.names.join(","))?;
    for k in 0..=steps {
        let t = k as f64 * H;
        let values: Vec<String> = (spec.values)(t).iter().map(|v| v.to_string()).collect();
        writeln!(w, "{t},{}", values.join(","))?;
    }
    w.flush()
}

/// An input file read back: names, times, and one row of values per time.
struct Inputs {
    names: Vec<String>,
    times: Vec<f64>,
    rows: Vec<Vec<f64>>,
}

fn read_inputs(path: &Path) -> Inputs {
    let text = std::fs::read_to_string(path).expect("read the input file");
    let mut lines = text.lines();
    let names = lines
        .next()
        .expect("header")
        .split(',')
        .skip(1)
        .map(str::to_string)
        .collect();
    let (mut times, mut rows) = (vec![], vec![]);
    for line in lines {
        let mut fields = line.split(',').map(|f| f.parse::<f64>().expect("a number"));
        times.push(fields.next().expect("time"));
        rows.push(fields.collect());
    }
    Inputs { names, times, rows }
}

// ---------------------------------------------------------------------------------------------
// Measurements
// ---------------------------------------------------------------------------------------------

/// This process's CPU time (all threads), seconds.
fn process_cpu() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: a valid out-pointer.
    let r = unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    assert_eq!(r, 0, "clock_gettime");
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

/// The last row of a results CSV (`time` first), by column name.
fn last_row_of_csv(path: &Path) -> Result<BTreeMap<String, f64>, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut lines = text.lines().filter(|l| !l.trim().is_empty());
    let header: Vec<&str> = lines.next().ok_or("empty results")?.split(',').collect();
    let last = lines.next_back().ok_or("no rows")?;
    header
        .iter()
        .zip(last.split(','))
        .skip(1)
        .map(|(name, v)| {
            let name = name.trim().trim_matches('"').to_string();
            let v = v.trim();
            let x = match v {
                "True" | "true" => 1.0,
                "False" | "false" => 0.0,
                _ => v.parse().map_err(|e| format!("{name}: {v:?}: {e}"))?,
            };
            Ok((name, x))
        })
        .collect()
}

/// What a child or script prints: `run STEPS WALL CPU` once, `final NAME VALUE` per output.
fn parse_report(text: &str) -> Result<(Timing, BTreeMap<String, f64>), String> {
    let mut timing = None;
    let mut last = BTreeMap::new();
    for line in text.lines() {
        let f: Vec<&str> = line.split_whitespace().collect();
        match f.as_slice() {
            ["run", _, wall, cpu] => {
                timing = Some(Timing {
                    wall: wall.parse().map_err(|e| format!("{line}: {e}"))?,
                    cpu: cpu.parse().map_err(|e| format!("{line}: {e}"))?,
                })
            }
            ["final", name, value] => {
                last.insert(
                    name.to_string(),
                    value.parse().map_err(|e| format!("{line}: {e}"))?,
                );
            }
            _ => {}
        }
    }
    Ok((
        timing.ok_or_else(|| format!("no `run` line in:\n{text}"))?,
        last,
    ))
}

// ---------------------------------------------------------------------------------------------
// In-process engines (run in a child process of this bench)
// ---------------------------------------------------------------------------------------------

/// The outputs of a model description by type, in declaration order.
struct Outputs {
    real: Vec<(u32, String)>,
    int: Vec<(u32, String)>,
    boolean: Vec<(u32, String)>,
}

impl Outputs {
    fn of(md: &ModelDescription) -> Outputs {
        let mut o = Outputs {
            real: vec![],
            int: vec![],
            boolean: vec![],
        };
        for v in &md.model_variables {
            if v.causality != Some(Causality::Output) {
                continue;
            }
            let entry = (v.value_reference, v.name.clone());
            match v.kind {
                VariableKind::Real { .. } => o.real.push(entry),
                VariableKind::Integer { .. } | VariableKind::Enumeration { .. } => {
                    o.int.push(entry)
                }
                VariableKind::Boolean { .. } => o.boolean.push(entry),
                VariableKind::String { .. } => {}
            }
        }
        o
    }

    fn vrs(list: &[(u32, String)]) -> Vec<u32> {
        list.iter().map(|(vr, _)| *vr).collect()
    }

    fn width(&self) -> usize {
        self.real.len() + self.int.len() + self.boolean.len()
    }

    /// Prints `final NAME VALUE` for the values of the last step.
    fn print_final(&self, reals: &[f64], ints: &[i32], bools: &[i32]) {
        for ((_, n), v) in self.real.iter().zip(reals) {
            println!("final {n} {v:?}");
        }
        for ((_, n), v) in self.int.iter().zip(ints) {
            println!("final {n} {v}");
        }
        for ((_, n), v) in self.boolean.iter().zip(bools) {
            println!("final {n} {}", i32::from(*v != 0));
        }
    }
}

/// Input value references in the order of the input file's columns.
fn input_vrs(md: &ModelDescription, inputs: &Inputs) -> Vec<u32> {
    inputs
        .names
        .iter()
        .map(|n| {
            md.model_variables
                .iter()
                .find(|v| &v.name == n)
                .unwrap_or_else(|| panic!("no variable {n}"))
                .value_reference
        })
        .collect()
}

fn check(status: fmi2StatusCode, what: &str) {
    assert_eq!(status, fmi2Status::fmi2OK, "{what}");
}

/// The bare C-call loop over `steps` steps: instantiate, initialize, steps, terminate, free.
fn c_loop(fmu: &Fmu, raw: &Raw, inputs: Option<&Inputs>, steps: u64) {
    let md = fmu.model_description();
    let out = Outputs::of(md);
    let (rv, iv, bv) = (
        Outputs::vrs(&out.real),
        Outputs::vrs(&out.int),
        Outputs::vrs(&out.boolean),
    );
    let in_vrs = inputs.map(|i| input_vrs(md, i)).unwrap_or_default();
    let args = InstanceArgs::of(fmu, "m");
    let (t0, c0) = (Instant::now(), process_cpu());
    // SAFETY: `raw` is loaded from this FMU's binary (`child`); arrays of the right lengths;
    // the instance is used only between instantiation and freeing, while `args` stays put.
    unsafe {
        let c = args.instantiate(raw);
        check(
            (raw.setup_experiment)(c, fmi2False, 0.0, 0.0, fmi2False, 0.0),
            "setupExperiment",
        );
        check((raw.enter_initialization_mode)(c), "enter");
        check((raw.exit_initialization_mode)(c), "exit");
        let mut rows: Vec<f64> = Vec::with_capacity(out.width() * steps as usize);
        let mut reals = vec![0.0; rv.len()];
        let mut ints = vec![0; iv.len()];
        let mut bools = vec![0; bv.len()];
        for k in 0..steps {
            if let Some(i) = inputs {
                let row = &i.rows[k as usize];
                check(
                    (raw.set_real)(c, in_vrs.as_ptr(), row.len(), row.as_ptr()),
                    "setReal",
                );
            }
            check((raw.do_step)(c, k as f64 * H, H, fmi2True), "doStep");
            check(
                (raw.get_real)(c, rv.as_ptr(), rv.len(), reals.as_mut_ptr()),
                "getReal",
            );
            rows.extend_from_slice(&reals);
            if !iv.is_empty() {
                check(
                    (raw.get_integer)(c, iv.as_ptr(), iv.len(), ints.as_mut_ptr()),
                    "getInteger",
                );
                rows.extend(ints.iter().map(|&v| v as f64));
            }
            if !bv.is_empty() {
                check(
                    (raw.get_boolean)(c, bv.as_ptr(), bv.len(), bools.as_mut_ptr()),
                    "getBoolean",
                );
                rows.extend(bools.iter().map(|&v| v as f64));
            }
        }
        check((raw.terminate)(c), "terminate");
        (raw.free_instance)(c);
        std::hint::black_box(&rows);
        println!(
            "run {steps} {} {}",
            t0.elapsed().as_secs_f64(),
            process_cpu() - c0
        );
        out.print_final(&reals, &ints, &bools);
    }
}

/// Instantiates and frees one instance (a PythonFMU binary initializes its interpreter then).
fn c_loop_prepare(fmu: &Fmu, raw: &Raw) {
    let args = InstanceArgs::of(fmu, "warm-up");
    // SAFETY: `raw` is loaded from this FMU's binary (`child`); the instance is freed at
    // once, while `args` stays put.
    unsafe {
        let c = args.instantiate(raw);
        (raw.free_instance)(c);
    }
}

/// What `fmi2Instantiate` is given for an instance of `fmu` (its name, the GUID, the resource
/// URI and the callbacks), kept for as long as the instance lives: the FMU may hold the
/// callbacks' address.
struct InstanceArgs {
    name: CString,
    guid: CString,
    uri: CString,
    callbacks: fmi2CallbackFunctions,
}

impl InstanceArgs {
    fn of(fmu: &Fmu, name: &str) -> InstanceArgs {
        InstanceArgs {
            name: CString::new(name).unwrap(),
            guid: CString::new(fmu.model_description().guid.as_str()).unwrap(),
            uri: CString::new(fmu.resource_uri()).unwrap(),
            callbacks: fmi2CallbackFunctions {
                logger: test_logger(),
                allocateMemory: None,
                freeMemory: None,
                stepFinished: None,
                componentEnvironment: std::ptr::null_mut(),
            },
        }
    }

    /// A co-simulation instance, not visible and without logging; panics when refused.
    ///
    /// # Safety
    /// `raw` is the FMU's own functions, and the instance must be freed before `self` is
    /// moved or dropped (it may keep the address of `self`'s strings and callbacks).
    unsafe fn instantiate(&self, raw: &Raw) -> *mut c_void {
        // SAFETY: valid NUL-terminated strings and callbacks that outlive the instance (the
        // caller's promise).
        let c = unsafe {
            (raw.instantiate)(
                self.name.as_ptr(),
                fmi2Type::fmi2CoSimulation as i32,
                self.guid.as_ptr(),
                self.uri.as_ptr(),
                &self.callbacks,
                fmi2False,
                fmi2False,
            )
        };
        assert!(!c.is_null(), "fmi2Instantiate");
        c
    }
}

/// `System::run` of the FMU alone, inputs from signals, every output recorded in memory.
fn harness_run(fmu: &Fmu, inputs: Option<&Inputs>, steps: u64) {
    let (t0, c0) = (Instant::now(), process_cpu());
    let mut system = System::new();
    system.add_component("m", fmu.clone()).unwrap();
    system.set_column_prefix(false);
    if let Some(i) = inputs {
        for (j, name) in i.names.iter().enumerate() {
            let signal = Signal {
                times: i.times.clone(),
                values: i.rows.iter().map(|r| r[j]).collect(),
                interpolate: true,
            };
            system.add_signal(&format!("m.{name}"), signal).unwrap();
        }
    }
    let config = RunConfig {
        stop_time: steps as f64 * H,
        step_size: H,
        ..RunConfig::default()
    };
    let out = system.run(&config).unwrap();
    let (wall, cpu) = (t0.elapsed().as_secs_f64(), process_cpu() - c0);
    assert!(
        matches!(out.outcome, Outcome::Completed { .. }),
        "{:?}",
        out.outcome
    );
    println!("run {steps} {wall} {cpu}");
    for name in out.results.names() {
        let column = out.results.column(name).unwrap();
        println!("final {name} {:?}", column.last().unwrap());
    }
}

/// fmi-rs's `FMU2<CS>` in a loop: created (which loads the binary), initialized, stepped,
/// terminated and dropped.
fn fmi_rs_loop(unzipdir: &Path, inputs: Option<&Inputs>, steps: u64) {
    use fmi_rs::fmi2::types::fmi2Status as Status;
    use fmi_rs::fmi2::{CS, FMU2};
    use fmi_rs::model_description::fmi2::{
        Causality as FCausality, ModelDescription as FModelDescription, VariableType,
    };
    let ok = |s: Status, what: &str| assert!(s == Status::Ok, "fmi-rs {what}: {s:?}");
    let md = FModelDescription::from_path(&unzipdir.join("modelDescription.xml"))
        .expect("fmi-rs reads the model description");
    let cs = md.coSimulation.as_ref().expect("co-simulation");
    let (mut rv, mut iv, mut bv) = (vec![], vec![], vec![]);
    let out = {
        let mut o = Outputs {
            real: vec![],
            int: vec![],
            boolean: vec![],
        };
        for v in md
            .modelVariables
            .iter()
            .filter(|v| v.causality == FCausality::Output)
        {
            let entry = (v.valueReference, v.name.clone());
            match v.variableType {
                VariableType::Real { .. } => o.real.push(entry),
                VariableType::Integer { .. } | VariableType::Enumeration { .. } => {
                    o.int.push(entry)
                }
                VariableType::Boolean { .. } => o.boolean.push(entry),
                VariableType::String { .. } => {}
            }
        }
        rv.extend(Outputs::vrs(&o.real));
        iv.extend(Outputs::vrs(&o.int));
        bv.extend(Outputs::vrs(&o.boolean));
        o
    };
    let in_vrs: Vec<u32> = inputs
        .map(|i| {
            i.names
                .iter()
                .map(|n| {
                    md.modelVariables
                        .iter()
                        .find(|v| &v.name == n)
                        .expect("input")
                        .valueReference
                })
                .collect()
        })
        .unwrap_or_default();
    let logger = std::sync::Arc::new(fmi_rs::fmi2::log::DefaultLogger::default());
    let (t0, c0) = (Instant::now(), process_cpu());
    let fmu = FMU2::<CS>::new(
        unzipdir,
        &cs.modelIdentifier,
        "m",
        &md.guid,
        false,
        false,
        false,
        logger,
        !cs.canNotUseMemoryManagementFunctions,
    )
    .expect("fmi-rs instantiates the FMU");
    ok(fmu.setupExperiment(None, 0.0, None), "setupExperiment");
    ok(fmu.enterInitializationMode(), "enterInitializationMode");
    ok(fmu.exitInitializationMode(), "exitInitializationMode");
    let mut rows: Vec<f64> = Vec::with_capacity(out.width() * steps as usize);
    let mut reals = vec![0.0; rv.len()];
    let mut ints = vec![0; iv.len()];
    let mut bools = vec![0; bv.len()];
    for k in 0..steps {
        if let Some(i) = inputs {
            ok(fmu.setReal(&in_vrs, &i.rows[k as usize]), "setReal");
        }
        ok(fmu.doStep(k as f64 * H, H, 1), "doStep");
        ok(fmu.getReal(&rv, &mut reals), "getReal");
        rows.extend_from_slice(&reals);
        if !iv.is_empty() {
            ok(fmu.getInteger(&iv, &mut ints), "getInteger");
            rows.extend(ints.iter().map(|&v| v as f64));
        }
        if !bv.is_empty() {
            ok(fmu.getBoolean(&bv, &mut bools), "getBoolean");
            rows.extend(bools.iter().map(|&v| v as f64));
        }
    }
    ok(fmu.terminate(), "terminate");
    drop(fmu);
    let (wall, cpu) = (t0.elapsed().as_secs_f64(), process_cpu() - c0);
    std::hint::black_box(&rows);
    println!("run {steps} {wall} {cpu}");
    out.print_final(&reals, &ints, &bools);
}

/// The child process: one run of one in-process engine (see [`CHILD_ENGINE`]).
fn child(engine: &str) {
    let var = |name: &str| std::env::var_os(name).unwrap_or_else(|| panic!("{name} unset"));
    let fmu_path = PathBuf::from(var(CHILD_FMU));
    let inputs_path = PathBuf::from(var(CHILD_INPUTS));
    let inputs = (!inputs_path.as_os_str().is_empty()).then(|| read_inputs(&inputs_path));
    let steps: u64 = var(CHILD_STEPS).to_str().unwrap().parse().unwrap();
    let preload: Vec<PathBuf> = std::env::var_os(CHILD_PRELOAD)
        .map(|p| vec![PathBuf::from(p)])
        .unwrap_or_default();
    // Loaded once before any timing: the extraction is start-up for every engine, and keeping
    // the binary loaded keeps fmi-rs's load of the same file from unloading it at the end (a
    // PythonFMU binary finalizes its interpreter when unloaded).
    let options = LoadOptions {
        preload,
        ..LoadOptions::default()
    };
    let fmu = Fmu::load(&fmu_path, &options).expect("load the FMU");
    match engine {
        "c-loop" => {
            let raw = Raw::load(fmu.binary_path());
            c_loop(&fmu, &raw, inputs.as_ref(), steps);
        }
        "c-loop-held" => {
            let libpython = std::env::var_os(CHILD_PRELOAD).expect("a PythonFMU export");
            // SAFETY: the runtime the harness has just preloaded; the functions' C signatures.
            unsafe {
                let lib = libloading::Library::new(&libpython).expect("libpython");
                let ensure: libloading::Symbol<unsafe extern "C" fn() -> i32> =
                    lib.get(b"PyGILState_Ensure\0").expect("PyGILState_Ensure");
                let save: libloading::Symbol<unsafe extern "C" fn() -> *mut c_void> =
                    lib.get(b"PyEval_SaveThread\0").expect("PyEval_SaveThread");
                // The FMU's first instantiation initializes the interpreter: one instance
                // before taking the thread state.
                let raw = Raw::load(fmu.binary_path());
                c_loop_prepare(&fmu, &raw);
                ensure();
                save();
                c_loop(&fmu, &raw, inputs.as_ref(), steps);
                std::mem::forget(lib);
            }
        }
        "harness" => harness_run(&fmu, inputs.as_ref(), steps),
        "fmi-rs" => {
            let dir = tempfile::tempdir().unwrap();
            fmi_rs::zip::extract_zip_archive(&fmu_path, dir.path()).expect("fmi-rs extracts");
            // The same file as fmi-rs's load, so that its dlclose does not unload it.
            let binary = dir.path().join(format!(
                "binaries/linux64/{}.so",
                fmu.model_description()
                    .co_simulation
                    .as_ref()
                    .unwrap()
                    .model_identifier
            ));
            // SAFETY: the FMU's binary, which the harness has just loaded from a copy.
            let _pinned = unsafe { libloading::Library::new(&binary) }.expect("load the binary");
            fmi_rs_loop(dir.path(), inputs.as_ref(), steps);
        }
        other => panic!("{CHILD_ENGINE}={other}: c-loop|c-loop-held|harness|fmi-rs"),
    }
}

// ---------------------------------------------------------------------------------------------
// Python engines
// ---------------------------------------------------------------------------------------------

/// fmpy's `simulate_fmu` and `write_csv`, the whole process (argv: fmu, inputs or "", stop
/// time, step, output file).
const FMPY_SIMULATE: &str = r#"
import sys
import numpy as np
from fmpy import simulate_fmu
from fmpy.util import write_csv
fmu, inputs, stop, step, out = sys.argv[1:6]
data = np.genfromtxt(inputs, delimiter=",", names=True, deletechars="") if inputs else None
r = simulate_fmu(fmu, fmi_type="CoSimulation", start_time=0.0, stop_time=float(stop),
                 step_size=float(step), output_interval=float(step), input=data)
write_csv(out, r)
"#;

/// fmpy's `FMU2Slave` loop, timed around instantiation to freeing (argv: fmu, inputs or "",
/// steps, step). Prints the same report as the Rust children.
const FMPY_LOOP: &str = r#"
import sys, time
from fmpy import read_model_description, extract
from fmpy.fmi2 import FMU2Slave
path, inputs, steps, h = sys.argv[1], sys.argv[2], int(sys.argv[3]), float(sys.argv[4])
md = read_model_description(path)
by_name = {v.name: v for v in md.modelVariables}
outs = [v for v in md.modelVariables if v.causality == "output"]
real = [v for v in outs if v.type == "Real"]
ints = [v for v in outs if v.type in ("Integer", "Enumeration")]
bools = [v for v in outs if v.type == "Boolean"]
rv, iv, bv = ([v.valueReference for v in l] for l in (real, ints, bools))
in_vrs, rows = [], []
if inputs:
    with open(inputs) as f:
        names = f.readline().strip().split(",")[1:]
        rows = [[float(x) for x in line.split(",")[1:]] for line in f]
    in_vrs = [by_name[n].valueReference for n in names]
unzipdir = extract(path)
t0, c0 = time.perf_counter(), time.process_time()
fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir,
                modelIdentifier=md.coSimulation.modelIdentifier, instanceName="m")
fmu.instantiate()
fmu.setupExperiment(startTime=0.0)
fmu.enterInitializationMode()
fmu.exitInitializationMode()
record = []
r, i, b = [], [], []
for k in range(steps):
    if in_vrs:
        fmu.setReal(in_vrs, rows[k])
    fmu.doStep(currentCommunicationPoint=k * h, communicationStepSize=h)
    r = fmu.getReal(rv)
    record.append(r)
    if iv:
        i = fmu.getInteger(iv)
        record.append(i)
    if bv:
        b = fmu.getBoolean(bv)
        record.append(b)
fmu.terminate()
fmu.freeInstance()
print("run", steps, time.perf_counter() - t0, time.process_time() - c0)
for v, x in zip(real, r):
    print("final", v.name, repr(float(x)))
for v, x in zip(ints, i):
    print("final", v.name, int(x))
for v, x in zip(bools, b):
    print("final", v.name, int(bool(x)))
"#;

/// The venv's Python, checked: fmpy, numpy and pythonfmu import. `Err`: what is missing and how
/// to install it.
fn find_python() -> Result<PathBuf, String> {
    let python = std::env::var_os("KNEEBENCH_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| repo_root().join(".venv/bin/python"));
    let how = "install the pinned fmpy and pythonfmu with `bash scripts/setup-python.sh` \
               (creates .venv), or set KNEEBENCH_PYTHON to a Python that has them";
    if !python.is_file() {
        return Err(format!("no Python at {}: {how}", python.display()));
    }
    let out = Command::new(&python)
        .args([
            "-c",
            "import importlib.util as u\n\
             print(' '.join(m for m in ('fmpy', 'numpy', 'pythonfmu') if u.find_spec(m) is None))",
        ])
        .output()
        .map_err(|e| format!("cannot run {}: {e}; {how}", python.display()))?;
    let missing = String::from_utf8_lossy(&out.stdout).trim().to_string();
    if !out.status.success() {
        return Err(format!(
            "{} does not run: {}; {how}",
            python.display(),
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    if !missing.is_empty() {
        return Err(format!(
            "{} lacks the Python packages {missing}: {how}",
            python.display()
        ));
    }
    Ok(python)
}

// ---------------------------------------------------------------------------------------------
// The table
// ---------------------------------------------------------------------------------------------

/// An engine of the table.
#[derive(Clone, Copy, PartialEq)]
enum Engine {
    CLoop,
    CLoopHeldThreadState,
    KneebenchRun,
    KneebenchRunInProcess,
    Harness,
    FmpySimulate,
    FmpyLoop,
    FmiRs,
}

impl Engine {
    fn label(self) -> &'static str {
        match self {
            Engine::CLoop => "bare C-call loop (the FMU's own cost)",
            Engine::CLoopHeldThreadState => "bare C-call loop, Python thread state held",
            Engine::KneebenchRun => "kneebench run, whole process",
            Engine::KneebenchRunInProcess => "kneebench run --isolate never, whole process",
            Engine::Harness => "kneebench System::run, in process",
            Engine::FmpySimulate => "fmpy simulate_fmu, whole process",
            Engine::FmpyLoop => "fmpy FMU2Slave loop, in process",
            Engine::FmiRs => "fmi-rs FMU2 loop, in process",
        }
    }

    fn is_peer(self) -> bool {
        matches!(
            self,
            Engine::FmpySimulate | Engine::FmpyLoop | Engine::FmiRs
        )
    }
}

/// An FMU of the table.
struct Case {
    label: &'static str,
    fmu: PathBuf,
    inputs: Option<PathBuf>,
    /// The PythonFMU export's runtime (preloaded, `PYTHONHOME`).
    python_runtime: Option<PythonRuntime>,
}

/// Everything the runs need.
struct Setup {
    kneebench: Option<PathBuf>,
    python: Option<PathBuf>,
    scratch: PathBuf,
}

/// The venv's Python running one of the fmpy scripts on `case`'s FMU and its inputs file
/// (empty: none); the caller adds the script's other arguments.
fn fmpy_script(
    setup: &Setup,
    script: &str,
    case: &Case,
    inputs: &std::ffi::OsStr,
) -> Result<Command, String> {
    let python = setup.python.as_ref().ok_or("no Python")?;
    let mut cmd = Command::new(python);
    cmd.arg("-c").arg(script).arg(&case.fmu).arg(inputs);
    Ok(cmd)
}

/// One run of `engine` on `case` for `steps` steps.
fn run_once(
    setup: &Setup,
    case: &Case,
    engine: Engine,
    steps: u64,
) -> Result<(Timing, BTreeMap<String, f64>), String> {
    let stop = format!("{}", steps as f64 * H);
    let out_csv = setup.scratch.join("out.csv");
    let _ = std::fs::remove_file(&out_csv);
    let inputs = case
        .inputs
        .as_ref()
        .map(|p| p.as_os_str().to_owned())
        .unwrap_or_default();
    match engine {
        Engine::CLoop | Engine::CLoopHeldThreadState | Engine::Harness | Engine::FmiRs => {
            let name = match engine {
                Engine::CLoop => "c-loop",
                Engine::CLoopHeldThreadState => "c-loop-held",
                Engine::Harness => "harness",
                _ => "fmi-rs",
            };
            let mut cmd = Command::new(std::env::current_exe().unwrap());
            cmd.env(CHILD_ENGINE, name)
                .env(CHILD_FMU, &case.fmu)
                .env(CHILD_INPUTS, &inputs)
                .env(CHILD_STEPS, steps.to_string());
            if let Some(rt) = &case.python_runtime {
                cmd.env(CHILD_PRELOAD, &rt.libpython)
                    .env("PYTHONHOME", &rt.home);
            }
            let (_, stdout) = time_process(&mut cmd)?;
            parse_report(&stdout)
        }
        Engine::KneebenchRun | Engine::KneebenchRunInProcess => {
            let exe = setup.kneebench.as_ref().ok_or("no kneebench binary")?;
            let mut cmd = Command::new(exe);
            cmd.arg("run")
                .arg(&case.fmu)
                .args(["--stop-time", &stop, "--step", &H.to_string(), "--quiet"])
                .arg("--output")
                .arg(&out_csv);
            if !inputs.is_empty() {
                cmd.arg("--inputs").arg(&inputs);
            }
            if let Some(rt) = &case.python_runtime {
                cmd.arg("--preload")
                    .arg(&rt.libpython)
                    .arg("--force")
                    .env("PYTHONHOME", &rt.home);
            }
            if engine == Engine::KneebenchRunInProcess {
                cmd.args(["--isolate", "never"]);
            }
            let (timing, _) = time_process(&mut cmd)?;
            Ok((timing, last_row_of_csv(&out_csv)?))
        }
        Engine::FmpySimulate => {
            let mut cmd = fmpy_script(setup, FMPY_SIMULATE, case, &inputs)?;
            cmd.args([&stop, &H.to_string()]).arg(&out_csv);
            let (timing, _) = time_process(&mut cmd)?;
            Ok((timing, last_row_of_csv(&out_csv)?))
        }
        Engine::FmpyLoop => {
            let mut cmd = fmpy_script(setup, FMPY_LOOP, case, &inputs)?;
            cmd.args([steps.to_string(), H.to_string()]);
            let (_, stdout) = time_process(&mut cmd)?;
            parse_report(&stdout)
        }
    }
}

/// Per-step and start-up costs of an engine, from the minima over the repeats.
struct Row {
    engine: Engine,
    /// Minimum wall and CPU times at each step count.
    min: [Timing; 2],
    last: BTreeMap<String, f64>,
}

impl Row {
    /// Seconds per step (wall, CPU): the slope between the two step counts.
    fn per_step(&self, steps: [u64; 2]) -> Timing {
        let n = (steps[1] - steps[0]) as f64;
        Timing {
            wall: (self.min[1].wall - self.min[0].wall) / n,
            cpu: (self.min[1].cpu - self.min[0].cpu) / n,
        }
    }

    /// Start-up seconds (wall, CPU): the time of the short run less its steps.
    fn start_up(&self, steps: [u64; 2]) -> Timing {
        let s = self.per_step(steps);
        Timing {
            wall: self.min[0].wall - steps[0] as f64 * s.wall,
            cpu: self.min[0].cpu - steps[0] as f64 * s.cpu,
        }
    }
}

/// The largest relative difference between two last rows over the names of `reference`
/// (`None` if a name is missing).
fn largest_difference(
    reference: &BTreeMap<String, f64>,
    other: &BTreeMap<String, f64>,
) -> Option<f64> {
    let mut worst = 0.0f64;
    for (name, &x) in reference {
        let y = *other.get(name)?;
        worst = worst.max((x - y).abs() / x.abs().max(y.abs()).max(1.0));
    }
    Some(worst)
}

fn env_steps() -> [u64; 2] {
    match std::env::var("KNEEBENCH_PEERS_STEPS") {
        Ok(s) => {
            let v: Vec<u64> = s
                .split(',')
                .map(|x| x.trim().parse().expect("KNEEBENCH_PEERS_STEPS=N1,N2"))
                .collect();
            assert!(
                v.len() == 2 && 0 < v[0] && v[0] < v[1],
                "KNEEBENCH_PEERS_STEPS=N1,N2 with 0 < N1 < N2"
            );
            [v[0], v[1]]
        }
        Err(_) => DEFAULT_STEPS,
    }
}

fn main() {
    if let Ok(engine) = std::env::var(CHILD_ENGINE) {
        child(&engine);
        return;
    }
    let steps = env_steps();
    let repeats: usize = std::env::var("KNEEBENCH_PEERS_REPEATS")
        .map(|s| s.parse().expect("KNEEBENCH_PEERS_REPEATS=N"))
        .unwrap_or(DEFAULT_REPEATS);

    let scratch = tempfile::tempdir().unwrap();
    let kneebench = build_kneebench()
        .map_err(|e| println!("peers: the kneebench rows are skipped: {e}"))
        .ok();
    let python = find_python()
        .map_err(|e| println!("peers: the fmpy rows and the PythonFMU export are skipped: {e}"))
        .ok();

    let exported = export_all(&fmu_library(), scratch.path()).expect("export our FMUs");
    let ours = |id: &str| {
        exported
            .iter()
            .find(|f| f.identifier == id)
            .unwrap_or_else(|| panic!("no {id}"))
            .path
            .clone()
    };
    let specs: [(&str, Option<InputSpec>); 3] = [
        ("GaitReference", None),
        (
            "PidController",
            Some(InputSpec {
                names: &["setpoint", "measurement"],
                values: pid_inputs,
            }),
        ),
        (
            "BenchPlant",
            Some(InputSpec {
                names: &["testCurrentCommand", "loadCurrentCommand"],
                values: plant_inputs,
            }),
        ),
    ];
    let mut cases = vec![];
    for (id, spec) in specs {
        let inputs = spec.map(|s| {
            let path = scratch.path().join(format!("{id}-inputs.csv"));
            write_inputs(&path, &s, steps[1]).expect("write the inputs");
            path
        });
        cases.push(Case {
            label: id,
            fmu: ours(id),
            inputs,
            python_runtime: None,
        });
    }
    if let Some(py) = &python {
        let built = pythonfmu::runtime(py).and_then(|rt| {
            let dir = scratch.path().join("pythonfmu");
            pythonfmu::build_first_order(py, &dir).map(|fmu| (rt, fmu))
        });
        match built {
            Ok((rt, fmu)) => {
                let path = scratch.path().join("FirstOrder-inputs.csv");
                let spec = InputSpec {
                    names: &["u"],
                    values: first_order_inputs,
                };
                write_inputs(&path, &spec, steps[1]).expect("write the inputs");
                cases.push(Case {
                    label: "FirstOrder (PythonFMU 0.7.0 export)",
                    fmu,
                    inputs: Some(path),
                    python_runtime: Some(rt),
                });
            }
            Err(e) => println!("peers: the PythonFMU export is skipped: {e}"),
        }
    }
    if let Ok(only) = std::env::var("KNEEBENCH_PEERS_ONLY") {
        cases.retain(|c| only.split(',').any(|o| c.label.starts_with(o.trim())));
    }
    let setup = Setup {
        kneebench,
        python,
        scratch: scratch.path().to_path_buf(),
    };

    let load = || {
        std::fs::read_to_string("/proc/loadavg")
            .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
            .unwrap_or_default()
    };
    println!(
        "peers: {} and {} steps of {H} s, every output recorded, minimum of {repeats} runs; load average {}",
        steps[0],
        steps[1],
        load()
    );
    let mut summary = vec![];
    for case in &cases {
        let mut engines = vec![
            Engine::CLoop,
            Engine::KneebenchRun,
            Engine::Harness,
            Engine::FmpySimulate,
            Engine::FmpyLoop,
            Engine::FmiRs,
        ];
        if case.python_runtime.is_some() {
            engines.insert(1, Engine::CLoopHeldThreadState);
            engines.insert(3, Engine::KneebenchRunInProcess);
        }
        let runnable = |e: &Engine| match e {
            Engine::FmpySimulate | Engine::FmpyLoop => setup.python.is_some(),
            Engine::KneebenchRun | Engine::KneebenchRunInProcess => setup.kneebench.is_some(),
            _ => true,
        };
        engines.retain(runnable);
        let mut minima: Vec<[Option<Timing>; 2]> = vec![[None; 2]; engines.len()];
        let mut lasts: Vec<Option<BTreeMap<String, f64>>> = vec![None; engines.len()];
        let mut failures: Vec<Option<String>> = vec![None; engines.len()];
        for _ in 0..repeats {
            for (e, &engine) in engines.iter().enumerate() {
                if failures[e].is_some() {
                    continue;
                }
                for (s, &n) in steps.iter().enumerate() {
                    match run_once(&setup, case, engine, n) {
                        Ok((t, last)) => {
                            let m = minima[e][s].get_or_insert(t);
                            m.wall = m.wall.min(t.wall);
                            m.cpu = m.cpu.min(t.cpu);
                            if s == 1 {
                                lasts[e] = Some(last);
                            }
                        }
                        Err(msg) => failures[e] = Some(msg),
                    }
                }
            }
        }
        let rows: Vec<Result<Row, String>> = engines
            .iter()
            .enumerate()
            .map(|(e, &engine)| match (&failures[e], minima[e], &lasts[e]) {
                (Some(msg), ..) => Err(msg.clone()),
                (None, [Some(a), Some(b)], Some(last)) => Ok(Row {
                    engine,
                    min: [a, b],
                    last: last.clone(),
                }),
                _ => Err("no run".into()),
            })
            .collect();
        print_case(case, &rows, steps, load(), &mut summary);
    }
    print_summary(&summary);
}

/// A line of the summary: the FMU and per-step CPU seconds of each engine.
struct SummaryLine {
    label: &'static str,
    per_step: Vec<(Engine, f64)>,
}

fn print_case(
    case: &Case,
    rows: &[Result<Row, String>],
    steps: [u64; 2],
    load: String,
    summary: &mut Vec<SummaryLine>,
) {
    let ok: Vec<&Row> = rows.iter().filter_map(|r| r.as_ref().ok()).collect();
    let reference = ok
        .iter()
        .find(|r| r.engine == Engine::CLoop)
        .map(|r| r.last.clone());
    let fastest_peer = ok
        .iter()
        .filter(|r| r.engine.is_peer())
        .map(|r| (r.engine, r.per_step(steps).cpu))
        .min_by(|a, b| a.1.total_cmp(&b.1));
    let c_loop = ok
        .iter()
        .find(|r| r.engine == Engine::CLoop)
        .map(|r| r.per_step(steps).cpu);
    println!();
    println!("{} (load average after: {load})", case.label);
    println!(
        "{:<46} {:>11} {:>11} {:>11} {:>11} {:>12} {:>12} {:>10}",
        "engine",
        "start wall",
        "start CPU",
        "us/step",
        "us/step",
        "fastest peer",
        "/ bare",
        "last row"
    );
    println!(
        "{:<46} {:>11} {:>11} {:>11} {:>11} {:>12} {:>12} {:>10}",
        "", "ms", "ms", "wall", "CPU", "/ this, CPU", "C loop, CPU", "vs C loop"
    );
    let mut line = SummaryLine {
        label: case.label,
        per_step: vec![],
    };
    for r in rows {
        match r {
            Err(msg) => println!("FAILED: {msg}"),
            Ok(r) => {
                let (s, u) = (r.start_up(steps), r.per_step(steps));
                line.per_step.push((r.engine, u.cpu));
                let peer = fastest_peer
                    .map(|(_, p)| format!("{:.2}x", p / u.cpu))
                    .unwrap_or_default();
                let bare = c_loop
                    .map(|c| format!("{:.2}x", u.cpu / c))
                    .unwrap_or_default();
                let agree = match reference.as_ref().map(|re| largest_difference(re, &r.last)) {
                    Some(Some(d)) => format!("{d:.1e}"),
                    Some(None) => "columns?".into(),
                    None => String::new(),
                };
                println!(
                    "{:<46} {:>11.1} {:>11.1} {:>11.3} {:>11.3} {:>12} {:>12} {:>10}",
                    r.engine.label(),
                    s.wall * 1e3,
                    s.cpu * 1e3,
                    u.wall * 1e6,
                    u.cpu * 1e6,
                    peer,
                    bare,
                    agree
                );
            }
        }
    }
    if let Some((peer, p)) = fastest_peer {
        for r in &ok {
            if matches!(
                r.engine,
                Engine::KneebenchRun | Engine::KneebenchRunInProcess
            ) {
                let x = p / r.per_step(steps).cpu;
                println!(
                    "{}: {x:.2}x faster per step (CPU) than the fastest peer ({}); target >= 3x: {}",
                    r.engine.label(),
                    peer.label(),
                    if x >= 3.0 { "met" } else { "MISSED" }
                );
            }
        }
    } else {
        println!("no peer ran: no ratio");
    }
    summary.push(line);
}

/// The README table: per-step CPU time of every engine, and the whole-process ratio.
fn print_summary(summary: &[SummaryLine]) {
    let columns = [
        Engine::CLoop,
        Engine::KneebenchRun,
        Engine::Harness,
        Engine::FmpySimulate,
        Engine::FmpyLoop,
        Engine::FmiRs,
    ];
    println!();
    println!("Per-step CPU time in us (README table):");
    println!();
    println!(
        "| FMU | bare C loop | kneebench run (whole process) | kneebench System::run | fmpy simulate_fmu (whole process) | fmpy FMU2Slave loop | fmi-rs FMU2 loop | kneebench run vs fastest peer |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for line in summary {
        let get = |e: Engine| line.per_step.iter().find(|(x, _)| *x == e).map(|x| x.1);
        let cells: Vec<String> = columns
            .iter()
            .map(|&e| {
                get(e)
                    .map(|v| format!("{:.3}", v * 1e6))
                    .unwrap_or_else(|| "-".into())
            })
            .collect();
        let peer = line
            .per_step
            .iter()
            .filter(|(e, _)| e.is_peer())
            .map(|x| x.1)
            .min_by(f64::total_cmp);
        let ratio = match (peer, get(Engine::KneebenchRun)) {
            (Some(p), Some(k)) => format!("{:.2}x", p / k),
            _ => "-".into(),
        };
        println!("| {} | {} | {ratio} |", line.label, cells.join(" | "));
    }
}
