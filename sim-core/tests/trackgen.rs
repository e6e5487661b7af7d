//! The track generator: determinism, geometric guarantees, the raceline, config errors,
//! and that the shipped maps are exactly what the generator makes of their seeds.

use std::path::{Path, PathBuf};

use paddock_sim::trackgen::{
    self, CENTERLINE_SPACING, GeneratedTrack, RACELINE_SPACING, SpeedLimits, TrackGenConfig,
    TrackGenError,
};

/// The maps in `maps/`: (name, seed, length). maps/README.md documents the same.
const SHIPPED: [(&str, u64, f64); 3] = [
    ("lakeside", 66, 140.0),
    ("quarry", 34, 230.0),
    ("harbour", 52, 105.0),
];

const FILES: [&str; 4] = ["map.yaml", "map.png", "centerline.csv", "raceline.csv"];

fn config(seed: u64, length_m: f64) -> TrackGenConfig {
    TrackGenConfig {
        seed,
        length_m,
        ..TrackGenConfig::default()
    }
}

/// A fresh scratch folder under the system temp dir, removed on drop.
struct Scratch(PathBuf);

impl Scratch {
    fn new(tag: &str) -> Self {
        let dir = std::env::temp_dir().join(format!(
            "paddock-trackgen-test-{}-{tag}",
            std::process::id()
        ));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn read_all(folder: &Path, name: &str) -> Vec<Vec<u8>> {
    FILES
        .iter()
        .map(|f| std::fs::read(folder.join(format!("{name}_{f}"))).unwrap())
        .collect()
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}

#[test]
fn same_config_gives_identical_files() {
    let scratch = Scratch::new("determinism");
    let cfg = config(7, 100.0);
    let a = trackgen::generate(&cfg).unwrap();
    let b = trackgen::generate(&cfg).unwrap();
    let fa = a.write(&scratch.0.join("a"), "t").unwrap();
    let fb = b.write(&scratch.0.join("b"), "t").unwrap();
    assert_eq!(fa, scratch.0.join("a").join("t"));
    assert_eq!(read_all(&fa, "t"), read_all(&fb, "t"));

    let other = trackgen::generate(&config(8, 100.0)).unwrap();
    assert_ne!(a.centerline, other.centerline);
}

#[test]
fn written_files_follow_the_racetracks_layout() {
    let scratch = Scratch::new("layout");
    let track = trackgen::generate(&config(3, 80.0)).unwrap();
    let folder = track.write(&scratch.0, "demo").unwrap();
    let yaml = std::fs::read_to_string(folder.join("demo_map.yaml")).unwrap();
    assert!(yaml.starts_with("image: demo_map.png\nresolution: 0.05\norigin: ["));
    assert!(yaml.contains("negate: 0\noccupied_thresh: 0.45\nfree_thresh: 0.196\n"));
    let origin: Vec<f64> = yaml
        .lines()
        .find_map(|l| l.strip_prefix("origin: ["))
        .unwrap()
        .trim_end_matches(']')
        .split(',')
        .map(|v| v.trim().parse().unwrap())
        .collect();
    assert_eq!(origin, track.origin.to_vec());

    let png = image::open(folder.join("demo_map.png")).unwrap();
    assert!(matches!(png, image::DynamicImage::ImageLuma8(_)));
    let grey = png.to_luma8();
    assert_eq!(
        grey.dimensions(),
        (track.occupancy.width, track.occupancy.height)
    );
    assert_eq!(grey.as_raw(), &track.occupancy.pixels);

    let center = std::fs::read_to_string(folder.join("demo_centerline.csv")).unwrap();
    let mut lines = center.lines();
    assert_eq!(lines.next(), Some("# x_m, y_m, w_tr_right_m, w_tr_left_m"));
    assert_eq!(lines.clone().count(), track.centerline.len());
    for line in lines {
        let fields: Vec<f64> = line.split(", ").map(|v| v.parse().unwrap()).collect();
        assert_eq!(fields.len(), 4);
    }

    let race = std::fs::read_to_string(folder.join("demo_raceline.csv")).unwrap();
    let header: Vec<&str> = race.lines().take_while(|l| l.starts_with('#')).collect();
    assert_eq!(
        header.last(),
        Some(&"# s_m; x_m; y_m; psi_rad; kappa_radpm; vx_mps; ax_mps2")
    );
    let rows: Vec<Vec<f64>> = race
        .lines()
        .skip(header.len())
        .map(|l| l.split(';').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), track.raceline.len());
    assert!(rows.iter().all(|r| r.len() == 7));

    assert!(track.write(&scratch.0, "../escape").is_err());
}

/// Segments (a, b) of the closed polyline `pts`.
fn segments(pts: &[[f64; 2]]) -> Vec<([f64; 2], [f64; 2])> {
    (0..pts.len())
        .map(|i| (pts[i], pts[(i + 1) % pts.len()]))
        .collect()
}

fn cross(o: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])
}

fn segments_cross(p: ([f64; 2], [f64; 2]), q: ([f64; 2], [f64; 2])) -> bool {
    let d1 = cross(q.0, q.1, p.0);
    let d2 = cross(q.0, q.1, p.1);
    let d3 = cross(p.0, p.1, q.0);
    let d4 = cross(p.0, p.1, q.1);
    d1 * d2 < 0.0 && d3 * d4 < 0.0
}

/// The corridor's left and right edges.
fn edges(track: &GeneratedTrack) -> (Vec<[f64; 2]>, Vec<[f64; 2]>) {
    let c = &track.centerline;
    let n = c.len();
    let mut left = Vec::with_capacity(n);
    let mut right = Vec::with_capacity(n);
    for i in 0..n {
        let (a, b) = (c[(i + n - 1) % n], c[(i + 1) % n]);
        let (tx, ty) = (b[0] - a[0], b[1] - a[1]);
        let len = (tx * tx + ty * ty).sqrt();
        let (nx, ny) = (-ty / len, tx / len);
        left.push([c[i][0] + c[i][3] * nx, c[i][1] + c[i][3] * ny]);
        right.push([c[i][0] - c[i][2] * nx, c[i][1] - c[i][2] * ny]);
    }
    (left, right)
}

/// Checks every guarantee the generator makes about one track.
fn check_track(track: &GeneratedTrack, cfg: &TrackGenConfig) {
    let c = &track.centerline;
    let n = c.len();
    let xy: Vec<[f64; 2]> = c.iter().map(|p| [p[0], p[1]]).collect();

    // Closed, uniform, about the requested length, starting at the origin heading +x.
    for i in 0..n {
        let d = dist(xy[i], xy[(i + 1) % n]);
        assert!((d - CENTERLINE_SPACING).abs() < 0.01, "spacing {d} at {i}");
    }
    assert!((track.length_m - cfg.length_m).abs() < 0.01 * cfg.length_m);
    assert!(dist(xy[0], [0.0, 0.0]) < 1e-9);
    assert!(xy[1][1].abs() < 1e-3 && xy[1][0] > 0.0);

    // Width within bounds.
    for p in c {
        let w = p[2] + p[3];
        assert!(
            w >= cfg.width_min - 1e-9 && w <= cfg.width_max + 1e-9,
            "width {w}"
        );
    }

    // Radius of curvature (circle through neighbours) never below the minimum.
    let mut min_r = f64::INFINITY;
    for i in 0..n {
        let (a, b, d) = (xy[(i + n - 1) % n], xy[i], xy[(i + 1) % n]);
        let k = 2.0 * cross(a, b, d).abs() / (dist(a, b) * dist(b, d) * dist(a, d));
        min_r = min_r.min(1.0 / k);
    }
    assert!(min_r >= cfg.min_radius_m, "min radius {min_r}");
    assert!((min_r - track.min_radius_m).abs() < 1e-6);

    // Neither edge crosses itself or the other (no overlapping corridor).
    let (left, right) = edges(track);
    let every = 2;
    let l: Vec<[f64; 2]> = left.iter().step_by(every).copied().collect();
    let r: Vec<[f64; 2]> = right.iter().step_by(every).copied().collect();
    let (sl, sr) = (segments(&l), segments(&r));
    let m = sl.len();
    for i in 0..m {
        for j in i + 2..m {
            if (j + 1) % m == i {
                continue;
            }
            assert!(!segments_cross(sl[i], sl[j]), "left edge crosses itself");
            assert!(!segments_cross(sr[i], sr[j]), "right edge crosses itself");
        }
        for sj in &sr {
            assert!(!segments_cross(sl[i], *sj), "left edge crosses right edge");
        }
    }

    // The centerline lies in free cells; just outside each edge is occupied.
    for (i, p) in c.iter().enumerate() {
        assert!(track.is_free(p[0], p[1]), "centerline point {i} not free");
    }
    for i in (0..n).step_by(5) {
        let (a, b) = (xy[(i + n - 1) % n], xy[(i + 1) % n]);
        let len = dist(a, b);
        let (nx, ny) = (-(b[1] - a[1]) / len, (b[0] - a[0]) / len);
        let out = 0.2;
        let pl = [
            xy[i][0] + (c[i][3] + out) * nx,
            xy[i][1] + (c[i][3] + out) * ny,
        ];
        let pr = [
            xy[i][0] - (c[i][2] + out) * nx,
            xy[i][1] - (c[i][2] + out) * ny,
        ];
        assert!(!track.is_free(pl[0], pl[1]), "left of {i} should be wall");
        assert!(!track.is_free(pr[0], pr[1]), "right of {i} should be wall");
    }
    // The occupied margin around the track.
    let img = &track.occupancy;
    let border = (cfg.margin_m / cfg.resolution) as u32 - 1;
    for row in 0..img.height {
        for col in 0..img.width {
            if row < border
                || col < border
                || row >= img.height - border
                || col >= img.width - border
            {
                assert_eq!(
                    img.pixels[(row * img.width + col) as usize],
                    trackgen::OCCUPIED
                );
            }
        }
    }

    check_raceline(track, cfg, &xy);
}

fn check_raceline(track: &GeneratedTrack, cfg: &TrackGenConfig, xy: &[[f64; 2]]) {
    let c = &track.centerline;
    let rl = &track.raceline;
    let k = rl.len();
    let limits = SpeedLimits::default();
    assert_eq!(rl[0].s, 0.0);
    for i in 0..k {
        let p = rl[i];
        let q = rl[(i + 1) % k];
        let ds = dist([p.x, p.y], [q.x, q.y]);
        assert!(
            (ds - RACELINE_SPACING).abs() < 0.02,
            "raceline spacing {ds} at {i}"
        );
        if i + 1 < k {
            assert!((q.s - p.s - ds).abs() < 1e-9);
        }
        assert!((0.0..std::f64::consts::TAU).contains(&p.psi));
        // Heading agrees with the direction of travel.
        let dir = (q.y - p.y).atan2(q.x - p.x);
        let diff = (dir - p.psi).rem_euclid(std::f64::consts::TAU);
        assert!(diff.min(std::f64::consts::TAU - diff) < 0.1, "psi at {i}");
        // Speed: lateral limit, cap, and ax consistent with the profile.
        assert!(p.vx > 0.0 && p.vx <= limits.v_max + 1e-12);
        assert!(
            p.vx * p.vx * p.kappa.abs() <= limits.lateral_accel() * (1.0 + 1e-9),
            "lateral acceleration at {i}"
        );
        let ax = (q.vx * q.vx - p.vx * p.vx) / (2.0 * ds);
        assert!((ax - p.ax).abs() < 1e-6);
        assert!(p.ax <= limits.accel + 1e-9 && p.ax >= -limits.brake - 1e-9);

        // Inside the corridor with the margin: lateral offset from the nearest
        // centerline point, along its normal.
        let j = (0..xy.len())
            .min_by(|&a, &b| dist(xy[a], [p.x, p.y]).total_cmp(&dist(xy[b], [p.x, p.y])))
            .unwrap();
        let n = xy.len();
        let (a, b) = (xy[(j + n - 1) % n], xy[(j + 1) % n]);
        let len = dist(a, b);
        let (nx, ny) = (-(b[1] - a[1]) / len, (b[0] - a[0]) / len);
        let offset = (p.x - xy[j][0]) * nx + (p.y - xy[j][1]) * ny;
        let margin = cfg.raceline_margin_m - 1e-3;
        assert!(
            offset <= c[j][3] - margin && -offset <= c[j][2] - margin,
            "raceline point {i} offset {offset} outside corridor (w {} {})",
            c[j][2],
            c[j][3]
        );
    }
    // The raceline turns once around, counter-clockwise, like the centerline.
    let turning: f64 = rl.iter().map(|p| p.kappa * RACELINE_SPACING).sum();
    assert!(
        (turning - std::f64::consts::TAU).abs() < 0.2,
        "total turning {turning}"
    );
}

#[test]
fn generated_tracks_keep_every_guarantee() {
    for (seed, length) in [(1, 40.0), (2, 120.0), (5, 300.0)] {
        let cfg = config(seed, length);
        let track = trackgen::generate(&cfg).unwrap();
        check_track(&track, &cfg);
    }
}

#[test]
fn narrow_and_coarse_tracks_keep_every_guarantee() {
    let cfg = TrackGenConfig {
        seed: 11,
        length_m: 90.0,
        width_min: 1.5,
        width_max: 2.5,
        resolution: 0.1,
        ..TrackGenConfig::default()
    };
    let track = trackgen::generate(&cfg).unwrap();
    check_track(&track, &cfg);
}

fn invalid(cfg: TrackGenConfig) -> String {
    match trackgen::generate(&cfg) {
        Err(e @ TrackGenError::InvalidConfig { .. }) => e.to_string(),
        other => panic!("expected a config error, got {other:?}"),
    }
}

#[test]
fn bad_configs_are_rejected_naming_field_and_value() {
    let base = TrackGenConfig::default();
    let msg = invalid(TrackGenConfig {
        length_m: f64::NAN,
        ..base.clone()
    });
    assert!(msg.contains("length_m") && msg.contains("NaN"), "{msg}");
    let msg = invalid(TrackGenConfig {
        length_m: 20.0,
        ..base.clone()
    });
    assert!(msg.contains("length_m = 20"), "{msg}");
    let msg = invalid(TrackGenConfig {
        length_m: 700.0,
        ..base.clone()
    });
    assert!(msg.contains("length_m = 700"), "{msg}");
    let msg = invalid(TrackGenConfig {
        width_min: 5.0,
        width_max: 4.0,
        ..base.clone()
    });
    assert!(
        msg.contains("width_min = 5") && msg.contains("width_max"),
        "{msg}"
    );
    let msg = invalid(TrackGenConfig {
        resolution: 0.0,
        ..base.clone()
    });
    assert!(msg.contains("resolution = 0"), "{msg}");
    let msg = invalid(TrackGenConfig {
        width_max: f64::INFINITY,
        ..base.clone()
    });
    assert!(msg.contains("width_max = inf"), "{msg}");
    let msg = invalid(TrackGenConfig {
        max_attempts: 0,
        ..base
    });
    assert!(msg.contains("max_attempts"), "{msg}");
}

#[test]
fn config_reads_from_yaml_with_defaults() {
    let cfg: TrackGenConfig = serde_norway::from_str("seed: 9\nlength_m: 150\n").unwrap();
    assert_eq!(cfg, config(9, 150.0));
    assert!(serde_norway::from_str::<TrackGenConfig>("lenght_m: 150\n").is_err());
}

/// The shipped maps are exactly what the generator makes of their documented seeds.
/// Run with PADDOCK_REGENERATE_MAPS=1 to rewrite them after a deliberate change to the
/// generator (and bump `GENERATOR_VERSION`).
#[test]
fn shipped_maps_match_the_generator() {
    let maps = Path::new(env!("CARGO_MANIFEST_DIR")).join("../maps");
    let readme = std::fs::read_to_string(maps.join("README.md")).unwrap();
    let regenerate = std::env::var_os("PADDOCK_REGENERATE_MAPS").is_some();
    let scratch = Scratch::new("shipped");
    for (name, seed, length) in SHIPPED {
        let command =
            format!("paddock maps generate --seed {seed} --length {length} --name {name}");
        assert!(readme.contains(&command), "README lacks `{command}`");
        let track = trackgen::generate(&config(seed, length)).unwrap();
        if regenerate {
            track.write(&maps, name).unwrap();
        }
        let fresh = track.write(&scratch.0, name).unwrap();
        let shipped = read_all(&maps.join(name), name);
        for (file, (a, b)) in FILES
            .iter()
            .zip(read_all(&fresh, name).iter().zip(&shipped))
        {
            assert!(
                a == b,
                "maps/{name}/{name}_{file} differs from the generator's output"
            );
        }
    }
}
