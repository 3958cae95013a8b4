//! COLMAP's binary model files, `cameras.bin` and `images.bin`, read as COLMAP's
//! `ReadCamerasBinary` and `ReadImagesBinary` read them (little-endian): a `u64` count, then
//! per camera `u32` id, `i32` model id, `u64` width and height, the model's `f64` parameters;
//! per image `u32` id, `f64` QW QX QY QZ TX TY TZ, `u32` camera id, the NAME up to a NUL
//! byte, a `u64` count of 2D points and 24 bytes each (skipped). Every refusal names the file
//! and the byte its record starts at; a count the file cannot hold and bytes after the last
//! record are refused.

use super::{camera_record, image_record, CameraRecord, ImageRecord, Place};
use crate::base::error::Error;
use crate::scene::lens::{refusal, Lens, LensModel, COLMAP_MODELS};
use crate::Result;
use std::path::Path;

/// A cursor over a model file's bytes.
struct Reader<'a> {
    path: &'a Path,
    bytes: &'a [u8],
    pos: usize,
    /// Where the current record starts, for errors.
    record: usize,
}

impl<'a> Reader<'a> {
    fn place(&self) -> Place {
        Place {
            file: self.path.to_path_buf(),
            line: None,
            byte: Some(self.record as u64),
        }
    }

    fn error(&self, msg: impl Into<String>) -> Error {
        self.place().error(msg)
    }

    /// The next `n` bytes, `what` naming them if the file ends first.
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8]> {
        let left = self.bytes.len() - self.pos;
        if n > left {
            return Err(self.error(format!(
                "the file ends inside {what} (at byte {}: {n} bytes needed, {left} left)",
                self.pos
            )));
        }
        let s = &self.bytes[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    fn array<const N: usize>(&mut self, what: &str) -> Result<[u8; N]> {
        let s = self.take(N, what)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    fn u32(&mut self, what: &str) -> Result<u32> {
        Ok(u32::from_le_bytes(self.array(what)?))
    }

    fn i32(&mut self, what: &str) -> Result<i32> {
        Ok(i32::from_le_bytes(self.array(what)?))
    }

    fn u64(&mut self, what: &str) -> Result<u64> {
        Ok(u64::from_le_bytes(self.array(what)?))
    }

    fn f64(&mut self, what: &str) -> Result<f64> {
        Ok(f64::from_le_bytes(self.array(what)?))
    }

    /// The record count at the start of the file, refused when `count x min_size` bytes do
    /// not fit in the rest of the file.
    fn count(&mut self, what: &str, min_size: usize) -> Result<usize> {
        let n = self.u64(&format!("the number of {what}"))?;
        let left = (self.bytes.len() - self.pos) as u64;
        match n.checked_mul(min_size as u64) {
            Some(need) if need <= left => Ok(n as usize),
            _ => Err(self.error(format!(
                "declares {n} {what}, more than its {left} remaining bytes can hold"
            ))),
        }
    }

    /// Refuses bytes after the last record.
    fn finish(&mut self) -> Result<()> {
        self.record = self.pos;
        match self.bytes.len() - self.pos {
            0 => Ok(()),
            n => Err(self.error(format!(
                "{n} bytes after the last record (not a COLMAP model file?)"
            ))),
        }
    }
}

fn open(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|e| Error::io(path, e))
}

/// The records of a COLMAP binary file: their count (each at least `min_size` bytes), then
/// each read by `read`, and nothing after the last.
fn records<T>(
    path: &Path,
    what: &str,
    min_size: usize,
    read: impl Fn(&mut Reader) -> Result<T>,
) -> Result<Vec<T>> {
    let bytes = open(path)?;
    let mut r = Reader {
        path,
        bytes: &bytes,
        pos: 0,
        record: 0,
    };
    let n = r.count(what, min_size)?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        r.record = r.pos;
        out.push(read(&mut r)?);
    }
    r.finish()?;
    Ok(out)
}

/// Every camera of `cameras.bin`.
pub fn cameras(path: &Path) -> Result<Vec<CameraRecord>> {
    // id, model, width, height and at least three parameters
    records(path, "cameras", 4 + 4 + 8 + 8 + 3 * 8, camera)
}

fn camera(r: &mut Reader) -> Result<CameraRecord> {
    let id = r.u32("a camera's id")?;
    let model_id = r.i32("a camera's model id")?;
    let model = LensModel::from_id(model_id).ok_or_else(|| {
        let name = usize::try_from(model_id)
            .ok()
            .and_then(|i| COLMAP_MODELS.get(i))
            .map_or(format!("id {model_id}"), |n| n.to_string());
        r.error(format!("camera {id}: {}", refusal(&name)))
    })?;
    let w = r.u64("a camera's width")?;
    let h = r.u64("a camera's height")?;
    let params = (0..model.param_names().len())
        .map(|_| r.f64("a camera's parameters"))
        .collect::<Result<Vec<f64>>>()?;
    camera_record(id, Lens::new(model, &params), (w, h), r.place())
}

/// Every image of `images.bin`.
pub fn images(path: &Path) -> Result<Vec<ImageRecord>> {
    // id, pose, camera id, a one-byte name and its NUL, the point count
    records(path, "images", 4 + 7 * 8 + 4 + 2 + 8, image)
}

fn image(r: &mut Reader) -> Result<ImageRecord> {
    let id = r.u32("an image's id")?;
    let mut pose = [0.0; 7];
    for v in &mut pose {
        *v = r.f64("an image's pose")?;
    }
    let camera = r.u32("an image's camera id")?;
    let rest = &r.bytes[r.pos..];
    let len = rest
        .iter()
        .position(|&b| b == 0)
        .ok_or_else(|| r.error(format!("image {id}: its NAME has no terminating NUL byte")))?;
    let name = std::str::from_utf8(&rest[..len])
        .map_err(|_| r.error(format!("image {id}: its NAME is not UTF-8")))?
        .to_string();
    r.pos += len + 1;
    let points = r.u64("an image's number of 2D points")?;
    let size = points
        .checked_mul(24)
        .and_then(|s| usize::try_from(s).ok())
        .unwrap_or(usize::MAX);
    r.take(size, "an image's 2D points")?;
    let q = [pose[0], pose[1], pose[2], pose[3]];
    let t = [pose[4], pose[5], pose[6]];
    image_record(id, (q, t), camera, name, r.place())
}
