//! COLMAP cameras as a scene's sensors, end to end: a COLMAP model written from the Cornell
//! box's own cameras (no distortion), in a frame a known similarity away, must give the same
//! cameras and the same reconstruction as the Mitsuba sensors; `inspect`, `scene.xml` and the
//! refusals of the command line say what the model is.

use glam::{DMat3, DVec3, Vec3};
use kdmap::base::progress::Mode;
use kdmap::config::{Config, Overrides, Preset, Similarity};
use kdmap::physics::camera::{fov_x_degrees, Camera};
use kdmap::scene::Sensor;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

fn fixture(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(p)
}

/// The similarity from the model's frame to the scene's: scale 0.5, 40 degrees about
/// (1, 2, 3), translated by (0.3, -1, 2); as rows.
fn rows() -> [[f64; 4]; 4] {
    let r = DMat3::from_axis_angle(DVec3::new(1.0, 2.0, 3.0).normalize(), 40f64.to_radians());
    let a = r * 0.5;
    let t = [0.3, -1.0, 2.0];
    let mut m = [[0.0; 4]; 4];
    for (i, row) in m.iter_mut().enumerate().take(3) {
        *row = [a.col(0)[i], a.col(1)[i], a.col(2)[i], t[i]];
    }
    m[3] = [0.0, 0.0, 0.0, 1.0];
    m
}

/// A unit quaternion `[w, x, y, z]` of rotation matrix `r` (Shepperd's method), written out
/// here rather than taken from kdmap so the test checks the convention independently.
fn quaternion(r: &DMat3) -> [f64; 4] {
    let m = |i: usize, j: usize| r.col(j)[i];
    let tr = m(0, 0) + m(1, 1) + m(2, 2);
    if tr > 0.0 {
        let s = (tr + 1.0).sqrt() * 2.0;
        let v = [
            0.25 * s,
            m(2, 1) - m(1, 2),
            m(0, 2) - m(2, 0),
            m(1, 0) - m(0, 1),
        ];
        [v[0], v[1] / s, v[2] / s, v[3] / s]
    } else if m(0, 0) > m(1, 1) && m(0, 0) > m(2, 2) {
        let s = (1.0 + m(0, 0) - m(1, 1) - m(2, 2)).sqrt() * 2.0;
        let v = [
            m(2, 1) - m(1, 2),
            0.25 * s * s,
            m(0, 1) + m(1, 0),
            m(0, 2) + m(2, 0),
        ];
        [v[0] / s, v[1] / s, v[2] / s, v[3] / s]
    } else if m(1, 1) > m(2, 2) {
        let s = (1.0 + m(1, 1) - m(0, 0) - m(2, 2)).sqrt() * 2.0;
        let v = [
            m(0, 2) - m(2, 0),
            m(0, 1) + m(1, 0),
            0.25 * s * s,
            m(1, 2) + m(2, 1),
        ];
        [v[0] / s, v[1] / s, v[2] / s, v[3] / s]
    } else {
        let s = (1.0 + m(2, 2) - m(0, 0) - m(1, 1)).sqrt() * 2.0;
        let v = [
            m(1, 0) - m(0, 1),
            m(0, 2) + m(2, 0),
            m(1, 2) + m(2, 1),
            0.25 * s * s,
        ];
        [v[0] / s, v[1] / s, v[2] / s, v[3] / s]
    }
}

/// One Mitsuba sensor as a COLMAP PINHOLE camera line and image line (id `k`), its pose taken
/// into the model's frame through the inverse of `sim`.
fn colmap_lines(k: usize, s: &Sensor, sim: &Similarity) -> (String, String) {
    let m = s.to_world.as_dmat4();
    let axis = |i: usize| m.col(i).truncate().normalize();
    // COLMAP's camera x is Mitsuba's -left, y is -up, z the same forward.
    let (x, y, z) = (-axis(0), -axis(1), axis(2));
    let back = sim.rotation.transpose();
    let r_cw = DMat3::from_cols(back * x, back * y, back * z).transpose();
    let centre = back * (m.col(3).truncate() - sim.translation) / sim.scale;
    let t = -(r_cw * centre);
    let q = quaternion(&r_cw);
    let (fw, fh) = (s.film_width as f64, s.film_height as f64);
    let fov_x = fov_x_degrees(s.fov, s.fov_axis, (fw / fh) as f32) as f64;
    let f = 0.5 * fw / (0.5 * fov_x.to_radians()).tan();
    let cx = fw * (0.5 - s.principal_point.x as f64) - s.crop_offset.0 as f64;
    let cy = fh * (0.5 - s.principal_point.y as f64) - s.crop_offset.1 as f64;
    let id = k + 1;
    let cam = format!(
        "{id} PINHOLE {} {} {f:?} {f:?} {cx:?} {cy:?}\n",
        s.width, s.height
    );
    let img = format!(
        "{id} {:?} {:?} {:?} {:?} {:?} {:?} {:?} {id} {}.exr\n\n",
        q[0], q[1], q[2], q[3], t.x, t.y, t.z, s.id
    );
    (cam, img)
}

/// A run config beside a text model of `scene`'s cameras in `dir`: the same scene and photos,
/// the sensors from `dir/sparse` in the frame of [`rows`].
fn write_model(dir: &Path, scene: &Path) -> PathBuf {
    let cfg = Config::load(scene, &Overrides::default()).unwrap();
    let sensors = kdmap::scene::load(&cfg).unwrap().sensors;
    let sim = Similarity::from_rows(&rows()).unwrap();
    let (mut cams, mut imgs) = (String::from("# cameras\n"), String::from("# images\n"));
    for (k, s) in sensors.iter().enumerate() {
        let (c, i) = colmap_lines(k, s, &sim);
        cams += &c;
        imgs += &i;
    }
    std::fs::create_dir_all(dir.join("sparse")).unwrap();
    std::fs::write(dir.join("sparse/cameras.txt"), cams).unwrap();
    std::fs::write(dir.join("sparse/images.txt"), imgs).unwrap();
    let mut toml = format!(
        "scene = {:?}\n[views]\ncolmap = \"sparse\"\nto_world = [",
        scene
    );
    for r in rows() {
        let _ = write!(toml, "[{:?}, {:?}, {:?}, {:?}], ", r[0], r[1], r[2], r[3]);
    }
    toml += "]\n";
    let run = dir.join("run.toml");
    std::fs::write(&run, toml).unwrap();
    run
}

/// Points spread through the Cornell box.
fn box_points() -> Vec<Vec3> {
    let mut v = Vec::new();
    for i in 0..7 {
        for j in 0..7 {
            for k in 0..7 {
                let f = |n: i32| -0.95 + 1.9 * n as f32 / 6.0;
                v.push(Vec3::new(f(i), 1.0 + f(j), f(k)));
            }
        }
    }
    v
}

/// The COLMAP model written from the fixture's cameras (through a scale-0.5 similarity) gives
/// cameras that project every point of the box where the Mitsuba cameras do, within 1e-3 px,
/// with the photos at `images/<NAME>`.
#[test]
fn colmap_cameras_project_as_the_mitsuba_cameras_they_were_written_from() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = fixture("cbox/input.xml");
    let run = write_model(tmp.path(), &scene);
    let m = kdmap::scene::load(&Config::load(&scene, &Overrides::default()).unwrap()).unwrap();
    let c = kdmap::scene::load(&Config::load(&run, &Overrides::default()).unwrap()).unwrap();
    assert_eq!(m.sensors.len(), c.sensors.len());
    for (a, b) in m.sensors.iter().zip(&c.sensors) {
        assert_eq!(a.id, b.id);
        assert!(b.lens.is_some() && a.lens.is_none());
        let photo = fixture("cbox/images").join(format!("{}.exr", a.id));
        assert_eq!(b.photo.as_deref(), Some(photo.as_path()));
        let (ca, cb) = (Camera::from_sensor(a), Camera::from_sensor(b));
        assert!((ca.position() - cb.position()).length() < 1e-5);
        let mut worst = 0.0f32;
        for p in box_points() {
            let (pa, pb) = (ca.project(p).unwrap(), cb.project(p).unwrap());
            worst = worst.max((pa - pb).length());
        }
        assert!(worst < 1e-3, "{}: {worst} px", a.id);
    }
    assert!(c.files.iter().any(|f| f.ends_with("sparse/images.txt")));
}

/// Every texture of a run whose sensors come from the COLMAP model equals the run with the
/// Mitsuba sensors (`--preset fast`) to within float rounding: the cameras differ only by the
/// rounding of their parameters (1e-4 px), and so do the rays; a few texels at edges, where
/// such a difference flips a pixel's classification, differ by up to a few 1e-3.
#[test]
fn a_colmap_run_reconstructs_as_the_mitsuba_run() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = fixture("cbox/input.xml");
    let run = write_model(tmp.path(), &scene);
    let fast = Overrides {
        preset: Some(Preset::Fast),
        ..Default::default()
    };
    let mut outs = Vec::new();
    for (name, input) in [("mitsuba", &scene), ("colmap", &run)] {
        let cfg = Config::load(input, &fast).unwrap();
        let out = tmp.path().join(name);
        kdmap::pipeline::reconstruct(&cfg, &out, Mode::Quiet).unwrap();
        outs.push(out);
    }
    let mut names: Vec<_> = std::fs::read_dir(outs[0].join("textures"))
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .filter(|n| n.to_string_lossy().ends_with("_albedo.exr"))
        .collect();
    names.sort();
    assert_eq!(names.len(), 7);
    let mut d = Vec::new();
    for name in &names {
        let a = kdmap::image::read_exr(outs[0].join("textures").join(name)).unwrap();
        let b = kdmap::image::read_exr(outs[1].join("textures").join(name)).unwrap();
        assert_eq!((a.width, a.height), (b.width, b.height), "{name:?}");
        d.extend((a.pixels.iter().zip(&b.pixels)).map(|(p, q)| (*p - *q).abs().max_element()));
    }
    let mean = d.iter().map(|&x| x as f64).sum::<f64>() / d.len() as f64;
    let worst = d.iter().fold(0.0f32, |a, &b| a.max(b));
    let share = |t: f32| d.iter().filter(|&&x| x > t).count() as f64 / d.len() as f64;
    eprintln!(
        "colmap vs mitsuba textures: max |dK_d| {worst:e}, mean {mean:e}, share over 1e-6 {:e}, \
         over 1e-5 {:e}, over 1e-4 {:e} ({} texels)",
        share(1e-6),
        share(1e-5),
        share(1e-4),
        d.len()
    );
    // Measured: mean 1.1e-6, 3% of texels over 1e-5, 14 of 407k over 1e-4 (texels where a
    // pixel's classification at an edge flips with the rounding), max 1.1e-3 (K_d ~ 0.5).
    assert!(mean < 1e-5, "mean {mean}");
    assert!(share(1e-4) < 1e-4 && worst < 5e-3, "max {worst}");
    let xml = std::fs::read_to_string(outs[1].join("scene.xml")).unwrap();
    assert_eq!(xml.matches("<!-- COLMAP PINHOLE camera").count(), 3);
    // scene.xml's sensors are the nearest perspective ones: here, the same cameras.
    let back = kdmap::scene::mitsuba::load(&outs[1].join("scene.xml")).unwrap();
    let m = kdmap::scene::mitsuba::load(&scene).unwrap();
    for (a, b) in m.sensors.iter().zip(&back.sensors) {
        let (ca, cb) = (Camera::from_sensor(a), Camera::from_sensor(b));
        for p in box_points() {
            assert!((ca.project(p).unwrap() - cb.project(p).unwrap()).length() < 1e-3);
        }
    }
}

fn kdmap(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_kdmap"))
        .args(args)
        .output()
        .expect("run kdmap")
}

/// `inspect` names the model and each camera's parameters; a model kdmap does not read is
/// refused in one line naming the model and the file (exit code 65).
#[test]
fn inspect_reports_the_model_and_bad_models_are_refused_in_one_line() {
    let tmp = tempfile::tempdir().unwrap();
    let run = write_model(tmp.path(), &fixture("cbox/input.xml"));
    let o = kdmap(&["inspect", run.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        text.contains("sensors from the COLMAP text model"),
        "{text}"
    );
    assert!(text.contains("to_world: scale 0.5"), "{text}");
    assert_eq!(text.matches("COLMAP PINHOLE: fx ").count(), 3, "{text}");
    assert!(text.contains("cam_train_0.exr: present"), "{text}");
    let cams = tmp.path().join("sparse/cameras.txt");
    let t = std::fs::read_to_string(&cams).unwrap();
    std::fs::write(&cams, t.replacen("PINHOLE", "OPENCV_FISHEYE", 1)).unwrap();
    let o = kdmap(&["inspect", run.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(65), "{err}");
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(
        lines[0].contains(
            "cameras.txt (line 2): camera 1: camera model OPENCV_FISHEYE is not supported"
        ),
        "{err}"
    );
}
