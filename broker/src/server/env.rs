//! Env sessions: opening on a worker, routing reset/step/close and their replies, and
//! the errors clients get when the hosting worker is gone.

use paddock_proto::{Body, EnvClosed, ErrorCode, error};

use super::{Broker, Side, hex};
use crate::core::{ClientKey, Pending, WorkerKey};
use crate::jobs::check_map;

impl Broker {
    pub(super) fn on_env_open(
        &mut self,
        client: ClientKey,
        rid: u64,
        open: paddock_proto::EnvOpen,
    ) {
        if let Err(e) = check_map(open.map.as_ref(), &self.store, "env_open.map") {
            return self.refuse(Side::Client, &client, rid, e);
        }
        let Some(worker) = self.disp.workers.pick_for_session() else {
            return self.refuse(
                Side::Client,
                &client,
                rid,
                error(
                    ErrorCode::Busy,
                    "env_open",
                    "no worker is connected to host an env session; retry later",
                ),
            );
        };
        self.forward(client, rid, worker, 0, Body::EnvOpen(open));
    }

    /// The worker and the worker's session id of a client's session, or an error
    /// reply naming `field`.
    /// Forwards an env reset, step or close to the worker hosting its session, with the
    /// broker's session id replaced by the worker's.
    pub(super) fn route_env(&mut self, client: ClientKey, rid: u64, mut body: Body) {
        let (session_id, field) = match &mut body {
            Body::EnvReset(r) => (&mut r.session_id, "env_reset.session_id"),
            Body::EnvStep(s) => (&mut s.session_id, "env_step.session_id"),
            Body::EnvClose(c) => (&mut c.session_id, "env_close.session_id"),
            _ => return,
        };
        let sid = *session_id;
        if let Some((w, wsid)) = self.session_route(&client, rid, sid, field) {
            *session_id = wsid;
            self.forward(client, rid, w, sid, body);
        }
    }

    pub(super) fn session_route(
        &mut self,
        client: &[u8],
        rid: u64,
        sid: u64,
        field: &str,
    ) -> Option<(WorkerKey, u64)> {
        if let Some(s) = self.sessions.get(sid, client) {
            return Some((s.worker.clone(), s.worker_session));
        }
        let message = self.lost_sessions.get(&sid).cloned().unwrap_or_else(|| {
            format!("{field} = {sid}: no such env session is open for this client")
        });
        self.refuse(
            Side::Client,
            client,
            rid,
            error(ErrorCode::NotFound, field, message),
        );
        None
    }

    pub(super) fn forward(
        &mut self,
        client: ClientKey,
        rid: u64,
        worker: WorkerKey,
        sid: u64,
        body: Body,
    ) {
        let fwd = self.sessions.forward(Pending {
            client,
            client_request: rid,
            worker: worker.clone(),
            session: sid,
        });
        self.send(Side::Worker, &worker, fwd, body);
    }

    pub(super) fn on_env_reply(&mut self, worker: WorkerKey, rid: u64, body: Body) {
        let Some(p) = self.sessions.reply(&worker, rid) else {
            tracing::warn!(peer = %hex(&worker), request_id = rid, "env reply to no pending request dropped");
            return;
        };
        let body = match body {
            Body::EnvOpened(mut o) => {
                let sid = self
                    .sessions
                    .opened(p.client.clone(), worker.clone(), o.session_id);
                if let Some(w) = self.disp.workers.get_mut(&worker) {
                    w.sessions += 1;
                }
                o.session_id = sid;
                Body::EnvOpened(o)
            }
            Body::EnvObservation(mut o) => {
                o.session_id = p.session;
                Body::EnvObservation(o)
            }
            Body::EnvClosed(_) => {
                self.sessions.close(p.session);
                if let Some(w) = self.disp.workers.get_mut(&worker) {
                    w.sessions = w.sessions.saturating_sub(1);
                }
                Body::EnvClosed(EnvClosed {
                    session_id: p.session,
                })
            }
            other => other,
        };
        self.send(Side::Client, &p.client, p.client_request, body);
    }
}
