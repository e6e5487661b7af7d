//! What the broker asks of the domain, as a small trait a crate above it implements
//! (`paddock-jobs`): the broker routes, keeps credit and liveness, stores and reduces,
//! and knows nothing of scenarios, drivers or the simulator.
//!
//! A [`Planner`] checks what clients hand in that only the domain can judge (a batch's
//! scenarios, what a map's files say) and turns job submissions into [`JobPlan`]s. A
//! plan is a sequence of map/reduce rounds: it hands out a [`Round`] of tasks, is told
//! the round's outcomes in task order (each the encoded `TaskOutcome` a worker sent, as
//! bytes), and after every round says what to store so a restarted broker can resume it.
//!
//! Every call runs on the broker's back-office thread, never on the socket thread, so
//! a CMA-ES update, a benchmark report or loading a map delays no heartbeat and no env
//! step.

use std::path::PathBuf;

use paddock_proto::{Error, JobSubmit, MapBundle, RolloutBatch, RolloutTaskSpec};

/// What the broker stores, as the plans read it: maps and blobs (model files), by hash.
pub trait Stored {
    /// The folder holding the files of the stored map with this hash; None when it is not
    /// stored.
    fn map_dir(&self, hash: &str) -> Option<PathBuf>;

    /// The bytes of the stored blob with this hash (a model file a client stored with
    /// `PutBlob`); None when it is not stored.
    fn blob(&self, hash: &str) -> Option<Vec<u8>>;
}

/// One round of a job: its scenarios (each an encoded `paddock.v1.Scenario`) and tasks
/// naming them by index, as a client's batch does.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Round {
    pub scenarios: Vec<Vec<u8>>,
    pub tasks: Vec<RolloutTaskSpec>,
}

/// A finished job's result: its document (the JSON the local command writes with
/// `--json`) and, for stored batches, the outcomes in task order.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct JobOutput {
    pub json: String,
    pub outcomes: Vec<Vec<u8>>,
}

/// What one task of a scenario asks of a worker, as the planner reads it from the
/// scenario: the broker derives the task's deadline and the size of its result from it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TaskBudget {
    /// The most simulated seconds an episode may last.
    pub sim_seconds: f64,
    /// The most physics steps an episode may take.
    pub steps: u64,
    /// Cars in the episode.
    pub agents: u32,
    /// Laps an episode may run (each car's lap times grow with them).
    pub laps: u32,
}

impl TaskBudget {
    /// The most bytes a task's outcome can take with the trajectory recorded every
    /// `record_decimation` steps (0: no trajectory): the episode's summary (a little
    /// over 100 bytes per car and 8 per lap time), and per sample its time and five f64
    /// per car (`paddock.v1.Trajectory`).
    pub fn result_bytes(&self, record_decimation: u32) -> u64 {
        let agents = u64::from(self.agents);
        let summary = 128 + agents * (128 + 8 * u64::from(self.laps.min(10_000)));
        if record_decimation == 0 {
            return summary;
        }
        let samples = self.steps / u64::from(record_decimation) + 2;
        summary + samples * 8 * (1 + 5 * agents) + agents * 64
    }
}

/// The domain side of jobs and batches; see the module documentation.
pub trait Planner: Send + 'static {
    /// What a task of this scenario (an encoded `paddock.v1.Scenario`) asks of a
    /// worker; None when the planner does not read scenarios (the broker then gives its
    /// tasks a fixed deadline and checks no result size before the work).
    fn budget(&self, scenario: &[u8]) -> Option<TaskBudget> {
        let _ = scenario;
        None
    }

    /// Checks every scenario and task of a batch before it is queued; an error names the
    /// first bad field under `prefix` (e.g. `rollout_batch.scenarios[2].laps`).
    fn check_batch(
        &self,
        batch: &RolloutBatch,
        maps: &dyn Stored,
        prefix: &str,
    ) -> Result<(), Error>;

    /// Checks what the files of a map bundle say (its form, names, size and hash, the
    /// broker checks itself).
    fn check_map(&self, bundle: &MapBundle) -> Result<(), Error>;

    /// The plan of a submitted job; an error names the bad field (`job_submit.tune.driver`).
    fn plan(&self, submit: &JobSubmit, maps: &dyn Stored) -> Result<Box<dyn JobPlan>, Error>;

    /// A stored job again: its submission and the state it stored after its last round.
    fn restore(
        &self,
        submit: &JobSubmit,
        state: &str,
        maps: &dyn Stored,
    ) -> Result<Box<dyn JobPlan>, String>;
}

/// A job as rounds; see the module documentation.
pub trait JobPlan: Send {
    /// "tune", "rollouts" or "benchmark".
    fn kind(&self) -> &'static str;

    /// The tasks of the next round (the same round until told), or None when done.
    fn next_round(&mut self) -> Result<Option<Round>, String>;

    /// The outcomes of the round from [`JobPlan::next_round`], in task order.
    fn tell(&mut self, outcomes: &[&[u8]]) -> Result<(), String>;

    /// (rounds done, rounds planned).
    fn rounds(&self) -> (u32, u32);

    fn episodes_done(&self) -> u64;

    /// Kind-specific progress, e.g. `{"best_so_far": 15.9}`.
    fn progress_json(&self) -> String;

    /// What must be stored to resume it.
    fn state_json(&self) -> String;

    /// The result, once done.
    fn result(&self) -> Option<JobOutput>;
}

/// A planner that accepts every batch unchecked and runs no jobs: a broker that only
/// routes (tests of the routing, benchmarks of the broker alone). Workers still check
/// every scenario they run and answer a bad one with an error outcome.
#[derive(Debug, Default, Clone, Copy)]
pub struct RouteOnly;

impl Planner for RouteOnly {
    fn check_batch(&self, batch: &RolloutBatch, _: &dyn Stored, prefix: &str) -> Result<(), Error> {
        check_task_indices(batch, prefix)
    }

    fn check_map(&self, _: &MapBundle) -> Result<(), Error> {
        Ok(())
    }

    fn plan(&self, _: &JobSubmit, _: &dyn Stored) -> Result<Box<dyn JobPlan>, Error> {
        Err(paddock_proto::error(
            paddock_proto::ErrorCode::InvalidArgument,
            "job_submit",
            "this broker runs no jobs (it was started without job plans)",
        ))
    }

    fn restore(&self, _: &JobSubmit, _: &str, _: &dyn Stored) -> Result<Box<dyn JobPlan>, String> {
        Err("this broker runs no jobs (it was started without job plans)".into())
    }
}

/// Checks that every task of a batch names one of its scenarios.
pub fn check_task_indices(batch: &RolloutBatch, prefix: &str) -> Result<(), Error> {
    for (j, t) in batch.tasks.iter().enumerate() {
        if t.scenario as usize >= batch.scenarios.len() {
            return Err(paddock_proto::error(
                paddock_proto::ErrorCode::InvalidArgument,
                format!("{prefix}.tasks[{j}].scenario"),
                format!(
                    "{prefix}.tasks[{j}].scenario = {} but the batch has {} scenarios",
                    t.scenario,
                    batch.scenarios.len()
                ),
            ));
        }
    }
    Ok(())
}
