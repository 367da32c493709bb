//! Loading and unloading the kneebench binary does not leak: 10,000 cycles of `dlopen`,
//! instantiate (each model in turn), initialize, one step, free, `dlclose`, in a child process
//! (this test binary, re-executed on the ignored test [`child_load_unload_cycles`]), with the
//! heap in use (malloc's own count) and the resident set size measured after a warm-up and at
//! the end. Before the fix each cycle left the binary's lazily built tables (model
//! descriptions, GUIDs, variable tables) on the heap, 38 KB per cycle for GaitReference alone,
//! 330 KB on average over the six models.
//!
//! The bounds are what the code needs, not a guess: the heap in use is the same after 10,000
//! cycles as after the warm-up (0 bytes per cycle, its samples differing by 48 bytes with the
//! model of the cycle), so it may grow by less than 1 byte per cycle on average, which any
//! allocation left behind per cycle breaks (malloc's smallest chunk is 32 bytes; one per six
//! cycles, a single model's, is 5 bytes per cycle). It is malloc's count of its chunks, not
//! a measure of time or of the machine, so it is the same on a loaded machine. A leak of 133
//! bytes per cycle (a boxed slice left behind by each fmi2Instantiate, tried) grows it by 144.5
//! bytes per cycle and fails; it passed the former check, 256 bytes per cycle of the resident
//! set size alone (164 bytes per cycle). The resident set size stays checked for what malloc
//! does not count, memory mapped outside it (a mapping left behind per cycle is at least a
//! page, 4096 bytes): measured 6 to 8 bytes per cycle, it moves by whole pages as malloc trims
//! and grows its arenas (its samples 170 KB apart, 18 bytes per cycle), and a transparent huge
//! page that the kernel puts under the heap would add 2 MiB at once (220 bytes per cycle), so
//! its bound stays 256 bytes per cycle.

use std::process::Command;

use kneebench_tests::*;

const CYCLES: usize = 10_000;
const WARM_UP: usize = 500;
const MODELS: &[&str] = &[
    "GaitReference",
    "PidController",
    "ImpedanceController",
    "ClutchScheduler",
    "BenchPlant",
    "BenchHardware",
];

/// The heap in use, in bytes: what malloc has handed out and not had back, over every arena
/// (`mallinfo2`: `uordblks`, plus `hblkhd` for the chunks it mapped on their own).
fn heap_in_use() -> u64 {
    // SAFETY: mallinfo2 only reads the allocator's statistics.
    let m = unsafe { libc::mallinfo2() };
    (m.uordblks + m.hblkhd) as u64
}

/// Resident set size of this process, in bytes.
fn rss() -> u64 {
    let statm = std::fs::read_to_string("/proc/self/statm").unwrap();
    let pages: u64 = statm.split_whitespace().nth(1).unwrap().parse().unwrap();
    pages * 4096
}

#[test]
fn rss_is_flat_over_10000_load_unload_cycles() {
    let out = Command::new(std::env::current_exe().unwrap())
        .args([
            "--ignored",
            "--exact",
            "child_load_unload_cycles",
            "--nocapture",
        ])
        .env("KNEEBENCH_LEAK_CHILD", "1")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // The growth per cycle after the warm-up of the measure on the line `name BEFORE AFTER`.
    let per_cycle = |name: &str| {
        let line = stdout
            .lines()
            .find(|l| l.starts_with(&format!("{name} ")))
            .unwrap_or_else(|| panic!("no {name} line in {stdout}"));
        let v: Vec<u64> = line
            .split_whitespace()
            .skip(1)
            .map(|x| x.parse().unwrap())
            .collect();
        let (after_warm_up, end) = (v[0], v[1]);
        let per_cycle = end.saturating_sub(after_warm_up) as f64 / (CYCLES - WARM_UP) as f64;
        println!(
            "{name} after {WARM_UP} cycles {after_warm_up} bytes, after {CYCLES} {end}: \
             {per_cycle:.2} bytes per cycle"
        );
        per_cycle
    };
    let (heap, rss) = (per_cycle("heap"), per_cycle("rss"));
    // Exact: no allocation outlives its cycle (see the module documentation).
    assert!(
        heap < 1.0,
        "the heap in use grew {heap:.2} bytes per load/unload cycle"
    );
    // Memory mapped outside malloc: page-sized noise (and a huge page) stays below it, a
    // mapping left behind per cycle (4096 bytes or more) does not.
    assert!(rss < 256.0, "RSS grew {rss:.0} bytes per load/unload cycle");
}

#[test]
#[ignore = "the child of rss_is_flat_over_10000_load_unload_cycles"]
fn child_load_unload_cycles() {
    if std::env::var_os("KNEEBENCH_LEAK_CHILD").is_none() {
        return;
    }
    let lib = fmu_library();
    let guids: Vec<String> = MODELS.iter().map(|m| guid_of(m)).collect();
    let (mut after_warm_up, mut heap_after_warm_up) = (0, 0);
    for k in 0..CYCLES {
        if k == WARM_UP {
            after_warm_up = rss();
            heap_after_warm_up = heap_in_use();
        }
        let raw = Raw::load(&lib);
        {
            let m = k % MODELS.len();
            let mut inst = RawInstance::new(&raw, "leak", &guids[m]);
            assert!(!inst.c.is_null(), "{}", inst.log.text());
            inst.initialize(0.0, None);
            assert_eq!(inst.step(0.0, 1e-3), fmi2Status::fmi2OK, "{}", MODELS[m]);
        }
        drop(raw);
    }
    println!("rss {after_warm_up} {}", rss());
    println!("heap {heap_after_warm_up} {}", heap_in_use());
}
