//! The pure model: command laws, input constraints, right-hand sides and integrators.
//!
//! Everything here is a plain function of its arguments, so system identification can
//! evaluate the same equations the simulator integrates. State vectors use the
//! reference's order, [`StateVec`] = `[x, y, steer_angle, v, yaw, yaw_rate, slip_angle]`,
//! and inputs are `u = [steering velocity, longitudinal acceleration]`.
//!
//! With every effect off, [`vehicle_dynamics_st`] is the reference's `vehicle_dynamics_st`
//! term by term, in the same floating-point association as f1tenth_gym `main`, so the
//! conformance trajectories are reproduced to the last bit or nearly so.

use crate::params::{
    GRAVITY, Integrator, KinematicBranch, TireSaturation, VehicleModel, VehicleParams,
};

/// Reference-order state vector: `[x, y, steer_angle, v, yaw, yaw_rate, slip_angle]`.
pub type StateVec = [f64; 7];

/// Below this signed speed [m/s] the single-track model falls back to kinematic equations.
pub const KINEMATIC_SPEED: f64 = 0.5;

/// Dead band of the bang-bang steering controller [rad].
pub const STEER_DEAD_BAND: f64 = 1e-4;

/// The reference's steering controller: full steering velocity towards the target,
/// zero within [`STEER_DEAD_BAND`] of it.
#[inline]
pub fn steering_velocity_command(target: f64, steer_angle: f64, sv_max: f64) -> f64 {
    let diff = target - steer_angle;
    // The reference writes `diff / |diff| * sv_max`; an explicit sign is identical for
    // finite values and stays finite for infinite ones.
    if libm::fabs(diff) > STEER_DEAD_BAND {
        if diff > 0.0 { sv_max } else { -sv_max }
    } else {
        0.0
    }
}

/// The reference's speed controller: `kp (speed_cmd - v)` with gains that depend on the
/// direction of travel and on whether the command speeds the car up or slows it down.
#[inline]
pub fn acceleration_command(speed_cmd: f64, v: f64, a_max: f64, v_max: f64, v_min: f64) -> f64 {
    let vel_diff = speed_cmd - v;
    let kp = if v > 0.0 {
        if vel_diff > 0.0 {
            10.0 * a_max / v_max
        } else {
            10.0 * a_max / (-v_min)
        }
    } else if vel_diff > 0.0 {
        2.0 * a_max / v_max
    } else {
        2.0 * a_max / (-v_min)
    };
    kp * vel_diff
}

/// Steering-velocity limits and the steering-angle stop (reference `steering_constraint`).
#[inline]
pub fn steering_constraint(steer_angle: f64, steer_vel: f64, p: &VehicleParams) -> f64 {
    if (steer_angle <= p.s_min && steer_vel <= 0.0) || (steer_angle >= p.s_max && steer_vel >= 0.0)
    {
        0.0
    } else if steer_vel <= p.sv_min {
        p.sv_min
    } else if steer_vel >= p.sv_max {
        p.sv_max
    } else {
        steer_vel
    }
}

/// Acceleration limits: `a_max` falling as `a_max v_switch / v` above `v_switch`, and the
/// speed stops at `v_min`/`v_max` (reference `accl_constraints`).
#[inline]
pub fn accl_constraints(v: f64, accl: f64, p: &VehicleParams) -> f64 {
    let pos_limit = if v > p.v_switch {
        p.a_max * p.v_switch / v
    } else {
        p.a_max
    };
    if (v <= p.v_min && accl <= 0.0) || (v >= p.v_max && accl >= 0.0) {
        0.0
    } else if accl <= -p.a_max {
        -p.a_max
    } else if accl >= pos_limit {
        pos_limit
    } else {
        accl
    }
}

/// Longitudinal deceleration from the `drag` effect (0 when off).
#[inline]
fn drag_decel(v: f64, p: &VehicleParams) -> Option<f64> {
    p.effects
        .drag
        .map(|d| d.c_lin * v + d.c_quad * v * libm::fabs(v))
}

/// The full right-hand side the simulator integrates: the model selected by `p.model`,
/// with the effects that act inside the dynamics (drag, tire saturation) and the local
/// friction coefficient `mu` (the friction map's value at the car, or `p.mu`).
#[inline]
pub fn vehicle_dynamics(x: &StateVec, u: [f64; 2], p: &VehicleParams, mu: f64) -> StateVec {
    match p.model {
        VehicleModel::St => vehicle_dynamics_st(x, u, p, mu),
        VehicleModel::Ks => vehicle_dynamics_ks(x, u, p),
    }
}

/// Kinematic single-track right-hand side over the full 7-state (the branch selected by
/// `p.kinematic_branch`), constraints applied to `u` first.
///
/// * `main`: rear-axle model, `x' = v cos(yaw)`, `yaw' = v tan(delta) / L`, the yaw rate
///   follows `d/dt (v tan(delta) / L)`, the slip angle is frozen.
/// * `v1`: centre-of-gravity model (CommonRoad KS-CoG) with `beta = atan(tan(delta) lr / L)`,
///   `x' = v cos(yaw + beta)`, `yaw' = v cos(beta) tan(delta) / L`; the slip angle follows
///   the exact derivative `d(beta)/dt = lr sv / (L cos^2(delta) (1 + (tan(delta) lr / L)^2))`
///   and the yaw rate `d/dt (v cos(slip) tan(delta) / L)` evaluated with the state's slip.
///   (This is what the v1.0.0 vectors show, not CommonRoad's `(tan^2(delta) lr / L)^2`.)
#[inline]
pub fn vehicle_dynamics_ks(x: &StateVec, u: [f64; 2], p: &VehicleParams) -> StateVec {
    let sv = steering_constraint(x[2], u[0], p);
    let accl = accl_constraints(x[3], u[1], p);
    kinematic_rhs(x, sv, accl, p)
}

/// Kinematic equations for already-constrained inputs.
#[inline]
fn kinematic_rhs(x: &StateVec, sv: f64, accl: f64, p: &VehicleParams) -> StateVec {
    let lwb = p.lf + p.lr;
    let v = x[3];
    let dv = match drag_decel(v, p) {
        Some(d) => accl - d,
        None => accl,
    };
    let tan_d = libm::tan(x[2]);
    let cos_d = libm::cos(x[2]);
    match p.kinematic_branch {
        KinematicBranch::Main => {
            let (sin_y, cos_y) = libm::sincos(x[4]);
            [
                v * cos_y,
                v * sin_y,
                sv,
                dv,
                v / lwb * tan_d,
                dv / lwb * tan_d + v / (lwb * (cos_d * cos_d)) * sv,
                0.0,
            ]
        }
        KinematicBranch::V1 => {
            let beta_hat = libm::atan(tan_d * p.lr / lwb);
            let q = tan_d * (p.lr / lwb);
            let d_beta = (1.0 / (1.0 + q * q)) * (p.lr / (lwb * (cos_d * cos_d))) * sv;
            let (sin_b, cos_b) = libm::sincos(x[6]);
            let dd_psi = 1.0 / lwb
                * (dv * cos_b * tan_d - v * sin_b * d_beta * tan_d
                    + v * cos_b * sv / (cos_d * cos_d));
            let (sin_h, cos_h) = libm::sincos(x[4] + beta_hat);
            [
                v * cos_h,
                v * sin_h,
                sv,
                dv,
                v * libm::cos(beta_hat) * tan_d / lwb,
                dd_psi,
                d_beta,
            ]
        }
    }
}

/// Dynamic single-track right-hand side with the reference's kinematic fallback below
/// [`KINEMATIC_SPEED`] (signed: reverse driving stays kinematic, see [`crate::dynamics`]).
/// Constraints are applied to `u` at the state `x`, as the reference does inside every
/// RK4 stage. `mu` scales both cornering stiffnesses.
///
/// With `effects.tire_saturation` set, the linear tire is replaced by a Pacejka curve per
/// axle (see [`lateral_forces`]); with `effects.drag`, `v' = a - drag(v)` (the load transfer
/// still uses the drive acceleration `a`).
#[inline]
pub fn vehicle_dynamics_st(x: &StateVec, u: [f64; 2], p: &VehicleParams, mu: f64) -> StateVec {
    let sv = steering_constraint(x[2], u[0], p);
    let accl = accl_constraints(x[3], u[1], p);
    if x[3] < KINEMATIC_SPEED {
        return kinematic_rhs(x, sv, accl, p);
    }
    let v = x[3];
    let dv = match drag_decel(v, p) {
        Some(d) => accl - d,
        None => accl,
    };
    let (dr, dbeta) = match p.effects.tire_saturation {
        None => linear_st_yaw_slip(x, accl, p, mu),
        Some(tire) => {
            let (ff, fr) = lateral_forces(x, accl, p, mu, Some(&tire));
            yaw_slip_from_forces(x, ff, fr, p)
        }
    };
    // sincos shares the argument reduction; it returns exactly libm's sin and cos.
    let (sin_h, cos_h) = libm::sincos(x[6] + x[4]);
    [v * cos_h, v * sin_h, sv, dv, x[5], dr, dbeta]
}

/// Yaw-rate and slip-angle derivatives of the CommonRoad ST model with linear tires,
/// written as f1tenth_gym `main` writes them (same association, same bits).
#[inline]
pub fn linear_st_yaw_slip(x: &StateVec, accl: f64, p: &VehicleParams, mu: f64) -> (f64, f64) {
    let g = GRAVITY;
    let (lf, lr, h, m, i) = (p.lf, p.lr, p.h, p.m, p.inertia);
    let (c_sf, c_sr) = (p.c_sf, p.c_sr);
    let (delta, v, r, beta) = (x[2], x[3], x[5], x[6]);
    let front = g * lr - accl * h;
    let rear = g * lf + accl * h;
    let dr = -mu * m / (v * i * (lr + lf)) * (lf * lf * c_sf * front + lr * lr * c_sr * rear) * r
        + mu * m / (i * (lr + lf)) * (lr * c_sr * rear - lf * c_sf * front) * beta
        + mu * m / (i * (lr + lf)) * lf * c_sf * front * delta;
    let dbeta = (mu / (v * v * (lr + lf)) * (c_sr * rear * lr - c_sf * front * lf) - 1.0) * r
        - mu / (v * (lr + lf)) * (c_sr * rear + c_sf * front) * beta
        + mu / (v * (lr + lf)) * (c_sf * front) * delta;
    (dr, dbeta)
}

/// Front and rear lateral tire forces [N] of the single-track model at state `x` with
/// longitudinal acceleration `accl` (load transfer), using the same linearised slip angles
/// as CommonRoad ST: `a_f = delta - beta - lf r / v`, `a_r = -beta + lr r / v`.
///
/// `tire = None` is the linear tire `F = mu C_S Fz a`; `Some` is the Pacejka curve
/// [`pacejka`] times `mu`: `F = mu Fz D sin(...)` with the slope `C_S` per unit `mu`. One
/// convention for both tires: `mu` (the vehicle's, a friction patch's, or the `friction`
/// the reality-gap tool fits) scales the whole lateral force, peak and slope.
#[inline]
pub fn lateral_forces(
    x: &StateVec,
    accl: f64,
    p: &VehicleParams,
    mu: f64,
    tire: Option<&TireSaturation>,
) -> (f64, f64) {
    let lwb = p.lf + p.lr;
    let (delta, v, r, beta) = (x[2], x[3], x[5], x[6]);
    let fz_f = p.m * (GRAVITY * p.lr - accl * p.h) / lwb;
    let fz_r = p.m * (GRAVITY * p.lf + accl * p.h) / lwb;
    let a_f = delta - beta - p.lf * r / v;
    let a_r = -beta + p.lr * r / v;
    match tire {
        None => (mu * p.c_sf * fz_f * a_f, mu * p.c_sr * fz_r * a_r),
        Some(t) => (
            mu * fz_f * pacejka(a_f, p.c_sf, t.d, t.c, t.e),
            mu * fz_r * pacejka(a_r, p.c_sr, t.d, t.c, t.e),
        ),
    }
}

/// Pacejka lateral force per unit normal load: `D sin(C atan(B a - E (B a - atan(B a))))`
/// with `B = slope / (C D)`, so that `d/da` at `a = 0` equals `slope` (the linear tire's
/// `mu C_S`).
#[inline]
pub fn pacejka(slip: f64, slope: f64, d: f64, c: f64, e: f64) -> f64 {
    let b = slope / (c * d);
    let ba = b * slip;
    d * libm::sin(c * libm::atan(ba - e * (ba - libm::atan(ba))))
}

/// Yaw-rate and slip-angle derivatives from the axle forces:
/// `r' = (lf Ff - lr Fr) / I`, `beta' = (Ff + Fr) / (m v) - r`.
#[inline]
pub fn yaw_slip_from_forces(
    x: &StateVec,
    f_front: f64,
    f_rear: f64,
    p: &VehicleParams,
) -> (f64, f64) {
    let dr = (p.lf * f_front - p.lr * f_rear) / p.inertia;
    let dbeta = (f_front + f_rear) / (p.m * x[3]) - x[5];
    (dr, dbeta)
}

/// One integration step of `x' = f(x)` with inputs held constant (reference
/// `update_pose`: `x + dt/6 (k1 + 2 k2 + 2 k3 + k4)`, or `x + dt f(x)`).
#[inline]
pub fn integrate(
    x: &StateVec,
    dt: f64,
    integrator: Integrator,
    f: impl Fn(&StateVec) -> StateVec,
) -> StateVec {
    match integrator {
        Integrator::Euler => {
            let k = f(x);
            std::array::from_fn(|i| x[i] + dt * k[i])
        }
        Integrator::Rk4 => {
            let k1 = f(x);
            let s2: StateVec = std::array::from_fn(|i| x[i] + dt * (k1[i] / 2.0));
            let k2 = f(&s2);
            let s3: StateVec = std::array::from_fn(|i| x[i] + dt * (k2[i] / 2.0));
            let k3 = f(&s3);
            let s4: StateVec = std::array::from_fn(|i| x[i] + dt * k3[i]);
            let k4 = f(&s4);
            let h = dt * (1.0 / 6.0);
            std::array::from_fn(|i| x[i] + h * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]))
        }
    }
}
