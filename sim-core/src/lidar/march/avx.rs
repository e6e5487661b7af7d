//! The AVX march: four rays per instruction (the widest path of CPUs without AVX-512).
//!
//! Stepping two packets side by side with a bit set of live packets, as the AVX-512 march
//! does, was tried for this path too and was not measurably faster on a loaded 2-core
//! AMD EPYC VM (see `docs/performance-scan.md`), so this keeps one packet per step and a
//! compacted list of live packets.
//!
//! On Intel CPUs with AVX2 the four clearances of a step come from one gather of the four
//! cells' 32-bit table words (each holds the cell's four quadrant bytes) instead of four
//! lane extractions and four scalar loads: about 10 % faster scans on an Intel Xeon VM
//! (`docs/performance-scan.md`). AMD CPUs keep the scalar loads, as the AVX-512 march
//! does, since its eight-lane gather made scans slower on an AMD EPYC; the four-lane
//! gather was not measured there. Both read the same bytes: the results are the same.

use super::{Batch, CHUNK, PACKET};
use crate::map::Map;

/// The AVX march as the method `$name` compiled with the CPU features `$features`;
/// `$gather`: whether a step's four clearances come from one AVX2 gather (else from four
/// lane extractions and scalar loads).
macro_rules! march_avx_fn {
    ($(#[$doc:meta])* $name:ident, $features:literal, $gather:literal) => {
    $(#[$doc])*
    #[target_feature(enable = $features)]
    pub(super) unsafe fn $name(&mut self, map: &Map, gx: f64, gy: f64, n: usize) {
        use std::arch::x86_64::*;
        debug_assert!(n & (PACKET - 1) == 0 && n <= CHUNK);
        let quadrants = map.quadrant_clearance();
        let wp = map.width() as f64 + 2.0;
        let v_wp = _mm256_set1_pd(wp);
        let v_gx = _mm256_set1_pd(gx);
        let v_gy = _mm256_set1_pd(gy);
        let one = _mm256_set1_pd(1.0);
        let zero = _mm256_setzero_pd();
        macro_rules! ld {
            ($a:expr, $o:expr) => {
                // SAFETY: $o + 4 <= n <= CHUNK, the array's length.
                unsafe { _mm256_loadu_pd($a[$o..$o + PACKET].as_ptr()) }
            };
        }
        // The bit offsets of the four rays' quadrant bytes in their cells' words.
        macro_rules! ldq {
            ($o:expr) => {
                // SAFETY: as for `ld`.
                unsafe { _mm_loadu_si128(self.qshift[$o..$o + PACKET].as_ptr().cast()) }
            };
        }
        macro_rules! st {
            ($a:expr, $o:expr, $v:expr) => {
                // SAFETY: as for `ld`.
                unsafe { _mm256_storeu_pd($a[$o..$o + PACKET].as_mut_ptr(), $v) }
            };
        }
        // The clearance of the four cells (c, r), each in its ray's quadrant (offsets
        // `base`); rays only ever sit on cells of the padded grid, so the indices are in
        // range.
        let four = _mm256_set1_pd(4.0);
        // The table as 32-bit words, one per padded cell, its last word, and map cell
        // (0, 0)'s word.
        let words = quadrants.as_ptr().cast::<i32>();
        let last_word = _mm_set1_epi32((quadrants.len() / 4) as i32 - 1);
        let cell0 = _mm256_set1_pd(wp + 1.0);
        let byte = _mm_set1_epi32(0xff);
        let clearance = |c: __m256d, r: __m256d, base: __m256d, shift: __m128i| -> __m256d {
            if $gather {
                let cell = _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(r, v_wp), c), cell0);
                // Clamped to the table (as unsigned: a negative index clamps too), as in
                // the AVX-512 march, so that a broken invariant would give a wrong
                // clearance, never a read outside it.
                let ii = _mm_min_epu32(_mm256_cvttpd_epi32(cell), last_word);
                // SAFETY: only the AVX2 version takes this branch; every index is a word
                // of the table (the four bytes of one padded cell).
                #[allow(unused_unsafe)]
                let v = unsafe {
                    let w = _mm_i32gather_epi32::<4>(words, ii);
                    _mm256_cvtepi32_pd(_mm_and_si128(_mm_srlv_epi32(w, shift), byte))
                };
                return v;
            }
            let cell = _mm256_add_pd(_mm256_mul_pd(r, v_wp), c);
            let idx = _mm256_add_pd(_mm256_mul_pd(cell, four), base);
            let ii = _mm256_cvttpd_epi32(idx);
            _mm256_cvtepi32_pd(_mm_setr_epi32(
                i32::from(quadrants[_mm_cvtsi128_si32(ii) as usize]),
                i32::from(quadrants[_mm_extract_epi32::<1>(ii) as usize]),
                i32::from(quadrants[_mm_extract_epi32::<2>(ii) as usize]),
                i32::from(quadrants[_mm_extract_epi32::<3>(ii) as usize]),
            ))
        };
        // A lane has stopped in an occupied cell or on the padding (clearance 0) or past
        // its range.
        let stopped = |v: __m256d, t: __m256d, tmax: __m256d| -> __m256d {
            _mm256_or_pd(
                _mm256_cmp_pd::<_CMP_EQ_OQ>(v, zero),
                _mm256_cmp_pd::<_CMP_GT_OQ>(t, tmax),
            )
        };
        // The clearance of each ray's current cell is carried along (in `self.v`), so a
        // ray is retired in the same pass as the step that stops it.
        let mut n_live = 0;
        let mut live = [0u16; CHUNK / PACKET];
        for p in 0..n / PACKET {
            let o = p * PACKET;
            let v = clearance(ld!(self.c, o), ld!(self.r, o), ld!(self.base, o), ldq!(o));
            st!(self.v, o, v);
            let stop = stopped(v, ld!(self.t, o), ld!(self.tmax, o));
            live[n_live] = p as u16;
            n_live += usize::from(_mm256_movemask_pd(stop) != 0b1111);
        }
        while n_live > 0 {
            let mut kept = 0;
            for j in 0..n_live {
                let p = usize::from(live[j]);
                let o = p * PACKET;
                let c = ld!(self.c, o);
                let r = ld!(self.r, o);
                let t = ld!(self.t, o);
                let v = ld!(self.v, o);
                let tmax = ld!(self.tmax, o);
                let stop = stopped(v, t, tmax);
                let k = _mm256_sub_pd(v, one);
                let sx = ld!(self.sx, o);
                let sy = ld!(self.sy, o);
                let px = ld!(self.px, o);
                let py = ld!(self.py, o);
                let bx = _mm256_add_pd(_mm256_add_pd(c, _mm256_mul_pd(k, sx)), px);
                let by = _mm256_add_pd(_mm256_add_pd(r, _mm256_mul_pd(k, sy)), py);
                let tx = _mm256_mul_pd(_mm256_sub_pd(bx, v_gx), ld!(self.inv_dx, o));
                let ty = _mm256_mul_pd(_mm256_sub_pd(by, v_gy), ld!(self.inv_dy, o));
                let exit_x = _mm256_cmp_pd::<_CMP_LT_OQ>(tx, ty);
                let tn = _mm256_blendv_pd(ty, tx, exit_x);
                let o_g = _mm256_blendv_pd(v_gx, v_gy, exit_x);
                let o_d = _mm256_blendv_pd(ld!(self.dx, o), ld!(self.dy, o), exit_x);
                let o_c = _mm256_blendv_pd(c, r, exit_x);
                let o_p = _mm256_blendv_pd(px, py, exit_x);
                let fl = _mm256_floor_pd(_mm256_add_pd(o_g, _mm256_mul_pd(tn, o_d)));
                // max(a, b) = a > b ? a : b and min(a, b) = a < b ? a : b: the scalar forms.
                let hi = _mm256_add_pd(o_c, _mm256_mul_pd(k, o_p));
                let lo = _mm256_sub_pd(hi, k);
                let other = _mm256_min_pd(_mm256_max_pd(fl, lo), hi);
                let k1 = _mm256_add_pd(k, one);
                let nc = _mm256_blendv_pd(other, _mm256_add_pd(c, _mm256_mul_pd(k1, sx)), exit_x);
                let nr = _mm256_blendv_pd(_mm256_add_pd(r, _mm256_mul_pd(k1, sy)), other, exit_x);
                // Stopped lanes keep their state (and so a valid cell).
                let c = _mm256_blendv_pd(nc, c, stop);
                let r = _mm256_blendv_pd(nr, r, stop);
                let t = _mm256_blendv_pd(tn, t, stop);
                let v = clearance(c, r, ld!(self.base, o), ldq!(o));
                st!(self.c, o, c);
                st!(self.r, o, r);
                st!(self.t, o, t);
                st!(self.v, o, v);
                live[kept] = p as u16;
                kept += usize::from(_mm256_movemask_pd(stopped(v, t, tmax)) != 0b1111);
            }
            n_live = kept;
        }
    }
    };
}

impl Batch {
    march_avx_fn!(
        /// [`Batch::march_scalar`] four rays at a time with AVX: the same operations lane
        /// by lane (IEEE add, sub, mul, compare, exact floor, min, max; no FMA), so the
        /// results are bit-identical to the portable version. A packet stays live until
        /// all four of its rays have stopped; a stopped lane keeps its state.
        ///
        /// # Safety
        /// The CPU must support AVX.
        march_avx, "avx", false
    );
    march_avx_fn!(
        /// [`Batch::march_avx`] with each step's four clearances read by one AVX2 gather.
        ///
        /// # Safety
        /// The CPU must support AVX and AVX2.
        march_avx_gather, "avx,avx2", true
    );
}
