//! The bench emulator: a server of the UDP bench protocol (`docs/bench-protocol.md`) with the
//! `BenchPlant` FMU running in real time behind it, so the hardware path (the `BenchHardware`
//! FMU's UDP backend, or any other client) is tested without hardware.
//!
//! The plant is loaded like any FMU ([`Fmu::load`]); its raw sensor outputs (encoder counts,
//! volts) are what the samples carry. The plant's time is the wall time since the session
//! began: on every frame the emulator first advances the plant to *now* with the command held
//! so far, then acts on the frame. A session begins with the first valid frame of a new session
//! identifier when no session is active (none yet, the previous one ended, or it has been
//! silent for the heartbeat timeout); each session gets a fresh plant at rest, prepared in
//! advance so the first frames are answered at once.
//!
//! Faults are injected by [`FaultInjection`] frames (from any address: an emulator-only frame
//! type) or [`EmulatorHandle::inject`]: dropped or delayed replies, a stuck or forced channel,
//! the emergency-stop button, silence (the link lost).

use std::collections::VecDeque;
use std::net::{SocketAddr, UdpSocket};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::bench_protocol::{
    ANALOG_CHANNELS, Command, Counters, FaultInjection, Frame, Payload, Receiver, Sample, Sender,
    SetValueKind, reason, status,
};
use crate::{Fmu, FmuError, Instance, InstanceOptions, LoadError, LoadOptions, Status};

/// The real-time support of the `fmu` crate's pacing (`SCHED_FIFO`), shared by including its
/// file as the protocol codec is.
#[path = "../../fmu/src/hardware/realtime.rs"]
#[allow(dead_code)]
mod realtime;

/// Value references of the bench signal interface used by the emulator.
mod vr {
    pub const TEST_VOLTAGE: u32 = 200;
    pub const TEST_CURRENT: u32 = 201;
    pub const LOAD_VOLTAGE: u32 = 202;
    pub const LOAD_CURRENT: u32 = 203;
    pub const TEST_ENABLE: u32 = 204;
    pub const LOAD_ENABLE: u32 = 205;
    pub const CLUTCH: u32 = 206;
    pub const EMERGENCY_STOP: u32 = 207;
    /// Encoder counts (test, load).
    pub const COUNTS: [u32; 2] = [320, 321];
    /// Analog channels in wire order: load cell, transducer, test current sense, load current
    /// sense, test supply sense, load supply sense.
    pub const ANALOG: [u32; 6] = [322, 324, 328, 329, 326, 327];
    pub const TRIP_CODE: u32 = 373;
    pub const TEST_DRIVER_MODE: u32 = 3;
    pub const LOAD_DRIVER_MODE: u32 = 4;
}

/// How to run an emulator.
#[derive(Debug, Clone)]
pub struct EmulatorConfig {
    /// Address to serve on, e.g. `127.0.0.1:47000` (port 0: an ephemeral port).
    pub bind: String,
    /// The `BenchPlant` FMU.
    pub fmu: PathBuf,
    /// Plant parameters to set (name, value as text).
    pub parameters: Vec<(String, String)>,
    /// Silence after which the server enters the safe state by itself.
    pub heartbeat_timeout: Duration,
    /// Faults in force from the start.
    pub faults: Vec<FaultInjection>,
    /// `SCHED_FIFO` priority (1-99) of the serving thread, so that the emulated bench answers
    /// like a real-time controller on a loaded machine; `None` leaves the scheduling alone. A
    /// refusal is reported on stderr and in [`EmulatorStats::realtime_priority`] (0), and the
    /// emulator serves anyway.
    pub realtime_priority: Option<i32>,
}

impl EmulatorConfig {
    /// Defaults: the protocol's heartbeat timeout, no parameters, no faults.
    pub fn new(bind: impl Into<String>, fmu: impl Into<PathBuf>) -> Self {
        Self {
            bind: bind.into(),
            fmu: fmu.into(),
            parameters: Vec::new(),
            heartbeat_timeout: crate::bench_protocol::HEARTBEAT_TIMEOUT,
            faults: Vec::new(),
            realtime_priority: None,
        }
    }
}

/// Emulator errors.
#[derive(Debug, thiserror::Error)]
pub enum EmulatorError {
    /// The plant FMU cannot be loaded.
    #[error("plant FMU: {0}")]
    Load(#[from] LoadError),
    /// A plant call failed.
    #[error("plant: {0}")]
    Plant(#[from] FmuError),
    /// A socket operation failed.
    #[error("socket: {0}")]
    Socket(#[from] std::io::Error),
    /// A bad configuration.
    #[error("{0}")]
    Config(String),
}

/// What the emulator did, for logs and tests.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EmulatorStats {
    /// Sessions begun.
    pub sessions: u64,
    /// The current (or last) session identifier.
    pub session: u32,
    /// Commands applied in the current session.
    pub commands_applied: u64,
    /// Commands refused (set-value kind differing from the drivers' mode).
    pub commands_refused: u64,
    /// Drive commands (anything on or nonzero) received in the safe state, never applied.
    pub drive_commands_in_safe_state: u64,
    /// Drive commands received after the client's own safe-state request (a correct client
    /// sends none).
    pub drive_commands_after_safe_request: u64,
    /// Safe-state requests received.
    pub safe_state_requests: u64,
    /// Safe-state acknowledgements sent.
    pub safe_state_acks: u64,
    /// Samples sent.
    pub samples_sent: u64,
    /// Replies dropped or held back by injected faults.
    pub replies_dropped: u64,
    /// The reason of the safe state of the current session, if in it.
    pub safe_reason: Option<u8>,
    /// Plant time \[s\] at which the safe state was entered.
    pub safe_since: Option<f64>,
    /// The plant's own trip code, if it tripped.
    pub plant_trip: Option<i32>,
    /// Plant time \[s\] of the current session.
    pub plant_time: f64,
    /// Frames rejected, by cause (all sessions).
    pub rejected: Counters,
    /// Fault-injection frames applied.
    pub faults_injected: u64,
    /// The `SCHED_FIFO` priority the serving thread runs at (0: normal scheduling).
    pub realtime_priority: i32,
}

/// A running emulator thread.
#[derive(Debug)]
pub struct EmulatorHandle {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    stats: Arc<Mutex<EmulatorStats>>,
    thread: Option<JoinHandle<Result<(), EmulatorError>>>,
}

impl EmulatorHandle {
    /// The address it serves on.
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// A snapshot of the statistics.
    pub fn stats(&self) -> EmulatorStats {
        self.stats.lock().map(|s| s.clone()).unwrap_or_default()
    }

    /// Sends a fault-injection frame to the emulator (as any client could).
    pub fn inject(&self, fault: FaultInjection) -> std::io::Result<()> {
        let socket = UdpSocket::bind(("127.0.0.1", 0))?;
        let (_, bytes) = Sender::new(0xFA17).frame(Payload::FaultInject(fault));
        // Count before sending: the emulator may apply the fault before this thread looks.
        let before = self.stats().faults_injected;
        socket.send_to(&bytes, self.addr)?;
        // Wait until the emulator has applied it.
        let start = Instant::now();
        while self.stats().faults_injected == before && start.elapsed() < Duration::from_secs(1) {
            std::thread::sleep(Duration::from_micros(100));
        }
        Ok(())
    }

    /// Stops the emulator and returns its final statistics.
    pub fn stop(mut self) -> Result<EmulatorStats, EmulatorError> {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            t.join()
                .map_err(|_| EmulatorError::Config("emulator thread panicked".into()))??;
        }
        Ok(self.stats())
    }
}

impl Drop for EmulatorHandle {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Starts an emulator on a thread; returns once it is bound and its first plant is ready.
pub fn spawn(config: EmulatorConfig) -> Result<EmulatorHandle, EmulatorError> {
    let server = Server::new(config)?;
    let addr = server.socket.local_addr()?;
    let stop = Arc::new(AtomicBool::new(false));
    let stats = Arc::new(Mutex::new(EmulatorStats::default()));
    let (s2, st2) = (stop.clone(), stats.clone());
    let thread = std::thread::Builder::new()
        .name("kneebench-emulator".into())
        .spawn(move || server.serve(&s2, &st2))?;
    Ok(EmulatorHandle {
        addr,
        stop,
        stats,
        thread: Some(thread),
    })
}

/// Serves until `stop` is set (the CLI's loop).
pub fn run(
    config: EmulatorConfig,
    stop: &AtomicBool,
    stats: &Mutex<EmulatorStats>,
    on_bound: impl FnOnce(SocketAddr),
) -> Result<(), EmulatorError> {
    let server = Server::new(config)?;
    on_bound(server.socket.local_addr()?);
    server.serve(stop, stats)
}

struct Session {
    id: u32,
    peer: SocketAddr,
    rx: Receiver,
    tx: Sender,
    plant: Instance,
    plant_time: f64,
    origin: Instant,
    last_valid: Instant,
    held: Command,
    last_command: u32,
    safe: Option<u8>,
    safe_requested: bool,
    server_trip: bool,
    ended: bool,
}

struct Server {
    socket: UdpSocket,
    fmu: Fmu,
    config: EmulatorConfig,
    kinds: [SetValueKind; 2],
    ready: Option<Instance>,
    session: Option<Session>,
    stats: EmulatorStats,
    rejected: Receiver,
    drop_replies: u32,
    delay: Option<(u32, Duration)>,
    delayed: VecDeque<(Instant, SocketAddr, Vec<u8>)>,
    stuck: [bool; 8],
    stuck_values: [Option<f64>; 8],
    forced: [Option<f64>; ANALOG_CHANNELS],
    emergency_stop: bool,
    silent: bool,
}

impl Server {
    fn new(config: EmulatorConfig) -> Result<Self, EmulatorError> {
        let fmu = Fmu::load(&config.fmu, &LoadOptions::default())?;
        let socket = UdpSocket::bind(&config.bind)?;
        socket.set_read_timeout(Some(Duration::from_micros(500)))?;
        let mut server = Self {
            socket,
            fmu,
            kinds: [SetValueKind::Current; 2],
            ready: None,
            session: None,
            stats: EmulatorStats::default(),
            rejected: Receiver::new(0),
            drop_replies: 0,
            delay: None,
            delayed: VecDeque::new(),
            stuck: [false; 8],
            stuck_values: [None; 8],
            forced: [None; ANALOG_CHANNELS],
            emergency_stop: false,
            silent: false,
            config,
        };
        let plant = server.prepare()?;
        let mut modes = [0; 2];
        let mut p = plant;
        p.get_integer(&[vr::TEST_DRIVER_MODE, vr::LOAD_DRIVER_MODE], &mut modes)?;
        let kind = |m: i32| {
            if m == 0 {
                SetValueKind::Voltage
            } else {
                SetValueKind::Current
            }
        };
        server.kinds = [kind(modes[0]), kind(modes[1])];
        server.ready = Some(p);
        for fault in server.config.faults.clone() {
            server.apply_fault(fault);
        }
        Ok(server)
    }

    /// A plant instance at rest, initialized at time 0.
    fn prepare(&mut self) -> Result<Instance, EmulatorError> {
        let mut plant = self
            .fmu
            .instantiate("emulated-bench", &InstanceOptions::default())?;
        for (name, value) in &self.config.parameters {
            let v = self.fmu.variable(name).ok_or_else(|| {
                EmulatorError::Config(format!("the plant has no parameter `{name}`"))
            })?;
            let vr = v.value_reference;
            let bad = |e: &dyn std::fmt::Display| {
                EmulatorError::Config(format!("parameter `{name}` = `{value}`: {e}"))
            };
            match crate::master::VarType::of(v) {
                crate::master::VarType::Real => {
                    let x: f64 = value.parse().map_err(|e| bad(&e))?;
                    plant.set_real(&[vr], &[x])?;
                }
                crate::master::VarType::Boolean => {
                    let x = matches!(value.as_str(), "true" | "1");
                    plant.set_boolean(&[vr], &[x])?;
                }
                crate::master::VarType::Integer => {
                    let x: i32 = value.parse().map_err(|e| bad(&e))?;
                    plant.set_integer(&[vr], &[x])?;
                }
                crate::master::VarType::String => {
                    plant.set_string(&[vr], &[value.as_str()])?;
                }
            }
        }
        plant.setup_experiment(None, 0.0, None)?;
        plant.enter_initialization_mode()?;
        plant.set_boolean(&[vr::TEST_ENABLE, vr::LOAD_ENABLE], &[false, false])?;
        plant.exit_initialization_mode()?;
        Ok(plant)
    }

    fn serve(
        mut self,
        stop: &AtomicBool,
        stats: &Mutex<EmulatorStats>,
    ) -> Result<(), EmulatorError> {
        let _realtime = match self.config.realtime_priority {
            Some(p) => match realtime::RealtimeThread::enter(p) {
                Ok(g) => {
                    self.stats.realtime_priority = g.priority;
                    Some(g)
                }
                Err(e) => {
                    eprintln!("kneebench emulate: real-time priority {p}: {e}; serving anyway");
                    None
                }
            },
            None => None,
        };
        let mut buf = [0u8; 2048];
        while !stop.load(Ordering::Relaxed) {
            let now = Instant::now();
            while let Some((due, _, _)) = self.delayed.front() {
                if *due > now {
                    break;
                }
                if let Some((_, to, bytes)) = self.delayed.pop_front() {
                    let _ = self.socket.send_to(&bytes, to);
                }
            }
            self.watchdog(now)?;
            if self.ready.is_none()
                && self
                    .session
                    .as_ref()
                    .is_none_or(|s| s.ended || s.safe.is_some())
            {
                self.ready = Some(self.prepare()?);
            }
            match self.socket.recv_from(&mut buf) {
                Ok((n, from)) => self.handle(&buf[..n], from)?,
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) => {}
                Err(e) => return Err(e.into()),
            }
            if let Ok(mut s) = stats.lock() {
                *s = self.stats.clone();
                s.rejected = self.rejected.counters;
                if let Some(session) = &self.session {
                    let c = session.rx.counters;
                    let r = &mut s.rejected;
                    r.replayed += c.replayed;
                    r.out_of_order += c.out_of_order;
                    r.wrong_session += c.wrong_session;
                    r.accepted += c.accepted;
                    r.gaps += c.gaps;
                }
            }
        }
        Ok(())
    }

    fn watchdog(&mut self, now: Instant) -> Result<(), EmulatorError> {
        let timeout = self.config.heartbeat_timeout;
        let Some(s) = self.session.as_mut() else {
            return Ok(());
        };
        if s.safe.is_none() && !s.ended && now.duration_since(s.last_valid) > timeout {
            s.server_trip = true;
            self.enter_safe(reason::HEARTBEAT_TIMEOUT)?;
        }
        Ok(())
    }

    fn advance(&mut self) -> Result<(), EmulatorError> {
        let Some(s) = self.session.as_mut() else {
            return Ok(());
        };
        if self.stats.plant_trip.is_some() {
            return Ok(());
        }
        let target = s.origin.elapsed().as_secs_f64();
        let h = target - s.plant_time;
        if h < 1e-6 {
            return Ok(());
        }
        let c = s.held;
        let (tv, tc) = match c.test_kind {
            SetValueKind::Voltage => (c.test_set_value, 0.0),
            SetValueKind::Current => (0.0, c.test_set_value),
        };
        let (lv, lc) = match c.load_kind {
            SetValueKind::Voltage => (c.load_set_value, 0.0),
            SetValueKind::Current => (0.0, c.load_set_value),
        };
        s.plant.set_real(
            &[
                vr::TEST_VOLTAGE,
                vr::TEST_CURRENT,
                vr::LOAD_VOLTAGE,
                vr::LOAD_CURRENT,
            ],
            &[tv, tc, lv, lc],
        )?;
        s.plant.set_boolean(
            &[
                vr::TEST_ENABLE,
                vr::LOAD_ENABLE,
                vr::CLUTCH,
                vr::EMERGENCY_STOP,
            ],
            &[c.test_enable, c.load_enable, c.clutch, self.emergency_stop],
        )?;
        let status = s.plant.do_step(s.plant_time, h)?;
        if status == Status::Discard && s.plant.terminated() {
            let mut code = [0];
            s.plant.get_integer(&[vr::TRIP_CODE], &mut code)?;
            s.plant_time = s.plant.last_successful_time().unwrap_or(s.plant_time);
            self.stats.plant_trip = Some(code[0]);
            s.server_trip = true;
            let why = if code[0] == 7 {
                reason::EMERGENCY_STOP
            } else {
                reason::BENCH_PROTECTION
            };
            self.enter_safe(why)?;
        } else {
            s.plant_time += h;
        }
        if let Some(s) = self.session.as_ref() {
            self.stats.plant_time = s.plant_time;
        }
        Ok(())
    }

    fn enter_safe(&mut self, why: u8) -> Result<(), EmulatorError> {
        let Some(s) = self.session.as_mut() else {
            return Ok(());
        };
        s.held = Command::safe(s.held.test_kind, s.held.load_kind);
        if s.safe.is_none() {
            s.safe = Some(why);
            self.stats.safe_reason = Some(why);
            self.stats.safe_since = Some(s.plant_time);
        }
        if self.stats.plant_trip.is_none() {
            s.plant.set_real(
                &[
                    vr::TEST_VOLTAGE,
                    vr::TEST_CURRENT,
                    vr::LOAD_VOLTAGE,
                    vr::LOAD_CURRENT,
                ],
                &[0.0; 4],
            )?;
            s.plant
                .set_boolean(&[vr::TEST_ENABLE, vr::LOAD_ENABLE, vr::CLUTCH], &[false; 3])?;
        }
        Ok(())
    }

    fn sample(&mut self, request: u32) -> Result<Sample, EmulatorError> {
        let Some(s) = self.session.as_mut() else {
            return Err(EmulatorError::Config("no session".into()));
        };
        let mut counts = [0.0; 2];
        s.plant.get_real(&vr::COUNTS, &mut counts)?;
        let mut analog = [0.0; ANALOG_CHANNELS];
        s.plant.get_real(&vr::ANALOG, &mut analog)?;
        let mut values = [counts[0], counts[1]];
        for (k, a) in analog.iter_mut().enumerate() {
            if self.stuck[k] {
                *a = *self.stuck_values[k].get_or_insert(*a);
            }
            if let Some(v) = self.forced[k] {
                *a = v;
            }
        }
        for (k, v) in values.iter_mut().enumerate() {
            if self.stuck[6 + k] {
                *v = *self.stuck_values[6 + k].get_or_insert(*v);
            }
        }
        let c = &s.held;
        let mut bits = 0;
        for (on, bit) in [
            (c.test_enable, status::TEST_ENABLED),
            (c.load_enable, status::LOAD_ENABLED),
            (c.clutch, status::CLUTCH),
            (s.safe.is_some(), status::SAFE_STATE),
            (self.emergency_stop, status::EMERGENCY_STOP),
            (s.server_trip, status::SERVER_TRIP),
        ] {
            if on {
                bits |= bit;
            }
        }
        Ok(Sample {
            request_sequence: request,
            last_command_sequence: s.last_command,
            server_time_us: (s.plant_time * 1e6).round() as u64,
            status: bits,
            safe_reason: s.safe.unwrap_or(reason::NONE),
            test_counts: values[0] as i64 as i32,
            load_counts: values[1] as i64 as i32,
            analog,
        })
    }

    fn reply(&mut self, payload: Payload) {
        let Some(s) = self.session.as_mut() else {
            return;
        };
        if self.silent {
            self.stats.replies_dropped += 1;
            return;
        }
        if self.drop_replies > 0 {
            self.drop_replies -= 1;
            self.stats.replies_dropped += 1;
            return;
        }
        let (_, bytes) = s.tx.frame(payload);
        let peer = s.peer;
        if let Some((n, delay)) = self.delay {
            self.delay = (n > 1).then_some((n - 1, delay));
            self.stats.replies_dropped += 1;
            self.delayed
                .push_back((Instant::now() + delay, peer, bytes));
            return;
        }
        let _ = self.socket.send_to(&bytes, peer);
    }

    fn apply_fault(&mut self, fault: FaultInjection) {
        self.stats.faults_injected += 1;
        match fault {
            FaultInjection::Clear => {
                self.drop_replies = 0;
                self.delay = None;
                self.stuck = [false; 8];
                self.stuck_values = [None; 8];
                self.forced = [None; ANALOG_CHANNELS];
                self.silent = false;
            }
            FaultInjection::DropReplies { count } => self.drop_replies = count,
            FaultInjection::DelayReplies { count, delay_s } => {
                self.delay = (count > 0).then(|| (count, Duration::from_secs_f64(delay_s)));
            }
            FaultInjection::Stuck { channel } => {
                if let Some(s) = self.stuck.get_mut(channel as usize) {
                    *s = true;
                }
            }
            FaultInjection::Force { channel, volts } => {
                if let Some(f) = self.forced.get_mut(channel as usize) {
                    *f = Some(volts);
                }
            }
            FaultInjection::EmergencyStop => {
                self.emergency_stop = true;
                if let Some(s) = self.session.as_mut() {
                    s.server_trip = true;
                }
                let _ = self.enter_safe(reason::EMERGENCY_STOP);
            }
            FaultInjection::Silence => self.silent = true,
        }
    }

    fn begin_session(&mut self, id: u32, peer: SocketAddr) -> Result<(), EmulatorError> {
        let plant = match self.ready.take() {
            Some(p) => p,
            None => self.prepare()?,
        };
        let now = Instant::now();
        self.session = Some(Session {
            id,
            peer,
            rx: Receiver::new(id),
            tx: Sender::new(id),
            plant,
            plant_time: 0.0,
            origin: now,
            last_valid: now,
            held: Command::safe(self.kinds[0], self.kinds[1]),
            last_command: 0,
            safe: None,
            safe_requested: false,
            server_trip: false,
            ended: false,
        });
        self.stats.sessions += 1;
        self.stats.session = id;
        self.stats.commands_applied = 0;
        self.stats.drive_commands_in_safe_state = 0;
        self.stats.drive_commands_after_safe_request = 0;
        self.stats.safe_reason = None;
        self.stats.safe_since = None;
        self.stats.plant_trip = None;
        self.stats.plant_time = 0.0;
        if self.emergency_stop {
            if let Some(s) = self.session.as_mut() {
                s.server_trip = true;
            }
            self.enter_safe(reason::EMERGENCY_STOP)?;
        }
        Ok(())
    }

    fn handle(&mut self, bytes: &[u8], from: SocketAddr) -> Result<(), EmulatorError> {
        let frame = match Frame::decode(bytes) {
            Ok(f) => f,
            Err(_) => {
                // Counted by the same filter the sessions use.
                let _ = self.rejected.accept(bytes);
                return Ok(());
            }
        };
        if let Payload::FaultInject(fault) = frame.payload {
            self.apply_fault(fault);
            return Ok(());
        }
        if self.silent {
            return Ok(());
        }
        let timeout = self.config.heartbeat_timeout;
        let new_session = match &self.session {
            None => true,
            Some(s) => {
                s.id != frame.session
                    && (s.ended || s.last_valid.elapsed() > timeout || s.safe.is_some())
            }
        };
        if new_session {
            // A late frame of an ended session must not begin a session of its own.
            if matches!(frame.payload, Payload::SafeState(_)) {
                return Ok(());
            }
            self.begin_session(frame.session, from)?;
        }
        let Some(s) = self.session.as_mut() else {
            return Ok(());
        };
        if from != s.peer {
            s.rx.counters.wrong_session += 1;
            return Ok(());
        }
        if s.rx.check(&frame).is_err() {
            return Ok(());
        }
        s.last_valid = Instant::now();
        self.advance()?;
        let Some(s) = self.session.as_mut() else {
            return Ok(());
        };
        match frame.payload {
            Payload::Command(c) => {
                if s.safe.is_some() {
                    if c.drives() {
                        self.stats.drive_commands_in_safe_state += 1;
                        if s.safe_requested {
                            self.stats.drive_commands_after_safe_request += 1;
                        }
                    }
                } else if [c.test_kind, c.load_kind] != self.kinds {
                    self.stats.commands_refused += 1;
                } else {
                    s.held = c;
                    s.last_command = frame.sequence;
                    self.stats.commands_applied += 1;
                }
            }
            Payload::Heartbeat => {
                let sample = self.sample(frame.sequence)?;
                self.stats.samples_sent += 1;
                self.reply(Payload::Sample(sample));
            }
            Payload::SafeState(r) => {
                self.stats.safe_state_requests += 1;
                s.safe_requested = true;
                self.enter_safe(r.reason)?;
                if r.reason == reason::SESSION_END
                    && let Some(s) = self.session.as_mut()
                {
                    s.ended = true;
                }
                let sample = self.sample(frame.sequence)?;
                self.stats.safe_state_acks += 1;
                self.reply(Payload::SafeStateAck(sample));
            }
            Payload::Sample(_) | Payload::SafeStateAck(_) | Payload::FaultInject(_) => {
                // Server-to-client frames are not acted on.
                self.rejected.counters.malformed += 1;
            }
        }
        Ok(())
    }
}
