//! Plane geometry shared by every part of the simulator: poses and oriented boxes.

use serde::{Deserialize, Serialize};

/// A pose in the map (world) frame: position in metres, heading in radians
/// (counter-clockwise from the +x axis).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Pose {
    pub x: f64,
    pub y: f64,
    pub theta: f64,
}

impl Pose {
    pub const fn new(x: f64, y: f64, theta: f64) -> Self {
        Self { x, y, theta }
    }
}

/// An oriented rectangle (a car body or a box obstacle): centre, heading, half extents.
/// `half_length` is along the heading, `half_width` across it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Obb {
    pub cx: f64,
    pub cy: f64,
    pub theta: f64,
    pub half_length: f64,
    pub half_width: f64,
}

impl Obb {
    /// The box of a car whose reference point is `pose` and whose body is `length` by
    /// `width`, centred on the reference point (as the f1tenth_gym reference does).
    pub fn car(pose: Pose, length: f64, width: f64) -> Self {
        Self {
            cx: pose.x,
            cy: pose.y,
            theta: pose.theta,
            half_length: 0.5 * length,
            half_width: 0.5 * width,
        }
    }

    /// Unit vector along the heading.
    #[inline]
    pub fn axis_u(&self) -> (f64, f64) {
        (libm::cos(self.theta), libm::sin(self.theta))
    }

    /// The four corners, counter-clockwise starting front-left.
    pub fn corners(&self) -> [(f64, f64); 4] {
        let (c, s) = self.axis_u();
        let (hl, hw) = (self.half_length, self.half_width);
        let corner = |a: f64, b: f64| (self.cx + a * c - b * s, self.cy + a * s + b * c);
        [
            corner(hl, hw),
            corner(-hl, hw),
            corner(-hl, -hw),
            corner(hl, -hw),
        ]
    }

    /// Radius of the circle around the centre that contains the box.
    #[inline]
    pub fn circumradius(&self) -> f64 {
        libm::hypot(self.half_length, self.half_width)
    }
}

/// Wrap an angle to [-pi, pi).
#[inline]
pub fn wrap_angle(a: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    let w = a - TAU * libm::floor((a + PI) / TAU);
    if w >= PI { w - TAU } else { w }
}

/// `s.rem_euclid(length)` (for `length > 0`), the same bits, without the division of
/// `f64::rem_euclid` for the values a loop's arc lengths mostly take: `s` in
/// (-length, 2 length), where the remainder is `s`, `s - length` (exact) or `s + length`
/// (as `rem_euclid` rounds it; at `-length` itself `rem_euclid` gives -0). Other values,
/// NaN and infinities take `rem_euclid`.
#[inline]
pub fn wrap_length(s: f64, length: f64) -> f64 {
    if (0.0..length).contains(&s) {
        s
    } else if s >= length && s < 2.0 * length {
        s - length
    } else if s < 0.0 && s > -length {
        s + length
    } else {
        s.rem_euclid(length)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_length_is_rem_euclid_bit_for_bit() {
        let mut rng = crate::rng::Rng::new(5);
        for &l in &[1.0, 0.1, 3.0, 87.654_321, 1234.5, 1e-300, f64::MAX / 4.0] {
            let mut values = vec![
                0.0,
                -0.0,
                l,
                -l,
                2.0 * l,
                -2.0 * l,
                l.next_down(),
                l.next_up(),
                (2.0 * l).next_down(),
                (-l).next_up(),
                (-l).next_down(),
                f64::MIN_POSITIVE,
                -f64::MIN_POSITIVE,
                f64::NAN,
                f64::INFINITY,
                f64::NEG_INFINITY,
            ];
            for _ in 0..20_000 {
                values.push(rng.uniform_range(-3.0, 3.0) * l);
            }
            for s in values {
                let (got, want) = (wrap_length(s, l), s.rem_euclid(l));
                assert!(
                    got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
                    "{s} mod {l}: {got} vs {want}"
                );
            }
        }
    }

    #[test]
    fn corners_of_rotated_box() {
        let b = Obb::car(Pose::new(1.0, 2.0, std::f64::consts::FRAC_PI_2), 0.58, 0.31);
        let c = b.corners();
        // front-left of a car heading +y is at (x - w/2, y + l/2)
        assert!((c[0].0 - (1.0 - 0.155)).abs() < 1e-12);
        assert!((c[0].1 - (2.0 + 0.29)).abs() < 1e-12);
    }

    #[test]
    fn wrap_angle_range() {
        for k in -20..20 {
            let a = k as f64 * 0.7;
            let w = wrap_angle(a);
            assert!(
                (-std::f64::consts::PI..std::f64::consts::PI).contains(&w),
                "{a} -> {w}"
            );
            assert!((libm::sin(w) - libm::sin(a)).abs() < 1e-9);
        }
    }
}
