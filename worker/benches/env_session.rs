//! The worker's share of a vector-env step (criterion; `cargo bench --workspace --bench
//! env_session`): one step of 64 envs of one car with its 1080-beam scan through
//! `Sessions::handle` (decode the request, step the worlds, write the observation
//! frames, fingerprint them), next to the same 64 worlds stepped by `Worlds::step`
//! writing their scans into one packed buffer: the simulator's own cost. Standing cars,
//! as `client-py/benchmarks/env_steps.py` drives them, on one thread (the rayon pool
//! is built with one thread, as a worker pinned to one core has). The times are the
//! thread's CPU time, so other processes on a busy machine do not count against them.

mod common;

use common::{BEAMS, ENVS, thread_cpu};
use criterion::{Criterion, Throughput};
use paddock_proto::{EnvOp, EnvStep, pack_f32};
use paddock_sim::world::{Action, PackedObservations};
use prost::Message;
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let mut sessions = common::session();
    let step = EnvStep {
        actions: pack_f32(&[0.0; 2 * ENVS]),
        reset_envs: vec![],
    }
    .encode_to_vec();
    // the simulator alone: the session's 64 worlds, as they are after its reset
    let mut worlds = common::session_worlds(&sessions);
    let actions = vec![Action::default(); ENVS];
    let mut scans = vec![0u8; ENVS * BEAMS * 4];
    let mut g = c.benchmark_group("env_step_64x1080");
    g.throughput(Throughput::Elements(ENVS as u64));
    g.bench_function("worlds_step", |b| {
        b.iter_custom(|iters| {
            let t0 = thread_cpu();
            for _ in 0..iters {
                let mut out = PackedObservations::scans(&mut scans, 1);
                worlds
                    .step(black_box(&actions), &[], Some(&mut out))
                    .unwrap();
            }
            thread_cpu() - t0
        })
    });
    g.bench_function("session_handle", |b| {
        b.iter_custom(|iters| {
            let t0 = thread_cpu();
            for _ in 0..iters {
                black_box(sessions.handle(1, EnvOp::EnvStep as i32, black_box(&step)));
            }
            thread_cpu() - t0
        })
    });
    g.finish();
}

fn main() {
    // one thread: the figure of a worker pinned to one core
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build_global()
        .expect("the global pool is built once");
    let mut c = Criterion::default().configure_from_args();
    bench(&mut c);
    c.final_summary();
}
