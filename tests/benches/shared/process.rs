//! Timing whole processes, shared by the benches that run `kneebench` as a user does
//! (`peers`, `whole_run`): wall and CPU time of a child process, and the build of the
//! `kneebench` binaries.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use kneebench_tests::repo_root;

/// Wall and CPU seconds of one run.
#[derive(Clone, Copy)]
pub struct Timing {
    /// Wall-clock seconds.
    pub wall: f64,
    /// CPU seconds (user + system).
    pub cpu: f64,
}

/// User + system CPU seconds of the waited-for children of this process so far.
pub fn children_cpu() -> f64 {
    // SAFETY: a zeroed rusage is a valid out-value.
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: a valid out-pointer.
    let r = unsafe { libc::getrusage(libc::RUSAGE_CHILDREN, &mut u) };
    assert_eq!(r, 0, "getrusage");
    let s = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    s(u.ru_utime) + s(u.ru_stime)
}

/// Runs `cmd` to completion as a whole process: its wall and CPU time, or a message.
pub fn time_process(cmd: &mut Command) -> Result<(Timing, String), String> {
    let program = Path::new(cmd.get_program())
        .file_name()
        .unwrap_or_default()
        .to_string_lossy()
        .into_owned();
    let cpu0 = children_cpu();
    let t0 = Instant::now();
    let out = cmd
        .output()
        .map_err(|e| format!("cannot start {program}: {e}"))?;
    let wall = t0.elapsed().as_secs_f64();
    let cpu = children_cpu() - cpu0;
    if !out.status.success() {
        return Err(format!(
            "{program} failed ({}):\n{}{}",
            out.status,
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    Ok((
        Timing { wall, cpu },
        String::from_utf8_lossy(&out.stdout).into_owned(),
    ))
}

/// Builds the `kneebench` and `kneebench-fmu-host` binaries of this source tree.
pub fn build_kneebench() -> Result<PathBuf, String> {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let status = Command::new(&cargo)
        .current_dir(repo_root())
        .args(["build", "--release", "-p", "kneebench-harness", "--bins"])
        .status()
        .map_err(|e| format!("cannot run cargo: {e}"))?;
    if !status.success() {
        return Err(format!(
            "cargo build --release -p kneebench-harness: {status}"
        ));
    }
    // Where cargo put it: `CARGO_TARGET_DIR` (relative to the root it was built from) when set.
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map_or_else(|| repo_root().join("target"), |dir| repo_root().join(dir));
    let exe = target.join("release/kneebench");
    if !exe.is_file() {
        return Err(format!("{} missing after the build", exe.display()));
    }
    Ok(exe)
}
