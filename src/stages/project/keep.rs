//! The projection's views kept on disk until the outputs re-render them. A re-render needs
//! each view's pixels classified and its corner rays, which the projection cast already (on
//! a room of 1.1M triangles and 16 photos of 512 x 384, 6.3M of the outputs' 8.1M rays). In
//! memory they would hold about 10 MB per such view through every stage in between, so they
//! go to the scratch directory (36 bytes a pixel: about 7 MB per such view), are read once and
//! removed. At most `memory_budget_mib` of them ([`Keeper`]): a hundred photos of 12
//! megapixels would take 43 GB, so the views past it are traced again.
//!
//! A view whose file is missing (a resumed run: the scratch directory is emptied when a run
//! opens it), cut short (a full disk: writing is best effort) or made with another camera
//! (refined poses) is traced again, and the outputs are the same bits either way.

use super::View;
use crate::image::Image;
use crate::physics::camera::Camera;
use std::io::Write;
use std::path::{Path, PathBuf};

/// The directory of the kept views under a scratch directory.
pub fn dir(scratch: &Path) -> PathBuf {
    scratch.join("views")
}

fn file(dir: &Path, index: usize) -> PathBuf {
    dir.join(format!("{index}.view"))
}

/// The camera as a file names it: its every field, each float to the bit (`Debug` writes the
/// shortest decimal that reads back as the same float).
fn camera_key(camera: &Camera) -> String {
    format!("{camera:?}")
}

/// Keeps views in a directory up to a number of bytes, in the order offered.
pub struct Keeper<'d> {
    dir: &'d Path,
    left: u64,
}

impl<'d> Keeper<'d> {
    pub fn new(dir: &'d Path, bytes: u64) -> Keeper<'d> {
        Keeper { dir, left: bytes }
    }

    /// Keeps `view` as view `index` ([`save`]) if it fits in what is left.
    pub fn offer(&mut self, index: usize, view: &View) {
        let (w, h) = (view.camera.width() as u64, view.camera.height() as u64);
        let bytes = 4 * (w * h * 6 + (w + 1) * (h + 1) * 3);
        if bytes <= self.left {
            self.left -= bytes;
            save(self.dir, index, view);
        }
    }
}

/// Writes `view` as view `index` into `dir`, best effort: a view that is not written is
/// traced again by the outputs. The file is the camera's key, its length first, then the
/// view's words ([`View::to_words`]), in this machine's byte order (the run that writes it
/// reads it).
pub fn save(dir: &Path, index: usize, view: &View) {
    let key = camera_key(&view.camera);
    let words = view.to_words();
    let write = || -> std::io::Result<()> {
        std::fs::create_dir_all(dir)?;
        let mut f = std::io::BufWriter::new(std::fs::File::create(file(dir, index))?);
        f.write_all(&(key.len() as u32).to_ne_bytes())?;
        f.write_all(key.as_bytes())?;
        f.write_all(bytemuck::cast_slice(&words))?;
        f.flush()
    };
    let _ = write();
}

/// View `index` of `camera` and `image` as [`save`] wrote it into `dir`, its file removed;
/// `None` where there is none of that camera and size (see the module doc).
pub fn take<'a>(dir: &Path, index: usize, camera: &Camera, image: &'a Image) -> Option<View<'a>> {
    let path = file(dir, index);
    let bytes = std::fs::read(&path).ok()?;
    let _ = std::fs::remove_file(&path);
    let key = camera_key(camera);
    let len = u32::from_ne_bytes(bytes.get(..4)?.try_into().ok()?) as usize;
    let rest = bytes.get(4..)?;
    if rest.get(..len)? != key.as_bytes() || (rest.len() - len) % 4 != 0 {
        return None;
    }
    let words: Vec<u32> = bytemuck::pod_collect_to_vec(&rest[len..]);
    View::from_words(camera.clone(), image, &words)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stages::project::view::tests::cbox_first_camera as cbox;
    use glam::Vec3;

    /// A kept view is the view traced again, bit for bit: kept from the projection's loose
    /// view, read as the outputs read it, and over a photo that masks a pixel the projection's
    /// did not. It is read once; another camera or a file cut short gets `None` (traced again).
    #[test]
    fn a_kept_view_is_the_view_traced_again() {
        let (scene, accel, cam) = cbox();
        let (w, h) = (cam.width(), cam.height());
        let mut px = vec![Vec3::splat(0.4); (w * h) as usize];
        px[(37 * w + 101) as usize] = Vec3::NAN;
        let img = Image::from_raw(w, h, px.clone());
        let nominal = View::new_with(&scene, &accel, cam.clone(), &img, true);
        let tmp = tempfile::tempdir().unwrap();
        let d = dir(tmp.path());
        let fresh = View::new(&scene, &accel, cam.clone(), &img);
        assert!(fresh.pixels.iter().filter(|p| p.clean).count() > 1000);

        save(&d, 3, &nominal);
        let kept = take(&d, 3, &cam, &img).expect("a kept view");
        assert!(kept.to_words() == fresh.to_words(), "the kept view differs");
        assert!(!file(&d, 3).exists() && take(&d, 3, &cam, &img).is_none());

        save(&d, 4, &nominal);
        let other = Camera::from_sensor(&scene.sensors[1]);
        assert!(take(&d, 4, &other, &img).is_none(), "another camera");

        save(&d, 5, &nominal);
        let bytes = std::fs::read(file(&d, 5)).unwrap();
        std::fs::write(file(&d, 5), &bytes[..bytes.len() - 4]).unwrap();
        assert!(take(&d, 5, &cam, &img).is_none(), "a file cut short");

        let at = (0..(w * h) as usize)
            .find(|&i| fresh.pixels[i].clean)
            .unwrap();
        px[at] = Vec3::NAN;
        let masking = Image::from_raw(w, h, px);
        save(&d, 6, &nominal);
        let kept = take(&d, 6, &cam, &masking).unwrap();
        let fresh = View::new(&scene, &accel, cam, &masking);
        assert!(!fresh.pixels[at].clean);
        assert!(kept.to_words() == fresh.to_words(), "a masked pixel");
    }

    /// A keeper keeps the views that fit in its bytes, in the order offered, and no more.
    #[test]
    fn a_keeper_keeps_views_up_to_its_bytes() {
        let (scene, accel, cam) = cbox();
        let (w, h) = (cam.width(), cam.height());
        let img = Image::from_raw(w, h, vec![Vec3::splat(0.4); (w * h) as usize]);
        let view = View::new(&scene, &accel, cam.clone(), &img);
        let one = 4 * view.to_words().len() as u64;
        let tmp = tempfile::tempdir().unwrap();
        let mut keeper = Keeper::new(tmp.path(), 2 * one + one / 2);
        for i in 0..4 {
            keeper.offer(i, &view);
        }
        let kept: Vec<bool> = (0..4)
            .map(|i| take(tmp.path(), i, &cam, &img).is_some())
            .collect();
        assert_eq!(kept, [true, true, false, false]);
    }
}
