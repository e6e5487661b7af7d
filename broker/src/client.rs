//! A small blocking client of the broker's frontend: one DEALER socket, requests
//! matched to replies by request id, each message an Envelope and its payload frames
//! ([`Client`]). Running batches of episodes through a broker (the
//! `paddock_rollout::Executor` of `--endpoint`) is the CLI's `RemoteExecutor`, on top
//! of this client and `paddock-wire`.
//!
//! ```no_run
//! use paddock_broker::client::Client;
//! use paddock_proto::{Body, StatusRequest};
//! let mut c = Client::connect("tcp://127.0.0.1:5555").unwrap(); // ok: example
//! let Body::BrokerStatus(s) = c.request(Body::StatusRequest(StatusRequest {})).unwrap() else { // ok: example
//!     unreachable!()
//! };
//! println!("{} workers", s.workers.len());
//! ```

use std::time::{Duration, Instant};

use paddock_libzmq::Curve;
use paddock_proto::Body;

mod resume;
pub use resume::{Answer, Next, ResumePolicy, Watch};

/// Why a request got no good reply.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error("zmq {what}: {source}")]
    Zmq {
        what: &'static str,
        source: zmq::Error,
    },
    #[error("no reply from the broker within {0:?}")]
    Timeout(Duration),
    /// A request went quiet and the broker did not answer a status request within
    /// this long: it is down, unreachable or stuck ([`Client::request_resumable`]).
    #[error(
        "the broker does not answer: no reply to a status request within {0:?} \
         (is it running and reachable?)"
    )]
    NotAnswering(Duration),
    /// The broker restarted (a new instance id) after each of this many sends of a
    /// request ([`Client::request_resumable`]).
    #[error("the broker restarted after each of {0} sends of the request: gave up")]
    Restarted(u32),
    /// The broker (or a worker behind it) refused the request.
    #[error("{}: {} ({})", paddock_proto::code_name(.0.code), .0.message, .0.field)]
    Remote(paddock_proto::Error),
    #[error("undecodable reply: {0}")]
    Protocol(String),
    /// The request was not sent (its socket would block, or ZeroMQ refused it).
    #[error("the request could not be sent to the broker: {0}")]
    Send(zmq::Error),
    /// The endpoint cannot be connected to (see `paddock_libzmq::check_connect_endpoint`).
    #[error("{0}")]
    Endpoint(String),
    /// The broker did not let this client in (its CURVE key is not allowed, or the
    /// handshake failed): reported as soon as libzmq sees it, not after the timeout.
    #[error(transparent)]
    Refused(#[from] paddock_libzmq::HandshakeFailure),
}

impl ClientError {
    /// Whether the request failed on the way (the broker does not answer, restarted
    /// too often, refused the connection, or the socket failed) rather than being
    /// refused by the broker or a worker.
    pub fn is_transport(&self) -> bool {
        !matches!(self, ClientError::Remote(_))
    }

    /// The refusal's code, for a remote error.
    pub fn code(&self) -> Option<paddock_proto::ErrorCode> {
        match self {
            ClientError::Remote(e) => paddock_proto::ErrorCode::try_from(e.code).ok(),
            _ => None,
        }
    }
}

fn zmq_err(what: &'static str) -> impl FnOnce(zmq::Error) -> ClientError {
    move |source| ClientError::Zmq { what, source }
}

/// A message received: its request id, its Envelope body and its payload frames (as
/// ZeroMQ received them, not copied).
#[derive(Debug)]
pub struct Received {
    pub request_id: u64,
    pub body: Body,
    pub payload: Vec<zmq::Message>,
}

/// A connection to a broker's frontend.
pub struct Client {
    _ctx: zmq::Context,
    socket: zmq::Socket,
    /// Handshake failures of a CURVE connection (None on plain TCP).
    handshake: Option<paddock_libzmq::HandshakeMonitor>,
    next_id: u64,
    /// How long [`Client::request`] waits for a reply.
    pub timeout: Duration,
    /// How long [`Client::recv`] polls without blocking before it sleeps: a reply that
    /// comes sooner (an env step) needs no thread wake-up. Zero: always block.
    pub spin: Duration,
    /// Sent in every request's Envelope (`client_token`): who this client is to a broker
    /// without CURVE. A new client carries this user's token
    /// (`paddock_libzmq::token::user_token`, the file the CLI and the Python client
    /// share), so its jobs and sessions stay reachable from its next connection. Empty:
    /// none (the client is its connection).
    pub token: Vec<u8>,
}

impl Client {
    /// Connects (ZeroMQ connects lazily: an absent broker shows as a timeout).
    pub fn connect(endpoint: &str) -> Result<Self, ClientError> {
        Self::connect_with(endpoint, &Curve::Off)
    }

    /// Connects with CURVE security (a client key pair and the broker's public key).
    pub fn connect_with(endpoint: &str, curve: &Curve) -> Result<Self, ClientError> {
        paddock_libzmq::check_connect_endpoint(endpoint).map_err(ClientError::Endpoint)?;
        let ctx = zmq::Context::new();
        let socket = ctx.socket(zmq::DEALER).map_err(zmq_err("socket"))?;
        curve.apply(&socket).map_err(zmq_err("curve"))?;
        socket.set_linger(0).map_err(zmq_err("linger"))?;
        let handshake = match curve {
            Curve::Client { keys, .. } => Some(
                paddock_libzmq::HandshakeMonitor::start(&ctx, &socket, &keys.public)
                    .map_err(zmq_err("monitor"))?,
            ),
            _ => None,
        };
        socket.connect(endpoint).map_err(zmq_err("connect"))?;
        Ok(Self {
            _ctx: ctx,
            socket,
            handshake,
            next_id: 1,
            timeout: Duration::from_secs(60),
            spin: crate::server::DEFAULT_SPIN,
            token: paddock_libzmq::token::user_token().unwrap_or_default(),
        })
    }

    /// Sends a message with a fresh request id and returns that id.
    pub fn send(&mut self, body: Body) -> Result<u64, ClientError> {
        self.send_with(body, Vec::new())
    }

    /// Sends a message and its payload frames with a fresh request id; returns the id.
    pub fn send_with(&mut self, body: Body, payload: Vec<Vec<u8>>) -> Result<u64, ClientError> {
        let id = self.next_id;
        self.next_id += 1;
        let header = paddock_proto::encode_with_token(id, self.token.clone(), body);
        let flags = if payload.is_empty() { 0 } else { zmq::SNDMORE };
        if self.handshake.is_some() {
            self.send_watched(&header, flags)?;
        } else {
            self.socket.send(header, flags).map_err(ClientError::Send)?;
        }
        let n = payload.len();
        for (i, frame) in payload.into_iter().enumerate() {
            let flags = if i + 1 < n { zmq::SNDMORE } else { 0 };
            self.socket.send(frame, flags).map_err(ClientError::Send)?;
        }
        Ok(id)
    }

    /// Sends a request's first frame with CURVE, watching the handshake. A key refused
    /// while the connection sat idle leaves no connection to send on, and a blocking send
    /// (this socket has no send timeout) would wait for good. libzmq keeps reconnecting
    /// meanwhile, each attempt refused again, so the socket can take a message when
    /// polled and have no connection an instant later: the send does not block, and on
    /// `EAGAIN` the wait resumes, watching for the refusal. (Once the first frame is taken
    /// the rest of the message follows it without blocking.)
    fn send_watched(&self, header: &[u8], flags: i32) -> Result<(), ClientError> {
        let t0 = Instant::now();
        loop {
            if !self.ready(zmq::POLLOUT, t0, self.timeout)? {
                return Err(ClientError::Timeout(self.timeout));
            }
            match self.socket.send(header, flags | zmq::DONTWAIT) {
                Ok(()) => return Ok(()),
                // the connection went between the poll and the send
                Err(zmq::Error::EAGAIN) => std::thread::sleep(Duration::from_millis(1)),
                Err(e) => return Err(ClientError::Send(e)),
            }
        }
    }

    /// Whether the socket is ready for `events` (`POLLIN`: a message waits; `POLLOUT`: it
    /// takes one) by `timeout` after `t0`, or the broker's refusal of this client's key,
    /// whichever comes first (a refusal waiting wins: between two refused attempts the
    /// socket can look ready).
    fn ready(
        &self,
        events: zmq::PollEvents,
        t0: Instant,
        timeout: Duration,
    ) -> Result<bool, ClientError> {
        loop {
            let left = timeout.saturating_sub(t0.elapsed());
            let ms = left.as_millis().min(i64::MAX as u128) as i64;
            let Some(handshake) = &self.handshake else {
                return Ok(self.socket.poll(events, ms).map_err(zmq_err("poll"))? > 0);
            };
            let mut items = [
                self.socket.as_poll_item(events),
                handshake.socket().as_poll_item(zmq::POLLIN),
            ];
            zmq::poll(&mut items, ms).map_err(zmq_err("poll"))?;
            let event = items[1].is_readable();
            if event && let Some(failure) = handshake.failure() {
                return Err(ClientError::Refused(failure));
            }
            if items[0].get_revents().intersects(events) {
                return Ok(true);
            }
            if !event {
                return Ok(false);
            }
        }
    }

    /// Receives the next message, whatever request it answers.
    pub fn recv(&mut self, timeout: Duration) -> Result<Received, ClientError> {
        let t0 = Instant::now();
        let spin_until = t0 + self.spin.min(timeout);
        let mut ready = self.socket.poll(zmq::POLLIN, 0).map_err(zmq_err("poll"))?;
        while ready == 0 && Instant::now() < spin_until {
            std::thread::yield_now();
            ready = self.socket.poll(zmq::POLLIN, 0).map_err(zmq_err("poll"))?;
        }
        // wait for the reply or a refusal of this client's key, whichever comes first
        if ready == 0 && !self.ready(zmq::POLLIN, t0, timeout)? {
            return Err(ClientError::Timeout(timeout));
        }
        let header = self.socket.recv_msg(0).map_err(zmq_err("recv"))?;
        let mut more = header.get_more();
        let mut payload = Vec::new();
        while more {
            let m = self.socket.recv_msg(0).map_err(zmq_err("recv"))?;
            more = m.get_more();
            payload.push(m);
        }
        let (request_id, body) = paddock_proto::decode(&header)
            .map_err(|(_, e)| ClientError::Protocol(e.to_string()))?;
        let want = paddock_proto::payload_frames(&body);
        if payload.len() != want {
            return Err(ClientError::Protocol(format!(
                "{} came with {} payload frames, expected {want}",
                paddock_proto::body_name(&body),
                payload.len()
            )));
        }
        Ok(Received {
            request_id,
            body,
            payload,
        })
    }

    /// Sends a request and waits for its reply. Messages for other request ids are
    /// dropped; `on_update` sees the request's intermediate messages (RolloutProgress,
    /// JobInfo of a watch) until a final reply arrives. An `Error` reply is returned
    /// as [`ClientError::Remote`].
    pub fn request_with(
        &mut self,
        body: Body,
        payload: Vec<Vec<u8>>,
        mut on_update: impl FnMut(&Body),
    ) -> Result<Received, ClientError> {
        let id = self.send_with(body, payload)?;
        let deadline = Instant::now() + self.timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(ClientError::Timeout(self.timeout));
            }
            // the request's whole timeout, not what was left of it, is the one to report
            let reply = match self.recv(left) {
                Err(ClientError::Timeout(_)) => return Err(ClientError::Timeout(self.timeout)),
                r => r?,
            };
            if reply.request_id != id {
                continue;
            }
            match reply.body {
                Body::Error(e) => return Err(ClientError::Remote(e)),
                Body::EnvReply(paddock_proto::EnvReply { error: Some(e), .. }) => {
                    return Err(ClientError::Remote(e));
                }
                Body::RolloutProgress(_) => on_update(&reply.body),
                _ => return Ok(reply),
            }
        }
    }

    /// A request without payload frames and its reply's body (payload frames dropped).
    pub fn request(&mut self, body: Body) -> Result<Body, ClientError> {
        self.request_with(body, Vec::new(), |_| {}).map(|r| r.body)
    }

    /// A request on env session `session_id` (0 to open one): `payload` is the encoded
    /// `EnvOpen`, `EnvReset`, `EnvStep` or `EnvRender` (none for a close). The reply's
    /// header (with the session id) and payload frames.
    pub fn env(
        &mut self,
        session_id: u64,
        op: paddock_proto::EnvOp,
        payload: Option<Vec<u8>>,
    ) -> Result<(paddock_proto::EnvReply, Vec<zmq::Message>), ClientError> {
        let header = Body::EnvRequest(paddock_proto::EnvRequest {
            session_id,
            op: op as i32,
        });
        let reply = self.request_with(header, payload.into_iter().collect(), |_| {})?;
        match reply.body {
            Body::EnvReply(r) => Ok((r, reply.payload)),
            other => Err(ClientError::Protocol(format!(
                "expected env_reply, got {}",
                paddock_proto::body_name(&other)
            ))),
        }
    }

    /// Stores a map in the broker (idempotent).
    pub fn put_map(&mut self, bundle: paddock_proto::MapBundle) -> Result<(), ClientError> {
        match self.request(Body::PutMap(paddock_proto::PutMap {
            bundle: Some(bundle),
        }))? {
            Body::MapStored(_) => Ok(()),
            other => Err(ClientError::Protocol(format!(
                "expected map_stored, got {}",
                paddock_proto::body_name(&other)
            ))),
        }
    }
}

impl Client {
    /// Stores bytes (a model file) in the broker (idempotent); returns their hash, by
    /// which scenarios name them (`onnx:<hash>`).
    pub fn put_blob(&mut self, data: Vec<u8>) -> Result<String, ClientError> {
        match self.request(Body::PutBlob(paddock_proto::PutBlob { data }))? {
            Body::BlobStored(b) => Ok(b.hash),
            other => Err(ClientError::Protocol(format!(
                "expected blob_stored, got {}",
                paddock_proto::body_name(&other)
            ))),
        }
    }
}

/// Whether an error asks for a map by hash (the answer is `PutMap`, then a retry).
pub fn is_missing_map(e: &ClientError) -> bool {
    matches!(e, ClientError::Remote(r)
        if r.code == paddock_proto::ErrorCode::NotFound as i32 && r.field.ends_with("map.hash"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A request nobody answers reports the request's timeout, not what was left of it
    /// when the wait began ("no reply from the broker within 9.99999952s" before).
    #[test]
    fn a_request_nobody_answers_reports_its_whole_timeout() {
        // a ROUTER that takes requests and never answers
        let ctx = zmq::Context::new();
        let silent = ctx.socket(zmq::ROUTER).unwrap();
        silent.set_linger(0).unwrap();
        silent.bind("tcp://127.0.0.1:*").unwrap();
        let endpoint = silent.get_last_endpoint().unwrap().unwrap();
        let mut client = Client::connect(&endpoint).unwrap();
        client.timeout = Duration::from_millis(300);
        let e = client
            .request(Body::StatusRequest(paddock_proto::StatusRequest {}))
            .expect_err("nobody answers");
        assert!(
            matches!(e, ClientError::Timeout(t) if t == client.timeout),
            "{e:?}"
        );
        assert_eq!(e.to_string(), "no reply from the broker within 300ms");
    }
}
