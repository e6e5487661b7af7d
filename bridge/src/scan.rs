//! Reading a real LIDAR's scan: REP 117 range semantics, and the driver's beam layout.
//!
//! REP 117 (and the drivers that follow it, urg_node for the Hokuyo on the F1TENTH car)
//! gives every beam one of four meanings:
//!
//! | range | meaning | the driver sees | time to collision |
//! |---|---|---|---|
//! | finite in `[range_min, range_max]` | a return | the range (capped at its max range) | counts |
//! | `+inf` | no return within `range_max`: open space | max range | skipped |
//! | `-inf` | an object closer than `range_min` | `range_min` | counts, at `range_min` |
//! | NaN, or finite outside `[range_min, range_max]` (Hokuyo error codes arrive as values below `range_min`) | invalid: nothing known | the nearer of the nearest known neighbours on either side | skipped, but counted: too many invalid beams ahead stop the car |
//!
//! So an invalid or too-close beam never reads as open road (it used to read as the
//! driver's max range and was skipped by the TTC check).

use paddock_sim::lidar::LidarConfig;

use crate::mount::{LaserMount, reproject};
use crate::msg::LaserScan;

/// What one beam says (REP 117).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Beam {
    /// A return at this range, m.
    Return(f64),
    /// Nothing within range (`+inf`).
    NoReturn,
    /// Something closer than `range_min` (`-inf`).
    TooClose,
    /// NaN, or a finite value outside `[range_min, range_max]` (a driver's error code).
    Invalid,
}

impl Beam {
    pub fn classify(r: f32, range_min: f32, range_max: f32) -> Self {
        if r.is_nan() {
            Self::Invalid
        } else if r == f32::INFINITY {
            Self::NoReturn
        } else if r == f32::NEG_INFINITY {
            Self::TooClose
        } else if r < range_min || r > range_max {
            Self::Invalid
        } else {
            Self::Return(r as f64)
        }
    }

    /// The range an obstacle check uses: a return's range, `range_min` when too close,
    /// none otherwise.
    pub fn obstacle_range(self, range_min: f64) -> Option<f64> {
        match self {
            Self::Return(r) => Some(r),
            Self::TooClose => Some(range_min),
            Self::NoReturn | Self::Invalid => None,
        }
    }
}

/// Unusable scan limits (a `range_min` that is not a non-negative number below
/// `range_max`), named for the log.
pub fn check_limits(scan: &LaserScan) -> Result<(), String> {
    let (lo, hi) = (scan.range_min, scan.range_max);
    if lo.is_finite() && hi.is_finite() && lo >= 0.0 && hi > lo {
        Ok(())
    } else {
        Err(format!(
            "scan limits range_min = {lo}, range_max = {hi} are unusable (REP 117 needs 0 <= range_min < range_max)"
        ))
    }
}

/// The scan's ranges as a driver should see them (see the module table), capped at
/// `max_range`; `out` is resized to the scan's beam count.
pub fn conservative_ranges(scan: &LaserScan, max_range: f64, out: &mut Vec<f64>) {
    let (lo, hi) = (scan.range_min, scan.range_max);
    let n = scan.ranges.len();
    out.clear();
    out.resize(n, f64::NAN);
    for (o, &r) in out.iter_mut().zip(&scan.ranges) {
        *o = match Beam::classify(r, lo, hi) {
            Beam::Return(r) => r.min(max_range),
            Beam::NoReturn => max_range,
            Beam::TooClose => (lo as f64).min(max_range),
            Beam::Invalid => f64::NAN,
        };
    }
    // invalid beams: the nearer of the nearest known beams on each side
    fill_gaps(out, (lo as f64).min(max_range));
}

/// Give every NaN in `out` the nearer of the nearest non-NaN values on either side
/// (`fallback` when there is none): an unknown beam never reads farther than what is
/// known around it.
pub fn fill_gaps(out: &mut [f64], fallback: f64) {
    let n = out.len();
    let mut left = vec![f64::NAN; n];
    let mut last = f64::NAN;
    for (l, &v) in left.iter_mut().zip(out.iter()) {
        if !v.is_nan() {
            last = v;
        }
        *l = last;
    }
    let mut next = f64::NAN;
    for i in (0..n).rev() {
        if !out[i].is_nan() {
            next = out[i];
            continue;
        }
        // f64::min ignores a NaN side
        let v = left[i].min(next);
        out[i] = if v.is_nan() { fallback } else { v };
    }
}

/// Maps a LaserScan's beams onto the driver's beam layout: by nearest angle when the
/// laser sits where the driver's does, else by re-projection ([`crate::mount`]).
#[derive(Debug, Clone, PartialEq)]
pub struct ScanAdapter {
    /// Geometry of the incoming scans this was built for.
    key: (usize, u32, u32),
    /// Source beam of each target beam.
    index: Vec<usize>,
    /// The source scan read conservatively (reused buffer).
    source: Vec<f64>,
    /// Where the scans come from, and the driver's laser, when they differ.
    reprojection: Option<(LaserMount, LidarConfig)>,
}

impl ScanAdapter {
    /// An adapter for scans like `scan` from a laser at the driver's position.
    pub fn new(scan: &LaserScan, target: &LidarConfig) -> Result<Self, String> {
        Self::mounted(scan, target, &LaserMount::ahead(target.mount_offset))
    }

    /// An adapter for scans like `scan` from a laser mounted at `mount`.
    pub fn mounted(
        scan: &LaserScan,
        target: &LidarConfig,
        mount: &LaserMount,
    ) -> Result<Self, String> {
        let n = scan.ranges.len();
        let (amin, inc) = (scan.angle_min as f64, scan.angle_increment as f64);
        if n == 0 {
            return Err("scan has no ranges".into());
        }
        if !(amin.is_finite() && inc.is_finite()) || (n > 1 && inc == 0.0) {
            return Err(format!(
                "scan geometry angle_min = {amin}, angle_increment = {inc} is unusable"
            ));
        }
        let m = target.num_beams;
        let step = if m > 1 {
            target.fov / (m - 1) as f64
        } else {
            0.0
        };
        let index = (0..m)
            .map(|j| {
                let a = -0.5 * target.fov + j as f64 * step;
                let i = if n > 1 {
                    ((a - amin) / inc).round()
                } else {
                    0.0
                };
                i.clamp(0.0, (n - 1) as f64) as usize
            })
            .collect();
        Ok(Self {
            key: Self::key(scan),
            index,
            source: Vec::with_capacity(n),
            reprojection: (!mount.matches(target)).then(|| (*mount, target.clone())),
        })
    }

    /// Does this adapter fit `scan`'s geometry?
    pub fn fits(&self, scan: &LaserScan) -> bool {
        self.key == Self::key(scan)
    }

    fn key(scan: &LaserScan) -> (usize, u32, u32) {
        (
            scan.ranges.len(),
            scan.angle_min.to_bits(),
            scan.angle_increment.to_bits(),
        )
    }

    /// Write the driver's view of `scan` (REP 117, conservatively) into `out`.
    pub fn apply(&mut self, scan: &LaserScan, max_range: f64, out: &mut [f64]) {
        conservative_ranges(scan, max_range, &mut self.source);
        if let Some((mount, target)) = &self.reprojection {
            let (amin, inc) = (scan.angle_min as f64, scan.angle_increment as f64);
            reproject(&self.source, amin, inc, mount, target, out);
            return;
        }
        for (o, &i) in out.iter_mut().zip(&self.index) {
            *o = self.source[i];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A Hokuyo UST-10LX scan as urg_node publishes it: 1081 beams over 270 degrees,
    /// range_min 0.06 m, range_max 30 m, every beam `r`.
    pub(crate) fn hokuyo(r: f32) -> LaserScan {
        let fov = 270f32.to_radians();
        LaserScan {
            angle_min: -fov / 2.0,
            angle_max: fov / 2.0,
            angle_increment: fov / 1080.0,
            range_min: 0.06,
            range_max: 30.0,
            ranges: vec![r; 1081],
            ..LaserScan::default()
        }
    }

    #[test]
    fn beams_read_as_rep_117_says() {
        let c = |r| Beam::classify(r, 0.06, 30.0);
        assert_eq!(c(5.0), Beam::Return(5.0));
        assert_eq!(c(0.06), Beam::Return(0.06f32 as f64));
        assert_eq!(c(f32::INFINITY), Beam::NoReturn);
        assert_eq!(c(f32::NEG_INFINITY), Beam::TooClose);
        assert_eq!(c(f32::NAN), Beam::Invalid);
        // Hokuyo error codes (values below 20 mm) and anything past range_max
        assert_eq!(c(0.0), Beam::Invalid);
        assert_eq!(c(0.017), Beam::Invalid);
        assert_eq!(c(65.533), Beam::Invalid);
        assert_eq!(Beam::TooClose.obstacle_range(0.06), Some(0.06));
        assert_eq!(Beam::Invalid.obstacle_range(0.06), None);
        assert!(check_limits(&hokuyo(1.0)).is_ok());
        let mut bad = hokuyo(1.0);
        bad.range_min = f32::NAN;
        assert!(check_limits(&bad).unwrap_err().contains("range_min = NaN"));
    }

    #[test]
    fn drivers_see_invalid_beams_as_their_nearer_neighbour_and_too_close_as_range_min() {
        let mut s = hokuyo(2.0);
        s.ranges[10] = 0.5;
        for r in &mut s.ranges[11..20] {
            *r = f32::NAN; // invalid between a 0.5 m and a 2 m return
        }
        s.ranges[500] = f32::NEG_INFINITY;
        s.ranges[600] = f32::INFINITY;
        s.ranges[700] = 0.004; // a Hokuyo error code
        for r in &mut s.ranges[1070..] {
            *r = f32::NAN; // invalid up to the edge: the one known side
        }
        let mut out = Vec::new();
        conservative_ranges(&s, 10.0, &mut out);
        assert!(out[11..20].iter().all(|&r| r == 0.5), "{:?}", &out[9..21]);
        assert_eq!(out[500], 0.06f32 as f64);
        assert_eq!(out[600], 10.0);
        assert_eq!(out[700], 2.0);
        assert!(out[1070..].iter().all(|&r| r == 2.0));
        // nothing known at all: everything as close as can be
        conservative_ranges(&hokuyo(f32::NAN), 10.0, &mut out);
        assert!(out.iter().all(|&r| r == 0.06f32 as f64));
    }

    #[test]
    fn adapter_resamples_a_1081_beam_scan_by_angle() {
        let mut s = hokuyo(5.0);
        s.ranges[540] = 1.5; // straight ahead
        s.ranges[0] = f32::NAN;
        s.ranges[1] = f32::INFINITY;
        let target = LidarConfig::default();
        let mut a = ScanAdapter::new(&s, &target).unwrap();
        assert!(a.fits(&s));
        let mut out = vec![0.0; target.num_beams];
        a.apply(&s, target.max_range, &mut out);
        // target beams 539/540 straddle 0 rad; one of them reads the 1.5 m return
        assert!(
            out[539] == 1.5 || out[540] == 1.5,
            "{} {}",
            out[539],
            out[540]
        );
        // the invalid edge beam takes its neighbour's open road, not a made-up one
        assert_eq!(out[0], target.max_range);
        assert!(
            out[1..530]
                .iter()
                .all(|&r| r == 5.0 || r == target.max_range)
        );
        let mut one = hokuyo(1.0);
        one.ranges.truncate(1);
        one.angle_increment = 0.0;
        assert!(ScanAdapter::new(&one, &target).is_ok());
        let mut bad = hokuyo(1.0);
        bad.angle_increment = f32::NAN;
        assert!(ScanAdapter::new(&bad, &target).is_err());
    }
}
