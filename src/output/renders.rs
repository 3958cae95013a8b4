//! `renders/<sensor>.exr|png|_compare.png` and the paper's comparison table: every input view
//! re-rendered from the recovered maps, side by side with its photo.
//!
//! A pixel is the mean of `k x k` stratified sub-pixel rays, as Mitsuba's box-filtered film
//! is ([`render::Film::Box`](crate::physics::render::Film::Box)): a ray that hits a reconstructed shape
//! reads its radiance texture `L_render = K_d / pi (E_d + E_i)` bilinearly; one that hits an
//! emitter shape sees its known area radiance from the front and black from behind (the
//! emitter is not reconstructed); a ray that hits nothing contributes black. Misses count in
//! the mean, so silhouettes against the background come out partly dark, as in the photo.
//! A film with a `tent` or `gaussian` filter then blurs these pixel means by its kernel
//! (`render::apply_pixel_filter`), as it blurred the photo.
//! Pixels that lie wholly on emitters keep the ORIGINAL photo's value, so the light itself
//! never shows up as reconstruction error.
//!
//! The table (`report.table`, the paper's "mean over a region, original vs re-rendered")
//! takes, per view and reconstructed shape, the pixels where the view sees that shape
//! cleanly (`project::View` classification: the whole pixel on one plane of the shape).
//! Those pixels are written as `renders/<sensor>_mask.png` (8-bit grey, `1 + shape index`,
//! 0 for pixels outside the table) with `renders/masks.json` = `{"shapes": [id, ...]}` in the
//! scene's shape order, so the table can be recomputed from the EXRs by other tools.

use super::page::{views as page_views, ViewFacts};
use super::plot::{draw_legend, legend_height, Canvas, ErrorScale, LegendStyle};
use crate::atlas::context::HitTable;
use crate::atlas::RunContext;
use crate::base::fsio;
use crate::image::{
    auto_exposure, read_photo, write_exr_rgb, write_pixmap_png, write_png_srgb, Image,
};
use crate::physics::camera::Camera;
use crate::physics::render::{apply_pixel_filter, render_view_with, Film, Plan, Texture};
use crate::report::ViewShapeRow;
use crate::scene::{luminance, Scene, Sensor};
use crate::stages::project::{exposure, keep, PixelInfo, View};
use crate::{Error, Result};
use glam::Vec3;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::Path;
use tiny_skia::Pixmap;

/// Sub-pixel rays per pixel side.
pub const SUPERSAMPLE: u32 = 4;

/// Re-render one view (see the module doc): `textures[shape]` is the radiance texture of each
/// reconstructed shape; `view.image` (the photo) supplies the pixels that lie wholly on
/// emitters. Pixels lying flat on one chart reuse the view's corner rays; the others are
/// traced.
pub fn render_recovered(
    p: &RunContext,
    hits: &HitTable,
    view: &View,
    textures: &[Option<Texture>],
    k: u32,
) -> Vec<Vec3> {
    let film = Film::Box {
        scene: &p.scene,
        photo: view.image,
    };
    let plan = |x, y| view.flat(hits, x, y).map_or(Plan::Trace, Plan::Flat);
    let cam = &view.camera;
    let render = render_view_with(&p.accel, cam, textures, k, film, &plan);
    apply_pixel_filter(&render, cam.width(), cam.height(), cam.filter())
        .into_iter()
        .map(|v| v.unwrap_or(Vec3::ZERO))
        .collect()
}

/// CIE 1931 xy chromaticity of a linear sRGB (D65) colour. Black has none; it gets the D65
/// white point (0.3127, 0.3290), the chromaticity of every grey.
pub fn xy_chromaticity(rgb: [f64; 3]) -> [f64; 2] {
    let [r, g, b] = rgb;
    let x = 0.4124 * r + 0.3576 * g + 0.1805 * b;
    let y = 0.2126 * r + 0.7152 * g + 0.0722 * b;
    let z = 0.0193 * r + 0.1192 * g + 0.9505 * b;
    let s = x + y + z;
    if s.abs() <= 1e-300 || !s.is_finite() {
        return [0.3127, 0.3290];
    }
    [x / s, y / s]
}

/// Mean and population standard deviation of luminance, and mean RGB, of `px`.
fn stats(px: &[Vec3]) -> (f64, f64, [f64; 3]) {
    let n = px.len().max(1) as f64;
    let mut rgb = [0.0f64; 3];
    let mut y = 0.0f64;
    for v in px {
        for k in 0..3 {
            rgb[k] += v[k] as f64;
        }
        y += luminance(*v) as f64;
    }
    let rgb = rgb.map(|c| c / n);
    let my = y / n;
    let var = px
        .iter()
        .map(|v| (luminance(*v) as f64 - my).powi(2))
        .sum::<f64>()
        / n;
    (my, var.sqrt(), rgb)
}

/// The table rows of one view: per reconstructed shape with at least one clean pixel,
/// original (`photo`) vs re-rendered (`render`) statistics over those pixels.
pub fn table_rows(
    view: &str,
    scene: &Scene,
    pixels: &[PixelInfo],
    photo: &[Vec3],
    render: &[Vec3],
) -> Vec<ViewShapeRow> {
    // each shape's pixels, in one pass over the view (not one per shape)
    let mut by_shape: Vec<Vec<usize>> = vec![Vec::new(); scene.shapes.len()];
    for (i, px) in pixels.iter().enumerate() {
        if in_table(scene, px) {
            by_shape[px.shape as usize].push(i);
        }
    }
    let mut rows = Vec::new();
    for (shape, idx) in scene.shapes.iter().zip(&by_shape) {
        if !shape.is_reconstructed() || idx.is_empty() {
            continue;
        }
        let a: Vec<Vec3> = idx.iter().map(|&i| photo[i]).collect();
        let b: Vec<Vec3> = idx.iter().map(|&i| render[i]).collect();
        let (ya, sa, ra) = stats(&a);
        let (yb, sb, rb) = stats(&b);
        rows.push(ViewShapeRow {
            view: view.to_string(),
            shape: shape.id.clone(),
            pixels: idx.len() as u64,
            mean_luminance: [ya, yb],
            std_luminance: [sa, sb],
            mean_rgb: [ra, rb],
            xy: [xy_chromaticity(ra), xy_chromaticity(rb)],
        });
    }
    rows
}

/// Whether pixel `px` counts in the table row of its shape (see [`table_rows`]).
fn in_table(scene: &Scene, px: &PixelInfo) -> bool {
    px.clean
        && scene
            .shapes
            .get(px.shape as usize)
            .is_some_and(|s| s.is_reconstructed())
}

/// The largest shape count whose indices fit an 8-bit mask (`1 + index <= 255`).
const MASK_MAX_SHAPES: usize = 255;

/// The pixels [`table_rows`] counts, as an 8-bit grey image: `1 + shape index` (the scene's
/// shape order, named in `masks.json`) where the pixel counts in that shape's row, 0 elsewhere.
/// Lets tools recompute the table from the EXRs independently (`tools/nightly.py`). `None`
/// for scenes with more than [`MASK_MAX_SHAPES`] shapes (no mask is written for them).
fn table_mask(scene: &Scene, pixels: &[PixelInfo], w: u32, h: u32) -> Option<Pixmap> {
    if !has_masks(scene) {
        return None;
    }
    let mut pm = Pixmap::new(w, h)?;
    for (o, px) in pm.data_mut().chunks_exact_mut(4).zip(pixels) {
        let v = if in_table(scene, px) {
            px.shape as u8 + 1
        } else {
            0
        };
        o.copy_from_slice(&[v, v, v, 255]);
    }
    Some(pm)
}

/// Whether the views of `scene` get table masks: at most [`MASK_MAX_SHAPES`] shapes.
fn has_masks(scene: &Scene) -> bool {
    scene.shapes.len() <= MASK_MAX_SHAPES
}

/// `masks.json`: `{"shapes": [id, ...]}` in the scene's shape order, so mask value `v > 0`
/// names shape `shapes[v - 1]`. The same for every view: written once, after the views (which
/// are written side by side), when they have masks ([`table_mask`]).
pub fn write_masks_json(dir: &Path, scene: &Scene) -> Result<()> {
    if !has_masks(scene) {
        return Ok(());
    }
    let ids: Vec<&str> = scene.shapes.iter().map(|s| s.id.as_str()).collect();
    let json = serde_json::json!({ "shapes": ids });
    let path = dir.join("masks.json");
    let text = serde_json::to_string_pretty(&json)
        .map_err(|e| Error::internal(format!("cannot serialize masks.json: {e}")))?;
    fsio::write_atomic(&path, text.as_bytes())
}

/// Re-render view `(sensor, photo path, gain)` (the sensor at the pose the run used), write
/// its EXR, PNG and comparison PNG into `dir` and the report page's photo, error panel and
/// values into `page_dir`, and return its table rows and page figures; the photo is divided by
/// its gain (exposure and white balance) as the projection divided it. The view's rays are
/// the ones the projection kept as view `index` in `kept` if it did ([`keep`]), else traced.
pub fn write_view(
    p: &RunContext,
    hits: &HitTable,
    textures: &[Option<Texture>],
    (sensor, photo_path, gain): (&Sensor, &Path, [f32; 3]),
    (dir, page_dir, (kept, index)): (&Path, &Path, (&Path, usize)),
    scale: &ErrorScale,
) -> Result<(Vec<ViewShapeRow>, ViewFacts)> {
    fsio::create_dir(dir)?;
    let photo = exposure::apply(&read_photo(photo_path, sensor, &p.response)?, gain);
    let camera = Camera::from_sensor(sensor);
    let view = keep::take(kept, index, &camera, &photo)
        .unwrap_or_else(|| View::new(&p.scene, &p.accel, camera, &photo));
    let render = render_recovered(p, hits, &view, textures, SUPERSAMPLE);
    let (w, h) = (sensor.width, sensor.height);
    let exposure = auto_exposure(&photo.pixels, &photo.valid);
    write_exr_rgb(dir.join(format!("{}.exr", sensor.id)), w, h, &render, false)?;
    write_png_srgb(
        dir.join(format!("{}.png", sensor.id)),
        w,
        h,
        &render,
        exposure,
    )?;
    let cmp = compare_image(p, &view, (&photo, &render), exposure, scale)?;
    cmp.write_png(&dir.join(format!("{}_compare.png", sensor.id)))?;
    if let Some(mask) = table_mask(&p.scene, &view.pixels, w, h) {
        write_pixmap_png(&dir.join(format!("{}_mask.png", sensor.id)), &mask)?;
    }
    let facts = page_files(
        p,
        (&view, &sensor.id),
        (&photo, &render),
        exposure,
        scale,
        page_dir,
    )?;
    let rows = table_rows(&sensor.id, &p.scene, &view.pixels, &photo.pixels, &render);
    Ok((rows, facts))
}

/// The report page's files of a view: the photo at the re-render's exposure, the error panel
/// and the values under the pointer (`page::views`).
fn page_files(
    p: &RunContext,
    (view, id): (&View, &str),
    (photo, render): (&Image, &[Vec3]),
    exposure: f32,
    scale: &ErrorScale,
    page_dir: &Path,
) -> Result<ViewFacts> {
    let (w, h) = (photo.width, photo.height);
    fsio::create_dir(page_dir)?;
    write_png_srgb(
        page_dir.join(format!("{id}_photo.png")),
        w,
        h,
        &photo.pixels,
        exposure,
    )?;
    let errors: Vec<Option<f32>> = (0..(w * h) as usize)
        .map(|i| error_value(p, view, photo, render, i))
        .collect();
    let mut pm = Pixmap::new(w, h).ok_or_else(|| Error::internal("an empty view"))?;
    for (o, e) in pm.data_mut().chunks_exact_mut(4).zip(&errors) {
        let [r, g, b] = e.map_or([0, 0, 0], |e| scale.color(e));
        o.copy_from_slice(&[r, g, b, 255]);
    }
    write_pixmap_png(&page_dir.join(format!("{id}_error.png")), &pm)?;
    let facts = ViewFacts {
        view: id.to_string(),
        width: w,
        height: h,
        stride: page_views::stride_for(w, h),
    };
    page_views::write_view_data(page_dir, &facts, (&photo.pixels, render, &errors))?;
    Ok(facts)
}

fn srgb8(v: f32) -> u8 {
    let v = if v.is_finite() {
        v.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let e = if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    };
    (e * 255.0 + 0.5) as u8
}

/// Background of the comparison image around its panels.
const COMPARE_BG: [u8; 3] = [32, 32, 32];
/// Pixels between the comparison image's panels.
const GAP: u32 = 4;
/// The comparison image's panel titles, left to right.
pub const PANEL_TITLES: [&str; 3] = ["Original", "Render", "Relative error"];

/// original | render | relative error `|Y_render - Y_photo| / Y_photo`, titled, with the
/// error legend under the third panel. The first two share `exposure`; error is shown where
/// the pixel's center lies on a reconstructed shape and the photo is not black.
fn compare_image(
    p: &RunContext,
    view: &View,
    (photo, render): (&Image, &[Vec3]),
    exposure: f32,
    scale: &ErrorScale,
) -> Result<Canvas> {
    let (w, h) = (photo.width, photo.height);
    let style = LegendStyle::light_on(COMPARE_BG, w);
    let title_h = style.text_px() * 3 / 2 + 6;
    let lh = legend_height(&style);
    let mut c = Canvas::new(3 * w + 2 * GAP, title_h + h + lh, COMPARE_BG);
    let gain = exposure.exp2();
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let err = error_color(p, view, photo, render, scale, i);
            let panels =
                [photo.pixels[i] * gain, render[i] * gain].map(|v| v.to_array().map(srgb8));
            for (k, col) in [panels[0], panels[1], err].into_iter().enumerate() {
                c.put(k as u32 * (w + GAP) + x, title_h + y, col);
            }
        }
    }
    c.draw("a comparison image", |root| {
        let font = style.font().pos(Pos::new(HPos::Center, VPos::Top));
        for (k, title) in PANEL_TITLES.iter().enumerate() {
            let x = k as u32 * (w + GAP) + w / 2;
            root.draw_text(title, &font, (x as i32, 4))?;
        }
        let area = root.clone().shrink((2 * (w + GAP), title_h + h), (w, lh));
        draw_legend(&area, scale, &style).map(|_| ())
    })?;
    Ok(c)
}

/// The error panel's colour of pixel `i`: black off reconstructed shapes and where the photo
/// is black or invalid.
fn error_color(
    p: &RunContext,
    view: &View,
    photo: &Image,
    render: &[Vec3],
    scale: &ErrorScale,
    i: usize,
) -> [u8; 3] {
    error_value(p, view, photo, render, i).map_or([0, 0, 0], |e| scale.color(e))
}

/// The relative luminance error of pixel `i`, where the error panel shows one: on a
/// reconstructed shape, where the photo is valid and not black.
fn error_value(
    p: &RunContext,
    view: &View,
    photo: &Image,
    render: &[Vec3],
    i: usize,
) -> Option<f32> {
    let s = view.pixels[i].shape;
    let recon = p
        .scene
        .shapes
        .get(s as usize)
        .is_some_and(|sh| sh.is_reconstructed());
    let yo = luminance(photo.pixels[i]);
    if !recon || !photo.valid[i] || yo <= 0.0 {
        return None;
    }
    Some((luminance(render[i]) - yo).abs() / yo)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grey_has_the_d65_white_point_and_primaries_their_own() {
        for g in [1e-4, 0.18, 1.0, 250.0] {
            let [x, y] = xy_chromaticity([g; 3]);
            assert!(
                (x - 0.3127).abs() < 1e-4 && (y - 0.3290).abs() < 1e-4,
                "{x} {y}"
            );
        }
        let [x, y] = xy_chromaticity([1.0, 0.0, 0.0]);
        assert!((x - 0.64).abs() < 1e-3 && (y - 0.33).abs() < 1e-3);
        let [x, y] = xy_chromaticity([0.0, 1.0, 0.0]);
        assert!((x - 0.30).abs() < 1e-3 && (y - 0.60).abs() < 1e-3);
        assert_eq!(xy_chromaticity([0.0; 3]), [0.3127, 0.3290]);
    }

    #[test]
    fn stats_are_population_mean_and_std() {
        let (m, s, rgb) = stats(&[Vec3::splat(1.0), Vec3::splat(3.0)]);
        assert!((m - 2.0).abs() < 1e-6 && (s - 1.0).abs() < 1e-6);
        assert!((rgb[1] - 2.0).abs() < 1e-9);
    }
}
