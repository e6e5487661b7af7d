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

mod csv;
mod grid;
mod laps;

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

pub use csv::{parse_centerline, parse_centerline_text, parse_raceline, parse_raceline_text};
pub use laps::LapCounter;

use crate::geometry::Pose;
use crate::map::MapError;
use grid::SegmentGrid;

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
    length: f64,
    raceline: Option<Vec<RacelinePoint>>,
    /// Coarse spatial hash of segments for global projection.
    grid: SegmentGrid,
    /// The segments from point i to point i+1 (wrapping), see [`Segments`].
    seg: Segments,
}

/// Each segment's start, unit direction and length as arrays, segment `j mod n` at `j`
/// for `j < n + 2 LOCAL_WINDOW`: a local search's window of segments is one run of
/// consecutive entries, wrapping or not, which the compiler can step through in vectors.
#[derive(Debug, Clone)]
struct Segments {
    ax: Vec<f64>,
    ay: Vec<f64>,
    dx: Vec<f64>,
    dy: Vec<f64>,
    len: Vec<f64>,
}

impl Segments {
    fn new(points: &[CenterPoint], dirs: &[(f64, f64)], lens: &[f64]) -> Segments {
        let idx = (0..points.len() + 2 * LOCAL_WINDOW).map(|j| j % points.len());
        Segments {
            ax: idx.clone().map(|i| points[i].x).collect(),
            ay: idx.clone().map(|i| points[i].y).collect(),
            dx: idx.clone().map(|i| dirs[i].0).collect(),
            dy: idx.clone().map(|i| dirs[i].1).collect(),
            len: idx.map(|i| lens[i]).collect(),
        }
    }

    /// The squared distances from (x, y) to segments `first..first + 2 LOCAL_WINDOW + 1`
    /// (`first < n`), each as [`Track::project_on_segment`] computes it (the same
    /// operations, so the same bits).
    #[inline]
    fn window(&self, first: usize, x: f64, y: f64) -> [f64; 2 * LOCAL_WINDOW + 1] {
        const W: usize = 2 * LOCAL_WINDOW + 1;
        let r = first..first + W;
        let (ax, ay) = (&self.ax[r.clone()], &self.ay[r.clone()]);
        let (dx, dy, len) = (&self.dx[r.clone()], &self.dy[r.clone()], &self.len[r]);
        let mut d2 = [0.0; W];
        for k in 0..W {
            let (rx, ry) = (x - ax[k], y - ay[k]);
            let t = rx * dx[k] + ry * dy[k];
            // `f64::clamp(0.0, len)`, NaN kept, as a select
            let t = if t < 0.0 { 0.0 } else { t };
            let t = if t > len[k] { len[k] } else { t };
            let (px, py) = (ax[k] + t * dx[k], ay[k] + t * dy[k]);
            d2[k] = (x - px) * (x - px) + (y - py) * (y - py);
        }
        d2
    }
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
        let seg = Segments::new(&points, &seg_dir, &seg_len);
        Ok(Self {
            points,
            cum_s,
            length: s,
            raceline,
            grid,
            seg,
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
        let s = crate::geometry::wrap_length(s, self.length);
        let i = match self.cum_s.binary_search_by(|v| v.total_cmp(&s)) {
            Ok(i) => i.min(self.points.len() - 1),
            Err(i) => i - 1,
        };
        let t = if self.seg.len[i] > 0.0 {
            (s - self.cum_s[i]) / self.seg.len[i]
        } else {
            0.0
        };
        let n = self.points.len();
        let (a, b) = (self.points[i], self.points[(i + 1) % n]);
        let (dx, dy) = (self.seg.dx[i], self.seg.dy[i]);
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
        let (ax, ay) = (self.seg.ax[i], self.seg.ay[i]);
        let (dx, dy) = (self.seg.dx[i], self.seg.dy[i]);
        let (rx, ry) = (x - ax, y - ay);
        let t = (rx * dx + ry * dy).clamp(0.0, self.seg.len[i]);
        let (px, py) = (ax + t * dx, ay + t * dy);
        let d2 = (x - px) * (x - px) + (y - py) * (y - py);
        let lateral = dx * ry - dy * rx;
        (d2, t, lateral)
    }

    fn projection_from(&self, i: usize, t: f64, lateral: f64) -> Projection {
        let (dx, dy) = (self.seg.dx[i], self.seg.dy[i]);
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

    /// The nearest to (x, y) of the segments `candidates` gives with their squared
    /// distances, as (squared distance, segment, t, lateral); ties go to the lower index,
    /// so the result never depends on the search order. (infinity, 0, 0, 0) when none is
    /// nearer than infinity.
    fn nearest_segment(
        &self,
        candidates: impl Iterator<Item = (usize, f64)>,
        x: f64,
        y: f64,
    ) -> (f64, usize, f64, f64) {
        let mut best = (f64::INFINITY, 0usize);
        for (i, d2) in candidates {
            if d2 < best.0 || (d2 == best.0 && i < best.1) {
                best = (d2, i);
            }
        }
        if best.0 == f64::INFINITY {
            return (f64::INFINITY, 0, 0.0, 0.0);
        }
        let (d2, t, lat) = self.project_on_segment(best.1, x, y);
        (d2, best.1, t, lat)
    }

    /// Segments `segments` with their squared distances to (x, y), for
    /// [`Track::nearest_segment`].
    fn distances(
        &self,
        segments: impl Iterator<Item = usize>,
        x: f64,
        y: f64,
    ) -> impl Iterator<Item = (usize, f64)> {
        segments.map(move |i| (i, self.project_on_segment(i, x, y).0))
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
            Some(list) => {
                let list = self.distances(list.iter().map(|&i| i as usize), x, y);
                self.nearest_segment(list, x, y)
            }
            None => self.nearest_segment(self.distances(0..n, x, y), x, y),
        };
        // The grid lists every segment within its search radius of the cell; a point
        // farther than that from every listed segment may have a nearer unlisted one.
        if self.beyond_grid(best.0) {
            best = self.nearest_segment(self.distances(0..n, x, y), x, y);
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
        // (Indices wrapped by a comparison: a remainder is an integer division, and this
        // runs every step of every car.)
        let wrap = |i: usize| if i >= n { i - n } else { i };
        let hint = if hint < n { hint } else { hint % n };
        let first = wrap(hint + n - LOCAL_WINDOW);
        // The window's distances all at once.
        let window = self.seg.window(first, x, y);
        let candidates = window
            .into_iter()
            .enumerate()
            .map(|(k, d2)| (wrap(first + k), d2));
        let best = self.nearest_segment(candidates, x, y);
        // Accept the local answer only if it lies strictly inside the window; otherwise
        // the car may have moved on (or jumped) and the global search decides.
        let offset = wrap(best.1 + n - first);
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

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A circle of radius r sampled at n points, counter-clockwise.
    pub(crate) fn circle(r: f64, n: usize) -> Track {
        Track::new(loop_points(r, n, 0.0), None).unwrap()
    }

    /// n points counter-clockwise on the loop of radius `r + wobble sin(3 a)` at angle a.
    fn loop_points(r: f64, n: usize, wobble: f64) -> Vec<CenterPoint> {
        (0..n)
            .map(|i| {
                let a = std::f64::consts::TAU * i as f64 / n as f64;
                let rr = r + wobble * (3.0 * a).sin();
                CenterPoint {
                    x: rr * a.cos(),
                    y: rr * a.sin(),
                    w_right: 1.0,
                    w_left: 1.0,
                }
            })
            .collect()
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

    /// `project_near` as it searched its window before the window's distances were
    /// taken all at once: the reference the test below holds it to, bit for bit.
    fn project_near_by_segments(t: &Track, x: f64, y: f64, hint: usize) -> Projection {
        let n = t.points.len();
        let first = (hint + n - LOCAL_WINDOW) % n;
        let mut best = (f64::INFINITY, 0usize, 0.0, 0.0);
        for i in (0..=2 * LOCAL_WINDOW).map(|k| (first + k) % n) {
            let (d2, s, lat) = t.project_on_segment(i, x, y);
            if d2 < best.0 || (d2 == best.0 && i < best.1) {
                best = (d2, i, s, lat);
            }
        }
        let offset = (best.1 + n - first) % n;
        if offset == 0 || offset == 2 * LOCAL_WINDOW || t.beyond_grid(best.0) {
            return t.project(x, y);
        }
        t.projection_from(best.1, best.2, best.3)
    }

    #[test]
    fn the_local_search_gives_the_bits_of_the_segment_by_segment_one() {
        let mut rng = crate::rng::Rng::new(17);
        let bits = |p: &Projection| (p.s.to_bits(), p.segment, p.lateral.to_bits());
        for trial in 0..40 {
            // Circles and wobbly loops of 14 to 300 points, some with repeated points.
            let n = 14 + rng.below(287) as usize;
            let r = rng.uniform_range(2.0, 50.0);
            let wobble = if trial % 2 == 0 { 0.0 } else { 0.3 * r };
            let mut pts = loop_points(r, n, wobble);
            if trial % 4 == 1 {
                pts[n / 2] = pts[n / 2 - 1];
            }
            let t = Track::new(pts, None).unwrap();
            let n = t.points.len();
            for _ in 0..500 {
                let a = rng.uniform_range(0.0, std::f64::consts::TAU);
                let rr = r * rng.uniform_range(0.5, 1.6);
                let (x, y) = (rr * a.cos(), rr * a.sin());
                // Hints near the answer, anywhere, and past the segment count.
                let near = t.project(x, y).segment + rng.below(5) as usize;
                for hint in [near % n, rng.below(n as u64) as usize, near + n] {
                    let want = project_near_by_segments(&t, x, y, hint % n);
                    assert_eq!(
                        bits(&t.project_near(x, y, hint)),
                        bits(&want),
                        "trial {trial}, ({x}, {y}), hint {hint} of {n}"
                    );
                }
            }
        }
    }

    #[test]
    fn ds_wraps() {
        let t = circle(10.0, 100);
        let l = t.length();
        assert!((t.ds(l - 0.1, 0.1) - 0.2).abs() < 1e-12);
        assert!((t.ds(0.1, l - 0.1) + 0.2).abs() < 1e-12);
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
