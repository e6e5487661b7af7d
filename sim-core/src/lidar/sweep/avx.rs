//! The sweep's AVX kernels: the runs' beam ranges, four runs at a time, and their
//! crossings, four beams at a time (the same operations lane by lane as the portable
//! code in `super`, so the same bits).

use std::arch::x86_64::*;
use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

use super::{ANGLE_SLACK, EPS, Fan, GROUP, LANES, Run};

/// `Sweep::cross`'s first and last beam of the runs, four at a time (each run's two ends'
/// directions by `atan2_fast`'s operations): of all of them if the arrays' length is a
/// multiple of four, else of all but the last `len % 4`, which only pad.
///
/// # Safety
/// The CPU must support AVX.
#[target_feature(enable = "avx")]
#[allow(clippy::too_many_arguments)]
#[inline]
pub(super) unsafe fn beams_of_runs<const VERTICAL: bool>(
    line: &[f32],
    los: &[f32],
    his: &[f32],
    g_line: f64,
    g_along: f64,
    fan: &Fan,
    far: f64,
    top: f64,
    first: &mut [f64],
    last: &mut [f64],
) {
    let m = line
        .len()
        .min(los.len())
        .min(his.len())
        .min(first.len())
        .min(last.len());
    let set = _mm256_set1_pd;
    let sign = set(-0.0);
    let index = |vx: __m256d, vy: __m256d| -> __m256d {
        // SAFETY: the CPU has AVX (this function's contract).
        let a = unsafe { angles(fan, vx, vy) };
        _mm256_mul_pd(_mm256_add_pd(a, set(fan.half_fov)), set(fan.inv_inc))
    };
    let slack = set(ANGLE_SLACK * fan.inv_inc);
    let wrap = set(PI * fan.inv_inc);
    let cull = set(far);
    let mut j = 0;
    while j + LANES <= m {
        // SAFETY: j + 4 <= m, within every array.
        let load = |a: &[f32]| unsafe { _mm256_cvtps_pd(_mm_loadu_ps(a.as_ptr().add(j))) };
        let across = _mm256_sub_pd(load(line), set(g_line));
        let a0 = _mm256_sub_pd(load(los), set(g_along));
        let a1 = _mm256_sub_pd(load(his), set(g_along));
        let (i0, i1) = if VERTICAL {
            (index(across, a0), index(across, a1))
        } else {
            (index(a0, across), index(a1, across))
        };
        let (a, b) = (_mm256_min_pd(i0, i1), _mm256_max_pd(i0, i1));
        let whole = _mm256_cmp_pd::<_CMP_GT_OQ>(_mm256_sub_pd(b, a), wrap);
        let a = _mm256_max_pd(_mm256_ceil_pd(_mm256_sub_pd(a, slack)), set(0.0));
        let b = _mm256_min_pd(_mm256_floor_pd(_mm256_add_pd(b, slack)), set(top));
        let a = _mm256_blendv_pd(a, set(0.0), whole);
        let b = _mm256_blendv_pd(b, set(top), whole);
        let dist = _mm256_sub_pd(
            _mm256_mul_pd(_mm256_andnot_pd(sign, across), set(1.0 - 1e-9)),
            set(EPS),
        );
        let b = _mm256_blendv_pd(b, set(-1.0), _mm256_cmp_pd::<_CMP_GT_OQ>(dist, cull));
        // SAFETY: as above.
        unsafe {
            _mm256_storeu_pd(first.as_mut_ptr().add(j), a);
            _mm256_storeu_pd(last.as_mut_ptr().add(j), b);
        }
        j += LANES;
    }
}

/// `atan2_fast` on four lanes (the same operations, but y = -0.0 gives +pi where
/// `atan2_fast` gives -pi on the negative x axis: both bound the same beams).
///
/// # Safety
/// The CPU must support AVX.
#[target_feature(enable = "avx")]
#[inline]
unsafe fn atan2(y: __m256d, x: __m256d) -> __m256d {
    let set = _mm256_set1_pd;
    let sign = set(-0.0);
    let (ax, ay) = (_mm256_andnot_pd(sign, x), _mm256_andnot_pd(sign, y));
    let swap = _mm256_cmp_pd::<_CMP_GT_OQ>(ay, ax);
    let num = _mm256_blendv_pd(ay, ax, swap);
    let den = _mm256_blendv_pd(ax, ay, swap);
    let red = _mm256_cmp_pd::<_CMP_GT_OQ>(num, _mm256_mul_pd(set(0.414_213_562_373_095), den));
    let z = _mm256_div_pd(
        _mm256_blendv_pd(num, _mm256_sub_pd(num, den), red),
        _mm256_blendv_pd(den, _mm256_add_pd(num, den), red),
    );
    let z2 = _mm256_mul_pd(z, z);
    let mut p = set(1.0 / 13.0);
    for k in [
        -1.0 / 11.0,
        1.0 / 9.0,
        -1.0 / 7.0,
        1.0 / 5.0,
        -1.0 / 3.0,
        1.0,
    ] {
        p = _mm256_add_pd(set(k), _mm256_mul_pd(z2, p));
    }
    let a = _mm256_add_pd(_mm256_and_pd(red, set(FRAC_PI_4)), _mm256_mul_pd(z, p));
    let a = _mm256_blendv_pd(a, _mm256_sub_pd(set(FRAC_PI_2), a), swap);
    let a = _mm256_blendv_pd(
        a,
        _mm256_sub_pd(set(PI), a),
        _mm256_cmp_pd::<_CMP_LT_OQ>(x, set(0.0)),
    );
    _mm256_blendv_pd(
        a,
        _mm256_sub_pd(set(0.0), a),
        _mm256_cmp_pd::<_CMP_LT_OQ>(y, set(0.0)),
    )
}

/// The directions relative to the heading of the four corners `(x[k], y[k])` as seen from
/// (gx, gy), by [`angles`].
///
/// # Safety
/// The CPU must support AVX.
#[target_feature(enable = "avx")]
#[inline]
pub(super) unsafe fn corner_angles(
    fan: &Fan,
    gx: f64,
    gy: f64,
    x: [f64; 4],
    y: [f64; 4],
) -> [f64; 4] {
    // SAFETY: the arrays hold four values each.
    let (vx, vy) = unsafe {
        (
            _mm256_sub_pd(_mm256_loadu_pd(x.as_ptr()), _mm256_set1_pd(gx)),
            _mm256_sub_pd(_mm256_loadu_pd(y.as_ptr()), _mm256_set1_pd(gy)),
        )
    };
    let mut out = [0.0; 4];
    // SAFETY: `out` holds four values; the CPU has AVX (this function's contract).
    unsafe { _mm256_storeu_pd(out.as_mut_ptr(), angles(fan, vx, vy)) };
    out
}

/// The directions of the vectors (vx, vy) relative to the heading, four at a time
/// (`Fan::angle`'s operations, by [`atan2`]).
///
/// # Safety
/// The CPU must support AVX.
#[target_feature(enable = "avx")]
#[inline]
unsafe fn angles(fan: &Fan, vx: __m256d, vy: __m256d) -> __m256d {
    let (c, s) = (_mm256_set1_pd(fan.cos), _mm256_set1_pd(fan.sin));
    let u = _mm256_add_pd(_mm256_mul_pd(vx, c), _mm256_mul_pd(vy, s));
    let v = _mm256_sub_pd(_mm256_mul_pd(vy, c), _mm256_mul_pd(vx, s));
    // SAFETY: the CPU has AVX (this function's contract).
    unsafe { atan2(v, u) }
}

/// `Sweep::cross`'s crossings with AVX: for each run (line, lo, hi) its beams
/// `first..=last` (none when last < first), four per instruction with the same operations
/// lane by lane as [`Run::cross`], so the same bits; each run's groups of beams marked in
/// `dirty`. Returns whether any beam was flagged (rare: set lane by lane behind a branch,
/// not by a load and a store per lane). A run within two lanes of beams (most are) takes exactly two, whatever its
/// span: the extra beams cannot cross it, and no loop exit is mispredicted.
///
/// # Safety
/// The CPU must support AVX.
#[target_feature(enable = "avx")]
#[allow(clippy::too_many_arguments)]
#[inline]
pub(super) unsafe fn cross_runs(
    line: &[f32],
    los: &[f32],
    his: &[f32],
    first: &[f64],
    last: &[f64],
    g_line: f64,
    g_along: f64,
    inv: &[f64],
    along: &[f64],
    best: &mut [f64],
    flag: &mut [f64],
    dirty: &mut [u64],
) -> bool {
    let m = first
        .len()
        .min(last.len())
        .min(line.len())
        .min(los.len())
        .min(his.len());
    let n = inv.len().min(along.len()).min(best.len()).min(flag.len());
    let zero = _mm256_setzero_pd();
    let mut flagged = false;
    let inf = _mm256_set1_pd(f64::INFINITY);
    let g = _mm256_set1_pd(g_along);
    let half = m.div_ceil(2);
    // The groups of beams 0..2048 to mark dirty.
    let mut marks = 0u128;
    for k in 0..m {
        // Runs from the two halves in turn: neighbouring runs (along a line) share beams,
        // and updating the same beams in a row would wait on each other's stores.
        let j = if k % 2 == 0 { k / 2 } else { half + k / 2 };
        let live = first[j] <= last[j];
        // A run with no beams is crossed, harmlessly, with beams 0..8 at a distance of 0
        // (t = 0: no crossing).
        let (b0, b1) = if live {
            (first[j] as usize, last[j] as usize)
        } else {
            (0, 0)
        };
        let run = Run::new(line[j], los[j], his[j], g_line, g_along);
        let dl = _mm256_set1_pd(if live { run.dl } else { 0.0 });
        let (lo_out, hi_out) = (_mm256_set1_pd(run.lo_out), _mm256_set1_pd(run.hi_out));
        let (lo_in, hi_in) = (_mm256_set1_pd(run.lo_in), _mm256_set1_pd(run.hi_in));
        let from = b0 & !(LANES - 1);
        let to = (b1 + 1).next_multiple_of(LANES).max(from + 2 * LANES);
        assert!(to <= n, "beams {from}..{to} of {n}");
        let (g0, g1) = (b0 / GROUP, b1 / GROUP);
        if g1 < 128 {
            // In registers (a store per run would chain the runs on their stores).
            let bits = (u128::MAX >> (127 - g1)) & (u128::MAX << g0);
            marks |= if live { bits } else { 0 };
        } else if live {
            for gm in g0..=g1 {
                dirty[gm / 64] |= 1 << (gm % 64);
            }
        }
        let mut i = from;
        while i < to {
            // SAFETY: i + 4 <= to <= the length of every array.
            unsafe {
                let t = _mm256_mul_pd(dl, _mm256_loadu_pd(inv.as_ptr().add(i)));
                let y = _mm256_add_pd(g, _mm256_mul_pd(t, _mm256_loadu_pd(along.as_ptr().add(i))));
                let b = _mm256_loadu_pd(best.as_ptr().add(i));
                let hit = _mm256_and_pd(
                    _mm256_and_pd(
                        _mm256_cmp_pd::<_CMP_GT_OQ>(t, zero),
                        _mm256_cmp_pd::<_CMP_LT_OQ>(t, b),
                    ),
                    _mm256_and_pd(
                        _mm256_cmp_pd::<_CMP_GE_OQ>(y, lo_out),
                        _mm256_cmp_pd::<_CMP_LE_OQ>(y, hi_out),
                    ),
                );
                let near = _mm256_or_pd(
                    _mm256_cmp_pd::<_CMP_LT_OQ>(y, lo_in),
                    _mm256_cmp_pd::<_CMP_GT_OQ>(y, hi_in),
                );
                // min(b, hit ? t : inf) is hit ? t : b (a hit has t < b); as a blend the
                // compiler would make it a masked store, which is slow on AMD CPUs and
                // stalls the next run's loads.
                let tm = _mm256_blendv_pd(inf, t, hit);
                _mm256_storeu_pd(best.as_mut_ptr().add(i), _mm256_min_pd(b, tm));
                let set = _mm256_movemask_pd(_mm256_and_pd(hit, near));
                if set != 0 {
                    flagged = true;
                    for l in 0..LANES {
                        if set & (1 << l) != 0 {
                            flag[i + l] = 1.0;
                        }
                    }
                }
            }
            i += LANES;
        }
    }
    for (w, word) in dirty.iter_mut().take(2).enumerate() {
        *word |= (marks >> (64 * w)) as u64;
    }
    flagged
}
