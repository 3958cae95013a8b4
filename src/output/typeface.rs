//! The one typeface of the output pictures' labels, embedded so that drawing text needs no
//! system font, fontconfig or freetype (kdmap runs on minimal containers).
//!
//! The font is DejaVu Sans Mono 2.37 (`assets/fonts/DejaVuSansMono.ttf`, 343 kB, as Debian's
//! fonts-dejavu-core ships it; Bitstream Vera licence with the Arev and public-domain DejaVu
//! parts, in `assets/fonts/LICENSE-DejaVu.txt`). plotters rasterizes it through `ab_glyph` on
//! bitmap backends; its SVG backend writes `<text>` elements that name the family.
//!
//! Why monospace: plotters' ab_glyph renderer puts each glyph at its pen position rounded
//! down to a whole pixel, so proportional text gets uneven gaps ("err or"). A monospace face
//! drawn at a size whose advance is a whole number of pixels ([`size_for_advance`]) has no
//! rounding at all, and evenly spaced labels; it is also half the size of DejaVu Sans.

use ab_glyph::{Font, FontRef};
use plotters::style::{register_font, FontStyle};
use std::sync::Once;

/// The TrueType file, in the binary.
pub const FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSansMono.ttf");

/// The family every label asks for (and the SVG names).
pub const FAMILY: &str = "monospace";

/// Make [`FONT`] plotters' [`FAMILY`], and its default family `sans-serif` too, so a style
/// left at plotters' default still finds a font. Idempotent; every drawing entry point calls
/// it before it draws.
pub fn register() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        for family in [FAMILY, "sans-serif"] {
            if register_font(family, FontStyle::Normal, FONT).is_err() {
                panic!("the embedded font assets/fonts/DejaVuSansMono.ttf does not parse");
            }
        }
    });
}

/// The font size (in plotters' sense: pixels from descent to ascent) at which every
/// character advances exactly `px` pixels.
pub fn size_for_advance(px: u32) -> f64 {
    let f = FontRef::try_from_slice(FONT).expect("the embedded font parses");
    let advance = f.h_advance_unscaled(f.glyph_id('0'));
    px as f64 * f.height_unscaled() as f64 / advance as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use ab_glyph::ScaleFont;

    #[test]
    fn the_embedded_font_has_every_label_character_at_one_advance() {
        register();
        let f = FontRef::try_from_slice(FONT).unwrap();
        let scaled = f.as_scaled(size_for_advance(7) as f32);
        let used = "0123456789.%-+ ()/abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ";
        for c in used.chars() {
            let g = f.glyph_id(c);
            assert!(g.0 != 0, "no glyph for {c:?}");
            let a = scaled.h_advance(g);
            assert!((a - 7.0).abs() < 1e-3, "{c:?} advances {a} pixels");
        }
        assert!(FONT.len() < 1 << 20, "the embedded font stays under 1 MB");
    }
}
