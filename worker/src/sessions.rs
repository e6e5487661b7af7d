//! Interactive env sessions hosted by this worker.
//!
//! The worker's message loop hands every `EnvOpen`, `EnvReset`, `EnvStep`, `EnvRender`
//! and `EnvClose` to [`Sessions::handle`] and sends back the body it returns with the same
//! request id. A session is one [`VecEnv`] (N copies of one environment); its replies are
//! [`EnvObservation`]s whose bulk numbers are packed little-endian bytes, so a Python
//! learner reads them with `numpy.frombuffer`.
//!
//! Why it looks like this:
//! - Protobuf stops here: requests become [`EnvConfig`] and slices, checked field by
//!   field; an error names the field as the client sent it (`env_step.actions`, with the
//!   byte count expected and got) and leaves the session as it was.
//! - Maps are named by content hash. The hash is looked up in the worker's map cache
//!   (`set_map_cache`); failing that, the map the name resolves to on this machine is
//!   used when its files have that very hash (a `paddock serve` worker beside the
//!   client), else the request is refused with `NOT_FOUND`. The worker asks
//!   [`Sessions::missing_map`] first and fetches a missing map from the broker before
//!   it hands the open over, as it does for rollout tasks.
//! - A panic inside a session (a bug) must not take the worker down: it becomes an
//!   `INTERNAL` error and that session is closed.

use std::collections::HashMap;
use std::panic::AssertUnwindSafe;
use std::path::PathBuf;

use paddock_proto::convert::with_prefix;
use paddock_proto::{
    Body, EnvClosed, EnvObservation, EnvOpen, EnvOpened, EnvReset, EnvStep, Error, ErrorCode,
    body_name, error, pack_f32, pack_f64, pack_u32, unpack_f64,
};
use paddock_rollout::env::{EnvConfig, EnvFrame, RewardWeights, VecEnv};
use paddock_rollout::{AgentSpec, RolloutError};
use paddock_sim::collision::CollisionMode;
use paddock_sim::geometry::Pose;
use paddock_sim::lidar::LidarConfig;
use paddock_sim::params::VehicleParams;
use paddock_sim::track::Circuit;
use paddock_sim::world::{ObstacleConfig, WorldError};

use crate::maps::{MapCache, is_hash};
use crate::render::Renderers;

/// Most sessions one worker hosts at once; more are answered `BUSY`.
pub const MAX_SESSIONS: usize = 256;

/// The env sessions open on this worker.
#[derive(Debug, Default)]
pub struct Sessions {
    open: HashMap<u64, VecEnv>,
    next_id: u64,
    maps: Option<MapCache>,
    /// Map name -> (hash of its local files, directory), computed once per name.
    local: HashMap<String, (String, PathBuf)>,
    renderers: Renderers,
    /// Replaces the default vehicle of every car (see `WorkerConfig::vehicle`).
    vehicle: Option<VehicleParams>,
}

fn invalid(field: impl Into<String>, message: impl Into<String>) -> Error {
    error(ErrorCode::InvalidArgument, field, message)
}

impl Sessions {
    pub fn new() -> Self {
        Self::default()
    }

    /// Look maps up by hash in `cache` (the worker's map cache).
    pub fn set_map_cache(&mut self, cache: MapCache) {
        self.maps = Some(cache);
    }

    /// Cars whose request carries the default vehicle get `vehicle` instead.
    pub fn set_default_vehicle(&mut self, vehicle: VehicleParams) {
        self.vehicle = (vehicle != VehicleParams::default()).then_some(vehicle);
    }

    /// The vehicle of a request's YAML, or this worker's vehicle for the default one.
    fn vehicle(&self, yaml: &str, prefix: &str) -> Result<VehicleParams, Error> {
        let v = vehicle_from_yaml(yaml, prefix)?;
        match &self.vehicle {
            Some(mine) if v == VehicleParams::default() => Ok(mine.clone()),
            _ => Ok(v),
        }
    }

    /// How many sessions are open.
    pub fn count(&self) -> usize {
        self.open.len()
    }

    /// The reply to one env message (`None`: no reply).
    pub fn handle(&mut self, request_id: u64, body: Body) -> Option<Body> {
        let _ = request_id;
        let name = body_name(&body);
        let reply = match body {
            Body::EnvOpen(o) => self.open(&o).map(Body::EnvOpened),
            Body::EnvReset(r) => self.reset(&r).map(Body::EnvObservation),
            Body::EnvStep(s) => self.step(&s).map(Body::EnvObservation),
            Body::EnvRender(r) => match self.open.get(&r.session_id) {
                Some(env) => {
                    std::panic::catch_unwind(AssertUnwindSafe(|| self.renderers.render(env, &r)))
                        .unwrap_or_else(|_| {
                            Err(error(
                                ErrorCode::Internal,
                                "env_render",
                                "rendering failed (a bug); the session is unchanged",
                            ))
                        })
                        .map(Body::EnvImage)
                }
                None => Err(unknown_session("env_render", r.session_id)),
            },
            Body::EnvClose(c) => match self.open.remove(&c.session_id) {
                Some(_) => Ok(Body::EnvClosed(EnvClosed {
                    session_id: c.session_id,
                })),
                None => Err(unknown_session("env_close", c.session_id)),
            },
            _ => Err(error(
                ErrorCode::UnknownType,
                name,
                format!("{name} is not an env session request"),
            )),
        };
        Some(reply.unwrap_or_else(Body::Error))
    }

    fn open(&mut self, o: &EnvOpen) -> Result<EnvOpened, Error> {
        if self.open.len() >= MAX_SESSIONS {
            return Err(error(
                ErrorCode::Busy,
                "env_open",
                format!(
                    "this worker already hosts {MAX_SESSIONS} env sessions; close one or retry later"
                ),
            ));
        }
        let config = self
            .config_from_proto(o)
            .map_err(|e| with_prefix(e, "env_open"))?;
        let env = guarded(|| VecEnv::new(config))
            .and_then(|r| r.map_err(|e| rollout_error(&e)))
            .map_err(|e| with_prefix(e, "env_open"))?;
        self.next_id += 1;
        let id = self.next_id;
        let (low, high) = env.action_bounds();
        let opened = EnvOpened {
            session_id: id,
            num_envs: u32_of(env.num_envs()),
            num_beams: u32_of(env.num_beams()),
            num_agents: u32_of(env.num_agents()),
            action_low: low.to_vec(),
            action_high: high.to_vec(),
            dt: env.dt(),
        };
        self.open.insert(id, env);
        Ok(opened)
    }

    fn reset(&mut self, r: &EnvReset) -> Result<EnvObservation, Error> {
        let id = r.session_id;
        let env = self
            .open
            .get_mut(&id)
            .ok_or_else(|| unknown_session("env_reset", id))?;
        let envs: Vec<usize> = r.envs.iter().map(|&i| i as usize).collect();
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
                    .collect::<Vec<_>>(),
            )
        };
        let result = guarded(|| {
            env.reset(&envs, &r.seeds, poses.as_deref())
                .map(|f| observation(id, f))
        });
        self.finish(id, "env_reset", result)
    }

    fn step(&mut self, s: &EnvStep) -> Result<EnvObservation, Error> {
        let id = s.session_id;
        let env = self
            .open
            .get_mut(&id)
            .ok_or_else(|| unknown_session("env_step", id))?;
        let n = env.num_envs();
        if s.actions.len() != n * 8 {
            return Err(invalid(
                "env_step.actions",
                format!(
                    "env_step.actions has {} bytes; expected {n} envs x [steer, speed] as f32 = {} bytes",
                    s.actions.len(),
                    n * 8
                ),
            ));
        }
        let actions: Vec<f32> = s
            .actions
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        let reset: Vec<usize> = s.reset_envs.iter().map(|&i| i as usize).collect();
        let result = guarded(|| env.step(&actions, &reset).map(|f| observation(id, f)));
        self.finish(id, "env_step", result)
    }

    /// The reply of a session call; a panicked session is closed.
    fn finish(
        &mut self,
        id: u64,
        prefix: &str,
        result: Result<Result<EnvObservation, RolloutError>, Error>,
    ) -> Result<EnvObservation, Error> {
        match result {
            Ok(r) => r.map_err(|e| with_prefix(rollout_error(&e), prefix)),
            Err(panic) => {
                self.open.remove(&id);
                Err(with_prefix(panic, prefix))
            }
        }
    }

    fn config_from_proto(&mut self, o: &EnvOpen) -> Result<EnvConfig, Error> {
        let map = self.map_dir(o.map.as_ref())?;
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
                vehicle: self.vehicle(&a.vehicle_yaml, &format!("opponents[{k}]"))?,
            });
        }
        let collision_mode = match paddock_proto::CollisionMode::try_from(o.collision_mode) {
            Ok(paddock_proto::CollisionMode::CollisionTerminate) => CollisionMode::Terminate,
            Ok(paddock_proto::CollisionMode::CollisionStop) => CollisionMode::Stop,
            Ok(paddock_proto::CollisionMode::CollisionIgnore) => CollisionMode::Ignore,
            Err(_) => {
                return Err(invalid(
                    "collision_mode",
                    format!(
                        "collision_mode = {} is not a known CollisionMode",
                        o.collision_mode
                    ),
                ));
            }
        };
        let lidar = match &o.lidar {
            None => LidarConfig::default(),
            Some(l) => LidarConfig {
                num_beams: l.num_beams as usize,
                fov: l.fov,
                max_range: l.max_range,
                noise_std: l.noise_std,
                mount_offset: l.mount_offset,
            },
        };
        let obstacles = match &o.obstacles {
            None => ObstacleConfig::default(),
            Some(b) => ObstacleConfig {
                count: b.count as usize,
                length: b.length,
                width: b.width,
                passage: b.passage,
                start_clearance: b.start_clearance,
            },
        };
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
            map: map.display().to_string(),
            num_envs: o.num_envs as usize,
            seed: o.seed,
            opponents,
            vehicle: self.vehicle(&o.vehicle_yaml, "")?,
            lidar,
            obstacles,
            laps: o.laps,
            time_limit: o.time_limit,
            collision_mode,
            reward,
            frame_skip: o.frame_skip,
        })
    }

    /// The directory of the map `m` names by hash (see the module docs).
    fn map_dir(&mut self, m: Option<&paddock_proto::MapRef>) -> Result<PathBuf, Error> {
        let Some(m) = m else {
            return Err(invalid("map", "map is missing: name the map by its hash"));
        };
        if !is_hash(&m.hash) {
            return Err(invalid(
                "map.hash",
                format!("map.hash = {:?} is not a hex SHA-256", m.hash),
            ));
        }
        self.find_map(m).ok_or_else(|| {
            error(
                ErrorCode::NotFound,
                "map.hash",
                format!(
                    "map {:?} with hash {} is not on this worker",
                    m.name,
                    m.hash.to_ascii_lowercase()
                ),
            )
        })
    }

    /// The hash (lower case) of the map `o` names when it is a well-formed hash of a map
    /// this worker does not hold, so the worker can fetch it before the open runs;
    /// `None` when the map is here or the request is malformed (the open reports that).
    pub fn missing_map(&mut self, o: &EnvOpen) -> Option<String> {
        let m = o.map.as_ref().filter(|m| is_hash(&m.hash))?;
        match self.find_map(m) {
            Some(_) => None,
            None => Some(m.hash.to_ascii_lowercase()),
        }
    }

    /// The directory of a map with a well-formed hash: the cache's, else the local map
    /// of that name when its files have that hash.
    fn find_map(&mut self, m: &paddock_proto::MapRef) -> Option<PathBuf> {
        let hash = m.hash.to_ascii_lowercase();
        if let Some(dir) = self.maps.as_ref().and_then(|c| c.get(&hash)) {
            return Some(dir);
        }
        // a client's map name is looked up among the known map folders only, never
        // opened as a path (it could name any file or directory of the host)
        let bare =
            !m.name.is_empty() && !m.name.contains(['/', '\\', '\0']) && !m.name.starts_with('.');
        if bare
            && !self.local.contains_key(&m.name)
            && let Ok(c) = Circuit::resolve(&m.name, &[])
            && let Ok(b) = paddock_proto::read_map_dir(&c.dir, &m.name)
        {
            self.local.insert(m.name.clone(), (b.hash, c.dir.clone()));
        }
        match self.local.get(&m.name) {
            Some((h, dir)) if *h == hash => Some(dir.clone()),
            _ => None,
        }
    }
}

fn unknown_session(prefix: &str, id: u64) -> Error {
    error(
        ErrorCode::NotFound,
        format!("{prefix}.session_id"),
        format!("{prefix}.session_id = {id}: no such env session on this worker"),
    )
}

fn u32_of(v: usize) -> u32 {
    u32::try_from(v).unwrap_or(u32::MAX)
}

fn vehicle_from_yaml(yaml: &str, prefix: &str) -> Result<VehicleParams, Error> {
    VehicleParams::from_yaml_str(yaml).map_err(|e| {
        let field = match e.field() {
            Some(f) => format!("vehicle_yaml.{f}"),
            None => "vehicle_yaml".into(),
        };
        with_prefix(invalid(field, e.to_string()), prefix)
    })
}

/// Runs `f`, turning a panic into an `INTERNAL` error.
fn guarded<T>(f: impl FnOnce() -> T) -> Result<T, Error> {
    std::panic::catch_unwind(AssertUnwindSafe(f)).map_err(|p| {
        let what = p
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| p.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown panic".into());
        error(
            ErrorCode::Internal,
            "",
            format!("the env session failed and was closed: {what}"),
        )
    })
}

/// The wire error of a session failure, with the field as the client named it.
fn rollout_error(e: &RolloutError) -> Error {
    match e {
        RolloutError::Invalid { field, .. } => invalid(field.clone(), e.to_string()),
        RolloutError::Map(_) => invalid("map", e.to_string()),
        RolloutError::Driver { agent, .. } => invalid(
            format!("opponents[{}]", agent.saturating_sub(1)),
            e.to_string(),
        ),
        RolloutError::World(WorldError::Config { field, .. }) => {
            invalid(field.clone(), e.to_string())
        }
        RolloutError::World(WorldError::Placement { .. }) => {
            error(ErrorCode::Internal, "", e.to_string())
        }
        RolloutError::World(_) => invalid("", e.to_string()),
    }
}

fn bytes_of(flags: &[bool]) -> Vec<u8> {
    flags.iter().map(|&b| u8::from(b)).collect()
}

fn observation(session_id: u64, f: &EnvFrame) -> EnvObservation {
    EnvObservation {
        session_id,
        num_envs: u32_of(f.num_envs),
        scans: pack_f32(&f.scans),
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

#[cfg(test)]
mod tests {
    use paddock_proto::{Lidar, MapRef, unpack_f32};
    use paddock_rollout::env::STATE_SIZE;

    use super::*;

    fn lakeside() -> MapRef {
        let dir = Circuit::resolve("lakeside", &[]).unwrap().dir.clone();
        let b = paddock_proto::read_map_dir(&dir, "lakeside").unwrap();
        paddock_proto::convert::map_ref(&b)
    }

    fn open_msg(num_envs: u32) -> EnvOpen {
        EnvOpen {
            map: Some(lakeside()),
            num_envs,
            seed: 4,
            lidar: Some(Lidar {
                num_beams: 64,
                fov: 4.7,
                max_range: 30.0,
                noise_std: 0.01,
                mount_offset: 0.0,
            }),
            laps: 1,
            time_limit: 60.0,
            frame_skip: 2,
            ..Default::default()
        }
    }

    fn expect_err(reply: Option<Body>) -> Error {
        match reply {
            Some(Body::Error(e)) => e,
            other => panic!("expected an error, got {other:?}"),
        }
    }

    fn expect_obs(reply: Option<Body>) -> EnvObservation {
        match reply {
            Some(Body::EnvObservation(o)) => o,
            other => panic!("expected an observation, got {other:?}"),
        }
    }

    fn open(s: &mut Sessions, n: u32) -> EnvOpened {
        match s.handle(1, Body::EnvOpen(open_msg(n))) {
            Some(Body::EnvOpened(o)) => o,
            other => panic!("expected opened, got {other:?}"),
        }
    }

    fn actions(n: usize) -> Vec<u8> {
        pack_f32(&(0..n).flat_map(|_| [0.0f32, 2.0]).collect::<Vec<_>>())
    }

    #[test]
    fn open_reset_step_close() {
        let mut s = Sessions::new();
        let o = open(&mut s, 3);
        assert_eq!((o.num_envs, o.num_beams, o.num_agents), (3, 64, 1));
        assert_eq!(o.action_low.len(), 2);
        assert!(o.action_low[0] < 0.0 && o.action_high[1] > 0.0);
        assert_eq!(s.count(), 1);
        let id = o.session_id;
        let r = expect_obs(s.handle(
            2,
            Body::EnvReset(EnvReset {
                session_id: id,
                seeds: vec![1, 2, 3],
                ..Default::default()
            }),
        ));
        assert_eq!(r.scans.len(), 3 * 64 * 4);
        assert_eq!(r.states.len(), 3 * STATE_SIZE * 8);
        assert_eq!(r.terminated, vec![0; 3]);
        assert_eq!(r.agent_lap_counts.len(), 3 * 4);
        let scans = unpack_f32(&r.scans, "scans").unwrap();
        assert!(scans.iter().all(|&x| x > 0.0 && x < 31.0));
        let st = expect_obs(s.handle(
            3,
            Body::EnvStep(EnvStep {
                session_id: id,
                actions: actions(3),
                reset_envs: vec![],
            }),
        ));
        let time = unpack_f64(&st.time, "time").unwrap();
        assert_eq!(time, vec![0.02; 3]);
        // the same through a VecEnv directly: the packed bytes are its frame
        let mut cfg = s.config_from_proto(&open_msg(3)).unwrap();
        cfg.num_envs = 3;
        let mut env = VecEnv::new(cfg).unwrap();
        env.reset(&[], &[1, 2, 3], None).unwrap();
        let f = env.step(&[0.0, 2.0, 0.0, 2.0, 0.0, 2.0], &[]).unwrap();
        assert_eq!(st, observation(id, f));
        match s.handle(
            4,
            Body::EnvClose(paddock_proto::EnvClose { session_id: id }),
        ) {
            Some(Body::EnvClosed(c)) => assert_eq!(c.session_id, id),
            other => panic!("unexpected {other:?}"),
        }
        assert_eq!(s.count(), 0);
        let e = expect_err(s.handle(
            5,
            Body::EnvClose(paddock_proto::EnvClose { session_id: id }),
        ));
        assert_eq!(e.code, ErrorCode::NotFound as i32);
        assert_eq!(e.field, "env_close.session_id");
    }

    #[test]
    fn a_worker_vehicle_replaces_only_the_default_one() {
        let fitted = VehicleParams {
            mu: 0.6,
            ..Default::default()
        };
        let mut s = Sessions::new();
        s.set_default_vehicle(fitted.clone());
        let mut o = open_msg(1);
        o.opponents = vec![paddock_proto::AgentSpec {
            driver: "pure-pursuit".into(),
            ..Default::default()
        }];
        let cfg = s.config_from_proto(&o).unwrap();
        assert_eq!(cfg.vehicle, fitted);
        assert_eq!(cfg.opponents[0].vehicle, fitted);
        // a request that carries its own vehicle keeps it
        let own = VehicleParams {
            m: 4.0,
            ..Default::default()
        };
        o.vehicle_yaml = own.to_yaml_string();
        assert_eq!(s.config_from_proto(&o).unwrap().vehicle, own);
        let plain = Sessions::new().config_from_proto(&open_msg(1)).unwrap();
        assert_eq!(plain.vehicle, VehicleParams::default());
    }

    #[test]
    fn bad_requests_name_the_field() {
        let mut s = Sessions::new();
        let id = open(&mut s, 2).session_id;
        let step = |actions: Vec<u8>| {
            Body::EnvStep(EnvStep {
                session_id: id,
                actions,
                reset_envs: vec![],
            })
        };
        let e = expect_err(s.handle(2, step(vec![0; 12])));
        assert_eq!(e.field, "env_step.actions");
        assert!(
            e.message
                .contains("expected 2 envs x [steer, speed] as f32 = 16 bytes"),
            "{}",
            e.message
        );
        assert!(e.message.contains("12 bytes"), "{}", e.message);
        let e = expect_err(s.handle(3, step(pack_f32(&[0.0, 1.0, f32::NAN, 1.0]))));
        assert_eq!(e.code, ErrorCode::InvalidArgument as i32);
        assert_eq!(e.field, "env_step.actions[2]");
        assert!(e.message.contains("NaN"), "{}", e.message);
        let e = expect_err(s.handle(
            4,
            Body::EnvStep(EnvStep {
                session_id: 99,
                actions: actions(2),
                reset_envs: vec![],
            }),
        ));
        assert_eq!(
            (e.code, e.field.as_str()),
            (ErrorCode::NotFound as i32, "env_step.session_id")
        );
        let e = expect_err(s.handle(
            5,
            Body::EnvReset(EnvReset {
                session_id: id,
                poses: pack_f64(&[1.0, 2.0]),
                ..Default::default()
            }),
        ));
        assert_eq!(e.field, "env_reset.poses");
        let e = expect_err(s.handle(
            6,
            Body::EnvReset(EnvReset {
                session_id: id,
                envs: vec![7],
                ..Default::default()
            }),
        ));
        assert_eq!(e.field, "env_reset.envs[0]");
        // the session survived all of that
        expect_obs(s.handle(7, step(actions(2))));

        let bad_open = |f: fn(&mut EnvOpen)| {
            let mut o = open_msg(1);
            f(&mut o);
            expect_err(Sessions::new().handle(8, Body::EnvOpen(o)))
        };
        let e = bad_open(|o| o.num_envs = 0);
        assert_eq!(e.field, "env_open.num_envs");
        let e = bad_open(|o| o.frame_skip = 0);
        assert_eq!(e.field, "env_open.frame_skip");
        let e = bad_open(|o| o.map = None);
        assert_eq!(e.field, "env_open.map");
        let e = bad_open(|o| o.map.as_mut().unwrap().hash = "ab".repeat(32));
        assert_eq!(
            (e.code, e.field.as_str()),
            (ErrorCode::NotFound as i32, "env_open.map.hash")
        );
        let e = bad_open(|o| {
            o.opponents = vec![paddock_proto::AgentSpec {
                driver: "nobody".into(),
                ..Default::default()
            }]
        });
        assert_eq!(e.field, "env_open.opponents[0].driver");
        assert!(e.message.contains("nobody"), "{}", e.message);
        let mut with_opponent = open_msg(1);
        with_opponent.opponents = vec![paddock_proto::AgentSpec {
            driver: "pure-pursuit".into(),
            ..Default::default()
        }];
        match Sessions::new().handle(8, Body::EnvOpen(with_opponent)) {
            Some(Body::EnvOpened(o)) => assert_eq!(o.num_agents, 2),
            other => panic!("no parameters = the defaults: {other:?}"),
        }
        let e = bad_open(|o| o.vehicle_yaml = "v_max: .nan".into());
        assert!(e.field.starts_with("env_open.vehicle_yaml"), "{}", e.field);
        let e = bad_open(|o| o.lidar.as_mut().unwrap().fov = -1.0);
        assert_eq!(e.field, "env_open.lidar");
        let e = expect_err(s.handle(
            9,
            Body::Heartbeat(paddock_proto::Heartbeat { in_flight: 0 }),
        ));
        assert_eq!(e.code, ErrorCode::UnknownType as i32);
    }

    #[test]
    fn maps_from_the_cache_by_hash() {
        let tmp = std::env::temp_dir().join(format!("paddock-sessions-{}", std::process::id()));
        let cache = MapCache::open(&tmp).unwrap();
        let dir = Circuit::resolve("lakeside", &[]).unwrap().dir.clone();
        let bundle = paddock_proto::read_map_dir(&dir, "custom-name").unwrap();
        cache.store(&bundle).unwrap();
        let mut s = Sessions::new();
        s.set_map_cache(cache);
        let mut o = open_msg(1);
        o.map = Some(paddock_proto::convert::map_ref(&bundle));
        let reply = s.handle(1, Body::EnvOpen(o));
        let _ = std::fs::remove_dir_all(&tmp);
        assert!(matches!(reply, Some(Body::EnvOpened(_))), "{reply:?}");
    }
}
