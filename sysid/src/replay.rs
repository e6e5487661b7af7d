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

/// Physics step of the simulator [s].
pub const DT: f64 = 0.01;

/// Floors of the per-channel noise scale (x, y [m], yaw [rad], vx, vy [m/s], yaw_rate
/// [rad/s]): a recording with almost no noise still weighs the channels sensibly.
const SIGMA_FLOOR: [f64; 6] = [0.005, 0.005, 0.003, 0.01, 0.01, 0.01];

/// Half-width of the local linear fit that smooths an anchor state [s].
const ANCHOR_HALF_WIDTH_S: f64 = 0.06;

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

/// The recording prepared for replay.
#[derive(Debug, Clone)]
pub struct Replay {
    commands: Vec<(f64, f64)>,
    /// Window start steps, and the anchor state at each.
    anchors: Vec<(usize, StateSample)>,
    samples: Vec<SampleRef>,
    meas: Vec<[f64; 6]>,
    /// Per-channel noise scale estimated from the recording (with floors).
    pub sigma: [f64; 6],
    pub window_s: f64,
}

/// Residuals of one replay.
#[derive(Debug, Clone)]
pub struct Residuals {
    /// recorded - simulated, per sample (yaw wrapped), in [`CHANNELS`] order.
    pub values: Vec<[f64; 6]>,
    /// Simulated channels per sample.
    pub simulated: Vec<[f64; 6]>,
    /// Window of each sample.
    pub window: Vec<usize>,
    /// Recording state index of each sample.
    pub state: Vec<usize>,
}

impl Replay {
    /// Prepare `rec` (already checked) with windows of `window_s` seconds.
    pub fn new(rec: &Recording, window_s: f64) -> Self {
        let t_end = rec.duration();
        let steps = (t_end / DT).floor() as usize + 1;
        let commands = rec.commands_on_grid(DT, steps);
        let win_steps = ((window_s / DT).round() as usize).max(10);
        let mut anchors = Vec::new();
        let mut a = 0usize;
        while a < steps {
            anchors.push((a, smoothed_state(rec, a as f64 * DT)));
            a += win_steps;
        }
        let mut samples = Vec::with_capacity(rec.states.len());
        let mut meas = Vec::with_capacity(rec.states.len());
        for (i, s) in rec.states.iter().enumerate() {
            let pos = s.t / DT;
            let step = pos.floor() as usize;
            if step + 1 > steps {
                continue;
            }
            let frac = pos - step as f64;
            samples.push(SampleRef {
                state: i,
                step,
                frac,
                window: step / win_steps,
            });
            meas.push(s.channels());
        }
        let sigma = noise_scale(rec);
        Self {
            commands,
            anchors,
            samples,
            meas,
            sigma,
            window_s: win_steps as f64 * DT,
        }
    }

    pub fn n_windows(&self) -> usize {
        self.anchors.len()
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
        self.anchors[w].0 as f64 * DT
    }

    /// Commands on the physics grid.
    pub fn commands(&self) -> &[(f64, f64)] {
        &self.commands
    }

    /// Run the replay with `p`, calling `visit(sample, residual, simulated)`.
    fn run(&self, p: &VehicleParams, mut visit: impl FnMut(usize, [f64; 6], [f64; 6])) {
        let first = self.anchors[0].1;
        let mut car = Vehicle::new(Pose::new(first.x, first.y, first.yaw.rem_euclid(TAU)));
        let mut next_anchor = 0usize;
        let mut si = 0usize;
        for (k, &(steer, speed)) in self.commands.iter().enumerate() {
            if next_anchor < self.anchors.len() && self.anchors[next_anchor].0 == k {
                anchor(&mut car, &self.anchors[next_anchor].1);
                next_anchor += 1;
            }
            let before = car.state;
            car.step(p, steer, speed, DT);
            let after = car.state;
            while si < self.samples.len() && self.samples[si].step == k {
                let f = self.samples[si].frac;
                let lerp = |a: f64, b: f64| a + f * (b - a);
                let yaw = before.yaw + f * wrap_pi(after.yaw - before.yaw);
                let (vx0, vy0) = body(&before);
                let (vx1, vy1) = body(&after);
                let sim = [
                    lerp(before.x, after.x),
                    lerp(before.y, after.y),
                    yaw,
                    lerp(vx0, vx1),
                    lerp(vy0, vy1),
                    lerp(before.yaw_rate, after.yaw_rate),
                ];
                let m = &self.meas[si];
                let mut r = [0.0; 6];
                for c in 0..6 {
                    r[c] = m[c] - sim[c];
                }
                r[2] = wrap_pi(r[2]);
                if !r.iter().all(|v| v.is_finite()) {
                    // a model that blew up: a huge but finite residual keeps sums usable
                    r = [1e3; 6];
                }
                visit(si, r, sim);
                si += 1;
            }
        }
    }

    /// Noise-normalised squared residual summed per window.
    pub fn window_costs(&self, p: &VehicleParams) -> Vec<f64> {
        let mut cost = vec![0.0; self.anchors.len()];
        let inv: [f64; 6] = std::array::from_fn(|c| 1.0 / (self.sigma[c] * self.sigma[c]));
        self.run(p, |si, r, _| {
            let w = self.samples[si].window;
            cost[w] += (0..6).map(|c| r[c] * r[c] * inv[c]).sum::<f64>();
        });
        cost
    }

    /// Every residual of a replay with `p`.
    pub fn residuals(&self, p: &VehicleParams) -> Residuals {
        let n = self.samples.len();
        let mut out = Residuals {
            values: Vec::with_capacity(n),
            simulated: Vec::with_capacity(n),
            window: self.samples.iter().map(|s| s.window).collect(),
            state: self.samples.iter().map(|s| s.state).collect(),
        };
        self.run(p, |_, r, sim| {
            out.values.push(r);
            out.simulated.push(sim);
        });
        out
    }
}

impl Residuals {
    /// Root mean square per channel over the samples whose window passes `keep`.
    pub fn rmse(&self, keep: impl Fn(usize) -> bool) -> [f64; 6] {
        let mut sum = [0.0; 6];
        let mut n = 0usize;
        for (r, &w) in self.values.iter().zip(&self.window) {
            if keep(w) {
                n += 1;
                for c in 0..6 {
                    sum[c] += r[c] * r[c];
                }
            }
        }
        std::array::from_fn(|c| (sum[c] / n.max(1) as f64).sqrt())
    }
}

use std::f64::consts::TAU;

fn body(s: &paddock_sim::dynamics::VehicleState) -> (f64, f64) {
    (s.v * libm::cos(s.slip_angle), s.v * libm::sin(s.slip_angle))
}

/// Reset the dynamic state to a recorded one; the wheel angle and command memory stay.
fn anchor(car: &mut Vehicle, s: &StateSample) {
    let speed = libm::hypot(s.vx, s.vy);
    let (v, slip) = if speed < 0.3 {
        (s.vx, 0.0)
    } else if s.vx >= 0.0 {
        (speed, libm::atan2(s.vy, s.vx))
    } else {
        (-speed, libm::atan2(-s.vy, -s.vx))
    };
    let st = &mut car.state;
    st.x = s.x;
    st.y = s.y;
    st.yaw = s.yaw.rem_euclid(TAU);
    st.v = v;
    st.yaw_rate = s.yaw_rate;
    st.slip_angle = slip;
}

/// The recorded state at `t`, smoothed by a local linear fit over nearby samples.
pub fn smoothed_state(rec: &Recording, t: f64) -> StateSample {
    let st = &rec.states;
    let lo = st.partition_point(|s| s.t < t - ANCHOR_HALF_WIDTH_S);
    let hi = st.partition_point(|s| s.t <= t + ANCHOR_HALF_WIDTH_S);
    let nearest = {
        let i = st.partition_point(|s| s.t < t).min(st.len() - 1);
        if i > 0 && (st[i - 1].t - t).abs() < (st[i].t - t).abs() {
            i - 1
        } else {
            i
        }
    };
    let pts: &[StateSample] = if hi >= lo + 3 {
        &st[lo..hi]
    } else {
        std::slice::from_ref(&st[nearest])
    };
    let yaw_ref = st[nearest].yaw;
    let mut out = StateSample {
        t,
        ..Default::default()
    };
    let n = pts.len() as f64;
    let tm = pts.iter().map(|s| s.t - t).sum::<f64>() / n;
    let var = pts.iter().map(|s| (s.t - t - tm).powi(2)).sum::<f64>();
    let mut vals = [0.0; 6];
    for (c, v) in vals.iter_mut().enumerate() {
        let y = |s: &StateSample| {
            let ch = s.channels()[c];
            if c == 2 {
                yaw_ref + wrap_pi(ch - yaw_ref)
            } else {
                ch
            }
        };
        let ym = pts.iter().map(y).sum::<f64>() / n;
        let slope = if var > 1e-12 {
            pts.iter()
                .map(|s| (s.t - t - tm) * (y(s) - ym))
                .sum::<f64>()
                / var
        } else {
            0.0
        };
        *v = ym - slope * tm;
    }
    out.x = vals[0];
    out.y = vals[1];
    out.yaw = wrap_pi(vals[2]);
    out.vx = vals[3];
    out.vy = vals[4];
    out.yaw_rate = vals[5];
    out
}

/// Per-channel measurement noise: each sample against the line through its neighbours
/// (`var = 1.5 sigma^2` for white noise), with floors.
pub fn noise_scale(rec: &Recording) -> [f64; 6] {
    let st = &rec.states;
    let mut sum = [0.0; 6];
    let mut n = 0usize;
    for w in st.windows(3) {
        let (a, b, c) = (w[0], w[1], w[2]);
        let span = c.t - a.t;
        if span <= 0.0 || span > 0.2 {
            continue;
        }
        let f = (b.t - a.t) / span;
        let (ca, cb, cc) = (a.channels(), b.channels(), c.channels());
        for k in 0..6 {
            let (ya, yc) = if k == 2 {
                (
                    cb[2] + wrap_pi(ca[2] - cb[2]),
                    cb[2] + wrap_pi(cc[2] - cb[2]),
                )
            } else {
                (ca[k], cc[k])
            };
            let pred = ya + f * (yc - ya);
            let e = cb[k] - pred;
            sum[k] += e * e;
        }
        n += 1;
    }
    std::array::from_fn(|k| {
        let s = (sum[k] / n.max(1) as f64 / 1.5).sqrt();
        s.max(SIGMA_FLOOR[k])
    })
}

/// The channel names, re-exported for reports.
pub fn channel_names() -> [&'static str; 6] {
    CHANNELS
}
