//! # paddock-policy: drivers
//!
//! A driver turns one car's view of the world into an action. Drivers are pure apart from
//! their own small memory (search hints, planner state), reset at every episode, so a
//! rollout stays a pure function of its scenario and seed.
//!
//! Every driver has a name, documented parameters with defaults and bounds (a
//! [`ParamSpec`] list: the vector CMA-ES tunes), and declares the sensors it needs, so a
//! rollout whose drivers do not read the LIDAR skips the scan.
//!
//! Besides the built-in drivers, a trained network exported to ONNX drives through
//! [`onnx::OnnxDriver`]; a [`DriverSpec`] names either kind (docs/onnx.md has the
//! observation contract).

pub mod follow_gap;
pub mod lattice;
pub mod mlp;
pub mod onnx;
pub mod perception;
pub mod pure_pursuit;
pub mod refpath;
pub mod rrt_star;
pub mod spec;
pub mod tracker;

use std::sync::Arc;

use paddock_sim::circuit::Circuit;
use paddock_sim::params::VehicleParams;
use paddock_sim::world::{Action, Observation};
use serde::{Deserialize, Serialize};

pub use follow_gap::{FollowTheGap, FollowTheGapParams};
pub use lattice::{Lattice, LatticeParams};
pub use mlp::{Mlp, MlpConfig, MlpDriver};
pub use pure_pursuit::{PurePursuit, PurePursuitParams};
pub use rrt_star::{RrtStar, RrtStarParams};
pub use spec::{DriverSpec, OnnxModel, is_model_path};

use paddock_sim::lidar::LidarConfig;

/// Errors building a driver; each names the driver, the parameter and the value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PolicyError {
    #[error("unknown driver {name:?} (known: {known})")]
    UnknownDriver { name: String, known: String },
    #[error("driver {driver}: expected {expected} parameters, got {got}")]
    ParamCount {
        driver: String,
        expected: usize,
        got: usize,
    },
    #[error("driver {driver}: unknown parameter {name:?} (known: {known})")]
    UnknownParam {
        driver: String,
        name: String,
        known: String,
    },
    #[error("driver {driver}: parameter {name} = {value} is outside [{lo}, {hi}]")]
    OutOfBounds {
        driver: String,
        name: String,
        value: f64,
        lo: f64,
        hi: f64,
    },
    #[error("driver {driver}: {message}")]
    Invalid { driver: String, message: String },
    #[error(transparent)]
    Onnx(#[from] onnx::OnnxError),
}

/// One tunable parameter of a driver.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ParamSpec {
    pub name: &'static str,
    pub default: f64,
    pub lo: f64,
    pub hi: f64,
    pub doc: &'static str,
}

impl ParamSpec {
    pub const fn new(
        name: &'static str,
        default: f64,
        lo: f64,
        hi: f64,
        doc: &'static str,
    ) -> Self {
        Self {
            name,
            default,
            lo,
            hi,
            doc,
        }
    }
}

/// The sensors a driver reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Sensors {
    pub lidar: bool,
}

/// A driver: observation -> action for agent `me`.
///
/// `obs` is the whole world's observation (every car's pose and speed, so planners can
/// see their opponents); a driver whose [`Sensors`] omit the LIDAR must not read the scans
/// (they are zeros then).
pub trait Driver: Send {
    /// The registry name (`pure-pursuit`, ...).
    fn name(&self) -> &'static str;
    fn sensors(&self) -> Sensors;
    /// Forget per-episode memory.
    fn reset(&mut self);
    fn act(&mut self, obs: &Observation, me: usize) -> Action;
    /// Why the driver can no longer drive (an ONNX model gave a non-finite action), if it
    /// cannot. A faulted driver returns a stop action; callers end the car's episode as a
    /// crash (rollouts) or keep it stopped (the bridge). Cleared by [`Driver::reset`].
    fn fault(&self) -> Option<&str> {
        None
    }
}

/// Validate `values` against `specs`: count, finiteness and bounds, naming the offender.
pub fn check_params(driver: &str, specs: &[ParamSpec], values: &[f64]) -> Result<(), PolicyError> {
    if values.len() != specs.len() {
        return Err(PolicyError::ParamCount {
            driver: driver.into(),
            expected: specs.len(),
            got: values.len(),
        });
    }
    for (s, &v) in specs.iter().zip(values) {
        if !(v.is_finite() && v >= s.lo && v <= s.hi) {
            return Err(PolicyError::OutOfBounds {
                driver: driver.into(),
                name: s.name.into(),
                value: v,
                lo: s.lo,
                hi: s.hi,
            });
        }
    }
    Ok(())
}

/// The default of every parameter in `specs`, in order.
pub fn default_values(specs: &[ParamSpec]) -> Vec<f64> {
    specs.iter().map(|s| s.default).collect()
}

/// A count parameter (tuned as a real number): rounded, at least 1.
fn rounded_count(x: f64) -> usize {
    libm::round(x).max(1.0) as usize
}

/// Defaults of `specs` with the named overrides applied (`name=value` pairs).
pub fn params_from_overrides(
    driver: &str,
    specs: &[ParamSpec],
    overrides: &[(String, f64)],
) -> Result<Vec<f64>, PolicyError> {
    let mut v = default_values(specs);
    for (name, value) in overrides {
        let Some(i) = specs.iter().position(|s| s.name == name) else {
            return Err(PolicyError::UnknownParam {
                driver: driver.into(),
                name: name.clone(),
                known: specs.iter().map(|s| s.name).collect::<Vec<_>>().join(", "),
            });
        };
        v[i] = *value;
    }
    check_params(driver, specs, &v)?;
    Ok(v)
}

/// What the registry knows of a driver without building one.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DriverInfo {
    pub name: &'static str,
    pub about: &'static str,
    pub sensors: Sensors,
    pub params: Vec<ParamSpec>,
}

/// Every driver the registry can build.
pub fn drivers() -> Vec<DriverInfo> {
    vec![
        DriverInfo {
            name: pure_pursuit::NAME,
            about: pure_pursuit::ABOUT,
            sensors: Sensors { lidar: false },
            params: pure_pursuit::param_specs(),
        },
        DriverInfo {
            name: follow_gap::NAME,
            about: follow_gap::ABOUT,
            sensors: Sensors { lidar: true },
            params: follow_gap::param_specs(),
        },
        DriverInfo {
            name: mlp::NAME,
            about: mlp::ABOUT,
            sensors: Sensors { lidar: true },
            params: mlp::param_specs(),
        },
        DriverInfo {
            name: lattice::NAME,
            about: lattice::ABOUT,
            sensors: Sensors { lidar: true },
            params: lattice::param_specs(),
        },
        DriverInfo {
            name: rrt_star::NAME,
            about: rrt_star::ABOUT,
            sensors: Sensors { lidar: true },
            params: rrt_star::param_specs(),
        },
    ]
}

/// Look a driver up by name (a built-in, or a registered ONNX model's `onnx:<sha256>`).
pub fn driver_info(name: &str) -> Result<DriverInfo, PolicyError> {
    if onnx::is_model_name(name) {
        let (name, policy) = registered_model(name)?;
        return Ok(DriverInfo {
            name,
            about: onnx::ABOUT,
            sensors: Sensors {
                lidar: policy.beams().is_some(),
            },
            params: Vec::new(),
        });
    }
    drivers()
        .into_iter()
        .find(|d| d.name == name)
        .ok_or_else(|| PolicyError::UnknownDriver {
            name: name.into(),
            known: drivers()
                .iter()
                .map(|d| d.name)
                .collect::<Vec<_>>()
                .join(", "),
        })
}

/// Build driver `name` with the parameter vector `params` (in [`DriverInfo::params`]
/// order) for a car with `vehicle` parameters on `circuit`. A registered ONNX model's
/// name (`onnx:<sha256>`, [`onnx::register`]) builds an [`onnx::OnnxDriver`] on the
/// process's shared plan; it takes no parameters.
pub fn build_driver(
    name: &str,
    params: &[f64],
    circuit: &Arc<Circuit>,
    vehicle: &VehicleParams,
) -> Result<Box<dyn Driver>, PolicyError> {
    if onnx::is_model_name(name) {
        let (name, policy) = registered_model(name)?;
        check_params(name, &[], params)?;
        return Ok(Box::new(onnx::OnnxDriver::new(name, policy, vehicle)));
    }
    build_builtin(name, params, circuit, vehicle)
}

/// Check driver `name`'s sensor needs against the car's LIDAR: an ONNX model's scan
/// input must have the LIDAR's beam count (and field of view, when its metadata gives
/// one); built-in drivers take any LIDAR.
pub fn check_lidar(name: &str, lidar: &LidarConfig) -> Result<(), PolicyError> {
    if onnx::is_model_name(name) {
        registered_model(name)?.1.check_lidar(lidar)?;
    }
    Ok(())
}

fn registered_model(name: &str) -> Result<(&'static str, Arc<onnx::OnnxPolicy>), PolicyError> {
    onnx::registered(name).ok_or_else(|| PolicyError::UnknownDriver {
        name: name.into(),
        known: "the built-in drivers and the ONNX models registered with this process".into(),
    })
}

fn build_builtin(
    name: &str,
    params: &[f64],
    circuit: &Arc<Circuit>,
    vehicle: &VehicleParams,
) -> Result<Box<dyn Driver>, PolicyError> {
    let info = driver_info(name)?;
    check_params(name, &info.params, params)?;
    match info.name {
        pure_pursuit::NAME => Ok(Box::new(PurePursuit::on_circuit(
            circuit,
            PurePursuitParams::from_vector(params, vehicle),
        ))),
        follow_gap::NAME => Ok(Box::new(FollowTheGap::new(
            FollowTheGapParams::from_vector(params, vehicle)?,
        ))),
        mlp::NAME => Ok(Box::new(MlpDriver::new(
            Mlp::from_vector(&MlpConfig::default(), params)?,
            circuit,
            vehicle,
        ))),
        lattice::NAME => Ok(Box::new(Lattice::new(
            circuit,
            LatticeParams::from_vector(params, vehicle)?,
        ))),
        rrt_star::NAME => Ok(Box::new(RrtStar::new(
            circuit,
            RrtStarParams::from_vector(params, vehicle)?,
        ))),
        _ => unreachable!("every registered driver is built above"),
    }
}
