//! A CMA-ES tuning run as a resumable state machine of rollout rounds.
//!
//! `paddock tune` and the broker's tune jobs run the same [`TuneJob`]: it hands out
//! rounds of episodes ([`TuneJob::next_round`]), is told their results in task order
//! ([`TuneJob::tell`]) and decides the next round. The whole state (optimizer, history,
//! phase) is serde-serialisable, so a broker stores it after every round and a restarted
//! broker resumes the job where it stopped; the result is the same wherever and however
//! the episodes ran.
//!
//! Phases:
//! 1. **generations**: each generation CMA-ES proposes `popsize` parameter vectors (ask),
//!    each driven from `seeds` seeded random starts; fitness = mean lap time, or a
//!    crash penalty that shrinks with the progress made (tell);
//! 2. **validation**: the best single sample and the distribution's mean are driven from
//!    `2 * seeds` fresh starts, and the better one is kept (the best sample was chosen on
//!    few noisy starts);
//! 3. **hold-out**: the defaults and the tuned vector on `holdout` starts nobody saw.

use std::sync::Arc;

use paddock_tune::{Optimizer, Options, Sigma0};
use serde::{Deserialize, Serialize};

use crate::benchmark::mean_std;
use crate::{EpisodeResult, EpisodeTask, RolloutError, Scenario, Termination, task_seed};

/// What to tune and how hard.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TuneSpec {
    pub driver: String,
    pub generations: u32,
    /// Candidates per generation (at least 2).
    pub popsize: usize,
    /// Seeded random starts each candidate is driven from.
    pub seeds: usize,
    /// Held-out starts for the final comparison.
    pub holdout: usize,
    /// Job seed: fixes the optimiser and every start.
    pub seed: u64,
    /// Cost of an episode that does not finish its lap, seconds (scaled by progress).
    pub crash_penalty: f64,
}

impl TuneSpec {
    /// The defaults of `paddock tune`.
    pub fn new(driver: &str) -> Self {
        Self {
            driver: driver.into(),
            generations: 60,
            popsize: 12,
            seeds: 8,
            holdout: 20,
            seed: 0,
            crash_penalty: 100.0,
        }
    }

    /// Check every field, naming the first bad one.
    pub fn validate(&self) -> Result<(), RolloutError> {
        let bad = |field: &str, value: String, reason: &str| {
            Err(RolloutError::invalid(field, value, reason))
        };
        if self.generations == 0 || self.generations > 10_000 {
            return bad(
                "generations",
                self.generations.to_string(),
                "must be 1..=10000",
            );
        }
        if self.popsize < 2 || self.popsize > 1_000 {
            return bad("popsize", self.popsize.to_string(), "must be 2..=1000");
        }
        if self.seeds == 0 || self.seeds > 1_000 {
            return bad("seeds", self.seeds.to_string(), "must be 1..=1000");
        }
        if self.holdout == 0 || self.holdout > 10_000 {
            return bad("holdout", self.holdout.to_string(), "must be 1..=10000");
        }
        if !(self.crash_penalty.is_finite() && self.crash_penalty > 0.0) {
            return bad(
                "crash_penalty",
                self.crash_penalty.to_string(),
                "must be a positive finite number",
            );
        }
        paddock_policy::driver_info(&self.driver)
            .map_err(|source| RolloutError::Driver { agent: 0, source })?;
        Ok(())
    }
}

/// One generation's record.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Generation {
    pub generation: u32,
    pub evaluations: u64,
    /// Best candidate of this generation: its fitness and mean lap time (when it
    /// finished from every start).
    pub best_fitness: f64,
    pub best_lap_time: Option<f64>,
    /// Mean lap time over this generation's finished episodes.
    pub mean_lap_time: Option<f64>,
    pub finished_fraction: f64,
    pub best_so_far: f64,
    pub sigma: f64,
}

/// Lap times of one parameter vector over a set of starts.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Evaluation {
    pub episodes: usize,
    pub finished: usize,
    pub lap_time_mean: Option<f64>,
    pub lap_time_std: Option<f64>,
}

impl Evaluation {
    pub fn of(results: &[EpisodeResult]) -> Self {
        let finished: Vec<&EpisodeResult> = results
            .iter()
            .filter(|e| e.agents[0].termination == Termination::Finished)
            .collect();
        let laps: Vec<f64> = finished
            .iter()
            .flat_map(|e| e.agents[0].lap_times.iter().copied())
            .collect();
        let (m, s) = mean_std(&laps);
        Self {
            episodes: results.len(),
            finished: finished.len(),
            lap_time_mean: m.is_finite().then_some(m),
            lap_time_std: s.is_finite().then_some(s),
        }
    }
}

/// The held-out improvement of `tuned` over `default` in percent of the default's mean
/// lap time. Claimed only when the tuned driver finishes at least as many held-out
/// starts: a faster mean over fewer finished laps is no improvement (the starts it
/// failed are the hard ones), so then there is none (`None`), as when either side
/// finished nothing.
pub fn improvement_pct(default: &Evaluation, tuned: &Evaluation) -> Option<f64> {
    if tuned.finished < default.finished {
        return None;
    }
    match (default.lap_time_mean, tuned.lap_time_mean) {
        (Some(d), Some(t)) => Some(100.0 * (d - t) / d),
        _ => None,
    }
}

/// The outcome of a finished job: every figure is a pure function of the spec, the
/// map and the drivers (no timings), so remote and local runs compare equal.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TuneResult {
    /// The tuned driver's name (`policy` in results stored before the rename).
    #[serde(alias = "policy")]
    pub driver: String,
    pub seed: u64,
    pub generations: usize,
    pub popsize: usize,
    pub seeds: usize,
    pub holdout: usize,
    pub evaluations: u64,
    pub episodes_run: u64,
    pub best_fitness: f64,
    /// "best sample" or "mean": which contender won validation.
    pub chosen: String,
    pub default_params: Vec<f64>,
    pub tuned_params: Vec<f64>,
    pub default: Evaluation,
    pub tuned: Evaluation,
    /// See [`improvement_pct`]: `None` when the tuned driver finished fewer held-out
    /// starts than the defaults, or either finished none.
    pub improvement_pct: Option<f64>,
    pub history: Vec<Generation>,
    /// The tuned car's first held-out episode, with its trajectory (for the lap plot).
    pub tuned_example: Option<EpisodeResult>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
enum Phase {
    Generations,
    Validation { contenders: Vec<Vec<f64>> },
    Holdout { tuned: Vec<f64>, chosen: String },
    Done,
}

/// A tuning run; see the module documentation.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TuneJob {
    spec: TuneSpec,
    base: Scenario,
    lap_length: f64,
    defaults: Vec<f64>,
    optimizer: Optimizer,
    phase: Phase,
    /// Candidates of the round handed out and not yet told (generation phase).
    pending: Option<Vec<Vec<f64>>>,
    history: Vec<Generation>,
    episodes_run: u64,
    result: Option<TuneResult>,
}

impl TuneJob {
    /// A job tuning `spec.driver` on `base`'s map (car 0 of `base` is the tuned car;
    /// its parameters are replaced by each candidate). `lap_length` scales the crash
    /// penalty by the progress made.
    pub fn new(spec: TuneSpec, base: Scenario, lap_length: f64) -> Result<Self, RolloutError> {
        spec.validate()?;
        if !(lap_length.is_finite() && lap_length > 0.0) {
            return Err(RolloutError::Invalid {
                field: "lap_length".into(),
                value: lap_length.to_string(),
                reason: "must be a positive finite number".into(),
            });
        }
        let info = paddock_policy::driver_info(&spec.driver)
            .map_err(|source| RolloutError::Driver { agent: 0, source })?;
        let defaults: Vec<f64> = info.params.iter().map(|p| p.default).collect();
        let bounds: Vec<(f64, f64)> = info.params.iter().map(|p| (p.lo, p.hi)).collect();
        let mut base = base;
        if base.agents.is_empty() {
            return Err(RolloutError::Invalid {
                field: "agents".into(),
                value: "0".into(),
                reason: "the scenario needs the tuned car as agent 0".into(),
            });
        }
        base.agents[0].driver = info.name.to_string();
        base.agents[0].params = defaults.clone();
        base.validate()?;
        let options = Options::new(defaults.clone(), Sigma0::FractionOfWidth(0.15))
            .with_bounds(bounds)
            .with_popsize(spec.popsize)
            .with_seed(spec.seed)
            .with_max_restarts(3);
        let optimizer = Optimizer::new(options).map_err(|e| RolloutError::Invalid {
            field: "spec".into(),
            value: spec.driver.clone(),
            reason: e.to_string(),
        })?;
        Ok(Self {
            spec,
            base,
            lap_length,
            defaults,
            optimizer,
            phase: Phase::Generations,
            pending: None,
            history: Vec::new(),
            episodes_run: 0,
            result: None,
        })
    }

    pub fn spec(&self) -> &TuneSpec {
        &self.spec
    }

    pub fn scenario(&self) -> &Scenario {
        &self.base
    }

    fn train_seeds(&self) -> Vec<u64> {
        (0..self.spec.seeds as u64)
            .map(|k| task_seed(self.spec.seed, k))
            .collect()
    }

    fn validation_seeds(&self) -> Vec<u64> {
        (0..(2 * self.spec.seeds) as u64)
            .map(|k| task_seed(self.spec.seed ^ 0x5641_4c49_4441_5445, k))
            .collect()
    }

    fn holdout_seeds(&self) -> Vec<u64> {
        (0..self.spec.holdout as u64)
            .map(|k| task_seed(self.spec.seed ^ 0x4845_4c44_4f55_5421, k))
            .collect()
    }

    /// Every parameter vector driven from every seed, vector-major.
    fn tasks_for(&self, params: &[Vec<f64>], seeds: &[u64]) -> Vec<EpisodeTask> {
        params
            .iter()
            .flat_map(|p| {
                let mut sc = self.base.clone();
                sc.agents[0].params = p.clone();
                let sc = Arc::new(sc);
                seeds.iter().map(move |&seed| EpisodeTask {
                    scenario: sc.clone(),
                    seed,
                    record: None,
                })
            })
            .collect()
    }

    fn cost(&self, e: &EpisodeResult) -> f64 {
        let a = &e.agents[0];
        if a.termination == Termination::Finished {
            a.lap_times.iter().sum()
        } else {
            let done = (a.progress / self.lap_length).clamp(0.0, 1.0);
            self.spec.crash_penalty * (2.0 - done)
        }
    }

    fn generations_left(&self) -> bool {
        (self.history.len() as u32) < self.spec.generations && self.optimizer.is_done().is_none()
    }

    /// The episodes of the next round, or None when the job is done. Until the round
    /// is told, calling again returns the same round.
    pub fn next_round(&mut self) -> Result<Option<Vec<EpisodeTask>>, RolloutError> {
        loop {
            match &self.phase {
                Phase::Generations => {
                    if !self.generations_left() {
                        self.start_validation()?;
                        continue;
                    }
                    if self.pending.is_none() {
                        let c = self.optimizer.ask().map_err(|e| internal(e.to_string()))?;
                        self.pending = Some(c);
                    }
                    let cands = self.pending.clone().unwrap_or_default();
                    return Ok(Some(self.tasks_for(&cands, &self.train_seeds())));
                }
                Phase::Validation { contenders } => {
                    return Ok(Some(self.tasks_for(contenders, &self.validation_seeds())));
                }
                Phase::Holdout { tuned, .. } => {
                    let holdout = self.holdout_seeds();
                    let mut tasks =
                        self.tasks_for(&[self.defaults.clone(), tuned.clone()], &holdout);
                    // the tuned lap on the first held-out start is recorded for plots
                    tasks[holdout.len()].record = Some(2);
                    return Ok(Some(tasks));
                }
                Phase::Done => return Ok(None),
            }
        }
    }

    fn start_validation(&mut self) -> Result<(), RolloutError> {
        let best = self
            .optimizer
            .best()
            .map(|(x, _)| x.to_vec())
            .ok_or_else(|| internal("the optimiser was told no finite fitness".into()))?;
        self.phase = Phase::Validation {
            contenders: vec![best, self.optimizer.mean()],
        };
        Ok(())
    }

    /// Tell the results of the round from [`TuneJob::next_round`], in task order.
    pub fn tell(&mut self, results: &[EpisodeResult]) -> Result<(), RolloutError> {
        let expected = match self.next_round()? {
            Some(tasks) => tasks.len(),
            None => {
                return Err(internal("the job is done; no round to tell".into()));
            }
        };
        if results.len() != expected || results.iter().any(|r| r.agents.is_empty()) {
            return Err(RolloutError::Invalid {
                field: "results".into(),
                value: results.len().to_string(),
                reason: format!("the round has {expected} episodes with one car each"),
            });
        }
        self.episodes_run += results.len() as u64;
        match self.phase.clone() {
            Phase::Generations => self.tell_generation(results),
            Phase::Validation { contenders } => {
                let n = self.validation_seeds().len();
                let costs: Vec<f64> = results
                    .chunks(n)
                    .map(|c| c.iter().map(|e| self.cost(e)).sum())
                    .collect();
                let mean_wins = costs[1] < costs[0];
                self.phase = Phase::Holdout {
                    tuned: contenders[usize::from(mean_wins)].clone(),
                    chosen: if mean_wins { "mean" } else { "best sample" }.into(),
                };
                Ok(())
            }
            Phase::Holdout { tuned, chosen } => {
                let (default_eps, tuned_eps) = results.split_at(self.spec.holdout);
                let default = Evaluation::of(default_eps);
                let tuned_eval = Evaluation::of(tuned_eps);
                let improvement_pct = improvement_pct(&default, &tuned_eval);
                let status = self.optimizer.status();
                self.result = Some(TuneResult {
                    driver: self.spec.driver.clone(),
                    seed: self.spec.seed,
                    generations: self.history.len(),
                    popsize: self.spec.popsize,
                    seeds: self.spec.seeds,
                    holdout: self.spec.holdout,
                    evaluations: status.evaluations,
                    episodes_run: self.episodes_run,
                    best_fitness: status.best_fitness,
                    chosen,
                    default_params: self.defaults.clone(),
                    tuned_params: tuned,
                    default,
                    tuned: tuned_eval,
                    improvement_pct,
                    history: self.history.clone(),
                    tuned_example: tuned_eps.first().cloned(),
                });
                self.phase = Phase::Done;
                Ok(())
            }
            Phase::Done => Err(internal("the job is done; no round to tell".into())),
        }
    }

    fn tell_generation(&mut self, results: &[EpisodeResult]) -> Result<(), RolloutError> {
        let candidates = self
            .pending
            .take()
            .ok_or_else(|| internal("no generation was handed out".into()))?;
        let k = self.spec.seeds;
        let fitness: Vec<f64> = results
            .chunks(k)
            .map(|c| c.iter().map(|e| self.cost(e)).sum::<f64>() / k as f64)
            .collect();
        self.optimizer
            .tell(&candidates, &fitness)
            .map_err(|e| internal(e.to_string()))?;
        let best_i = (0..fitness.len())
            .min_by(|&a, &b| fitness[a].total_cmp(&fitness[b]))
            .unwrap_or(0);
        let best_eval = Evaluation::of(&results[best_i * k..(best_i + 1) * k]);
        let all = Evaluation::of(results);
        let status = self.optimizer.status();
        self.history.push(Generation {
            generation: self.history.len() as u32 + 1,
            evaluations: status.evaluations,
            best_fitness: fitness[best_i],
            best_lap_time: (best_eval.finished == k)
                .then_some(best_eval.lap_time_mean)
                .flatten(),
            mean_lap_time: all.lap_time_mean,
            finished_fraction: all.finished as f64 / all.episodes as f64,
            best_so_far: status.best_fitness,
            sigma: status.sigma,
        });
        Ok(())
    }

    /// Rounds told so far.
    pub fn rounds_done(&self) -> u32 {
        let extra = match self.phase {
            Phase::Generations => 0,
            Phase::Validation { .. } => 0,
            Phase::Holdout { .. } => 1,
            Phase::Done => 2,
        };
        self.history.len() as u32 + extra
    }

    /// Rounds planned: generations (fewer if CMA-ES stops early), validation, hold-out.
    pub fn rounds_total(&self) -> u32 {
        if matches!(self.phase, Phase::Generations) && self.generations_left() {
            self.spec.generations + 2
        } else {
            self.history.len() as u32 + 2
        }
    }

    pub fn history(&self) -> &[Generation] {
        &self.history
    }

    pub fn episodes_run(&self) -> u64 {
        self.episodes_run
    }

    pub fn is_done(&self) -> bool {
        matches!(self.phase, Phase::Done)
    }

    /// The outcome, once done.
    pub fn result(&self) -> Option<&TuneResult> {
        self.result.as_ref()
    }

    /// A short progress document: phase, generation, best so far, last mean lap time.
    pub fn progress_json(&self) -> String {
        let phase = match self.phase {
            Phase::Generations => "generations",
            Phase::Validation { .. } => "validation",
            Phase::Holdout { .. } => "holdout",
            Phase::Done => "done",
        };
        let last = self.history.last();
        serde_json::json!({
            "phase": phase,
            "generation": self.history.len(),
            "best_so_far": last.map(|g| g.best_so_far),
            "mean_lap_time": last.and_then(|g| g.mean_lap_time),
            "episodes_run": self.episodes_run,
        })
        .to_string()
    }
}

fn internal(reason: String) -> RolloutError {
    RolloutError::Invalid {
        field: "tune_job".into(),
        value: String::new(),
        reason,
    }
}

#[cfg(test)]
mod tests;
