//! The software-in-the-loop car: the simulator as a ROS 2 node with the car's topics.
//!
//! Like f1tenth_gym_ros, it publishes `/scan` (sensor_msgs/LaserScan) and `/odom`
//! (nav_msgs/Odometry, pose in the map frame) for the ego car and `/opp_scan`,
//! `/opp_odom` for an opponent, takes `/drive` (and `/opp_drive`) commands
//! (ackermann_msgs/AckermannDriveStamped, the newest held until the next) and
//! `/initialpose` (geometry_msgs/PoseWithCovarianceStamped: the ego car is placed there
//! and the episode restarts). So `paddock bridge drive`, or any ROS 2 driver, runs
//! against it unchanged. Like f1tenth_gym_ros it also publishes TF: each car's pose as
//! the transform odometry frame -> body frame on `/tf` (with every odometry message, same
//! stamp), and the LIDAR mount, body -> laser frame, once on `/tf_static` (transient
//! local, so RViz or a tf2 listener started later still gets it).
//!
//! Physics steps at 100 Hz (the simulator's 0.01 s), paced by the wall clock times
//! `rate` (1 = real time; tests use a few times real time, and every period below is in
//! simulated seconds). Scans go out at `scan_hz`, odometry at `odom_hz`. Message stamps
//! are a wall-clock epoch plus simulated time, so a recording of a faster-than-real-time
//! run still carries the simulated timeline in its header stamps.
//!
//! ## When a command takes effect
//! Each loop publishes the state at simulated time `t`, waits until the wall clock
//! reaches `t + dt` (scaled by `rate`), then takes the newest commands and steps the
//! physics from `t` to `t + dt`. A driver's answer to the state at `t` that arrives
//! within that wait (one physics period of wall time, 10 ms / `rate`) is applied to the
//! very next step, as in a rollout where the driver acts on the observation at `t`; one
//! that arrives later waits a step. (Taking commands before the wait instead, as an
//! earlier version did, delayed every command by a step, and by two whenever the answer
//! missed the short window at `--rate 4`.)

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use paddock_policy::Driver;
use paddock_sim::circuit::Circuits;
use paddock_sim::collision::CollisionMode;
use paddock_sim::geometry::Pose as SimPose;
use paddock_sim::lidar::LidarConfig;
use paddock_sim::params::VehicleParams;
use paddock_sim::world::{Action, AgentConfig, Observation, Starts, World, WorldConfig};

use crate::BridgeError;
use crate::drive::DriverSpec;
use crate::msg::{
    AckermannDriveStamped, Header, LaserScan, Odometry, Point, Pose, PoseWithCovariance,
    PoseWithCovarianceStamped, Quaternion, TFMessage, Time, Transform, TransformStamped, Twist,
    TwistWithCovariance, Vector3,
};
use crate::ros::{Frames, RosConfig, RosNode, publish, take_latest};

/// Who drives the opponent car.
#[derive(Debug, Clone, PartialEq)]
pub enum Opponent {
    /// A ROS 2 node, over the opponent topics.
    Ros,
    /// A Paddock driver inside the SIL process (its scan and odometry are still
    /// published on the opponent topics).
    Driver(DriverSpec),
}

/// Settings of the SIL car.
#[derive(Debug, Clone, PartialEq)]
pub struct SilOptions {
    pub map: String,
    /// Simulated seconds per wall-clock second.
    pub rate: f64,
    pub scan_hz: f64,
    pub odom_hz: f64,
    /// End when the ego car has driven this many laps.
    pub laps: Option<u32>,
    /// End after this many simulated seconds.
    pub seconds: Option<f64>,
    /// Start at this arc length of the centerline, m.
    pub start_s: f64,
    /// Seeds the LIDAR noise.
    pub seed: u64,
    pub lidar: LidarConfig,
    pub vehicle: VehicleParams,
    pub opponent: Option<Opponent>,
    /// A crashed car is halted and put back (`stop`), or out (`terminate`).
    pub collision_mode: CollisionMode,
    /// Hold the simulation (publishing the start state) until the first `/drive`
    /// message, so a driver's discovery time is not part of its lap.
    pub wait_for_drive: bool,
    /// Publish the cars' transforms on `/tf` and `/tf_static`.
    pub tf: bool,
}

impl Default for SilOptions {
    fn default() -> Self {
        Self {
            map: paddock_sim::circuit::DEFAULT_MAP.into(),
            rate: 1.0,
            scan_hz: 40.0,
            odom_hz: 100.0,
            laps: None,
            seconds: None,
            start_s: 0.0,
            seed: 0,
            lidar: LidarConfig::default(),
            vehicle: VehicleParams::default(),
            opponent: None,
            collision_mode: CollisionMode::Stop,
            wait_for_drive: false,
            tf: true,
        }
    }
}

impl SilOptions {
    pub fn validate(&self) -> Result<(), BridgeError> {
        let pos = |field: &str, v: f64, hi: f64| {
            if v.is_finite() && v > 0.0 && v <= hi {
                Ok(())
            } else {
                Err(BridgeError::config(
                    field,
                    v,
                    &format!("must be in (0, {hi}]"),
                ))
            }
        };
        pos("rate", self.rate, 100.0)?;
        pos("scan_hz", self.scan_hz, 100.0)?;
        pos("odom_hz", self.odom_hz, 100.0)?;
        if let Some(s) = self.seconds {
            pos("seconds", s, 1e7)?;
        }
        if self.laps == Some(0) {
            return Err(BridgeError::config("laps", 0, "must be at least 1"));
        }
        if !self.start_s.is_finite() {
            return Err(BridgeError::config(
                "start_s",
                self.start_s,
                "must be finite",
            ));
        }
        Ok(())
    }
}

/// What a SIL run did.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SilSummary {
    pub map: String,
    /// Completed lap times per car, s.
    pub lap_times: Vec<Vec<f64>>,
    pub sim_time: f64,
    pub steps: u64,
    /// Steps with a collision, per car.
    pub collision_steps: Vec<u64>,
    pub drive_messages: u64,
    pub scans_published: u64,
    pub odoms_published: u64,
    /// `/tf` messages (one per odometry tick, every car's transform in it).
    pub tfs_published: u64,
    /// Worst lag behind the wall-clock schedule, s (the schedule restarts after 50 ms).
    pub max_lag_s: f64,
    pub wall_s: f64,
}

fn epoch_now() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0)
}

/// One car's outgoing messages.
struct CarTopics {
    scan: crate::ros::Publisher<LaserScan>,
    odom: crate::ros::Publisher<Odometry>,
    scan_name: String,
    odom_name: String,
    frames: Frames,
}

fn scan_msg(
    obs: &Observation,
    i: usize,
    lidar: &LidarConfig,
    stamp: Time,
    f: &Frames,
    scan_hz: f64,
) -> LaserScan {
    let n = lidar.num_beams;
    LaserScan {
        header: Header::new(stamp, &f.laser),
        angle_min: (-0.5 * lidar.fov) as f32,
        angle_max: (0.5 * lidar.fov) as f32,
        angle_increment: if n > 1 {
            (lidar.fov / (n - 1) as f64) as f32
        } else {
            0.0
        },
        time_increment: 0.0,
        scan_time: (1.0 / scan_hz) as f32,
        range_min: 0.0,
        range_max: lidar.max_range as f32,
        ranges: obs.scan(i).iter().map(|&r| r as f32).collect(),
        intensities: Vec::new(),
    }
}

/// `frames.odom` -> `frames.base`: where the car is, as tf2 wants it.
fn pose_transform(obs: &Observation, i: usize, stamp: Time, f: &Frames) -> TransformStamped {
    TransformStamped {
        header: Header::new(stamp, &f.odom),
        child_frame_id: f.base.clone(),
        transform: Transform {
            translation: Vector3 {
                x: obs.poses_x[i],
                y: obs.poses_y[i],
                z: 0.0,
            },
            rotation: Quaternion::from_yaw(obs.poses_theta[i]),
        },
    }
}

/// `frames.base` -> `frames.laser`: where the simulated LIDAR sits, the vehicle's
/// `laser_mount` when it has one, else `mount_offset` ahead of the car's reference point
/// (the point the pose and the scan's ray casting use; 0 by default, as f1tenth_gym_ros).
fn laser_transform(
    lidar: &LidarConfig,
    vehicle: &VehicleParams,
    stamp: Time,
    f: &Frames,
) -> TransformStamped {
    let (x, y, yaw, flipped) = match vehicle.laser_mount {
        Some(m) => (m.x, m.y, m.yaw, m.flipped),
        None => (lidar.mount_offset, 0.0, 0.0, false),
    };
    let (s, c) = libm::sincos(0.5 * yaw);
    // a yaw about z, then (upside down) a half turn about x
    let rotation = if flipped {
        Quaternion {
            x: c,
            y: s,
            z: 0.0,
            w: 0.0,
        }
    } else {
        Quaternion::from_yaw(yaw)
    };
    TransformStamped {
        header: Header::new(stamp, &f.base),
        child_frame_id: f.laser.clone(),
        transform: Transform {
            translation: Vector3 { x, y, z: 0.0 },
            rotation,
        },
    }
}

fn odom_msg(obs: &Observation, i: usize, stamp: Time, f: &Frames) -> Odometry {
    Odometry {
        header: Header::new(stamp, &f.odom),
        child_frame_id: f.base.clone(),
        pose: PoseWithCovariance {
            pose: Pose {
                position: Point {
                    x: obs.poses_x[i],
                    y: obs.poses_y[i],
                    z: 0.0,
                },
                orientation: Quaternion::from_yaw(obs.poses_theta[i]),
            },
            ..Default::default()
        },
        twist: TwistWithCovariance {
            twist: Twist {
                linear: Vector3 {
                    x: obs.linear_vels_x[i],
                    y: obs.linear_vels_y[i],
                    z: 0.0,
                },
                angular: Vector3 {
                    x: 0.0,
                    y: 0.0,
                    z: obs.ang_vels_z[i],
                },
            },
            ..Default::default()
        },
    }
}

/// Run the SIL car on the map `options.map` names in `circuits` until `stop` is set,
/// the laps are driven or the time is up.
pub fn run_sil(
    circuits: &Circuits,
    options: &SilOptions,
    ros: &RosConfig,
    stop: &AtomicBool,
) -> Result<SilSummary, BridgeError> {
    options.validate()?;
    let circuit = circuits.get(&options.map)?;
    let n = if options.opponent.is_some() { 2 } else { 1 };
    let config = WorldConfig {
        dt: 0.01,
        lidar: options.lidar.clone(),
        collision_mode: options.collision_mode,
        agents: vec![
            AgentConfig {
                params: options.vehicle.clone(),
                scan: true,
            };
            n
        ],
        laps: options.laps,
        ..WorldConfig::default()
    };
    let mut world = World::new(circuit.clone(), config)?;
    let starts = Starts::Grid { s: options.start_s };
    world.reset(options.seed, &starts)?;
    let mut opp_driver: Option<Box<dyn Driver>> = match &options.opponent {
        Some(Opponent::Driver(spec)) => {
            spec.check_lidar(&options.lidar)?;
            Some(spec.build(&circuit, &options.vehicle)?)
        }
        _ => None,
    };

    let mut node = RosNode::new("paddock_sil", ros)?;
    let t = &ros.topics;
    let mut cars = vec![CarTopics {
        scan: node.publisher(&t.scan)?,
        odom: node.publisher(&t.odom)?,
        scan_name: t.scan.clone(),
        odom_name: t.odom.clone(),
        frames: ros.frames.clone(),
    }];
    if n == 2 {
        cars.push(CarTopics {
            scan: node.publisher(&t.opp_scan)?,
            odom: node.publisher(&t.opp_odom)?,
            scan_name: t.opp_scan.clone(),
            odom_name: t.opp_odom.clone(),
            frames: ros.frames.opponent(),
        });
    }
    let drive_sub = node.subscription::<AckermannDriveStamped>(&t.drive)?;
    let opp_drive_sub = match options.opponent {
        Some(Opponent::Ros) => Some(node.subscription::<AckermannDriveStamped>(&t.opp_drive)?),
        _ => None,
    };
    let pose_sub = node.subscription::<PoseWithCovarianceStamped>(&t.initialpose)?;
    let tf_pub = if options.tf {
        let statics = node.static_publisher::<TFMessage>(&t.tf_static)?;
        let stamp = Time::from_secs(epoch_now());
        let transforms = cars
            .iter()
            .map(|car| laser_transform(&options.lidar, &options.vehicle, stamp, &car.frames))
            .collect();
        publish(&statics, &t.tf_static, TFMessage { transforms });
        // kept alive with the node: late subscribers get the static transforms from it
        Some((node.publisher::<TFMessage>(&t.tf)?, statics))
    } else {
        None
    };
    tracing::info!(map = %circuit.name, cars = n, rate = options.rate, domain = ros.domain_id, "SIL car up");

    let scan_period = 1.0 / options.scan_hz;
    let odom_period = 1.0 / options.odom_hz;
    let wall0 = Instant::now();
    let mut actions = vec![Action::default(); n];
    let mut summary = SilSummary {
        map: circuit.name.clone(),
        lap_times: vec![Vec::new(); n],
        sim_time: 0.0,
        steps: 0,
        collision_steps: vec![0; n],
        drive_messages: 0,
        scans_published: 0,
        odoms_published: 0,
        tfs_published: 0,
        max_lag_s: 0.0,
        wall_s: 0.0,
    };
    let publish_state = |world: &World,
                         stamp: Time,
                         scans: bool,
                         summary: &mut SilSummary|
     -> Result<(), BridgeError> {
        let obs = world.observation()?;
        if let Some((tf, _)) = &tf_pub {
            let transforms = cars
                .iter()
                .enumerate()
                .map(|(i, car)| pose_transform(obs, i, stamp, &car.frames))
                .collect();
            if publish(tf, &t.tf, TFMessage { transforms }) {
                summary.tfs_published += 1;
            }
        }
        for (i, car) in cars.iter().enumerate() {
            if publish(
                &car.odom,
                &car.odom_name,
                odom_msg(obs, i, stamp, &car.frames),
            ) {
                summary.odoms_published += 1;
            }
            if scans {
                let m = scan_msg(obs, i, &options.lidar, stamp, &car.frames, options.scan_hz);
                if publish(&car.scan, &car.scan_name, m) {
                    summary.scans_published += 1;
                }
            }
        }
        Ok(())
    };

    // Waiting for the driver: the start state goes out at the scan rate in wall time.
    let mut started = !options.wait_for_drive;
    while !started {
        if stop.load(Ordering::Relaxed) {
            summary.wall_s = wall0.elapsed().as_secs_f64();
            return Ok(summary);
        }
        publish_state(&world, Time::from_secs(epoch_now()), true, &mut summary)?;
        let deadline = Instant::now() + Duration::from_secs_f64(scan_period);
        while Instant::now() < deadline {
            if let Some(m) = take_latest(&drive_sub, &t.drive) {
                actions[0] = Action::new(m.drive.steering_angle as f64, m.drive.speed as f64);
                summary.drive_messages += 1;
                started = true;
                break;
            }
            std::thread::sleep(Duration::from_micros(500));
        }
    }
    if options.wait_for_drive {
        tracing::info!(
            waited_s = wall0.elapsed().as_secs_f64(),
            "first drive command: running"
        );
    }

    // stamps are epoch0 + simulated time; a restart moves epoch0 on so they keep rising
    let mut epoch0 = epoch_now();
    let mut run0 = Instant::now();
    let mut sim_base = 0.0; // sim time at run0 (moves when the schedule restarts)
    let (mut next_scan, mut next_odom) = (0.0, 0.0);
    loop {
        let sim_t = world.state()?.time;
        // publish the state at sim_t
        let scans_due = sim_t + 1e-9 >= next_scan;
        if scans_due || sim_t + 1e-9 >= next_odom {
            publish_state(
                &world,
                Time::from_secs(epoch0 + sim_t),
                scans_due,
                &mut summary,
            )?;
            while next_odom <= sim_t + 1e-9 {
                next_odom += odom_period;
            }
            while scans_due && next_scan <= sim_t + 1e-9 {
                next_scan += scan_period;
            }
        }
        let ego_done = world.state()?.agents[0].status != paddock_sim::world::AgentStatus::Racing
            && options.laps.is_some();
        if stop.load(Ordering::Relaxed)
            || ego_done
            || world.done()
            || options.seconds.is_some_and(|s| sim_t + 1e-9 >= s)
        {
            break;
        }
        // pace: the step from sim_t to sim_t + dt ends at wall time (sim_t + dt) / rate
        // (since the schedule's base); commands that arrive until then apply to it
        let target = (sim_t + world.config().dt - sim_base) / options.rate;
        let elapsed = run0.elapsed().as_secs_f64();
        if target > elapsed {
            std::thread::sleep(Duration::from_secs_f64(target - elapsed));
        } else {
            let lag = elapsed - target;
            summary.max_lag_s = summary.max_lag_s.max(lag);
            if lag > 0.05 {
                // too far behind: restart the schedule rather than rush to catch up
                sim_base = sim_t + world.config().dt;
                run0 = Instant::now();
            }
        }
        // commands
        if let Some(m) = take_latest(&drive_sub, &t.drive) {
            actions[0] = Action::new(m.drive.steering_angle as f64, m.drive.speed as f64);
            summary.drive_messages += 1;
        }
        if let Some(sub) = &opp_drive_sub
            && let Some(m) = take_latest(sub, &t.opp_drive)
        {
            actions[1] = Action::new(m.drive.steering_angle as f64, m.drive.speed as f64);
        }
        if let Some(d) = &mut opp_driver {
            actions[1] = d.act(world.observation()?, 1);
        }
        if let Some(p) = take_latest(&pose_sub, &t.initialpose) {
            let q = &p.pose.pose;
            let pose = SimPose::new(q.position.x, q.position.y, q.orientation.yaw());
            let mut poses: Vec<SimPose> = (0..n)
                .map(|i| {
                    let o = world.observation().expect("reset above");
                    SimPose::new(o.poses_x[i], o.poses_y[i], o.poses_theta[i])
                })
                .collect();
            poses[0] = pose;
            match world.reset(options.seed, &Starts::Poses(poses)) {
                Ok(_) => {
                    // time restarts at 0: the header clock goes on one step after sim_t
                    epoch0 += sim_t + world.config().dt;
                    tracing::info!(?pose, "initial pose: episode restarted");
                    summary.lap_times.iter_mut().for_each(Vec::clear);
                    if let Some(d) = &mut opp_driver {
                        d.reset();
                    }
                    actions.iter_mut().for_each(|a| *a = Action::default());
                    (next_scan, next_odom) = (0.0, 0.0);
                    sim_base = 0.0;
                    run0 = Instant::now();
                    continue;
                }
                Err(e) => tracing::warn!(error = %e, "initial pose rejected"),
            }
        }
        // non-finite commands would be refused by the world: hold the car instead
        for (i, a) in actions.iter_mut().enumerate() {
            if !(a.steer.is_finite() && a.speed.is_finite()) {
                tracing::warn!(car = i, ?a, "non-finite command replaced by a stop");
                *a = Action::default();
            }
        }
        let events = world.step(&actions)?;
        summary.steps += 1;
        for i in 0..n {
            if events.collided[i] {
                summary.collision_steps[i] += 1;
                if summary.collision_steps[i] == 1 {
                    tracing::warn!(car = i, t = world.state()?.time, "collision");
                }
            }
            if events.lap_completed[i] {
                let laps = world.lap_times(i)?;
                tracing::info!(
                    car = i,
                    lap = laps.len(),
                    time = laps[laps.len() - 1],
                    "lap"
                );
            }
        }
    }
    let state = world.state()?;
    summary.sim_time = state.time;
    for i in 0..n {
        summary.lap_times[i] = world.lap_times(i)?.to_vec();
    }
    summary.wall_s = wall0.elapsed().as_secs_f64();
    tracing::info!(laps = ?summary.lap_times, sim_time = summary.sim_time, max_lag_s = summary.max_lag_s, "SIL car stopped");
    Ok(summary)
}
