//! The broker's protocol state machines, free of sockets and of the wall clock
//! ("sans-IO"): the server feeds them messages and the current time and carries out
//! what they decide. Each is unit-tested with a virtual clock.

pub mod blobs;
pub mod replay;
pub mod scheduler;
pub mod sessions;
pub mod workers;

use std::time::Duration;

pub use blobs::{BlobLimits, Blobs};
pub use replay::{LogLimits, Logged, SessionLog};
pub use scheduler::{Assigned, Busy, Completion, Limits, Scheduler};
pub use sessions::{
    Held, Lost, Orphans, Pending, ReplayStats, Reply, ReplyHead, Route, Sent, Session,
    SessionState, Sessions,
};
pub use workers::{Liveness, Tick, WorkerInfo, WorkerKey, Workers};

/// A task's id, unique for the broker's lifetime.
pub type TaskId = u64;
/// A batch or job round: a set of tasks reduced together.
pub type SourceId = u64;
/// A client's ZeroMQ routing identity on the frontend socket.
pub type ClientKey = Vec<u8>;
/// Who a client is, for ownership (jobs, env sessions) and per-client bounds: `key:`
/// and its CURVE public key (Z85) when the broker authenticates clients, so every
/// connection of one key is one client; else `peer:` and its connection's routing id.
pub type Principal = String;

/// The [`Principal`] of a client with CURVE user id `user_id` (the ZAP handler sets it
/// to the key) and routing id `route`.
pub fn principal(user_id: Option<&str>, route: &[u8]) -> Principal {
    match user_id {
        Some(key) if !key.is_empty() => format!("key:{key}"),
        _ => format!("peer:{}", hex(route)),
    }
}

/// Bytes as lower-case hex digits (routing ids in logs and principals, job ids).
pub use paddock_proto::hex;

/// Workers and tasks together: credit-based dispatch and requeueing. `R` is what the
/// broker keeps of a task's result.
#[derive(Debug)]
pub struct Dispatcher<R> {
    pub workers: Workers,
    pub tasks: Scheduler<R>,
}

/// A dead worker's aftermath.
#[derive(Debug, Default, PartialEq)]
pub struct Requeued {
    /// Tasks put back in their queues.
    pub requeued: usize,
    /// Tasks that exhausted their attempts: the caller fails them.
    pub exhausted: Vec<TaskId>,
}

impl<R> Dispatcher<R> {
    pub fn new(liveness: Liveness, limits: Limits) -> Self {
        Self {
            workers: Workers::new(liveness),
            tasks: Scheduler::new(limits),
        }
    }

    /// Hands queued tasks to workers with free credit, fairly; returns the assignments.
    pub fn dispatch(&mut self) -> Vec<(WorkerKey, Assigned)> {
        let mut out = Vec::new();
        while let Some(w) = self.workers.pick_for_task() {
            let Some(a) = self.tasks.next_for(&w) else {
                break;
            };
            let ok = self.workers.assign(&w, a.task);
            debug_assert!(ok, "picked worker has credit");
            out.push((w, a));
        }
        out
    }

    /// Requeues the tasks a departed worker held.
    pub fn requeue(&mut self, tasks: impl IntoIterator<Item = TaskId>) -> Requeued {
        let tasks: Vec<TaskId> = tasks.into_iter().collect();
        let n = tasks.len();
        let exhausted = self.tasks.requeue(tasks);
        Requeued {
            requeued: n - exhausted.len(),
            exhausted,
        }
    }

    /// Declares silent workers dead (their tasks requeued) and lists heartbeats due.
    pub fn tick(&mut self, now: Duration) -> (Tick, Requeued) {
        let tick = self.workers.tick(now);
        let mut all = Vec::new();
        for (_, w) in &tick.dead {
            all.extend(w.in_flight.iter().copied());
        }
        let r = self.requeue(all);
        (tick, r)
    }

    /// A worker's result: frees its credit and stores the outcome (first one wins, and
    /// only from a worker the task was handed to).
    pub fn result(&mut self, worker: &[u8], task: TaskId, outcome: R) -> Completion {
        self.workers.release(worker, task);
        self.tasks.complete_from(task, worker, outcome)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hello(id: &str, capacity: u32) -> paddock_proto::WorkerHello {
        paddock_proto::WorkerHello {
            worker_id: id.into(),
            capacity,
            ..Default::default()
        }
    }

    fn s(x: f64) -> Duration {
        Duration::from_secs_f64(x)
    }

    #[test]
    fn dispatch_respects_credit_and_a_dead_workers_tasks_run_elsewhere() {
        let mut d = Dispatcher::<u64>::new(Liveness::default(), Limits::default());
        d.workers
            .hello(b"a".to_vec(), &hello("a", 2), s(0.0))
            .unwrap();
        d.workers
            .hello(b"b".to_vec(), &hello("b", 1), s(0.0))
            .unwrap();
        let src = d.tasks.submit(b"c", 5).unwrap();
        let first = d.dispatch();
        assert_eq!(first.len(), 3, "2 + 1 credits");
        assert!(d.dispatch().is_empty(), "no credit left");
        // b answers its task; a falls silent
        let (bk, ba) = first.iter().find(|(w, _)| w == b"b").unwrap().clone();
        assert!(matches!(
            d.result(&bk, ba.task, Default::default()),
            Completion::Accepted { .. }
        ));
        for t in [1.0, 2.0, 2.9] {
            d.workers.seen(b"b", s(t));
            assert!(d.tick(s(t)).0.dead.is_empty());
        }
        let next = d.dispatch();
        assert_eq!(next.len(), 1);
        d.workers.seen(b"b", s(3.0));
        let (tick, r) = d.tick(s(3.0));
        assert_eq!(tick.dead.len(), 1);
        assert_eq!(r.requeued, 2);
        // b (capacity 1) now works through everything left, one task at a time
        let mut done = 1;
        let mut guard = 0;
        loop {
            let batch = d.dispatch();
            for (w, _) in &batch {
                assert_eq!(w, b"b");
                assert!(d.workers.get(b"b").unwrap().in_flight.len() <= 1);
            }
            // b still holds the task from `next` first
            let held: Vec<TaskId> = d
                .workers
                .get(b"b")
                .unwrap()
                .in_flight
                .iter()
                .copied()
                .collect();
            for t in held {
                if let Completion::Accepted { .. } = d.result(b"b", t, Default::default()) {
                    done += 1;
                }
            }
            guard += 1;
            if d.tasks.take_results(src).is_some() || guard > 20 {
                break;
            }
        }
        assert_eq!(done, 5);
    }
}
