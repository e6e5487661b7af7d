//! Occupancy-grid maps: ROS map_server YAML + PNG/PGM, immutable once built.
//!
//! A [`Map`] holds the occupancy grid (row 0 = the image's bottom row, i.e. the map
//! origin side), its resolution and origin pose, and three acceleration structures:
//! - four quadrant clearances per cell (the side of the largest all-free square with
//!   that cell as one corner, one table per corner direction), built eagerly in one pass
//!   each: the LIDAR jumps across the square ahead of a ray, which in a corridor is far
//!   larger than the square centred on the ray's cell (that one is limited by the wall
//!   beside or behind it), and their minimum is the Chebyshev clearance that
//!   [`Map::clearance`] reads;
//! - the exact Euclidean distance transform ([`Map::distance_field`]), built on first
//!   use, needed only by the reference (f1tenth_gym) scan mode;
//! - the wall faces in straight runs by 64 x 64-cell block and facing side (`faces`),
//!   built on first use by the LIDAR's angular sweep (12 bytes per run and 16 per block:
//!   about 0.3 MiB for a 2000 x 2000-cell race track with 20,000 runs).
//!
//! A map is a plain value: nothing here keeps maps beyond the values a caller holds (a
//! [`crate::circuit::Circuits`] registry is how a program loads each map once).

mod edt;
pub(crate) mod faces;
mod load;

use std::sync::OnceLock;

use crate::geometry::Pose;

pub use load::{
    MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE, MapError, OccupancyRule, bundle_image_name, decode_image,
    image_dimensions,
};

/// The largest quadrant clearance stored per cell (saturating; a capped value is a
/// lower bound, so everything that reads it stays exact or conservative).
pub(crate) const CLEARANCE_MAX: u8 = u8::MAX;

/// An occupancy-grid map. Immutable after construction; `Send + Sync`.
#[derive(Debug)]
pub struct Map {
    name: String,
    width: usize,
    height: usize,
    resolution: f64,
    origin: Pose,
    /// cos and sin of the origin yaw (libm), cached for the frame transforms.
    origin_cos: f64,
    origin_sin: f64,
    occupied: Vec<bool>,
    /// Quadrant clearances on the grid padded with one cell on every side, row-major
    /// `(width + 2) x (height + 2)`, four bytes per cell (one cache line holds all four
    /// quadrants of a cell): quadrant `quad` of map cell (c, r) at
    /// `4 * ((r + 1) * (width + 2) + c + 1) + quad`. Quadrant `(x_neg as usize) | (y_neg as usize) << 1` holds, per cell, the
    /// side `q` of the largest all-free square `[c, c + (q-1) sx] x [r, r + (q-1) sy]`
    /// (`sx = -1` if `x_neg` else 1, likewise `sy`), saturated at [`CLEARANCE_MAX`]; 0 on
    /// occupied cells and on the padding (the map border counts as a wall here). So a
    /// ray jumping across such squares never leaves the padded grid. The minimum over the
    /// four quadrants is the Chebyshev clearance: the cell is then the centre of an
    /// all-free `(2q-1) x (2q-1)` block.
    quadrants: Vec<u8>,
    content_hash: OnceLock<u64>,
    distance_field: OnceLock<Vec<f64>>,
    /// The wall faces for the LIDAR's angular sweep, built on first use (`None`: the map
    /// is too large for them, see [`faces::FaceSets::new`]).
    wall_faces: OnceLock<Option<faces::FaceSets>>,
}

impl Map {
    /// A map from a row-major occupancy grid (`occupied[row * width + col]`, row 0 at the
    /// origin side). `resolution` is metres per cell; `origin` is the pose of the corner of
    /// cell (0, 0) in the world frame (ROS map_server convention, yaw honoured).
    pub fn from_grid(
        name: &str,
        width: usize,
        height: usize,
        resolution: f64,
        origin: Pose,
        occupied: Vec<bool>,
    ) -> Result<Map, MapError> {
        let bad = |reason: String| MapError::InvalidGrid {
            name: name.to_string(),
            reason,
        };
        if width == 0 || height == 0 {
            return Err(bad(format!("empty grid {width} x {height}")));
        }
        if width > i32::MAX as usize / 2 || height > i32::MAX as usize / 2 {
            return Err(bad(format!("grid {width} x {height} is too large")));
        }
        let cells = width
            .checked_mul(height)
            .ok_or_else(|| bad(format!("grid {width} x {height} is too large")))?;
        if occupied.len() != cells {
            return Err(bad(format!(
                "occupancy has {} cells, expected width {width} x height {height} = {cells}",
                occupied.len()
            )));
        }
        if !(resolution.is_finite() && resolution > 0.0) {
            return Err(bad(format!(
                "resolution {resolution} is not a positive finite number"
            )));
        }
        if !(origin.x.is_finite() && origin.y.is_finite() && origin.theta.is_finite()) {
            return Err(bad(format!(
                "origin ({}, {}, {}) is not finite",
                origin.x, origin.y, origin.theta
            )));
        }
        let quadrants = quadrant_clearance(width, height, &occupied);
        Ok(Map {
            name: name.to_string(),
            width,
            height,
            resolution,
            origin,
            origin_cos: libm::cos(origin.theta),
            origin_sin: libm::sin(origin.theta),
            occupied,
            quadrants,
            content_hash: OnceLock::new(),
            distance_field: OnceLock::new(),
            wall_faces: OnceLock::new(),
        })
    }

    pub fn name(&self) -> &str {
        &self.name
    }
    /// Metres per cell.
    pub fn resolution(&self) -> f64 {
        self.resolution
    }
    /// Pose of the outer corner of cell (0, 0) in the world frame.
    pub fn origin(&self) -> Pose {
        self.origin
    }
    /// Columns.
    pub fn width(&self) -> usize {
        self.width
    }
    /// Rows.
    pub fn height(&self) -> usize {
        self.height
    }

    /// FNV-1a (64 bit) over, in order: width and height (u64 little-endian), the bits of
    /// resolution, origin x, y and yaw (u64 little-endian each), then one byte per cell
    /// (1 = occupied, 0 = free) in row-major order, row 0 first. Independent of the file
    /// the map came from, so maps can be shipped and compared by hash.
    /// Computed on first use and kept.
    pub fn content_hash(&self) -> u64 {
        *self.content_hash.get_or_init(|| {
            hash_grid(
                self.width,
                self.height,
                self.resolution,
                self.origin,
                &self.occupied,
            )
        })
    }

    /// World (x, y) in metres to continuous grid coordinates (col, row) in cells: cell
    /// (c, r) covers [c, c+1) x [r, r+1). The origin yaw is applied.
    #[inline]
    pub fn world_to_grid(&self, x: f64, y: f64) -> (f64, f64) {
        let (dx, dy) = (x - self.origin.x, y - self.origin.y);
        let xr = self.origin_cos * dx + self.origin_sin * dy;
        let yr = -self.origin_sin * dx + self.origin_cos * dy;
        (xr / self.resolution, yr / self.resolution)
    }

    /// Inverse of [`Map::world_to_grid`].
    #[inline]
    pub fn grid_to_world(&self, gx: f64, gy: f64) -> (f64, f64) {
        let (xr, yr) = (gx * self.resolution, gy * self.resolution);
        (
            self.origin.x + self.origin_cos * xr - self.origin_sin * yr,
            self.origin.y + self.origin_sin * xr + self.origin_cos * yr,
        )
    }

    /// Whether cell (col, row) is occupied; off-map cells are free.
    #[inline]
    pub fn cell_occupied(&self, col: i64, row: i64) -> bool {
        if col < 0 || row < 0 || col >= self.width as i64 || row >= self.height as i64 {
            return false;
        }
        self.occupied[row as usize * self.width + col as usize]
    }

    /// Whether the world point (x, y) lies in an occupied cell.
    pub fn occupied_at(&self, x: f64, y: f64) -> bool {
        let (gx, gy) = self.world_to_grid(x, y);
        if !(gx.is_finite() && gy.is_finite()) {
            return false;
        }
        self.cell_occupied(libm::floor(gx) as i64, libm::floor(gy) as i64)
    }

    /// A conservative lower bound (metres) on the distance from (x, y) to the nearest
    /// occupied cell square; 0 inside an occupied cell. From the Chebyshev clearance:
    /// the point's cell is the centre of an all-free square block, and the distance to
    /// that block's border bounds the distance to any occupied cell. O(1).
    pub fn clearance(&self, x: f64, y: f64) -> f64 {
        let (gx, gy) = self.world_to_grid(x, y);
        if !(gx.is_finite() && gy.is_finite()) {
            return 0.0;
        }
        let (w, h) = (self.width as f64, self.height as f64);
        if gx < 0.0 || gy < 0.0 || gx >= w || gy >= h {
            // Every occupied cell lies inside the map rectangle.
            let ex = (-gx).max(gx - w).max(0.0);
            let ey = (-gy).max(gy - h).max(0.0);
            return libm::hypot(ex, ey) * self.resolution;
        }
        let (c, r) = (gx as usize, gy as usize);
        let v = self.chebyshev_at(c, r);
        if v == 0 {
            return 0.0;
        }
        let k = f64::from(v - 1);
        let (fx, fy) = (gx - c as f64, gy - r as f64);
        let m = (k + fx).min(k + 1.0 - fx).min(k + fy).min(k + 1.0 - fy);
        m.max(0.0) * self.resolution
    }

    /// The exact Euclidean distance transform, row-major like the grid: for each cell the
    /// distance in metres from its centre to the nearest occupied cell centre (0 on
    /// occupied cells), i.e. `scipy.ndimage.distance_transform_edt(free) * resolution`;
    /// `f64::INFINITY` everywhere if no cell is occupied. Computed on first use (O(N),
    /// Felzenszwalb-Huttenlocher) and kept.
    pub fn distance_field(&self) -> &[f64] {
        self.distance_field.get_or_init(|| {
            let d2 = edt::squared_edt(self.width, self.height, &self.occupied);
            d2.into_iter()
                .map(|v| {
                    if v == u64::MAX {
                        f64::INFINITY
                    } else {
                        self.resolution * libm::sqrt(v as f64)
                    }
                })
                .collect()
        })
    }

    /// Row-major occupancy, row 0 at the origin side.
    pub fn occupancy(&self) -> &[bool] {
        &self.occupied
    }

    /// The padded quadrant clearances, four bytes per cell (see the field doc); for the
    /// LIDAR.
    #[inline]
    pub(crate) fn quadrant_clearance(&self) -> &[u8] {
        &self.quadrants
    }

    /// The wall faces in runs by block and side, by the free region they border (built on
    /// first use; `None` for maps too large for them); for the LIDAR.
    #[inline]
    pub(crate) fn wall_faces(&self) -> Option<&faces::FaceSets> {
        // Built out of line: once per map, and kept out of the scan's code.
        #[cold]
        #[inline(never)]
        fn build(map: &Map) -> Option<faces::FaceSets> {
            faces::FaceSets::new(map.width, map.height, &map.occupied)
        }
        self.wall_faces.get_or_init(|| build(self)).as_ref()
    }

    /// The Chebyshev clearance of map cell (c, r): the minimum of its four quadrant
    /// clearances (each quadrant square of that side is free, and together they make the
    /// centred block; conversely the centred block contains each of them).
    fn chebyshev_at(&self, c: usize, r: usize) -> u8 {
        let i = 4 * ((r + 1) * (self.width + 2) + c + 1);
        let q = &self.quadrants[i..i + 4];
        q[0].min(q[1]).min(q[2]).min(q[3])
    }
}

/// The four quadrant clearance tables (see `Map::quadrants`), each by the largest-square
/// recurrence `q = 0` if occupied, else `1 + min(q(c+sx, r), q(c, r+sy), q(c+sx, r+sy))`,
/// saturating at [`CLEARANCE_MAX`], swept from the far corner. The padding is 0.
fn quadrant_clearance(w: usize, h: usize, occupied: &[bool]) -> Vec<u8> {
    let wp = w + 2;
    let n = wp * (h + 2);
    let mut q = vec![0u8; 4 * n];
    // Written with plain index loops: maps load in debug builds (tests) too, where
    // closures and iterator adaptors are not inlined.
    for quad in 0..4 {
        let (x_neg, y_neg) = (quad & 1 != 0, quad & 2 != 0);
        for i in 0..h {
            // Padded row r, swept away from its neighbour row (already done).
            let r = if y_neg { 1 + i } else { h - i };
            let (row, prev) = if y_neg {
                let (done, rest) = q.split_at_mut(4 * r * wp);
                (&mut rest[..4 * wp], &done[4 * (r - 1) * wp..])
            } else {
                let (rest, done) = q.split_at_mut(4 * (r + 1) * wp);
                (&mut rest[4 * r * wp..], &done[..4 * wp])
            };
            let src = &occupied[(r - 1) * w..r * w];
            for j in 0..w {
                let c = if x_neg { 1 + j } else { w - j };
                let nc = if x_neg { c - 1 } else { c + 1 };
                let (at, next) = (4 * c + quad, 4 * nc + quad);
                row[at] = if src[c - 1] {
                    0
                } else {
                    let m = row[next].min(prev[at]).min(prev[next]);
                    if m == CLEARANCE_MAX { m } else { m + 1 }
                };
            }
        }
    }
    q
}

fn hash_grid(w: usize, h: usize, resolution: f64, origin: Pose, occupied: &[bool]) -> u64 {
    const OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
    const PRIME: u64 = 0x0000_0100_0000_01b3;
    let mut hash = OFFSET;
    let mut feed = |bytes: &[u8]| {
        for &b in bytes {
            hash ^= u64::from(b);
            hash = hash.wrapping_mul(PRIME);
        }
    };
    feed(&(w as u64).to_le_bytes());
    feed(&(h as u64).to_le_bytes());
    for v in [resolution, origin.x, origin.y, origin.theta] {
        feed(&v.to_bits().to_le_bytes());
    }
    for &o in occupied {
        feed(&[u8::from(o)]);
    }
    hash
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(w: usize, h: usize, occ: &[(usize, usize)]) -> Map {
        let mut g = vec![false; w * h];
        for &(c, r) in occ {
            g[r * w + c] = true;
        }
        Map::from_grid("t", w, h, 0.1, Pose::new(0.0, 0.0, 0.0), g).unwrap()
    }

    #[test]
    fn map_is_send_and_sync() {
        fn check<T: Send + Sync>() {}
        check::<Map>();
        check::<std::sync::Arc<Map>>();
    }

    #[test]
    fn chebyshev_matches_brute_force() {
        let mut rng = crate::rng::Rng::new(5);
        let (w, h) = (23, 17);
        let occ: Vec<(usize, usize)> = (0..12)
            .map(|_| (rng.below(w as u64) as usize, rng.below(h as u64) as usize))
            .collect();
        let m = grid(w, h, &occ);
        for r in 0..h {
            for c in 0..w {
                let (ci, ri) = (c as i64, r as i64);
                let border = (ci + 1).min(ri + 1).min(w as i64 - ci).min(h as i64 - ri);
                let brute = occ
                    .iter()
                    .map(|&(oc, or)| (oc as i64 - ci).abs().max((or as i64 - ri).abs()))
                    .min()
                    .unwrap()
                    .min(border);
                let got = m.chebyshev_at(c, r);
                assert_eq!(i64::from(got), brute, "cell {c},{r}");
            }
        }
    }

    /// Every quadrant table holds the largest free square with the cell as its corner,
    /// the map border counting as a wall, and 0 on occupied cells and the padding.
    #[test]
    fn quadrant_clearance_matches_brute_force() {
        let mut rng = crate::rng::Rng::new(11);
        let (w, h) = (29, 19);
        let occ: Vec<(usize, usize)> = (0..25)
            .map(|_| (rng.below(w as u64) as usize, rng.below(h as u64) as usize))
            .collect();
        let m = grid(w, h, &occ);
        let q = m.quadrant_clearance();
        let free = |c: i64, r: i64| {
            c >= 0 && r >= 0 && c < w as i64 && r < h as i64 && !m.cell_occupied(c, r)
        };
        for quad in 0..4usize {
            let sx = if quad & 1 != 0 { -1 } else { 1 };
            let sy = if quad & 2 != 0 { -1 } else { 1 };
            for r in -1..=h as i64 {
                for c in -1..=w as i64 {
                    let square_free =
                        |k: i64| (0..=k).all(|i| (0..=k).all(|j| free(c + i * sx, r + j * sy)));
                    let mut side = 0;
                    while square_free(side) {
                        side += 1;
                    }
                    let got = q[4 * ((r + 1) * (w as i64 + 2) + c + 1) as usize + quad];
                    assert_eq!(i64::from(got), side, "quadrant {quad} cell {c},{r}");
                }
            }
        }
    }

    #[test]
    fn quadrant_clearance_saturates() {
        let m = grid(300, 3, &[]);
        let q = m.quadrant_clearance();
        // Only three rows: the square is limited by the height, never above 3.
        assert_eq!(q[4 * ((1 + 1) * 302 + 1)], 2);
        let big = grid(270, 270, &[]);
        let q2 = big.quadrant_clearance();
        assert_eq!(q2[4 * (272 + 1)], CLEARANCE_MAX);
        assert_eq!(q2[4 * (270 * 272 + 270) + 3], CLEARANCE_MAX);
        assert_eq!(q2[4 * (272 + 1) + 3], 1);
    }

    #[test]
    fn clearance_is_a_lower_bound() {
        let m = grid(30, 30, &[(10, 10), (20, 5), (3, 25)]);
        let mut rng = crate::rng::Rng::new(9);
        for _ in 0..2000 {
            let (x, y) = (rng.uniform_range(-1.0, 4.0), rng.uniform_range(-1.0, 4.0));
            let cl = m.clearance(x, y);
            let exact = [(10, 10), (20, 5), (3, 25)]
                .iter()
                .map(|&(c, r)| {
                    let (x0, y0) = (c as f64 * 0.1, r as f64 * 0.1);
                    let ex = (x0 - x).max(x - (x0 + 0.1)).max(0.0);
                    let ey = (y0 - y).max(y - (y0 + 0.1)).max(0.0);
                    libm::hypot(ex, ey)
                })
                .fold(f64::INFINITY, f64::min);
            assert!(cl <= exact + 1e-12, "({x},{y}) clearance {cl} > {exact}");
        }
        assert_eq!(m.clearance(1.05, 1.05), 0.0);
    }

    #[test]
    fn edt_matches_brute_force() {
        let occ = [(2, 3), (10, 1), (7, 7), (0, 8)];
        let m = grid(12, 9, &occ);
        let df = m.distance_field();
        for r in 0..9 {
            for c in 0..12 {
                let best = occ
                    .iter()
                    .map(|&(oc, or)| {
                        let (a, b) = (oc as i64 - c as i64, or as i64 - r as i64);
                        (a * a + b * b) as f64
                    })
                    .fold(f64::INFINITY, f64::min);
                assert_eq!(df[r * 12 + c], 0.1 * libm::sqrt(best));
            }
        }
        let empty = grid(4, 4, &[]);
        assert!(empty.distance_field().iter().all(|d| d.is_infinite()));
    }

    #[test]
    fn yaw_round_trip_and_hash() {
        let mut g = vec![false; 20 * 10];
        g[3 * 20 + 5] = true;
        let m = Map::from_grid("y", 20, 10, 0.5, Pose::new(1.0, 2.0, 0.7), g.clone()).unwrap();
        let (x, y) = m.grid_to_world(5.5, 3.5);
        assert!(m.occupied_at(x, y));
        let (gx, gy) = m.world_to_grid(x, y);
        assert!((gx - 5.5).abs() < 1e-12 && (gy - 3.5).abs() < 1e-12);
        let m2 = Map::from_grid("other name", 20, 10, 0.5, Pose::new(1.0, 2.0, 0.7), g).unwrap();
        assert_eq!(m.content_hash(), m2.content_hash());
        let m3 = grid(20, 10, &[(5, 3)]);
        assert_ne!(m.content_hash(), m3.content_hash());
    }
}
