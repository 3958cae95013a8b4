//! The pictures that carry numbers: the error colour scale (viridis) with its legend bar, and
//! the convergence plot of `report.json`'s iterations. Everything is drawn with tiny-skia;
//! labels come from the built-in bitmap font (`font.rs`).

use super::font::{draw_text, text_height, text_width};
use crate::report::IterationStats;
use tiny_skia::{Color, Paint, PathBuilder, Pixmap, Rect, Stroke, Transform};

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

/// Height in pixels of a legend drawn by [`draw_legend`] at font `scale`.
pub fn legend_height(scale: u32) -> u32 {
    (10 + 4 + 4) * scale + text_height(scale) + 4
}

fn paint(c: [u8; 3]) -> Paint<'static> {
    let mut p = Paint::default();
    p.set_color_rgba8(c[0], c[1], c[2], 255);
    p.anti_alias = false;
    p
}

pub(crate) fn fill(pm: &mut Pixmap, x: f32, y: f32, w: f32, h: f32, c: [u8; 3]) {
    if let Some(r) = Rect::from_xywh(x, y, w, h) {
        pm.fill_rect(r, &paint(c), Transform::identity(), None);
    }
}

/// Draw the colour bar of `scale` at `(x, y)`, `width` pixels wide, with tick marks and
/// percentage labels under it, in `text` colour. Takes [`legend_height`] pixels.
pub fn draw_legend(
    pm: &mut Pixmap,
    x: i32,
    y: i32,
    width: u32,
    scale: &ErrorScale,
    font: u32,
    text: [u8; 3],
) {
    let bar_h = 10 * font;
    // Room for half a label each side so the end labels are not clipped.
    let margin = text_width("00.0%", font) / 2 + 2;
    let inner = width.saturating_sub(2 * margin).max(2);
    let x0 = x + margin as i32;
    for i in 0..inner {
        let t = i as f32 / (inner - 1) as f32;
        fill(
            pm,
            (x0 + i as i32) as f32,
            y as f32 + 2.0,
            1.0,
            bar_h as f32,
            viridis(t),
        );
    }
    let color = Color::from_rgba8(text[0], text[1], text[2], 255);
    for (v, label) in scale.ticks() {
        let tx = x0 + ((v / scale.max) * (inner - 1) as f32).round() as i32;
        let ty = y + 2 + bar_h as i32;
        fill(
            pm,
            tx as f32,
            ty as f32,
            font as f32,
            (4 * font) as f32,
            text,
        );
        let lw = text_width(&label, font) as i32;
        draw_text(pm, tx - lw / 2, ty + 8 * font as i32, &label, font, color);
    }
}

/// Where the convergence plot's data go: the plot area in pixels, the decades of the log
/// y axis and the iteration range of the x axis.
struct Frame {
    left: f32,
    top: f32,
    pw: f32,
    ph: f32,
    /// Decades of the y axis, `10^lo ..= 10^hi`.
    lo: i32,
    hi: i32,
    x_max: f32,
}

/// Values below this show at it on the log axis (zeros included).
const PLOT_FLOOR: f64 = 1e-6;

impl Frame {
    fn px(&self, i: f32) -> f32 {
        self.left + self.pw * i / self.x_max
    }

    fn py(&self, v: f64) -> f32 {
        let l = v.max(PLOT_FLOOR).log10();
        let t = (l - self.lo as f64) / (self.hi - self.lo) as f64;
        self.top + self.ph * (1.0 - t as f32)
    }
}

/// Whole decades `(lo, hi)` around every finite positive value (at least one decade).
fn decade_range(iters: &[IterationStats]) -> (i32, i32) {
    let vals: Vec<f64> = iters
        .iter()
        .flat_map(|s| [s.rms_rel_error, s.max_rel_error])
        .filter(|v| v.is_finite())
        .map(|v| v.max(PLOT_FLOOR))
        .collect();
    if vals.is_empty() {
        return (-3, 0);
    }
    let mn = vals.iter().cloned().fold(f64::INFINITY, f64::min);
    let mx = vals.iter().cloned().fold(0.0, f64::max);
    let lo = mn.log10().floor() as i32;
    let hi = (mx.log10().ceil() as i32).max(lo + 1);
    (lo, hi)
}

/// The convergence plot: RMS and maximum per-texel relative error per iteration on a log
/// axis (decades labelled in percent), iterations along x.
pub fn convergence_plot(iters: &[IterationStats]) -> Pixmap {
    let (w, h) = (800u32, 500u32);
    let mut pm = Pixmap::new(w, h).expect("fixed plot size");
    pm.fill(Color::WHITE);
    let (left, right, top, bottom) = (130.0f32, 30.0f32, 60.0f32, 80.0f32);
    let (lo, hi) = decade_range(iters);
    let f = Frame {
        left,
        top,
        pw: w as f32 - left - right,
        ph: h as f32 - top - bottom,
        lo,
        hi,
        x_max: (iters.len().max(2) - 1) as f32,
    };
    draw_axes(&mut pm, &f, iters.len());
    type Series = ([u8; 3], &'static str, fn(&IterationStats) -> f64);
    let series: [Series; 2] = [
        ([31, 119, 180], "RMS", |s| s.rms_rel_error),
        ([214, 39, 40], "MAX", |s| s.max_rel_error),
    ];
    for (si, (color, name, get)) in series.iter().enumerate() {
        let pts: Vec<(f32, f32)> = iters
            .iter()
            .enumerate()
            .filter(|(_, s)| get(s).is_finite())
            .map(|(i, s)| (f.px(i as f32), f.py(get(s))))
            .collect();
        draw_series(&mut pm, &pts, *color);
        // Legend entry, top right.
        let ly = 20.0 + si as f32 * 24.0;
        let lx = w as f32 - 150.0;
        fill(&mut pm, lx, ly + 6.0, 36.0, 3.0, *color);
        draw_text(
            &mut pm,
            (lx + 46.0) as i32,
            ly as i32,
            name,
            2,
            Color::BLACK,
        );
    }
    pm
}

/// Grid, ticks, labels and axes of the convergence plot for `n` iterations.
fn draw_axes(pm: &mut Pixmap, f: &Frame, n: usize) {
    let font = 2u32;
    let black = Color::BLACK;
    let grid = [220u8, 220, 220];
    let (left, top, pw, ph) = (f.left, f.top, f.pw, f.ph);
    // Decade grid lines and labels.
    for k in f.lo..=f.hi {
        let y = f.py(10f64.powi(k));
        fill(pm, left, y, pw, 1.0, grid);
        fill(pm, left - 8.0, y, 8.0, 2.0, [0, 0, 0]);
        let label = decade_percent_label(k);
        let lw = text_width(&label, font) as f32;
        let ty = (y - text_height(font) as f32 / 2.0) as i32;
        draw_text(pm, (left - 14.0 - lw) as i32, ty, &label, font, black);
    }
    // Iteration ticks: at most ~10 labels.
    let step = n.div_ceil(10).max(1);
    for i in (0..n.max(2)).step_by(step) {
        let x = f.px(i as f32);
        fill(pm, x, top, 1.0, ph, grid);
        fill(pm, x, top + ph, 2.0, 8.0, [0, 0, 0]);
        let label = i.to_string();
        let lw = text_width(&label, font) as f32;
        let tx = (x - lw / 2.0) as i32;
        draw_text(pm, tx, (top + ph + 14.0) as i32, &label, font, black);
    }
    // Axes.
    fill(pm, left, top, 2.0, ph, [0, 0, 0]);
    fill(pm, left, top + ph, pw, 2.0, [0, 0, 0]);
    let xl = "ITERATION";
    let tx = (left + pw / 2.0 - text_width(xl, font) as f32 / 2.0) as i32;
    draw_text(pm, tx, (pm.height() as f32 - 30.0) as i32, xl, font, black);
    draw_text(pm, 20, 20, "REL. ERROR", font, black);
}

/// One data series: a polyline through `pts` and a square marker at each.
fn draw_series(pm: &mut Pixmap, pts: &[(f32, f32)], color: [u8; 3]) {
    let mut paint = Paint::default();
    paint.set_color_rgba8(color[0], color[1], color[2], 255);
    paint.anti_alias = true;
    if pts.len() >= 2 {
        let mut pb = PathBuilder::new();
        pb.move_to(pts[0].0, pts[0].1);
        for &(x, y) in &pts[1..] {
            pb.line_to(x, y);
        }
        if let Some(path) = pb.finish() {
            let stroke = Stroke {
                width: 3.0,
                ..Default::default()
            };
            pm.stroke_path(&path, &paint, &stroke, Transform::identity(), None);
        }
    }
    for &(x, y) in pts {
        fill(pm, x - 4.0, y - 4.0, 8.0, 8.0, color);
    }
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
        for (_, l) in (ErrorScale { max: 0.2 }).ticks() {
            assert!(super::super::font::supports(&l), "{l}");
        }
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

    #[test]
    fn plot_draws_with_and_without_data() {
        let it = |i: u32, r: f64, m: f64| IterationStats {
            iteration: i,
            rms_rel_error: r,
            max_rel_error: m,
            ..Default::default()
        };
        let pm = convergence_plot(&[it(0, 0.2, 0.9), it(1, 0.02, 0.1), it(2, 0.004, 0.019)]);
        // some red and blue pixels are drawn
        let has = |c: [u8; 3]| {
            pm.pixels()
                .iter()
                .any(|p| [p.red(), p.green(), p.blue()] == c)
        };
        assert!(has([31, 119, 180]) && has([214, 39, 40]));
        let _ = convergence_plot(&[]);
        let _ = convergence_plot(&[it(0, 0.0, f64::NAN)]);
    }
}
