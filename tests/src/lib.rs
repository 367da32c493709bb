//! Helpers shared by the end-to-end tests: where the built binaries are, how to reach the
//! project's Python venv with the pinned fmpy, and a raw FMI 2.0 binding that can make every
//! call an importer can make, including the wrong ones.

use std::ffi::{CStr, CString, c_char, c_int, c_void};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

pub mod campaign;
pub mod loop_memory;
pub mod pythonfmu;

pub use kneebench_fmu::fmi2::types::*;

/// The study's SEA gait scenario (one cycle, the study's gains) written as `dir/SEA.ssp` from
/// the exported FMUs in `fmus`: the system the benches run, and its path.
pub fn write_sea_ssp(fmus: &Path, dir: &Path) -> (kneebench_harness::study::Scenario, PathBuf) {
    use kneebench_harness::study::{Actuator, Gait, StudyGains, gait_scenario, write_ssp};
    let scenario = gait_scenario(
        Actuator::Sea,
        Gait::bench_full(),
        StudyGains::for_actuator(Actuator::Sea),
        1,
    );
    let path = dir.join("SEA.ssp");
    write_ssp(&scenario, fmus, &path).expect("the SEA scenario is written");
    (scenario, path)
}

/// The repository root.
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("tests/ has a parent")
        .to_path_buf()
}

/// The cargo profile directory of the running test (`target/<profile>`).
pub fn profile_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("current exe");
    // target/<profile>/deps/<test binary>
    exe.parent()
        .and_then(Path::parent)
        .expect("test binary lives in target/<profile>/deps")
        .to_path_buf()
}

/// The FMU binary, built by cargo as this crate's dependency (cargo builds every crate type
/// of a dependency, so the cdylib lands in `deps/`).
pub fn fmu_library() -> PathBuf {
    let dir = profile_dir();
    [
        dir.join("deps/libkneebench_fmu.so"),
        dir.join("libkneebench_fmu.so"),
    ]
    .into_iter()
    .find(|p| p.is_file())
    .unwrap_or_else(|| panic!("libkneebench_fmu.so missing under {}", dir.display()))
}

/// The Python of the project's venv (pinned fmpy), created on first use.
pub fn python() -> PathBuf {
    static PYTHON: OnceLock<PathBuf> = OnceLock::new();
    PYTHON
        .get_or_init(|| {
            if let Ok(p) = std::env::var("KNEEBENCH_PYTHON") {
                return PathBuf::from(p);
            }
            let out = Command::new("bash")
                .arg(repo_root().join("scripts/setup-python.sh"))
                .output()
                .expect("run scripts/setup-python.sh");
            assert!(
                out.status.success(),
                "setup-python.sh failed: {}",
                String::from_utf8_lossy(&out.stderr)
            );
            PathBuf::from(String::from_utf8(out.stdout).unwrap().trim())
        })
        .clone()
}

/// Runs a Python snippet in the venv; returns stdout, panics with stderr on failure.
pub fn run_python(script: &str, args: &[&str]) -> String {
    let out = Command::new(python())
        .arg("-c")
        .arg(script)
        .args(args)
        .output()
        .expect("run python");
    assert!(
        out.status.success(),
        "python failed:\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// fmpy's package directory (headers under `c-code/`).
pub fn fmpy_dir() -> PathBuf {
    PathBuf::from(
        run_python(
            "import fmpy, os; print(os.path.dirname(fmpy.__file__))",
            &[],
        )
        .trim(),
    )
}

/// The GUID of a model of the binary.
pub fn guid_of(identifier: &str) -> String {
    kneebench_fmu::registry::find_by_identifier(identifier)
        .expect("model exists")
        .info()
        .guid
        .clone()
}

/// The value references of every Real output of `md`, in declaration order (what the
/// bit-for-bit comparisons of whole steps read).
pub fn real_outputs(md: &model_description::ModelDescription) -> Vec<u32> {
    md.model_variables
        .iter()
        .filter(|v| {
            v.causality == Some(model_description::Causality::Output)
                && matches!(v.kind, model_description::VariableKind::Real { .. })
        })
        .map(|v| v.value_reference)
        .collect()
}

/// Asserts that a child process that ran one `#[ignore]`d test of its own test binary succeeded
/// and that the test really ran (a filter that matches nothing exits 0 as well); the failure
/// message carries the child's stdout and stderr.
pub fn assert_child_test_ran(out: &std::process::Output) {
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "the child failed:\n{text}");
    assert!(
        text.contains("test result: ok. 1 passed"),
        "the child test did not run:\n{text}"
    );
}

/// Messages collected by the C test logger (layout of `kb_log` in `c/test_logger.c`).
#[repr(C)]
pub struct LogBuffer {
    buf: [u8; 1 << 16],
    len: usize,
    /// Number of messages received.
    pub count: c_int,
    /// The componentEnvironment the last message carried.
    pub last_environment: *mut c_void,
}

impl LogBuffer {
    /// An empty buffer, boxed so that its address is stable.
    pub fn new() -> Box<Self> {
        Box::new(Self {
            buf: [0; 1 << 16],
            len: 0,
            count: 0,
            last_environment: std::ptr::null_mut(),
        })
    }
    /// The messages so far, one per line: `[status|category|instance] message`.
    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.buf[..self.len]).into_owned()
    }
    /// Forgets the messages so far.
    pub fn clear(&mut self) {
        self.len = 0;
        self.count = 0;
    }
}

unsafe extern "C" {
    fn kb_test_logger(
        env: *mut c_void,
        name: *const c_char,
        status: c_int,
        category: *const c_char,
        fmt: *const c_char,
        ...
    );
}

/// The test logger as an FMI callback.
pub fn test_logger() -> fmi2CallbackLogger {
    // SAFETY: kb_test_logger has the C signature of fmi2CallbackLogger; fmi2Status is a C int
    // enum, passed identically.
    Some(unsafe {
        std::mem::transmute::<
            unsafe extern "C" fn(
                *mut c_void,
                *const c_char,
                c_int,
                *const c_char,
                *const c_char,
                ...
            ),
            unsafe extern "C" fn(
                fmi2ComponentEnvironment,
                fmi2String,
                fmi2Status,
                fmi2String,
                fmi2String,
                ...
            ),
        >(kb_test_logger)
    })
}

/// The FMI functions of a binary, resolved by name, called raw.
pub struct Raw {
    _lib: libloading::Library,
    /// fmi2Instantiate with `fmuType` as a plain int, to test invalid values.
    pub instantiate: unsafe extern "C" fn(
        fmi2String,
        c_int,
        fmi2String,
        fmi2String,
        *const fmi2CallbackFunctions,
        fmi2Boolean,
        fmi2Boolean,
    ) -> fmi2Component,
    /// fmi2FreeInstance.
    pub free_instance: fmi2FreeInstanceTYPE,
    /// fmi2SetDebugLogging.
    pub set_debug_logging: fmi2SetDebugLoggingTYPE,
    /// fmi2SetupExperiment.
    pub setup_experiment: fmi2SetupExperimentTYPE,
    /// fmi2EnterInitializationMode.
    pub enter_initialization_mode: fmi2ComponentOnlyTYPE,
    /// fmi2ExitInitializationMode.
    pub exit_initialization_mode: fmi2ComponentOnlyTYPE,
    /// fmi2Terminate.
    pub terminate: fmi2ComponentOnlyTYPE,
    /// fmi2Reset.
    pub reset: fmi2ComponentOnlyTYPE,
    /// fmi2GetReal.
    pub get_real: fmi2GetRealTYPE,
    /// fmi2GetInteger.
    pub get_integer: fmi2GetIntegerTYPE,
    /// fmi2GetBoolean.
    pub get_boolean: fmi2GetBooleanTYPE,
    /// fmi2GetString.
    pub get_string: fmi2GetStringTYPE,
    /// fmi2SetReal.
    pub set_real: fmi2SetRealTYPE,
    /// fmi2SetInteger.
    pub set_integer: fmi2SetIntegerTYPE,
    /// fmi2SetBoolean.
    pub set_boolean: fmi2SetBooleanTYPE,
    /// fmi2SetString.
    pub set_string: fmi2SetStringTYPE,
    /// fmi2GetFMUstate.
    pub get_fmu_state: fmi2GetFMUstateTYPE,
    /// fmi2SetFMUstate.
    pub set_fmu_state: fmi2SetFMUstateTYPE,
    /// fmi2FreeFMUstate.
    pub free_fmu_state: fmi2GetFMUstateTYPE,
    /// fmi2SerializedFMUstateSize.
    pub serialized_size: fmi2SerializedFMUstateSizeTYPE,
    /// fmi2SerializeFMUstate.
    pub serialize: fmi2SerializeFMUstateTYPE,
    /// fmi2DeSerializeFMUstate.
    pub deserialize: fmi2DeSerializeFMUstateTYPE,
    /// fmi2GetRealOutputDerivatives.
    pub get_real_output_derivatives: fmi2GetRealOutputDerivativesTYPE,
    /// fmi2SetRealInputDerivatives.
    pub set_real_input_derivatives: fmi2SetRealInputDerivativesTYPE,
    /// fmi2GetDirectionalDerivative.
    pub get_directional_derivative: fmi2GetDirectionalDerivativeTYPE,
    /// fmi2DoStep.
    pub do_step: fmi2DoStepTYPE,
    /// fmi2CancelStep.
    pub cancel_step: fmi2ComponentOnlyTYPE,
    /// fmi2GetStatus with the kind as a plain int.
    pub get_status: unsafe extern "C" fn(fmi2Component, c_int, *mut fmi2Status) -> fmi2StatusCode,
    /// fmi2GetRealStatus.
    pub get_real_status:
        unsafe extern "C" fn(fmi2Component, c_int, *mut fmi2Real) -> fmi2StatusCode,
    /// fmi2GetIntegerStatus.
    pub get_integer_status:
        unsafe extern "C" fn(fmi2Component, c_int, *mut fmi2Integer) -> fmi2StatusCode,
    /// fmi2GetBooleanStatus.
    pub get_boolean_status:
        unsafe extern "C" fn(fmi2Component, c_int, *mut fmi2Boolean) -> fmi2StatusCode,
    /// fmi2GetStringStatus.
    pub get_string_status:
        unsafe extern "C" fn(fmi2Component, c_int, *mut fmi2String) -> fmi2StatusCode,
}

impl Raw {
    /// Loads `path` (each path is a separate load, as with separately extracted FMUs).
    pub fn load(path: &Path) -> Raw {
        // SAFETY: the kneebench binary; symbol types match fmu/src/fmi2/export.rs, which the
        // C ABI test checks against the official headers.
        unsafe {
            let lib = libloading::Library::new(path).expect("load binary");
            macro_rules! sym {
                ($name:literal) => {
                    *lib.get(concat!($name, "\0").as_bytes()).expect($name)
                };
            }
            Raw {
                instantiate: sym!("fmi2Instantiate"),
                free_instance: sym!("fmi2FreeInstance"),
                set_debug_logging: sym!("fmi2SetDebugLogging"),
                setup_experiment: sym!("fmi2SetupExperiment"),
                enter_initialization_mode: sym!("fmi2EnterInitializationMode"),
                exit_initialization_mode: sym!("fmi2ExitInitializationMode"),
                terminate: sym!("fmi2Terminate"),
                reset: sym!("fmi2Reset"),
                get_real: sym!("fmi2GetReal"),
                get_integer: sym!("fmi2GetInteger"),
                get_boolean: sym!("fmi2GetBoolean"),
                get_string: sym!("fmi2GetString"),
                set_real: sym!("fmi2SetReal"),
                set_integer: sym!("fmi2SetInteger"),
                set_boolean: sym!("fmi2SetBoolean"),
                set_string: sym!("fmi2SetString"),
                get_fmu_state: sym!("fmi2GetFMUstate"),
                set_fmu_state: sym!("fmi2SetFMUstate"),
                free_fmu_state: sym!("fmi2FreeFMUstate"),
                serialized_size: sym!("fmi2SerializedFMUstateSize"),
                serialize: sym!("fmi2SerializeFMUstate"),
                deserialize: sym!("fmi2DeSerializeFMUstate"),
                get_real_output_derivatives: sym!("fmi2GetRealOutputDerivatives"),
                set_real_input_derivatives: sym!("fmi2SetRealInputDerivatives"),
                get_directional_derivative: sym!("fmi2GetDirectionalDerivative"),
                do_step: sym!("fmi2DoStep"),
                cancel_step: sym!("fmi2CancelStep"),
                get_status: sym!("fmi2GetStatus"),
                get_real_status: sym!("fmi2GetRealStatus"),
                get_integer_status: sym!("fmi2GetIntegerStatus"),
                get_boolean_status: sym!("fmi2GetBooleanStatus"),
                get_string_status: sym!("fmi2GetStringStatus"),
                _lib: lib,
            }
        }
    }
}

/// An instance made through [`Raw`], with its log.
pub struct RawInstance<'a> {
    /// The functions.
    pub f: &'a Raw,
    /// The component (NULL if instantiation failed).
    pub c: fmi2Component,
    /// Messages the instance logged.
    pub log: Box<LogBuffer>,
    _callbacks: Box<fmi2CallbackFunctions>,
    _name: CString,
}

impl<'a> RawInstance<'a> {
    /// Instantiates `guid` for co-simulation with the test logger.
    pub fn new(f: &'a Raw, name: &str, guid: &str) -> Self {
        Self::with_type(f, name, guid, fmi2Type::fmi2CoSimulation as c_int)
    }

    /// Instantiates with an explicit fmuType value.
    pub fn with_type(f: &'a Raw, name: &str, guid: &str, fmu_type: c_int) -> Self {
        let mut log = LogBuffer::new();
        let callbacks = Box::new(fmi2CallbackFunctions {
            logger: test_logger(),
            allocateMemory: None,
            freeMemory: None,
            stepFinished: None,
            componentEnvironment: (&mut *log as *mut LogBuffer).cast(),
        });
        let name = CString::new(name).unwrap();
        let guid = CString::new(guid).unwrap();
        // SAFETY: valid strings and callbacks that outlive the instance.
        let c = unsafe {
            (f.instantiate)(
                name.as_ptr(),
                fmu_type,
                guid.as_ptr(),
                c"file:///tmp/resources".as_ptr(),
                &*callbacks,
                fmi2False,
                fmi2False,
            )
        };
        Self {
            f,
            c,
            log,
            _callbacks: callbacks,
            _name: name,
        }
    }

    /// setupExperiment(start, stop) + enter + exit initialization.
    pub fn initialize(&mut self, start: f64, stop: Option<f64>) {
        // SAFETY: valid component.
        unsafe {
            assert_eq!(
                (self.f.setup_experiment)(
                    self.c,
                    fmi2False,
                    0.0,
                    start,
                    fmi2Boolean::from(stop.is_some()),
                    stop.unwrap_or(0.0)
                ),
                fmi2Status::fmi2OK
            );
            assert_eq!(
                (self.f.enter_initialization_mode)(self.c),
                fmi2Status::fmi2OK
            );
            assert_eq!(
                (self.f.exit_initialization_mode)(self.c),
                fmi2Status::fmi2OK
            );
        }
    }

    /// fmi2GetReal of the given value references; panics unless OK.
    pub fn reals(&mut self, vrs: &[u32]) -> Vec<f64> {
        let mut out = vec![0.0; vrs.len()];
        // SAFETY: arrays of the right length.
        let s = unsafe { (self.f.get_real)(self.c, vrs.as_ptr(), vrs.len(), out.as_mut_ptr()) };
        assert_eq!(s, fmi2Status::fmi2OK, "{}", self.log.text());
        out
    }

    /// fmi2DoStep.
    pub fn step(&mut self, t: f64, h: f64) -> fmi2StatusCode {
        // SAFETY: valid component.
        unsafe { (self.f.do_step)(self.c, t, h, fmi2True) }
    }

    /// fmi2GetFMUstate + serialization: the state's bytes.
    pub fn serialized_state(&mut self) -> Vec<u8> {
        // SAFETY: valid component and out-pointers; the state is freed before returning.
        unsafe {
            let mut state: fmi2FMUstate = std::ptr::null_mut();
            assert_eq!(
                (self.f.get_fmu_state)(self.c, &mut state),
                fmi2Status::fmi2OK
            );
            let mut size = 0usize;
            assert_eq!(
                (self.f.serialized_size)(self.c, state, &mut size),
                fmi2Status::fmi2OK
            );
            let mut bytes = vec![0u8; size];
            assert_eq!(
                (self.f.serialize)(self.c, state, bytes.as_mut_ptr().cast(), size),
                fmi2Status::fmi2OK
            );
            assert_eq!(
                (self.f.free_fmu_state)(self.c, &mut state),
                fmi2Status::fmi2OK
            );
            assert!(state.is_null());
            bytes
        }
    }

    /// Deserializes and sets a state; returns the status of the first call that fails.
    pub fn restore(&mut self, bytes: &[u8]) -> fmi2StatusCode {
        // SAFETY: valid component, buffer and out-pointer; the state is freed.
        unsafe {
            let mut state: fmi2FMUstate = std::ptr::null_mut();
            let s = (self.f.deserialize)(self.c, bytes.as_ptr().cast(), bytes.len(), &mut state);
            if s != fmi2Status::fmi2OK {
                return s;
            }
            let s = (self.f.set_fmu_state)(self.c, state);
            (self.f.free_fmu_state)(self.c, &mut state);
            s
        }
    }

    /// The log as text.
    pub fn log_text(&self) -> String {
        self.log.text()
    }
}

impl Drop for RawInstance<'_> {
    fn drop(&mut self) {
        if !self.c.is_null() {
            // SAFETY: the component is ours and freed once.
            unsafe { (self.f.free_instance)(self.c) };
        }
    }
}

/// A C string for a call.
pub fn cstr(s: &str) -> CString {
    CString::new(s).unwrap()
}

/// Reads a C string.
///
/// # Safety
/// `p` must be a valid NUL-terminated string.
pub unsafe fn read_cstr(p: *const c_char) -> String {
    // SAFETY: guaranteed by the caller.
    unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned()
}

/// Every kneebench FMU, exported once per test binary into a temporary directory kept for the
/// process.
pub fn exported_fmus() -> &'static (
    tempfile::TempDir,
    Vec<kneebench_harness::package::ExportedFmu>,
) {
    static FMUS: OnceLock<(
        tempfile::TempDir,
        Vec<kneebench_harness::package::ExportedFmu>,
    )> = OnceLock::new();
    FMUS.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let fmus =
            kneebench_harness::package::export_all(&fmu_library(), dir.path()).expect("export");
        (dir, fmus)
    })
}

/// The exported FMU of model `identifier` (see [`exported_fmus`]).
pub fn exported_fmu(identifier: &str) -> PathBuf {
    exported_fmus()
        .1
        .iter()
        .find(|f| f.identifier == identifier)
        .unwrap_or_else(|| panic!("no {identifier}"))
        .path
        .clone()
}

/// Serialises the real-time tests of a test binary: they pace against the wall clock (1 ms
/// deadlines, a link watchdog of a few ms) with an emulator thread each; run side by side on a
/// 2-core machine they steal each other's cores and trip the watchdog spuriously. One at a
/// time, as on the bench. A failed test poisons the lock; the next one still runs.
pub fn one_real_time_test_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static REAL_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());
    REAL_TIME
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// A bench key file made by `Key::create_file` (mode 0600) and its key, once per test binary,
/// so the hardware runs go through the authenticated handshake and tagged frames as on the
/// bench.
pub fn bench_key_file() -> &'static (
    tempfile::TempDir,
    PathBuf,
    kneebench_harness::bench_protocol::Key,
) {
    static KEY: OnceLock<(
        tempfile::TempDir,
        PathBuf,
        kneebench_harness::bench_protocol::Key,
    )> = OnceLock::new();
    KEY.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bench.key");
        let key = kneebench_harness::bench_protocol::Key::create_file(&path).unwrap();
        (dir, path, key)
    })
}

/// `BenchHardware` (backend Udp, soft pacing, no tare, a 20 ms reply timeout generous for a
/// loaded test machine, real-time priority 50 where permitted) as an experiment bench, talking
/// to a fresh emulator of `BenchPlant` with `plant_params`; the emulator stops when its handle
/// is dropped.
pub fn hardware_bench_over_emulator(
    plant_params: Vec<(String, String)>,
) -> (
    kneebench_harness::emulator::EmulatorHandle,
    kneebench_harness::experiment::Bench,
) {
    use kneebench_harness::emulator::{EmulatorConfig, spawn};
    let mut config = EmulatorConfig::new("127.0.0.1:0", exported_fmu("BenchPlant"));
    config.parameters = plant_params;
    config.realtime_priority = Some(50);
    let emu = spawn(config).expect("emulator");
    let params = [
        ("backend", "1".to_string()),
        ("pacing", "1".to_string()),
        ("serverAddress", emu.addr().to_string()),
        ("tareSamples", "0".to_string()),
        // Generous for a loaded test machine (the watchdog is tested in hardware.rs).
        ("replyTimeout", "0.02".to_string()),
        ("realtimePriority", "50".to_string()),
    ];
    let bench = kneebench_harness::experiment::Bench::load(
        &exported_fmu("BenchHardware"),
        params
            .iter()
            .map(|(n, v)| (n.to_string(), v.clone()))
            .collect(),
        None,
    )
    .expect("BenchHardware as an experiment bench");
    (emu, bench)
}

/// The longest host stall up to which a real-time run on the emulated bench is the test's to
/// judge, as the run measured it (the bench's longest pause between two of the master's
/// frames, `EmulatorStats::largest_frame_gap`, or a row's lateness plus reply time); above it
/// the host disturbed the run (the bench integrated the stall under one logged period) \[s\].
pub const HOST_DISTURBANCE: f64 = 5e-3;

/// Whether an end reason (or error text) names a stop that the host's timing causes: the
/// master's link watchdog, or the bench stopping itself (its heartbeat watchdog or protection).
pub fn ended_by_host(reason: &str) -> bool {
    reason.contains("link watchdog") || reason.contains("stopped itself")
}

/// Whether a safety interlock latched the emulated bench's run, whichever side latched first:
/// the emulated plant's trip, the bench's protection, or the master's own interlock (its safe
/// state asked as a client request). After a stall of more than two periods such a trip is the
/// host's: a torque command held for milliseconds in a 1 kHz loop.
pub fn interlock_latched(stats: &kneebench_harness::emulator::EmulatorStats) -> bool {
    use kneebench_harness::bench_protocol::reason;
    stats.plant_trip.is_some()
        || matches!(
            stats.safe_reason,
            Some(r) if r == reason::BENCH_PROTECTION || r == reason::CLIENT_REQUEST
        )
}

/// How late the master's loop ran behind its real-time schedule before an interlock ended the
/// run \[s\], as `BenchHardware` logs it next to the trip ("pacing before trip C: N overruns in
/// M steps, largest lateness L us"); `None` when the run did not end so or never ran late.
pub fn master_lateness(outcome: &kneebench_harness::Outcome) -> Option<f64> {
    let kneebench_harness::Outcome::Terminated { messages, .. } = outcome else {
        return None;
    };
    messages.iter().rev().find_map(|m| {
        let (_, rest) = m.split_once("pacing before trip")?;
        let (_, late) = rest.split_once("largest lateness ")?;
        let us: f64 = late.strip_suffix(" us")?.parse().ok()?;
        Some(us * 1e-6)
    })
}

/// Runs `experiment` on `BenchHardware` over a fresh emulator of the plant with
/// `plant_params` ([`hardware_bench_over_emulator`]), in a fresh directory. An attempt the host
/// disturbed is run again on a fresh emulator, at most `attempts`: one that the link watchdog
/// or the emulated bench itself stopped (`experiment` returns the run's end reason, or the
/// error a run whose safe state was not confirmed fails with; see [`ended_by_host`]), and one
/// in which the bench measured a pause above [`HOST_DISTURBANCE`] between two of the master's
/// frames, whatever its outcome. Any other outcome is the caller's to assert on (any other
/// error panics). `None`, said as `NOT COMPARED`, when every attempt was disturbed.
pub fn experiment_over_emulator<T>(
    plant_params: &[(&str, &str)],
    attempts: usize,
    experiment: impl FnMut(
        &kneebench_harness::experiment::Bench,
        &Path,
    ) -> Result<(T, Option<String>), String>,
) -> Option<T> {
    experiment_over_emulator_within(plant_params, attempts, HOST_DISTURBANCE, experiment)
}

/// [`experiment_over_emulator`] with its own limit on the bench's longest pause between two
/// of the master's frames (\[s\], instead of [`HOST_DISTURBANCE`]), for an experiment whose
/// result a shorter stall already spoils.
pub fn experiment_over_emulator_within<T>(
    plant_params: &[(&str, &str)],
    attempts: usize,
    largest_pause: f64,
    mut experiment: impl FnMut(
        &kneebench_harness::experiment::Bench,
        &Path,
    ) -> Result<(T, Option<String>), String>,
) -> Option<T> {
    for attempt in 1..=attempts {
        let (emu, bench) = hardware_bench_over_emulator(
            plant_params
                .iter()
                .map(|(n, v)| (n.to_string(), v.to_string()))
                .collect(),
        );
        let out = tempfile::tempdir().unwrap();
        let outcome = experiment(&bench, out.path());
        let gap = emu.stop().map(|s| s.largest_frame_gap).unwrap_or(0.0);
        let reason = match outcome {
            _ if gap > largest_pause => Some(format!("a pause of {:.0} us", gap * 1e6)),
            Ok((result, reason)) if !reason.as_deref().is_some_and(ended_by_host) => {
                return Some(result);
            }
            Ok((_, reason)) => reason,
            Err(e) if ended_by_host(&e) => Some(e),
            Err(e) => panic!("attempt {attempt}: {e}"),
        };
        eprintln!("attempt {attempt} disturbed by the host ({reason:?}); run again");
    }
    eprintln!("NOT COMPARED: the host disturbed all {attempts} attempts");
    None
}

/// The reason an experiment's run ended early, if it did.
pub fn reason_of(end: &kneebench_harness::experiment::RunEnd) -> Option<String> {
    match end {
        kneebench_harness::experiment::RunEnd::Completed => None,
        kneebench_harness::experiment::RunEnd::Tripped { reason, .. } => Some(reason.clone()),
    }
}
