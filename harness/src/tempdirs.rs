//! The private directories FMU and SSP archives are extracted into, and those a sweep writes
//! its scenario system into.
//!
//! Each is named `kneebench-<kind>-<pid>-<random>` in the system's temporary directory and
//! removed when its owner is dropped: at the end of a run, after an error, and after a run
//! stopped by a signal (the run ends at a communication point and unwinds normally). A
//! process that dies without unwinding (killed, crashed, a second Ctrl-C) leaves its
//! directories behind; [`remove_stale`], called when the CLI starts, removes those whose
//! process is gone.

use std::path::{Path, PathBuf};

/// The name prefix of every extraction directory.
const PREFIX: &str = "kneebench-";

/// The kinds of directory, as named: extracted FMUs and SSPs, and a sweep's scenario `.ssp`
/// (`sweep::Prepared`).
const KINDS: [&str; 3] = ["fmu", "ssp", "sweep"];

/// A fresh private directory `kneebench-<kind>-<pid>-<random>` in the temporary directory.
pub fn create(kind: &str) -> std::io::Result<tempfile::TempDir> {
    tempfile::Builder::new()
        .prefix(&format!("{PREFIX}{kind}-{}-", std::process::id()))
        .tempdir()
}

/// The process id in the name of an extraction directory, if it is one.
fn owner(name: &str) -> Option<u32> {
    let rest = name.strip_prefix(PREFIX)?;
    let (kind, rest) = rest.split_once('-')?;
    if !KINDS.contains(&kind) {
        return None;
    }
    let (pid, random) = rest.split_once('-')?;
    if random.is_empty() || !pid.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    pid.parse().ok()
}

/// Whether process `pid` exists (Linux: `/proc/<pid>`).
fn alive(pid: u32) -> bool {
    Path::new("/proc").join(pid.to_string()).exists()
}

/// Removes the extraction directories in `dir` left by processes that no longer exist;
/// returns the ones removed. Errors (a directory of another user, say) are skipped.
pub fn remove_stale_in(dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut removed = Vec::new();
    for e in entries.flatten() {
        let name = e.file_name();
        let Some(pid) = name.to_str().and_then(owner) else {
            continue;
        };
        if pid == std::process::id() || alive(pid) {
            continue;
        }
        let is_dir = e.file_type().is_ok_and(|t| t.is_dir());
        if is_dir && std::fs::remove_dir_all(e.path()).is_ok() {
            removed.push(e.path());
        }
    }
    removed
}

/// [`remove_stale_in`] the system's temporary directory.
pub fn remove_stale() -> Vec<PathBuf> {
    remove_stale_in(&std::env::temp_dir())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_carry_the_pid_and_only_dead_owners_are_cleaned() {
        let d = tempfile::tempdir().unwrap();
        assert_eq!(owner("kneebench-fmu-123-abc"), Some(123));
        assert_eq!(owner("kneebench-ssp-9-x"), Some(9));
        assert_eq!(owner("kneebench-sweep-31-x"), Some(31));
        assert_eq!(owner("kneebench-fmu-abc"), None);
        assert_eq!(owner("kneebench-other-1-x"), None);
        assert_eq!(owner("kneebench-fmu-12-"), None);
        // A pid above the kernel's maximum (4194304) belongs to no process.
        let dead = d.path().join("kneebench-fmu-99999999-aaaa");
        let dead_sweep = d.path().join("kneebench-sweep-99999998-dddd");
        let mine = d
            .path()
            .join(format!("kneebench-ssp-{}-bbbb", std::process::id()));
        let init = d.path().join("kneebench-fmu-1-cccc");
        let other = d.path().join("unrelated-99999999-x");
        for p in [&dead, &dead_sweep, &mine, &init, &other] {
            std::fs::create_dir(p).unwrap();
            std::fs::write(p.join("f"), b"x").unwrap();
        }
        let mut removed = remove_stale_in(d.path());
        removed.sort();
        assert_eq!(removed, vec![dead.clone(), dead_sweep.clone()]);
        assert!(
            !dead.exists()
                && !dead_sweep.exists()
                && mine.exists()
                && init.exists()
                && other.exists()
        );
        let made = create("fmu").unwrap();
        let name = made
            .path()
            .file_name()
            .unwrap()
            .to_str()
            .unwrap()
            .to_string();
        assert_eq!(owner(&name), Some(std::process::id()));
    }
}
