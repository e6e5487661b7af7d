//! Smoothing the recorded states into the states a replay window starts from, and the
//! recording's own noise scale.

use crate::recording::{Recording, StateSample, wrap_pi};

/// Floors of the per-channel noise scale (x, y [m], yaw [rad], vx, vy [m/s], yaw_rate
/// [rad/s]): a recording with almost no noise still weighs the channels sensibly.
const SIGMA_FLOOR: [f64; 6] = [0.005, 0.005, 0.003, 0.01, 0.01, 0.01];

/// Half-width of the local linear fit that smooths an anchor state [s].
const ANCHOR_HALF_WIDTH_S: f64 = 0.06;
/// Fewest samples of that fit.
const ANCHOR_MIN_POINTS: usize = 3;

/// Half-width of the local fit that derives unmeasured velocities from the pose [s].
const DERIVE_HALF_WIDTH_S: f64 = 0.15;

/// Value and slope at `t` of channel `c` by a least-squares line through the measured
/// samples of `pts` (yaw unwrapped around `yaw_ref`); `None` with fewer than `min` samples.
fn local_line(
    pts: &[StateSample],
    t: f64,
    c: usize,
    yaw_ref: f64,
    min: usize,
) -> Option<(f64, f64)> {
    let y = |s: &StateSample| {
        let ch = s.channels()[c];
        if c == 2 {
            yaw_ref + wrap_pi(ch - yaw_ref)
        } else {
            ch
        }
    };
    let used: Vec<&StateSample> = pts.iter().filter(|s| s.channels()[c].is_finite()).collect();
    if used.len() < min {
        return None;
    }
    // all samples at one instant: their mean, flat
    weighted_line(used.iter().map(|s| (s.t - t, y(s), 1.0))).or_else(|| {
        let ym = used.iter().map(|s| y(s)).sum::<f64>() / used.len() as f64;
        Some((ym, 0.0))
    })
}

/// The recorded state at `t`, smoothed by a local linear fit over nearby samples of one
/// run. A velocity channel that was not measured is derived from the pose (its slope over
/// a wider span): `yaw_rate` from the yaw, `vx` and `vy` from the position turned into
/// the body frame.
pub fn smoothed_state(st: &[StateSample], t: f64) -> StateSample {
    smoothed(st, t, true)
}

/// [`smoothed_state`]; without `derive`, unmeasured velocities stay NaN.
pub(super) fn smoothed(st: &[StateSample], t: f64, derive: bool) -> StateSample {
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
    // too few samples within the half-width (a run's first instants, a sparse log): the
    // three nearest, still a line through them. The nearest sample alone, which this
    // used to take, put the anchor a sample period off in time, and whether it did
    // hung on the logging jitter: a latency tried 5 ms apart scored the run starts
    // thousands apart.
    let pts: &[StateSample] = if hi >= lo + ANCHOR_MIN_POINTS {
        &st[lo..hi]
    } else {
        let (mut a, mut b) = (nearest, nearest + 1);
        while b - a < ANCHOR_MIN_POINTS.min(st.len()) {
            let left = a > 0 && (b == st.len() || t - st[a - 1].t < st[b].t - t);
            if left {
                a -= 1;
            } else {
                b += 1;
            }
        }
        &st[a..b]
    };
    let yaw_ref = st[nearest].yaw;
    let mut vals = [f64::NAN; 6];
    for (c, v) in vals.iter_mut().enumerate() {
        if let Some((value, _)) = local_line(pts, t, c, yaw_ref, 1) {
            *v = value;
        }
    }
    if derive && vals[3..].iter().any(|v| !v.is_finite()) {
        let wlo = st.partition_point(|s| s.t < t - DERIVE_HALF_WIDTH_S);
        let whi = st.partition_point(|s| s.t <= t + DERIVE_HALF_WIDTH_S);
        let wide = &st[wlo..whi.max(wlo)];
        let slope = |c: usize| local_line(wide, t, c, yaw_ref, 3).map_or(0.0, |l| l.1);
        let yaw = vals[2];
        let (sx, sy) = (slope(0), slope(1));
        let (sn, cs) = (libm::sin(yaw), libm::cos(yaw));
        if !vals[3].is_finite() {
            vals[3] = cs * sx + sn * sy;
        }
        if !vals[4].is_finite() {
            vals[4] = -sn * sx + cs * sy;
        }
        if !vals[5].is_finite() {
            vals[5] = slope(2);
        }
    }
    let vals: [f64; 6] = std::array::from_fn(|c| {
        if vals[c].is_finite() || !derive && c >= 3 {
            vals[c]
        } else {
            0.0
        }
    });
    StateSample {
        t,
        x: vals[0],
        y: vals[1],
        yaw: wrap_pi(vals[2]),
        vx: vals[3],
        vy: vals[4],
        yaw_rate: vals[5],
    }
}

/// Per-channel measurement noise: each sample against the line through its neighbours
/// (`var = 1.5 sigma^2` for white noise), within each run, over the samples where the
/// channel was measured, with floors.
pub fn noise_scale(rec: &Recording) -> [f64; 6] {
    let mut sum = [0.0; 6];
    let mut n = [0usize; 6];
    for run in rec.runs() {
        let st = &rec.states[run.first_state..run.first_state + run.n_states];
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
                let e = cb[k] - (ya + f * (yc - ya));
                if e.is_finite() {
                    sum[k] += e * e;
                    n[k] += 1;
                }
            }
        }
    }
    std::array::from_fn(|k| {
        let s = (sum[k] / n[k].max(1) as f64 / 1.5).sqrt();
        s.max(SIGMA_FLOOR[k])
    })
}

/// A least-squares line through weighted points `(u, y, w)`: its value at `u = 0` and its
/// slope; `None` with fewer than two points of positive weight or no spread in `u`.
fn weighted_line(pts: impl Iterator<Item = (f64, f64, f64)> + Clone) -> Option<(f64, f64)> {
    let (mut sw, mut su, mut sy, mut n) = (0.0, 0.0, 0.0, 0usize);
    for (u, y, w) in pts.clone().filter(|p| p.2 > 0.0) {
        sw += w;
        su += w * u;
        sy += w * y;
        n += 1;
    }
    if n < 2 {
        return None;
    }
    let (mu, my) = (su / sw, sy / sw);
    let (mut suu, mut suy) = (0.0, 0.0);
    for (u, y, w) in pts.filter(|p| p.2 > 0.0) {
        suu += w * (u - mu) * (u - mu);
        suy += w * (u - mu) * (y - my);
    }
    if suu <= 1e-12 * sw {
        return None;
    }
    let slope = suy / suu;
    Some((my - slope * mu, slope))
}

/// Weight of a sample `u` seconds after a run's start in a fit over `span` seconds:
/// `sin(pi u / span)`, nothing outside `(0, span)`.
pub(super) fn start_weight(u: f64, span: f64) -> f64 {
    if u > 0.0 && u < span {
        libm::sin(std::f64::consts::PI * u / span)
    } else {
        0.0
    }
}

/// The state where a run starts, `t` on the log's clock (the run's first step plus the
/// latency tried), from the run's samples `st` logged in `(t, t + span)`, by weighted
/// lines ([`start_weight`]). Samples before `t` show the car before the run and are not
/// used; and the weights vanish at both ends, so a latency tried a little longer or
/// shorter moves the estimate smoothly: a sample crossing the start, or the far end,
/// weighs nothing there. (A plain fit over the samples after `t` jumped each time one
/// crossed, and the cost with it, a sawtooth in the latency whose teeth, aligned over
/// the runs, pulled the fit to just before a crossing.) A run from rest starts at rest:
/// its velocities are zero. With fewer than two samples inside, the three nearest after
/// `t`.
pub(super) fn start_state(st: &[StateSample], t: f64, span: f64, moving: bool) -> StateSample {
    let own = st.partition_point(|s| s.t <= t).min(st.len() - 1);
    let yaw_ref = st[own].yaw;
    let near = &st[own..st.partition_point(|s| s.t < t + span).max(own + 1)];
    let line = |c: usize| {
        weighted_line(near.iter().filter_map(move |s| {
            let v = s.channels()[c];
            let v = if c == 2 {
                yaw_ref + wrap_pi(v - yaw_ref)
            } else {
                v
            };
            v.is_finite()
                .then(|| (s.t - t, v, start_weight(s.t - t, span)))
        }))
    };
    let (Some(x), Some(y), Some(yaw)) = (line(0), line(1), line(2)) else {
        let mut s = smoothed(&st[own..], t, true);
        if !moving {
            (s.vx, s.vy, s.yaw_rate) = (0.0, 0.0, 0.0);
        }
        return s;
    };
    let (sn, cs) = (libm::sin(yaw.0), libm::cos(yaw.0));
    let measured = |c: usize, derived: f64| line(c).map_or(derived, |l| l.0);
    let (vx, vy, yaw_rate) = if moving {
        (
            measured(3, cs * x.1 + sn * y.1),
            measured(4, -sn * x.1 + cs * y.1),
            measured(5, yaw.1),
        )
    } else {
        (0.0, 0.0, 0.0)
    };
    StateSample {
        t,
        x: x.0,
        y: y.0,
        yaw: wrap_pi(yaw.0),
        vx,
        vy,
        yaw_rate,
    }
}
