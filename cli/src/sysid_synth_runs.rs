//! `paddock sysid synth --runs N --manoeuvre step|arc|speed-step`: a test day of short
//! open-loop manoeuvres, as a real car is driven to identify it: steering steps (with a
//! reversal), constant-radius arcs and speed steps, at low and at racing speed, each run
//! starting at rest or in motion, logged at 20-50 Hz with noise and jitter, optionally
//! with only the pose and the speed. Commands change only at logged rows (a controller
//! acting when it logs), so the CSV pairs each row with the command in force.

use std::path::Path;

use anyhow::{Result, bail};
use paddock_sim::dynamics::{Vehicle, VehicleState};
use paddock_sim::geometry::Pose;
use paddock_sim::params::VehicleParams;
use paddock_sim::rng::Rng;
use paddock_sysid::recording::{Command, Recording, StateSample, wrap_pi};

const DT: f64 = 0.01;
/// Time driven with the first commands before logging starts, for runs in motion [s].
const PRE_ROLL_S: f64 = 1.5;

/// One manoeuvre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Manoeuvre {
    Step,
    Arc,
    SpeedStep,
}

impl Manoeuvre {
    pub fn parse(s: &str) -> Result<Self> {
        Ok(match s.trim() {
            "step" => Manoeuvre::Step,
            "arc" => Manoeuvre::Arc,
            "speed-step" => Manoeuvre::SpeedStep,
            other => bail!("--manoeuvre {other:?}: one of step, arc, speed-step"),
        })
    }
}

/// What the test day looks like.
pub struct DayPlan {
    pub manoeuvres: Vec<Manoeuvre>,
    pub runs: usize,
    pub seconds: f64,
    pub rate_hz: f64,
    /// Log `vy` and `yaw_rate` too.
    pub full_state: bool,
    /// "rest", "moving" or "mixed".
    pub start: String,
    pub seed: u64,
    pub noise: [f64; 6],
    pub measurement_delay: f64,
}

/// Commands of run `k` at time `t` (held between logged rows).
struct Schedule {
    kind: Manoeuvre,
    speed: f64,
    steer: f64,
    speed2: f64,
    seconds: f64,
}

impl Schedule {
    fn at(&self, t: f64) -> (f64, f64) {
        let f = t / self.seconds;
        match self.kind {
            // straight, a step, a reversal, back to straight
            Manoeuvre::Step => {
                let s = if f < 0.15 {
                    0.0
                } else if f < 0.5 {
                    self.steer
                } else if f < 0.85 {
                    -self.steer
                } else {
                    0.0
                };
                (s, self.speed)
            }
            Manoeuvre::Arc => (self.steer, self.speed),
            Manoeuvre::SpeedStep => {
                let v = if (0.3..0.65).contains(&f) {
                    self.speed2
                } else {
                    self.speed
                };
                (0.3 * self.steer, v)
            }
        }
    }
}

/// A history of true states on the physics grid, read at any time (a delayed sensor).
pub struct History {
    pub t0: f64,
    pub states: Vec<[f64; 6]>,
}

impl History {
    pub fn push(&mut self, car: &Vehicle) {
        let (vx, vy) = car.body_velocity();
        let s = car.state;
        self.states.push([s.x, s.y, s.yaw, vx, vy, s.yaw_rate]);
    }
    pub fn at(&self, t: f64) -> [f64; 6] {
        let pos = ((t - self.t0) / DT).max(0.0);
        let k = (pos.floor() as usize).min(self.states.len() - 1);
        let k1 = (k + 1).min(self.states.len() - 1);
        let f = (pos - k as f64).clamp(0.0, 1.0);
        let (a, b) = (self.states[k], self.states[k1]);
        let mut out: [f64; 6] = std::array::from_fn(|c| a[c] + f * (b[c] - a[c]));
        out[2] = a[2] + f * wrap_pi(b[2] - a[2]);
        out
    }
}

/// Write the runs (`run-NN.csv` in `dir`) and return a summary per run.
/// One logged row: the command sent at `t` and the measured state `m` (x, y, yaw, vx, vy,
/// yaw rate); without `full_state` the car logs no vy and no yaw rate (NaN).
pub(crate) fn push_row(
    rec: &mut Recording,
    t: f64,
    cmd: (f64, f64),
    m: &[f64; 6],
    full_state: bool,
) {
    rec.commands.push(Command {
        t,
        steer: cmd.0,
        speed: cmd.1,
    });
    let unlogged = |v: f64| if full_state { v } else { f64::NAN };
    rec.states.push(StateSample {
        t,
        x: m[0],
        y: m[1],
        yaw: wrap_pi(m[2]),
        vx: m[3],
        vy: unlogged(m[4]),
        yaw_rate: unlogged(m[5]),
    });
}

pub fn write_day(
    plan: &DayPlan,
    truth: &VehicleParams,
    dir: &Path,
) -> Result<Vec<serde_json::Value>> {
    std::fs::create_dir_all(dir)?;
    let root = Rng::new(plan.seed);
    let mut summary = Vec::new();
    for k in 0..plan.runs {
        let mut rng = root.fork(k as u64 + 1);
        let kind = plan.manoeuvres[k % plan.manoeuvres.len()];
        // alternate low and racing speeds; keep the lateral acceleration below ~6 m/s^2
        let racing = (k / plan.manoeuvres.len()) % 2 == 1;
        let speed = if racing {
            rng.uniform_range(4.0, 5.5)
        } else {
            rng.uniform_range(1.5, 2.5)
        };
        let wheelbase = truth.lf + truth.lr;
        let max_steer = libm::atan(6.0 * wheelbase / (speed * speed)).min(0.3);
        let sign = if rng.uniform() < 0.5 { -1.0 } else { 1.0 };
        let steer = sign * rng.uniform_range(0.5, 1.0) * max_steer;
        let speed2 = speed + rng.uniform_range(1.0, 2.0);
        let moving = match plan.start.as_str() {
            "rest" => false,
            "moving" => true,
            _ => k % 2 == 1,
        };
        let sched = Schedule {
            kind,
            speed,
            steer,
            speed2,
            seconds: plan.seconds,
        };
        let rec = drive(plan, truth, &sched, moving, &mut rng)?;
        let file = dir.join(format!("run-{:02}.csv", k + 1));
        std::fs::write(&file, rec.to_csv_string())?;
        summary.push(serde_json::json!({
            "file": file.file_name().map(|n| n.to_string_lossy().into_owned()),
            "manoeuvre": format!("{kind:?}"),
            "speed_cmd": (speed * 1000.0).round() / 1000.0,
            "steer_cmd": (steer * 1e4).round() / 1e4,
            "start": if moving { "moving" } else { "rest" },
        }));
    }
    Ok(summary)
}

fn drive(
    plan: &DayPlan,
    truth: &VehicleParams,
    sched: &Schedule,
    moving: bool,
    rng: &mut Rng,
) -> Result<Recording> {
    let yaw0 = rng.uniform_range(-3.0, 3.0);
    let mut car = Vehicle::new(Pose::new(0.0, 0.0, yaw0.rem_euclid(std::f64::consts::TAU)));
    let first = sched.at(0.0);
    let mut hist = History {
        t0: 0.0,
        states: Vec::new(),
    };
    if moving {
        // drive into the first commands' steady state before the log starts
        car = Vehicle::with_state(VehicleState {
            v: first.1,
            yaw: car.state.yaw,
            ..car.state
        });
        car.settle_commands(truth, first.0, first.1, DT);
        let n = (PRE_ROLL_S / DT) as usize;
        hist.t0 = -(n as f64) * DT;
        for _ in 0..n {
            hist.push(&car);
            car.step(truth, first.0, first.1, DT);
        }
    }
    let period = 1.0 / plan.rate_hz;
    let mut rec = Recording::default();
    let mut next_row = 0.0f64;
    let mut cmd = (0.0, 0.0);
    let mut yaw_push = 0.0f64;
    let mut speed_push = 0.0f64;
    let steps = (plan.seconds / DT).round() as usize;
    for k in 0..=steps {
        let tk = k as f64 * DT;
        hist.push(&car);
        while next_row <= tk + 1e-9 {
            let exact = hist.at(next_row - plan.measurement_delay);
            let m: [f64; 6] = std::array::from_fn(|c| exact[c] + plan.noise[c] * rng.normal());
            cmd = sched.at(next_row);
            push_row(&mut rec, next_row, cmd, &m, plan.full_state);
            let jitter = rng.uniform_range(-0.1, 0.1) * period;
            next_row = ((next_row + period + jitter) * 1e4).round() / 1e4;
        }
        if k == steps {
            break;
        }
        car.step(truth, cmd.0, cmd.1, DT);
        // small random pushes in yaw and speed while moving (first-order random processes)
        let moving_now = car.state.v.abs().min(1.0);
        let a = libm::exp(-DT / 0.4);
        yaw_push = a * yaw_push + 0.4 * libm::sqrt(1.0 - a * a) * rng.normal();
        let b = libm::exp(-DT / 0.6);
        speed_push = b * speed_push + 0.2 * libm::sqrt(1.0 - b * b) * rng.normal();
        car.state.yaw_rate += moving_now * yaw_push * DT;
        car.state.v += moving_now * speed_push * DT;
        if !car.state.v.is_finite() || car.state.v.abs() > 50.0 {
            bail!("the car became unstable at t = {tk:.2} s with these effects; try milder values");
        }
    }
    Ok(rec)
}
