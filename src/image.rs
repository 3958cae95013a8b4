//! Image input and output: photos in (OpenEXR: float or half, RGB(A), any channel order;
//! PNG and JPEG through a response curve, in `ldr`) with bad pixels masked and counted,
//! OpenEXR results out (written atomically), and sRGB PNG previews. Besides the headers the
//! scene reads for a photo's size (`scene::photos`), nothing else in the crate decodes a photo.
//!
//! Pixels are stored row-major with row 0 at the top, as OpenEXR and Mitsuba's film store them.

use crate::base::error::{Error, Result};
use crate::base::fsio;
use crate::config::Response;
use crate::scene::photos::is_8bit;
use crate::scene::Sensor;
use exr::prelude::{
    self as x, f16, Encoding, FlatSamples, LayerAttributes, ReadChannels, ReadLayers,
    SpecificChannels, WritableImage,
};
use glam::Vec3;
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

mod ldr;
pub use ldr::{read_ldr, read_ldr_bytes, response_lut, DARK_CODE, JPEG_RING};

/// A linear RGB image with a per-pixel validity mask.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    /// Row-major, row 0 = top. Masked pixels hold zero.
    pub pixels: Vec<Vec3>,
    /// `false` where the file held a non-finite or negative value in any of R, G, B, or (an
    /// 8-bit photo) a clipped or near-black pixel.
    pub valid: Vec<bool>,
    /// How many pixels are masked (`valid == false`).
    pub masked: usize,
}

impl Image {
    /// The pixel at column `x`, row `y` (row 0 = top).
    #[inline]
    pub fn get(&self, x: u32, y: u32) -> Vec3 {
        self.pixels[(y * self.width + x) as usize]
    }

    #[inline]
    pub fn is_valid(&self, x: u32, y: u32) -> bool {
        self.valid[(y * self.width + x) as usize]
    }

    /// Build from raw values, masking non-finite or negative pixels (set to zero, counted).
    pub fn from_raw(width: u32, height: u32, mut pixels: Vec<Vec3>) -> Image {
        assert_eq!(pixels.len(), width as usize * height as usize);
        let mut valid = vec![true; pixels.len()];
        let mut masked = 0;
        for (p, v) in pixels.iter_mut().zip(valid.iter_mut()) {
            if !(p.is_finite() && p.min_element() >= 0.0) {
                *p = Vec3::ZERO;
                *v = false;
                masked += 1;
            }
        }
        Image {
            width,
            height,
            pixels,
            valid,
            masked,
        }
    }
}

fn exr_error(path: &Path, e: x::Error) -> Error {
    match e {
        x::Error::Io(io) if io.kind() == std::io::ErrorKind::NotFound => Error::io(path, io),
        x::Error::Io(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            Error::input(path, "not a readable OpenEXR file: truncated")
        }
        x::Error::Io(io) => Error::io(path, io),
        other => Error::input(
            path,
            format!(
                "not a readable OpenEXR file: {}",
                one_line(&other.to_string())
            ),
        ),
    }
}

/// An EXR encoder failure: the OS error if it is one (a full disk), else a bug.
fn exr_write_error(path: &Path, e: x::Error) -> Error {
    match e {
        x::Error::Io(io) => Error::io(path, io),
        other => Error::internal(format!(
            "{}: EXR encoder: {}",
            path.display(),
            one_line(&other.to_string())
        )),
    }
}

fn one_line(s: &str) -> String {
    s.replace('\n', " ")
}

/// Find channel `want` ("R", "G" or "B") in a layer: an exact name, else a unique
/// `<prefix>.R` style name (legacy multi-layer files).
fn find_channel<'a>(
    list: &'a [x::AnyChannel<FlatSamples>],
    want: &str,
) -> Option<&'a x::AnyChannel<FlatSamples>> {
    if let Some(c) = list.iter().find(|c| c.name.eq(want)) {
        return Some(c);
    }
    let suffix = format!(".{want}");
    let mut it = list
        .iter()
        .filter(|c| c.name.to_string().ends_with(&suffix));
    match (it.next(), it.next()) {
        (Some(c), None) => Some(c),
        _ => None,
    }
}

fn samples_f32(s: &FlatSamples) -> Vec<f32> {
    match s {
        FlatSamples::F16(v) => v.iter().map(|h| h.to_f32()).collect(),
        FlatSamples::F32(v) => v.clone(),
        FlatSamples::U32(v) => v.iter().map(|&u| u as f32).collect(),
    }
}

/// Read a linear RGB OpenEXR image (float, half or uint channels; R, G, B found by name in any
/// order; alpha and other channels ignored). Non-finite or negative pixels are masked.
pub fn read_exr(path: impl AsRef<Path>) -> Result<Image> {
    let path = path.as_ref();
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    read_exr_from(std::io::BufReader::new(file), path)
}

/// [`read_exr`] on the bytes of a file already read; `path` names the file in errors.
pub fn read_exr_bytes(bytes: &[u8], path: &Path) -> Result<Image> {
    read_exr_from(std::io::Cursor::new(bytes), path)
}

/// Most decoded sample bytes an EXR may hold per byte of file: above what any of its
/// compressions reaches (deflate, in ZIP and PXR24, tops out near 1032:1), so only a header
/// that lies about its size is refused, before the decoder allocates for it.
const MAX_EXPANSION: u64 = 2048;

/// Decoded sample bytes always accepted, whatever the file's size.
const MIN_DECODED_LIMIT: u64 = 1 << 20;

/// Bytes the decoder allocates for the samples of every layer's full-resolution level.
fn decoded_bytes(meta: &x::MetaData) -> u64 {
    meta.headers
        .iter()
        .map(|h| {
            let area = (h.layer_size.x() as u64).saturating_mul(h.layer_size.y() as u64);
            h.channels
                .list
                .iter()
                .map(|c| area.saturating_mul(c.sample_type.bytes_per_sample() as u64))
                .fold(0, u64::saturating_add)
        })
        .fold(0, u64::saturating_add)
}

/// Reads the header and refuses an image whose samples could not fit in a file of
/// `file_bytes` bytes; leaves `reader` at the start of the file.
fn check_exr_size(reader: &mut (impl Read + Seek), file_bytes: u64, path: &Path) -> Result<()> {
    let meta =
        x::MetaData::read_from_buffered(&mut *reader, true).map_err(|e| exr_error(path, e))?;
    let decoded = decoded_bytes(&meta);
    let limit = file_bytes
        .saturating_mul(MAX_EXPANSION)
        .max(MIN_DECODED_LIMIT);
    if decoded > limit {
        return Err(Error::input(
            path,
            format!(
                "not a readable OpenEXR file: its header declares {decoded} bytes of samples, \
                 more than a {file_bytes}-byte file can hold"
            ),
        ));
    }
    reader
        .seek(SeekFrom::Start(0))
        .map_err(|e| Error::io(path, e))?;
    Ok(())
}

/// Whether the run has one worker thread (`--threads 1`, or one core): exr then encodes and
/// decodes on the calling thread instead of starting threads of its own, so a one-thread run
/// is one thread (and its instruction counts, `tools/icount.py`, do not depend on the others').
fn one_thread() -> bool {
    rayon::current_num_threads() == 1
}

/// Images below this many pixels are encoded on the calling thread: exr starts a thread pool
/// of its own (a thread per core) for every parallel write, which costs more than a small
/// image's compression, and the outputs of a run of many shapes are written side by side.
const PARALLEL_EXR_PIXELS: usize = 1 << 18;

/// Whether an image of `size` pixels is encoded on the calling thread ([`one_thread`], or a
/// small image, [`PARALLEL_EXR_PIXELS`]). The bytes are the same either way.
fn encode_here(size: (usize, usize)) -> bool {
    one_thread() || size.0 * size.1 < PARALLEL_EXR_PIXELS
}

/// [`read_exr`] from any seekable reader of the file's bytes.
fn read_exr_from(mut reader: impl Read + Seek, path: &Path) -> Result<Image> {
    let file_bytes = reader
        .seek(SeekFrom::End(0))
        .and_then(|n| reader.seek(SeekFrom::Start(0)).map(|_| n))
        .map_err(|e| Error::io(path, e))?;
    check_exr_size(&mut reader, file_bytes, path)?;
    let img = x::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .all_layers()
        .all_attributes()
        .pedantic();
    // one worker thread (`--threads 1`): no decoding threads of exr's own either
    let img = match one_thread() {
        true => img.non_parallel(),
        false => img,
    }
    .from_buffered(reader)
    .map_err(|e| exr_error(path, e))?;

    let mut names: Vec<String> = Vec::new();
    for layer in &img.layer_data {
        let list = &layer.channel_data.list;
        names.extend(list.iter().map(|c| c.name.to_string()));
        let (Some(r), Some(g), Some(b)) = (
            find_channel(list, "R"),
            find_channel(list, "G"),
            find_channel(list, "B"),
        ) else {
            continue;
        };
        let (w, h) = (layer.size.x(), layer.size.y());
        if [r, g, b]
            .iter()
            .any(|c| c.sampling.x() != 1 || c.sampling.y() != 1)
        {
            return Err(Error::input(
                path,
                "subsampled R/G/B channels are not supported",
            ));
        }
        let (rv, gv, bv) = (
            samples_f32(&r.sample_data),
            samples_f32(&g.sample_data),
            samples_f32(&b.sample_data),
        );
        let n = w * h;
        if rv.len() != n || gv.len() != n || bv.len() != n {
            return Err(Error::input(
                path,
                "channel sizes do not match the image size",
            ));
        }
        let (Ok(wu), Ok(hu)) = (u32::try_from(w), u32::try_from(h)) else {
            return Err(Error::input(
                path,
                format!("image size {w}x{h} is too large"),
            ));
        };
        let pixels = (0..n).map(|i| Vec3::new(rv[i], gv[i], bv[i])).collect();
        return Ok(Image::from_raw(wu, hu, pixels));
    }
    let what = if names.iter().any(|n| n == "Y" || n.ends_with(".Y")) {
        "a luminance-only (Y) image is not supported; an RGB image is needed".to_string()
    } else {
        format!("no R, G, B channels found (channels: {})", names.join(", "))
    };
    Err(Error::input(path, what))
}

/// [`read_exr`], then check the size is `width` x `height`.
pub fn read_exr_expect(path: impl AsRef<Path>, width: u32, height: u32) -> Result<Image> {
    let path = path.as_ref();
    let img = read_exr(path)?;
    if (img.width, img.height) != (width, height) {
        return Err(Error::input(
            path,
            format!(
                "image is {}x{} but {width}x{height} was expected",
                img.width, img.height
            ),
        ));
    }
    Ok(img)
}

/// The photo taken by `sensor`: an OpenEXR as it is, a PNG or JPEG (by its extension) through
/// `response` ([`read_ldr`]); its size must be the sensor's film size.
pub fn read_photo(path: impl AsRef<Path>, sensor: &Sensor, response: &Response) -> Result<Image> {
    let path = path.as_ref();
    let img = match is_8bit(path) {
        true => read_ldr(path, response)?,
        false => read_exr(path)?,
    };
    if (img.width, img.height) != (sensor.width, sensor.height) {
        return Err(Error::input(
            path,
            format!(
                "image is {}x{} but sensor {} film is {}x{}",
                img.width, img.height, sensor.id, sensor.width, sensor.height
            ),
        ));
    }
    Ok(img)
}

/// [`read_photo`] with the default response (sRGB) for a PNG or JPEG.
pub fn read_sensor_image(path: impl AsRef<Path>, sensor: &Sensor) -> Result<Image> {
    read_photo(path, sensor, &Response::Srgb)
}

fn check_len(path: &Path, width: u32, height: u32, pixels: &[Vec3]) -> Result<()> {
    if pixels.len() != width as usize * height as usize || width == 0 || height == 0 {
        return Err(Error::internal(format!(
            "{}: cannot write a {width}x{height} image from {} pixels",
            path.display(),
            pixels.len()
        )));
    }
    Ok(())
}

/// Write a linear RGB OpenEXR image (row-major, row 0 = top), ZIP-compressed, as 32-bit float
/// or, with `half`, as 16-bit half (finite values beyond the half range are clamped to it).
/// The file appears only once it is complete.
pub fn write_exr_rgb(
    path: impl AsRef<Path>,
    width: u32,
    height: u32,
    pixels: &[Vec3],
    half: bool,
) -> Result<()> {
    let path = path.as_ref();
    check_len(path, width, height, pixels)?;
    let w = width as usize;
    write_exr_rgb_fn(path, width, height, half, |x, y| {
        pixels[y as usize * w + x as usize]
    })
}

/// [`write_exr_rgb`] from a pixel function `at(x, y)`, for images too large to hold whole
/// (the encoder pulls pixels a block of rows at a time).
pub fn write_exr_rgb_fn(
    path: impl AsRef<Path>,
    width: u32,
    height: u32,
    half: bool,
    at: impl Fn(u32, u32) -> Vec3 + Sync,
) -> Result<()> {
    let path = path.as_ref();
    if width == 0 || height == 0 {
        return Err(Error::internal(format!(
            "{}: cannot write a {width}x{height} image",
            path.display()
        )));
    }
    let size = (width as usize, height as usize);
    let at = |p: x::Vec2<usize>| at(p.x() as u32, p.y() as u32);
    fsio::write_atomic_with(path, |tmp| {
        if half {
            let to_h = |v: f32| {
                let v = if v.is_finite() {
                    v.clamp(-65504.0, 65504.0)
                } else {
                    v
                };
                f16::from_f32(v)
            };
            encode_rgb(tmp, size, |p| {
                let c = at(p);
                (to_h(c.x), to_h(c.y), to_h(c.z))
            })
        } else {
            encode_rgb(tmp, size, |p| {
                let c = at(p);
                (c.x, c.y, c.z)
            })
        }
        .map_err(|e| exr_write_error(path, e))
    })
}

/// One RGB layer of `size` whose pixel `p` is `px(p)` (f32 or f16 samples), ZIP-compressed,
/// encoded into `tmp` on exr's workers or, for small images or one thread, here.
fn encode_rgb<T: x::IntoSample>(
    tmp: &Path,
    size: (usize, usize),
    px: impl Sync + Fn(x::Vec2<usize>) -> (T, T, T),
) -> exr::error::UnitResult {
    let ch = SpecificChannels::rgb(px);
    let attrs = LayerAttributes::default();
    let w = x::Image::from_layer(x::Layer::new(size, attrs, Encoding::SMALL_LOSSLESS, ch));
    match encode_here(size) {
        true => w.write().non_parallel().to_file(tmp),
        false => w.write().to_file(tmp),
    }
}

/// Exposure (stops) that maps the 99th percentile luminance of `vals` (where `mask`) to 0.9:
/// the automatic exposure of every preview that is not an albedo.
pub fn auto_exposure(vals: &[Vec3], mask: &[bool]) -> f32 {
    auto_exposure_with(|f| {
        for (v, _) in vals.iter().zip(mask).filter(|(_, &m)| m) {
            f(*v);
        }
    })
}

/// [`auto_exposure`] over the values `visit` hands to its callback (called twice), without
/// holding them: the exact 99th percentile by a two-level radix select on the luminance's
/// bits (positive finite floats order as their bit patterns), the same value as sorting.
pub fn auto_exposure_with(visit: impl Fn(&mut dyn FnMut(Vec3))) -> f32 {
    let lum = |v: Vec3| Some(crate::scene::luminance(v)).filter(|y| y.is_finite() && *y > 0.0);
    let mut high = vec![0u64; 1 << 16];
    visit(&mut |v| {
        if let Some(y) = lum(v) {
            high[(y.to_bits() >> 16) as usize] += 1;
        }
    });
    let n: u64 = high.iter().sum();
    if n == 0 {
        return 0.0;
    }
    let k = ((n as f64 * 0.99) as u64).min(n - 1);
    let (bin, before) = nth_bin(&high, k);
    let mut low = vec![0u64; 1 << 16];
    visit(&mut |v| {
        if let Some(y) = lum(v) {
            if (y.to_bits() >> 16) as usize == bin {
                low[(y.to_bits() & 0xffff) as usize] += 1;
            }
        }
    });
    let (lo, _) = nth_bin(&low, k - before);
    let v = f32::from_bits(((bin as u32) << 16) | lo as u32);
    (0.9 / v).log2()
}

/// The bin holding the `k`-th (0-based) counted item, and how many items lie before it.
fn nth_bin(counts: &[u64], k: u64) -> (usize, u64) {
    let mut before = 0u64;
    for (i, &c) in counts.iter().enumerate() {
        if before + c > k {
            return (i, before);
        }
        before += c;
    }
    (counts.len() - 1, before)
}

/// The sRGB transfer function, for a linear value in [0, 1].
fn srgb_encode(v: f32) -> f32 {
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// Write an 8-bit sRGB PNG preview of linear RGB pixels scaled by `2^exposure` (stops, as in
/// Mitsuba and tev), clamped to [0, 1]; non-finite pixels show black. Written atomically.
pub fn write_png_srgb(
    path: impl AsRef<Path>,
    width: u32,
    height: u32,
    pixels: &[Vec3],
    exposure: f32,
) -> Result<()> {
    let path = path.as_ref();
    check_len(path, width, height, pixels)?;
    let w = width as usize;
    write_png_srgb_fn(path, width, height, exposure, |x, y| {
        pixels[y as usize * w + x as usize]
    })
}

/// [`write_png_srgb`] from a pixel function `at(x, y)`, a row at a time.
pub fn write_png_srgb_fn(
    path: impl AsRef<Path>,
    width: u32,
    height: u32,
    exposure: f32,
    at: impl Fn(u32, u32) -> Vec3,
) -> Result<()> {
    let scale = exposure.exp2();
    write_png_rows(path.as_ref(), width, height, |y| {
        Ok((0..width).flat_map(|x| srgb8(at(x, y), scale)).collect())
    })
}

/// One pixel of an sRGB preview: `c * scale` clamped to [0, 1], encoded, opaque.
pub fn srgb8(c: Vec3, scale: f32) -> [u8; 4] {
    let mut px = [0, 0, 0, 255];
    for k in 0..3 {
        let v = c[k] * scale;
        let v = if v.is_finite() {
            v.clamp(0.0, 1.0)
        } else {
            0.0
        };
        px[k] = (srgb_encode(v) * 255.0 + 0.5) as u8;
    }
    px
}

/// Write an 8-bit RGBA PNG whose row `y` is `row(y)` (4 bytes per pixel), streamed to the file
/// (no image is held whole); atomically.
pub fn write_png_rows(
    path: &Path,
    width: u32,
    height: u32,
    mut row: impl FnMut(u32) -> Result<Vec<u8>>,
) -> Result<()> {
    if width == 0 || height == 0 {
        return Err(Error::internal(format!(
            "{}: cannot make a {width}x{height} PNG",
            path.display()
        )));
    }
    let bad = |e: png::EncodingError| {
        Error::internal(format!(
            "{}: cannot encode PNG: {}",
            path.display(),
            one_line(&e.to_string())
        ))
    };
    fsio::write_atomic_buffered(path, |out| {
        let mut enc = png::Encoder::new(out, width, height);
        enc.set_color(png::ColorType::Rgba);
        enc.set_depth(png::BitDepth::Eight);
        // fdeflate's fast mode: most of what the previews cost was zlib's deflate
        enc.set_compression(png::Compression::Fast);
        let mut w = enc.write_header().map_err(bad)?;
        let mut sw = w.stream_writer().map_err(bad)?;
        for y in 0..height {
            let r = row(y)?;
            if r.len() != 4 * width as usize {
                return Err(Error::internal(format!(
                    "{}: row {y} has {} bytes for {width} pixels",
                    path.display(),
                    r.len()
                )));
            }
            std::io::Write::write_all(&mut sw, &r).map_err(|e| Error::io(path, e))?;
        }
        sw.finish().map_err(bad)?;
        // the IEND chunk, written here so that its error is one (dropped, the writer drops it)
        w.finish().map_err(bad)
    })
}

/// Encode `pm` as PNG and write it atomically.
pub fn write_pixmap_png(path: &Path, pm: &tiny_skia::Pixmap) -> Result<()> {
    let bytes = pm.encode_png().map_err(|e| {
        Error::internal(format!(
            "{}: cannot encode PNG: {}",
            path.display(),
            one_line(&e.to_string())
        ))
    })?;
    fsio::write_atomic(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(w: u32, h: u32) -> Vec<Vec3> {
        (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                Vec3::new(x * 0.37 + 0.01, y * 1.9 + 0.5, (x * y) * 0.013 + 1e-3)
            })
            .collect()
    }

    #[test]
    fn float_round_trip_is_exact() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.exr");
        let px = ramp(13, 7);
        write_exr_rgb(&p, 13, 7, &px, false).unwrap();
        assert!(!fsio::tmp_path(&p).exists());
        let img = read_exr(&p).unwrap();
        assert_eq!((img.width, img.height, img.masked), (13, 7, 0));
        assert_eq!(img.pixels, px);
        assert!(img.valid.iter().all(|&v| v));
        // row 0 is the top row, x runs along a row
        assert_eq!(img.get(3, 2), px[2 * 13 + 3]);
    }

    #[test]
    fn an_exr_is_the_same_bytes_encoded_on_one_thread_or_many() {
        let dir = tempfile::tempdir().unwrap();
        // one image above the size encoded in parallel, one below it
        for (w, h) in [(640u32, 420u32), (40, 30)] {
            let px = ramp(w, h);
            let (a, b) = (dir.path().join("a.exr"), dir.path().join("b.exr"));
            write_exr_rgb(&a, w, h, &px, false).unwrap();
            let one = rayon::ThreadPoolBuilder::new()
                .num_threads(1)
                .build()
                .unwrap();
            one.install(|| write_exr_rgb(&b, w, h, &px, false)).unwrap();
            let (a, b) = (std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
            assert!(a == b, "{w}x{h}");
            assert_eq!(read_exr(dir.path().join("a.exr")).unwrap().pixels, px);
        }
        assert!(!encode_here((640, 420)) || one_thread());
        assert!(encode_here((40, 30)));
    }

    #[test]
    fn half_round_trip_within_1e3() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("h.exr");
        let px = ramp(9, 11);
        write_exr_rgb(&p, 9, 11, &px, true).unwrap();
        let img = read_exr_expect(&p, 9, 11).unwrap();
        for (a, b) in img.pixels.iter().zip(&px) {
            for k in 0..3 {
                assert!((a[k] - b[k]).abs() <= 1e-3 * b[k].abs(), "{a} vs {b}");
            }
        }
    }

    #[test]
    fn channels_in_any_order_with_alpha() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("bgra.exr");
        let (w, h) = (5usize, 4usize);
        let val = |i: usize, k: usize| (i * 10 + k) as f32;
        let n = w * h;
        let mk = |name: &str, k: usize| {
            x::AnyChannel::new(name, FlatSamples::F32((0..n).map(|i| val(i, k)).collect()))
        };
        // listed B, G, R, A on purpose (the writer sorts them by name anyway)
        let chans = x::AnyChannels::sort(smallvec_of(vec![
            mk("B", 2),
            mk("G", 1),
            mk("R", 0),
            mk("A", 9),
        ]));
        x::Image::from_channels((w, h), chans)
            .write()
            .to_file(&p)
            .unwrap();
        let img = read_exr(&p).unwrap();
        for i in 0..n {
            assert_eq!(img.pixels[i], Vec3::new(val(i, 0), val(i, 1), val(i, 2)));
        }
    }

    fn smallvec_of(
        v: Vec<x::AnyChannel<FlatSamples>>,
    ) -> x::SmallVec<[x::AnyChannel<FlatSamples>; 4]> {
        v.into_iter().collect()
    }

    #[test]
    fn bad_pixels_are_masked_and_counted() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("bad.exr");
        let mut px = ramp(4, 3);
        px[0].x = f32::NAN;
        px[5].y = -0.5;
        px[7].z = f32::INFINITY;
        px[8] = Vec3::splat(f32::NEG_INFINITY);
        write_exr_rgb(&p, 4, 3, &px, false).unwrap();
        let img = read_exr(&p).unwrap();
        assert_eq!(img.masked, 4);
        for (i, &orig) in px.iter().enumerate() {
            let bad = [0, 5, 7, 8].contains(&i);
            assert_eq!(img.valid[i], !bad, "pixel {i}");
            let want = if bad { Vec3::ZERO } else { orig };
            assert_eq!(img.pixels[i], want);
        }
    }

    #[test]
    fn size_mismatch_names_both_sizes() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("cam_train_0.exr");
        write_exr_rgb(&p, 8, 8, &ramp(8, 8), true).unwrap();
        let e = read_exr_expect(&p, 16, 16).unwrap_err().to_string();
        assert!(e.contains("cam_train_0.exr") && e.contains("8x8") && e.contains("16x16"));
        let s = Sensor::simple(
            "cam_train_0",
            glam::Mat4::IDENTITY,
            40.0,
            crate::scene::FovAxis::X,
            (16, 16),
            crate::scene::PixelFilter::Box,
        );
        let e = read_sensor_image(&p, &s).unwrap_err().to_string();
        assert!(
            e.ends_with("cam_train_0.exr: image is 8x8 but sensor cam_train_0 film is 16x16"),
            "{e}"
        );
    }

    #[test]
    fn missing_truncated_and_corrupt_files_are_errors_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("missing.exr");
        let e = read_exr(&missing).unwrap_err().to_string();
        assert!(e.contains("missing.exr"), "{e}");

        let good = dir.path().join("good.exr");
        write_exr_rgb(&good, 32, 32, &ramp(32, 32), false).unwrap();
        let bytes = std::fs::read(&good).unwrap();
        for (name, data) in [
            ("truncated.exr", bytes[..bytes.len() * 2 / 3].to_vec()),
            ("header_only.exr", bytes[..40].to_vec()),
            ("garbage.exr", b"this is not an exr file at all".to_vec()),
            ("empty.exr", Vec::new()),
        ] {
            let p = dir.path().join(name);
            std::fs::write(&p, data).unwrap();
            let e = read_exr(&p).unwrap_err().to_string();
            assert!(e.contains(name), "{e}");
            assert!(!e.contains('\n'), "{e}");
        }
    }

    #[test]
    fn luminance_only_image_is_refused_clearly() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("y.exr");
        let ch = x::AnyChannels::sort(smallvec_of(vec![x::AnyChannel::new(
            "Y",
            FlatSamples::F32(vec![0.5; 6]),
        )]));
        x::Image::from_channels((3, 2), ch)
            .write()
            .to_file(&p)
            .unwrap();
        let e = read_exr(&p).unwrap_err().to_string();
        assert!(e.contains("y.exr") && e.contains("luminance"), "{e}");
    }

    #[test]
    fn png_preview_is_written_and_wrong_sizes_refused() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.png");
        write_png_srgb(&p, 4, 3, &ramp(4, 3), -2.0).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
        assert!(!fsio::tmp_path(&p).exists());
        assert!(write_png_srgb(&p, 5, 3, &ramp(4, 3), 0.0).is_err());
        assert!(write_exr_rgb(dir.path().join("b.exr"), 5, 3, &ramp(4, 3), false).is_err());
        assert!((srgb_encode(1.0) - 1.0).abs() < 1e-6);
        assert!((srgb_encode(0.18) - 0.4613).abs() < 1e-3);
    }
}
