//! Interactive env sessions on the wire: the open request as an [`EnvConfig`] (read by
//! the same agent, LIDAR, obstacle and collision readers as a scenario), resets and steps
//! as plain slices, and an [`EnvFrame`] as its payload frames: the small
//! [`EnvObservation`] message and the scans frame, which travels untouched from the
//! worker to the learner.

use paddock_proto::{
    EnvObservation, EnvOpen, EnvOpened, EnvReset, EnvStep, Error, ErrorCode, error, pack_f32,
    pack_f64, pack_u32, unpack_f64,
};
use paddock_rollout::env::{EnvConfig, EnvFrame, RewardWeights, VecEnv};
use paddock_rollout::{AgentSpec, RolloutError};
use paddock_sim::geometry::Pose;
use paddock_sim::params::VehicleParams;
use paddock_sim::world::WorldError;

use crate::scenario::{
    collision_mode_from_proto, lidar_from_proto, obstacles_from_proto, vehicle_from_yaml,
};
use crate::{invalid, u32_of};

/// The env config of an open request on the map `map` (a map folder, or a name the
/// worker's circuit registry knows). Cars whose
/// request carries the default vehicle get `default_vehicle` when one is given (a
/// worker started with `--vehicle`). Errors name the field as the client sent it
/// (`opponents[1].params`, `lidar.fov`, ...).
pub fn config_from_proto(
    o: &EnvOpen,
    map: &str,
    default_vehicle: Option<&VehicleParams>,
) -> Result<EnvConfig, Error> {
    let vehicle = |yaml: &str, prefix: &str| -> Result<VehicleParams, Error> {
        let v = vehicle_from_yaml(yaml, prefix)?;
        match default_vehicle {
            Some(mine) if v == VehicleParams::default() => Ok(mine.clone()),
            _ => Ok(v),
        }
    };
    let mut opponents = Vec::with_capacity(o.opponents.len());
    for (k, a) in o.opponents.iter().enumerate() {
        // no parameters: the driver's defaults (a known driver; an unknown one is
        // refused by the session's checks, naming it)
        let params = match AgentSpec::with_defaults(&a.driver) {
            Ok(defaults) if a.params.is_empty() => defaults.params,
            _ => a.params.clone(),
        };
        opponents.push(AgentSpec {
            driver: a.driver.clone(),
            params,
            vehicle: vehicle(&a.vehicle_yaml, &format!("opponents[{k}]"))?,
        });
    }
    let reward = match &o.reward {
        None => RewardWeights::default(),
        Some(w) => RewardWeights {
            progress: w.progress,
            collision: w.collision,
            lap: w.lap,
            time: w.time,
        },
    };
    Ok(EnvConfig {
        map: map.to_string(),
        num_envs: o.num_envs as usize,
        seed: o.seed,
        // 0 (a client that does not set it): one learner
        learners: (o.learners as usize).max(1),
        opponents,
        vehicle: vehicle(&o.vehicle_yaml, "")?,
        lidar: lidar_from_proto(o.lidar.as_ref())?,
        obstacles: obstacles_from_proto(o.obstacles.as_ref())?,
        laps: o.laps,
        time_limit: o.time_limit,
        collision_mode: collision_mode_from_proto(o.collision_mode)?,
        reward,
        frame_skip: o.frame_skip,
    })
}

/// The reply to an open: the session's shape and action bounds.
pub fn opened_to_proto(env: &VecEnv) -> EnvOpened {
    let (low, high) = env.action_bounds();
    EnvOpened {
        num_envs: u32_of(env.num_envs()),
        num_beams: u32_of(env.num_beams()),
        num_agents: u32_of(env.num_agents()),
        action_low: low.to_vec(),
        action_high: high.to_vec(),
        dt: env.dt(),
        num_learners: u32_of(env.num_learners()),
    }
}

/// A reset request as the env takes it.
#[derive(Debug, Clone, PartialEq)]
pub struct Reset {
    pub envs: Vec<usize>,
    pub seeds: Vec<u64>,
    pub poses: Option<Vec<Pose>>,
}

impl Reset {
    /// Whether it resets every one of `num_envs` envs, each with its own seed: the
    /// session's state after it does not depend on anything before it (a rebuild of the
    /// session may start here).
    pub fn restarts_all(&self, num_envs: usize) -> bool {
        let targets = if self.envs.is_empty() {
            num_envs
        } else {
            let mut seen = vec![false; num_envs];
            for &i in &self.envs {
                match seen.get_mut(i) {
                    Some(s) if !*s => *s = true,
                    _ => return false,
                }
            }
            if seen.iter().any(|s| !s) {
                return false;
            }
            self.envs.len()
        };
        self.seeds.len() == targets
    }
}

/// The reset of an `EnvReset` (field names under `env_reset`).
pub fn reset_from_proto(r: &EnvReset) -> Result<Reset, Error> {
    let poses = if r.poses.is_empty() {
        None
    } else {
        let v = unpack_f64(&r.poses, "env_reset.poses")?;
        if v.len() % 3 != 0 {
            return Err(invalid(
                "env_reset.poses",
                format!(
                    "env_reset.poses holds {} f64 values, not a whole number of [x, y, theta] poses",
                    v.len()
                ),
            ));
        }
        Some(
            v.chunks_exact(3)
                .map(|p| Pose::new(p[0], p[1], p[2]))
                .collect(),
        )
    };
    Ok(Reset {
        envs: r.envs.iter().map(|&i| i as usize).collect(),
        seeds: r.seeds.clone(),
        poses,
    })
}

/// The actions (`num_envs` x `learners` x [steer, speed]) and the envs to reset instead
/// of stepping of an `EnvStep`.
pub fn step_from_proto(
    s: &EnvStep,
    num_envs: usize,
    learners: usize,
) -> Result<(Vec<f32>, Vec<usize>), Error> {
    let want = num_envs * learners * 8;
    if s.actions.len() != want {
        let shape = if learners == 1 {
            format!("{num_envs} envs x [steer, speed]")
        } else {
            format!("{num_envs} envs x {learners} learners x [steer, speed]")
        };
        return Err(invalid(
            "env_step.actions",
            format!(
                "env_step.actions has {} bytes; expected {shape} as f32 = {want} bytes",
                s.actions.len(),
            ),
        ));
    }
    let actions = s
        .actions
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    Ok((actions, s.reset_envs.iter().map(|&i| i as usize).collect()))
}

fn bytes_of(flags: &[bool]) -> Vec<u8> {
    flags.iter().map(|&b| u8::from(b)).collect()
}

/// The payload frames of an observation: the [`EnvObservation`] message (everything but
/// the scans) and the scans as packed little-endian f32, `num_envs x num_beams`, copied
/// from the frame (an env session has its worlds write the scans frame directly:
/// [`observation_meta`]).
pub fn observation_frames(f: &EnvFrame) -> (EnvObservation, Vec<u8>) {
    (observation_meta(f), pack_f32(&f.scans))
}

/// The `EnvObservation` message of a frame (everything but the scans, whose frame an
/// env session writes itself: [`VecEnv::step_packed`]).
pub fn observation_meta(f: &EnvFrame) -> EnvObservation {
    EnvObservation {
        num_envs: u32_of(f.num_envs),
        states: pack_f64(&f.states),
        rewards: pack_f64(&f.rewards),
        terminated: bytes_of(&f.terminated),
        truncated: bytes_of(&f.truncated),
        progress: pack_f64(&f.progress),
        laps: pack_u32(&f.laps),
        time: pack_f64(&f.time),
        agent_collisions: bytes_of(&f.agent_collisions),
        agent_lap_counts: pack_u32(&f.agent_lap_counts),
        agent_lap_times: pack_f64(&f.agent_lap_times),
    }
}

/// The wire error of an env session's failure, with the field as the client named it
/// (cars `learners..` are `opponents[0..]`).
pub fn env_error(e: &RolloutError, learners: usize) -> Error {
    match e {
        RolloutError::Invalid { field, .. } => invalid(field.clone(), e.to_string()),
        RolloutError::Map(_) => invalid("map", e.to_string()),
        RolloutError::Driver { agent, .. } => invalid(
            format!("opponents[{}]", agent.saturating_sub(learners)),
            e.to_string(),
        ),
        RolloutError::World(WorldError::Config { field, .. }) => {
            invalid(field.clone(), e.to_string())
        }
        RolloutError::World(WorldError::Placement { .. }) => {
            error(ErrorCode::Internal, "", e.to_string())
        }
        RolloutError::World(_) => invalid("", e.to_string()),
        RolloutError::Transport { .. } => error(ErrorCode::Internal, "", e.to_string()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_seeded_reset_is_a_restart_point() {
        let r = |envs: &[usize], seeds: &[u64]| Reset {
            envs: envs.to_vec(),
            seeds: seeds.to_vec(),
            poses: None,
        };
        assert!(r(&[], &[1, 2, 3]).restarts_all(3));
        assert!(r(&[2, 0, 1], &[1, 2, 3]).restarts_all(3));
        assert!(!r(&[], &[]).restarts_all(3));
        assert!(!r(&[0, 1], &[1, 2]).restarts_all(3));
        assert!(!r(&[0, 0, 1], &[1, 2, 3]).restarts_all(3));
        assert!(!r(&[0, 1, 7], &[1, 2, 3]).restarts_all(3));
        // start poses are part of the request, which the rebuild starts with
        let mut posed = r(&[], &[1, 2, 3]);
        posed.poses = Some(vec![Pose::new(0.0, 0.0, 0.0); 3]);
        assert!(posed.restarts_all(3));
    }

    #[test]
    fn actions_must_match_the_envs() {
        let step = EnvStep {
            actions: pack_f32(&[0.1, 2.0, -0.1, 3.0]),
            reset_envs: vec![1],
        };
        let (a, reset) = step_from_proto(&step, 2, 1).unwrap();
        assert_eq!(a, [0.1, 2.0, -0.1, 3.0]);
        assert_eq!(reset, [1]);
        let e = step_from_proto(&step, 3, 1).unwrap_err();
        assert_eq!(e.field, "env_step.actions");
        assert!(e.message.contains("24 bytes"), "{}", e.message);
        let e = step_from_proto(&step, 2, 2).unwrap_err();
        assert!(
            e.message
                .contains("expected 2 envs x 2 learners x [steer, speed] as f32 = 32 bytes"),
            "{}",
            e.message
        );
        let e = reset_from_proto(&EnvReset {
            poses: pack_f64(&[1.0, 2.0]),
            ..Default::default()
        })
        .unwrap_err();
        assert_eq!(e.field, "env_reset.poses");
    }
}
