//! Rollout tasks: handing queued tasks to workers, progress, and the reduction of a
//! finished batch or job round; tasks given up after repeated worker deaths.

use std::time::{Duration, Instant};

use paddock_proto::{
    Body, ErrorCode, RolloutProgress, RolloutResult, TaskAssign, TaskOutcome, error, task_outcome,
};

use super::{Broker, Side, SourceOwner};
use crate::core::{Assigned, ClientKey, Completion, SourceId};
use crate::jobs::{batch_tasks, check_batch};

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
            if let Completion::Accepted {
                source,
                finished: true,
                ..
            } = self.disp.tasks.complete(t, outcome)
            {
                self.finish_source(source);
            }
        }
    }

    // ------------------------------------------------------------------ tasks

    pub(super) fn dispatch(&mut self) {
        for (worker, a) in self.disp.dispatch() {
            self.assign(&worker, &a);
        }
    }

    pub(super) fn assign(&mut self, worker: &[u8], a: &Assigned) {
        let Some(owner) = self.sources.get(&a.source) else {
            return;
        };
        let t = owner.task(a.index);
        let msg = TaskAssign {
            task_id: a.task,
            scenario: Some((*t.scenario).clone()),
            seed: t.seed,
            record_decimation: t.record_decimation,
        };
        self.send(Side::Worker, worker, a.task, Body::TaskAssign(msg));
    }

    pub(super) fn maybe_progress(&mut self, source: SourceId, done: usize, total: usize) {
        let Some(SourceOwner::Batch {
            client,
            request_id,
            progress: true,
            last_progress,
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
        self.send(
            Side::Client,
            &client,
            rid,
            Body::RolloutProgress(RolloutProgress {
                done: done as u32,
                total: total as u32,
            }),
        );
    }

    pub(super) fn finish_source(&mut self, source: SourceId) {
        let Some((_, outcomes)) = self.disp.tasks.take_results(source) else {
            return;
        };
        match self.sources.remove(&source) {
            Some(SourceOwner::Batch {
                client, request_id, ..
            }) => {
                self.send(
                    Side::Client,
                    &client,
                    request_id,
                    Body::RolloutResult(RolloutResult { outcomes }),
                );
            }
            Some(SourceOwner::Job { job_id, .. }) => self.job_round_done(&job_id, outcomes),
            None => {}
        }
    }

    pub(super) fn on_batch(
        &mut self,
        client: ClientKey,
        rid: u64,
        batch: paddock_proto::RolloutBatch,
    ) {
        let scenarios = match check_batch(&batch, &self.store, "rollout_batch") {
            Ok(s) => s,
            Err(e) => return self.refuse(Side::Client, &client, rid, e),
        };
        let tasks = batch_tasks(&batch, &scenarios);
        let limit = self
            .cfg
            .limits
            .max_tasks_per_client
            .min(self.cfg.limits.max_tasks);
        if tasks.len() > limit {
            return self.refuse(
                Side::Client,
                &client,
                rid,
                error(
                    ErrorCode::InvalidArgument,
                    "rollout_batch.tasks",
                    format!(
                        "{} tasks exceed the {limit} one client may queue: split the batch",
                        tasks.len()
                    ),
                ),
            );
        }
        match self.disp.tasks.submit(&client, tasks.len()) {
            Ok(source) => {
                self.sources.insert(
                    source,
                    SourceOwner::Batch {
                        client,
                        request_id: rid,
                        tasks,
                        progress: batch.progress,
                        last_progress: Instant::now(),
                    },
                );
                // an empty batch is finished already
                self.finish_source(source);
            }
            Err(busy) => self.refuse(
                Side::Client,
                &client,
                rid,
                error(ErrorCode::Busy, "rollout_batch.tasks", busy.to_string()),
            ),
        }
    }
}
