//! Pacing of `BenchHardware` against the emulator on loopback: a 60 s run at 1 kHz in soft
//! real time, reporting the lateness of the step deadlines (p50, p99, max), the overruns and
//! the reply times of the link.
//!
//! ```text
//! cargo bench -p kneebench-tests --bench pacing            # 60 s, SCHED_FIFO 80 and mlockall if permitted
//! KNEEBENCH_PACING_SECONDS=5 cargo bench -p kneebench-tests --bench pacing
//! KNEEBENCH_PACING_RT=0 KNEEBENCH_PACING_LOCK=0 cargo bench -p kneebench-tests --bench pacing   # as before them
//! KNEEBENCH_PACING_FLOOD=100000 cargo bench -p kneebench-tests --bench pacing   # under a flood of junk
//! ```
//!
//! Environment: `KNEEBENCH_PACING_SECONDS` (run length, default 60), `KNEEBENCH_PACING_RT`
//! (the FMU's `realtimePriority` and the emulator thread's, default 80; 0 leaves both in
//! normal scheduling), `KNEEBENCH_PACING_LOCK` (the FMU's `lockMemory`, default 1; 0: off),
//! `KNEEBENCH_PACING_REPLY_TIMEOUT` and `KNEEBENCH_PACING_SPIN` (the FMU's `replyTimeout` and
//! `spinMargin` in seconds; default: the FMU's), `KNEEBENCH_PACING_FLOOD` (datagrams of junk
//! a second sent at the emulator during the run from another socket, default 0: random bytes,
//! truncated frames, frames under another key, forged frames of the live session, replays of
//! an earlier session's frames; the `flood` line tells how many were sent and how the
//! emulator counted them).
//!
//! The `authentication` line is the cost of the frame tags per control period's round trip
//! (COMMAND and HEARTBEAT out, SAMPLE back: three frames tagged and three verified), measured
//! in the same run: the codec of those three frames with their tags (`Sender::frame`,
//! `Receiver::accept`) against the same codec without them (`Frame::encode_body`,
//! `Frame::peek` and `Frame::decode_fields`).
//!
//! The lateness of a step is read from the FMU's `lastLateness` after every step: how far
//! after its absolute deadline `fmi2DoStep` continued. An overrun is a step that reached its
//! deadline already late (the FMU's `overrunCount`). The reply time is how long the sample of
//! the step took to arrive after its request (`lastReplyTime`). The loop is the FMU alone
//! (commands: a 0.4 Hz current sine that keeps the bench moving), driven by the harness's
//! instance API. Variables the FMU under test does not declare (an older build) are skipped,
//! so the same program measures a before and an after. A trip ends the run early: its code is
//! printed with the figures up to it and the program exits with status 1.
//!
//! The `environment` line tells how busy the machine was (all processes, both cores) and how
//! much time its hypervisor stole, the last line how the overruns fell on seconds with and
//! without steal time: on a shared virtual machine the overruns follow the other processes'
//! load (see the `BenchHardware` documentation, "Pacing"), so compare runs of similar load.

use std::time::{Duration, Instant};

use kneebench_harness::bench_protocol::auth::TagKey;
use kneebench_harness::bench_protocol::{
    BenchSetup, ClientHandshake, Command, Frame, HandshakeReply, Key, Payload, Receiver, Sample,
    Sender, SetValueKind,
};
use kneebench_harness::emulator::{EmulatorConfig, spawn};
use kneebench_harness::package::export_all;
use kneebench_harness::{Fmu, InstanceOptions, LoadOptions, Status};
use kneebench_tests::fmu_library;

fn env<T: std::str::FromStr>(name: &str) -> Option<T> {
    std::env::var(name).ok().and_then(|s| s.parse().ok())
}

/// The value `p` (0..1) of sorted `v`, in microseconds.
fn pct(v: &[f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v[((p * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)] * 1e6
}

/// (minor, major) page faults of this process so far (Linux; zeros elsewhere).
fn page_faults() -> (u64, u64) {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the command name (which may hold spaces, so split after its ')').
    let rest = stat.rsplit_once(')').map(|(_, r)| r).unwrap_or("");
    let f: Vec<u64> = rest
        .split_whitespace()
        .map(|x| x.parse().unwrap_or(0))
        .collect();
    // minflt is field 10, majflt field 12 of proc(5); `rest` starts at field 3.
    (
        f.get(7).copied().unwrap_or(0),
        f.get(9).copied().unwrap_or(0),
    )
}

/// (busy, steal) jiffies of the whole machine so far (Linux; zeros elsewhere).
fn machine_time() -> (u64, u64) {
    let stat = std::fs::read_to_string("/proc/stat").unwrap_or_default();
    let f: Vec<u64> = stat
        .lines()
        .next()
        .unwrap_or("")
        .split_whitespace()
        .skip(1)
        .map(|x| x.parse().unwrap_or(0))
        .collect();
    let get = |i: usize| f.get(i).copied().unwrap_or(0);
    (get(0) + get(1) + get(2) + get(5) + get(6), get(7))
}

/// Records an earlier session's frames at the emulator (for the flood's replays).
fn recorded_session(addr: std::net::SocketAddr) -> Vec<Vec<u8>> {
    let socket = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    socket
        .set_read_timeout(Some(Duration::from_millis(500)))
        .unwrap();
    let setup = BenchSetup {
        configuration: 1,
        test_kind: SetValueKind::Current,
        load_kind: SetValueKind::Current,
    };
    let mut hs = ClientHandshake::new(&Key::loopback(), setup).unwrap();
    socket.send_to(hs.hello(), addr).unwrap();
    let mut buf = [0u8; 256];
    let mut session = loop {
        let n = socket.recv(&mut buf).expect("the emulator answers");
        if let Ok(HandshakeReply::Welcome(s)) = hs.receive(&buf[..n]) {
            break s;
        }
    };
    let safe = Command::safe(SetValueKind::Current, SetValueKind::Current);
    let mut frames = Vec::new();
    for _ in 0..50 {
        for p in [Payload::Command(safe), Payload::Heartbeat] {
            let (_, b) = session.tx.frame(p);
            socket.send_to(&b, addr).unwrap();
            frames.push(b);
        }
    }
    let (_, b) = session.tx.frame(Payload::SafeState(
        kneebench_harness::bench_protocol::SafeStateRequest { reason: 4 },
    ));
    socket.send_to(&b, addr).unwrap();
    frames.push(b);
    std::thread::sleep(Duration::from_millis(20));
    frames
}

/// Sends `rate` junk datagrams a second at `addr` until `stop`; returns how many.
fn flood(
    addr: std::net::SocketAddr,
    rate: u64,
    recorded: Vec<Vec<u8>>,
    live: std::sync::Arc<std::sync::atomic::AtomicU32>,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
) -> u64 {
    use std::sync::atomic::Ordering;
    let socket = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let wrong = Key::from_bytes([0x77; 32]);
    let wrong_hello = ClientHandshake::new(
        &wrong,
        BenchSetup {
            configuration: 1,
            test_kind: SetValueKind::Current,
            load_kind: SetValueKind::Current,
        },
    )
    .unwrap();
    let mut rng = 0x2545_F491_4F6C_DD1Du64;
    let mut next = move || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        rng
    };
    let drive = Command {
        test_set_value: 1.0,
        load_set_value: 1.0,
        test_enable: true,
        load_enable: true,
        clutch: true,
        test_kind: SetValueKind::Current,
        load_kind: SetValueKind::Current,
    };
    let mut sent = 0u64;
    let start = Instant::now();
    while !stop.load(Ordering::Relaxed) {
        // Send what is due by now (batches of 1 ms).
        let due = (start.elapsed().as_secs_f64() * rate as f64) as u64;
        while sent < due {
            let session = live.load(Ordering::Relaxed).max(1);
            let bytes: Vec<u8> = match next() % 5 {
                0 => (0..next() % 130).map(|_| next() as u8).collect(),
                1 => {
                    let r = &recorded[(next() as usize) % recorded.len()];
                    r[..(next() as usize) % r.len()].to_vec()
                }
                2 if next() % 2 == 0 => wrong_hello.hello().to_vec(),
                2 => {
                    let mut tx = Sender::new(
                        session,
                        wrong.session(session, &[0; 16], &[0; 16]).client_to_server,
                    );
                    tx.sequence = next() as u32 >> 1;
                    tx.frame(Payload::Command(drive)).1
                }
                3 => {
                    let mut f = Frame {
                        session,
                        sequence: (next() as u32).max(1),
                        payload: Payload::Command(drive),
                    }
                    .encode_body();
                    f.extend((0..16).map(|_| next() as u8));
                    f
                }
                _ => recorded[(next() as usize) % recorded.len()].clone(),
            };
            let _ = socket.send_to(&bytes, addr);
            sent += 1;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    sent
}

/// Nanoseconds per control period's round trip for the codec of its three frames, with
/// their tags and without (see the file's docs).
fn authentication_cost() -> (f64, f64) {
    let c2s = TagKey::new(b"client to server");
    let s2c = TagKey::new(b"server to client");
    let command = Payload::Command(Command {
        test_set_value: 1.5,
        load_set_value: -0.5,
        test_enable: true,
        load_enable: true,
        clutch: false,
        test_kind: SetValueKind::Current,
        load_kind: SetValueKind::Current,
    });
    let n = 200_000u32;
    let sample = |seq| {
        Payload::Sample(Sample {
            request_sequence: seq,
            last_command_sequence: seq - 1,
            server_time_us: u64::from(seq) * 1000,
            status: 0,
            safe_reason: 0,
            test_counts: 1234,
            load_counts: -77,
            analog: [5.4, 0.25, 2.5, 2.5, 3.3, 6.7],
        })
    };
    let mut sink = 0u64;
    // With tags: the real path.
    let (mut ctx, mut srx) = (Sender::new(9, c2s.clone()), Receiver::new(9, c2s.clone()));
    let (mut stx, mut crx) = (Sender::new(9, s2c.clone()), Receiver::new(9, s2c.clone()));
    let t = Instant::now();
    for _ in 0..n {
        let (_, a) = ctx.frame(command);
        let (seq, b) = ctx.frame(Payload::Heartbeat);
        sink += u64::from(srx.accept(&a).is_ok()) + u64::from(srx.accept(&b).is_ok());
        let (_, c) = stx.frame(sample(seq));
        sink += u64::from(crx.accept(&c).is_ok());
    }
    let with = t.elapsed().as_nanos() as f64 / f64::from(n);
    // The same frames without tags.
    let t = Instant::now();
    for k in 1..=n {
        let seq = 2 * k;
        let enc = |sequence, payload| {
            let mut v = Frame {
                session: 9,
                sequence,
                payload,
            }
            .encode_body();
            v.extend_from_slice(&[0; 16]);
            v
        };
        let dec = |bytes: &[u8]| {
            Frame::peek(bytes)
                .and_then(|h| Frame::decode_fields(h, &bytes[16..bytes.len() - 16]))
                .is_ok()
        };
        let a = enc(seq - 1, command);
        let b = enc(seq, Payload::Heartbeat);
        sink += u64::from(dec(&a)) + u64::from(dec(&b));
        let c = enc(k, sample(seq));
        sink += u64::from(dec(&c));
    }
    let without = t.elapsed().as_nanos() as f64 / f64::from(n);
    assert_eq!(sink, 6 * u64::from(n));
    (with, without)
}

fn main() {
    let seconds: f64 = env("KNEEBENCH_PACING_SECONDS").unwrap_or(60.0);
    let flood_rate: u64 = env("KNEEBENCH_PACING_FLOOD").unwrap_or(0);
    let priority: i32 = env("KNEEBENCH_PACING_RT").unwrap_or(80);
    let lock: i32 = env("KNEEBENCH_PACING_LOCK").unwrap_or(1);
    let reply_timeout: Option<f64> = env("KNEEBENCH_PACING_REPLY_TIMEOUT");
    let spin: Option<f64> = env("KNEEBENCH_PACING_SPIN");
    let h = 1e-3;
    let dir = tempfile::tempdir().unwrap();
    let fmus = export_all(&fmu_library(), dir.path()).expect("export");
    let path = |id: &str| {
        fmus.iter()
            .find(|f| f.identifier == id)
            .unwrap()
            .path
            .clone()
    };
    let mut config = EmulatorConfig::new("127.0.0.1:0", path("BenchPlant"));
    config.realtime_priority = (priority > 0).then_some(priority);
    config.log_rejections = false;
    let emu = spawn(config).unwrap();
    let recorded = recorded_session(emu.addr());
    let fmu = Fmu::load(path("BenchHardware"), &LoadOptions::default()).unwrap();
    let vr = |name: &str| fmu.variable(name).map(|v| v.value_reference);
    let mut i = fmu.instantiate("hw", &InstanceOptions::default()).unwrap();
    i.set_integer(&[400, 402], &[1, 1]).unwrap();
    i.set_string(&[401], &[&emu.addr().to_string()]).unwrap();
    if let Some(v) = vr("realtimePriority") {
        i.set_integer(&[v], &[priority]).unwrap();
    }
    if let Some(v) = vr("lockMemory") {
        i.set_boolean(&[v], &[lock != 0]).unwrap();
    }
    if let Some(t) = reply_timeout {
        i.set_real(&[404], &[t]).unwrap();
    }
    if let Some(t) = spin {
        i.set_real(&[406], &[t]).unwrap();
    }
    let reply_vr = vr("lastReplyTime");
    i.setup_experiment(None, 0.0, None).unwrap();
    i.enter_initialization_mode().unwrap();
    let mut timeout = [0.0, 0.0];
    i.get_real(&[404, 406], &mut timeout).unwrap();
    i.exit_initialization_mode().unwrap();
    let live = std::sync::Arc::new(std::sync::atomic::AtomicU32::new(emu.stats().session));
    let stop_flood = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let flooder = (flood_rate > 0).then(|| {
        let (l, s) = (live.clone(), stop_flood.clone());
        let addr = emu.addr();
        std::thread::spawn(move || flood(addr, flood_rate, recorded, l, s))
    });
    let n = (seconds / h).round() as usize;
    let mut lateness = Vec::with_capacity(n);
    let mut replies = Vec::with_capacity(n);
    let mut ended = None;
    let (faults0, machine0) = (page_faults(), machine_time());
    // Per second of the run: overruns, and whether the hypervisor stole CPU time from this
    // virtual machine then (steal time, /proc/stat): read once a second, after a step, in the
    // slack before the next deadline.
    let mut seconds_log: Vec<(i32, u64)> = Vec::new();
    let (mut last_overruns, mut last_steal) = (0, machine0.1);
    let start = Instant::now();
    for k in 0..n {
        let t = k as f64 * h;
        let current = 2.0 * (std::f64::consts::TAU * 0.4 * t).sin();
        i.set_real(&[201], &[current]).unwrap();
        match i.do_step(t, h) {
            Ok(Status::Ok) | Ok(Status::Warning) => {}
            other => {
                let mut code = [0];
                let _ = i.get_integer(&[373], &mut code);
                ended = Some(format!(
                    "step {k} (t = {t:.3} s): {other:?}, tripCode {}",
                    code[0]
                ));
                break;
            }
        }
        let mut v = [0.0];
        i.get_real(&[451], &mut v).unwrap();
        lateness.push(v[0]);
        if let Some(r) = reply_vr {
            i.get_real(&[r], &mut v).unwrap();
            replies.push(v[0]);
        }
        if (k + 1) % 1000 == 0 {
            let mut o = [0];
            i.get_integer(&[450], &mut o).unwrap();
            let steal = machine_time().1;
            seconds_log.push((o[0] - last_overruns, steal - last_steal));
            (last_overruns, last_steal) = (o[0], steal);
        }
    }
    let wall = start.elapsed().as_secs_f64();
    stop_flood.store(true, std::sync::atomic::Ordering::Relaxed);
    let flooded = flooder.map(|t| t.join().unwrap_or(0));
    let (faults1, machine1) = (page_faults(), machine_time());
    let mut overruns = [0];
    i.get_integer(&[450], &mut overruns).unwrap();
    let mut rejected = [0, 0];
    i.get_integer(&[453, 454], &mut rejected).unwrap();
    drop(i);
    let stats = emu.stop().unwrap();
    let steps = lateness.len();
    lateness.sort_by(f64::total_cmp);
    replies.sort_by(f64::total_cmp);
    println!(
        "pacing: {steps} steps of 1 ms in soft real time against the emulator on loopback \
         (realtimePriority {priority}, lockMemory {lock}, replyTimeout {:.0} us, spinMargin {:.0} us)",
        timeout[0] * 1e6,
        timeout[1] * 1e6
    );
    println!("  wall time        {wall:.3} s (asked {seconds} s)");
    println!(
        "  lateness         p50 {:.1} us, p99 {:.1} us, p99.9 {:.1} us, max {:.1} us",
        pct(&lateness, 0.5),
        pct(&lateness, 0.99),
        pct(&lateness, 0.999),
        pct(&lateness, 1.0)
    );
    println!("  overruns         {}", overruns[0]);
    if !replies.is_empty() {
        println!(
            "  reply time       p50 {:.1} us, p99 {:.1} us, p99.9 {:.1} us, max {:.1} us",
            pct(&replies, 0.5),
            pct(&replies, 0.99),
            pct(&replies, 0.999),
            pct(&replies, 1.0)
        );
    }
    println!(
        "  link             {} rejected frames, {} stale replies; emulator: {} commands applied, {} samples sent",
        rejected[0], rejected[1], stats.commands_applied, stats.samples_sent
    );
    println!(
        "  environment      emulator thread SCHED_FIFO {}; page faults in the loop {} minor, {} major; \
         machine busy {:.0} % of 2 cores, steal {:.2} s",
        stats.realtime_priority,
        faults1.0 - faults0.0,
        faults1.1 - faults0.1,
        (machine1.0 - machine0.0) as f64 / (2.0 * wall),
        (machine1.1 - machine0.1) as f64 / 100.0
    );
    let stolen: Vec<_> = seconds_log.iter().filter(|(_, s)| *s > 0).collect();
    println!(
        "  steal vs overruns {} of {} seconds had steal time, with {} overruns; the other {} seconds had {} overruns",
        stolen.len(),
        seconds_log.len(),
        stolen.iter().map(|(o, _)| o).sum::<i32>(),
        seconds_log.len() - stolen.len(),
        seconds_log
            .iter()
            .filter(|(_, s)| *s == 0)
            .map(|(o, _)| o)
            .sum::<i32>()
    );
    if let Some(sent) = flooded {
        println!(
            "  flood            {sent} junk datagrams ({:.0}/s asked {flood_rate}/s); emulator rejected {} (unauthenticated {}, truncated {}, malformed {}, wrong session {}, replayed or out of order {}), foreign {}",
            sent as f64 / wall,
            stats.rejected.rejected(),
            stats.rejected.unauthenticated,
            stats.rejected.truncated,
            stats.rejected.malformed,
            stats.rejected.wrong_session,
            stats.rejected.replayed + stats.rejected.out_of_order,
            stats.foreign_frames
        );
    }
    let (with, without) = authentication_cost();
    println!(
        "  authentication   {:.2} us per round trip (3 frames tagged and verified: {:.2} us with tags, {:.2} us without)",
        (with - without) * 1e-3,
        with * 1e-3,
        without * 1e-3
    );
    if let Some(why) = ended {
        println!("  RUN ENDED EARLY  {why}");
        std::process::exit(1);
    }
}
