//! One call's work on the copies' worlds as a batch: resets, then `frame_skip` batch
//! steps of the copies that step (each copy's opponents act and its learners' rewards
//! add up between them), with the learners' scans written into the caller's buffer by
//! the last batch step, each right after its world's step.
//!
//! With several rayon threads the copies are cut into a few runs of consecutive copies,
//! one batch each, stepped on the pool's threads; a copy's bits do not depend on the
//! cut (nothing a copy reads is changed by another).

use paddock_sim::world::{Action, PackedObservations, WorldsMut};
use rayon::prelude::*;

use super::EnvConfig;
use super::slot::{Op, Slot};
use crate::RolloutError;

/// Runs per rayon thread: a little more than one, so a thread that finishes early takes
/// another.
const RUNS_PER_THREAD: usize = 4;

/// A run of consecutive copies and everything of theirs one call reads and writes.
pub(super) struct Run<'a> {
    pub(super) slots: &'a mut [Slot],
    pub(super) worlds: WorldsMut<'a>,
    pub(super) ops: &'a [Op],
    /// The learners' actions (`[steer, speed]` per learner) of every copy of the run;
    /// empty in a call that steps no copy.
    pub(super) actions: &'a [f32],
    /// Every car's action of every copy of the run (reused).
    pub(super) cars: &'a mut [Action],
    /// Which copies of the run step in the current physics step (reused).
    pub(super) active: &'a mut [bool],
    /// The learners' packed scans of every copy of the run.
    pub(super) scans: &'a mut [u8],
}

impl<'a> Run<'a> {
    /// Runs the ops, on several threads when the pool has them (`pool`, else the calling
    /// thread's rayon pool); the first error of any copy (the others still run).
    pub(super) fn apply(
        self,
        config: &EnvConfig,
        max_steps: u64,
        pool: Option<&rayon::ThreadPool>,
    ) -> Result<(), RolloutError> {
        // one thread (a worker pinned to one core): the calling thread steps them all,
        // with no hand-over to the pool and back
        let threads = pool.map_or_else(rayon::current_num_threads, |p| p.current_num_threads());
        let runs = (threads * RUNS_PER_THREAD).min(self.slots.len());
        if threads <= 1 || runs <= 1 {
            return self.run(config, max_steps);
        }
        let mut parts = Vec::with_capacity(runs);
        let mut rest = self;
        for k in 0..runs {
            let left = rest.slots.len();
            let size = left / (runs - k);
            if k + 1 == runs {
                parts.push(rest);
                break;
            }
            let (head, tail) = rest.split_at(size);
            parts.push(head);
            rest = tail;
        }
        let step = move || -> Vec<Result<(), RolloutError>> {
            parts
                .into_par_iter()
                .map(|r| r.run(config, max_steps))
                .collect()
        };
        let results = match pool {
            Some(p) => p.install(step),
            None => step(),
        };
        results.into_iter().collect()
    }

    /// Copies `0..at` and `at..` of this run.
    fn split_at(self, at: usize) -> (Run<'a>, Run<'a>) {
        let n = self.slots.len();
        let cars = self.cars.len() / n;
        let scan = self.scans.len() / n;
        let act = self.actions.len() / n;
        let (s0, s1) = self.slots.split_at_mut(at);
        let (w0, w1) = self.worlds.split_at(at);
        let (o0, o1) = self.ops.split_at(at);
        let (a0, a1) = self.actions.split_at(at * act);
        let (c0, c1) = self.cars.split_at_mut(at * cars);
        let (f0, f1) = self.active.split_at_mut(at);
        let (p0, p1) = self.scans.split_at_mut(at * scan);
        (
            Run {
                slots: s0,
                worlds: w0,
                ops: o0,
                actions: a0,
                cars: c0,
                active: f0,
                scans: p0,
            },
            Run {
                slots: s1,
                worlds: w1,
                ops: o1,
                actions: a1,
                cars: c1,
                active: f1,
                scans: p1,
            },
        )
    }

    /// Runs the ops of this run's copies on this thread.
    fn run(self, config: &EnvConfig, max_steps: u64) -> Result<(), RolloutError> {
        let Run {
            slots,
            mut worlds,
            ops,
            actions,
            cars,
            active,
            scans,
        } = self;
        let n = slots.len();
        if n == 0 {
            return Ok(());
        }
        let agents = cars.len() / n;
        let per_copy = actions.len() / n;
        let mut out = PackedObservations::scans(scans, config.learners);
        let mut first_error = None;
        let mut stepping = false;
        for (k, (slot, op)) in slots.iter_mut().zip(ops).enumerate() {
            active[k] = false;
            match op {
                Op::Keep => {}
                Op::Step => {
                    active[k] = slot.begin_step();
                    stepping |= active[k];
                }
                Op::Reset { seed, poses } => {
                    if let Err(e) = slot.reset(worlds.world_mut(k), *seed, poses.clone()) {
                        first_error.get_or_insert(e);
                    }
                }
            }
        }
        if !stepping {
            // a copy's own error first: a failed first reset leaves nothing to pack
            let packed = worlds.pack(&mut out);
            return match first_error {
                Some(e) => Err(e),
                None => packed.map_err(RolloutError::from),
            };
        }
        let skip = config.frame_skip.max(1);
        for sub in 0..skip {
            for (k, slot) in slots.iter_mut().enumerate() {
                if !active[k] {
                    continue;
                }
                let learner = &actions[k * per_copy..(k + 1) * per_copy];
                let mine = &mut cars[k * agents..(k + 1) * agents];
                if let Err(e) = slot.prepare(worlds.world(k), learner, mine) {
                    active[k] = false;
                    first_error.get_or_insert(e);
                }
            }
            let last = sub + 1 == skip;
            if !last && !active.iter().any(|&a| a) {
                continue;
            }
            worlds.step(cars, active, last.then_some(&mut out))?;
            for (k, slot) in slots.iter_mut().enumerate() {
                if !active[k] {
                    continue;
                }
                match slot.finish(worlds.world(k), worlds.events(k), config, max_steps) {
                    Ok(go) => active[k] = go,
                    Err(e) => {
                        active[k] = false;
                        first_error.get_or_insert(e);
                    }
                }
            }
        }
        first_error.map_or(Ok(()), Err)
    }
}
