//! Only invited peers get in: a broker process with CURVE keys, real worker and client
//! processes. A client with no key, an unknown key or a revoked key is refused; an
//! allowed one works; a flood of refused handshakes does not grow the broker.

use std::path::Path;
use std::time::{Duration, Instant};

use paddock_e2e::{Proc, free_port, paddock, paddock_bin, serial};

fn rss_kib(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).expect("proc status");
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .expect("VmRSS")
}

fn status_with(endpoint: &str, key: &Path, broker_key: &Path) -> std::process::Output {
    std::process::Command::new(paddock_bin())
        .args(["status", "--json", "--endpoint", endpoint, "--key"])
        .arg(key)
        .arg("--broker-key")
        .arg(broker_key)
        .output()
        .expect("paddock status")
}

#[test]
fn only_allowed_keys_get_in() {
    let _serial = serial();
    let dir = tempfile::tempdir().expect("temp dir");
    let keys = dir.path().join("keys");
    let out = paddock(&[
        "keys",
        "generate",
        "--out",
        keys.to_str().expect("utf-8 path"),
    ]);
    assert!(out.status.success(), "{out:?}");
    // secret key files are private (created 0600, never chmod-ed later), public ones not
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = |p: &str| {
            std::fs::metadata(keys.join(p))
                .expect("key file")
                .permissions()
                .mode()
                & 0o777
        };
        for secret in ["broker.key", "worker.key", "client.key"] {
            assert_eq!(mode(secret), 0o600, "{secret}");
        }
        assert_eq!(mode("broker.pub") & 0o600, 0o600);
    }
    // a second client, to be revoked, and a stranger the broker never saw
    let out = paddock(&[
        "keys",
        "generate",
        "--role",
        "client",
        "--name",
        "bob",
        "--out",
        keys.to_str().expect("utf-8 path"),
    ]);
    assert!(out.status.success(), "{out:?}");
    let stranger = dir.path().join("stranger");
    let out = paddock(&[
        "keys",
        "generate",
        "--role",
        "client",
        "--out",
        stranger.to_str().expect("utf-8 path"),
    ]);
    assert!(out.status.success(), "{out:?}");

    let (cp, wp) = (free_port(), free_port());
    let front = format!("tcp://127.0.0.1:{cp}");
    let back = format!("tcp://127.0.0.1:{wp}");
    let state = dir.path().join("state");
    let k = |p: &str| keys.join(p).display().to_string();
    let broker = Proc::spawn(
        "broker",
        &[
            "broker",
            "--bind",
            &front,
            "--worker-bind",
            &back,
            "--state",
            state.to_str().expect("utf-8 path"),
            "--secret-key",
            &k("broker.key"),
            "--client-keys",
            &k("clients"),
            "--worker-keys",
            &k("workers"),
        ],
    );
    let _worker = Proc::spawn(
        "worker",
        &[
            "worker",
            "--connect",
            &back,
            "--threads",
            "1",
            "--key",
            &k("worker.key"),
            "--broker-key",
            &k("broker.pub"),
        ],
    );
    let broker_pub = keys.join("broker.pub");
    // the allowed client sees the keyed worker registered
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let out = status_with(&front, &keys.join("client.key"), &broker_pub);
        if out.status.success() {
            let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("status JSON");
            if v["workers"].as_array().map(Vec::len) == Some(1) {
                break;
            }
        }
        assert!(
            Instant::now() < deadline,
            "the keyed worker did not register: {out:?}"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    // and can run episodes through it
    let out = std::process::Command::new(paddock_bin())
        .args([
            "rollout",
            "--driver",
            "pure-pursuit",
            "--episodes",
            "2",
            "--seed",
            "1",
            "--json",
            "--endpoint",
            &front,
            "--key",
            &k("client.key"),
            "--broker-key",
            &k("broker.pub"),
        ])
        .output()
        .expect("paddock rollout");
    assert!(out.status.success(), "{out:?}");

    // no key at all
    let out = paddock(&["status", "--endpoint", &front]);
    assert!(!out.status.success(), "a client without keys got in");
    // a key the broker does not know: refused, and the client says so with the key's
    // fingerprint (not "no reply within 10s")
    let t0 = Instant::now();
    let out = status_with(&front, &stranger.join("client.key"), &broker_pub);
    let took = t0.elapsed();
    assert!(!out.status.success(), "a client with an unknown key got in");
    let stranger_public =
        paddock_broker::curve::read_public(&stranger.join("client.key")).expect("stranger key");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("refused this client's key")
            && stderr.contains(&paddock_broker::curve::fingerprint(&stranger_public)),
        "the refused client was not told why: {stderr}"
    );
    assert!(
        took < Duration::from_secs(9),
        "the refusal took {took:?}, as long as the reply timeout"
    );
    // refused while idle, before its first request (the connection is gone by the time
    // it sends): the library's client says so at once too, instead of blocking in the send.
    // Idle for different times: libzmq keeps reconnecting, each attempt refused, so the
    // request can meet a connection being set up or one just refused (a send that polled
    // writable then found no connection blocked for good, as a CI run met).
    for idle in [500, 130, 40, 5, 0].repeat(2) {
        let mut client = paddock_broker::client::Client::connect_with(
            &front,
            &paddock_broker::curve::Curve::Client {
                keys: paddock_broker::curve::KeyPair::generate().expect("key pair"),
                server_public: paddock_broker::curve::read_public(&broker_pub).expect("broker.pub"),
            },
        )
        .expect("client");
        client.timeout = Duration::from_secs(30);
        std::thread::sleep(Duration::from_millis(idle));
        let t0 = Instant::now();
        let e = client
            .request(paddock_proto::Body::StatusRequest(
                paddock_proto::StatusRequest {},
            ))
            .expect_err("an unknown key got in");
        assert!(
            matches!(e, paddock_broker::client::ClientError::Refused(_)),
            "{e}"
        );
        assert!(
            t0.elapsed() < Duration::from_secs(9),
            "the refusal took {:?}",
            t0.elapsed()
        );
    }
    // bob works until his public key is removed
    let out = status_with(&front, &keys.join("bob.key"), &broker_pub);
    assert!(
        out.status.success(),
        "bob's allowed key was refused: {out:?}"
    );
    std::fs::remove_file(keys.join("clients/bob.pub")).expect("revoke bob");
    let out = status_with(&front, &keys.join("bob.key"), &broker_pub);
    assert!(!out.status.success(), "a revoked key got in");

    // a flood of handshakes with unknown keys: refused, and the broker does not grow
    let before = rss_kib(broker.pid());
    let ctx = zmq::Context::new();
    let broker_public = paddock_broker::curve::read_public(&broker_pub).expect("broker.pub");
    let mut sockets = Vec::new();
    for _ in 0..300 {
        let s = ctx.socket(zmq::DEALER).expect("socket");
        s.set_linger(0).expect("linger");
        paddock_broker::curve::Curve::Client {
            keys: paddock_broker::curve::KeyPair::generate().expect("key pair"),
            server_public: broker_public.clone(),
        }
        .apply(&s)
        .expect("curve");
        s.connect(&front).expect("connect");
        s.send(vec![0u8; 1024], 0).expect("queue a message");
        sockets.push(s);
    }
    std::thread::sleep(Duration::from_secs(3));
    drop(sockets);
    let after = rss_kib(broker.pid());
    assert!(
        after < before + 16 * 1024,
        "300 refused peers grew the broker from {before} KiB to {after} KiB"
    );
    // the allowed client is still served
    let out = status_with(&front, &keys.join("client.key"), &broker_pub);
    assert!(
        out.status.success(),
        "the broker stopped serving after refusals: {out:?}"
    );
}
