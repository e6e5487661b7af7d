//! The worker's side of the heartbeat protocol, free of sockets and of the wall clock:
//! every method takes `now`, so "the broker is dead after 3 missed beats" and the
//! reconnect backoff are unit tests with a virtual clock.

use std::time::{Duration, Instant};

/// When to send a heartbeat and when the broker counts as dead.
#[derive(Debug, Clone)]
pub struct Liveness {
    interval: Duration,
    missed_allowed: u32,
    last_heard: Instant,
    last_sent: Instant,
}

impl Liveness {
    /// A fresh connection at `now`: heard and sent just now.
    pub fn new(interval: Duration, missed_allowed: u32, now: Instant) -> Self {
        Self {
            interval,
            missed_allowed: missed_allowed.max(1),
            last_heard: now,
            last_sent: now,
        }
    }

    /// The broker's welcome may change the beat and the tolerance.
    pub fn configure(&mut self, interval: Duration, missed_allowed: u32) {
        if !interval.is_zero() {
            self.interval = interval;
        }
        if missed_allowed > 0 {
            self.missed_allowed = missed_allowed;
        }
    }

    pub fn interval(&self) -> Duration {
        self.interval
    }

    /// Any message from the broker counts as a sign of life.
    pub fn heard(&mut self, now: Instant) {
        self.last_heard = now;
    }

    /// Any message to the broker counts as a heartbeat.
    pub fn sent(&mut self, now: Instant) {
        self.last_sent = now;
    }

    /// Whether a heartbeat is due.
    pub fn beat_due(&self, now: Instant) -> bool {
        now.saturating_duration_since(self.last_sent) >= self.interval
    }

    /// Whether the broker missed `missed_allowed` beats in a row.
    pub fn broker_dead(&self, now: Instant) -> bool {
        now.saturating_duration_since(self.last_heard) >= self.interval * self.missed_allowed
    }

    /// How long the loop may wait before it has something to do.
    pub fn wait(&self, now: Instant) -> Duration {
        let beat = (self.last_sent + self.interval).saturating_duration_since(now);
        let dead =
            (self.last_heard + self.interval * self.missed_allowed).saturating_duration_since(now);
        beat.min(dead)
    }
}

/// Exponential reconnect backoff: `initial`, doubling up to `max`; reset once the broker
/// answers.
#[derive(Debug, Clone)]
pub struct Backoff {
    initial: Duration,
    max: Duration,
    next: Duration,
}

impl Backoff {
    pub fn new(initial: Duration, max: Duration) -> Self {
        Self {
            initial,
            max: max.max(initial),
            next: initial,
        }
    }

    /// The pause before the next attempt; later attempts wait longer.
    pub fn next_delay(&mut self) -> Duration {
        let d = self.next;
        self.next = (self.next * 2).min(self.max);
        d
    }

    /// The broker answered: the next failure starts from `initial` again.
    pub fn reset(&mut self) {
        self.next = self.initial;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn broker_dead_after_three_missed_beats() {
        let t0 = Instant::now();
        let s = Duration::from_secs(1);
        let mut l = Liveness::new(s, 3, t0);
        assert!(!l.beat_due(t0));
        assert!(l.beat_due(t0 + s));
        l.sent(t0 + s);
        assert!(!l.beat_due(t0 + s + Duration::from_millis(999)));
        assert!(!l.broker_dead(t0 + Duration::from_millis(2999)));
        assert!(l.broker_dead(t0 + 3 * s));
        l.heard(t0 + Duration::from_millis(2500));
        assert!(!l.broker_dead(t0 + 3 * s));
        assert!(l.broker_dead(t0 + Duration::from_millis(5500)));
        assert_eq!(
            l.wait(t0 + Duration::from_millis(1500)),
            Duration::from_millis(500)
        );
        l.configure(Duration::from_millis(100), 5);
        assert!(l.broker_dead(t0 + Duration::from_millis(3000)));
        assert!(!l.broker_dead(t0 + Duration::from_millis(2999)));
        l.configure(Duration::ZERO, 0);
        assert_eq!(l.interval(), Duration::from_millis(100));
    }

    #[test]
    fn backoff_doubles_to_a_cap_and_resets() {
        let ms = Duration::from_millis;
        let mut b = Backoff::new(ms(100), ms(500));
        let seq: Vec<Duration> = (0..5).map(|_| b.next_delay()).collect();
        assert_eq!(seq, [ms(100), ms(200), ms(400), ms(500), ms(500)]);
        b.reset();
        assert_eq!(b.next_delay(), ms(100));
    }
}
