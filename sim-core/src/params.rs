//! Vehicle parameters: the f1tenth_gym single-track parameter set, the model options and
//! the optional model components ("effects") that the reference lacks.
//!
//! The YAML names are the reference's own (`mu`, `C_Sf`, `C_Sr`, `lf`, `lr`, `h`, `m`, `I`,
//! `s_min`, `s_max`, `sv_min`, `sv_max`, `v_switch`, `a_max`, `v_min`, `v_max`, `width`,
//! `length`), so a parameter dictionary from the reference drops straight in. Missing keys
//! take the reference defaults ([`VehicleParams::default`]); unknown keys are rejected,
//! because a misspelt key silently falling back to a default is the worst kind of sim-to-real
//! gap. Every loader validates.
//!
//! ```yaml
//! mu: 1.0489
//! m: 3.74
//! model: st            # st | ks
//! integrator: rk4      # rk4 | euler
//! effects:
//!   steering_delay: { delay_s: 0.04 }
//!   drag: { c_lin: 0.1, c_quad: 0.02 }
//!   friction_patch: [ { mu: 0.6, region: [0.0, -1.0, 5.0, 1.0] } ]
//!   tire_saturation: { D: 1.0, C: 1.3, E: 0.0 }
//!   steering_gain: { gain: 0.9 }
//!   speed_gain: { gain: 1.05 }
//!   steering_backlash: { width_rad: 0.03 }
//! ```

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

mod calibration;
pub use calibration::{SpeedGain, SteeringBacklash, SteeringGain};

/// Gravitational acceleration used by the reference model [m/s^2].
pub const GRAVITY: f64 = 9.81;

/// Longest accepted `steering_delay` [s].
pub const MAX_DELAY_S: f64 = 10.0;

/// Which right-hand side is integrated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VehicleModel {
    /// Dynamic single-track model with the reference's kinematic fallback at low speed.
    #[default]
    St,
    /// Kinematic single-track model at every speed (the fallback branch, always).
    Ks,
}

/// Time integrator of one step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Integrator {
    /// Classic fourth-order Runge-Kutta (the reference env's default).
    #[default]
    Rk4,
    /// Explicit Euler (the reference `RaceCar`'s own default).
    Euler,
}

/// Which equations the low-speed kinematic fallback uses (see [`crate::dynamics`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum KinematicBranch {
    /// f1tenth_gym `main`: rear-axle kinematic model, slip angle frozen.
    #[default]
    Main,
    /// f1tenth_gym `v1.0.0`: centre-of-gravity kinematic model (CommonRoad KS-CoG).
    V1,
}

/// Pure delay of the steering command, on top of the reference's 2-step buffer.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SteeringDelay {
    /// Extra delay [s]; rounded to whole steps: `round(delay_s / dt)`.
    pub delay_s: f64,
}

/// First-order lag with time constant `tau_s` [s] (0 = no lag).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FirstOrderLag {
    pub tau_s: f64,
}

/// Constant steering bias: wheel angle target = command + `offset_rad`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SteeringOffset {
    pub offset_rad: f64,
}

/// Longitudinal resistance: `dv/dt -= c_lin v + c_quad v |v|`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Drag {
    /// Linear (rolling / viscous) coefficient [1/s].
    pub c_lin: f64,
    /// Quadratic (aerodynamic) coefficient [1/m].
    pub c_quad: f64,
}

/// A box of the map with its own friction coefficient (one entry of the friction map).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrictionPatch {
    /// Friction coefficient inside the region (replaces `mu`).
    pub mu: f64,
    /// `[xmin, ymin, xmax, ymax]` in the map frame [m], bounds inclusive.
    pub region: [f64; 4],
}

impl FrictionPatch {
    /// Whether the point lies inside the region (bounds inclusive).
    #[inline]
    pub fn contains(&self, x: f64, y: f64) -> bool {
        let [xmin, ymin, xmax, ymax] = self.region;
        x >= xmin && x <= xmax && y >= ymin && y <= ymax
    }
}

/// Pacejka "magic formula" lateral tire, per axle:
/// `Fy = mu Fz D sin(C atan(B a - E (B a - atan(B a))))`, with `B = C_S / (C D)` so the
/// slope at zero slip equals the linear tire's `mu C_S`. `mu` scales the whole force, peak
/// and slope, as it scales the linear tire (a friction patch or a fitted `friction` lowers
/// both).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TireSaturation {
    /// Peak factor per unit of `mu`: the peak lateral force / normal load is `mu D`.
    #[serde(rename = "D")]
    pub d: f64,
    /// Shape factor.
    #[serde(rename = "C")]
    pub c: f64,
    /// Curvature factor (<= 1).
    #[serde(rename = "E")]
    pub e: f64,
}

/// Optional model components, all off by default. Written by the reality-gap tool.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Effects {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub steering_delay: Option<SteeringDelay>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub steering_lag: Option<FirstOrderLag>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub steering_offset: Option<SteeringOffset>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub drive_lag: Option<FirstOrderLag>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub drag: Option<Drag>,
    /// The friction map: the first patch containing the step-start position sets `mu`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub friction_patch: Option<Vec<FrictionPatch>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tire_saturation: Option<TireSaturation>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub steering_gain: Option<SteeringGain>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub speed_gain: Option<SpeedGain>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub steering_backlash: Option<SteeringBacklash>,
}

impl Effects {
    /// Whether every effect is off (the reference model).
    pub fn all_off(&self) -> bool {
        *self == Effects::default()
    }
}

/// Where the LIDAR sits on the car: position relative to the reference point
/// (`base_link`) [m], yaw [rad], and mounted upside down (its beams then sweep
/// clockwise), as the car's `base_link -> laser` transform says.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LaserMount {
    pub x: f64,
    pub y: f64,
    pub yaw: f64,
    pub flipped: bool,
}

/// One car's physical parameters and model options.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VehicleParams {
    /// Surface friction coefficient [-].
    pub mu: f64,
    /// Front cornering stiffness per unit load [1/rad].
    #[serde(rename = "C_Sf")]
    pub c_sf: f64,
    /// Rear cornering stiffness per unit load [1/rad].
    #[serde(rename = "C_Sr")]
    pub c_sr: f64,
    /// Centre of gravity to front axle [m].
    pub lf: f64,
    /// Centre of gravity to rear axle [m].
    pub lr: f64,
    /// Height of the centre of gravity [m].
    pub h: f64,
    /// Mass [kg].
    pub m: f64,
    /// Yaw moment of inertia [kg m^2].
    #[serde(rename = "I")]
    pub inertia: f64,
    /// Steering angle limits [rad].
    pub s_min: f64,
    pub s_max: f64,
    /// Steering velocity limits [rad/s].
    pub sv_min: f64,
    pub sv_max: f64,
    /// Speed above which the acceleration limit falls as `a_max v_switch / v` [m/s].
    pub v_switch: f64,
    /// Maximum longitudinal acceleration [m/s^2].
    pub a_max: f64,
    /// Speed limits [m/s] (`v_min` < 0: reverse).
    pub v_min: f64,
    pub v_max: f64,
    /// Body width and length [m] (collisions only).
    pub width: f64,
    pub length: f64,
    pub model: VehicleModel,
    pub integrator: Integrator,
    pub kinematic_branch: KinematicBranch,
    #[serde(skip_serializing_if = "Effects::all_off")]
    pub effects: Effects,
    /// The LIDAR's mount on this car (None: the world's `lidar.mount_offset`, straight
    /// ahead, as the reference simulator).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub laser_mount: Option<LaserMount>,
}

impl Default for VehicleParams {
    /// The f1tenth_gym environment defaults.
    fn default() -> Self {
        Self {
            mu: 1.0489,
            c_sf: 4.718,
            c_sr: 5.4562,
            lf: 0.15875,
            lr: 0.17145,
            h: 0.074,
            m: 3.74,
            inertia: 0.04712,
            s_min: -0.4189,
            s_max: 0.4189,
            sv_min: -3.2,
            sv_max: 3.2,
            v_switch: 7.319,
            a_max: 9.51,
            v_min: -5.0,
            v_max: 20.0,
            width: 0.31,
            length: 0.58,
            model: VehicleModel::St,
            integrator: Integrator::Rk4,
            kinematic_branch: KinematicBranch::Main,
            effects: Effects::default(),
            laser_mount: None,
        }
    }
}

/// Why a parameter set was rejected or could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ParamsError {
    #[error("vehicle parameter `{field}` = {value} is not a finite number")]
    NotFinite { field: String, value: f64 },
    #[error("vehicle parameter `{field}` = {value} is out of range: must be {requirement}")]
    OutOfRange {
        field: String,
        value: f64,
        requirement: String,
    },
    #[error("cannot read vehicle file {}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("invalid vehicle YAML{}: {message}", path.as_ref().map(|p| format!(" in {}", p.display())).unwrap_or_default())]
    Yaml {
        path: Option<PathBuf>,
        message: String,
    },
}

impl ParamsError {
    /// The offending field (dotted path, e.g. `effects.drag.c_lin`), if a value was rejected.
    pub fn field(&self) -> Option<&str> {
        match self {
            ParamsError::NotFinite { field, .. } | ParamsError::OutOfRange { field, .. } => {
                Some(field)
            }
            _ => None,
        }
    }
}

/// The accepted file shape when the parameters sit under a top-level `params:` key.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Wrapped {
    params: VehicleParams,
}

/// Probe: does the document have a top-level `params:` key?
#[derive(Deserialize)]
struct Probe {
    params: Option<serde::de::IgnoredAny>,
}

impl VehicleParams {
    /// Parse and validate a YAML document: either the parameters at the top level or nested
    /// under a single top-level `params:` key. An empty document gives the defaults.
    /// Several documents (separated by `---`) are layers: each one's keys replace the
    /// earlier ones' (a vehicle file followed by overrides).
    pub fn from_yaml_str(text: &str) -> Result<Self, ParamsError> {
        Self::parse(text, None)
    }

    /// Read, parse and validate a vehicle YAML file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ParamsError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|source| ParamsError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&text, Some(path))
    }

    /// The parameters as a YAML document (flat form; effects only when any is on).
    pub fn to_yaml_string(&self) -> String {
        // Serialising plain data with string keys cannot fail.
        serde_norway::to_string(self).expect("VehicleParams serialises to YAML")
    }

    fn parse(text: &str, path: Option<&Path>) -> Result<Self, ParamsError> {
        let yaml_err = |e: serde_norway::Error| ParamsError::Yaml {
            path: path.map(Path::to_path_buf),
            message: e.to_string(),
        };
        let has_content = text.lines().any(|l| {
            let l = l.trim();
            !l.is_empty() && !l.starts_with('#') && l != "---"
        });
        if !has_content {
            return Ok(Self::default());
        }
        if serde_norway::Deserializer::from_str(text).nth(1).is_some() {
            return Self::parse_layers(text, path);
        }
        let nested = serde_norway::from_str::<Probe>(text)
            .map(|p| p.params.is_some())
            .unwrap_or(false);
        let params = if nested {
            serde_norway::from_str::<Wrapped>(text)
                .map_err(yaml_err)?
                .params
        } else {
            serde_norway::from_str::<VehicleParams>(text).map_err(yaml_err)?
        };
        params.validate()?;
        Ok(params)
    }

    /// Several documents merged key by key, later ones winning (see [`Self::from_yaml_str`]).
    fn parse_layers(text: &str, path: Option<&Path>) -> Result<Self, ParamsError> {
        use serde_norway::Value;
        let yaml_err = |message: String| ParamsError::Yaml {
            path: path.map(Path::to_path_buf),
            message,
        };
        let mut merged = serde_norway::Mapping::new();
        for (i, doc) in serde_norway::Deserializer::from_str(text).enumerate() {
            let map = match Value::deserialize(doc).map_err(|e| yaml_err(e.to_string()))? {
                Value::Null => continue,
                Value::Mapping(m) => m,
                _ => return Err(yaml_err(format!("document {i} is not a mapping of keys"))),
            };
            let map = match map.get("params") {
                Some(Value::Mapping(inner)) if map.len() == 1 => inner.clone(),
                _ => map,
            };
            for (k, v) in map {
                merged.insert(k, v);
            }
        }
        let params: VehicleParams = serde_norway::from_value(Value::Mapping(merged))
            .map_err(|e| yaml_err(e.to_string()))?;
        params.validate()?;
        Ok(params)
    }

    /// Wheelbase `lf + lr` [m].
    #[inline]
    pub fn wheelbase(&self) -> f64 {
        self.lf + self.lr
    }

    /// Check every value; the error names the first offending field and its value.
    pub fn validate(&self) -> Result<(), ParamsError> {
        let positive = [
            ("mu", self.mu),
            ("C_Sf", self.c_sf),
            ("C_Sr", self.c_sr),
            ("lf", self.lf),
            ("lr", self.lr),
            ("m", self.m),
            ("I", self.inertia),
            ("sv_max", self.sv_max),
            ("v_switch", self.v_switch),
            ("a_max", self.a_max),
            ("v_max", self.v_max),
            ("width", self.width),
            ("length", self.length),
        ];
        for (field, value) in positive {
            check(field, value, value > 0.0, "> 0")?;
        }
        check("h", self.h, self.h >= 0.0, ">= 0")?;
        check("sv_min", self.sv_min, self.sv_min < 0.0, "< 0")?;
        check("v_min", self.v_min, self.v_min < 0.0, "< 0")?;
        check("s_min", self.s_min, true, "")?;
        check("s_max", self.s_max, true, "")?;
        let s_max = self.s_max;
        check(
            "s_min",
            self.s_min,
            self.s_min < s_max,
            &format!("< s_max = {s_max}"),
        )?;
        if let Some(m) = &self.laser_mount {
            check("laser_mount.x", m.x, m.x.abs() <= 5.0, "within +-5 m")?;
            check("laser_mount.y", m.y, m.y.abs() <= 5.0, "within +-5 m")?;
            check(
                "laser_mount.yaw",
                m.yaw,
                m.yaw.abs() <= 7.0,
                "within +-7 rad",
            )?;
        }
        self.effects.validate()
    }
}

impl Effects {
    /// Check every effect's parameters (field names are dotted paths under `effects`).
    pub fn validate(&self) -> Result<(), ParamsError> {
        if let Some(d) = &self.steering_delay {
            check(
                "effects.steering_delay.delay_s",
                d.delay_s,
                (0.0..=MAX_DELAY_S).contains(&d.delay_s),
                "in [0, 10] s",
            )?;
        }
        if let Some(l) = &self.steering_lag {
            check(
                "effects.steering_lag.tau_s",
                l.tau_s,
                l.tau_s >= 0.0,
                ">= 0",
            )?;
        }
        if let Some(o) = &self.steering_offset {
            check("effects.steering_offset.offset_rad", o.offset_rad, true, "")?;
        }
        if let Some(l) = &self.drive_lag {
            check("effects.drive_lag.tau_s", l.tau_s, l.tau_s >= 0.0, ">= 0")?;
        }
        if let Some(d) = &self.drag {
            check("effects.drag.c_lin", d.c_lin, d.c_lin >= 0.0, ">= 0")?;
            check("effects.drag.c_quad", d.c_quad, d.c_quad >= 0.0, ">= 0")?;
        }
        if let Some(patches) = &self.friction_patch {
            for (i, p) in patches.iter().enumerate() {
                check(
                    &format!("effects.friction_patch[{i}].mu"),
                    p.mu,
                    p.mu > 0.0,
                    "> 0",
                )?;
                for (k, v) in p.region.iter().enumerate() {
                    check(
                        &format!("effects.friction_patch[{i}].region[{k}]"),
                        *v,
                        true,
                        "",
                    )?;
                }
                let [xmin, ymin, xmax, ymax] = p.region;
                check(
                    &format!("effects.friction_patch[{i}].region[2]"),
                    xmax,
                    xmax >= xmin,
                    &format!(">= xmin = {xmin}"),
                )?;
                check(
                    &format!("effects.friction_patch[{i}].region[3]"),
                    ymax,
                    ymax >= ymin,
                    &format!(">= ymin = {ymin}"),
                )?;
            }
        }
        if let Some(t) = &self.tire_saturation {
            check("effects.tire_saturation.D", t.d, t.d > 0.0, "> 0")?;
            check("effects.tire_saturation.C", t.c, t.c > 0.0, "> 0")?;
            check("effects.tire_saturation.E", t.e, t.e <= 1.0, "<= 1")?;
        }
        calibration::validate(
            self.steering_gain.as_ref(),
            self.speed_gain.as_ref(),
            self.steering_backlash.as_ref(),
        )
    }
}

/// Finite and `ok`, else the matching error.
fn check(field: &str, value: f64, ok: bool, requirement: &str) -> Result<(), ParamsError> {
    if !value.is_finite() {
        return Err(ParamsError::NotFinite {
            field: field.to_string(),
            value,
        });
    }
    if !ok {
        return Err(ParamsError::OutOfRange {
            field: field.to_string(),
            value,
            requirement: requirement.to_string(),
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests;
