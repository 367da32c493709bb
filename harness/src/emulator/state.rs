//! The emulator's persisted state (its `--state` file): the latch and whether a session is
//! live, so that a restart keeps the latch and one under a live session latches
//! (`docs/bench-protocol.md` §10).

use std::path::Path;

use super::EmulatorError;
use crate::bench_protocol::reason;

/// The persisted state: (latch, a session live). Format: `latch R` and `live 0|1` lines.
pub(super) fn read_state(path: &Path) -> Result<(Option<u8>, bool), EmulatorError> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok((None, false)),
        Err(e) => {
            return Err(EmulatorError::Config(format!(
                "state file {}: {e}",
                path.display()
            )));
        }
    };
    let bad = |line: &str| {
        EmulatorError::Config(format!(
            "state file {}: unreadable line `{line}` (expected `latch R` and `live 0|1`)",
            path.display()
        ))
    };
    let (mut latch, mut live) = (None, false);
    for line in text.lines().filter(|l| !l.trim().is_empty()) {
        match line.split_once(' ') {
            Some(("latch", r)) => {
                let r: u8 = r.trim().parse().map_err(|_| bad(line))?;
                if r > reason::MAX || r == reason::SESSION_END {
                    return Err(bad(line));
                }
                latch = (r != reason::NONE).then_some(r);
            }
            Some(("live", l)) => {
                live = match l.trim() {
                    "0" => false,
                    "1" => true,
                    _ => return Err(bad(line)),
                }
            }
            _ => return Err(bad(line)),
        }
    }
    Ok((latch, live))
}

/// Writes the state atomically: a new temporary file in the same directory, created
/// exclusively (`O_EXCL`: never through an existing file or symbolic link) with a random name
/// and mode 0600, renamed over `path`.
pub(super) fn write_state(path: &Path, latch: Option<u8>, live: bool) -> std::io::Result<()> {
    use std::io::Write;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let mut prefix = std::ffi::OsString::from(".");
    prefix.push(path.file_name().unwrap_or_default());
    prefix.push(".");
    let mut f = tempfile::Builder::new()
        .prefix(&prefix)
        .suffix(".tmp")
        .tempfile_in(dir)?;
    writeln!(f, "latch {}", latch.unwrap_or(reason::NONE))?;
    writeln!(f, "live {}", u8::from(live))?;
    // Not synced: the rename makes the file whole for a process that dies (the page cache
    // outlives it), and a sync would stall the serving loop by milliseconds on a busy disk.
    // A bench controller that must survive a power cut syncs (protocol §10).
    f.persist(path).map_err(|e| e.error)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_state_round_trips_and_a_damaged_file_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bench.state");
        assert_eq!(read_state(&path).unwrap(), (None, false));
        write_state(&path, Some(reason::HEARTBEAT_TIMEOUT), true).unwrap();
        assert_eq!(
            read_state(&path).unwrap(),
            (Some(reason::HEARTBEAT_TIMEOUT), true)
        );
        write_state(&path, None, false).unwrap();
        assert_eq!(read_state(&path).unwrap(), (None, false));
        for bad in [
            "latch 4\n",
            "latch 9\n",
            "live 2\n",
            "latch x\n",
            "colour blue\n",
        ] {
            std::fs::write(&path, bad).unwrap();
            let e = read_state(&path).unwrap_err().to_string();
            assert!(e.contains("unreadable line"), "{bad}: {e}");
        }
    }

    /// The temporary file was `<path>.tmp`, made by `File::create`: it followed a symbolic
    /// link planted there (writing, as the emulator's user, wherever it pointed) and was
    /// created 0644.
    #[cfg(unix)]
    #[test]
    fn the_state_is_written_through_a_new_private_file_never_through_a_planted_link() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bench.state");
        let victim = dir.path().join("victim");
        std::fs::write(&victim, "precious\n").unwrap();
        std::os::unix::fs::symlink(&victim, dir.path().join("bench.state.tmp")).unwrap();
        write_state(&path, Some(reason::CLIENT_REQUEST), false).unwrap();
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious\n");
        assert_eq!(
            read_state(&path).unwrap(),
            (Some(reason::CLIENT_REQUEST), false)
        );
        let meta = std::fs::symlink_metadata(&path).unwrap();
        assert!(meta.file_type().is_file());
        assert_eq!(meta.permissions().mode() & 0o777, 0o600);
        // Nothing left beside it but the planted link and its target.
        let mut names: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(names, ["bench.state", "bench.state.tmp", "victim"]);
    }
}
