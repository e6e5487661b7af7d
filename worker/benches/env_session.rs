//! The worker's share of a vector-env step (criterion; `cargo bench --workspace --bench
//! env_session`): one step of 64 envs of one car with its 1080-beam scan through
//! `Sessions::handle` (decode the request, step the worlds, write the observation
//! frames, fingerprint them), next to the same 64 worlds stepped by `Worlds::step`
//! writing their scans into one packed buffer: the simulator's own cost. Standing cars,
//! as `client-py/benchmarks/env_steps.py` drives them, on one thread (the rayon pool
//! is built with one thread, as a worker pinned to one core has). The times are the
//! thread's CPU time, so other processes on a busy machine do not count against them.

use criterion::{Criterion, Throughput};
use paddock_proto::{EnvOp, EnvOpen, EnvReset, EnvStep, Lidar, pack_f32};
use paddock_sim::circuit::Circuits;
use paddock_sim::world::{Action, PackedObservations, Worlds};
use paddock_worker::sessions::Sessions;
use prost::Message;
use std::hint::black_box;
use std::time::Duration;

const ENVS: usize = 64;
const BEAMS: u32 = 1080;

fn open_msg(circuits: &Circuits) -> EnvOpen {
    let bundle = paddock_wire::local_map(circuits, "lakeside").expect("a shipped map");
    EnvOpen {
        map: Some(paddock_wire::map_ref(&bundle)),
        num_envs: ENVS as u32,
        seed: 0,
        lidar: Some(Lidar {
            num_beams: BEAMS,
            fov: 4.7,
            max_range: 30.0,
            noise_std: 0.01,
            mount_offset: 0.0,
        }),
        laps: 100,
        time_limit: 36_000.0,
        frame_skip: 1,
        ..Default::default()
    }
}

fn bench(c: &mut Criterion) {
    let circuits = Circuits::new();
    let mut sessions = Sessions::new();
    sessions.set_circuits(circuits.clone());
    let opened = sessions.handle(
        1,
        EnvOp::EnvOpen as i32,
        &open_msg(&circuits).encode_to_vec(),
    );
    assert!(opened.header.error.is_none(), "{:?}", opened.header.error);
    let step = EnvStep {
        actions: pack_f32(&[0.0; 2 * ENVS]),
        reset_envs: vec![],
    }
    .encode_to_vec();
    // the simulator alone: the session's 64 worlds, as they are after its reset
    let mut worlds = {
        // seeds 0..64, as the Python bench's `reset(seed=0)`: the same start poses
        let reset = EnvReset {
            seeds: (0..ENVS as u64).collect(),
            ..Default::default()
        };
        let reply = sessions.handle(1, EnvOp::EnvReset as i32, &reset.encode_to_vec());
        assert!(reply.header.error.is_none(), "{:?}", reply.header.error);
        sessions_worlds(&sessions)
    };
    let actions = vec![Action::default(); ENVS];
    let mut scans = vec![0u8; ENVS * BEAMS as usize * 4];
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

/// This thread's CPU time so far.
fn thread_cpu() -> Duration {
    use nix::time::{ClockId, clock_gettime};
    clock_gettime(ClockId::CLOCK_THREAD_CPUTIME_ID)
        .map(Duration::from)
        .expect("this thread's CPU clock")
}

/// A copy of session 1's worlds (the bench's own batch, stepped without the session).
fn sessions_worlds(sessions: &Sessions) -> Worlds {
    let env = sessions.env(1).expect("session 1 is open");
    let first = env.world(0).expect("one env at least");
    let mut worlds = Worlds::of(first, env.num_envs());
    for i in 0..env.num_envs() {
        let snapshot = env.world(i).and_then(|w| w.snapshot().ok()).expect("reset");
        worlds.world_mut(i).restore(&snapshot).unwrap();
    }
    worlds
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
