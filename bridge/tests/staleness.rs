//! Staleness by header stamp as well as arrival: a sensor that keeps sending, on time,
//! messages whose data is old stops the car (by arrival alone it looked fresh).

use paddock_bridge::drive::{DriveCore, DriverSpec};
use paddock_bridge::msg::{Header, LaserScan, Odometry, Time};
use paddock_bridge::safety::{SafetyConfig, StopReason};
use paddock_sim::circuit::Circuits;
use paddock_sim::lidar::LidarConfig;
use paddock_sim::params::VehicleParams;

const EPOCH: f64 = 1.7e9;

fn scan(stamp: f64) -> LaserScan {
    let lidar = LidarConfig::default();
    let n = lidar.num_beams;
    LaserScan {
        header: Header::new(Time::from_secs(stamp), "laser"),
        angle_min: (-0.5 * lidar.fov) as f32,
        angle_max: (0.5 * lidar.fov) as f32,
        angle_increment: (lidar.fov / (n - 1) as f64) as f32,
        range_min: 0.06,
        range_max: 30.0,
        ranges: vec![8.0; n],
        ..LaserScan::default()
    }
}

fn odom(stamp: f64) -> Odometry {
    let mut o = Odometry {
        header: Header::new(Time::from_secs(stamp), "odom"),
        ..Odometry::default()
    };
    o.twist.twist.linear.x = 1.0;
    o
}

fn core() -> DriveCore {
    let circuit = Circuits::new().get("lakeside").unwrap();
    let d = DriverSpec::resolve("follow-the-gap", &[])
        .unwrap()
        .build(&circuit, &VehicleParams::default())
        .unwrap();
    DriveCore::new(d, LidarConfig::default(), SafetyConfig::default()).unwrap()
}

/// Fresh sensors at 40 Hz for 1 s (3 ms delay); returns the time of the last.
fn drive_fresh(c: &mut DriveCore) -> f64 {
    let mut t = 0.0;
    for k in 0..40 {
        t = k as f64 * 0.025;
        assert!(c.on_odom(&odom(EPOCH + t), t + 0.003));
        assert!(c.on_scan(&scan(EPOCH + t), t + 0.003));
        let v = c.command(t + 0.004).unwrap();
        assert_eq!(v.stop, None, "{v:?}");
    }
    t
}

#[test]
fn a_sensor_resending_its_last_messages_stops_the_car() {
    let mut c = core();
    let last = drive_fresh(&mut c);
    // the LIDAR and odometry drivers hang and re-send their last message, on time
    let mut stopped_at = None;
    for k in 1..40 {
        let t = last + k as f64 * 0.025;
        assert!(
            !c.on_odom(&odom(EPOCH + last), t + 0.003),
            "a re-send is refused"
        );
        assert!(!c.on_scan(&scan(EPOCH + last), t + 0.003));
        let v = c.command(t + 0.004).unwrap();
        if v.stop.is_some() && stopped_at.is_none() {
            assert!(
                matches!(v.stop, Some(StopReason::StaleOdom { .. })),
                "{v:?}"
            );
            assert_eq!(v.action.speed, 0.0);
            stopped_at = Some(t + 0.004 - last);
        }
    }
    // within the sensor timeout (0.25 s) and a command period of it
    let after = stopped_at.expect("the car stops");
    assert!(
        (0.25..0.3).contains(&after),
        "stopped {after} s after the last fresh data"
    );
}

#[test]
fn old_data_arriving_on_time_stops_the_car_at_once() {
    let mut c = core();
    let last = drive_fresh(&mut c);
    // the drivers stall for 0.6 s, then deliver what they buffered: stamps advancing,
    // on time by arrival, but the data is 0.55 s old
    let t = last + 0.6;
    let stamp = EPOCH + last + 0.05;
    assert!(c.on_odom(&odom(stamp), t + 0.003));
    assert!(c.on_scan(&scan(stamp), t + 0.003));
    let v = c.command(t + 0.004).unwrap();
    assert!(
        matches!(v.stop, Some(StopReason::StaleOdom { age: Some(a) }) if a > 0.4),
        "{v:?}"
    );
    // by arrival alone the same messages were fresh: with the stamp age off (drift 1)
    // the car would have driven on
    let mut off = {
        let circuit = Circuits::new().get("lakeside").unwrap();
        let d = DriverSpec::resolve("follow-the-gap", &[])
            .unwrap()
            .build(&circuit, &VehicleParams::default())
            .unwrap();
        let safety = SafetyConfig {
            max_clock_drift: 1.0,
            ..SafetyConfig::default()
        };
        DriveCore::new(d, LidarConfig::default(), safety).unwrap()
    };
    let last = drive_fresh(&mut off);
    let t = last + 0.6;
    assert!(off.on_odom(&odom(EPOCH + last + 0.05), t + 0.003));
    assert!(off.on_scan(&scan(EPOCH + last + 0.05), t + 0.003));
    assert_eq!(off.command(t + 0.004).unwrap().stop, None);
}
