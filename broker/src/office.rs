//! The back office: a thread beside the socket thread that does everything slow, so no
//! heartbeat and no env step waits for it. It owns the store (SQLite job table, maps and
//! blobs on disk) and the [`Planner`] with the running [`JobPlan`]s:
//!
//! - checks batches (the planner reads every scenario) and hands them back to be queued;
//! - runs jobs: takes submissions, hands each job's rounds to the socket thread, is told
//!   the outcomes, tells the plan (a CMA-ES update, a benchmark report), stores the job
//!   after every round and resumes stored jobs at start;
//! - answers job queries (status, list, result, watch, cancel);
//! - stores maps and blobs clients put, and reads them for workers that ask.
//!
//! It talks to the socket thread only through two channels: [`Command`]s in, [`Event`]s
//! out (every event followed by a doorbell frame, so the socket thread's poll wakes).

use std::collections::BTreeMap;
use std::sync::mpsc::{Receiver, Sender};

use paddock_proto::{
    Body, ErrorCode, JobInfo, JobListing, JobResult, JobState, JobSubmit, MapStored,
    RolloutTaskSpec, error,
};
use prost::Message;

use crate::core::{ClientKey, Principal, WorkerKey};
use crate::plan::{JobPlan, Planner, Round, Stored, TaskBudget};
use crate::server::BrokerError;
use crate::state::{JobRecord, Store, unix_now};

/// What the socket thread asks of the back office.
pub(crate) enum Command {
    /// Check a client's batch; queue it (an [`Event::Queue`]) or refuse it.
    CheckBatch {
        client: ClientKey,
        who: Principal,
        rid: u64,
        batch: paddock_proto::RolloutBatch,
    },
    /// A job request: submit, status, list, cancel, result or watch.
    Job {
        client: ClientKey,
        /// Who asks: jobs belong to the principal that submitted them.
        owner: Principal,
        /// An admin key: sees and manages every job.
        admin: bool,
        rid: u64,
        body: Box<Body>,
    },
    /// The outcomes of a job's round, in task order.
    RoundDone {
        job_id: String,
        outcomes: Vec<Vec<u8>>,
    },
    PutMap {
        client: ClientKey,
        rid: u64,
        put: paddock_proto::PutMap,
    },
    MapRequest {
        worker: WorkerKey,
        rid: u64,
        hash: String,
    },
    PutBlob {
        client: ClientKey,
        rid: u64,
        data: Vec<u8>,
    },
    BlobRequest {
        worker: WorkerKey,
        rid: u64,
        hash: String,
    },
    Stop,
}

/// Whose tasks an [`Event::Queue`] carries.
pub(crate) enum Owner {
    Batch {
        client: ClientKey,
        who: Principal,
        rid: u64,
        progress: bool,
    },
    Job {
        job_id: String,
    },
}

/// What the back office asks of the socket thread.
pub(crate) enum Event {
    /// Send a message (and payload frames) to a client or worker.
    Send {
        to_worker: bool,
        peer: Vec<u8>,
        rid: u64,
        body: Box<Body>,
        frames: Vec<Vec<u8>>,
    },
    /// Queue checked tasks: their scenarios by (hash, bytes), tasks naming them by index.
    Queue {
        owner: Owner,
        scenarios: Vec<(String, Vec<u8>)>,
        /// What a task of each scenario asks of a worker (its deadline), where the
        /// planner can tell.
        budgets: Vec<Option<TaskBudget>>,
        tasks: Vec<RolloutTaskSpec>,
    },
    /// Drop a cancelled job's round.
    Cancel { job_id: String },
    /// Jobs queued or running.
    Active { jobs: u32 },
}

/// The running back office.
pub(crate) struct Office {
    handle: std::thread::JoinHandle<()>,
}

impl Office {
    /// Stores `maps` (the shipped maps), resumes the stored unfinished jobs and starts
    /// the thread.
    pub(crate) fn start(
        planner: Box<dyn Planner>,
        store: Store,
        maps: &[paddock_proto::MapBundle],
        limits: OfficeLimits,
        commands: Receiver<Command>,
        events: Sender<Event>,
        bell: zmq::Socket,
    ) -> Result<Self, BrokerError> {
        for bundle in maps {
            store.put_map(bundle)?;
        }
        let mut state = State {
            planner,
            store,
            limits,
            jobs: BTreeMap::new(),
            events,
            bell,
        };
        state.resume_jobs()?;
        state.pump_jobs();
        let handle = std::thread::Builder::new()
            .name("paddock-broker-office".into())
            .spawn(move || state.run(commands))
            .map_err(BrokerError::Thread)?;
        Ok(Self { handle })
    }

    /// Waits for the thread to finish (after [`Command::Stop`]).
    pub(crate) fn join(self) {
        if self.handle.join().is_err() {
            tracing::error!("the broker's back-office thread panicked");
        }
    }
}

/// Bounds the back office applies.
#[derive(Debug, Clone, Copy)]
pub(crate) struct OfficeLimits {
    /// Most jobs queued or running at once.
    pub max_jobs: usize,
    /// Most tasks in one round (a job whose round is larger fails).
    pub max_round_tasks: usize,
    /// Largest message: a batch whose results would not fit is refused before the work.
    pub max_message_bytes: usize,
    /// Job names, submissions, and jobs stored per client.
    pub max_job_name_bytes: usize,
    pub max_job_submit_bytes: usize,
    pub max_jobs_per_client: usize,
    /// Bytes of maps and blobs the store may hold (shipped maps not counted).
    pub max_store_bytes: u64,
}

struct RunningJob {
    record: JobRecord,
    plan: Box<dyn JobPlan>,
    /// A round is with the socket thread.
    in_round: bool,
    watchers: Vec<(ClientKey, u64)>,
}

struct State {
    planner: Box<dyn Planner>,
    store: Store,
    limits: OfficeLimits,
    jobs: BTreeMap<String, RunningJob>,
    events: Sender<Event>,
    bell: zmq::Socket,
}

impl Stored for Store {
    fn map_dir(&self, hash: &str) -> Option<std::path::PathBuf> {
        match self.has_map(hash) {
            Ok(true) => Some(Store::map_dir(self, hash)),
            _ => None,
        }
    }

    fn blob(&self, hash: &str) -> Option<Vec<u8>> {
        match Store::blob(self, hash) {
            Ok(b) => b,
            Err(e) => {
                tracing::warn!(hash, error = %e, "cannot read a stored blob");
                None
            }
        }
    }
}

impl State {
    fn run(mut self, commands: Receiver<Command>) {
        while let Ok(command) = commands.recv() {
            if matches!(command, Command::Stop) {
                break;
            }
            self.handle(command);
            self.pump_jobs();
        }
    }

    fn emit(&self, event: Event) {
        if self.events.send(event).is_ok() {
            let _ = self.bell.send(&b""[..], zmq::DONTWAIT);
        }
    }

    fn reply(&self, peer: &[u8], rid: u64, body: Body) {
        self.reply_frames(peer, rid, body, Vec::new());
    }

    fn reply_frames(&self, peer: &[u8], rid: u64, body: Body, frames: Vec<Vec<u8>>) {
        self.emit(Event::Send {
            to_worker: false,
            peer: peer.to_vec(),
            rid,
            body: Box::new(body),
            frames,
        });
    }

    /// Refuses a request (the socket thread counts and logs it, within the log's rate).
    fn refuse(&self, peer: &[u8], rid: u64, e: paddock_proto::Error) {
        self.reply(peer, rid, Body::Error(e));
    }

    /// The budgets of a batch's scenarios, after checking that its results fit in one
    /// message: a batch whose outcomes could exceed it is refused before any work, with
    /// the size and how to split it.
    fn check_result_size(
        &self,
        batch: &paddock_proto::RolloutBatch,
        prefix: &str,
    ) -> Result<Vec<Option<TaskBudget>>, paddock_proto::Error> {
        let budgets: Vec<Option<TaskBudget>> = batch
            .scenarios
            .iter()
            .map(|s| self.planner.budget(s))
            .collect();
        let limit = self.limits.max_message_bytes as u64;
        let mut total: u64 = 0;
        for (j, t) in batch.tasks.iter().enumerate() {
            let Some(Some(b)) = budgets.get(t.scenario as usize) else {
                continue;
            };
            let bytes = b.result_bytes(t.record_decimation);
            if bytes > limit {
                return Err(error(
                    ErrorCode::TooLarge,
                    format!("{prefix}.tasks[{j}].record_decimation"),
                    format!(
                        "{prefix}.tasks[{j}]: its trajectory (record_decimation = {}) could take {:.1} MiB, over the {:.0} MiB a message may carry: record every Nth step with a larger decimation",
                        t.record_decimation,
                        bytes as f64 / 1048576.0,
                        limit as f64 / 1048576.0
                    ),
                ));
            }
            total += bytes;
        }
        if total > limit {
            let parts = total.div_ceil(limit);
            return Err(error(
                ErrorCode::TooLarge,
                format!("{prefix}.tasks"),
                format!(
                    "the results of these {} tasks could take {:.1} MiB, over the {:.0} MiB a message may carry: split the batch into at least {parts} batches (paddock rollout does this by itself)",
                    batch.tasks.len(),
                    total as f64 / 1048576.0,
                    limit as f64 / 1048576.0
                ),
            ));
        }
        Ok(budgets)
    }

    fn to_worker(&self, worker: &[u8], rid: u64, body: Body) {
        self.emit(Event::Send {
            to_worker: true,
            peer: worker.to_vec(),
            rid,
            body: Box::new(body),
            frames: Vec::new(),
        });
    }

    fn handle(&mut self, command: Command) {
        match command {
            Command::CheckBatch {
                client,
                who,
                rid,
                batch,
            } => {
                let checked = self
                    .planner
                    .check_batch(&batch, &self.store, "rollout_batch")
                    .and_then(|()| self.check_result_size(&batch, "rollout_batch"));
                match checked {
                    Ok(budgets) => {
                        let scenarios = batch
                            .scenarios
                            .into_iter()
                            .map(|s| (paddock_proto::blob_hash(&s), s))
                            .collect();
                        self.emit(Event::Queue {
                            owner: Owner::Batch {
                                client,
                                who,
                                rid,
                                progress: batch.progress,
                            },
                            scenarios,
                            budgets,
                            tasks: batch.tasks,
                        });
                    }
                    Err(e) => self.refuse(&client, rid, e),
                }
            }
            Command::Job {
                client,
                owner,
                admin,
                rid,
                body,
            } => self.on_job(client, &owner, admin, rid, *body),
            Command::RoundDone { job_id, outcomes } => self.round_done(&job_id, outcomes),
            Command::PutMap { client, rid, put } => self.put_map(&client, rid, put),
            Command::MapRequest { worker, rid, hash } => match self.store.map_bundle(&hash) {
                Ok(Some(bundle)) => self.to_worker(&worker, rid, Body::MapBundle(bundle)),
                Ok(None) => self.to_worker(
                    &worker,
                    rid,
                    Body::Error(error(
                        ErrorCode::NotFound,
                        "map_request.hash",
                        format!("map hash {hash:?} is not stored in this broker"),
                    )),
                ),
                Err(e) => self.to_worker(
                    &worker,
                    rid,
                    Body::Error(error(ErrorCode::Internal, "map_request.hash", e.to_string())),
                ),
            },
            Command::PutBlob { client, rid, data } => {
                if !self.store.has_blob(&paddock_proto::blob_hash(&data))
                    && !self.room_for(&client, rid, data.len() as u64, "put_blob.data")
                {
                    return;
                }
                self.put_blob(&client, rid, &data)
            }
            Command::BlobRequest { worker, rid, hash } => match self.store.blob(&hash) {

                Ok(Some(data)) => {
                    self.to_worker(&worker, rid, Body::Blob(paddock_proto::Blob { hash, data }))
                }
                Ok(None) => self.to_worker(
                    &worker,
                    rid,
                    Body::Error(error(
                        ErrorCode::NotFound,
                        "blob_request.hash",
                        format!(
                            "blob {hash:?} is neither held for a task in flight nor stored in this broker"
                        ),
                    )),
                ),
                Err(e) => self.to_worker(
                    &worker,
                    rid,
                    Body::Error(error(ErrorCode::Internal, "blob_request.hash", e.to_string())),
                ),
            },
            Command::Stop => {}
        }
    }

    fn put_blob(&self, client: &[u8], rid: u64, data: &[u8]) {
        match self.store.put_blob(data) {
            Ok(hash) => {
                tracing::info!(hash = %hash, bytes = data.len(), "blob stored");
                self.reply(
                    client,
                    rid,
                    Body::BlobStored(paddock_proto::BlobStored { hash }),
                );
            }
            Err(e) => self.refuse(
                client,
                rid,
                error(ErrorCode::Internal, "put_blob.data", e.to_string()),
            ),
        }
    }

    /// Whether the store has room for `bytes` more; refuses the request when not.
    fn room_for(&self, client: &[u8], rid: u64, bytes: u64, field: &str) -> bool {
        let held = self.store.stored_bytes();
        let limit = self.limits.max_store_bytes;
        if held.saturating_add(bytes) <= limit {
            return true;
        }
        self.refuse(
            client,
            rid,
            error(
                ErrorCode::Busy,
                field,
                format!(
                    "the broker's store holds {:.1} MiB of maps and models; {:.1} MiB more would exceed its limit of {:.0} MiB (--max-store-mib)",
                    held as f64 / 1048576.0,
                    bytes as f64 / 1048576.0,
                    limit as f64 / 1048576.0
                ),
            ),
        );
        false
    }

    fn put_map(&mut self, client: &[u8], rid: u64, p: paddock_proto::PutMap) {
        let Some(bundle) = p.bundle else {
            return self.refuse(
                client,
                rid,
                error(
                    ErrorCode::InvalidArgument,
                    "put_map.bundle",
                    "put_map needs a bundle",
                ),
            );
        };
        let checked =
            paddock_proto::check_bundle(&bundle).and_then(|()| self.planner.check_map(&bundle));
        if let Err(mut e) = checked {
            e.field = if e.field.is_empty() {
                "put_map".into()
            } else {
                format!("put_map.{}", e.field)
            };
            return self.refuse(client, rid, e);
        }
        let bytes: u64 = bundle.files.iter().map(|f| f.data.len() as u64).sum();
        if !matches!(self.store.has_map(&bundle.hash), Ok(true))
            && !self.room_for(client, rid, bytes, "put_map.bundle")
        {
            return;
        }
        match self.store.put_map(&bundle) {
            Ok(()) => {
                tracing::info!(name = %bundle.name, hash = %bundle.hash, "map stored");
                self.reply(
                    client,
                    rid,
                    Body::MapStored(MapStored { hash: bundle.hash }),
                );
            }
            Err(e) => self.refuse(
                client,
                rid,
                error(ErrorCode::Internal, "put_map.bundle", e.to_string()),
            ),
        }
    }

    // ------------------------------------------------------------------ jobs
}

mod jobs;
