//! The broker process: two ROUTER sockets (clients on the frontend, workers on the
//! backend) around the sans-IO state machines of [`crate::core`], the job runner of
//! [`crate::jobs`] and the store of [`crate::state`].
//!
//! One thread polls both sockets with a short timeout, so timers (heartbeats, dead
//! workers, job rounds) run even when nothing arrives. Every refused request gets an
//! `Error` reply naming the field and value; it is counted by code (see
//! `BrokerStatus.errors`) and logged, and the broker goes on serving everyone else.
//!
//! The env-session routing lives in `env.rs`, the job runner in `jobs.rs`, task
//! dispatch and batch reduction in `tasks.rs`.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use paddock_libzmq::{Authenticator, Curve};
use paddock_proto::{
    Body, BrokerStatus, ErrorCode, JobInfo, JobListing, JobResult, JobState, MapStored,
    RolloutResult, TaskOutcome, WorkerStatus, WorkerWelcome, code_name, error, task_outcome,
};
use prost::Message;

mod env;
mod jobs;
mod tasks;

use crate::core::{
    ClientKey, Completion, Dispatcher, Limits, Liveness, LogLimits, Sessions, SourceId, WorkerKey,
};
use crate::jobs::{JobWork, TaskTemplate};
use crate::state::{JobRecord, Store, StoreError};

/// How to run a broker.
#[derive(Debug, Clone)]
pub struct BrokerConfig {
    /// Client endpoint, e.g. `tcp://0.0.0.0:5555` (`tcp://127.0.0.1:0`: any free port).
    pub frontend: String,
    /// Worker endpoint.
    pub backend: String,
    /// The state directory (job database and maps).
    pub state_dir: PathBuf,
    pub liveness: Liveness,
    pub limits: Limits,
    /// Env-session replay logs: their bounds, and how long a session whose worker died
    /// waits for another worker to be rebuilt on.
    pub session_logs: LogLimits,
    /// Larger frames are answered with TOO_LARGE unread.
    pub max_message_bytes: usize,
    /// Most jobs queued or running at once; more are refused with BUSY.
    pub max_jobs: usize,
    /// The poll timeout, i.e. the resolution of the broker's timers.
    pub tick: Duration,
    /// CURVE encryption and authentication; None: plain TCP (loopback and trusted
    /// networks only).
    pub security: Option<Security>,
    /// A second worker endpoint, e.g. `inproc://paddock-workers`, for workers in this
    /// process sharing the broker's ZeroMQ context (see [`Broker::bind_in`]): no TCP and
    /// no I/O thread between them, two thread hand-offs fewer per env step.
    pub local_backend: Option<String>,
    /// After forwarding env-session traffic the loop polls without blocking for this
    /// long before it sleeps: the reply (or the client's next step) usually comes
    /// sooner, and a thread that never slept needs no wake-up. Rollout tasks never arm
    /// it, and an idle broker never spins. Zero: always block.
    pub spin: Duration,
    /// Maps stored at start and listed by name in the status (the shipped maps), so
    /// clients name them without uploading them.
    pub maps: Vec<paddock_proto::MapBundle>,
}

/// A broker open to the network: its key pair and, per endpoint, the directory of
/// public keys allowed in. A key file removed from a directory is refused from the
/// next connection on.
#[derive(Debug, Clone)]
pub struct Security {
    pub keys: paddock_libzmq::KeyPair,
    pub client_keys: PathBuf,
    pub worker_keys: PathBuf,
}

/// The default [`BrokerConfig::spin`].
pub const DEFAULT_SPIN: Duration = Duration::from_micros(200);

impl BrokerConfig {
    /// The defaults: 1 s heartbeats, 3 missed = dead, 64 MiB messages, 10 ms ticks.
    pub fn new(frontend: &str, backend: &str, state_dir: impl Into<PathBuf>) -> Self {
        Self {
            frontend: frontend.into(),
            backend: backend.into(),
            state_dir: state_dir.into(),
            liveness: Liveness::default(),
            limits: Limits::default(),
            session_logs: LogLimits::default(),
            max_message_bytes: paddock_proto::MAX_MESSAGE_BYTES,
            max_jobs: 1000,
            tick: Duration::from_millis(10),
            security: None,
            local_backend: None,
            spin: DEFAULT_SPIN,
            maps: Vec::new(),
        }
    }
}

/// Why the broker could not start or stopped.
#[derive(Debug, thiserror::Error)]
pub enum BrokerError {
    #[error("{what} {endpoint}: {source}")]
    Socket {
        what: &'static str,
        endpoint: String,
        source: zmq::Error,
    },
    #[error(transparent)]
    Store(#[from] StoreError),
}

/// What a source of tasks in the scheduler is for.
enum SourceOwner {
    Batch {
        client: ClientKey,
        request_id: u64,
        tasks: Vec<TaskTemplate>,
        progress: bool,
        last_progress: Instant,
    },
    Job {
        job_id: String,
        tasks: Vec<TaskTemplate>,
    },
}

impl SourceOwner {
    fn task(&self, index: usize) -> &TaskTemplate {
        match self {
            SourceOwner::Batch { tasks, .. } | SourceOwner::Job { tasks, .. } => &tasks[index],
        }
    }
}

struct RunningJob {
    record: JobRecord,
    work: JobWork,
    source: Option<SourceId>,
    watchers: Vec<(ClientKey, u64)>,
}

#[derive(Default)]
struct Stats {
    errors: BTreeMap<String, u64>,
    tasks_done: u64,
    /// Completion times of the last 10 s of tasks.
    recent: VecDeque<Instant>,
    duplicates: u64,
}

/// Which socket a message came on.
#[derive(Clone, Copy, PartialEq, Debug)]
enum Side {
    Client,
    Worker,
}

/// The broker; see the module documentation.
pub struct Broker {
    cfg: BrokerConfig,
    /// The ZAP handler when CURVE is on (stopped on drop, before the context).
    _auth: Option<Authenticator>,
    _ctx: zmq::Context,
    front: zmq::Socket,
    back: zmq::Socket,
    frontend_endpoint: String,
    backend_endpoint: String,
    /// Poll without blocking until then (armed by env-session traffic).
    spin_until: Option<Instant>,
    store: Store,
    disp: Dispatcher,
    sessions: Sessions,
    /// Sessions lost for good (with their worker, or a failed replay): why, for a
    /// helpful error.
    lost_sessions: HashMap<u64, String>,
    sources: HashMap<SourceId, SourceOwner>,
    jobs: BTreeMap<String, RunningJob>,
    stats: Stats,
    started: Instant,
}

fn socket_err(what: &'static str, endpoint: &str) -> impl FnOnce(zmq::Error) -> BrokerError {
    let endpoint = endpoint.to_string();
    move |source| BrokerError::Socket {
        what,
        endpoint,
        source,
    }
}

fn router(
    ctx: &zmq::Context,
    endpoint: &str,
    what: &'static str,
    curve: &Curve,
) -> Result<(zmq::Socket, String), BrokerError> {
    let s = ctx
        .socket(zmq::ROUTER)
        .map_err(socket_err(what, endpoint))?;
    curve.apply(&s).map_err(socket_err(what, endpoint))?;
    s.set_linger(0).map_err(socket_err(what, endpoint))?;
    s.set_sndhwm(100_000).map_err(socket_err(what, endpoint))?;
    s.set_rcvhwm(100_000).map_err(socket_err(what, endpoint))?;
    s.bind(endpoint).map_err(socket_err(what, endpoint))?;
    let bound = s
        .get_last_endpoint()
        .map_err(socket_err(what, endpoint))?
        .unwrap_or_else(|_| endpoint.to_string());
    Ok((s, bound))
}

fn job_state(state: JobState) -> i32 {
    state as i32
}

fn is_finished(state: i32) -> bool {
    state == JobState::Succeeded as i32
        || state == JobState::Failed as i32
        || state == JobState::CancelledJob as i32
}

fn info_of(r: &JobRecord) -> JobInfo {
    JobInfo {
        job_id: r.id.clone(),
        name: r.name.clone(),
        kind: r.kind.clone(),
        state: r.state,
        rounds_done: r.rounds_done,
        rounds_total: r.rounds_total,
        episodes_done: r.episodes_done,
        progress_json: r.progress_json.clone(),
        error: r.error.clone(),
        created_at: r.created_at,
        updated_at: r.updated_at,
    }
}

impl Broker {
    /// Opens the store in `cfg.state_dir`, binds both sockets and resumes the stored
    /// unfinished jobs.
    pub fn bind(cfg: BrokerConfig) -> Result<Self, BrokerError> {
        Self::bind_in(cfg, zmq::Context::new())
    }

    /// [`Broker::bind`] in the ZeroMQ context `ctx`: workers of this process connect to
    /// [`BrokerConfig::local_backend`] (an `inproc://` endpoint) in the same context.
    pub fn bind_in(cfg: BrokerConfig, ctx: zmq::Context) -> Result<Self, BrokerError> {
        let store = Store::open(&cfg.state_dir)?;
        for bundle in &cfg.maps {
            store.put_map(bundle)?;
        }
        // the ZAP handler must be in place before the secured sockets bind
        let (auth, front_curve, back_curve) = match &cfg.security {
            None => (None, Curve::Off, Curve::Off),
            Some(sec) => {
                let auth = Authenticator::start(
                    &ctx,
                    vec![
                        ("clients".into(), sec.client_keys.clone()),
                        ("workers".into(), sec.worker_keys.clone()),
                    ],
                )
                .map_err(socket_err("authenticator", "inproc://zeromq.zap.01"))?;
                let server = |domain: &str| Curve::Server {
                    keys: sec.keys.clone(),
                    domain: domain.into(),
                };
                (Some(auth), server("clients"), server("workers"))
            }
        };
        let (front, frontend_endpoint) =
            router(&ctx, &cfg.frontend, "client endpoint", &front_curve)?;
        let (back, backend_endpoint) = router(&ctx, &cfg.backend, "worker endpoint", &back_curve)?;
        if let Some(local) = &cfg.local_backend {
            back.bind(local)
                .map_err(socket_err("local worker endpoint", local))?;
        }
        let mut disp = Dispatcher::new(cfg.liveness, cfg.limits);
        // task ids from the clock (microseconds x 4096): a late result for a task of
        // an earlier run of this broker can never match a task of this one
        let micros = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_micros() as u64);
        disp.tasks.set_first_task_id(micros.saturating_mul(4096));
        let session_logs = cfg.session_logs;
        let mut b = Self {
            disp,
            cfg,
            _auth: auth,
            _ctx: ctx,
            front,
            back,
            frontend_endpoint,
            backend_endpoint,
            spin_until: None,
            store,
            sessions: Sessions::new(session_logs),
            lost_sessions: HashMap::new(),
            sources: HashMap::new(),
            jobs: BTreeMap::new(),
            stats: Stats::default(),
            started: Instant::now(),
        };
        b.resume_jobs()?;
        tracing::info!(
            frontend = %b.frontend_endpoint,
            backend = %b.backend_endpoint,
            state = %b.cfg.state_dir.display(),
            jobs_resumed = b.jobs.len(),
            "broker listening"
        );
        Ok(b)
    }

    /// The client endpoint as bound (the real port when bound to port 0).
    pub fn frontend_endpoint(&self) -> &str {
        &self.frontend_endpoint
    }

    /// The worker endpoint as bound.
    pub fn backend_endpoint(&self) -> &str {
        &self.backend_endpoint
    }

    /// Serves until `stop` is set; then tells the workers goodbye.
    pub fn run(&mut self, stop: &AtomicBool) -> Result<(), BrokerError> {
        while !stop.load(Ordering::Relaxed) {
            self.poll_once(self.cfg.tick)?;
        }
        let keys: Vec<WorkerKey> = self.disp.workers.iter().map(|(k, _)| k.clone()).collect();
        for k in keys {
            self.send(
                Side::Worker,
                &k,
                0,
                Body::Bye(paddock_proto::Bye {
                    reason: "broker stopping".into(),
                }),
            );
        }
        Ok(())
    }

    /// Waits up to `timeout` for messages, handles everything that arrived, then runs
    /// the timers and dispatches. (`run` calls this in a loop; tests may drive it.)
    pub fn poll_once(&mut self, timeout: Duration) -> Result<(), BrokerError> {
        let (front_ready, back_ready) = self.wait(timeout)?;
        // bounded drains keep one busy side from starving the other
        if back_ready {
            for _ in 0..1000 {
                match self.back.recv_multipart(zmq::DONTWAIT) {
                    Ok(parts) => self.on_frames(Side::Worker, parts),
                    Err(_) => break,
                }
            }
        }
        if front_ready {
            for _ in 0..1000 {
                match self.front.recv_multipart(zmq::DONTWAIT) {
                    Ok(parts) => self.on_frames(Side::Client, parts),
                    Err(_) => break,
                }
            }
        }
        self.on_timers();
        self.pump_jobs();
        self.dispatch();
        Ok(())
    }

    fn now(&self) -> Duration {
        self.started.elapsed()
    }

    /// Whether each socket has a message: polls without blocking while the spin is
    /// armed, then waits up to `timeout`.
    fn wait(&mut self, timeout: Duration) -> Result<(bool, bool), BrokerError> {
        if let Some(until) = self.spin_until.take() {
            loop {
                let ready = self.poll_sockets(0)?;
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
        self.poll_sockets(timeout.as_millis() as i64)
    }

    fn poll_sockets(&self, timeout_ms: i64) -> Result<(bool, bool), BrokerError> {
        let mut items = [
            self.front.as_poll_item(zmq::POLLIN),
            self.back.as_poll_item(zmq::POLLIN),
        ];
        match zmq::poll(&mut items, timeout_ms) {
            Ok(_) => Ok((items[0].is_readable(), items[1].is_readable())),
            Err(zmq::Error::EINTR) => Ok((false, false)),
            Err(e) => Err(BrokerError::Socket {
                what: "poll",
                endpoint: self.frontend_endpoint.clone(),
                source: e,
            }),
        }
    }

    /// Polls without blocking for [`BrokerConfig::spin`] from now on.
    fn arm_spin(&mut self) {
        if !self.cfg.spin.is_zero() {
            self.spin_until = Some(Instant::now() + self.cfg.spin);
        }
    }

    // ------------------------------------------------------------------ sending

    fn send_raw(&mut self, side: Side, peer: &[u8], payload: Vec<u8>) {
        let socket = match side {
            Side::Client => &self.front,
            Side::Worker => &self.back,
        };
        if let Err(e) = socket.send_multipart([peer.to_vec(), payload], zmq::DONTWAIT) {
            tracing::warn!(?side, error = %e, "send failed; message dropped");
        }
        if side == Side::Worker {
            let now = self.now();
            self.disp.workers.sent(peer, now);
        }
    }

    fn send(&mut self, side: Side, peer: &[u8], request_id: u64, body: Body) {
        let frame = paddock_proto::encode(request_id, body);
        self.send_raw(side, peer, frame);
    }

    /// Sends an error reply, counting and logging it.
    fn refuse(&mut self, side: Side, peer: &[u8], request_id: u64, e: paddock_proto::Error) {
        let code = code_name(e.code);
        *self.stats.errors.entry(code.to_string()).or_default() += 1;
        tracing::warn!(
            ?side,
            peer = %hex(peer),
            request_id,
            code,
            field = %e.field,
            message = %e.message,
            "request refused"
        );
        self.send(side, peer, request_id, Body::Error(e));
    }

    // ------------------------------------------------------------------ receiving

    fn on_frames(&mut self, side: Side, mut parts: Vec<Vec<u8>>) {
        if parts.is_empty() {
            return;
        }
        let peer = parts.remove(0);
        // a DEALER sends [payload]; a REQ-style peer [empty, payload]
        if parts.len() == 2 && parts[0].is_empty() {
            parts.remove(0);
        }
        if parts.len() != 1 {
            let n = parts.len();
            self.refuse(
                side,
                &peer,
                0,
                error(
                    ErrorCode::BadMessage,
                    "",
                    format!("expected one frame holding an Envelope, got {n} frames"),
                ),
            );
            return;
        }
        let frame = parts.pop().unwrap_or_default();
        if side == Side::Worker {
            let now = self.now();
            self.disp.workers.seen(&peer, now);
        }
        if frame.len() > self.cfg.max_message_bytes {
            let e = paddock_proto::ProtoError::TooLarge {
                size: frame.len(),
                limit: self.cfg.max_message_bytes,
            };
            self.refuse(side, &peer, 0, e.to_error());
            return;
        }
        match paddock_proto::decode(&frame) {
            Ok((rid, body)) => match side {
                Side::Client => self.on_client(peer, rid, body),
                Side::Worker => self.on_worker(peer, rid, body),
            },
            Err((rid, e)) => self.refuse(side, &peer, rid, e.to_error()),
        }
    }

    fn wrong_socket(&mut self, side: Side, peer: &[u8], rid: u64, body: &Body) {
        let name = paddock_proto::body_name(body);
        let socket = match side {
            Side::Client => "client",
            Side::Worker => "worker",
        };
        self.refuse(
            side,
            peer,
            rid,
            error(
                ErrorCode::UnknownType,
                "body",
                format!("body {name} is not accepted on the broker's {socket} socket"),
            ),
        );
    }

    fn on_client(&mut self, client: ClientKey, rid: u64, body: Body) {
        match body {
            Body::RolloutBatch(b) => self.on_batch(client, rid, b),
            Body::PutMap(p) => self.on_put_map(client, rid, p),
            Body::StatusRequest(_) => {
                let status = self.status();
                self.send(Side::Client, &client, rid, Body::BrokerStatus(status));
            }
            Body::EnvOpen(o) => self.on_env_open(client, rid, o),
            body @ (Body::EnvReset(_)
            | Body::EnvStep(_)
            | Body::EnvClose(_)
            | Body::EnvRender(_)) => self.route_env(client, rid, body),
            Body::JobSubmit(s) => self.on_job_submit(client, rid, s),
            Body::JobStatus(r) => {
                if let Some(rec) = self.job_record(&client, rid, &r.job_id, "job_status.job_id") {
                    self.send(Side::Client, &client, rid, Body::JobInfo(info_of(&rec)));
                }
            }
            Body::JobList(_) => match self.store.jobs() {
                Ok(jobs) => {
                    let jobs = jobs
                        .iter()
                        .map(|r| match self.jobs.get(&r.id) {
                            Some(j) => info_of(&j.record),
                            None => info_of(r),
                        })
                        .collect();
                    self.send(
                        Side::Client,
                        &client,
                        rid,
                        Body::JobListing(JobListing { jobs }),
                    );
                }
                Err(e) => self.refuse(
                    Side::Client,
                    &client,
                    rid,
                    error(ErrorCode::Internal, "job_list", e.to_string()),
                ),
            },
            Body::JobCancel(c) => self.on_job_cancel(client, rid, &c.job_id),
            Body::JobResultRequest(r) => {
                if let Some(rec) =
                    self.job_record(&client, rid, &r.job_id, "job_result_request.job_id")
                {
                    let rollouts = if rec.result_bin.is_empty() {
                        None
                    } else {
                        RolloutResult::decode(rec.result_bin.as_slice()).ok()
                    };
                    let reply = JobResult {
                        info: Some(info_of(&rec)),
                        result_json: rec.result_json.clone(),
                        rollouts,
                    };
                    self.send(Side::Client, &client, rid, Body::JobResult(reply));
                }
            }
            Body::JobWatch(w) => {
                if let Some(rec) = self.job_record(&client, rid, &w.job_id, "job_watch.job_id") {
                    self.send(Side::Client, &client, rid, Body::JobInfo(info_of(&rec)));
                    if let Some(j) = self.jobs.get_mut(&w.job_id) {
                        j.watchers.push((client, rid));
                    }
                }
            }
            other => self.wrong_socket(Side::Client, &client, rid, &other),
        }
    }

    fn on_worker(&mut self, worker: WorkerKey, rid: u64, body: Body) {
        let known = self.disp.workers.get(&worker).is_some();
        match body {
            Body::WorkerHello(h) => {
                let now = self.now();
                match self.disp.workers.hello(worker.clone(), &h, now) {
                    Ok(old) => {
                        tracing::info!(
                            worker_id = %h.worker_id,
                            hostname = %h.hostname,
                            capacity = h.capacity,
                            "worker joined"
                        );
                        if !old.is_empty() {
                            let r = self.disp.requeue(old);
                            self.fail_exhausted(r.exhausted);
                        }
                        let welcome = WorkerWelcome {
                            heartbeat_ms: self.cfg.liveness.interval.as_millis() as u32,
                            liveness: self.cfg.liveness.liveness,
                        };
                        self.send(Side::Worker, &worker, rid, Body::WorkerWelcome(welcome));
                    }
                    Err(e) => {
                        let field = match e {
                            crate::core::workers::HelloError::Capacity(_) => {
                                "worker_hello.capacity"
                            }
                            crate::core::workers::HelloError::EmptyId => "worker_hello.worker_id",
                        };
                        self.refuse(
                            Side::Worker,
                            &worker,
                            rid,
                            error(ErrorCode::InvalidArgument, field, e.to_string()),
                        );
                    }
                }
            }
            Body::TaskResult(r) => {
                // a result is accepted even from a worker declared dead: the first wins
                let outcome = r.outcome.unwrap_or_else(|| TaskOutcome {
                    outcome: Some(task_outcome::Outcome::Error(error(
                        ErrorCode::BadMessage,
                        "task_result.outcome",
                        "the worker sent a result without an outcome",
                    ))),
                });
                match self.disp.result(&worker, r.task_id, outcome) {
                    Completion::Accepted {
                        source,
                        done,
                        total,
                        finished,
                        ..
                    } => {
                        self.stats.tasks_done += 1;
                        self.stats.recent.push_back(Instant::now());
                        if finished {
                            self.finish_source(source);
                        } else {
                            self.maybe_progress(source, done, total);
                        }
                    }
                    Completion::Dropped => {
                        self.stats.duplicates += 1;
                        tracing::debug!(task_id = r.task_id, "late duplicate result dropped");
                    }
                }
                if !known {
                    self.unknown_worker(&worker, rid);
                }
            }
            Body::Heartbeat(_) => {
                if !known {
                    self.unknown_worker(&worker, rid);
                }
            }
            Body::MapRequest(m) => match self.store.map_bundle(&m.hash) {
                Ok(Some(bundle)) => {
                    if let Some(w) = self.disp.workers.get_mut(&worker) {
                        w.maps.insert(m.hash.clone());
                    }
                    self.send(Side::Worker, &worker, rid, Body::MapBundle(bundle));
                }
                Ok(None) => self.refuse(
                    Side::Worker,
                    &worker,
                    rid,
                    error(
                        ErrorCode::NotFound,
                        "map_request.hash",
                        format!("map hash {:?} is not stored in this broker", m.hash),
                    ),
                ),
                Err(e) => self.refuse(
                    Side::Worker,
                    &worker,
                    rid,
                    error(ErrorCode::Internal, "map_request.hash", e.to_string()),
                ),
            },
            Body::Bye(b) => {
                tracing::info!(peer = %hex(&worker), reason = %b.reason, "worker left");
                if let Some(info) = self.disp.workers.remove(&worker) {
                    self.worker_gone(&worker, info.in_flight.into_iter().collect(), "left");
                }
            }
            Body::EnvOpened(o) => self.on_env_reply(worker, rid, Body::EnvOpened(o)),
            Body::EnvObservation(o) => self.on_env_reply(worker, rid, Body::EnvObservation(o)),
            Body::EnvClosed(c) => self.on_env_reply(worker, rid, Body::EnvClosed(c)),
            Body::EnvImage(i) => self.on_env_reply(worker, rid, Body::EnvImage(i)),
            // an error from a worker answers a forwarded env request, if any
            Body::Error(e) => self.on_env_reply(worker, rid, Body::Error(e)),
            other => self.wrong_socket(Side::Worker, &worker, rid, &other),
        }
    }

    fn unknown_worker(&mut self, worker: &[u8], rid: u64) {
        self.refuse(
            Side::Worker,
            worker,
            rid,
            error(
                ErrorCode::NotFound,
                "worker_id",
                "this broker does not know this worker (declared dead, or the broker restarted): send worker_hello again",
            ),
        );
    }

    // ------------------------------------------------------------------ timers

    fn on_timers(&mut self) {
        let now = self.now();
        let (tick, requeued) = self.disp.tick(now);
        for (key, info) in &tick.dead {
            tracing::warn!(
                worker_id = %info.worker_id,
                hostname = %info.hostname,
                tasks_requeued = info.in_flight.len(),
                "worker silent for {:?}: declared dead",
                self.cfg.liveness.expiry()
            );
            self.worker_gone(key, Vec::new(), "died");
        }
        self.fail_exhausted(requeued.exhausted);
        self.resume_sessions();
        for key in tick.heartbeat {
            let in_flight = self
                .disp
                .workers
                .get(&key)
                .map_or(0, |w| w.in_flight.len() as u32);
            self.send(
                Side::Worker,
                &key,
                0,
                Body::Heartbeat(paddock_proto::Heartbeat { in_flight }),
            );
        }
        let horizon = Instant::now() - Duration::from_secs(10).min(self.started.elapsed());
        while self.stats.recent.front().is_some_and(|&t| t < horizon) {
            self.stats.recent.pop_front();
        }
    }

    /// Cleans up after a worker that left or died: requeues `tasks` (when it was not
    /// done already) and fails its env sessions.
    fn worker_gone(&mut self, worker: &[u8], tasks: Vec<u64>, how: &str) {
        if !tasks.is_empty() {
            let r = self.disp.requeue(tasks);
            self.fail_exhausted(r.exhausted);
        }
        let orphans = self.sessions.worker_gone(worker, self.now());
        for lost in orphans.lost {
            self.session_lost(lost);
        }
        for sid in &orphans.stalled {
            tracing::warn!(
                session = sid,
                peer = %hex(worker),
                "env session's worker {how}: it waits to be replayed on another worker"
            );
        }
        for p in orphans.pending {
            let what = if p.session == 0 {
                "the env session being opened".to_string()
            } else {
                format!("env session {}", p.session)
            };
            let e = error(
                ErrorCode::Internal,
                "session_id",
                format!("{what} was lost: its worker {how} before answering"),
            );
            self.refuse(Side::Client, &p.client, p.client_request, e);
        }
        self.resume_sessions();
    }

    // ------------------------------------------------------------------ maps

    fn on_put_map(&mut self, client: ClientKey, rid: u64, p: paddock_proto::PutMap) {
        let Some(bundle) = p.bundle else {
            return self.refuse(
                Side::Client,
                &client,
                rid,
                error(
                    ErrorCode::InvalidArgument,
                    "put_map.bundle",
                    "put_map needs a bundle",
                ),
            );
        };
        if let Err(e) = paddock_proto::check_bundle(&bundle) {
            return self.refuse(
                Side::Client,
                &client,
                rid,
                paddock_proto::convert::with_prefix(e, "put_map"),
            );
        }
        match self.store.put_map(&bundle) {
            Ok(()) => {
                tracing::info!(name = %bundle.name, hash = %bundle.hash, "map stored");
                self.send(
                    Side::Client,
                    &client,
                    rid,
                    Body::MapStored(MapStored { hash: bundle.hash }),
                );
            }
            Err(e) => self.refuse(
                Side::Client,
                &client,
                rid,
                error(ErrorCode::Internal, "put_map.bundle", e.to_string()),
            ),
        }
    }

    // ------------------------------------------------------------------ status

    fn status(&self) -> BrokerStatus {
        let now = self.now();
        let window = self.started.elapsed().as_secs_f64().clamp(1e-3, 10.0);
        BrokerStatus {
            version: env!("CARGO_PKG_VERSION").into(),
            workers: self
                .disp
                .workers
                .iter()
                .map(|(k, w)| WorkerStatus {
                    worker_id: w.worker_id.clone(),
                    hostname: w.hostname.clone(),
                    capacity: w.capacity,
                    in_flight: w.in_flight.len() as u32,
                    tasks_done: w.tasks_done,
                    last_seen_s: now.saturating_sub(w.last_seen).as_secs_f64(),
                    env_sessions: self.sessions.count_on(k),
                })
                .collect(),
            queue_depth: self.disp.tasks.queued() as u64,
            tasks_in_flight: self.disp.workers.in_flight() as u64,
            tasks_per_s: self.stats.recent.len() as f64 / window,
            tasks_done: self.stats.tasks_done,
            jobs_running: self.jobs.len() as u32,
            env_sessions: self.sessions.len() as u32,
            sessions_replayed: self.sessions.stats().replayed,
            sessions_lost: self.sessions.stats().lost,
            maps: self
                .cfg
                .maps
                .iter()
                .map(paddock_proto::convert::map_ref)
                .collect(),
            errors: self
                .stats
                .errors
                .iter()
                .map(|(k, v)| (k.clone(), *v))
                .collect(),
            uptime_s: self.started.elapsed().as_secs_f64(),
        }
    }
}

fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}
