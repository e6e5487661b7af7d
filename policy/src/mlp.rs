//! An MLP policy for learners: observation features -> tanh hidden layers -> [steer,
//! speed], squashed into the car's limits.
//!
//! ## Features (in this order; [`MlpConfig::num_features`] of them)
//! 1. `beams` LIDAR sectors: the scan cut into `beams` equal runs of beams, each the
//!    minimum range of its run divided by the LIDAR's default `max_range` (30 m), so in
//!    [0, 1];
//! 2. speed: longitudinal speed / the car's `v_max`;
//! 3. steering: current steering angle / the car's steering limit;
//! 4. if `track_features`: the lateral offset from the circuit's driving line (its
//!    raceline, or a line inside the map's free space), with its hairpins rounded
//!    ([`crate::refpath::ROUNDING_PASSES`]), metres, positive to the left, clamped to
//!    [-3, 3];
//! 5. if `track_features`: the heading error, car heading minus that line's heading, rad,
//!    wrapped to [-pi, pi).
//!
//! ## Network
//! `layers` = [features, hidden..., 2]; hidden layers use tanh, the output is linear:
//! o = [o_steer, o_speed]. The action is steer = s_lim * tanh(o_steer) (s_lim the car's
//! symmetric steering limit) and speed = v_top * (tanh(o_speed) + 1) / 2 with v_top =
//! min(`speed_max`, the car's `v_max`).
//!
//! ## Parameter vector
//! Layer by layer: the weight matrix row by row (`w{l}[{out}][{in}]`), then the biases
//! (`b{l}[{out}]`). Every entry is bounded to [-5, 5] for tuners.
//!
//! ## Default init (the registry defaults)
//! All zeros except: hidden unit 0 of the first layer reads the lateral offset (weight
//! -0.6) and the heading error (-1.2), unit 0 of each further hidden layer copies unit 0
//! of the layer before (weight 1), the steering output reads unit 0 (weight 2), and the
//! speed output's bias is atanh(2 * 3 / v_top - 1) for v_top = 10, i.e. a 3 m/s
//! command. That is a slow raceline follower (a Stanley-like law) a learner can start
//! from; without track features only the speed bias is set.
//!
//! ## File format
//! JSON: `{"layers": [27, 16, 2], "weights": [...]}` plus optional `beams` (23),
//! `track_features` (true), `speed_max` (10.0). [`Mlp::load`] errors name the file and
//! the field.

use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

use paddock_sim::circuit::Circuit;
use paddock_sim::geometry::wrap_angle;
use paddock_sim::lidar::LidarConfig;
use paddock_sim::params::VehicleParams;
use paddock_sim::world::{Action, Observation};
use serde::{Deserialize, Serialize};

use crate::refpath::{ROUNDING_PASSES, RefPath};
use crate::{Driver, ParamSpec, PolicyError, Sensors};

pub const NAME: &str = "mlp";
pub const ABOUT: &str =
    "MLP policy (23 LIDAR sectors, speed, steering, raceline offset and heading -> 16 tanh -> 2)";

/// Bounds of every weight in the parameter vector.
pub const WEIGHT_BOUND: f64 = 5.0;

/// The features and the architecture.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MlpConfig {
    /// LIDAR sectors (0: no LIDAR, the driver then does not ask for scans).
    pub beams: usize,
    /// Append the raceline lateral offset and heading error.
    pub track_features: bool,
    /// Hidden layer widths.
    pub hidden: Vec<usize>,
    /// Top of the speed output, m/s (also capped at the car's `v_max`).
    pub speed_max: f64,
}

impl Default for MlpConfig {
    fn default() -> Self {
        Self {
            beams: 23,
            track_features: true,
            hidden: vec![16],
            speed_max: 10.0,
        }
    }
}

impl MlpConfig {
    pub fn num_features(&self) -> usize {
        self.beams + 2 + if self.track_features { 2 } else { 0 }
    }

    /// [features, hidden..., 2].
    pub fn layers(&self) -> Vec<usize> {
        let mut l = vec![self.num_features()];
        l.extend(&self.hidden);
        l.push(2);
        l
    }

    /// Length of the parameter vector.
    pub fn num_params(&self) -> usize {
        self.layers().windows(2).map(|w| w[1] * (w[0] + 1)).sum()
    }

    /// Parameter specs: one per weight, named `w{l}[{out}][{in}]` / `b{l}[{out}]`, with
    /// the default init described in the module docs.
    pub fn param_specs(&self) -> Vec<ParamSpec> {
        let names = param_names(&self.layers());
        let init = self.default_weights();
        names
            .iter()
            .zip(init)
            .map(|(name, default)| {
                ParamSpec::new(name, default, -WEIGHT_BOUND, WEIGHT_BOUND, "MLP weight")
            })
            .collect()
    }

    /// The documented default init (see the module docs).
    pub fn default_weights(&self) -> Vec<f64> {
        let layers = self.layers();
        let mut w = vec![0.0; self.num_params()];
        let mut offset = 0;
        let last = layers.len() - 2;
        for l in 0..=last {
            let (n_in, n_out) = (layers[l], layers[l + 1]);
            let at = |o: usize, i: usize| offset + o * n_in + i;
            let bias = |o: usize| offset + n_out * n_in + o;
            if self.track_features && l == 0 && l < last {
                w[at(0, self.beams + 2)] = -0.6;
                w[at(0, self.beams + 3)] = -1.2;
            } else if self.track_features && l < last {
                w[at(0, 0)] = 1.0;
            }
            if l == last {
                if self.track_features && last > 0 {
                    w[at(0, 0)] = 2.0;
                }
                w[bias(1)] = libm::atanh(2.0 * 3.0 / 10.0 - 1.0);
            }
            offset += n_out * (n_in + 1);
        }
        w
    }
}

/// Leaked-once parameter names for a layer layout (ParamSpec names are `'static`).
fn param_names(layers: &[usize]) -> &'static [String] {
    static DEFAULT: OnceLock<Vec<String>> = OnceLock::new();
    let make = || {
        let mut names = Vec::new();
        for (l, w) in layers.windows(2).enumerate() {
            for o in 0..w[1] {
                for i in 0..w[0] {
                    names.push(format!("w{l}[{o}][{i}]"));
                }
            }
            for o in 0..w[1] {
                names.push(format!("b{l}[{o}]"));
            }
        }
        names
    };
    if layers == MlpConfig::default().layers() {
        DEFAULT.get_or_init(make)
    } else {
        // other layouts are rare (built once per tuning run); leaking them is bounded
        Box::leak(make().into_boxed_slice())
    }
}

/// Errors loading or saving a network file; each names the file and the field.
#[derive(Debug, thiserror::Error)]
pub enum MlpError {
    #[error("cannot read or write {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: not valid MLP JSON: {message}")]
    Json { path: PathBuf, message: String },
    #[error("{path}: field {field:?}: {message}")]
    Field {
        path: PathBuf,
        field: &'static str,
        message: String,
    },
}

/// The file layout.
#[derive(Debug, Serialize, Deserialize)]
struct MlpFile {
    layers: Option<Vec<usize>>,
    weights: Option<Vec<f64>>,
    #[serde(default)]
    beams: Option<usize>,
    #[serde(default)]
    track_features: Option<bool>,
    #[serde(default)]
    speed_max: Option<f64>,
}

/// The network: a config and its flat weights.
#[derive(Debug, Clone, PartialEq)]
pub struct Mlp {
    pub config: MlpConfig,
    layers: Vec<usize>,
    weights: Vec<f64>,
}

impl Mlp {
    /// A network from a flat weight vector (layout in the module docs).
    pub fn from_vector(config: &MlpConfig, weights: &[f64]) -> Result<Self, PolicyError> {
        let invalid = |message: String| PolicyError::Invalid {
            driver: NAME.into(),
            message,
        };
        if config.hidden.contains(&0) {
            return Err(invalid(format!(
                "hidden = {:?}: a layer needs at least one unit",
                config.hidden
            )));
        }
        if !(config.speed_max.is_finite() && config.speed_max > 0.0) {
            return Err(invalid(format!(
                "speed_max = {} must be a positive number",
                config.speed_max
            )));
        }
        if weights.len() != config.num_params() {
            return Err(PolicyError::ParamCount {
                driver: NAME.into(),
                expected: config.num_params(),
                got: weights.len(),
            });
        }
        if let Some(i) = weights.iter().position(|w| !w.is_finite()) {
            return Err(invalid(format!(
                "weight {} = {} is not finite",
                param_names(&config.layers())[i],
                weights[i]
            )));
        }
        Ok(Self {
            config: config.clone(),
            layers: config.layers(),
            weights: weights.to_vec(),
        })
    }

    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    pub fn layers(&self) -> &[usize] {
        &self.layers
    }

    /// Raw outputs [o_steer, o_speed] for a feature vector.
    pub fn forward(&self, features: &[f64]) -> [f64; 2] {
        let mut x: Vec<f64> = features.to_vec();
        let mut offset = 0;
        let last = self.layers.len() - 2;
        for l in 0..=last {
            let (n_in, n_out) = (self.layers[l], self.layers[l + 1]);
            let w = &self.weights[offset..offset + n_out * n_in];
            let b = &self.weights[offset + n_out * n_in..offset + n_out * (n_in + 1)];
            let y: Vec<f64> = (0..n_out)
                .map(|o| {
                    let z = b[o]
                        + w[o * n_in..(o + 1) * n_in]
                            .iter()
                            .zip(&x)
                            .map(|(a, b)| a * b)
                            .sum::<f64>();
                    if l < last { libm::tanh(z) } else { z }
                })
                .collect();
            x = y;
            offset += n_out * (n_in + 1);
        }
        [x[0], x[1]]
    }

    /// Read a network from a JSON file.
    pub fn load(path: &Path) -> Result<Self, MlpError> {
        let text = std::fs::read_to_string(path).map_err(|source| MlpError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_json(&text, path)
    }

    /// Parse a network from JSON text; `path` only names the source in errors.
    pub fn from_json(text: &str, path: &Path) -> Result<Self, MlpError> {
        let field = |field: &'static str, message: String| MlpError::Field {
            path: path.to_path_buf(),
            field,
            message,
        };
        let file: MlpFile = serde_json::from_str(text).map_err(|e| MlpError::Json {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let layers = file
            .layers
            .ok_or_else(|| field("layers", "missing".into()))?;
        let weights = file
            .weights
            .ok_or_else(|| field("weights", "missing".into()))?;
        let defaults = MlpConfig::default();
        let beams = file.beams.unwrap_or(defaults.beams);
        let track_features = file.track_features.unwrap_or(defaults.track_features);
        let speed_max = file.speed_max.unwrap_or(defaults.speed_max);
        if layers.len() < 2 {
            return Err(field(
                "layers",
                format!("{layers:?}: needs at least an input and an output size"),
            ));
        }
        let config = MlpConfig {
            beams,
            track_features,
            hidden: layers[1..layers.len() - 1].to_vec(),
            speed_max,
        };
        if layers[0] != config.num_features() {
            return Err(field(
                "layers",
                format!(
                    "input size {} does not match the {} features of beams = {beams}, track_features = {track_features}",
                    layers[0],
                    config.num_features()
                ),
            ));
        }
        if layers[layers.len() - 1] != 2 {
            return Err(field(
                "layers",
                format!(
                    "output size {} must be 2 (steer, speed)",
                    layers[layers.len() - 1]
                ),
            ));
        }
        if layers.contains(&0) {
            return Err(field("layers", format!("{layers:?}: a layer of size 0")));
        }
        if !(speed_max.is_finite() && speed_max > 0.0) {
            return Err(field("speed_max", format!("{speed_max} must be > 0")));
        }
        if weights.len() != config.num_params() {
            return Err(field(
                "weights",
                format!(
                    "{} values, layers {layers:?} need {}",
                    weights.len(),
                    config.num_params()
                ),
            ));
        }
        Mlp::from_vector(&config, &weights).map_err(|e| field("weights", e.to_string()))
    }

    /// The JSON text of this network.
    pub fn to_json(&self) -> String {
        let file = MlpFile {
            layers: Some(self.layers.clone()),
            weights: Some(self.weights.clone()),
            beams: Some(self.config.beams),
            track_features: Some(self.config.track_features),
            speed_max: Some(self.config.speed_max),
        };
        serde_json::to_string(&file).expect("plain numbers serialise")
    }

    /// Write the network as JSON (f64 values round-trip exactly).
    pub fn save(&self, path: &Path) -> Result<(), MlpError> {
        std::fs::write(path, self.to_json()).map_err(|source| MlpError::Io {
            path: path.to_path_buf(),
            source,
        })
    }
}

/// The driver: features from the observation, the network, the squashing.
#[derive(Debug, Clone)]
pub struct MlpDriver {
    pub mlp: Mlp,
    path: Option<Arc<RefPath>>,
    hint: Option<usize>,
    steer_max: f64,
    v_top: f64,
    v_max: f64,
    max_range: f64,
    features: Vec<f64>,
}

impl MlpDriver {
    /// The track features are measured against the circuit's driving line.
    pub fn new(mlp: Mlp, circuit: &Circuit, vehicle: &VehicleParams) -> Self {
        let path = mlp
            .config
            .track_features
            .then(|| Arc::new(RefPath::from_circuit(circuit).smoothed(ROUNDING_PASSES)));
        Self {
            steer_max: vehicle.s_max.min(-vehicle.s_min),
            v_top: mlp.config.speed_max.min(vehicle.v_max),
            v_max: vehicle.v_max,
            max_range: LidarConfig::default().max_range,
            mlp,
            path,
            hint: None,
            features: Vec::new(),
        }
    }

    /// The feature vector of agent `me` (see the module docs).
    pub fn features(&mut self, obs: &Observation, me: usize) -> &[f64] {
        let c = &self.mlp.config;
        self.features.clear();
        if c.beams > 0 {
            let scan: &[f64] = if obs.num_beams > 0 { obs.scan(me) } else { &[] };
            let n = scan.len();
            for k in 0..c.beams {
                let (a, b) = (
                    k * n / c.beams,
                    ((k + 1) * n / c.beams).max(k * n / c.beams + 1),
                );
                let m = scan
                    .get(a..b.min(n))
                    .unwrap_or(&[])
                    .iter()
                    .fold(self.max_range, |m, &r| m.min(r));
                self.features.push((m / self.max_range).clamp(0.0, 1.0));
            }
        }
        self.features.push(obs.linear_vels_x[me] / self.v_max);
        self.features
            .push(obs.steering_angles[me] / self.steer_max.max(1e-9));
        if let Some(path) = &self.path {
            let f = path.project(obs.poses_x[me], obs.poses_y[me], self.hint);
            self.hint = Some(f.index);
            self.features.push(f.d.clamp(-3.0, 3.0));
            self.features.push(wrap_angle(obs.poses_theta[me] - f.psi));
        }
        &self.features
    }
}

impl Driver for MlpDriver {
    fn name(&self) -> &'static str {
        NAME
    }

    fn sensors(&self) -> Sensors {
        Sensors {
            lidar: self.mlp.config.beams > 0,
        }
    }

    fn reset(&mut self) {
        self.hint = None;
    }

    fn act(&mut self, obs: &Observation, me: usize) -> Action {
        self.features(obs, me);
        let [o_steer, o_speed] = self.mlp.forward(&self.features);
        Action::new(
            self.steer_max * libm::tanh(o_steer),
            self.v_top * 0.5 * (libm::tanh(o_speed) + 1.0),
        )
    }
}

/// The registry's parameter specs: the default architecture.
pub fn param_specs() -> Vec<ParamSpec> {
    MlpConfig::default().param_specs()
}
