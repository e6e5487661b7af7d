//! A Paddock driver on the car: `/scan` + `/odom` in, `/drive` out.
//!
//! [`DriveCore`] is the sans-IO heart: it turns the newest scan and odometry into the
//! one-car [`Observation`] a driver reads, asks the driver for an action and passes it
//! through the [`Safety`] layer. [`run_drive`] is the ROS loop around it.
//!
//! - The car's pose comes from `/odom` (position and yaw of the pose, body velocity and
//!   yaw rate of the twist). Map-based drivers (pure pursuit, lattice, MLP) need that pose
//!   in the map frame: on the car, feed `/odom` from a localiser (particle filter, SLAM
//!   in localisation mode) or remap the localiser's odometry onto the odom topic; the SIL
//!   car publishes map-frame odometry.
//! - The steering angle a driver may read is the last steering command sent (the car does
//!   not measure it).
//! - Scans are resampled to the beam layout the driver was built for (the simulator's
//!   [`LidarConfig`]: 1080 beams over 4.7 rad by default) by nearest angle, read with
//!   REP 117's semantics ([`crate::scan`]): no return (`+inf`) as max range, too close
//!   (`-inf`) as `range_min`, an invalid beam (NaN, an error code) as the nearer of its
//!   nearest known neighbours, never as open road.
//! - A LIDAR driver acts on every new scan, a pose driver on every new odometry message,
//!   so the loop follows the sensors' clock (and a faster-than-real-time SIL car). A
//!   command is also sent at least every `1 / rate_hz` seconds, so the stale-sensor stop
//!   reaches the car even when the sensors fall silent.
//! - Latency is the time from the triggering message's arrival to the command's publish.

use std::cell::Cell;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use paddock_policy::Driver;
use paddock_sim::lidar::LidarConfig;
use paddock_sim::world::{Action, Observation};

use crate::BridgeError;
pub use crate::driver_spec::DriverSpec;
use crate::freshness::{Freshness, SensorClock};
use crate::mount::LaserMount;
use crate::msg::{
    AckermannDrive, AckermannDriveStamped, Header, LaserScan, Odometry, TFMessage, Time,
};
use crate::ros::{RosConfig, RosNode, publish, take_all, take_newest};
use crate::safety::{Safety, SafetyConfig, SafetyCounters, StopReason, Verdict};
use crate::scan::{ScanAdapter, check_limits};

/// The driver, its view of the car, and the safety layer; no I/O.
pub struct DriveCore {
    driver: Box<dyn Driver>,
    lidar_driver: bool,
    lidar: LidarConfig,
    safety: Safety,
    adapter: Option<ScanAdapter>,
    /// Where the car's laser sits (default: where the driver's does).
    mount: LaserMount,
    obs: Observation,
    scan_clock: SensorClock,
    odom_clock: SensorClock,
    speed: f64,
    last: Option<StopReason>,
    /// The driver's fault was logged (an ONNX model's non-finite action: the driver
    /// returns the stop action from then on).
    fault_logged: bool,
}

impl DriveCore {
    /// `lidar` is the scan layout the driver expects (the one it was tuned with).
    pub fn new(
        mut driver: Box<dyn Driver>,
        lidar: LidarConfig,
        safety: SafetyConfig,
    ) -> Result<Self, BridgeError> {
        if lidar.num_beams == 0 || !(lidar.fov > 0.0 && lidar.max_range > 0.0) {
            return Err(BridgeError::config(
                "lidar",
                format!("{lidar:?}"),
                "needs num_beams >= 1, fov > 0 and max_range > 0",
            ));
        }
        driver.reset();
        let lidar_driver = driver.sensors().lidar;
        let obs = Observation::one_car(vec![lidar.max_range; lidar.num_beams]);
        let drift = safety.max_clock_drift;
        let mount = LaserMount::ahead(lidar.mount_offset);
        let mut safety = Safety::new(safety)?;
        safety.set_mount(mount);
        Ok(Self {
            driver,
            lidar_driver,
            lidar,
            safety,
            adapter: None,
            mount,
            obs,
            scan_clock: SensorClock::new(drift),
            odom_clock: SensorClock::new(drift),
            speed: 0.0,
            last: None,
            fault_logged: false,
        })
    }

    /// Does the driver read the scan (and so act on every new scan)?
    pub fn lidar_driver(&self) -> bool {
        self.lidar_driver
    }

    pub fn driver_name(&self) -> &'static str {
        self.driver.name()
    }

    pub fn safety(&self) -> &Safety {
        &self.safety
    }

    /// Why the driver can no longer drive (an ONNX model's non-finite action), if it
    /// cannot: it then asks for the stop action on every command.
    pub fn fault(&self) -> Option<&str> {
        self.driver.fault()
    }

    /// Where the car's laser sits: scans are re-projected to the driver's laser, and the
    /// safety layer measures from `base_link`.
    pub fn set_laser_mount(&mut self, mount: LaserMount) -> Result<(), BridgeError> {
        mount
            .validate()
            .map_err(|e| BridgeError::config("laser mount", format!("{mount:?}"), &e))?;
        if mount != self.mount {
            self.mount = mount;
            self.adapter = None;
            self.safety.set_mount(mount);
        }
        Ok(())
    }

    pub fn laser_mount(&self) -> LaserMount {
        self.mount
    }

    /// Take a scan that arrived at `now`. A scan with unusable geometry, or one whose
    /// stamp is not newer than the last (a re-send), is dropped (and logged); the
    /// previous one then ages towards the stale-sensor stop.
    pub fn on_scan(&mut self, scan: &LaserScan, now: f64) -> bool {
        if let Err(e) = check_limits(scan) {
            tracing::warn!(error = %e, "dropping scan");
            return false;
        }
        if !fresh(&mut self.scan_clock, scan.header.stamp, now, "scan") {
            return false;
        }
        if self.adapter.as_ref().is_none_or(|a| !a.fits(scan)) {
            match ScanAdapter::mounted(scan, &self.lidar, &self.mount) {
                Ok(a) => self.adapter = Some(a),
                Err(e) => {
                    tracing::warn!(error = %e, "dropping scan");
                    return false;
                }
            }
        }
        if let Some(a) = &mut self.adapter {
            a.apply(scan, self.lidar.max_range, &mut self.obs.scans);
        }
        self.safety.on_scan(scan, self.speed, now);
        true
    }

    /// Take odometry that arrived at `now`; a message with non-finite numbers, or not
    /// newer than the last, is dropped.
    pub fn on_odom(&mut self, odom: &Odometry, now: f64) -> bool {
        let p = &odom.pose.pose;
        let t = &odom.twist.twist;
        let yaw = p.orientation.yaw();
        let values = [
            p.position.x,
            p.position.y,
            yaw,
            t.linear.x,
            t.linear.y,
            t.angular.z,
        ];
        if !values.iter().all(|v| v.is_finite()) {
            tracing::warn!(?values, "dropping odometry with non-finite values");
            return false;
        }
        if !fresh(&mut self.odom_clock, odom.header.stamp, now, "odometry") {
            return false;
        }
        let o = &mut self.obs;
        o.poses_x[0] = p.position.x;
        o.poses_y[0] = p.position.y;
        o.poses_theta[0] = yaw;
        o.linear_vels_x[0] = t.linear.x;
        o.linear_vels_y[0] = t.linear.y;
        o.ang_vels_z[0] = t.angular.z;
        o.slip_angles[0] = if t.linear.x.abs() > 0.1 {
            libm::atan2(t.linear.y, t.linear.x)
        } else {
            0.0
        };
        self.speed = t.linear.x;
        true
    }

    /// The command to send at `now`; an error when the driver panics (the caller then
    /// stops the car and ends: a driver that panicked once is not trusted again).
    pub fn command(&mut self, now: f64) -> Result<Verdict, BridgeError> {
        let (scan_age, odom_age) = (self.scan_clock.age(now), self.odom_clock.age(now));
        let ready = odom_age.is_some() && (!self.lidar_driver || scan_age.is_some());
        let requested = if ready {
            let (driver, obs) = (&mut self.driver, &self.obs);
            catch_unwind(AssertUnwindSafe(|| driver.act(obs, 0))).map_err(|panic| {
                let message = panic
                    .downcast_ref::<&str>()
                    .map(|s| s.to_string())
                    .or_else(|| panic.downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "panicked".to_string());
                BridgeError::Driver {
                    driver: self.driver.name().to_string(),
                    message: format!("panicked: {message}"),
                }
            })?
        } else {
            Action::default()
        };
        if !self.fault_logged
            && let Some(fault) = self.driver.fault()
        {
            tracing::error!(%fault, "the driver faulted: the car is held stopped");
            self.fault_logged = true;
        }
        let needs_scan = self.lidar_driver || self.safety.needs_scan();
        let verdict = self
            .safety
            .filter(requested, scan_age, odom_age, needs_scan);
        self.obs.steering_angles[0] = verdict.action.steer;
        match (&self.last, &verdict.stop) {
            (None, Some(r)) => tracing::warn!(reason = %r, "stopping the car"),
            (Some(_), None) => tracing::info!("driving"),
            _ => {}
        }
        self.last = verdict.stop;
        Ok(verdict)
    }
}

/// Let `clock` judge a message stamped `stamp` arriving at `now`; log a refusal.
fn fresh(clock: &mut SensorClock, stamp: Time, now: f64, what: &str) -> bool {
    let secs = if stamp.is_zero() {
        0.0
    } else {
        stamp.as_secs()
    };
    match clock.on_message(secs, now) {
        Freshness::Accepted => true,
        Freshness::NotNewer { behind } => {
            tracing::warn!(
                sensor = what,
                behind_s = behind,
                "dropping a message not newer than the last (re-sent?)"
            );
            false
        }
    }
}

/// Settings of the drive loop.
#[derive(Debug, Clone, PartialEq)]
pub struct DriveOptions {
    /// Least rate at which commands go out, Hz.
    pub rate_hz: f64,
    /// Stop after this many seconds (None: until stopped).
    pub seconds: Option<f64>,
    pub lidar: LidarConfig,
    pub safety: SafetyConfig,
    /// The laser's mount on the car; None: from `/tf_static` (`frames.base` -> the
    /// laser frame) once a transform arrives, the driver's laser position until then.
    pub laser_mount: Option<LaserMount>,
}

impl Default for DriveOptions {
    fn default() -> Self {
        Self {
            rate_hz: 40.0,
            seconds: None,
            lidar: LidarConfig::default(),
            safety: SafetyConfig::default(),
            laser_mount: None,
        }
    }
}

/// Scan-to-command (or odometry-to-command) latency figures, milliseconds.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct LatencySummary {
    pub count: usize,
    pub mean_ms: f64,
    pub p50_ms: f64,
    pub p99_ms: f64,
    pub max_ms: f64,
}

impl LatencySummary {
    pub fn from_samples(samples_s: &[f64]) -> Self {
        if samples_s.is_empty() {
            return Self::default();
        }
        let mut v: Vec<f64> = samples_s.iter().map(|s| s * 1e3).collect();
        v.sort_by(f64::total_cmp);
        let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize];
        Self {
            count: v.len(),
            mean_ms: v.iter().sum::<f64>() / v.len() as f64,
            p50_ms: q(0.5),
            p99_ms: q(0.99),
            max_ms: v[v.len() - 1],
        }
    }
}

/// What a drive run did.
#[derive(Debug, Clone, PartialEq)]
pub struct DriveSummary {
    pub driver: String,
    /// "scan" or "odom": the message whose arrival triggers a command.
    pub trigger: &'static str,
    pub commands: u64,
    pub scans: u64,
    pub odoms: u64,
    pub duration_s: f64,
    /// From the triggering message's arrival (taken off the DDS queue) to the publish.
    pub latency: LatencySummary,
    /// From the triggering message's DDS source timestamp (its publisher's wall clock:
    /// meaningful when sensor driver and bridge share a host clock) to the publish.
    pub end_to_end: LatencySummary,
    pub safety: SafetyCounters,
    /// The laser mount in use at the end, and where it came from ("flags",
    /// "/tf_static", or "default": the driver's laser position).
    pub laser_mount: LaserMount,
    pub laser_mount_source: &'static str,
    /// The driver's fault, when it faulted (an ONNX model's non-finite action): the car
    /// was held stopped from then on.
    pub fault: Option<String>,
}

fn epoch_ns() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos() as i64)
        .unwrap_or(0)
}

fn wall_clock_stamp() -> Time {
    Time::from_secs(epoch_ns() as f64 * 1e-9)
}

/// Sends zero speed (five times, 10 ms apart, so that a lossy link still delivers it)
/// when dropped: on the normal end of the loop, on an error return and while unwinding
/// from a panic, so no way out of [`run_drive`] leaves the last command in place.
struct ZeroSpeedOnExit<F: Fn(&Verdict) -> bool> {
    send: F,
}

impl<F: Fn(&Verdict) -> bool> Drop for ZeroSpeedOnExit<F> {
    fn drop(&mut self) {
        let halt = Verdict {
            action: Action::new(0.0, 0.0),
            stop: None,
            clamped: false,
        };
        for _ in 0..5 {
            (self.send)(&halt);
            std::thread::sleep(Duration::from_millis(10));
        }
        // a reliable writer repeats unacknowledged samples: give it a moment before the
        // participant goes away
        std::thread::sleep(Duration::from_millis(50));
        tracing::info!("zero speed sent");
    }
}

/// Run `core` as a ROS 2 node until `stop` is set (a signal) or `options.seconds` pass.
/// Every way out sends zero speed first: the normal end, an error (the driver panicked:
/// [`BridgeError::Driver`]) and a panic in the loop itself.
pub fn run_drive(
    mut core: DriveCore,
    ros: &RosConfig,
    options: &DriveOptions,
    stop: &AtomicBool,
) -> Result<DriveSummary, BridgeError> {
    if !(options.rate_hz.is_finite() && options.rate_hz >= 1.0 && options.rate_hz <= 1000.0) {
        return Err(BridgeError::config(
            "rate_hz",
            options.rate_hz,
            "must be in [1, 1000] Hz",
        ));
    }
    let mut node = RosNode::new("paddock_drive", ros)?;
    let topics = ros.topics.clone();
    let scan_sub = node.subscription::<LaserScan>(&topics.scan)?;
    let odom_sub = node.subscription::<Odometry>(&topics.odom)?;
    let drive_pub = node.publisher::<AckermannDriveStamped>(&topics.drive)?;
    let frame = ros.frames.base.clone();
    let mut mount_source = "default";
    let tf_static_sub = match options.laser_mount {
        Some(mount) => {
            core.set_laser_mount(mount)?;
            mount_source = "flags";
            None
        }
        None => Some(node.static_subscription::<TFMessage>(&topics.tf_static)?),
    };
    let mut scan_frame: Option<String> = None;
    tracing::info!(
        driver = core.driver_name(),
        scan = %topics.scan, odom = %topics.odom, drive = %topics.drive,
        domain = ros.domain_id, "drive node up"
    );
    let t0 = Instant::now();
    let now = || t0.elapsed().as_secs_f64();
    let period = 1.0 / options.rate_hz;
    let mut next_tick = 0.0;
    let mut latencies = Vec::new();
    let mut end_to_end = Vec::new();
    // the newest sensor stamp and when it arrived: commands are stamped on the
    // sensors' clock (sim time on the SIL car) plus the time spent since
    let sensor_clock: Cell<Option<(Time, f64)>> = Cell::new(None);
    let (mut commands, mut scans, mut odoms) = (0u64, 0u64, 0u64);
    let stamp_at = |t: f64| match sensor_clock.get() {
        Some((stamp, at)) if !stamp.is_zero() => Time::from_secs(stamp.as_secs() + (t - at)),
        _ => wall_clock_stamp(),
    };
    let send = |v: &Verdict| {
        publish(
            &drive_pub,
            &topics.drive,
            AckermannDriveStamped {
                header: Header::new(stamp_at(now()), &frame),
                drive: AckermannDrive {
                    steering_angle: v.action.steer as f32,
                    speed: v.action.speed as f32,
                    ..AckermannDrive::default()
                },
            },
        )
    };
    let stop_guard = ZeroSpeedOnExit { send: &send };
    loop {
        if stop.load(Ordering::Relaxed) || options.seconds.is_some_and(|s| now() >= s) {
            break;
        }
        // (arrival time, source timestamp) of the message that triggers a command
        let mut trigger: Option<(f64, Option<i64>)> = None;
        if let Some((odom, source)) = take_newest(&odom_sub, &topics.odom) {
            let t = now();
            odoms += 1;
            if core.on_odom(&odom, t) {
                sensor_clock.set(Some((odom.header.stamp, t)));
                if !core.lidar_driver() {
                    trigger = Some((t, source));
                }
            }
        }
        if let Some(sub) = &tf_static_sub {
            for tf in take_all(sub, &topics.tf_static) {
                let laser = scan_frame.as_deref().unwrap_or(&ros.frames.laser);
                for t in &tf.transforms {
                    if t.header.frame_id != ros.frames.base || t.child_frame_id != laser {
                        continue;
                    }
                    match LaserMount::from_transform(&t.transform) {
                        Ok(mount) => {
                            if mount != core.laser_mount() || mount_source != "/tf_static" {
                                tracing::info!(?mount, "laser mount from {}", topics.tf_static);
                            }
                            core.set_laser_mount(mount)?;
                            mount_source = "/tf_static";
                        }
                        Err(e) => tracing::warn!(
                            error = %e,
                            "ignoring {} -> {laser} on {}",
                            ros.frames.base,
                            topics.tf_static
                        ),
                    }
                }
            }
        }
        if let Some((scan, source)) = take_newest(&scan_sub, &topics.scan) {
            let t = now();
            scans += 1;
            if scan_frame.as_deref() != Some(scan.header.frame_id.as_str())
                && !scan.header.frame_id.is_empty()
            {
                scan_frame = Some(scan.header.frame_id.clone());
            }
            if core.on_scan(&scan, t) {
                sensor_clock.set(Some((scan.header.stamp, t)));
                if core.lidar_driver() {
                    trigger = Some((t, source));
                }
            }
        }
        let t = now();
        if trigger.is_some() || t >= next_tick {
            let verdict = core.command(t).inspect_err(|e| {
                tracing::error!(error = %e, "stopping the car: the driver failed");
            })?;
            send(&verdict);
            commands += 1;
            if let Some((arrived, source)) = trigger {
                let l = now() - arrived;
                latencies.push(l);
                let e2e = source.map(|s| (epoch_ns() - s) as f64 * 1e-9);
                // another host's clock can be off: keep only plausible values
                if let Some(e) = e2e.filter(|e| (0.0..10.0).contains(e)) {
                    end_to_end.push(e);
                }
                tracing::trace!(
                    latency_ms = l * 1e3,
                    end_to_end_ms = e2e.map(|e| e * 1e3),
                    "command sent"
                );
            }
            next_tick = t + period;
        }
        std::thread::sleep(Duration::from_micros(250));
    }
    // the clean stop
    drop(stop_guard);
    let latency = LatencySummary::from_samples(&latencies);
    let e2e = LatencySummary::from_samples(&end_to_end);
    let summary = DriveSummary {
        driver: core.driver_name().to_string(),
        trigger: if core.lidar_driver() { "scan" } else { "odom" },
        commands,
        scans,
        odoms,
        duration_s: now(),
        latency,
        end_to_end: e2e,
        safety: *core.safety().counters(),
        laser_mount: core.laser_mount(),
        laser_mount_source: mount_source,
        fault: core.fault().map(str::to_string),
    };
    tracing::info!(
        commands,
        latency_mean_ms = latency.mean_ms,
        latency_p99_ms = latency.p99_ms,
        latency_max_ms = latency.max_ms,
        end_to_end_mean_ms = e2e.mean_ms,
        end_to_end_p99_ms = e2e.p99_ms,
        "drive node stopped; zero speed sent"
    );
    Ok(summary)
}

#[cfg(test)]
mod tests;
