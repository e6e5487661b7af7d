//! Rollout tasks: queuing checked batches and job rounds, handing tasks to workers (a
//! task names its scenario by hash; a worker fetches each scenario once), progress, and
//! the reduction of a finished batch or round: its outcome frames, untouched, in task
//! order. Tasks given up after repeated worker deaths get an error outcome.

use std::time::{Duration, Instant};

use paddock_proto::{
    Body, ErrorCode, RolloutProgress, RolloutResult, RolloutTaskSpec, TaskAssign, TaskOutcome,
    error, task_outcome,
};
use prost::Message;

use super::{Broker, OwnerKind, Side, SourceOwner, hex};
use crate::core::{Assigned, ClientKey, Completion, Principal, SourceId};
use crate::office::Command;

impl Broker {
    pub(super) fn fail_exhausted(&mut self, tasks: Vec<u64>) {
        let attempts = self.cfg.limits.max_attempts;
        for t in tasks {
            let outcome = TaskOutcome {
                outcome: Some(task_outcome::Outcome::Error(error(
                    ErrorCode::Internal,
                    "task",
                    format!("task {t} was given up after {attempts} workers died running it"),
                ))),
            };
            *self.stats.errors.entry("INTERNAL".into()).or_default() += 1;
            let frame = zmq::Message::from(outcome.encode_to_vec());
            if let Completion::Accepted {
                source,
                finished: true,
                ..
            } = self.disp.tasks.complete(t, frame)
            {
                self.finish_source(source);
            }
        }
    }

    pub(super) fn dispatch(&mut self) {
        for (worker, a) in self.disp.dispatch() {
            self.assign(&worker, &a);
        }
    }

    fn assign(&mut self, worker: &[u8], a: &Assigned) {
        let Some(owner) = self.sources.get(&a.source) else {
            return;
        };
        let Some(&(scenario, seed, record_decimation)) = owner.tasks.get(a.index) else {
            return;
        };
        let msg = TaskAssign {
            task_id: a.task,
            scenario_hash: owner.hashes[scenario as usize].clone(),
            seed,
            record_decimation,
        };
        let time = owner
            .deadlines
            .get(scenario as usize)
            .copied()
            .unwrap_or(self.cfg.bounds.task_time_unknown);
        let due = self.now() + time;
        self.deadlines.push(due, a.task, worker.to_vec());
        self.send(Side::Worker, worker, a.task, Body::TaskAssign(msg));
    }

    pub(super) fn on_task_result(&mut self, worker: &[u8], task_id: u64, outcome: zmq::Message) {
        match self.disp.result(worker, task_id, outcome) {
            Completion::Accepted {
                source,
                done,
                total,
                finished,
                ..
            } => {
                self.stats.tasks_done += 1;
                self.stats.recent.push_back(Instant::now());
                if finished {
                    self.finish_source(source);
                } else {
                    self.maybe_progress(source, done, total);
                }
            }
            Completion::Dropped => {
                self.stats.duplicates += 1;
                tracing::debug!(task_id, peer = %hex(worker), "late, duplicate or foreign result dropped");
            }
        }
    }

    fn maybe_progress(&mut self, source: SourceId, done: usize, total: usize) {
        let Some(SourceOwner {
            kind:
                OwnerKind::Batch {
                    client,
                    request_id,
                    progress: true,
                    last_progress,
                    ..
                },
            ..
        }) = self.sources.get_mut(&source)
        else {
            return;
        };
        if last_progress.elapsed() < Duration::from_millis(100) {
            return;
        }
        *last_progress = Instant::now();
        let (client, rid) = (client.clone(), *request_id);
        self.send(Side::Client, &client, rid, self.progress_body(done, total));
    }

    /// A batch's progress as its client gets it.
    pub(super) fn progress_body(&self, done: usize, total: usize) -> Body {
        Body::RolloutProgress(RolloutProgress {
            done: done as u32,
            total: total as u32,
            instance: self.instance.clone(),
        })
    }

    pub(super) fn finish_source(&mut self, source: SourceId) {
        let Some((_, outcomes)) = self.disp.tasks.take_results(source) else {
            return;
        };
        let Some(owner) = self.sources.remove(&source) else {
            return;
        };
        self.blobs.release(&owner.hashes);
        match owner.kind {
            OwnerKind::Batch {
                client, request_id, ..
            } => {
                let n = outcomes.len() as u32;
                self.send_with(
                    Side::Client,
                    &client,
                    request_id,
                    Body::RolloutResult(RolloutResult { outcomes: n }),
                    outcomes,
                );
            }
            OwnerKind::Job { job_id } => {
                self.job_sources.remove(&job_id);
                let outcomes = outcomes.iter().map(|m| m.to_vec()).collect();
                self.tell_office(Command::RoundDone { job_id, outcomes });
            }
        }
    }

    /// A client's batch: its size is checked here, its scenarios by the back office,
    /// which hands it back to be queued ([`Broker::queue`]).
    pub(super) fn on_batch(
        &mut self,
        client: ClientKey,
        who: Principal,
        rid: u64,
        batch: paddock_proto::RolloutBatch,
    ) {
        let limit = self
            .cfg
            .limits
            .max_tasks_per_client
            .min(self.cfg.limits.max_tasks);
        if batch.tasks.len() > limit {
            return self.refuse(
                Side::Client,
                &client,
                rid,
                error(
                    ErrorCode::InvalidArgument,
                    "rollout_batch.tasks",
                    format!(
                        "{} tasks exceed the {limit} one client may queue: split the batch",
                        batch.tasks.len()
                    ),
                ),
            );
        }
        self.tell_office(Command::CheckBatch {
            client,
            who,
            rid,
            batch,
        });
    }

    /// Queues a checked batch or a job round: its tasks in the scheduler, its scenarios
    /// (hash, bytes) held until it finishes. Err: why there is no room.
    pub(super) fn queue(
        &mut self,
        kind: OwnerKind,
        scenarios: Vec<(String, Vec<u8>)>,
        deadlines: Vec<Duration>,
        tasks: &[RolloutTaskSpec],
    ) -> Result<SourceId, String> {
        // per-client bounds count by principal: every connection of one CURVE key (or
        // client token) is one client
        let key = match &kind {
            OwnerKind::Batch { who, .. } => who.clone().into_bytes(),
            OwnerKind::Job { job_id } => format!("job:{job_id}").into_bytes(),
        };
        let hashes: Vec<String> = scenarios.iter().map(|(h, _)| h.clone()).collect();
        let blobs = scenarios
            .into_iter()
            .map(|(h, b)| {
                let n = b.len();
                (h, b, n)
            })
            .collect();
        self.blobs.take(blobs).map_err(|e| e.to_string())?;
        let source = match self.disp.tasks.submit(&key, tasks.len()) {
            Ok(s) => s,
            Err(busy) => {
                self.blobs.release(&hashes);
                return Err(busy.to_string());
            }
        };
        self.sources.insert(
            source,
            SourceOwner {
                kind,
                tasks: tasks
                    .iter()
                    .map(|t| (t.scenario, t.seed, t.record_decimation))
                    .collect(),
                hashes,
                deadlines,
            },
        );
        // an empty batch is finished already
        self.finish_source(source);
        Ok(source)
    }

    /// A worker asks for a scenario (or another blob) by hash: from the sources in
    /// flight, else from what the back office keeps on disk.
    pub(super) fn on_blob_request(&mut self, worker: Vec<u8>, rid: u64, hash: String) {
        match self.blobs.get(&hash) {
            Some(data) => {
                let blob = paddock_proto::Blob {
                    hash,
                    data: data.clone(),
                };
                self.send(Side::Worker, &worker, rid, Body::Blob(blob));
            }
            None => self.tell_office(Command::BlobRequest { worker, rid, hash }),
        }
    }

    /// Job rounds that found no room in the queues, tried again.
    pub(super) fn queue_waiting_rounds(&mut self) {
        for _ in 0..self.waiting_rounds.len() {
            let Some((job_id, scenarios, deadlines, tasks)) = self.waiting_rounds.pop_front()
            else {
                break;
            };
            self.queue_round(job_id, scenarios, deadlines, tasks);
        }
    }

    /// Queues a job's round, or keeps it waiting when the queues are full.
    pub(super) fn queue_round(
        &mut self,
        job_id: String,
        scenarios: Vec<(String, Vec<u8>)>,
        deadlines: Vec<Duration>,
        tasks: Vec<RolloutTaskSpec>,
    ) {
        let kind = OwnerKind::Job {
            job_id: job_id.clone(),
        };
        match self.queue(kind, scenarios.clone(), deadlines.clone(), &tasks) {
            Ok(source) => {
                if self.sources.contains_key(&source) {
                    self.job_sources.insert(job_id, source);
                }
            }
            Err(_) => self
                .waiting_rounds
                .push_back((job_id, scenarios, deadlines, tasks)),
        }
    }
}
