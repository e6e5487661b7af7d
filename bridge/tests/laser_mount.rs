//! The laser's mount on the car, applied to the driver's view and to the TTC check: a
//! Hokuyo 0.27 m ahead of base_link (f1tenth_system), upright or upside down.

use paddock_bridge::drive::{DriveCore, DriverSpec};
use paddock_bridge::mount::LaserMount;
use paddock_bridge::msg::{LaserScan, Odometry};
use paddock_bridge::safety::{Safety, SafetyConfig, StopReason};
use paddock_sim::circuit::Circuits;
use paddock_sim::lidar::LidarConfig;
use paddock_sim::params::VehicleParams;

const N: usize = 1081;

/// A Hokuyo scan from a laser at `mount` in a corridor (walls `left` / `right` metres
/// to the sides of base_link's axis) closed by a wall `front` metres ahead of base_link.
fn scan_from(mount: &LaserMount, left: f64, right: f64, front: f64) -> LaserScan {
    let fov = 270f64.to_radians();
    let inc = fov / (N - 1) as f64;
    let ranges = (0..N)
        .map(|k| {
            let b = mount.beam_angle(-fov / 2.0 + k as f64 * inc);
            let (s, c) = (b.sin(), b.cos());
            let mut r = f64::INFINITY;
            if s > 1e-9 {
                r = r.min((left - mount.y) / s);
            }
            if s < -1e-9 {
                r = r.min((-right - mount.y) / s);
            }
            if c > 1e-9 {
                r = r.min((front - mount.x) / c);
            }
            if r > 30.0 { f32::INFINITY } else { r as f32 }
        })
        .collect();
    LaserScan {
        angle_min: (-fov / 2.0) as f32,
        angle_max: (fov / 2.0) as f32,
        angle_increment: inc as f32,
        range_min: 0.06,
        range_max: 30.0,
        ranges,
        ..LaserScan::default()
    }
}

fn gap_core(mount: LaserMount) -> DriveCore {
    let circuit = Circuits::new().get("lakeside").unwrap();
    let d = DriverSpec::resolve("follow-the-gap", &[])
        .unwrap()
        .build(&circuit, &VehicleParams::default())
        .unwrap();
    let mut c = DriveCore::new(d, LidarConfig::default(), SafetyConfig::default()).unwrap();
    c.set_laser_mount(mount).unwrap();
    c
}

fn steer_for(mount: LaserMount, left: f64, right: f64) -> f64 {
    let mut c = gap_core(mount);
    let mut o = Odometry::default();
    o.twist.twist.linear.x = 1.0;
    c.on_odom(&o, 0.0);
    c.on_scan(&scan_from(&mount, left, right, 20.0), 0.0);
    let v = c.command(0.01).unwrap();
    assert_eq!(v.stop, None, "{v:?}");
    v.action.steer
}

const UPRIGHT: LaserMount = LaserMount {
    x: 0.27,
    y: 0.0,
    yaw: 0.0,
    flipped: false,
};
const UPSIDE_DOWN: LaserMount = LaserMount {
    x: 0.27,
    y: 0.0,
    yaw: 0.0,
    flipped: true,
};

#[test]
fn an_upside_down_laser_steers_the_driver_the_same_way() {
    // an opening to the right: the gap follower turns right (negative steer)
    let at_base = steer_for(LaserMount::default(), 0.5, 3.0);
    assert!(at_base < -0.01, "{at_base}");
    let upright = steer_for(UPRIGHT, 0.5, 3.0);
    let flipped = steer_for(UPSIDE_DOWN, 0.5, 3.0);
    assert!(upright < -0.01 && flipped < -0.01, "{upright} {flipped}");
    assert!((upright - flipped).abs() < 0.02, "{upright} vs {flipped}");
    // unmirrored, the flipped scan would have turned the car left, into the wall
    let mut c = gap_core(LaserMount::default());
    let mut o = Odometry::default();
    o.twist.twist.linear.x = 1.0;
    c.on_odom(&o, 0.0);
    c.on_scan(&scan_from(&UPSIDE_DOWN, 0.5, 3.0, 20.0), 0.0);
    assert!(c.command(0.01).unwrap().action.steer > 0.01);
}

#[test]
fn ttc_is_measured_in_base_link_from_the_lasers_station() {
    // a wall 0.87 m ahead of base_link: 0.6 m ahead of the laser, 0.15 s at 4 m/s
    for mount in [UPRIGHT, UPSIDE_DOWN] {
        let scan = scan_from(&mount, 1.0, 1.0, 0.87);
        let ttc = Safety::time_to_collision_from(&mount, &scan, 4.0, 0.2);
        assert!((ttc - 0.15).abs() < 1e-3, "{mount:?}: {ttc}");
        let mut c = gap_core(mount);
        let mut o = Odometry::default();
        o.twist.twist.linear.x = 4.0;
        c.on_odom(&o, 0.0);
        c.on_scan(&scan, 0.0);
        let v = c.command(0.01).unwrap();
        assert!(
            matches!(v.stop, Some(StopReason::Emergency { .. })),
            "{v:?}"
        );
    }
    // an obstacle on the car's left only, 0.1 m beside its axis and 0.6 m ahead of the
    // laser: inside the 0.2 m corridor; a flipped laser reports it at negative angles
    let scan = scan_from(&UPSIDE_DOWN, 0.1, 3.0, 30.0);
    let ttc = Safety::time_to_collision_from(&UPSIDE_DOWN, &scan, 4.0, 0.2);
    assert!(ttc.is_finite() && ttc < 0.25, "{ttc}");
}

mod common;

/// The SIL car with a laser mount in its vehicle parameters publishes that mount on
/// /tf_static, which the drive node reads back as the same mount.
#[test]
fn the_sil_car_publishes_its_vehicle_laser_mount() {
    use paddock_bridge::msg::TFMessage;
    use paddock_bridge::ros::{Frames, RosConfig, RosNode, take_all};
    use paddock_bridge::sil::SilOptions;
    use paddock_sim::params::LaserMount as SimMount;
    use std::time::{Duration, Instant};

    let ros = RosConfig {
        domain_id: 66,
        frames: Frames::f1tenth_gym_ros(),
        ..RosConfig::default()
    };
    let vehicle = VehicleParams {
        laser_mount: Some(SimMount {
            x: 0.27,
            y: 0.01,
            yaw: 0.1,
            flipped: true,
        }),
        ..VehicleParams::default()
    };
    let sil = common::SilThread::start(
        SilOptions {
            map: "lakeside".into(),
            seconds: Some(30.0),
            vehicle,
            ..SilOptions::default()
        },
        &ros,
    );
    let mut node = RosNode::new("tf_static_listener", &ros).unwrap();
    let sub = node.static_subscription::<TFMessage>("/tf_static").unwrap();
    let t0 = Instant::now();
    let mut got = Vec::new();
    while got.is_empty() && t0.elapsed() < Duration::from_secs(10) {
        got = take_all(&sub, "/tf_static");
        std::thread::sleep(Duration::from_millis(20));
    }
    sil.stop();
    let t = &got.last().expect("a /tf_static message").transforms[0];
    assert_eq!(t.header.frame_id, "ego_racecar/base_link");
    let m = LaserMount::from_transform(&t.transform).unwrap();
    assert!(
        (m.x - 0.27).abs() < 1e-12 && (m.y - 0.01).abs() < 1e-12 && (m.yaw - 0.1).abs() < 1e-9,
        "{m:?}"
    );
    assert!(m.flipped);
}
