//! 8-bit photos end to end, made in the tests from the Cornell box's EXR photos (whose
//! radiance fits in [0, 1] but for the light itself, so "known" exposure holds at scale 1):
//! PNG and JPEG photos found beside a Mitsuba scene and read through `match_views` and
//! `read_photos`, a glTF camera's film taken from its PNG, two photos of one sensor and a
//! malformed JPEG refused before any work, and a reconstruction from 8-bit PNGs whose mean
//! albedo per shape is the EXR run's within 1% (measured: 0.13% at most).

use glam::Vec3;
use kdmap::atlas::context::{match_views, read_photos};
use kdmap::base::progress::Mode;
use kdmap::config::{Config, Overrides};
use kdmap::image::{read_exr, srgb8, Image, DARK_CODE};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const CAMS: [&str; 3] = ["cam_train_0", "cam_train_1", "cam_train_2"];

fn fixture(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(rel)
}

/// The 8-bit sRGB codes of the cbox photo of `cam` (rounded, clipped at 1).
fn codes_of(cam: &str) -> (u32, u32, Vec<[u8; 3]>) {
    let img = read_exr(fixture(&format!("cbox/images/{cam}.exr"))).unwrap();
    let codes = img.pixels.iter().map(|&p| {
        let c = srgb8(p, 1.0);
        [c[0], c[1], c[2]]
    });
    (img.width, img.height, codes.collect())
}

/// The cbox photo of `cam` written as an 8-bit sRGB PNG, or a JPEG of quality 95.
fn write_8bit(cam: &str, path: &Path) {
    let (w, h, codes) = codes_of(cam);
    let img = image::RgbImage::from_fn(w, h, |x, y| image::Rgb(codes[(y * w + x) as usize]));
    if path.extension().is_some_and(|e| e == "png") {
        img.save(path).unwrap();
    } else {
        let f = std::fs::File::create(path).unwrap();
        let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(f, 95);
        img.write_with_encoder(enc).unwrap();
    }
}

/// A directory holding the cbox scene file (and its meshes when `meshes`) and
/// `images/<cam>.<ext>` for each (cam, ext) of `photos`; returns the scene file.
fn cbox_with(dir: &Path, photos: &[(&str, &str)], meshes: bool) -> PathBuf {
    std::fs::create_dir_all(dir.join("images")).unwrap();
    std::fs::copy(fixture("cbox/input.xml"), dir.join("input.xml")).unwrap();
    if meshes {
        std::fs::create_dir_all(dir.join("meshes")).unwrap();
        for e in std::fs::read_dir(fixture("cbox/meshes")).unwrap() {
            let p = e.unwrap().path();
            std::fs::copy(&p, dir.join("meshes").join(p.file_name().unwrap())).unwrap();
        }
    }
    for (cam, ext) in photos {
        let p = dir.join("images").join(format!("{cam}.{ext}"));
        match *ext {
            "exr" => {
                std::fs::copy(fixture(&format!("cbox/images/{cam}.exr")), p).unwrap();
            }
            _ => write_8bit(cam, &p),
        }
    }
    dir.join("input.xml")
}

#[test]
fn png_and_jpeg_photos_are_found_and_read_through_the_response() {
    let tmp = tempfile::tempdir().unwrap();
    let photos = [
        ("cam_train_0", "png"),
        ("cam_train_1", "JPG"),
        ("cam_train_2", "exr"),
    ];
    let scene = cbox_with(tmp.path(), &photos, false);
    let cfg = Config::for_scene(scene);
    let outline = kdmap::scene::load_outline(&cfg).unwrap();
    let views = match_views(&outline, &cfg, Mode::Quiet).unwrap();
    let found: Vec<String> = (views.iter())
        .map(|(_, p)| p.file_name().unwrap().to_string_lossy().into())
        .collect();
    assert_eq!(
        found,
        ["cam_train_0.png", "cam_train_1.JPG", "cam_train_2.exr"]
    );
    let read = read_photos(&outline, &views, &cfg.response, Mode::Quiet).unwrap();
    let exr: Vec<_> = (CAMS.iter())
        .map(|c| read_exr(fixture(&format!("cbox/images/{c}.exr"))).unwrap())
        .collect();
    assert_eq!(read[2], exr[2], "the EXR as it is");
    check_png(&read[0], &exr[0], &codes_of("cam_train_0").2);
    check_jpeg(&read[1], &exr[1], &views[1].1);
}

/// The PNG `png` of the photo `truth`, whose codes are `codes`: every pixel within half a
/// code of its radiance, the masks as the codes say.
fn check_png(png: &Image, truth: &Image, codes: &[[u8; 3]]) {
    let mut masked = 0;
    for (i, c) in codes.iter().enumerate() {
        let clipped = c.contains(&255);
        let dark = c.iter().all(|&c| c as u32 <= DARK_CODE);
        assert_eq!(png.valid[i], !(clipped || dark), "pixel {i} {c:?}");
        masked += usize::from(clipped || dark);
        if png.valid[i] {
            within_half_a_code(png.pixels[i], truth.pixels[i], i);
        }
    }
    assert_eq!(png.masked, masked);
    let clipped = codes.iter().filter(|c| c.contains(&255)).count();
    assert!(
        clipped > 100 && clipped < 2000,
        "{clipped}: the light and its edge"
    );
    // the pixels that see no surface (radiance 0) are among the near-black ones
    let black = (truth.pixels.iter())
        .filter(|p| p.max_element() == 0.0)
        .count();
    assert!(masked - clipped >= black, "{masked} {clipped} {black}");
}

/// The JPEG `jpg` (file `path`) of the photo `truth`: its own clipped pixels and their ring,
/// and its near-black ones, masked; the rest agrees with `truth` on average.
fn check_jpeg(jpg: &Image, truth: &Image, path: &Path) {
    let decoded = image::open(path).unwrap().into_rgb8();
    let code = |x: i64, y: i64| {
        decoded
            .get_pixel(x.clamp(0, 255) as u32, y.clamp(0, 255) as u32)
            .0
    };
    let mut ring = 0;
    for (i, &valid) in jpg.valid.iter().enumerate() {
        let (x, y) = ((i % 256) as i64, (i / 256) as i64);
        let near_clip = (-1..=1).any(|dy| (-1..=1).any(|dx| code(x + dx, y + dy).contains(&255)));
        let dark = code(x, y).iter().all(|&c| c as u32 <= DARK_CODE);
        assert_eq!(valid, !(near_clip || dark), "pixel ({x}, {y})");
        ring += usize::from(near_clip && !code(x, y).contains(&255));
    }
    assert!(
        ring > 50,
        "{ring} pixels masked for being beside a clipped one"
    );
    let mean = |img: &Image| {
        let (s, n) = (img.pixels.iter().zip(&jpg.valid))
            .filter(|(_, &v)| v)
            .fold((Vec3::ZERO, 0), |(s, n), (p, _)| (s + *p, n + 1));
        s / n as f32
    };
    let (a, b) = (mean(jpg), mean(truth));
    assert!(((a - b) / b).abs().max_element() < 0.02, "{a} vs {b}");
}

/// `got` (decoded from the 8-bit code of `want`) is `want` to within half a code step of the
/// sRGB curve, per channel.
fn within_half_a_code(got: Vec3, want: Vec3, i: usize) {
    let enc = |v: f32| {
        if v <= 0.003_130_8 {
            12.92 * v
        } else {
            1.055 * v.powf(1.0 / 2.4) - 0.055
        }
    };
    for k in 0..3 {
        let (g, w) = (enc(got[k]) * 255.0, enc(want[k].clamp(0.0, 1.0)) * 255.0);
        assert!(
            (g - w).abs() <= 0.5 + 1e-3,
            "pixel {i} channel {k}: {g} vs {w}"
        );
    }
}

#[test]
fn a_gltf_camera_takes_its_film_from_its_png_or_jpeg() {
    let tmp = tempfile::tempdir().unwrap();
    for f in ["cbox.gltf", "cbox.bin"] {
        std::fs::copy(fixture(&format!("cbox-gltf/{f}")), tmp.path().join(f)).unwrap();
    }
    std::fs::create_dir(tmp.path().join("images")).unwrap();
    write_8bit("cam_train_0", &tmp.path().join("images/cam_train_0.jpeg"));
    write_8bit("cam_train_1", &tmp.path().join("cam_train_1.png"));
    let run = tmp.path().join("run.toml");
    std::fs::write(
        &run,
        "scene = \"cbox.gltf\"\n[views]\ncam_train_1 = \"cam_train_1.png\"\n",
    )
    .unwrap();
    let cfg = Config::load(&run, &Overrides::default()).unwrap();
    let scene = kdmap::scene::load_outline(&cfg).unwrap();
    let film = |id: &str| {
        let s = scene.sensors.iter().find(|s| s.id == id).unwrap();
        (s.width, s.height)
    };
    assert_eq!(film("cam_train_0"), (256, 256), "images/<node name>.jpeg");
    assert_eq!(film("cam_train_1"), (256, 256), "a [views] path");
    // a second photo of one camera is refused when the scene is read
    write_8bit("cam_train_0", &tmp.path().join("images/cam_train_0.png"));
    let e = kdmap::scene::load_outline(&cfg).unwrap_err().to_string();
    assert!(
        e.contains("'cam_train_0' has 2 photos (cam_train_0.jpeg, cam_train_0.png)"),
        "{e}"
    );
}

fn kdmap(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kdmap"))
        .args(args)
        .output()
        .expect("run kdmap")
}

/// The one `error:` line of a run refused as bad input (exit code 65) before the atlas.
fn refused(o: &Output) -> String {
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(65), "{err}");
    assert!(
        !err.contains("[atlas]") && !err.contains("panicked"),
        "{err}"
    );
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error: ")).collect();
    assert_eq!(lines.len(), 1, "{err}");
    lines[0].to_string()
}

#[test]
fn two_photos_of_a_sensor_and_a_malformed_jpeg_are_refused_naming_them() {
    let tmp = tempfile::tempdir().unwrap();
    let photos = [
        ("cam_train_0", "exr"),
        ("cam_train_0", "jpg"),
        ("cam_train_1", "exr"),
    ];
    let scene = cbox_with(tmp.path(), &photos, true);
    let out = tmp.path().join("out");
    let args = [
        "reconstruct",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    let e = refused(&kdmap(&args));
    let images = tmp.path().join("images");
    let want = format!(
        "error: {}: sensor 'cam_train_0' has 2 photos (cam_train_0.exr, cam_train_0.jpg): \
         ambiguous",
        images.display()
    );
    assert!(e.starts_with(&want), "{e}");

    std::fs::remove_file(images.join("cam_train_0.exr")).unwrap();
    let jpg = images.join("cam_train_0.jpg");
    let bytes = std::fs::read(&jpg).unwrap();
    std::fs::write(&jpg, &bytes[..bytes.len() / 2]).unwrap();
    let e = refused(&kdmap(&args));
    let want = format!("error: {}: not a readable JPEG file: ", jpg.display());
    assert!(e.starts_with(&want), "{e}");
}

/// A run config for `scene` with `views` (sensor id -> photo), at CI size: the photon
/// method's small settings of the resume tests, no projection refinement; the photos' gains
/// known (the PNGs hold the EXRs' values, so the runs must agree without any estimate).
fn write_run(dir: &Path, name: &str, views: &[(&str, PathBuf)]) -> PathBuf {
    let mut text = format!(
        "scene = {:?}\n[atlas]\ntexels_per_unit = 24.0\n[direct]\narea_samples = 4\n\
         [projection]\nrefine_passes = 0\n[photons]\nbatch_size = 1024\n\
         [solver]\nmethod = \"photons\"\n[views]\nexposure = \"known\"\n",
        fixture("cbox/input.xml")
    );
    for (id, p) in views {
        text.push_str(&format!("{id} = {p:?}\n"));
    }
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn reconstruct(cfg: &Path, out: &Path) -> String {
    let o = kdmap(&[
        "reconstruct",
        cfg.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--photons",
        "20000",
        "--iterations",
        "3",
        "--threads",
        "2",
        "--progress",
        "never",
    ]);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{err}");
    err
}

/// Per reconstructed shape, the mean albedo over the texels both runs observed.
fn mean_albedo(a: &Path, b: &Path) -> BTreeMap<String, (Vec3, Vec3)> {
    let shapes = [
        "floor",
        "ceiling",
        "back",
        "left",
        "right",
        "short_box",
        "tall_box",
    ];
    let read = |out: &Path, f: String| read_exr(out.join(f)).unwrap().pixels;
    let mut means = BTreeMap::new();
    for id in shapes {
        let (ka, kb) = (
            read(a, format!("textures/{id}_albedo.exr")),
            read(b, format!("textures/{id}_albedo.exr")),
        );
        let (ca, cb) = (
            read(a, format!("maps/{id}_coverage.exr")),
            read(b, format!("maps/{id}_coverage.exr")),
        );
        let both: Vec<usize> = (0..ka.len())
            .filter(|&i| ca[i].x > 0.0 && cb[i].x > 0.0)
            .collect();
        assert!(both.len() > 100, "{id}: {} texels", both.len());
        let mean = |k: &[Vec3]| both.iter().map(|&i| k[i]).sum::<Vec3>() / both.len() as f32;
        means.insert(id.to_string(), (mean(&ka), mean(&kb)));
    }
    means
}

#[test]
fn albedo_from_8bit_pngs_is_the_exr_runs_within_1_percent() {
    let tmp = tempfile::tempdir().unwrap();
    let views: Vec<(&str, PathBuf)> = (CAMS.iter())
        .map(|c| (*c, tmp.path().join(format!("{c}.png"))))
        .collect();
    for (c, p) in &views {
        write_8bit(c, p);
    }
    let png_cfg = write_run(tmp.path(), "png.toml", &views);
    let exr_views: Vec<(&str, PathBuf)> = (CAMS.iter())
        .map(|c| (*c, fixture(&format!("cbox/images/{c}.exr"))))
        .collect();
    let exr_cfg = write_run(tmp.path(), "exr.toml", &exr_views);
    let (png_out, exr_out) = (tmp.path().join("png"), tmp.path().join("exr"));
    let err = reconstruct(&png_cfg, &png_out);
    assert_eq!(
        err.matches("8-bit photos have no absolute scale").count(),
        1,
        "{err}"
    );
    assert!(
        err.contains("cam_train_0.png: ") && err.contains("clipped or near-black pixels masked")
    );
    let exr_err = reconstruct(&exr_cfg, &exr_out);
    assert!(!exr_err.contains("8-bit"), "{exr_err}");
    for (id, (png, exr)) in mean_albedo(&png_out, &exr_out) {
        let rel = (png - exr) / exr;
        eprintln!("{id}: 8-bit {png:.4} EXR {exr:.4} relative {rel:+.4}");
        assert!(rel.abs().max_element() < 0.01, "{id}: {png} vs {exr}");
    }
}
