//! The candidate effects: sim-core's optional model components, with their parameter
//! names (exactly the report's), the bounds the fit searches, and how a parameter vector
//! is written into [`VehicleParams`].

use paddock_sim::params::{
    Drag, FirstOrderLag, FrictionPatch, SpeedGain, SteeringBacklash, SteeringDelay, SteeringGain,
    SteeringOffset, TireSaturation, VehicleParams,
};
use serde_json::{Value, json};

use crate::SysidError;

/// One candidate effect.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum EffectKind {
    SteeringDelay,
    SteeringLag,
    SteeringOffset,
    DriveLag,
    Drag,
    Friction,
    FrictionPatch,
    TireSaturation,
    SteeringGain,
    SteeringBacklash,
    SpeedGain,
    /// Latency of the pose source: every measured state lags the truth. A property of
    /// the sensors, not of the car: it is reported, not written into the vehicle.
    MeasurementDelay,
}

/// Every candidate, in report order.
pub const ALL: [EffectKind; 12] = [
    EffectKind::SteeringDelay,
    EffectKind::SteeringLag,
    EffectKind::SteeringOffset,
    EffectKind::SteeringGain,
    EffectKind::SteeringBacklash,
    EffectKind::DriveLag,
    EffectKind::SpeedGain,
    EffectKind::Drag,
    EffectKind::Friction,
    EffectKind::FrictionPatch,
    EffectKind::TireSaturation,
    EffectKind::MeasurementDelay,
];

impl EffectKind {
    pub fn name(self) -> &'static str {
        match self {
            EffectKind::SteeringDelay => "steering_delay",
            EffectKind::SteeringLag => "steering_lag",
            EffectKind::SteeringOffset => "steering_offset",
            EffectKind::DriveLag => "drive_lag",
            EffectKind::Drag => "drag",
            EffectKind::Friction => "friction",
            EffectKind::FrictionPatch => "friction_patch",
            EffectKind::TireSaturation => "tire_saturation",
            EffectKind::SteeringGain => "steering_gain",
            EffectKind::SteeringBacklash => "steering_backlash",
            EffectKind::SpeedGain => "speed_gain",
            EffectKind::MeasurementDelay => "measurement_delay",
        }
    }

    pub fn from_name(name: &str) -> Result<Self, SysidError> {
        ALL.into_iter()
            .find(|k| k.name() == name)
            .ok_or_else(|| SysidError::Option {
                field: "effect".into(),
                value: name.into(),
                requirement: format!(
                    "one of {}",
                    ALL.iter().map(|k| k.name()).collect::<Vec<_>>().join(", ")
                ),
            })
    }

    /// Parameter names of the vector form (`friction_patch`: mu, then the region).
    pub fn param_names(self) -> &'static [&'static str] {
        match self {
            EffectKind::SteeringDelay | EffectKind::MeasurementDelay => &["delay_s"],
            EffectKind::SteeringGain | EffectKind::SpeedGain => &["gain"],
            EffectKind::SteeringBacklash => &["width_rad"],
            EffectKind::SteeringLag | EffectKind::DriveLag => &["tau_s"],
            EffectKind::SteeringOffset => &["offset_rad"],
            EffectKind::Drag => &["c_lin", "c_quad"],
            EffectKind::Friction => &["mu"],
            EffectKind::FrictionPatch => &["mu", "xmin", "ymin", "xmax", "ymax"],
            EffectKind::TireSaturation => &["D", "C", "E"],
        }
    }

    /// Number of parameters the evidence has to pay for.
    pub fn n_params(self) -> usize {
        self.param_names().len()
    }

    /// Search bounds of the physical parameters (the region's come from the recording).
    pub fn bounds(self) -> Vec<(f64, f64)> {
        match self {
            EffectKind::SteeringDelay => vec![(0.0, 0.25)],
            EffectKind::SteeringLag => vec![(0.0, 0.4)],
            EffectKind::SteeringOffset => vec![(-0.1, 0.1)],
            EffectKind::DriveLag => vec![(0.0, 1.0)],
            EffectKind::Drag => vec![(0.0, 1.5), (0.0, 0.3)],
            EffectKind::Friction => vec![(0.2, 2.0)],
            EffectKind::FrictionPatch => vec![(0.15, 2.0)],
            EffectKind::TireSaturation => vec![(0.2, 1.6), (0.9, 2.2), (-1.5, 0.9)],
            EffectKind::SteeringGain | EffectKind::SpeedGain => vec![(0.6, 1.4)],
            EffectKind::SteeringBacklash => vec![(0.0, 0.15)],
            EffectKind::MeasurementDelay => vec![(0.0, 0.25)],
        }
    }

    /// Where the fit starts (the effect switched "almost off").
    pub fn start(self, nominal: &VehicleParams) -> Vec<f64> {
        match self {
            EffectKind::SteeringDelay => vec![0.0],
            EffectKind::SteeringLag => vec![0.02],
            EffectKind::SteeringOffset => vec![0.0],
            EffectKind::DriveLag => vec![0.05],
            EffectKind::Drag => vec![0.05, 0.01],
            EffectKind::Friction | EffectKind::FrictionPatch => vec![nominal.mu],
            EffectKind::TireSaturation => vec![1.0, 1.5, 0.0],
            EffectKind::SteeringGain | EffectKind::SpeedGain => vec![1.0],
            EffectKind::SteeringBacklash => vec![0.005],
            EffectKind::MeasurementDelay => vec![0.005],
        }
    }

    /// Typical values, used by `synth` when a parameter is not given.
    pub fn typical(self) -> Vec<f64> {
        match self {
            EffectKind::SteeringDelay => vec![0.06],
            EffectKind::SteeringLag => vec![0.08],
            EffectKind::SteeringOffset => vec![0.02],
            EffectKind::DriveLag => vec![0.25],
            EffectKind::Drag => vec![0.15, 0.03],
            EffectKind::Friction => vec![0.7],
            EffectKind::FrictionPatch => vec![0.55, f64::NAN, f64::NAN, f64::NAN, f64::NAN],
            EffectKind::TireSaturation => vec![0.6, 1.6, 0.3],
            EffectKind::SteeringGain => vec![0.85],
            EffectKind::SteeringBacklash => vec![0.04],
            EffectKind::SpeedGain => vec![1.1],
            EffectKind::MeasurementDelay => vec![0.05],
        }
    }

    /// Whether a fitted value is too small for the car to feel (a tenth of a degree, 1 %,
    /// 5 ms): such a fit is not a finding, however it scores.
    pub fn negligible(self, v: &[f64]) -> bool {
        match self {
            EffectKind::SteeringGain | EffectKind::SpeedGain => (v[0] - 1.0).abs() < 0.01,
            EffectKind::SteeringBacklash => v[0] < 0.005,
            EffectKind::SteeringOffset => v[0].abs() < 0.002,
            EffectKind::SteeringDelay | EffectKind::SteeringLag | EffectKind::MeasurementDelay => {
                v[0] < 0.005
            }
            EffectKind::DriveLag => v[0] < 0.01,
            _ => false,
        }
    }

    /// Whether the effect lives in the vehicle (sim-core) rather than in the sensors.
    pub fn in_vehicle(self) -> bool {
        self != EffectKind::MeasurementDelay
    }

    /// Write the effect with parameter vector `v` into `p` (friction: the model's `mu`;
    /// `measurement_delay` is not the vehicle's and writes nothing).
    pub fn apply(self, p: &mut VehicleParams, v: &[f64]) {
        let fx = &mut p.effects;
        match self {
            EffectKind::SteeringDelay => fx.steering_delay = Some(SteeringDelay { delay_s: v[0] }),
            EffectKind::SteeringLag => fx.steering_lag = Some(FirstOrderLag { tau_s: v[0] }),
            EffectKind::SteeringOffset => {
                fx.steering_offset = Some(SteeringOffset { offset_rad: v[0] })
            }
            EffectKind::DriveLag => fx.drive_lag = Some(FirstOrderLag { tau_s: v[0] }),
            EffectKind::Drag => {
                fx.drag = Some(Drag {
                    c_lin: v[0],
                    c_quad: v[1],
                })
            }
            EffectKind::Friction => p.mu = v[0],
            EffectKind::FrictionPatch => {
                fx.friction_patch = Some(vec![FrictionPatch {
                    mu: v[0],
                    region: [v[1], v[2], v[3], v[4]],
                }])
            }
            EffectKind::TireSaturation => {
                fx.tire_saturation = Some(TireSaturation {
                    d: v[0],
                    c: v[1],
                    e: v[2],
                })
            }
            EffectKind::SteeringGain => fx.steering_gain = Some(SteeringGain { gain: v[0] }),
            EffectKind::SpeedGain => fx.speed_gain = Some(SpeedGain { gain: v[0] }),
            EffectKind::SteeringBacklash => {
                fx.steering_backlash = Some(SteeringBacklash { width_rad: v[0] })
            }
            EffectKind::MeasurementDelay => {}
        }
    }

    /// The parameters as the report writes them.
    pub fn params_json(self, v: &[f64]) -> Value {
        let r = |x: f64| (x * 1e5).round() / 1e5;
        match self {
            EffectKind::FrictionPatch => json!({
                "mu": r(v[0]),
                "region": [r(v[1]), r(v[2]), r(v[3]), r(v[4])],
            }),
            _ => {
                let mut m = serde_json::Map::new();
                for (n, x) in self.param_names().iter().zip(v) {
                    m.insert((*n).to_string(), json!(r(*x)));
                }
                Value::Object(m)
            }
        }
    }
}

/// Parse `NAME[:param=value,...]` (as `paddock sysid synth --effect` takes it). Missing
/// parameters take [`EffectKind::typical`]; a `friction_patch` without a region gets NaNs
/// there, for the caller to place.
pub fn parse_effect_spec(spec: &str) -> Result<(EffectKind, Vec<f64>), SysidError> {
    let (name, rest) = spec.split_once(':').unwrap_or((spec, ""));
    let kind = EffectKind::from_name(name.trim())?;
    let mut v = kind.typical();
    for kv in rest.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let (k, val) = kv.split_once('=').ok_or_else(|| SysidError::Option {
            field: format!("effect {}", kind.name()),
            value: kv.into(),
            requirement: "parameters are written name=value".into(),
        })?;
        let i = kind
            .param_names()
            .iter()
            .position(|n| *n == k.trim())
            .ok_or_else(|| SysidError::Option {
                field: format!("effect {}", kind.name()),
                value: k.into(),
                requirement: format!("parameters are {}", kind.param_names().join(", ")),
            })?;
        let x: f64 = val.trim().parse().map_err(|_| SysidError::Option {
            field: format!("{}.{}", kind.name(), k.trim()),
            value: val.into(),
            requirement: "a number".into(),
        })?;
        if !x.is_finite() {
            return Err(SysidError::Option {
                field: format!("{}.{}", kind.name(), k.trim()),
                value: val.into(),
                requirement: "a finite number".into(),
            });
        }
        v[i] = x;
    }
    Ok((kind, v))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_apply_validates() {
        let nominal = VehicleParams::default();
        for k in ALL {
            assert_eq!(EffectKind::from_name(k.name()).unwrap(), k);
            let mut p = nominal.clone();
            let mut v = k.typical();
            if k == EffectKind::FrictionPatch {
                v = vec![0.5, 0.0, 0.0, 1.0, 1.0];
            }
            k.apply(&mut p, &v);
            p.validate().unwrap();
            assert_eq!(p != nominal, k.in_vehicle(), "{}", k.name());
            assert_eq!(k.bounds().len(), k.start(&nominal).len());
        }
        assert!(EffectKind::from_name("wind").is_err());
    }

    #[test]
    fn effect_specs_parse() {
        let (k, v) = parse_effect_spec("drag:c_lin=0.2").unwrap();
        assert_eq!(k, EffectKind::Drag);
        assert_eq!(v, vec![0.2, 0.03]);
        assert!(parse_effect_spec("drag:c_cube=1").is_err());
        assert!(parse_effect_spec("drag:c_lin=x").is_err());
        assert!(parse_effect_spec("warp").is_err());
    }
}
