//! The broker's socket thread: two ROUTER sockets (clients on the frontend, workers on
//! the backend) around the sans-IO state machines of [`crate::core`], and a link to the
//! back office ([`crate::office`]) where everything slow happens: job plans, the job
//! store, maps on disk.
//!
//! A message is an Envelope frame and the payload frames its body announces
//! ([`paddock_proto::payload_frames`]). This thread decodes the Envelope only: env
//! requests and replies, task results and rollout results pass through as the
//! `zmq::Message`s they arrived in, never decoded, copied or re-encoded. One thread
//! polls both sockets and the back office's doorbell with a short timeout, so timers
//! (heartbeats, dead workers) run even when nothing arrives. Every refused request gets
//! an `Error` reply naming the field and value; it is counted by code (see
//! `BrokerStatus.errors`) and logged, and the broker goes on serving everyone else.
//!
//! The env-session routing lives in `env.rs`, task dispatch and batch reduction in
//! `tasks.rs`, the traffic with the back office in `office.rs`, workers (hello, bye,
//! liveness timers) and the status in `workers.rs`, the configuration in `config.rs`.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use paddock_libzmq::{Authenticator, Curve};
use paddock_proto::{Body, ErrorCode, error};

mod config;
mod env;
mod guard;
mod io;
mod office;
mod tasks;
mod workers;

pub use config::{Bounds, BrokerConfig, BrokerError, DEFAULT_SPIN, Security};
pub use guard::clip;

use crate::core::{Blobs, ClientKey, Dispatcher, Principal, Sessions, SourceId, WorkerKey};
use crate::office::{Command, Event, Office, OfficeLimits};
use crate::plan::Planner;
use crate::state::Store;

/// A task's result as the broker keeps it: the payload frame the worker sent.
type Outcome = zmq::Message;

/// A job round waiting for room in the queues: the job, its scenarios (hash, bytes) and
/// tasks.
type WaitingRound = (
    String,
    Vec<(String, Vec<u8>)>,
    Vec<Duration>,
    Vec<paddock_proto::RolloutTaskSpec>,
);

/// What a source of tasks in the scheduler is for, and the scenarios its tasks name.
struct SourceOwner {
    kind: OwnerKind,
    /// Scenario hash of each task (index into `hashes`).
    tasks: Vec<(u32, u64, u32)>,
    /// The distinct scenario hashes the source holds a reference on.
    hashes: Vec<String>,
    /// How long a task of each scenario (by index into `hashes`) may take on a worker.
    deadlines: Vec<Duration>,
}

enum OwnerKind {
    Batch {
        client: ClientKey,
        /// Whose batch it is (per-client bounds).
        who: Principal,
        request_id: u64,
        progress: bool,
        last_progress: Instant,
    },
    Job {
        job_id: String,
    },
}

#[derive(Default)]
struct Stats {
    errors: BTreeMap<String, u64>,
    tasks_done: u64,
    /// Completion times of the last 10 s of tasks.
    recent: VecDeque<Instant>,
    duplicates: u64,
    jobs_active: u32,
}

/// Which socket a message came on.
#[derive(Clone, Copy, PartialEq, Debug)]
pub(crate) enum Side {
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
    /// Rung by the back office when it has events.
    bell: zmq::Socket,
    office: Option<Office>,
    to_office: mpsc::Sender<Command>,
    from_office: mpsc::Receiver<Event>,
    frontend_endpoint: String,
    backend_endpoint: String,
    /// Poll without blocking until then (armed by env-session traffic).
    spin_until: Option<Instant>,
    disp: Dispatcher<Outcome>,
    sessions: Sessions,
    /// Sessions lost for good (with their worker, or a failed replay): why, for a
    /// helpful error.
    lost_sessions: HashMap<u64, String>,
    /// `lost_sessions` oldest first (bounded by `Bounds::max_lost_sessions`).
    lost_order: VecDeque<u64>,
    /// Deadlines of the tasks handed to workers.
    deadlines: guard::Deadlines,
    /// The refusal log's rate limit.
    log_budget: guard::LogBudget,
    /// When the guards (deadlines, idle sessions, batch keep-alives) last ran.
    guarded_at: Duration,
    sources: HashMap<SourceId, SourceOwner>,
    /// Source of each job's round in flight.
    job_sources: HashMap<String, SourceId>,
    /// Job rounds waiting for room in the queues.
    waiting_rounds: VecDeque<WaitingRound>,
    /// Scenario bytes of the sources in flight, by hash.
    blobs: Blobs<Vec<u8>>,
    stats: Stats,
    started: Instant,
    /// This run's instance id (`BrokerStatus.instance`): drawn at random at start.
    instance: String,
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
    max_message_bytes: usize,
    clients: bool,
) -> Result<(zmq::Socket, String), BrokerError> {
    paddock_libzmq::check_bind_endpoint(endpoint).map_err(|e| BrokerError::Endpoint(e, what))?;
    let s = ctx
        .socket(zmq::ROUTER)
        .map_err(socket_err(what, endpoint))?;
    curve.apply(&s).map_err(socket_err(what, endpoint))?;
    s.set_linger(0).map_err(socket_err(what, endpoint))?;
    s.set_sndhwm(100_000).map_err(socket_err(what, endpoint))?;
    s.set_rcvhwm(100_000).map_err(socket_err(what, endpoint))?;
    // refuse oversized frames at the socket, before they are read into memory
    s.set_maxmsgsize(i64::try_from(max_message_bytes).unwrap_or(i64::MAX))
        .map_err(socket_err(what, endpoint))?;
    if clients {
        // a send to a client that has gone fails (EHOSTUNREACH) instead of vanishing:
        // that is how a batch whose client left is noticed and cancelled
        s.set_router_mandatory(true)
            .map_err(socket_err(what, endpoint))?;
        // ZMTP heartbeats close connections whose peer vanished without a FIN
        s.set_heartbeat_ivl(5_000)
            .map_err(socket_err(what, endpoint))?;
        s.set_heartbeat_timeout(15_000)
            .map_err(socket_err(what, endpoint))?;
    }
    s.bind(endpoint).map_err(socket_err(what, endpoint))?;
    let bound = s
        .get_last_endpoint()
        .map_err(socket_err(what, endpoint))?
        .unwrap_or_else(|_| endpoint.to_string());
    Ok((s, bound))
}

impl Broker {
    /// Opens the store in `cfg.state_dir`, binds both sockets and resumes the stored
    /// unfinished jobs with `planner`.
    pub fn bind(cfg: BrokerConfig, planner: impl Planner) -> Result<Self, BrokerError> {
        Self::bind_in(cfg, planner, zmq::Context::new())
    }

    /// [`Broker::bind`] in the ZeroMQ context `ctx`: workers of this process connect to
    /// [`BrokerConfig::local_backend`] (an `inproc://` endpoint) in the same context.
    pub fn bind_in(
        cfg: BrokerConfig,
        planner: impl Planner,
        ctx: zmq::Context,
    ) -> Result<Self, BrokerError> {
        let store = Store::open(&cfg.state_dir)?;
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
        let max = cfg.max_message_bytes;
        let (front, frontend_endpoint) = router(
            &ctx,
            &cfg.frontend,
            "client endpoint",
            &front_curve,
            max,
            true,
        )?;
        let (back, backend_endpoint) = router(
            &ctx,
            &cfg.backend,
            "worker endpoint",
            &back_curve,
            max,
            false,
        )?;
        if let Some(local) = &cfg.local_backend {
            back.bind(local)
                .map_err(socket_err("local worker endpoint", local))?;
        }
        let (to_office, office_rx) = mpsc::channel();
        let (office_tx, from_office) = mpsc::channel();
        let bell_endpoint = format!("inproc://paddock-office-{}", office_doorbell_seq());
        let bell = ctx
            .socket(zmq::PULL)
            .map_err(socket_err("doorbell", &bell_endpoint))?;
        bell.bind(&bell_endpoint)
            .map_err(socket_err("doorbell", &bell_endpoint))?;
        let ringer = ctx
            .socket(zmq::PUSH)
            .map_err(socket_err("doorbell", &bell_endpoint))?;
        ringer
            .connect(&bell_endpoint)
            .map_err(socket_err("doorbell", &bell_endpoint))?;
        let limits = OfficeLimits {
            max_jobs: cfg.max_jobs,
            max_round_tasks: cfg.limits.max_tasks_per_client.min(cfg.limits.max_tasks),
            max_message_bytes: cfg.max_message_bytes,
            max_job_name_bytes: cfg.bounds.max_job_name_bytes,
            max_job_submit_bytes: cfg.bounds.max_job_submit_bytes,
            max_jobs_per_client: cfg.bounds.max_jobs_per_client,
            max_store_bytes: cfg.bounds.max_store_bytes,
        };
        let office = Office::start(
            Box::new(planner),
            store,
            &cfg.maps,
            limits,
            office_rx,
            office_tx,
            ringer,
        )?;
        let mut disp = Dispatcher::new(cfg.liveness, cfg.limits);
        // task ids from the clock (microseconds x 4096): a late result for a task of
        // an earlier run of this broker can never match a task of this one
        let micros = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_micros() as u64);
        disp.tasks.set_first_task_id(micros.saturating_mul(4096));
        let session_logs = cfg.session_logs;
        let blobs = Blobs::new(cfg.blobs);
        let b = Self {
            disp,
            cfg,
            _auth: auth,
            _ctx: ctx,
            front,
            back,
            bell,
            office: Some(office),
            to_office,
            from_office,
            frontend_endpoint,
            backend_endpoint,
            spin_until: None,
            sessions: Sessions::new(session_logs),
            lost_sessions: HashMap::new(),
            lost_order: VecDeque::new(),
            deadlines: guard::Deadlines::default(),
            log_budget: guard::LogBudget::default(),
            guarded_at: Duration::ZERO,
            sources: HashMap::new(),
            job_sources: HashMap::new(),
            waiting_rounds: VecDeque::new(),
            blobs,
            stats: Stats::default(),
            started: Instant::now(),
            instance: workers::draw_instance_id(),
        };
        tracing::info!(
            frontend = %b.frontend_endpoint,
            backend = %b.backend_endpoint,
            state = %b.cfg.state_dir.display(),
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

    /// Serves until `stop` is set; then tells the workers goodbye and stops the back
    /// office (which finishes what it was doing: a job round being stored is stored).
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
        self.stop_office();
        Ok(())
    }

    fn stop_office(&mut self) {
        if let Some(office) = self.office.take() {
            let _ = self.to_office.send(Command::Stop);
            office.join();
        }
    }

    /// Waits up to `timeout` for messages, handles everything that arrived, then runs
    /// the timers and dispatches. (`run` calls this in a loop; tests may drive it.)
    pub fn poll_once(&mut self, timeout: Duration) -> Result<(), BrokerError> {
        let (front_ready, back_ready, bell_ready) = self.wait(timeout)?;
        // bounded drains keep one busy side from starving the other
        if back_ready {
            for _ in 0..1000 {
                match recv_parts(&self.back) {
                    Some(parts) => self.on_frames(Side::Worker, parts),
                    None => break,
                }
            }
        }
        if front_ready {
            for _ in 0..1000 {
                match recv_parts(&self.front) {
                    Some(parts) => self.on_frames(Side::Client, parts),
                    None => break,
                }
            }
        }
        if bell_ready {
            while self.bell.recv_bytes(zmq::DONTWAIT).is_ok() {}
        }
        while let Ok(event) = self.from_office.try_recv() {
            self.on_office(event);
        }
        self.on_timers();
        self.queue_waiting_rounds();
        self.dispatch();
        Ok(())
    }

    fn now(&self) -> Duration {
        self.started.elapsed()
    }

    /// Whether each socket has a message: polls without blocking while the spin is
    /// armed, then waits up to `timeout`.
    fn wait(&mut self, timeout: Duration) -> Result<(bool, bool, bool), BrokerError> {
        if let Some(until) = self.spin_until.take() {
            loop {
                let ready = self.poll_sockets(0)?;
                if ready.0 || ready.1 || ready.2 {
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

    fn poll_sockets(&self, timeout_ms: i64) -> Result<(bool, bool, bool), BrokerError> {
        let mut items = [
            self.front.as_poll_item(zmq::POLLIN),
            self.back.as_poll_item(zmq::POLLIN),
            self.bell.as_poll_item(zmq::POLLIN),
        ];
        match zmq::poll(&mut items, timeout_ms) {
            Ok(_) => Ok((
                items[0].is_readable(),
                items[1].is_readable(),
                items[2].is_readable(),
            )),
            Err(zmq::Error::EINTR) => Ok((false, false, false)),
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

    // ------------------------------------------------------------------ receiving

    fn on_frames(&mut self, side: Side, mut parts: Vec<zmq::Message>) {
        if parts.len() < 2 {
            return;
        }
        let peer: Vec<u8> = parts.remove(0).to_vec();
        if side == Side::Worker {
            let now = self.now();
            self.disp.workers.seen(&peer, now);
        }
        let mut payload = parts.split_off(1);
        let Some(mut header) = parts.pop() else {
            return;
        };
        if header.len() > self.cfg.max_message_bytes {
            let e = paddock_proto::ProtoError::TooLarge {
                size: header.len(),
                limit: self.cfg.max_message_bytes,
            };
            self.refuse(side, &peer, 0, e.to_error());
            return;
        }
        let (rid, token, body) = match paddock_proto::decode_envelope(&header) {
            Ok(x) => x,
            Err((rid, e)) => return self.refuse(side, &peer, rid, e.to_error()),
        };
        let want = paddock_proto::payload_frames(&body);
        if payload.len() != want {
            let name = paddock_proto::body_name(&body);
            return self.refuse(
                side,
                &peer,
                rid,
                error(
                    ErrorCode::BadMessage,
                    "",
                    format!(
                        "{name} is followed by {want} payload frame(s), this message has {}",
                        payload.len()
                    ),
                ),
            );
        }
        match side {
            Side::Client => {
                let who = match io::principal_of(header.gets("User-Id"), &peer, &token) {
                    Ok(who) => who,
                    Err(e) => return self.refuse(side, &peer, rid, e),
                };
                self.on_client(peer, who, rid, body, &mut payload)
            }
            Side::Worker => self.on_worker(peer, rid, body, &mut payload),
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

    fn on_client(
        &mut self,
        client: ClientKey,
        who: Principal,
        rid: u64,
        body: Body,
        payload: &mut Vec<zmq::Message>,
    ) {
        match body {
            Body::RolloutBatch(b) => self.on_batch(client, who, rid, b),
            Body::StatusRequest(_) => {
                let status = self.status();
                self.send(Side::Client, &client, rid, Body::BrokerStatus(status));
            }
            Body::EnvRequest(r) => self.on_env_request(client, who, rid, r, payload.pop()),
            Body::PutMap(p) => self.tell_office(Command::PutMap {
                client,
                rid,
                put: p,
            }),
            Body::PutBlob(p) => self.tell_office(Command::PutBlob {
                client,
                rid,
                data: p.data,
            }),
            body @ (Body::JobSubmit(_)
            | Body::JobStatus(_)
            | Body::JobList(_)
            | Body::JobCancel(_)
            | Body::JobResultRequest(_)
            | Body::JobWatch(_)
            | Body::JobDelete(_)) => {
                let admin = self.is_admin(&who);
                self.tell_office(Command::Job {
                    client,
                    owner: who,
                    admin,
                    rid,
                    body: Box::new(body),
                })
            }
            other => self.wrong_socket(Side::Client, &client, rid, &other),
        }
    }
}

impl Drop for Broker {
    fn drop(&mut self) {
        self.stop_office();
    }
}

/// The frames of one message, each as the `zmq::Message` it arrived in; None when
/// nothing waits.
fn recv_parts(socket: &zmq::Socket) -> Option<Vec<zmq::Message>> {
    let first = socket.recv_msg(zmq::DONTWAIT).ok()?;
    let mut more = first.get_more();
    let mut parts = vec![first];
    while more {
        match socket.recv_msg(0) {
            Ok(m) => {
                more = m.get_more();
                parts.push(m);
            }
            Err(_) => break,
        }
    }
    Some(parts)
}

/// A name for a broker's doorbell endpoint, unique in the process.
fn office_doorbell_seq() -> String {
    static SEQ: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    format!(
        "{}-{}",
        std::process::id(),
        SEQ.fetch_add(1, Ordering::Relaxed)
    )
}

pub(crate) use crate::core::hex;
