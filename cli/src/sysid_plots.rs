//! Plots of a reality-gap analysis: recorded vs nominal vs fitted time series, residual
//! by place on the track, residual by operating regime (PNG, no system fonts).

use std::path::Path;

use anyhow::Result;
use paddock_sysid::Analysis;
use paddock_sysid::effects::EffectKind;
use paddock_sysid::locate::Group;
use paddock_sysid::recording::Recording;
use paddock_sysid::replay::Residuals;
use plotters::prelude::*;

use crate::plots::{fonts, save_png};

const RECORDED: RGBColor = RGBColor(90, 90, 90);
const NOMINAL: RGBColor = RGBColor(215, 50, 40);
const FITTED: RGBColor = RGBColor(30, 90, 210);

/// Write `timeseries.png`, `residual_by_place.png` and `residual_by_regime.png`.
pub fn write_all(dir: &Path, rec: &Recording, a: &Analysis) -> Result<()> {
    fonts();
    timeseries(&dir.join("timeseries.png"), rec, a)?;
    by_place(&dir.join("residual_by_place.png"), rec, a)?;
    by_regime(&dir.join("residual_by_regime.png"), a)?;
    Ok(())
}

/// The 12 s around the time segment where the nominal model is worst.
fn excerpt(rec: &Recording, a: &Analysis) -> (f64, f64) {
    let worst = a
        .located
        .time
        .iter()
        .max_by(|x, y| x.ratio.total_cmp(&y.ratio))
        .map_or(0.0, |g| g.range[0]);
    let len = 12.0f64.min(rec.duration());
    let t0 = worst.min(rec.duration() - len).max(0.0);
    (t0, t0 + len)
}

/// Points of channel `c` of a replay, split into its windows.
fn segments(rec: &Recording, res: &Residuals, c: usize, t0: f64, t1: f64) -> Vec<Vec<(f64, f64)>> {
    let mut out: Vec<Vec<(f64, f64)>> = Vec::new();
    let mut last_w = usize::MAX;
    for (i, sim) in res.simulated.iter().enumerate() {
        let t = rec.states[res.state[i]].t;
        if t < t0 || t > t1 {
            continue;
        }
        if res.window[i] != last_w {
            out.push(Vec::new());
            last_w = res.window[i];
        }
        if let Some(seg) = out.last_mut() {
            seg.push((t, sim[c]));
        }
    }
    out
}

fn timeseries(path: &Path, rec: &Recording, a: &Analysis) -> Result<()> {
    let (t0, t1) = excerpt(rec, a);
    let panels = [
        (3usize, "vx [m/s]"),
        (4, "vy [m/s]"),
        (5, "yaw rate [rad/s]"),
    ];
    let (w, h) = (1100u32, 900u32);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE)?;
        let root = root.titled(
            "Recorded (grey) vs nominal model (red) vs fitted model (blue), windows re-anchored",
            ("sans-serif", 20),
        )?;
        let areas = root.split_evenly((panels.len(), 1));
        for (area, (c, label)) in areas.iter().zip(panels) {
            let recorded: Vec<(f64, f64)> = rec
                .states
                .iter()
                .filter(|s| s.t >= t0 && s.t <= t1)
                .map(|s| (s.t, s.channels()[c]))
                .collect();
            let nominal = segments(rec, &a.nominal_residuals, c, t0, t1);
            let fitted = segments(rec, &a.fitted_residuals, c, t0, t1);
            let all = recorded
                .iter()
                .chain(nominal.iter().flatten())
                .chain(fitted.iter().flatten())
                .map(|p| p.1)
                .filter(|v| v.is_finite());
            let (mut lo, mut hi) = (f64::MAX, f64::MIN);
            for v in all {
                lo = lo.min(v);
                hi = hi.max(v);
            }
            if lo > hi {
                (lo, hi) = (-1.0, 1.0);
            }
            let pad = ((hi - lo) * 0.08).max(1e-3);
            let mut chart = ChartBuilder::on(area)
                .margin(8)
                .x_label_area_size(32)
                .y_label_area_size(60)
                .build_cartesian_2d(t0..t1, (lo - pad)..(hi + pad))?;
            chart
                .configure_mesh()
                .x_desc("t [s]")
                .y_desc(label)
                .label_style(("sans-serif", 13))
                .draw()?;
            chart.draw_series(
                recorded
                    .iter()
                    .map(|p| Circle::new(*p, 2, RECORDED.filled())),
            )?;
            for (segs, color) in [(&nominal, NOMINAL), (&fitted, FITTED)] {
                for seg in segs.iter() {
                    chart
                        .draw_series(LineSeries::new(seg.iter().copied(), color.stroke_width(2)))?;
                }
            }
        }
        root.present()?;
    }
    save_png(path, buf, w, h)
}

/// Blue (small) to red (large) on a log scale of the residual score.
fn heat(score: f64, max: f64) -> RGBColor {
    let t = ((1.0 + score).ln() / (1.0 + max).ln()).clamp(0.0, 1.0);
    let mix = |a: f64, b: f64| (a + t * (b - a)).round() as u8;
    RGBColor(mix(40.0, 220.0), mix(90.0, 40.0), mix(200.0, 30.0))
}

/// Per sample: the mean squared noise-normalised residual over the channels measured
/// there (a pose-and-speed log has no vy and yaw_rate: NaN, which coloured every sample
/// black).
fn sample_scores(res: &Residuals, sigma: &[f64; 6]) -> Vec<f64> {
    res.values
        .iter()
        .map(|r| {
            let (sum, n) = (0..6)
                .map(|c| (r[c] / sigma[c]).powi(2))
                .filter(|v| v.is_finite())
                .fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
            if n == 0 { 0.0 } else { sum / n as f64 }
        })
        .collect()
}

/// The colour scale of [`heat`] as a vertical bar, labelled in score units.
fn colour_bar<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    max: f64,
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let mut chart = ChartBuilder::on(area)
        .caption("residual", ("sans-serif", 14))
        .margin_top(40)
        .margin_bottom(40)
        .margin_right(10)
        .y_label_area_size(45)
        .build_cartesian_2d(0.0f64..1.0, 0.0f64..1.0)?;
    // the bar's height is log(1 + score), as the colours are
    let score = |t: f64| (1.0 + max).powf(t) - 1.0;
    chart
        .configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_labels(6)
        .y_label_formatter(&|t| {
            let v = score(*t);
            if v < 10.0 {
                format!("{v:.1}")
            } else {
                format!("{v:.0}")
            }
        })
        .y_desc("mean (residual / noise)^2")
        .label_style(("sans-serif", 11))
        .draw()?;
    const STEPS: usize = 100;
    chart.draw_series((0..STEPS).map(|i| {
        let (t0, t1) = (i as f64 / STEPS as f64, (i + 1) as f64 / STEPS as f64);
        Rectangle::new([(0.0, t0), (1.0, t1)], heat(score(t0), max).filled())
    }))?;
    Ok(())
}

fn by_place(path: &Path, rec: &Recording, a: &Analysis) -> Result<()> {
    let nominal = sample_scores(&a.nominal_residuals, &a.noise_floor);
    let fitted = sample_scores(&a.fitted_residuals, &a.noise_floor);
    // colour scale up to the 98th percentile of the nominal scores
    let mut sorted = nominal.clone();
    sorted.sort_by(|x, y| x.total_cmp(y));
    let max = sorted
        .get((sorted.len() as f64 * 0.98) as usize)
        .copied()
        .unwrap_or(1.0)
        .max(1.0);
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for s in &rec.states {
        x0 = x0.min(s.x);
        x1 = x1.max(s.x);
        y0 = y0.min(s.y);
        y1 = y1.max(s.y);
    }
    let span = (x1 - x0).max(y1 - y0).max(1.0) * 0.05;
    let (x0, x1, y0, y1) = (x0 - span, x1 + span, y0 - span, y1 + span);
    let (w, h) = (1410u32, 650u32);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    let patch = a
        .effects
        .iter()
        .find(|e| e.kind == EffectKind::FrictionPatch)
        .map(|e| e.values.clone());
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE)?;
        let root = root.titled(
            "Residual by place (blue small, red large; log scale)",
            ("sans-serif", 20),
        )?;
        let (maps, bar) = root.split_horizontally(w - 110);
        colour_bar(&bar, max)?;
        let halves = maps.split_evenly((1, 2));
        for (area, (title, scores)) in halves
            .iter()
            .zip([("nominal model", &nominal), ("fitted model", &fitted)])
        {
            let mut chart = ChartBuilder::on(area)
                .caption(title, ("sans-serif", 16))
                .margin(10)
                .x_label_area_size(30)
                .y_label_area_size(45)
                .build_cartesian_2d(x0..x1, y0..y1)?;
            chart
                .configure_mesh()
                .x_desc("x [m]")
                .y_desc("y [m]")
                .label_style(("sans-serif", 12))
                .draw()?;
            chart.draw_series(scores.iter().enumerate().map(|(i, sc)| {
                let s = &rec.states[a.nominal_residuals.state[i]];
                Circle::new((s.x, s.y), 3, heat(*sc, max).filled())
            }))?;
            if let Some(v) = &patch {
                chart.draw_series(std::iter::once(Rectangle::new(
                    [(v[1], v[2]), (v[3], v[4])],
                    BLACK.stroke_width(2),
                )))?;
            }
        }
        root.present()?;
    }
    save_png(path, buf, w, h)
}

fn short(g: &Group) -> String {
    let (lo, hi) = (g.range[0], g.range[1]);
    let fmt = |v: f64| {
        if v.is_infinite() {
            "+".to_string()
        } else {
            format!("{v}")
        }
    };
    match g.label.as_str() {
        "speed_mps" => format!("v {}-{}", fmt(lo), fmt(hi)),
        "lateral_accel_mps2" => format!("ay {}-{}", fmt(lo), fmt(hi)),
        "steering_rate_radps" => format!("sr {}-{}", fmt(lo), fmt(hi)),
        "braking" => {
            if lo < 0.5 {
                "no brake".into()
            } else {
                "braking".into()
            }
        }
        other => other.to_string(),
    }
}

fn by_regime(path: &Path, a: &Analysis) -> Result<()> {
    let nominal = &a.located.regimes;
    let fitted = &a.located_fitted.regimes;
    let n = nominal.len();
    let (w, h) = (1400u32, 600u32);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    let top = nominal
        .iter()
        .chain(fitted.iter())
        .map(|g| g.score)
        .fold(1.0f64, f64::max)
        * 1.1;
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE)?;
        let labels: Vec<String> = nominal.iter().map(short).collect();
        let mut chart = ChartBuilder::on(&root)
            .caption(
                "Mean residual by regime (noise-normalised): nominal (red) vs fitted (blue)",
                ("sans-serif", 20),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(-0.5f64..(n as f64 - 0.5), 0.0..top)?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(n)
            .x_label_formatter(&|x| {
                let i = x.round();
                if (x - i).abs() < 1e-6 && i >= 0.0 && (i as usize) < labels.len() {
                    labels[i as usize].clone()
                } else {
                    String::new()
                }
            })
            .y_desc("mean squared residual / noise")
            .label_style(("sans-serif", 11))
            .draw()?;
        chart.draw_series(nominal.iter().enumerate().map(|(i, g)| {
            let x = i as f64;
            Rectangle::new([(x - 0.38, 0.0), (x, g.score)], NOMINAL.filled())
        }))?;
        chart.draw_series(nominal.iter().enumerate().filter_map(|(i, g)| {
            let f = fitted
                .iter()
                .find(|f| f.label == g.label && f.range == g.range)?;
            let x = i as f64;
            Some(Rectangle::new(
                [(x, 0.0), (x + 0.38, f.score)],
                FITTED.filled(),
            ))
        }))?;
        root.present()?;
    }
    save_png(path, buf, w, h)
}
