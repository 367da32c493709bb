//! The master's side of an isolated FMU: the host process (a Unix socket pair as its standard
//! input and output), its watchdog, and the instance proxy that batches the master's calls.
//!
//! # Batching
//!
//! A step of the master is "set the inputs, `fmi2DoStep`, get the outputs". The proxy sends it
//! as one request:
//!
//! - **sets are queued**: `fmi2Set*` answers `fmi2OK` at once and is sent with the next call
//!   that needs an answer. When the FMU then refuses it, that later call reports the error, named
//!   after the set (`fmi2SetReal returned Error ...`); an `fmi2Discard` of a queued set is not
//!   reported (the master does not act on it either).
//! - **reads are prefetched**: the reads (`fmi2GetReal/Integer/Boolean`) the master made after
//!   the previous `fmi2DoStep` are made again right after this one, in the same request, and
//!   answered from that copy while nothing else was called. A read that differs from the
//!   pattern is a request of its own.
//!
//! So the steady state is one round trip per instance and step.

use std::io::{self, Read};
use std::os::fd::{AsRawFd, OwnedFd};
use std::os::unix::net::UnixStream;
use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use super::protocol::*;
use super::{HOST_ARG, HostFailure};
use crate::fmi2::fmi2StatusCode;
use crate::instance::{LogContext, LogMessage, LogStatus};
use crate::load::{LoadError, OPTIONAL_FUNCTIONS};

/// The reading room of a master's socket buffer (it grows for longer frames).
const READ_CHUNK: usize = 64 * 1024;

/// A running host process and the socket to it.
pub(crate) struct Process {
    child: Child,
    /// The master's end of the socket pair (the host has the other end as its standard input
    /// and output); `None` once closed.
    sock: Option<UnixStream>,
    /// Bytes read and not yet consumed: `rbuf[rpos..rend]`. The rest of `rbuf` is room for the
    /// next read, zeroed once when the buffer grows (not per read: a step reads every time).
    rbuf: Vec<u8>,
    rpos: usize,
    rend: usize,
    /// The payload of the last reply.
    reply: Vec<u8>,
    timeout: Duration,
    dead: Option<HostFailure>,
}

/// Waits until `fd` is ready for `events` or the deadline passes (false then).
fn wait_fd(fd: i32, events: i16, deadline: Instant) -> io::Result<bool> {
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Ok(false);
        }
        let ms = left.as_millis().clamp(1, i32::MAX as u128) as i32;
        let mut p = libc::pollfd {
            fd,
            events,
            revents: 0,
        };
        // SAFETY: one valid pollfd.
        let n = unsafe { libc::poll(&mut p, 1, ms) };
        if n < 0 {
            let e = io::Error::last_os_error();
            if e.kind() == io::ErrorKind::Interrupted {
                continue;
            }
            return Err(e);
        }
        if n > 0 {
            return Ok(true);
        }
    }
}

impl Process {
    /// Starts `helper` as an FMU host.
    pub(crate) fn spawn(helper: &Path, timeout: Duration) -> Result<Process, HostFailure> {
        // A socket pair rather than pipes: the master sends with MSG_NOSIGNAL, so a host that
        // died between two calls is an error of the next call, never a SIGPIPE (which
        // `kneebench` leaves at its default action, terminating).
        let start = |e: io::Error| HostFailure::Start(e.to_string());
        let (sock, theirs) = UnixStream::pair().map_err(start)?;
        let theirs_out = theirs.try_clone().map_err(start)?;
        let mut command = Command::new(helper);
        command
            .arg(HOST_ARG)
            .stdin(Stdio::from(OwnedFd::from(theirs)))
            .stdout(Stdio::from(OwnedFd::from(theirs_out)))
            .stderr(Stdio::inherit());
        // The host stays in the master's process group (a terminal's Ctrl-Z stops both) but
        // ignores SIGINT, SIGTERM and SIGHUP, which a terminal or `kill -INT -PGID` sends to
        // the whole group: the master handles them (it stops at the next communication point
        // and keeps the rows) and its hosts must live until then; they die with the master
        // (PR_SET_PDEATHSIG) or when it closes their socket. Set before exec, so there is no
        // window in which the host still has the default action.
        // SAFETY: the closure runs between fork and exec and calls only signal(2), which is
        // async-signal-safe; SIG_IGN is a valid disposition for these signals.
        unsafe {
            command.pre_exec(|| {
                for signal in [libc::SIGINT, libc::SIGTERM, libc::SIGHUP] {
                    if libc::signal(signal, libc::SIG_IGN) == libc::SIG_ERR {
                        return Err(io::Error::last_os_error());
                    }
                }
                Ok(())
            });
        }
        let child = command
            .spawn()
            .map_err(|e| HostFailure::Start(format!("cannot start '{}': {e}", helper.display())))?;
        sock.set_nonblocking(true).map_err(start)?;
        Ok(Process {
            child,
            sock: Some(sock),
            rbuf: vec![0; READ_CHUNK],
            rpos: 0,
            rend: 0,
            reply: Vec::new(),
            timeout,
            dead: None,
        })
    }

    /// Sends a complete frame and waits (at most the call timeout) for the reply, whose payload
    /// (after the kind byte) is then in `self.reply`. Log frames on the way go to `log`.
    pub(crate) fn round_trip(
        &mut self,
        frame: &[u8],
        log: &mut dyn FnMut(LogMessage),
    ) -> Result<(), HostFailure> {
        if let Some(d) = &self.dead {
            return Err(d.clone());
        }
        let deadline = Instant::now() + self.timeout;
        match self.exchange(frame, deadline, log) {
            Ok(()) => Ok(()),
            Err(Exchange::Timeout) => {
                let _ = self.child.kill();
                let _ = self.child.wait();
                Err(self.set_dead(HostFailure::Timeout(self.timeout)))
            }
            Err(Exchange::Closed) => {
                let f = self.reap();
                Err(self.set_dead(f))
            }
            Err(Exchange::Protocol(m)) => {
                let _ = self.child.kill();
                let _ = self.child.wait();
                Err(self.set_dead(HostFailure::Protocol(m)))
            }
        }
    }

    fn set_dead(&mut self, f: HostFailure) -> HostFailure {
        self.dead = Some(f.clone());
        f
    }

    /// The process closed its end: how it ended (killed when it does not end within a second).
    fn reap(&mut self) -> HostFailure {
        let until = Instant::now() + Duration::from_secs(1);
        loop {
            match self.child.try_wait() {
                Ok(Some(status)) => {
                    return match (status.signal(), status.code()) {
                        (Some(signal), _) => HostFailure::Signal(signal),
                        (None, Some(code)) => HostFailure::Exit(code),
                        (None, None) => HostFailure::Protocol(format!("ended: {status}")),
                    };
                }
                Ok(None) if Instant::now() < until => std::thread::sleep(Duration::from_millis(2)),
                _ => {
                    let _ = self.child.kill();
                    let _ = self.child.wait();
                    return HostFailure::Protocol(
                        "closed its socket without ending (killed)".into(),
                    );
                }
            }
        }
    }

    fn exchange(
        &mut self,
        frame: &[u8],
        deadline: Instant,
        log: &mut dyn FnMut(LogMessage),
    ) -> Result<(), Exchange> {
        let fd = self.sock.as_ref().ok_or(Exchange::Closed)?.as_raw_fd();
        let mut sent = 0;
        while sent < frame.len() {
            let rest = &frame[sent..];
            // SAFETY: a valid buffer of `rest.len()` bytes on our socket.
            let n = unsafe { libc::send(fd, rest.as_ptr().cast(), rest.len(), libc::MSG_NOSIGNAL) };
            if n > 0 {
                sent += n as usize;
                continue;
            }
            let e = io::Error::last_os_error();
            match e.kind() {
                io::ErrorKind::WouldBlock => {
                    if !wait_fd(fd, libc::POLLOUT, deadline).map_err(|_| Exchange::Closed)? {
                        return Err(Exchange::Timeout);
                    }
                }
                io::ErrorKind::Interrupted => {}
                _ => return Err(Exchange::Closed),
            }
        }
        let mut from = self.sock.as_ref().ok_or(Exchange::Closed)?;
        loop {
            // Every complete frame in the buffer.
            while self.rend - self.rpos >= 4 {
                let at = self.rpos;
                let len = u32::from_le_bytes(self.rbuf[at..at + 4].try_into().expect("4")) as usize;
                if len == 0 || len > MAX_FRAME {
                    return Err(Exchange::Protocol(format!("a frame of {len} bytes")));
                }
                if self.rend - at - 4 < len {
                    break;
                }
                let payload = &self.rbuf[at + 4..at + 4 + len];
                self.rpos = at + 4 + len;
                match payload[0] {
                    FRAME_REPLY => {
                        self.reply.clear();
                        self.reply.extend_from_slice(&payload[1..]);
                        if self.rpos == self.rend {
                            self.rpos = 0;
                            self.rend = 0;
                        }
                        return Ok(());
                    }
                    FRAME_LOG => log(decode_log(&payload[1..]).map_err(|e| {
                        Exchange::Protocol(format!("a malformed log message: {e}"))
                    })?),
                    k => return Err(Exchange::Protocol(format!("a frame of kind {k}"))),
                }
            }
            // The start of a frame moves to the front; a full buffer grows (a frame is at most
            // MAX_FRAME bytes, so it grows to at most twice that).
            if self.rpos > 0 {
                self.rbuf.copy_within(self.rpos..self.rend, 0);
                self.rend -= self.rpos;
                self.rpos = 0;
            }
            if self.rend == self.rbuf.len() {
                self.rbuf.resize(2 * self.rbuf.len(), 0);
            }
            // Wait first: right after a request its answer is not there yet, and a read would
            // only say so (one system call less per round trip).
            if !wait_fd(fd, libc::POLLIN, deadline).map_err(|_| Exchange::Closed)? {
                return Err(Exchange::Timeout);
            }
            match from.read(&mut self.rbuf[self.rend..]) {
                Ok(0) => return Err(Exchange::Closed),
                Ok(n) => self.rend += n,
                Err(e) => match e.kind() {
                    io::ErrorKind::WouldBlock | io::ErrorKind::Interrupted => {}
                    _ => return Err(Exchange::Closed),
                },
            }
        }
    }
}

impl Drop for Process {
    /// Closes the sending half of the socket (the host then terminates and frees its instance and exits) and
    /// waits for the process, at most the call timeout, then kills it.
    fn drop(&mut self) {
        let Some(sock) = self.sock.take() else {
            return;
        };
        // Our sending half closes; the host reads end of file.
        let _ = sock.shutdown(std::net::Shutdown::Write);
        if self.dead.is_some() {
            return;
        }
        let until = Instant::now() + self.timeout;
        loop {
            match self.child.try_wait() {
                Ok(Some(_)) => return,
                Ok(None) if Instant::now() < until => {
                    // Wait for the host to close its end (it exits right after).
                    let _ = wait_fd(
                        sock.as_raw_fd(),
                        libc::POLLIN,
                        Instant::now() + Duration::from_millis(20),
                    );
                    let mut sink = [0u8; 4096];
                    while let Ok(n) = (&sock).read(&mut sink) {
                        if n == 0 {
                            break;
                        }
                    }
                }
                _ => {
                    let _ = self.child.kill();
                    let _ = self.child.wait();
                    return;
                }
            }
        }
    }
}

enum Exchange {
    Timeout,
    Closed,
    Protocol(String),
}

fn decode_log(b: &[u8]) -> Result<LogMessage, ProtocolError> {
    let mut d = Dec::new(b);
    let status = LogStatus::from_c(std::ffi::c_int::from(d.u8()?));
    Ok(LogMessage {
        status,
        instance: d.string()?,
        category: d.string()?,
        message: d.string()?,
    })
}

/// What the host reported when it loaded the binary.
pub(crate) struct Probe {
    pub(crate) version: String,
    pub(crate) types_platform: String,
    pub(crate) missing_optional: Vec<&'static str>,
}

/// Starts a host and loads `binary` in it.
pub(crate) fn load(
    helper: &Path,
    timeout: Duration,
    binary: &Path,
    preload: &[PathBuf],
    keep_python_thread_state: bool,
) -> Result<(Process, Probe), LoadError> {
    let host_err = |failure| LoadError::Host {
        binary: binary.to_path_buf(),
        failure,
    };
    let mut p = Process::spawn(helper, timeout).map_err(host_err)?;
    let mut e = Enc::frame(REQ_LOAD);
    e.str(&binary.to_string_lossy());
    e.u32(preload.len() as u32);
    for l in preload {
        e.str(&l.to_string_lossy());
    }
    e.u8(u8::from(keep_python_thread_state));
    p.round_trip(e.finish(), &mut |m| eprintln!("{m}"))
        .map_err(host_err)?;
    let bad = |e: ProtocolError| LoadError::Host {
        binary: binary.to_path_buf(),
        failure: HostFailure::Protocol(e.0),
    };
    let mut d = Dec::new(&p.reply);
    match d.u8().map_err(bad)? {
        0 => {
            let version = d.string().map_err(bad)?;
            let types_platform = d.string().map_err(bad)?;
            let n = d.u32().map_err(bad)?;
            let mut missing_optional = Vec::new();
            for _ in 0..n {
                let name = d.string().map_err(bad)?;
                if let Some(s) = OPTIONAL_FUNCTIONS.iter().find(|s| **s == name) {
                    missing_optional.push(*s);
                }
            }
            Ok((
                p,
                Probe {
                    version,
                    types_platform,
                    missing_optional,
                },
            ))
        }
        1 => {
            let name = d.string().map_err(bad)?;
            let name = crate::load::REQUIRED_FUNCTIONS
                .iter()
                .find(|s| **s == name)
                .copied()
                .unwrap_or("an FMI function");
            Err(LoadError::MissingFunction { name })
        }
        _ => Err(LoadError::HostLoad {
            binary: binary.to_path_buf(),
            message: d.string().map_err(bad)?,
        }),
    }
}

/// Why a call of a remote instance did not give a status.
#[derive(Debug)]
pub(crate) enum RemoteFail {
    /// A queued call (a set) failed with this status.
    Call {
        function: &'static str,
        code: fmi2StatusCode,
    },
    /// The host died or broke the protocol during `function`.
    Host {
        function: &'static str,
        queued: usize,
        failure: HostFailure,
    },
}

/// One read made ahead, answered from here until anything else is called.
struct Cached {
    op: u8,
    vrs: (usize, usize),
    code: i32,
    values: (usize, usize),
    used: bool,
}

/// An instance living in a host process.
pub(crate) struct RemoteInstance {
    proc: Process,
    /// The batch being collected (frame header and count written on sending).
    pending: Enc,
    pending_ops: Vec<u8>,
    /// The reads made since the last `fmi2DoStep` (the first `observed_len` are this step's).
    observed: Vec<(u8, Vec<u32>)>,
    observed_len: usize,
    cache: Vec<Cached>,
    cache_vrs: Vec<u32>,
    cache_reals: Vec<f64>,
    cache_ints: Vec<i32>,
}

impl RemoteInstance {
    /// Instantiates in `proc` (which has the binary loaded). `Ok(None)`: `fmi2Instantiate`
    /// returned NULL.
    pub(crate) fn instantiate(
        mut proc: Process,
        name: &str,
        guid: &str,
        resource_uri: &str,
        visible: bool,
        logging_on: bool,
        ctx: &LogContext,
    ) -> Result<Option<RemoteInstance>, HostFailure> {
        let mut e = Enc::frame(REQ_INSTANTIATE);
        e.str(name);
        e.str(guid);
        e.str(resource_uri);
        e.u8(visible as u8);
        e.u8(logging_on as u8);
        proc.round_trip(e.finish(), &mut |m| ctx.deliver(m))?;
        let ok = Dec::new(&proc.reply)
            .u8()
            .map_err(|e| HostFailure::Protocol(e.0))?;
        if ok == 0 {
            return Ok(None);
        }
        Ok(Some(RemoteInstance {
            proc,
            pending: Enc::frame(REQ_BATCH),
            pending_ops: Vec::new(),
            observed: Vec::new(),
            observed_len: 0,
            cache: Vec::new(),
            cache_vrs: Vec::new(),
            cache_reals: Vec::new(),
            cache_ints: Vec::new(),
        }))
    }

    fn push(&mut self, op: u8, flags: u8, args: impl FnOnce(&mut Enc)) {
        if self.pending_ops.is_empty() {
            self.pending.reset(REQ_BATCH);
            self.pending.u32(0);
        }
        self.pending.u8(op);
        self.pending.u8(flags);
        args(&mut self.pending);
        self.pending_ops.push(op);
    }

    /// Queues a set (answered at the next call that needs an answer).
    pub(crate) fn queue(&mut self, op: u8, args: impl FnOnce(&mut Enc)) {
        self.drop_cache();
        self.push(op, 0, args);
    }

    /// Sends the queued calls and `op`; `decode` reads `op`'s results. With `prefetch`, the
    /// reads observed after the previous step are made after `op` (and cached).
    pub(crate) fn call<T>(
        &mut self,
        ctx: &LogContext,
        op: u8,
        args: impl FnOnce(&mut Enc),
        prefetch: bool,
        decode: impl FnOnce(&mut Dec<'_>) -> Result<T, ProtocolError>,
    ) -> Result<(fmi2StatusCode, T), RemoteFail> {
        self.drop_cache();
        self.push(op, 0, args);
        let main = self.pending_ops.len() - 1;
        if prefetch {
            for k in 0..self.observed_len {
                let (o, vrs) = std::mem::take(&mut self.observed[k]);
                self.push(o, FLAG_SPECULATIVE, |e| e.u32s(&vrs));
                self.observed[k] = (o, vrs);
            }
            self.observed_len = 0;
        }
        let n = self.pending_ops.len() as u32;
        self.pending.buf[5..9].copy_from_slice(&n.to_le_bytes());
        let ops = std::mem::take(&mut self.pending_ops);
        let r = self
            .proc
            .round_trip(self.pending.finish(), &mut |m| ctx.deliver(m));
        let queued = main;
        let result = match r {
            Err(failure) => Err(RemoteFail::Host {
                function: call_name(op),
                queued,
                failure,
            }),
            Ok(()) => self.decode_reply(&ops, main, decode).map_err(|e| match e {
                ReplyError::Call { function, code } => RemoteFail::Call { function, code },
                ReplyError::Protocol(m) => RemoteFail::Host {
                    function: call_name(op),
                    queued,
                    failure: HostFailure::Protocol(m),
                },
            }),
        };
        self.pending_ops = ops;
        self.pending_ops.clear();
        result
    }

    fn decode_reply<T>(
        &mut self,
        ops: &[u8],
        main: usize,
        decode: impl FnOnce(&mut Dec<'_>) -> Result<T, ProtocolError>,
    ) -> Result<(fmi2StatusCode, T), ReplyError> {
        let reply = std::mem::take(&mut self.proc.reply);
        let r = (|| {
            let mut d = Dec::new(&reply);
            let done = d.u32()? as usize;
            if done > ops.len() {
                return Err(ReplyError::Protocol(format!(
                    "{done} results for {} calls",
                    ops.len()
                )));
            }
            for &op in &ops[..done.min(main)] {
                let code = d.i32()?;
                if !(0..=2).contains(&code) {
                    return Err(ReplyError::Call {
                        function: call_name(op),
                        code: fmi2StatusCode(code),
                    });
                }
            }
            if done <= main {
                return Err(ReplyError::Protocol(
                    "the host stopped before the call".into(),
                ));
            }
            let code = d.i32()?;
            let value = decode(&mut d)?;
            for (k, &op) in ops.iter().enumerate().take(done).skip(main + 1) {
                let c = d.i32()?;
                let (o, vrs) = &self.observed[k - main - 1];
                debug_assert_eq!(*o, op);
                let v0 = self.cache_vrs.len();
                self.cache_vrs.extend_from_slice(vrs);
                let vrs = (v0, self.cache_vrs.len());
                let values = if op == CALL_GET_REAL {
                    let a = self.cache_reals.len();
                    self.cache_reals.extend(d.f64s()?);
                    (a, self.cache_reals.len())
                } else {
                    let a = self.cache_ints.len();
                    self.cache_ints.extend(d.i32s()?);
                    (a, self.cache_ints.len())
                };
                self.cache.push(Cached {
                    op,
                    vrs,
                    code: c,
                    values,
                    used: false,
                });
            }
            Ok((fmi2StatusCode(code), value))
        })();
        self.proc.reply = reply;
        r
    }

    /// Records a read the master made (the pattern prefetched after the next step).
    fn observe(&mut self, op: u8, vrs: &[u32]) {
        let k = self.observed_len;
        match self.observed.get(k) {
            Some((o, v)) if *o == op && v == vrs => {}
            _ => {
                self.observed.truncate(k);
                self.observed.push((op, vrs.to_vec()));
            }
        }
        self.observed_len += 1;
    }

    /// A Real read: from the prefetched copy when it has it.
    pub(crate) fn get_real(
        &mut self,
        ctx: &LogContext,
        vrs: &[u32],
        out: &mut [f64],
    ) -> Result<fmi2StatusCode, RemoteFail> {
        self.observe(CALL_GET_REAL, vrs);
        if let Some(c) = self.take_cached(CALL_GET_REAL, vrs) {
            out.copy_from_slice(&self.cache_reals[c.1.0..c.1.1]);
            return Ok(fmi2StatusCode(c.0));
        }
        self.call(
            ctx,
            CALL_GET_REAL,
            |e| e.u32s(vrs),
            false,
            |d| d.f64s_into(out),
        )
        .map(|r| r.0)
    }

    /// An Integer or Boolean read (`op`): from the prefetched copy when it has it.
    pub(crate) fn get_ints(
        &mut self,
        ctx: &LogContext,
        op: u8,
        vrs: &[u32],
        out: &mut [i32],
    ) -> Result<fmi2StatusCode, RemoteFail> {
        self.observe(op, vrs);
        if let Some(c) = self.take_cached(op, vrs) {
            out.copy_from_slice(&self.cache_ints[c.1.0..c.1.1]);
            return Ok(fmi2StatusCode(c.0));
        }
        self.call(ctx, op, |e| e.u32s(vrs), false, |d| d.i32s_into(out))
            .map(|r| r.0)
    }

    fn take_cached(&mut self, op: u8, vrs: &[u32]) -> Option<(i32, (usize, usize))> {
        let cache_vrs = &self.cache_vrs;
        let c = self
            .cache
            .iter_mut()
            .find(|c| !c.used && c.op == op && &cache_vrs[c.vrs.0..c.vrs.1] == vrs)?;
        c.used = true;
        Some((c.code, c.values))
    }

    /// Forgets the prefetched reads (the storage is reused).
    fn drop_cache(&mut self) {
        self.cache.clear();
        self.cache_vrs.clear();
        self.cache_reals.clear();
        self.cache_ints.clear();
    }
}

enum ReplyError {
    Call {
        function: &'static str,
        code: fmi2StatusCode,
    },
    Protocol(String),
}

impl From<ProtocolError> for ReplyError {
    fn from(e: ProtocolError) -> Self {
        ReplyError::Protocol(e.0)
    }
}

/// The loaded-but-not-yet-instantiated host of a probe, reused by the first instantiation.
pub(crate) struct RemoteFmu {
    pub(crate) helper: PathBuf,
    pub(crate) timeout: Duration,
    pub(crate) binary: PathBuf,
    pub(crate) preload: Vec<PathBuf>,
    /// [`PythonThreadState::Kept`](crate::load::PythonThreadState::Kept), passed to each host.
    pub(crate) keep_python_thread_state: bool,
    pub(crate) probe: Probe,
    pub(crate) spare: Mutex<Option<Process>>,
}

impl RemoteFmu {
    /// A process with the binary loaded: the probe's, or a new one.
    pub(crate) fn process(&self) -> Result<Process, LoadError> {
        if let Some(p) = self.spare.lock().unwrap_or_else(|p| p.into_inner()).take() {
            return Ok(p);
        }
        load(
            &self.helper,
            self.timeout,
            &self.binary,
            &self.preload,
            self.keep_python_thread_state,
        )
        .map(|(p, _)| p)
    }
}
