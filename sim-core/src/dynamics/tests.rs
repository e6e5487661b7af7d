//! Unit tests of the vehicle step and its effects. The reference conformance lives in
//! `tests/conformance_dynamics.rs`.

use super::*;
use crate::params::{
    Drag, Effects, FirstOrderLag, FrictionPatch, Integrator, KinematicBranch, SteeringDelay,
    SteeringOffset, TireSaturation, VehicleModel,
};

const DT: f64 = 0.01;

fn with_effects(effects: Effects) -> VehicleParams {
    VehicleParams {
        effects,
        ..Default::default()
    }
}

/// Run `n` steps from rest with constant commands; states after each step.
fn run(p: &VehicleParams, steer: f64, speed: f64, n: usize) -> Vec<VehicleState> {
    let mut car = Vehicle::new(Pose::default());
    (0..n)
        .map(|_| {
            car.step(p, steer, speed, DT);
            car.state
        })
        .collect()
}

#[test]
fn steering_delay_shifts_the_steering_response_by_whole_steps() {
    let nominal = run(&VehicleParams::default(), 0.3, 2.0, 200);
    let p = with_effects(Effects {
        steering_delay: Some(SteeringDelay { delay_s: 0.05 }),
        ..Default::default()
    });
    let delayed = run(&p, 0.3, 2.0, 200);
    // The wheel angle depends only on the command sequence: exactly 5 steps later.
    for k in 0..195 {
        assert_eq!(
            delayed[k + 5].steer_angle,
            nominal[k].steer_angle,
            "step {k}"
        );
    }
    assert!(delayed[..7].iter().all(|s| s.steer_angle == 0.0));
    // Nominal: the command given at step 0 acts in step 2 (state after 3 steps).
    assert_eq!(nominal[1].steer_angle, 0.0);
    assert!(nominal[2].steer_angle > 0.0);
    assert!(delayed[7].steer_angle > 0.0);
}

#[test]
fn zero_length_effects_are_the_reference() {
    let nominal = run(&VehicleParams::default(), 0.2, 5.0, 300);
    let p = with_effects(Effects {
        steering_delay: Some(SteeringDelay { delay_s: 0.004 }), // rounds to 0 steps
        steering_lag: Some(FirstOrderLag { tau_s: 0.0 }),
        steering_offset: Some(SteeringOffset { offset_rad: 0.0 }),
        drive_lag: Some(FirstOrderLag { tau_s: 0.0 }),
        friction_patch: Some(vec![FrictionPatch {
            mu: 0.2,
            region: [100.0, 100.0, 101.0, 101.0], // never reached
        }]),
        ..Default::default()
    });
    assert_eq!(run(&p, 0.2, 5.0, 300), nominal);
}

#[test]
fn steering_lag_smooths_the_wheel_angle() {
    let nominal = run(&VehicleParams::default(), 0.3, 2.0, 200);
    let p = with_effects(Effects {
        steering_lag: Some(FirstOrderLag { tau_s: 0.1 }),
        ..Default::default()
    });
    let lagged = run(&p, 0.3, 2.0, 200);
    // The nominal wheel reaches the lattice point below 0.3 in 9 moves (steps 2..=10);
    // the lagged one follows an exponential target and gets there much later.
    let first_at = |traj: &[VehicleState], a: f64| traj.iter().position(|s| s.steer_angle >= a);
    let n_nom = first_at(&nominal, 0.28).unwrap();
    let n_lag = first_at(&lagged, 0.28).unwrap();
    assert_eq!(n_nom, 10);
    assert!(n_lag >= n_nom + 10, "{n_lag} vs {n_nom}");
    for s in [&nominal[199], &lagged[199]] {
        assert!((s.steer_angle - 0.3).abs() <= 0.032 + 1e-12, "{s:?}");
    }
}

#[test]
fn drive_lag_slows_the_speed_response() {
    let nominal = run(&VehicleParams::default(), 0.0, 3.0, 500);
    let p = with_effects(Effects {
        drive_lag: Some(FirstOrderLag { tau_s: 0.3 }),
        ..Default::default()
    });
    let lagged = run(&p, 0.0, 3.0, 500);
    assert!(
        lagged[29].v < nominal[29].v - 0.5,
        "{} {}",
        lagged[29].v,
        nominal[29].v
    );
    assert!((lagged[499].v - 3.0).abs() < 0.01, "{}", lagged[499].v);
    assert!((nominal[499].v - 3.0).abs() < 1e-6);
}

#[test]
fn steering_offset_biases_the_wheel_and_turns_the_car() {
    let straight = run(&VehicleParams::default(), 0.0, 3.0, 300);
    assert!(straight.iter().all(|s| s.y == 0.0 && s.steer_angle == 0.0));
    let p = with_effects(Effects {
        steering_offset: Some(SteeringOffset { offset_rad: 0.05 }),
        ..Default::default()
    });
    let biased = run(&p, 0.0, 3.0, 300);
    let tail = &biased[100..];
    let mean = tail.iter().map(|s| s.steer_angle).sum::<f64>() / tail.len() as f64;
    assert!((mean - 0.05).abs() < 0.02, "mean wheel angle {mean}");
    assert!(
        biased[299].y > 0.5 && biased[299].yaw > 0.3,
        "{:?}",
        biased[299]
    );
}

#[test]
fn drag_lowers_top_speed() {
    let free = run(&VehicleParams::default(), 0.0, 20.0, 3000);
    let p = with_effects(Effects {
        drag: Some(Drag {
            c_lin: 0.1,
            c_quad: 0.05,
        }),
        ..Default::default()
    });
    let dragged = run(&p, 0.0, 20.0, 3000);
    let (vf, vd) = (free[2999].v, dragged[2999].v);
    assert!(vf > 19.9, "{vf}");
    assert!(vd < vf - 2.0, "{vd} vs {vf}");
    // Terminal speed: the limited drive force balances drag.
    let decel = 0.1 * vd + 0.05 * vd * vd;
    let drive = accl_constraints(vd, acceleration_command(20.0, vd, 9.51, 20.0, -5.0), &p);
    assert!((drive - decel).abs() < 1e-3, "{drive} vs {decel}");
}

#[test]
fn friction_patch_applies_only_inside_its_region() {
    let patch = FrictionPatch {
        mu: 0.3,
        region: [5.0, -2.0, 10.0, 2.0],
    };
    let p = with_effects(Effects {
        friction_patch: Some(vec![
            patch,
            FrictionPatch {
                mu: 0.9,
                region: [0.0, -2.0, 20.0, 2.0],
            },
        ]),
        ..Default::default()
    });
    assert_eq!(friction_at(&p, 7.0, 0.0), 0.3); // first match wins
    assert_eq!(friction_at(&p, 5.0, 2.0), 0.3); // bounds inclusive
    assert_eq!(friction_at(&p, 12.0, 0.0), 0.9);
    assert_eq!(friction_at(&p, -1.0, 0.0), p.mu);
    assert_eq!(friction_at(&p, 7.0, 3.0), p.mu);

    // Drive along x and steer: identical to the reference until the car enters the
    // patch, different afterwards.
    let only = with_effects(Effects {
        friction_patch: Some(vec![patch]),
        ..Default::default()
    });
    let steer = |k: usize| if k % 100 < 50 { 0.1 } else { -0.1 };
    let mut a = Vehicle::new(Pose::default());
    let mut b = a.clone();
    let mut entered = None;
    for k in 0..400 {
        let inside = patch.contains(b.state.x, b.state.y);
        a.step(&VehicleParams::default(), steer(k), 6.0, DT);
        b.step(&only, steer(k), 6.0, DT);
        if inside && entered.is_none() {
            entered = Some(k);
        }
        if entered.is_none() {
            assert_eq!(a, b, "step {k}");
        }
    }
    assert!(entered.is_some(), "the car never reached the patch");
    assert_ne!(a.state, b.state);
}

#[test]
fn linear_force_form_equals_the_st_equations() {
    let p = VehicleParams::default();
    for (x, accl) in [
        ([0.0, 0.0, 0.2, 5.0, 1.0, 0.8, -0.05], 3.0),
        ([0.0, 0.0, -0.4, 9.0, 1.0, -4.0, 0.3], -9.51),
        ([0.0, 0.0, 0.05, 0.7, 1.0, 0.1, 0.01], 0.5),
    ] {
        for mu in [p.mu, 0.4] {
            let (r1, b1) = linear_st_yaw_slip(&x, accl, &p, mu);
            let (ff, fr) = lateral_forces(&x, accl, &p, mu, None);
            let (r2, b2) = yaw_slip_from_forces(&x, ff, fr, &p);
            assert!((r1 - r2).abs() <= 1e-12 * r1.abs().max(1.0), "{r1} {r2}");
            assert!((b1 - b2).abs() <= 1e-12 * b1.abs().max(1.0), "{b1} {b2}");
        }
    }
}

#[test]
fn pacejka_at_small_slip_matches_the_linear_tire() {
    let p = VehicleParams::default();
    let tire = TireSaturation {
        d: 1.0,
        c: 1.3,
        e: -0.5,
    };
    let slope = p.mu * p.c_sf;
    for slip in [1e-7, -3e-6, 1e-5] {
        let f = pacejka(slip, slope, tire.d, tire.c, tire.e);
        assert!((f / (slope * slip) - 1.0).abs() < 1e-6, "{slip}: {f}");
    }
    // Whole model, tiny slip: the saturated RHS is the linear one.
    let x = [0.0, 0.0, 1e-5, 5.0, 0.0, 1e-5, -1e-6];
    let lin = vehicle_dynamics_st(&x, [0.0, 0.0], &p, p.mu);
    let sat_p = with_effects(Effects {
        tire_saturation: Some(tire),
        ..Default::default()
    });
    let sat = vehicle_dynamics_st(&x, [0.0, 0.0], &sat_p, p.mu);
    for i in 0..7 {
        assert!(
            (lin[i] - sat[i]).abs() <= 1e-8 * lin[i].abs().max(1e-12),
            "{i}: {} vs {}",
            lin[i],
            sat[i]
        );
    }
    // Saturation: the force never exceeds the peak D per unit load.
    for slip in [0.1, 0.3, 1.0] {
        assert!(pacejka(slip, slope, 1.0, 1.3, 0.0).abs() <= 1.0);
    }
}

/// Max |total lateral force| / m over a hard corner at 10 m/s.
fn max_lateral_accel(p: &VehicleParams) -> f64 {
    let mut car = Vehicle::new(Pose::default());
    let mut max_ay = 0.0f64;
    for k in 0..800 {
        let steer = if k < 300 { 0.0 } else { 0.4 };
        car.step(p, steer, 10.0, DT);
        let x = car.state.to_array();
        if x[3] >= KINEMATIC_SPEED {
            let mu = friction_at(p, x[0], x[1]);
            let (ff, fr) = lateral_forces(&x, 0.0, p, mu, p.effects.tire_saturation.as_ref());
            max_ay = max_ay.max(((ff + fr) / p.m).abs());
        }
        assert!(x.iter().all(|v| v.is_finite()), "step {k}: {x:?}");
    }
    max_ay
}

#[test]
fn tire_saturation_caps_lateral_acceleration() {
    let linear = max_lateral_accel(&VehicleParams::default());
    let p = with_effects(Effects {
        tire_saturation: Some(TireSaturation {
            d: 1.0,
            c: 1.5,
            e: 0.0,
        }),
        ..Default::default()
    });
    let saturated = max_lateral_accel(&p);
    // The total normal load is m g, so the peak is mu D g.
    assert!(saturated <= 9.81 * p.mu * 1.0 + 1e-9, "{saturated}");
    assert!(saturated > 0.8 * 9.81 * p.mu, "{saturated}");
    assert!(linear > 2.0 * 9.81, "{linear}");
    // mu scales the whole magic-formula force, as it scales the linear tire: half the mu,
    // half the peak (the convention `friction` with `tire_saturation` relies on)
    let half = VehicleParams {
        mu: 0.5 * p.mu,
        ..p.clone()
    };
    let x = [0.0, 0.0, 0.3, 5.0, 0.0, 0.2, -0.05];
    let tire = p.effects.tire_saturation.as_ref();
    for (a, b) in [
        lateral_forces(&x, 0.0, &p, p.mu, tire),
        lateral_forces(&x, 0.0, &half, half.mu, tire),
    ]
    .windows(2)
    .map(|w| (w[0], w[1]))
    {
        assert!((b.0 - 0.5 * a.0).abs() < 1e-9 * a.0.abs(), "{a:?} {b:?}");
        assert!(
            (b.1 - 0.5 * a.1).abs() < 1e-9 * a.1.abs().max(1e-9),
            "{a:?} {b:?}"
        );
    }
}

#[test]
fn reverse_driving_stays_bounded() {
    for branch in [KinematicBranch::Main, KinematicBranch::V1] {
        let p = VehicleParams {
            kinematic_branch: branch,
            ..Default::default()
        };
        let traj = run(&p, 0.3, -3.0, 500);
        let last = traj.last().unwrap();
        assert!((last.v + 3.0).abs() < 0.01, "{branch:?}: {last:?}");
        assert!(traj.iter().all(|s| s.yaw_rate.abs() < 10.0), "{branch:?}");
    }
}

#[test]
fn models_and_integrators_agree_at_low_speed() {
    // Below 0.5 m/s the ST model is the kinematic one; Euler and RK4 agree to O(dt).
    let base = run(&VehicleParams::default(), 0.2, 0.4, 300);
    for (model, integrator, tol) in [
        (VehicleModel::Ks, Integrator::Rk4, 0.0),
        (VehicleModel::St, Integrator::Euler, 0.01),
    ] {
        let p = VehicleParams {
            model,
            integrator,
            ..Default::default()
        };
        let other = run(&p, 0.2, 0.4, 300);
        let (a, b) = (base.last().unwrap(), other.last().unwrap());
        assert!(
            (a.x - b.x).abs() <= tol && (a.y - b.y).abs() <= tol,
            "{a:?} {b:?}"
        );
    }
    // At speed the kinematic model ignores tire slip: different from ST.
    let st = run(&VehicleParams::default(), 0.3, 8.0, 300);
    let ks = run(
        &VehicleParams {
            model: VehicleModel::Ks,
            ..Default::default()
        },
        0.3,
        8.0,
        300,
    );
    assert!(ks.iter().all(|s| s.slip_angle == 0.0));
    assert!((st[299].x - ks[299].x).abs() > 0.1);
}

#[test]
fn non_finite_commands_and_steps_do_not_poison_the_state() {
    let p = with_effects(Effects {
        steering_lag: Some(FirstOrderLag { tau_s: 0.1 }),
        drive_lag: Some(FirstOrderLag { tau_s: 0.1 }),
        steering_delay: Some(SteeringDelay { delay_s: 0.03 }),
        ..Default::default()
    });
    let mut car = Vehicle::new(Pose::new(1.0, 2.0, 0.5));
    for k in 0..100 {
        car.step(&p, 0.2, 4.0, DT);
        let bad = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY][k % 3];
        car.step(&p, bad, bad, DT);
        car.step(&p, 0.1, 3.0, bad);
        car.step(&p, 0.1, 3.0, -DT);
        assert!(
            car.state.to_array().iter().all(|v| v.is_finite()),
            "{car:?}"
        );
    }
    // A zero/negative/NaN dt is a no-op.
    let before = car.clone();
    car.step(&p, 0.1, 3.0, 0.0);
    car.step(&p, 0.1, 3.0, f64::NAN);
    assert_eq!(car, before);
}

#[test]
fn halt_reset_pose_and_body_velocity() {
    let p = VehicleParams::default();
    let mut car = Vehicle::new(Pose::new(1.0, -2.0, 0.3));
    assert_eq!(car.pose(), Pose::new(1.0, -2.0, 0.3));
    for _ in 0..200 {
        car.step(&p, 0.3, 6.0, DT);
    }
    let (vx, vy) = car.body_velocity();
    assert!((vx.hypot(vy) - car.state.v).abs() < 1e-12);
    assert!(vy != 0.0);
    let pose = car.pose();
    let steer = car.state.steer_angle;
    car.halt();
    assert_eq!(car.pose(), pose);
    assert_eq!(car.state.steer_angle, steer);
    assert_eq!(
        (car.state.v, car.state.yaw_rate, car.state.slip_angle),
        (0.0, 0.0, 0.0)
    );
    assert_eq!(car.body_velocity(), (0.0, 0.0));
    car.reset(Pose::new(3.0, 4.0, 1.0));
    assert_eq!(car, Vehicle::new(Pose::new(3.0, 4.0, 1.0)));
    assert!(car.pending_steer().is_empty());
}

#[test]
fn yaw_stays_in_zero_to_two_pi() {
    let traj = run(&VehicleParams::default(), 0.3, 3.0, 3000);
    assert!(traj.iter().all(|s| (0.0..=TAU).contains(&s.yaw)));
    let right = run(&VehicleParams::default(), -0.3, 3.0, 3000);
    assert!(right.iter().all(|s| (0.0..=TAU).contains(&s.yaw)));
}

#[test]
fn snapshot_round_trips_through_serde() {
    let p = with_effects(Effects {
        steering_delay: Some(SteeringDelay { delay_s: 0.05 }),
        steering_lag: Some(FirstOrderLag { tau_s: 0.1 }),
        ..Default::default()
    });
    let mut car = Vehicle::new(Pose::default());
    for k in 0..57 {
        car.step(&p, 0.01 * k as f64, 4.0, DT);
    }
    let text = serde_norway::to_string(&car).unwrap();
    let mut back: Vehicle = serde_norway::from_str(&text).unwrap();
    assert_eq!(back, car);
    // The restored copy continues bit-identically.
    for _ in 0..50 {
        car.step(&p, 0.2, 5.0, DT);
        back.step(&p, 0.2, 5.0, DT);
    }
    assert_eq!(back, car);
}

#[test]
fn steering_and_speed_gains_scale_the_targets() {
    let p = with_effects(Effects {
        steering_gain: Some(crate::params::SteeringGain { gain: 0.8 }),
        speed_gain: Some(crate::params::SpeedGain { gain: 1.1 }),
        ..Default::default()
    });
    let s = run(&p, 0.2, 2.0, 400);
    let last = s.last().unwrap();
    assert!(
        (last.steer_angle - 0.16).abs() < 2e-4,
        "{}",
        last.steer_angle
    );
    assert!((last.v - 2.2).abs() < 1e-3, "{}", last.v);
    // gain 1 and no play are the reference, bit for bit
    let unit = with_effects(Effects {
        steering_gain: Some(crate::params::SteeringGain { gain: 1.0 }),
        speed_gain: Some(crate::params::SpeedGain { gain: 1.0 }),
        steering_backlash: Some(crate::params::SteeringBacklash { width_rad: 0.0 }),
        ..Default::default()
    });
    assert_eq!(
        run(&unit, 0.2, 5.0, 300),
        run(&VehicleParams::default(), 0.2, 5.0, 300)
    );
}

#[test]
fn steering_backlash_lags_after_a_reversal() {
    // the wheel chatters within one bang-bang step (sv_max dt = 0.032 rad) of its target
    let w = 0.1;
    let tol = 3.2 * DT + 1e-9;
    let p = with_effects(Effects {
        steering_backlash: Some(crate::params::SteeringBacklash { width_rad: w }),
        ..Default::default()
    });
    let mut car = Vehicle::new(Pose::default());
    let mut settle = |cmd: f64| {
        for _ in 0..300 {
            car.step(&p, cmd, 1.0, DT);
        }
        car.state.steer_angle
    };
    let up = settle(0.2);
    let down = settle(-0.2);
    let back = settle(0.1);
    assert!((up - (0.2 - w / 2.0)).abs() <= tol, "{up}");
    assert!((down - (-0.2 + w / 2.0)).abs() <= tol, "{down}");
    assert!((back - (0.1 - w / 2.0)).abs() <= tol, "{back}");
    // inside the band the wheel's target does not move
    let held = settle(0.1 - w * 0.9);
    assert!((held - (0.1 - w / 2.0)).abs() <= tol, "{held} vs {back}");
}

#[test]
fn settled_commands_hold_a_steady_state() {
    let p = with_effects(Effects {
        steering_delay: Some(SteeringDelay { delay_s: 0.05 }),
        steering_lag: Some(FirstOrderLag { tau_s: 0.1 }),
        drive_lag: Some(FirstOrderLag { tau_s: 0.3 }),
        steering_gain: Some(crate::params::SteeringGain { gain: 0.9 }),
        ..Default::default()
    });
    let mut car = Vehicle::with_state(VehicleState {
        v: 3.0,
        ..Default::default()
    });
    car.settle_commands(&p, 0.1, 3.0, DT);
    assert!((car.state.steer_angle - 0.09).abs() < 1e-12);
    for _ in 0..50 {
        car.step(&p, 0.1, 3.0, DT);
        assert!((car.state.steer_angle - 0.09).abs() < 2e-4);
        assert!((car.state.v - 3.0).abs() < 0.05, "{}", car.state.v);
    }
}
