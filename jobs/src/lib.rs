//! # paddock-jobs: the job plans the broker runs
//!
//! The broker routes and reduces; what a job *is* lives here, above it, behind its
//! [`Planner`] trait ([`Plans`]):
//!
//! - a **tune** job is the same [`TuneJob`](paddock_rollout::tune_job::TuneJob) as the
//!   local `paddock tune` (CMA-ES generations, validation, hold-out), so its result is
//!   the same document;
//! - a **benchmark** job is one round of the benchmark's episodes reduced to its report;
//! - a **rollouts** job is a stored batch: one round, its outcomes kept as they came.
//!
//! A job is checked when submitted (every field, the map by hash), then alternates
//! between handing out a round of tasks and being told its outcomes in task order.
//! After every round the broker stores [`JobPlan::state_json`]; [`Planner::restore`]
//! rebuilds the job from its stored spec and state, so a restarted broker resumes it.
//! The broker calls all of this on its back-office thread.
//!
//! The same [`Plans`] also checks what only the domain can judge of a client's batch
//! (every scenario, through [`paddock_wire`]) and of a map bundle (what its files say).

mod benchmark;
mod rollouts;
mod tune;

use std::path::PathBuf;

use paddock_broker::plan::{JobPlan, Planner, Stored, check_task_indices};
use paddock_proto::{
    Error, ErrorCode, JobSubmit, MapBundle, MapRef, RolloutBatch, error, job_submit,
};
use paddock_wire::with_prefix;

pub use benchmark::BenchmarkPlan;
pub use rollouts::RolloutsPlan;
pub use tune::TunePlan;

/// The job plans of the `paddock` broker; see the crate documentation.
#[derive(Debug, Default, Clone, Copy)]
pub struct Plans;

pub(crate) fn invalid(field: impl Into<String>, message: impl Into<String>) -> Error {
    error(ErrorCode::InvalidArgument, field, message)
}

/// Checks a map reference: a stored hash, else NOT_FOUND naming `field`; the folder of
/// its files.
pub(crate) fn check_map(
    map: Option<&MapRef>,
    maps: &dyn Stored,
    field: &str,
) -> Result<(MapRef, PathBuf), Error> {
    let Some(m) = map else {
        return Err(invalid(
            field,
            format!("{field} is missing: a map is named by its content hash"),
        ));
    };
    match maps.map_dir(&m.hash) {
        Some(dir) => Ok((m.clone(), dir)),
        None => Err(error(
            ErrorCode::NotFound,
            format!("{field}.hash"),
            format!(
                "map {:?} with hash {:?} is not stored in this broker: send put_map, then retry",
                m.name, m.hash
            ),
        )),
    }
}

/// Registers the ONNX models `agents` name (`onnx:<sha256>`) that this process has not
/// registered yet, from the blobs the broker stores, so the checks that follow judge
/// them like any driver; `driver_field(i)` names car `i`'s driver in errors. NOT_FOUND
/// when a model is not stored (a client stores it with `PutBlob` first).
pub(crate) fn register_models(
    agents: &[paddock_proto::AgentSpec],
    stored: &dyn Stored,
    driver_field: impl Fn(usize) -> String,
) -> Result<(), Error> {
    for hash in paddock_wire::unregistered_models(agents) {
        let i = agents
            .iter()
            .position(|a| paddock_wire::model_hash_of(&a.driver) == Some(hash.as_str()))
            .unwrap_or(0);
        let field = driver_field(i);
        let Some(bytes) = stored.blob(&hash) else {
            return Err(error(
                ErrorCode::NotFound,
                field.clone(),
                format!(
                    "{field} = onnx:{hash}: the model is not stored in this broker: send put_blob with the model's bytes, then retry"
                ),
            ));
        };
        paddock_wire::register_model(&hash, &bytes).map_err(|r| r.to_error(&field))?;
    }
    Ok(())
}

/// Checks every scenario of a batch (decoded, every field, its map stored) and every
/// task index; errors name the field under `prefix`.
pub(crate) fn check_batch(
    batch: &RolloutBatch,
    maps: &dyn Stored,
    prefix: &str,
) -> Result<(), Error> {
    for (i, bytes) in batch.scenarios.iter().enumerate() {
        let field = format!("{prefix}.scenarios[{i}]");
        let wire =
            <paddock_proto::Scenario as prost::Message>::decode(bytes.as_slice()).map_err(|e| {
                error(
                    ErrorCode::BadMessage,
                    field.clone(),
                    format!(
                        "{field}: {} bytes do not decode as a Scenario: {e}",
                        bytes.len()
                    ),
                )
            })?;
        let (_, dir) = check_map(wire.map.as_ref(), maps, &format!("{field}.map"))?;
        register_models(&wire.agents, maps, |i| {
            format!("{field}.agents[{i}].driver")
        })?;
        paddock_wire::scenario_from_proto(&wire, &dir).map_err(|e| with_prefix(e, &field))?;
    }
    check_task_indices(batch, prefix)
}

/// What an episode of `time_limit` simulated seconds with `agents` cars and `laps` laps
/// asks of a worker (its deadline and the size of its result, see
/// [`paddock_broker::TaskBudget`]); episodes step at the simulator's default timestep.
pub fn episode_budget(time_limit: f64, agents: usize, laps: u32) -> paddock_broker::TaskBudget {
    paddock_broker::TaskBudget {
        sim_seconds: time_limit,
        steps: (time_limit / paddock_sim::world::WorldConfig::default().dt).ceil() as u64,
        agents: u32::try_from(agents).unwrap_or(u32::MAX),
        laps,
    }
}

impl Planner for Plans {
    fn budget(&self, scenario: &[u8]) -> Option<paddock_broker::TaskBudget> {
        let wire = <paddock_proto::Scenario as prost::Message>::decode(scenario).ok()?;
        if !(wire.time_limit.is_finite() && wire.time_limit > 0.0) {
            return None;
        }
        Some(episode_budget(
            wire.time_limit,
            wire.agents.len(),
            wire.laps,
        ))
    }

    fn check_batch(
        &self,
        batch: &RolloutBatch,
        maps: &dyn Stored,
        prefix: &str,
    ) -> Result<(), Error> {
        check_batch(batch, maps, prefix)
    }

    fn check_map(&self, bundle: &MapBundle) -> Result<(), Error> {
        paddock_wire::check_map_bundle(bundle)
    }

    fn plan(&self, submit: &JobSubmit, maps: &dyn Stored) -> Result<Box<dyn JobPlan>, Error> {
        match &submit.spec {
            None => Err(invalid(
                "job_submit.spec",
                "a job needs a spec: tune, rollouts or benchmark",
            )),
            Some(job_submit::Spec::Tune(t)) => Ok(Box::new(TunePlan::new(t, maps)?)),
            Some(job_submit::Spec::Rollouts(b)) => Ok(Box::new(RolloutsPlan::new(b, maps)?)),
            Some(job_submit::Spec::Benchmark(b)) => Ok(Box::new(BenchmarkPlan::new(b, maps)?)),
        }
    }

    fn restore(
        &self,
        submit: &JobSubmit,
        state: &str,
        maps: &dyn Stored,
    ) -> Result<Box<dyn JobPlan>, String> {
        let refused =
            |e: Error| format!("stored job spec is refused now: {}: {}", e.field, e.message);
        match &submit.spec {
            Some(job_submit::Spec::Tune(t)) => {
                let mut plan = TunePlan::new(t, maps).map_err(refused)?;
                if !state.is_empty() {
                    plan.restore(state)?;
                }
                Ok(Box::new(plan))
            }
            _ => self.plan(submit, maps).map_err(refused),
        }
    }
}

/// Wire rounds of domain tasks on `map`: scenarios shared between tasks are encoded once.
pub(crate) fn round_of(
    tasks: &[paddock_rollout::EpisodeTask],
    map: &MapRef,
) -> paddock_broker::Round {
    let batch = paddock_wire::batch_to_proto(tasks, |_| map.clone(), false);
    paddock_broker::Round {
        scenarios: batch.scenarios,
        tasks: batch.tasks,
    }
}

/// The domain outcomes of a round's outcome frames; the first failed episode fails it.
pub(crate) fn episodes(outcomes: &[&[u8]]) -> Result<Vec<paddock_rollout::EpisodeResult>, String> {
    outcomes
        .iter()
        .enumerate()
        .map(|(i, o)| {
            paddock_wire::outcome_from_bytes(o).map_err(|e| format!("episode {i} failed: {e}"))
        })
        .collect()
}

pub(crate) fn or_default<T: PartialEq + Default>(v: T, d: T) -> T {
    if v == T::default() { d } else { v }
}

/// A rollout error as the error of a submission under `prefix`.
pub(crate) fn rollout_err(e: &paddock_rollout::RolloutError, prefix: &str) -> Error {
    let mut p = paddock_wire::rollout_error_to_proto(e);
    p.code = ErrorCode::InvalidArgument as i32;
    with_prefix(p, prefix)
}
