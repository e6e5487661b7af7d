//! The back office's jobs: submissions, queries (status, list, result, watch, cancel),
//! their rounds handed to the socket thread and their outcomes told to the plan, the job
//! stored after every round and resumed at start.

use super::*;

pub(super) fn job_state(state: JobState) -> i32 {
    state as i32
}

pub(super) fn is_finished(state: i32) -> bool {
    state == JobState::Succeeded as i32
        || state == JobState::Failed as i32
        || state == JobState::CancelledJob as i32
}

pub(super) fn info_of(r: &JobRecord) -> JobInfo {
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
pub(super) fn pack_outcomes(outcomes: &[Vec<u8>]) -> Vec<u8> {
    let mut out = Vec::with_capacity(outcomes.iter().map(|o| o.len() + 8).sum());
    for o in outcomes {
        out.extend_from_slice(&(o.len() as u64).to_le_bytes());
        out.extend_from_slice(o);
    }
    out
}

pub(super) fn unpack_outcomes(mut bytes: &[u8]) -> Vec<Vec<u8>> {
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

/// Who asks about jobs: the client's principal, and whether it is an admin key.
#[derive(Clone, Copy)]
pub(super) struct Asker<'a> {
    pub owner: &'a str,
    pub admin: bool,
}

impl Asker<'_> {
    /// Whether it may see and manage `rec` (jobs stored before jobs had owners are
    /// everyone's).
    fn may(&self, rec: &JobRecord) -> bool {
        self.admin || rec.owner == self.owner || rec.owner.is_empty()
    }
}

/// Jobs a listing carries at most (the newest).
pub(super) const MAX_LISTED_JOBS: usize = 1000;

impl State {
    pub(super) fn on_job(
        &mut self,
        client: ClientKey,
        owner: &str,
        admin: bool,
        rid: u64,
        body: Body,
    ) {
        let who = Asker { owner, admin };
        match body {
            Body::JobSubmit(s) => self.submit(client, owner, rid, s),
            Body::JobStatus(r) => {
                if let Some(rec) =
                    self.job_record(&client, who, rid, &r.job_id, "job_status.job_id")
                {
                    self.reply(&client, rid, Body::JobInfo(info_of(&rec)));
                }
            }
            Body::JobList(_) => match self
                .store
                .jobs_of((!admin).then_some(owner), MAX_LISTED_JOBS)
            {
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
            Body::JobCancel(c) => self.cancel(&client, who, rid, &c.job_id),
            Body::JobDelete(d) => self.delete(&client, who, rid, &d.job_id),
            Body::JobResultRequest(r) => {
                if let Some(rec) =
                    self.job_record(&client, who, rid, &r.job_id, "job_result_request.job_id")
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
                if let Some(rec) = self.job_record(&client, who, rid, &w.job_id, "job_watch.job_id")
                {
                    self.reply(&client, rid, Body::JobInfo(info_of(&rec)));
                    if let Some(j) = self.jobs.get_mut(&w.job_id) {
                        j.watchers.push((client, rid));
                    }
                }
            }
            _ => {}
        }
    }

    /// Job `id` if `who` may see it; else a NOT_FOUND reply (the same for a job of
    /// another client as for no job, so ids cannot be probed).
    pub(super) fn job_record(
        &self,
        client: &[u8],
        who: Asker<'_>,
        rid: u64,
        id: &str,
        field: &str,
    ) -> Option<JobRecord> {
        let found = match self.jobs.get(id) {
            Some(j) => Ok(Some(j.record.clone())),
            None => self.store.job(id),
        };
        match found {
            Ok(Some(r)) if who.may(&r) => Some(r),
            Ok(_) => {
                let id = crate::server::clip(id, 80);
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

    /// Refuses a submission over a size bound; true when it is within them.
    fn submission_fits(&self, client: &[u8], owner: &str, rid: u64, submit: &JobSubmit) -> bool {
        let l = &self.limits;
        let refusal = if submit.name.len() > l.max_job_name_bytes {
            Some(error(
                ErrorCode::InvalidArgument,
                "job_submit.name",
                format!(
                    "job_submit.name has {} bytes, the limit is {}",
                    submit.name.len(),
                    l.max_job_name_bytes
                ),
            ))
        } else if submit.encoded_len() > l.max_job_submit_bytes {
            Some(error(
                ErrorCode::TooLarge,
                "job_submit",
                format!(
                    "the job submission has {} bytes, the limit is {}",
                    submit.encoded_len(),
                    l.max_job_submit_bytes
                ),
            ))
        } else {
            match self.store.count_jobs(Some(owner)) {
                Ok(n) if n >= l.max_jobs_per_client => Some(error(
                    ErrorCode::Busy,
                    "job_submit",
                    format!(
                        "this client has {n} jobs stored, the limit is {}: delete finished ones (paddock jobs delete)",
                        l.max_jobs_per_client
                    ),
                )),
                Ok(_) => None,
                Err(e) => Some(error(ErrorCode::Internal, "job_submit", e.to_string())),
            }
        };
        match refusal {
            Some(e) => {
                self.refuse(client, rid, e);
                false
            }
            None => true,
        }
    }

    pub(super) fn submit(&mut self, client: ClientKey, owner: &str, rid: u64, submit: JobSubmit) {
        if !self.submission_fits(&client, owner, rid, &submit) {
            return;
        }
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
            owner: owner.to_string(),
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

    pub(super) fn active_changed(&self) {
        self.emit(Event::Active {
            jobs: self.jobs.len() as u32,
        });
    }

    /// Deletes a job (cancelling it first when it is queued or running).
    pub(super) fn delete(&mut self, client: &[u8], who: Asker<'_>, rid: u64, id: &str) {
        if self
            .job_record(client, who, rid, id, "job_delete.job_id")
            .is_none()
        {
            return;
        }
        self.stop_job(id);
        match self.store.delete_job(id) {
            Ok(_) => {
                tracing::info!(job_id = id, "job deleted");
                let done = paddock_proto::JobDeleted {
                    job_id: id.to_string(),
                };
                self.reply(client, rid, Body::JobDeleted(done));
            }
            Err(e) => self.refuse(
                client,
                rid,
                error(ErrorCode::Internal, "job_delete.job_id", e.to_string()),
            ),
        }
    }

    /// Cancels job `id` if it is queued or running: its round dropped, its row stored
    /// as cancelled, its watchers told. The cancelled record, or None when it was not
    /// active.
    fn stop_job(&mut self, id: &str) -> Option<JobRecord> {
        let j = self.jobs.remove(id)?;
        if j.in_round {
            self.emit(Event::Cancel {
                job_id: id.to_string(),
            });
        }
        let mut rec = j.record;
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
        Some(rec)
    }

    pub(super) fn cancel(&mut self, client: &[u8], who: Asker<'_>, rid: u64, id: &str) {
        let Some(mut rec) = self.job_record(client, who, rid, id, "job_cancel.job_id") else {
            return;
        };
        if let Some(stopped) = self.stop_job(id) {
            rec = stopped;
        }
        self.reply(client, rid, Body::JobInfo(info_of(&rec)));
    }

    pub(super) fn resume_jobs(&mut self) -> Result<(), BrokerError> {
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
    pub(super) fn pump_jobs(&mut self) {
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
                    let budgets = scenarios.iter().map(|s| self.planner.budget(s)).collect();
                    let scenarios = scenarios
                        .into_iter()
                        .map(|s| (paddock_proto::blob_hash(&s), s))
                        .collect();
                    self.emit(Event::Queue {
                        owner: Owner::Job { job_id: id },
                        scenarios,
                        budgets,
                        tasks,
                    });
                }
                Ok(None) => self.end_job(&id, None),
                Err(e) => self.end_job(&id, Some(e)),
            }
        }
    }

    pub(super) fn round_done(&mut self, id: &str, outcomes: Vec<Vec<u8>>) {
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

    pub(super) fn end_job(&mut self, id: &str, failure: Option<String>) {
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
