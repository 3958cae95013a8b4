//! Tests of the COLMAP reader: text and binary agree, the pose convention against a rotation
//! made by hand, the sensor ids, and one-line refusals of malformed files.

use super::*;
use crate::physics::camera::Camera;
use crate::scene::LensModel;
use glam::Vec3;

/// A camera as written: id, model, width, height, parameters.
type Cam = (u32, LensModel, u64, u64, Vec<f64>);
/// An image as written: id, QW QX QY QZ TX TY TZ, camera id, name.
type Img = (u32, [f64; 7], u32, &'static str);

fn sample() -> (Vec<Cam>, Vec<Img>) {
    let s = std::f64::consts::FRAC_1_SQRT_2;
    let cams = vec![
        (
            1,
            LensModel::SimplePinhole,
            100,
            80,
            vec![100.0, 50.0, 40.0],
        ),
        (2, LensModel::Pinhole, 64, 48, vec![70.0, 72.5, 31.0, 25.5]),
        (
            3,
            LensModel::SimpleRadial,
            64,
            48,
            vec![60.0, 32.0, 24.0, -0.05],
        ),
        (
            4,
            LensModel::Radial,
            64,
            48,
            vec![60.0, 32.0, 24.0, -0.05, 0.01],
        ),
        (
            5,
            LensModel::OpenCv,
            64,
            48,
            vec![61.0, 59.0, 33.0, 23.0, -0.05, 0.01, 0.001, -0.002],
        ),
    ];
    let imgs = vec![
        (7, [s, 0.0, s, 0.0, 0.0, 0.0, 2.0], 1, "front.exr"),
        (3, [1.0, 0.0, 0.0, 0.0, 0.5, -0.25, 4.0], 5, "left/0001.jpg"),
        (9, [0.5, 0.5, 0.5, 0.5, 1.0, 2.0, 3.0], 3, "b.png"),
    ];
    (cams, imgs)
}

fn write_text(dir: &Path, cams: &[Cam], imgs: &[Img]) {
    let mut c = String::from("# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n");
    for (id, m, w, h, p) in cams {
        let ps: Vec<String> = p.iter().map(|x| format!("{x:?}")).collect();
        c += &format!("{id} {} {w} {h} {}\n", m.name(), ps.join(" "));
    }
    std::fs::write(dir.join("cameras.txt"), c).unwrap();
    let mut i = String::from("# Image list with two lines of data per image:\n");
    for (k, (id, pose, cam, name)) in imgs.iter().enumerate() {
        let ps: Vec<String> = pose.iter().map(|x| format!("{x:?}")).collect();
        i += &format!("{id} {} {cam} {name}\n", ps.join(" "));
        i += match k {
            0 => "\n",
            _ => "12.5 30.25 -1 40.0 41.0 17\n",
        };
    }
    std::fs::write(dir.join("images.txt"), i).unwrap();
}

fn write_bin(dir: &Path, cams: &[Cam], imgs: &[Img]) {
    let mut c = (cams.len() as u64).to_le_bytes().to_vec();
    for (id, m, w, h, p) in cams {
        c.extend(id.to_le_bytes());
        c.extend(m.id().to_le_bytes());
        c.extend(w.to_le_bytes());
        c.extend(h.to_le_bytes());
        p.iter().for_each(|x| c.extend(x.to_le_bytes()));
    }
    std::fs::write(dir.join("cameras.bin"), c).unwrap();
    let mut i = (imgs.len() as u64).to_le_bytes().to_vec();
    for (k, (id, pose, cam, name)) in imgs.iter().enumerate() {
        i.extend(id.to_le_bytes());
        pose.iter().for_each(|x| i.extend(x.to_le_bytes()));
        i.extend(cam.to_le_bytes());
        i.extend(name.as_bytes());
        i.push(0);
        i.extend((k as u64).to_le_bytes());
        for j in 0..k {
            i.extend((j as f64).to_le_bytes());
            i.extend(1.5f64.to_le_bytes());
            i.extend(u64::MAX.to_le_bytes());
        }
    }
    std::fs::write(dir.join("images.bin"), i).unwrap();
}

fn dir_with(text: bool, cams: &[Cam], imgs: &[Img]) -> tempfile::TempDir {
    let d = tempfile::tempdir().unwrap();
    match text {
        true => write_text(d.path(), cams, imgs),
        false => write_bin(d.path(), cams, imgs),
    }
    d
}

fn err(r: Result<Model>) -> String {
    let e = r.unwrap_err().to_string();
    assert!(!e.contains('\n'), "{e}");
    e
}

#[test]
fn text_and_binary_readers_agree() {
    let (cams, imgs) = sample();
    let (t, b) = (dir_with(true, &cams, &imgs), dir_with(false, &cams, &imgs));
    let (mt, mb) = (read(t.path()).unwrap(), read(b.path()).unwrap());
    assert_eq!((mt.format, mb.format), (Format::Text, Format::Binary));
    assert_eq!(mt.cameras.len(), 5);
    assert_eq!(mt.images.len(), 3);
    for (a, b) in mt.cameras.iter().zip(&mb.cameras) {
        assert_eq!(
            (a.id, a.width, a.height, &a.lens),
            (b.id, b.width, b.height, &b.lens)
        );
    }
    for (a, b) in mt.images.iter().zip(&mb.images) {
        assert_eq!(
            (a.id, a.qvec, a.tvec, a.camera),
            (b.id, b.qvec, b.tvec, b.camera)
        );
        assert_eq!(a.name, b.name);
    }
    assert_eq!(mt.images[1].name, "left/0001.jpg");
    assert_eq!(mt.cameras[4].lens.params[7], -0.002);
    assert_eq!(mt.images[0].place.line, Some(2));
    assert_eq!(mb.images[0].place.byte, Some(8));
    // With both pairs present the binary one is read, as COLMAP does.
    write_text(b.path(), &cams[..1], &[]);
    assert_eq!(read(b.path()).unwrap().format, Format::Binary);
}

/// World-to-camera `q = (cos 45, 0, sin 45, 0)` is a quarter turn about y: `R = [[0, 0, 1],
/// [0, 1, 0], [-1, 0, 0]]`. With `t = (0, 0, 2)` the centre is `-R^T t = (2, 0, 0)`, the
/// camera looks along world -x, its right (x) is world +z and its down (y) world +y. So with
/// f = 100 and the principal point (50, 40): (-3, 0, 0) is 5 ahead, at (50, 40); (-3, 0, 1)
/// is 1 right, at (70, 40); (-3, 1, 0) is 1 down, at (50, 60). A similarity moves the points
/// and the camera together: the pixels stay.
#[test]
fn quaternion_convention_matches_a_rotation_made_by_hand() {
    let (cams, imgs) = sample();
    let d = dir_with(true, &cams, &imgs);
    let model = read(d.path()).unwrap();
    let rows = [
        [0.0, -2.0, 0.0, 1.0],
        [2.0, 0.0, 0.0, 2.0],
        [0.0, 0.0, 2.0, 3.0],
        [0.0, 0.0, 0.0, 1.0],
    ];
    for sim in [Similarity::IDENTITY, Similarity::from_rows(&rows).unwrap()] {
        let s = sensors(&model, &sim, Path::new("/scene")).unwrap();
        assert_eq!(s[0].id, "front");
        assert_eq!(
            s[0].photo.as_deref(),
            Some(Path::new("/scene/images/front.exr"))
        );
        let cam = Camera::from_sensor(&s[0]);
        let map = |p: [f64; 3]| sim.point(DVec3::from(p)).as_vec3();
        assert!((cam.position() - map([2.0, 0.0, 0.0])).length() < 1e-5);
        let r = sim.rotation.as_mat3();
        assert!((cam.forward() - r * Vec3::new(-1.0, 0.0, 0.0)).length() < 1e-6);
        for (p, want) in [
            ([-3.0, 0.0, 0.0], Vec2::new(50.0, 40.0)),
            ([-3.0, 0.0, 1.0], Vec2::new(70.0, 40.0)),
            ([-3.0, 1.0, 0.0], Vec2::new(50.0, 60.0)),
        ] {
            let px = cam.project(map(p)).unwrap();
            assert!((px - want).length() < 1e-3, "{p:?}: {px} vs {want}");
        }
    }
}

#[test]
fn sensor_ids_drop_the_extension_and_flatten_folders() {
    assert_eq!(sensor_id("left/0001.jpg"), "left_0001");
    assert_eq!(sensor_id("a.b/c"), "a.b_c");
    assert_eq!(sensor_id("x.tar.gz"), "x.tar");
    assert_eq!(sensor_id(".hidden"), ".hidden");
    assert_eq!(sensor_id("dir\\IMG_1.JPG"), "dir_IMG_1");
    let (cams, mut imgs) = sample();
    imgs[2].3 = "left_0001.png";
    let d = dir_with(true, &cams, &imgs);
    let m = read(d.path()).unwrap();
    let e = sensors(&m, &Similarity::IDENTITY, Path::new("."))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("images.txt (line 6): image 9 ('left_0001.png') has the sensor id"),
        "{e}"
    );
    assert!(e.contains("of image 3 ('left/0001.jpg', line 4)"), "{e}");
}

/// Malformed text files: one line naming the file and line, never a panic.
#[test]
fn malformed_text_is_refused_in_one_located_line() {
    let (cams, imgs) = sample();
    let cases: [(&str, &str, &str); 9] = [
        ("cameras.txt", "1 FULL_OPENCV 64 48 1 2 3 4 5 6 7 8 9 10 11 12\n", "cameras.txt (line 1): camera 1: camera model FULL_OPENCV is not supported (kdmap reads SIMPLE_PINHOLE"),
        ("cameras.txt", "# c\n1 FISHY 64 48 1\n", "cameras.txt (line 2): camera 1: unknown camera model FISHY"),
        ("cameras.txt", "1 PINHOLE 64 48 1 2 3\n", "(line 1): camera 1: PINHOLE takes 4 parameters (fx, fy, cx, cy), not 3"),
        ("cameras.txt", "1 PINHOLE 64 x 1 2 3 4\n", "(line 1): HEIGHT 'x' is not a whole number"),
        ("cameras.txt", "1 SIMPLE_RADIAL 640 480 100 320 240 -0.9\n", "camera 1: the SIMPLE_RADIAL distortion (f 100, cx 320, cy 240, k -0.9) folds over the 640x480 image"),
        ("images.txt", "1 1 0 0 0 0 0 0 1\n", "images.txt (line 1): missing NAME (field 10)"),
        ("images.txt", "1 1 0 0 zero 0 0 0 1 a.exr\n", "(line 1): QZ 'zero' is not a number"),
        ("images.txt", "1 0.9 0 0 0 0 0 0 1 a.exr\n", "(line 1): image 1: QW QX QY QZ = [0.9, 0.0, 0.0, 0.0] is not a unit quaternion"),
        ("images.txt", "1 1 0 0 0 0 0 0 1 a.exr\n2 1 0 0 0 0 0 0 1 b.exr\n\n", "images.txt (line 2): expected the POINTS2D line of image 1"),
    ];
    for (file, content, want) in cases {
        let d = dir_with(true, &cams, &imgs);
        std::fs::write(d.path().join(file), content).unwrap();
        let e = err(read(d.path()));
        assert!(e.contains(want), "{e}\n  wanted: {want}");
    }
    let d = dir_with(true, &cams, &imgs);
    std::fs::write(
        d.path().join("images.txt"),
        "1 1 0 0 0 0 0 0 4 a.exr\n\n1 1 0 0 0 0 0 0 1 b.exr\n",
    )
    .unwrap();
    let e = err(read(d.path()));
    assert!(
        e.contains("images.txt (line 3): image 1 is defined twice (first at line 1)"),
        "{e}"
    );
    std::fs::write(d.path().join("images.txt"), "1 1 0 0 0 0 0 0 42 a.exr\n").unwrap();
    let m = read(d.path()).unwrap();
    let e = sensors(&m, &Similarity::IDENTITY, Path::new("."))
        .unwrap_err()
        .to_string();
    assert!(e.contains("(line 1): image 1 uses camera 42, which"), "{e}");
    std::fs::write(
        d.path().join("cameras.txt"),
        b"1 PINHOLE 64 48 1 2 3 4\n\xff\n",
    )
    .unwrap();
    assert!(err(read(d.path())).contains("cameras.txt (line 2): not UTF-8 text"));
}

/// Malformed binary files: refused at the record's byte, whatever the truncation; an unknown
/// model is named.
#[test]
fn malformed_binary_is_refused_in_one_located_line() {
    let (cams, imgs) = sample();
    let d = dir_with(false, &cams, &imgs);
    for file in ["cameras.bin", "images.bin"] {
        let full = std::fs::read(d.path().join(file)).unwrap();
        for cut in 0..full.len() {
            std::fs::write(d.path().join(file), &full[..cut]).unwrap();
            let e = err(read(d.path()));
            assert!(e.contains(file) && e.contains("byte"), "{cut}: {e}");
        }
        let mut more = full.clone();
        more.push(0);
        std::fs::write(d.path().join(file), &more).unwrap();
        let e = err(read(d.path()));
        assert!(e.contains("1 bytes after the last record"), "{e}");
        std::fs::write(d.path().join(file), &full).unwrap();
    }
    let mut full_opencv = cams.clone();
    full_opencv[0] = (1, LensModel::OpenCv, 64, 48, vec![1.0; 8]);
    write_bin(d.path(), &full_opencv, &imgs);
    let mut bytes = std::fs::read(d.path().join("cameras.bin")).unwrap();
    bytes[12..16].copy_from_slice(&6i32.to_le_bytes());
    std::fs::write(d.path().join("cameras.bin"), &bytes).unwrap();
    let e = err(read(d.path()));
    assert!(
        e.contains("cameras.bin, byte 8: camera 1: camera model FULL_OPENCV is not supported"),
        "{e}"
    );
    bytes[12..16].copy_from_slice(&99i32.to_le_bytes());
    std::fs::write(d.path().join("cameras.bin"), &bytes).unwrap();
    assert!(err(read(d.path())).contains("unknown camera model id 99"));
    let mut huge = u64::MAX.to_le_bytes().to_vec();
    huge.extend([0u8; 64]);
    std::fs::write(d.path().join("cameras.bin"), &huge).unwrap();
    assert!(err(read(d.path())).contains("declares 18446744073709551615 cameras"));
}

#[test]
fn a_directory_without_a_model_is_refused() {
    let d = tempfile::tempdir().unwrap();
    std::fs::create_dir(d.path().join("0")).unwrap();
    let e = err(read(d.path()));
    assert!(
        e.contains("no COLMAP sparse model here") && e.contains("try .../0"),
        "{e}"
    );
    let e = read(&d.path().join("nope")).unwrap_err();
    assert_eq!(e.exit_code(), crate::base::error::exit::MISSING);
}
