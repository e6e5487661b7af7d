//! Conformance with the f1tenth_gym reference dynamics.
//!
//! Replays every trajectory in `shared/conformance/f1tenth_gym_dynamics/` (reference branch
//! `main`, our default parameters) and its `v1.0.0/` folder (with `kinematic_branch: v1`):
//! same initial state, same raw commands, one `Vehicle::step` per row, every state column
//! compared. See that folder's README for how the vectors were made.
//!
//! The folder is found through `PADDOCK_SHARED` (the `shared` directory) or by walking up
//! from this crate to a directory that holds `shared/conformance`. If it is missing the
//! tests fail, unless `PADDOCK_ALLOW_MISSING_SHARED=1`.

mod common;

use std::path::Path;

use paddock_sim::dynamics::{Vehicle, VehicleState};
use paddock_sim::geometry::wrap_angle;
use paddock_sim::params::{KinematicBranch, VehicleParams};

const DT: f64 = 0.01;
/// Absolute tolerance on every column (the brief's bar; we expect ~1e-15).
const TOL: f64 = 1e-6;
const FORWARD_CASES: [&str; 6] = [
    "accel_from_rest",
    "step_steer_low_speed",
    "sine_steer_5mps",
    "hard_brake_from_8mps",
    "slalom_7mps",
    "near_limit_corner",
];
const REVERSE_CASE: &str = "reverse_then_forward";
/// `main` leaves the kinematic branch in reverse and then diverges (upstream issue #53).
/// Its step 0.07 -> 0.08 s already evaluates the dynamic equations in the RK stages whose
/// speed is below -0.5 m/s (the row at 0.08 s has slip -0.12 rad), which Paddock's signed
/// switch deliberately does not; so `main` rows are compared up to 0.07 s, the last row
/// produced by kinematic stages only.
const MAIN_REVERSE_VALID_UNTIL: f64 = 0.07;
const COLUMNS: [&str; 7] = [
    "x",
    "y",
    "yaw",
    "v",
    "steer_angle",
    "yaw_rate",
    "slip_angle",
];

struct Row {
    t: f64,
    steer_cmd: f64,
    speed_cmd: f64,
    /// x, y, yaw, v, steer_angle, yaw_rate, slip_angle (file order).
    state: [f64; 7],
}

fn read_case(path: &Path) -> Vec<Row> {
    let text = std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    let mut lines = text.lines();
    let header = lines.next().expect("header");
    assert_eq!(
        header,
        "t,steer_cmd,speed_cmd,x,y,yaw,v,steer_angle,yaw_rate,slip_angle",
        "{}",
        path.display()
    );
    lines
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let f: Vec<f64> = l
                .split(',')
                .map(|s| {
                    s.parse()
                        .unwrap_or_else(|_| panic!("bad number {s:?} in {l}"))
                })
                .collect();
            assert_eq!(f.len(), 10, "{l}");
            Row {
                t: f[0],
                steer_cmd: f[1],
                speed_cmd: f[2],
                state: [f[3], f[4], f[5], f[6], f[7], f[8], f[9]],
            }
        })
        .collect()
}

fn file_order(s: &VehicleState) -> [f64; 7] {
    [
        s.x,
        s.y,
        s.yaw,
        s.v,
        s.steer_angle,
        s.yaw_rate,
        s.slip_angle,
    ]
}

/// Replays `rows` and returns, per column, the max absolute error over rows with
/// `t <= t_max`, plus every state the replay went through.
fn replay(rows: &[Row], p: &VehicleParams, t_max: f64) -> ([f64; 7], Vec<VehicleState>) {
    let r0 = &rows[0].state;
    let mut car = Vehicle::with_state(VehicleState {
        x: r0[0],
        y: r0[1],
        yaw: r0[2],
        v: r0[3],
        steer_angle: r0[4],
        yaw_rate: r0[5],
        slip_angle: r0[6],
    });
    let mut max_err = [0.0f64; 7];
    let mut states = vec![car.state];
    for k in 0..rows.len() - 1 {
        car.step(p, rows[k].steer_cmd, rows[k].speed_cmd, DT);
        states.push(car.state);
        let want = &rows[k + 1];
        if want.t > t_max + 1e-9 {
            continue;
        }
        let got = file_order(&car.state);
        for c in 0..7 {
            let err = if c == 2 {
                wrap_angle(got[c] - want.state[c]).abs()
            } else {
                (got[c] - want.state[c]).abs()
            };
            // NaN must count as a failure, not vanish in max().
            max_err[c] = if err.is_nan() {
                f64::INFINITY
            } else {
                max_err[c].max(err)
            };
        }
    }
    (max_err, states)
}

fn report(folder: &str, case: &str, err: &[f64; 7]) -> f64 {
    let worst = err.iter().cloned().fold(0.0, f64::max);
    let cols: Vec<String> = COLUMNS
        .iter()
        .zip(err)
        .map(|(c, e)| format!("{c}={e:.1e}"))
        .collect();
    println!(
        "{folder:>6} {case:<22} max |err| = {worst:.3e}  ({})",
        cols.join(" ")
    );
    worst
}

fn check_folder(dir: &Path, folder: &str, p: &VehicleParams, cases: &[&str], t_max: f64) {
    let mut failures = Vec::new();
    for case in cases {
        let rows = read_case(&dir.join(format!("{case}.csv")));
        let (err, _) = replay(&rows, p, t_max);
        let worst = report(folder, case, &err);
        if worst > TOL {
            failures.push(format!("{folder}/{case}: {worst:e}"));
        }
    }
    assert!(failures.is_empty(), "beyond {TOL:e}: {failures:?}");
}

#[test]
fn main_branch_forward_cases_match() {
    let Some(dir) = common::shared("conformance/f1tenth_gym_dynamics") else {
        return;
    };
    check_folder(
        &dir,
        "main",
        &VehicleParams::default(),
        &FORWARD_CASES,
        f64::INFINITY,
    );
}

#[test]
fn v1_branch_all_cases_match() {
    let Some(dir) = common::shared("conformance/f1tenth_gym_dynamics") else {
        return;
    };
    let p = VehicleParams {
        kinematic_branch: KinematicBranch::V1,
        ..Default::default()
    };
    let mut cases = FORWARD_CASES.to_vec();
    cases.push(REVERSE_CASE);
    check_folder(&dir.join("v1.0.0"), "v1.0.0", &p, &cases, f64::INFINITY);
}

#[test]
fn main_branch_reverse_matches_until_divergence_then_stays_bounded() {
    let Some(dir) = common::shared("conformance/f1tenth_gym_dynamics") else {
        return;
    };
    let p = VehicleParams::default();
    check_folder(&dir, "main", &p, &[REVERSE_CASE], MAIN_REVERSE_VALID_UNTIL);
    let rows = read_case(&dir.join(format!("{REVERSE_CASE}.csv")));
    let (_, states) = replay(&rows, &p, MAIN_REVERSE_VALID_UNTIL);
    assert_eq!(states.len(), 801);
    let mut max_r = 0.0f64;
    for (k, s) in states.iter().enumerate() {
        assert!(
            file_order(s).iter().all(|v| v.is_finite()),
            "non-finite state at step {k}: {s:?}"
        );
        assert!(
            s.yaw_rate.abs() < 10.0,
            "yaw rate {} at step {k}",
            s.yaw_rate
        );
        max_r = max_r.max(s.yaw_rate.abs());
    }
    // It really reverses, then really drives forward again.
    let v_at = |t: f64| states[(t / DT).round() as usize].v;
    assert!(v_at(3.9) < -1.9, "{}", v_at(3.9));
    assert!(v_at(7.9) > 1.9, "{}", v_at(7.9));
    println!("main reverse_then_forward: max |yaw_rate| over 8 s = {max_r:.3}");
}

#[test]
fn shipped_default_vehicle_is_the_reference_vehicle() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("vehicles/f1tenth.yaml");
    let p = VehicleParams::load(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(p, VehicleParams::default());
}
