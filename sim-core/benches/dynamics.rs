//! Cost of one `Vehicle::step` (dynamic single-track model, RK4) at speed while steering.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use paddock_sim::dynamics::Vehicle;
use paddock_sim::geometry::Pose;
use paddock_sim::params::VehicleParams;

const DT: f64 = 0.01;

fn bench_step(c: &mut Criterion) {
    let p = VehicleParams::default();
    let mut car = Vehicle::new(Pose::default());
    // Bring the car up to speed in the dynamic branch first.
    for _ in 0..300 {
        car.step(&p, 0.0, 6.0, DT);
    }
    let start = car.clone();
    let mut k = 0u32;
    c.bench_function("vehicle_step_st_rk4", |b| {
        b.iter(|| {
            // A slow slalom, so the steering controller and the tires work.
            k += 1;
            let steer = if k % 200 < 100 { 0.2 } else { -0.2 };
            car.step(
                black_box(&p),
                black_box(steer),
                black_box(6.0),
                black_box(DT),
            );
            if k == 100_000 {
                k = 0;
                car = start.clone();
            }
        })
    });
    black_box(&car);
}

criterion_group!(benches, bench_step);
criterion_main!(benches);
