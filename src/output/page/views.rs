//! The page's views: per view, photo and re-render under one wipe slider, the error panel
//! with its colour scale, zoom, and the values under the pointer in the scene's units (read
//! from `report/views/<view>.js`, loaded when the pointer first enters the view). Also
//! writes those value files: half floats, base64, in a classic script so they load from
//! `file://` where a fetch would be refused.

use super::facts::ViewFacts;
use super::html::esc;
use crate::base::fsio;
use crate::output::plot::viridis;
use crate::Result;
use base64::Engine as _;
use glam::Vec3;
use std::fmt::Write as _;
use std::path::Path;

/// Most value samples along a view's longer side; larger photos are subsampled.
const MAX_SAMPLES: u32 = 512;

/// Pixels per value sample along each axis for a `w x h` photo.
pub fn stride_for(w: u32, h: u32) -> u32 {
    w.max(h).div_ceil(MAX_SAMPLES).max(1)
}

/// Write `<dir>/<view>.js`: every `stride`-th pixel's photo RGB, re-render RGB and relative
/// error (NaN where none is shown), as 7 little-endian half floats, base64.
pub fn write_view_data(
    dir: &Path,
    facts: &ViewFacts,
    (photo, render, error): (&[Vec3], &[Vec3], &[Option<f32>]),
) -> Result<()> {
    fsio::create_dir(dir)?;
    let (w, s) = (facts.width as usize, facts.stride as usize);
    let mut bytes = Vec::new();
    for y in (0..facts.height as usize).step_by(s) {
        for x in (0..w).step_by(s) {
            let i = y * w + x;
            let e = error[i].unwrap_or(f32::NAN);
            let vals = photo[i]
                .to_array()
                .into_iter()
                .chain(render[i].to_array())
                .chain([e]);
            for v in vals {
                bytes.extend_from_slice(&half::f16::from_f32(v).to_le_bytes());
            }
        }
    }
    let b64 = base64::engine::general_purpose::STANDARD.encode(&bytes);
    let js = format!(
        "kdmapViewData({},\"{b64}\");\n",
        serde_json::json!(facts.view)
    );
    fsio::write_atomic(&dir.join(format!("{}.js", facts.view)), js.as_bytes())
}

/// The views section: one figure per view.
pub fn views(
    views: &[ViewFacts],
    error_max: Option<f32>,
    render_exists: &dyn Fn(&str) -> bool,
) -> String {
    let mut s = String::from(
        "<p>Drag the slider to wipe between the photo (left of the line) and the re-render from \
         the recovered albedo (right); the zoom buttons enlarge both panels, which then scroll. \
         Under the pointer: the photo's and the re-render's linear RGB in the scene's radiance \
         units (the photo divided by its estimated exposure), and their relative luminance error.</p>",
    );
    if let Some(m) = error_max {
        s += &error_legend(m);
    }
    for v in views.iter().filter(|v| render_exists(&v.view)) {
        s += &figure(v);
    }
    s
}

/// One view's figure.
fn figure(v: &ViewFacts) -> String {
    let id = esc(&v.view);
    let size = format!("width=\"{}\" height=\"{}\"", v.width, v.height);
    format!(
        "<figure class=\"view\" data-view=\"{id}\" data-w=\"{w}\" data-h=\"{h}\" data-stride=\"{st}\">\
         <figcaption>{id} <small>({w} x {h})</small></figcaption>\
         <div class=\"panels\"><div class=\"pane\"><div class=\"stack\">\
         <img class=\"photo\" src=\"report/views/{id}_photo.png\" {size} loading=\"lazy\" alt=\"photo {id}\">\
         <img class=\"render\" src=\"renders/{id}.png\" {size} loading=\"lazy\" alt=\"re-render {id}\">\
         <div class=\"wipe-line\"></div></div></div>\
         <div class=\"pane\"><div class=\"stack\"><img class=\"error\" src=\"report/views/{id}_error.png\" {size} loading=\"lazy\" alt=\"relative error {id}\"></div></div></div>\
         <div class=\"controls\"><label>photo <input type=\"range\" class=\"wipe\" min=\"0\" max=\"100\" value=\"50\" aria-label=\"wipe between photo and re-render\"> re-render</label>\
         <span class=\"zoom\">zoom <button data-zoom=\"1\">1x</button><button data-zoom=\"2\">2x</button><button data-zoom=\"4\">4x</button></span>\
         <a href=\"renders/{id}_compare.png\">comparison image</a> <a href=\"renders/{id}.exr\">re-render EXR</a></div>\
         <output class=\"readout\">point at the images for values</output></figure>\n",
        w = v.width,
        h = v.height,
        st = v.stride
    )
}

/// The error colour scale as a gradient bar from 0 to `max` (a fraction).
pub fn error_legend(max: f32) -> String {
    let mut stops = String::new();
    for i in 0..=10 {
        let [r, g, b] = viridis(i as f32 / 10.0);
        let _ = write!(
            stops,
            "<stop offset=\"{}%\" stop-color=\"rgb({r},{g},{b})\"/>",
            i * 10
        );
    }
    let mut ticks = String::new();
    for i in 0..=5 {
        let x = 10.0 + 300.0 * i as f32 / 5.0;
        let _ = write!(
            ticks,
            "<text x=\"{x:.0}\" y=\"40\" text-anchor=\"middle\">{}%</text>",
            (100.0 * max * i as f32 / 5.0 * 10.0).round() / 10.0
        );
    }
    format!(
        "<figure class=\"legend\"><svg xmlns=\"http://www.w3.org/2000/svg\" viewBox=\"0 0 420 48\" width=\"420\" height=\"48\" role=\"img\" aria-label=\"error colour scale\">\
         <defs><linearGradient id=\"viridis\">{stops}</linearGradient></defs>\
         <rect x=\"10\" y=\"4\" width=\"300\" height=\"18\" fill=\"url(#viridis)\"/>{ticks}\
         <text x=\"318\" y=\"18\">and above</text></svg>\
         <figcaption>Relative luminance error |Y<sub>render</sub> - Y<sub>photo</sub>| / Y<sub>photo</sub>; black: no reconstructed surface or a black photo pixel.</figcaption></figure>"
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The value file holds 7 half floats per sample, in order, and the error's absence as NaN.
    #[test]
    fn value_data_is_seven_halves_per_sample() {
        let tmp = tempfile::tempdir().unwrap();
        let f = ViewFacts {
            view: "cam".into(),
            width: 2,
            height: 1,
            stride: 1,
        };
        let photo = [Vec3::new(0.5, 1.0, 2.0), Vec3::ONE];
        let render = [Vec3::splat(0.25), Vec3::ZERO];
        write_view_data(tmp.path(), &f, (&photo, &render, &[Some(0.125), None])).unwrap();
        let js = std::fs::read_to_string(tmp.path().join("cam.js")).unwrap();
        let b64 = js.split('"').nth(3).unwrap();
        let bytes = base64::engine::general_purpose::STANDARD
            .decode(b64)
            .unwrap();
        let h: Vec<f32> = bytes
            .chunks(2)
            .map(|c| half::f16::from_le_bytes([c[0], c[1]]).to_f32())
            .collect();
        assert_eq!(h.len(), 14);
        assert_eq!(&h[..7], &[0.5, 1.0, 2.0, 0.25, 0.25, 0.25, 0.125]);
        assert!(h[13].is_nan() && h[7] == 1.0);
        assert_eq!(stride_for(512, 300), 1);
        assert_eq!(stride_for(2048, 1024), 4);
    }
}
