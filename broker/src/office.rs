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
use crate::plan::{JobPlan, Maps, Planner, Round};
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

impl Maps for Store {
    fn map_dir(&self, hash: &str) -> Option<std::path::PathBuf> {
        match self.has_map(hash) {
            Ok(true) => Some(Store::map_dir(self, hash)),
            _ => None,
        }
    }
}

fn job_state(state: JobState) -> i32 {
    state as i32
}

fn is_finished(state: i32) -> bool {
    state == JobState::Succeeded as i32
        || state == JobState::Failed as i32
        || state == JobState::CancelledJob as i32
}

fn info_of(r: &JobRecord) -> JobInfo {
    JobInfo {
        job_id: r.id.clone(),
        name: r.name.clone(),
        kind: r.kind.clone(),
        state: r.state,
        rounds_done: r.rounds_done,
        rounds_total: r.rounds_total,
        episodes_done: r.episodes_done,
        progress_json: r.progress_json.clone(),
        error: r.error.clone(),
        created_at: r.created_at,
        updated_at: r.updated_at,
    }
}

/// Stored outcomes of a rollout job: each as a u64 little-endian length and its bytes.
fn pack_outcomes(outcomes: &[Vec<u8>]) -> Vec<u8> {
    let mut out = Vec::with_capacity(outcomes.iter().map(|o| o.len() + 8).sum());
    for o in outcomes {
        out.extend_from_slice(&(o.len() as u64).to_le_bytes());
        out.extend_from_slice(o);
    }
    out
}

fn unpack_outcomes(mut bytes: &[u8]) -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    while bytes.len() >= 8 {
        let (len, rest) = bytes.split_at(8);
        let n = u64::from_le_bytes(len.try_into().unwrap_or([0; 8])) as usize;
        if n > rest.len() {
            break;
        }
        out.push(rest[..n].to_vec());
        bytes = &rest[n..];
    }
    out
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

    fn on_job(&mut self, client: ClientKey, rid: u64, body: Body) {
        match body {
            Body::JobSubmit(s) => self.submit(client, rid, s),
            Body::JobStatus(r) => {
                if let Some(rec) = self.job_record(&client, rid, &r.job_id, "job_status.job_id") {
                    self.reply(&client, rid, Body::JobInfo(info_of(&rec)));
                }
            }
            Body::JobList(_) => match self.store.jobs() {
                Ok(jobs) => {
                    let jobs = jobs
                        .iter()
                        .map(|r| match self.jobs.get(&r.id) {
                            Some(j) => info_of(&j.record),
                            None => info_of(r),
                        })
                        .collect();
                    self.reply(&client, rid, Body::JobListing(JobListing { jobs }));
                }
                Err(e) => self.refuse(
                    &client,
                    rid,
                    error(ErrorCode::Internal, "job_list", e.to_string()),
                ),
            },
            Body::JobCancel(c) => self.cancel(&client, rid, &c.job_id),
            Body::JobResultRequest(r) => {
                if let Some(rec) =
                    self.job_record(&client, rid, &r.job_id, "job_result_request.job_id")
                {
                    let outcomes = unpack_outcomes(&rec.result_bin);
                    let reply = JobResult {
                        info: Some(info_of(&rec)),
                        result_json: rec.result_json.clone(),
                        outcomes: outcomes.len() as u32,
                    };
                    self.reply_frames(&client, rid, Body::JobResult(reply), outcomes);
                }
            }
            Body::JobWatch(w) => {
                if let Some(rec) = self.job_record(&client, rid, &w.job_id, "job_watch.job_id") {
                    self.reply(&client, rid, Body::JobInfo(info_of(&rec)));
                    if let Some(j) = self.jobs.get_mut(&w.job_id) {
                        j.watchers.push((client, rid));
                    }
                }
            }
            _ => {}
        }
    }

    fn job_record(&self, client: &[u8], rid: u64, id: &str, field: &str) -> Option<JobRecord> {
        if let Some(j) = self.jobs.get(id) {
            return Some(j.record.clone());
        }
        match self.store.job(id) {
            Ok(Some(r)) => Some(r),
            Ok(None) => {
                self.refuse(
                    client,
                    rid,
                    error(
                        ErrorCode::NotFound,
                        field,
                        format!("{field} = {id:?}: no such job"),
                    ),
                );
                None
            }
            Err(e) => {
                self.refuse(
                    client,
                    rid,
                    error(ErrorCode::Internal, field, e.to_string()),
                );
                None
            }
        }
    }

    fn submit(&mut self, client: ClientKey, rid: u64, submit: JobSubmit) {
        let active = self.jobs.len();
        if active >= self.limits.max_jobs {
            return self.refuse(
                &client,
                rid,
                error(
                    ErrorCode::Busy,
                    "job_submit",
                    format!(
                        "{active} jobs are queued or running, the limit is {}",
                        self.limits.max_jobs
                    ),
                ),
            );
        }
        let plan = match self.planner.plan(&submit, &self.store) {
            Ok(p) => p,
            Err(e) => return self.refuse(&client, rid, e),
        };
        let now = unix_now();
        let (rounds_done, rounds_total) = plan.rounds();
        let mut record = JobRecord {
            name: submit.name.clone(),
            kind: plan.kind().into(),
            state: job_state(JobState::Queued),
            spec: submit.encode_to_vec(),
            job_state: plan.state_json(),
            progress_json: plan.progress_json(),
            rounds_done,
            rounds_total,
            created_at: now,
            updated_at: now,
            ..Default::default()
        };
        if let Err(e) = self.store.insert_job(&mut record) {
            return self.refuse(
                &client,
                rid,
                error(ErrorCode::Internal, "job_submit", e.to_string()),
            );
        }
        tracing::info!(job_id = %record.id, kind = %record.kind, name = %record.name, "job submitted");
        self.reply(&client, rid, Body::JobInfo(info_of(&record)));
        self.jobs.insert(
            record.id.clone(),
            RunningJob {
                record,
                plan,
                in_round: false,
                watchers: Vec::new(),
            },
        );
        self.active_changed();
    }

    fn active_changed(&self) {
        self.emit(Event::Active {
            jobs: self.jobs.len() as u32,
        });
    }

    fn cancel(&mut self, client: &[u8], rid: u64, id: &str) {
        let Some(mut rec) = self.job_record(client, rid, id, "job_cancel.job_id") else {
            return;
        };
        if let Some(j) = self.jobs.remove(id) {
            if j.in_round {
                self.emit(Event::Cancel {
                    job_id: id.to_string(),
                });
            }
            rec = j.record;
            rec.state = job_state(JobState::CancelledJob);
            rec.updated_at = unix_now();
            if let Err(e) = self.store.update_job(&rec) {
                tracing::error!(job_id = id, error = %e, "storing a cancelled job failed");
            }
            tracing::info!(job_id = id, "job cancelled");
            for (c, w) in j.watchers {
                self.reply(&c, w, Body::JobInfo(info_of(&rec)));
            }
            self.active_changed();
        }
        self.reply(client, rid, Body::JobInfo(info_of(&rec)));
    }

    fn resume_jobs(&mut self) -> Result<(), BrokerError> {
        for rec in self.store.jobs()? {
            if is_finished(rec.state) {
                continue;
            }
            let restored = JobSubmit::decode(rec.spec.as_slice())
                .map_err(|e| format!("stored job spec does not decode: {e}"))
                .and_then(|submit| self.planner.restore(&submit, &rec.job_state, &self.store));
            match restored {
                Ok(plan) => {
                    tracing::info!(job_id = %rec.id, rounds_done = rec.rounds_done, "job resumed");
                    self.jobs.insert(
                        rec.id.clone(),
                        RunningJob {
                            record: rec,
                            plan,
                            in_round: false,
                            watchers: Vec::new(),
                        },
                    );
                }
                Err(e) => {
                    let mut rec = rec;
                    rec.state = job_state(JobState::Failed);
                    rec.error = format!("could not be resumed: {e}");
                    rec.updated_at = unix_now();
                    tracing::error!(job_id = %rec.id, error = %rec.error, "job not resumed");
                    self.store.update_job(&rec)?;
                }
            }
        }
        self.active_changed();
        Ok(())
    }

    /// Hands the next round of every job without one in flight to the socket thread.
    fn pump_jobs(&mut self) {
        let idle: Vec<String> = self
            .jobs
            .iter()
            .filter(|(_, j)| !j.in_round)
            .map(|(id, _)| id.clone())
            .collect();
        for id in idle {
            let Some(j) = self.jobs.get_mut(&id) else {
                continue;
            };
            match j.plan.next_round() {
                Ok(Some(round)) if round.tasks.len() > self.limits.max_round_tasks => {
                    let n = round.tasks.len();
                    let limit = self.limits.max_round_tasks;
                    self.end_job(
                        &id,
                        Some(format!(
                            "a round of {n} tasks exceeds the queue limit of {limit}"
                        )),
                    );
                }
                Ok(Some(Round { scenarios, tasks })) => {
                    j.in_round = true;
                    if j.record.state == job_state(JobState::Queued) {
                        j.record.state = job_state(JobState::Running);
                    }
                    let scenarios = scenarios
                        .into_iter()
                        .map(|s| (paddock_proto::blob_hash(&s), s))
                        .collect();
                    self.emit(Event::Queue {
                        owner: Owner::Job { job_id: id },
                        scenarios,
                        tasks,
                    });
                }
                Ok(None) => self.end_job(&id, None),
                Err(e) => self.end_job(&id, Some(e)),
            }
        }
    }

    fn round_done(&mut self, id: &str, outcomes: Vec<Vec<u8>>) {
        let Some(j) = self.jobs.get_mut(id) else {
            return;
        };
        j.in_round = false;
        let views: Vec<&[u8]> = outcomes.iter().map(Vec::as_slice).collect();
        if let Err(e) = j.plan.tell(&views) {
            return self.end_job(id, Some(e));
        }
        let (done, total) = j.plan.rounds();
        j.record.rounds_done = done;
        j.record.rounds_total = total;
        j.record.episodes_done = j.plan.episodes_done();
        j.record.progress_json = j.plan.progress_json();
        j.record.job_state = j.plan.state_json();
        j.record.updated_at = unix_now();
        if let Some(out) = j.plan.result() {
            j.record.result_json = out.json;
            j.record.result_bin = pack_outcomes(&out.outcomes);
            j.record.state = job_state(JobState::Succeeded);
        }
        let rec = j.record.clone();
        let watchers = j.watchers.clone();
        if let Err(e) = self.store.update_job(&rec) {
            tracing::error!(job_id = id, error = %e, "storing a job round failed");
        }
        tracing::info!(
            job_id = id,
            rounds_done = done,
            rounds_total = total,
            "job round done"
        );
        if is_finished(rec.state) {
            self.jobs.remove(id);
            self.active_changed();
        }
        for (c, w) in watchers {
            self.reply(&c, w, Body::JobInfo(info_of(&rec)));
        }
    }

    fn end_job(&mut self, id: &str, failure: Option<String>) {
        let Some(mut j) = self.jobs.remove(id) else {
            return;
        };
        j.record.updated_at = unix_now();
        match failure {
            Some(e) => {
                j.record.state = job_state(JobState::Failed);
                j.record.error = e;
                tracing::warn!(job_id = id, error = %j.record.error, "job failed");
            }
            None => {
                if let Some(out) = j.plan.result() {
                    j.record.result_json = out.json;
                    j.record.result_bin = pack_outcomes(&out.outcomes);
                }
                j.record.state = job_state(JobState::Succeeded);
            }
        }
        if let Err(e) = self.store.update_job(&j.record) {
            tracing::error!(job_id = id, error = %e, "storing a finished job failed");
        }
        for (c, w) in j.watchers {
            self.reply(&c, w, Body::JobInfo(info_of(&j.record)));
        }
        self.active_changed();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stored_outcomes_round_trip() {
        let outcomes = vec![vec![1, 2, 3], vec![], vec![9; 300]];
        assert_eq!(unpack_outcomes(&pack_outcomes(&outcomes)), outcomes);
        // a cut store gives the whole outcomes before the cut
        let packed = pack_outcomes(&outcomes);
        assert_eq!(unpack_outcomes(&packed[..15]), vec![vec![1, 2, 3]]);
    }
}
