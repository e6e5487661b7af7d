//! RRT* in the driving line's Frenet frame, with a pure-pursuit tracking controller, for
//! racing against others.
//!
//! Every `replan_every` steps (receding horizon) the planner grows a tree from the car's
//! Frenet state (arc length `s`, offset `d` from the driving line) over a window `H`
//! metres ahead (`horizon_min`, or `horizon_time` seconds at the current speed if
//! farther). A node is a point (u, d) with u = s - s_car in [0, H] and d in
//! [-`lateral_span`, `lateral_span`]; an edge is the straight segment between two nodes in
//! that frame (a path that follows the track's bends), always forward (u grows), with a
//! lateral slope |dd/du| of at most `max_slope`. Each of `iterations` samples (the goal,
//! (H, 0), with probability `goal_bias`; otherwise uniform in the window) is joined to its
//! nearest node, cut to `step_size`; the new node takes the cheapest collision-free parent
//! within `rewire_radius`, then rewires its neighbours through itself when that is
//! cheaper (the RRT* steps of Karaman and Frazzoli). The previous plan's waypoints are
//! sampled first, so a good plan survives from one replan to the next.
//!
//! Edge cost: its length, plus `w_offset` x the mean |offset| x its length along the
//! track (the driving line is the fastest way round), plus `w_opponent` x a proximity
//! penalty to the other cars' predicted boxes. An edge is in collision when, sampled every
//! 0.2 m, the car's box grown by `wall_margin` touches a wall of the map, the box grown by
//! `car_margin` holds a LIDAR return that is not a wall and not another car (a static
//! obstacle), or it overlaps another car's predicted box at the time the car would get
//! there (the other car keeps its speed along the driving line at its current offset;
//! its box grows by `car_margin` plus 10 % of its predicted travel).
//!
//! The plan is the cheapest node that reaches 90 % of the window (or, when none does, the
//! node that gets farthest: the speed plan then stops at its end, or matches the speed of
//! a car in the way), smoothed by a moving average of the offsets where that stays clear
//! of walls and obstacles. It is tracked by the planners' shared tracker
//! ([`crate::tracker`]: pure pursuit, lookahead `lookahead_min` + `lookahead_gain` x
//! speed, with a cross-track term). Speed: the driving line's profile times
//! `speed_scale`, capped by `max_speed` and by sqrt(`lat_accel` / |curvature|) of the
//! plan, with a backward pass at `brake_decel`.
//!
//! Deterministic: the sampler is a seeded PRNG re-seeded at every reset and at the first
//! step from the car's start pose, so an episode stays a pure function of its scenario
//! and seed. Reads the LIDAR (obstacles) and the other cars' poses and speeds
//! ([`crate::perception`]).

use std::sync::Arc;

use paddock_sim::circuit::Circuit;
use paddock_sim::collision::{obb_hits_map, obb_overlap};
use paddock_sim::geometry::{Obb, Pose};
use paddock_sim::map::Map;
use paddock_sim::params::VehicleParams;
use paddock_sim::rng::Rng;
use paddock_sim::world::{Action, Observation};
use serde::{Deserialize, Serialize};

use crate::perception::{Perception, View};
use crate::refpath::RefPath;
use crate::tracker::{self, Sample, Tracker, TrackerParams, with_headings};
use crate::{Driver, ParamSpec, PolicyError, Sensors, default_values, rounded_count};

pub const NAME: &str = "rrt-star";
pub const ABOUT: &str = "RRT* in the driving line's Frenet frame (walls, obstacles, predicted opponents) + pure pursuit";

/// Spacing of collision checks and plan samples along u, m.
const SAMPLE_STEP: f64 = 0.2;
/// The plan continues at its last offset this far beyond its end, m (for the lookahead).
const EXTENSION: f64 = 3.0;
/// Walls are not checked this close to the root (the car is already there), m.
const ROOT_FREE: f64 = 0.4;
/// Distance within which a predicted car adds proximity cost, m.
const PROXIMITY: f64 = 2.0;
/// How many parameters precede the tracker's in the vector.
const OWN_PARAMS: usize = 13;
/// A plan that stops short of this (m) because of walls leaves the car stuck.
const STUCK_REACH: f64 = 1.0;
/// Speed while rejoining the driving line from a stuck plan, m/s.
const CREEP: f64 = 1.0;
/// Half-width of the moving average that smooths the plan's offsets, samples.
const SMOOTH_HALF: usize = 3;

mod params;
pub use params::{RrtStarParams, param_specs};

/// A tree node in the window's frame: u metres ahead of the car along the driving line,
/// offset d.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Node {
    u: f64,
    d: f64,
    parent: usize,
    cost: f64,
}

/// Why an edge is not free.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Blocked {
    Static,
    Car { speed: f64 },
}

#[derive(Debug, Clone)]
pub struct RrtStar {
    pub params: RrtStarParams,
    path: Arc<RefPath>,
    map: Arc<Map>,
    rng: Rng,
    seeded: bool,
    /// The current plan rejoins the driving line at creep speed.
    creep: bool,
    /// The plan being tracked and the tree's waypoints it came from (s, d).
    tracker: Tracker,
    waypoints: Vec<(f64, f64)>,
    ref_hint: Option<usize>,
    /// Per-replan context.
    s0: f64,
    v_time: f64,
    /// The other cars and the obstacles at the last replan.
    seen: Perception,
    nodes: Vec<Node>,
}

impl RrtStar {
    pub fn new(circuit: &Circuit, params: RrtStarParams) -> Self {
        Self {
            params,
            path: Arc::new(RefPath::from_circuit(circuit)),
            map: circuit.map.clone(),
            rng: Rng::new(0),
            seeded: false,
            creep: false,
            tracker: Tracker::default(),
            waypoints: Vec::new(),
            ref_hint: None,
            s0: 0.0,
            v_time: 1.0,
            seen: Perception::default(),
            nodes: Vec::new(),
        }
    }

    fn horizon(&self, speed: f64) -> f64 {
        self.params
            .horizon_min
            .max(self.params.horizon_time * speed.max(0.0))
    }

    fn perceive(&mut self, obs: &Observation, me: usize, pose: Pose, reach: f64) {
        let view = View {
            me,
            pose,
            own_s: None,
            reach,
            length: self.params.length,
            width: self.params.width,
        };
        self.seen.observe(&self.path, &self.map, obs, view);
    }

    /// Is the car's box at (u, d) heading along slope `slope` clear of walls and
    /// obstacles?
    fn static_free(&self, u: f64, d: f64, slope: f64) -> bool {
        let p = &self.params;
        let (x, y, psi) = self.path.to_world(self.s0 + u, d);
        let heading = psi + libm::atan(slope);
        let body = Obb::car(Pose::new(x, y, heading), p.length, p.width);
        if u > ROOT_FREE {
            let walls = Obb {
                half_length: body.half_length + p.wall_margin,
                half_width: body.half_width + p.wall_margin,
                ..body
            };
            if self.map.clearance(x, y) <= walls.circumradius() && obb_hits_map(&walls, &self.map) {
                return false;
            }
        }
        let (hl, hw) = (
            body.half_length + p.car_margin,
            body.half_width + p.car_margin,
        );
        let r2 = hl * hl + hw * hw;
        let (sn, cs) = libm::sincos(heading);
        !self.seen.obstacles.iter().any(|&(ox, oy)| {
            let (dx, dy) = (ox - x, oy - y);
            if dx * dx + dy * dy > r2 {
                return false;
            }
            let (a, b) = (dx * cs + dy * sn, -dx * sn + dy * cs);
            a.abs() <= hl && b.abs() <= hw
        })
    }

    /// Check the edge a -> b: Ok(proximity cost) or what blocks it.
    fn edge(&self, a: (f64, f64), b: (f64, f64)) -> Result<f64, Blocked> {
        let p = &self.params;
        let du = b.0 - a.0;
        let slope = (b.1 - a.1) / du;
        let n = libm::ceil(du / SAMPLE_STEP).max(1.0) as usize;
        let mut proximity = 0.0;
        for k in 1..=n {
            let u = a.0 + du * k as f64 / n as f64;
            let d = a.1 + slope * (u - a.0);
            if !self.static_free(u, d, slope) {
                return Err(Blocked::Static);
            }
            if self.seen.others.is_empty() {
                continue;
            }
            let (x, y, psi) = self.path.to_world(self.s0 + u, d);
            let body = Obb::car(Pose::new(x, y, psi + libm::atan(slope)), p.length, p.width);
            let t = u / self.v_time;
            for o in &self.seen.others {
                let travel = o.vs * t;
                let (ox, oy, opsi) = self.path.to_world(o.s + travel, o.d);
                let dist = libm::hypot(ox - x, oy - y);
                if dist > 3.0 {
                    continue;
                }
                proximity += (1.0 - dist / PROXIMITY).max(0.0).powi(2) * du / n as f64;
                let mut theirs = Obb::car(Pose::new(ox, oy, opsi + o.e), p.length, p.width);
                theirs.half_length += p.car_margin + 0.1 * travel.abs();
                theirs.half_width += p.car_margin;
                if obb_overlap(&body, &theirs) {
                    return Err(Blocked::Car {
                        speed: o.vs.max(0.0),
                    });
                }
            }
        }
        Ok(proximity)
    }

    fn edge_cost(&self, a: (f64, f64), b: (f64, f64), proximity: f64) -> f64 {
        let p = &self.params;
        let du = b.0 - a.0;
        libm::hypot(du, b.1 - a.1)
            + p.w_offset * 0.5 * (a.1.abs() + b.1.abs()) * du
            + p.w_opponent * proximity
    }

    /// Grow the tree; returns the waypoints (u, d) of the plan and, for a plan that stops
    /// short of the window, the speed to end at.
    fn grow(&mut self, d0: f64, horizon: f64) -> (Vec<(f64, f64)>, Option<f64>) {
        let p = self.params.clone();
        self.nodes.clear();
        self.nodes.push(Node {
            u: 0.0,
            d: d0,
            parent: 0,
            cost: 0.0,
        });
        let mut end_speed: Option<f64> = None;
        // the previous plan's waypoints first, then random samples
        let warm: Vec<(f64, f64)> = self
            .waypoints
            .iter()
            .map(|&(s, d)| (self.path.ds(self.s0, s), d))
            .filter(|&(u, _)| u > 0.1 && u <= horizon)
            .collect();
        for it in 0..warm.len() + p.iterations {
            let target = if it < warm.len() {
                warm[it]
            } else if self.rng.uniform() < p.goal_bias {
                (horizon, 0.0)
            } else {
                (
                    self.rng.uniform_range(0.0, horizon),
                    self.rng.uniform_range(-p.lateral_span, p.lateral_span),
                )
            };
            // nearest node behind the sample
            let Some(near) = (0..self.nodes.len())
                .filter(|&i| self.nodes[i].u < target.0 - 1e-6)
                .min_by(|&i, &j| {
                    let di = dist2(&self.nodes[i], target);
                    let dj = dist2(&self.nodes[j], target);
                    di.total_cmp(&dj).then(i.cmp(&j))
                })
            else {
                continue;
            };
            let from = (self.nodes[near].u, self.nodes[near].d);
            let mut to = target;
            let len = libm::hypot(to.0 - from.0, to.1 - from.1);
            if len > p.step_size {
                let k = p.step_size / len;
                to = (from.0 + k * (to.0 - from.0), from.1 + k * (to.1 - from.1));
            }
            let du = to.0 - from.0;
            if du < 0.05 {
                continue;
            }
            // keep the slope within the limit
            let lim = p.max_slope * du;
            to.1 = from.1 + (to.1 - from.1).clamp(-lim, lim);
            // cheapest free parent among the neighbours
            let mut best: Option<(usize, f64)> = None;
            let mut blocked_by_car: Option<f64> = None;
            for i in 0..self.nodes.len() {
                let n = self.nodes[i];
                let du = to.0 - n.u;
                if du < 0.05
                    || (to.1 - n.d).abs() > p.max_slope * du
                    || (i != near && dist2(&n, to) > p.rewire_radius * p.rewire_radius)
                {
                    continue;
                }
                let cost_here = n.cost + self.edge_cost((n.u, n.d), to, 0.0);
                if best.is_some_and(|b| cost_here >= b.1) {
                    continue;
                }
                match self.edge((n.u, n.d), to) {
                    Ok(prox) => {
                        let c = n.cost + self.edge_cost((n.u, n.d), to, prox);
                        if best.is_none_or(|b| c < b.1) {
                            best = Some((i, c));
                        }
                    }
                    Err(Blocked::Car { speed }) => blocked_by_car = Some(speed),
                    Err(Blocked::Static) => {}
                }
            }
            let Some((parent, cost)) = best else {
                if let Some(v) = blocked_by_car {
                    end_speed = Some(end_speed.map_or(v, |e: f64| e.min(v)));
                }
                continue;
            };
            let new = self.nodes.len();
            self.nodes.push(Node {
                u: to.0,
                d: to.1,
                parent,
                cost,
            });
            // rewire the neighbours ahead through the new node
            for i in 1..new {
                let n = self.nodes[i];
                let du = n.u - to.0;
                if du < 0.05
                    || (n.d - to.1).abs() > p.max_slope * du
                    || dist2(&n, to) > p.rewire_radius * p.rewire_radius
                {
                    continue;
                }
                if cost + self.edge_cost(to, (n.u, n.d), 0.0) >= n.cost {
                    continue;
                }
                if let Ok(prox) = self.edge(to, (n.u, n.d)) {
                    let c = cost + self.edge_cost(to, (n.u, n.d), prox);
                    if c < n.cost {
                        let delta = c - n.cost;
                        self.nodes[i].parent = new;
                        self.nodes[i].cost = c;
                        self.shift_subtree(i, delta);
                    }
                }
            }
        }
        // the cheapest node across the window, else the one that gets farthest
        let reach = 0.9 * horizon;
        let goal = (0..self.nodes.len())
            .filter(|&i| self.nodes[i].u >= reach)
            .min_by(|&i, &j| self.nodes[i].cost.total_cmp(&self.nodes[j].cost));
        let (goal, stop) = match goal {
            Some(g) => (g, None),
            None => {
                let g = (0..self.nodes.len())
                    .max_by(|&i, &j| {
                        self.nodes[i]
                            .u
                            .total_cmp(&self.nodes[j].u)
                            .then(self.nodes[j].cost.total_cmp(&self.nodes[i].cost))
                    })
                    .unwrap_or(0);
                (g, Some(end_speed.unwrap_or(0.0)))
            }
        };
        let mut chain = vec![goal];
        let mut i = goal;
        while i != 0 && chain.len() <= self.nodes.len() {
            i = self.nodes[i].parent;
            chain.push(i);
        }
        chain.reverse();
        (
            chain
                .iter()
                .map(|&i| (self.nodes[i].u, self.nodes[i].d))
                .collect(),
            stop,
        )
    }

    /// Add `delta` to the cost of every descendant of node `root`.
    fn shift_subtree(&mut self, root: usize, delta: f64) {
        let mut stack = vec![root];
        let mut guard = 0;
        while let Some(k) = stack.pop() {
            guard += 1;
            if guard > self.nodes.len() {
                break;
            }
            for j in 1..self.nodes.len() {
                if j != k && self.nodes[j].parent == k {
                    self.nodes[j].cost += delta;
                    stack.push(j);
                }
            }
        }
    }

    /// The plan's samples from waypoints (u, d): linear in u between them, smoothed where
    /// the smoothing stays clear, extended at the last offset.
    fn samples(&self, waypoints: &[(f64, f64)]) -> Vec<Sample> {
        let end = waypoints.last().map_or(0.0, |w| w.0);
        let count = libm::ceil(end / SAMPLE_STEP).max(1.0) as usize;
        let mut us: Vec<f64> = (0..=count)
            .map(|k| (k as f64 * SAMPLE_STEP).min(end))
            .collect();
        let mut ds: Vec<f64> = us
            .iter()
            .map(|&u| {
                let k = waypoints
                    .windows(2)
                    .position(|w| u <= w[1].0)
                    .unwrap_or(waypoints.len().saturating_sub(2));
                match (waypoints.get(k), waypoints.get(k + 1)) {
                    (Some(a), Some(b)) if b.0 > a.0 => a.1 + (b.1 - a.1) * (u - a.0) / (b.0 - a.0),
                    (Some(a), _) => a.1,
                    _ => 0.0,
                }
            })
            .collect();
        // moving average, endpoints held; kept only if it stays clear
        let m = ds.len();
        if m > 2 * SMOOTH_HALF + 1 {
            let mut smooth = ds.clone();
            for _ in 0..2 {
                let prev = smooth.clone();
                for (k, v) in smooth.iter_mut().enumerate().take(m - 1).skip(1) {
                    let (a, b) = (k.saturating_sub(SMOOTH_HALF), (k + SMOOTH_HALF).min(m - 1));
                    *v = prev[a..=b].iter().sum::<f64>() / (b - a + 1) as f64;
                }
            }
            let clear = (1..m).all(|k| {
                let slope = (smooth[k] - smooth[k - 1]) / (us[k] - us[k - 1]).max(1e-9);
                self.static_free(us[k], smooth[k], slope)
            });
            if clear {
                ds = smooth;
            }
        }
        let last = *ds.last().unwrap_or(&0.0);
        let extra = libm::ceil(EXTENSION / SAMPLE_STEP) as usize;
        for k in 1..=extra {
            us.push(end + k as f64 * SAMPLE_STEP);
            ds.push(last);
        }
        let mut out: Vec<Sample> = Vec::with_capacity(us.len());
        for (&u, &d) in us.iter().zip(&ds) {
            let (x, y, _) = self.path.to_world(self.s0 + u, d);
            let smp = Sample::after(out.last(), x, y, self.s0 + u, d);
            if out.last().is_some_and(|prev| smp.sigma - prev.sigma < 1e-9) {
                continue;
            }
            out.push(smp);
        }
        with_headings(&mut out);
        out
    }

    /// Speed limits along the plan; `stop` ends a plan that is short of the window at
    /// that speed.
    fn speed_plan(&self, c: &mut [Sample], plan_end: f64, stop: Option<f64>) {
        let creep = if self.creep { CREEP } else { f64::INFINITY };
        self.params
            .tracker
            .speed_plan(&self.path, c, |smp| match stop {
                Some(v_end) if smp.s - self.s0 >= plan_end - 0.3 => creep.min(v_end),
                _ => creep,
            });
    }

    fn replan(&mut self, obs: &Observation, me: usize, pose: Pose, speed: f64) {
        let f = self.path.project(pose.x, pose.y, self.ref_hint);
        self.ref_hint = Some(f.index);
        self.s0 = f.s;
        self.v_time = speed.max(1.0);
        let horizon = self.horizon(speed);
        self.perceive(obs, me, pose, horizon + EXTENSION);
        let (mut waypoints, mut stop) = self.grow(f.d, horizon);
        let mut end = waypoints.last().map_or(0.0, |w| w.0);
        if stop == Some(0.0) && end < STUCK_REACH && !self.obstacle_ahead(pose) {
            // walls block every way out (a hairpin the frame folds over, a car pressed
            // against a wall): rejoin the driving line itself, slowly
            waypoints = vec![(0.0, 0.0), (horizon, 0.0)];
            end = horizon;
            stop = None;
            self.creep = true;
        } else {
            self.creep = false;
        }
        let mut plan = self.samples(&waypoints);
        self.speed_plan(&mut plan, end, stop);
        self.waypoints = waypoints
            .iter()
            .skip(1)
            .map(|&(u, d)| (self.s0 + u, d))
            .collect();
        self.tracker.set_plan(plan);
    }

    /// Is a LIDAR obstacle within a car length ahead of the car?
    fn obstacle_ahead(&self, pose: Pose) -> bool {
        let (sn, cs) = libm::sincos(pose.theta);
        let reach = self.params.length + self.params.car_margin + 0.5;
        self.seen.obstacles.iter().any(|&(ox, oy)| {
            let (dx, dy) = (ox - pose.x, oy - pose.y);
            let (a, b) = (dx * cs + dy * sn, -dx * sn + dy * cs);
            a > 0.0 && a < reach && b.abs() < self.params.width + self.params.car_margin
        })
    }

    fn drive(&mut self, obs: &Observation, me: usize) -> Action {
        let pose = Pose::new(obs.poses_x[me], obs.poses_y[me], obs.poses_theta[me]);
        let speed = obs.linear_vels_x[me];
        if !self.seeded {
            // the sampler's stream follows from the start pose (itself from the seed)
            let mix = pose.x.to_bits()
                ^ pose.y.to_bits().rotate_left(21)
                ^ pose.theta.to_bits().rotate_left(42);
            self.rng = Rng::new(mix);
            self.seeded = true;
        }
        if self.tracker.due(pose, self.params.replan_every) {
            self.replan(obs, me, pose, speed);
        }
        self.tracker.follow(&self.params.tracker, pose, speed)
    }
}

fn dist2(n: &Node, p: (f64, f64)) -> f64 {
    (n.u - p.0) * (n.u - p.0) + (n.d - p.1) * (n.d - p.1)
}

impl Driver for RrtStar {
    fn name(&self) -> &'static str {
        NAME
    }

    fn sensors(&self) -> Sensors {
        Sensors { lidar: true }
    }

    fn reset(&mut self) {
        self.rng = Rng::new(0);
        self.seeded = false;
        self.creep = false;
        self.tracker.reset();
        self.waypoints.clear();
        self.ref_hint = None;
    }

    fn act(&mut self, obs: &Observation, me: usize) -> Action {
        self.drive(obs, me)
    }
}
