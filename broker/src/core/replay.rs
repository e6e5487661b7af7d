//! The replay log of an env session: what the broker needs to rebuild the session on
//! another worker when its worker dies.
//!
//! The simulator is deterministic (same open request, seeds and actions: same bits), so
//! a session is rebuilt by sending its `EnvOpen` and then every answered `EnvReset` and
//! `EnvStep`, in order, to a live worker. Each entry keeps a fingerprint of the reply
//! the client got, and the replay's replies are checked against it: a rebuilt session
//! that would differ is reported lost instead of continuing with other numbers.
//!
//! Memory is bounded: a reset of every env with one seed each makes everything before
//! it irrelevant, so the log restarts there (compaction); past [`LogLimits::max_bytes`]
//! or [`LogLimits::max_entries`] the log is dropped and the session marked not
//! replayable (until its next such reset), with the reason given to the client if its
//! worker dies.

use std::time::Duration;

use paddock_proto::{Body, EnvObservation, EnvOpen, EnvReset, EnvStep};

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
    /// 64 MiB or a million requests per session (about three hours of one env at
    /// 100 steps/s with unseeded resets); 5 s for another worker.
    fn default() -> Self {
        Self {
            max_bytes: 64 << 20,
            max_entries: 1_000_000,
            wait: Duration::from_secs(5),
        }
    }
}

/// A request that changes a session's state, as the client sent it (the session id is
/// set when it is sent to a worker).
#[derive(Debug, Clone, PartialEq)]
pub enum EnvRequest {
    Reset(EnvReset),
    Step(EnvStep),
}

impl EnvRequest {
    /// Memory held for it in a log (payload and bookkeeping).
    fn bytes(&self) -> usize {
        let payload = match self {
            EnvRequest::Reset(r) => r.envs.len() * 4 + r.seeds.len() * 8 + r.poses.len(),
            EnvRequest::Step(s) => s.actions.len() + s.reset_envs.len() * 4,
        };
        payload + std::mem::size_of::<Entry>()
    }

    /// The message for a worker whose id for the session is `worker_session`.
    pub fn to_body(&self, worker_session: u64) -> Body {
        match self {
            EnvRequest::Reset(r) => Body::EnvReset(EnvReset {
                session_id: worker_session,
                ..r.clone()
            }),
            EnvRequest::Step(s) => Body::EnvStep(EnvStep {
                session_id: worker_session,
                ..s.clone()
            }),
        }
    }

    /// Whether it resets every one of `num_envs` envs, each with its own seed: the
    /// session's state after it does not depend on anything before it.
    fn restarts_all(&self, num_envs: usize) -> bool {
        let EnvRequest::Reset(r) = self else {
            return false;
        };
        let targets = if r.envs.is_empty() {
            num_envs
        } else {
            let mut seen = vec![false; num_envs];
            for &i in &r.envs {
                match seen.get_mut(i as usize) {
                    Some(s) if !*s => *s = true,
                    _ => return false,
                }
            }
            if seen.iter().any(|s| !s) {
                return false;
            }
            r.envs.len()
        };
        r.seeds.len() == targets
    }
}

/// A fingerprint of an observation, to check a replayed reply against the original
/// (all numeric fields; not the session id, which differs between workers).
pub fn fingerprint(o: &EnvObservation) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325 ^ u64::from(o.num_envs);
    for field in [
        &o.scans,
        &o.states,
        &o.rewards,
        &o.terminated,
        &o.truncated,
        &o.progress,
        &o.laps,
        &o.time,
        &o.agent_collisions,
        &o.agent_lap_counts,
        &o.agent_lap_times,
    ] {
        h = mix(h, field.len() as u64);
        h = hash_bytes(h, field);
    }
    h
}

/// Folds `bytes` into `h`: four independent lanes of 8-byte words, so the multiplies of a
/// 64-env step's scans (about 276 KB, on the broker's loop for every step) overlap instead of
/// waiting on each other; then the tail, and the lanes folded together.
fn hash_bytes(h: u64, bytes: &[u8]) -> u64 {
    let word = |w: &[u8]| {
        let mut b = [0u8; 8];
        b[..w.len()].copy_from_slice(w);
        u64::from_le_bytes(b)
    };
    let mut lanes = [
        h,
        h ^ 0x9e37_79b9_7f4a_7c15,
        h ^ 0xc2b2_ae3d_27d4_eb4f,
        h ^ 0x1656_67b1_9e37_79f9,
    ];
    let mut blocks = bytes.chunks_exact(32);
    for block in &mut blocks {
        for (lane, w) in lanes.iter_mut().zip(block.chunks_exact(8)) {
            *lane = mix(*lane, word(w));
        }
    }
    let mut h = lanes.into_iter().fold(h, mix);
    for w in blocks.remainder().chunks(8) {
        h = mix(h, word(w));
    }
    h
}

fn mix(h: u64, v: u64) -> u64 {
    (h ^ v).wrapping_mul(0x0100_0000_01b3).rotate_left(23)
}

#[derive(Debug, Clone, PartialEq)]
struct Entry {
    request: EnvRequest,
    /// Fingerprint of the reply the client got.
    reply: u64,
}

/// One session's log: its open request and the answered requests since the last
/// compaction.
#[derive(Debug, Clone)]
pub struct SessionLog {
    open: EnvOpen,
    num_envs: usize,
    entries: Vec<Entry>,
    bytes: usize,
    limits: LogLimits,
    /// Why it can no longer rebuild the session.
    not_replayable: Option<String>,
    compactions: u64,
}

impl SessionLog {
    /// The log of a session opened with `open`, of `num_envs` envs.
    pub fn new(open: EnvOpen, num_envs: usize, limits: LogLimits) -> Self {
        Self {
            open,
            num_envs,
            entries: Vec::new(),
            bytes: 0,
            limits,
            not_replayable: None,
            compactions: 0,
        }
    }

    /// Records a request the worker answered with `reply`.
    pub fn record(&mut self, request: EnvRequest, reply: &EnvObservation) {
        if request.restarts_all(self.num_envs)
            && (!self.entries.is_empty() || self.not_replayable.is_some())
        {
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
        self.entries.push(Entry {
            request,
            reply: fingerprint(reply),
        });
    }

    /// Ok when the session can be rebuilt, else why not.
    pub fn replayable(&self) -> Result<(), &str> {
        match &self.not_replayable {
            Some(why) => Err(why),
            None => Ok(()),
        }
    }

    /// The request that opened the session.
    pub fn open(&self) -> &EnvOpen {
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
    pub fn request(&self, index: usize) -> Option<&EnvRequest> {
        self.entries.get(index).map(|e| &e.request)
    }

    /// Whether `reply` to replayed request `index` equals the reply the client got.
    pub fn matches(&self, index: usize, reply: &EnvObservation) -> bool {
        self.entries
            .get(index)
            .is_some_and(|e| e.reply == fingerprint(reply))
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.bytes
    }

    /// Times the log restarted at a reset of every env.
    pub fn compactions(&self) -> u64 {
        self.compactions
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn step(a: f32) -> EnvRequest {
        EnvRequest::Step(EnvStep {
            session_id: 0,
            actions: paddock_proto::pack_f32(&[0.0, a]),
            reset_envs: vec![],
        })
    }

    fn reset(envs: Vec<u32>, seeds: Vec<u64>) -> EnvRequest {
        EnvRequest::Reset(EnvReset {
            session_id: 0,
            envs,
            seeds,
            poses: vec![],
        })
    }

    fn obs(t: f64) -> EnvObservation {
        EnvObservation {
            num_envs: 2,
            time: paddock_proto::pack_f64(&[t, t]),
            ..Default::default()
        }
    }

    fn log(limits: LogLimits) -> SessionLog {
        SessionLog::new(EnvOpen::default(), 2, limits)
    }

    #[test]
    fn replies_are_checked_by_fingerprint() {
        let mut l = log(LogLimits::default());
        l.record(reset(vec![], vec![]), &obs(0.0));
        l.record(step(1.0), &obs(0.01));
        assert_eq!(l.len(), 2);
        assert!(l.matches(1, &obs(0.01)));
        assert!(!l.matches(1, &obs(0.02)), "a different reply is caught");
        assert!(!l.matches(2, &obs(0.01)), "no such entry");
        let mut other_id = obs(0.01);
        other_id.session_id = 9;
        assert!(l.matches(1, &other_id), "the session id is not compared");
        assert_eq!(l.request(1), Some(&step(1.0)));
        match l.request(1).expect("entry 1 is logged").to_body(7) {
            Body::EnvStep(s) => assert_eq!(s.session_id, 7),
            other => panic!("expected a step, got {other:?}"),
        }
    }

    #[test]
    fn a_seeded_reset_of_every_env_compacts_the_log() {
        let mut l = log(LogLimits::default());
        l.record(reset(vec![], vec![]), &obs(0.0));
        for k in 0..10 {
            l.record(step(k as f32), &obs(0.01 * k as f64));
        }
        // not every env, or not every env seeded: the past still matters
        l.record(reset(vec![1], vec![5]), &obs(0.0));
        l.record(reset(vec![], vec![5]), &obs(0.0));
        l.record(reset(vec![0, 0], vec![5, 6]), &obs(0.0));
        l.record(reset(vec![], vec![]), &obs(0.0));
        assert_eq!((l.len(), l.compactions()), (15, 0));
        l.record(reset(vec![1, 0], vec![5, 6]), &obs(0.0));
        assert_eq!((l.len(), l.compactions()), (1, 1));
        l.record(step(1.0), &obs(0.01));
        l.record(reset(vec![], vec![3, 4]), &obs(0.0));
        assert_eq!((l.len(), l.compactions()), (1, 2));
        assert_eq!(l.request(0), Some(&reset(vec![], vec![3, 4])));
        assert!(l.replayable().is_ok());
    }

    #[test]
    fn past_its_bound_a_session_is_not_replayable() {
        let per = step(0.0).bytes();
        let mut l = log(LogLimits {
            max_bytes: 10 * per,
            ..LogLimits::default()
        });
        for _ in 0..10 {
            l.record(step(0.0), &obs(0.0));
        }
        assert!(l.replayable().is_ok());
        assert_eq!(l.bytes(), 10 * per);
        l.record(step(0.0), &obs(0.0));
        let why = l.replayable().unwrap_err();
        assert!(
            why.contains("bound") && why.contains("11 requests"),
            "{why}"
        );
        assert_eq!((l.len(), l.bytes()), (0, 0), "the memory is freed");
        l.record(step(0.0), &obs(0.0));
        assert!(
            l.replayable().is_err(),
            "steps after the cut are not logged"
        );
        assert_eq!(l.len(), 0);
        // a reset of every env with seeds determines the session again
        l.record(reset(vec![], vec![1, 2]), &obs(0.0));
        assert!(l.replayable().is_ok());
        assert_eq!(l.len(), 1);

        let mut l = log(LogLimits {
            max_entries: 3,
            ..LogLimits::default()
        });
        for _ in 0..3 {
            l.record(step(0.0), &obs(0.0));
        }
        assert!(l.replayable().is_ok());
        l.record(step(0.0), &obs(0.0));
        assert!(l.replayable().is_err());
    }
}
