//! Box bounds by a smooth periodic transformation of an unbounded internal space.
//!
//! CMA-ES runs in an internal space where every point is feasible. For a dimension with
//! bounds `[lo, hi]` the internal coordinate `y` is first normalised (the box becomes
//! `[0, 1]`) and then mapped into the box by a piecewise linear/quadratic,
//! reflecting map `u = t(y)`, the construction that pycma documents for its
//! `BoundTransform` ("BoxConstraintsLinQuadTransformation"):
//!
//! * identity on the interior `[a, 1 - a]`,
//! * a quadratic on `[-a, a]`: `u = (y + a)^2 / (4a)`, reaching the bound 0 with zero
//!   slope at `y = -a` and joining the identity with slope 1 at `y = a` (likewise at
//!   the upper bound),
//! * mirrored at `-a` and `1 + a`, hence periodic with period `2 (1 + 2a)`.
//!
//! The map is continuously differentiable, so an optimum on a bound becomes a smooth
//! (locally quadratic) optimum at `y = -a` inside the internal space, and CMA-ES
//! converges to it linearly instead of bouncing off a wall. Every internal point maps
//! into the box, so no candidate is ever rejected or repaired after sampling. The
//! margin is `a = 0.05` of the box width.
//!
//! A dimension without bounds (both infinite) is used as it is.

use serde::{Deserialize, Serialize};

/// Width of the quadratic zone at each bound, as a fraction of the box width.
const MARGIN: f64 = 0.05;

/// How one coordinate maps from the internal space to the user's space.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub(crate) enum Dim {
    /// No bounds: internal coordinate = user coordinate.
    Free,
    /// Box `[lo, lo + width]`; internal coordinate is in units of `width`.
    Box { lo: f64, hi: f64 },
}

impl Dim {
    /// Internal -> user coordinate; always inside `[lo, hi]` for a box.
    pub(crate) fn to_user(self, y: f64) -> f64 {
        match self {
            Dim::Free => y,
            Dim::Box { lo, hi } => {
                let u = lin_quad(y);
                // Rounding in lo + w*u could step just outside; the promise is strict.
                (lo + (hi - lo) * u).clamp(lo, hi)
            }
        }
    }

    /// User -> internal coordinate, the inverse of `to_user` on the central period.
    /// Values outside the box are clamped to it first.
    pub(crate) fn to_internal(self, x: f64) -> f64 {
        match self {
            Dim::Free => x,
            Dim::Box { lo, hi } => {
                let u = ((x - lo) / (hi - lo)).clamp(0.0, 1.0);
                let a = MARGIN;
                if u < a {
                    -a + libm::sqrt(4.0 * a * u)
                } else if u > 1.0 - a {
                    1.0 + a - libm::sqrt(4.0 * a * (1.0 - u))
                } else {
                    u
                }
            }
        }
    }

    /// Scale of one user unit in internal units (to express an absolute sigma0).
    pub(crate) fn internal_per_user_unit(self) -> f64 {
        match self {
            Dim::Free => 1.0,
            Dim::Box { lo, hi } => 1.0 / (hi - lo),
        }
    }
}

/// The normalised map R -> [0, 1] described in the module doc.
fn lin_quad(y: f64) -> f64 {
    let a = MARGIN;
    let period = 2.0 * (1.0 + 2.0 * a);
    // Fold into one period [-a, -a + period), then mirror the second half.
    let mut s = (y + a) % period;
    if s < 0.0 {
        s += period;
    }
    if s > 1.0 + 2.0 * a {
        s = period - s;
    }
    let y = s - a; // now in [-a, 1 + a]
    if y < a {
        (y + a) * (y + a) / (4.0 * a)
    } else if y > 1.0 - a {
        let r = 1.0 + a - y;
        1.0 - r * r / (4.0 * a)
    } else {
        y
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn maps_every_real_into_the_box() {
        let d = Dim::Box { lo: -2.0, hi: 3.0 };
        for k in -2000..2000 {
            let y = k as f64 * 0.0173 + 1e-3;
            let x = d.to_user(y);
            assert!((-2.0..=3.0).contains(&x), "{y} -> {x}");
        }
        for y in [-1e300, 1e300, -1e17, 1e17] {
            let x = d.to_user(y);
            assert!((-2.0..=3.0).contains(&x), "{y} -> {x}");
        }
    }

    #[test]
    fn inverse_round_trips_and_map_is_continuous() {
        let d = Dim::Box { lo: 1.0, hi: 5.0 };
        for k in 0..=400 {
            let x = 1.0 + 4.0 * k as f64 / 400.0;
            let back = d.to_user(d.to_internal(x));
            assert!((back - x).abs() < 1e-12, "{x} -> {back}");
        }
        let mut prev = d.to_user(-3.0);
        for k in 1..=60_000 {
            let y = -3.0 + k as f64 * 1e-4;
            let x = d.to_user(y);
            assert!((x - prev).abs() <= 4.0 * 1e-4 * 1.0001, "jump at {y}");
            prev = x;
        }
    }

    #[test]
    fn bound_is_a_smooth_minimum_in_internal_space() {
        // Near y = -a the distance to the lower bound is quadratic in (y + a).
        let d = Dim::Box { lo: 0.0, hi: 1.0 };
        let h = 1e-3;
        let x1 = d.to_user(-MARGIN + h);
        let x2 = d.to_user(-MARGIN - h);
        assert!((x1 - h * h / (4.0 * MARGIN)).abs() < 1e-15);
        assert!((x1 - x2).abs() < 1e-15);
    }
}
