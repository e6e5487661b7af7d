//! Which driver the bridge runs: a `paddock tune` result, an ONNX model file or a
//! registry name, with parameter overrides.
//!
//! A model file is read, checked against the observation contract and optimised once
//! (registered with the process as `onnx:<sha256>`, as `paddock rollout` does), so the
//! bridge runs the very plan, and gives the very action bits, that a local rollout does.

use std::path::Path;
use std::sync::Arc;

use paddock_policy::{Driver, ParamSpec, build_driver, driver_info, is_model_path};
use paddock_sim::circuit::Circuit;
use paddock_sim::lidar::LidarConfig;
use paddock_sim::params::VehicleParams;

use crate::BridgeError;

/// Which driver with which parameters: a `paddock tune` result, an ONNX model or a
/// registry name.
#[derive(Debug, Clone, PartialEq)]
pub struct DriverSpec {
    /// The registry name (`onnx:<sha256>` for a model file).
    pub name: String,
    /// What the user gave: the name, or the file (tune result, model).
    pub source: String,
    /// In the driver's parameter order.
    pub params: Vec<f64>,
    /// The map a tune result was tuned on.
    pub map: Option<String>,
}

impl DriverSpec {
    /// `driver` is a `paddock tune` result.json (its `driver`, `params.tuned` and `map`
    /// fields; `policy` in results written before the rename) when it names an existing file, otherwise a driver name with its defaults;
    /// `overrides` (`name=value`) apply on top either way.
    ///
    /// A path ending in `.onnx` is an ONNX model: read, checked and registered with this
    /// process; it takes no parameters.
    pub fn resolve(driver: &str, overrides: &[(String, f64)]) -> Result<Self, BridgeError> {
        if is_model_path(driver) {
            let name = paddock_policy::DriverSpec::parse(driver)?.register()?;
            let params = paddock_policy::params_from_overrides(&name, &[], overrides)?;
            return Ok(Self {
                name,
                source: driver.to_string(),
                params,
                map: None,
            });
        }
        let path = Path::new(driver);
        if path.is_file() {
            return Self::from_tune_result(path, overrides);
        }
        if driver.ends_with(".json") {
            return Err(BridgeError::config(
                "--driver",
                driver,
                "no such file (give a paddock tune result.json or a driver name)",
            ));
        }
        let info = driver_info(driver)?;
        let params = paddock_policy::params_from_overrides(info.name, &info.params, overrides)?;
        Ok(Self {
            name: info.name.to_string(),
            source: driver.to_string(),
            params,
            map: None,
        })
    }

    fn from_tune_result(path: &Path, overrides: &[(String, f64)]) -> Result<Self, BridgeError> {
        let text = std::fs::read_to_string(path).map_err(|e| BridgeError::io(path, e))?;
        let bad = |message: String| BridgeError::format(path, message);
        let v: serde_json::Value =
            serde_json::from_str(&text).map_err(|e| bad(format!("not JSON: {e}")))?;
        let name = v["driver"]
            .as_str()
            .or_else(|| v["policy"].as_str())
            .ok_or_else(
                || bad("no string field \"driver\" (a paddock tune result.json?)".into()),
            )?;
        let info = driver_info(name)?;
        let tuned = v["params"]["tuned"]
            .as_object()
            .ok_or_else(|| bad("no object field \"params.tuned\"".into()))?;
        let mut named: Vec<(String, f64)> = Vec::with_capacity(tuned.len() + overrides.len());
        for (k, x) in tuned {
            let x = x
                .as_f64()
                .ok_or_else(|| bad(format!("params.tuned.{k} = {x} is not a number")))?;
            named.push((k.clone(), x));
        }
        for spec in &info.params {
            if !tuned.contains_key(spec.name) {
                return Err(bad(format!(
                    "params.tuned lacks parameter {:?} of driver {}",
                    spec.name, info.name
                )));
            }
        }
        named.extend_from_slice(overrides);
        let params = paddock_policy::params_from_overrides(info.name, &info.params, &named)?;
        Ok(Self {
            name: info.name.to_string(),
            source: path.display().to_string(),
            params,
            map: v["map"].as_str().map(str::to_string),
        })
    }

    pub fn param_specs(&self) -> Result<Vec<ParamSpec>, BridgeError> {
        Ok(driver_info(&self.name)?.params)
    }

    /// Check the driver against the LIDAR it will read: an ONNX model's scan input must
    /// have its beam count (and field of view, when the model's metadata gives one).
    pub fn check_lidar(&self, lidar: &LidarConfig) -> Result<(), BridgeError> {
        Ok(paddock_policy::check_lidar(&self.name, lidar)?)
    }

    pub fn build(
        &self,
        circuit: &Arc<Circuit>,
        vehicle: &VehicleParams,
    ) -> Result<Box<dyn Driver>, BridgeError> {
        Ok(build_driver(&self.name, &self.params, circuit, vehicle)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn policy_from_a_tune_result_and_by_name() {
        let dir = std::env::temp_dir().join(format!("paddock-bridge-spec-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let info = driver_info("pure-pursuit").unwrap();
        let mut tuned = serde_json::Map::new();
        for p in &info.params {
            tuned.insert(p.name.into(), serde_json::json!(0.5 * (p.lo + p.hi)));
        }
        let path = dir.join("result.json");
        let doc = serde_json::json!({"map": "quarry", "driver": "pure-pursuit",
            "params": {"default": {}, "tuned": tuned}});
        std::fs::write(&path, doc.to_string()).unwrap();
        let s = DriverSpec::resolve(path.to_str().unwrap(), &[]).unwrap();
        assert_eq!(s.name, "pure-pursuit");
        assert_eq!(s.map.as_deref(), Some("quarry"));
        assert_eq!(s.params[0], 0.5 * (info.params[0].lo + info.params[0].hi));
        let first = info.params[0].name.to_string();
        let s = DriverSpec::resolve(path.to_str().unwrap(), &[(first, info.params[0].lo)]).unwrap();
        assert_eq!(s.params[0], info.params[0].lo);
        // a missing parameter is named
        tuned.remove(info.params[1].name);
        let doc = serde_json::json!({"policy": "pure-pursuit", "params": {"tuned": tuned}});
        std::fs::write(&path, doc.to_string()).unwrap();
        let e = DriverSpec::resolve(path.to_str().unwrap(), &[])
            .unwrap_err()
            .to_string();
        assert!(e.contains(info.params[1].name), "{e}");
        let e = DriverSpec::resolve("no-such-driver", &[])
            .unwrap_err()
            .to_string();
        assert!(e.contains("no-such-driver"), "{e}");
        let e = DriverSpec::resolve("missing.json", &[])
            .unwrap_err()
            .to_string();
        assert!(e.contains("--driver") && e.contains("missing.json"), "{e}");
        let d = DriverSpec::resolve("pure-pursuit", &[]).unwrap();
        assert_eq!(d.params.len(), info.params.len());
        std::fs::remove_dir_all(&dir).ok();
    }
}
