//! Criterion benchmark of whole world steps on the default shipped map: one car and two
//! cars, with and without the 1080-beam LIDAR. Cars drive a fixed gentle arc; episodes
//! restart from the snapshot taken after reset, so every iteration steps a car in
//! motion on the track.

use criterion::{Criterion, criterion_group, criterion_main};
use paddock_sim::collision::CollisionMode;
use paddock_sim::track::Circuit;
use paddock_sim::world::{Action, Starts, World, WorldConfig};
use std::hint::black_box;

fn world(agents: usize, scan: bool) -> World {
    let circuit = Circuit::default_circuit().expect("the default map ships with the project");
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
    for (agents, scan) in [(1, false), (1, true), (2, false), (2, true)] {
        let mut w = world(agents, scan);
        let start = w.snapshot().unwrap();
        let actions = vec![Action::new(0.05, 4.0); agents];
        let name = format!(
            "world_step/{agents}car_{}",
            if scan { "scan" } else { "noscan" }
        );
        let mut k = 0u32;
        c.bench_function(&name, |b| {
            b.iter(|| {
                k += 1;
                if k.is_multiple_of(200) {
                    w.restore(&start).unwrap();
                }
                black_box(w.step(black_box(&actions)).unwrap());
            })
        });
    }
}

criterion_group!(benches, bench_world);
criterion_main!(benches);
