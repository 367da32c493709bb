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
//!   the time between the two samples, as the velocities: a late sample ends a longer
//!   interval, the samples that catch up shorter ones, so that the energy per cycle counts
//!   the time the bench ran), `E_k`, `E_p` and their rates, friction torques and loss powers from each
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
//! frames in `rejectedFrames` and late replies in `staleReplies`. `benchSampleTime` is the
//! bench's own clock when it took the last sample (the server's, to the microsecond): a row
//! logged at the schedule's time `t` holds readings taken at that bench time, which differs
//! from `t` by more than jitter only when the loop ran late (a stall, then steps back to back
//! to catch up). `kneebench identify` resamples a log that has it onto the bench's clock.
//!
//! ## FMU state
//! None: the model description declares `canGetAndSetFMUstate="false"` and
//! `canSerializeFMUstate="false"`, and `fmi2GetFMUstate`, `fmi2SetFMUstate`,
//! `fmi2FreeFMUstate` and the serialization functions answer fmi2Error with a log line naming
//! the flag. The physical bench cannot be rewound: a state saved after initialization could
//! never be restored, and one saved before it holds nothing that setting the parameters again
//! does not.

mod measure;
mod session;
#[cfg(test)]
mod tests;
mod variables;

use crate::release::Lazy;

use super::bench::{BenchOutputs, BenchParameters, SignalGroup};
use super::bench_plant::{BenchCommands, BenchSignals};
use crate::hardware::calibration::Plausibility;
use crate::model::{
    EnumerationType, Model, ModelError, StateError, StateReader, StateWriter, StepOutcome, Variable,
};
use crate::registry::ReferenceInputs;
use session::Slot;
use variables::{ENUMERATIONS, VARIABLES};

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
    /// The bench's clock at the last sample \[s\] (`benchSampleTime`).
    bench_sample_time: f64,
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
    /// The physical bench cannot be rewound (module docs, "FMU state").
    const CAN_GET_AND_SET_FMU_STATE: bool = false;
    /// No states to serialize.
    const CAN_SERIALIZE_FMU_STATE: bool = false;

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

    /// Unreachable through the C API (the FMU-state functions are refused, module docs "FMU
    /// state"); kept as a second line for a state that reaches the instance another way (the
    /// glue's unit tests restore states directly).
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
        static HTML: Lazy<String> =
            unsafe { Lazy::new(|| crate::model::module_doc_html(include_str!("mod.rs"))) };
        &HTML
    }
}
