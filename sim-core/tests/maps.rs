//! Map loading on the shipped race tracks, maps as values, error reporting, origin yaw,
//! and a throughput measurement of the LIDAR on real tracks (ignored by default).

mod common;

use std::path::{Path, PathBuf};

use paddock_sim::geometry::Pose;
use paddock_sim::lidar::{Lidar, LidarConfig};
use paddock_sim::map::{Map, MapError};

/// The shared folder holding `maps/`.
fn shared_dir() -> Option<PathBuf> {
    common::shared("maps").and_then(|m| m.parent().map(Path::to_path_buf))
}

/// (yaml, centerline csv) of every track folder in shared/maps.
fn tracks(shared: &Path) -> Vec<(String, PathBuf, PathBuf)> {
    let mut out = Vec::new();
    let mut dirs: Vec<_> = std::fs::read_dir(shared.join("maps"))
        .expect("read shared/maps")
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .filter(|p| p.is_dir())
        .collect();
    dirs.sort();
    for dir in dirs {
        let mut files: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .filter_map(|e| e.ok())
            .map(|e| e.path())
            .collect();
        files.sort();
        let yaml = files
            .iter()
            .find(|p| p.to_string_lossy().ends_with("_map.yaml"));
        let center = files
            .iter()
            .find(|p| p.to_string_lossy().ends_with("_centerline.csv"));
        if let (Some(y), Some(c)) = (yaml, center) {
            let name = dir.file_name().unwrap().to_string_lossy().into_owned();
            out.push((name, y.clone(), c.clone()));
        }
    }
    out
}

fn centerline(path: &Path) -> Vec<(f64, f64)> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|s| s.trim().parse().unwrap()).collect();
            (v[0], v[1])
        })
        .collect()
}

/// Poses on the centerline, heading towards the next point.
fn centerline_poses(points: &[(f64, f64)]) -> Vec<Pose> {
    (0..points.len())
        .map(|i| {
            let (x, y) = points[i];
            let (nx, ny) = points[(i + 1) % points.len()];
            Pose::new(x, y, libm::atan2(ny - y, nx - x))
        })
        .collect()
}

#[test]
fn every_track_loads_and_its_centerline_is_free() {
    let Some(shared) = shared_dir() else { return };
    let tracks = tracks(&shared);
    // The shared folder holds 23 track folders (Montreal and Shanghai lack a raceline,
    // not a centerline).
    assert!(tracks.len() >= 23, "found only {} tracks", tracks.len());
    // Two threads: loading 23 maps of 2000 x 2000 cells is slow in debug builds.
    let check = |(name, yaml, center): &(String, PathBuf, PathBuf)| {
        let map = Map::load(yaml).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(map.width() > 0 && map.height() > 0);
        let pts = centerline(center);
        let free = pts.iter().filter(|&&(x, y)| !map.occupied_at(x, y)).count();
        let share = free as f64 / pts.len() as f64;
        assert!(
            share >= 0.95,
            "{name}: only {:.1} % of {} centerline points are free",
            100.0 * share,
            pts.len()
        );
    };
    let (first, second) = tracks.split_at(tracks.len() / 2);
    std::thread::scope(|s| {
        let other = s.spawn(|| second.iter().for_each(check));
        first.iter().for_each(check);
        other.join().unwrap();
    });
}

#[test]
fn maps_are_values_and_coexist() {
    let Some(shared) = shared_dir() else { return };
    let tracks = tracks(&shared);
    let (_, yaml_a, center_a) = &tracks[0];
    let (_, yaml_b, center_b) = &tracks[1];
    let a1 = Map::load(yaml_a).unwrap();
    // a different spelling of the same path loads the same map (a new value)
    let dotted = yaml_a
        .parent()
        .unwrap()
        .join(".")
        .join(yaml_a.file_name().unwrap());
    let a2 = Map::load(&dotted).unwrap();
    assert_eq!(a1.content_hash(), a2.content_hash());
    let b = Map::load(yaml_b).unwrap();
    assert_ne!(a1.content_hash(), b.content_hash());
    // each map still answers for itself after the other was loaded
    let pa = centerline(center_a);
    let pb = centerline(center_b);
    let free_a = pa.iter().filter(|&&(x, y)| !a1.occupied_at(x, y)).count();
    let free_b = pb.iter().filter(|&&(x, y)| !b.occupied_at(x, y)).count();
    assert!(free_a * 20 >= pa.len() * 19 && free_b * 20 >= pb.len() * 19);
    // loads on several threads at once give the same map
    let handles: Vec<_> = (0..4)
        .map(|_| {
            let y = yaml_b.clone();
            std::thread::spawn(move || Map::load(&y).unwrap().content_hash())
        })
        .collect();
    for h in handles {
        assert_eq!(h.join().unwrap(), b.content_hash());
    }
}

fn temp_dir(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("paddock-maps-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A tiny valid 8-bit grey PGM (P5).
fn write_pgm(path: &Path, w: usize, h: usize, pixels: &[u8]) {
    let mut bytes = format!("P5\n{w} {h}\n255\n").into_bytes();
    bytes.extend_from_slice(pixels);
    std::fs::write(path, bytes).unwrap();
}

fn load_err(dir: &Path, file: &str, yaml: &str) -> MapError {
    let path = dir.join(file);
    std::fs::write(&path, yaml).unwrap();
    Map::load(&path).expect_err(yaml)
}

#[test]
fn bad_files_give_errors_naming_the_problem() {
    let dir = temp_dir("bad");
    write_pgm(&dir.join("ok.pgm"), 2, 2, &[0, 254, 254, 254]);
    let cases = [
        ("a.yaml", "image: [unclosed\n", "not valid YAML"),
        ("b.yaml", "resolution: 0.05\norigin: [0, 0, 0]\n", "`image`"),
        (
            "c.yaml",
            "image: missing.png\nresolution: 0.05\norigin: [0, 0, 0]\n",
            "missing.png",
        ),
        (
            "d.yaml",
            "image: ok.pgm\nresolution: .nan\norigin: [0, 0, 0]\n",
            "`resolution` = .nan",
        ),
        (
            "e.yaml",
            "image: ok.pgm\nresolution: -1\norigin: [0, 0, 0]\n",
            "`resolution` = -1",
        ),
        (
            "f.yaml",
            "image: ok.pgm\nresolution: 0.05\norigin: [0, .nan, 0]\n",
            "`origin`",
        ),
        (
            "g.yaml",
            "image: ok.pgm\norigin: [0, 0, 0]\n",
            "`resolution`",
        ),
        (
            "h.yaml",
            "image: ok.pgm\nresolution: 0.05\norigin: [0, 0, 0]\noccupied_thresh: 3\n",
            "`occupied_thresh` = 3",
        ),
        (
            "i.yaml",
            "image: ok.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nmode: weird\n",
            "`mode` = weird",
        ),
    ];
    for (file, yaml, needle) in cases {
        let msg = load_err(&dir, file, yaml).to_string();
        assert!(msg.contains(needle), "{file}: {msg:?} lacks {needle:?}");
        assert!(msg.contains(file) || msg.contains("missing.png"), "{msg}");
    }
    // An image that is not an image.
    std::fs::write(dir.join("junk.png"), b"not a png").unwrap();
    let msg = load_err(
        &dir,
        "j.yaml",
        "image: junk.png\nresolution: 0.05\norigin: [0, 0, 0]\n",
    )
    .to_string();
    assert!(msg.contains("junk.png"), "{msg}");
    // A missing YAML.
    let msg = Map::load(&dir.join("nope.yaml")).unwrap_err().to_string();
    assert!(msg.contains("nope.yaml"), "{msg}");
    // from_grid validation.
    let e = Map::from_grid("g", 2, 2, 0.1, Pose::default(), vec![false; 3]).unwrap_err();
    assert!(e.to_string().contains("`g`"), "{e}");
    let e = Map::from_grid("g", 2, 2, f64::NAN, Pose::default(), vec![false; 4]).unwrap_err();
    assert!(e.to_string().contains("resolution"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn ros_semantics_negate_and_image_orientation() {
    let dir = temp_dir("ros");
    // Top row (image) = [0, 100]; bottom row = [205, 254]. With occupied_thresh 0.65:
    // 0 -> p=1 occupied; 100 -> p=0.61 free; 205 unknown -> free; 254 free.
    write_pgm(&dir.join("m.pgm"), 2, 2, &[0, 100, 205, 254]);
    let yaml = dir.join("m.yaml");
    std::fs::write(
        &yaml,
        "image: m.pgm\nresolution: 1.0\norigin: [0.0, 0.0, 0.0]\nnegate: 0\n\
         occupied_thresh: 0.65\nfree_thresh: 0.196\n",
    )
    .unwrap();
    let m = Map::load(&yaml).unwrap();
    assert_eq!(m.name(), "m");
    // Row 0 of the grid = bottom row of the image.
    assert!(!m.cell_occupied(0, 0) && !m.cell_occupied(1, 0));
    assert!(m.cell_occupied(0, 1) && !m.cell_occupied(1, 1));
    assert!(
        !m.cell_occupied(-1, 0) && !m.cell_occupied(5, 5),
        "off-map is free"
    );
    let yaml_n = dir.join("n.yaml");
    std::fs::write(
        &yaml_n,
        "image: m.pgm\nresolution: 1.0\norigin: [0.0, 0.0, 0.0]\nnegate: 1\n\
         occupied_thresh: 0.65\nfree_thresh: 0.196\n",
    )
    .unwrap();
    let n = Map::load(&yaml_n).unwrap();
    // negate: p = v / 255 -> 205 (0.80) and 254 occupied, 0 and 100 free.
    assert!(n.cell_occupied(0, 0) && n.cell_occupied(1, 0));
    assert!(!n.cell_occupied(0, 1) && !n.cell_occupied(1, 1));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn origin_yaw_is_honoured() {
    // 10 x 4 cells of 0.5 m, one occupied cell at (col 6, row 1), map rotated by 90
    // degrees: grid +x points along world +y.
    let (w, h) = (10, 4);
    let mut g = vec![false; w * h];
    g[w + 6] = true;
    let yaw = std::f64::consts::FRAC_PI_2;
    let m = Map::from_grid("yawed", w, h, 0.5, Pose::new(2.0, -1.0, yaw), g).unwrap();
    // Cell (6, 1) centre in the map frame: (3.25, 0.75) -> world (2 - 0.75, -1 + 3.25).
    assert!(m.occupied_at(1.25, 2.25));
    assert!(!m.occupied_at(2.0 + 0.75, -1.0 + 3.25));
    let (gx, gy) = m.world_to_grid(1.25, 2.25);
    assert!(
        (gx - 6.5).abs() < 1e-9 && (gy - 1.5).abs() < 1e-9,
        "{gx} {gy}"
    );
    // A LIDAR at the map-frame point (1.0, 0.75) looking along the map's +x axis (world
    // +y) hits the cell's near side at map x = 3.0: range 2.0 m.
    let lidar = Lidar::new(LidarConfig {
        num_beams: 3,
        fov: 0.2,
        ..LidarConfig::default()
    });
    let (x, y) = m.grid_to_world(2.0, 1.5);
    let mut out = [0.0; 3];
    lidar.scan(&m, Pose::new(x, y, yaw), &[], &mut out);
    assert!((out[1] - 2.0).abs() < 1e-9, "{out:?}");
}

/// Rays per second of `scan` and `scan_reference` from centerline poses of real tracks
/// and of Paddock's shipped maps (`maps/`, in the repository).
/// `cargo test -p paddock-sim --release --test maps -- --ignored --nocapture`
#[test]
#[ignore = "measurement; run in release with --nocapture"]
fn lidar_throughput_on_tracks() {
    let Some(shared) = shared_dir() else { return };
    let lidar = Lidar::new(LidarConfig::default());
    let mut out = vec![0.0; 1080];
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut all = tracks(&shipped);
    all.extend(tracks(&shared));
    for (name, yaml, center) in all {
        if !["Spielberg", "Monza", "Silverstone", "Austin"].contains(&name.as_str())
            && !["lakeside", "harbour", "quarry"].contains(&name.as_str())
        {
            continue;
        }
        let map = Map::load(&yaml).unwrap();
        let _ = map.distance_field();
        let poses = centerline_poses(&centerline(&center));
        let mut sum = 0.0;
        // Best of 5 passes over the centerline (the first warms the caches).
        let mut time = |reference: bool| {
            let mut best = f64::INFINITY;
            for _ in 0..5 {
                let t0 = std::time::Instant::now();
                for p in &poses {
                    if reference {
                        lidar.scan_reference(&map, *p, &mut out);
                    } else {
                        lidar.scan(&map, *p, &[], &mut out);
                    }
                    sum += out.iter().sum::<f64>();
                }
                best = best.min(t0.elapsed().as_secs_f64());
            }
            (poses.len() * 1080) as f64 / best
        };
        let fast = time(false);
        let slow = time(true);
        eprintln!(
            "{name} ({} x {} @ {} m, {} poses): scan {:.1} M rays/s, scan_reference {:.1} M \
             rays/s (checksum {sum:.1})",
            map.width(),
            map.height(),
            map.resolution(),
            poses.len(),
            fast / 1e6,
            slow / 1e6
        );
    }
}
