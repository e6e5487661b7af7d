//! The map's wall faces: every cell side between a free and an occupied cell of the map,
//! merged into straight runs and binned into square blocks of cells, for the LIDAR's
//! angular sweep (`lidar::sweep`).
//!
//! A face is kept with the side it faces, since a ray can only meet a face from the free
//! side: a vertical face on the line x = X with the occupied cell at column X is met by
//! rays going +x, with the occupied cell at X - 1 by rays going -x; horizontal faces
//! likewise. Consecutive faces of one kind on one grid line make a run `[lo, hi]` along
//! the line; runs are cut at block borders, so each run lies inside its block (the block
//! of its occupied cells), and a block's runs are stored together per side.

/// Cells per side of a block. 64 rather than 32: fewer blocks to walk and cull per scan
/// for a few more runs to cross (measured on the sweep, docs/performance-scan.md).
pub(crate) const BLOCK: usize = 64;

/// The side a face faces, as the index of its runs within a block: the face is met by
/// rays going +x (`PLUS_X`: occupied cell on the larger-x side), -x, +y or -y.
pub(crate) const PLUS_X: usize = 0;
pub(crate) const MINUS_X: usize = 1;
pub(crate) const PLUS_Y: usize = 2;
pub(crate) const MINUS_Y: usize = 3;

/// The wall faces of a map in runs, by block and side (see the module doc).
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
}

impl WallFaces {
    /// The faces of a `width x height` row-major occupancy grid; `None` when the grid's
    /// coordinates do not fit f32 exactly or the run count u32 (maps far beyond any real
    /// track: the LIDAR then marches).
    pub(crate) fn new(width: usize, height: usize, occupied: &[bool]) -> Option<WallFaces> {
        const EXACT: usize = 1 << 24;
        if width >= EXACT || height >= EXACT {
            return None;
        }
        let occ = |c: usize, r: usize| occupied[r * width + c];
        let (blocks_x, blocks_y) = (width.div_ceil(BLOCK), height.div_ceil(BLOCK));
        // (key, line, lo, hi), key = 4 * block + side.
        let mut runs: Vec<(usize, u32, u32, u32)> = Vec::new();
        let key = |bx: usize, by: usize, side: usize| 4 * (by * blocks_x + bx) + side;
        // Vertical faces on the inner lines x = 1 .. width - 1 (the map's outer border
        // cannot be reached from inside it), runs along y; then horizontal faces on the
        // lines y = 1 .. height - 1, runs along x.
        for_line_runs(width, height, occ, |x, occupied_after, r0, r1| {
            let side = if occupied_after { PLUS_X } else { MINUS_X };
            let bx = if occupied_after { x } else { x - 1 } / BLOCK;
            runs.push((key(bx, r0 / BLOCK, side), x as u32, r0 as u32, r1 as u32));
        });
        for_line_runs(
            height,
            width,
            |y, c| occ(c, y),
            |y, occupied_after, c0, c1| {
                let side = if occupied_after { PLUS_Y } else { MINUS_Y };
                let by = if occupied_after { y } else { y - 1 } / BLOCK;
                runs.push((key(c0 / BLOCK, by, side), y as u32, c0 as u32, c1 as u32));
            },
        );
        if runs.len() >= u32::MAX as usize {
            return None;
        }
        // Counting sort by key (stable: runs keep their order along each line).
        let keys = 4 * blocks_x * blocks_y;
        let mut start = vec![0u32; keys + 1];
        for &(k, ..) in &runs {
            start[k + 1] += 1;
        }
        for k in 0..keys {
            start[k + 1] += start[k];
        }
        let mut next = start.clone();
        let (mut line, mut lo, mut hi) = (
            vec![0.0f32; runs.len()],
            vec![0.0f32; runs.len()],
            vec![0.0f32; runs.len()],
        );
        for &(k, l, a, b) in &runs {
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
        Some(WallFaces {
            blocks_x,
            blocks_y,
            start,
            line,
            lo,
            hi,
        })
    }

    /// The runs of block (bx, by) facing `side`, as a range of run indices.
    #[inline(always)]
    pub(crate) fn runs(&self, bx: usize, by: usize, side: usize) -> std::ops::Range<usize> {
        let k = 4 * (by * self.blocks_x + bx) + side;
        self.start[k] as usize..self.start[k + 1] as usize
    }

    /// Whether block (bx, by) has no faces.
    #[inline(always)]
    pub(crate) fn block_empty(&self, bx: usize, by: usize) -> bool {
        let k = 4 * (by * self.blocks_x + bx);
        self.start[k] == self.start[k + 4]
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
    use super::*;

    #[test]
    fn faces_of_a_small_grid_are_found_with_their_sides_and_runs() {
        // 3 x 3 with the centre occupied: four one-cell faces around it.
        let mut occ = vec![false; 9];
        occ[4] = true;
        let f = WallFaces::new(3, 3, &occ).unwrap();
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
        // and one -x run per block row.
        let (w, h) = (10, 2 * BLOCK + 6);
        let occ: Vec<bool> = (0..w * h).map(|i| i % w == 5).collect();
        let f = WallFaces::new(w, h, &occ).unwrap();
        assert_eq!((f.blocks_x, f.blocks_y), (1, 3));
        let b = BLOCK as f32;
        for (by, (lo, hi)) in [(0.0, b), (b, 2.0 * b), (2.0 * b, h as f32)]
            .into_iter()
            .enumerate()
        {
            for (side, line) in [(PLUS_X, 5.0), (MINUS_X, 6.0)] {
                let r = f.runs(0, by, side);
                assert_eq!(r.len(), 1, "block row {by} side {side}");
                assert_eq!(
                    (f.line[r.start], f.lo[r.start], f.hi[r.start]),
                    (line, lo, hi)
                );
            }
            assert!(f.runs(0, by, PLUS_Y).is_empty() && f.runs(0, by, MINUS_Y).is_empty());
        }
        assert!(!f.block_empty(0, 2));
        let empty = WallFaces::new(4, 4, &[false; 16]).unwrap();
        assert!(empty.block_empty(0, 0) && empty.line.len() == 3);
    }
}
