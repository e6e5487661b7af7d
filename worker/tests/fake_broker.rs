//! The worker against a scripted broker (a ROUTER socket in the test): hello, credit,
//! map requests, results equal to local runs, bad input, heartbeats and reconnects.

// links libzmq (built with CURVE by paddock-libzmq) into this binary
use paddock_libzmq as _;
use std::time::{Duration, Instant};

use paddock_proto::convert::{local_map, map_ref, outcome_from_proto, scenario_to_proto};
use paddock_proto::{Body, ErrorCode, TaskAssign};
use paddock_rollout::{Scenario, run_episode};
use paddock_worker::{WorkerConfig, WorkerThread};

struct FakeBroker {
    _ctx: zmq::Context,
    sock: zmq::Socket,
    endpoint: String,
}

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
    fn recv(&self) -> (Vec<u8>, u64, Body) {
        let deadline = Instant::now() + Duration::from_secs(20);
        loop {
            assert!(Instant::now() < deadline, "no message from the worker");
            self.sock.set_rcvtimeo(500).unwrap();
            let Ok(parts) = self.sock.recv_multipart(0) else {
                continue;
            };
            let (id, body) = paddock_proto::decode(&parts[1]).unwrap();
            if !matches!(body, Body::Heartbeat(_)) {
                return (parts[0].clone(), id, body);
            }
        }
    }

    fn send(&self, to: &[u8], request_id: u64, body: Body) {
        self.send_raw(to, &paddock_proto::encode(request_id, body));
    }

    fn send_raw(&self, to: &[u8], frame: &[u8]) {
        self.sock.send_multipart([to, frame], 0).unwrap();
    }
}

fn scenario() -> Scenario {
    let mut s = Scenario::single("pure-pursuit").unwrap();
    s.time_limit = 1.0;
    s.lidar.num_beams = 60;
    s
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
fn runs_tasks_asks_for_maps_once_and_refuses_bad_input() {
    let broker = FakeBroker::new();
    let maps = tempfile::tempdir().unwrap();
    let worker = WorkerThread::spawn(config(&broker.endpoint, maps.path())).unwrap();
    let (wid, _, hello) = broker.recv();
    let Body::WorkerHello(hello) = hello else {
        panic!("expected hello, got {hello:?}");
    };
    // two threads, each with one task running and one waiting
    assert_eq!(hello.capacity, 2 * paddock_worker::PREFETCH as u32);
    assert!(hello.maps.is_empty());
    assert_eq!(hello.worker_id, worker.worker_id);

    let s = scenario();
    let bundle = local_map(&s.map).unwrap();
    let wire = scenario_to_proto(&s, map_ref(&bundle));
    for task_id in [10, 11] {
        let t = TaskAssign {
            task_id,
            scenario: Some(wire.clone()),
            seed: task_id,
            record_decimation: if task_id == 11 { 7 } else { 0 },
        };
        broker.send(&wid, 100 + task_id, Body::TaskAssign(t));
    }
    // one map request for both tasks
    let (_, map_req_id, body) = broker.recv();
    let Body::MapRequest(req) = body else {
        panic!("expected map request, got {body:?}");
    };
    assert_eq!(req.hash, bundle.hash);
    broker.send(&wid, map_req_id, Body::MapBundle(bundle.clone()));

    let mut results = Vec::new();
    while results.len() < 2 {
        let (_, rid, body) = broker.recv();
        match body {
            Body::TaskResult(r) => {
                assert_eq!(rid, 100 + r.task_id);
                results.push(r);
            }
            other => panic!("unexpected {other:?}"),
        }
    }
    results.sort_by_key(|r| r.task_id);
    for r in &results {
        let remote = outcome_from_proto(r.outcome.as_ref().unwrap()).unwrap();
        let record = (r.task_id == 11).then_some(7);
        let local = run_episode(&s, r.task_id, record).unwrap();
        assert_eq!(remote, local, "task {}", r.task_id);
    }

    // a task with NaN parameters: an error outcome naming the field, no crash
    let mut bad = wire.clone();
    bad.agents[0].params[1] = f64::NAN;
    broker.send(
        &wid,
        7,
        Body::TaskAssign(TaskAssign {
            task_id: 12,
            scenario: Some(bad),
            seed: 1,
            record_decimation: 0,
        }),
    );
    let (_, _, body) = broker.recv();
    let Body::TaskResult(r) = body else {
        panic!("expected a result, got {body:?}");
    };
    assert_eq!(r.task_id, 12);
    match r.outcome.unwrap().outcome.unwrap() {
        paddock_proto::task_outcome::Outcome::Error(e) => {
            assert_eq!(e.code, ErrorCode::InvalidArgument as i32);
            assert_eq!(e.field, "task_assign.scenario.agents[0].params[1]");
        }
        other => panic!("expected an error, got {other:?}"),
    }

    // a map hash that is not a hash; an unknown map the broker does not have either
    let mut odd = wire.clone();
    odd.map.as_mut().unwrap().hash = "../../etc".into();
    broker.send(
        &wid,
        8,
        Body::TaskAssign(TaskAssign {
            task_id: 13,
            scenario: Some(odd),
            seed: 1,
            record_decimation: 0,
        }),
    );
    let (_, _, body) = broker.recv();
    let Body::TaskResult(r) = body else {
        panic!("expected a result, got {body:?}");
    };
    let Some(paddock_proto::task_outcome::Outcome::Error(e)) = r.outcome.unwrap().outcome else {
        panic!("expected an error outcome");
    };
    assert_eq!(e.field, "task_assign.scenario.map.hash");

    let mut unknown = wire.clone();
    unknown.map.as_mut().unwrap().hash = "ab".repeat(32);
    broker.send(
        &wid,
        9,
        Body::TaskAssign(TaskAssign {
            task_id: 14,
            scenario: Some(unknown),
            seed: 1,
            record_decimation: 0,
        }),
    );
    let (_, req_id, body) = broker.recv();
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
    let (_, _, body) = broker.recv();
    let Body::TaskResult(r) = body else {
        panic!("expected a result, got {body:?}");
    };
    assert_eq!(r.task_id, 14);
    let Some(paddock_proto::task_outcome::Outcome::Error(e)) = r.outcome.unwrap().outcome else {
        panic!("expected an error outcome");
    };
    assert_eq!(e.code, ErrorCode::NotFound as i32);

    // garbage, a wrong version and a message a worker does not take: error replies
    broker.send_raw(&wid, &[0xff, 0x01, 0x02]);
    let (_, _, body) = broker.recv();
    let Body::Error(e) = body else {
        panic!("expected an error, got {body:?}");
    };
    assert_eq!(e.code, ErrorCode::BadMessage as i32);
    broker.send(
        &wid,
        55,
        Body::StatusRequest(paddock_proto::StatusRequest {}),
    );
    let (_, rid, body) = broker.recv();
    assert_eq!(rid, 55);
    let Body::Error(e) = body else {
        panic!("expected an error, got {body:?}");
    };
    assert_eq!(e.code, ErrorCode::UnknownType as i32);
    // env messages reach the sessions
    broker.send(
        &wid,
        56,
        Body::EnvClose(paddock_proto::EnvClose { session_id: 4 }),
    );
    let (_, rid, _) = broker.recv();
    assert_eq!(rid, 56);

    // it is still serving: the map is cached now, no request this time
    broker.send(
        &wid,
        60,
        Body::TaskAssign(TaskAssign {
            task_id: 20,
            scenario: Some(wire.clone()),
            seed: 20,
            record_decimation: 0,
        }),
    );
    let (_, _, body) = broker.recv();
    let Body::TaskResult(r) = body else {
        panic!("expected a result, got {body:?}");
    };
    assert_eq!(
        outcome_from_proto(r.outcome.as_ref().unwrap()).unwrap(),
        run_episode(&s, 20, None).unwrap()
    );
    assert_eq!(
        worker
            .stats
            .maps_requested
            .load(std::sync::atomic::Ordering::Relaxed),
        2
    );
    worker.stop().unwrap();
    let (_, _, body) = broker.recv();
    assert!(matches!(body, Body::Bye(_)), "{body:?}");
}

#[test]
fn beats_and_reconnects_when_the_broker_falls_silent() {
    let broker = FakeBroker::new();
    let maps = tempfile::tempdir().unwrap();
    let worker = WorkerThread::spawn(config(&broker.endpoint, maps.path())).unwrap();
    let (_, _, hello) = broker.recv();
    assert!(matches!(hello, Body::WorkerHello(_)));
    // heartbeats arrive about every 100 ms while the broker says nothing
    broker.sock.set_rcvtimeo(1000).unwrap();
    let parts = broker.sock.recv_multipart(0).unwrap();
    let (_, body) = paddock_proto::decode(&parts[1]).unwrap();
    assert!(matches!(body, Body::Heartbeat(_)), "{body:?}");
    // after 3 silent beats (300 ms) plus the backoff it says hello again
    let t0 = Instant::now();
    let (_, _, again) = broker.recv();
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
    let (wid, _, hello) = broker.recv();
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
    let (_, _, again) = broker.recv();
    assert!(matches!(again, Body::WorkerHello(_)), "{again:?}");
    assert!(
        t0.elapsed() < Duration::from_millis(250),
        "{:?}",
        t0.elapsed()
    );
    worker.stop().unwrap();
}

fn env_open(map: paddock_proto::MapRef, num_envs: u32) -> paddock_proto::EnvOpen {
    paddock_proto::EnvOpen {
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
    }
}

/// Reset with seeds 1..=n, then two steps; the observations.
fn drive(mut call: impl FnMut(Body) -> Body, session_id: u64, n: u32) -> Vec<Body> {
    let actions = paddock_proto::pack_f32(
        &(0..n)
            .flat_map(|i| [0.05 * i as f32, 2.5])
            .collect::<Vec<_>>(),
    );
    let mut out = vec![call(Body::EnvReset(paddock_proto::EnvReset {
        session_id,
        seeds: (1..=u64::from(n)).collect(),
        ..Default::default()
    }))];
    for _ in 0..2 {
        out.push(call(Body::EnvStep(paddock_proto::EnvStep {
            session_id,
            actions: actions.clone(),
            reset_envs: vec![],
        })));
    }
    out
}

#[test]
fn env_opens_wait_for_a_map_the_worker_lacks_and_ask_for_it_once() {
    let broker = FakeBroker::new();
    let maps = tempfile::tempdir().unwrap();
    let worker = WorkerThread::spawn(config(&broker.endpoint, maps.path())).unwrap();
    let (wid, _, hello) = broker.recv();
    assert!(matches!(hello, Body::WorkerHello(_)), "{hello:?}");

    // the shipped map under a name that resolves to nothing on this machine: only the
    // broker can supply it
    let mut bundle = local_map("lakeside").unwrap();
    bundle.name = "uploaded-copy".into();
    let uploaded = map_ref(&bundle);
    broker.send(&wid, 200, Body::EnvOpen(env_open(uploaded.clone(), 2)));
    broker.send(&wid, 201, Body::EnvOpen(env_open(uploaded.clone(), 1)));
    // one map request for both opens, and nothing answered before the map is here
    let (_, map_req_id, body) = broker.recv();
    let Body::MapRequest(req) = body else {
        panic!("expected a map request, got {body:?}");
    };
    assert_eq!(req.hash, bundle.hash);
    broker.send(&wid, map_req_id, Body::MapBundle(bundle.clone()));
    let mut opened = Vec::new();
    for want in [200, 201] {
        let (_, rid, body) = broker.recv();
        assert_eq!(rid, want);
        let Body::EnvOpened(o) = body else {
            panic!("expected env_opened for request {want}, got {body:?}");
        };
        opened.push(o);
    }
    assert_eq!((opened[0].num_envs, opened[1].num_envs), (2, 1));

    // the same session on a worker that has the map locally (by its shipped name)
    let mut local = paddock_worker::sessions::Sessions::new();
    let Some(Body::EnvOpened(here)) = local.handle(
        1,
        Body::EnvOpen(env_open(map_ref(&local_map("lakeside").unwrap()), 2)),
    ) else {
        panic!("the shipped map opens locally");
    };
    let mut rid = 210;
    let remote = drive(
        |b| {
            rid += 1;
            broker.send(&wid, rid, b);
            let (_, got, body) = broker.recv();
            assert_eq!(got, rid);
            body
        },
        opened[0].session_id,
        2,
    );
    let expected = drive(|b| local.handle(1, b).unwrap(), here.session_id, 2);
    for (k, (r, l)) in remote.iter().zip(&expected).enumerate() {
        let (Body::EnvObservation(r), Body::EnvObservation(l)) = (r, l) else {
            panic!("request {k}: expected observations, got {r:?} and {l:?}");
        };
        assert_eq!(r.scans, l.scans, "request {k}: scans");
        assert_eq!(r.states, l.states, "request {k}: states");
        assert_eq!(r.rewards, l.rewards, "request {k}: rewards");
        assert_eq!(r.time, l.time, "request {k}: time");
    }

    // a hash the broker does not have either: both opens get an error naming it
    let missing = paddock_proto::MapRef {
        hash: "ab".repeat(32),
        name: "nowhere".into(),
    };
    broker.send(&wid, 300, Body::EnvOpen(env_open(missing.clone(), 1)));
    broker.send(&wid, 301, Body::EnvOpen(env_open(missing.clone(), 1)));
    let (_, map_req_id, body) = broker.recv();
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
    for want in [300, 301] {
        let (_, rid, body) = broker.recv();
        assert_eq!(rid, want);
        let Body::Error(e) = body else {
            panic!("expected an error for request {want}, got {body:?}");
        };
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
