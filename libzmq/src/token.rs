//! The client token: who a client is to a broker without CURVE (`Envelope.client_token`
//! in the protocol). 32 random bytes drawn once per user and kept in a private file, so
//! every process of that user (the CLI, Python learners) is one client: it lists and
//! manages its own jobs and keeps its env sessions across reconnections. With CURVE the
//! broker goes by the key instead.
//!
//! The file holds the token as 64 hex digits and a newline. Its path: `$PADDOCK_CLIENT_TOKEN_FILE`,
//! else `$XDG_CONFIG_HOME/paddock/client-token`, else `~/.config/paddock/client-token`.
//! It is created 0600 from its first byte (see [`crate::write_key_file`]).

use std::path::{Path, PathBuf};

use crate::keys::KeyError;

/// Bytes of a token.
pub const TOKEN_BYTES: usize = 32;

/// Where this user's token file is; None without a home directory.
pub fn token_path() -> Option<PathBuf> {
    if let Some(p) = std::env::var_os("PADDOCK_CLIENT_TOKEN_FILE").filter(|p| !p.is_empty()) {
        return Some(PathBuf::from(p));
    }
    let config = std::env::var_os("XDG_CONFIG_HOME")
        .filter(|p| !p.is_empty())
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".config")))?;
    Some(config.join("paddock").join("client-token"))
}

/// The token in `path`, drawn and written there first when the file does not exist.
pub fn load_or_create(path: &Path) -> Result<Vec<u8>, KeyError> {
    match std::fs::read_to_string(path) {
        Ok(text) => parse(path, &text),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            let mut b = [0u8; TOKEN_BYTES];
            getrandom::fill(&mut b).map_err(|e| KeyError::Io {
                path: path.into(),
                source: std::io::Error::other(e),
            })?;
            let text: String = b.iter().map(|x| format!("{x:02x}")).collect();
            match crate::write_key_file(path, &format!("{text}\n"), true, false) {
                Ok(()) => Ok(b.to_vec()),
                // another process created it first: use theirs
                Err(KeyError::Exists { .. }) => {
                    let text = std::fs::read_to_string(path).map_err(|source| KeyError::Io {
                        path: path.into(),
                        source,
                    })?;
                    parse(path, &text)
                }
                Err(e) => Err(e),
            }
        }
        Err(source) => Err(KeyError::Io {
            path: path.into(),
            source,
        }),
    }
}

fn parse(path: &Path, text: &str) -> Result<Vec<u8>, KeyError> {
    let t = text.trim();
    let bad = |reason: String| KeyError::Key {
        path: path.into(),
        line: 1,
        field: "token",
        reason,
    };
    if t.len() != 2 * TOKEN_BYTES {
        return Err(bad(format!(
            "{} characters; a client token is {} hex digits",
            t.len(),
            2 * TOKEN_BYTES
        )));
    }
    (0..TOKEN_BYTES)
        .map(|i| {
            u8::from_str_radix(&t[2 * i..2 * i + 2], 16)
                .map_err(|_| bad(format!("character {} is not a hex digit", 2 * i + 1)))
        })
        .collect()
}

/// This user's token ([`token_path`], created on first use); None when there is no
/// place for it (no home directory) or it cannot be read or written, said once on
/// stderr: the client then goes by its connection.
pub fn user_token() -> Option<Vec<u8>> {
    let path = token_path()?;
    match load_or_create(&path) {
        Ok(t) => Some(t),
        Err(e) => {
            tracing::warn!(error = %e, "no client token; jobs and sessions belong to this connection only");
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_token_is_created_private_once_and_read_back() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sub").join("client-token");
        let a = load_or_create(&path).unwrap();
        assert_eq!(a.len(), TOKEN_BYTES);
        let b = load_or_create(&path).unwrap();
        assert_eq!(a, b);
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(&path).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o600);
        let other = dir.path().join("other");
        assert_ne!(load_or_create(&other).unwrap(), a, "drawn, not fixed");
        std::fs::write(&other, "xyz\n").unwrap();
        let e = load_or_create(&other).unwrap_err().to_string();
        assert!(e.contains("token") && e.contains("3 characters"), "{e}");
    }
}
