//! Interactive env sessions hosted by this worker.
//!
//! The worker's message loop hands every env request (`EnvRequest{session_id, op}` and
//! its payload frame) to [`Sessions::handle`] and sends back the [`EnvReply`] header and
//! payload frames it returns, under the same request id. A session is one [`VecEnv`] (N
//! copies of one environment) under the id the broker gave it at open; its observations
//! travel as two frames: the small `EnvObservation` message and the scans, written once,
//! by each world right after its step ([`VecEnv::step_packed`]), into the frame that
//! goes on the socket, so a Python learner reads them with `numpy.frombuffer` and nobody
//! copies them on the way.
//!
//! Why it looks like this:
//! - Protobuf stops here: requests become an [`EnvConfig`] and slices through
//!   [`paddock_wire::env`], checked field by field; an error names the field as the
//!   client sent it (`env_step.actions`, with the byte count expected and got) and
//!   leaves the session as it was.
//! - Every reply carries a fingerprint of its payload frames
//!   ([`paddock_proto::fingerprint`]) and says whether its request was a restart point
//!   (a reset of every env with its own seed): the broker keeps both to rebuild the
//!   session on another worker if this one dies, without decoding anything.
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
use std::sync::Arc;

use paddock_proto::{
    EnvOp, EnvOpen, EnvRender, EnvReply, EnvReset, EnvStep, Error, ErrorCode, error,
};
use paddock_rollout::RolloutError;
use paddock_rollout::env::VecEnv;
use paddock_sim::circuit::{Circuit, Circuits};
use paddock_sim::lidar::ScanPath;
use paddock_sim::params::VehicleParams;
use paddock_wire::with_prefix;
use prost::Message;

use crate::maps::{MapCache, is_hash};
use crate::render::Renderers;
use crate::scan_path::{SCAN_PATH_VAR, ScanPathVarError};

/// Most sessions one worker hosts at once; more are answered `BUSY`.
pub const MAX_SESSIONS: usize = 256;

/// The env sessions open on this worker.
#[derive(Debug, Default)]
pub struct Sessions {
    open: HashMap<u64, VecEnv>,
    maps: Option<MapCache>,
    /// The circuits sessions run on: maps of the cache by folder, local maps by name.
    circuits: Circuits,
    /// Map name -> (hash of its local files, circuit), computed once per name.
    local: HashMap<String, (String, Arc<Circuit>)>,
    renderers: Renderers,
    /// Replaces the default vehicle of every car (see `WorkerConfig::vehicle`).
    vehicle: Option<VehicleParams>,
    /// Replies carry no fingerprint (0): nobody rebuilds these sessions elsewhere.
    unfingerprinted: bool,
    /// The scan path of the sessions' worlds (`None`: the widest), or why the setting
    /// was refused (every open is then refused, naming it).
    scan_path: Option<Result<ScanPath, ScanPathVarError>>,
    /// The pool the sessions' copies step on (`None`: the calling thread's rayon pool).
    pool: Option<Arc<rayon::ThreadPool>>,
}

/// Where the map of an open request is: a folder of the map cache, or a local map
/// already loaded.
enum MapAt {
    Cached(PathBuf),
    Local(Arc<Circuit>),
}

/// A reply: its header and payload frames.
#[derive(Debug, Clone, PartialEq)]
pub struct Reply {
    pub header: EnvReply,
    pub frames: Vec<Vec<u8>>,
}

fn invalid(field: impl Into<String>, message: impl Into<String>) -> Error {
    error(ErrorCode::InvalidArgument, field, message)
}

fn decode<M: Message + Default>(payload: &[u8], what: &str) -> Result<M, Error> {
    M::decode(payload).map_err(|e| {
        error(
            ErrorCode::BadMessage,
            what,
            format!("{what}: {} bytes do not decode: {e}", payload.len()),
        )
    })
}

impl Sessions {
    pub fn new() -> Self {
        Self::default()
    }

    /// Step the copies of sessions opened from now on on `pool`'s threads instead of the
    /// calling thread's rayon pool (the in-process library's own pool, made again in a
    /// forked child).
    pub fn set_pool(&mut self, pool: Arc<rayon::ThreadPool>) {
        self.pool = Some(pool);
    }

    /// Look maps up by hash in `cache` (the worker's map cache).
    pub fn set_map_cache(&mut self, cache: MapCache) {
        self.maps = Some(cache);
    }

    /// Load circuits through `circuits` (the worker's registry, shared with its tasks):
    /// local maps are looked up by name in it.
    pub fn set_circuits(&mut self, circuits: Circuits) {
        self.circuits = circuits;
    }

    /// Cars whose request carries the default vehicle get `vehicle` instead.
    pub fn set_default_vehicle(&mut self, vehicle: VehicleParams) {
        self.vehicle = (vehicle != VehicleParams::default()).then_some(vehicle);
    }

    /// Whether replies carry the fingerprint of their payload frames (the default). A
    /// host whose sessions are never rebuilt on another worker (the in-process library,
    /// which has no broker) turns it off and saves a pass over every reply's scans; its
    /// replies' `fingerprint` is then 0.
    pub fn set_fingerprints(&mut self, on: bool) {
        self.unfingerprinted = !on;
    }

    /// The LIDAR code path of the worlds of sessions opened from now on (see
    /// [`crate::scan_path`]): a path, `None` for the widest this CPU supports, or a
    /// refused setting, which every open then answers with an `INVALID_ARGUMENT` error
    /// naming `PADDOCK_SCAN_PATH` (where no program checked the setting before).
    pub fn set_scan_path(&mut self, setting: Result<Option<ScanPath>, ScanPathVarError>) {
        self.scan_path = setting.transpose();
    }

    /// The env of session `id`, when it is open here.
    pub fn env(&self, id: u64) -> Option<&VecEnv> {
        self.open.get(&id)
    }

    /// How many sessions are open.
    pub fn count(&self) -> usize {
        self.open.len()
    }

    /// The reply to the request `op` on session `session_id` with payload `payload`.
    pub fn handle(&mut self, session_id: u64, op: i32, payload: &[u8]) -> Reply {
        self.handle_into(session_id, op, payload, None)
    }

    /// [`Sessions::handle`], with the scans of a step or reset written into `scans` when
    /// it is given and has exactly their size (`VecEnv::packed_scans_len`): the reply's
    /// scans frame is then empty and the caller's buffer holds them, so they are written
    /// once, where the caller reads them. Otherwise the scans come in a frame of their
    /// own, as from `handle`. The fingerprint covers the frames as returned.
    pub fn handle_into(
        &mut self,
        session_id: u64,
        op: i32,
        payload: &[u8],
        scans: Option<&mut [u8]>,
    ) -> Reply {
        let mut restart = false;
        let result =
            match EnvOp::try_from(op) {
                Ok(EnvOp::EnvOpen) => decode(payload, "env_open")
                    .and_then(|o: EnvOpen| self.open(session_id, &o))
                    .map(|opened| vec![opened.encode_to_vec()]),
                Ok(EnvOp::EnvReset) => decode(payload, "env_reset").and_then(|r: EnvReset| {
                    let (frames, all) = self.reset(session_id, &r, scans)?;
                    restart = all;
                    Ok(frames)
                }),
                Ok(EnvOp::EnvStep) => decode(payload, "env_step")
                    .and_then(|s: EnvStep| self.step(session_id, &s, scans)),
                Ok(EnvOp::EnvRender) => decode(payload, "env_render")
                    .and_then(|r: EnvRender| self.render(session_id, &r)),
                Ok(EnvOp::EnvClose) => match self.open.remove(&session_id) {
                    Some(_) => Ok(Vec::new()),
                    None => Err(unknown_session(session_id)),
                },
                _ => Err(invalid(
                    "env_request.op",
                    format!("env_request.op = {op} is not an env request this worker serves"),
                )),
            };
        match result {
            Ok(frames) => {
                let fingerprint = if self.unfingerprinted {
                    0
                } else {
                    let views: Vec<&[u8]> = frames.iter().map(Vec::as_slice).collect();
                    paddock_proto::fingerprint(&views)
                };
                Reply {
                    header: EnvReply {
                        session_id,
                        op,
                        fingerprint,
                        restart,
                        error: None,
                    },
                    frames,
                }
            }
            Err(e) => Reply {
                header: EnvReply {
                    session_id,
                    op,
                    fingerprint: 0,
                    restart: false,
                    error: Some(e),
                },
                frames: Vec::new(),
            },
        }
    }

    fn open(&mut self, id: u64, o: &EnvOpen) -> Result<paddock_proto::EnvOpened, Error> {
        // Only the broker gives session ids, and it opens an id again only to rebuild a
        // session it took for lost: on this worker when it declared this worker dead
        // and then heard from it again. The rebuild replaces the stale copy.
        if self.open.remove(&id).is_some() {
            tracing::info!(
                session = id,
                "the broker opens a session this worker hosts again (a rebuild): replacing it"
            );
        }
        let path = match &self.scan_path {
            None => None,
            Some(Ok(path)) => Some(*path),
            Some(Err(e)) => return Err(invalid(SCAN_PATH_VAR, e.to_string())),
        };
        if self.open.len() >= MAX_SESSIONS {
            return Err(error(
                ErrorCode::Busy,
                "env_open",
                format!(
                    "this worker already hosts {MAX_SESSIONS} env sessions; close one or retry later"
                ),
            ));
        }
        let at = self
            .map_at(o.map.as_ref())
            .map_err(|e| with_prefix(e, "env_open"))?;
        let name = match &at {
            MapAt::Cached(dir) => dir.display().to_string(),
            MapAt::Local(c) => c.name.clone(),
        };
        let config = paddock_wire::env::config_from_proto(o, &name, self.vehicle.as_ref())
            .map_err(|e| with_prefix(e, "env_open"))?;
        let learners = config.learners;
        let circuits = &self.circuits;
        let pool = self.pool.clone();
        let mut env = guarded(|| {
            let circuit = match at {
                MapAt::Cached(dir) => circuits.load(&dir)?,
                MapAt::Local(c) => c,
            };
            VecEnv::with_circuit_in(config, circuit, pool)
        })
        .and_then(|r| r.map_err(|e| paddock_wire::env::env_error(&e, learners)))
        .map_err(|e| with_prefix(e, "env_open"))?;
        if let Some(path) = path {
            env.set_scan_path(path)
                .map_err(|e| invalid(SCAN_PATH_VAR, format!("{SCAN_PATH_VAR}={path}: {e}")))?;
        }
        let opened = paddock_wire::env::opened_to_proto(&env);
        self.open.insert(id, env);
        Ok(opened)
    }

    /// The observation frames after a reset, and whether it was a restart point.
    fn reset(
        &mut self,
        id: u64,
        r: &EnvReset,
        into: Option<&mut [u8]>,
    ) -> Result<(Vec<Vec<u8>>, bool), Error> {
        let env = self.open.get_mut(&id).ok_or_else(|| unknown_session(id))?;
        let reset = paddock_wire::env::reset_from_proto(r)?;
        let all = reset.restarts_all(env.num_envs());
        let len = env.packed_scans_len();
        let result = observed(len, into, move |out| {
            env.reset_packed(&reset.envs, &reset.seeds, reset.poses.as_deref(), out)
        });
        self.finish(id, "env_reset", result).map(|f| (f, all))
    }

    fn step(
        &mut self,
        id: u64,
        s: &EnvStep,
        into: Option<&mut [u8]>,
    ) -> Result<Vec<Vec<u8>>, Error> {
        let env = self.open.get_mut(&id).ok_or_else(|| unknown_session(id))?;
        let (actions, reset) =
            paddock_wire::env::step_from_proto(s, env.num_envs(), env.num_learners())?;
        let len = env.packed_scans_len();
        let result = observed(len, into, move |out| env.step_packed(&actions, &reset, out));
        self.finish(id, "env_step", result)
    }

    fn render(&mut self, id: u64, r: &EnvRender) -> Result<Vec<Vec<u8>>, Error> {
        let env = self.open.get(&id).ok_or_else(|| unknown_session(id))?;
        let renderers = &mut self.renderers;
        std::panic::catch_unwind(AssertUnwindSafe(|| renderers.render(env, r)))
            .unwrap_or_else(|_| {
                Err(error(
                    ErrorCode::Internal,
                    "env_render",
                    "rendering failed (a bug); the session is unchanged",
                ))
            })
            .map(|(image, rgb)| vec![image.encode_to_vec(), rgb])
    }

    /// The reply of a session call; a panicked session is closed.
    fn finish(
        &mut self,
        id: u64,
        prefix: &str,
        result: Result<Result<Vec<Vec<u8>>, RolloutError>, Error>,
    ) -> Result<Vec<Vec<u8>>, Error> {
        let learners = self.open.get(&id).map_or(1, VecEnv::num_learners);
        match result {
            Ok(r) => r.map_err(|e| with_prefix(paddock_wire::env::env_error(&e, learners), prefix)),
            Err(panic) => {
                self.open.remove(&id);
                Err(with_prefix(panic, prefix))
            }
        }
    }

    /// Where the map `m` names by hash is (see the module docs).
    fn map_at(&mut self, m: Option<&paddock_proto::MapRef>) -> Result<MapAt, Error> {
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

    /// The hash (lower case) of the map an open request (its payload) names when it is a
    /// well-formed hash of a map this worker does not hold, so the worker can fetch it
    /// before the open runs; `None` when the map is here or the request is malformed
    /// (the open reports that).
    pub fn missing_map(&mut self, payload: &[u8]) -> Option<String> {
        let o = EnvOpen::decode(payload).ok()?;
        let m = o.map.as_ref().filter(|m| is_hash(&m.hash))?;
        match self.find_map(m) {
            Some(_) => None,
            None => Some(m.hash.to_ascii_lowercase()),
        }
    }

    /// Where a map with a well-formed hash is: the cache's folder, else the local map of
    /// that name when its files have that hash.
    fn find_map(&mut self, m: &paddock_proto::MapRef) -> Option<MapAt> {
        let hash = m.hash.to_ascii_lowercase();
        if let Some(dir) = self.maps.as_ref().and_then(|c| c.get(&hash)) {
            return Some(MapAt::Cached(dir));
        }
        // a client's map name is looked up among the known map folders only, never
        // opened as a path (it could name any file or directory of the host)
        let bare =
            !m.name.is_empty() && !m.name.contains(['/', '\\', '\0']) && !m.name.starts_with('.');
        if bare
            && !self.local.contains_key(&m.name)
            && let Ok(c) = self.circuits.by_name(&m.name)
            && let Ok(b) = paddock_wire::circuit_bundle(&c, &m.name)
        {
            self.local.insert(m.name.clone(), (b.hash, c));
        }
        match self.local.get(&m.name) {
            Some((h, c)) if *h == hash => Some(MapAt::Local(c.clone())),
            _ => None,
        }
    }
}

fn unknown_session(id: u64) -> Error {
    error(
        ErrorCode::NotFound,
        "env_request.session_id",
        format!("env_request.session_id = {id}: no such env session on this worker"),
    )
}

/// Runs `f`, turning a panic into an `INTERNAL` error.
fn guarded<T>(f: impl FnOnce() -> T) -> Result<T, Error> {
    std::panic::catch_unwind(AssertUnwindSafe(f)).map_err(|p| {
        let what = crate::panic_message(p.as_ref());
        error(
            ErrorCode::Internal,
            "",
            format!("the env session failed and was closed: {what}"),
        )
    })
}

/// The observation frames of `call` (a step or reset writing `len` bytes of scans into
/// the buffer it is given), a panic as an `INTERNAL` error: the scans go into the
/// caller's buffer `into` when it has that size (the scans frame then empty), else into
/// a frame of their own.
fn observed<'e>(
    len: usize,
    into: Option<&mut [u8]>,
    call: impl FnOnce(&mut [u8]) -> Result<&'e paddock_rollout::env::EnvFrame, RolloutError>,
) -> Result<Result<Vec<Vec<u8>>, RolloutError>, Error> {
    guarded(|| match into {
        Some(buf) if buf.len() == len => call(buf).map(|f| observation(f, Vec::new())),
        _ => {
            let mut own = vec![0; len];
            let f = call(&mut own)?;
            Ok(observation(f, own))
        }
    })
}

/// The payload frames of an observation whose learners' scans `scans` holds packed
/// (empty when they went into the caller's buffer).
fn observation(f: &paddock_rollout::env::EnvFrame, scans: Vec<u8>) -> Vec<Vec<u8>> {
    vec![
        paddock_wire::env::observation_meta(f).encode_to_vec(),
        scans,
    ]
}

#[cfg(test)]
mod tests;
