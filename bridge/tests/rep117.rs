//! REP 117 on the car: Hokuyo-shaped scans (urg_node: 1081 beams over 270 degrees,
//! range_min 0.06 m, range_max 30 m) whose beams ahead say "too close" (`-inf`),
//! "invalid" (NaN) or carry Hokuyo error codes (values below range_min), in a corridor
//! with walls 0.5 m to either side. Each used to read as open road: the drive node kept
//! commanding 2-4 m/s. Now the car stops.

use paddock_bridge::drive::{DriveCore, DriverSpec};
use paddock_bridge::msg::{LaserScan, Odometry};
use paddock_bridge::safety::{Safety, SafetyConfig, StopReason};
use paddock_sim::circuit::Circuits;
use paddock_sim::lidar::LidarConfig;
use paddock_sim::params::VehicleParams;

const N: usize = 1081;

/// A corridor: walls `half` metres to each side, open (`+inf`, no return) ahead.
fn hokuyo_corridor(half: f32) -> LaserScan {
    let fov = 270f32.to_radians();
    let inc = fov / (N - 1) as f32;
    let ranges = (0..N)
        .map(|k| {
            let s = (-fov / 2.0 + k as f32 * inc).sin();
            if s.abs() < 1e-6 {
                f32::INFINITY
            } else {
                let r = half / s.abs();
                if r > 30.0 { f32::INFINITY } else { r }
            }
        })
        .collect();
    LaserScan {
        angle_min: -fov / 2.0,
        angle_max: fov / 2.0,
        angle_increment: inc,
        range_min: 0.06,
        range_max: 30.0,
        ranges,
        ..LaserScan::default()
    }
}

/// Overwrite the beams within `deg` degrees of straight ahead with `r`.
fn ahead(mut s: LaserScan, deg: f32, r: f32) -> LaserScan {
    for k in 0..N {
        let a = s.angle_min + k as f32 * s.angle_increment;
        if a.abs() <= deg.to_radians() {
            s.ranges[k] = r;
        }
    }
    s
}

fn moving(v: f64) -> Odometry {
    let mut o = Odometry::default();
    o.twist.twist.linear.x = v;
    o
}

fn gap_core() -> DriveCore {
    let circuit = Circuits::new().get("lakeside").unwrap();
    let d = DriverSpec::resolve("follow-the-gap", &[])
        .unwrap()
        .build(&circuit, &VehicleParams::default())
        .unwrap();
    let safety = SafetyConfig {
        max_speed: 4.0,
        ..SafetyConfig::default()
    };
    DriveCore::new(d, LidarConfig::default(), safety).unwrap()
}

/// The command after one odometry message at `v` and one scan.
fn command_for(scan: &LaserScan, v: f64) -> paddock_bridge::safety::Verdict {
    let mut c = gap_core();
    assert!(c.on_odom(&moving(v), 0.0));
    assert!(c.on_scan(scan, 0.0));
    c.command(0.01).unwrap()
}

#[test]
fn an_open_corridor_drives() {
    let v = command_for(&hokuyo_corridor(0.5), 3.0);
    assert_eq!(v.stop, None);
    assert!(v.action.speed >= 1.0, "{v:?}");
}

#[test]
fn too_close_returns_ahead_are_obstacles_at_range_min() {
    let scan = ahead(hokuyo_corridor(0.5), 10.0, f32::NEG_INFINITY);
    // TTC: range_min cos(angle) / v, smallest at the cone's 10 degree edge
    let ttc = Safety::time_to_collision(&scan, 3.0, 0.2);
    let edge = 0.06f32 as f64 * 10f64.to_radians().cos() / 3.0;
    assert!(ttc >= edge - 1e-4 && ttc <= 0.06f32 as f64 / 3.0, "{ttc}");
    let v = command_for(&scan, 3.0);
    assert!(
        matches!(v.stop, Some(StopReason::Emergency { .. })),
        "{v:?}"
    );
    assert_eq!(v.action.speed, 0.0);
}

#[test]
fn nan_or_error_codes_ahead_leave_the_car_blind_and_stopped() {
    for (what, r) in [
        ("NaN", f32::NAN),
        ("error code 0", 0.0),
        ("error code 17 mm", 0.017),
    ] {
        let scan = ahead(hokuyo_corridor(0.5), 10.0, r);
        assert_eq!(
            Safety::time_to_collision(&scan, 3.0, 0.2),
            f64::INFINITY,
            "{what}: invalid beams give no range"
        );
        let (invalid, beams) = Safety::invalid_ahead(&scan, 20f64.to_radians());
        assert!(
            invalid * 2 >= beams && beams > 100,
            "{what}: {invalid}/{beams}"
        );
        let v = command_for(&scan, 3.0);
        assert!(
            matches!(v.stop, Some(StopReason::BlindAhead { .. })),
            "{what}: {v:?}"
        );
        assert_eq!(v.action.speed, 0.0, "{what}");
    }
}

#[test]
fn a_few_invalid_beams_do_not_stop_the_car_and_a_good_scan_releases_it() {
    // a dark patch: 5 % of the cone ahead invalid
    let mut scan = hokuyo_corridor(0.5);
    let mid = N / 2;
    for r in &mut scan.ranges[mid - 4..mid + 4] {
        *r = f32::NAN;
    }
    let v = command_for(&scan, 3.0);
    assert_eq!(v.stop, None, "{v:?}");
    let mut c = gap_core();
    c.on_odom(&moving(1.0), 0.0);
    c.on_scan(&ahead(hokuyo_corridor(0.5), 30.0, f32::NAN), 0.0);
    assert!(matches!(
        c.command(0.01).unwrap().stop,
        Some(StopReason::BlindAhead { .. })
    ));
    c.on_odom(&moving(0.0), 0.02);
    c.on_scan(&hokuyo_corridor(0.5), 0.03);
    assert_eq!(c.command(0.04).unwrap().stop, None);
}

#[test]
fn the_driver_never_sees_open_road_where_the_scan_says_nothing() {
    // invalid beams everywhere but a 1 m return straight ahead: the driver sees 1 m all
    // round, not the 30 m it would have seen before
    let mut scan = hokuyo_corridor(0.5);
    for r in scan.ranges.iter_mut() {
        *r = f32::NAN;
    }
    scan.ranges[N / 2] = 1.0;
    let mut out = Vec::new();
    paddock_bridge::scan::conservative_ranges(&scan, 10.0, &mut out);
    assert!(out.iter().all(|&r| r == 1.0));
}
