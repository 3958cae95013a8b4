//! The glTF loader against hand-computed scenes: hierarchy, winding, UVs, units, cameras,
//! lights, the spot cone, and every refusal with its JSON path.

use super::*;
use crate::scene::{Emitter, Sides};
use base64::Engine as _;
use glam::{Vec2, Vec3};
use serde_json::{json, Value};

/// A data URI holding `bytes`.
fn data_uri(bytes: &[u8]) -> String {
    format!(
        "data:application/octet-stream;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(bytes)
    )
}

/// A glTF document with one unit quad (z = 0, facing +z; UV (0,0) at vertex 0) in one
/// buffer, `nodes` and `extra` merged in at top level.
fn doc(nodes: Value, extra: Value) -> Value {
    let pos: [f32; 12] = [0., 0., 0., 1., 0., 0., 1., 1., 0., 0., 1., 0.];
    let uv: [f32; 8] = [0., 0., 1., 0., 1., 1., 0., 1.];
    let idx: [u16; 6] = [0, 1, 2, 0, 2, 3];
    let mut bin: Vec<u8> = bytemuck::cast_slice(&pos).to_vec();
    bin.extend_from_slice(bytemuck::cast_slice(&uv));
    bin.extend_from_slice(bytemuck::cast_slice(&idx));
    let mut d = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": nodes,
        "meshes": [{"name": "quad", "primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}]}],
        "materials": [{"name": "m"}],
        "buffers": [{"byteLength": bin.len(), "uri": data_uri(&bin)}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 32},
            {"buffer": 0, "byteOffset": 80, "byteLength": 12}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3", "min": [0,0,0], "max": [1,1,0]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}
        ]
    });
    if let (Some(o), Some(e)) = (d.as_object_mut(), extra.as_object()) {
        for (k, v) in e {
            o.insert(k.clone(), v.clone());
        }
    }
    d
}

fn load_doc(d: &Value, scale: f32) -> Result<Scene> {
    let views = BTreeMap::new();
    let opts = LoadOptions {
        views: &views,
        photometric_scale: scale,
        meshes: true,
    };
    parse(d.to_string().as_bytes(), Path::new("/x/s.gltf"), &opts)
}

fn err_of(d: &Value) -> String {
    load_doc(d, 1.0).unwrap_err().to_string()
}

#[test]
fn node_hierarchy_composes_parent_then_child() {
    // parent: translate (10, 0, 0); child: rotate 90 degrees about z, scale 2.
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let d = doc(
        json!([
            {"name": "root", "translation": [10, 0, 0], "children": [1]},
            {"name": "wall", "rotation": [0, 0, h, h], "scale": [2, 2, 2], "mesh": 0}
        ]),
        json!({}),
    );
    let s = load_doc(&d, 1.0).unwrap();
    assert_eq!(s.shapes.len(), 1);
    let m = &s.shapes[0].mesh;
    assert_eq!(s.shapes[0].id, "wall");
    // vertex (1, 0, 0): scaled (2, 0, 0), rotated (0, 2, 0), translated (10, 2, 0)
    assert!(m.positions[1].abs_diff_eq(Vec3::new(10.0, 2.0, 0.0), 1e-5));
    assert!(m.positions[2].abs_diff_eq(Vec3::new(8.0, 2.0, 0.0), 1e-5));
    assert!(m.face_normal_raw(0).normalize().abs_diff_eq(Vec3::Z, 1e-5));
    // v flipped to kdmap's v-up convention
    let uv = m.uvs.as_ref().unwrap();
    assert_eq!(uv[0], Vec2::new(0.0, 1.0));
    assert_eq!(uv[2], Vec2::new(1.0, 0.0));
    assert_eq!(s.shapes[0].sides, Sides::Front);
    assert!(s.shapes[0].is_reconstructed() && s.emitters.is_empty());
}

#[test]
fn a_mirroring_node_keeps_the_front_face_outward() {
    // mirrored in z: the quad's front (counter-clockwise) side now faces -z in the world
    let d = doc(
        json!([{"name": "m", "scale": [1, 1, -1], "mesh": 0}]),
        json!({}),
    );
    let s = load_doc(&d, 1.0).unwrap();
    let n = s.shapes[0].mesh.face_normal_raw(0).normalize();
    assert!(n.abs_diff_eq(-Vec3::Z, 1e-6), "{n}");
}

#[test]
fn metallic_and_double_sided_materials_are_reconstructed_diffuse() {
    let mut d = doc(json!([{"name": "a", "mesh": 0}]), json!({}));
    d["materials"][0] = json!({"doubleSided": true,
        "pbrMetallicRoughness": {"baseColorFactor": [0.2, 0.4, 0.6, 1], "metallicFactor": 1}});
    let s = load_doc(&d, 1.0).unwrap();
    assert_eq!(s.shapes[0].sides, Sides::Both);
    assert!(s.shapes[0].is_reconstructed());
    assert_eq!(
        s.shapes[0].reflectance,
        Some(crate::scene::ReflectanceSpec::Constant(Vec3::new(
            0.2, 0.4, 0.6
        )))
    );
}

#[test]
fn emissive_material_is_a_one_sided_area_light_in_scene_units() {
    let mut d = doc(json!([{"name": "lamp", "mesh": 0}]), json!({}));
    d["materials"][0] = json!({"emissiveFactor": [1.0, 0.5, 0.25],
        "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 8.0}}});
    let s = load_doc(&d, 0.5).unwrap();
    let want = Vec3::new(4.0, 2.0, 1.0);
    assert_eq!(s.shapes[0].emission, Some(want));
    assert!(!s.shapes[0].is_reconstructed());
    match s.emitters[..] {
        [Emitter::Area { shape: 0, radiance }] => assert_eq!(radiance, want),
        _ => panic!("{:?}", s.emitters),
    }
}

/// A scene with one light node (at (1, 2, 3), turned so local -Z points down -Y) holding
/// `light`.
fn light_doc(light: Value) -> Value {
    let h = std::f32::consts::FRAC_1_SQRT_2;
    doc(
        json!([{"name": "L", "translation": [1, 2, 3], "rotation": [-h, 0, 0, h],
            "extensions": {"KHR_lights_punctual": {"light": 0}}}]),
        json!({"extensionsUsed": ["KHR_lights_punctual"],
            "extensions": {"KHR_lights_punctual": {"lights": [light]}}}),
    )
}

#[test]
fn punctual_lights_convert_with_the_one_photometric_scale() {
    let s = load_doc(
        &light_doc(json!({"type": "point", "color": [1, 0.5, 0], "intensity": 100})),
        0.01,
    )
    .unwrap();
    match &s.emitters[..] {
        [Emitter::Point {
            position,
            intensity,
        }] => {
            assert!(position.abs_diff_eq(Vec3::new(1.0, 2.0, 3.0), 1e-6));
            assert!(intensity.abs_diff_eq(Vec3::new(1.0, 0.5, 0.0), 1e-6));
        }
        e => panic!("{e:?}"),
    }
    let s = load_doc(
        &light_doc(json!({"type": "directional", "intensity": 3})),
        2.0,
    )
    .unwrap();
    match &s.emitters[..] {
        [Emitter::Directional {
            direction,
            irradiance,
        }] => {
            assert!(direction.abs_diff_eq(-Vec3::Y, 1e-6), "{direction}");
            assert!(irradiance.abs_diff_eq(Vec3::splat(6.0), 1e-6));
        }
        e => panic!("{e:?}"),
    }
    let spot = json!({"type": "spot", "intensity": 5, "spot": {"innerConeAngle": 0.2, "outerConeAngle": 0.5}});
    let s = load_doc(&light_doc(spot), 1.0).unwrap();
    match &s.emitters[..] {
        [Emitter::Spot {
            position,
            axis,
            to_world,
            intensity,
            cutoff,
            beam_width,
        }] => {
            assert!(position.abs_diff_eq(Vec3::new(1.0, 2.0, 3.0), 1e-6));
            assert!(axis.abs_diff_eq(-Vec3::Y, 1e-6));
            assert!(to_world.z_axis.truncate().abs_diff_eq(-Vec3::Y, 1e-6));
            assert_eq!(*intensity, Vec3::splat(5.0));
            assert_eq!(*beam_width, 0.2);
            assert!(*cutoff > 0.2 && *cutoff < 0.5, "{cutoff}");
        }
        e => panic!("{e:?}"),
    }
}

#[test]
fn spot_cone_keeps_the_power_and_stays_close_to_the_gltf_falloff() {
    for (i, o) in [(0.0f32, 0.785), (0.2, 0.5), (0.5, 0.6), (1.0, 1.5)] {
        let (b, c) = spot_cone(i, o);
        assert_eq!(b, i);
        let (i, o, c) = (i as f64, o as f64, c as f64);
        let pg = lights::power(|t| lights::gltf_spot_falloff(t, i, o), o);
        let pm = lights::power(|t| lights::mitsuba_spot_falloff(t, i, c), o);
        assert!((pm / pg - 1.0).abs() < 1e-6, "power {pm} vs {pg}");
        let worst = (0..=1000)
            .map(|k| {
                let t = o * k as f64 / 1000.0;
                (lights::gltf_spot_falloff(t, i, o) - lights::mitsuba_spot_falloff(t, i, c)).abs()
            })
            .fold(0.0, f64::max);
        assert!(worst < 0.15, "({i}, {o}): falloffs differ by {worst}");
        eprintln!("cone ({i}, {o}): cutoff {c:.4}, largest falloff difference {worst:.3}");
    }
}

#[test]
fn camera_frame_is_turned_half_a_turn_and_takes_yfov() {
    let d = doc(
        json!([{"name": "cam", "translation": [0, 1, 5], "camera": 0}]),
        json!({"cameras": [{"type": "perspective", "perspective": {"yfov": 0.6, "aspectRatio": 1.5, "znear": 0.1}}]}),
    );
    let s = load_doc(&d, 1.0).unwrap();
    let c = &s.sensors[0];
    assert_eq!(c.id, "cam");
    assert_eq!(c.fov_axis, crate::scene::FovAxis::Y);
    assert!((c.fov - 0.6f32.to_degrees()).abs() < 1e-4);
    // no photo: the nominal film with the stated aspect
    assert_eq!((c.width, c.height), (768, NOMINAL_HEIGHT));
    // Mitsuba +z (forward) = glTF -Z; Mitsuba +x (image left) = glTF -X
    assert!(c.to_world.z_axis.truncate().abs_diff_eq(-Vec3::Z, 1e-6));
    assert!(c.to_world.x_axis.truncate().abs_diff_eq(-Vec3::X, 1e-6));
    assert!(c.to_world.y_axis.truncate().abs_diff_eq(Vec3::Y, 1e-6));
    assert!(c
        .to_world
        .w_axis
        .truncate()
        .abs_diff_eq(Vec3::new(0.0, 1.0, 5.0), 1e-6));
}

#[test]
fn duplicate_and_unusable_names_get_distinct_ids() {
    let d = doc(
        json!([{"name": "a/b", "children": [1, 2]}, {"name": "a/b", "mesh": 0}, {"mesh": 0}]),
        json!({}),
    );
    let s = load_doc(&d, 1.0).unwrap();
    let ids: Vec<_> = s.shapes.iter().map(|s| s.id.as_str()).collect();
    assert_eq!(ids, ["a_b", "quad"]);
    let d = doc(
        json!([{"name": "x", "mesh": 0, "children": [1]}, {"name": "x", "mesh": 0}]),
        json!({}),
    );
    let s = load_doc(&d, 1.0).unwrap();
    let ids: Vec<_> = s.shapes.iter().map(|s| s.id.as_str()).collect();
    assert_eq!(ids, ["x", "x_1"]);
}

#[test]
fn strips_and_fans_become_triangle_lists() {
    use ::gltf::mesh::Mode;
    let s = primitive::triangles(Mode::TriangleStrip, &[0, 1, 2, 3]).unwrap();
    assert_eq!(s, vec![[0, 1, 2], [2, 1, 3]]);
    let f = primitive::triangles(Mode::TriangleFan, &[0, 1, 2, 3]).unwrap();
    assert_eq!(f, vec![[0, 1, 2], [0, 2, 3]]);
    assert!(primitive::triangles(Mode::Lines, &[0, 1]).is_none());
}

#[test]
fn bad_files_get_one_located_line() {
    let bad_json = load_doc_text("{\n  \"asset\": {\"version\": \"2.0\"},\n  oops\n}");
    assert!(bad_json.contains("/x/s.gltf (line 3, col 3)"), "{bad_json}");
    let ok = || doc(json!([{"name": "a", "mesh": 0}]), json!({}));

    let mut d = ok();
    d["accessors"][2]["bufferView"] = json!(7);
    let e = err_of(&d);
    assert!(
        e.starts_with("/x/s.gltf, accessors[2].bufferView: invalid glTF"),
        "{e}"
    );

    let mut d = ok();
    d["buffers"][0]["byteLength"] = json!(1000);
    let e = err_of(&d);
    assert!(
        e.contains("buffers[0]: holds 92 bytes but its byteLength is 1000"),
        "{e}"
    );

    let mut d = ok();
    d["accessors"][2]["count"] = json!(3);
    d["bufferViews"][2]["byteLength"] = json!(6);
    d["accessors"][0]["count"] = json!(2);
    let e = err_of(&d);
    assert!(
        e.contains("meshes[0].primitives[0]: index 2 out of range (2 vertices)"),
        "{e}"
    );

    let mut d = ok();
    d["accessors"][0]["componentType"] = json!(5121);
    let e = err_of(&d);
    assert!(
        e.contains("meshes[0].primitives[0].POSITION (accessors[0])"),
        "{e}"
    );

    let mut d = ok();
    d["nodes"][0]["camera"] = json!(0);
    d["cameras"] = json!([{"type": "orthographic", "orthographic": {"xmag": 1, "ymag": 1, "znear": 0, "zfar": 1}}]);
    let e = err_of(&d);
    assert!(
        e.contains("nodes[0] 'a' (cameras[0]): orthographic cameras are not supported"),
        "{e}"
    );

    let mut d = ok();
    d["extensionsUsed"] = json!(["KHR_draco_mesh_compression"]);
    d["extensionsRequired"] = json!(["KHR_draco_mesh_compression"]);
    let e = err_of(&d);
    assert!(
        e.contains("extensionsRequired") && e.contains("KHR_draco_mesh_compression"),
        "{e}"
    );

    let e = err_of(&light_doc(json!({"type": "point", "range": 4})));
    assert!(
        e.contains("nodes[0] 'L' (KHR_lights_punctual light 0): 'range'"),
        "{e}"
    );

    let mut d = ok();
    d["nodes"] = json!([{"name": "a", "children": [1]}, {"name": "b", "children": [0]}]);
    let e = err_of(&d);
    assert!(
        e.contains("nodes[0] 'a': node is reached twice") || e.contains("invalid glTF"),
        "{e}"
    );

    for e in [bad_json, e] {
        assert!(!e.contains('\n'));
    }
}

fn load_doc_text(text: &str) -> String {
    let views = BTreeMap::new();
    let opts = LoadOptions {
        views: &views,
        photometric_scale: 1.0,
        meshes: true,
    };
    parse(text.as_bytes(), Path::new("/x/s.gltf"), &opts)
        .unwrap_err()
        .to_string()
}

#[test]
fn external_buffers_are_read_beside_the_file_and_listed() {
    let dir = tempfile::tempdir().unwrap();
    let mut d = doc(json!([{"name": "a", "mesh": 0}]), json!({}));
    let uri = d["buffers"][0]["uri"].as_str().unwrap().to_string();
    let bytes = decode_data_uri(uri.strip_prefix("data:").unwrap()).unwrap();
    std::fs::write(dir.path().join("my data.bin"), &bytes).unwrap();
    d["buffers"][0]["uri"] = json!("my%20data.bin");
    let path = dir.path().join("s.gltf");
    std::fs::write(&path, d.to_string()).unwrap();
    let views = BTreeMap::new();
    let opts = LoadOptions {
        views: &views,
        photometric_scale: 1.0,
        meshes: true,
    };
    let s = load(&path, &opts).unwrap();
    assert_eq!(s.files, vec![dir.path().join("my data.bin")]);
    assert_eq!(s.shapes[0].mesh.triangles.len(), 2);
    // the outline reads no buffer at all
    std::fs::remove_file(dir.path().join("my data.bin")).unwrap();
    let o = load(
        &path,
        &LoadOptions {
            meshes: false,
            ..opts
        },
    )
    .unwrap();
    assert!(o.shapes[0].mesh.positions.is_empty());
    assert!(load(&path, &opts)
        .unwrap_err()
        .to_string()
        .contains("my data.bin"));
}
