//! Follow-the-gap: a reactive driver that reads only the LIDAR.
//!
//! Each step: clip the ranges at `clip_range` and smooth them with a moving average of
//! `window` beams; keep the beams within `view_angle` of the heading. Extend every
//! disparity (neighbouring beams differing by more than `disparity_threshold`): the
//! nearer range is copied over the beams the car's half width plus `car_margin` would
//! sweep on the far side, so the car does not cut a corner. Find the closest point and
//! clear a bubble of `bubble_radius` around it. The free gaps are the runs of beams above
//! `gap_threshold`; the chosen one has the largest sum of ranges (wide and deep). Aim at
//! a blend of its furthest beam (`aim_centre` = 0) and its centre (`aim_centre` = 1);
//! steer `steer_gain` times the aim angle, clamped to the car's limits. Speed falls from
//! `max_speed` towards `min_speed` with the steering angle and is capped so that the car
//! can stop within the free distance straight ahead at `brake_decel`.
//!
//! The driver knows no map: it assumes the scan spans the default LIDAR field of view
//! ([`LidarConfig::default`]) with beams evenly spaced across it.

use paddock_sim::lidar::LidarConfig;
use paddock_sim::params::VehicleParams;
use paddock_sim::world::{Action, Observation};
use serde::{Deserialize, Serialize};

use crate::{Driver, ParamSpec, PolicyError, Sensors, default_values};

pub const NAME: &str = "follow-the-gap";
pub const ABOUT: &str = "reactive follow-the-gap on the LIDAR (bubble, disparity extension)";

/// Half-width of the cone straight ahead whose nearest return limits the speed, rad.
const AHEAD_CONE: f64 = 0.12;

/// The tunable parameters, in vector order.
pub fn param_specs() -> Vec<ParamSpec> {
    vec![
        ParamSpec::new(
            "clip_range",
            8.0,
            1.0,
            30.0,
            "ranges are clipped to this, m",
        ),
        ParamSpec::new(
            "window",
            3.0,
            1.0,
            31.0,
            "moving-average window, beams (rounded)",
        ),
        ParamSpec::new(
            "view_angle",
            1.6,
            0.5,
            2.35,
            "only beams within this angle of the heading are considered, rad",
        ),
        ParamSpec::new(
            "bubble_radius",
            0.6,
            0.0,
            2.0,
            "radius of the safety bubble cleared around the closest point, m",
        ),
        ParamSpec::new(
            "disparity_threshold",
            0.4,
            0.05,
            5.0,
            "a jump between neighbouring ranges larger than this is a disparity, m",
        ),
        ParamSpec::new(
            "car_margin",
            0.2,
            0.0,
            1.0,
            "margin beyond the car's half width when extending disparities, m",
        ),
        ParamSpec::new(
            "gap_threshold",
            1.5,
            0.2,
            10.0,
            "beams longer than this are free, m",
        ),
        ParamSpec::new(
            "aim_centre",
            0.3,
            0.0,
            1.0,
            "aim point: 0 = the gap's furthest beam, 1 = its centre, blended between",
        ),
        ParamSpec::new(
            "steer_gain",
            1.0,
            0.2,
            3.0,
            "steering angle per radian of aim angle",
        ),
        ParamSpec::new(
            "max_speed",
            7.5,
            0.5,
            20.0,
            "speed when steering straight, m/s",
        ),
        ParamSpec::new(
            "min_speed",
            2.0,
            0.2,
            20.0,
            "speed at full steering lock, m/s (at most max_speed)",
        ),
        ParamSpec::new(
            "brake_decel",
            4.0,
            0.5,
            15.0,
            "the car must be able to stop within the free distance ahead at this, m/s^2",
        ),
    ]
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FollowTheGapParams {
    pub clip_range: f64,
    pub window: usize,
    pub view_angle: f64,
    pub bubble_radius: f64,
    pub disparity_threshold: f64,
    pub car_margin: f64,
    pub gap_threshold: f64,
    pub aim_centre: f64,
    pub steer_gain: f64,
    pub max_speed: f64,
    pub min_speed: f64,
    pub brake_decel: f64,
    /// From the car (not tuned): steering limit, rad, and half body width, m.
    pub steer_max: f64,
    pub half_width: f64,
}

impl Default for FollowTheGapParams {
    fn default() -> Self {
        Self::from_vector(&default_values(&param_specs()), &VehicleParams::default())
            .expect("defaults are valid")
    }
}

impl FollowTheGapParams {
    /// From a vector in [`param_specs`] order (bounds checked by the caller); checks the
    /// relations between parameters.
    pub fn from_vector(v: &[f64], vehicle: &VehicleParams) -> Result<Self, PolicyError> {
        if v[10] > v[9] {
            return Err(PolicyError::Invalid {
                driver: NAME.into(),
                message: format!(
                    "parameter min_speed = {} must not exceed max_speed = {}",
                    v[10], v[9]
                ),
            });
        }
        Ok(Self {
            clip_range: v[0],
            window: libm::round(v[1]) as usize,
            view_angle: v[2],
            bubble_radius: v[3],
            disparity_threshold: v[4],
            car_margin: v[5],
            gap_threshold: v[6],
            aim_centre: v[7],
            steer_gain: v[8],
            max_speed: v[9],
            min_speed: v[10],
            brake_decel: v[11],
            steer_max: vehicle.s_max.min(-vehicle.s_min),
            half_width: 0.5 * vehicle.width,
        })
    }
}

#[derive(Debug, Clone)]
pub struct FollowTheGap {
    pub params: FollowTheGapParams,
    fov: f64,
    /// Work buffers (no state carries from one step to the next).
    clipped: Vec<f64>,
    ranges: Vec<f64>,
}

impl FollowTheGap {
    pub fn new(params: FollowTheGapParams) -> Self {
        Self {
            params,
            fov: LidarConfig::default().fov,
            clipped: Vec::new(),
            ranges: Vec::new(),
        }
    }

    /// The action for one scan (beam i at `-fov/2 + i fov/(n-1)` from the heading).
    pub fn act_scan(&mut self, scan: &[f64]) -> Action {
        let p = self.params.clone();
        let n = scan.len();
        if n < 2 {
            return Action::new(0.0, 0.0);
        }
        let inc = self.fov / (n - 1) as f64;
        let angle = |i: usize| -0.5 * self.fov + i as f64 * inc;
        self.clipped.clear();
        self.clipped
            .extend(scan.iter().map(|&r| r.clamp(0.0, p.clip_range)));
        // moving average (the window shrinks at the ends)
        let half = p.window / 2;
        self.ranges.clear();
        let mut acc = 0.0;
        let mut lo = 0usize;
        let mut hi = 0usize; // the sum covers [lo, hi)
        for i in 0..n {
            let (want_lo, want_hi) = (i.saturating_sub(half), (i + half + 1).min(n));
            while hi < want_hi {
                acc += self.clipped[hi];
                hi += 1;
            }
            while lo < want_lo {
                acc -= self.clipped[lo];
                lo += 1;
            }
            self.ranges.push(acc / (hi - lo) as f64);
        }
        // the beams we look at
        let first = ((-p.view_angle + 0.5 * self.fov) / inc).ceil().max(0.0) as usize;
        let last = (((p.view_angle + 0.5 * self.fov) / inc).floor() as usize).min(n - 1);
        if first >= last {
            return Action::new(0.0, p.min_speed);
        }
        let r = &mut self.ranges;
        for (i, v) in r.iter_mut().enumerate() {
            if i < first || i > last {
                *v = 0.0;
            }
        }
        // disparity extension: the nearer range covers the beams the car would sweep
        let reach = p.half_width + p.car_margin;
        let raw = r.clone();
        for i in first..last {
            let (a, b) = (raw[i], raw[i + 1]);
            if (a - b).abs() <= p.disparity_threshold {
                continue;
            }
            let near = a.min(b).max(0.05);
            let k = (libm::atan(reach / near) / inc).ceil() as usize;
            if a < b {
                for v in &mut r[i + 1..=(i + k).min(last)] {
                    *v = v.min(near);
                }
            } else {
                for v in &mut r[i.saturating_sub(k).max(first)..=i] {
                    *v = v.min(near);
                }
            }
        }
        // safety bubble around the closest point
        let closest = (first..=last)
            .min_by(|&a, &b| r[a].total_cmp(&r[b]).then(a.cmp(&b)))
            .unwrap_or(first);
        let rc = r[closest].max(0.05);
        let k = (libm::atan(p.bubble_radius / rc) / inc).ceil() as usize;
        for v in &mut r[closest.saturating_sub(k).max(first)..=(closest + k).min(last)] {
            *v = 0.0;
        }
        // the gap with the largest sum of ranges
        let mut best: Option<(f64, usize, usize)> = None;
        let mut i = first;
        while i <= last {
            if r[i] <= p.gap_threshold {
                i += 1;
                continue;
            }
            let start = i;
            let mut sum = 0.0;
            while i <= last && r[i] > p.gap_threshold {
                sum += r[i];
                i += 1;
            }
            if best.is_none_or(|b| sum > b.0) {
                best = Some((sum, start, i - 1));
            }
        }
        let aim = match best {
            Some((_, a, b)) => {
                let furthest = (a..=b)
                    .max_by(|&x, &y| r[x].total_cmp(&r[y]).then(y.cmp(&x)))
                    .unwrap_or(a);
                let centre = 0.5 * (a + b) as f64;
                let blend = (1.0 - p.aim_centre) * furthest as f64 + p.aim_centre * centre;
                angle(0) + blend * inc
            }
            // no gap: head for the longest beam
            None => angle(
                (first..=last)
                    .max_by(|&x, &y| raw[x].total_cmp(&raw[y]).then(y.cmp(&x)))
                    .unwrap_or(n / 2),
            ),
        };
        let steer = (p.steer_gain * aim).clamp(-p.steer_max, p.steer_max);
        let frac = if p.steer_max > 0.0 {
            steer.abs() / p.steer_max
        } else {
            0.0
        };
        let mut speed = p.max_speed - (p.max_speed - p.min_speed) * frac;
        // stop within the free distance straight ahead
        let ahead = (0..n)
            .filter(|&i| angle(i).abs() <= AHEAD_CONE)
            .map(|i| scan[i])
            .fold(f64::INFINITY, f64::min);
        if ahead.is_finite() {
            let free = (ahead - 0.5).max(0.0);
            speed = speed.min(libm::sqrt(2.0 * p.brake_decel * free));
        }
        Action::new(steer, speed.max(p.min_speed.min(1.0)))
    }
}

impl Driver for FollowTheGap {
    fn name(&self) -> &'static str {
        NAME
    }

    fn sensors(&self) -> Sensors {
        Sensors { lidar: true }
    }

    fn reset(&mut self) {}

    fn act(&mut self, obs: &Observation, me: usize) -> Action {
        if obs.num_beams == 0 {
            return Action::new(0.0, 0.0);
        }
        self.act_scan(obs.scan(me))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steers_towards_the_open_side() {
        let mut ftg = FollowTheGap::new(FollowTheGapParams::default());
        // a wall close on the right half, open on the left
        let scan: Vec<f64> = (0..1080)
            .map(|i| if i < 540 { 1.0 } else { 10.0 })
            .collect();
        let a = ftg.act_scan(&scan);
        assert!(a.steer > 0.0, "{a:?}");
        assert!(a.speed > 0.0);
    }
}
