//! A COLMAP sparse model as the sensors of a scene: structure-from-motion gives the cameras
//! (`cameras.txt` + `images.txt`, or `cameras.bin` + `images.bin`; `points3D` is not read), the
//! scene file keeps the geometry and the lights. Each registered image becomes a sensor with
//! its camera's lens (`scene::lens`), posed in the scene's frame through `[views] to_world`.
//!
//! Conventions (COLMAP's `doc/format.rst`, `src/colmap/scene/reconstruction_io*.cc`): an image
//! holds the world-to-camera rotation as a unit quaternion `QW QX QY QZ` (Hamilton, w first)
//! and the translation `TX TY TZ`, so a world point `X` is `R X + t` in the camera frame (x
//! right, y down, z forward) and the camera centre is `-R^T t`. The sensor's `to_world` is
//! Mitsuba's frame of that camera: columns `(-x, -y, z, centre)` mapped into the scene by the
//! similarity (positions through all of it, axes through its rotation).
//!
//! A sensor's id is the image's NAME without its extension, with `/` and `\` (subfolders)
//! turned into `_`: `left/0001.jpg` is `left_0001`. Two images with one id are refused. Its
//! photo is `<scene dir>/images/<NAME>`.

mod binary;
mod text;

use crate::base::error::{Error, Location};
use crate::config::Similarity;
use crate::scene::lens::Lens;
use crate::scene::{FovAxis, PixelFilter, Scene, Sensor};
use crate::Result;
use glam::{DMat3, DMat4, DQuat, DVec3, Vec2};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Where a record of a model file is: its line (text) or the byte its record starts at
/// (binary).
#[derive(Debug, Clone, PartialEq)]
pub struct Place {
    pub file: PathBuf,
    pub line: Option<u32>,
    pub byte: Option<u64>,
}

impl Place {
    /// An input error at this place, in one line: `images.txt (line 5): ...` or
    /// `images.bin, byte 96: ...`.
    pub fn error(&self, msg: impl Into<String>) -> Error {
        Error::Input {
            path: self.file.clone(),
            loc: Location {
                line: self.line,
                col: None,
                element: self.byte.map(|b| format!("byte {b}")),
            },
            msg: msg.into(),
        }
    }
}

/// One camera of the model: its size and lens.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraRecord {
    pub id: u32,
    pub width: u32,
    pub height: u32,
    pub lens: Lens,
    pub place: Place,
}

/// One registered image: its world-to-camera pose, its camera and its file name.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageRecord {
    pub id: u32,
    /// `QW QX QY QZ`, normalized.
    pub qvec: [f64; 4],
    pub tvec: [f64; 3],
    pub camera: u32,
    pub name: String,
    pub place: Place,
}

/// Which of COLMAP's two formats a model is in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    Text,
    Binary,
}

/// A sparse model's cameras and images, in file order.
#[derive(Debug, Clone, PartialEq)]
pub struct Model {
    pub format: Format,
    /// The two files read (cameras, then images).
    pub files: Vec<PathBuf>,
    pub cameras: Vec<CameraRecord>,
    pub images: Vec<ImageRecord>,
}

/// The model's files in `dir`: the binary pair when both are there (as COLMAP prefers), else
/// the text pair.
pub fn model_files(dir: &Path) -> Result<(Format, PathBuf, PathBuf)> {
    if !dir.is_dir() {
        let e = std::io::Error::new(
            std::io::ErrorKind::NotFound,
            "no such directory (views.colmap names a COLMAP sparse model's directory)",
        );
        return Err(Error::io(dir, e));
    }
    for (format, ext) in [(Format::Binary, "bin"), (Format::Text, "txt")] {
        let (c, i) = (
            dir.join(format!("cameras.{ext}")),
            dir.join(format!("images.{ext}")),
        );
        if c.is_file() && i.is_file() {
            return Ok((format, c, i));
        }
    }
    let hint = match dir.join("0").is_dir() {
        true => " (COLMAP's mapper writes its models into numbered folders: try .../0)",
        false => "",
    };
    Err(Error::input(
        dir,
        format!(
            "no COLMAP sparse model here: expected cameras.txt and images.txt, or cameras.bin \
             and images.bin{hint}"
        ),
    ))
}

/// Read the sparse model in `dir`, its camera ids and image ids each unique.
pub fn read(dir: &Path) -> Result<Model> {
    let (format, cams, imgs) = model_files(dir)?;
    let (cameras, images) = match format {
        Format::Text => (text::cameras(&cams)?, text::images(&imgs)?),
        Format::Binary => (binary::cameras(&cams)?, binary::images(&imgs)?),
    };
    unique(cameras.iter().map(|c| (c.id, &c.place)), "camera")?;
    unique(images.iter().map(|i| (i.id, &i.place)), "image")?;
    Ok(Model {
        format,
        files: vec![cams, imgs],
        cameras,
        images,
    })
}

/// Refuses a second record with an id already seen.
fn unique<'a>(ids: impl Iterator<Item = (u32, &'a Place)>, what: &str) -> Result<()> {
    let mut seen: HashMap<u32, &Place> = HashMap::new();
    for (id, place) in ids {
        if let Some(first) = seen.insert(id, place) {
            return Err(place.error(format!(
                "{what} {id} is defined twice (first at {})",
                where_is(first)
            )));
        }
    }
    Ok(())
}

/// `line 4` or `byte 8`.
fn where_is(p: &Place) -> String {
    match (p.line, p.byte) {
        (Some(l), _) => format!("line {l}"),
        (_, Some(b)) => format!("byte {b}"),
        _ => "?".into(),
    }
}

/// A camera record from parsed fields: its size and lens checked (the distortion one-to-one
/// over the image).
pub(crate) fn camera_record(
    id: u32,
    lens: std::result::Result<Lens, String>,
    (width, height): (u64, u64),
    place: Place,
) -> Result<CameraRecord> {
    let dim = |v: u64, what: &str| match u32::try_from(v) {
        Ok(v) if v > 0 => Ok(v),
        _ => Err(place.error(format!(
            "camera {id}: {what} {v} is not a positive 32-bit size"
        ))),
    };
    let (width, height) = (dim(width, "WIDTH")?, dim(height, "HEIGHT")?);
    let lens = lens.map_err(|m| place.error(format!("camera {id}: {m}")))?;
    lens.check_image(width, height)
        .map_err(|m| place.error(format!("camera {id}: {m}")))?;
    Ok(CameraRecord {
        id,
        width,
        height,
        lens,
        place,
    })
}

/// An image record from parsed fields: the quaternion finite and of unit length (to 1e-3, as
/// written with fewer digits; then normalized) and the translation finite.
pub(crate) fn image_record(
    id: u32,
    (q, t): ([f64; 4], [f64; 3]),
    camera: u32,
    name: String,
    place: Place,
) -> Result<ImageRecord> {
    let norm = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    if norm.is_nan() || (norm - 1.0).abs() > 1e-3 {
        return Err(place.error(format!(
            "image {id}: QW QX QY QZ = {q:?} is not a unit quaternion (norm {norm})"
        )));
    }
    if !t.iter().all(|x| x.is_finite()) {
        return Err(place.error(format!("image {id}: TX TY TZ = {t:?} is not finite")));
    }
    if name.is_empty() {
        return Err(place.error(format!("image {id}: empty NAME")));
    }
    Ok(ImageRecord {
        id,
        qvec: q.map(|x| x / norm),
        tvec: t,
        camera,
        name,
        place,
    })
}

/// A sensor id from an image's NAME: the extension dropped, `/` and `\` (and control
/// characters) turned into `_`, so ids stay file names.
pub fn sensor_id(name: &str) -> String {
    let start = name.rfind(['/', '\\']).map_or(0, |i| i + 1);
    let stem = match name.rfind('.') {
        Some(i) if i > start => &name[..i],
        _ => name,
    };
    let clean = |c: char| match c == '/' || c == '\\' || c.is_control() {
        true => '_',
        false => c,
    };
    stem.chars().map(clean).collect()
}

/// Mitsuba's camera-to-world (columns left, up, forward, centre) of an image with
/// world-to-camera rotation `q` (`QW QX QY QZ`) and translation `t`, in the frame `sim` maps
/// the model into.
pub fn camera_to_world(q: [f64; 4], t: [f64; 3], sim: &Similarity) -> DMat4 {
    let r = DMat3::from_quat(DQuat::from_xyzw(q[1], q[2], q[3], q[0]));
    let centre = -(r.transpose() * DVec3::from(t));
    // The camera's axes (x right, y down, z forward) in the model's frame, then the scene's.
    let axes = sim.rotation * r.transpose();
    DMat4::from_cols(
        (-axes.x_axis).extend(0.0),
        (-axes.y_axis).extend(0.0),
        axes.z_axis.extend(0.0),
        sim.point(centre).extend(1.0),
    )
}

/// The sensor of `image` through `cam`: COLMAP's lens, and as the Mitsuba fields the nearest
/// `perspective` sensor (horizontal fov from `fx`, the principal point as Mitsuba's offset).
fn sensor(image: &ImageRecord, cam: &CameraRecord, sim: &Similarity, dir: &Path) -> Sensor {
    let l = &cam.lens;
    let (w, h) = (cam.width as f64, cam.height as f64);
    Sensor {
        id: sensor_id(&image.name),
        to_world: camera_to_world(image.qvec, image.tvec, sim).as_mat4(),
        fov: (2.0 * (w / (2.0 * l.fx)).atan()).to_degrees() as f32,
        fov_axis: FovAxis::X,
        width: cam.width,
        height: cam.height,
        film_width: cam.width,
        film_height: cam.height,
        crop_offset: (0, 0),
        principal_point: Vec2::new((0.5 - l.cx / w) as f32, (0.5 - l.cy / h) as f32),
        filter: PixelFilter::Box,
        lens: Some(l.clone()),
        photo: Some(dir.join("images").join(&image.name)),
    }
}

/// Every image of `model` as a sensor, in file order, posed by `sim`, its photo in
/// `<scene_dir>/images/`. Refused: an image whose camera the model lacks, an id that is not a
/// file name, two images with one id.
pub fn sensors(model: &Model, sim: &Similarity, scene_dir: &Path) -> Result<Vec<Sensor>> {
    let cams: HashMap<u32, &CameraRecord> = model.cameras.iter().map(|c| (c.id, c)).collect();
    let mut ids: HashMap<String, &ImageRecord> = HashMap::new();
    let mut out = Vec::with_capacity(model.images.len());
    for im in &model.images {
        let cam = cams.get(&im.camera).ok_or_else(|| {
            im.place.error(format!(
                "image {} uses camera {}, which {} does not define",
                im.id,
                im.camera,
                model.files[0].display()
            ))
        })?;
        let s = sensor(im, cam, sim, scene_dir);
        if s.id.is_empty() || s.id == "." || s.id == ".." {
            return Err(im.place.error(format!(
                "image {}: NAME '{}' gives no usable sensor id",
                im.id, im.name
            )));
        }
        if let Some(first) = ids.insert(s.id.clone(), im) {
            return Err(im.place.error(format!(
                "image {} ('{}') has the sensor id '{}' of image {} ('{}', {}): ids are the \
                 names without extension and folders, and must differ",
                im.id,
                im.name,
                s.id,
                first.id,
                first.name,
                where_is(&first.place)
            )));
        }
        out.push(s);
    }
    Ok(out)
}

/// The scene's sensors replaced by the COLMAP model in `dir`, mapped by `to_world` (rows of
/// the similarity from the model's frame to the scene's; identity if `None`). The model's
/// files join the scene's inputs.
pub fn replace_sensors(
    scene: &mut Scene,
    dir: &Path,
    to_world: Option<&[[f64; 4]; 4]>,
) -> Result<()> {
    let sim = match to_world {
        Some(m) => Similarity::from_rows(m).map_err(Error::config)?,
        None => Similarity::IDENTITY,
    };
    let model = read(dir)?;
    scene.sensors = sensors(&model, &sim, &scene.dir())?;
    scene.files.extend(model.files);
    Ok(())
}

#[cfg(test)]
mod tests;
