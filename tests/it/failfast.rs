//! Bad inputs are refused before any heavy work: a truncated photo, a photo of the wrong size
//! and an unlit scene each get the usual one-line located error and exit code 65 before the
//! atlas stage starts, so no geometry store is ever made; photos with non-finite or negative
//! pixels are still accepted, their bad pixels masked and counted.

use glam::Vec3;
use kdmap::image::{read_exr, write_exr_rgb};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A copy of the `cbox` fixture in `dir` (scene, meshes, photos) to corrupt; returns the
/// scene file.
fn cbox_copy(dir: &Path) -> PathBuf {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/cbox");
    let dst = dir.join("cbox");
    for sub in ["meshes", "images"] {
        std::fs::create_dir_all(dst.join(sub)).unwrap();
        for e in std::fs::read_dir(src.join(sub)).unwrap() {
            let p = e.unwrap().path();
            std::fs::copy(&p, dst.join(sub).join(p.file_name().unwrap())).unwrap();
        }
    }
    std::fs::copy(src.join("input.xml"), dst.join("input.xml")).unwrap();
    dst.join("input.xml")
}

fn reconstruct(scene: &Path, out: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kdmap"))
        .args(["reconstruct", scene.to_str().unwrap(), "--out"])
        .arg(out)
        .output()
        .expect("run kdmap")
}

/// The run was refused with exit code 65 and one `error:` line, before the atlas stage:
/// no atlas progress, no geometry store. Returns the error line.
fn refused_before_the_atlas(o: &Output, out: &Path) -> String {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(65), "{err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error: ")).collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(
        !err.contains("[atlas]") && !err.contains("panicked"),
        "{err}"
    );
    let geometry = out.join("checkpoint").join("geometry.tiles");
    assert!(!geometry.exists(), "the atlas was built before the refusal");
    lines[0].to_string()
}

#[test]
fn a_truncated_photo_is_refused_before_the_atlas() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = cbox_copy(tmp.path());
    let photo = scene.parent().unwrap().join("images/cam_train_2.exr");
    let len = std::fs::metadata(&photo).unwrap().len();
    let f = std::fs::OpenOptions::new()
        .write(true)
        .open(&photo)
        .unwrap();
    f.set_len(len * 2 / 3).unwrap();
    let out = tmp.path().join("out");
    let e = refused_before_the_atlas(&reconstruct(&scene, &out), &out);
    assert!(
        e.starts_with(&format!("error: {}: ", photo.display())),
        "{e}"
    );
    assert!(e.contains("OpenEXR"), "{e}");
}

#[test]
fn a_photo_of_another_size_than_its_film_is_refused_before_the_atlas() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = cbox_copy(tmp.path());
    let photo = scene.parent().unwrap().join("images/cam_train_1.exr");
    write_exr_rgb(&photo, 64, 48, &vec![Vec3::splat(0.5); 64 * 48], true).unwrap();
    let out = tmp.path().join("out");
    let e = refused_before_the_atlas(&reconstruct(&scene, &out), &out);
    assert!(
        e.starts_with(&format!("error: {}: ", photo.display())),
        "{e}"
    );
    assert!(e.contains("64x48") && e.contains("256x256"), "{e}");
}

#[test]
fn an_unlit_scene_is_refused_naming_the_scene() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = cbox_copy(tmp.path());
    let xml = std::fs::read_to_string(&scene).unwrap();
    let emitter = "<emitter type=\"area\"><rgb name=\"radiance\" value=\"17, 12, 4\"/></emitter>";
    assert!(xml.contains(emitter), "the fixture's light changed");
    // No emitter at all, then an emitter of zero power.
    for (what, by) in [
        ("no emitter", ""),
        (
            "none of its 1 emitters",
            "<emitter type=\"area\"><rgb name=\"radiance\" value=\"0, 0, 0\"/></emitter>",
        ),
    ] {
        std::fs::write(&scene, xml.replace(emitter, by)).unwrap();
        let out = tmp.path().join("out");
        let e = refused_before_the_atlas(&reconstruct(&scene, &out), &out);
        assert!(
            e.starts_with(&format!("error: {}: ", scene.display())),
            "{e}"
        );
        assert!(e.contains("unlit") && e.contains(what), "{e}");
    }
}

#[test]
fn bad_pixels_are_still_accepted_masked_and_counted() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = cbox_copy(tmp.path());
    let photo = scene.parent().unwrap().join("images/cam_train_0.exr");
    let img = read_exr(&photo).unwrap();
    let mut pixels = img.pixels.clone();
    for (i, p) in pixels.iter_mut().enumerate().take(1000) {
        *p = match i % 3 {
            0 => Vec3::new(f32::NAN, 0.5, 0.5),
            1 => Vec3::new(0.5, f32::INFINITY, 0.5),
            _ => Vec3::new(0.5, 0.5, -1.0),
        };
    }
    write_exr_rgb(&photo, img.width, img.height, &pixels, false).unwrap();
    let cfg = tmp.path().join("run.toml");
    let text = format!(
        "scene = {:?}\n[atlas]\ntexels_per_unit = 16.0\n[projection]\nrefine_passes = 0\n",
        scene
    );
    std::fs::write(&cfg, text).unwrap();
    let out = tmp.path().join("out");
    let o = Command::new(env!("CARGO_BIN_EXE_kdmap"))
        .args([
            "project",
            cfg.to_str().unwrap(),
            "--progress",
            "never",
            "--out",
        ])
        .arg(&out)
        .output()
        .expect("run kdmap");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let note = format!(
        "{}: 1000 non-finite or negative pixels masked",
        photo.display()
    );
    assert!(err.contains(&note), "{err}");
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains(" pixels masked"), "{stdout}");
    assert!(!stdout.contains(" 0 pixels masked"), "{stdout}");
}
