//! # paddock-rollout: episodes, batches and the benchmark tasks
//!
//! An episode is a pure function of (scenario, seed): the scenario names the map, the
//! cars with their drivers and parameters, how they start, the obstacles and when the
//! episode ends; the seed fixes every random choice (start poses, obstacles, LIDAR
//! noise). [`run_episode`] returns per-agent results (lap times, collision, progress,
//! termination reason, return) and, on request, the trajectory.
//!
//! Batches run behind one interface, [`Executor`]: a list of tasks in, results out in
//! task order. [`LocalExecutor`] runs them on all cores of this process; a remote
//! executor (the broker) implements the same trait, so tuning and benchmarks do not
//! care where episodes run.

pub mod benchmark;
pub mod env;
mod episode;
mod executor;
mod scenario;
pub mod tune_job;

pub use episode::{
    AgentResult, AgentTrace, EpisodeResult, Termination, Trajectory, episode_world, run_episode,
};
pub use executor::{EpisodeTask, Executor, LocalExecutor};
pub use scenario::{AgentSpec, Scenario, StartSpec};

/// Errors from building or running an episode; each names the field and value.
#[derive(Debug, thiserror::Error)]
pub enum RolloutError {
    #[error("invalid scenario: {field} = {value}: {reason}")]
    Invalid {
        field: String,
        value: String,
        reason: String,
    },
    #[error(transparent)]
    Map(#[from] paddock_sim::track::TrackError),
    #[error("agent {agent}: {source}")]
    Driver {
        agent: usize,
        source: paddock_policy::PolicyError,
    },
    #[error(transparent)]
    World(#[from] paddock_sim::world::WorldError),
    /// The episodes could not be run where they were sent (a broker that does not
    /// answer, restarted too often, or sent an undecodable reply): nothing is wrong
    /// with the scenario.
    #[error("broker at {endpoint}: {reason}")]
    Transport { endpoint: String, reason: String },
}

impl RolloutError {
    /// A refused field: names the field, its value and the reason.
    pub fn invalid(field: &str, value: impl ToString, reason: &str) -> Self {
        Self::Invalid {
            field: field.into(),
            value: value.to_string(),
            reason: reason.into(),
        }
    }
}

/// The seed of task `index` of a job with seed `job_seed`: a pure function of the two
/// (never of arrival order or worker), well mixed so neighbouring tasks are unrelated.
pub fn task_seed(job_seed: u64, index: u64) -> u64 {
    // SplitMix64 finaliser over the pair
    let mut z = job_seed
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add(index.wrapping_mul(0xD1B5_4A32_D192_ED03))
        .wrapping_add(0x632B_E59B_D9B4_E019);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    #[test]
    fn task_seeds_differ() {
        let mut seen = std::collections::HashSet::new();
        for job in 0..10 {
            for i in 0..100 {
                assert!(seen.insert(super::task_seed(job, i)));
            }
        }
        assert_eq!(super::task_seed(3, 4), super::task_seed(3, 4));
    }
}
