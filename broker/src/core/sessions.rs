//! Env sessions: which worker hosts each session, which client owns it, and which
//! forwarded requests wait for a worker's reply.
//!
//! The broker gives every session its own id (workers number theirs independently)
//! and every forwarded request its own request id (clients number theirs
//! independently), and maps both back on the reply.

use std::collections::HashMap;

use super::{ClientKey, WorkerKey};

/// One open session.
#[derive(Debug, Clone, PartialEq)]
pub struct Session {
    pub client: ClientKey,
    pub worker: WorkerKey,
    /// The worker's own id for it.
    pub worker_session: u64,
}

/// A request forwarded to a worker, waiting for its reply.
#[derive(Debug, Clone, PartialEq)]
pub struct Pending {
    pub client: ClientKey,
    pub client_request: u64,
    pub worker: WorkerKey,
    /// The broker's session id (0 for an open still waiting for its id).
    pub session: u64,
}

/// What a dead worker leaves behind.
#[derive(Debug, Default, PartialEq)]
pub struct Orphans {
    /// Sessions lost with it: (broker session id, owning client).
    pub sessions: Vec<(u64, ClientKey)>,
    /// Requests that will never be answered by it.
    pub pending: Vec<Pending>,
}

#[derive(Debug, Default)]
pub struct Sessions {
    sessions: HashMap<u64, Session>,
    pending: HashMap<u64, Pending>,
    next_session: u64,
    next_request: u64,
}

impl Sessions {
    pub fn new() -> Self {
        Self {
            next_session: 1,
            next_request: 1,
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

    /// Registers a session the worker opened; returns the broker's id for it.
    pub fn opened(&mut self, client: ClientKey, worker: WorkerKey, worker_session: u64) -> u64 {
        let id = self.next_session;
        self.next_session += 1;
        self.sessions.insert(
            id,
            Session {
                client,
                worker,
                worker_session,
            },
        );
        id
    }

    /// The session `id` if `client` owns it.
    pub fn get(&self, id: u64, client: &[u8]) -> Option<&Session> {
        self.sessions.get(&id).filter(|s| s.client == client)
    }

    pub fn close(&mut self, id: u64) -> Option<Session> {
        self.sessions.remove(&id)
    }

    /// Forgets everything on a worker that died.
    pub fn worker_gone(&mut self, worker: &[u8]) -> Orphans {
        let mut out = Orphans::default();
        self.sessions.retain(|&id, s| {
            if s.worker == worker {
                out.sessions.push((id, s.client.clone()));
                false
            } else {
                true
            }
        });
        self.pending.retain(|_, p| {
            if p.worker == worker {
                out.pending.push(p.clone());
                false
            } else {
                true
            }
        });
        out.sessions.sort_by_key(|(id, _)| *id);
        out.pending.sort_by_key(|p| p.client_request);
        out
    }

    /// Sessions hosted by `worker`.
    pub fn count_on(&self, worker: &[u8]) -> u32 {
        self.sessions
            .values()
            .filter(|s| s.worker == worker)
            .count() as u32
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
    use super::*;

    #[test]
    fn replies_route_back_and_a_dead_worker_orphans_its_sessions() {
        let mut s = Sessions::new();
        let r1 = s.forward(Pending {
            client: b"c1".to_vec(),
            client_request: 5,
            worker: b"w1".to_vec(),
            session: 0,
        });
        let r2 = s.forward(Pending {
            client: b"c2".to_vec(),
            client_request: 5,
            worker: b"w2".to_vec(),
            session: 0,
        });
        assert_ne!(r1, r2, "equal client request ids do not collide");
        assert!(
            s.reply(b"w2", r1).is_none(),
            "only the asked worker answers"
        );
        let p = s.reply(b"w1", r1).unwrap();
        assert_eq!(p.client, b"c1");
        let a = s.opened(b"c1".to_vec(), b"w1".to_vec(), 1);
        let b = s.opened(b"c2".to_vec(), b"w2".to_vec(), 1);
        assert_ne!(a, b, "workers' equal session ids get distinct broker ids");
        assert!(s.get(a, b"c2").is_none(), "a session belongs to its client");
        assert_eq!(s.get(a, b"c1").unwrap().worker_session, 1);
        let orphans = s.worker_gone(b"w2");
        assert_eq!(orphans.sessions, vec![(b, b"c2".to_vec())]);
        assert_eq!(orphans.pending.len(), 1);
        assert_eq!(s.len(), 1);
        assert_eq!(s.count_on(b"w1"), 1);
    }
}
