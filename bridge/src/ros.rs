//! ROS 2 plumbing: the domain, topic names, QoS and frame ids, and typed publishers and
//! subscriptions over `ros2-client` (RustDDS: pure Rust, no ROS installation needed).
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

use ros2_client::{
    Context, ContextOptions, MessageTypeName, Name, Node, NodeName, NodeOptions, Publisher,
    QosProfile, Subscription,
    qos::{Durability, History, WhenFull},
};

use crate::BridgeError;
use crate::msg::RosMessage;

/// Reliability and history depth of one side (publishers or subscriptions).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct QosConfig {
    pub reliable: bool,
    pub depth: usize,
}

impl QosConfig {
    fn profile(&self) -> QosProfile {
        let base = QosProfile::publisher_default()
            .durability(Durability::Volatile)
            .history(History::KeepLast {
                depth: self.depth.max(1),
            });
        if self.reliable {
            base.reliability_reliable(WhenFull::DEFAULT)
        } else {
            base.reliability_best_effort()
        }
    }
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
    /// The defaults with the domain from `ROS_DOMAIN_ID` when it is set.
    pub fn from_env() -> Result<Self, BridgeError> {
        let mut c = Self::default();
        if let Ok(v) = std::env::var("ROS_DOMAIN_ID") {
            c.domain_id = parse_domain_id(&v)?;
        }
        Ok(c)
    }

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

/// tf2's QoS for `/tf_static`: reliable, transient local, keep last 1.
fn static_qos() -> QosProfile {
    QosProfile::publisher_default()
        .durability(Durability::TransientLocal)
        .history(History::KeepLast { depth: 1 })
        .reliability_reliable(WhenFull::DEFAULT)
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

/// A ROS 2 topic name ("/scan", "/car1/odom") as `ros2-client` wants it.
fn topic_name(field: &str, name: &str) -> Result<Name, BridgeError> {
    if !name.starts_with('/') {
        return Err(BridgeError::config(
            field,
            name,
            "must be an absolute topic name starting with '/'",
        ));
    }
    let (ns, base) = name.rsplit_once('/').unwrap_or(("", name));
    let ns = if ns.is_empty() { "/" } else { ns };
    Name::new(ns, base).map_err(|e| BridgeError::config(field, name, &format!("{e:?}")))
}

/// One ROS 2 node on its own DDS participant.
pub struct RosNode {
    // Fields drop in order: the node before the context it lives in.
    node: Node,
    _context: Context,
    config: RosConfig,
}

impl RosNode {
    /// Join domain `config.domain_id` as node `name`.
    pub fn new(name: &str, config: &RosConfig) -> Result<Self, BridgeError> {
        config.validate()?;
        let ros = |what: &str, e: &dyn std::fmt::Debug| BridgeError::Ros {
            what: what.to_string(),
            message: format!("{e:?}"),
        };
        let context = Context::with_options(ContextOptions::new().domain_id(config.domain_id))
            .map_err(|e| ros("creating the DDS participant", &e))?;
        let node_name = NodeName::new(&config.namespace, name)
            .map_err(|e| BridgeError::config("node name", name, &format!("{e:?}")))?;
        let node = context
            .new_node(node_name, NodeOptions::new().enable_rosout(false))
            .map_err(|e| ros("creating the node", &e))?;
        Ok(Self {
            node,
            _context: context,
            config: config.clone(),
        })
    }

    pub fn config(&self) -> &RosConfig {
        &self.config
    }

    /// The DDS topic of `M` named `topic`.
    fn topic<M: RosMessage>(
        &mut self,
        topic: &str,
        qos: &QosProfile,
    ) -> Result<ros2_client::dds::rustdds::Topic, BridgeError> {
        let name = topic_name("topic", topic)?;
        self.node
            .create_topic(&name, MessageTypeName::new(M::PACKAGE, M::TYPE), qos)
            .map_err(|e| BridgeError::Ros {
                what: format!("creating topic {topic}"),
                message: format!("{e:?}"),
            })
    }

    /// A publisher of `M` on `topic` with the configured publish QoS.
    pub fn publisher<M: RosMessage>(&mut self, topic: &str) -> Result<Publisher<M>, BridgeError> {
        let qos = self.config.publish_qos.profile();
        let t = self.topic::<M>(topic, &qos)?;
        self.node
            .create_publisher::<M>(&t, Some(qos))
            .map_err(|e| BridgeError::Ros {
                what: format!("creating a publisher on {topic}"),
                message: format!("{e:?}"),
            })
    }

    /// A publisher of `M` on `topic` with tf2's static QoS (reliable, transient local,
    /// keep last 1): the last message reaches every subscriber that joins later.
    pub fn static_publisher<M: RosMessage>(
        &mut self,
        topic: &str,
    ) -> Result<Publisher<M>, BridgeError> {
        let qos = static_qos();
        let t = self.topic::<M>(topic, &qos)?;
        self.node
            .create_publisher::<M>(&t, Some(qos))
            .map_err(|e| BridgeError::Ros {
                what: format!("creating a latched publisher on {topic}"),
                message: format!("{e:?}"),
            })
    }

    /// A subscription with tf2's static QoS: receives what a [`Self::static_publisher`]
    /// (or a tf2 `StaticTransformBroadcaster`) published before it joined.
    pub fn static_subscription<M: RosMessage>(
        &mut self,
        topic: &str,
    ) -> Result<Subscription<M>, BridgeError> {
        let qos = static_qos();
        let t = self.topic::<M>(topic, &qos)?;
        self.node
            .create_subscription::<M>(&t, Some(qos))
            .map_err(|e| BridgeError::Ros {
                what: format!("subscribing to {topic} (transient local)"),
                message: format!("{e:?}"),
            })
    }

    /// A subscription to `M` on `topic` with the configured subscribe QoS.
    pub fn subscription<M: RosMessage>(
        &mut self,
        topic: &str,
    ) -> Result<Subscription<M>, BridgeError> {
        let qos = self.config.subscribe_qos.profile();
        let t = self.topic::<M>(topic, &qos)?;
        self.node
            .create_subscription::<M>(&t, Some(qos))
            .map_err(|e| BridgeError::Ros {
                what: format!("subscribing to {topic}"),
                message: format!("{e:?}"),
            })
    }
}

/// Take every waiting message, keeping the newest; read errors are logged and skipped
/// (a malformed sample from a peer must not stop the car's loop).
pub fn take_latest<M: RosMessage>(sub: &Subscription<M>, topic: &str) -> Option<M> {
    take_newest(sub, topic).map(|(m, _)| m)
}

/// Take every waiting message, oldest first; read errors are logged and skipped.
pub fn take_all<M: RosMessage>(sub: &Subscription<M>, topic: &str) -> Vec<M> {
    let mut all = Vec::new();
    loop {
        match sub.take() {
            Ok(Some((m, _))) => all.push(m),
            Ok(None) => return all,
            Err(e) => {
                tracing::warn!(topic, error = ?e, "dropping an unreadable message");
                return all;
            }
        }
    }
}

/// [`take_latest`] with the newest message's DDS source timestamp (the publisher's wall
/// clock when it wrote the sample), nanoseconds since the epoch.
pub fn take_newest<M: RosMessage>(sub: &Subscription<M>, topic: &str) -> Option<(M, Option<i64>)> {
    let mut latest = None;
    loop {
        match sub.take() {
            Ok(Some((m, info))) => {
                latest = Some((m, info.source_timestamp().map(|t| t.to_nanos())));
            }
            Ok(None) => break,
            Err(e) => {
                tracing::warn!(topic, error = ?e, "dropping an unreadable message");
                break;
            }
        }
    }
    latest
}

/// Publish, logging (not failing) on a full or broken writer.
pub fn publish<M: RosMessage>(publisher: &Publisher<M>, topic: &str, msg: M) -> bool {
    match publisher.publish(msg) {
        Ok(()) => true,
        Err(e) => {
            tracing::warn!(topic, error = ?e, "publish failed");
            false
        }
    }
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
