//! 8-bit photos (PNG, JPEG; 16-bit PNGs too) as linear images: decoded by pure-Rust decoders
//! (PNG by `image`, JPEG by `zune-jpeg` in strict mode), every code taken through the run's
//! response curve, and the pixels whose codes say nothing reliable masked: clipped ones (and,
//! in a JPEG, their neighbours) and near-black ones. The values are linear in [0, 1]: an 8-bit
//! photo has no absolute scale.

use super::Image;
use crate::base::error::{Error, Result};
use crate::config::Response;
use crate::scene::photos::is_jpeg;
use ::image::ImageFormat;
use glam::Vec3;
use std::path::Path;

/// A pixel whose every channel is at or below this code (of 255) is masked as near-black. At
/// code 2 the sRGB curve gives 6.1e-4 and one code step is 3.0e-4, so rounding alone is +-25%
/// of the value, and a sensor's noise, its black-level offset and JPEG's DCT rounding (1-2
/// codes) are as large: the value is nearly all noise. Code 3 would still be +-17%; a higher
/// threshold would start to hide real dark surfaces. A pixel with one brighter channel is
/// kept: its bright channels are good, and the dark ones' absolute error is small.
pub const DARK_CODE: u32 = 2;

/// How far (pixels, in x and y) the mask of a JPEG's clipped pixel reaches: JPEG usually
/// halves chroma resolution (a pixel's colour is shared with its neighbour) and its DCT
/// quantisation rings at the sharp edge of a clipped area, so the pixels next to a clipped
/// one are wrong too, though not at the top code. PNG is lossless: no ring.
pub const JPEG_RING: u32 = 1;

/// A decoded photo's samples, RGB interleaved, and the top code of their depth.
enum Samples {
    Eight(Vec<u8>),
    Sixteen(Vec<u16>),
}

/// Read a PNG or JPEG photo (by its extension) as linear RGB: codes through `response`,
/// clipped pixels (any channel at the top code; for a JPEG, also the pixels within
/// [`JPEG_RING`] of one) and near-black ones (every channel at or below [`DARK_CODE`] of 255)
/// masked and counted. Grey images are read as RGB, alpha is ignored. A 16-bit PNG goes
/// through the same curve on code / 65535, with the thresholds scaled to its range.
pub fn read_ldr(path: &Path, response: &Response) -> Result<Image> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    read_ldr_bytes(&bytes, path, response)
}

/// [`read_ldr`] on the bytes of a file already read; `path` names the file in errors and its
/// extension tells the format.
pub fn read_ldr_bytes(bytes: &[u8], path: &Path, response: &Response) -> Result<Image> {
    let jpeg = is_jpeg(path);
    let (width, height, samples) = decode(bytes, path, jpeg)?;
    let ring = if jpeg { JPEG_RING } else { 0 };
    Ok(match samples {
        Samples::Eight(s) => linearize(width, height, &s, 255, response, ring),
        Samples::Sixteen(s) => linearize(width, height, &s, 65535, response, ring),
    })
}

fn decode(bytes: &[u8], path: &Path, jpeg: bool) -> Result<(u32, u32, Samples)> {
    if jpeg {
        return decode_jpeg(bytes, path);
    }
    let bad = |e: ::image::ImageError| {
        let msg = e.to_string().replace('\n', " ");
        Error::input(path, format!("not a readable PNG file: {msg}"))
    };
    let reader = ::image::ImageReader::with_format(std::io::Cursor::new(bytes), ImageFormat::Png);
    let img = reader.decode().map_err(bad)?;
    let (w, h) = (img.width(), img.height());
    let samples = match img.color().bytes_per_pixel() > 4 {
        true => Samples::Sixteen(img.into_rgb16().into_raw()),
        false => Samples::Eight(img.into_rgb8().into_raw()),
    };
    Ok((w, h, samples))
}

/// A JPEG decoded in strict mode, as RGB: a truncated or corrupt file is an error, where the
/// lenient mode (image's) fills what it cannot decode with grey.
fn decode_jpeg(bytes: &[u8], path: &Path) -> Result<(u32, u32, Samples)> {
    use zune_jpeg::zune_core::{bytestream::ZCursor, colorspace::ColorSpace};
    let options = zune_jpeg::zune_core::options::DecoderOptions::default()
        .set_strict_mode(true)
        .jpeg_set_out_colorspace(ColorSpace::RGB);
    let mut dec = zune_jpeg::JpegDecoder::new_with_options(ZCursor::new(bytes), options);
    let bad = |e: String| {
        let msg = e.replace('\n', " ");
        Error::input(path, format!("not a readable JPEG file: {msg}"))
    };
    let rgb = dec.decode().map_err(|e| bad(e.to_string()))?;
    let (w, h) = dec.dimensions().ok_or_else(|| bad("no frame".into()))?;
    if dec.output_colorspace() != Some(ColorSpace::RGB) || rgb.len() != w * h * 3 {
        return Err(bad("not decodable as RGB".into()));
    }
    Ok((w as u32, h as u32, Samples::Eight(rgb)))
}

/// The linear value of every code `0..=top` under `response` (the sRGB curve exactly as
/// IEC 61966-2-1 states it; a table of 256 values interpolated linearly for deeper codes).
pub fn response_lut(response: &Response, top: u32) -> Vec<f32> {
    (0..=top)
        .map(|c| {
            let v = c as f64 / top as f64;
            let y = match response {
                Response::Srgb if v <= 0.04045 => v / 12.92,
                Response::Srgb => ((v + 0.055) / 1.055).powf(2.4),
                Response::Linear => v,
                Response::Gamma(g) => v.powf(*g as f64),
                Response::Table(t) => table(t, c as f64 * 255.0 / top as f64),
            };
            y as f32
        })
        .collect()
}

/// `t` (the linear values of codes 0..=255) at code `x` in [0, 255], linearly interpolated.
fn table(t: &[f32], x: f64) -> f64 {
    let i = (x.floor() as usize).min(t.len().saturating_sub(2));
    let f = x - i as f64;
    match t.get(i + 1) {
        Some(&b) => t[i] as f64 * (1.0 - f) + b as f64 * f,
        None => t.first().copied().unwrap_or(0.0) as f64,
    }
}

/// The image of interleaved RGB `samples` whose top code is `top`: each code through the
/// response, then the mask of [`unknown`] applied (masked pixels hold zero).
fn linearize<T: Copy + Into<u32>>(
    width: u32,
    height: u32,
    samples: &[T],
    top: u32,
    response: &Response,
    ring: u32,
) -> Image {
    let lut = response_lut(response, top);
    let code = |i: usize| samples[i].into();
    let n = width as usize * height as usize;
    let dark = DARK_CODE * top / 255;
    let unknown = unknown(
        width,
        height,
        |i| [0, 1, 2].map(|k| code(3 * i + k)),
        top,
        dark,
        ring,
    );
    let mut masked = 0;
    let mut pixels = Vec::with_capacity(n);
    let mut valid = Vec::with_capacity(n);
    for (i, &bad) in unknown.iter().enumerate() {
        let p = Vec3::from_array([0, 1, 2].map(|k| lut[code(3 * i + k) as usize]));
        let ok = !bad && p.is_finite();
        masked += usize::from(!ok);
        pixels.push(if ok { p } else { Vec3::ZERO });
        valid.push(ok);
    }
    Image {
        width,
        height,
        pixels,
        valid,
        masked,
    }
}

/// Per pixel, whether its codes say nothing reliable: any channel at `top` (clipped), or
/// within `ring` pixels (in x and y) of such a pixel, or every channel at or below `dark`.
/// `codes(i)` are pixel `i`'s R, G, B codes, row-major.
pub fn unknown(
    width: u32,
    height: u32,
    codes: impl Fn(usize) -> [u32; 3],
    top: u32,
    dark: u32,
    ring: u32,
) -> Vec<bool> {
    let n = width as usize * height as usize;
    let clipped: Vec<bool> = (0..n).map(|i| codes(i).contains(&top)).collect();
    let mut out: Vec<bool> = (0..n)
        .map(|i| codes(i).iter().all(|&c| c <= dark))
        .collect();
    let (w, h, r) = (width as i64, height as i64, ring as i64);
    for i in (0..n).filter(|&i| clipped[i]) {
        let (x, y) = ((i as i64) % w, (i as i64) / w);
        for yy in (y - r).max(0)..=(y + r).min(h - 1) {
            for xx in (x - r).max(0)..=(x + r).min(w - 1) {
                out[(yy * w + xx) as usize] = true;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests;
