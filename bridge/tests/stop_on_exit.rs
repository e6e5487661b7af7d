//! Every way out of the drive loop sends the zero-speed stop: here a driver that panics
//! mid-drive. The loop reports the failure as an error (naming the driver and the panic)
//! after sending zero speed, which a separate participant watching `/drive` sees last.
//! (The signals, SIGINT / SIGTERM / SIGHUP, are tested on the `paddock` binary against
//! Cyclone DDS: bridge/interop/test_stop_and_recordings.py.)

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread;
use std::time::{Duration, Instant};

use paddock_bridge::BridgeError;
use paddock_bridge::drive::{DriveCore, DriveOptions, run_drive};
use paddock_bridge::msg::{AckermannDriveStamped, Header, Odometry, Time};
use paddock_bridge::ros::{RosConfig, RosNode, publish, take_newest};
use paddock_bridge::safety::SafetyConfig;
use paddock_policy::{Driver, Sensors};
use paddock_sim::lidar::LidarConfig;
use paddock_sim::world::{Action, Observation};

/// Drives straight at 2 m/s, then panics on its `panic_at`-th action (as a driver with
/// an indexing bug would on an unexpected observation).
struct PanicsMidDrive {
    acts: u32,
    panic_at: u32,
}

impl Driver for PanicsMidDrive {
    fn name(&self) -> &'static str {
        "panics-mid-drive"
    }
    fn sensors(&self) -> Sensors {
        Sensors { lidar: false }
    }
    fn reset(&mut self) {
        self.acts = 0;
    }
    fn act(&mut self, _obs: &Observation, _me: usize) -> Action {
        self.acts += 1;
        if self.acts >= self.panic_at {
            let beams: Vec<f64> = Vec::new();
            // an out-of-bounds index: a real bug's panic, not a scripted error value
            let _ = beams[self.acts as usize];
        }
        Action::new(0.0, 2.0)
    }
}

#[test]
fn a_driver_panic_sends_zero_speed_and_ends_with_an_error_naming_it() {
    let ros = RosConfig {
        domain_id: 65,
        ..RosConfig::default()
    };
    let stop = Arc::new(AtomicBool::new(false));
    let drive = {
        let (ros, stop) = (ros.clone(), stop.clone());
        thread::spawn(move || {
            let options = DriveOptions {
                safety: SafetyConfig {
                    ttc_threshold: 0.0,
                    sensor_timeout: 1.0,
                    ..SafetyConfig::default()
                },
                ..DriveOptions::default()
            };
            let driver = Box::new(PanicsMidDrive {
                acts: 0,
                panic_at: 200,
            });
            let core = DriveCore::new(driver, LidarConfig::default(), options.safety).unwrap();
            run_drive(core, &ros, &options, &stop)
        })
    };
    let mut car = RosNode::new("car", &ros).unwrap();
    let odom_pub = car.publisher::<Odometry>("/odom").unwrap();
    let drive_sub = car.subscription::<AckermannDriveStamped>("/drive").unwrap();
    let mut seen: Vec<f32> = Vec::new();
    let t0 = Instant::now();
    while !drive.is_finished() && t0.elapsed() < Duration::from_secs(30) {
        let mut odom = Odometry {
            header: Header::new(Time::from_secs(1e9 + t0.elapsed().as_secs_f64()), "odom"),
            ..Odometry::default()
        };
        odom.twist.twist.linear.x = 2.0;
        publish(&odom_pub, "/odom", odom);
        thread::sleep(Duration::from_millis(10));
        while let Some((d, _)) = take_newest(&drive_sub, "/drive") {
            seen.push(d.drive.speed);
        }
    }
    stop.store(true, Ordering::Relaxed);
    let result = drive.join().expect("the panic is caught inside the loop");
    // late samples of the stop burst
    let t1 = Instant::now();
    while t1.elapsed() < Duration::from_millis(500) {
        while let Some((d, _)) = take_newest(&drive_sub, "/drive") {
            seen.push(d.drive.speed);
        }
        thread::sleep(Duration::from_millis(10));
    }
    match result {
        Err(BridgeError::Driver { driver, message }) => {
            assert_eq!(driver, "panics-mid-drive");
            assert!(message.contains("index out of bounds"), "{message}");
        }
        other => panic!("expected the driver's failure, got {other:?}"),
    }
    assert!(
        seen.contains(&2.0),
        "the car drove before the panic: {seen:?}"
    );
    assert_eq!(seen.last(), Some(&0.0), "last command seen: {seen:?}");
}
