//! Broker benchmarks (not timed tests): `cargo bench -p paddock-broker`.
//!
//! 1. env-step round trip through the broker on loopback, client -> broker -> worker
//!    -> broker -> client, with an echo worker that answers with observations of the
//!    real size (1080-beam scans): p50/p99 for 1 env and for a batch of 64 envs;
//! 2. rollouts/s of the same batch locally (one thread) and through the broker with
//!    1 and 2 single-threaded in-process workers (one episode per task).

#[path = "../tests/common/mod.rs"]
mod common;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use common::*;
use paddock_broker::client::Client;
use paddock_proto::{Body, pack_f32, pack_f64};
use paddock_rollout::{Executor, LocalExecutor};

const BEAMS: usize = 1080;

/// A worker that hosts fake env sessions answering steps with full-size observations.
fn echo_worker(backend: &str, stop: Arc<AtomicBool>) -> std::thread::JoinHandle<()> {
    let backend = backend.to_string();
    std::thread::spawn(move || {
        let peer = RawPeer::connect(&backend);
        peer.send(
            1,
            Body::WorkerHello(paddock_proto::WorkerHello {
                worker_id: "echo".into(),
                capacity: 1,
                ..Default::default()
            }),
        );
        let mut num_envs = 1usize;
        while !stop.load(Ordering::Relaxed) {
            let Some((rid, body)) = peer.try_recv(Duration::from_millis(20)) else {
                continue;
            };
            match body {
                Body::EnvOpen(o) => {
                    num_envs = o.num_envs as usize;
                    peer.send(
                        rid,
                        Body::EnvOpened(paddock_proto::EnvOpened {
                            session_id: 1,
                            num_envs: o.num_envs,
                            num_beams: BEAMS as u32,
                            num_agents: 1,
                            ..Default::default()
                        }),
                    );
                }
                Body::EnvStep(s) => {
                    let obs = paddock_proto::EnvObservation {
                        session_id: s.session_id,
                        num_envs: num_envs as u32,
                        scans: pack_f32(&vec![1.5; num_envs * BEAMS]),
                        states: pack_f64(&vec![0.25; num_envs * 7]),
                        rewards: pack_f64(&vec![0.1; num_envs]),
                        terminated: vec![0; num_envs],
                        truncated: vec![0; num_envs],
                        progress: pack_f64(&vec![1.0; num_envs]),
                        laps: vec![0; 4 * num_envs],
                        time: pack_f64(&vec![0.01; num_envs]),
                        ..Default::default()
                    };
                    peer.send(rid, Body::EnvObservation(obs));
                }
                _ => {}
            }
        }
    })
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

fn env_round_trip(num_envs: u32, steps: usize) {
    let dir = tempfile::tempdir().unwrap();
    let broker = TestBroker::start(dir.path().into(), |_| {});
    let stop = Arc::new(AtomicBool::new(false));
    let worker = echo_worker(&broker.backend, stop.clone());
    let mut c = Client::connect(&broker.frontend).unwrap();
    let (bundle, map) = lakeside();
    c.put_map(bundle).unwrap();
    let session = loop {
        match c.request(Body::EnvOpen(paddock_proto::EnvOpen {
            map: Some(map.clone()),
            num_envs,
            ..Default::default()
        })) {
            Ok(Body::EnvOpened(o)) => break o.session_id,
            // the worker may not have said hello yet
            _ => std::thread::sleep(Duration::from_millis(20)),
        }
    };
    let actions = pack_f32(&vec![0.1; 2 * num_envs as usize]);
    let mut times = Vec::with_capacity(steps);
    for i in 0..steps + 200 {
        let t0 = Instant::now();
        let reply = c
            .request(Body::EnvStep(paddock_proto::EnvStep {
                session_id: session,
                actions: actions.clone(),
                ..Default::default()
            }))
            .unwrap();
        let dt = t0.elapsed().as_secs_f64() * 1e6;
        assert!(matches!(reply, Body::EnvObservation(_)));
        if i >= 200 {
            times.push(dt);
        }
    }
    times.sort_by(f64::total_cmp);
    println!(
        "env step round trip, {num_envs:>2} env(s): p50 {:>7.1} us  p99 {:>7.1} us  ({steps} steps)",
        percentile(&times, 0.5),
        percentile(&times, 0.99)
    );
    stop.store(true, Ordering::Relaxed);
    worker.join().unwrap();
}

fn rollouts(episodes: usize) {
    let (_, map) = lakeside();
    let b = batch(&map, episodes, 42, 10.0);
    // the same tasks as domain tasks, for the local executor
    let dir = paddock_sim::track::Circuit::resolve("lakeside", &[])
        .unwrap()
        .dir
        .clone();
    let scenario =
        Arc::new(paddock_proto::convert::scenario_from_proto(&b.scenarios[0], &dir).unwrap());
    let tasks: Vec<_> = b
        .tasks
        .iter()
        .map(|t| paddock_rollout::EpisodeTask {
            scenario: scenario.clone(),
            seed: t.seed,
            record: paddock_proto::convert::record_from_proto(t.record_decimation),
        })
        .collect();
    // load the map (distance field) before timing
    let local = run_locally(&batch(&map, 1, 0, 0.1));
    assert_eq!(local.len(), 1);
    let local = run_locally(&b);
    let mut local_rate = 0.0;
    for threads in [1usize, 2] {
        let exec = LocalExecutor::new(threads).unwrap();
        let t0 = Instant::now();
        exec.run_batch(&tasks, &|_| {});
        let rate = episodes as f64 / t0.elapsed().as_secs_f64();
        if threads == 1 {
            local_rate = rate;
        }
        println!("rollouts locally, {threads} thread(s): {rate:>8.1} episodes/s");
    }
    for workers in [1usize, 2] {
        let dir = tempfile::tempdir().unwrap();
        let cache = tempfile::tempdir().unwrap();
        let broker = TestBroker::start(dir.path().into(), |_| {});
        let c = RawPeer::connect(&broker.frontend);
        put_lakeside(&c);
        let ws: Vec<TestWorker> = (0..workers)
            .map(|i| {
                TestWorker::spawn(
                    &broker.backend,
                    WorkerOpts {
                        capacity: 2,
                        id: format!("w{i}"),
                        ..Default::default()
                    },
                    cache.path().join(i.to_string()),
                )
            })
            .collect();
        for w in &ws {
            w.wait_welcomed();
        }
        // warm the workers' map caches
        c.send(1, Body::RolloutBatch(batch(&map, 2 * workers, 1, 0.1)));
        c.reply_to(1, Duration::from_secs(60));
        let t0 = Instant::now();
        c.send(2, Body::RolloutBatch(b.clone()));
        let got = match c.reply_to(2, Duration::from_secs(600)) {
            Body::RolloutResult(r) => r.outcomes,
            other => panic!("expected rollout_result, got {other:?}"),
        };
        let rate = episodes as f64 / t0.elapsed().as_secs_f64();
        assert_eq!(got, local, "remote == local");
        println!(
            "rollouts via broker, {workers} worker(s): {rate:>6.1} episodes/s  (x{:.3} of local 1 thread)",
            rate / local_rate
        );
    }
}

fn main() {
    // `cargo test --benches` runs this with --bench absent: keep that quick
    let quick = !std::env::args().any(|a| a == "--bench");
    let (steps, episodes) = if quick { (50, 8) } else { (5000, 200) };
    env_round_trip(1, steps);
    env_round_trip(64, steps);
    rollouts(episodes);
}
