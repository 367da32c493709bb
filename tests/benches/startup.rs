//! Start-up of the study's systems: `cargo bench -p kneebench-tests --bench startup`.
//!
//! What a run does before its first step, for the study's SEA (4 components, 3 FMUs) and CSEA
//! (5 components, 5 FMUs) `.ssp` files: `ssp::load_system` (the SSP read, the FMUs extracted,
//! their model descriptions parsed, their binaries loaded) and a run of one step (instantiate,
//! initialize, one step, terminate, free), everything dropped after each repeat (so every
//! repeat loads and unloads the binaries again, as a new process would).
//!
//! - **shared**: the default loading for runs ([`Binaries::Shared`]): only the model
//!   description and resources extracted, each distinct binary once per process, the FMUs read
//!   in place from the SSP.
//! - **private**: the previous path ([`Binaries::Private`]), kept as the baseline: every entry of
//!   the SSP and of each FMU extracted, a copy of the binary per FMU.
//!
//! Medians of [`REPEATS`] interleaved repeats, in ms, and private / shared.
use std::path::Path;
use std::time::Instant;

use kneebench_harness::package::export_all;
use kneebench_harness::study::{Actuator, Gait, StudyGains, gait_scenario, write_ssp};
use kneebench_harness::{Binaries, LoadOptions, Outcome, ssp};
use kneebench_tests::fmu_library;

/// Repeats of each measurement.
const REPEATS: usize = 15;

/// Loads `path` with `binaries` and runs one step: seconds for the load, and in all.
#[inline(never)]
fn start(path: &Path, binaries: Binaries) -> (f64, f64) {
    let t0 = Instant::now();
    let mut loaded = ssp::load_system(
        path,
        &LoadOptions {
            binaries,
            ..LoadOptions::default()
        },
    )
    .unwrap();
    let load = t0.elapsed().as_secs_f64();
    loaded.config.stop_time = loaded.config.start_time + loaded.config.step_size;
    let out = loaded.system.run(&loaded.config).unwrap();
    let total = t0.elapsed().as_secs_f64();
    assert!(
        matches!(out.outcome, Outcome::Completed { .. }),
        "{:?}",
        out.outcome
    );
    drop(loaded);
    (load, total)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    // `cargo bench` passes `--bench`; nothing to parse.
    let dir = tempfile::tempdir().unwrap();
    let fmus = dir.path().join("fmus");
    export_all(&fmu_library(), &fmus).expect("export");
    for actuator in [Actuator::Sea, Actuator::Csea] {
        let scenario = gait_scenario(
            actuator,
            Gait::bench_full(),
            StudyGains::for_actuator(actuator),
            1,
        );
        let path = dir.path().join(format!("{actuator:?}.ssp"));
        write_ssp(&scenario, &fmus, &path).unwrap();
        let distinct: std::collections::HashSet<_> =
            scenario.components.iter().map(|c| &c.fmu).collect();
        // Warm up (the page cache, this process's allocator).
        start(&path, Binaries::Shared);
        start(&path, Binaries::Private);
        let (mut shared, mut private) = ((vec![], vec![]), (vec![], vec![]));
        for _ in 0..REPEATS {
            let (l, t) = start(&path, Binaries::Shared);
            shared.0.push(l);
            shared.1.push(t);
            let (l, t) = start(&path, Binaries::Private);
            private.0.push(l);
            private.1.push(t);
        }
        let (sl, st) = (median(shared.0), median(shared.1));
        let (pl, pt) = (median(private.0), median(private.1));
        println!(
            "{actuator:?}.ssp: {} components, {} FMUs; medians of {REPEATS}",
            scenario.components.len(),
            distinct.len()
        );
        println!(
            "  shared   load {:6.2} ms   load + instantiate + initialize + 1 step {:6.2} ms",
            sl * 1e3,
            st * 1e3
        );
        println!(
            "  private  load {:6.2} ms   load + instantiate + initialize + 1 step {:6.2} ms  (the previous path)",
            pl * 1e3,
            pt * 1e3
        );
        println!(
            "  private / shared: load {:.1}x, to the first step {:.1}x",
            pl / sl,
            pt / st
        );
    }
}
