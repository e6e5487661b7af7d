//! A broker on an open port, tried as hostile clients and rogue workers would: real
//! `paddock broker` and `paddock worker` processes on loopback, clients that hold too
//! much, leave without a word, forge results, reuse another client's connection, reach
//! for other clients' jobs, or flood the broker with refusals. Each test names the bound
//! or rule it checks (docs/security.md has the table); the broker keeps serving
//! everyone else throughout.

use std::io::Write;
use std::net::TcpStream;
use std::time::{Duration, Instant};

use paddock_broker::client::{Client, ClientError};
use paddock_e2e::{Cluster, paddock, serial};
use paddock_proto::{Body, EnvOp, ErrorCode, MapBundle, MapRef};
use paddock_rollout::{EpisodeTask, Executor, LocalExecutor, Scenario, task_seed};
use paddock_wire::{batch_to_proto, local_map, map_ref, outcome_from_bytes};
use prost::Message;

const T: Duration = Duration::from_secs(20);

fn bundle() -> MapBundle {
    local_map(&paddock_sim::circuit::Circuits::new(), "lakeside").unwrap()
}

fn lakeside() -> MapRef {
    map_ref(&bundle())
}

fn tasks(n: usize, time_limit: f64) -> Vec<EpisodeTask> {
    let mut s = Scenario::single("pure-pursuit").unwrap();
    s.time_limit = time_limit;
    let s = std::sync::Arc::new(s);
    (0..n)
        .map(|k| EpisodeTask {
            scenario: s.clone(),
            seed: task_seed(17, k as u64),
            record: None,
        })
        .collect()
}

/// A client with its own client token (`who` picks one of 256 distinct tokens).
fn client(c: &Cluster, who: u8) -> Client {
    let mut cl = Client::connect(&c.front).unwrap();
    cl.timeout = T;
    cl.token = vec![who; 32];
    cl
}

/// The error code of a refused request.
fn code(e: &ClientError) -> Option<ErrorCode> {
    e.code()
}

fn status(c: &Cluster) -> paddock_proto::BrokerStatus {
    let mut cl = client(c, 0);
    match cl.request(Body::StatusRequest(paddock_proto::StatusRequest {})) {
        Ok(Body::BrokerStatus(s)) => s,
        other => panic!("status: {other:?}"),
    }
}

fn rss_kib(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).expect("proc status");
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .expect("VmRSS")
}

fn open_payload() -> Vec<u8> {
    paddock_proto::EnvOpen {
        map: Some(lakeside()),
        num_envs: 1,
        seed: 3,
        lidar: Some(paddock_proto::Lidar {
            num_beams: 30,
            fov: 4.7,
            max_range: 30.0,
            ..Default::default()
        }),
        laps: 1,
        time_limit: 30.0,
        frame_skip: 1,
        ..Default::default()
    }
    .encode_to_vec()
}

fn open(cl: &mut Client) -> Result<u64, ClientError> {
    cl.env(0, EnvOp::EnvOpen, Some(open_payload()))
        .map(|(r, _)| r.session_id)
}

fn reset(cl: &mut Client, sid: u64) -> Result<(), ClientError> {
    let r = paddock_proto::EnvReset {
        seeds: vec![1],
        ..Default::default()
    };
    cl.env(sid, EnvOp::EnvReset, Some(r.encode_to_vec()))
        .map(|_| ())
}

#[test]
fn sessions_are_bounded_per_client_and_in_total_and_idle_ones_close() {
    let _serial = serial();
    let c = Cluster::start_with(
        1,
        1,
        &[
            "--sessions-per-client",
            "2",
            "--sessions-total",
            "3",
            "--session-idle-s",
            "2",
        ],
    );
    let mut a = client(&c, 1);
    let a1 = open(&mut a).unwrap();
    let a2 = open(&mut a).unwrap();
    let e = open(&mut a).unwrap_err();
    assert_eq!(code(&e), Some(ErrorCode::Busy), "{e}");
    assert!(e.to_string().contains("limit per client is 2"), "{e}");
    // the same client on a second connection is the same client: same bound, and its
    // sessions answer there
    let mut a_again = client(&c, 1);
    assert_eq!(
        code(&open(&mut a_again).unwrap_err()),
        Some(ErrorCode::Busy)
    );
    reset(&mut a_again, a2).unwrap();
    // another client gets the last place of the total
    let mut b = client(&c, 2);
    let b1 = open(&mut b).unwrap();
    let e = open(&mut b).unwrap_err();
    assert!(e.to_string().contains("--sessions-total"), "{e}");
    // another client cannot reach a's session
    let e = reset(&mut b, a1).unwrap_err();
    assert_eq!(code(&e), Some(ErrorCode::NotFound), "{e}");
    // nobody sends anything for longer than the idle limit: every session closes
    std::thread::sleep(Duration::from_millis(3500));
    let e = reset(&mut a, a1).unwrap_err();
    assert!(e.to_string().contains("without a request"), "{e}");
    assert_eq!(status(&c).env_sessions, 0);
    // and the places are free again
    open(&mut b).unwrap();
    let _ = b1;
}

#[test]
fn unfinished_tasks_count_per_client_not_per_connection_and_leave_with_the_client() {
    let _serial = serial();
    // no workers: everything stays queued
    let c = Cluster::start_with(0, 1, &["--tasks-per-client", "10"]);
    let ts = tasks(4, 1.0);
    let b = bundle();
    let batch = || batch_to_proto(&ts, |_| map_ref(&b), false);
    let mut sockets: Vec<Client> = (0..5).map(|_| client(&c, 7)).collect();
    let mut refused = 0;
    for s in &mut sockets {
        s.send(Body::RolloutBatch(batch())).unwrap();
        // a refused batch gets BUSY; a queued one the progress the broker sends every
        // second while it waits
        match s.recv(T).expect("a refusal or the batch's progress").body {
            Body::Error(e) => {
                assert_eq!(e.code, ErrorCode::Busy as i32, "{e:?}");
                refused += 1;
            }
            Body::RolloutProgress(p) => assert_eq!((p.done, p.total), (0, 4)),
            other => panic!("unexpected {other:?}"),
        }
    }
    assert_eq!(refused, 3, "10 tasks per client: two batches of 4 fit");
    assert_eq!(status(&c).queue_depth, 8);
    // another client still has its own room
    let mut other = client(&c, 8);
    other.send(Body::RolloutBatch(batch())).unwrap();
    assert!(matches!(
        other.recv(T).expect("the batch's progress").body,
        Body::RolloutProgress(_)
    ));
    assert_eq!(status(&c).queue_depth, 12);
    // clients that leave take their queued tasks with them
    drop(sockets);
    drop(other);
    let t0 = Instant::now();
    while status(&c).queue_depth > 0 {
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "queued tasks of departed clients stay queued"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
}

/// A raw DEALER socket with its own routing id.
fn raw_client(ctx: &zmq::Context, front: &str, routing_id: &[u8]) -> zmq::Socket {
    let s = ctx.socket(zmq::DEALER).unwrap();
    s.set_identity(routing_id).unwrap();
    s.set_linger(0).unwrap();
    s.set_rcvtimeo(T.as_millis() as i32).unwrap();
    s.connect(front).unwrap();
    s
}

fn raw_env(s: &zmq::Socket, token: &[u8], sid: u64, op: EnvOp, payload: Vec<u8>) -> Body {
    let header = paddock_proto::encode_with_token(
        9,
        token.to_vec(),
        Body::EnvRequest(paddock_proto::EnvRequest {
            session_id: sid,
            op: op as i32,
        }),
    );
    s.send_multipart([header, payload], 0).unwrap();
    let frames = s.recv_multipart(0).expect("a reply");
    paddock_proto::decode(&frames[0]).unwrap().1
}

#[test]
fn a_peer_reusing_a_departed_clients_routing_id_does_not_get_its_session() {
    let _serial = serial();
    let c = Cluster::start(1, 1);
    let ctx = zmq::Context::new();
    let alice = raw_client(&ctx, &c.front, b"conn-1");
    let Body::EnvReply(opened) = raw_env(&alice, &[1; 32], 0, EnvOp::EnvOpen, open_payload())
    else {
        panic!("no session");
    };
    assert!(opened.error.is_none(), "{opened:?}");
    let sid = opened.session_id;
    drop(alice);
    std::thread::sleep(Duration::from_millis(500));
    // mallory takes the routing id alice had, and knows the session id
    let mallory = raw_client(&ctx, &c.front, b"conn-1");
    let reset = paddock_proto::EnvReset {
        seeds: vec![1],
        ..Default::default()
    };
    match raw_env(
        &mallory,
        &[2; 32],
        sid,
        EnvOp::EnvReset,
        reset.encode_to_vec(),
    ) {
        Body::Error(e) => assert_eq!(e.code, ErrorCode::NotFound as i32, "{e:?}"),
        other => panic!("mallory reached alice's session: {other:?}"),
    }
    // alice, back on a new connection, still has it
    let alice = raw_client(&ctx, &c.front, b"conn-2");
    match raw_env(
        &alice,
        &[1; 32],
        sid,
        EnvOp::EnvReset,
        reset.encode_to_vec(),
    ) {
        Body::EnvReply(r) => assert!(r.error.is_none(), "{r:?}"),
        other => panic!("alice lost her session: {other:?}"),
    }
}

#[test]
fn jobs_belong_to_their_client_have_unguessable_ids_bounded_names_and_can_be_deleted() {
    let _serial = serial();
    let c = Cluster::start_with(0, 1, &["--jobs-per-client", "2"]);
    let b = bundle();
    let submit = |name: String| {
        Body::JobSubmit(paddock_proto::JobSubmit {
            name,
            spec: Some(paddock_proto::job_submit::Spec::Rollouts(batch_to_proto(
                &tasks(2, 1.0),
                |_| map_ref(&b),
                false,
            ))),
        })
    };
    let mut a = client(&c, 1);
    let Ok(Body::JobInfo(job)) = a.request(submit("mine".into())) else {
        panic!("submit refused");
    };
    let id = job.job_id.clone();
    assert!(id.starts_with("job-") && id.len() == 36, "{id}");
    let list = |cl: &mut Client| match cl.request(Body::JobList(paddock_proto::JobListRequest {})) {
        Ok(Body::JobListing(l)) => l.jobs.into_iter().map(|j| j.job_id).collect::<Vec<_>>(),
        other => panic!("list: {other:?}"),
    };
    assert_eq!(list(&mut a), vec![id.clone()]);
    // another client neither sees nor reaches it
    let mut b_client = client(&c, 2);
    assert!(list(&mut b_client).is_empty());
    let asks = [
        Body::JobStatus(paddock_proto::JobStatusRequest { job_id: id.clone() }),
        Body::JobCancel(paddock_proto::JobCancel { job_id: id.clone() }),
        Body::JobResultRequest(paddock_proto::JobResultRequest { job_id: id.clone() }),
        Body::JobWatch(paddock_proto::JobWatch { job_id: id.clone() }),
        Body::JobDelete(paddock_proto::JobDelete { job_id: id.clone() }),
    ];
    for ask in asks {
        let e = b_client.request(ask).unwrap_err();
        assert_eq!(code(&e), Some(ErrorCode::NotFound), "{e}");
    }
    // a 30 MiB name is refused, and the listing stays small and quick
    let e = a.request(submit("x".repeat(30 << 20))).unwrap_err();
    assert!(
        e.to_string().contains("job_submit.name has 31457280 bytes"),
        "{e}"
    );
    assert_eq!(list(&mut a).len(), 1);
    // jobs stored per client are bounded
    assert!(matches!(
        a.request(submit("second".into())),
        Ok(Body::JobInfo(_))
    ));
    let e = a.request(submit("third".into())).unwrap_err();
    assert!(e.to_string().contains("paddock jobs delete"), "{e}");
    // the owner deletes its job (queued: cancelled first), through the CLI too
    let out = paddock(&["jobs", "delete", &id, "--endpoint", &c.front, "--json"]);
    // the CLI has this user's token, not client 1's: to it the job does not exist
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("no such job"),
        "{out:?}"
    );
    match a.request(Body::JobDelete(paddock_proto::JobDelete {
        job_id: id.clone(),
    })) {
        Ok(Body::JobDeleted(d)) => assert_eq!(d.job_id, id),
        other => panic!("delete: {other:?}"),
    }
    assert_eq!(list(&mut a).len(), 1);
    let e = a
        .request(Body::JobStatus(paddock_proto::JobStatusRequest {
            job_id: id,
        }))
        .unwrap_err();
    assert_eq!(code(&e), Some(ErrorCode::NotFound));
    assert!(matches!(
        a.request(submit("third".into())),
        Ok(Body::JobInfo(_))
    ));
}

#[test]
fn a_batch_whose_results_cannot_fit_a_message_is_refused_before_any_work() {
    let _serial = serial();
    let c = Cluster::start(1, 1);
    let mut cl = client(&c, 1);
    let b = bundle();
    // 600 episodes that run their whole 60 s (100 laps to go) with the trajectory of
    // every step: ~170 MiB of results
    let mut s = Scenario::single("pure-pursuit").unwrap();
    s.time_limit = 60.0;
    s.laps = 100;
    let s = std::sync::Arc::new(s);
    let ts: Vec<EpisodeTask> = (0..600)
        .map(|k| EpisodeTask {
            scenario: s.clone(),
            seed: task_seed(17, k),
            record: Some(1),
        })
        .collect();
    let e = cl
        .request(Body::RolloutBatch(batch_to_proto(
            &ts,
            |_| map_ref(&b),
            false,
        )))
        .unwrap_err();
    assert_eq!(code(&e), Some(ErrorCode::TooLarge), "{e}");
    let text = e.to_string();
    assert!(text.contains("split the batch into at least"), "{text}");
    std::thread::sleep(Duration::from_millis(300));
    let s = status(&c);
    assert_eq!((s.tasks_done, s.queue_depth, s.tasks_in_flight), (0, 0, 0));
}

/// The envelope and payload frames of the next message on a worker-side socket.
fn next_message(s: &zmq::Socket, wait: Duration) -> Option<(u64, Body)> {
    if s.poll(zmq::POLLIN, wait.as_millis() as i64).ok()? == 0 {
        return None;
    }
    let frames = s.recv_multipart(0).ok()?;
    paddock_proto::decode(&frames[0]).ok()
}

#[test]
fn rogue_workers_neither_hold_tasks_forever_nor_slip_in_results() {
    let _serial = serial();
    let c = Cluster::start_with(
        0,
        1,
        &["--task-time-base-s", "1.5", "--task-time-per-sim-s", "0"],
    );
    let ctx = zmq::Context::new();
    // a rogue announces a huge capacity and answers heartbeats, but never its tasks
    let rogue = ctx.socket(zmq::DEALER).unwrap();
    rogue.set_linger(0).unwrap();
    rogue.connect(&c.back).unwrap();
    let hello = paddock_proto::WorkerHello {
        worker_id: "rogue".into(),
        capacity: 4096,
        ..Default::default()
    };
    rogue
        .send(paddock_proto::encode(1, Body::WorkerHello(hello)), 0)
        .unwrap();
    assert!(matches!(
        next_message(&rogue, T),
        Some((_, Body::WorkerWelcome(_)))
    ));
    let ts = tasks(3, 2.0);
    let b = bundle();
    let mut cl = client(&c, 1);
    let rid = cl
        .send(Body::RolloutBatch(batch_to_proto(
            &ts,
            |_| map_ref(&b),
            false,
        )))
        .unwrap();
    // a socket that never registered forges results for the rogue's tasks
    let thief = ctx.socket(zmq::DEALER).unwrap();
    thief.set_linger(0).unwrap();
    thief.connect(&c.back).unwrap();
    let forged = paddock_proto::TaskOutcome {
        outcome: Some(paddock_proto::task_outcome::Outcome::Episode(
            paddock_proto::EpisodeResult {
                seed: 1,
                steps: 1,
                ..Default::default()
            },
        )),
    }
    .encode_to_vec();
    let mut assigned = Vec::new();
    let mut bye = None;
    let t0 = Instant::now();
    while bye.is_none() && t0.elapsed() < Duration::from_secs(15) {
        match next_message(&rogue, Duration::from_millis(200)) {
            Some((_, Body::TaskAssign(a))) => {
                let header = paddock_proto::encode(
                    2,
                    Body::TaskResult(paddock_proto::TaskResult { task_id: a.task_id }),
                );
                thief.send_multipart([header, forged.clone()], 0).unwrap();
                assigned.push((a.task_id, Instant::now()));
            }
            Some((_, Body::Bye(b))) => bye = Some((b.reason, Instant::now())),
            Some((_, Body::Heartbeat(_))) | None => {
                let beat = paddock_proto::encode(
                    0,
                    Body::Heartbeat(paddock_proto::Heartbeat {
                        in_flight: assigned.len() as u32,
                    }),
                );
                rogue.send(beat, 0).unwrap();
            }
            Some(_) => {}
        }
    }
    assert_eq!(assigned.len(), 3, "the rogue got every task");
    let (reason, at) = bye.expect("the rogue was never dropped");
    assert!(reason.contains("deadline"), "{reason}");
    let held = at - assigned[0].1;
    assert!(
        held < Duration::from_secs(5),
        "dropped {held:?} after the assignment"
    );
    // an honest worker then runs the tasks; the forged results never counted
    let mut c = c;
    c.add_worker(1);
    let got = loop {
        let r = cl
            .recv(Duration::from_secs(60))
            .expect("the batch's result");
        assert_eq!(r.request_id, rid);
        match r.body {
            Body::RolloutResult(_) => break r.payload,
            Body::RolloutProgress(_) => continue,
            other => panic!("unexpected {other:?}"),
        }
    };
    let local = LocalExecutor::new(1, paddock_sim::circuit::Circuits::new())
        .unwrap()
        .run_batch(&ts, &|_| {});
    for (g, l) in got.iter().zip(local) {
        let g = outcome_from_bytes(g).unwrap();
        assert_eq!(format!("{g:?}"), format!("{:?}", l.unwrap()));
    }
}

/// A raw TCP peer speaking ZMTP 3.0 (NULL mechanism) as a DEALER, which then announces
/// one frame of `size` bytes and sends its first bytes.
fn announce_frame(port: u16, size: u64) -> Option<TcpStream> {
    let mut s = TcpStream::connect(("127.0.0.1", port)).ok()?;
    let mut greeting = vec![0xFF, 0, 0, 0, 0, 0, 0, 0, 1, 0x7F, 3, 0];
    let mut mech = b"NULL".to_vec();
    mech.resize(20, 0);
    greeting.extend(mech);
    greeting.push(0); // as-server
    greeting.resize(64, 0);
    s.write_all(&greeting).ok()?;
    // READY command: Socket-Type DEALER
    let mut body = vec![5];
    body.extend(b"READY");
    body.push(11);
    body.extend(b"Socket-Type");
    body.extend(6u32.to_be_bytes());
    body.extend(b"DEALER");
    let mut cmd = vec![0x04, body.len() as u8];
    cmd.extend(body);
    s.write_all(&cmd).ok()?;
    // a long message frame of `size` bytes, and 1 MiB of it
    let mut frame = vec![0x02];
    frame.extend(size.to_be_bytes());
    s.write_all(&frame).ok()?;
    let chunk = vec![0u8; 1 << 20];
    let _ = s.write_all(&chunk);
    Some(s)
}

#[test]
fn oversized_frames_are_refused_at_the_socket_and_refusals_are_logged_briefly() {
    let _serial = serial();
    let c = Cluster::start_with(0, 1, &["--refusal-log-rate", "5"]);
    let pid = c.broker.as_ref().unwrap().pid();
    let port: u16 = c.front.rsplit(':').next().unwrap().parse().unwrap();
    let before = rss_kib(pid);
    // five peers announce 1 GiB frames and keep streaming
    let peers: Vec<TcpStream> = (0..5)
        .filter_map(|_| announce_frame(port, 1 << 30))
        .collect();
    std::thread::sleep(Duration::from_millis(1500));
    let after = rss_kib(pid);
    assert!(
        after < before + 64 * 1024,
        "RSS {before} -> {after} KiB with five announced 1 GiB frames"
    );
    drop(peers);
    // a flood of refusals with long fields: counted, logged at a bounded rate, each
    // line cut short
    let mut cl = client(&c, 1);
    let long_id = "j".repeat(100_000);
    for _ in 0..300 {
        let _ = cl.request(Body::JobStatus(paddock_proto::JobStatusRequest {
            job_id: long_id.clone(),
        }));
    }
    std::thread::sleep(Duration::from_millis(300));
    let s = status(&c);
    assert!(s.errors.get("NOT_FOUND").copied().unwrap_or(0) >= 300);
    let log = c.broker.as_ref().unwrap().log();
    let refused: Vec<&str> = log
        .lines()
        .filter(|l| l.contains("request refused"))
        .collect();
    assert!(
        !refused.is_empty() && refused.len() < 150,
        "{} refusal lines logged for 300 refusals",
        refused.len()
    );
    let longest = log.lines().map(str::len).max().unwrap_or(0);
    assert!(longest < 2000, "a log line of {longest} bytes");
    assert!(log.contains("refusals_not_logged"), "{log}");
}

/// The broker's RSS stays flat under sustained bad input and under clients that open
/// sessions and walk away (bounded in time: about 20 s).
#[test]
fn soak_rss_stays_flat_under_bad_input_and_abandoned_sessions() {
    let _serial = serial();
    let c = Cluster::start_with(
        1,
        1,
        &[
            "--session-idle-s",
            "1",
            "--sessions-per-client",
            "4",
            "--refusal-log-rate",
            "5",
        ],
    );
    let pid = c.broker.as_ref().unwrap().pid();
    let ctx = zmq::Context::new();
    let opened = std::cell::Cell::new(0usize);
    let round = |k: usize| {
        // clients that open sessions and vanish
        for j in 0..4 {
            let mut cl = client(&c, (10 + (k * 4 + j) % 200) as u8);
            if open(&mut cl).is_ok() {
                opened.set(opened.get() + 1);
            }
        }
        // and garbage of every kind
        let s = ctx.socket(zmq::DEALER).unwrap();
        s.set_linger(0).unwrap();
        s.connect(&c.front).unwrap();
        for i in 0..200u32 {
            let junk: Vec<u8> = (0..(i * 37 % 5000)).map(|x| (x * 131 + i) as u8).collect();
            let _ = s.send(junk, zmq::DONTWAIT);
        }
    };
    for k in 0..6 {
        round(k);
    }
    std::thread::sleep(Duration::from_millis(2500));
    let base = rss_kib(pid);
    let t0 = Instant::now();
    let mut k = 6;
    while t0.elapsed() < Duration::from_secs(15) {
        round(k);
        k += 1;
    }
    std::thread::sleep(Duration::from_millis(2500));
    let end = rss_kib(pid);
    let s = status(&c);
    assert!(
        end < base + 16 * 1024,
        "RSS grew {base} -> {end} KiB over {k} rounds"
    );
    assert!(
        s.env_sessions <= 16,
        "{} sessions left open",
        s.env_sessions
    );
    let opened = opened.get();
    eprintln!(
        "soak: broker RSS {base} -> {end} KiB over {k} rounds; {opened} sessions opened and abandoned; {} refusals",
        s.errors.values().sum::<u64>()
    );
    assert!(
        opened >= 2 * k,
        "only {opened} of {} sessions opened",
        4 * k
    );
}

/// A client connected with the CURVE key pair in `key` (a `paddock keys` file).
fn keyed_client(front: &str, key: &std::path::Path, broker_pub: &std::path::Path) -> Client {
    use paddock_broker::curve;
    let curve = curve::Curve::Client {
        keys: curve::KeyPair::read(key).expect("key file"),
        server_public: curve::read_public(broker_pub).expect("broker.pub"),
    };
    let mut c = Client::connect_with(front, &curve).expect("a client socket");
    c.timeout = T;
    c
}

#[test]
fn with_curve_jobs_belong_to_the_key_and_an_admin_key_sees_all() {
    let _serial = serial();
    let dir = tempfile::tempdir().unwrap();
    let keys = dir.path().join("keys");
    let k = |p: &str| keys.join(p).display().to_string();
    let out = paddock(&["keys", "generate", "--out", &k("")]);
    assert!(out.status.success(), "{out:?}");
    for name in ["bob", "admin"] {
        let out = paddock(&[
            "keys",
            "generate",
            "--role",
            "client",
            "--name",
            name,
            "--out",
            &k(""),
        ]);
        assert!(out.status.success(), "{out:?}");
    }
    let broker_pub = keys.join("broker.pub");
    let curve = paddock_broker::curve::Curve::Client {
        keys: paddock_broker::curve::KeyPair::read(&keys.join("client.key")).unwrap(),
        server_public: paddock_broker::curve::read_public(&broker_pub).unwrap(),
    };
    let mut c = Cluster::start_secured(
        0,
        1,
        &[
            "--secret-key",
            &k("broker.key"),
            "--client-keys",
            &k("clients"),
            "--worker-keys",
            &k("workers"),
            "--admin-key",
            &k("clients/admin.pub"),
        ],
        curve,
    );
    let mut alice = keyed_client(&c.front, &keys.join("client.key"), &broker_pub);
    let mut bob = keyed_client(&c.front, &keys.join("bob.key"), &broker_pub);
    let mut admin = keyed_client(&c.front, &keys.join("admin.key"), &broker_pub);
    // the same client token on every connection: CURVE keys decide, not tokens
    for cl in [&mut alice, &mut bob, &mut admin] {
        cl.token = vec![5; 32];
    }
    let b = bundle();
    let submit = Body::JobSubmit(paddock_proto::JobSubmit {
        name: "alice's".into(),
        spec: Some(paddock_proto::job_submit::Spec::Rollouts(batch_to_proto(
            &tasks(1, 1.0),
            |_| map_ref(&b),
            false,
        ))),
    });
    let Ok(Body::JobInfo(job)) = alice.request(submit) else {
        panic!("alice's submission was refused: {}", c.broker_report());
    };
    let list = |cl: &mut Client| match cl.request(Body::JobList(paddock_proto::JobListRequest {})) {
        Ok(Body::JobListing(l)) => l.jobs.into_iter().map(|j| j.job_id).collect::<Vec<_>>(),
        other => panic!("list: {other:?}"),
    };
    assert_eq!(list(&mut alice), vec![job.job_id.clone()]);
    assert!(list(&mut bob).is_empty(), "bob sees alice's job");
    let e = bob
        .request(Body::JobCancel(paddock_proto::JobCancel {
            job_id: job.job_id.clone(),
        }))
        .unwrap_err();
    assert_eq!(code(&e), Some(ErrorCode::NotFound), "{e}");
    assert_eq!(list(&mut admin), vec![job.job_id.clone()]);
    match admin.request(Body::JobCancel(paddock_proto::JobCancel {
        job_id: job.job_id.clone(),
    })) {
        Ok(Body::JobInfo(i)) => assert_eq!(i.state, paddock_proto::JobState::CancelledJob as i32),
        other => panic!("the admin could not cancel: {other:?}"),
    }
    c.broker.take();
}
