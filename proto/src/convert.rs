//! Conversions between the wire types and the rollout domain types.
//!
//! Protobuf types stop at the edge: a worker turns a [`crate::TaskAssign`] into an
//! [`EpisodeTask`] here, a client turns [`EpisodeResult`]s back from the wire here.
//! Every f64 travels as its exact bits (proto doubles, packed little-endian bytes,
//! vehicle YAML written with shortest round-trip floats), so a result computed remotely
//! equals the same result computed locally (`PartialEq`). Decoding checks every field a
//! request may carry and names the first bad one in an [`Error`] (`INVALID_ARGUMENT`),
//! e.g. `agents[1].params[2]`; [`with_prefix`] puts the enclosing path in front.

use std::path::Path;
use std::sync::Arc;

use paddock_policy::PolicyError;
use paddock_rollout::{
    AgentResult, AgentSpec, AgentTrace, EpisodeResult, EpisodeTask, RolloutError, Scenario,
    StartSpec, Termination, Trajectory,
};
use paddock_sim::collision::CollisionMode;
use paddock_sim::geometry::Pose;
use paddock_sim::lidar::LidarConfig;
use paddock_sim::params::VehicleParams;
use paddock_sim::world::ObstacleConfig;

use crate::{Error, ErrorCode, error, pack_f64, unpack_f64};

/// Most LIDAR beams a request may ask for.
pub const MAX_BEAMS: u32 = 10_000;
/// Most obstacles a request may ask for.
pub const MAX_OBSTACLES: u32 = 1_000;

fn invalid(field: impl Into<String>, message: impl Into<String>) -> Error {
    error(ErrorCode::InvalidArgument, field, message)
}

/// The same error with `prefix` put in front of its field path
/// (`"scenarios[0]"` + `"agents[1].params[2]"` = `"scenarios[0].agents[1].params[2]"`).
pub fn with_prefix(mut e: Error, prefix: &str) -> Error {
    if prefix.is_empty() {
        return e;
    }
    e.field = if e.field.is_empty() {
        prefix.to_string()
    } else if e.field.starts_with('[') {
        format!("{prefix}{}", e.field)
    } else {
        format!("{prefix}.{}", e.field)
    };
    e
}

// ------------------------------------------------------------------ maps

/// The map directory of a map name or directory (as [`Scenario::map`] holds it) and its
/// bundle: every file, the content hash and the name the client used.
pub fn local_map(map: &str) -> Result<crate::MapBundle, Error> {
    let circuit = paddock_sim::track::Circuit::resolve(map, &[])
        .map_err(|e| error(ErrorCode::NotFound, "map", format!("map {map:?}: {e}")))?;
    let bundle = crate::read_map_dir(&circuit.dir, map).map_err(|e| {
        error(
            ErrorCode::Internal,
            "map",
            format!("reading map {map:?} from {}: {e}", circuit.dir.display()),
        )
    })?;
    // what the broker and workers will check: refuse here, before sending
    crate::check_bundle(&bundle).map_err(|mut e| {
        e.message = format!("map {map:?} in {}: {}", circuit.dir.display(), e.message);
        e
    })?;
    Ok(bundle)
}

/// The bundles of the maps shipped inside the binary ([`paddock_sim::shipped`]), each
/// named by its map name; the same bundles as [`crate::read_map_dir`] makes of the
/// project's map folders.
pub fn shipped_bundles() -> Vec<crate::MapBundle> {
    paddock_sim::shipped::shipped_maps()
        .iter()
        .map(|m| {
            let files: Vec<crate::MapFile> = m
                .files
                .iter()
                .map(|(name, data)| crate::MapFile {
                    name: name.to_string(),
                    data: data.to_vec(),
                })
                .collect();
            crate::MapBundle {
                hash: crate::bundle_hash(&files),
                name: m.name.to_string(),
                files,
            }
        })
        .collect()
}

/// The [`crate::MapRef`] naming a bundle.
pub fn map_ref(bundle: &crate::MapBundle) -> crate::MapRef {
    crate::MapRef {
        name: bundle.name.clone(),
        hash: bundle.hash.clone(),
    }
}

// ------------------------------------------------------------------ scenarios

fn agent_to_proto(a: &AgentSpec) -> crate::AgentSpec {
    crate::AgentSpec {
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

fn u32_of(v: usize) -> u32 {
    // a count beyond u32 is refused by the receiver's range checks
    u32::try_from(v).unwrap_or(u32::MAX)
}

/// The wire form of a scenario whose map is `map`.
pub fn scenario_to_proto(s: &Scenario, map: crate::MapRef) -> crate::Scenario {
    let (start_kind, start_poses) = match &s.starts {
        StartSpec::Random => (crate::StartKind::StartRandom, Vec::new()),
        StartSpec::RandomReversed => (crate::StartKind::StartRandomReversed, Vec::new()),
        StartSpec::Poses(p) => (
            crate::StartKind::StartPoses,
            p.iter()
                .map(|p| crate::Pose {
                    x: p.x,
                    y: p.y,
                    theta: p.theta,
                })
                .collect(),
        ),
    };
    crate::Scenario {
        map: Some(map),
        agents: s.agents.iter().map(agent_to_proto).collect(),
        start_kind: start_kind as i32,
        start_poses,
        obstacles: Some(crate::Obstacles {
            count: u32_of(s.obstacles.count),
            length: s.obstacles.length,
            width: s.obstacles.width,
            passage: s.obstacles.passage,
            start_clearance: s.obstacles.start_clearance,
        }),
        laps: s.laps,
        time_limit: s.time_limit,
        collision_mode: match s.collision_mode {
            CollisionMode::Terminate => crate::CollisionMode::CollisionTerminate,
            CollisionMode::Stop => crate::CollisionMode::CollisionStop,
            CollisionMode::Ignore => crate::CollisionMode::CollisionIgnore,
        } as i32,
        lidar: Some(crate::Lidar {
            num_beams: u32_of(s.lidar.num_beams),
            fov: s.lidar.fov,
            max_range: s.lidar.max_range,
            noise_std: s.lidar.noise_std,
            mount_offset: s.lidar.mount_offset,
        }),
        crash_penalty: s.crash_penalty,
    }
}

fn check_range(field: &str, v: f64, lo: f64, hi: f64) -> Result<(), Error> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(invalid(
            field,
            format!("{field} = {v} is outside [{lo}, {hi}]"),
        ))
    }
}

fn lidar_from_proto(l: Option<&crate::Lidar>) -> Result<LidarConfig, Error> {
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

fn obstacles_from_proto(o: Option<&crate::Obstacles>) -> Result<ObstacleConfig, Error> {
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
        value: crate::code_name(e.code).into(),
        reason: e.message.clone(),
    }
}

/// The domain scenario of a wire scenario whose map files lie in `map_dir`; every field
/// is checked ([`Scenario::validate`] and the ranges here) and the first bad one named.
pub fn scenario_from_proto(s: &crate::Scenario, map_dir: &Path) -> Result<Scenario, Error> {
    let mut agents = Vec::with_capacity(s.agents.len());
    for (i, a) in s.agents.iter().enumerate() {
        let vehicle = VehicleParams::from_yaml_str(&a.vehicle_yaml).map_err(|e| {
            let field = match e.field() {
                Some(f) => format!("agents[{i}].vehicle_yaml.{f}"),
                None => format!("agents[{i}].vehicle_yaml"),
            };
            invalid(field, e.to_string())
        })?;
        agents.push(AgentSpec {
            driver: a.driver.clone(),
            params: a.params.clone(),
            vehicle,
        });
    }
    let starts = match crate::StartKind::try_from(s.start_kind) {
        Ok(crate::StartKind::StartRandom) => StartSpec::Random,
        Ok(crate::StartKind::StartRandomReversed) => StartSpec::RandomReversed,
        Ok(crate::StartKind::StartPoses) => {
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
    let collision_mode = match crate::CollisionMode::try_from(s.collision_mode) {
        Ok(crate::CollisionMode::CollisionTerminate) => CollisionMode::Terminate,
        Ok(crate::CollisionMode::CollisionStop) => CollisionMode::Stop,
        Ok(crate::CollisionMode::CollisionIgnore) => CollisionMode::Ignore,
        Err(_) => {
            return Err(invalid(
                "collision_mode",
                format!(
                    "collision_mode = {} is not a known CollisionMode",
                    s.collision_mode
                ),
            ));
        }
    };
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

/// The domain task of a [`crate::TaskAssign`] whose map files lie in `map_dir`.
pub fn task_from_assign(t: &crate::TaskAssign, map_dir: &Path) -> Result<EpisodeTask, Error> {
    let scenario = t
        .scenario
        .as_ref()
        .ok_or_else(|| invalid("task_assign.scenario", "a task needs a scenario"))?;
    let scenario = scenario_from_proto(scenario, map_dir)
        .map_err(|e| with_prefix(e, "task_assign.scenario"))?;
    Ok(EpisodeTask {
        scenario: Arc::new(scenario),
        seed: t.seed,
        record: record_from_proto(t.record_decimation),
    })
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

/// A [`crate::RolloutBatch`] of `tasks`: scenarios shared between tasks are sent once.
/// `map_of` gives the [`crate::MapRef`] of each scenario's map.
pub fn batch_to_proto(
    tasks: &[EpisodeTask],
    mut map_of: impl FnMut(&str) -> crate::MapRef,
    progress: bool,
) -> crate::RolloutBatch {
    let mut scenarios: Vec<(Arc<Scenario>, crate::Scenario)> = Vec::new();
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
        specs.push(crate::RolloutTaskSpec {
            scenario: u32_of(index),
            seed: t.seed,
            record_decimation: record_to_proto(t.record),
        });
    }
    crate::RolloutBatch {
        scenarios: scenarios.into_iter().map(|(_, w)| w).collect(),
        tasks: specs,
        progress,
    }
}

// ------------------------------------------------------------------ results

fn termination_to_proto(t: Termination) -> crate::Termination {
    match t {
        Termination::Finished => crate::Termination::Finished,
        Termination::Crashed => crate::Termination::Crashed,
        Termination::TimeLimit => crate::Termination::TimeLimit,
    }
}

/// The wire form of an episode's result; trajectories as packed f64.
pub fn episode_result_to_proto(r: &EpisodeResult) -> crate::EpisodeResult {
    crate::EpisodeResult {
        seed: r.seed,
        map: r.map.clone(),
        steps: r.steps,
        time: r.time,
        agents: r
            .agents
            .iter()
            .map(|a| crate::AgentResult {
                driver: a.driver.clone(),
                termination: termination_to_proto(a.termination) as i32,
                lap_times: a.lap_times.clone(),
                collided: a.collided,
                progress: a.progress,
                end_time: a.end_time,
                episode_return: a.episode_return,
            })
            .collect(),
        trajectory: r.trajectory.as_ref().map(|tr| crate::Trajectory {
            decimation: tr.decimation,
            t: pack_f64(&tr.t),
            agents: tr
                .agents
                .iter()
                .map(|a| crate::AgentTrace {
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
pub fn episode_result_from_proto(r: &crate::EpisodeResult) -> Result<EpisodeResult, Error> {
    let mut agents = Vec::with_capacity(r.agents.len());
    for (i, a) in r.agents.iter().enumerate() {
        let termination = match crate::Termination::try_from(a.termination) {
            Ok(crate::Termination::Finished) => Termination::Finished,
            Ok(crate::Termination::Crashed) => Termination::Crashed,
            Ok(crate::Termination::TimeLimit) => Termination::TimeLimit,
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
pub fn outcome_to_proto(r: &Result<EpisodeResult, RolloutError>) -> crate::TaskOutcome {
    crate::TaskOutcome {
        outcome: Some(match r {
            Ok(e) => crate::task_outcome::Outcome::Episode(episode_result_to_proto(e)),
            Err(e) => crate::task_outcome::Outcome::Error(rollout_error_to_proto(e)),
        }),
    }
}

/// The domain outcome of one wire outcome; a missing or undecodable outcome is an error
/// outcome naming the problem.
pub fn outcome_from_proto(o: &crate::TaskOutcome) -> Result<EpisodeResult, RolloutError> {
    match &o.outcome {
        Some(crate::task_outcome::Outcome::Episode(e)) => {
            episode_result_from_proto(e).map_err(|e| rollout_error_from_proto(&e))
        }
        Some(crate::task_outcome::Outcome::Error(e)) => Err(rollout_error_from_proto(e)),
        None => Err(rollout_error_from_proto(&error(
            ErrorCode::BadMessage,
            "outcome",
            "a task outcome carries neither an episode nor an error",
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use paddock_rollout::run_episode;

    fn scenario() -> Scenario {
        let mut s = Scenario::single("pure-pursuit").unwrap();
        s.time_limit = 3.0;
        s.agents
            .push(AgentSpec::with_defaults("follow-the-gap").unwrap());
        s.agents[1].vehicle.m = 3.0 + 0.1 + 0.2; // not exactly representable
        s.agents[1].params[0] *= 1.0 + f64::EPSILON;
        s.lidar.num_beams = 270;
        s.obstacles.count = 2;
        s.collision_mode = CollisionMode::Stop;
        s
    }

    fn map_dir() -> std::path::PathBuf {
        paddock_sim::track::Circuit::resolve("lakeside", &[])
            .unwrap()
            .dir
            .clone()
    }

    #[test]
    fn shipped_bundles_are_the_project_map_folders() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../maps");
        let bundles = shipped_bundles();
        assert!(bundles.len() >= 3);
        for b in &bundles {
            crate::check_bundle(b).unwrap();
            let folder = crate::read_map_dir(&root.join(&b.name), &b.name).unwrap();
            assert_eq!(b.files, folder.files, "{}", b.name);
            assert_eq!(b.hash, folder.hash, "{}", b.name);
            // and a name resolves to the same bundle
            assert_eq!(local_map(&b.name).unwrap().hash, b.hash);
        }
    }

    #[test]
    fn scenario_round_trips_bit_for_bit() {
        let s = scenario();
        let bundle = local_map(&s.map).unwrap();
        assert_eq!(bundle.name, "lakeside");
        crate::check_bundle(&bundle).unwrap();
        let wire = scenario_to_proto(&s, map_ref(&bundle));
        // through bytes, as on the socket
        let bytes = prost::Message::encode_to_vec(&wire);
        let wire: crate::Scenario = prost::Message::decode(bytes.as_slice()).unwrap();
        let back = scenario_from_proto(&wire, &map_dir()).unwrap();
        let mut expected = s.clone();
        expected.map = map_dir().display().to_string();
        assert_eq!(back, expected);
        let mut poses = s.clone();
        poses.agents.truncate(1);
        poses.starts = StartSpec::Poses(vec![Pose {
            x: 0.1,
            y: -2.5,
            theta: 1.0 / 3.0,
        }]);
        let back =
            scenario_from_proto(&scenario_to_proto(&poses, map_ref(&bundle)), &map_dir()).unwrap();
        assert_eq!(back.starts, poses.starts);
    }

    #[test]
    fn bad_values_are_named() {
        let s = scenario();
        let bundle = local_map(&s.map).unwrap();
        let good = scenario_to_proto(&s, map_ref(&bundle));
        let dir = map_dir();
        let check = |mutate: &dyn Fn(&mut crate::Scenario), field: &str| {
            let mut w = good.clone();
            mutate(&mut w);
            let e = scenario_from_proto(&w, &dir).unwrap_err();
            assert_eq!(e.code, ErrorCode::InvalidArgument as i32, "{e:?}");
            assert_eq!(e.field, field, "{e:?}");
            assert!(!e.message.is_empty());
        };
        check(&|w| w.agents[1].params[2] = f64::NAN, "agents[1].params[2]");
        check(&|w| w.agents[0].params[0] = 1e9, "agents[0].params[0]");
        check(
            &|w| w.agents[0].params.pop().map(|_| ()).unwrap(),
            "agents[0].params",
        );
        check(
            &|w| w.agents[1].driver = "nobody".into(),
            "agents[1].driver",
        );
        check(&|w| w.time_limit = f64::NAN, "time_limit");
        check(&|w| w.laps = 0, "laps");
        check(&|w| w.crash_penalty = -1.0, "crash_penalty");
        check(&|w| w.start_kind = 17, "start_kind");
        check(&|w| w.collision_mode = -3, "collision_mode");
        check(
            &|w| w.lidar.as_mut().unwrap().num_beams = 0,
            "lidar.num_beams",
        );
        check(
            &|w| w.lidar.as_mut().unwrap().fov = f64::INFINITY,
            "lidar.fov",
        );
        check(
            &|w| w.obstacles.as_mut().unwrap().count = 5000,
            "obstacles.count",
        );
        check(&|w| w.agents.clear(), "agents");
        check(
            &|w| w.agents[0].vehicle_yaml = "m: .nan\n".into(),
            "agents[0].vehicle_yaml.m",
        );
        check(
            &|w| w.agents[0].vehicle_yaml = "m: [1, 2\n".into(),
            "agents[0].vehicle_yaml",
        );
        check(
            &|w| {
                w.start_kind = crate::StartKind::StartPoses as i32;
                w.start_poses = vec![crate::Pose {
                    x: f64::NAN,
                    y: 0.0,
                    theta: 0.0,
                }];
            },
            "start_poses[0].x",
        );
        let assign = crate::TaskAssign {
            task_id: 1,
            scenario: Some({
                let mut w = good.clone();
                w.laps = 0;
                w
            }),
            seed: 3,
            record_decimation: 0,
        };
        let e = task_from_assign(&assign, &dir).unwrap_err();
        assert_eq!(e.field, "task_assign.scenario.laps");
        let e = with_prefix(invalid("agents[1].params[2]", "x"), "scenarios[0]");
        assert_eq!(e.field, "scenarios[0].agents[1].params[2]");
    }

    #[test]
    fn results_round_trip_bit_for_bit() {
        let mut s = scenario();
        s.agents.truncate(1);
        s.time_limit = 1.5;
        let local = run_episode(&s, 7, Some(5)).unwrap();
        assert!(local.trajectory.as_ref().unwrap().t.len() > 10);
        let wire = outcome_to_proto(&Ok(local.clone()));
        let bytes = prost::Message::encode_to_vec(&wire);
        let wire: crate::TaskOutcome = prost::Message::decode(bytes.as_slice()).unwrap();
        assert_eq!(outcome_from_proto(&wire).unwrap(), local);

        // the same episode run from the wire scenario (map from its directory) is equal
        let bundle = local_map(&s.map).unwrap();
        let assign = crate::TaskAssign {
            task_id: 9,
            scenario: Some(scenario_to_proto(&s, map_ref(&bundle))),
            seed: 7,
            record_decimation: record_to_proto(Some(5)),
        };
        let task = task_from_assign(&assign, &map_dir()).unwrap();
        let remote = run_episode(&task.scenario, task.seed, task.record).unwrap();
        assert_eq!(remote, local);

        // errors travel with their field
        let err = run_episode(
            &Scenario {
                laps: 0,
                ..s.clone()
            },
            1,
            None,
        )
        .unwrap_err();
        let back = outcome_from_proto(&outcome_to_proto(&Err(err))).unwrap_err();
        assert!(back.to_string().contains("laps"), "{back}");

        // ragged trajectories are refused
        let mut bad = episode_result_to_proto(&local);
        bad.trajectory.as_mut().unwrap().agents[0].x.pop();
        let e = episode_result_from_proto(&bad).unwrap_err();
        assert_eq!(e.field, "trajectory.agents[0].x");
        let mut bad = episode_result_to_proto(&local);
        bad.trajectory.as_mut().unwrap().agents[0].y.truncate(8);
        assert_eq!(
            episode_result_from_proto(&bad).unwrap_err().field,
            "trajectory.agents[0].y"
        );
        let mut bad = episode_result_to_proto(&local);
        bad.agents[0].termination = 99;
        assert_eq!(
            episode_result_from_proto(&bad).unwrap_err().field,
            "agents[0].termination"
        );
    }

    #[test]
    fn batches_share_scenarios() {
        let s = Arc::new(scenario());
        let other = Arc::new(Scenario {
            laps: 2,
            ..scenario()
        });
        let tasks: Vec<EpisodeTask> = (0..5)
            .map(|i| EpisodeTask {
                scenario: if i == 3 { other.clone() } else { s.clone() },
                seed: i,
                record: (i == 1).then_some(0),
            })
            .collect();
        let mut asked = 0;
        let batch = batch_to_proto(
            &tasks,
            |m| {
                asked += 1;
                crate::MapRef {
                    name: m.into(),
                    hash: "h".into(),
                }
            },
            true,
        );
        assert_eq!(asked, 2);
        assert_eq!(batch.scenarios.len(), 2);
        let idx: Vec<u32> = batch.tasks.iter().map(|t| t.scenario).collect();
        assert_eq!(idx, [0, 0, 0, 1, 0]);
        assert_eq!(batch.tasks[1].record_decimation, 1);
        assert_eq!(batch.tasks[2].record_decimation, 0);
        assert!(local_map("no-such-map-anywhere").is_err());
    }
}
