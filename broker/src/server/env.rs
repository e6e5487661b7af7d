//! Env sessions: opening on a worker, routing reset/step/close and their replies, and
//! rebuilding a session on another worker when its worker dies (by replaying its log,
//! see [`crate::core::replay`]), or the errors clients get when that is not possible.

use paddock_proto::{Body, EnvClosed, ErrorCode, error};

use super::{Broker, Side, hex};
use crate::core::{
    ClientKey, EnvRequest, Forwarded, Lost, Pending, Queued, ReplayStep, SessionState, WorkerKey,
};
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
        let body = Body::EnvOpen(open.clone());
        self.forward(client, rid, worker, 0, Forwarded::Open(open), body);
    }

    /// Forwards an env reset, step, close or render to the worker hosting its session, with the
    /// broker's session id replaced by the worker's; holds it while the session is
    /// being rebuilt.
    pub(super) fn route_env(&mut self, client: ClientKey, rid: u64, body: Body) {
        let (sid, field, what) = match body {
            Body::EnvReset(r) => (
                r.session_id,
                "env_reset.session_id",
                Forwarded::Request(EnvRequest::Reset(r)),
            ),
            Body::EnvStep(s) => (
                s.session_id,
                "env_step.session_id",
                Forwarded::Request(EnvRequest::Step(s)),
            ),
            Body::EnvClose(c) => (c.session_id, "env_close.session_id", Forwarded::Close),
            Body::EnvRender(r) => (
                r.session_id,
                "env_render.session_id",
                Forwarded::Read(Body::EnvRender(r)),
            ),
            _ => return,
        };
        let route = self.sessions.get(sid, &client).map(|s| {
            (
                s.state == SessionState::Live,
                s.worker.clone(),
                s.worker_session,
            )
        });
        match route {
            Some((true, worker, wsid)) => {
                if let Some(body) = what.to_body(wsid) {
                    self.forward(client, rid, worker, sid, what, body);
                }
            }
            Some((false, ..)) => self.sessions.hold(
                sid,
                Queued {
                    client_request: rid,
                    what,
                },
            ),
            None => {
                let message = self.lost_sessions.get(&sid).cloned().unwrap_or_else(|| {
                    format!("{field} = {sid}: no such env session is open for this client")
                });
                self.refuse(
                    Side::Client,
                    &client,
                    rid,
                    error(ErrorCode::NotFound, field, message),
                );
            }
        }
    }

    fn forward(
        &mut self,
        client: ClientKey,
        rid: u64,
        worker: WorkerKey,
        sid: u64,
        what: Forwarded,
        body: Body,
    ) {
        let fwd = self.sessions.forward(Pending {
            client,
            client_request: rid,
            worker: worker.clone(),
            session: sid,
            what,
        });
        self.send(Side::Worker, &worker, fwd, body);
        self.arm_spin();
    }

    /// A worker's `EnvOpened`, `EnvObservation`, `EnvClosed`, `EnvImage` or `Error` for
    /// request `rid`.
    pub(super) fn on_env_reply(&mut self, worker: WorkerKey, rid: u64, body: Body) {
        let Some(p) = self.sessions.reply(&worker, rid) else {
            if let Body::Error(e) = &body {
                tracing::warn!(
                    peer = %hex(&worker),
                    code = paddock_proto::code_name(e.code),
                    field = %e.field,
                    message = %e.message,
                    "worker reported an error"
                );
            } else {
                tracing::warn!(peer = %hex(&worker), request_id = rid, "env reply to no pending request dropped");
            }
            return;
        };
        let body = match (p.what, body) {
            (what @ (Forwarded::ReplayOpen | Forwarded::Replay(_)), body) => {
                let step = self.sessions.replay_reply(p.session, &what, &body);
                return self.on_replay_step(p.session, &p.client, &worker, step);
            }
            (_, Body::Error(e)) => {
                *self
                    .stats
                    .errors
                    .entry(paddock_proto::code_name(e.code).to_string())
                    .or_default() += 1;
                Body::Error(e)
            }
            (Forwarded::Open(open), Body::EnvOpened(mut o)) => {
                let sid = self.sessions.opened(
                    p.client.clone(),
                    worker.clone(),
                    o.session_id,
                    open,
                    o.num_envs as usize,
                );
                if let Some(w) = self.disp.workers.get_mut(&worker) {
                    w.sessions += 1;
                }
                o.session_id = sid;
                Body::EnvOpened(o)
            }
            (Forwarded::Request(request), Body::EnvObservation(mut o)) => {
                self.sessions.record(p.session, request, &o);
                o.session_id = p.session;
                Body::EnvObservation(o)
            }
            (Forwarded::Read(_), Body::EnvImage(mut i)) => {
                i.session_id = p.session;
                Body::EnvImage(i)
            }
            (Forwarded::Close, Body::EnvClosed(_)) => {
                self.sessions.close(p.session);
                if let Some(w) = self.disp.workers.get_mut(&worker) {
                    w.sessions = w.sessions.saturating_sub(1);
                }
                Body::EnvClosed(EnvClosed {
                    session_id: p.session,
                })
            }
            (_, other) => other,
        };
        self.send(Side::Client, &p.client, p.client_request, body);
        self.arm_spin();
    }

    fn on_replay_step(&mut self, sid: u64, client: &[u8], worker: &[u8], step: ReplayStep) {
        match step {
            ReplayStep::Send(requests) => {
                for (i, body) in requests {
                    self.forward(
                        client.to_vec(),
                        0,
                        worker.to_vec(),
                        sid,
                        Forwarded::Replay(i),
                        body,
                    );
                }
            }
            ReplayStep::Continue | ReplayStep::Ignore => {}
            ReplayStep::Done(held) => {
                tracing::info!(
                    session = sid,
                    worker = %hex(worker),
                    held_requests = held.len(),
                    "env session rebuilt on another worker by replay"
                );
                for q in held {
                    self.route_held(client, sid, q);
                }
            }
            ReplayStep::Failed(lost) => {
                if let Some(w) = self.disp.workers.get_mut(worker) {
                    w.sessions = w.sessions.saturating_sub(1);
                }
                self.session_lost(lost);
            }
        }
    }

    /// Sends a request held during a replay, now that its session is live again.
    fn route_held(&mut self, client: &[u8], sid: u64, q: Queued) {
        let Some((worker, wsid)) = self
            .sessions
            .get(sid, client)
            .map(|s| (s.worker.clone(), s.worker_session))
        else {
            return;
        };
        if let Some(body) = q.what.to_body(wsid) {
            self.forward(client.to_vec(), q.client_request, worker, sid, q.what, body);
        }
    }

    /// A session gone for good: its held requests are answered with the reason, and
    /// later requests get it as `NOT_FOUND`.
    pub(super) fn session_lost(&mut self, lost: Lost) {
        tracing::warn!(
            session = lost.session,
            held_requests = lost.queued.len(),
            reason = %lost.reason,
            "env session lost"
        );
        self.lost_sessions.insert(lost.session, lost.reason.clone());
        for q in lost.queued {
            let e = error(ErrorCode::Internal, "session_id", lost.reason.clone());
            self.refuse(Side::Client, &lost.client, q.client_request, e);
        }
    }

    /// Starts rebuilding the sessions whose worker died on live workers, and gives up
    /// those that waited too long.
    pub(super) fn resume_sessions(&mut self) {
        for lost in self.sessions.tick(self.now()) {
            self.session_lost(lost);
        }
        for sid in self.sessions.stalled() {
            let Some(worker) = self.disp.workers.pick_for_session() else {
                break;
            };
            let Some(open) = self.sessions.start_replay(sid, worker.clone()) else {
                continue;
            };
            let (client, steps) = match self.sessions.session(sid) {
                Some(s) => (s.client.clone(), s.log.len()),
                None => continue,
            };
            if let Some(w) = self.disp.workers.get_mut(&worker) {
                w.sessions += 1;
            }
            tracing::info!(
                session = sid,
                worker = %hex(&worker),
                requests = steps,
                "replaying an env session on another worker"
            );
            self.forward(
                client,
                0,
                worker,
                sid,
                Forwarded::ReplayOpen,
                Body::EnvOpen(open),
            );
        }
    }
}
