//! Known materials written back as Mitsuba 3 bsdfs, so the recovered `scene.xml` keeps the
//! mirrors and glass of the input (kdmap's loader reads each form back to the same
//! [`KnownBsdf`]). A `principled` input comes back as the blend kdmap used for it; a coated
//! shape's material as its `plastic` or `roughplastic` over the recovered base, a bitmap.

use crate::scene::{KnownBsdf, Rgb, Rough};
use std::fmt::Write as _;

fn rgb(name: &str, c: Rgb) -> String {
    format!("<rgb name=\"{name}\" value=\"{}, {}, {}\"/>", c.x, c.y, c.z)
}

fn float(name: &str, v: f32) -> String {
    format!("<float name=\"{name}\" value=\"{v}\"/>")
}

fn rough_props(r: &Rough) -> String {
    let dist = if r.ggx { "ggx" } else { "beckmann" };
    format!(
        "<string name=\"distribution\" value=\"{dist}\"/>{}",
        float("alpha", r.alpha)
    )
}

/// `b` as one Mitsuba `<bsdf>` element.
pub fn bsdf_xml(b: &KnownBsdf) -> String {
    let mut w = String::new();
    let _ = match b {
        KnownBsdf::Diffuse(c) => write!(
            w,
            "<bsdf type=\"diffuse\">{}</bsdf>",
            rgb("reflectance", *c)
        ),
        KnownBsdf::Conductor {
            eta,
            k,
            tint,
            rough,
        } => {
            let (kind, r) = match rough {
                Some(r) => ("roughconductor", rough_props(r)),
                None => ("conductor", String::new()),
            };
            write!(
                w,
                "<bsdf type=\"{kind}\">{}{}{}{r}</bsdf>",
                rgb("eta", *eta),
                rgb("k", *k),
                rgb("specular_reflectance", *tint)
            )
        }
        KnownBsdf::Dielectric {
            eta,
            reflect,
            transmit,
            rough,
            thin,
        } => {
            let (kind, r) = match (thin, rough) {
                (true, _) => ("thindielectric", String::new()),
                (false, Some(r)) => ("roughdielectric", rough_props(r)),
                (false, None) => ("dielectric", String::new()),
            };
            write!(
                w,
                "<bsdf type=\"{kind}\">{}{}{}{}{r}</bsdf>",
                float("int_ior", *eta),
                float("ext_ior", 1.0),
                rgb("specular_reflectance", *reflect),
                rgb("specular_transmittance", *transmit)
            )
        }
        KnownBsdf::Plastic {
            eta,
            diffuse,
            specular,
            rough,
            nonlinear,
            ..
        } => {
            let (kind, r) = match rough {
                Some(r) => ("roughplastic", rough_props(r)),
                None => ("plastic", String::new()),
            };
            write!(
                w,
                "<bsdf type=\"{kind}\">{}{}{}{}<boolean name=\"nonlinear\" value=\"{nonlinear}\"/>{r}</bsdf>",
                float("int_ior", *eta),
                float("ext_ior", 1.0),
                rgb("diffuse_reflectance", *diffuse),
                rgb("specular_reflectance", *specular)
            )
        }
        KnownBsdf::Blend { weight, a, b } => write!(
            w,
            "<bsdf type=\"blendbsdf\">{}{}{}</bsdf>",
            float("weight", *weight),
            bsdf_xml(a),
            bsdf_xml(b)
        ),
        KnownBsdf::Mask { opacity, inner } => write!(
            w,
            "<bsdf type=\"mask\">{}{}</bsdf>",
            float("opacity", *opacity),
            bsdf_xml(inner)
        ),
        KnownBsdf::Null => write!(w, "<bsdf type=\"null\"/>"),
    };
    w
}

/// A coated material (see [`KnownBsdf::coat`]) as a `plastic` or `roughplastic` whose
/// `diffuse_reflectance` is the bitmap `texture` (linear values, `raw`).
pub fn coated_xml(b: &KnownBsdf, texture: &str) -> String {
    let Some(KnownBsdf::Plastic {
        eta,
        specular,
        rough,
        ..
    }) = b.coat()
    else {
        return bsdf_xml(b);
    };
    let (kind, r) = match rough {
        Some(r) => ("roughplastic", rough_props(r)),
        None => ("plastic", String::new()),
    };
    format!(
        "<bsdf type=\"{kind}\">{}{}<texture type=\"bitmap\" name=\"diffuse_reflectance\">\
         <string name=\"filename\" value=\"{texture}\"/><boolean name=\"raw\" value=\"true\"/>\
         </texture>{}{r}</bsdf>",
        float("int_ior", *eta),
        float("ext_ior", 1.0),
        rgb("specular_reflectance", *specular)
    )
}
