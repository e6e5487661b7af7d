//! The car side's safety layer, free of I/O: every command the driver proposes passes
//! through [`Safety::filter`] before it is published.
//!
//! In order of precedence:
//! 1. **Stale sensors**: no odometry (or, when the scan is needed, no scan) younger than
//!    `sensor_timeout` -> zero speed, straight wheels. A sensor's age is the larger of
//!    its arrival age and its header-stamp age ([`crate::freshness`]), so a re-sent or
//!    buffered old message does not count as fresh.
//! 2. **Emergency stop**: the smallest time to collision over the scan's returns below
//!    `ttc_threshold` -> zero speed. It stays engaged until the TTC has been clear for
//!    `ttc_release` seconds (no chattering at the threshold). With a corridor
//!    (`corridor_half_width > 0`, the default) only returns inside the strip the car
//!    sweeps driving straight on count, each at `ttc = (r cos(angle)) / v`: a wall beside
//!    the car at racing speed is not an obstacle (the classic per-beam
//!    `r / (v cos(angle))` over all beams brakes for it: 2 d / v for a wall d metres to
//!    the side, 0.14 s at 7 m/s and 0.5 m). With `corridor_half_width = 0` the classic
//!    per-beam formula is used.
//! 3. **Blind ahead**: more than `max_invalid_ahead` of the beams within `ahead_half_angle`
//!    of straight ahead are invalid (REP 117: NaN, or an error code outside
//!    `[range_min, range_max]`) -> zero speed until a scan sees ahead again. Too-close
//!    returns (`-inf`) are not invalid: they count for the TTC as obstacles at
//!    `range_min` ([`crate::scan`]).
//! 4. **Invalid command** (a non-finite steer or speed) -> zero speed.
//! 5. **Clamps**: steering to `[-max_steer, max_steer]`, speed to `[min_speed, max_speed]`.
//!
//! Times are plain seconds on one monotonic clock chosen by the caller, so tests drive a
//! virtual clock.

use paddock_sim::world::Action;

use crate::BridgeError;
use crate::mount::LaserMount;
use crate::msg::LaserScan;
use crate::scan::Beam;

/// Limits and thresholds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SafetyConfig {
    /// Steering limit, rad (both sides).
    pub max_steer: f64,
    /// Forward speed limit, m/s.
    pub max_speed: f64,
    /// Lowest speed allowed, m/s (negative allows reversing; 0 forbids it).
    pub min_speed: f64,
    /// A sensor older than this is stale, s.
    pub sensor_timeout: f64,
    /// Emergency stop below this time to collision, s (0 disables the check).
    pub ttc_threshold: f64,
    /// The emergency stop releases after the TTC has been clear this long, s.
    pub ttc_release: f64,
    /// Half width of the straight-ahead strip whose returns count for the TTC, m (the
    /// car's half width, 0.155 m on the F1TENTH car, plus a margin; 0: every beam, the
    /// classic per-beam TTC).
    pub corridor_half_width: f64,
    /// Half angle of the cone ahead checked for invalid beams, rad.
    pub ahead_half_angle: f64,
    /// Stop when more than this fraction of the beams ahead are invalid (1: never).
    pub max_invalid_ahead: f64,
    /// How fast a sensor's stamp clock may fall behind ours, s/s: the bound on the
    /// clock-offset estimate behind the stamp age ([`crate::freshness`]).
    pub max_clock_drift: f64,
}

impl Default for SafetyConfig {
    fn default() -> Self {
        Self {
            max_steer: 0.4189,
            max_speed: 4.0,
            min_speed: 0.0,
            sensor_timeout: 0.25,
            ttc_threshold: 0.25,
            ttc_release: 0.5,
            corridor_half_width: 0.2,
            ahead_half_angle: 20f64.to_radians(),
            max_invalid_ahead: 0.25,
            max_clock_drift: 0.01,
        }
    }
}

impl SafetyConfig {
    pub fn validate(&self) -> Result<(), BridgeError> {
        let checks: [(&str, f64, bool, &str); 10] = [
            (
                "max_clock_drift",
                self.max_clock_drift,
                (0.0..=1.0).contains(&self.max_clock_drift),
                "must be in [0, 1] s/s (1: no stamp age; arrival and newer stamps only)",
            ),
            (
                "ahead_half_angle",
                self.ahead_half_angle,
                self.ahead_half_angle > 0.0 && self.ahead_half_angle <= std::f64::consts::PI,
                "must be in (0, pi] rad",
            ),
            (
                "max_invalid_ahead",
                self.max_invalid_ahead,
                (0.0..=1.0).contains(&self.max_invalid_ahead),
                "must be a fraction in [0, 1] (1: never stop for invalid beams)",
            ),
            (
                "corridor_half_width",
                self.corridor_half_width,
                (0.0..=5.0).contains(&self.corridor_half_width),
                "must be in [0, 5] m (0: classic per-beam TTC)",
            ),
            (
                "max_steer",
                self.max_steer,
                self.max_steer > 0.0 && self.max_steer <= 1.6,
                "must be in (0, 1.6] rad",
            ),
            (
                "max_speed",
                self.max_speed,
                self.max_speed >= 0.0 && self.max_speed <= 50.0,
                "must be in [0, 50] m/s",
            ),
            (
                "min_speed",
                self.min_speed,
                self.min_speed <= 0.0 && self.min_speed >= -50.0,
                "must be in [-50, 0] m/s",
            ),
            (
                "sensor_timeout",
                self.sensor_timeout,
                self.sensor_timeout > 0.0 && self.sensor_timeout <= 10.0,
                "must be in (0, 10] s",
            ),
            (
                "ttc_threshold",
                self.ttc_threshold,
                (0.0..=10.0).contains(&self.ttc_threshold),
                "must be in [0, 10] s (0 disables the emergency stop)",
            ),
            (
                "ttc_release",
                self.ttc_release,
                (0.0..=60.0).contains(&self.ttc_release),
                "must be in [0, 60] s",
            ),
        ];
        for (field, value, ok, reason) in checks {
            if !(value.is_finite() && ok) {
                return Err(BridgeError::config(field, value, reason));
            }
        }
        Ok(())
    }
}

/// Why a command was replaced by a stop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StopReason {
    /// No scan received yet, or the last is older than the timeout (its age, s).
    StaleScan { age: Option<f64> },
    /// No odometry received yet, or the last is older than the timeout.
    StaleOdom { age: Option<f64> },
    /// Time to collision below the threshold (the TTC that engaged it, s).
    Emergency { ttc: f64 },
    /// Too many invalid beams ahead in the newest scan (invalid, beams in the cone).
    BlindAhead { invalid: usize, beams: usize },
    /// The driver proposed a non-finite command.
    InvalidCommand,
}

impl std::fmt::Display for StopReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let age =
            |a: &Option<f64>| a.map_or("never received".to_string(), |a| format!("{a:.3} s old"));
        match self {
            Self::StaleScan { age: a } => write!(f, "stale scan ({})", age(a)),
            Self::StaleOdom { age: a } => write!(f, "stale odometry ({})", age(a)),
            Self::Emergency { ttc } => write!(f, "emergency stop (time to collision {ttc:.3} s)"),
            Self::BlindAhead { invalid, beams } => write!(
                f,
                "blind ahead ({invalid} of the {beams} beams ahead invalid)"
            ),
            Self::InvalidCommand => write!(f, "non-finite command from the driver"),
        }
    }
}

/// What goes out, and why.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Verdict {
    pub action: Action,
    pub stop: Option<StopReason>,
    /// The command was inside the limits only after clamping.
    pub clamped: bool,
}

/// How often each rule acted.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SafetyCounters {
    pub commands: u64,
    pub stale: u64,
    pub emergency: u64,
    pub invalid: u64,
    /// Commands replaced because the scan was blind ahead.
    pub blind: u64,
    pub clamped: u64,
    /// Times the emergency stop engaged (rising edges).
    pub emergency_engaged: u64,
    /// Smallest TTC seen over the run, s.
    pub min_ttc: f64,
}

/// The safety layer's state.
#[derive(Debug, Clone)]
pub struct Safety {
    config: SafetyConfig,
    /// The TTC that engaged the stop, while engaged.
    engaged: Option<f64>,
    clear_since: Option<f64>,
    /// (invalid, beams) ahead in the newest scan, when over the limit.
    blind: Option<(usize, usize)>,
    /// Where the scans come from.
    mount: LaserMount,
    counters: SafetyCounters,
}

impl Safety {
    pub fn new(config: SafetyConfig) -> Result<Self, BridgeError> {
        config.validate()?;
        Ok(Self {
            config,
            engaged: None,
            clear_since: None,
            blind: None,
            mount: LaserMount::default(),
            counters: SafetyCounters {
                min_ttc: f64::INFINITY,
                ..SafetyCounters::default()
            },
        })
    }

    pub fn config(&self) -> &SafetyConfig {
        &self.config
    }

    pub fn counters(&self) -> &SafetyCounters {
        &self.counters
    }

    /// Take the laser's mount on the car (for TTC and the blind-ahead cone).
    pub fn set_mount(&mut self, mount: LaserMount) {
        self.mount = mount;
    }

    /// Is the emergency stop engaged?
    pub fn emergency_engaged(&self) -> bool {
        self.engaged.is_some()
    }

    /// Smallest time to collision over `scan`'s returns for a car moving forward at
    /// `speed` (infinite when not approaching anything): inside the straight-ahead strip
    /// of half width `corridor` when it is > 0, else per beam over all beams. Too-close
    /// beams (`-inf`) count as obstacles at `range_min`; invalid and no-return beams are
    /// skipped (REP 117).
    pub fn time_to_collision(scan: &LaserScan, speed: f64, corridor: f64) -> f64 {
        Self::time_to_collision_from(&LaserMount::default(), scan, speed, corridor)
    }

    /// [`Self::time_to_collision`] for a laser mounted at `mount`: the corridor in
    /// `base_link`, distances ahead measured from the laser's station along the car
    /// (`max(mount.x, 0)`: near the car's front on the F1TENTH car; base_link is the
    /// rear axle, and measuring from it would brake later than before).
    pub fn time_to_collision_from(
        mount: &LaserMount,
        scan: &LaserScan,
        speed: f64,
        corridor: f64,
    ) -> f64 {
        if !(speed.is_finite() && speed > 0.0) {
            return f64::INFINITY;
        }
        let (lo, hi) = (scan.range_min, scan.range_max);
        let station = mount.x.max(0.0);
        let mut best = f64::INFINITY;
        for (i, &r) in scan.ranges.iter().enumerate() {
            let Some(r) = Beam::classify(r, lo, hi).obstacle_range(lo as f64) else {
                continue;
            };
            let angle = scan.angle_min as f64 + i as f64 * scan.angle_increment as f64;
            let (px, py) = mount.point(angle, r);
            // distance ahead of the laser's station along the car (near its front)
            let ahead = px - station;
            if ahead <= 0.0 {
                continue;
            }
            let ttc = if corridor > 0.0 {
                if py.abs() > corridor {
                    continue;
                }
                ahead / speed
            } else {
                // r / (v cos), r and its angle seen from the station
                (ahead * ahead + py * py) / (speed * ahead)
            };
            best = best.min(ttc);
        }
        best
    }

    /// (invalid beams, beams) within `half_angle` of straight ahead.
    pub fn invalid_ahead(scan: &LaserScan, half_angle: f64) -> (usize, usize) {
        Self::invalid_ahead_from(&LaserMount::default(), scan, half_angle)
    }

    /// [`Self::invalid_ahead`] for a laser mounted at `mount` (ahead of the car).
    pub fn invalid_ahead_from(
        mount: &LaserMount,
        scan: &LaserScan,
        half_angle: f64,
    ) -> (usize, usize) {
        let (mut invalid, mut beams) = (0, 0);
        for (i, &r) in scan.ranges.iter().enumerate() {
            let angle = scan.angle_min as f64 + i as f64 * scan.angle_increment as f64;
            if paddock_sim::geometry::wrap_angle(mount.beam_angle(angle)).abs() > half_angle {
                continue;
            }
            beams += 1;
            if Beam::classify(r, scan.range_min, scan.range_max) == Beam::Invalid {
                invalid += 1;
            }
        }
        (invalid, beams)
    }

    /// Update the emergency stop and the blind-ahead check with a new scan taken while
    /// moving at `speed`.
    pub fn on_scan(&mut self, scan: &LaserScan, speed: f64, now: f64) {
        let (invalid, beams) =
            Self::invalid_ahead_from(&self.mount, scan, self.config.ahead_half_angle);
        let blind = invalid as f64 > self.config.max_invalid_ahead * beams as f64 || beams == 0;
        match (self.blind.is_some(), blind) {
            (false, true) => tracing::warn!(invalid, beams, "blind ahead: too many invalid beams"),
            (true, false) => tracing::info!("seeing ahead again"),
            _ => {}
        }
        self.blind = blind.then_some((invalid, beams));
        if self.config.ttc_threshold <= 0.0 {
            return;
        }
        let ttc =
            Self::time_to_collision_from(&self.mount, scan, speed, self.config.corridor_half_width);
        self.counters.min_ttc = self.counters.min_ttc.min(ttc);
        if ttc < self.config.ttc_threshold {
            if self.engaged.is_none() {
                self.counters.emergency_engaged += 1;
                tracing::warn!(ttc, speed, "emergency stop engaged");
                self.engaged = Some(ttc);
            }
            self.clear_since = None;
        } else if self.engaged.is_some() {
            let since = *self.clear_since.get_or_insert(now);
            if now - since >= self.config.ttc_release {
                tracing::info!("emergency stop released");
                self.engaged = None;
                self.clear_since = None;
            }
        }
    }

    /// Pass `requested` through the rules. `scan_age` / `odom_age` are the ages of the
    /// newest messages (None: never received); the scan is checked for staleness only when
    /// `needs_scan` (a LIDAR driver, or the emergency stop enabled).
    pub fn filter(
        &mut self,
        requested: Action,
        scan_age: Option<f64>,
        odom_age: Option<f64>,
        needs_scan: bool,
    ) -> Verdict {
        self.counters.commands += 1;
        let stale =
            |age: Option<f64>| age.is_none_or(|a| a.is_nan() || a > self.config.sensor_timeout);
        let stop = if stale(odom_age) {
            self.counters.stale += 1;
            Some(StopReason::StaleOdom { age: odom_age })
        } else if needs_scan && stale(scan_age) {
            self.counters.stale += 1;
            Some(StopReason::StaleScan { age: scan_age })
        } else if let Some(ttc) = self.engaged {
            self.counters.emergency += 1;
            Some(StopReason::Emergency { ttc })
        } else if let Some((invalid, beams)) = self.blind.filter(|_| needs_scan) {
            self.counters.blind += 1;
            Some(StopReason::BlindAhead { invalid, beams })
        } else if !(requested.steer.is_finite() && requested.speed.is_finite()) {
            self.counters.invalid += 1;
            Some(StopReason::InvalidCommand)
        } else {
            None
        };
        if stop.is_some() {
            return Verdict {
                action: Action::new(0.0, 0.0),
                stop,
                clamped: false,
            };
        }
        let c = &self.config;
        let action = Action::new(
            requested.steer.clamp(-c.max_steer, c.max_steer),
            requested.speed.clamp(c.min_speed, c.max_speed),
        );
        let clamped = action != requested;
        if clamped {
            self.counters.clamped += 1;
        }
        Verdict {
            action,
            stop: None,
            clamped,
        }
    }

    /// Does this configuration need a fresh scan even for a driver that does not read it?
    pub fn needs_scan(&self) -> bool {
        self.config.ttc_threshold > 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wall_ahead(distance: f32) -> LaserScan {
        // 5 beams over [-pi/2, pi/2]; the straight-ahead beam sees `distance`
        LaserScan {
            angle_min: -std::f32::consts::FRAC_PI_2,
            angle_max: std::f32::consts::FRAC_PI_2,
            angle_increment: std::f32::consts::FRAC_PI_4,
            range_min: 0.05,
            range_max: 30.0,
            ranges: vec![1.0, 20.0, distance, 20.0, 1.0],
            ..LaserScan::default()
        }
    }

    fn cfg() -> SafetyConfig {
        SafetyConfig {
            max_speed: 5.0,
            ..SafetyConfig::default()
        }
    }

    #[test]
    fn clamps_steer_and_speed() {
        let mut s = Safety::new(cfg()).unwrap();
        let v = s.filter(Action::new(0.9, 12.0), Some(0.0), Some(0.0), true);
        assert_eq!(v.action, Action::new(0.4189, 5.0));
        assert!(v.clamped && v.stop.is_none());
        let v = s.filter(Action::new(-0.9, -3.0), Some(0.0), Some(0.0), true);
        assert_eq!(v.action, Action::new(-0.4189, 0.0));
        let v = s.filter(Action::new(0.1, 2.0), Some(0.0), Some(0.0), true);
        assert_eq!(v.action, Action::new(0.1, 2.0));
        assert!(!v.clamped);
        assert_eq!(s.counters().clamped, 2);
        let v = s.filter(Action::new(f64::NAN, 2.0), Some(0.0), Some(0.0), true);
        assert_eq!(v.stop, Some(StopReason::InvalidCommand));
        assert_eq!(v.action.speed, 0.0);
    }

    #[test]
    fn stale_sensors_stop_the_car() {
        let mut s = Safety::new(cfg()).unwrap();
        let go = Action::new(0.0, 3.0);
        assert_eq!(
            s.filter(go, Some(0.1), None, true).stop,
            Some(StopReason::StaleOdom { age: None })
        );
        assert_eq!(
            s.filter(go, Some(0.3), Some(0.0), true).stop,
            Some(StopReason::StaleScan { age: Some(0.3) })
        );
        // a driver that does not read the scan, with the TTC check off, ignores its age
        assert_eq!(s.filter(go, None, Some(0.2), false).stop, None);
        assert_eq!(s.filter(go, Some(0.2), Some(0.2), true).action, go);
        assert_eq!(
            s.filter(go, Some(0.0), Some(f64::NAN), true).action.speed,
            0.0
        );
        assert_eq!(s.counters().stale, 3);
    }

    #[test]
    fn time_to_collision_uses_the_closing_speed_per_beam() {
        let scan = wall_ahead(2.0);
        // ahead: 2 m at 4 m/s = 0.5 s; the side beams at +-90 deg are not approached;
        // the 45 deg beams: 20 / (4 cos 45) = 7.07 s
        assert!((Safety::time_to_collision(&scan, 4.0, 0.0) - 0.5).abs() < 1e-6);
        assert_eq!(Safety::time_to_collision(&scan, 0.0, 0.0), f64::INFINITY);
        assert_eq!(Safety::time_to_collision(&scan, -2.0, 0.0), f64::INFINITY);
        let mut bad = wall_ahead(f32::NAN);
        bad.ranges[1] = 0.01; // below range_min: ignored
        let side = 20.0 / (4.0 * std::f64::consts::FRAC_1_SQRT_2);
        assert!((Safety::time_to_collision(&bad, 4.0, 0.0) - side).abs() < 1e-4);
        // the corridor keeps the return straight ahead, drops the 45 deg ones (14 m aside)
        assert!((Safety::time_to_collision(&scan, 4.0, 0.3) - 0.5).abs() < 1e-6);
        assert_eq!(Safety::time_to_collision(&bad, 4.0, 0.3), f64::INFINITY);
    }

    #[test]
    fn a_wall_beside_the_car_stops_only_the_classic_ttc() {
        // a wall 0.5 m to the left, parallel to the car: returns at angle a have r = 0.5 / sin a
        let n = 91;
        let inc = std::f64::consts::FRAC_PI_2 / (n - 1) as f64;
        let scan = LaserScan {
            angle_min: 0.0,
            angle_increment: inc as f32,
            range_min: 0.05,
            range_max: 30.0,
            ranges: (0..n)
                .map(|i| {
                    let a = i as f64 * inc;
                    if a < 0.02 {
                        f32::INFINITY
                    } else {
                        (0.5 / a.sin()).min(30.0) as f32
                    }
                })
                .collect(),
            ..LaserScan::default()
        };
        let classic = Safety::time_to_collision(&scan, 7.0, 0.0);
        assert!((classic - 2.0 * 0.5 / 7.0).abs() < 0.01, "{classic}");
        assert_eq!(Safety::time_to_collision(&scan, 7.0, 0.3), f64::INFINITY);
    }

    #[test]
    fn emergency_stop_engages_and_releases_after_a_clear_spell() {
        let mut s = Safety::new(cfg()).unwrap();
        let go = Action::new(0.0, 3.0);
        s.on_scan(&wall_ahead(10.0), 4.0, 0.0);
        assert_eq!(s.filter(go, Some(0.0), Some(0.0), true).action, go);
        s.on_scan(&wall_ahead(0.8), 4.0, 0.1); // 0.2 s < 0.25 s
        let v = s.filter(go, Some(0.0), Some(0.0), true);
        assert!(matches!(v.stop, Some(StopReason::Emergency { ttc }) if (ttc - 0.2).abs() < 1e-6));
        assert_eq!(v.action.speed, 0.0);
        // stopped: the TTC is clear, but the stop holds for ttc_release
        s.on_scan(&wall_ahead(0.8), 0.0, 0.2);
        s.on_scan(&wall_ahead(0.8), 0.0, 0.6);
        assert!(s.emergency_engaged());
        s.on_scan(&wall_ahead(0.8), 0.0, 0.71);
        assert!(!s.emergency_engaged());
        assert_eq!(s.filter(go, Some(0.0), Some(0.0), true).action, go);
        assert_eq!(s.counters().emergency_engaged, 1);
        assert_eq!(s.counters().emergency, 1);
    }

    #[test]
    fn disabled_ttc_never_engages_and_bad_config_is_named() {
        let mut s = Safety::new(SafetyConfig {
            ttc_threshold: 0.0,
            ..cfg()
        })
        .unwrap();
        s.on_scan(&wall_ahead(0.1), 5.0, 0.0);
        assert!(!s.emergency_engaged() && !s.needs_scan());
        let e = Safety::new(SafetyConfig {
            corridor_half_width: -1.0,
            ..cfg()
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("corridor_half_width"), "{e}");
        let e = Safety::new(SafetyConfig {
            max_speed: f64::NAN,
            ..cfg()
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("max_speed") && e.contains("NaN"), "{e}");
        let e = Safety::new(SafetyConfig {
            min_speed: 1.0,
            ..cfg()
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("min_speed = 1"), "{e}");
    }
}
