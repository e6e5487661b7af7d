//! Top-down pictures of a race: the map, the driving line, every car as an oriented
//! rectangle with its heading, car 0's LIDAR scan, and a lap and time overlay.
//!
//! Rendering is a pure function: a [`Renderer`] is built once per (circuit, width) and
//! holds the static background (walls, driving line, start line); [`Renderer::render`]
//! turns a [`Scene`] (the world's state at one instant) into an RGB [`Frame`]. Everything
//! that shows a race makes its frames here, from the same data:
//!
//! - the worker renders an env session's copies for `env.render()` in Python (the frame
//!   travels back as packed bytes; a local and a remote env give the same bytes, because
//!   both are rendered by a worker),
//! - `paddock rollout --video` and `paddock benchmark --video` render an episode from its
//!   recorded trajectory ([`replay`]).
//!
//! Frames are deterministic: the same scene gives the same bytes (f64 arithmetic in a
//! fixed order, trigonometry from `libm`, the font compiled in).

use paddock_sim::circuit::Circuit;
use paddock_sim::geometry::{Obb, Pose};
use paddock_sim::world::{AgentStatus, World};

mod raster;
pub mod replay;
mod text;

pub use raster::{Canvas, Rgb};
pub use text::{FONT_TTF, draw_text, text_width};

/// Narrowest frame, pixels.
pub const MIN_WIDTH: u32 = 160;
/// Widest frame, pixels.
pub const MAX_WIDTH: u32 = 2048;
/// Frame width when none is asked for, pixels.
pub const DEFAULT_WIDTH: u32 = 800;

/// Rendering errors.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error("{field} = {value}: {reason}")]
    Invalid {
        field: String,
        value: String,
        reason: String,
    },
    #[error(transparent)]
    World(#[from] paddock_sim::world::WorldError),
    #[error(transparent)]
    Rollout(#[from] paddock_rollout::RolloutError),
}

/// How a car stands in the race.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CarStatus {
    Racing,
    Crashed,
    Finished,
}

impl From<AgentStatus> for CarStatus {
    fn from(s: AgentStatus) -> Self {
        match s {
            AgentStatus::Racing => CarStatus::Racing,
            AgentStatus::Crashed => CarStatus::Crashed,
            AgentStatus::Finished => CarStatus::Finished,
        }
    }
}

/// One car at one instant.
#[derive(Debug, Clone, PartialEq)]
pub struct CarView {
    pub pose: Pose,
    /// Body length and width, metres.
    pub length: f64,
    pub width: f64,
    /// Forward speed, m/s.
    pub speed: f64,
    /// Completed laps.
    pub laps: u32,
    pub status: CarStatus,
}

/// A LIDAR scan: beams spread evenly over `fov` around the origin's heading.
#[derive(Debug, Clone, PartialEq)]
pub struct ScanView {
    /// The scan origin (the car's pose moved by the LIDAR's mount offset).
    pub origin: Pose,
    pub fov: f64,
    pub max_range: f64,
    /// Ranges, metres.
    pub ranges: Vec<f64>,
}

/// What one frame shows.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Scene {
    /// Simulated seconds.
    pub time: f64,
    /// The laps a car must drive (None: no target).
    pub laps: Option<u32>,
    pub cars: Vec<CarView>,
    pub obstacles: Vec<Obb>,
    /// Car 0's scan.
    pub scan: Option<ScanView>,
    /// A caption shown at the right of the overlay (map, episode, drivers).
    pub caption: String,
}

impl Scene {
    /// The scene of `world` now: every car, the obstacles, car 0's scan (if car 0 scans).
    pub fn from_world(world: &World) -> Result<Self, RenderError> {
        let state = world.state()?;
        let config = world.config();
        let obs = &state.observation;
        let cars = state
            .agents
            .iter()
            .enumerate()
            .map(|(i, a)| CarView {
                pose: a.vehicle.pose(),
                length: config.agents[i].params.length,
                width: config.agents[i].params.width,
                speed: obs.linear_vels_x[i],
                laps: a.laps.laps,
                status: a.status.into(),
            })
            .collect::<Vec<_>>();
        let scan = match (config.agents.first(), cars.first()) {
            (Some(a), Some(car)) if a.scan => Some(ScanView {
                origin: lidar_origin(car.pose, config.lidar.mount_offset),
                fov: config.lidar.fov,
                max_range: config.lidar.max_range,
                ranges: obs.scan(0).to_vec(),
            }),
            _ => None,
        };
        Ok(Self {
            time: state.time,
            laps: config.laps,
            cars,
            obstacles: state.obstacles.clone(),
            scan,
            caption: world.circuit().name.clone(),
        })
    }
}

/// The scan origin of a car at `pose` with the LIDAR `offset` metres ahead.
pub fn lidar_origin(pose: Pose, offset: f64) -> Pose {
    Pose::new(
        pose.x + offset * libm::cos(pose.theta),
        pose.y + offset * libm::sin(pose.theta),
        pose.theta,
    )
}

/// An RGB image, rows top to bottom, 3 bytes per pixel.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frame {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
}

/// Car colours, by car index (cycled).
pub const CAR_COLOURS: [Rgb; 6] = [
    Rgb(228, 45, 60),
    Rgb(30, 110, 235),
    Rgb(25, 160, 80),
    Rgb(245, 150, 0),
    Rgb(150, 70, 200),
    Rgb(0, 165, 175),
];
const FREE: Rgb = Rgb(238, 238, 233);
const WALL: Rgb = Rgb(52, 58, 68);
const LINE: Rgb = Rgb(90, 160, 230);
const OBSTACLE: Rgb = Rgb(165, 100, 45);
const HUD: Rgb = Rgb(28, 31, 38);
const HUD_TEXT: Rgb = Rgb(245, 245, 245);
const HUD_DIM: Rgb = Rgb(160, 166, 178);
const INK: Rgb = Rgb(20, 20, 24);
const WHITE: Rgb = Rgb(255, 255, 255);

/// Draws scenes of one circuit at one size.
#[derive(Debug, Clone)]
pub struct Renderer {
    background: Canvas,
    /// World -> pixel: px = (x - x0) * scale + left, py = (y1 - y) * scale + top.
    x0: f64,
    y1: f64,
    scale: f64,
    left: f64,
    top: f64,
    font: f32,
    hud: usize,
}

impl Renderer {
    /// A renderer of `circuit` whose frames are `width` pixels wide (the height follows
    /// the track's shape, rounded to an even number so video encoders take it).
    pub fn new(circuit: &Circuit, width: u32) -> Result<Self, RenderError> {
        if !(MIN_WIDTH..=MAX_WIDTH).contains(&width) {
            return Err(RenderError::Invalid {
                field: "width".into(),
                value: width.to_string(),
                reason: format!("must be in {MIN_WIDTH}..={MAX_WIDTH} pixels"),
            });
        }
        let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        let mut extend = |x: f64, y: f64, r: f64| {
            x0 = x0.min(x - r);
            x1 = x1.max(x + r);
            y0 = y0.min(y - r);
            y1 = y1.max(y + r);
        };
        for p in circuit.track.points() {
            extend(p.x, p.y, p.w_right.max(p.w_left));
        }
        for p in circuit.driving_line() {
            extend(p.x, p.y, 0.0);
        }
        let margin = 1.0;
        let (x0, x1, y0, y1) = (x0 - margin, x1 + margin, y0 - margin, y1 + margin);
        let w = f64::from(width);
        let font = (w / 50.0).clamp(10.0, 28.0) as f32;
        let hud = (f64::from(font) * 2.1).round() as usize;
        let mut scale = w / (x1 - x0);
        let max_h = 1.25 * w;
        if (y1 - y0) * scale > max_h {
            scale = max_h / (y1 - y0);
        }
        let map_h = ((y1 - y0) * scale).ceil() as usize;
        let height = (hud + map_h).div_ceil(2) * 2;
        let left = 0.5 * (w - (x1 - x0) * scale);
        let top = hud as f64 + 0.5 * ((height - hud) as f64 - (y1 - y0) * scale);
        let mut r = Self {
            background: Canvas::new(width as usize, height, FREE),
            x0,
            y1,
            scale,
            left,
            top,
            font,
            hud,
        };
        r.draw_background(circuit);
        Ok(r)
    }

    pub fn width(&self) -> u32 {
        self.background.width as u32
    }

    pub fn height(&self) -> u32 {
        self.background.height as u32
    }

    /// Pixels per metre.
    pub fn scale(&self) -> f64 {
        self.scale
    }

    /// The pixel (continuous coordinates) of world point (x, y).
    pub fn to_px(&self, x: f64, y: f64) -> (f64, f64) {
        (
            (x - self.x0) * self.scale + self.left,
            (self.y1 - y) * self.scale + self.top,
        )
    }

    fn to_world(&self, px: f64, py: f64) -> (f64, f64) {
        (
            (px - self.left) / self.scale + self.x0,
            self.y1 - (py - self.top) / self.scale,
        )
    }

    fn draw_background(&mut self, circuit: &Circuit) {
        let map = &circuit.map;
        let (w, h) = (self.background.width, self.background.height);
        // walls: the occupancy grid at each pixel's centre; where a pixel or one of its
        // neighbours differs (an edge), sampled 3 x 3 and blended by coverage
        let rows = h - self.hud;
        let mut centre = vec![false; w * rows];
        for (k, cell) in centre.iter_mut().enumerate() {
            let (px, py) = ((k % w) as f64 + 0.5, (k / w + self.hud) as f64 + 0.5);
            let (x, y) = self.to_world(px, py);
            *cell = map.occupied_at(x, y);
        }
        for row in 0..rows {
            for px in 0..w {
                let here = centre[row * w + px];
                let uniform = (row.saturating_sub(1)..(row + 2).min(rows)).all(|r| {
                    (px.saturating_sub(1)..(px + 2).min(w)).all(|c| centre[r * w + c] == here)
                });
                let py = row + self.hud;
                let hits = if uniform {
                    9 * u32::from(here)
                } else {
                    let mut hits = 0u32;
                    for sy in 0..3 {
                        for sx in 0..3 {
                            let (x, y) = self.to_world(
                                px as f64 + (f64::from(sx) + 0.5) / 3.0,
                                py as f64 + (f64::from(sy) + 0.5) / 3.0,
                            );
                            hits += u32::from(map.occupied_at(x, y));
                        }
                    }
                    hits
                };
                if hits > 0 {
                    self.background.blend(px, py, WALL, f64::from(hits) / 9.0);
                }
            }
        }
        // the driving line, closed
        let line = circuit.driving_line();
        let width = (self.scale * 0.06).clamp(1.0, 3.0);
        for k in 0..line.len() {
            let (a, b) = (&line[k], &line[(k + 1) % line.len()]);
            let (pa, pb) = (self.to_px(a.x, a.y), self.to_px(b.x, b.y));
            self.background.line(pa, pb, width, LINE, 0.9);
        }
        // the start line, chequered across the track at arc length 0
        let (c, wr, wl) = circuit.track.at(0.0);
        let (nx, ny) = (-libm::sin(c.theta), libm::cos(c.theta));
        let pieces = 8;
        let stripe = (self.scale * 0.15).clamp(2.0, 6.0);
        for k in 0..pieces {
            let f0 = -wr + (wl + wr) * k as f64 / pieces as f64;
            let f1 = -wr + (wl + wr) * (k + 1) as f64 / pieces as f64;
            let a = self.to_px(c.x + f0 * nx, c.y + f0 * ny);
            let b = self.to_px(c.x + f1 * nx, c.y + f1 * ny);
            let colour = if k % 2 == 0 { INK } else { WHITE };
            self.background.line(a, b, stripe, colour, 1.0);
        }
    }

    /// The frame of `scene`.
    pub fn render(&self, scene: &Scene) -> Frame {
        let mut c = self.background.clone();
        for o in &scene.obstacles {
            let pts = o.corners().map(|(x, y)| self.to_px(x, y));
            c.fill_polygon(&pts, OBSTACLE, 1.0);
        }
        if let Some(scan) = &scene.scan {
            self.draw_scan(&mut c, scan);
        }
        // car 0 on top
        for (i, car) in scene.cars.iter().enumerate().rev() {
            self.draw_car(&mut c, car, CAR_COLOURS[i % CAR_COLOURS.len()]);
        }
        self.draw_hud(&mut c, scene);
        Frame {
            width: c.width as u32,
            height: c.height as u32,
            rgb: c.rgb,
        }
    }

    fn draw_scan(&self, c: &mut Canvas, scan: &ScanView) {
        let n = scan.ranges.len();
        if n == 0 {
            return;
        }
        let colour = CAR_COLOURS[0];
        let inc = if n > 1 {
            scan.fov / (n - 1) as f64
        } else {
            0.0
        };
        let end = |k: usize| {
            let r = scan.ranges[k].clamp(0.0, scan.max_range);
            let a = scan.origin.theta - 0.5 * scan.fov + k as f64 * inc;
            self.to_px(
                scan.origin.x + r * libm::cos(a),
                scan.origin.y + r * libm::sin(a),
            )
        };
        // the seen area as a translucent fan, then the returns as dots
        let step = n.div_ceil(360).max(1);
        let mut fan = vec![self.to_px(scan.origin.x, scan.origin.y)];
        fan.extend((0..n).step_by(step).map(end));
        fan.push(end(n - 1));
        c.fill_polygon(&fan, colour, 0.13);
        let dot = (self.scale * 0.04).clamp(0.8, 2.5);
        for k in (0..n).step_by(n.div_ceil(540).max(1)) {
            if scan.ranges[k] < scan.max_range * 0.999 {
                c.disc(end(k), dot, colour, 0.85);
            }
        }
    }

    fn draw_car(&self, c: &mut Canvas, car: &CarView, colour: Rgb) {
        let body = Obb::car(car.pose, car.length, car.width);
        let alpha = if car.status == CarStatus::Finished {
            0.35
        } else {
            1.0
        };
        // a dark outline one pixel wide, the body, then a white nose wedge for the heading
        let grow = 1.0 / self.scale;
        let outline = Obb {
            half_length: body.half_length + grow,
            half_width: body.half_width + grow,
            ..body
        };
        let px = |pts: [(f64, f64); 4]| pts.map(|(x, y)| self.to_px(x, y));
        // a halo, so a car (a dozen pixels long at 800 pixels) is seen at a glance
        let halo = (1.1 * car.length * self.scale).max(10.0);
        c.disc(
            self.to_px(car.pose.x, car.pose.y),
            halo,
            colour,
            0.28 * alpha,
        );
        c.fill_polygon(&px(outline.corners()), INK, alpha);
        c.fill_polygon(&px(body.corners()), colour, alpha);
        let (cs, sn) = (libm::cos(car.pose.theta), libm::sin(car.pose.theta));
        let local =
            |a: f64, b: f64| self.to_px(car.pose.x + a * cs - b * sn, car.pose.y + a * sn + b * cs);
        let (hl, hw) = (body.half_length, body.half_width);
        let nose = [
            local(hl, 0.0),
            local(0.05 * hl, 0.75 * hw),
            local(0.05 * hl, -0.75 * hw),
        ];
        c.fill_polygon(&nose, WHITE, 0.9 * alpha);
        // a short heading tick ahead of the car
        let tick = (hl + 0.1, hl + 0.1 + (14.0 / self.scale).max(0.3));
        c.line(
            local(tick.0, 0.0),
            local(tick.1, 0.0),
            2.0,
            colour,
            0.8 * alpha,
        );
        if car.status == CarStatus::Crashed {
            let r = hl + 0.15;
            for (a, b) in [((r, r), (-r, -r)), ((r, -r), (-r, r))] {
                c.line(local(a.0, a.1), local(b.0, b.1), 3.0, INK, 1.0);
            }
        }
    }

    fn draw_hud(&self, c: &mut Canvas, scene: &Scene) {
        let width = c.width;
        c.rect(0, 0, width, self.hud, HUD, 1.0);
        let size = self.font;
        let y = 0.5 * (self.hud as f32 - size * 1.17);
        let mut x = 0.6 * size;
        let time = format!("{:6.2} s", scene.time);
        draw_text(c, &time, x, y, size, HUD_TEXT);
        x += text_width("0000.00 s", size) + size;
        for (i, car) in scene.cars.iter().enumerate().take(4) {
            let colour = CAR_COLOURS[i % CAR_COLOURS.len()];
            let sq = (0.75 * size).round() as usize;
            c.rect(
                x as usize,
                (0.5 * (self.hud - sq) as f32) as usize,
                sq,
                sq,
                colour,
                1.0,
            );
            x += sq as f32 + 0.4 * size;
            let lap = match scene.laps {
                Some(total) => format!("lap {}/{total}", (car.laps + 1).min(total)),
                None => format!("lap {}", car.laps + 1),
            };
            let state = match car.status {
                CarStatus::Racing => format!("{lap}  {:4.1} m/s", car.speed),
                CarStatus::Crashed => format!("{lap}  crashed"),
                CarStatus::Finished => "finished".to_string(),
            };
            draw_text(c, &state, x, y, size, HUD_TEXT);
            x += text_width(&state, size) + 1.2 * size;
        }
        let cap = text_width(&scene.caption, size);
        if !scene.caption.is_empty() && x + cap + 0.6 * size < width as f32 {
            draw_text(
                c,
                &scene.caption,
                width as f32 - cap - 0.6 * size,
                y,
                size,
                HUD_DIM,
            );
        }
    }
}

#[cfg(test)]
mod tests;
