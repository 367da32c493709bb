//! Pacing of `BenchHardware` against the emulator on loopback: a 60 s run at 1 kHz in soft
//! real time, reporting the lateness of the step deadlines (p50, p99, max) and the overruns.
//!
//! ```text
//! cargo bench -p kneebench-tests --bench pacing            # 60 s
//! KNEEBENCH_PACING_SECONDS=5 cargo bench -p kneebench-tests --bench pacing
//! ```
//!
//! The lateness of a step is read from the FMU's `lastLateness` after every step: how far
//! after its absolute deadline `fmi2DoStep` continued. The loop is the FMU alone (commands: a
//! 0.4 Hz current sine that keeps the bench moving), driven by the harness's instance API.

use std::time::Instant;

use kneebench_harness::emulator::{EmulatorConfig, spawn};
use kneebench_harness::package::export_all;
use kneebench_harness::{Fmu, InstanceOptions, LoadOptions, Status};
use kneebench_tests::fmu_library;

fn main() {
    let seconds: f64 = std::env::var("KNEEBENCH_PACING_SECONDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(60.0);
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
    let emu = spawn(EmulatorConfig::new("127.0.0.1:0", path("BenchPlant"))).unwrap();
    let fmu = Fmu::load(path("BenchHardware"), &LoadOptions::default()).unwrap();
    let mut i = fmu.instantiate("hw", &InstanceOptions::default()).unwrap();
    i.set_integer(&[400, 402], &[1, 1]).unwrap();
    i.set_string(&[401], &[&emu.addr().to_string()]).unwrap();
    i.setup_experiment(None, 0.0, None).unwrap();
    i.enter_initialization_mode().unwrap();
    i.exit_initialization_mode().unwrap();
    let n = (seconds / h).round() as usize;
    let mut lateness = Vec::with_capacity(n);
    let start = Instant::now();
    for k in 0..n {
        let t = k as f64 * h;
        let current = 2.0 * (std::f64::consts::TAU * 0.4 * t).sin();
        i.set_real(&[201], &[current]).unwrap();
        match i.do_step(t, h) {
            Ok(Status::Ok) | Ok(Status::Warning) => {}
            other => panic!("step {k}: {other:?}"),
        }
        let mut v = [0.0];
        i.get_real(&[451], &mut v).unwrap();
        lateness.push(v[0]);
    }
    let wall = start.elapsed().as_secs_f64();
    let mut overruns = [0];
    i.get_integer(&[450], &mut overruns).unwrap();
    let mut rejected = [0, 0];
    i.get_integer(&[453, 454], &mut rejected).unwrap();
    drop(i);
    let stats = emu.stop().unwrap();
    lateness.sort_by(f64::total_cmp);
    let pct = |p: f64| lateness[((p * (n - 1) as f64).round() as usize).min(n - 1)] * 1e6;
    println!("pacing: {n} steps of 1 ms in soft real time against the emulator on loopback");
    println!("  wall time        {wall:.3} s (simulated {seconds} s)");
    println!(
        "  lateness         p50 {:.1} us, p99 {:.1} us, p99.9 {:.1} us, max {:.1} us",
        pct(0.5),
        pct(0.99),
        pct(0.999),
        pct(1.0)
    );
    println!("  overruns         {}", overruns[0]);
    println!(
        "  link             {} rejected frames, {} stale replies; emulator: {} commands applied, {} samples sent",
        rejected[0], rejected[1], stats.commands_applied, stats.samples_sent
    );
}
