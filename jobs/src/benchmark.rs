//! Benchmark jobs: one round of a benchmark task's episodes (B1 alone, B2 among
//! obstacles, B3 head to head), reduced to its report.

use paddock_broker::plan::{JobOutput, JobPlan, Round, Stored};
use paddock_proto::{Error, MapRef};
use paddock_rollout::benchmark::{BenchmarkSpec, Task, report};
use paddock_rollout::{EpisodeResult, RolloutError};

use crate::{check_map, invalid, or_default, register_models, rollout_err, round_of};

/// A benchmark job; see the module documentation.
#[derive(Debug)]
pub struct BenchmarkPlan {
    spec: Box<BenchmarkSpec>,
    map: MapRef,
    result: Option<String>,
}

fn agent_from_proto(
    a: Option<&paddock_proto::AgentSpec>,
    dir: &std::path::Path,
    stored: &dyn Stored,
    field: &str,
) -> Result<paddock_rollout::AgentSpec, Error> {
    let Some(a) = a else {
        return Err(invalid(field, format!("{field} is missing")));
    };
    register_models(std::slice::from_ref(a), stored, |_| {
        format!("{field}.driver")
    })?;
    // checked as the only car of a minimal scenario, so every agent rule applies
    let probe = paddock_proto::Scenario {
        agents: vec![a.clone()],
        laps: 1,
        time_limit: 1.0,
        ..Default::default()
    };
    let sc = paddock_wire::scenario_from_proto(&probe, dir).map_err(|mut e| {
        e.field = e.field.replacen("agents[0]", field, 1);
        e.message = e.message.replacen("agents[0]", field, 1);
        e
    })?;
    sc.agents
        .into_iter()
        .next()
        .ok_or_else(|| invalid(field, "the agent could not be read"))
}

impl BenchmarkPlan {
    /// A checked benchmark job (field names under `job_submit.benchmark`).
    pub fn new(b: &paddock_proto::BenchmarkSpec, maps: &dyn Stored) -> Result<Self, Error> {
        let task: Task = b
            .task
            .parse()
            .map_err(|e: String| invalid("job_submit.benchmark.task", e))?;
        let (map, dir) = check_map(b.map.as_ref(), maps, "job_submit.benchmark.map")?;
        let driver =
            agent_from_proto(b.driver.as_ref(), &dir, maps, "job_submit.benchmark.driver")?;
        let opponent = match (&b.opponent, task) {
            (Some(o), _) => Some(agent_from_proto(
                Some(o),
                &dir,
                maps,
                "job_submit.benchmark.opponent",
            )?),
            (None, Task::B3) => Some(
                paddock_rollout::AgentSpec::with_defaults("pure-pursuit")
                    .map_err(|e| invalid("job_submit.benchmark.opponent", e.to_string()))?,
            ),
            (None, _) => None,
        };
        let spec = BenchmarkSpec {
            task,
            map: dir.display().to_string(),
            driver,
            opponent,
            episodes: b.episodes as usize,
            seed: b.seed,
            laps: or_default(b.laps, 2),
            obstacles: or_default(b.obstacles as usize, 8),
            time_limit: or_default(b.time_limit, 180.0),
        };
        spec.tasks()
            .map_err(|e| rollout_err(&e, "job_submit.benchmark"))?;
        Ok(Self {
            spec: Box::new(spec),
            map,
            result: None,
        })
    }
}

impl JobPlan for BenchmarkPlan {
    fn kind(&self) -> &'static str {
        "benchmark"
    }

    fn next_round(&mut self) -> Result<Option<Round>, String> {
        if self.result.is_some() {
            return Ok(None);
        }
        let tasks = self.spec.tasks().map_err(|e| e.to_string())?;
        Ok(Some(round_of(&tasks, &self.map)))
    }

    fn tell(&mut self, outcomes: &[&[u8]]) -> Result<(), String> {
        let results: Vec<Result<EpisodeResult, RolloutError>> = outcomes
            .iter()
            .map(|o| paddock_wire::outcome_from_bytes(o))
            .collect();
        if let Some((i, Err(e))) = results.iter().enumerate().find(|(_, r)| r.is_err()) {
            return Err(format!("episode {i} failed: {e}"));
        }
        let rep = report(&self.spec, &results);
        self.result = Some(serde_json::to_string(&rep).map_err(|e| e.to_string())?);
        Ok(())
    }

    fn rounds(&self) -> (u32, u32) {
        (u32::from(self.result.is_some()), 1)
    }

    fn episodes_done(&self) -> u64 {
        if self.result.is_some() {
            self.spec.episodes as u64
        } else {
            0
        }
    }

    fn progress_json(&self) -> String {
        let (d, t) = self.rounds();
        serde_json::json!({ "rounds_done": d, "rounds_total": t }).to_string()
    }

    fn state_json(&self) -> String {
        String::new()
    }

    fn result(&self) -> Option<JobOutput> {
        self.result.clone().map(|json| JobOutput {
            json,
            outcomes: Vec::new(),
        })
    }
}
