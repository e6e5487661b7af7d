//! CDR, the encoding of ROS 2 messages on DDS and in bags: the one codec of the project.
//!
//! Plain CDR (XCDR1) is positional: a struct is its fields in IDL order with natural
//! alignment (counted from the start of the body), a fixed array its values with no
//! length, a sequence or string a `u32` length and the values. The message types of
//! [`crate::msg`] are serde structs in IDL field order, so the `cdr-encoding` serialiser
//! writes the bytes rclcpp and rclpy write.
//!
//! A complete payload, what an MCAP `cdr` message or a rosbag2 row holds, is a 4-byte
//! encapsulation header (`00 01 00 00`: plain CDR, little endian) and the body; on DDS the
//! header travels as the sample's representation identifier and the body alone as the
//! data ([`encode_body`], [`decode_body`]). The bridge's DDS layer and the bag readers
//! and writers both go through these functions.

use serde::Serialize;
use serde::de::DeserializeOwned;

/// The CDR encapsulation header of little-endian plain CDR (XCDR1), as ROS 2 writes it.
pub const CDR_LE_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// Byte order of a CDR body (the encapsulation header says which).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ByteOrder {
    Little,
    Big,
}

/// A message that could not be encoded or decoded, and why.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("CDR: {0}")]
pub struct CdrError(pub String);

/// Serialise `msg` as a little-endian CDR body (no encapsulation header): a DDS sample's
/// data.
pub fn encode_body<M: Serialize>(msg: &M) -> Result<Vec<u8>, CdrError> {
    cdr_encoding::to_vec::<M, byteorder::LittleEndian>(msg).map_err(|e| CdrError(e.to_string()))
}

/// Decode a CDR body (no encapsulation header) of the given byte order.
pub fn decode_body<M: DeserializeOwned>(body: &[u8], order: ByteOrder) -> Result<M, CdrError> {
    let decoded = match order {
        ByteOrder::Little => cdr_encoding::from_bytes::<M, byteorder::LittleEndian>(body),
        ByteOrder::Big => cdr_encoding::from_bytes::<M, byteorder::BigEndian>(body),
    };
    decoded.map(|(m, _)| m).map_err(|e| CdrError(e.to_string()))
}

/// Serialise `msg` as a complete CDR payload (encapsulation header + little-endian body),
/// the bytes an MCAP `cdr` message and a rosbag2 row carry.
pub fn to_cdr<M: Serialize>(msg: &M) -> Result<Vec<u8>, CdrError> {
    let body = encode_body(msg)?;
    let mut out = Vec::with_capacity(body.len() + 4);
    out.extend_from_slice(&CDR_LE_HEADER);
    out.extend_from_slice(&body);
    Ok(out)
}

/// Decode a complete CDR payload (encapsulation header + body), either byte order.
pub fn from_cdr<M: DeserializeOwned>(bytes: &[u8]) -> Result<M, CdrError> {
    if bytes.len() < 4 {
        return Err(CdrError(format!(
            "{} bytes: too short for a CDR payload (needs a 4-byte header)",
            bytes.len()
        )));
    }
    let order = match (bytes[0], bytes[1]) {
        (0x00, 0x01) => ByteOrder::Little,
        (0x00, 0x00) => ByteOrder::Big,
        (a, b) => {
            return Err(CdrError(format!(
                "encapsulation {a:#04x} {b:#04x} is not plain CDR (XCDR1)"
            )));
        }
    };
    decode_body(&bytes[4..], order)
}
