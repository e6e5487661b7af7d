//! Scenarios and rollout tasks on the wire: one reader for every field a scenario (or an
//! env session, see [`crate::env`]) carries, naming the first bad value.

use std::path::Path;
use std::sync::Arc;

use paddock_policy::PolicyError;
use paddock_proto::{Error, ErrorCode, error};
use paddock_rollout::{AgentSpec, EpisodeTask, RolloutError, Scenario, StartSpec};
use paddock_sim::collision::CollisionMode;
use paddock_sim::geometry::Pose;
use paddock_sim::lidar::LidarConfig;
use paddock_sim::params::VehicleParams;
use paddock_sim::world::ObstacleConfig;
use prost::Message;

use crate::{check_range, invalid, u32_of, with_prefix};

/// Most LIDAR beams a request may ask for.
pub const MAX_BEAMS: u32 = 10_000;
/// Most obstacles a request may ask for.
pub const MAX_OBSTACLES: u32 = 1_000;

pub(crate) fn agent_to_proto(a: &AgentSpec) -> paddock_proto::AgentSpec {
    paddock_proto::AgentSpec {
        driver: a.driver.clone(),
        params: a.params.clone(),
        // the default vehicle travels as nothing at all
        vehicle_yaml: if a.vehicle == VehicleParams::default() {
            String::new()
        } else {
            a.vehicle.to_yaml_string()
        },
    }
}

/// The wire form of a scenario whose map is `map`.
pub fn scenario_to_proto(s: &Scenario, map: paddock_proto::MapRef) -> paddock_proto::Scenario {
    let (start_kind, start_poses) = match &s.starts {
        StartSpec::Random => (paddock_proto::StartKind::StartRandom, Vec::new()),
        StartSpec::RandomReversed => (paddock_proto::StartKind::StartRandomReversed, Vec::new()),
        StartSpec::Poses(p) => (
            paddock_proto::StartKind::StartPoses,
            p.iter()
                .map(|p| paddock_proto::Pose {
                    x: p.x,
                    y: p.y,
                    theta: p.theta,
                })
                .collect(),
        ),
    };
    paddock_proto::Scenario {
        map: Some(map),
        agents: s.agents.iter().map(agent_to_proto).collect(),
        start_kind: start_kind as i32,
        start_poses,
        obstacles: Some(paddock_proto::Obstacles {
            count: u32_of(s.obstacles.count),
            length: s.obstacles.length,
            width: s.obstacles.width,
            passage: s.obstacles.passage,
            start_clearance: s.obstacles.start_clearance,
        }),
        laps: s.laps,
        time_limit: s.time_limit,
        collision_mode: collision_mode_to_proto(s.collision_mode),
        lidar: Some(paddock_proto::Lidar {
            num_beams: u32_of(s.lidar.num_beams),
            fov: s.lidar.fov,
            max_range: s.lidar.max_range,
            noise_std: s.lidar.noise_std,
            mount_offset: s.lidar.mount_offset,
        }),
        crash_penalty: s.crash_penalty,
    }
}

pub(crate) fn lidar_from_proto(l: Option<&paddock_proto::Lidar>) -> Result<LidarConfig, Error> {
    let Some(l) = l else {
        return Ok(LidarConfig::default());
    };
    if l.num_beams == 0 || l.num_beams > MAX_BEAMS {
        return Err(invalid(
            "lidar.num_beams",
            format!(
                "lidar.num_beams = {} is outside [1, {MAX_BEAMS}]",
                l.num_beams
            ),
        ));
    }
    check_range("lidar.fov", l.fov, 1e-6, std::f64::consts::TAU)?;
    check_range("lidar.max_range", l.max_range, 1e-6, 1e4)?;
    check_range("lidar.noise_std", l.noise_std, 0.0, 1e3)?;
    check_range("lidar.mount_offset", l.mount_offset, -10.0, 10.0)?;
    Ok(LidarConfig {
        num_beams: l.num_beams as usize,
        fov: l.fov,
        max_range: l.max_range,
        noise_std: l.noise_std,
        mount_offset: l.mount_offset,
    })
}

pub(crate) fn obstacles_from_proto(
    o: Option<&paddock_proto::Obstacles>,
) -> Result<ObstacleConfig, Error> {
    let Some(o) = o else {
        return Ok(ObstacleConfig::default());
    };
    if o.count > MAX_OBSTACLES {
        return Err(invalid(
            "obstacles.count",
            format!("obstacles.count = {} is above {MAX_OBSTACLES}", o.count),
        ));
    }
    check_range("obstacles.length", o.length, 0.0, 100.0)?;
    check_range("obstacles.width", o.width, 0.0, 100.0)?;
    check_range("obstacles.passage", o.passage, 0.0, 100.0)?;
    check_range("obstacles.start_clearance", o.start_clearance, 0.0, 1e4)?;
    Ok(ObstacleConfig {
        count: o.count as usize,
        length: o.length,
        width: o.width,
        passage: o.passage,
        start_clearance: o.start_clearance,
    })
}

/// The error reply for a scenario that [`Scenario::validate`] or an episode refused,
/// with the field path of the offending value (e.g. `agents[1].params[2]`).
pub fn rollout_error_to_proto(e: &RolloutError) -> Error {
    match e {
        RolloutError::Invalid { field, .. } => invalid(field.clone(), e.to_string()),
        RolloutError::Driver { agent, source } => {
            let field = match source {
                PolicyError::UnknownDriver { .. } => format!("agents[{agent}].driver"),
                PolicyError::ParamCount { .. } => format!("agents[{agent}].params"),
                PolicyError::OutOfBounds { driver, name, .. }
                | PolicyError::UnknownParam { driver, name, .. } => {
                    match paddock_policy::driver_info(driver)
                        .ok()
                        .and_then(|d| d.params.iter().position(|p| p.name == name))
                    {
                        Some(k) => format!("agents[{agent}].params[{k}]"),
                        None => format!("agents[{agent}].params"),
                    }
                }
                PolicyError::Invalid { .. } => format!("agents[{agent}]"),
                PolicyError::Onnx(_) => format!("agents[{agent}].driver"),
            };
            invalid(field, e.to_string())
        }
        RolloutError::Map(_) => error(ErrorCode::InvalidArgument, "map", e.to_string()),
        RolloutError::World(_) => error(ErrorCode::InvalidArgument, "", e.to_string()),
        RolloutError::Transport { .. } => error(ErrorCode::Internal, "", e.to_string()),
    }
}

/// The domain error for an error that came over the wire (a remote task's failure).
pub fn rollout_error_from_proto(e: &Error) -> RolloutError {
    RolloutError::Invalid {
        field: if e.field.is_empty() {
            "(remote)".into()
        } else {
            e.field.clone()
        },
        value: paddock_proto::code_name(e.code).into(),
        reason: e.message.clone(),
    }
}

/// The domain scenario of a wire scenario whose map files lie in `map_dir`; every field
/// is checked ([`Scenario::validate`] and the ranges here) and the first bad one named.
pub fn scenario_from_proto(s: &paddock_proto::Scenario, map_dir: &Path) -> Result<Scenario, Error> {
    let mut agents = Vec::with_capacity(s.agents.len());
    for (i, a) in s.agents.iter().enumerate() {
        let vehicle = vehicle_from_yaml(&a.vehicle_yaml, &format!("agents[{i}]"))?;
        agents.push(AgentSpec {
            driver: a.driver.clone(),
            params: a.params.clone(),
            vehicle,
        });
    }
    let starts = match paddock_proto::StartKind::try_from(s.start_kind) {
        Ok(paddock_proto::StartKind::StartRandom) => StartSpec::Random,
        Ok(paddock_proto::StartKind::StartRandomReversed) => StartSpec::RandomReversed,
        Ok(paddock_proto::StartKind::StartPoses) => {
            let mut poses = Vec::with_capacity(s.start_poses.len());
            for (i, p) in s.start_poses.iter().enumerate() {
                for (name, v) in [("x", p.x), ("y", p.y), ("theta", p.theta)] {
                    if !v.is_finite() {
                        return Err(invalid(
                            format!("start_poses[{i}].{name}"),
                            format!("start_poses[{i}].{name} = {v} is not a finite number"),
                        ));
                    }
                }
                poses.push(Pose {
                    x: p.x,
                    y: p.y,
                    theta: p.theta,
                });
            }
            StartSpec::Poses(poses)
        }
        Err(_) => {
            return Err(invalid(
                "start_kind",
                format!("start_kind = {} is not a known StartKind", s.start_kind),
            ));
        }
    };
    let collision_mode = collision_mode_from_proto(s.collision_mode)?;
    let scenario = Scenario {
        map: map_dir.display().to_string(),
        agents,
        starts,
        obstacles: obstacles_from_proto(s.obstacles.as_ref())?,
        laps: s.laps,
        time_limit: s.time_limit,
        collision_mode,
        lidar: lidar_from_proto(s.lidar.as_ref())?,
        crash_penalty: s.crash_penalty,
    };
    scenario
        .validate()
        .map_err(|e| rollout_error_to_proto(&e))?;
    Ok(scenario)
}

/// The domain scenario of an encoded wire scenario (as a batch carries it and a worker
/// fetches it by hash) whose map files lie in `map_dir`.
pub fn scenario_from_bytes(bytes: &[u8], map_dir: &Path) -> Result<Scenario, Error> {
    let wire = paddock_proto::Scenario::decode(bytes).map_err(|e| {
        error(
            ErrorCode::BadMessage,
            "",
            format!("the scenario's {} bytes do not decode: {e}", bytes.len()),
        )
    })?;
    scenario_from_proto(&wire, map_dir)
}

/// The domain task of a [`paddock_proto::TaskAssign`] whose scenario (named by hash in
/// the assignment) is `scenario`.
pub fn task_from_assign(t: &paddock_proto::TaskAssign, scenario: Arc<Scenario>) -> EpisodeTask {
    EpisodeTask {
        scenario,
        seed: t.seed,
        record: record_from_proto(t.record_decimation),
    }
}

/// The vehicle of a vehicle YAML (empty: the default vehicle); errors name the field
/// under `prefix` (e.g. `agents[1].vehicle_yaml.m`).
pub(crate) fn vehicle_from_yaml(yaml: &str, prefix: &str) -> Result<VehicleParams, Error> {
    VehicleParams::from_yaml_str(yaml).map_err(|e| {
        let field = match e.field() {
            Some(f) => format!("vehicle_yaml.{f}"),
            None => "vehicle_yaml".into(),
        };
        with_prefix(invalid(field, e.to_string()), prefix)
    })
}

/// The collision mode of its wire value.
pub(crate) fn collision_mode_from_proto(v: i32) -> Result<CollisionMode, Error> {
    match paddock_proto::CollisionMode::try_from(v) {
        Ok(paddock_proto::CollisionMode::CollisionTerminate) => Ok(CollisionMode::Terminate),
        Ok(paddock_proto::CollisionMode::CollisionStop) => Ok(CollisionMode::Stop),
        Ok(paddock_proto::CollisionMode::CollisionIgnore) => Ok(CollisionMode::Ignore),
        Err(_) => Err(invalid(
            "collision_mode",
            format!("collision_mode = {v} is not a known CollisionMode"),
        )),
    }
}

/// The wire value of a collision mode.
pub(crate) fn collision_mode_to_proto(m: CollisionMode) -> i32 {
    let mode = match m {
        CollisionMode::Terminate => paddock_proto::CollisionMode::CollisionTerminate,
        CollisionMode::Stop => paddock_proto::CollisionMode::CollisionStop,
        CollisionMode::Ignore => paddock_proto::CollisionMode::CollisionIgnore,
    };
    mode as i32
}

/// `record_decimation` on the wire: 0 = summary only.
pub fn record_to_proto(record: Option<u32>) -> u32 {
    // run_episode records every max(1, d) steps, so Some(0) means every step
    record.map_or(0, |d| d.max(1))
}

/// The task's recording request from `record_decimation`.
pub fn record_from_proto(d: u32) -> Option<u32> {
    (d > 0).then_some(d)
}

/// A [`paddock_proto::RolloutBatch`] of `tasks`: scenarios shared between tasks are sent once.
/// `map_of` gives the [`paddock_proto::MapRef`] of each scenario's map.
pub fn batch_to_proto(
    tasks: &[EpisodeTask],
    mut map_of: impl FnMut(&str) -> paddock_proto::MapRef,
    progress: bool,
) -> paddock_proto::RolloutBatch {
    let mut scenarios: Vec<(Arc<Scenario>, paddock_proto::Scenario)> = Vec::new();
    let mut specs = Vec::with_capacity(tasks.len());
    for t in tasks {
        let index = match scenarios
            .iter()
            .position(|(s, _)| Arc::ptr_eq(s, &t.scenario) || **s == *t.scenario)
        {
            Some(i) => i,
            None => {
                let wire = scenario_to_proto(&t.scenario, map_of(&t.scenario.map));
                scenarios.push((t.scenario.clone(), wire));
                scenarios.len() - 1
            }
        };
        specs.push(paddock_proto::RolloutTaskSpec {
            scenario: u32_of(index),
            seed: t.seed,
            record_decimation: record_to_proto(t.record),
        });
    }
    paddock_proto::RolloutBatch {
        scenarios: scenarios
            .into_iter()
            .map(|(_, w)| w.encode_to_vec())
            .collect(),
        tasks: specs,
        progress,
    }
}

// ------------------------------------------------------------------ results
