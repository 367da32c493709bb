//! The FMU host process: loads one FMU binary, runs one instance, executes the master's batches
//! of FMI calls (see [`protocol`](super::protocol)).
//!
//! Standard output is the reply channel: it is moved to a private descriptor first and
//! descriptor 1 is pointed at standard error, so that an FMU printing to `stdout` cannot corrupt
//! the protocol. The host asks the kernel to kill it when the master dies
//! (`PR_SET_PDEATHSIG`).

use std::ffi::CString;
use std::fs::File;
use std::io::{self, Read, Write};
use std::os::fd::FromRawFd;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use super::protocol::*;
use crate::embedded_python::ThreadStateUser;
use crate::fmi2::*;
use crate::instance::{LogContext, LogMessage, Phase, callbacks_for};
use crate::load::{LoadError, LocalBinary};

/// The instance the host runs.
struct HostInstance {
    c: fmi2Component,
    phase: Phase,
    /// For a binary with an embedded CPython: this (the only) thread's Python thread state
    /// ([`crate::embedded_python`]), released after the instance is freed.
    python: Option<ThreadStateUser>,
    // Kept alive (and at fixed addresses) for the FMU, which may keep both pointers.
    _callbacks: Box<fmi2CallbackFunctions>,
    _ctx: Box<LogContext>,
    _name: CString,
}

struct Host {
    out: Arc<Mutex<File>>,
    // Dropped before the binary (fields drop in order), even when a bad request ends the host
    // without `shutdown`: its thread state must go before the interpreter the binary's
    // unloading finalizes.
    inst: Option<HostInstance>,
    binary: Option<Arc<LocalBinary>>,
    /// Whether a binary with an embedded CPython gets a kept Python thread state.
    keep_python_thread_state: bool,
    reals: Vec<f64>,
    ints: Vec<i32>,
}

/// Runs the host on standard input and output (a socket) until the master closes its end.
pub(crate) fn serve() -> io::Result<()> {
    // SAFETY: prctl(PR_SET_PDEATHSIG) and getppid take no pointers.
    unsafe {
        libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL);
        if libc::getppid() == 1 {
            return Err(io::Error::other("the master process is gone"));
        }
    }
    // SAFETY: dup/dup2 on the standard descriptors, which are open (the master made them its socket).
    let out_fd = unsafe {
        let fd = libc::dup(1);
        if fd < 0 || libc::dup2(2, 1) < 0 {
            return Err(io::Error::last_os_error());
        }
        libc::fcntl(fd, libc::F_SETFD, libc::FD_CLOEXEC);
        fd
    };
    // SAFETY: out_fd is a fresh descriptor owned by nothing else.
    let out = Arc::new(Mutex::new(unsafe { File::from_raw_fd(out_fd) }));
    let mut host = Host {
        out,
        inst: None,
        binary: None,
        keep_python_thread_state: false,
        reals: Vec::new(),
        ints: Vec::new(),
    };
    let stdin = io::stdin();
    let mut input = stdin.lock();
    let mut frame = Vec::new();
    let mut reply = Enc::frame(FRAME_REPLY);
    loop {
        let mut len = [0u8; 4];
        match input.read_exact(&mut len) {
            Ok(()) => {}
            Err(e) if e.kind() == io::ErrorKind::UnexpectedEof => break,
            Err(e) => return Err(e),
        }
        let len = u32::from_le_bytes(len) as usize;
        if len > MAX_FRAME {
            return Err(io::Error::other(format!("request of {len} bytes")));
        }
        frame.resize(len, 0);
        input.read_exact(&mut frame)?;
        reply.reset(FRAME_REPLY);
        host.handle(&frame, &mut reply)
            .map_err(|e| io::Error::other(format!("bad request: {e}")))?;
        let bytes = reply.finish();
        let mut out = host.out.lock().unwrap_or_else(|p| p.into_inner());
        out.write_all(bytes)?;
    }
    host.shutdown();
    Ok(())
}

fn write_log(out: &Mutex<File>, m: &LogMessage) {
    let mut e = Enc::frame(FRAME_LOG);
    e.u8(match m.status {
        crate::LogStatus::Ok => 0,
        crate::LogStatus::Warning => 1,
        crate::LogStatus::Discard => 2,
        crate::LogStatus::Error => 3,
        crate::LogStatus::Fatal => 4,
        crate::LogStatus::Other => 5,
    });
    e.str(&m.instance);
    e.str(&m.category);
    e.str(&m.message);
    let mut out = out.lock().unwrap_or_else(|p| p.into_inner());
    // A failed write means the master is gone; the next reply fails the same way.
    let _ = out.write_all(e.finish());
}

fn kind_of(k: i32) -> Result<fmi2StatusKind, ProtocolError> {
    Ok(match k {
        0 => fmi2StatusKind::fmi2DoStepStatus,
        1 => fmi2StatusKind::fmi2PendingStatus,
        2 => fmi2StatusKind::fmi2LastSuccessfulTime,
        3 => fmi2StatusKind::fmi2Terminated,
        _ => return Err(ProtocolError(format!("status kind {k}"))),
    })
}

impl Host {
    fn handle(&mut self, frame: &[u8], reply: &mut Enc) -> Result<(), ProtocolError> {
        let mut d = Dec::new(frame);
        match d.u8()? {
            REQ_LOAD => {
                let binary = PathBuf::from(d.string()?);
                let preload: Vec<PathBuf> = d.strings()?.into_iter().map(PathBuf::from).collect();
                self.keep_python_thread_state = d.u8()? != 0;
                match LocalBinary::open(&binary, &preload) {
                    Ok(b) => {
                        reply.u8(0);
                        reply.str(&b.version);
                        reply.str(&b.types_platform);
                        reply.u32(b.missing_optional.len() as u32);
                        for m in &b.missing_optional {
                            reply.str(m);
                        }
                        self.binary = Some(Arc::new(b));
                    }
                    Err(LoadError::MissingFunction { name }) => {
                        reply.u8(1);
                        reply.str(name);
                    }
                    Err(e) => {
                        reply.u8(2);
                        reply.str(&e.to_string());
                    }
                }
            }
            REQ_INSTANTIATE => {
                let name = CString::new(d.string()?).map_err(|_| ProtocolError("NUL".into()))?;
                let guid = CString::new(d.string()?).map_err(|_| ProtocolError("NUL".into()))?;
                let uri = CString::new(d.string()?).map_err(|_| ProtocolError("NUL".into()))?;
                let visible = d.u8()? as fmi2Boolean;
                let logging = d.u8()? as fmi2Boolean;
                let (Some(b), None) = (&self.binary, &self.inst) else {
                    return Err(ProtocolError("instantiate before load or twice".into()));
                };
                let out = self.out.clone();
                let ctx = LogContext::new(
                    Some(Arc::new(move |m: &LogMessage| write_log(&out, m))),
                    false,
                );
                let callbacks = callbacks_for(&ctx);
                // SAFETY: valid NUL-terminated strings and a callbacks struct that live as long
                // as the instance (both kept in HostInstance).
                let c = unsafe {
                    (b.functions.instantiate)(
                        name.as_ptr(),
                        fmi2Type::fmi2CoSimulation,
                        guid.as_ptr(),
                        uri.as_ptr(),
                        &*callbacks,
                        visible,
                        logging,
                    )
                };
                reply.u8(u8::from(!c.is_null()));
                if !c.is_null() {
                    let python = ThreadStateUser::for_instance(
                        b.python,
                        self.keep_python_thread_state,
                        b.clone() as crate::embedded_python::KeepLoaded,
                    );
                    self.inst = Some(HostInstance {
                        c,
                        phase: Phase::Instantiated,
                        python,
                        _callbacks: callbacks,
                        _ctx: ctx,
                        _name: name,
                    });
                }
            }
            REQ_BATCH => self.batch(&mut d, reply)?,
            k => return Err(ProtocolError(format!("request kind {k}"))),
        }
        Ok(())
    }

    fn batch(&mut self, d: &mut Dec<'_>, reply: &mut Enc) -> Result<(), ProtocolError> {
        let (Some(b), Some(inst)) = (&self.binary, &mut self.inst) else {
            return Err(ProtocolError("a call before instantiation".into()));
        };
        let f = b.functions;
        let c = inst.c;
        if let Some(p) = &mut inst.python {
            // Every call of the batch runs on this thread.
            p.enter();
        }
        let n = d.u32()?;
        let count_at = reply.buf.len();
        reply.u32(0);
        let mut done = 0u32;
        let mut clean = true;
        for _ in 0..n {
            let op = d.u8()?;
            let flags = d.u8()?;
            if flags & FLAG_SPECULATIVE != 0 && !clean {
                break;
            }
            if inst.phase == Phase::Fatal {
                break;
            }
            let code_at = reply.buf.len();
            reply.i32(0);
            // SAFETY (every FFI call below): `c` is the live component this host instantiated,
            // the arrays passed have the lengths passed, and out pointers point to locals or
            // to buffers of the right length.
            let s: fmi2StatusCode = match op {
                CALL_SET_REAL => {
                    let vrs = d.u32s()?;
                    let v = d.f64s()?;
                    check_len(vrs.len(), v.len())?;
                    unsafe { (f.set_real)(c, vrs.as_ptr(), vrs.len(), v.as_ptr()) }
                }
                CALL_SET_INTEGER | CALL_SET_BOOLEAN => {
                    let vrs = d.u32s()?;
                    let v = d.i32s()?;
                    check_len(vrs.len(), v.len())?;
                    let g = if op == CALL_SET_INTEGER {
                        f.set_integer
                    } else {
                        f.set_boolean
                    };
                    unsafe { g(c, vrs.as_ptr(), vrs.len(), v.as_ptr()) }
                }
                CALL_SET_STRING => {
                    let vrs = d.u32s()?;
                    let v = d.strings()?;
                    check_len(vrs.len(), v.len())?;
                    let owned: Vec<CString> = v
                        .into_iter()
                        .map(|s| CString::new(s).map_err(|_| ProtocolError("NUL".into())))
                        .collect::<Result<_, _>>()?;
                    let ptrs: Vec<fmi2String> = owned.iter().map(|s| s.as_ptr()).collect();
                    unsafe { (f.set_string)(c, vrs.as_ptr(), vrs.len(), ptrs.as_ptr()) }
                }
                CALL_GET_REAL => {
                    let vrs = d.u32s()?;
                    self.reals.clear();
                    self.reals.resize(vrs.len(), 0.0);
                    let s = unsafe {
                        (f.get_real)(c, vrs.as_ptr(), vrs.len(), self.reals.as_mut_ptr())
                    };
                    reply.f64s(&self.reals);
                    s
                }
                CALL_GET_INTEGER | CALL_GET_BOOLEAN => {
                    let vrs = d.u32s()?;
                    self.ints.clear();
                    self.ints.resize(vrs.len(), 0);
                    let g = if op == CALL_GET_INTEGER {
                        f.get_integer
                    } else {
                        f.get_boolean
                    };
                    let s = unsafe { g(c, vrs.as_ptr(), vrs.len(), self.ints.as_mut_ptr()) };
                    reply.i32s(&self.ints);
                    s
                }
                CALL_GET_STRING => {
                    let vrs = d.u32s()?;
                    let mut ptrs: Vec<fmi2String> = vec![std::ptr::null(); vrs.len()];
                    let s =
                        unsafe { (f.get_string)(c, vrs.as_ptr(), vrs.len(), ptrs.as_mut_ptr()) };
                    reply.u32(ptrs.len() as u32);
                    for &p in &ptrs {
                        // NUL-terminated or NULL when the status allows reading them; after an
                        // error they are not read.
                        let text = if s.0 <= 2 {
                            unsafe { crate::load::cstr_lossy(p) }
                        } else {
                            String::new()
                        };
                        reply.str(&text);
                    }
                    s
                }
                CALL_DO_STEP => {
                    let t = d.f64()?;
                    let h = d.f64()?;
                    unsafe { (f.do_step)(c, t, h, fmi2True) }
                }
                CALL_SET_DEBUG_LOGGING => {
                    let on = d.u8()? as fmi2Boolean;
                    let cats = d.strings()?;
                    let owned: Vec<CString> = cats
                        .into_iter()
                        .map(|s| CString::new(s).map_err(|_| ProtocolError("NUL".into())))
                        .collect::<Result<_, _>>()?;
                    let ptrs: Vec<fmi2String> = owned.iter().map(|s| s.as_ptr()).collect();
                    unsafe { (f.set_debug_logging)(c, on, ptrs.len(), ptrs.as_ptr()) }
                }
                CALL_SETUP_EXPERIMENT => {
                    let tol_def = d.u8()? as fmi2Boolean;
                    let tol = d.f64()?;
                    let start = d.f64()?;
                    let stop_def = d.u8()? as fmi2Boolean;
                    let stop = d.f64()?;
                    unsafe { (f.setup_experiment)(c, tol_def, tol, start, stop_def, stop) }
                }
                CALL_ENTER_INITIALIZATION => unsafe { (f.enter_initialization_mode)(c) },
                CALL_EXIT_INITIALIZATION => unsafe { (f.exit_initialization_mode)(c) },
                CALL_CANCEL_STEP => unsafe { (f.cancel_step)(c) },
                CALL_TERMINATE => unsafe { (f.terminate)(c) },
                CALL_RESET => unsafe { (f.reset)(c) },
                CALL_GET_STATUS => {
                    let k = kind_of(d.i32()?)?;
                    let mut v = fmi2StatusCode(0);
                    let s = unsafe { (f.get_status)(c, k, &mut v) };
                    reply.i32(v.0);
                    s
                }
                CALL_GET_REAL_STATUS => {
                    let k = kind_of(d.i32()?)?;
                    let mut v = 0.0;
                    let s = unsafe { (f.get_real_status)(c, k, &mut v) };
                    reply.f64(v);
                    s
                }
                CALL_GET_INTEGER_STATUS | CALL_GET_BOOLEAN_STATUS => {
                    let k = kind_of(d.i32()?)?;
                    let mut v = 0;
                    let g = if op == CALL_GET_INTEGER_STATUS {
                        f.get_integer_status
                    } else {
                        f.get_boolean_status
                    };
                    let s = unsafe { g(c, k, &mut v) };
                    reply.i32(v);
                    s
                }
                CALL_GET_STRING_STATUS => {
                    let k = kind_of(d.i32()?)?;
                    let mut v: fmi2String = std::ptr::null();
                    let s = unsafe { (f.get_string_status)(c, k, &mut v) };
                    let text = if s.0 <= 2 {
                        unsafe { crate::load::cstr_lossy(v) }
                    } else {
                        String::new()
                    };
                    reply.str(&text);
                    s
                }
                CALL_GET_OUTPUT_DERIVATIVES => {
                    let vrs = d.u32s()?;
                    let orders = d.i32s()?;
                    check_len(vrs.len(), orders.len())?;
                    let g = optional(f.get_real_output_derivatives)?;
                    self.reals.clear();
                    self.reals.resize(vrs.len(), 0.0);
                    let s = unsafe {
                        g(
                            c,
                            vrs.as_ptr(),
                            vrs.len(),
                            orders.as_ptr(),
                            self.reals.as_mut_ptr(),
                        )
                    };
                    reply.f64s(&self.reals);
                    s
                }
                CALL_SET_INPUT_DERIVATIVES => {
                    let vrs = d.u32s()?;
                    let orders = d.i32s()?;
                    let v = d.f64s()?;
                    check_len(vrs.len(), orders.len())?;
                    check_len(vrs.len(), v.len())?;
                    let g = optional(f.set_real_input_derivatives)?;
                    unsafe { g(c, vrs.as_ptr(), vrs.len(), orders.as_ptr(), v.as_ptr()) }
                }
                CALL_GET_FMU_STATE => {
                    let g = optional(f.get_fmu_state)?;
                    let mut p = d.u64()? as usize as fmi2FMUstate;
                    let s = unsafe { g(c, &mut p) };
                    reply.u64(p as usize as u64);
                    s
                }
                CALL_SET_FMU_STATE => {
                    let g = optional(f.set_fmu_state)?;
                    let p = d.u64()? as usize as fmi2FMUstate;
                    unsafe { g(c, p) }
                }
                CALL_FREE_FMU_STATE => {
                    let g = optional(f.free_fmu_state)?;
                    let mut p = d.u64()? as usize as fmi2FMUstate;
                    unsafe { g(c, &mut p) }
                }
                CALL_SERIALIZE_FMU_STATE => {
                    let size_f = optional(f.serialized_fmu_state_size)?;
                    let ser_f = optional(f.serialize_fmu_state)?;
                    let p = d.u64()? as usize as fmi2FMUstate;
                    let mut size = 0usize;
                    let mut s = unsafe { size_f(c, p, &mut size) };
                    let mut buf = Vec::new();
                    if s.0 <= 1 {
                        buf = vec![0u8; size];
                        s = unsafe { ser_f(c, p, buf.as_mut_ptr() as *mut fmi2Byte, size) };
                    }
                    reply.bytes(&buf);
                    s
                }
                CALL_DESERIALIZE_FMU_STATE => {
                    let g = optional(f.deserialize_fmu_state)?;
                    let bytes = d.bytes()?;
                    let mut p: fmi2FMUstate = std::ptr::null_mut();
                    let s = unsafe { g(c, bytes.as_ptr() as *const fmi2Byte, bytes.len(), &mut p) };
                    reply.u64(p as usize as u64);
                    s
                }
                other => return Err(ProtocolError(format!("call {other}"))),
            };
            reply.buf[code_at..code_at + 4].copy_from_slice(&s.0.to_le_bytes());
            done += 1;
            inst.phase = next_phase(inst.phase, op, s);
            match s.0 {
                0 | 1 => {}
                2 => clean = false,
                _ => break,
            }
        }
        reply.buf[count_at..count_at + 4].copy_from_slice(&done.to_le_bytes());
        Ok(())
    }

    /// Terminates (when initialized) and frees the instance, as dropping an in-process instance
    /// does; after fmi2Fatal the instance is left alone.
    fn shutdown(&mut self) {
        if let (Some(b), Some(mut inst)) = (&self.binary, self.inst.take()) {
            if let Some(p) = &mut inst.python {
                p.enter();
            }
            // SAFETY: the live component of this host; no call after fmi2Fatal.
            unsafe {
                match inst.phase {
                    Phase::Fatal => return,
                    Phase::Initialization | Phase::StepComplete => {
                        let _ = (b.functions.terminate)(inst.c);
                    }
                    _ => {}
                }
                (b.functions.free_instance)(inst.c);
            }
            // `inst` (and its Python thread state) goes now, the binary with the host.
        }
    }
}

/// The phase after `op` returned `s` (the same transitions as the in-process instance).
fn next_phase(phase: Phase, op: u8, s: fmi2StatusCode) -> Phase {
    match s.0 {
        0..=2 => match op {
            CALL_ENTER_INITIALIZATION => Phase::Initialization,
            CALL_EXIT_INITIALIZATION => Phase::StepComplete,
            CALL_TERMINATE => Phase::Terminated,
            CALL_RESET => Phase::Instantiated,
            _ => phase,
        },
        4 => Phase::Fatal,
        5 => phase,
        _ => Phase::Error,
    }
}

fn check_len(a: usize, b: usize) -> Result<(), ProtocolError> {
    if a == b {
        Ok(())
    } else {
        Err(ProtocolError(format!("{a} value references, {b} values")))
    }
}

fn optional<T>(f: Option<T>) -> Result<T, ProtocolError> {
    f.ok_or_else(|| ProtocolError("a call of a function the binary does not export".into()))
}
