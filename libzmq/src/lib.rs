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

mod keys;
mod monitor;
pub mod token;

pub use monitor::{HandshakeFailure, HandshakeMonitor};

pub use keys::{
    KEY_Z85_LEN, KeyError, KeyPair, allowed_keys, check_key, fingerprint, public_file,
    public_of_secret, read_public, write_key_file, z85_decode,
};

use std::collections::HashSet;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// Checks an endpoint a socket is to connect to, naming what is wrong: a TCP endpoint
/// needs a port in [1, 65535] (ZeroMQ takes `tcp://host:99999` and connects to nothing,
/// so a typo showed only as a timeout). Other transports (`ipc://`, `inproc://`) are
/// left to ZeroMQ.
pub fn check_connect_endpoint(endpoint: &str) -> Result<(), String> {
    check_tcp_port(endpoint, 1, "")
}

/// Checks an endpoint a socket is to bind, naming what is wrong: a TCP endpoint's port
/// must be `*`, or a whole number in [0, 65535] (0: any free port). libzmq takes
/// `tcp://host:99999` and binds port 99999 - 65536 = 34463 instead. Other transports are
/// left to ZeroMQ.
pub fn check_bind_endpoint(endpoint: &str) -> Result<(), String> {
    check_tcp_port(endpoint, 0, " (0 or *: any free port)")
}

/// The checks of [`check_connect_endpoint`] and [`check_bind_endpoint`]: a TCP endpoint's
/// port in `[lo, 65535]` (or `*` where `lo` is 0), `note` said after the range.
fn check_tcp_port(endpoint: &str, lo: u32, note: &str) -> Result<(), String> {
    let Some((transport, address)) = endpoint.split_once("://") else {
        return Err(format!(
            "endpoint {endpoint:?} is not a ZeroMQ endpoint like tcp://HOST:PORT"
        ));
    };
    if transport != "tcp" {
        return Ok(());
    }
    let Some((_, port)) = address
        .rsplit_once(':')
        .filter(|(host, _)| !host.is_empty())
    else {
        return Err(format!(
            "endpoint {endpoint:?} has no host and port (tcp://HOST:PORT)"
        ));
    };
    match port.parse::<u32>() {
        Ok(p) if (lo..=65535).contains(&p) => Ok(()),
        _ if lo == 0 && port == "*" => Ok(()),
        _ => Err(format!(
            "endpoint {endpoint:?}: port {port} is out of range: must be a whole number in [{lo}, 65535]{note}"
        )),
    }
}

/// Whether the linked libzmq supports CURVE (always true for this crate's build).
pub fn has_curve() -> bool {
    zmq::has("curve") == Some(true)
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
    check_key(text).map_err(|_| zmq::Error::EINVAL)
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
                let fingerprint = fingerprint(&user);
                tracing::warn!(
                    domain,
                    address,
                    key = user,
                    fingerprint,
                    reason = text,
                    "peer refused"
                );
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

    #[test]
    fn connect_endpoints_are_checked() {
        for good in [
            "tcp://127.0.0.1:5555",
            "tcp://broker.example:1",
            "tcp://[::1]:65535",
            "ipc:///tmp/paddock.sock",
            "inproc://x",
        ] {
            assert_eq!(check_connect_endpoint(good), Ok(()), "{good}");
        }
        for (bad, said) in [
            (
                "tcp://127.0.0.1:99999",
                "port 99999 is out of range: must be a whole number in [1, 65535]",
            ),
            ("tcp://127.0.0.1:0", "port 0 is out of range"),
            ("tcp://127.0.0.1:x", "port x is out of range"),
            ("tcp://127.0.0.1:-1", "port -1 is out of range"),
            ("tcp://127.0.0.1", "no host and port"),
            ("tcp://:5555", "no host and port"),
            ("127.0.0.1:5555", "is not a ZeroMQ endpoint"),
        ] {
            let e = check_connect_endpoint(bad).unwrap_err();
            assert!(e.contains(said) && e.contains(bad), "{bad}: {e}");
        }
    }

    #[test]
    fn bind_endpoints_are_checked() {
        for good in [
            "tcp://127.0.0.1:5555",
            "tcp://*:5555",
            "tcp://0.0.0.0:0",
            "tcp://127.0.0.1:*",
            "ipc:///tmp/paddock.sock",
        ] {
            assert_eq!(check_bind_endpoint(good), Ok(()), "{good}");
        }
        for (bad, said) in [
            (
                "tcp://127.0.0.1:99999",
                "port 99999 is out of range: must be a whole number in [0, 65535]",
            ),
            ("tcp://127.0.0.1:x", "port x is out of range"),
            ("tcp://127.0.0.1", "no host and port"),
            ("nonsense", "is not a ZeroMQ endpoint"),
        ] {
            let e = check_bind_endpoint(bad).unwrap_err();
            assert!(e.contains(said) && e.contains(bad), "{bad}: {e}");
        }
    }

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
        // a refused client is told so by its handshake monitor, with its key's fingerprint
        let s = ctx.socket(zmq::DEALER).unwrap();
        s.set_linger(0).unwrap();
        client(&stranger).apply(&s).unwrap();
        let monitor = HandshakeMonitor::start(&ctx, &s, &stranger.public).unwrap();
        s.connect(&endpoint).unwrap();
        s.send("ping", 0).unwrap();
        let mut items = [monitor.socket().as_poll_item(zmq::POLLIN)];
        assert_eq!(
            zmq::poll(&mut items, 5000).unwrap(),
            1,
            "no handshake event"
        );
        match monitor.failure() {
            Some(HandshakeFailure::Refused {
                fingerprint,
                status,
                ..
            }) => {
                assert_eq!(fingerprint, crate::fingerprint(&stranger.public));
                assert_eq!(status, 400);
            }
            other => panic!("expected a refusal, got {other:?}"),
        }
        // revoke: remove the key file; new connections are refused
        std::fs::remove_file(allowed.join("good.pub")).unwrap();
        assert!(!exchange(&ctx, &endpoint, &client(&good)));
        assert!(auth.stats().allowed.load(Ordering::Relaxed) >= 1);
        assert!(auth.stats().refused.load(Ordering::Relaxed) >= 2);
        stop.store(true, Ordering::Relaxed);
        echo.join().unwrap();
    }
}
