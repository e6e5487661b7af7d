//! A lattice planner for racing against others, in the Frenet frame of the circuit's
//! driving line (its raceline, or a line inside the map's free space) with its hairpins
//! rounded ([`crate::refpath::ROUNDING_PASSES`]).
//!
//! Every `replan_every` steps (receding horizon) the planner samples goal states ahead
//! on the raceline: `num_lengths` distances (from `horizon_min`, or `horizon_time`
//! seconds at the current speed if farther, up to twice that) times `num_offsets` lateral
//! offsets evenly spread over [-`lateral_span`, `lateral_span`]. Each goal is joined to
//! the car's state (offset, heading relative to the raceline) by a quintic lateral
//! profile d(s) with zero slope and curvature at the goal, then held at the goal offset.
//!
//! A candidate is rejected if, sampled every 0.2 m, the car's box (grown by
//! `wall_margin`) touches a wall of the map, the box grown by `car_margin` contains a
//! LIDAR return that is not a wall and not another car (a static obstacle), the box
//! overlaps another car's predicted box (constant speed along the raceline at its
//! current offset: a constant-velocity prediction in the track's frame, which stays on
//! the track in curves; the box is grown by `car_margin` plus 10 % of the predicted
//! travel), or the path's curvature exceeds what the steering allows.
//!
//! The cost of a valid candidate is `w_offset` x the mean |offset| along it, plus
//! `w_curvature` x the mean squared curvature beyond the raceline's, plus `w_opponent` x
//! a proximity penalty to the predicted cars, plus `w_change` x the change of goal offset
//! from the last plan, plus `w_progress` x the fraction of the reference speed the
//! path's curvature takes away (less progress). When every candidate is rejected the
//! one that runs longest before its first conflict is taken, and the speed plan stops
//! before a static conflict or matches the other car's speed at a car conflict.
//!
//! The chosen path is tracked by the planners' shared tracker ([`crate::tracker`]: pure
//! pursuit, lookahead `lookahead_min` + `lookahead_gain` x speed, with a cross-track
//! term). Speed: the raceline's speed profile times `speed_scale`, capped by `max_speed`
//! and by sqrt(`lat_accel` / |curvature|) of the chosen path, with a backward pass at
//! `brake_decel` so the car slows in time.
//!
//! Reads the LIDAR (obstacles) and the observation's poses and speeds of the other cars
//! ([`crate::perception`]).

use std::sync::Arc;

use paddock_sim::circuit::Circuit;
use paddock_sim::collision::{obb_hits_map, obb_overlap};
use paddock_sim::geometry::{Obb, Pose, wrap_angle};
use paddock_sim::map::Map;
use paddock_sim::params::VehicleParams;
use paddock_sim::world::{Action, Observation};
use serde::{Deserialize, Serialize};

use crate::perception::{Perception, View};
use crate::refpath::{ROUNDING_PASSES, RefPath};
use crate::tracker::{self, Sample, Tracker, TrackerParams, with_headings};
use crate::{Driver, ParamSpec, PolicyError, Sensors, default_values, rounded_count};

pub const NAME: &str = "lattice";
pub const ABOUT: &str =
    "Frenet lattice planner (quintic offsets, wall/obstacle/opponent checks) + pure pursuit";

/// Spacing of the samples along a candidate, m.
const SAMPLE_STEP: f64 = 0.2;
/// Length a candidate is continued at its goal offset beyond the goal, m.
const EXTENSION: f64 = 4.0;
/// Distance within which a predicted car adds proximity cost, m.
const PROXIMITY: f64 = 2.0;
/// Speed through a curve too tight for the steering, or past a wall the car is
/// already grazing, m/s.
const CREEP: f64 = 1.0;
/// How many parameters precede the tracker's in the vector.
const OWN_PARAMS: usize = 13;

/// The tunable parameters, in vector order.
pub fn param_specs() -> Vec<ParamSpec> {
    let p = ParamSpec::new;
    let mut specs = vec![
        p(
            "replan_every",
            15.0,
            1.0,
            50.0,
            "steps between replans (rounded)",
        ),
        p("horizon_min", 5.0, 1.0, 20.0, "shortest goal distance, m"),
        p(
            "horizon_time",
            0.8,
            0.1,
            3.0,
            "shortest goal distance in seconds at the current speed",
        ),
        p(
            "num_lengths",
            3.0,
            1.0,
            6.0,
            "goal distances sampled, from the shortest to twice it (rounded)",
        ),
        p(
            "lateral_span",
            1.2,
            0.0,
            4.0,
            "goal offsets span [-span, span] around the raceline, m",
        ),
        p(
            "num_offsets",
            9.0,
            1.0,
            25.0,
            "goal offsets sampled (rounded)",
        ),
        p(
            "wall_margin",
            0.05,
            0.0,
            0.5,
            "the car's box grows by this against walls, m",
        ),
        p(
            "car_margin",
            0.25,
            0.0,
            1.5,
            "the car's box grows by this against cars and obstacles, m",
        ),
        p(
            "w_offset",
            1.0,
            0.0,
            20.0,
            "cost per metre of mean offset from the raceline",
        ),
        p(
            "w_curvature",
            20.0,
            0.0,
            200.0,
            "cost per (1/m)^2 of mean squared extra curvature",
        ),
        p(
            "w_opponent",
            5.0,
            0.0,
            50.0,
            "cost of proximity to the other cars' predicted boxes",
        ),
        p(
            "w_change",
            0.5,
            0.0,
            20.0,
            "cost per metre of goal-offset change from the last plan",
        ),
        p(
            "w_progress",
            2.0,
            0.0,
            20.0,
            "cost of the fraction of reference speed the curvature takes away",
        ),
    ];
    specs.extend(tracker::param_specs(
        "multiplies the raceline's speed profile",
        "lateral acceleration allowed on the chosen path, m/s^2",
    ));
    specs
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LatticeParams {
    pub replan_every: usize,
    pub horizon_min: f64,
    pub horizon_time: f64,
    pub num_lengths: usize,
    pub lateral_span: f64,
    pub num_offsets: usize,
    pub wall_margin: f64,
    pub car_margin: f64,
    pub w_offset: f64,
    pub w_curvature: f64,
    pub w_opponent: f64,
    pub w_change: f64,
    pub w_progress: f64,
    /// The tracker's parameters (the vector's last [`tracker::NUM_PARAMS`]).
    #[serde(flatten)]
    pub tracker: TrackerParams,
    /// From the car (not tuned): body length and width.
    pub length: f64,
    pub width: f64,
}

impl Default for LatticeParams {
    fn default() -> Self {
        Self::from_vector(&default_values(&param_specs()), &VehicleParams::default())
            .expect("defaults are valid")
    }
}

impl LatticeParams {
    /// From a vector in [`param_specs`] order (bounds checked by the caller).
    pub fn from_vector(v: &[f64], vehicle: &VehicleParams) -> Result<Self, PolicyError> {
        let tracker = TrackerParams::after_own(NAME, v, OWN_PARAMS, vehicle)?;
        let p = Self {
            replan_every: rounded_count(v[0]),
            horizon_min: v[1],
            horizon_time: v[2],
            num_lengths: rounded_count(v[3]),
            lateral_span: v[4],
            num_offsets: rounded_count(v[5]),
            wall_margin: v[6],
            car_margin: v[7],
            w_offset: v[8],
            w_curvature: v[9],
            w_opponent: v[10],
            w_change: v[11],
            w_progress: v[12],
            tracker,
            length: vehicle.length,
            width: vehicle.width,
        };
        if p.num_offsets > 1 && p.lateral_span <= 0.0 {
            return Err(PolicyError::Invalid {
                driver: NAME.into(),
                message: format!(
                    "parameter lateral_span = {} must be > 0 when num_offsets = {} > 1",
                    p.lateral_span, p.num_offsets
                ),
            });
        }
        Ok(p)
    }
}

/// Where candidates start, in the raceline frame.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Start {
    s0: f64,
    d0: f64,
    /// dd/ds and d2d/ds2.
    p0: f64,
    a0: f64,
}

/// What a candidate runs into first.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Conflict {
    Static { sigma: f64 },
    Car { sigma: f64, speed: f64 },
    Curvature { sigma: f64 },
}

impl Conflict {
    fn sigma(&self) -> f64 {
        match *self {
            Conflict::Static { sigma }
            | Conflict::Car { sigma, .. }
            | Conflict::Curvature { sigma } => sigma,
        }
    }
}

#[derive(Debug, Clone)]
pub struct Lattice {
    pub params: LatticeParams,
    path: Arc<RefPath>,
    map: Arc<Map>,
    /// The plan being tracked.
    tracker: Tracker,
    ref_hint: Option<usize>,
    last_offset: f64,
    /// Work buffers.
    /// The other cars and the obstacles at the last replan.
    seen: Perception,
}

impl Lattice {
    pub fn new(circuit: &Circuit, params: LatticeParams) -> Self {
        Self {
            params,
            path: Arc::new(RefPath::from_circuit(circuit).smoothed(ROUNDING_PASSES)),
            map: circuit.map.clone(),
            tracker: Tracker::default(),
            ref_hint: None,
            last_offset: 0.0,
            seen: Perception::default(),
        }
    }

    fn perceive(&mut self, obs: &Observation, me: usize, pose: Pose) {
        let view = View {
            me,
            pose,
            own_s: Some(self.path.project(pose.x, pose.y, self.ref_hint).s),
            reach: self.horizon_max(obs.linear_vels_x[me]) + EXTENSION,
            length: self.params.length,
            width: self.params.width,
        };
        self.seen.observe(&self.path, &self.map, obs, view);
    }

    fn horizon_min(&self, speed: f64) -> f64 {
        self.params
            .horizon_min
            .max(self.params.horizon_time * speed.max(0.0))
    }

    fn horizon_max(&self, speed: f64) -> f64 {
        2.0 * self.horizon_min(speed)
    }

    /// The samples of the candidate from Frenet state (s0, d0, slope p0 = dd/ds,
    /// second derivative a0) to offset `dg` at distance `len` along the raceline, then
    /// held at `dg` up to `total` metres.
    fn candidate(&self, start: Start, dg: f64, len: f64, total: f64) -> Vec<Sample> {
        let Start { s0, d0, p0, a0 } = start;
        // d(t) = d0 + p0 L t + a t^2 + c3 t^3 + c4 t^4 + c5 t^5, t = u / L, with
        // d(1) = dg and d'(1) = d''(1) = 0
        let a = 0.5 * a0 * len * len;
        let h = dg - d0 - p0 * len - a;
        let q = -p0 * len - 2.0 * a;
        let r = -2.0 * a;
        let (c3, c4, c5) = (
            10.0 * h - 4.0 * q + 0.5 * r,
            7.0 * q - 15.0 * h - r,
            6.0 * h - 3.0 * q + 0.5 * r,
        );
        let count = (total / SAMPLE_STEP).ceil() as usize;
        let mut out: Vec<Sample> = Vec::with_capacity(count + 1);
        for k in 0..=count {
            let u = (k as f64 * SAMPLE_STEP).min(total);
            let d = if u < len {
                let t = u / len;
                d0 + p0 * len * t + a * t * t + t * t * t * (c3 + t * (c4 + t * c5))
            } else {
                dg
            };
            let (x, y, _) = self.path.to_world(s0 + u, d);
            out.push(Sample::after(out.last(), x, y, s0 + u, d));
        }
        with_headings(&mut out);
        out
    }

    /// The first conflict along the candidate (up to its goal) and the proximity cost.
    fn check(&self, c: &[Sample], len: f64, speed: f64) -> (Option<Conflict>, f64) {
        let p = &self.params;
        let kappa_max = p.tracker.kappa_max();
        let v_time = speed.max(1.0);
        let mut proximity = 0.0;
        let grow = |o: &Obb, m: f64| Obb {
            half_length: o.half_length + m,
            half_width: o.half_width + m,
            ..*o
        };
        for smp in c.iter().filter(|smp| smp.s - c[0].s <= len) {
            let body = Obb::car(Pose::new(smp.x, smp.y, smp.heading), p.length, p.width);
            if smp.kappa.abs() > kappa_max && smp.sigma > 0.5 {
                return (Some(Conflict::Curvature { sigma: smp.sigma }), proximity);
            }
            let walls = grow(&body, p.wall_margin);
            if self.map.clearance(smp.x, smp.y) <= walls.circumradius()
                && obb_hits_map(&walls, &self.map)
            {
                return (Some(Conflict::Static { sigma: smp.sigma }), proximity);
            }
            let wide = grow(&body, p.car_margin);
            let (cs, sn) = (libm::cos(smp.heading), libm::sin(smp.heading));
            let r2 = wide.circumradius() * wide.circumradius();
            for &(ox, oy) in &self.seen.obstacles {
                let (dx, dy) = (ox - smp.x, oy - smp.y);
                if dx * dx + dy * dy > r2 {
                    continue;
                }
                let (u, v) = (dx * cs + dy * sn, -dx * sn + dy * cs);
                if u.abs() <= wide.half_length && v.abs() <= wide.half_width {
                    return (Some(Conflict::Static { sigma: smp.sigma }), proximity);
                }
            }
            let t = smp.sigma / v_time;
            for o in self.seen.others.iter().filter(|o| !o.behind) {
                let travel = o.vs * t;
                let (x, y, psi) = self.path.to_world(o.s + travel, o.d);
                let dist = libm::hypot(x - smp.x, y - smp.y);
                if dist > 3.0 {
                    continue;
                }
                proximity += (1.0 - dist / PROXIMITY).max(0.0).powi(2) * SAMPLE_STEP;
                let mut theirs = grow(
                    &Obb::car(Pose::new(x, y, psi + o.e), p.length, p.width),
                    p.car_margin,
                );
                theirs.half_length += 0.1 * travel.abs();
                if obb_overlap(&body, &theirs) {
                    return (
                        Some(Conflict::Car {
                            sigma: smp.sigma,
                            speed: o.vs.max(0.0),
                        }),
                        proximity,
                    );
                }
            }
        }
        (None, proximity)
    }

    /// Speed limits along the chosen path.
    fn speed_plan(&self, c: &mut [Sample], conflict: Option<Conflict>) {
        // a curve too tight for the steering is still driven, slowly (the tracker turns
        // at full lock); stopping there would leave the car stuck for good
        let (stop_at, v_at) = match conflict {
            None => (f64::INFINITY, f64::INFINITY),
            Some(Conflict::Car { sigma, speed }) => (sigma - 0.3, speed),
            Some(Conflict::Curvature { sigma }) => (sigma - 0.5, CREEP),
            Some(Conflict::Static { sigma }) if sigma < 0.6 => (0.0, CREEP),
            Some(Conflict::Static { sigma }) => (sigma - 0.5, 0.0),
        };
        self.params.tracker.speed_plan(&self.path, c, |smp| {
            if smp.sigma >= stop_at {
                v_at
            } else {
                f64::INFINITY
            }
        });
    }

    /// Continue the current plan where the car is on it (its offset, slope and
    /// curvature there, so a replan keeps the plan's turn and the tracker alone corrects
    /// tracking errors), or start at the car's offset along the raceline when there is
    /// no plan (or the car has left it).
    fn start_state(&self, s: f64, d: f64, e: f64) -> Start {
        let own = Start {
            s0: s,
            d0: d,
            p0: libm::tan(e.clamp(-1.0, 1.0)),
            a0: 0.0,
        };
        let plan = self.tracker.plan();
        if plan.len() < 3 {
            return own;
        }
        // the plan's samples bracketing the car's arc length
        let s_car = plan[0].s + self.path.ds(plan[0].s, s);
        let Some(k) = (0..plan.len() - 1).find(|&k| plan[k].s <= s_car && s_car < plan[k + 1].s)
        else {
            return own;
        };
        let (a, b, c) = (&plan[k.saturating_sub(1)], &plan[k], &plan[k + 1]);
        let h1 = if k == 0 { 1.0 } else { b.s - a.s };
        let h2 = c.s - b.s;
        if h1 <= 1e-9 || h2 <= 1e-9 {
            return own;
        }
        let slope = (c.d - b.d) / h2;
        let second = if k == 0 {
            0.0
        } else {
            2.0 * ((c.d - b.d) / h2 - (b.d - a.d) / h1) / (h1 + h2)
        };
        let d_plan = b.d + (s_car - b.s) / h2 * (c.d - b.d);
        Start {
            s0: s_car,
            d0: d_plan,
            p0: slope,
            a0: second,
        }
    }

    fn replan(&mut self, pose: Pose, speed: f64) {
        let p = self.params.clone();
        let f = self.path.project(pose.x, pose.y, self.ref_hint);
        self.ref_hint = Some(f.index);
        let start = self.start_state(f.s, f.d, wrap_angle(pose.theta - f.psi));
        let l0 = self.horizon_min(speed);
        // every candidate covers the same window, so their costs compare
        let window = self.horizon_max(speed);
        let mut best: Option<(f64, Vec<Sample>, f64)> = None; // cost, samples, offset
        let mut fallback: Option<(f64, f64, Vec<Sample>, Conflict, f64)> = None;
        for li in 0..p.num_lengths {
            let len = if p.num_lengths > 1 {
                l0 * (1.0 + li as f64 / (p.num_lengths - 1) as f64)
            } else {
                l0
            };
            for oi in 0..p.num_offsets {
                let dg = if p.num_offsets > 1 {
                    -p.lateral_span + 2.0 * p.lateral_span * oi as f64 / (p.num_offsets - 1) as f64
                } else {
                    0.0
                };
                let c = self.candidate(start, dg, len, window + EXTENSION);
                let (conflict, proximity) = self.check(&c, window, speed);
                let within: Vec<&Sample> = c.iter().filter(|s| s.s - f.s <= window).collect();
                let count = within.len().max(1) as f64;
                let mean_offset = within.iter().map(|s| s.d.abs()).sum::<f64>() / count;
                let extra_curv = within
                    .iter()
                    .map(|s| {
                        let k = s.kappa - self.path.at(s.s).kappa;
                        k * k
                    })
                    .sum::<f64>()
                    / count;
                let max_kappa = within.iter().fold(0.0f64, |m, s| m.max(s.kappa.abs()));
                let lost = p.tracker.speed_lost(&self.path, f.s, max_kappa);
                let cost = p.w_offset * mean_offset
                    + p.w_curvature * extra_curv
                    + p.w_opponent * proximity
                    + p.w_change * (dg - self.last_offset).abs()
                    + p.w_progress * lost;
                match conflict {
                    None => {
                        if best.as_ref().is_none_or(|b| cost < b.0) {
                            best = Some((cost, c, dg));
                        }
                    }
                    Some(conflict) => {
                        let reach = conflict.sigma();
                        if fallback.as_ref().is_none_or(|b| {
                            reach > b.0 + 1e-9 || (reach > b.0 - 1e-9 && cost < b.1)
                        }) {
                            fallback = Some((reach, cost, c, conflict, dg));
                        }
                    }
                }
            }
        }
        let (mut plan, conflict, offset) = match (best, fallback) {
            (Some((_, c, dg)), _) => (c, None, dg),
            (None, Some((_, _, c, conflict, dg))) => (c, Some(conflict), dg),
            (None, None) => (Vec::new(), None, 0.0),
        };
        self.speed_plan(&mut plan, conflict);
        self.tracker.set_plan(plan);
        self.last_offset = offset;
    }

    /// The action for a car at `pose` moving at `speed`; `obs` gives the others.
    fn drive(&mut self, obs: &Observation, me: usize) -> Action {
        let pose = Pose::new(obs.poses_x[me], obs.poses_y[me], obs.poses_theta[me]);
        let speed = obs.linear_vels_x[me];
        if self.tracker.due(pose, self.params.replan_every) {
            self.perceive(obs, me, pose);
            self.replan(pose, speed);
        }
        self.tracker.follow(&self.params.tracker, pose, speed)
    }
}

impl Driver for Lattice {
    fn name(&self) -> &'static str {
        NAME
    }

    fn sensors(&self) -> Sensors {
        Sensors { lidar: true }
    }

    fn reset(&mut self) {
        self.tracker.reset();
        self.ref_hint = None;
        self.last_offset = 0.0;
    }

    fn act(&mut self, obs: &Observation, me: usize) -> Action {
        self.drive(obs, me)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quintic_meets_its_boundary_conditions() {
        let c = paddock_sim::circuit::Circuits::new()
            .get("lakeside")
            .expect("shipped map");
        let l = Lattice::new(&c, LatticeParams::default());
        let start = Start {
            s0: 10.0,
            d0: 0.4,
            p0: 0.2,
            a0: 0.0,
        };
        let path = l.candidate(start, -0.6, 5.0, 9.0);
        assert!((path[0].d - 0.4).abs() < 1e-12);
        let goal = path.iter().find(|s| s.s >= 15.0 - 1e-9).expect("goal");
        assert!((goal.d + 0.6).abs() < 1e-9, "{}", goal.d);
        // slope at the start: one small step
        let slope = (path[1].d - path[0].d) / SAMPLE_STEP;
        assert!((slope - 0.2).abs() < 0.05, "{slope}");
    }
}
