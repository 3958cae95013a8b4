//! `meshes/<id>.obj` (+ `<id>.mtl`): each shape's world-space mesh, with the atlas UVs for
//! reconstructed shapes, so `scene.xml` and any DCC tool can put the recovered albedo on it.
//!
//! UVs follow the OBJ convention (v up): texel coordinates `(x, y)` (y down) become
//! `vt = (x / width, 1 - y / height)`. Mitsuba's OBJ loader flips v back (its default
//! `flip_tex_coords = true`), so its bitmap lookup lands on texel `(x, y)` again. Every
//! triangle corner gets its own `vt` (charts split vertices anyway); positions and normals
//! stay shared. Numbers are written in Rust's shortest round-trip form, so reading the file
//! back gives the same `f32` bits.

use crate::atlas::uv::ShapeAtlas;
use crate::base::fsio::write_atomic;
use crate::scene::Shape;
use crate::Result;
use std::fmt::Write as _;
use std::path::Path;

/// The `o`, `v` and `vn` lines of `shape` into `s`; whether it has a normal per vertex.
fn write_vertices(s: &mut String, shape: &Shape) -> bool {
    let mesh = &shape.mesh;
    let _ = writeln!(s, "o {}", shape.id);
    for p in &mesh.positions {
        let _ = writeln!(s, "v {} {} {}", p.x, p.y, p.z);
    }
    let normals = mesh
        .normals
        .as_ref()
        .filter(|n| n.len() == mesh.positions.len());
    for n in normals.into_iter().flatten() {
        let _ = writeln!(s, "vn {} {} {}", n.x, n.y, n.z);
    }
    normals.is_some()
}

/// The OBJ text of `shape`, with `atlas`'s UVs if given, using material `<id>` from
/// `<id>.mtl` when `material` is set.
pub fn obj_text(shape: &Shape, atlas: Option<&ShapeAtlas>, material: bool) -> String {
    let mesh = &shape.mesh;
    let mut s = String::with_capacity(64 * (mesh.positions.len() + 3 * mesh.triangles.len()));
    let _ = writeln!(
        s,
        "# kdmap: shape '{}' in world space{}",
        shape.id,
        if atlas.is_some() {
            ", with the albedo atlas UVs (v up)"
        } else {
            ""
        }
    );
    if material {
        let _ = writeln!(s, "mtllib {}.mtl", shape.id);
    }
    let normals = write_vertices(&mut s, shape);
    if let Some(a) = atlas {
        let (w, h) = (a.width as f64, a.height as f64);
        for tri in &a.corner_uv {
            for c in tri {
                let u = (c.x as f64 / w).clamp(0.0, 1.0) as f32;
                let v = (1.0 - c.y as f64 / h).clamp(0.0, 1.0) as f32;
                let _ = writeln!(s, "vt {u} {v}");
            }
        }
    }
    if material {
        let _ = writeln!(s, "usemtl {}", shape.id);
    }
    let uv = atlas.is_some_and(|a| a.corner_uv.len() == mesh.triangles.len());
    for (t, tri) in mesh.triangles.iter().enumerate() {
        s.push('f');
        for (c, &i) in tri.iter().enumerate() {
            let v = i + 1;
            let vt = 3 * t + c + 1;
            let _ = match (uv, normals) {
                (true, true) => write!(s, " {v}/{vt}/{v}"),
                (true, false) => write!(s, " {v}/{vt}"),
                (false, true) => write!(s, " {v}//{v}"),
                (false, false) => write!(s, " {v}"),
            };
        }
        s.push('\n');
    }
    s
}

/// The MTL text for a reconstructed shape: a white diffuse whose `map_Kd` is the albedo
/// preview PNG (viewers treat PNG colour maps as sRGB, which the preview is).
pub fn mtl_text(id: &str) -> String {
    format!(
        "# kdmap: recovered albedo of shape '{id}'\n\
         newmtl {id}\n\
         Ka 0 0 0\n\
         Kd 1 1 1\n\
         Ks 0 0 0\n\
         illum 1\n\
         map_Kd ../textures/{id}_albedo.png\n"
    )
}

/// Write `<dir>/<id>.obj`, and `<dir>/<id>.mtl` for a shape with an atlas.
pub fn write_shape_mesh(dir: &Path, shape: &Shape, atlas: Option<&ShapeAtlas>) -> Result<()> {
    crate::base::fsio::create_dir(dir)?;
    let material = atlas.is_some();
    let obj = dir.join(format!("{}.obj", shape.id));
    write_atomic(&obj, obj_text(shape, atlas, material).as_bytes())?;
    if material {
        let mtl = dir.join(format!("{}.mtl", shape.id));
        write_atomic(&mtl, mtl_text(&shape.id).as_bytes())?;
    }
    Ok(())
}

/// The OBJ text of `shape` with its own input UVs (one `vt` per vertex, v up as kept), for the
/// albedo folded into them (`uv_fold`; `<id>_uv.obj`); `None` without UVs for every vertex.
pub fn obj_text_input_uv(shape: &Shape) -> Option<String> {
    let mesh = &shape.mesh;
    let uvs = mesh
        .uvs
        .as_ref()
        .filter(|u| u.len() == mesh.positions.len())?;
    let mut s = String::with_capacity(80 * (mesh.positions.len() + mesh.triangles.len()));
    let _ = writeln!(
        s,
        "# kdmap: shape '{}' in world space, with its input UVs (v up) for the folded albedo",
        shape.id
    );
    let normals = write_vertices(&mut s, shape);
    for uv in uvs {
        let _ = writeln!(s, "vt {} {}", uv.x, uv.y);
    }
    for tri in &mesh.triangles {
        s.push('f');
        for &i in tri {
            let v = i + 1;
            let _ = match normals {
                true => write!(s, " {v}/{v}/{v}"),
                false => write!(s, " {v}/{v}"),
            };
        }
        s.push('\n');
    }
    Some(s)
}

/// Write `<dir>/<id>_uv.obj` ([`obj_text_input_uv`]); nothing for a shape without UVs.
pub fn write_shape_uv_mesh(dir: &Path, shape: &Shape) -> Result<()> {
    let Some(text) = obj_text_input_uv(shape) else {
        return Ok(());
    };
    crate::base::fsio::create_dir(dir)?;
    write_atomic(&dir.join(format!("{}_uv.obj", shape.id)), text.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::{Mesh, Sides};
    use glam::{Vec2, Vec3};

    fn quad() -> Shape {
        let mesh = Mesh {
            positions: vec![
                Vec3::ZERO,
                Vec3::X,
                Vec3::new(1.0, 1.0, 0.0),
                Vec3::new(0.1, 1.0 / 3.0, 0.0),
            ],
            normals: Some(vec![Vec3::Z; 4]),
            uvs: None,
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            flipped: Vec::new(),
        };
        Shape {
            kind: "obj".into(),
            ..Shape::plain("wall", mesh, Sides::Front)
        }
    }

    #[test]
    fn obj_has_one_vt_per_corner_with_v_up() {
        let atlas = ShapeAtlas {
            width: 10,
            height: 20,
            corner_uv: vec![
                [
                    Vec2::new(1.0, 1.0),
                    Vec2::new(9.0, 1.0),
                    Vec2::new(9.0, 19.0),
                ],
                [
                    Vec2::new(1.0, 1.0),
                    Vec2::new(9.0, 19.0),
                    Vec2::new(1.0, 19.0),
                ],
            ],
            charts: 1,
            texel_density: 8.0,
            levels: 0,
        };
        let s = obj_text(&quad(), Some(&atlas), true);
        assert!(s.contains("mtllib wall.mtl\n") && s.contains("usemtl wall\n"));
        assert!(s.contains("\nv 0.1 0.33333334 0\n"), "{s}");
        assert!(s.contains("\nvt 0.1 0.95\n"), "{s}");
        assert!(s.contains("\nvt 0.9 0.05\n"), "{s}");
        assert!(
            s.contains("\nf 1/1/1 2/2/2 3/3/3\nf 1/4/1 3/5/3 4/6/4\n"),
            "{s}"
        );
        assert_eq!(s.matches("\nvt ").count(), 6);
        let plain = obj_text(&quad(), None, false);
        assert!(plain.contains("\nf 1//1 2//2 3//3\n") && !plain.contains("vt"));
        assert!(mtl_text("wall").contains("map_Kd ../textures/wall_albedo.png"));
    }

    /// The input UVs are written as kept (OBJ convention), one per vertex, so Mitsuba's
    /// loader (which flips v) reads them as the input file had them.
    #[test]
    fn the_input_uv_mesh_keeps_the_input_uvs() {
        let mut q = quad();
        assert!(obj_text_input_uv(&q).is_none());
        q.mesh.uvs = Some(vec![
            Vec2::new(0.0, 0.0),
            Vec2::new(20.0, 0.0),
            Vec2::new(20.0, 20.0),
            Vec2::new(2.0, 6.5),
        ]);
        let s = obj_text_input_uv(&q).unwrap();
        assert!(s.contains("\nvt 20 20\nvt 2 6.5\n"), "{s}");
        assert!(
            s.contains("\nf 1/1/1 2/2/2 3/3/3\nf 1/1/1 3/3/3 4/4/4\n"),
            "{s}"
        );
        assert_eq!(s.matches("\nvt ").count(), 4);
    }
}
