//! ONNX models by content hash.
//!
//! A scenario, a job or an env open names a model as the driver `onnx:<sha256>`; the
//! model's bytes travel on their own, like maps: a client stores them in the broker once
//! (`PutBlob`), and a process that meets a name it has not registered (a worker, the
//! broker's job checks) fetches the bytes by that hash once and registers them
//! ([`register_model`]), which checks the model against the observation contract and
//! optimises it once for the process. A name never makes a process open a file.

use paddock_proto::{AgentSpec, Error, ErrorCode, blob_hash, error, is_hash};

/// The content hash a driver name carries when it names a model (`onnx:<sha256>`, the
/// hash in lower-case hex); None for any other driver name.
pub fn model_hash_of(driver: &str) -> Option<&str> {
    driver.strip_prefix("onnx:").filter(|h| is_hash(h))
}

/// The hashes of the models `agents` name that this process has not registered yet,
/// each once, in the order the agents name them.
pub fn unregistered_models(agents: &[AgentSpec]) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for a in agents {
        if let Some(h) = model_hash_of(&a.driver)
            && paddock_policy::onnx::registered(&a.driver).is_none()
            && !out.iter().any(|o| o == h)
        {
            out.push(h.to_string());
        }
    }
    out
}

/// The field of the first agent (under `prefix`, e.g. `agents` or `opponents`) whose
/// driver is the model with hash `hash`: `agents[2].driver`; `prefix` alone when none is.
pub fn model_field(agents: &[AgentSpec], hash: &str, prefix: &str) -> String {
    agents
        .iter()
        .position(|a| model_hash_of(&a.driver) == Some(hash))
        .map_or_else(|| prefix.to_string(), |i| format!("{prefix}[{i}].driver"))
}

/// Why a fetched model was refused; [`ModelRefused::to_error`] names the field that
/// named it.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelRefused {
    pub code: ErrorCode,
    pub hash: String,
    pub cause: String,
}

impl ModelRefused {
    /// The error reply for the car whose driver `field` named the model.
    pub fn to_error(&self, field: &str) -> Error {
        error(
            self.code,
            field,
            format!("{field} = onnx:{}: {}", self.hash, self.cause),
        )
    }
}

/// Registers the model whose bytes `data` were fetched for `hash`: the bytes must have
/// that hash, and the model must load and meet the observation contract.
pub fn register_model(hash: &str, data: &[u8]) -> Result<(), ModelRefused> {
    let refused = |code, cause| ModelRefused {
        code,
        hash: hash.to_string(),
        cause,
    };
    let got = blob_hash(data);
    if got != hash {
        return Err(refused(
            ErrorCode::Internal,
            format!("the {} bytes fetched for it have hash {got}", data.len()),
        ));
    }
    let label = format!("onnx:{}", &hash[..hash.len().min(12)]);
    paddock_policy::onnx::register(data, &label)
        .map(|_| ())
        .map_err(|e| refused(ErrorCode::InvalidArgument, e.to_string()))
}
