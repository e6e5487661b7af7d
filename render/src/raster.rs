//! A small RGB canvas: anti-aliased polygon fill (the one primitive: lines, discs and
//! boxes are polygons), alpha blending, and glyph coverage from the text module.
//!
//! Why not a drawing library: the frames must be bit-identical wherever they are made,
//! the primitives needed are few, and a scanline fill with exact horizontal coverage on
//! four sub-rows per pixel is short, fast and plainly deterministic (f64 arithmetic only,
//! in a fixed order).

/// An RGB colour.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rgb(pub u8, pub u8, pub u8);

/// Sub-rows per pixel row in the polygon fill.
const SUB: usize = 4;

/// A `width` x `height` RGB buffer, row 0 at the top.
#[derive(Debug, Clone, PartialEq)]
pub struct Canvas {
    pub width: usize,
    pub height: usize,
    pub rgb: Vec<u8>,
    /// Coverage of the row being filled (scratch).
    cover: Vec<f64>,
}

impl Canvas {
    pub fn new(width: usize, height: usize, fill: Rgb) -> Self {
        let mut rgb = Vec::with_capacity(width * height * 3);
        for _ in 0..width * height {
            rgb.extend_from_slice(&[fill.0, fill.1, fill.2]);
        }
        Self {
            width,
            height,
            rgb,
            cover: vec![0.0; width + 2],
        }
    }

    /// Blend `c` over pixel (x, y) with opacity `a` in [0, 1].
    #[inline]
    pub fn blend(&mut self, x: usize, y: usize, c: Rgb, a: f64) {
        if x >= self.width || y >= self.height || a <= 0.0 {
            return;
        }
        let k = (y * self.width + x) * 3;
        let a = a.min(1.0);
        let mix = |dst: u8, src: u8| -> u8 {
            (f64::from(dst) + a * (f64::from(src) - f64::from(dst))).round() as u8
        };
        self.rgb[k] = mix(self.rgb[k], c.0);
        self.rgb[k + 1] = mix(self.rgb[k + 1], c.1);
        self.rgb[k + 2] = mix(self.rgb[k + 2], c.2);
    }

    /// The colour at (x, y) (tests).
    pub fn pixel(&self, x: usize, y: usize) -> Rgb {
        let k = (y * self.width + x) * 3;
        Rgb(self.rgb[k], self.rgb[k + 1], self.rgb[k + 2])
    }

    /// Fill the polygon `pts` (pixel coordinates, closed implicitly, even-odd rule) with
    /// colour `c` at opacity `alpha`, anti-aliased.
    pub fn fill_polygon(&mut self, pts: &[(f64, f64)], c: Rgb, alpha: f64) {
        if pts.len() < 3 || alpha <= 0.0 {
            return;
        }
        if pts.iter().any(|(x, y)| !(x.is_finite() && y.is_finite())) {
            return;
        }
        let (mut y0, mut y1) = (f64::MAX, f64::MIN);
        let (mut x0, mut x1) = (f64::MAX, f64::MIN);
        for &(x, y) in pts {
            y0 = y0.min(y);
            y1 = y1.max(y);
            x0 = x0.min(x);
            x1 = x1.max(x);
        }
        let h = self.height as f64;
        let w = self.width as f64;
        if y1 < 0.0 || y0 >= h || x1 < 0.0 || x0 >= w {
            return;
        }
        let row0 = y0.max(0.0).floor() as usize;
        let row1 = (y1.min(h - 1e-9).floor() as usize).min(self.height - 1);
        let col0 = x0.max(0.0).floor() as usize;
        let col1 = (x1.min(w - 1e-9).floor() as usize).min(self.width - 1);
        let mut xs: Vec<f64> = Vec::with_capacity(16);
        for row in row0..=row1 {
            self.cover[col0..=col1 + 1]
                .iter_mut()
                .for_each(|c| *c = 0.0);
            for k in 0..SUB {
                let sy = row as f64 + (k as f64 + 0.5) / SUB as f64;
                xs.clear();
                for i in 0..pts.len() {
                    let (ax, ay) = pts[i];
                    let (bx, by) = pts[(i + 1) % pts.len()];
                    if (ay <= sy) != (by <= sy) {
                        xs.push(ax + (sy - ay) / (by - ay) * (bx - ax));
                    }
                }
                xs.sort_by(f64::total_cmp);
                for span in xs.chunks_exact(2) {
                    let a = span[0].clamp(0.0, w);
                    let b = span[1].clamp(0.0, w);
                    if b > a {
                        self.add_span(a, b, 1.0 / SUB as f64);
                    }
                }
            }
            for col in col0..=col1 {
                let cov = self.cover[col];
                if cov > 0.0 {
                    self.blend(col, row, c, alpha * cov.min(1.0));
                }
            }
        }
    }

    /// Add `weight` x the overlap of [a, b) with each pixel column to the coverage row.
    fn add_span(&mut self, a: f64, b: f64, weight: f64) {
        let ia = a.floor() as usize;
        let ib = b.floor() as usize;
        if ia == ib {
            self.cover[ia] += (b - a) * weight;
            return;
        }
        self.cover[ia] += (ia as f64 + 1.0 - a) * weight;
        for c in &mut self.cover[ia + 1..ib] {
            *c += weight;
        }
        if ib < self.cover.len() {
            self.cover[ib] += (b - ib as f64) * weight;
        }
    }

    /// A straight segment `width` pixels wide with square ends.
    pub fn line(&mut self, a: (f64, f64), b: (f64, f64), width: f64, c: Rgb, alpha: f64) {
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let len = dx.hypot(dy);
        if len < 1e-9 {
            return;
        }
        let (nx, ny) = (-dy / len * 0.5 * width, dx / len * 0.5 * width);
        self.fill_polygon(
            &[
                (a.0 + nx, a.1 + ny),
                (b.0 + nx, b.1 + ny),
                (b.0 - nx, b.1 - ny),
                (a.0 - nx, a.1 - ny),
            ],
            c,
            alpha,
        );
    }

    /// A disc of radius `r` pixels.
    pub fn disc(&mut self, centre: (f64, f64), r: f64, c: Rgb, alpha: f64) {
        let n = 20;
        let pts: Vec<(f64, f64)> = (0..n)
            .map(|k| {
                let t = std::f64::consts::TAU * k as f64 / n as f64;
                (centre.0 + r * libm::cos(t), centre.1 + r * libm::sin(t))
            })
            .collect();
        self.fill_polygon(&pts, c, alpha);
    }

    /// An axis-aligned rectangle of whole pixels.
    pub fn rect(&mut self, x: usize, y: usize, w: usize, h: usize, c: Rgb, alpha: f64) {
        for row in y..(y + h).min(self.height) {
            for col in x..(x + w).min(self.width) {
                self.blend(col, row, c, alpha);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: Rgb = Rgb(255, 255, 255);
    const K: Rgb = Rgb(0, 0, 0);

    #[test]
    fn a_pixel_aligned_square_is_filled_exactly() {
        let mut c = Canvas::new(10, 10, W);
        c.fill_polygon(&[(2.0, 3.0), (6.0, 3.0), (6.0, 5.0), (2.0, 5.0)], K, 1.0);
        for y in 0..10 {
            for x in 0..10 {
                let inside = (2..6).contains(&x) && (3..5).contains(&y);
                assert_eq!(c.pixel(x, y), if inside { K } else { W }, "({x}, {y})");
            }
        }
    }

    #[test]
    fn edges_are_anti_aliased_by_their_coverage() {
        let mut c = Canvas::new(4, 4, W);
        // half of column 1 covered
        c.fill_polygon(&[(1.5, 0.0), (3.0, 0.0), (3.0, 4.0), (1.5, 4.0)], K, 1.0);
        assert_eq!(c.pixel(0, 1), W);
        assert_eq!(c.pixel(1, 1), Rgb(128, 128, 128));
        assert_eq!(c.pixel(2, 1), K);
        assert_eq!(c.pixel(3, 1), W);
    }

    #[test]
    fn shapes_off_the_canvas_or_degenerate_are_ignored() {
        let mut c = Canvas::new(4, 4, W);
        let before = c.clone();
        c.fill_polygon(&[(-9.0, -9.0), (-5.0, -9.0), (-5.0, -5.0)], K, 1.0);
        c.fill_polygon(&[(0.0, 0.0), (f64::NAN, 1.0), (2.0, 2.0)], K, 1.0);
        c.line((1.0, 1.0), (1.0, 1.0), 2.0, K, 1.0);
        assert_eq!(c, before);
        // partly off the canvas: the visible part is drawn, nothing panics
        c.fill_polygon(
            &[(-3.0, -3.0), (2.0, -3.0), (2.0, 2.0), (-3.0, 2.0)],
            K,
            1.0,
        );
        assert_eq!(c.pixel(0, 0), K);
        assert_eq!(c.pixel(3, 3), W);
    }
}
