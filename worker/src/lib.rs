//! # paddock-worker: runs rollout tasks for a broker
//!
//! A worker connects a DEALER socket to the broker's backend, says hello with its
//! capacity and the maps it holds, and then runs the tasks the broker assigns, sending
//! each result as soon as it is finished. The broker never assigns more tasks than the
//! capacity (credit). The capacity is twice the threads of its rayon pool: each thread
//! has one task running and one waiting, so no thread idles for the broker's round trip
//! between two short episodes.
//!
//! Why it is built this way:
//! - Episodes run on a rayon pool; finished results come back to the socket thread
//!   through an in-process PUSH/PULL pair, so the loop polls one set of sockets and a
//!   result leaves the moment it is ready (no polling interval adds latency).
//! - Heartbeats both ways ([`liveness::Liveness`]): the worker beats every second; a
//!   broker silent for three beats is taken for dead and the worker reconnects with a
//!   new socket and exponential backoff ([`liveness::Backoff`]). Results of tasks that
//!   finish while it is away are sent on the new connection; the broker drops those it
//!   already re-ran (late duplicates, by task id).
//! - Scenarios and maps travel by content hash: a task names its scenario by hash, and
//!   the worker keeps the scenarios it has seen ([`tasks::Scenarios`]) and the maps on
//!   disk ([`maps::MapCache`]); a task or an env open for an unknown hash waits while
//!   the worker asks the broker for it, once per hash (an env session on a container
//!   worker runs on a map a client uploaded, and so does the broker's replay of a lost
//!   session on another worker).
//! - Protobuf stops at [`paddock_wire`]: the one conversion between the wire and the
//!   domain, shared with the clients and the broker's job plans.
//! - The socket loop is [`Worker`] (`serve.rs`); running episodes is [`tasks::Runner`].
//! - Bad input never crashes it: a task that fails to decode or validate, or whose
//!   episode panics, comes back as an error outcome for that task only.
//! - Env sessions are served by [`sessions::Sessions`]. An env step is a round trip the
//!   client waits for, so after answering one the loop polls without blocking for
//!   [`WorkerConfig::spin`] before it sleeps: on an idle machine a wake-up costs more
//!   than the step. Only env traffic arms it (rollout results never do).
//! - A worker in the broker's own process (`paddock serve`) shares the broker's ZeroMQ
//!   context and connects over `inproc://` ([`Worker::new_in`]): no TCP, no I/O thread.

mod fetch;
pub mod liveness;
pub mod maps;
pub mod render;
pub mod scan_path;
mod serve;
pub mod sessions;
pub mod tasks;

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use paddock_libzmq::Curve;
use paddock_sim::circuit::Circuits;
use paddock_sim::lidar::ScanPath;
use paddock_sim::params::VehicleParams;

pub use serve::Worker;

/// What a caught panic says: its message, or "unknown panic".
pub fn panic_message(panic: &(dyn std::any::Any + Send)) -> String {
    panic
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into())
}

/// Errors that stop a worker (bad input from the broker never does).
#[derive(Debug, thiserror::Error)]
pub enum WorkerError {
    #[error("zmq: {what}: {source}")]
    Zmq { what: String, source: zmq::Error },
    #[error("map cache {}: {source}", dir.display())]
    Maps {
        dir: PathBuf,
        source: std::io::Error,
    },
    #[error("threads = {threads}: {message}")]
    Threads { threads: usize, message: String },
    /// The broker's endpoint cannot be connected to (a TCP port out of range, say).
    #[error("{0}")]
    Endpoint(String),
}

pub(crate) fn zmq_err(what: impl Into<String>) -> impl FnOnce(zmq::Error) -> WorkerError {
    let what = what.into();
    move |source| WorkerError::Zmq { what, source }
}

/// Tasks held per pool thread: one running and one waiting (see the module docs).
pub const PREFETCH: usize = 2;

/// How a worker runs.
#[derive(Debug, Clone)]
pub struct WorkerConfig {
    /// The broker's backend endpoint, e.g. `tcp://127.0.0.1:5556`.
    pub connect: String,
    /// Episodes run at once; 0 = one per core.
    pub threads: usize,
    /// Where maps are kept by hash.
    pub maps_dir: PathBuf,
    /// Heartbeat period (the broker's welcome may change it).
    pub heartbeat: Duration,
    /// Missed heartbeats before the broker counts as dead.
    pub liveness: u32,
    /// First and longest pause between reconnect attempts.
    pub backoff_initial: Duration,
    pub backoff_max: Duration,
    /// CURVE keys (the worker's key pair and the broker's public key); Off: plain TCP.
    pub curve: Curve,
    /// Touched at every heartbeat while the broker answers (a container health check).
    pub health_file: Option<PathBuf>,
    /// After answering an env-session request the loop polls without blocking for this
    /// long before it sleeps, so the session's next request, when it comes soon, needs
    /// no thread wake-up. Rollout tasks never arm it; an idle worker never spins. Zero:
    /// always block.
    pub spin: Duration,
    /// The vehicle of every car whose request carries the default vehicle (which travels
    /// as nothing): `paddock serve --vehicle`, so clients that name no vehicle drive the
    /// fitted car. Requests that carry a vehicle are unaffected.
    pub vehicle: VehicleParams,
    /// The circuits the worker loads (each once, shared by its tasks and sessions): its
    /// cached maps by folder, and local maps by name for sessions (`paddock serve` with
    /// `PADDOCK_MAPS`).
    pub circuits: Circuits,
    /// The LIDAR code path of the env sessions' worlds (`PADDOCK_SCAN_PATH`, read by the
    /// `paddock` command, see [`scan_path`]); `None`: the widest this CPU supports.
    pub scan_path: Option<ScanPath>,
}

/// The default [`WorkerConfig::spin`].
pub const DEFAULT_SPIN: Duration = Duration::from_micros(200);

impl WorkerConfig {
    pub fn new(connect: impl Into<String>) -> Self {
        Self {
            connect: connect.into(),
            threads: 0,
            maps_dir: default_maps_dir(),
            heartbeat: Duration::from_secs(1),
            liveness: 3,
            backoff_initial: Duration::from_millis(250),
            backoff_max: Duration::from_secs(8),
            curve: Curve::Off,
            health_file: None,
            spin: DEFAULT_SPIN,
            vehicle: VehicleParams::default(),
            circuits: Circuits::new(),
            scan_path: None,
        }
    }
}

/// `$XDG_CACHE_HOME/paddock/maps`, else `~/.cache/paddock/maps`, else a folder in the
/// system's temporary directory.
pub fn default_maps_dir() -> PathBuf {
    if let Some(x) = std::env::var_os("XDG_CACHE_HOME").filter(|x| !x.is_empty()) {
        return PathBuf::from(x).join("paddock/maps");
    }
    if let Some(h) = std::env::var_os("HOME").filter(|h| !h.is_empty()) {
        return PathBuf::from(h).join(".cache/paddock/maps");
    }
    std::env::temp_dir().join("paddock-maps")
}

/// This machine's name, for status listings.
pub fn hostname() -> String {
    ["/proc/sys/kernel/hostname", "/etc/hostname"]
        .iter()
        .find_map(|p| std::fs::read_to_string(p).ok())
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
        .or_else(|| std::env::var("HOSTNAME").ok())
        .unwrap_or_else(|| "unknown".into())
}

/// Counters for logs and tests.
#[derive(Debug, Default)]
pub struct WorkerStats {
    pub tasks_received: AtomicU64,
    pub tasks_done: AtomicU64,
    pub task_errors: AtomicU64,
    pub bad_messages: AtomicU64,
    pub reconnects: AtomicU64,
    pub maps_requested: AtomicU64,
}

/// A worker running on its own thread (used by `paddock serve` and tests).
pub struct WorkerThread {
    stop: Arc<AtomicBool>,
    handle: Option<std::thread::JoinHandle<Result<(), WorkerError>>>,
    pub worker_id: String,
    pub stats: Arc<WorkerStats>,
}

impl WorkerThread {
    /// Builds a worker and starts serving on a new thread.
    pub fn spawn(cfg: WorkerConfig) -> Result<Self, WorkerError> {
        Self::spawn_in(cfg, zmq::Context::new())
    }

    /// [`WorkerThread::spawn`] in the ZeroMQ context `ctx` (see [`Worker::new_in`]).
    pub fn spawn_in(cfg: WorkerConfig, ctx: zmq::Context) -> Result<Self, WorkerError> {
        let mut worker = Worker::new_in(cfg, ctx)?;
        let stop = Arc::new(AtomicBool::new(false));
        let worker_id = worker.worker_id().to_string();
        let stats = worker.stats();
        let flag = stop.clone();
        let handle = std::thread::Builder::new()
            .name("paddock-worker".into())
            .spawn(move || worker.run(&flag))
            .map_err(|e| WorkerError::Threads {
                threads: 1,
                message: e.to_string(),
            })?;
        Ok(Self {
            stop,
            handle: Some(handle),
            worker_id,
            stats,
        })
    }

    /// Stops the worker (after its Bye) and waits for its thread.
    pub fn stop(mut self) -> Result<(), WorkerError> {
        self.stop.store(true, Ordering::Relaxed);
        match self.handle.take().map(|h| h.join()) {
            Some(Ok(r)) => r,
            Some(Err(_)) => Err(WorkerError::Threads {
                threads: 1,
                message: "worker thread panicked".into(),
            }),
            None => Ok(()),
        }
    }
}

impl Drop for WorkerThread {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}
