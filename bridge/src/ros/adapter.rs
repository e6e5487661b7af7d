//! RustDDS's (de)serializer hooks, filled with the project's one CDR codec
//! (`paddock_recordings::cdr`): a sample on DDS is the same body an MCAP or rosbag2
//! message holds after its 4-byte encapsulation header, which DDS carries as the sample's
//! representation identifier instead.

use std::marker::PhantomData;

use paddock_recordings::cdr::{ByteOrder, CdrError, decode_body, encode_body};
use rustdds::RepresentationIdentifier;
use rustdds::bytes::Bytes;
use rustdds::no_key::{Decode, DefaultDecoder, DeserializerAdapter, SerializerAdapter};
use serde::Serialize;
use serde::de::DeserializeOwned;

/// The adapter type RustDDS's readers and writers are parameterised with.
pub struct RosCdr<M>(PhantomData<M>);

/// What a reader decodes: plain CDR (XCDR1) in either byte order, as ROS 2 writes it.
const DECODED: [RepresentationIdentifier; 2] = [
    RepresentationIdentifier::CDR_LE,
    RepresentationIdentifier::CDR_BE,
];

impl<M: Serialize> SerializerAdapter<M> for RosCdr<M> {
    type Error = CdrError;

    fn output_encoding() -> RepresentationIdentifier {
        RepresentationIdentifier::CDR_LE
    }

    fn to_bytes(value: &M) -> Result<Bytes, CdrError> {
        encode_body(value).map(Bytes::from)
    }
}

impl<M> DeserializerAdapter<M> for RosCdr<M> {
    type Error = CdrError;
    type Decoded = M;

    fn supported_encodings() -> &'static [RepresentationIdentifier] {
        &DECODED
    }

    fn transform_decoded(decoded: M) -> M {
        decoded
    }
}

impl<M: DeserializeOwned> DefaultDecoder<M> for RosCdr<M> {
    type Decoder = RosCdrDecoder<M>;
    const DECODER: RosCdrDecoder<M> = RosCdrDecoder(PhantomData);
}

/// The decoder object RustDDS asks for: stateless.
pub struct RosCdrDecoder<M>(PhantomData<M>);

// by hand: a derive would require `M: Clone`
impl<M> Clone for RosCdrDecoder<M> {
    fn clone(&self) -> Self {
        Self(PhantomData)
    }
}

impl<'de, M: DeserializeOwned> Decode<'de, M> for RosCdrDecoder<M> {
    type Error = CdrError;

    fn decode_bytes(
        self,
        body: &'de [u8],
        encoding: RepresentationIdentifier,
    ) -> Result<M, CdrError> {
        let order = if encoding == RepresentationIdentifier::CDR_LE {
            ByteOrder::Little
        } else if encoding == RepresentationIdentifier::CDR_BE {
            ByteOrder::Big
        } else {
            return Err(CdrError(format!(
                "sample encoding {encoding:?} is not plain CDR (XCDR1)"
            )));
        };
        decode_body(body, order)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use paddock_recordings::cdr::to_cdr;
    use paddock_recordings::msg::{AckermannDrive, AckermannDriveStamped, Header, Time};

    /// A DDS sample's data is the bag payload without its header, both ways.
    #[test]
    fn samples_are_the_bag_bytes_without_the_header() {
        let m = AckermannDriveStamped {
            header: Header::new(Time { sec: 5, nanosec: 9 }, "base_link"),
            drive: AckermannDrive {
                speed: 1.5,
                ..AckermannDrive::default()
            },
        };
        let body = RosCdr::<AckermannDriveStamped>::to_bytes(&m).unwrap();
        assert_eq!(&to_cdr(&m).unwrap()[4..], &body[..]);
        let back =
            RosCdr::<AckermannDriveStamped>::from_bytes(&body, RepresentationIdentifier::CDR_LE)
                .unwrap();
        assert_eq!(back, m);
        assert!(
            RosCdr::<AckermannDriveStamped>::from_bytes(&body, RepresentationIdentifier::PL_CDR_LE)
                .is_err()
        );
    }
}
