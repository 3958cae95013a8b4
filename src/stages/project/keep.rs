//! The projection's views kept on disk until the outputs re-render them. A re-render needs
//! each view's pixels classified and its corner rays, which the projection cast already (on
//! a room of 1.1M triangles and 16 photos of 512 x 384, 6.3M of the outputs' 8.1M rays). In
//! memory they would hold about 10 MB per such view through every stage in between, so they
//! go to the scratch directory (36 bytes a pixel: about 7 MB per such view), are read once and
//! removed. At most `memory_budget_mib` of them, and only out of the disk the rest of the run
//! does not need ([`allowance`]): a hundred photos of 12 megapixels would take 43 GB, so the
//! views past it are traced again.
//!
//! A view whose file is missing (a resumed run: the scratch directory is emptied when a run
//! opens it), cut short (a full disk: writing is best effort) or made with another camera
//! (refined poses) is traced again, and the outputs are the same bits either way.

use super::View;
use crate::image::Image;
use crate::physics::camera::Camera;
use std::io::{Read, Write};
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

/// What the rest of a run writes to disk from the projection to the end of the outputs
/// (checkpoint snapshots of the state, the refinement's and the noise probe's working stores,
/// the gather's scratch, the output maps), taken as at most this many times the bytes of the
/// state and geometry stores.
pub const RESERVE: u64 = 4;

/// Bytes of views a run may keep ([`Keeper`]): at most `budget`, and only out of the disk the
/// rest of the run does not need: what is `free` (none when unknown) beyond [`RESERVE`] times
/// `stores`, the bytes of the state and geometry stores. Kept views must never be what fills
/// the disk under a checkpoint.
pub fn allowance(budget: u64, free: Option<u64>, stores: u64) -> u64 {
    let spare = free.map_or(0, |f| f.saturating_sub(RESERVE.saturating_mul(stores)));
    budget.min(spare)
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
        let bytes = 4 * View::word_count(&view.camera) as u64;
        if bytes <= self.left {
            self.left -= bytes;
            save(self.dir, index, view);
        }
    }
}

/// Writes `view` as view `index` into `dir`, best effort: a view that is not written is
/// traced again by the outputs. The file is the camera's key, its length first, then the
/// view's words ([`View::words`]), in this machine's byte order (the run that writes it
/// reads it).
pub fn save(dir: &Path, index: usize, view: &View) {
    let key = camera_key(&view.camera);
    let write = || -> std::io::Result<()> {
        std::fs::create_dir_all(dir)?;
        let mut f = std::io::BufWriter::new(std::fs::File::create(file(dir, index))?);
        f.write_all(&(key.len() as u32).to_ne_bytes())?;
        f.write_all(key.as_bytes())?;
        for w in view.words() {
            f.write_all(&w.to_ne_bytes())?;
        }
        f.flush()
    };
    let _ = write();
}

/// View `index` of `camera` and `image` as [`save`] wrote it into `dir`, its file removed;
/// `None` where there is none of that camera and size (see the module doc). The words are
/// read into place, not through a copy of the file's bytes.
pub fn take<'a>(dir: &Path, index: usize, camera: &Camera, image: &'a Image) -> Option<View<'a>> {
    let path = file(dir, index);
    let mut f = std::fs::File::open(&path).ok()?;
    let _ = std::fs::remove_file(&path); // the open file is still read
    let key = camera_key(camera);
    let mut len = [0u8; 4];
    f.read_exact(&mut len).ok()?;
    // the length is checked before anything is allocated for it
    if u32::from_ne_bytes(len) as usize != key.len() {
        return None;
    }
    let mut named = vec![0u8; key.len()];
    if f.read_exact(&mut named).is_err() || named != key.as_bytes() {
        return None;
    }
    let mut words = vec![0u32; View::word_count(camera)];
    f.read_exact(bytemuck::cast_slice_mut(&mut words)).ok()?;
    if f.read(&mut [0u8]).ok()? != 0 {
        return None; // longer than a view of this camera
    }
    View::from_words(camera.clone(), image, &words)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stages::project::view::tests::{
        cbox_first_camera as cbox, grey_with_a_masked_pixel,
    };
    use glam::Vec3;

    /// Views are kept out of the memory budget and the disk beyond the reserve only: none
    /// when the free space is unknown or within the reserve (a disk with room for the working
    /// files and a snapshot or two keeps none).
    #[test]
    fn views_are_kept_only_out_of_the_disk_the_run_can_spare() {
        let (budget, stores) = (1000, 300);
        assert_eq!(allowance(budget, None, stores), 0, "free space unknown");
        assert_eq!(
            allowance(budget, Some(1200), stores),
            0,
            "within the reserve"
        );
        assert_eq!(allowance(budget, Some(1000), stores), 0, "below it");
        assert_eq!(
            allowance(budget, Some(1450), stores),
            250,
            "what is beyond it"
        );
        assert_eq!(
            allowance(budget, Some(9000), stores),
            budget,
            "the budget bounds it"
        );
        assert_eq!(
            allowance(budget, Some(u64::MAX), u64::MAX),
            0,
            "no overflow"
        );
    }

    /// A kept view is the view traced again, bit for bit: kept from the projection's loose
    /// view, read as the outputs read it, and over a photo that masks a pixel the projection's
    /// did not. It is read once; another camera or a file cut short or too long gets `None`
    /// (traced again).
    #[test]
    fn a_kept_view_is_the_view_traced_again() {
        let (scene, accel, cam) = cbox();
        let (w, h) = (cam.width(), cam.height());
        let mut px = grey_with_a_masked_pixel(&cam);
        let img = Image::from_raw(w, h, px.clone());
        let nominal = View::new_with(&scene, &accel, cam.clone(), &img, true);
        let tmp = tempfile::tempdir().unwrap();
        let d = dir(tmp.path());
        let fresh = View::new(&scene, &accel, cam.clone(), &img);
        assert!(fresh.pixels.iter().filter(|p| p.clean).count() > 1000);

        save(&d, 3, &nominal);
        let kept = take(&d, 3, &cam, &img).expect("a kept view");
        assert!(kept.words().eq(fresh.words()), "the kept view differs");
        assert!(!file(&d, 3).exists() && take(&d, 3, &cam, &img).is_none());

        save(&d, 4, &nominal);
        let other = Camera::from_sensor(&scene.sensors[1]);
        assert!(take(&d, 4, &other, &img).is_none(), "another camera");

        save(&d, 5, &nominal);
        let bytes = std::fs::read(file(&d, 5)).unwrap();
        std::fs::write(file(&d, 5), &bytes[..bytes.len() - 4]).unwrap();
        assert!(take(&d, 5, &cam, &img).is_none(), "a file cut short");
        save(&d, 7, &nominal);
        let mut bytes = std::fs::read(file(&d, 7)).unwrap();
        bytes.extend_from_slice(&[0; 4]);
        std::fs::write(file(&d, 7), &bytes).unwrap();
        assert!(take(&d, 7, &cam, &img).is_none(), "a file too long");

        let at = (0..(w * h) as usize)
            .find(|&i| fresh.pixels[i].clean)
            .unwrap();
        px[at] = Vec3::NAN;
        let masking = Image::from_raw(w, h, px);
        save(&d, 6, &nominal);
        let kept = take(&d, 6, &cam, &masking).unwrap();
        let fresh = View::new(&scene, &accel, cam, &masking);
        assert!(!fresh.pixels[at].clean);
        assert!(kept.words().eq(fresh.words()), "a masked pixel");
    }

    /// A keeper keeps the views that fit in its bytes, in the order offered, and no more.
    #[test]
    fn a_keeper_keeps_views_up_to_its_bytes() {
        let (scene, accel, cam) = cbox();
        let (w, h) = (cam.width(), cam.height());
        let img = Image::from_raw(w, h, vec![Vec3::splat(0.4); (w * h) as usize]);
        let view = View::new(&scene, &accel, cam.clone(), &img);
        let one = 4 * view.words().count() as u64;
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
