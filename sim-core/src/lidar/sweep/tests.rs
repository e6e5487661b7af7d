//! The sweep's own parts: its angle bounds, culling maxima and run selection.

use super::fan::atan2_fast;
use super::*;
use crate::geometry::wrap_angle;
use std::f64::consts::TAU;

#[cfg(target_arch = "x86_64")]
#[test]
fn atan2_ps_is_within_its_bound() {
    use std::arch::x86_64::*;
    if !std::arch::is_x86_feature_detected!("avx") {
        return;
    }
    // SAFETY (each call): the CPU has AVX (checked above).
    let atan2 = |y: f32, x: f32| unsafe {
        _mm256_cvtss_f32(avx::atan2_ps(_mm256_set1_ps(y), _mm256_set1_ps(x)))
    };
    // radians: the bound `atan2_ps` documents
    let bound = 2.7e-4;
    let mut worst = 0.0f64;
    let n = 200_000;
    for r in [1e-9, 1e-3, 1.0, 1e4, 3e7] {
        for i in (0..n).step_by(8) {
            let (mut xs, mut ys) = ([0f32; 8], [0f32; 8]);
            let mut exact = [0f64; 8];
            for l in 0..8 {
                let a = -PI + TAU * (i + l) as f64 / n as f64;
                let (y, x) = (r * libm::sin(a), r * libm::cos(a));
                (xs[l], ys[l]) = (x as f32, y as f32);
                exact[l] = libm::atan2(y, x);
            }
            let mut got = [0f32; 8];
            // SAFETY: the CPU has AVX (checked above); the arrays hold eight lanes.
            unsafe {
                let a = avx::atan2_ps(_mm256_loadu_ps(ys.as_ptr()), _mm256_loadu_ps(xs.as_ptr()));
                _mm256_storeu_ps(got.as_mut_ptr(), a);
            }
            for l in 0..8 {
                worst = worst.max(wrap_angle(f64::from(got[l]) - exact[l]).abs());
            }
        }
    }
    assert!(worst < bound, "worst error {worst}");
    assert!(worst < avx::ANGLE_ERR_PS);
    // the axes where they are, and the negative x axis: +pi for y = +-0.0, as the
    // double-precision atan2
    let (pi, half) = (std::f32::consts::PI, std::f32::consts::FRAC_PI_2);
    for (y, x, want) in [
        (0.0, 3.0, 0.0),
        (-0.0, 3.0, 0.0),
        (-0.0, -2.0, pi),
        (0.0, -2.0, pi),
        (5.0, 0.0, half),
        (-5.0, 0.0, -half),
    ] {
        assert_eq!(atan2(y, x), want, "atan2({y}, {x})");
    }
    // each octant's side of the diagonals
    for k in 0..8 {
        let a = -PI + TAU * (k as f64 + 0.5) / 8.0;
        for d in [-1e-3, 0.0, 1e-3] {
            let (y, x) = (libm::sin(a + d) as f32, libm::cos(a + d) as f32);
            let want = libm::atan2(f64::from(y), f64::from(x));
            let got = f64::from(atan2(y, x));
            assert!(
                (got - want).abs() < bound,
                "atan2({y}, {x}) = {got}, not {want}"
            );
        }
    }
}

/// The AVX form's beams of a side's runs hold every beam whose direction (by the double-
/// precision atan2) lies between the directions of the run's ends, on fans narrow and
/// nearly full, of few beams and of many, from origins near and far; a run's lanes are
/// whole and at least two; the span returned holds those of the runs that have beams.
#[cfg(target_arch = "x86_64")]
#[test]
fn the_runs_beams_hold_every_beam_between_their_ends() {
    if !std::arch::is_x86_feature_detected!("avx") {
        return;
    }
    let mut rng = crate::rng::Rng::new(77);
    let mut checked = 0;
    for k in 0..3000 {
        let (n, fov) = [(1080, 4.7), (64, 1.0), (721, 5.9), (4096, 6.2)][k % 4];
        let inc = fov / (n - 1) as f64;
        let heading = rng.uniform_range(-PI, PI);
        let fan = Fan::new(libm::cos(heading), libm::sin(heading), fov, inc);
        let (g_line, g_along) = (
            rng.uniform_range(0.0, 3000.0),
            rng.uniform_range(0.0, 3000.0),
        );
        let spread = [2.0, 30.0, 600.0][k % 3];
        let m = 1 + rng.below(11) as usize;
        let mut line = vec![0f32; m + 3];
        let (mut los, mut his) = (vec![0f32; m + 3], vec![0f32; m + 3]);
        for j in 0..m + 3 {
            let l = (g_line + rng.uniform_range(-spread, spread)).round();
            line[j] = l as f32;
            let lo = (g_along + rng.uniform_range(-spread, spread)).floor();
            los[j] = lo as f32;
            his[j] = (lo + 1.0 + rng.below(40) as f64) as f32;
        }
        let top = (n - 1) as f64;
        for vertical in [false, true] {
            let mut runs = avx::Runs::default();
            runs.reserve(m);
            // SAFETY: the CPU has AVX (checked above); the slices hold m + 3 runs.
            let span = unsafe {
                if vertical {
                    avx::beams_of_runs::<true>(
                        &line, &los, &his, m, g_line, g_along, &fan, 1e9, top, &mut runs,
                    )
                } else {
                    avx::beams_of_runs::<false>(
                        &line, &los, &his, m, g_line, g_along, &fan, 1e9, top, &mut runs,
                    )
                }
            };
            let (mut least, mut most) = (usize::MAX, 0);
            for j in 0..m {
                let (from, to) = runs.lanes(j);
                assert!(from % LANES == 0 && to % LANES == 0 && to >= from + 2 * LANES);
                let across = f64::from(line[j]) - g_line;
                let end = |along: f32| {
                    let along = f64::from(along) - g_along;
                    let (x, y) = if vertical {
                        (across, along)
                    } else {
                        (along, across)
                    };
                    let a = libm::atan2(y * fan.cos - x * fan.sin, x * fan.cos + y * fan.sin);
                    (a + fan.half_fov) * fan.inv_inc
                };
                let (i0, i1) = (end(los[j]), end(his[j]));
                let (a, b) = (i0.min(i1), i0.max(i1));
                if (b - a - PI * fan.inv_inc).abs() < 1.0 {
                    // seen across nearly half a turn: either answer is safe
                    continue;
                }
                // the beams between the ends (by more than the double atan2's rounding);
                // a run across the direction behind takes every beam
                let want = if b - a > PI * fan.inv_inc {
                    0..n
                } else {
                    let first = (a + 1e-9).ceil().max(0.0) as usize;
                    let last = (b - 1e-9).floor().min(top);
                    first..(last + 1.0).max(0.0) as usize
                };
                if want.is_empty() {
                    continue;
                }
                checked += 1;
                assert!(
                    from <= want.start && want.end <= to,
                    "run {j} (vertical {vertical}): beams {want:?} not in {from}..{to}"
                );
                least = least.min(want.start);
                most = most.max(want.end - 1);
            }
            if least <= most {
                let (l, h) = span.expect("a span");
                assert!(
                    l <= least && most <= h,
                    "span {l}..={h} misses {least}..={most}"
                );
            }
        }
    }
    assert!(checked > 5000, "only {checked} runs had beams");
}

#[test]
fn atan2_fast_is_within_its_bound() {
    let mut worst = 0.0f64;
    for i in 0..20_000 {
        let a = -PI + TAU * i as f64 / 20_000.0;
        for r in [1e-3, 1.0, 1e4] {
            let (y, x) = (r * libm::sin(a), r * libm::cos(a));
            let e = wrap_angle(atan2_fast(y, x) - libm::atan2(y, x)).abs();
            worst = worst.max(e);
        }
    }
    assert!(worst < 1e-6, "worst error {worst}");
    assert!(worst * 5.0 < ANGLE_SLACK);
}

#[test]
fn the_culling_maxima_are_the_largest_values_on_every_path() {
    let mut rng = crate::rng::Rng::new(5);
    for len in 0..70 {
        let v: Vec<f64> = (0..len).map(|_| rng.uniform_range(0.0, 900.0)).collect();
        for start in [0.0, 450.0, 1e9] {
            let want = v.iter().fold(start, |a: f64, &b| a.max(b));
            assert_eq!(
                max_of::<false>(start, &v),
                want,
                "{len} values from {start}"
            );
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx") {
                assert_eq!(max_of::<true>(start, &v), want, "{len} values from {start}");
            }
        }
    }
}

#[test]
fn marking_groups_marks_exactly_the_groups_of_the_beams() {
    let beams = 64 * GROUP * 3;
    for (b0, b1) in [(0, 0), (0, beams - 1), (15, 16), (1000, 1030), (1023, 1024)]
        .into_iter()
        .chain(
            (0..beams)
                .step_by(97)
                .map(|b| (b, (b + 777).min(beams - 1))),
        )
    {
        let mut dirty = [0u64; 3];
        mark_groups(&mut dirty, b0, b1);
        for g in 0..beams / GROUP {
            let want = (b0 / GROUP..=b1 / GROUP).contains(&g);
            assert_eq!(
                dirty[g / 64] >> (g % 64) & 1 == 1,
                want,
                "group {g} of {b0}..={b1}"
            );
        }
    }
}

#[test]
fn the_boxes_directions_are_within_their_slack() {
    let mut rng = crate::rng::Rng::new(9);
    for _ in 0..20_000 {
        let heading = rng.uniform_range(-PI, PI);
        let fan = Fan::new(libm::cos(heading), libm::sin(heading), 4.7, 4.7 / 1079.0);
        let (gx, gy) = (
            rng.uniform_range(0.0, 2000.0),
            rng.uniform_range(0.0, 2000.0),
        );
        let corner = |rng: &mut crate::rng::Rng| -> [f64; 4] {
            let (x0, y0) = (rng.below(32) as f64 * 64.0, rng.below(32) as f64 * 64.0);
            [x0, y0, x0 + 64.0, y0 + 64.0]
        };
        let (group, rect) = (corner(&mut rng), corner(&mut rng));
        let exact = |[x0, y0, x1, y1]: [f64; 4]| -> [f64; 4] {
            let (xs, ys) = ([x0, x1, x0, x1], [y0, y0, y1, y1]);
            std::array::from_fn(|k| {
                let (vx, vy) = (xs[k] - gx, ys[k] - gy);
                libm::atan2(vy * fan.cos - vx * fan.sin, vx * fan.cos + vy * fan.sin)
            })
        };
        let check = |avx: bool| {
            let (ga, ra, slack) = if avx {
                box_angles::<true>(&fan, gx, gy, Some(group), rect)
            } else {
                box_angles::<false>(&fan, gx, gy, Some(group), rect)
            };
            for (got, want) in [(ga, exact(group)), (ra, exact(rect))] {
                for k in 0..4 {
                    let e = wrap_angle(got[k] - want[k]).abs();
                    assert!(e < slack, "{e} over {slack} (avx {avx})");
                }
            }
        };
        check(false);
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx") {
            check(true);
        }
    }
}

#[test]
fn a_sides_runs_are_narrowed_to_those_ahead_and_within_reach() {
    let mut rng = crate::rng::Rng::new(11);
    for _ in 0..2000 {
        let m = rng.below(40) as usize;
        let mut lines: Vec<f32> = (0..m).map(|_| rng.below(200) as f32).collect();
        lines.sort_by(f32::total_cmp);
        let start = vec![0, m as u32, m as u32, m as u32, m as u32];
        let (rows, cols) = crate::map::faces::block_bits(1, 1, &start);
        let faces = WallFaces {
            blocks_x: 1,
            blocks_y: 1,
            rows,
            cols,
            start,
            lo: vec![0.0; m + 3],
            hi: vec![1.0; m + 3],
            line: lines.iter().copied().chain([0.0; 3]).collect(),
        };
        let g = rng.below(200) as f64 + rng.uniform_range(1e-6, 1.0 - 1e-6);
        let far = rng.uniform_range(0.0, 120.0);
        for plus in [true, false] {
            let got = if plus {
                ahead::<true>(&faces, 0..m, g, far)
            } else {
                ahead::<false>(&faces, 0..m, g, far)
            };
            for (j, &l) in lines.iter().enumerate() {
                let across = f64::from(l) - g;
                let beyond = if plus { across > 0.0 } else { across < 0.0 };
                let near = across.abs() * (1.0 - 1e-9) - EPS <= far;
                if beyond && near {
                    assert!(got.contains(&j), "run {j} on {l} from {g} within {far}");
                }
                if got.contains(&j) {
                    assert!(beyond && across.abs() <= far + 3.0, "run {j} on {l}");
                }
            }
        }
    }
}
