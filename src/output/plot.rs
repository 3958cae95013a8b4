//! The pictures that carry numbers, their common part: the error colour scale (viridis), its
//! legend bar (a plotters chart: ticks, percent labels, caption) and the RGB canvas plotters
//! draws the output PNGs' labels on. Text comes from the embedded font (`typeface.rs`); the
//! convergence chart is in `convergence.rs`.

use super::typeface;
use crate::base::error::{Error, Result};
use crate::image::write_png_rows;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::ops::Range;
use std::path::Path;

/// Matplotlib's viridis at nine evenly spaced points (8-bit sRGB), interpolated linearly:
/// perceptually ordered, readable in grey scale and by colour-blind readers.
const VIRIDIS: [[u8; 3]; 9] = [
    [68, 1, 84],
    [71, 44, 122],
    [59, 82, 139],
    [44, 113, 142],
    [33, 145, 140],
    [39, 173, 129],
    [92, 200, 99],
    [170, 220, 50],
    [253, 231, 37],
];

/// Colour of covered but unobserved texels on error maps, and of pixels without a relative
/// error (background, emitters, black photo pixels) on comparison images.
pub const NO_DATA: [u8; 3] = [96, 96, 96];

/// The viridis colour of `t` in [0, 1] (clamped; NaN maps to the low end).
pub fn viridis(t: f32) -> [u8; 3] {
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) };
    let f = t * (VIRIDIS.len() - 1) as f32;
    let i = (f.floor() as usize).min(VIRIDIS.len() - 2);
    let u = f - i as f32;
    let (a, b) = (VIRIDIS[i], VIRIDIS[i + 1]);
    [0, 1, 2].map(|k| (a[k] as f32 + (b[k] as f32 - a[k] as f32) * u + 0.5) as u8)
}

/// The relative-error colour scale shared by every error map and comparison image of a run:
/// `0 ..= max` (fractions) onto viridis, values above `max` saturate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ErrorScale {
    pub max: f32,
}

impl ErrorScale {
    /// The scale ends the paper's figures suggest: 5% first, wider only when needed.
    pub const STEPS: [f32; 9] = [0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 100.0];

    /// The smallest of [`Self::STEPS`] that at most 1% of the values exceed, from
    /// `exceed[k]` = how many of `total` values exceed `STEPS[k]`.
    pub fn from_exceedance(exceed: &[u64; 9], total: u64) -> ErrorScale {
        let allowed = total / 100;
        let k = exceed
            .iter()
            .position(|&n| n <= allowed)
            .unwrap_or(Self::STEPS.len() - 1);
        ErrorScale {
            max: Self::STEPS[k],
        }
    }

    pub fn color(&self, e: f32) -> [u8; 3] {
        viridis(e / self.max)
    }

    /// Five equal steps from 0 to `max`, as `(fraction, label)`.
    pub fn ticks(&self) -> Vec<(f32, String)> {
        (0..=5)
            .map(|i| {
                let v = self.max * i as f32 / 5.0;
                (v, percent_label(v as f64))
            })
            .collect()
    }
}

/// `0.012` -> `"1.2%"`: at most one decimal, trailing `.0` dropped.
pub fn percent_label(frac: f64) -> String {
    let p = frac * 100.0;
    let r = (p * 10.0).round() / 10.0;
    if (r - r.round()).abs() < 1e-9 {
        format!("{}%", r.round() as i64)
    } else {
        format!("{r:.1}%")
    }
}

/// `10^k` as a percentage label without floating-point noise: `k = -2` -> `"1%"`,
/// `k = -4` -> `"0.01%"`, `k = 0` -> `"100%"`.
pub fn decade_percent_label(k: i32) -> String {
    let e = k + 2;
    if e >= 0 {
        format!("1{}%", "0".repeat(e as usize))
    } else {
        format!("0.{}1%", "0".repeat((-e - 1) as usize))
    }
}

/// An opaque 8-bit RGB picture: the buffer plotters' bitmap backend draws on (3 bytes a
/// pixel, rows top first), written as an RGBA PNG.
pub struct Canvas {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
}

/// What drawing on a [`Canvas`] can fail with.
pub type DrawError = DrawingAreaErrorKind<<BitMapBackend<'static> as DrawingBackend>::ErrorType>;

impl Canvas {
    /// A `width x height` canvas filled with `background`.
    pub fn new(width: u32, height: u32, background: [u8; 3]) -> Canvas {
        let n = width as usize * height as usize;
        Canvas {
            width,
            height,
            rgb: background.repeat(n),
        }
    }

    pub fn pixel(&self, x: u32, y: u32) -> [u8; 3] {
        let o = 3 * (y as usize * self.width as usize + x as usize);
        [self.rgb[o], self.rgb[o + 1], self.rgb[o + 2]]
    }

    pub fn put(&mut self, x: u32, y: u32, c: [u8; 3]) {
        let o = 3 * (y as usize * self.width as usize + x as usize);
        self.rgb[o..o + 3].copy_from_slice(&c);
    }

    /// Row `y` as opaque RGBA, as [`write_png_rows`] takes it.
    pub fn rgba_row(&self, y: u32) -> Vec<u8> {
        let w = self.width as usize;
        let row = &self.rgb[3 * y as usize * w..3 * (y as usize + 1) * w];
        row.chunks_exact(3)
            .flat_map(|c| [c[0], c[1], c[2], 255])
            .collect()
    }

    pub fn write_png(&self, path: &Path) -> Result<()> {
        write_png_rows(path, self.width, self.height, |y| Ok(self.rgba_row(y)))
    }

    /// Let plotters draw on the whole canvas (the embedded font registered first).
    pub fn draw<T>(
        &mut self,
        what: &str,
        f: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> std::result::Result<T, DrawError>,
    ) -> Result<T> {
        typeface::register();
        let (w, h) = (self.width, self.height);
        let root = BitMapBackend::with_buffer(&mut self.rgb, (w, h)).into_drawing_area();
        let out = f(&root).map_err(|e| draw_error(what, e))?;
        root.present().map_err(|e| draw_error(what, e))?;
        Ok(out)
    }
}

/// A plotters failure as the crate's error (a bug: our layouts are fixed).
pub fn draw_error(what: &str, e: impl std::fmt::Display) -> Error {
    Error::internal(format!("cannot draw {what}: {e}"))
}

/// An 8-bit sRGB colour as plotters takes it.
pub fn rgb(c: [u8; 3]) -> RGBColor {
    RGBColor(c[0], c[1], c[2])
}

/// The legend's caption, under its tick labels: what the colours measure.
pub const LEGEND_TITLE: &str = "relative luminance error";

/// How a legend looks: the width of a character in pixels, text (and tick) colour,
/// background.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LegendStyle {
    pub char_px: u32,
    pub text: [u8; 3],
    pub background: [u8; 3],
}

impl LegendStyle {
    /// Light text on `background`, larger on pictures at least 400 pixels wide, smaller on
    /// ones too narrow for [`LEGEND_TITLE`] in 7-pixel characters.
    pub fn light_on(background: [u8; 3], width: u32) -> LegendStyle {
        let fit = width / (LEGEND_TITLE.len() as u32 + 2);
        LegendStyle {
            char_px: if width >= 400 { 10 } else { fit.clamp(5, 7) },
            text: [240, 240, 240],
            background,
        }
    }

    /// The text's height in pixels.
    pub fn text_px(&self) -> u32 {
        typeface::size_for_advance(self.char_px).ceil() as u32
    }

    /// The labels' font and colour.
    pub fn font(&self) -> TextStyle<'static> {
        let size = typeface::size_for_advance(self.char_px);
        (typeface::FAMILY, size).into_font().color(&rgb(self.text))
    }

    fn bar_height(&self) -> u32 {
        self.text_px()
    }

    /// Under the bar: tick marks, their labels and the caption.
    fn label_area(&self) -> u32 {
        2 * TICK + 2 * self.text_px() + self.text_px() / 2 + 4
    }
}

/// Length of the legend's tick marks, in pixels.
const TICK: u32 = 4;
/// The legend's x axis counts thousandths of the scale's maximum.
const LEGEND_UNITS: i32 = 1000;
/// Free pixels above and below a legend.
const LEGEND_PAD: u32 = 3;

/// Height in pixels of a legend drawn by [`draw_legend`] in `style`.
pub fn legend_height(style: &LegendStyle) -> u32 {
    2 * LEGEND_PAD + style.bar_height() + style.label_area()
}

/// Draw the colour bar of `scale` across `area` (best [`legend_height`] tall) on its
/// background: a plotters chart whose x axis is the error, with ticks at [`ErrorScale::ticks`]
/// labelled in percent and [`LEGEND_TITLE`] under them. Returns the bar's pixel columns
/// within `area` (the first shows 0, the last `scale.max`).
pub fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    scale: &ErrorScale,
    style: &LegendStyle,
) -> std::result::Result<Range<i32>, DrawingAreaErrorKind<DB::ErrorType>> {
    area.fill(&rgb(style.background))?;
    let bar = legend_axis(area, scale, style)?;
    // A column at a time: the column of the axis' value v shows v's colour.
    let (w, h) = bar.dim_in_pixel();
    for x in 0..w as i32 {
        let v = x as f32 / (w as f32 - 1.0).max(1.0) * scale.max;
        let c = rgb(scale.color(v)).filled();
        bar.draw(&Rectangle::new([(x, 0), (x + 1, h as i32)], c))?;
    }
    let (columns, x0) = (bar.get_pixel_range().0, area.get_base_pixel().0);
    Ok(columns.start - x0..columns.end - x0)
}

/// The legend's axis, ticks, labels and caption; returns the plot area the bar fills. The x
/// axis counts thousandths of `scale.max` (plotters formats an integer axis with custom key
/// points), the ticks are [`ErrorScale::ticks`] with their labels.
fn legend_axis<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    scale: &ErrorScale,
    style: &LegendStyle,
) -> std::result::Result<DrawingArea<DB, Shift>, DrawingAreaErrorKind<DB::ErrorType>> {
    let font = style.font();
    // Room for half an end label each side.
    let half = area.estimate_text_size("100%", &font)?.0 / 2 + 2;
    let ticks = scale.ticks();
    let at = |v: f32| (v / scale.max * LEGEND_UNITS as f32).round() as i32;
    let keys: Vec<i32> = ticks.iter().map(|t| at(t.0)).collect();
    let label = |k: &i32| match keys.iter().position(|x| x == k) {
        Some(i) => ticks[i].1.clone(),
        None => String::new(),
    };
    let mut chart = ChartBuilder::on(area)
        .margin(LEGEND_PAD)
        .margin_left(half)
        .margin_right(half)
        .x_label_area_size(style.label_area())
        .build_cartesian_2d((0..LEGEND_UNITS).with_key_points(keys.clone()), 0..1)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .disable_y_axis()
        .axis_style(rgb(style.text))
        .set_tick_mark_size(LabelAreaPosition::Bottom, TICK as i32)
        .x_label_style(font.clone())
        .x_label_formatter(&label)
        .x_desc(LEGEND_TITLE)
        .axis_desc_style(font)
        .draw()?;
    Ok(chart.plotting_area().strip_coord_spec())
}

/// A `width`-wide picture of just the legend of `scale` in `style`.
pub fn legend_canvas(width: u32, scale: &ErrorScale, style: &LegendStyle) -> Result<Canvas> {
    let mut c = Canvas::new(width, legend_height(style), style.background);
    c.draw("the error legend", |area| draw_legend(area, scale, style))?;
    Ok(c)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn viridis_ends_and_clamps() {
        assert_eq!(viridis(0.0), [68, 1, 84]);
        assert_eq!(viridis(1.0), [253, 231, 37]);
        assert_eq!(viridis(7.0), viridis(1.0));
        assert_eq!(viridis(-1.0), viridis(0.0));
        assert_eq!(viridis(f32::NAN), viridis(0.0));
        assert_eq!(viridis(0.5), [33, 145, 140]);
    }

    #[test]
    fn labels_have_no_float_noise() {
        assert_eq!(percent_label(0.01), "1%");
        assert_eq!(percent_label(0.012), "1.2%");
        assert_eq!(percent_label(0.05), "5%");
        assert_eq!(percent_label(0.0), "0%");
        assert_eq!(decade_percent_label(-2), "1%");
        assert_eq!(decade_percent_label(-3), "0.1%");
        assert_eq!(decade_percent_label(-5), "0.001%");
        assert_eq!(decade_percent_label(0), "100%");
        let s = ErrorScale { max: 0.05 };
        let t: Vec<String> = s.ticks().into_iter().map(|t| t.1).collect();
        assert_eq!(t, ["0%", "1%", "2%", "3%", "4%", "5%"]);
    }

    #[test]
    fn scale_widens_only_when_more_than_one_percent_exceed() {
        // 1000 values: 5 above 5% -> keep 5%; 50 above 5%, 5 above 10% -> 10%.
        let mut ex = [0u64; 9];
        ex[0] = 5;
        assert_eq!(ErrorScale::from_exceedance(&ex, 1000).max, 0.05);
        ex[0] = 50;
        ex[1] = 5;
        assert_eq!(ErrorScale::from_exceedance(&ex, 1000).max, 0.1);
        assert_eq!(ErrorScale::from_exceedance(&[1000; 9], 1000).max, 100.0);
    }

    const BLACK_BG: LegendStyle = LegendStyle {
        char_px: 7,
        text: [240, 240, 240],
        background: [0, 0, 0],
    };

    #[test]
    fn the_legend_bar_shows_the_scale_colours_at_their_values() {
        let scale = ErrorScale { max: 0.05 };
        let mut c = Canvas::new(300, legend_height(&BLACK_BG), BLACK_BG.background);
        let cols = c
            .draw("a legend", |a| draw_legend(a, &scale, &BLACK_BG))
            .unwrap();
        assert!(
            cols.start > 0 && cols.end < 300 && cols.len() > 200,
            "{cols:?}"
        );
        let y = LEGEND_PAD + BLACK_BG.bar_height() / 2;
        // 0, 1%, ..., 5%: the column of a value holds its colour (within one column's step)
        for (v, _) in scale.ticks() {
            let x = cols.start + ((v / scale.max) * (cols.len() - 1) as f32).round() as i32;
            let (got, want) = (c.pixel(x as u32, y), scale.color(v));
            let near = (0..3).all(|k| got[k].abs_diff(want[k]) <= 3);
            assert!(near, "{v}: {got:?} vs {want:?} at x {x}");
        }
        assert_eq!(c.pixel(cols.start as u32, y), viridis(0.0));
        assert!(
            c.pixel(cols.end as u32 + 1, y) == [0, 0, 0],
            "right of the bar"
        );
    }

    #[test]
    fn the_legend_labels_draw_text_under_the_bar() {
        let scale = ErrorScale { max: 0.2 };
        let c = legend_canvas(240, &scale, &BLACK_BG).unwrap();
        assert_eq!(c.height, legend_height(&BLACK_BG));
        // below the bar and the tick marks: grey text pixels (viridis is never grey)
        let top = LEGEND_PAD + BLACK_BG.bar_height() + TICK + 1;
        let text = (top..c.height)
            .flat_map(|y| (0..c.width).map(move |x| (x, y)))
            .filter(|&(x, y)| {
                let p = c.pixel(x, y);
                p[0] > 100 && p[0] == p[1] && p[1] == p[2]
            })
            .count();
        assert!(text > 200, "{text} text pixels");
        // the rows hold both the tick labels and the caption: text in the lower half too
        let low = (c.height - BLACK_BG.text_px()..c.height)
            .any(|y| (0..c.width).any(|x| c.pixel(x, y)[0] > 100));
        assert!(low, "no caption");
    }

    #[test]
    fn legends_fit_their_caption_at_every_width() {
        for width in [120, 160, 240, 399, 400, 1200] {
            let style = LegendStyle::light_on([0, 0, 0], width);
            let caption = LEGEND_TITLE.len() as u32 * style.char_px;
            assert!(caption <= width || style.char_px == 5, "{width}: {style:?}");
            let c = legend_canvas(width, &ErrorScale { max: 1.0 }, &style).unwrap();
            // nothing drawn into the last row or column: the caption and end labels fit
            let last = c.height - 1;
            assert!(
                (0..c.width).all(|x| c.pixel(x, last) == [0, 0, 0]),
                "{width}"
            );
            assert!(
                (0..c.height).all(|y| c.pixel(c.width - 1, y) == [0, 0, 0]),
                "{width}"
            );
        }
    }

    #[test]
    fn a_canvas_writes_an_opaque_png() {
        let mut c = Canvas::new(3, 2, [1, 2, 3]);
        c.put(2, 1, [9, 8, 7]);
        assert_eq!(c.rgba_row(1), [1, 2, 3, 255, 1, 2, 3, 255, 9, 8, 7, 255]);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.png");
        c.write_png(&path).unwrap();
        let pm = tiny_skia::Pixmap::load_png(&path).unwrap();
        assert_eq!((pm.width(), pm.height()), (3, 2));
        let p = pm.pixel(2, 1).unwrap();
        assert_eq!([p.red(), p.green(), p.blue(), p.alpha()], [9, 8, 7, 255]);
    }
}
