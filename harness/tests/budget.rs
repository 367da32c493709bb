//! One archive budget per run: an SSP and the FMUs inside it share the entry and byte limits,
//! so an archive inside an archive gets what is left, not a fresh allowance.

mod common;

use std::path::{Path, PathBuf};

use kneebench_harness::load::extract_archive_within;
use kneebench_harness::ssp::{self, Ssd, SspComponent, SspSystem};
use kneebench_harness::{ArchiveBudget, ArchiveLimits, Fmu, LoadError, LoadOptions};

/// An SSP with two components whose FMUs are two archive entries (so each is extracted once):
/// returns the SSP's path and the two FMUs'.
fn two_fmu_ssp(dir: &Path) -> (PathBuf, [PathBuf; 2]) {
    let fmu = common::kbtest_fmu(dir);
    let md = Fmu::load(&fmu, &LoadOptions::default())
        .unwrap()
        .model_description()
        .clone();
    let b = dir.join("kbtest-b.fmu");
    std::fs::copy(&fmu, &b).unwrap();
    let ssd = Ssd {
        name: "budget".into(),
        version: "1.0".into(),
        system: SspSystem {
            name: "root".into(),
            components: vec![
                SspComponent::from_model_description("a", "resources/a.fmu", &md),
                SspComponent::from_model_description("b", "resources/b.fmu", &md),
            ],
            connections: vec![],
        },
        default_experiment: None,
    };
    let path = dir.join("two.ssp");
    ssp::write_ssp(
        &ssd,
        &[
            ("resources/a.fmu".into(), fmu.clone()),
            ("resources/b.fmu".into(), b.clone()),
        ],
        &path,
    )
    .unwrap();
    (path, [fmu, b])
}

/// (entries, bytes) of one archive alone.
fn usage(archive: &Path) -> (usize, u64) {
    let d = tempfile::tempdir().unwrap();
    let budget = ArchiveBudget::new(ArchiveLimits::default());
    extract_archive_within(archive, d.path(), &budget).unwrap();
    (budget.used_entries(), budget.used_bytes())
}

fn load(ssp_path: &Path, limits: ArchiveLimits) -> Result<(), LoadError> {
    match ssp::load_system(
        ssp_path,
        &LoadOptions {
            limits,
            ..LoadOptions::default()
        },
    ) {
        Ok(_) => Ok(()),
        Err(ssp::SspError::Load { source, .. }) => Err(source),
        Err(e) => panic!("{e}"),
    }
}

#[test]
fn an_ssp_and_its_fmus_share_one_budget() {
    let d = tempfile::tempdir().unwrap();
    let (ssp_path, [a, b]) = two_fmu_ssp(d.path());
    let (se, sb) = usage(&ssp_path);
    let (ae, ab) = usage(&a);
    let (be, bb) = usage(&b);
    let (entries, bytes) = (se + ae + be, sb + ab + bb);
    let generous = ArchiveLimits::default();

    // Exactly the run's total: loads.
    load(
        &ssp_path,
        ArchiveLimits {
            max_entries: entries,
            max_total_bytes: bytes,
            ..generous
        },
    )
    .unwrap();

    // One byte less: every archive alone fits (each is well under the limit), together they do
    // not. The last FMU's last entry passes it.
    assert!(sb.max(ab).max(bb) < bytes - 1);
    let e = load(
        &ssp_path,
        ArchiveLimits {
            max_total_bytes: bytes - 1,
            ..generous
        },
    )
    .unwrap_err();
    assert!(
        matches!(&e, LoadError::TotalTooLarge { limit, .. } if *limit == bytes - 1),
        "{e:?}"
    );
    assert!(
        e.to_string().contains("counting every archive of this run"),
        "{e}"
    );

    // One entry less: the same for the entry count.
    assert!(se.max(ae).max(be) < entries - 1);
    let e = load(
        &ssp_path,
        ArchiveLimits {
            max_entries: entries - 1,
            ..generous
        },
    )
    .unwrap_err();
    assert!(
        matches!(&e, LoadError::TooManyEntries { count, limit } if *count == entries && *limit == entries - 1),
        "{e:?}"
    );
}

#[test]
fn a_budget_passed_to_single_loads_is_shared_by_them() {
    let d = tempfile::tempdir().unwrap();
    let fmu = common::kbtest_fmu(d.path());
    let (_, one) = usage(&fmu);
    let budget = ArchiveBudget::new(ArchiveLimits {
        max_total_bytes: 2 * one,
        ..ArchiveLimits::default()
    });
    let options = LoadOptions {
        budget: Some(budget.clone()),
        ..LoadOptions::default()
    };
    Fmu::load(&fmu, &options).unwrap();
    Fmu::load(&fmu, &options).unwrap();
    assert_eq!(budget.used_bytes(), 2 * one);
    let e = Fmu::load(&fmu, &options).unwrap_err();
    assert!(matches!(e, LoadError::TotalTooLarge { .. }), "{e:?}");
    // Without a shared budget every load gets the limits afresh.
    let fresh = LoadOptions {
        limits: *budget.limits(),
        ..LoadOptions::default()
    };
    for _ in 0..3 {
        Fmu::load(&fmu, &fresh).unwrap();
    }
}
