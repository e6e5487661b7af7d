//! Workers on the backend: hello and bye, their task results and errors, the liveness
//! timers that declare a silent one dead (its tasks requeued, its env sessions stalled
//! for a rebuild), and the broker's status.

use std::time::{Duration, Instant};

use paddock_proto::{Body, BrokerStatus, ErrorCode, WorkerStatus, WorkerWelcome, code_name, error};

use super::{Broker, Side, hex};
use crate::core::WorkerKey;
use crate::office::Command;

impl Broker {
    pub(super) fn on_worker(
        &mut self,
        worker: WorkerKey,
        rid: u64,
        body: Body,
        payload: &mut Vec<zmq::Message>,
    ) {
        let known = self.disp.workers.get(&worker).is_some();
        match body {
            Body::WorkerHello(h) => self.on_hello(worker, rid, &h),
            Body::TaskResult(r) => {
                if let Some(outcome) = payload.pop() {
                    self.on_task_result(&worker, r.task_id, outcome);
                }
                if !known {
                    self.unknown_worker(&worker, rid);
                }
            }
            Body::Heartbeat(_) => {
                if !known {
                    self.unknown_worker(&worker, rid);
                }
            }
            Body::MapRequest(m) => self.tell_office(Command::MapRequest {
                worker,
                rid,
                hash: m.hash,
            }),
            Body::BlobRequest(b) => self.on_blob_request(worker, rid, b.hash),
            Body::Bye(b) => {
                tracing::info!(peer = %hex(&worker), reason = %b.reason, "worker left");
                if let Some(info) = self.disp.workers.remove(&worker) {
                    self.worker_gone(&worker, info.in_flight.into_iter().collect(), "left");
                }
            }
            Body::EnvReply(r) => self.on_env_reply(worker, rid, r, std::mem::take(payload)),
            Body::Error(e) => {
                // a worker's error answers something of ours (a blob or map it could
                // not use): logged, nothing waits for it
                tracing::warn!(
                    peer = %hex(&worker),
                    code = code_name(e.code),
                    field = %e.field,
                    message = %e.message,
                    "worker reported an error"
                );
            }
            other => self.wrong_socket(Side::Worker, &worker, rid, &other),
        }
    }

    pub(super) fn on_hello(&mut self, worker: WorkerKey, rid: u64, h: &paddock_proto::WorkerHello) {
        let now = self.now();
        match self.disp.workers.hello(worker.clone(), h, now) {
            Ok(old) => {
                tracing::info!(
                    worker_id = %h.worker_id,
                    hostname = %h.hostname,
                    capacity = h.capacity,
                    "worker joined"
                );
                if !old.is_empty() {
                    let r = self.disp.requeue(old);
                    self.fail_exhausted(r.exhausted);
                }
                let welcome = WorkerWelcome {
                    heartbeat_ms: self.cfg.liveness.interval.as_millis() as u32,
                    liveness: self.cfg.liveness.liveness,
                };
                self.send(Side::Worker, &worker, rid, Body::WorkerWelcome(welcome));
            }
            Err(e) => {
                let field = match e {
                    crate::core::workers::HelloError::Capacity(_) => "worker_hello.capacity",
                    crate::core::workers::HelloError::EmptyId => "worker_hello.worker_id",
                };
                self.refuse(
                    Side::Worker,
                    &worker,
                    rid,
                    error(ErrorCode::InvalidArgument, field, e.to_string()),
                );
            }
        }
    }

    pub(super) fn unknown_worker(&mut self, worker: &[u8], rid: u64) {
        self.refuse(
            Side::Worker,
            worker,
            rid,
            error(
                ErrorCode::NotFound,
                "worker_id",
                "this broker does not know this worker (declared dead, or the broker restarted): send worker_hello again",
            ),
        );
    }

    // ------------------------------------------------------------------ timers

    pub(super) fn on_timers(&mut self) {
        let now = self.now();
        let (tick, requeued) = self.disp.tick(now);
        for (key, info) in &tick.dead {
            tracing::warn!(
                worker_id = %info.worker_id,
                hostname = %info.hostname,
                tasks_requeued = info.in_flight.len(),
                "worker silent for {:?}: declared dead",
                self.cfg.liveness.expiry()
            );
            self.worker_gone(key, Vec::new(), "died");
        }
        self.fail_exhausted(requeued.exhausted);
        // the guards scan tables: four times a second is often enough
        if now.saturating_sub(self.guarded_at) >= Duration::from_millis(250) {
            self.guarded_at = now;
            self.enforce_deadlines();
            self.expire_idle_sessions();
            self.keep_batches_alive();
        }
        self.resume_sessions();
        for key in tick.heartbeat {
            let in_flight = self
                .disp
                .workers
                .get(&key)
                .map_or(0, |w| w.in_flight.len() as u32);
            self.send(
                Side::Worker,
                &key,
                0,
                Body::Heartbeat(paddock_proto::Heartbeat { in_flight }),
            );
        }
        let horizon = Instant::now() - Duration::from_secs(10).min(self.started.elapsed());
        while self.stats.recent.front().is_some_and(|&t| t < horizon) {
            self.stats.recent.pop_front();
        }
    }

    /// Cleans up after a worker that left or died: requeues `tasks` (when it was not
    /// done already) and stalls or loses its env sessions.
    pub(super) fn worker_gone(&mut self, worker: &[u8], tasks: Vec<u64>, how: &str) {
        if !tasks.is_empty() {
            let r = self.disp.requeue(tasks);
            self.fail_exhausted(r.exhausted);
        }
        let orphans = self.sessions.worker_gone(worker, self.now());
        for lost in orphans.lost {
            self.session_lost(lost);
        }
        for sid in &orphans.stalled {
            tracing::warn!(
                session = sid,
                peer = %hex(worker),
                "env session's worker {how}: it waits to be replayed on another worker"
            );
        }
        self.resume_sessions();
    }

    // ------------------------------------------------------------------ status

    pub(super) fn status(&self) -> BrokerStatus {
        let now = self.now();
        let window = self.started.elapsed().as_secs_f64().clamp(1e-3, 10.0);
        BrokerStatus {
            version: env!("CARGO_PKG_VERSION").into(),
            workers: self
                .disp
                .workers
                .iter()
                .map(|(k, w)| WorkerStatus {
                    worker_id: w.worker_id.clone(),
                    hostname: w.hostname.clone(),
                    capacity: w.capacity,
                    in_flight: w.in_flight.len() as u32,
                    tasks_done: w.tasks_done,
                    last_seen_s: now.saturating_sub(w.last_seen).as_secs_f64(),
                    env_sessions: self.sessions.count_on(k),
                })
                .collect(),
            queue_depth: self.disp.tasks.queued() as u64,
            tasks_in_flight: self.disp.workers.in_flight() as u64,
            tasks_per_s: self.stats.recent.len() as f64 / window,
            tasks_done: self.stats.tasks_done,
            jobs_running: self.stats.jobs_active,
            env_sessions: self.sessions.len() as u32,
            sessions_replayed: self.sessions.stats().replayed,
            sessions_lost: self.sessions.stats().lost,
            maps: self
                .cfg
                .maps
                .iter()
                .map(|b| paddock_proto::MapRef {
                    name: b.name.clone(),
                    hash: b.hash.clone(),
                })
                .collect(),
            errors: self
                .stats
                .errors
                .iter()
                .map(|(k, v)| (k.clone(), *v))
                .collect(),
            uptime_s: self.started.elapsed().as_secs_f64(),
            instance: self.instance.clone(),
        }
    }
}

/// A fresh broker instance id: 16 hex digits from the OS's randomness (else from the
/// clock), so that a client tells a restarted broker from the one that took its batch.
pub(super) fn draw_instance_id() -> String {
    let mut b = [0u8; 8];
    if getrandom::fill(&mut b).is_err() {
        let t = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(1, |d| d.as_nanos() as u64);
        b = (t ^ u64::from(std::process::id()).rotate_left(40)).to_le_bytes();
    }
    format!("{:016x}", u64::from_le_bytes(b))
}
