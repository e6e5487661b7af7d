//! Every code path of the exact LIDAR scan (portable, AVX, AVX-512: those this CPU has),
//! each by the march and by the angular sweep over wall faces, gives the same bits on the
//! same input, over many random poses on the real race tracks
//! of `shared/maps` and on the shipped maps, with and without other cars in view; along
//! driven trajectories (consecutive poses a step apart, with resets to far poses); and
//! from degenerate poses (origins on grid lines and cell corners, beams along the grid
//! axes and diagonals, origins in walls and off the map).

mod common;

use std::path::PathBuf;

use paddock_sim::circuit::Circuits;
use paddock_sim::geometry::{Obb, Pose};
use paddock_sim::lidar::{Lidar, LidarConfig, ScanAlgorithm, ScanPath};
use paddock_sim::map::Map;
use paddock_sim::rng::Rng;
use paddock_sim::track::Track;
use paddock_sim::world::{Action, Starts, World, WorldConfig};

/// (name, map yaml, centerline csv) of every track folder in shared/maps.
fn shared_tracks() -> Vec<(String, PathBuf, PathBuf)> {
    let Some(maps) = common::shared("maps") else {
        return Vec::new();
    };
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(&maps)
        .expect("read shared/maps")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    dirs.sort();
    dirs.into_iter()
        .filter_map(|dir| {
            let files: Vec<PathBuf> = std::fs::read_dir(&dir)
                .ok()?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .collect();
            let find = |end: &str| {
                files
                    .iter()
                    .find(|p| p.to_string_lossy().ends_with(end))
                    .cloned()
            };
            let name = dir.file_name()?.to_string_lossy().into_owned();
            Some((name, find("_map.yaml")?, find("_centerline.csv")?))
        })
        .collect()
}

/// Scans from `poses` random poses near the centreline of `track` (off it by up to 1.5 m,
/// any heading; a third of them with one to three cars around) on every path this CPU
/// has, and asserts that each path's ranges equal the portable path's bit for bit.
/// Returns the number of scans compared.
fn check_track(name: &str, map: &Map, track: &Track, seed: u64, poses: usize) -> usize {
    let paths = every_path(LidarConfig::default());
    assert_eq!(paths[0].path(), ScanPath::Portable);
    let mut rng = Rng::new(seed);
    let beams = paths[0].num_beams();
    let (mut want, mut got) = (vec![0.0; beams], vec![0.0; beams]);
    let mut compared = 0;
    for _ in 0..poses {
        let (on_line, _, _) = track.at(rng.uniform_range(0.0, track.length()));
        let pose = Pose::new(
            on_line.x + rng.uniform_range(-1.5, 1.5),
            on_line.y + rng.uniform_range(-1.5, 1.5),
            rng.uniform_range(-std::f64::consts::PI, std::f64::consts::PI),
        );
        let cars: Vec<Obb> = if rng.below(3) == 0 {
            (0..1 + rng.below(3))
                .map(|_| {
                    let car = Pose::new(
                        pose.x + rng.uniform_range(-4.0, 4.0),
                        pose.y + rng.uniform_range(-4.0, 4.0),
                        rng.uniform_range(-3.0, 3.0),
                    );
                    Obb::car(car, 0.58, 0.31)
                })
                .collect()
        } else {
            Vec::new()
        };
        paths[0].scan(map, pose, &cars, &mut want);
        for fast in &paths[1..] {
            fast.scan(map, pose, &cars, &mut got);
            for (i, (a, b)) in got.iter().zip(&want).enumerate() {
                assert_eq!(
                    a.to_bits(),
                    b.to_bits(),
                    "{name}: path {} ({}) beam {i} from {pose:?} with {} cars: {a} vs \
                     portable {b}",
                    fast.path(),
                    fast.algorithm(),
                    cars.len()
                );
            }
            compared += 1;
        }
    }
    compared
}

#[test]
fn every_scan_path_gives_the_same_bits_on_real_tracks() {
    let tracks = shared_tracks();
    if tracks.is_empty() {
        return;
    }
    assert!(tracks.len() >= 20, "found only {} tracks", tracks.len());
    let mut compared = 0;
    for (k, (name, yaml, center)) in tracks.iter().enumerate() {
        let map = Map::load(yaml).unwrap_or_else(|e| panic!("{name}: {e}"));
        let track = Track::load(center, None).unwrap_or_else(|e| panic!("{name}: {e}"));
        compared += check_track(name, &map, &track, 1000 + k as u64, 150);
    }
    // each path by the sweep and all but the portable by the march, then the default
    let others = 2 * ScanPath::ALL.iter().filter(|p| p.supported()).count();
    assert_eq!(compared, others * tracks.len() * 150);
}

#[test]
fn every_scan_path_gives_the_same_bits_on_shipped_maps() {
    for name in ["lakeside", "harbour", "quarry"] {
        let circuit = Circuits::new()
            .get(name)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        check_track(name, &circuit.map, &circuit.track, 7, 300);
    }
}

/// Asserts that every path this CPU has scans `pose` to the same bits as the portable
/// path.
fn assert_paths_agree(name: &str, lidars: &[Lidar], map: &Map, pose: Pose, cars: &[Obb]) {
    let beams = lidars[0].num_beams();
    let (mut want, mut got) = (vec![0.0; beams], vec![0.0; beams]);
    lidars[0].scan(map, pose, cars, &mut want);
    for fast in &lidars[1..] {
        fast.scan(map, pose, cars, &mut got);
        for (i, (a, b)) in got.iter().zip(&want).enumerate() {
            assert_eq!(
                a.to_bits(),
                b.to_bits(),
                "{name}: path {} ({}) beam {i} from {pose:?}: {a} vs portable {b}",
                fast.path(),
                fast.algorithm()
            );
        }
    }
}

/// `config` on every path this CPU has, by the march (portable first) and by the sweep, then
/// with the defaults (the widest path, the algorithm chosen by timing).
fn every_path(config: LidarConfig) -> Vec<Lidar> {
    let lidar = Lidar::new(config);
    let paths = ScanPath::ALL.into_iter().filter(|p| p.supported());
    let march = paths
        .clone()
        .map(|p| lidar.clone().with_path(p).unwrap().with_sweep(false));
    let sweep = paths.map(|p| lidar.clone().with_path(p).unwrap().with_sweep(true));
    // and as a world scans by default: the widest path, each thread choosing its algorithm
    let auto = std::iter::once(lidar.clone());
    march.chain(sweep).chain(auto).collect()
}

/// A car driven along the centreline: poses 0.01 s apart at 4-12 m/s with a weaving
/// heading and lateral offset, and every 150 poses a reset to a random far pose (as an
/// episode reset does); another car in view half the time. Returns the poses scanned.
fn drive(name: &str, lidars: &[Lidar], map: &Map, track: &Track, seed: u64, poses: usize) -> usize {
    let mut rng = Rng::new(seed);
    let mut s = rng.uniform_range(0.0, track.length());
    let mut speed = 8.0;
    for k in 0..poses {
        if k % 150 == 149 {
            s = rng.uniform_range(0.0, track.length());
        }
        speed = (speed + rng.uniform_range(-0.2, 0.2)).clamp(4.0, 12.0);
        s = (s + speed * 0.01) % track.length();
        let (on_line, _, _) = track.at(s);
        let phase = k as f64 * 0.02;
        let (ps, pc) = libm::sincos(on_line.theta);
        let lateral = 0.6 * libm::sin(phase);
        let pose = Pose::new(
            on_line.x - ps * lateral,
            on_line.y + pc * lateral,
            on_line.theta + 0.2 * libm::cos(phase),
        );
        let cars = if (k / 40) % 2 == 0 {
            let (ahead, _, _) = track.at((s + 2.0) % track.length());
            vec![Obb::car(ahead, 0.58, 0.31)]
        } else {
            Vec::new()
        };
        assert_paths_agree(name, lidars, map, pose, &cars);
    }
    poses
}

#[test]
fn every_scan_path_gives_the_same_bits_along_driven_trajectories() {
    let lidars = every_path(LidarConfig::default());
    let mut scanned = 0;
    for (k, name) in ["lakeside", "harbour", "quarry"].into_iter().enumerate() {
        let circuit = Circuits::new()
            .get(name)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        scanned += drive(
            name,
            &lidars,
            &circuit.map,
            &circuit.track,
            50 + k as u64,
            400,
        );
    }
    for (k, (name, yaml, center)) in shared_tracks().iter().enumerate().step_by(4) {
        let map = Map::load(yaml).unwrap_or_else(|e| panic!("{name}: {e}"));
        let track = Track::load(center, None).unwrap_or_else(|e| panic!("{name}: {e}"));
        scanned += drive(name, &lidars, &map, &track, 70 + k as u64, 300);
    }
    assert!(scanned >= 1200, "scanned {scanned} poses");
}

#[test]
fn every_scan_path_gives_the_same_bits_from_degenerate_poses() {
    let circuit = Circuits::new().get("lakeside").unwrap();
    let map = &circuit.map;
    // Beams every pi/8 from -pi/2 (the middle one exactly along the heading), and the
    // default fan.
    let configs = [
        LidarConfig {
            num_beams: 9,
            fov: std::f64::consts::PI,
            ..LidarConfig::default()
        },
        LidarConfig::default(),
    ];
    let (w, h) = (map.width() as f64, map.height() as f64);
    let mut rng = Rng::new(5);
    let mut scanned = 0;
    for config in configs {
        let lidars = every_path(config);
        for k in 0..400 {
            // Cell corners, cell sides and centres, on and off the map and in walls.
            let (gx, gy) = match k % 4 {
                0 => (rng.below(w as u64) as f64, rng.below(h as u64) as f64),
                1 => (rng.below(w as u64) as f64, rng.below(h as u64) as f64 + 0.5),
                2 => (rng.below(w as u64) as f64 + 0.5, rng.below(h as u64) as f64),
                _ => (
                    rng.uniform_range(-20.0, w + 20.0).floor(),
                    rng.uniform_range(-20.0, h + 20.0).floor(),
                ),
            };
            let (x, y) = map.grid_to_world(gx, gy);
            let theta = match k % 3 {
                0 => rng.below(8) as f64 * std::f64::consts::FRAC_PI_4,
                1 => rng.below(4) as f64 * std::f64::consts::FRAC_PI_2 - std::f64::consts::PI,
                _ => rng.uniform_range(-3.2, 3.2),
            };
            assert_paths_agree("lakeside", &lidars, map, Pose::new(x, y, theta), &[]);
            scanned += 1;
        }
    }
    assert_eq!(scanned, 800);
}

#[test]
fn forcing_a_path_is_checked_and_reported() {
    let lidar = Lidar::new(LidarConfig::default());
    assert_eq!(lidar.path(), ScanPath::best());
    for path in ScanPath::ALL {
        assert_eq!(ScanPath::from_name(path.name()), Some(path));
        // only the `avx` path may gather its clearances
        let loads = path.clearance_loads();
        assert!(loads == "scalar loads" || (loads == "gather" && path == ScanPath::Avx));
        // the sweep's loops: none on the portable path, 256-bit on `avx`, either on
        // `avx512`
        let vectors = path.sweep_vectors();
        match path {
            ScanPath::Portable => assert_eq!(vectors, "none"),
            ScanPath::Avx => assert_eq!(vectors, "256-bit"),
            ScanPath::Avx512 => assert!(vectors == "256-bit" || vectors == "512-bit"),
        }
        match lidar.clone().with_path(path) {
            Ok(forced) => {
                assert!(path.supported());
                assert_eq!(forced.path(), path);
            }
            Err(e) => {
                assert!(!path.supported());
                assert!(e.to_string().contains(path.name()), "{e}");
            }
        }
    }
    assert_eq!(ScanPath::from_name("sse9"), None);
}

/// Worlds of three cars (boxes in each other's scans when in view) step to the same bits
/// whether their scans are marched or swept, on every path this CPU has, with the
/// default seeded noise: same scans, poses and events, step after step, across resets.
#[test]
fn worlds_step_to_the_same_bits_by_march_and_by_sweep() {
    let circuit = Circuits::new().get("harbour").unwrap();
    let config = WorldConfig::with_agents(3);
    for path in ScanPath::ALL.into_iter().filter(|p| p.supported()) {
        let mut worlds: Vec<World> = [false, true]
            .into_iter()
            .map(|sweep| {
                let mut w = World::new(circuit.clone(), config.clone()).unwrap();
                w.set_scan_path(path).unwrap();
                w.set_scan_sweep(sweep);
                let want = if sweep {
                    ScanAlgorithm::Sweep
                } else {
                    ScanAlgorithm::March
                };
                assert_eq!(w.scan_algorithm(), want);
                w
            })
            .collect();
        for episode in 0..3u64 {
            for w in &mut worlds {
                w.reset(episode, &Starts::Random).unwrap();
            }
            for k in 0..150 {
                let steer = 0.3 * libm::sin(k as f64 * 0.05 + episode as f64);
                let actions = [
                    Action::new(steer, 4.0),
                    Action::new(-steer, 5.0),
                    Action::new(0.1, 3.0),
                ];
                let events: Vec<String> = worlds
                    .iter_mut()
                    .map(|w| format!("{:?}", w.step(&actions).unwrap()))
                    .collect();
                assert_eq!(events[0], events[1], "{path}: episode {episode} step {k}");
                let (a, b) = (
                    worlds[0].observation().unwrap(),
                    worlds[1].observation().unwrap(),
                );
                let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(
                    bits(&a.scans),
                    bits(&b.scans),
                    "{path}: episode {episode} step {k}"
                );
                assert_eq!(bits(&a.poses_x), bits(&b.poses_x));
            }
        }
    }
}

#[test]
fn a_map_beyond_the_bound_on_wall_faces_is_marched_to_the_same_bits() {
    // A checkerboard 2048 cells across around a free room: far more wall-face runs than
    // the sweep keeps faces for, so every scan is marched, on every path alike.
    let side = 2048;
    let room = |c: usize, r: usize| (924..1124).contains(&c) && (924..1124).contains(&r);
    let occupied = (0..side * side)
        .map(|i| {
            let (c, r) = (i % side, i / side);
            !room(c, r) && (c + r) % 2 == 1
        })
        .collect();
    let map = Map::from_grid(
        "board",
        side,
        side,
        0.05,
        Pose::new(0.0, 0.0, 0.0),
        occupied,
    )
    .expect("a valid grid");
    let lidars = every_path(LidarConfig::default());
    let (marched, swept) = paddock_sim::lidar::thread_scans_by_algorithm();
    let mut rng = Rng::new(9);
    for _ in 0..20 {
        let pose = Pose::new(
            rng.uniform_range(47.0, 55.0),
            rng.uniform_range(47.0, 55.0),
            rng.uniform_range(-3.2, 3.2),
        );
        assert_paths_agree("board", &lidars, &map, pose, &[]);
    }
    let (marched_after, swept_after) = paddock_sim::lidar::thread_scans_by_algorithm();
    assert_eq!(swept_after, swept, "no scan is swept");
    // (the default's timing trials count twice)
    assert!(marched_after - marched >= 20 * lidars.len() as u64);
}
