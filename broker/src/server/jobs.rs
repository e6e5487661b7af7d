//! Jobs: submission, rounds through the scheduler, storing after every round,
//! resuming stored jobs, status, cancel and watch.

use paddock_proto::{Body, ErrorCode, JobState, TaskOutcome, error};
use prost::Message;

use super::{Broker, BrokerError, RunningJob, Side, SourceOwner, info_of, is_finished, job_state};
use crate::core::ClientKey;
use crate::jobs::JobWork;
use crate::state::{JobRecord, unix_now};

impl Broker {
    pub(super) fn job_record(
        &mut self,
        client: &[u8],
        rid: u64,
        id: &str,
        field: &str,
    ) -> Option<JobRecord> {
        if let Some(j) = self.jobs.get(id) {
            return Some(j.record.clone());
        }
        match self.store.job(id) {
            Ok(Some(r)) => Some(r),
            Ok(None) => {
                self.refuse(
                    Side::Client,
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
                    Side::Client,
                    client,
                    rid,
                    error(ErrorCode::Internal, field, e.to_string()),
                );
                None
            }
        }
    }

    pub(super) fn on_job_submit(
        &mut self,
        client: ClientKey,
        rid: u64,
        submit: paddock_proto::JobSubmit,
    ) {
        let active = self.jobs.len();
        if active >= self.cfg.max_jobs {
            return self.refuse(
                Side::Client,
                &client,
                rid,
                error(
                    ErrorCode::Busy,
                    "job_submit",
                    format!(
                        "{active} jobs are queued or running, the limit is {}",
                        self.cfg.max_jobs
                    ),
                ),
            );
        }
        let (kind, work) = match JobWork::from_submit(&submit, &self.store) {
            Ok(x) => x,
            Err(e) => return self.refuse(Side::Client, &client, rid, e),
        };
        let now = unix_now();
        let (rounds_done, rounds_total) = work.rounds();
        let mut record = JobRecord {
            name: submit.name.clone(),
            kind: kind.into(),
            state: job_state(JobState::Queued),
            spec: submit.encode_to_vec(),
            job_state: work.state_json(),
            progress_json: work.progress_json(),
            rounds_done,
            rounds_total,
            created_at: now,
            updated_at: now,
            ..Default::default()
        };
        if let Err(e) = self.store.insert_job(&mut record) {
            return self.refuse(
                Side::Client,
                &client,
                rid,
                error(ErrorCode::Internal, "job_submit", e.to_string()),
            );
        }
        tracing::info!(job_id = %record.id, kind, name = %record.name, "job submitted");
        self.send(Side::Client, &client, rid, Body::JobInfo(info_of(&record)));
        self.jobs.insert(
            record.id.clone(),
            RunningJob {
                record,
                work,
                source: None,
                watchers: Vec::new(),
            },
        );
    }

    pub(super) fn on_job_cancel(&mut self, client: ClientKey, rid: u64, id: &str) {
        let Some(mut rec) = self.job_record(&client, rid, id, "job_cancel.job_id") else {
            return;
        };
        if let Some(j) = self.jobs.remove(id) {
            if let Some(s) = j.source {
                self.disp.tasks.cancel(s);
                self.sources.remove(&s);
            }
            rec = j.record;
            rec.state = job_state(JobState::CancelledJob);
            rec.updated_at = unix_now();
            if let Err(e) = self.store.update_job(&rec) {
                tracing::error!(job_id = id, error = %e, "storing a cancelled job failed");
            }
            tracing::info!(job_id = id, "job cancelled");
            for (c, w) in j.watchers {
                self.send(Side::Client, &c, w, Body::JobInfo(info_of(&rec)));
            }
        }
        self.send(Side::Client, &client, rid, Body::JobInfo(info_of(&rec)));
    }

    pub(super) fn resume_jobs(&mut self) -> Result<(), BrokerError> {
        for rec in self.store.jobs()? {
            if is_finished(rec.state) {
                continue;
            }
            match JobWork::restore(&rec.spec, &rec.job_state, &self.store) {
                Ok(work) => {
                    tracing::info!(job_id = %rec.id, rounds_done = rec.rounds_done, "job resumed");
                    self.jobs.insert(
                        rec.id.clone(),
                        RunningJob {
                            record: rec,
                            work,
                            source: None,
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
        Ok(())
    }

    /// Starts the next round of every job without one in flight.
    pub(super) fn pump_jobs(&mut self) {
        let idle: Vec<String> = self
            .jobs
            .iter()
            .filter(|(_, j)| j.source.is_none())
            .map(|(id, _)| id.clone())
            .collect();
        for id in idle {
            let Some(j) = self.jobs.get_mut(&id) else {
                continue;
            };
            let limit = self
                .cfg
                .limits
                .max_tasks_per_client
                .min(self.cfg.limits.max_tasks);
            match j.work.next_round() {
                Ok(Some(tasks)) if tasks.len() > limit => {
                    let n = tasks.len();
                    self.end_job(
                        &id,
                        Some(format!(
                            "a round of {n} tasks exceeds the queue limit of {limit}"
                        )),
                    );
                }
                Ok(Some(tasks)) => {
                    let key = format!("job:{id}").into_bytes();
                    match self.disp.tasks.submit(&key, tasks.len()) {
                        Ok(source) => {
                            j.source = Some(source);
                            if j.record.state == job_state(JobState::Queued) {
                                j.record.state = job_state(JobState::Running);
                            }
                            self.sources.insert(
                                source,
                                SourceOwner::Job {
                                    job_id: id.clone(),
                                    tasks,
                                },
                            );
                            self.finish_source(source);
                        }
                        // the queue is full: the round waits for room
                        Err(_) => continue,
                    }
                }
                Ok(None) => self.end_job(&id, None),
                Err(e) => self.end_job(&id, Some(e)),
            }
        }
    }

    pub(super) fn job_round_done(&mut self, id: &str, outcomes: Vec<TaskOutcome>) {
        let Some(j) = self.jobs.get_mut(id) else {
            return;
        };
        j.source = None;
        if let Err(e) = j.work.tell(outcomes) {
            return self.end_job(id, Some(e));
        }
        let (done, total) = j.work.rounds();
        j.record.rounds_done = done;
        j.record.rounds_total = total;
        j.record.episodes_done = j.work.episodes_done();
        j.record.progress_json = j.work.progress_json();
        j.record.job_state = j.work.state_json();
        j.record.updated_at = unix_now();
        if let Some((json, bin)) = j.work.result() {
            j.record.result_json = json;
            j.record.result_bin = bin;
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
        }
        for (c, w) in watchers {
            self.send(Side::Client, &c, w, Body::JobInfo(info_of(&rec)));
        }
    }

    pub(super) fn end_job(&mut self, id: &str, failure: Option<String>) {
        let Some(mut j) = self.jobs.remove(id) else {
            return;
        };
        j.record.updated_at = unix_now();
        match failure {
            Some(e) => {
                j.record.state = job_state(JobState::Failed);
                j.record.error = e;
                *self.stats.errors.entry("INTERNAL".into()).or_default() += 1;
                tracing::warn!(job_id = id, error = %j.record.error, "job failed");
            }
            None => {
                if let Some((json, bin)) = j.work.result() {
                    j.record.result_json = json;
                    j.record.result_bin = bin;
                }
                j.record.state = job_state(JobState::Succeeded);
            }
        }
        if let Err(e) = self.store.update_job(&j.record) {
            tracing::error!(job_id = id, error = %e, "storing a finished job failed");
        }
        for (c, w) in j.watchers {
            self.send(Side::Client, &c, w, Body::JobInfo(info_of(&j.record)));
        }
    }
}
