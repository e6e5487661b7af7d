//! ROS 2 plumbing: the domain, the distribution, topic names, QoS and frame ids, and typed
//! publishers and subscriptions ([`node`], written over RustDDS: pure Rust, no ROS
//! installation needed), listed in the ROS graph in the distribution's layout ([`graph`]).
//!
//! Defaults are those of f1tenth_system (`/scan`, `/odom`, `/drive`) and f1tenth_gym_ros
//! (`/initialpose`, `/opp_scan`, `/opp_odom`, `/opp_drive`, `/tf`, `/tf_static`).
//!
//! QoS defaults are chosen to match every peer: our publishers are reliable (a reliable
//! writer serves both reliable and best-effort readers) and our subscriptions best effort
//! (a best-effort reader matches both kinds of writer, e.g. a LIDAR driver publishing
//! with the sensor-data profile). Both are configurable. `/tf_static` is the exception:
//! tf2 fixes its QoS (reliable, transient local, keep last 1) so that a listener started
//! later still receives the static transforms, and [`RosNode::static_publisher`] and
//! [`RosNode::static_subscription`] use exactly that.
//!
//! Nothing here reads the environment: the command line resolves `ROS_DOMAIN_ID` and
//! `ROS_DISTRO` into [`RosConfig`].

mod adapter;
pub mod graph;
pub mod node;

pub use graph::RosDistro;
pub use node::{Publisher, RosNode, Subscription, publish, take_all, take_latest, take_newest};

use crate::BridgeError;

/// Reliability and history depth of one side (publishers or subscriptions).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct QosConfig {
    pub reliable: bool,
    pub depth: usize,
}

/// Topic names.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TopicNames {
    pub scan: String,
    pub odom: String,
    pub drive: String,
    pub initialpose: String,
    pub opp_scan: String,
    pub opp_odom: String,
    pub opp_drive: String,
    pub tf: String,
    pub tf_static: String,
}

impl Default for TopicNames {
    fn default() -> Self {
        Self {
            scan: "/scan".into(),
            odom: "/odom".into(),
            drive: "/drive".into(),
            initialpose: "/initialpose".into(),
            opp_scan: "/opp_scan".into(),
            opp_odom: "/opp_odom".into(),
            opp_drive: "/opp_drive".into(),
            tf: "/tf".into(),
            tf_static: "/tf_static".into(),
        }
    }
}

/// Frame ids written into message headers and transforms.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frames {
    /// Odometry's `header.frame_id`, and the parent of the cars' transforms on `/tf`.
    pub odom: String,
    /// The car body: odometry's `child_frame_id` and the drive command's frame.
    pub base: String,
    /// The LIDAR's frame.
    pub laser: String,
    /// The opponent car's body frame.
    pub opp_base: String,
    /// The opponent car's LIDAR frame.
    pub opp_laser: String,
}

impl Default for Frames {
    /// The car's frames (f1tenth_system: VESC odometry `odom` -> `base_link`, LIDAR `laser`).
    fn default() -> Self {
        Self {
            odom: "odom".into(),
            base: "base_link".into(),
            laser: "laser".into(),
            opp_base: "opp_base_link".into(),
            opp_laser: "opp_laser".into(),
        }
    }
}

impl Frames {
    /// f1tenth_gym_ros's frames, the SIL car's defaults: the simulator's pose is in the
    /// `map` frame, and each car's frames carry its namespace.
    pub fn f1tenth_gym_ros() -> Self {
        Self {
            odom: "map".into(),
            base: "ego_racecar/base_link".into(),
            laser: "ego_racecar/laser".into(),
            opp_base: "opp_racecar/base_link".into(),
            opp_laser: "opp_racecar/laser".into(),
        }
    }

    /// The opponent car's frames, as the ego car's would be.
    pub fn opponent(&self) -> Self {
        Self {
            odom: self.odom.clone(),
            base: self.opp_base.clone(),
            laser: self.opp_laser.clone(),
            opp_base: self.base.clone(),
            opp_laser: self.laser.clone(),
        }
    }

    /// Check that every frame id is a usable tf2 frame (not empty, no leading `/`).
    pub fn validate(&self) -> Result<(), BridgeError> {
        for (field, id) in [
            ("frames.odom", &self.odom),
            ("frames.base", &self.base),
            ("frames.laser", &self.laser),
            ("frames.opp_base", &self.opp_base),
            ("frames.opp_laser", &self.opp_laser),
        ] {
            if id.is_empty() || id.starts_with('/') || id.chars().any(char::is_whitespace) {
                return Err(BridgeError::config(
                    field,
                    format!("{id:?}"),
                    "a frame id must be non-empty, without whitespace or a leading '/' (tf2)",
                ));
            }
        }
        Ok(())
    }
}

/// Where and how to talk ROS 2.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RosConfig {
    /// DDS domain (ROS_DOMAIN_ID).
    pub domain_id: u16,
    /// The car's ROS 2 distribution (ROS_DISTRO): the layout of the graph record.
    pub distro: RosDistro,
    pub namespace: String,
    pub topics: TopicNames,
    pub frames: Frames,
    pub publish_qos: QosConfig,
    pub subscribe_qos: QosConfig,
}

impl Default for RosConfig {
    fn default() -> Self {
        Self {
            domain_id: 0,
            distro: RosDistro::default(),
            namespace: "/".into(),
            topics: TopicNames::default(),
            frames: Frames::default(),
            publish_qos: QosConfig {
                reliable: true,
                depth: 5,
            },
            subscribe_qos: QosConfig {
                reliable: false,
                depth: 5,
            },
        }
    }
}

impl RosConfig {
    /// Check the names and numbers, naming the offending field.
    pub fn validate(&self) -> Result<(), BridgeError> {
        if self.domain_id > 232 {
            return Err(BridgeError::config(
                "domain_id",
                self.domain_id,
                "must be 0..=232 (DDS port mapping)",
            ));
        }
        let t = &self.topics;
        for (field, name) in [
            ("topics.scan", &t.scan),
            ("topics.odom", &t.odom),
            ("topics.drive", &t.drive),
            ("topics.initialpose", &t.initialpose),
            ("topics.opp_scan", &t.opp_scan),
            ("topics.opp_odom", &t.opp_odom),
            ("topics.opp_drive", &t.opp_drive),
            ("topics.tf", &t.tf),
            ("topics.tf_static", &t.tf_static),
        ] {
            topic_name(field, name)?;
        }
        self.frames.validate()?;
        for (field, q) in [
            ("publish_qos.depth", &self.publish_qos),
            ("subscribe_qos.depth", &self.subscribe_qos),
        ] {
            if q.depth == 0 || q.depth > 10_000 {
                return Err(BridgeError::config(field, q.depth, "must be 1..=10000"));
            }
        }
        Ok(())
    }
}

/// Parse a ROS_DOMAIN_ID value.
pub fn parse_domain_id(v: &str) -> Result<u16, BridgeError> {
    match v.trim().parse::<u16>() {
        Ok(d) if d <= 232 => Ok(d),
        _ => Err(BridgeError::config(
            "ROS_DOMAIN_ID",
            v,
            "must be an integer 0..=232",
        )),
    }
}

/// Check one token of a ROS name: ASCII letters, digits and underscores, not starting
/// with a digit, no doubled underscore (ROS 2's topic and node name rules).
fn name_token(token: &str) -> Result<(), String> {
    if token.is_empty() {
        return Err("an empty name part (a doubled or trailing '/')".into());
    }
    if let Some(c) = token
        .chars()
        .find(|c| !(c.is_ascii_alphanumeric() || *c == '_'))
    {
        return Err(format!(
            "the character {c:?} (letters, digits and '_' only)"
        ));
    }
    if token.starts_with(|c: char| c.is_ascii_digit()) {
        return Err(format!("{token:?} starts with a digit"));
    }
    if token.contains("__") {
        return Err(format!("{token:?} has a doubled underscore"));
    }
    Ok(())
}

/// Check an absolute ROS 2 topic name ("/scan", "/car1/odom"); it is returned as given.
pub(crate) fn topic_name<'a>(field: &str, name: &'a str) -> Result<&'a str, BridgeError> {
    let Some(rest) = name.strip_prefix('/') else {
        return Err(BridgeError::config(
            field,
            name,
            "must be an absolute topic name starting with '/'",
        ));
    };
    for token in rest.split('/') {
        name_token(token).map_err(|why| BridgeError::config(field, name, &why))?;
    }
    Ok(name)
}

/// Check a node's namespace ("/" or "/car1") and name ("paddock_drive").
pub(crate) fn node_name(namespace: &str, name: &str) -> Result<(), BridgeError> {
    name_token(name).map_err(|why| BridgeError::config("node name", name, &why))?;
    if namespace != "/" {
        topic_name("namespace", namespace)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_names_and_domains_are_named() {
        let mut c = RosConfig::default();
        c.topics.drive = "drive".into();
        let e = c.validate().unwrap_err().to_string();
        assert!(e.contains("topics.drive = drive"), "{e}");
        c = RosConfig {
            domain_id: 300,
            ..RosConfig::default()
        };
        assert!(c.validate().unwrap_err().to_string().contains("domain_id"));
        assert!(
            parse_domain_id("x")
                .unwrap_err()
                .to_string()
                .contains("ROS_DOMAIN_ID")
        );
        assert_eq!(parse_domain_id(" 42 ").unwrap(), 42);
        assert!(topic_name("t", "/car1/odom").is_ok());
        assert!(topic_name("t", "/scan").is_ok());
        for bad in [
            "/",
            "/scan/",
            "//scan",
            "/2scan",
            "/sc__an",
            "/sc an",
            "/car-1/odom",
        ] {
            assert!(topic_name("t", bad).is_err(), "{bad}");
        }
        assert!(node_name("/", "paddock_drive").is_ok());
        assert!(node_name("/car1", "paddock_drive").is_ok());
        assert!(node_name("car1", "paddock_drive").is_err());
        assert!(node_name("/", "paddock-drive").is_err());
        let mut c = RosConfig::default();
        c.frames.laser = "/laser".into();
        let e = c.validate().unwrap_err().to_string();
        assert!(e.contains("frames.laser = \"/laser\""), "{e}");
        assert!(Frames::f1tenth_gym_ros().validate().is_ok());
        let opp = Frames::f1tenth_gym_ros().opponent();
        assert_eq!(opp.base, "opp_racecar/base_link");
        assert_eq!(opp.odom, "map");
    }
}
