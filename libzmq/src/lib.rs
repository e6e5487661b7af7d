//! # paddock-libzmq: ZeroMQ with CURVE, key files, and who may connect
//!
//! The `zmq` crate's bundled libzmq has no CURVE; this crate builds one that has (see
//! `build.rs`) and every Paddock binary links it. On top it gives:
//! - [`KeyPair`] and the key files `paddock keys generate` writes: a secret key file
//!   (`public = "..."` and `secret = "..."`, Z85) and a public key file (`public = "..."`);
//! - [`Curve`]: how a socket is secured (server with its key pair, or client with its
//!   key pair and the server's public key) and [`Curve::apply`] to set it on a socket;
//! - [`Authenticator`]: the ZAP handler of a broker: a peer is let in only when its
//!   public key is in the allowed-keys directory of the socket's domain ("clients" or
//!   "workers"). The directory is read again on each handshake, so removing a key file
//!   revokes the key for new connections at once. Refusals are logged once per key (a
//!   bounded set), and a refused peer never gets past the handshake, so it costs the
//!   broker no memory beyond the handshake itself.

use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// Whether the linked libzmq supports CURVE (always true for this crate's build).
pub fn has_curve() -> bool {
    zmq::has("curve") == Some(true)
}

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

/// Errors reading or using keys; each names the file or the key.
#[derive(Debug, thiserror::Error)]
pub enum KeyError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: {reason}")]
    Format { path: PathBuf, reason: String },
    #[error("zmq: {0}")]
    Zmq(#[from] zmq::Error),
}

impl KeyPair {
    /// A fresh random key pair.
    pub fn generate() -> Result<Self, KeyError> {
        let kp = zmq::CurveKeyPair::new()?;
        Ok(Self {
            public: zmq::z85_encode(&kp.public_key).map_err(|e| KeyError::Format {
                path: PathBuf::new(),
                reason: e.to_string(),
            })?,
            secret: zmq::z85_encode(&kp.secret_key).map_err(|e| KeyError::Format {
                path: PathBuf::new(),
                reason: e.to_string(),
            })?,
        })
    }

    /// The text of a secret key file.
    pub fn to_secret_file(&self) -> String {
        format!(
            "# Paddock CURVE key pair: keep this file secret\npublic = \"{}\"\nsecret = \"{}\"\n",
            self.public, self.secret
        )
    }

    /// Reads a secret key file.
    pub fn read(path: &Path) -> Result<Self, KeyError> {
        let (public, secret) = parse_key_file(path)?;
        let secret = secret.ok_or_else(|| KeyError::Format {
            path: path.into(),
            reason: "no `secret = \"...\"` line: this is not a secret key file".into(),
        })?;
        let public = public.ok_or_else(|| KeyError::Format {
            path: path.into(),
            reason: "no `public = \"...\"` line beside the secret key".into(),
        })?;
        Ok(Self { public, secret })
    }
}

/// The text of a public key file.
pub fn public_file(public: &str) -> String {
    format!("# Paddock CURVE public key\npublic = \"{public}\"\n")
}

/// Reads a public key file (or the public half of a secret key file).
pub fn read_public(path: &Path) -> Result<String, KeyError> {
    let (public, _) = parse_key_file(path)?;
    public.ok_or_else(|| KeyError::Format {
        path: path.into(),
        reason: "no `public = \"...\"` line".into(),
    })
}

fn check_z85_key(text: &str) -> Result<(), String> {
    if text.len() != 40 {
        return Err(format!(
            "key {text:?} has {} characters; a Z85 CURVE key has 40",
            text.len()
        ));
    }
    match zmq::z85_decode(text) {
        Ok(bytes) if bytes.len() == 32 => Ok(()),
        _ => Err(format!("key {text:?} is not valid Z85")),
    }
}

fn parse_key_file(path: &Path) -> Result<(Option<String>, Option<String>), KeyError> {
    let text = std::fs::read_to_string(path).map_err(|source| KeyError::Io {
        path: path.into(),
        source,
    })?;
    let mut public = None;
    let mut secret = None;
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let (name, value) = match line.split_once('=') {
            Some((n, v)) => (n.trim(), v.trim().trim_matches('"')),
            None => ("public", line.trim_matches('"')),
        };
        check_z85_key(value).map_err(|reason| KeyError::Format {
            path: path.into(),
            reason: format!("line {}: {reason}", i + 1),
        })?;
        match name {
            "public" | "public-key" => public = Some(value.to_string()),
            "secret" | "secret-key" => secret = Some(value.to_string()),
            other => {
                return Err(KeyError::Format {
                    path: path.into(),
                    reason: format!("line {}: unknown entry {other:?}", i + 1),
                });
            }
        }
    }
    Ok((public, secret))
}

/// The public keys in an allowed-keys directory (every readable key file in it).
pub fn allowed_keys(dir: &Path) -> HashSet<String> {
    let mut keys = HashSet::new();
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

/// How one socket is secured.
#[derive(Debug, Clone, Default)]
pub enum Curve {
    /// Plain TCP, no encryption or authentication.
    #[default]
    Off,
    /// A broker socket: its key pair; peers are checked by the [`Authenticator`]
    /// under `domain`.
    Server { keys: KeyPair, domain: String },
    /// A client or worker: its key pair and the broker's public key.
    Client {
        keys: KeyPair,
        server_public: String,
    },
}

impl Curve {
    /// Sets the CURVE options on `socket`; call before bind/connect.
    pub fn apply(&self, socket: &zmq::Socket) -> Result<(), zmq::Error> {
        match self {
            Curve::Off => Ok(()),
            Curve::Server { keys, domain } => {
                socket.set_zap_domain(domain)?;
                socket.set_curve_server(true)?;
                socket.set_curve_secretkey(&z85(&keys.secret)?)?;
                socket.set_curve_publickey(&z85(&keys.public)?)
            }
            Curve::Client {
                keys,
                server_public,
            } => {
                socket.set_curve_serverkey(&z85(server_public)?)?;
                socket.set_curve_publickey(&z85(&keys.public)?)?;
                socket.set_curve_secretkey(&z85(&keys.secret)?)
            }
        }
    }

    pub fn is_on(&self) -> bool {
        !matches!(self, Curve::Off)
    }
}

fn z85(text: &str) -> Result<Vec<u8>, zmq::Error> {
    zmq::z85_decode(text).map_err(|_| zmq::Error::EINVAL)
}

/// Counters of an [`Authenticator`].
#[derive(Debug, Default)]
pub struct AuthStats {
    pub allowed: AtomicU64,
    pub refused: AtomicU64,
}

/// The ZAP handler: answers libzmq's handshake questions for every CURVE server socket
/// of one context, on its own thread, until the context is dropped.
pub struct Authenticator {
    stats: Arc<AuthStats>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

/// At most this many refused keys are remembered (to log each once).
const MAX_REMEMBERED_REFUSALS: usize = 4096;

impl Authenticator {
    /// Starts the handler on `ctx`. `domains` maps a ZAP domain (set on each server
    /// socket by [`Curve::Server`]) to its allowed-keys directory. Must run before the
    /// server sockets bind.
    pub fn start(ctx: &zmq::Context, domains: Vec<(String, PathBuf)>) -> Result<Self, zmq::Error> {
        let socket = ctx.socket(zmq::REP)?;
        socket.set_linger(0)?;
        socket.bind("inproc://zeromq.zap.01")?;
        let stats = Arc::new(AuthStats::default());
        let stop = Arc::new(AtomicBool::new(false));
        let (thread_stats, thread_stop) = (stats.clone(), stop.clone());
        let thread = std::thread::Builder::new()
            .name("paddock-zap".into())
            .spawn(move || serve(socket, domains, thread_stats, thread_stop))
            .map_err(|_| zmq::Error::EMFILE)?;
        Ok(Self {
            stats,
            stop,
            thread: Some(thread),
        })
    }

    pub fn stats(&self) -> &AuthStats {
        &self.stats
    }
}

impl Drop for Authenticator {
    fn drop(&mut self) {
        // the handler's socket holds the context open: stop the thread so it closes
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn serve(
    socket: zmq::Socket,
    domains: Vec<(String, PathBuf)>,
    stats: Arc<AuthStats>,
    stop: Arc<AtomicBool>,
) {
    let mut refused_seen: HashSet<String> = HashSet::new();
    while !stop.load(Ordering::Relaxed) {
        match socket.poll(zmq::POLLIN, 100) {
            Ok(0) => continue,
            Ok(_) => {}
            Err(_) => return,
        }
        let frames = match socket.recv_multipart(0) {
            Ok(f) => f,
            Err(zmq::Error::ETERM) => return,
            Err(e) => {
                tracing::warn!(error = %e, "ZAP receive failed");
                return;
            }
        };
        // version, request id, domain, address, identity, mechanism, credentials...
        let field = |i: usize| frames.get(i).map(|f| f.as_slice()).unwrap_or(b"");
        let request_id = field(1).to_vec();
        let domain = String::from_utf8_lossy(field(2)).into_owned();
        let address = String::from_utf8_lossy(field(3)).into_owned();
        let mechanism = field(5);
        let (ok, text, user) = if field(0) != b"1.0" {
            (false, "unsupported ZAP version".to_string(), String::new())
        } else if mechanism != b"CURVE" {
            (
                false,
                "only CURVE peers are accepted".to_string(),
                String::new(),
            )
        } else {
            let key = zmq::z85_encode(field(6)).unwrap_or_default();
            match domains.iter().find(|(d, _)| *d == domain) {
                Some((_, dir)) if allowed_keys(dir).contains(&key) => (true, "OK".to_string(), key),
                Some(_) => (false, format!("key not allowed in {domain}"), key),
                None => (false, format!("unknown domain {domain:?}"), key),
            }
        };
        if ok {
            stats.allowed.fetch_add(1, Ordering::Relaxed);
        } else {
            stats.refused.fetch_add(1, Ordering::Relaxed);
            if refused_seen.len() < MAX_REMEMBERED_REFUSALS
                && refused_seen.insert(format!("{domain}/{user}"))
            {
                tracing::warn!(domain, address, key = user, reason = text, "peer refused");
            }
        }
        let reply: Vec<Vec<u8>> = vec![
            b"1.0".to_vec(),
            request_id,
            if ok { b"200".to_vec() } else { b"400".to_vec() },
            text.into_bytes(),
            if ok { user.into_bytes() } else { Vec::new() },
            Vec::new(),
        ];
        if let Err(e) = socket.send_multipart(reply, 0) {
            if e == zmq::Error::ETERM {
                return;
            }
            tracing::warn!(error = %e, "ZAP reply failed");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("paddock-libzmq-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn curve_is_built_in() {
        assert!(has_curve());
    }

    #[test]
    fn key_files_round_trip_and_bad_ones_are_named() {
        let d = tmp("files");
        let kp = KeyPair::generate().unwrap();
        std::fs::write(d.join("a.key"), kp.to_secret_file()).unwrap();
        std::fs::write(d.join("a.pub"), public_file(&kp.public)).unwrap();
        assert_eq!(KeyPair::read(&d.join("a.key")).unwrap(), kp);
        assert_eq!(read_public(&d.join("a.pub")).unwrap(), kp.public);
        assert_eq!(read_public(&d.join("a.key")).unwrap(), kp.public);
        let e = KeyPair::read(&d.join("a.pub")).unwrap_err().to_string();
        assert!(e.contains("a.pub") && e.contains("secret"), "{e}");
        std::fs::write(d.join("bad.pub"), "public = \"tooshort\"\n").unwrap();
        let e = read_public(&d.join("bad.pub")).unwrap_err().to_string();
        assert!(e.contains("bad.pub") && e.contains("40"), "{e}");
        let e = read_public(&d.join("missing.pub")).unwrap_err().to_string();
        assert!(e.contains("missing.pub"), "{e}");
    }

    fn exchange(ctx: &zmq::Context, endpoint: &str, curve: &Curve) -> bool {
        let s = ctx.socket(zmq::DEALER).unwrap();
        s.set_linger(0).unwrap();
        s.set_rcvtimeo(700).unwrap();
        curve.apply(&s).unwrap();
        s.connect(endpoint).unwrap();
        s.send("ping", 0).unwrap();
        s.recv_bytes(0).is_ok()
    }

    #[test]
    fn only_allowed_keys_get_in_and_revocation_takes_effect() {
        let d = tmp("auth");
        let allowed = d.join("clients");
        std::fs::create_dir_all(&allowed).unwrap();
        let server = KeyPair::generate().unwrap();
        let good = KeyPair::generate().unwrap();
        let stranger = KeyPair::generate().unwrap();
        std::fs::write(allowed.join("good.pub"), public_file(&good.public)).unwrap();

        let ctx = zmq::Context::new();
        let auth = Authenticator::start(&ctx, vec![("clients".into(), allowed.clone())]).unwrap();
        let router = ctx.socket(zmq::ROUTER).unwrap();
        Curve::Server {
            keys: server.clone(),
            domain: "clients".into(),
        }
        .apply(&router)
        .unwrap();
        router.bind("tcp://127.0.0.1:*").unwrap();
        let endpoint = router.get_last_endpoint().unwrap().unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let echo_stop = stop.clone();
        let echo = std::thread::spawn(move || {
            router.set_rcvtimeo(100).unwrap();
            while !echo_stop.load(Ordering::Relaxed) {
                if let Ok(m) = router.recv_multipart(0) {
                    router.send_multipart(m, 0).unwrap();
                }
            }
        });
        let client = |keys: &KeyPair| Curve::Client {
            keys: keys.clone(),
            server_public: server.public.clone(),
        };
        assert!(exchange(&ctx, &endpoint, &client(&good)));
        assert!(!exchange(&ctx, &endpoint, &client(&stranger)));
        assert!(!exchange(&ctx, &endpoint, &Curve::Off));
        // a client that has the wrong idea of the server's key
        let wrong_server = Curve::Client {
            keys: good.clone(),
            server_public: stranger.public.clone(),
        };
        assert!(!exchange(&ctx, &endpoint, &wrong_server));
        // revoke: remove the key file; new connections are refused
        std::fs::remove_file(allowed.join("good.pub")).unwrap();
        assert!(!exchange(&ctx, &endpoint, &client(&good)));
        assert!(auth.stats().allowed.load(Ordering::Relaxed) >= 1);
        assert!(auth.stats().refused.load(Ordering::Relaxed) >= 2);
        stop.store(true, Ordering::Relaxed);
        echo.join().unwrap();
    }
}
