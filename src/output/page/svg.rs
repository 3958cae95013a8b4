//! The page's plots as inline SVG: line charts of per-iteration and per-pass figures and bar
//! charts of per-stage figures. Drawn here as a few dozen elements each, so the page needs no
//! plotting script and scales them sharply at any zoom.

use super::html::{esc, num};
use std::fmt::Write as _;

const W: f64 = 560.0;
const H: f64 = 260.0;
/// Plot area margins: left, right, top, bottom.
const M: [f64; 4] = [76.0, 150.0, 16.0, 40.0];
/// Series colours (colour-blind safe, Okabe-Ito).
const COLOURS: [&str; 6] = [
    "#0072b2", "#e69f00", "#009e73", "#d55e00", "#cc79a7", "#56b4e9",
];

/// One line of a chart: a name and its `(x, y)` points.
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
}

/// A line chart of `series` with axis titles; `y_pct` labels the y axis in percent.
pub fn line_chart(
    title: &str,
    x_title: &str,
    y_title: &str,
    series: &[Series],
    y_pct: bool,
) -> String {
    let pts = series.iter().flat_map(|s| s.points.iter());
    let (x0, x1) = bounds(pts.clone().map(|p| p.0), false);
    let (_, y1) = bounds(pts.map(|p| p.1), true);
    let sx = |x: f64| M[0] + (x - x0) / (x1 - x0) * (W - M[0] - M[1]);
    let sy = |y: f64| H - M[3] - y / y1 * (H - M[2] - M[3]);
    let mut s = open(title);
    axes(&mut s, x_title, y_title);
    for i in 0..=4 {
        let y = y1 * i as f64 / 4.0;
        let label = match y_pct {
            true if y1 >= 0.04 => format!("{:.1}%", 100.0 * y),
            true => format!("{:.2}%", 100.0 * y),
            false => num(y),
        };
        tick_y(&mut s, sy(y), &label);
    }
    for x in x_ticks(x0, x1) {
        let _ = write!(
            s,
            "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text>",
            sx(x),
            H - M[3] + 16.0,
            x as i64
        );
    }
    for (k, se) in series.iter().enumerate() {
        let c = COLOURS[k % COLOURS.len()];
        let path: Vec<String> = se
            .points
            .iter()
            .map(|&(x, y)| format!("{:.1},{:.1}", sx(x), sy(y)))
            .collect();
        let _ = write!(
            s,
            "<polyline fill=\"none\" stroke=\"{c}\" stroke-width=\"2\" points=\"{}\"/>",
            path.join(" ")
        );
        for &(x, y) in &se.points {
            let _ = write!(
                s,
                "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"3\" fill=\"{c}\"/>",
                sx(x),
                sy(y)
            );
        }
        key(&mut s, k, c, &se.name);
    }
    s.push_str("</svg>");
    s
}

/// A horizontal bar chart of `(label, value)` with the values written at the bars' ends.
pub fn bar_chart(title: &str, unit: &str, bars: &[(String, f64)]) -> String {
    let (_, v1) = bounds(bars.iter().map(|b| b.1), true);
    let row = 20.0;
    let h = M[2] + row * bars.len() as f64 + 8.0;
    let mut s = format!(
        "<svg class=\"chart\" xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 {W} {h}\" role=\"img\" aria-label=\"{t}\"><title>{t}</title>",
        t = esc(title)
    );
    let x0 = 150.0;
    for (i, (label, v)) in bars.iter().enumerate() {
        let y = M[2] + row * i as f64;
        let w = v / v1 * (W - x0 - 110.0);
        let _ = write!(
            s,
            "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\">{}</text><rect x=\"{x0}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"{}\"/><text x=\"{:.1}\" y=\"{:.1}\">{} {}</text>",
            x0 - 6.0, y + 13.0, esc(label), y + 3.0, w.max(0.5), row - 6.0, COLOURS[0], x0 + w + 6.0, y + 13.0, num(*v), esc(unit)
        );
    }
    s.push_str("</svg>");
    s
}

/// The chart's opening tag, sized by its view box.
fn open(title: &str) -> String {
    format!(
        "<svg class=\"chart\" xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 {W} {H}\" role=\"img\" aria-label=\"{t}\"><title>{t}</title>",
        t = esc(title)
    )
}

/// The two axis lines and their titles.
fn axes(s: &mut String, x_title: &str, y_title: &str) {
    let (l, b, r) = (M[0], H - M[3], W - M[1]);
    let _ = write!(
        s,
        "<path d=\"M{l},{t} V{b} H{r}\" stroke=\"#888\" fill=\"none\"/><text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text><text transform=\"translate(14,{:.1}) rotate(-90)\" text-anchor=\"middle\">{}</text>",
        (l + r) / 2.0, H - 6.0, esc(x_title), (M[2] + b) / 2.0, esc(y_title), t = M[2]
    );
}

/// A y tick with its grid line and label.
fn tick_y(s: &mut String, y: f64, label: &str) {
    let _ = write!(
        s,
        "<line x1=\"{}\" x2=\"{}\" y1=\"{y:.1}\" y2=\"{y:.1}\" stroke=\"#ddd\"/><text x=\"{}\" y=\"{:.1}\" text-anchor=\"end\">{}</text>",
        M[0], W - M[1], M[0] - 6.0, y + 4.0, esc(label)
    );
}

/// The legend entry of series `k`.
fn key(s: &mut String, k: usize, colour: &str, name: &str) {
    let y = M[2] + 8.0 + 18.0 * k as f64;
    let x = W - M[1] + 12.0;
    let _ = write!(
        s,
        "<rect x=\"{x}\" y=\"{:.1}\" width=\"14\" height=\"4\" fill=\"{colour}\"/><text x=\"{}\" y=\"{:.1}\">{}</text>",
        y - 2.0, x + 20.0, y + 4.0, esc(name)
    );
}

/// The range of `v`; from 0 when `from_zero`; never empty (a lone value gets a unit span).
fn bounds(v: impl Iterator<Item = f64>, from_zero: bool) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for x in v.filter(|x| x.is_finite()) {
        lo = lo.min(x);
        hi = hi.max(x);
    }
    if from_zero {
        lo = 0.0;
    }
    if !lo.is_finite() || !hi.is_finite() {
        return (0.0, 1.0);
    }
    if hi <= lo {
        hi = lo + if lo == 0.0 { 1.0 } else { lo.abs() };
    }
    (lo, hi)
}

/// Whole-number x ticks, at most about eight.
fn x_ticks(x0: f64, x1: f64) -> Vec<f64> {
    let step = ((x1 - x0) / 8.0).ceil().max(1.0);
    let mut v = Vec::new();
    let mut x = x0.ceil();
    while x <= x1 + 1e-9 {
        v.push(x);
        x += step;
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every point is inside the plot area, and the highest one at its top.
    #[test]
    fn points_land_inside_the_plot_area() {
        let s = Series {
            name: "rms".into(),
            points: vec![(1.0, 0.02), (2.0, 0.01), (3.0, 0.005)],
        };
        let svg = line_chart("t", "iteration", "error", &[s], true);
        let cys: Vec<f64> = svg
            .split("cy=\"")
            .skip(1)
            .map(|t| t.split('"').next().unwrap().parse().unwrap())
            .collect();
        assert_eq!(cys.len(), 3);
        assert!((cys[0] - M[2]).abs() < 0.1, "{cys:?}");
        assert!(cys.iter().all(|y| *y >= M[2] - 0.1 && *y <= H - M[3]));
        assert!(svg.contains("2.00%") && svg.starts_with("<svg"));
    }

    #[test]
    fn bars_scale_to_the_largest_and_labels_are_escaped() {
        let svg = bar_chart("t", "s", &[("a<b".into(), 2.0), ("c".into(), 1.0)]);
        assert!(svg.contains("a&lt;b") && !svg.contains("a<b"));
        let ws: Vec<f64> = svg
            .split("width=\"")
            .skip(1)
            .map(|t| t.split('"').next().unwrap().parse().unwrap())
            .collect();
        assert!((ws[0] - 2.0 * ws[1]).abs() < 0.2, "{ws:?}");
        assert_eq!(bounds([3.0, 3.0].into_iter(), false), (3.0, 6.0));
        assert_eq!(x_ticks(1.0, 3.0), vec![1.0, 2.0, 3.0]);
    }
}
