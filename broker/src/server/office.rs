//! The socket thread's side of the back office: commands go out on a channel, events
//! come back on another (with a doorbell frame that wakes the poll), and the socket
//! thread carries them out: replies to send, checked batches and job rounds to queue,
//! rounds to cancel.

use super::{Broker, OwnerKind, Side};
use crate::office::{Command, Event, Owner};

impl Broker {
    /// Drops a batch or round: its open tasks (late results are dropped) and the
    /// scenarios it held.
    pub(super) fn cancel_source(&mut self, source: crate::core::SourceId) {
        self.disp.tasks.cancel(source);
        if let Some(owner) = self.sources.remove(&source) {
            self.blobs.release(&owner.hashes);
            if let OwnerKind::Job { job_id } = &owner.kind {
                self.job_sources.remove(job_id);
            }
        }
    }

    /// How long a task of each scenario may take on a worker.
    fn task_times(
        &self,
        budgets: &[Option<crate::plan::TaskBudget>],
        n: usize,
    ) -> Vec<std::time::Duration> {
        let b = &self.cfg.bounds;
        (0..n)
            .map(|i| match budgets.get(i).copied().flatten() {
                Some(t) if t.sim_seconds.is_finite() && t.sim_seconds >= 0.0 => {
                    let per = (t.sim_seconds * b.task_time_per_sim_s).min(86_400.0);
                    b.task_time_base + std::time::Duration::from_secs_f64(per.max(0.0))
                }
                _ => b.task_time_unknown,
            })
            .collect()
    }

    pub(super) fn tell_office(&mut self, command: Command) {
        if self.to_office.send(command).is_err() {
            tracing::error!("the back office has stopped; request dropped");
        }
    }

    pub(super) fn on_office(&mut self, event: Event) {
        match event {
            Event::Send {
                to_worker,
                peer,
                rid,
                body,
                frames,
            } => {
                let side = if to_worker {
                    Side::Worker
                } else {
                    Side::Client
                };
                match *body {
                    paddock_proto::Body::Error(e) => self.refuse(side, &peer, rid, e),
                    body => {
                        let frames = frames.into_iter().map(zmq::Message::from).collect();
                        self.send_with(side, &peer, rid, body, frames);
                    }
                }
            }
            Event::Queue {
                owner,
                scenarios,
                budgets,
                tasks,
            } => match owner {
                Owner::Batch {
                    client,
                    who,
                    rid,
                    progress,
                } => {
                    let kind = OwnerKind::Batch {
                        client: client.clone(),
                        who,
                        request_id: rid,
                        progress,
                        last_progress: std::time::Instant::now(),
                    };
                    let deadlines = self.task_times(&budgets, scenarios.len());
                    if let Err(why) = self.queue(kind, scenarios, deadlines, &tasks) {
                        self.refuse(
                            Side::Client,
                            &client,
                            rid,
                            paddock_proto::error(
                                paddock_proto::ErrorCode::Busy,
                                "rollout_batch.tasks",
                                why,
                            ),
                        );
                    }
                }
                Owner::Job { job_id } => {
                    let deadlines = self.task_times(&budgets, scenarios.len());
                    self.queue_round(job_id, scenarios, deadlines, tasks)
                }
            },
            Event::Cancel { job_id } => {
                self.waiting_rounds.retain(|r| r.0 != job_id);
                if let Some(source) = self.job_sources.remove(&job_id) {
                    self.cancel_source(source);
                }
            }
            Event::Active { jobs } => self.stats.jobs_active = jobs,
        }
    }
}
