//! Recordings: the car's topics into MCAP, and MCAP out to the reality-gap CSV.
//!
//! [`record`] subscribes to `/scan`, `/odom` and `/drive` and writes every message as a
//! ROS 2 bag in MCAP ([`paddock_recordings::write::McapBag`]: profile `ros2`, `cdr`
//! messages, `ros2msg` schemas, `offered_qos_profiles` on every channel), so Foxglove,
//! `ros2 bag` (with the MCAP storage plugin) and `paddock sysid --recording run.mcap` read
//! it directly. Chunks are 256 KiB, so a recording cut off by a power failure loses at
//! most its last quarter megabyte (under a second of the car's topics): [`read_gap_rows`]
//! reads such a file up to its last complete chunk.
//!
//! A message's log time is its header stamp ([`LogClock::Header`], the default: the
//! sensor's own clock, and the simulated timeline on a faster-than-real-time SIL car) or
//! its arrival time ([`LogClock::Receive`]); a zero stamp falls back to arrival time.
//!
//! [`export_csv`] reads any recording [`paddock_recordings::read_bag`] reads (this MCAP,
//! a rosbag2 bag folder in SQLite3 or MCAP storage, a bare `.db3`) and writes `t,steer_cmd,speed_cmd,x,y,yaw,vx,vy,yaw_rate`: one row per
//! odometry message from the first drive command on, `t` from 0 s, the newest command at
//! or before the row held, yaw wrapped to [-pi, pi).

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use paddock_recordings::msg::{
    AckermannDriveStamped, LaserScan, Odometry, PlanarState, RosMessage, Stamped,
};
pub use paddock_recordings::track::RecordingTopics;
use paddock_recordings::track::{drive_commands, planar_track};
use paddock_recordings::write::McapBag;
use paddock_recordings::{RecordingError, Truncation, read_bag};

use crate::BridgeError;
use crate::ros::{RosConfig, RosNode, Subscription};

/// Which time a recorded message is logged at.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LogClock {
    /// The message's header stamp (arrival time when the stamp is zero).
    #[default]
    Header,
    /// When the recorder received it.
    Receive,
}

impl std::str::FromStr for LogClock {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "header" => Ok(Self::Header),
            "receive" => Ok(Self::Receive),
            _ => Err(format!("unknown clock {s:?} (header, receive)")),
        }
    }
}

/// The writer named in the MCAP header.
const LIBRARY: &str = concat!("paddock-bridge ", env!("CARGO_PKG_VERSION"));

fn bag_error(e: RecordingError) -> BridgeError {
    match e {
        RecordingError::Io { path, source } => BridgeError::Io {
            path,
            error: source,
        },
        RecordingError::Format { path, message } => BridgeError::Format { path, message },
    }
}

/// Settings of a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordOptions {
    /// Stop after this many wall-clock seconds (None: until stopped).
    pub seconds: Option<f64>,
    pub clock: LogClock,
}

impl Default for RecordOptions {
    fn default() -> Self {
        Self {
            seconds: None,
            clock: LogClock::Header,
        }
    }
}

/// Messages recorded per topic.
#[derive(Debug, Clone, PartialEq, Default, serde::Serialize)]
pub struct RecordSummary {
    pub messages: BTreeMap<String, u64>,
    pub duration_s: f64,
}

fn epoch_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}

fn drain<M: RosMessage + Stamped, W: Write + std::io::Seek>(
    sub: &Subscription<M>,
    topic: &str,
    clock: LogClock,
    bag: &mut McapBag<W>,
    count: &mut u64,
) -> Result<(), BridgeError> {
    loop {
        match sub.take() {
            Ok(Some((m, _))) => {
                let received = epoch_ns();
                let stamp = m.stamp();
                let stamp_ns = if stamp.is_zero() {
                    received
                } else {
                    stamp.as_nanos()
                };
                let log = match clock {
                    LogClock::Header => stamp_ns,
                    LogClock::Receive => received,
                };
                bag.write(topic, &m, log, stamp_ns).map_err(bag_error)?;
                *count += 1;
            }
            Ok(None) => return Ok(()),
            Err(e) => {
                tracing::warn!(topic, error = ?e, "skipping an unreadable message");
                return Ok(());
            }
        }
    }
}

/// Record the car's `/scan`, `/odom` and `/drive` into the MCAP file `out` until `stop`
/// is set or `options.seconds` pass.
pub fn record(
    ros: &RosConfig,
    out: &Path,
    options: &RecordOptions,
    stop: &AtomicBool,
) -> Result<RecordSummary, BridgeError> {
    if let Some(s) = options.seconds
        && !(s.is_finite() && s > 0.0)
    {
        return Err(BridgeError::config("seconds", s, "must be > 0"));
    }
    let shown = out.display().to_string();
    let file = File::create(out).map_err(|e| BridgeError::io(out, e))?;
    let mut bag = McapBag::new(BufWriter::new(file), &shown, LIBRARY).map_err(bag_error)?;
    let t = &ros.topics;
    bag.add_topic::<LaserScan>(&t.scan).map_err(bag_error)?;
    bag.add_topic::<Odometry>(&t.odom).map_err(bag_error)?;
    bag.add_topic::<AckermannDriveStamped>(&t.drive)
        .map_err(bag_error)?;
    let mut node = RosNode::new("paddock_record", ros)?;
    let scan = node.subscription::<LaserScan>(&t.scan)?;
    let odom = node.subscription::<Odometry>(&t.odom)?;
    let drive = node.subscription::<AckermannDriveStamped>(&t.drive)?;
    tracing::info!(out = %shown, "recording");
    let t0 = Instant::now();
    let (mut n_scan, mut n_odom, mut n_drive) = (0u64, 0u64, 0u64);
    loop {
        let done = stop.load(Ordering::Relaxed)
            || options
                .seconds
                .is_some_and(|s| t0.elapsed().as_secs_f64() >= s);
        drain(&scan, &t.scan, options.clock, &mut bag, &mut n_scan)?;
        drain(&odom, &t.odom, options.clock, &mut bag, &mut n_odom)?;
        drain(&drive, &t.drive, options.clock, &mut bag, &mut n_drive)?;
        if done {
            break;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    let mut w = bag.finish().map_err(bag_error)?;
    w.flush().map_err(|e| BridgeError::io(out, e))?;
    let messages = BTreeMap::from([
        (t.scan.clone(), n_scan),
        (t.odom.clone(), n_odom),
        (t.drive.clone(), n_drive),
    ]);
    tracing::info!(?messages, "recording closed");
    Ok(RecordSummary {
        messages,
        duration_s: t0.elapsed().as_secs_f64(),
    })
}

/// One row of the reality-gap CSV.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GapRow {
    pub t: f64,
    pub steer_cmd: f64,
    pub speed_cmd: f64,
    /// The odometry: x, y, yaw (in [-pi, pi)), vx, vy, yaw_rate.
    pub state: PlanarState,
}

/// The CSV header of the reality-gap layout.
pub const GAP_CSV_HEADER: &str = "t,steer_cmd,speed_cmd,x,y,yaw,vx,vy,yaw_rate";

/// Read the drive commands and the car's track (the pose and the velocities, as
/// [`RecordingTopics`] says; see `paddock_recordings::track`) of a recording (see
/// [`export_csv`]) into reality-gap rows, one per pose from the first command on; a
/// channel not measured is NaN. A truncated MCAP is read up to its last complete chunk,
/// with a warning; [`read_gap_rows_reporting`] hands that report back.
pub fn read_gap_rows(path: &Path, topics: &RecordingTopics) -> Result<Vec<GapRow>, BridgeError> {
    read_gap_rows_reporting(path, topics).map(|(rows, _)| rows)
}

/// What [`read_gap_rows_reporting`] read besides the rows.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GapReport {
    /// What was recovered when the file was never finalised.
    pub truncation: Option<Truncation>,
    /// Channels not measured, poses skipped (`paddock_recordings::track::Track::notes`).
    pub notes: Vec<String>,
}

/// [`read_gap_rows`], with what was recovered when the file was never finalised and what
/// was not measured.
pub fn read_gap_rows_reporting(
    path: &Path,
    topics: &RecordingTopics,
) -> Result<(Vec<GapRow>, GapReport), BridgeError> {
    let bad = |message: String| BridgeError::format(path, message);
    let bag = read_bag(
        path,
        &topics.all().iter().map(String::as_str).collect::<Vec<_>>(),
    )
    .map_err(bag_error)?;
    let drive = drive_commands(&bag, path, topics).map_err(bag_error)?;
    let track = planar_track(&bag, path, topics).map_err(bag_error)?;
    let first_cmd = drive[0].log_time;
    let mut rows = Vec::with_capacity(track.samples.len());
    let mut k = 0;
    let mut t0 = None;
    for s in &track.samples {
        let t = s.log_time;
        if t < first_cmd {
            continue;
        }
        while k + 1 < drive.len() && drive[k + 1].log_time <= t {
            k += 1;
        }
        let t0 = *t0.get_or_insert(t);
        rows.push(GapRow {
            t: (t - t0) as f64 * 1e-9,
            steer_cmd: drive[k].steer,
            speed_cmd: drive[k].speed,
            state: s.state,
        });
    }
    if rows.is_empty() {
        return Err(bad(format!(
            "no {} pose at or after the first {} command",
            topics.pose_topic(),
            topics.drive
        )));
    }
    Ok((
        rows,
        GapReport {
            truncation: bag.truncation,
            notes: track.notes,
        },
    ))
}

/// Export a recording (a `paddock bridge record` MCAP, a rosbag2 bag folder in SQLite3
/// or MCAP storage, or a bare `.db3`) to the reality-gap CSV `out`; returns the rows
/// written and what was recovered (an MCAP file never finalised) or not measured.
pub fn export_csv(
    recording: &Path,
    out: &Path,
    topics: &RecordingTopics,
) -> Result<(usize, GapReport), BridgeError> {
    let (rows, report) = read_gap_rows_reporting(recording, topics)?;
    let io = |e| BridgeError::io(out, e);
    let mut w = BufWriter::new(File::create(out).map_err(io)?);
    writeln!(w, "{GAP_CSV_HEADER}").map_err(io)?;
    for r in &rows {
        let s = &r.state;
        // a channel not measured is an empty field, as the reality-gap CSV takes it
        let v = |x: f64| {
            if x.is_finite() {
                x.to_string()
            } else {
                String::new()
            }
        };
        writeln!(
            w,
            "{},{},{},{},{},{},{},{},{}",
            r.t,
            r.steer_cmd,
            r.speed_cmd,
            s.x,
            s.y,
            s.yaw,
            v(s.vx),
            v(s.vy),
            v(s.yaw_rate)
        )
        .map_err(io)?;
    }
    w.flush().map_err(io)?;
    Ok((rows.len(), report))
}

#[cfg(test)]
mod tests {
    use super::*;
    use paddock_recordings::msg::{AckermannDrive, Header, Quaternion};

    #[test]
    fn bag_round_trips_to_gap_rows() {
        let dir = std::env::temp_dir().join(format!("paddock-bridge-bag-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("run.mcap");
        let topics = RecordingTopics::default();
        let mut bag = McapBag::new(
            BufWriter::new(File::create(&path).unwrap()),
            "run.mcap",
            LIBRARY,
        )
        .unwrap();
        bag.add_topic::<Odometry>(&topics.odom).unwrap();
        bag.add_topic::<AckermannDriveStamped>(&topics.drive)
            .unwrap();
        let s = 1_000_000_000u64;
        let mut odom = Odometry::default();
        // odometry before the first command is left out
        bag.write(&topics.odom, &odom, 5 * s, 5 * s).unwrap();
        let cmd = |steer: f32, speed: f32| AckermannDriveStamped {
            header: Header::default(),
            drive: AckermannDrive {
                steering_angle: steer,
                speed,
                ..Default::default()
            },
        };
        bag.write(&topics.drive, &cmd(0.1, 2.0), 6 * s, 6 * s)
            .unwrap();
        for k in 0..4u64 {
            odom.pose.pose.position.x = k as f64;
            odom.pose.pose.orientation = Quaternion::from_yaw(3.0 + k as f64);
            odom.twist.twist.linear.x = 1.5;
            bag.write(&topics.odom, &odom, 6 * s + k * s / 10, 0)
                .unwrap();
        }
        bag.write(&topics.drive, &cmd(-0.2, 3.0), 6 * s + s / 10, 0)
            .unwrap();
        bag.finish().unwrap().flush().unwrap();
        let rows = read_gap_rows(&path, &topics).unwrap();
        assert_eq!(rows.len(), 4);
        assert_eq!(rows[0].t, 0.0);
        assert!((rows[3].t - 0.3).abs() < 1e-9);
        assert_eq!((rows[0].steer_cmd as f32, rows[0].speed_cmd), (0.1, 2.0));
        // a command logged at the same time as an odometry message applies to it
        assert_eq!((rows[1].steer_cmd as f32, rows[1].speed_cmd), (-0.2, 3.0));
        for r in &rows {
            assert!((-std::f64::consts::PI..std::f64::consts::PI).contains(&r.state.yaw));
        }
        let csv = dir.join("run.csv");
        // vy and the yaw rate are 0 in every message while the car moves 3 m: not set
        let (n, report) = export_csv(&path, &csv, &topics).unwrap();
        assert_eq!((n, report.truncation), (4, None));
        assert_eq!(report.notes.len(), 1);
        assert!(
            report.notes[0].starts_with("vy, yaw_rate exactly 0 in every /odom message"),
            "{:?}",
            report.notes
        );
        let text = std::fs::read_to_string(&csv).unwrap();
        assert!(text.starts_with(&format!("{GAP_CSV_HEADER}\n0,")));
        // a channel not measured is an empty field
        assert!(text.lines().nth(1).unwrap().ends_with(",1.5,,"), "{text}");
        // errors name the file and what is missing
        let other = RecordingTopics {
            drive: "/other".into(),
            ..RecordingTopics::default()
        };
        let e = read_gap_rows(&path, &other).unwrap_err().to_string();
        assert!(e.contains("/other") && e.contains("run.mcap"), "{e}");
        std::fs::write(&csv, b"not mcap").unwrap();
        assert!(read_gap_rows(&csv, &topics).is_err());
        std::fs::remove_dir_all(&dir).ok();
    }
}
