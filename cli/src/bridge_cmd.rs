//! `paddock bridge`: a Paddock driver on the ROS 2 car, the software-in-the-loop car,
//! recordings to MCAP and their export to the reality-gap CSV.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicI32, Ordering};

use crate::args::{self, outln};
use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use paddock_bridge::drive::{DriveCore, DriveOptions, DriverSpec, run_drive};
use paddock_bridge::mount::{LaserMount, MAX_OFFSET, MAX_YAW};
use paddock_bridge::record::{LogClock, RecordOptions, RecordingTopics, export_csv, record};
use paddock_bridge::ros::Frames;
use paddock_bridge::safety::SafetyConfig;
use paddock_bridge::sil::{Opponent, SilOptions, run_sil};
use paddock_sim::circuit::{Circuits, DEFAULT_MAP};
use paddock_sim::collision::CollisionMode;

mod ros_args;
use ros_args::RosArgs;

#[derive(Args)]
pub struct BridgeArgs {
    // boxed: the node commands' many flags would make `paddock`'s command enum large
    #[command(subcommand)]
    command: Box<BridgeCommand>,
}

#[derive(Subcommand)]
enum BridgeCommand {
    /// Run a driver on the car: subscribe /scan and /odom, publish /drive, behind the
    /// safety layer (stale-sensor stop, clamps, time-to-collision stop; zero speed on
    /// every exit: SIGINT, SIGTERM, SIGHUP, a failing driver).
    Drive(DriveArgs),
    /// The software-in-the-loop car: the simulator with the car's topics, in real time.
    Sil(SilArgs),
    /// Record /scan, /odom and /drive to an MCAP file (a ROS 2 bag), finalised on SIGINT,
    /// SIGTERM and SIGHUP.
    Record(RecordArgs),
    /// Export a recording (MCAP, rosbag2 bag folder, .db3) to the reality-gap CSV
    /// (t,steer_cmd,speed_cmd,x,y,yaw,vx,vy,yaw_rate).
    ExportCsv(ExportArgs),
}

#[derive(Args)]
struct DriveArgs {
    /// A `paddock tune` result.json, an ONNX model file (`model.onnx`; docs/onnx.md), or
    /// a driver name (`paddock drivers`).
    #[arg(long, alias = "policy")]
    driver: String,
    /// Parameter overrides, `name=value,name=value`.
    #[arg(long)]
    params: Option<String>,
    /// The map (shipped name or directory) for map-based drivers; default: the tune
    /// result's map, else the default map. Their pose comes from /odom (map frame).
    #[arg(long)]
    map: Option<String>,
    /// Vehicle YAML (as `paddock sysid` writes it) for drivers that plan with the car's
    /// geometry and limits (default: the f1tenth_gym vehicle).
    #[arg(long, value_name = "FILE")]
    vehicle: Option<PathBuf>,
    /// Steering limit, rad.
    #[arg(long, default_value_t = 0.4189, value_parser = args::number(0.0, 1.6))]
    max_steer: f64,
    /// Speed limit, m/s (raise it deliberately).
    #[arg(long, default_value_t = 4.0, value_parser = args::number(0.0, 30.0))]
    max_speed: f64,
    /// Lowest speed, m/s (negative allows reversing).
    #[arg(long, default_value_t = 0.0, value_parser = args::number(-30.0, 30.0))]
    min_speed: f64,
    /// A sensor older than this stops the car, s.
    #[arg(long, default_value_t = 0.25, value_parser = args::above(0.0, 10.0))]
    sensor_timeout: f64,
    /// Emergency stop below this time to collision, s (0 disables it).
    #[arg(long, default_value_t = 0.25, value_parser = args::number(0.0, 10.0))]
    ttc: f64,
    /// The emergency stop releases after this long clear, s.
    #[arg(long, default_value_t = 0.5, value_parser = args::number(0.0, 10.0))]
    ttc_release: f64,
    /// Half width of the straight-ahead strip whose returns count for the TTC, m
    /// (0: every beam, the classic per-beam TTC).
    #[arg(long, default_value_t = 0.2, value_parser = args::number(0.0, 5.0))]
    ttc_corridor: f64,
    /// Stop while more than this fraction of the scan's beams within 20 degrees of
    /// straight ahead are invalid (REP 117: NaN or an error code; 1: never).
    #[arg(long, default_value_t = 0.25, value_parser = args::number(0.0, 1.0))]
    max_invalid_ahead: f64,
    /// How fast a sensor's header-stamp clock may fall behind this host's, s/s: the
    /// bound of the clock-offset estimate behind the stamp age (a SIL car slower than
    /// real time, `--rate R` < 1, needs at least 1 - R; 1 turns the stamp age off).
    #[arg(long, default_value_t = 0.01, value_parser = args::number(0.0, 1.0))]
    max_clock_drift: f64,
    /// The laser's position ahead of base_link, m. Any --laser-* flag sets the mount;
    /// without them it comes from /tf_static (base frame -> laser frame), and until
    /// that arrives the laser is taken to sit where the simulator's does (base_link).
    #[arg(long, allow_hyphen_values = true, value_parser = args::number(-MAX_OFFSET, MAX_OFFSET))]
    laser_x: Option<f64>,
    /// The laser's position to the left of base_link, m.
    #[arg(long, allow_hyphen_values = true, value_parser = args::number(-MAX_OFFSET, MAX_OFFSET))]
    laser_y: Option<f64>,
    /// The laser's yaw on the car, rad (pi: looking backwards; within two turns).
    #[arg(long, allow_hyphen_values = true, value_parser = laser_yaw)]
    laser_yaw: Option<f64>,
    /// The laser is mounted upside down (its beams sweep clockwise).
    #[arg(long)]
    laser_flipped: bool,
    /// Least command rate, Hz (commands also follow every new sensor message).
    #[arg(long, default_value_t = 40.0, value_parser = args::above(0.0, 1_000.0))]
    rate_hz: f64,
    /// Stop after this many seconds.
    #[arg(long, value_parser = args::above(0.0, 1e6))]
    seconds: Option<f64>,
    #[command(flatten)]
    ros: RosArgs,
}

#[derive(Args)]
struct SilArgs {
    /// Map: shipped name or directory.
    #[arg(long, default_value = DEFAULT_MAP)]
    map: String,
    /// A second car: a driver name or an ONNX model file (driven inside the SIL), or
    /// `ros` (driven over /opp_drive).
    #[arg(long)]
    opponent: Option<String>,
    /// Parameter overrides for the opponent driver, `name=value,...`.
    #[arg(long)]
    opponent_params: Option<String>,
    /// Vehicle YAML of both cars (as `paddock sysid` writes it: the fitted car, and
    /// `laser_mount` with x, y, yaw, flipped, which then places the simulated laser
    /// instead of --laser-x; default: the f1tenth_gym vehicle).
    #[arg(long, value_name = "FILE")]
    vehicle: Option<PathBuf>,
    /// Simulated seconds per wall-clock second (1 = real time).
    #[arg(long, default_value_t = 1.0, value_parser = args::above(0.0, 1_000.0))]
    rate: f64,
    /// LIDAR scans published per simulated second.
    #[arg(long, default_value_t = 40.0, value_parser = args::above(0.0, 1_000.0))]
    scan_hz: f64,
    /// Odometry messages published per simulated second.
    #[arg(long, default_value_t = 100.0, value_parser = args::above(0.0, 1_000.0))]
    odom_hz: f64,
    /// End after the ego car drives this many laps.
    #[arg(long, value_parser = args::whole::<u32>(1, 1_000))]
    laps: Option<u32>,
    /// End after this many simulated seconds.
    #[arg(long, value_parser = args::above(0.0, 1e6))]
    seconds: Option<f64>,
    /// Start at this arc length along the centerline, m.
    #[arg(long, default_value_t = 0.0, value_parser = args::number(0.0, 1e5))]
    start_s: f64,
    /// Seed of the LIDAR noise.
    #[arg(long, default_value_t = 0, value_parser = args::seed())]
    seed: u64,
    /// LIDAR noise standard deviation, m.
    #[arg(long, default_value_t = 0.01, value_parser = args::number(0.0, 1.0))]
    lidar_noise: f64,
    /// The simulated laser's position ahead of the car's reference point (base_link),
    /// m: 0 as f1tenth_gym_ros (`scan_distance_to_base_link`); 0.27 is where
    /// f1tenth_system mounts the Hokuyo. Published on /tf_static.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true, value_parser = args::number(-1.0, 1.0))]
    laser_x: f64,
    /// What a collision does: stop (put back and halted), terminate, ignore.
    #[arg(long, default_value = "stop")]
    collision: String,
    /// Hold the simulation until the first /drive command.
    #[arg(long)]
    wait_for_drive: bool,
    /// Do not publish /tf (odometry frame -> each car) and /tf_static (car -> laser).
    #[arg(long)]
    no_tf: bool,
    /// Print the summary as JSON.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    ros: RosArgs,
}

#[derive(Args)]
struct RecordArgs {
    /// The MCAP file to write.
    #[arg(long)]
    out: PathBuf,
    /// Stop after this many seconds (else Ctrl-C).
    #[arg(long, value_parser = args::above(0.0, 1e6))]
    seconds: Option<f64>,
    /// Log time of each message: `header` (its stamp) or `receive` (arrival).
    #[arg(long, default_value = "header")]
    clock: String,
    #[command(flatten)]
    ros: RosArgs,
}

#[derive(Args)]
struct ExportArgs {
    /// The recording: an MCAP file (one never finalised is read up to its last complete
    /// chunk), a rosbag2 bag folder (SQLite3 or MCAP storage) or a `.db3` file.
    recording: PathBuf,
    /// The CSV file to write.
    #[arg(long)]
    out: PathBuf,
    /// The recording's drive command topic (ackermann_msgs/AckermannDriveStamped).
    #[arg(long, default_value = "/drive")]
    drive_topic: String,
    /// The recording's odometry topic (nav_msgs/Odometry): the velocities, and the pose
    /// unless --pose-topic.
    #[arg(long, default_value = "/odom")]
    odom_topic: String,
    /// The pose's own topic, a localiser's or motion capture's (nav_msgs/Odometry,
    /// geometry_msgs/PoseStamped or PoseWithCovarianceStamped, or the transforms: /tf);
    /// the velocities at each pose are interpolated from --odom-topic. Default:
    /// --odom-topic.
    #[arg(long)]
    pose_topic: Option<String>,
    /// With the transforms as the pose topic (--pose-topic /tf, with /tf_static): the
    /// frames, PARENT,CHILD, whose pose is read [default: map,base_link].
    #[arg(long, value_parser = args::frame_pair)]
    pose_frames: Option<[String; 2]>,
}

/// The parser of `--laser-yaw`: as `args::number(-MAX_YAW, MAX_YAW)`, its range said as
/// two turns (`[-2 pi, 2 pi]`) rather than in sixteen digits.
fn laser_yaw(text: &str) -> Result<f64, String> {
    let range = "[-2 pi, 2 pi]";
    let v: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("{text:?} is not a number in {range}"))?;
    if !(v.is_finite() && v.abs() <= MAX_YAW) {
        return Err(format!(
            "{text} is out of range: must be a number in {range}"
        ));
    }
    Ok(v)
}

pub fn run(args: &BridgeArgs, circuits: &Circuits) -> Result<()> {
    match args.command.as_ref() {
        BridgeCommand::Drive(a) => drive(a, circuits),
        BridgeCommand::Sil(a) => sil(a, circuits),
        BridgeCommand::Record(a) => rec(a),
        BridgeCommand::ExportCsv(a) => export(a),
    }
}

/// Set by SIGINT (Ctrl-C), SIGTERM (systemd, docker stop, launch) and SIGHUP (the
/// terminal or SSH session closing): each ends a node through its clean stop (the drive
/// node's zero-speed command, the recorder's finalised MCAP).
static STOP: AtomicBool = AtomicBool::new(false);
/// The signal that set [`STOP`].
static STOP_SIGNAL: AtomicI32 = AtomicI32::new(0);

extern "C" fn on_stop_signal(signal: std::ffi::c_int) {
    // only atomic stores: async-signal-safe
    STOP_SIGNAL.store(signal, Ordering::Relaxed);
    STOP.store(true, Ordering::Relaxed);
}

/// Install the stop handler for SIGINT, SIGTERM and SIGHUP.
fn stop_flag() -> Result<&'static AtomicBool> {
    use nix::sys::signal::{SaFlags, SigAction, SigHandler, SigSet, Signal, sigaction};
    let action = SigAction::new(
        SigHandler::Handler(on_stop_signal),
        SaFlags::SA_RESTART,
        SigSet::empty(),
    );
    for signal in [Signal::SIGINT, Signal::SIGTERM, Signal::SIGHUP] {
        // SAFETY: the handler only stores to atomics, which is async-signal-safe, and no
        // other handler of ours is replaced (the bridge commands install none else)
        unsafe { sigaction(signal, &action) }
            .with_context(|| format!("installing the {signal} handler"))?;
    }
    Ok(&STOP)
}

/// Say which signal ended a node, if one did.
fn report_signal() {
    let signal = STOP_SIGNAL.load(Ordering::Relaxed);
    if signal != 0 {
        let name = nix::sys::signal::Signal::try_from(signal)
            .map(|s| s.as_str())
            .unwrap_or("a signal");
        eprintln!("stopped by {name}");
    }
}

fn overrides(text: Option<&str>) -> Result<Vec<(String, f64)>> {
    let Some(text) = text else {
        return Ok(Vec::new());
    };
    text.split(',')
        .filter(|p| !p.trim().is_empty())
        .map(|pair| {
            let (name, value) = pair
                .split_once('=')
                .with_context(|| format!("--params: {pair:?} is not name=value"))?;
            let v: f64 = value
                .trim()
                .parse()
                .with_context(|| format!("--params: {}: {value:?} is not a number", name.trim()))?;
            Ok((name.trim().to_string(), v))
        })
        .collect()
}

fn drive(a: &DriveArgs, circuits: &Circuits) -> Result<()> {
    let ros = a.ros.config(Frames::default())?;
    let spec =
        DriverSpec::resolve(&a.driver, &overrides(a.params.as_deref())?).context("--driver")?;
    let map = a
        .map
        .clone()
        .or_else(|| spec.map.clone())
        .unwrap_or_else(|| DEFAULT_MAP.to_string());
    let circuit = circuits.get(&map).with_context(|| format!("--map {map}"))?;
    let driver = spec.build(&circuit, &args::vehicle(a.vehicle.as_deref())?)?;
    let options = DriveOptions {
        rate_hz: a.rate_hz,
        seconds: a.seconds,
        safety: SafetyConfig {
            max_steer: a.max_steer,
            max_speed: a.max_speed,
            min_speed: a.min_speed,
            sensor_timeout: a.sensor_timeout,
            ttc_threshold: a.ttc,
            ttc_release: a.ttc_release,
            corridor_half_width: a.ttc_corridor,
            max_invalid_ahead: a.max_invalid_ahead,
            max_clock_drift: a.max_clock_drift,
            ..SafetyConfig::default()
        },
        laser_mount: (a.laser_x.is_some()
            || a.laser_y.is_some()
            || a.laser_yaw.is_some()
            || a.laser_flipped)
            .then(|| LaserMount {
                x: a.laser_x.unwrap_or(0.0),
                y: a.laser_y.unwrap_or(0.0),
                yaw: a.laser_yaw.unwrap_or(0.0),
                flipped: a.laser_flipped,
            }),
        ..DriveOptions::default()
    };
    spec.check_lidar(&options.lidar).context("--driver")?;
    let core = DriveCore::new(driver, options.lidar.clone(), options.safety)?;
    let stop = stop_flag()?;
    let shown = if spec.source == spec.name {
        spec.name.clone()
    } else {
        format!("{} ({})", spec.source, spec.name)
    };
    eprintln!(
        "driving {shown} (map {}) on {} -> {}, domain {}; Ctrl-C, SIGTERM or SIGHUP stops the car",
        circuit.name, ros.topics.scan, ros.topics.drive, ros.domain_id
    );
    let s = run_drive(core, &ros, &options, stop);
    report_signal();
    let s = s?;
    let l = &s.latency;
    let c = &s.safety;
    outln!(
        "{} commands in {:.1} s ({} scans, {} odometry); zero speed sent at exit",
        s.commands,
        s.duration_s,
        s.scans,
        s.odoms
    );
    outln!(
        "{}->drive latency over {} commands: mean {:.2} ms, p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms",
        s.trigger,
        l.count,
        l.mean_ms,
        l.p50_ms,
        l.p99_ms,
        l.max_ms
    );
    let e = &s.end_to_end;
    if e.count > 0 {
        outln!(
            "{} publish->drive publish (DDS source stamps, same-host clock) over {}: mean {:.2} ms, p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms",
            s.trigger,
            e.count,
            e.mean_ms,
            e.p50_ms,
            e.p99_ms,
            e.max_ms
        );
    }
    if let Some(fault) = &s.fault {
        outln!("the driver faulted and the car was held stopped: {fault}");
    }
    let m = &s.laser_mount;
    outln!(
        "laser mount ({}): x {:.3} m, y {:.3} m, yaw {:.3} rad{}",
        s.laser_mount_source,
        m.x,
        m.y,
        m.yaw,
        if m.flipped { ", flipped" } else { "" }
    );
    outln!(
        "safety: {} stale-sensor stops, {} emergency-stop commands ({} engagements, min TTC {:.2} s), {} blind-ahead stops, {} clamped, {} invalid",
        c.stale,
        c.emergency,
        c.emergency_engaged,
        c.min_ttc,
        c.blind,
        c.clamped,
        c.invalid
    );
    Ok(())
}

fn sil(a: &SilArgs, circuits: &Circuits) -> Result<()> {
    let ros = a.ros.config(Frames::f1tenth_gym_ros())?;
    let opponent = match a.opponent.as_deref() {
        None => None,
        Some("ros") => Some(Opponent::Ros),
        Some(name) => Some(Opponent::Driver(
            DriverSpec::resolve(name, &overrides(a.opponent_params.as_deref())?)
                .context("--opponent")?,
        )),
    };
    let collision_mode: CollisionMode = a
        .collision
        .parse()
        .map_err(|e: String| anyhow::anyhow!("--collision: {e}"))?;
    let mut lidar = paddock_sim::lidar::LidarConfig {
        noise_std: a.lidar_noise,
        ..Default::default()
    };
    lidar.mount_offset = a.laser_x;
    let options = SilOptions {
        map: a.map.clone(),
        rate: a.rate,
        scan_hz: a.scan_hz,
        odom_hz: a.odom_hz,
        laps: a.laps,
        seconds: a.seconds,
        start_s: a.start_s,
        seed: a.seed,
        lidar,
        opponent,
        collision_mode,
        wait_for_drive: a.wait_for_drive,
        tf: !a.no_tf,
        vehicle: args::vehicle(a.vehicle.as_deref())?,
    };
    let stop = stop_flag()?;
    eprintln!(
        "SIL car on {} at {}x real time, domain {}; Ctrl-C ends",
        a.map, a.rate, ros.domain_id
    );
    let s = run_sil(circuits, &options, &ros, stop);
    report_signal();
    let s = s?;
    if a.json {
        outln!("{}", serde_json::to_string_pretty(&s)?);
        return Ok(());
    }
    outln!(
        "{}: {:.2} s simulated in {:.2} s wall ({} steps), {} drive messages, max lag {:.1} ms",
        s.map,
        s.sim_time,
        s.wall_s,
        s.steps,
        s.drive_messages,
        s.max_lag_s * 1e3
    );
    for (i, laps) in s.lap_times.iter().enumerate() {
        let shown: Vec<String> = laps.iter().map(|t| format!("{t:.2}")).collect();
        outln!(
            "car {i}: laps [{}] s, {} steps in collision",
            shown.join(", "),
            s.collision_steps[i]
        );
    }
    Ok(())
}

fn rec(a: &RecordArgs) -> Result<()> {
    let ros = a.ros.config(Frames::default())?;
    let clock: LogClock = a
        .clock
        .parse()
        .map_err(|e: String| anyhow::anyhow!("--clock: {e}"))?;
    let stop = stop_flag()?;
    eprintln!(
        "recording {}, {}, {} to {}; Ctrl-C ends",
        ros.topics.scan,
        ros.topics.odom,
        ros.topics.drive,
        a.out.display()
    );
    let s = record(
        &ros,
        &a.out,
        &RecordOptions {
            seconds: a.seconds,
            clock,
        },
        stop,
    );
    report_signal();
    let s = s?;
    for (topic, n) in &s.messages {
        outln!("{topic}: {n} messages");
    }
    outln!("wrote {} ({:.1} s)", a.out.display(), s.duration_s);
    Ok(())
}

fn export(a: &ExportArgs) -> Result<()> {
    let topics = RecordingTopics {
        drive: a.drive_topic.clone(),
        odom: a.odom_topic.clone(),
        pose: a.pose_topic.clone(),
        pose_frames: a.pose_frames.clone(),
    };
    let (rows, report) = export_csv(&a.recording, &a.out, &topics)?;
    if let Some(t) = report.truncation {
        eprintln!("{}: {t}", a.recording.display());
    }
    for note in &report.notes {
        eprintln!("{}: {note}", a.recording.display());
    }
    outln!("wrote {} ({rows} rows)", a.out.display());
    Ok(())
}
