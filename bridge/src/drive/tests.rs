use super::*;
use crate::msg::{Pose, PoseWithCovariance, Quaternion, Twist, TwistWithCovariance, Vector3};
use paddock_sim::circuit::Circuits;
use paddock_sim::params::VehicleParams;

fn scan(n: usize, fov: f32, r: f32) -> LaserScan {
    LaserScan {
        angle_min: -fov / 2.0,
        angle_max: fov / 2.0,
        angle_increment: fov / (n - 1) as f32,
        range_min: 0.02,
        range_max: 30.0,
        ranges: vec![r; n],
        ..LaserScan::default()
    }
}

fn odom(x: f64, yaw: f64, v: f64) -> Odometry {
    Odometry {
        pose: PoseWithCovariance {
            pose: Pose {
                position: crate::msg::Point { x, y: 0.0, z: 0.0 },
                orientation: Quaternion::from_yaw(yaw),
            },
            ..Default::default()
        },
        twist: TwistWithCovariance {
            twist: Twist {
                linear: Vector3 {
                    x: v,
                    ..Default::default()
                },
                ..Default::default()
            },
            ..Default::default()
        },
        ..Default::default()
    }
}

fn gap_core(safety: SafetyConfig) -> DriveCore {
    let circuit = Circuits::new().get("lakeside").unwrap();
    let spec = DriverSpec::resolve("follow-the-gap", &[]).unwrap();
    let d = spec.build(&circuit, &VehicleParams::default()).unwrap();
    DriveCore::new(d, LidarConfig::default(), safety).unwrap()
}

#[test]
fn core_waits_for_sensors_then_drives_then_stops_when_stale() {
    let mut c = gap_core(SafetyConfig {
        max_speed: 3.0,
        ..SafetyConfig::default()
    });
    assert!(c.lidar_driver());
    let v = c.command(0.0).unwrap();
    assert!(matches!(v.stop, Some(StopReason::StaleOdom { age: None })));
    assert!(c.on_odom(&odom(0.0, 0.0, 1.0), 0.0));
    assert!(c.on_scan(&scan(1080, 4.7, 8.0), 0.01));
    let v = c.command(0.02).unwrap();
    assert_eq!(v.stop, None);
    assert!(v.action.speed > 0.0 && v.action.speed <= 3.0, "{v:?}");
    // nothing new for 0.3 s: stale, zero speed
    let v = c.command(0.32).unwrap();
    assert!(
        matches!(v.stop, Some(StopReason::StaleOdom { .. })),
        "{v:?}"
    );
    assert_eq!(v.action.speed, 0.0);
    assert!(!c.on_odom(&odom(f64::NAN, 0.0, 1.0), 0.4));
}

#[test]
fn core_emergency_stops_on_a_close_wall_ahead() {
    let mut c = gap_core(SafetyConfig::default());
    c.on_odom(&odom(0.0, 0.0, 4.0), 0.0);
    let mut s = scan(1080, 4.7, 8.0);
    for r in &mut s.ranges[500..580] {
        *r = 0.6; // 0.15 s at 4 m/s
    }
    c.on_scan(&s, 0.0);
    let v = c.command(0.01).unwrap();
    assert!(
        matches!(v.stop, Some(StopReason::Emergency { .. })),
        "{v:?}"
    );
    assert_eq!(v.action.speed, 0.0);
}

#[test]
fn latency_summary_quantiles() {
    let s = LatencySummary::from_samples(&[0.001, 0.002, 0.003, 0.010]);
    assert_eq!(s.count, 4);
    assert!((s.mean_ms - 4.0).abs() < 1e-9);
    assert_eq!(s.max_ms, 10.0);
    assert_eq!(LatencySummary::from_samples(&[]).count, 0);
}
