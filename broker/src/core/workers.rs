//! The worker registry: who is connected, what each holds (credit), and who fell silent.
//!
//! Liveness follows the Paranoid Pirate pattern: both sides send a heartbeat every
//! `interval` when they have sent nothing else; a peer silent for `liveness` intervals
//! is dead. Time is passed in (`now`, time since the broker started), so the rules are
//! tested with a virtual clock.

use std::collections::{BTreeMap, BTreeSet, HashSet};
use std::time::Duration;

use super::TaskId;

/// A worker's ZeroMQ routing identity on the backend socket.
pub type WorkerKey = Vec<u8>;

/// The most tasks one worker may announce.
pub const MAX_CAPACITY: u32 = 4096;

/// Heartbeat timing, shared with workers in `WorkerWelcome`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Liveness {
    /// Heartbeat period.
    pub interval: Duration,
    /// Missed periods before a peer is declared dead.
    pub liveness: u32,
}

impl Default for Liveness {
    fn default() -> Self {
        Self {
            interval: Duration::from_secs(1),
            liveness: 3,
        }
    }
}

impl Liveness {
    /// Silence longer than this means dead.
    pub fn expiry(&self) -> Duration {
        self.interval * self.liveness
    }
}

/// One connected worker.
#[derive(Debug, Clone, PartialEq)]
pub struct WorkerInfo {
    pub worker_id: String,
    pub hostname: String,
    pub version: String,
    pub capacity: u32,
    /// Tasks assigned and not yet answered: never more than `capacity`.
    pub in_flight: BTreeSet<TaskId>,
    /// Env sessions it hosts.
    pub sessions: u32,
    pub tasks_done: u64,
    /// Map hashes it holds (from its hello and its map requests).
    pub maps: HashSet<String>,
    pub last_seen: Duration,
    pub last_sent: Duration,
}

impl WorkerInfo {
    pub fn free_credit(&self) -> u32 {
        self.capacity.saturating_sub(self.in_flight.len() as u32)
    }
}

/// What a clock tick asks of the broker.
#[derive(Debug, Default, PartialEq)]
pub struct Tick {
    /// Workers silent for too long, removed; their in-flight tasks must be requeued.
    pub dead: Vec<(WorkerKey, WorkerInfo)>,
    /// Workers that need a heartbeat now.
    pub heartbeat: Vec<WorkerKey>,
}

/// Why a hello was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum HelloError {
    #[error("worker_hello.capacity = {0}: must be 1..={MAX_CAPACITY}")]
    Capacity(u32),
    #[error("worker_hello.worker_id is empty")]
    EmptyId,
}

/// All connected workers, keyed by routing identity (ordered, so choices are
/// reproducible).
#[derive(Debug, Default)]
pub struct Workers {
    pub liveness: Liveness,
    workers: BTreeMap<WorkerKey, WorkerInfo>,
}

impl Workers {
    pub fn new(liveness: Liveness) -> Self {
        Self {
            liveness,
            workers: BTreeMap::new(),
        }
    }

    /// Registers a worker. A second hello on the same identity replaces the first;
    /// the old registration's in-flight tasks are returned for requeueing.
    pub fn hello(
        &mut self,
        key: WorkerKey,
        hello: &paddock_proto::WorkerHello,
        now: Duration,
    ) -> Result<Vec<TaskId>, HelloError> {
        if hello.capacity == 0 || hello.capacity > MAX_CAPACITY {
            return Err(HelloError::Capacity(hello.capacity));
        }
        if hello.worker_id.is_empty() {
            return Err(HelloError::EmptyId);
        }
        let info = WorkerInfo {
            worker_id: hello.worker_id.clone(),
            hostname: hello.hostname.clone(),
            version: hello.version.clone(),
            capacity: hello.capacity,
            in_flight: BTreeSet::new(),
            sessions: 0,
            tasks_done: 0,
            maps: hello.maps.iter().cloned().collect(),
            last_seen: now,
            last_sent: now,
        };
        let old = self.workers.insert(key, info);
        Ok(old
            .map(|o| o.in_flight.into_iter().collect())
            .unwrap_or_default())
    }

    /// Notes any message from `key`; false if the worker is not registered.
    pub fn seen(&mut self, key: &[u8], now: Duration) -> bool {
        match self.workers.get_mut(key) {
            Some(w) => {
                w.last_seen = now;
                true
            }
            None => false,
        }
    }

    /// Notes that the broker sent `key` something (a heartbeat is then not needed).
    pub fn sent(&mut self, key: &[u8], now: Duration) {
        if let Some(w) = self.workers.get_mut(key) {
            w.last_sent = now;
        }
    }

    /// Removes a worker (it said bye, or was found dead); returns it.
    pub fn remove(&mut self, key: &[u8]) -> Option<WorkerInfo> {
        self.workers.remove(key)
    }

    /// Declares silent workers dead and lists those due a heartbeat.
    pub fn tick(&mut self, now: Duration) -> Tick {
        let expiry = self.liveness.expiry();
        let dead_keys: Vec<WorkerKey> = self
            .workers
            .iter()
            .filter(|(_, w)| now.saturating_sub(w.last_seen) >= expiry)
            .map(|(k, _)| k.clone())
            .collect();
        let dead = dead_keys
            .into_iter()
            .filter_map(|k| self.workers.remove(&k).map(|w| (k, w)))
            .collect();
        let heartbeat = self
            .workers
            .iter()
            .filter(|(_, w)| now.saturating_sub(w.last_sent) >= self.liveness.interval)
            .map(|(k, _)| k.clone())
            .collect();
        Tick { dead, heartbeat }
    }

    /// The worker with the most free credit (ties: the first by identity), if any has.
    pub fn pick_for_task(&self) -> Option<WorkerKey> {
        let mut best: Option<(&WorkerKey, u32)> = None;
        for (k, w) in &self.workers {
            let free = w.free_credit();
            if free > 0 && best.is_none_or(|(_, b)| free > b) {
                best = Some((k, free));
            }
        }
        best.map(|(k, _)| k.clone())
    }

    /// The worker for a new env session: fewest sessions per unit of capacity.
    pub fn pick_for_session(&self) -> Option<WorkerKey> {
        self.workers
            .iter()
            .min_by(|(_, a), (_, b)| {
                let la = a.sessions as f64 / a.capacity as f64;
                let lb = b.sessions as f64 / b.capacity as f64;
                la.total_cmp(&lb)
            })
            .map(|(k, _)| k.clone())
    }

    /// Records an assignment. Refuses (returns false) when it would exceed the credit.
    pub fn assign(&mut self, key: &[u8], task: TaskId) -> bool {
        match self.workers.get_mut(key) {
            Some(w) if w.free_credit() > 0 => w.in_flight.insert(task),
            _ => false,
        }
    }

    /// Frees the credit of a task the worker answered; false if it did not hold it.
    pub fn release(&mut self, key: &[u8], task: TaskId) -> bool {
        let Some(w) = self.workers.get_mut(key) else {
            return false;
        };
        let held = w.in_flight.remove(&task);
        if held {
            w.tasks_done += 1;
        }
        held
    }

    pub fn get(&self, key: &[u8]) -> Option<&WorkerInfo> {
        self.workers.get(key)
    }

    pub fn get_mut(&mut self, key: &[u8]) -> Option<&mut WorkerInfo> {
        self.workers.get_mut(key)
    }

    pub fn iter(&self) -> impl Iterator<Item = (&WorkerKey, &WorkerInfo)> {
        self.workers.iter()
    }

    pub fn len(&self) -> usize {
        self.workers.len()
    }

    pub fn is_empty(&self) -> bool {
        self.workers.is_empty()
    }

    pub fn in_flight(&self) -> usize {
        self.workers.values().map(|w| w.in_flight.len()).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hello(id: &str, capacity: u32) -> paddock_proto::WorkerHello {
        paddock_proto::WorkerHello {
            worker_id: id.into(),
            capacity,
            version: "0.1.0".into(),
            hostname: "h".into(),
            maps: vec![],
        }
    }

    fn s(x: f64) -> Duration {
        Duration::from_secs_f64(x)
    }

    #[test]
    fn silent_worker_dies_after_three_missed_heartbeats() {
        let mut w = Workers::new(Liveness::default());
        w.hello(b"a".to_vec(), &hello("a", 2), s(0.0)).unwrap();
        w.hello(b"b".to_vec(), &hello("b", 2), s(0.0)).unwrap();
        assert!(w.assign(b"a", 7));
        // b keeps talking, a falls silent
        for t in [0.9, 1.8, 2.7] {
            assert!(w.seen(b"b", s(t)));
            assert!(w.tick(s(t)).dead.is_empty(), "nobody dead at {t}");
        }
        assert!(w.seen(b"b", s(2.99)));
        assert!(w.tick(s(2.99)).dead.is_empty());
        let tick = w.tick(s(3.0));
        assert_eq!(tick.dead.len(), 1);
        assert_eq!(tick.dead[0].0, b"a".to_vec());
        assert_eq!(
            tick.dead[0].1.in_flight.iter().copied().collect::<Vec<_>>(),
            [7]
        );
        assert_eq!(w.len(), 1);
        assert!(!w.seen(b"a", s(3.1)), "a dead worker is forgotten");
    }

    #[test]
    fn heartbeats_are_due_only_after_an_interval_without_sending() {
        let mut w = Workers::new(Liveness::default());
        w.hello(b"a".to_vec(), &hello("a", 1), s(0.0)).unwrap();
        assert!(w.tick(s(0.5)).heartbeat.is_empty());
        assert_eq!(w.tick(s(1.0)).heartbeat, vec![b"a".to_vec()]);
        w.sent(b"a", s(1.0));
        w.seen(b"a", s(1.0));
        assert!(w.tick(s(1.5)).heartbeat.is_empty());
        assert_eq!(w.tick(s(2.0)).heartbeat.len(), 1);
    }

    #[test]
    fn credit_is_never_exceeded() {
        let mut w = Workers::new(Liveness::default());
        w.hello(b"a".to_vec(), &hello("a", 2), s(0.0)).unwrap();
        w.hello(b"b".to_vec(), &hello("b", 1), s(0.0)).unwrap();
        let mut next = 0;
        while let Some(k) = w.pick_for_task() {
            assert!(w.assign(&k, next));
            next += 1;
        }
        assert_eq!(next, 3);
        assert!(!w.assign(b"a", 99), "a full worker refuses");
        assert_eq!(w.get(b"a").unwrap().in_flight.len(), 2);
        assert!(w.release(b"a", 0));
        assert!(!w.release(b"a", 0), "a task is released once");
        assert_eq!(w.pick_for_task(), Some(b"a".to_vec()));
    }

    #[test]
    fn bad_hellos_are_refused_and_rehello_returns_old_tasks() {
        let mut w = Workers::new(Liveness::default());
        assert_eq!(
            w.hello(b"a".to_vec(), &hello("a", 0), s(0.0)),
            Err(HelloError::Capacity(0))
        );
        assert_eq!(
            w.hello(b"a".to_vec(), &hello("", 1), s(0.0)),
            Err(HelloError::EmptyId)
        );
        w.hello(b"a".to_vec(), &hello("a", 4), s(0.0)).unwrap();
        w.assign(b"a", 1);
        w.assign(b"a", 2);
        assert_eq!(
            w.hello(b"a".to_vec(), &hello("a", 4), s(1.0)).unwrap(),
            [1, 2]
        );
        assert_eq!(w.in_flight(), 0);
    }
}
