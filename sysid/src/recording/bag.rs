//! A [`Recording`] from and to a ROS 2 bag: `ackermann_msgs/msg/AckermannDriveStamped`
//! commands and `nav_msgs/msg/Odometry` states, through the messages and the CDR codec of
//! `paddock-recordings` (the ones the bridge speaks on the car).

use std::io::Cursor;
use std::path::Path;

use paddock_recordings::msg::{
    AckermannDrive, AckermannDriveStamped, Header, Odometry, Pose, PoseWithCovariance, Quaternion,
    Time, Twist, TwistWithCovariance, Vector3,
};
use paddock_recordings::track::{drive_commands, planar_track};
use paddock_recordings::write::McapBag;
use paddock_recordings::{Bag, RecordingError};

use super::{Command, Recording, RecordingTopics, StateSample, clean};
use crate::SysidError;

/// How an MCAP recording given as bytes is named in errors.
const MCAP_NAME: &str = "the MCAP recording";

/// Frame ids of the bags [`Recording::to_mcap`] writes.
const ODOM_FRAME: &str = "map";
const BASE_FRAME: &str = "base_link";

fn format_error(e: RecordingError) -> SysidError {
    SysidError::Format {
        message: e.to_string(),
    }
}

impl Recording {
    /// Decode a ROS 2 bag: `ackermann_msgs/msg/AckermannDriveStamped` on the drive topic,
    /// the pose and the velocities as [`RecordingTopics`] says (read by
    /// `paddock_recordings::track`), all CDR. Time is the log time, from the first message
    /// of either.
    pub fn from_mcap(bytes: &[u8], topics: &RecordingTopics) -> Result<Self, SysidError> {
        let bag = paddock_recordings::read_mcap(
            bytes,
            Path::new(MCAP_NAME),
            &topics.all().iter().map(String::as_str).collect::<Vec<_>>(),
        )
        .map_err(format_error)?;
        Self::from_bag(bag, topics, Path::new(MCAP_NAME))
    }

    /// `path` names the recording in errors.
    pub(super) fn from_bag(
        bag: Bag,
        topics: &RecordingTopics,
        path: &Path,
    ) -> Result<Self, SysidError> {
        let drive = drive_commands(&bag, path, topics).map_err(format_error)?;
        let track = planar_track(&bag, path, topics).map_err(format_error)?;
        if track.samples.is_empty() {
            return Err(SysidError::Format {
                message: format!(
                    "no finite pose on {:?} ({})",
                    topics.pose_topic(),
                    track.notes.join("; ")
                ),
            });
        }
        let t0 = drive[0].log_time.min(track.samples[0].log_time);
        let secs = |ns: u64| (ns - t0) as f64 * 1e-9;
        let mut rec = Recording::default();
        if let Some(t) = &bag.truncation {
            rec.warnings.push(t.to_string());
        }
        rec.warnings.extend(track.notes);
        for d in drive {
            if !(d.steer.is_finite() && d.speed.is_finite()) {
                rec.warnings.push(format!(
                    "non-finite drive command at t = {:.3} s skipped",
                    secs(d.log_time)
                ));
                continue;
            }
            rec.commands.push(Command {
                t: secs(d.log_time),
                steer: d.steer,
                speed: d.speed,
            });
        }
        for s in track.samples {
            let p = s.state;
            rec.states.push(StateSample {
                t: secs(s.log_time),
                x: p.x,
                y: p.y,
                yaw: p.yaw,
                vx: p.vx,
                vy: p.vy,
                yaw_rate: p.yaw_rate,
            });
        }
        let runs = clean::into_runs(rec.commands, rec.states, false, rec.warnings, "bag")?;
        Ok(Self::join(runs))
    }

    /// Write a ROS 2 bag (uncompressed MCAP) with the drive and odometry topics.
    pub fn to_mcap(&self, topics: &RecordingTopics) -> Result<Vec<u8>, SysidError> {
        let library = concat!("paddock-sysid ", env!("CARGO_PKG_VERSION"));
        let mut bag =
            McapBag::new(Cursor::new(Vec::new()), MCAP_NAME, library).map_err(format_error)?;
        bag.add_topic::<AckermannDriveStamped>(&topics.drive)
            .map_err(format_error)?;
        bag.add_topic::<Odometry>(&topics.odom)
            .map_err(format_error)?;
        // merge both streams in time order
        let mut events: Vec<(u64, bool, usize)> = self
            .commands
            .iter()
            .enumerate()
            .map(|(i, c)| (secs_to_ns(c.t), true, i))
            .chain(
                self.states
                    .iter()
                    .enumerate()
                    .map(|(i, s)| (secs_to_ns(s.t), false, i)),
            )
            .collect();
        events.sort();
        for (ns, is_drive, i) in events {
            let written = if is_drive {
                let c = self.commands[i];
                bag.write(&topics.drive, &drive_message(ns, c.steer, c.speed), ns, ns)
            } else {
                bag.write(&topics.odom, &odometry_message(ns, &self.states[i]), ns, ns)
            };
            written.map_err(format_error)?;
        }
        Ok(bag.finish().map_err(format_error)?.into_inner())
    }
}

fn secs_to_ns(t: f64) -> u64 {
    (t * 1e9).round().max(0.0) as u64
}

fn drive_message(ns: u64, steer: f64, speed: f64) -> AckermannDriveStamped {
    AckermannDriveStamped {
        header: Header::new(Time::from_nanos(ns), BASE_FRAME),
        drive: AckermannDrive {
            steering_angle: steer as f32,
            speed: speed as f32,
            ..AckermannDrive::default()
        },
    }
}

fn odometry_message(ns: u64, s: &StateSample) -> Odometry {
    let mut o = Odometry {
        header: Header::new(Time::from_nanos(ns), ODOM_FRAME),
        child_frame_id: BASE_FRAME.into(),
        pose: PoseWithCovariance::default(),
        twist: TwistWithCovariance::default(),
    };
    o.pose.pose = Pose {
        orientation: Quaternion::from_yaw(s.yaw),
        ..Pose::default()
    };
    o.pose.pose.position.x = s.x;
    o.pose.pose.position.y = s.y;
    o.twist.twist = Twist {
        linear: Vector3 {
            x: s.vx,
            y: s.vy,
            z: 0.0,
        },
        angular: Vector3 {
            x: 0.0,
            y: 0.0,
            z: s.yaw_rate,
        },
    };
    o
}

#[cfg(test)]
mod tests {
    use super::*;
    use paddock_recordings::cdr::from_cdr;

    /// `n` states 25 ms apart driving along x, a command with each.
    fn recording(n: usize) -> Recording {
        let at = |i: usize| i as f64 * 0.025;
        Recording {
            commands: (0..n)
                .map(|i| Command {
                    t: at(i),
                    steer: 0.1,
                    speed: 2.0,
                })
                .collect(),
            states: (0..n)
                .map(|i| StateSample {
                    t: at(i),
                    x: at(i),
                    y: 0.0,
                    yaw: 0.5,
                    vx: 1.0,
                    vy: 0.1,
                    yaw_rate: 0.2,
                })
                .collect(),
            ..Recording::default()
        }
    }

    #[test]
    fn mcap_round_trip() {
        let r = recording(200);
        let topics = RecordingTopics {
            drive: "/car/drive".into(),
            odom: "/car/odom".into(),
            ..RecordingTopics::default()
        };
        let bytes = r.to_mcap(&topics).unwrap();
        let back = Recording::from_mcap(&bytes, &topics).unwrap();
        assert_eq!(back.states.len(), 200);
        assert_eq!(back.commands.len(), 200);
        assert!((back.states[50].x - r.states[50].x).abs() < 1e-9);
        assert!((back.states[50].t - r.states[50].t).abs() < 1e-9);
        assert!((back.states[50].yaw - 0.5).abs() < 1e-12);
        assert_eq!(
            (
                back.states[9].vx,
                back.states[9].vy,
                back.states[9].yaw_rate
            ),
            (1.0, 0.1, 0.2)
        );
        assert!((back.commands[7].steer - 0.1).abs() < 1e-6);
        let e = Recording::from_mcap(&bytes, &RecordingTopics::default()).unwrap_err();
        assert!(e.to_string().contains("/car/drive"), "{e}");
        let e = Recording::from_mcap(b"\x89MCAP0\r\ngarbage", &topics).unwrap_err();
        assert!(e.to_string().contains("MCAP"), "{e}");
    }

    /// The bag's messages are the ROS types: what the bridge's `export-csv` reads too.
    #[test]
    fn the_bag_carries_the_ros_messages_and_their_schemas() {
        let r = recording(120);
        let bytes = r.to_mcap(&RecordingTopics::default()).unwrap();
        let bag = paddock_recordings::read_mcap(&bytes, Path::new("x.mcap"), &["/odom", "/drive"])
            .unwrap();
        assert_eq!(
            bag.topics["/drive"].type_name,
            "ackermann_msgs/msg/AckermannDriveStamped"
        );
        assert!(bag.topics["/odom"].offered_qos_profiles.is_some());
        let odom = bag.messages.iter().find(|m| m.topic == "/odom").unwrap();
        let o: Odometry = from_cdr(&odom.data).unwrap();
        assert_eq!(
            (o.header.frame_id.as_str(), o.child_frame_id.as_str()),
            (ODOM_FRAME, BASE_FRAME)
        );
        let drive = bag.messages.iter().find(|m| m.topic == "/drive").unwrap();
        let d: AckermannDriveStamped = from_cdr(&drive.data).unwrap();
        assert_eq!(Time::from_nanos(drive.log_time), d.header.stamp);
        assert_eq!(d.drive.speed, 2.0);
    }
}
