//! The occupancy image of a corridor: a cell is free when its centre lies within the
//! (linearly interpolated) half width of the nearest centerline segment, occupied
//! otherwise. Row 0 is the top of the image (highest y), as ROS map_server expects.

use super::{FREE, OCCUPIED, OccupancyImage};

/// Renders the corridor of the closed centerline `pts` with half widths `half`, with
/// `margin` metres of occupied cells around it. Returns the image and the world position
/// of its bottom-left corner.
pub(super) fn render(
    pts: &[[f64; 2]],
    half: &[f64],
    resolution: f64,
    margin: f64,
) -> (OccupancyImage, [f64; 2]) {
    let n = pts.len();
    let h_max = half.iter().copied().fold(0.0, f64::max);
    let (mut min_x, mut min_y) = (f64::INFINITY, f64::INFINITY);
    let (mut max_x, mut max_y) = (f64::NEG_INFINITY, f64::NEG_INFINITY);
    for p in pts {
        min_x = min_x.min(p[0]);
        min_y = min_y.min(p[1]);
        max_x = max_x.max(p[0]);
        max_y = max_y.max(p[1]);
    }
    let pad = h_max + margin;
    // The origin sits on the resolution grid and is written with few digits, so the file
    // and the image agree exactly.
    let snap = |v: f64| libm::round(libm::floor(v / resolution) * resolution * 1e6) / 1e6;
    let origin = [snap(min_x - pad), snap(min_y - pad)];
    let width = libm::ceil((max_x + pad - origin[0]) / resolution) as usize;
    let height = libm::ceil((max_y + pad - origin[1]) / resolution) as usize;
    let mut pixels = vec![OCCUPIED; width * height];

    let cell_of = |v: f64, o: f64| libm::floor((v - o) / resolution);
    for i in 0..n {
        let j = (i + 1) % n;
        let (a, b) = (pts[i], pts[j]);
        let (ha, hb) = (half[i], half[j]);
        let reach = ha.max(hb);
        let c0 = cell_of(a[0].min(b[0]) - reach, origin[0]).max(0.0) as usize;
        let c1 = (cell_of(a[0].max(b[0]) + reach, origin[0]) as usize).min(width - 1);
        let r0 = cell_of(a[1].min(b[1]) - reach, origin[1]).max(0.0) as usize;
        let r1 = (cell_of(a[1].max(b[1]) + reach, origin[1]) as usize).min(height - 1);
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let len2 = dx * dx + dy * dy;
        for gy in r0..=r1 {
            let y = origin[1] + (gy as f64 + 0.5) * resolution;
            let row = height - 1 - gy;
            for gx in c0..=c1 {
                let idx = row * width + gx;
                if pixels[idx] == FREE {
                    continue;
                }
                let x = origin[0] + (gx as f64 + 0.5) * resolution;
                let t = if len2 > 0.0 {
                    (((x - a[0]) * dx + (y - a[1]) * dy) / len2).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                let (px, py) = (a[0] + t * dx - x, a[1] + t * dy - y);
                let h = ha + t * (hb - ha);
                if px * px + py * py <= h * h {
                    pixels[idx] = FREE;
                }
            }
        }
    }
    (
        OccupancyImage {
            width: width as u32,
            height: height as u32,
            pixels,
        },
        origin,
    )
}
