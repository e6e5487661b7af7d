//! One 1080-beam LIDAR scan on a race-track-like map: a stadium-shaped ring corridor
//! 3 m wide with 0.1 m walls, 0.05 m cells, 1040 x 1040 cells (free outside the walls,
//! like the shipped track maps), from poses on the centre line heading along it.
//! Compares the exact [`Lidar::scan`] on each code path this CPU has (`scan/portable`,
//! `scan/avx`, `scan/avx512`), by the march and by the angular sweep over wall faces
//! (`scan_sweep/avx`, ...), with the reference port [`Lidar::scan_reference`], on that
//! map and on the default shipped map. Rays per second = 1080 / time per scan
//! (criterion's "thrpt", in elements). On a shared machine use the `scan_rounds` bench
//! instead (CPU time, alternating rounds); figures per path: `docs/performance-scan.md`.
//!
//! Recorded (2-core AMD EPYC VM shared with other builds, so +-20 %; AVX path):
//! scan 28-31 M rays/s (about 36 us per scan), scan_reference 6.8-7.0 M rays/s.
//! AVX-512 march (eight rays per packet, gathered clearances) on a 2-core Xeon VM under
//! load 3-4, side by side with the AVX march of the same build: scan 32-34 -> 22-25 us
//! (32-49 M rays/s).
//! On shipped tracks from centerline poses (`cargo test -p paddock-sim --release --test
//! maps -- --ignored --nocapture`): scan 31-37 M rays/s, scan_reference 8-10 M rays/s.
//! Quadrant clearance tables instead of the centred Chebyshev block, measured side by
//! side with the previous build on the same (busier) VM: scan 20.9-22.7 -> 24.5-25.2 M
//! rays/s here; `paddock perf` medians of 3, rays/s: lakeside 22.4 -> 25.0, harbour
//! 23.9 -> 27.8, quarry 20.8 -> 24.0 M.
//! AVX-512 march stepping two packets interleaved, scalar clearance loads instead of the
//! gather, a bit set of live packets, chunks of 384 rays (2-core AMD EPYC Zen 5 VM under
//! load 2-4, old and new build alternated, medians of 6): scan 13.1 -> 11.2 us (83 -> 97 M
//! rays/s); `--bench world` world_step/1car_scan 17.3 -> 14.4 us (medians of 5).
//! `lidar_noise/add_noise` times the seeded noise of one scan (1080 Gaussian draws).

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use paddock_sim::circuit::{Circuit, Circuits};
use paddock_sim::geometry::Pose;
use paddock_sim::lidar::{Lidar, LidarConfig, ScanPath};
use paddock_sim::map::Map;

const RES: f64 = 0.05;
const SIZE: usize = 1040;
const HALF_STRAIGHT: f64 = 8.0;
const RADIUS: f64 = 16.0;
const HALF_WIDTH: f64 = 1.5;
const WALL: f64 = 0.1;

/// Distance from (x, y) to the stadium's centre line (segment of half length
/// HALF_STRAIGHT on the x axis, inflated by RADIUS), signed: negative inside.
fn centre_offset(x: f64, y: f64) -> f64 {
    let cx = x.clamp(-HALF_STRAIGHT, HALF_STRAIGHT);
    (x - cx).hypot(y) - RADIUS
}

fn ring_map() -> Map {
    let origin = -(SIZE as f64) * RES / 2.0;
    let mut occupied = vec![false; SIZE * SIZE];
    for r in 0..SIZE {
        for c in 0..SIZE {
            let x = origin + (c as f64 + 0.5) * RES;
            let y = origin + (r as f64 + 0.5) * RES;
            let d = centre_offset(x, y).abs();
            occupied[r * SIZE + c] = (HALF_WIDTH..HALF_WIDTH + WALL).contains(&d);
        }
    }
    Map::from_grid(
        "ring",
        SIZE,
        SIZE,
        RES,
        Pose::new(origin, origin, 0.0),
        occupied,
    )
    .expect("valid synthetic map")
}

/// Poses on the centre line, counter-clockwise, heading along the track.
fn centre_poses(n: usize) -> Vec<Pose> {
    let straight = 2.0 * HALF_STRAIGHT;
    let arc = std::f64::consts::PI * RADIUS;
    let lap = 2.0 * (straight + arc);
    (0..n)
        .map(|i| {
            let s = lap * i as f64 / n as f64;
            if s < straight {
                Pose::new(-HALF_STRAIGHT + s, -RADIUS, 0.0)
            } else if s < straight + arc {
                let a = -std::f64::consts::FRAC_PI_2 + (s - straight) / RADIUS;
                Pose::new(
                    HALF_STRAIGHT + RADIUS * a.cos(),
                    RADIUS * a.sin(),
                    a + std::f64::consts::FRAC_PI_2,
                )
            } else if s < 2.0 * straight + arc {
                Pose::new(
                    HALF_STRAIGHT - (s - straight - arc),
                    RADIUS,
                    std::f64::consts::PI,
                )
            } else {
                let a = std::f64::consts::FRAC_PI_2 + (s - 2.0 * straight - arc) / RADIUS;
                Pose::new(
                    -HALF_STRAIGHT + RADIUS * a.cos(),
                    RADIUS * a.sin(),
                    a + std::f64::consts::FRAC_PI_2,
                )
            }
        })
        .collect()
}

/// Poses on the centreline of the default shipped map, heading along it.
fn shipped_poses(circuit: &Circuit, n: usize) -> Vec<Pose> {
    let len = circuit.track.length();
    (0..n)
        .map(|i| circuit.track.at(len * i as f64 / n as f64).0)
        .collect()
}

fn bench_scan(c: &mut Criterion) {
    let ring = ring_map();
    let _ = ring.distance_field();
    let circuit = Circuits::new()
        .default_circuit()
        .expect("the default map ships with the project");
    let maps: [(String, &Map, Vec<Pose>); 2] = [
        ("lidar_ring_0.05m".to_string(), &ring, centre_poses(97)),
        (
            format!("lidar_{}", circuit.name),
            &circuit.map,
            shipped_poses(&circuit, 97),
        ),
    ];
    for (group_name, map, poses) in &maps {
        let mut group = c.benchmark_group(group_name);
        let lidar = Lidar::new(LidarConfig::default());
        let mut out = vec![0.0; lidar.num_beams()];
        group.throughput(Throughput::Elements(lidar.num_beams() as u64));
        let mut i = 0;
        // Every path this CPU has, labelled (`scan/avx` is what AVX2-only CPUs run).
        // Then the same by the angular sweep over wall faces (`scan_sweep/avx`, ...).
        for sweep in [false, true] {
            for path in ScanPath::ALL.into_iter().filter(|p| p.supported()) {
                let lidar = lidar.clone().with_path(path).expect("supported path");
                let lidar = lidar.with_sweep(sweep);
                let id = if sweep { "scan_sweep" } else { "scan" };
                group.bench_function(format!("{id}/{path}"), |b| {
                    b.iter(|| {
                        i = (i + 1) % poses.len();
                        lidar.scan(map, black_box(poses[i]), &[], &mut out);
                        black_box(&out);
                    })
                });
            }
        }
        group.bench_function("scan_reference", |b| {
            b.iter(|| {
                i = (i + 1) % poses.len();
                lidar.scan_reference(map, black_box(poses[i]), &mut out);
                black_box(&out);
            })
        });
        group.finish();
    }
}

/// The seeded noise of one scan (`Lidar::add_noise`: 1080 Gaussian draws added to the
/// ranges), which every noisy step adds to its scan.
fn bench_noise(c: &mut Criterion) {
    let lidar = Lidar::new(LidarConfig::default());
    let mut out = vec![5.0; lidar.num_beams()];
    let mut rng = paddock_sim::rng::Rng::new(7);
    let mut group = c.benchmark_group("lidar_noise");
    group.throughput(Throughput::Elements(lidar.num_beams() as u64));
    group.bench_function("add_noise", |b| {
        b.iter(|| {
            lidar.add_noise(black_box(&mut out), &mut rng);
            // Back near 5 m, so the values stay in range over many iterations.
            out.fill(5.0);
        })
    });
    group.finish();
}

criterion_group!(benches, bench_scan, bench_noise);
criterion_main!(benches);
