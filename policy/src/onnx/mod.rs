//! ONNX policies: a network exported by any learner, run in pure Rust with `tract`.
//!
//! A model is read, checked against the observation contract and optimised once into an
//! [`OnnxPolicy`] (a plan behind an `Arc`); every episode and thread then runs that plan
//! through its own [`OnnxDriver`]. The contract (docs/onnx.md has the long form):
//!
//! - **Inputs** are named after observation keys, all `float32`, batch dimension first
//!   (symbolic or 1; Paddock feeds one car at a time):
//!   - `scans` `[batch, beams]`: the car's LIDAR ranges in metres; `beams` must be a fixed
//!     number and equal the vehicle's LIDAR beam count;
//!   - a scalar key ([`SCALAR_KEYS`]: `linear_vels_x`, `poses_theta`, ...) as `[batch]` or
//!     `[batch, 1]`, the car's own value in SI units (`collisions` is 0 or 1);
//!   - `prev_action` `[batch, 2]`: the action this driver returned at the previous step
//!     (after clamping), zeros at the start of an episode.
//!
//!   Any subset is allowed; an input with another name or shape is refused at load time.
//! - **Output**: the output named `action`, or the only output, `float32` `[batch, 2]` =
//!   (steering angle rad, speed m/s), clamped to the vehicle's limits.
//! - **Metadata** (ONNX `metadata_props`, all optional): `paddock.action_repeat` (an
//!   integer >= 1: the network runs every that many steps and its action is held in
//!   between), `paddock.lidar_fov` (radians, checked against the vehicle's LIDAR).
//! - **Size**: a model file larger than [`MAX_MODEL_BYTES`] is refused before it is read.
//!
//! A non-finite action at run time is not an action: [`OnnxDriver`] stops the car
//! (steering 0, speed 0) and reports the fault through [`crate::Driver::fault`]; the
//! rollout ends that car's episode as a crash.

mod contract;
mod driver;
mod registry;
mod sample;
pub mod write;

use paddock_sim::lidar::LidarConfig;
use paddock_sim::world::Observation;
use sha2::{Digest, Sha256};
use tract_onnx::prelude::*;

pub use driver::OnnxDriver;
pub(crate) use registry::register_by_hash;
pub use registry::{is_model_name, model_name, register, registered};

/// The registry name of ONNX drivers.
pub const NAME: &str = "onnx";
pub const ABOUT: &str = "ONNX model (inputs named after observation keys -> [steering, speed])";

/// The largest model file accepted, bytes (64 MiB: a LIDAR policy is usually well under
/// 1 MiB; the cap bounds what a model can make a process hold).
pub const MAX_MODEL_BYTES: usize = 64 << 20;

/// The scalar observation keys a model may take as inputs, `[batch]` or `[batch, 1]`.
pub const SCALAR_KEYS: &[&str] = &[
    "poses_x",
    "poses_y",
    "poses_theta",
    "linear_vels_x",
    "linear_vels_y",
    "ang_vels_z",
    "steering_angles",
    "slip_angles",
    "progress",
    "lap_times",
    "lap_counts",
    "collisions",
];

/// The input carrying the LIDAR scan.
pub const SCANS: &str = "scans";
/// The optional input carrying the previous action.
pub const PREV_ACTION: &str = "prev_action";
/// Metadata key: hold each action for this many steps.
pub const META_ACTION_REPEAT: &str = "paddock.action_repeat";
/// Metadata key: the LIDAR field of view the model was trained with, radians.
pub const META_LIDAR_FOV: &str = "paddock.lidar_fov";

/// Why a model was refused, or why it failed at run time; each names the model.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum OnnxError {
    #[error("model {model}: {size} bytes is over the {max}-byte limit")]
    TooLarge {
        model: String,
        size: u64,
        max: usize,
    },
    #[error("model {model}: cannot read it: {cause}")]
    Io { model: String, cause: String },
    #[error("model {model}: not an ONNX model: {cause}")]
    NotOnnx { model: String, cause: String },
    #[error("model {model}: input {input:?} is not an observation key (known: {known})")]
    UnknownInput {
        model: String,
        input: String,
        known: String,
    },
    #[error("model {model}: input {input:?} has element type {got}, expected float32")]
    InputType {
        model: String,
        input: String,
        got: String,
    },
    #[error("model {model}: input {input:?} has shape {got}, expected {expected}")]
    InputShape {
        model: String,
        input: String,
        expected: String,
        got: String,
    },
    #[error("model {model}: it has no inputs (expected a subset of the observation keys)")]
    NoInputs { model: String },
    #[error("model {model}: {message}")]
    Output { model: String, message: String },
    #[error("model {model}: metadata {key} = {value:?}: {message}")]
    Metadata {
        model: String,
        key: String,
        value: String,
        message: String,
    },
    #[error(
        "model {model}: input scans has {model_beams} beams, the vehicle's LIDAR {lidar_beams}"
    )]
    BeamCount {
        model: String,
        model_beams: usize,
        lidar_beams: usize,
    },
    #[error(
        "model {model}: trained with a LIDAR field of view of {model_fov} rad, the vehicle's is {lidar_fov} rad"
    )]
    FieldOfView {
        model: String,
        model_fov: f64,
        lidar_fov: f64,
    },
    #[error("model {model}: tract cannot run it: {cause}")]
    Unsupported { model: String, cause: String },
    #[error("model {model}: inference failed: {cause}")]
    Run { model: String, cause: String },
}

/// What one model input carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Feed {
    /// The car's scan, this many beams.
    Scans { beams: usize },
    /// One scalar observation key (an entry of [`SCALAR_KEYS`]).
    Scalar(&'static str),
    /// The previous action.
    PrevAction,
}

/// One model input: its name, what it carries and the shape fed (batch 1).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InputSlot {
    pub name: String,
    pub feed: Feed,
    pub shape: Vec<usize>,
}

type Plan = TypedSimplePlan<TypedModel>;

/// A checked, optimised model: share it (`Arc`) between every driver that runs it.
pub struct OnnxPolicy {
    label: String,
    hash: String,
    inputs: Vec<InputSlot>,
    action_repeat: u32,
    lidar_fov: Option<f64>,
    plan: Plan,
}

impl std::fmt::Debug for OnnxPolicy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OnnxPolicy")
            .field("label", &self.label)
            .field("hash", &self.hash)
            .field("inputs", &self.inputs)
            .field("action_repeat", &self.action_repeat)
            .field("lidar_fov", &self.lidar_fov)
            .finish_non_exhaustive()
    }
}

/// Hex SHA-256 of a model's bytes: its identity wherever it travels.
pub fn model_hash(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

impl OnnxPolicy {
    /// Read, check and optimise the model at `path` (size capped before reading).
    pub fn load(path: &std::path::Path) -> Result<Self, OnnxError> {
        let model = path.display().to_string();
        let bytes = read_model_file(path)?;
        Self::from_bytes(&bytes, &model)
    }

    /// Check and optimise a model from its bytes; `label` names it in errors.
    pub fn from_bytes(bytes: &[u8], label: &str) -> Result<Self, OnnxError> {
        let model = label.to_string();
        if bytes.len() > MAX_MODEL_BYTES {
            return Err(OnnxError::TooLarge {
                model,
                size: bytes.len() as u64,
                max: MAX_MODEL_BYTES,
            });
        }
        let onnx = tract_onnx::onnx();
        let proto = onnx
            .proto_model_for_read(&mut &bytes[..])
            .map_err(|e| OnnxError::NotOnnx {
                model: model.clone(),
                cause: format!("{e:#}"),
            })?;
        let Some(graph) = proto.graph.as_ref().filter(|_| proto.ir_version > 0) else {
            return Err(OnnxError::NotOnnx {
                model,
                cause: "no IR version or no graph".into(),
            });
        };
        let (action_repeat, lidar_fov) = contract::read_metadata(&proto, &model)?;
        let inputs = contract::check_inputs(graph, &model)?;
        let output = contract::pick_output(graph, &model)?;

        let mut net = onnx
            .model_for_proto_model(&proto)
            .map_err(|e| OnnxError::Unsupported {
                model: model.clone(),
                cause: format!("{e:#}"),
            })?;
        let unsupported = |e: TractError| OnnxError::Unsupported {
            model: model.clone(),
            cause: format!("{e:#}"),
        };
        // feed facts in tract's input order, matched by name
        let outlets = net.input_outlets().map_err(unsupported)?.to_vec();
        let mut ordered = Vec::with_capacity(inputs.len());
        for (i, outlet) in outlets.iter().enumerate() {
            let name = net.node(outlet.node).name.clone();
            let Some(slot) = inputs.iter().find(|s| s.name == name) else {
                return Err(OnnxError::Unsupported {
                    model: model.clone(),
                    cause: format!("tract input {name:?} is not a graph input"),
                });
            };
            net.set_input_fact(
                i,
                InferenceFact::dt_shape(f32::datum_type(), slot.shape.clone()),
            )
            .map_err(unsupported)?;
            ordered.push(slot.clone());
        }
        let out = net.output_outlets().map_err(unsupported)?[output];
        net.set_output_outlets(&[out]).map_err(unsupported)?;
        let typed = net.into_optimized().map_err(unsupported)?;
        let fact = typed.output_fact(0).map_err(unsupported)?;
        if fact.datum_type != f32::datum_type() || fact.shape.as_concrete() != Some(&[1, 2][..]) {
            return Err(OnnxError::Output {
                model: model.clone(),
                message: format!(
                    "the action output is {:?} {:?}, expected float32 [batch, 2] (steering rad, speed m/s)",
                    fact.datum_type, fact.shape
                ),
            });
        }
        let plan = typed.into_runnable().map_err(unsupported)?;
        Ok(Self {
            label: model,
            hash: model_hash(bytes),
            inputs: ordered,
            action_repeat,
            lidar_fov,
            plan,
        })
    }

    /// The label given at load (the file path, usually).
    pub fn label(&self) -> &str {
        &self.label
    }

    /// Hex SHA-256 of the model's bytes.
    pub fn hash(&self) -> &str {
        &self.hash
    }

    /// The inputs, in the order the plan takes them.
    pub fn inputs(&self) -> &[InputSlot] {
        &self.inputs
    }

    /// The LIDAR beam count the model reads, if it reads the scan.
    pub fn beams(&self) -> Option<usize> {
        self.inputs.iter().find_map(|s| match s.feed {
            Feed::Scans { beams } => Some(beams),
            _ => None,
        })
    }

    /// Steps each action is held for (metadata `paddock.action_repeat`, default 1).
    pub fn action_repeat(&self) -> u32 {
        self.action_repeat
    }

    /// The field of view from metadata `paddock.lidar_fov`, if given.
    pub fn lidar_fov(&self) -> Option<f64> {
        self.lidar_fov
    }

    /// Check the model's scan input against the vehicle's LIDAR.
    pub fn check_lidar(&self, lidar: &LidarConfig) -> Result<(), OnnxError> {
        let Some(beams) = self.beams() else {
            return Ok(());
        };
        if beams != lidar.num_beams {
            return Err(OnnxError::BeamCount {
                model: self.label.clone(),
                model_beams: beams,
                lidar_beams: lidar.num_beams,
            });
        }
        if let Some(fov) = self.lidar_fov
            && (fov - lidar.fov).abs() > 1e-6
        {
            return Err(OnnxError::FieldOfView {
                model: self.label.clone(),
                model_fov: fov,
                lidar_fov: lidar.fov,
            });
        }
        Ok(())
    }

    /// Run the network for car `me` of `obs` with previous action `prev`: the raw
    /// (unclamped) output. Errors when the scan's beam count does not match or tract fails.
    pub fn infer(
        &self,
        obs: &Observation,
        me: usize,
        prev: [f64; 2],
    ) -> Result<[f32; 2], OnnxError> {
        let mut feeds = Vec::with_capacity(self.inputs.len());
        for slot in &self.inputs {
            feeds.push(match slot.feed {
                Feed::Scans { beams } => {
                    if obs.num_beams != beams {
                        return Err(OnnxError::BeamCount {
                            model: self.label.clone(),
                            model_beams: beams,
                            lidar_beams: obs.num_beams,
                        });
                    }
                    obs.scan(me).iter().map(|&r| r as f32).collect()
                }
                Feed::Scalar(key) => vec![scalar(obs, key, me) as f32],
                Feed::PrevAction => vec![prev[0] as f32, prev[1] as f32],
            });
        }
        self.run(&feeds)
    }

    /// Run the network on raw input values, one flat vector per input in
    /// [`Self::inputs`] order (each of its slot's shape): the raw output.
    pub fn run(&self, feeds: &[Vec<f32>]) -> Result<[f32; 2], OnnxError> {
        let run_err = |cause: String| OnnxError::Run {
            model: self.label.clone(),
            cause,
        };
        if feeds.len() != self.inputs.len() {
            return Err(run_err(format!(
                "{} inputs given, the model takes {}",
                feeds.len(),
                self.inputs.len()
            )));
        }
        let mut values: TVec<TValue> = TVec::with_capacity(feeds.len());
        for (slot, data) in self.inputs.iter().zip(feeds) {
            let t = Tensor::from_shape(&slot.shape, data)
                .map_err(|e| run_err(format!("input {}: {e:#}", slot.name)))?;
            values.push(t.into());
        }
        let out = self
            .plan
            .run(values)
            .map_err(|e| run_err(format!("{e:#}")))?;
        let view = out[0]
            .to_array_view::<f32>()
            .map_err(|e| run_err(format!("{e:#}")))?;
        let v: Vec<f32> = view.iter().copied().collect();
        match v[..] {
            [steer, speed] => Ok([steer, speed]),
            _ => Err(run_err(format!(
                "action has {} values, expected 2",
                v.len()
            ))),
        }
    }
}

/// Read a model file, refusing one over [`MAX_MODEL_BYTES`] before reading it.
pub fn read_model_file(path: &std::path::Path) -> Result<Vec<u8>, OnnxError> {
    use std::io::Read;
    let model = path.display().to_string();
    let io = |e: std::io::Error| OnnxError::Io {
        model: model.clone(),
        cause: e.to_string(),
    };
    let file = std::fs::File::open(path).map_err(io)?;
    let size = file.metadata().map_err(io)?.len();
    if size > MAX_MODEL_BYTES as u64 {
        return Err(OnnxError::TooLarge {
            model,
            size,
            max: MAX_MODEL_BYTES,
        });
    }
    let mut bytes = Vec::with_capacity(size as usize);
    // the take() bounds a file that grows while being read
    file.take(MAX_MODEL_BYTES as u64 + 1)
        .read_to_end(&mut bytes)
        .map_err(io)?;
    if bytes.len() > MAX_MODEL_BYTES {
        return Err(OnnxError::TooLarge {
            model,
            size: bytes.len() as u64,
            max: MAX_MODEL_BYTES,
        });
    }
    Ok(bytes)
}

/// The car's value of scalar observation key `key`.
pub fn scalar(obs: &Observation, key: &str, me: usize) -> f64 {
    match key {
        "poses_x" => obs.poses_x[me],
        "poses_y" => obs.poses_y[me],
        "poses_theta" => obs.poses_theta[me],
        "linear_vels_x" => obs.linear_vels_x[me],
        "linear_vels_y" => obs.linear_vels_y[me],
        "ang_vels_z" => obs.ang_vels_z[me],
        "steering_angles" => obs.steering_angles[me],
        "slip_angles" => obs.slip_angles[me],
        "progress" => obs.progress[me],
        "lap_times" => obs.lap_times[me],
        "lap_counts" => f64::from(obs.lap_counts[me]),
        "collisions" => f64::from(u8::from(obs.collisions[me])),
        _ => unreachable!("inputs are checked against SCALAR_KEYS at load"),
    }
}
