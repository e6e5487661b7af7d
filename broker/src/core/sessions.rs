//! Env sessions: which worker hosts each session, which client owns it, which
//! forwarded requests wait for a worker's reply, and the rebuilding of a session on
//! another worker when its worker dies.
//!
//! The broker gives every session its own id (workers number theirs independently)
//! and every forwarded request its own request id (clients number theirs
//! independently), and maps both back on the reply.
//!
//! A session's life: `Live` on its worker; when that worker dies, `Stalled` (its
//! unanswered requests held, in order) until a live worker is found, then `Replaying`
//! there (its open and logged requests sent again, each reply checked against the
//! original, see [`super::replay`]); then `Live` again with the held requests sent.
//! A session that cannot be replayed, finds no worker within [`LogLimits::wait`] or
//! whose replay fails is lost.

use std::collections::{HashMap, VecDeque};
use std::time::Duration;

use paddock_proto::{Body, EnvOpen};

use super::replay::{EnvRequest, LogLimits, SessionLog};
use super::{ClientKey, WorkerKey};

/// Where a session stands.
#[derive(Debug, Clone, PartialEq)]
pub enum SessionState {
    Live,
    /// Its worker is gone; waiting since `since` for a worker to rebuild it on.
    Stalled {
        since: Duration,
    },
    /// Being rebuilt on its (new) worker; `answered` logged requests checked so far.
    Replaying {
        opened: bool,
        answered: usize,
    },
}

/// One open session.
#[derive(Debug, Clone)]
pub struct Session {
    pub client: ClientKey,
    pub worker: WorkerKey,
    /// The worker's own id for it.
    pub worker_session: u64,
    pub state: SessionState,
    pub log: SessionLog,
    /// Client requests held while it is not live, in arrival order.
    queued: VecDeque<Queued>,
}

/// What a forwarded request was.
#[derive(Debug, Clone, PartialEq)]
pub enum Forwarded {
    /// A client's open, waiting for the worker's session id.
    Open(EnvOpen),
    /// A client's reset or step, logged when answered.
    Request(EnvRequest),
    /// A client's request that reads the session without changing it (a render):
    /// forwarded with the worker's session id, never logged for replay.
    Read(Body),
    Close,
    /// The open of a replay.
    ReplayOpen,
    /// Request `index` of a replay's log.
    Replay(usize),
}

impl Forwarded {
    /// The message for the worker; `None` for an open (sent as is) or replay.
    pub fn to_body(&self, worker_session: u64) -> Option<Body> {
        match self {
            Forwarded::Request(r) => Some(r.to_body(worker_session)),
            Forwarded::Read(body) => {
                let mut body = body.clone();
                if let Body::EnvRender(r) = &mut body {
                    r.session_id = worker_session;
                }
                Some(body)
            }
            Forwarded::Close => Some(Body::EnvClose(paddock_proto::EnvClose {
                session_id: worker_session,
            })),
            _ => None,
        }
    }
}

/// A request forwarded to a worker, waiting for its reply.
#[derive(Debug, Clone, PartialEq)]
pub struct Pending {
    pub client: ClientKey,
    /// The client's request id (0 for a replay's own requests).
    pub client_request: u64,
    pub worker: WorkerKey,
    /// The broker's session id (0 for an open still waiting for its id).
    pub session: u64,
    pub what: Forwarded,
}

/// A client request held while its session is being rebuilt.
#[derive(Debug, Clone, PartialEq)]
pub struct Queued {
    pub client_request: u64,
    pub what: Forwarded,
}

/// A session that is gone for good, with the requests that will never be answered.
#[derive(Debug, Clone, PartialEq)]
pub struct Lost {
    pub session: u64,
    pub client: ClientKey,
    /// Why, for the client ("... was lost: ...").
    pub reason: String,
    pub queued: Vec<Queued>,
}

/// What a dead worker leaves behind.
#[derive(Debug, Default, PartialEq)]
pub struct Orphans {
    /// Sessions lost with it (not replayable).
    pub lost: Vec<Lost>,
    /// Sessions waiting to be rebuilt elsewhere.
    pub stalled: Vec<u64>,
    /// Requests that will never be answered: opens in flight and requests of lost
    /// sessions.
    pub pending: Vec<Pending>,
}

/// The next move of a replay.
#[derive(Debug, PartialEq)]
pub enum ReplayStep {
    /// Send these logged requests (index, message with the worker's session id).
    Send(Vec<(usize, Body)>),
    /// A replayed reply checked; more to come.
    Continue,
    /// Rebuilt: the session is live again; send these held requests in order.
    Done(Vec<Queued>),
    /// Not an answer of a running replay (late, or its session is gone): drop it.
    Ignore,
    /// The replay failed: the session is lost.
    Failed(Lost),
}

/// Replay counters, for the broker status.
#[derive(Debug, Default, Clone, Copy, PartialEq)]
pub struct ReplayStats {
    /// Sessions rebuilt on another worker.
    pub replayed: u64,
    /// Sessions lost with their worker (not replayable, no worker, or replay failed).
    pub lost: u64,
}

#[derive(Debug, Default)]
pub struct Sessions {
    sessions: HashMap<u64, Session>,
    pending: HashMap<u64, Pending>,
    next_session: u64,
    next_request: u64,
    limits: LogLimits,
    stats: ReplayStats,
}

impl Sessions {
    pub fn new(limits: LogLimits) -> Self {
        Self {
            next_session: 1,
            next_request: 1,
            limits,
            ..Self::default()
        }
    }

    /// Records a request forwarded to `worker`; returns the request id to use.
    pub fn forward(&mut self, p: Pending) -> u64 {
        let id = self.next_request;
        self.next_request += 1;
        self.pending.insert(id, p);
        id
    }

    /// The waiting request a worker's reply answers (removed), if it came from the
    /// worker it was sent to.
    pub fn reply(&mut self, worker: &[u8], request: u64) -> Option<Pending> {
        match self.pending.get(&request) {
            Some(p) if p.worker == worker => self.pending.remove(&request),
            _ => None,
        }
    }

    /// Registers a session the worker opened for `open` (of `num_envs` envs); returns
    /// the broker's id for it.
    pub fn opened(
        &mut self,
        client: ClientKey,
        worker: WorkerKey,
        worker_session: u64,
        open: EnvOpen,
        num_envs: usize,
    ) -> u64 {
        let id = self.next_session;
        self.next_session += 1;
        self.sessions.insert(
            id,
            Session {
                client,
                worker,
                worker_session,
                state: SessionState::Live,
                log: SessionLog::new(open, num_envs, self.limits),
                queued: VecDeque::new(),
            },
        );
        id
    }

    /// The session `id` if `client` owns it.
    pub fn get(&self, id: u64, client: &[u8]) -> Option<&Session> {
        self.sessions.get(&id).filter(|s| s.client == client)
    }

    /// Session `id`, whoever owns it.
    pub fn session(&self, id: u64) -> Option<&Session> {
        self.sessions.get(&id)
    }

    /// Logs a request the session's worker answered with `reply`.
    pub fn record(&mut self, id: u64, request: EnvRequest, reply: &paddock_proto::EnvObservation) {
        if let Some(s) = self.sessions.get_mut(&id) {
            s.log.record(request, reply);
        }
    }

    /// Holds a client request until session `id` is live again.
    pub fn hold(&mut self, id: u64, q: Queued) {
        if let Some(s) = self.sessions.get_mut(&id) {
            s.queued.push_back(q);
        }
    }

    pub fn close(&mut self, id: u64) -> Option<Session> {
        self.sessions.remove(&id)
    }

    /// Takes in the sessions and requests of a worker that died at `now`: replayable
    /// sessions wait for another worker with their unanswered requests held; the
    /// others are lost.
    pub fn worker_gone(&mut self, worker: &[u8], now: Duration) -> Orphans {
        let mut out = Orphans::default();
        let mut ids: Vec<u64> = self
            .sessions
            .iter()
            .filter(|(_, s)| s.worker == worker)
            .map(|(&id, _)| id)
            .collect();
        ids.sort_unstable();
        let mut orphaned: Vec<(u64, Pending)> = Vec::new();
        self.pending.retain(|&rid, p| {
            if p.worker == worker {
                orphaned.push((rid, p.clone()));
                false
            } else {
                true
            }
        });
        orphaned.sort_by_key(|(rid, _)| *rid);
        for id in ids {
            let Some(s) = self.sessions.get_mut(&id) else {
                continue;
            };
            match s.log.replayable() {
                Ok(()) => {
                    // requests sent before the death go first, in the order sent
                    let mut held: VecDeque<Queued> = orphaned
                        .iter()
                        .filter(|(_, p)| p.session == id)
                        .filter(|(_, p)| {
                            matches!(
                                p.what,
                                Forwarded::Request(_) | Forwarded::Read(_) | Forwarded::Close
                            )
                        })
                        .map(|(_, p)| Queued {
                            client_request: p.client_request,
                            what: p.what.clone(),
                        })
                        .collect();
                    held.extend(s.queued.drain(..));
                    s.queued = held;
                    s.state = SessionState::Stalled { since: now };
                    out.stalled.push(id);
                }
                Err(why) => {
                    let reason = format!("env session {id} was lost: its worker died and {why}");
                    if let Some(lost) = self.lose(id, reason) {
                        out.lost.push(lost);
                    }
                }
            }
        }
        for (_, p) in orphaned {
            let client_request = matches!(p.what, Forwarded::Open(_))
                || (matches!(
                    p.what,
                    Forwarded::Request(_) | Forwarded::Read(_) | Forwarded::Close
                ) && !self.sessions.contains_key(&p.session));
            if client_request {
                out.pending.push(p);
            }
        }
        out
    }

    /// Removes session `id` as lost, with its held requests.
    fn lose(&mut self, id: u64, reason: String) -> Option<Lost> {
        let s = self.sessions.remove(&id)?;
        self.pending.retain(|_, p| {
            p.session != id || !matches!(p.what, Forwarded::ReplayOpen | Forwarded::Replay(_))
        });
        self.stats.lost += 1;
        Some(Lost {
            session: id,
            client: s.client,
            reason,
            queued: s.queued.into(),
        })
    }

    /// Sessions waiting for a worker to be rebuilt on, oldest id first.
    pub fn stalled(&self) -> Vec<u64> {
        let mut ids: Vec<u64> = self
            .sessions
            .iter()
            .filter(|(_, s)| matches!(s.state, SessionState::Stalled { .. }))
            .map(|(&id, _)| id)
            .collect();
        ids.sort_unstable();
        ids
    }

    /// Starts rebuilding stalled session `id` on `worker`: the open to forward there
    /// (as [`Forwarded::ReplayOpen`]).
    pub fn start_replay(&mut self, id: u64, worker: WorkerKey) -> Option<EnvOpen> {
        let s = self.sessions.get_mut(&id)?;
        if !matches!(s.state, SessionState::Stalled { .. }) {
            return None;
        }
        s.worker = worker;
        s.state = SessionState::Replaying {
            opened: false,
            answered: 0,
        };
        Some(s.log.open().clone())
    }

    /// A worker's answer to a replay request `what` of session `id`.
    pub fn replay_reply(&mut self, id: u64, what: &Forwarded, reply: &Body) -> ReplayStep {
        let Some(s) = self.sessions.get_mut(&id) else {
            return ReplayStep::Ignore;
        };
        let SessionState::Replaying { opened, answered } = &mut s.state else {
            return ReplayStep::Ignore;
        };
        let failure = match (what, reply) {
            (Forwarded::ReplayOpen, Body::EnvOpened(o)) if !*opened => {
                *opened = true;
                s.worker_session = o.session_id;
                if s.log.is_empty() {
                    None
                } else {
                    let wsid = o.session_id;
                    let sends = (0..s.log.len())
                        .filter_map(|i| s.log.request(i).map(|r| (i, r.to_body(wsid))))
                        .collect();
                    return ReplayStep::Send(sends);
                }
            }
            (Forwarded::Replay(i), Body::EnvObservation(o)) if *i == *answered => {
                if s.log.matches(*i, o) {
                    *answered += 1;
                    if *answered < s.log.len() {
                        return ReplayStep::Continue;
                    }
                    None
                } else {
                    Some(format!(
                        "replaying it on another worker gave a different observation at request {} of {} (the workers disagree: different versions?)",
                        i + 1,
                        s.log.len()
                    ))
                }
            }
            (_, Body::Error(e)) => Some(format!(
                "replaying it on another worker failed: {} ({})",
                e.message, e.field
            )),
            (_, other) => Some(format!(
                "replaying it on another worker got an unexpected {}",
                paddock_proto::body_name(other)
            )),
        };
        match failure {
            None => {
                s.state = SessionState::Live;
                self.stats.replayed += 1;
                ReplayStep::Done(s.queued.drain(..).collect())
            }
            Some(why) => {
                let reason = format!("env session {id} was lost: its worker died and {why}");
                match self.lose(id, reason) {
                    Some(lost) => ReplayStep::Failed(lost),
                    None => ReplayStep::Ignore,
                }
            }
        }
    }

    /// Sessions that waited longer than [`LogLimits::wait`] for a worker: lost.
    pub fn tick(&mut self, now: Duration) -> Vec<Lost> {
        let wait = self.limits.wait;
        let mut expired: Vec<u64> = self
            .sessions
            .iter()
            .filter(|(_, s)| {
                matches!(s.state, SessionState::Stalled { since } if now.saturating_sub(since) >= wait)
            })
            .map(|(&id, _)| id)
            .collect();
        expired.sort_unstable();
        expired
            .into_iter()
            .filter_map(|id| {
                let reason = format!(
                    "env session {id} was lost: its worker died and no other worker was available within {wait:?} to rebuild it on"
                );
                self.lose(id, reason)
            })
            .collect()
    }

    /// Sessions hosted by `worker`.
    pub fn count_on(&self, worker: &[u8]) -> u32 {
        self.sessions
            .values()
            .filter(|s| s.worker == worker && !matches!(s.state, SessionState::Stalled { .. }))
            .count() as u32
    }

    pub fn stats(&self) -> ReplayStats {
        self.stats
    }

    pub fn len(&self) -> usize {
        self.sessions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.sessions.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use paddock_proto::{EnvObservation, EnvOpened, EnvStep, pack_f32, pack_f64};

    use super::*;

    fn pending(client: &[u8], rid: u64, worker: &[u8], session: u64, what: Forwarded) -> Pending {
        Pending {
            client: client.to_vec(),
            client_request: rid,
            worker: worker.to_vec(),
            session,
            what,
        }
    }

    fn step(a: f32) -> EnvRequest {
        EnvRequest::Step(EnvStep {
            session_id: 0,
            actions: pack_f32(&[0.0, a]),
            reset_envs: vec![],
        })
    }

    fn obs(t: f64) -> EnvObservation {
        EnvObservation {
            num_envs: 1,
            time: pack_f64(&[t]),
            ..Default::default()
        }
    }

    fn opened(id: u64) -> Body {
        Body::EnvOpened(EnvOpened {
            session_id: id,
            ..Default::default()
        })
    }

    fn secs(x: f64) -> Duration {
        Duration::from_secs_f64(x)
    }

    #[test]
    fn replies_route_back_and_a_dead_worker_orphans_its_sessions() {
        let mut s = Sessions::new(LogLimits::default());
        let open = Forwarded::Open(EnvOpen::default());
        let r1 = s.forward(pending(b"c1", 5, b"w1", 0, open.clone()));
        let r2 = s.forward(pending(b"c2", 5, b"w2", 0, open.clone()));
        assert_ne!(r1, r2, "equal client request ids do not collide");
        assert!(
            s.reply(b"w2", r1).is_none(),
            "only the asked worker answers"
        );
        let p = s.reply(b"w1", r1).expect("w1 answers its own request");
        assert_eq!(p.client, b"c1");
        let a = s.opened(b"c1".to_vec(), b"w1".to_vec(), 1, EnvOpen::default(), 1);
        let b = s.opened(b"c2".to_vec(), b"w2".to_vec(), 1, EnvOpen::default(), 1);
        assert_ne!(a, b, "workers' equal session ids get distinct broker ids");
        assert!(s.get(a, b"c2").is_none(), "a session belongs to its client");
        assert_eq!(
            s.get(a, b"c1").expect("c1 owns session a").worker_session,
            1
        );
        let orphans = s.worker_gone(b"w2", secs(1.0));
        assert_eq!(orphans.stalled, vec![b], "a replayable session waits");
        assert_eq!(orphans.pending.len(), 1, "the open in flight is answered");
        assert_eq!(s.len(), 2);
        assert_eq!((s.count_on(b"w1"), s.count_on(b"w2")), (1, 0));
    }

    /// A session with a logged history on w1; w1 dies with one step in flight and a
    /// second step arrives while the session is stalled.
    fn stalled_session() -> (Sessions, u64) {
        let mut s = Sessions::new(LogLimits::default());
        let id = s.opened(b"c".to_vec(), b"w1".to_vec(), 7, EnvOpen::default(), 1);
        for k in 1..=3 {
            let rid = s.forward(pending(
                b"c",
                k,
                b"w1",
                id,
                Forwarded::Request(step(k as f32)),
            ));
            let p = s.reply(b"w1", rid).expect("w1 answers the step");
            let Forwarded::Request(r) = p.what else {
                panic!("a client request")
            };
            s.record(id, r, &obs(0.01 * k as f64));
        }
        s.forward(pending(b"c", 4, b"w1", id, Forwarded::Request(step(4.0))));
        let orphans = s.worker_gone(b"w1", secs(10.0));
        assert_eq!(orphans.stalled, vec![id]);
        assert!(orphans.pending.is_empty() && orphans.lost.is_empty());
        s.hold(
            id,
            Queued {
                client_request: 5,
                what: Forwarded::Request(step(5.0)),
            },
        );
        (s, id)
    }

    #[test]
    fn a_render_in_flight_when_its_worker_dies_is_held_and_never_logged() {
        let mut s = Sessions::new(LogLimits::default());
        let id = s.opened(b"c".to_vec(), b"w1".to_vec(), 7, EnvOpen::default(), 1);
        let rid = s.forward(pending(b"c", 1, b"w1", id, Forwarded::Request(step(1.0))));
        let p = s.reply(b"w1", rid).unwrap();
        let Forwarded::Request(r) = p.what else {
            panic!("a client request")
        };
        s.record(id, r, &obs(0.01));
        let render = Forwarded::Read(Body::EnvRender(paddock_proto::EnvRender {
            session_id: id,
            envs: vec![0],
            width: 320,
        }));
        // sent with the worker's own session id
        match render.to_body(7) {
            Some(Body::EnvRender(r)) => {
                assert_eq!((r.session_id, r.envs, r.width), (7, vec![0], 320))
            }
            other => panic!("{other:?}"),
        }
        let rid = s.forward(pending(b"c", 2, b"w1", id, render.clone()));
        let orphans = s.worker_gone(b"w1", secs(10.0));
        assert_eq!(orphans.stalled, vec![id]);
        assert!(orphans.pending.is_empty(), "held, not answered as lost");
        assert!(s.reply(b"w1", rid).is_none());
        let session = s.session(id).unwrap();
        assert_eq!(session.log.len(), 1, "a render is not logged");
        assert_eq!(session.queued.len(), 1);
        assert_eq!(session.queued[0].what, render);
    }

    #[test]
    fn a_stalled_session_is_replayed_on_another_worker_then_its_held_requests_go() {
        let (mut s, id) = stalled_session();
        assert_eq!(s.stalled(), vec![id]);
        assert!(s.tick(secs(14.9)).is_empty(), "still within the wait");
        assert!(s.start_replay(id, b"w2".to_vec()).is_some());
        assert!(s.stalled().is_empty());
        assert!(
            s.tick(secs(100.0)).is_empty(),
            "a running replay does not expire"
        );
        let ReplayStep::Send(sends) = s.replay_reply(id, &Forwarded::ReplayOpen, &opened(3)) else {
            panic!("the log is sent after the open");
        };
        assert_eq!(sends.len(), 3);
        for (i, (k, body)) in sends.iter().enumerate() {
            assert_eq!(*k, i);
            let Body::EnvStep(st) = body else {
                panic!("a step")
            };
            assert_eq!(st.session_id, 3, "the new worker's session id");
        }
        let reply = |t: f64| Body::EnvObservation(obs(t));
        assert_eq!(
            s.replay_reply(id, &Forwarded::Replay(0), &reply(0.01)),
            ReplayStep::Continue
        );
        assert_eq!(
            s.replay_reply(id, &Forwarded::Replay(1), &reply(0.02)),
            ReplayStep::Continue
        );
        let ReplayStep::Done(held) = s.replay_reply(id, &Forwarded::Replay(2), &reply(0.03)) else {
            panic!("rebuilt");
        };
        let order: Vec<u64> = held.iter().map(|q| q.client_request).collect();
        assert_eq!(order, vec![4, 5], "in flight first, then the held one");
        let live = s.get(id, b"c").expect("the rebuilt session is open");
        assert_eq!(
            (live.worker.as_slice(), live.worker_session),
            (&b"w2"[..], 3)
        );
        assert_eq!(live.state, SessionState::Live);
        assert_eq!(
            s.stats(),
            ReplayStats {
                replayed: 1,
                lost: 0
            }
        );
        assert_eq!(
            s.replay_reply(id, &Forwarded::Replay(2), &reply(0.03)),
            ReplayStep::Ignore,
            "a late duplicate is dropped"
        );
    }

    #[test]
    fn a_replay_that_diverges_or_fails_loses_the_session() {
        let (mut s, id) = stalled_session();
        s.start_replay(id, b"w2".to_vec());
        s.replay_reply(id, &Forwarded::ReplayOpen, &opened(3));
        let ReplayStep::Failed(lost) =
            s.replay_reply(id, &Forwarded::Replay(0), &Body::EnvObservation(obs(0.5)))
        else {
            panic!("a different observation fails the replay");
        };
        assert!(
            lost.reason
                .contains("different observation at request 1 of 3"),
            "{}",
            lost.reason
        );
        assert_eq!(
            lost.queued.len(),
            2,
            "the held requests are answered with the loss"
        );
        assert!(s.get(id, b"c").is_none());

        let (mut s, id) = stalled_session();
        s.start_replay(id, b"w2".to_vec());
        let e = paddock_proto::error(
            paddock_proto::ErrorCode::NotFound,
            "env_open.map.hash",
            "no map",
        );
        let ReplayStep::Failed(lost) = s.replay_reply(id, &Forwarded::ReplayOpen, &Body::Error(e))
        else {
            panic!("an error fails the replay");
        };
        assert!(lost.reason.contains("no map"), "{}", lost.reason);
        assert_eq!(s.stats().lost, 1);
    }

    #[test]
    fn the_replay_worker_dying_too_stalls_the_session_again() {
        let (mut s, id) = stalled_session();
        s.start_replay(id, b"w2".to_vec());
        let rid = s.forward(pending(b"c", 0, b"w2", id, Forwarded::ReplayOpen));
        let orphans = s.worker_gone(b"w2", secs(12.0));
        assert_eq!(orphans.stalled, vec![id]);
        assert!(
            orphans.pending.is_empty(),
            "replay requests are not the client's"
        );
        assert!(s.reply(b"w2", rid).is_none());
        assert_eq!(
            s.get(id, b"c")
                .expect("the stalled session is kept")
                .queued
                .len(),
            2,
            "held requests kept"
        );
        // no third worker within the wait: lost, naming why
        assert!(s.tick(secs(16.9)).is_empty());
        let lost = s.tick(secs(17.0));
        assert_eq!(lost.len(), 1);
        assert!(
            lost[0].reason.contains("no other worker"),
            "{}",
            lost[0].reason
        );
        assert_eq!(lost[0].queued.len(), 2);
        assert!(s.is_empty());
    }

    #[test]
    fn a_session_past_its_log_bound_is_lost_with_its_worker() {
        let mut s = Sessions::new(LogLimits {
            max_entries: 2,
            ..LogLimits::default()
        });
        let id = s.opened(b"c".to_vec(), b"w1".to_vec(), 1, EnvOpen::default(), 1);
        for k in 0..3 {
            s.record(id, step(k as f32), &obs(0.0));
        }
        let in_flight = s.forward(pending(b"c", 9, b"w1", id, Forwarded::Request(step(9.0))));
        let orphans = s.worker_gone(b"w1", secs(1.0));
        assert!(orphans.stalled.is_empty());
        assert_eq!(orphans.lost.len(), 1);
        assert!(
            orphans.lost[0]
                .reason
                .contains("replay log reached its bound"),
            "{}",
            orphans.lost[0].reason
        );
        assert_eq!(
            orphans.pending.len(),
            1,
            "its request in flight is answered"
        );
        assert_eq!(orphans.pending[0].client_request, 9);
        assert!(s.reply(b"w1", in_flight).is_none());
        assert_eq!(s.stats().lost, 1);
    }
}
