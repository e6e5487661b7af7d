//! Interactive environments for learners: [`VecEnv`] holds N independent copies of one
//! environment and steps them together.
//!
//! In every copy the learner drives car 0 with `[steer, speed]` actions; further cars
//! (opponents) are driven by registry drivers. After a reset or a step, [`EnvFrame`] holds
//! every copy's observation: car 0's LIDAR scan as `f32`, every car's state, the reward
//! (weighted by [`RewardWeights`]), and the `terminated` (car 0 crashed or finished) and
//! `truncated` (time limit) flags.
//!
//! Why it looks like this:
//! - **The learner resets.** A copy that has ended is not reset here: stepping it again
//!   changes nothing (reward 0, flags kept) until the learner asks for a reset, either
//!   with [`VecEnv::reset`] or with the `reset_envs` of [`VecEnv::step`] (a next-step
//!   autoreset in the same call). Python's vector env declares that mode.
//! - **Deterministic per seed.** Copy `i` starts with its own seed stream derived from
//!   the session seed; a seeded reset restarts that stream from the given seed, so the
//!   same seeds and actions give the same bits, on any worker, in any thread order.
//! - **All or nothing.** Requests are checked completely before any copy changes, so a
//!   bad action leaves the session as it was.

use std::sync::Arc;

use paddock_policy::{Driver, build_driver, driver_info};
use paddock_sim::geometry::Pose;
use paddock_sim::track::Circuit;
use paddock_sim::world::{Action, AgentStatus, Starts, World};
use rayon::prelude::*;

use crate::{RolloutError, task_seed};

mod config;

use config::invalid;
pub use config::{
    EnvConfig, MAX_BEAMS, MAX_ENVS, MAX_FRAME_SKIP, MAX_OPPONENTS, RewardWeights, STATE_SIZE,
};

/// Every copy's observation after a reset or a step, in flat arrays (env-major), ready
/// to be packed as bytes.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct EnvFrame {
    pub num_envs: usize,
    pub num_agents: usize,
    pub num_beams: usize,
    /// `num_envs x num_beams`: car 0's LIDAR ranges, metres (noise included, >= 0).
    pub scans: Vec<f32>,
    /// `num_envs x num_agents x STATE_SIZE`: `[x, y, theta, vx, vy, yaw_rate, steer]`.
    pub states: Vec<f64>,
    /// `num_envs`: the last step's reward (0 after a reset).
    pub rewards: Vec<f64>,
    /// `num_envs`: car 0 crashed or finished its laps.
    pub terminated: Vec<bool>,
    /// `num_envs`: the time limit ended the episode first.
    pub truncated: Vec<bool>,
    /// `num_envs`: car 0's progress along the track, metres.
    pub progress: Vec<f64>,
    /// `num_envs`: car 0's completed laps.
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
    fn new(num_envs: usize, num_agents: usize, num_beams: usize) -> Self {
        Self {
            num_envs,
            num_agents,
            num_beams,
            scans: vec![0.0; num_envs * num_beams],
            states: vec![0.0; num_envs * num_agents * STATE_SIZE],
            rewards: vec![0.0; num_envs],
            terminated: vec![false; num_envs],
            truncated: vec![false; num_envs],
            progress: vec![0.0; num_envs],
            laps: vec![0; num_envs],
            time: vec![0.0; num_envs],
            agent_collisions: vec![false; num_envs * num_agents],
            agent_lap_counts: vec![0; num_envs * num_agents],
            agent_lap_times: vec![0.0; num_envs * num_agents],
        }
    }
}

/// What to do with one copy in a call.
#[derive(Debug, Clone)]
enum Op {
    Keep,
    Step(Action),
    Reset {
        seed: Option<u64>,
        poses: Option<Vec<Pose>>,
    },
}

/// One copy: its world, its opponents' drivers and its seed stream.
struct Slot {
    world: World,
    opponents: Vec<Box<dyn Driver>>,
    actions: Vec<Action>,
    seed_base: u64,
    episodes: u64,
    reward: f64,
    terminated: bool,
    truncated: bool,
}

impl Slot {
    fn apply(&mut self, op: &Op, config: &EnvConfig, max_steps: u64) -> Result<(), RolloutError> {
        match op {
            Op::Keep => Ok(()),
            Op::Step(a) => self.step(*a, config, max_steps),
            Op::Reset { seed, poses } => self.reset(*seed, poses.clone()),
        }
    }

    /// Car 0's scan as `f32` (noise can dip a range below zero: clamped to 0).
    fn write_scan(&self, out: &mut [f32]) {
        if let Ok(state) = self.world.state() {
            for (dst, &r) in out.iter_mut().zip(state.observation.scan(0)) {
                *dst = r.max(0.0) as f32;
            }
        }
    }

    fn reset(&mut self, seed: Option<u64>, poses: Option<Vec<Pose>>) -> Result<(), RolloutError> {
        let world_seed = match seed {
            Some(s) => {
                self.seed_base = s;
                self.episodes = 1;
                s
            }
            None => {
                let s = task_seed(self.seed_base, self.episodes);
                self.episodes += 1;
                s
            }
        };
        let starts = poses.map_or(Starts::Random, Starts::Poses);
        self.world.reset(world_seed, &starts)?;
        for d in &mut self.opponents {
            d.reset();
        }
        self.reward = 0.0;
        self.terminated = false;
        self.truncated = false;
        Ok(())
    }

    fn step(
        &mut self,
        action: Action,
        config: &EnvConfig,
        max_steps: u64,
    ) -> Result<(), RolloutError> {
        self.reward = 0.0;
        if self.terminated || self.truncated {
            return Ok(());
        }
        let w = config.reward;
        let dt = self.world.config().dt;
        for _ in 0..config.frame_skip {
            let state = self.world.state()?;
            let progress_before = state.agents[0].laps.progress;
            self.actions[0] = action;
            for (k, d) in self.opponents.iter_mut().enumerate() {
                let i = k + 1;
                self.actions[i] = if state.agents[i].status == AgentStatus::Racing {
                    d.act(&state.observation, i)
                } else {
                    Action::default()
                };
            }
            let events = self.world.step(&self.actions)?;
            let state = self.world.state()?;
            let car = &state.agents[0];
            self.reward += w.progress * (car.laps.progress - progress_before)
                + w.collision * f64::from(u8::from(events.collided[0]))
                + w.lap * f64::from(u8::from(events.lap_completed[0]))
                + w.time * dt;
            if car.status != AgentStatus::Racing {
                self.terminated = true;
                break;
            }
            if state.steps >= max_steps {
                self.truncated = true;
                break;
            }
        }
        Ok(())
    }
}

/// N independent copies of one environment, stepped together.
pub struct VecEnv {
    config: EnvConfig,
    circuit: Arc<Circuit>,
    slots: Vec<Slot>,
    frame: EnvFrame,
    max_steps: u64,
}

impl std::fmt::Debug for VecEnv {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VecEnv")
            .field("map", &self.circuit.name)
            .field("num_envs", &self.slots.len())
            .field("num_agents", &self.num_agents())
            .finish()
    }
}

impl VecEnv {
    /// Build the copies and reset each one from its own seed stream.
    pub fn new(config: EnvConfig) -> Result<Self, RolloutError> {
        config.validate()?;
        let circuit = Circuit::resolve(&config.map, &[])?;
        let mut scans = Vec::with_capacity(config.opponents.len());
        for (k, o) in config.opponents.iter().enumerate() {
            scans.push(
                driver_info(&o.driver)
                    .map_err(|source| RolloutError::Driver {
                        agent: k + 1,
                        source,
                    })?
                    .sensors
                    .lidar,
            );
        }
        let world_config = config.world_config(&scans);
        let world = World::new(circuit.clone(), world_config)?;
        let num_agents = world.num_agents();
        let mut slots = Vec::with_capacity(config.num_envs);
        for i in 0..config.num_envs {
            let mut opponents = Vec::with_capacity(config.opponents.len());
            for (k, o) in config.opponents.iter().enumerate() {
                opponents.push(
                    build_driver(&o.driver, &o.params, &circuit, &o.vehicle).map_err(|source| {
                        RolloutError::Driver {
                            agent: k + 1,
                            source,
                        }
                    })?,
                );
            }
            slots.push(Slot {
                world: world.clone(),
                opponents,
                actions: vec![Action::default(); num_agents],
                seed_base: task_seed(config.seed, i as u64),
                episodes: 0,
                reward: 0.0,
                terminated: false,
                truncated: false,
            });
        }
        let max_steps = (config.time_limit / world.config().dt).ceil() as u64;
        let frame = EnvFrame::new(config.num_envs, num_agents, config.lidar.num_beams);
        let mut env = Self {
            config,
            circuit,
            slots,
            frame,
            max_steps,
        };
        let ops = vec![
            Op::Reset {
                seed: None,
                poses: None
            };
            env.num_envs()
        ];
        env.apply(&ops)?;
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

    /// Cars per copy: the learner's and the opponents'.
    pub fn num_agents(&self) -> usize {
        1 + self.config.opponents.len()
    }

    pub fn num_beams(&self) -> usize {
        self.config.lidar.num_beams
    }

    /// Physics step, seconds.
    pub fn dt(&self) -> f64 {
        0.01
    }

    /// The learner's action bounds: `([steer_min, speed_min], [steer_max, speed_max])`.
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
        self.slots.get(i).map(|s| &s.world)
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
        self.apply(&ops)?;
        Ok(&self.frame)
    }

    /// Step every copy with `actions` (`num_envs x [steer, speed]`), except the copies in
    /// `reset_envs`, which are reset from their own seed streams instead. A copy that has
    /// ended and is not reset stays as it is (reward 0).
    pub fn step(
        &mut self,
        actions: &[f32],
        reset_envs: &[usize],
    ) -> Result<&EnvFrame, RolloutError> {
        let n = self.num_envs();
        if actions.len() != 2 * n {
            return invalid(
                "actions",
                format!("{} values", actions.len()),
                &format!("expected num_envs x [steer, speed] = {} values", 2 * n),
            );
        }
        if let Some(k) = actions.iter().position(|a| !a.is_finite()) {
            let what = if k % 2 == 0 { "steer" } else { "speed" };
            return invalid(
                &format!("actions[{k}]"),
                actions[k],
                &format!("env {} {what} must be a finite number", k / 2),
            );
        }
        let mut ops: Vec<Op> = actions
            .chunks_exact(2)
            .map(|a| Op::Step(Action::new(f64::from(a[0]), f64::from(a[1]))))
            .collect();
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
        self.apply(&ops)?;
        Ok(&self.frame)
    }

    /// Run `ops` (one per copy; in parallel for several copies) and refresh the frame.
    fn apply(&mut self, ops: &[Op]) -> Result<(), RolloutError> {
        let config = &self.config;
        let max_steps = self.max_steps;
        let beams = self.frame.num_beams;
        // each copy writes its own scan while still on its thread
        let run = |((s, op), out): ((&mut Slot, &Op), &mut [f32])| {
            let r = s.apply(op, config, max_steps);
            s.write_scan(out);
            r
        };
        let results: Vec<Result<(), RolloutError>> = if self.slots.len() > 1 {
            self.slots
                .par_iter_mut()
                .zip(ops.par_iter())
                .zip(self.frame.scans.par_chunks_mut(beams))
                .map(run)
                .collect()
        } else {
            self.slots
                .iter_mut()
                .zip(ops)
                .zip(self.frame.scans.chunks_mut(beams))
                .map(run)
                .collect()
        };
        self.refresh();
        results.into_iter().collect()
    }

    fn refresh(&mut self) {
        let f = &mut self.frame;
        let agents = f.num_agents;
        for (i, slot) in self.slots.iter().enumerate() {
            let Ok(state) = slot.world.state() else {
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
            f.rewards[i] = slot.reward;
            f.terminated[i] = slot.terminated;
            f.truncated[i] = slot.truncated;
            f.progress[i] = obs.progress[0];
            f.laps[i] = obs.lap_counts[0];
            f.time[i] = state.time;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::AgentSpec;
    use paddock_sim::params::VehicleParams;

    fn cfg(num_envs: usize) -> EnvConfig {
        let mut c = EnvConfig::single("lakeside", num_envs, 7);
        c.lidar.num_beams = 108;
        c
    }

    fn field_of(e: RolloutError) -> String {
        match e {
            RolloutError::Invalid { field, .. } => field,
            other => panic!("expected an Invalid error, got {other}"),
        }
    }

    /// Gentle constant actions: slow and straight-ish.
    fn slow(n: usize) -> Vec<f32> {
        (0..n).flat_map(|i| [0.02 * i as f32, 1.5]).collect()
    }

    #[test]
    fn same_seed_same_bits() {
        let mut a = VecEnv::new(cfg(3)).unwrap();
        let mut b = VecEnv::new(cfg(3)).unwrap();
        assert_eq!(a.frame(), b.frame());
        for _ in 0..20 {
            let fa = a.step(&slow(3), &[]).unwrap().clone();
            let fb = b.step(&slow(3), &[]).unwrap();
            assert_eq!(&fa, fb);
        }
        // a seeded reset restarts the stream: twice the same
        let r1 = a.reset(&[], &[5, 6, 7], None).unwrap().clone();
        a.step(&slow(3), &[]).unwrap();
        let r2 = a.reset(&[], &[5, 6, 7], None).unwrap().clone();
        assert_eq!(r1, r2);
        // different copies start in different places
        assert_ne!(r1.states[0], r1.states[STATE_SIZE]);
        // unseeded resets after a seeded one are deterministic too
        let u1 = a.reset(&[], &[], None).unwrap().clone();
        a.reset(&[], &[5, 6, 7], None).unwrap();
        let u2 = a.reset(&[], &[], None).unwrap().clone();
        assert_eq!(u1, u2);
        assert_ne!(u1.states, r1.states);
    }

    #[test]
    fn copies_are_independent_of_batching() {
        // copy i of a 3-env session equals a 1-env session given the same seed and actions
        let mut batch = VecEnv::new(cfg(3)).unwrap();
        batch.reset(&[], &[11, 12, 13], None).unwrap();
        let acts = slow(3);
        for _ in 0..15 {
            batch.step(&acts, &[]).unwrap();
        }
        for i in 0..3 {
            let mut one = VecEnv::new(cfg(1)).unwrap();
            one.reset(&[], &[11 + i as u64], None).unwrap();
            for _ in 0..15 {
                one.step(&acts[2 * i..2 * i + 2], &[]).unwrap();
            }
            let (f, g) = (batch.frame(), one.frame());
            assert_eq!(&f.scans[i * 108..(i + 1) * 108], &g.scans[..]);
            assert_eq!(
                &f.states[i * STATE_SIZE..(i + 1) * STATE_SIZE],
                &g.states[..]
            );
            assert_eq!(f.rewards[i], g.rewards[0]);
            assert_eq!(f.progress[i], g.progress[0]);
        }
    }

    #[test]
    fn progress_reward_sums_to_progress_and_frame_skip_advances_time() {
        let mut c = cfg(1);
        c.frame_skip = 4;
        c.reward = RewardWeights {
            progress: 1.0,
            collision: 0.0,
            lap: 0.0,
            time: 0.0,
        };
        let mut env = VecEnv::new(c).unwrap();
        env.reset(&[], &[3], None).unwrap();
        let mut total = 0.0;
        for k in 1..=10 {
            let f = env.step(&[0.0, 2.0], &[]).unwrap();
            total += f.rewards[0];
            assert!(
                (f.time[0] - 0.04 * k as f64).abs() < 1e-9,
                "time {}",
                f.time[0]
            );
            assert!(!f.terminated[0] && !f.truncated[0]);
        }
        let f = env.frame();
        assert!(f.progress[0] > 0.1, "the car moved: {}", f.progress[0]);
        assert!((total - f.progress[0]).abs() < 1e-9);
        // a time weight adds weight * seconds
        let mut c = cfg(1);
        c.reward = RewardWeights {
            progress: 0.0,
            collision: 0.0,
            lap: 0.0,
            time: -2.0,
        };
        c.frame_skip = 3;
        let mut env = VecEnv::new(c).unwrap();
        let r = env.step(&[0.0, 1.0], &[]).unwrap().rewards[0];
        assert!((r + 0.06).abs() < 1e-12, "reward {r}");
    }

    #[test]
    fn time_limit_truncates() {
        let mut c = cfg(2);
        c.time_limit = 0.5;
        c.frame_skip = 5;
        let mut env = VecEnv::new(c).unwrap();
        for k in 1..=10 {
            let f = env.step(&slow(2), &[]).unwrap();
            assert_eq!(f.truncated, vec![k == 10; 2], "step {k}");
        }
        assert!((env.frame().time[0] - 0.5).abs() < 1e-12);
        // an ended copy stays as it is until reset
        let before = env.frame().clone();
        let f = env.step(&slow(2), &[]).unwrap();
        assert_eq!(f.rewards, vec![0.0; 2]);
        assert_eq!(f.states, before.states);
        assert_eq!(f.truncated, vec![true; 2]);
        // reset_envs in a step resets that copy and steps the other
        let f = env.step(&slow(2), &[1]).unwrap();
        assert_eq!(f.truncated, vec![true, false]);
        assert_eq!(f.time[1], 0.0);
        assert_eq!(f.rewards[1], 0.0);
    }

    #[test]
    fn a_crash_terminates_with_the_collision_penalty() {
        let mut env = VecEnv::new(cfg(1)).unwrap();
        let mut crashed = None;
        for k in 0..2000 {
            let f = env.step(&[0.4, 8.0], &[]).unwrap();
            if f.terminated[0] {
                crashed = Some((k, f.rewards[0]));
                break;
            }
        }
        let (_, reward) = crashed.expect("full lock at speed hits a wall");
        let f = env.frame();
        assert!(f.agent_collisions[0]);
        assert!(!f.truncated[0]);
        // progress part is small; the penalty dominates
        assert!(reward < -9.0, "reward {reward}");
    }

    #[test]
    fn opponents_drive_themselves() {
        let mut c = cfg(2);
        c.opponents = vec![AgentSpec::with_defaults("pure-pursuit").unwrap()];
        let mut env = VecEnv::new(c).unwrap();
        assert_eq!(env.num_agents(), 2);
        let start = env.frame().states.clone();
        for _ in 0..100 {
            env.step(&[0.0, 0.0, 0.0, 0.0], &[]).unwrap();
        }
        let f = env.frame();
        assert_eq!(f.states.len(), 2 * 2 * STATE_SIZE);
        assert_eq!(f.agent_lap_counts.len(), 4);
        // the opponent (car 1) moved, the learner standing still did not go far
        let opp = STATE_SIZE;
        let moved = (f.states[opp] - start[opp]).hypot(f.states[opp + 1] - start[opp + 1]);
        assert!(moved > 1.0, "opponent moved {moved} m");
        assert!(f.states[3].abs() < 0.5, "learner speed {}", f.states[3]);
    }

    #[test]
    fn reset_to_given_poses() {
        let mut env = VecEnv::new(cfg(2)).unwrap();
        let p0 = *env
            .world(0)
            .unwrap()
            .start_poses_for(99, &Starts::Random)
            .unwrap()
            .first()
            .unwrap();
        let p1 = Pose::new(p0.x, p0.y, p0.theta + 0.1);
        let f = env.reset(&[1], &[], Some(&[p1])).unwrap();
        let row = &f.states[STATE_SIZE..2 * STATE_SIZE];
        assert_eq!((row[0], row[1], row[2]), (p1.x, p1.y, p1.theta));
        assert_eq!(f.time[1], 0.0);
    }

    #[test]
    fn bad_requests_name_the_field_and_change_nothing() {
        let mut env = VecEnv::new(cfg(2)).unwrap();
        env.step(&slow(2), &[]).unwrap();
        let before = env.frame().clone();
        let e = env.step(&[0.0; 3], &[]).unwrap_err();
        assert!(
            e.to_string()
                .contains("expected num_envs x [steer, speed] = 4"),
            "{e}"
        );
        assert_eq!(field_of(e), "actions");
        let e = env.step(&[0.0, 1.0, 0.0, f32::NAN], &[]).unwrap_err();
        assert!(e.to_string().contains("env 1 speed"), "{e}");
        assert_eq!(field_of(e), "actions[3]");
        assert_eq!(
            field_of(env.step(&slow(2), &[2]).unwrap_err()),
            "reset_envs[0]"
        );
        assert_eq!(field_of(env.reset(&[5], &[], None).unwrap_err()), "envs[0]");
        assert_eq!(
            field_of(env.reset(&[0, 0], &[], None).unwrap_err()),
            "envs[1]"
        );
        assert_eq!(field_of(env.reset(&[], &[1], None).unwrap_err()), "seeds");
        assert_eq!(
            field_of(env.reset(&[0], &[], Some(&[])).unwrap_err()),
            "poses"
        );
        let nan = Pose::new(0.0, f64::NAN, 0.0);
        assert_eq!(
            field_of(env.reset(&[0], &[], Some(&[nan])).unwrap_err()),
            "poses[0]"
        );
        assert_eq!(env.frame(), &before);

        let check = |f: fn(&mut EnvConfig), field: &str| {
            let mut c = cfg(1);
            f(&mut c);
            let e = VecEnv::new(c).unwrap_err();
            assert!(e.to_string().contains(field), "{field}: {e}");
        };
        check(|c| c.num_envs = 0, "num_envs");
        check(|c| c.frame_skip = 0, "frame_skip");
        check(|c| c.time_limit = f64::NAN, "time_limit");
        check(|c| c.reward.collision = f64::INFINITY, "reward.collision");
        check(|c| c.lidar.num_beams = 0, "lidar.num_beams");
        check(|c| c.laps = 0, "laps");
        check(
            |c| {
                c.opponents = vec![AgentSpec {
                    driver: "nobody".into(),
                    params: vec![],
                    vehicle: VehicleParams::default(),
                }]
            },
            "opponents[0].driver",
        );
        check(
            |c| {
                let mut o = AgentSpec::with_defaults("pure-pursuit").unwrap();
                o.params[0] = f64::NAN;
                c.opponents = vec![o];
            },
            "opponents[0].params",
        );
        let e = VecEnv::new(EnvConfig::single("no-such-map", 1, 0)).unwrap_err();
        assert!(e.to_string().contains("no-such-map"), "{e}");
    }
}
