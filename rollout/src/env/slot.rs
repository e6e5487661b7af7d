//! One copy of the environment beside its world: its opponents' drivers, its seed
//! stream and what its learners got from the last call. The copies' worlds live together
//! in the env's [`Worlds`](paddock_sim::world::Worlds); each call hands a slot its own.

use paddock_policy::Driver;
use paddock_sim::geometry::Pose;
use paddock_sim::world::{Action, AgentStatus, Starts, StepEvents, World};

use crate::{RolloutError, task_seed};

/// What to do with one copy in a call.
#[derive(Debug, Clone)]
pub(super) enum Op {
    Keep,
    /// Step with this copy's learner actions (from the call's action slice).
    Step,
    Reset {
        seed: Option<u64>,
        poses: Option<Vec<Pose>>,
    },
}

/// One copy. Cars `0..learners` are the learners', the rest the opponents'.
pub(super) struct Slot {
    pub(super) opponents: Vec<Box<dyn Driver>>,
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
    pub(super) fn new(opponents: Vec<Box<dyn Driver>>, learners: usize, seed_base: u64) -> Self {
        Self {
            opponents,
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

    pub(super) fn reset(
        &mut self,
        world: &mut World,
        seed: Option<u64>,
        poses: Option<Vec<Pose>>,
    ) -> Result<(), RolloutError> {
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
        world.reset(world_seed, &starts)?;
        for d in &mut self.opponents {
            d.reset();
        }
        self.rewards.iter_mut().for_each(|r| *r = 0.0);
        self.done.iter_mut().for_each(|d| *d = false);
        self.truncated = false;
        Ok(())
    }

    /// The start of a step of `frame_skip` physics steps: the rewards start from 0;
    /// whether the copy steps at all (an ended copy stays as it is).
    pub(super) fn begin_step(&mut self) -> bool {
        self.rewards.iter_mut().for_each(|r| *r = 0.0);
        !self.ended()
    }

    /// Before a physics step: note each learner's progress and write every car's action
    /// into `cars` (the learners' `learner` actions, `[steer, speed]` as `f32`; a
    /// learner out of the race stands still; the opponents' drivers act on the world's
    /// observation).
    pub(super) fn prepare(
        &mut self,
        world: &World,
        learner: &[f32],
        cars: &mut [Action],
    ) -> Result<(), RolloutError> {
        let state = world.state()?;
        for (b, a) in self.progress_before.iter_mut().zip(&state.agents) {
            *b = a.laps.progress;
        }
        let learners = self.done.len();
        for (k, a) in learner.chunks_exact(2).enumerate() {
            cars[k] = if self.done[k] {
                Action::default()
            } else {
                Action::new(f64::from(a[0]), f64::from(a[1]))
            };
        }
        for (j, d) in self.opponents.iter_mut().enumerate() {
            let i = learners + j;
            cars[i] = if state.agents[i].status == AgentStatus::Racing {
                d.act(&state.observation, i)
            } else {
                Action::default()
            };
        }
        world.check_actions(cars)?;
        Ok(())
    }

    /// After a physics step: each learner's reward and end; whether the copy goes on
    /// with the next physics step of the call.
    pub(super) fn finish(
        &mut self,
        world: &World,
        events: &StepEvents,
        config: &super::EnvConfig,
        max_steps: u64,
    ) -> Result<bool, RolloutError> {
        let w = config.reward;
        let dt = world.config().dt;
        let state = world.state()?;
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
            return Ok(false);
        }
        if state.steps >= max_steps {
            self.truncated = true;
            return Ok(false);
        }
        Ok(true)
    }
}
