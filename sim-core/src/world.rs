//! The world: N cars stepped together on one circuit from one seed.
//!
//! One [`World::step`] advances every racing car by `dt` with its own action, then
//! resolves collisions (car-wall, car-obstacle, car-car) by the episode's
//! [`CollisionMode`], updates progress and laps, and finally casts each car's LIDAR
//! (seeing walls, obstacles and the other cars) with noise from that car's own seeded
//! stream. The observation has the reference's field names and units.
//!
//! Everything that changes during an episode lives in [`WorldState`], which is plain,
//! serialisable data: [`World::snapshot`] and [`World::restore`] copy it whole, so an
//! episode can be replayed or resumed from any step with identical bits.

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::collision::{CollisionMode, obb_hits_map, obb_overlap};
use crate::dynamics::Vehicle;
use crate::geometry::{Obb, Pose, wrap_angle};
use crate::lidar::{Lidar, LidarConfig, ScanPath, ScanPathError};
use crate::params::VehicleParams;
use crate::rng::Rng;
use crate::track::{Circuit, LapCounter};

/// Errors from building, resetting or stepping a world. Each names the field and value.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum WorldError {
    #[error("invalid world config: {field} = {value}: {reason}")]
    Config {
        field: String,
        value: String,
        reason: String,
    },
    #[error("agent {agent}: {field} = {value} is not a finite number")]
    NonFiniteAction {
        agent: usize,
        field: &'static str,
        value: f64,
    },
    #[error("expected {expected} actions (one per agent), got {got}")]
    ActionCount { expected: usize, got: usize },
    #[error("expected {expected} start poses (one per agent), got {got}")]
    PoseCount { expected: usize, got: usize },
    #[error("start pose of agent {agent} is not finite: {pose:?}")]
    NonFinitePose { agent: usize, pose: Pose },
    #[error("could not place {what} on the track after {attempts} attempts: {reason}")]
    Placement {
        what: String,
        attempts: usize,
        reason: String,
    },
    #[error("snapshot has {got} agents, this world has {expected}")]
    SnapshotMismatch { expected: usize, got: usize },
    #[error("the world has not been reset")]
    NotReset,
}

/// One car's configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AgentConfig {
    pub params: VehicleParams,
    /// Cast this car's LIDAR every step (drivers that do not use it skip the cost).
    pub scan: bool,
}

impl Default for AgentConfig {
    fn default() -> Self {
        Self {
            params: VehicleParams::default(),
            scan: true,
        }
    }
}

/// Static box obstacles placed at seeded random places on the track.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObstacleConfig {
    pub count: usize,
    /// Box size along and across the track, metres.
    pub length: f64,
    pub width: f64,
    /// Free passage kept beside every obstacle, metres.
    pub passage: f64,
    /// No obstacle within this distance of a start pose, metres.
    pub start_clearance: f64,
}

impl Default for ObstacleConfig {
    fn default() -> Self {
        Self {
            count: 0,
            length: 0.4,
            width: 0.4,
            passage: 1.0,
            start_clearance: 4.0,
        }
    }
}

/// Episode settings that hold for every step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WorldConfig {
    /// Timestep, seconds (the reference's 0.01).
    pub dt: f64,
    pub lidar: LidarConfig,
    pub collision_mode: CollisionMode,
    pub agents: Vec<AgentConfig>,
    pub obstacles: ObstacleConfig,
    /// A car that completes this many laps is finished (None: never).
    pub laps: Option<u32>,
}

impl Default for WorldConfig {
    fn default() -> Self {
        Self {
            dt: 0.01,
            lidar: LidarConfig::default(),
            collision_mode: CollisionMode::Terminate,
            agents: vec![AgentConfig::default()],
            obstacles: ObstacleConfig::default(),
            laps: None,
        }
    }
}

impl WorldConfig {
    /// `n` identical default cars.
    pub fn with_agents(n: usize) -> Self {
        Self {
            agents: vec![AgentConfig::default(); n],
            ..Self::default()
        }
    }

    fn validate(&self) -> Result<(), WorldError> {
        let bad = |field: &str, value: String, reason: &str| {
            Err(WorldError::Config {
                field: field.into(),
                value,
                reason: reason.into(),
            })
        };
        if !(self.dt.is_finite() && self.dt > 0.0 && self.dt <= 0.1) {
            return bad("dt", self.dt.to_string(), "must be in (0, 0.1] seconds");
        }
        if self.agents.is_empty() {
            return bad("agents", "0".into(), "a world needs at least one agent");
        }
        if self.agents.len() > 64 {
            return bad("agents", self.agents.len().to_string(), "at most 64 agents");
        }
        for (i, a) in self.agents.iter().enumerate() {
            if let Err(e) = a.params.validate() {
                return bad(
                    &format!("agents[{i}].params"),
                    String::new(),
                    &e.to_string(),
                );
            }
        }
        let o = &self.obstacles;
        for (name, v) in [
            ("obstacles.length", o.length),
            ("obstacles.width", o.width),
            ("obstacles.passage", o.passage),
            ("obstacles.start_clearance", o.start_clearance),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(name, v.to_string(), "must be a finite number >= 0");
            }
        }
        if o.count > 1000 {
            return bad("obstacles.count", o.count.to_string(), "at most 1000");
        }
        let l = &self.lidar;
        if l.num_beams == 0 || l.num_beams > 100_000 {
            return bad(
                "lidar.num_beams",
                l.num_beams.to_string(),
                "must be 1..=100000",
            );
        }
        for (name, v) in [
            ("lidar.fov", l.fov),
            ("lidar.max_range", l.max_range),
            ("lidar.noise_std", l.noise_std),
            ("lidar.mount_offset", l.mount_offset),
        ] {
            if !v.is_finite() {
                return bad(name, v.to_string(), "must be finite");
            }
        }
        if l.max_range <= 0.0 || l.noise_std < 0.0 || l.fov <= 0.0 {
            return bad(
                "lidar",
                format!("{l:?}"),
                "fov and max_range must be > 0, noise_std >= 0",
            );
        }
        Ok(())
    }
}

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

    fn resize(&mut self, n: usize, beams: usize) {
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

/// N cars on one circuit.
#[derive(Debug, Clone)]
pub struct World {
    circuit: Arc<Circuit>,
    config: WorldConfig,
    lidar: Lidar,
    state: Option<WorldState>,
    /// Reused buffers: every car's box, and the shapes one car's LIDAR sees.
    shapes: Vec<Obb>,
    present: Vec<bool>,
    seen: Vec<Obb>,
}

/// Distance between grid slots, metres along the track.
const GRID_GAP: f64 = 1.2;
const PLACEMENT_ATTEMPTS: usize = 1000;

impl World {
    pub fn new(circuit: Arc<Circuit>, config: WorldConfig) -> Result<Self, WorldError> {
        config.validate()?;
        let lidar = Lidar::new(config.lidar.clone());
        Ok(Self {
            circuit,
            config,
            lidar,
            state: None,
            shapes: Vec::new(),
            present: Vec::new(),
            seen: Vec::new(),
        })
    }

    pub fn circuit(&self) -> &Arc<Circuit> {
        &self.circuit
    }

    pub fn config(&self) -> &WorldConfig {
        &self.config
    }

    /// Forces the LIDAR scans onto one code path (benches and `paddock perf` measure each
    /// path this way; every path gives the same bits). An error if this CPU cannot run it.
    pub fn set_scan_path(&mut self, path: ScanPath) -> Result<(), ScanPathError> {
        self.lidar = self.lidar.clone().with_path(path)?;
        Ok(())
    }

    /// The code path of this world's LIDAR scans (see [`Lidar::path`]).
    pub fn scan_path(&self) -> ScanPath {
        self.lidar.path()
    }

    pub fn num_agents(&self) -> usize {
        self.config.agents.len()
    }

    pub fn state(&self) -> Result<&WorldState, WorldError> {
        self.state.as_ref().ok_or(WorldError::NotReset)
    }

    /// The current observation.
    pub fn observation(&self) -> Result<&Observation, WorldError> {
        Ok(&self.state()?.observation)
    }

    /// Completed lap times of agent `i`, seconds.
    pub fn lap_times(&self, i: usize) -> Result<&[f64], WorldError> {
        Ok(&self.state()?.agents[i].laps.lap_times)
    }

    pub fn obstacles(&self) -> Result<&[Obb], WorldError> {
        Ok(&self.state()?.obstacles)
    }

    /// A copy of everything that changes during an episode.
    pub fn snapshot(&self) -> Result<WorldState, WorldError> {
        self.state().cloned()
    }

    /// Continue from a snapshot of a world with the same circuit and config.
    pub fn restore(&mut self, snapshot: &WorldState) -> Result<(), WorldError> {
        if snapshot.agents.len() != self.num_agents() {
            return Err(WorldError::SnapshotMismatch {
                expected: self.num_agents(),
                got: snapshot.agents.len(),
            });
        }
        self.state = Some(snapshot.clone());
        Ok(())
    }

    /// Start an episode: place the cars, place the obstacles, observe.
    pub fn reset(&mut self, seed: u64, starts: &Starts) -> Result<&Observation, WorldError> {
        let root = Rng::new(seed);
        let mut obstacle_rng = root.fork(2);
        let poses = self.start_poses_for(seed, starts)?;
        let obstacles = self.place_obstacles(&poses, &mut obstacle_rng)?;
        let track = &self.circuit.track;
        let agents = poses
            .iter()
            .enumerate()
            .map(|(i, &pose)| AgentState {
                vehicle: Vehicle::new(pose),
                laps: LapCounter::start(track, pose.x, pose.y, 0.0),
                status: AgentStatus::Racing,
                finish_time: None,
                collided: false,
                noise: root.fork(100 + i as u64),
            })
            .collect();
        let mut observation = Observation::default();
        observation.resize(self.num_agents(), self.config.lidar.num_beams);
        self.state = Some(WorldState {
            seed,
            time: 0.0,
            steps: 0,
            agents,
            obstacles,
            observation,
        });
        let n = self.num_agents();
        self.resolve_collisions(&[], &mut vec![false; n]);
        self.observe();
        Ok(&self.state.as_ref().expect("state set above").observation)
    }

    /// Advance every racing car by one timestep.
    pub fn step(&mut self, actions: &[Action]) -> Result<StepEvents, WorldError> {
        let n = self.num_agents();
        if actions.len() != n {
            return Err(WorldError::ActionCount {
                expected: n,
                got: actions.len(),
            });
        }
        for (agent, a) in actions.iter().enumerate() {
            if !a.steer.is_finite() {
                return Err(WorldError::NonFiniteAction {
                    agent,
                    field: "steer",
                    value: a.steer,
                });
            }
            if !a.speed.is_finite() {
                return Err(WorldError::NonFiniteAction {
                    agent,
                    field: "speed",
                    value: a.speed,
                });
            }
        }
        let dt = self.config.dt;
        let state = self.state.as_mut().ok_or(WorldError::NotReset)?;
        // Stop mode puts a colliding car back where it was: keep the states before the step.
        let stop_mode = self.config.collision_mode == CollisionMode::Stop;
        let mut before: Vec<Option<Vehicle>> = Vec::new();
        if stop_mode {
            before.resize(n, None);
        }
        for (i, (agent, a)) in state.agents.iter_mut().zip(actions).enumerate() {
            if agent.status != AgentStatus::Racing {
                continue;
            }
            if stop_mode {
                before[i] = Some(agent.vehicle.clone());
            }
            agent
                .vehicle
                .step(&self.config.agents[i].params, a.steer, a.speed, dt);
        }
        state.steps += 1;
        state.time = state.steps as f64 * dt;
        let mut events = StepEvents {
            collided: vec![false; n],
            lap_completed: vec![false; n],
            terminated: vec![false; n],
        };
        self.resolve_collisions(&before, &mut events.collided);
        let state = self.state.as_mut().expect("checked above");
        let track = &self.circuit.track;
        for (i, agent) in state.agents.iter_mut().enumerate() {
            if agent.status == AgentStatus::Racing {
                let p = agent.vehicle.pose();
                if agent.laps.update(track, p.x, p.y, state.time, dt) > 0 {
                    events.lap_completed[i] = true;
                }
                if let Some(target) = self.config.laps
                    && agent.laps.laps >= target
                {
                    agent.status = AgentStatus::Finished;
                    agent.finish_time = Some(state.time);
                }
            }
            events.terminated[i] = agent.status != AgentStatus::Racing;
        }
        self.observe();
        Ok(events)
    }

    /// Every car out of the race?
    pub fn done(&self) -> bool {
        self.state
            .as_ref()
            .is_some_and(|s| s.agents.iter().all(|a| a.status != AgentStatus::Racing))
    }

    fn car_box(&self, i: usize, v: &Vehicle) -> Obb {
        let p = &self.config.agents[i].params;
        Obb::car(v.pose(), p.length, p.width)
    }

    /// Detect collisions of the cars in their current poses and apply the collision
    /// mode. `before` holds each car's vehicle state before the step (Stop mode; empty
    /// otherwise). Leaves every car's final box in `self.shapes` for the scans.
    fn resolve_collisions(&mut self, before: &[Option<Vehicle>], collided: &mut [bool]) {
        let state = self.state.as_ref().expect("reset before collisions");
        let n = state.agents.len();
        let mut boxes = std::mem::take(&mut self.shapes);
        boxes.clear();
        boxes.extend(
            state
                .agents
                .iter()
                .enumerate()
                .map(|(i, a)| self.car_box(i, &a.vehicle)),
        );
        let map = &self.circuit.map;
        let mut hit = vec![false; n];
        for i in 0..n {
            if state.agents[i].status != AgentStatus::Racing {
                continue;
            }
            hit[i] = obb_hits_map(&boxes[i], map)
                || state.obstacles.iter().any(|o| obb_overlap(&boxes[i], o));
        }
        for i in 0..n {
            for j in i + 1..n {
                let racing_i = state.agents[i].status == AgentStatus::Racing;
                let racing_j = state.agents[j].status == AgentStatus::Racing;
                // finished cars have left the track; crashed ones are still in the way
                let present = |k: usize| state.agents[k].status != AgentStatus::Finished;
                if (racing_i || racing_j)
                    && present(i)
                    && present(j)
                    && obb_overlap(&boxes[i], &boxes[j])
                {
                    hit[i] |= racing_i;
                    hit[j] |= racing_j;
                }
            }
        }
        let mode = self.config.collision_mode;
        let state = self.state.as_mut().expect("reset before collisions");
        for i in 0..n {
            if state.agents[i].status != AgentStatus::Racing {
                continue;
            }
            let agent = &mut state.agents[i];
            agent.collided = hit[i];
            collided[i] = hit[i];
            if !hit[i] {
                continue;
            }
            match mode {
                CollisionMode::Terminate => {
                    agent.status = AgentStatus::Crashed;
                    agent.finish_time = Some(state.time);
                }
                CollisionMode::Stop => {
                    if let Some(prev) = before.get(i).and_then(Option::as_ref) {
                        agent.vehicle = prev.clone();
                        let p = &self.config.agents[i].params;
                        boxes[i] = Obb::car(agent.vehicle.pose(), p.length, p.width);
                    }
                    agent.vehicle.halt();
                }
                CollisionMode::Ignore => {}
            }
        }
        self.shapes = boxes;
    }

    fn observe(&mut self) {
        let state = self.state.as_mut().expect("reset before observe");
        let beams = self.config.lidar.num_beams;
        // The cars' boxes (`self.shapes`, left by the collision pass) that scans see:
        // every car still on the track.
        self.present.clear();
        if self.config.agents.iter().any(|a| a.scan) {
            self.present.extend(
                state
                    .agents
                    .iter()
                    .map(|a| a.status != AgentStatus::Finished),
            );
        }
        let obs = &mut state.observation;
        for (i, agent) in state.agents.iter_mut().enumerate() {
            let v = &agent.vehicle;
            let pose = v.pose();
            let (vx, vy) = v.body_velocity();
            obs.poses_x[i] = pose.x;
            obs.poses_y[i] = pose.y;
            obs.poses_theta[i] = pose.theta;
            obs.linear_vels_x[i] = vx;
            obs.linear_vels_y[i] = vy;
            obs.ang_vels_z[i] = v.state.yaw_rate;
            obs.steering_angles[i] = v.state.steer_angle;
            obs.slip_angles[i] = v.state.slip_angle;
            obs.collisions[i] = agent.collided;
            obs.lap_counts[i] = agent.laps.laps;
            obs.progress[i] = agent.laps.progress;
            obs.lap_times[i] = agent.finish_time.unwrap_or(state.time);
            if !self.config.agents[i].scan {
                continue;
            }
            let out = &mut obs.scans[i * beams..(i + 1) * beams];
            // Every other car and every obstacle is seen.
            self.seen.clear();
            self.seen.extend(
                self.shapes
                    .iter()
                    .enumerate()
                    .filter(|&(k, _)| k != i && self.present[k])
                    .map(|(_, o)| *o),
            );
            self.seen.extend_from_slice(&state.obstacles);
            match self.config.agents[i].params.laser_mount {
                // the LIDAR places its origin `mount_offset` ahead of the pose itself
                None => self.lidar.scan(&self.circuit.map, pose, &self.seen, out),
                Some(m) => {
                    // this car's mount replaces `mount_offset`: the origin at (x, y) in
                    // the car's frame, looking along `yaw` (the LIDAR adds its offset back)
                    let (s, c) = libm::sincos(pose.theta);
                    let heading = pose.theta + m.yaw;
                    let (hs, hc) = libm::sincos(heading);
                    let off = self.config.lidar.mount_offset;
                    let origin = Pose::new(
                        pose.x + m.x * c - m.y * s - off * hc,
                        pose.y + m.x * s + m.y * c - off * hs,
                        heading,
                    );
                    self.lidar.scan(&self.circuit.map, origin, &self.seen, out);
                    if m.flipped {
                        // upside down, the beams sweep clockwise
                        out.reverse();
                    }
                }
            }
            if self.config.lidar.noise_std > 0.0 {
                self.lidar.add_noise(out, &mut agent.noise);
            }
        }
    }

    /// The start poses `reset(seed, starts)` places the cars at, without resetting.
    pub fn start_poses_for(&self, seed: u64, starts: &Starts) -> Result<Vec<Pose>, WorldError> {
        self.start_poses(starts, &mut Rng::new(seed).fork(1))
    }

    fn start_poses(&self, starts: &Starts, rng: &mut Rng) -> Result<Vec<Pose>, WorldError> {
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

    fn place_obstacles(&self, starts: &[Pose], rng: &mut Rng) -> Result<Vec<Obb>, WorldError> {
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
