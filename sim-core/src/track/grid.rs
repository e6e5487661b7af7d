//! The segment grid behind [`super::Track::project`]: a spatial hash of centerline
//! segments, so a projection looks at a handful of segments instead of all of them.

use super::CenterPoint;

/// A uniform grid over the track's bounding box listing, per cell, every segment within
/// `exact_radius` of the cell. A point whose nearest listed segment is within that radius
/// has its exact nearest segment in the list.
#[derive(Debug, Clone)]
pub(super) struct SegmentGrid {
    x0: f64,
    y0: f64,
    cell: f64,
    nx: usize,
    ny: usize,
    pub(super) exact_radius: f64,
    starts: Vec<u32>,
    items: Vec<u32>,
}

impl SegmentGrid {
    pub(super) fn build(points: &[CenterPoint]) -> Self {
        let n = points.len();
        let (mut xmin, mut ymin, mut xmax, mut ymax) = (
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        );
        let mut wmax: f64 = 0.0;
        for p in points {
            xmin = xmin.min(p.x);
            ymin = ymin.min(p.y);
            xmax = xmax.max(p.x);
            ymax = ymax.max(p.y);
            wmax = wmax.max(p.w_left).max(p.w_right);
        }
        let cell = 2.0;
        // Cars stay within the corridor; beyond this radius the global scan decides.
        let exact_radius = (wmax + 2.0).max(3.0);
        let pad = exact_radius + cell;
        let (x0, y0) = (xmin - pad, ymin - pad);
        let nx = (((xmax + pad - x0) / cell).ceil() as usize).clamp(1, 4096);
        let ny = (((ymax + pad - y0) / cell).ceil() as usize).clamp(1, 4096);
        let mut lists: Vec<Vec<u32>> = vec![Vec::new(); nx * ny];
        // A segment is listed in every cell whose square, grown by exact_radius, the
        // segment's bounding box touches.
        let grow = exact_radius + cell * std::f64::consts::SQRT_2;
        for i in 0..n {
            let (a, b) = (points[i], points[(i + 1) % n]);
            let (sx0, sx1) = (a.x.min(b.x) - grow, a.x.max(b.x) + grow);
            let (sy0, sy1) = (a.y.min(b.y) - grow, a.y.max(b.y) + grow);
            let cx0 = (((sx0 - x0) / cell).floor().max(0.0)) as usize;
            let cx1 = ((((sx1 - x0) / cell).floor()) as usize).min(nx - 1);
            let cy0 = (((sy0 - y0) / cell).floor().max(0.0)) as usize;
            let cy1 = ((((sy1 - y0) / cell).floor()) as usize).min(ny - 1);
            for cy in cy0..=cy1 {
                for cx in cx0..=cx1 {
                    lists[cy * nx + cx].push(i as u32);
                }
            }
        }
        let mut starts = Vec::with_capacity(nx * ny + 1);
        let mut items = Vec::new();
        for l in &lists {
            starts.push(items.len() as u32);
            items.extend_from_slice(l);
        }
        starts.push(items.len() as u32);
        Self {
            x0,
            y0,
            cell,
            nx,
            ny,
            exact_radius,
            starts,
            items,
        }
    }

    pub(super) fn candidates(&self, x: f64, y: f64) -> Option<&[u32]> {
        let cx = ((x - self.x0) / self.cell).floor();
        let cy = ((y - self.y0) / self.cell).floor();
        if !(cx >= 0.0 && cy >= 0.0 && (cx as usize) < self.nx && (cy as usize) < self.ny) {
            return None;
        }
        let k = cy as usize * self.nx + cx as usize;
        let list = &self.items[self.starts[k] as usize..self.starts[k + 1] as usize];
        if list.is_empty() { None } else { Some(list) }
    }
}
