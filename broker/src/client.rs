//! A small blocking client of the broker's frontend: one DEALER socket, requests
//! matched to replies by request id ([`Client`]), and [`RemoteExecutor`], the
//! [`paddock_rollout::Executor`] that runs batches through a broker (uploading maps
//! the broker lacks).
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
    /// The broker (or a worker behind it) refused the request.
    #[error("{}: {} ({})", paddock_proto::code_name(.0.code), .0.message, .0.field)]
    Remote(paddock_proto::Error),
    #[error("undecodable reply: {0}")]
    Protocol(String),
    /// The broker did not let this client in (its CURVE key is not allowed, or the
    /// handshake failed): reported as soon as libzmq sees it, not after the timeout.
    #[error(transparent)]
    Refused(#[from] paddock_libzmq::HandshakeFailure),
}

impl ClientError {
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
}

impl Client {
    /// Connects (ZeroMQ connects lazily: an absent broker shows as a timeout).
    pub fn connect(endpoint: &str) -> Result<Self, ClientError> {
        Self::connect_with(endpoint, &Curve::Off)
    }

    /// Connects with CURVE security (a client key pair and the broker's public key).
    pub fn connect_with(endpoint: &str, curve: &Curve) -> Result<Self, ClientError> {
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
        })
    }

    /// Sends a message with a fresh request id and returns that id.
    pub fn send(&mut self, body: Body) -> Result<u64, ClientError> {
        let id = self.next_id;
        self.next_id += 1;
        self.socket
            .send(paddock_proto::encode(id, body), 0)
            .map_err(zmq_err("send"))?;
        Ok(id)
    }

    /// Receives the next message, whatever request it answers.
    pub fn recv(&mut self, timeout: Duration) -> Result<(u64, Body), ClientError> {
        let t0 = Instant::now();
        let spin_until = t0 + self.spin.min(timeout);
        let mut ready = self.socket.poll(zmq::POLLIN, 0).map_err(zmq_err("poll"))?;
        while ready == 0 && Instant::now() < spin_until {
            std::thread::yield_now();
            ready = self.socket.poll(zmq::POLLIN, 0).map_err(zmq_err("poll"))?;
        }
        while ready == 0 {
            let left = timeout.saturating_sub(t0.elapsed());
            let ms = left.as_millis().min(i64::MAX as u128) as i64;
            let Some(handshake) = &self.handshake else {
                ready = self.socket.poll(zmq::POLLIN, ms).map_err(zmq_err("poll"))?;
                break;
            };
            // wait for the reply or a refusal of this client's key, whichever comes first
            let mut items = [
                self.socket.as_poll_item(zmq::POLLIN),
                handshake.socket().as_poll_item(zmq::POLLIN),
            ];
            zmq::poll(&mut items, ms).map_err(zmq_err("poll"))?;
            let (reply, event) = (items[0].is_readable(), items[1].is_readable());
            if reply {
                ready = 1;
            } else if event {
                if let Some(failure) = handshake.failure() {
                    return Err(ClientError::Refused(failure));
                }
            } else {
                break;
            }
        }
        if ready == 0 {
            return Err(ClientError::Timeout(timeout));
        }
        let frame = self.socket.recv_bytes(0).map_err(zmq_err("recv"))?;
        paddock_proto::decode(&frame).map_err(|(_, e)| ClientError::Protocol(e.to_string()))
    }

    /// Sends a request and waits for its reply. Messages for other request ids are
    /// dropped; `on_update` sees the request's intermediate messages (RolloutProgress,
    /// JobInfo of a watch) until a final reply arrives. An `Error` reply is returned
    /// as [`ClientError::Remote`].
    pub fn request_with(
        &mut self,
        body: Body,
        mut on_update: impl FnMut(&Body),
    ) -> Result<Body, ClientError> {
        let id = self.send(body)?;
        let deadline = Instant::now() + self.timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(ClientError::Timeout(self.timeout));
            }
            let (rid, reply) = self.recv(left)?;
            if rid != id {
                continue;
            }
            match reply {
                Body::Error(e) => return Err(ClientError::Remote(e)),
                Body::RolloutProgress(_) => on_update(&reply),
                other => return Ok(other),
            }
        }
    }

    /// [`Client::request_with`] ignoring updates.
    pub fn request(&mut self, body: Body) -> Result<Body, ClientError> {
        self.request_with(body, |_| {})
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

/// Whether an error asks for a map by hash (the answer is `PutMap`, then a retry).
pub fn is_missing_map(e: &ClientError) -> bool {
    matches!(e, ClientError::Remote(r)
        if r.code == paddock_proto::ErrorCode::NotFound as i32 && r.field.ends_with("map.hash"))
}

impl Client {
    /// [`Client::request_with`], storing `maps` in the broker and retrying once when
    /// the broker does not know a map hash the request names.
    pub fn request_with_maps(
        &mut self,
        body: Body,
        maps: &[paddock_proto::MapBundle],
        mut on_update: impl FnMut(&Body),
    ) -> Result<Body, ClientError> {
        match self.request_with(body.clone(), &mut on_update) {
            Err(e) if is_missing_map(&e) && !maps.is_empty() => {
                for m in maps {
                    self.put_map(m.clone())?;
                }
                self.request_with(body, on_update)
            }
            other => other,
        }
    }
}

/// Runs batches of episodes through a broker: the [`paddock_rollout::Executor`] of
/// `--endpoint`, so tuning, benchmarks and rollouts do not care where episodes run.
/// Maps are sent by content hash, and uploaded when the broker lacks them.
pub struct RemoteExecutor {
    client: std::sync::Mutex<Client>,
    maps: std::sync::Mutex<std::collections::HashMap<String, paddock_proto::MapBundle>>,
    parallelism: usize,
}

impl RemoteExecutor {
    /// Connects to a broker's frontend and asks for its capacity.
    pub fn connect(endpoint: &str) -> Result<Self, ClientError> {
        Self::connect_with(endpoint, &Curve::Off)
    }

    /// [`RemoteExecutor::connect`] with CURVE security.
    pub fn connect_with(endpoint: &str, curve: &Curve) -> Result<Self, ClientError> {
        let mut client = Client::connect_with(endpoint, curve)?;
        client.timeout = Duration::from_secs(10);
        let parallelism: usize =
            match client.request(Body::StatusRequest(paddock_proto::StatusRequest {}))? {
                Body::BrokerStatus(s) => s.workers.iter().map(|w| w.capacity as usize).sum(),
                other => {
                    return Err(ClientError::Protocol(format!(
                        "expected broker_status, got {}",
                        paddock_proto::body_name(&other)
                    )));
                }
            };
        // batches may run for a long time; progress arrives meanwhile
        client.timeout = Duration::from_secs(24 * 3600);
        Ok(Self {
            client: std::sync::Mutex::new(client),
            maps: std::sync::Mutex::new(std::collections::HashMap::new()),
            parallelism: parallelism.max(1),
        })
    }

    fn bundle(&self, map: &str) -> Result<paddock_proto::MapBundle, paddock_proto::Error> {
        let mut maps = self.maps.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(b) = maps.get(map) {
            return Ok(b.clone());
        }
        let b = paddock_proto::convert::local_map(map)?;
        maps.insert(map.to_string(), b.clone());
        Ok(b)
    }

    fn try_run(
        &self,
        tasks: &[paddock_rollout::EpisodeTask],
        progress: &(dyn Fn(usize) + Sync),
    ) -> Result<Vec<paddock_proto::TaskOutcome>, String> {
        let mut bundles: Vec<paddock_proto::MapBundle> = Vec::new();
        let mut failure = None;
        let batch = paddock_proto::convert::batch_to_proto(
            tasks,
            |map| match self.bundle(map) {
                Ok(b) => {
                    let r = paddock_proto::convert::map_ref(&b);
                    if !bundles.iter().any(|x| x.hash == b.hash) {
                        bundles.push(b);
                    }
                    r
                }
                Err(e) => {
                    failure = Some(format!("map {map:?}: {}", e.message));
                    paddock_proto::MapRef::default()
                }
            },
            true,
        );
        if let Some(f) = failure {
            return Err(f);
        }
        let mut client = self.client.lock().unwrap_or_else(|p| p.into_inner());
        let reply = client
            .request_with_maps(Body::RolloutBatch(batch), &bundles, |u| {
                if let Body::RolloutProgress(p) = u {
                    progress(p.done as usize);
                }
            })
            .map_err(|e| e.to_string())?;
        match reply {
            Body::RolloutResult(r) if r.outcomes.len() == tasks.len() => Ok(r.outcomes),
            Body::RolloutResult(r) => Err(format!(
                "the broker answered {} outcomes for {} tasks",
                r.outcomes.len(),
                tasks.len()
            )),
            other => Err(format!(
                "expected rollout_result, got {}",
                paddock_proto::body_name(&other)
            )),
        }
    }
}

impl paddock_rollout::Executor for RemoteExecutor {
    fn run_batch(
        &self,
        tasks: &[paddock_rollout::EpisodeTask],
        progress: &(dyn Fn(usize) + Sync),
    ) -> Vec<Result<paddock_rollout::EpisodeResult, paddock_rollout::RolloutError>> {
        if tasks.is_empty() {
            return Vec::new();
        }
        match self.try_run(tasks, progress) {
            Ok(outcomes) => {
                progress(tasks.len());
                outcomes
                    .iter()
                    .map(paddock_proto::convert::outcome_from_proto)
                    .collect()
            }
            Err(reason) => tasks
                .iter()
                .map(|_| {
                    Err(paddock_rollout::RolloutError::Invalid {
                        field: "endpoint".into(),
                        value: String::new(),
                        reason: reason.clone(),
                    })
                })
                .collect(),
        }
    }

    fn parallelism(&self) -> usize {
        self.parallelism
    }
}
