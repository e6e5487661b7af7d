//! [`DriverSpec`]: which driver a car gets, a built-in by name or an ONNX model by its
//! bytes.
//!
//! A spec is data, not a loaded network, so it can travel: a model is identified by the
//! hex SHA-256 of its bytes (as map bundles are). Requests (scenarios, jobs) only ever
//! carry driver *names*; a model's name is `onnx:<sha256>` and resolves only once the
//! model is registered with the process ([`crate::onnx::register`]), which loads and
//! optimises it once. Locally, [`DriverSpec::parse`] reads a `.onnx` path the user gave
//! and [`DriverSpec::register`] turns it into that name. A later wire format can send the
//! hash in the request and the bytes once per worker, which registers them on arrival.

use std::path::Path;
use std::sync::Arc;

use crate::PolicyError;
use crate::onnx::{self, OnnxError};

/// Which driver a car gets.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DriverSpec {
    /// A registry driver (`pure-pursuit`, ...) or an already registered model's name.
    Named(String),
    /// An ONNX model's bytes.
    Onnx(OnnxModel),
}

/// An ONNX model's bytes with their content hash (computed here, so they always agree)
/// and a label for messages (the file it came from, or `onnx:<hash prefix>`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OnnxModel {
    label: String,
    hash: String,
    bytes: Arc<[u8]>,
}

impl OnnxModel {
    /// A model from its bytes; errors when they are over [`onnx::MAX_MODEL_BYTES`].
    pub fn from_bytes(bytes: Vec<u8>, label: Option<&str>) -> Result<Self, PolicyError> {
        let hash = onnx::model_hash(&bytes);
        let label = label.map_or_else(|| format!("onnx:{}", &hash[..12]), str::to_string);
        if bytes.len() > onnx::MAX_MODEL_BYTES {
            return Err(OnnxError::TooLarge {
                model: label,
                size: bytes.len() as u64,
                max: onnx::MAX_MODEL_BYTES,
            }
            .into());
        }
        Ok(Self {
            label,
            hash,
            bytes: bytes.into(),
        })
    }

    /// Read a model file (size capped before reading).
    pub fn read(path: &Path) -> Result<Self, PolicyError> {
        let bytes = onnx::read_model_file(path)?;
        Self::from_bytes(bytes, Some(&path.display().to_string()))
    }

    pub fn label(&self) -> &str {
        &self.label
    }

    /// Hex SHA-256 of the bytes.
    pub fn hash(&self) -> &str {
        &self.hash
    }

    pub fn bytes(&self) -> &[u8] {
        &self.bytes
    }
}

/// Whether a driver name is a model file path (it ends in `.onnx`, any case).
pub fn is_model_path(name: &str) -> bool {
    name.len() > 5
        && name.is_char_boundary(name.len() - 5)
        && name[name.len() - 5..].eq_ignore_ascii_case(".onnx")
}

impl DriverSpec {
    /// A driver as a user writes it on the command line: a path ending in `.onnx` is read
    /// as a model (not yet checked: see [`Self::register`]); anything else must be a
    /// driver name ([`crate::driver_info`] knows it). Never call it on a name from a
    /// request: it opens files.
    pub fn parse(name: &str) -> Result<Self, PolicyError> {
        if is_model_path(name) {
            return Ok(Self::Onnx(OnnxModel::read(Path::new(name))?));
        }
        crate::driver_info(name)?;
        Ok(Self::Named(name.to_string()))
    }

    /// The driver name to put in a scenario: a name as it is; a model is checked,
    /// optimised and registered with this process (once per content hash), and its name
    /// `onnx:<sha256>` returned.
    pub fn register(&self) -> Result<String, PolicyError> {
        match self {
            Self::Named(name) => Ok(name.clone()),
            Self::Onnx(m) => Ok(onnx::register_by_hash(&m.hash, &m.bytes, &m.label)?.to_string()),
        }
    }
}
