//! Criterion benchmark of whole world steps on the default shipped map: one car and two
//! cars, with and without the 1080-beam LIDAR. Cars drive a fixed gentle arc; episodes
//! restart from the snapshot taken after reset, so every iteration steps a car in
//! motion on the track. Steps with scans are measured on every LIDAR code path the CPU
//! has (`world_step/1car_scan/avx` is what CPUs without AVX-512 run).

use criterion::{Criterion, criterion_group, criterion_main};
use paddock_sim::circuit::Circuits;
use paddock_sim::collision::CollisionMode;
use paddock_sim::lidar::ScanPath;
use paddock_sim::world::{Action, Starts, StepEvents, World, WorldConfig};
use std::hint::black_box;

fn world(agents: usize, scan: bool) -> World {
    let circuit = Circuits::new()
        .default_circuit()
        .expect("the default map ships with the project");
    let mut cfg = WorldConfig::with_agents(agents);
    cfg.collision_mode = CollisionMode::Ignore;
    for a in &mut cfg.agents {
        a.scan = scan;
    }
    let mut w = World::new(circuit, cfg).unwrap();
    w.reset(0, &Starts::Random).unwrap();
    w
}

fn bench_world(c: &mut Criterion) {
    // With scans, every LIDAR path this CPU has (`avx` is what AVX2-only CPUs run).
    let paths: Vec<ScanPath> = ScanPath::ALL
        .into_iter()
        .filter(|p| p.supported())
        .collect();
    let mut cases = vec![(1, None), (2, None)];
    for agents in [1, 2] {
        cases.extend(paths.iter().map(|&p| (agents, Some(p))));
    }
    for (agents, path) in cases {
        let mut w = world(agents, path.is_some());
        if let Some(p) = path {
            w.set_scan_path(p).expect("supported path");
        }
        let start = w.snapshot().unwrap();
        let actions = vec![Action::new(0.05, 4.0); agents];
        // Stepped as rollouts and vector envs step a world: into events kept between steps.
        let mut events = StepEvents::default();
        let name = match path {
            Some(p) => format!("world_step/{agents}car_scan/{p}"),
            None => format!("world_step/{agents}car_noscan"),
        };
        let mut k = 0u32;
        c.bench_function(&name, |b| {
            b.iter(|| {
                k += 1;
                if k.is_multiple_of(200) {
                    w.restore(&start).unwrap();
                }
                w.step_into(black_box(&actions), &mut events).unwrap();
                black_box(&events);
            })
        });
    }
}

criterion_group!(benches, bench_world);
criterion_main!(benches);
