//! Laps: progress by arc length along the centerline and lap times.

use serde::{Deserialize, Serialize};

use super::Track;

/// Per-agent progress along the track and lap timing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LapCounter {
    /// Centerline arc length at the last update.
    pub s: f64,
    /// Segment index of the last projection (search hint).
    pub segment: usize,
    /// Unwrapped arc length driven since the start (negative when backwards).
    pub progress: f64,
    /// Completed laps.
    pub laps: u32,
    /// Time of each completed lap, seconds.
    pub lap_times: Vec<f64>,
    /// Episode time at which the current lap started.
    pub lap_start_time: f64,
}

impl LapCounter {
    /// Start counting at `(x, y)` at episode time `t`.
    pub fn start(track: &Track, x: f64, y: f64, t: f64) -> Self {
        let p = track.project(x, y);
        Self {
            s: p.s,
            segment: p.segment,
            progress: 0.0,
            laps: 0,
            lap_times: Vec::new(),
            lap_start_time: t,
        }
    }

    /// Update with the car's new position after a step that ended at time `t` and lasted
    /// `dt`. Returns the number of laps completed in this step (0 or 1 in practice). Lap
    /// times are interpolated within the step.
    pub fn update(&mut self, track: &Track, x: f64, y: f64, t: f64, dt: f64) -> u32 {
        let p = track.project_near(x, y, self.segment);
        let ds = track.ds(self.s, p.s);
        let before = self.progress;
        self.s = p.s;
        self.segment = p.segment;
        self.progress += ds;
        let mut completed = 0;
        let l = track.length();
        while self.progress >= (self.laps as f64 + 1.0) * l {
            let target = (self.laps as f64 + 1.0) * l;
            let frac = if self.progress > before {
                ((target - before) / (self.progress - before)).clamp(0.0, 1.0)
            } else {
                1.0
            };
            let t_cross = t - dt + frac * dt;
            self.lap_times.push(t_cross - self.lap_start_time);
            self.lap_start_time = t_cross;
            self.laps += 1;
            completed += 1;
        }
        completed
    }

    /// Time of the current (unfinished) lap so far, or the last lap's time.
    pub fn current_lap_time(&self, t: f64) -> f64 {
        t - self.lap_start_time
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::tests::circle;

    fn drive(t: &Track, start_angle: f64, dir: f64, seconds: f64, omega: f64) -> LapCounter {
        let dt = 0.01;
        let r = 10.0;
        let mut c = LapCounter::start(t, r * start_angle.cos(), r * start_angle.sin(), 0.0);
        let steps = (seconds / dt).round() as usize;
        for k in 1..=steps {
            let a = start_angle + dir * omega * k as f64 * dt;
            c.update(t, r * a.cos(), r * a.sin(), k as f64 * dt, dt);
        }
        c
    }

    #[test]
    fn laps_from_any_start() {
        let t = circle(10.0, 400);
        // one revolution every 2*pi/omega seconds
        let omega = 1.0;
        let period = std::f64::consts::TAU / omega;
        for start in [0.0, 1.0, 2.5, 5.9] {
            let c = drive(&t, start, 1.0, 2.5 * period, omega);
            assert_eq!(c.laps, 2, "start {start}");
            for lt in &c.lap_times {
                assert!((lt - period).abs() < 0.02, "lap time {lt} vs {period}");
            }
        }
    }

    #[test]
    fn backwards_never_counts_laps() {
        let t = circle(10.0, 400);
        let c = drive(&t, 0.3, -1.0, 20.0, 1.0);
        assert_eq!(c.laps, 0);
        assert!(c.progress < -2.0 * t.length());
    }

    #[test]
    fn lost_distance_must_be_driven_again() {
        let t = circle(10.0, 400);
        let dt = 0.01;
        let r = 10.0;
        let mut c = LapCounter::start(&t, r, 0.0, 0.0);
        let mut a: f64 = 0.0;
        let mut time = 0.0;
        // back a quarter lap, then forward one full lap: still short of a lap
        for (dir, rev) in [(-1.0, 0.25), (1.0, 1.0)] {
            let steps = (rev * 628.0) as usize;
            for _ in 0..steps {
                a += dir * std::f64::consts::TAU / 628.0;
                time += dt;
                c.update(&t, r * a.cos(), r * a.sin(), time, dt);
            }
        }
        assert_eq!(c.laps, 0);
        for _ in 0..200 {
            a += std::f64::consts::TAU / 628.0;
            time += dt;
            c.update(&t, r * a.cos(), r * a.sin(), time, dt);
        }
        assert_eq!(c.laps, 1);
    }
}
