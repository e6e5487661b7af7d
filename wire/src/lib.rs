//! # paddock-wire: the one adapter between the wire and the domain
//!
//! Protobuf types stop at the edge. A worker turns a task's scenario bytes into an
//! [`EpisodeTask`](paddock_rollout::EpisodeTask) here and its result back into a
//! [`TaskOutcome`](paddock_proto::TaskOutcome); a client turns its scenarios into wire
//! batches and the outcomes back into [`EpisodeResult`](paddock_rollout::EpisodeResult)s
//! here; an env session's open request becomes an
//! [`EnvConfig`](paddock_rollout::env::EnvConfig) and its frames the observation payload
//! here; the job plans plugged into the broker read specs and outcomes here. One
//! conversion for each thing, shared by all of them: a scenario and an env session are
//! read by the same agent, LIDAR, obstacle and collision readers, so they accept and
//! refuse the same values with the same field names.
//!
//! Every f64 travels as its exact bits (proto doubles, packed little-endian bytes,
//! vehicle YAML written with shortest round-trip floats), so a result computed remotely
//! equals the same result computed locally (`PartialEq`). Decoding checks every field a
//! request may carry and names the first bad one in an [`Error`] (`INVALID_ARGUMENT`),
//! e.g. `agents[1].params[2]`; [`with_prefix`] puts the enclosing path in front.

pub mod env;
pub mod maps;
pub mod models;
pub mod results;
pub mod scenario;
#[cfg(test)]
mod tests;

pub use maps::{check_map_bundle, circuit_bundle, local_map, map_ref, shipped_bundles};
pub use models::{ModelRefused, model_field, model_hash_of, register_model, unregistered_models};
pub use results::{
    episode_result_from_proto, episode_result_to_proto, outcome_from_bytes, outcome_from_proto,
    outcome_to_bytes, outcome_to_proto,
};
pub use scenario::{
    MAX_BEAMS, MAX_OBSTACLES, batch_to_proto, record_from_proto, record_to_proto,
    rollout_error_from_proto, rollout_error_to_proto, scenario_from_bytes, scenario_from_proto,
    scenario_to_proto, task_from_assign,
};

use paddock_proto::{Error, ErrorCode, error};

pub(crate) fn invalid(field: impl Into<String>, message: impl Into<String>) -> Error {
    error(ErrorCode::InvalidArgument, field, message)
}

/// The same error with `prefix` put in front of its field path
/// (`"scenarios[0]"` + `"agents[1].params[2]"` = `"scenarios[0].agents[1].params[2]"`).
pub fn with_prefix(mut e: Error, prefix: &str) -> Error {
    if prefix.is_empty() {
        return e;
    }
    e.field = if e.field.is_empty() {
        prefix.to_string()
    } else if e.field.starts_with('[') {
        format!("{prefix}{}", e.field)
    } else {
        format!("{prefix}.{}", e.field)
    };
    e
}

pub(crate) fn u32_of(v: usize) -> u32 {
    // a count beyond u32 is refused by the receiver's range checks
    u32::try_from(v).unwrap_or(u32::MAX)
}

pub(crate) fn check_range(field: &str, v: f64, lo: f64, hi: f64) -> Result<(), Error> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(invalid(
            field,
            format!("{field} = {v} is outside [{lo}, {hi}]"),
        ))
    }
}
