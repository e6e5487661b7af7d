//! Tune jobs: CMA-ES over a driver's parameters, the same [`TuneJob`] as `paddock tune`.

use std::path::Path;

use paddock_broker::plan::{JobOutput, JobPlan, Round, Stored};
use paddock_proto::{Error, MapRef};
use paddock_rollout::tune_job::{TuneJob, TuneSpec};
use paddock_rollout::{RolloutError, Scenario};
use paddock_sim::circuit::Circuit;

use crate::{check_map, episodes, invalid, or_default, rollout_err, round_of};

/// A tune job; see the module documentation.
#[derive(Debug)]
pub struct TunePlan {
    job: Box<TuneJob>,
    map: MapRef,
}

/// The base scenario of a tune job on the map in folder `dir`: what `paddock tune`
/// builds from its arguments.
fn tune_base(driver: &str, dir: &Path, circuit: &Circuit) -> Result<Scenario, RolloutError> {
    let mut base =
        Scenario::single(driver).map_err(|source| RolloutError::Driver { agent: 0, source })?;
    base.map = dir.display().to_string();
    base.laps = 1;
    base.time_limit = 60.0 + 0.5 * circuit.track.length();
    Ok(base)
}

/// The circuit of a stored map, loaded for this job alone (its track length).
fn load_circuit(dir: &Path, field: &str) -> Result<Circuit, Error> {
    Circuit::load(dir).map_err(|e| {
        invalid(
            field,
            format!("the stored map does not load as a circuit: {e}"),
        )
    })
}

impl TunePlan {
    /// A checked tune job of the submission `t` (field names under `job_submit.tune`).
    pub fn new(t: &paddock_proto::TuneSpec, maps: &dyn Stored) -> Result<Self, Error> {
        let (map, dir) = check_map(t.map.as_ref(), maps, "job_submit.tune.map")?;
        let circuit = load_circuit(&dir, "job_submit.tune.map")?;
        let driver = paddock_policy::driver_info(&t.driver)
            .map_err(|e| {
                invalid(
                    "job_submit.tune.driver",
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
            tune_base(driver, &dir, &circuit).map_err(|e| rollout_err(&e, "job_submit.tune"))?;
        base.agents[0].vehicle = paddock_sim::params::VehicleParams::from_yaml_str(&t.vehicle_yaml)
            .map_err(|e| {
                let field = match e.field() {
                    Some(f) => format!("job_submit.tune.vehicle_yaml.{f}"),
                    None => "job_submit.tune.vehicle_yaml".into(),
                };
                invalid(field, e.to_string())
            })?;
        let job = TuneJob::new(spec, base, circuit.track.length())
            .map_err(|e| rollout_err(&e, "job_submit.tune"))?;
        Ok(Self {
            job: Box::new(job),
            map,
        })
    }

    /// Continues from the state stored after the last round.
    pub fn restore(&mut self, state: &str) -> Result<(), String> {
        let restored: TuneJob = serde_json::from_str(state)
            .map_err(|e| format!("stored tune state does not parse: {e}"))?;
        *self.job = restored;
        Ok(())
    }
}

impl JobPlan for TunePlan {
    fn kind(&self) -> &'static str {
        "tune"
    }

    fn next_round(&mut self) -> Result<Option<Round>, String> {
        let Some(tasks) = self.job.next_round().map_err(|e| e.to_string())? else {
            return Ok(None);
        };
        Ok(Some(round_of(&tasks, &self.map)))
    }

    fn tell(&mut self, outcomes: &[&[u8]]) -> Result<(), String> {
        let episodes = episodes(outcomes)?;
        self.job.tell(&episodes).map_err(|e| e.to_string())
    }

    fn rounds(&self) -> (u32, u32) {
        (self.job.rounds_done(), self.job.rounds_total())
    }

    fn episodes_done(&self) -> u64 {
        self.job.episodes_run()
    }

    fn progress_json(&self) -> String {
        self.job.progress_json()
    }

    fn state_json(&self) -> String {
        serde_json::to_string(&*self.job).unwrap_or_default()
    }

    fn result(&self) -> Option<JobOutput> {
        self.job.result().map(|r| JobOutput {
            json: serde_json::to_string(r).unwrap_or_default(),
            outcomes: Vec::new(),
        })
    }
}
