//! Support for the end-to-end tests: the real `paddock` binary started as broker and
//! worker processes on loopback, with free ports, killed when dropped.
//!
//! The binary is looked for in `$PADDOCK_BIN`, else next to the test executable
//! (`target/<profile>/paddock`, which `cargo test --workspace` builds because the cli
//! package has integration tests). If it is absent the tests fail with a message that
//! says how to build it.

use std::net::TcpListener;
use std::path::PathBuf;
use std::process::{Child, Command, Output, Stdio};
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// The `paddock` executable under test.
pub fn paddock_bin() -> PathBuf {
    if let Some(p) = std::env::var_os("PADDOCK_BIN") {
        let p = PathBuf::from(p);
        assert!(p.is_file(), "PADDOCK_BIN={} is not a file", p.display());
        return p;
    }
    let exe = std::env::current_exe().expect("the test executable's path");
    // target/<profile>/deps/cluster-HASH -> target/<profile>/paddock
    let profile_dir = exe
        .parent()
        .and_then(|deps| deps.parent())
        .expect("the test executable lies in target/<profile>/deps");
    let bin = profile_dir.join(format!("paddock{}", std::env::consts::EXE_SUFFIX));
    assert!(
        bin.is_file(),
        "the paddock binary is not at {}: build it first with `cargo build -p paddock` \
         (add --release for release tests) or set PADDOCK_BIN",
        bin.display()
    );
    bin
}

/// The end-to-end tests share two cores and time their failure detection: they run one
/// at a time.
pub fn serial() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    LOCK.lock().unwrap_or_else(|e| e.into_inner())
}

/// A free loopback TCP port (bound and released; the OS does not hand it out again at
/// once).
pub fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free loopback port")
        .port()
}

/// A child process, killed (SIGKILL) when dropped. Its stderr goes to a log file, shown
/// when a test fails for want of it.
pub struct Proc {
    pub name: String,
    child: Child,
    log: tempfile::NamedTempFile,
}

impl Proc {
    pub fn spawn(name: &str, args: &[&str]) -> Proc {
        let log = tempfile::NamedTempFile::new().expect("a log file");
        let stderr = log.reopen().expect("the log file, for writing");
        let child = Command::new(paddock_bin())
            .args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(stderr)
            .spawn()
            .unwrap_or_else(|e| panic!("starting {name} ({args:?}): {e}"));
        Proc {
            name: name.to_string(),
            child,
            log,
        }
    }

    /// Everything the process wrote to stderr so far.
    pub fn log(&self) -> String {
        std::fs::read_to_string(self.log.path()).unwrap_or_default()
    }

    /// The last lines the process wrote to stderr.
    pub fn log_tail(&self) -> String {
        let text = std::fs::read_to_string(self.log.path()).unwrap_or_default();
        let lines: Vec<&str> = text.lines().collect();
        lines[lines.len().saturating_sub(20)..].join("\n")
    }

    /// Whether it runs, or how it ended, and its last stderr lines.
    pub fn report(&mut self) -> String {
        let state = match self.child.try_wait() {
            Ok(None) => "running".to_string(),
            Ok(Some(status)) => format!("exited: {status}"),
            Err(e) => format!("unknown: {e}"),
        };
        format!("{} {state}; stderr:\n{}", self.name, self.log_tail())
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// kill -9.
    pub fn kill9(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// Sends a signal by name (STOP, CONT, ...).
    pub fn signal(&self, sig: &str) {
        let ok = Command::new("kill")
            .arg(format!("-{sig}"))
            .arg(self.pid().to_string())
            .status()
            .map(|s| s.success())
            .unwrap_or(false);
        assert!(ok, "kill -{sig} {} ({}) failed", self.pid(), self.name);
    }

    /// Whether the process is still running.
    pub fn alive(&mut self) -> bool {
        matches!(self.child.try_wait(), Ok(None))
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        // a stopped process must be continued to die cleanly on some kernels
        let _ = Command::new("kill")
            .args(["-CONT", &self.pid().to_string()])
            .stderr(Stdio::null())
            .status();
        self.kill9();
    }
}

/// Runs `paddock ARGS` to completion.
pub fn paddock(args: &[&str]) -> Output {
    Command::new(paddock_bin())
        .args(args)
        .stdin(Stdio::null())
        .output()
        .unwrap_or_else(|e| panic!("running paddock {args:?}: {e}"))
}

/// A broker process and its worker processes on loopback.
pub struct Cluster {
    pub front: String,
    pub back: String,
    pub state: tempfile::TempDir,
    pub maps: tempfile::TempDir,
    pub broker: Option<Proc>,
    pub workers: Vec<Proc>,
    /// Flags the broker is started with besides its endpoints and state.
    pub broker_args: Vec<String>,
    /// How the test's own status client connects (CURVE when the broker has keys).
    pub curve: paddock_broker::curve::Curve,
}

impl Cluster {
    /// A broker with `workers` workers of `threads` threads each, all registered.
    pub fn start(workers: usize, threads: usize) -> Cluster {
        Self::start_with(workers, threads, &[])
    }

    /// [`Cluster::start`] with more broker flags (`--sessions-per-client 2`, ...).
    pub fn start_with(workers: usize, threads: usize, broker_args: &[&str]) -> Cluster {
        Self::start_secured(
            workers,
            threads,
            broker_args,
            paddock_broker::curve::Curve::Off,
        )
    }

    /// [`Cluster::start_with`] for a broker with CURVE keys (in `broker_args`): the
    /// test's status client connects with `curve`; no workers are started.
    pub fn start_secured(
        workers: usize,
        threads: usize,
        broker_args: &[&str],
        curve: paddock_broker::curve::Curve,
    ) -> Cluster {
        let mut c = Cluster {
            front: String::new(),
            back: String::new(),
            state: tempfile::tempdir().expect("a state directory"),
            maps: tempfile::tempdir().expect("a maps directory"),
            broker: None,
            workers: Vec::new(),
            broker_args: broker_args.iter().map(|a| a.to_string()).collect(),
            curve,
        };
        // a port found free can be taken by another socket before the broker binds it:
        // then the broker exits, and it starts again on other ports
        for attempt in 1..=3 {
            c.front = format!("tcp://127.0.0.1:{}", free_port());
            c.back = format!("tcp://127.0.0.1:{}", free_port());
            c.start_broker();
            if c.broker_answers(Duration::from_secs(20)) {
                break;
            }
            let report = c.broker_report();
            assert!(
                attempt < 3 && report.contains("exited"),
                "the broker on {} does not answer: {report}",
                c.front
            );
        }
        for _ in 0..workers {
            c.add_worker(threads);
        }
        c.wait_workers(workers, Duration::from_secs(20));
        c
    }

    /// Starts (or restarts) the broker on the same endpoints and state directory.
    pub fn start_broker(&mut self) {
        let state = self.state.path().display().to_string();
        let mut args = vec![
            "broker",
            "--bind",
            &self.front,
            "--worker-bind",
            &self.back,
            "--state",
            &state,
        ];
        args.extend(self.broker_args.iter().map(String::as_str));
        self.broker = Some(Proc::spawn("broker", &args));
    }

    pub fn add_worker(&mut self, threads: usize) {
        // each worker its own map cache, so every one of them asks the broker for maps
        let maps = self.maps.path().join(format!("w{}", self.workers.len()));
        let maps = maps.display().to_string();
        let threads = threads.to_string();
        self.workers.push(Proc::spawn(
            "worker",
            &[
                "worker",
                "--connect",
                &self.back,
                "--threads",
                &threads,
                "--maps",
                &maps,
            ],
        ));
    }

    /// `paddock status --json` of the broker.
    pub fn status(&self) -> serde_json::Value {
        let out = paddock(&["status", "--endpoint", &self.front, "--json"]);
        assert!(
            out.status.success(),
            "paddock status failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        serde_json::from_slice(&out.stdout).expect("status --json prints JSON")
    }

    /// The number of workers the broker counts as alive (status request in-process).
    pub fn workers_alive(&self) -> Option<usize> {
        let mut c = paddock_broker::client::Client::connect_with(&self.front, &self.curve).ok()?;
        c.timeout = Duration::from_secs(2);
        match c.request(paddock_proto::Body::StatusRequest(
            paddock_proto::StatusRequest {},
        )) {
            Ok(paddock_proto::Body::BrokerStatus(s)) => Some(s.workers.len()),
            _ => None,
        }
    }

    /// Waits until the broker counts `n` workers.
    pub fn wait_workers(&mut self, n: usize, within: Duration) {
        let t0 = Instant::now();
        loop {
            if self.workers_alive() == Some(n) {
                return;
            }
            if t0.elapsed() >= within {
                let now = self.workers_alive();
                panic!(
                    "the broker did not count {n} workers within {within:?} (now {now:?}); {}",
                    self.broker_report()
                );
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Whether the broker answers a status request within `within` (false at once if
    /// its process has ended).
    fn broker_answers(&mut self, within: Duration) -> bool {
        let t0 = Instant::now();
        while t0.elapsed() < within {
            if self.workers_alive().is_some() {
                return true;
            }
            if self.broker.as_mut().is_some_and(|b| !b.alive()) {
                return false;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        false
    }

    /// The broker process's state and last stderr lines.
    pub fn broker_report(&mut self) -> String {
        self.broker
            .as_mut()
            .map_or_else(|| "no broker process".to_string(), Proc::report)
    }

    /// A client of the broker.
    pub fn client(&self) -> paddock_broker::client::Client {
        let mut c = paddock_broker::client::Client::connect(&self.front).expect("a client socket");
        c.timeout = Duration::from_secs(60);
        c
    }
}
