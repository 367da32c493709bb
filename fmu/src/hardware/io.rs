//! The bench's I/O behind one small trait, and its two backends.
//!
//! [`BenchIo`] is the bench controller's I/O seen from the control loop, in the spirit of
//! embedded-hal: it knows raw counts, raw volts and digital lines, nothing of calibration or
//! safety. Its unit of work is one control period: [`BenchIo::write`] sets both driver set
//! values, both enables and the clutch output together (held until the next write), and
//! [`BenchIo::read`] samples every input together (both encoder counters, the six analog
//! inputs, the emergency-stop line). Over a network the two are one frame each, which is why
//! the trait is not split per pin.
//!
//! * [`SimulatedBench`]: the plant physics in process ([`BenchPlant`]), giving the raw counts
//!   and volts of its sensor models. Time is the simulation's: `read(t)` advances the physics to
//!   `t` with the held command.
//! * [`UdpBench`]: a client of a real-time I/O server speaking the protocol of
//!   `docs/bench-protocol.md` ([`super::protocol`]). Time is the wall clock: `read` samples now.

use std::net::{SocketAddr, ToSocketAddrs, UdpSocket};
use std::time::{Duration, Instant};

use super::protocol::{
    ANALOG_CHANNELS, Acknowledge, AnalogChannel, BenchSetup, ClientHandshake, Command, Counters,
    FrameType, HandshakeReply, Key, MAX_FRAME_LEN, Payload, SafeStateRequest, Sample, Session,
    SetValueKind, VERSION, reason, refusal, status,
};
use super::realtime::{now_ns, wait_readable_until};
use crate::models::bench::{BenchInputs, BenchParameters, BenchPlant, DriverMode, Interlock};

/// An I/O failure: the bench did not answer, or answered wrongly.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum IoError {
    /// No valid answer within the timeout.
    #[error("no valid reply within {0:?}")]
    Timeout(Duration),
    /// The operating system refused a socket operation.
    #[error("socket: {0}")]
    Socket(String),
    /// The backend cannot be set up.
    #[error("backend setup: {0}")]
    Setup(String),
    /// The bench refused a command (for example a set-value kind its driver is not set up for).
    #[error("command refused: {0}")]
    Refused(String),
}

impl From<std::io::Error> for IoError {
    fn from(e: std::io::Error) -> Self {
        IoError::Socket(e.to_string())
    }
}

/// The bench's I/O for one control period at a time.
pub trait BenchIo: Send {
    /// Sets both set values, both enables and the clutch output (held until the next write);
    /// returns the command's identifier (its sequence number), which samples confirm.
    fn write(&mut self, t: f64, command: &Command) -> Result<u32, IoError>;

    /// Samples every input. `t` is the time of the sample relative to the start of the run
    /// (the simulated bench advances to it; a real bench samples now).
    fn read(&mut self, t: f64) -> Result<Sample, IoError>;

    /// Commands the safe state (set values zero, drivers disabled, clutch released, latched)
    /// and waits up to `timeout` for its acknowledgement; returns the acknowledging sample.
    fn enter_safe_state(
        &mut self,
        t: f64,
        reason: u8,
        timeout: Duration,
    ) -> Result<Sample, IoError>;

    /// Whether a sample's `server_time_us` is the bench's wall clock, so that the time between
    /// two samples is the difference of their timestamps (a real bench, the emulator), rather
    /// than the requested times (the in-process bench: false).
    fn timestamps_are_wall_time(&self) -> bool {
        false
    }

    /// Sets how long a sample is awaited (network backends; the in-process bench ignores it).
    fn set_reply_timeout(&mut self, _timeout: Duration) {}

    /// Frames rejected by the receive filter (zero for in-process backends).
    fn counters(&self) -> Counters {
        Counters::default()
    }

    /// Replies that arrived for an earlier request (late) and were ignored.
    fn stale_replies(&self) -> u64 {
        0
    }

    /// The [`reason`] of a safe state the bench was latched in when the session began (an
    /// earlier session's trip, its watchdog, the button), 0 for none. Only an explicit
    /// [`BenchIo::acknowledge`] clears it.
    fn latched(&self) -> u8 {
        reason::NONE
    }

    /// Acknowledges the latched safe state of reason `latch` (authenticated); returns the
    /// sample that answers it, which shows the safe state gone unless the bench keeps it (the
    /// emergency stop still pressed).
    fn acknowledge(&mut self, latch: u8) -> Result<Sample, IoError> {
        Err(IoError::Refused(format!(
            "nothing to acknowledge (latch reason {latch})"
        )))
    }
}

/// The set-value kind of a driver mode.
pub fn kind_of(mode: DriverMode) -> SetValueKind {
    match mode {
        DriverMode::Voltage => SetValueKind::Voltage,
        DriverMode::Current => SetValueKind::Current,
    }
}

/// The physics of the bench in process, seen through its raw sensors.
#[derive(Debug, Clone)]
pub struct SimulatedBench {
    plant: BenchPlant,
    command: Command,
    kinds: [SetValueKind; 2],
    last_command: u32,
    safe: Option<u8>,
}

impl SimulatedBench {
    /// A bench at rest with the plant parameters `params`.
    pub fn new(params: BenchParameters) -> Result<Self, IoError> {
        let kinds = [
            kind_of(params.test_driver_mode),
            kind_of(params.load_driver_mode),
        ];
        let plant = BenchPlant::new(params).map_err(|e| IoError::Setup(e.to_string()))?;
        Ok(Self {
            plant,
            command: Command::safe(kinds[0], kinds[1]),
            kinds,
            last_command: 0,
            safe: None,
        })
    }

    fn advance(&mut self, t: f64) -> Result<(), IoError> {
        let h = t - self.plant.time();
        if h <= 1e-12 * (1.0 + t.abs()) {
            return Ok(());
        }
        let c = &self.command;
        let inputs = BenchInputs {
            test_command: if c.test_enable { c.test_set_value } else { 0.0 },
            load_command: if c.load_enable { c.load_set_value } else { 0.0 },
            test_enable: c.test_enable,
            load_enable: c.load_enable,
            clutch_engage: c.clutch,
            emergency_stop: false,
        };
        if let crate::models::bench::StepOutcome::Rejected(e) = self.plant.step(&inputs, h) {
            return Err(IoError::Refused(e.to_string()));
        }
        Ok(())
    }

    fn sample(&self, request_sequence: u32) -> Sample {
        let o = self.plant.outputs();
        let mut analog = [0.0; ANALOG_CHANNELS];
        analog[AnalogChannel::LoadCell.index()] = o.load_cell_voltage;
        analog[AnalogChannel::Transducer.index()] = o.transducer_voltage;
        analog[AnalogChannel::TestCurrentSense.index()] = o.test_current_sense_voltage;
        analog[AnalogChannel::LoadCurrentSense.index()] = o.load_current_sense_voltage;
        analog[AnalogChannel::TestSupplySense.index()] = o.test_supply_sense_voltage;
        analog[AnalogChannel::LoadSupplySense.index()] = o.load_supply_sense_voltage;
        let mut bits = 0;
        let c = &self.command;
        for (on, bit) in [
            (c.test_enable, status::TEST_ENABLED),
            (c.load_enable, status::LOAD_ENABLED),
            (c.clutch, status::CLUTCH),
        ] {
            if on {
                bits |= bit;
            }
        }
        let mut safe_reason = self.safe.unwrap_or(reason::NONE);
        if let Some((interlock, _)) = self.plant.trip() {
            // The bench's own protection stopped it (a driver fault or the button).
            bits |= status::SERVER_TRIP | status::SAFE_STATE;
            if interlock == Interlock::EmergencyStop {
                bits |= status::EMERGENCY_STOP;
                safe_reason = reason::EMERGENCY_STOP;
            } else if safe_reason == reason::NONE {
                safe_reason = reason::BENCH_PROTECTION;
            }
        }
        if self.safe.is_some() {
            bits |= status::SAFE_STATE;
        }
        Sample {
            request_sequence,
            last_command_sequence: self.last_command,
            server_time_us: (self.plant.time() * 1e6).round() as u64,
            status: bits,
            safe_reason,
            // Wrapping 32-bit counters, as the bench's FPGA counters are.
            test_counts: o.actuation_encoder_counts as i64 as i32,
            load_counts: o.load_encoder_counts as i64 as i32,
            analog,
        }
    }
}

impl BenchIo for SimulatedBench {
    fn write(&mut self, t: f64, command: &Command) -> Result<u32, IoError> {
        self.advance(t)?;
        if [command.test_kind, command.load_kind] != self.kinds {
            return Err(IoError::Refused(
                "set-value kind differs from the drivers' mode".into(),
            ));
        }
        self.last_command += 1;
        if self.safe.is_none() {
            self.command = *command;
        }
        Ok(self.last_command)
    }

    fn read(&mut self, t: f64) -> Result<Sample, IoError> {
        self.advance(t)?;
        Ok(self.sample(0))
    }

    fn enter_safe_state(
        &mut self,
        t: f64,
        reason: u8,
        _timeout: Duration,
    ) -> Result<Sample, IoError> {
        self.advance(t)?;
        self.command = Command::safe(self.kinds[0], self.kinds[1]);
        self.safe.get_or_insert(reason);
        Ok(self.sample(0))
    }
}

/// How long the client waits for an answer to one HELLO before sending it again.
const HELLO_RESEND: Duration = Duration::from_millis(20);

/// A client of a bench I/O server over UDP, in an authenticated session.
#[derive(Debug)]
pub struct UdpBench {
    socket: UdpSocket,
    session: Session,
    reply_timeout: Duration,
    spin_ns: u64,
    stale: u64,
    buf: [u8; 2048],
}

/// What [`UdpBench::connect`] needs.
#[derive(Debug, Clone)]
pub struct UdpSetup {
    /// "host:port" of the server.
    pub address: String,
    /// The bench key; `None`: the public loopback key, allowed only towards a loopback
    /// address.
    pub key: Option<Key>,
    /// The bench setup the server must have.
    pub setup: BenchSetup,
    /// How long the handshake may take (a busy server is asked again until then).
    pub handshake_timeout: Duration,
    /// How long a reply is awaited.
    pub reply_timeout: Duration,
    /// The last part of each wait that is spun rather than slept.
    pub spin: Duration,
}

impl UdpBench {
    /// Opens an authenticated session with the server (`docs/bench-protocol.md`, §6).
    pub fn connect(setup: &UdpSetup) -> Result<Self, IoError> {
        let address = &setup.address;
        let server: SocketAddr = address
            .to_socket_addrs()
            .map_err(|e| IoError::Setup(format!("server address `{address}`: {e}")))?
            .next()
            .ok_or_else(|| {
                IoError::Setup(format!("server address `{address}` resolves to nothing"))
            })?;
        // No server listens on port 0: refused at once, not after the handshake timeout.
        if server.port() == 0 {
            return Err(IoError::Setup(format!(
                "server address `{address}`: port 0 is not a bench address"
            )));
        }
        let key = match &setup.key {
            Some(k) if k.weakness().is_none() || server.ip().is_loopback() => k.clone(),
            None if server.ip().is_loopback() => Key::loopback(),
            // A key that is no secret (the loopback key, say) authenticates nothing: as none.
            Some(_) | None => {
                return Err(IoError::Setup(format!(
                    "server {server} is not on this machine: a key file is needed (`kneebench key new FILE` on the bench; keyFile)"
                )));
            }
        };
        let local = if server.is_ipv4() {
            "0.0.0.0:0"
        } else {
            "[::]:0"
        };
        let socket = UdpSocket::bind(local)?;
        socket.connect(server)?;
        // The socket stays blocking (a full send buffer on a loaded machine delays a send
        // rather than failing it); receives wait in `ppoll` first, so they never block.
        #[cfg(not(target_os = "linux"))]
        socket.set_read_timeout(Some(Duration::from_micros(100)))?;
        let mut hs =
            ClientHandshake::new(&key, setup.setup).map_err(|e| IoError::Setup(e.to_string()))?;
        let spin_ns = u64::try_from(setup.spin.as_nanos()).unwrap_or(u64::MAX);
        let mut buf = [0u8; 2048];
        let end = now_ns() + duration_ns(setup.handshake_timeout);
        let mut busy: Option<String> = None;
        let mut last_send_error: Option<String> = None;
        while now_ns() < end {
            // An error an ICMP message may have caused (port unreachable: no server yet) is
            // a lost HELLO, sent again until the end; a local error fails at once.
            match socket.send(hs.hello()) {
                Ok(_) => {}
                Err(e) if datagram_lost(&e) => {
                    last_send_error = Some(e.to_string());
                }
                Err(e) => {
                    return Err(IoError::Setup(format!(
                        "sending the handshake to {server}: {e}"
                    )));
                }
            }
            let until = (now_ns() + duration_ns(HELLO_RESEND)).min(end);
            while let Some(n) = recv_until(&socket, &mut buf, until, spin_ns)? {
                match hs.receive(&buf[..n]) {
                    Ok(HandshakeReply::Welcome(session)) => {
                        return Ok(Self {
                            socket,
                            session: *session,
                            reply_timeout: setup.reply_timeout,
                            spin_ns,
                            stale: 0,
                            buf,
                        });
                    }
                    Ok(HandshakeReply::Refused(r)) if r.code == refusal::BUSY => {
                        // Another master's session is live: it may end (release or its
                        // watchdog) before our timeout.
                        busy = Some(r.text().to_owned());
                    }
                    Ok(HandshakeReply::Refused(r)) => {
                        return Err(IoError::Refused(format!(
                            "the bench at {server} refused the session: {}",
                            r.text()
                        )));
                    }
                    Err(_) => {}
                }
            }
        }
        Err(match busy {
            Some(text) => IoError::Refused(format!(
                "the bench at {server} refused the session for {:?}: {text}",
                setup.handshake_timeout
            )),
            None => IoError::Setup(format!(
                "no answer to the handshake from {server} within {:?}: the server is not running or not reachable, holds another key, or speaks another protocol version (this client speaks version {VERSION}); {} frames rejected{}",
                setup.handshake_timeout,
                hs.counters().rejected(),
                last_send_error
                    .map(|e| format!("; last network error: {e}"))
                    .unwrap_or_default()
            )),
        })
    }

    /// The session identifier.
    pub fn session(&self) -> u32 {
        self.session.tx.session
    }

    /// Sends `payload`, waits up to the reply timeout (an absolute deadline, kept to the
    /// microsecond whatever the kernel's tick: [`recv_until`]) for the reply of type `expect`
    /// to it.
    fn exchange(&mut self, payload: Payload, expect: FrameType) -> Result<Sample, IoError> {
        let (sequence, bytes) = self.session.tx.frame(payload);
        let deadline = now_ns() + duration_ns(self.reply_timeout);
        // A request lost to an ICMP-reported error is as lost on the network: only the
        // reply timeout below ends the wait.
        send_datagram(&self.socket, &bytes)?;
        loop {
            let Some(n) = recv_until(&self.socket, &mut self.buf, deadline, self.spin_ns)? else {
                return Err(IoError::Timeout(self.reply_timeout));
            };
            if n > MAX_FRAME_LEN {
                self.session.rx.counters.malformed += 1;
                continue;
            }
            let Ok(frame) = self.session.rx.accept(&self.buf[..n]) else {
                continue;
            };
            let sample = match (frame.payload, expect) {
                (Payload::Sample(s), FrameType::Sample)
                | (Payload::SafeStateAck(s), FrameType::SafeStateAck) => s,
                _ => {
                    self.stale += 1;
                    continue;
                }
            };
            if sample.request_sequence != sequence {
                self.stale += 1;
                continue;
            }
            return Ok(sample);
        }
    }
}

fn duration_ns(d: Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}

/// How many times a datagram is sent while each send fails with an error that an ICMP
/// message may have caused ([`icmp_caused`]). Each such error is reported once and consumed by
/// the call that reports it (without sending the datagram), so the second attempt normally
/// sends it; more attempts only cover ICMP messages arriving between the attempts.
const SEND_ATTEMPTS: usize = 4;

/// Whether a socket error on the connected UDP socket may have been caused by an ICMP (or
/// ICMPv6) error message rather than by this machine's configuration. Linux reports such a
/// message (a "hard" error: `udp_err`, `icmp_err_convert`, `icmpv6_err_convert`) to the next
/// send or receive on a connected socket, and anyone who can send IP packets to the client can
/// forge one (it needs only the addresses and ports): it proves nothing about the link. The
/// bench link therefore counts it as a lost datagram, never as a link failure by itself; the
/// reply timeout (the link watchdog) decides. The values:
///
/// * `ECONNREFUSED`: port unreachable (also: no server listening yet);
/// * `EHOSTUNREACH`: host unreachable, administratively prohibited, filtered, precedence,
///   ICMPv6 address unreachable, beyond scope, time exceeded;
/// * `ENETUNREACH`: network unknown or prohibited, ICMPv6 no route;
/// * `EHOSTDOWN`: host unknown; `ENONET`: host isolated; `ENOPROTOOPT`: protocol
///   unreachable; `EPROTO`: parameter problem;
/// * `EMSGSIZE`: fragmentation needed / packet too big (a frame of at most 116 bytes never
///   exceeds a link's MTU by itself);
/// * `EACCES`: ICMPv6 administratively prohibited, policy failure, reject route (a connected
///   socket got its local `EACCES`, broadcast without `SO_BROADCAST`, from `connect`).
///
/// `EHOSTUNREACH` and `ENETUNREACH` are also what a send gets locally when the route to the
/// server is gone; every datagram is then lost, and the reply timeout trips the link within
/// the period as it would for a cut cable. Every other error fails at once: they are local
/// (`ENETDOWN` an interface down, `EPERM` a firewall rule, `EADDRNOTAVAIL` the local address
/// gone, `ENOBUFS`, `EBADF`, `EINVAL`, ...) and no ICMP message produces them.
pub fn icmp_caused(e: &std::io::Error) -> bool {
    matches!(
        e.raw_os_error(),
        Some(
            libc::ECONNREFUSED
                | libc::EHOSTUNREACH
                | libc::ENETUNREACH
                | libc::EHOSTDOWN
                | libc::ENONET
                | libc::ENOPROTOOPT
                | libc::EPROTO
                | libc::EMSGSIZE
                | libc::EACCES
        )
    )
}

/// Whether a failed send or receive lost only the datagram at hand: an error an ICMP message
/// may have caused ([`icmp_caused`]), or a signal that interrupted the call.
fn datagram_lost(e: &std::io::Error) -> bool {
    icmp_caused(e) || e.kind() == std::io::ErrorKind::Interrupted
}

/// Sends `bytes` on the connected `socket`. An error an ICMP message may have caused
/// ([`icmp_caused`]) is consumed by the failing call, which did not send the datagram: the
/// send is tried again, up to `SEND_ATTEMPTS` (4) times. `Ok(true)`: sent; `Ok(false)`: lost
/// (every attempt failed so); `Err`: a local error.
pub fn send_datagram(socket: &UdpSocket, bytes: &[u8]) -> Result<bool, IoError> {
    for _ in 0..SEND_ATTEMPTS {
        match socket.send(bytes) {
            Ok(_) => return Ok(true),
            Err(e) if datagram_lost(&e) => {}
            Err(e) => return Err(e.into()),
        }
    }
    Ok(false)
}

/// Receives one datagram from the connected `socket` if one is there before the monotonic
/// clock reads `deadline_ns`: waits in `ppoll` until `spin_ns` before the deadline, then spins
/// (polling without waiting). A datagram already queued is read before the deadline is
/// checked, so one that arrived while a descheduled thread was not running is still read
/// (the slack is the thread's scheduling latency, not the kernel's tick); while the thread
/// runs, nothing that arrives after the deadline is read. An error an ICMP message may have
/// caused ([`icmp_caused`], e.g. a forged port unreachable) is no reply: the wait goes on.
/// `Ok(None)`: the deadline passed.
pub fn recv_until(
    socket: &UdpSocket,
    buf: &mut [u8],
    deadline_ns: u64,
    spin_ns: u64,
) -> Result<Option<usize>, IoError> {
    use std::os::fd::AsRawFd;
    let fd = socket.as_raw_fd();
    loop {
        let now = now_ns();
        let wait_until = if now < deadline_ns && deadline_ns - now > spin_ns {
            deadline_ns - spin_ns
        } else {
            // Past the deadline or in the spin: only look.
            0
        };
        if wait_readable_until(fd, wait_until) {
            match socket.recv(buf) {
                Ok(n) => return Ok(Some(n)),
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) || datagram_lost(&e) => {}
                Err(e) => return Err(e.into()),
            }
        }
        let now = now_ns();
        if now >= deadline_ns {
            return Ok(None);
        }
        if deadline_ns - now <= spin_ns {
            std::hint::spin_loop();
        }
    }
}

impl BenchIo for UdpBench {
    fn write(&mut self, _t: f64, command: &Command) -> Result<u32, IoError> {
        let (sequence, bytes) = self.session.tx.frame(Payload::Command(*command));
        // A command lost to an ICMP-reported error is as lost on the network: the sample of
        // the period does not confirm it, and that trips the link.
        send_datagram(&self.socket, &bytes)?;
        Ok(sequence)
    }

    fn read(&mut self, _t: f64) -> Result<Sample, IoError> {
        self.exchange(Payload::Heartbeat, FrameType::Sample)
    }

    fn enter_safe_state(
        &mut self,
        _t: f64,
        reason: u8,
        timeout: Duration,
    ) -> Result<Sample, IoError> {
        let start = Instant::now();
        loop {
            match self.exchange(
                Payload::SafeState(SafeStateRequest { reason }),
                FrameType::SafeStateAck,
            ) {
                Ok(ack) => return Ok(ack),
                Err(IoError::Timeout(_)) if start.elapsed() < timeout => continue,
                Err(IoError::Timeout(_)) => return Err(IoError::Timeout(timeout)),
                Err(e) if start.elapsed() < timeout => {
                    // A refused send (ICMP port unreachable) may pass: retry until the timeout.
                    let _ = e;
                    std::thread::sleep(self.reply_timeout);
                }
                Err(e) => return Err(e),
            }
        }
    }

    fn latched(&self) -> u8 {
        self.session.latched
    }

    fn acknowledge(&mut self, latch: u8) -> Result<Sample, IoError> {
        let s = self.exchange(
            Payload::Acknowledge(Acknowledge { reason: latch }),
            FrameType::Sample,
        )?;
        if !s.has(status::SAFE_STATE) {
            self.session.latched = reason::NONE;
        }
        Ok(s)
    }

    fn set_reply_timeout(&mut self, timeout: Duration) {
        self.reply_timeout = timeout;
    }

    fn timestamps_are_wall_time(&self) -> bool {
        true
    }

    fn counters(&self) -> Counters {
        self.session.rx.counters
    }

    fn stale_replies(&self) -> u64 {
        self.stale
    }
}

impl Drop for UdpBench {
    fn drop(&mut self) {
        // Release the bench at once rather than by the server's heartbeat timeout (best
        // effort: the server's watchdog covers a lost frame).
        let (_, bytes) = self.session.tx.frame(Payload::SafeState(SafeStateRequest {
            reason: reason::SESSION_END,
        }));
        let _ = self.socket.send(&bytes);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn simulated_bench_gives_raw_counts_and_volts_and_holds_the_safe_state() {
        let p = BenchParameters::default();
        let mut bench = SimulatedBench::new(p.clone()).unwrap();
        let s0 = bench.read(0.0).unwrap();
        assert_eq!((s0.test_counts, s0.load_counts), (0, 0));
        assert!((s0.analog[AnalogChannel::TestCurrentSense.index()] - 2.5).abs() < 1e-12);
        assert!(
            (s0.analog[AnalogChannel::TestSupplySense.index()] - (0.002 + 0.139 * 24.0)).abs()
                < 1e-12
        );
        let drive = Command {
            test_set_value: 2.0,
            load_set_value: 0.0,
            test_enable: true,
            load_enable: true,
            clutch: false,
            test_kind: SetValueKind::Current,
            load_kind: SetValueKind::Current,
        };
        assert_eq!(bench.write(0.0, &drive).unwrap(), 1);
        let s1 = bench.read(0.2).unwrap();
        assert_eq!(s1.last_command_sequence, 1);
        assert!(s1.test_counts > 100, "{s1:?}");
        assert!(s1.has(status::TEST_ENABLED));
        let ack = bench
            .enter_safe_state(0.2, reason::CLIENT_REQUEST, Duration::ZERO)
            .unwrap();
        assert!(ack.has(status::SAFE_STATE) && !ack.has(status::TEST_ENABLED));
        // A drive command after the safe state is not applied.
        bench.write(0.2, &drive).unwrap();
        assert!(!bench.read(0.3).unwrap().has(status::TEST_ENABLED));
        let voltage = Command {
            test_kind: SetValueKind::Voltage,
            ..drive
        };
        assert!(matches!(
            bench.write(0.3, &voltage),
            Err(IoError::Refused(_))
        ));
    }

    /// A minimal bench server on loopback for the client's tests: answers the HELLO, applies
    /// COMMANDs (confirmed by the samples), answers HEARTBEAT and SAFE_STATE, ends at the
    /// release or after 2 s of silence.
    fn serve_one_session(key: Key) -> (SocketAddr, std::thread::JoinHandle<u64>) {
        use super::super::protocol::{Frame, Receiver, Sender, Welcome};
        let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
        socket
            .set_read_timeout(Some(Duration::from_secs(2)))
            .unwrap();
        let address = socket.local_addr().unwrap();
        let handle = std::thread::spawn(move || {
            let mut buf = [0u8; 2048];
            let hk = key.handshake();
            let (n, peer) = socket.recv_from(&mut buf).unwrap();
            let hello = Frame::decode(&buf[..n], &hk).unwrap();
            let Payload::Hello(h) = hello.payload else {
                panic!("not a HELLO")
            };
            let ns = [7u8; 16];
            let (_, welcome) = Sender::new(hello.session, hk).frame(Payload::Welcome(Welcome {
                client_nonce: h.nonce,
                server_nonce: ns,
                latched: reason::NONE,
            }));
            socket.send_to(&welcome, peer).unwrap();
            let keys = key.session(hello.session, &h.nonce, &ns);
            let mut tx = Sender::new(hello.session, keys.server_to_client);
            tx.sequence = 1;
            let mut rx = Receiver::new(hello.session, keys.client_to_server);
            rx.last_sequence = 1;
            let mut last_command = 0;
            let mut answered = 0;
            while let Ok((n, from)) = socket.recv_from(&mut buf) {
                let Ok(f) = rx.accept(&buf[..n]) else {
                    continue;
                };
                let sample = |request_sequence| Sample {
                    request_sequence,
                    last_command_sequence: last_command,
                    ..Sample::default()
                };
                let reply = match f.payload {
                    Payload::Command(_) => {
                        last_command = f.sequence;
                        continue;
                    }
                    Payload::Heartbeat => Payload::Sample(sample(f.sequence)),
                    Payload::SafeState(r) if r.reason == reason::SESSION_END => break,
                    Payload::SafeState(_) => Payload::SafeStateAck(sample(f.sequence)),
                    _ => continue,
                };
                socket.send_to(&tx.frame(reply).1, from).unwrap();
                answered += 1;
            }
            answered
        });
        (address, handle)
    }

    /// Leaves a real ICMP error pending on the client's connected socket: the socket is
    /// connected for a moment to a closed loopback port and sends there, so that the kernel
    /// answers with an ICMP port unreachable, reported (`ECONNREFUSED`) to the next call on the
    /// socket, and is connected back to `server`. A forged ICMP message has the same effect.
    fn plant_port_unreachable(socket: &UdpSocket, server: SocketAddr) {
        let closed = UdpSocket::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap();
        socket.connect(closed).unwrap();
        socket.send(b"?").unwrap();
        std::thread::sleep(Duration::from_millis(2));
        socket.connect(server).unwrap();
    }

    #[test]
    fn an_icmp_error_is_a_lost_datagram_not_a_link_failure() {
        let key = Key::generate().unwrap();
        let (server, handle) = serve_one_session(key.clone());
        let mut bench = UdpBench::connect(&UdpSetup {
            address: server.to_string(),
            key: Some(key),
            setup: BenchSetup {
                configuration: 1,
                test_kind: SetValueKind::Current,
                load_kind: SetValueKind::Current,
            },
            handshake_timeout: Duration::from_secs(2),
            reply_timeout: Duration::from_millis(500),
            spin: Duration::ZERO,
        })
        .unwrap();
        let command = Command::safe(SetValueKind::Current, SetValueKind::Current);
        // The planted error is the kind a forged ICMP port unreachable leaves.
        plant_port_unreachable(&bench.socket, server);
        let e = bench
            .socket
            .take_error()
            .unwrap()
            .expect("an ICMP error pending");
        assert_eq!(e.kind(), std::io::ErrorKind::ConnectionRefused, "{e}");
        // One period after another as `BenchHardware`'s step runs them, with an ICMP error
        // reported to the command's send, to the heartbeat's send, to both: every write and
        // read succeeds and every sample confirms the period's command (no link trip).
        for period in 0..30 {
            if period % 3 != 1 {
                plant_port_unreachable(&bench.socket, server);
            }
            let seq = bench.write(0.0, &command).expect("write");
            if period % 3 != 0 {
                plant_port_unreachable(&bench.socket, server);
            }
            let sample = bench.read(0.0).expect("read");
            assert_eq!(sample.last_command_sequence, seq, "period {period}");
        }
        plant_port_unreachable(&bench.socket, server);
        let ack = bench
            .enter_safe_state(0.0, reason::CLIENT_REQUEST, Duration::from_secs(1))
            .unwrap();
        assert!(ack.request_sequence > 0);
        drop(bench);
        assert_eq!(handle.join().unwrap(), 31);
    }

    #[test]
    fn errors_of_icmp_messages_are_told_from_local_ones() {
        use std::io::Error;
        for e in [
            libc::ECONNREFUSED,
            libc::EHOSTUNREACH,
            libc::ENETUNREACH,
            libc::EHOSTDOWN,
            libc::ENONET,
            libc::ENOPROTOOPT,
            libc::EPROTO,
            libc::EMSGSIZE,
            libc::EACCES,
        ] {
            assert!(icmp_caused(&Error::from_raw_os_error(e)), "{e}");
        }
        for e in [
            libc::ENETDOWN,
            libc::EPERM,
            libc::EADDRNOTAVAIL,
            libc::ENOBUFS,
            libc::EBADF,
            libc::EINVAL,
            libc::ENOTCONN,
        ] {
            assert!(!icmp_caused(&Error::from_raw_os_error(e)), "{e}");
        }
        assert!(!icmp_caused(&Error::other("not an OS error")));
    }

    #[test]
    fn an_icmp_error_while_waiting_for_the_reply_is_no_reply() {
        let quiet = UdpSocket::bind("127.0.0.1:0").unwrap();
        let server = quiet.local_addr().unwrap();
        let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
        socket.connect(server).unwrap();
        plant_port_unreachable(&socket, server);
        let mut buf = [0u8; 64];
        let deadline = now_ns() + 20_000_000;
        assert_eq!(recv_until(&socket, &mut buf, deadline, 0), Ok(None));
        // A datagram after the error is still read.
        plant_port_unreachable(&socket, server);
        quiet
            .send_to(b"reply", socket.local_addr().unwrap())
            .unwrap();
        let deadline = now_ns() + 1_000_000_000;
        assert_eq!(recv_until(&socket, &mut buf, deadline, 0), Ok(Some(5)));
    }

    #[test]
    fn keyless_sessions_are_refused_towards_another_machine() {
        let setup = UdpSetup {
            address: "192.0.2.1:47000".into(),
            key: None,
            setup: BenchSetup {
                configuration: 0,
                test_kind: SetValueKind::Current,
                load_kind: SetValueKind::Current,
            },
            handshake_timeout: Duration::from_millis(10),
            reply_timeout: Duration::from_millis(1),
            spin: Duration::ZERO,
        };
        let e = UdpBench::connect(&setup).unwrap_err().to_string();
        assert!(e.contains("a key file is needed"), "{e}");
        // Nor with a key that is no secret.
        for key in [Key::loopback(), Key::from_bytes([0; 32])] {
            let setup = UdpSetup {
                key: Some(key),
                ..setup.clone()
            };
            let e = UdpBench::connect(&setup).unwrap_err().to_string();
            assert!(e.contains("a key file is needed"), "{e}");
        }
    }

    #[test]
    fn port_0_is_refused_before_the_handshake() {
        let setup = UdpSetup {
            address: "127.0.0.1:0".into(),
            key: None,
            setup: BenchSetup {
                configuration: 0,
                test_kind: SetValueKind::Current,
                load_kind: SetValueKind::Current,
            },
            handshake_timeout: Duration::from_secs(60),
            reply_timeout: Duration::from_millis(1),
            spin: Duration::ZERO,
        };
        let start = Instant::now();
        let e = UdpBench::connect(&setup).unwrap_err().to_string();
        assert!(start.elapsed() < Duration::from_secs(10));
        assert!(e.contains("port 0 is not a bench address"), "{e}");
    }

    #[test]
    fn a_silent_server_is_reported_after_the_handshake_timeout() {
        // A bound socket that never answers.
        let quiet = UdpSocket::bind("127.0.0.1:0").unwrap();
        let setup = UdpSetup {
            address: quiet.local_addr().unwrap().to_string(),
            key: None,
            setup: BenchSetup {
                configuration: 0,
                test_kind: SetValueKind::Current,
                load_kind: SetValueKind::Current,
            },
            handshake_timeout: Duration::from_millis(50),
            reply_timeout: Duration::from_millis(1),
            spin: Duration::ZERO,
        };
        let start = Instant::now();
        let e = UdpBench::connect(&setup).unwrap_err().to_string();
        assert!(start.elapsed() >= Duration::from_millis(50));
        assert!(e.contains("no answer to the handshake"), "{e}");
        assert!(e.contains("version 2"), "{e}");
    }
}
