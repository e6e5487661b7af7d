//! Rollout jobs: a client's batch stored by the broker, run as one round, its outcomes
//! kept as the workers sent them.

use paddock_broker::plan::{JobOutput, JobPlan, Round, Stored};
use paddock_proto::{Error, RolloutBatch};

use crate::check_batch;

/// A stored batch; see the module documentation.
#[derive(Debug)]
pub struct RolloutsPlan {
    batch: RolloutBatch,
    outcomes: Option<Vec<Vec<u8>>>,
}

impl RolloutsPlan {
    /// A checked batch job (field names under `job_submit.rollouts`).
    pub fn new(batch: &RolloutBatch, maps: &dyn Stored) -> Result<Self, Error> {
        check_batch(batch, maps, "job_submit.rollouts")?;
        Ok(Self {
            batch: batch.clone(),
            outcomes: None,
        })
    }
}

impl JobPlan for RolloutsPlan {
    fn kind(&self) -> &'static str {
        "rollouts"
    }

    fn next_round(&mut self) -> Result<Option<Round>, String> {
        Ok(self.outcomes.is_none().then(|| Round {
            scenarios: self.batch.scenarios.clone(),
            tasks: self.batch.tasks.clone(),
        }))
    }

    fn tell(&mut self, outcomes: &[&[u8]]) -> Result<(), String> {
        self.outcomes = Some(outcomes.iter().map(|o| o.to_vec()).collect());
        Ok(())
    }

    fn rounds(&self) -> (u32, u32) {
        (u32::from(self.outcomes.is_some()), 1)
    }

    fn episodes_done(&self) -> u64 {
        self.outcomes.as_ref().map_or(0, |o| o.len() as u64)
    }

    fn progress_json(&self) -> String {
        let (d, t) = self.rounds();
        serde_json::json!({ "rounds_done": d, "rounds_total": t }).to_string()
    }

    fn state_json(&self) -> String {
        String::new()
    }

    fn result(&self) -> Option<JobOutput> {
        let outcomes = self.outcomes.as_ref()?;
        let errors = outcomes
            .iter()
            .filter(|o| paddock_wire::outcome_from_bytes(o).is_err())
            .count();
        let doc = serde_json::json!({ "episodes": outcomes.len(), "errors": errors });
        Some(JobOutput {
            json: doc.to_string(),
            outcomes: outcomes.clone(),
        })
    }
}
