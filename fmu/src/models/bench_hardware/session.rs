//! The bench hardware FMU's I/O session: opening the backend, the tare at initialization,
//! one control period (command, pacing, sample, checks) and the trip into the safe state (the
//! `bench_hardware` module docs, "One control period" and "Trips, the safe state and the FMI
//! status").

use std::time::Duration;

use super::measure::{interlock, measure, raw_into};
use super::{Backend, BenchHardwareModel, trip};
use crate::hardware::calibration::{Calibration, Plausibility, Side, Tare, Unwrapper};
use crate::hardware::consistency::{ConsistencyCheck, Inconsistency};
use crate::hardware::io::{BenchIo, IoError, SimulatedBench, UdpBench, UdpSetup, kind_of};
use crate::hardware::pacing::{Pacer, PacingMode};
use crate::hardware::protocol::{BenchSetup, Command, Key, reason, status};
use crate::hardware::realtime::{RealtimeThread, lock_memory, now_ns};
use crate::model::{ModelError, StepOutcome};
use crate::models::bench::{BenchOutputs, BenchParameters, Configuration, DriverMode};

/// How long a sample is awaited during initialization [s].
const INIT_REPLY_TIMEOUT: f64 = 0.2;

/// What exists only between initialization and the end of the instance.
pub(super) struct Runtime {
    pub(super) io: Box<dyn BenchIo>,
    pub(super) p: BenchParameters,
    pub(super) cal: Calibration,
    pub(super) limits: Plausibility,
    pub(super) consistency: ConsistencyCheck,
    pub(super) pacer: Pacer,
    pub(super) encoders: [Unwrapper; 2],
    pub(super) counts: [i64; 2],
    /// Encoder movement [counts] over the last period and the one before.
    pub(super) delta: [[i64; 2]; 2],
    /// Time [s] between the samples of those movements (the last period's, the one before).
    pub(super) dt: [f64; 2],
    /// The server's timestamp of the last sample [us] (Udp backend).
    pub(super) server_us: u64,
    pub(super) trip: Option<(i32, f64)>,
    /// The bench's time since initialization: the sum of the step sizes (so the simulated
    /// backend advances by exactly `h`, whatever rounding the importer's times carry).
    pub(super) bench_time: f64,
    pub(super) safe_timeout: Duration,
    pub(super) warnings: Vec<String>,
    /// `SCHED_FIFO` of the stepping thread, asked for once at the first paced step; restored
    /// when the runtime ends (or at a trip).
    pub(super) realtime: Option<RealtimeThread>,
    /// The first paced step's checks are done.
    pub(super) first_step_checked: bool,
    /// `SCHED_FIFO` was asked for.
    pub(super) realtime_tried: bool,
    /// Reply time of the last sample and the largest [s].
    pub(super) reply_time: (f64, f64),
}

/// The runtime holder: a clone of the model (a description copy) has no bench connection.
#[derive(Default)]
pub(super) struct Slot(pub(super) Option<Box<Runtime>>);

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

fn saturate(x: u64) -> i32 {
    i32::try_from(x).unwrap_or(i32::MAX)
}

impl BenchHardwareModel {
    /// The bench parameters with the enumerations applied.
    fn parameters(&self) -> Result<BenchParameters, ModelError> {
        let p = self
            .params
            .with_enumerations(
                self.configuration,
                self.friction_model,
                self.test_driver_mode,
                self.load_driver_mode,
            )
            .map_err(ModelError::new)?;
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

    pub(super) fn start(&mut self) -> Result<(), ModelError> {
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
        self.sync_statistics();
        Ok(())
    }

    fn trip(&mut self, code: i32, at: f64) -> Result<StepOutcome, ModelError> {
        let start = self.start_time;
        self.outputs.trip_code = code;
        let Some(rt) = self.runtime.0.as_mut() else {
            return Err(ModelError::new("not initialized"));
        };
        rt.trip = Some((code, at));
        // How far the master had fallen behind its schedule before the trip: a loop that ran
        // late (a loaded host) holds its commands longer than a period, which an interlock may
        // answer; the log says so next to the trip (only the first overruns are logged singly).
        let pacing = rt.pacer.stats;
        if pacing.overruns > 0 {
            rt.warnings.push(format!(
                "pacing before trip {code}: {} overruns in {} steps, largest lateness {:.0} us",
                pacing.overruns,
                pacing.steps,
                pacing.max_lateness * 1e6
            ));
        }
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
            self.bench_sample_time = rt.server_us as f64 * 1e-6;
        }
    }

    pub(super) fn step(&mut self, t: f64, h: f64) -> Result<StepOutcome, ModelError> {
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
