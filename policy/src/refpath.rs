//! A closed reference path (the raceline, or the centerline when a track has none) with
//! arc length, a Frenet projection (s along the path, d to its left) and a speed
//! profile, shared by the drivers that reason in the track's frame (lattice, MLP
//! features).
//!
//! Headings and curvatures are computed from the points themselves (not read from the
//! raceline file), so a centerline-only track works the same way; the raceline's own
//! speed profile is used where there is one.

use paddock_sim::geometry::{wrap_angle, wrap_length};
use paddock_sim::track::Track;

/// Speed profile used when the track has no raceline: lateral acceleration, braking and
/// cap (m/s^2, m/s^2, m/s), the pure-pursuit defaults.
const FALLBACK_LAT_ACCEL: f64 = 5.0;
const FALLBACK_BRAKE: f64 = 5.0;
const FALLBACK_MAX_SPEED: f64 = 7.0;

/// Rounds of [`RefPath::smoothed`] the lattice planner and the MLP's track features
/// apply to the driving line: enough to round the hairpins where some real tracks' lines
/// fold back on themselves (Silverstone, Yas Marina, Moscow Raceway), few enough to keep
/// the line off the inside walls (measured on the 23 real tracks).
pub const ROUNDING_PASSES: usize = 6;

/// A point of the reference path at some arc length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RefPoint {
    pub x: f64,
    pub y: f64,
    /// Heading, radians CCW from +x.
    pub psi: f64,
    /// Signed curvature, 1/m (positive: turning left).
    pub kappa: f64,
    /// Planned speed, m/s.
    pub vx: f64,
}

/// A point in the path's Frenet frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frenet {
    /// Arc length along the path, [0, length).
    pub s: f64,
    /// Signed lateral offset, positive to the left.
    pub d: f64,
    /// Path heading at `s`.
    pub psi: f64,
    /// Index of the nearest path point (a hint for the next projection).
    pub index: usize,
}

#[derive(Debug, Clone)]
pub struct RefPath {
    xs: Vec<f64>,
    ys: Vec<f64>,
    /// Cumulative arc length; `cum[n]` is the loop length.
    cum: Vec<f64>,
    /// Heading at each point (mean of the adjacent segments' directions).
    psi: Vec<f64>,
    kappa: Vec<f64>,
    vx: Vec<f64>,
}

impl RefPath {
    /// The circuit's driving line (its raceline, or a line computed inside the map's
    /// free space where the raceline grazes walls; see `Circuit::driving_line`), with its
    /// speed profile.
    pub fn from_circuit(circuit: &paddock_sim::circuit::Circuit) -> Self {
        let line = circuit.driving_line();
        Self::new(
            line.iter().map(|p| p.x).collect(),
            line.iter().map(|p| p.y).collect(),
            Some(line.iter().map(|p| p.vx).collect()),
        )
    }

    /// This path with its corners rounded: `passes` rounds of moving each point halfway
    /// towards the mean of its two neighbours (a tight hairpin, where the path folds
    /// back on itself, becomes a curve a follower can hold). Keeps the speed profile.
    pub fn smoothed(&self, passes: usize) -> Self {
        let n = self.xs.len();
        let (mut xs, mut ys) = (self.xs.clone(), self.ys.clone());
        for _ in 0..passes {
            let (px, py) = (xs.clone(), ys.clone());
            for i in 0..n {
                let (a, b) = ((i + n - 1) % n, (i + 1) % n);
                xs[i] = 0.5 * px[i] + 0.25 * (px[a] + px[b]);
                ys[i] = 0.5 * py[i] + 0.25 * (py[a] + py[b]);
            }
        }
        Self::new(xs, ys, Some(self.vx.clone()))
    }

    /// The track's raceline (with its speed profile), or its centerline (with a
    /// curvature-based profile).
    pub fn from_track(track: &Track) -> Self {
        let (xs, ys, vx): (Vec<f64>, Vec<f64>, Option<Vec<f64>>) = match track.raceline() {
            Some(r) => (
                r.iter().map(|p| p.x).collect(),
                r.iter().map(|p| p.y).collect(),
                Some(r.iter().map(|p| p.vx).collect()),
            ),
            None => (
                track.points().iter().map(|p| p.x).collect(),
                track.points().iter().map(|p| p.y).collect(),
                None,
            ),
        };
        Self::new(xs, ys, vx)
    }

    /// A closed path through the points (at least 3); `vx` is its speed profile, or
    /// `None` to derive one from the curvature.
    pub fn new(mut xs: Vec<f64>, mut ys: Vec<f64>, vx: Option<Vec<f64>>) -> Self {
        let mut vx = vx;
        // drop a duplicated closing point
        let n0 = xs.len();
        if n0 > 3 && libm::hypot(xs[0] - xs[n0 - 1], ys[0] - ys[n0 - 1]) < 1e-9 {
            xs.pop();
            ys.pop();
            if let Some(v) = vx.as_mut() {
                v.pop();
            }
        }
        let n = xs.len();
        let mut cum = Vec::with_capacity(n + 1);
        let mut seg = Vec::with_capacity(n);
        let mut s = 0.0;
        for i in 0..n {
            cum.push(s);
            let j = (i + 1) % n;
            s += libm::hypot(xs[j] - xs[i], ys[j] - ys[i]);
            seg.push(libm::atan2(ys[j] - ys[i], xs[j] - xs[i]));
        }
        cum.push(s);
        let psi: Vec<f64> = (0..n)
            .map(|i| {
                let prev = seg[(i + n - 1) % n];
                wrap_angle(prev + 0.5 * wrap_angle(seg[i] - prev))
            })
            .collect();
        let kappa = curvature(&xs, &ys);
        let vx = vx.unwrap_or_else(|| fallback_profile(&kappa, &cum));
        Self {
            xs,
            ys,
            cum,
            psi,
            kappa,
            vx,
        }
    }

    pub fn num_points(&self) -> usize {
        self.xs.len()
    }

    /// Loop length, metres.
    pub fn length(&self) -> f64 {
        self.cum[self.xs.len()]
    }

    /// Signed arc-length difference `b - a` wrapped into [-L/2, L/2).
    pub fn ds(&self, a: f64, b: f64) -> f64 {
        let l = self.length();
        let d = b - a;
        d - l * libm::floor((d + 0.5 * l) / l)
    }

    fn segment(&self, s: f64) -> (usize, f64) {
        let n = self.xs.len();
        let s = wrap_length(s, self.length());
        let i = match self.cum.binary_search_by(|v| v.total_cmp(&s)) {
            Ok(i) => i.min(n - 1),
            Err(i) => i - 1,
        };
        let len = self.cum[i + 1] - self.cum[i];
        let t = if len > 0.0 {
            (s - self.cum[i]) / len
        } else {
            0.0
        };
        (i, t.clamp(0.0, 1.0))
    }

    /// The path at arc length `s` (wrapped), linearly interpolated.
    pub fn at(&self, s: f64) -> RefPoint {
        let n = self.xs.len();
        let (i, t) = self.segment(s);
        let j = (i + 1) % n;
        let lerp = |a: f64, b: f64| a + t * (b - a);
        RefPoint {
            x: lerp(self.xs[i], self.xs[j]),
            y: lerp(self.ys[i], self.ys[j]),
            psi: wrap_angle(self.psi[i] + t * wrap_angle(self.psi[j] - self.psi[i])),
            kappa: lerp(self.kappa[i], self.kappa[j]),
            vx: lerp(self.vx[i], self.vx[j]),
        }
    }

    /// The world point at Frenet coordinates (s, d) and the path heading there.
    pub fn to_world(&self, s: f64, d: f64) -> (f64, f64, f64) {
        let p = self.at(s);
        let (sn, cs) = libm::sincos(p.psi);
        (p.x - d * sn, p.y + d * cs, p.psi)
    }

    /// Path point `i`.
    pub fn point(&self, i: usize) -> (f64, f64) {
        (self.xs[i], self.ys[i])
    }

    /// Curvature at each path point.
    pub fn kappa(&self) -> &[f64] {
        &self.kappa
    }

    /// Cumulative arc length at each path point; the last entry is the loop length.
    pub fn cum(&self) -> &[f64] {
        &self.cum
    }

    /// Squared distance from path point `i` to (x, y).
    pub fn d2(&self, i: usize, x: f64, y: f64) -> f64 {
        (self.xs[i] - x) * (self.xs[i] - x) + (self.ys[i] - y) * (self.ys[i] - y)
    }

    /// The first path index at least `dist` metres along the path from index `i`.
    pub fn ahead(&self, i: usize, dist: f64) -> usize {
        let n = self.xs.len();
        let total = self.length();
        let mut j = i;
        for _ in 0..n {
            if wrap_length(self.cum[j] - self.cum[i], total) >= dist {
                break;
            }
            j = if j + 1 == n { 0 } else { j + 1 };
        }
        j
    }

    /// Index of the path point nearest (x, y): a downhill walk from `hint`, or a global
    /// search when there is no hint or the walk ends far away (ties: lowest index).
    pub fn nearest(&self, x: f64, y: f64, hint: Option<usize>) -> usize {
        let n = self.xs.len();
        let local = hint.filter(|&h| h < n).and_then(|h| {
            let mut best = h;
            loop {
                let next = if best + 1 == n { 0 } else { best + 1 };
                let prev = if best == 0 { n - 1 } else { best - 1 };
                if self.d2(next, x, y) < self.d2(best, x, y) {
                    best = next;
                } else if self.d2(prev, x, y) < self.d2(best, x, y) {
                    best = prev;
                } else {
                    break;
                }
            }
            (self.d2(best, x, y) <= 4.0).then_some(best)
        });
        local.unwrap_or_else(|| {
            (0..n)
                .min_by(|&a, &b| {
                    self.d2(a, x, y)
                        .total_cmp(&self.d2(b, x, y))
                        .then(a.cmp(&b))
                })
                .unwrap_or(0)
        })
    }

    /// Frenet coordinates of (x, y): projected onto the nearer of the two segments at
    /// the nearest path point.
    pub fn project(&self, x: f64, y: f64, hint: Option<usize>) -> Frenet {
        let n = self.xs.len();
        let i = self.nearest(x, y, hint);
        let mut best: Option<(f64, f64, f64)> = None; // (dist2, s, d)
        for a in [(i + n - 1) % n, i] {
            let b = (a + 1) % n;
            let (dx, dy) = (self.xs[b] - self.xs[a], self.ys[b] - self.ys[a]);
            let len = libm::hypot(dx, dy);
            if len <= 0.0 {
                continue;
            }
            let (ux, uy) = (dx / len, dy / len);
            let (rx, ry) = (x - self.xs[a], y - self.ys[a]);
            let t = (rx * ux + ry * uy).clamp(0.0, len);
            let (px, py) = (self.xs[a] + t * ux, self.ys[a] + t * uy);
            let dist2 = (x - px) * (x - px) + (y - py) * (y - py);
            let d = ux * ry - uy * rx;
            if best.is_none_or(|b| dist2 < b.0) {
                best = Some((dist2, self.cum[a] + t, d));
            }
        }
        let (_, s, d) = best.unwrap_or((0.0, self.cum[i], 0.0));
        let s = wrap_length(s, self.length());
        Frenet {
            s,
            d,
            psi: self.at(s).psi,
            index: i,
        }
    }
}

/// Curvature of the closed polyline at each point: the circle through the neighbours two
/// points away on each side (smooths sampling noise).
pub fn curvature(xs: &[f64], ys: &[f64]) -> Vec<f64> {
    let n = xs.len();
    (0..n)
        .map(|i| {
            let a = (i + n - 2) % n;
            let b = (i + 2) % n;
            let (ax, ay) = (xs[i] - xs[a], ys[i] - ys[a]);
            let (bx, by) = (xs[b] - xs[i], ys[b] - ys[i]);
            let (cx, cy) = (xs[b] - xs[a], ys[b] - ys[a]);
            let cross = ax * by - ay * bx;
            let denom = libm::hypot(ax, ay) * libm::hypot(bx, by) * libm::hypot(cx, cy);
            if denom > 1e-12 {
                2.0 * cross / denom
            } else {
                0.0
            }
        })
        .collect()
}

fn fallback_profile(kappa: &[f64], cum: &[f64]) -> Vec<f64> {
    speed_profile(
        kappa,
        cum,
        FALLBACK_LAT_ACCEL,
        FALLBACK_BRAKE,
        FALLBACK_MAX_SPEED,
    )
}

/// A speed profile for a closed path: v = sqrt(`lat_accel` / |kappa|) capped at
/// `max_speed`, then backward passes around the loop so the car can brake from each
/// speed to the next at `brake` (v_i <= sqrt(v_{i+1}^2 + 2 brake ds)).
pub fn speed_profile(
    kappa: &[f64],
    cum: &[f64],
    lat_accel: f64,
    brake: f64,
    max_speed: f64,
) -> Vec<f64> {
    let n = kappa.len();
    let mut v: Vec<f64> = kappa
        .iter()
        .map(|k| {
            if k.abs() > 1e-9 {
                libm::sqrt(lat_accel / k.abs()).min(max_speed)
            } else {
                max_speed
            }
        })
        .collect();
    for _ in 0..2 {
        for k in (0..n).rev() {
            let j = (k + 1) % n;
            let lim = libm::sqrt(v[j] * v[j] + 2.0 * brake * (cum[k + 1] - cum[k]));
            v[k] = v[k].min(lim);
        }
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    fn circle(r: f64, n: usize) -> RefPath {
        let (xs, ys): (Vec<f64>, Vec<f64>) = (0..n)
            .map(|i| {
                let a = std::f64::consts::TAU * i as f64 / n as f64;
                (r * a.cos(), r * a.sin())
            })
            .unzip();
        RefPath::new(xs, ys, None)
    }

    #[test]
    fn frenet_round_trip_on_a_circle() {
        let p = circle(10.0, 400);
        assert!((p.length() - std::f64::consts::TAU * 10.0).abs() < 0.01);
        assert!((p.at(3.0).kappa - 0.1).abs() < 1e-3);
        for &(s, d) in &[(1.0, 0.5), (20.0, -1.0), (60.0, 0.0)] {
            let (x, y, _) = p.to_world(s, d);
            let f = p.project(x, y, None);
            assert!(p.ds(s, f.s).abs() < 0.02, "{s} -> {}", f.s);
            assert!((f.d - d).abs() < 0.01, "{d} -> {}", f.d);
        }
    }
}
