//! Scene import, end to end: the fixture scenes load with the geometry, lights and cameras
//! their files describe (checked against closed forms), Mitsuba's transform and parameter
//! rules hold, every kind of bad input is refused with one line naming file and line, and the
//! `kdmap inspect` binary behaves (exit codes, one-line errors, no panics).

use glam::{Vec2, Vec3};
use kdmap::scene::{mitsuba, Emitter, FovAxis, Scene, Sides};
use std::path::{Path, PathBuf};
use std::process::Command;

fn fixture(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(p)
}

fn load(p: &str) -> Scene {
    mitsuba::load(&fixture(p)).unwrap_or_else(|e| panic!("{e}"))
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol
}

/// Write `xml` as a scene file in a fresh temp dir (kept alive by the returned guard).
fn temp_scene(xml: &str) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("scene.xml");
    std::fs::write(&p, xml).unwrap();
    (dir, p)
}

fn load_xml(xml: &str) -> Scene {
    let (_d, p) = temp_scene(xml);
    mitsuba::load(&p).unwrap_or_else(|e| panic!("{e}"))
}

const IDS: [&str; 8] = [
    "floor",
    "ceiling",
    "back",
    "left",
    "right",
    "short_box",
    "tall_box",
    "light",
];

/// Closed forms from the OBJ vertex data: the walls are 2 x 2 squares, the light is
/// 0.5 x 0.5; the boxes stand on square footprints whose edge is |v2 - v1| (0.6) and are 0.6
/// and 1.2 tall, so their surfaces are 4 e h + 2 e^2.
fn expected_areas() -> [f64; 8] {
    let edge = |a: [f64; 2], b: [f64; 2]| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
    let e_short = edge([-0.044603, 0.549180], [0.529180, 0.724603]);
    let e_tall = edge([-0.549180, 0.074603], [0.024603, -0.100820]);
    assert!(close(e_short, 0.6, 1e-5) && close(e_tall, 0.6, 1e-5));
    let boxed = |e: f64, h: f64| 4.0 * e * h + 2.0 * e * e;
    [
        4.0,
        4.0,
        4.0,
        4.0,
        4.0,
        boxed(e_short, 0.6),
        boxed(e_tall, 1.2),
        0.25,
    ]
}

fn check_cbox(s: &Scene, wall_triangles: usize) {
    let ids: Vec<_> = s.shapes.iter().map(|s| s.id.as_str()).collect();
    assert_eq!(ids, IDS);
    for (sh, area) in s.shapes.iter().zip(expected_areas()) {
        assert_eq!(sh.kind, "obj");
        assert!(
            close(sh.mesh.area(), area, 1e-4),
            "{}: {}",
            sh.id,
            sh.mesh.area()
        );
        assert_eq!(sh.sides, Sides::Front, "{}", sh.id);
        let want = match sh.id.as_str() {
            "short_box" | "tall_box" => 12,
            "light" => 2,
            _ => wall_triangles,
        };
        assert_eq!(sh.mesh.triangles.len(), want, "{}", sh.id);
        assert!(sh
            .file
            .as_ref()
            .unwrap()
            .ends_with(format!("meshes/{}.obj", sh.id)));
        assert!(sh.mesh.uvs.is_some() && sh.mesh.normals.is_some());
    }
    // The floor faces up (geometric and shading normal), the light down.
    let floor = &s.shapes[0].mesh;
    for t in 0..floor.triangles.len() {
        assert!(floor
            .face_normal_raw(t)
            .normalize()
            .abs_diff_eq(Vec3::Y, 1e-6));
        assert!(floor.shading_normal(t, 0.3, 0.3).abs_diff_eq(Vec3::Y, 1e-6));
    }
    let light = &s.shapes[7];
    assert!(light.mesh.face_normal_raw(0).y < 0.0);
    assert_eq!(light.emission, Some(Vec3::new(17.0, 12.0, 4.0)));
    assert!(s.shapes[..7].iter().all(|s| s.emission.is_none()));
    assert_eq!(s.emitters.len(), 1);
    match s.emitters[0] {
        Emitter::Area { shape, radiance } => {
            assert_eq!(shape, 7);
            assert_eq!(radiance, Vec3::new(17.0, 12.0, 4.0));
        }
        ref e => panic!("{e:?}"),
    }
    assert_eq!(s.triangle_count(), 5 * wall_triangles + 24 + 2);
    let (lo, hi) = s.bounds();
    assert!(lo.abs_diff_eq(Vec3::new(-1.0, 0.0, -1.0), 1e-6));
    assert!(hi.abs_diff_eq(Vec3::new(1.0, 2.0, 1.0), 1e-6));
}

#[test]
fn cbox_loads_with_closed_form_areas() {
    let s = load("cbox/input.xml");
    check_cbox(&s, 2);
    // UVs as in the OBJ file (v up): the floor's first vertex (-1, 0, 1) has vt (0, 0).
    assert_eq!(s.shapes[0].mesh.uvs.as_ref().unwrap()[0], Vec2::ZERO);
}

#[test]
fn cbox_tex_loads_with_subdivided_walls() {
    // Same room, walls split into 2 x 2 quads (8 triangles), same light.
    let s = load("cbox-tex/input.xml");
    check_cbox(&s, 8);
}

#[test]
fn cbox_sensors_use_mitsuba_lookat() {
    let s = load("cbox/input.xml");
    let ids: Vec<_> = s.sensors.iter().map(|c| c.id.as_str()).collect();
    assert_eq!(ids, ["cam_train_0", "cam_train_1", "cam_train_2"]);
    let fovs: Vec<_> = s.sensors.iter().map(|c| c.fov).collect();
    assert_eq!(fovs, [42.0, 40.0, 42.0]);
    let origins = [[-0.8, 1.0, 3.6], [0.0, 1.1, 3.8], [0.8, 0.9, 3.6]];
    for (c, o) in s.sensors.iter().zip(origins) {
        assert_eq!((c.width, c.height, c.fov_axis), (256, 256, FovAxis::X));
        let o = Vec3::from_array(o);
        let m = c.to_world;
        let (x, y, z) = (
            m.x_axis.truncate(),
            m.y_axis.truncate(),
            m.z_axis.truncate(),
        );
        // dir = normalize(target - origin); left = normalize(up x dir); up' = dir x left.
        let dir = (Vec3::new(0.0, 1.0, 0.0) - o).normalize();
        let left = Vec3::Y.cross(dir).normalize();
        assert!(z.abs_diff_eq(dir, 1e-6), "{z} vs {dir}");
        assert!(x.abs_diff_eq(left, 1e-6));
        assert!(y.abs_diff_eq(dir.cross(left), 1e-6));
        assert!(m.w_axis.truncate().abs_diff_eq(o, 1e-6));
        // Mitsuba's camera: local +x is image left. Looking down -z from +z, left is -x.
        assert!(x.x < -0.9);
        assert!(m.transform_point3(Vec3::Z).abs_diff_eq(o + dir, 1e-5));
    }
}

fn floor_with(ops: &str) -> Vec<Vec3> {
    let floor = fixture("cbox/meshes/floor.obj");
    let s = load_xml(&format!(
        r#"<scene version="3.0.0"><shape type="obj">
             <string name="filename" value="{}"/>
             <transform name="to_world">{ops}</transform></shape></scene>"#,
        floor.display()
    ));
    s.shapes[0].mesh.positions.clone()
}

#[test]
fn transforms_compose_in_file_order() {
    let p0 = Vec3::new(-1.0, 0.0, 1.0); // the floor's first vertex
    let t = Vec3::new(0.0, 0.0, 3.0);
    let rot = glam::Mat3::from_rotation_x(90f32.to_radians());
    let tr = floor_with(r#"<translate x="0" y="0" z="3"/><rotate x="1" angle="90"/>"#);
    let rt = floor_with(r#"<rotate x="1" angle="90"/><translate value="0, 0, 3"/>"#);
    assert!(tr[0].abs_diff_eq(rot * (p0 + t), 1e-5), "{}", tr[0]);
    assert!(rt[0].abs_diff_eq(rot * p0 + t, 1e-5), "{}", rt[0]);
    // Numerically different: (-1, -4, 0) vs (-1, -1, 3).
    assert!(tr[0].abs_diff_eq(Vec3::new(-1.0, -4.0, 0.0), 1e-5));
    assert!(rt[0].abs_diff_eq(Vec3::new(-1.0, -1.0, 3.0), 1e-5));
    // A 4x4 matrix (row-major) and a scale, in order.
    let ms =
        floor_with(r#"<matrix value="1 0 0 10  0 1 0 0  0 0 1 0  0 0 0 1"/><scale value="2"/>"#);
    assert!(ms[0].abs_diff_eq(Vec3::new(18.0, 0.0, 2.0), 1e-5));
}

#[test]
fn default_parameters_refs_and_builtins() {
    let floor = fixture("cbox/meshes/floor.obj");
    let s = load_xml(&format!(
        r#"<scene version="3.0.0">
             <default name="mesh" value="{}"/>
             <default name="fov" value="55"/>
             <default name="res" value="64"/>
             <bsdf type="twosided" id="paint"><bsdf type="diffuse"><rgb name="reflectance" value="0.2"/></bsdf></bsdf>
             <shape type="obj" id="a"><string name="filename" value="$mesh"/><ref id="paint"/></shape>
             <shape type="obj"><string name="filename" value="$mesh"/><ref name="bsdf" id="paint"/>
               <boolean name="face_normals" value="true"/></shape>
             <shape type="rectangle"><transform name="to_world"><scale value="0.5"/></transform></shape>
             <shape type="cube"><transform name="to_world"><scale x="2" y="1" z="1"/></transform></shape>
             <shape type="sphere"><float name="radius" value="2"/></shape>
             <sensor type="perspective" id="cam"><float name="fov" value="$fov"/>
               <film type="hdrfilm"><integer name="width" value="$res"/><integer name="height" value="$res"/></film>
             </sensor>
           </scene>"#,
        floor.display()
    ));
    let ids: Vec<_> = s.shapes.iter().map(|s| s.id.as_str()).collect();
    assert_eq!(ids, ["a", "shape_1", "shape_2", "shape_3", "shape_4"]);
    assert_eq!(s.shapes[0].sides, Sides::Both);
    assert_eq!(s.shapes[1].sides, Sides::Both);
    // the two that refer to one bsdf share its name; the others have none of their own
    let names: Vec<_> = s
        .shapes
        .iter()
        .map(|s| s.material_name.as_deref())
        .collect();
    assert_eq!(names, [Some("paint"), Some("paint"), None, None, None]);
    assert!(
        s.shapes[1].mesh.normals.is_none(),
        "face_normals drops them"
    );
    assert_eq!(s.shapes[2].sides, Sides::Front);
    assert!(close(s.shapes[2].mesh.area(), 1.0, 1e-6));
    // 2 x 2 x 2 cube stretched to 4 x 2 x 2: 2 (4x2) faces x 2 + 2 (2x2) ... = 16 + 16 + 8.
    assert!(close(s.shapes[3].mesh.area(), 40.0, 1e-4));
    let sphere = s.shapes[4].mesh.area();
    let exact = 16.0 * std::f64::consts::PI;
    assert!(sphere < exact && sphere > 0.999 * exact, "{sphere}");
    assert_eq!(s.sensors[0].fov, 55.0);
    assert_eq!((s.sensors[0].width, s.sensors[0].height), (64, 64));
}

#[test]
fn ply_shapes_load_through_the_scene() {
    let dir = tempfile::tempdir().unwrap();
    let ply = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
               property float z\nelement face 1\nproperty list uchar int vertex_index\nend_header\n\
               0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
    std::fs::write(dir.path().join("tri.ply"), ply).unwrap();
    let xml = dir.path().join("s.xml");
    std::fs::write(
        &xml,
        r#"<scene version="3.0.0"><shape type="ply" id="tri"><string name="filename" value="tri.ply"/>
           <transform name="to_world"><scale value="2"/></transform>
           <boolean name="flip_normals" value="true"/></shape></scene>"#,
    )
    .unwrap();
    let s = mitsuba::load(&xml).unwrap();
    let m = &s.shapes[0].mesh;
    assert!(close(m.area(), 2.0, 1e-6));
    assert!(m.face_normal_raw(0).z < 0.0, "flipped");
    // No normals in the file: Mitsuba computes smooth ones (here the flat one), then flips.
    assert!(m.normals.as_ref().unwrap()[0].abs_diff_eq(-Vec3::Z, 1e-6));
}

/// The error for a bad fixture, checked to be one line naming `file` (and `line` if given).
fn bad(name: &str, file: &str, line: Option<u32>, what: &str) -> String {
    let e = mitsuba::load(&fixture(&format!("bad/{name}")))
        .err()
        .unwrap_or_else(|| panic!("{name} loaded"))
        .to_string();
    assert!(!e.contains('\n'), "{e}");
    assert!(e.contains(file), "{name}: {e}");
    if let Some(l) = line {
        assert!(e.contains(&format!("(line {l}")), "{name}: {e}");
    }
    assert!(e.contains(what), "{name}: {e}");
    e
}

#[test]
fn bad_inputs_are_refused_with_file_and_line() {
    bad("malformed.xml", "malformed.xml", Some(4), "malformed XML");
    let e = bad(
        "unknown_plugin.xml",
        "unknown_plugin.xml",
        Some(3),
        "unknown shape plugin 'teapot'",
    );
    assert!(
        e.contains("(line 3, col 3), <shape type=\"teapot\" id=\"pot\">"),
        "{e}"
    );
    let e = bad(
        "missing_mesh.xml",
        "missing_mesh.xml",
        Some(2),
        "does_not_exist.obj",
    );
    assert!(e.contains("<shape type=\"obj\" id=\"ghost\">"), "{e}");
    // The mesh errors name the XML line of the shape and the OBJ file and its own line.
    let e = bad(
        "bad_index.xml",
        "meshes/bad_index.obj (line 6)",
        Some(2),
        "out of range",
    );
    assert!(e.contains("bad_index.xml"), "{e}");
    bad("nan.xml", "meshes/nan.obj (line 2)", Some(2), "non-finite");
    // an environment map whose file is missing: the XML line and the map's name
    let e = bad(
        "envmap.xml",
        "envmap.xml",
        Some(4),
        "cannot read environment map",
    );
    assert!(e.contains("sky.exr"), "{e}");
    bad("spectrum.xml", "spectrum.xml", Some(4), "wavelength");
    let e = mitsuba::load(&fixture("bad/no_such_scene.xml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("no_such_scene.xml"), "{e}");
}

fn kdmap(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_kdmap"))
        .args(args)
        .output()
        .expect("run kdmap")
}

#[test]
fn inspect_binary_summarizes_the_scene() {
    let scene = fixture("cbox/input.xml");
    let out = kdmap(&["inspect", scene.to_str().unwrap()]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for id in IDS {
        assert!(stdout.contains(id), "{id} missing from\n{stdout}");
    }
    for cam in ["cam_train_0", "cam_train_1", "cam_train_2"] {
        let line = stdout
            .lines()
            .find(|l| l.contains(&format!("{cam}.exr")))
            .unwrap_or_else(|| panic!("{cam} missing from\n{stdout}"));
        assert!(
            line.contains("present") && line.contains("256x256"),
            "{line}"
        );
    }
    assert!(stdout.contains("area on 'light'"), "{stdout}");
}

#[test]
fn inspect_binary_fails_in_one_line() {
    // malformed input exits 65 (EX_DATAERR), a missing file 66 (EX_NOINPUT)
    for (args, file, code) in [
        (vec!["inspect", "bad/malformed.xml"], "malformed.xml", 65),
        (vec!["inspect", "bad/bad_index.xml"], "bad_index.obj", 65),
        (
            vec!["inspect", "bad/no_such_scene.xml"],
            "no_such_scene.xml",
            66,
        ),
    ] {
        let full = fixture(args[1]);
        let out = kdmap(&[args[0], full.to_str().unwrap()]);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(code), "{stderr}");
        assert_eq!(stderr.lines().count(), 1, "{stderr}");
        assert!(
            stderr.starts_with("error: ") && stderr.contains(file),
            "{stderr}"
        );
        assert!(!stderr.contains("panicked"), "{stderr}");
        assert!(out.stdout.is_empty());
    }
    let out = kdmap(&["no-such-subcommand"]);
    assert_eq!(out.status.code(), Some(2));
    assert!(!String::from_utf8_lossy(&out.stderr).contains("panicked"));
}
