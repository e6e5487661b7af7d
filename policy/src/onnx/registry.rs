//! The process's registered models: `onnx:<sha256>` names and their shared plans.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

use super::{NAME, OnnxError, OnnxPolicy, model_hash};

/// The driver name of a registered model: `onnx:` and its hex SHA-256.
pub fn model_name(hash: &str) -> String {
    format!("{NAME}:{hash}")
}

/// Register a model with this process: check and optimise it once (a second call with the
/// same bytes returns at once) and return its driver name, `onnx:<sha256>`, which
/// [`crate::build_driver`] and [`crate::driver_info`] then accept.
///
/// Only registered models have names, so a request naming a model (a broker job, a
/// worker's episode) can never make a process open a file: a trusted caller (the CLI
/// reading a path the user gave, later a worker fetching a model by hash as it fetches
/// maps) registers it first.
pub fn register(bytes: &[u8], label: &str) -> Result<&'static str, OnnxError> {
    register_by_hash(&model_hash(bytes), bytes, label)
}

/// [`register`] with the bytes' hash already known (`hash` must be [`model_hash`] of
/// `bytes`).
pub(crate) fn register_by_hash(
    hash: &str,
    bytes: &[u8],
    label: &str,
) -> Result<&'static str, OnnxError> {
    if let Some((name, _)) = registered_hash(hash) {
        return Ok(name);
    }
    // optimise outside the lock: another thread may do the same work, the first wins
    let policy = Arc::new(OnnxPolicy::from_bytes(bytes, label)?);
    let mut map = REGISTRY
        .get_or_init(Default::default)
        .lock()
        .unwrap_or_else(|e| e.into_inner());
    let entry = map.entry(hash.to_string()).or_insert_with(|| {
        // one small string per registered model for the process's life: driver names
        // are `&'static str`
        let name: &'static str = Box::leak(model_name(hash).into_boxed_str());
        (name, policy)
    });
    Ok(entry.0)
}

fn registered_hash(hash: &str) -> Option<(&'static str, Arc<OnnxPolicy>)> {
    REGISTRY
        .get_or_init(Default::default)
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .get(hash)
        .map(|(n, p)| (*n, p.clone()))
}

/// The registered model called `name` (`onnx:<sha256>`): its name and shared policy.
pub fn registered(name: &str) -> Option<(&'static str, Arc<OnnxPolicy>)> {
    registered_hash(name.strip_prefix(NAME)?.strip_prefix(':')?)
}

/// Whether `name` is an ONNX driver name (`onnx:...`), registered or not.
pub fn is_model_name(name: &str) -> bool {
    name.starts_with("onnx:")
}

type Registry = Mutex<HashMap<String, (&'static str, Arc<OnnxPolicy>)>>;

static REGISTRY: OnceLock<Registry> = OnceLock::new();
