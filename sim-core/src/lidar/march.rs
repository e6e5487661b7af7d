//! Exact grid ray marching accelerated by the quadrant clearance.
//!
//! A ray is tracked by its current cell (c, r) and the parameter t (in cells) at which it
//! entered that cell; every boundary crossing is computed in closed form from the ray
//! origin, `t = (boundary - g) / d`, so no error accumulates along the ray. A ray with
//! direction signs (sx, sy) reads the clearance table of its own quadrant: in a free cell
//! whose value says that the square `[c, c + k sx] x [r, r + k sy]` is free, the ray
//! (which moves monotonically away from the square's corner cell) can only leave it
//! through its far x or far y side, and jumps there; with k = 0 that is one exact
//! grid-traversal step. The square ahead of the ray is not limited by the walls beside
//! or behind it, so rays along a corridor take much longer jumps than with a block
//! centred on the cell. A ray
//! stops in the first occupied cell (hit at its entry t), past `tmax`, or on the padding
//! around the map (it left the map rectangle, which is convex: it never comes back).
//!
//! Speed comes from the batch layout: the rays of a chunk live in arrays
//! (structure of arrays) and are advanced in passes, one step per live ray per pass, with
//! the live list compacted without branches. The iterations of a pass are independent,
//! so the CPU overlaps their memory loads and arithmetic, and the only branch is the loop
//! itself. Cell indices are kept as exact integral floats: a step converts to an integer
//! once, for the memory index. On x86-64 CPUs with AVX-512 (detected at run time) eight
//! rays share each instruction; with AVX only, four rays (a packet stays live until all
//! its rays have stopped; neighbouring beams take similar step counts, so few lanes idle:
//! on the shipped tracks 85 % of the AVX-512 lanes stepped are live rays, which leaves
//! little to gain from repacking them); elsewhere a portable version runs. All perform
//! the same IEEE operations lane by lane, without FMA, so their results are bit-identical
//! (tested), as determinism requires. Eight lanes against four took about 30 % off the
//! time per scan (`cargo bench -p paddock-sim --bench scan`).
//!
//! The AVX-512 march is bound by the latency of a step's chain of dependent operations
//! and by its instruction count, not by memory (the time per step is the same with a
//! clearance table of 4 MiB or of 60 KiB), so it steps two packets at once with their
//! operations interleaved, loads the eight clearances with scalar loads (on AMD Zen a
//! gather costs more), and tracks the live packets in a bit set. Together with chunks of
//! 384 rays instead of 256 (fewer chunk ends where a few long rays are traced alone),
//! that took about 15 % off the time per scan on an AMD EPYC (Zen 5) VM.

use crate::map::Map;

/// Rays per batch: the batch's arrays (about 43 KiB) stay in a 48 KiB L1 cache. 512 was
/// slower: arrays 4 KiB apart put each ray's fourteen values in the same cache set.
pub(super) const CHUNK: usize = 384;
/// Rays per SIMD packet (four f64 lanes of AVX).
const PACKET: usize = 4;

/// Whether the AVX march can run: the CPU has AVX, and the map's table indices fit the
/// i32 lanes it converts them to.
#[cfg(target_arch = "x86_64")]
pub(super) fn avx_usable(map: &Map) -> bool {
    map.quadrant_clearance().len() < i32::MAX as usize && std::arch::is_x86_feature_detected!("avx")
}

/// Whether the AVX-512 march can run (eight rays per packet): the CPU has AVX-512F and
/// AVX2 (for the table indices), and the table is not empty and its indices fit i32
/// lanes.
#[cfg(target_arch = "x86_64")]
pub(super) fn avx512_usable(map: &Map) -> bool {
    let len = map.quadrant_clearance().len();
    len > 0
        && len < i32::MAX as usize
        && std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx2")
}

/// 1.5 * 2^52: adding and subtracting it rounds a float of magnitude < 2^51 to an integer.
const ROUND: f64 = 6_755_399_441_055_744.0;

/// Exact floor for |v| < 2^51 with SSE2 arithmetic only (no libm call, no int round trip;
/// Rust neither reassociates nor contracts float operations, so this is reliable).
#[inline(always)]
fn floor_small(v: f64) -> f64 {
    let r = (v + ROUND) - ROUND;
    if r > v { r - 1.0 } else { r }
}

/// The rays of one chunk, structure of arrays. Fill `dx`, `dy` (unit direction in the grid
/// frame) and `tmax` (cells) for rays `0..n`, then call [`Batch::cast`].
pub(super) struct Batch {
    pub dx: [f64; CHUNK],
    pub dy: [f64; CHUNK],
    pub tmax: [f64; CHUNK],
    inv_dx: [f64; CHUNK],
    inv_dy: [f64; CHUNK],
    /// Step direction (+1 / -1) and far-boundary offset (1 / 0) per axis.
    sx: [f64; CHUNK],
    sy: [f64; CHUNK],
    px: [f64; CHUNK],
    py: [f64; CHUNK],
    /// Offset of the ray's quadrant of map cell (0, 0) in the clearance table.
    base: [f64; CHUNK],
    /// Current cell (map coordinates; -1 and width / height are the padding) and the ray
    /// parameter at which the ray entered it.
    c: [f64; CHUNK],
    r: [f64; CHUNK],
    t: [f64; CHUNK],
    /// Clearance of the current cell (AVX march only).
    v: [f64; CHUNK],
    live: [u16; CHUNK],
    /// The widest SIMD march `cast` may use (tests force each one): 0 portable, 1 AVX,
    /// 2 AVX-512.
    pub simd: u8,
}

impl Batch {
    pub(super) fn new() -> Box<Self> {
        Box::new(Self {
            dx: [0.0; CHUNK],
            dy: [0.0; CHUNK],
            tmax: [0.0; CHUNK],
            inv_dx: [0.0; CHUNK],
            inv_dy: [0.0; CHUNK],
            sx: [0.0; CHUNK],
            sy: [0.0; CHUNK],
            px: [0.0; CHUNK],
            py: [0.0; CHUNK],
            base: [0.0; CHUNK],
            c: [0.0; CHUNK],
            r: [0.0; CHUNK],
            t: [0.0; CHUNK],
            v: [0.0; CHUNK],
            live: [0; CHUNK],
            simd: 2,
        })
    }

    /// Traces rays `0..n` from the grid point (gx, gy); writes for each into `out` the hit
    /// parameter in cells (the distance in cells, directions being unit) or infinity when
    /// nothing is hit before its `tmax` inside the map.
    #[inline(always)]
    pub(super) fn cast<const AVX: bool>(
        &mut self,
        map: &Map,
        gx: f64,
        gy: f64,
        n: usize,
        out: &mut [f64],
    ) {
        assert!(n <= CHUNK && out.len() >= n);
        let (w, h) = (map.width() as f64, map.height() as f64);
        // Pad to whole packets (of four, or eight for AVX-512) with rays that stop at once
        // (tmax < 0).
        let padded = n.next_multiple_of(2 * PACKET);
        for i in n..padded {
            self.dx[i] = 1.0;
            self.dy[i] = 0.0;
            self.tmax[i] = -1.0;
        }
        self.prepare(map, gx, gy, padded);
        #[cfg(target_arch = "x86_64")]
        {
            // `AVX` selects the code path at compile time (so that callers compiled with AVX
            // inline it); the check keeps this safe whatever the caller.
            if AVX && self.simd >= 2 && avx512_usable(map) {
                // SAFETY: `avx512_usable` checked that the CPU supports AVX-512F and AVX2.
                unsafe { self.march_avx512(map, gx, gy, padded) };
                self.finish(w, h, n, out);
                return;
            }
            if AVX && self.simd >= 1 && avx_usable(map) {
                // SAFETY: `avx_usable` checked that the CPU supports AVX.
                unsafe { self.march_avx(map, gx, gy, padded) };
                self.finish(w, h, n, out);
                return;
            }
        }
        self.march_scalar(map, gx, gy, padded);
        self.finish(w, h, n, out);
    }

    /// Advances rays `0..n` until each stops (portable version).
    fn march_scalar(&mut self, map: &Map, gx: f64, gy: f64, n: usize) {
        let quadrants = map.quadrant_clearance();
        let wp = map.width() as f64 + 2.0;
        let mut n_live = n;
        while n_live > 0 {
            let mut kept = 0;
            for j in 0..n_live {
                let i = usize::from(self.live[j]);
                let (c, r, t) = (self.c[i], self.r[i], self.t[i]);
                // Rays only ever sit on cells of the padded grid: the index is in range.
                let v = quadrants[((r * wp + c) * 4.0 + self.base[i]) as usize];
                let stop = (v == 0) | (t > self.tmax[i]);
                // Exit of the free square of side k + 1 (garbage when stopped: discarded).
                let k = f64::from(v) - 1.0;
                let tx = ((c + k * self.sx[i] + self.px[i]) - gx) * self.inv_dx[i];
                let ty = ((r + k * self.sy[i] + self.py[i]) - gy) * self.inv_dy[i];
                let exit_x = tx < ty;
                let tn = if exit_x { tx } else { ty };
                // The cell on the other axis at the exit point; bounding it to the square
                // ([o_c, o_c + k] or [o_c - k, o_c] as the ray goes up or down that axis)
                // only absorbs rounding.
                let (o_g, o_d, o_c, o_p) = if exit_x {
                    (gy, self.dy[i], r, self.py[i])
                } else {
                    (gx, self.dx[i], c, self.px[i])
                };
                let hi = o_c + k * o_p;
                let lo = hi - k;
                let fl = floor_small(o_g + tn * o_d);
                let other = if fl > lo { fl } else { lo };
                let other = if other < hi { other } else { hi };
                let (nc, nr) = if exit_x {
                    (c + (k + 1.0) * self.sx[i], other)
                } else {
                    (other, r + (k + 1.0) * self.sy[i])
                };
                self.c[i] = if stop { c } else { nc };
                self.r[i] = if stop { r } else { nr };
                self.t[i] = if stop { t } else { tn };
                self.live[kept] = i as u16;
                kept += usize::from(!stop);
            }
            n_live = kept;
        }
    }

    /// Results from the final states: the entry parameter of the occupied cell a ray
    /// stopped in, or infinity (past `tmax`, or stopped on the padding: off the map).
    #[inline(always)]
    fn finish(&self, w: f64, h: f64, n: usize, out: &mut [f64]) {
        for (i, o) in out.iter_mut().enumerate().take(n) {
            let (c, r) = (self.c[i], self.r[i]);
            let on_map = c >= 0.0 && r >= 0.0 && c < w && r < h;
            *o = if self.t[i] <= self.tmax[i] && on_map {
                self.t[i]
            } else {
                f64::INFINITY
            };
        }
    }

    /// Per-ray constants and the first cell: the origin's cell, or where the ray enters
    /// the map rectangle (a ray that never does starts on the padding, i.e. finished).
    #[inline(always)]
    fn prepare(&mut self, map: &Map, gx: f64, gy: f64, n: usize) {
        let (w, h) = (map.width() as f64, map.height() as f64);
        // Map cell (0, 0) in the padded grid.
        let base0 = 4.0 * (map.width() as f64 + 3.0);
        for i in 0..n {
            // -0.0 would give an inverse of -infinity and a wrong stepping direction.
            let dx = if self.dx[i] == 0.0 { 0.0 } else { self.dx[i] };
            let dy = if self.dy[i] == 0.0 { 0.0 } else { self.dy[i] };
            self.dx[i] = dx;
            self.dy[i] = dy;
            self.inv_dx[i] = 1.0 / dx;
            self.inv_dy[i] = 1.0 / dy;
            self.sx[i] = if dx >= 0.0 { 1.0 } else { -1.0 };
            self.px[i] = if dx >= 0.0 { 1.0 } else { 0.0 };
            self.sy[i] = if dy >= 0.0 { 1.0 } else { -1.0 };
            self.py[i] = if dy >= 0.0 { 1.0 } else { 0.0 };
            // Quadrant (x_neg as usize) | (y_neg as usize) << 1, as `Map` lays them out.
            let quadrant = (1.0 - self.px[i]) + 2.0 * (1.0 - self.py[i]);
            self.base[i] = base0 + quadrant;
            self.live[i] = i as u16;
        }
        if gx >= 0.0 && gy >= 0.0 && gx < w && gy < h {
            let (c, r) = (floor_small(gx), floor_small(gy));
            self.c[..n].fill(c);
            self.r[..n].fill(r);
            self.t[..n].fill(0.0);
            return;
        }
        for i in 0..n {
            // Clip the ray to the map rectangle [0, w] x [0, h].
            let mut t0 = 0.0f64;
            let mut t1 = self.tmax[i];
            let mut enters = true;
            for (g, inv, size) in [(gx, self.inv_dx[i], w), (gy, self.inv_dy[i], h)] {
                if inv.is_infinite() {
                    enters &= g >= 0.0 && g < size;
                } else {
                    let (a, b) = ((0.0 - g) * inv, (size - g) * inv);
                    t0 = t0.max(a.min(b));
                    t1 = t1.min(a.max(b));
                }
            }
            if enters && t0 <= t1 {
                self.t[i] = t0;
                self.c[i] = floor_small(gx + t0 * self.dx[i]).max(0.0).min(w - 1.0);
                self.r[i] = floor_small(gy + t0 * self.dy[i]).max(0.0).min(h - 1.0);
            } else {
                self.t[i] = 0.0;
                self.c[i] = -1.0;
                self.r[i] = -1.0;
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
impl Batch {
    /// [`Batch::march_scalar`] four rays at a time with AVX: the same operations lane by
    /// lane (IEEE add, sub, mul, compare, exact floor, min, max; no FMA), so the results
    /// are bit-identical to the portable version. A packet stays live until all four of
    /// its rays have stopped; a stopped lane keeps its state.
    ///
    /// # Safety
    /// The CPU must support AVX.
    #[target_feature(enable = "avx")]
    unsafe fn march_avx(&mut self, map: &Map, gx: f64, gy: f64, n: usize) {
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
        let clearance = |c: __m256d, r: __m256d, base: __m256d| -> __m256d {
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
            let v = clearance(ld!(self.c, o), ld!(self.r, o), ld!(self.base, o));
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
                let v = clearance(c, r, ld!(self.base, o));
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
}

#[cfg(target_arch = "x86_64")]
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
    unsafe fn march_avx512(&mut self, map: &Map, gx: f64, gy: f64, n: usize) {
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

/// A plain Amanatides-Woo traversal without the block jumps, for tests: the hit
/// parameter in cells or infinity.
#[cfg(test)]
pub(super) fn cast_simple(map: &Map, gx: f64, gy: f64, dx: f64, dy: f64, tmax: f64) -> f64 {
    let (w, h) = (map.width() as i64, map.height() as i64);
    let (mut c, mut r) = (gx.floor() as i64, gy.floor() as i64);
    if map.cell_occupied(c, r) {
        return 0.0;
    }
    let (sx, sy) = (if dx > 0.0 { 1 } else { -1 }, if dy > 0.0 { 1 } else { -1 });
    let tdx = if dx != 0.0 {
        (1.0 / dx).abs()
    } else {
        f64::INFINITY
    };
    let tdy = if dy != 0.0 {
        (1.0 / dy).abs()
    } else {
        f64::INFINITY
    };
    let mut tmx = if dx > 0.0 {
        (c as f64 + 1.0 - gx) * tdx
    } else if dx < 0.0 {
        (gx - c as f64) * tdx
    } else {
        f64::INFINITY
    };
    let mut tmy = if dy > 0.0 {
        (r as f64 + 1.0 - gy) * tdy
    } else if dy < 0.0 {
        (gy - r as f64) * tdy
    } else {
        f64::INFINITY
    };
    loop {
        let t;
        if tmx < tmy {
            t = tmx;
            tmx += tdx;
            c += sx;
        } else {
            t = tmy;
            tmy += tdy;
            r += sy;
        }
        if t > tmax {
            return f64::INFINITY;
        }
        if map.cell_occupied(c, r) {
            return t;
        }
        if (c < 0 && sx < 0) || (c >= w && sx > 0) || (r < 0 && sy < 0) || (r >= h && sy > 0) {
            return f64::INFINITY;
        }
    }
}
