//! What a task or an env open needs before it runs, fetched from the broker by content
//! hash: a task's scenario, the ONNX models its cars drive with, its map; an env open's
//! opponents' models and its map.
//!
//! Everything is asked for once per hash, however many tasks wait for it ([`Fetches`]).
//! A task first waits for its scenario's bytes; then it (and an env open from the start)
//! is *advanced*: the first model it names that this process has not registered is
//! fetched and it waits for that; then its map, the same way; then it runs. A model
//! arrives as a `Blob` with the bytes the client stored (`PutBlob`); it is checked against
//! its hash and the observation contract and registered with the process once
//! ([`paddock_wire::register_model`]). A fetch that fails answers everything waiting for
//! it with an error naming the field that named the hash.

use std::collections::HashMap;
use std::sync::Arc;
use std::sync::atomic::Ordering;

use paddock_proto::{Body, EnvOp, EnvOpen, EnvRequest, ErrorCode, TaskAssign, error};
use paddock_wire::with_prefix;
use prost::Message;

use crate::maps::is_hash;
use crate::serve::Worker;
use crate::tasks::decode_scenario;

/// What is fetched from the broker by hash.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Kind {
    /// An encoded scenario (`BlobRequest`).
    Scenario,
    /// A map bundle (`MapRequest`).
    Map,
    /// An ONNX model file (`BlobRequest`).
    Model,
}

/// A task or an env open waiting for a map or a model.
#[derive(Debug)]
pub enum Waiter {
    /// A task and its scenario (wire form).
    Task {
        request_id: u64,
        task: TaskAssign,
        scenario: Box<paddock_proto::Scenario>,
    },
    /// An env open (its request id, session id and payload).
    Open {
        request_id: u64,
        session_id: u64,
        payload: Vec<u8>,
    },
}

/// What waits for which fetch from the broker; every hash is asked for once.
#[derive(Debug, Default)]
pub struct Fetches {
    /// Fetch requests in flight: request id -> what and its hash.
    requests: HashMap<u64, (Kind, String)>,
    /// Tasks waiting for their scenario, by scenario hash (with their request ids).
    scenario_waiters: HashMap<String, Vec<(u64, TaskAssign)>>,
    /// Tasks and opens waiting for a map or a model, by what and its hash (lower case).
    waiters: HashMap<(Kind, String), Vec<Waiter>>,
}

impl Fetches {
    /// Whether a fetch of `hash` is in flight.
    fn asked(&self, kind: Kind, hash: &str) -> bool {
        self.requests.values().any(|(k, h)| *k == kind && h == hash)
    }

    /// Forgets everything (a new connection: the broker requeued the tasks and
    /// answered or replayed the opens).
    pub fn clear(&mut self) {
        *self = Self::default();
    }
}

/// The wire field of a waiter's map hash.
fn map_field(w: &Waiter) -> &'static str {
    match w {
        Waiter::Task { .. } => "task_assign.scenario.map.hash",
        Waiter::Open { .. } => "env_open.map.hash",
    }
}

/// The wire field of the first car of a waiter that drives with the model `hash`.
fn model_field(w: &Waiter, hash: &str) -> String {
    match w {
        Waiter::Task { scenario, .. } => {
            paddock_wire::model_field(&scenario.agents, hash, "task_assign.scenario.agents")
        }
        Waiter::Open { payload, .. } => {
            let opponents = EnvOpen::decode(payload.as_slice())
                .map(|o| o.opponents)
                .unwrap_or_default();
            paddock_wire::model_field(&opponents, hash, "env_open.opponents")
        }
    }
}

impl Worker {
    /// Asks the broker for `hash` unless a request for it is in flight.
    fn fetch(&mut self, sock: &zmq::Socket, kind: Kind, hash: String) {
        if self.fetches.asked(kind, &hash) {
            return;
        }
        let id = self.request_id();
        self.fetches.requests.insert(id, (kind, hash.clone()));
        let body = match kind {
            Kind::Map => {
                self.stats.maps_requested.fetch_add(1, Ordering::Relaxed);
                Body::MapRequest(paddock_proto::MapRequest { hash })
            }
            Kind::Scenario | Kind::Model => Body::BlobRequest(paddock_proto::BlobRequest { hash }),
        };
        self.send(sock, id, body);
    }

    pub(crate) fn on_task(&mut self, sock: &zmq::Socket, request_id: u64, t: TaskAssign) {
        self.stats.tasks_received.fetch_add(1, Ordering::Relaxed);
        self.in_flight.insert(t.task_id);
        let hash = t.scenario_hash.clone();
        if !is_hash(&hash) {
            let e = error(
                ErrorCode::InvalidArgument,
                "task_assign.scenario_hash",
                format!("{hash:?} is not a hex SHA-256 scenario hash"),
            );
            return self.runner.fail(request_id, t.task_id, e);
        }
        if let Some(scenario) = self.scenarios.get(&hash) {
            return self.runner.spawn(request_id, &t, scenario);
        }
        self.fetches
            .scenario_waiters
            .entry(hash.clone())
            .or_default()
            .push((request_id, t));
        self.fetch(sock, Kind::Scenario, hash);
    }

    /// An env open: it runs once its opponents' models and its map are here.
    pub(crate) fn on_open(
        &mut self,
        sock: &zmq::Socket,
        request_id: u64,
        session_id: u64,
        payload: Vec<u8>,
    ) {
        self.advance(
            sock,
            Waiter::Open {
                request_id,
                session_id,
                payload,
            },
        );
    }

    /// Runs a waiter whose models and map are all here, or fetches the first missing one
    /// and parks it there.
    fn advance(&mut self, sock: &zmq::Socket, w: Waiter) {
        let (model, map) = match &w {
            Waiter::Task { scenario, .. } => {
                let model = paddock_wire::unregistered_models(&scenario.agents)
                    .into_iter()
                    .next();
                let map = scenario
                    .map
                    .as_ref()
                    .map(|m| m.hash.to_ascii_lowercase())
                    .filter(|m| is_hash(m) && self.cache.get(m).is_none());
                (model, map)
            }
            Waiter::Open { payload, .. } => {
                let model = EnvOpen::decode(payload.as_slice()).ok().and_then(|o| {
                    paddock_wire::unregistered_models(&o.opponents)
                        .into_iter()
                        .next()
                });
                (model, self.sessions.missing_map(payload))
            }
        };
        let need = model
            .map(|h| (Kind::Model, h))
            .or_else(|| map.map(|h| (Kind::Map, h)));
        if let Some((kind, hash)) = need {
            self.fetches
                .waiters
                .entry((kind, hash.clone()))
                .or_default()
                .push(w);
            return self.fetch(sock, kind, hash);
        }
        match w {
            Waiter::Task {
                request_id,
                task,
                scenario,
            } => self.start(request_id, task, &scenario),
            Waiter::Open {
                request_id,
                session_id,
                payload,
            } => {
                let r = EnvRequest {
                    session_id,
                    op: EnvOp::EnvOpen as i32,
                };
                self.on_env(sock, request_id, &r, &payload);
            }
        }
    }

    /// Bytes from the broker: a scenario (the tasks waiting for it advance) or a model
    /// (registered, then what waits for it advances).
    pub(crate) fn on_blob(
        &mut self,
        sock: &zmq::Socket,
        request_id: u64,
        blob: paddock_proto::Blob,
    ) {
        let Some((kind, hash)) = self.fetches.requests.remove(&request_id) else {
            return;
        };
        if kind == Kind::Model {
            let waiting = self
                .fetches
                .waiters
                .remove(&(Kind::Model, hash.clone()))
                .unwrap_or_default();
            if waiting.is_empty() {
                return;
            }
            match paddock_wire::register_model(&hash, &blob.data) {
                Ok(()) => {
                    tracing::info!(model = %hash, bytes = blob.data.len(), "registered a model from the broker");
                    for w in waiting {
                        self.advance(sock, w);
                    }
                }
                Err(refused) => {
                    tracing::warn!(model = %hash, error = %refused.cause, "refused a model");
                    self.stats.bad_messages.fetch_add(1, Ordering::Relaxed);
                    self.fail_waiters(sock, waiting, refused.code, |w| {
                        let e = refused.to_error(&model_field(w, &hash));
                        (e.field, e.message)
                    });
                }
            }
            return;
        }
        let waiting = self
            .fetches
            .scenario_waiters
            .remove(&hash)
            .unwrap_or_default();
        if waiting.is_empty() {
            return;
        }
        if paddock_proto::blob_hash(&blob.data) != hash {
            self.stats.bad_messages.fetch_add(1, Ordering::Relaxed);
            let e = error(
                ErrorCode::Internal,
                "task_assign.scenario_hash",
                format!("the broker's bytes for scenario {hash} do not have that hash"),
            );
            for (rid, t) in waiting {
                self.runner.fail(rid, t.task_id, e.clone());
            }
            return;
        }
        match decode_scenario(&blob.data) {
            Ok(wire) => {
                for (rid, t) in waiting {
                    let w = Waiter::Task {
                        request_id: rid,
                        task: t,
                        scenario: Box::new(wire.clone()),
                    };
                    self.advance(sock, w);
                }
            }
            Err(e) => {
                for (rid, t) in waiting {
                    self.runner.fail(rid, t.task_id, e.clone());
                }
            }
        }
    }

    /// Runs a task whose scenario (wire form) names a map this worker holds and models
    /// it has registered, or answers it with the error that names the bad field.
    fn start(&mut self, request_id: u64, t: TaskAssign, wire: &paddock_proto::Scenario) {
        if let Some(s) = self.scenarios.get(&t.scenario_hash) {
            return self.runner.spawn(request_id, &t, s);
        }
        let dir = match wire.map.as_ref().map(|m| m.hash.to_ascii_lowercase()) {
            Some(h) if is_hash(&h) => self.cache.get(&h),
            _ => None,
        };
        let Some(dir) = dir else {
            let e = error(
                ErrorCode::InvalidArgument,
                "task_assign.scenario.map.hash",
                "the scenario names no map by a hex SHA-256 hash this worker could fetch",
            );
            return self.runner.fail(request_id, t.task_id, e);
        };
        match paddock_wire::scenario_from_proto(wire, &dir) {
            Ok(s) => {
                let s = Arc::new(s);
                self.scenarios.insert(t.scenario_hash.clone(), s.clone());
                self.runner.spawn(request_id, &t, s);
            }
            Err(e) => self.runner.fail(
                request_id,
                t.task_id,
                with_prefix(e, "task_assign.scenario"),
            ),
        }
    }

    pub(crate) fn on_map(
        &mut self,
        sock: &zmq::Socket,
        request_id: u64,
        bundle: paddock_proto::MapBundle,
    ) {
        self.fetches.requests.remove(&request_id);
        let lower = bundle.hash.to_ascii_lowercase();
        let waiting = self
            .fetches
            .waiters
            .remove(&(Kind::Map, lower.clone()))
            .unwrap_or_default();
        match self.cache.store(&bundle) {
            Ok(_) => {
                for w in waiting {
                    self.advance(sock, w);
                }
            }
            Err(e) => {
                tracing::warn!(hash = %lower, error = %e.message, "refused a map bundle");
                self.stats.bad_messages.fetch_add(1, Ordering::Relaxed);
                let why = format!("its bundle was refused: {} ({})", e.message, e.field);
                let code = ErrorCode::try_from(e.code).unwrap_or(ErrorCode::NotFound);
                self.fail_map_waiters(sock, &lower, waiting, code, &why);
            }
        }
    }

    /// Answers everything that waited for the map `hash`, which could not be had, with an
    /// error naming the hash and why (keeping the code of the failure it reports).
    fn fail_map_waiters(
        &mut self,
        sock: &zmq::Socket,
        hash: &str,
        waiting: Vec<Waiter>,
        code: ErrorCode,
        why: &str,
    ) {
        self.fail_waiters(sock, waiting, code, |w| {
            let field = map_field(w);
            let message = match w {
                Waiter::Task { .. } => format!(
                    "map {hash}: the map is not on this worker and fetching it from the broker failed: {why}"
                ),
                Waiter::Open { .. } => format!(
                    "{field} = {hash}: the map is not on this worker and fetching it from the broker failed: {why}"
                ),
            };
            (field.to_string(), message)
        });
    }

    /// Answers each waiter with an error; `what` gives its field and message.
    fn fail_waiters(
        &mut self,
        sock: &zmq::Socket,
        waiting: Vec<Waiter>,
        code: ErrorCode,
        what: impl Fn(&Waiter) -> (String, String),
    ) {
        for w in waiting {
            let (field, message) = what(&w);
            let e = error(code, field, message);
            match w {
                Waiter::Task {
                    request_id, task, ..
                } => self.runner.fail(request_id, task.task_id, e),
                Waiter::Open {
                    request_id,
                    session_id,
                    ..
                } => {
                    let r = EnvRequest {
                        session_id,
                        op: EnvOp::EnvOpen as i32,
                    };
                    self.reply_env(sock, request_id, &r, Err(e));
                }
            }
        }
    }

    /// The broker's error answer to a fetch (true), or false when `request_id` is not one.
    pub(crate) fn on_fetch_error(
        &mut self,
        sock: &zmq::Socket,
        request_id: u64,
        e: &paddock_proto::Error,
    ) -> bool {
        let Some((kind, hash)) = self.fetches.requests.remove(&request_id) else {
            return false;
        };
        let why = format!("the broker answered: {} ({})", e.message, e.field);
        let code = ErrorCode::try_from(e.code).unwrap_or(ErrorCode::NotFound);
        match kind {
            Kind::Map => {
                let waiting = self
                    .fetches
                    .waiters
                    .remove(&(Kind::Map, hash.clone()))
                    .unwrap_or_default();
                self.fail_map_waiters(sock, &hash, waiting, code, &why);
            }
            Kind::Model => {
                let waiting = self
                    .fetches
                    .waiters
                    .remove(&(Kind::Model, hash.clone()))
                    .unwrap_or_default();
                self.fail_waiters(sock, waiting, code, |w| {
                    let field = model_field(w, &hash);
                    let message = format!(
                        "{field} = onnx:{hash}: the model is not on this worker and fetching it from the broker failed: {why} (a client stores a model with put_blob before naming it)"
                    );
                    (field, message)
                });
            }
            Kind::Scenario => {
                for (rid, t) in self
                    .fetches
                    .scenario_waiters
                    .remove(&hash)
                    .unwrap_or_default()
                {
                    let e = error(
                        code,
                        "task_assign.scenario_hash",
                        format!("scenario {hash}: fetching it from the broker failed: {why}"),
                    );
                    self.runner.fail(rid, t.task_id, e);
                }
            }
        }
        true
    }
}
