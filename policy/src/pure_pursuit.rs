//! Pure pursuit on a raceline with a curvature-based speed profile.
//!
//! Steering: aim at the path point one lookahead distance ahead, where the lookahead is
//! `lookahead_min` plus `lookahead_gain` times the speed, and steer the circle through it:
//! delta = `steer_gain` * atan(L * 2 y / d^2). Speed: a profile computed once from the
//! path's own curvature, v = sqrt(`lat_accel` / |kappa|) capped at `max_speed`, then a
//! backward pass so the car can brake from each speed to the next at `brake_decel`; the
//! command is the profile a short preview ahead of the car, times `speed_scale`. The path
//! is the track's raceline, or its centerline when it has none. Farther than 0.2 m from
//! the path the speed command drops (divided by 1 + excess metres) and the lookahead grows by twice the distance, so a car that
//! starts off the line joins it without overshooting. Needs no LIDAR.

use paddock_sim::circuit::Circuit;
use paddock_sim::geometry::Pose;
use paddock_sim::params::VehicleParams;
use paddock_sim::track::Track;
use paddock_sim::world::{Action, Observation};
use serde::{Deserialize, Serialize};

use crate::refpath::{RefPath, speed_profile};
use crate::{Driver, ParamSpec, Sensors, default_values};

pub const NAME: &str = "pure-pursuit";

/// Distance from the path (m) tolerated at full speed.
const OFF_PATH_DEADBAND: f64 = 0.2;
/// Speed divisor growth per metre beyond the deadband.
const OFF_PATH_SLOWDOWN: f64 = 1.0;
/// Extra lookahead per metre of distance from the path.
const OFF_PATH_REACH: f64 = 2.0;
pub const ABOUT: &str = "pure pursuit on the raceline with a curvature-based speed profile";

/// The tunable parameters, in vector order.
pub fn param_specs() -> Vec<ParamSpec> {
    vec![
        ParamSpec::new(
            "lookahead_min",
            0.6,
            0.3,
            3.0,
            "lookahead distance at standstill, m",
        ),
        ParamSpec::new(
            "lookahead_gain",
            0.1,
            0.0,
            0.6,
            "lookahead growth with speed, s (lookahead = min + gain * v)",
        ),
        ParamSpec::new(
            "lat_accel",
            2.5,
            1.0,
            15.0,
            "lateral acceleration the speed profile allows, m/s^2",
        ),
        ParamSpec::new(
            "brake_decel",
            5.0,
            1.0,
            15.0,
            "deceleration the speed profile plans with, m/s^2",
        ),
        ParamSpec::new("max_speed", 5.0, 1.0, 20.0, "speed cap, m/s"),
        ParamSpec::new("speed_scale", 1.0, 0.2, 1.5, "multiplies the speed profile"),
        ParamSpec::new(
            "steer_gain",
            1.0,
            0.5,
            2.0,
            "multiplies the pure-pursuit steering angle",
        ),
    ]
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PurePursuitParams {
    pub lookahead_min: f64,
    pub lookahead_gain: f64,
    pub lat_accel: f64,
    pub brake_decel: f64,
    pub max_speed: f64,
    pub speed_scale: f64,
    pub steer_gain: f64,
    /// Wheelbase used by the steering law, m (lf + lr of the car; not tuned).
    pub wheelbase: f64,
}

impl Default for PurePursuitParams {
    fn default() -> Self {
        Self::from_vector(&default_values(&param_specs()), &VehicleParams::default())
    }
}

impl PurePursuitParams {
    /// From a vector in [`param_specs`] order (validated by the caller).
    pub fn from_vector(v: &[f64], vehicle: &VehicleParams) -> Self {
        Self {
            lookahead_min: v[0],
            lookahead_gain: v[1],
            lat_accel: v[2],
            brake_decel: v[3],
            max_speed: v[4],
            speed_scale: v[5],
            steer_gain: v[6],
            wheelbase: vehicle.lf + vehicle.lr,
        }
    }

    pub fn to_vector(&self) -> Vec<f64> {
        vec![
            self.lookahead_min,
            self.lookahead_gain,
            self.lat_accel,
            self.brake_decel,
            self.max_speed,
            self.speed_scale,
            self.steer_gain,
        ]
    }
}

#[derive(Debug, Clone)]
pub struct PurePursuit {
    pub params: PurePursuitParams,
    path: RefPath,
    /// Planned speed at each path point.
    profile: Vec<f64>,
    hint: Option<usize>,
}

impl PurePursuit {
    /// Follow the circuit's driving line (its raceline where that keeps clear of the
    /// walls, else a line computed inside the map's free space).
    pub fn on_circuit(circuit: &Circuit, params: PurePursuitParams) -> Self {
        Self::on_path(RefPath::from_circuit(circuit), params)
    }

    /// Follow the track's raceline, or its centerline if it has none.
    pub fn new(track: &Track, params: PurePursuitParams) -> Self {
        Self::on_path(RefPath::from_track(track), params)
    }

    /// Follow `path` with its own speed profile from the driver's parameters.
    pub fn on_path(path: RefPath, params: PurePursuitParams) -> Self {
        let profile = speed_profile(
            path.kappa(),
            path.cum(),
            params.lat_accel,
            params.brake_decel,
            params.max_speed,
        );
        Self {
            params,
            path,
            profile,
            hint: None,
        }
    }

    /// The planned speed at each path point (before `speed_scale`).
    pub fn profile(&self) -> &[f64] {
        &self.profile
    }

    /// The action for a car at `pose` moving at `speed` (m/s).
    pub fn act_pose(&mut self, pose: Pose, speed: f64) -> Action {
        let path = &self.path;
        let i = path.nearest(pose.x, pose.y, self.hint);
        self.hint = Some(i);
        let p = &self.params;
        let lookahead = p.lookahead_min + p.lookahead_gain * speed.max(0.0);
        // off the path, aim farther along it, so the car joins it at a shallow angle
        let off_path = libm::sqrt(path.d2(i, pose.x, pose.y));
        let j = path.ahead(i, lookahead + OFF_PATH_REACH * off_path);
        let (tx, ty) = path.point(j);
        let (dx, dy) = (tx - pose.x, ty - pose.y);
        let (s, c) = libm::sincos(pose.theta);
        let local_y = -s * dx + c * dy;
        let dist2 = (dx * dx + dy * dy).max(1e-6);
        let curvature = 2.0 * local_y / dist2;
        let steer = p.steer_gain * libm::atan(p.wheelbase * curvature);
        // look a little ahead for the speed: the car needs time to slow down
        let k = path.ahead(i, 0.25 * speed.max(0.0));
        // far from the path (a start off the line, a slide) the car closes in slowly:
        // converging at full speed overshoots into the far wall
        let off = (off_path - OFF_PATH_DEADBAND).max(0.0);
        let speed_cmd = self.profile[k] * p.speed_scale / (1.0 + OFF_PATH_SLOWDOWN * off);
        Action::new(steer, speed_cmd)
    }
}

impl Driver for PurePursuit {
    fn name(&self) -> &'static str {
        NAME
    }

    fn sensors(&self) -> Sensors {
        Sensors { lidar: false }
    }

    fn reset(&mut self) {
        self.hint = None;
    }

    fn act(&mut self, obs: &Observation, me: usize) -> Action {
        let pose = Pose::new(obs.poses_x[me], obs.poses_y[me], obs.poses_theta[me]);
        self.act_pose(pose, obs.linear_vels_x[me])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use paddock_sim::track::CenterPoint;

    fn circle(r: f64) -> Track {
        let pts = (0..400)
            .map(|i| {
                let a = std::f64::consts::TAU * i as f64 / 400.0;
                CenterPoint {
                    x: r * a.cos(),
                    y: r * a.sin(),
                    w_right: 1.0,
                    w_left: 1.0,
                }
            })
            .collect();
        Track::new(pts, None).unwrap()
    }

    #[test]
    fn profile_follows_curvature() {
        let params = PurePursuitParams {
            max_speed: 20.0,
            ..PurePursuitParams::default()
        };
        let pp = PurePursuit::new(&circle(10.0), params);
        // v = sqrt(a / kappa) = sqrt(2.5 * 10)
        for v in pp.profile() {
            assert!((v - 25f64.sqrt()).abs() < 0.05, "{v}");
        }
        // the cap applies
        let capped = PurePursuitParams {
            max_speed: 3.0,
            ..PurePursuitParams::default()
        };
        let pp = PurePursuit::new(&circle(10.0), capped);
        assert!(pp.profile().iter().all(|&v| v == 3.0));
    }

    #[test]
    fn steers_left_on_a_ccw_circle() {
        let mut pp = PurePursuit::new(&circle(10.0), PurePursuitParams::default());
        let a = pp.act_pose(Pose::new(10.0, 0.0, std::f64::consts::FRAC_PI_2), 3.0);
        let expected = (0.33f64 / 10.0).atan();
        assert!(
            a.steer > 0.5 * expected && a.steer < 2.0 * expected,
            "{a:?}"
        );
        assert!(a.speed > 4.0);
    }

    #[test]
    fn vector_round_trip() {
        let p = PurePursuitParams::default();
        let v = p.to_vector();
        assert_eq!(v.len(), param_specs().len());
        assert_eq!(
            PurePursuitParams::from_vector(&v, &VehicleParams::default()),
            p
        );
    }
}
