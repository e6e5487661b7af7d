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

use crate::core::{ClientKey, WorkerKey};
use crate::plan::{JobPlan, Planner, Round, Stored};
use crate::server::BrokerError;
use crate::state::{JobRecord, Store, unix_now};

/// What the socket thread asks of the back office.
pub(crate) enum Command {
    /// Check a client's batch; queue it (an [`Event::Queue`]) or refuse it.
    CheckBatch {
        client: ClientKey,
        rid: u64,
        batch: paddock_proto::RolloutBatch,
    },
    /// A job request: submit, status, list, cancel, result or watch.
    Job {
        client: ClientKey,
        rid: u64,
        body: Body,
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

    fn refuse(&self, peer: &[u8], rid: u64, e: paddock_proto::Error) {
        tracing::warn!(
            request_id = rid,
            code = paddock_proto::code_name(e.code),
            field = %e.field,
            message = %e.message,
            "request refused"
        );
        self.reply(peer, rid, Body::Error(e));
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
            Command::CheckBatch { client, rid, batch } => {
                match self
                    .planner
                    .check_batch(&batch, &self.store, "rollout_batch")
                {
                    Ok(()) => {
                        let scenarios = batch
                            .scenarios
                            .into_iter()
                            .map(|s| (paddock_proto::blob_hash(&s), s))
                            .collect();
                        self.emit(Event::Queue {
                            owner: Owner::Batch {
                                client,
                                rid,
                                progress: batch.progress,
                            },
                            scenarios,
                            tasks: batch.tasks,
                        });
                    }
                    Err(e) => self.refuse(&client, rid, e),
                }
            }
            Command::Job { client, rid, body } => self.on_job(client, rid, body),
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
            Command::PutBlob { client, rid, data } => match self.store.put_blob(&data) {
                Ok(hash) => {
                    tracing::info!(hash = %hash, bytes = data.len(), "blob stored");
                    self.reply(&client, rid, Body::BlobStored(paddock_proto::BlobStored { hash }));
                }
                Err(e) => self.refuse(
                    &client,
                    rid,
                    error(ErrorCode::Internal, "put_blob.data", e.to_string()),
                ),
            },
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
