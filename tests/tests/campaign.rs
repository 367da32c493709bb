//! The bench link's fault campaign, quick set: every case of `kneebench_tests::campaign` once
//! (the long campaign, N runs of each with a table, is `cargo bench --bench campaign`), and
//! the watchdog fed by nothing but authenticated frames of the live session.
//!
//! Each case runs `BenchHardware` through the master into a streamed CSV file against the
//! emulator on loopback and asserts the reaction, its latency in control periods, the latch
//! and its acknowledgement, no drive command after the safe state, and every row on disk
//! (`campaign::Observation::check`). A run the host disturbs (a link trip the fault does not
//! cause, a trip before the fault: a descheduled emulator on a loaded 2-core machine) is run
//! again, at most three attempts; a case that never gets an undisturbed run fails.

use std::net::UdpSocket;
use std::time::{Duration, Instant};

use kneebench_harness::bench_protocol::{
    Command, FaultInjection, Payload, Sender, SetValueKind, reason,
};
use kneebench_harness::emulator::{EmulatorConfig, spawn};
use kneebench_tests::campaign::{self, Bench, Case, Expected, Fault, Observation};
use kneebench_tests::*;

fn bench(dir: &std::path::Path) -> Bench {
    Bench::in_dir(dir)
}

/// This test binary as the master process of the SIGKILL case: it runs only
/// [`campaign_master_process`].
fn child() -> std::process::Command {
    let mut c = std::process::Command::new(std::env::current_exe().unwrap());
    c.args([
        "--exact",
        "campaign_master_process",
        "--ignored",
        "--nocapture",
        "--test-threads=1",
    ]);
    c
}

/// Not a test: the master process that the SIGKILL case starts (with
/// `campaign::CHILD_ENV` set) and kills. Run by hand without that variable, it does nothing.
#[test]
#[ignore = "the master process of the SIGKILL case, started by it"]
fn campaign_master_process() {
    campaign::child_master_if_asked();
}

/// Runs `case` until a run is not disturbed by the host (at most three attempts) and asserts
/// what it must show.
fn assert_case(bench: &Bench, case: &Case) -> Observation {
    let mut disturbances = Vec::new();
    for _ in 0..3 {
        let obs = campaign::run_case(bench, case, &child);
        if let Some(why) = &obs.disturbed {
            eprintln!("{}: disturbed run ({why}); again", case.name);
            disturbances.push(why.clone());
            continue;
        }
        eprintln!(
            "{}: code {:?}, {:?} periods, latch {:?}, {} rows on disk, {} refused",
            case.name, obs.code, obs.periods, obs.latch, obs.rows_on_disk, obs.refused
        );
        if let Err(e) = obs.check(case) {
            panic!("{e}");
        }
        return obs;
    }
    panic!("{}: three disturbed runs: {disturbances:?}", case.name);
}

fn cases_named(filter: impl Fn(&Case) -> bool) -> Vec<Case> {
    let cases: Vec<Case> = campaign::cases().into_iter().filter(filter).collect();
    assert!(!cases.is_empty());
    cases
}

#[test]
fn link_faults_trip_within_one_period_or_are_absorbed() {
    let _rt = one_real_time_test_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let bench = bench(dir.path());
    for case in cases_named(|c| {
        matches!(
            c.fault,
            Fault::Inject(
                FaultInjection::DropReplies { .. }
                    | FaultInjection::DelayReplies { .. }
                    | FaultInjection::Duplicate { .. }
                    | FaultInjection::Reorder { .. }
                    | FaultInjection::Corrupt { .. }
                    | FaultInjection::Silence
            )
        )
    }) {
        let obs = assert_case(&bench, &case);
        // The absorbed faults were there: their copies were refused, by the master (in its
        // rejectedFrames) or by the server.
        if case.expected == Expected::Completes {
            let refused = obs.refused + obs.master_refused.expect("rejectedFrames recorded");
            assert!(refused >= 1, "{}: no copy refused: {obs:?}", case.name);
        }
        if case.name == "link cut" {
            // The server's own watchdog made the bench safe: not before its 50 periods, and
            // soon after (up to 250 periods: a descheduled emulator on a loaded machine; the
            // benchmark's table gives the latencies measured).
            let w = obs.watchdog_periods.expect("the watchdog latched");
            assert!((50..=250).contains(&w), "watchdog after {w} periods");
        }
    }
}

#[test]
fn sensor_faults_trip_with_their_code_or_are_documented_as_undetectable() {
    let _rt = one_real_time_test_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let bench = bench(dir.path());
    for case in cases_named(|c| {
        matches!(
            c.fault,
            Fault::Inject(
                FaultInjection::Stuck { .. }
                    | FaultInjection::Force { .. }
                    | FaultInjection::Noise { .. }
                    | FaultInjection::Offset { .. }
            )
        )
    }) {
        assert_case(&bench, &case);
    }
}

#[test]
fn driver_fault_and_supply_drop_stop_the_bench() {
    let _rt = one_real_time_test_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let bench = bench(dir.path());
    for case in cases_named(|c| {
        matches!(
            c.fault,
            Fault::Inject(FaultInjection::DriverFault { .. } | FaultInjection::SupplyDrop { .. })
        )
    }) {
        assert_case(&bench, &case);
    }
}

/// The master process killed with SIGKILL mid-run: the emulator's watchdog latches the safe
/// state (reason 2) within its timeout, the latch survives into a new session that must
/// acknowledge it, and every row the master made is on disk, complete (it writes through, as
/// `kneebench run --flush-every-row` does; the row of its last exchange may be missing).
#[test]
fn a_master_killed_with_sigkill_leaves_the_bench_latched_and_its_rows_on_disk() {
    let _rt = one_real_time_test_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let bench = bench(dir.path());
    for case in cases_named(|c| c.fault == Fault::KillMaster) {
        let obs = assert_case(&bench, &case);
        // Killed 1.5 s into the run: about 1500 rows made (the case's check compares them
        // with what the server saw, row for row but the last).
        assert!(obs.rows_on_disk >= 1000, "{obs:?}");
    }
}

/// The server restarted mid-run: the master trips (link watchdog) and cannot confirm the safe
/// state to a server that does not know its session (fmi2Error, not a run that goes on); the
/// new server starts latched from its state file (reason 6) until a new master acknowledges.
#[test]
fn a_server_restarted_mid_run_trips_the_master_and_starts_latched() {
    let _rt = one_real_time_test_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let bench = bench(dir.path());
    for case in cases_named(|c| c.fault == Fault::RestartServer) {
        let obs = assert_case(&bench, &case);
        assert_eq!(obs.latch, Some(reason::SERVER_RESTART));
    }
}

/// The watchdog is fed only by authenticated, new frames of the live session: the master goes
/// silent while a forger keeps sending its session's frames (replays of the master's frames,
/// and frames with forged tags, from the master's own address as a spoofer would and from
/// another), and the watchdog fires as if nothing came, its delay measured from the master's
/// last frame.
#[test]
fn forged_and_replayed_frames_do_not_keep_the_watchdog_alive() {
    let _rt = one_real_time_test_at_a_time();
    let timeout = Duration::from_millis(30);
    let mut config = EmulatorConfig::new("127.0.0.1:0", exported_fmu("BenchPlant"));
    config.key = Some(bench_key_file().2.clone());
    config.heartbeat_timeout = timeout;
    config.log_rejections = false;
    let emu = spawn(config).unwrap();
    let (master, mut session) = campaign::hand_session(emu.addr(), &bench_key_file().2);
    let mut buf = [0u8; 256];
    let drive = Command {
        test_set_value: 1.0,
        load_set_value: 0.0,
        test_enable: true,
        load_enable: false,
        clutch: false,
        test_kind: SetValueKind::Current,
        load_kind: SetValueKind::Current,
    };
    let mut captured = Vec::new();
    for _ in 0..5 {
        let (_, c) = session.tx.frame(Payload::Command(drive));
        master.send(&c).unwrap();
        let (_, hb) = session.tx.frame(Payload::Heartbeat);
        master.send(&hb).unwrap();
        let n = master.recv(&mut buf).unwrap();
        session.rx.accept(&buf[..n]).expect("a sample");
        captured.push(c);
        captured.push(hb);
    }
    assert!(emu.stats().outputs.is_some_and(|c| c.drives()));
    // The master falls silent. The forger: the master's frames again, frames of the session
    // under the handshake key and under a key of its own, the next sequence numbers with a
    // flipped tag; from the master's address and from its own.
    let forger = UdpSocket::bind("127.0.0.1:0").unwrap();
    let wrong_key = kneebench_harness::bench_protocol::Key::from_bytes([7; 32]);
    let mut under_handshake = Sender::new(session.tx.session, bench_key_file().2.handshake());
    let mut under_wrong = Sender::new(
        session.tx.session,
        wrong_key.session(1, &[0; 16], &[0; 16]).client_to_server,
    );
    under_handshake.sequence = session.tx.sequence;
    under_wrong.sequence = session.tx.sequence;
    let start = Instant::now();
    let mut sent = 0u64;
    while start.elapsed() < timeout * 8 {
        let mut forged = vec![captured[sent as usize % captured.len()].clone()];
        forged.push(under_handshake.frame(Payload::Heartbeat).1);
        forged.push(under_wrong.frame(Payload::Command(drive)).1);
        let (_, mut flipped) = session.tx.clone().frame(Payload::Heartbeat);
        let last = flipped.len() - 1;
        flipped[last] ^= 1;
        forged.push(flipped);
        for (k, f) in forged.iter().enumerate() {
            if k % 2 == 0 {
                master.send(f).unwrap();
            } else {
                forger.send_to(f, emu.addr()).unwrap();
            }
            sent += 1;
        }
        std::thread::sleep(Duration::from_micros(500));
    }
    let s = emu.stats();
    assert!(sent > 100, "{sent}");
    assert_eq!(s.safe_reason, Some(reason::HEARTBEAT_TIMEOUT), "{s:?}");
    assert!(!s.outputs.is_some_and(|c| c.drives()), "{s:?}");
    // Fired at the timeout after the master's last valid frame, while the forger was still
    // sending: had the forged frames fed it, it would have fired no earlier than 9 timeouts
    // after that frame (8 of forging, then its own). Below 6 leaves a descheduled emulator on
    // a loaded machine 150 ms of slack; the timing itself is tested in bench_link.rs.
    let delay = s.latched_at.unwrap() - s.last_valid_time;
    assert!(
        delay >= timeout.as_secs_f64() && delay < timeout.as_secs_f64() * 6.0,
        "the watchdog fired {delay} s after the last valid frame"
    );
    // Every forged frame was refused and counted; none was applied.
    assert!(
        s.rejected.rejected() + s.foreign_frames >= sent * 9 / 10,
        "{} + {} refused of {sent}: {s:?}",
        s.rejected.rejected(),
        s.foreign_frames
    );
    assert_eq!(s.commands_applied, 5);
}

/// As a bench server (`refuse_fault_frames`, the CLI's `--no-faults`), the emulator refuses
/// the live session's fault-injection frames and counts them; the same frame is obeyed by an
/// emulator that accepts them.
#[test]
fn a_server_that_refuses_fault_frames_counts_them_and_changes_nothing() {
    let _rt = one_real_time_test_at_a_time();
    for refuse in [true, false] {
        let mut config = EmulatorConfig::new("127.0.0.1:0", exported_fmu("BenchPlant"));
        config.key = Some(bench_key_file().2.clone());
        config.refuse_fault_frames = refuse;
        config.log_rejections = false;
        let emu = spawn(config).unwrap();
        let (socket, mut session) = campaign::hand_session(emu.addr(), &bench_key_file().2);
        let mut buf = [0u8; 256];
        let (_, fault) = session
            .tx
            .frame(Payload::FaultInject(FaultInjection::DriverFault {
                driver: 0,
            }));
        socket.send(&fault).unwrap();
        let (_, hb) = session.tx.frame(Payload::Heartbeat);
        socket.send(&hb).unwrap();
        let sample = loop {
            let n = socket.recv(&mut buf).unwrap();
            if let Ok(f) = session.rx.accept(&buf[..n])
                && let Payload::Sample(s) = f.payload
            {
                break s;
            }
        };
        let s = emu.stop().unwrap();
        if refuse {
            assert_eq!(s.fault_frames_refused, 1, "{s:?}");
            assert_eq!(s.faults_injected, 0);
            assert_eq!(s.safe_reason, None);
            assert!(!sample.has(kneebench_harness::bench_protocol::status::SAFE_STATE));
        } else {
            assert_eq!(s.fault_frames_refused, 0);
            assert_eq!(s.faults_injected, 1);
            assert_eq!(s.safe_reason, Some(reason::BENCH_PROTECTION));
            assert!(sample.has(kneebench_harness::bench_protocol::status::SERVER_TRIP));
        }
    }
}
