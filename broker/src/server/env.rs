//! Env sessions: opening on a worker, routing requests and replies, and rebuilding a
//! session on another worker when its worker dies (by replaying its log, see
//! [`crate::core::replay`]), or the errors clients get when that is not possible.
//!
//! Nothing here decodes a payload. A client's request is `EnvRequest{session_id, op}`
//! and one payload frame; the broker sends that header and that very frame to the
//! session's worker. The worker's reply is `EnvReply{session_id, op, fingerprint,
//! restart}` and its payload frames; the broker forwards the reply's frames to the client
//! as they came. It keeps a copy of the (small) payload of each open, reset and step for
//! the replay log, and the fingerprint the worker computed.

use paddock_proto::{Body, EnvOp, EnvReply, EnvRequest, ErrorCode, error};

use super::{Broker, Side, hex};
use crate::core::{Held, Logged, Lost, Pending, Principal, Reply, ReplyHead, Route, Sent};

const OPEN: i32 = EnvOp::EnvOpen as i32;
const RESET: i32 = EnvOp::EnvReset as i32;
const STEP: i32 = EnvOp::EnvStep as i32;
const RENDER: i32 = EnvOp::EnvRender as i32;
const CLOSE: i32 = EnvOp::EnvClose as i32;

/// A fresh session id: unguessable, never 0 and not in use.
fn draw_session_id(taken: impl Fn(u64) -> bool) -> u64 {
    loop {
        let mut b = [0u8; 8];
        if getrandom::fill(&mut b).is_err() {
            // no OS randomness: still unique, from the clock
            let t = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(1, |d| d.as_nanos() as u64);
            b = t.to_le_bytes();
        }
        let id = u64::from_le_bytes(b) >> 11; // 53 bits: exact in a JSON or Python float
        if id != 0 && !taken(id) {
            return id;
        }
    }
}

impl Broker {
    pub(super) fn on_env_request(
        &mut self,
        client: Vec<u8>,
        who: Principal,
        rid: u64,
        req: EnvRequest,
        payload: Option<zmq::Message>,
    ) {
        match req.op {
            OPEN => self.on_env_open(client, who, rid, payload),
            RESET | STEP | RENDER | CLOSE => self.route_env(client, &who, rid, req, payload),
            op => self.refuse(
                Side::Client,
                &client,
                rid,
                error(
                    ErrorCode::InvalidArgument,
                    "env_request.op",
                    format!("env_request.op = {op} is not a known EnvOp"),
                ),
            ),
        }
    }

    fn on_env_open(
        &mut self,
        client: Vec<u8>,
        who: Principal,
        rid: u64,
        payload: Option<zmq::Message>,
    ) {
        let b = &self.cfg.bounds;
        let (mine, all) = (self.sessions.owned_by(&who), self.sessions.len());
        let over = if mine >= b.sessions_per_client {
            Some(format!(
                "this client holds {mine} env sessions, the limit per client is {} (--sessions-per-client): close one first",
                b.sessions_per_client
            ))
        } else if all >= b.sessions_total {
            Some(format!(
                "the broker holds {all} env sessions, its limit (--sessions-total); retry later",
            ))
        } else {
            None
        };
        if let Some(why) = over {
            return self.refuse(
                Side::Client,
                &client,
                rid,
                error(ErrorCode::Busy, "env_request", why),
            );
        }
        let Some(worker) = self.disp.workers.pick_for_session() else {
            return self.refuse(
                Side::Client,
                &client,
                rid,
                error(
                    ErrorCode::Busy,
                    "env_request",
                    "no worker is connected to host an env session; retry later",
                ),
            );
        };
        let sessions = &self.sessions;
        let lost = &self.lost_sessions;
        let sid = draw_session_id(|id| sessions.contains(id) || lost.contains_key(&id));
        let payload = payload.unwrap_or_else(zmq::Message::new);
        let now = self.now();
        self.sessions.open(
            sid,
            (client, who),
            worker.clone(),
            payload.to_vec(),
            rid,
            now,
        );
        if let Some(w) = self.disp.workers.get_mut(&worker) {
            w.sessions += 1;
        }
        self.send_env(&worker, rid, sid, OPEN, Some(payload));
    }

    /// Sends a request on session `sid` to `worker`: the header and the payload frame.
    fn send_env(
        &mut self,
        worker: &[u8],
        rid: u64,
        sid: u64,
        op: i32,
        payload: Option<zmq::Message>,
    ) {
        let header = EnvRequest {
            session_id: sid,
            op,
        };
        self.send_with(
            Side::Worker,
            worker,
            rid,
            Body::EnvRequest(header),
            payload.into_iter().collect(),
        );
        self.arm_spin();
    }

    /// Forwards a reset, step, render or close to the worker hosting its session; holds
    /// it while the session is being rebuilt.
    fn route_env(
        &mut self,
        client: Vec<u8>,
        who: &str,
        rid: u64,
        req: EnvRequest,
        payload: Option<zmq::Message>,
    ) {
        let sid = req.session_id;
        let now = self.now();
        match self.sessions.route(sid, &client, who, now) {
            Route::Send(worker) => {
                let sent = match req.op {
                    RESET | STEP => Sent::Change(Logged {
                        op: req.op,
                        payload: payload.as_ref().map(|p| p.to_vec()).unwrap_or_default(),
                    }),
                    RENDER => Sent::Read,
                    _ => Sent::Close,
                };
                self.sessions.sent(
                    sid,
                    Pending {
                        client_request: rid,
                        sent,
                    },
                );
                self.send_env(&worker, rid, sid, req.op, payload);
            }
            Route::Hold => self.sessions.hold(
                sid,
                Held {
                    client_request: rid,
                    op: req.op,
                    payload: payload.map(|p| p.to_vec()).unwrap_or_default(),
                },
            ),
            Route::Unknown => {
                let field = "env_request.session_id";
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

    /// A worker's reply on a session: forwarded as it came (header and payload frames)
    /// to the client that asked, or checked and dropped when it answers a replay.
    pub(super) fn on_env_reply(
        &mut self,
        worker: Vec<u8>,
        rid: u64,
        reply: EnvReply,
        payload: Vec<zmq::Message>,
    ) {
        let sid = reply.session_id;
        let head = ReplyHead {
            op: reply.op,
            fingerprint: reply.fingerprint,
            restart: reply.restart,
            error: reply.error.is_some(),
        };
        match self.sessions.reply(sid, &worker, head) {
            Reply::Forward { client, request } => {
                if let Some(e) = &reply.error {
                    *self
                        .stats
                        .errors
                        .entry(paddock_proto::code_name(e.code).to_string())
                        .or_default() += 1;
                }
                // a refused open or a close ends the session on its worker
                let ended = (reply.error.is_some() && reply.op == OPEN)
                    || (reply.error.is_none() && reply.op == CLOSE);
                if ended && let Some(w) = self.disp.workers.get_mut(&worker) {
                    w.sessions = w.sessions.saturating_sub(1);
                }
                self.send_with(
                    Side::Client,
                    &client,
                    request,
                    Body::EnvReply(reply),
                    payload,
                );
                self.arm_spin();
            }
            Reply::Continue => {}
            Reply::Send(requests) => {
                let indices: Vec<usize> = requests.iter().map(|(i, _)| *i).collect();
                self.sessions.replay_sent(sid, indices);
                for (_, r) in requests {
                    self.send_env(&worker, 0, sid, r.op, Some(zmq::Message::from(r.payload)));
                }
            }
            Reply::Done(held) => {
                tracing::info!(
                    session = sid,
                    worker = %hex(&worker),
                    held_requests = held.len(),
                    "env session rebuilt on another worker by replay"
                );
                let owner = self
                    .sessions
                    .session(sid)
                    .map(|s| (s.client.clone(), s.owner.clone()));
                if let Some((client, who)) = owner {
                    for h in held {
                        let payload = (h.op != CLOSE).then(|| zmq::Message::from(h.payload));
                        let req = EnvRequest {
                            session_id: sid,
                            op: h.op,
                        };
                        self.route_env(client.clone(), &who, h.client_request, req, payload);
                    }
                }
            }
            Reply::Failed(lost) => {
                if let Some(w) = self.disp.workers.get_mut(&worker) {
                    w.sessions = w.sessions.saturating_sub(1);
                }
                self.session_lost(lost);
            }
            Reply::Ignore => {
                tracing::debug!(
                    peer = %hex(&worker),
                    session = sid,
                    request_id = rid,
                    "env reply that nothing waits for dropped"
                );
            }
        }
    }

    /// A session gone for good: its waiting requests are answered with the reason, and
    /// later requests get it as `NOT_FOUND`.
    pub(super) fn session_lost(&mut self, lost: Lost) {
        tracing::warn!(
            session = lost.session,
            requests = lost.requests.len(),
            reason = %lost.reason,
            "env session lost"
        );
        self.remember_lost(lost.session, lost.reason.clone());
        for rid in lost.requests {
            let e = error(
                ErrorCode::Internal,
                "env_request.session_id",
                lost.reason.clone(),
            );
            self.refuse(Side::Client, &lost.client, rid, e);
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
            let steps = self.sessions.session(sid).map_or(0, |s| s.log.len());
            if let Some(w) = self.disp.workers.get_mut(&worker) {
                w.sessions += 1;
            }
            tracing::info!(
                session = sid,
                worker = %hex(&worker),
                requests = steps,
                "replaying an env session on another worker"
            );
            self.send_env(&worker, 0, sid, OPEN, Some(zmq::Message::from(open)));
        }
    }
}
