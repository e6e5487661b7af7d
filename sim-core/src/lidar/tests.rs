use super::march::{Batch, CHUNK, cast_simple};
use super::*;
use crate::geometry::Pose;

fn free_map(w: usize, h: usize, res: f64) -> Map {
    Map::from_grid(
        "free",
        w,
        h,
        res,
        Pose::new(0.0, 0.0, 0.0),
        vec![false; w * h],
    )
    .unwrap()
}

#[test]
fn ray_obb_slab_cases() {
    let b = Obb {
        cx: 5.0,
        cy: 0.0,
        theta: 0.0,
        half_length: 1.0,
        half_width: 0.5,
    };
    // Head-on: near face at x = 4.
    assert!((ray_obb(0.0, 0.0, 1.0, 0.0, &b).unwrap() - 4.0).abs() < 1e-12);
    // Pointing away, and passing beside.
    assert_eq!(ray_obb(0.0, 0.0, -1.0, 0.0, &b), None);
    assert_eq!(ray_obb(0.0, 1.0, 1.0, 0.0, &b), None);
    // Origin inside.
    assert_eq!(ray_obb(5.2, 0.1, 0.0, 1.0, &b), Some(0.0));
    // Parallel to a face, on its line: touches.
    assert!((ray_obb(0.0, 0.5, 1.0, 0.0, &b).unwrap() - 4.0).abs() < 1e-12);
    // Diagonal onto the corner region: hits the bottom face y = -0.5 at x = 4.5.
    let (d, s) = (std::f64::consts::FRAC_1_SQRT_2, std::f64::consts::SQRT_2);
    let t = ray_obb(4.0, -1.0, d, d, &b).unwrap();
    assert!((t - 0.5 * s).abs() < 1e-12, "{t}");
    // Rotated by 90 degrees: the box now spans x in [4.5, 5.5].
    let r = Obb {
        theta: std::f64::consts::FRAC_PI_2,
        ..b
    };
    assert!((ray_obb(0.0, 0.0, 1.0, 0.0, &r).unwrap() - 4.5).abs() < 1e-12);
    // A degenerate (negative) box is never hit.
    let neg = Obb {
        half_width: -1.0,
        ..b
    };
    assert_eq!(ray_obb(0.0, 0.0, 1.0, 0.0, &neg), None);
}

#[test]
fn scan_sees_boxes_and_walls() {
    // 20 x 10 m free map with a wall column at x in [15, 15.5).
    let (w, h, res) = (40, 20, 0.5);
    let mut g = vec![false; w * h];
    for r in 0..h {
        g[r * w + 30] = true;
    }
    let map = Map::from_grid("wall", w, h, res, Pose::new(0.0, 0.0, 0.0), g).unwrap();
    let lidar = Lidar::new(LidarConfig {
        num_beams: 3,
        fov: 0.2,
        ..LidarConfig::default()
    });
    let pose = Pose::new(2.0, 5.0, 0.0);
    let mut out = [0.0; 3];
    lidar.scan(&map, pose, &[], &mut out);
    assert!((out[1] - 13.0).abs() < 1e-9, "{out:?}");
    // A car 4 m ahead, sideways: its near side at x = 6 - 0.155.
    let car = Obb::car(Pose::new(6.0, 5.0, std::f64::consts::FRAC_PI_2), 0.58, 0.31);
    lidar.scan(&map, pose, &[car], &mut out);
    assert!((out[1] - (4.0 - 0.155)).abs() < 1e-9, "{out:?}");
    // The outer beams (+-0.1 rad) pass beside the car and see the wall.
    assert!((out[0] - 13.0 / libm::cos(0.1)).abs() < 1e-9, "{out:?}");
    // A box behind the wall is hidden by it.
    let far = Obb::car(Pose::new(17.0, 5.0, 0.0), 0.58, 0.31);
    lidar.scan(&map, pose, &[far], &mut out);
    assert!((out[1] - 13.0).abs() < 1e-9, "{out:?}");
    // Inside an occupied cell every beam is 0; inside a box too.
    lidar.scan(&map, Pose::new(15.2, 5.0, 1.0), &[], &mut out);
    assert_eq!(out, [0.0; 3]);
    lidar.scan(&map, Pose::new(6.0, 5.0, 0.0), &[car], &mut out);
    assert_eq!(out, [0.0; 3]);
}

#[test]
fn off_map_origin_mount_offset_and_max_range() {
    let mut g = vec![false; 20 * 20];
    g[10 * 20 + 10] = true;
    let map = Map::from_grid("dot", 20, 20, 0.1, Pose::new(0.0, 0.0, 0.0), g).unwrap();
    let lidar = Lidar::new(LidarConfig {
        num_beams: 3,
        fov: 0.02,
        ..LidarConfig::default()
    });
    let mut out = [0.0; 3];
    // From off the map (x = -3), the beam enters and hits the cell's face at x = 1.0.
    lidar.scan(&map, Pose::new(-3.0, 1.05, 0.0), &[], &mut out);
    assert!((out[1] - 4.0).abs() < 1e-9, "{out:?}");
    // Looking away from the map: nothing.
    lidar.scan(
        &map,
        Pose::new(-3.0, 1.05, std::f64::consts::PI),
        &[],
        &mut out,
    );
    assert_eq!(out[1], 30.0);
    // Mount offset moves the scan origin forward.
    let mounted = Lidar::new(LidarConfig {
        mount_offset: 0.25,
        ..lidar.config().clone()
    });
    mounted.scan(&map, Pose::new(0.5, 1.05, 0.0), &[], &mut out);
    assert!((out[1] - 0.25).abs() < 1e-9, "{out:?}");
    // Max range clamps.
    let short = Lidar::new(LidarConfig {
        max_range: 0.3,
        ..lidar.config().clone()
    });
    short.scan(&map, Pose::new(0.5, 1.05, 0.0), &[], &mut out);
    assert_eq!(out[1], 0.3);
}

#[test]
fn noise_is_seeded_and_small() {
    let lidar = Lidar::new(LidarConfig::default());
    let map = free_map(10, 10, 0.1);
    let mut a = vec![0.0; 1080];
    lidar.scan(&map, Pose::new(0.5, 0.5, 0.0), &[], &mut a);
    let mut b = a.clone();
    let clean = a.clone();
    lidar.add_noise(&mut a, &mut Rng::new(3));
    lidar.add_noise(&mut b, &mut Rng::new(3));
    assert_eq!(a, b);
    let var = a
        .iter()
        .zip(&clean)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f64>()
        / 1080.0;
    assert!(
        (libm::sqrt(var) - 0.01).abs() < 0.002,
        "std {}",
        libm::sqrt(var)
    );
}

/// A random grid: scattered cells (sparse or dense) and a few blocks.
pub(crate) fn random_map(rng: &mut Rng, w: usize, h: usize) -> Map {
    let mut g = vec![false; w * h];
    let density = if rng.uniform() < 0.5 { 0.04 } else { 0.003 };
    for cell in g.iter_mut() {
        *cell = rng.uniform() < density;
    }
    for _ in 0..6 {
        let (c0, r0) = (rng.below(w as u64) as usize, rng.below(h as u64) as usize);
        let (bw, bh) = (1 + rng.below(8) as usize, 1 + rng.below(8) as usize);
        for r in r0..(r0 + bh).min(h) {
            for c in c0..(c0 + bw).min(w) {
                g[r * w + c] = true;
            }
        }
    }
    Map::from_grid("random", w, h, 0.05, Pose::new(-1.0, 2.0, 0.0), g).unwrap()
}

/// Casts `dirs` (dx, dy, tmax) from (gx, gy) with the batch march, portable and (where
/// the CPU has them) AVX and AVX-512; asserts that the portable one equals
/// [`cast_simple`] to 1e-9 cells and that the SIMD ones equal it bit for bit. Returns the
/// number of rays.
fn check_rays(batch: &mut Batch, map: &Map, gx: f64, gy: f64, dirs: &[(f64, f64, f64)]) -> usize {
    let n = dirs.len();
    let run = |batch: &mut Batch, simd: u8| -> Vec<f64> {
        for (i, &(dx, dy, tmax)) in dirs.iter().enumerate() {
            batch.dx[i] = dx;
            batch.dy[i] = dy;
            batch.tmax[i] = tmax;
        }
        let mut out = vec![0.0; n];
        batch.simd = simd;
        if simd > 0 {
            batch.cast::<true>(map, gx, gy, n, &mut out);
        } else {
            batch.cast::<false>(map, gx, gy, n, &mut out);
        }
        batch.simd = 2;
        out
    };
    let portable = run(batch, 0);
    let (w, h) = (map.width(), map.height());
    for (i, &(dx, dy, tmax)) in dirs.iter().enumerate() {
        let want = cast_simple(map, gx, gy, dx, dy, tmax);
        let got = portable[i];
        let ok = if want.is_infinite() {
            got.is_infinite()
        } else {
            (got - want).abs() <= 1e-9
        };
        assert!(
            ok,
            "map {w}x{h} from ({gx}, {gy}) dir ({dx}, {dy}) tmax {tmax}: {got} vs {want}"
        );
    }
    #[cfg(target_arch = "x86_64")]
    {
        // The AVX march both with and (on AVX2 CPUs) without gathered clearances.
        let avx = march::avx_usable(map);
        let gather = avx && std::arch::is_x86_feature_detected!("avx2");
        for (simd, usable, forced) in [
            (1, avx, Some(false)),
            (1, gather, Some(true)),
            (2, march::avx512_usable(map), None),
        ] {
            if usable {
                batch.avx_gather = forced;
                let fast = run(batch, simd);
                batch.avx_gather = None;
                for (i, (a, b)) in fast.iter().zip(&portable).enumerate() {
                    assert_eq!(
                        a.to_bits(),
                        b.to_bits(),
                        "simd level {simd} (gather {forced:?}), ray {i}"
                    );
                }
            }
        }
    }
    n
}

/// The accelerated march (both the portable and, where the CPU has it, the AVX version)
/// equals a plain cell-by-cell DDA, from origins on and off the map, to 1e-9 cells; and
/// the two versions agree bit for bit.
#[test]
fn march_equals_simple_dda_on_random_grids() {
    let mut rng = Rng::new(2024);
    let mut batch = Batch::new();
    let mut rays = 0;
    for _ in 0..16 {
        let (w, h) = (20 + rng.below(80) as usize, 20 + rng.below(80) as usize);
        let map = random_map(&mut rng, w, h);
        for trial in 0..6 {
            // Origins anywhere, off the map included (every side and corner), some on
            // cell corners exactly.
            let mut gx = rng.uniform_range(-10.0, w as f64 + 10.0);
            let mut gy = rng.uniform_range(-10.0, h as f64 + 10.0);
            let on_corner = trial == 5;
            if on_corner {
                gx = gx.floor();
                gy = gy.floor();
            }
            let n = 1 + rng.below(CHUNK as u64) as usize;
            let mut dirs = Vec::new();
            let d = std::f64::consts::FRAC_1_SQRT_2;
            for i in 0..n {
                let (dx, dy) = match i % 23 {
                    // Exactly axis-aligned and diagonal rays in every quadrant, including
                    // -0.0 components, and nearly axis-aligned ones.
                    0 => (1.0, 0.0),
                    1 => (-1.0, -0.0),
                    2 => (0.0, 1.0),
                    3 => (-0.0, -1.0),
                    // A diagonal from a cell corner runs through corners only, touching
                    // cells at single points, where which of them counts is a tie-break.
                    4..=7 if on_corner => (0.6, -0.8),
                    4 => (d, d),
                    5 => (-d, d),
                    6 => (d, -d),
                    7 => (-d, -d),
                    8 => (1.0, -1e-12),
                    9 => (-1e-12, 1.0),
                    10 => (-1.0, 1e-12),
                    _ => {
                        let (s, c) = libm::sincos(rng.uniform_range(-4.0, 4.0));
                        (c, s)
                    }
                };
                let tmax = if i % 5 == 0 {
                    rng.uniform_range(0.0, 40.0)
                } else {
                    1e9
                };
                dirs.push((dx, dy, tmax));
            }
            rays += check_rays(&mut batch, &map, gx, gy, &dirs);
        }
    }
    assert!(rays > 3000, "{rays} rays");
}

/// Like the shipped tracks: a closed corridor (a ring of random width, off-centre, so
/// its sides run at every angle) with everything outside it occupied, and origins inside
/// it, where rays take long quadrant jumps along the corridor and graze its walls.
#[test]
fn march_equals_simple_dda_in_corridors() {
    let mut rng = Rng::new(77);
    let mut batch = Batch::new();
    let mut rays = 0;
    for _ in 0..6 {
        let (w, h) = (120 + rng.below(200) as usize, 120 + rng.below(200) as usize);
        let (cx, cy) = (w as f64 * rng.uniform_range(0.4, 0.6), h as f64 * 0.5);
        let outer = 0.45 * w.min(h) as f64;
        let inner = outer - rng.uniform_range(8.0, 40.0);
        let mut g = vec![false; w * h];
        for r in 0..h {
            for c in 0..w {
                let d = libm::hypot(c as f64 + 0.5 - cx, 1.3 * (r as f64 + 0.5 - cy));
                g[r * w + c] = !(inner..outer).contains(&d);
            }
        }
        let map = Map::from_grid("ring", w, h, 0.05, Pose::new(0.0, 0.0, 0.0), g).unwrap();
        let mut origins = 0;
        while origins < 8 {
            let (gx, gy) = (
                rng.uniform_range(0.0, w as f64),
                rng.uniform_range(0.0, h as f64),
            );
            if map.cell_occupied(gx as i64, gy as i64) {
                continue;
            }
            origins += 1;
            let n = CHUNK;
            let a0 = rng.uniform_range(-4.0, 4.0);
            let dirs: Vec<(f64, f64, f64)> = (0..n)
                .map(|i| {
                    let (s, c) = libm::sincos(a0 + i as f64 * 0.0245);
                    (c, s, 1e9)
                })
                .collect();
            rays += check_rays(&mut batch, &map, gx, gy, &dirs);
        }
    }
    assert!(rays > 10_000, "{rays} rays");
}

#[test]
fn reference_scan_of_occupied_origin_is_zero_and_free_map_is_max() {
    let lidar = Lidar::new(LidarConfig::default());
    let mut out = vec![1.0; 1080];
    lidar.scan_reference(&free_map(10, 10, 0.1), Pose::new(0.5, 0.5, 0.3), &mut out);
    assert!(out.iter().all(|&r| r == 30.0));
    let mut g = vec![false; 100];
    g[55] = true;
    let map = Map::from_grid("d", 10, 10, 0.1, Pose::new(0.0, 0.0, 0.0), g).unwrap();
    lidar.scan_reference(&map, Pose::new(0.55, 0.55, 0.0), &mut out);
    assert!(out.iter().all(|&r| r == 0.0));
}

/// A random pose on `map` or up to `margin` metres off it, heading within
/// `[-turn, turn]`, and up to `boxes - 1` car-sized boxes within 2 m of it.
fn random_scene(rng: &mut Rng, map: &Map, margin: f64, turn: f64, boxes: u64) -> (Pose, Vec<Obb>) {
    let o = map.origin();
    let (w, h) = (map.width() as f64, map.height() as f64);
    let pose = Pose::new(
        o.x + rng.uniform_range(-margin, w * map.resolution() + margin),
        o.y + rng.uniform_range(-margin, h * map.resolution() + margin),
        rng.uniform_range(-turn, turn),
    );
    let boxes = (0..rng.below(boxes))
        .map(|_| Obb {
            cx: pose.x + rng.uniform_range(-2.0, 2.0),
            cy: pose.y + rng.uniform_range(-2.0, 2.0),
            theta: rng.uniform_range(-3.0, 3.0),
            half_length: 0.25,
            half_width: 0.15,
        })
        .collect();
    (pose, boxes)
}

/// A whole scan (box limits, beam rotations, march, metres) gives the same bits on the
/// widest SIMD path this CPU has as on the portable one, boxes and off-map origins
/// included.
#[test]
fn scan_is_bit_identical_across_simd_paths() {
    let mut rng = Rng::new(99);
    let lidar = Lidar::new(LidarConfig::default()).with_sweep(false);
    let (mut fast, mut portable) = (vec![0.0; 1080], vec![0.0; 1080]);
    for _ in 0..6 {
        let (w, h) = (60 + rng.below(100) as usize, 60 + rng.below(100) as usize);
        let map = random_map(&mut rng, w, h);
        for _ in 0..5 {
            let (pose, boxes) = random_scene(&mut rng, &map, 1.0, 4.0, 4);
            lidar.scan(&map, pose, &boxes, &mut fast);
            lidar.scan_with(&map, pose, &boxes, &mut portable, ScanPath::Portable, None);
            for (i, (a, b)) in fast.iter().zip(&portable).enumerate() {
                assert_eq!(a.to_bits(), b.to_bits(), "beam {i} from {pose:?}");
            }
        }
    }
}

/// The default fan, a narrow one of 64 beams and a nearly full one of 721 beams to 10 m.
fn fans() -> [LidarConfig; 3] {
    [
        LidarConfig::default(),
        LidarConfig {
            num_beams: 64,
            fov: 1.0,
            ..LidarConfig::default()
        },
        LidarConfig {
            num_beams: 721,
            fov: 5.9,
            max_range: 10.0,
            ..LidarConfig::default()
        },
    ]
}

/// Testing each box only on the beams within its angular span gives the same bits as
/// testing it on every beam: cars near and far, behind the car and across the ends of
/// the beam fan, rotated, overlapping the origin's circle, with headings of any turn, on
/// the default fan and on a narrow and a nearly full one.
#[test]
fn boxes_tested_on_their_beams_only_give_the_same_bits() {
    let circuit = crate::circuit::Circuits::new().default_circuit().unwrap();
    let map = &circuit.map;
    let track = &circuit.track;
    let configs = fans();
    let mut rng = Rng::new(11);
    // beams that met a box before the walls
    let mut on_boxes = 0;
    for config in configs {
        let culled = Lidar::new(config.clone());
        let every = Lidar::new(config).with_every_beam_on_boxes();
        let n = culled.num_beams();
        let (mut a, mut b, mut walls) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        for k in 0..400 {
            let (on_line, _, _) = track.at(rng.uniform_range(0.0, track.length()));
            let turns = rng.below(5) as f64 - 2.0;
            let pose = Pose::new(
                on_line.x + rng.uniform_range(-1.0, 1.0),
                on_line.y + rng.uniform_range(-1.0, 1.0),
                rng.uniform_range(-std::f64::consts::PI, std::f64::consts::PI)
                    + turns * std::f64::consts::TAU,
            );
            let reach = if k % 4 == 0 { 0.6 } else { 6.0 };
            let cars: Vec<Obb> = (0..1 + rng.below(4))
                .map(|_| {
                    let car = Pose::new(
                        pose.x + rng.uniform_range(-reach, reach),
                        pose.y + rng.uniform_range(-reach, reach),
                        rng.uniform_range(-4.0, 4.0),
                    );
                    Obb::car(
                        car,
                        rng.uniform_range(0.1, 1.2),
                        rng.uniform_range(0.05, 0.6),
                    )
                })
                .collect();
            culled.scan(map, pose, &cars, &mut a);
            every.scan(map, pose, &cars, &mut b);
            for (i, (x, y)) in a.iter().zip(&b).enumerate() {
                assert_eq!(
                    x.to_bits(),
                    y.to_bits(),
                    "beam {i} from {pose:?} with {cars:?}"
                );
            }
            culled.scan(map, pose, &[], &mut walls);
            on_boxes += a.iter().zip(&walls).filter(|(x, w)| x < w).count();
        }
    }
    assert!(on_boxes > 50_000, "only {on_boxes} beams met a box");
}

/// The angular sweep gives the march's bits, boxes included, on random grids (dense and
/// sparse, turned or not in the world frame, origins on and off the map), on a real track from random and from degenerate
/// poses (origins on cell corners and centres with beams along the diagonals, where
/// crossings fall on cell corners and must be left to the march), on every SIMD path this
/// CPU has, and on narrow and nearly full fans; and it does sweep most scans.
#[test]
fn sweep_gives_the_march_bits_and_leaves_corner_crossings_to_it() {
    let counts = || {
        let sw = SCAN_SWEEP.take().unwrap_or_default();
        let c = (sw.swept, sw.handed);
        SCAN_SWEEP.set(Some(sw));
        c
    };
    let (swept0, handed0) = counts();
    let mut configs = fans().to_vec();
    configs.push(LidarConfig {
        num_beams: 9,
        fov: std::f64::consts::PI,
        ..LidarConfig::default()
    });
    let check = |lidar: &Lidar, map: &Map, pose: Pose, boxes: &[Obb], what: &str| {
        let n = lidar.num_beams();
        let (mut want, mut got) = (vec![0.0; n], vec![0.0; n]);
        let march = lidar.clone().with_sweep(false);
        march.scan_with(map, pose, boxes, &mut want, ScanPath::Portable, None);
        let swept = lidar.clone().with_sweep(true);
        for path in ScanPath::ALL.into_iter().filter(|p| p.supported()) {
            // On `avx512` the sweep compiled both ways (see `path::sweep_in_256_bits`).
            let widths: &[bool] = if path == ScanPath::Avx512 {
                &[false, true]
            } else {
                &[false]
            };
            for &narrow in widths {
                path::SWEEP_IN_256_BITS.set(Some(narrow));
                swept.scan_with(map, pose, boxes, &mut got, path, None);
                path::SWEEP_IN_256_BITS.set(None);
                for (i, (a, b)) in got.iter().zip(&want).enumerate() {
                    assert_eq!(
                        a.to_bits(),
                        b.to_bits(),
                        "{what}: {path} (sweep in 256 bits: {narrow}) beam {i} of {n} \
                         from {pose:?}: sweep {a} vs march {b}"
                    );
                }
            }
        }
    };
    let mut rng = Rng::new(2024);
    for config in &configs {
        let lidar = Lidar::new(config.clone());
        for k in 0..8 {
            let (w, h) = (40 + rng.below(200) as usize, 40 + rng.below(200) as usize);
            let map = random_map(&mut rng, w, h);
            // Half of them with the grid turned in the world frame.
            let map = if k % 2 == 0 {
                map
            } else {
                let yaw = rng.uniform_range(-3.0, 3.0);
                let grid = map.occupancy().to_vec();
                Map::from_grid("turned", w, h, 0.05, Pose::new(-1.0, 2.0, yaw), grid).unwrap()
            };
            for _ in 0..6 {
                let (pose, boxes) = random_scene(&mut rng, &map, 0.5, 7.0, 3);
                check(&lidar, &map, pose, &boxes, "random grid");
            }
        }
    }
    // Maps more than 64 blocks of 64 cells across or along (the ring walk reads each
    // ring's blocks with faces off words of 64 blocks), scanned from near the first
    // word's end so that rings straddle it.
    let lidar = Lidar::new(LidarConfig::default());
    for (w, h) in [(4400, 96), (96, 4400)] {
        let mut g = vec![false; w * h];
        for cell in g.iter_mut() {
            *cell = rng.uniform() < 0.002;
        }
        let map = Map::from_grid("wide", w, h, 0.05, Pose::new(0.0, 0.0, 0.0), g).unwrap();
        for _ in 0..12 {
            let along = rng.uniform_range(3900.0, 4300.0);
            let across = rng.uniform_range(1.0, 95.0);
            let (gx, gy) = if w > h {
                (along, across)
            } else {
                (across, along)
            };
            let (x, y) = map.grid_to_world(gx, gy);
            let pose = Pose::new(x, y, rng.uniform_range(-4.0, 4.0));
            check(&lidar, &map, pose, &[], "map of more than 64 blocks");
        }
    }
    let circuit = crate::circuit::Circuits::new().default_circuit().unwrap();
    let (map, track) = (&circuit.map, &circuit.track);
    let (w, h) = (map.width() as f64, map.height() as f64);
    for config in &configs {
        let lidar = Lidar::new(config.clone());
        for k in 0..120 {
            let pose = if k % 2 == 0 {
                let (p, _, _) = track.at(rng.uniform_range(0.0, track.length()));
                Pose::new(
                    p.x + rng.uniform_range(-1.0, 1.0),
                    p.y + rng.uniform_range(-1.0, 1.0),
                    rng.uniform_range(-4.0, 4.0),
                )
            } else {
                // A cell centre (or corner) near the track, heading a multiple of pi/8.
                let (p, _, _) = track.at(rng.uniform_range(0.0, track.length()));
                let (gx, gy) = map.world_to_grid(p.x, p.y);
                let f = if k % 4 == 1 { 0.5 } else { 0.0 };
                let (gx, gy) = (
                    (gx.floor() + f).clamp(0.0, w - 1.0),
                    (gy.floor() + f).clamp(0.0, h - 1.0),
                );
                let (x, y) = map.grid_to_world(gx, gy);
                Pose::new(x, y, rng.below(16) as f64 * std::f64::consts::FRAC_PI_8)
            };
            check(&lidar, map, pose, &[], "default circuit");
        }
    }
    let (swept, handed) = counts();
    let (swept, handed) = (swept - swept0, handed - handed0);
    let per_path = ScanPath::ALL.iter().filter(|p| p.supported()).count() as u64;
    assert!(
        swept > per_path * 4 * 100,
        "only {swept} scans swept of {}",
        per_path * 4 * 168
    );
    assert!(handed > 0, "no beam was left to the march");
}

/// A scan with its noise drawn during the scan (`scan_noisy`) gives the bits and the
/// generator state of the scan then `add_noise`: on every path, by each algorithm and by
/// `auto` (whose trial scans add the noise after), with boxes and without, on fans whose
/// beams are and are not a multiple of the set-up's blocks, from poses the sweep takes,
/// leaves some beams of to the march, or leaves whole to it.
#[test]
fn noisy_scans_are_the_scan_then_its_noise() {
    let circuit = crate::circuit::Circuits::new().default_circuit().unwrap();
    let (track, map) = (&circuit.track, &circuit.map);
    let mut configs = fans().to_vec();
    configs.push(LidarConfig {
        num_beams: 9,
        fov: std::f64::consts::PI,
        noise_std: 0.5,
        ..LidarConfig::default()
    });
    let mut rng = Rng::new(77);
    let mut scenes = Vec::new();
    for k in 0..24 {
        let (p, _, _) = track.at(rng.uniform_range(0.0, track.length()));
        let pose = match k % 3 {
            0 => p,
            // at a cell centre, beams through cell corners: some beams to the march
            1 => {
                let (gx, gy) = map.world_to_grid(p.x, p.y);
                let (x, y) = map.grid_to_world(gx.floor() + 0.5, gy.floor() + 0.5);
                Pose::new(x, y, (k % 16) as f64 * std::f64::consts::FRAC_PI_8)
            }
            // on a grid line: the whole scan to the march
            _ => {
                let (gx, gy) = map.world_to_grid(p.x, p.y);
                let (x, y) = map.grid_to_world(gx.floor(), gy);
                Pose::new(x, y, p.theta)
            }
        };
        let boxes = if k % 2 == 0 {
            random_scene(&mut rng, map, 0.0, 0.0, 4).1
        } else {
            Vec::new()
        };
        let boxes: Vec<Obb> = boxes
            .iter()
            .map(|b| Obb {
                cx: pose.x + (b.cx - map.origin().x) % 2.0,
                cy: pose.y + (b.cy - map.origin().y) % 2.0,
                ..*b
            })
            .collect();
        scenes.push((pose, boxes));
    }
    let handed = || {
        let sw = SCAN_SWEEP.take().unwrap_or_default();
        let h = sw.handed;
        SCAN_SWEEP.set(Some(sw));
        h
    };
    let handed0 = handed();
    for config in &configs {
        for algorithm in [
            ScanAlgorithm::Auto,
            ScanAlgorithm::Sweep,
            ScanAlgorithm::March,
        ] {
            let lidar = Lidar::new(config.clone()).with_algorithm(algorithm);
            let n = lidar.num_beams();
            let (mut want, mut got) = (vec![0.0; n], vec![0.0; n]);
            for path in ScanPath::ALL.into_iter().filter(|p| p.supported()) {
                let (mut a, mut b) = (Rng::new(5), Rng::new(5));
                for (i, (pose, boxes)) in scenes.iter().enumerate() {
                    lidar.scan_with(map, *pose, boxes, &mut want, path, None);
                    lidar.add_noise(&mut want, &mut a);
                    lidar.scan_with(map, *pose, boxes, &mut got, path, Some(&mut b));
                    for (j, (g, w)) in got.iter().zip(&want).enumerate() {
                        assert_eq!(
                            g.to_bits(),
                            w.to_bits(),
                            "{algorithm:?} {path}, {n} beams, scene {i}, beam {j}"
                        );
                    }
                    assert_eq!(a, b, "{algorithm:?} {path}, {n} beams, scene {i}");
                }
            }
        }
    }
    assert!(
        handed() > handed0,
        "no beam of a swept scan was left to the march"
    );
    // the public call is the same
    let lidar = Lidar::new(LidarConfig::default());
    let (mut want, mut got) = (vec![0.0; 1080], vec![0.0; 1080]);
    let (mut a, mut b) = (Rng::new(8), Rng::new(8));
    lidar.scan(map, scenes[0].0, &scenes[0].1, &mut want);
    lidar.add_noise(&mut want, &mut a);
    lidar.scan_noisy(map, scenes[0].0, &scenes[0].1, &mut got, &mut b);
    assert_eq!(
        got.iter().map(|r| r.to_bits()).collect::<Vec<_>>(),
        want.iter().map(|r| r.to_bits()).collect::<Vec<_>>()
    );
    assert_eq!(a, b);
}

#[test]
fn the_algorithm_is_chosen_by_default_on_every_path_and_can_be_forced() {
    for path in ScanPath::ALL.into_iter().filter(|p| p.supported()) {
        let lidar = Lidar::new(LidarConfig::default()).with_path(path).unwrap();
        assert_eq!(lidar.algorithm(), ScanAlgorithm::Auto, "default on {path}");
        for a in ScanAlgorithm::ALL {
            assert_eq!(
                lidar.clone().with_algorithm(a).algorithm(),
                a,
                "{a} on {path}"
            );
        }
        assert_eq!(
            lidar.clone().with_sweep(true).algorithm(),
            ScanAlgorithm::Sweep
        );
        assert_eq!(lidar.with_sweep(false).algorithm(), ScanAlgorithm::March);
    }
}

/// By default a thread's first scans of a map are each computed by both algorithms (and
/// give the same bits as either forced); forced, every scan takes the one asked for.
#[test]
fn auto_scans_try_both_algorithms_and_forced_scans_take_one() {
    let circuit = crate::circuit::Circuits::new().default_circuit().unwrap();
    let (map, track) = (&circuit.map, &circuit.track);
    let n = choice::TRIAL as u64;
    // a map of its own, so that no earlier scan of this thread has settled its choice
    let map = Map::from_grid(
        "copy",
        map.width(),
        map.height(),
        map.resolution(),
        map.origin(),
        map.occupancy().to_vec(),
    )
    .unwrap();
    let auto = Lidar::new(LidarConfig::default());
    let sweep = auto.clone().with_algorithm(ScanAlgorithm::Sweep);
    let march = auto.clone().with_algorithm(ScanAlgorithm::March);
    let beams = auto.num_beams();
    let (mut a, mut b) = (vec![0.0; beams], vec![0.0; beams]);
    let poses: Vec<Pose> = (0..n)
        .map(|i| track.at(track.length() * i as f64 / n as f64).0)
        .collect();
    let delta = |f: &mut dyn FnMut()| {
        let (m0, s0) = thread_scans_by_algorithm();
        f();
        let (m1, s1) = thread_scans_by_algorithm();
        (m1 - m0, s1 - s0)
    };
    let mut forced = 0;
    for (i, &p) in poses.iter().enumerate() {
        let by_auto = delta(&mut || auto.scan(&map, p, &[], &mut a));
        let by_march = delta(&mut || march.scan(&map, p, &[], &mut b));
        assert_eq!(by_march, (1, 0));
        assert_eq!(
            a.iter().map(|r| r.to_bits()).collect::<Vec<_>>(),
            b.iter().map(|r| r.to_bits()).collect::<Vec<_>>(),
            "auto vs march from {p:?}"
        );
        // the trial: by the march and by the sweep (which marches the scans it does not
        // apply to)
        let by_sweep = delta(&mut || sweep.scan(&map, p, &[], &mut b));
        assert!(by_sweep == (0, 1) || by_sweep == (1, 0), "{by_sweep:?}");
        assert_eq!(by_auto, (by_sweep.0 + 1, by_sweep.1), "scan {i}");
        forced += by_sweep.1;
    }
    assert!(forced > n / 2, "{forced} of {n} scans swept when forced");
}
