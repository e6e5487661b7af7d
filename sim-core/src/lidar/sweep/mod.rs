//! The exact scan as an angular sweep over the wall faces in view, with the march as the
//! referee of near-ties.
//!
//! Instead of following each ray cell by cell, the sweep takes the map's wall faces
//! ([`WallFaces`]: straight runs of cell sides between a free and an occupied cell, by
//! 64 x 64-cell block and by the side they face; only those of the origin's free region,
//! see `FaceSets`: on a race track's map half of them) block by block, nearest blocks first,
//! and crosses each run with the beams that can see its block: a beam going +x meets a
//! run on the line x = X at `t = (X - gx) / dx` (the march's own expression, so the same
//! bits) if `gy + t dy` lies on the run. A beam's range is the least such t. Blocks wholly
//! beyond the current range of every beam that can see them are skipped (per group of 16
//! beams the largest current range is kept), first by groups of 2 x 2 blocks, then one
//! by one, and the sweep ends at the first ring of blocks beyond all of them.
//!
//! The march decides which cell a ray enters at a cell corner by its own rounding; the
//! sweep cannot see those decisions. So a beam whose crossing of a run lies within
//! [`EPS`] cells of one of the run's ends, where the geometry changes, is flagged and
//! traced again by the march, whose result it takes. Away from run ends a crossing is
//! decided the same way by both (the cells on either side of the crossing point are the
//! same whichever way a rounding goes), so every beam gets the march's bits. The whole
//! scan is left to the march when its origin is off the map, in an occupied cell, or
//! within [`EPS`] of a grid line, and for fans that are not a plain arc of beams.

#[cfg(target_arch = "x86_64")]
mod avx;
mod beams;
mod fan;
mod lines;

use std::f64::consts::PI;

use super::metres;
use crate::map::Map;
use crate::map::faces::{BLOCK, MINUS_X, MINUS_Y, PLUS_X, PLUS_Y, WallFaces};
use beams::Beams;
pub(super) use beams::Noise;
pub(super) use fan::Fan;
use fan::{ANGLE_SLACK, beams_seeing, box_angles};
use lines::Lines;

/// Cells: a crossing this near a run's end is left to the march (the rounding of either
/// side's expressions is below 1e-12 cells on maps up to 2^24 cells across).
const EPS: f64 = 1e-9;
/// Beams per block of the culling maxima.
const GROUP: usize = 16;
/// Blocks per side of a group of blocks culled at once before its blocks one by one.
const SUPER: usize = 2;
/// A run's beams are crossed in whole aligned lanes of this many (the extra beams cannot
/// cross it: testing them changes nothing).
const LANES: usize = 4;

/// The sweep's per-beam arrays, kept per thread and reused.
#[derive(Default)]
pub(super) struct Sweep {
    /// Unit direction in the grid frame of each beam (see [`Sweep::prepare`]).
    pub dx: Lines,
    pub dy: Lines,
    inv_dx: Lines,
    inv_dy: Lines,
    /// The least crossing so far (starts beyond the beam's range limit in cells).
    best: Lines,
    /// Non-zero: a crossing near a run end; the march decides this beam. All zero between
    /// scans (a scan clears the few it set), so a scan sets it only where it flags.
    flag: Lines,
    /// Whether this scan has flagged any beam.
    flagged: bool,
    /// Per group of [`GROUP`] beams, the largest `best`, and a bit set of the groups a
    /// crossing test may have lowered since.
    group_max: Vec<f64>,
    dirty: Vec<u64>,
    /// Per group of SUPER x SUPER blocks: the scan (`serial`) in which it was found
    /// beyond every beam that can see it, and the scan and ring (`stamp`) in which it was
    /// last tested.
    super_dead: Vec<u64>,
    super_tested: Vec<u64>,
    /// This thread's scans so far, and `serial << 16 | ring` of the ring being swept.
    serial: u64,
    stamp: u64,
    /// The range limit of each beam in metres (the caller's scratch), read only when
    /// `uniform` is `None`; else every beam's limit is `uniform`.
    pub limit: Vec<f64>,
    pub uniform: Option<f64>,
    /// Cells per metre of the scan being swept.
    inv_res: f64,
    /// Per run of the block side being crossed: its first and last beam (portable code),
    /// and what the AVX crossings need of it.
    first: Vec<f64>,
    last: Vec<f64>,
    #[cfg(target_arch = "x86_64")]
    runs: avx::Runs,
    /// The beams [`Sweep::run`] leaves to the march, and their noise where it is drawn
    /// alongside.
    pub marched: Vec<u32>,
    pub marched_noise: Vec<f64>,
    /// Scans swept and beams left to the march since this thread's first (for tests, and
    /// `thread_scans_by_algorithm`).
    pub swept: u64,
    pub handed: u64,
}

/// The wall faces of the origin's free region if the sweep applies to a scan of `n` beams
/// of `fan` from the grid point (gx, gy) with range limits up to `tmax` cells; `None` when
/// the caller must march every beam (see the module doc). Out of line: once per scan.
#[inline(never)]
pub(super) fn faces_for<'m>(
    map: &'m Map,
    gx: f64,
    gy: f64,
    fan: &Fan,
    n: usize,
    tmax: f64,
) -> Option<&'m WallFaces> {
    let (w, h) = (map.width() as f64, map.height() as f64);
    let near_line = |g: f64| {
        let f = g - libm::floor(g);
        !(f > EPS && f < 1.0 - EPS)
    };
    let applies = n >= 2
        && fan.fov > 0.0
        && fan.fov < 1.9 * PI
        && fan.inc > 0.0
        && gx >= 0.0
        && gy >= 0.0
        && gx < w
        && gy < h
        && !near_line(gx)
        && !near_line(gy)
        && !map.cell_occupied(gx as i64, gy as i64)
        && tmax.is_finite();
    if !applies {
        return None;
    }
    // The faces of the origin's free region decide every range (see `FaceSets::new`).
    map.wall_faces()
        .map(|sets| sets.at(gx as usize, gy as usize))
}

impl Sweep {
    /// Sizes the arrays for `n` beams (contents unspecified until filled). The arrays the
    /// crossings read are padded to whole lanes of four with beams that meet nothing (an
    /// inverse of 0 gives t = 0, never a crossing).
    pub(super) fn resize(&mut self, n: usize) {
        if self.limit.len() == n {
            return;
        }
        self.limit.resize(n, 0.0);
        // One lane more: the crossings of a short run take two lanes whatever its span;
        // and whole groups (the padding's ranges stay 0, below every beam's).
        let padded = (n.next_multiple_of(LANES) + LANES).next_multiple_of(GROUP);
        for v in [
            &mut self.dx,
            &mut self.dy,
            &mut self.inv_dx,
            &mut self.inv_dy,
            &mut self.best,
            &mut self.flag,
        ] {
            v.zeroed(padded);
        }
        let groups = n.div_ceil(GROUP);
        self.group_max.resize(groups, 0.0);
        self.dirty.clear();
        self.dirty.resize(groups.div_ceil(64), 0);
    }

    /// The beams' directions in the grid frame (the beam's `cos` and `sin` relative to the
    /// heading turned by the heading's `gc`, `gs`, as the march computes them), and their
    /// limits in cells from `uniform` or `limit` (metres, set by the caller) and `inv_res`.
    /// With `noise` (the generator, the standard deviation and one value per beam), the
    /// scan's noise is drawn too, as [`crate::lidar::Lidar::add_noise`] draws it; the
    /// caller then asks [`Sweep::run`] to add it.
    #[inline(always)]
    pub(super) fn prepare(
        &mut self,
        beam_cos: &[f64],
        beam_sin: &[f64],
        gc: f64,
        gs: f64,
        inv_res: f64,
        noise: Option<Noise<'_>>,
    ) {
        let n = self.limit.len();
        self.inv_res = inv_res;
        let beams = Beams {
            beam_cos: &beam_cos[..n],
            beam_sin: &beam_sin[..n],
            dx: &mut self.dx[..n],
            dy: &mut self.dy[..n],
            inv_dx: &mut self.inv_dx[..n],
            inv_dy: &mut self.inv_dy[..n],
            best: &mut self.best[..n],
        };
        // Any start beyond the limit will do (a crossing beyond it is no hit).
        match self.uniform {
            Some(limit) => {
                let start = limit * inv_res + 1.0;
                beams.fill(gc, gs, |_| start, None, noise);
            }
            None => {
                let limit = &self.limit[..n];
                beams.fill(
                    gc,
                    gs,
                    |j| limit[j] * inv_res + 1.0,
                    Some((limit, inv_res)),
                    noise,
                );
            }
        }
    }

    /// Beam `i`'s range limit in metres.
    #[inline(always)]
    pub(super) fn limit_of(&self, i: usize) -> f64 {
        self.uniform.unwrap_or_else(|| self.limit[i])
    }

    /// Beam `i`'s range limit in cells, as the sweep compares crossings with it.
    #[inline(always)]
    pub(super) fn limit_cells(&self, i: usize) -> f64 {
        self.limit_of(i) * self.inv_res
    }

    /// Sweeps `faces` (those of the map, see [`faces_for`]) from the grid point (gx, gy)
    /// for the beams `dx`, `dy` and their limits (see [`Sweep::prepare`]; `fan` says where they
    /// point): `out[i]` is the range in metres (cells times `res`, capped at the beam's
    /// limit) for every beam not listed in `marched`: those the caller marches. If
    /// `noisy`, `out` holds the scan's noise (see [`Sweep::prepare`]) and gets each range
    /// added to it, and the noise of the beams listed in `marched` is kept in
    /// `marched_noise` (in the same order).
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(super) fn run<const AVX: bool>(
        &mut self,
        faces: &WallFaces,
        gx: f64,
        gy: f64,
        res: f64,
        fan: &Fan,
        out: &mut [f64],
        noisy: bool,
    ) {
        let n = self.limit.len();
        self.marched.clear();
        self.marched_noise.clear();
        for g in 0..self.group_max.len() {
            self.group_max[g] = self.group_best::<AVX>(g);
        }
        let supers = faces.blocks_x.div_ceil(SUPER) * faces.blocks_y.div_ceil(SUPER);
        if self.super_dead.len() < supers {
            self.super_dead.resize(supers, 0);
            self.super_tested.resize(supers, 0);
        }
        self.serial += 1;
        self.flagged = false;
        self.sweep::<AVX>(faces, gx, gy, fan);
        if self.flagged {
            for (i, f) in self.flag[..n].iter_mut().enumerate() {
                if *f != 0.0 {
                    self.marched.push(i as u32);
                    if noisy {
                        self.marched_noise.push(out[i]);
                    }
                    *f = 0.0;
                }
            }
        }
        let (best, inv_res) = (&self.best[..n], self.inv_res);
        // A crossing beyond the limit (in cells) is no hit.
        let range = |b: f64, limit: f64| {
            let cells = if b <= limit * inv_res {
                b
            } else {
                f64::INFINITY
            };
            metres(cells, res, limit)
        };
        // Four loops, each plain: one loop choosing the limit and the store per beam made
        // whole scans about a tenth slower (measured).
        match (self.uniform, noisy) {
            (Some(limit), false) => {
                for i in 0..n {
                    out[i] = range(best[i], limit);
                }
            }
            (None, false) => {
                let limit = &self.limit[..n];
                for i in 0..n {
                    out[i] = range(best[i], limit[i]);
                }
            }
            // The noise after the range, as `Lidar::add_noise` adds it.
            (Some(limit), true) => {
                for i in 0..n {
                    out[i] += range(best[i], limit);
                }
            }
            (None, true) => {
                let limit = &self.limit[..n];
                for i in 0..n {
                    out[i] += range(best[i], limit[i]);
                }
            }
        }
        self.swept += 1;
        self.handed += self.marched.len() as u64;
    }

    /// The blocks ring by ring from the origin's block outwards: of each ring only those
    /// with faces, read off the bits of its two rows and two columns (a branch per block
    /// with faces and per row or column, where testing every block of the ring cost a
    /// mispredicted branch on most of the empty ones).
    #[inline(always)]
    fn sweep<const AVX: bool>(&mut self, faces: &WallFaces, gx: f64, gy: f64, fan: &Fan) {
        let b = BLOCK as isize;
        let (ox, oy) = (gx as isize / b, gy as isize / b);
        let (bw, bh) = (faces.blocks_x as isize, faces.blocks_y as isize);
        let rings = ox.max(bw - 1 - ox).max(oy).max(bh - 1 - oy);
        let mut reach = self.reach::<AVX>();
        for k in 0..=rings {
            // Ring k lies at least k - 1 blocks away (with a margin for rounding).
            if (k - 1) as f64 * BLOCK as f64 * (1.0 - 1e-9) - EPS > reach {
                break;
            }
            self.stamp = self.serial << 16 | (k as u64 & 0xffff);
            // The ring's blocks with faces, by the bits of its two rows (one, the origin's
            // block, for ring 0) and two columns within the map.
            let rows: &[isize] = if k == 0 { &[oy] } else { &[oy - k, oy + k] };
            let (x0, x1) = ((ox - k).max(0), (ox + k).min(bw - 1));
            for &by in rows {
                if (0..bh).contains(&by) {
                    for bx in faces.row_blocks(by as usize, x0 as usize, x1 as usize) {
                        self.block::<AVX>(faces, bx, by as usize, gx, gy, fan, reach);
                    }
                }
            }
            let (y0, y1) = ((oy - k + 1).max(0), (oy + k - 1).min(bh - 1));
            if y0 <= y1 {
                for bx in [ox - k, ox + k] {
                    if (0..bw).contains(&bx) {
                        for by in faces.col_blocks(bx as usize, y0 as usize, y1 as usize) {
                            self.block::<AVX>(faces, bx as usize, by, gx, gy, fan, reach);
                        }
                    }
                }
            }
            reach = self.reach::<AVX>();
        }
    }

    /// The largest current range of the beams of group `g` (a whole group: the padding
    /// past the last beam holds zeros).
    #[inline(always)]
    fn group_best<const AVX: bool>(&self, g: usize) -> f64 {
        let group: &[f64; GROUP] = self.best[g * GROUP..(g + 1) * GROUP]
            .try_into()
            .expect("whole groups");
        #[cfg(target_arch = "x86_64")]
        if AVX {
            // SAFETY: `AVX` is set only by callers that checked the CPU has AVX.
            return unsafe { avx::max16(group) };
        }
        max_of::<false>(0.0, group)
    }

    /// The largest current range of any beam.
    #[inline(always)]
    fn reach<const AVX: bool>(&self) -> f64 {
        max_of::<AVX>(0.0, &self.group_max)
    }

    /// One block with faces: culled by distance, then its runs crossed with the beams
    /// that can see it.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn block<const AVX: bool>(
        &mut self,
        faces: &WallFaces,
        bx: usize,
        by: usize,
        gx: f64,
        gy: f64,
        fan: &Fan,
        reach: f64,
    ) {
        let (x0, y0) = ((bx * BLOCK) as f64, (by * BLOCK) as f64);
        let (x1, y1) = (x0 + BLOCK as f64, y0 + BLOCK as f64);
        let ex = (x0 - gx).max(gx - x1).max(0.0);
        let ey = (y0 - gy).max(gy - y1).max(0.0);
        let d2 = ex * ex + ey * ey;
        if beyond(d2, reach) {
            return;
        }
        // First its group of blocks, once per ring: far blocks are mostly culled whole
        // groups at a time, and once culled a group stays culled (ranges only shrink).
        let si = (by / SUPER) * faces.blocks_x.div_ceil(SUPER) + bx / SUPER;
        if self.super_dead[si] == self.serial {
            return;
        }
        let test_group = self.super_tested[si] != self.stamp;
        let side = (SUPER * BLOCK) as f64;
        let (sx0, sy0) = ((bx / SUPER) as f64 * side, (by / SUPER) as f64 * side);
        let (sx1, sy1) = (sx0 + side, sy0 + side);
        let group = [sx0, sy0, sx1, sy1];
        // The directions of the block's corners, and of its group's when the group is to
        // be tested.
        let (group_angles, angles, slack) =
            box_angles::<AVX>(fan, gx, gy, test_group.then_some(group), [x0, y0, x1, y1]);
        if test_group {
            self.super_tested[si] = self.stamp;
            let sex = (sx0 - gx).max(gx - sx1).max(0.0);
            let sey = (sy0 - gy).max(gy - sy1).max(0.0);
            let sd2 = sex * sex + sey * sey;
            if beyond(sd2, self.seen::<AVX>(fan, group_angles, slack, sex, sey)) {
                self.super_dead[si] = self.serial;
                return;
            }
        }
        let far = self.seen::<AVX>(fan, angles, slack, ex, ey);
        if beyond(d2, far) {
            return;
        }
        if x1 > gx {
            let runs = ahead::<true>(faces, faces.runs(bx, by, PLUS_X), gx, far);
            self.cross::<true, AVX>(faces, runs, gx, gy, fan, far);
        }
        if x0 < gx {
            let runs = ahead::<false>(faces, faces.runs(bx, by, MINUS_X), gx, far);
            self.cross::<true, AVX>(faces, runs, gx, gy, fan, far);
        }
        if y1 > gy {
            let runs = ahead::<true>(faces, faces.runs(bx, by, PLUS_Y), gy, far);
            self.cross::<false, AVX>(faces, runs, gy, gx, fan, far);
        }
        if y0 < gy {
            let runs = ahead::<false>(faces, faces.runs(bx, by, MINUS_Y), gy, far);
            self.cross::<false, AVX>(faces, runs, gy, gx, fan, far);
        }
        for w in 0..self.dirty.len() {
            let mut bits = std::mem::take(&mut self.dirty[w]);
            while bits != 0 {
                let g = 64 * w + bits.trailing_zeros() as usize;
                bits &= bits - 1;
                self.group_max[g] = self.group_best::<AVX>(g);
            }
        }
    }

    /// The largest current range of the beams that can see a box whose corners lie in
    /// the directions `angles` (within `slack` radians, see [`box_angles`]), `ex` and `ey`
    /// away from the origin along x and y (from within a cell of the box, or inside it,
    /// every beam may).
    #[inline(always)]
    fn seen<const AVX: bool>(
        &self,
        fan: &Fan,
        angles: [f64; 4],
        slack: f64,
        ex: f64,
        ey: f64,
    ) -> f64 {
        let n = self.limit.len();
        let ranges = if ex < 1.0 && ey < 1.0 {
            [0..n, 0..0]
        } else {
            beams_seeing(fan, n, angles, slack)
        };
        // The largest range of the beams that can see the box.
        let mut far = 0.0f64;
        for beams in ranges {
            if beams.is_empty() {
                continue;
            }
            let (g0, g1) = (beams.start / GROUP, (beams.end - 1) / GROUP);
            far = max_of::<AVX>(far, &self.group_max[g0..=g1]);
        }
        far
    }

    /// Crosses the runs `runs` (on lines x = const if `VERTICAL`, else y = const) with
    /// the beams that can see each; `g_line` is the origin's coordinate across the lines,
    /// `g_along` along them. Runs farther across than `far` (the largest range of the
    /// beams that see the block) are passed over. Marks the groups of the beams tested.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn cross<const VERTICAL: bool, const AVX: bool>(
        &mut self,
        faces: &WallFaces,
        runs: std::ops::Range<usize>,
        g_line: f64,
        g_along: f64,
        fan: &Fan,
        far: f64,
    ) {
        let m = runs.len();
        if m == 0 {
            return;
        }
        let n = self.limit.len();
        // The runs, and three more (padding or other runs) to read four at a time.
        let more = runs.start..runs.end + LANES - 1;
        let (line, los, his) = (
            &faces.line[more.clone()],
            &faces.lo[more.clone()],
            &faces.hi[more],
        );
        let top = (n - 1) as f64;
        // A beam's crossing of a line: the inverse of its direction across the lines, and
        // its direction along them.
        let (inv, along) = if VERTICAL {
            (&self.inv_dx[..], &self.dy[..])
        } else {
            (&self.inv_dy[..], &self.dx[..])
        };
        #[cfg(target_arch = "x86_64")]
        if AVX {
            self.runs.reserve(m);
            // SAFETY: `AVX` is set only by callers that checked the CPU has AVX; the
            // slices hold m + 3 runs and `runs` is reserved for m.
            unsafe {
                let span = avx::beams_of_runs::<VERTICAL>(
                    line,
                    los,
                    his,
                    m,
                    g_line,
                    g_along,
                    fan,
                    far,
                    top,
                    &mut self.runs,
                );
                let Some((b0, b1)) = span else { return };
                // Every beam any run may lower (a group marked without need is only
                // measured again).
                mark_groups(&mut self.dirty, b0, b1);
                self.flagged |=
                    avx::cross_runs(&self.runs, m, inv, along, &mut self.best, &mut self.flag);
            }
            return;
        }
        // Each run's beams: between its two ends' directions, with slack.
        // (Grown only: a call to resize per block side cost more than its work on the
        // blocks with few runs.)
        if self.first.len() < m {
            self.first.resize(m, 0.0);
            self.last.resize(m, 0.0);
        }
        let (first, last) = (&mut self.first[..], &mut self.last[..]);
        let slack = ANGLE_SLACK * fan.inv_inc;
        let wrap = PI * fan.inv_inc;
        let mut j = 0;
        while j < m {
            let across = f64::from(line[j]) - g_line;
            let a0 = f64::from(los[j]) - g_along;
            let a1 = f64::from(his[j]) - g_along;
            let ((x0, y0), (x1, y1)) = if VERTICAL {
                ((across, a0), (across, a1))
            } else {
                ((a0, across), (a1, across))
            };
            let i0 = (fan.angle(x0, y0) + fan.half_fov) * fan.inv_inc;
            let i1 = (fan.angle(x1, y1) + fan.half_fov) * fan.inv_inc;
            let (a, b) = if i0 < i1 { (i0, i1) } else { (i1, i0) };
            // A run across the direction behind the car: every beam (rare, and safe).
            let whole = b - a > wrap;
            let a = if whole {
                0.0
            } else {
                (a - slack).ceil().max(0.0)
            };
            let b = if whole {
                top
            } else {
                (b + slack).floor().min(top)
            };
            // Farther than any beam's range (a beam's t is at least the distance across):
            // no beams.
            let b = if across.abs() * (1.0 - 1e-9) - EPS > far {
                -1.0
            } else {
                b
            };
            first[j] = a;
            last[j] = b;
            j += 1;
        }
        let best = &mut self.best[..];
        let flag = &mut self.flag[..];
        for j in 0..m {
            if first[j] > last[j] {
                continue;
            }
            let (b0, b1) = (first[j] as usize, last[j] as usize);
            mark_groups(&mut self.dirty, b0, b1);
            let run = Run::new(line[j], los[j], his[j], g_line, g_along);
            let (from, to) = (b0 & !(LANES - 1), (b1 + 1).next_multiple_of(LANES));
            self.flagged |= run.cross(inv, along, best, flag, from, to);
        }
    }
}

/// Of the runs `runs` of one block side (sorted by line: see `WallFaces`), those that
/// rays from the origin (at `g_line` across the lines) can meet from their free side
/// (lines beyond the origin: above it for the `PLUS` sides, below for the others) no
/// farther across than `far`, give or take a line (the crossings pass over the rest the
/// same). A ray that crosses a run's line from its occupied side has passed through the
/// run's occupied cells, so it met a face nearer before: the runs left out change no
/// range. Found by counting lines below thresholds (loops the compiler vectorises; a
/// binary search's branches cost more than it saved on maps with few runs per block).
#[inline(always)]
fn ahead<const PLUS: bool>(
    faces: &WallFaces,
    runs: std::ops::Range<usize>,
    g_line: f64,
    far: f64,
) -> std::ops::Range<usize> {
    let lines = &faces.line[runs.clone()];
    let (Some(&least), Some(&most)) = (lines.first(), lines.last()) else {
        return runs;
    };
    // Most sides lie wholly beyond the origin and within reach: two comparisons.
    let reach = with_margin(far);
    let whole = if PLUS {
        f64::from(least) > g_line && f64::from(most) <= g_line + reach
    } else {
        f64::from(most) < g_line && f64::from(least) >= g_line - reach
    };
    if whole {
        return runs;
    }
    let below = |t: f64| {
        let t = t as f32;
        lines.iter().filter(|&&l| l < t).count()
    };
    // Lines are whole numbers and the origin is off every line: a line is beyond it
    // (above) exactly when it is at least floor(g_line) + 1. (The standard floor and
    // ceiling, exact like any: inlined as one instruction where the caller has SSE4.1 or
    // AVX, where `libm`'s were calls.)
    let origin = g_line.floor() + 1.0;
    let (first, last) = if PLUS {
        (below(origin), below((g_line + reach).ceil() + 2.0))
    } else {
        (below((g_line - reach).floor() - 1.0), below(origin))
    };
    runs.start + first..runs.start + last.max(first)
}

/// The largest of `start` and `v` (none of them NaN), four lanes at a time: a fold one by
/// one is a chain of dependent maxima, which the compiler keeps (it may not reorder a
/// floating-point fold), and the culling maxima are measured after every block. With
/// `AVX` by [`avx::max_of`] (the compiler left this fold in two-lane and scalar
/// maxima, a fifth of the sweep's own time).
#[inline(always)]
fn max_of<const AVX: bool>(start: f64, v: &[f64]) -> f64 {
    #[cfg(target_arch = "x86_64")]
    if AVX {
        // SAFETY: `AVX` is set only by callers that checked the CPU has AVX.
        return unsafe { avx::max_of(start, v) };
    }
    let max = |a: f64, b: f64| if b > a { b } else { a };
    let mut lanes = [start; 4];
    let mut quads = v.chunks_exact(4);
    for q in &mut quads {
        for k in 0..4 {
            lanes[k] = max(lanes[k], q[k]);
        }
    }
    let tail = quads.remainder().iter().fold(start, |a, &b| max(a, b));
    max(max(lanes[0], lanes[1]), max(max(lanes[2], lanes[3]), tail))
}

/// Marks in `dirty` the groups of beams `b0..=b1` (their culling maxima to be measured
/// again after the block).
#[inline(always)]
fn mark_groups(dirty: &mut [u64], b0: usize, b1: usize) {
    let (g0, g1) = (b0 / GROUP, b1 / GROUP);
    for (w, word) in dirty.iter_mut().enumerate().take(g1 / 64 + 1).skip(g0 / 64) {
        let lo = if w == g0 / 64 { g0 % 64 } else { 0 };
        let hi = if w == g1 / 64 { g1 % 64 } else { 63 };
        *word |= (u64::MAX >> (63 - hi)) & (u64::MAX << lo);
    }
}

/// Whether a box whose nearest point lies at squared distance `d2` (cells) from the origin
/// is beyond every range up to `reach`, with a margin for rounding. By squares: a square
/// root per block visited was a fifth of a scan's time on fine maps (its latency, on the
/// ring walk's critical path).
#[inline(always)]
fn beyond(d2: f64, reach: f64) -> bool {
    let r = with_margin(reach);
    d2 > r * r
}

/// A distance `reach` (cells) widened by the culling's margin for rounding: what lies
/// farther than this is beyond it.
#[inline(always)]
fn with_margin(reach: f64) -> f64 {
    (reach + EPS) * (1.0 + 2e-9)
}

/// One run as its crossings need it: the distance across to its line, the origin's
/// coordinate along it from the run's middle, and the run's half length widened and
/// narrowed by [`EPS`]. A crossing's distance from the middle then says both whether it
/// lies on the run and whether near an end, in fewer operations than four bounds; it
/// differs from the bounds' answer only within rounding of `EPS` from an end, where either
/// answer is safe (a crossing there is flagged if it counts, and a ray passing that near
/// outside a run's end or inside it meets the cells the march says).
struct Run {
    dl: f64,
    off: f64,
    half_out: f64,
    half_in: f64,
}

impl Run {
    /// The run on the line `line` from `lo` to `hi`, seen from an origin at `g_line`
    /// across and `g_along` along the lines.
    #[inline(always)]
    fn new(line: f32, lo: f32, hi: f32, g_line: f64, g_along: f64) -> Run {
        let (lo, hi) = (f64::from(lo), f64::from(hi));
        let half = (hi - lo) * 0.5;
        Run {
            dl: f64::from(line) - g_line,
            off: g_along - (lo + hi) * 0.5,
            half_out: half + EPS,
            half_in: half - EPS,
        }
    }

    /// Crosses the run with beams `from..to`: a beam whose crossing lies on the run (to
    /// within [`EPS`]) and before its best so far takes it; one within [`EPS`] of an end
    /// is flagged. Returns whether any was.
    #[inline(always)]
    fn cross(
        &self,
        inv: &[f64],
        along: &[f64],
        best: &mut [f64],
        flag: &mut [f64],
        from: usize,
        to: usize,
    ) -> bool {
        let mut flagged = false;
        for i in from..to {
            let t = self.dl * inv[i];
            // The crossing's distance along the line from the run's middle.
            let d = (t * along[i] + self.off).abs();
            let hit = (t > 0.0) & (t < best[i]) & (d <= self.half_out);
            let near = d > self.half_in;
            // As a minimum, not a select, for the same reason as in `avx::cross_runs`.
            let tm = if hit { t } else { f64::INFINITY };
            best[i] = if best[i] < tm { best[i] } else { tm };
            flag[i] = if hit & near { 1.0 } else { flag[i] };
            flagged |= hit & near;
        }
        flagged
    }
}

#[cfg(test)]
mod tests;
