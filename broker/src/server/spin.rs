//! When the broker polls without blocking instead of sleeping.
//!
//! After it forwards env-session traffic, the answer usually comes within a few tens of
//! microseconds (a one-env step, a learner's next action), and a loop that never slept
//! needs no wake-up. But a 64-env step keeps the worker's threads busy for most of a
//! millisecond; spinning through that wait only takes a core from them on a small
//! machine. So the broker remembers, per side, whether that side's last answer came
//! within the window, and spins while waiting for it only if so: one slow answer turns
//! the spin off for that side, the next quick one turns it back on.

use std::time::{Duration, Instant};

use super::Side;

/// The spin state of one broker loop.
pub(super) struct Spin {
    window: Duration,
    /// The side an answer is awaited from, and since when.
    armed: Option<(Side, Instant)>,
    /// Per side (client, worker): its last awaited answer took longer than the window.
    slow: [bool; 2],
}

fn index(side: Side) -> usize {
    match side {
        Side::Client => 0,
        Side::Worker => 1,
    }
}

impl Spin {
    /// A zero window never spins.
    pub(super) fn new(window: Duration) -> Self {
        Self {
            window,
            armed: None,
            slow: [false; 2],
        }
    }

    /// Env traffic was just forwarded to `side`: its answer is awaited from `now`.
    pub(super) fn arm(&mut self, side: Side, now: Instant) {
        if !self.window.is_zero() {
            self.armed = Some((side, now));
        }
    }

    /// Until when to poll without blocking: the end of the window if an answer is
    /// awaited from a side whose last answer came within it.
    pub(super) fn until(&self) -> Option<Instant> {
        match self.armed {
            Some((side, since)) if !self.slow[index(side)] => Some(since + self.window),
            _ => None,
        }
    }

    /// Messages arrived at `now` on the client socket and/or the worker socket: an
    /// answer from the awaited side ends the wait and records whether it was quick.
    pub(super) fn arrived(&mut self, client: bool, worker: bool, now: Instant) {
        if let Some((side, since)) = self.armed {
            let from_side = match side {
                Side::Client => client,
                Side::Worker => worker,
            };
            if from_side {
                self.slow[index(side)] = now.saturating_duration_since(since) > self.window;
                self.armed = None;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: Duration = Duration::from_micros(200);

    #[test]
    fn spins_for_quick_sides_only() {
        let t0 = Instant::now();
        let mut s = Spin::new(W);
        assert_eq!(s.until(), None, "nothing awaited: no spin");
        // first time: spin
        s.arm(Side::Worker, t0);
        assert_eq!(s.until(), Some(t0 + W));
        // the worker answers after 800 us: slow
        s.arrived(false, true, t0 + Duration::from_micros(800));
        assert_eq!(s.until(), None);
        // the client answers quickly
        let t1 = t0 + Duration::from_millis(1);
        s.arm(Side::Client, t1);
        assert_eq!(s.until(), Some(t1 + W));
        s.arrived(true, false, t1 + Duration::from_micros(50));
        // waiting for the slow worker again: sleep, not spin
        let t2 = t1 + Duration::from_millis(1);
        s.arm(Side::Worker, t2);
        assert_eq!(s.until(), None);
        // a client message does not end the wait for the worker
        s.arrived(true, false, t2 + Duration::from_micros(10));
        assert!(s.armed.is_some());
        // the worker is quick again: the next wait spins
        s.arrived(false, true, t2 + Duration::from_micros(60));
        s.arm(Side::Worker, t2 + Duration::from_millis(1));
        assert!(s.until().is_some());
        // the client side stayed quick
        s.arm(Side::Client, t2);
        assert!(s.until().is_some());
    }

    #[test]
    fn zero_window_never_spins() {
        let mut s = Spin::new(Duration::ZERO);
        s.arm(Side::Worker, Instant::now());
        assert_eq!(s.until(), None);
    }
}
