//! The map's wall faces: every cell side between a free and an occupied cell of the map,
//! merged into straight runs and binned into square blocks of cells, for the LIDAR's
//! angular sweep (`lidar::sweep`).
//!
//! A face is kept with the side it faces, since a ray can only meet a face from the free
//! side: a vertical face on the line x = X with the occupied cell at column X is met by
//! rays going +x, with the occupied cell at X - 1 by rays going -x; horizontal faces
//! likewise. Consecutive faces of one kind on one grid line make a run `[lo, hi]` along
//! the line; runs are cut at block borders, so each run lies inside its block (the block
//! of its occupied cells), and a block's runs are stored together per side. The faces are
//! kept apart by the free region they border ([`FaceSets`]): a scan from a free cell
//! needs only its own region's.

/// Cells per side of a block. 64 rather than 32: fewer blocks to walk and cull per scan
/// for a few more runs to cross (measured on the sweep, docs/performance-scan.md).
pub(crate) const BLOCK: usize = 64;

/// The side a face faces, as the index of its runs within a block: the face is met by
/// rays going +x (`PLUS_X`: occupied cell on the larger-x side), -x, +y or -y.
pub(crate) const PLUS_X: usize = 0;
pub(crate) const MINUS_X: usize = 1;
pub(crate) const PLUS_Y: usize = 2;
pub(crate) const MINUS_Y: usize = 3;

/// Wall faces in runs, by block and side (see the module doc): those of one free region
/// of a map, or of several.
#[derive(Debug)]
pub(crate) struct WallFaces {
    /// Blocks per row and per column of the map.
    pub blocks_x: usize,
    pub blocks_y: usize,
    /// The runs of block (bx, by) facing side `s` are `start[k]..start[k + 1]`,
    /// `k = 4 * (by * blocks_x + bx) + s`.
    pub start: Vec<u32>,
    /// Per run: the grid line (x = line for the x sides, y = line for the y sides) and
    /// the run's extent `[lo, hi]` along it, in cells; then three zeros, so that runs can
    /// be read four at a time.
    pub line: Vec<f32>,
    pub lo: Vec<f32>,
    pub hi: Vec<f32>,
    /// The blocks that have faces, as bits: row `by`'s blocks `bx` in the words
    /// `rows[by * w..]`, `w = blocks_x.div_ceil(64)` (bit `bx % 64` of word `bx / 64`),
    /// column `bx`'s blocks `by` likewise in `cols`; so that the sweep's ring walk visits
    /// only those (one branch per set bit and per row or column instead of one per block).
    pub rows: Vec<u64>,
    pub cols: Vec<u64>,
}

/// At most this many runs per map (the real tracks of `shared/maps` have 20-41 thousand):
/// a map with more, such as a noise or checkerboard image at the size cap, is marched
/// (the same ranges) rather than let it hold gigabytes while its faces are built (about
/// 40 bytes a run then, 12 kept).
const MAX_RUNS: usize = 2 << 20;

/// At most this many face sets per map: the regions with the most runs get one each, the
/// rest share the last (a superset of each one's faces, which is just as exact).
const MAX_SETS: usize = 16;

/// The wall faces of a map split by the free region they border (see [`FaceSets::new`]).
#[derive(Debug)]
pub(crate) struct FaceSets {
    width: usize,
    /// Per map cell, row-major: the index in `sets` of the faces of its free region (0 on
    /// occupied cells). One byte a cell; empty when there is one set.
    set_of: Vec<u8>,
    sets: Vec<WallFaces>,
}

impl FaceSets {
    /// The faces of a `width x height` row-major occupancy grid, split by the free region
    /// (free cells joined across sides and corners) each borders; `None` when the grid's
    /// coordinates do not fit f32 exactly or it has more than [`MAX_RUNS`] runs (maps far
    /// beyond any real track: the LIDAR then marches).
    ///
    /// A ray from a free cell stays in that cell's region (it passes from cell to cell
    /// across a side or a corner) until it enters an occupied cell, across a face of that
    /// region; a face of any other region lies at least a cell away from the region's
    /// cells, so a ray meets it, if at all, only after that first face. So the region's
    /// faces decide every range from within it, and the others need not be crossed. On a
    /// race track's map, whose walls are drawn as lines with free space on both sides, the
    /// track's region borders half the faces: the outer walls' outer sides belong to the
    /// region around the track, the inner walls' inner sides to the infield's.
    pub(crate) fn new(width: usize, height: usize, occupied: &[bool]) -> Option<FaceSets> {
        const EXACT: usize = 1 << 24;
        if width >= EXACT || height >= EXACT {
            return None;
        }
        let occ = |c: usize, r: usize| occupied[r * width + c];
        // Counted first, so that nothing is held for a map beyond the bound; the spans of
        // free cells are at most one per run and row.
        let mut total = 0;
        for_line_runs(width, height, occ, |_, _, _, _| total += 1);
        for_line_runs(height, width, |y, c| occ(c, y), |_, _, _, _| total += 1);
        if total > MAX_RUNS {
            return None;
        }
        let regions = Regions::new(width, height, occupied);
        let (blocks_x, blocks_y) = (width.div_ceil(BLOCK), height.div_ceil(BLOCK));
        // (key, line, lo, hi, region), key = 4 * block + side.
        let mut runs: Vec<(usize, u32, u32, u32, usize)> = Vec::new();
        // A run on line `line` (x = line if `vertical`, else y = line) along `k0..k1`,
        // whose occupied cells lie after the line if `occupied_after`: its side, its
        // block (that of its occupied cells) and its free cells' region.
        let mut add = |vertical: bool, line: usize, occupied_after: bool, k0: usize, k1: usize| {
            let (plus, minus) = if vertical {
                (PLUS_X, MINUS_X)
            } else {
                (PLUS_Y, MINUS_Y)
            };
            let (side, occupied, free) = if occupied_after {
                (plus, line, line - 1)
            } else {
                (minus, line - 1, line)
            };
            let (bx, by, col, row) = if vertical {
                (occupied / BLOCK, k0 / BLOCK, free, k0)
            } else {
                (k0 / BLOCK, occupied / BLOCK, k0, free)
            };
            let key = 4 * (by * blocks_x + bx) + side;
            let region = regions.of(col, row);
            runs.push((key, line as u32, k0 as u32, k1 as u32, region));
        };
        // Vertical faces on the inner lines x = 1 .. width - 1 (the map's outer border
        // cannot be reached from inside it), runs along y; then horizontal faces on the
        // lines y = 1 .. height - 1, runs along x. A run's free cells are one region's
        // (they are side by side).
        for_line_runs(width, height, occ, |x, after, r0, r1| {
            add(true, x, after, r0, r1)
        });
        for_line_runs(
            height,
            width,
            |y, c| occ(c, y),
            |y, after, c0, c1| add(false, y, after, c0, c1),
        );
        // The regions by their runs, most first (ties by region: the same order on every
        // machine); each of the first MAX_SETS - 1 gets a set, the rest share one.
        let mut count = vec![0usize; regions.count];
        for r in &runs {
            count[r.4] += 1;
        }
        let mut order: Vec<usize> = (0..regions.count).collect();
        order.sort_by_key(|&g| (std::cmp::Reverse(count[g]), g));
        let mut set_of_region = vec![0u8; regions.count];
        for (rank, &g) in order.iter().enumerate() {
            set_of_region[g] = rank.min(MAX_SETS - 1) as u8;
        }
        let sets_len = regions.count.clamp(1, MAX_SETS);
        let sets = (0..sets_len)
            .map(|s| {
                let mine = runs
                    .iter()
                    .filter(|r| usize::from(set_of_region[r.4]) == s)
                    .map(|&(k, l, a, b, _)| (k, l, a, b));
                WallFaces::from_runs(blocks_x, blocks_y, mine)
            })
            .collect();
        // With one set every cell's is the first: no grid.
        let mut set_of = Vec::new();
        if sets_len > 1 {
            set_of.resize(width * height, 0u8);
            for row in 0..height {
                for span in regions.row_start[row]..regions.row_start[row + 1] {
                    let (a, b) = regions.spans[span];
                    let set = set_of_region[regions.region[span]];
                    set_of[row * width + a as usize..row * width + b as usize].fill(set);
                }
            }
        }
        Some(FaceSets {
            width,
            set_of,
            sets,
        })
    }

    /// The faces that decide every range from the free map cell (col, row): those of its
    /// region (and, for a small region, of others too).
    #[inline(always)]
    pub(crate) fn at(&self, col: usize, row: usize) -> &WallFaces {
        if self.set_of.is_empty() {
            return &self.sets[0];
        }
        &self.sets[usize::from(self.set_of[row * self.width + col])]
    }

    /// The bytes these faces hold: the runs (12 bytes each, and three of padding per set),
    /// each set's index of its blocks' runs and bits of its blocks with faces, and the
    /// grid of each cell's set.
    #[cfg(test)]
    pub(crate) fn bytes(&self) -> usize {
        let set = |f: &WallFaces| {
            4 * (f.start.len() + f.line.len() + f.lo.len() + f.hi.len())
                + 8 * (f.rows.len() + f.cols.len())
        };
        self.set_of.len() + self.sets.iter().map(set).sum::<usize>()
    }

    /// Every set, for tests.
    #[cfg(test)]
    pub(crate) fn sets(&self) -> &[WallFaces] {
        &self.sets
    }
}

/// The free regions of an occupancy grid: its free cells joined across sides and corners,
/// found by joining each row's spans of free cells with those of the row below that touch
/// them (union-find over spans, a few per row, rather than a label per cell).
struct Regions {
    /// Per row, its spans `[a, b)` of free cells in `spans[row_start[row]..row_start[row +
    /// 1]]`, and per span its region (`0..count`).
    row_start: Vec<usize>,
    spans: Vec<(u32, u32)>,
    region: Vec<usize>,
    count: usize,
}

impl Regions {
    fn new(width: usize, height: usize, occupied: &[bool]) -> Regions {
        let mut row_start = Vec::with_capacity(height + 1);
        let mut spans = Vec::new();
        for row in occupied.chunks_exact(width).take(height) {
            row_start.push(spans.len());
            let mut c = 0;
            while c < width {
                if row[c] {
                    c += 1;
                    continue;
                }
                let a = c;
                while c < width && !row[c] {
                    c += 1;
                }
                spans.push((a as u32, c as u32));
            }
        }
        row_start.push(spans.len());
        // Union-find over the spans (path halving; the lower index becomes the root).
        let mut parent: Vec<usize> = (0..spans.len()).collect();
        let find = |parent: &mut [usize], mut s: usize| {
            while parent[s] != s {
                parent[s] = parent[parent[s]];
                s = parent[s];
            }
            s
        };
        for row in 1..height {
            let (mut i, i_end) = (row_start[row - 1], row_start[row]);
            let (mut j, j_end) = (i_end, row_start[row + 1]);
            while i < i_end && j < j_end {
                let ((a0, b0), (a1, b1)) = (spans[i], spans[j]);
                // Cells a0..b0 and a1..b1 of adjacent rows touch (across a side or a
                // corner) when neither lies wholly more than one cell past the other.
                if a0 <= b1 && a1 <= b0 {
                    let (ri, rj) = (find(&mut parent, i), find(&mut parent, j));
                    parent[ri.max(rj)] = ri.min(rj);
                }
                if b0 < b1 { i += 1 } else { j += 1 }
            }
        }
        // Regions numbered in the order of their first span.
        let mut number = vec![usize::MAX; spans.len()];
        let mut region = Vec::with_capacity(spans.len());
        let mut count = 0;
        for s in 0..spans.len() {
            let root = find(&mut parent, s);
            if number[root] == usize::MAX {
                number[root] = count;
                count += 1;
            }
            region.push(number[root]);
        }
        Regions {
            row_start,
            spans,
            region,
            count,
        }
    }

    /// The region of the free cell (col, row).
    fn of(&self, col: usize, row: usize) -> usize {
        let spans = &self.spans[self.row_start[row]..self.row_start[row + 1]];
        // The first span ending past col holds it.
        let k = spans.partition_point(|&(_, b)| (b as usize) <= col);
        debug_assert!(k < spans.len() && spans[k].0 as usize <= col);
        self.region[self.row_start[row] + k]
    }
}

impl WallFaces {
    /// The faces of the runs `(key, line, lo, hi)` (key = 4 * block + side), in their
    /// order along each line, on a map of `blocks_x x blocks_y` blocks.
    fn from_runs(
        blocks_x: usize,
        blocks_y: usize,
        runs: impl Iterator<Item = (usize, u32, u32, u32)> + Clone,
    ) -> WallFaces {
        // Counting sort by key (stable: runs keep their order along each line).
        let keys = 4 * blocks_x * blocks_y;
        let mut start = vec![0u32; keys + 1];
        let mut len = 0;
        for (k, ..) in runs.clone() {
            start[k + 1] += 1;
            len += 1;
        }
        for k in 0..keys {
            start[k + 1] += start[k];
        }
        let mut next = start.clone();
        let (mut line, mut lo, mut hi) = (vec![0.0f32; len], vec![0.0f32; len], vec![0.0f32; len]);
        for (k, l, a, b) in runs {
            let i = next[k] as usize;
            next[k] += 1;
            line[i] = l as f32;
            lo[i] = a as f32;
            hi[i] = b as f32;
        }
        // Three dummy runs past the end, so that a block side's runs can be read four at a
        // time (what is computed for the dummies is not used).
        for v in [&mut line, &mut lo, &mut hi] {
            v.extend([0.0; 3]);
        }
        let (rows, cols) = block_bits(blocks_x, blocks_y, &start);
        WallFaces {
            blocks_x,
            blocks_y,
            start,
            line,
            lo,
            hi,
            rows,
            cols,
        }
    }

    /// The blocks `bx` in `x0..=x1` of row `by` that have faces, in increasing order
    /// (`x0 <= x1 < blocks_x`, `by < blocks_y`).
    #[inline(always)]
    pub(crate) fn row_blocks(&self, by: usize, x0: usize, x1: usize) -> SetBits<'_> {
        SetBits::of_line(&self.rows, self.blocks_x, by, x0, x1)
    }

    /// The blocks `by` in `y0..=y1` of column `bx` that have faces, in increasing order
    /// (`y0 <= y1 < blocks_y`, `bx < blocks_x`).
    #[inline(always)]
    pub(crate) fn col_blocks(&self, bx: usize, y0: usize, y1: usize) -> SetBits<'_> {
        SetBits::of_line(&self.cols, self.blocks_y, bx, y0, y1)
    }

    /// The runs of block (bx, by) facing `side`, as a range of run indices.
    #[inline(always)]
    pub(crate) fn runs(&self, bx: usize, by: usize, side: usize) -> std::ops::Range<usize> {
        let k = 4 * (by * self.blocks_x + bx) + side;
        self.start[k] as usize..self.start[k + 1] as usize
    }

    /// Whether block (bx, by) has no faces (the sweep reads [`WallFaces::rows`] and
    /// [`WallFaces::cols`] instead; the tests check those against this).
    #[cfg(test)]
    pub(crate) fn block_empty(&self, bx: usize, by: usize) -> bool {
        let k = 4 * (by * self.blocks_x + bx);
        self.start[k] == self.start[k + 4]
    }
}

/// [`WallFaces::rows`] and [`WallFaces::cols`] of the blocks whose runs `start` (see
/// [`WallFaces::start`]) holds.
pub(crate) fn block_bits(blocks_x: usize, blocks_y: usize, start: &[u32]) -> (Vec<u64>, Vec<u64>) {
    let (row_words, col_words) = (blocks_x.div_ceil(64), blocks_y.div_ceil(64));
    let mut rows = vec![0u64; blocks_y * row_words];
    let mut cols = vec![0u64; blocks_x * col_words];
    for by in 0..blocks_y {
        for bx in 0..blocks_x {
            let k = 4 * (by * blocks_x + bx);
            if start[k] != start[k + 4] {
                rows[by * row_words + bx / 64] |= 1 << (bx % 64);
                cols[bx * col_words + by / 64] |= 1 << (by % 64);
            }
        }
    }
    (rows, cols)
}

/// The set bits at `lo..=hi` of a bit set held in words (bit `i % 64` of word `i / 64`),
/// in increasing order.
pub(crate) struct SetBits<'a> {
    words: &'a [u64],
    /// The word being read, its bits below the next one cleared, and its index.
    bits: u64,
    word: usize,
    /// The last word and its bits at or below `hi`.
    last: usize,
    last_mask: u64,
}

impl<'a> SetBits<'a> {
    /// The set bits at `lo..=hi` of line `line` of `lines` (rows or columns of `len`
    /// bits each, every line in whole words).
    #[inline(always)]
    fn of_line(lines: &'a [u64], len: usize, line: usize, lo: usize, hi: usize) -> Self {
        let w = len.div_ceil(64);
        SetBits::new(&lines[line * w..(line + 1) * w], lo, hi)
    }

    #[inline(always)]
    fn new(words: &'a [u64], lo: usize, hi: usize) -> SetBits<'a> {
        let (word, last) = (lo / 64, hi / 64);
        let last_mask = u64::MAX >> (63 - hi % 64);
        let mut bits = words[word] & (u64::MAX << (lo % 64));
        if word == last {
            bits &= last_mask;
        }
        SetBits {
            words,
            bits,
            word,
            last,
            last_mask,
        }
    }
}

impl Iterator for SetBits<'_> {
    type Item = usize;

    #[inline(always)]
    fn next(&mut self) -> Option<usize> {
        while self.bits == 0 {
            if self.word >= self.last {
                return None;
            }
            self.word += 1;
            self.bits = self.words[self.word];
            if self.word == self.last {
                self.bits &= self.last_mask;
            }
        }
        let i = 64 * self.word + self.bits.trailing_zeros() as usize;
        self.bits &= self.bits - 1;
        Some(i)
    }
}

/// The face runs on the grid lines `1..lines` across a grid `lines` cells across and
/// `len` along: `occ(i, k)` is the occupancy of cell `k` along, `i` across; a face lies
/// on line `i` where cells `i - 1` and `i` differ. Each run of faces alike (the same side
/// occupied) within one block along goes to `run(i, occupied_after, k0, k1)`: line `i`,
/// whether cell `i` is the occupied one, cells `k0..k1` along.
fn for_line_runs(
    lines: usize,
    len: usize,
    occ: impl Fn(usize, usize) -> bool,
    mut run: impl FnMut(usize, bool, usize, usize),
) {
    for i in 1..lines {
        let mut k = 0;
        while k < len {
            let (before, after) = (occ(i - 1, k), occ(i, k));
            if before == after {
                k += 1;
                continue;
            }
            let start = k;
            let block_end = (k / BLOCK + 1) * BLOCK;
            while k < len && k < block_end && occ(i - 1, k) == before && occ(i, k) == after {
                k += 1;
            }
            run(i, after, start, k);
        }
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;

    use super::*;

    /// (side, line, cell along) of every one-cell face of `f`.
    fn unit_faces(f: &WallFaces) -> Vec<(usize, u32, u32)> {
        let mut out = Vec::new();
        for by in 0..f.blocks_y {
            for bx in 0..f.blocks_x {
                for side in [PLUS_X, MINUS_X, PLUS_Y, MINUS_Y] {
                    for i in f.runs(bx, by, side) {
                        for k in f.lo[i] as u32..f.hi[i] as u32 {
                            out.push((side, f.line[i] as u32, k));
                        }
                    }
                }
            }
        }
        out
    }

    #[test]
    fn faces_of_a_small_grid_are_found_with_their_sides_and_runs() {
        // 3 x 3 with the centre occupied: four one-cell faces around it, one region.
        let mut occ = vec![false; 9];
        occ[4] = true;
        let sets = FaceSets::new(3, 3, &occ).unwrap();
        assert_eq!(sets.sets().len(), 1);
        let f = sets.at(0, 0);
        assert_eq!((f.blocks_x, f.blocks_y), (1, 1));
        let get = |side| {
            f.runs(0, 0, side)
                .map(|i| (f.line[i], f.lo[i], f.hi[i]))
                .collect::<Vec<_>>()
        };
        assert_eq!(get(PLUS_X), vec![(1.0, 1.0, 2.0)]);
        assert_eq!(get(MINUS_X), vec![(2.0, 1.0, 2.0)]);
        assert_eq!(get(PLUS_Y), vec![(1.0, 1.0, 2.0)]);
        assert_eq!(get(MINUS_Y), vec![(2.0, 1.0, 2.0)]);
    }

    #[test]
    fn runs_merge_along_a_wall_and_are_cut_at_block_borders() {
        // A wall along column 5 of a grid 10 wide and two blocks and 6 cells high: one +x
        // run per block row for the region left of it, one -x run for the region right.
        let (w, h) = (10, 2 * BLOCK + 6);
        let occ: Vec<bool> = (0..w * h).map(|i| i % w == 5).collect();
        let sets = FaceSets::new(w, h, &occ).unwrap();
        assert_eq!(sets.sets().len(), 2);
        let b = BLOCK as f32;
        for (by, (lo, hi)) in [(0.0, b), (b, 2.0 * b), (2.0 * b, h as f32)]
            .into_iter()
            .enumerate()
        {
            for (col, side, line) in [(0, PLUS_X, 5.0), (9, MINUS_X, 6.0)] {
                let f = sets.at(col, by * BLOCK);
                assert_eq!((f.blocks_x, f.blocks_y), (1, 3));
                let r = f.runs(0, by, side);
                assert_eq!(r.len(), 1, "block row {by} side {side}");
                assert_eq!(
                    (f.line[r.start], f.lo[r.start], f.hi[r.start]),
                    (line, lo, hi)
                );
                let other = if side == PLUS_X { MINUS_X } else { PLUS_X };
                assert!(f.runs(0, by, other).is_empty());
                assert!(f.runs(0, by, PLUS_Y).is_empty() && f.runs(0, by, MINUS_Y).is_empty());
                assert!(!f.block_empty(0, by));
            }
        }
        // A checkerboard 2048 cells across: every face a run of its own, more than the
        // bound, so no faces (the LIDAR marches), and at the bound still built.
        let side = 2048;
        let board: Vec<bool> = (0..side * side)
            .map(|i| (i % side + i / side) % 2 == 1)
            .collect();
        assert!(FaceSets::new(side, side, &board).is_none());
        let rows = MAX_RUNS / (2 * side - 1);
        let board: Vec<bool> = (0..side * rows)
            .map(|i| (i % side + i / side) % 2 == 1)
            .collect();
        assert!(FaceSets::new(side, rows, &board).is_some());
        let empty = FaceSets::new(4, 4, &[false; 16]).unwrap();
        assert!(empty.at(2, 2).block_empty(0, 0) && empty.at(2, 2).line.len() == 3);
        let full = FaceSets::new(4, 4, &[true; 16]).unwrap();
        assert_eq!(full.sets().len(), 1);
        assert!(full.sets()[0].block_empty(0, 0));
    }

    #[test]
    fn one_set_keeps_no_grid_and_the_memory_is_bounded() {
        // A ring wall inside a 300 x 200 map: two regions, a grid of one byte a cell.
        let (w, h) = (300, 200);
        let ring = |c: usize, r: usize| {
            let (x, y) = (c as f64 - 150.0, r as f64 - 100.0);
            let d = (x * x / 4.0 + y * y).sqrt();
            (60.0..63.0).contains(&d)
        };
        let occ: Vec<bool> = (0..w * h).map(|i| ring(i % w, i / w)).collect();
        let sets = FaceSets::new(w, h, &occ).unwrap();
        assert_eq!(sets.sets().len(), 2);
        let runs: usize = sets.sets().iter().map(|f| f.line.len() - 3).sum();
        let (bw, bh) = (w.div_ceil(BLOCK), h.div_ceil(BLOCK));
        let index = 4 * (4 * bw * bh + 1) + 8 * (bh * bw.div_ceil(64) + bw * bh.div_ceil(64));
        assert_eq!(sets.bytes(), w * h + 12 * (runs + 6) + 2 * index);
        assert!(!std::ptr::eq(sets.at(150, 100), sets.at(0, 0)));
        // The same wall cut in two arcs: one region, no grid.
        let occ: Vec<bool> = (0..w * h)
            .map(|i| ring(i % w, i / w) && !(140..160).contains(&(i % w)))
            .collect();
        let sets = FaceSets::new(w, h, &occ).unwrap();
        assert_eq!(sets.sets().len(), 1);
        assert!(std::ptr::eq(sets.at(150, 100), sets.at(0, 0)));
        let runs = sets.sets()[0].line.len() - 3;
        assert_eq!(sets.bytes(), 12 * (runs + 3) + index);
    }

    #[test]
    fn the_blocks_with_faces_are_found_by_row_and_by_column() {
        // 70 x 130 blocks (two words per row, three per column), about one block in
        // five with faces.
        let (bw, bh) = (70, 130);
        let mut rng = crate::rng::Rng::new(5);
        let mut start = vec![0u32; 4 * bw * bh + 1];
        for k in 0..4 * bw * bh {
            start[k + 1] = start[k] + u32::from(rng.below(20) == 0);
        }
        let (rows, cols) = block_bits(bw, bh, &start);
        let f = WallFaces {
            blocks_x: bw,
            blocks_y: bh,
            start,
            line: vec![],
            lo: vec![],
            hi: vec![],
            rows,
            cols,
        };
        for _ in 0..3000 {
            let (by, bx) = (rng.below(bh as u64) as usize, rng.below(bw as u64) as usize);
            let (a, b) = (rng.below(bw as u64) as usize, rng.below(bw as u64) as usize);
            let (x0, x1) = (a.min(b), a.max(b));
            let want: Vec<usize> = (x0..=x1).filter(|&x| !f.block_empty(x, by)).collect();
            assert_eq!(
                f.row_blocks(by, x0, x1).collect::<Vec<_>>(),
                want,
                "row {by}, {x0}..={x1}"
            );
            let (a, b) = (rng.below(bh as u64) as usize, rng.below(bh as u64) as usize);
            let (y0, y1) = (a.min(b), a.max(b));
            let want: Vec<usize> = (y0..=y1).filter(|&y| !f.block_empty(bx, y)).collect();
            assert_eq!(
                f.col_blocks(bx, y0, y1).collect::<Vec<_>>(),
                want,
                "column {bx}, {y0}..={y1}"
            );
        }
        // whole rows and columns, and the ends of words
        for by in 0..bh {
            let want: Vec<usize> = (0..bw).filter(|&x| !f.block_empty(x, by)).collect();
            assert_eq!(f.row_blocks(by, 0, bw - 1).collect::<Vec<_>>(), want);
            for x in [0, 63, 64, bw - 1] {
                let got: Vec<usize> = f.row_blocks(by, x, x).collect();
                assert_eq!(got.is_empty(), f.block_empty(x, by));
            }
        }
        for bx in 0..bw {
            let want: Vec<usize> = (0..bh).filter(|&y| !f.block_empty(bx, y)).collect();
            assert_eq!(f.col_blocks(bx, 0, bh - 1).collect::<Vec<_>>(), want);
        }
    }

    /// The free regions of a grid by a flood fill across sides and corners: per cell its
    /// region (usize::MAX on occupied cells), and the number of regions.
    fn flood(w: usize, h: usize, occ: &[bool]) -> (Vec<usize>, usize) {
        let mut region = vec![usize::MAX; w * h];
        let mut count = 0;
        for start in 0..w * h {
            if occ[start] || region[start] != usize::MAX {
                continue;
            }
            region[start] = count;
            let mut stack = vec![start];
            while let Some(c) = stack.pop() {
                let (x, y) = ((c % w) as isize, (c / w) as isize);
                for (dx, dy) in (-1..=1).flat_map(|dx| (-1..=1).map(move |dy| (dx, dy))) {
                    let (nx, ny) = (x + dx, y + dy);
                    if nx < 0 || ny < 0 || nx >= w as isize || ny >= h as isize {
                        continue;
                    }
                    let n = ny as usize * w + nx as usize;
                    if !occ[n] && region[n] == usize::MAX {
                        region[n] = count;
                        stack.push(n);
                    }
                }
            }
            count += 1;
        }
        (region, count)
    }

    #[test]
    fn each_free_cell_gets_every_face_of_its_region_and_each_face_is_kept_once() {
        let mut rng = crate::rng::Rng::new(3);
        for trial in 0..60 {
            // Small grids with many regions (more than MAX_SETS: pockets share a set), and
            // grids across several blocks with few.
            let (w, h, density) = if trial % 3 == 0 {
                (
                    150 + rng.below(40) as usize,
                    70 + rng.below(80) as usize,
                    0.2,
                )
            } else {
                (5 + rng.below(40) as usize, 5 + rng.below(40) as usize, 0.5)
            };
            let occ: Vec<bool> = (0..w * h)
                .map(|_| rng.uniform_range(0.0, 1.0) < density)
                .collect();
            let (region, count) = flood(w, h, &occ);
            // Every face by the region of its free cell.
            let mut want: Vec<BTreeSet<(usize, u32, u32)>> = vec![BTreeSet::new(); count];
            for r in 0..h {
                for x in 1..w {
                    let (a, b) = (occ[r * w + x - 1], occ[r * w + x]);
                    if a != b {
                        let (side, free) = if b { (PLUS_X, x - 1) } else { (MINUS_X, x) };
                        want[region[r * w + free]].insert((side, x as u32, r as u32));
                    }
                }
            }
            for y in 1..h {
                for c in 0..w {
                    let (a, b) = (occ[(y - 1) * w + c], occ[y * w + c]);
                    if a != b {
                        let (side, free) = if b { (PLUS_Y, y - 1) } else { (MINUS_Y, y) };
                        want[region[free * w + c]].insert((side, y as u32, c as u32));
                    }
                }
            }
            let sets = FaceSets::new(w, h, &occ).unwrap();
            assert_eq!(sets.sets().len(), count.clamp(1, MAX_SETS), "trial {trial}");
            let got: Vec<BTreeSet<_>> = sets
                .sets()
                .iter()
                .map(|f| unit_faces(f).into_iter().collect())
                .collect();
            // Each face in exactly one set.
            let total: usize = got.iter().map(BTreeSet::len).sum();
            let all: BTreeSet<_> = want.iter().flatten().copied().collect();
            assert_eq!(total, all.len(), "trial {trial}");
            assert_eq!(got.iter().flatten().copied().collect::<BTreeSet<_>>(), all);
            let mut checked = BTreeSet::new();
            for (cell, &g) in region.iter().enumerate() {
                if g == usize::MAX {
                    continue;
                }
                let set = sets.at(cell % w, cell / w);
                let k = sets
                    .sets()
                    .iter()
                    .position(|s| std::ptr::eq(s, set))
                    .unwrap();
                if !checked.insert((g, k)) {
                    continue;
                }
                assert!(got[k].is_superset(&want[g]), "trial {trial} cell {cell}");
                if count <= MAX_SETS {
                    assert_eq!(got[k], want[g], "trial {trial} cell {cell}");
                }
            }
        }
    }
}
