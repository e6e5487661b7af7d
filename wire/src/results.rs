//! Episode results and task outcomes on the wire.

use paddock_proto::{Error, ErrorCode, error, pack_f64, unpack_f64};
use paddock_rollout::{
    AgentResult, AgentTrace, EpisodeResult, RolloutError, Termination, Trajectory,
};
use prost::Message;

use crate::scenario::{rollout_error_from_proto, rollout_error_to_proto};

fn termination_to_proto(t: Termination) -> paddock_proto::Termination {
    match t {
        Termination::Finished => paddock_proto::Termination::Finished,
        Termination::Crashed => paddock_proto::Termination::Crashed,
        Termination::TimeLimit => paddock_proto::Termination::TimeLimit,
    }
}

/// The wire form of an episode's result; trajectories as packed f64.
pub fn episode_result_to_proto(r: &EpisodeResult) -> paddock_proto::EpisodeResult {
    paddock_proto::EpisodeResult {
        seed: r.seed,
        map: r.map.clone(),
        steps: r.steps,
        time: r.time,
        agents: r
            .agents
            .iter()
            .map(|a| paddock_proto::AgentResult {
                driver: a.driver.clone(),
                termination: termination_to_proto(a.termination) as i32,
                lap_times: a.lap_times.clone(),
                collided: a.collided,
                progress: a.progress,
                end_time: a.end_time,
                episode_return: a.episode_return,
            })
            .collect(),
        trajectory: r.trajectory.as_ref().map(|tr| paddock_proto::Trajectory {
            decimation: tr.decimation,
            t: pack_f64(&tr.t),
            agents: tr
                .agents
                .iter()
                .map(|a| paddock_proto::AgentTrace {
                    x: pack_f64(&a.x),
                    y: pack_f64(&a.y),
                    theta: pack_f64(&a.theta),
                    speed: pack_f64(&a.speed),
                    steer: pack_f64(&a.steer),
                })
                .collect(),
        }),
    }
}

/// The domain result of a wire result; packed arrays are checked for whole values and
/// equal lengths.
pub fn episode_result_from_proto(r: &paddock_proto::EpisodeResult) -> Result<EpisodeResult, Error> {
    let mut agents = Vec::with_capacity(r.agents.len());
    for (i, a) in r.agents.iter().enumerate() {
        let termination = match paddock_proto::Termination::try_from(a.termination) {
            Ok(paddock_proto::Termination::Finished) => Termination::Finished,
            Ok(paddock_proto::Termination::Crashed) => Termination::Crashed,
            Ok(paddock_proto::Termination::TimeLimit) => Termination::TimeLimit,
            _ => {
                return Err(error(
                    ErrorCode::BadMessage,
                    format!("agents[{i}].termination"),
                    format!("agents[{i}].termination = {} is not known", a.termination),
                ));
            }
        };
        agents.push(AgentResult {
            driver: a.driver.clone(),
            termination,
            lap_times: a.lap_times.clone(),
            collided: a.collided,
            progress: a.progress,
            end_time: a.end_time,
            episode_return: a.episode_return,
        });
    }
    let trajectory = match &r.trajectory {
        None => None,
        Some(tr) => {
            let t = unpack_f64(&tr.t, "trajectory.t")?;
            let mut traces = Vec::with_capacity(tr.agents.len());
            for (i, a) in tr.agents.iter().enumerate() {
                let unpack = |bytes: &[u8], name: &str| -> Result<Vec<f64>, Error> {
                    let field = format!("trajectory.agents[{i}].{name}");
                    let v = unpack_f64(bytes, &field)?;
                    if v.len() != t.len() {
                        return Err(error(
                            ErrorCode::BadMessage,
                            field.clone(),
                            format!(
                                "{field} has {} samples, trajectory.t has {}",
                                v.len(),
                                t.len()
                            ),
                        ));
                    }
                    Ok(v)
                };
                traces.push(AgentTrace {
                    x: unpack(&a.x, "x")?,
                    y: unpack(&a.y, "y")?,
                    theta: unpack(&a.theta, "theta")?,
                    speed: unpack(&a.speed, "speed")?,
                    steer: unpack(&a.steer, "steer")?,
                });
            }
            Some(Trajectory {
                decimation: tr.decimation,
                t,
                agents: traces,
            })
        }
    };
    Ok(EpisodeResult {
        seed: r.seed,
        map: r.map.clone(),
        steps: r.steps,
        time: r.time,
        agents,
        trajectory,
    })
}

/// The wire outcome of one task.
pub fn outcome_to_proto(r: &Result<EpisodeResult, RolloutError>) -> paddock_proto::TaskOutcome {
    paddock_proto::TaskOutcome {
        outcome: Some(match r {
            Ok(e) => paddock_proto::task_outcome::Outcome::Episode(episode_result_to_proto(e)),
            Err(e) => paddock_proto::task_outcome::Outcome::Error(rollout_error_to_proto(e)),
        }),
    }
}

/// The domain outcome of one wire outcome; a missing or undecodable outcome is an error
/// outcome naming the problem.
pub fn outcome_from_proto(o: &paddock_proto::TaskOutcome) -> Result<EpisodeResult, RolloutError> {
    match &o.outcome {
        Some(paddock_proto::task_outcome::Outcome::Episode(e)) => {
            episode_result_from_proto(e).map_err(|e| rollout_error_from_proto(&e))
        }
        Some(paddock_proto::task_outcome::Outcome::Error(e)) => Err(rollout_error_from_proto(e)),
        None => Err(rollout_error_from_proto(&error(
            ErrorCode::BadMessage,
            "outcome",
            "a task outcome carries neither an episode nor an error",
        ))),
    }
}

/// The encoded wire outcome of one task: the payload frame a worker sends after its
/// `TaskResult` header.
pub fn outcome_to_bytes(r: &Result<EpisodeResult, RolloutError>) -> Vec<u8> {
    outcome_to_proto(r).encode_to_vec()
}

/// The domain outcome of one encoded wire outcome (a payload frame of a rollout result).
pub fn outcome_from_bytes(bytes: &[u8]) -> Result<EpisodeResult, RolloutError> {
    match paddock_proto::TaskOutcome::decode(bytes) {
        Ok(o) => outcome_from_proto(&o),
        Err(e) => Err(rollout_error_from_proto(&error(
            ErrorCode::BadMessage,
            "outcome",
            format!(
                "a task outcome of {} bytes does not decode: {e}",
                bytes.len()
            ),
        ))),
    }
}
