//! Where cars start and where obstacles stand: seeded, checked against walls and each
//! other, with a bounded number of attempts.

use super::{Starts, World, WorldError};
use crate::collision::{obb_hits_map, obb_overlap};
use crate::geometry::{Obb, Pose, wrap_angle};
use crate::rng::Rng;

/// Distance between grid slots, metres along the track.
const GRID_GAP: f64 = 1.2;
const PLACEMENT_ATTEMPTS: usize = 1000;

impl World {
    /// The start poses `reset(seed, starts)` places the cars at, without resetting.
    pub fn start_poses_for(&self, seed: u64, starts: &Starts) -> Result<Vec<Pose>, WorldError> {
        self.start_poses(starts, &mut Rng::new(seed).fork(1))
    }

    pub(super) fn start_poses(
        &self,
        starts: &Starts,
        rng: &mut Rng,
    ) -> Result<Vec<Pose>, WorldError> {
        let n = self.num_agents();
        match starts {
            Starts::Poses(p) => {
                if p.len() != n {
                    return Err(WorldError::PoseCount {
                        expected: n,
                        got: p.len(),
                    });
                }
                for (agent, pose) in p.iter().enumerate() {
                    if !(pose.x.is_finite() && pose.y.is_finite() && pose.theta.is_finite()) {
                        return Err(WorldError::NonFinitePose { agent, pose: *pose });
                    }
                }
                Ok(p.clone())
            }
            Starts::Grid { s } => {
                if !s.is_finite() {
                    return Err(WorldError::Config {
                        field: "starts.grid.s".into(),
                        value: s.to_string(),
                        reason: "must be finite".into(),
                    });
                }
                let poses = self.grid(*s);
                self.check_free(&poses)
                    .map_err(|reason| WorldError::Placement {
                        what: "the starting grid".into(),
                        attempts: 1,
                        reason,
                    })?;
                Ok(poses)
            }
            Starts::Random => {
                let track = &self.circuit.track;
                let mut last = String::new();
                for _ in 0..PLACEMENT_ATTEMPTS {
                    let s = rng.uniform_range(0.0, track.length());
                    let mut poses = self.grid(s);
                    if n == 1 {
                        // a lone car also gets a random lateral offset and heading error
                        let (c, wr, wl) = track.at(s);
                        let room = (wr.min(wl) - 0.5).max(0.0);
                        let lat = rng.uniform_range(-0.5 * room, 0.5 * room);
                        let dth = rng.uniform_range(-0.1, 0.1);
                        poses[0] = Pose::new(
                            c.x - lat * libm::sin(c.theta),
                            c.y + lat * libm::cos(c.theta),
                            wrap_angle(c.theta + dth),
                        );
                    }
                    match self.check_free(&poses) {
                        Ok(()) => return Ok(poses),
                        Err(reason) => last = reason,
                    }
                }
                Err(WorldError::Placement {
                    what: "random starting poses".into(),
                    attempts: PLACEMENT_ATTEMPTS,
                    reason: last,
                })
            }
        }
    }

    /// A staggered grid: car i at GRID_GAP * i behind s, alternating sides.
    fn grid(&self, s: f64) -> Vec<Pose> {
        let track = &self.circuit.track;
        let n = self.num_agents();
        (0..n)
            .map(|i| {
                let (c, wr, wl) = track.at(s - GRID_GAP * i as f64);
                let lat = if n == 1 {
                    0.0
                } else {
                    let side = if i % 2 == 0 { 1.0 } else { -1.0 };
                    side * 0.3 * wr.min(wl).min(1.2)
                };
                Pose::new(
                    c.x - lat * libm::sin(c.theta),
                    c.y + lat * libm::cos(c.theta),
                    c.theta,
                )
            })
            .collect()
    }

    fn check_free(&self, poses: &[Pose]) -> Result<(), String> {
        let boxes: Vec<Obb> = poses
            .iter()
            .enumerate()
            .map(|(i, &p)| {
                let params = &self.config.agents[i].params;
                Obb::car(p, params.length, params.width)
            })
            .collect();
        for (i, b) in boxes.iter().enumerate() {
            if obb_hits_map(b, &self.circuit.map) {
                return Err(format!("agent {i} at {:?} touches a wall", poses[i]));
            }
            for (j, c) in boxes.iter().enumerate().skip(i + 1) {
                if obb_overlap(b, c) {
                    return Err(format!("agents {i} and {j} overlap"));
                }
            }
        }
        Ok(())
    }

    pub(super) fn place_obstacles(
        &self,
        starts: &[Pose],
        rng: &mut Rng,
    ) -> Result<Vec<Obb>, WorldError> {
        let cfg = &self.config.obstacles;
        let track = &self.circuit.track;
        let mut out: Vec<Obb> = Vec::with_capacity(cfg.count);
        for k in 0..cfg.count {
            let mut placed = false;
            let mut last = String::new();
            for _ in 0..PLACEMENT_ATTEMPTS {
                let s = rng.uniform_range(0.0, track.length());
                let (c, wr, wl) = track.at(s);
                let half = 0.5 * cfg.width;
                // lateral offset in [-wr + half, wl - half], keeping a passage on one side
                let lo = -wr + half;
                let hi = wl - half;
                if hi <= lo {
                    last = format!("track too narrow at s = {s:.1}");
                    continue;
                }
                let lat = rng.uniform_range(lo, hi);
                let yaw = rng.uniform_range(-0.5, 0.5);
                let gap_right = wr + lat - half;
                let gap_left = wl - lat - half;
                if gap_right.max(gap_left) < cfg.passage {
                    last = format!("no passage of {} m beside s = {s:.1}", cfg.passage);
                    continue;
                }
                let obb = Obb {
                    cx: c.x - lat * libm::sin(c.theta),
                    cy: c.y + lat * libm::cos(c.theta),
                    theta: wrap_angle(c.theta + yaw),
                    half_length: 0.5 * cfg.length,
                    half_width: half,
                };
                if obb_hits_map(&obb, &self.circuit.map) {
                    last = "touches a wall".into();
                    continue;
                }
                if starts
                    .iter()
                    .any(|p| libm::hypot(p.x - obb.cx, p.y - obb.cy) < cfg.start_clearance)
                {
                    last = "too close to a start pose".into();
                    continue;
                }
                // keep obstacles apart so that a passage remains between them
                if out.iter().any(|o| {
                    libm::hypot(o.cx - obb.cx, o.cy - obb.cy)
                        < o.circumradius() + obb.circumradius() + cfg.passage
                }) {
                    last = "too close to another obstacle".into();
                    continue;
                }
                out.push(obb);
                placed = true;
                break;
            }
            if !placed {
                return Err(WorldError::Placement {
                    what: format!("obstacle {k}"),
                    attempts: PLACEMENT_ATTEMPTS,
                    reason: last,
                });
            }
        }
        Ok(out)
    }
}
