//! The ROS graph record: what `ros2 node list` and `ros2 topic info -v` read.
//!
//! A ROS 2 participant says which nodes it hosts, and which of its DDS readers and
//! writers belong to each, by publishing rmw_dds_common's `ParticipantEntitiesInfo` on
//! the DDS topic `ros_discovery_info` (reliable, transient local, keep last 1, so a tool
//! started later still gets it). The entities are named by their gid, and the gid's size
//! changed between distributions: `char[24]` on Humble (the 16-byte DDS GUID and 8 zero
//! bytes), `uint8[16]` from Iron on. CDR has no lengths for fixed arrays, so a reader of
//! the other layout misparses every record. Hence the layout is chosen at run time
//! ([`RosDistro`]), not when the program is built.
//!
//! The record is a ROS message, but an rmw-internal one whose layout depends on the
//! distribution, so it lives here with the node layer rather than with the car's
//! messages in `paddock-recordings`; it is encoded by the same CDR codec.

use std::fmt;
use std::str::FromStr;

use serde::Serialize;
use serde::ser::{SerializeTuple, Serializer};

use crate::BridgeError;

/// The DDS topic of the graph record (no `rt/` prefix: it is not a ROS topic).
pub const TOPIC: &str = "ros_discovery_info";
/// The DDS type name of the graph record.
pub const TYPE_NAME: &str = "rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_";

/// The ROS 2 distribution of the car's stack, which fixes the graph record's layout.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum RosDistro {
    /// Humble Hawksbill (2022 LTS): 24-byte gids.
    Humble,
    /// Iron Irwini: 16-byte gids from here on.
    Iron,
    /// Jazzy Jalisco (2024 LTS).
    #[default]
    Jazzy,
    /// Kilted Kaiju.
    Kilted,
    /// Rolling Ridley (the development line).
    Rolling,
}

impl RosDistro {
    /// Every distribution understood, oldest first.
    pub const ALL: [RosDistro; 5] = [
        RosDistro::Humble,
        RosDistro::Iron,
        RosDistro::Jazzy,
        RosDistro::Kilted,
        RosDistro::Rolling,
    ];

    /// The name `ROS_DISTRO` holds when the distribution is sourced (`humble`).
    pub const fn name(self) -> &'static str {
        match self {
            RosDistro::Humble => "humble",
            RosDistro::Iron => "iron",
            RosDistro::Jazzy => "jazzy",
            RosDistro::Kilted => "kilted",
            RosDistro::Rolling => "rolling",
        }
    }

    /// Bytes of a gid in this distribution's graph record.
    pub const fn gid_bytes(self) -> usize {
        match self {
            RosDistro::Humble => 24,
            _ => 16,
        }
    }
}

impl fmt::Display for RosDistro {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for RosDistro {
    type Err = BridgeError;

    /// A distribution name as `ROS_DISTRO` holds it (case and surrounding blanks ignored).
    fn from_str(s: &str) -> Result<Self, BridgeError> {
        let want = s.trim().to_ascii_lowercase();
        Self::ALL
            .into_iter()
            .find(|d| d.name() == want)
            .ok_or_else(|| {
                let names: Vec<&str> = Self::ALL.iter().map(|d| d.name()).collect();
                BridgeError::config(
                    "ros_distro",
                    format!("{s:?}"),
                    &format!(
                        "unknown ROS 2 distribution; one of {} (it sets the layout of the ROS \
                         graph record: 24-byte gids on Humble, 16 from Iron on)",
                        names.join(", ")
                    ),
                )
            })
    }
}

/// A DDS entity's gid in one distribution's layout: the 16-byte GUID, zero-padded to the
/// layout's length.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Gid {
    guid: [u8; 16],
    bytes: usize,
}

impl Gid {
    pub fn new(guid: [u8; 16], distro: RosDistro) -> Self {
        Self {
            guid,
            bytes: distro.gid_bytes(),
        }
    }

    /// The bytes as the record carries them.
    pub fn to_bytes(&self) -> Vec<u8> {
        (0..self.bytes)
            .map(|i| self.guid.get(i).copied().unwrap_or(0))
            .collect()
    }
}

impl Serialize for Gid {
    /// A fixed array (`char[24]` / `uint8[16]`): the bytes with no length.
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut t = s.serialize_tuple(self.bytes)?;
        for b in self.to_bytes() {
            t.serialize_element(&b)?;
        }
        t.end()
    }
}

/// rmw_dds_common/NodeEntitiesInfo: one node and its readers and writers.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct NodeEntitiesInfo {
    pub node_namespace: String,
    pub node_name: String,
    pub reader_gid_seq: Vec<Gid>,
    pub writer_gid_seq: Vec<Gid>,
}

/// rmw_dds_common/ParticipantEntitiesInfo: a participant and the nodes it hosts.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ParticipantEntitiesInfo {
    pub gid: Gid,
    pub node_entities_info_seq: Vec<NodeEntitiesInfo>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use paddock_recordings::cdr::encode_body;

    fn record(distro: RosDistro) -> ParticipantEntitiesInfo {
        let guid = |last: u8| {
            let mut g = [7u8; 16];
            g[15] = last;
            g
        };
        ParticipantEntitiesInfo {
            gid: Gid::new(guid(0xc1), distro),
            node_entities_info_seq: vec![NodeEntitiesInfo {
                node_namespace: "/".into(),
                node_name: "paddock_drive".into(),
                reader_gid_seq: vec![Gid::new(guid(4), distro), Gid::new(guid(5), distro)],
                writer_gid_seq: vec![Gid::new(guid(3), distro)],
            }],
        }
    }

    /// The bytes of each layout, field by field (rmw_dds_common's IDL of each release).
    #[test]
    fn humble_writes_24_byte_gids_and_iron_on_16() {
        for (distro, n) in [(RosDistro::Humble, 24), (RosDistro::Jazzy, 16)] {
            let b = encode_body(&record(distro)).unwrap();
            let mut at = 0;
            let gid = |b: &[u8], at: &mut usize, last: u8| {
                assert_eq!(&b[*at..*at + 15], &[7u8; 15], "{distro}");
                assert_eq!(b[*at + 15], last, "{distro}");
                assert!(b[*at + 16..*at + n].iter().all(|&x| x == 0), "{distro}");
                *at += n;
            };
            let u32_at =
                |b: &[u8], at: usize| u32::from_le_bytes(b[at..at + 4].try_into().unwrap());
            gid(&b, &mut at, 0xc1);
            assert_eq!(u32_at(&b, at), 1, "one node");
            at += 4;
            assert_eq!(u32_at(&b, at), 2);
            assert_eq!(&b[at + 4..at + 6], b"/\0");
            at += 8; // "/\0" and padding to 4
            assert_eq!(u32_at(&b, at), 14);
            assert_eq!(&b[at + 4..at + 18], b"paddock_drive\0");
            at += 20; // 14 bytes and padding to 4
            assert_eq!(u32_at(&b, at), 2, "two readers");
            at += 4;
            gid(&b, &mut at, 4);
            gid(&b, &mut at, 5);
            assert_eq!(u32_at(&b, at), 1, "one writer");
            at += 4;
            gid(&b, &mut at, 3);
            assert_eq!(at, b.len());
        }
    }

    #[test]
    fn distributions_parse_by_name_and_unknown_ones_are_named() {
        assert_eq!(" Humble\n".parse::<RosDistro>().unwrap(), RosDistro::Humble);
        for d in RosDistro::ALL {
            assert_eq!(d.name().parse::<RosDistro>().unwrap(), d);
        }
        assert_eq!(RosDistro::Iron.gid_bytes(), 16);
        let e = "foxy".parse::<RosDistro>().unwrap_err().to_string();
        assert!(
            e.contains("\"foxy\"") && e.contains("humble, iron, jazzy"),
            "{e}"
        );
    }
}
