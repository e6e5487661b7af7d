//! Test harness: a real [`Broker`] with the real job plans on loopback ports, raw DEALER
//! clients and a raw test worker that runs episodes with `paddock_rollout::run_episode`
//! (or fakes env sessions), with knobs to misbehave. Messages are an Envelope frame and
//! payload frames, as on the wire.

#![allow(dead_code)]

use std::collections::{HashMap, VecDeque};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use paddock_broker::{Broker, BrokerConfig};
use paddock_proto::{Body, MapRef, encode_with_token};
use prost::Message;

pub struct TestBroker {
    pub frontend: String,
    pub backend: String,
    pub stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<()>>,
}

impl TestBroker {
    /// Starts a broker on free loopback ports; `tweak` adjusts the config.
    pub fn start(state: PathBuf, tweak: impl FnOnce(&mut BrokerConfig)) -> Self {
        Self::start_in(state, zmq::Context::new(), tweak)
    }

    /// [`TestBroker::start`] in the ZeroMQ context `ctx` (for `inproc://` workers).
    pub fn start_in(
        state: PathBuf,
        ctx: zmq::Context,
        tweak: impl FnOnce(&mut BrokerConfig),
    ) -> Self {
        let mut cfg = BrokerConfig::new("tcp://127.0.0.1:0", "tcp://127.0.0.1:0", state);
        tweak(&mut cfg);
        let mut broker = Broker::bind_in(cfg, paddock_jobs::Plans, ctx).expect("broker binds");
        let frontend = broker.frontend_endpoint().to_string();
        let backend = broker.backend_endpoint().to_string();
        let stop = Arc::new(AtomicBool::new(false));
        let s = stop.clone();
        let handle = std::thread::spawn(move || broker.run(&s).expect("broker runs"));
        Self {
            frontend,
            backend,
            stop,
            handle: Some(handle),
        }
    }

    pub fn shutdown(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            h.join().expect("broker thread");
        }
    }
}

impl Drop for TestBroker {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// The client token every test peer sends.
pub const TEST_TOKEN: [u8; 32] = [0x5a; 32];

/// A raw DEALER speaking bytes to the broker.
pub struct RawPeer {
    _ctx: zmq::Context,
    pub socket: zmq::Socket,
    /// The client token its Envelopes carry ([`TEST_TOKEN`] unless changed).
    pub token: Vec<u8>,
}

impl RawPeer {
    pub fn connect(endpoint: &str) -> Self {
        Self::connect_in(zmq::Context::new(), endpoint)
    }

    /// [`RawPeer::connect`] in the ZeroMQ context `ctx`.
    pub fn connect_in(ctx: zmq::Context, endpoint: &str) -> Self {
        let socket = ctx.socket(zmq::DEALER).unwrap();
        socket.set_linger(0).unwrap();
        socket.connect(endpoint).unwrap();
        Self {
            _ctx: ctx,
            socket,
            token: TEST_TOKEN.to_vec(),
        }
    }

    /// The same peer as another client (another client token).
    pub fn with_client(mut self, who: u8) -> Self {
        self.token = vec![who; 32];
        self
    }

    pub fn send_raw(&self, bytes: &[u8]) {
        self.socket.send(bytes, 0).unwrap();
    }

    /// Sends an Envelope with the tests' client token: every peer of a test is one
    /// client, as every connection of one user is.
    pub fn send(&self, rid: u64, body: Body) {
        self.send_raw(&encode_with_token(rid, self.token.clone(), body));
    }

    /// Sends an Envelope and its payload frames.
    pub fn send_with(&self, rid: u64, body: Body, payload: Vec<Vec<u8>>) {
        let mut frames = vec![encode_with_token(rid, self.token.clone(), body)];
        frames.extend(payload);
        self.socket.send_multipart(frames, 0).unwrap();
    }

    /// An env request (`op` on session `sid`, 0 to open) with its payload message.
    pub fn env(&self, rid: u64, sid: u64, op: paddock_proto::EnvOp, payload: Option<Vec<u8>>) {
        let header = Body::EnvRequest(paddock_proto::EnvRequest {
            session_id: sid,
            op: op as i32,
        });
        self.send_with(rid, header, payload.into_iter().collect());
    }

    /// The next message (panics after `timeout`).
    pub fn recv(&self, timeout: Duration) -> (u64, Body) {
        let (rid, body, _) = self.recv_frames(timeout);
        (rid, body)
    }

    /// The next message with its payload frames (panics after `timeout`).
    pub fn recv_frames(&self, timeout: Duration) -> (u64, Body, Vec<Vec<u8>>) {
        self.try_recv_frames(timeout)
            .unwrap_or_else(|| panic!("no message within {timeout:?}"))
    }

    pub fn try_recv(&self, timeout: Duration) -> Option<(u64, Body)> {
        self.try_recv_frames(timeout).map(|(r, b, _)| (r, b))
    }

    pub fn try_recv_frames(&self, timeout: Duration) -> Option<(u64, Body, Vec<Vec<u8>>)> {
        if self
            .socket
            .poll(zmq::POLLIN, timeout.as_millis() as i64)
            .unwrap()
            == 0
        {
            return None;
        }
        let mut frames = self.socket.recv_multipart(0).unwrap();
        let payload = frames.split_off(1);
        let (rid, body) =
            paddock_proto::decode(&frames[0]).expect("the broker sends valid envelopes");
        assert_eq!(
            payload.len(),
            paddock_proto::payload_frames(&body),
            "payload frames of {body:?}"
        );
        Some((rid, body, payload))
    }

    /// The reply to request `rid`, skipping progress messages.
    pub fn reply_to(&self, rid: u64, timeout: Duration) -> Body {
        self.reply_frames_to(rid, timeout).0
    }

    /// The reply to request `rid` with its payload frames, skipping progress messages.
    pub fn reply_frames_to(&self, rid: u64, timeout: Duration) -> (Body, Vec<Vec<u8>>) {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let (id, body, payload) = self.recv_frames(left.max(Duration::from_millis(1)));
            if id == rid && !matches!(body, Body::RolloutProgress(_)) {
                return (body, payload);
            }
        }
    }

    /// The outcomes of the rollout result answering request `rid`, decoded.
    pub fn outcomes(&self, rid: u64, timeout: Duration) -> Vec<paddock_proto::TaskOutcome> {
        match self.reply_frames_to(rid, timeout) {
            (Body::RolloutResult(r), frames) => {
                assert_eq!(r.outcomes as usize, frames.len());
                frames.iter().map(|f| decode_outcome(f)).collect()
            }
            other => panic!("expected rollout_result, got {other:?}"),
        }
    }
}

/// A task outcome's payload frame, decoded.
pub fn decode_outcome(frame: &[u8]) -> paddock_proto::TaskOutcome {
    paddock_proto::TaskOutcome::decode(frame).expect("an outcome frame decodes")
}

/// The shipped default map as a bundle and its reference.
pub fn lakeside() -> (paddock_proto::MapBundle, MapRef) {
    let b = paddock_wire::local_map(&paddock_sim::circuit::Circuits::new(), "lakeside").unwrap();
    let r = paddock_wire::map_ref(&b);
    (b, r)
}

/// Stores the default map in the broker through `peer`.
pub fn put_lakeside(peer: &RawPeer) -> MapRef {
    let (bundle, r) = lakeside();
    peer.send(
        9_000,
        Body::PutMap(paddock_proto::PutMap {
            bundle: Some(bundle),
        }),
    );
    match peer.reply_to(9_000, Duration::from_secs(10)) {
        Body::MapStored(m) => assert_eq!(m.hash, r.hash),
        other => panic!("expected map_stored, got {other:?}"),
    }
    r
}

/// A short single-car scenario (fast episodes).
pub fn short_scenario(time_limit: f64) -> paddock_rollout::Scenario {
    let mut s = paddock_rollout::Scenario::single("pure-pursuit").unwrap();
    s.time_limit = time_limit;
    s
}

/// Knobs of the test worker.
#[derive(Clone)]
pub struct WorkerOpts {
    pub capacity: u32,
    /// Hold each task this long before answering (tasks pile up to test credit).
    pub delay: Duration,
    /// After receiving this many tasks, go silent for good (no results, no heartbeats).
    pub silent_after: Option<usize>,
    /// Send every result twice.
    pub duplicate: bool,
    pub heartbeat: Duration,
    pub id: String,
}

impl Default for WorkerOpts {
    fn default() -> Self {
        Self {
            capacity: 2,
            delay: Duration::ZERO,
            silent_after: None,
            duplicate: false,
            heartbeat: Duration::from_millis(100),
            id: "w".into(),
        }
    }
}

#[derive(Default)]
pub struct WorkerStats {
    pub received: AtomicUsize,
    pub answered: AtomicUsize,
    pub max_in_flight: AtomicUsize,
    /// Task ids received, in order.
    pub tasks: Mutex<Vec<u64>>,
    /// Request ids, session ids and ops of env requests received.
    pub env_requests: Mutex<Vec<(u64, u64, i32)>>,
    pub welcomed: AtomicBool,
}

pub struct TestWorker {
    pub stats: Arc<WorkerStats>,
    pub stop: Arc<AtomicBool>,
    handle: Option<JoinHandle<()>>,
}

impl Drop for TestWorker {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

impl TestWorker {
    pub fn spawn(backend: &str, opts: WorkerOpts, cache: PathBuf) -> Self {
        let stats = Arc::new(WorkerStats::default());
        let stop = Arc::new(AtomicBool::new(false));
        let (st, sp) = (stats.clone(), stop.clone());
        let backend = backend.to_string();
        let handle = std::thread::spawn(move || worker_loop(&backend, opts, cache, &st, &sp));
        Self {
            stats,
            stop,
            handle: Some(handle),
        }
    }

    pub fn wait_welcomed(&self) {
        let t0 = Instant::now();
        while !self.stats.welcomed.load(Ordering::Relaxed) {
            assert!(
                t0.elapsed() < Duration::from_secs(10),
                "worker never welcomed"
            );
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}

/// Runs episodes on its own thread, so the message loop keeps heartbeating (as a real
/// worker does) however long an episode takes.
fn compute_thread(
    jobs: std::sync::mpsc::Receiver<(paddock_proto::TaskAssign, paddock_proto::Scenario, PathBuf)>,
    results: std::sync::mpsc::Sender<(u64, Vec<u8>)>,
) {
    let circuits = paddock_sim::circuit::Circuits::new();
    for (t, wire, dir) in jobs {
        let scenario =
            paddock_wire::scenario_from_proto(&wire, &dir).expect("the broker checked the task");
        let task = paddock_wire::task_from_assign(&t, std::sync::Arc::new(scenario));
        let r = paddock_rollout::run_episode(&circuits, &task.scenario, task.seed, task.record);
        if results
            .send((t.task_id, paddock_wire::outcome_to_bytes(&r)))
            .is_err()
        {
            return;
        }
    }
}

fn map_hash(s: &paddock_proto::Scenario) -> String {
    s.map.as_ref().map(|m| m.hash.clone()).unwrap_or_default()
}

fn hello(peer: &RawPeer, opts: &WorkerOpts) {
    peer.send(
        1,
        Body::WorkerHello(paddock_proto::WorkerHello {
            worker_id: opts.id.clone(),
            capacity: opts.capacity,
            version: "test".into(),
            hostname: "test-host".into(),
            maps: vec![],
        }),
    );
}

fn worker_loop(
    backend: &str,
    opts: WorkerOpts,
    cache: PathBuf,
    stats: &WorkerStats,
    stop: &AtomicBool,
) {
    use paddock_proto::EnvOp;
    let peer = RawPeer::connect(backend);
    hello(&peer, &opts);
    let (job_tx, job_rx) = std::sync::mpsc::channel();
    let (res_tx, res_rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || compute_thread(job_rx, res_tx));
    let mut maps: HashMap<String, PathBuf> = HashMap::new();
    let mut scenarios: HashMap<String, paddock_proto::Scenario> = HashMap::new();
    let mut asked: HashMap<String, bool> = HashMap::new();
    let mut pending: VecDeque<(Instant, paddock_proto::TaskAssign)> = VecDeque::new();
    let mut outstanding = 0usize;
    let mut last_beat = Instant::now();
    let mut silent = false;
    let mut next_request = 100u64;
    while !stop.load(Ordering::Relaxed) {
        let wait = if outstanding > 0 && !silent {
            Duration::from_millis(1)
        } else {
            Duration::from_millis(5)
        };
        if let Some((rid, body, payload)) = peer.try_recv_frames(wait) {
            match body {
                Body::WorkerWelcome(_) => stats.welcomed.store(true, Ordering::Relaxed),
                // the broker forgot us (declared dead while busy): register again
                Body::Error(e) if e.field == "worker_id" && !silent => hello(&peer, &opts),
                Body::TaskAssign(t) => {
                    let n = stats.received.fetch_add(1, Ordering::Relaxed) + 1;
                    stats.tasks.lock().unwrap().push(t.task_id);
                    if opts.silent_after.is_some_and(|k| n > k) {
                        silent = true;
                    }
                    let hash = t.scenario_hash.clone();
                    if !scenarios.contains_key(&hash) && !asked.contains_key(&hash) && !silent {
                        asked.insert(hash.clone(), true);
                        next_request += 1;
                        peer.send(
                            next_request,
                            Body::BlobRequest(paddock_proto::BlobRequest { hash }),
                        );
                    }
                    pending.push_back((Instant::now() + opts.delay, t));
                    outstanding += 1;
                    stats
                        .max_in_flight
                        .fetch_max(outstanding, Ordering::Relaxed);
                }
                Body::Blob(b) => {
                    let wire = paddock_proto::Scenario::decode(b.data.as_slice()).unwrap();
                    let m = map_hash(&wire);
                    if !maps.contains_key(&m) && !asked.contains_key(&m) {
                        asked.insert(m.clone(), true);
                        next_request += 1;
                        peer.send(
                            next_request,
                            Body::MapRequest(paddock_proto::MapRequest { hash: m }),
                        );
                    }
                    scenarios.insert(b.hash, wire);
                }
                Body::MapBundle(b) => {
                    let dir = cache.join(&b.hash).join(&b.name);
                    paddock_proto::write_map_dir(&b, &dir).unwrap();
                    maps.insert(b.hash.clone(), dir);
                }
                Body::EnvRequest(r) if !silent => {
                    stats
                        .env_requests
                        .lock()
                        .unwrap()
                        .push((rid, r.session_id, r.op));
                    let reply = |op: i32, frames: Vec<Vec<u8>>| {
                        let views: Vec<&[u8]> = frames.iter().map(Vec::as_slice).collect();
                        let header = paddock_proto::EnvReply {
                            session_id: r.session_id,
                            op,
                            fingerprint: paddock_proto::fingerprint(&views),
                            restart: false,
                            error: None,
                        };
                        peer.send_with(rid, Body::EnvReply(header), frames);
                    };
                    match EnvOp::try_from(r.op) {
                        Ok(EnvOp::EnvOpen) => {
                            let o = paddock_proto::EnvOpen::decode(payload[0].as_slice()).unwrap();
                            let opened = paddock_proto::EnvOpened {
                                num_envs: o.num_envs,
                                ..Default::default()
                            };
                            reply(r.op, vec![opened.encode_to_vec()]);
                        }
                        Ok(EnvOp::EnvStep) => {
                            if opts.silent_after == Some(0) {
                                silent = true;
                                continue;
                            }
                            // echo the actions back as rewards
                            let s = paddock_proto::EnvStep::decode(payload[0].as_slice()).unwrap();
                            let obs = paddock_proto::EnvObservation {
                                rewards: s.actions,
                                ..Default::default()
                            };
                            reply(r.op, vec![obs.encode_to_vec(), Vec::new()]);
                        }
                        Ok(EnvOp::EnvClose) => reply(r.op, Vec::new()),
                        _ => {}
                    }
                }
                _ => {}
            }
        }
        if silent {
            continue;
        }
        while let Some((due, t)) = pending.front() {
            let Some(wire) = scenarios.get(&t.scenario_hash) else {
                break;
            };
            let Some(dir) = maps.get(&map_hash(wire)) else {
                break;
            };
            if *due > Instant::now() {
                break;
            }
            let (wire, dir) = (wire.clone(), dir.clone());
            let (_, t) = pending.pop_front().expect("front exists");
            job_tx.send((t, wire, dir)).expect("compute thread alive");
        }
        while let Ok((task_id, outcome)) = res_rx.try_recv() {
            let msg = Body::TaskResult(paddock_proto::TaskResult { task_id });
            peer.send_with(task_id, msg.clone(), vec![outcome.clone()]);
            if opts.duplicate {
                peer.send_with(task_id, msg, vec![outcome]);
            }
            outstanding -= 1;
            stats.answered.fetch_add(1, Ordering::Relaxed);
        }
        if last_beat.elapsed() >= opts.heartbeat {
            last_beat = Instant::now();
            peer.send(
                0,
                Body::Heartbeat(paddock_proto::Heartbeat {
                    in_flight: outstanding as u32,
                }),
            );
        }
    }
}

/// The outcomes of a batch run locally, in task order.
pub fn run_locally(batch: &paddock_proto::RolloutBatch) -> Vec<paddock_proto::TaskOutcome> {
    // the shipped map by name: the same files as the batch's map
    let dir = std::path::Path::new("lakeside");
    let circuits = paddock_sim::circuit::Circuits::new();
    batch
        .tasks
        .iter()
        .map(|t| {
            let sc = paddock_wire::scenario_from_bytes(&batch.scenarios[t.scenario as usize], dir)
                .unwrap();
            let r = paddock_rollout::run_episode(
                &circuits,
                &sc,
                t.seed,
                paddock_wire::record_from_proto(t.record_decimation),
            );
            paddock_wire::outcome_to_proto(&r)
        })
        .collect()
}

/// A batch of `n` short episodes on `map` with seeds from `seed`.
pub fn batch(map: &MapRef, n: usize, seed: u64, time_limit: f64) -> paddock_proto::RolloutBatch {
    let sc = paddock_wire::scenario_to_proto(&short_scenario(time_limit), map.clone());
    paddock_proto::RolloutBatch {
        scenarios: vec![sc.encode_to_vec()],
        tasks: (0..n as u64)
            .map(|k| paddock_proto::RolloutTaskSpec {
                scenario: 0,
                seed: paddock_rollout::task_seed(seed, k),
                record_decimation: if k == 0 { 5 } else { 0 },
            })
            .collect(),
        progress: true,
    }
}

pub fn status(peer: &RawPeer, rid: u64) -> paddock_proto::BrokerStatus {
    peer.send(rid, Body::StatusRequest(paddock_proto::StatusRequest {}));
    match peer.reply_to(rid, Duration::from_secs(10)) {
        Body::BrokerStatus(s) => s,
        other => panic!("expected broker_status, got {other:?}"),
    }
}

pub fn expect_error(body: Body) -> paddock_proto::Error {
    match body {
        Body::Error(e) => e,
        other => panic!("expected an error, got {other:?}"),
    }
}
