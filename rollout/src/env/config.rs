//! What defines a session's environment ([`EnvConfig`], [`RewardWeights`]) and its limits,
//! checked field by field before any copy is built.

use paddock_policy::{check_params, driver_info};
use paddock_sim::collision::CollisionMode;
use paddock_sim::lidar::LidarConfig;
use paddock_sim::params::VehicleParams;
use paddock_sim::world::{AgentConfig, ObstacleConfig, WorldConfig};
use serde::{Deserialize, Serialize};

use crate::{AgentSpec, RolloutError};

/// Most copies one session may hold.
pub const MAX_ENVS: usize = 1024;
/// Most cars per copy, learners and opponents together (as a scenario).
pub const MAX_CARS: usize = 16;
/// Most opponents per copy (16 cars in all, as a scenario).
pub const MAX_OPPONENTS: usize = MAX_CARS - 1;
/// Most LIDAR beams of a learner's scan.
pub const MAX_BEAMS: usize = 10_000;
/// Most scan values of one frame (`num_envs x learners x beams`): a frame's scans stay
/// within 40 MB, as with one learner at the other limits.
pub const MAX_SCAN_VALUES: usize = MAX_ENVS * MAX_BEAMS;
/// Most physics steps per env step.
pub const MAX_FRAME_SKIP: u32 = 1000;
/// Values per car in [`EnvFrame::states`](super::EnvFrame::states):
/// `[x, y, theta, vx, vy, yaw_rate, steer]`.
pub const STATE_SIZE: usize = 7;

/// Reward of one env step: the weighted sum over its physics steps of
/// `progress * metres gained + collision * (collided this step) + lap * (lap completed) +
/// time * seconds`. Give penalties as negative weights.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RewardWeights {
    pub progress: f64,
    pub collision: f64,
    pub lap: f64,
    pub time: f64,
}

impl Default for RewardWeights {
    /// One per metre of progress along the track, minus 10 for a crash.
    fn default() -> Self {
        Self {
            progress: 1.0,
            collision: -10.0,
            lap: 0.0,
            time: 0.0,
        }
    }
}

/// Everything that defines one session's environment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EnvConfig {
    /// Map name (shipped maps) or directory.
    pub map: String,
    pub num_envs: usize,
    /// Root of every copy's seed stream.
    pub seed: u64,
    /// Learner cars per copy: cars `0..learners`, driven by the learner's actions
    /// (1: a single-agent env; more: self-play and multi-agent learners).
    #[serde(default = "one")]
    pub learners: usize,
    /// Cars `learners..` of every copy and their drivers.
    pub opponents: Vec<AgentSpec>,
    /// The learners' cars.
    pub vehicle: VehicleParams,
    pub lidar: LidarConfig,
    pub obstacles: ObstacleConfig,
    /// A car finishes (its learner is terminated) after this many laps.
    pub laps: u32,
    /// Simulated seconds before an episode is truncated.
    pub time_limit: f64,
    pub collision_mode: CollisionMode,
    pub reward: RewardWeights,
    /// Physics steps per env step (the action is repeated), >= 1.
    pub frame_skip: u32,
}

impl EnvConfig {
    /// `num_envs` copies of one car alone on `map` with the defaults.
    pub fn single(map: &str, num_envs: usize, seed: u64) -> Self {
        Self {
            map: map.into(),
            num_envs,
            seed,
            learners: 1,
            opponents: Vec::new(),
            vehicle: VehicleParams::default(),
            lidar: LidarConfig::default(),
            obstacles: ObstacleConfig::default(),
            laps: 1,
            time_limit: 120.0,
            collision_mode: CollisionMode::Terminate,
            reward: RewardWeights::default(),
            frame_skip: 1,
        }
    }

    /// Check every field, naming the first bad one.
    pub fn validate(&self) -> Result<(), RolloutError> {
        if self.map.is_empty() {
            return invalid("map", "\"\"", "a map name or directory is required");
        }
        if self.num_envs == 0 || self.num_envs > MAX_ENVS {
            return invalid(
                "num_envs",
                self.num_envs,
                &format!("must be 1..={MAX_ENVS}"),
            );
        }
        if self.learners == 0 || self.learners > MAX_CARS {
            return invalid(
                "learners",
                self.learners,
                &format!("must be 1..={MAX_CARS}"),
            );
        }
        if self.opponents.len() > MAX_CARS - self.learners {
            return invalid(
                "opponents",
                self.opponents.len(),
                &format!(
                    "at most {} opponents beside {} learners ({MAX_CARS} cars in all)",
                    MAX_CARS - self.learners,
                    self.learners
                ),
            );
        }
        for (k, o) in self.opponents.iter().enumerate() {
            let info = driver_info(&o.driver).or_else(|e| {
                invalid(&format!("opponents[{k}].driver"), &o.driver, &e.to_string())
            })?;
            check_params(info.name, &info.params, &o.params).or_else(|e| {
                invalid(
                    &format!("opponents[{k}].params"),
                    format!("{:?}", o.params),
                    &e.to_string(),
                )
            })?;
            o.vehicle.validate().or_else(|e| {
                invalid(
                    &format!("opponents[{k}].vehicle"),
                    e.field().unwrap_or(""),
                    &e.to_string(),
                )
            })?;
        }
        self.vehicle
            .validate()
            .or_else(|e| invalid("vehicle", e.field().unwrap_or(""), &e.to_string()))?;
        if self.lidar.num_beams == 0 || self.lidar.num_beams > MAX_BEAMS {
            return invalid(
                "lidar.num_beams",
                self.lidar.num_beams,
                &format!("a learner's scan needs 1..={MAX_BEAMS} beams"),
            );
        }
        let values = self.num_envs * self.learners * self.lidar.num_beams;
        if values > MAX_SCAN_VALUES {
            return invalid(
                "lidar.num_beams",
                self.lidar.num_beams,
                &format!(
                    "{} envs x {} learners x {} beams = {values} scan values, over the \
                     {MAX_SCAN_VALUES} of one frame",
                    self.num_envs, self.learners, self.lidar.num_beams
                ),
            );
        }
        if self.laps == 0 || self.laps > 100 {
            return invalid("laps", self.laps, "must be 1..=100");
        }
        if !(self.time_limit.is_finite() && self.time_limit > 0.0 && self.time_limit <= 36_000.0) {
            return invalid(
                "time_limit",
                self.time_limit,
                "must be in (0, 36000] seconds",
            );
        }
        if self.frame_skip == 0 || self.frame_skip > MAX_FRAME_SKIP {
            return invalid(
                "frame_skip",
                self.frame_skip,
                &format!("must be 1..={MAX_FRAME_SKIP}"),
            );
        }
        let w = &self.reward;
        for (name, v) in [
            ("reward.progress", w.progress),
            ("reward.collision", w.collision),
            ("reward.lap", w.lap),
            ("reward.time", w.time),
        ] {
            if !v.is_finite() {
                return invalid(name, v, "must be a finite number");
            }
        }
        // lidar ranges and obstacles: `World::new` checks them in `VecEnv::new`
        Ok(())
    }

    pub(super) fn world_config(&self, opponent_scans: &[bool]) -> WorldConfig {
        let mut agents = vec![
            AgentConfig {
                params: self.vehicle.clone(),
                scan: true,
            };
            self.learners
        ];
        agents.extend(
            self.opponents
                .iter()
                .zip(
                    opponent_scans
                        .iter()
                        .copied()
                        .chain(std::iter::repeat(false)),
                )
                .map(|(o, scan)| AgentConfig {
                    params: o.vehicle.clone(),
                    scan,
                }),
        );
        WorldConfig {
            dt: 0.01,
            lidar: self.lidar.clone(),
            collision_mode: self.collision_mode,
            agents,
            obstacles: self.obstacles.clone(),
            laps: Some(self.laps),
        }
    }
}

fn one() -> usize {
    1
}

pub(super) fn invalid<T>(
    field: &str,
    value: impl ToString,
    reason: &str,
) -> Result<T, RolloutError> {
    Err(RolloutError::Invalid {
        field: field.into(),
        value: value.to_string(),
        reason: reason.into(),
    })
}
