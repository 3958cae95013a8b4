//! `scene.glb`: the recovered scene as one binary glTF 2.0 file that Blender, three.js and
//! game engines open, beside `scene.xml`. Every shape is a mesh node in world space (identity
//! transform). Reconstructed shapes carry their atlas UVs and a `baseColorTexture`: the 8-bit
//! sRGB PNG of the recovered albedo (`textures/<id>_albedo.png`, embedded; the float EXR stays
//! in `textures/`), metallic 0, roughness 1. Known diffuse materials become a constant
//! `baseColorFactor`; emitter shapes a black surface with `emissiveFactor` x
//! `KHR_materials_emissive_strength`. Sensors become perspective cameras (the full film's
//! vertical field of view and aspect; glTF has no crop window or principal point offset, so
//! those are dropped), lights `KHR_lights_punctual` lights. Light values are divided by
//! `photometric_scale`, so a glTF scene loaded with that scale round-trips.
//!
//! The JSON is built with `serde_json` and framed by the `gltf` crate's GLB writer.
//! Triangles are written unindexed, one vertex per corner (atlas charts split vertices
//! anyway); UVs are texel coordinates over the texture size (glTF's v runs down, like the
//! atlas's y, so no flip).

use crate::atlas::uv::ShapeAtlas;
use crate::base::error::Error;
use crate::base::fsio::write_atomic_buffered;
use crate::physics::camera::fov_x_degrees;
use crate::scene::gltf::{gltf_camera_to_world, spot_cone};
use crate::scene::{Emitter, KnownBsdf, Material, Scene, Sensor, Shape, Sides};
use crate::Result;
use glam::{Mat4, Vec3};
use serde_json::{json, Value};
use std::path::Path;

/// The binary chunk and the JSON arrays that point into it, while the file is assembled.
#[derive(Default)]
struct Doc {
    bin: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
    meshes: Vec<Value>,
    materials: Vec<Value>,
    textures: Vec<Value>,
    images: Vec<Value>,
    nodes: Vec<Value>,
    cameras: Vec<Value>,
    lights: Vec<Value>,
    emissive_strength: bool,
    /// Whether a known glass was written (`KHR_materials_transmission` and `_ior`).
    transmission: bool,
}

impl Doc {
    /// Append `bytes` (4-byte aligned) as a buffer view; its index.
    fn view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        while self.bin.len() % 4 != 0 {
            self.bin.push(0);
        }
        let mut v = json!({"buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len()});
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        self.bin.extend_from_slice(bytes);
        self.views.push(v);
        self.views.len() - 1
    }

    /// A float accessor of `n`-component vectors; POSITION gets its min/max (required).
    fn floats(&mut self, data: &[f32], n: usize, bounds: bool) -> usize {
        let view = self.view(bytemuck::cast_slice(data), Some(34962));
        let ty = ["SCALAR", "VEC2", "VEC3", "VEC4"][n - 1];
        let mut a =
            json!({"bufferView": view, "componentType": 5126, "count": data.len() / n, "type": ty});
        if bounds {
            let mut lo = vec![f32::INFINITY; n];
            let mut hi = vec![f32::NEG_INFINITY; n];
            for c in data.chunks_exact(n) {
                for k in 0..n {
                    lo[k] = lo[k].min(c[k]);
                    hi[k] = hi[k].max(c[k]);
                }
            }
            a["min"] = json!(lo);
            a["max"] = json!(hi);
        }
        self.accessors.push(a);
        self.accessors.len() - 1
    }
}

/// The 16 numbers of a glTF node matrix (column-major).
fn matrix(m: &Mat4) -> Value {
    json!(m.to_cols_array())
}

/// A glTF node matrix that has Mitsuba frame `to_world` (camera or spot; +z forward, +x
/// left): the inverse of the import's half turn about y (which is its own inverse).
fn gltf_frame(to_world: &Mat4) -> Mat4 {
    gltf_camera_to_world(&to_world.as_dmat4()).unwrap_or(*to_world)
}

/// `(color, intensity)` of an RGB value: the color's largest channel 1.
fn color_intensity(v: Vec3) -> ([f32; 3], f32) {
    let m = v.max_element();
    if m > 0.0 {
        ((v / m).to_array(), m)
    } else {
        ([0.0; 3], 0.0)
    }
}

/// The glTF outer cone whose power-matched Mitsuba cutoff ([`spot_cone`]) is `cutoff` for
/// inner cone `beam`, by bisection; a cutoff past reach gives the widest cone (pi/2).
fn outer_cone(beam: f32, cutoff: f32) -> f32 {
    let (mut lo, mut hi) = (cutoff, std::f32::consts::FRAC_PI_2);
    if cutoff - beam < 1e-6 || spot_cone(beam, hi).1 <= cutoff {
        return cutoff.min(hi);
    }
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if spot_cone(beam, mid).1 < cutoff {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// The material of one shape: recovered albedo texture `texture`, known, or emitting.
fn material(d: &mut Doc, shape: &Shape, texture: Option<usize>, scale: f32) -> Value {
    let mut m = json!({
        "name": shape.id,
        "doubleSided": shape.sides == Sides::Both,
        "pbrMetallicRoughness": {"metallicFactor": 0.0, "roughnessFactor": 1.0},
    });
    let pbr = &mut m["pbrMetallicRoughness"];
    if let Some(r) = shape.emission {
        pbr["baseColorFactor"] = json!([0.0, 0.0, 0.0, 1.0]);
        let (c, s) = color_intensity(r / scale);
        m["emissiveFactor"] = json!(c);
        if s != 1.0 {
            m["extensions"] = json!({"KHR_materials_emissive_strength": {"emissiveStrength": s}});
            d.emissive_strength = true;
        }
    } else if let Some(t) = texture {
        pbr["baseColorTexture"] = json!({"index": t});
    } else if let Material::Known(k) = &shape.material {
        known_pbr(d, &mut m, &k.bsdf);
    }
    m
}

/// A known material as close as glTF's metallic-roughness model allows: diffuse and
/// plastic as a base colour, a conductor as a metal of its normal-incidence reflectance, glass
/// with `KHR_materials_transmission` and `KHR_materials_ior`, a blend as its heavier part,
/// a mask (and `null`) as alpha blending.
fn known_pbr(d: &mut Doc, m: &mut Value, b: &KnownBsdf) {
    let rough = |r: &Option<crate::scene::Rough>| r.map_or(0.0, |r| r.alpha.sqrt().min(1.0));
    let pbr = &mut m["pbrMetallicRoughness"];
    match b {
        KnownBsdf::Diffuse(c) => pbr["baseColorFactor"] = json!([c.x, c.y, c.z, 1.0]),
        KnownBsdf::Plastic {
            diffuse, rough: r, ..
        } => {
            pbr["baseColorFactor"] = json!([diffuse.x, diffuse.y, diffuse.z, 1.0]);
            pbr["roughnessFactor"] = json!(rough(r));
        }
        KnownBsdf::Conductor {
            eta,
            k,
            tint,
            rough: r,
        } => {
            let f0 = crate::scene::material::fresnel_conductor(1.0, *eta, *k) * *tint;
            pbr["baseColorFactor"] = json!([f0.x, f0.y, f0.z, 1.0]);
            pbr["metallicFactor"] = json!(1.0);
            pbr["roughnessFactor"] = json!(rough(r));
        }
        KnownBsdf::Dielectric {
            eta,
            transmit,
            rough: r,
            ..
        } => {
            pbr["baseColorFactor"] = json!([transmit.x, transmit.y, transmit.z, 1.0]);
            pbr["roughnessFactor"] = json!(rough(r));
            m["extensions"] = json!({
                "KHR_materials_transmission": {"transmissionFactor": 1.0},
                "KHR_materials_ior": {"ior": eta},
            });
            d.transmission = true;
        }
        KnownBsdf::Blend { weight, a, b } => known_pbr(d, m, if *weight > 0.5 { b } else { a }),
        KnownBsdf::Mask { opacity, inner } => {
            known_pbr(d, m, inner);
            m["pbrMetallicRoughness"]["baseColorFactor"][3] = json!(opacity);
            m["alphaMode"] = json!("BLEND");
        }
        KnownBsdf::Null => {
            pbr["baseColorFactor"] = json!([0.0, 0.0, 0.0, 0.0]);
            m["alphaMode"] = json!("BLEND");
        }
    }
}

/// One shape: its mesh (per-corner vertices), material and node.
fn add_shape(
    d: &mut Doc,
    shape: &Shape,
    atlas: Option<&ShapeAtlas>,
    png: Option<&[u8]>,
    scale: f32,
) {
    let mesh = &shape.mesh;
    let mut pos = Vec::with_capacity(9 * mesh.triangles.len());
    let mut nrm = Vec::new();
    let mut uv = Vec::new();
    for (t, tri) in mesh.triangles.iter().enumerate() {
        for (c, &i) in tri.iter().enumerate() {
            pos.extend(mesh.positions[i as usize].to_array());
            match &mesh.normals {
                Some(n) => nrm.extend(n[i as usize].to_array()),
                None => nrm.extend(mesh.face_normal_raw(t).normalize_or_zero().to_array()),
            }
            if let Some(a) = atlas {
                let p = a.corner_uv[t][c];
                uv.extend([p.x / a.width as f32, p.y / a.height as f32]);
            }
        }
    }
    let mut attrs = json!({
        "POSITION": d.floats(&pos, 3, true),
        "NORMAL": d.floats(&nrm, 3, false),
    });
    let texture = match (atlas, png) {
        (Some(_), Some(png)) => {
            attrs["TEXCOORD_0"] = json!(d.floats(&uv, 2, false));
            let view = d.view(png, None);
            d.images.push(json!({"name": format!("{}_albedo", shape.id), "bufferView": view, "mimeType": "image/png"}));
            d.textures
                .push(json!({"sampler": 0, "source": d.images.len() - 1}));
            Some(d.textures.len() - 1)
        }
        _ => None,
    };
    let m = material(d, shape, texture, scale);
    d.materials.push(m);
    d.meshes.push(json!({"name": shape.id, "primitives": [{"attributes": attrs, "material": d.materials.len() - 1}]}));
    d.nodes
        .push(json!({"name": shape.id, "mesh": d.meshes.len() - 1}));
}

/// One sensor as a perspective camera node.
fn add_camera(d: &mut Doc, s: &Sensor) {
    let aspect = s.film_width as f32 / s.film_height.max(1) as f32;
    let fx = fov_x_degrees(s.fov, s.fov_axis, aspect).to_radians();
    let yfov = 2.0 * ((fx / 2.0).tan() / aspect).atan();
    d.cameras.push(json!({"name": s.id, "type": "perspective",
        "perspective": {"yfov": yfov, "aspectRatio": aspect, "znear": 0.01}}));
    let mut node = json!({"name": s.id, "camera": d.cameras.len() - 1, "matrix": matrix(&gltf_frame(&s.to_world))});
    if let Some(l) = &s.lens {
        // glTF cameras have neither distortion nor a principal point: the nearest is centred.
        node["extras"] = json!({"colmap_camera": {"model": l.model.name(), "params": l.params,
            "note": "the nearest glTF camera: yfov from fx, centred; the distortion and the principal point offset are not represented"}});
    }
    d.nodes.push(node);
}

/// A Mitsuba-style frame (+z = `dir`) for a directional light.
fn frame_along(dir: Vec3) -> Mat4 {
    let z = dir.normalize();
    let up = if z.y.abs() < 0.9 { Vec3::Y } else { Vec3::X };
    let x = up.cross(z).normalize();
    let y = z.cross(x);
    Mat4::from_cols(x.extend(0.0), y.extend(0.0), z.extend(0.0), glam::Vec4::W)
}

/// One punctual light (area lights are written with their shape; environment light has no
/// glTF form and is left out).
fn add_light(d: &mut Doc, e: &Emitter, scale: f32) {
    let n = d.lights.len();
    let (light, m) = match e {
        Emitter::Point {
            position,
            intensity,
        } => {
            let (c, i) = color_intensity(*intensity / scale);
            (
                json!({"type": "point", "color": c, "intensity": i}),
                Mat4::from_translation(*position),
            )
        }
        Emitter::Spot {
            to_world,
            intensity,
            cutoff,
            beam_width,
            ..
        } => {
            let (c, i) = color_intensity(*intensity / scale);
            let outer = outer_cone(*beam_width, *cutoff);
            let inner = beam_width.min(outer * 0.999);
            (
                json!({"type": "spot", "color": c, "intensity": i,
                "spot": {"innerConeAngle": inner, "outerConeAngle": outer}}),
                gltf_frame(to_world),
            )
        }
        Emitter::Directional {
            direction,
            irradiance,
        } => {
            let (c, i) = color_intensity(*irradiance / scale);
            (
                json!({"type": "directional", "color": c, "intensity": i}),
                gltf_frame(&frame_along(*direction)),
            )
        }
        // glTF has no environment light: the sky stays in scene.xml only
        Emitter::Area { .. } | Emitter::Environment(_) => return,
    };
    d.lights.push(light);
    d.nodes
        .push(json!({"name": format!("light_{n}"), "matrix": matrix(&m),
        "extensions": {"KHR_lights_punctual": {"light": n}}}));
}

/// The GLB bytes of `scene` with `atlases` and, per shape, the albedo PNG `pngs` (both
/// `None` for shapes not reconstructed); light values divided by `scale`; the cameras are
/// `sensors` (the scene's at the poses the run used).
pub fn scene_glb(
    scene: &Scene,
    sensors: &[Sensor],
    atlases: &[Option<ShapeAtlas>],
    pngs: &[Option<Vec<u8>>],
    scale: f32,
) -> Result<Vec<u8>> {
    scene_doc(scene, sensors, atlases, pngs, scale)?
        .to_vec()
        .map_err(|e| Error::internal(format!("scene.glb: {e:?}")))
}

/// [`scene_glb`] before it is framed: written to a file as it is framed, its binary chunk is
/// held once (a scene of 2M triangles has a 190 MB chunk).
fn scene_doc(
    scene: &Scene,
    sensors: &[Sensor],
    atlases: &[Option<ShapeAtlas>],
    pngs: &[Option<Vec<u8>>],
    scale: f32,
) -> Result<::gltf::binary::Glb<'static>> {
    let mut d = Doc::default();
    for (i, shape) in scene.shapes.iter().enumerate() {
        let atlas = atlases.get(i).and_then(|a| a.as_ref());
        let png = pngs.get(i).and_then(|p| p.as_deref());
        add_shape(&mut d, shape, atlas, png, scale);
    }
    for s in sensors {
        add_camera(&mut d, s);
    }
    for e in &scene.emitters {
        add_light(&mut d, e, scale);
    }
    let mut used = Vec::new();
    let mut root = json!({
        "asset": {"version": "2.0", "generator": "kdmap"},
        "scene": 0,
        "scenes": [{"nodes": (0..d.nodes.len()).collect::<Vec<_>>()}],
        "nodes": d.nodes, "meshes": d.meshes, "materials": d.materials,
        "accessors": d.accessors, "bufferViews": d.views,
        "buffers": [{"byteLength": d.bin.len()}],
    });
    if !d.images.is_empty() {
        root["images"] = json!(d.images);
        root["textures"] = json!(d.textures);
        root["samplers"] =
            json!([{"magFilter": 9729, "minFilter": 9729, "wrapS": 33071, "wrapT": 33071}]);
    }
    if !d.cameras.is_empty() {
        root["cameras"] = json!(d.cameras);
    }
    if !d.lights.is_empty() {
        root["extensions"] = json!({"KHR_lights_punctual": {"lights": d.lights}});
        used.push("KHR_lights_punctual");
    }
    if d.emissive_strength {
        used.push("KHR_materials_emissive_strength");
    }
    if d.transmission {
        used.extend(["KHR_materials_transmission", "KHR_materials_ior"]);
    }
    if !used.is_empty() {
        root["extensionsUsed"] = json!(used);
    }
    glb_doc(&root, d.bin)
}

/// The JSON and binary chunk as a GLB to write.
fn glb_doc(root: &Value, bin: Vec<u8>) -> Result<::gltf::binary::Glb<'static>> {
    let json =
        serde_json::to_vec(root).map_err(|e| Error::internal(format!("scene.glb JSON: {e}")))?;
    Ok(::gltf::binary::Glb {
        header: ::gltf::binary::Header {
            magic: *b"glTF",
            version: 2,
            length: 0,
        },
        json: json.into(),
        bin: Some(bin.into()),
    })
}

/// Write `<out>/scene.glb`, embedding the albedo previews `textures/<id>_albedo.png` that
/// the run wrote before; `sensors` as in [`scene_glb`].
pub fn write_scene_glb(
    out: &Path,
    scene: &Scene,
    sensors: &[Sensor],
    atlases: &[Option<ShapeAtlas>],
    scale: f32,
) -> Result<()> {
    let pngs = scene
        .shapes
        .iter()
        .zip(atlases)
        .map(|(s, a)| match a {
            Some(_) => {
                let f = out.join("textures").join(format!("{}_albedo.png", s.id));
                std::fs::read(&f).map(Some).map_err(|e| Error::io(&f, e))
            }
            None => Ok(None),
        })
        .collect::<Result<Vec<_>>>()?;
    let doc = scene_doc(scene, sensors, atlases, &pngs, scale)?;
    let path = out.join("scene.glb");
    write_atomic_buffered(&path, |w| {
        doc.to_writer(w).map_err(|e| match e {
            ::gltf::Error::Io(e) => Error::io(&path, e),
            e => Error::internal(format!("scene.glb: {e:?}")),
        })
    })
}

#[cfg(test)]
mod tests;
