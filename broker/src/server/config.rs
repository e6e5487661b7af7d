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
    /// What one client, and all of them together, may make the broker hold.
    pub bounds: Bounds,
}

/// The broker's bounds beyond the task queues ([`Limits`]), the replay logs
/// ([`LogLimits`]) and the scenario store ([`BlobLimits`]); docs/security.md has the
/// whole table with the `paddock serve` flag of each.
#[derive(Debug, Clone, PartialEq)]
pub struct Bounds {
    /// Env sessions one client (principal) may hold at once.
    pub sessions_per_client: usize,
    /// Env sessions in the whole broker.
    pub sessions_total: usize,
    /// An env session without a request for this long is closed; zero: never.
    pub session_idle: Duration,
    /// Ended sessions whose reason is kept for their owner's next request.
    pub max_lost_sessions: usize,
    /// A task's deadline: this much, plus [`Bounds::task_time_per_sim_s`] for every
    /// simulated second the scenario allows.
    pub task_time_base: Duration,
    /// Wall-clock seconds a worker may take per simulated second of an episode.
    pub task_time_per_sim_s: f64,
    /// Deadline of a task whose scenario the planner cannot read (a routing-only broker).
    pub task_time_unknown: Duration,
    /// Bytes of a job's name.
    pub max_job_name_bytes: usize,
    /// Bytes of an encoded job submission.
    pub max_job_submit_bytes: usize,
    /// Jobs one client may have stored (finished ones count until deleted).
    pub max_jobs_per_client: usize,
    /// Bytes of maps and model files clients may store (`PutMap`, `PutBlob`).
    pub max_store_bytes: u64,
    /// Characters of a client's input quoted in a log line.
    pub log_field_chars: usize,
    /// Refusals logged per second (the rest counted, the count logged later).
    pub refusal_log_rate: u32,
}

impl Default for Bounds {
    fn default() -> Self {
        Self {
            sessions_per_client: 64,
            sessions_total: 256,
            session_idle: Duration::from_secs(600),
            max_lost_sessions: 4096,
            task_time_base: Duration::from_secs(60),
            task_time_per_sim_s: 1.0,
            task_time_unknown: Duration::from_secs(600),
            max_job_name_bytes: 256,
            max_job_submit_bytes: 16 << 20,
            max_jobs_per_client: 1000,
            max_store_bytes: 4 << 30,
            log_field_chars: super::guard::DEFAULT_LOG_FIELD_CHARS,
            refusal_log_rate: super::guard::DEFAULT_REFUSAL_LOG_RATE,
        }
    }
}

/// A broker open to the network: its key pair and, per endpoint, the directory of
/// public keys allowed in. A key file removed from a directory is refused from the
/// next connection on.
#[derive(Debug, Clone)]
pub struct Security {
    pub keys: paddock_libzmq::KeyPair,
    pub client_keys: PathBuf,
    pub worker_keys: PathBuf,
    /// Client public keys (Z85) that see and manage every client's jobs.
    pub admin_keys: Vec<String>,
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
            bounds: Bounds::default(),
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
    /// An endpoint to bind that libzmq would take and then bind elsewhere (a TCP port
    /// over 65535 wraps round) or refuse without saying why.
    #[error("{0} (the {1})")]
    Endpoint(String, &'static str),
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("starting the back-office thread: {0}")]
    Thread(std::io::Error),
}
