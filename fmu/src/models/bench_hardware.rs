//! # BenchHardware: the knee-actuator bench itself, behind the plant's interface
//!
//! This FMU stands for the physical bench. Its inputs and outputs are the bench signal
//! interface of `BenchPlant`, generated from the same table (`io_variables`), so names,
//! causality, units and value references are identical and a system file runs unchanged with
//! either FMU. Its parameters that mean the same as the plant's have the plant's names and
//! value references; the hardware's own parameters are at value references 400 and up.
//!
//! ## Backends (`backend`)
//! * `Simulated` (default): the plant physics in process, seen through its raw sensors
//!   (encoder counts, volts). No network; with `pacing = None` it runs as fast as a
//!   simulation. Its own interlock thresholds (spring deflection, motor torque, regenerated
//!   power) are lifted so that this FMU's checks are the line being exercised; the drivers'
//!   over-current protection and the emergency stop stay.
//! * `Udp`: a client of a real-time I/O server on the bench controller (`serverAddress`,
//!   e.g. `127.0.0.1:47000`), speaking the protocol of `docs/bench-protocol.md`. Needs
//!   `pacing` Soft or Hard. `kneebench emulate` serves the same protocol with the plant behind
//!   it.
//!
//! ## One control period (`fmi2DoStep(t, h)`)
//! 1. An `emergencyStop` input trips at `t`, before anything is sent.
//! 2. The command (the set value of each driver's mode, clipped to +-supply in voltage mode
//!    and +-current limit in current mode; enables; clutch) is written: held by the bench
//!    from now on.
//! 3. Pacing waits for the absolute deadline of `t + h` (below).
//! 4. All inputs are sampled (over UDP: a heartbeat answered by a sample, within
//!    `replyTimeout`), checked and calibrated; the outputs at `t + h` are computed from them.
//! 5. The checks, in this order of precedence: the bench reports its emergency stop (code 7)
//!    or that it stopped itself (11); a raw channel outside its plausibility window (10); two
//!    sensors of the same torque disagreeing for `consistencyPersistence` samples (12, 13;
//!    "Sensor consistency" below); the interlocks of bench-model.md §7 on the calibrated
//!    sample (1-6); the sample does not confirm the command of this period (8); a pacing
//!    overrun in hard real time (9).
//!
//! The networked loop has the inherent delay of any sampled loop: the command written at `t`
//! acts over the period and the sample at `t + h` shows its effect, like the plant FMU; the
//! extra delay is the network latency (tens of microseconds on loopback) by which the command
//! arrives after `t`.
//!
//! ## Trips, the safe state and the FMI status
//! A trip latches. The FMU commands the safe state (set values zero, both drivers disabled,
//! clutch released; latched by the server for the session, and no drive command is sent
//! afterwards) and waits up to `safeStateTimeout` for its acknowledgement, a sample taken in
//! the safe state showing the drivers disabled and the clutch released.
//! * **Acknowledged**: `fmi2DoStep` returns `fmi2Discard` with `fmi2Terminated = true`;
//!   `fmi2LastSuccessfulTime` is `t + h` for trips found in the sample (its outputs are the
//!   tripping sample's) and `t` for an emergency-stop input or a lost link (no new sample).
//!   `tripCode` tells which.
//! * **Not acknowledged** (link lost, server gone, an acknowledgement that shows outputs still
//!   on): `fmi2DoStep` returns `fmi2Error` and the instance is unusable. The bench is then
//!   protected only by the server's own heartbeat watchdog (safe state 50 ms after the last
//!   frame, `docs/bench-protocol.md`).
//!
//! Re-arming needs a new instance: a tripped instance never sends a drive command again, and
//! the server keeps the safe state latched across sessions until a master acknowledges it
//! (below, "The bench link").
//!
//! | tripCode | cause | status |
//! |---|---|---|
//! | 1 | spring deflection above `springDeflectionLimit` | Discard / Error |
//! | 2, 3 | test: the shaft torque the transducer measures (the test motor's torque past the harmonic drive); load: the output-side load-motor torque; above `motorTorqueLimit` | Discard / Error |
//! | 4, 5 | motor current above the driver limit (test, load) | Discard / Error |
//! | 6 | load driver regenerating more than `loadRegenPowerLimit` | Discard / Error |
//! | 7 | emergency stop (input or the bench's button) | Discard / Error |
//! | 8 | link watchdog: no valid sample within `replyTimeout`, or a command not confirmed | Discard / Error |
//! | 9 | pacing overrun (hard real time) | Discard / Error |
//! | 10 | sensor fault: a raw channel outside its plausibility window | Discard / Error |
//! | 11 | the bench stopped itself (server watchdog or its own protection) | Discard / Error |
//! | 12 | sensor fault: the torque transducer disagrees with `k` x the encoders' spring deflection (SEA, CSEA) | Discard / Error |
//! | 13 | sensor fault: the load cell disagrees with `i_HD Km1` x the measured test-motor current | Discard / Error |
//!
//! (Discard when the safe state is acknowledged, Error when it is not.)
//!
//! ## The bench link (`keyFile`, `acknowledgeSafeState`)
//! The Udp backend opens an authenticated session (`docs/bench-protocol.md`, version 2): it
//! reads the bench's key from `keyFile` (made by `kneebench key new`; refused if its group or
//! others may read it; empty: the public loopback key, only for a server on this machine),
//! proves it in a handshake that also carries `configuration`, `testDriverMode` and
//! `loadDriverMode` (a server set up differently refuses, naming the setting, and the
//! initialization fails with that text), and tags every frame with the session's keys. A
//! server held by another master is asked again until the handshake's 0.2 s end. A bench
//! whose safe state is latched from an earlier session (a trip, its watchdog, the button, the
//! bench's own protection, a server restarted under a live session) fails the initialization with the latch's reason unless `acknowledgeSafeState` is true:
//! then the FMU acknowledges it (logged as a warning) and goes on if the bench leaves the safe
//! state (not while the emergency stop is pressed).
//!
//! ## Calibration and initialization
//! During initialization samples are awaited up to 0.2 s (the server may be starting its
//! session); from the first step on, `replyTimeout`.
//! `fmi2ExitInitializationMode` opens the backend, commands the drivers disabled and the clutch
//! released, and reads `tareSamples` samples (default 50): their mean is the zero of the torque
//! transducer and of the load cell (calibration of bench-model.md §8, with the tared zero in
//! place of the published offset `a`; see `hardware::calibration`). The encoder counts at
//! initialization are the zero of both angles: the bench must be at its reference position,
//! at rest and unloaded. A sample in the safe state, with the emergency stop pressed or out of
//! its plausibility windows fails the initialization (`fmi2Error`).
//!
//! ## Outputs
//! * Measured: encoder counts and angles (relative to initialization), actuation/load angles
//!   (= encoder angles), raw volts of the six analog inputs, calibrated load-cell and
//!   transducer torques, motor currents (ACS712), clutch output state.
//! * Derived from measurements each period: velocities (backward difference of the encoder
//!   angles over the time between the two samples: the server's timestamps over UDP, so a late
//!   sample does not read as a speed jump; `h`, taken to the nanosecond, on the simulated
//!   backend; a sample less than half a period after the last, as when the loop catches up
//!   after a stall, widens the difference to the last two intervals, so that a count over a
//!   tenth of a period does not read as a speed spike), accelerations (difference of velocities),
//!   spring deflection and torque (`k (theta1 - theta2)`, `k` of the configuration), motor
//!   and output torques (`Km i`, ratios), armature voltages (the set value in voltage mode;
//!   `R i + Ke w_m` in current mode and for a disabled driver), driver saturation (that voltage at the measured supply),
//!   mechanical and electrical powers, regenerated power, energies (trapezoidal integrals over
//!   the period), `E_k`, `E_p` and their rates, friction torques and loss powers from each
//!   side's torque and power balance (model parameters `I`, `c`, `k`), copper and back-emf
//!   energies.
//! * `actuationStuck`/`loadStuck`: the encoder did not move during the period.
//!   `hdSurfaceClampCount`/`hdSurfaceClamped`: always 0/false (no loss surface on hardware).
//!
//! ## Sensor consistency (`consistencyTolerance`, `consistencyRelativeTolerance`, `consistencyPersistence`)
//! A sensor stuck at a believable value passes its plausibility window. Two torques are
//! therefore measured twice and compared every period (`hardware::consistency`):
//! * SEA and CSEA: the torque transducer (in series with the spring) against the spring torque
//!   from the encoders, `k (theta1 - theta2)`; a mismatch trips with code 12. Not in DA (the
//!   blocked spring's deflection is below the encoders' resolution).
//! * Every configuration: the load cell (the test motor's reaction torque) against
//!   `i_HD Km1 i1` from the current sensor; code 13. A stuck current sensor trips it too.
//!
//! The pair disagrees when `|a - b| > consistencyTolerance + consistencyRelativeTolerance x
//! max(|a|, |b|)`; `consistencyPersistence` consecutive disagreeing samples trip (the trip is
//! found in the sample that completes the run, so it comes `consistencyPersistence` periods
//! after the first disagreeing sample; 0 turns the checks off). Defaults and why:
//! * `consistencyTolerance` = 1 N m: the encoder quantisation gives at most
//!   `k (res1 + res2)` = 340.54 x (1.96e-5 + 4.76e-5) = 0.023 N m of spring-torque error; the
//!   tared calibrations leave gain errors `1 - cos(c)` of 5e-5 and 1.8e-4; sampling all inputs
//!   in one frame makes the skew between them the server's read time (well under 0.1 ms, i.e.
//!   under 0.01 N m at the gait's 100 N m/s). The 1 N m (5 % of the 20 N m interlock) covers
//!   these 40 times over, plus amplifier noise and the transducer's few-tenths-of-a-N m
//!   hysteresis on the real bench.
//! * `consistencyRelativeTolerance` = 0.25: the bench's stiffness is an identified 340.54 N m/rad
//!   against a designed 257.4 (24 % apart) and varies with amplitude; the motor constants and
//!   the load cell's lever are known to a few per cent. A real stuck sensor gives a mismatch
//!   that grows with the torque the other sensor sees, so the relative term does not hide it.
//! * `consistencyPersistence` = 10 samples (10 ms at 1 kHz): a single glitch (a noise spike,
//!   a torque transient faster than the sensors' bandwidths) does not trip; a stuck sensor
//!   does, 10 ms after its mismatch leaves the allowance, while the encoder-based spring
//!   deflection interlock (code 1) still guards the spring meanwhile.
//!
//! ## The link watchdog's reply timeout (`replyTimeout`)
//! The sample of a period is asked for at its deadline and must arrive within `replyTimeout`,
//! else the link watchdog trips (code 8). The default is **0.8 ms**, 0.8 of the default 1 ms
//! control period (it was 0.5 ms), because:
//! * it must stay below the period: the bench's "a control period missed" watchdog, and the
//!   requirement that a lost sample trips within one control period; and a reply that comes
//!   just inside it must leave the rest of the period (0.2 ms) for the master, the
//!   controllers and the next command, so that it does not by itself make the next step an
//!   overrun;
//! * it must be well above what a healthy link takes. `docs/bench-protocol.md` allows a
//!   server that polls its socket in a 2 kHz timed loop, which alone answers up to 0.5 ms
//!   late, plus the Ethernet round trip and the myRIO's processing (0.1-0.2 ms): 0.5 ms
//!   tripped such a conforming server. Against the emulator on loopback on the 2-core
//!   development machine, with `realtimePriority` 80 and a concurrent compilation, the reply
//!   times were p50 70 us, p99 140 us, p99.9 0.3-0.6 ms (60 s runs, `cargo bench --bench
//!   pacing`); in normal scheduling under the same load p99 0.7-1.3 ms, which no setting
//!   below the period can carry: there `realtimePriority` is the remedy, not a longer timeout.
//!
//! The timeout is an absolute deadline kept to the microsecond (`ppoll` until `spinMargin`
//! before it, a spin for the rest: `hardware::io::recv_until`), never a socket receive timeout,
//! which the kernel rounds up to its tick (0.8 ms became 4 ms at 250 Hz, and replies 2-5 ms
//! late were accepted). A reply that is late by even 10 % trips (`tests/tests/bench_link.rs`).
//!
//! A `replyTimeout` not below the step size is logged as a warning at the first step. For
//! another control period scale it with the period (0.8 h).
//!
//! ## Pacing (`pacing`)
//! `None`, `Soft` (real time; overruns counted in `overrunCount` and logged as warnings) or
//! `Hard` (an overrun trips, code 9). `fmi2DoStep` sleeps until the absolute deadline
//! `origin + (t + h - t_first)` on the monotonic clock, `origin` being the wall time of the
//! first step: an absolute `clock_nanosleep` until `spinMargin` before it, a spin for the rest.
//! `realtimePriority` (1-99) puts the thread that calls `fmi2DoStep` in `SCHED_FIFO` at that
//! priority from the first step until the instance is freed or trips (its previous policy is
//! then restored; threads it starts do not inherit it), with a 1 ns timer slack: other
//! processes on the machine (a compilation, a browser) then cannot delay a wake-up or the
//! reply handling by a scheduler time slice. `lockMemory` locks the process's pages
//! (`mlockall`). Both need the right to (`CAP_SYS_NICE` / `RLIMIT_RTPRIO`, `RLIMIT_MEMLOCK`);
//! when refused, a warning is logged and the run goes on in normal scheduling. What they
//! cannot remove: on a kernel without full preemption (`PREEMPT_NONE`, as on the 2-core
//! development VM) a woken real-time thread still waits for another process's system call or
//! page fault to reach a preemption point, and a virtual machine's CPUs are descheduled by
//! its host (steal time) when the machine is busy; both stall a step by milliseconds now and
//! then while, say, a compilation runs (measured: `tests/benches/pacing.rs`). The bench's
//! controller PC should run a `PREEMPT_RT` (or `preempt=full`) kernel on bare metal. Lateness
//! statistics are in the local variables `lastLateness` and `maxLateness`, the reply time of
//! the samples (request to arrival) in `lastReplyTime` and `maxReplyTime`, the link's rejected
//! frames in `rejectedFrames` and late replies in `staleReplies`.
//!
//! ## FMU state
//! `fmi2GetFMUstate` works; restoring a state saved after initialization is refused: the
//! physical bench cannot be rewound.

use crate::release::Lazy;
use std::time::Duration;

use super::bench::{
    BenchOutputs, BenchParameters, Configuration, DriverMode, FrictionModel, SignalGroup,
};
use super::bench_plant::{
    BenchCommands, BenchSignals, for_each_bench_parameter, io_variables, unit_of, with_unit,
};
use crate::hardware::calibration::{Calibration, Plausibility, Side, Tare, Unwrapper};
use crate::hardware::consistency::{ConsistencyCheck, Inconsistency};
use crate::hardware::io::{BenchIo, IoError, SimulatedBench, UdpBench, UdpSetup, kind_of};
use crate::hardware::pacing::{Pacer, PacingMode};
use crate::hardware::protocol::{AnalogChannel, BenchSetup, Command, Key, Sample, reason, status};
use crate::hardware::realtime::{RealtimeThread, lock_memory, now_ns};
use crate::model::{
    EnumerationType, Model, ModelError, Start, StateError, StateReader, StateWriter, StepOutcome,
    Variable,
};
use crate::registry::ReferenceInputs;

/// How long a sample is awaited during initialization [s].
const INIT_REPLY_TIMEOUT: f64 = 0.2;

/// The default `replyTimeout` \[s\] (module docs, "The link watchdog's reply timeout").
pub const DEFAULT_REPLY_TIMEOUT: f64 = 8e-4;

/// Trip codes beyond the plant's interlocks (1-7).
pub mod trip {
    /// Link watchdog: no valid sample in time, or a command not confirmed.
    pub const LINK: i32 = 8;
    /// Pacing overrun in hard real time.
    pub const OVERRUN: i32 = 9;
    /// A raw channel outside its plausibility window.
    pub const SENSOR: i32 = 10;
    /// The bench stopped itself (server watchdog, its own protection).
    pub const BENCH: i32 = 11;
    /// The torque transducer disagrees with the spring deflection (SEA, CSEA).
    pub const TRANSDUCER_INCONSISTENT: i32 = 12;
    /// The load cell disagrees with the test-motor current.
    pub const LOAD_CELL_INCONSISTENT: i32 = 13;

    /// The log text of a trip code.
    pub fn name(code: i32) -> &'static str {
        match code {
            1 => "spring deflection above limit",
            2 => "test motor torque outside limit",
            3 => "load motor torque outside limit",
            4 => "test motor current above driver limit",
            5 => "load motor current above driver limit",
            6 => "load driver regenerated power above limit",
            7 => "emergency stop",
            LINK => "link watchdog: bench I/O did not answer or confirm in time",
            OVERRUN => "pacing overrun in hard real time",
            SENSOR => "sensor fault: raw reading outside its plausible range",
            BENCH => "the bench stopped itself (server watchdog or protection)",
            TRANSDUCER_INCONSISTENT => {
                "sensor fault: torque transducer disagrees with the spring deflection"
            }
            LOAD_CELL_INCONSISTENT => {
                "sensor fault: load cell disagrees with the test-motor current"
            }
            _ => "unknown trip",
        }
    }
}

/// The I/O backend.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Backend {
    /// The plant physics in process.
    Simulated,
    /// A UDP client of a bench I/O server.
    Udp,
}

impl Backend {
    /// From the FMU's enumeration value.
    pub fn from_i32(v: i32) -> Option<Self> {
        match v {
            0 => Some(Self::Simulated),
            1 => Some(Self::Udp),
            _ => None,
        }
    }
}

// SAFETY: a static (Lazy registers its address for the release at unload).
static ENUMERATIONS: Lazy<Vec<EnumerationType>> = unsafe {
    Lazy::new(|| {
        let mut v = super::bench_plant::ENUMERATIONS.to_vec();
        v.push(EnumerationType {
            name: "Backend",
            description: "Where the bench's I/O is",
            items: &[
                (
                    "Simulated",
                    0,
                    "The plant physics in process, through its raw sensors",
                ),
                (
                    "Udp",
                    1,
                    "A real-time I/O server (bench controller or `kneebench emulate`) over UDP",
                ),
            ],
        });
        v.push(EnumerationType {
            name: "Pacing",
            description: "How fmi2DoStep keeps time",
            items: &[
                ("None", 0, "As fast as possible (Simulated backend only)"),
                (
                    "Soft",
                    1,
                    "Real time; overruns are counted and logged as warnings",
                ),
                ("Hard", 2, "Real time; an overrun trips the bench"),
            ],
        });
        v
    })
};

/// What exists only between initialization and the end of the instance.
struct Runtime {
    io: Box<dyn BenchIo>,
    p: BenchParameters,
    cal: Calibration,
    limits: Plausibility,
    consistency: ConsistencyCheck,
    pacer: Pacer,
    encoders: [Unwrapper; 2],
    counts: [i64; 2],
    /// Encoder movement [counts] over the last period and the one before.
    delta: [[i64; 2]; 2],
    /// Time [s] between the samples of those movements (the last period's, the one before).
    dt: [f64; 2],
    /// The server's timestamp of the last sample [us] (Udp backend).
    server_us: u64,
    trip: Option<(i32, f64)>,
    /// The bench's time since initialization: the sum of the step sizes (so the simulated
    /// backend advances by exactly `h`, whatever rounding the importer's times carry).
    bench_time: f64,
    safe_timeout: Duration,
    warnings: Vec<String>,
    /// `SCHED_FIFO` of the stepping thread, asked for once at the first paced step; restored
    /// when the runtime ends (or at a trip).
    realtime: Option<RealtimeThread>,
    /// The first paced step's checks are done.
    first_step_checked: bool,
    /// `SCHED_FIFO` was asked for.
    realtime_tried: bool,
    /// Reply time of the last sample and the largest [s].
    reply_time: (f64, f64),
}

/// The runtime holder: a clone of the model (a description copy) has no bench connection.
#[derive(Default)]
struct Slot(Option<Box<Runtime>>);

impl Clone for Slot {
    fn clone(&self) -> Self {
        Slot(None)
    }
}

impl std::fmt::Debug for Slot {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.0.is_some() {
            "Slot(running)"
        } else {
            "Slot(idle)"
        })
    }
}

/// The bench hardware FMU.
#[derive(Debug, Clone, Default)]
pub struct BenchHardwareModel {
    params: BenchParameters,
    configuration: i32,
    friction_model: i32,
    test_driver_mode: i32,
    load_driver_mode: i32,
    backend: i32,
    server_address: String,
    pacing: i32,
    tare_samples: i32,
    reply_timeout: f64,
    safe_state_timeout: f64,
    spin_margin: f64,
    realtime_priority: i32,
    lock_memory: bool,
    key_file: String,
    acknowledge_safe_state: bool,
    plausibility: Plausibility,
    consistency_tolerance: f64,
    consistency_relative: f64,
    consistency_persistence: i32,
    commands: BenchCommands,
    outputs: BenchOutputs,
    start_time: f64,
    overrun_count: i32,
    last_lateness: f64,
    max_lateness: f64,
    rejected_frames: i32,
    stale_replies: i32,
    last_reply_time: f64,
    max_reply_time: f64,
    runtime: Slot,
}

impl BenchSignals for BenchHardwareModel {
    fn commands(&self) -> &BenchCommands {
        &self.commands
    }
    fn commands_mut(&mut self) -> &mut BenchCommands {
        &mut self.commands
    }
    fn signals_mut(&mut self) -> &mut BenchOutputs {
        &mut self.outputs
    }
    /// Every measurement is taken once per step: a read is a field load.
    fn read_signal<T>(&self, _group: SignalGroup, read: fn(&BenchOutputs) -> T) -> T {
        read(&self.outputs)
    }
}

/// The plant parameters the hardware FMU declares too (see `for_each_bench_parameter`).
const SHARED_PARAMETERS: &[&str] = &[
    "actuationInertia",
    "loadInertia",
    "actuationDamping",
    "loadDamping",
    "springStiffness",
    "directCouplingStiffness",
    "harmonicDriveRatio",
    "reductionRatio",
    "testMotorResistance",
    "testMotorTorqueConstant",
    "testMotorBackEmfConstant",
    "loadMotorResistance",
    "loadMotorTorqueConstant",
    "loadMotorBackEmfConstant",
    "testSupplyVoltage",
    "loadSupplyVoltage",
    "testCurrentLimit",
    "loadCurrentLimit",
    "loadRegenPowerLimit",
    "clutchRatedPower",
    "hardwareOffsetPower",
    "encoderCountsPerRevolution",
    "transducerOffset",
    "transducerGain",
    "transducerPhase",
    "loadCellOffset",
    "loadCellGain",
    "loadCellPhase",
    "calibrationPendulumMoment",
    "dividerOffset",
    "dividerGain",
    "currentSensorOffset",
    "currentSensorSensitivity",
    "springDeflectionLimit",
    "motorTorqueLimit",
];

// SAFETY: a static (Lazy registers its address for the release at unload).
static VARIABLES: Lazy<Vec<Variable<BenchHardwareModel>>> = unsafe {
    Lazy::new(|| {
        type V = Variable<BenchHardwareModel>;
        let d = BenchParameters::default();
        let range = |field: &str| {
            BenchParameters::PARAMETER_LIMITS
                .iter()
                .find(|(n, _, _)| *n == field)
                .map(|&(_, lo, hi)| (lo, hi))
                .unwrap_or((f64::NEG_INFINITY, f64::INFINITY))
        };
        macro_rules! window {
            ($name:literal, $vr:expr, $ch:expr, $end:tt, $desc:literal) => {
                V::real(
                    $name,
                    $vr,
                    |m| m.plausibility.analog[$ch as usize].$end,
                    |m, v| m.plausibility.analog[$ch as usize].$end = v,
                )
                .parameter(Start::Real(Plausibility::DEFAULT.analog[$ch as usize].$end))
                .unit("V")
                .range(-10.0, 10.0)
                .describe($desc)
            };
        }
        macro_rules! local {
            (real $name:literal, $vr:expr, $field:ident, $unit:literal, $desc:literal) => {
                V::real($name, $vr, |m| m.$field, |m, v| m.$field = v)
                    .discrete()
                    .unit($unit)
                    .describe($desc)
            };
            (int $name:literal, $vr:expr, $field:ident, $desc:literal) => {
                V::integer($name, $vr, |m| m.$field, |m, v| m.$field = v)
                    .discrete()
                    .describe($desc)
            };
        }
        use AnalogChannel as A;
        let mut v = vec![
        V::enumeration(
            "configuration",
            1,
            "Configuration",
            |m| m.configuration,
            |m, v| m.configuration = v,
        )
        .parameter(Start::Integer(d.configuration.as_i32()))
        .describe("Actuator configuration the bench is set up in (spring stiffness used; simulated backend)"),
        V::enumeration(
            "frictionModel",
            2,
            "FrictionModel",
            |m| m.friction_model,
            |m, v| m.friction_model = v,
        )
        .parameter(Start::Integer(d.friction_model.as_i32()))
        .describe("Friction law of the simulated backend"),
        V::enumeration(
            "testDriverMode",
            3,
            "DriverMode",
            |m| m.test_driver_mode,
            |m, v| m.test_driver_mode = v,
        )
        .parameter(Start::Integer(d.test_driver_mode.as_i32()))
        .describe("Test driver's configured mode: which command input is sent (the server refuses a mismatch)"),
        V::enumeration(
            "loadDriverMode",
            4,
            "DriverMode",
            |m| m.load_driver_mode,
            |m, v| m.load_driver_mode = v,
        )
        .parameter(Start::Integer(d.load_driver_mode.as_i32()))
        .describe("Load driver's configured mode"),
        V::enumeration("backend", 400, "Backend", |m| m.backend, |m, v| m.backend = v)
            .parameter(Start::Integer(0))
            .describe("I/O backend: Simulated (in process) or Udp (bench I/O server)"),
        V::string(
            "serverAddress",
            401,
            |m| &m.server_address,
            |m, v| m.server_address = v.to_owned(),
        )
        .parameter(Start::String("127.0.0.1:47000"))
        .describe("host:port of the bench I/O server (Udp backend)"),
        V::enumeration("pacing", 402, "Pacing", |m| m.pacing, |m, v| m.pacing = v)
            .parameter(Start::Integer(0))
            .describe("Pacing: None, Soft or Hard real time"),
        V::integer(
            "tareSamples",
            403,
            |m| m.tare_samples,
            |m, v| m.tare_samples = v,
        )
        .parameter(Start::Integer(50))
        .range(0.0, 100_000.0)
        .describe("Samples averaged at initialization for the zero of the torque channels (0: published offsets)"),
        V::real("replyTimeout", 404, |m| m.reply_timeout, |m, v| m.reply_timeout = v)
            .parameter(Start::Real(DEFAULT_REPLY_TIMEOUT))
            .unit("s")
            .range(1e-5, 1.0)
            .describe("Link watchdog: longest wait for a sample after the deadline (default 0.8 ms: 0.8 of the default 1 ms period; keep below the control period, see the documentation)"),
        V::real(
            "safeStateTimeout",
            405,
            |m| m.safe_state_timeout,
            |m, v| m.safe_state_timeout = v,
        )
        .parameter(Start::Real(0.05))
        .unit("s")
        .range(1e-4, 10.0)
        .describe("Longest wait for the safe state's acknowledgement (the request is repeated every replyTimeout)"),
        V::real("spinMargin", 406, |m| m.spin_margin, |m, v| m.spin_margin = v)
            .parameter(Start::Real(5e-5))
            .unit("s")
            .range(0.0, 0.01)
            .describe("Pacing spins (instead of sleeping) this long before each deadline"),
        V::integer(
            "realtimePriority",
            408,
            |m| m.realtime_priority,
            |m, v| m.realtime_priority = v,
        )
        .parameter(Start::Integer(0))
        .range(0.0, 99.0)
        .describe("Pacing Soft/Hard: SCHED_FIFO priority (1-99) of the thread calling fmi2DoStep, from the first step to the end of the instance or a trip; 0 leaves the scheduling alone. Refused (no CAP_SYS_NICE or RLIMIT_RTPRIO): a warning, the run goes on"),
        V::boolean(
            "lockMemory",
            409,
            |m| m.lock_memory,
            |m, v| m.lock_memory = v,
        )
        .parameter(Start::Boolean(false))
        .describe("Pacing Soft/Hard: lock the importer process's pages in memory (mlockall, process-wide, not undone) at initialization. Refused: a warning"),
        V::string(
            "keyFile",
            425,
            |m| &m.key_file,
            |m, v| m.key_file = v.to_owned(),
        )
        .parameter(Start::String(""))
        .describe("Udp backend: the bench's key file (`kneebench key new FILE`; readable by its owner only). Empty: the public loopback key, allowed only for a server on this machine"),
        V::boolean(
            "acknowledgeSafeState",
            426,
            |m| m.acknowledge_safe_state,
            |m, v| m.acknowledge_safe_state = v,
        )
        .parameter(Start::Boolean(false))
        .describe("Udp backend: at initialization, clear a safe state the bench latched in an earlier session (a trip, its watchdog, the button) by an explicit acknowledgement. Set it only after checking the bench; false: such a latch fails the initialization"),
        V::real(
            "maxEncoderSpeed",
            407,
            |m| m.plausibility.max_speed,
            |m, v| m.plausibility.max_speed = v,
        )
        .parameter(Start::Real(Plausibility::DEFAULT.max_speed))
        .unit("rad/s")
        .range(0.0, 1e4)
        .describe("Plausibility: fastest output-axis speed; a larger encoder jump is a sensor fault"),
        V::real(
            "consistencyTolerance",
            422,
            |m| m.consistency_tolerance,
            |m, v| m.consistency_tolerance = v,
        )
        .parameter(Start::Real(ConsistencyCheck::DEFAULT_TOLERANCE))
        .unit("N.m")
        .range(0.0, 100.0)
        .describe("Sensor consistency: absolute allowance between the transducer and k x encoder deflection (SEA, CSEA), and between the load cell and i_HD Km1 x test current"),
        V::real(
            "consistencyRelativeTolerance",
            423,
            |m| m.consistency_relative,
            |m, v| m.consistency_relative = v,
        )
        .parameter(Start::Real(ConsistencyCheck::DEFAULT_RELATIVE))
        .range(0.0, 10.0)
        .describe("Sensor consistency: allowance per N m of the larger of the two torques compared"),
        V::integer(
            "consistencyPersistence",
            424,
            |m| m.consistency_persistence,
            |m, v| m.consistency_persistence = v,
        )
        .parameter(Start::Integer(ConsistencyCheck::DEFAULT_PERSISTENCE as i32))
        .range(0.0, 100_000.0)
        .describe("Sensor consistency: consecutive disagreeing samples that trip (code 12 transducer, 13 load cell); 0 turns the checks off"),
        window!("loadCellVoltageMin", 410, A::LoadCell, 0, "Plausibility window of the load cell, low end"),
        window!("loadCellVoltageMax", 411, A::LoadCell, 1, "Load cell, high end"),
        window!("transducerVoltageMin", 412, A::Transducer, 0, "Torque transducer, low end"),
        window!("transducerVoltageMax", 413, A::Transducer, 1, "Torque transducer, high end"),
        window!("testCurrentSenseVoltageMin", 414, A::TestCurrentSense, 0, "Test current sensor, low end"),
        window!("testCurrentSenseVoltageMax", 415, A::TestCurrentSense, 1, "Test current sensor, high end"),
        window!("loadCurrentSenseVoltageMin", 416, A::LoadCurrentSense, 0, "Load current sensor, low end"),
        window!("loadCurrentSenseVoltageMax", 417, A::LoadCurrentSense, 1, "Load current sensor, high end"),
        window!("testSupplySenseVoltageMin", 418, A::TestSupplySense, 0, "Test supply divider, low end (18 V supply)"),
        window!("testSupplySenseVoltageMax", 419, A::TestSupplySense, 1, "Test supply divider, high end (30 V)"),
        window!("loadSupplySenseVoltageMin", 420, A::LoadSupplySense, 0, "Load supply divider, low end (40 V)"),
        window!("loadSupplySenseVoltageMax", 421, A::LoadSupplySense, 1, "Load supply divider, high end (56 V)"),
        local!(int "overrunCount", 450, overrun_count, "Pacing overruns so far"),
        local!(real "lastLateness", 451, last_lateness, "s", "Lateness of the last step's deadline"),
        local!(real "maxLateness", 452, max_lateness, "s", "Largest lateness so far"),
        local!(int "rejectedFrames", 453, rejected_frames, "Frames from the server rejected (unauthenticated, malformed, replayed, out of order, wrong version or session)"),
        local!(int "staleReplies", 454, stale_replies, "Replies that came too late for their request and were ignored"),
        local!(real "lastReplyTime", 455, last_reply_time, "s", "How long the last step's sample took to arrive after its request"),
        local!(real "maxReplyTime", 456, max_reply_time, "s", "Longest reply time so far"),
    ];
        // The plant's parameters that the measurements need (calibration, conversions, limits),
        // from the plant's own list: same name, value reference, unit, range and meaning; fixed
        // here, as the bench is set up once per run.
        macro_rules! param {
            ($name:literal, $vr:expr, $field:ident, $unit:tt, $desc:literal) => {
                if SHARED_PARAMETERS.contains(&$name) {
                    let (lo, hi) = range(stringify!($field));
                    let var = V::real($name, $vr, |m| m.params.$field, |m, x| m.params.$field = x)
                        .parameter(Start::Real(d.$field))
                        .range(lo, hi)
                        .describe($desc);
                    v.push(with_unit(var, unit_of!($unit)));
                }
            };
        }
        for_each_bench_parameter!(param);
        v.extend(io_variables::<BenchHardwareModel>());
        v
    })
};

fn saturate(x: u64) -> i32 {
    i32::try_from(x).unwrap_or(i32::MAX)
}

impl BenchHardwareModel {
    /// The bench parameters with the enumerations applied.
    fn parameters(&self) -> Result<BenchParameters, ModelError> {
        let mut p = self.params.clone();
        p.configuration = Configuration::from_i32(self.configuration)
            .ok_or_else(|| ModelError::new(format!("configuration {}", self.configuration)))?;
        p.friction_model = FrictionModel::from_i32(self.friction_model)
            .ok_or_else(|| ModelError::new(format!("frictionModel {}", self.friction_model)))?;
        p.test_driver_mode = DriverMode::from_i32(self.test_driver_mode)
            .ok_or_else(|| ModelError::new(format!("testDriverMode {}", self.test_driver_mode)))?;
        p.load_driver_mode = DriverMode::from_i32(self.load_driver_mode)
            .ok_or_else(|| ModelError::new(format!("loadDriverMode {}", self.load_driver_mode)))?;
        p.validate().map_err(|e| ModelError::new(e.to_string()))?;
        Ok(p)
    }

    /// The command of this period from the inputs, clipped like the drivers clip.
    fn command(&self, p: &BenchParameters) -> Result<Command, ModelError> {
        let c = &self.commands;
        let pick =
            |mode: DriverMode, voltage: f64, current: f64, supply: f64, limit: f64| match mode {
                DriverMode::Voltage => voltage.clamp(-supply, supply),
                DriverMode::Current => current.clamp(-limit, limit),
            };
        for (name, v) in [
            ("testVoltageCommand", c.test_voltage),
            ("testCurrentCommand", c.test_current),
            ("loadVoltageCommand", c.load_voltage),
            ("loadCurrentCommand", c.load_current),
        ] {
            if !v.is_finite() {
                return Err(ModelError::new(format!("input {name} is not finite: {v}")));
            }
        }
        Ok(Command {
            test_set_value: pick(
                p.test_driver_mode,
                c.test_voltage,
                c.test_current,
                p.test_supply_voltage,
                p.test_current_limit,
            ),
            load_set_value: pick(
                p.load_driver_mode,
                c.load_voltage,
                c.load_current,
                p.load_supply_voltage,
                p.load_current_limit,
            ),
            test_enable: c.test_enable,
            load_enable: c.load_enable,
            clutch: c.clutch_engage,
            test_kind: kind_of(p.test_driver_mode),
            load_kind: kind_of(p.load_driver_mode),
        })
    }

    fn open_backend(&self, p: &BenchParameters) -> Result<Box<dyn BenchIo>, ModelError> {
        let backend = Backend::from_i32(self.backend)
            .ok_or_else(|| ModelError::new(format!("backend {}", self.backend)))?;
        match backend {
            Backend::Simulated => {
                // The bench's own protection in the simulation: the drivers' over-current
                // and the button stay; the interlocks this FMU checks are lifted so that the
                // FMU's checks are what trips.
                let mut sim = p.clone();
                sim.spring_deflection_limit = 10.0;
                sim.motor_torque_limit = 1e4;
                sim.load_regen_power_limit = 1e6;
                Ok(Box::new(
                    SimulatedBench::new(sim).map_err(|e| ModelError::new(e.to_string()))?,
                ))
            }
            Backend::Udp => {
                if PacingMode::from_i32(self.pacing) == Some(PacingMode::None) {
                    return Err(ModelError::new(
                        "the Udp backend needs real-time pacing (pacing = Soft or Hard)",
                    ));
                }
                let key = if self.key_file.is_empty() {
                    None
                } else {
                    Some(
                        Key::load_file(std::path::Path::new(&self.key_file))
                            .map_err(|e| ModelError::new(format!("keyFile: {e}")))?,
                    )
                };
                let setup =
                    UdpSetup {
                        address: self.server_address.clone(),
                        key,
                        setup: BenchSetup {
                            configuration: p.configuration.as_i32() as u8,
                            test_kind: kind_of(p.test_driver_mode),
                            load_kind: kind_of(p.load_driver_mode),
                        },
                        // A server whose previous session was not released is free again after
                        // its heartbeat timeout (at most 100 ms): asked again until then.
                        handshake_timeout: Duration::from_secs_f64(INIT_REPLY_TIMEOUT.max(
                            crate::hardware::protocol::MAX_HEARTBEAT_TIMEOUT.as_secs_f64() * 2.0,
                        )),
                        // Initialization (tare) may wait longer than a period.
                        reply_timeout: Duration::from_secs_f64(
                            self.reply_timeout.max(INIT_REPLY_TIMEOUT),
                        ),
                        spin: Duration::from_secs_f64(self.spin_margin),
                    };
                Ok(Box::new(
                    UdpBench::connect(&setup).map_err(|e| ModelError::new(e.to_string()))?,
                ))
            }
        }
    }

    fn start(&mut self) -> Result<(), ModelError> {
        let p = self.parameters()?;
        let pacing = PacingMode::from_i32(self.pacing)
            .ok_or_else(|| ModelError::new(format!("pacing {}", self.pacing)))?;
        let mut io = self.open_backend(&p)?;
        let safe = Command::safe(kind_of(p.test_driver_mode), kind_of(p.load_driver_mode));
        let io_err =
            |what: &str, e: IoError| ModelError::new(format!("initialization: {what}: {e}"));
        let latched = io.latched();
        if latched != reason::NONE {
            if !self.acknowledge_safe_state {
                return Err(ModelError::new(format!(
                    "initialization: the bench is latched in its safe state ({}) from an earlier session; check the bench, then set acknowledgeSafeState = true to clear the latch",
                    reason_name(latched)
                )));
            }
            let s = io
                .acknowledge(latched)
                .map_err(|e| io_err("acknowledging the latched safe state", e))?;
            if s.has(status::SAFE_STATE) {
                return Err(ModelError::new(format!(
                    "initialization: the bench kept its safe state after the acknowledgement ({}, status {:#04x}): release the emergency stop",
                    reason_name(s.safe_reason),
                    s.status
                )));
            }
        }
        let seq = io
            .write(0.0, &safe)
            .map_err(|e| io_err("disabling the drivers", e))?;
        let mut rt = Runtime {
            io,
            cal: Calibration::new(&p),
            p,
            limits: self.plausibility,
            consistency: ConsistencyCheck::new(
                self.consistency_tolerance,
                self.consistency_relative,
                u32::try_from(self.consistency_persistence).unwrap_or(0),
            ),
            pacer: Pacer::new(pacing, Duration::from_secs_f64(self.spin_margin)),
            encoders: [Unwrapper::default(); 2],
            counts: [0; 2],
            delta: [[0; 2]; 2],
            dt: [0.0; 2],
            server_us: 0,
            trip: None,
            bench_time: 0.0,
            safe_timeout: Duration::from_secs_f64(self.safe_state_timeout),
            warnings: Vec::new(),
            realtime: None,
            first_step_checked: false,
            realtime_tried: false,
            reply_time: (0.0, 0.0),
        };
        if latched != reason::NONE {
            rt.warnings.push(format!(
                "acknowledged the bench's latched safe state ({}) as acknowledgeSafeState asked",
                reason_name(latched)
            ));
        }
        if self.lock_memory
            && pacing != PacingMode::None
            && let Err(e) = lock_memory()
        {
            rt.warnings
                .push(format!("lockMemory: {e}; pages stay pageable"));
        }
        let mut tare = Tare::default();
        let mut last = None;
        for _ in 0..self.tare_samples.max(1) {
            let s = rt.io.read(0.0).map_err(|e| io_err("tare sample", e))?;
            if s.has(status::SAFE_STATE) || s.has(status::EMERGENCY_STOP) {
                return Err(ModelError::new(format!(
                    "initialization: the bench is in the safe state (reason {}, status {:#04x}); release the emergency stop and restart the server's session",
                    s.safe_reason, s.status
                )));
            }
            if s.last_command_sequence != seq {
                return Err(ModelError::new(
                    "initialization: the bench did not confirm the drivers-disabled command",
                ));
            }
            rt.limits
                .check_analog(&s)
                .map_err(|e| ModelError::new(format!("initialization: {e}")))?;
            if self.tare_samples > 0 {
                tare.add(&s);
            }
            last = Some(s);
        }
        rt.cal.apply_tare(&tare);
        rt.io
            .set_reply_timeout(Duration::from_secs_f64(self.reply_timeout));
        let Some(s) = last else {
            return Err(ModelError::new("initialization: no sample"));
        };
        rt.encoders[0].update(s.test_counts);
        rt.encoders[1].update(s.load_counts);
        rt.server_us = s.server_time_us;
        let prev = BenchOutputs::default();
        self.outputs = measure(&rt, &s, &safe, None, &prev, [false; 2]);
        self.runtime = Slot(Some(Box::new(rt)));
        Ok(())
    }

    fn trip(&mut self, code: i32, at: f64) -> Result<StepOutcome, ModelError> {
        let start = self.start_time;
        self.outputs.trip_code = code;
        let Some(rt) = self.runtime.0.as_mut() else {
            return Err(ModelError::new("not initialized"));
        };
        rt.trip = Some((code, at));
        // No more pacing: the thread goes back to its own scheduling.
        rt.realtime = None;
        let name = trip::name(code);
        let bench_at = rt.bench_time.min(at - start).max(0.0);
        match rt
            .io
            .enter_safe_state(bench_at, reason::CLIENT_REQUEST, rt.safe_timeout)
        {
            Ok(ack)
                if ack.has(status::SAFE_STATE)
                    && !ack.has(status::TEST_ENABLED | status::LOAD_ENABLED | status::CLUTCH) =>
            {
                Ok(StepOutcome::Terminated { at, reason: name })
            }
            Ok(ack) => Err(ModelError::new(format!(
                "trip {code} ({name}) at t = {at}: the bench acknowledged the safe state with outputs still on (status {:#04x}): NOT SAFE",
                ack.status
            ))),
            Err(e) => Err(ModelError::new(format!(
                "trip {code} ({name}) at t = {at}: safe state NOT confirmed ({e}); only the bench's own watchdog can stop it"
            ))),
        }
    }

    fn sync_statistics(&mut self) {
        if let Some(rt) = self.runtime.0.as_ref() {
            let s = rt.pacer.stats;
            self.overrun_count = saturate(s.overruns);
            self.last_lateness = s.last_lateness;
            self.max_lateness = s.max_lateness;
            self.rejected_frames = saturate(rt.io.counters().rejected());
            self.stale_replies = saturate(rt.io.stale_replies());
            (self.last_reply_time, self.max_reply_time) = rt.reply_time;
        }
    }

    fn step(&mut self, t: f64, h: f64) -> Result<StepOutcome, ModelError> {
        // Step sizes to the nanosecond: importers that form h as a difference of float times
        // send 0.0010000000000000009; finite differences must not depend on that rounding.
        let h = match (h * 1e9).round() / 1e9 {
            snapped if snapped > 0.0 => snapped,
            _ => h,
        };
        let Some(rt) = self.runtime.0.as_mut() else {
            return Err(ModelError::new("the bench was not initialized"));
        };
        if let Some((code, at)) = rt.trip {
            return Ok(StepOutcome::Terminated {
                at,
                reason: trip::name(code),
            });
        }
        if self.commands.emergency_stop {
            return self.trip(7, t);
        }
        let p = rt.p.clone();
        let command = match self.command(&p) {
            Ok(c) => c,
            Err(e) => {
                // A broken controller: stop the bench, then fail.
                let _ = self.trip(trip::LINK, t);
                return Err(e);
            }
        };
        let Some(rt) = self.runtime.0.as_mut() else {
            return Err(ModelError::new("the bench was not initialized"));
        };
        if !rt.first_step_checked && rt.pacer.mode() != PacingMode::None {
            rt.first_step_checked = true;
            if self.backend == Backend::Udp as i32 && self.reply_timeout >= h {
                rt.warnings.push(format!(
                    "replyTimeout {} s is not below the step size {h} s: a missing sample is found only after the next deadline has passed",
                    self.reply_timeout
                ));
            }
        }
        if !rt.realtime_tried && rt.pacer.mode() != PacingMode::None && self.realtime_priority > 0 {
            rt.realtime_tried = true;
            match RealtimeThread::enter(self.realtime_priority) {
                Ok(g) => rt.realtime = Some(g),
                Err(e) => rt.warnings.push(format!(
                    "realtimePriority {}: {e}; pacing continues with normal scheduling",
                    self.realtime_priority
                )),
            }
        }
        rt.pacer.start(t);
        let now = rt.bench_time;
        let seq = match rt.io.write(now, &command) {
            Ok(seq) => seq,
            Err(_) => return self.trip(trip::LINK, t),
        };
        let wait = rt.pacer.wait(t + h);
        if wait.overrun && rt.pacer.mode() == PacingMode::Soft {
            let n = rt.pacer.stats.overruns;
            if n <= 20 || n.is_multiple_of(1000) {
                rt.warnings.push(format!(
                    "overrun at t = {t}: the step reached its deadline {:.0} us late ({n} overruns so far)",
                    wait.lateness * 1e6
                ));
            }
        }
        rt.bench_time = now + h;
        let asked = now_ns();
        let sample = rt.io.read(now + h);
        let reply = now_ns().saturating_sub(asked) as f64 * 1e-9;
        rt.reply_time = (reply, rt.reply_time.1.max(reply));
        let sample = match sample {
            Ok(s) => s,
            Err(_) => {
                self.sync_statistics();
                return self.trip(trip::LINK, t);
            }
        };
        // Raw channels into the outputs first, so that a row at the trip shows them.
        let prev = self.outputs;
        let first_counts = rt.counts;
        let c1 = rt.encoders[0].update(sample.test_counts);
        let c2 = rt.encoders[1].update(sample.load_counts);
        rt.counts = [c1, c2];
        rt.delta = [[c1 - first_counts[0], c2 - first_counts[1]], rt.delta[0]];
        // Over UDP the samples are as far apart as the server's clock says (a late sample
        // after an overrun covers more than h); the simulated bench is sampled exactly at h.
        let dt = match rt.io.timestamps_are_wall_time() {
            true if sample.server_time_us > rt.server_us => {
                (sample.server_time_us - rt.server_us) as f64 * 1e-6
            }
            _ => h,
        };
        rt.server_us = sample.server_time_us;
        rt.dt = [dt, rt.dt[0]];
        let stuck = [c1 == first_counts[0], c2 == first_counts[1]];
        let mut code = 0;
        if sample.has(status::EMERGENCY_STOP) {
            code = 7;
        } else if sample.has(status::SAFE_STATE) {
            code = trip::BENCH;
        } else if rt.limits.check_analog(&sample).is_err()
            || rt
                .limits
                .check_encoder(&rt.cal, Side::Actuation, c1 - first_counts[0], h)
                .is_err()
            || rt
                .limits
                .check_encoder(&rt.cal, Side::Load, c2 - first_counts[1], h)
                .is_err()
        {
            code = trip::SENSOR;
        }
        if code == trip::SENSOR {
            let fault = rt
                .limits
                .check_analog(&sample)
                .err()
                .map(|e| e.to_string())
                .unwrap_or_else(|| "encoder jump".into());
            rt.warnings.push(format!("t = {}: {fault}", t + h));
            raw_into(&mut self.outputs, &sample);
        } else {
            self.outputs = measure(rt, &sample, &command, Some(h), &prev, stuck);
        }
        if code == 0 {
            let o = &self.outputs;
            let spring = (rt.p.configuration != Configuration::Da)
                .then_some((o.transducer_torque, o.spring_torque));
            match rt
                .consistency
                .update(spring, (o.load_cell_torque, o.test_output_torque))
            {
                Some(fault) => {
                    code = match fault {
                        Inconsistency::Transducer { .. } => trip::TRANSDUCER_INCONSISTENT,
                        Inconsistency::LoadCell { .. } => trip::LOAD_CELL_INCONSISTENT,
                    };
                    rt.warnings.push(format!(
                        "t = {}: {fault} for {} samples",
                        t + h,
                        rt.consistency.persistence
                    ));
                }
                None => code = interlock(&rt.p, &self.outputs),
            }
        }
        if code == 0 && sample.last_command_sequence != seq {
            code = trip::LINK;
        }
        if code == 0 && wait.overrun && rt.pacer.mode() == PacingMode::Hard {
            code = trip::OVERRUN;
        }
        self.sync_statistics();
        if code != 0 {
            return self.trip(code, t + h);
        }
        Ok(StepOutcome::Completed)
    }
}

/// The log text of a safe-state reason.
fn reason_name(r: u8) -> &'static str {
    match r {
        reason::CLIENT_REQUEST => "a master's trip",
        reason::HEARTBEAT_TIMEOUT => "the server's heartbeat watchdog",
        reason::EMERGENCY_STOP => "the emergency stop",
        reason::SESSION_END => "a session end",
        reason::BENCH_PROTECTION => "the bench's own protection",
        reason::SERVER_RESTART => "a server restart under a live session",
        _ => "unknown reason",
    }
}

/// The interlock of bench-model.md §7 the outputs violate (code 1-6), or 0.
fn interlock(p: &BenchParameters, o: &BenchOutputs) -> i32 {
    if o.spring_deflection.abs() > p.spring_deflection_limit {
        1
    } else if o.transducer_torque.abs() > p.motor_torque_limit {
        // The test motor's torque past the harmonic drive: the shaft torque the transducer
        // measures (the plant's definition; see its documentation).
        2
    } else if o.load_output_torque.abs() > p.motor_torque_limit {
        3
    } else if o.test_motor_current.abs() > p.test_current_limit {
        4
    } else if o.load_motor_current.abs() > p.load_current_limit {
        5
    } else if o.load_regenerated_power > p.load_regen_power_limit {
        6
    } else {
        0
    }
}

fn raw_into(o: &mut BenchOutputs, s: &Sample) {
    let a = |c: AnalogChannel| s.analog[c.index()];
    o.load_cell_voltage = a(AnalogChannel::LoadCell);
    o.transducer_voltage = a(AnalogChannel::Transducer);
    o.test_current_sense_voltage = a(AnalogChannel::TestCurrentSense);
    o.load_current_sense_voltage = a(AnalogChannel::LoadCurrentSense);
    o.test_supply_sense_voltage = a(AnalogChannel::TestSupplySense);
    o.load_supply_sense_voltage = a(AnalogChannel::LoadSupplySense);
    o.clutch_engaged = s.has(status::CLUTCH);
}

/// Armature voltage estimate and saturation of one driver.
fn armature(
    enabled: bool,
    kind_is_voltage: bool,
    set_value: f64,
    needed: f64,
    supply: f64,
) -> (f64, bool) {
    if enabled && kind_is_voltage {
        (set_value.clamp(-supply, supply), set_value.abs() >= supply)
    } else {
        (
            needed.clamp(-supply, supply),
            enabled && needed.abs() >= supply,
        )
    }
}

/// The outputs from a sample (module docs, "Outputs"). `h` is `None` at initialization.
fn measure(
    rt: &Runtime,
    s: &Sample,
    applied: &Command,
    h: Option<f64>,
    prev: &BenchOutputs,
    stuck: [bool; 2],
) -> BenchOutputs {
    let p = &rt.p;
    let cal = &rt.cal;
    let mut o = BenchOutputs::default();
    raw_into(&mut o, s);
    let a = |c: AnalogChannel| s.analog[c.index()];
    let [c1, c2] = [rt.encoders[0].total(), rt.encoders[1].total()];
    let th1 = cal.angle(Side::Actuation, c1);
    let th2 = cal.angle(Side::Load, c2);
    o.actuation_encoder_counts = c1 as f64;
    o.load_encoder_counts = c2 as f64;
    o.actuation_encoder_angle = th1;
    o.load_encoder_angle = th2;
    o.actuation_angle = th1;
    o.load_angle = th2;
    let (w1, w2, a1, a2) = match h {
        Some(h) => {
            // From integer count differences, so that equal movements give exactly zero
            // acceleration whatever rounding the step size carries.
            let [now, before] = rt.delta;
            let [dt, dt_before] = rt.dt;
            let dt = if dt > 0.0 { dt } else { h };
            if dt < 0.5 * h && dt_before > 0.0 {
                // The loop catching up after a stall: this sample follows the last by much
                // less than a period, too short for its counts to make a velocity (one count
                // over 0.1 ms reads as a speed spike, and the powers and the regenerated-power
                // interlock with it). The window widens to the last two intervals.
                let span = dt + dt_before;
                let w = |side, counts| cal.angle(side, counts) / span;
                let w_before = |side, counts| cal.angle(side, counts) / dt_before;
                let (w1, w2) = (
                    w(Side::Actuation, now[0] + before[0]),
                    w(Side::Load, now[1] + before[1]),
                );
                (
                    w1,
                    w2,
                    (w1 - w_before(Side::Actuation, before[0])) / (0.5 * span),
                    (w2 - w_before(Side::Load, before[1])) / (0.5 * span),
                )
            } else if dt_before == dt || dt_before <= 0.0 {
                (
                    cal.angle(Side::Actuation, now[0]) / dt,
                    cal.angle(Side::Load, now[1]) / dt,
                    cal.angle(Side::Actuation, now[0] - before[0]) / (dt * dt),
                    cal.angle(Side::Load, now[1] - before[1]) / (dt * dt),
                )
            } else {
                let w = |side, counts| cal.angle(side, counts) / dt;
                let w_before = |side, counts| cal.angle(side, counts) / dt_before;
                (
                    w(Side::Actuation, now[0]),
                    w(Side::Load, now[1]),
                    (w(Side::Actuation, now[0]) - w_before(Side::Actuation, before[0])) / dt,
                    (w(Side::Load, now[1]) - w_before(Side::Load, before[1])) / dt,
                )
            }
        }
        None => (0.0, 0.0, 0.0, 0.0),
    };
    o.actuation_velocity = w1;
    o.load_velocity = w2;
    o.actuation_acceleration = a1;
    o.load_acceleration = a2;
    let k = match p.configuration {
        Configuration::Da => p.direct_coupling_stiffness,
        _ => p.spring_stiffness,
    };
    let defl = th1 - th2;
    o.spring_deflection = defl;
    o.spring_torque = k * defl;
    let i1 = cal.current(a(AnalogChannel::TestCurrentSense));
    let i2 = cal.current(a(AnalogChannel::LoadCurrentSense));
    o.test_motor_current = i1;
    o.load_motor_current = i2;
    o.test_motor_torque = p.test_motor_torque_constant * i1;
    o.load_motor_torque = p.load_motor_torque_constant * i2;
    o.test_output_torque = p.harmonic_drive_ratio * o.test_motor_torque;
    o.load_output_torque = p.reduction_ratio * o.load_motor_torque;
    o.transducer_torque = cal.transducer_torque(a(AnalogChannel::Transducer));
    o.load_cell_torque = cal.load_cell_torque(a(AnalogChannel::LoadCell));
    let wm1 = p.harmonic_drive_ratio * w1;
    let wm2 = p.reduction_ratio * w2;
    let supply1 = cal.supply_voltage(a(AnalogChannel::TestSupplySense));
    let supply2 = cal.supply_voltage(a(AnalogChannel::LoadSupplySense));
    let (v1, sat1) = armature(
        applied.test_enable,
        p.test_driver_mode == DriverMode::Voltage,
        applied.test_set_value,
        p.test_motor_resistance * i1 + p.test_motor_back_emf_constant * wm1,
        supply1,
    );
    let (v2, sat2) = armature(
        applied.load_enable,
        p.load_driver_mode == DriverMode::Voltage,
        applied.load_set_value,
        p.load_motor_resistance * i2 + p.load_motor_back_emf_constant * wm2,
        supply2,
    );
    o.test_motor_voltage = v1;
    o.load_motor_voltage = v2;
    o.test_driver_saturated = sat1;
    o.load_driver_saturated = sat2;
    o.actuation_stuck = stuck[0];
    o.load_stuck = stuck[1];
    o.test_mechanical_power = o.test_output_torque * w1;
    o.load_mechanical_power = o.load_output_torque * w2;
    o.kinetic_energy = 0.5 * (p.actuation_inertia * w1 * w1 + p.load_inertia * w2 * w2);
    o.potential_energy = 0.5 * k * defl * defl;
    o.kinetic_energy_change = o.kinetic_energy;
    o.potential_energy_change = o.potential_energy;
    o.actuation_loss_power =
        p.actuation_inertia * w1 * a1 + o.spring_torque * w1 - o.test_mechanical_power;
    o.load_loss_power = p.load_inertia * w2 * a2 - o.spring_torque * w2 - o.load_mechanical_power;
    o.loss_power = o.actuation_loss_power + o.load_loss_power;
    o.actuation_friction_torque =
        p.actuation_inertia * a1 + p.actuation_damping * w1 + o.spring_torque
            - o.test_output_torque;
    o.load_friction_torque =
        p.load_inertia * a2 + p.load_damping * w2 - o.spring_torque - o.load_output_torque;
    o.test_electrical_power = v1 * i1;
    o.load_electrical_power = v2 * i2;
    o.load_regenerated_power = (-o.load_electrical_power).max(0.0);
    o.clutch_power = if o.clutch_engaged {
        p.clutch_power
    } else {
        0.0
    };
    o.offset_power = p.hardware_offset_power;
    o.total_electrical_power =
        o.test_electrical_power + o.load_electrical_power + o.clutch_power + o.offset_power;
    let copper = [
        p.test_motor_resistance * i1 * i1,
        p.load_motor_resistance * i2 * i2,
    ];
    let emf = [
        p.test_motor_back_emf_constant * wm1 * i1,
        p.load_motor_back_emf_constant * wm2 * i2,
    ];
    if let Some(h) = h {
        o.kinetic_energy_rate = (o.kinetic_energy - prev.kinetic_energy) / h;
        o.potential_energy_rate = (o.potential_energy - prev.potential_energy) / h;
        let trap = |acc: f64, a: f64, b: f64| acc + 0.5 * h * (a + b);
        let pos = |x: f64| x.max(0.0);
        o.test_mechanical_energy = trap(
            prev.test_mechanical_energy,
            prev.test_mechanical_power,
            o.test_mechanical_power,
        );
        o.test_mechanical_energy_consumed = trap(
            prev.test_mechanical_energy_consumed,
            pos(prev.test_mechanical_power),
            pos(o.test_mechanical_power),
        );
        o.load_mechanical_energy = trap(
            prev.load_mechanical_energy,
            prev.load_mechanical_power,
            o.load_mechanical_power,
        );
        o.load_mechanical_energy_consumed = trap(
            prev.load_mechanical_energy_consumed,
            pos(prev.load_mechanical_power),
            pos(o.load_mechanical_power),
        );
        o.loss_energy = trap(prev.loss_energy, prev.loss_power, o.loss_power);
        o.actuation_loss_energy = trap(
            prev.actuation_loss_energy,
            prev.actuation_loss_power,
            o.actuation_loss_power,
        );
        o.load_loss_energy = trap(
            prev.load_loss_energy,
            prev.load_loss_power,
            o.load_loss_power,
        );
        o.test_electrical_energy = trap(
            prev.test_electrical_energy,
            prev.test_electrical_power,
            o.test_electrical_power,
        );
        o.test_electrical_energy_consumed = trap(
            prev.test_electrical_energy_consumed,
            pos(prev.test_electrical_power),
            pos(o.test_electrical_power),
        );
        o.load_electrical_energy = trap(
            prev.load_electrical_energy,
            prev.load_electrical_power,
            o.load_electrical_power,
        );
        o.load_electrical_energy_consumed = trap(
            prev.load_electrical_energy_consumed,
            pos(prev.load_electrical_power),
            pos(o.load_electrical_power),
        );
        o.clutch_energy = trap(prev.clutch_energy, prev.clutch_power, o.clutch_power);
        o.offset_energy = trap(prev.offset_energy, prev.offset_power, o.offset_power);
        o.total_electrical_energy = trap(
            prev.total_electrical_energy,
            prev.total_electrical_power,
            o.total_electrical_power,
        );
        o.total_electrical_energy_consumed = trap(
            prev.total_electrical_energy_consumed,
            pos(prev.total_electrical_power),
            pos(o.total_electrical_power),
        );
        let prev_copper = [
            p.test_motor_resistance * prev.test_motor_current.powi(2),
            p.load_motor_resistance * prev.load_motor_current.powi(2),
        ];
        let prev_emf = [
            p.test_motor_back_emf_constant
                * p.harmonic_drive_ratio
                * prev.actuation_velocity
                * prev.test_motor_current,
            p.load_motor_back_emf_constant
                * p.reduction_ratio
                * prev.load_velocity
                * prev.load_motor_current,
        ];
        o.test_copper_loss_energy = trap(prev.test_copper_loss_energy, prev_copper[0], copper[0]);
        o.load_copper_loss_energy = trap(prev.load_copper_loss_energy, prev_copper[1], copper[1]);
        o.test_back_emf_energy = trap(prev.test_back_emf_energy, prev_emf[0], emf[0]);
        o.load_back_emf_energy = trap(prev.load_back_emf_energy, prev_emf[1], emf[1]);
    }
    o.trip_code = prev.trip_code;
    o
}

impl ReferenceInputs for BenchHardwareModel {
    fn reference_inputs() -> Option<String> {
        // The plant's documented open-loop run (current-mode sinusoids, clutch pulse), on the
        // simulated backend: the packed reference results show the hardware path (raw sensors,
        // calibration with tare, finite-difference velocities) on the same inputs.
        BenchPlantInputs::reference_inputs()
    }
}

use super::bench_plant::BenchPlantModel as BenchPlantInputs;

impl Model for BenchHardwareModel {
    const IDENTIFIER: &'static str = "BenchHardware";
    const DESCRIPTION: &'static str = "The knee-actuator test bench itself: the plant's signal interface over bench I/O (simulated in process, or a UDP real-time I/O server), with calibration, tare, plausibility checks, real-time pacing and latched safety interlocks";
    const DEFAULT_EXPERIMENT: (f64, f64, f64) = (0.0, 5.0, 1e-3);

    fn variables() -> &'static [Variable<Self>] {
        &VARIABLES
    }

    fn enumerations() -> &'static [EnumerationType] {
        &ENUMERATIONS
    }

    fn initialize(&mut self, start_time: f64) -> Result<(), ModelError> {
        self.start_time = start_time;
        self.start()
    }

    fn calculate(&mut self, _t: f64) -> Result<(), ModelError> {
        Ok(())
    }

    /// [`MAX_INTERNAL_STEPS_PER_CALL`](crate::model::MAX_INTERNAL_STEPS_PER_CALL) internal
    /// integration steps of `maxInternalStep`.
    fn max_step_size(&self) -> f64 {
        crate::model::MAX_INTERNAL_STEPS_PER_CALL * self.params.max_internal_step
    }

    fn do_step(&mut self, t: f64, h: f64) -> Result<StepOutcome, ModelError> {
        self.step(t, h)
    }

    fn take_warnings(&mut self) -> Vec<String> {
        match self.runtime.0.as_mut() {
            Some(rt) if !rt.warnings.is_empty() => std::mem::take(&mut rt.warnings),
            _ => Vec::new(),
        }
    }

    fn save_internal(&self, w: &mut StateWriter) {
        w.f64(self.start_time);
        w.bool(self.runtime.0.is_some());
    }

    fn load_internal(&mut self, r: &mut StateReader<'_>) -> Result<(), StateError> {
        self.start_time = r.f64()?;
        if r.bool()? {
            return Err(StateError(
                "a BenchHardware state saved after initialization cannot be restored: the physical bench cannot be rewound".into(),
            ));
        }
        Ok(())
    }

    fn documentation() -> &'static str {
        // SAFETY: a static (Lazy registers its address for the release at unload).
        static HTML: Lazy<String> = unsafe {
            Lazy::new(|| crate::model::module_doc_html(include_str!("bench_hardware.rs")))
        };
        &HTML
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Causality, model_description};
    use crate::models::bench_plant::BenchPlantModel;
    use ::model_description::ModelDescription;

    fn interface(md: &ModelDescription) -> Vec<String> {
        md.model_variables
            .iter()
            .filter(|v| matches!(v.causality, Some(Causality::Input | Causality::Output)))
            .map(|v| format!("{v:?}"))
            .collect()
    }

    #[test]
    fn inputs_and_outputs_are_the_plants_exactly() {
        let plant = model_description::<BenchPlantModel>();
        let hw = model_description::<BenchHardwareModel>();
        let (a, b) = (interface(&plant), interface(&hw));
        assert!(a.len() >= 8 + 74, "{}", a.len());
        assert_eq!(a, b);
        // Outputs are listed in the same order in the ModelStructure, by name.
        let outputs = |md: &ModelDescription| {
            md.model_structure
                .outputs
                .iter()
                .map(|u| md.model_variables[u.index as usize - 1].name.clone())
                .collect::<Vec<_>>()
        };
        assert_eq!(outputs(&plant), outputs(&hw));
    }

    #[test]
    fn shared_parameters_have_the_plants_reference_unit_and_range() {
        let plant = model_description::<BenchPlantModel>();
        let hw = model_description::<BenchHardwareModel>();
        let mut shared = 0;
        for v in &hw.model_variables {
            if v.value_reference < 400 && v.causality == Some(Causality::Parameter) {
                let Some(pv) = plant.model_variables.iter().find(|p| p.name == v.name) else {
                    panic!(
                        "{} is not a plant parameter but has a plant-range reference",
                        v.name
                    )
                };
                assert_eq!(pv.value_reference, v.value_reference, "{}", v.name);
                assert_eq!(
                    format!("{:?}", pv.kind),
                    format!("{:?}", v.kind),
                    "{}",
                    v.name
                );
                shared += 1;
            } else if v.causality == Some(Causality::Parameter) {
                assert!(
                    plant
                        .model_variables
                        .iter()
                        .all(|p| p.value_reference != v.value_reference),
                    "{}",
                    v.name
                );
            }
        }
        assert!(shared >= 35, "{shared}");
    }

    fn started(configure: impl FnOnce(&mut BenchHardwareModel)) -> BenchHardwareModel {
        let mut m = crate::fmi2::instance::fresh_model::<BenchHardwareModel>();
        configure(&mut m);
        m.initialize(0.0).unwrap();
        m
    }

    fn run(m: &mut BenchHardwareModel, n: usize, h: f64) -> Option<(f64, &'static str)> {
        for k in 0..n {
            match m.do_step(k as f64 * h, h).unwrap() {
                StepOutcome::Completed => {}
                StepOutcome::Terminated { at, reason } => return Some((at, reason)),
            }
        }
        None
    }

    #[test]
    fn simulated_bench_at_rest_reads_zero_after_the_tare() {
        let mut m = started(|_| {});
        assert!(m.outputs.transducer_torque.abs() < 1e-12);
        assert!(m.outputs.load_cell_torque.abs() < 1e-9);
        m.commands.test_enable = false;
        m.commands.load_enable = false;
        assert_eq!(run(&mut m, 100, 1e-3), None);
        assert_eq!(m.outputs.actuation_encoder_counts, 0.0);
        assert!(m.outputs.test_motor_current.abs() < 1e-12);
    }

    #[test]
    fn simulated_bench_follows_the_plant() {
        use crate::models::bench::{BenchInputs, BenchPlant};
        let h = 1e-3;
        let mut hw = started(|_| {});
        let mut plant = BenchPlant::new(BenchParameters::default()).unwrap();
        let cal = Calibration::new(&BenchParameters::default());
        for k in 0..1000 {
            let t = k as f64 * h;
            let i1 = 2.0 * (std::f64::consts::TAU * 0.4 * t).sin();
            hw.commands.test_current = i1;
            let inputs = BenchInputs {
                test_command: i1,
                test_enable: true,
                load_enable: true,
                ..BenchInputs::default()
            };
            assert_eq!(hw.do_step(t, h).unwrap(), StepOutcome::Completed);
            plant.step(&inputs, h);
            let (a, b) = (&hw.outputs, plant.outputs());
            assert_eq!(a.actuation_encoder_counts, b.actuation_encoder_counts);
            assert!(
                (a.actuation_angle - b.actuation_angle).abs() < cal.resolution(Side::Actuation)
            );
            assert!((a.test_motor_current - b.test_motor_current).abs() < 1e-12);
        }
        assert!(hw.outputs.actuation_encoder_counts > 1000.0);
    }

    #[test]
    fn interlocks_trip_latch_and_never_drive_again() {
        // Test motor torque (the shaft torque): the load side held by friction, 5 A x 0.037 x
        // 160 = 29.6 N m winds the spring past 20 N m.
        let mut m = started(|m| m.params.load_static_friction = 100.0);
        m.commands.test_current = 5.0;
        let (at, reason) = run(&mut m, 100, 1e-3).unwrap();
        assert_eq!(m.outputs.trip_code, 2, "{reason}");
        assert!(at <= 0.2, "{at}");
        // Latched: the next step reports the same trip and does nothing.
        assert_eq!(
            m.do_step(at, 1e-3).unwrap(),
            StepOutcome::Terminated { at, reason }
        );
        // Emergency-stop input: trips at the start of the step.
        let mut m = started(|_| {});
        m.commands.emergency_stop = true;
        assert_eq!(run(&mut m, 10, 1e-3), Some((0.0, "emergency stop")));
        assert_eq!(m.outputs.trip_code, 7);
        // Spring deflection: the load side is pushed against a blocked actuation side.
        let mut m2 = started(|m| m.params.motor_torque_limit = 1e3);
        m2.commands.clutch_engage = true;
        m2.commands.load_current = 4.5;
        run(&mut m2, 2000, 1e-3).unwrap();
        assert_eq!(m2.outputs.trip_code, 1);
        // A sensor window that excludes the reading: sensor fault.
        let mut m3 = started(|m| {
            m.plausibility.analog[AnalogChannel::TestCurrentSense.index()] = (2.0, 2.7)
        });
        m3.commands.test_current = 3.0;
        run(&mut m3, 100, 1e-3).unwrap();
        assert_eq!(m3.outputs.trip_code, trip::SENSOR);
    }

    #[test]
    fn realtime_priority_and_lock_memory_are_honoured_or_refused_with_a_warning() {
        use crate::hardware::realtime::current_policy;
        // On a thread of its own: the test harness's threads keep their scheduling.
        std::thread::spawn(|| {
            let before = current_policy();
            let mut m = started(|m| {
                m.pacing = 1;
                m.realtime_priority = 7;
                m.lock_memory = true;
            });
            assert_eq!(run(&mut m, 3, 1e-3), None);
            let warnings = m.take_warnings().join("\n");
            let rt = m.runtime.0.as_ref().unwrap();
            match &rt.realtime {
                Some(g) => {
                    assert_eq!(g.priority, 7);
                    assert_eq!(current_policy(), Some((1, 7)));
                }
                None => assert!(warnings.contains("realtimePriority 7"), "{warnings}"),
            }
            let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
            let locked = status
                .lines()
                .find(|l| l.starts_with("VmLck:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok());
            assert!(
                locked.is_some_and(|kb| kb > 0) || warnings.contains("lockMemory"),
                "{locked:?} {warnings}"
            );
            // The thread gets its scheduling back with the instance.
            drop(m);
            assert_eq!(current_policy(), before);
            // Without pacing nothing is asked for.
            let mut m = started(|m| m.realtime_priority = 7);
            assert_eq!(run(&mut m, 3, 1e-3), None);
            assert_eq!(current_policy(), before);
            assert!(m.take_warnings().is_empty());
        })
        .join()
        .unwrap();
    }

    #[test]
    fn consistency_checks_trip_on_a_stuck_reading_and_stay_quiet_on_a_healthy_bench() {
        // A healthy SEA bench winding its spring against a held load side: no trip before the
        // shaft-torque interlock (code 2), the checks quiet all along.
        let mut m = started(|m| {
            m.configuration = 1;
            m.params.load_static_friction = 100.0;
        });
        m.commands.test_current = 4.0;
        let (_, reason) = run(&mut m, 2000, 1e-3).unwrap();
        assert_eq!(m.outputs.trip_code, 2, "{reason}");
        // The same with a tolerance no healthy reading meets: code 12 after exactly the
        // persistence (the transducer is checked before the load cell).
        let mut m = started(|m| {
            m.configuration = 1;
            m.params.load_static_friction = 100.0;
            m.consistency_tolerance = 0.0;
            m.consistency_relative = 0.0;
            m.consistency_persistence = 4;
        });
        m.commands.test_current = 4.0;
        let (at, reason) = run(&mut m, 2000, 1e-3).unwrap();
        assert_eq!(
            m.outputs.trip_code,
            trip::TRANSDUCER_INCONSISTENT,
            "{reason}"
        );
        assert!(at < 0.1, "{at}");
        // DA: no spring check; the load cell pair is the one that trips.
        let mut m = started(|m| {
            m.configuration = 0;
            m.consistency_tolerance = 0.0;
            m.consistency_relative = 0.0;
            m.consistency_persistence = 3;
        });
        m.commands.test_current = 1.0;
        run(&mut m, 100, 1e-3).unwrap();
        assert_eq!(m.outputs.trip_code, trip::LOAD_CELL_INCONSISTENT);
        // Persistence 0: off.
        let mut m = started(|m| {
            m.consistency_tolerance = 0.0;
            m.consistency_relative = 0.0;
            m.consistency_persistence = 0;
        });
        m.commands.test_current = 1.0;
        assert_eq!(run(&mut m, 100, 1e-3), None);
    }

    /// The simulated bench behind a wall-clock server: its timestamps are the sample times,
    /// and the sample of step `late` is taken `delay` s late (as after an overrun).
    struct LateBench {
        bench: SimulatedBench,
        reads: usize,
        late: usize,
        delay: f64,
        slip: f64,
        /// Taken off the slip at the sample after the late one: that sample comes less than a
        /// period after the late one (the loop catching up).
        catch_up: f64,
    }

    impl BenchIo for LateBench {
        fn write(&mut self, t: f64, command: &Command) -> Result<u32, IoError> {
            self.bench.write(t + self.slip, command)
        }
        fn read(&mut self, t: f64) -> Result<Sample, IoError> {
            self.reads += 1;
            if self.reads == self.late {
                self.slip += self.delay;
            }
            if self.reads == self.late + 1 {
                self.slip -= self.catch_up;
            }
            self.bench.read(t + self.slip)
        }
        fn enter_safe_state(
            &mut self,
            t: f64,
            reason: u8,
            timeout: Duration,
        ) -> Result<Sample, IoError> {
            self.bench.enter_safe_state(t + self.slip, reason, timeout)
        }
        fn timestamps_are_wall_time(&self) -> bool {
            true
        }
    }

    #[test]
    fn a_late_sample_does_not_read_as_a_speed_jump() {
        let mut m = started(|_| {});
        let p = m.runtime.0.as_ref().unwrap().p.clone();
        let mut sim = p.clone();
        sim.spring_deflection_limit = 10.0;
        sim.motor_torque_limit = 1e4;
        let rt = m.runtime.0.as_mut().unwrap();
        rt.io = Box::new(LateBench {
            bench: SimulatedBench::new(sim).unwrap(),
            reads: 0,
            late: 400,
            delay: 2e-3,
            slip: 0.0,
            catch_up: 0.0,
        });
        rt.server_us = 0;
        // A steady current: the shaft turns at a nearly constant speed (about 50 counts per
        // period) by step 300.
        m.commands.test_current = 3.0;
        let h = 1e-3;
        let mut speeds = Vec::new();
        for k in 0..402 {
            assert_eq!(m.do_step(k as f64 * h, h).unwrap(), StepOutcome::Completed);
            speeds.push(m.outputs.actuation_velocity);
        }
        let (before, late) = (speeds[398], speeds[399]);
        assert!(before > 0.1, "{before}");
        // The late sample covers 3 ms of motion; its speed is still the shaft's.
        assert!((late - before).abs() < 0.1 * before, "{before} {late}");
    }

    #[test]
    fn a_sample_right_after_a_late_one_does_not_read_as_a_speed_spike() {
        let mut m = started(|_| {});
        let p = m.runtime.0.as_ref().unwrap().p.clone();
        let mut sim = p.clone();
        sim.spring_deflection_limit = 10.0;
        sim.motor_torque_limit = 1e4;
        let h = 1e-3;
        let rt = m.runtime.0.as_mut().unwrap();
        rt.io = Box::new(LateBench {
            bench: SimulatedBench::new(sim).unwrap(),
            reads: 0,
            late: 400,
            delay: 2e-3,
            slip: 0.0,
            // The next sample 0.1 ms after the late one.
            catch_up: 0.9e-3,
        });
        rt.server_us = 0;
        m.commands.test_current = 3.0;
        let mut speeds = Vec::new();
        for k in 0..402 {
            assert_eq!(m.do_step(k as f64 * h, h).unwrap(), StepOutcome::Completed);
            speeds.push(m.outputs.actuation_velocity);
        }
        let (before, caught_up) = (speeds[398], speeds[400]);
        assert!(before > 0.1, "{before}");
        // About 5 counts in 0.1 ms: a one-count error alone would be 20 %.
        assert!(
            (caught_up - before).abs() < 0.05 * before,
            "{before} {caught_up}"
        );
    }

    #[test]
    fn udp_backend_needs_pacing_and_a_state_after_start_is_not_restorable() {
        let mut m = crate::fmi2::instance::fresh_model::<BenchHardwareModel>();
        m.backend = 1;
        assert!(m.initialize(0.0).unwrap_err().message.contains("pacing"));
        let m = started(|_| {});
        let mut w = StateWriter::default();
        m.save_internal(&mut w);
        let mut fresh = BenchHardwareModel::default();
        assert!(
            fresh
                .load_internal(&mut StateReader::new(&w.bytes))
                .is_err()
        );
    }
}
