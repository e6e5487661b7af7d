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
//! - Maps travel by content hash and are kept on disk ([`maps::MapCache`]); a task or
//!   an env open for an unknown hash waits while the worker asks the broker for the
//!   map, once per hash (an env session on a container worker runs on a map a client
//!   uploaded, and so does the broker's replay of a lost session on another worker).
//! - Bad input never crashes it: a task that fails to decode or validate, or whose
//!   episode panics, comes back as an error outcome for that task only.
//! - Env sessions are served by [`sessions::Sessions`]. An env step is a round trip the
//!   client waits for, so after answering one the loop polls without blocking for
//!   [`WorkerConfig::spin`] before it sleeps: on an idle machine a wake-up costs more
//!   than the step. Only env traffic arms it (rollout results never do).
//! - A worker in the broker's own process (`paddock serve`) shares the broker's ZeroMQ
//!   context and connects over `inproc://` ([`Worker::new_in`]): no TCP, no I/O thread.

pub mod liveness;
pub mod maps;
pub mod render;
pub mod sessions;

use std::collections::{HashMap, HashSet};
use std::panic::AssertUnwindSafe;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use paddock_proto::convert::{outcome_to_proto, task_from_assign};
use paddock_proto::{Body, EnvOpen, ErrorCode, TaskAssign, TaskOutcome, TaskResult, error};
use paddock_sim::params::VehicleParams;
use paddock_sim::track::Circuit;

use crate::liveness::{Backoff, Liveness};
use crate::maps::{MapCache, is_hash};
use crate::sessions::Sessions;
use paddock_libzmq::Curve;

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
}

fn zmq_err(what: impl Into<String>) -> impl FnOnce(zmq::Error) -> WorkerError {
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
        }
    }
}

/// Gives `vehicle` to every car of `scenario` that has the default vehicle.
fn default_vehicle(scenario: &mut Arc<paddock_rollout::Scenario>, vehicle: &VehicleParams) {
    let stock = VehicleParams::default();
    if scenario.agents.iter().any(|a| a.vehicle == stock) {
        for a in &mut Arc::make_mut(scenario).agents {
            if a.vehicle == stock {
                a.vehicle = vehicle.clone();
            }
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

type Circuits = Arc<Mutex<HashMap<PathBuf, Arc<Circuit>>>>;

/// A worker: its pool, its map cache and its sessions; [`Worker::run`] serves a broker.
pub struct Worker {
    cfg: WorkerConfig,
    ctx: zmq::Context,
    worker_id: String,
    /// Tasks held at once (the credit declared to the broker).
    capacity: usize,
    /// Threads of the pool.
    threads: usize,
    pool: rayon::ThreadPool,
    results_rx: zmq::Socket,
    results_tx: Arc<Mutex<zmq::Socket>>,
    cache: MapCache,
    circuits: Circuits,
    sessions: Sessions,
    /// Tasks waiting for their map, by map hash.
    waiting: HashMap<String, Vec<(u64, TaskAssign)>>,
    /// Env opens waiting for their map, by map hash (lower case), with their request ids.
    waiting_opens: HashMap<String, Vec<(u64, EnvOpen)>>,
    /// Map requests in flight: request id -> hash.
    map_requests: HashMap<u64, String>,
    requested: HashSet<String>,
    in_flight: HashSet<u64>,
    next_request: u64,
    /// The broker does not know us (it restarted, or declared us dead): say hello again.
    rehello: bool,
    /// Poll without blocking until then (armed by env-session traffic).
    spin_until: Option<Instant>,
    stats: Arc<WorkerStats>,
}

static WORKER_SEQ: AtomicU64 = AtomicU64::new(0);

impl Worker {
    pub fn new(cfg: WorkerConfig) -> Result<Self, WorkerError> {
        Self::new_in(cfg, zmq::Context::new())
    }

    /// [`Worker::new`] in the ZeroMQ context `ctx`: a worker in the broker's own
    /// process connects to the broker's `inproc://` endpoint through the broker's
    /// context.
    pub fn new_in(cfg: WorkerConfig, ctx: zmq::Context) -> Result<Self, WorkerError> {
        let threads = if cfg.threads == 0 {
            std::thread::available_parallelism().map_or(1, |n| n.get())
        } else {
            cfg.threads
        };
        if threads > 4096 {
            return Err(WorkerError::Threads {
                threads,
                message: "at most 4096 threads".into(),
            });
        }
        let seq = WORKER_SEQ.fetch_add(1, Ordering::Relaxed);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(move |i| format!("paddock-worker{seq}-{i}"))
            .build()
            .map_err(|e| WorkerError::Threads {
                threads,
                message: e.to_string(),
            })?;
        let cache = MapCache::open(&cfg.maps_dir).map_err(|source| WorkerError::Maps {
            dir: cfg.maps_dir.clone(),
            source,
        })?;
        let mut sessions = Sessions::new();
        sessions.set_map_cache(cache.clone());
        sessions.set_default_vehicle(cfg.vehicle.clone());
        let endpoint = format!(
            "inproc://paddock-worker-results-{}-{seq}",
            std::process::id()
        );
        let results_rx = ctx.socket(zmq::PULL).map_err(zmq_err("results socket"))?;
        results_rx
            .bind(&endpoint)
            .map_err(zmq_err(format!("bind {endpoint}")))?;
        let results_tx = ctx.socket(zmq::PUSH).map_err(zmq_err("results socket"))?;
        results_tx
            .connect(&endpoint)
            .map_err(zmq_err(format!("connect {endpoint}")))?;
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos());
        let worker_id = format!("{}-{}-{seq}-{nanos:08x}", hostname(), std::process::id());
        Ok(Self {
            cfg,
            ctx,
            worker_id,
            capacity: threads * PREFETCH,
            threads,
            pool,
            results_rx,
            results_tx: Arc::new(Mutex::new(results_tx)),
            sessions,
            cache,
            circuits: Arc::default(),
            waiting: HashMap::new(),
            waiting_opens: HashMap::new(),
            map_requests: HashMap::new(),
            requested: HashSet::new(),
            in_flight: HashSet::new(),
            next_request: 1,
            rehello: false,
            spin_until: None,
            stats: Arc::default(),
        })
    }

    pub fn worker_id(&self) -> &str {
        &self.worker_id
    }

    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Episodes run at once.
    pub fn threads(&self) -> usize {
        self.threads
    }

    pub fn stats(&self) -> Arc<WorkerStats> {
        self.stats.clone()
    }

    fn connect(&mut self) -> Result<zmq::Socket, WorkerError> {
        let sock = self
            .ctx
            .socket(zmq::DEALER)
            .map_err(zmq_err("dealer socket"))?;
        self.cfg.curve.apply(&sock).map_err(zmq_err("curve keys"))?;
        sock.set_linger(0).map_err(zmq_err("linger"))?;
        sock.connect(&self.cfg.connect)
            .map_err(zmq_err(format!("connect {}", self.cfg.connect)))?;
        self.hello(&sock);
        Ok(sock)
    }

    fn hello(&mut self, sock: &zmq::Socket) {
        let hello = paddock_proto::WorkerHello {
            worker_id: self.worker_id.clone(),
            capacity: u32::try_from(self.capacity).unwrap_or(u32::MAX),
            version: env!("CARGO_PKG_VERSION").into(),
            hostname: hostname(),
            maps: self.cache.hashes(),
        };
        let id = self.request_id();
        send(sock, &paddock_proto::encode(id, Body::WorkerHello(hello)));
    }

    fn request_id(&mut self) -> u64 {
        let id = self.next_request;
        self.next_request += 1;
        id
    }

    /// Serves the broker until `stop` is set, reconnecting whenever it goes silent.
    pub fn run(&mut self, stop: &AtomicBool) -> Result<(), WorkerError> {
        let mut backoff = Backoff::new(self.cfg.backoff_initial, self.cfg.backoff_max);
        let mut first = true;
        while !stop.load(Ordering::Relaxed) {
            if !first {
                self.stats.reconnects.fetch_add(1, Ordering::Relaxed);
            }
            first = false;
            let sock = self.connect()?;
            tracing::info!(
                worker = %self.worker_id,
                capacity = self.capacity,
                broker = %self.cfg.connect,
                "connected"
            );
            let mut live = Liveness::new(self.cfg.heartbeat, self.cfg.liveness, Instant::now());
            let mut last_hello = Instant::now();
            self.rehello = false;
            // tasks waiting for a map were requeued by the broker when it lost us, and
            // the env opens waiting for one were answered by it (or replayed elsewhere)
            self.waiting.clear();
            self.waiting_opens.clear();
            self.map_requests.clear();
            self.requested.clear();
            loop {
                if stop.load(Ordering::Relaxed) {
                    let bye = paddock_proto::Bye {
                        reason: "worker stopping".into(),
                    };
                    let id = self.request_id();
                    send(&sock, &paddock_proto::encode(id, Body::Bye(bye)));
                    return Ok(());
                }
                let now = Instant::now();
                let wait = live
                    .wait(now)
                    .min(Duration::from_millis(100))
                    .max(Duration::from_millis(1));
                let (sock_in, results_in) = self.wait(&sock, wait)?;
                if results_in {
                    self.forward_results(&sock, &mut live);
                }
                if sock_in {
                    while let Ok(frame) = sock.recv_bytes(zmq::DONTWAIT) {
                        live.heard(Instant::now());
                        backoff.reset();
                        self.on_frame(&sock, &frame, &mut live);
                    }
                }
                let now = Instant::now();
                if self.rehello {
                    self.rehello = false;
                    // at most one hello per beat, however many refusals arrive
                    if now.duration_since(last_hello) >= live.interval() / 2 {
                        tracing::info!(broker = %self.cfg.connect, "broker does not know this worker; saying hello again");
                        self.stats.reconnects.fetch_add(1, Ordering::Relaxed);
                        self.hello(&sock);
                        last_hello = now;
                        live.sent(now);
                    }
                }
                if live.beat_due(now) {
                    let hb = paddock_proto::Heartbeat {
                        in_flight: u32::try_from(self.in_flight.len()).unwrap_or(u32::MAX),
                    };
                    send(&sock, &paddock_proto::encode(0, Body::Heartbeat(hb)));
                    live.sent(now);
                    if let Some(path) = &self.cfg.health_file {
                        // healthy: the broker was heard from within its liveness window
                        if let Err(e) = std::fs::write(path, b"ok\n") {
                            tracing::warn!(path = %path.display(), error = %e, "cannot write the health file");
                        }
                    }
                }
                if live.broker_dead(now) {
                    let pause = backoff.next_delay();
                    tracing::warn!(
                        broker = %self.cfg.connect,
                        pause_ms = pause.as_millis() as u64,
                        "broker silent; reconnecting"
                    );
                    drop(sock);
                    let until = Instant::now() + pause;
                    while Instant::now() < until && !stop.load(Ordering::Relaxed) {
                        std::thread::sleep(Duration::from_millis(20));
                    }
                    break;
                }
            }
        }
        Ok(())
    }

    /// Whether the broker socket and the results socket have messages: polls without
    /// blocking while the spin is armed, then waits up to `timeout`.
    fn wait(&mut self, sock: &zmq::Socket, timeout: Duration) -> Result<(bool, bool), WorkerError> {
        let poll = |ms: i64| -> Result<(bool, bool), WorkerError> {
            let mut items = [
                sock.as_poll_item(zmq::POLLIN),
                self.results_rx.as_poll_item(zmq::POLLIN),
            ];
            zmq::poll(&mut items, ms).map_err(zmq_err("poll"))?;
            Ok((items[0].is_readable(), items[1].is_readable()))
        };
        if let Some(until) = self.spin_until.take() {
            loop {
                let ready = poll(0)?;
                if ready.0 || ready.1 {
                    return Ok(ready);
                }
                if Instant::now() >= until {
                    break;
                }
                // lets a thread this one waits for run, on a machine with few cores
                std::thread::yield_now();
            }
        }
        poll(timeout.as_millis() as i64)
    }

    fn forward_results(&mut self, sock: &zmq::Socket, live: &mut Liveness) {
        while let Ok(parts) = self.results_rx.recv_multipart(zmq::DONTWAIT) {
            let [id, frame] = parts.as_slice() else {
                continue;
            };
            if let Ok(id) = <[u8; 8]>::try_from(id.as_slice()) {
                self.in_flight.remove(&u64::from_le_bytes(id));
            }
            send(sock, frame);
            live.sent(Instant::now());
        }
    }

    fn reply(&self, sock: &zmq::Socket, request_id: u64, body: Body) {
        send(sock, &paddock_proto::encode(request_id, body));
    }

    fn on_frame(&mut self, sock: &zmq::Socket, frame: &[u8], live: &mut Liveness) {
        let (request_id, body) = match paddock_proto::decode(frame) {
            Ok(x) => x,
            Err((id, e)) => {
                self.stats.bad_messages.fetch_add(1, Ordering::Relaxed);
                tracing::warn!(error = %e, "bad frame from the broker");
                self.reply(sock, id, Body::Error(e.to_error()));
                return;
            }
        };
        match body {
            Body::WorkerWelcome(w) => {
                live.configure(Duration::from_millis(w.heartbeat_ms.into()), w.liveness);
            }
            Body::Heartbeat(_) => {}
            Body::TaskAssign(t) => self.on_task(sock, request_id, t),
            Body::MapBundle(b) => self.on_map(sock, request_id, b),
            Body::Bye(b) => {
                tracing::info!(reason = %b.reason, "broker said bye");
                // treat as silence: the loop reconnects once the beats run out
            }
            Body::Error(e) => self.on_error(sock, request_id, e),
            Body::EnvOpen(o) => match self.sessions.missing_map(&o) {
                Some(hash) => {
                    self.waiting_opens
                        .entry(hash.clone())
                        .or_default()
                        .push((request_id, o));
                    self.request_map(sock, hash);
                }
                None => self.on_env(sock, request_id, Body::EnvOpen(o)),
            },
            b @ (Body::EnvReset(_) | Body::EnvStep(_) | Body::EnvClose(_) | Body::EnvRender(_)) => {
                self.on_env(sock, request_id, b);
            }
            other => {
                self.stats.bad_messages.fetch_add(1, Ordering::Relaxed);
                let name = paddock_proto::body_name(&other);
                tracing::warn!(body = name, "unexpected message from the broker");
                self.reply(
                    sock,
                    request_id,
                    Body::Error(error(
                        ErrorCode::UnknownType,
                        "body",
                        format!("a worker does not accept {name}"),
                    )),
                );
            }
        }
    }

    /// Answers an env-session request and arms the spin (see [`WorkerConfig::spin`]).
    fn on_env(&mut self, sock: &zmq::Socket, request_id: u64, body: Body) {
        if let Some(reply) = self.sessions.handle(request_id, body) {
            self.reply(sock, request_id, reply);
        }
        if !self.cfg.spin.is_zero() {
            self.spin_until = Some(Instant::now() + self.cfg.spin);
        }
    }

    /// Asks the broker for the map `hash` unless a request for it is in flight.
    fn request_map(&mut self, sock: &zmq::Socket, hash: String) {
        if self.requested.insert(hash.clone()) {
            self.stats.maps_requested.fetch_add(1, Ordering::Relaxed);
            let id = self.request_id();
            self.map_requests.insert(id, hash.clone());
            self.reply(
                sock,
                id,
                Body::MapRequest(paddock_proto::MapRequest { hash }),
            );
        }
    }

    /// Answers the env opens that waited for the map `hash`, which could not be had, with
    /// an error naming the hash and why.
    /// The error keeps the code of the failure it reports (`NOT_FOUND` when the broker
    /// has no such map).
    fn fail_opens(&mut self, sock: &zmq::Socket, hash: &str, code: i32, why: &str) {
        let code = ErrorCode::try_from(code).unwrap_or(ErrorCode::NotFound);
        for (rid, _) in self.waiting_opens.remove(hash).unwrap_or_default() {
            let e = error(
                code,
                "env_open.map.hash",
                format!(
                    "env_open.map.hash = {hash}: the map is not on this worker and fetching it from the broker failed: {why}"
                ),
            );
            self.reply(sock, rid, Body::Error(e));
        }
    }

    fn fail_task(
        &mut self,
        sock: &zmq::Socket,
        request_id: u64,
        task_id: u64,
        e: paddock_proto::Error,
    ) {
        self.stats.task_errors.fetch_add(1, Ordering::Relaxed);
        let result = TaskResult {
            task_id,
            outcome: Some(TaskOutcome {
                outcome: Some(paddock_proto::task_outcome::Outcome::Error(e)),
            }),
        };
        self.reply(sock, request_id, Body::TaskResult(result));
    }

    fn on_task(&mut self, sock: &zmq::Socket, request_id: u64, t: TaskAssign) {
        self.stats.tasks_received.fetch_add(1, Ordering::Relaxed);
        let hash = t
            .scenario
            .as_ref()
            .and_then(|s| s.map.as_ref())
            .map(|m| m.hash.clone());
        let Some(hash) = hash else {
            let e = error(
                ErrorCode::InvalidArgument,
                "task_assign.scenario.map",
                "a task needs a scenario with a map reference",
            );
            return self.fail_task(sock, request_id, t.task_id, e);
        };
        if !is_hash(&hash) {
            let e = error(
                ErrorCode::InvalidArgument,
                "task_assign.scenario.map.hash",
                format!("{hash:?} is not a hex SHA-256 map hash"),
            );
            return self.fail_task(sock, request_id, t.task_id, e);
        }
        if let Some(dir) = self.cache.get(&hash) {
            self.spawn(request_id, t, dir);
            return;
        }
        self.waiting
            .entry(hash.clone())
            .or_default()
            .push((request_id, t));
        self.request_map(sock, hash);
    }

    fn on_map(&mut self, sock: &zmq::Socket, request_id: u64, bundle: paddock_proto::MapBundle) {
        self.map_requests.remove(&request_id);
        let hash = bundle.hash.clone();
        self.requested.remove(&hash);
        let waiting = self.waiting.remove(&hash).unwrap_or_default();
        let lower = hash.to_ascii_lowercase();
        match self.cache.store(&bundle) {
            Ok(dir) => {
                for (rid, t) in waiting {
                    self.spawn(rid, t, dir.clone());
                }
                // the sessions find the map in the cache now
                for (rid, o) in self.waiting_opens.remove(&lower).unwrap_or_default() {
                    self.on_env(sock, rid, Body::EnvOpen(o));
                }
            }
            Err(e) => {
                tracing::warn!(hash = %hash, error = %e.message, "refused a map bundle");
                self.stats.bad_messages.fetch_add(1, Ordering::Relaxed);
                for (rid, t) in waiting {
                    let tx = self.results_tx.clone();
                    push_result(&tx, rid, t.task_id, error_outcome(e.clone()));
                }
                let why = format!("its bundle was refused: {} ({})", e.message, e.field);
                self.fail_opens(sock, &lower, e.code, &why);
            }
        }
    }

    fn on_error(&mut self, sock: &zmq::Socket, request_id: u64, e: paddock_proto::Error) {
        if let Some(hash) = self.map_requests.remove(&request_id) {
            // the broker has no such map: every task and env open waiting for it fails
            // with that error
            self.requested.remove(&hash);
            for (rid, t) in self.waiting.remove(&hash).unwrap_or_default() {
                self.stats.task_errors.fetch_add(1, Ordering::Relaxed);
                push_result(&self.results_tx, rid, t.task_id, error_outcome(e.clone()));
            }
            let why = format!("the broker answered: {} ({})", e.message, e.field);
            self.fail_opens(sock, &hash.to_ascii_lowercase(), e.code, &why);
        } else if e.code == ErrorCode::NotFound as i32 && e.field == "worker_id" {
            self.rehello = true;
        } else {
            tracing::warn!(
                code = paddock_proto::code_name(e.code),
                field = %e.field,
                message = %e.message,
                "the broker refused a message"
            );
        }
    }

    fn spawn(&mut self, request_id: u64, t: TaskAssign, dir: PathBuf) {
        self.in_flight.insert(t.task_id);
        let tx = self.results_tx.clone();
        let circuits = self.circuits.clone();
        let stats = self.stats.clone();
        let vehicle = (self.cfg.vehicle != VehicleParams::default())
            .then(|| Arc::new(self.cfg.vehicle.clone()));
        self.pool.spawn(move || {
            let task_id = t.task_id;
            let outcome = std::panic::catch_unwind(AssertUnwindSafe(|| {
                keep_circuit(&circuits, &dir);
                match task_from_assign(&t, &dir) {
                    Ok(mut task) => {
                        if let Some(v) = &vehicle {
                            default_vehicle(&mut task.scenario, v);
                        }
                        outcome_to_proto(&paddock_rollout::run_episode(
                            &task.scenario,
                            task.seed,
                            task.record,
                        ))
                    }
                    Err(e) => error_outcome(e),
                }
            }))
            .unwrap_or_else(|panic| {
                let what = panic
                    .downcast_ref::<&str>()
                    .map(|s| s.to_string())
                    .or_else(|| panic.downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "unknown panic".into());
                error_outcome(error(
                    ErrorCode::Internal,
                    "",
                    format!("task {task_id} panicked: {what}"),
                ))
            });
            if matches!(
                outcome.outcome,
                Some(paddock_proto::task_outcome::Outcome::Error(_))
            ) {
                stats.task_errors.fetch_add(1, Ordering::Relaxed);
            }
            stats.tasks_done.fetch_add(1, Ordering::Relaxed);
            push_result(&tx, request_id, task_id, outcome);
        });
    }
}

/// Loads a map directory's circuit once and keeps it alive, so later episodes on the
/// same map share its distance field and driving line instead of rebuilding them.
fn keep_circuit(circuits: &Circuits, dir: &std::path::Path) {
    let known = circuits
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .contains_key(dir);
    if !known && let Ok(c) = Circuit::load(dir) {
        circuits
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert(dir.to_path_buf(), c);
    }
}

fn error_outcome(e: paddock_proto::Error) -> TaskOutcome {
    TaskOutcome {
        outcome: Some(paddock_proto::task_outcome::Outcome::Error(e)),
    }
}

fn push_result(tx: &Mutex<zmq::Socket>, request_id: u64, task_id: u64, outcome: TaskOutcome) {
    let frame = paddock_proto::encode(
        request_id,
        Body::TaskResult(TaskResult {
            task_id,
            outcome: Some(outcome),
        }),
    );
    let sock = tx.lock().unwrap_or_else(|e| e.into_inner());
    if let Err(e) = sock.send_multipart([task_id.to_le_bytes().to_vec(), frame], 0) {
        tracing::error!(task_id, error = %e, "could not hand a result to the socket thread");
    }
}

fn send(sock: &zmq::Socket, frame: &[u8]) {
    // never block the loop on a broker that is away: its queue is bounded, it requeues
    if let Err(e) = sock.send(frame, zmq::DONTWAIT) {
        tracing::debug!(error = %e, "send to broker failed");
    }
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
