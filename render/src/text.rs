//! Text on a [`Canvas`]: the DejaVu Sans face compiled into the binary (no system fonts),
//! rasterised by `ab_glyph` into coverage that is blended like any other shape.

use std::sync::OnceLock;

use ab_glyph::{Font, FontRef, PxScale, ScaleFont, point};

use crate::raster::{Canvas, Rgb};

/// The DejaVu Sans TrueType face (its licence: `render/assets/DejaVuSans.LICENSE`).
pub static FONT_TTF: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

fn font() -> &'static FontRef<'static> {
    static FONT: OnceLock<FontRef<'static>> = OnceLock::new();
    // the bytes are a valid TrueType face (the text tests draw with it)
    FONT.get_or_init(|| FontRef::try_from_slice(FONT_TTF).expect("embedded TrueType face"))
}

/// Width in pixels of `text` at `size` pixels.
pub fn text_width(text: &str, size: f32) -> f32 {
    let f = font().as_scaled(PxScale::from(size));
    let mut w = 0.0;
    let mut prev = None;
    for ch in text.chars() {
        let id = f.glyph_id(ch);
        if let Some(p) = prev {
            w += f.kern(p, id);
        }
        w += f.h_advance(id);
        prev = Some(id);
    }
    w
}

/// Draw `text` with its top-left corner at (x, y), `size` pixels high.
pub fn draw_text(canvas: &mut Canvas, text: &str, x: f32, y: f32, size: f32, c: Rgb) {
    let f = font().as_scaled(PxScale::from(size));
    let baseline = y + f.ascent();
    let mut pen = x;
    let mut prev = None;
    for ch in text.chars() {
        let id = f.glyph_id(ch);
        if let Some(p) = prev {
            pen += f.kern(p, id);
        }
        let glyph = id.with_scale_and_position(PxScale::from(size), point(pen, baseline));
        pen += f.h_advance(id);
        prev = Some(id);
        let Some(outline) = font().outline_glyph(glyph) else {
            continue; // a space
        };
        let b = outline.px_bounds();
        outline.draw(|gx, gy, cov| {
            let (px, py) = (
                b.min.x as i64 + i64::from(gx),
                b.min.y as i64 + i64::from(gy),
            );
            if px >= 0 && py >= 0 {
                canvas.blend(px as usize, py as usize, c, f64::from(cov));
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_is_drawn_inside_its_measured_box() {
        let white = Rgb(255, 255, 255);
        let mut c = Canvas::new(120, 30, white);
        let w = text_width("lap 1/2", 16.0);
        assert!(w > 30.0 && w < 80.0, "width {w}");
        draw_text(&mut c, "lap 1/2", 10.0, 5.0, 16.0, Rgb(0, 0, 0));
        let mut inked = 0;
        for y in 0..30 {
            for x in 0..120 {
                if c.pixel(x, y) != white {
                    inked += 1;
                    assert!(x >= 9 && (x as f32) <= 11.0 + w, "ink at x = {x}");
                    assert!((4..=25).contains(&y), "ink at y = {y}");
                }
            }
        }
        assert!(inked > 60, "{inked} pixels inked");
    }
}
