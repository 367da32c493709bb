//! Authentication of the bench protocol: the bench's secret key and its key file, the
//! HMAC-SHA256 tags every frame carries, and the per-session keys the handshake derives.
//!
//! * [`Key`]: 32 random bytes shared by the bench server and its masters, kept in a key file
//!   (64 hexadecimal digits and a newline) that only its owner may read or write
//!   ([`Key::create_file`], [`Key::load_file`]).
//! * [`TagKey`]: one HMAC-SHA256 key, precomputed (the inner and outer pads are hashed once),
//!   producing and checking the 16-byte truncated tags of frames.
//! * [`Key::handshake`] and [`Key::session`]: the key of the handshake frames, and the two
//!   direction keys of a session, derived from the bench key, the session number and both
//!   sides' fresh nonces (`docs/bench-protocol.md`, §6).

use std::path::Path;

use hmac::{Hmac, KeyInit, Mac};
use sha2::Sha256;

#[cfg(unix)]
use super::user::effective_uid;

/// Bytes of the bench key.
pub const KEY_LEN: usize = 32;
/// Bytes of a frame's tag: HMAC-SHA256 truncated to its first 128 bits.
pub const TAG_LEN: usize = 16;
/// Bytes of a handshake nonce.
pub const NONCE_LEN: usize = 16;

/// Why a key could not be made, read or used.
#[derive(Debug, thiserror::Error)]
pub enum KeyError {
    /// The key file cannot be read or written.
    #[error("key file {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// The key file may be read or written by others than its owner.
    #[error(
        "key file {path} is accessible to its group or to others (mode {mode:03o}); the key is a secret: `chmod 600 {path}`"
    )]
    Permissions {
        /// The file.
        path: String,
        /// Its permission bits.
        mode: u32,
    },
    /// The key file is no regular file (a directory, a FIFO, a device): reading it would
    /// fail, block or never end.
    #[error("key file {0} is not a regular file; give the file written by `kneebench key new`")]
    NotAFile(String),
    /// The key file holds a key that is no secret (the public loopback key, the fuzz key, a
    /// byte repeated).
    #[error("key file {path}: {why}; make a secret key with `kneebench key new FILE`")]
    NotSecret {
        /// The file.
        path: String,
        /// What is wrong with the key.
        why: WeakKey,
    },
    /// The key file is owned by another user than the one running this program: that user
    /// (or whoever it is) can change the key.
    #[error(
        "key file {path} is owned by user {owner}, not by the user running this (user {user}); the key must be the user's own: `chown {user} {path}` (or run as its owner)"
    )]
    Owner {
        /// The file.
        path: String,
        /// The file's owner (uid).
        owner: u32,
        /// The effective user (uid) of this process.
        user: u32,
    },
    /// The key file's directory lets others replace the file: writable by its group or by
    /// others without the sticky bit, or owned by another user than this one or root.
    #[error("key file {path}: its directory {dir} {why}: others could replace the key")]
    Directory {
        /// The file.
        path: String,
        /// The directory.
        dir: String,
        /// What is wrong with it (with the command that mends it).
        why: String,
    },
    /// The key file does not hold 64 hexadecimal digits.
    #[error(
        "key file {0}: expected one line of 64 hexadecimal digits (a key from `kneebench key new`)"
    )]
    Format(String),
    /// The key file exists already (never overwritten).
    #[error("key file {0} exists already; not overwritten")]
    Exists(String),
    /// The operating system's random number generator failed.
    #[error("random number generator: {0}")]
    Random(String),
}

/// Why a key of the right form is no secret (refused in a key file, `docs/bench-protocol.md`
/// §6.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum WeakKey {
    /// The public loopback development key ([`Key::loopback`]).
    #[error(
        "it is the public loopback development key (docs/bench-protocol.md §6.1), which everyone can compute"
    )]
    Loopback,
    /// The published key of the fuzz targets (`fuzzing::fuzz_key`).
    #[error("it is the published key of the protocol's fuzz targets")]
    Fuzz,
    /// All 32 bytes equal (64 zeros, say): no random key.
    #[error("all its 32 bytes are 0x{0:02x}: not a random key")]
    Repeated(u8),
}

/// Fills `buf` from the operating system's random number generator.
pub fn random_bytes(buf: &mut [u8]) -> Result<(), KeyError> {
    getrandom::fill(buf).map_err(|e| KeyError::Random(e.to_string()))
}

/// A fresh handshake nonce.
pub fn nonce() -> Result<[u8; NONCE_LEN], KeyError> {
    let mut n = [0u8; NONCE_LEN];
    random_bytes(&mut n)?;
    Ok(n)
}

/// The bench's secret key.
#[derive(Clone, PartialEq, Eq)]
pub struct Key([u8; KEY_LEN]);

impl std::fmt::Debug for Key {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Never print the secret.
        f.write_str("Key(..)")
    }
}

const HANDSHAKE_LABEL: &[u8] = b"kneebench bench protocol 2: handshake";
const C2S_LABEL: &[u8] = b"kneebench bench protocol 2: client to server";
const S2C_LABEL: &[u8] = b"kneebench bench protocol 2: server to client";
const LOOPBACK_LABEL: &[u8] = b"kneebench loopback development key: public, no secret";

impl Key {
    /// A key from its bytes.
    pub fn from_bytes(bytes: [u8; KEY_LEN]) -> Self {
        Self(bytes)
    }

    /// A new random key.
    pub fn generate() -> Result<Self, KeyError> {
        let mut k = [0u8; KEY_LEN];
        random_bytes(&mut k)?;
        Ok(Self(k))
    }

    /// The public key of keyless operation on loopback (`docs/bench-protocol.md`, §6.1): the
    /// SHA-256 of a published text. It authenticates nothing (everyone knows it); a server
    /// uses it only bound to a loopback address, a client only towards one.
    pub fn loopback() -> Self {
        use sha2::Digest;
        Self(Sha256::digest(LOOPBACK_LABEL).into())
    }

    /// The key as 64 lowercase hexadecimal digits (the key file's text, without the newline).
    pub fn to_hex(&self) -> String {
        self.0.iter().map(|b| format!("{b:02x}")).collect()
    }

    /// A key from 64 hexadecimal digits (surrounding white space ignored), as a key file holds
    /// it: `None` if the text is not 64 hexadecimal digits, `Some(Err)` for a key that is no
    /// secret ([`Key::weakness`]), which a key file must not hold.
    pub fn from_hex(text: &str) -> Option<Result<Self, WeakKey>> {
        let t = text.trim();
        if t.len() != 2 * KEY_LEN || !t.is_ascii() {
            return None;
        }
        let mut k = [0u8; KEY_LEN];
        for (i, b) in k.iter_mut().enumerate() {
            *b = u8::from_str_radix(&t[2 * i..2 * i + 2], 16).ok()?;
        }
        let key = Self(k);
        Some(match key.weakness() {
            Some(why) => Err(why),
            None => Ok(key),
        })
    }

    /// Why this key is no secret: the public loopback key, the fuzz targets' key, or one byte
    /// repeated (`None`: none of these; a key from [`Key::generate`] is none of them but with
    /// a probability of 2^-248).
    pub fn weakness(&self) -> Option<WeakKey> {
        if *self == Self::loopback() {
            Some(WeakKey::Loopback)
        } else if *self == super::fuzzing::fuzz_key() {
            Some(WeakKey::Fuzz)
        } else if self.0.iter().all(|&b| b == self.0[0]) {
            Some(WeakKey::Repeated(self.0[0]))
        } else {
            None
        }
    }

    /// Writes a new random key to `path`, readable and writable by its owner only (mode 0600,
    /// set at creation). An existing file is never overwritten.
    pub fn create_file(path: &Path) -> Result<Self, KeyError> {
        use std::io::Write;
        let name = path.display().to_string();
        let key = Self::generate()?;
        let mut options = std::fs::OpenOptions::new();
        options.write(true).create_new(true);
        #[cfg(unix)]
        {
            use std::os::unix::fs::OpenOptionsExt;
            options.mode(0o600);
        }
        let mut file = options.open(path).map_err(|source| {
            if source.kind() == std::io::ErrorKind::AlreadyExists {
                KeyError::Exists(name.clone())
            } else {
                KeyError::Io {
                    path: name.clone(),
                    source,
                }
            }
        })?;
        writeln!(file, "{}", key.to_hex())
            .and_then(|_| file.sync_all())
            .map_err(|source| KeyError::Io { path: name, source })?;
        Ok(key)
    }

    /// Reads the key file at `path`; refuses a file that is not a regular file, and on Unix
    /// one that its group or others may read or write, that another user owns, or whose
    /// directory others may write to ([`check_key_directory`]); refuses a key that is no
    /// secret ([`Key::weakness`]).
    pub fn load_file(path: &Path) -> Result<Self, KeyError> {
        let name = path.display().to_string();
        let io = |source| KeyError::Io {
            path: name.clone(),
            source,
        };
        let meta = std::fs::metadata(path).map_err(io)?;
        if !meta.is_file() {
            return Err(KeyError::NotAFile(name));
        }
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt;
            use std::os::unix::fs::PermissionsExt;
            let mode = meta.permissions().mode() & 0o777;
            if mode & 0o077 != 0 {
                return Err(KeyError::Permissions { path: name, mode });
            }
            let user = effective_uid();
            if meta.uid() != user {
                return Err(KeyError::Owner {
                    path: name,
                    owner: meta.uid(),
                    user,
                });
            }
            check_key_directory(path, user)?;
        }
        // A key file is one short line; do not read an arbitrarily large file.
        if meta.len() > 256 {
            return Err(KeyError::Format(name));
        }
        let text = std::fs::read_to_string(path).map_err(io)?;
        match Self::from_hex(&text) {
            Some(Ok(key)) => Ok(key),
            Some(Err(why)) => Err(KeyError::NotSecret { path: name, why }),
            None => Err(KeyError::Format(name)),
        }
    }

    fn derive(&self, parts: &[&[u8]]) -> TagKey {
        let mut mac = TagKey::mac(&self.0);
        for p in parts {
            mac.update(p);
        }
        TagKey::new(&mac.finalize().into_bytes())
    }

    /// The key of the handshake frames (HELLO, WELCOME, REFUSE).
    pub fn handshake(&self) -> TagKey {
        self.derive(&[HANDSHAKE_LABEL])
    }

    /// The session keys of `session` from both sides' nonces.
    pub fn session(
        &self,
        session: u32,
        client_nonce: &[u8; NONCE_LEN],
        server_nonce: &[u8; NONCE_LEN],
    ) -> SessionKeys {
        let s = session.to_be_bytes();
        SessionKeys {
            client_to_server: self.derive(&[C2S_LABEL, &s, client_nonce, server_nonce]),
            server_to_client: self.derive(&[S2C_LABEL, &s, client_nonce, server_nonce]),
        }
    }
}

/// The two keys of a session, one per direction (so that a frame cannot be reflected back to
/// its sender).
#[derive(Clone)]
pub struct SessionKeys {
    /// Tags the client's frames.
    pub client_to_server: TagKey,
    /// Tags the server's frames.
    pub server_to_client: TagKey,
}

impl std::fmt::Debug for SessionKeys {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("SessionKeys(..)")
    }
}

/// An HMAC-SHA256 key with its pads hashed once; tags are the first [`TAG_LEN`] bytes of the
/// HMAC.
#[derive(Clone)]
pub struct TagKey(Hmac<Sha256>);

impl std::fmt::Debug for TagKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("TagKey(..)")
    }
}

impl TagKey {
    fn mac(key: &[u8]) -> Hmac<Sha256> {
        // HMAC takes keys of any length: this cannot fail.
        <Hmac<Sha256> as KeyInit>::new_from_slice(key).unwrap_or_else(|_| unreachable!())
    }

    /// A tag key from raw key bytes.
    pub fn new(key: &[u8]) -> Self {
        Self(Self::mac(key))
    }

    /// The tag of `bytes`.
    pub fn tag(&self, bytes: &[u8]) -> [u8; TAG_LEN] {
        let mut mac = self.0.clone();
        mac.update(bytes);
        let full = mac.finalize().into_bytes();
        let mut t = [0u8; TAG_LEN];
        t.copy_from_slice(&full[..TAG_LEN]);
        t
    }

    /// Whether `tag` is the tag of `bytes` (compared in constant time).
    pub fn verify(&self, bytes: &[u8], tag: &[u8]) -> bool {
        if tag.len() != TAG_LEN {
            return false;
        }
        let mut mac = self.0.clone();
        mac.update(bytes);
        mac.verify_truncated_left(tag).is_ok()
    }
}

/// Checks that no other user can replace the key file at `path`: its directory (that of the
/// path as given and, through symbolic links, that of the file itself) must be owned by
/// `user` or root and not writable by its group or others, unless sticky (like `/tmp`, where
/// only a file's owner may remove or rename it).
#[cfg(unix)]
pub fn check_key_directory(path: &Path, user: u32) -> Result<(), KeyError> {
    use std::os::unix::fs::{MetadataExt, PermissionsExt};
    let name = path.display().to_string();
    let parent = |p: &Path| match p.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => Path::new(".").to_path_buf(),
    };
    let mut dirs = vec![parent(path)];
    if let Ok(real) = std::fs::canonicalize(path) {
        dirs.push(parent(&real));
    }
    for dir in dirs {
        let meta = std::fs::metadata(&dir).map_err(|source| KeyError::Io {
            path: dir.display().to_string(),
            source,
        })?;
        let mode = meta.permissions().mode();
        let d = dir.display().to_string();
        let why = if meta.uid() != user && meta.uid() != 0 {
            Some(format!(
                "is owned by user {} (neither this user {user} nor root); keep the key in a directory of your own",
                meta.uid()
            ))
        } else if mode & 0o022 != 0 && mode & 0o1000 == 0 {
            Some(format!(
                "is writable by its group or others (mode {:03o}) and not sticky; `chmod go-w {d}`",
                mode & 0o777
            ))
        } else {
            None
        };
        if let Some(why) = why {
            return Err(KeyError::Directory {
                path: name,
                dir: d,
                why,
            });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hmac_sha256_matches_rfc_4231_case_2() {
        // RFC 4231, test case 2: key "Jefe", data "what do ya want for nothing?".
        let k = TagKey::new(b"Jefe");
        let t = k.tag(b"what do ya want for nothing?");
        assert_eq!(
            t,
            [
                0x5b, 0xdc, 0xc1, 0x46, 0xbf, 0x60, 0x75, 0x4e, 0x6a, 0x04, 0x24, 0x26, 0x08, 0x95,
                0x75, 0xc7
            ]
        );
        assert!(k.verify(b"what do ya want for nothing?", &t));
        assert!(!k.verify(b"what do ya want for nothing!", &t));
        assert!(!k.verify(b"what do ya want for nothing?", &t[..15]));
    }

    #[test]
    fn session_keys_differ_by_direction_nonce_and_session() {
        let k = Key::from_bytes([7; KEY_LEN]);
        let a = k.session(1, &[1; NONCE_LEN], &[2; NONCE_LEN]);
        let b = k.session(1, &[1; NONCE_LEN], &[3; NONCE_LEN]);
        let c = k.session(2, &[1; NONCE_LEN], &[2; NONCE_LEN]);
        let msg = b"frame";
        let tags = [
            a.client_to_server.tag(msg),
            a.server_to_client.tag(msg),
            b.client_to_server.tag(msg),
            c.client_to_server.tag(msg),
            k.handshake().tag(msg),
            Key::from_bytes([8; KEY_LEN]).handshake().tag(msg),
        ];
        for i in 0..tags.len() {
            for j in i + 1..tags.len() {
                assert_ne!(tags[i], tags[j], "{i} {j}");
            }
        }
    }

    #[test]
    fn key_files_are_created_private_and_refused_when_others_can_read_them() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bench.key");
        let key = Key::create_file(&path).unwrap();
        assert_eq!(Key::load_file(&path).unwrap(), key);
        assert!(matches!(Key::create_file(&path), Err(KeyError::Exists(_))));
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(&path).unwrap().permissions().mode() & 0o777;
            assert_eq!(mode, 0o600);
            for bad in [0o644, 0o640, 0o604, 0o660, 0o602] {
                std::fs::set_permissions(&path, std::fs::Permissions::from_mode(bad)).unwrap();
                let e = Key::load_file(&path).unwrap_err();
                assert!(matches!(e, KeyError::Permissions { .. }), "{bad:o}: {e}");
                assert!(e.to_string().contains("chmod 600"), "{e}");
            }
            std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o400)).unwrap();
            assert_eq!(Key::load_file(&path).unwrap(), key);
        }
        let bad = dir.path().join("bad.key");
        std::fs::write(&bad, "not a key\n").unwrap();
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(&bad, std::fs::Permissions::from_mode(0o600)).unwrap();
        }
        assert!(matches!(Key::load_file(&bad), Err(KeyError::Format(_))));
        let e = Key::load_file(dir.path()).unwrap_err();
        assert!(matches!(e, KeyError::NotAFile(_)), "{e}");
        assert!(e.to_string().contains("is not a regular file"), "{e}");
        assert!(matches!(
            Key::load_file(&dir.path().join("missing")),
            Err(KeyError::Io { .. })
        ));
        assert_eq!(format!("{key:?}"), "Key(..)");
    }

    #[test]
    fn hex_round_trips() {
        let k = Key::generate().unwrap();
        assert_eq!(Key::from_hex(&k.to_hex()), Some(Ok(k.clone())));
        assert_eq!(Key::from_hex(&format!(" {}\n", k.to_hex())), Some(Ok(k)));
        assert_eq!(Key::from_hex("00"), None);
        assert_eq!(Key::from_hex(&"g".repeat(64)), None);
        assert_ne!(Key::loopback(), Key::from_bytes([0; KEY_LEN]));
    }

    /// Writes `text` as a key file of mode 0600 in `dir`.
    fn key_file(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600)).unwrap();
        }
        path
    }

    #[test]
    fn keys_that_are_no_secret_are_refused_in_key_files() {
        let dir = tempfile::tempdir().unwrap();
        for (key, why, says) in [
            (
                Key::loopback(),
                WeakKey::Loopback,
                "public loopback development key",
            ),
            (
                super::super::fuzzing::fuzz_key(),
                WeakKey::Fuzz,
                "fuzz targets",
            ),
            (
                Key::from_bytes([0; KEY_LEN]),
                WeakKey::Repeated(0),
                "all its 32 bytes are 0x00",
            ),
            (
                Key::from_bytes([0xff; KEY_LEN]),
                WeakKey::Repeated(0xff),
                "all its 32 bytes are 0xff",
            ),
        ] {
            assert_eq!(key.weakness(), Some(why));
            assert_eq!(Key::from_hex(&key.to_hex()), Some(Err(why)));
            let path = key_file(dir.path(), "weak.key", &format!("{}\n", key.to_hex()));
            let e = Key::load_file(&path).unwrap_err();
            assert!(matches!(e, KeyError::NotSecret { .. }), "{e}");
            let text = e.to_string();
            assert!(
                text.contains(says) && text.contains("kneebench key new"),
                "{text}"
            );
        }
        // One byte off a repeated key is no longer refused (nor is a random key).
        let mut bytes = [0u8; KEY_LEN];
        bytes[31] = 1;
        assert_eq!(Key::from_bytes(bytes).weakness(), None);
        assert_eq!(Key::generate().unwrap().weakness(), None);
    }

    #[cfg(unix)]
    #[test]
    fn key_files_of_another_user_or_in_a_directory_others_can_write_are_refused() {
        use std::os::unix::fs::{MetadataExt, PermissionsExt};
        let dir = tempfile::tempdir().unwrap();
        let user = effective_uid();
        assert_eq!(user, std::fs::metadata(dir.path()).unwrap().uid());
        let key = Key::generate().unwrap();
        let path = key_file(dir.path(), "bench.key", &key.to_hex());
        assert_eq!(Key::load_file(&path).unwrap(), key);
        // The directory writable by its group or others, unless sticky.
        for (mode, refused) in [
            (0o770, true),
            (0o707, true),
            (0o777, true),
            (0o1777, false),
            (0o755, false),
        ] {
            std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(mode)).unwrap();
            let r = Key::load_file(&path);
            assert_eq!(r.is_err(), refused, "{mode:o}: {r:?}");
            if let Err(e) = r {
                assert!(matches!(e, KeyError::Directory { .. }), "{e}");
                assert!(e.to_string().contains("chmod go-w"), "{e}");
            }
        }
        std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o700)).unwrap();
        // A file owned by another user: only root can make one to try.
        if user == 0 {
            std::os::unix::fs::chown(&path, Some(65534), None).unwrap();
            let e = Key::load_file(&path).unwrap_err();
            assert!(matches!(e, KeyError::Owner { owner: 65534, .. }), "{e}");
            assert!(e.to_string().contains("owned by user 65534"), "{e}");
            std::os::unix::fs::chown(&path, Some(0), None).unwrap();
            std::os::unix::fs::chown(dir.path(), Some(65534), None).unwrap();
            let e = Key::load_file(&path).unwrap_err();
            assert!(matches!(e, KeyError::Directory { .. }), "{e}");
            assert!(e.to_string().contains("owned by user 65534"), "{e}");
        }
    }
}
