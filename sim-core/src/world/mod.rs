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

mod batch;
mod config;
mod placement;
mod state;

use std::sync::Arc;

pub use batch::{PACKED_STATE, PackedObservations, Worlds, WorldsMut};
pub use config::{AgentConfig, ObstacleConfig, WorldConfig, WorldError};
pub use state::{Action, AgentState, AgentStatus, Observation, Starts, StepEvents, WorldState};

use crate::circuit::Circuit;
use crate::collision::{CollisionMode, obb_hits_map, obb_overlap};
use crate::dynamics::Vehicle;
use crate::geometry::{Obb, Pose};
use crate::lidar::{Lidar, ScanAlgorithm, ScanPath, ScanPathError};
use crate::rng::Rng;
use crate::track::LapCounter;

/// N cars on one circuit.
///
/// A clone shares the circuit and the LIDAR's tables with the original (both are
/// read-only), so the worlds of a vector env ([`Worlds`]) read one copy of them.
#[derive(Debug, Clone)]
pub struct World {
    circuit: Arc<Circuit>,
    config: WorldConfig,
    lidar: Arc<Lidar>,
    state: Option<WorldState>,
    /// Reused buffers: every car's box, and the shapes one car's LIDAR sees.
    shapes: Vec<Obb>,
    present: Vec<bool>,
    seen: Vec<Obb>,
    /// Reused buffers of a step: each car's vehicle before it (Stop mode), and which
    /// cars hit something.
    before: Vec<Option<Vehicle>>,
    hit: Vec<bool>,
}

impl World {
    pub fn new(circuit: Arc<Circuit>, config: WorldConfig) -> Result<Self, WorldError> {
        config.validate()?;
        let lidar = Arc::new(Lidar::new(config.lidar.clone()));
        Ok(Self {
            circuit,
            config,
            lidar,
            state: None,
            shapes: Vec::new(),
            present: Vec::new(),
            seen: Vec::new(),
            before: Vec::new(),
            hit: Vec::new(),
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
        self.lidar = Arc::new((*self.lidar).clone().with_path(path)?);
        Ok(())
    }

    /// The code path of this world's LIDAR scans (see [`Lidar::path`]).
    pub fn scan_path(&self) -> ScanPath {
        self.lidar.path()
    }

    /// Takes this world's LIDAR scans by `algorithm` (see [`Lidar::with_algorithm`]): the
    /// same bits, another speed.
    pub fn set_scan_algorithm(&mut self, algorithm: ScanAlgorithm) {
        self.lidar = Arc::new((*self.lidar).clone().with_algorithm(algorithm));
    }

    /// Takes this world's LIDAR scans by the angular sweep over wall faces (`on`) or by
    /// the march alone (see [`Lidar::with_sweep`]).
    pub fn set_scan_sweep(&mut self, on: bool) {
        self.lidar = Arc::new((*self.lidar).clone().with_sweep(on));
    }

    /// How this world's scans are computed.
    pub fn scan_algorithm(&self) -> ScanAlgorithm {
        self.lidar.algorithm()
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
        self.before.clear();
        self.resolve_collisions(&mut vec![false; n]);
        self.observe();
        Ok(&self.state.as_ref().expect("state set above").observation)
    }

    /// Advance every racing car by one timestep.
    pub fn step(&mut self, actions: &[Action]) -> Result<StepEvents, WorldError> {
        let mut events = StepEvents::default();
        self.step_into(actions, &mut events)?;
        Ok(events)
    }

    /// [`World::step`], writing what the step did into `events` (resized to the cars):
    /// a step that allocates nothing once the buffers have their size.
    pub fn step_into(
        &mut self,
        actions: &[Action],
        events: &mut StepEvents,
    ) -> Result<(), WorldError> {
        self.check_actions(actions)?;
        let n = self.num_agents();
        let dt = self.config.dt;
        let state = self.state.as_mut().ok_or(WorldError::NotReset)?;
        // Stop mode puts a colliding car back where it was: keep the states before the step.
        let stop_mode = self.config.collision_mode == CollisionMode::Stop;
        let before = &mut self.before;
        before.clear();
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
        for v in [
            &mut events.collided,
            &mut events.lap_completed,
            &mut events.terminated,
        ] {
            v.clear();
            v.resize(n, false);
        }
        self.resolve_collisions(&mut events.collided);
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
        Ok(())
    }

    /// Whether `actions` are a valid step of this world: one finite action per car.
    pub fn check_actions(&self, actions: &[Action]) -> Result<(), WorldError> {
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
        self.state().map(|_| ())
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
    /// mode. `self.before` holds each car's vehicle state before the step (Stop mode;
    /// empty otherwise). Leaves every car's final box in `self.shapes` for the scans.
    fn resolve_collisions(&mut self, collided: &mut [bool]) {
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
        let mut hit = std::mem::take(&mut self.hit);
        hit.clear();
        hit.resize(n, false);
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
                    if let Some(prev) = self.before.get(i).and_then(Option::as_ref) {
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
        self.hit = hit;
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
            // The LIDAR places its origin `mount_offset` ahead of the pose itself; a car's
            // mount replaces that: the origin at (x, y) in the car's frame, looking along
            // `yaw` (the LIDAR adds its offset back).
            let mount = self.config.agents[i].params.laser_mount;
            let origin = match mount {
                None => pose,
                Some(m) => {
                    let (s, c) = libm::sincos(pose.theta);
                    let heading = pose.theta + m.yaw;
                    let (hs, hc) = libm::sincos(heading);
                    let off = self.config.lidar.mount_offset;
                    Pose::new(
                        pose.x + m.x * c - m.y * s - off * hc,
                        pose.y + m.x * s + m.y * c - off * hs,
                        heading,
                    )
                }
            };
            let map = &self.circuit.map;
            // Upside down, the beams sweep clockwise: reversed, then their noise added.
            let flipped = mount.is_some_and(|m| m.flipped);
            let noisy = self.config.lidar.noise_std > 0.0;
            if noisy && !flipped {
                // the noise drawn during the scan: the same values as after it
                self.lidar
                    .scan_noisy(map, origin, &self.seen, out, &mut agent.noise);
            } else {
                self.lidar.scan(map, origin, &self.seen, out);
            }
            if flipped {
                out.reverse();
                if noisy {
                    self.lidar.add_noise(out, &mut agent.noise);
                }
            }
        }
    }
}
