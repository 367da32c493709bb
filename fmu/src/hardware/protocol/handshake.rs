//! The handshake that opens a session (`docs/bench-protocol.md`, §6): its frames' payloads,
//! the bench setup both sides must agree on, and the client's side of it, free of I/O.
//!
//! ```text
//! client                                              server
//! HELLO(session s, seq 1: nonce Nc, setup)   --->     checks the tag (handshake key), the
//!                                                     setup, that no other master is live
//!                                            <---     WELCOME(s, seq 1: Nc, Ns, latch)
//!                                                     or REFUSE(s, seq 1: code, Nc, text)
//! session keys from (key, s, Nc, Ns); every later frame is tagged with them
//! COMMAND / HEARTBEAT / ... (s, seq 2, 3, ...) --->   the first one that authenticates makes
//!                                                     s the live session
//! ```
//!
//! The HELLO's tag proves the client holds the key (junk and wrong keys are dropped before
//! any state is kept); the WELCOME's tag over the client's fresh nonce proves the server
//! holds it and is not a replay; the first session frame, tagged with keys that depend on the
//! server's fresh nonce, proves the client is live (a replayed HELLO never gets further).

use super::auth::{Key, KeyError, NONCE_LEN, TagKey};
use super::{
    DecodeError, Frame, Payload, Reader, Receiver, Rejection, Sender, SetValueKind, Writer, reason,
};

/// Payload length of a [`Hello`].
pub const HELLO_LEN: usize = NONCE_LEN + 4;
/// Payload length of a [`Welcome`].
pub const WELCOME_LEN: usize = 2 * NONCE_LEN + 4;
/// Bytes of a refusal's text.
pub const REFUSE_TEXT_LEN: usize = 64;
/// Payload length of a [`Refusal`].
pub const REFUSE_LEN: usize = 4 + NONCE_LEN + REFUSE_TEXT_LEN;
/// Payload length of an [`Acknowledge`].
pub const ACKNOWLEDGE_LEN: usize = 4;

/// Refusal codes (REFUSE byte 0).
pub mod refusal {
    /// The client speaks another protocol version (sent unauthenticated, see the protocol).
    pub const VERSION: u8 = 1;
    /// Another master's session is live.
    pub const BUSY: u8 = 2;
    /// The client's bench setup differs from the server's.
    pub const SETUP: u8 = 3;
    /// The highest defined code.
    pub const MAX: u8 = 3;
}

/// The actuator configuration and the drivers' modes: both sides must agree on them before
/// a single set value is sent (a current is never applied as a voltage, a controller tuned
/// for the spring never drives the rigid coupling).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BenchSetup {
    /// 0 DA, 1 SEA, 2 CSEA.
    pub configuration: u8,
    /// The test driver's mode.
    pub test_kind: SetValueKind,
    /// The load driver's mode.
    pub load_kind: SetValueKind,
}

fn configuration_name(c: u8) -> &'static str {
    match c {
        0 => "DA",
        1 => "SEA",
        2 => "CSEA",
        _ => "unknown",
    }
}

fn kind_name(k: SetValueKind) -> &'static str {
    match k {
        SetValueKind::Voltage => "Voltage",
        SetValueKind::Current => "Current",
    }
}

impl BenchSetup {
    /// The first setting in which `client` differs from this (the server's) setup, as a
    /// message naming it, or `None` when they agree.
    pub fn difference(&self, client: &BenchSetup) -> Option<String> {
        if self.configuration != client.configuration {
            return Some(format!(
                "configuration differs: bench {}, client {}",
                configuration_name(self.configuration),
                configuration_name(client.configuration)
            ));
        }
        for (name, bench, ours) in [
            ("testDriverMode", self.test_kind, client.test_kind),
            ("loadDriverMode", self.load_kind, client.load_kind),
        ] {
            if bench != ours {
                return Some(format!(
                    "{name} differs: bench {}, client {}",
                    kind_name(bench),
                    kind_name(ours)
                ));
            }
        }
        None
    }
}

/// HELLO: a client opens a handshake.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Hello {
    /// The client's fresh nonce.
    pub nonce: [u8; NONCE_LEN],
    /// The client's bench setup.
    pub setup: BenchSetup,
}

/// WELCOME: the server accepts a handshake.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Welcome {
    /// The client's nonce, echoed.
    pub client_nonce: [u8; NONCE_LEN],
    /// The server's fresh nonce.
    pub server_nonce: [u8; NONCE_LEN],
    /// The [`reason`] of the latched safe state the new session inherits (0: none).
    pub latched: u8,
}

/// REFUSE: the server refuses a handshake.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Refusal {
    /// A [`refusal`] code.
    pub code: u8,
    /// The client's nonce, echoed (zero in an unauthenticated version refusal).
    pub client_nonce: [u8; NONCE_LEN],
    /// UTF-8, zero-padded: why, naming the setting that differs.
    text: [u8; REFUSE_TEXT_LEN],
}

impl Refusal {
    /// A refusal with `text` (cut to [`REFUSE_TEXT_LEN`] bytes at a character boundary).
    pub fn new(code: u8, client_nonce: [u8; NONCE_LEN], text: &str) -> Self {
        let mut end = text.len().min(REFUSE_TEXT_LEN);
        while !text.is_char_boundary(end) {
            end -= 1;
        }
        let mut t = [0u8; REFUSE_TEXT_LEN];
        t[..end].copy_from_slice(&text.as_bytes()[..end]);
        Self {
            code,
            client_nonce,
            text: t,
        }
    }

    /// The text.
    pub fn text(&self) -> &str {
        let n = self
            .text
            .iter()
            .position(|&b| b == 0)
            .unwrap_or(REFUSE_TEXT_LEN);
        // Checked to be UTF-8 when decoded or built.
        std::str::from_utf8(&self.text[..n]).unwrap_or("")
    }
}

/// ACKNOWLEDGE: the client clears the latched safe state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Acknowledge {
    /// The [`reason`] of the latch acknowledged: must be the one in force.
    pub reason: u8,
}

fn setup_kind(v: u8) -> Result<SetValueKind, DecodeError> {
    SetValueKind::from_u8(v).ok_or(DecodeError::BadPayload("unknown driver mode"))
}

impl Hello {
    pub(super) fn encode(&self, w: &mut Writer) {
        w.bytes(&self.nonce);
        w.u8(self.setup.configuration);
        w.u8(self.setup.test_kind as u8);
        w.u8(self.setup.load_kind as u8);
        w.u8(0);
    }

    pub(super) fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        let nonce = r.take::<NONCE_LEN>();
        let configuration = r.u8();
        let test_kind = setup_kind(r.u8())?;
        let load_kind = setup_kind(r.u8())?;
        if r.u8() != 0 {
            return Err(DecodeError::BadPayload("reserved hello byte set"));
        }
        if configuration > 2 {
            return Err(DecodeError::BadPayload("unknown configuration"));
        }
        Ok(Self {
            nonce,
            setup: BenchSetup {
                configuration,
                test_kind,
                load_kind,
            },
        })
    }
}

impl Welcome {
    pub(super) fn encode(&self, w: &mut Writer) {
        w.bytes(&self.client_nonce);
        w.bytes(&self.server_nonce);
        w.u8(self.latched);
        w.u8(0);
        w.u16(0);
    }

    pub(super) fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        let client_nonce = r.take::<NONCE_LEN>();
        let server_nonce = r.take::<NONCE_LEN>();
        let latched = r.u8();
        if r.u8() != 0 || r.u16() != 0 {
            return Err(DecodeError::BadPayload("reserved welcome bytes set"));
        }
        if latched > reason::MAX || latched == reason::SESSION_END {
            return Err(DecodeError::BadPayload("unknown latch reason"));
        }
        Ok(Self {
            client_nonce,
            server_nonce,
            latched,
        })
    }
}

impl Refusal {
    pub(super) fn encode(&self, w: &mut Writer) {
        w.u8(self.code);
        w.u8(0);
        w.u16(0);
        w.bytes(&self.client_nonce);
        w.bytes(&self.text);
    }

    pub(super) fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        let code = r.u8();
        if r.u8() != 0 || r.u16() != 0 {
            return Err(DecodeError::BadPayload("reserved refusal bytes set"));
        }
        if code == 0 || code > refusal::MAX {
            return Err(DecodeError::BadPayload("unknown refusal code"));
        }
        let client_nonce = r.take::<NONCE_LEN>();
        let text = r.take::<REFUSE_TEXT_LEN>();
        let n = text.iter().position(|&b| b == 0).unwrap_or(REFUSE_TEXT_LEN);
        if text[n..].iter().any(|&b| b != 0) || std::str::from_utf8(&text[..n]).is_err() {
            return Err(DecodeError::BadPayload(
                "refusal text is not zero-padded UTF-8",
            ));
        }
        Ok(Self {
            code,
            client_nonce,
            text,
        })
    }
}

impl Acknowledge {
    pub(super) fn encode(&self, w: &mut Writer) {
        w.u8(self.reason);
        w.u8(0);
        w.u16(0);
    }

    pub(super) fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        let reason_code = r.u8();
        if r.u8() != 0 || r.u16() != 0 {
            return Err(DecodeError::BadPayload(
                "reserved acknowledgement bytes set",
            ));
        }
        if reason_code == reason::NONE
            || reason_code == reason::SESSION_END
            || reason_code > reason::MAX
        {
            return Err(DecodeError::BadPayload("unknown latch reason"));
        }
        Ok(Self {
            reason: reason_code,
        })
    }
}

/// An established session, client side: frames out under the client-to-server key, frames in
/// under the server-to-client key.
#[derive(Debug, Clone)]
pub struct Session {
    /// Numbers and tags the client's frames.
    pub tx: Sender,
    /// Authenticates and filters the server's frames.
    pub rx: Receiver,
    /// The latched safe state the session began with (a [`reason`], 0: none).
    pub latched: u8,
}

/// What the server answered to a HELLO.
#[derive(Debug, Clone)]
pub enum HandshakeReply {
    /// The session is established.
    Welcome(Box<Session>),
    /// The server refused it.
    Refused(Refusal),
}

/// The client's side of a handshake.
#[derive(Debug, Clone)]
pub struct ClientHandshake {
    key: Key,
    handshake: TagKey,
    session: u32,
    nonce: [u8; NONCE_LEN],
    hello: Vec<u8>,
    counters: super::Counters,
}

impl ClientHandshake {
    /// A handshake for a new random session with `setup`, under `key`.
    pub fn new(key: &Key, setup: BenchSetup) -> Result<Self, KeyError> {
        let mut s = [0u8; 4];
        let session = loop {
            super::auth::random_bytes(&mut s)?;
            let v = u32::from_be_bytes(s);
            if v != 0 {
                break v;
            }
        };
        Ok(Self::with_nonce(key, setup, session, super::auth::nonce()?))
    }

    /// A handshake with a given session number (nonzero) and nonce: for tests and fuzzing,
    /// which need it reproducible. A real client draws both at random ([`Self::new`]): a
    /// reused nonce lets an old WELCOME be replayed.
    pub fn with_nonce(key: &Key, setup: BenchSetup, session: u32, nonce: [u8; NONCE_LEN]) -> Self {
        let session = session.max(1);
        let handshake = key.handshake();
        let hello = Frame {
            session,
            sequence: 1,
            payload: Payload::Hello(Hello { nonce, setup }),
        }
        .encode(&handshake);
        Self {
            key: key.clone(),
            counters: super::Counters::default(),
            handshake,
            session,
            nonce,
            hello,
        }
    }

    /// The session number.
    pub fn session(&self) -> u32 {
        self.session
    }

    /// The HELLO datagram (the same bytes on every resend).
    pub fn hello(&self) -> &[u8] {
        &self.hello
    }

    /// Frames rejected so far.
    pub fn counters(&self) -> super::Counters {
        self.counters
    }

    /// Reads a datagram from the server: a WELCOME or a REFUSE answering this HELLO. Anything
    /// else (another session's, unauthenticated, an answer to another nonce) is rejected and
    /// counted. The echoed nonce, fresh for this handshake, is what makes an answer new (the
    /// server numbers both answers 1).
    pub fn receive(&mut self, bytes: &[u8]) -> Result<HandshakeReply, Rejection> {
        let header = Frame::peek(bytes).inspect_err(|&e| self.counters.count(e))?;
        if header.session != self.session {
            self.counters.wrong_session += 1;
            return Err(Rejection::WrongSession {
                got: header.session,
                expected: self.session,
            });
        }
        let frame =
            Frame::decode(bytes, &self.handshake).inspect_err(|&e| self.counters.count(e))?;
        match frame.payload {
            Payload::Welcome(w) if w.client_nonce == self.nonce => {
                self.counters.accepted += 1;
                let keys = self.key.session(self.session, &self.nonce, &w.server_nonce);
                let mut tx = Sender::new(self.session, keys.client_to_server);
                tx.sequence = 1;
                let mut rx = Receiver::new(self.session, keys.server_to_client);
                rx.last_sequence = frame.sequence;
                rx.counters = self.counters;
                Ok(HandshakeReply::Welcome(Box::new(Session {
                    tx,
                    rx,
                    latched: w.latched,
                })))
            }
            Payload::Refuse(r) if r.client_nonce == self.nonce => {
                self.counters.accepted += 1;
                Ok(HandshakeReply::Refused(r))
            }
            _ => {
                self.counters.malformed += 1;
                Err(Rejection::Malformed(DecodeError::BadPayload(
                    "not an answer to this handshake",
                )))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Command, FrameType, MAX_FRAME_LEN};
    use super::*;

    fn setup() -> BenchSetup {
        BenchSetup {
            configuration: 1,
            test_kind: SetValueKind::Current,
            load_kind: SetValueKind::Current,
        }
    }

    /// The server's side, as the emulator does it, for the client's handshake.
    fn welcome(key: &Key, hello: &[u8], latched: u8) -> (Vec<u8>, Sender, Receiver) {
        let hk = key.handshake();
        let f = Frame::decode(hello, &hk).unwrap();
        let Payload::Hello(h) = f.payload else {
            panic!()
        };
        let ns = [9u8; NONCE_LEN];
        let bytes = Sender::new(f.session, hk).frame(Payload::Welcome(Welcome {
            client_nonce: h.nonce,
            server_nonce: ns,
            latched,
        }));
        let keys = key.session(f.session, &h.nonce, &ns);
        let mut tx = Sender::new(f.session, keys.server_to_client);
        tx.sequence = 1;
        let mut rx = Receiver::new(f.session, keys.client_to_server);
        rx.last_sequence = 1;
        (bytes.1, tx, rx)
    }

    #[test]
    fn handshake_derives_matching_session_keys_and_carries_the_latch() {
        let key = Key::generate().unwrap();
        let mut c = ClientHandshake::new(&key, setup()).unwrap();
        assert_eq!(c.hello(), c.hello());
        let (w, mut server_tx, mut server_rx) = welcome(&key, c.hello(), reason::HEARTBEAT_TIMEOUT);
        let HandshakeReply::Welcome(mut s) = c.receive(&w).unwrap() else {
            panic!()
        };
        assert_eq!(s.latched, reason::HEARTBEAT_TIMEOUT);
        let (seq, cmd) = s.tx.frame(Payload::Command(Command::safe(
            SetValueKind::Current,
            SetValueKind::Current,
        )));
        assert_eq!(seq, 2);
        assert!(server_rx.accept(&cmd).is_ok());
        // A replay of the client's frame, and the same frame offered to the client, fail.
        assert_eq!(server_rx.accept(&cmd), Err(Rejection::Replayed(2)));
        let mut reflected = s.rx.clone();
        assert!(matches!(
            reflected.accept(&cmd),
            Err(Rejection::Malformed(DecodeError::BadTag))
        ));
        let (_, hb) = server_tx.frame(Payload::Heartbeat);
        assert!(s.rx.accept(&hb).is_ok());
        // The welcome again (resent by the server for a lost one) gives the same keys: the
        // nonce makes it this handshake's answer, not a new session.
        let HandshakeReply::Welcome(again) = c.receive(&w).unwrap() else {
            panic!()
        };
        let (_, hb2) = server_tx.frame(Payload::Heartbeat);
        assert!(again.rx.clone().accept(&hb2).is_ok());
        // Another handshake's welcome (another session number) is not.
        let other = ClientHandshake::new(&key, setup()).unwrap();
        let (w2, _, _) = welcome(&key, other.hello(), 0);
        assert!(matches!(
            c.receive(&w2),
            Err(Rejection::WrongSession { .. })
        ));
    }

    #[test]
    fn a_welcome_under_another_key_or_for_another_nonce_is_rejected() {
        let key = Key::generate().unwrap();
        let mut c = ClientHandshake::new(&key, setup()).unwrap();
        let other = Key::generate().unwrap();
        // The server holds another key: it cannot even read the hello.
        assert_eq!(
            Frame::decode(c.hello(), &other.handshake()),
            Err(DecodeError::BadTag)
        );
        // A welcome tagged by a server with another key.
        let forged = Sender::new(c.session(), other.handshake()).frame(Payload::Welcome(Welcome {
            client_nonce: [0; NONCE_LEN],
            server_nonce: [1; NONCE_LEN],
            latched: 0,
        }));
        assert!(matches!(
            c.receive(&forged.1),
            Err(Rejection::Malformed(DecodeError::BadTag))
        ));
        // An authentic welcome of an earlier handshake (another nonce).
        let earlier = ClientHandshake::new(&key, setup()).unwrap();
        let (w, _, _) = welcome(&key, earlier.hello(), 0);
        let mut w2 = w.clone();
        // Same session number as ours, to reach the nonce check.
        w2[8..12].copy_from_slice(&c.session().to_be_bytes());
        let n = w2.len() - 16;
        let tag = key.handshake().tag(&w2[..n]);
        w2[n..].copy_from_slice(&tag);
        assert!(c.receive(&w2).is_err());
        assert_eq!(c.counters().unauthenticated, 1);
    }

    #[test]
    fn a_refusal_names_the_setting_that_differs() {
        let bench = setup();
        assert_eq!(bench.difference(&bench), None);
        let e = bench
            .difference(&BenchSetup {
                configuration: 0,
                ..bench
            })
            .unwrap();
        assert_eq!(e, "configuration differs: bench SEA, client DA");
        let e = bench
            .difference(&BenchSetup {
                load_kind: SetValueKind::Voltage,
                ..bench
            })
            .unwrap();
        assert_eq!(e, "loadDriverMode differs: bench Current, client Voltage");
        let key = Key::generate().unwrap();
        let mut c = ClientHandshake::new(&key, setup()).unwrap();
        let f = Frame::decode(c.hello(), &key.handshake()).unwrap();
        let Payload::Hello(h) = f.payload else {
            panic!()
        };
        let r = Refusal::new(refusal::SETUP, h.nonce, &e);
        let (_, bytes) = Sender::new(c.session(), key.handshake()).frame(Payload::Refuse(r));
        assert!(bytes.len() <= MAX_FRAME_LEN);
        match c.receive(&bytes).unwrap() {
            HandshakeReply::Refused(r) => {
                assert_eq!(r.code, refusal::SETUP);
                assert_eq!(r.text(), e);
            }
            other => panic!("{other:?}"),
        }
        // Long texts are cut at a character boundary.
        let long = "é".repeat(40);
        let r = Refusal::new(refusal::BUSY, [0; NONCE_LEN], &long);
        assert_eq!(r.text().len(), 64);
        assert_eq!(FrameType::Refuse.payload_len(), REFUSE_LEN);
    }
}
