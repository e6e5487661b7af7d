//! # paddock-policy: drivers
//!
//! A driver turns one car's observation into an action. Drivers are pure apart from
//! their own small memory (a search hint), so a rollout stays a pure function of its
//! scenario and seed.

use paddock_sim::geometry::Pose;
use paddock_sim::track::{RacelinePoint, Track};
use paddock_sim::world::Action;
use serde::{Deserialize, Serialize};

/// Pure pursuit on a raceline: steer towards the raceline point one lookahead distance
/// ahead; drive the raceline's speed profile scaled by `speed_scale`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PurePursuitParams {
    /// Lookahead at standstill, metres.
    pub lookahead_min: f64,
    /// Lookahead growth with speed, seconds (lookahead = min + gain * v).
    pub lookahead_gain: f64,
    /// Multiplies the raceline's speed profile.
    pub speed_scale: f64,
    /// Upper bound on the commanded speed, m/s.
    pub max_speed: f64,
    /// Wheelbase used by the steering law, metres (lf + lr of the default car).
    pub wheelbase: f64,
}

impl Default for PurePursuitParams {
    fn default() -> Self {
        Self {
            lookahead_min: 0.8,
            lookahead_gain: 0.15,
            speed_scale: 0.6,
            max_speed: 12.0,
            wheelbase: 0.3302,
        }
    }
}

#[derive(Debug, Clone)]
pub struct PurePursuit {
    pub params: PurePursuitParams,
    path: Vec<RacelinePoint>,
    /// Cumulative arc length of `path`, closing the loop.
    cum: Vec<f64>,
    hint: Option<usize>,
}

impl PurePursuit {
    /// Follow the track's raceline, or its centerline (at 5 m/s) if it has none.
    pub fn new(track: &Track, params: PurePursuitParams) -> Self {
        let path: Vec<RacelinePoint> = match track.raceline() {
            Some(r) => r.to_vec(),
            None => track
                .points()
                .iter()
                .map(|p| RacelinePoint {
                    s: 0.0,
                    x: p.x,
                    y: p.y,
                    psi: 0.0,
                    kappa: 0.0,
                    vx: 5.0,
                    ax: 0.0,
                })
                .collect(),
        };
        let mut cum = Vec::with_capacity(path.len() + 1);
        let mut s = 0.0;
        for i in 0..path.len() {
            cum.push(s);
            let (a, b) = (&path[i], &path[(i + 1) % path.len()]);
            s += libm::hypot(b.x - a.x, b.y - a.y);
        }
        cum.push(s);
        Self {
            params,
            path,
            cum,
            hint: None,
        }
    }

    /// Forget the search hint (call at episode reset).
    pub fn reset(&mut self) {
        self.hint = None;
    }

    fn nearest(&mut self, x: f64, y: f64) -> usize {
        let n = self.path.len();
        let d2 = |i: usize| {
            let p = &self.path[i];
            (p.x - x) * (p.x - x) + (p.y - y) * (p.y - y)
        };
        let best = match self.hint {
            Some(h) => {
                // walk downhill from the hint in both directions
                let mut best = h;
                loop {
                    let next = (best + 1) % n;
                    let prev = (best + n - 1) % n;
                    if d2(next) < d2(best) {
                        best = next;
                    } else if d2(prev) < d2(best) {
                        best = prev;
                    } else {
                        break;
                    }
                }
                // a jump (reset, spin) makes the local answer far off: search globally
                if d2(best) > 4.0 { None } else { Some(best) }
            }
            None => None,
        };
        let best = best.unwrap_or_else(|| {
            (0..n)
                .min_by(|&a, &b| d2(a).total_cmp(&d2(b)).then(a.cmp(&b)))
                .unwrap_or(0)
        });
        self.hint = Some(best);
        best
    }

    /// The action for a car at `pose` moving at `speed` (m/s).
    pub fn act(&mut self, pose: Pose, speed: f64) -> Action {
        let n = self.path.len();
        let i = self.nearest(pose.x, pose.y);
        let p = &self.params;
        let lookahead = p.lookahead_min + p.lookahead_gain * speed.max(0.0);
        // the first path point at least `lookahead` ahead along the path
        let total = self.cum[n];
        let mut j = i;
        for _ in 0..n {
            let along = (self.cum[j] - self.cum[i]).rem_euclid(total);
            let (tx, ty) = (self.path[j].x, self.path[j].y);
            if along >= lookahead || libm::hypot(tx - pose.x, ty - pose.y) >= lookahead {
                break;
            }
            j = (j + 1) % n;
        }
        let target = &self.path[j];
        let (dx, dy) = (target.x - pose.x, target.y - pose.y);
        let (s, c) = libm::sincos(pose.theta);
        let local_y = -s * dx + c * dy;
        let dist2 = (dx * dx + dy * dy).max(1e-6);
        let curvature = 2.0 * local_y / dist2;
        let steer = libm::atan(p.wheelbase * curvature);
        let speed_cmd = (self.path[i].vx * p.speed_scale).min(p.max_speed);
        Action::new(steer, speed_cmd)
    }
}
