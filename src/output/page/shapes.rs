//! The page's shapes: the per-shape table (area, texels, observed share, mean `K_d`, error),
//! then per shape its recovered albedo and every map, each with its colour scale and units.

use super::facts::{MapScale, ShapeFacts};
use super::html::{esc, num, pct, rgb, table};
use crate::report::ShapeTexels;
use std::fmt::Write as _;

/// What a map shows, and in which unit.
pub fn map_meaning(name: &str) -> (&'static str, &'static str) {
    match name {
        "luminance" => (
            "L_orig: the photos projected onto the surface",
            "scene radiance units",
        ),
        "coverage" => (
            "coverage: the views' observation weight (0: no view saw it)",
            "weight",
        ),
        "direct" => (
            "E_d: direct irradiance from the lights",
            "scene irradiance units",
        ),
        "indirect" => (
            "E_i: irradiance by way of other surfaces",
            "scene irradiance units",
        ),
        "colorless" => ("colorless luminance, eq. (10)", "scene radiance units"),
        "kd_stderr" => ("standard error of K_d", "albedo (0-1)"),
        "disagreement" => ("views down-weighted as disagreeing", "views"),
        "error" => ("relative error of the re-rendered luminance", "fraction"),
        _ => ("", ""),
    }
}

/// The per-shape table.
pub fn shape_table(shapes: &[ShapeFacts], atlas: &[ShapeTexels]) -> String {
    let rows: Vec<Vec<String>> = shapes
        .iter()
        .map(|s| {
            let a = atlas.iter().find(|a| a.shape == s.shape);
            vec![
                format!("<a href=\"#shape-{0}\">{0}</a>", esc(&s.shape)),
                num(s.area),
                a.map_or("-".into(), |a| format!("{} x {}", a.width, a.height)),
                a.map_or("-".into(), |a| num(a.texels_per_unit as f64)),
                s.covered.to_string(),
                pct(s.observed as f64 / s.covered.max(1) as f64, 1),
                s.mean_kd.map_or("-".into(), rgb),
                s.mean_error.map_or("-".into(), |e| pct(e, 2)),
            ]
        })
        .collect();
    table(
        &[
            "shape",
            "area (units²)",
            "texture",
            "texels per unit",
            "surface texels",
            "observed",
            "mean K_d (observed)",
            "mean rel. error",
        ],
        &rows,
    )
}

/// Per shape, its albedo and maps as a gallery.
pub fn galleries(shapes: &[ShapeFacts], exists: &dyn Fn(&str) -> bool) -> String {
    let mut s = String::new();
    for sh in shapes {
        let id = esc(&sh.shape);
        let _ = write!(s, "<h3 id=\"shape-{id}\">{id}</h3><div class=\"gallery\">");
        let albedo = format!("textures/{}_albedo.png", sh.shape);
        if exists(&albedo) {
            s += &tile(
                &albedo,
                "K_d: the recovered albedo (sRGB)",
                &grey_scale(1.0, "albedo"),
            );
        }
        for m in &sh.maps {
            let file = format!("maps/{}_{}.png", sh.shape, m.name);
            if exists(&file) {
                s += &map_tile(&file, m);
            }
        }
        s.push_str("</div>");
    }
    s
}

/// One map's tile: its image, meaning and colour scale.
fn map_tile(file: &str, m: &MapScale) -> String {
    let (what, unit) = map_meaning(&m.name);
    let scale = match m.name.as_str() {
        "error" => {
            "<span class=\"scale\">colour scale in the image; grey: not observed</span>".to_string()
        }
        _ => grey_scale(m.white, unit),
    };
    tile(file, if what.is_empty() { &m.name } else { what }, &scale)
}

/// An image in the gallery, linking to itself at full size.
fn tile(file: &str, caption: &str, scale: &str) -> String {
    let f = esc(file);
    format!(
        "<figure class=\"map\"><a href=\"{f}\"><img src=\"{f}\" loading=\"lazy\" decoding=\"async\" alt=\"{c}\"></a><figcaption>{c}<br>{scale}</figcaption></figure>",
        c = esc(caption)
    )
}

/// The preview's scale: black is 0, white is `white` (per channel, sRGB-encoded between).
fn grey_scale(white: f32, unit: &str) -> String {
    format!(
        "<span class=\"scale\"><span class=\"ramp\"></span> 0 to {} {} (per channel; brighter clips)</span>",
        num(white as f64),
        esc(unit)
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A map whose PNG is missing gets no tile; the albedo's scale is 0 to 1.
    #[test]
    fn galleries_show_what_exists_with_scales() {
        let sh = ShapeFacts {
            shape: "floor".into(),
            maps: vec![
                MapScale {
                    name: "direct".into(),
                    white: 2.5,
                },
                MapScale {
                    name: "indirect".into(),
                    white: 1.0,
                },
            ],
            ..Default::default()
        };
        let g = galleries(&[sh], &|f: &str| f != "maps/floor_indirect.png");
        assert!(
            g.contains("textures/floor_albedo.png") && g.contains("0 to 1 albedo"),
            "{g}"
        );
        assert!(
            g.contains("maps/floor_direct.png") && g.contains("0 to 2.5 scene irradiance"),
            "{g}"
        );
        assert!(!g.contains("floor_indirect"));
    }
}
