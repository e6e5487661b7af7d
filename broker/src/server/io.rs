//! Sending on the broker's sockets (replies, refusals and their rate-limited log) and
//! who a client is.

use paddock_proto::{Body, ErrorCode, code_name, error};

use super::guard::clip;
use super::{Broker, Side, hex};
use crate::core::Principal;

impl Broker {
    /// Sends `[peer, frames...]`, the frames moved into the socket (no copy). False when
    /// the peer is gone (the socket has no route to it).
    pub(super) fn send_frames(
        &mut self,
        side: Side,
        peer: &[u8],
        frames: Vec<zmq::Message>,
    ) -> bool {
        let socket = match side {
            Side::Client => &self.front,
            Side::Worker => &self.back,
        };
        let n = frames.len();
        let mut result = socket.send(peer, zmq::SNDMORE | zmq::DONTWAIT);
        for (i, f) in frames.into_iter().enumerate() {
            if result.is_err() {
                break;
            }
            let flags = if i + 1 < n {
                zmq::SNDMORE | zmq::DONTWAIT
            } else {
                zmq::DONTWAIT
            };
            result = socket.send(f, flags);
        }
        if side == Side::Worker {
            let now = self.now();
            self.disp.workers.sent(peer, now);
        }
        match result {
            Ok(()) => true,
            Err(zmq::Error::EHOSTUNREACH) => {
                tracing::debug!(?side, peer = %hex(peer), "peer gone; message dropped");
                false
            }
            Err(e) => {
                tracing::warn!(?side, peer = %hex(peer), error = %e, "send failed; message dropped");
                true
            }
        }
    }

    pub(super) fn send(&mut self, side: Side, peer: &[u8], request_id: u64, body: Body) {
        self.send_with(side, peer, request_id, body, Vec::new());
    }

    /// Sends `body` to a client; false when the client has gone.
    pub(super) fn send_to_client(&mut self, client: &[u8], request_id: u64, body: Body) -> bool {
        let frame = zmq::Message::from(paddock_proto::encode(request_id, body));
        self.send_frames(Side::Client, client, vec![frame])
    }

    /// Sends an Envelope and its payload frames.
    pub(super) fn send_with(
        &mut self,
        side: Side,
        peer: &[u8],
        request_id: u64,
        body: Body,
        payload: Vec<zmq::Message>,
    ) {
        let mut frames = Vec::with_capacity(1 + payload.len());
        frames.push(zmq::Message::from(paddock_proto::encode(request_id, body)));
        frames.extend(payload);
        self.send_frames(side, peer, frames);
    }

    /// Sends an error reply, counting and logging it (the client's input quoted at
    /// most `Bounds::log_field_chars` characters, at most `Bounds::refusal_log_rate`
    /// lines a second; the refusals not logged are counted in the next line).
    pub(super) fn refuse(
        &mut self,
        side: Side,
        peer: &[u8],
        request_id: u64,
        e: paddock_proto::Error,
    ) {
        let code = code_name(e.code);
        *self.stats.errors.entry(code.to_string()).or_default() += 1;
        let now = self.now();
        if self.log_budget.allow(now, self.cfg.bounds.refusal_log_rate) {
            let max = self.cfg.bounds.log_field_chars;
            let suppressed = std::mem::take(&mut self.log_budget.suppressed);
            tracing::warn!(
                ?side,
                peer = %clip(&hex(peer), 64),
                request_id,
                code,
                field = %clip(&e.field, max),
                message = %clip(&e.message, max),
                refusals_not_logged = suppressed,
                "request refused"
            );
        }
        self.send(side, peer, request_id, Body::Error(e));
    }
}

/// Who a client is ([`crate::core::principal`]): its CURVE key when the ZAP handler
/// set one, else its client token (kept as a hash), else its connection. A token of
/// the wrong size is refused.
pub(super) fn principal_of(
    user_id: Option<&str>,
    route: &[u8],
    token: &[u8],
) -> Result<Principal, paddock_proto::Error> {
    if user_id.is_some_and(|k| !k.is_empty()) || token.is_empty() {
        return Ok(crate::core::principal(user_id, route));
    }
    let (min, max) = (
        paddock_proto::MIN_CLIENT_TOKEN,
        paddock_proto::MAX_CLIENT_TOKEN,
    );
    if token.len() < min || token.len() > max {
        return Err(error(
            ErrorCode::InvalidArgument,
            "client_token",
            format!(
                "client_token has {} bytes; it must have {min} to {max} (random bytes drawn once by the client)",
                token.len()
            ),
        ));
    }
    Ok(format!("token:{}", &paddock_proto::blob_hash(token)[..32]))
}
