//! `scene.glb` read back by the `gltf` crate (it validates) and by kdmap's own glTF loader:
//! geometry, UVs, the embedded texture, cameras and every light kind survive.

use super::*;
use crate::scene::gltf::{parse, LoadOptions};
use crate::scene::{FovAxis, Mesh, PixelFilter};
use glam::{Vec2, Vec3};
use std::collections::BTreeMap;

fn quad(id: &str, emission: Option<Vec3>, sides: Sides) -> Shape {
    let mesh = Mesh {
        positions: vec![
            Vec3::ZERO,
            Vec3::X,
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.5),
        ],
        normals: None,
        uvs: None,
        triangles: vec![[0, 1, 2], [0, 2, 3]],
        flipped: Vec::new(),
    };
    Shape {
        kind: "obj".into(),
        emission,
        ..Shape::plain(id, mesh, sides)
    }
}

fn scene() -> (Scene, Vec<Option<ShapeAtlas>>) {
    let lamp = Vec3::new(17.0, 12.0, 4.0);
    let look = crate::scene::mitsuba::look_at(
        glam::DVec3::new(0.5, 2.0, 4.0),
        glam::DVec3::new(0.5, 0.5, 0.0),
        Some(glam::DVec3::Y),
    )
    .unwrap()
    .as_mat4();
    let spot_frame = crate::scene::mitsuba::look_at(
        glam::DVec3::new(0.0, 3.0, 1.0),
        glam::DVec3::new(0.2, 0.0, 1.0),
        Some(glam::DVec3::Z),
    )
    .unwrap()
    .as_mat4();
    let (beam, cutoff) = spot_cone(0.3, 0.6);
    let scene = Scene {
        path: "in.xml".into(),
        shapes: vec![
            quad("wall", None, Sides::Both),
            quad("lamp", Some(lamp), Sides::Front),
        ],
        emitters: vec![
            Emitter::Point {
                position: Vec3::new(1.0, 2.0, 3.0),
                intensity: Vec3::new(5.0, 4.0, 2.0),
            },
            Emitter::Spot {
                position: spot_frame.w_axis.truncate(),
                axis: spot_frame.z_axis.truncate(),
                to_world: spot_frame,
                intensity: Vec3::splat(7.0),
                cutoff,
                beam_width: beam,
            },
            Emitter::Directional {
                direction: Vec3::new(0.2, -1.0, 0.1).normalize(),
                irradiance: Vec3::new(1.0, 2.0, 3.0),
            },
            Emitter::Area {
                shape: 1,
                radiance: lamp,
            },
        ],
        sensors: vec![crate::scene::Sensor::simple(
            "cam",
            look,
            40.0,
            FovAxis::X,
            (64, 32),
            PixelFilter::Box,
        )],
        files: vec![],
    };
    let atlas = ShapeAtlas {
        width: 8,
        height: 4,
        corner_uv: vec![
            [
                Vec2::new(1.0, 1.0),
                Vec2::new(7.0, 1.0),
                Vec2::new(7.0, 3.0),
            ],
            [
                Vec2::new(1.0, 1.0),
                Vec2::new(7.0, 3.0),
                Vec2::new(1.0, 3.0),
            ],
        ],
        charts: 1,
        texel_density: 4.0,
        levels: 0,
    };
    (scene, vec![Some(atlas), None])
}

#[test]
fn glb_round_trips_through_the_gltf_crate_and_kdmap() {
    let (scene, atlases) = scene();
    let png = b"\x89PNG fake bytes".to_vec();
    let bytes = scene_glb(
        &scene,
        &scene.sensors,
        &atlases,
        &[Some(png.clone()), None],
        0.5,
    )
    .unwrap();
    // the gltf crate validates the document
    let g = ::gltf::Gltf::from_slice(&bytes).unwrap();
    let blob = g.blob.clone().unwrap();
    let mesh = g.meshes().next().unwrap();
    let prim = mesh.primitives().next().unwrap();
    let r = prim.reader(|_| Some(&blob[..]));
    let pos: Vec<Vec3> = r.read_positions().unwrap().map(Vec3::from).collect();
    let uv: Vec<Vec2> = r
        .read_tex_coords(0)
        .unwrap()
        .into_f32()
        .map(Vec2::from)
        .collect();
    let wall = &scene.shapes[0].mesh;
    let atlas = atlases[0].as_ref().unwrap();
    for (t, tri) in wall.triangles.iter().enumerate() {
        for c in 0..3 {
            assert_eq!(pos[3 * t + c], wall.positions[tri[c] as usize]);
            let want = atlas.corner_uv[t][c] / Vec2::new(8.0, 4.0);
            assert_eq!(uv[3 * t + c], want);
        }
    }
    let img = g.images().next().unwrap();
    let ::gltf::image::Source::View { view, mime_type } = img.source() else {
        panic!()
    };
    assert_eq!(mime_type, "image/png");
    assert_eq!(
        &blob[view.offset()..view.offset() + view.length()],
        &png[..]
    );
    let m = prim.material();
    assert!(m.double_sided());
    assert_eq!(m.pbr_metallic_roughness().metallic_factor(), 0.0);
    assert!(m.pbr_metallic_roughness().base_color_texture().is_some());

    // kdmap reads it back with the same scale: the same lights, cameras and area light
    let views = BTreeMap::new();
    let opts = LoadOptions {
        views: &views,
        photometric_scale: 0.5,
        meshes: true,
    };
    let back = parse(&bytes, Path::new("out/scene.glb"), &opts).unwrap();
    assert_eq!(back.shapes.len(), 2);
    assert_eq!(back.shapes[0].sides, Sides::Both);
    assert_eq!(
        back.shapes[1]
            .emission
            .map(|e| (e - Vec3::new(17.0, 12.0, 4.0)).abs().max_element() < 1e-4),
        Some(true)
    );
    let cam = &back.sensors[0];
    assert!(cam.to_world.abs_diff_eq(scene.sensors[0].to_world, 1e-5));
    let fx = crate::physics::camera::fov_x_degrees(cam.fov, cam.fov_axis, 2.0);
    assert!((fx - 40.0).abs() < 1e-3, "{fx}");
    assert_eq!(back.emitters.len(), 4);
    for (a, b) in back.emitters.iter().zip(&scene.emitters) {
        assert_same_emitter(a, b);
    }
}

/// `a` is `b` read back: the same kind, position, direction and strength.
fn assert_same_emitter(a: &Emitter, b: &Emitter) {
    match (a, b) {
        (
            Emitter::Point {
                position: p,
                intensity: i,
            },
            Emitter::Point {
                position: q,
                intensity: j,
            },
        ) => {
            assert!(p.abs_diff_eq(*q, 1e-5) && i.abs_diff_eq(*j, 1e-5));
        }
        (
            Emitter::Spot {
                position: p,
                axis: x,
                intensity: i,
                cutoff: c,
                beam_width: w,
                ..
            },
            Emitter::Spot {
                position: q,
                axis: y,
                intensity: j,
                cutoff: d,
                beam_width: v,
                ..
            },
        ) => {
            assert!(p.abs_diff_eq(*q, 1e-5) && x.abs_diff_eq(*y, 1e-5) && i.abs_diff_eq(*j, 1e-5));
            assert!(
                (c - d).abs() < 1e-4 && (w - v).abs() < 1e-6,
                "{a:?} vs {b:?}"
            );
        }
        (
            Emitter::Directional {
                direction: x,
                irradiance: i,
            },
            Emitter::Directional {
                direction: y,
                irradiance: j,
            },
        ) => assert!(
            x.abs_diff_eq(*y, 1e-5) && i.abs_diff_eq(*j, 1e-5),
            "{a:?} vs {b:?}"
        ),
        (
            Emitter::Area {
                shape: s,
                radiance: r,
            },
            Emitter::Area {
                shape: t,
                radiance: q,
            },
        ) => {
            assert_eq!(s, t);
            assert!(r.abs_diff_eq(*q, 1e-4));
        }
        _ => panic!("{a:?} vs {b:?}"),
    }
}

#[test]
fn a_known_diffuse_material_keeps_its_color() {
    let (mut scene, mut atlases) = scene();
    scene.shapes[0].material = Material::Known(Box::new(crate::scene::KnownMaterial {
        plugin: "diffuse (known)".into(),
        bsdf: KnownBsdf::Diffuse(Vec3::new(0.1, 0.2, 0.3)),
    }));
    atlases[0] = None;
    let bytes = scene_glb(&scene, &scene.sensors, &atlases, &[None, None], 1.0).unwrap();
    let g = ::gltf::Gltf::from_slice(&bytes).unwrap();
    let m = g.materials().next().unwrap();
    assert_eq!(
        m.pbr_metallic_roughness().base_color_factor(),
        [0.1, 0.2, 0.3, 1.0]
    );
    assert_eq!(g.images().count(), 0);
}

#[test]
fn the_written_glb_is_the_framed_bytes() {
    let (scene, atlases) = scene();
    let out = tempfile::tempdir().unwrap();
    let textures = out.path().join("textures");
    std::fs::create_dir_all(&textures).unwrap();
    let png = b"\x89PNG fake bytes, odd length".to_vec();
    let id = &scene.shapes[0].id;
    std::fs::write(textures.join(format!("{id}_albedo.png")), &png).unwrap();
    write_scene_glb(out.path(), &scene, &scene.sensors, &atlases, 0.5).unwrap();
    let written = std::fs::read(out.path().join("scene.glb")).unwrap();
    let bytes = scene_glb(&scene, &scene.sensors, &atlases, &[Some(png), None], 0.5).unwrap();
    assert_eq!(written, bytes);
    assert_eq!(written.len() % 4, 0);
}
