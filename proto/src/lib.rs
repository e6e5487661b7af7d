//! # paddock-proto: the wire contract
//!
//! Every ZeroMQ message between clients, the broker and workers is one [`Envelope`]
//! (see `paddock.proto` and `PROTOCOL.md` in this crate). This crate holds the
//! generated types and the checks every peer applies before it trusts a frame:
//! [`decode`] refuses oversized frames, undecodable bytes, a wrong protocol version and
//! an empty body, each with an [`Error`] naming the problem that can be sent straight
//! back. Bulk numbers travel as packed little-endian bytes ([`pack_f64`],
//! [`unpack_f64`], ...); maps travel by content hash ([`bundle_hash`]).

use std::path::Path;

use prost::Message;
use sha2::{Digest, Sha256};

pub mod convert;

/// The generated protobuf types (package `paddock.v1`).
pub mod v1 {
    include!(concat!(env!("OUT_DIR"), "/paddock.v1.rs"));
}

pub use v1::envelope::Body;
pub use v1::*;

/// The protocol version this build speaks.
pub const PROTOCOL_VERSION: u32 = 1;

/// Frames larger than this are refused unread.
pub const MAX_MESSAGE_BYTES: usize = 64 << 20;

/// Largest map bundle accepted (all files together).
pub const MAX_MAP_BYTES: usize = 48 << 20;

/// Why a frame was refused; [`ProtoError::to_error`] makes the reply.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProtoError {
    #[error("message of {size} bytes exceeds the limit of {limit} bytes")]
    TooLarge { size: usize, limit: usize },
    #[error("malformed envelope: {0}")]
    Malformed(String),
    #[error("protocol_version {got} is not supported (this peer speaks {PROTOCOL_VERSION})")]
    Version { got: u32 },
    #[error("envelope has no body")]
    EmptyBody,
}

impl ProtoError {
    /// The error reply for this refusal.
    pub fn to_error(&self) -> Error {
        let (code, field) = match self {
            ProtoError::TooLarge { .. } => (ErrorCode::TooLarge, ""),
            ProtoError::Malformed(_) => (ErrorCode::BadMessage, ""),
            ProtoError::Version { .. } => (ErrorCode::UnsupportedVersion, "protocol_version"),
            ProtoError::EmptyBody => (ErrorCode::UnknownType, "body"),
        };
        error(code, field, self.to_string())
    }
}

/// Decodes and checks one frame. The request id is returned even when the body is
/// refused, where it could be read, so the error reply can carry it.
pub fn decode(frame: &[u8]) -> Result<(u64, Body), (u64, ProtoError)> {
    if frame.len() > MAX_MESSAGE_BYTES {
        return Err((
            0,
            ProtoError::TooLarge {
                size: frame.len(),
                limit: MAX_MESSAGE_BYTES,
            },
        ));
    }
    let env = Envelope::decode(frame).map_err(|e| (0, ProtoError::Malformed(e.to_string())))?;
    if env.protocol_version != PROTOCOL_VERSION {
        return Err((
            env.request_id,
            ProtoError::Version {
                got: env.protocol_version,
            },
        ));
    }
    match env.body {
        Some(body) => Ok((env.request_id, body)),
        None => Err((env.request_id, ProtoError::EmptyBody)),
    }
}

/// Encodes one message with the current protocol version.
pub fn encode(request_id: u64, body: Body) -> Vec<u8> {
    Envelope {
        protocol_version: PROTOCOL_VERSION,
        request_id,
        body: Some(body),
    }
    .encode_to_vec()
}

/// An [`Error`] message.
pub fn error(code: ErrorCode, field: impl Into<String>, message: impl Into<String>) -> Error {
    Error {
        code: code as i32,
        field: field.into(),
        message: message.into(),
    }
}

/// An encoded error reply.
pub fn encode_error(
    request_id: u64,
    code: ErrorCode,
    field: impl Into<String>,
    message: impl Into<String>,
) -> Vec<u8> {
    encode(request_id, Body::Error(error(code, field, message)))
}

/// The body's name as in `paddock.proto`, for logs and counters.
pub fn body_name(body: &Body) -> &'static str {
    match body {
        Body::WorkerHello(_) => "worker_hello",
        Body::WorkerWelcome(_) => "worker_welcome",
        Body::Heartbeat(_) => "heartbeat",
        Body::TaskAssign(_) => "task_assign",
        Body::TaskResult(_) => "task_result",
        Body::MapRequest(_) => "map_request",
        Body::MapBundle(_) => "map_bundle",
        Body::Bye(_) => "bye",
        Body::RolloutBatch(_) => "rollout_batch",
        Body::RolloutResult(_) => "rollout_result",
        Body::RolloutProgress(_) => "rollout_progress",
        Body::PutMap(_) => "put_map",
        Body::MapStored(_) => "map_stored",
        Body::EnvOpen(_) => "env_open",
        Body::EnvOpened(_) => "env_opened",
        Body::EnvReset(_) => "env_reset",
        Body::EnvStep(_) => "env_step",
        Body::EnvObservation(_) => "env_observation",
        Body::EnvClose(_) => "env_close",
        Body::EnvClosed(_) => "env_closed",
        Body::EnvRender(_) => "env_render",
        Body::EnvImage(_) => "env_image",
        Body::JobSubmit(_) => "job_submit",
        Body::JobInfo(_) => "job_info",
        Body::JobStatus(_) => "job_status",
        Body::JobList(_) => "job_list",
        Body::JobListing(_) => "job_listing",
        Body::JobCancel(_) => "job_cancel",
        Body::JobResultRequest(_) => "job_result_request",
        Body::JobResult(_) => "job_result",
        Body::JobWatch(_) => "job_watch",
        Body::StatusRequest(_) => "status_request",
        Body::BrokerStatus(_) => "broker_status",
        Body::Error(_) => "error",
    }
}

/// The name of an error code as in `paddock.proto` (e.g. "INVALID_ARGUMENT").
pub fn code_name(code: i32) -> &'static str {
    ErrorCode::try_from(code)
        .map(|c| c.as_str_name())
        .unwrap_or("UNKNOWN_CODE")
}

// ------------------------------------------------------------------ packed numbers

/// Packs values as their `N`-byte little-endian forms, written in place into one
/// allocation (a loop the compiler turns into wide copies: the 64-env scans of an env
/// step are 276 KB, packed on the worker's socket thread while its pool waits).
fn pack<T: Copy, const N: usize>(values: &[T], le_bytes: impl Fn(T) -> [u8; N]) -> Vec<u8> {
    let mut out = vec![0u8; values.len() * N];
    for (o, &v) in out.chunks_exact_mut(N).zip(values) {
        o.copy_from_slice(&le_bytes(v));
    }
    out
}

/// Packs f64 values little endian.
pub fn pack_f64(values: &[f64]) -> Vec<u8> {
    pack(values, f64::to_le_bytes)
}

/// Packs f32 values little endian.
pub fn pack_f32(values: &[f32]) -> Vec<u8> {
    pack(values, f32::to_le_bytes)
}

/// Packs u32 values little endian.
pub fn pack_u32(values: &[u32]) -> Vec<u8> {
    pack(values, u32::to_le_bytes)
}

/// Unpacks little-endian f64 values; `field` names the bytes in the error.
pub fn unpack_f64(bytes: &[u8], field: &str) -> Result<Vec<f64>, Error> {
    if !bytes.len().is_multiple_of(8) {
        return Err(error(
            ErrorCode::BadMessage,
            field,
            format!(
                "{field}: {} bytes is not a whole number of f64 values",
                bytes.len()
            ),
        ));
    }
    Ok(bytes
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().expect("8-byte chunk")))
        .collect())
}

/// Unpacks little-endian f32 values; `field` names the bytes in the error.
pub fn unpack_f32(bytes: &[u8], field: &str) -> Result<Vec<f32>, Error> {
    if !bytes.len().is_multiple_of(4) {
        return Err(error(
            ErrorCode::BadMessage,
            field,
            format!(
                "{field}: {} bytes is not a whole number of f32 values",
                bytes.len()
            ),
        ));
    }
    Ok(bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().expect("4-byte chunk")))
        .collect())
}

// ------------------------------------------------------------------ map bundles

/// The content hash of a map: hex SHA-256 over its files in name order (name, length,
/// bytes of each), so the same files give the same hash wherever they are read.
pub fn bundle_hash(files: &[MapFile]) -> String {
    let mut sorted: Vec<&MapFile> = files.iter().collect();
    sorted.sort_by(|a, b| a.name.cmp(&b.name));
    let mut h = Sha256::new();
    for f in sorted {
        h.update((f.name.len() as u64).to_le_bytes());
        h.update(f.name.as_bytes());
        h.update((f.data.len() as u64).to_le_bytes());
        h.update(&f.data);
    }
    h.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

/// Reads every regular file of a map directory into a bundle (hash filled in).
pub fn read_map_dir(dir: &Path, name: &str) -> std::io::Result<MapBundle> {
    let mut files = Vec::new();
    let mut total = 0usize;
    for entry in std::fs::read_dir(dir)? {
        let entry = entry?;
        if !entry.file_type()?.is_file() {
            continue;
        }
        let file_name = entry.file_name().to_string_lossy().into_owned();
        let data = std::fs::read(entry.path())?;
        total += data.len();
        if total > MAX_MAP_BYTES {
            return Err(std::io::Error::other(format!(
                "map directory {} holds more than {MAX_MAP_BYTES} bytes",
                dir.display()
            )));
        }
        files.push(MapFile {
            name: file_name,
            data,
        });
    }
    files.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(MapBundle {
        hash: bundle_hash(&files),
        name: name.to_string(),
        files,
    })
}

/// Checks a received bundle: bare file names, size limit, and that the hash matches
/// its files. The error names the offending field.
pub fn check_bundle(bundle: &MapBundle) -> Result<(), Error> {
    if bundle.files.is_empty() {
        return Err(error(
            ErrorCode::InvalidArgument,
            "map_bundle.files",
            "a map bundle needs at least one file",
        ));
    }
    let mut total = 0usize;
    for (i, f) in bundle.files.iter().enumerate() {
        let bad_name = f.name.is_empty()
            || f.name == "."
            || f.name == ".."
            || f.name.contains('/')
            || f.name.contains('\\')
            || f.name.contains('\0');
        if bad_name {
            return Err(error(
                ErrorCode::InvalidArgument,
                format!("map_bundle.files[{i}].name"),
                format!("{:?} is not a bare file name", f.name),
            ));
        }
        total += f.data.len();
    }
    if total > MAX_MAP_BYTES {
        return Err(error(
            ErrorCode::TooLarge,
            "map_bundle.files",
            format!("{total} bytes of map files exceed the limit of {MAX_MAP_BYTES}"),
        ));
    }
    check_bundle_images(bundle)?;
    let hash = bundle_hash(&bundle.files);
    if hash != bundle.hash {
        return Err(error(
            ErrorCode::InvalidArgument,
            "map_bundle.hash",
            format!(
                "hash {:?} does not match the files (their hash is {hash})",
                bundle.hash
            ),
        ));
    }
    Ok(())
}

/// A bundle is self-contained: each map YAML's `image:` must be a bare name of a file
/// in the bundle (never a path: nothing outside the bundle is opened, so a client cannot
/// probe the host's files), and each image's header must claim a size within the caps of
/// [`paddock_sim::map::image_dimensions`]. Only headers are read here, so this is cheap
/// enough for the broker's socket thread; the pixels are decoded by the worker.
fn check_bundle_images(bundle: &MapBundle) -> Result<(), Error> {
    for (i, f) in bundle.files.iter().enumerate() {
        if !(f.name.ends_with(".yaml") || f.name.ends_with(".yml")) {
            continue;
        }
        let Ok(text) = std::str::from_utf8(&f.data) else {
            continue;
        };
        let field = format!("map_bundle.files[{i}].image");
        let image = match paddock_sim::map::bundle_image_name(text) {
            Ok(Some(name)) => name,
            Ok(None) => continue,
            Err(reason) => return Err(error(ErrorCode::InvalidArgument, field, reason)),
        };
        let Some((j, img)) = bundle
            .files
            .iter()
            .enumerate()
            .find(|(_, g)| g.name == image)
        else {
            return Err(error(
                ErrorCode::InvalidArgument,
                field,
                format!("{image:?} is not a file of the bundle"),
            ));
        };
        paddock_sim::map::image_dimensions(&img.data).map_err(|reason| {
            let code = if reason.contains("exceeds the limit") {
                ErrorCode::TooLarge
            } else {
                ErrorCode::InvalidArgument
            };
            error(
                code,
                format!("map_bundle.files[{j}].data"),
                format!("map image {image:?}: {reason}"),
            )
        })?;
    }
    Ok(())
}

/// Writes a checked bundle's files into `dir` (created if missing).
pub fn write_map_dir(bundle: &MapBundle, dir: &Path) -> std::io::Result<()> {
    check_bundle(bundle).map_err(|e| std::io::Error::other(e.message))?;
    std::fs::create_dir_all(dir)?;
    for f in &bundle.files {
        std::fs::write(dir.join(&f.name), &f.data)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_keeps_request_id_and_body() {
        let frame = encode(42, Body::MapRequest(MapRequest { hash: "abc".into() }));
        let (id, body) = decode(&frame).unwrap();
        assert_eq!(id, 42);
        assert_eq!(body, Body::MapRequest(MapRequest { hash: "abc".into() }));
    }

    #[test]
    fn refusals_name_the_problem() {
        let (_, e) = decode(&[0xff, 0xff, 0xff]).unwrap_err();
        assert!(matches!(e, ProtoError::Malformed(_)));
        let old = Envelope {
            protocol_version: 7,
            request_id: 5,
            body: Some(Body::StatusRequest(StatusRequest {})),
        }
        .encode_to_vec();
        let (id, e) = decode(&old).unwrap_err();
        assert_eq!(id, 5);
        assert_eq!(e, ProtoError::Version { got: 7 });
        assert_eq!(e.to_error().field, "protocol_version");
        let empty = Envelope {
            protocol_version: PROTOCOL_VERSION,
            request_id: 9,
            body: None,
        }
        .encode_to_vec();
        assert_eq!(decode(&empty).unwrap_err(), (9, ProtoError::EmptyBody));
        let huge = vec![0u8; MAX_MESSAGE_BYTES + 1];
        assert!(matches!(
            decode(&huge).unwrap_err().1,
            ProtoError::TooLarge { .. }
        ));
    }

    #[test]
    fn packed_numbers_round_trip_and_reject_ragged_bytes() {
        let v = [1.5, -0.0, f64::MAX, 3.25e-300];
        assert_eq!(unpack_f64(&pack_f64(&v), "x").unwrap(), v);
        let w = [1.5f32, -2.0, 7.0e-30];
        assert_eq!(unpack_f32(&pack_f32(&w), "scans").unwrap(), w);
        // little endian, byte for byte
        assert_eq!(pack_f32(&[1.0]), [0, 0, 0x80, 0x3f]);
        assert_eq!(pack_u32(&[0x0102_0304, 7]), [4, 3, 2, 1, 7, 0, 0, 0]);
        assert_eq!(pack_f64(&[-2.0])[7], 0xc0);
        assert!(pack_f32(&[]).is_empty());
        let e = unpack_f64(&[0u8; 9], "trajectory.t").unwrap_err();
        assert_eq!(e.field, "trajectory.t");
        assert!(e.message.contains("9 bytes"));
    }

    #[test]
    fn bundle_hash_ignores_order_and_checks_names() {
        let a = MapFile {
            name: "a.yaml".into(),
            data: b"x".to_vec(),
        };
        let b = MapFile {
            name: "b.png".into(),
            data: vec![1, 2, 3],
        };
        assert_eq!(
            bundle_hash(&[a.clone(), b.clone()]),
            bundle_hash(&[b.clone(), a.clone()])
        );
        let mut bundle = MapBundle {
            hash: bundle_hash(&[a.clone(), b.clone()]),
            name: "m".into(),
            files: vec![a.clone(), b],
        };
        check_bundle(&bundle).unwrap();
        bundle.files[1].data.push(0);
        assert_eq!(check_bundle(&bundle).unwrap_err().field, "map_bundle.hash");
        bundle.files[1].name = "../evil".into();
        assert_eq!(
            check_bundle(&bundle).unwrap_err().field,
            "map_bundle.files[1].name"
        );
    }

    fn map_bundle(yaml: &str, image: (&str, Vec<u8>)) -> MapBundle {
        let files = vec![
            MapFile {
                name: "m_map.yaml".into(),
                data: yaml.as_bytes().to_vec(),
            },
            MapFile {
                name: image.0.into(),
                data: image.1,
            },
        ];
        MapBundle {
            hash: bundle_hash(&files),
            name: "m".into(),
            files,
        }
    }

    fn yaml(image: &str) -> String {
        format!("image: {image}\nresolution: 0.05\norigin: [0, 0, 0]\n")
    }

    /// A client's bundle could name any host file as its image, and the different errors
    /// for existing, missing and directory paths told the client which exist.
    #[test]
    fn bundle_image_paths_outside_the_bundle_are_refused_without_opening_them() {
        let png = std::fs::read(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../maps/lakeside/lakeside_map.png"
        ))
        .unwrap();
        check_bundle(&map_bundle(&yaml("m_map.png"), ("m_map.png", png.clone()))).unwrap();
        let mut messages = Vec::new();
        for bad in [
            "/etc/passwd",
            "/nonexistent/x.png",
            "/tmp",
            "../m_map.png",
            "../../etc/hosts",
        ] {
            let e = check_bundle(&map_bundle(&yaml(bad), ("m_map.png", png.clone()))).unwrap_err();
            assert_eq!(e.field, "map_bundle.files[0].image", "{bad}: {e:?}");
            assert_eq!(e.code, ErrorCode::InvalidArgument as i32);
            assert!(e.message.contains(bad), "{bad}: {}", e.message);
            messages.push(e.message.replace(bad, "PATH"));
        }
        // the same answer whether the path exists, is missing or is a directory
        messages.dedup();
        assert_eq!(messages.len(), 1, "{messages:?}");
        // a bare name that is not in the bundle
        let e = check_bundle(&map_bundle(&yaml("other.png"), ("m_map.png", png))).unwrap_err();
        assert_eq!(e.field, "map_bundle.files[0].image");
        assert!(
            e.message.contains("not a file of the bundle"),
            "{}",
            e.message
        );
    }

    #[test]
    fn bundle_images_above_the_size_cap_are_refused_from_the_header() {
        // a PNG header claiming 20000 x 20000 pixels, then a token of image data
        fn chunk(out: &mut Vec<u8>, kind: &[u8], data: &[u8]) {
            out.extend_from_slice(&(data.len() as u32).to_be_bytes());
            let start = out.len();
            out.extend_from_slice(kind);
            out.extend_from_slice(data);
            let mut crc = !0u32;
            for &b in &out[start..] {
                crc ^= u32::from(b);
                for _ in 0..8 {
                    crc = if crc & 1 == 1 {
                        (crc >> 1) ^ 0xEDB8_8320
                    } else {
                        crc >> 1
                    };
                }
            }
            out.extend_from_slice(&(!crc).to_be_bytes());
        }
        let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
        let mut ihdr = 20_000u32.to_be_bytes().repeat(2);
        ihdr.extend_from_slice(&[8, 0, 0, 0, 0]);
        chunk(&mut png, b"IHDR", &ihdr);
        chunk(
            &mut png,
            b"IDAT",
            &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01],
        );
        chunk(&mut png, b"IEND", &[]);
        let e = check_bundle(&map_bundle(&yaml("m_map.png"), ("m_map.png", png))).unwrap_err();
        assert_eq!(e.field, "map_bundle.files[1].data");
        assert_eq!(e.code, ErrorCode::TooLarge as i32);
        assert!(e.message.contains("20000 x 20000"), "{}", e.message);
    }
}
