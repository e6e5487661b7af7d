//! Collision tests: car against car (exact oriented rectangles, separating axis theorem)
//! and car against the map's occupied cells (exact rectangle-versus-square overlap).
//!
//! The reference detects collisions through the LIDAR's time-to-collision; here they are
//! geometric, so a car that touches a wall is caught even where no beam points.

use serde::{Deserialize, Serialize};

use crate::geometry::Obb;
use crate::map::Map;

/// What happens to a car that collides, set per episode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CollisionMode {
    /// The car is out of the episode: it stays where it crashed (other cars still hit it).
    #[default]
    Terminate,
    /// The car is put back where it was before the colliding step and halted; it may
    /// drive on.
    Stop,
    /// The collision is reported and nothing else happens.
    Ignore,
}

impl std::str::FromStr for CollisionMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "terminate" => Ok(Self::Terminate),
            "stop" => Ok(Self::Stop),
            "ignore" => Ok(Self::Ignore),
            other => Err(format!(
                "unknown collision mode {other:?} (expected terminate, stop or ignore)"
            )),
        }
    }
}

/// Do two oriented rectangles overlap (touching counts)? Exact separating-axis test on
/// the four edge normals.
pub fn obb_overlap(a: &Obb, b: &Obb) -> bool {
    let (ac, as_) = a.axis_u();
    let (bc, bs) = b.axis_u();
    let axes = [(ac, as_), (-as_, ac), (bc, bs), (-bs, bc)];
    let (dx, dy) = (b.cx - a.cx, b.cy - a.cy);
    for (ux, uy) in axes {
        let ra =
            a.half_length * (ac * ux + as_ * uy).abs() + a.half_width * (-as_ * ux + ac * uy).abs();
        let rb =
            b.half_length * (bc * ux + bs * uy).abs() + b.half_width * (-bs * ux + bc * uy).abs();
        if (dx * ux + dy * uy).abs() > ra + rb {
            return false;
        }
    }
    true
}

/// Does the rectangle overlap any occupied cell of the map? Off-map space is free.
pub fn obb_hits_map(obb: &Obb, map: &Map) -> bool {
    // Fast rejection: the whole box is inside a disc of free space.
    if map.clearance(obb.cx, obb.cy) > obb.circumradius() {
        return false;
    }
    // Then by two smaller discs, one around each half of the box (a car beside a wall,
    // which the disc around the whole box reaches): each clear of every occupied cell by
    // `DISC_MARGIN`, far beyond the roundings of the centres, of `clearance` and of the
    // cell-by-cell test, which would find every cell apart from the box too; so the
    // answer is the same, without that test's trigonometry and cells.
    let (c, s) = obb.axis_u();
    let half = 0.5 * obb.half_length;
    let (ox, oy) = (half * c, half * s);
    let r = libm::hypot(half, obb.half_width) + DISC_MARGIN;
    if map.clearance(obb.cx + ox, obb.cy + oy) > r && map.clearance(obb.cx - ox, obb.cy - oy) > r {
        return false;
    }
    hits_cell_by_cell(obb, map)
}

/// Metres: how far from every occupied cell [`obb_hits_map`]'s two discs must be to
/// answer for the box (a hundred-thousandth of a 5 cm cell at least, against roundings of
/// about 1e-12 m on maps of a few hundred metres).
const DISC_MARGIN: f64 = 1e-6;

/// Whether `obb` overlaps an occupied cell of `map`, cell by cell under its bounding box
/// (the exact rectangle-versus-square test of [`obb_hits_map`]).
fn hits_cell_by_cell(obb: &Obb, map: &Map) -> bool {
    let res = map.resolution();
    // The box in grid coordinates (cells): centre, heading relative to the grid axes,
    // and half extents in cells.
    let (gx, gy) = map.world_to_grid(obb.cx, obb.cy);
    let theta = obb.theta - map.origin().theta;
    let (c, s) = (libm::cos(theta), libm::sin(theta));
    let (hl, hw) = (obb.half_length / res, obb.half_width / res);
    // Axis-aligned extent of the box in the grid.
    let ex = hl * c.abs() + hw * s.abs();
    let ey = hl * s.abs() + hw * c.abs();
    let col0 = libm::floor(gx - ex) as i64;
    let col1 = libm::floor(gx + ex) as i64;
    let row0 = libm::floor(gy - ey) as i64;
    let row1 = libm::floor(gy + ey) as i64;
    for row in row0..=row1 {
        for col in col0..=col1 {
            if !map.cell_occupied(col, row) {
                continue;
            }
            // Separating axes: the grid axes (the cell's) and the box's two axes.
            let (qx, qy) = (col as f64 + 0.5 - gx, row as f64 + 0.5 - gy);
            if qx.abs() > 0.5 + ex || qy.abs() > 0.5 + ey {
                continue;
            }
            // box axis u = (c, s): the cell's projection radius is 0.5(|c| + |s|)
            let rcell = 0.5 * (c.abs() + s.abs());
            if (qx * c + qy * s).abs() > hl + rcell {
                continue;
            }
            if (-qx * s + qy * c).abs() > hw + rcell {
                continue;
            }
            return true;
        }
    }
    false
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Pose;

    fn car(x: f64, y: f64, th: f64) -> Obb {
        Obb::car(Pose::new(x, y, th), 0.58, 0.31)
    }

    #[test]
    fn boxes_side_by_side() {
        let a = car(0.0, 0.0, 0.0);
        assert!(obb_overlap(&a, &car(0.0, 0.30, 0.0)));
        assert!(!obb_overlap(&a, &car(0.0, 0.32, 0.0)));
        assert!(obb_overlap(&a, &car(0.57, 0.0, 0.0)));
        assert!(!obb_overlap(&a, &car(0.59, 0.0, 0.0)));
    }

    #[test]
    fn rotated_corner_gap() {
        // Diamond corner pointing at an axis-aligned box: the corner is at x = 0.29 +
        // half-diagonal of the other box.
        let a = car(0.0, 0.0, 0.0);
        let b = Obb {
            cx: 0.0,
            cy: 0.0,
            theta: std::f64::consts::FRAC_PI_4,
            half_length: 0.1,
            half_width: 0.1,
        };
        let reach = 0.1 * std::f64::consts::SQRT_2;
        let mut b1 = b;
        b1.cx = 0.29 + reach - 1e-6;
        assert!(obb_overlap(&a, &b1));
        let mut b2 = b;
        b2.cx = 0.29 + reach + 1e-6;
        assert!(!obb_overlap(&a, &b2));
    }

    #[test]
    fn the_discs_reject_only_boxes_the_cells_clear() {
        // Boxes of cars and of other sizes at every heading, anywhere on grids of scattered
        // cells and blocks: the answer with the rejections is the cell-by-cell one.
        let mut rng = crate::rng::Rng::new(23);
        let (mut near_misses, mut hits) = (0, 0);
        for trial in 0..30 {
            let (w, h) = (60 + rng.below(60) as usize, 60 + rng.below(60) as usize);
            let map = crate::lidar::tests::random_map(&mut rng, w, h);
            for _ in 0..2000 {
                let (gx, gy) = (
                    rng.uniform_range(0.0, w as f64),
                    rng.uniform_range(0.0, h as f64),
                );
                let (x, y) = map.grid_to_world(gx, gy);
                let th = rng.uniform_range(-7.0, 7.0);
                let obb = if rng.uniform() < 0.7 {
                    car(x, y, th)
                } else {
                    Obb {
                        cx: x,
                        cy: y,
                        theta: th,
                        half_length: rng.uniform_range(0.01, 0.6),
                        half_width: rng.uniform_range(0.01, 0.4),
                    }
                };
                let want = hits_cell_by_cell(&obb, &map);
                assert_eq!(obb_hits_map(&obb, &map), want, "trial {trial}: {obb:?}");
                hits += usize::from(want);
                let whole = map.clearance(obb.cx, obb.cy) > obb.circumradius();
                near_misses += usize::from(!whole && !want);
            }
        }
        // both answers met often, and boxes the whole-box disc could not clear that hit
        // nothing (those the two discs may answer for)
        assert!(hits > 5_000 && near_misses > 5_000, "{hits} {near_misses}");
    }

    #[test]
    fn sat_agrees_with_sampling() {
        // Random boxes: SAT says "overlap" iff a dense point sample of one lies in the
        // other, up to the sampling resolution.
        let mut rng = crate::rng::Rng::new(11);
        let inside = |o: &Obb, x: f64, y: f64| {
            let (c, s) = o.axis_u();
            let (dx, dy) = (x - o.cx, y - o.cy);
            (dx * c + dy * s).abs() <= o.half_length && (-dx * s + dy * c).abs() <= o.half_width
        };
        let mut agree = 0;
        for _ in 0..400 {
            let a = car(0.0, 0.0, rng.uniform_range(-3.0, 3.0));
            let b = car(
                rng.uniform_range(-0.7, 0.7),
                rng.uniform_range(-0.7, 0.7),
                rng.uniform_range(-3.0, 3.0),
            );
            let sat = obb_overlap(&a, &b);
            let mut sampled = false;
            let n = 60;
            'outer: for i in 0..=n {
                for j in 0..=n {
                    let u = -b.half_length + 2.0 * b.half_length * i as f64 / n as f64;
                    let v = -b.half_width + 2.0 * b.half_width * j as f64 / n as f64;
                    let (c, s) = b.axis_u();
                    if inside(&a, b.cx + u * c - v * s, b.cy + u * s + v * c) {
                        sampled = true;
                        break 'outer;
                    }
                }
            }
            if sampled {
                assert!(sat, "sampling found overlap SAT missed: {a:?} {b:?}");
            }
            if sat == sampled {
                agree += 1;
            }
        }
        // SAT may see overlaps thinner than the sample spacing; nearly all must agree
        assert!(agree >= 390, "agree {agree}/400");
    }
}
