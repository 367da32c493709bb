//! The kneebench UDP bench protocol, version 2: frames, their big-endian codec, their
//! authentication, the handshake, and the receive filter that rejects unauthenticated,
//! malformed, replayed and out-of-order frames.
//!
//! The normative description is `docs/bench-protocol.md`; this module implements it for both
//! ends: the hardware FMU (client) and the emulator (`kneebench emulate`, server). It depends on
//! `std`, `thiserror`, `libc` and the RustCrypto `hmac`/`sha2` and `getrandom` crates only, so the
//! harness includes this very directory with `#[path]` (it never links the models) and both
//! ends share one codec.
//!
//! A frame is a 16-byte header, a payload whose length the header states and which must equal
//! the length of its type, and a 16-byte tag, HMAC-SHA256 over header and payload truncated
//! to 128 bits (the `auth` module):
//!
//! ```text
//! magic u32 "KNBP" | version u8 | type u8 | payload length u16 | session u32 | sequence u32
//! payload ... | tag [16]
//! ```

#![allow(dead_code)]

pub mod auth;
pub mod fuzzing;
pub mod handshake;
pub mod user;

use std::time::Duration;

pub use auth::{Key, KeyError, SessionKeys, TAG_LEN, TagKey};
pub use handshake::{
    Acknowledge, BenchSetup, ClientHandshake, HandshakeReply, Hello, Refusal, Session, Welcome,
    refusal,
};

/// `"KNBP"`: the first four bytes of every frame.
pub const MAGIC: u32 = 0x4B4E_4250;
/// The protocol version this codec speaks; frames of any other version are rejected.
pub const VERSION: u8 = 2;
/// Bytes of the header.
pub const HEADER_LEN: usize = 16;
/// No valid frame is longer than this (the longest payload is the refusal's 84 bytes).
pub const MAX_FRAME_LEN: usize = HEADER_LEN + handshake::REFUSE_LEN + TAG_LEN;
/// The port a bench I/O server listens on unless configured otherwise.
pub const DEFAULT_PORT: u16 = 47000;
/// The longest a server waits for a valid frame of its session before it enters the safe state
/// by itself (the link watchdog of the server side).
pub const HEARTBEAT_TIMEOUT: Duration = Duration::from_millis(50);
/// The longest heartbeat timeout a server may be configured with.
pub const MAX_HEARTBEAT_TIMEOUT: Duration = Duration::from_millis(100);
/// The longest interval between two frames of a client that wants to keep its session alive
/// (half the server's timeout, so one lost heartbeat is survivable).
pub const HEARTBEAT_INTERVAL: Duration = Duration::from_millis(25);

/// Payload length of a [`Command`].
pub const COMMAND_LEN: usize = 20;
/// Payload length of a heartbeat.
pub const HEARTBEAT_LEN: usize = 0;
/// Payload length of a [`Sample`] (also of a safe-state acknowledgement).
pub const SAMPLE_LEN: usize = 76;
/// Payload length of a [`SafeStateRequest`].
pub const SAFE_STATE_LEN: usize = 4;
/// Payload length of a [`FaultInjection`].
pub const FAULT_LEN: usize = 16;

/// Number of analog input channels in a sample.
pub const ANALOG_CHANNELS: usize = 6;

/// The frame types (header byte 5).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum FrameType {
    /// Client to server: set values and digital outputs, applied on receipt and held.
    Command = 1,
    /// Client to server: keeps the session alive and asks for a sample.
    Heartbeat = 2,
    /// Server to client: the inputs sampled when the server received the heartbeat.
    Sample = 3,
    /// Client to server: enter the safe state now (latched for the session).
    SafeState = 4,
    /// Server to client: the safe state is in force; carries a sample taken after entering it.
    SafeStateAck = 5,
    /// Client to an emulator, in an authenticated session: inject a fault (a real bench server
    /// rejects it).
    FaultInject = 6,
    /// Client to server: opens a handshake (nonce, the client's bench setup).
    Hello = 7,
    /// Server to client: accepts a handshake (both nonces, the server's latch).
    Welcome = 8,
    /// Server to client: refuses a handshake (why, in a code and a text).
    Refuse = 9,
    /// Client to server: clears the latched safe state (an explicit, authenticated
    /// acknowledgement); answered by a sample.
    Acknowledge = 10,
}

impl FrameType {
    /// From the header byte.
    pub fn from_u8(v: u8) -> Option<Self> {
        Some(match v {
            1 => Self::Command,
            2 => Self::Heartbeat,
            3 => Self::Sample,
            4 => Self::SafeState,
            5 => Self::SafeStateAck,
            6 => Self::FaultInject,
            7 => Self::Hello,
            8 => Self::Welcome,
            9 => Self::Refuse,
            10 => Self::Acknowledge,
            _ => return None,
        })
    }

    /// The payload length frames of this type must have.
    pub fn payload_len(self) -> usize {
        match self {
            Self::Command => COMMAND_LEN,
            Self::Heartbeat => HEARTBEAT_LEN,
            Self::Sample | Self::SafeStateAck => SAMPLE_LEN,
            Self::SafeState => SAFE_STATE_LEN,
            Self::FaultInject => FAULT_LEN,
            Self::Hello => handshake::HELLO_LEN,
            Self::Welcome => handshake::WELCOME_LEN,
            Self::Refuse => handshake::REFUSE_LEN,
            Self::Acknowledge => handshake::ACKNOWLEDGE_LEN,
        }
    }

    /// Whether frames of this type are tagged with the handshake key (rather than a session
    /// key).
    pub fn is_handshake(self) -> bool {
        matches!(self, Self::Hello | Self::Welcome | Self::Refuse)
    }
}

/// What a driver set value is: the driver's operating mode as the client believes it to be.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum SetValueKind {
    /// Armature voltage \[V\].
    Voltage = 0,
    /// Current \[A\].
    Current = 1,
}

impl SetValueKind {
    /// From the wire byte.
    pub fn from_u8(v: u8) -> Option<Self> {
        match v {
            0 => Some(Self::Voltage),
            1 => Some(Self::Current),
            _ => None,
        }
    }
}

/// A command: set values and digital outputs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Command {
    /// Test-motor driver set value (volts or amperes per `test_kind`).
    pub test_set_value: f64,
    /// Load-motor driver set value.
    pub load_set_value: f64,
    /// Test driver enable output.
    pub test_enable: bool,
    /// Load driver enable output.
    pub load_enable: bool,
    /// Clutch output (energised = engaged).
    pub clutch: bool,
    /// What `test_set_value` is; a server whose driver is configured otherwise rejects the frame.
    pub test_kind: SetValueKind,
    /// What `load_set_value` is.
    pub load_kind: SetValueKind,
}

impl Command {
    /// The safe command: set values zero, drivers disabled, clutch released.
    pub fn safe(test_kind: SetValueKind, load_kind: SetValueKind) -> Self {
        Self {
            test_set_value: 0.0,
            load_set_value: 0.0,
            test_enable: false,
            load_enable: false,
            clutch: false,
            test_kind,
            load_kind,
        }
    }

    /// Whether this command drives anything (a set value or an output on).
    pub fn drives(&self) -> bool {
        self.test_enable
            || self.load_enable
            || self.clutch
            || self.test_set_value != 0.0
            || self.load_set_value != 0.0
    }
}

/// The analog channels of a sample, in wire order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum AnalogChannel {
    /// Load cell amplifier output \[V\].
    LoadCell = 0,
    /// Torque transducer amplifier output \[V\].
    Transducer = 1,
    /// Test-motor current sensor (ACS712) \[V\].
    TestCurrentSense = 2,
    /// Load-motor current sensor \[V\].
    LoadCurrentSense = 3,
    /// Test supply voltage divider \[V\].
    TestSupplySense = 4,
    /// Load supply voltage divider \[V\].
    LoadSupplySense = 5,
}

impl AnalogChannel {
    /// All channels, in wire order.
    pub const ALL: [AnalogChannel; ANALOG_CHANNELS] = [
        Self::LoadCell,
        Self::Transducer,
        Self::TestCurrentSense,
        Self::LoadCurrentSense,
        Self::TestSupplySense,
        Self::LoadSupplySense,
    ];

    /// Index in [`Sample::analog`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// A short name for logs.
    pub fn name(self) -> &'static str {
        match self {
            Self::LoadCell => "load cell",
            Self::Transducer => "torque transducer",
            Self::TestCurrentSense => "test current sensor",
            Self::LoadCurrentSense => "load current sensor",
            Self::TestSupplySense => "test supply divider",
            Self::LoadSupplySense => "load supply divider",
        }
    }
}

/// Status bits of a sample.
pub mod status {
    /// The server is in the safe state (latched until an authenticated acknowledgement).
    pub const SAFE_STATE: u8 = 1 << 0;
    /// The emergency-stop button is pressed.
    pub const EMERGENCY_STOP: u8 = 1 << 1;
    /// The test driver's enable output is on.
    pub const TEST_ENABLED: u8 = 1 << 2;
    /// The load driver's enable output is on.
    pub const LOAD_ENABLED: u8 = 1 << 3;
    /// The clutch output is on.
    pub const CLUTCH: u8 = 1 << 4;
    /// The server entered the safe state by itself (its heartbeat watchdog or the button).
    pub const SERVER_TRIP: u8 = 1 << 5;
    /// Bits a version-2 server may set.
    pub const DEFINED: u8 = 0x3F;
}

/// Why the safe state was entered (sample byte 17, safe-state request byte 0, welcome byte
/// 32, acknowledgement byte 0).
pub mod reason {
    /// Not in the safe state.
    pub const NONE: u8 = 0;
    /// Requested by the client (its own trip code is logged on the client).
    pub const CLIENT_REQUEST: u8 = 1;
    /// The server's heartbeat watchdog expired.
    pub const HEARTBEAT_TIMEOUT: u8 = 2;
    /// The emergency-stop button.
    pub const EMERGENCY_STOP: u8 = 3;
    /// The client ended its session normally (a release: not latched).
    pub const SESSION_END: u8 = 4;
    /// The bench's own protection stopped it (a driver fault, a server-side interlock).
    pub const BENCH_PROTECTION: u8 = 5;
    /// The server started while its persisted state says a session was live: it went down
    /// (a crash, a restart) under a master, whose control was lost with it.
    pub const SERVER_RESTART: u8 = 6;
    /// The highest defined reason.
    pub const MAX: u8 = 6;
}

/// Inputs sampled by the server.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Sample {
    /// Sequence number of the heartbeat or safe-state request this answers.
    pub request_sequence: u32,
    /// Sequence number of the last command the server applied (0: none).
    pub last_command_sequence: u32,
    /// Server time of the sample \[us\] since the session began (monotonic).
    pub server_time_us: u64,
    /// [`status`] bits.
    pub status: u8,
    /// [`reason`] of the safe state (0 when not in it).
    pub safe_reason: u8,
    /// Test-motor encoder counter (x4 decoded, wrapping).
    pub test_counts: i32,
    /// Load-motor encoder counter.
    pub load_counts: i32,
    /// Analog inputs \[V\], indexed by [`AnalogChannel`].
    pub analog: [f64; ANALOG_CHANNELS],
}

impl Sample {
    /// Whether status bit `bit` is set.
    pub fn has(&self, bit: u8) -> bool {
        self.status & bit != 0
    }
}

/// A safe-state request.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SafeStateRequest {
    /// A [`reason`] code.
    pub reason: u8,
}

/// A fault for an emulator to inject.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FaultInjection {
    /// Clear every injected fault (a pressed emulated emergency stop stays latched).
    Clear,
    /// Drop the next `count` replies (samples and acknowledgements).
    DropReplies {
        /// How many.
        count: u32,
    },
    /// Send the next `count` replies `delay_s` late.
    DelayReplies {
        /// How many.
        count: u32,
        /// Delay \[s\].
        delay_s: f64,
    },
    /// Hold an input channel (analog 0-5, encoders 6 test and 7 load) at its present value.
    Stuck {
        /// The channel.
        channel: u8,
    },
    /// Force an analog channel (0-5) to `volts`.
    Force {
        /// The channel.
        channel: u8,
        /// The value \[V\].
        volts: f64,
    },
    /// Press the emulated emergency-stop button.
    EmergencyStop,
    /// Stop answering anything (the link is lost) until a `Clear`.
    Silence,
    /// The link duplicates the next `count` frames of one direction (each arrives twice).
    Duplicate {
        /// Which frames.
        direction: LinkDirection,
        /// How many.
        count: u32,
    },
    /// The link swaps the next two frames of one direction (the first arrives after the
    /// second).
    Reorder {
        /// Which frames.
        direction: LinkDirection,
    },
    /// The link corrupts the next `count` frames of one direction (one byte inverted).
    Corrupt {
        /// Which frames.
        direction: LinkDirection,
        /// How many.
        count: u32,
    },
    /// Add Gaussian noise of standard deviation `volts` to an analog channel (0-5), drawn
    /// from a generator seeded with `seed` (repeatable).
    Noise {
        /// The channel.
        channel: u8,
        /// Standard deviation \[V\], finite, not negative.
        volts: f64,
        /// The generator's seed.
        seed: u32,
    },
    /// Add a constant `volts` to an analog channel (0-5).
    Offset {
        /// The channel.
        channel: u8,
        /// The offset \[V\], finite.
        volts: f64,
    },
    /// A driver faults (0 test, 1 load): it switches its output off and raises its fault
    /// line, on which the server enters its safe state by itself (the bench's protection).
    DriverFault {
        /// The driver.
        driver: u8,
    },
    /// A driver's supply (0 test, 1 load) falls to `volts`: the driver saturates there and
    /// the supply divider reads it.
    SupplyDrop {
        /// The supply.
        supply: u8,
        /// The supply voltage now \[V\], 0 to 100.
        volts: f64,
    },
}

/// The direction of the link a link fault acts on (the fault frame's channel byte).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkDirection {
    /// The server's replies (channel 0).
    ToClient,
    /// The client's frames as the server receives them (channel 1).
    ToServer,
}

impl LinkDirection {
    fn byte(self) -> u8 {
        match self {
            Self::ToClient => 0,
            Self::ToServer => 1,
        }
    }

    fn of(byte: u8) -> Option<Self> {
        match byte {
            0 => Some(Self::ToClient),
            1 => Some(Self::ToServer),
            _ => None,
        }
    }
}

impl FaultInjection {
    fn encode(&self) -> (u8, u8, f64, u32) {
        match *self {
            Self::Clear => (0, 0, 0.0, 0),
            Self::DropReplies { count } => (1, 0, 0.0, count),
            Self::DelayReplies { count, delay_s } => (2, 0, delay_s, count),
            Self::Stuck { channel } => (3, channel, 0.0, 0),
            Self::Force { channel, volts } => (4, channel, volts, 0),
            Self::EmergencyStop => (5, 0, 0.0, 0),
            Self::Silence => (6, 0, 0.0, 0),
            Self::Duplicate { direction, count } => (7, direction.byte(), 0.0, count),
            Self::Reorder { direction } => (8, direction.byte(), 0.0, 0),
            Self::Corrupt { direction, count } => (9, direction.byte(), 0.0, count),
            Self::Noise {
                channel,
                volts,
                seed,
            } => (10, channel, volts, seed),
            Self::Offset { channel, volts } => (11, channel, volts, 0),
            Self::DriverFault { driver } => (12, driver, 0.0, 0),
            Self::SupplyDrop { supply, volts } => (13, supply, volts, 0),
        }
    }

    fn decode(kind: u8, channel: u8, value: f64, count: u32) -> Result<Self, DecodeError> {
        // A field the kind does not use must be zero: nothing is silently dropped (found by
        // fuzzing: a Force with a count re-encoded without it).
        let (uses_value, uses_count) = match kind {
            1 | 7 | 9 => (false, true),
            2 | 10 => (true, true),
            4 | 11 | 13 => (true, false),
            _ => (false, false),
        };
        if (!uses_value && value.to_bits() != 0) || (!uses_count && count != 0) {
            return Err(DecodeError::BadPayload("unused fault field not zero"));
        }
        let no_channel = |f: Self| {
            if channel == 0 {
                Ok(f)
            } else {
                Err(DecodeError::BadPayload("fault channel must be 0"))
            }
        };
        match kind {
            0 => no_channel(Self::Clear),
            1 => no_channel(Self::DropReplies { count }),
            2 if value.is_finite() && (0.0..=10.0).contains(&value) => {
                no_channel(Self::DelayReplies {
                    count,
                    delay_s: value,
                })
            }
            2 => Err(DecodeError::BadPayload("delay outside 0..10 s")),
            3 if channel < 8 => Ok(Self::Stuck { channel }),
            4 if (channel as usize) < ANALOG_CHANNELS && value.is_finite() => Ok(Self::Force {
                channel,
                volts: value,
            }),
            3 | 4 => Err(DecodeError::BadPayload(
                "fault channel or value out of range",
            )),
            5 => no_channel(Self::EmergencyStop),
            6 => no_channel(Self::Silence),
            7..=9 => {
                let direction = LinkDirection::of(channel).ok_or(DecodeError::BadPayload(
                    "link fault direction must be 0 or 1",
                ))?;
                Ok(match kind {
                    7 => Self::Duplicate { direction, count },
                    8 => Self::Reorder { direction },
                    _ => Self::Corrupt { direction, count },
                })
            }
            10 if (channel as usize) < ANALOG_CHANNELS && value.is_finite() && value >= 0.0 => {
                Ok(Self::Noise {
                    channel,
                    volts: value,
                    seed: count,
                })
            }
            11 if (channel as usize) < ANALOG_CHANNELS && value.is_finite() => Ok(Self::Offset {
                channel,
                volts: value,
            }),
            10 | 11 => Err(DecodeError::BadPayload(
                "fault channel or value out of range",
            )),
            12 if channel < 2 => Ok(Self::DriverFault { driver: channel }),
            13 if channel < 2 && value.is_finite() && (0.0..=100.0).contains(&value) => {
                Ok(Self::SupplyDrop {
                    supply: channel,
                    volts: value,
                })
            }
            12 | 13 => Err(DecodeError::BadPayload(
                "driver or supply 0 or 1, supply 0 to 100 V",
            )),
            _ => Err(DecodeError::BadPayload("unknown fault kind")),
        }
    }
}

/// The payload of a frame, by type.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Payload {
    /// [`FrameType::Command`].
    Command(Command),
    /// [`FrameType::Heartbeat`].
    Heartbeat,
    /// [`FrameType::Sample`].
    Sample(Sample),
    /// [`FrameType::SafeState`].
    SafeState(SafeStateRequest),
    /// [`FrameType::SafeStateAck`].
    SafeStateAck(Sample),
    /// [`FrameType::FaultInject`].
    FaultInject(FaultInjection),
    /// [`FrameType::Hello`].
    Hello(Hello),
    /// [`FrameType::Welcome`].
    Welcome(Welcome),
    /// [`FrameType::Refuse`].
    Refuse(Refusal),
    /// [`FrameType::Acknowledge`].
    Acknowledge(Acknowledge),
}

impl Payload {
    /// The frame type of this payload.
    pub fn frame_type(&self) -> FrameType {
        match self {
            Self::Command(_) => FrameType::Command,
            Self::Heartbeat => FrameType::Heartbeat,
            Self::Sample(_) => FrameType::Sample,
            Self::SafeState(_) => FrameType::SafeState,
            Self::SafeStateAck(_) => FrameType::SafeStateAck,
            Self::FaultInject(_) => FrameType::FaultInject,
            Self::Hello(_) => FrameType::Hello,
            Self::Welcome(_) => FrameType::Welcome,
            Self::Refuse(_) => FrameType::Refuse,
            Self::Acknowledge(_) => FrameType::Acknowledge,
        }
    }
}

/// A decoded frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame {
    /// Session identifier chosen by the client (nonzero).
    pub session: u32,
    /// The sender's sequence number in the session (starts at 1, strictly increasing).
    pub sequence: u32,
    /// The payload.
    pub payload: Payload,
}

/// The header of a datagram whose structure (length, magic, version, type) is valid, read
/// before its tag is checked, so that a receiver can choose the key.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    /// The frame type.
    pub frame_type: FrameType,
    /// The session number (not yet checked to be nonzero).
    pub session: u32,
    /// The sequence number (not yet checked to be nonzero).
    pub sequence: u32,
}

/// Why bytes are not a valid frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// Shorter than a header and a tag, or shorter than the header's length says.
    #[error("truncated frame ({0} bytes)")]
    Truncated(usize),
    /// Longer than the header's length says, or than any frame.
    #[error("frame too long ({0} bytes)")]
    TooLong(usize),
    /// The magic number is wrong.
    #[error("bad magic number {0:#010x}")]
    BadMagic(u32),
    /// A version this codec does not speak.
    #[error("unsupported protocol version {0} (this end speaks version {VERSION})")]
    WrongVersion(u8),
    /// An unknown frame type.
    #[error("unknown frame type {0}")]
    UnknownType(u8),
    /// The header's payload length does not match the type.
    #[error("payload length {got} for a frame type of {expected}")]
    BadLength {
        /// Stated length.
        got: usize,
        /// The type's length.
        expected: usize,
    },
    /// The tag does not authenticate the frame under the key in force (a wrong key, another
    /// session's key, or a corrupted frame).
    #[error("authentication failed")]
    BadTag,
    /// Session 0 or sequence 0.
    #[error("session and sequence must be nonzero")]
    ZeroSequence,
    /// A payload field out of its range (reserved bits set, unknown enumeration, non-finite).
    #[error("malformed payload: {0}")]
    BadPayload(&'static str),
}

struct Writer(Vec<u8>);

impl Writer {
    fn u8(&mut self, v: u8) {
        self.0.push(v);
    }
    fn u16(&mut self, v: u16) {
        self.0.extend_from_slice(&v.to_be_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_be_bytes());
    }
    fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_be_bytes());
    }
    fn i32(&mut self, v: i32) {
        self.0.extend_from_slice(&v.to_be_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.0.extend_from_slice(&v.to_bits().to_be_bytes());
    }
    fn bytes(&mut self, v: &[u8]) {
        self.0.extend_from_slice(v);
    }
}

struct Reader<'a>(&'a [u8]);

impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0u8; N];
        // The payload length was checked against the type before any field is read.
        let n = N.min(self.0.len());
        out[..n].copy_from_slice(&self.0[..n]);
        self.0 = &self.0[n..];
        out
    }
    fn u8(&mut self) -> u8 {
        self.take::<1>()[0]
    }
    fn u16(&mut self) -> u16 {
        u16::from_be_bytes(self.take())
    }
    fn u32(&mut self) -> u32 {
        u32::from_be_bytes(self.take())
    }
    fn u64(&mut self) -> u64 {
        u64::from_be_bytes(self.take())
    }
    fn i32(&mut self) -> i32 {
        i32::from_be_bytes(self.take())
    }
    fn f64(&mut self) -> f64 {
        f64::from_bits(self.u64())
    }
}

fn encode_sample(w: &mut Writer, s: &Sample) {
    w.u32(s.request_sequence);
    w.u32(s.last_command_sequence);
    w.u64(s.server_time_us);
    w.u8(s.status);
    w.u8(s.safe_reason);
    w.u16(0);
    w.i32(s.test_counts);
    w.i32(s.load_counts);
    for v in s.analog {
        w.f64(v);
    }
}

fn decode_sample(r: &mut Reader<'_>) -> Result<Sample, DecodeError> {
    let request_sequence = r.u32();
    let last_command_sequence = r.u32();
    let server_time_us = r.u64();
    let status = r.u8();
    let safe_reason = r.u8();
    if r.u16() != 0 {
        return Err(DecodeError::BadPayload(
            "reserved sample bytes are not zero",
        ));
    }
    if status & !status::DEFINED != 0 {
        return Err(DecodeError::BadPayload("undefined status bits set"));
    }
    if safe_reason > reason::MAX {
        return Err(DecodeError::BadPayload("unknown safe-state reason"));
    }
    let test_counts = r.i32();
    let load_counts = r.i32();
    let mut analog = [0f64; ANALOG_CHANNELS];
    for v in &mut analog {
        *v = r.f64();
        if !v.is_finite() {
            return Err(DecodeError::BadPayload("analog value is not finite"));
        }
    }
    Ok(Sample {
        request_sequence,
        last_command_sequence,
        server_time_us,
        status,
        safe_reason,
        test_counts,
        load_counts,
        analog,
    })
}

impl Frame {
    /// The frame's header and payload (everything the tag covers), without the tag.
    pub fn encode_body(&self) -> Vec<u8> {
        let ty = self.payload.frame_type();
        let len = ty.payload_len();
        let mut w = Writer(Vec::with_capacity(HEADER_LEN + len + TAG_LEN));
        w.u32(MAGIC);
        w.u8(VERSION);
        w.u8(ty as u8);
        w.u16(len as u16);
        w.u32(self.session);
        w.u32(self.sequence);
        match &self.payload {
            Payload::Command(c) => {
                w.f64(c.test_set_value);
                w.f64(c.load_set_value);
                w.u8(u8::from(c.test_enable)
                    | u8::from(c.load_enable) << 1
                    | u8::from(c.clutch) << 2);
                w.u8(c.test_kind as u8);
                w.u8(c.load_kind as u8);
                w.u8(0);
            }
            Payload::Heartbeat => {}
            Payload::Sample(s) | Payload::SafeStateAck(s) => encode_sample(&mut w, s),
            Payload::SafeState(s) => {
                w.u8(s.reason);
                w.u8(0);
                w.u16(0);
            }
            Payload::FaultInject(f) => {
                let (kind, channel, value, count) = f.encode();
                w.u8(kind);
                w.u8(channel);
                w.u16(0);
                w.f64(value);
                w.u32(count);
            }
            Payload::Hello(h) => h.encode(&mut w),
            Payload::Welcome(h) => h.encode(&mut w),
            Payload::Refuse(h) => h.encode(&mut w),
            Payload::Acknowledge(h) => h.encode(&mut w),
        }
        w.0
    }

    /// The frame's bytes on the wire, tagged with `key`.
    pub fn encode(&self, key: &TagKey) -> Vec<u8> {
        let mut bytes = self.encode_body();
        let tag = key.tag(&bytes);
        bytes.extend_from_slice(&tag);
        bytes
    }

    /// Checks the structure of a datagram (length, magic, version, type, payload length: the
    /// checks 1-4 of the protocol's acceptance order) and reads its header. Never panics.
    pub fn peek(bytes: &[u8]) -> Result<Header, DecodeError> {
        // A peer of another version is told so whatever its frames' lengths.
        if bytes.len() >= 5 && bytes[..4] == MAGIC.to_be_bytes() && bytes[4] != VERSION {
            return Err(DecodeError::WrongVersion(bytes[4]));
        }
        if bytes.len() < HEADER_LEN + TAG_LEN {
            return Err(DecodeError::Truncated(bytes.len()));
        }
        if bytes.len() > MAX_FRAME_LEN {
            return Err(DecodeError::TooLong(bytes.len()));
        }
        let mut r = Reader(bytes);
        let magic = r.u32();
        if magic != MAGIC {
            return Err(DecodeError::BadMagic(magic));
        }
        let version = r.u8();
        if version != VERSION {
            return Err(DecodeError::WrongVersion(version));
        }
        let ty_byte = r.u8();
        let ty = FrameType::from_u8(ty_byte).ok_or(DecodeError::UnknownType(ty_byte))?;
        let len = r.u16() as usize;
        if len != ty.payload_len() {
            return Err(DecodeError::BadLength {
                got: len,
                expected: ty.payload_len(),
            });
        }
        let total = HEADER_LEN + len + TAG_LEN;
        if bytes.len() < total {
            return Err(DecodeError::Truncated(bytes.len()));
        }
        if bytes.len() > total {
            return Err(DecodeError::TooLong(bytes.len()));
        }
        Ok(Header {
            frame_type: ty,
            session: r.u32(),
            sequence: r.u32(),
        })
    }

    /// Decodes one datagram authenticated with `key`. Never panics; every malformation and a
    /// tag that does not match is an error, and no field is read before the tag is checked.
    pub fn decode(bytes: &[u8], key: &TagKey) -> Result<Frame, DecodeError> {
        let header = Self::peek(bytes)?;
        let body_len = bytes.len() - TAG_LEN;
        if !key.verify(&bytes[..body_len], &bytes[body_len..]) {
            return Err(DecodeError::BadTag);
        }
        Self::decode_fields(header, &bytes[HEADER_LEN..body_len])
    }

    /// The fields of a frame whose structure `peek` checked and whose tag was verified (or,
    /// for measuring the cost of authentication, deliberately not: never act on such a frame).
    pub fn decode_fields(header: Header, payload: &[u8]) -> Result<Frame, DecodeError> {
        let Header {
            frame_type: ty,
            session,
            sequence,
        } = header;
        if session == 0 || sequence == 0 {
            return Err(DecodeError::ZeroSequence);
        }
        let mut r = Reader(payload);
        let payload = match ty {
            FrameType::Command => {
                let test_set_value = r.f64();
                let load_set_value = r.f64();
                let outputs = r.u8();
                let test_kind = SetValueKind::from_u8(r.u8());
                let load_kind = SetValueKind::from_u8(r.u8());
                let reserved = r.u8();
                if !(test_set_value.is_finite() && load_set_value.is_finite()) {
                    return Err(DecodeError::BadPayload("set value is not finite"));
                }
                if outputs & !0x07 != 0 || reserved != 0 {
                    return Err(DecodeError::BadPayload("reserved command bits set"));
                }
                let (Some(test_kind), Some(load_kind)) = (test_kind, load_kind) else {
                    return Err(DecodeError::BadPayload("unknown set-value kind"));
                };
                Payload::Command(Command {
                    test_set_value,
                    load_set_value,
                    test_enable: outputs & 1 != 0,
                    load_enable: outputs & 2 != 0,
                    clutch: outputs & 4 != 0,
                    test_kind,
                    load_kind,
                })
            }
            FrameType::Heartbeat => Payload::Heartbeat,
            FrameType::Sample => Payload::Sample(decode_sample(&mut r)?),
            FrameType::SafeStateAck => Payload::SafeStateAck(decode_sample(&mut r)?),
            FrameType::SafeState => {
                let reason_code = r.u8();
                if r.u8() != 0 || r.u16() != 0 {
                    return Err(DecodeError::BadPayload("reserved safe-state bytes set"));
                }
                if reason_code > reason::MAX {
                    return Err(DecodeError::BadPayload("unknown safe-state reason"));
                }
                Payload::SafeState(SafeStateRequest {
                    reason: reason_code,
                })
            }
            FrameType::FaultInject => {
                let kind = r.u8();
                let channel = r.u8();
                if r.u16() != 0 {
                    return Err(DecodeError::BadPayload("reserved fault bytes set"));
                }
                let value = r.f64();
                let count = r.u32();
                Payload::FaultInject(FaultInjection::decode(kind, channel, value, count)?)
            }
            FrameType::Hello => Payload::Hello(Hello::decode(&mut r)?),
            FrameType::Welcome => Payload::Welcome(Welcome::decode(&mut r)?),
            FrameType::Refuse => Payload::Refuse(Refusal::decode(&mut r)?),
            FrameType::Acknowledge => Payload::Acknowledge(Acknowledge::decode(&mut r)?),
        };
        Ok(Frame {
            session,
            sequence,
            payload,
        })
    }
}

/// Why a decoded frame is not acted on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum Rejection {
    /// The bytes are not a valid, authenticated frame.
    #[error(transparent)]
    Malformed(#[from] DecodeError),
    /// A frame of another session.
    #[error("frame of session {got:#x}, expected {expected:#x}")]
    WrongSession {
        /// The frame's session.
        got: u32,
        /// The session in force.
        expected: u32,
    },
    /// The same sequence number as the last accepted frame.
    #[error("replayed sequence number {0}")]
    Replayed(u32),
    /// A sequence number below the last accepted one.
    #[error("out-of-order sequence number {got} after {last}")]
    OutOfOrder {
        /// The frame's number.
        got: u32,
        /// The last accepted number.
        last: u32,
    },
}

/// Counts of everything a [`Receiver`] rejected, by cause, and of frames it missed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counters {
    /// Frames accepted.
    pub accepted: u64,
    /// Shorter than their header says, or than a header.
    pub truncated: u64,
    /// A frame of a version other than [`VERSION`].
    pub wrong_version: u64,
    /// A tag that does not authenticate the frame (wrong key, stale session, corruption).
    pub unauthenticated: u64,
    /// Any other malformation (magic, type, length, payload fields).
    pub malformed: u64,
    /// Of a session other than the one in force.
    pub wrong_session: u64,
    /// Replayed (the last accepted sequence number again).
    pub replayed: u64,
    /// Out of order (below the last accepted sequence number).
    pub out_of_order: u64,
    /// Sequence numbers skipped between accepted frames (frames lost or still in flight).
    pub gaps: u64,
}

impl Counters {
    /// Every rejected frame, whatever the cause.
    pub fn rejected(&self) -> u64 {
        self.truncated
            + self.wrong_version
            + self.unauthenticated
            + self.malformed
            + self.wrong_session
            + self.replayed
            + self.out_of_order
    }

    /// Counts a decoding error under its cause.
    pub fn count(&mut self, e: DecodeError) {
        match e {
            DecodeError::Truncated(_) => self.truncated += 1,
            DecodeError::WrongVersion(_) => self.wrong_version += 1,
            DecodeError::BadTag => self.unauthenticated += 1,
            _ => self.malformed += 1,
        }
    }

    /// Adds `other`'s counts to these.
    pub fn add(&mut self, other: &Counters) {
        self.accepted += other.accepted;
        self.truncated += other.truncated;
        self.wrong_version += other.wrong_version;
        self.unauthenticated += other.unauthenticated;
        self.malformed += other.malformed;
        self.wrong_session += other.wrong_session;
        self.replayed += other.replayed;
        self.out_of_order += other.out_of_order;
        self.gaps += other.gaps;
    }
}

/// The receive side of one session: checks the tag under the session's key, decodes, checks
/// the session and the sequence number, and counts every rejection. A frame it returns is
/// authentic, new, in order, of the session and well formed.
#[derive(Debug, Clone)]
pub struct Receiver {
    /// The session in force.
    pub session: u32,
    /// The last accepted sequence number (0: none yet).
    pub last_sequence: u32,
    /// What was accepted and rejected.
    pub counters: Counters,
    key: TagKey,
}

impl Receiver {
    /// A receiver for frames of `session` tagged with `key`.
    pub fn new(session: u32, key: TagKey) -> Self {
        Self {
            session,
            last_sequence: 0,
            counters: Counters::default(),
            key,
        }
    }

    /// Decodes, authenticates and checks `bytes`; counts the outcome.
    pub fn accept(&mut self, bytes: &[u8]) -> Result<Frame, Rejection> {
        match Frame::peek(bytes) {
            Ok(h) if h.session != self.session => {
                // Not of this session: its tag is not ours to check.
                self.counters.wrong_session += 1;
                return Err(Rejection::WrongSession {
                    got: h.session,
                    expected: self.session,
                });
            }
            _ => {}
        }
        let frame = match Frame::decode(bytes, &self.key) {
            Ok(f) => f,
            Err(e) => {
                self.counters.count(e);
                return Err(e.into());
            }
        };
        self.check(&frame)?;
        Ok(frame)
    }

    /// Checks the session and sequence number of an authenticated frame; counts the outcome.
    pub fn check(&mut self, frame: &Frame) -> Result<(), Rejection> {
        if frame.session != self.session {
            self.counters.wrong_session += 1;
            return Err(Rejection::WrongSession {
                got: frame.session,
                expected: self.session,
            });
        }
        if frame.sequence == self.last_sequence {
            self.counters.replayed += 1;
            return Err(Rejection::Replayed(frame.sequence));
        }
        if frame.sequence < self.last_sequence {
            self.counters.out_of_order += 1;
            return Err(Rejection::OutOfOrder {
                got: frame.sequence,
                last: self.last_sequence,
            });
        }
        self.counters.gaps += u64::from(frame.sequence - self.last_sequence - 1);
        self.last_sequence = frame.sequence;
        self.counters.accepted += 1;
        Ok(())
    }
}

/// The send side of one session: numbers frames 1, 2, 3, ... and tags them.
#[derive(Debug, Clone)]
pub struct Sender {
    /// The session.
    pub session: u32,
    /// The sequence number of the last frame sent.
    pub sequence: u32,
    key: TagKey,
}

impl Sender {
    /// A sender for `session`, tagging with `key`.
    pub fn new(session: u32, key: TagKey) -> Self {
        Self {
            session,
            sequence: 0,
            key,
        }
    }

    /// The next frame with `payload`, encoded. A session never wraps its numbers: at the
    /// 2^32 - 1st frame (50 days at 1 kHz) the sender stays there and the receiver refuses
    /// further frames as replays; a new session is needed.
    pub fn frame(&mut self, payload: Payload) -> (u32, Vec<u8>) {
        self.sequence = self.sequence.saturating_add(1);
        let bytes = Frame {
            session: self.session,
            sequence: self.sequence,
            payload,
        }
        .encode(&self.key);
        (self.sequence, bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key() -> TagKey {
        TagKey::new(b"test key")
    }

    /// Re-tags a modified frame, so that the check under test is the one that fails.
    fn retag(b: &mut [u8]) {
        let n = b.len() - TAG_LEN;
        let t = key().tag(&b[..n]);
        b[n..].copy_from_slice(&t);
    }

    fn sample() -> Sample {
        Sample {
            request_sequence: 7,
            last_command_sequence: 6,
            server_time_us: 123_456,
            status: status::TEST_ENABLED | status::CLUTCH,
            safe_reason: 0,
            test_counts: -42,
            load_counts: 1 << 30,
            analog: [5.43, 0.245, 2.5, 2.6, 3.338, 6.674],
        }
    }

    fn all_payloads() -> Vec<Payload> {
        vec![
            Payload::Command(Command {
                test_set_value: 1.5,
                load_set_value: -0.25,
                test_enable: true,
                load_enable: false,
                clutch: true,
                test_kind: SetValueKind::Current,
                load_kind: SetValueKind::Voltage,
            }),
            Payload::Heartbeat,
            Payload::Sample(sample()),
            Payload::SafeState(SafeStateRequest {
                reason: reason::CLIENT_REQUEST,
            }),
            Payload::SafeStateAck(sample()),
            Payload::FaultInject(FaultInjection::DelayReplies {
                count: 3,
                delay_s: 0.004,
            }),
            Payload::FaultInject(FaultInjection::Force {
                channel: 1,
                volts: 9.5,
            }),
            Payload::FaultInject(FaultInjection::Stuck { channel: 7 }),
            Payload::FaultInject(FaultInjection::Duplicate {
                direction: LinkDirection::ToServer,
                count: 2,
            }),
            Payload::FaultInject(FaultInjection::Reorder {
                direction: LinkDirection::ToClient,
            }),
            Payload::FaultInject(FaultInjection::Corrupt {
                direction: LinkDirection::ToServer,
                count: 1,
            }),
            Payload::FaultInject(FaultInjection::Noise {
                channel: 0,
                volts: 0.002,
                seed: 7,
            }),
            Payload::FaultInject(FaultInjection::Offset {
                channel: 1,
                volts: -0.02,
            }),
            Payload::FaultInject(FaultInjection::DriverFault { driver: 1 }),
            Payload::FaultInject(FaultInjection::SupplyDrop {
                supply: 0,
                volts: 12.0,
            }),
            Payload::Hello(Hello {
                nonce: [3; 16],
                setup: BenchSetup {
                    configuration: 2,
                    test_kind: SetValueKind::Voltage,
                    load_kind: SetValueKind::Current,
                },
            }),
            Payload::Welcome(Welcome {
                client_nonce: [3; 16],
                server_nonce: [4; 16],
                latched: reason::EMERGENCY_STOP,
            }),
            Payload::Refuse(Refusal::new(
                refusal::SETUP,
                [3; 16],
                "configuration differs",
            )),
            Payload::Acknowledge(Acknowledge {
                reason: reason::HEARTBEAT_TIMEOUT,
            }),
        ]
    }

    #[test]
    fn fault_kinds_refuse_fields_out_of_range() {
        let refused = |kind, channel, value: f64, count| {
            FaultInjection::decode(kind, channel, value, count).is_err()
        };
        // Link faults: direction 0 or 1; reorder takes no count.
        assert!(refused(7, 2, 0.0, 1));
        assert!(refused(8, 0, 0.0, 1));
        assert!(refused(9, 0, 1.0, 1));
        // Noise: an analog channel, a finite sigma not negative.
        assert!(refused(10, 6, 0.1, 0));
        assert!(refused(10, 0, -0.1, 0));
        assert!(refused(10, 0, f64::NAN, 0));
        // Offset: finite, no count.
        assert!(refused(11, 0, f64::INFINITY, 0));
        assert!(refused(11, 0, 0.1, 3));
        // Driver and supply: 0 or 1; a supply of 0 to 100 V.
        assert!(refused(12, 2, 0.0, 0));
        assert!(refused(13, 0, 101.0, 0));
        assert!(refused(13, 0, -1.0, 0));
        assert!(refused(14, 0, 0.0, 0));
        assert_eq!(
            FaultInjection::decode(13, 1, 30.0, 0).unwrap(),
            FaultInjection::SupplyDrop {
                supply: 1,
                volts: 30.0
            }
        );
    }

    #[test]
    fn every_frame_type_round_trips() {
        for (k, payload) in all_payloads().into_iter().enumerate() {
            let f = Frame {
                session: 0xDEAD_BEEF,
                sequence: k as u32 + 1,
                payload,
            };
            let bytes = f.encode(&key());
            assert_eq!(
                bytes.len(),
                HEADER_LEN + payload.frame_type().payload_len() + TAG_LEN
            );
            assert!(bytes.len() <= MAX_FRAME_LEN);
            assert_eq!(Frame::decode(&bytes, &key()), Ok(f));
            assert_eq!(
                Frame::decode(&bytes, &TagKey::new(b"another key")),
                Err(DecodeError::BadTag)
            );
        }
    }

    #[test]
    fn header_is_big_endian() {
        let (_, bytes) = Sender::new(0x0102_0304, key()).frame(Payload::Heartbeat);
        assert_eq!(
            &bytes[..HEADER_LEN],
            &[b'K', b'N', b'B', b'P', 2, 2, 0, 0, 1, 2, 3, 4, 0, 0, 0, 1]
        );
    }

    fn rx_with_one_frame() -> (Receiver, Sender) {
        let mut tx = Sender::new(9, key());
        let mut rx = Receiver::new(9, key());
        let (_, b) = tx.frame(Payload::Heartbeat);
        rx.accept(&b).unwrap();
        (rx, tx)
    }

    #[test]
    fn truncated_frames_are_rejected_and_counted() {
        let (mut rx, mut tx) = rx_with_one_frame();
        let (_, b) = tx.frame(Payload::Sample(sample()));
        for n in 0..b.len() {
            assert!(rx.accept(&b[..n]).is_err());
        }
        assert_eq!(rx.counters.truncated, b.len() as u64);
        assert_eq!(rx.counters.accepted, 1);
        // The whole frame is still new: nothing was acted on.
        assert!(rx.accept(&b).is_ok());
    }

    #[test]
    fn malformed_frames_are_rejected_and_counted() {
        let (mut rx, mut tx) = rx_with_one_frame();
        let (_, good) = tx.frame(Payload::Command(Command::safe(
            SetValueKind::Current,
            SetValueKind::Current,
        )));
        let mut bad_magic = good.clone();
        bad_magic[0] ^= 0x20;
        let mut bad_tag = good.clone();
        bad_tag[HEADER_LEN] ^= 1;
        let mut long = good.clone();
        long.push(0);
        let mut bad_type = good.clone();
        bad_type[5] = 99;
        let mut reserved = good.clone();
        reserved[HEADER_LEN + 16] = 0x80;
        retag(&mut reserved);
        for (bytes, what) in [
            (&bad_magic, "magic"),
            (&bad_tag, "tag"),
            (&long, "length"),
            (&bad_type, "type"),
            (&reserved, "reserved bits"),
        ] {
            assert!(
                matches!(rx.accept(bytes), Err(Rejection::Malformed(_))),
                "{what}"
            );
        }
        assert_eq!(rx.counters.unauthenticated, 1);
        assert_eq!(rx.counters.malformed, 4);
        assert_eq!(rx.counters.accepted, 1);
    }

    #[test]
    fn wrong_version_is_rejected_and_counted() {
        let (mut rx, mut tx) = rx_with_one_frame();
        let (_, mut b) = tx.frame(Payload::Heartbeat);
        b[4] = 1;
        retag(&mut b);
        assert_eq!(
            rx.accept(&b),
            Err(Rejection::Malformed(DecodeError::WrongVersion(1)))
        );
        assert_eq!(rx.counters.wrong_version, 1);
    }

    #[test]
    fn replayed_and_out_of_order_frames_are_rejected_and_counted() {
        let mut tx = Sender::new(5, key());
        let mut rx = Receiver::new(5, key());
        let frames: Vec<Vec<u8>> = (0..4).map(|_| tx.frame(Payload::Heartbeat).1).collect();
        rx.accept(&frames[0]).unwrap();
        rx.accept(&frames[2]).unwrap();
        assert_eq!(rx.counters.gaps, 1);
        assert_eq!(rx.accept(&frames[2]), Err(Rejection::Replayed(3)));
        assert_eq!(
            rx.accept(&frames[1]),
            Err(Rejection::OutOfOrder { got: 2, last: 3 })
        );
        assert_eq!(
            rx.accept(&frames[0]),
            Err(Rejection::OutOfOrder { got: 1, last: 3 })
        );
        rx.accept(&frames[3]).unwrap();
        assert_eq!(rx.counters.replayed, 1);
        assert_eq!(rx.counters.out_of_order, 2);
        assert_eq!(rx.counters.accepted, 3);
        assert_eq!(rx.counters.rejected(), 3);
    }

    #[test]
    fn frames_of_another_session_are_rejected() {
        let mut rx = Receiver::new(5, key());
        let (_, b) = Sender::new(6, key()).frame(Payload::Heartbeat);
        assert!(matches!(
            rx.accept(&b),
            Err(Rejection::WrongSession { got: 6, .. })
        ));
        assert_eq!(rx.counters.wrong_session, 1);
        let zero = Frame {
            session: 5,
            sequence: 0,
            payload: Payload::Heartbeat,
        }
        .encode(&key());
        assert_eq!(
            rx.accept(&zero),
            Err(Rejection::Malformed(DecodeError::ZeroSequence))
        );
    }

    #[test]
    fn non_finite_values_are_malformed() {
        let f = Frame {
            session: 1,
            sequence: 1,
            payload: Payload::Command(Command {
                test_set_value: f64::NAN,
                ..Command::safe(SetValueKind::Voltage, SetValueKind::Voltage)
            }),
        };
        assert!(matches!(
            Frame::decode(&f.encode(&key()), &key()),
            Err(DecodeError::BadPayload(_))
        ));
    }

    /// xorshift64*: a fixed-seed generator for the robustness test (no dependency).
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
        }
        fn below(&mut self, n: usize) -> usize {
            (self.next() % n as u64) as usize
        }
    }

    #[test]
    fn random_and_mutated_bytes_never_panic_and_never_pass_unchecked() {
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
        let valid: Vec<Vec<u8>> = all_payloads()
            .into_iter()
            .enumerate()
            .map(|(k, payload)| {
                Frame {
                    session: 77,
                    sequence: k as u32 + 1,
                    payload,
                }
                .encode(&key())
            })
            .collect();
        let mut decoded_mutants = 0;
        for i in 0..20_000 {
            let bytes: Vec<u8> = if i % 2 == 0 {
                let n = rng.below(MAX_FRAME_LEN + 16);
                (0..n).map(|_| rng.next() as u8).collect()
            } else {
                let mut b = valid[rng.below(valid.len())].clone();
                for _ in 0..1 + rng.below(4) {
                    match rng.below(3) {
                        0 => {
                            let k = rng.below(b.len());
                            b[k] ^= 1 << rng.below(8);
                        }
                        1 => {
                            let k = rng.below(b.len() + 1);
                            b.truncate(k);
                            if b.is_empty() {
                                b.push(0);
                            }
                        }
                        _ => b.push(rng.next() as u8),
                    }
                }
                b
            };
            if valid.contains(&bytes) {
                continue;
            }
            if let Ok(f) = Frame::decode(&bytes, &key()) {
                // Anything that decodes must re-encode to the same bytes (no silent repair).
                assert_eq!(f.encode(&key()), bytes);
                decoded_mutants += 1;
            }
        }
        // A forged tag passes with probability 2^-128: no mutant may pass.
        assert_eq!(decoded_mutants, 0);
    }
}
