//! Where the LIDAR sits on the car: the `base_link -> laser` transform.
//!
//! On the F1TENTH car (f1tenth_system) the Hokuyo sits about 0.27 m ahead of
//! `base_link`, and some cars mount it rotated by 180 degrees or upside down. A driver
//! tuned in the simulator expects the scan from the simulator's laser position
//! (`LidarConfig::mount_offset` ahead of the reference point, looking forward; 0 by
//! default, as f1tenth_gym and f1tenth_gym_ros's `scan_distance_to_base_link`), and the
//! time-to-collision check needs distances from the car, not from the laser. So the
//! bridge takes the mount from `/tf_static` (or flags) and
//!
//! - re-projects each scan into the driver's laser position and heading
//!   ([`reproject`]): every beam becomes a point in `base_link`, seen again from where
//!   the driver's laser would be, binned to its beams (nearest point wins, gaps take
//!   the nearer neighbour: never open road);
//! - measures TTC and "blind ahead" in `base_link` ([`LaserMount::point`],
//!   [`LaserMount::beam_angle`]).
//!
//! A mount equal to the driver's laser (the default) leaves the scan path exactly as
//! it was.

use paddock_sim::lidar::LidarConfig;

use crate::msg::Transform;
use crate::scan::fill_gaps;

/// The farthest a laser may sit from `base_link` along either axis, m.
pub const MAX_OFFSET: f64 = 5.0;
/// The largest yaw of a laser on the car, either way, rad (two turns in all).
pub const MAX_YAW: f64 = 2.0 * std::f64::consts::PI;

/// The laser's pose on the car, in `base_link`: position (m), yaw (rad) and whether it
/// is mounted upside down (its beams then sweep clockwise seen from above).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LaserMount {
    pub x: f64,
    pub y: f64,
    pub yaw: f64,
    pub flipped: bool,
}

impl LaserMount {
    /// Laser `x` metres straight ahead of `base_link`, looking forward.
    pub fn ahead(x: f64) -> Self {
        Self {
            x,
            ..Self::default()
        }
    }

    /// Direction in `base_link` of the beam at scan angle `angle`.
    pub fn beam_angle(&self, angle: f64) -> f64 {
        if self.flipped {
            self.yaw - angle
        } else {
            self.yaw + angle
        }
    }

    /// The point in `base_link` of a return at `range` on the beam at `angle`.
    pub fn point(&self, angle: f64, range: f64) -> (f64, f64) {
        let (s, c) = libm::sincos(self.beam_angle(angle));
        (self.x + range * c, self.y + range * s)
    }

    /// Is this exactly the driver's laser (`mount_offset` ahead, forward, upright)?
    pub fn matches(&self, lidar: &LidarConfig) -> bool {
        self.x == lidar.mount_offset && self.y == 0.0 && self.yaw == 0.0 && !self.flipped
    }

    /// Check the numbers, naming the offender.
    pub fn validate(&self) -> Result<(), String> {
        for (field, v) in [("laser x", self.x), ("laser y", self.y)] {
            if !(v.is_finite() && v.abs() <= MAX_OFFSET) {
                return Err(format!("{field} = {v}: must be within +-{MAX_OFFSET} m"));
            }
        }
        if !(self.yaw.is_finite() && self.yaw.abs() <= MAX_YAW) {
            return Err(format!(
                "laser yaw = {}: must be within +-2 pi rad",
                self.yaw
            ));
        }
        Ok(())
    }

    /// The mount from a `base_link -> laser` transform: its translation, the yaw of the
    /// laser's x axis, and flipped when its z axis points down. A laser tilted by more
    /// than about 6 degrees out of the plane is refused (a 2D scan then is not).
    pub fn from_transform(t: &Transform) -> Result<Self, String> {
        let q = &t.rotation;
        let n = (q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w).sqrt();
        if !(n.is_finite() && n > 1e-9) {
            return Err(format!("rotation {q:?} is not a quaternion"));
        }
        let (x, y, z, w) = (q.x / n, q.y / n, q.z / n, q.w / n);
        // rotation matrix columns: the laser's x and z axes in base_link
        let x_axis = (
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y + w * z),
            2.0 * (x * z - w * y),
        );
        let z_axis = (
            2.0 * (x * z + w * y),
            2.0 * (y * z - w * x),
            1.0 - 2.0 * (x * x + y * y),
        );
        if x_axis.2.abs() > 0.1 || z_axis.2.abs() < 0.99 {
            return Err(format!(
                "the laser is tilted out of the horizontal plane (rotation {q:?})"
            ));
        }
        let mount = Self {
            x: t.translation.x,
            y: t.translation.y,
            yaw: libm::atan2(x_axis.1, x_axis.0),
            flipped: z_axis.2 < 0.0,
        };
        mount.validate()?;
        Ok(mount)
    }
}

/// Re-project `ranges` (already read conservatively, capped at `max_range`) of a scan
/// with `angle_min` / `angle_increment` from `mount` into the driver's laser
/// (`lidar`: its beams, its `mount_offset`), writing the driver's beams into `out`.
pub fn reproject(
    ranges: &[f64],
    angle_min: f64,
    angle_increment: f64,
    mount: &LaserMount,
    lidar: &LidarConfig,
    out: &mut [f64],
) {
    let m = out.len();
    let step = if m > 1 {
        lidar.fov / (m - 1) as f64
    } else {
        1.0
    };
    out.fill(f64::NAN);
    for (i, &r) in ranges.iter().enumerate() {
        let (px, py) = mount.point(angle_min + i as f64 * angle_increment, r);
        let (dx, dy) = (px - lidar.mount_offset, py);
        let a = libm::atan2(dy, dx);
        let j = ((a + 0.5 * lidar.fov) / step).round();
        if j < 0.0 || j >= m as f64 {
            continue;
        }
        let d = libm::hypot(dx, dy).min(lidar.max_range);
        let o = &mut out[j as usize];
        if o.is_nan() || d < *o {
            *o = d;
        }
    }
    // beams no point fell on (behind the car, or between sparse points)
    fill_gaps(out, 0.0);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msg::{Quaternion, Vector3};

    fn transform(x: f64, rotation: Quaternion) -> Transform {
        Transform {
            translation: Vector3 { x, y: 0.0, z: 0.1 },
            rotation,
        }
    }

    #[test]
    fn mounts_from_transforms() {
        let m = LaserMount::from_transform(&transform(0.27, Quaternion::default())).unwrap();
        assert_eq!(m, LaserMount::ahead(0.27));
        // rotated 180 degrees about z: looking backwards
        let m = LaserMount::from_transform(&transform(
            0.27,
            Quaternion::from_yaw(std::f64::consts::PI),
        ))
        .unwrap();
        assert!(
            (m.yaw.abs() - std::f64::consts::PI).abs() < 1e-9 && !m.flipped,
            "{m:?}"
        );
        // upside down: 180 degrees about x, still looking forward
        let roll = Quaternion {
            x: 1.0,
            y: 0.0,
            z: 0.0,
            w: 0.0,
        };
        let m = LaserMount::from_transform(&transform(0.27, roll)).unwrap();
        assert!(m.yaw.abs() < 1e-9 && m.flipped, "{m:?}");
        // a beam at +90 degrees of an upside-down laser points to the car's right
        let (px, py) = m.point(std::f64::consts::FRAC_PI_2, 1.0);
        assert!((px - 0.27).abs() < 1e-9 && (py + 1.0).abs() < 1e-9);
        // tilted 30 degrees: refused
        let h = 15f64.to_radians();
        let pitch = Quaternion {
            x: 0.0,
            y: h.sin(),
            z: 0.0,
            w: h.cos(),
        };
        assert!(
            LaserMount::from_transform(&transform(0.2, pitch))
                .unwrap_err()
                .contains("tilted")
        );
        let bad = Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 0.0,
        };
        assert!(LaserMount::from_transform(&transform(0.2, bad)).is_err());
        assert!(
            LaserMount::ahead(f64::NAN)
                .validate()
                .unwrap_err()
                .contains("laser x = NaN")
        );
    }

    /// A wall 2 m ahead of base_link (x = 2), seen by a laser mounted `mount`.
    fn wall_scan(mount: &LaserMount, n: usize, fov: f64) -> Vec<f64> {
        (0..n)
            .map(|i| {
                let a = -0.5 * fov + i as f64 * fov / (n - 1) as f64;
                let b = mount.beam_angle(a);
                let c = libm::cos(b);
                // from (mount.x, mount.y) along b to x = 2
                if c > 1e-6 { (2.0 - mount.x) / c } else { 30.0 }.min(30.0)
            })
            .collect()
    }

    #[test]
    fn a_wall_reads_the_same_to_the_driver_however_the_laser_is_mounted() {
        let lidar = LidarConfig::default();
        let fov = 270f64.to_radians();
        let n = 1081;
        let want = wall_scan(&LaserMount::default(), lidar.num_beams, lidar.fov);
        for mount in [
            LaserMount::ahead(0.27),
            LaserMount {
                x: 0.27,
                yaw: 0.3,
                ..LaserMount::default()
            },
            LaserMount {
                x: 0.1,
                flipped: true,
                ..LaserMount::default()
            },
        ] {
            let scan = wall_scan(&mount, n, fov);
            let mut out = vec![0.0; lidar.num_beams];
            reproject(
                &scan,
                -0.5 * fov,
                fov / (n - 1) as f64,
                &mount,
                &lidar,
                &mut out,
            );
            // straight ahead the driver sees the wall at 2 m from base_link
            let mid = lidar.num_beams / 2;
            for j in mid - 100..mid + 100 {
                assert!(
                    (out[j] - want[j]).abs() < 0.02,
                    "{mount:?} beam {j}: {} vs {}",
                    out[j],
                    want[j]
                );
            }
            assert!(out.iter().all(|r| r.is_finite() && *r >= 0.0));
        }
    }
}
