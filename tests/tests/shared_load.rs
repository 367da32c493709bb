//! Loading for runs ([`Binaries::Shared`], the default: only what a run needs extracted, each
//! distinct binary loaded once per process, FMUs read in place from the SSP) against the plain
//! path ([`Binaries::Private`]: every entry extracted, a copy of the binary per FMU): the same
//! systems give the same results bit for bit, and the fast path really shares and skips; the
//! per-user binary cache is used, and a damaged cache file is replaced.
//!
//! One test in this binary: it points the cache (read once per process) at a directory of its
//! own before anything is loaded.

use std::path::Path;

use kneebench_harness::package::export_all;
use kneebench_harness::study::{Actuator, Gait, StudyGains, gait_scenario, write_ssp};
use kneebench_harness::{ArchiveBudget, ArchiveLimits, Binaries, LoadOptions, Outcome, ssp};
use kneebench_tests::fmu_library;

fn options(binaries: Binaries, budget: &std::sync::Arc<ArchiveBudget>) -> LoadOptions {
    LoadOptions {
        binaries,
        budget: Some(budget.clone()),
        ..LoadOptions::default()
    }
}

/// Runs `path` (0.5 s, every output recorded) loaded with `binaries`: the rows, flattened
/// (time first), the column names, the run's archive usage (entries, bytes) and the loaded
/// system (kept to inspect).
fn run(
    path: &Path,
    binaries: Binaries,
) -> (Vec<u64>, Vec<String>, (usize, u64), ssp::LoadedSystem) {
    let budget = ArchiveBudget::new(ArchiveLimits::default());
    let mut loaded = ssp::load_system(path, &options(binaries, &budget)).unwrap();
    loaded.config.stop_time = 0.5;
    let out = loaded.system.run(&loaded.config).unwrap();
    assert!(
        matches!(out.outcome, Outcome::Completed { .. }),
        "{:?}",
        out.outcome
    );
    let mut bits = Vec::new();
    for (t, row) in out.results.times().iter().zip(out.results.rows()) {
        bits.push(t.to_bits());
        bits.extend(row.iter().map(|v| v.to_bits()));
    }
    let usage = (budget.used_entries(), budget.used_bytes());
    (bits, out.results.names().to_vec(), usage, loaded)
}

/// The `.so` files in `dir`.
fn cached(dir: &Path) -> Vec<std::path::PathBuf> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "so"))
        .collect()
}

#[test]
fn the_shared_load_runs_the_study_systems_bit_for_bit_like_the_plain_one() {
    let d = tempfile::tempdir().unwrap();
    let cache = d.path().join("cache");
    // SAFETY: the only test of this binary, before any thread of its own or any load.
    unsafe { std::env::set_var("KNEEBENCH_CACHE_DIR", &cache) };
    let fmus = d.path().join("fmus");
    export_all(&fmu_library(), &fmus).unwrap();
    for actuator in [Actuator::Sea, Actuator::Csea] {
        let scenario = gait_scenario(
            actuator,
            Gait::bench_full(),
            StudyGains::for_actuator(actuator),
            1,
        );
        let path = d.path().join(format!("{actuator:?}.ssp"));
        write_ssp(&scenario, &fmus, &path).unwrap();

        let (plain, plain_names, plain_usage, private) = run(&path, Binaries::Private);
        let (fast, fast_names, fast_usage, shared) = run(&path, Binaries::Shared);
        assert_eq!(plain_names, fast_names, "{actuator:?}");
        assert!(plain.len() > 500 * plain_names.len(), "{actuator:?}");
        assert!(plain == fast, "{actuator:?}: the results differ");
        // The same archives counted: what is left in an archive counts the size it declares.
        assert_eq!(plain_usage, fast_usage, "{actuator:?}");

        // Plain: a binary per FMU inside its directory, everything extracted.
        let components: Vec<_> = private.system.components().collect();
        let binaries: std::collections::HashSet<_> = components
            .iter()
            .map(|(_, f)| f.binary_path().to_path_buf())
            .collect();
        let distinct_fmus: std::collections::HashSet<_> = components
            .iter()
            .map(|(_, f)| f.directory().to_path_buf())
            .collect();
        assert_eq!(binaries.len(), distinct_fmus.len(), "{actuator:?}");
        for (_, f) in &components {
            assert!(f.binary_path().starts_with(f.directory()));
            assert!(f.directory().join("documentation/index.html").is_file());
        }
        // Shared: one binary for every component (all carry kneebench's library), nothing
        // but the model description and the resources extracted, read from inside the SSP.
        let components: Vec<_> = shared.system.components().collect();
        let first = components[0].1.binary_path().to_path_buf();
        assert!(first.is_file());
        assert_eq!(cached(&cache), vec![first.clone()], "{actuator:?}");
        for (name, f) in &components {
            assert_eq!(f.binary_path(), first, "{actuator:?} {name}");
            assert!(f.directory().join("modelDescription.xml").is_file());
            assert!(!f.directory().join("documentation").exists());
            assert!(!f.directory().join("extra").exists());
            assert!(!f.directory().join("binaries").exists());
            assert!(
                f.source_path().starts_with(&path),
                "{}",
                f.source_path().display()
            );
        }
        drop(shared);

        // A damaged cache file (same size, other bytes) is found out by its CRC and replaced;
        // the results do not change.
        let mut bytes = std::fs::read(&first).unwrap();
        let middle = bytes.len() / 2;
        bytes[middle] ^= 0xff;
        std::fs::write(&first, &bytes).unwrap();
        let (again, _, again_usage, reloaded) = run(&path, Binaries::Shared);
        assert!(
            again == plain,
            "{actuator:?}: the results differ after repairing"
        );
        assert_eq!(again_usage, plain_usage);
        assert_eq!(
            reloaded.system.components().next().unwrap().1.binary_path(),
            first
        );
        assert_ne!(std::fs::read(&first).unwrap(), bytes, "not replaced");
    }
}
