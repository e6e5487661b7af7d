//! The centerline of a candidate track: a random star-shaped corner polygon whose edges
//! are kept straight and whose corners are rounded by a periodic cubic B-spline, scaled
//! to the target length and resampled at uniform arc-length spacing.
//!
//! A star-shaped polygon (corners at increasing polar angles) is simple by construction,
//! so the only ways a candidate can fail are a corner tighter than the minimum radius
//! and two parts of the corridor closer than the wall gap; both are checked in
//! [`super::generate`] and the candidate is thrown away.

use std::f64::consts::TAU;

use crate::rng::Rng;

/// Spacing (m) of the dense B-spline samples the uniform resampling interpolates.
const DENSE_STEP: f64 = 0.01;

/// Largest tightness (flank distance over the shorter adjacent edge) a corner may get.
const MAX_TIGHTNESS: f64 = 0.49;
/// Rounds of widening corners that are too tight.
const REPAIR_ROUNDS: usize = 24;

/// A closed polyline at uniform arc-length spacing, counter-clockwise, first point not
/// repeated at the end. Corners tighter than `min_radius` are widened (up to a limit)
/// before the shape is sampled, so most candidates survive the radius check.
pub(super) fn candidate(
    rng: &mut Rng,
    length_m: f64,
    spacing: f64,
    min_radius: f64,
) -> Vec<[f64; 2]> {
    let (mut corners, mut tightness) = corner_polygon(rng, length_m);
    let k = corners.len();
    let mut control = control_points(&corners, &tightness);
    for _ in 0..REPAIR_ROUNDS {
        let scale = length_m / closed_length(&sample_bspline(&control, |_, _| 16));
        let mut changed = false;
        for i in 0..k {
            // The spans around corner i: control points 5i-2 .. 5i+2.
            let kappa = (0..4)
                .map(|d| span_max_curvature(&control, (5 * (i + k) - 2 + d) % control.len()))
                .fold(0.0, f64::max);
            if kappa / scale * min_radius <= 1.0 {
                continue;
            }
            changed = true;
            if tightness[i] < MAX_TIGHTNESS {
                tightness[i] = (tightness[i] * 1.25).min(MAX_TIGHTNESS);
            } else {
                // Already as round as its edges allow: make the turn itself gentler by
                // pulling the corner a quarter of the way to its neighbours' midpoint.
                let (a, b) = (corners[(i + k - 1) % k], corners[(i + 1) % k]);
                let mid = [0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1])];
                let c = &mut corners[i];
                c[0] += 0.25 * (mid[0] - c[0]);
                c[1] += 0.25 * (mid[1] - c[1]);
            }
        }
        if !changed {
            break;
        }
        control = control_points(&corners, &tightness);
    }
    let scale = length_m / closed_length(&sample_bspline(&control, |_, _| 16));
    let control: Vec<[f64; 2]> = control
        .iter()
        .map(|p| [p[0] * scale, p[1] * scale])
        .collect();
    let dense = sample_bspline(&control, |a, b| {
        let chord = libm::hypot(b[0] - a[0], b[1] - a[1]);
        (libm::ceil(chord / DENSE_STEP) as usize).max(8)
    });
    resample_closed(&dense, spacing)
}

/// Corner points at jittered increasing polar angles with random radii (some pulled far
/// in, which makes hairpins and chicanes), and each corner's tightness.
fn corner_polygon(rng: &mut Rng, length_m: f64) -> (Vec<[f64; 2]>, Vec<f64>) {
    let base = (length_m / 14.0).clamp(7.0, 22.0) as u64;
    let k = (base + rng.below(5)).saturating_sub(2).max(6) as usize;
    let corners: Vec<[f64; 2]> = (0..k)
        .map(|i| {
            let theta = (i as f64 + rng.uniform_range(-0.3, 0.3)) * TAU / k as f64;
            let r = if rng.uniform() < 0.35 {
                rng.uniform_range(0.15, 0.45)
            } else {
                rng.uniform_range(0.6, 1.0)
            };
            [r * libm::cos(theta), r * libm::sin(theta)]
        })
        .collect();
    let tightness = (0..k).map(|_| rng.uniform_range(0.08, 0.35)).collect();
    (corners, tightness)
}

/// Control points: each corner, then along its outgoing edge a flanking point at the
/// corner's distance, two collinear fill points and the next corner's flanking point, so
/// the spline runs straight between corners. The flank distance is the corner's
/// tightness times its shorter adjacent edge (small = tight corner).
fn control_points(corners: &[[f64; 2]], tightness: &[f64]) -> Vec<[f64; 2]> {
    let k = corners.len();
    let edge_len = |i: usize| {
        let (a, b) = (corners[i], corners[(i + 1) % k]);
        libm::hypot(b[0] - a[0], b[1] - a[1])
    };
    let flank: Vec<f64> = (0..k)
        .map(|i| tightness[i] * edge_len((i + k - 1) % k).min(edge_len(i)))
        .collect();
    let mut control = Vec::with_capacity(5 * k);
    for i in 0..k {
        let j = (i + 1) % k;
        let (a, b) = (corners[i], corners[j]);
        let e = edge_len(i);
        let u = [(b[0] - a[0]) / e, (b[1] - a[1]) / e];
        let start = flank[i];
        let end = e - flank[j];
        let at = |d: f64| [a[0] + d * u[0], a[1] + d * u[1]];
        control.push(a);
        for f in [0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0] {
            control.push(at(start + f * (end - start)));
        }
    }
    control
}

/// Largest |curvature| of the B-spline span between control points j and j+1 (sampled).
fn span_max_curvature(control: &[[f64; 2]], j: usize) -> f64 {
    let m = control.len();
    let p = [
        control[(j + m - 1) % m],
        control[j],
        control[(j + 1) % m],
        control[(j + 2) % m],
    ];
    let mut best = 0.0_f64;
    for step in 0..=8 {
        let t = step as f64 / 8.0;
        let d1 = [
            -(1.0 - t) * (1.0 - t) / 2.0,
            (3.0 * t * t - 4.0 * t) / 2.0,
            (-3.0 * t * t + 2.0 * t + 1.0) / 2.0,
            t * t / 2.0,
        ];
        let d2 = [1.0 - t, 3.0 * t - 2.0, 1.0 - 3.0 * t, t];
        let mut v = [0.0; 2];
        let mut a = [0.0; 2];
        for q in 0..4 {
            for c in 0..2 {
                v[c] += d1[q] * p[q][c];
                a[c] += d2[q] * p[q][c];
            }
        }
        let speed = libm::hypot(v[0], v[1]);
        if speed > 1e-12 {
            best = best.max((v[0] * a[1] - v[1] * a[0]).abs() / (speed * speed * speed));
        }
    }
    best
}

/// Samples the closed uniform cubic B-spline of `control`; `count(p_j, p_j1)` gives the
/// number of samples of the span between control points j and j+1.
fn sample_bspline(
    control: &[[f64; 2]],
    count: impl Fn([f64; 2], [f64; 2]) -> usize,
) -> Vec<[f64; 2]> {
    let m = control.len();
    let mut out = Vec::new();
    for j in 0..m {
        let p0 = control[(j + m - 1) % m];
        let p1 = control[j];
        let p2 = control[(j + 1) % m];
        let p3 = control[(j + 2) % m];
        let n = count(p1, p2);
        for step in 0..n {
            let t = step as f64 / n as f64;
            let t2 = t * t;
            let t3 = t2 * t;
            let u = 1.0 - t;
            let b0 = u * u * u / 6.0;
            let b1 = (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0;
            let b2 = (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0;
            let b3 = t3 / 6.0;
            out.push([
                b0 * p0[0] + b1 * p1[0] + b2 * p2[0] + b3 * p3[0],
                b0 * p0[1] + b1 * p1[1] + b2 * p2[1] + b3 * p3[1],
            ]);
        }
    }
    out
}

/// Length of the closed polyline through `pts`.
pub(super) fn closed_length(pts: &[[f64; 2]]) -> f64 {
    let n = pts.len();
    (0..n)
        .map(|i| {
            let (a, b) = (pts[i], pts[(i + 1) % n]);
            libm::hypot(b[0] - a[0], b[1] - a[1])
        })
        .sum()
}

/// Resamples a closed polyline to `round(length / spacing)` points equally spaced in arc
/// length (linear interpolation), starting at the first point.
pub(super) fn resample_closed(pts: &[[f64; 2]], spacing: f64) -> Vec<[f64; 2]> {
    let n_in = pts.len();
    let total = closed_length(pts);
    let n_out = (libm::round(total / spacing) as usize).max(3);
    let step = total / n_out as f64;
    let mut out = Vec::with_capacity(n_out);
    let mut seg = 0usize;
    let mut seg_start = 0.0;
    let mut seg_len = seg_length(pts, 0);
    for k in 0..n_out {
        let s = k as f64 * step;
        while s > seg_start + seg_len && seg + 1 < n_in {
            seg_start += seg_len;
            seg += 1;
            seg_len = seg_length(pts, seg);
        }
        let t = if seg_len > 0.0 {
            ((s - seg_start) / seg_len).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let (a, b) = (pts[seg], pts[(seg + 1) % n_in]);
        out.push([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]);
    }
    out
}

fn seg_length(pts: &[[f64; 2]], i: usize) -> f64 {
    let (a, b) = (pts[i], pts[(i + 1) % pts.len()]);
    libm::hypot(b[0] - a[0], b[1] - a[1])
}

/// Signed curvature (1/m, positive = turning left) at every point of a closed polyline:
/// the inverse radius of the circle through the point and its two neighbours.
pub(super) fn closed_curvature(pts: &[[f64; 2]]) -> Vec<f64> {
    let n = pts.len();
    (0..n)
        .map(|i| {
            let a = pts[(i + n - 1) % n];
            let b = pts[i];
            let c = pts[(i + 1) % n];
            menger(a, b, c)
        })
        .collect()
}

fn menger(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> f64 {
    let cross = (b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0]);
    let ab = libm::hypot(b[0] - a[0], b[1] - a[1]);
    let bc = libm::hypot(c[0] - b[0], c[1] - b[1]);
    let ca = libm::hypot(a[0] - c[0], a[1] - c[1]);
    let denom = ab * bc * ca;
    if denom > 0.0 {
        2.0 * cross / denom
    } else {
        0.0
    }
}

/// Unit left normals of a closed polyline (central differences).
pub(super) fn closed_left_normals(pts: &[[f64; 2]]) -> Vec<[f64; 2]> {
    let n = pts.len();
    (0..n)
        .map(|i| {
            let a = pts[(i + n - 1) % n];
            let c = pts[(i + 1) % n];
            let (tx, ty) = (c[0] - a[0], c[1] - a[1]);
            let len = libm::hypot(tx, ty);
            [-ty / len, tx / len]
        })
        .collect()
}

/// Twice the signed area (positive = counter-clockwise).
pub(super) fn signed_area2(pts: &[[f64; 2]]) -> f64 {
    let n = pts.len();
    (0..n)
        .map(|i| {
            let (a, b) = (pts[i], pts[(i + 1) % n]);
            a[0] * b[1] - b[0] * a[1]
        })
        .sum()
}

/// A smooth periodic width profile over `n` points: a few random low harmonics mapped
/// onto [w_min, w_max] (both ends reached when they differ).
pub(super) fn width_profile(rng: &mut Rng, n: usize, w_min: f64, w_max: f64) -> Vec<f64> {
    let harmonics: Vec<(f64, f64, f64)> = (1..=4)
        .map(|j| {
            let amp = rng.uniform_range(0.3, 1.0) / j as f64;
            let phase = rng.uniform_range(0.0, TAU);
            (j as f64, amp, phase)
        })
        .collect();
    let raw: Vec<f64> = (0..n)
        .map(|i| {
            let u = TAU * i as f64 / n as f64;
            harmonics
                .iter()
                .map(|&(j, amp, phase)| amp * libm::sin(j * u + phase))
                .sum()
        })
        .collect();
    let lo = raw.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = raw.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let span = (hi - lo).max(1e-12);
    raw.iter()
        .map(|&r| w_min + (w_max - w_min) * (r - lo) / span)
        .collect()
}

/// Checks that no two parts of the corridor come closer than `gap` (m of wall between
/// their edges) unless they are adjacent along the track. `half` is the half width at
/// each point. For each point, the run of neighbours that stay within reach is walked
/// both ways; any other point within reach is a second part of the track that comes too
/// close. Returns the offending pair of indices.
pub(super) fn find_too_close(pts: &[[f64; 2]], half: &[f64], gap: f64) -> Option<(usize, usize)> {
    let n = pts.len();
    let reach = |a: usize, b: usize| half[a] + half[b] + gap;
    let dist = |a: usize, b: usize| libm::hypot(pts[a][0] - pts[b][0], pts[a][1] - pts[b][1]);
    let mut adjacent = vec![false; n];
    for a in 0..n {
        adjacent.iter_mut().for_each(|x| *x = false);
        adjacent[a] = true;
        for dir in [1, n - 1] {
            let mut b = (a + dir) % n;
            while b != a && dist(a, b) < reach(a, b) {
                adjacent[b] = true;
                b = (b + dir) % n;
            }
        }
        let far = (0..n).zip(&adjacent).filter(|&(_, &adj)| !adj);
        if let Some((b, _)) = far.into_iter().find(|&(b, _)| dist(a, b) < reach(a, b)) {
            return Some((a, b));
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn circle(r: f64, n: usize) -> Vec<[f64; 2]> {
        (0..n)
            .map(|i| {
                let a = TAU * i as f64 / n as f64;
                [r * libm::cos(a), r * libm::sin(a)]
            })
            .collect()
    }

    #[test]
    fn curvature_of_a_circle_is_one_over_radius() {
        let pts = circle(5.0, 400);
        for k in closed_curvature(&pts) {
            assert!((k - 0.2).abs() < 1e-3, "{k}");
        }
        assert!(signed_area2(&pts) > 0.0);
    }

    #[test]
    fn resampling_gives_uniform_spacing() {
        let pts = resample_closed(&circle(10.0, 5000), 0.1);
        let n = pts.len();
        for i in 0..n {
            let d = seg_length(&pts, i);
            assert!((d - 0.1).abs() < 1e-3, "{d}");
        }
    }

    #[test]
    fn a_figure_of_eight_is_too_close_to_itself() {
        let pts: Vec<[f64; 2]> = (0..600)
            .map(|i| {
                let a = TAU * i as f64 / 600.0;
                [20.0 * libm::sin(a), 10.0 * libm::sin(2.0 * a)]
            })
            .collect();
        let half = vec![1.0; pts.len()];
        assert!(find_too_close(&pts, &half, 1.5).is_some());
        assert!(find_too_close(&circle(20.0, 600), &half, 1.5).is_none());
    }

    #[test]
    fn width_profile_spans_the_range() {
        let w = width_profile(&mut Rng::new(1), 1000, 2.0, 4.0);
        let lo = w.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = w.iter().copied().fold(0.0, f64::max);
        assert!((lo - 2.0).abs() < 1e-9 && (hi - 4.0).abs() < 1e-9);
    }
}
