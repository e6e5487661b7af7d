//! What the planners (lattice, RRT*) see at a replan: the other cars, placed in the
//! driving line's frame for a constant-speed prediction along it, and the LIDAR returns
//! that are neither a wall of the map nor another car (static obstacles the map lacks).

use paddock_sim::geometry::{Pose, wrap_angle};
use paddock_sim::lidar::LidarConfig;
use paddock_sim::map::Map;
use paddock_sim::world::Observation;

use crate::refpath::RefPath;

/// Every this many LIDAR beams is read for obstacles.
const BEAM_STRIDE: usize = 2;
/// A LIDAR return this close to a wall of the map is the wall, m.
const WALL_RETURN: f64 = 0.15;
/// A LIDAR return this far beyond another car's body is not that car, m.
const CAR_RETURN: f64 = 0.3;
/// Another car whose driving-line arc length is this far behind this car's is behind, m.
const BEHIND: f64 = 0.3;

/// Another car, predicted along the driving line.
#[derive(Debug, Clone, Copy)]
pub struct Other {
    pub s: f64,
    pub d: f64,
    /// Heading relative to the driving line.
    pub e: f64,
    /// Behind this car: it is the other car's to avoid (braking for a car that closes
    /// in from behind would only invite it into this one).
    pub behind: bool,
    /// Speed along the driving line, m/s.
    pub vs: f64,
    pub x: f64,
    pub y: f64,
}

/// The other cars and the static obstacles, refreshed by [`Perception::observe`].
#[derive(Debug, Clone)]
pub struct Perception {
    fov: f64,
    max_range: f64,
    pub others: Vec<Other>,
    pub obstacles: Vec<(f64, f64)>,
}

impl Default for Perception {
    fn default() -> Self {
        let lidar = LidarConfig::default();
        Self {
            fov: lidar.fov,
            max_range: lidar.max_range,
            others: Vec::new(),
            obstacles: Vec::new(),
        }
    }
}

/// Where the observing car is and what it looks for.
#[derive(Debug, Clone, Copy)]
pub struct View {
    /// The observing car's index and pose.
    pub me: usize,
    pub pose: Pose,
    /// Its driving-line arc length, to mark the cars behind it (`None`: none is).
    pub own_s: Option<f64>,
    /// LIDAR returns farther than this are not read, m.
    pub reach: f64,
    /// The observing car's body length and width, m (a return this near another car's
    /// centre, plus a margin, is that car).
    pub length: f64,
    pub width: f64,
}

impl Perception {
    /// Refresh the other cars and the obstacles from `obs` as seen by `view.me`.
    pub fn observe(&mut self, path: &RefPath, map: &Map, obs: &Observation, view: View) {
        self.others.clear();
        for j in (0..obs.poses_x.len()).filter(|&j| j != view.me) {
            let (x, y, th) = (obs.poses_x[j], obs.poses_y[j], obs.poses_theta[j]);
            let f = path.project(x, y, None);
            let e = wrap_angle(th - f.psi);
            // a crashed car stays where it is
            let v = if obs.collisions[j] {
                0.0
            } else {
                obs.linear_vels_x[j]
            };
            self.others.push(Other {
                s: f.s,
                d: f.d,
                e,
                behind: view.own_s.is_some_and(|own| path.ds(own, f.s) < -BEHIND),
                vs: v * libm::cos(e),
                x,
                y,
            });
        }
        self.obstacles.clear();
        if obs.num_beams < 2 {
            return;
        }
        let scan = obs.scan(view.me);
        let nb = scan.len();
        let inc = self.fov / (nb - 1) as f64;
        let car_r = 0.5 * libm::hypot(view.length, view.width) + CAR_RETURN;
        let pose = view.pose;
        for i in (0..nb).step_by(BEAM_STRIDE) {
            let r = scan[i];
            if !(r < 0.98 * self.max_range && r < view.reach) {
                continue;
            }
            let (sn, cs) = libm::sincos(pose.theta - 0.5 * self.fov + i as f64 * inc);
            let (px, py) = (pose.x + r * cs, pose.y + r * sn);
            if map.clearance(px, py) < WALL_RETURN {
                continue;
            }
            if self
                .others
                .iter()
                .any(|o| libm::hypot(px - o.x, py - o.y) < car_r)
            {
                continue;
            }
            self.obstacles.push((px, py));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use paddock_sim::circuit::Circuits;

    /// Three cars on the driving line: the observer at s = 10 m, one 5 m behind it, one
    /// 10 m ahead that has crashed. A scan of five beams, of which 0, 2 and 4 are read:
    /// one out of range, one on a box in the free space in front of the observer, one on
    /// the car ahead.
    #[test]
    fn marks_cars_behind_and_keeps_only_static_returns() {
        let circuit = Circuits::new().get("lakeside").expect("shipped map");
        let path = RefPath::from_circuit(&circuit);
        let place = |s: f64| path.to_world(s, 0.0);
        let cars = [place(10.0), place(5.0), place(20.0)];
        let mut seen = Perception::default();
        // turn the observer so that its last beam (half the field of view to its left)
        // points at the car ahead
        let to_ahead = libm::atan2(cars[2].1 - cars[0].1, cars[2].0 - cars[0].0);
        let me = Pose::new(cars[0].0, cars[0].1, to_ahead - 0.5 * seen.fov);
        let d_ahead = libm::hypot(cars[2].0 - me.x, cars[2].1 - me.y);
        // the middle beam, straight ahead, on a box in free space
        let along = |r: f64| {
            let (sn, cs) = libm::sincos(me.theta);
            (me.x + r * cs, me.y + r * sn)
        };
        let r_box = [0.6, 0.8, 1.0, 1.2]
            .into_iter()
            .find(|&r| circuit.map.clearance(along(r).0, along(r).1) > 2.0 * WALL_RETURN)
            .expect("free space in front of the car");
        // clear of the walls, so only the car explains the return there
        assert!(circuit.map.clearance(cars[2].0, cars[2].1) > WALL_RETURN);
        let obs = Observation {
            num_beams: 5,
            scans: vec![
                seen.max_range,
                0.0,
                r_box,
                0.0,
                d_ahead,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
            ],
            poses_x: cars.iter().map(|c| c.0).collect(),
            poses_y: cars.iter().map(|c| c.1).collect(),
            poses_theta: vec![me.theta, cars[1].2, cars[2].2],
            linear_vels_x: vec![3.0, 4.0, 5.0],
            collisions: vec![false, false, true],
            ..Observation::default()
        };
        let view = View {
            me: 0,
            pose: me,
            own_s: Some(10.0),
            reach: 50.0,
            length: 0.5,
            width: 0.3,
        };
        seen.observe(&path, &circuit.map, &obs, view);
        assert_eq!(seen.others.len(), 2);
        assert!(seen.others[0].behind);
        assert!(!seen.others[1].behind);
        // the crashed car stands still; the other drives along the line
        assert_eq!(seen.others[1].vs, 0.0);
        assert!(seen.others[0].vs > 3.9, "{}", seen.others[0].vs);
        assert_eq!(seen.obstacles.len(), 1, "{:?}", seen.obstacles);
        let (bx, by) = along(r_box);
        assert!(libm::hypot(seen.obstacles[0].0 - bx, seen.obstacles[0].1 - by) < 1e-9);
        // without a position of its own, no car is behind
        let view = View {
            own_s: None,
            ..view
        };
        seen.observe(&path, &circuit.map, &obs, view);
        assert!(seen.others.iter().all(|o| !o.behind));
    }
}
