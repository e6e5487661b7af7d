//! Replay of the recorded commands through sim-core's dynamics over short windows, each
//! re-anchored to the recorded state, and the residuals per channel.
//!
//! One pass runs the whole recording on the physics grid. At every window start the
//! simulated `x, y, yaw, v, yaw_rate, slip` are replaced by the smoothed recorded state;
//! the wheel angle and the command path's memory (extra delay line, 2-step buffer, lags)
//! carry on, because they depend only on the commands, which are known exactly. So the
//! replay is exactly what the simulator would do from that state, and errors never
//! compound past one window.

use paddock_sim::dynamics::Vehicle;
use paddock_sim::geometry::Pose;
use paddock_sim::params::VehicleParams;

use crate::recording::{CHANNELS, Recording, StateSample, wrap_pi};

mod smooth;
mod start;

pub use smooth::{noise_scale, smoothed_state};
use smooth::{smoothed, start_state};
use start::StartWindow;

/// Physics step of the simulator [s].
pub const DT: f64 = 0.01;

#[derive(Debug, Clone, Copy)]
struct SampleRef {
    /// Index into the recording's states.
    state: usize,
    /// Physics step whose interval holds the sample.
    step: usize,
    /// Position inside that interval, in [0, 1).
    frac: f64,
    window: usize,
}

/// A window start: the recorded state the replay is reset to there.
#[derive(Debug, Clone, Copy)]
struct Anchor {
    step: usize,
    state: StateSample,
    /// First window of a run: the car starts afresh (command path at rest, or settled
    /// on the run's first command when the run starts in motion).
    fresh: bool,
    run: usize,
}

/// Speed above which a run counts as starting in motion [m/s].
const MOVING_MPS: f64 = 0.3;

/// Bounds of the span over which a run's start state is fitted [s].
const START_SPAN_S: (f64, f64) = (0.12, 0.3);

/// The recording prepared for replay.
#[derive(Debug, Clone)]
pub struct Replay {
    commands: Vec<(f64, f64)>,
    anchors: Vec<Anchor>,
    samples: Vec<SampleRef>,
    meas: Vec<[f64; 6]>,
    /// Sample times and the recording's states (for a measurement delay).
    times: Vec<f64>,
    states: Vec<StateSample>,
    /// State index range of each run.
    runs: Vec<(usize, usize)>,
    /// Whether each run starts in motion (its speed where it starts, whatever latency is
    /// tried: the start's treatment must not change with it).
    moving: Vec<bool>,
    /// Span of each run's start fit [s] ([`start_state`]): four sample periods, within
    /// [`START_SPAN_S`].
    start_span: Vec<f64>,
    /// Per-channel noise scale estimated from the recording (with floors).
    pub sigma: [f64; 6],
    pub window_s: f64,
    win_steps: usize,
}

/// Residuals of one replay.
#[derive(Debug, Clone)]
pub struct Residuals {
    /// recorded - simulated, per sample (yaw wrapped), in [`CHANNELS`] order; NaN where
    /// the channel was not measured.
    pub values: Vec<[f64; 6]>,
    /// Simulated channels per sample.
    pub simulated: Vec<[f64; 6]>,
    /// Window of each sample.
    pub window: Vec<usize>,
    /// Recording state index of each sample.
    pub state: Vec<usize>,
}

fn step_of(t: f64) -> (usize, f64) {
    let pos = (t / DT + 1e-9).max(0.0);
    let step = pos.floor();
    (step as usize, (pos - step).clamp(0.0, 1.0))
}

impl Replay {
    /// Prepare `rec` (already checked) with windows of `window_s` seconds; each run
    /// starts its own windows.
    pub fn new(rec: &Recording, window_s: f64) -> Self {
        let t_end = rec.duration();
        let steps = (t_end / DT).floor() as usize + 1;
        let commands = rec.commands_on_grid(DT, steps);
        let win_steps = ((window_s / DT).round() as usize).max(10);
        let runs: Vec<(usize, usize)> = rec
            .runs()
            .iter()
            .map(|r| (r.first_state, r.first_state + r.n_states))
            .collect();
        let moving = runs
            .iter()
            .map(|&(lo, hi)| {
                let st = &rec.states[lo..hi];
                lo < hi && smoothed(st, st[0].t, true).vx.abs() > MOVING_MPS
            })
            .collect();
        let start_span = runs
            .iter()
            .map(|&(lo, hi)| {
                let mut dt: Vec<f64> = rec.states[lo..hi]
                    .windows(2)
                    .map(|w| w[1].t - w[0].t)
                    .collect();
                dt.sort_by(f64::total_cmp);
                let period = dt.get(dt.len() / 2).copied().unwrap_or(0.0);
                (4.0 * period).clamp(START_SPAN_S.0, START_SPAN_S.1)
            })
            .collect();
        let mut replay = Self {
            commands,
            anchors: Vec::new(),
            samples: Vec::with_capacity(rec.states.len()),
            meas: Vec::with_capacity(rec.states.len()),
            times: rec.states.iter().map(|s| s.t).collect(),
            states: rec.states.clone(),
            runs,
            moving,
            start_span,
            sigma: noise_scale(rec),
            window_s: win_steps as f64 * DT,
            win_steps,
        };
        replay.anchors = replay.anchors_at(0.0);
        for (r, &(lo, hi)) in replay.runs.clone().iter().enumerate() {
            for i in lo..hi {
                let (step, frac) = replay.sample_step(r, replay.times[i]);
                if step >= steps {
                    continue;
                }
                let window = replay.anchors.partition_point(|a| a.step <= step) - 1;
                replay.samples.push(SampleRef {
                    state: i,
                    step,
                    frac,
                    window,
                });
                replay.meas.push(rec.states[i].channels());
            }
        }
        replay
    }

    /// Window starts when the measurements lag the truth by `delay` [s]: the state at
    /// step `k` is the one recorded at `k dt + delay`.
    fn anchors_at(&self, delay: f64) -> Vec<Anchor> {
        let steps = self.commands.len();
        let mut anchors = Vec::new();
        for (r, &(lo, hi)) in self.runs.iter().enumerate() {
            if lo >= hi {
                continue;
            }
            let first = ((self.times[lo] / DT) - 1e-9).ceil().max(0.0) as usize;
            let last = ((self.times[hi - 1] / DT) + 1e-9).floor() as usize;
            let st = &self.states[lo..hi];
            let mut a = first;
            while a <= last && a < steps {
                let fresh = a == first;
                let t = a as f64 * DT + delay;
                // where a run starts, only the samples of the run's own states (with a
                // latency, the first `delay` seconds of the log still show the car
                // before it; a fit across that edge gave a start from rest the speed of
                // the acceleration after it); elsewhere unmeasured velocities are
                // carried on from the replay itself (less noisy than a pose derivative)
                let state = if fresh {
                    start_state(st, t, self.start_span[r], self.moving[r])
                } else {
                    smoothed(st, t, false)
                };
                anchors.push(Anchor {
                    step: a,
                    state,
                    fresh,
                    run: r,
                });
                a += self.win_steps;
            }
        }
        anchors
    }

    /// Step and fraction of a sample at `t` of run `r`. A time before the run's first
    /// step (a latency reaching back past its start) gives that step and a negative
    /// fraction: the replay extrapolates the start state back in time.
    fn sample_step(&self, r: usize, t: f64) -> (usize, f64) {
        let start = self.times[self.runs[r].0];
        let first = ((start / DT) - 1e-9).ceil().max(0.0) as usize;
        let (step, frac) = step_of(t);
        if step < first {
            (first, (t / DT - first as f64).min(0.0))
        } else {
            (step, frac)
        }
    }

    pub fn n_windows(&self) -> usize {
        self.anchors.len()
    }

    /// Measured values (samples x channels measured) per window.
    pub fn window_counts(&self) -> Vec<usize> {
        let mut out = vec![0usize; self.anchors.len()];
        for (s, m) in self.samples.iter().zip(&self.meas) {
            out[s.window] += m.iter().filter(|v| v.is_finite()).count();
        }
        out
    }

    pub fn n_samples(&self) -> usize {
        self.samples.len()
    }

    /// Physics steps of one replay.
    pub fn n_steps(&self) -> usize {
        self.commands.len()
    }

    /// Window start time [s] of window `w`.
    pub fn window_start(&self, w: usize) -> f64 {
        self.anchors[w].step as f64 * DT
    }

    /// Run of window `w`.
    pub fn window_run(&self, w: usize) -> usize {
        self.anchors[w].run
    }

    /// Number of runs.
    pub fn n_runs(&self) -> usize {
        self.runs.len()
    }

    /// Commands on the physics grid.
    pub fn commands(&self) -> &[(f64, f64)] {
        &self.commands
    }

    /// Run the replay with `p`, the measurements lagging the truth by `delay` [s],
    /// calling `visit(sample, window, residual, simulated)`.
    fn run(
        &self,
        p: &VehicleParams,
        delay: f64,
        mut visit: impl FnMut(usize, usize, [f64; 6], [f64; 6]),
    ) {
        let shifted;
        let (anchors, samples): (&[Anchor], &[SampleRef]) = if delay == 0.0 {
            (&self.anchors, &self.samples)
        } else {
            let anchors = self.anchors_at(delay);
            let samples: Vec<SampleRef> = self
                .samples
                .iter()
                .map(|s| {
                    let r = self.anchors[s.window].run;
                    let (step, frac) = self.sample_step(r, self.times[s.state] - delay);
                    let window = anchors
                        .partition_point(|a| a.step <= step)
                        .saturating_sub(1);
                    SampleRef {
                        step,
                        frac,
                        window,
                        ..*s
                    }
                })
                .collect();
            shifted = (anchors, samples);
            (&shifted.0, &shifted.1)
        };
        let first = anchors[0].state;
        let mut car = Vehicle::new(Pose::new(first.x, first.y, first.yaw.rem_euclid(TAU)));
        let mut next_anchor = 0usize;
        let mut si = 0usize;
        // a run's first window waits for its start pose to be fitted
        let mut start = StartWindow::default();
        let mut start_step = 0usize;
        for (k, &(steer, speed)) in self.commands.iter().enumerate() {
            if next_anchor < anchors.len() && anchors[next_anchor].step == k {
                start.flush(&self.sigma, &mut visit);
                let a = &anchors[next_anchor];
                if a.fresh && next_anchor > 0 {
                    car = Vehicle::new(Pose::new(a.state.x, a.state.y, 0.0));
                }
                anchor(&mut car, &a.state);
                if a.fresh && self.moving[a.run] {
                    car.settle_commands(p, steer, speed, DT);
                }
                if a.fresh {
                    start.begin((car.state.x, car.state.y), self.start_span[a.run]);
                    start_step = k;
                }
                next_anchor += 1;
            }
            let before = car.state;
            car.step(p, steer, speed, DT);
            let after = car.state;
            while si < samples.len() && samples[si].step == k {
                let f = samples[si].frac;
                let sim = if f < 0.0 {
                    before_start(&before, f * DT)
                } else {
                    let lerp = |a: f64, b: f64| a + f * (b - a);
                    let yaw = before.yaw + f * wrap_pi(after.yaw - before.yaw);
                    let (vx0, vy0) = body(&before);
                    let (vx1, vy1) = body(&after);
                    [
                        lerp(before.x, after.x),
                        lerp(before.y, after.y),
                        yaw,
                        lerp(vx0, vx1),
                        lerp(vy0, vy1),
                        lerp(before.yaw_rate, after.yaw_rate),
                    ]
                };
                let m = &self.meas[si];
                let mut r = [0.0; 6];
                for c in 0..6 {
                    r[c] = m[c] - sim[c];
                }
                r[2] = wrap_pi(r[2]);
                if !sim.iter().all(|v| v.is_finite()) {
                    // a model that blew up: a huge but finite residual keeps sums usable
                    r = [1e3; 6];
                }
                for c in 0..6 {
                    if !m[c].is_finite() {
                        r[c] = f64::NAN;
                    }
                }
                if start.is_open() {
                    let u = (k - start_step) as f64 * DT + f * DT;
                    start.hold((si, samples[si].window, r, sim, u));
                } else {
                    visit(si, samples[si].window, r, sim);
                }
                si += 1;
            }
        }
        start.flush(&self.sigma, &mut visit);
    }

    /// Noise-normalised squared residual summed per window.
    pub fn window_costs(&self, p: &VehicleParams) -> Vec<f64> {
        self.window_costs_at(p, 0.0)
    }

    /// [`Self::window_costs`] with the measurements lagging the truth by `delay` [s].
    pub fn window_costs_at(&self, p: &VehicleParams, delay: f64) -> Vec<f64> {
        let mut cost = vec![0.0; self.anchors.len()];
        let inv: [f64; 6] = std::array::from_fn(|c| 1.0 / (self.sigma[c] * self.sigma[c]));
        self.run(p, delay, |_, w, r, _| {
            let w = w.min(cost.len() - 1);
            cost[w] += (0..6)
                .filter(|&c| r[c].is_finite())
                .map(|c| r[c] * r[c] * inv[c])
                .sum::<f64>();
        });
        cost
    }

    /// Every residual of a replay with `p`.
    pub fn residuals(&self, p: &VehicleParams) -> Residuals {
        self.residuals_at(p, 0.0)
    }

    /// [`Self::residuals`] with the measurements lagging the truth by `delay` [s].
    pub fn residuals_at(&self, p: &VehicleParams, delay: f64) -> Residuals {
        let n = self.samples.len();
        let mut out = Residuals {
            values: Vec::with_capacity(n),
            simulated: Vec::with_capacity(n),
            window: Vec::with_capacity(n),
            state: self.samples.iter().map(|s| s.state).collect(),
        };
        self.run(p, delay, |_, w, r, sim| {
            out.values.push(r);
            out.simulated.push(sim);
            out.window.push(w);
        });
        out
    }
}

impl Residuals {
    /// Root mean square per channel over the samples whose window passes `keep`.
    /// NaN for a channel never measured there.
    pub fn rmse(&self, keep: impl Fn(usize) -> bool) -> [f64; 6] {
        let (sum, n) = self.sum_sq(keep);
        std::array::from_fn(|c| {
            if n[c] == 0 {
                f64::NAN
            } else {
                (sum[c] / n[c] as f64).sqrt()
            }
        })
    }

    /// Per channel: the sum of squared residuals and the number of measured samples over
    /// the samples whose window passes `keep` (pooling blocks where a channel is measured
    /// in some only).
    pub fn sum_sq(&self, keep: impl Fn(usize) -> bool) -> ([f64; 6], [usize; 6]) {
        let mut sum = [0.0; 6];
        let mut n = [0usize; 6];
        for (r, &w) in self.values.iter().zip(&self.window) {
            if keep(w) {
                for c in 0..6 {
                    if r[c].is_finite() {
                        n[c] += 1;
                        sum[c] += r[c] * r[c];
                    }
                }
            }
        }
        (sum, n)
    }
}

use std::f64::consts::TAU;

fn body(s: &paddock_sim::dynamics::VehicleState) -> (f64, f64) {
    (s.v * libm::cos(s.slip_angle), s.v * libm::sin(s.slip_angle))
}

/// The channels `dt` (< 0) before a run's start state `s`: the car drove on steadily
/// before the run (at rest, or in the steady state of its first command), so the pose is
/// carried back along its velocity and the velocities are the start's.
fn before_start(s: &paddock_sim::dynamics::VehicleState, dt: f64) -> [f64; 6] {
    let (vx, vy) = body(s);
    let (sn, cs) = (libm::sin(s.yaw), libm::cos(s.yaw));
    [
        s.x + dt * (cs * vx - sn * vy),
        s.y + dt * (sn * vx + cs * vy),
        s.yaw + dt * s.yaw_rate,
        vx,
        vy,
        s.yaw_rate,
    ]
}

/// Reset the dynamic state to a recorded one; the wheel angle and command memory stay,
/// and so do the velocities the recording does not have (NaN).
fn anchor(car: &mut Vehicle, s: &StateSample) {
    let st = &mut car.state;
    st.x = s.x;
    st.y = s.y;
    st.yaw = s.yaw.rem_euclid(TAU);
    if s.yaw_rate.is_finite() {
        st.yaw_rate = s.yaw_rate;
    }
    match (s.vx.is_finite(), s.vy.is_finite()) {
        (true, true) => {
            let speed = libm::hypot(s.vx, s.vy);
            let (v, slip) = if speed < 0.3 {
                (s.vx, 0.0)
            } else if s.vx >= 0.0 {
                (speed, libm::atan2(s.vy, s.vx))
            } else {
                (-speed, libm::atan2(-s.vy, -s.vx))
            };
            st.v = v;
            st.slip_angle = slip;
        }
        // the speed alone (a VESC): keep the replay's own slip
        (true, false) => {
            let c = libm::cos(st.slip_angle);
            st.v = if c > 0.5 { s.vx / c } else { s.vx };
        }
        _ => {}
    }
}

/// The channel names, re-exported for reports.
pub fn channel_names() -> [&'static str; 6] {
    CHANNELS
}
