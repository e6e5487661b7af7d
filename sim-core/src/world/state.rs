//! What changes during an episode and what a step reports: actions, observations,
//! per-car state and the snapshot of a whole world.

use serde::{Deserialize, Serialize};

use crate::dynamics::Vehicle;
use crate::geometry::{Obb, Pose};
use crate::rng::Rng;
use crate::track::LapCounter;

/// How to place the cars at reset.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Starts {
    /// These poses, one per agent.
    Poses(Vec<Pose>),
    /// A seeded random place on the track; further cars line up behind it on a
    /// staggered grid.
    Random,
    /// A staggered grid behind arc length `s` of the centerline, in agent order.
    Grid { s: f64 },
}

/// A car's command: target steering angle (rad) and target speed (m/s), as the
/// reference's action.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Action {
    pub steer: f64,
    pub speed: f64,
}

impl Action {
    pub const fn new(steer: f64, speed: f64) -> Self {
        Self { steer, speed }
    }
}

/// Where a car stands in the episode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AgentStatus {
    Racing,
    /// Collided under [`CollisionMode::Terminate`].
    Crashed,
    /// Completed the configured number of laps.
    Finished,
}

/// Per-agent observations, one entry per agent in each field: the reference's
/// observation dict plus steering angle, progress and slip.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Observation {
    pub num_beams: usize,
    /// Agent-major ranges, `num_agents * num_beams` metres (zeros for a car whose scan is
    /// off).
    pub scans: Vec<f64>,
    pub poses_x: Vec<f64>,
    pub poses_y: Vec<f64>,
    pub poses_theta: Vec<f64>,
    /// Body-frame velocity of the reference point, m/s (v cos(slip), v sin(slip)).
    pub linear_vels_x: Vec<f64>,
    pub linear_vels_y: Vec<f64>,
    pub ang_vels_z: Vec<f64>,
    /// Did the car collide in the last step (or, once crashed, ever).
    pub collisions: Vec<bool>,
    /// Race time: seconds since the start, frozen when the car finishes or crashes.
    pub lap_times: Vec<f64>,
    pub lap_counts: Vec<u32>,
    pub steering_angles: Vec<f64>,
    /// Arc length driven along the centerline since the start, metres (negative when
    /// backwards).
    pub progress: Vec<f64>,
    pub slip_angles: Vec<f64>,
}

impl Observation {
    /// One car at rest at the origin, on the grid, with no collision, lap or progress,
    /// whose scan is `scan`: the observation a driver is given where there is no world
    /// (a bridge's first action, a benchmark or test of a driver on its own).
    pub fn one_car(scan: Vec<f64>) -> Self {
        Observation {
            num_beams: scan.len(),
            scans: scan,
            poses_x: vec![0.0],
            poses_y: vec![0.0],
            poses_theta: vec![0.0],
            linear_vels_x: vec![0.0],
            linear_vels_y: vec![0.0],
            ang_vels_z: vec![0.0],
            collisions: vec![false],
            lap_times: vec![0.0],
            lap_counts: vec![0],
            steering_angles: vec![0.0],
            progress: vec![0.0],
            slip_angles: vec![0.0],
        }
    }

    /// The scan of agent `i`.
    pub fn scan(&self, i: usize) -> &[f64] {
        &self.scans[i * self.num_beams..(i + 1) * self.num_beams]
    }

    /// FNV-1a over the exact bits of every field: equal digests mean equal observations.
    pub fn digest(&self) -> u64 {
        let mut h = Fnv::new();
        h.u64(self.num_beams as u64);
        for v in [
            &self.scans,
            &self.poses_x,
            &self.poses_y,
            &self.poses_theta,
            &self.linear_vels_x,
            &self.linear_vels_y,
            &self.ang_vels_z,
            &self.lap_times,
            &self.steering_angles,
            &self.progress,
            &self.slip_angles,
        ] {
            for x in v.iter() {
                h.u64(x.to_bits());
            }
        }
        for &c in &self.collisions {
            h.u64(c as u64);
        }
        for &c in &self.lap_counts {
            h.u64(c as u64);
        }
        h.0
    }

    pub(super) fn resize(&mut self, n: usize, beams: usize) {
        self.num_beams = beams;
        self.scans = vec![0.0; n * beams];
        for v in [
            &mut self.poses_x,
            &mut self.poses_y,
            &mut self.poses_theta,
            &mut self.linear_vels_x,
            &mut self.linear_vels_y,
            &mut self.ang_vels_z,
            &mut self.lap_times,
            &mut self.steering_angles,
            &mut self.progress,
            &mut self.slip_angles,
        ] {
            *v = vec![0.0; n];
        }
        self.collisions = vec![false; n];
        self.lap_counts = vec![0; n];
    }
}

struct Fnv(u64);
impl Fnv {
    fn new() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }
    fn u64(&mut self, v: u64) {
        for b in v.to_le_bytes() {
            self.0 ^= b as u64;
            self.0 = self.0.wrapping_mul(0x0100_0000_01b3);
        }
    }
}

/// One car's changing state.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AgentState {
    pub vehicle: Vehicle,
    pub laps: LapCounter,
    pub status: AgentStatus,
    /// Episode time at which the status last changed from racing.
    pub finish_time: Option<f64>,
    pub collided: bool,
    /// This car's LIDAR noise stream.
    pub noise: Rng,
}

/// Everything that changes during an episode: a snapshot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WorldState {
    pub seed: u64,
    pub time: f64,
    pub steps: u64,
    pub agents: Vec<AgentState>,
    pub obstacles: Vec<Obb>,
    pub observation: Observation,
}

/// What one step did, per agent.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct StepEvents {
    /// Collided during this step.
    pub collided: Vec<bool>,
    /// Completed a lap during this step.
    pub lap_completed: Vec<bool>,
    /// Out of the race (crashed or finished) after this step.
    pub terminated: Vec<bool>,
}
