//! Where a camera's photo is and how large it is, known before any photo is decoded: the
//! default `images/<id>.exr|png|jpg|jpeg` (exactly one, or the sensor is ambiguous), and a
//! photo's size from its header. The scene needs both (a glTF camera's film is its photo's
//! size), and `image` decodes photos after the scene is loaded, so this lives here.

use crate::base::error::{Error, Result};
use std::path::{Path, PathBuf};

/// The photo formats a view may have, by file extension (compared without case).
pub const EXTENSIONS: &[&str] = &["exr", "png", "jpg", "jpeg"];

/// Whether `path` names an 8-bit (display-referred) photo: PNG or JPEG, by its extension.
/// Anything else is read as OpenEXR.
pub fn is_8bit(path: &Path) -> bool {
    matches!(extension(path).as_deref(), Some("png" | "jpg" | "jpeg"))
}

/// Whether `path` names a JPEG, by its extension.
pub fn is_jpeg(path: &Path) -> bool {
    matches!(extension(path).as_deref(), Some("jpg" | "jpeg"))
}

fn extension(path: &Path) -> Option<String> {
    path.extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
}

/// The photo of sensor `id` in `dir` (a scene's `images/`): the one file `<id>.<ext>` with an
/// extension of [`EXTENSIONS`] in any case, `None` if there is none (or no `dir`). Two or more
/// are refused, naming them: an `.exr` beside a `.jpg` of the same view is usually a
/// conversion's leftover, and the two differ in scale, so kdmap does not guess.
pub fn find(dir: &Path, id: &str) -> Result<Option<PathBuf>> {
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(Error::io(dir, e)),
    };
    let mut found: Vec<PathBuf> = Vec::new();
    for e in entries {
        let p = e.map_err(|e| Error::io(dir, e))?.path();
        let ours = p.file_stem().is_some_and(|s| s == id)
            && extension(&p).is_some_and(|x| EXTENSIONS.contains(&x.as_str()))
            && p.is_file();
        if ours {
            found.push(p);
        }
    }
    found.sort();
    match found.len() {
        0 | 1 => Ok(found.pop()),
        _ => {
            let names: Vec<String> = found
                .iter()
                .map(|p| p.file_name().unwrap_or_default().to_string_lossy().into())
                .collect();
            Err(Error::input(
                dir,
                format!(
                    "sensor '{id}' has {} photos ({}): ambiguous; keep one, or name it in the \
                     run config's [views]",
                    found.len(),
                    names.join(", ")
                ),
            ))
        }
    }
}

/// The width and height of a photo from its header: an OpenEXR's first part's data window,
/// a PNG's or JPEG's frame. A file that cannot be read is an error naming it.
pub fn size(photo: &Path) -> Result<(u32, u32)> {
    if !is_8bit(photo) {
        let meta = exr::meta::MetaData::read_from_file(photo, false)
            .map_err(|e| Error::input(photo, format!("not a readable OpenEXR file: {e}")))?;
        let h = meta
            .headers
            .first()
            .ok_or_else(|| Error::input(photo, "OpenEXR file without a header"))?;
        return Ok((h.layer_size.width() as u32, h.layer_size.height() as u32));
    }
    let format = match is_jpeg(photo) {
        true => ::image::ImageFormat::Jpeg,
        false => ::image::ImageFormat::Png,
    };
    let file = std::fs::File::open(photo).map_err(|e| Error::io(photo, e))?;
    ::image::ImageReader::with_format(std::io::BufReader::new(file), format)
        .into_dimensions()
        .map_err(|e| {
            let what = if is_jpeg(photo) { "JPEG" } else { "PNG" };
            let msg = e.to_string().replace('\n', " ");
            Error::input(photo, format!("not a readable {what} file: {msg}"))
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn touch(dir: &Path, name: &str) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, b"x").unwrap();
        p
    }

    #[test]
    fn one_photo_of_any_format_is_found_in_any_case() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        assert_eq!(find(&d.join("none"), "cam").unwrap(), None);
        assert_eq!(find(d, "cam").unwrap(), None);
        touch(d, "cam.txt");
        touch(d, "cam_1.exr");
        touch(d, "other.jpg");
        std::fs::create_dir(d.join("cam.png")).unwrap(); // a directory is no photo
        assert_eq!(find(d, "cam").unwrap(), None);
        std::fs::remove_dir(d.join("cam.png")).unwrap();
        for name in ["cam.exr", "cam.png", "cam.jpg", "cam.jpeg", "cam.JPG"] {
            let p = touch(d, name);
            assert_eq!(find(d, "cam").unwrap(), Some(p.clone()), "{name}");
            std::fs::remove_file(p).unwrap();
        }
        // a sensor id with a dot in it
        let p = touch(d, "cam.0.png");
        assert_eq!(find(d, "cam.0").unwrap(), Some(p));
    }

    #[test]
    fn two_photos_of_one_sensor_are_refused_naming_both() {
        let dir = tempfile::tempdir().unwrap();
        touch(dir.path(), "cam.exr");
        touch(dir.path(), "cam.jpg");
        let e = find(dir.path(), "cam").unwrap_err();
        assert_eq!(e.exit_code(), crate::base::error::exit::INPUT);
        let s = e.to_string();
        assert!(
            s.contains("'cam' has 2 photos (cam.exr, cam.jpg): ambiguous"),
            "{s}"
        );
        assert!(!s.contains('\n'), "{s}");
    }

    #[test]
    fn extensions_tell_8bit_photos_and_jpegs() {
        for (p, ldr, jpeg) in [
            ("a.exr", false, false),
            ("a.png", true, false),
            ("a.PNG", true, false),
            ("a.jpg", true, true),
            ("a.JPEG", true, true),
            ("a", false, false),
            ("a.hdr", false, false),
        ] {
            assert_eq!(is_8bit(Path::new(p)), ldr, "{p}");
            assert_eq!(is_jpeg(Path::new(p)), jpeg, "{p}");
        }
    }

    #[test]
    fn sizes_come_from_the_headers_and_bad_files_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let png = dir.path().join("a.png");
        ::image::RgbImage::new(7, 3).save(&png).unwrap();
        assert_eq!(size(&png).unwrap(), (7, 3));
        let jpg = dir.path().join("b.jpg");
        ::image::RgbImage::new(5, 9).save(&jpg).unwrap();
        assert_eq!(size(&jpg).unwrap(), (5, 9));
        let bad = touch(dir.path(), "c.png");
        let e = size(&bad).unwrap_err();
        assert_eq!(e.exit_code(), crate::base::error::exit::INPUT);
        assert!(
            e.to_string().contains("c.png: not a readable PNG file"),
            "{e}"
        );
    }
}
