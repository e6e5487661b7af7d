//! The 2D LIDAR: exact ray casting on the occupancy grid and against oriented boxes, and
//! a bit-exact port of the f1tenth_gym reference scan.
//!
//! [`Lidar::scan`] is exact: each beam returns the distance to the first occupied cell
//! square or box side it meets (clamped to `max_range`), computed from the ray origin in
//! closed form, with no marching error. It is fast because the map stores, per free cell
//! and per quadrant of directions, the side of the largest all-free square that has the
//! cell as its corner and extends that way: a ray jumps straight to the far side of the
//! square ahead of it, and only when heading into a wall does it take exact one-cell
//! grid-traversal steps (Amanatides-Woo). Several beams are traced interleaved so their
//! memory loads overlap; the march runs on the widest [`ScanPath`] the CPU supports
//! (AVX-512, AVX or portable), all giving the same bits.
//!
//! A scan can instead be taken, on every path, by an angular sweep over the map's wall
//! faces (`sweep`): runs of cell sides between free and occupied cells, block by block
//! from the car outwards, crossed with the beams that can see them by the march's own
//! expressions; beams whose crossings fall within 1e-9 cells of a run's end, where the
//! march's rounding decides, are marched. So it gives the march's bits (tested on every
//! track). Which of the two is faster depends on the map and the CPU, so by default
//! ([`ScanAlgorithm::Auto`]) each thread times both on its first scans of a map and
//! again from time to time, and takes the faster (`choice`); [`Lidar::with_algorithm`]
//! forces either. [`Lidar::scan_reference`] reproduces the
//! reference's sphere tracing on the distance transform, including its
//! angle quantisation, for conformance with f1tenth_gym (see
//! `shared/conformance/f1tenth_gym_scan`).

mod choice;
mod march;
mod path;
mod reference;
mod sweep;

pub use path::{ScanPath, ScanPathError, cpu_features, cpu_model};

use serde::{Deserialize, Serialize};

use crate::geometry::{Obb, Pose, wrap_angle};
use crate::map::Map;
use crate::rng::Rng;

thread_local! {
    /// The ray batch of this thread's scans (see `Lidar::scan_chunks`).
    static SCAN_BATCH: std::cell::Cell<Option<Box<march::Batch>>> =
        const { std::cell::Cell::new(None) };
    /// The per-beam arrays of this thread's sweeps (see `Lidar::scan_sweep`).
    static SCAN_SWEEP: std::cell::Cell<Option<Box<sweep::Sweep>>> =
        const { std::cell::Cell::new(None) };
    /// This thread's choices between the sweep and the march (see `choice`).
    static SCAN_CHOICE: std::cell::RefCell<choice::Choice> =
        const { std::cell::RefCell::new(choice::Choice::new()) };
}

/// How the exact scan is computed: the same bits whichever, at speeds that depend on the
/// map and the CPU.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ScanAlgorithm {
    /// Each thread times both on its first scans of a map (and again every 2,048 scans)
    /// and takes the faster.
    #[default]
    Auto,
    /// The angular sweep over the map's wall faces.
    Sweep,
    /// The march through the grid, accelerated by the clearance table.
    March,
}

impl ScanAlgorithm {
    pub const ALL: [ScanAlgorithm; 3] = [
        ScanAlgorithm::Auto,
        ScanAlgorithm::Sweep,
        ScanAlgorithm::March,
    ];

    /// `auto`, `sweep` or `march`.
    pub fn name(self) -> &'static str {
        match self {
            ScanAlgorithm::Auto => "auto",
            ScanAlgorithm::Sweep => "sweep",
            ScanAlgorithm::March => "march",
        }
    }
}

impl std::fmt::Display for ScanAlgorithm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// This thread's scans so far by the algorithm that computed them: `(march, sweep)`
/// (a scan the sweep does not apply to, from off the map say, counts as marched; a scan
/// of a trial of [`ScanAlgorithm::Auto`] is computed, and counted, by both).
pub fn thread_scans_by_algorithm() -> (u64, u64) {
    let scans = SCAN_CHOICE.with_borrow(|c| c.scans);
    let sweep = SCAN_SWEEP.take();
    let swept = sweep.as_ref().map_or(0, |s| s.swept);
    SCAN_SWEEP.set(sweep);
    (scans.saturating_sub(swept), swept)
}

/// LIDAR parameters. Defaults are those of the f1tenth_gym reference (Hokuyo UST-10LX).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct LidarConfig {
    pub num_beams: usize,
    /// Field of view in radians; beams span [-fov/2, fov/2] around the heading.
    pub fov: f64,
    /// Metres; ranges are clamped to it.
    pub max_range: f64,
    /// Standard deviation (metres) of the Gaussian noise added by [`Lidar::add_noise`].
    pub noise_std: f64,
    /// Metres forward of the car's reference point along its heading (the reference's
    /// `lidar_dist`).
    pub mount_offset: f64,
}

impl Default for LidarConfig {
    fn default() -> Self {
        Self {
            num_beams: 1080,
            fov: 4.7,
            max_range: 30.0,
            noise_std: 0.01,
            mount_offset: 0.0,
        }
    }
}

/// A LIDAR with its precomputed beam directions. Cheap to share; `scan` takes `&self`.
#[derive(Debug, Clone)]
pub struct Lidar {
    config: LidarConfig,
    /// cos / sin of each beam's angle relative to the heading.
    beam_cos: Vec<f64>,
    beam_sin: Vec<f64>,
    reference: reference::TrigTable,
    /// The march's code path; `None`: the widest the CPU supports.
    path: Option<ScanPath>,
    /// Whether each box is tested only on the beams that can meet it (tests turn it off
    /// to compare with testing every beam).
    cull_boxes: bool,
    /// The sweep, the march, or the faster of them (same bits either way).
    algorithm: ScanAlgorithm,
}

impl Lidar {
    pub fn new(config: LidarConfig) -> Self {
        let n = config.num_beams;
        let inc = if n > 1 {
            config.fov / (n - 1) as f64
        } else {
            0.0
        };
        let (mut beam_cos, mut beam_sin) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for i in 0..n {
            let (s, c) = libm::sincos(-config.fov / 2.0 + i as f64 * inc);
            beam_cos.push(c);
            beam_sin.push(s);
        }
        let reference = reference::TrigTable::new(&config);
        Self {
            config,
            beam_cos,
            beam_sin,
            reference,
            path: None,
            cull_boxes: true,
            algorithm: ScanAlgorithm::Auto,
        }
    }

    /// This LIDAR with its scans forced onto `path` (benches, tests and `paddock perf`
    /// use it to measure each path; every path gives the same bits). An error if this
    /// CPU cannot run the path.
    pub fn with_path(mut self, path: ScanPath) -> Result<Self, ScanPathError> {
        if !path.supported() {
            return Err(ScanPathError {
                path,
                features: cpu_features(),
            });
        }
        self.path = Some(path);
        Ok(self)
    }

    /// This LIDAR with its scans taken by `algorithm`, whatever the path: the same bits
    /// whichever (tested); only the speed differs.
    pub fn with_algorithm(mut self, algorithm: ScanAlgorithm) -> Self {
        self.algorithm = algorithm;
        self
    }

    /// This LIDAR with its scans taken by the angular sweep over the map's wall faces
    /// (`on`) or by the march alone ([`Lidar::with_algorithm`]).
    pub fn with_sweep(self, on: bool) -> Self {
        self.with_algorithm(if on {
            ScanAlgorithm::Sweep
        } else {
            ScanAlgorithm::March
        })
    }

    /// How scans are computed: as set by [`Lidar::with_algorithm`], else
    /// [`ScanAlgorithm::Auto`] (measured per map, CPU and path, the sweep and the march
    /// are each the faster somewhere: `docs/performance-scan.md`).
    pub fn algorithm(&self) -> ScanAlgorithm {
        self.algorithm
    }

    /// The code path [`Lidar::scan`] takes: the one forced by [`Lidar::with_path`], else
    /// the widest this CPU supports. (A map whose clearance table does not fit 32-bit
    /// indices, over 500 million cells, is scanned by the portable path whatever this
    /// says.)
    pub fn path(&self) -> ScanPath {
        self.path.unwrap_or_else(ScanPath::best)
    }

    pub fn config(&self) -> &LidarConfig {
        &self.config
    }

    /// Beam `i` points at `pose.theta - fov/2 + i * fov/(num_beams - 1)`.
    pub fn num_beams(&self) -> usize {
        self.config.num_beams
    }

    /// The scan origin of a car at `pose`: `mount_offset` metres ahead along the heading.
    fn origin(&self, pose: Pose) -> (f64, f64) {
        let off = self.config.mount_offset;
        if off == 0.0 {
            return (pose.x, pose.y);
        }
        let (s, c) = libm::sincos(pose.theta);
        (pose.x + off * c, pose.y + off * s)
    }

    /// Exact ranges (no noise) from a car at `pose` into `out` (`num_beams` long): the
    /// nearest of the first occupied cell square (off-map is free) and the first side of
    /// any box in `shapes` (other cars, obstacles; do not pass the scanning car's own
    /// body), clamped to `max_range`. A scan origin inside an occupied cell or inside a
    /// box gives 0 for the beams concerned.
    ///
    /// # Panics
    /// If `out.len() != num_beams`.
    pub fn scan(&self, map: &Map, pose: Pose, shapes: &[Obb], out: &mut [f64]) {
        self.scan_with(map, pose, shapes, out, self.path(), None);
    }

    /// [`Lidar::scan`] then [`Lidar::add_noise`] with `rng`: the same values and the same
    /// generator state after. Faster where the sweep takes the scan with AVX: its per-beam
    /// set-up (two divisions a beam) and the noise's draws (a chain of integer operations)
    /// are done together, each in the other's shadow.
    ///
    /// # Panics
    /// If `out.len() != num_beams`.
    pub fn scan_noisy(
        &self,
        map: &Map,
        pose: Pose,
        shapes: &[Obb],
        out: &mut [f64],
        rng: &mut Rng,
    ) {
        self.scan_with(map, pose, shapes, out, self.path(), Some(rng));
    }

    /// [`Lidar::scan`] on `path` (which the caller checked this CPU supports), then
    /// [`Lidar::add_noise`] with `noise` if given (drawn during the scan where that pays).
    fn scan_with(
        &self,
        map: &Map,
        pose: Pose,
        shapes: &[Obb],
        out: &mut [f64],
        path: ScanPath,
        mut noise: Option<&mut Rng>,
    ) {
        let n = self.config.num_beams;
        assert_eq!(out.len(), n, "scan buffer length must equal num_beams");
        let (x, y) = self.origin(pose);
        let max_range = self.config.max_range;
        // Beam directions in the world frame and in the grid frame.
        let (ws, wc) = libm::sincos(pose.theta);
        let yaw = map.origin().theta;
        let (gs, gc) = if yaw == 0.0 {
            (ws, wc)
        } else {
            libm::sincos(pose.theta - yaw)
        };
        let (gx, gy) = map.world_to_grid(x, y);
        let res = map.resolution();
        let inv_res = 1.0 / res;
        let boxes: Vec<(BoxFrame, BeamRanges)> = shapes
            .iter()
            .filter(|b| {
                libm::hypot(b.cx - x, b.cy - y) - b.circumradius() <= max_range
                    && b.half_length >= 0.0
                    && b.half_width >= 0.0
            })
            .map(|b| {
                let beams = if self.cull_boxes {
                    self.beams_towards(b, x, y, pose.theta)
                } else {
                    [0..self.config.num_beams, 0..0]
                };
                (BoxFrame::new(b), beams)
            })
            .collect();
        let key = choice::Key {
            map: map as *const Map as usize,
            path: path.level(),
            beams: n,
        };
        let pick = SCAN_CHOICE.with_borrow_mut(|c| c.pick(self.algorithm, key));
        let job = ScanJob {
            x,
            y,
            gx,
            gy,
            wc,
            ws,
            gc,
            gs,
            res,
            inv_res,
            max_range,
            sweep: pick.sweep,
            boxes: &boxes,
        };
        let Some(trial) = pick.trial else {
            self.scan_on(map, &job, out, path, &mut noise);
            if let Some(rng) = noise {
                self.add_noise(out, rng);
            }
            return;
        };
        // A trial scan: by both algorithms, the picked one first, each timed (the same
        // bits either way, so `out` holds the scan whichever ran last).
        let mut nanos = [0u64; 2];
        for sweep in [pick.sweep, !pick.sweep] {
            let job = ScanJob { sweep, ..job };
            let start = std::time::Instant::now();
            self.scan_on(map, &job, out, path, &mut None);
            nanos[usize::from(sweep)] =
                u64::try_from(start.elapsed().as_nanos()).unwrap_or(u64::MAX);
        }
        SCAN_CHOICE.with_borrow_mut(|c| c.timed(trial, nanos[0], nanos[1]));
        if let Some(rng) = noise {
            self.add_noise(out, rng);
        }
    }

    /// The scan of `job` on the widest of `path` and the paths `map` allows. Takes
    /// `noise` where it draws the scan's noise and adds it (see [`Lidar::scan_noisy`]);
    /// else leaves it to the caller.
    fn scan_on(
        &self,
        map: &Map,
        job: &ScanJob,
        out: &mut [f64],
        path: ScanPath,
        noise: &mut Option<&mut Rng>,
    ) {
        #[cfg(target_arch = "x86_64")]
        {
            if path >= ScanPath::Avx512 && march::avx512_usable(map) {
                if job.sweep && path::sweep_in_256_bits() {
                    // The sweep compiled for AVX, its march (of the beams it leaves, or of
                    // every beam where it does not apply) still AVX-512's.
                    // SAFETY: `avx512_usable` checked that the CPU supports AVX-512F, so
                    // AVX.
                    unsafe { self.scan_avx(map, job, out, path.level(), noise) };
                    return;
                }
                // SAFETY: `avx512_usable` checked that the CPU supports AVX-512F and AVX2.
                unsafe { self.scan_avx512(map, job, out, noise) };
                return;
            }
            if path >= ScanPath::Avx && march::avx_usable(map) {
                // SAFETY: `avx_usable` checked that the CPU supports AVX.
                unsafe { self.scan_avx(map, job, out, path.level(), noise) };
                return;
            }
        }
        self.scan_chunks::<false>(map, job, out, 0, noise);
    }

    /// [`Lidar::scan_chunks`] compiled with AVX enabled, so that its simple per-beam loops
    /// vectorise too (IEEE operations lane by lane, no FMA: the same bits).
    ///
    /// # Safety
    /// The CPU must support AVX.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx")]
    unsafe fn scan_avx(
        &self,
        map: &Map,
        job: &ScanJob,
        out: &mut [f64],
        level: u8,
        noise: &mut Option<&mut Rng>,
    ) {
        self.scan_chunks::<true>(map, job, out, level, noise);
    }

    /// [`Lidar::scan_chunks`] compiled with AVX-512 enabled (the march itself picks its
    /// AVX-512 version either way; this widens the per-beam loops around it). On Intel
    /// CPUs the sweep's scans go to [`Lidar::scan_avx`] instead (see
    /// `path::sweep_in_256_bits`).
    ///
    /// # Safety
    /// The CPU must support AVX-512F and AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx2")]
    unsafe fn scan_avx512(
        &self,
        map: &Map,
        job: &ScanJob,
        out: &mut [f64],
        noise: &mut Option<&mut Rng>,
    ) {
        self.scan_chunks::<true>(map, job, out, 2, noise);
    }

    /// The scan by the sweep if `job` asks for it and it applies, else the beams in
    /// chunks: box limits, grid directions, the march (at most SIMD level `level`, see
    /// [`ScanPath`]), metres. `noise` as in [`Lidar::scan_on`].
    #[inline(always)]
    fn scan_chunks<const AVX: bool>(
        &self,
        map: &Map,
        job: &ScanJob,
        out: &mut [f64],
        level: u8,
        noise: &mut Option<&mut Rng>,
    ) {
        if job.sweep && self.scan_sweep::<AVX>(map, job, out, level, noise) {
            return;
        }
        let n = out.len();
        // The ray batch (tens of KiB) is rewritten for every chunk, so one per thread
        // serves every scan instead of a fresh allocation each time.
        let mut batch = SCAN_BATCH.take().unwrap_or_else(march::Batch::new);
        batch.simd = level;
        let mut limits = [0.0; march::CHUNK];
        let mut start = 0;
        while start < n {
            let len = (n - start).min(march::CHUNK);
            let beam_cos = &self.beam_cos[start..start + len];
            let beam_sin = &self.beam_sin[start..start + len];
            let limits = &mut limits[..len];
            // The boxes first, so that the grid march stops early behind them.
            self.box_limits(job, start, limits);
            for j in 0..len {
                let (bc, bs) = (beam_cos[j], beam_sin[j]);
                batch.dx[j] = job.gc * bc - job.gs * bs;
                batch.dy[j] = job.gs * bc + job.gc * bs;
                batch.tmax[j] = limits[j] * job.inv_res;
            }
            let chunk_out = &mut out[start..start + len];
            batch.cast::<AVX>(map, job.gx, job.gy, len, chunk_out);
            for (o, &lim) in chunk_out.iter_mut().zip(limits.iter()) {
                *o = metres(*o, job.res, lim);
            }
            start += len;
        }
        SCAN_BATCH.set(Some(batch));
    }

    /// The scan by the angular sweep (see `sweep`), the beams it leaves to the march
    /// marched; false (nothing written) when the sweep does not apply. With `AVX` it
    /// takes `noise` (see [`Lidar::scan_on`]) and draws it alongside its set-up.
    #[inline(always)]
    fn scan_sweep<const AVX: bool>(
        &self,
        map: &Map,
        job: &ScanJob,
        out: &mut [f64],
        level: u8,
        noise: &mut Option<&mut Rng>,
    ) -> bool {
        let n = out.len();
        let fov = self.config.fov;
        let inc = if n > 1 { fov / (n - 1) as f64 } else { 0.0 };
        let fan = sweep::Fan::new(job.gc, job.gs, fov, inc);
        let Some(faces) =
            sweep::faces_for(map, job.gx, job.gy, &fan, n, job.max_range * job.inv_res)
        else {
            return false;
        };
        let mut sw = SCAN_SWEEP.take().unwrap_or_default();
        sw.resize(n);
        // Every beam's limit is the range unless a box may be in the way of some.
        if job
            .boxes
            .iter()
            .all(|(_, beams)| beams.iter().all(|b| b.is_empty()))
        {
            sw.uniform = Some(job.max_range);
        } else {
            sw.uniform = None;
            self.box_limits(job, 0, &mut sw.limit);
        }
        // With AVX the scan's noise is drawn alongside the set-up, into `out`, and the
        // ranges added to it.
        let noise = if AVX { noise.take() } else { None };
        let noisy = noise.is_some();
        let noise = noise.map(|rng| (rng, self.config.noise_std, &mut *out));
        sw.prepare(
            &self.beam_cos,
            &self.beam_sin,
            job.gc,
            job.gs,
            job.inv_res,
            noise,
        );
        sw.run::<AVX>(faces, job.gx, job.gy, job.res, &fan, out, noisy);
        if !sw.marched.is_empty() {
            let mut batch = SCAN_BATCH.take().unwrap_or_else(march::Batch::new);
            batch.simd = level;
            let mut cells = [0.0; march::CHUNK];
            for (c, chunk) in sw.marched.chunks(march::CHUNK).enumerate() {
                for (j, &i) in chunk.iter().enumerate() {
                    let i = i as usize;
                    (batch.dx[j], batch.dy[j], batch.tmax[j]) =
                        (sw.dx[i], sw.dy[i], sw.limit_cells(i));
                }
                batch.cast::<AVX>(map, job.gx, job.gy, chunk.len(), &mut cells);
                for (j, &i) in chunk.iter().enumerate() {
                    let i = i as usize;
                    let r = metres(cells[j], job.res, sw.limit_of(i));
                    // the noise after the range, as `add_noise` adds it
                    out[i] = if noisy {
                        r + sw.marched_noise[c * march::CHUNK + j]
                    } else {
                        r
                    };
                }
            }
            SCAN_BATCH.set(Some(batch));
        }
        SCAN_SWEEP.set(Some(sw));
        true
    }

    /// The range limits (metres) of beams `start..start + limits.len()`: `max_range`, or
    /// nearer where a box of `job` is in the way (each box tried only on the beams that
    /// can meet it).
    #[inline(always)]
    fn box_limits(&self, job: &ScanJob, start: usize, limits: &mut [f64]) {
        limits.fill(job.max_range);
        let end = start + limits.len();
        for (b, ranges) in job.boxes {
            for beams in ranges {
                for j in beams.start.max(start)..beams.end.min(end) {
                    let (bc, bs) = (self.beam_cos[j], self.beam_sin[j]);
                    let (dx, dy) = (job.wc * bc - job.ws * bs, job.ws * bc + job.wc * bs);
                    if let Some(t) = b.ray(job.x, job.y, dx, dy) {
                        let lim = &mut limits[j - start];
                        *lim = lim.min(t);
                    }
                }
            }
        }
    }

    /// This LIDAR testing every box on every beam (for tests of the culling).
    #[cfg(test)]
    fn with_every_beam_on_boxes(mut self) -> Self {
        self.cull_boxes = false;
        self
    }

    /// The beams (one or two index ranges) that can meet box `b` from the scan origin
    /// (x, y) of a car heading `theta`: from outside the box's circumscribed circle the
    /// directions that meet a convex box are those between its corners', so the beams
    /// within that span and two beyond each end (far more than rounding needs); every beam
    /// from nearer, or when the fan's beams could wrap round. A beam left out would have
    /// missed the box: the ranges are the same bits as testing every beam.
    fn beams_towards(&self, b: &Obb, x: f64, y: f64, theta: f64) -> BeamRanges {
        use std::f64::consts::{PI, TAU};
        let n = self.config.num_beams;
        let fov = self.config.fov;
        let all = [0..n, 0..0];
        let (ex, ey) = (b.cx - x, b.cy - y);
        let outside = libm::hypot(ex, ey) > 1.000_001 * b.circumradius() + 1e-9;
        if n < 2 || !(fov > 0.0 && fov < PI * 1.9) || !outside {
            return all;
        }
        let inc = fov / (n - 1) as f64;
        let centre = libm::atan2(ey, ex);
        let (mut lo, mut hi) = (0.0f64, 0.0f64);
        for (qx, qy) in b.corners() {
            let beta = wrap_angle(libm::atan2(qy - y, qx - x) - centre);
            lo = lo.min(beta);
            hi = hi.max(beta);
        }
        let rel = wrap_angle(centre - theta);
        let mut out = [0..0, 0..0];
        let mut k = 0;
        for shift in [-TAU, 0.0, TAU] {
            let (a, z) = (rel + lo + shift + fov / 2.0, rel + hi + shift + fov / 2.0);
            let first = (a / inc).ceil() - 2.0;
            let last = (z / inc).floor() + 2.0;
            if !(first.is_finite() && last.is_finite()) {
                return all;
            }
            let (first, last) = (first.max(0.0), last.min((n - 1) as f64));
            if first <= last && k < 2 {
                out[k] = first as usize..last as usize + 1;
                k += 1;
            }
        }
        out
    }

    /// The f1tenth_gym reference scan (no noise), bit-for-bit: beam directions from its
    /// 2000-entry trig table with `int()` truncation of the drifting table index, sphere
    /// tracing on [`Map::distance_field`] with eps 1e-4, and its off-map lookup (which
    /// reads the top-right pixel of the image). Boxes are not seen. Meant for conformance
    /// and comparison; [`Lidar::scan`] is the exact and faster scan.
    ///
    /// # Panics
    /// If `out.len() != num_beams`.
    pub fn scan_reference(&self, map: &Map, pose: Pose, out: &mut [f64]) {
        assert_eq!(
            out.len(),
            self.config.num_beams,
            "scan buffer length must equal num_beams"
        );
        let (x, y) = self.origin(pose);
        reference::scan(&self.reference, &self.config, map, x, y, pose.theta, out);
    }

    /// Adds N(0, noise_std) to every beam, after the clamp, as the reference does (so a
    /// noisy range can exceed `max_range` or be negative).
    pub fn add_noise(&self, out: &mut [f64], rng: &mut Rng) {
        rng.add_normal(out, 0.0, self.config.noise_std);
    }
}

/// The range in metres of a beam whose hit parameter is `cells` (the march's and the
/// sweep's result: infinity for none) and whose limit is `limit` metres.
#[inline(always)]
fn metres(cells: f64, res: f64, limit: f64) -> f64 {
    let r = cells * res;
    if r < limit { r } else { limit }
}

/// What every beam of one scan shares.
struct ScanJob<'a> {
    /// Scan origin, world frame and grid frame.
    x: f64,
    y: f64,
    gx: f64,
    gy: f64,
    /// cos / sin of the heading in the world frame and in the grid frame.
    wc: f64,
    ws: f64,
    gc: f64,
    gs: f64,
    res: f64,
    inv_res: f64,
    max_range: f64,
    /// Whether to take the angular sweep.
    sweep: bool,
    /// Each box, with the beams that can meet it.
    boxes: &'a [(BoxFrame, BeamRanges)],
}

/// Beam indices as one or two ranges (a span across the fan's ends is two).
type BeamRanges = [std::ops::Range<usize>; 2];

/// A box prepared for many rays: centre, axes and half extents.
struct BoxFrame {
    cx: f64,
    cy: f64,
    c: f64,
    s: f64,
    hl: f64,
    hw: f64,
}

impl BoxFrame {
    fn new(b: &Obb) -> Self {
        let (s, c) = libm::sincos(b.theta);
        Self {
            cx: b.cx,
            cy: b.cy,
            c,
            s,
            hl: b.half_length,
            hw: b.half_width,
        }
    }

    #[inline]
    fn ray(&self, ox: f64, oy: f64, dx: f64, dy: f64) -> Option<f64> {
        let (rx, ry) = (ox - self.cx, oy - self.cy);
        slab(
            rx * self.c + ry * self.s,
            -rx * self.s + ry * self.c,
            dx * self.c + dy * self.s,
            -dx * self.s + dy * self.c,
            self.hl,
            self.hw,
        )
    }
}

/// Ray-box intersection by the slab test in the box frame. The ray is
/// `(ox, oy) + t (dx, dy)`, t >= 0; returns the smallest such t on the box (the distance
/// when `(dx, dy)` is a unit vector), `Some(0.0)` if the origin is inside or on the box,
/// `None` if the ray misses.
pub fn ray_obb(ox: f64, oy: f64, dx: f64, dy: f64, obb: &Obb) -> Option<f64> {
    if !(obb.half_length >= 0.0 && obb.half_width >= 0.0) {
        return None;
    }
    BoxFrame::new(obb).ray(ox, oy, dx, dy)
}

/// Slab test on the axis-aligned box [-hx, hx] x [-hy, hy].
#[inline]
fn slab(ox: f64, oy: f64, dx: f64, dy: f64, hx: f64, hy: f64) -> Option<f64> {
    let mut t0 = 0.0f64;
    let mut t1 = f64::INFINITY;
    for (o, d, h) in [(ox, dx, hx), (oy, dy, hy)] {
        if d == 0.0 {
            if o < -h || o > h {
                return None;
            }
        } else {
            let inv = 1.0 / d;
            let (a, b) = ((-h - o) * inv, (h - o) * inv);
            let (near, far) = if a < b { (a, b) } else { (b, a) };
            t0 = t0.max(near);
            t1 = t1.min(far);
            if t0 > t1 {
                return None;
            }
        }
    }
    if t0.is_finite() { Some(t0) } else { None }
}

#[cfg(test)]
pub(crate) mod tests;
