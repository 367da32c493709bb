//! Operating-system support for a real-time control thread: the monotonic clock in
//! nanoseconds, absolute sleeps on it, the `SCHED_FIFO` policy, the timer slack and memory
//! locking.
//!
//! On Linux these are the C library's own functions (`clock_gettime`, `clock_nanosleep` with
//! `TIMER_ABSTIME`, `sched_setscheduler`, `prctl(PR_SET_TIMERSLACK)`, `mlockall`), declared
//! here against the libc that `std` links anyway. Elsewhere the clock is `std::time::Instant`,
//! the sleep `std::thread::sleep`, and the scheduling requests report
//! [`RealtimeError::Unsupported`].
//!
//! Everything here is best effort by design: a refused request (no `CAP_SYS_NICE`, an
//! `RLIMIT_RTPRIO` of 0, a container without real-time bandwidth) is an error the caller
//! turns into a logged warning, never a failure of the run.

use std::fmt;

/// Why a real-time request was not granted.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RealtimeError {
    /// The operating system refused it (`errno`).
    Refused {
        /// The call.
        call: &'static str,
        /// The OS error number.
        errno: i32,
    },
    /// Not available on this operating system.
    Unsupported(&'static str),
}

impl fmt::Display for RealtimeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RealtimeError::Refused { call, errno } => write!(
                f,
                "{call} refused: {}",
                std::io::Error::from_raw_os_error(*errno)
            ),
            RealtimeError::Unsupported(what) => {
                write!(f, "{what} is not supported on this operating system")
            }
        }
    }
}

impl std::error::Error for RealtimeError {}

#[cfg(target_os = "linux")]
mod sys {
    use std::ffi::{c_int, c_long};

    /// `struct timespec` (64-bit `time_t` and `long` on the 64-bit targets this is built for;
    /// on 32-bit glibc without `_TIME_BITS=64`, `time_t` is `long` too).
    #[repr(C)]
    pub struct Timespec {
        pub tv_sec: c_long,
        pub tv_nsec: c_long,
    }

    /// `struct sched_param`.
    #[repr(C)]
    pub struct SchedParam {
        pub sched_priority: c_int,
    }

    pub const CLOCK_MONOTONIC: c_int = 1;
    pub const TIMER_ABSTIME: c_int = 1;
    pub const SCHED_FIFO: c_int = 1;
    pub const SCHED_RESET_ON_FORK: c_int = 0x4000_0000;
    pub const PR_SET_TIMERSLACK: c_int = 29;
    pub const PR_GET_TIMERSLACK: c_int = 30;
    pub const MCL_CURRENT: c_int = 1;
    pub const MCL_FUTURE: c_int = 2;
    pub const EINTR: c_int = 4;

    unsafe extern "C" {
        pub fn clock_gettime(clock: c_int, ts: *mut Timespec) -> c_int;
        pub fn clock_nanosleep(
            clock: c_int,
            flags: c_int,
            request: *const Timespec,
            remain: *mut Timespec,
        ) -> c_int;
        pub fn sched_setscheduler(pid: c_int, policy: c_int, param: *const SchedParam) -> c_int;
        pub fn sched_getscheduler(pid: c_int) -> c_int;
        pub fn sched_getparam(pid: c_int, param: *mut SchedParam) -> c_int;
        pub fn gettid() -> c_int;
        pub fn prctl(option: c_int, ...) -> c_int;
        pub fn mlockall(flags: c_int) -> c_int;
        pub fn setsockopt(
            fd: c_int,
            level: c_int,
            name: c_int,
            value: *const std::ffi::c_void,
            len: u32,
        ) -> c_int;
        pub fn getsockopt(
            fd: c_int,
            level: c_int,
            name: c_int,
            value: *mut std::ffi::c_void,
            len: *mut u32,
        ) -> c_int;
        pub fn ppoll(
            fds: *mut PollFd,
            nfds: std::ffi::c_ulong,
            timeout: *const Timespec,
            sigmask: *const std::ffi::c_void,
        ) -> c_int;
    }

    /// `struct pollfd`.
    #[repr(C)]
    pub struct PollFd {
        pub fd: c_int,
        pub events: i16,
        pub revents: i16,
    }

    pub const POLLIN: i16 = 1;
    pub const SOL_SOCKET: c_int = 1;
    pub const SO_RCVBUF: c_int = 8;
    pub const SO_RCVBUFFORCE: c_int = 33;

    pub fn errno() -> i32 {
        std::io::Error::last_os_error().raw_os_error().unwrap_or(0)
    }
}

/// Nanoseconds on the monotonic clock (`CLOCK_MONOTONIC`, the clock of `Instant` on Linux).
#[cfg(target_os = "linux")]
pub fn now_ns() -> u64 {
    let mut ts = sys::Timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC always exists on Linux.
    unsafe { sys::clock_gettime(sys::CLOCK_MONOTONIC, &mut ts) };
    (ts.tv_sec as u64)
        .saturating_mul(1_000_000_000)
        .saturating_add(ts.tv_nsec as u64)
}

/// Nanoseconds on a monotonic clock (since the first call).
#[cfg(not(target_os = "linux"))]
pub fn now_ns() -> u64 {
    use std::sync::OnceLock;
    use std::time::Instant;
    static BASE: OnceLock<Instant> = OnceLock::new();
    BASE.get_or_init(Instant::now).elapsed().as_nanos() as u64
}

/// Sleeps until the monotonic clock reads `deadline_ns` (an absolute sleep: a preemption
/// between reading the clock and sleeping does not make the wake-up later). Returns at once if
/// it has passed.
#[cfg(target_os = "linux")]
pub fn sleep_until_ns(deadline_ns: u64) {
    let ts = sys::Timespec {
        tv_sec: (deadline_ns / 1_000_000_000) as _,
        tv_nsec: (deadline_ns % 1_000_000_000) as _,
    };
    loop {
        // SAFETY: `ts` is a valid timespec; `remain` may be NULL with TIMER_ABSTIME.
        let rc = unsafe {
            sys::clock_nanosleep(
                sys::CLOCK_MONOTONIC,
                sys::TIMER_ABSTIME,
                &ts,
                std::ptr::null_mut(),
            )
        };
        if rc != sys::EINTR {
            return;
        }
    }
}

/// Sleeps until the monotonic clock reads `deadline_ns`.
#[cfg(not(target_os = "linux"))]
pub fn sleep_until_ns(deadline_ns: u64) {
    let now = now_ns();
    if deadline_ns > now {
        std::thread::sleep(std::time::Duration::from_nanos(deadline_ns - now));
    }
}

/// Waits until the file descriptor `fd` is readable or the monotonic clock reads
/// `deadline_ns`, whichever comes first; returns whether it is readable. The wait is
/// `ppoll` with a nanosecond timeout recomputed from the absolute deadline on every
/// (interrupted) call, so it ends within the timer slack of the deadline (50 us for a normal
/// thread, 1 ns under [`RealtimeThread`]), never rounded up to the kernel's tick as a
/// socket's receive timeout (`SO_RCVTIMEO`) is. Callers that need the deadline to the
/// microsecond wait until a margin before it and spin for the rest, as the pacer does.
#[cfg(target_os = "linux")]
pub fn wait_readable_until(fd: std::os::fd::RawFd, deadline_ns: u64) -> bool {
    loop {
        let now = now_ns();
        let left = deadline_ns.saturating_sub(now);
        let ts = sys::Timespec {
            tv_sec: (left / 1_000_000_000) as _,
            tv_nsec: (left % 1_000_000_000) as _,
        };
        let mut pfd = sys::PollFd {
            fd,
            events: sys::POLLIN,
            revents: 0,
        };
        // SAFETY: one valid pollfd, a valid timespec, no signal mask (NULL: unchanged).
        let rc = unsafe { sys::ppoll(&mut pfd, 1, &ts, std::ptr::null()) };
        if rc > 0 {
            return true;
        }
        if rc == 0 || sys::errno() != sys::EINTR || now_ns() >= deadline_ns {
            return false;
        }
    }
}

/// Waits until `fd` may be readable or the deadline passes (elsewhere than on Linux: short
/// sleeps; the caller reads with a short receive timeout and decides).
#[cfg(not(target_os = "linux"))]
pub fn wait_readable_until(_fd: i32, deadline_ns: u64) -> bool {
    let now = now_ns();
    if deadline_ns > now {
        std::thread::sleep(std::time::Duration::from_nanos(
            (deadline_ns - now).min(50_000),
        ));
    }
    true
}

/// Asks for a socket receive buffer of `bytes` (`SO_RCVBUFFORCE`, which needs
/// `CAP_NET_ADMIN`, else `SO_RCVBUF`, capped by `net.core.rmem_max`); returns the size the
/// kernel granted (it doubles the request for its bookkeeping), or `None` if it cannot be
/// read. A server keeps its legitimate frames through a burst of junk only if the junk that
/// arrives while it is descheduled fits in this buffer.
#[cfg(target_os = "linux")]
pub fn set_receive_buffer(fd: std::os::fd::RawFd, bytes: usize) -> Option<usize> {
    let v = i32::try_from(bytes).unwrap_or(i32::MAX);
    let size = std::mem::size_of::<i32>() as u32;
    // SAFETY: `v` and `got` are valid ints of the length given; the calls only read or write
    // them.
    unsafe {
        let p = (&v as *const i32).cast();
        if sys::setsockopt(fd, sys::SOL_SOCKET, sys::SO_RCVBUFFORCE, p, size) != 0 {
            sys::setsockopt(fd, sys::SOL_SOCKET, sys::SO_RCVBUF, p, size);
        }
        let mut got = 0i32;
        let mut len = size;
        (sys::getsockopt(
            fd,
            sys::SOL_SOCKET,
            sys::SO_RCVBUF,
            (&mut got as *mut i32).cast(),
            &mut len,
        ) == 0)
            .then_some(usize::try_from(got).unwrap_or(0))
    }
}

/// The receive buffer stays the system's default here.
#[cfg(not(target_os = "linux"))]
pub fn set_receive_buffer(_fd: i32, _bytes: usize) -> Option<usize> {
    None
}

/// The calling thread raised to a real-time policy; dropping it restores the thread's
/// previous policy, priority and timer slack (from any thread of the process).
#[derive(Debug)]
pub struct RealtimeThread {
    #[cfg(target_os = "linux")]
    tid: i32,
    #[cfg(target_os = "linux")]
    previous: (i32, i32),
    #[cfg(target_os = "linux")]
    slack: Option<i64>,
    /// The `SCHED_FIFO` priority granted.
    pub priority: i32,
}

impl RealtimeThread {
    /// Puts the calling thread in `SCHED_FIFO` at `priority` (1..99) and sets its timer slack
    /// to 1 ns. Threads it creates afterwards do not inherit the policy
    /// (`SCHED_RESET_ON_FORK`).
    #[cfg(target_os = "linux")]
    pub fn enter(priority: i32) -> Result<Self, RealtimeError> {
        let priority = priority.clamp(1, 99);
        // SAFETY: plain syscalls on the calling thread with valid pointers.
        unsafe {
            let tid = sys::gettid();
            let policy = sys::sched_getscheduler(0);
            let mut old = sys::SchedParam { sched_priority: 0 };
            if policy < 0 || sys::sched_getparam(0, &mut old) != 0 {
                return Err(RealtimeError::Refused {
                    call: "sched_getscheduler",
                    errno: sys::errno(),
                });
            }
            let param = sys::SchedParam {
                sched_priority: priority,
            };
            if sys::sched_setscheduler(0, sys::SCHED_FIFO | sys::SCHED_RESET_ON_FORK, &param) != 0 {
                return Err(RealtimeError::Refused {
                    call: "sched_setscheduler(SCHED_FIFO)",
                    errno: sys::errno(),
                });
            }
            let slack = sys::prctl(sys::PR_GET_TIMERSLACK);
            let slack = (slack >= 0
                && sys::prctl(sys::PR_SET_TIMERSLACK, 1 as std::ffi::c_ulong) == 0)
                .then_some(i64::from(slack));
            Ok(Self {
                tid,
                previous: (policy, old.sched_priority),
                slack,
                priority,
            })
        }
    }

    /// Real-time scheduling is not available here.
    #[cfg(not(target_os = "linux"))]
    pub fn enter(_priority: i32) -> Result<Self, RealtimeError> {
        Err(RealtimeError::Unsupported("SCHED_FIFO"))
    }
}

impl Drop for RealtimeThread {
    fn drop(&mut self) {
        #[cfg(target_os = "linux")]
        // SAFETY: plain syscalls with valid pointers; a thread that has ended makes them fail
        // harmlessly (ESRCH).
        unsafe {
            let param = sys::SchedParam {
                sched_priority: self.previous.1,
            };
            sys::sched_setscheduler(self.tid, self.previous.0, &param);
            if let Some(slack) = self.slack
                && sys::gettid() == self.tid
            {
                sys::prctl(sys::PR_SET_TIMERSLACK, slack as std::ffi::c_ulong);
            }
        }
    }
}

/// The calling thread's scheduling policy and priority (`SCHED_FIFO` is 1, normal
/// scheduling 0), without the reset-on-fork flag; `None` where unsupported.
#[cfg(target_os = "linux")]
pub fn current_policy() -> Option<(i32, i32)> {
    let mut p = sys::SchedParam { sched_priority: 0 };
    // SAFETY: plain syscalls on the calling thread with a valid pointer.
    unsafe {
        let policy = sys::sched_getscheduler(0);
        (policy >= 0 && sys::sched_getparam(0, &mut p) == 0)
            .then_some((policy & !sys::SCHED_RESET_ON_FORK, p.sched_priority))
    }
}

/// The calling thread's scheduling policy: unsupported here.
#[cfg(not(target_os = "linux"))]
pub fn current_policy() -> Option<(i32, i32)> {
    None
}

/// Locks the process's present and future pages in memory (`mlockall`), so that no page
/// fault of the control loop waits for the disk. Process-wide and never undone.
#[cfg(target_os = "linux")]
pub fn lock_memory() -> Result<(), RealtimeError> {
    // SAFETY: a plain syscall.
    if unsafe { sys::mlockall(sys::MCL_CURRENT | sys::MCL_FUTURE) } != 0 {
        return Err(RealtimeError::Refused {
            call: "mlockall",
            errno: sys::errno(),
        });
    }
    Ok(())
}

/// Memory locking is not available here.
#[cfg(not(target_os = "linux"))]
pub fn lock_memory() -> Result<(), RealtimeError> {
    Err(RealtimeError::Unsupported("mlockall"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn absolute_sleeps_end_at_or_after_their_deadline() {
        let start = std::time::Instant::now();
        for k in 1..=5u64 {
            let deadline = now_ns() + 500_000;
            sleep_until_ns(deadline);
            assert!(now_ns() >= deadline, "{k}");
        }
        // A deadline in the past returns at once.
        let before = now_ns();
        sleep_until_ns(before.saturating_sub(1_000_000));
        assert!(now_ns() - before < 5_000_000);
        assert!(start.elapsed() >= std::time::Duration::from_micros(2500));
    }

    #[test]
    fn waits_for_readable_end_at_the_deadline_or_on_data() {
        use std::os::fd::AsRawFd;
        let a = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        let b = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        // Nothing to read: returns false, not before the deadline.
        let deadline = now_ns() + 300_000;
        assert!(!wait_readable_until(a.as_raw_fd(), deadline));
        let end = now_ns();
        assert!(end >= deadline);
        b.send_to(b"x", a.local_addr().unwrap()).unwrap();
        assert!(wait_readable_until(a.as_raw_fd(), now_ns() + 1_000_000_000));
        // A past deadline with data waiting still reports it.
        assert!(wait_readable_until(a.as_raw_fd(), 0));
    }

    #[test]
    fn the_clock_is_instants_clock() {
        // Both read CLOCK_MONOTONIC on Linux: differences agree.
        let (a, i) = (now_ns(), std::time::Instant::now());
        std::thread::sleep(std::time::Duration::from_millis(2));
        let (b, d) = (now_ns(), i.elapsed());
        let diff = (b - a) as i128 - d.as_nanos() as i128;
        assert!(diff.abs() < 500_000, "{diff}");
    }

    #[test]
    fn realtime_is_granted_and_restored_or_refused_with_a_reason() {
        // On a thread of its own: the test harness's threads are left alone.
        std::thread::spawn(|| match RealtimeThread::enter(10) {
            Ok(rt) => {
                assert_eq!(rt.priority, 10);
                assert_eq!(current_policy(), Some((1, 10)));
                drop(rt);
                assert_eq!(current_policy(), Some((0, 0)));
            }
            Err(e) => assert!(!e.to_string().is_empty()),
        })
        .join()
        .unwrap();
    }
}
