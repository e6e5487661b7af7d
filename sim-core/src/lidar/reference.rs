//! Port of the f1tenth_gym `ScanSimulator2D` (laser_models.py), step for step, so that it
//! reproduces the reference's ranges bit-for-bit. The quirks are deliberate: a trig table
//! of 2000 entries over linspace(0, 2 pi, 2000) (step 2 pi / 1999), the table index
//! advanced by 2000 * increment / 2 pi and truncated with `int()`, sphere tracing on the
//! cell-centre distance transform with eps 1e-4, and an off-map lookup that reads the
//! top-right image pixel (numpy's `dt[-1, -1]`).

use std::f64::consts::TAU;

use super::LidarConfig;
use crate::map::Map;

const THETA_DIS: usize = 2000;
const EPS: f64 = 1e-4;

#[derive(Debug, Clone)]
pub(super) struct TrigTable {
    sin: Vec<f64>,
    cos: Vec<f64>,
    index_increment: f64,
}

impl TrigTable {
    pub(super) fn new(config: &LidarConfig) -> Self {
        // numpy.linspace(0, 2 pi, 2000): i * (2 pi / 1999), the last entry exactly 2 pi.
        let step = TAU / (THETA_DIS - 1) as f64;
        let angles = (0..THETA_DIS).map(|i| {
            if i == THETA_DIS - 1 {
                TAU
            } else {
                i as f64 * step
            }
        });
        let (mut sin, mut cos) = (Vec::new(), Vec::new());
        for a in angles {
            sin.push(libm::sin(a));
            cos.push(libm::cos(a));
        }
        let angle_increment = if config.num_beams > 1 {
            config.fov / (config.num_beams - 1) as f64
        } else {
            0.0
        };
        Self {
            sin,
            cos,
            index_increment: THETA_DIS as f64 * angle_increment / TAU,
        }
    }
}

/// The reference's `distance_transform(x, y)`: `dt[xy_2_rc(x, y)]`.
struct Lookup<'a> {
    dt: &'a [f64],
    width: usize,
    ox: f64,
    oy: f64,
    oc: f64,
    os: f64,
    res: f64,
    w_m: f64,
    h_m: f64,
}

impl Lookup<'_> {
    #[inline(always)]
    fn at(&self, x: f64, y: f64) -> f64 {
        let xt0 = x - self.ox;
        let yt0 = y - self.oy;
        let xt = self.oc * xt0 + self.os * yt0;
        let yt = -self.os * xt0 + self.oc * yt0;
        // Written so that NaN also takes the off-map branch.
        let inside = xt >= 0.0 && xt < self.w_m && yt >= 0.0 && yt < self.h_m;
        let idx = if inside {
            let c = (xt / self.res) as usize;
            let r = (yt / self.res) as usize;
            // numba does not bounds-check: a column rounded up to `width` reads the next
            // row's first cell in the flat array.
            (r * self.width + c).min(self.dt.len() - 1)
        } else {
            self.dt.len() - 1
        };
        self.dt[idx]
    }
}

pub(super) fn scan(
    table: &TrigTable,
    config: &LidarConfig,
    map: &Map,
    x: f64,
    y: f64,
    theta: f64,
    out: &mut [f64],
) {
    let origin = map.origin();
    let res = map.resolution();
    let lookup = Lookup {
        dt: map.distance_field(),
        width: map.width(),
        ox: origin.x,
        oy: origin.y,
        oc: libm::cos(origin.theta),
        os: libm::sin(origin.theta),
        res,
        w_m: map.width() as f64 * res,
        h_m: map.height() as f64 * res,
    };
    let max_range = config.max_range;
    let dis = THETA_DIS as f64;
    let mut ti = dis * (theta - config.fov / 2.0) / TAU;
    ti %= dis;
    while ti < 0.0 {
        ti += dis;
    }
    let d0 = lookup.at(x, y);
    for o in out.iter_mut() {
        let k = (ti as usize).min(THETA_DIS - 1);
        let (s, c) = (table.sin[k], table.cos[k]);
        *o = trace(&lookup, x, y, c, s, d0, max_range);
        ti += table.index_increment;
        while ti >= dis {
            ti -= dis;
        }
    }
}

#[inline(always)]
fn trace(lookup: &Lookup, mut x: f64, mut y: f64, c: f64, s: f64, d0: f64, max_range: f64) -> f64 {
    let mut d = d0;
    let mut total = d;
    // A map without any occupied cell has an infinite field: nothing to hit.
    if d.is_infinite() {
        return max_range;
    }
    while d > EPS && total <= max_range {
        x += d * c;
        y += d * s;
        d = lookup.at(x, y);
        total += d;
    }
    if total > max_range {
        total = max_range;
    }
    total
}
