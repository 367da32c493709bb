//! The emulator's side of the link (protocol §6-§7): handshakes (HELLO, WELCOME, the
//! refusals and the per-address answer budget), the session frames of the live master, and the
//! actions they ask for. The plant behind it (advancing, sampling, the safe state, injected
//! faults) is in the parent module.

use super::*;

impl Server {
    fn begin_session(&mut self, p: Pending) -> Result<(), EmulatorError> {
        let plant = match self.ready.take() {
            Some(plant) => plant,
            None => self.prepare()?,
        };
        if let Some(old) = self.session.take() {
            self.rejected_before.add(&old.rx.counters);
        }
        let now = Instant::now();
        let mut tx = Sender::new(p.session, p.keys.server_to_client);
        // The WELCOME was the server's frame 1.
        tx.sequence = 1;
        let mut rx = Receiver::new(p.session, p.keys.client_to_server);
        // The HELLO was the client's frame 1.
        rx.last_sequence = 1;
        self.session = Some(Session {
            id: p.session,
            peer: p.peer,
            rx,
            tx,
            plant,
            plant_time: 0.0,
            origin: now,
            last_valid: now,
            held: Command::safe(self.kinds[0], self.kinds[1]),
            last_command: 0,
            safe_requested: false,
            server_trip: false,
            ended: false,
            expired: false,
        });
        self.stats.sessions += 1;
        self.stats.session = p.session;
        self.stats.commands_applied = 0;
        self.stats.drive_commands_in_safe_state = 0;
        self.stats.drive_commands_after_safe_request = 0;
        self.stats.plant_trip = None;
        self.stats.plant_time = 0.0;
        self.stats.largest_frame_gap = 0.0;
        let bench_fault = if self.emergency_stop {
            Some(reason::EMERGENCY_STOP)
        } else if self.driver_fault.contains(&true) {
            Some(reason::BENCH_PROTECTION)
        } else {
            None
        };
        if let Some(why) = bench_fault {
            if let Some(s) = self.session.as_mut() {
                s.server_trip = true;
            }
            self.enter_safe(why)?;
        }
        Ok(())
    }

    /// Logs a refused frame, at most one line a second (the rest are counted in the line).
    fn log_refusal(&mut self, what: &dyn std::fmt::Display, from: SocketAddr) {
        if !self.config.log_rejections {
            return;
        }
        let now = Instant::now();
        match self.log.0 {
            Some(last) if now.duration_since(last) < Duration::from_secs(1) => self.log.1 += 1,
            _ => {
                let more = std::mem::take(&mut self.log.1);
                eprintln!(
                    "kneebench emulate: refused a frame from {from}: {what} ({more} more refused since the last report)"
                );
                self.stats.log_lines += 1;
                self.log.0 = Some(now);
            }
        }
    }

    /// Whether a handshake answer may go to `to` now (and counts it): a token bucket per
    /// source IP address ([`HANDSHAKE_ANSWERS_PER_SOURCE`]). A HELLO over budget is dropped
    /// and counted in [`EmulatorStats::handshakes_dropped`].
    fn answer_allowed(&mut self, to: SocketAddr) -> bool {
        let now = Instant::now();
        let budgets = &mut self.answer_budgets;
        if budgets.len() >= MAX_ANSWER_BUDGETS && !budgets.contains_key(&to.ip()) {
            // Forget the budgets that have refilled (idle for a second), else all of them
            // (failing open: a flood from many addresses must not lock out a new master).
            budgets.retain(|_, (t, _)| now.duration_since(*t) < Duration::from_secs(1));
            if budgets.len() >= MAX_ANSWER_BUDGETS {
                budgets.clear();
            }
        }
        let (last, tokens) = budgets
            .entry(to.ip())
            .or_insert((now, HANDSHAKE_ANSWERS_PER_SOURCE));
        *tokens = (*tokens
            + now.duration_since(*last).as_secs_f64() * HANDSHAKE_ANSWERS_PER_SOURCE)
            .min(HANDSHAKE_ANSWERS_PER_SOURCE);
        *last = now;
        if *tokens < 1.0 {
            self.stats.handshakes_dropped += 1;
            return false;
        }
        *tokens -= 1.0;
        true
    }

    fn send_handshake(&mut self, session: u32, payload: Payload, to: SocketAddr) {
        let (_, bytes) = Sender::new(session.max(1), self.handshake.clone()).frame(payload);
        self.outbox.push((bytes, to));
    }

    /// A frame of another version: answered with an unauthenticated REFUSE saying which
    /// version this server speaks, at most [`VERSION_REFUSALS_PER_SECOND`] a second.
    fn refuse_version(&mut self, got: u8, bytes: &[u8], from: SocketAddr) {
        self.log_refusal(&DecodeError::WrongVersion(got), from);
        let now = Instant::now();
        if now.duration_since(self.version_budget.0) >= Duration::from_secs(1) {
            self.version_budget = (now, 0);
        }
        if self.version_budget.1 >= VERSION_REFUSALS_PER_SECOND {
            return;
        }
        self.version_budget.1 += 1;
        self.stats.version_refusals += 1;
        let session = bytes
            .get(8..12)
            .map(|b| u32::from_be_bytes([b[0], b[1], b[2], b[3]]))
            .unwrap_or(0);
        let text = format!("protocol version {got} refused: this server speaks version {VERSION}");
        let mut frame = Frame {
            session: session.max(1),
            sequence: 1,
            payload: Payload::Refuse(Refusal::new(refusal::VERSION, [0; NONCE_LEN], &text)),
        }
        .encode_body();
        // Unauthenticated (the peer's key is not known to be ours): a zero tag.
        frame.extend_from_slice(&[0; TAG_LEN]);
        self.outbox.push((frame, from));
    }

    /// Handles one datagram; returns whether it was acted on (a session frame accepted or a
    /// handshake answered), so that the statistics are published before the reply.
    pub(super) fn handle(&mut self, bytes: &[u8], from: SocketAddr) -> Result<bool, EmulatorError> {
        let header = match Frame::peek(bytes) {
            Ok(h) => h,
            Err(DecodeError::WrongVersion(v)) => {
                self.rejected.wrong_version += 1;
                self.refuse_version(v, bytes, from);
                return Ok(!self.outbox.is_empty());
            }
            Err(e) => {
                self.rejected.count(e);
                self.log_refusal(&e, from);
                return Ok(false);
            }
        };
        if self.silent {
            return Ok(false);
        }
        if header.frame_type == FrameType::Hello {
            self.on_hello(bytes, header, from);
            return Ok(!self.outbox.is_empty());
        }
        let before = self.stats.faults_injected + self.rejected.accepted;
        let accepted = self.session.as_ref().map_or(0, |s| s.rx.counters.accepted);
        self.on_session_frame(bytes, header, from)?;
        let after = self.stats.faults_injected + self.rejected.accepted;
        let accepted_now = self.session.as_ref().map_or(0, |s| s.rx.counters.accepted);
        Ok(accepted_now != accepted || after != before || !self.outbox.is_empty())
    }

    fn on_hello(&mut self, bytes: &[u8], header: Header, from: SocketAddr) {
        let frame = match Frame::decode(bytes, &self.handshake) {
            Ok(f) => f,
            Err(e) => {
                self.rejected.count(e);
                self.log_refusal(&format!("handshake: {e}"), from);
                return;
            }
        };
        let Payload::Hello(hello) = frame.payload else {
            return;
        };
        let now = Instant::now();
        self.pending
            .retain(|p| now.duration_since(p.created) < PENDING_LIFETIME);
        // A HELLO is not fresh (it carries no time): an authentic one may be a replay, of a
        // handshake in progress or of an old one, from any address. None may evict or
        // disturb a half-open handshake (protocol §6.3).
        if let Some(p) = self
            .pending
            .iter()
            .find(|p| p.session == header.session && p.client_nonce == hello.nonce)
        {
            if p.peer == from {
                // The same HELLO again (our WELCOME was lost): the same WELCOME.
                let welcome = p.welcome.clone();
                if self.answer_allowed(from) {
                    self.outbox.push((welcome, from));
                }
            } else {
                self.stats.replayed_hellos += 1;
                self.log_refusal(
                    &"handshake: a HELLO already answered to another address (a replay)",
                    from,
                );
            }
            return;
        }
        if !self.answer_allowed(from) {
            self.log_refusal(&"handshake: answer budget of the address spent", from);
            return;
        }
        if let Some(diff) = self.setup.difference(&hello.setup) {
            self.stats.setup_refusals += 1;
            self.log_refusal(&format!("handshake: {diff}"), from);
            let r = Refusal::new(refusal::SETUP, hello.nonce, &diff);
            self.send_handshake(frame.session, Payload::Refuse(r), from);
            return;
        }
        if self.live() {
            self.stats.busy_refusals += 1;
            self.log_refusal(&"handshake while another master's session is live", from);
            let r = Refusal::new(
                refusal::BUSY,
                hello.nonce,
                "another master's session is live (until its release or watchdog)",
            );
            self.send_handshake(frame.session, Payload::Refuse(r), from);
            return;
        }
        let server_nonce = match nonce() {
            Ok(n) => n,
            Err(e) => {
                eprintln!("kneebench emulate: {e}; handshake not answered");
                return;
            }
        };
        let (_, welcome) =
            Sender::new(frame.session, self.handshake.clone()).frame(Payload::Welcome(Welcome {
                client_nonce: hello.nonce,
                server_nonce,
                latched: self.latch.unwrap_or(reason::NONE),
            }));
        let of_source = self
            .pending
            .iter()
            .filter(|p| p.peer.ip() == from.ip())
            .count();
        if self.pending.len() >= MAX_PENDING || of_source >= MAX_PENDING_PER_SOURCE {
            // Never evict a half-open handshake: the new one waits for room (its client
            // sends its HELLO again).
            self.stats.handshakes_dropped += 1;
            self.log_refusal(&"handshake: too many half-open handshakes", from);
            return;
        }
        self.outbox.push((welcome.clone(), from));
        self.pending.push_back(Pending {
            session: frame.session,
            peer: from,
            client_nonce: hello.nonce,
            keys: self.key.session(frame.session, &hello.nonce, &server_nonce),
            welcome,
            created: now,
        });
    }

    fn on_session_frame(
        &mut self,
        bytes: &[u8],
        header: Header,
        from: SocketAddr,
    ) -> Result<(), EmulatorError> {
        let current = self
            .session
            .as_ref()
            .is_some_and(|s| s.id == header.session);
        let frame = if current {
            let Some(s) = self.session.as_mut() else {
                return Ok(());
            };
            if from != s.peer {
                self.stats.foreign_frames += 1;
                self.log_refusal(&"a frame of the session from another address", from);
                return Ok(());
            }
            let accepted = s.rx.accept(bytes);
            match accepted {
                Ok(f) => f,
                Err(e) => {
                    self.log_refusal(&e, from);
                    return Ok(());
                }
            }
        } else if self.pending.iter().any(|p| p.session == header.session) {
            // Half-open handshakes are told apart by session number and source address (a
            // replayed HELLO may have made one of the same number for another address).
            let Some(i) = self
                .pending
                .iter()
                .position(|p| p.session == header.session && p.peer == from)
            else {
                self.stats.foreign_frames += 1;
                self.log_refusal(&"a frame of a handshake from another address", from);
                return Ok(());
            };
            let frame = match Frame::decode(bytes, &self.pending[i].keys.client_to_server) {
                Ok(f) => f,
                Err(e) => {
                    self.rejected.count(e);
                    self.log_refusal(&e, from);
                    return Ok(());
                }
            };
            if self.live() {
                // Another master completed its handshake first.
                self.stats.busy_refusals += 1;
                self.log_refusal(&"a new session while another master's is live", from);
                return Ok(());
            }
            if let Some(p) = self.pending.remove(i) {
                self.begin_session(p)?;
            }
            let Some(s) = self.session.as_mut() else {
                return Ok(());
            };
            if let Err(e) = s.rx.check(&frame) {
                self.log_refusal(&e, from);
                return Ok(());
            }
            frame
        } else {
            // An old session's frame, a stranger's, or a forged session number.
            self.rejected.wrong_session += 1;
            self.log_refusal(&"a frame of no session in force", from);
            return Ok(());
        };
        if let Some(s) = self.session.as_mut() {
            let now = Instant::now();
            let gap = now.duration_since(s.last_valid).as_secs_f64();
            self.stats.largest_frame_gap = self.stats.largest_frame_gap.max(gap);
            s.last_valid = now;
            self.stats.last_valid_time = s.last_valid.duration_since(s.origin).as_secs_f64();
        }
        self.act(frame)
    }

    /// Acts on an authenticated, new frame of the current session.
    fn act(&mut self, frame: Frame) -> Result<(), EmulatorError> {
        self.advance()?;
        let Some(s) = self.session.as_mut() else {
            return Ok(());
        };
        match frame.payload {
            Payload::Command(c) => {
                if self.latch.is_some() || s.ended || s.expired {
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
                    self.stats.commands_applied_total += 1;
                    if c.drives() {
                        self.stats.drive_commands_applied_total += 1;
                        if self.stats.heartbeats_at_first_drive.is_none() {
                            self.stats.heartbeats_at_first_drive = Some(self.stats.heartbeats_seen);
                        }
                    }
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
                if r.reason == reason::SESSION_END {
                    s.ended = true;
                }
                self.enter_safe(r.reason)?;
                let sample = self.sample(frame.sequence)?;
                self.stats.safe_state_acks += 1;
                self.reply(Payload::SafeStateAck(sample));
            }
            Payload::Acknowledge(a) => {
                let plant_tripped = self.stats.plant_trip.is_some();
                if self.latch == Some(a.reason)
                    && !self.emergency_stop
                    && !self.driver_fault.contains(&true)
                    && !plant_tripped
                    && !s.ended
                    && !s.expired
                {
                    self.latch = None;
                    s.server_trip = false;
                    s.safe_requested = false;
                    self.stats.acknowledgements += 1;
                    self.stats.safe_since = None;
                    self.stats.latched_at = None;
                } else {
                    self.stats.acknowledgements_refused += 1;
                }
                let sample = self.sample(frame.sequence)?;
                self.stats.samples_sent += 1;
                self.reply(Payload::Sample(sample));
            }
            Payload::FaultInject(_) if self.config.refuse_fault_frames => {
                self.stats.fault_frames_refused += 1;
                let peer = s.peer;
                self.log_refusal(&"a fault-injection frame (this server refuses them)", peer);
            }
            Payload::FaultInject(f) => self.apply_fault(f),
            Payload::Sample(_)
            | Payload::SafeStateAck(_)
            | Payload::Hello(_)
            | Payload::Welcome(_)
            | Payload::Refuse(_) => {
                // Server-to-client frames are not acted on.
                self.rejected.malformed += 1;
            }
        }
        Ok(())
    }
}
