//! Interactive environments for learners: [`VecEnv`] holds N independent copies of one
//! environment and steps them together.
//!
//! In every copy the learners drive cars `0..learners` with `[steer, speed]` actions (one
//! learner by default, as a gymnasium env; several for self-play and multi-agent
//! learners, as f1tenth_gym's `step(np.array([[steer, speed], ...]))`); further cars
//! (opponents) are driven by registry drivers or registered ONNX models. After a reset or
//! a step, [`EnvFrame`] holds every copy's observation: the learners' LIDAR scans as
//! `f32`, every car's state, each learner's reward (weighted by [`RewardWeights`]) and
//! `terminated` flag (that car crashed or finished), and the copy's `truncated` flag
//! (time limit).
//!
//! Why it looks like this:
//! - **The learner resets.** A copy that has ended (every learner out of the race, or
//!   the time limit) is not reset here: stepping it again changes nothing (rewards 0,
//!   flags kept) until the learner asks for a reset, either with [`VecEnv::reset`] or
//!   with the `reset_envs` of [`VecEnv::step`] (a next-step autoreset in the same call).
//!   Python's vector env declares that mode. A learner whose car is out while others
//!   race on gets reward 0 and its action is ignored.
//! - **Deterministic per seed.** Copy `i` starts with its own seed stream derived from
//!   the session seed; a seeded reset restarts that stream from the given seed, so the
//!   same seeds and actions give the same bits, on any worker, in any thread order. A
//!   copy reset with seed `s` is the world a rollout with seed `s` starts from (same
//!   map, cars, LIDAR and obstacles), so learners and benchmarks see the same races.
//! - **All or nothing.** Requests are checked completely before any copy changes, so a
//!   bad action leaves the session as it was.
//! - **One batch.** The copies' worlds are one [`Worlds`]: each call steps them as a
//!   batch (split into a few runs of copies when rayon has several threads) and writes
//!   the learners' scans right after each world's step, into the frame or, with
//!   [`VecEnv::step_packed`], straight into the caller's buffer (an env session's
//!   reply frame), without allocating per step. Copy `i` gets the same bits whether
//!   it runs alone, in a batch, or on another thread.

use std::sync::Arc;

use paddock_policy::{build_driver, check_lidar, driver_info};
use paddock_sim::circuit::{Circuit, Circuits};
use paddock_sim::geometry::Pose;
use paddock_sim::lidar::{ScanPath, ScanPathError};
use paddock_sim::world::{Action, World, Worlds};

use crate::{RolloutError, task_seed};

mod batch;
mod config;
mod slot;

use config::invalid;
pub use config::{
    EnvConfig, MAX_BEAMS, MAX_CARS, MAX_ENVS, MAX_FRAME_SKIP, MAX_OPPONENTS, MAX_SCAN_VALUES,
    RewardWeights, STATE_SIZE,
};
use slot::{Op, Slot};

/// Bytes of one learner's scan in a packed scans buffer (`f32` little-endian).
const SCAN_VALUE_BYTES: usize = 4;

/// Every copy's observation after a reset or a step, in flat arrays (env-major), ready
/// to be packed as bytes. With one learner every per-learner array has one entry per
/// copy.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct EnvFrame {
    pub num_envs: usize,
    /// Cars per copy: the learners' and the opponents'.
    pub num_agents: usize,
    /// Learner cars per copy (cars `0..num_learners`).
    pub num_learners: usize,
    pub num_beams: usize,
    /// `num_envs x num_learners x num_beams`: each learner's LIDAR ranges, metres
    /// (noise included, >= 0).
    pub scans: Vec<f32>,
    /// `num_envs x num_agents x STATE_SIZE`: `[x, y, theta, vx, vy, yaw_rate, steer]`.
    pub states: Vec<f64>,
    /// `num_envs x num_learners`: the last step's reward (0 after a reset).
    pub rewards: Vec<f64>,
    /// `num_envs x num_learners`: that learner's car crashed or finished its laps.
    pub terminated: Vec<bool>,
    /// `num_envs`: the time limit ended the episode first.
    pub truncated: Vec<bool>,
    /// `num_envs x num_learners`: each learner's progress along the track, metres.
    pub progress: Vec<f64>,
    /// `num_envs x num_learners`: each learner's completed laps.
    pub laps: Vec<u32>,
    /// `num_envs`: simulated seconds since the reset.
    pub time: Vec<f64>,
    /// `num_envs x num_agents`: collided in the last physics step.
    pub agent_collisions: Vec<bool>,
    /// `num_envs x num_agents`: completed laps.
    pub agent_lap_counts: Vec<u32>,
    /// `num_envs x num_agents`: race time, frozen when the car stops racing.
    pub agent_lap_times: Vec<f64>,
}

impl EnvFrame {
    fn new(num_envs: usize, num_agents: usize, num_learners: usize, num_beams: usize) -> Self {
        let per_learner = num_envs * num_learners;
        Self {
            num_envs,
            num_agents,
            num_learners,
            num_beams,
            scans: vec![0.0; per_learner * num_beams],
            states: vec![0.0; num_envs * num_agents * STATE_SIZE],
            rewards: vec![0.0; per_learner],
            terminated: vec![false; per_learner],
            truncated: vec![false; num_envs],
            progress: vec![0.0; per_learner],
            laps: vec![0; per_learner],
            time: vec![0.0; num_envs],
            agent_collisions: vec![false; num_envs * num_agents],
            agent_lap_counts: vec![0; num_envs * num_agents],
            agent_lap_times: vec![0.0; num_envs * num_agents],
        }
    }

    /// Whether copy `i` has ended: every learner out of the race, or the time limit.
    pub fn ended(&self, i: usize) -> bool {
        let l = self.num_learners;
        self.truncated[i] || self.terminated[i * l..(i + 1) * l].iter().all(|&t| t)
    }
}

/// N independent copies of one environment, stepped together.
pub struct VecEnv {
    config: EnvConfig,
    circuit: Arc<Circuit>,
    worlds: Worlds,
    slots: Vec<Slot>,
    frame: EnvFrame,
    max_steps: u64,
    /// Reused per call: every car's action, which copies step, the packed scans.
    cars: Vec<Action>,
    active: Vec<bool>,
    packed: Vec<u8>,
    /// The pool the copies step on (`None`: the calling thread's rayon pool).
    pool: Option<Arc<rayon::ThreadPool>>,
}

impl std::fmt::Debug for VecEnv {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VecEnv")
            .field("map", &self.circuit.name)
            .field("num_envs", &self.slots.len())
            .field("num_agents", &self.num_agents())
            .field("num_learners", &self.num_learners())
            .finish()
    }
}

impl VecEnv {
    /// Build the copies on the circuit `config.map` names in `circuits` and reset each
    /// one from its own seed stream.
    pub fn new(circuits: &Circuits, config: EnvConfig) -> Result<Self, RolloutError> {
        config.validate()?;
        let circuit = circuits.get(&config.map)?;
        Self::with_circuit(config, circuit)
    }

    /// [`VecEnv::new`] on `circuit` (which `config.map` then only names).
    pub fn with_circuit(config: EnvConfig, circuit: Arc<Circuit>) -> Result<Self, RolloutError> {
        Self::with_circuit_in(config, circuit, None)
    }

    /// [`VecEnv::with_circuit`] whose copies step on `pool`'s threads (`None`: the rayon
    /// pool of the calling thread, the global one outside any pool). A library loaded
    /// into another program's process gives its own pool, which it can make again in a
    /// forked child (the global pool's threads are gone there, for good).
    pub fn with_circuit_in(
        config: EnvConfig,
        circuit: Arc<Circuit>,
        pool: Option<Arc<rayon::ThreadPool>>,
    ) -> Result<Self, RolloutError> {
        config.validate()?;
        let learners = config.learners;
        let mut scans = Vec::with_capacity(config.opponents.len());
        for (k, o) in config.opponents.iter().enumerate() {
            let agent = learners + k;
            let driver = |source| RolloutError::Driver { agent, source };
            check_lidar(&o.driver, &config.lidar).map_err(driver)?;
            scans.push(driver_info(&o.driver).map_err(driver)?.sensors.lidar);
        }
        let world_config = config.world_config(&scans);
        let world = World::new(circuit.clone(), world_config)?;
        let num_agents = world.num_agents();
        let worlds = Worlds::of(&world, config.num_envs);
        let mut slots = Vec::with_capacity(config.num_envs);
        for i in 0..config.num_envs {
            let mut opponents = Vec::with_capacity(config.opponents.len());
            for (k, o) in config.opponents.iter().enumerate() {
                opponents.push(
                    build_driver(&o.driver, &o.params, &circuit, &o.vehicle).map_err(|source| {
                        RolloutError::Driver {
                            agent: learners + k,
                            source,
                        }
                    })?,
                );
            }
            slots.push(Slot::new(
                opponents,
                learners,
                task_seed(config.seed, i as u64),
            ));
        }
        let max_steps = (config.time_limit / world.config().dt).ceil() as u64;
        let frame = EnvFrame::new(
            config.num_envs,
            num_agents,
            learners,
            config.lidar.num_beams,
        );
        let cars = vec![Action::default(); config.num_envs * num_agents];
        let active = vec![false; config.num_envs];
        let mut env = Self {
            config,
            circuit,
            worlds,
            slots,
            frame,
            max_steps,
            cars,
            active,
            packed: Vec::new(),
            pool,
        };
        let ops = vec![
            Op::Reset {
                seed: None,
                poses: None
            };
            env.num_envs()
        ];
        env.call(&ops, &[], None)?;
        Ok(env)
    }

    pub fn config(&self) -> &EnvConfig {
        &self.config
    }

    pub fn circuit(&self) -> &Arc<Circuit> {
        &self.circuit
    }

    pub fn num_envs(&self) -> usize {
        self.slots.len()
    }

    /// Cars per copy: the learners' and the opponents'.
    pub fn num_agents(&self) -> usize {
        self.config.learners + self.config.opponents.len()
    }

    /// Takes every world's LIDAR scans on `path` (see `Worlds::set_scan_path`): the same
    /// bits, another speed; an error, changing nothing, if this CPU cannot run it.
    pub fn set_scan_path(&mut self, path: ScanPath) -> Result<(), ScanPathError> {
        self.worlds.set_scan_path(path)
    }

    /// The code path of the worlds' LIDAR scans.
    pub fn scan_path(&self) -> ScanPath {
        self.worlds.world(0).scan_path()
    }

    /// Learner cars per copy (cars `0..num_learners`).
    pub fn num_learners(&self) -> usize {
        self.config.learners
    }

    pub fn num_beams(&self) -> usize {
        self.config.lidar.num_beams
    }

    /// Physics step, seconds.
    pub fn dt(&self) -> f64 {
        0.01
    }

    /// Every learner's action bounds: `([steer_min, speed_min], [steer_max, speed_max])`.
    pub fn action_bounds(&self) -> ([f64; 2], [f64; 2]) {
        let v = &self.config.vehicle;
        ([v.s_min, v.v_min], [v.s_max, v.v_max])
    }

    /// The observation after the last call.
    pub fn frame(&self) -> &EnvFrame {
        &self.frame
    }

    /// The world of copy `i` (for inspection and tests).
    pub fn world(&self, i: usize) -> Option<&World> {
        (i < self.worlds.len()).then(|| self.worlds.world(i))
    }

    /// Bytes of the packed scans of [`VecEnv::step_packed`] and [`VecEnv::reset_packed`]:
    /// `num_envs x num_learners x num_beams` `f32`.
    pub fn packed_scans_len(&self) -> usize {
        self.num_envs() * self.num_learners() * self.num_beams() * SCAN_VALUE_BYTES
    }

    /// Reset copies `envs` (empty: all) with `seeds` (empty: each copy's own stream;
    /// else one per reset copy) and optional start `poses` (one per car of every reset
    /// copy, copy-major). Copies not named keep their state; the frame holds them all.
    pub fn reset(
        &mut self,
        envs: &[usize],
        seeds: &[u64],
        poses: Option<&[Pose]>,
    ) -> Result<&EnvFrame, RolloutError> {
        let ops = self.reset_ops(envs, seeds, poses)?;
        self.call(&ops, &[], None)?;
        Ok(&self.frame)
    }

    /// [`VecEnv::reset`], with the learners' scans written into `scans`
    /// ([`VecEnv::packed_scans_len`] bytes of little-endian `f32`, the layout of an env
    /// session's scans frame) instead of the frame, whose `scans` is left empty.
    pub fn reset_packed(
        &mut self,
        envs: &[usize],
        seeds: &[u64],
        poses: Option<&[Pose]>,
        scans: &mut [u8],
    ) -> Result<&EnvFrame, RolloutError> {
        let ops = self.reset_ops(envs, seeds, poses)?;
        self.call(&ops, &[], Some(scans))?;
        Ok(&self.frame)
    }

    /// The ops of a reset request, checked.
    fn reset_ops(
        &self,
        envs: &[usize],
        seeds: &[u64],
        poses: Option<&[Pose]>,
    ) -> Result<Vec<Op>, RolloutError> {
        let n = self.num_envs();
        let targets: Vec<usize> = if envs.is_empty() {
            (0..n).collect()
        } else {
            envs.to_vec()
        };
        let mut ops = vec![Op::Keep; n];
        for (j, &i) in targets.iter().enumerate() {
            if i >= n {
                return invalid(
                    &format!("envs[{j}]"),
                    i,
                    &format!("the session has {n} envs (indices 0..{n})"),
                );
            }
            if !matches!(ops[i], Op::Keep) {
                return invalid(&format!("envs[{j}]"), i, "named twice");
            }
            ops[i] = Op::Reset {
                seed: None,
                poses: None,
            };
        }
        if !seeds.is_empty() && seeds.len() != targets.len() {
            return invalid(
                "seeds",
                format!("{} seeds", seeds.len()),
                &format!("give none or one per reset env ({} envs)", targets.len()),
            );
        }
        let agents = self.num_agents();
        if let Some(p) = poses {
            if p.len() != targets.len() * agents {
                return invalid(
                    "poses",
                    format!("{} poses", p.len()),
                    &format!(
                        "expected one per car of every reset env: {} envs x {agents} cars = {}",
                        targets.len(),
                        targets.len() * agents
                    ),
                );
            }
            if let Some(k) = p
                .iter()
                .position(|q| !(q.x.is_finite() && q.y.is_finite() && q.theta.is_finite()))
            {
                return invalid(
                    &format!("poses[{k}]"),
                    format!("{:?}", p[k]),
                    "x, y and theta must be finite",
                );
            }
        }
        for (j, &i) in targets.iter().enumerate() {
            ops[i] = Op::Reset {
                seed: seeds.get(j).copied(),
                poses: poses.map(|p| p[j * agents..(j + 1) * agents].to_vec()),
            };
        }
        Ok(ops)
    }

    /// Step every copy with `actions` (`num_envs x num_learners x [steer, speed]`),
    /// except the copies in `reset_envs`, which are reset from their own seed streams
    /// instead. A copy that has ended and is not reset stays as it is (rewards 0).
    pub fn step(
        &mut self,
        actions: &[f32],
        reset_envs: &[usize],
    ) -> Result<&EnvFrame, RolloutError> {
        let ops = self.step_ops(actions, reset_envs)?;
        self.call(&ops, actions, None)?;
        Ok(&self.frame)
    }

    /// [`VecEnv::step`], with the learners' scans written into `scans`
    /// ([`VecEnv::packed_scans_len`] bytes of little-endian `f32`, the layout of an env
    /// session's scans frame) instead of the frame, whose `scans` is left empty: each
    /// scan is written once, right after its world's step.
    pub fn step_packed(
        &mut self,
        actions: &[f32],
        reset_envs: &[usize],
        scans: &mut [u8],
    ) -> Result<&EnvFrame, RolloutError> {
        let ops = self.step_ops(actions, reset_envs)?;
        self.call(&ops, actions, Some(scans))?;
        Ok(&self.frame)
    }

    /// The ops of a step request, checked.
    fn step_ops(&self, actions: &[f32], reset_envs: &[usize]) -> Result<Vec<Op>, RolloutError> {
        let n = self.num_envs();
        let l = self.num_learners();
        let shape = if l == 1 {
            "num_envs x [steer, speed]".to_string()
        } else {
            format!("num_envs x {l} learners x [steer, speed]")
        };
        if actions.len() != 2 * l * n {
            return invalid(
                "actions",
                format!("{} values", actions.len()),
                &format!("expected {shape} = {} values", 2 * l * n),
            );
        }
        if let Some(k) = actions.iter().position(|a| !a.is_finite()) {
            let what = if k % 2 == 0 { "steer" } else { "speed" };
            let whose = if l == 1 {
                format!("env {}", k / 2)
            } else {
                format!("env {} learner {}", k / (2 * l), (k / 2) % l)
            };
            return invalid(
                &format!("actions[{k}]"),
                actions[k],
                &format!("{whose} {what} must be a finite number"),
            );
        }
        let mut ops = vec![Op::Step; n];
        for (j, &i) in reset_envs.iter().enumerate() {
            if i >= n {
                return invalid(
                    &format!("reset_envs[{j}]"),
                    i,
                    &format!("the session has {n} envs (indices 0..{n})"),
                );
            }
            ops[i] = Op::Reset {
                seed: None,
                poses: None,
            };
        }
        Ok(ops)
    }

    /// Run `ops` (one per copy) with the learners' `actions` of the stepped copies, write
    /// the scans into `scans` (else into the frame) and refresh the frame.
    fn call(
        &mut self,
        ops: &[Op],
        actions: &[f32],
        scans: Option<&mut [u8]>,
    ) -> Result<(), RolloutError> {
        let len = self.packed_scans_len();
        let result = match scans {
            Some(out) => {
                if out.len() != len {
                    return invalid(
                        "scans",
                        format!("{} bytes", out.len()),
                        &format!("expected num_envs x learners x beams x 4 = {len} bytes"),
                    );
                }
                self.frame.scans.clear();
                self.apply(ops, actions, out)
            }
            None => {
                let mut packed = std::mem::take(&mut self.packed);
                packed.resize(len, 0);
                let result = self.apply(ops, actions, &mut packed);
                self.frame.scans.clear();
                self.frame.scans.extend(
                    packed
                        .chunks_exact(SCAN_VALUE_BYTES)
                        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
                );
                self.packed = packed;
                result
            }
        };
        self.refresh();
        result
    }

    /// Run `ops` on the batch of worlds (see [`batch`]).
    fn apply(&mut self, ops: &[Op], actions: &[f32], scans: &mut [u8]) -> Result<(), RolloutError> {
        let run = batch::Run {
            slots: &mut self.slots,
            worlds: self.worlds.batch_mut(),
            ops,
            actions,
            cars: &mut self.cars,
            active: &mut self.active,
            scans,
        };
        run.apply(&self.config, self.max_steps, self.pool.as_deref())
    }

    fn refresh(&mut self) {
        let f = &mut self.frame;
        let (agents, learners) = (f.num_agents, f.num_learners);
        for (i, (slot, world)) in self.slots.iter().zip(self.worlds.iter()).enumerate() {
            let Ok(state) = world.state() else {
                continue;
            };
            let obs = &state.observation;
            for a in 0..agents {
                let row = &mut f.states[(i * agents + a) * STATE_SIZE..][..STATE_SIZE];
                row.copy_from_slice(&[
                    obs.poses_x[a],
                    obs.poses_y[a],
                    obs.poses_theta[a],
                    obs.linear_vels_x[a],
                    obs.linear_vels_y[a],
                    obs.ang_vels_z[a],
                    obs.steering_angles[a],
                ]);
                f.agent_collisions[i * agents + a] = obs.collisions[a];
                f.agent_lap_counts[i * agents + a] = obs.lap_counts[a];
                f.agent_lap_times[i * agents + a] = obs.lap_times[a];
            }
            for k in 0..learners {
                let j = i * learners + k;
                f.rewards[j] = slot.rewards[k];
                f.terminated[j] = slot.done[k];
                f.progress[j] = obs.progress[k];
                f.laps[j] = obs.lap_counts[k];
            }
            f.truncated[i] = slot.truncated;
            f.time[i] = state.time;
        }
    }
}

#[cfg(test)]
mod tests;
