//! CURVE key pairs and the key files `paddock keys generate` writes.
//!
//! Reading is strict, because a key file that half-parses is worse than none: every key
//! must be 40 characters of the Z85 alphabet encoding 32 bytes (no silent decoding
//! errors: libzmq's own decoder leaves the all-zero key behind on a bad character), and a
//! secret key file's `public` must be the public key of its `secret` (derived with
//! libzmq's `zmq_curve_public`), so a pair spliced from two key pairs is refused. Errors
//! name the file, the field and what is wrong, and never print a secret key.
//!
//! Writing is atomic and private: the file is created with mode 0600 in the target
//! directory under a temporary name (there is no moment at which it is readable by
//! others) and then moved into place.

use std::io::Write;
use std::path::{Path, PathBuf};

/// A CURVE key pair, both halves as 40-character Z85 text.
#[derive(Clone, PartialEq, Eq)]
pub struct KeyPair {
    pub public: String,
    pub secret: String,
}

impl std::fmt::Debug for KeyPair {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("KeyPair")
            .field("public", &self.public)
            .field("secret", &"<hidden>")
            .finish()
    }
}

/// Errors reading, writing or using keys; each names the file or the key.
#[derive(Debug, thiserror::Error)]
pub enum KeyError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {reason}")]
    Format { path: PathBuf, reason: String },
    /// A key that is present but unusable; `reason` never contains a secret key.
    #[error("{path}: line {line}: field `{field}`: {reason}")]
    Key {
        path: PathBuf,
        line: usize,
        field: &'static str,
        reason: String,
    },
    #[error("{path} exists; pass --force to overwrite it (old keys stop working)")]
    Exists { path: PathBuf },
    #[error("zmq: {0}")]
    Zmq(#[from] zmq::Error),
}

/// The Z85 alphabet (ZeroMQ RFC 32).
const Z85: &[u8; 85] =
    b"0123456789abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ.-:+=^!/*?&<>()[]{}@%$#";

/// Length of a Z85 CURVE key (32 bytes).
pub const KEY_Z85_LEN: usize = 40;

/// Decodes Z85 text strictly: length a multiple of 5, every character in the alphabet,
/// every 5-character group below 2^32. The error says what is wrong without repeating
/// the text (it may be a secret).
pub fn z85_decode(text: &str) -> Result<Vec<u8>, String> {
    let bytes = text.as_bytes();
    if !bytes.len().is_multiple_of(5) {
        return Err(format!(
            "{} characters is not a multiple of 5, so not Z85",
            bytes.len()
        ));
    }
    let mut out = Vec::with_capacity(bytes.len() / 5 * 4);
    for (g, group) in bytes.chunks(5).enumerate() {
        let mut value: u64 = 0;
        for (i, &c) in group.iter().enumerate() {
            let Some(digit) = Z85.iter().position(|&z| z == c) else {
                return Err(format!(
                    "character {} is not in the Z85 alphabet",
                    g * 5 + i + 1
                ));
            };
            value = value * 85 + digit as u64;
        }
        let value = u32::try_from(value)
            .map_err(|_| format!("characters {}..{} overflow 32 bits", g * 5 + 1, g * 5 + 5))?;
        out.extend_from_slice(&value.to_be_bytes());
    }
    Ok(out)
}

/// Checks one Z85 CURVE key: 40 characters decoding to 32 bytes.
pub fn check_key(text: &str) -> Result<Vec<u8>, String> {
    let n = text.chars().count();
    if n != KEY_Z85_LEN {
        return Err(format!(
            "has {n} characters; a Z85 CURVE key has {KEY_Z85_LEN}"
        ));
    }
    z85_decode(text)
}

/// The public key of a secret key (both Z85), computed by libzmq.
pub fn public_of_secret(secret: &str) -> Result<String, String> {
    check_key(secret)?;
    let secret_c = std::ffi::CString::new(secret).map_err(|_| "contains a NUL".to_string())?;
    let mut public = [0u8; KEY_Z85_LEN + 1];
    // SAFETY: libzmq reads a NUL-terminated 40-character Z85 secret (checked above) and
    // writes 41 bytes (40 characters and a NUL) into `public`, which has that size.
    let rc = unsafe { zmq_curve_public(public.as_mut_ptr().cast(), secret_c.as_ptr()) };
    if rc != 0 {
        return Err("libzmq cannot derive its public key (is CURVE built in?)".into());
    }
    String::from_utf8(public[..KEY_Z85_LEN].to_vec()).map_err(|_| "libzmq returned non-Z85".into())
}

unsafe extern "C" {
    // libzmq's own function, linked by this crate's build; the zmq crate does not
    // expose it.
    fn zmq_curve_public(
        z85_public_key: *mut std::ffi::c_char,
        z85_secret_key: *const std::ffi::c_char,
    ) -> std::ffi::c_int;
}

/// A short fingerprint of a public key for logs and error messages: the first 8 hex
/// digits of the SHA-256 of its 32 bytes (of the text itself if it is not Z85). The
/// broker logs the same fingerprint when it refuses the key.
pub fn fingerprint(public: &str) -> String {
    use sha2::{Digest, Sha256};
    let bytes = z85_decode(public).unwrap_or_else(|_| public.as_bytes().to_vec());
    Sha256::digest(&bytes)[..4]
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

impl KeyPair {
    /// A fresh random key pair.
    pub fn generate() -> Result<Self, KeyError> {
        let kp = zmq::CurveKeyPair::new()?;
        let enc = |k: &[u8]| {
            zmq::z85_encode(k).map_err(|e| KeyError::Format {
                path: PathBuf::new(),
                reason: e.to_string(),
            })
        };
        Ok(Self {
            public: enc(&kp.public_key)?,
            secret: enc(&kp.secret_key)?,
        })
    }

    /// The text of a secret key file.
    pub fn to_secret_file(&self) -> String {
        format!(
            "# Paddock CURVE key pair: keep this file secret\npublic = \"{}\"\nsecret = \"{}\"\n",
            self.public, self.secret
        )
    }

    /// Reads a secret key file: both keys valid, and `public` the public key of `secret`.
    pub fn read(path: &Path) -> Result<Self, KeyError> {
        let file = parse_key_file(path)?;
        let Some((secret_line, secret)) = file.secret else {
            return Err(KeyError::Format {
                path: path.into(),
                reason: "no `secret = \"...\"` line: this is not a secret key file".into(),
            });
        };
        let Some((_, public)) = file.public else {
            return Err(KeyError::Format {
                path: path.into(),
                reason: "no `public = \"...\"` line beside the secret key".into(),
            });
        };
        let derived = public_of_secret(&secret).map_err(|reason| KeyError::Key {
            path: path.into(),
            line: secret_line,
            field: "secret",
            reason,
        })?;
        if derived != public {
            return Err(KeyError::Key {
                path: path.into(),
                line: secret_line,
                field: "secret",
                reason: format!(
                    "its public key (fingerprint {}) is not the file's `public` (fingerprint {}): \
                     the two halves come from different key pairs",
                    fingerprint(&derived),
                    fingerprint(&public)
                ),
            });
        }
        Ok(Self { public, secret })
    }
}

/// The text of a public key file.
pub fn public_file(public: &str) -> String {
    format!("# Paddock CURVE public key\npublic = \"{public}\"\n")
}

/// Reads a public key file (or the public half of a secret key file, which is then
/// checked whole).
pub fn read_public(path: &Path) -> Result<String, KeyError> {
    let file = parse_key_file(path)?;
    if file.secret.is_some() {
        return KeyPair::read(path).map(|kp| kp.public);
    }
    file.public.map(|(_, k)| k).ok_or_else(|| KeyError::Format {
        path: path.into(),
        reason: "no `public = \"...\"` line".into(),
    })
}

/// The public keys in an allowed-keys directory (every readable key file in it).
pub fn allowed_keys(dir: &Path) -> std::collections::HashSet<String> {
    let mut keys = std::collections::HashSet::new();
    let Ok(entries) = std::fs::read_dir(dir) else {
        return keys;
    };
    for e in entries.flatten() {
        let path = e.path();
        if path.is_file()
            && let Ok(k) = read_public(&path)
        {
            keys.insert(k);
        }
    }
    keys
}

struct KeyFile {
    /// (line number, key) of each entry.
    public: Option<(usize, String)>,
    secret: Option<(usize, String)>,
}

fn parse_key_file(path: &Path) -> Result<KeyFile, KeyError> {
    let text = std::fs::read_to_string(path).map_err(|source| KeyError::Io {
        path: path.into(),
        source,
    })?;
    let mut file = KeyFile {
        public: None,
        secret: None,
    };
    for (i, line) in text.lines().enumerate() {
        let line_no = i + 1;
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let (name, value) = match line.split_once('=') {
            Some((n, v)) => (n.trim(), v.trim().trim_matches('"')),
            None => ("public", line.trim_matches('"')),
        };
        let (field, slot) = match name {
            "public" | "public-key" => ("public", &mut file.public),
            "secret" | "secret-key" => ("secret", &mut file.secret),
            other => {
                return Err(KeyError::Format {
                    path: path.into(),
                    reason: format!("line {line_no}: unknown entry {other:?}"),
                });
            }
        };
        if slot.is_some() {
            return Err(KeyError::Key {
                path: path.into(),
                line: line_no,
                field,
                reason: "appears twice".into(),
            });
        }
        check_key(value).map_err(|reason| KeyError::Key {
            path: path.into(),
            line: line_no,
            field,
            reason,
        })?;
        *slot = Some((line_no, value.to_string()));
    }
    Ok(file)
}

/// Writes a key file atomically: the text goes to a temporary file created in the same
/// directory with mode 0600 (`private`) or 0644 (before the umask), which is then moved to
/// `path`. Without `force` an existing `path` is left alone and reported. Creates the
/// directory if missing.
pub fn write_key_file(path: &Path, text: &str, private: bool, force: bool) -> Result<(), KeyError> {
    let io = |p: &Path| {
        let p = p.to_path_buf();
        move |source| KeyError::Io { path: p, source }
    };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&dir).map_err(io(&dir))?;
    let (tmp_path, mut tmp) = create_temp(&dir, path, private)?;
    let result = (|| {
        tmp.write_all(text.as_bytes()).map_err(io(&tmp_path))?;
        tmp.sync_all().map_err(io(&tmp_path))?;
        drop(tmp);
        if force {
            std::fs::rename(&tmp_path, path).map_err(io(path))
        } else {
            // a hard link fails if `path` exists: no check-then-write race
            match std::fs::hard_link(&tmp_path, path) {
                Ok(()) => Ok(()),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                    Err(KeyError::Exists { path: path.into() })
                }
                Err(e) => Err(io(path)(e)),
            }
        }
    })();
    let _ = std::fs::remove_file(&tmp_path);
    result
}

/// A new, empty temporary file beside `path` in `dir`, created with its final mode.
fn create_temp(
    dir: &Path,
    path: &Path,
    private: bool,
) -> Result<(PathBuf, std::fs::File), KeyError> {
    let base = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "key".into());
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create_new(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.mode(if private { 0o600 } else { 0o644 });
    }
    #[cfg(not(unix))]
    let _ = private;
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.subsec_nanos())
        .unwrap_or(0);
    for attempt in 0..100u32 {
        let tmp = dir.join(format!(
            ".{base}.tmp-{}-{nanos:x}-{attempt}",
            std::process::id()
        ));
        match options.open(&tmp) {
            Ok(f) => return Ok((tmp, f)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(source) => return Err(KeyError::Io { path: tmp, source }),
        }
    }
    Err(KeyError::Format {
        path: dir.into(),
        reason: "cannot create a temporary key file".into(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("paddock-keys-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn z85_matches_libzmq_on_good_keys_and_refuses_what_libzmq_ignores() {
        for _ in 0..20 {
            let kp = KeyPair::generate().unwrap();
            assert_eq!(
                z85_decode(&kp.public).unwrap(),
                zmq::z85_decode(&kp.public).unwrap()
            );
            assert_eq!(public_of_secret(&kp.secret).unwrap(), kp.public);
        }
        // RFC 32's test vector
        assert_eq!(
            z85_decode("HelloWorld").unwrap(),
            [0x86, 0x4F, 0xD2, 0x6F, 0xB5, 0x59, 0xF7, 0x5B]
        );
        assert!(
            z85_decode("Hello\"orld")
                .unwrap_err()
                .contains("character 6")
        );
        assert!(z85_decode("#####").unwrap_err().contains("overflow"));
        assert!(z85_decode("abcd").unwrap_err().contains("multiple of 5"));
    }

    #[test]
    fn fingerprint_is_eight_hex_of_the_key_bytes() {
        let kp = KeyPair::generate().unwrap();
        let f = fingerprint(&kp.public);
        assert_eq!(f.len(), 8);
        assert!(f.chars().all(|c| c.is_ascii_hexdigit()));
        assert_eq!(f, fingerprint(&kp.public));
        assert_ne!(f, fingerprint(&KeyPair::generate().unwrap().public));
    }

    /// A broker key file of invalid characters used to run with the all-zero secret.
    #[test]
    fn invalid_z85_secret_is_refused_without_printing_it() {
        let d = tmp("badz85");
        let kp = KeyPair::generate().unwrap();
        let bad_secret = format!("~~~~{}", &kp.secret[4..]);
        let file = d.join("broker.key");
        std::fs::write(
            &file,
            format!("public = \"{}\"\nsecret = \"{bad_secret}\"\n", kp.public),
        )
        .unwrap();
        let e = KeyPair::read(&file).unwrap_err().to_string();
        assert!(e.contains("broker.key") && e.contains("`secret`"), "{e}");
        assert!(e.contains("not in the Z85 alphabet"), "{e}");
        assert!(
            !e.contains(&bad_secret[4..]),
            "the error printed the secret: {e}"
        );
    }

    #[test]
    fn short_keys_are_refused_with_the_field_named() {
        let d = tmp("short");
        let kp = KeyPair::generate().unwrap();
        let file = d.join("client.key");
        std::fs::write(
            &file,
            format!(
                "public = \"{}\"\nsecret = \"{}\"\n",
                kp.public,
                &kp.secret[..35]
            ),
        )
        .unwrap();
        let e = KeyPair::read(&file).unwrap_err().to_string();
        assert!(
            e.contains("client.key") && e.contains("line 2") && e.contains("`secret`"),
            "{e}"
        );
        assert!(
            e.contains("35 characters") && !e.contains(&kp.secret[..35]),
            "{e}"
        );
        std::fs::write(d.join("c.pub"), "public = \"tooshort\"\n").unwrap();
        let e = read_public(&d.join("c.pub")).unwrap_err().to_string();
        assert!(
            e.contains("c.pub") && e.contains("`public`") && e.contains("40"),
            "{e}"
        );
    }

    #[test]
    fn a_pair_from_two_key_pairs_is_refused() {
        let d = tmp("mismatch");
        let (a, b) = (KeyPair::generate().unwrap(), KeyPair::generate().unwrap());
        let spliced = KeyPair {
            public: a.public.clone(),
            secret: b.secret.clone(),
        };
        let file = d.join("broker.key");
        std::fs::write(&file, spliced.to_secret_file()).unwrap();
        let e = KeyPair::read(&file).unwrap_err().to_string();
        assert!(
            e.contains("broker.key") && e.contains("different key pairs"),
            "{e}"
        );
        assert!(e.contains(&fingerprint(&a.public)) && e.contains(&fingerprint(&b.public)));
        assert!(!e.contains(&b.secret), "{e}");
        // read_public of a secret key file checks the whole pair too
        assert!(read_public(&file).is_err());
        std::fs::write(&file, a.to_secret_file()).unwrap();
        assert_eq!(KeyPair::read(&file).unwrap(), a);
        assert_eq!(read_public(&file).unwrap(), a.public);
    }

    #[cfg(unix)]
    #[test]
    fn key_files_are_created_private_and_atomically() {
        use std::os::unix::fs::PermissionsExt;
        let d = tmp("mode");
        let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
        // the temporary file is 0600 from its creation, before a byte is written
        let (t, _f) = create_temp(&d, &d.join("x.key"), true).unwrap();
        assert_eq!(mode(&t), 0o600);
        let kp = KeyPair::generate().unwrap();
        let file = d.join("sub/broker.key");
        write_key_file(&file, &kp.to_secret_file(), true, false).unwrap();
        assert_eq!(mode(&file), 0o600);
        assert_eq!(KeyPair::read(&file).unwrap(), kp);
        // no leftovers but the one temp file made above
        let names: Vec<_> = std::fs::read_dir(d.join("sub"))
            .unwrap()
            .flatten()
            .collect();
        assert_eq!(names.len(), 1, "{names:?}");
        // an existing file is kept without --force, replaced with it
        let other = KeyPair::generate().unwrap();
        let e = write_key_file(&file, &other.to_secret_file(), true, false).unwrap_err();
        assert!(matches!(e, KeyError::Exists { .. }), "{e}");
        assert_eq!(KeyPair::read(&file).unwrap(), kp);
        write_key_file(&file, &other.to_secret_file(), true, true).unwrap();
        assert_eq!(KeyPair::read(&file).unwrap(), other);
        assert_eq!(mode(&file), 0o600);
    }
}
