//! What keeps a broker on an open port within its bounds, beyond the queues: the
//! refusal log (lines cut short, a rate per second, the rest counted and summed up),
//! idle env sessions closed, tasks held past their deadline taken back from their
//! worker (which is dropped), and batches whose client has gone cancelled.

use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::time::Duration;

use paddock_proto::{Body, EnvOp, EnvRequest};

use super::{Broker, OwnerKind, Side, hex};
use crate::core::{Principal, TaskId, WorkerKey};

/// How much of a client's input a log line quotes, at most (characters).
pub const DEFAULT_LOG_FIELD_CHARS: usize = 200;
/// Refusals logged per second at most; the others are counted, and the count logged
/// with the next line that is written.
pub const DEFAULT_REFUSAL_LOG_RATE: u32 = 20;

/// Cuts `s` to at most `max` characters, saying how much was left out.
pub fn clip(s: &str, max: usize) -> std::borrow::Cow<'_, str> {
    match s.char_indices().nth(max) {
        None => std::borrow::Cow::Borrowed(s),
        Some((at, _)) => {
            std::borrow::Cow::Owned(format!("{}... ({} bytes in all)", &s[..at], s.len()))
        }
    }
}

/// The refusal log's rate limit: a budget of lines per one-second window.
#[derive(Debug, Default)]
pub(super) struct LogBudget {
    window: Duration,
    written: u32,
    /// Refusals not logged since the last line written.
    pub suppressed: u64,
}

impl LogBudget {
    /// Whether a line may be written at `now` with `rate` lines per second.
    pub fn allow(&mut self, now: Duration, rate: u32) -> bool {
        if now.saturating_sub(self.window) >= Duration::from_secs(1) {
            self.window = now;
            self.written = 0;
        }
        if self.written < rate {
            self.written += 1;
            true
        } else {
            self.suppressed += 1;
            false
        }
    }
}

/// Deadlines of the tasks handed to workers, soonest first (entries of tasks that
/// finished or moved are skipped when they come up).
#[derive(Debug, Default)]
pub(super) struct Deadlines {
    heap: BinaryHeap<Reverse<(Duration, TaskId, WorkerKey)>>,
}

impl Deadlines {
    pub fn push(&mut self, due: Duration, task: TaskId, worker: WorkerKey) {
        self.heap.push(Reverse((due, task, worker)));
    }

    /// The entries due at `now`.
    pub fn due(&mut self, now: Duration) -> Vec<(TaskId, WorkerKey)> {
        let mut out = Vec::new();
        while let Some(Reverse((due, _, _))) = self.heap.peek() {
            if *due > now {
                break;
            }
            if let Some(Reverse((_, t, w))) = self.heap.pop() {
                out.push((t, w));
            }
        }
        out
    }
}

impl Broker {
    /// Closes env sessions idle past the limit (on their worker too); their owner's
    /// next request is told why.
    pub(super) fn expire_idle_sessions(&mut self) {
        let idle = self.cfg.bounds.session_idle;
        if idle.is_zero() {
            return;
        }
        for sid in self.sessions.idle(self.now(), idle) {
            let reason = format!(
                "env session {sid} was closed after {}s without a request (the broker's idle limit, --session-idle-s)",
                idle.as_secs()
            );
            let Some((lost, worker)) = self.sessions.expire(sid, reason.clone()) else {
                continue;
            };
            tracing::info!(
                session = sid,
                idle_s = idle.as_secs(),
                "idle env session closed"
            );
            self.remember_lost(sid, reason);
            if let Some(w) = self.disp.workers.get_mut(&worker) {
                w.sessions = w.sessions.saturating_sub(1);
            }
            // the worker's reply to this close finds no session and is dropped
            let close = EnvRequest {
                session_id: sid,
                op: EnvOp::EnvClose as i32,
            };
            self.send(Side::Worker, &worker, 0, Body::EnvRequest(close));
            debug_assert!(lost.requests.is_empty());
        }
    }

    /// Keeps the reason a session ended for its owner's next request, the oldest
    /// forgotten past the bound.
    pub(super) fn remember_lost(&mut self, sid: u64, reason: String) {
        if self.lost_sessions.insert(sid, reason).is_none() {
            self.lost_order.push_back(sid);
        }
        while self.lost_order.len() > self.cfg.bounds.max_lost_sessions {
            if let Some(old) = self.lost_order.pop_front() {
                self.lost_sessions.remove(&old);
            }
        }
    }

    /// Tasks held past their deadline: the worker holding one is dropped (told so with
    /// a Bye) and its tasks go back to the queue.
    pub(super) fn enforce_deadlines(&mut self) {
        let now = self.now();
        for (task, worker) in self.deadlines.due(now) {
            let holds = self
                .disp
                .workers
                .get(&worker)
                .is_some_and(|w| w.in_flight.contains(&task));
            if !holds {
                continue;
            }
            let Some(info) = self.disp.workers.remove(&worker) else {
                continue;
            };
            tracing::warn!(
                worker_id = %clip(&info.worker_id, DEFAULT_LOG_FIELD_CHARS),
                peer = %hex(&worker),
                task,
                tasks_requeued = info.in_flight.len(),
                "worker held a task past its deadline: dropped, its tasks requeued"
            );
            self.send(
                Side::Worker,
                &worker,
                0,
                Body::Bye(paddock_proto::Bye {
                    reason: format!("task {task} passed its deadline on this worker: dropped"),
                }),
            );
            self.worker_gone(&worker, info.in_flight.into_iter().collect(), "was dropped");
        }
    }

    /// Tells each batch's client how far its batch is, at least once a second: a client
    /// that has gone (the socket has no route to it any more) has its batch cancelled,
    /// so its queued tasks do not run for no one.
    pub(super) fn keep_batches_alive(&mut self) {
        let every = Duration::from_secs(1);
        let mut gone = Vec::new();
        let mut due = Vec::new();
        for (&source, owner) in &self.sources {
            if let OwnerKind::Batch {
                client,
                request_id,
                last_progress,
                ..
            } = &owner.kind
                && last_progress.elapsed() >= every
            {
                due.push((source, client.clone(), *request_id));
            }
        }
        for (source, client, rid) in due {
            let (done, total) = self.disp.tasks.progress(source).unwrap_or((0, 0));
            let msg = self.progress_body(done, total);
            if let Some(OwnerKind::Batch { last_progress, .. }) =
                self.sources.get_mut(&source).map(|o| &mut o.kind)
            {
                *last_progress = std::time::Instant::now();
            }
            if !self.send_to_client(&client, rid, msg) {
                gone.push(source);
            }
        }
        for source in gone {
            tracing::info!(source, "the batch's client has gone: batch cancelled");
            self.cancel_source(source);
        }
    }

    /// Whether `who` is an admin key (sees and manages every job).
    pub(super) fn is_admin(&self, who: &Principal) -> bool {
        let Some(key) = who.strip_prefix("key:") else {
            return false;
        };
        self.cfg
            .security
            .as_ref()
            .is_some_and(|s| s.admin_keys.iter().any(|k| k == key))
    }
}
