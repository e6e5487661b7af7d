//! The sweep's AVX kernels: the runs' beam ranges, four runs at a time, and their
//! crossings, four beams at a time (the same arithmetic lane by lane as the portable
//! code in `super`, so the same bits), and the culling's maxima. The directions that
//! bound the runs' and the blocks' beam ranges are taken in single precision and the
//! ranges widened by its error bound: a range only has to hold every beam that can cross
//! the run or see the block, and a beam that cannot changes nothing, so the bits stay the
//! same.

use std::arch::x86_64::*;
use std::f64::consts::PI;

use super::{ANGLE_SLACK, EPS, Fan, LANES};

/// What [`cross_runs`] needs of each run of a block side, computed four runs at a time by
/// [`beams_of_runs`]: its beams as whole lanes `from..to` (at least two lanes) and the
/// run as [`super::Run`] holds it (`dl` is 0 for a run with no beams: its lanes then cross
/// nothing).
#[derive(Default)]
pub(super) struct Runs {
    from: Vec<i32>,
    to: Vec<i32>,
    dl: Vec<f64>,
    off: Vec<f64>,
    half_out: Vec<f64>,
    half_in: Vec<f64>,
}

impl Runs {
    /// Room for `m` runs and the three that pad the last four (grown only: a call to
    /// resize per block side cost more than the work on blocks with few runs).
    #[inline(always)]
    pub(super) fn reserve(&mut self, m: usize) {
        let len = m + LANES - 1;
        if self.from.len() < len {
            self.from.resize(len, 0);
            self.to.resize(len, 0);
            for v in [
                &mut self.dl,
                &mut self.off,
                &mut self.half_out,
                &mut self.half_in,
            ] {
                v.resize(len, 0.0);
            }
        }
    }
}

/// `Sweep::cross`'s beams of the first `m` runs `(line, lo, hi)`, four at a time (each
/// run's two ends' directions by `atan2_fast`'s operations), into `runs` with the
/// run's own values as [`super::Run::new`] computes them. Returns the least first and the
/// greatest last beam of the runs that have beams, if any.
///
/// # Safety
/// The CPU must support AVX; the slices hold `m` rounded up to a multiple of four runs
/// (`runs` reserved for `m`).
#[target_feature(enable = "avx")]
#[allow(clippy::too_many_arguments)]
#[inline]
pub(super) unsafe fn beams_of_runs<const VERTICAL: bool>(
    line: &[f32],
    los: &[f32],
    his: &[f32],
    m: usize,
    g_line: f64,
    g_along: f64,
    fan: &Fan,
    far: f64,
    top: f64,
    runs: &mut Runs,
) -> Option<(usize, usize)> {
    let len = line
        .len()
        .min(los.len())
        .min(his.len())
        .min(runs.from.len())
        .min(runs.half_in.len());
    assert!(m.next_multiple_of(LANES) <= len, "{m} runs of {len}");
    let set = _mm256_set1_pd;
    let sign = set(-0.0);
    // Both ends of four runs, eight directions, at once in single precision: a beam
    // range only has to hold the beams that can cross the run (the crossings decide, in
    // double precision, with the march's expressions), so a range wider by the eight-lane
    // atan2's error bound gives the same crossings and the same bits.
    let indices = |x0: __m256d, y0: __m256d, x1: __m256d, y1: __m256d| {
        // SAFETY: the CPU has AVX (this function's contract).
        let (a0, a1) = unsafe { angles_ps(fan, x0, y0, x1, y1) };
        let index =
            |a: __m256d| _mm256_mul_pd(_mm256_add_pd(a, set(fan.half_fov)), set(fan.inv_inc));
        (index(a0), index(a1))
    };
    let slack = set((ANGLE_SLACK + ANGLE_ERR_PS) * fan.inv_inc);
    let wrap = set(PI * fan.inv_inc);
    let cull = set(far);
    let lanes = set(LANES as f64);
    let quarter = set(1.0 / LANES as f64);
    let (mut least, mut most) = (set(f64::INFINITY), set(-1.0));
    let mut j = 0;
    while j < m {
        // SAFETY: j + 4 <= len, within every array.
        let load = |a: &[f32]| unsafe { _mm256_cvtps_pd(_mm_loadu_ps(a.as_ptr().add(j))) };
        let (line, lo, hi) = (load(line), load(los), load(his));
        let across = _mm256_sub_pd(line, set(g_line));
        let a0 = _mm256_sub_pd(lo, set(g_along));
        let a1 = _mm256_sub_pd(hi, set(g_along));
        let (i0, i1) = if VERTICAL {
            indices(across, a0, across, a1)
        } else {
            indices(a0, across, a1, across)
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
        // Live: not farther than any beam's range, has beams, and one of the m runs
        // (the lanes past m pad).
        let index = _mm256_add_pd(set(j as f64), _mm256_set_pd(3.0, 2.0, 1.0, 0.0));
        let live = _mm256_and_pd(
            _mm256_and_pd(
                _mm256_cmp_pd::<_CMP_LE_OQ>(dist, cull),
                _mm256_cmp_pd::<_CMP_LE_OQ>(a, b),
            ),
            _mm256_cmp_pd::<_CMP_LT_OQ>(index, set(m as f64)),
        );
        least = _mm256_min_pd(least, _mm256_blendv_pd(set(f64::INFINITY), a, live));
        most = _mm256_max_pd(most, _mm256_blendv_pd(set(-1.0), b, live));
        // Whole lanes: from the lane of the first beam to past the lane of the last, at
        // least two lanes (so that no loop exit is mispredicted); beams 0..8 for a run
        // with no beams.
        let from = _mm256_mul_pd(_mm256_floor_pd(_mm256_mul_pd(a, quarter)), lanes);
        let to = _mm256_mul_pd(
            _mm256_ceil_pd(_mm256_mul_pd(_mm256_add_pd(b, set(1.0)), quarter)),
            lanes,
        );
        let to = _mm256_max_pd(to, _mm256_add_pd(from, set(2.0 * LANES as f64)));
        let from = _mm256_and_pd(from, live);
        let to = _mm256_blendv_pd(set(2.0 * LANES as f64), to, live);
        // SAFETY: as above.
        unsafe {
            let at = |v: &mut Vec<f64>| v.as_mut_ptr().add(j);
            _mm_storeu_si128(
                runs.from.as_mut_ptr().add(j).cast(),
                _mm256_cvttpd_epi32(from),
            );
            _mm_storeu_si128(runs.to.as_mut_ptr().add(j).cast(), _mm256_cvttpd_epi32(to));
            _mm256_storeu_pd(at(&mut runs.dl), _mm256_and_pd(across, live));
            let half = _mm256_mul_pd(_mm256_sub_pd(hi, lo), set(0.5));
            let mid = _mm256_mul_pd(_mm256_add_pd(lo, hi), set(0.5));
            _mm256_storeu_pd(at(&mut runs.off), _mm256_sub_pd(set(g_along), mid));
            _mm256_storeu_pd(at(&mut runs.half_out), _mm256_add_pd(half, set(EPS)));
            _mm256_storeu_pd(at(&mut runs.half_in), _mm256_sub_pd(half, set(EPS)));
        }
        j += LANES;
    }
    let (mut l, mut h) = ([0.0; 4], [0.0; 4]);
    // SAFETY: four values each.
    unsafe {
        _mm256_storeu_pd(l.as_mut_ptr(), least);
        _mm256_storeu_pd(h.as_mut_ptr(), most);
    }
    let (l, h) = (
        l[0].min(l[1]).min(l[2].min(l[3])),
        h[0].max(h[1]).max(h[2].max(h[3])),
    );
    (l <= h).then_some((l as usize, h as usize))
}

/// The largest of `start` and `v` (none of them NaN): `super::max_of`, four lanes per
/// instruction in two chains.
///
/// # Safety
/// The CPU must support AVX.
#[target_feature(enable = "avx")]
#[inline]
pub(super) unsafe fn max_of(start: f64, v: &[f64]) -> f64 {
    let (mut a, mut b) = (_mm256_set1_pd(start), _mm256_set1_pd(start));
    let mut eights = v.chunks_exact(8);
    for q in &mut eights {
        // SAFETY: eight values.
        unsafe {
            a = _mm256_max_pd(a, _mm256_loadu_pd(q.as_ptr()));
            b = _mm256_max_pd(b, _mm256_loadu_pd(q.as_ptr().add(4)));
        }
    }
    let mut rest = eights.remainder().chunks_exact(4);
    for q in &mut rest {
        // SAFETY: four values.
        a = _mm256_max_pd(a, unsafe { _mm256_loadu_pd(q.as_ptr()) });
    }
    let max = |a: f64, b: f64| if b > a { b } else { a };
    rest.remainder()
        .iter()
        .fold(lanes_max(_mm256_max_pd(a, b)), |a, &b| max(a, b))
}

/// The largest of 16 values (none of them NaN) and 0: `super::max_of(0.0, v)` as a
/// tree of four-lane maxima.
///
/// # Safety
/// The CPU must support AVX.
#[target_feature(enable = "avx")]
#[inline]
pub(super) unsafe fn max16(v: &[f64; 16]) -> f64 {
    let p = v.as_ptr();
    // SAFETY: sixteen values.
    let m = unsafe {
        _mm256_max_pd(
            _mm256_max_pd(_mm256_loadu_pd(p), _mm256_loadu_pd(p.add(4))),
            _mm256_max_pd(_mm256_loadu_pd(p.add(8)), _mm256_loadu_pd(p.add(12))),
        )
    };
    lanes_max(_mm256_max_pd(m, _mm256_setzero_pd()))
}

/// The largest of the four lanes of `m` (none of them NaN).
#[target_feature(enable = "avx")]
#[inline]
fn lanes_max(m: __m256d) -> f64 {
    let h = _mm_max_pd(_mm256_castpd256_pd128(m), _mm256_extractf128_pd::<1>(m));
    _mm_cvtsd_f64(_mm_max_sd(h, _mm_unpackhi_pd(h, h)))
}

/// `super::box_angles` with AVX: the directions relative to the heading of the corners
/// of the boxes `a` and `b` (each `[x0, y0, x1, y1]`) as seen from (gx, gy), eight at once
/// by [`angles_ps`] (so within [`ANGLE_SLACK`] + [`ANGLE_ERR_PS`]).
///
/// # Safety
/// The CPU must support AVX.
#[target_feature(enable = "avx")]
#[inline]
pub(super) unsafe fn box_angles(
    fan: &Fan,
    gx: f64,
    gy: f64,
    a: [f64; 4],
    b: [f64; 4],
) -> ([f64; 4], [f64; 4]) {
    let set = _mm256_set_pd;
    let (g, h) = (_mm256_set1_pd(gx), _mm256_set1_pd(gy));
    let xs = |[x0, _, x1, _]: [f64; 4]| _mm256_sub_pd(set(x1, x0, x1, x0), g);
    let ys = |[_, y0, _, y1]: [f64; 4]| _mm256_sub_pd(set(y1, y1, y0, y0), h);
    // SAFETY: the CPU has AVX (this function's contract).
    let (va, vb) = unsafe { angles_ps(fan, xs(a), ys(a), xs(b), ys(b)) };
    let (mut out_a, mut out_b) = ([0.0; 4], [0.0; 4]);
    // SAFETY: four values each.
    unsafe {
        _mm256_storeu_pd(out_a.as_mut_ptr(), va);
        _mm256_storeu_pd(out_b.as_mut_ptr(), vb);
    }
    (out_a, out_b)
}

/// Radians: the error bound of [`angles_ps`] (at most 4.2e-5: the series' own 4.0e-5
/// and the single-precision roundings; 3.5e-5 measured), with room to spare.
pub(super) const ANGLE_ERR_PS: f64 = 5e-5;

/// The directions relative to the heading of the vectors (x0, y0) and (x1, y1), four of
/// each, within [`ANGLE_SLACK`] + [`ANGLE_ERR_PS`] of the exact ones (where
/// `Fan::angle` is within `ANGLE_SLACK`): turned into the fan's frame in double precision,
/// then eight directions at once by [`atan2_ps`]. The vectors must not be (0, 0).
///
/// # Safety
/// The CPU must support AVX.
#[target_feature(enable = "avx")]
#[inline]
unsafe fn angles_ps(
    fan: &Fan,
    x0: __m256d,
    y0: __m256d,
    x1: __m256d,
    y1: __m256d,
) -> (__m256d, __m256d) {
    let (c, s) = (_mm256_set1_pd(fan.cos), _mm256_set1_pd(fan.sin));
    let u = |x, y| _mm256_cvtpd_ps(_mm256_add_pd(_mm256_mul_pd(x, c), _mm256_mul_pd(y, s)));
    let v = |x, y| _mm256_cvtpd_ps(_mm256_sub_pd(_mm256_mul_pd(y, c), _mm256_mul_pd(x, s)));
    let u = _mm256_set_m128(u(x1, y1), u(x0, y0));
    let v = _mm256_set_m128(v(x1, y1), v(x0, y0));
    // SAFETY: the CPU has AVX (this function's contract).
    let a = unsafe { atan2_ps(v, u) };
    (
        _mm256_cvtps_pd(_mm256_castps256_ps128(a)),
        _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(a)),
    )
}

/// atan2(y, x) on eight single-precision lanes within 4.2e-5 radians: `atan2_fast`'s
/// octant reduction, a reciprocal refined by one Newton step instead of the division,
/// and the series to z^7 (its error at |z| <= tan(pi/8) is under 4.0e-5). y = -0.0
/// gives +pi on the negative x axis (`atan2_fast` -pi: both bound the same beams). The
/// argument must not be (0, 0).
///
/// # Safety
/// The CPU must support AVX.
#[target_feature(enable = "avx")]
#[inline]
pub(super) unsafe fn atan2_ps(y: __m256, x: __m256) -> __m256 {
    let set = _mm256_set1_ps;
    let sign = set(-0.0);
    let (ax, ay) = (_mm256_andnot_ps(sign, x), _mm256_andnot_ps(sign, y));
    let swap = _mm256_cmp_ps::<_CMP_GT_OQ>(ay, ax);
    let num = _mm256_blendv_ps(ay, ax, swap);
    let den = _mm256_blendv_ps(ax, ay, swap);
    let red = _mm256_cmp_ps::<_CMP_GT_OQ>(num, _mm256_mul_ps(set(0.414_213_56), den));
    let top = _mm256_blendv_ps(num, _mm256_sub_ps(num, den), red);
    let bottom = _mm256_blendv_ps(den, _mm256_add_ps(num, den), red);
    let r = _mm256_rcp_ps(bottom);
    let r = _mm256_mul_ps(r, _mm256_sub_ps(set(2.0), _mm256_mul_ps(bottom, r)));
    let z = _mm256_mul_ps(top, r);
    let z2 = _mm256_mul_ps(z, z);
    let mut p = set(-1.0 / 7.0);
    for k in [1.0 / 5.0, -1.0 / 3.0, 1.0] {
        p = _mm256_add_ps(set(k), _mm256_mul_ps(z2, p));
    }
    let a = _mm256_add_ps(
        _mm256_and_ps(red, set(std::f32::consts::FRAC_PI_4)),
        _mm256_mul_ps(z, p),
    );
    let a = _mm256_blendv_ps(a, _mm256_sub_ps(set(std::f32::consts::FRAC_PI_2), a), swap);
    let a = _mm256_blendv_ps(
        a,
        _mm256_sub_ps(set(std::f32::consts::PI), a),
        _mm256_cmp_ps::<_CMP_LT_OQ>(x, set(0.0)),
    );
    _mm256_blendv_ps(
        a,
        _mm256_sub_ps(set(0.0), a),
        _mm256_cmp_ps::<_CMP_LT_OQ>(y, set(0.0)),
    )
}

/// `Sweep::cross`'s crossings with AVX: each of the first `m` runs of `runs` (see
/// [`beams_of_runs`]) with its lanes of beams, four beams per instruction with the same
/// arithmetic lane by lane as [`super::Run::cross`], so the same ranges and flags (its
/// hit test, less the comparison with the current range, which the minimum does not
/// need: asked only where a flag may be set). Returns whether any beam was flagged (rare:
/// set lane by lane behind a branch, not by a load and a store per lane).
///
/// # Safety
/// The CPU must support AVX.
#[target_feature(enable = "avx")]
#[inline]
pub(super) unsafe fn cross_runs(
    runs: &Runs,
    m: usize,
    inv: &[f64],
    along: &[f64],
    best: &mut [f64],
    flag: &mut [f64],
) -> bool {
    let n = inv.len().min(along.len()).min(best.len()).min(flag.len());
    let (from, to) = (&runs.from[..m], &runs.to[..m]);
    let (dl, off) = (&runs.dl[..m], &runs.off[..m]);
    let (half_out, half_in) = (&runs.half_out[..m], &runs.half_in[..m]);
    let sign = _mm256_set1_pd(-0.0);
    let zero = _mm256_setzero_pd();
    let mut flagged = false;
    let inf = _mm256_set1_pd(f64::INFINITY);
    let half = m.div_ceil(2);
    for k in 0..m {
        // Runs from the two halves in turn: neighbouring runs (along a line) share beams,
        // and updating the same beams in a row would wait on each other's stores.
        let j = if k % 2 == 0 { k / 2 } else { half + k / 2 };
        let (start, end) = (from[j] as usize, to[j] as usize);
        assert!(end <= n, "beams {start}..{end} of {n}");
        let dl = _mm256_set1_pd(dl[j]);
        let off = _mm256_set1_pd(off[j]);
        let (half_out, half_in) = (_mm256_set1_pd(half_out[j]), _mm256_set1_pd(half_in[j]));
        let mut i = start;
        while i < end {
            // SAFETY: i + 4 <= end <= the length of every array.
            unsafe {
                let t = _mm256_mul_pd(dl, _mm256_loadu_pd(inv.as_ptr().add(i)));
                // The crossing's place along the line from the run's middle.
                let rel = _mm256_add_pd(
                    _mm256_mul_pd(t, _mm256_loadu_pd(along.as_ptr().add(i))),
                    off,
                );
                let b = _mm256_loadu_pd(best.as_ptr().add(i));
                // On the run and ahead; a hit is such a crossing nearer than `b`, but the
                // minimum below needs no test of that, and the flags test it only in
                // their rare branch.
                let d = _mm256_andnot_pd(sign, rel);
                let on = _mm256_and_pd(
                    _mm256_cmp_pd::<_CMP_GT_OQ>(t, zero),
                    _mm256_cmp_pd::<_CMP_LE_OQ>(d, half_out),
                );
                let near = _mm256_cmp_pd::<_CMP_GT_OQ>(d, half_in);
                // min(b, on ? t : inf) is b, or t where t < b (a hit); as a blend the
                // compiler would make it a masked store, which is slow on AMD CPUs and
                // stalls the next run's loads.
                let tm = _mm256_blendv_pd(inf, t, on);
                _mm256_storeu_pd(best.as_mut_ptr().add(i), _mm256_min_pd(b, tm));
                let set = _mm256_movemask_pd(_mm256_and_pd(on, near));
                if set != 0 {
                    // A hit near an end of the run: flagged.
                    let set = set & _mm256_movemask_pd(_mm256_cmp_pd::<_CMP_LT_OQ>(t, b));
                    flagged |= set != 0;
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
    flagged
}
