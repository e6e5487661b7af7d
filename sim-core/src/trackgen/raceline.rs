//! The racing line: lateral offsets along the centerline normals that minimise the sum of
//! squared second differences of the line (a discrete minimum-curvature objective), inside
//! the corridor less a safety margin; then a speed profile by forward and backward passes.
//!
//! The optimisation is a box-constrained quadratic problem, solved by accelerated
//! projected gradient (FISTA with adaptive restart), coarse to fine: the coarse levels fix
//! the long-wave shape quickly and the fine levels only correct it locally, which a plain
//! gradient method on the fine level alone would take far too long to do.

use std::f64::consts::TAU;

use super::{RacelinePoint, SpeedLimits, shape};

/// Node spacings (m) of the coarse-to-fine levels, and the iterations spent on each.
const LEVELS: [(f64, usize); 4] = [(3.2, 3000), (1.6, 1500), (0.8, 800), (0.4, 600)];

/// The corridor sampled at the centerline points (uniform spacing `step`).
pub(super) struct Corridor<'a> {
    pub points: &'a [[f64; 2]],
    pub normals: &'a [[f64; 2]],
    /// Allowed offset range along the left normal at each point (negative = right).
    pub lo: &'a [f64],
    pub hi: &'a [f64],
    pub step: f64,
}

/// The optimal line itself: each centerline point moved along its normal by its optimal
/// offset.
pub(super) fn optimal_line(c: &Corridor) -> Vec<[f64; 2]> {
    let alpha = optimal_offsets(c);
    c.points
        .iter()
        .zip(c.normals)
        .zip(&alpha)
        .map(|((p, nrm), a)| [p[0] + a * nrm[0], p[1] + a * nrm[1]])
        .collect()
}

/// Optimal lateral offsets at every centerline point.
pub(super) fn optimal_offsets(c: &Corridor) -> Vec<f64> {
    let n = c.points.len();
    let length = c.step * n as f64;
    let mut prev: Option<(Vec<f64>, usize)> = None;
    for (spacing, iterations) in LEVELS {
        let m = (libm::round(length / spacing) as usize).max(8);
        let at = |k: usize| k as f64 * n as f64 / m as f64;
        let pts: Vec<[f64; 2]> = (0..m).map(|k| lerp2(c.points, at(k))).collect();
        let nrm: Vec<[f64; 2]> = (0..m)
            .map(|k| {
                let v = lerp2(c.normals, at(k));
                let len = libm::hypot(v[0], v[1]);
                [v[0] / len, v[1] / len]
            })
            .collect();
        let lo: Vec<f64> = (0..m).map(|k| lerp(c.lo, at(k))).collect();
        let hi: Vec<f64> = (0..m).map(|k| lerp(c.hi, at(k))).collect();
        let start: Vec<f64> = match &prev {
            None => vec![0.0; m],
            Some((alpha, pm)) => (0..m)
                .map(|k| lerp(alpha, k as f64 * *pm as f64 / m as f64))
                .collect(),
        };
        let alpha = fista(&pts, &nrm, &lo, &hi, start, iterations);
        prev = Some((alpha, m));
    }
    let (alpha, m) = prev.expect("at least one level");
    // Back onto the fine points, by periodic Catmull-Rom interpolation (smooth, local).
    (0..n)
        .map(|i| {
            let x = i as f64 * m as f64 / n as f64;
            let k = libm::floor(x) as usize;
            let t = x - k as f64;
            let p = |d: isize| alpha[(k as isize + d).rem_euclid(m as isize) as usize];
            let v = catmull_rom(p(-1), p(0), p(1), p(2), t);
            v.clamp(c.lo[i], c.hi[i])
        })
        .collect()
}

fn fista(
    pts: &[[f64; 2]],
    nrm: &[[f64; 2]],
    lo: &[f64],
    hi: &[f64],
    start: Vec<f64>,
    iterations: usize,
) -> Vec<f64> {
    let m = pts.len();
    // Gradient Lipschitz constant: 2 * ||D2^T D2|| <= 2 * 16.
    let step = 1.0 / 32.0;
    let mut x: Vec<f64> = start
        .iter()
        .enumerate()
        .map(|(i, &a)| a.clamp(lo[i], hi[i]))
        .collect();
    let mut y = x.clone();
    let mut t = 1.0;
    let mut grad = vec![0.0; m];
    let mut p = vec![[0.0; 2]; m];
    let mut x_new = vec![0.0; m];
    for _ in 0..iterations {
        for i in 0..m {
            p[i] = [pts[i][0] + y[i] * nrm[i][0], pts[i][1] + y[i] * nrm[i][1]];
        }
        for i in 0..m {
            let q = |d: isize| p[(i as isize + d).rem_euclid(m as isize) as usize];
            let (a, b, c, d, e) = (q(-2), q(-1), q(0), q(1), q(2));
            let fx = a[0] - 4.0 * b[0] + 6.0 * c[0] - 4.0 * d[0] + e[0];
            let fy = a[1] - 4.0 * b[1] + 6.0 * c[1] - 4.0 * d[1] + e[1];
            grad[i] = 2.0 * (nrm[i][0] * fx + nrm[i][1] * fy);
        }
        let mut restart = 0.0;
        for i in 0..m {
            x_new[i] = (y[i] - step * grad[i]).clamp(lo[i], hi[i]);
            restart += grad[i] * (x_new[i] - x[i]);
        }
        if restart > 0.0 {
            // Momentum is pointing uphill: drop it (O'Donoghue and Candes restart).
            t = 1.0;
        }
        let t_new = 0.5 * (1.0 + libm::sqrt(1.0 + 4.0 * t * t));
        let beta = (t - 1.0) / t_new;
        for i in 0..m {
            let v = x_new[i] + beta * (x_new[i] - x[i]);
            y[i] = v.clamp(lo[i], hi[i]);
            x[i] = x_new[i];
        }
        t = t_new;
    }
    x
}

fn catmull_rom(p0: f64, p1: f64, p2: f64, p3: f64, t: f64) -> f64 {
    let t2 = t * t;
    let t3 = t2 * t;
    0.5 * (2.0 * p1
        + (p2 - p0) * t
        + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * t2
        + (3.0 * p1 - p0 - 3.0 * p2 + p3) * t3)
}

/// Periodic linear interpolation at fractional index `x`.
fn lerp(v: &[f64], x: f64) -> f64 {
    let n = v.len();
    let k = libm::floor(x) as usize;
    let t = x - k as f64;
    let (a, b) = (v[k % n], v[(k + 1) % n]);
    a + t * (b - a)
}

fn lerp2(v: &[[f64; 2]], x: f64) -> [f64; 2] {
    let n = v.len();
    let k = libm::floor(x) as usize;
    let t = x - k as f64;
    let (a, b) = (v[k % n], v[(k + 1) % n]);
    [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]
}

/// The raceline through `line` (a closed polyline), resampled at `spacing`, with heading,
/// curvature and speed profile.
pub(super) fn build(line: &[[f64; 2]], spacing: f64, limits: &SpeedLimits) -> Vec<RacelinePoint> {
    let pts = shape::resample_closed(line, spacing);
    let n = pts.len();
    let raw = shape::closed_curvature(&pts);
    // A light 5-point average takes the resampling ripple out of the curvature.
    let kappa: Vec<f64> = (0..n)
        .map(|i| {
            (-2..=2)
                .map(|d: isize| raw[(i as isize + d).rem_euclid(n as isize) as usize])
                .sum::<f64>()
                / 5.0
        })
        .collect();
    let ds: Vec<f64> = (0..n)
        .map(|i| {
            let (a, b) = (pts[i], pts[(i + 1) % n]);
            libm::hypot(b[0] - a[0], b[1] - a[1])
        })
        .collect();
    let vx = speed_profile(&kappa, &ds, limits);
    let mut s = 0.0;
    (0..n)
        .map(|i| {
            let a = pts[(i + n - 1) % n];
            let c = pts[(i + 1) % n];
            let mut psi = libm::atan2(c[1] - a[1], c[0] - a[0]).rem_euclid(TAU);
            if psi >= TAU {
                psi -= TAU;
            }
            let v_next = vx[(i + 1) % n];
            let ax = (v_next * v_next - vx[i] * vx[i]) / (2.0 * ds[i]);
            let point = RacelinePoint {
                s,
                x: pts[i][0],
                y: pts[i][1],
                psi,
                kappa: kappa[i],
                vx: vx[i],
                ax,
            };
            s += ds[i];
            point
        })
        .collect()
}

/// Closed-loop speed profile: the lateral limit gives a speed cap at each point; a
/// forward pass adds acceleration and a backward pass braking, both inside the friction
/// ellipse. Starting both passes at the slowest point makes the loop consistent.
pub(super) fn speed_profile(kappa: &[f64], ds: &[f64], limits: &SpeedLimits) -> Vec<f64> {
    let n = kappa.len();
    let a_lat = limits.lateral_accel();
    let cap: Vec<f64> = kappa
        .iter()
        .map(|&k| {
            let k = k.abs();
            if k > 1e-9 {
                limits.v_max.min(libm::sqrt(a_lat / k))
            } else {
                limits.v_max
            }
        })
        .collect();
    let start = (0..n)
        .min_by(|&a, &b| cap[a].total_cmp(&cap[b]))
        .unwrap_or(0);
    let remaining = |v: f64, k: f64| {
        let used = v * v * k.abs() / a_lat;
        libm::sqrt((1.0 - used * used).max(0.0))
    };
    let mut fwd = cap.clone();
    for step in 1..=n {
        let i = (start + step) % n;
        let p = (i + n - 1) % n;
        let a = limits.accel * remaining(fwd[p], kappa[p]);
        fwd[i] = cap[i].min(libm::sqrt(fwd[p] * fwd[p] + 2.0 * a * ds[p]));
    }
    let mut bwd = cap;
    for step in 1..=n {
        let i = (start + n - step) % n;
        let q = (i + 1) % n;
        let b = limits.brake * remaining(bwd[q], kappa[q]);
        bwd[i] = bwd[i].min(libm::sqrt(bwd[q] * bwd[q] + 2.0 * b * ds[i]));
    }
    fwd.iter().zip(&bwd).map(|(f, b)| f.min(*b)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn speed_on_a_circle_is_the_lateral_limit() {
        let limits = SpeedLimits::default();
        let kappa = vec![0.2; 300];
        let ds = vec![0.1; 300];
        let v = speed_profile(&kappa, &ds, &limits);
        let expect = libm::sqrt(limits.lateral_accel() / 0.2);
        assert!(v.iter().all(|&x| (x - expect).abs() < 1e-9));
    }

    #[test]
    fn speed_respects_accel_and_brake() {
        let limits = SpeedLimits::default();
        // A straight with one tight bend.
        let n = 1000;
        let kappa: Vec<f64> = (0..n)
            .map(|i| if (500..520).contains(&i) { 0.35 } else { 0.0 })
            .collect();
        let ds = vec![0.1; n];
        let v = speed_profile(&kappa, &ds, &limits);
        for i in 0..n {
            let j = (i + 1) % n;
            let ax = (v[j] * v[j] - v[i] * v[i]) / (2.0 * ds[i]);
            assert!(
                ax <= limits.accel + 1e-9 && ax >= -limits.brake - 1e-9,
                "{ax}"
            );
            assert!(v[i] <= limits.v_max + 1e-12);
        }
    }
}
