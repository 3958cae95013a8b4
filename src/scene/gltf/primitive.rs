//! One glTF mesh primitive -> one world-space [`Shape`]: triangles (lists, strips, fans),
//! positions, normals and `TEXCOORD_0` read through the `gltf` crate's accessor readers after
//! checking each accessor's type and byte ranges (the readers do not), indices checked against the vertex
//! count, and the material's emission settled in scene units.
//!
//! glTF puts the texture origin at the top left (v down); kdmap meshes keep v up, as OBJ and
//! Mitsuba do, so `v` becomes `1 - v`. A node whose world transform mirrors (negative
//! determinant) has clockwise front faces (glTF spec, "Transformations"): the winding is
//! reversed so the face normal points to the front as everywhere else in kdmap.

use super::{at, Builder};
use crate::scene::{Material, Mesh, ReflectanceSpec, Shape, Sides};
use crate::Result;
use ::gltf::accessor::{DataType, Dimensions};
use ::gltf::mesh::Mode;
use glam::{DMat4, Vec2, Vec3};

/// The shape of primitive `prim` of `node`'s mesh at `world`, named `id`. In an outline
/// (`meshes` off) the mesh is empty.
pub(super) fn shape(
    b: &Builder,
    node: &::gltf::Node,
    prim: &::gltf::Primitive,
    world: &DMat4,
    id: String,
) -> Result<Shape> {
    let here = match node.mesh() {
        Some(m) => format!("meshes[{}].primitives[{}]", m.index(), prim.index()),
        None => super::node_label(node),
    };
    let material = prim.material();
    let emission = emission(b, &material, &here)?;
    let mesh = if b.opts.meshes {
        let mut mesh = read_mesh(b, prim, &here)?;
        mesh.transform(&world.as_mat4());
        if world.determinant() < 0.0 {
            for t in &mut mesh.triangles {
                t.swap(1, 2);
            }
        }
        mesh
    } else {
        Mesh::default()
    };
    let base = material.pbr_metallic_roughness();
    let reflectance = base
        .base_color_texture()
        .is_none()
        .then(|| ReflectanceSpec::Constant(Vec3::from_slice(&base.base_color_factor()[..3])));
    Ok(Shape {
        id,
        kind: "gltf".into(),
        file: None,
        mesh,
        sides: if material.double_sided() {
            Sides::Both
        } else {
            Sides::Front
        },
        emission,
        reflectance,
        material: Material::Unknown,
        material_name: material.index().map(|i| format!("material {i}")),
    })
}

/// The material's emitted radiance in scene units (`emissiveFactor` x emissive strength x
/// photometric scale), if it emits at all.
fn emission(b: &Builder, m: &::gltf::Material, here: &str) -> Result<Option<Vec3>> {
    let e = Vec3::from(m.emissive_factor()) * m.emissive_strength().unwrap_or(1.0);
    if !(e.is_finite() && e.min_element() >= 0.0) {
        return Err(at(
            b.path,
            here,
            "emissive factor and strength must be finite and not negative",
        ));
    }
    if e == Vec3::ZERO {
        return Ok(None);
    }
    if m.emissive_texture().is_some() {
        return Err(at(
            b.path,
            here,
            "emissiveTexture is not supported: area lights emit uniformly",
        ));
    }
    Ok(Some(e * b.opts.photometric_scale))
}

/// Refuse an accessor that is not `dims` of `types` (a typed message naming `what`), or
/// whose bytes do not lie inside its buffer ([`super::accessor`]).
fn check_accessor(
    b: &Builder,
    here: &str,
    what: &str,
    acc: &::gltf::Accessor,
    dims: Dimensions,
    types: &[DataType],
) -> Result<()> {
    if acc.dimensions() != dims || !types.contains(&acc.data_type()) {
        return Err(at(
            b.path,
            &format!("{here}.{what} (accessors[{}])", acc.index()),
            format!(
                "{:?} of {:?}: expected {dims:?} of {types:?}",
                acc.dimensions(),
                acc.data_type()
            ),
        ));
    }
    match super::accessor::layout_error(acc, b.buffers) {
        Some(e) => Err(at(
            b.path,
            &format!("{here}.{what} (accessors[{}])", acc.index()),
            e,
        )),
        None => Ok(()),
    }
}

/// The primitive's mesh in its node's local frame.
fn read_mesh(b: &Builder, prim: &::gltf::Primitive, here: &str) -> Result<Mesh> {
    let bad = |what: &str| at(b.path, here, format!("{what} lies outside its buffer"));
    let reader = prim.reader(|buf| b.buffers.get(buf.index()).map(|v| v.as_slice()));
    let pos_acc = prim
        .get(&::gltf::Semantic::Positions)
        .ok_or_else(|| at(b.path, here, "has no POSITION attribute"))?;
    check_accessor(
        b,
        here,
        "POSITION",
        &pos_acc,
        Dimensions::Vec3,
        &[DataType::F32],
    )?;
    let positions: Vec<Vec3> = reader
        .read_positions()
        .ok_or_else(|| bad("POSITION"))?
        .map(Vec3::from)
        .collect();
    if positions.len() != pos_acc.count() || positions.iter().any(|p| !p.is_finite()) {
        return Err(bad("POSITION (or it is not finite)"));
    }
    let normals = match prim.get(&::gltf::Semantic::Normals) {
        Some(acc) => {
            check_accessor(b, here, "NORMAL", &acc, Dimensions::Vec3, &[DataType::F32])?;
            let n: Vec<Vec3> = reader
                .read_normals()
                .ok_or_else(|| bad("NORMAL"))?
                .map(|n| Vec3::from(n).normalize_or_zero())
                .collect();
            (n.len() == positions.len()).then_some(n)
        }
        None => None,
    };
    let uvs = match prim.get(&::gltf::Semantic::TexCoords(0)) {
        Some(acc) => {
            let types = [DataType::F32, DataType::U8, DataType::U16];
            check_accessor(b, here, "TEXCOORD_0", &acc, Dimensions::Vec2, &types)?;
            let uv: Vec<Vec2> = reader
                .read_tex_coords(0)
                .ok_or_else(|| bad("TEXCOORD_0"))?
                .into_f32()
                .map(|[u, v]| Vec2::new(u, 1.0 - v))
                .collect();
            (uv.len() == positions.len()).then_some(uv)
        }
        None => None,
    };
    let indices: Vec<u32> = match prim.indices() {
        Some(acc) => {
            let types = [DataType::U8, DataType::U16, DataType::U32];
            check_accessor(b, here, "indices", &acc, Dimensions::Scalar, &types)?;
            let idx: Vec<u32> = reader
                .read_indices()
                .ok_or_else(|| bad("indices"))?
                .into_u32()
                .collect();
            if idx.len() != acc.count() {
                return Err(bad("indices"));
            }
            idx
        }
        None => (0..positions.len() as u32).collect(),
    };
    if let Some(i) = indices.iter().find(|&&i| i as usize >= positions.len()) {
        return Err(at(
            b.path,
            here,
            format!("index {i} out of range ({} vertices)", positions.len()),
        ));
    }
    let triangles = triangles(prim.mode(), &indices).ok_or_else(|| {
        at(
            b.path,
            here,
            format!("mode {:?}: only triangles are supported", prim.mode()),
        )
    })?;
    Ok(Mesh {
        positions,
        normals,
        uvs,
        triangles,
        flipped: Vec::new(),
    })
}

/// Triangle list from indices in `mode` (strips alternate their winding as the spec says);
/// `None` for points and lines.
pub(super) fn triangles(mode: Mode, idx: &[u32]) -> Option<Vec<[u32; 3]>> {
    let n = idx.len();
    Some(match mode {
        Mode::Triangles => idx.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        Mode::TriangleStrip => (0..n.saturating_sub(2))
            .map(|i| {
                if i % 2 == 0 {
                    [idx[i], idx[i + 1], idx[i + 2]]
                } else {
                    [idx[i + 1], idx[i], idx[i + 2]]
                }
            })
            .collect(),
        Mode::TriangleFan => (1..n.saturating_sub(1))
            .map(|i| [idx[0], idx[i], idx[i + 1]])
            .collect(),
        _ => return None,
    })
}
