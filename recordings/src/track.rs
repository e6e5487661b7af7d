//! A car's track in the plane from a recording: its pose from one topic and its
//! velocities from another or the same, each read as the type the recording names.
//!
//! A real car's stack seldom puts both in one message that measures both. The pose comes
//! from a localiser (a particle filter's `nav_msgs/Odometry` with an unset twist, AMCL's
//! `PoseWithCovarianceStamped`) or a motion-capture system (`PoseStamped`); the speed
//! from the VESC's odometry (`/odom`, whose own pose is dead reckoning). [`planar_track`]
//! takes the pose topic and the velocity topic apart:
//!
//! - the pose topic may carry `nav_msgs/msg/Odometry`, `geometry_msgs/msg/PoseStamped`,
//!   `geometry_msgs/msg/PoseWithCovarianceStamped`, or the transforms
//!   (`tf2_msgs/msg/TFMessage` on `/tf`, with `/tf_static`: the pose of one frame in
//!   another, [`tf`]); the velocity topic `nav_msgs/msg/Odometry` (its twist, in the body
//!   frame). Both may be one topic;
//! - from another topic, the velocities at a pose are interpolated in log time between
//!   the two velocity messages around it, when they are at most
//!   [`MAX_VELOCITY_GAP_NS`] apart; elsewhere they are not measured (NaN);
//! - a velocity component that is exactly 0 in every message while the pose moves
//!   [`MOVING_M`] or more was never set (a localiser's twist, the VESC's lateral speed): it
//!   is taken as not measured (NaN) and said in [`Track::notes`].
//!
//! Times are the log times, as everywhere in a recording's analysis.

use std::path::Path;

pub mod tf;

use crate::cdr::from_cdr;
use crate::msg::{
    AckermannDriveStamped, Odometry, PlanarState, Pose, PoseStamped, PoseWithCovarianceStamped,
    RosMessage, TFMessage, Twist,
};
use crate::{Bag, RecordingError};

/// The topics of a recording that a car's track and its commands are read from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordingTopics {
    /// `ackermann_msgs/msg/AckermannDriveStamped` commands.
    pub drive: String,
    /// `nav_msgs/msg/Odometry`: the velocities (its twist), and the pose unless `pose`.
    pub odom: String,
    /// The pose's own topic (a localiser's or motion capture's): any of [`POSE_TYPES`].
    pub pose: Option<String>,
    /// With transforms for the pose (`/tf`): the parent and the child frame whose pose is
    /// read (default [`DEFAULT_POSE_FRAMES`]).
    pub pose_frames: Option<[String; 2]>,
}

/// The frames a pose is read between from transforms unless said: the car's `base_link`
/// in the `map`.
pub const DEFAULT_POSE_FRAMES: [&str; 2] = ["map", "base_link"];

impl RecordingTopics {
    /// The topic the pose is read from.
    pub fn pose_topic(&self) -> &str {
        self.pose.as_deref().unwrap_or(&self.odom)
    }

    /// The static transforms that go with transforms on the pose topic: `/tf_static` for
    /// `/tf`.
    pub fn static_tf_topic(&self) -> String {
        format!("{}_static", self.pose_topic())
    }

    /// Every topic read.
    pub fn all(&self) -> Vec<String> {
        vec![
            self.drive.clone(),
            self.odom.clone(),
            self.pose_topic().to_string(),
            self.static_tf_topic(),
        ]
    }
}

impl Default for RecordingTopics {
    fn default() -> Self {
        Self {
            drive: "/drive".into(),
            odom: "/odom".into(),
            pose: None,
            pose_frames: None,
        }
    }
}

/// The types a pose topic may carry.
pub const POSE_TYPES: [&str; 4] = [
    "nav_msgs/msg/Odometry",
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "tf2_msgs/msg/TFMessage",
];

/// The longest time between two velocity messages that a pose between them takes its
/// velocities from [ns] (0.2 s: ten periods of a 50-Hz VESC odometry).
pub const MAX_VELOCITY_GAP_NS: u64 = 200_000_000;

/// How far the pose must move (the diagonal of the box around it) before a velocity
/// component that is 0 in every message is taken as unset rather than measured [m].
pub const MOVING_M: f64 = 0.5;

/// One sample of a [`Track`]: the state at a pose message's log time. A channel that was
/// not measured there is NaN.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackSample {
    /// Nanoseconds since the epoch (the pose message's log time).
    pub log_time: u64,
    pub state: PlanarState,
}

/// A car's track read from a recording.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Track {
    /// By log time, one per pose message with a finite pose.
    pub samples: Vec<TrackSample>,
    /// What was not measured or was skipped, and why (for the user).
    pub notes: Vec<String>,
}

#[derive(Clone, Copy, PartialEq)]
enum PoseKind {
    Odometry,
    PoseStamped,
    PoseWithCovariance,
    Transforms,
}

/// The type name as `pkg/msg/Type` (ROS 1 era tools write `pkg/Type`).
fn canonical(type_name: &str) -> String {
    match type_name.split('/').collect::<Vec<_>>()[..] {
        [pkg, ty] => format!("{pkg}/msg/{ty}"),
        _ => type_name.to_string(),
    }
}

/// The pose topic's kind, or why it cannot be read.
fn pose_kind(bag: &Bag, path: &Path, topic: &str) -> Result<PoseKind, RecordingError> {
    let Some(info) = bag.topics.get(topic).filter(|i| i.messages > 0) else {
        return Err(RecordingError::format(
            path,
            format!(
                "no messages on the pose topic {topic:?} (topics in the recording: {})",
                bag.topic_list()
            ),
        ));
    };
    check_encoding(path, topic, &info.encoding)?;
    let ty = canonical(&info.type_name);
    [
        (Odometry::schema_name(), PoseKind::Odometry),
        (PoseStamped::schema_name(), PoseKind::PoseStamped),
        (
            PoseWithCovarianceStamped::schema_name(),
            PoseKind::PoseWithCovariance,
        ),
        (TFMessage::schema_name(), PoseKind::Transforms),
    ]
    .into_iter()
    .find(|(name, _)| *name == ty)
    .map(|(_, k)| k)
    .ok_or_else(|| {
        RecordingError::format(
            path,
            format!(
                "the pose topic {topic:?} carries {}; a pose is read from {}",
                info.type_name,
                POSE_TYPES.join(", ")
            ),
        )
    })
}

fn check_encoding(path: &Path, topic: &str, encoding: &str) -> Result<(), RecordingError> {
    if encoding == "cdr" {
        Ok(())
    } else {
        Err(RecordingError::format(
            path,
            format!("topic {topic:?} has message encoding {encoding:?}; only cdr (ROS 2) is read"),
        ))
    }
}

fn decode<T: RosMessage>(
    path: &Path,
    topic: &str,
    index: usize,
    data: &[u8],
) -> Result<T, RecordingError> {
    from_cdr(data).map_err(|e| {
        RecordingError::format(
            path,
            format!(
                "{topic} message {index} is not a valid {}: {e}",
                T::schema_name()
            ),
        )
    })
}

fn velocities(t: &Twist) -> [f64; 3] {
    [t.linear.x, t.linear.y, t.angular.z]
}

const VELOCITY_NAMES: [&str; 3] = ["vx", "vy", "yaw_rate"];

/// A drive command as recorded: its log time [ns], steering angle [rad] and speed [m/s].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriveCommand {
    pub log_time: u64,
    pub steer: f64,
    pub speed: f64,
}

/// The drive commands of `bag` on `topics.drive` (`ackermann_msgs/msg/AckermannDriveStamped`,
/// CDR), by log time, at least one; an error names the topic, its type and what the
/// recording holds when there are none or they are not commands.
pub fn drive_commands(
    bag: &Bag,
    path: &Path,
    topics: &RecordingTopics,
) -> Result<Vec<DriveCommand>, RecordingError> {
    let topic = topics.drive.as_str();
    let Some(info) = bag.topics.get(topic).filter(|i| i.messages > 0) else {
        return Err(RecordingError::format(
            path,
            format!(
                "no messages on the drive topic {topic:?} (topics in the recording: {})",
                bag.topic_list()
            ),
        ));
    };
    check_encoding(path, topic, &info.encoding)?;
    if canonical(&info.type_name) != AckermannDriveStamped::schema_name() {
        return Err(RecordingError::format(
            path,
            format!(
                "the drive topic {topic:?} carries {}; commands are read from {}",
                info.type_name,
                AckermannDriveStamped::schema_name()
            ),
        ));
    }
    let mut out = Vec::new();
    for m in bag.messages.iter().filter(|m| m.topic == topic) {
        let d: AckermannDriveStamped = decode(path, topic, out.len(), &m.data)?;
        out.push(DriveCommand {
            log_time: m.log_time,
            steer: d.drive.steering_angle as f64,
            speed: d.drive.speed as f64,
        });
    }
    if out.is_empty() {
        return Err(RecordingError::format(
            path,
            format!("no messages on the drive topic {topic:?} were recovered"),
        ));
    }
    out.sort_by_key(|d| d.log_time);
    Ok(out)
}

/// Read the track of `bag` (which must hold the messages of [`RecordingTopics::all`]):
/// the pose from its pose topic, the velocities from its odometry topic (see the module
/// docs). `path` names the recording in errors.
pub fn planar_track(
    bag: &Bag,
    path: &Path,
    topics: &RecordingTopics,
) -> Result<Track, RecordingError> {
    let (pose_topic, velocity_topic) = (topics.pose_topic(), topics.odom.as_str());
    let kind = pose_kind(bag, path, pose_topic)?;
    if kind != PoseKind::Transforms
        && let Some([p, c]) = &topics.pose_frames
    {
        return Err(RecordingError::format(
            path,
            format!(
                "pose frames {p},{c} are read from transforms (tf2_msgs/msg/TFMessage); the \
                 pose topic {pose_topic:?} carries {}",
                bag.topics[pose_topic].type_name
            ),
        ));
    }
    let mut notes = Vec::new();
    let same = velocity_topic == pose_topic;
    // where the velocities come from: the pose's own Odometry, another topic, or nowhere
    let separate = if same {
        if kind != PoseKind::Odometry {
            notes.push(format!(
                "{pose_topic} carries {} (no velocities): vx, vy and yaw_rate not measured",
                canonical(&bag.topics[pose_topic].type_name)
            ));
        }
        false
    } else {
        match bag.topics.get(velocity_topic).filter(|i| i.messages > 0) {
            None => {
                notes.push(format!(
                    "no messages on the velocity topic {velocity_topic:?}: vx, vy and \
                     yaw_rate not measured"
                ));
                false
            }
            Some(info) => {
                check_encoding(path, velocity_topic, &info.encoding)?;
                if canonical(&info.type_name) != Odometry::schema_name() {
                    return Err(RecordingError::format(
                        path,
                        format!(
                            "the velocity topic {velocity_topic:?} carries {}; velocities are \
                             read from {}'s twist",
                            info.type_name,
                            Odometry::schema_name()
                        ),
                    ));
                }
                true
            }
        }
    };

    let mut poses: Vec<(u64, [f64; 3], [f64; 3])> = Vec::new();
    if kind == PoseKind::Transforms {
        let [parent, child] = topics
            .pose_frames
            .clone()
            .unwrap_or(DEFAULT_POSE_FRAMES.map(String::from));
        let static_topic = topics.static_tf_topic();
        let (p, tf_notes) = tf::frame_poses(bag, path, pose_topic, &static_topic, &parent, &child)?;
        poses = p.into_iter().map(|(t, p)| (t, p, [f64::NAN; 3])).collect();
        notes.extend(tf_notes);
    }
    let mut vels: Vec<(u64, [f64; 3])> = Vec::new();
    let (mut n_pose, mut n_vel, mut non_finite) = (0usize, 0usize, 0usize);
    for m in &bag.messages {
        if m.topic == pose_topic {
            let (pose, v): (Pose, [f64; 3]) = match kind {
                PoseKind::Odometry => {
                    let o: Odometry = decode(path, pose_topic, n_pose, &m.data)?;
                    let v = if same {
                        velocities(&o.twist.twist)
                    } else {
                        [f64::NAN; 3]
                    };
                    (o.pose.pose, v)
                }
                PoseKind::PoseStamped => {
                    let p: PoseStamped = decode(path, pose_topic, n_pose, &m.data)?;
                    (p.pose, [f64::NAN; 3])
                }
                PoseKind::PoseWithCovariance => {
                    let p: PoseWithCovarianceStamped = decode(path, pose_topic, n_pose, &m.data)?;
                    (p.pose.pose, [f64::NAN; 3])
                }
                // read above, by `tf`
                PoseKind::Transforms => continue,
            };
            n_pose += 1;
            let p = pose.planar();
            if p.iter().all(|x| x.is_finite()) {
                poses.push((m.log_time, p, v));
            } else {
                non_finite += 1;
            }
        } else if separate && m.topic == velocity_topic {
            let o: Odometry = decode(path, velocity_topic, n_vel, &m.data)?;
            n_vel += 1;
            vels.push((m.log_time, velocities(&o.twist.twist)));
        }
    }
    if non_finite > 0 {
        notes.push(format!(
            "{non_finite} of {n_pose} {pose_topic} messages with a non-finite pose skipped"
        ));
    }
    poses.sort_by_key(|p| p.0);
    vels.sort_by_key(|v| v.0);

    // the box around the poses: does the car move?
    let extent = {
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for (_, p, _) in &poses {
            for k in 0..2 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        if poses.is_empty() {
            0.0
        } else {
            (hi[0] - lo[0]).hypot(hi[1] - lo[1])
        }
    };
    // components never set: exactly 0 in every message while the car moves
    let unset: [bool; 3] = std::array::from_fn(|c| {
        let mut values = if separate {
            Box::new(vels.iter().map(|v| v.1[c])) as Box<dyn Iterator<Item = f64>>
        } else {
            Box::new(poses.iter().map(|p| p.2[c]))
        };
        let mut n = 0usize;
        let all_zero = values.all(|x| {
            n += 1;
            x == 0.0
        });
        all_zero && n >= 2 && extent >= MOVING_M
    });
    if unset.iter().any(|&u| u) {
        let names: Vec<&str> = (0..3)
            .filter(|&c| unset[c])
            .map(|c| VELOCITY_NAMES[c])
            .collect();
        let topic = if separate { velocity_topic } else { pose_topic };
        notes.push(format!(
            "{} exactly 0 in every {topic} message while the car moves {extent:.1} m: taken \
             as not measured (a field the source leaves unset)",
            names.join(", ")
        ));
    }

    let mut samples = Vec::with_capacity(poses.len());
    let mut k = 0usize;
    let mut unmatched = 0usize;
    for (t, p, own) in poses {
        let mut v = own;
        if separate {
            // the last velocity message at or before t, and the next
            while k + 1 < vels.len() && vels[k + 1].0 <= t {
                k += 1;
            }
            v = match (vels.get(k), vels.get(k + 1)) {
                (Some(a), _) if a.0 == t => a.1,
                (Some(a), Some(b)) if a.0 < t && t < b.0 && b.0 - a.0 <= MAX_VELOCITY_GAP_NS => {
                    let u = (t - a.0) as f64 / (b.0 - a.0) as f64;
                    std::array::from_fn(|c| a.1[c] + u * (b.1[c] - a.1[c]))
                }
                _ => {
                    unmatched += 1;
                    [f64::NAN; 3]
                }
            };
        }
        for c in 0..3 {
            if unset[c] || !v[c].is_finite() {
                v[c] = f64::NAN;
            }
        }
        samples.push(TrackSample {
            log_time: t,
            state: PlanarState {
                x: p[0],
                y: p[1],
                yaw: p[2],
                vx: v[0],
                vy: v[1],
                yaw_rate: v[2],
            },
        });
    }
    if separate && unmatched > 0 {
        notes.push(format!(
            "{unmatched} of {} poses without {velocity_topic} messages around them within \
             {:.1} s: their velocities not measured",
            samples.len(),
            MAX_VELOCITY_GAP_NS as f64 * 1e-9
        ));
    }
    Ok(Track { samples, notes })
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;
    use crate::cdr::to_cdr;
    use crate::msg::{Header, Quaternion, Time};
    use crate::{BagMessage, StorageFormat, TopicInfo};

    const S: u64 = 1_000_000_000;

    #[derive(Default)]
    struct Rec {
        messages: Vec<BagMessage>,
        topics: BTreeMap<String, TopicInfo>,
    }

    impl Rec {
        fn add<M: RosMessage>(&mut self, topic: &str, t: u64, m: &M) {
            self.add_typed(topic, &M::schema_name(), t, to_cdr(m).unwrap());
        }

        fn add_typed(&mut self, topic: &str, type_name: &str, t: u64, data: Vec<u8>) {
            self.topics
                .entry(topic.to_string())
                .or_insert_with(|| TopicInfo {
                    type_name: type_name.to_string(),
                    encoding: "cdr".into(),
                    messages: 0,
                    offered_qos_profiles: None,
                })
                .messages += 1;
            self.messages.push(BagMessage {
                topic: topic.to_string(),
                log_time: t,
                data,
            });
        }

        fn bag(mut self) -> Bag {
            self.messages.sort_by_key(|m| m.log_time);
            Bag {
                format: StorageFormat::Mcap,
                messages: self.messages,
                topics: self.topics,
                truncation: None,
            }
        }
    }

    fn pose(x: f64, yaw: f64) -> Pose {
        let mut p = Pose {
            orientation: Quaternion::from_yaw(yaw),
            ..Pose::default()
        };
        p.position.x = x;
        p
    }

    fn odom(x: f64, vx: f64, vy: f64, wz: f64) -> Odometry {
        let mut o = Odometry::default();
        o.pose.pose = pose(x, 0.1);
        o.twist.twist.linear.x = vx;
        o.twist.twist.linear.y = vy;
        o.twist.twist.angular.z = wz;
        o
    }

    fn stamped(x: f64) -> PoseStamped {
        PoseStamped {
            header: Header::new(Time::default(), "map"),
            pose: pose(x, 0.1),
        }
    }

    fn track(bag: &Bag, pose: &str, vel: &str) -> Result<Track, String> {
        let topics = RecordingTopics {
            odom: vel.into(),
            pose: Some(pose.into()),
            ..RecordingTopics::default()
        };
        planar_track(bag, Path::new("run.mcap"), &topics).map_err(|e| e.to_string())
    }

    #[test]
    fn one_odometry_topic_gives_pose_and_velocities() {
        let mut r = Rec::default();
        for k in 0..20u64 {
            r.add("/odom", k * S / 20, &odom(k as f64 * 0.1, 2.0, 0.1, 0.3));
        }
        let t = track(&r.bag(), "/odom", "/odom").unwrap();
        assert_eq!(t.samples.len(), 20);
        assert!(t.notes.is_empty(), "{:?}", t.notes);
        let s = t.samples[7].state;
        assert_eq!((s.x, s.vx, s.vy, s.yaw_rate), (7.0 * 0.1, 2.0, 0.1, 0.3));
        assert!((s.yaw - 0.1).abs() < 1e-12);
    }

    #[test]
    fn a_motion_capture_pose_takes_the_vesc_speed_between_its_messages() {
        let mut r = Rec::default();
        // poses at 100 Hz from 0.005 s, speeds at 20 Hz from 0 with a hole from 0.5 to 1 s
        for k in 0..150u64 {
            r.add("/mocap", S / 200 + k * S / 100, &stamped(k as f64 * 0.02));
        }
        for k in 0..30u64 {
            if !(10..20).contains(&k) {
                r.add("/odom", k * S / 20, &odom(0.0, k as f64, 0.0, 0.0));
            }
        }
        let t = track(&r.bag(), "/mocap", "/odom").unwrap();
        assert_eq!(t.samples.len(), 150);
        // interpolated: at 0.005 s, between 0 (0 m/s) and 0.05 s (1 m/s)
        assert!((t.samples[0].state.vx - 0.1).abs() < 1e-12);
        assert!((t.samples[10].state.vx - 2.1).abs() < 1e-12);
        // in the hole (0.45 -> 1.0 s is 0.55 s apart) and after the last (1.45 s): NaN
        assert!(t.samples[60].state.vx.is_nan());
        assert!(t.samples[149].state.vx.is_nan());
        // vy and yaw_rate are 0 in every message while the car moves 3 m: unset
        assert!(t.samples[0].state.vy.is_nan() && t.samples[0].state.yaw_rate.is_nan());
        let notes = t.notes.join("\n");
        assert!(
            notes.contains("vy, yaw_rate exactly 0 in every /odom message"),
            "{notes}"
        );
        assert!(
            notes.contains("of 150 poses without /odom messages"),
            "{notes}"
        );
    }

    #[test]
    fn a_localisers_unset_twist_is_not_taken_as_standing_still() {
        let mut r = Rec::default();
        for k in 0..40u64 {
            r.add(
                "/pf/pose/odom",
                k * S / 40,
                &odom(k as f64 * 0.05, 0.0, 0.0, 0.0),
            );
        }
        let t = track(&r.bag(), "/pf/pose/odom", "/pf/pose/odom").unwrap();
        assert!(t.samples.iter().all(|s| s.state.vx.is_nan()));
        assert!(
            t.notes[0].starts_with("vx, vy, yaw_rate exactly 0"),
            "{:?}",
            t.notes
        );
        // a car at rest: its zeros are measured
        let mut r = Rec::default();
        for k in 0..40u64 {
            r.add("/odom", k * S / 40, &odom(1e-3 * k as f64, 0.0, 0.0, 0.0));
        }
        let t = track(&r.bag(), "/odom", "/odom").unwrap();
        assert!(t.samples.iter().all(|s| s.state.vx == 0.0));
        assert!(t.notes.is_empty());
    }

    #[test]
    fn an_amcl_pose_alone_has_no_velocities() {
        let mut r = Rec::default();
        for k in 0..5u64 {
            let mut p = PoseWithCovarianceStamped::default();
            p.pose.pose = pose(k as f64, -3.0);
            r.add("/amcl_pose", k * S, &p);
        }
        let bag = r.bag();
        let t = track(&bag, "/amcl_pose", "/amcl_pose").unwrap();
        assert_eq!(t.samples.len(), 5);
        assert!((t.samples[4].state.yaw + 3.0).abs() < 1e-12 && t.samples[4].state.x == 4.0);
        assert!(t.notes[0].contains("PoseWithCovarianceStamped (no velocities)"));
        // a velocity topic that is not in the recording
        let t = track(&bag, "/amcl_pose", "/odom").unwrap();
        assert!(t.notes[0].contains("no messages on the velocity topic \"/odom\""));
    }

    #[test]
    fn errors_name_the_topic_its_type_and_what_is_read() {
        let mut r = Rec::default();
        r.add("/odom", 0, &odom(0.0, 1.0, 0.0, 0.0));
        r.add("/mocap", 0, &stamped(0.0));
        r.add_typed("/scan", "sensor_msgs/msg/LaserScan", 0, vec![0, 1, 0, 0]);
        r.add_typed("/broken", "nav_msgs/Odometry", 0, vec![0, 1, 0, 0, 9]);
        let bag = r.bag();
        let e = track(&bag, "/pose", "/odom").unwrap_err();
        assert!(e.contains("run.mcap") && e.contains("no messages on the pose topic \"/pose\""));
        assert!(e.contains("/odom (1 nav_msgs/msg/Odometry)"), "{e}");
        let e = track(&bag, "/scan", "/odom").unwrap_err();
        assert!(
            e.contains("carries sensor_msgs/msg/LaserScan; a pose is read from"),
            "{e}"
        );
        let e = track(&bag, "/mocap", "/mocap2").unwrap();
        assert!(e.notes[0].contains("/mocap2"));
        let e = track(&bag, "/odom", "/mocap").unwrap_err();
        assert!(e.contains("the velocity topic \"/mocap\" carries geometry_msgs/msg/PoseStamped"));
        // a ROS 1 style type name is read; a message that does not decode is named
        let e = track(&bag, "/broken", "/broken").unwrap_err();
        assert!(
            e.contains("/broken message 0 is not a valid nav_msgs/msg/Odometry"),
            "{e}"
        );
    }

    fn transform(parent: &str, child: &str, p: [f64; 3]) -> crate::msg::TransformStamped {
        let mut t = crate::msg::TransformStamped {
            header: Header::new(Time::default(), parent),
            child_frame_id: child.into(),
            ..Default::default()
        };
        t.transform.translation.x = p[0];
        t.transform.translation.y = p[1];
        t.transform.rotation = Quaternion::from_yaw(p[2]);
        t
    }

    fn inverse(p: [f64; 3]) -> [f64; 3] {
        let (s, c) = p[2].sin_cos();
        [-(c * p[0] + s * p[1]), -(-s * p[0] + c * p[1]), -p[2]]
    }

    fn compose(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
        let (s, c) = a[2].sin_cos();
        [
            a[0] + c * b[0] - s * b[1],
            a[1] + s * b[0] + c * b[1],
            a[2] + b[2],
        ]
    }

    /// A car whose localiser publishes `map -> odom` at 10 Hz and whose odometry publishes
    /// `odom -> base_link` at 50 Hz, drifting; the laser is mounted by `/tf_static`.
    fn tf_recording() -> (Bag, impl Fn(u64) -> [f64; 3]) {
        let truth = |t: u64| {
            let s = t as f64 * 1e-9;
            [s, 0.5 * s * s, 0.3 * s]
        };
        let drift = |t: u64| {
            let s = t as f64 * 1e-9;
            [0.1 * s, -0.05 * s, 0.02 * s]
        };
        let mut r = Rec::default();
        r.add(
            "/tf_static",
            0,
            &TFMessage {
                transforms: vec![transform("base_link", "laser", [0.27, 0.0, 0.0])],
            },
        );
        for k in 0..=150u64 {
            let t = k * S / 50;
            // the odometry's pose: the truth seen from a drifting frame
            let odom = compose(drift(t), truth(t));
            let mut transforms = vec![transform("odom", "/base_link", odom)];
            if k % 5 == 0 {
                // the localiser's correction, with a stack's leading slash on one side
                transforms.push(transform("/map", "odom", inverse(drift(t))));
            }
            r.add("/tf", t, &TFMessage { transforms });
        }
        (r.bag(), truth)
    }

    fn tf_track(bag: &Bag, frames: Option<[&str; 2]>) -> Result<Track, String> {
        let topics = RecordingTopics {
            pose: Some("/tf".into()),
            pose_frames: frames.map(|f| f.map(String::from)),
            ..RecordingTopics::default()
        };
        planar_track(bag, Path::new("run.mcap"), &topics).map_err(|e| e.to_string())
    }

    #[test]
    fn a_pose_from_the_transforms_chains_the_localiser_and_the_odometry() {
        let (bag, truth) = tf_recording();
        let t = tf_track(&bag, None).unwrap();
        // every 50-Hz odometry transform within the localiser's first and last: 151
        assert_eq!(t.samples.len(), 151);
        let mut worst = 0.0f64;
        for s in &t.samples {
            let want = truth(s.log_time);
            let got = [s.state.x, s.state.y, s.state.yaw];
            for c in 0..3 {
                worst = worst.max((got[c] - want[c]).abs());
            }
            assert!(s.state.vx.is_nan());
        }
        // the correction interpolated between its 10-Hz messages
        assert!(worst < 2e-3, "{worst}");
        assert!(
            t.notes
                .iter()
                .any(|n| n.contains("no messages on the velocity topic"))
        );
        // the laser, through the static mount
        let t = tf_track(&bag, Some(["map", "laser"])).unwrap();
        let s = t.samples[100];
        let want = compose(truth(s.log_time), [0.27, 0.0, 0.0]);
        assert!((s.state.x - want[0]).abs() < 2e-3 && (s.state.y - want[1]).abs() < 2e-3);
    }

    #[test]
    fn transforms_that_do_not_reach_are_named() {
        let (bag, _) = tf_recording();
        let e = tf_track(&bag, Some(["earth", "base_link"])).unwrap_err();
        assert!(
            e.contains("no chain of transforms from \"earth\" to \"base_link\""),
            "{e}"
        );
        assert!(
            e.ends_with(
                "the transforms recorded: odom -> base_link, base_link -> laser, map -> odom"
            ),
            "{e}"
        );
        // frames given for a pose that is not a transform
        let mut r = Rec::default();
        r.add("/odom", 0, &odom(0.0, 1.0, 0.0, 0.0));
        let topics = RecordingTopics {
            pose_frames: Some(["map".into(), "base_link".into()]),
            ..RecordingTopics::default()
        };
        let e = planar_track(&r.bag(), Path::new("run.mcap"), &topics)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("pose frames map,base_link are read from transforms"),
            "{e}"
        );
        // a frame with two parents
        let mut r = Rec::default();
        for (k, p) in ["odom", "map"].iter().enumerate() {
            r.add(
                "/tf",
                k as u64,
                &TFMessage {
                    transforms: vec![transform(p, "base_link", [0.0; 3])],
                },
            );
        }
        let e = tf_track(&r.bag(), None).unwrap_err();
        assert!(
            e.contains("not a tree: base_link has two parents, odom and map"),
            "{e}"
        );
    }

    #[test]
    fn drive_commands_are_read_from_their_type_only() {
        let mut r = Rec::default();
        for k in [2u64, 0, 1] {
            let mut d = AckermannDriveStamped::default();
            d.drive.steering_angle = 0.25;
            d.drive.speed = k as f32;
            r.add("/drive", k * S, &d);
        }
        r.add("/odom", 0, &odom(0.0, 1.0, 0.0, 0.0));
        let bag = r.bag();
        let path = Path::new("run.mcap");
        let got = drive_commands(&bag, path, &RecordingTopics::default()).unwrap();
        assert_eq!(
            got.iter()
                .map(|d| (d.log_time, d.steer, d.speed))
                .collect::<Vec<_>>(),
            [(0, 0.25, 0.0), (S, 0.25, 1.0), (2 * S, 0.25, 2.0)]
        );
        let topics = |drive: &str| RecordingTopics {
            drive: drive.into(),
            ..RecordingTopics::default()
        };
        let e = drive_commands(&bag, path, &topics("/odom"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("the drive topic \"/odom\" carries nav_msgs/msg/Odometry; commands are read from ackermann_msgs/msg/AckermannDriveStamped"),
            "{e}"
        );
        let e = drive_commands(&bag, path, &topics("/ackermann_cmd"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("no messages on the drive topic \"/ackermann_cmd\" (topics in the recording: /drive (3"), "{e}");
    }

    #[test]
    fn non_finite_poses_are_skipped_and_counted() {
        let mut r = Rec::default();
        for k in 0..4u64 {
            let x = if k == 2 { f64::NAN } else { k as f64 };
            r.add("/odom", k * S, &odom(x, 1.0, f64::INFINITY, 0.2));
        }
        let t = track(&r.bag(), "/odom", "/odom").unwrap();
        assert_eq!(t.samples.len(), 3);
        assert!(
            t.samples
                .iter()
                .all(|s| s.state.vy.is_nan() && s.state.vx == 1.0)
        );
        assert_eq!(
            t.notes,
            ["1 of 4 /odom messages with a non-finite pose skipped"]
        );
    }
}
