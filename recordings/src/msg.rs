//! The ROS 2 messages the car's stack speaks, as plain serde structs.
//!
//! Field order and types follow the ROS 2 IDL of each message exactly, because CDR (the
//! DDS wire encoding, [`crate::cdr`]) is positional: a struct serialises as its fields in
//! order with natural alignment, a `float64[36]` as 36 values with no length, a
//! `float32[]` as a `u32` length and the values. So encoded they are byte-compatible with
//! rclcpp / rclpy nodes (Humble and later), on DDS and in bags alike.
//!
//! [`RosMessage`] adds the package and type name (DDS type `pkg::msg::dds_::Type_`) and
//! the `ros2msg` schema text that MCAP files carry so Foxglove and `ros2 bag` can decode
//! the recorded bytes.

use serde::de::{self, SeqAccess, Visitor};
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// The `ros2msg` schemas ([`RosMessage::SCHEMA`]).
mod schemas;

/// A message with its ROS 2 type name and MCAP schema.
pub trait RosMessage:
    Serialize + for<'de> Deserialize<'de> + Clone + std::fmt::Debug + Send + 'static
{
    /// ROS package (`sensor_msgs`).
    const PACKAGE: &'static str;
    /// Type name within the package (`LaserScan`).
    const TYPE: &'static str;
    /// The `ros2msg` schema: the message definition followed by every nested type's.
    const SCHEMA: &'static str;

    /// `sensor_msgs/msg/LaserScan`: the name MCAP schemas and `ros2 bag` use.
    fn schema_name() -> String {
        format!("{}/msg/{}", Self::PACKAGE, Self::TYPE)
    }

    /// `sensor_msgs::msg::dds_::LaserScan_`: the DDS type name.
    fn dds_type_name() -> String {
        format!("{}::msg::dds_::{}_", Self::PACKAGE, Self::TYPE)
    }
}

/// builtin_interfaces/Time.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    /// From seconds since the epoch (negative or non-finite values give zero).
    pub fn from_secs(t: f64) -> Self {
        if !(t.is_finite() && t > 0.0) {
            return Self::default();
        }
        let sec = t.floor();
        let mut nanosec = ((t - sec) * 1e9).round() as u32;
        let mut sec = sec as i64;
        if nanosec >= 1_000_000_000 {
            nanosec -= 1_000_000_000;
            sec += 1;
        }
        Self {
            sec: sec.min(i32::MAX as i64) as i32,
            nanosec,
        }
    }

    /// From nanoseconds since the epoch (seconds beyond `i32` saturate).
    pub fn from_nanos(ns: u64) -> Self {
        Self {
            sec: (ns / 1_000_000_000).min(i32::MAX as u64) as i32,
            nanosec: (ns % 1_000_000_000) as u32,
        }
    }

    pub fn as_secs(&self) -> f64 {
        self.sec as f64 + self.nanosec as f64 * 1e-9
    }

    /// Nanoseconds since the epoch (zero for negative times).
    pub fn as_nanos(&self) -> u64 {
        if self.sec < 0 {
            return 0;
        }
        self.sec as u64 * 1_000_000_000 + self.nanosec as u64
    }

    pub fn is_zero(&self) -> bool {
        self.sec == 0 && self.nanosec == 0
    }
}

/// std_msgs/Header.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

impl Header {
    pub fn new(stamp: Time, frame_id: &str) -> Self {
        Self {
            stamp,
            frame_id: frame_id.to_string(),
        }
    }
}

/// sensor_msgs/LaserScan.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct LaserScan {
    pub header: Header,
    pub angle_min: f32,
    pub angle_max: f32,
    pub angle_increment: f32,
    pub time_increment: f32,
    pub scan_time: f32,
    pub range_min: f32,
    pub range_max: f32,
    pub ranges: Vec<f32>,
    pub intensities: Vec<f32>,
}

/// geometry_msgs/Point.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Point {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

/// geometry_msgs/Quaternion.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

impl Default for Quaternion {
    fn default() -> Self {
        Self {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }
    }
}

impl Quaternion {
    /// A rotation by `yaw` about z.
    pub fn from_yaw(yaw: f64) -> Self {
        Self {
            x: 0.0,
            y: 0.0,
            z: libm::sin(0.5 * yaw),
            w: libm::cos(0.5 * yaw),
        }
    }

    /// The yaw (rotation about z) of this orientation, in [-pi, pi].
    pub fn yaw(&self) -> f64 {
        libm::atan2(
            2.0 * (self.w * self.z + self.x * self.y),
            1.0 - 2.0 * (self.y * self.y + self.z * self.z),
        )
    }
}

/// geometry_msgs/Pose.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Pose {
    pub position: Point,
    pub orientation: Quaternion,
}

impl Pose {
    /// x, y and the yaw in [-pi, pi) (atan2's pi taken as -pi, so the range is half
    /// open); the rest of a 3-D pose is not read.
    pub fn planar(&self) -> [f64; 3] {
        let yaw = self.orientation.yaw();
        let yaw = if yaw >= std::f64::consts::PI {
            yaw - std::f64::consts::TAU
        } else {
            yaw
        };
        [self.position.x, self.position.y, yaw]
    }
}

/// A `float64[36]` covariance (row-major 6x6). Serde derives stop at 32-element arrays,
/// so this (de)serialises by hand as a fixed-length tuple: CDR writes 36 doubles with no
/// length prefix, as the IDL's bounded array requires.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Covariance(pub [f64; 36]);

impl Default for Covariance {
    fn default() -> Self {
        Self([0.0; 36])
    }
}

impl Serialize for Covariance {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeTuple;
        let mut t = s.serialize_tuple(36)?;
        for v in &self.0 {
            t.serialize_element(v)?;
        }
        t.end()
    }
}

impl<'de> Deserialize<'de> for Covariance {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = Covariance;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("36 float64 values")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Covariance, A::Error> {
                let mut out = [0.0; 36];
                for (i, slot) in out.iter_mut().enumerate() {
                    *slot = seq
                        .next_element()?
                        .ok_or_else(|| de::Error::invalid_length(i, &self))?;
                }
                Ok(Covariance(out))
            }
        }
        d.deserialize_tuple(36, V)
    }
}

/// geometry_msgs/PoseWithCovariance.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct PoseWithCovariance {
    pub pose: Pose,
    pub covariance: Covariance,
}

/// geometry_msgs/Vector3.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Vector3 {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

/// geometry_msgs/Twist.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Twist {
    pub linear: Vector3,
    pub angular: Vector3,
}

/// geometry_msgs/TwistWithCovariance.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct TwistWithCovariance {
    pub twist: Twist,
    pub covariance: Covariance,
}

/// nav_msgs/Odometry.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Odometry {
    pub header: Header,
    pub child_frame_id: String,
    pub pose: PoseWithCovariance,
    pub twist: TwistWithCovariance,
}

/// What an odometry message says of a car moving in the plane.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PlanarState {
    /// Position in the header frame [m].
    pub x: f64,
    pub y: f64,
    /// Heading in the header frame [rad], in [-pi, pi).
    pub yaw: f64,
    /// Velocities in the body (child) frame [m/s], as odometry's twist is given.
    pub vx: f64,
    pub vy: f64,
    /// [rad/s].
    pub yaw_rate: f64,
}

impl Odometry {
    /// The planar state: the pose's x, y and yaw, the twist's forward, lateral and yaw
    /// rates (the rest of a 3-D odometry message is not read).
    pub fn planar_state(&self) -> PlanarState {
        let tw = &self.twist.twist;
        let [x, y, yaw] = self.pose.pose.planar();
        PlanarState {
            x,
            y,
            yaw,
            vx: tw.linear.x,
            vy: tw.linear.y,
            yaw_rate: tw.angular.z,
        }
    }
}

/// ackermann_msgs/AckermannDrive.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct AckermannDrive {
    pub steering_angle: f32,
    pub steering_angle_velocity: f32,
    pub speed: f32,
    pub acceleration: f32,
    pub jerk: f32,
}

/// ackermann_msgs/AckermannDriveStamped.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct AckermannDriveStamped {
    pub header: Header,
    pub drive: AckermannDrive,
}

/// geometry_msgs/PoseStamped (a motion-capture system's pose, a localiser's inferred pose).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PoseStamped {
    pub header: Header,
    pub pose: Pose,
}

/// geometry_msgs/PoseWithCovarianceStamped (RViz's "2D Pose Estimate" on /initialpose).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PoseWithCovarianceStamped {
    pub header: Header,
    pub pose: PoseWithCovariance,
}

/// geometry_msgs/Transform.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Transform {
    pub translation: Vector3,
    pub rotation: Quaternion,
}

/// geometry_msgs/TransformStamped: `child_frame_id`'s pose in `header.frame_id`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TransformStamped {
    pub header: Header,
    pub child_frame_id: String,
    pub transform: Transform,
}

/// tf2_msgs/TFMessage: what `/tf` and `/tf_static` carry.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TFMessage {
    pub transforms: Vec<TransformStamped>,
}

/// A message with a header stamp.
pub trait Stamped {
    fn stamp(&self) -> Time;
}

impl Stamped for LaserScan {
    fn stamp(&self) -> Time {
        self.header.stamp
    }
}

impl Stamped for Odometry {
    fn stamp(&self) -> Time {
        self.header.stamp
    }
}

impl Stamped for AckermannDriveStamped {
    fn stamp(&self) -> Time {
        self.header.stamp
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cdr::{CDR_LE_HEADER, from_cdr, to_cdr};

    const SEP: &str =
        "================================================================================\n";
    const TIME_DEF: &str = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n";
    const HEADER_DEF: &str =
        "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n";

    #[test]
    fn schema_separator_matches_ros2msg_convention() {
        assert_eq!(SEP.trim_end().len(), 80);
        assert!(Odometry::SCHEMA.contains(&format!("{}{}", SEP, TIME_DEF)));
        assert!(LaserScan::SCHEMA.contains(&format!("{}{}", SEP, HEADER_DEF)));
        assert_eq!(
            LaserScan::dds_type_name(),
            "sensor_msgs::msg::dds_::LaserScan_"
        );
        assert_eq!(
            AckermannDriveStamped::schema_name(),
            "ackermann_msgs/msg/AckermannDriveStamped"
        );
    }

    #[test]
    fn ackermann_bytes_match_the_idl_layout() {
        let m = AckermannDriveStamped {
            header: Header::new(Time { sec: 3, nanosec: 7 }, "base_link"),
            drive: AckermannDrive {
                steering_angle: 0.25,
                speed: 2.5,
                ..Default::default()
            },
        };
        let b = to_cdr(&m).unwrap();
        // header(4) + sec(4) + nanosec(4) + len(4) + "base_link\0"(10) + pad(2) + 5 * f32
        assert_eq!(b.len(), 4 + 4 + 4 + 4 + 10 + 2 + 20);
        assert_eq!(&b[..4], &CDR_LE_HEADER);
        assert_eq!(&b[4..8], &3i32.to_le_bytes());
        assert_eq!(&b[12..16], &10u32.to_le_bytes());
        assert_eq!(&b[16..26], b"base_link\0");
        assert_eq!(&b[28..32], &0.25f32.to_le_bytes());
        assert_eq!(&b[36..40], &2.5f32.to_le_bytes());
        assert_eq!(from_cdr::<AckermannDriveStamped>(&b).unwrap(), m);
    }

    #[test]
    fn odometry_round_trips_with_covariance() {
        let mut cov = Covariance::default();
        cov.0[35] = 9.5;
        let m = Odometry {
            header: Header::new(Time::from_secs(12.5), "odom"),
            child_frame_id: "base_link".into(),
            pose: PoseWithCovariance {
                pose: Pose {
                    position: Point {
                        x: 1.0,
                        y: -2.0,
                        z: 0.0,
                    },
                    orientation: Quaternion::from_yaw(2.0),
                },
                covariance: cov,
            },
            twist: TwistWithCovariance::default(),
        };
        let b = to_cdr(&m).unwrap();
        let back: Odometry = from_cdr(&b).unwrap();
        assert_eq!(back, m);
        assert!((back.pose.pose.orientation.yaw() - 2.0).abs() < 1e-12);
        let planar = back.planar_state();
        assert_eq!((planar.x, planar.y), (1.0, -2.0));
        assert!((planar.yaw - 2.0).abs() < 1e-12);
        assert!(from_cdr::<Odometry>(&b[..b.len() - 8]).is_err());
        assert!(from_cdr::<Odometry>(&[0x00, 0x03, 0, 0, 1]).is_err());
    }

    #[test]
    fn tf_message_bytes_match_the_idl_layout() {
        let m = TFMessage {
            transforms: vec![TransformStamped {
                header: Header::new(Time { sec: 1, nanosec: 2 }, "map"),
                child_frame_id: "base_link".into(),
                transform: Transform {
                    translation: Vector3 {
                        x: 1.5,
                        y: -2.0,
                        z: 0.0,
                    },
                    rotation: Quaternion::from_yaw(0.5),
                },
            }],
        };
        let b = to_cdr(&m).unwrap();
        // sequence length, stamp, "map\0", "base_link\0" + pad to 8, then 7 doubles
        assert_eq!(&b[4..8], &1u32.to_le_bytes());
        assert_eq!(&b[16..20], &4u32.to_le_bytes());
        assert_eq!(&b[20..24], b"map\0");
        assert_eq!(&b[24..28], &10u32.to_le_bytes());
        assert_eq!(&b[28..38], b"base_link\0");
        // doubles align to 8 from the body start (offset 4 in the payload): 38 -> 44
        assert_eq!(&b[44..52], &1.5f64.to_le_bytes());
        assert_eq!(b.len(), 44 + 7 * 8);
        assert_eq!(from_cdr::<TFMessage>(&b).unwrap(), m);
        assert_eq!(
            TFMessage::dds_type_name(),
            "tf2_msgs::msg::dds_::TFMessage_"
        );
    }

    #[test]
    fn planar_yaw_is_half_open() {
        let mut o = Odometry::default();
        o.pose.pose.orientation = Quaternion {
            x: 0.0,
            y: 0.0,
            z: 1.0,
            w: 0.0,
        };
        assert_eq!(o.pose.pose.orientation.yaw(), std::f64::consts::PI);
        assert_eq!(o.planar_state().yaw, -std::f64::consts::PI);
        o.twist.twist.angular.z = 0.5;
        o.twist.twist.linear.y = -0.25;
        assert_eq!(
            (o.planar_state().vy, o.planar_state().yaw_rate),
            (-0.25, 0.5)
        );
    }

    #[test]
    fn time_conversions() {
        let t = Time::from_secs(1.999_999_999_9);
        assert_eq!(t, Time { sec: 2, nanosec: 0 });
        assert_eq!(Time::from_secs(-1.0), Time::default());
        assert_eq!(Time::from_secs(3.25).as_nanos(), 3_250_000_000);
        assert_eq!(
            Time::from_nanos(3_250_000_007),
            Time {
                sec: 3,
                nanosec: 250_000_007
            }
        );
        assert_eq!(Time::from_nanos(u64::MAX).sec, i32::MAX);
    }
}
