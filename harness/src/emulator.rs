//! The bench emulator: a server of the UDP bench protocol (`docs/bench-protocol.md`) with the
//! `BenchPlant` FMU running in real time behind it, so the hardware path (the `BenchHardware`
//! FMU's UDP backend, or any other client) is tested without hardware.
//!
//! The plant is loaded like any FMU ([`Fmu::load`]); its raw sensor outputs (encoder counts,
//! volts) are what the samples carry. The plant's time is the wall time since the session
//! began: on every frame the emulator first advances the plant to *now* with the command held
//! so far, then acts on the frame. Each session gets a fresh plant at rest, prepared in
//! advance so the first frames are answered at once.
//!
//! **Sessions** are authenticated (protocol §6): a master proves it holds the bench key in a
//! handshake that also carries its bench setup (a master set up differently is refused with
//! the setting that differs); every later frame is tagged with the session's keys. One master
//! at a time: while a session is live, a HELLO of any other master is refused (busy) and
//! frames from any other address or session are dropped and counted; the bench is free again
//! after the master's release (SAFE_STATE, reason session end) or its heartbeat watchdog.
//! **The safe state latches across sessions**: a trip, the watchdog or the emergency stop
//! keeps the outputs safe in every later session until the session's master acknowledges it
//! explicitly (ACKNOWLEDGE, authenticated). Rejected frames are counted
//! ([`EmulatorStats::rejected`] and the fields after it) and logged on stderr at most once a
//! second.
//!
//! Faults are injected in process ([`EmulatorHandle::inject`], the CLI's `--fault`) or by
//! FAULT_INJECT frames of the live, authenticated session (refused and counted with
//! [`EmulatorConfig::refuse_fault_frames`], as a bench server does): the link's faults
//! (replies dropped or delayed; frames of either direction duplicated, reordered or
//! corrupted; silence, the link lost), the sensors' (a channel stuck, forced, noisy or
//! offset), the bench's (the emergency-stop button, a driver fault, a supply drop).
//!
//! **A restart keeps the latch** when the emulator has a state file
//! ([`EmulatorConfig::state_file`], the CLI's `--state`): it records the latch and whether a
//! session is live, and a server that starts while it says a session was live (it went down
//! under a master) starts latched with reason [`reason::SERVER_RESTART`], as protocol §10
//! asks of a bench controller.
//!
//! Timing: the serving loop waits in `ppoll` until the next event it owes (a delayed reply,
//! the session's watchdog deadline) or a datagram, so the watchdog and delayed replies keep
//! their configured times whatever the kernel's tick.

use std::collections::VecDeque;
use std::net::{SocketAddr, ToSocketAddrs, UdpSocket};
use std::os::fd::AsRawFd;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::bench_protocol::auth::{NONCE_LEN, nonce};
use crate::bench_protocol::{
    ANALOG_CHANNELS, BenchSetup, Command, Counters, DecodeError, FaultInjection, Frame, FrameType,
    Header, Key, LinkDirection, Payload, Receiver, Refusal, Sample, Sender, SessionKeys,
    SetValueKind, TAG_LEN, TagKey, VERSION, Welcome, reason, refusal, status,
};
use crate::{Fmu, FmuError, Instance, InstanceOptions, LoadError, LoadOptions, Status};

/// The real-time support of the `fmu` crate's pacing (`SCHED_FIFO`, `ppoll`), shared by
/// including its file as the protocol codec is.
#[path = "../../fmu/src/hardware/realtime.rs"]
#[allow(dead_code)]
pub(crate) mod realtime;

mod faults;
mod link;
mod state;

use faults::{LinkFault, direction_index, gaussian, noise_state};
use state::{read_state, write_state};

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
    /// Supply voltages (test, load): tunable parameters of the plant.
    pub const SUPPLY: [u32; 2] = [43, 44];
    pub const CONFIGURATION: u32 = 1;
    pub const TEST_DRIVER_MODE: u32 = 3;
    pub const LOAD_DRIVER_MODE: u32 = 4;
}

/// Handshakes answered but not yet completed (half-open) that the server remembers. A
/// half-open handshake is never evicted before [`PENDING_LIFETIME`]: with the table full, a
/// new HELLO is not answered (counted in [`EmulatorStats::handshakes_dropped`]; its client
/// sends it again).
const MAX_PENDING: usize = 64;
/// Half-open handshakes of one source IP address at most (the rest of the table stays for
/// the other addresses).
const MAX_PENDING_PER_SOURCE: usize = 16;
/// How long an answered handshake waits for its first session frame.
const PENDING_LIFETIME: Duration = Duration::from_secs(1);
/// Handshake answers (WELCOME, REFUSE) sent to one source IP address: a burst of this many,
/// refilled at this many a second. A master's handshake takes one to eleven (a HELLO every
/// 20 ms for 0.2 s); the limit keeps a replayed or spoofed HELLO from making the server a
/// reflector.
const HANDSHAKE_ANSWERS_PER_SOURCE: f64 = 64.0;
/// Source addresses whose answer budget the server tracks at most (idle ones are forgotten
/// first; past this, the oldest budgets are dropped, which can only grant answers).
const MAX_ANSWER_BUDGETS: usize = 1024;
/// Version refusals sent at most per second (they are unauthenticated: never a reflector).
const VERSION_REFUSALS_PER_SECOND: u64 = 10;
/// The receive buffer the server asks for \[bytes\] (granted up to the system's limit, or
/// fully with `CAP_NET_ADMIN`).
const RECEIVE_BUFFER: usize = 8 << 20;
/// The longest the serving loop waits without looking at its stop flag and fault queue.
const IDLE_WAIT: Duration = Duration::from_millis(1);

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
    /// The bench key; `None`: the public loopback key (protocol §6.1), refused unless `bind`
    /// is a loopback address.
    pub key: Option<Key>,
    /// Log refused frames on stderr (at most one line a second).
    pub log_rejections: bool,
    /// Behave as a bench server towards the network: FAULT_INJECT frames are refused and
    /// counted ([`EmulatorStats::fault_frames_refused`]) even from the live session. Faults
    /// injected by the emulator's owner ([`EmulatorConfig::faults`], [`EmulatorHandle::inject`])
    /// still act: they stand for what happens to the bench itself.
    pub refuse_fault_frames: bool,
    /// A file that keeps the latch and whether a session is live across restarts (module
    /// docs); `None`: a restart forgets them.
    pub state_file: Option<PathBuf>,
}

impl EmulatorConfig {
    /// Defaults: the protocol's heartbeat timeout, no parameters, no faults, no key (loopback
    /// only), rejections logged.
    pub fn new(bind: impl Into<String>, fmu: impl Into<PathBuf>) -> Self {
        Self {
            bind: bind.into(),
            fmu: fmu.into(),
            parameters: Vec::new(),
            heartbeat_timeout: crate::bench_protocol::HEARTBEAT_TIMEOUT,
            faults: Vec::new(),
            realtime_priority: None,
            key: None,
            log_rejections: true,
            refuse_fault_frames: false,
            state_file: None,
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
    /// Commands applied in all sessions.
    pub commands_applied_total: u64,
    /// Drive commands (anything on or nonzero) applied in all sessions.
    pub drive_commands_applied_total: u64,
    /// The outputs the drivers hold now (set values, enables, clutch).
    pub outputs: Option<Command>,
    /// Commands refused (set-value kind differing from the drivers' mode).
    pub commands_refused: u64,
    /// Drive commands (anything on or nonzero) received in the safe state, never applied
    /// (current session).
    pub drive_commands_in_safe_state: u64,
    /// Drive commands received after the client's own safe-state request (a correct client
    /// sends none; current session).
    pub drive_commands_after_safe_request: u64,
    /// Safe-state requests received.
    pub safe_state_requests: u64,
    /// Safe-state acknowledgements sent.
    pub safe_state_acks: u64,
    /// Samples sent.
    pub samples_sent: u64,
    /// Replies dropped or held back by injected faults.
    pub replies_dropped: u64,
    /// The latched safe state's reason, if latched (it survives sessions).
    pub safe_reason: Option<u8>,
    /// Plant time \[s\] at which the safe state was entered (in the session that latched it).
    pub safe_since: Option<f64>,
    /// The plant's own trip code, if it tripped.
    pub plant_trip: Option<i32>,
    /// Plant time \[s\] of the current session.
    pub plant_time: f64,
    /// Frames rejected, by cause (all sessions and the handshakes).
    pub rejected: Counters,
    /// Frames of the live (or a pending) session from another address: a second master or a
    /// spoofer; dropped.
    pub foreign_frames: u64,
    /// Handshakes refused because another master's session was live.
    pub busy_refusals: u64,
    /// HELLOs (authentic, so replays) of a handshake already half-open from another source
    /// address: not answered, and the half-open handshake is left as it is.
    pub replayed_hellos: u64,
    /// HELLOs not answered because the half-open handshakes' table (or the source address's
    /// share of it) was full, or the source address's answer budget spent.
    pub handshakes_dropped: u64,
    /// Handshakes refused because the master's bench setup differs.
    pub setup_refusals: u64,
    /// Frames of another protocol version answered with a version refusal.
    pub version_refusals: u64,
    /// Latches cleared by an acknowledgement.
    pub acknowledgements: u64,
    /// Acknowledgements refused (wrong reason, the button still pressed, nothing latched).
    pub acknowledgements_refused: u64,
    /// Fault injections applied (in process and by authenticated frames).
    pub faults_injected: u64,
    /// Lines logged about refused frames (at most one a second).
    pub log_lines: u64,
    /// The `SCHED_FIFO` priority the serving thread runs at (0: normal scheduling).
    pub realtime_priority: i32,
    /// FAULT_INJECT frames refused ([`EmulatorConfig::refuse_fault_frames`]).
    pub fault_frames_refused: u64,
    /// The latch the server started with, restored from its state file (a restart).
    pub restored_latch: Option<u8>,
    /// HEARTBEAT datagrams received (by their header, as they arrive: valid or not, any
    /// session), the campaign's clock of control periods.
    pub heartbeats_seen: u64,
    /// [`Self::heartbeats_seen`] when the last fault was applied.
    pub heartbeats_at_fault: u64,
    /// [`Self::heartbeats_seen`] when the first drive command was applied (since the start):
    /// where a master's run began on the campaign's clock, taken by the serving thread itself
    /// (an observer polling the statistics sees it late when it is descheduled).
    pub heartbeats_at_first_drive: Option<u64>,
    /// [`Self::heartbeats_seen`] when the first SAFE_STATE datagram (any session) after the
    /// last fault (or the start) arrived: a client's trip is `this - heartbeats_at_fault`
    /// control periods after the fault.
    pub heartbeats_at_safe_request: Option<u64>,
    /// Session time \[s\] (wall clock since the session began) of the last valid frame.
    pub last_valid_time: f64,
    /// Session time \[s\] at which the safe state latched (in the session that latched it).
    pub latched_at: Option<f64>,
    /// Frames the emulated link duplicated, reordered or corrupted (both directions).
    pub link_faults_applied: u64,
    /// The longest wall-clock interval \[s\] between handling two valid frames of the current
    /// session, measured on the bench's side: how long the master, the link or the serving
    /// loop itself stalled (the plant is advanced when a frame is handled, so this is also its
    /// longest step).
    pub largest_frame_gap: f64,
}

/// A running emulator thread.
#[derive(Debug)]
pub struct EmulatorHandle {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    stats: Arc<Mutex<EmulatorStats>>,
    faults: Arc<Mutex<VecDeque<FaultInjection>>>,
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

    /// Injects a fault in process (the emulator's owner is trusted; over the network only the
    /// live session may) and waits until the emulator has applied it.
    pub fn inject(&self, fault: FaultInjection) -> Result<(), EmulatorError> {
        let before = self.stats().faults_injected;
        self.faults
            .lock()
            .map_err(|_| EmulatorError::Config("emulator fault queue poisoned".into()))?
            .push_back(fault);
        let start = Instant::now();
        while self.stats().faults_injected == before {
            if start.elapsed() > Duration::from_secs(1) {
                return Err(EmulatorError::Config(
                    "the emulator did not apply the fault within 1 s".into(),
                ));
            }
            std::thread::sleep(Duration::from_micros(50));
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
    let faults = server.injected.clone();
    let (s2, st2) = (stop.clone(), stats.clone());
    let thread = std::thread::Builder::new()
        .name("kneebench-emulator".into())
        .spawn(move || server.serve(&s2, &st2))?;
    Ok(EmulatorHandle {
        addr,
        stop,
        stats,
        faults,
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

/// Checks that serving on `bind` with `key` is allowed: without a key, or with one that is
/// no secret ([`Key::weakness`]: the public loopback key, say), only on a loopback address.
pub fn check_bind(bind: &str, key: Option<&Key>) -> Result<(), EmulatorError> {
    if key.is_some_and(|k| k.weakness().is_none()) {
        return Ok(());
    }
    let what = match key.and_then(Key::weakness) {
        Some(why) => format!("with a key that is no secret ({why})"),
        None => "without a key".to_string(),
    };
    let addrs: Vec<SocketAddr> = bind
        .to_socket_addrs()
        .map_err(|e| EmulatorError::Config(format!("bind address `{bind}`: {e}")))?
        .collect();
    if let Some(a) = addrs.iter().find(|a| !a.ip().is_loopback()) {
        return Err(EmulatorError::Config(format!(
            "refusing to serve on {a} {what}: every host that reaches it could drive the bench; give a key file (--key FILE, or --new-key FILE to make one) or bind a loopback address"
        )));
    }
    Ok(())
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
    safe_requested: bool,
    server_trip: bool,
    /// Released by its master (SAFE_STATE with reason session end).
    ended: bool,
    /// Its heartbeat watchdog expired.
    expired: bool,
}

/// A handshake answered with a WELCOME, waiting for its first session frame.
struct Pending {
    session: u32,
    peer: SocketAddr,
    client_nonce: [u8; NONCE_LEN],
    welcome: Vec<u8>,
    keys: SessionKeys,
    created: Instant,
}

struct Server {
    socket: UdpSocket,
    fmu: Fmu,
    config: EmulatorConfig,
    key: Key,
    handshake: TagKey,
    setup: BenchSetup,
    kinds: [SetValueKind; 2],
    ready: Option<Instance>,
    session: Option<Session>,
    pending: VecDeque<Pending>,
    /// The latched safe state's reason (survives sessions; cleared only by ACKNOWLEDGE).
    latch: Option<u8>,
    stats: EmulatorStats,
    /// Rejections outside the sessions' own receivers (handshakes, strangers, old sessions).
    rejected: Counters,
    /// Rejections of ended sessions' receivers.
    rejected_before: Counters,
    injected: Arc<Mutex<VecDeque<FaultInjection>>>,
    drop_replies: u32,
    delay: Option<(u32, Duration)>,
    delayed: VecDeque<(Instant, SocketAddr, Vec<u8>)>,
    stuck: [bool; 8],
    stuck_values: [Option<f64>; 8],
    forced: [Option<f64>; ANALOG_CHANNELS],
    emergency_stop: bool,
    silent: bool,
    /// Link faults per direction (index: [`direction_index`]).
    link: [LinkFault; 2],
    /// Noise per analog channel: (standard deviation \[V\], generator state).
    noise: [Option<(f64, u64)>; ANALOG_CHANNELS],
    /// Offset per analog channel \[V\].
    offset: [f64; ANALOG_CHANNELS],
    /// Drivers (test, load) whose fault line is raised.
    driver_fault: [bool; 2],
    /// Supplies (test, load) dropped to a voltage; the nominal ones.
    supply: [Option<f64>; 2],
    supply_nominal: [f64; 2],
    /// (latch, session live) as last written to the state file.
    persisted: (Option<u8>, bool),
    /// (second of the last log line, refusals not logged since)
    log: (Option<Instant>, u64),
    /// (start of the current second, version refusals sent in it)
    version_budget: (Instant, u64),
    /// Handshake answers each source IP address may still get: (last refill, tokens).
    answer_budgets: std::collections::HashMap<std::net::IpAddr, (Instant, f64)>,
    /// Datagrams to send once the frame at hand is handled and the statistics published.
    outbox: Vec<(Vec<u8>, SocketAddr)>,
}

impl Server {
    fn new(config: EmulatorConfig) -> Result<Self, EmulatorError> {
        check_bind(&config.bind, config.key.as_ref())?;
        let fmu = Fmu::load(&config.fmu, &LoadOptions::default())?;
        // The emulator drives the plant's own interface: another model would be driven through
        // value references it does not have.
        let model = &fmu.model_description().model_name;
        if model != "BenchPlant" {
            return Err(EmulatorError::Config(format!(
                "{} is a {model}, not the bench plant (BenchPlant.fmu)",
                config.fmu.display()
            )));
        }
        let socket = UdpSocket::bind(&config.bind)?;
        // Non-blocking: the serving loop drains what is queued and waits in `ppoll`. (Its
        // send buffer only ever holds its own replies, a few hundred bytes a period.)
        socket.set_nonblocking(true)?;
        // Room for 8 MB of datagrams: a flood of junk that arrives while the thread is
        // descheduled must not push the master's frames out of the queue.
        realtime::set_receive_buffer(socket.as_raw_fd(), RECEIVE_BUFFER);
        let key = config.key.clone().unwrap_or_else(Key::loopback);
        let mut server = Self {
            socket,
            fmu,
            handshake: key.handshake(),
            key,
            setup: BenchSetup {
                configuration: 0,
                test_kind: SetValueKind::Current,
                load_kind: SetValueKind::Current,
            },
            kinds: [SetValueKind::Current; 2],
            ready: None,
            session: None,
            pending: VecDeque::new(),
            latch: None,
            stats: EmulatorStats::default(),
            rejected: Counters::default(),
            rejected_before: Counters::default(),
            injected: Arc::new(Mutex::new(VecDeque::new())),
            drop_replies: 0,
            delay: None,
            delayed: VecDeque::new(),
            stuck: [false; 8],
            stuck_values: [None; 8],
            forced: [None; ANALOG_CHANNELS],
            emergency_stop: false,
            silent: false,
            link: Default::default(),
            noise: [None; ANALOG_CHANNELS],
            offset: [0.0; ANALOG_CHANNELS],
            driver_fault: [false; 2],
            supply: [None; 2],
            supply_nominal: [0.0; 2],
            persisted: (None, false),
            log: (None, 0),
            version_budget: (Instant::now(), 0),
            answer_budgets: std::collections::HashMap::new(),
            outbox: Vec::new(),
            config,
        };
        let mut plant = server.prepare()?;
        let mut modes = [0; 3];
        plant.get_integer(
            &[
                vr::CONFIGURATION,
                vr::TEST_DRIVER_MODE,
                vr::LOAD_DRIVER_MODE,
            ],
            &mut modes,
        )?;
        let kind = |m: i32| {
            if m == 0 {
                SetValueKind::Voltage
            } else {
                SetValueKind::Current
            }
        };
        server.kinds = [kind(modes[1]), kind(modes[2])];
        server.setup = BenchSetup {
            configuration: u8::try_from(modes[0]).unwrap_or(u8::MAX),
            test_kind: server.kinds[0],
            load_kind: server.kinds[1],
        };
        plant.get_real(&vr::SUPPLY, &mut server.supply_nominal)?;
        server.ready = Some(plant);
        if let Some(path) = server.config.state_file.clone() {
            let (latch, live) = read_state(&path)?;
            server.latch = match (latch, live) {
                (Some(r), _) => Some(r),
                // It went down under a master: the master's control was lost with it.
                (None, true) => Some(reason::SERVER_RESTART),
                (None, false) => None,
            };
            server.stats.restored_latch = server.latch;
            server.persist();
        }
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
        // A supply that dropped stays dropped for the next session's bench.
        for (k, volts) in self.supply.iter().enumerate() {
            if let Some(v) = volts {
                plant.set_real(&[vr::SUPPLY[k]], &[*v])?;
            }
        }
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
            let queued: Vec<FaultInjection> = match self.injected.lock() {
                Ok(mut q) => q.drain(..).collect(),
                Err(_) => Vec::new(),
            };
            for f in queued {
                self.apply_fault(f);
            }
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
                    .is_none_or(|s| s.ended || s.expired || self.latch.is_some())
            {
                self.ready = Some(self.prepare()?);
            }
            // A bounded batch, so that delayed replies and the watchdog keep their times under
            // a flood.
            for _ in 0..256 {
                match self.socket.recv_from(&mut buf) {
                    Ok((n, from)) => {
                        let bytes = &buf[..n.min(buf.len())];
                        self.count_arrival(bytes);
                        // What the (emulated) link delivers of it.
                        let delivered = self.link[direction_index(LinkDirection::ToServer)].pass(
                            bytes.to_vec(),
                            from,
                            &mut self.stats.link_faults_applied,
                        );
                        for (bytes, from) in delivered {
                            if self.handle(&bytes, from)? {
                                // Published before the replies go out: whoever gets a reply
                                // sees the frame's effect in the statistics.
                                self.publish(stats);
                            }
                            for (bytes, to) in self.outbox.drain(..) {
                                let _ = self.socket.send_to(&bytes, to);
                            }
                        }
                    }
                    Err(e)
                        if matches!(
                            e.kind(),
                            std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                        ) =>
                    {
                        break;
                    }
                    // ICMP errors of earlier sends (a master gone): not this socket's failure.
                    Err(e)
                        if matches!(
                            e.kind(),
                            std::io::ErrorKind::ConnectionRefused
                                | std::io::ErrorKind::ConnectionReset
                        ) => {}
                    Err(e) => return Err(e.into()),
                }
            }
            self.publish(stats);
            self.persist();
            let mut wake = Instant::now() + IDLE_WAIT;
            if let Some((due, _, _)) = self.delayed.front() {
                wake = wake.min(*due);
            }
            if let Some(s) = &self.session
                && !s.ended
                && !s.expired
            {
                wake = wake.min(s.last_valid + self.config.heartbeat_timeout);
            }
            let left = wake.saturating_duration_since(Instant::now());
            realtime::wait_readable_until(
                self.socket.as_raw_fd(),
                realtime::now_ns() + u64::try_from(left.as_nanos()).unwrap_or(u64::MAX),
            );
        }
        self.publish(stats);
        Ok(())
    }

    /// Counts a datagram's arrival by its header's type (the campaign's clock: HEARTBEATs are
    /// control periods, the first SAFE_STATE after a fault is a client's reaction).
    fn count_arrival(&mut self, bytes: &[u8]) {
        match Frame::peek(bytes).map(|h| h.frame_type) {
            Ok(FrameType::Heartbeat) => self.stats.heartbeats_seen += 1,
            Ok(FrameType::SafeState) if self.stats.heartbeats_at_safe_request.is_none() => {
                self.stats.heartbeats_at_safe_request = Some(self.stats.heartbeats_seen);
            }
            _ => {}
        }
    }

    /// Writes the state file when the latch or the session's liveness changed.
    fn persist(&mut self) {
        let Some(path) = &self.config.state_file else {
            return;
        };
        let live = self
            .session
            .as_ref()
            .is_some_and(|s| !s.ended && !s.expired);
        let now = (self.latch, live);
        if now == self.persisted {
            return;
        }
        if let Err(e) = write_state(path, now.0, now.1) {
            eprintln!(
                "kneebench emulate: state file {}: {e}; a restart may forget the latch",
                path.display()
            );
        }
        self.persisted = now;
    }

    fn publish(&self, stats: &Mutex<EmulatorStats>) {
        if let Ok(mut s) = stats.lock() {
            *s = self.stats.clone();
            s.safe_reason = self.latch;
            let mut r = self.rejected;
            r.add(&self.rejected_before);
            if let Some(session) = &self.session {
                r.add(&session.rx.counters);
                s.outputs = Some(session.held);
            }
            s.rejected = r;
        }
    }

    /// The session whose master holds the bench: begun, not released, its watchdog not
    /// expired.
    fn live(&self) -> bool {
        self.session.as_ref().is_some_and(|s| {
            !s.ended && !s.expired && s.last_valid.elapsed() <= self.config.heartbeat_timeout
        })
    }

    fn watchdog(&mut self, now: Instant) -> Result<(), EmulatorError> {
        let timeout = self.config.heartbeat_timeout;
        let Some(s) = self.session.as_mut() else {
            return Ok(());
        };
        if !s.ended && !s.expired && now.duration_since(s.last_valid) > timeout {
            s.expired = true;
            if self.latch.is_none() {
                s.server_trip = true;
            }
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

    /// Outputs safe; latched with `why` unless already latched (the first reason stays).
    fn enter_safe(&mut self, why: u8) -> Result<(), EmulatorError> {
        let Some(s) = self.session.as_mut() else {
            self.latch.get_or_insert(why);
            return Ok(());
        };
        s.held = Command::safe(s.held.test_kind, s.held.load_kind);
        if why != reason::SESSION_END && self.latch.is_none() {
            self.latch = Some(why);
            self.stats.safe_since = Some(s.plant_time);
            self.stats.latched_at = Some(s.origin.elapsed().as_secs_f64());
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
            *a += self.offset[k];
            if let Some((sigma, state)) = self.noise[k].as_mut() {
                *a += *sigma * gaussian(state);
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
            (self.latch.is_some() || s.ended, status::SAFE_STATE),
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
            safe_reason: match (self.latch, s.ended) {
                (Some(r), _) => r,
                (None, true) => reason::SESSION_END,
                (None, false) => reason::NONE,
            },
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
        let delivered = self.link[direction_index(LinkDirection::ToClient)].pass(
            bytes,
            peer,
            &mut self.stats.link_faults_applied,
        );
        self.outbox.extend(delivered);
    }

    /// Sets a plant's supply voltages to the faulted (or the nominal) ones.
    fn set_supplies(&mut self) {
        let volts: Vec<f64> = (0..2)
            .map(|k| self.supply[k].unwrap_or(self.supply_nominal[k]))
            .collect();
        let plants = self
            .session
            .as_mut()
            .map(|s| &mut s.plant)
            .into_iter()
            .chain(self.ready.as_mut());
        for plant in plants {
            if let Err(e) = plant.set_real(&vr::SUPPLY, &volts) {
                eprintln!("kneebench emulate: supply voltages {volts:?} not set: {e}");
            }
        }
    }

    fn apply_fault(&mut self, fault: FaultInjection) {
        self.stats.faults_injected += 1;
        self.stats.heartbeats_at_fault = self.stats.heartbeats_seen;
        self.stats.heartbeats_at_safe_request = None;
        match fault {
            FaultInjection::Clear => {
                self.drop_replies = 0;
                self.delay = None;
                self.stuck = [false; 8];
                self.stuck_values = [None; 8];
                self.forced = [None; ANALOG_CHANNELS];
                self.silent = false;
                self.link = Default::default();
                self.noise = [None; ANALOG_CHANNELS];
                self.offset = [0.0; ANALOG_CHANNELS];
                self.driver_fault = [false; 2];
                if self.supply.iter().any(Option::is_some) {
                    self.supply = [None; 2];
                    self.set_supplies();
                }
            }
            FaultInjection::Duplicate { direction, count } => {
                self.link[direction_index(direction)].duplicate = count;
            }
            FaultInjection::Reorder { direction } => {
                self.link[direction_index(direction)].reorder = true;
            }
            FaultInjection::Corrupt { direction, count } => {
                self.link[direction_index(direction)].corrupt = count;
            }
            FaultInjection::Noise {
                channel,
                volts,
                seed,
            } => {
                if let Some(n) = self.noise.get_mut(channel as usize) {
                    *n = (volts > 0.0).then_some((volts, noise_state(seed)));
                }
            }
            FaultInjection::Offset { channel, volts } => {
                if let Some(o) = self.offset.get_mut(channel as usize) {
                    *o = volts;
                }
            }
            FaultInjection::DriverFault { driver } => {
                if let Some(f) = self.driver_fault.get_mut(driver as usize) {
                    *f = true;
                }
                if let Some(s) = self.session.as_mut() {
                    s.server_trip = true;
                }
                let _ = self.enter_safe(reason::BENCH_PROTECTION);
            }
            FaultInjection::SupplyDrop { supply, volts } => {
                if let Some(v) = self.supply.get_mut(supply as usize) {
                    *v = Some(volts);
                }
                self.set_supplies();
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
}
