//! Env sessions: which worker hosts each session, which client owns it, which requests
//! wait for the worker's reply, and the rebuilding of a session on another worker when
//! its worker dies.
//!
//! The broker gives a session its id when the client opens it (an unguessable number the
//! server draws) and sends that id to the worker, so both ends name the session alike and
//! nothing in a request or reply is rewritten on the way. A worker answers a session's
//! requests in the order it got them, so the replies of a session are matched to its
//! requests first in, first out; the request id the client chose travels to the worker
//! and back unchanged.
//!
//! A session's life: `Opening` until its worker answers the open; `Live`; when its worker
//! dies, `Stalled` (its unanswered requests held, in order) until a live worker is found,
//! then `Replaying` there (its open and logged requests sent again, each reply checked
//! against the original by fingerprint, see [`super::replay`]); then `Live` again with
//! the held requests sent. A session that cannot be replayed, finds no worker within
//! [`LogLimits::wait`] or whose replay fails is lost.

use std::collections::{HashMap, VecDeque};
use std::time::Duration;

use paddock_proto::EnvOp;

use super::replay::{LogLimits, Logged, SessionLog};
use super::{ClientKey, Principal, WorkerKey};

/// Where a session stands.
#[derive(Debug, Clone, PartialEq)]
pub enum SessionState {
    /// Its open is on the way to its worker.
    Opening,
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

/// What a request sent to the session's worker was.
#[derive(Debug, Clone, PartialEq)]
pub enum Sent {
    /// The client's open.
    Open,
    /// A client's reset or step, logged when answered.
    Change(Logged),
    /// A client's request that reads the session without changing it (a render).
    Read,
    Close,
    /// The open of a replay.
    ReplayOpen,
    /// Request `index` of a replay's log.
    Replay(usize),
}

/// A request sent to a worker and not answered yet.
#[derive(Debug, Clone, PartialEq)]
pub struct Pending {
    /// The client's request id (0 for a replay's own requests).
    pub client_request: u64,
    pub sent: Sent,
}

/// A client request held while its session is not live: sent when it is live again.
#[derive(Debug, Clone, PartialEq)]
pub struct Held {
    pub client_request: u64,
    /// The request's op (`paddock_proto::EnvOp`).
    pub op: i32,
    pub payload: Vec<u8>,
}

/// One session.
#[derive(Debug, Clone)]
pub struct Session {
    /// Where its replies go: the routing id of the owner's latest connection.
    pub client: ClientKey,
    /// Who owns it (see [`super::Principal`]): only requests of this principal reach it.
    pub owner: Principal,
    /// When a request of its client last arrived (broker time).
    pub last_used: Duration,
    pub worker: WorkerKey,
    pub state: SessionState,
    pub log: SessionLog,
    /// Requests sent to the worker, oldest first.
    pending: VecDeque<Pending>,
    /// Client requests held while it is not live, in arrival order.
    held: VecDeque<Held>,
}

impl Session {
    /// Requests held while the session is not live.
    pub fn held(&self) -> usize {
        self.held.len()
    }
}

/// A session that is gone for good, with the client requests that will never be
/// answered.
#[derive(Debug, Clone, PartialEq)]
pub struct Lost {
    pub session: u64,
    pub client: ClientKey,
    /// Why, for the client ("... was lost: ...").
    pub reason: String,
    pub requests: Vec<u64>,
}

/// What a dead worker leaves behind.
#[derive(Debug, Default, PartialEq)]
pub struct Orphans {
    /// Sessions lost with it (not replayable, or still opening).
    pub lost: Vec<Lost>,
    /// Sessions waiting to be rebuilt elsewhere.
    pub stalled: Vec<u64>,
}

/// Where a client's request on session `id` goes.
#[derive(Debug, Clone, PartialEq)]
pub enum Route {
    /// To this worker, now.
    Send(WorkerKey),
    /// Held until the session is live again ([`Sessions::hold`]).
    Hold,
    /// No such session for this client.
    Unknown,
}

/// What to do with a worker's reply.
#[derive(Debug, PartialEq)]
pub enum Reply {
    /// Forward it to `client` under its request id.
    Forward { client: ClientKey, request: u64 },
    /// A replayed reply checked; more to come.
    Continue,
    /// Send these logged requests of a replay (index, request).
    Send(Vec<(usize, Logged)>),
    /// Rebuilt: the session is live again; send these held requests in order.
    Done(Vec<Held>),
    /// The replay failed: the session is lost.
    Failed(Lost),
    /// Not a reply anything waits for (late, from another worker, its session gone).
    Ignore,
}

/// The header facts of a worker's reply the sessions need.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReplyHead {
    pub op: i32,
    pub fingerprint: u64,
    pub restart: bool,
    /// The worker refused the request (`EnvReply.error`), with no payload.
    pub error: bool,
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
    limits: LogLimits,
    stats: ReplayStats,
}

impl Sessions {
    pub fn new(limits: LogLimits) -> Self {
        Self {
            limits,
            ..Self::default()
        }
    }

    /// Registers session `id` (drawn by the caller, unused) being opened by `client`
    /// (owned by `owner`) on `worker` with the open request `open` (its payload), sent
    /// under `request` at `now`.
    pub fn open(
        &mut self,
        id: u64,
        client: (ClientKey, Principal),
        worker: WorkerKey,
        open: Vec<u8>,
        request: u64,
        now: Duration,
    ) {
        let (client, owner) = client;
        self.sessions.insert(
            id,
            Session {
                client,
                owner,
                last_used: now,
                worker,
                state: SessionState::Opening,
                log: SessionLog::new(open, self.limits),
                pending: VecDeque::from([Pending {
                    client_request: request,
                    sent: Sent::Open,
                }]),
                held: VecDeque::new(),
            },
        );
    }

    /// Whether id `id` names a session (open or being opened).
    pub fn contains(&self, id: u64) -> bool {
        self.sessions.contains_key(&id)
    }

    /// The session `id` if `owner` owns it.
    pub fn get(&self, id: u64, owner: &str) -> Option<&Session> {
        self.sessions.get(&id).filter(|s| s.owner == owner)
    }

    /// Sessions `owner` holds.
    pub fn owned_by(&self, owner: &str) -> usize {
        self.sessions.values().filter(|s| s.owner == owner).count()
    }

    /// Live sessions no request has reached for `idle` or longer at `now`, with nothing
    /// on the way to their worker, oldest first.
    pub fn idle(&self, now: Duration, idle: Duration) -> Vec<u64> {
        let mut ids: Vec<(Duration, u64)> = self
            .sessions
            .iter()
            .filter(|(_, s)| {
                s.state == SessionState::Live
                    && s.pending.is_empty()
                    && now.saturating_sub(s.last_used) >= idle
            })
            .map(|(&id, s)| (s.last_used, id))
            .collect();
        ids.sort_unstable();
        ids.into_iter().map(|(_, id)| id).collect()
    }

    /// Ends session `id` for good with `reason` (an idle session expired): the session
    /// and the worker that hosted it, or None when there is no such session.
    pub fn expire(&mut self, id: u64, reason: String) -> Option<(Lost, WorkerKey)> {
        let worker = self.sessions.get(&id)?.worker.clone();
        self.lose(id, reason).map(|l| (l, worker))
    }

    /// Session `id`, whoever owns it.
    pub fn session(&self, id: u64) -> Option<&Session> {
        self.sessions.get(&id)
    }

    /// Where the request of `client` (principal `owner`) on session `id`, arrived at
    /// `now`, goes. Only the owner reaches a session; an owner that reconnected (the
    /// same CURVE key, a new routing id) gets the replies on its new connection.
    pub fn route(&mut self, id: u64, client: &[u8], owner: &str, now: Duration) -> Route {
        let Some(s) = self.sessions.get_mut(&id).filter(|s| s.owner == owner) else {
            return Route::Unknown;
        };
        s.last_used = now;
        if s.client != client {
            s.client = client.to_vec();
        }
        if s.state == SessionState::Live {
            Route::Send(s.worker.clone())
        } else {
            Route::Hold
        }
    }

    /// Records a request sent to session `id`'s worker.
    pub fn sent(&mut self, id: u64, p: Pending) {
        if let Some(s) = self.sessions.get_mut(&id) {
            s.pending.push_back(p);
        }
    }

    /// Holds a client request until session `id` is live again.
    pub fn hold(&mut self, id: u64, h: Held) {
        if let Some(s) = self.sessions.get_mut(&id) {
            s.held.push_back(h);
        }
    }

    /// What to do with `worker`'s reply on session `id`.
    pub fn reply(&mut self, id: u64, worker: &[u8], head: ReplyHead) -> Reply {
        let Some(s) = self.sessions.get_mut(&id) else {
            return Reply::Ignore;
        };
        if s.worker != worker {
            return Reply::Ignore;
        }
        let Some(p) = s.pending.pop_front() else {
            return Reply::Ignore;
        };
        match p.sent {
            Sent::ReplayOpen | Sent::Replay(_) => self.replay_reply(id, p.sent, head),
            Sent::Open => {
                let client = s.client.clone();
                if head.error {
                    self.sessions.remove(&id);
                } else {
                    s.state = SessionState::Live;
                }
                Reply::Forward {
                    client,
                    request: p.client_request,
                }
            }
            Sent::Change(request) => {
                if !head.error {
                    s.log.record(request, head.fingerprint, head.restart);
                }
                Reply::Forward {
                    client: s.client.clone(),
                    request: p.client_request,
                }
            }
            Sent::Read => Reply::Forward {
                client: s.client.clone(),
                request: p.client_request,
            },
            Sent::Close => {
                let client = s.client.clone();
                if !head.error {
                    self.sessions.remove(&id);
                }
                Reply::Forward {
                    client,
                    request: p.client_request,
                }
            }
        }
    }

    fn replay_reply(&mut self, id: u64, sent: Sent, head: ReplyHead) -> Reply {
        let Some(s) = self.sessions.get_mut(&id) else {
            return Reply::Ignore;
        };
        let SessionState::Replaying { opened, answered } = &mut s.state else {
            return Reply::Ignore;
        };
        let failure = if head.error {
            Some(format!(
                "replaying it on another worker failed at {} (the worker refused it)",
                match sent {
                    Sent::ReplayOpen => "the open".to_string(),
                    Sent::Replay(i) => format!("request {} of {}", i + 1, s.log.len()),
                    _ => "a request".to_string(),
                }
            ))
        } else {
            match sent {
                Sent::ReplayOpen if !*opened && head.op == EnvOp::EnvOpen as i32 => {
                    *opened = true;
                    if !s.log.is_empty() {
                        let sends = (0..s.log.len())
                            .filter_map(|i| s.log.request(i).map(|r| (i, r.clone())))
                            .collect();
                        return Reply::Send(sends);
                    }
                    None
                }
                Sent::Replay(i) if i == *answered => {
                    if s.log.matches(i, head.fingerprint) {
                        *answered += 1;
                        if *answered < s.log.len() {
                            return Reply::Continue;
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
                _ => Some(format!(
                    "replaying it on another worker got an unexpected {} reply",
                    paddock_proto::op_name(head.op)
                )),
            }
        };
        match failure {
            None => {
                s.state = SessionState::Live;
                self.stats.replayed += 1;
                Reply::Done(s.held.drain(..).collect())
            }
            Some(why) => {
                let reason = format!("env session {id} was lost: its worker died and {why}");
                match self.lose(id, reason) {
                    Some(lost) => Reply::Failed(lost),
                    None => Reply::Ignore,
                }
            }
        }
    }

    /// Takes in the sessions of a worker that died at `now`: replayable sessions wait
    /// for another worker with their unanswered client requests held; the others (and
    /// sessions still opening) are lost.
    pub fn worker_gone(&mut self, worker: &[u8], now: Duration) -> Orphans {
        let mut out = Orphans::default();
        let mut ids: Vec<u64> = self
            .sessions
            .iter()
            .filter(|(_, s)| s.worker == worker && !matches!(s.state, SessionState::Stalled { .. }))
            .map(|(&id, _)| id)
            .collect();
        ids.sort_unstable();
        for id in ids {
            let Some(s) = self.sessions.get_mut(&id) else {
                continue;
            };
            if s.state == SessionState::Opening {
                let reason = format!(
                    "the env session being opened (id {id}) was lost: its worker died before answering"
                );
                if let Some(lost) = self.lose(id, reason) {
                    out.lost.push(lost);
                }
                continue;
            }
            match s.log.replayable() {
                Ok(()) => {
                    // requests sent before the death go first, in the order sent; a
                    // replay's own requests are dropped (the replay starts over)
                    let mut held: VecDeque<Held> = s
                        .pending
                        .drain(..)
                        .filter_map(|p| {
                            let (op, payload) = match p.sent {
                                Sent::Change(l) => (l.op, l.payload),
                                Sent::Read | Sent::Close => (resend_op(&p.sent), Vec::new()),
                                _ => return None,
                            };
                            Some(Held {
                                client_request: p.client_request,
                                op,
                                payload,
                            })
                        })
                        .collect();
                    held.extend(s.held.drain(..));
                    s.held = held;
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
        out
    }

    /// Removes session `id` as lost, with the client requests it held or had in flight.
    fn lose(&mut self, id: u64, reason: String) -> Option<Lost> {
        let s = self.sessions.remove(&id)?;
        if s.state != SessionState::Opening {
            self.stats.lost += 1;
        }
        let mut requests: Vec<u64> = s
            .pending
            .iter()
            .filter(|p| !matches!(p.sent, Sent::ReplayOpen | Sent::Replay(_)))
            .map(|p| p.client_request)
            .collect();
        requests.extend(s.held.iter().map(|h| h.client_request));
        Some(Lost {
            session: id,
            client: s.client,
            reason,
            requests,
        })
    }

    /// Sessions waiting for a worker to be rebuilt on, oldest first.
    pub fn stalled(&self) -> Vec<u64> {
        let mut ids: Vec<(Duration, u64)> = self
            .sessions
            .iter()
            .filter_map(|(&id, s)| match s.state {
                SessionState::Stalled { since } => Some((since, id)),
                _ => None,
            })
            .collect();
        ids.sort_unstable();
        ids.into_iter().map(|(_, id)| id).collect()
    }

    /// Starts rebuilding stalled session `id` on `worker`: the open request to send there
    /// (recorded as a replay's open).
    pub fn start_replay(&mut self, id: u64, worker: WorkerKey) -> Option<Vec<u8>> {
        let s = self.sessions.get_mut(&id)?;
        if !matches!(s.state, SessionState::Stalled { .. }) {
            return None;
        }
        s.worker = worker;
        s.state = SessionState::Replaying {
            opened: false,
            answered: 0,
        };
        s.pending = VecDeque::from([Pending {
            client_request: 0,
            sent: Sent::ReplayOpen,
        }]);
        Some(s.log.open().to_vec())
    }

    /// Records the replay requests sent after a replay's open.
    pub fn replay_sent(&mut self, id: u64, indices: impl IntoIterator<Item = usize>) {
        if let Some(s) = self.sessions.get_mut(&id) {
            s.pending.extend(indices.into_iter().map(|i| Pending {
                client_request: 0,
                sent: Sent::Replay(i),
            }));
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

/// The op a held read or close is sent again with.
fn resend_op(sent: &Sent) -> i32 {
    match sent {
        Sent::Read => EnvOp::EnvRender as i32,
        _ => EnvOp::EnvClose as i32,
    }
}

#[cfg(test)]
mod tests;
