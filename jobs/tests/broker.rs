//! The real broker (with the real job plans) over real ZeroMQ sockets, with raw clients
//! and test workers.

mod common;

use std::time::{Duration, Instant};

use common::*;
use paddock_proto::{Body, EnvOp, Envelope, ErrorCode, PROTOCOL_VERSION};
use prost::Message;

const T: Duration = Duration::from_secs(30);

fn code(e: &paddock_proto::Error) -> ErrorCode {
    ErrorCode::try_from(e.code).unwrap()
}

/// The batch with its scenario `i` changed by `f`.
fn with_scenario(
    mut b: paddock_proto::RolloutBatch,
    i: usize,
    f: impl FnOnce(&mut paddock_proto::Scenario),
) -> paddock_proto::RolloutBatch {
    let mut s = paddock_proto::Scenario::decode(b.scenarios[i].as_slice()).unwrap();
    f(&mut s);
    b.scenarios[i] = s.encode_to_vec();
    b
}

fn step(actions: Vec<u8>) -> Option<Vec<u8>> {
    Some(
        paddock_proto::EnvStep {
            actions,
            ..Default::default()
        }
        .encode_to_vec(),
    )
}

/// The rewards an echo worker put in an observation reply.
fn echoed(reply: (Body, Vec<Vec<u8>>), session: u64) -> Vec<u8> {
    match reply {
        (Body::EnvReply(r), frames) => {
            assert_eq!(r.session_id, session);
            assert!(r.error.is_none(), "{:?}", r.error);
            paddock_proto::EnvObservation::decode(frames[0].as_slice())
                .unwrap()
                .rewards
        }
        other => panic!("expected env_reply, got {other:?}"),
    }
}

/// The error of an env reply or of a plain error reply.
fn env_error(body: Body) -> paddock_proto::Error {
    match body {
        Body::EnvReply(paddock_proto::EnvReply { error: Some(e), .. }) | Body::Error(e) => e,
        other => panic!("expected an error, got {other:?}"),
    }
}

#[test]
fn every_bad_input_gets_an_error_reply_and_the_broker_keeps_serving() {
    let dir = tempfile::tempdir().unwrap();
    let broker = TestBroker::start(dir.path().into(), |c| c.max_message_bytes = 1 << 20);
    let c = RawPeer::connect(&broker.frontend);

    // malformed frame
    c.send_raw(&[0xff, 0xff, 0xff, 0x01]);
    let e = expect_error(c.recv(T).1);
    assert_eq!(code(&e), ErrorCode::BadMessage);
    assert!(e.message.contains("malformed"), "{e:?}");

    // wrong version, keeping the request id
    let old = Envelope {
        protocol_version: 9,
        request_id: 11,
        client_token: Vec::new(),
        body: Some(Body::StatusRequest(paddock_proto::StatusRequest {})),
    };
    c.send_raw(&old.encode_to_vec());
    let (rid, body) = c.recv(T);
    assert_eq!(rid, 11);
    let e = expect_error(body);
    assert_eq!(code(&e), ErrorCode::UnsupportedVersion);
    assert_eq!(e.field, "protocol_version");
    assert!(e.message.contains('9'), "{e:?}");

    // empty body
    let empty = Envelope {
        protocol_version: PROTOCOL_VERSION,
        request_id: 12,
        client_token: Vec::new(),
        body: None,
    };
    c.send_raw(&empty.encode_to_vec());
    let e = expect_error(c.reply_to(12, T));
    assert_eq!(code(&e), ErrorCode::UnknownType);

    // a body the client socket does not accept
    c.send(
        13,
        Body::Heartbeat(paddock_proto::Heartbeat { in_flight: 0 }),
    );
    let e = expect_error(c.reply_to(13, T));
    assert_eq!(code(&e), ErrorCode::UnknownType);
    assert!(e.message.contains("heartbeat"), "{e:?}");

    // a payload frame after a body that has none
    c.send_with(
        22,
        Body::StatusRequest(paddock_proto::StatusRequest {}),
        vec![b"b".to_vec()],
    );
    let e = expect_error(c.reply_to(22, T));
    assert_eq!(code(&e), ErrorCode::BadMessage);
    assert!(
        e.message
            .contains("followed by 0 payload frame(s), this message has 1"),
        "{e:?}"
    );

    // oversized: refused by the socket before it is read into memory (the connection
    // is dropped; the client's socket reconnects and is served again)
    c.send_raw(&vec![0u8; (1 << 20) + 1]);
    assert!(c.try_recv(Duration::from_millis(500)).is_none());
    let _ = status(&c, 23);

    // unknown map hash
    let (_, map) = lakeside();
    c.send(14, Body::RolloutBatch(batch(&map, 2, 0, 1.0)));
    let e = expect_error(c.reply_to(14, T));
    assert_eq!(code(&e), ErrorCode::NotFound);
    assert_eq!(e.field, "rollout_batch.scenarios[0].map.hash");
    assert!(e.message.contains(&map.hash), "{e:?}");

    let map = put_lakeside(&c);

    // NaN parameter
    let b = with_scenario(batch(&map, 2, 0, 1.0), 0, |s| {
        s.agents[0].params[1] = f64::NAN
    });
    c.send(15, Body::RolloutBatch(b));
    let e = expect_error(c.reply_to(15, T));
    assert_eq!(code(&e), ErrorCode::InvalidArgument);
    assert_eq!(e.field, "rollout_batch.scenarios[0].agents[0].params[1]");
    assert!(e.message.contains("NaN"), "{e:?}");

    // unknown driver
    let b = with_scenario(batch(&map, 2, 0, 1.0), 0, |s| {
        s.agents[0].driver = "no-such-driver".into()
    });
    c.send(16, Body::RolloutBatch(b));
    let e = expect_error(c.reply_to(16, T));
    assert_eq!(code(&e), ErrorCode::InvalidArgument);
    assert_eq!(e.field, "rollout_batch.scenarios[0].agents[0].driver");
    assert!(e.message.contains("no-such-driver"), "{e:?}");

    // out-of-range task index and time limit
    let mut b = batch(&map, 2, 0, 1.0);
    b.tasks[1].scenario = 3;
    c.send(17, Body::RolloutBatch(b));
    let e = expect_error(c.reply_to(17, T));
    assert_eq!(e.field, "rollout_batch.tasks[1].scenario");
    let b = with_scenario(batch(&map, 2, 0, 1.0), 0, |s| s.time_limit = -1.0);
    c.send(18, Body::RolloutBatch(b));
    let e = expect_error(c.reply_to(18, T));
    assert_eq!(e.field, "rollout_batch.scenarios[0].time_limit");

    // a bad map bundle and an unknown job and session
    let (mut bundle, _) = lakeside();
    bundle.files[0].data.push(0);
    c.send(
        19,
        Body::PutMap(paddock_proto::PutMap {
            bundle: Some(bundle),
        }),
    );
    let e = expect_error(c.reply_to(19, T));
    assert_eq!(e.field, "put_map.map_bundle.hash");
    c.send(
        20,
        Body::JobStatus(paddock_proto::JobStatusRequest {
            job_id: "job-404".into(),
        }),
    );
    let e = expect_error(c.reply_to(20, T));
    assert_eq!(
        (code(&e), e.field.as_str()),
        (ErrorCode::NotFound, "job_status.job_id")
    );
    c.env(21, 77, EnvOp::EnvStep, step(vec![]));
    let e = expect_error(c.reply_to(21, T));
    assert_eq!(
        (code(&e), e.field.as_str()),
        (ErrorCode::NotFound, "env_request.session_id")
    );

    // a bad worker hello on the worker socket
    let w = RawPeer::connect(&broker.backend);
    w.send(
        3,
        Body::WorkerHello(paddock_proto::WorkerHello {
            worker_id: "w".into(),
            capacity: 0,
            ..Default::default()
        }),
    );
    let e = expect_error(w.reply_to(3, T));
    assert_eq!(e.field, "worker_hello.capacity");

    // still serving: a good batch runs, and every refusal was counted by code
    let cache = tempfile::tempdir().unwrap();
    let _worker = TestWorker::spawn(&broker.backend, WorkerOpts::default(), cache.path().into());
    let good = batch(&map, 3, 1, 1.0);
    c.send(30, Body::RolloutBatch(good.clone()));
    assert_eq!(c.outcomes(30, T), run_locally(&good));
    let s = status(&c, 31);
    let count = |k: &str| s.errors.get(k).copied().unwrap_or(0);
    assert_eq!(count("BAD_MESSAGE"), 2);
    assert_eq!(count("UNSUPPORTED_VERSION"), 1);
    assert_eq!(count("UNKNOWN_TYPE"), 2);
    assert_eq!(count("NOT_FOUND"), 3);
    assert_eq!(count("INVALID_ARGUMENT"), 6);
}

#[test]
fn remote_results_equal_local_and_credit_is_never_exceeded() {
    let dir = tempfile::tempdir().unwrap();
    let broker = TestBroker::start(dir.path().into(), |_| {});
    let c = RawPeer::connect(&broker.frontend);
    let map = put_lakeside(&c);
    let cache = tempfile::tempdir().unwrap();
    let workers: Vec<TestWorker> = (0..2)
        .map(|i| {
            TestWorker::spawn(
                &broker.backend,
                WorkerOpts {
                    capacity: 2,
                    delay: Duration::from_millis(20),
                    id: format!("w{i}"),
                    ..Default::default()
                },
                cache.path().join(format!("w{i}")),
            )
        })
        .collect();
    for w in &workers {
        w.wait_welcomed();
    }
    let b = batch(&map, 16, 7, 1.5);
    c.send(1, Body::RolloutBatch(b.clone()));
    let mut progress = 0;
    let got: Vec<paddock_proto::TaskOutcome> = loop {
        let (rid, body, frames) = c.recv_frames(T);
        assert_eq!(rid, 1);
        match body {
            Body::RolloutProgress(p) => {
                assert!(p.done as usize > progress && p.total == 16, "{p:?}");
                progress = p.done as usize;
            }
            Body::RolloutResult(r) => {
                assert_eq!(r.outcomes, 16);
                break frames.iter().map(|f| decode_outcome(f)).collect();
            }
            other => panic!("unexpected {other:?}"),
        }
    };
    assert_eq!(got, run_locally(&b), "remote == local, bit for bit");
    assert!(matches!(
        got[0].outcome,
        Some(paddock_proto::task_outcome::Outcome::Episode(ref e)) if e.trajectory.is_some()
    ));
    let mut total = 0;
    for w in &workers {
        let max = w
            .stats
            .max_in_flight
            .load(std::sync::atomic::Ordering::Relaxed);
        assert!(max <= 2, "a worker held {max} tasks with capacity 2");
        total += w.stats.received.load(std::sync::atomic::Ordering::Relaxed);
    }
    assert_eq!(total, 16);
    let s = status(&c, 2);
    assert_eq!(s.workers.len(), 2);
    assert_eq!(s.tasks_done, 16);
    assert_eq!(s.queue_depth, 0);
    assert!(s.tasks_per_s > 0.0);
}

#[test]
fn a_dead_workers_tasks_are_requeued_and_duplicates_dropped() {
    let dir = tempfile::tempdir().unwrap();
    let broker = TestBroker::start(dir.path().into(), |c| {
        c.liveness.interval = Duration::from_millis(200);
    });
    let c = RawPeer::connect(&broker.frontend);
    let map = put_lakeside(&c);
    let cache = tempfile::tempdir().unwrap();
    // goes silent after taking 3 tasks (like kill -9 or SIGSTOP)
    let dying = TestWorker::spawn(
        &broker.backend,
        WorkerOpts {
            capacity: 3,
            silent_after: Some(0),
            id: "dying".into(),
            ..Default::default()
        },
        cache.path().join("a"),
    );
    dying.wait_welcomed();
    let b = batch(&map, 10, 3, 1.0);
    c.send(1, Body::RolloutBatch(b.clone()));
    let t0 = Instant::now();
    while dying
        .stats
        .received
        .load(std::sync::atomic::Ordering::Relaxed)
        < 3
    {
        assert!(t0.elapsed() < T);
        std::thread::sleep(Duration::from_millis(5));
    }
    // a healthy worker that answers everything twice joins
    let healthy = TestWorker::spawn(
        &broker.backend,
        WorkerOpts {
            capacity: 2,
            duplicate: true,
            id: "healthy".into(),
            ..Default::default()
        },
        cache.path().join("b"),
    );
    let got = c.outcomes(1, T);
    assert_eq!(got, run_locally(&b));
    // the dead worker's three tasks ran on the healthy one
    let ran = healthy
        .stats
        .received
        .load(std::sync::atomic::Ordering::Relaxed);
    assert!(ran >= 10, "the healthy worker ran {ran} of 10 tasks");
    let s = status(&c, 2);
    assert_eq!(s.workers.len(), 1, "{:?}", s.workers);
    assert_eq!(s.workers[0].worker_id, "healthy");
    assert_eq!(s.tasks_done, 10, "duplicates are not counted");
    drop(dying);
}

#[test]
fn a_small_batch_is_not_starved_by_a_huge_one() {
    let dir = tempfile::tempdir().unwrap();
    let broker = TestBroker::start(dir.path().into(), |_| {});
    let big = RawPeer::connect(&broker.frontend);
    let small = RawPeer::connect(&broker.frontend);
    let map = put_lakeside(&big);
    let cache = tempfile::tempdir().unwrap();
    let w = TestWorker::spawn(
        &broker.backend,
        WorkerOpts {
            capacity: 1,
            delay: Duration::from_millis(10),
            ..Default::default()
        },
        cache.path().into(),
    );
    w.wait_welcomed();
    big.send(1, Body::RolloutBatch(batch(&map, 60, 1, 0.5)));
    std::thread::sleep(Duration::from_millis(50));
    small.send(1, Body::RolloutBatch(batch(&map, 2, 2, 0.5)));
    let r = small.outcomes(1, T);
    assert_eq!(r.len(), 2);
    let done_when_small_finished = w.stats.answered.load(std::sync::atomic::Ordering::Relaxed);
    assert!(
        done_when_small_finished < 20,
        "the small batch waited for {done_when_small_finished} tasks"
    );
    assert_eq!(big.outcomes(1, T).len(), 60);
}

#[test]
fn a_full_queue_answers_busy() {
    let dir = tempfile::tempdir().unwrap();
    let broker = TestBroker::start(dir.path().into(), |c| {
        c.limits.max_tasks_per_client = 5;
        c.limits.max_tasks = 8;
    });
    let a = RawPeer::connect(&broker.frontend);
    let b = RawPeer::connect(&broker.frontend);
    let map = put_lakeside(&a);
    // no worker: tasks stay queued
    a.send(1, Body::RolloutBatch(batch(&map, 5, 0, 0.5)));
    a.send(2, Body::RolloutBatch(batch(&map, 1, 0, 0.5)));
    let e = expect_error(a.reply_to(2, T));
    assert_eq!(code(&e), ErrorCode::Busy);
    assert_eq!(e.field, "rollout_batch.tasks");
    assert!(e.message.contains("client queue"), "{e:?}");
    b.send(1, Body::RolloutBatch(batch(&map, 4, 0, 0.5)));
    let e = expect_error(b.reply_to(1, T));
    assert!(e.message.contains("broker queue"), "{e:?}");
    assert_eq!(status(&b, 2).queue_depth, 5);
    // a batch that could never fit is refused outright
    b.send(3, Body::RolloutBatch(batch(&map, 6, 0, 0.5)));
    let e = expect_error(b.reply_to(3, T));
    assert_eq!(code(&e), ErrorCode::InvalidArgument);
    assert!(e.message.contains("split the batch"), "{e:?}");
    // once a worker drains the queue, a takes work again
    let cache = tempfile::tempdir().unwrap();
    let _w = TestWorker::spawn(&broker.backend, WorkerOpts::default(), cache.path().into());
    assert_eq!(a.outcomes(1, T).len(), 5);
    a.send(3, Body::RolloutBatch(batch(&map, 5, 0, 0.5)));
    assert_eq!(a.outcomes(3, T).len(), 5);
}

#[test]
fn env_sessions_route_by_session_and_move_when_their_worker_dies() {
    let dir = tempfile::tempdir().unwrap();
    let broker = TestBroker::start(dir.path().into(), |c| {
        c.liveness.interval = Duration::from_millis(200);
        c.session_logs.wait = Duration::from_millis(300);
    });
    let c1 = RawPeer::connect(&broker.frontend);
    let c2 = RawPeer::connect(&broker.frontend).with_client(2);
    let map = put_lakeside(&c1);
    let open_msg = |n: u32| {
        Some(
            paddock_proto::EnvOpen {
                map: Some(map.clone()),
                num_envs: n,
                ..Default::default()
            }
            .encode_to_vec(),
        )
    };
    c1.env(1, 0, EnvOp::EnvOpen, open_msg(1));
    let e = expect_error(c1.reply_to(1, T));
    assert_eq!(code(&e), ErrorCode::Busy, "no worker yet: {e:?}");
    let cache = tempfile::tempdir().unwrap();
    // the second worker dies on its first step
    let w1 = TestWorker::spawn(
        &broker.backend,
        WorkerOpts {
            id: "a".into(),
            ..Default::default()
        },
        cache.path().join("a"),
    );
    w1.wait_welcomed();
    let open = |c: &RawPeer, rid: u64| {
        c.env(rid, 0, EnvOp::EnvOpen, open_msg(2));
        match c.reply_frames_to(rid, T) {
            (Body::EnvReply(r), frames) => {
                assert_eq!(r.op, EnvOp::EnvOpen as i32);
                assert!(r.error.is_none(), "{:?}", r.error);
                let o = paddock_proto::EnvOpened::decode(frames[0].as_slice()).unwrap();
                assert_eq!(o.num_envs, 2);
                r.session_id
            }
            other => panic!("expected env_reply, got {other:?}"),
        }
    };
    let s1 = open(&c1, 2);
    let w2 = TestWorker::spawn(
        &broker.backend,
        WorkerOpts {
            id: "b".into(),
            silent_after: Some(0),
            ..Default::default()
        },
        cache.path().join("b"),
    );
    w2.wait_welcomed();
    let s2 = open(&c2, 2);
    assert_ne!(s1, s2);
    assert!(
        s1 > 1 << 20 && s2 > 1 << 20,
        "session ids are drawn, not counted: {s1} {s2}"
    );
    // both clients use request id 5; each gets its own echo back
    for (c, s, v) in [(&c1, s1, 1u8), (&c2, s2, 2u8)] {
        c.env(5, s, EnvOp::EnvStep, step(vec![v; 16]));
    }
    assert_eq!(echoed(c1.reply_frames_to(5, T), s1), vec![1u8; 16]);
    // the worker saw the broker's session id and the client's request id: nothing was
    // rewritten on the way
    let seen = w1.stats.env_requests.lock().unwrap().clone();
    assert!(
        seen.contains(&(5, s1, EnvOp::EnvStep as i32)),
        "{seen:?} lacks the step of session {s1}"
    );
    // c2's worker went silent: declared dead, its session is rebuilt on w1 by replay
    // and the pending step answered from there
    assert_eq!(
        echoed(c2.reply_frames_to(5, T), s2),
        vec![2u8; 16],
        "the session keeps its id after the replay"
    );
    let st = status(&c1, 9);
    assert_eq!((st.sessions_replayed, st.sessions_lost), (1, 0));
    assert_eq!(st.env_sessions, 2);
    // a client cannot drive another client's session
    c2.env(7, s1, EnvOp::EnvStep, step(vec![]));
    assert_eq!(code(&env_error(c2.reply_to(7, T))), ErrorCode::NotFound);
    c1.env(8, s1, EnvOp::EnvClose, None);
    match c1.reply_to(8, T) {
        Body::EnvReply(r) => {
            assert_eq!((r.session_id, r.op), (s1, EnvOp::EnvClose as i32));
            assert!(r.error.is_none());
        }
        other => panic!("expected env_reply, got {other:?}"),
    }
    assert_eq!(status(&c1, 10).env_sessions, 1);
    // the last worker goes: no other worker within the wait, so the session is lost
    drop(w1);
    c2.env(11, s2, EnvOp::EnvStep, step(vec![3; 16]));
    let e = env_error(c2.reply_to(11, T));
    assert!(
        e.message.contains(&format!("env session {s2} was lost")),
        "{e:?}"
    );
    c2.env(12, s2, EnvOp::EnvStep, step(vec![]));
    let e = env_error(c2.reply_to(12, T));
    assert_eq!(code(&e), ErrorCode::NotFound);
    assert!(e.message.contains("no other worker"), "{e:?}");
    let st = status(&c1, 13);
    assert_eq!(
        (st.sessions_replayed, st.sessions_lost, st.env_sessions),
        (1, 1, 0)
    );
}

#[test]
fn fifty_concurrent_clients_get_their_own_replies() {
    let dir = tempfile::tempdir().unwrap();
    let broker = TestBroker::start(dir.path().into(), |_| {});
    let map = put_lakeside(&RawPeer::connect(&broker.frontend));
    let cache = tempfile::tempdir().unwrap();
    let _w = TestWorker::spawn(
        &broker.backend,
        WorkerOpts {
            capacity: 4,
            ..Default::default()
        },
        cache.path().into(),
    );
    let expected: Vec<_> = (0..5u64)
        .map(|k| run_locally(&batch(&map, 1, k, 0.3)))
        .collect();
    let threads: Vec<_> = (0..50u64)
        .map(|i| {
            let endpoint = broker.frontend.clone();
            let map = map.clone();
            let expected = expected[(i % 5) as usize].clone();
            std::thread::spawn(move || {
                let c = RawPeer::connect(&endpoint);
                // every client uses the same request ids
                c.send(1, Body::RolloutBatch(batch(&map, 1, i % 5, 0.3)));
                c.send(2, Body::StatusRequest(paddock_proto::StatusRequest {}));
                let mut got_batch = None;
                let mut got_status = false;
                while got_batch.is_none() || !got_status {
                    match c.recv_frames(T) {
                        (1, Body::RolloutResult(_), frames) => {
                            got_batch =
                                Some(frames.iter().map(|f| decode_outcome(f)).collect::<Vec<_>>())
                        }
                        (1, Body::RolloutProgress(_), _) => {}
                        (2, Body::BrokerStatus(_), _) => got_status = true,
                        other => panic!("client {i}: unexpected {other:?}"),
                    }
                }
                assert_eq!(got_batch.unwrap(), expected, "client {i}");
            })
        })
        .collect();
    for t in threads {
        t.join().unwrap();
    }
}

#[test]
fn the_broker_can_run_on_another_thread() {
    fn is_send<T: Send>() {}
    is_send::<paddock_broker::Broker>();
}

#[test]
fn a_worker_saying_bye_has_its_tasks_requeued_at_once() {
    let dir = tempfile::tempdir().unwrap();
    // a long liveness: only the bye can free the tasks in time
    let broker = TestBroker::start(dir.path().into(), |c| {
        c.liveness.interval = Duration::from_secs(60);
    });
    let c = RawPeer::connect(&broker.frontend);
    let map = put_lakeside(&c);
    let leaving = RawPeer::connect(&broker.backend);
    leaving.send(
        1,
        Body::WorkerHello(paddock_proto::WorkerHello {
            worker_id: "leaving".into(),
            capacity: 2,
            ..Default::default()
        }),
    );
    assert!(matches!(leaving.reply_to(1, T), Body::WorkerWelcome(_)));
    let b = batch(&map, 4, 9, 0.5);
    c.send(2, Body::RolloutBatch(b.clone()));
    for _ in 0..2 {
        assert!(matches!(leaving.recv(T).1, Body::TaskAssign(_)));
    }
    leaving.send(
        3,
        Body::Bye(paddock_proto::Bye {
            reason: "shutting down".into(),
        }),
    );
    let cache = tempfile::tempdir().unwrap();
    let stayer = TestWorker::spawn(&broker.backend, WorkerOpts::default(), cache.path().into());
    let t0 = Instant::now();
    assert_eq!(c.outcomes(2, T), run_locally(&b));
    assert!(t0.elapsed() < Duration::from_secs(20));
    assert_eq!(
        stayer
            .stats
            .received
            .load(std::sync::atomic::Ordering::Relaxed),
        4
    );
    // a message from the departed worker is answered with "hello again"
    leaving.send(
        4,
        Body::Heartbeat(paddock_proto::Heartbeat { in_flight: 0 }),
    );
    let e = expect_error(leaving.reply_to(4, T));
    assert_eq!(
        (code(&e), e.field.as_str()),
        (ErrorCode::NotFound, "worker_id")
    );
}
