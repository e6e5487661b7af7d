//! The worker's socket loop: one DEALER to the broker's backend, the results socket of
//! the pool, heartbeats and reconnects, and what each message from the broker starts.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use paddock_proto::{Body, EnvOp, EnvReply, EnvRequest, ErrorCode, error};

use crate::fetch::Fetches;
use crate::liveness::{Backoff, Liveness};
use crate::maps::MapCache;
use crate::sessions::Sessions;
use crate::tasks::{Runner, Scenarios};
use crate::{PREFETCH, WorkerConfig, WorkerError, WorkerStats, hostname, zmq_err};

/// A worker: its pool, its caches and its sessions; [`Worker::run`] serves a broker.
pub struct Worker {
    pub(crate) cfg: WorkerConfig,
    pub(crate) ctx: zmq::Context,
    pub(crate) worker_id: String,
    /// Tasks held at once (the credit declared to the broker).
    pub(crate) capacity: usize,
    /// Threads of the pool.
    pub(crate) threads: usize,
    pub(crate) runner: Runner,
    pub(crate) results_rx: zmq::Socket,
    pub(crate) cache: MapCache,
    pub(crate) scenarios: Scenarios,
    pub(crate) fetches: Fetches,
    pub(crate) sessions: Sessions,
    pub(crate) in_flight: std::collections::HashSet<u64>,
    pub(crate) next_request: u64,
    /// The broker does not know us (it restarted, or declared us dead): say hello again.
    pub(crate) rehello: bool,
    /// Poll without blocking until then (armed by env-session traffic).
    pub(crate) spin_until: Option<Instant>,
    pub(crate) stats: Arc<WorkerStats>,
}

static WORKER_SEQ: AtomicU64 = AtomicU64::new(0);

/// Sends frames without blocking: a broker that is away has a bounded queue and
/// requeues what it does not get.
fn send_frames(sock: &zmq::Socket, frames: Vec<Vec<u8>>) {
    let n = frames.len();
    for (i, f) in frames.into_iter().enumerate() {
        let flags = if i + 1 < n {
            zmq::SNDMORE | zmq::DONTWAIT
        } else {
            zmq::DONTWAIT
        };
        if let Err(e) = sock.send(f, flags) {
            tracing::debug!(error = %e, "send to broker failed");
            return;
        }
    }
}

impl Worker {
    pub fn new(cfg: WorkerConfig) -> Result<Self, WorkerError> {
        Self::new_in(cfg, zmq::Context::new())
    }

    /// [`Worker::new`] in the ZeroMQ context `ctx`: a worker in the broker's own
    /// process connects to the broker's `inproc://` endpoint through the broker's
    /// context.
    pub fn new_in(cfg: WorkerConfig, ctx: zmq::Context) -> Result<Self, WorkerError> {
        paddock_libzmq::check_connect_endpoint(&cfg.connect).map_err(WorkerError::Endpoint)?;
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
        sessions.set_circuits(cfg.circuits.clone());
        sessions.set_default_vehicle(cfg.vehicle.clone());
        sessions.set_scan_path(Ok(cfg.scan_path));
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
        let stats: Arc<WorkerStats> = Arc::default();
        let runner = Runner::new(
            pool,
            results_tx,
            stats.clone(),
            &cfg.vehicle,
            cfg.circuits.clone(),
        );
        Ok(Self {
            cfg,
            ctx,
            worker_id,
            capacity: threads * PREFETCH,
            threads,
            runner,
            results_rx,
            sessions,
            cache,
            scenarios: Scenarios::default(),
            fetches: Fetches::default(),
            in_flight: Default::default(),
            next_request: 1,
            rehello: false,
            spin_until: None,
            stats,
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

    /// The LIDAR code path of its env sessions' worlds.
    fn scan_path(&self) -> paddock_sim::lidar::ScanPath {
        self.cfg
            .scan_path
            .unwrap_or_else(paddock_sim::lidar::ScanPath::best)
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
        self.send(sock, id, Body::WorkerHello(hello));
    }

    pub(crate) fn request_id(&mut self) -> u64 {
        let id = self.next_request;
        self.next_request += 1;
        id
    }

    pub(crate) fn send(&self, sock: &zmq::Socket, request_id: u64, body: Body) {
        send_frames(sock, vec![paddock_proto::encode(request_id, body)]);
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
                cpu = %paddock_sim::lidar::cpu_model(),
                scan_path = %self.scan_path(),
                sweep_vectors = self.scan_path().sweep_vectors(),
                "connected"
            );
            let mut live = Liveness::new(self.cfg.heartbeat, self.cfg.liveness, Instant::now());
            let mut last_hello = Instant::now();
            self.rehello = false;
            // tasks waiting for a fetch were requeued by the broker when it lost us, and
            // the env opens waiting for one were answered by it (or replayed elsewhere)
            self.fetches.clear();
            loop {
                if stop.load(Ordering::Relaxed) {
                    let bye = paddock_proto::Bye {
                        reason: "worker stopping".into(),
                    };
                    let id = self.request_id();
                    self.send(&sock, id, Body::Bye(bye));
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
                    while let Ok(first) = sock.recv_bytes(zmq::DONTWAIT) {
                        let mut parts = vec![first];
                        while sock.get_rcvmore().unwrap_or(false) {
                            match sock.recv_bytes(0) {
                                Ok(p) => parts.push(p),
                                Err(_) => break,
                            }
                        }
                        live.heard(Instant::now());
                        backoff.reset();
                        self.on_message(&sock, parts, &mut live);
                    }
                }
                let now = Instant::now();
                if self.rehello {
                    self.rehello = false;
                    // at most one hello per beat, however many refusals arrive
                    if now.duration_since(last_hello) >= live.interval() / 2 {
                        tracing::info!(broker = %self.cfg.connect, "broker does not know this worker; saying hello again");
                        self.stats.reconnects.fetch_add(1, Ordering::Relaxed);
                        // as after a reconnect: a broker that forgot this worker (it
                        // restarted, or declared it dead) requeued the tasks waiting for a
                        // fetch, and a restarted one never answers the fetches in flight,
                        // which would otherwise never be asked for again
                        self.fetches.clear();
                        self.hello(&sock);
                        last_hello = now;
                        live.sent(now);
                    }
                }
                if live.beat_due(now) {
                    let hb = paddock_proto::Heartbeat {
                        in_flight: u32::try_from(self.in_flight.len()).unwrap_or(u32::MAX),
                    };
                    self.send(&sock, 0, Body::Heartbeat(hb));
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
        while let Ok(mut parts) = self.results_rx.recv_multipart(zmq::DONTWAIT) {
            if parts.len() != 3 {
                continue;
            }
            if let Ok(id) = <[u8; 8]>::try_from(parts[0].as_slice()) {
                self.in_flight.remove(&u64::from_le_bytes(id));
            }
            let frames = parts.split_off(1);
            send_frames(sock, frames);
            live.sent(Instant::now());
        }
    }

    fn on_message(&mut self, sock: &zmq::Socket, mut parts: Vec<Vec<u8>>, live: &mut Liveness) {
        let payload = parts.split_off(1);
        let Some(header) = parts.pop() else {
            return;
        };
        let (request_id, body) = match paddock_proto::decode(&header) {
            Ok(x) => x,
            Err((id, e)) => {
                self.stats.bad_messages.fetch_add(1, Ordering::Relaxed);
                tracing::warn!(error = %e, "bad frame from the broker");
                self.send(sock, id, Body::Error(e.to_error()));
                return;
            }
        };
        let want = paddock_proto::payload_frames(&body);
        if payload.len() != want {
            self.stats.bad_messages.fetch_add(1, Ordering::Relaxed);
            let name = paddock_proto::body_name(&body);
            tracing::warn!(
                body = name,
                frames = payload.len(),
                "message with the wrong number of payload frames"
            );
            let e = error(
                ErrorCode::BadMessage,
                "",
                format!(
                    "{name} is followed by {want} payload frame(s), this message has {}",
                    payload.len()
                ),
            );
            if let Body::EnvRequest(r) = &body {
                return self.reply_env(sock, request_id, r, Err(e));
            }
            return self.send(sock, request_id, Body::Error(e));
        }
        match body {
            Body::WorkerWelcome(w) => {
                live.configure(Duration::from_millis(w.heartbeat_ms.into()), w.liveness);
            }
            Body::Heartbeat(_) => {}
            Body::TaskAssign(t) => self.on_task(sock, request_id, t),
            Body::Blob(b) => self.on_blob(sock, request_id, b),
            Body::MapBundle(b) => self.on_map(sock, request_id, b),
            Body::Bye(b) => {
                tracing::info!(reason = %b.reason, "broker said bye");
                // treat as silence: the loop reconnects once the beats run out
            }
            Body::Error(e) => self.on_error(sock, request_id, e),
            Body::EnvRequest(r) => {
                let payload = payload.into_iter().next().unwrap_or_default();
                if r.op == EnvOp::EnvOpen as i32 {
                    return self.on_open(sock, request_id, r.session_id, payload);
                }
                self.on_env(sock, request_id, &r, &payload);
            }
            other => {
                self.stats.bad_messages.fetch_add(1, Ordering::Relaxed);
                let name = paddock_proto::body_name(&other);
                tracing::warn!(body = name, "unexpected message from the broker");
                self.send(
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
    pub(crate) fn on_env(
        &mut self,
        sock: &zmq::Socket,
        request_id: u64,
        r: &EnvRequest,
        payload: &[u8],
    ) {
        let reply = self.sessions.handle(r.session_id, r.op, payload);
        let mut frames = Vec::with_capacity(1 + reply.frames.len());
        frames.push(paddock_proto::encode(
            request_id,
            Body::EnvReply(reply.header),
        ));
        frames.extend(reply.frames);
        send_frames(sock, frames);
        if !self.cfg.spin.is_zero() {
            self.spin_until = Some(Instant::now() + self.cfg.spin);
        }
    }

    /// An env reply carrying only an error.
    pub(crate) fn reply_env(
        &mut self,
        sock: &zmq::Socket,
        request_id: u64,
        r: &EnvRequest,
        e: Result<(), paddock_proto::Error>,
    ) {
        let header = EnvReply {
            session_id: r.session_id,
            op: r.op,
            fingerprint: 0,
            restart: false,
            error: e.err(),
        };
        self.send(sock, request_id, Body::EnvReply(header));
    }

    fn on_error(&mut self, sock: &zmq::Socket, request_id: u64, e: paddock_proto::Error) {
        if self.on_fetch_error(sock, request_id, &e) {
            return;
        }
        if e.code == ErrorCode::NotFound as i32 && e.field == "worker_id" {
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

    /// Where maps are kept.
    pub fn maps_dir(&self) -> PathBuf {
        self.cache.root().to_path_buf()
    }
}
