//! The replay log of an env session: what the broker needs to rebuild the session on
//! another worker when its worker dies.
//!
//! The simulator is deterministic (same open request, seeds and actions: same bits), so
//! a session is rebuilt by sending its open request and then every answered reset and
//! step, in order, to a live worker. The broker never decodes them: it keeps each
//! request's payload bytes as the client sent them, and the fingerprint of the reply
//! that the worker computed ([`paddock_proto::fingerprint`], in the reply's header). The
//! replay's replies must carry the same fingerprints: a rebuilt session that would differ
//! is reported lost instead of continuing with other numbers.
//!
//! Memory is bounded: a reset of every env with one seed each makes everything before
//! it irrelevant (the worker says so in its reply's `restart` flag), so the log restarts
//! there (compaction); past [`LogLimits::max_bytes`] or [`LogLimits::max_entries`] the
//! log is dropped and the session marked not replayable (until its next such reset),
//! with the reason given to the client if its worker dies.

use std::time::Duration;

/// Bounds of the replay logs, and how long a session whose worker died waits for
/// another worker.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LogLimits {
    /// Bytes one session's log may hold (requests and bookkeeping).
    pub max_bytes: usize,
    /// Requests one session's log may hold since its last compaction.
    pub max_entries: usize,
    /// How long a session whose worker died waits for a live worker to be rebuilt on;
    /// then it is lost.
    pub wait: Duration,
}

impl Default for LogLimits {
    /// 16 MiB or a million requests per session (about 40 minutes of one env at 100
    /// steps/s with unseeded resets; a seeded reset compacts the log); 5 s for another
    /// worker.
    fn default() -> Self {
        Self {
            max_bytes: 16 << 20,
            max_entries: 1_000_000,
            wait: Duration::from_secs(5),
        }
    }
}

/// A request that changes a session's state (a reset or a step), as the client sent it:
/// its op (`paddock_proto::EnvOp`) and payload bytes, never decoded by the broker.
#[derive(Debug, Clone, PartialEq)]
pub struct Logged {
    pub op: i32,
    pub payload: Vec<u8>,
}

impl Logged {
    /// Memory held for it in a log (payload and bookkeeping).
    fn bytes(&self) -> usize {
        self.payload.len() + std::mem::size_of::<Entry>()
    }
}

#[derive(Debug, Clone, PartialEq)]
struct Entry {
    request: Logged,
    /// Fingerprint of the reply the client got.
    reply: u64,
}

/// One session's log: its open request and the answered requests since the last
/// compaction.
#[derive(Debug, Clone)]
pub struct SessionLog {
    open: Vec<u8>,
    entries: Vec<Entry>,
    bytes: usize,
    limits: LogLimits,
    /// Why it can no longer rebuild the session.
    not_replayable: Option<String>,
    compactions: u64,
}

impl SessionLog {
    /// The log of a session opened with the open request `open` (its payload bytes).
    pub fn new(open: Vec<u8>, limits: LogLimits) -> Self {
        Self {
            open,
            entries: Vec::new(),
            bytes: 0,
            limits,
            not_replayable: None,
            compactions: 0,
        }
    }

    /// Records a request the worker answered with a reply of fingerprint `reply`;
    /// `restart`: the worker says the request reset every env with its own seed.
    pub fn record(&mut self, request: Logged, reply: u64, restart: bool) {
        if restart && (!self.entries.is_empty() || self.not_replayable.is_some()) {
            // the open and this reset determine the session again
            self.entries.clear();
            self.bytes = 0;
            self.not_replayable = None;
            self.compactions += 1;
        }
        if self.not_replayable.is_some() {
            return;
        }
        let bytes = request.bytes();
        if self.bytes + bytes > self.limits.max_bytes
            || self.entries.len() >= self.limits.max_entries
        {
            self.not_replayable = Some(format!(
                "its replay log reached its bound ({} requests, {} bytes; at most {} requests \
                 and {} bytes since the last reset of every env with seeds)",
                self.entries.len() + 1,
                self.bytes + bytes,
                self.limits.max_entries,
                self.limits.max_bytes
            ));
            self.entries = Vec::new();
            self.bytes = 0;
            return;
        }
        self.bytes += bytes;
        self.entries.push(Entry { request, reply });
    }

    /// Ok when the session can be rebuilt, else why not.
    pub fn replayable(&self) -> Result<(), &str> {
        match &self.not_replayable {
            Some(why) => Err(why),
            None => Ok(()),
        }
    }

    /// The payload of the request that opened the session.
    pub fn open(&self) -> &[u8] {
        &self.open
    }

    /// Requests to replay after the open.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Request `index` of the replay.
    pub fn request(&self, index: usize) -> Option<&Logged> {
        self.entries.get(index).map(|e| &e.request)
    }

    /// Whether the reply fingerprint `reply` to replayed request `index` equals that of
    /// the reply the client got.
    pub fn matches(&self, index: usize, reply: u64) -> bool {
        self.entries.get(index).is_some_and(|e| e.reply == reply)
    }

    /// Bytes held (the open request and the log).
    pub fn bytes(&self) -> usize {
        self.bytes + self.open.len()
    }

    /// Times the log restarted at a reset of every env.
    pub fn compactions(&self) -> u64 {
        self.compactions
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const RESET: i32 = paddock_proto::EnvOp::EnvReset as i32;
    const STEP: i32 = paddock_proto::EnvOp::EnvStep as i32;

    fn step(a: u8) -> Logged {
        Logged {
            op: STEP,
            payload: vec![a; 16],
        }
    }

    fn reset(a: u8) -> Logged {
        Logged {
            op: RESET,
            payload: vec![a; 4],
        }
    }

    fn log(limits: LogLimits) -> SessionLog {
        SessionLog::new(b"open".to_vec(), limits)
    }

    #[test]
    fn replies_are_checked_by_fingerprint() {
        let mut l = log(LogLimits::default());
        l.record(reset(0), 11, false);
        l.record(step(1), 12, false);
        assert_eq!(l.len(), 2);
        assert!(l.matches(1, 12));
        assert!(!l.matches(1, 13), "a different reply is caught");
        assert!(!l.matches(2, 12), "no such entry");
        assert_eq!(l.request(1), Some(&step(1)));
        assert_eq!(l.open(), b"open");
    }

    #[test]
    fn a_restart_point_compacts_the_log() {
        let mut l = log(LogLimits::default());
        l.record(reset(0), 1, false);
        for k in 0..10 {
            l.record(step(k), 2, false);
        }
        assert_eq!((l.len(), l.compactions()), (11, 0));
        l.record(reset(5), 3, true);
        assert_eq!((l.len(), l.compactions()), (1, 1));
        l.record(step(1), 4, false);
        l.record(reset(6), 5, true);
        assert_eq!((l.len(), l.compactions()), (1, 2));
        assert_eq!(l.request(0), Some(&reset(6)));
        assert!(l.replayable().is_ok());
    }

    #[test]
    fn past_its_bound_a_session_is_not_replayable() {
        let per = step(0).bytes();
        let mut l = log(LogLimits {
            max_bytes: 10 * per,
            ..LogLimits::default()
        });
        for _ in 0..10 {
            l.record(step(0), 0, false);
        }
        assert!(l.replayable().is_ok());
        assert_eq!(l.bytes(), 10 * per + 4);
        l.record(step(0), 0, false);
        let why = l.replayable().unwrap_err();
        assert!(
            why.contains("bound") && why.contains("11 requests"),
            "{why}"
        );
        assert_eq!((l.len(), l.bytes()), (0, 4), "the memory is freed");
        l.record(step(0), 0, false);
        assert!(
            l.replayable().is_err(),
            "steps after the cut are not logged"
        );
        assert_eq!(l.len(), 0);
        // a reset of every env with seeds determines the session again
        l.record(reset(1), 0, true);
        assert!(l.replayable().is_ok());
        assert_eq!(l.len(), 1);

        let mut l = log(LogLimits {
            max_entries: 3,
            ..LogLimits::default()
        });
        for _ in 0..3 {
            l.record(step(0), 0, false);
        }
        assert!(l.replayable().is_ok());
        l.record(step(0), 0, false);
        assert!(l.replayable().is_err());
    }
}
