//! COLMAP's text model files, `cameras.txt` and `images.txt`, read as COLMAP's
//! `ReadCamerasText` and `ReadImagesText` read them: `#` comments and blank lines skipped,
//! fields separated by spaces; each image takes two lines, the second (its 2D points, possibly
//! empty) checked for shape and otherwise ignored. Every refusal names the file and line.

use super::{camera_record, image_record, CameraRecord, ImageRecord, Place};
use crate::base::error::Error;
use crate::scene::lens::{refusal, Lens, LensModel};
use crate::Result;
use std::path::Path;
use std::str::FromStr;

/// The file as text; refused when it is not UTF-8, at the line of the first bad byte.
fn read_text(path: &Path) -> Result<String> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    String::from_utf8(bytes).map_err(|e| {
        let good = &e.as_bytes()[..e.utf8_error().valid_up_to()];
        let line = 1 + good.iter().filter(|&&b| b == b'\n').count() as u32;
        Error::input_at(path, line, "not UTF-8 text")
    })
}

/// The place of line `line` (1-based) of `path`.
fn at(path: &Path, line: usize) -> Place {
    Place {
        file: path.to_path_buf(),
        line: Some(line as u32),
        byte: None,
    }
}

/// Field `i` of `tokens`, called `name`, parsed as a `T` (`what` says what it should be).
fn field<T: FromStr>(tokens: &[&str], i: usize, name: &str, what: &str, p: &Place) -> Result<T> {
    let t = tokens
        .get(i)
        .ok_or_else(|| p.error(format!("missing {name} (field {})", i + 1)))?;
    t.parse()
        .map_err(|_| p.error(format!("{name} '{t}' is not {what}")))
}

/// Every camera of `cameras.txt`: `CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`.
pub fn cameras(path: &Path) -> Result<Vec<CameraRecord>> {
    let text = read_text(path)?;
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        out.push(camera_line(line, at(path, n + 1))?);
    }
    Ok(out)
}

fn camera_line(line: &str, p: Place) -> Result<CameraRecord> {
    let t: Vec<&str> = line.split_whitespace().collect();
    let id: u32 = field(&t, 0, "CAMERA_ID", "a camera id (a whole number)", &p)?;
    let name = t
        .get(1)
        .ok_or_else(|| p.error(format!("camera {id}: missing MODEL")))?;
    let model = LensModel::from_name(name)
        .ok_or_else(|| p.error(format!("camera {id}: {}", refusal(name))))?;
    let w: u64 = field(&t, 2, "WIDTH", "a whole number", &p)?;
    let h: u64 = field(&t, 3, "HEIGHT", "a whole number", &p)?;
    let params = (4..t.len())
        .map(|i| field(&t, i, "a parameter", "a number", &p))
        .collect::<Result<Vec<f64>>>()?;
    camera_record(id, Lens::new(model, &params), (w, h), p)
}

/// Every image of `images.txt`: `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`, then one line
/// of `X Y POINT3D_ID` triples (may be empty).
pub fn images(path: &Path) -> Result<Vec<ImageRecord>> {
    let text = read_text(path)?;
    let mut out = Vec::new();
    let mut lines = text.lines().enumerate();
    while let Some((n, line)) = lines.next() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let image = image_line(line, at(path, n + 1))?;
        // As COLMAP: the next line, whatever it is, holds the image's 2D points.
        if let Some((m, points)) = lines.next() {
            check_points(points, image.id, at(path, m + 1))?;
        }
        out.push(image);
    }
    Ok(out)
}

fn image_line(line: &str, p: Place) -> Result<ImageRecord> {
    let t: Vec<&str> = line.split_whitespace().collect();
    let id: u32 = field(&t, 0, "IMAGE_ID", "an image id (a whole number)", &p)?;
    let names = ["QW", "QX", "QY", "QZ", "TX", "TY", "TZ"];
    let mut pose = [0.0; 7];
    for (k, name) in names.iter().enumerate() {
        pose[k] = field(&t, k + 1, name, "a number", &p)?;
    }
    let camera: u32 = field(&t, 8, "CAMERA_ID", "a camera id (a whole number)", &p)?;
    let name: String = field(&t, 9, "NAME", "a file name", &p)?;
    if t.len() > 10 {
        return Err(p.error(format!(
            "image {id}: {} fields after CAMERA_ID, expected one NAME (names with spaces are not \
             read)",
            t.len() - 9
        )));
    }
    let q = [pose[0], pose[1], pose[2], pose[3]];
    let tv = [pose[4], pose[5], pose[6]];
    image_record(id, (q, tv), camera, name, p)
}

/// An image's second line: empty, or `X Y POINT3D_ID` triples. Anything else means the file
/// lost its two-lines-per-image layout (say, an image line where the points should be).
fn check_points(line: &str, id: u32, p: Place) -> Result<()> {
    let t: Vec<&str> = line.split_whitespace().collect();
    let numeric = t.iter().all(|x| x.parse::<f64>().is_ok());
    if t.len() % 3 != 0 || !numeric {
        return Err(p.error(format!(
            "expected the POINTS2D line of image {id} (X Y POINT3D_ID triples, or an empty \
             line): each image takes two lines"
        )));
    }
    Ok(())
}
