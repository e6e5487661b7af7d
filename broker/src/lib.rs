//! # paddock-broker: the ZeroMQ MapReduce broker
//!
//! Clients (the CLI, Python learners) send rollout batches, env-session requests and
//! jobs to the broker's frontend ROUTER; workers connect to its backend ROUTER,
//! announce their capacity and run tasks. The broker hands each worker at most as many
//! tasks as its capacity (credit), takes turns between batches so a huge one does not
//! starve a small one, requeues the tasks of workers that fall silent, drops late
//! duplicate results by task id and reduces results in task order, so a batch gives
//! the same results bit for bit however many workers ran it. Jobs (tuning runs,
//! benchmarks, stored batches) run as rounds planned by a [`plan::Planner`] from a crate
//! above this one and are stored in SQLite after every round, so a restarted broker
//! resumes them.
//!
//! The broker knows nothing of the simulator: this crate depends on the wire protocol
//! and ZeroMQ only. It routes by each message's small Envelope header and forwards the
//! payload frames (observations, scenarios, results) without decoding them.
//!
//! Layers, each testable alone:
//! - [`core`]: the protocol state machines (worker liveness and credit, the task
//!   table with fairness and bounds, env-session routing and replay, blobs held for
//!   tasks), free of sockets and of the wall clock, unit-tested with a virtual clock;
//! - [`state`]: the store under `--state DIR` (job table, maps and blobs by content hash);
//! - [`plan`]: the trait the domain implements: checks, job plans as rounds;
//! - `office`: the back-office thread that runs plans and the store off the socket
//!   thread;
//! - [`server`]: [`Broker`], the socket loop around them;
//! - [`client`]: a small blocking client ([`client::Client`]) for the CLI and tests.
//!
//! The wire protocol is described in `proto/PROTOCOL.md`.

pub mod client;
pub mod core;
mod office;
pub mod plan;
pub mod server;
pub mod state;

/// ZeroMQ with CURVE: key pairs, socket security, the ZAP authenticator.
pub use paddock_libzmq as curve;
pub use plan::{JobOutput, JobPlan, Planner, Round, RouteOnly, Stored, TaskBudget};
pub use server::{Bounds, Broker, BrokerConfig, BrokerError, Security};
/// The ZeroMQ binding the broker is built on: a process that embeds the broker and its
/// workers creates one [`zmq::Context`] for both ([`Broker::bind_in`]).
pub use zmq;
