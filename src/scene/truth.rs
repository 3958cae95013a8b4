//! Ground-truth albedo for measuring accuracy (tests, benchmarks, the nightly harness): the
//! diffuse `reflectance` each shape's BSDF states in a Mitsuba `truth.xml`, read by the same
//! XML reader as every scene (so `<ref>`-named BSDFs and textures resolve), either a constant
//! RGB or an sRGB-encoded bitmap on the mesh's own UVs. Never an input of a reconstruction;
//! scoring a run against it is `crate::accuracy`.

use super::{mitsuba, Mesh, ReflectanceSpec, Rgb};
use crate::base::error::{Error, Result};
use glam::{Vec2, Vec3};
use std::collections::HashMap;
use std::path::Path;

/// One shape's true reflectance.
#[derive(Debug, Clone)]
pub enum Reflectance {
    Constant(Rgb),
    /// Linear RGB texels (decoded from sRGB), row 0 = top, looked up at the mesh UVs.
    Bitmap {
        width: u32,
        height: u32,
        texels: Vec<Vec3>,
    },
}

/// The true reflectance of every shape id that states one, with the meshes it was painted on.
#[derive(Debug, Clone, Default)]
pub struct Truth {
    pub shapes: HashMap<String, Reflectance>,
}

fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

fn load_bitmap(path: &Path) -> Result<Reflectance> {
    let pm = tiny_skia::Pixmap::load_png(path)
        .map_err(|e| Error::input(path, format!("cannot read PNG: {e}")))?;
    let texels = pm
        .pixels()
        .iter()
        .map(|p| {
            let c = p.demultiply();
            Vec3::new(
                srgb_to_linear(c.red() as f32 / 255.0),
                srgb_to_linear(c.green() as f32 / 255.0),
                srgb_to_linear(c.blue() as f32 / 255.0),
            )
        })
        .collect();
    Ok(Reflectance::Bitmap {
        width: pm.width(),
        height: pm.height(),
        texels,
    })
}

impl Truth {
    /// Read the diffuse reflectance of every shape of a Mitsuba truth file.
    pub fn load(path: &Path) -> Result<Truth> {
        let scene = mitsuba::load(path)?;
        let mut shapes = HashMap::new();
        for s in &scene.shapes {
            let r = match &s.reflectance {
                Some(ReflectanceSpec::Constant(c)) => Reflectance::Constant(*c),
                Some(ReflectanceSpec::Bitmap(f)) => load_bitmap(f)?,
                None => continue,
            };
            shapes.insert(s.id.clone(), r);
        }
        Ok(Truth { shapes })
    }
}

impl Reflectance {
    /// The true albedo at barycentrics `(b1, b2)` of triangle `tri` of `mesh` (whose UVs,
    /// v up, are the ones the truth texture was painted on). Bilinear, repeating, like
    /// Mitsuba's bitmap texture.
    pub fn eval(&self, mesh: &Mesh, tri: usize, b1: f32, b2: f32) -> Rgb {
        match self {
            Reflectance::Constant(c) => *c,
            Reflectance::Bitmap {
                width,
                height,
                texels,
            } => {
                let Some(uvs) = &mesh.uvs else {
                    return Vec3::ZERO;
                };
                let [a, b, c] = mesh.triangles[tri];
                let uv: Vec2 =
                    uvs[a as usize] * (1.0 - b1 - b2) + uvs[b as usize] * b1 + uvs[c as usize] * b2;
                let (w, h) = (*width as i64, *height as i64);
                let fx = uv.x * w as f32 - 0.5;
                let fy = (1.0 - uv.y) * h as f32 - 0.5;
                let (x0, y0) = (fx.floor() as i64, fy.floor() as i64);
                let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
                let g = |x: i64, y: i64| texels[(y.rem_euclid(h) * w + x.rem_euclid(w)) as usize];
                let top = g(x0, y0) * (1.0 - tx) + g(x0 + 1, y0) * tx;
                let bot = g(x0, y0 + 1) * (1.0 - tx) + g(x0 + 1, y0 + 1) * tx;
                top * (1.0 - ty) + bot * ty
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_decode_endpoints() {
        assert_eq!(srgb_to_linear(0.0), 0.0);
        assert!((srgb_to_linear(1.0) - 1.0).abs() < 1e-6);
        assert!((srgb_to_linear(0.5) - 0.21404).abs() < 1e-4);
    }

    #[test]
    fn reads_constants_and_bitmaps_of_the_fixture() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures");
        let t = Truth::load(&root.join("cbox/truth.xml")).unwrap();
        match &t.shapes["left"] {
            Reflectance::Constant(c) => assert_eq!(*c, Vec3::new(0.63, 0.065, 0.05)),
            other => panic!("{other:?}"),
        }
        let t = Truth::load(&root.join("cbox-tex/truth.xml")).unwrap();
        match &t.shapes["right"] {
            Reflectance::Bitmap { width, height, .. } => assert_eq!((*width, *height), (256, 171)),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn named_bsdfs_and_textures_resolve_through_refs() {
        let dir = tempfile::tempdir().unwrap();
        let mut pm = tiny_skia::Pixmap::new(2, 1).unwrap();
        pm.fill(tiny_skia::Color::from_rgba8(255, 255, 255, 255));
        pm.save_png(dir.path().join("t.png")).unwrap();
        let xml = r#"<scene version="3.0.0">
            <bsdf type="twosided" id="white"><bsdf type="diffuse">
                <rgb name="reflectance" value="0.2, 0.4, 0.6"/></bsdf></bsdf>
            <texture type="bitmap" id="tex"><string name="filename" value="t.png"/></texture>
            <bsdf type="diffuse" id="textured"><ref name="reflectance" id="tex"/></bsdf>
            <shape type="rectangle" id="a"><ref id="white"/></shape>
            <shape type="rectangle" id="b"><ref name="bsdf" id="textured"/></shape>
            <shape type="rectangle" id="c"/>
        </scene>"#;
        let p = dir.path().join("truth.xml");
        std::fs::write(&p, xml).unwrap();
        let t = Truth::load(&p).unwrap();
        assert!(matches!(t.shapes["a"], Reflectance::Constant(c) if c == Vec3::new(0.2, 0.4, 0.6)));
        assert!(matches!(
            t.shapes["b"],
            Reflectance::Bitmap { width: 2, .. }
        ));
        assert!(!t.shapes.contains_key("c"));
    }
}
