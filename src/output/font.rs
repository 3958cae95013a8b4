//! A tiny hand-written 5x7 bitmap font for the labels on the output PNGs (legend ticks, plot
//! axes, panel titles).
//!
//! Why it exists: tiny-skia, the crate's only rasterizer, draws paths but has no text, and a
//! font crate plus an embedded TrueType file would be a large dependency for a few dozen
//! labels made of digits, `.`, `%`, `-`, `e` and a handful of capital letters. Each glyph is
//! seven rows of five bits (bit 4 is the leftmost column), drawn as filled squares, so the
//! labels stay crisp at any integer scale and need no anti-aliasing.

use tiny_skia::{Color, Paint, Pixmap, Rect, Transform};

/// Glyph cell width and height in font pixels (the advance adds one column of spacing).
pub const GLYPH_W: u32 = 5;
pub const GLYPH_H: u32 = 7;
/// Horizontal advance per character, in font pixels.
pub const ADVANCE: u32 = GLYPH_W + 1;

/// The rows of a glyph, top first; `None` for characters the font lacks.
fn glyph(c: char) -> Option<[u8; 7]> {
    Some(match c {
        '0' => [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E],
        '1' => [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E],
        '2' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F],
        '3' => [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E],
        '4' => [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02],
        '5' => [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E],
        '6' => [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E],
        '7' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E],
        '9' => [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C],
        '.' => [0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C],
        '%' => [0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03],
        '-' => [0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00],
        '+' => [0x00, 0x04, 0x04, 0x1F, 0x04, 0x04, 0x00],
        'e' => [0x00, 0x00, 0x0E, 0x11, 0x1F, 0x10, 0x0E],
        'x' => [0x00, 0x00, 0x11, 0x0A, 0x04, 0x0A, 0x11],
        ' ' => [0x00; 7],
        'A' => [0x0E, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'D' => [0x1E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x1E],
        'E' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F],
        'G' => [0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F],
        'I' => [0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E],
        'L' => [0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F],
        'M' => [0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11],
        'N' => [0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11],
        'O' => [0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'R' => [0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11],
        'S' => [0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E],
        'T' => [0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04],
        'V' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04],
        'X' => [0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11],
        _ => return None,
    })
}

/// Whether every character of `text` has a glyph.
pub fn supports(text: &str) -> bool {
    text.chars().all(|c| glyph(c).is_some())
}

/// Width in pixels of `text` drawn at `scale` (no trailing spacing column).
pub fn text_width(text: &str, scale: u32) -> u32 {
    let n = text.chars().count() as u32;
    (n * ADVANCE).saturating_sub(1) * scale
}

/// Height in pixels of a line of text at `scale`.
pub fn text_height(scale: u32) -> u32 {
    GLYPH_H * scale
}

/// Draw `text` with its top-left corner at `(x, y)` (pixels), each font pixel a
/// `scale x scale` square of `color`. Characters without a glyph are drawn as blanks;
/// whatever falls outside the pixmap is clipped.
pub fn draw_text(pm: &mut Pixmap, x: i32, y: i32, text: &str, scale: u32, color: Color) {
    let mut paint = Paint::default();
    paint.set_color(color);
    paint.anti_alias = false;
    let s = scale.max(1) as f32;
    for (i, c) in text.chars().enumerate() {
        let Some(rows) = glyph(c) else { continue };
        let gx = x as f32 + (i as u32 * ADVANCE) as f32 * s;
        for (r, bits) in rows.iter().enumerate() {
            for col in 0..GLYPH_W {
                if bits & (0x10 >> col) != 0 {
                    let px = gx + col as f32 * s;
                    let py = y as f32 + r as f32 * s;
                    if let Some(rect) = Rect::from_xywh(px, py, s, s) {
                        pm.fill_rect(rect, &paint, Transform::identity(), None);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn glyphs_fit_five_columns_and_digits_differ() {
        let mut seen = std::collections::HashSet::new();
        for c in "0123456789.%-+ex ADEGILMNORSTVX".chars() {
            let g = glyph(c).unwrap();
            assert!(g.iter().all(|r| r & !0x1F == 0), "{c}");
            if c != ' ' {
                assert!(g.iter().any(|&r| r != 0), "{c} is blank");
                assert!(seen.insert(g), "{c} duplicates another glyph");
            }
        }
        assert!(supports("1e-3 12.5%"));
        assert!(!supports("q"));
    }

    #[test]
    fn text_is_drawn_where_asked_and_clipped() {
        let mut pm = Pixmap::new(40, 20).unwrap();
        draw_text(&mut pm, 2, 3, "1", 2, Color::WHITE);
        let lit = |x: u32, y: u32| pm.pixel(x, y).unwrap().red() > 0;
        // '1' row 0 is 0x04: column 2 -> pixels x = 2 + 2*2 .. +2, y = 3..5
        assert!(lit(6, 3) && lit(7, 4));
        assert!(!lit(2, 3) && !lit(10, 3));
        // bottom row 0x0E spans columns 1..=3
        assert!(lit(4, 3 + 12) && lit(9, 3 + 13));
        assert_eq!(text_width("10%", 1), 17);
        // off-canvas text does not panic
        draw_text(&mut pm, 35, 15, "888", 3, Color::WHITE);
        draw_text(&mut pm, -50, -50, "888", 1, Color::WHITE);
    }
}
