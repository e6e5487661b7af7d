//! One copy of the environment: its world, its opponents' drivers, its seed stream and
//! what its learners got from the last call.

use paddock_policy::Driver;
use paddock_sim::geometry::Pose;
use paddock_sim::world::{Action, AgentStatus, Starts, World};

use super::EnvConfig;
use crate::{RolloutError, task_seed};

/// What to do with one copy in a call.
#[derive(Debug, Clone)]
pub(super) enum Op {
    Keep,
    /// One action per learner car.
    Step(Vec<Action>),
    Reset {
        seed: Option<u64>,
        poses: Option<Vec<Pose>>,
    },
}

/// One copy. Cars `0..learners` are the learners', the rest the opponents'.
pub(super) struct Slot {
    pub(super) world: World,
    pub(super) opponents: Vec<Box<dyn Driver>>,
    pub(super) actions: Vec<Action>,
    pub(super) seed_base: u64,
    pub(super) episodes: u64,
    /// Per learner: the last step's reward.
    pub(super) rewards: Vec<f64>,
    /// Per learner: out of the race (crashed or finished).
    pub(super) done: Vec<bool>,
    pub(super) truncated: bool,
    /// Per learner: progress before the physics step (kept to reuse its memory).
    progress_before: Vec<f64>,
}

impl Slot {
    pub(super) fn new(
        world: World,
        opponents: Vec<Box<dyn Driver>>,
        learners: usize,
        seed_base: u64,
    ) -> Self {
        let cars = world.num_agents();
        Self {
            world,
            opponents,
            actions: vec![Action::default(); cars],
            seed_base,
            episodes: 0,
            rewards: vec![0.0; learners],
            done: vec![false; learners],
            truncated: false,
            progress_before: vec![0.0; learners],
        }
    }

    /// Every learner is out of the race, or the time limit ended the episode: stepping
    /// changes nothing until a reset.
    pub(super) fn ended(&self) -> bool {
        self.truncated || self.done.iter().all(|&d| d)
    }

    pub(super) fn apply(
        &mut self,
        op: &Op,
        config: &EnvConfig,
        max_steps: u64,
    ) -> Result<(), RolloutError> {
        match op {
            Op::Keep => Ok(()),
            Op::Step(a) => self.step(a, config, max_steps),
            Op::Reset { seed, poses } => self.reset(*seed, poses.clone()),
        }
    }

    /// The learners' scans as `f32`, learner-major (noise can dip a range below zero:
    /// clamped to 0).
    pub(super) fn write_scans(&self, out: &mut [f32], beams: usize) {
        if let Ok(state) = self.world.state() {
            for (k, dst) in out.chunks_exact_mut(beams).enumerate() {
                for (d, &r) in dst.iter_mut().zip(state.observation.scan(k)) {
                    *d = r.max(0.0) as f32;
                }
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
        self.rewards.iter_mut().for_each(|r| *r = 0.0);
        self.done.iter_mut().for_each(|d| *d = false);
        self.truncated = false;
        Ok(())
    }

    /// `frame_skip` physics steps with the learners' `actions` held; a learner out of the
    /// race gets no reward and its action is not used.
    fn step(
        &mut self,
        actions: &[Action],
        config: &EnvConfig,
        max_steps: u64,
    ) -> Result<(), RolloutError> {
        self.rewards.iter_mut().for_each(|r| *r = 0.0);
        if self.ended() {
            return Ok(());
        }
        let w = config.reward;
        let dt = self.world.config().dt;
        let learners = actions.len();
        for _ in 0..config.frame_skip {
            let state = self.world.state()?;
            for (b, a) in self.progress_before.iter_mut().zip(&state.agents) {
                *b = a.laps.progress;
            }
            for (k, a) in actions.iter().enumerate() {
                self.actions[k] = if self.done[k] { Action::default() } else { *a };
            }
            for (j, d) in self.opponents.iter_mut().enumerate() {
                let i = learners + j;
                self.actions[i] = if state.agents[i].status == AgentStatus::Racing {
                    d.act(&state.observation, i)
                } else {
                    Action::default()
                };
            }
            let events = self.world.step(&self.actions)?;
            let state = self.world.state()?;
            for (k, progress_before) in self.progress_before.iter().enumerate() {
                if self.done[k] {
                    continue;
                }
                let car = &state.agents[k];
                self.rewards[k] += w.progress * (car.laps.progress - progress_before)
                    + w.collision * f64::from(u8::from(events.collided[k]))
                    + w.lap * f64::from(u8::from(events.lap_completed[k]))
                    + w.time * dt;
                self.done[k] = car.status != AgentStatus::Racing;
            }
            if self.done.iter().all(|&d| d) {
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
