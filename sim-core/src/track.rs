//! Tracks: the centerline and raceline of a circuit, progress by arc length, and laps.
//!
//! Progress is measured by projecting the car onto the closed centerline polyline and
//! unwrapping the arc-length coordinate step by step, so it is correct from any start
//! pose, grows when the car drives the track's direction and shrinks when it drives
//! backwards. A lap is complete when the unwrapped progress since the start first reaches
//! the next multiple of the track length: driving backwards never counts a lap, and the
//! distance lost backwards must be driven again before the next one counts.
//!
//! File formats are those of the F1TENTH racetracks collection:
//! `<name>_centerline.csv` (`x_m, y_m, w_tr_right_m, w_tr_left_m`) and
//! `<name>_raceline.csv` (`s_m; x_m; y_m; psi_rad; kappa_radpm; vx_mps; ax_mps2`).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock, Weak};

use serde::{Deserialize, Serialize};

use crate::geometry::Pose;
use crate::map::{Map, MapError};

/// Errors while loading a track or a circuit. Each names the file and what is wrong.
#[derive(Debug, thiserror::Error)]
pub enum TrackError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path} line {line}: {message}")]
    Parse {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
    #[error(transparent)]
    Map(#[from] MapError),
    #[error(
        "unknown map {name:?}: not a directory or map YAML, and not among the maps in {searched}"
    )]
    UnknownMap { name: String, searched: String },
}

/// One centerline sample: position and the free width to each side (metres).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CenterPoint {
    pub x: f64,
    pub y: f64,
    pub w_right: f64,
    pub w_left: f64,
}

/// One raceline sample (the TUM global raceline format).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RacelinePoint {
    pub s: f64,
    pub x: f64,
    pub y: f64,
    /// Heading, radians CCW from +x.
    pub psi: f64,
    /// Signed curvature, 1/m.
    pub kappa: f64,
    /// Target speed, m/s.
    pub vx: f64,
    /// Target longitudinal acceleration, m/s^2.
    pub ax: f64,
}

/// Where a point projects onto the centerline.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Projection {
    /// Arc length along the centerline, in [0, length).
    pub s: f64,
    /// Index of the segment the point projects onto.
    pub segment: usize,
    /// Signed lateral offset, positive to the left of the driving direction.
    pub lateral: f64,
    /// Heading of the centerline at the projection.
    pub heading: f64,
}

/// A closed centerline (and optional raceline) with an arc-length index.
#[derive(Debug, Clone)]
pub struct Track {
    points: Vec<CenterPoint>,
    /// Cumulative arc length at each point; `cum_s[n] = length` closes the loop.
    cum_s: Vec<f64>,
    /// Unit direction and length of the segment from point i to point i+1 (wrapping).
    seg_dir: Vec<(f64, f64)>,
    seg_len: Vec<f64>,
    length: f64,
    raceline: Option<Vec<RacelinePoint>>,
    /// Coarse spatial hash of segments for global projection.
    grid: SegmentGrid,
}

/// How far (in segments) a local projection search looks around its hint.
const LOCAL_WINDOW: usize = 6;

impl Track {
    /// A track from centerline points (the loop closes from the last point back to the
    /// first; a duplicated closing point is dropped).
    pub fn new(
        mut points: Vec<CenterPoint>,
        raceline: Option<Vec<RacelinePoint>>,
    ) -> Result<Self, String> {
        if points.len() >= 2 {
            let (a, b) = (points[0], points[points.len() - 1]);
            if libm::hypot(a.x - b.x, a.y - b.y) < 1e-9 {
                points.pop();
            }
        }
        if points.len() < 3 {
            return Err(format!(
                "a centerline needs at least 3 points, found {}",
                points.len()
            ));
        }
        for (i, p) in points.iter().enumerate() {
            if !(p.x.is_finite()
                && p.y.is_finite()
                && p.w_right.is_finite()
                && p.w_left.is_finite())
            {
                return Err(format!("centerline point {i} is not finite: {p:?}"));
            }
            if p.w_right < 0.0 || p.w_left < 0.0 {
                return Err(format!("centerline point {i} has a negative width: {p:?}"));
            }
        }
        let n = points.len();
        let mut cum_s = Vec::with_capacity(n + 1);
        let mut seg_dir = Vec::with_capacity(n);
        let mut seg_len = Vec::with_capacity(n);
        let mut s = 0.0;
        for i in 0..n {
            let (a, b) = (points[i], points[(i + 1) % n]);
            let len = libm::hypot(b.x - a.x, b.y - a.y);
            cum_s.push(s);
            let dir = if len > 0.0 {
                ((b.x - a.x) / len, (b.y - a.y) / len)
            } else {
                (1.0, 0.0)
            };
            seg_dir.push(dir);
            seg_len.push(len);
            s += len;
        }
        cum_s.push(s);
        if s <= 0.0 {
            return Err("the centerline has zero length".into());
        }
        if let Some(r) = &raceline {
            if r.len() < 3 {
                return Err(format!(
                    "a raceline needs at least 3 points, found {}",
                    r.len()
                ));
            }
            if let Some((i, p)) = r.iter().enumerate().find(|(_, p)| {
                !(p.x.is_finite() && p.y.is_finite() && p.vx.is_finite() && p.psi.is_finite())
            }) {
                return Err(format!("raceline point {i} is not finite: {p:?}"));
            }
        }
        let grid = SegmentGrid::build(&points);
        Ok(Self {
            points,
            cum_s,
            seg_dir,
            seg_len,
            length: s,
            raceline,
            grid,
        })
    }

    /// Load `<centerline>.csv` and, if given, the raceline CSV.
    pub fn load(centerline: &Path, raceline: Option<&Path>) -> Result<Self, TrackError> {
        let points = parse_centerline(centerline)?;
        let race = match raceline {
            Some(p) => Some(parse_raceline(p)?),
            None => None,
        };
        Track::new(points, race).map_err(|message| TrackError::Invalid {
            path: centerline.to_path_buf(),
            message,
        })
    }

    pub fn points(&self) -> &[CenterPoint] {
        &self.points
    }

    pub fn raceline(&self) -> Option<&[RacelinePoint]> {
        self.raceline.as_deref()
    }

    /// Centerline length in metres.
    pub fn length(&self) -> f64 {
        self.length
    }

    /// Position, heading and widths at arc length `s` (wrapped into the loop).
    pub fn at(&self, s: f64) -> (Pose, f64, f64) {
        let s = s.rem_euclid(self.length);
        let i = match self.cum_s.binary_search_by(|v| v.total_cmp(&s)) {
            Ok(i) => i.min(self.points.len() - 1),
            Err(i) => i - 1,
        };
        let t = if self.seg_len[i] > 0.0 {
            (s - self.cum_s[i]) / self.seg_len[i]
        } else {
            0.0
        };
        let n = self.points.len();
        let (a, b) = (self.points[i], self.points[(i + 1) % n]);
        let (dx, dy) = self.seg_dir[i];
        let pose = Pose::new(
            a.x + t * (b.x - a.x),
            a.y + t * (b.y - a.y),
            libm::atan2(dy, dx),
        );
        let wr = a.w_right + t * (b.w_right - a.w_right);
        let wl = a.w_left + t * (b.w_left - a.w_left);
        (pose, wr, wl)
    }

    fn project_on_segment(&self, i: usize, x: f64, y: f64) -> (f64, f64, f64) {
        // returns (squared distance, t in [0, len], signed lateral)
        let a = self.points[i];
        let (dx, dy) = self.seg_dir[i];
        let (rx, ry) = (x - a.x, y - a.y);
        let t = (rx * dx + ry * dy).clamp(0.0, self.seg_len[i]);
        let (px, py) = (a.x + t * dx, a.y + t * dy);
        let d2 = (x - px) * (x - px) + (y - py) * (y - py);
        let lateral = dx * ry - dy * rx;
        (d2, t, lateral)
    }

    fn projection_from(&self, i: usize, t: f64, lateral: f64) -> Projection {
        let (dx, dy) = self.seg_dir[i];
        let mut s = self.cum_s[i] + t;
        if s >= self.length {
            s -= self.length;
        }
        Projection {
            s,
            segment: i,
            lateral,
            heading: libm::atan2(dy, dx),
        }
    }

    /// The nearest of `segments` to (x, y) as (squared distance, segment, t, lateral);
    /// ties go to the lower index, so the result never depends on the search order.
    fn nearest_segment(
        &self,
        segments: impl Iterator<Item = usize>,
        x: f64,
        y: f64,
    ) -> (f64, usize, f64, f64) {
        let mut best = (f64::INFINITY, 0usize, 0.0, 0.0);
        for i in segments {
            let (d2, t, lat) = self.project_on_segment(i, x, y);
            if d2 < best.0 || (d2 == best.0 && i < best.1) {
                best = (d2, i, t, lat);
            }
        }
        best
    }

    /// Is a nearest-segment answer beyond the radius within which the segment grid's
    /// candidate lists are exact?
    fn beyond_grid(&self, d2: f64) -> bool {
        d2.is_nan() || d2.sqrt() > self.grid.exact_radius
    }

    /// Project a point onto the centerline: the nearest point of the polyline.
    pub fn project(&self, x: f64, y: f64) -> Projection {
        let n = self.points.len();
        let mut best = match self.grid.candidates(x, y) {
            Some(list) => self.nearest_segment(list.iter().map(|&i| i as usize), x, y),
            None => self.nearest_segment(0..n, x, y),
        };
        // The grid lists every segment within its search radius of the cell; a point
        // farther than that from every listed segment may have a nearer unlisted one.
        if self.beyond_grid(best.0) {
            best = self.nearest_segment(0..n, x, y);
        }
        self.projection_from(best.1, best.2, best.3)
    }

    /// Project near a previous projection (`hint` = its segment): a local search that
    /// falls back to the global one when the point is not near that part of the track.
    pub fn project_near(&self, x: f64, y: f64, hint: usize) -> Projection {
        let n = self.points.len();
        if n <= 2 * LOCAL_WINDOW + 1 {
            return self.project(x, y);
        }
        let first = (hint + n - LOCAL_WINDOW) % n;
        let best = self.nearest_segment((0..=2 * LOCAL_WINDOW).map(|k| (first + k) % n), x, y);
        // Accept the local answer only if it lies strictly inside the window; otherwise
        // the car may have moved on (or jumped) and the global search decides.
        let offset = (best.1 + n - first) % n;
        if offset == 0 || offset == 2 * LOCAL_WINDOW || self.beyond_grid(best.0) {
            return self.project(x, y);
        }
        self.projection_from(best.1, best.2, best.3)
    }

    /// Signed arc-length difference `s_new - s_old` wrapped into [-L/2, L/2).
    pub fn ds(&self, s_old: f64, s_new: f64) -> f64 {
        let l = self.length;
        let d = s_new - s_old;
        d - l * libm::floor((d + 0.5 * l) / l)
    }
}

/// Parse an F1TENTH centerline CSV: `x, y, w_right, w_left` per line, `#` comments.
pub fn parse_centerline(path: &Path) -> Result<Vec<CenterPoint>, TrackError> {
    let text = std::fs::read_to_string(path).map_err(|source| TrackError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut out = Vec::new();
    for (ln, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let v = parse_fields(path, ln + 1, line, ',', 4)?;
        out.push(CenterPoint {
            x: v[0],
            y: v[1],
            w_right: v[2],
            w_left: v[3],
        });
    }
    Ok(out)
}

/// Parse a raceline CSV in the TUM format: `s; x; y; psi; kappa; vx; ax`, `#` comments.
pub fn parse_raceline(path: &Path) -> Result<Vec<RacelinePoint>, TrackError> {
    let text = std::fs::read_to_string(path).map_err(|source| TrackError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut out = Vec::new();
    for (ln, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let v = parse_fields(path, ln + 1, line, ';', 7)?;
        out.push(RacelinePoint {
            s: v[0],
            x: v[1],
            y: v[2],
            psi: v[3],
            kappa: v[4],
            vx: v[5],
            ax: v[6],
        });
    }
    Ok(out)
}

fn parse_fields(
    path: &Path,
    line: usize,
    text: &str,
    sep: char,
    n: usize,
) -> Result<Vec<f64>, TrackError> {
    let fields: Vec<&str> = text.split(sep).map(str::trim).collect();
    if fields.len() < n {
        return Err(TrackError::Parse {
            path: path.to_path_buf(),
            line,
            message: format!(
                "expected {n} fields separated by {sep:?}, found {}: {text:?}",
                fields.len()
            ),
        });
    }
    fields[..n]
        .iter()
        .enumerate()
        .map(|(col, f)| match f.parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err(TrackError::Parse {
                path: path.to_path_buf(),
                line,
                message: format!("column {} is not a finite number: {f:?}", col + 1),
            }),
        })
        .collect()
}

/// A uniform grid over the track's bounding box listing, per cell, every segment within
/// `exact_radius` of the cell. A point whose nearest listed segment is within that radius
/// has its exact nearest segment in the list.
#[derive(Debug, Clone)]
struct SegmentGrid {
    x0: f64,
    y0: f64,
    cell: f64,
    nx: usize,
    ny: usize,
    exact_radius: f64,
    starts: Vec<u32>,
    items: Vec<u32>,
}

impl SegmentGrid {
    fn build(points: &[CenterPoint]) -> Self {
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

    fn candidates(&self, x: f64, y: f64) -> Option<&[u32]> {
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

/// Per-agent progress along the track and lap timing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LapCounter {
    /// Centerline arc length at the last update.
    pub s: f64,
    /// Segment index of the last projection (search hint).
    pub segment: usize,
    /// Unwrapped arc length driven since the start (negative when backwards).
    pub progress: f64,
    /// Completed laps.
    pub laps: u32,
    /// Time of each completed lap, seconds.
    pub lap_times: Vec<f64>,
    /// Episode time at which the current lap started.
    pub lap_start_time: f64,
}

impl LapCounter {
    /// Start counting at `(x, y)` at episode time `t`.
    pub fn start(track: &Track, x: f64, y: f64, t: f64) -> Self {
        let p = track.project(x, y);
        Self {
            s: p.s,
            segment: p.segment,
            progress: 0.0,
            laps: 0,
            lap_times: Vec::new(),
            lap_start_time: t,
        }
    }

    /// Update with the car's new position after a step that ended at time `t` and lasted
    /// `dt`. Returns the number of laps completed in this step (0 or 1 in practice). Lap
    /// times are interpolated within the step.
    pub fn update(&mut self, track: &Track, x: f64, y: f64, t: f64, dt: f64) -> u32 {
        let p = track.project_near(x, y, self.segment);
        let ds = track.ds(self.s, p.s);
        let before = self.progress;
        self.s = p.s;
        self.segment = p.segment;
        self.progress += ds;
        let mut completed = 0;
        let l = track.length();
        while self.progress >= (self.laps as f64 + 1.0) * l {
            let target = (self.laps as f64 + 1.0) * l;
            let frac = if self.progress > before {
                ((target - before) / (self.progress - before)).clamp(0.0, 1.0)
            } else {
                1.0
            };
            let t_cross = t - dt + frac * dt;
            self.lap_times.push(t_cross - self.lap_start_time);
            self.lap_start_time = t_cross;
            self.laps += 1;
            completed += 1;
        }
        completed
    }

    /// Time of the current (unfinished) lap so far, or the last lap's time.
    pub fn current_lap_time(&self, t: f64) -> f64 {
        t - self.lap_start_time
    }
}

/// A circuit: an occupancy map and its track, loaded from one directory in the
/// F1TENTH racetracks layout (`<name>_map.yaml`, `<name>_centerline.csv`, optional
/// `<name>_raceline.csv`). Circuits are shared: loading the same directory twice in one
/// process returns the same `Arc`.
#[derive(Debug)]
pub struct Circuit {
    pub name: String,
    pub dir: PathBuf,
    pub map: Arc<Map>,
    pub track: Arc<Track>,
    /// The line drivers follow, computed on first use (see [`Circuit::driving_line`]).
    driving_line: OnceLock<Vec<RacelinePoint>>,
}

/// A raceline whose points keep at least this clearance (m) from every wall is driven as
/// it is; otherwise [`Circuit::driving_line`] computes one inside the map's free space.
pub const DRIVING_LINE_CLEARANCE: f64 = 0.25;
/// Wall margin (m) of a computed driving line: half the car's width plus room to track.
pub const DRIVING_LINE_MARGIN: f64 = 0.4;

type CircuitCache = Mutex<HashMap<PathBuf, Weak<Circuit>>>;

fn circuit_cache() -> &'static CircuitCache {
    static CACHE: OnceLock<CircuitCache> = OnceLock::new();
    CACHE.get_or_init(|| Mutex::new(HashMap::new()))
}

impl Circuit {
    pub fn new(name: &str, dir: PathBuf, map: Arc<Map>, track: Arc<Track>) -> Self {
        Self {
            name: name.to_string(),
            dir,
            map,
            track,
            driving_line: OnceLock::new(),
        }
    }

    /// The racing line drivers follow: the circuit's raceline if it keeps
    /// [`DRIVING_LINE_CLEARANCE`] from the walls everywhere, else (no raceline, or one
    /// that grazes walls, as the racelines of some real tracks do where the map's corridor
    /// is narrower than its centerline file claims) a minimum-curvature line computed
    /// inside the map's free space, [`DRIVING_LINE_MARGIN`] from the walls. Computed once
    /// per circuit, deterministically.
    pub fn driving_line(&self) -> &[RacelinePoint] {
        self.driving_line.get_or_init(|| {
            if let Some(r) = self.track.raceline()
                && r.iter()
                    .all(|p| self.map.clearance(p.x, p.y) >= DRIVING_LINE_CLEARANCE)
            {
                return r.to_vec();
            }
            crate::trackgen::raceline_in_map(
                &self.map,
                &self.track,
                DRIVING_LINE_MARGIN,
                &crate::trackgen::SpeedLimits::default(),
            )
        })
    }

    /// Load the circuit in `dir`, or the circuit whose map YAML is `dir`.
    pub fn load(path: &Path) -> Result<Arc<Circuit>, TrackError> {
        let dir = if path.is_file() {
            path.parent().unwrap_or(Path::new(".")).to_path_buf()
        } else {
            path.to_path_buf()
        };
        let key = dir.canonicalize().map_err(|source| TrackError::Io {
            path: dir.clone(),
            source,
        })?;
        if let Some(c) = circuit_cache()
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get(&key)
            .and_then(Weak::upgrade)
        {
            return Ok(c);
        }
        let yaml = if path.is_file() {
            path.to_path_buf()
        } else {
            find_with_suffix(&dir, "_map.yaml")?
        };
        let file_name = yaml
            .file_name()
            .and_then(|n| n.to_str())
            .unwrap_or_default()
            .to_string();
        let stem = file_name
            .strip_suffix("_map.yaml")
            .or_else(|| file_name.strip_suffix(".yaml"))
            .unwrap_or(&file_name)
            .to_string();
        let centerline = dir.join(format!("{stem}_centerline.csv"));
        if !centerline.is_file() {
            return Err(TrackError::Invalid {
                path: centerline,
                message: "missing centerline file (a circuit needs <name>_centerline.csv next to its map YAML)".into(),
            });
        }
        let raceline = dir.join(format!("{stem}_raceline.csv"));
        let map = Map::load(&yaml)?;
        let track = Track::load(
            &centerline,
            raceline.is_file().then_some(raceline.as_path()),
        )?;
        let circuit = Arc::new(Circuit::new(&stem, key.clone(), map, Arc::new(track)));
        circuit_cache()
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert(key, Arc::downgrade(&circuit));
        Ok(circuit)
    }

    /// Resolve a map by name or path: an existing directory or YAML path is loaded as is;
    /// otherwise `name` is looked up (case-insensitively) among the maps in `extra_dirs`,
    /// then in the folders added by [`crate::shipped::add_map_dirs`], then among the maps
    /// shipped inside the library ([`crate::shipped`]).
    pub fn resolve(name: &str, extra_dirs: &[PathBuf]) -> Result<Arc<Circuit>, TrackError> {
        let p = Path::new(name);
        if p.exists() {
            return Circuit::load(p);
        }
        let mut dirs: Vec<PathBuf> = extra_dirs.to_vec();
        dirs.extend(crate::shipped::map_dirs());
        for d in &dirs {
            for entry in list_circuit_dirs(d) {
                if entry
                    .file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.eq_ignore_ascii_case(name))
                {
                    return Circuit::load(&entry);
                }
            }
        }
        if let Some(m) = crate::shipped::shipped_map(name) {
            return Circuit::load(&crate::shipped::shipped_map_dir(m)?);
        }
        let shipped: Vec<&str> = crate::shipped::shipped_maps()
            .iter()
            .map(|m| m.name)
            .collect();
        let mut searched: Vec<String> = dirs.iter().map(|d| d.display().to_string()).collect();
        searched.push(format!("the shipped maps ({})", shipped.join(", ")));
        Err(TrackError::UnknownMap {
            name: name.to_string(),
            searched: searched.join(", "),
        })
    }

    /// The default circuit (the first shipped map, [`DEFAULT_MAP`]).
    pub fn default_circuit() -> Result<Arc<Circuit>, TrackError> {
        Circuit::resolve(DEFAULT_MAP, &[])
    }
}

/// The map used whenever no map is named.
pub const DEFAULT_MAP: &str = "lakeside";

/// The circuit directories inside `dir` (those holding a `*_map.yaml`), sorted by name.
pub fn list_circuit_dirs(dir: &Path) -> Vec<PathBuf> {
    let mut out: Vec<PathBuf> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_dir() && find_with_suffix(p, "_map.yaml").is_ok())
        .collect();
    out.sort();
    out
}

fn find_with_suffix(dir: &Path, suffix: &str) -> Result<PathBuf, TrackError> {
    let rd = std::fs::read_dir(dir).map_err(|source| TrackError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut found: Vec<PathBuf> = rd
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.ends_with(suffix))
        })
        .collect();
    found.sort();
    found.into_iter().next().ok_or_else(|| TrackError::Invalid {
        path: dir.to_path_buf(),
        message: format!("no *{suffix} file in this directory"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A circle of radius r sampled at n points, counter-clockwise.
    fn circle(r: f64, n: usize) -> Track {
        let pts = (0..n)
            .map(|i| {
                let a = std::f64::consts::TAU * i as f64 / n as f64;
                CenterPoint {
                    x: r * a.cos(),
                    y: r * a.sin(),
                    w_right: 1.0,
                    w_left: 1.0,
                }
            })
            .collect();
        Track::new(pts, None).unwrap()
    }

    #[test]
    fn length_and_projection() {
        let t = circle(10.0, 400);
        let exact = 2.0 * 400.0 * 10.0 * (std::f64::consts::PI / 400.0).sin();
        assert!((t.length() - exact).abs() < 1e-9);
        let p = t.project(0.0, 10.5);
        assert!((p.s - t.length() / 4.0).abs() < 0.01, "{p:?}");
        assert!(p.lateral < 0.0, "outside a CCW loop is to the right");
        assert_eq!(t.project_near(0.0, 10.5, p.segment), p);
    }

    #[test]
    fn ds_wraps() {
        let t = circle(10.0, 100);
        let l = t.length();
        assert!((t.ds(l - 0.1, 0.1) - 0.2).abs() < 1e-12);
        assert!((t.ds(0.1, l - 0.1) + 0.2).abs() < 1e-12);
    }

    fn drive(t: &Track, start_angle: f64, dir: f64, seconds: f64, omega: f64) -> LapCounter {
        let dt = 0.01;
        let r = 10.0;
        let mut c = LapCounter::start(t, r * start_angle.cos(), r * start_angle.sin(), 0.0);
        let steps = (seconds / dt).round() as usize;
        for k in 1..=steps {
            let a = start_angle + dir * omega * k as f64 * dt;
            c.update(t, r * a.cos(), r * a.sin(), k as f64 * dt, dt);
        }
        c
    }

    #[test]
    fn laps_from_any_start() {
        let t = circle(10.0, 400);
        // one revolution every 2*pi/omega seconds
        let omega = 1.0;
        let period = std::f64::consts::TAU / omega;
        for start in [0.0, 1.0, 2.5, 5.9] {
            let c = drive(&t, start, 1.0, 2.5 * period, omega);
            assert_eq!(c.laps, 2, "start {start}");
            for lt in &c.lap_times {
                assert!((lt - period).abs() < 0.02, "lap time {lt} vs {period}");
            }
        }
    }

    #[test]
    fn backwards_never_counts_laps() {
        let t = circle(10.0, 400);
        let c = drive(&t, 0.3, -1.0, 20.0, 1.0);
        assert_eq!(c.laps, 0);
        assert!(c.progress < -2.0 * t.length());
    }

    #[test]
    fn lost_distance_must_be_driven_again() {
        let t = circle(10.0, 400);
        let dt = 0.01;
        let r = 10.0;
        let mut c = LapCounter::start(&t, r, 0.0, 0.0);
        let mut a: f64 = 0.0;
        let mut time = 0.0;
        // back a quarter lap, then forward one full lap: still short of a lap
        for (dir, rev) in [(-1.0, 0.25), (1.0, 1.0)] {
            let steps = (rev * 628.0) as usize;
            for _ in 0..steps {
                a += dir * std::f64::consts::TAU / 628.0;
                time += dt;
                c.update(&t, r * a.cos(), r * a.sin(), time, dt);
            }
        }
        assert_eq!(c.laps, 0);
        for _ in 0..200 {
            a += std::f64::consts::TAU / 628.0;
            time += dt;
            c.update(&t, r * a.cos(), r * a.sin(), time, dt);
        }
        assert_eq!(c.laps, 1);
    }

    #[test]
    fn bad_centerline_rejected() {
        let pts = vec![
            CenterPoint {
                x: 0.0,
                y: 0.0,
                w_right: 1.0,
                w_left: 1.0,
            };
            2
        ];
        assert!(Track::new(pts, None).is_err());
        let mut pts: Vec<CenterPoint> = circle(5.0, 10).points().to_vec();
        pts[3].x = f64::NAN;
        let e = Track::new(pts, None).unwrap_err();
        assert!(e.contains("point 3"), "{e}");
    }
}
