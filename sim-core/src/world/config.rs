//! What a world is built from: its cars, obstacles, LIDAR and rules, checked once.

use serde::{Deserialize, Serialize};

use crate::collision::CollisionMode;
use crate::geometry::Pose;
use crate::lidar::LidarConfig;
use crate::params::VehicleParams;

/// Errors from building, resetting or stepping a world. Each names the field and value.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum WorldError {
    #[error("invalid world config: {field} = {value}: {reason}")]
    Config {
        field: String,
        value: String,
        reason: String,
    },
    #[error("agent {agent}: {field} = {value} is not a finite number")]
    NonFiniteAction {
        agent: usize,
        field: &'static str,
        value: f64,
    },
    #[error("expected {expected} actions (one per agent), got {got}")]
    ActionCount { expected: usize, got: usize },
    #[error("expected {expected} start poses (one per agent), got {got}")]
    PoseCount { expected: usize, got: usize },
    #[error("start pose of agent {agent} is not finite: {pose:?}")]
    NonFinitePose { agent: usize, pose: Pose },
    #[error("could not place {what} on the track after {attempts} attempts: {reason}")]
    Placement {
        what: String,
        attempts: usize,
        reason: String,
    },
    #[error("snapshot has {got} agents, this world has {expected}")]
    SnapshotMismatch { expected: usize, got: usize },
    #[error("the world has not been reset")]
    NotReset,
}

/// One car's configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AgentConfig {
    pub params: VehicleParams,
    /// Cast this car's LIDAR every step (drivers that do not use it skip the cost).
    pub scan: bool,
}

impl Default for AgentConfig {
    fn default() -> Self {
        Self {
            params: VehicleParams::default(),
            scan: true,
        }
    }
}

/// Static box obstacles placed at seeded random places on the track.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ObstacleConfig {
    pub count: usize,
    /// Box size along and across the track, metres.
    pub length: f64,
    pub width: f64,
    /// Free passage kept beside every obstacle, metres.
    pub passage: f64,
    /// No obstacle within this distance of a start pose, metres.
    pub start_clearance: f64,
}

impl Default for ObstacleConfig {
    fn default() -> Self {
        Self {
            count: 0,
            length: 0.4,
            width: 0.4,
            passage: 1.0,
            start_clearance: 4.0,
        }
    }
}

/// Episode settings that hold for every step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WorldConfig {
    /// Timestep, seconds (the reference's 0.01).
    pub dt: f64,
    pub lidar: LidarConfig,
    pub collision_mode: CollisionMode,
    pub agents: Vec<AgentConfig>,
    pub obstacles: ObstacleConfig,
    /// A car that completes this many laps is finished (None: never).
    pub laps: Option<u32>,
}

impl Default for WorldConfig {
    fn default() -> Self {
        Self {
            dt: 0.01,
            lidar: LidarConfig::default(),
            collision_mode: CollisionMode::Terminate,
            agents: vec![AgentConfig::default()],
            obstacles: ObstacleConfig::default(),
            laps: None,
        }
    }
}

impl WorldConfig {
    /// `n` identical default cars.
    pub fn with_agents(n: usize) -> Self {
        Self {
            agents: vec![AgentConfig::default(); n],
            ..Self::default()
        }
    }

    pub(super) fn validate(&self) -> Result<(), WorldError> {
        let bad = |field: &str, value: String, reason: &str| {
            Err(WorldError::Config {
                field: field.into(),
                value,
                reason: reason.into(),
            })
        };
        if !(self.dt.is_finite() && self.dt > 0.0 && self.dt <= 0.1) {
            return bad("dt", self.dt.to_string(), "must be in (0, 0.1] seconds");
        }
        if self.agents.is_empty() {
            return bad("agents", "0".into(), "a world needs at least one agent");
        }
        if self.agents.len() > 64 {
            return bad("agents", self.agents.len().to_string(), "at most 64 agents");
        }
        for (i, a) in self.agents.iter().enumerate() {
            if let Err(e) = a.params.validate() {
                return bad(
                    &format!("agents[{i}].params"),
                    String::new(),
                    &e.to_string(),
                );
            }
        }
        let o = &self.obstacles;
        for (name, v) in [
            ("obstacles.length", o.length),
            ("obstacles.width", o.width),
            ("obstacles.passage", o.passage),
            ("obstacles.start_clearance", o.start_clearance),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(name, v.to_string(), "must be a finite number >= 0");
            }
        }
        if o.count > 1000 {
            return bad("obstacles.count", o.count.to_string(), "at most 1000");
        }
        let l = &self.lidar;
        if l.num_beams == 0 || l.num_beams > 100_000 {
            return bad(
                "lidar.num_beams",
                l.num_beams.to_string(),
                "must be 1..=100000",
            );
        }
        for (name, v) in [
            ("lidar.fov", l.fov),
            ("lidar.max_range", l.max_range),
            ("lidar.noise_std", l.noise_std),
            ("lidar.mount_offset", l.mount_offset),
        ] {
            if !v.is_finite() {
                return bad(name, v.to_string(), "must be finite");
            }
        }
        if l.max_range <= 0.0 || l.noise_std < 0.0 || l.fov <= 0.0 {
            return bad(
                "lidar",
                format!("{l:?}"),
                "fov and max_range must be > 0, noise_std >= 0",
            );
        }
        Ok(())
    }
}
