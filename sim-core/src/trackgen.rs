//! Seeded race-track generator.
//!
//! [`generate`] turns a [`TrackGenConfig`] into a closed, non-self-intersecting track of
//! about the requested length: a centerline with a smoothly varying width, a
//! minimum-curvature racing line with a speed profile, and an occupancy image.
//! [`GeneratedTrack::write`] stores it in the f1tenth racetracks layout (map YAML + PNG,
//! centerline CSV, TUM raceline CSV) that the simulator's map and track loaders read.
//!
//! Why this shape: corners come from a random star-shaped polygon (simple by
//! construction), edges stay straight and corners are rounded by a cubic B-spline, which
//! gives real-looking straights, hairpins, chicanes and sweepers with continuous
//! curvature. A candidate whose tightest corner is below the minimum radius, or whose
//! corridor comes back within the wall gap of itself, is thrown away and the next one is
//! drawn from an independent stream forked from the seed, so the whole output (every
//! byte of every file) is a function of the config alone.

mod raceline;
mod raster;
mod shape;

use std::fmt::Write as _;
use std::io;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::rng::Rng;

/// Grey value of a free cell in the occupancy image.
pub const FREE: u8 = 254;
/// Grey value of an occupied cell.
pub const OCCUPIED: u8 = 0;
/// Centerline point spacing (m).
pub const CENTERLINE_SPACING: f64 = 0.1;
/// Raceline point spacing (m), as in the f1tenth racetracks files.
pub const RACELINE_SPACING: f64 = 0.2;
/// Bumped whenever the generator's output for a given config changes.
pub const GENERATOR_VERSION: u32 = 1;
/// Extra clearance the raceline optimiser keeps beyond `raceline_margin_m`, so that the
/// interpolated, resampled line still honours the margin.
const RACELINE_SLACK: f64 = 0.05;
/// Curvature below this (1/m; radius above 25 m) counts as straight when choosing the
/// start line.
const STRAIGHT_KAPPA: f64 = 0.04;

/// What to generate. Every field has a default; `seed` and `length_m` are the ones
/// usually set.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrackGenConfig {
    pub seed: u64,
    /// Target centerline length (m), 40..=600.
    pub length_m: f64,
    /// Narrowest track width (m, wall to wall).
    pub width_min: f64,
    /// Widest track width (m); the width varies smoothly between the two.
    pub width_max: f64,
    /// Map resolution (m per cell).
    pub resolution: f64,
    /// Occupied border around the track in the image (m).
    pub margin_m: f64,
    /// Least wall thickness (m) between two parts of the track that are not adjacent.
    pub wall_gap_m: f64,
    /// Least centerline radius of curvature (m).
    pub min_radius_m: f64,
    /// Least distance (m) from the raceline to either edge of the corridor.
    pub raceline_margin_m: f64,
    /// Candidates drawn before giving up.
    pub max_attempts: u32,
    /// Limits of the raceline's speed profile.
    pub speed: SpeedLimits,
}

impl Default for TrackGenConfig {
    fn default() -> Self {
        Self {
            seed: 0,
            length_m: 120.0,
            width_min: 2.0,
            width_max: 4.0,
            resolution: 0.05,
            margin_m: 2.0,
            wall_gap_m: 1.5,
            min_radius_m: 2.5,
            raceline_margin_m: 0.35,
            max_attempts: 500,
            speed: SpeedLimits::default(),
        }
    }
}

/// Speed-profile limits. The lateral limit is `mu * g * lateral_safety`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SpeedLimits {
    pub mu: f64,
    pub g: f64,
    pub lateral_safety: f64,
    /// Longitudinal acceleration limit (m/s^2).
    pub accel: f64,
    /// Braking limit (m/s^2, positive).
    pub brake: f64,
    /// Speed cap (m/s).
    pub v_max: f64,
}

impl Default for SpeedLimits {
    fn default() -> Self {
        // mu and g of the f1tenth_gym default vehicle; accel below its a_max of 9.51.
        Self {
            mu: 1.0489,
            g: 9.81,
            lateral_safety: 0.8,
            accel: 7.0,
            brake: 8.0,
            v_max: 12.0,
        }
    }
}

impl SpeedLimits {
    /// The lateral acceleration the profile may use (m/s^2).
    pub fn lateral_accel(&self) -> f64 {
        self.mu * self.g * self.lateral_safety
    }
}

#[derive(Debug, thiserror::Error)]
pub enum TrackGenError {
    #[error("invalid track generator config: {field} = {value}: {reason}")]
    InvalidConfig {
        field: &'static str,
        value: String,
        reason: String,
    },
    #[error("no valid track for seed {seed} after {attempts} attempts (last rejection: {reason})")]
    NoValidTrack {
        seed: u64,
        attempts: u32,
        reason: String,
    },
}

/// One raceline point, as in the TUM raceline CSV (the same type tracks load).
pub use crate::track::RacelinePoint;

/// An 8-bit grey occupancy image, row-major, row 0 at the top (highest y).
#[derive(Debug, Clone, PartialEq)]
pub struct OccupancyImage {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<u8>,
}

/// A generated track. The driving direction is counter-clockwise; the first centerline
/// point is the origin of the world frame, on the longest straight, heading along +x.
#[derive(Debug, Clone)]
pub struct GeneratedTrack {
    /// (x, y, w_right, w_left) at uniform spacing; the first point is not repeated.
    pub centerline: Vec<[f64; 4]>,
    /// The racing line, closed; the first point is not repeated.
    pub raceline: Vec<RacelinePoint>,
    pub occupancy: OccupancyImage,
    /// Metres per cell.
    pub resolution: f64,
    /// World position of the bottom-left corner of the image, and yaw 0.
    pub origin: [f64; 3],
    pub seed: u64,
    /// The candidate (1-based) that was accepted.
    pub attempts: u32,
    /// Centerline length (m).
    pub length_m: f64,
    /// Tightest centerline radius of curvature (m).
    pub min_radius_m: f64,
}

/// Generates the track that `config` describes (see the module docs).
pub fn generate(config: &TrackGenConfig) -> Result<GeneratedTrack, TrackGenError> {
    validate(config)?;
    let root = Rng::new(config.seed);
    let mut reason = String::new();
    for attempt in 1..=config.max_attempts {
        let mut rng = root.fork(u64::from(attempt));
        match candidate(config, &mut rng) {
            Ok((pts, widths, min_radius)) => {
                return Ok(finish(config, attempt, pts, widths, min_radius));
            }
            Err(why) => reason = why,
        }
    }
    Err(TrackGenError::NoValidTrack {
        seed: config.seed,
        attempts: config.max_attempts,
        reason,
    })
}

type Candidate = (Vec<[f64; 2]>, Vec<f64>, f64);

/// One candidate centerline and its widths, or why it was rejected.
fn candidate(config: &TrackGenConfig, rng: &mut Rng) -> Result<Candidate, String> {
    let target_radius = 1.05 * config.min_radius_m.max(0.5 * config.width_max + 0.5);
    let pts = shape::candidate(rng, config.length_m, CENTERLINE_SPACING, target_radius);
    if shape::signed_area2(&pts) <= 0.0 {
        return Err("clockwise".into());
    }
    let widths = shape::width_profile(rng, pts.len(), config.width_min, config.width_max);
    let kappa = shape::closed_curvature(&pts);
    let mut min_radius = f64::INFINITY;
    for (i, k) in kappa.iter().enumerate() {
        let radius = 1.0 / k.abs();
        let needed = config.min_radius_m.max(0.5 * widths[i] + 0.5);
        if radius < needed {
            return Err(format!("corner radius {radius:.2} m < {needed:.2} m"));
        }
        min_radius = min_radius.min(radius);
    }
    // The separation test at ~0.25 m spacing is as good and 6x cheaper than at 0.1 m.
    let stride = (libm::round(0.25 / CENTERLINE_SPACING) as usize).max(1);
    let coarse: Vec<[f64; 2]> = pts.iter().step_by(stride).copied().collect();
    let half: Vec<f64> = widths.iter().step_by(stride).map(|w| 0.5 * w).collect();
    if let Some((a, b)) = shape::find_too_close(&coarse, &half, config.wall_gap_m) {
        return Err(format!(
            "corridor too close to itself near ({:.1}, {:.1}) and ({:.1}, {:.1})",
            coarse[a][0], coarse[a][1], coarse[b][0], coarse[b][1]
        ));
    }
    Ok((pts, widths, min_radius))
}

/// Puts the start on the longest straight at the world origin heading +x, then builds the
/// raceline and the image.
fn finish(
    config: &TrackGenConfig,
    attempt: u32,
    pts: Vec<[f64; 2]>,
    widths: Vec<f64>,
    min_radius: f64,
) -> GeneratedTrack {
    let n = pts.len();
    let kappa = shape::closed_curvature(&pts);
    let start = start_index(&kappa);
    let pts: Vec<[f64; 2]> = (0..n).map(|i| pts[(start + i) % n]).collect();
    let widths: Vec<f64> = (0..n).map(|i| widths[(start + i) % n]).collect();
    let (p0, p1, pn) = (pts[0], pts[1], pts[n - 1]);
    let heading = libm::atan2(p1[1] - pn[1], p1[0] - pn[0]);
    let (s, c) = libm::sincos(-heading);
    let pts: Vec<[f64; 2]> = pts
        .iter()
        .map(|p| {
            let (dx, dy) = (p[0] - p0[0], p[1] - p0[1]);
            [c * dx - s * dy, s * dx + c * dy]
        })
        .collect();
    let half: Vec<f64> = widths.iter().map(|w| 0.5 * w).collect();

    let normals = shape::closed_left_normals(&pts);
    let keep = config.raceline_margin_m + RACELINE_SLACK;
    let hi: Vec<f64> = half.iter().map(|h| (h - keep).max(0.0)).collect();
    let lo: Vec<f64> = hi.iter().map(|h| -h).collect();
    let corridor = raceline::Corridor {
        points: &pts,
        normals: &normals,
        lo: &lo,
        hi: &hi,
        step: shape::closed_length(&pts) / n as f64,
    };
    let raceline = raceline::build(
        &raceline::optimal_line(&corridor),
        RACELINE_SPACING,
        &config.speed,
    );

    let (occupancy, origin) = raster::render(&pts, &half, config.resolution, config.margin_m);
    GeneratedTrack {
        centerline: (0..n)
            .map(|i| [pts[i][0], pts[i][1], half[i], half[i]])
            .collect(),
        raceline,
        occupancy,
        resolution: config.resolution,
        origin: [origin[0], origin[1], 0.0],
        seed: config.seed,
        attempts: attempt,
        length_m: shape::closed_length(&pts),
        min_radius_m: min_radius,
    }
}

/// A third of the way into the longest straight, so a grid has room ahead.
fn start_index(kappa: &[f64]) -> usize {
    let n = kappa.len();
    let straight = |i: usize| kappa[i % n].abs() < STRAIGHT_KAPPA;
    // Begin scanning just after a non-straight point so no run is split by the wrap.
    let Some(first_bend) = (0..n).find(|&i| !straight(i)) else {
        return 0;
    };
    let (mut best_start, mut best_len) = (0, 0);
    let mut i = first_bend + 1;
    while i <= first_bend + n {
        if straight(i) {
            let run_start = i;
            while i <= first_bend + n && straight(i) {
                i += 1;
            }
            if i - run_start > best_len {
                best_start = run_start;
                best_len = i - run_start;
            }
        } else {
            i += 1;
        }
    }
    (best_start + best_len / 3) % n
}

fn validate(c: &TrackGenConfig) -> Result<(), TrackGenError> {
    fn range(field: &'static str, v: f64, lo: f64, hi: f64) -> Result<(), TrackGenError> {
        if v.is_finite() && (lo..=hi).contains(&v) {
            Ok(())
        } else {
            Err(TrackGenError::InvalidConfig {
                field,
                value: v.to_string(),
                reason: format!("must be a number in [{lo}, {hi}]"),
            })
        }
    }
    range("length_m", c.length_m, 40.0, 600.0)?;
    range("width_min", c.width_min, 1.0, 8.0)?;
    range("width_max", c.width_max, 1.0, 8.0)?;
    if c.width_min > c.width_max {
        return Err(TrackGenError::InvalidConfig {
            field: "width_min",
            value: c.width_min.to_string(),
            reason: format!("must not exceed width_max ({})", c.width_max),
        });
    }
    range("resolution", c.resolution, 0.01, 0.5)?;
    range("margin_m", c.margin_m, 0.0, 50.0)?;
    range("wall_gap_m", c.wall_gap_m, 0.0, 10.0)?;
    range("min_radius_m", c.min_radius_m, 0.5, 50.0)?;
    range(
        "raceline_margin_m",
        c.raceline_margin_m,
        0.0,
        0.5 * c.width_min - RACELINE_SLACK,
    )?;
    if c.max_attempts == 0 {
        return Err(TrackGenError::InvalidConfig {
            field: "max_attempts",
            value: "0".into(),
            reason: "must be at least 1".into(),
        });
    }
    let s = &c.speed;
    range("speed.mu", s.mu, 0.01, 10.0)?;
    range("speed.g", s.g, 0.1, 100.0)?;
    range("speed.lateral_safety", s.lateral_safety, 0.01, 1.0)?;
    range("speed.accel", s.accel, 0.01, 100.0)?;
    range("speed.brake", s.brake, 0.01, 100.0)?;
    range("speed.v_max", s.v_max, 0.1, 100.0)?;
    Ok(())
}

impl GeneratedTrack {
    /// The image cell (column, row from the top) holding world point (x, y).
    pub fn cell_of(&self, x: f64, y: f64) -> Option<(u32, u32)> {
        let col = libm::floor((x - self.origin[0]) / self.resolution);
        let up = libm::floor((y - self.origin[1]) / self.resolution);
        let (w, h) = (self.occupancy.width as f64, self.occupancy.height as f64);
        if col < 0.0 || up < 0.0 || col >= w || up >= h {
            return None;
        }
        Some((col as u32, (h - 1.0 - up) as u32))
    }

    /// Whether world point (x, y) lies in a free cell.
    pub fn is_free(&self, x: f64, y: f64) -> bool {
        self.cell_of(x, y).is_some_and(|(c, r)| {
            self.occupancy.pixels[(r * self.occupancy.width + c) as usize] == FREE
        })
    }

    /// Number of free cells.
    pub fn free_cells(&self) -> usize {
        self.occupancy.pixels.iter().filter(|&&p| p == FREE).count()
    }

    /// Writes `dir/name/name_{map.yaml, map.png, centerline.csv, raceline.csv}` and returns
    /// the folder. `name` must be a plain file name.
    pub fn write(&self, dir: &Path, name: &str) -> io::Result<PathBuf> {
        let plain = !name.is_empty()
            && name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-' || c == '.')
            && name != "."
            && name != "..";
        if !plain {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("map name {name:?} must be a plain name (letters, digits, _ - .)"),
            ));
        }
        let folder = dir.join(name);
        std::fs::create_dir_all(&folder)?;
        std::fs::write(folder.join(format!("{name}_map.yaml")), self.map_yaml(name))?;
        std::fs::write(folder.join(format!("{name}_map.png")), self.map_png()?)?;
        std::fs::write(
            folder.join(format!("{name}_centerline.csv")),
            self.centerline_csv(),
        )?;
        std::fs::write(
            folder.join(format!("{name}_raceline.csv")),
            self.raceline_csv(),
        )?;
        Ok(folder)
    }

    /// The ROS map_server YAML.
    pub fn map_yaml(&self, name: &str) -> String {
        format!(
            "image: {name}_map.png\nresolution: {}\norigin: [{}, {}, 0.0]\nnegate: 0\n\
             occupied_thresh: 0.45\nfree_thresh: 0.196\n",
            self.resolution, self.origin[0], self.origin[1]
        )
    }

    /// The image as an 8-bit grey PNG.
    pub fn map_png(&self) -> io::Result<Vec<u8>> {
        use image::ImageEncoder;
        use image::codecs::png::{CompressionType, FilterType, PngEncoder};
        let mut out = Vec::new();
        PngEncoder::new_with_quality(&mut out, CompressionType::Best, FilterType::Adaptive)
            .write_image(
                &self.occupancy.pixels,
                self.occupancy.width,
                self.occupancy.height,
                image::ExtendedColorType::L8,
            )
            .map_err(io::Error::other)?;
        Ok(out)
    }

    /// The centerline CSV (`# x_m, y_m, w_tr_right_m, w_tr_left_m`).
    pub fn centerline_csv(&self) -> String {
        let mut out = String::from("# x_m, y_m, w_tr_right_m, w_tr_left_m\n");
        for [x, y, wr, wl] in &self.centerline {
            let _ = writeln!(out, "{x:.6}, {y:.6}, {wr:.6}, {wl:.6}");
        }
        out
    }

    /// The raceline CSV in the TUM format of the f1tenth racetracks.
    pub fn raceline_csv(&self) -> String {
        let mut out = format!(
            "# paddock trackgen v{GENERATOR_VERSION}\n# seed {}, centerline length {:.3} m\n\
             # s_m; x_m; y_m; psi_rad; kappa_radpm; vx_mps; ax_mps2\n",
            self.seed, self.length_m
        );
        for p in &self.raceline {
            let _ = writeln!(
                out,
                "{:.7};{:.7};{:.7};{:.7};{:.7};{:.7};{:.7}",
                p.s, p.x, p.y, p.psi, p.kappa, p.vx, p.ax
            );
        }
        out
    }
}

/// A minimum-curvature racing line for an existing circuit, inside the free space its map
/// really has: the corridor is measured along the centerline normals on the occupancy
/// grid (not taken from the centerline file's widths, which real maps do not always
/// honour), less `margin` metres on each side; where the corridor is narrower than two
/// margins the line keeps to its middle. Same optimiser and speed profile as the
/// generator's racelines.
pub fn raceline_in_map(
    map: &crate::map::Map,
    track: &crate::track::Track,
    margin: f64,
    limits: &SpeedLimits,
) -> Vec<RacelinePoint> {
    const STEP: f64 = 0.1;
    const MAX_REACH: f64 = 6.0;
    let length = track.length();
    let n = (libm::ceil(length / STEP) as usize).max(8);
    let step = length / n as f64;
    let probe = (0.5 * map.resolution()).max(0.01);
    let mut pts = Vec::with_capacity(n);
    let mut normals = Vec::with_capacity(n);
    let mut lo = Vec::with_capacity(n);
    let mut hi = Vec::with_capacity(n);
    for k in 0..n {
        let (pose, _, _) = track.at(k as f64 * step);
        let (s, c) = libm::sincos(pose.theta);
        let normal = [-s, c];
        // free distance to each side: march until the first occupied cell
        let free = |side: f64| {
            let mut d = 0.0;
            while d < MAX_REACH {
                if map.occupied_at(pose.x + side * d * normal[0], pose.y + side * d * normal[1]) {
                    return (d - probe).max(0.0);
                }
                d += probe;
            }
            MAX_REACH
        };
        let (left, right) = (free(1.0), free(-1.0));
        let (mut l, mut h) = (-(right - margin), left - margin);
        if l > h {
            let mid = 0.5 * (left - right);
            (l, h) = (mid, mid);
        }
        pts.push([pose.x, pose.y]);
        normals.push(normal);
        lo.push(l);
        hi.push(h);
    }
    let corridor = raceline::Corridor {
        points: &pts,
        normals: &normals,
        lo: &lo,
        hi: &hi,
        step,
    };
    raceline::build(&raceline::optimal_line(&corridor), RACELINE_SPACING, limits)
}
