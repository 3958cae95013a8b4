//! Ground-truth albedo for measuring accuracy (tests, benchmarks, the nightly harness): the
//! diffuse `reflectance` each shape's BSDF states in a Mitsuba `truth.xml`, read by the same
//! XML reader as every scene (so `<ref>`-named BSDFs and textures resolve), either a constant
//! RGB or a bitmap on the mesh's own UVs (PNG and JPEG sRGB-encoded, OpenEXR and Radiance HDR
//! linear, as Mitsuba 3 reads them). Never an input of a reconstruction;
//! scoring a run against it is `crate::accuracy`.

use super::{envmap, mitsuba, Mesh, ReflectanceSpec, Rgb};
use crate::base::error::{Error, Result};
use glam::{Vec2, Vec3};
use std::collections::HashMap;
use std::path::Path;

/// One shape's true reflectance.
#[derive(Debug, Clone)]
pub enum Reflectance {
    Constant(Rgb),
    /// Linear RGB texels (PNG and JPEG codes decoded from sRGB), row 0 = top, looked up at the
    /// mesh UVs.
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

/// A truth texture as linear RGB, by Mitsuba 3's convention for a `bitmap` texture (`raw`
/// false): 8- and 16-bit PNG and JPEG codes are sRGB-encoded, OpenEXR and Radiance HDR
/// values are linear as stored.
fn load_bitmap(path: &Path) -> Result<Reflectance> {
    let ext = (path.extension().and_then(|e| e.to_str())).map(|e| e.to_ascii_lowercase());
    let (width, height, texels) = match ext.as_deref() {
        Some("png") => decode_png(path)?,
        Some("jpg" | "jpeg") => decode_jpeg(path)?,
        Some("exr") => envmap::read_exr(path).map_err(|e| bad(path, "OpenEXR", e))?,
        Some("hdr") => envmap::read_hdr(path).map_err(|e| bad(path, "Radiance HDR", e))?,
        _ => {
            let msg = "a truth texture must be .png, .jpg, .jpeg, .exr or .hdr";
            return Err(Error::input(path, msg));
        }
    };
    if let Some(i) = texels.iter().position(|t| !t.is_finite()) {
        let (x, y) = (i as u32 % width.max(1), i as u32 / width.max(1));
        return Err(Error::input(
            path,
            format!("texel ({x}, {y}) is not finite"),
        ));
    }
    Ok(Reflectance::Bitmap {
        width,
        height,
        texels,
    })
}

fn bad(path: &Path, format: &str, e: String) -> Error {
    Error::input(
        path,
        format!("cannot read {format}: {}", e.replace('\n', " ")),
    )
}

/// A PNG's RGB codes (alpha dropped; 16-bit kept) decoded from sRGB.
fn decode_png(path: &Path) -> Result<(u32, u32, Vec<Vec3>)> {
    let read = || -> std::result::Result<_, ::image::ImageError> {
        let f = std::io::BufReader::new(std::fs::File::open(path)?);
        ::image::ImageReader::with_format(f, ::image::ImageFormat::Png).decode()
    };
    let img = read().map_err(|e| bad(path, "PNG", e.to_string()))?;
    let (w, h) = (img.width(), img.height());
    let texels = match img.color().bytes_per_pixel() > 4 {
        true => srgb_texels(&img.into_rgb16().into_raw(), 65535.0),
        false => srgb_texels(&img.into_rgb8().into_raw(), 255.0),
    };
    Ok((w, h, texels))
}

/// A JPEG's codes decoded from sRGB, in strict mode: a truncated or corrupt file is an error
/// (a lenient decoder fills what it cannot decode with grey).
fn decode_jpeg(path: &Path) -> Result<(u32, u32, Vec<Vec3>)> {
    use zune_jpeg::zune_core::{bytestream::ZCursor, colorspace::ColorSpace, options};
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let opts = options::DecoderOptions::default()
        .set_strict_mode(true)
        .jpeg_set_out_colorspace(ColorSpace::RGB);
    let mut dec = zune_jpeg::JpegDecoder::new_with_options(ZCursor::new(&bytes[..]), opts);
    let rgb = dec.decode().map_err(|e| bad(path, "JPEG", e.to_string()))?;
    let (w, h) = dec.dimensions().unwrap_or((0, 0));
    if dec.output_colorspace() != Some(ColorSpace::RGB) || rgb.len() != w * h * 3 || w == 0 {
        return Err(bad(path, "JPEG", "not decodable as RGB".into()));
    }
    Ok((w as u32, h as u32, srgb_texels(&rgb, 255.0)))
}

/// Interleaved RGB codes with `top` as white, decoded from sRGB.
fn srgb_texels<T: Copy + Into<f64>>(codes: &[T], top: f64) -> Vec<Vec3> {
    let lin = |c: T| srgb_to_linear((c.into() / top) as f32);
    let px = codes.chunks_exact(3);
    px.map(|c| Vec3::new(lin(c[0]), lin(c[1]), lin(c[2])))
        .collect()
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

    /// A texture of every code pair, saved as PNG, JPEG (quality 100), EXR and HDR (the
    /// PNG's linear values): every format reads back as the PNG does, within the JPEG's
    /// compression and RGBE's 8-bit mantissa (relative to a texel's brightest channel).
    #[test]
    fn jpeg_exr_and_hdr_textures_read_as_the_png_does() {
        let dir = tempfile::tempdir().unwrap();
        let (w, h) = (64u32, 48u32);
        let code = |x: u32, y: u32| [(x * 4) as u8, (y * 5) as u8, ((x + y) * 2) as u8];
        let png = ::image::RgbImage::from_fn(w, h, |x, y| ::image::Rgb(code(x, y)));
        png.save(dir.path().join("t.png")).unwrap();
        let jpg = std::fs::File::create(dir.path().join("t.jpg")).unwrap();
        let mut enc = ::image::codecs::jpeg::JpegEncoder::new_with_quality(jpg, 100);
        enc.encode_image(&png).unwrap();
        let lin = |x: u32, y: u32| {
            let c = code(x, y).map(|c| srgb_to_linear(c as f32 / 255.0));
            (c[0], c[1], c[2])
        };
        exr::prelude::write_rgb_file(dir.path().join("t.exr"), w as usize, h as usize, |x, y| {
            lin(x as u32, y as u32)
        })
        .unwrap();
        let hdr: Vec<::image::Rgb<f32>> = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| ::image::Rgb(<[f32; 3]>::from(lin(x, y))))
            .collect();
        let f = std::fs::File::create(dir.path().join("t.hdr")).unwrap();
        (::image::codecs::hdr::HdrEncoder::new(f).encode(&hdr, w as usize, h as usize)).unwrap();
        let texels = |name: &str| match load_bitmap(&dir.path().join(name)).unwrap() {
            Reflectance::Bitmap {
                width,
                height,
                texels,
            } => {
                assert_eq!((width, height), (w, h), "{name}");
                texels
            }
            other => panic!("{other:?}"),
        };
        let reference = texels("t.png");
        assert_eq!(reference[0], Vec3::ZERO);
        assert!((reference[(w + 1) as usize].x - srgb_to_linear(4.0 / 255.0)).abs() < 1e-7);
        assert_eq!(texels("t.exr"), reference, "EXR is linear, as stored");
        let worst = |name: &str, rel: bool| {
            let t = texels(name);
            let d = |(a, b): (&Vec3, &Vec3)| match rel {
                // RGBE shares one exponent: precision relative to the brightest channel
                true => (*a - *b).abs().max_element() / b.max_element().max(1e-3),
                false => (*a - *b).abs().max_element(),
            };
            t.iter().zip(&reference).map(d).fold(0.0f32, f32::max)
        };
        let hdr_err = worst("t.hdr", true);
        assert!(hdr_err < 1.0 / 64.0, "HDR off by {hdr_err} (relative)");
        // JPEG at quality 100: a few codes at most, not the sRGB curve's factor of ~5 at mid
        // grey that reading it as linear would give
        let jpg_err = worst("t.jpg", false);
        eprintln!("largest difference from the PNG: JPEG {jpg_err:.4}, HDR {hdr_err:.4} relative");
        assert!(jpg_err < 0.03, "JPEG off by {jpg_err}");
    }

    #[test]
    fn an_unknown_or_broken_texture_is_one_line_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        for (name, bytes) in [
            ("t.tga", &b"x"[..]),
            ("t.jpg", b"\xff\xd8\xff junk"),
            ("t.exr", b"junk"),
        ] {
            let p = dir.path().join(name);
            std::fs::write(&p, bytes).unwrap();
            let e = load_bitmap(&p).unwrap_err().to_string();
            assert!(
                e.starts_with(&p.display().to_string()) && !e.contains('\n'),
                "{e}"
            );
        }
    }
}
