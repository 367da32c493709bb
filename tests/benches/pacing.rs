//! Pacing of `BenchHardware` against the emulator on loopback: a 60 s run at 1 kHz in soft
//! real time, reporting the lateness of the step deadlines (p50, p99, max), the overruns and
//! the reply times of the link.
//!
//! ```text
//! cargo bench -p kneebench-tests --bench pacing            # 60 s, SCHED_FIFO 80 and mlockall if permitted
//! KNEEBENCH_PACING_SECONDS=5 cargo bench -p kneebench-tests --bench pacing
//! KNEEBENCH_PACING_RT=0 KNEEBENCH_PACING_LOCK=0 cargo bench -p kneebench-tests --bench pacing   # as before them
//! ```
//!
//! Environment: `KNEEBENCH_PACING_SECONDS` (run length, default 60), `KNEEBENCH_PACING_RT`
//! (the FMU's `realtimePriority` and the emulator thread's, default 80; 0 leaves both in
//! normal scheduling), `KNEEBENCH_PACING_LOCK` (the FMU's `lockMemory`, default 1; 0: off),
//! `KNEEBENCH_PACING_REPLY_TIMEOUT` and `KNEEBENCH_PACING_SPIN` (the FMU's `replyTimeout` and
//! `spinMargin` in seconds; default: the FMU's).
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

use std::time::Instant;

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

fn main() {
    let seconds: f64 = env("KNEEBENCH_PACING_SECONDS").unwrap_or(60.0);
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
    let emu = spawn(config).unwrap();
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
    if let Some(why) = ended {
        println!("  RUN ENDED EARLY  {why}");
        std::process::exit(1);
    }
}
