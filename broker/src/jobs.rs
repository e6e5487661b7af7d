//! Jobs as map/reduce rounds: what each kind of job hands out and how it reduces.
//!
//! A job is checked when submitted (every field, the map by hash), then alternates
//! between handing out a round of tasks ([`JobWork::next_round`]) and being told its
//! outcomes in task order ([`JobWork::tell`]). After every round the server stores
//! [`JobWork::state_json`]; [`JobWork::restore`] rebuilds the job from its stored spec
//! and state, so a restarted broker resumes it. Tune jobs run the same
//! [`TuneJob`] as the local `paddock tune`, so their result is the same document.

use std::sync::Arc;

use paddock_proto::convert::{
    outcome_from_proto, record_to_proto, scenario_from_proto, scenario_to_proto, with_prefix,
};
use paddock_proto::{ErrorCode, MapRef, RolloutResult, error, job_submit};
use paddock_rollout::benchmark::{BenchmarkSpec, Task, report};
use paddock_rollout::tune_job::{TuneJob, TuneSpec};
use paddock_rollout::{EpisodeResult, RolloutError, Scenario};
use paddock_sim::track::Circuit;
use prost::Message;

use crate::state::Store;

/// One task of a round, as sent to a worker.
#[derive(Debug, Clone, PartialEq)]
pub struct TaskTemplate {
    pub scenario: Arc<paddock_proto::Scenario>,
    pub seed: u64,
    pub record_decimation: u32,
}

/// The work of one job; see the module documentation.
#[derive(Debug)]
pub enum JobWork {
    Tune {
        job: Box<TuneJob>,
        map: MapRef,
    },
    Rollouts {
        scenarios: Vec<Arc<paddock_proto::Scenario>>,
        batch: Box<paddock_proto::RolloutBatch>,
        result: Option<RolloutResult>,
    },
    Benchmark {
        spec: Box<BenchmarkSpec>,
        map: MapRef,
        result: Option<String>,
    },
}

/// Checks a map reference: a known hash, else NOT_FOUND naming `field`.
pub fn check_map(
    map: Option<&MapRef>,
    store: &Store,
    field: &str,
) -> Result<(MapRef, std::path::PathBuf), paddock_proto::Error> {
    let Some(m) = map else {
        return Err(error(
            ErrorCode::InvalidArgument,
            field,
            format!("{field} is missing: a map is named by its content hash"),
        ));
    };
    let known = store.has_map(&m.hash).map_err(|e| {
        error(
            ErrorCode::Internal,
            format!("{field}.hash"),
            format!("looking up map {:?}: {e}", m.hash),
        )
    })?;
    if !known {
        return Err(error(
            ErrorCode::NotFound,
            format!("{field}.hash"),
            format!(
                "map {:?} with hash {:?} is not stored in this broker: send put_map, then retry",
                m.name, m.hash
            ),
        ));
    }
    Ok((m.clone(), store.map_dir(&m.hash)))
}

/// Checks every scenario and task of a batch; `prefix` names the batch in errors
/// (e.g. "rollout_batch").
pub fn check_batch(
    batch: &paddock_proto::RolloutBatch,
    store: &Store,
    prefix: &str,
) -> Result<Vec<Arc<paddock_proto::Scenario>>, paddock_proto::Error> {
    let mut out = Vec::with_capacity(batch.scenarios.len());
    for (i, sc) in batch.scenarios.iter().enumerate() {
        let field = format!("{prefix}.scenarios[{i}]");
        let (_, dir) = check_map(sc.map.as_ref(), store, &format!("{field}.map"))?;
        scenario_from_proto(sc, &dir).map_err(|e| with_prefix(e, &field))?;
        out.push(Arc::new(sc.clone()));
    }
    for (j, t) in batch.tasks.iter().enumerate() {
        if t.scenario as usize >= out.len() {
            return Err(error(
                ErrorCode::InvalidArgument,
                format!("{prefix}.tasks[{j}].scenario"),
                format!(
                    "{prefix}.tasks[{j}].scenario = {} but the batch has {} scenarios",
                    t.scenario,
                    out.len()
                ),
            ));
        }
    }
    Ok(out)
}

/// The tasks of a checked batch.
pub fn batch_tasks(
    batch: &paddock_proto::RolloutBatch,
    scenarios: &[Arc<paddock_proto::Scenario>],
) -> Vec<TaskTemplate> {
    batch
        .tasks
        .iter()
        .map(|t| TaskTemplate {
            scenario: scenarios[t.scenario as usize].clone(),
            seed: t.seed,
            record_decimation: t.record_decimation,
        })
        .collect()
}

fn invalid(field: String, message: String) -> paddock_proto::Error {
    error(ErrorCode::InvalidArgument, field, message)
}

fn rollout_err(e: &RolloutError, prefix: &str) -> paddock_proto::Error {
    let mut p = paddock_proto::convert::rollout_error_to_proto(e);
    p.code = ErrorCode::InvalidArgument as i32;
    with_prefix(p, prefix)
}

fn or_default<T: PartialEq + Default>(v: T, d: T) -> T {
    if v == T::default() { d } else { v }
}

/// The base scenario of a tune job: what `paddock tune` builds from its arguments.
fn tune_base(driver: &str, circuit: &Circuit) -> Result<Scenario, RolloutError> {
    let mut base =
        Scenario::single(driver).map_err(|source| RolloutError::Driver { agent: 0, source })?;
    base.map = circuit.dir.display().to_string();
    base.laps = 1;
    base.time_limit = 60.0 + 0.5 * circuit.track.length();
    Ok(base)
}

fn load_circuit(dir: &std::path::Path, field: &str) -> Result<Arc<Circuit>, paddock_proto::Error> {
    Circuit::resolve(&dir.display().to_string(), &[]).map_err(|e| {
        invalid(
            field.to_string(),
            format!("the stored map does not load as a circuit: {e}"),
        )
    })
}

fn agent_from_proto(
    a: Option<&paddock_proto::AgentSpec>,
    dir: &std::path::Path,
    field: &str,
) -> Result<paddock_rollout::AgentSpec, paddock_proto::Error> {
    let Some(a) = a else {
        return Err(invalid(field.into(), format!("{field} is missing")));
    };
    // checked as the only car of a minimal scenario, so every agent rule applies
    let probe = paddock_proto::Scenario {
        agents: vec![a.clone()],
        laps: 1,
        time_limit: 1.0,
        ..Default::default()
    };
    let sc = scenario_from_proto(&probe, dir).map_err(|mut e| {
        e.field = e.field.replacen("agents[0]", field, 1);
        e.message = e.message.replacen("agents[0]", field, 1);
        e
    })?;
    sc.agents.into_iter().next().ok_or_else(|| {
        paddock_proto::error(
            paddock_proto::ErrorCode::InvalidArgument,
            field,
            "the agent could not be read",
        )
    })
}

impl JobWork {
    /// A checked job from its submission; the `kind` is "tune", "rollouts" or
    /// "benchmark".
    pub fn from_submit(
        submit: &paddock_proto::JobSubmit,
        store: &Store,
    ) -> Result<(&'static str, JobWork), paddock_proto::Error> {
        match &submit.spec {
            None => Err(invalid(
                "job_submit.spec".into(),
                "a job needs a spec: tune, rollouts or benchmark".into(),
            )),
            Some(job_submit::Spec::Tune(t)) => {
                let (map, dir) = check_map(t.map.as_ref(), store, "job_submit.tune.map")?;
                let circuit = load_circuit(&dir, "job_submit.tune.map")?;
                let driver = paddock_policy::driver_info(&t.driver)
                    .map_err(|e| {
                        invalid(
                            "job_submit.tune.driver".into(),
                            format!("job_submit.tune.driver = {:?}: {e}", t.driver),
                        )
                    })?
                    .name;
                let spec = TuneSpec {
                    driver: driver.to_string(),
                    generations: or_default(t.generations, 60),
                    popsize: or_default(t.popsize as usize, 12),
                    seeds: or_default(t.seeds as usize, 8),
                    holdout: or_default(t.holdout as usize, 20),
                    seed: t.seed,
                    crash_penalty: or_default(t.crash_penalty, 100.0),
                };
                let mut base =
                    tune_base(driver, &circuit).map_err(|e| rollout_err(&e, "job_submit.tune"))?;
                base.agents[0].vehicle = paddock_sim::params::VehicleParams::from_yaml_str(
                    &t.vehicle_yaml,
                )
                .map_err(|e| {
                    let field = match e.field() {
                        Some(f) => format!("job_submit.tune.vehicle_yaml.{f}"),
                        None => "job_submit.tune.vehicle_yaml".into(),
                    };
                    invalid(field, e.to_string())
                })?;
                let job = TuneJob::new(spec, base, circuit.track.length())
                    .map_err(|e| rollout_err(&e, "job_submit.tune"))?;
                Ok((
                    "tune",
                    JobWork::Tune {
                        job: Box::new(job),
                        map,
                    },
                ))
            }
            Some(job_submit::Spec::Rollouts(b)) => {
                let scenarios = check_batch(b, store, "job_submit.rollouts")?;
                Ok((
                    "rollouts",
                    JobWork::Rollouts {
                        scenarios,
                        batch: Box::new(b.clone()),
                        result: None,
                    },
                ))
            }
            Some(job_submit::Spec::Benchmark(b)) => {
                let task: Task = b
                    .task
                    .parse()
                    .map_err(|e: String| invalid("job_submit.benchmark.task".into(), e))?;
                let (map, dir) = check_map(b.map.as_ref(), store, "job_submit.benchmark.map")?;
                let driver =
                    agent_from_proto(b.driver.as_ref(), &dir, "job_submit.benchmark.driver")?;
                let opponent = match (&b.opponent, task) {
                    (Some(o), _) => Some(agent_from_proto(
                        Some(o),
                        &dir,
                        "job_submit.benchmark.opponent",
                    )?),
                    (None, Task::B3) => Some(
                        paddock_rollout::AgentSpec::with_defaults("pure-pursuit").map_err(|e| {
                            invalid("job_submit.benchmark.opponent".into(), e.to_string())
                        })?,
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
                Ok((
                    "benchmark",
                    JobWork::Benchmark {
                        spec: Box::new(spec),
                        map,
                        result: None,
                    },
                ))
            }
        }
    }

    /// Rebuilds a stored job: its submission `spec` (encoded `JobSubmit`) and, for a
    /// tune job, its state after the last stored round.
    pub fn restore(spec: &[u8], job_state: &str, store: &Store) -> Result<JobWork, String> {
        let submit = paddock_proto::JobSubmit::decode(spec)
            .map_err(|e| format!("stored job spec does not decode: {e}"))?;
        let (_, mut work) = Self::from_submit(&submit, store)
            .map_err(|e| format!("stored job spec is refused now: {}: {}", e.field, e.message))?;
        if let JobWork::Tune { job, .. } = &mut work
            && !job_state.is_empty()
        {
            let restored: TuneJob = serde_json::from_str(job_state)
                .map_err(|e| format!("stored tune state does not parse: {e}"))?;
            **job = restored;
        }
        Ok(work)
    }

    /// The tasks of the next round (the same round until told), or None when done.
    pub fn next_round(&mut self) -> Result<Option<Vec<TaskTemplate>>, String> {
        match self {
            JobWork::Tune { job, map } => {
                let Some(tasks) = job.next_round().map_err(|e| e.to_string())? else {
                    return Ok(None);
                };
                Ok(Some(domain_tasks(&tasks, map)))
            }
            JobWork::Rollouts {
                scenarios,
                batch,
                result,
            } => Ok(result.is_none().then(|| batch_tasks(batch, scenarios))),
            JobWork::Benchmark { spec, map, result } => {
                if result.is_some() {
                    return Ok(None);
                }
                let tasks = spec.tasks().map_err(|e| e.to_string())?;
                Ok(Some(domain_tasks(&tasks, map)))
            }
        }
    }

    /// The outcomes of the round from [`JobWork::next_round`], in task order.
    pub fn tell(&mut self, outcomes: Vec<paddock_proto::TaskOutcome>) -> Result<(), String> {
        match self {
            JobWork::Tune { job, .. } => {
                let mut episodes: Vec<EpisodeResult> = Vec::with_capacity(outcomes.len());
                for (i, o) in outcomes.iter().enumerate() {
                    episodes.push(
                        outcome_from_proto(o).map_err(|e| format!("episode {i} failed: {e}"))?,
                    );
                }
                job.tell(&episodes).map_err(|e| e.to_string())
            }
            JobWork::Rollouts { result, .. } => {
                *result = Some(RolloutResult { outcomes });
                Ok(())
            }
            JobWork::Benchmark { spec, result, .. } => {
                let results: Vec<Result<EpisodeResult, RolloutError>> =
                    outcomes.iter().map(outcome_from_proto).collect();
                if let Some((i, Err(e))) = results.iter().enumerate().find(|(_, r)| r.is_err()) {
                    return Err(format!("episode {i} failed: {e}"));
                }
                let rep = report(spec, &results);
                *result = Some(serde_json::to_string(&rep).map_err(|e| e.to_string())?);
                Ok(())
            }
        }
    }

    /// (rounds done, rounds planned).
    pub fn rounds(&self) -> (u32, u32) {
        match self {
            JobWork::Tune { job, .. } => (job.rounds_done(), job.rounds_total()),
            JobWork::Rollouts { result, .. } => (u32::from(result.is_some()), 1),
            JobWork::Benchmark { result, .. } => (u32::from(result.is_some()), 1),
        }
    }

    pub fn episodes_done(&self) -> u64 {
        match self {
            JobWork::Tune { job, .. } => job.episodes_run(),
            JobWork::Rollouts { result, .. } => {
                result.as_ref().map_or(0, |r| r.outcomes.len() as u64)
            }
            JobWork::Benchmark { spec, result, .. } => {
                if result.is_some() {
                    spec.episodes as u64
                } else {
                    0
                }
            }
        }
    }

    pub fn progress_json(&self) -> String {
        match self {
            JobWork::Tune { job, .. } => job.progress_json(),
            _ => {
                let (d, t) = self.rounds();
                serde_json::json!({ "rounds_done": d, "rounds_total": t }).to_string()
            }
        }
    }

    /// What must be stored to resume (tune jobs: the whole `TuneJob`).
    pub fn state_json(&self) -> String {
        match self {
            JobWork::Tune { job, .. } => serde_json::to_string(job).unwrap_or_default(),
            _ => String::new(),
        }
    }

    /// The result document and binary result, once done.
    pub fn result(&self) -> Option<(String, Vec<u8>)> {
        match self {
            JobWork::Tune { job, .. } => job
                .result()
                .map(|r| (serde_json::to_string(r).unwrap_or_default(), Vec::new())),
            JobWork::Rollouts { result, .. } => result.as_ref().map(|r| {
                let errors = r
                    .outcomes
                    .iter()
                    .filter(|o| {
                        !matches!(
                            o.outcome,
                            Some(paddock_proto::task_outcome::Outcome::Episode(_))
                        )
                    })
                    .count();
                let doc = serde_json::json!({ "episodes": r.outcomes.len(), "errors": errors });
                (doc.to_string(), r.encode_to_vec())
            }),
            JobWork::Benchmark { result, .. } => result.clone().map(|r| (r, Vec::new())),
        }
    }
}

/// Wire tasks of domain tasks on `map`; scenarios shared between tasks are converted
/// once.
fn domain_tasks(tasks: &[paddock_rollout::EpisodeTask], map: &MapRef) -> Vec<TaskTemplate> {
    let mut cache: Vec<(Arc<Scenario>, Arc<paddock_proto::Scenario>)> = Vec::new();
    tasks
        .iter()
        .map(|t| {
            let wire = match cache.iter().find(|(d, _)| Arc::ptr_eq(d, &t.scenario)) {
                Some((_, w)) => w.clone(),
                None => {
                    let w = Arc::new(scenario_to_proto(&t.scenario, map.clone()));
                    cache.push((t.scenario.clone(), w.clone()));
                    w
                }
            };
            TaskTemplate {
                scenario: wire,
                seed: t.seed,
                record_decimation: record_to_proto(t.record),
            }
        })
        .collect()
}
