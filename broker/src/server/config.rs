//! How to run a broker ([`BrokerConfig`]) and why it could not ([`BrokerError`]).

use std::path::PathBuf;
use std::time::Duration;

use crate::core::{BlobLimits, Limits, Liveness, LogLimits};
use crate::state::StoreError;

/// How to run a broker.
#[derive(Debug, Clone)]
pub struct BrokerConfig {
    /// Client endpoint, e.g. `tcp://0.0.0.0:5555` (`tcp://127.0.0.1:0`: any free port).
    pub frontend: String,
    /// Worker endpoint.
    pub backend: String,
    /// The state directory (job database and maps).
    pub state_dir: PathBuf,
    pub liveness: Liveness,
    pub limits: Limits,
    /// Env-session replay logs: their bounds, and how long a session whose worker died
    /// waits for another worker to be rebuilt on.
    pub session_logs: LogLimits,
    /// Scenario bytes held for the batches and job rounds in flight.
    pub blobs: BlobLimits,
    /// Larger frames are answered with TOO_LARGE unread.
    pub max_message_bytes: usize,
    /// Most jobs queued or running at once; more are refused with BUSY.
    pub max_jobs: usize,
    /// The poll timeout, i.e. the resolution of the broker's timers.
    pub tick: Duration,
    /// CURVE encryption and authentication; None: plain TCP (loopback and trusted
    /// networks only).
    pub security: Option<Security>,
    /// A second worker endpoint, e.g. `inproc://paddock-workers`, for workers in this
    /// process sharing the broker's ZeroMQ context (see [`Broker::bind_in`]): no TCP and
    /// no I/O thread between them, two thread hand-offs fewer per env step.
    pub local_backend: Option<String>,
    /// After forwarding env-session traffic the loop polls without blocking for this
    /// long before it sleeps: the reply (or the client's next step) usually comes
    /// sooner, and a thread that never slept needs no wake-up. Rollout tasks never arm
    /// it, and an idle broker never spins. Zero: always block.
    pub spin: Duration,
    /// Maps stored at start and listed by name in the status (the shipped maps), so
    /// clients name them without uploading them.
    pub maps: Vec<paddock_proto::MapBundle>,
}

/// A broker open to the network: its key pair and, per endpoint, the directory of
/// public keys allowed in. A key file removed from a directory is refused from the
/// next connection on.
#[derive(Debug, Clone)]
pub struct Security {
    pub keys: paddock_libzmq::KeyPair,
    pub client_keys: PathBuf,
    pub worker_keys: PathBuf,
}

/// The default [`BrokerConfig::spin`].
pub const DEFAULT_SPIN: Duration = Duration::from_micros(200);

impl BrokerConfig {
    /// The defaults: 1 s heartbeats, 3 missed = dead, 64 MiB messages, 10 ms ticks.
    pub fn new(frontend: &str, backend: &str, state_dir: impl Into<PathBuf>) -> Self {
        Self {
            frontend: frontend.into(),
            backend: backend.into(),
            state_dir: state_dir.into(),
            liveness: Liveness::default(),
            limits: Limits::default(),
            session_logs: LogLimits::default(),
            blobs: BlobLimits::default(),
            max_message_bytes: paddock_proto::MAX_MESSAGE_BYTES,
            max_jobs: 1000,
            tick: Duration::from_millis(10),
            security: None,
            local_backend: None,
            spin: DEFAULT_SPIN,
            maps: Vec::new(),
        }
    }
}

/// Why the broker could not start or stopped.
#[derive(Debug, thiserror::Error)]
pub enum BrokerError {
    #[error("{what} {endpoint}: {source}")]
    Socket {
        what: &'static str,
        endpoint: String,
        source: zmq::Error,
    },
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("starting the back-office thread: {0}")]
    Thread(std::io::Error),
}
