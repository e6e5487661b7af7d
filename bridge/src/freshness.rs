//! How old a sensor's newest data is: by arrival and by header stamp.
//!
//! Arrival time alone trusts the sensor: a driver that re-sends an old scan, or a bag
//! replayed into the car, arrives on time and looks fresh. So each sensor's age is the
//! larger of
//!
//! - its **arrival age**: time since the newest accepted message arrived, and
//! - its **stamp age**: how much older the newest stamp is than it would be had it
//!   arrived with the least delay seen, `now - (stamp + offset)`. The stamp clock (the
//!   sensor's host, or simulated time) and ours differ by an unknown offset; it is
//!   estimated as the smallest `arrival - stamp` seen (the message with the least
//!   delay), and the estimate is **bounded**: it may fall at once (a smaller delay is a
//!   better estimate) but rise by at most `max_drift` seconds per second since that
//!   sample (clock drift), so old data cannot drag it along.
//!
//! A message whose stamp is not newer than the newest accepted one (a re-send, or a
//! clock gone backwards) is refused: it refreshes nothing, and the sensor ages towards
//! the stale-sensor stop. A zero stamp (a driver that does not stamp) falls back to
//! arrival time. Times are seconds; `now` is the caller's monotonic clock.

/// One sensor's freshness.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorClock {
    max_drift: f64,
    /// Arrival of the newest accepted message.
    arrived: Option<f64>,
    /// Stamp of the newest accepted message (None: unstamped).
    stamp: Option<f64>,
    /// Offset sample with the least delay: (arrival - stamp, its arrival).
    offset: Option<(f64, f64)>,
}

/// What [`SensorClock::on_message`] made of a message.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Freshness {
    Accepted,
    /// Its stamp is not newer than the newest accepted one (s behind it).
    NotNewer {
        behind: f64,
    },
}

impl SensorClock {
    /// `max_drift`: how fast the stamp clock may fall behind ours, s/s.
    pub fn new(max_drift: f64) -> Self {
        Self {
            max_drift,
            arrived: None,
            stamp: None,
            offset: None,
        }
    }

    /// The estimated `arrival - stamp` of a message with the least delay, at `now`.
    fn offset_at(&self, now: f64) -> Option<f64> {
        self.offset
            .map(|(o, at)| o + self.max_drift * (now - at).max(0.0))
    }

    /// Take a message stamped `stamp` (s; 0: unstamped) arriving at `now`.
    pub fn on_message(&mut self, stamp: f64, now: f64) -> Freshness {
        if stamp == 0.0 || !stamp.is_finite() {
            self.arrived = Some(now);
            self.stamp = None;
            self.offset = None;
            return Freshness::Accepted;
        }
        if let Some(last) = self.stamp
            && stamp <= last
        {
            return Freshness::NotNewer {
                behind: last - stamp,
            };
        }
        let sample = now - stamp;
        if self.offset_at(now).is_none_or(|o| sample <= o) {
            self.offset = Some((sample, now));
        }
        self.arrived = Some(now);
        self.stamp = Some(stamp);
        Freshness::Accepted
    }

    /// Age of the newest accepted data at `now` (None: nothing accepted yet).
    pub fn age(&self, now: f64) -> Option<f64> {
        let arrived = self.arrived?;
        let by_arrival = (now - arrived).max(0.0);
        let by_stamp = match (self.stamp, self.offset_at(now)) {
            (Some(stamp), Some(offset)) => (now - (stamp + offset)).max(0.0),
            _ => 0.0,
        };
        Some(by_arrival.max(by_stamp))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const EPOCH: f64 = 1.7e9;

    #[test]
    fn a_steady_sensor_is_as_old_as_its_last_arrival() {
        let mut c = SensorClock::new(0.01);
        assert_eq!(c.age(0.0), None);
        // 40 Hz, 5 ms delay, its clock 1.7e9 s ahead of ours
        for k in 0..40 {
            let t = k as f64 * 0.025;
            assert_eq!(c.on_message(EPOCH + t, t + 0.005), Freshness::Accepted);
        }
        let last = 39.0 * 0.025 + 0.005;
        assert!((c.age(last).unwrap()).abs() < 1e-6);
        assert!((c.age(last + 0.1).unwrap() - 0.1).abs() < 1e-6);
    }

    #[test]
    fn a_resent_old_message_refreshes_nothing() {
        let mut c = SensorClock::new(0.01);
        for k in 0..10 {
            let t = k as f64 * 0.025;
            c.on_message(EPOCH + t, t);
        }
        // the driver hangs and re-sends its last scan at the usual rate
        for k in 10..30 {
            let t = k as f64 * 0.025;
            assert_eq!(
                c.on_message(EPOCH + 0.225, t),
                Freshness::NotNewer { behind: 0.0 }
            );
        }
        assert!((c.age(0.75).unwrap() - 0.525).abs() < 1e-9);
    }

    #[test]
    fn an_old_message_arriving_now_is_old() {
        let mut c = SensorClock::new(0.01);
        for k in 0..10 {
            let t = k as f64 * 0.025;
            c.on_message(EPOCH + t, t + 0.002);
        }
        // silence, then a message stamped 0.1 s after the last, arriving 0.6 s later: a
        // buffered scan, 0.5 s old on arrival, though its arrival is fresh
        let now = 0.225 + 0.6;
        assert_eq!(c.on_message(EPOCH + 0.325, now), Freshness::Accepted);
        let age = c.age(now).unwrap();
        // 0.5 s late, less the usual 2 ms delay and the offset's allowed drift (0.6 s)
        assert!((age - (0.5 - 0.002 - 0.01 * 0.598)).abs() < 1e-6, "{age}");
    }

    #[test]
    fn the_offset_estimate_follows_a_faster_clock_and_drift_within_its_bound() {
        // simulated time at 4x real time: the offset falls, the age stays at arrival age
        let mut c = SensorClock::new(0.01);
        for k in 0..100 {
            let t = k as f64 * 0.01;
            c.on_message(EPOCH + 4.0 * t, t);
        }
        assert!(c.age(0.99).unwrap() < 1e-9);
        // a clock 0.5 % slower than ours (within the bound): stays fresh
        let mut c = SensorClock::new(0.01);
        for k in 0..1000 {
            let t = k as f64 * 0.01;
            c.on_message(EPOCH + 0.995 * t, t);
        }
        assert!(c.age(9.99).unwrap() < 1e-9);
        // 5 % slower (beyond it): its data falls behind and reads as old
        let mut c = SensorClock::new(0.01);
        for k in 0..1000 {
            let t = k as f64 * 0.01;
            c.on_message(EPOCH + 0.95 * t, t);
        }
        assert!(c.age(9.99).unwrap() > 0.3);
    }

    #[test]
    fn unstamped_messages_age_by_arrival() {
        let mut c = SensorClock::new(0.01);
        c.on_message(0.0, 1.0);
        c.on_message(0.0, 2.0);
        assert_eq!(c.age(2.5), Some(0.5));
    }
}
