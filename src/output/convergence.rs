//! `report_convergence.svg|png`: how the solver converged, the per-texel relative error of
//! each iteration of `report.json` (RMS, mean and maximum) on a logarithmic axis labelled in
//! percent, as a plotters chart. The SVG keeps its text as `<text>` (no font inside); the PNG
//! is rasterized with the embedded font (`typeface.rs`).

use super::plot::{decade_percent_label, rgb, Canvas};
use super::typeface::{self, size_for_advance, FAMILY};
use crate::base::error::Result;
use crate::base::fsio;
use crate::report::IterationStats;
use plotters::coord::combinators::{LogCoord, WithKeyPoints};
use plotters::coord::types::RangedCoordu32;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::Path;

/// The chart's size in pixels (SVG user units).
pub const SIZE: (u32, u32) = (800, 500);

/// Values below this show at it on the log axis (zeros included).
const PLOT_FLOOR: f64 = 1e-6;

/// A plotted statistic: legend label, colour, and its value in an iteration.
type Series = (&'static str, [u8; 3], fn(&IterationStats) -> f64);

/// The series, in legend order (matplotlib's first colours).
pub const SERIES: [Series; 3] = [
    ("max", [214, 39, 40], |s| s.max_rel_error),
    ("RMS", [31, 119, 180], |s| s.rms_rel_error),
    ("mean", [44, 160, 44], |s| s.mean_rel_error),
];

pub const X_DESC: &str = "iteration";
pub const Y_DESC: &str = "relative luminance error per texel";
const CAPTION: &str = "Convergence of the solver";

/// Write `report_convergence.svg` and `report_convergence.png` into `out`.
pub fn write_convergence(out: &Path, iters: &[IterationStats]) -> Result<()> {
    let svg = convergence_svg(iters)?;
    fsio::write_atomic(&out.join("report_convergence.svg"), svg.as_bytes())?;
    convergence_png(iters)?.write_png(&out.join("report_convergence.png"))
}

/// The chart as an SVG document.
pub fn convergence_svg(iters: &[IterationStats]) -> Result<String> {
    typeface::register();
    let draw_err = |e| super::plot::draw_error("the convergence chart", e);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
        draw_chart(&root, iters).map_err(draw_err)?;
        root.present().map_err(draw_err)?;
    }
    Ok(svg)
}

/// The chart rasterized.
pub fn convergence_png(iters: &[IterationStats]) -> Result<Canvas> {
    let mut c = Canvas::new(SIZE.0, SIZE.1, [255, 255, 255]);
    c.draw("the convergence chart", |root| draw_chart(root, iters))?;
    Ok(c)
}

/// Whole decades `(lo, hi)` around every finite positive value (at least one decade).
fn decade_range(iters: &[IterationStats]) -> (i32, i32) {
    let vals: Vec<f64> = iters
        .iter()
        .flat_map(|s| SERIES.map(|(_, _, get)| get(s)))
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

/// The chart's coordinates: iterations along x, the error on a log axis along y.
type Chart<'a, DB> =
    ChartContext<'a, DB, Cartesian2d<RangedCoordu32, WithKeyPoints<LogCoord<f64>>>>;
type DrawResult<T, DB> =
    std::result::Result<T, DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>>;

/// Axes, grid, the series and their legend on `root`.
fn draw_chart<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    iters: &[IterationStats],
) -> DrawResult<(), DB> {
    root.fill(&WHITE)?;
    let x_max = (iters.len().max(2) - 1) as u32;
    let mut chart = ChartBuilder::on(root)
        .caption(CAPTION, (FAMILY, size_for_advance(12)))
        .margin(16)
        .x_label_area_size(56)
        .y_label_area_size(96)
        .build_cartesian_2d(0..x_max, log_axis(decade_range(iters)))?;
    chart
        .configure_mesh()
        .x_labels(10)
        .x_desc(X_DESC)
        .y_desc(Y_DESC)
        .y_label_formatter(&|v| decade_percent_label(v.log10().round() as i32))
        .label_style((FAMILY, size_for_advance(8)))
        .axis_desc_style((FAMILY, size_for_advance(9)))
        .draw()?;
    for series in SERIES {
        draw_series(&mut chart, iters, series)?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .label_font((FAMILY, size_for_advance(8)))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
}

/// The log axis from `10^lo` to `10^hi`: ticks and labels at the decades, light grid lines
/// at 2..9 times each.
fn log_axis((lo, hi): (i32, i32)) -> WithKeyPoints<LogCoord<f64>> {
    let decades: Vec<f64> = (lo..=hi).map(|k| 10f64.powi(k)).collect();
    let minor = (lo..hi).flat_map(|k| (2..10).map(move |m| m as f64 * 10f64.powi(k)));
    (decades[0]..decades[decades.len() - 1])
        .log_scale()
        .with_key_points(decades)
        .with_light_points(minor)
}

/// One series: a line through its finite values (zeros at [`PLOT_FLOOR`]), a dot at each,
/// and its legend entry.
fn draw_series<DB: DrawingBackend>(
    chart: &mut Chart<'_, DB>,
    iters: &[IterationStats],
    (name, color, get): Series,
) -> DrawResult<(), DB> {
    let pts: Vec<(u32, f64)> = iters
        .iter()
        .enumerate()
        .filter(|(_, s)| get(s).is_finite())
        .map(|(i, s)| (i as u32, get(s).max(PLOT_FLOOR)))
        .collect();
    let c = rgb(color);
    chart
        .draw_series(LineSeries::new(pts.iter().copied(), c.stroke_width(2)))?
        .label(name)
        .legend(move |(x, y)| PathElement::new([(x, y), (x + 24, y)], c.stroke_width(3)));
    chart.draw_series(pts.iter().map(|&p| Circle::new(p, 4, c.filled())))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn it(i: u32, r: f64, m: f64) -> IterationStats {
        IterationStats {
            iteration: i,
            rms_rel_error: r,
            mean_rel_error: r * 0.7,
            max_rel_error: m,
            ..Default::default()
        }
    }

    fn known() -> Vec<IterationStats> {
        vec![it(0, 0.2, 0.9), it(1, 0.02, 0.1), it(2, 0.004, 0.019)]
    }

    #[test]
    fn decades_cover_every_series() {
        // mean 0.0028 of the last iteration reaches below the RMS's decade
        assert_eq!(decade_range(&known()), (-3, 0));
        assert_eq!(decade_range(&[]), (-3, 0));
        assert_eq!(decade_range(&[it(0, 0.05, 0.05)]), (-2, -1));
    }

    #[test]
    fn the_svg_has_the_series_axes_and_decade_labels() {
        let svg = convergence_svg(&known()).unwrap();
        assert!(svg.starts_with("<svg"), "{}", &svg[..40]);
        // plotters writes each text element's text on a line of its own
        let texts: Vec<&str> = svg.lines().map(str::trim).collect();
        for t in [
            "max", "RMS", "mean", X_DESC, Y_DESC, CAPTION, "0.1%", "1%", "100%", "2",
        ] {
            assert!(texts.contains(&t), "no text {t:?}");
        }
        // one polyline per series, in its colour
        for (_, c, _) in SERIES {
            let hex = format!("#{:02X}{:02X}{:02X}", c[0], c[1], c[2]);
            assert!(svg.contains(&hex), "no {hex}");
        }
    }

    #[test]
    fn the_png_draws_with_and_without_data() {
        let c = convergence_png(&known()).unwrap();
        assert_eq!((c.width, c.height), SIZE);
        let has = |want: [u8; 3]| c.rgb.chunks_exact(3).any(|p| p == want);
        for (_, color, _) in SERIES {
            assert!(has(color), "{color:?}");
        }
        // labels: dark anti-aliased text pixels left of the plot (the y tick labels)
        let text = (60..400)
            .flat_map(|y| (0..90).map(move |x| (x, y)))
            .filter(|&(x, y)| c.pixel(x, y)[0] < 128)
            .count();
        assert!(text > 50, "{text}");
        convergence_png(&[]).unwrap();
        convergence_png(&[it(0, 0.0, f64::NAN)]).unwrap();
        convergence_svg(&[]).unwrap();
    }
}
