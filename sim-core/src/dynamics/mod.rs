//! Vehicle dynamics: the f1tenth_gym single-track car, step for step.
//!
//! [`Vehicle::step`] is the reference's `RaceCar.update_pose(steer, speed)`:
//!
//! 1. the steering command goes through a 2-step buffer (the command given at step k acts
//!    at step k+2; the first two steps use 0);
//! 2. P controllers turn the commands into inputs: bang-bang steering velocity
//!    (`±sv_max`, 0 within 1e-4 rad of the target) and `accl = kp (speed_cmd - v)` with the
//!    reference's direction-dependent gains;
//! 3. `u = [sv, accl]` is held over the step and integrated with RK4 (or Euler) over the
//!    dynamic single-track model ([`vehicle_dynamics_st`]); the input constraints
//!    (`steering_constraint`, `accl_constraints`) are re-applied at every RK stage state;
//! 4. the yaw is wrapped once into `[0, 2pi)` (`if yaw > 2pi: -2pi elif yaw < 0: +2pi`).
//!
//! With the default parameters the conformance vectors of f1tenth_gym `main` are reproduced
//! (see `tests/conformance_dynamics.rs`).
//!
//! ## The low-speed kinematic fallback: one deliberate departure
//!
//! The dynamic equations divide by `v`, so below 0.5 m/s the reference switches to a
//! kinematic model. `main` switches on `|v| < 0.5`, which leaves reverse driving faster than
//! 0.5 m/s on the dynamic equations with a negative speed; they are unstable there and the
//! yaw rate explodes within tenths of a second (upstream issue #53). `v1.0.0` switches on the
//! signed `v < 0.5`, which keeps reverse driving kinematic and stable. Paddock always uses
//! the signed test, so forward driving matches `main` exactly and reverse driving stays
//! bounded. [`KinematicBranch`](crate::params::KinematicBranch) then chooses the equations:
//! `main`'s rear-axle model (default) or `v1.0.0`'s centre-of-gravity model.
//!
//! ## Effects (all off by default)
//!
//! Command path, in this order, before the controllers: `steering_delay` (extra whole
//! steps, a zero-filled ring in front of the 2-step buffer), `steering_lag` and `drive_lag`
//! (first-order lags, `1 - exp(-dt/tau)` per step), `steering_gain` (scales the
//! steering target), `steering_offset` (added to it), `steering_backlash` (play between it
//! and the wheel's target); `speed_gain` scales the speed command before `drive_lag`. Inside the right-hand side: `drag` (subtracted from `v'`) and
//! `tire_saturation` (Pacejka axle forces instead of the linear tire; dynamic branch only).
//! `friction_patch` picks `mu` once per step from the step-start position.
//!
//! ## State
//!
//! [`VehicleState`] holds the reference state `[x, y, steer_angle, v, yaw, yaw_rate,
//! slip_angle]` by name; `x, y` is the centre of gravity in the dynamic branch (with the
//! `main` kinematic equations it moves as the rear axle would, as in the reference).

mod actuators;
mod model;

pub use actuators::{DelayLine, MAX_DELAY_STEPS, SteerBuffer, lag_gain, lag_update};
pub use model::{
    KINEMATIC_SPEED, STEER_DEAD_BAND, StateVec, acceleration_command, accl_constraints, integrate,
    lateral_forces, linear_st_yaw_slip, pacejka, steering_constraint, steering_velocity_command,
    vehicle_dynamics, vehicle_dynamics_ks, vehicle_dynamics_st, yaw_slip_from_forces,
};

use std::f64::consts::TAU;

use serde::{Deserialize, Serialize};

use crate::geometry::Pose;
use crate::params::VehicleParams;

/// The single-track state, in the reference's order
/// `[x, y, steer_angle, v, yaw, yaw_rate, slip_angle]` (see [`VehicleState::to_array`]).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct VehicleState {
    /// Position [m] (map frame).
    pub x: f64,
    pub y: f64,
    /// Front wheel angle [rad].
    pub steer_angle: f64,
    /// Speed along the velocity direction [m/s] (negative: reverse).
    pub v: f64,
    /// Heading [rad], kept in `[0, 2pi)` by one wrap per step.
    pub yaw: f64,
    /// [rad/s].
    pub yaw_rate: f64,
    /// Angle between heading and velocity at the centre of gravity [rad].
    pub slip_angle: f64,
}

impl VehicleState {
    /// At rest at `pose`.
    pub fn at_rest(pose: Pose) -> Self {
        Self {
            x: pose.x,
            y: pose.y,
            yaw: pose.theta,
            ..Self::default()
        }
    }

    /// The reference state vector.
    #[inline]
    pub fn to_array(&self) -> StateVec {
        [
            self.x,
            self.y,
            self.steer_angle,
            self.v,
            self.yaw,
            self.yaw_rate,
            self.slip_angle,
        ]
    }

    /// From the reference state vector.
    #[inline]
    pub fn from_array(s: StateVec) -> Self {
        Self {
            x: s[0],
            y: s[1],
            steer_angle: s[2],
            v: s[3],
            yaw: s[4],
            yaw_rate: s[5],
            slip_angle: s[6],
        }
    }
}

/// One car's complete dynamic state: the single-track state plus every memory of the
/// command path (steering buffer, delay line, lag states). Cloning it is a snapshot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Vehicle {
    pub state: VehicleState,
    steer_buffer: SteerBuffer,
    steer_delay: DelayLine,
    steer_lag: f64,
    drive_lag: f64,
    /// Output of the steering play (`steering_backlash`).
    #[serde(default)]
    steer_play: f64,
}

impl Vehicle {
    /// At rest at `pose`, buffers empty.
    pub fn new(pose: Pose) -> Self {
        Self {
            state: VehicleState::at_rest(pose),
            steer_buffer: SteerBuffer::default(),
            steer_delay: DelayLine::default(),
            steer_lag: 0.0,
            drive_lag: 0.0,
            steer_play: 0.0,
        }
    }

    /// From a given state (for example a reference test's initial speed), buffers empty.
    pub fn with_state(state: VehicleState) -> Self {
        Self {
            state,
            ..Self::new(Pose::default())
        }
    }

    /// Back to rest at `pose` with empty buffers (keeps the delay line's allocation).
    pub fn reset(&mut self, pose: Pose) {
        self.state = VehicleState::at_rest(pose);
        self.steer_buffer = SteerBuffer::default();
        self.steer_delay.clear();
        self.steer_lag = 0.0;
        self.drive_lag = 0.0;
        self.steer_play = 0.0;
    }

    /// Fill the command path as if `steer_cmd` and `speed_cmd` had been held for a long
    /// time (a replay that starts in motion): the delay line and the 2-step buffer hold
    /// the command, the lags sit at their inputs, the play is centred on its input and the
    /// wheel angle at its target (within the steering limits). Pose, speed, yaw rate and
    /// slip are untouched.
    pub fn settle_commands(&mut self, p: &VehicleParams, steer_cmd: f64, speed_cmd: f64, dt: f64) {
        let fx = &p.effects;
        let steer = if steer_cmd.is_finite() {
            steer_cmd
        } else {
            0.0
        };
        let speed = if speed_cmd.is_finite() {
            speed_cmd
        } else {
            0.0
        };
        match fx.steering_delay {
            Some(d) if dt > 0.0 && (d.delay_s / dt).round() >= 1.0 => self
                .steer_delay
                .fill(steer, (d.delay_s / dt).round() as usize),
            _ => self.steer_delay.clear(),
        }
        self.steer_buffer = SteerBuffer::filled(steer);
        self.steer_lag = steer;
        let mut target = steer;
        if let Some(g) = fx.steering_gain {
            target *= g.gain;
        }
        if let Some(o) = fx.steering_offset {
            target += o.offset_rad;
        }
        self.steer_play = target;
        self.state.steer_angle = target.clamp(p.s_min, p.s_max);
        self.drive_lag = match fx.speed_gain {
            Some(g) => speed * g.gain,
            None => speed,
        };
    }

    /// Pose of the reference point: `(x, y, yaw)`.
    #[inline]
    pub fn pose(&self) -> Pose {
        Pose::new(self.state.x, self.state.y, self.state.yaw)
    }

    /// Velocity in the body frame: `(v cos(slip), v sin(slip))` [m/s].
    #[inline]
    pub fn body_velocity(&self) -> (f64, f64) {
        let s = &self.state;
        (s.v * libm::cos(s.slip_angle), s.v * libm::sin(s.slip_angle))
    }

    /// Stop dead (a collision): zero speed, yaw rate and slip; pose and wheel angle kept.
    /// The speed-command lag rests at 0 and the steering lag at the current wheel angle;
    /// commands already in the steering buffers stay queued.
    pub fn halt(&mut self) {
        self.state.v = 0.0;
        self.state.yaw_rate = 0.0;
        self.state.slip_angle = 0.0;
        self.drive_lag = 0.0;
        self.steer_lag = self.state.steer_angle;
    }

    /// Steering commands waiting in the reference's 2-step buffer, newest first.
    pub fn pending_steer(&self) -> &[f64] {
        self.steer_buffer.pending()
    }

    /// Advance one step of `dt` seconds with the raw commands (steering angle [rad],
    /// speed [m/s]); see the module documentation. Non-finite commands count as 0;
    /// a non-positive or non-finite `dt` leaves the vehicle unchanged.
    pub fn step(&mut self, p: &VehicleParams, steer_cmd: f64, speed_cmd: f64, dt: f64) {
        if !(dt.is_finite() && dt > 0.0) {
            return;
        }
        let steer_cmd = if steer_cmd.is_finite() {
            steer_cmd
        } else {
            0.0
        };
        let speed_cmd = if speed_cmd.is_finite() {
            speed_cmd
        } else {
            0.0
        };
        let fx = &p.effects;

        // Steering command path: extra delay -> reference buffer -> lag -> gain -> offset
        // -> play.
        let delayed = match fx.steering_delay {
            Some(d) => {
                let n = (d.delay_s / dt).round();
                let n = if n >= 1.0 { n as usize } else { 0 };
                self.steer_delay.push(steer_cmd, n)
            }
            None => {
                if !self.steer_delay.is_empty() {
                    self.steer_delay.clear();
                }
                steer_cmd
            }
        };
        let mut steer_target = self.steer_buffer.push(delayed);
        if let Some(l) = fx.steering_lag {
            steer_target = lag_update(&mut self.steer_lag, steer_target, lag_gain(dt, l.tau_s));
        }
        if let Some(g) = fx.steering_gain {
            steer_target *= g.gain;
        }
        if let Some(o) = fx.steering_offset {
            steer_target += o.offset_rad;
        }
        if let Some(b) = fx.steering_backlash {
            steer_target = b.update(&mut self.steer_play, steer_target);
        }
        let speed_cmd = match fx.speed_gain {
            Some(g) => speed_cmd * g.gain,
            None => speed_cmd,
        };
        let speed_target = match fx.drive_lag {
            Some(l) => lag_update(&mut self.drive_lag, speed_cmd, lag_gain(dt, l.tau_s)),
            None => speed_cmd,
        };

        let s = &self.state;
        let sv = steering_velocity_command(steer_target, s.steer_angle, p.sv_max);
        let accl = acceleration_command(speed_target, s.v, p.a_max, p.v_max, p.v_min);
        let u = [sv, accl];
        let mu = friction_at(p, s.x, s.y);

        let x0 = s.to_array();
        let mut x1 = integrate(&x0, dt, p.integrator, |x| vehicle_dynamics(x, u, p, mu));
        if x1[4] > TAU {
            x1[4] -= TAU;
        } else if x1[4] < 0.0 {
            x1[4] += TAU;
        }
        self.state = VehicleState::from_array(x1);
    }
}

/// Friction coefficient at `(x, y)`: the first `friction_patch` containing the point,
/// else `p.mu`.
#[inline]
pub fn friction_at(p: &VehicleParams, x: f64, y: f64) -> f64 {
    match &p.effects.friction_patch {
        Some(patches) => patches
            .iter()
            .find(|patch| patch.contains(x, y))
            .map_or(p.mu, |patch| patch.mu),
        None => p.mu,
    }
}

#[cfg(test)]
mod tests;
