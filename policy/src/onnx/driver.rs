//! The driver that runs an [`OnnxPolicy`] for one car.

use std::sync::Arc;

use paddock_sim::params::VehicleParams;
use paddock_sim::world::{Action, Observation};

#[cfg(doc)]
use super::NAME;
use super::OnnxPolicy;

use crate::{Driver, Sensors};

/// One car's ONNX driver: a shared plan plus this car's limits and memory (the previous
/// action, the action-repeat countdown, a fault).
///
/// A non-finite network output, or an inference error, latches a fault: from then on the
/// driver returns the stop action (steering 0, speed 0) and [`Driver::fault`] says why,
/// until [`Driver::reset`].
#[derive(Debug)]
pub struct OnnxDriver {
    name: &'static str,
    policy: Arc<OnnxPolicy>,
    steer: (f64, f64),
    speed: (f64, f64),
    prev: Action,
    hold: u32,
    fault: Option<String>,
}

impl OnnxDriver {
    /// A driver called `name` (the registered `onnx:<sha256>`, or [`NAME`]).
    pub fn new(name: &'static str, policy: Arc<OnnxPolicy>, vehicle: &VehicleParams) -> Self {
        Self {
            name,
            policy,
            steer: (vehicle.s_min, vehicle.s_max),
            speed: (vehicle.v_min, vehicle.v_max),
            prev: Action::default(),
            hold: 0,
            fault: None,
        }
    }

    pub fn policy(&self) -> &Arc<OnnxPolicy> {
        &self.policy
    }

    /// The stop action a faulted driver returns.
    pub const STOP: Action = Action::new(0.0, 0.0);
}

impl Driver for OnnxDriver {
    fn name(&self) -> &'static str {
        self.name
    }

    fn sensors(&self) -> Sensors {
        Sensors {
            lidar: self.policy.beams().is_some(),
        }
    }

    fn reset(&mut self) {
        self.prev = Action::default();
        self.hold = 0;
        self.fault = None;
    }

    fn act(&mut self, obs: &Observation, me: usize) -> Action {
        if self.fault.is_some() {
            return Self::STOP;
        }
        if self.hold > 0 {
            self.hold -= 1;
            return self.prev;
        }
        let raw = self
            .policy
            .infer(obs, me, [self.prev.steer, self.prev.speed]);
        match raw {
            Ok([steer, speed]) if steer.is_finite() && speed.is_finite() => {
                let a = Action::new(
                    f64::from(steer).clamp(self.steer.0, self.steer.1),
                    f64::from(speed).clamp(self.speed.0, self.speed.1),
                );
                self.prev = a;
                self.hold = self.policy.action_repeat() - 1;
                a
            }
            Ok([steer, speed]) => {
                self.fault = Some(format!(
                    "model {}: non-finite action (steering {steer}, speed {speed})",
                    self.policy.label()
                ));
                Self::STOP
            }
            Err(e) => {
                self.fault = Some(e.to_string());
                Self::STOP
            }
        }
    }

    fn fault(&self) -> Option<&str> {
        self.fault.as_deref()
    }
}
