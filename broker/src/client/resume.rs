//! Requests that outlive a broker restart.
//!
//! A rollout batch is idempotent: its outcomes are a pure function of its scenarios and
//! seeds, so running it twice gives the same bits. A broker that restarts loses the
//! batches it was running (jobs are stored; batches are not), so the client watches the
//! broker while it waits and sends the batch again when the broker that took it is gone.
//!
//! The broker draws an instance id when its process starts (`BrokerStatus.instance`,
//! also carried by `RolloutProgress`). The client sends a `StatusRequest` right before
//! each send of the request (the *opening* status: its answer names the instance that
//! took the request). When nothing comes for the request for [`ResumePolicy::quiet`],
//! the client asks for the status again, every [`ResumePolicy::ping_every`]:
//!
//! - the instance that holds the request answers: it is still running there; wait on;
//! - another instance answers (or the opening status was never answered): the broker
//!   restarted and lost the request; send it again, at most
//!   [`ResumePolicy::max_resends`] times. The first final reply to any send is the
//!   answer, so results are taken once, never twice;
//! - nobody answers within [`ResumePolicy::answer_within`]: the broker does not answer
//!   ([`super::ClientError::NotAnswering`]).
//!
//! ZeroMQ's DEALER socket reconnects by itself, so the new sends (and the status
//! requests) reach the restarted broker on the same endpoint. The rules live in
//! [`Watch`], a state machine without sockets, tested here with a virtual clock.

use std::collections::HashSet;
use std::time::{Duration, Instant};

use paddock_proto::{Body, StatusRequest};

use super::{Client, ClientError, Received};

/// How a resumable request watches the broker.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ResumePolicy {
    /// Silence on the request after which the client asks the broker's status.
    pub quiet: Duration,
    /// How long a status request may go unanswered before the broker is given up.
    pub answer_within: Duration,
    /// How often the status is asked again while it goes unanswered (a request may
    /// have been lost with the connection of a broker that died).
    pub ping_every: Duration,
    /// How many times the request is sent again after restarts of the broker.
    pub max_resends: u32,
}

impl Default for ResumePolicy {
    fn default() -> Self {
        Self {
            quiet: Duration::from_secs(3),
            answer_within: Duration::from_secs(10),
            ping_every: Duration::from_secs(1),
            max_resends: 3,
        }
    }
}

/// What the client does next.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Next {
    /// Wait for a message, at most this long.
    Wait(Duration),
    /// Ask for the broker's status.
    Ping,
    /// Give up: no status reply within this long.
    NotAnswering(Duration),
}

/// What a status reply to a ping means.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Answer {
    /// The broker that holds the request answered: wait on.
    Alive,
    /// Another broker instance answered: send the request again.
    Resend,
    /// Another instance answered after the last allowed re-send: give up, after this
    /// many sends in all.
    GiveUp(u32),
}

/// The rules of a resumable request (module docs), without sockets or clocks: the
/// caller passes the time.
#[derive(Debug, Clone)]
pub struct Watch {
    policy: ResumePolicy,
    /// The instance believed to hold the current send (None: its opening status is
    /// not answered yet).
    holder: Option<String>,
    last_heard: Instant,
    /// When the first unanswered status request of this silence was sent.
    asking_since: Option<Instant>,
    last_ping: Instant,
    sends: u32,
}

impl Watch {
    /// A watch of a request sent (the first time) at `now`.
    pub fn new(policy: ResumePolicy, now: Instant) -> Self {
        Self {
            policy,
            holder: None,
            last_heard: now,
            asking_since: None,
            last_ping: now,
            sends: 1,
        }
    }

    /// How many times the request was sent.
    pub fn sends(&self) -> u32 {
        self.sends
    }

    /// The request was sent again at `now`.
    pub fn resent(&mut self, now: Instant) {
        self.sends += 1;
        self.holder = None;
        self.heard(now);
    }

    /// Anything that shows the request alive (progress of an earlier send, say).
    pub fn heard(&mut self, now: Instant) {
        self.last_heard = now;
        self.asking_since = None;
    }

    /// The opening status of the current send was answered by `instance`.
    pub fn opened(&mut self, now: Instant, instance: &str) {
        self.holder = Some(instance.to_string());
        self.heard(now);
    }

    /// Progress of the current send, from broker instance `instance` (empty: a broker
    /// that does not say): that instance holds the request.
    pub fn progress(&mut self, now: Instant, instance: &str) {
        if !instance.is_empty() {
            self.holder = Some(instance.to_string());
        }
        self.heard(now);
    }

    /// A status request sent since the current send was answered by `instance`.
    pub fn answered(&mut self, now: Instant, instance: &str) -> Answer {
        if self.holder.as_deref() == Some(instance) {
            self.heard(now);
            return Answer::Alive;
        }
        if self.sends > self.policy.max_resends {
            Answer::GiveUp(self.sends)
        } else {
            Answer::Resend
        }
    }

    /// What to do at `now`.
    pub fn next(&mut self, now: Instant) -> Next {
        let p = &self.policy;
        match self.asking_since {
            None => {
                let idle = now.saturating_duration_since(self.last_heard);
                if idle >= p.quiet {
                    self.asking_since = Some(now);
                    self.last_ping = now;
                    Next::Ping
                } else {
                    Next::Wait(p.quiet - idle)
                }
            }
            Some(since) => {
                let waited = now.saturating_duration_since(since);
                if waited >= p.answer_within {
                    return Next::NotAnswering(p.answer_within);
                }
                let since_ping = now.saturating_duration_since(self.last_ping);
                if since_ping >= p.ping_every {
                    self.last_ping = now;
                    Next::Ping
                } else {
                    Next::Wait((p.ping_every - since_ping).min(p.answer_within - waited))
                }
            }
        }
    }
}

fn status_request() -> Body {
    Body::StatusRequest(StatusRequest {})
}

impl Client {
    /// Sends an idempotent request (a `RolloutBatch`) and waits for its final reply,
    /// through restarts of the broker (module docs): the request is sent again when
    /// another broker instance answers, and a broker that does not answer a status
    /// request within `policy.answer_within` ends the wait with
    /// [`ClientError::NotAnswering`]. `on_update` sees the progress messages of the
    /// current send. An `Error` reply is returned as [`ClientError::Remote`].
    pub fn request_resumable(
        &mut self,
        body: Body,
        policy: &ResumePolicy,
        mut on_update: impl FnMut(&Body),
    ) -> Result<Received, ClientError> {
        let mut opening = self.send(status_request())?;
        let mut current = self.send(body.clone())?;
        let mut sends = HashSet::from([current]);
        // status requests sent since the current send (earlier ones are not about it)
        let mut pings = HashSet::new();
        let mut watch = Watch::new(*policy, Instant::now());
        loop {
            let wait = match watch.next(Instant::now()) {
                Next::Wait(d) => d,
                Next::Ping => {
                    pings.insert(self.send(status_request())?);
                    continue;
                }
                Next::NotAnswering(waited) => return Err(ClientError::NotAnswering(waited)),
            };
            let reply = match self.recv(wait) {
                Ok(r) => r,
                Err(ClientError::Timeout(_)) => continue,
                Err(e) => return Err(e),
            };
            let now = Instant::now();
            let rid = reply.request_id;
            if rid == opening || pings.contains(&rid) {
                let Body::BrokerStatus(status) = &reply.body else {
                    continue;
                };
                if rid == opening {
                    watch.opened(now, &status.instance);
                    continue;
                }
                match watch.answered(now, &status.instance) {
                    Answer::Alive => {}
                    Answer::Resend => {
                        tracing::info!(
                            instance = %status.instance,
                            "the broker restarted and lost the request: sending it again"
                        );
                        pings.clear();
                        opening = self.send(status_request())?;
                        current = self.send(body.clone())?;
                        sends.insert(current);
                        watch.resent(now);
                    }
                    Answer::GiveUp(sends) => return Err(ClientError::Restarted(sends)),
                }
                continue;
            }
            if !sends.contains(&rid) {
                continue; // a reply to an earlier request, or an earlier opening status
            }
            match reply.body {
                Body::Error(e) => return Err(ClientError::Remote(e)),
                Body::RolloutProgress(ref p) => {
                    if rid == current {
                        watch.progress(now, &p.instance);
                        on_update(&reply.body);
                    } else {
                        watch.heard(now);
                    }
                }
                _ => return Ok(reply),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const S: Duration = Duration::from_secs(1);

    fn policy() -> ResumePolicy {
        ResumePolicy {
            quiet: 3 * S,
            answer_within: 10 * S,
            ping_every: S,
            max_resends: 2,
        }
    }

    #[test]
    fn a_quiet_request_pings_after_the_quiet_time_and_waits_on_when_its_broker_answers() {
        let t0 = Instant::now();
        let mut w = Watch::new(policy(), t0);
        w.opened(t0, "a");
        assert_eq!(w.next(t0), Next::Wait(3 * S));
        assert_eq!(w.next(t0 + 2 * S), Next::Wait(S));
        assert_eq!(w.next(t0 + 3 * S), Next::Ping);
        // unanswered for a while: pinged again every second
        assert_eq!(w.next(t0 + 3 * S), Next::Wait(S));
        assert_eq!(w.next(t0 + 4 * S), Next::Ping);
        assert_eq!(w.answered(t0 + 5 * S, "a"), Answer::Alive);
        assert_eq!(w.next(t0 + 5 * S), Next::Wait(3 * S));
        assert_eq!(w.sends(), 1);
    }

    #[test]
    fn progress_keeps_a_request_from_pinging() {
        let t0 = Instant::now();
        let mut w = Watch::new(policy(), t0);
        w.opened(t0, "a");
        for k in 1..10 {
            w.progress(t0 + 2 * k * S, "a");
            assert_eq!(w.next(t0 + 2 * k * S + S), Next::Wait(2 * S));
        }
    }

    #[test]
    fn another_instance_answering_means_send_again_a_bounded_number_of_times() {
        let t0 = Instant::now();
        let mut w = Watch::new(policy(), t0);
        w.opened(t0, "a");
        assert_eq!(w.next(t0 + 3 * S), Next::Ping);
        assert_eq!(w.answered(t0 + 4 * S, "b"), Answer::Resend);
        w.resent(t0 + 4 * S);
        assert_eq!(w.next(t0 + 4 * S), Next::Wait(3 * S));
        w.opened(t0 + 4 * S, "b");
        assert_eq!(w.next(t0 + 7 * S), Next::Ping);
        assert_eq!(w.answered(t0 + 7 * S, "b"), Answer::Alive);
        assert_eq!(w.next(t0 + 10 * S), Next::Ping);
        assert_eq!(w.answered(t0 + 10 * S, "c"), Answer::Resend);
        w.resent(t0 + 10 * S);
        assert_eq!(w.next(t0 + 13 * S), Next::Ping);
        assert_eq!(w.answered(t0 + 13 * S, "d"), Answer::GiveUp(3));
    }

    #[test]
    fn a_send_whose_opening_status_went_unanswered_is_sent_again() {
        // the broker that got the opening status died before answering it: whoever
        // answers a later ping did not take the request
        let t0 = Instant::now();
        let mut w = Watch::new(policy(), t0);
        assert_eq!(w.next(t0 + 3 * S), Next::Ping);
        assert_eq!(w.answered(t0 + 4 * S, "b"), Answer::Resend);
    }

    #[test]
    fn progress_names_the_instance_that_holds_the_request() {
        // the opening status went to a broker that died; the send itself reached the
        // restarted one, which reports progress
        let t0 = Instant::now();
        let mut w = Watch::new(policy(), t0);
        w.progress(t0 + S, "b");
        assert_eq!(w.next(t0 + 4 * S), Next::Ping);
        assert_eq!(w.answered(t0 + 4 * S, "b"), Answer::Alive);
    }

    #[test]
    fn a_broker_that_does_not_answer_is_given_up_after_answer_within() {
        let t0 = Instant::now();
        let mut w = Watch::new(policy(), t0);
        w.opened(t0, "a");
        assert_eq!(w.next(t0 + 3 * S), Next::Ping);
        let mut pings = 1;
        let mut t = t0 + 3 * S;
        loop {
            match w.next(t) {
                Next::Ping => pings += 1,
                Next::Wait(d) => {
                    assert!(d <= S, "waits {d:?} between pings");
                    t += d;
                }
                Next::NotAnswering(waited) => {
                    assert_eq!(waited, 10 * S);
                    break;
                }
            }
        }
        assert_eq!(t, t0 + 13 * S, "given up 10 s after the first ping");
        assert_eq!(pings, 10, "one status request a second");
    }
}
