//! Batches of episodes behind one interface.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use paddock_sim::circuit::Circuits;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::{EpisodeResult, RolloutError, Scenario, run_episode};

/// One episode to run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpisodeTask {
    pub scenario: Arc<Scenario>,
    pub seed: u64,
    /// Record the trajectory every this many steps.
    pub record: Option<u32>,
}

/// Runs a batch of episodes and returns their results in task order, whatever order
/// they ran in. `progress` is called with the number of finished tasks as they finish.
pub trait Executor: Sync {
    fn run_batch(
        &self,
        tasks: &[EpisodeTask],
        progress: &(dyn Fn(usize) + Sync),
    ) -> Vec<Result<EpisodeResult, RolloutError>>;

    /// How many episodes it runs at once.
    fn parallelism(&self) -> usize;
}

/// Runs episodes on the cores of this process (a rayon pool), on the circuits of one
/// registry: each map is loaded once for all its batches.
pub struct LocalExecutor {
    pool: rayon::ThreadPool,
    circuits: Circuits,
}

impl LocalExecutor {
    /// `threads` = 0: one per core. Scenarios name their maps in `circuits`.
    pub fn new(threads: usize, circuits: Circuits) -> Result<Self, RolloutError> {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("paddock-rollout-{i}"))
            .build()
            .map_err(|e| RolloutError::Invalid {
                field: "threads".into(),
                value: threads.to_string(),
                reason: e.to_string(),
            })?;
        Ok(Self { pool, circuits })
    }
}

impl Executor for LocalExecutor {
    fn run_batch(
        &self,
        tasks: &[EpisodeTask],
        progress: &(dyn Fn(usize) + Sync),
    ) -> Vec<Result<EpisodeResult, RolloutError>> {
        let done = AtomicUsize::new(0);
        self.pool.install(|| {
            tasks
                .par_iter()
                .with_max_len(1)
                .map(|t| {
                    let r = run_episode(&self.circuits, &t.scenario, t.seed, t.record);
                    progress(done.fetch_add(1, Ordering::Relaxed) + 1);
                    r
                })
                .collect()
        })
    }

    fn parallelism(&self) -> usize {
        self.pool.current_num_threads()
    }
}
