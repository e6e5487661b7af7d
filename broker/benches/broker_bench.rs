//! Broker benchmarks (not timed tests): `cargo bench -p paddock-broker`.
//!
//! 1. env-step round trip through the broker on loopback, client -> broker -> worker
//!    -> broker -> client, with an echo worker that answers with observations of the
//!    real size (1080-beam scans): p50/p99 for 1 env and for a batch of 64 envs, with
//!    the worker on TCP (a `paddock worker` process) and on `inproc://` in the broker's
//!    context (the `paddock serve` topology); the client is always on TCP. Each line
//!    also gives the voluntary context switches of all threads per step: every one is
//!    a thread that slept and had to be woken, the main cost on an idle machine.
//!
//! Rollouts/s through the broker against the same batch run locally (the overhead and
//! the scaling from one to two workers) are measured with real worker processes by
//! `paddock perf-cluster`, not here.

#[path = "observation.rs"]
mod observation;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use paddock_broker::client::Client;
use paddock_broker::{Broker, BrokerConfig, RouteOnly};
use paddock_proto::{Body, EnvOp, decode, encode, pack_f32};
use prost::Message;

const BEAMS: usize = 1080;

/// The spin of the client, the broker or the echo worker (`role` 0, 1, 2): the
/// default, or from `PADDOCK_BENCH_SPIN_US`, microseconds, one value for all or
/// `client,broker,worker` (0: always block, as before spinning existed).
fn spin(role: usize) -> Duration {
    let Ok(v) = std::env::var("PADDOCK_BENCH_SPIN_US") else {
        return paddock_broker::server::DEFAULT_SPIN;
    };
    let values: Vec<u64> = v.split(',').filter_map(|x| x.trim().parse().ok()).collect();
    let us = values.get(role).or(values.first()).copied();
    us.map_or(paddock_broker::server::DEFAULT_SPIN, Duration::from_micros)
}

/// A worker that hosts fake env sessions answering steps with full-size observations.
/// It waits like the real worker: polls without blocking for a while after a reply.
fn echo_worker(
    ctx: zmq::Context,
    backend: &str,
    stop: Arc<AtomicBool>,
) -> std::thread::JoinHandle<()> {
    let backend = backend.to_string();
    std::thread::spawn(move || {
        let s = ctx.socket(zmq::DEALER).unwrap();
        s.set_linger(0).unwrap();
        s.connect(&backend).unwrap();
        let mut spin_until = Instant::now();
        let hello = paddock_proto::WorkerHello {
            worker_id: "echo".into(),
            capacity: 1,
            ..Default::default()
        };
        s.send(encode(1, Body::WorkerHello(hello)), 0).unwrap();
        let mut num_envs = 1usize;
        while !stop.load(Ordering::Relaxed) {
            while Instant::now() < spin_until && s.poll(zmq::POLLIN, 0).unwrap() == 0 {
                std::thread::yield_now();
            }
            if s.poll(zmq::POLLIN, 20).unwrap() == 0 {
                continue;
            }
            let mut parts = s.recv_multipart(0).unwrap();
            let payload = parts.split_off(1);
            let Ok((rid, Body::EnvRequest(r))) = decode(&parts[0]) else {
                continue;
            };
            let header = |fingerprint| {
                encode(
                    rid,
                    Body::EnvReply(paddock_proto::EnvReply {
                        session_id: r.session_id,
                        op: r.op,
                        fingerprint,
                        ..Default::default()
                    }),
                )
            };
            if r.op == EnvOp::EnvOpen as i32 {
                let o = paddock_proto::EnvOpen::decode(payload[0].as_slice()).unwrap();
                num_envs = o.num_envs as usize;
                let opened = paddock_proto::EnvOpened {
                    num_envs: o.num_envs,
                    num_beams: BEAMS as u32,
                    num_agents: 1,
                    ..Default::default()
                };
                s.send_multipart([header(0), opened.encode_to_vec()], 0)
                    .unwrap();
            } else if r.op == EnvOp::EnvStep as i32 {
                let mut frames = vec![header(7)];
                frames.extend(observation::observation(num_envs, BEAMS));
                s.send_multipart(frames, 0).unwrap();
                spin_until = Instant::now() + spin(2);
            }
        }
    })
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

/// Voluntary context switches of every thread of this process so far.
fn context_switches() -> u64 {
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return 0;
    };
    tasks
        .flatten()
        .filter_map(|t| std::fs::read_to_string(t.path().join("status")).ok())
        .filter_map(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("voluntary_ctxt_switches:"))
                .and_then(|v| v.trim().parse::<u64>().ok())
        })
        .sum()
}

fn env_round_trip(num_envs: u32, steps: usize, inproc: bool) {
    let dir = tempfile::tempdir().unwrap();
    let ctx = zmq::Context::new();
    let local = "inproc://bench-workers";
    let mut cfg = BrokerConfig::new("tcp://127.0.0.1:0", "tcp://127.0.0.1:0", dir.path());
    cfg.local_backend = Some(local.into());
    cfg.spin = spin(1);
    let mut broker = Broker::bind_in(cfg, RouteOnly, ctx.clone()).unwrap();
    let (frontend, backend) = (
        broker.frontend_endpoint().to_string(),
        broker.backend_endpoint().to_string(),
    );
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    let broker_thread = std::thread::spawn(move || broker.run(&flag).unwrap());
    let (worker_ctx, endpoint) = if inproc {
        (ctx.clone(), local.to_string())
    } else {
        (zmq::Context::new(), backend)
    };
    let worker = echo_worker(worker_ctx, &endpoint, stop.clone());
    let mut c = Client::connect(&frontend).unwrap();
    c.spin = spin(0);
    let map = paddock_proto::MapRef {
        name: "lakeside".into(),
        hash: "0".repeat(64),
    };
    let open = paddock_proto::EnvOpen {
        map: Some(map),
        num_envs,
        ..Default::default()
    };
    let session = loop {
        match c.env(0, EnvOp::EnvOpen, Some(open.encode_to_vec())) {
            Ok((r, _)) => break r.session_id,
            // the worker may not have said hello yet
            _ => std::thread::sleep(Duration::from_millis(20)),
        }
    };
    let step = paddock_proto::EnvStep {
        actions: pack_f32(&vec![0.1; 2 * num_envs as usize]),
        ..Default::default()
    }
    .encode_to_vec();
    let mut times = Vec::with_capacity(steps);
    let mut switches = 0;
    for i in 0..steps + 200 {
        if i == 200 {
            switches = context_switches();
        }
        let t0 = Instant::now();
        let (reply, frames) = c.env(session, EnvOp::EnvStep, Some(step.clone())).unwrap();
        let dt = t0.elapsed().as_secs_f64() * 1e6;
        assert_eq!((reply.session_id, frames.len()), (session, 2));
        if i >= 200 {
            times.push(dt);
        }
    }
    let switches = (context_switches() - switches) as f64 / steps as f64;
    times.sort_by(f64::total_cmp);
    let via = if inproc { "inproc" } else { "tcp   " };
    println!(
        "env step round trip, {num_envs:>2} env(s), worker {via}: p50 {:>7.1} us  p99 {:>7.1} us  {switches:>5.1} wake-ups/step  ({steps} steps)",
        percentile(&times, 0.5),
        percentile(&times, 0.99)
    );
    stop.store(true, Ordering::Relaxed);
    worker.join().unwrap();
    broker_thread.join().unwrap();
}

fn main() {
    // `cargo test --benches` runs this with --bench absent: keep that quick
    let quick = !std::env::args().any(|a| a == "--bench");
    let steps = if quick { 50 } else { 5000 };
    for inproc in [false, true] {
        env_round_trip(1, steps, inproc);
        env_round_trip(64, steps, inproc);
    }
}
