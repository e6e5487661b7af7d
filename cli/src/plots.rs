//! PNG plots: convergence curves and a lap drawn on the map coloured by speed.
//!
//! plotters draws into an RGB buffer (its bitmap backend, no system fonts: the DejaVu
//! Sans face compiled into `paddock-render`), and the `image` crate encodes the PNG.

use std::path::Path;
use std::sync::Once;

use anyhow::{Context, Result};
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};

use paddock_sim::circuit::Circuit;

static FONT: &[u8] = paddock_render::FONT_TTF;

/// Registers the shipped sans-serif face with plotters (once per process).
pub(crate) fn fonts() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // the bytes are a valid TrueType face (checked by the plot tests)
        let _ = register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// Encodes an RGB plot buffer of `w` x `h` pixels as a PNG file.
pub(crate) fn save_png(path: &Path, buf: Vec<u8>, w: u32, h: u32) -> Result<()> {
    let img = image::RgbImage::from_raw(w, h, buf).context("plot buffer size")?;
    img.save(path)
        .with_context(|| format!("writing {}", path.display()))
}

/// A named series of (x, y) points.
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    pub color: RGBColor,
}

/// Line plot of several series.
pub fn line_plot(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
) -> Result<()> {
    fonts();
    let (w, h) = (900u32, 560u32);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE)?;
        let pts = series.iter().flat_map(|s| s.points.iter());
        let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
        for &(x, y) in pts.filter(|(x, y)| x.is_finite() && y.is_finite()) {
            x0 = x0.min(x);
            x1 = x1.max(x);
            y0 = y0.min(y);
            y1 = y1.max(y);
        }
        if x0 > x1 {
            (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
        }
        let pad = ((y1 - y0) * 0.08).max(1e-3);
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(42)
            .y_label_area_size(60)
            .build_cartesian_2d(x0..x1.max(x0 + 1e-9), (y0 - pad)..(y1 + pad))?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc(y_label)
            .label_style(("sans-serif", 14))
            .draw()?;
        for s in series {
            let color = s.color;
            chart
                .draw_series(LineSeries::new(
                    s.points
                        .iter()
                        .copied()
                        .filter(|(x, y)| x.is_finite() && y.is_finite()),
                    color.stroke_width(2),
                ))?
                .label(s.name.clone())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                });
        }
        chart
            .configure_series_labels()
            .label_font(("sans-serif", 14))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()?;
        root.present()?;
    }
    save_png(path, buf, w, h)
}

/// Speed colour ramp: blue (slow) - green - yellow - red (fast).
fn ramp(t: f64) -> RGBColor {
    let t = t.clamp(0.0, 1.0);
    let stops = [
        (0.0, (40, 60, 200)),
        (0.33, (30, 170, 90)),
        (0.66, (240, 200, 30)),
        (1.0, (220, 40, 30)),
    ];
    for w in stops.windows(2) {
        let ((a, ca), (b, cb)) = (w[0], w[1]);
        if t <= b {
            let u = (t - a) / (b - a);
            let mix = |p: u8, q: u8| (p as f64 + u * (q as f64 - p as f64)).round() as u8;
            return RGBColor(mix(ca.0, cb.0), mix(ca.1, cb.1), mix(ca.2, cb.2));
        }
    }
    RGBColor(220, 40, 30)
}

/// The lap `xs, ys` (world metres) drawn over the map, each segment coloured by `speed`.
pub fn lap_on_map(
    path: &Path,
    title: &str,
    circuit: &Circuit,
    xs: &[f64],
    ys: &[f64],
    speed: &[f64],
) -> Result<()> {
    fonts();
    let map = &circuit.map;
    // world bounding box of the track, with a margin
    let pts = circuit.track.points();
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in pts {
        x0 = x0.min(p.x - p.w_right.max(p.w_left));
        x1 = x1.max(p.x + p.w_right.max(p.w_left));
        y0 = y0.min(p.y - p.w_right.max(p.w_left));
        y1 = y1.max(p.y + p.w_right.max(p.w_left));
    }
    let margin = 1.5;
    let (x0, x1, y0, y1) = (x0 - margin, x1 + margin, y0 - margin, y1 + margin);
    let plot_w = 1000u32;
    let scale = plot_w as f64 / (x1 - x0);
    let plot_h = (((y1 - y0) * scale).round() as u32).clamp(100, 1400);
    let (bar_h, top) = (60u32, 40u32);
    let (w, h) = (plot_w, plot_h + top + bar_h);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    // the occupancy grid, sampled at pixel centres
    for py in 0..plot_h {
        for px in 0..plot_w {
            let wx = x0 + (px as f64 + 0.5) / scale;
            let wy = y1 - (py as f64 + 0.5) / scale;
            let k = (((py + top) * w + px) * 3) as usize;
            let v = if map.occupied_at(wx, wy) { 70 } else { 245 };
            buf[k..k + 3].copy_from_slice(&[v, v, v]);
        }
    }
    let to_px = |x: f64, y: f64| {
        (
            ((x - x0) * scale).round() as i32,
            ((y1 - y) * scale).round() as i32 + top as i32,
        )
    };
    let vmax = speed.iter().copied().fold(0.0f64, f64::max).max(1e-6);
    let vmin = speed.iter().copied().fold(f64::MAX, f64::min).min(vmax);
    let norm = |v: f64| (v - vmin) / (vmax - vmin).max(1e-6);
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        for i in 1..xs.len().min(ys.len()).min(speed.len()) {
            let c = ramp(norm(0.5 * (speed[i - 1] + speed[i])));
            root.draw(&PathElement::new(
                vec![to_px(xs[i - 1], ys[i - 1]), to_px(xs[i], ys[i])],
                c.stroke_width(3),
            ))?;
        }
        if let (Some(&x), Some(&y)) = (xs.first(), ys.first()) {
            root.draw(&Circle::new(to_px(x, y), 6, BLACK.filled()))?;
        }
        root.draw(&Text::new(
            title.to_string(),
            (10, 10),
            ("sans-serif", 20).into_font().color(&BLACK),
        ))?;
        // colour bar
        let (bx, by, bw) = (60i32, (plot_h + top) as i32 + 14, (w as i32) - 200);
        for i in 0..bw {
            let c = ramp(i as f64 / bw as f64);
            root.draw(&PathElement::new(
                vec![(bx + i, by), (bx + i, by + 16)],
                c.stroke_width(1),
            ))?;
        }
        let label = |v: f64| format!("{v:.1} m/s");
        root.draw(&Text::new(
            label(vmin),
            (bx - 55, by + 1),
            ("sans-serif", 14).into_font().color(&BLACK),
        ))?;
        root.draw(&Text::new(
            label(vmax),
            (bx + bw + 8, by + 1),
            ("sans-serif", 14).into_font().color(&BLACK),
        ))?;
        root.present()?;
    }
    save_png(path, buf, w, h)
}
