//! The socket thread's side of the back office: commands go out on a channel, events
//! come back on another (with a doorbell frame that wakes the poll), and the socket
//! thread carries them out: replies to send, checked batches and job rounds to queue,
//! rounds to cancel.

use super::{Broker, OwnerKind, Side};
use crate::office::{Command, Event, Owner};

impl Broker {
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
                if let paddock_proto::Body::Error(e) = &*body {
                    *self
                        .stats
                        .errors
                        .entry(paddock_proto::code_name(e.code).to_string())
                        .or_default() += 1;
                }
                let frames = frames.into_iter().map(zmq::Message::from).collect();
                self.send_with(side, &peer, rid, *body, frames);
            }
            Event::Queue {
                owner,
                scenarios,
                tasks,
            } => match owner {
                Owner::Batch {
                    client,
                    rid,
                    progress,
                } => {
                    let kind = OwnerKind::Batch {
                        client: client.clone(),
                        request_id: rid,
                        progress,
                        last_progress: std::time::Instant::now(),
                    };
                    if let Err(why) = self.queue(kind, scenarios, &tasks) {
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
                Owner::Job { job_id } => self.queue_round(job_id, scenarios, tasks),
            },
            Event::Cancel { job_id } => {
                self.waiting_rounds.retain(|(j, _, _)| *j != job_id);
                if let Some(source) = self.job_sources.remove(&job_id) {
                    self.disp.tasks.cancel(source);
                    if let Some(owner) = self.sources.remove(&source) {
                        self.blobs.release(&owner.hashes);
                    }
                }
            }
            Event::Active { jobs } => self.stats.jobs_active = jobs,
        }
    }
}
