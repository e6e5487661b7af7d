//! Broker capacity (a bench binary, not a timed test): one broker thread routes for many
//! in-process fake clients and workers (all on `inproc://` in one ZeroMQ context, so the
//! broker thread is the only real work), and the bench reports what it got through:
//! env steps/s and tasks/s routed, payload bytes/s forwarded, and the broker thread's CPU
//! time per routed message (from `/proc/self/task/<tid>/schedstat`, so other load on the
//! machine does not count).
//!
//! ```text
//! cargo bench -p paddock-broker --bench capacity -- [seconds per case]
//! ```
//!
//! Cases: env sessions with 1-env and 64-env observations (1080-beam scans, and 64 envs
//! with 1-beam scans: the same messages with 1/1000 of the bytes, so a difference between
//! the two 64-env lines is work per byte), each client stepping its own session in a
//! loop; rollout batches of small tasks answered at once by the fake workers. A routed message is one request or one reply passing the broker
//! (an env step is two: the step and its observation; a task is two: the assignment and
//! its result).

#[path = "observation.rs"]
mod observation;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use paddock_broker::{Broker, BrokerConfig, RouteOnly};
use paddock_proto::{Body, EnvOp, decode, encode, pack_f32};
use prost::Message;

const BEAMS: usize = 1080;
/// The scan length of a session whose open asks for this many beams (`lidar.num_beams`;
/// absent: [`BEAMS`]).
fn beams_of(o: &paddock_proto::EnvOpen) -> usize {
    o.lidar.as_ref().map_or(BEAMS, |l| l.num_beams as usize)
}
const FRONT: &str = "inproc://capacity-front";
const BACK: &str = "inproc://capacity-back";
const CLIENTS: usize = 8;
const WORKERS: usize = 4;

/// The broker thread's CPU time so far, nanoseconds.
fn cpu_ns(tid: &str) -> u64 {
    std::fs::read_to_string(format!("/proc/self/task/{tid}/schedstat"))
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse().ok())
        .unwrap_or(0)
}

fn send_frames(s: &zmq::Socket, frames: Vec<Vec<u8>>) {
    let _ = s.send_multipart(frames, 0);
}

/// A worker that answers env steps with full-size observations and tasks with a small
/// episode result, at once.
fn fake_worker(
    ctx: zmq::Context,
    index: usize,
    stop: Arc<AtomicBool>,
) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let s = ctx.socket(zmq::DEALER).unwrap();
        s.set_linger(0).unwrap();
        s.connect(BACK).unwrap();
        let hello = paddock_proto::WorkerHello {
            worker_id: format!("fake-{index}"),
            capacity: 64,
            ..Default::default()
        };
        s.send(encode(1, Body::WorkerHello(hello)), 0).unwrap();
        let mut sessions: Vec<(u64, (usize, usize))> = Vec::new();
        // the frames of an observation by (envs, beams)
        let mut obs_cache: std::collections::HashMap<(usize, usize), Vec<Vec<u8>>> =
            Default::default();
        let outcome = paddock_proto::TaskOutcome {
            outcome: Some(paddock_proto::task_outcome::Outcome::Episode(
                paddock_proto::EpisodeResult {
                    seed: 1,
                    map: "lakeside".into(),
                    steps: 100,
                    time: 1.0,
                    ..Default::default()
                },
            )),
        }
        .encode_to_vec();
        while !stop.load(Ordering::Relaxed) {
            if s.poll(zmq::POLLIN, 20).unwrap() == 0 {
                continue;
            }
            let Ok(mut parts) = s.recv_multipart(0) else {
                continue;
            };
            let payload = parts.split_off(1);
            let Ok((rid, body)) = decode(&parts[0]) else {
                continue;
            };
            match body {
                Body::EnvRequest(r) if r.op == EnvOp::EnvOpen as i32 => {
                    let o = paddock_proto::EnvOpen::decode(payload[0].as_slice()).unwrap();
                    sessions.push((r.session_id, (o.num_envs as usize, beams_of(&o))));
                    let opened = paddock_proto::EnvOpened {
                        num_envs: o.num_envs,
                        num_beams: beams_of(&o) as u32,
                        num_agents: 1,
                        ..Default::default()
                    };
                    let header = paddock_proto::EnvReply {
                        session_id: r.session_id,
                        op: r.op,
                        ..Default::default()
                    };
                    send_frames(
                        &s,
                        vec![encode(rid, Body::EnvReply(header)), opened.encode_to_vec()],
                    );
                }
                Body::EnvRequest(r) => {
                    let n = sessions
                        .iter()
                        .find(|(id, _)| *id == r.session_id)
                        .map_or((1, BEAMS), |(_, n)| *n);
                    let obs = obs_cache
                        .entry(n)
                        .or_insert_with(|| observation::observation(n.0, n.1))
                        .clone();
                    let header = paddock_proto::EnvReply {
                        session_id: r.session_id,
                        op: r.op,
                        fingerprint: 7,
                        ..Default::default()
                    };
                    let mut frames = vec![encode(rid, Body::EnvReply(header))];
                    frames.extend(obs);
                    send_frames(&s, frames);
                }
                Body::TaskAssign(t) => {
                    let header = encode(
                        rid,
                        Body::TaskResult(paddock_proto::TaskResult { task_id: t.task_id }),
                    );
                    send_frames(&s, vec![header, outcome.clone()]);
                }
                _ => {}
            }
        }
    })
}

struct Case {
    name: String,
    seconds: f64,
    units: u64,
    messages: u64,
    bytes: u64,
    cpu_ns: u64,
}

fn report(c: &Case, unit: &str) {
    println!(
        "{:<36} {:>10.0} {unit}/s  {:>8.1} MB/s forwarded  {:>6.2} us broker CPU per message  ({:.0} % of a core)",
        c.name,
        c.units as f64 / c.seconds,
        c.bytes as f64 / c.seconds / 1e6,
        c.cpu_ns as f64 / 1e3 / c.messages.max(1) as f64,
        100.0 * c.cpu_ns as f64 / 1e9 / c.seconds,
    );
}

fn env_case(ctx: &zmq::Context, tid: &str, num_envs: u32, beams: u32, seconds: f64) -> Case {
    let map = map_ref();
    let stop = Arc::new(AtomicBool::new(false));
    let steps = Arc::new(AtomicU64::new(0));
    let bytes = Arc::new(AtomicU64::new(0));
    let go = Arc::new(AtomicBool::new(false));
    let mut clients = Vec::new();
    for _ in 0..CLIENTS {
        let (ctx, map, stop, steps, bytes, go) = (
            ctx.clone(),
            map.clone(),
            stop.clone(),
            steps.clone(),
            bytes.clone(),
            go.clone(),
        );
        clients.push(std::thread::spawn(move || {
            let s = ctx.socket(zmq::DEALER).unwrap();
            s.set_linger(0).unwrap();
            s.connect(FRONT).unwrap();
            let mut rid = 0u64;
            // an env request and its reply header and size in bytes
            let mut request = |sid: u64, op: EnvOp, payload: Vec<u8>| -> (Body, usize) {
                rid += 1;
                let header = Body::EnvRequest(paddock_proto::EnvRequest {
                    session_id: sid,
                    op: op as i32,
                });
                s.send_multipart([encode(rid, header), payload], 0).unwrap();
                loop {
                    let parts = s.recv_multipart(0).unwrap();
                    let (id, b) = decode(&parts[0]).unwrap();
                    if id == rid {
                        return (b, parts.iter().map(Vec::len).sum());
                    }
                }
            };
            let session = loop {
                let open = paddock_proto::EnvOpen {
                    map: Some(map.clone()),
                    num_envs,
                    lidar: Some(paddock_proto::Lidar {
                        num_beams: beams,
                        ..Default::default()
                    }),
                    ..Default::default()
                };
                match request(0, EnvOp::EnvOpen, open.encode_to_vec()) {
                    (Body::EnvReply(r), _) if r.error.is_none() => break r.session_id,
                    _ => std::thread::sleep(Duration::from_millis(10)),
                }
            };
            let actions = pack_f32(&vec![0.1; 2 * num_envs as usize]);
            while !go.load(Ordering::Relaxed) {
                std::thread::yield_now();
            }
            while !stop.load(Ordering::Relaxed) {
                let step = paddock_proto::EnvStep {
                    actions: actions.clone(),
                    ..Default::default()
                };
                let (reply, size) = request(session, EnvOp::EnvStep, step.encode_to_vec());
                assert!(matches!(reply, Body::EnvReply(_)), "{reply:?}");
                steps.fetch_add(1, Ordering::Relaxed);
                bytes.fetch_add((size + actions.len()) as u64, Ordering::Relaxed);
            }
        }));
    }
    std::thread::sleep(Duration::from_millis(300));
    go.store(true, Ordering::Relaxed);
    std::thread::sleep(Duration::from_millis(200));
    let (s0, b0, c0, t0) = (
        steps.load(Ordering::Relaxed),
        bytes.load(Ordering::Relaxed),
        cpu_ns(tid),
        Instant::now(),
    );
    std::thread::sleep(Duration::from_secs_f64(seconds));
    let (s1, b1, c1, dt) = (
        steps.load(Ordering::Relaxed),
        bytes.load(Ordering::Relaxed),
        cpu_ns(tid),
        t0.elapsed().as_secs_f64(),
    );
    stop.store(true, Ordering::Relaxed);
    for c in clients {
        c.join().unwrap();
    }
    Case {
        name: format!("env step, {num_envs:>2} env(s) x {beams:>4} beams"),
        seconds: dt,
        units: s1 - s0,
        messages: 2 * (s1 - s0),
        bytes: b1 - b0,
        cpu_ns: c1 - c0,
    }
}

/// A map reference: nothing here loads maps (the broker does not decode the open, and
/// the fake workers ignore it).
fn map_ref() -> paddock_proto::MapRef {
    paddock_proto::MapRef {
        name: "lakeside".into(),
        hash: "0".repeat(64),
    }
}

fn task_case(ctx: &zmq::Context, tid: &str, seconds: f64) -> Case {
    let scenario = paddock_proto::Scenario {
        map: Some(map_ref()),
        agents: vec![paddock_proto::AgentSpec {
            driver: "pure-pursuit".into(),
            ..Default::default()
        }],
        laps: 1,
        time_limit: 1.0,
        ..Default::default()
    };
    const BATCH: usize = 1000;
    let batch = paddock_proto::RolloutBatch {
        scenarios: vec![scenario.encode_to_vec()],
        tasks: (0..BATCH as u64)
            .map(|seed| paddock_proto::RolloutTaskSpec {
                scenario: 0,
                seed,
                record_decimation: 0,
            })
            .collect(),
        progress: false,
    };
    let s = ctx.socket(zmq::DEALER).unwrap();
    s.set_linger(0).unwrap();
    s.connect(FRONT).unwrap();
    let frame = encode(1, Body::RolloutBatch(batch));
    let run = |s: &zmq::Socket| -> usize {
        s.send(&frame, 0).unwrap();
        let parts = s.recv_multipart(0).unwrap();
        let (_, body) = decode(&parts[0]).unwrap();
        assert!(matches!(body, Body::RolloutResult(_)), "{body:?}");
        parts.iter().map(Vec::len).sum()
    };
    run(&s);
    let (c0, t0) = (cpu_ns(tid), Instant::now());
    let (mut tasks, mut bytes) = (0u64, 0u64);
    while t0.elapsed().as_secs_f64() < seconds {
        bytes += (run(&s) + frame.len()) as u64;
        tasks += BATCH as u64;
    }
    let (c1, dt) = (cpu_ns(tid), t0.elapsed().as_secs_f64());
    Case {
        name: "rollout tasks, 1000/batch".into(),
        seconds: dt,
        units: tasks,
        messages: 2 * tasks,
        bytes,
        cpu_ns: c1 - c0,
    }
}

fn main() {
    let quick = !std::env::args().any(|a| a == "--bench");
    let seconds: f64 = std::env::args()
        .skip(1)
        .find(|a| !a.starts_with('-'))
        .and_then(|a| a.parse().ok())
        .unwrap_or(if quick { 0.2 } else { 3.0 });
    let dir = tempfile::tempdir().unwrap();
    let ctx = zmq::Context::new();
    let cfg = BrokerConfig::new(FRONT, BACK, dir.path());
    let mut broker = Broker::bind_in(cfg, RouteOnly, ctx.clone()).unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let (tx, rx) = std::sync::mpsc::channel();
    let s = stop.clone();
    let handle = std::thread::spawn(move || {
        let me = std::fs::read_link("/proc/thread-self").unwrap();
        tx.send(me.file_name().unwrap().to_string_lossy().into_owned())
            .unwrap();
        broker.run(&s).unwrap();
    });
    let tid = rx.recv().unwrap();
    let workers: Vec<_> = (0..WORKERS)
        .map(|i| fake_worker(ctx.clone(), i, stop.clone()))
        .collect();
    std::thread::sleep(Duration::from_millis(300));
    for round in 0..2 {
        println!("round {}", round + 1);
        report(&env_case(&ctx, &tid, 1, 1080, seconds), "env steps");
        report(&env_case(&ctx, &tid, 64, 1080, seconds), "env steps");
        report(&env_case(&ctx, &tid, 64, 1, seconds), "env steps");
        report(&task_case(&ctx, &tid, seconds), "tasks");
    }
    stop.store(true, Ordering::Relaxed);
    for w in workers {
        w.join().unwrap();
    }
    handle.join().unwrap();
}
