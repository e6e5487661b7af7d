//! Where a scan's beams point ([`Fan`]), and which of them can see a box: the directions
//! of its corners, to within a stated slack, and the beam ranges between them.

use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

#[cfg(target_arch = "x86_64")]
use super::avx;

/// Radians: the error bound of [`atan2_fast`] (1e-6) with room to spare.
pub(super) const ANGLE_SLACK: f64 = 1e-5;

/// Where the scan's beams point: beam i at grid-frame angle `heading - fov/2 + i inc`.
pub(in crate::lidar) struct Fan {
    pub fov: f64,
    pub inc: f64,
    /// cos and sin of the heading, `fov / 2` and `1 / inc`.
    pub cos: f64,
    pub sin: f64,
    pub half_fov: f64,
    pub inv_inc: f64,
}

impl Fan {
    /// The direction of the vector (vx, vy) relative to the heading, by [`atan2_fast`]
    /// (`avx::angles_ps` the same, eight at a time in single precision).
    #[inline(always)]
    pub(super) fn angle(&self, vx: f64, vy: f64) -> f64 {
        let (c, s) = (self.cos, self.sin);
        atan2_fast(vy * c - vx * s, vx * c + vy * s)
    }

    /// The fan of a scan whose heading in the grid frame has cosine `cos` and sine `sin`.
    pub(in crate::lidar) fn new(cos: f64, sin: f64, fov: f64, inc: f64) -> Fan {
        Fan {
            fov,
            inc,
            cos,
            sin,
            half_fov: 0.5 * fov,
            inv_inc: 1.0 / inc,
        }
    }
}

/// The directions (relative to the heading) of the corners of the box `[x0, x1] x [y0,
/// y1]` seen from (gx, gy), and first those of `group`'s if given (else zeros), and the
/// radians by which they may be off: [`ANGLE_SLACK`] by [`Fan::angle`], more with `AVX`,
/// which takes all eight at once in single precision (`avx::box_angles`). Beam ranges
/// from them only have to hold every beam that can see the box, so the bits stay the
/// same.
#[inline(always)]
pub(super) fn box_angles<const AVX: bool>(
    fan: &Fan,
    gx: f64,
    gy: f64,
    group: Option<[f64; 4]>,
    rect: [f64; 4],
) -> ([f64; 4], [f64; 4], f64) {
    #[cfg(target_arch = "x86_64")]
    if AVX {
        // SAFETY: `AVX` is set only by callers that checked the CPU has AVX.
        let (a, b) = unsafe { avx::box_angles(fan, gx, gy, group.unwrap_or(rect), rect) };
        return (a, b, ANGLE_SLACK + avx::ANGLE_ERR_PS);
    }
    let corners = |[x0, y0, x1, y1]: [f64; 4]| {
        let (xs, ys) = ([x0, x1, x0, x1], [y0, y0, y1, y1]);
        std::array::from_fn(|k| fan.angle(xs[k] - gx, ys[k] - gy))
    };
    (group.map_or([0.0; 4], corners), corners(rect), ANGLE_SLACK)
}

/// The beams (one or two index ranges) that can see a box from outside it whose corners
/// lie in the directions `angle` (each within `slack` radians): those between them, with
/// `slack` to spare on each side.
#[inline(always)]
pub(super) fn beams_seeing(
    fan: &Fan,
    n: usize,
    angle: [f64; 4],
    slack: f64,
) -> [std::ops::Range<usize>; 2] {
    let lo = angle[0].min(angle[1]).min(angle[2].min(angle[3]));
    let hi = angle[0].max(angle[1]).max(angle[2].max(angle[3]));
    if hi - lo > PI {
        // A box seen from outside spans less than a half turn: this one spans the
        // direction straight behind. Measured from 0 to 2 pi its span is one interval.
        let turn = |a: f64| if a < 0.0 { a + 2.0 * PI } else { a };
        let (a, b, c, d) = (
            turn(angle[0]),
            turn(angle[1]),
            turn(angle[2]),
            turn(angle[3]),
        );
        let (lo, hi) = (a.min(b).min(c.min(d)), a.max(b).max(c.max(d)));
        [
            beams_between(fan, n, lo, PI, slack),
            beams_between(fan, n, -PI, hi - 2.0 * PI, slack),
        ]
    } else {
        [beams_between(fan, n, lo, hi, slack), 0..0]
    }
}

/// The beams of a fan of `n` whose directions lie between `a` and `z` (radians from the
/// heading), with `slack` radians to spare on each side. Inlined, not a closure: the
/// compiler kept a closure out of line and compiled it without AVX.
#[inline(always)]
fn beams_between(fan: &Fan, n: usize, a: f64, z: f64, slack: f64) -> std::ops::Range<usize> {
    let slack = slack * fan.inv_inc;
    let top = (n - 1) as f64;
    let first = ((a + fan.half_fov) * fan.inv_inc - slack).ceil().max(0.0);
    let last = ((z + fan.half_fov) * fan.inv_inc + slack).floor().min(top);
    if first <= last {
        first as usize..last as usize + 1
    } else {
        0..0
    }
}

/// atan2(y, x) within 1e-6 radians (a series on an octant reduced to |z| <= tan(pi/8)),
/// without branches (so that loops over it vectorise); the argument must not be (0, 0).
#[inline(always)]
pub(super) fn atan2_fast(y: f64, x: f64) -> f64 {
    let (ax, ay) = (x.abs(), y.abs());
    let swap = ay > ax;
    let (num, den) = if swap { (ax, ay) } else { (ay, ax) };
    // atan(z) = pi/4 + atan((z - 1) / (z + 1)) above tan(pi/8): one division either way.
    let red = num > 0.414_213_562_373_095 * den;
    let z = if red { num - den } else { num } / if red { num + den } else { den };
    let z2 = z * z;
    let series = z
        * (1.0
            + z2 * (-1.0 / 3.0
                + z2 * (1.0 / 5.0
                    + z2 * (-1.0 / 7.0 + z2 * (1.0 / 9.0 + z2 * (-1.0 / 11.0 + z2 / 13.0))))));
    let a = if red { FRAC_PI_4 } else { 0.0 } + series;
    let a = if swap { FRAC_PI_2 - a } else { a };
    let a = if x < 0.0 { PI - a } else { a };
    if y < 0.0 { -a } else { a }
}
