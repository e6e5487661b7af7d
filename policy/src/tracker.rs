//! The path tracker the planners (lattice, RRT*) share: pure pursuit with a cross-track
//! term along a sampled plan, and the plan's speed limits.
//!
//! Steering: aim at the plan point `lookahead_min` + `lookahead_gain` x speed ahead of
//! the car's nearest plan point, steer the circle through it, and subtract a Stanley-like
//! term `atan(track_gain x cross-track error / (speed + 1))` (the lookahead alone corrects
//! an offset from the plan slowly at speed). Speed: the plan's limit a quarter second
//! ahead. The limits are the driving line's speed profile times `speed_scale`, capped by
//! `max_speed` and by sqrt(`lat_accel` / |curvature|) of the plan (and by whatever the
//! planner adds), with a backward pass at `brake_decel` so the car slows in time.
//!
//! A planner replans when the car is more than `OFF_PLAN` (0.4 m) from its plan, near the
//! plan's end, or every `replan_every` steps ([`Tracker::due`]).

use paddock_sim::geometry::{Pose, wrap_angle};
use paddock_sim::params::VehicleParams;
use paddock_sim::world::Action;
use serde::{Deserialize, Serialize};

use crate::refpath::RefPath;
use crate::{ParamSpec, PolicyError};

/// How many tunable parameters the tracker has (they end each planner's vector).
pub const NUM_PARAMS: usize = 7;

/// Replan when the car is this far from its plan, m.
const OFF_PLAN: f64 = 0.4;
/// Replan when the car is within this many samples of the plan's end.
const END_SAMPLES: usize = 5;

/// The tracker's tunable parameters, in vector order. The planners word the path they
/// track differently, so the two docs that name it are theirs.
pub fn param_specs(speed_scale_doc: &'static str, lat_accel_doc: &'static str) -> Vec<ParamSpec> {
    vec![
        ParamSpec::new(
            "lookahead_min",
            0.8,
            0.3,
            3.0,
            "pure-pursuit lookahead at standstill, m",
        ),
        ParamSpec::new(
            "lookahead_gain",
            0.15,
            0.0,
            0.6,
            "pure-pursuit lookahead growth with speed, s",
        ),
        ParamSpec::new(
            "track_gain",
            0.5,
            0.0,
            10.0,
            "cross-track gain of the tracker (Stanley-like term), 1/s",
        ),
        ParamSpec::new("speed_scale", 0.85, 0.2, 1.5, speed_scale_doc),
        ParamSpec::new("lat_accel", 3.0, 1.0, 15.0, lat_accel_doc),
        ParamSpec::new("max_speed", 5.0, 1.0, 20.0, "speed cap, m/s"),
        ParamSpec::new(
            "brake_decel",
            5.0,
            1.0,
            15.0,
            "deceleration the speed plan assumes, m/s^2",
        ),
    ]
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrackerParams {
    pub lookahead_min: f64,
    pub lookahead_gain: f64,
    pub track_gain: f64,
    pub speed_scale: f64,
    pub lat_accel: f64,
    pub max_speed: f64,
    pub brake_decel: f64,
    /// From the car (not tuned): wheelbase and steering limit.
    pub wheelbase: f64,
    pub steer_max: f64,
}

impl TrackerParams {
    /// From the [`NUM_PARAMS`] values in [`param_specs`] order (bounds checked by the
    /// caller).
    pub fn from_vector(v: &[f64; NUM_PARAMS], vehicle: &VehicleParams) -> Self {
        Self {
            lookahead_min: v[0],
            lookahead_gain: v[1],
            track_gain: v[2],
            speed_scale: v[3],
            lat_accel: v[4],
            max_speed: v[5],
            brake_decel: v[6],
            wheelbase: vehicle.lf + vehicle.lr,
            steer_max: vehicle.s_max.min(-vehicle.s_min),
        }
    }

    /// The tracker's parameters from a planner's vector `v`: its first `own` values are
    /// the planner's, the last [`NUM_PARAMS`] the tracker's. Errors when `v` has not
    /// `own` + [`NUM_PARAMS`] values, so the planner may index its own.
    pub fn after_own(
        driver: &str,
        v: &[f64],
        own: usize,
        vehicle: &VehicleParams,
    ) -> Result<Self, PolicyError> {
        match v.get(own..).map(<&[f64; NUM_PARAMS]>::try_from) {
            Some(Ok(tail)) => Ok(Self::from_vector(tail, vehicle)),
            _ => Err(PolicyError::ParamCount {
                driver: driver.into(),
                expected: own + NUM_PARAMS,
                got: v.len(),
            }),
        }
    }

    /// The largest curvature the steering allows, 1/m.
    pub fn kappa_max(&self) -> f64 {
        libm::tan(self.steer_max) / self.wheelbase
    }

    /// The speed a curve of curvature `kappa` allows.
    fn curve_speed(&self, kappa: f64) -> f64 {
        if kappa.abs() > 1e-6 {
            libm::sqrt(self.lat_accel / kappa.abs())
        } else {
            f64::INFINITY
        }
    }

    /// The fraction of the reference speed at `s` that a path whose largest |curvature|
    /// is `max_kappa` takes away.
    pub fn speed_lost(&self, path: &RefPath, s: f64, max_kappa: f64) -> f64 {
        let v_ref = path.at(s).vx * self.speed_scale;
        let v_curve = self.curve_speed(max_kappa);
        if v_ref > 0.0 {
            (1.0 - v_curve / v_ref).max(0.0)
        } else {
            0.0
        }
    }

    /// Speed limits along `plan`: the driving line's profile, the curvature, the
    /// planner's own `cap` at each sample, then a backward braking pass.
    pub fn speed_plan(&self, path: &RefPath, plan: &mut [Sample], cap: impl Fn(&Sample) -> f64) {
        for smp in plan.iter_mut() {
            let reference = (path.at(smp.s).vx * self.speed_scale).min(self.max_speed);
            smp.v = reference.min(self.curve_speed(smp.kappa)).min(cap(smp));
        }
        for k in (0..plan.len().saturating_sub(1)).rev() {
            let ds = plan[k + 1].sigma - plan[k].sigma;
            let lim = libm::sqrt(plan[k + 1].v * plan[k + 1].v + 2.0 * self.brake_decel * ds);
            plan[k].v = plan[k].v.min(lim);
        }
    }
}

/// One sample of a plan in the world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    pub x: f64,
    pub y: f64,
    pub heading: f64,
    /// Arc length from the plan's start, m.
    pub sigma: f64,
    pub kappa: f64,
    /// Driving-line arc length (unwrapped) and offset.
    pub s: f64,
    pub d: f64,
    /// Speed limit (filled by [`TrackerParams::speed_plan`]).
    pub v: f64,
}

impl Sample {
    /// The sample at world point (x, y), driving-line coordinates (s, d), following
    /// `prev` (its arc length continues `prev`'s); heading, curvature and speed are
    /// filled later ([`with_headings`], [`TrackerParams::speed_plan`]).
    pub fn after(prev: Option<&Sample>, x: f64, y: f64, s: f64, d: f64) -> Self {
        let sigma = match prev {
            Some(prev) => prev.sigma + libm::hypot(x - prev.x, y - prev.y),
            None => 0.0,
        };
        Self {
            x,
            y,
            heading: 0.0,
            sigma,
            kappa: 0.0,
            s,
            d,
            v: 0.0,
        }
    }
}

/// Fill the headings (central differences) and curvatures (heading change over arc
/// length; the ends copy their neighbours) of `plan`.
pub fn with_headings(plan: &mut [Sample]) {
    let m = plan.len();
    for k in 0..m {
        let (a, b) = (k.saturating_sub(1), (k + 1).min(m - 1));
        plan[k].heading = libm::atan2(plan[b].y - plan[a].y, plan[b].x - plan[a].x);
    }
    for k in 1..m.saturating_sub(1) {
        let dh = wrap_angle(plan[k + 1].heading - plan[k - 1].heading);
        let ds = plan[k + 1].sigma - plan[k - 1].sigma;
        plan[k].kappa = if ds > 1e-9 { dh / ds } else { 0.0 };
    }
    if m >= 2 {
        plan[0].kappa = plan[1].kappa;
        plan[m - 1].kappa = plan[m - 2].kappa;
    }
}

/// The plan being tracked and where the car is on it.
#[derive(Debug, Clone, Default)]
pub struct Tracker {
    plan: Vec<Sample>,
    /// The plan sample nearest the car at the last look-up (the search starts there).
    hint: usize,
    since_replan: usize,
}

impl Tracker {
    pub fn plan(&self) -> &[Sample] {
        &self.plan
    }

    /// Forget the plan.
    pub fn reset(&mut self) {
        self.plan.clear();
        self.hint = 0;
        self.since_replan = 0;
    }

    /// Track `plan` from now on.
    pub fn set_plan(&mut self, plan: Vec<Sample>) {
        self.plan = plan;
        self.hint = 0;
        self.since_replan = 0;
    }

    /// The plan sample nearest (x, y), searched forward from the last one, and its
    /// distance.
    fn nearest(&mut self, x: f64, y: f64) -> Option<(usize, f64)> {
        if self.plan.is_empty() {
            return None;
        }
        let d2 = |s: &Sample| (s.x - x) * (s.x - x) + (s.y - y) * (s.y - y);
        let mut i = self.hint.min(self.plan.len() - 1);
        while i + 1 < self.plan.len() && d2(&self.plan[i + 1]) <= d2(&self.plan[i]) {
            i += 1;
        }
        self.hint = i;
        Some((i, libm::sqrt(d2(&self.plan[i]))))
    }

    /// Is a replan due for a car at `pose`: no plan, the car off it or near its end, or
    /// `replan_every` steps since the last?
    pub fn due(&mut self, pose: Pose, replan_every: usize) -> bool {
        self.nearest(pose.x, pose.y).is_none_or(|(i, dist)| {
            dist > OFF_PLAN
                || self.since_replan >= replan_every
                || i + END_SAMPLES >= self.plan.len()
        })
    }

    /// The action that follows the plan for a car at `pose` moving at `speed` (a
    /// standstill without a plan).
    pub fn follow(&mut self, p: &TrackerParams, pose: Pose, speed: f64) -> Action {
        self.since_replan += 1;
        let Some((i, _)) = self.nearest(pose.x, pose.y) else {
            return Action::new(0.0, 0.0);
        };
        let plan = &self.plan;
        let ahead = |dist: f64| {
            let target = plan[i].sigma + dist;
            (i..plan.len())
                .find(|&k| plan[k].sigma >= target)
                .unwrap_or(plan.len() - 1)
        };
        let j = ahead(p.lookahead_min + p.lookahead_gain * speed.max(0.0));
        let (dx, dy) = (plan[j].x - pose.x, plan[j].y - pose.y);
        let (sn, cs) = libm::sincos(pose.theta);
        let local_y = -sn * dx + cs * dy;
        let dist2 = (dx * dx + dy * dy).max(1e-6);
        let q = &plan[i];
        let (hs, hc) = libm::sincos(q.heading);
        let cross = -hs * (pose.x - q.x) + hc * (pose.y - q.y);
        let steer = (libm::atan(p.wheelbase * 2.0 * local_y / dist2)
            - libm::atan(p.track_gain * cross / (speed.max(0.0) + 1.0)))
        .clamp(-p.steer_max, p.steer_max);
        let k = ahead(0.25 * speed.max(0.0));
        Action::new(steer, plan[k].v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn straight(n: usize) -> Vec<Sample> {
        let mut plan: Vec<Sample> = Vec::new();
        for k in 0..n {
            let x = 0.2 * k as f64;
            plan.push(Sample::after(plan.last(), x, 0.0, x, 0.0));
        }
        with_headings(&mut plan);
        plan
    }

    #[test]
    fn specs_and_fields_line_up() {
        let specs = param_specs("a", "b");
        assert_eq!(specs.len(), NUM_PARAMS);
        let v: [f64; NUM_PARAMS] = std::array::from_fn(|k| specs[k].default);
        let p = TrackerParams::from_vector(&v, &VehicleParams::default());
        let by_name = |n: &str| specs.iter().find(|s| s.name == n).expect(n).default;
        assert_eq!(p.lookahead_min, by_name("lookahead_min"));
        assert_eq!(p.lookahead_gain, by_name("lookahead_gain"));
        assert_eq!(p.track_gain, by_name("track_gain"));
        assert_eq!(p.speed_scale, by_name("speed_scale"));
        assert_eq!(p.lat_accel, by_name("lat_accel"));
        assert_eq!(p.max_speed, by_name("max_speed"));
        assert_eq!(p.brake_decel, by_name("brake_decel"));
    }

    #[test]
    fn straight_plan_has_no_curvature_and_steers_straight() {
        let plan = straight(40);
        assert!(plan.iter().all(|s| s.heading == 0.0 && s.kappa == 0.0));
        assert!((plan[39].sigma - 7.8).abs() < 1e-12);
        let specs = param_specs("a", "b");
        let v: [f64; NUM_PARAMS] = std::array::from_fn(|k| specs[k].default);
        let p = TrackerParams::from_vector(&v, &VehicleParams::default());
        let mut t = Tracker::default();
        assert!(t.due(Pose::new(0.0, 0.0, 0.0), 10));
        t.set_plan(plan);
        assert!(!t.due(Pose::new(1.0, 0.0, 0.0), 10));
        // left of the plan: steer right, back towards it
        let a = t.follow(&p, Pose::new(1.0, 0.3, 0.0), 2.0);
        assert!(a.steer < 0.0, "{}", a.steer);
        // far off the plan: replan
        assert!(t.due(Pose::new(1.0, 1.0, 0.0), 10));
    }
}
