//! Every code path of the exact LIDAR scan (portable, AVX, AVX-512: those this CPU has)
//! gives the same bits on the same input, over many random poses on the real race tracks
//! of `shared/maps` and on the shipped maps, with and without other cars in view.

mod common;

use std::path::PathBuf;

use paddock_sim::circuit::Circuits;
use paddock_sim::geometry::{Obb, Pose};
use paddock_sim::lidar::{Lidar, LidarConfig, ScanPath};
use paddock_sim::map::Map;
use paddock_sim::rng::Rng;
use paddock_sim::track::Track;

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
    let lidar = Lidar::new(LidarConfig::default());
    let paths: Vec<Lidar> = ScanPath::ALL
        .into_iter()
        .filter(|p| p.supported())
        .map(|p| lidar.clone().with_path(p).unwrap())
        .collect();
    assert_eq!(paths[0].path(), ScanPath::Portable);
    let mut rng = Rng::new(seed);
    let beams = lidar.num_beams();
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
                    "{name}: path {} beam {i} from {pose:?} with {} cars: {a} vs portable {b}",
                    fast.path(),
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
    let wider = ScanPath::ALL.iter().filter(|p| p.supported()).count() - 1;
    assert_eq!(compared, wider * tracks.len() * 150);
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

#[test]
fn forcing_a_path_is_checked_and_reported() {
    let lidar = Lidar::new(LidarConfig::default());
    assert_eq!(lidar.path(), ScanPath::best());
    for path in ScanPath::ALL {
        assert_eq!(ScanPath::from_name(path.name()), Some(path));
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
