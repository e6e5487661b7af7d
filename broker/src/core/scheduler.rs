//! The task table: batches ("sources") of tasks waiting for workers, in flight, and
//! done, with fair dispatch, bounded queues and in-order reduction.
//!
//! - A *source* is one client batch or one round of a job. Its tasks are numbered
//!   0..n; results are kept by that index, so the reduced result is in task order
//!   whatever order workers answer in.
//! - Dispatch takes one task from each source with queued tasks in turn
//!   (round-robin), so a huge batch does not starve a small one submitted after it.
//! - A task id is answered once: the first result wins, later ones (a worker declared
//!   dead that was only slow, a requeued copy) are dropped by id. A result counts only
//!   from a worker the task was handed to.
//! - Results are whatever the caller keeps (`R`: the broker keeps each task's payload
//!   frame, undecoded).
//! - The number of unfinished tasks is bounded, in total and per client; a submission
//!   over a bound is refused with [`Busy`] rather than queued.

use std::collections::{BTreeMap, HashMap, VecDeque};

use super::{ClientKey, SourceId, TaskId, WorkerKey};

/// Queue bounds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    /// Unfinished tasks in the whole broker.
    pub max_tasks: usize,
    /// Unfinished tasks of one client.
    pub max_tasks_per_client: usize,
    /// Times a task is handed to a worker before it fails (a task that kills workers).
    pub max_attempts: u32,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            max_tasks: 1_000_000,
            max_tasks_per_client: 200_000,
            max_attempts: 5,
        }
    }
}

/// A submission refused because a queue bound would be exceeded.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{what}: {have} unfinished tasks + {asked} new would exceed the limit of {limit}")]
pub struct Busy {
    pub what: &'static str,
    pub have: usize,
    pub asked: usize,
    pub limit: usize,
}

#[derive(Debug)]
struct Source<R> {
    client: ClientKey,
    queue: VecDeque<TaskId>,
    results: Vec<Option<R>>,
    done: usize,
}

#[derive(Debug, Clone, PartialEq)]
struct Task {
    source: SourceId,
    index: usize,
    attempts: u32,
    worker: Option<WorkerKey>,
    /// Every worker it was handed to (at most `max_attempts`): a result counts only from
    /// one of them.
    holders: Vec<WorkerKey>,
}

/// A task handed to a worker.
#[derive(Debug, Clone, PartialEq)]
pub struct Assigned {
    pub task: TaskId,
    pub source: SourceId,
    pub index: usize,
}

/// What a result did.
#[derive(Debug, Clone, PartialEq)]
pub enum Completion {
    /// Stored; `finished` when it was the source's last task.
    Accepted {
        source: SourceId,
        index: usize,
        done: usize,
        total: usize,
        finished: bool,
    },
    /// The task is not (or no longer) open: a late duplicate or a cancelled source.
    Dropped,
}

/// See the module documentation.
#[derive(Debug)]
pub struct Scheduler<R> {
    pub limits: Limits,
    tasks: HashMap<TaskId, Task>,
    sources: BTreeMap<SourceId, Source<R>>,
    /// Sources with queued tasks, in turn order.
    turn: VecDeque<SourceId>,
    per_client: HashMap<ClientKey, usize>,
    next_task: TaskId,
    next_source: SourceId,
}

impl<R> Scheduler<R> {
    pub fn new(limits: Limits) -> Self {
        Self {
            limits,
            tasks: HashMap::new(),
            sources: BTreeMap::new(),
            turn: VecDeque::new(),
            per_client: HashMap::new(),
            next_task: 1,
            next_source: 1,
        }
    }

    /// Numbers tasks from `first` on. A broker starts from a value derived from the
    /// clock, so a task id of an earlier run (a late result from a worker that outlived
    /// a broker restart) never names a task of this run.
    pub fn set_first_task_id(&mut self, first: TaskId) {
        self.next_task = first.max(1);
    }

    /// Queues a source of `n` tasks for `client`, or refuses it when a bound would be
    /// exceeded. A source of 0 tasks is finished at once.
    pub fn submit(&mut self, client: &[u8], n: usize) -> Result<SourceId, Busy> {
        let total = self.tasks.len();
        if total + n > self.limits.max_tasks {
            return Err(Busy {
                what: "broker queue",
                have: total,
                asked: n,
                limit: self.limits.max_tasks,
            });
        }
        let mine = self.per_client.get(client).copied().unwrap_or(0);
        if mine + n > self.limits.max_tasks_per_client {
            return Err(Busy {
                what: "client queue",
                have: mine,
                asked: n,
                limit: self.limits.max_tasks_per_client,
            });
        }
        let id = self.next_source;
        self.next_source += 1;
        let mut queue = VecDeque::with_capacity(n);
        for index in 0..n {
            let t = self.next_task;
            self.next_task += 1;
            self.tasks.insert(
                t,
                Task {
                    source: id,
                    index,
                    attempts: 0,
                    worker: None,
                    holders: Vec::new(),
                },
            );
            queue.push_back(t);
        }
        if n > 0 {
            self.turn.push_back(id);
            *self.per_client.entry(client.to_vec()).or_default() += n;
        }
        self.sources.insert(
            id,
            Source {
                client: client.to_vec(),
                queue,
                results: (0..n).map(|_| None).collect(),
                done: 0,
            },
        );
        Ok(id)
    }

    /// The next task to hand out (round-robin over sources), recorded as held by
    /// `worker`.
    pub fn next_for(&mut self, worker: &[u8]) -> Option<Assigned> {
        while let Some(sid) = self.turn.pop_front() {
            let Some(src) = self.sources.get_mut(&sid) else {
                continue;
            };
            let Some(t) = src.queue.pop_front() else {
                continue;
            };
            if !src.queue.is_empty() {
                self.turn.push_back(sid);
            }
            // a queued task is always open; a stale id is skipped, never trusted
            let Some(task) = self.tasks.get_mut(&t) else {
                continue;
            };
            task.worker = Some(worker.to_vec());
            if !task.holders.iter().any(|h| h == worker) {
                task.holders.push(worker.to_vec());
            }
            task.attempts += 1;
            return Some(Assigned {
                task: t,
                source: sid,
                index: task.index,
            });
        }
        None
    }

    /// Puts tasks of a dead worker back at the head of their sources' queues. Tasks
    /// already tried `max_attempts` times are returned instead (the caller fails them).
    pub fn requeue(&mut self, tasks: impl IntoIterator<Item = TaskId>) -> Vec<TaskId> {
        let mut exhausted = Vec::new();
        for t in tasks {
            let Some(task) = self.tasks.get_mut(&t) else {
                continue;
            };
            task.worker = None;
            if task.attempts >= self.limits.max_attempts {
                exhausted.push(t);
                continue;
            }
            let sid = task.source;
            if let Some(src) = self.sources.get_mut(&sid) {
                if src.queue.is_empty() {
                    self.turn.push_front(sid);
                }
                src.queue.push_front(t);
            }
        }
        exhausted
    }

    /// Stores the outcome `worker` sent for `task` (the first one wins; one from a
    /// worker the task was never handed to is dropped).
    pub fn complete_from(&mut self, task: TaskId, worker: &[u8], outcome: R) -> Completion {
        match self.tasks.get(&task) {
            Some(t) if t.holders.iter().any(|h| h == worker) => self.complete(task, outcome),
            _ => Completion::Dropped,
        }
    }

    /// Stores a task's outcome (the first one wins), whoever answers (the broker itself
    /// for a task given up).
    pub fn complete(&mut self, task: TaskId, outcome: R) -> Completion {
        let Some(t) = self.tasks.remove(&task) else {
            return Completion::Dropped;
        };
        let Some(src) = self.sources.get_mut(&t.source) else {
            return Completion::Dropped;
        };
        // a requeued copy may still wait in the queue
        if t.worker.is_none() {
            src.queue.retain(|&q| q != task);
        }
        if let Some(n) = self.per_client.get_mut(&src.client) {
            *n = n.saturating_sub(1);
        }
        src.results[t.index] = Some(outcome);
        src.done += 1;
        let total = src.results.len();
        Completion::Accepted {
            source: t.source,
            index: t.index,
            done: src.done,
            total,
            finished: src.done == total,
        }
    }

    /// The outcomes of a finished source in task order, removing it. None while any
    /// task is open.
    pub fn take_results(&mut self, source: SourceId) -> Option<(ClientKey, Vec<R>)> {
        let src = self.sources.get(&source)?;
        if src.done < src.results.len() {
            return None;
        }
        let src = self.sources.remove(&source)?;
        // done == len: every slot holds its result
        let results = src.results.into_iter().flatten().collect();
        Some((src.client, results))
    }

    /// Drops a source and its open tasks (their late results will be dropped).
    pub fn cancel(&mut self, source: SourceId) {
        let Some(src) = self.sources.remove(&source) else {
            return;
        };
        let open: Vec<TaskId> = self
            .tasks
            .iter()
            .filter(|(_, t)| t.source == source)
            .map(|(&id, _)| id)
            .collect();
        for t in &open {
            self.tasks.remove(t);
        }
        if let Some(n) = self.per_client.get_mut(&src.client) {
            *n = n.saturating_sub(open.len());
        }
        self.turn.retain(|&s| s != source);
    }

    /// Tasks waiting for a worker.
    pub fn queued(&self) -> usize {
        self.sources.values().map(|s| s.queue.len()).sum()
    }

    /// Tasks not yet answered (queued or in flight).
    pub fn open(&self) -> usize {
        self.tasks.len()
    }

    /// (done, total) of a source.
    pub fn progress(&self, source: SourceId) -> Option<(usize, usize)> {
        self.sources.get(&source).map(|s| (s.done, s.results.len()))
    }

    /// The source and index of an open task.
    pub fn task(&self, task: TaskId) -> Option<(SourceId, usize)> {
        self.tasks.get(&task).map(|t| (t.source, t.index))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    type Scheduler = super::Scheduler<u64>;

    fn ok(seed: u64) -> u64 {
        seed
    }

    fn seed_of(o: &u64) -> u64 {
        *o
    }

    #[test]
    fn results_are_reduced_in_task_order_whatever_the_arrival_order() {
        let mut s = Scheduler::new(Limits::default());
        let src = s.submit(b"c", 4).unwrap();
        let got: Vec<Assigned> = (0..4).map(|_| s.next_for(b"w").unwrap()).collect();
        assert!(s.next_for(b"w").is_none());
        for a in got.iter().rev() {
            assert!(s.take_results(src).is_none());
            s.complete(a.task, ok(a.index as u64 * 10));
        }
        let (client, results) = s.take_results(src).unwrap();
        assert_eq!(client, b"c");
        assert_eq!(
            results.iter().map(seed_of).collect::<Vec<_>>(),
            [0, 10, 20, 30]
        );
        assert_eq!(s.open(), 0);
    }

    #[test]
    fn duplicate_results_are_dropped_by_task_id() {
        let mut s = Scheduler::new(Limits::default());
        let src = s.submit(b"c", 1).unwrap();
        let a = s.next_for(b"w1").unwrap();
        // w1 is declared dead, the task is requeued and handed to w2
        assert!(s.requeue([a.task]).is_empty());
        let b = s.next_for(b"w2").unwrap();
        assert_eq!(a.task, b.task);
        // the slow w1 answers first: accepted; w2's copy is then a duplicate
        assert!(matches!(
            s.complete(a.task, ok(1)),
            Completion::Accepted { finished: true, .. }
        ));
        assert_eq!(s.complete(b.task, ok(2)), Completion::Dropped);
        let (_, r) = s.take_results(src).unwrap();
        assert_eq!(seed_of(&r[0]), 1);
    }

    #[test]
    fn results_count_only_from_a_worker_the_task_was_handed_to() {
        let mut s = Scheduler::new(Limits::default());
        let src = s.submit(b"c", 1).unwrap();
        let a = s.next_for(b"w1").unwrap();
        assert_eq!(
            s.complete_from(a.task, b"stranger", ok(9)),
            Completion::Dropped
        );
        assert!(s.requeue([a.task]).is_empty());
        s.next_for(b"w2").unwrap();
        // the first holder, declared dead but only slow, still counts
        assert!(matches!(
            s.complete_from(a.task, b"w1", ok(1)),
            Completion::Accepted { finished: true, .. }
        ));
        assert_eq!(s.take_results(src).unwrap().1, vec![1]);
    }

    #[test]
    fn a_late_result_removes_the_requeued_copy() {
        let mut s = Scheduler::new(Limits::default());
        s.submit(b"c", 1).unwrap();
        let a = s.next_for(b"w1").unwrap();
        s.requeue([a.task]);
        assert_eq!(s.queued(), 1);
        s.complete(a.task, ok(1));
        assert_eq!(s.queued(), 0);
        assert!(s.next_for(b"w2").is_none());
    }

    #[test]
    fn round_robin_keeps_a_small_batch_from_starving() {
        let mut s = Scheduler::new(Limits::default());
        let big = s.submit(b"big", 1000).unwrap();
        let small = s.submit(b"small", 3).unwrap();
        let order: Vec<SourceId> = (0..6).map(|_| s.next_for(b"w").unwrap().source).collect();
        assert_eq!(order, [big, small, big, small, big, small]);
        assert_eq!(s.next_for(b"w").unwrap().source, big);
    }

    #[test]
    fn over_the_limits_is_busy() {
        let mut s = Scheduler::new(Limits {
            max_tasks: 10,
            max_tasks_per_client: 6,
            max_attempts: 2,
        });
        s.submit(b"a", 6).unwrap();
        let e = s.submit(b"a", 1).unwrap_err();
        assert_eq!(e.what, "client queue");
        assert_eq!((e.have, e.asked, e.limit), (6, 1, 6));
        s.submit(b"b", 4).unwrap();
        assert_eq!(s.submit(b"c", 1).unwrap_err().what, "broker queue");
        // finishing work frees room
        let t = s.next_for(b"w").unwrap();
        s.complete(t.task, ok(0));
        s.submit(b"c", 1).unwrap();
    }

    #[test]
    fn a_task_that_keeps_killing_workers_is_given_up() {
        let mut s = Scheduler::new(Limits {
            max_attempts: 2,
            ..Limits::default()
        });
        s.submit(b"c", 1).unwrap();
        let a = s.next_for(b"w1").unwrap();
        assert!(s.requeue([a.task]).is_empty());
        let b = s.next_for(b"w2").unwrap();
        assert_eq!(s.requeue([b.task]), [b.task]);
        assert!(s.next_for(b"w3").is_none());
    }

    #[test]
    fn cancel_drops_queued_and_in_flight_tasks() {
        let mut s = Scheduler::new(Limits::default());
        let src = s.submit(b"c", 3).unwrap();
        let a = s.next_for(b"w").unwrap();
        s.cancel(src);
        assert_eq!(s.open(), 0);
        assert_eq!(s.queued(), 0);
        assert_eq!(s.complete(a.task, ok(0)), Completion::Dropped);
        assert!(s.next_for(b"w").is_none());
        // the client's quota is free again
        s.submit(b"c", Limits::default().max_tasks_per_client)
            .unwrap();
    }

    #[test]
    fn task_ids_of_an_earlier_run_name_nothing() {
        let mut earlier = Scheduler::new(Limits::default());
        earlier.submit(b"c", 3).unwrap();
        let old = earlier.next_for(b"w").unwrap().task;
        let mut s = Scheduler::new(Limits::default());
        s.set_first_task_id(1 << 40);
        s.submit(b"c", 3).unwrap();
        assert_eq!(s.complete(old, ok(0)), Completion::Dropped);
        assert_eq!(s.next_for(b"w").unwrap().task, 1 << 40);
    }

    #[test]
    fn an_empty_source_is_finished_at_once() {
        let mut s = Scheduler::new(Limits::default());
        let src = s.submit(b"c", 0).unwrap();
        assert_eq!(s.take_results(src).unwrap().1.len(), 0);
    }
}
