//! The worker against a scripted broker (a ROUTER socket in the test): hello, credit,
//! scenario and map requests (once per hash), results equal to local runs, bad input,
//! heartbeats and reconnects, env sessions under the broker's session ids.

// links libzmq (built with CURVE by paddock-libzmq) into this binary
use paddock_libzmq as _;
use std::time::{Duration, Instant};

use paddock_proto::{Body, EnvOp, ErrorCode, TaskAssign, TaskOutcome};
use paddock_rollout::{Scenario, run_episode};
use paddock_wire::{local_map, map_ref, outcome_from_bytes, scenario_to_proto};
use paddock_worker::{WorkerConfig, WorkerThread};
use prost::Message;

struct FakeBroker {
    _ctx: zmq::Context,
    sock: zmq::Socket,
    endpoint: String,
}

/// A message from the worker: its identity, request id, body and payload frames.
type Got = (Vec<u8>, u64, Body, Vec<Vec<u8>>);

impl FakeBroker {
    fn new() -> Self {
        let ctx = zmq::Context::new();
        let sock = ctx.socket(zmq::ROUTER).unwrap();
        sock.set_linger(0).unwrap();
        sock.bind("tcp://127.0.0.1:0").unwrap();
        let endpoint = sock.get_last_endpoint().unwrap().unwrap();
        Self {
            _ctx: ctx,
            sock,
            endpoint,
        }
    }

    /// The next message that is not a heartbeat, with the worker's identity.
    fn recv(&self) -> Got {
        let deadline = Instant::now() + Duration::from_secs(20);
        loop {
            assert!(Instant::now() < deadline, "no message from the worker");
            self.sock.set_rcvtimeo(500).unwrap();
            let Ok(mut parts) = self.sock.recv_multipart(0) else {
                continue;
            };
            let payload = parts.split_off(2);
            let (id, body) = paddock_proto::decode(&parts[1]).unwrap();
            assert_eq!(
                payload.len(),
                paddock_proto::payload_frames(&body),
                "payload frames of {body:?}"
            );
            if !matches!(body, Body::Heartbeat(_)) {
                return (parts[0].clone(), id, body, payload);
            }
        }
    }

    fn send(&self, to: &[u8], request_id: u64, body: Body) {
        self.send_with(to, request_id, body, Vec::new());
    }

    fn send_with(&self, to: &[u8], request_id: u64, body: Body, payload: Vec<Vec<u8>>) {
        let mut frames = vec![to.to_vec(), paddock_proto::encode(request_id, body)];
        frames.extend(payload);
        self.sock.send_multipart(frames, 0).unwrap();
    }

    fn send_raw(&self, to: &[u8], frame: &[u8]) {
        self.sock.send_multipart([to, frame], 0).unwrap();
    }

    fn env(&self, to: &[u8], rid: u64, sid: u64, op: EnvOp, payload: Option<Vec<u8>>) {
        let header = Body::EnvRequest(paddock_proto::EnvRequest {
            session_id: sid,
            op: op as i32,
        });
        self.send_with(to, rid, header, payload.into_iter().collect());
    }
}

fn scenario() -> Scenario {
    let mut s = Scenario::single("pure-pursuit").unwrap();
    s.time_limit = 1.0;
    s.lidar.num_beams = 60;
    s
}

/// An encoded wire scenario and its hash.
fn blob(s: &paddock_proto::Scenario) -> (Vec<u8>, String) {
    let bytes = s.encode_to_vec();
    let hash = paddock_proto::blob_hash(&bytes);
    (bytes, hash)
}

fn assign(task_id: u64, hash: &str, record_decimation: u32) -> Body {
    Body::TaskAssign(TaskAssign {
        task_id,
        scenario_hash: hash.into(),
        seed: task_id,
        record_decimation,
    })
}

/// A task result's id and outcome.
fn result(got: Got) -> (u64, TaskOutcome) {
    match got {
        (_, _, Body::TaskResult(r), payload) => (
            r.task_id,
            TaskOutcome::decode(payload[0].as_slice()).unwrap(),
        ),
        other => panic!("expected a task result, got {other:?}"),
    }
}

fn error_of(o: TaskOutcome) -> paddock_proto::Error {
    match o.outcome {
        Some(paddock_proto::task_outcome::Outcome::Error(e)) => e,
        other => panic!("expected an error outcome, got {other:?}"),
    }
}

/// Answers the worker's next message, a blob request for `hash`, with `data`.
fn serve_blob(broker: &FakeBroker, wid: &[u8], hash: &str, data: &[u8]) {
    let (_, rid, body, _) = broker.recv();
    let Body::BlobRequest(req) = body else {
        panic!("expected a blob request, got {body:?}");
    };
    assert_eq!(req.hash, hash);
    let b = paddock_proto::Blob {
        hash: hash.into(),
        data: data.to_vec(),
    };
    broker.send(wid, rid, Body::Blob(b));
}

fn config(endpoint: &str, maps: &std::path::Path) -> WorkerConfig {
    let mut cfg = WorkerConfig::new(endpoint);
    cfg.threads = 2;
    cfg.maps_dir = maps.to_path_buf();
    cfg.heartbeat = Duration::from_millis(100);
    cfg.backoff_initial = Duration::from_millis(50);
    cfg.backoff_max = Duration::from_millis(200);
    cfg
}

#[test]
fn runs_tasks_asks_for_scenarios_and_maps_once_and_refuses_bad_input() {
    let broker = FakeBroker::new();
    let maps = tempfile::tempdir().unwrap();
    let worker = WorkerThread::spawn(config(&broker.endpoint, maps.path())).unwrap();
    let (wid, _, hello, _) = broker.recv();
    let Body::WorkerHello(hello) = hello else {
        panic!("expected hello, got {hello:?}");
    };
    // two threads, each with one task running and one waiting
    assert_eq!(hello.capacity, 2 * paddock_worker::PREFETCH as u32);
    assert!(hello.maps.is_empty());
    assert_eq!(hello.worker_id, worker.worker_id);

    let s = scenario();
    let bundle = local_map(&paddock_sim::circuit::Circuits::new(), &s.map).unwrap();
    let wire = scenario_to_proto(&s, map_ref(&bundle));
    let (bytes, hash) = blob(&wire);
    for task_id in [10, 11] {
        let record = if task_id == 11 { 7 } else { 0 };
        broker.send(&wid, 100 + task_id, assign(task_id, &hash, record));
    }
    // one scenario request, then one map request, for both tasks
    serve_blob(&broker, &wid, &hash, &bytes);
    let (_, map_req_id, body, _) = broker.recv();
    let Body::MapRequest(req) = body else {
        panic!("expected map request, got {body:?}");
    };
    assert_eq!(req.hash, bundle.hash);
    broker.send(&wid, map_req_id, Body::MapBundle(bundle.clone()));

    let mut results = Vec::new();
    while results.len() < 2 {
        let got = broker.recv();
        assert_eq!(got.1, 100 + result(got.clone()).0, "the task's request id");
        results.push(result(got));
    }
    results.sort_by_key(|r| r.0);
    for (task_id, outcome) in &results {
        let remote = outcome_from_bytes(&outcome.encode_to_vec()).unwrap();
        let record = (*task_id == 11).then_some(7);
        let local =
            run_episode(&paddock_sim::circuit::Circuits::new(), &s, *task_id, record).unwrap();
        assert_eq!(remote, local, "task {task_id}");
    }

    // a scenario with NaN parameters: an error outcome naming the field, no crash
    let mut bad = wire.clone();
    bad.agents[0].params[1] = f64::NAN;
    let (bad_bytes, bad_hash) = blob(&bad);
    broker.send(&wid, 7, assign(12, &bad_hash, 0));
    serve_blob(&broker, &wid, &bad_hash, &bad_bytes);
    let (id, outcome) = result(broker.recv());
    assert_eq!(id, 12);
    let e = error_of(outcome);
    assert_eq!(e.code, ErrorCode::InvalidArgument as i32);
    assert_eq!(e.field, "task_assign.scenario.agents[0].params[1]");

    // a scenario hash that is not a hash; a scenario whose map hash is not a hash
    broker.send(&wid, 8, assign(13, "../../etc", 0));
    let e = error_of(result(broker.recv()).1);
    assert_eq!(e.field, "task_assign.scenario_hash");
    let mut odd = wire.clone();
    odd.map.as_mut().unwrap().hash = "../../etc".into();
    let (odd_bytes, odd_hash) = blob(&odd);
    broker.send(&wid, 8, assign(14, &odd_hash, 0));
    serve_blob(&broker, &wid, &odd_hash, &odd_bytes);
    let e = error_of(result(broker.recv()).1);
    assert_eq!(e.field, "task_assign.scenario.map.hash");

    // bytes that do not have the hash they came under
    let mut other = wire.clone();
    other.laps = 3;
    let (_, other_hash) = blob(&other);
    broker.send(&wid, 9, assign(15, &other_hash, 0));
    serve_blob(&broker, &wid, &other_hash, &bytes);
    let e = error_of(result(broker.recv()).1);
    assert_eq!(e.code, ErrorCode::Internal as i32);
    assert!(e.message.contains("do not have that hash"), "{}", e.message);

    // a map the broker does not have either
    let mut unknown = wire.clone();
    unknown.map.as_mut().unwrap().hash = "ab".repeat(32);
    let (unknown_bytes, unknown_hash) = blob(&unknown);
    broker.send(&wid, 9, assign(16, &unknown_hash, 0));
    serve_blob(&broker, &wid, &unknown_hash, &unknown_bytes);
    let (_, req_id, body, _) = broker.recv();
    assert!(matches!(body, Body::MapRequest(_)), "{body:?}");
    broker.send(
        &wid,
        req_id,
        Body::Error(paddock_proto::error(
            ErrorCode::NotFound,
            "map_request.hash",
            "no such map",
        )),
    );
    let (id, outcome) = result(broker.recv());
    assert_eq!(id, 16);
    assert_eq!(error_of(outcome).code, ErrorCode::NotFound as i32);

    // a scenario the broker no longer has
    let mut gone = wire.clone();
    gone.laps = 4;
    let (_, gone_hash) = blob(&gone);
    broker.send(&wid, 9, assign(17, &gone_hash, 0));
    let (_, req_id, body, _) = broker.recv();
    assert!(matches!(body, Body::BlobRequest(_)), "{body:?}");
    broker.send(
        &wid,
        req_id,
        Body::Error(paddock_proto::error(
            ErrorCode::NotFound,
            "blob_request.hash",
            "not held",
        )),
    );
    let e = error_of(result(broker.recv()).1);
    assert_eq!(
        (e.code, e.field.as_str()),
        (ErrorCode::NotFound as i32, "task_assign.scenario_hash")
    );

    // garbage, a wrong version, a message a worker does not take and a payload frame too
    // many: error replies
    broker.send_raw(&wid, &[0xff, 0x01, 0x02]);
    let (_, _, body, _) = broker.recv();
    let Body::Error(e) = body else {
        panic!("expected an error, got {body:?}");
    };
    assert_eq!(e.code, ErrorCode::BadMessage as i32);
    broker.send(
        &wid,
        55,
        Body::StatusRequest(paddock_proto::StatusRequest {}),
    );
    let (_, rid, body, _) = broker.recv();
    assert_eq!(rid, 55);
    let Body::Error(e) = body else {
        panic!("expected an error, got {body:?}");
    };
    assert_eq!(e.code, ErrorCode::UnknownType as i32);
    broker.send_with(&wid, 57, assign(18, &hash, 0), vec![b"extra".to_vec()]);
    let (_, rid, body, _) = broker.recv();
    assert_eq!(rid, 57);
    let Body::Error(e) = body else {
        panic!("expected an error, got {body:?}");
    };
    assert_eq!(e.code, ErrorCode::BadMessage as i32);
    // env requests reach the sessions, and their errors come in the env reply
    broker.env(&wid, 56, 4, EnvOp::EnvClose, None);
    let (_, rid, body, _) = broker.recv();
    assert_eq!(rid, 56);
    let Body::EnvReply(r) = body else {
        panic!("expected an env reply, got {body:?}");
    };
    assert_eq!(r.session_id, 4);
    assert_eq!(r.error.unwrap().code, ErrorCode::NotFound as i32);

    // it is still serving: the scenario and map are cached now, no request this time
    broker.send(&wid, 60, assign(20, &hash, 0));
    let (_, outcome) = result(broker.recv());
    assert_eq!(
        outcome_from_bytes(&outcome.encode_to_vec()).unwrap(),
        run_episode(&paddock_sim::circuit::Circuits::new(), &s, 20, None).unwrap()
    );
    assert_eq!(
        worker
            .stats
            .maps_requested
            .load(std::sync::atomic::Ordering::Relaxed),
        2
    );
    worker.stop().unwrap();
    let (_, _, body, _) = broker.recv();
    assert!(matches!(body, Body::Bye(_)), "{body:?}");
}

#[test]
fn beats_and_reconnects_when_the_broker_falls_silent() {
    let broker = FakeBroker::new();
    let maps = tempfile::tempdir().unwrap();
    let worker = WorkerThread::spawn(config(&broker.endpoint, maps.path())).unwrap();
    let (_, _, hello, _) = broker.recv();
    assert!(matches!(hello, Body::WorkerHello(_)));
    // heartbeats arrive about every 100 ms while the broker says nothing
    broker.sock.set_rcvtimeo(1000).unwrap();
    let parts = broker.sock.recv_multipart(0).unwrap();
    let (_, body) = paddock_proto::decode(&parts[1]).unwrap();
    assert!(matches!(body, Body::Heartbeat(_)), "{body:?}");
    // after 3 silent beats (300 ms) plus the backoff it says hello again
    let t0 = Instant::now();
    let (_, _, again, _) = broker.recv();
    assert!(matches!(again, Body::WorkerHello(_)), "{again:?}");
    assert!(t0.elapsed() < Duration::from_secs(3));
    assert!(
        worker
            .stats
            .reconnects
            .load(std::sync::atomic::Ordering::Relaxed)
            >= 1
    );
    worker.stop().unwrap();
}

#[test]
fn says_hello_again_to_a_restarted_broker_that_does_not_know_it() {
    let broker = FakeBroker::new();
    let maps = tempfile::tempdir().unwrap();
    let mut cfg = config(&broker.endpoint, maps.path());
    // long enough that a reconnect for silence cannot explain a second hello
    cfg.heartbeat = Duration::from_millis(300);
    let worker = WorkerThread::spawn(cfg).unwrap();
    let (wid, _, hello, _) = broker.recv();
    assert!(matches!(hello, Body::WorkerHello(_)));
    // a restarted broker answers the next heartbeat with NOT_FOUND for worker_id
    broker.sock.set_rcvtimeo(2000).unwrap();
    let parts = broker.sock.recv_multipart(0).unwrap();
    let (rid, body) = paddock_proto::decode(&parts[1]).unwrap();
    assert!(matches!(body, Body::Heartbeat(_)), "{body:?}");
    let t0 = Instant::now();
    broker.send(
        &wid,
        rid,
        Body::Error(paddock_proto::error(
            ErrorCode::NotFound,
            "worker_id",
            "this broker does not know this worker",
        )),
    );
    let (_, _, again, _) = broker.recv();
    assert!(matches!(again, Body::WorkerHello(_)), "{again:?}");
    assert!(
        t0.elapsed() < Duration::from_millis(250),
        "{:?}",
        t0.elapsed()
    );
    worker.stop().unwrap();
}

/// A restarted broker never answers the fetches the worker asked of the old one: once
/// the new one says it does not know the worker, a task naming the same scenario makes
/// the worker ask for it again (it used to wait for the lost answer forever).
#[test]
fn asks_again_for_a_scenario_it_asked_of_a_broker_that_restarted() {
    let broker = FakeBroker::new();
    let maps = tempfile::tempdir().unwrap();
    let mut cfg = config(&broker.endpoint, maps.path());
    // long beats: no reconnect for silence (which also forgets fetches) in this test
    cfg.heartbeat = Duration::from_secs(2);
    let worker = WorkerThread::spawn(cfg).unwrap();
    let (wid, _, hello, _) = broker.recv();
    assert!(matches!(hello, Body::WorkerHello(_)));
    let b = local_map(&paddock_sim::circuit::Circuits::new(), "lakeside").unwrap();
    let wire = scenario_to_proto(&scenario(), map_ref(&b));
    let (bytes, hash) = blob(&wire);
    broker.send(&wid, 1, assign(1, &hash, 0));
    let (_, _, asked, _) = broker.recv();
    assert!(matches!(asked, Body::BlobRequest(_)), "{asked:?}");
    // the broker dies with the request unanswered; the new one does not know the worker
    // (a worker says hello at most once per half beat)
    std::thread::sleep(Duration::from_millis(1100));
    broker.send(
        &wid,
        0,
        Body::Error(paddock_proto::error(
            ErrorCode::NotFound,
            "worker_id",
            "this broker does not know this worker",
        )),
    );
    let (_, _, again, _) = broker.recv();
    assert!(matches!(again, Body::WorkerHello(_)), "{again:?}");
    // the new broker assigns a task of the same scenario: the worker asks for it again
    broker.send(&wid, 2, assign(2, &hash, 0));
    serve_blob(&broker, &wid, &hash, &bytes);
    let (_, map_req_id, body, _) = broker.recv();
    assert!(matches!(body, Body::MapRequest(_)), "{body:?}");
    broker.send(&wid, map_req_id, Body::MapBundle(b.clone()));
    let got = broker.recv();
    let (task_id, outcome) = result(got);
    assert_eq!(task_id, 2);
    assert!(
        matches!(
            outcome.outcome,
            Some(paddock_proto::task_outcome::Outcome::Episode(_))
        ),
        "{outcome:?}"
    );
    worker.stop().unwrap();
}

fn env_open(map: paddock_proto::MapRef, num_envs: u32) -> Option<Vec<u8>> {
    let o = paddock_proto::EnvOpen {
        map: Some(map),
        num_envs,
        seed: 3,
        lidar: Some(paddock_proto::Lidar {
            num_beams: 48,
            fov: 4.7,
            max_range: 30.0,
            noise_std: 0.01,
            mount_offset: 0.0,
        }),
        laps: 1,
        time_limit: 30.0,
        frame_skip: 1,
        ..Default::default()
    };
    Some(o.encode_to_vec())
}

/// Reset with seeds 1..=n, then two steps; the replies' payload frames and fingerprints.
fn drive(
    mut call: impl FnMut(EnvOp, Vec<u8>) -> (u64, Vec<Vec<u8>>),
    n: u32,
) -> Vec<(u64, Vec<Vec<u8>>)> {
    let actions = paddock_proto::pack_f32(
        &(0..n)
            .flat_map(|i| [0.05 * i as f32, 2.5])
            .collect::<Vec<_>>(),
    );
    let reset = paddock_proto::EnvReset {
        seeds: (1..=u64::from(n)).collect(),
        ..Default::default()
    };
    let mut out = vec![call(EnvOp::EnvReset, reset.encode_to_vec())];
    for _ in 0..2 {
        let step = paddock_proto::EnvStep {
            actions: actions.clone(),
            reset_envs: vec![],
        };
        out.push(call(EnvOp::EnvStep, step.encode_to_vec()));
    }
    out
}

#[test]
fn env_opens_wait_for_a_map_the_worker_lacks_and_ask_for_it_once() {
    let broker = FakeBroker::new();
    let maps = tempfile::tempdir().unwrap();
    let worker = WorkerThread::spawn(config(&broker.endpoint, maps.path())).unwrap();
    let (wid, _, hello, _) = broker.recv();
    assert!(matches!(hello, Body::WorkerHello(_)), "{hello:?}");

    // the shipped map under a name that resolves to nothing on this machine: only the
    // broker can supply it
    let mut bundle = local_map(&paddock_sim::circuit::Circuits::new(), "lakeside").unwrap();
    bundle.name = "uploaded-copy".into();
    let uploaded = map_ref(&bundle);
    let (s1, s2) = (0x5eed_0001, 0x5eed_0002);
    broker.env(&wid, 200, s1, EnvOp::EnvOpen, env_open(uploaded.clone(), 2));
    broker.env(&wid, 201, s2, EnvOp::EnvOpen, env_open(uploaded.clone(), 1));
    // one map request for both opens, and nothing answered before the map is here
    let (_, map_req_id, body, _) = broker.recv();
    let Body::MapRequest(req) = body else {
        panic!("expected a map request, got {body:?}");
    };
    assert_eq!(req.hash, bundle.hash);
    broker.send(&wid, map_req_id, Body::MapBundle(bundle.clone()));
    let mut opened = Vec::new();
    for (want, sid) in [(200, s1), (201, s2)] {
        let (_, rid, body, frames) = broker.recv();
        assert_eq!(rid, want);
        let Body::EnvReply(r) = body else {
            panic!("expected an env reply for request {want}, got {body:?}");
        };
        assert_eq!(r.session_id, sid, "the session has the broker's id");
        assert!(r.error.is_none(), "{:?}", r.error);
        opened.push(paddock_proto::EnvOpened::decode(frames[0].as_slice()).unwrap());
    }
    assert_eq!((opened[0].num_envs, opened[1].num_envs), (2, 1));

    // the same session on a worker that has the map locally (by its shipped name)
    let mut local = paddock_worker::sessions::Sessions::new();
    let here = local.handle(
        1,
        EnvOp::EnvOpen as i32,
        &env_open(
            map_ref(&local_map(&paddock_sim::circuit::Circuits::new(), "lakeside").unwrap()),
            2,
        )
        .unwrap(),
    );
    assert!(here.header.error.is_none(), "the shipped map opens locally");
    let mut rid = 210;
    let remote = drive(
        |op, payload| {
            rid += 1;
            broker.env(&wid, rid, s1, op, Some(payload));
            let (_, got, body, frames) = broker.recv();
            assert_eq!(got, rid);
            let Body::EnvReply(r) = body else {
                panic!("expected an env reply, got {body:?}");
            };
            (r.fingerprint, frames)
        },
        2,
    );
    let expected = drive(
        |op, payload| {
            let r = local.handle(1, op as i32, &payload);
            (r.header.fingerprint, r.frames)
        },
        2,
    );
    assert_eq!(remote, expected, "the same frames and fingerprints");

    // a hash the broker does not have either: both opens get an error naming it
    let missing = paddock_proto::MapRef {
        hash: "ab".repeat(32),
        name: "nowhere".into(),
    };
    broker.env(&wid, 300, 3, EnvOp::EnvOpen, env_open(missing.clone(), 1));
    broker.env(&wid, 301, 4, EnvOp::EnvOpen, env_open(missing.clone(), 1));
    let (_, map_req_id, body, _) = broker.recv();
    let Body::MapRequest(req) = body else {
        panic!("expected a map request, got {body:?}");
    };
    assert_eq!(req.hash, missing.hash);
    broker.send(
        &wid,
        map_req_id,
        Body::Error(paddock_proto::error(
            ErrorCode::NotFound,
            "map_request.hash",
            format!("map hash {:?} is not stored in this broker", missing.hash),
        )),
    );
    for (want, sid) in [(300, 3), (301, 4)] {
        let (_, rid, body, frames) = broker.recv();
        assert_eq!(rid, want);
        assert!(frames.is_empty());
        let Body::EnvReply(r) = body else {
            panic!("expected an env reply for request {want}, got {body:?}");
        };
        assert_eq!(r.session_id, sid);
        let e = r.error.expect("an error");
        assert_eq!(
            (e.code, e.field.as_str()),
            (ErrorCode::NotFound as i32, "env_open.map.hash")
        );
        assert!(e.message.contains(&missing.hash), "{}", e.message);
        assert!(
            e.message.contains("not stored in this broker"),
            "{}",
            e.message
        );
    }
    assert_eq!(
        worker
            .stats
            .maps_requested
            .load(std::sync::atomic::Ordering::Relaxed),
        2
    );
    worker.stop().unwrap();
}
