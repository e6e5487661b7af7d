//! Rollout tasks: the scenarios a worker has seen, and running episodes.
//!
//! A task names its scenario by hash. The worker keeps the scenarios it has seen,
//! decoded and checked ([`Scenarios`], bounded); what a new one waits for is in
//! `fetch.rs`.
//!
//! Episodes run on a rayon pool ([`Runner`]); finished results come back to the socket
//! thread through an in-process PUSH/PULL pair as ready-made frames (the `TaskResult`
//! header and the encoded outcome), so the loop polls one set of sockets and a result
//! leaves the moment it is ready.

use std::collections::{HashMap, VecDeque};
use std::panic::AssertUnwindSafe;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};

use paddock_proto::{Body, ErrorCode, TaskAssign, TaskOutcome, TaskResult, error};
use paddock_rollout::Scenario;
use paddock_sim::circuit::Circuits;
use paddock_sim::params::VehicleParams;
use prost::Message;

use crate::WorkerStats;

/// Most decoded scenarios kept; the oldest go first (they are fetched again if needed).
pub const MAX_SCENARIOS: usize = 1024;

/// Decoded, checked scenarios by hash (bounded, oldest dropped first).
#[derive(Debug, Default)]
pub struct Scenarios {
    by_hash: HashMap<String, Arc<Scenario>>,
    order: VecDeque<String>,
}

impl Scenarios {
    pub fn get(&self, hash: &str) -> Option<Arc<Scenario>> {
        self.by_hash.get(hash).cloned()
    }

    pub fn insert(&mut self, hash: String, scenario: Arc<Scenario>) {
        if self.by_hash.insert(hash.clone(), scenario).is_none() {
            self.order.push_back(hash);
        }
        while self.order.len() > MAX_SCENARIOS {
            if let Some(old) = self.order.pop_front() {
                self.by_hash.remove(&old);
            }
        }
    }

    pub fn len(&self) -> usize {
        self.by_hash.len()
    }

    pub fn is_empty(&self) -> bool {
        self.by_hash.is_empty()
    }
}

/// The pool episodes run on and the channel their results come back on.
pub struct Runner {
    pool: rayon::ThreadPool,
    results_tx: Arc<Mutex<zmq::Socket>>,
    /// The worker's circuit registry: each map is loaded once and later episodes on it
    /// share its distance field and driving line instead of rebuilding them.
    circuits: Circuits,
    stats: Arc<WorkerStats>,
    /// Replaces the default vehicle of every car (see `WorkerConfig::vehicle`).
    vehicle: Option<Arc<VehicleParams>>,
}

impl Runner {
    pub fn new(
        pool: rayon::ThreadPool,
        results_tx: zmq::Socket,
        stats: Arc<WorkerStats>,
        vehicle: &VehicleParams,
        circuits: Circuits,
    ) -> Self {
        Self {
            pool,
            results_tx: Arc::new(Mutex::new(results_tx)),
            circuits,
            stats,
            vehicle: (*vehicle != VehicleParams::default()).then(|| Arc::new(vehicle.clone())),
        }
    }

    /// Runs task `t` (answering request `request_id`) of `scenario` on the pool.
    pub fn spawn(&self, request_id: u64, t: &TaskAssign, scenario: Arc<Scenario>) {
        let tx = self.results_tx.clone();
        let circuits = self.circuits.clone();
        let stats = self.stats.clone();
        let vehicle = self.vehicle.clone();
        let mut task = paddock_wire::task_from_assign(t, scenario);
        let task_id = t.task_id;
        self.pool.spawn(move || {
            let outcome = std::panic::catch_unwind(AssertUnwindSafe(|| {
                if let Some(v) = &vehicle {
                    default_vehicle(&mut task.scenario, v);
                }
                paddock_rollout::run_episode(&circuits, &task.scenario, task.seed, task.record)
            }));
            let bytes = match outcome {
                Ok(result) => {
                    if result.is_err() {
                        stats.task_errors.fetch_add(1, Ordering::Relaxed);
                    }
                    paddock_wire::outcome_to_bytes(&result)
                }
                Err(panic) => {
                    stats.task_errors.fetch_add(1, Ordering::Relaxed);
                    let what = crate::panic_message(panic.as_ref());
                    error_outcome(error(
                        ErrorCode::Internal,
                        "",
                        format!("task {task_id} panicked: {what}"),
                    ))
                }
            };
            stats.tasks_done.fetch_add(1, Ordering::Relaxed);
            push_result(&tx, request_id, task_id, bytes);
        });
    }

    /// Answers a task that cannot run with an error outcome.
    pub fn fail(&self, request_id: u64, task_id: u64, e: paddock_proto::Error) {
        self.stats.task_errors.fetch_add(1, Ordering::Relaxed);
        push_result(&self.results_tx, request_id, task_id, error_outcome(e));
    }
}

fn error_outcome(e: paddock_proto::Error) -> Vec<u8> {
    TaskOutcome {
        outcome: Some(paddock_proto::task_outcome::Outcome::Error(e)),
    }
    .encode_to_vec()
}

/// Gives `vehicle` to every car of `scenario` that has the default vehicle.
fn default_vehicle(scenario: &mut Arc<Scenario>, vehicle: &VehicleParams) {
    let stock = VehicleParams::default();
    if scenario.agents.iter().any(|a| a.vehicle == stock) {
        for a in &mut Arc::make_mut(scenario).agents {
            if a.vehicle == stock {
                a.vehicle = vehicle.clone();
            }
        }
    }
}

/// Hands a finished task's frames to the socket thread: `[task id, header, outcome]`.
fn push_result(tx: &Mutex<zmq::Socket>, request_id: u64, task_id: u64, outcome: Vec<u8>) {
    let header = paddock_proto::encode(request_id, Body::TaskResult(TaskResult { task_id }));
    let sock = tx.lock().unwrap_or_else(|e| e.into_inner());
    let parts = [task_id.to_le_bytes().to_vec(), header, outcome];
    if let Err(e) = sock.send_multipart(parts, 0) {
        tracing::error!(task_id, error = %e, "could not hand a result to the socket thread");
    }
}

/// A scenario's bytes decoded; the error names the field under `task_assign.scenario`.
pub fn decode_scenario(bytes: &[u8]) -> Result<paddock_proto::Scenario, paddock_proto::Error> {
    paddock_proto::Scenario::decode(bytes).map_err(|e| {
        error(
            ErrorCode::BadMessage,
            "task_assign.scenario",
            format!("the scenario's {} bytes do not decode: {e}", bytes.len()),
        )
    })
}
