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
    /// Run `j`'s beams as whole lanes `from..to`.
    #[cfg(test)]
    pub(super) fn lanes(&self, j: usize) -> (usize, usize) {
        (self.from[j] as usize, self.to[j] as usize)
    }

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

/// `Sweep::cross`'s beams of the first `m` runs `(line, lo, hi)`, four at a time, into
/// `runs` with the run's own values as [`super::Run::new`] computes them. Returns the least
/// first and the greatest last beam of the runs that have beams, if any. The beams are
/// found from the directions of each run's two ends, eight at once by [`atan2_ps`], and
/// the beam indices in single precision: a range only has to hold every beam that can
/// cross the run (the crossings decide, in double precision, with the march's
/// expressions), so a range wider by their error bounds gives the same crossings and the
/// same bits.
///
/// # Safety
/// The CPU must support AVX; the slices hold `m` rounded up to a multiple of four runs
/// (`runs` reserved for `m`).
#[target_feature(enable = "avx")]
#[allow(clippy::too_many_arguments)]
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
    // SAFETY: the CPU has AVX (this function's contract); every load and store is within
    // the first `len` values (checked above).
    unsafe {
        let set = _mm256_set1_pd;
        let sign = set(-0.0);
        // Beam index = direction / inc + fov / (2 inc), in single precision: its roundings
        // (each at most half an ulp of the largest index, `bound`) widen the slack.
        let inv_inc = _mm256_set1_ps(fan.inv_inc as f32);
        let start = _mm256_set1_ps((fan.half_fov * fan.inv_inc) as f32);
        let bound = (fan.half_fov + PI) * fan.inv_inc;
        let slack = (ANGLE_SLACK + ANGLE_ERR_PS) * fan.inv_inc + INDEX_ERR_PS * bound;
        let slack = _mm_set1_ps(slack as f32);
        let wrap = _mm_set1_ps((PI * fan.inv_inc) as f32);
        let last = _mm_set1_ps(top as f32);
        let cull = set(far);
        let (mut least, mut most) = (_mm_set1_epi32(i32::MAX), _mm_set1_epi32(-1));
        let lane = _mm_setr_epi32(0, 1, 2, 3);
        let (whole_lanes, two_lanes) = (_mm_set1_epi32(!3), _mm_set1_epi32(2 * LANES as i32));
        let mut j = 0;
        while j < m {
            let (line, lo, hi) = (
                _mm256_cvtps_pd(_mm_loadu_ps(line.as_ptr().add(j))),
                _mm256_cvtps_pd(_mm_loadu_ps(los.as_ptr().add(j))),
                _mm256_cvtps_pd(_mm_loadu_ps(his.as_ptr().add(j))),
            );
            let across = _mm256_sub_pd(line, set(g_line));
            let a0 = _mm256_sub_pd(lo, set(g_along));
            let a1 = _mm256_sub_pd(hi, set(g_along));
            // Both ends of four runs: the first ends in the low lanes, the last ends in
            // the high ones.
            let angles = if VERTICAL {
                angles_ps(fan, across, a0, across, a1)
            } else {
                angles_ps(fan, a0, across, a1, across)
            };
            let index = _mm256_add_ps(_mm256_mul_ps(angles, inv_inc), start);
            let (i0, i1) = (
                _mm256_castps256_ps128(index),
                _mm256_extractf128_ps::<1>(index),
            );
            let (a, b) = (_mm_min_ps(i0, i1), _mm_max_ps(i0, i1));
            // A run across the direction behind the car: every beam (rare, and safe).
            let whole = _mm_cmp_ps::<_CMP_GT_OQ>(_mm_sub_ps(b, a), wrap);
            let a = _mm_max_ps(_mm_ceil_ps(_mm_sub_ps(a, slack)), _mm_setzero_ps());
            let b = _mm_min_ps(_mm_floor_ps(_mm_add_ps(b, slack)), last);
            let a = _mm_cvttps_epi32(_mm_andnot_ps(whole, a));
            let b = _mm_cvttps_epi32(_mm_blendv_ps(b, last, whole));
            // Live: not farther than any beam's range, has beams, and one of the m runs
            // (the lanes past m pad).
            let dist = _mm256_sub_pd(
                _mm256_mul_pd(_mm256_andnot_pd(sign, across), set(1.0 - 1e-9)),
                set(EPS),
            );
            let within = _mm256_castpd_ps(_mm256_cmp_pd::<_CMP_LE_OQ>(dist, cull));
            // the four 64-bit masks as 32-bit ones (their low halves)
            let within = _mm_castps_si128(_mm_shuffle_ps::<0b10_00_10_00>(
                _mm256_castps256_ps128(within),
                _mm256_extractf128_ps::<1>(within),
            ));
            let real = _mm_cmplt_epi32(
                _mm_add_epi32(_mm_set1_epi32(j as i32), lane),
                _mm_set1_epi32(m as i32),
            );
            let live = _mm_andnot_si128(_mm_cmpgt_epi32(a, b), _mm_and_si128(within, real));
            least = _mm_min_epi32(least, _mm_blendv_epi8(_mm_set1_epi32(i32::MAX), a, live));
            most = _mm_max_epi32(most, _mm_blendv_epi8(_mm_set1_epi32(-1), b, live));
            // Whole lanes: from the lane of the first beam to past the lane of the last,
            // at least two lanes (so that no loop exit is mispredicted); beams 0..8 for a
            // run with no beams.
            let from = _mm_and_si128(a, whole_lanes);
            let to = _mm_and_si128(_mm_add_epi32(b, _mm_set1_epi32(LANES as i32)), whole_lanes);
            let to = _mm_max_epi32(to, _mm_add_epi32(from, two_lanes));
            _mm_storeu_si128(
                runs.from.as_mut_ptr().add(j).cast(),
                _mm_and_si128(from, live),
            );
            _mm_storeu_si128(
                runs.to.as_mut_ptr().add(j).cast(),
                _mm_blendv_epi8(two_lanes, to, live),
            );
            let live = _mm256_castsi256_pd(_mm256_set_m128i(
                _mm_unpackhi_epi32(live, live),
                _mm_unpacklo_epi32(live, live),
            ));
            let half = _mm256_mul_pd(_mm256_sub_pd(hi, lo), set(0.5));
            let mid = _mm256_mul_pd(_mm256_add_pd(lo, hi), set(0.5));
            for (v, x) in [
                (&mut runs.dl, _mm256_and_pd(across, live)),
                (&mut runs.off, _mm256_sub_pd(set(g_along), mid)),
                (&mut runs.half_out, _mm256_add_pd(half, set(EPS))),
                (&mut runs.half_in, _mm256_sub_pd(half, set(EPS))),
            ] {
                _mm256_storeu_pd(v.as_mut_ptr().add(j), x);
            }
            j += LANES;
        }
        // the least and the greatest of the four lanes: swap halves, then neighbours
        let least = _mm_min_epi32(least, _mm_shuffle_epi32::<0b01_00_11_10>(least));
        let least = _mm_min_epi32(least, _mm_shuffle_epi32::<0b10_11_00_01>(least));
        let most = _mm_max_epi32(most, _mm_shuffle_epi32::<0b01_00_11_10>(most));
        let most = _mm_max_epi32(most, _mm_shuffle_epi32::<0b10_11_00_01>(most));
        let (l, h) = (_mm_cvtsi128_si32(least), _mm_cvtsi128_si32(most));
        (l <= h).then_some((l as usize, h as usize))
    }
}

/// The per-beam arrays `super::beams::Beams::prepare` reads and fills, for [`prepare8`] (called
/// once per batch of the noise's draws, where slices' bounds checks each time cost more
/// than the work).
#[derive(Clone, Copy)]
pub(super) struct BeamPtrs {
    pub bc: *const f64,
    pub bs: *const f64,
    pub dx: *mut f64,
    pub dy: *mut f64,
    pub inv_dx: *mut f64,
    pub inv_dy: *mut f64,
    /// The first `best` of each beam: `limit[j] * inv_res + 1.0`, or `start` for every
    /// beam where `limit` is null.
    pub best: *mut f64,
    pub limit: *const f64,
    pub inv_res: f64,
    pub start: f64,
}

/// `super::beams::Beams::prepare` for beams `j..j + 8`: their directions in the grid frame (the
/// beams' `bc`, `bs` turned by the heading's `gc`, `gs`), the inverses of those and their
/// first ranges, four beams per instruction with the same operations lane by lane, so the
/// same bits (-0.0 made 0.0 as there). Each array's eight values are stored together, so
/// that its pointer is read once (in the noise's loop, where this is inlined, the pointers
/// live on the stack: there are more of them than free registers).
///
/// # Safety
/// The CPU must support AVX; every array of `beams` holds at least `j + 8` values.
#[target_feature(enable = "avx")]
#[inline]
pub(super) unsafe fn prepare8(gc: f64, gs: f64, beams: &BeamPtrs, j: usize) {
    let (gc, gs) = (_mm256_set1_pd(gc), _mm256_set1_pd(gs));
    let (zero, one) = (_mm256_setzero_pd(), _mm256_set1_pd(1.0));
    // +-0.0 -> 0.0
    let signless = |v| _mm256_andnot_pd(_mm256_cmp_pd::<_CMP_EQ_OQ>(v, zero), v);
    // SAFETY: the CPU has AVX, and the arrays hold beams j..j + 8 (this function's
    // contract).
    unsafe {
        let load = |p: *const f64| (_mm256_loadu_pd(p.add(j)), _mm256_loadu_pd(p.add(j + 4)));
        let store = |p: *mut f64, (a, b): (__m256d, __m256d)| {
            _mm256_storeu_pd(p.add(j), a);
            _mm256_storeu_pd(p.add(j + 4), b);
        };
        let (c, s) = (load(beams.bc), load(beams.bs));
        let turn = |c, s| {
            let x = _mm256_sub_pd(_mm256_mul_pd(gc, c), _mm256_mul_pd(gs, s));
            let y = _mm256_add_pd(_mm256_mul_pd(gs, c), _mm256_mul_pd(gc, s));
            (signless(x), signless(y))
        };
        let ((x0, y0), (x1, y1)) = (turn(c.0, s.0), turn(c.1, s.1));
        store(beams.dx, (x0, x1));
        store(beams.dy, (y0, y1));
        let inv = |v| _mm256_div_pd(one, v);
        store(beams.inv_dx, (inv(x0), inv(x1)));
        store(beams.inv_dy, (inv(y0), inv(y1)));
        let best = if beams.limit.is_null() {
            let start = _mm256_set1_pd(beams.start);
            (start, start)
        } else {
            let (l0, l1) = load(beams.limit);
            let inv_res = _mm256_set1_pd(beams.inv_res);
            let first = |l| _mm256_add_pd(_mm256_mul_pd(l, inv_res), one);
            (first(l0), first(l1))
        };
        store(beams.best, best);
    }
}

/// Relative: the roundings of a beam index in single precision (those of `1 / inc` and of
/// the start, of the product and the sum, of the slack's sum or difference: five half
/// ulps of the largest index at most) with room to spare, as a share of the largest index.
const INDEX_ERR_PS: f64 = 4.0 * f32::EPSILON as f64;

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
    let v = unsafe { angles_ps(fan, xs(a), ys(a), xs(b), ys(b)) };
    let (va, vb) = (
        _mm256_cvtps_pd(_mm256_castps256_ps128(v)),
        _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(v)),
    );
    let (mut out_a, mut out_b) = ([0.0; 4], [0.0; 4]);
    // SAFETY: four values each.
    unsafe {
        _mm256_storeu_pd(out_a.as_mut_ptr(), va);
        _mm256_storeu_pd(out_b.as_mut_ptr(), vb);
    }
    (out_a, out_b)
}

/// Radians: the error bound of [`atan2_ps`] (at most 2.7e-4: the reciprocal estimate's
/// 1.84e-4, the polynomial's own 8.14e-5 and the single-precision roundings; 2.17e-4
/// measured), with room to spare.
pub(super) const ANGLE_ERR_PS: f64 = 4e-4;

/// The directions relative to the heading of the vectors (x0, y0) and (x1, y1), four of
/// each (the first four lanes, then the others), within [`ANGLE_SLACK`] +
/// [`ANGLE_ERR_PS`] of the exact ones (where `Fan::angle` is within `ANGLE_SLACK`):
/// turned into the fan's frame in double precision, then eight directions at once by
/// [`atan2_ps`]. The vectors must not be (0, 0).
///
/// # Safety
/// The CPU must support AVX.
#[target_feature(enable = "avx")]
#[inline]
unsafe fn angles_ps(fan: &Fan, x0: __m256d, y0: __m256d, x1: __m256d, y1: __m256d) -> __m256 {
    let (c, s) = (_mm256_set1_pd(fan.cos), _mm256_set1_pd(fan.sin));
    let u = |x, y| _mm256_cvtpd_ps(_mm256_add_pd(_mm256_mul_pd(x, c), _mm256_mul_pd(y, s)));
    let v = |x, y| _mm256_cvtpd_ps(_mm256_sub_pd(_mm256_mul_pd(y, c), _mm256_mul_pd(x, s)));
    let u = _mm256_set_m128(u(x1, y1), u(x0, y0));
    let v = _mm256_set_m128(v(x1, y1), v(x0, y0));
    // SAFETY: the CPU has AVX (this function's contract).
    unsafe { atan2_ps(v, u) }
}

/// atan2(y, x) on eight single-precision lanes within 2.7e-4 radians, by a short chain of
/// dependent operations (the runs' beams wait on it): the quotient z of the smaller and
/// the larger of |x| and |y| by the larger's reciprocal estimate (whose relative error the
/// instruction set bounds by 1.5 * 2^-12 on every CPU; with the product's rounding 3.67e-4
/// of z, so at most 1.84e-4 radians in the angle, atan's slope times z being at most one
/// half), an odd polynomial of degree 7 for atan on [0, 1] (its minimax coefficients,
/// error 8.14e-5) by Estrin's scheme in the square, and the octant's offset and sign in
/// one sum. y = -0.0 gives +pi on the negative x axis (`atan2_fast` -pi: both bound the
/// same beams). The argument must not be (0, 0).
///
/// # Safety
/// The CPU must support AVX.
#[target_feature(enable = "avx")]
#[inline]
pub(super) unsafe fn atan2_ps(y: __m256, x: __m256) -> __m256 {
    // atan(z) ~ z (C0 + C1 w + C2 w^2 + C3 w^3), w = z^2, on [0, 1]: the
    // coefficients that minimise the largest error (a linear program over 4001 points),
    // rounded to single precision
    const C: [f32; 4] = [0.999_213_8, -0.321_174_9, 0.146_264_17, -0.038_986_307];
    let set = _mm256_set1_ps;
    let sign = set(-0.0);
    let (ax, ay) = (_mm256_andnot_ps(sign, x), _mm256_andnot_ps(sign, y));
    let z = _mm256_mul_ps(_mm256_min_ps(ax, ay), _mm256_rcp_ps(_mm256_max_ps(ax, ay)));
    let w = _mm256_mul_ps(z, z);
    let w2 = _mm256_mul_ps(w, w);
    let low = _mm256_add_ps(_mm256_mul_ps(w, set(C[1])), set(C[0]));
    let high = _mm256_add_ps(_mm256_mul_ps(w, set(C[3])), set(C[2]));
    let p = _mm256_add_ps(_mm256_mul_ps(w2, high), low);
    let r = _mm256_mul_ps(z, p);
    // atan2 = k + r or k - r: past the diagonal pi/2 - r, on the left pi less that,
    // below the axis its negative.
    let swap = _mm256_cmp_ps::<_CMP_GT_OQ>(ay, ax);
    let left = _mm256_cmp_ps::<_CMP_LT_OQ>(x, set(0.0));
    let below = _mm256_cmp_ps::<_CMP_LT_OQ>(y, set(0.0));
    let k = _mm256_and_ps(swap, set(std::f32::consts::FRAC_PI_2));
    let k = _mm256_blendv_ps(k, _mm256_sub_ps(set(std::f32::consts::PI), k), left);
    let k = _mm256_xor_ps(k, _mm256_and_ps(below, sign));
    let flip = _mm256_and_ps(_mm256_xor_ps(_mm256_xor_ps(swap, left), below), sign);
    _mm256_add_ps(k, _mm256_xor_ps(r, flip))
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
    // (Macros: a closure here is compiled as a function of its own, without inlining.)
    // One lane of four beams from beam i, against the run whose values are broadcast in
    // `dl`, `off`, `half_out` and `half_in`.
    macro_rules! lane {
        ($i:expr, $dl:expr, $off:expr, $half_out:expr, $half_in:expr) => {{
            let i: usize = $i;
            // SAFETY: i + 4 <= end <= the length of every array (checked by `one!`).
            unsafe {
                let t = _mm256_mul_pd($dl, _mm256_loadu_pd(inv.as_ptr().add(i)));
                // The crossing's place along the line from the run's middle.
                let rel = _mm256_add_pd(
                    _mm256_mul_pd(t, _mm256_loadu_pd(along.as_ptr().add(i))),
                    $off,
                );
                let b = _mm256_loadu_pd(best.as_ptr().add(i));
                // On the run and ahead; a hit is such a crossing nearer than `b`, but the
                // minimum below needs no test of that, and the flags test it only in
                // their rare branch.
                let d = _mm256_andnot_pd(sign, rel);
                let on = _mm256_and_pd(
                    _mm256_cmp_pd::<_CMP_GT_OQ>(t, zero),
                    _mm256_cmp_pd::<_CMP_LE_OQ>(d, $half_out),
                );
                let near = _mm256_cmp_pd::<_CMP_GT_OQ>(d, $half_in);
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
        }};
    }
    // Run j with its lanes: two at least (see `beams_of_runs`), those two without a
    // loop's branches, the rest, if any, in a loop (about 1 % fewer instructions a scan,
    // a twentieth of the crossings' branches).
    macro_rules! one {
        ($j:expr) => {{
            let j: usize = $j;
            let (start, end) = (from[j] as usize, to[j] as usize);
            assert!(
                start + 2 * LANES <= end && end <= n,
                "beams {start}..{end} of {n}: two lanes at least, within the beams"
            );
            let dl = _mm256_set1_pd(dl[j]);
            let off = _mm256_set1_pd(off[j]);
            let (half_out, half_in) = (_mm256_set1_pd(half_out[j]), _mm256_set1_pd(half_in[j]));
            lane!(start, dl, off, half_out, half_in);
            lane!(start + LANES, dl, off, half_out, half_in);
            let mut i = start + 2 * LANES;
            while i < end {
                lane!(i, dl, off, half_out, half_in);
                i += LANES;
            }
        }};
    }
    // Runs from the two halves in turn: neighbouring runs (along a line) share beams, and
    // updating the same beams in a row would wait on each other's stores. (Two calls a
    // turn rather than one index chosen per run: its arithmetic cost more than the call's
    // second copy.)
    let half = m.div_ceil(2);
    for j in 0..m - half {
        one!(j);
        one!(half + j);
    }
    if m % 2 == 1 {
        one!(half - 1);
    }
    flagged
}
