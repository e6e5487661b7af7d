//! Writing a ROS 2 bag in MCAP: profile `ros2`, message encoding `cdr` (the DDS payload
//! bytes, [`crate::cdr`]), one `ros2msg` schema per type with its nested definitions
//! ([`RosMessage::SCHEMA`]), so Foxglove, `ros2 bag` (with the MCAP storage plugin, the
//! default from Iron on) and this crate's readers open it.
//!
//! Each channel carries the `offered_qos_profiles` metadata that the ROS 2 MCAP profile
//! requires ([`offered_qos_profiles`]). Chunks are [`CHUNK_BYTES`], so a file cut off by
//! a power failure loses at most its last quarter megabyte: [`crate::read_mcap`] reads
//! such a file up to its last complete chunk.

use std::collections::BTreeMap;
use std::io::{Seek, Write};

use crate::RecordingError;
use crate::cdr::to_cdr;
use crate::msg::RosMessage;

/// Chunk size of the bags written: what a power cut can lose at most.
pub const CHUNK_BYTES: u64 = 256 * 1024;

/// History depth written into each channel's `offered_qos_profiles`.
pub const OFFERED_DEPTH: usize = 5;

/// rosbag2's `offered_qos_profiles` for a channel: one profile, reliable (1), volatile
/// (2), keep last (1) `depth`, default deadline, lifespan and liveliness. This is
/// Humble's numeric layout, which later distributions read too; reliable and volatile is
/// what `ros2 bag play` then offers, which matches reliable and best-effort subscribers
/// alike.
pub fn offered_qos_profiles(depth: usize) -> String {
    let zero = "\n    sec: 0\n    nsec: 0";
    format!(
        "- history: 1\n  depth: {depth}\n  reliability: 1\n  durability: 2\n  \
         deadline:{zero}\n  lifespan:{zero}\n  liveliness: 1\n  \
         liveliness_lease_duration:{zero}\n  avoid_ros_namespace_conventions: false"
    )
}

/// An MCAP ROS 2 bag being written.
pub struct McapBag<W: Write + Seek> {
    writer: mcap::Writer<W>,
    channels: BTreeMap<String, u16>,
    schemas: BTreeMap<String, u16>,
    sequence: u32,
    path: String,
}

impl<W: Write + Seek> McapBag<W> {
    /// Start a bag on `w`; `path` names it in errors, `library` goes into the header
    /// (the writing program and its version).
    pub fn new(w: W, path: &str, library: &str) -> Result<Self, RecordingError> {
        let writer = mcap::WriteOptions::new()
            .compression(None)
            .chunk_size(Some(CHUNK_BYTES))
            .profile("ros2")
            .library(library)
            .create(w)
            .map_err(|e| mcap_error(path, e))?;
        Ok(Self {
            writer,
            channels: BTreeMap::new(),
            schemas: BTreeMap::new(),
            sequence: 0,
            path: path.to_string(),
        })
    }

    /// Register `topic` carrying `M`.
    pub fn add_topic<M: RosMessage>(&mut self, topic: &str) -> Result<(), RecordingError> {
        let name = M::schema_name();
        let schema = match self.schemas.get(&name) {
            Some(&id) => id,
            None => {
                let id = self
                    .writer
                    .add_schema(&name, "ros2msg", M::SCHEMA.as_bytes())
                    .map_err(|e| mcap_error(&self.path, e))?;
                self.schemas.insert(name, id);
                id
            }
        };
        let metadata = BTreeMap::from([(
            "offered_qos_profiles".to_string(),
            offered_qos_profiles(OFFERED_DEPTH),
        )]);
        let id = self
            .writer
            .add_channel(schema, topic, "cdr", &metadata)
            .map_err(|e| mcap_error(&self.path, e))?;
        self.channels.insert(topic.to_string(), id);
        Ok(())
    }

    /// Write `msg` on `topic` (registered with [`McapBag::add_topic`]).
    pub fn write<M: RosMessage>(
        &mut self,
        topic: &str,
        msg: &M,
        log_time_ns: u64,
        publish_time_ns: u64,
    ) -> Result<(), RecordingError> {
        let Some(&channel_id) = self.channels.get(topic) else {
            return Err(RecordingError::Format {
                path: self.path.clone(),
                message: format!("topic {topic} is not registered in this bag"),
            });
        };
        let data = to_cdr(msg).map_err(|e| RecordingError::Format {
            path: self.path.clone(),
            message: format!("encoding a {topic} message: {e}"),
        })?;
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time: log_time_ns,
            publish_time: publish_time_ns,
        };
        self.sequence = self.sequence.wrapping_add(1);
        self.writer
            .write_to_known_channel(&header, &data)
            .map_err(|e| mcap_error(&self.path, e))
    }

    /// Write the summary and hand back the sink.
    pub fn finish(mut self) -> Result<W, RecordingError> {
        self.writer
            .finish()
            .map_err(|e| mcap_error(&self.path, e))?;
        Ok(self.writer.into_inner())
    }
}

fn mcap_error(path: &str, e: mcap::McapError) -> RecordingError {
    RecordingError::Format {
        path: path.to_string(),
        message: format!("MCAP: {e}"),
    }
}
