//! A ROS 2 node written directly over RustDDS, as an rmw layer would put it on DDS.
//!
//! What makes a DDS participant a ROS 2 node to its peers is small: topics named
//! `rt/<topic>` with the type `pkg::msg::dds_::Type_`, plain CDR samples, and the graph
//! record on `ros_discovery_info` ([`super::graph`]) naming the node and its readers and
//! writers, in the layout of the car's distribution. A node here is one DDS participant;
//! each reader or writer it creates is added to its graph record, which is published
//! again (transient local: late joiners get the latest), and published empty when the
//! node is dropped, so `ros2 node list` forgets it.

use rustdds::policy::{Deadline, Lifespan, Ownership};
use rustdds::{
    DomainParticipant, Duration, GUID, QosPolicies, QosPolicyBuilder, RTPSEntity, Timestamp,
    TopicKind, no_key,
};
use serde::Serialize;
use serde::de::DeserializeOwned;

use super::adapter::RosCdr;
use super::graph::{self, Gid, NodeEntitiesInfo, ParticipantEntitiesInfo, RosDistro};
use super::{QosConfig, RosConfig, node_name, topic_name};
use crate::BridgeError;
use crate::msg::RosMessage;

/// A publisher of `M` on one topic.
pub struct Publisher<M: Serialize> {
    writer: no_key::DataWriter<M, RosCdr<M>>,
    topic: String,
}

impl<M: Serialize> Publisher<M> {
    /// Publish `msg`, stamped with the wall clock as its DDS source timestamp.
    pub fn publish(&self, msg: M) -> Result<(), BridgeError> {
        self.writer
            .write(msg, Some(Timestamp::now()))
            .map_err(|e| BridgeError::Ros {
                what: format!("publishing on {}", self.topic),
                // Display: the Debug form carries the whole message
                message: e.to_string(),
            })
    }

    pub fn guid(&self) -> GUID {
        self.writer.guid()
    }
}

/// A subscription to `M` on one topic.
pub struct Subscription<M: DeserializeOwned + 'static> {
    reader: no_key::SimpleDataReader<M, RosCdr<M>>,
    topic: String,
}

impl<M: DeserializeOwned + 'static> Subscription<M> {
    /// The oldest waiting message and its DDS source timestamp (the publisher's wall
    /// clock when it wrote the sample, nanoseconds since the epoch), if any.
    pub fn take(&self) -> Result<Option<(M, Option<i64>)>, BridgeError> {
        self.reader.drain_read_notifications();
        let sample = self.reader.try_take_one().map_err(|e| BridgeError::Ros {
            what: format!("reading {}", self.topic),
            message: e.to_string(),
        })?;
        Ok(sample.map(|s| {
            let source = s.source_timestamp().and_then(epoch_nanos);
            (s.into_value(), source)
        }))
    }

    pub fn guid(&self) -> GUID {
        self.reader.guid()
    }
}

/// An RTPS timestamp (seconds and 2^-32 fractions since the epoch) in nanoseconds; None
/// for the reserved "invalid" and "infinite" values.
fn epoch_nanos(t: Timestamp) -> Option<i64> {
    if t == Timestamp::INVALID || t == Timestamp::INFINITE {
        return None;
    }
    let ticks = t.to_ticks();
    let seconds = ticks >> 32;
    let fraction = ticks & 0xffff_ffff;
    Some((seconds * 1_000_000_000 + ((fraction * 1_000_000_000) >> 32)) as i64)
}

/// The DDS QoS of a ROS profile: every policy set, as rmw sets them (automatic liveliness,
/// infinite deadline and lifespan; a reliable writer blocks at most 100 ms on a full
/// history).
pub(super) fn policies(reliable: bool, transient_local: bool, depth: usize) -> QosPolicies {
    use rustdds::policy::{Durability, History, Liveliness, Reliability};
    QosPolicyBuilder::new()
        .durability(if transient_local {
            Durability::TransientLocal
        } else {
            Durability::Volatile
        })
        .reliability(if reliable {
            Reliability::Reliable {
                max_blocking_time: Duration::from_millis(100),
            }
        } else {
            Reliability::BestEffort
        })
        .history(History::KeepLast {
            depth: depth.clamp(1, i32::MAX as usize) as i32,
        })
        .liveliness(Liveliness::Automatic {
            lease_duration: Duration::INFINITE,
        })
        .deadline(Deadline(Duration::INFINITE))
        .lifespan(Lifespan {
            duration: Duration::INFINITE,
        })
        .build()
}

impl QosConfig {
    fn policies(&self) -> QosPolicies {
        policies(self.reliable, false, self.depth)
    }
}

/// tf2's QoS for `/tf_static`: reliable, transient local, keep last 1.
fn static_qos() -> QosPolicies {
    policies(true, true, 1)
}

/// The graph record's QoS (rmw_dds_common): reliable, transient local, keep last 1.
fn graph_qos() -> QosPolicies {
    QosPolicyBuilder::new()
        .durability(rustdds::policy::Durability::TransientLocal)
        .deadline(Deadline(Duration::INFINITE))
        .ownership(Ownership::Shared)
        .reliable(Duration::ZERO)
        .history(rustdds::policy::History::KeepLast { depth: 1 })
        .lifespan(Lifespan {
            duration: Duration::INFINITE,
        })
        .build()
}

/// One ROS 2 node on its own DDS participant.
pub struct RosNode {
    config: RosConfig,
    namespace: String,
    name: String,
    readers: Vec<GUID>,
    writers: Vec<GUID>,
    graph_writer: no_key::DataWriter<ParticipantEntitiesInfo, RosCdr<ParticipantEntitiesInfo>>,
    publisher: rustdds::Publisher,
    subscriber: rustdds::Subscriber,
    // last: the entities above belong to it
    participant: DomainParticipant,
}

fn ros_error(what: impl Into<String>) -> impl FnOnce(rustdds::dds::CreateError) -> BridgeError {
    let what = what.into();
    move |e| BridgeError::Ros {
        what,
        message: e.to_string(),
    }
}

impl RosNode {
    /// Join domain `config.domain_id` as node `name`, listed in the graph in the layout
    /// of `config.distro`.
    pub fn new(name: &str, config: &RosConfig) -> Result<Self, BridgeError> {
        config.validate()?;
        node_name(&config.namespace, name)?;
        let participant = DomainParticipant::new(config.domain_id)
            .map_err(ros_error("creating the DDS participant"))?;
        let publisher = participant
            .create_publisher(&policies(true, false, 1))
            .map_err(ros_error("creating the DDS publisher"))?;
        let subscriber = participant
            .create_subscriber(&policies(false, false, 1))
            .map_err(ros_error("creating the DDS subscriber"))?;
        let graph_topic = participant
            .create_topic(
                graph::TOPIC.to_string(),
                graph::TYPE_NAME.to_string(),
                &graph_qos(),
                TopicKind::NoKey,
            )
            .map_err(ros_error("creating the ROS graph topic"))?;
        let graph_writer = publisher
            .create_datawriter_no_key::<ParticipantEntitiesInfo, RosCdr<ParticipantEntitiesInfo>>(
                &graph_topic,
                None,
            )
            .map_err(ros_error("creating the ROS graph writer"))?;
        let writers = vec![graph_writer.guid()];
        let node = Self {
            config: config.clone(),
            namespace: config.namespace.clone(),
            name: name.to_string(),
            readers: Vec::new(),
            writers,
            graph_writer,
            publisher,
            subscriber,
            participant,
        };
        node.announce(true);
        Ok(node)
    }

    pub fn config(&self) -> &RosConfig {
        &self.config
    }

    /// The graph record of this participant: this node with its entities, or (`listed`
    /// false) no node.
    fn graph_record(&self, listed: bool) -> ParticipantEntitiesInfo {
        let distro: RosDistro = self.config.distro;
        let gid = |g: &GUID| Gid::new(g.to_bytes(), distro);
        let nodes = if listed {
            vec![NodeEntitiesInfo {
                node_namespace: self.namespace.clone(),
                node_name: self.name.clone(),
                reader_gid_seq: self.readers.iter().map(gid).collect(),
                writer_gid_seq: self.writers.iter().map(gid).collect(),
            }]
        } else {
            Vec::new()
        };
        ParticipantEntitiesInfo {
            gid: gid(&self.participant.guid()),
            node_entities_info_seq: nodes,
        }
    }

    /// Publish the graph record (logged, not failed: the topics work without it).
    fn announce(&self, listed: bool) {
        if let Err(e) = self
            .graph_writer
            .write(self.graph_record(listed), Some(Timestamp::now()))
        {
            tracing::warn!(error = %e, "publishing the ROS graph record failed");
        }
    }

    /// The DDS topic of `M` named `topic` (`/scan` is `rt/scan`).
    fn topic<M: RosMessage>(
        &self,
        topic: &str,
        qos: &QosPolicies,
    ) -> Result<rustdds::Topic, BridgeError> {
        let dds_name = format!("rt{}", topic_name("topic", topic)?);
        self.participant
            .create_topic(dds_name, M::dds_type_name(), qos, TopicKind::NoKey)
            .map_err(ros_error(format!("creating topic {topic}")))
    }

    fn add_writer<M: RosMessage>(
        &mut self,
        topic: &str,
        qos: QosPolicies,
        what: &str,
    ) -> Result<Publisher<M>, BridgeError> {
        let t = self.topic::<M>(topic, &qos)?;
        let writer = self
            .publisher
            .create_datawriter_no_key::<M, RosCdr<M>>(&t, Some(qos))
            .map_err(ros_error(format!("creating a {what} on {topic}")))?;
        self.writers.push(writer.guid());
        self.announce(true);
        Ok(Publisher {
            writer,
            topic: topic.to_string(),
        })
    }

    fn add_reader<M: RosMessage>(
        &mut self,
        topic: &str,
        qos: QosPolicies,
        what: &str,
    ) -> Result<Subscription<M>, BridgeError> {
        let t = self.topic::<M>(topic, &qos)?;
        let reader = self
            .subscriber
            .create_simple_datareader_no_key::<M, RosCdr<M>>(&t, Some(qos))
            .map_err(ros_error(format!("{what} {topic}")))?;
        self.readers.push(reader.guid());
        self.announce(true);
        Ok(Subscription {
            reader,
            topic: topic.to_string(),
        })
    }

    /// A publisher of `M` on `topic` with the configured publish QoS.
    pub fn publisher<M: RosMessage>(&mut self, topic: &str) -> Result<Publisher<M>, BridgeError> {
        let qos = self.config.publish_qos.policies();
        self.add_writer(topic, qos, "publisher")
    }

    /// A publisher of `M` on `topic` with tf2's static QoS (reliable, transient local,
    /// keep last 1): the last message reaches every subscriber that joins later.
    pub fn static_publisher<M: RosMessage>(
        &mut self,
        topic: &str,
    ) -> Result<Publisher<M>, BridgeError> {
        self.add_writer(topic, static_qos(), "latched publisher")
    }

    /// A subscription with tf2's static QoS: receives what a [`Self::static_publisher`]
    /// (or a tf2 `StaticTransformBroadcaster`) published before it joined.
    pub fn static_subscription<M: RosMessage>(
        &mut self,
        topic: &str,
    ) -> Result<Subscription<M>, BridgeError> {
        self.add_reader(topic, static_qos(), "subscribing (transient local) to")
    }

    /// A subscription to `M` on `topic` with the configured subscribe QoS.
    pub fn subscription<M: RosMessage>(
        &mut self,
        topic: &str,
    ) -> Result<Subscription<M>, BridgeError> {
        let qos = self.config.subscribe_qos.policies();
        self.add_reader(topic, qos, "subscribing to")
    }
}

impl Drop for RosNode {
    /// Tell the graph the node is gone (as rmw does when a node is destroyed).
    fn drop(&mut self) {
        self.announce(false);
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
                tracing::warn!(topic, error = %e, "dropping an unreadable message");
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
            Ok(Some(sample)) => latest = Some(sample),
            Ok(None) => break,
            Err(e) => {
                tracing::warn!(topic, error = %e, "dropping an unreadable message");
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
            tracing::warn!(topic, error = %e, "publish failed");
            false
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rtps_timestamps_in_nanoseconds() {
        // 3.5 s: seconds 3, fraction 2^31
        let t = Timestamp::from_ticks((3 << 32) | (1 << 31));
        assert_eq!(epoch_nanos(t), Some(3_500_000_000));
        assert_eq!(epoch_nanos(Timestamp::INVALID), None);
        let now = epoch_nanos(Timestamp::now()).unwrap();
        let wall = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_nanos() as i64;
        assert!((wall - now).abs() < 1_000_000_000, "{wall} {now}");
    }
}
