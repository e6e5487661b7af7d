//! # paddock-proto: the wire contract
//!
//! Every ZeroMQ message between clients, the broker and workers is an [`Envelope`] frame
//! (the routing header) followed by the payload frames its body announces
//! ([`payload_frames`]; see `paddock.proto` and `PROTOCOL.md` in this crate). The broker
//! routes by the header and forwards payload frames without decoding them. This crate
//! holds the generated types and the checks every peer applies before it trusts a frame:
//! [`decode`] refuses oversized frames, undecodable bytes, a wrong protocol version and
//! an empty body, each with an [`Error`] naming the problem that can be sent straight
//! back. Bulk numbers travel as packed little-endian bytes ([`pack_f64`],
//! [`unpack_f64`], ...); maps and other content travel by hash ([`bundle_hash`],
//! [`blob_hash`]).
//!
//! This crate is the ground floor: it knows nothing of the simulator, drivers or
//! rollouts. Conversions between these messages and the domain live in `paddock-wire`.

use std::path::Path;

use prost::Message;
use sha2::{Digest, Sha256};

/// The generated protobuf types (package `paddock.v1`).
pub mod v1 {
    include!(concat!(env!("OUT_DIR"), "/paddock.v1.rs"));
}

pub use v1::envelope::Body;
pub use v1::*;

/// The protocol version this build speaks.
pub const PROTOCOL_VERSION: u32 = 2;

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
    decode_envelope(frame).map(|(rid, _, body)| (rid, body))
}

/// [`decode`], with the Envelope's `client_token` (empty when the sender gave none).
pub fn decode_envelope(frame: &[u8]) -> Result<(u64, Vec<u8>, Body), (u64, ProtoError)> {
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
        Some(body) => Ok((env.request_id, env.client_token, body)),
        None => Err((env.request_id, ProtoError::EmptyBody)),
    }
}

/// Encodes one message with the current protocol version.
pub fn encode(request_id: u64, body: Body) -> Vec<u8> {
    encode_with_token(request_id, Vec::new(), body)
}

/// [`encode`] with a client token (see `Envelope.client_token`).
pub fn encode_with_token(request_id: u64, client_token: Vec<u8>, body: Body) -> Vec<u8> {
    Envelope {
        protocol_version: PROTOCOL_VERSION,
        request_id,
        client_token,
        body: Some(body),
    }
    .encode_to_vec()
}

/// Bytes of a client token (`Envelope.client_token`): at least this many, so it cannot
/// be guessed...
pub const MIN_CLIENT_TOKEN: usize = 16;
/// ... and at most this many.
pub const MAX_CLIENT_TOKEN: usize = 64;

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
        Body::BlobRequest(_) => "blob_request",
        Body::Blob(_) => "blob",
        Body::RolloutBatch(_) => "rollout_batch",
        Body::RolloutResult(_) => "rollout_result",
        Body::RolloutProgress(_) => "rollout_progress",
        Body::PutMap(_) => "put_map",
        Body::MapStored(_) => "map_stored",
        Body::PutBlob(_) => "put_blob",
        Body::BlobStored(_) => "blob_stored",
        Body::EnvRequest(_) => "env_request",
        Body::EnvReply(_) => "env_reply",
        Body::JobSubmit(_) => "job_submit",
        Body::JobInfo(_) => "job_info",
        Body::JobStatus(_) => "job_status",
        Body::JobList(_) => "job_list",
        Body::JobListing(_) => "job_listing",
        Body::JobCancel(_) => "job_cancel",
        Body::JobResultRequest(_) => "job_result_request",
        Body::JobResult(_) => "job_result",
        Body::JobWatch(_) => "job_watch",
        Body::JobDelete(_) => "job_delete",
        Body::JobDeleted(_) => "job_deleted",
        Body::StatusRequest(_) => "status_request",
        Body::BrokerStatus(_) => "broker_status",
        Body::Error(_) => "error",
    }
}

/// How many payload frames follow an Envelope with this body (see `paddock.proto`).
pub fn payload_frames(body: &Body) -> usize {
    match body {
        Body::EnvRequest(r) => match EnvOp::try_from(r.op) {
            Ok(EnvOp::EnvClose) | Ok(EnvOp::Unspecified) | Err(_) => 0,
            Ok(_) => 1,
        },
        Body::EnvReply(r) if r.error.is_some() => 0,
        Body::EnvReply(r) => match EnvOp::try_from(r.op) {
            Ok(EnvOp::EnvOpen) => 1,
            Ok(EnvOp::EnvReset) | Ok(EnvOp::EnvStep) | Ok(EnvOp::EnvRender) => 2,
            _ => 0,
        },
        Body::TaskResult(_) => 1,
        Body::RolloutResult(r) => r.outcomes as usize,
        Body::JobResult(r) => r.outcomes as usize,
        _ => 0,
    }
}

/// The name of an env op as in `paddock.proto` (e.g. "ENV_STEP").
pub fn op_name(op: i32) -> &'static str {
    EnvOp::try_from(op)
        .map(|o| o.as_str_name())
        .unwrap_or("UNKNOWN_OP")
}

/// A fingerprint of a reply's payload frames (64-bit, not cryptographic): a worker puts
/// it in every [`EnvReply`], and the broker compares a rebuilt session's replies with the
/// originals by it. Reads eight bytes at a time in four independent lanes, so the 280 KB
/// of a 64-env observation take a few tens of microseconds.
pub fn fingerprint(frames: &[&[u8]]) -> u64 {
    const K: [u64; 4] = [
        0x9e37_79b9_7f4a_7c15,
        0xc2b2_ae3d_27d4_eb4f,
        0x1656_67b1_9e37_79f9,
        0x85eb_ca77_c2b2_ae63,
    ];
    let mut lanes = K;
    for (n, frame) in frames.iter().enumerate() {
        lanes[n % 4] ^= (frame.len() as u64).wrapping_mul(K[(n + 1) % 4]);
        let mut words = frame.chunks_exact(32);
        for block in &mut words {
            for (lane, (word, k)) in lanes.iter_mut().zip(block.chunks_exact(8).zip(K)) {
                let w = u64::from_le_bytes(word.try_into().unwrap_or([0; 8]));
                *lane = (*lane ^ w).wrapping_mul(k).rotate_left(29);
            }
        }
        let mut tail = [0u8; 32];
        let rest = words.remainder();
        tail[..rest.len()].copy_from_slice(rest);
        for (lane, (word, k)) in lanes.iter_mut().zip(tail.chunks_exact(8).zip(K)) {
            let w = u64::from_le_bytes(word.try_into().unwrap_or([0; 8]));
            *lane = (*lane ^ w ^ rest.len() as u64)
                .wrapping_mul(k)
                .rotate_left(31);
        }
    }
    let mut h = 0u64;
    for (i, lane) in lanes.iter().enumerate() {
        h = (h ^ lane.rotate_left(16 * i as u32)).wrapping_mul(K[i]);
        h ^= h >> 32;
    }
    h
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

// ------------------------------------------------------------------ content hashes

/// The hex SHA-256 of some bytes: the name of a blob (an encoded scenario, a model file).
pub fn blob_hash(data: &[u8]) -> String {
    hex(&Sha256::digest(data))
}

/// Bytes as lower-case hex digits, two a byte (hashes, routing ids, tokens). A table
/// lookup per digit: the broker writes one for every client request (its principal),
/// where a `format!` per byte was most of the request's own work.
pub fn hex(bytes: &[u8]) -> String {
    const DIGITS: &[u8; 16] = b"0123456789abcdef";
    let mut s = String::with_capacity(2 * bytes.len());
    for &b in bytes {
        s.push(char::from(DIGITS[usize::from(b >> 4)]));
        s.push(char::from(DIGITS[usize::from(b & 0xf)]));
    }
    s
}

/// Whether `s` is a lower-case hex SHA-256 (64 digits), as [`blob_hash`] and
/// [`bundle_hash`] write them.
pub fn is_hash(s: &str) -> bool {
    s.len() == 64 && s.bytes().all(|b| matches!(b, b'0'..=b'9' | b'a'..=b'f'))
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
    hex(&h.finalize())
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

/// Checks a received bundle's form: bare file names, size limit, and that the hash
/// matches its files. The error names the offending field. (What the files say, e.g.
/// that a map YAML's image is a file of the bundle of a sane size, is checked by
/// `paddock_wire::check_map_bundle`.)
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
    fn hex_writes_two_lower_case_digits_a_byte() {
        assert_eq!(hex(&[]), "");
        let all: Vec<u8> = (0..=255).collect();
        let want: String = all.iter().map(|b| format!("{b:02x}")).collect();
        assert_eq!(hex(&all), want);
        // the hashes' published test vectors (FIPS 180-2): the same text as before
        assert_eq!(
            blob_hash(b"abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        assert_eq!(
            blob_hash(b""),
            "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"
        );
        assert!(is_hash(&blob_hash(b"abc")));
    }

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
            client_token: Vec::new(),
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
            client_token: Vec::new(),
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
}
