//! The AVX-512 march: eight rays per instruction, two packets stepped together.

use super::{Batch, CHUNK, PACKET};
use crate::map::Map;

impl Batch {
    /// [`Batch::march_avx`] eight rays at a time with AVX-512: the same operations lane by
    /// lane (IEEE add, sub, mul, compare, exact floor, min, max; no FMA; selections by
    /// mask instead of blend), so the results are bit-identical to the portable version.
    /// A packet stays live until all eight of its rays have stopped; two packets are
    /// stepped side by side.
    ///
    /// # Safety
    /// The CPU must support AVX-512F and AVX2.
    #[target_feature(enable = "avx512f,avx2")]
    pub(super) unsafe fn march_avx512(&mut self, map: &Map, gx: f64, gy: f64, n: usize) {
        use std::arch::x86_64::*;
        const LANES: usize = 2 * PACKET;
        debug_assert!(n.is_multiple_of(LANES) && n <= CHUNK);
        let quadrants = map.quadrant_clearance();
        let wp = map.width() as f64 + 2.0;
        let v_wp = _mm512_set1_pd(wp);
        let v_gx = _mm512_set1_pd(gx);
        let v_gy = _mm512_set1_pd(gy);
        let one = _mm512_set1_pd(1.0);
        let zero = _mm512_setzero_pd();
        let four = _mm512_set1_pd(4.0);
        // `avx512_usable` checked that the table is not empty and its length fits an i32.
        let last = _mm256_set1_epi32(quadrants.len() as i32 - 1);
        macro_rules! ld {
            ($a:expr, $o:expr) => {
                // SAFETY: $o + 8 <= n <= CHUNK, the array's length.
                unsafe { _mm512_loadu_pd($a[$o..$o + LANES].as_ptr()) }
            };
        }
        macro_rules! st {
            ($a:expr, $o:expr, $v:expr) => {
                // SAFETY: as for `ld`.
                unsafe { _mm512_storeu_pd($a[$o..$o + LANES].as_mut_ptr(), $v) }
            };
        }
        // The clearance of the eight cells (c, r), each in its ray's quadrant; rays only
        // ever sit on cells of the padded grid, so the indices are in range.
        let clearance = |c: __m512d, r: __m512d, base: __m512d| -> __m512d {
            let cell = _mm512_add_pd(_mm512_mul_pd(r, v_wp), c);
            let idx = _mm512_add_pd(_mm512_mul_pd(cell, four), base);
            // Clamped to the table (as unsigned: a negative index clamps too), so that a
            // broken invariant would give a wrong clearance, never a read outside it.
            let ii = _mm256_min_epu32(_mm512_cvttpd_epi32(idx), last);
            // Eight scalar loads: on AMD Zen cheaper than a gather (which made scans about
            // 10 % faster on an Intel Xeon, about 5 % slower on an AMD EPYC).
            let mut lanes = [0u32; LANES];
            // SAFETY: `lanes` holds eight u32, 32 bytes.
            unsafe { _mm256_storeu_si256(lanes.as_mut_ptr().cast(), ii) };
            // SAFETY: every index is at most `last`, in the table.
            let q = |i: u32| i32::from(unsafe { *quadrants.get_unchecked(i as usize) });
            _mm512_cvtepi32_pd(_mm256_setr_epi32(
                q(lanes[0]),
                q(lanes[1]),
                q(lanes[2]),
                q(lanes[3]),
                q(lanes[4]),
                q(lanes[5]),
                q(lanes[6]),
                q(lanes[7]),
            ))
        };
        let stopped = |v: __m512d, t: __m512d, tmax: __m512d| -> __mmask8 {
            _mm512_cmp_pd_mask::<_CMP_EQ_OQ>(v, zero) | _mm512_cmp_pd_mask::<_CMP_GT_OQ>(t, tmax)
        };
        // The live packets as a bit set: which packets a pass visits comes from its
        // copy, so no load or store address waits for a clearance (as an index into a
        // compacted list of live packets would).
        const _: () = assert!(CHUNK / LANES <= 64);
        let mut live = 0u64;
        for p in 0..n / LANES {
            let o = p * LANES;
            let v = clearance(ld!(self.c, o), ld!(self.r, o), ld!(self.base, o));
            st!(self.v, o, v);
            let stop = stopped(v, ld!(self.t, o), ld!(self.tmax, o));
            live |= u64::from(stop != 0xff) << p;
        }
        // Two packets per iteration, their operations interleaved one by one: a step is a
        // long chain of dependent operations (exit of the free square, next cell, its
        // clearance), and two chains side by side keep the CPU busier than one after the
        // other (about 10 % per scan). With one packet left, the second slot repeats it:
        // the same step from the same state, stored twice.
        macro_rules! both {
            ($u:ident => $e:expr) => {
                [
                    {
                        let $u = 0;
                        $e
                    },
                    {
                        let $u = 1;
                        $e
                    },
                ]
            };
        }
        while live != 0 {
            let mut pass = live;
            while pass != 0 {
                let p0 = pass.trailing_zeros() as usize;
                pass &= pass - 1;
                let p1 = if pass == 0 {
                    p0
                } else {
                    pass.trailing_zeros() as usize
                };
                pass &= pass.wrapping_sub(1);
                let os = [p0 * LANES, p1 * LANES];
                let c = both!(u => ld!(self.c, os[u]));
                let r = both!(u => ld!(self.r, os[u]));
                let t = both!(u => ld!(self.t, os[u]));
                let v = both!(u => ld!(self.v, os[u]));
                let tmax = both!(u => ld!(self.tmax, os[u]));
                let stop = both!(u => stopped(v[u], t[u], tmax[u]));
                let k = both!(u => _mm512_sub_pd(v[u], one));
                let sx = both!(u => ld!(self.sx, os[u]));
                let sy = both!(u => ld!(self.sy, os[u]));
                let px = both!(u => ld!(self.px, os[u]));
                let py = both!(u => ld!(self.py, os[u]));
                let kx = both!(u => _mm512_mul_pd(k[u], sx[u]));
                let ky = both!(u => _mm512_mul_pd(k[u], sy[u]));
                let bx = both!(u => _mm512_add_pd(_mm512_add_pd(c[u], kx[u]), px[u]));
                let by = both!(u => _mm512_add_pd(_mm512_add_pd(r[u], ky[u]), py[u]));
                let inv_dx = both!(u => ld!(self.inv_dx, os[u]));
                let inv_dy = both!(u => ld!(self.inv_dy, os[u]));
                let tx = both!(u => _mm512_mul_pd(_mm512_sub_pd(bx[u], v_gx), inv_dx[u]));
                let ty = both!(u => _mm512_mul_pd(_mm512_sub_pd(by[u], v_gy), inv_dy[u]));
                // `_mm512_mask_blend_pd(m, a, b)` takes b where m is set.
                let exit_x = both!(u => _mm512_cmp_pd_mask::<_CMP_LT_OQ>(tx[u], ty[u]));
                let tn = both!(u => _mm512_mask_blend_pd(exit_x[u], ty[u], tx[u]));
                let o_g = both!(u => _mm512_mask_blend_pd(exit_x[u], v_gx, v_gy));
                let dx = both!(u => ld!(self.dx, os[u]));
                let dy = both!(u => ld!(self.dy, os[u]));
                let o_d = both!(u => _mm512_mask_blend_pd(exit_x[u], dx[u], dy[u]));
                let o_c = both!(u => _mm512_mask_blend_pd(exit_x[u], c[u], r[u]));
                let o_p = both!(u => _mm512_mask_blend_pd(exit_x[u], px[u], py[u]));
                let at = both!(u => _mm512_add_pd(o_g[u], _mm512_mul_pd(tn[u], o_d[u])));
                let fl = both!(u => _mm512_roundscale_pd::<
                    { _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC },
                >(at[u]));
                let hi = both!(u => _mm512_add_pd(o_c[u], _mm512_mul_pd(k[u], o_p[u])));
                let lo = both!(u => _mm512_sub_pd(hi[u], k[u]));
                // max(a, b) = a > b ? a : b and min(a, b) = a < b ? a : b, as in the
                // other versions (the operands are never NaN here).
                let other = both!(u => _mm512_min_pd(_mm512_max_pd(fl[u], lo[u]), hi[u]));
                let k1 = both!(u => _mm512_add_pd(k[u], one));
                let jx = both!(u => _mm512_add_pd(c[u], _mm512_mul_pd(k1[u], sx[u])));
                let jy = both!(u => _mm512_add_pd(r[u], _mm512_mul_pd(k1[u], sy[u])));
                let nc = both!(u => _mm512_mask_blend_pd(exit_x[u], other[u], jx[u]));
                let nr = both!(u => _mm512_mask_blend_pd(exit_x[u], jy[u], other[u]));
                // Stopped lanes keep their state (and so a valid cell).
                let c = both!(u => _mm512_mask_blend_pd(stop[u], nc[u], c[u]));
                let r = both!(u => _mm512_mask_blend_pd(stop[u], nr[u], r[u]));
                let t = both!(u => _mm512_mask_blend_pd(stop[u], tn[u], t[u]));
                let v = both!(u => clearance(c[u], r[u], ld!(self.base, os[u])));
                for u in 0..2 {
                    st!(self.c, os[u], c[u]);
                    st!(self.r, os[u], r[u]);
                    st!(self.t, os[u], t[u]);
                    st!(self.v, os[u], v[u]);
                    let dead = stopped(v[u], t[u], tmax[u]) == 0xff;
                    live &= !(u64::from(dead) << (os[u] / LANES));
                }
            }
        }
    }
}
