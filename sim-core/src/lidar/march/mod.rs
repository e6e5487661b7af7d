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

#[cfg(target_arch = "x86_64")]
mod avx;
#[cfg(target_arch = "x86_64")]
mod avx512;

/// Rays per batch: the batch's arrays (about 45 KiB) stay in a 48 KiB L1 cache. 512 was
/// slower: arrays 4 KiB apart put each ray's fourteen values in the same cache set.
pub(super) const CHUNK: usize = 384;
/// Rays per SIMD packet (four f64 lanes of AVX).
const PACKET: usize = 4;

/// Whether the AVX march can run: the CPU has AVX, and the table is not empty and its
/// indices fit the i32 lanes it converts them to.
#[cfg(target_arch = "x86_64")]
pub(super) fn avx_usable(map: &Map) -> bool {
    let len = map.quadrant_clearance().len();
    len > 0 && len < i32::MAX as usize && std::arch::is_x86_feature_detected!("avx")
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

/// Whether the AVX march reads its clearances by AVX2 gathers: on Intel CPUs with AVX2
/// (faster there; see `avx.rs`). Detected once.
#[cfg(target_arch = "x86_64")]
pub(in crate::lidar) fn avx_gather_pays() -> bool {
    static PAYS: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *PAYS.get_or_init(|| super::path::intel() && std::arch::is_x86_feature_detected!("avx2"))
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
    /// Bit offset of the ray's quadrant in a cell's four table bytes read as one
    /// little-endian u32 (the AVX2 gather reads whole cells).
    qshift: [i32; CHUNK],
    /// The widest SIMD march `cast` may use (tests force each one): 0 portable, 1 AVX,
    /// 2 AVX-512.
    pub simd: u8,
    /// Whether the AVX march gathers its clearances (tests force each way; honoured only
    /// on CPUs with AVX2); `None`: where that pays, see [`avx_gather_pays`].
    pub avx_gather: Option<bool>,
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
            qshift: [0; CHUNK],
            simd: 2,
            avx_gather: None,
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
                let gather = self.avx_gather.unwrap_or_else(avx_gather_pays);
                if gather && std::arch::is_x86_feature_detected!("avx2") {
                    // SAFETY: the CPU supports AVX (`avx_usable`) and AVX2.
                    unsafe { self.march_avx_gather(map, gx, gy, padded) };
                } else {
                    // SAFETY: `avx_usable` checked that the CPU supports AVX.
                    unsafe { self.march_avx(map, gx, gy, padded) };
                }
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
            self.qshift[i] = 8 * quadrant as i32;
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
