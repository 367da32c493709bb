//! The user this process acts as: the one owner that files which must be this user's own may
//! have (the bench key file, [`super::auth`]; the harness, which includes this directory, also
//! checks its cache of extracted FMU binaries with it).

/// The effective user id of this process (`geteuid`).
#[cfg(unix)]
pub fn effective_uid() -> u32 {
    // SAFETY: geteuid has no preconditions, cannot fail and touches no memory of ours.
    unsafe { libc::geteuid() }
}

#[cfg(all(test, unix))]
mod tests {
    use super::*;

    /// A file this process creates is owned by its effective user (file system uid).
    #[test]
    fn a_new_file_is_owned_by_the_effective_user() {
        use std::os::unix::fs::MetadataExt;
        let file = tempfile::NamedTempFile::new().unwrap();
        assert_eq!(file.as_file().metadata().unwrap().uid(), effective_uid());
    }
}
