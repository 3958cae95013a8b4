//! Mesh sources for the scene: OBJ and PLY files, and Mitsuba 3's built-in `rectangle`,
//! `cube` and `sphere`, all in the shape's local space (the XML loader applies `to_world`).
//!
//! # Texture coordinates
//! Every [`Mesh`] holds UVs in the **OBJ convention: `v` points up**, i.e. `v = 1` is the top
//! row of a texture image. OBJ files are kept as written. Mitsuba uses the opposite
//! convention internally (`v = 0` is the top row; its OBJ loader flips `v` unless
//! `flip_tex_coords` is false), so the UVs that Mitsuba takes as they are — PLY files and the
//! built-in shapes — are converted here with `v -> 1 - v`. A texture painted through these
//! UVs therefore lands where Mitsuba would put it.
//!
//! # Why OBJ files are pre-checked before `tobj`
//! `tobj` (4.0) does the parsing, triangulation (fans, as Mitsuba) and per-corner vertex
//! de-duplication, but on its own it
//! - silently drops a texture/normal index of `0` (it becomes its "missing" marker),
//! - overflows (a panic in debug builds) on a negative `vt`/`vn` index reaching before the
//!   first element,
//! - turns `l` polylines of three or more points into triangles, and faces of one or two
//!   vertices into degenerate triangles,
//! - misaligns UVs/normals when only some faces have them, and
//! - reports errors without a line number.
//!
//! So [`load_obj`] first scans the text once: every `v`/`vt`/`vn` must be finite numbers,
//! every face index must resolve inside the file (1-based, or negative = relative), every
//! face must have at least three corners; it records whether all corners carry UVs/normals;
//! `l`/`p` records are blanked. Errors name the file and line. Only then does `tobj` build
//! the mesh. UVs or normals present on only some corners are dropped (Mitsuba would read
//! uninitialized data there).
//!
//! # Normals
//! As Mitsuba: a mesh without vertex normals (and without `face_normals`) gets smooth
//! normals, each vertex's the angle-weighted mean of its faces' normals
//! ([`compute_vertex_normals`]); the caller does that after `to_world` since Mitsuba does.

use crate::base::error::{Error, Location};
use crate::scene::Mesh;
use crate::Result;
use glam::{Vec2, Vec3};
use std::path::Path;

/// Latitude rings of the tessellated `sphere` (pole to pole).
pub const SPHERE_RINGS: usize = 64;
/// Longitude segments of the tessellated `sphere`.
pub const SPHERE_SEGMENTS: usize = 128;

/// The whole of a mesh file. Only regular files: a device or a pipe (`/dev/zero`) named as a
/// mesh would never end.
fn read_bytes(path: &Path) -> Result<Vec<u8>> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if !meta.is_file() {
        return Err(Error::input(
            path,
            "not a regular file (a mesh must be an .obj or .ply file)",
        ));
    }
    std::fs::read(path).map_err(|e| Error::io(path, e))
}

fn at_line(path: &Path, line: usize, element: &str, msg: impl Into<String>) -> Error {
    Error::Input {
        path: path.to_path_buf(),
        loc: Location {
            line: Some(line.min(u32::MAX as usize) as u32),
            col: None,
            element: Some(element.to_string()),
        },
        msg: msg.into(),
    }
}

/// Collapse the whitespace of a third-party message onto one line.
fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}

// ---------------------------------------------------------------------------------------------
// OBJ
// ---------------------------------------------------------------------------------------------

/// What the pre-check learned about an OBJ text.
struct ObjScan {
    /// The text with `l`/`p` records blanked, for `tobj`.
    text: String,
    all_uv: bool,
    all_normal: bool,
}

fn parse_obj_float(path: &Path, line: usize, record: &str, tok: Option<&str>) -> Result<f32> {
    let tok = tok.ok_or_else(|| at_line(path, line, record, "too few numbers"))?;
    let v: f32 = tok
        .parse()
        .map_err(|_| at_line(path, line, record, format!("invalid number '{tok}'")))?;
    if !v.is_finite() {
        return Err(at_line(
            path,
            line,
            record,
            format!("non-finite number '{tok}'"),
        ));
    }
    Ok(v)
}

/// Resolve one OBJ index (1-based, or negative = relative to the elements read so far) and
/// check it against `total` (the count in the whole file; `so_far` for relative ones).
fn check_obj_index(
    path: &Path,
    line: usize,
    what: &str,
    tok: &str,
    so_far: usize,
    total: usize,
) -> Result<()> {
    let i: i64 = tok
        .parse()
        .map_err(|_| at_line(path, line, "f", format!("invalid {what} index '{tok}'")))?;
    let resolved = if i > 0 {
        i - 1
    } else if i < 0 {
        so_far as i64 + i
    } else {
        return Err(at_line(
            path,
            line,
            "f",
            format!("{what} index 0 (OBJ indices start at 1)"),
        ));
    };
    if resolved < 0 || resolved >= total as i64 {
        return Err(at_line(
            path,
            line,
            "f",
            format!("{what} index {i} out of range (the file has {total} {what}s)"),
        ));
    }
    Ok(())
}

/// Per-record counts while scanning an OBJ file: seen so far, and in the whole file (OBJ
/// indices may point forward or, when negative, back from the current count).
#[derive(Default)]
struct ObjCounts {
    seen: [usize; 3],
    total: [usize; 3],
    /// Whether some face corner has / lacks a texture coordinate and a normal.
    uv: (bool, bool),
    normal: (bool, bool),
}

fn scan_obj(text: &str, path: &Path) -> Result<ObjScan> {
    let mut c = ObjCounts::default();
    for l in text.lines() {
        match l.split_whitespace().next() {
            Some("v") => c.total[0] += 1,
            Some("vt") => c.total[1] += 1,
            Some("vn") => c.total[2] += 1,
            _ => {}
        }
    }
    let mut faces = 0usize;
    let mut out = String::with_capacity(text.len());
    for (i, l) in text.lines().enumerate() {
        let line = i + 1;
        let mut words = l.split_whitespace();
        match words.next() {
            Some("v") => {
                check_obj_vertex(path, line, words.collect())?;
                c.seen[0] += 1;
            }
            Some("vt") => {
                parse_obj_float(path, line, "vt", words.next())?;
                parse_obj_float(path, line, "vt", words.next())?;
                c.seen[1] += 1;
            }
            Some("vn") => {
                let n = Vec3::new(
                    parse_obj_float(path, line, "vn", words.next())?,
                    parse_obj_float(path, line, "vn", words.next())?,
                    parse_obj_float(path, line, "vn", words.next())?,
                );
                if n.length_squared() == 0.0 || !n.normalize().is_finite() {
                    return Err(at_line(path, line, "vn", "zero-length normal"));
                }
                c.seen[2] += 1;
            }
            Some("f") => {
                check_obj_face(path, line, words.collect(), &mut c)?;
                faces += 1;
            }
            // Points and polylines are not surfaces; tobj would make triangles of them.
            Some("l") | Some("p") => {
                out.push('\n');
                continue;
            }
            _ => {}
        }
        out.push_str(l);
        out.push('\n');
    }
    if faces == 0 {
        return Err(Error::input(path, "the OBJ file has no faces"));
    }
    Ok(ObjScan {
        text: out,
        all_uv: c.uv.0 && !c.uv.1,
        all_normal: c.normal.0 && !c.normal.1,
    })
}

/// A `v` record: 3 coordinates (+ w, or r g b), all numbers, w not 0.
fn check_obj_vertex(path: &Path, line: usize, toks: Vec<&str>) -> Result<()> {
    if !matches!(toks.len(), 3 | 4 | 6) {
        return Err(at_line(
            path,
            line,
            "v",
            format!(
                "expected 3 coordinates (+ w or r g b), found {}",
                toks.len()
            ),
        ));
    }
    for t in &toks {
        parse_obj_float(path, line, "v", Some(t))?;
    }
    if toks.len() == 4 && toks[3].parse::<f32>().ok() == Some(0.0) {
        return Err(at_line(path, line, "v", "homogeneous w = 0"));
    }
    Ok(())
}

/// An `f` record: at least 3 corners `v[/vt[/vn]]`, every index in range.
fn check_obj_face(path: &Path, line: usize, corners: Vec<&str>, c: &mut ObjCounts) -> Result<()> {
    if corners.len() < 3 {
        return Err(at_line(
            path,
            line,
            "f",
            format!("a face needs at least 3 vertices, found {}", corners.len()),
        ));
    }
    for corner in corners {
        let parts: Vec<&str> = corner.split('/').collect();
        if parts.len() > 3 || parts[0].is_empty() {
            return Err(at_line(
                path,
                line,
                "f",
                format!("malformed face vertex '{corner}'"),
            ));
        }
        check_obj_index(path, line, "vertex", parts[0], c.seen[0], c.total[0])?;
        match parts.get(1).filter(|s| !s.is_empty()) {
            Some(t) => {
                check_obj_index(path, line, "texture coordinate", t, c.seen[1], c.total[1])?;
                c.uv.0 = true;
            }
            None => c.uv.1 = true,
        }
        match parts.get(2).filter(|s| !s.is_empty()) {
            Some(t) => {
                check_obj_index(path, line, "normal", t, c.seen[2], c.total[2])?;
                c.normal.0 = true;
            }
            None => c.normal.1 = true,
        }
    }
    Ok(())
}

/// Load a Wavefront OBJ file (all objects and groups merged, polygons fan-triangulated),
/// keeping positions, normals and UVs as written (see the module docs on conventions).
pub fn load_obj(path: &Path) -> Result<Mesh> {
    parse_obj_bytes(&read_bytes(path)?, path)
}

/// [`load_obj`] on the bytes of a file already read (the text must be UTF-8); `path` names
/// the file in errors.
pub fn parse_obj_bytes(bytes: &[u8], path: &Path) -> Result<Mesh> {
    let text = std::str::from_utf8(bytes)
        .map_err(|_| Error::input(path, "the OBJ file is not valid UTF-8 text"))?;
    parse_obj(text, path)
}

/// [`load_obj`] on text already read; `path` names the file in errors.
pub fn parse_obj(text: &str, path: &Path) -> Result<Mesh> {
    let scan = scan_obj(text, path)?;
    let opts = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ignore_points: true,
        ignore_lines: true,
    };
    let (models, _materials) = tobj::load_obj_buf(&mut scan.text.as_bytes(), &opts, |_| {
        // Materials are not trusted (we recover them); never open .mtl files.
        Err(tobj::LoadError::OpenFileFailed)
    })
    .map_err(|e| Error::input(path, format!("cannot read OBJ: {e}")))?;

    let mut mesh = Mesh::default();
    let mut uvs = Vec::new();
    let mut normals = Vec::new();
    let (mut keep_uv, mut keep_n) = (scan.all_uv, scan.all_normal);
    for m in &models {
        let m = &m.mesh;
        let base = mesh.positions.len();
        let nverts = m.positions.len() / 3;
        let offset = u32::try_from(base)
            .map_err(|_| Error::input(path, "too many vertices for 32-bit indices"))?;
        mesh.positions.extend(
            m.positions
                .chunks_exact(3)
                .map(|p| Vec3::new(p[0], p[1], p[2])),
        );
        keep_uv &= m.texcoords.len() == nverts * 2;
        keep_n &= m.normals.len() == nverts * 3;
        if keep_uv {
            uvs.extend(m.texcoords.chunks_exact(2).map(|t| Vec2::new(t[0], t[1])));
        }
        if keep_n {
            normals.extend(
                m.normals
                    .chunks_exact(3)
                    .map(|n| Vec3::new(n[0], n[1], n[2]).normalize_or_zero()),
            );
        }
        for t in m.indices.chunks_exact(3) {
            if t.iter().any(|&i| i as usize >= nverts) {
                return Err(Error::input(path, "internal OBJ index out of range"));
            }
            mesh.triangles
                .push([t[0] + offset, t[1] + offset, t[2] + offset]);
        }
    }
    mesh.uvs = keep_uv.then_some(uvs);
    mesh.normals = keep_n.then_some(normals);
    if mesh.triangles.is_empty() {
        return Err(Error::input(path, "the OBJ file has no faces"));
    }
    check_finite(&mesh, path)?;
    Ok(mesh)
}

// ---------------------------------------------------------------------------------------------
// PLY
// ---------------------------------------------------------------------------------------------

/// ply-rs's message on one line, without its nested debug dump of the inner error.
fn ply_message(e: &std::io::Error) -> String {
    let s = one_line(&e.to_string());
    match s.find(" Error: Custom {") {
        Some(i) => s[..i].to_string(),
        None => s,
    }
}

/// One PLY element, keeping only the properties a mesh needs (faster than ply-rs's maps).
#[derive(Default)]
struct PlyRecord {
    xyz: [Option<f64>; 3],
    n: [Option<f64>; 3],
    /// `u v`, `texture_u texture_v`, `s t`, in Mitsuba's order of preference.
    uv: [[Option<f64>; 2]; 3],
    /// `vertex_index` (preferred, as Mitsuba) and `vertex_indices`.
    index: [Option<Vec<i64>>; 2],
    non_integer_index: bool,
}

fn ply_scalar(p: &ply_rs::ply::Property) -> Option<f64> {
    use ply_rs::ply::Property as P;
    Some(match *p {
        P::Char(v) => v as f64,
        P::UChar(v) => v as f64,
        P::Short(v) => v as f64,
        P::UShort(v) => v as f64,
        P::Int(v) => v as f64,
        P::UInt(v) => v as f64,
        P::Float(v) => v as f64,
        P::Double(v) => v,
        _ => return None,
    })
}

fn ply_index_list(p: &ply_rs::ply::Property) -> Option<Vec<i64>> {
    use ply_rs::ply::Property as P;
    Some(match p {
        P::ListChar(v) => v.iter().map(|&i| i as i64).collect(),
        P::ListUChar(v) => v.iter().map(|&i| i as i64).collect(),
        P::ListShort(v) => v.iter().map(|&i| i as i64).collect(),
        P::ListUShort(v) => v.iter().map(|&i| i as i64).collect(),
        P::ListInt(v) => v.iter().map(|&i| i as i64).collect(),
        P::ListUInt(v) => v.iter().map(|&i| i as i64).collect(),
        _ => return None,
    })
}

impl ply_rs::ply::PropertyAccess for PlyRecord {
    fn new() -> Self {
        PlyRecord::default()
    }
    fn set_property(&mut self, key: String, p: ply_rs::ply::Property) {
        let slot = match key.as_str() {
            "x" => &mut self.xyz[0],
            "y" => &mut self.xyz[1],
            "z" => &mut self.xyz[2],
            "nx" => &mut self.n[0],
            "ny" => &mut self.n[1],
            "nz" => &mut self.n[2],
            "u" => &mut self.uv[0][0],
            "v" => &mut self.uv[0][1],
            "texture_u" => &mut self.uv[1][0],
            "texture_v" => &mut self.uv[1][1],
            "s" => &mut self.uv[2][0],
            "t" => &mut self.uv[2][1],
            "vertex_index" | "vertex_indices" => {
                let k = usize::from(key == "vertex_indices");
                match ply_index_list(&p) {
                    Some(l) => self.index[k] = Some(l),
                    None => self.non_integer_index = true,
                }
                return;
            }
            _ => return,
        };
        *slot = ply_scalar(&p);
    }
}

/// Refuse headers whose element counts cannot fit in the file (each record takes at least
/// one byte); ply-rs would otherwise loop a long time on records of no properties.
fn check_ply_header(bytes: &[u8], path: &Path) -> Result<()> {
    let end = bytes
        .windows(10)
        .position(|w| w == b"end_header")
        .ok_or_else(|| Error::input(path, "not a PLY file (no end_header)"))?;
    let header = String::from_utf8_lossy(&bytes[..end]);
    let mut current: Option<(usize, u64, usize)> = None; // (line, count, properties)
    let mut total: u64 = 0;
    let finish = |c: Option<(usize, u64, usize)>, total: &mut u64| -> Result<()> {
        if let Some((line, count, props)) = c {
            if count > 0 && props == 0 {
                return Err(at_line(path, line, "element", "element without properties"));
            }
            *total = total.saturating_add(count);
        }
        Ok(())
    };
    for (i, l) in header.lines().enumerate() {
        let mut w = l.split_whitespace();
        let keyword = w.clone().next();
        if let (Some(k @ ("format" | "element")), Some(n)) = (keyword, oversized_number(l)) {
            return Err(at_line(path, i + 1, k, format!("number {n} is too large")));
        }
        match w.next() {
            Some("element") => {
                finish(current.take(), &mut total)?;
                let _name = w.next();
                let count: u64 = w
                    .next()
                    .and_then(|c| c.parse().ok())
                    .ok_or_else(|| at_line(path, i + 1, "element", "missing or invalid count"))?;
                current = Some((i + 1, count, 0));
            }
            Some("property") => {
                if let Some(c) = &mut current {
                    c.2 += 1;
                }
            }
            _ => {}
        }
    }
    finish(current.take(), &mut total)?;
    if total > bytes.len() as u64 {
        return Err(Error::input(
            path,
            format!(
                "the header declares {total} records but the file has only {} bytes",
                bytes.len()
            ),
        ));
    }
    Ok(())
}

/// The first run of digits in `line` that does not fit a `u64` (ply-rs panics on those in
/// `format` and `element` lines).
fn oversized_number(line: &str) -> Option<&str> {
    line.split(|c: char| !c.is_ascii_digit())
        .find(|run| !run.is_empty() && run.parse::<u64>().is_err())
}

/// Load a PLY mesh (ASCII or binary, either byte order): `vertex` with `x y z`, optional
/// `nx ny nz` and `u v` / `texture_u texture_v` / `s t`; `face` with a `vertex_index` or
/// `vertex_indices` list (polygons are fan-triangulated). Other elements and properties are
/// ignored. UVs are converted to the OBJ convention (`v -> 1 - v`, see the module docs).
pub fn load_ply(path: &Path) -> Result<Mesh> {
    let bytes = read_bytes(path)?;
    parse_ply(&bytes, path)
}

/// [`load_ply`] on bytes already read; `path` names the file in errors.
pub fn parse_ply(bytes: &[u8], path: &Path) -> Result<Mesh> {
    check_ply_header(bytes, path)?;
    let parser = ply_rs::parser::Parser::<PlyRecord>::new();
    let ply = parser
        .read_ply(&mut &bytes[..])
        .map_err(|e| Error::input(path, format!("cannot read PLY: {}", ply_message(&e))))?;
    let (has_n, uv_slot) = ply_vertex_layout(&ply, path)?;
    let verts = ply.payload.get("vertex").map(Vec::as_slice).unwrap_or(&[]);
    let mut mesh = ply_vertices(verts, has_n, uv_slot, path)?;
    if mesh.positions.len() > u32::MAX as usize {
        return Err(Error::input(path, "too many vertices for 32-bit indices"));
    }
    if let Some(fdef) = ply.header.elements.get("face") {
        if !fdef.properties.contains_key("vertex_index")
            && !fdef.properties.contains_key("vertex_indices")
        {
            return Err(Error::input(
                path,
                "the 'face' element has no 'vertex_index'/'vertex_indices' list",
            ));
        }
    }
    let faces = ply.payload.get("face").map(Vec::as_slice).unwrap_or(&[]);
    mesh.triangles = ply_triangles(faces, mesh.positions.len() as i64, path)?;
    if mesh.triangles.is_empty() {
        return Err(Error::input(path, "the PLY file has no faces"));
    }
    Ok(mesh)
}

/// Whether the PLY's vertices have normals, and which of the texture-coordinate name pairs
/// they use; an error without `x`, `y`, `z`.
fn ply_vertex_layout(
    ply: &ply_rs::ply::Ply<PlyRecord>,
    path: &Path,
) -> Result<(bool, Option<usize>)> {
    let vdef = ply
        .header
        .elements
        .get("vertex")
        .ok_or_else(|| Error::input(path, "the PLY file has no 'vertex' element"))?;
    let has = |k: &str| vdef.properties.contains_key(k);
    for k in ["x", "y", "z"] {
        if !has(k) {
            return Err(Error::input(
                path,
                format!("the 'vertex' element has no '{k}' property"),
            ));
        }
    }
    let has_n = has("nx") && has("ny") && has("nz");
    let uv_slot = [("u", "v"), ("texture_u", "texture_v"), ("s", "t")]
        .iter()
        .position(|(a, b)| has(a) && has(b));
    Ok((has_n, uv_slot))
}

/// The vertices' positions, normals (if `has_n`) and texture coordinates (pair `uv_slot`, v
/// flipped to kdmap's v-up); non-finite values refused by vertex.
fn ply_vertices(
    verts: &[PlyRecord],
    has_n: bool,
    uv_slot: Option<usize>,
    path: &Path,
) -> Result<Mesh> {
    let mut mesh = Mesh::default();
    let mut normals = Vec::new();
    let mut uvs = Vec::new();
    for (i, r) in verts.iter().enumerate() {
        let get = |v: Option<f64>| v.unwrap_or(0.0) as f32;
        let bad = |msg: &str| at_line_free(path, format!("vertex {i}"), msg);
        let p = Vec3::new(get(r.xyz[0]), get(r.xyz[1]), get(r.xyz[2]));
        if !p.is_finite() {
            return Err(bad("non-finite position"));
        }
        mesh.positions.push(p);
        if has_n {
            let n = Vec3::new(get(r.n[0]), get(r.n[1]), get(r.n[2]));
            if !n.is_finite() || n.length_squared() == 0.0 || !n.normalize().is_finite() {
                return Err(bad("non-finite or zero-length normal"));
            }
            normals.push(n.normalize());
        }
        if let Some(k) = uv_slot {
            let uv = Vec2::new(get(r.uv[k][0]), 1.0 - get(r.uv[k][1]));
            if !uv.is_finite() {
                return Err(bad("non-finite texture coordinate"));
            }
            uvs.push(uv);
        }
    }
    mesh.normals = has_n.then_some(normals);
    mesh.uvs = uv_slot.map(|_| uvs);
    Ok(mesh)
}

/// The faces as triangles (polygons fanned from their first vertex), each index checked
/// against the `nv` vertices.
fn ply_triangles(faces: &[PlyRecord], nv: i64, path: &Path) -> Result<Vec<[u32; 3]>> {
    let mut out = Vec::new();
    for (f, r) in faces.iter().enumerate() {
        let bad = |msg: String| at_line_free(path, format!("face {f}"), msg);
        if r.non_integer_index {
            return Err(bad("vertex indices are not integers".into()));
        }
        let Some(idx) = r.index[0].as_ref().or(r.index[1].as_ref()) else {
            return Err(bad("no vertex index list".into()));
        };
        if idx.len() < 3 {
            return Err(bad(format!(
                "a face needs at least 3 vertices, found {}",
                idx.len()
            )));
        }
        if let Some(b) = idx.iter().find(|&&i| i < 0 || i >= nv) {
            return Err(bad(format!(
                "vertex index {b} out of range (the file has {nv} vertices)"
            )));
        }
        for k in 2..idx.len() {
            out.push([idx[0] as u32, idx[k - 1] as u32, idx[k] as u32]);
        }
    }
    Ok(out)
}

/// An error located by record (e.g. `vertex 12`) rather than by line.
fn at_line_free(path: &Path, element: String, msg: impl Into<String>) -> Error {
    Error::Input {
        path: path.to_path_buf(),
        loc: Location {
            element: Some(element),
            ..Default::default()
        },
        msg: msg.into(),
    }
}

// ---------------------------------------------------------------------------------------------
// Built-in shapes (Mitsuba 3 conventions, local space)
// ---------------------------------------------------------------------------------------------

/// Mitsuba's `rectangle`: `[-1, 1]^2` in the `z = 0` plane, facing +z, two triangles.
/// Mitsuba's `uv = ((x + 1) / 2, (y + 1) / 2)`, stored here in the OBJ convention.
/// No vertex normals: the surface is flat, so shading uses the geometric normal.
pub fn rectangle() -> Mesh {
    let positions = vec![
        Vec3::new(-1.0, -1.0, 0.0),
        Vec3::new(1.0, -1.0, 0.0),
        Vec3::new(1.0, 1.0, 0.0),
        Vec3::new(-1.0, 1.0, 0.0),
    ];
    let uvs = positions
        .iter()
        .map(|p| Vec2::new((p.x + 1.0) / 2.0, 1.0 - (p.y + 1.0) / 2.0))
        .collect();
    Mesh {
        positions,
        normals: None,
        uvs: Some(uvs),
        triangles: vec![[0, 1, 2], [0, 2, 3]],
        flipped: Vec::new(),
    }
}

/// Mitsuba's `cube`: `[-1, 1]^3`, 24 vertices (4 per face) with outward face normals, each
/// face mapped onto `[0, 1]^2` in uv as Mitsuba lays it out, two counter-clockwise (seen from
/// outside) triangles per face.
pub fn cube() -> Mesh {
    // Per face: outward normal and its four corners in Mitsuba's order; the corners take
    // Mitsuba uvs (0,1) (1,1) (1,0) (0,0) and form triangles (0,1,2) and (3,0,2).
    const FACES: [([f32; 3], [[f32; 3]; 4]); 6] = [
        (
            [0., -1., 0.],
            [
                [1., -1., -1.],
                [1., -1., 1.],
                [-1., -1., 1.],
                [-1., -1., -1.],
            ],
        ),
        (
            [0., 1., 0.],
            [[1., 1., -1.], [-1., 1., -1.], [-1., 1., 1.], [1., 1., 1.]],
        ),
        (
            [1., 0., 0.],
            [[1., -1., -1.], [1., 1., -1.], [1., 1., 1.], [1., -1., 1.]],
        ),
        (
            [0., 0., 1.],
            [[1., -1., 1.], [1., 1., 1.], [-1., 1., 1.], [-1., -1., 1.]],
        ),
        (
            [-1., 0., 0.],
            [
                [-1., -1., 1.],
                [-1., 1., 1.],
                [-1., 1., -1.],
                [-1., -1., -1.],
            ],
        ),
        (
            [0., 0., -1.],
            [
                [1., 1., -1.],
                [1., -1., -1.],
                [-1., -1., -1.],
                [-1., 1., -1.],
            ],
        ),
    ];
    const MITSUBA_UV: [[f32; 2]; 4] = [[0., 1.], [1., 1.], [1., 0.], [0., 0.]];
    let mut m = Mesh {
        normals: Some(Vec::with_capacity(24)),
        uvs: Some(Vec::with_capacity(24)),
        ..Default::default()
    };
    for (f, (n, corners)) in FACES.iter().enumerate() {
        for (c, uv) in corners.iter().zip(MITSUBA_UV) {
            m.positions.push(Vec3::from_array(*c));
            if let Some(ns) = &mut m.normals {
                ns.push(Vec3::from_array(*n));
            }
            if let Some(us) = &mut m.uvs {
                us.push(Vec2::new(uv[0], 1.0 - uv[1]));
            }
        }
        let b = 4 * f as u32;
        m.triangles.push([b, b + 1, b + 2]);
        m.triangles.push([b + 3, b, b + 2]);
    }
    m
}

/// Mitsuba's `sphere` of radius 1 at the origin, tessellated as a UV sphere of
/// [`SPHERE_RINGS`] x [`SPHERE_SEGMENTS`] quads (one triangle at each pole), with exact unit
/// outward normals and Mitsuba's `uv = (phi / 2pi, theta / pi)` (theta from +z, phi from +x
/// towards +y) in the OBJ convention. The seam and poles have duplicated vertices so the UVs
/// stay continuous. Its area is about 0.04% below `4 pi` (flat facets).
pub fn sphere() -> Mesh {
    let (nr, ns) = (SPHERE_RINGS, SPHERE_SEGMENTS);
    let mut m = Mesh {
        normals: Some(Vec::new()),
        uvs: Some(Vec::new()),
        ..Default::default()
    };
    for i in 0..=nr {
        let theta = std::f64::consts::PI * i as f64 / nr as f64;
        for j in 0..=ns {
            let phi = std::f64::consts::TAU * j as f64 / ns as f64;
            // Exact zeros at the poles and seam so duplicated vertices coincide.
            let (st, ct) = if i == 0 {
                (0.0, 1.0)
            } else if i == nr {
                (0.0, -1.0)
            } else {
                theta.sin_cos()
            };
            let (sp, cp) = if j == 0 || j == ns {
                (0.0, 1.0)
            } else {
                phi.sin_cos()
            };
            let p = Vec3::new((st * cp) as f32, (st * sp) as f32, ct as f32);
            m.positions.push(p);
            if let Some(n) = &mut m.normals {
                n.push(p);
            }
            if let Some(u) = &mut m.uvs {
                u.push(Vec2::new(j as f32 / ns as f32, 1.0 - i as f32 / nr as f32));
            }
        }
    }
    let idx = |i: usize, j: usize| (i * (ns + 1) + j) as u32;
    for i in 0..nr {
        for j in 0..ns {
            let (a, b, c, d) = (idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1));
            if i != 0 {
                m.triangles.push([a, c, d]);
            }
            if i != nr - 1 {
                m.triangles.push([a, b, c]);
            }
        }
    }
    m
}

// ---------------------------------------------------------------------------------------------
// Mesh edits used by the XML loader
// ---------------------------------------------------------------------------------------------

/// Mitsuba's `flip_normals`: the surface's front becomes its back. Reverses every triangle's
/// winding (so the geometric normal flips) and negates the vertex normals.
pub fn flip_normals(mesh: &mut Mesh) {
    for t in &mut mesh.triangles {
        t.swap(1, 2);
    }
    if let Some(ns) = &mut mesh.normals {
        for n in ns.iter_mut() {
            *n = -*n;
        }
    }
}

/// Mitsuba's smooth vertex normals for meshes without them: at each vertex, the mean of the
/// unit normals of its triangles weighted by the triangle's angle at that vertex. Vertices of
/// degenerate triangles only get a zero normal (which shading treats as absent).
pub fn compute_vertex_normals(mesh: &Mesh) -> Vec<Vec3> {
    let mut acc = vec![Vec3::ZERO; mesh.positions.len()];
    for t in &mesh.triangles {
        let p = t.map(|i| mesh.positions[i as usize]);
        let n = (p[1] - p[0]).cross(p[2] - p[0]).normalize_or_zero();
        if n == Vec3::ZERO {
            continue;
        }
        for k in 0..3 {
            let e1 = (p[(k + 1) % 3] - p[k]).normalize_or_zero();
            let e2 = (p[(k + 2) % 3] - p[k]).normalize_or_zero();
            let angle = e1.dot(e2).clamp(-1.0, 1.0).acos();
            acc[t[k] as usize] += n * angle;
        }
    }
    acc.into_iter().map(Vec3::normalize_or_zero).collect()
}

/// Mirror the texture coordinates vertically (`v -> 1 - v`), e.g. for an OBJ with
/// `flip_tex_coords = false`.
pub fn flip_v(mesh: &mut Mesh) {
    if let Some(uvs) = &mut mesh.uvs {
        for uv in uvs.iter_mut() {
            uv.y = 1.0 - uv.y;
        }
    }
}

/// Every position, normal and UV must be finite (e.g. after an extreme `to_world`).
pub fn check_finite(mesh: &Mesh, path: &Path) -> Result<()> {
    if let Some(i) = mesh.positions.iter().position(|p| !p.is_finite()) {
        return Err(at_line_free(
            path,
            format!("vertex {i}"),
            "non-finite position",
        ));
    }
    if let Some(ns) = &mesh.normals {
        if let Some(i) = ns.iter().position(|n| !n.is_finite()) {
            return Err(at_line_free(
                path,
                format!("vertex {i}"),
                "non-finite normal",
            ));
        }
    }
    if let Some(us) = &mesh.uvs {
        if let Some(i) = us.iter().position(|u| !u.is_finite()) {
            return Err(at_line_free(
                path,
                format!("vertex {i}"),
                "non-finite texture coordinate",
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn write(dir: &Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
        let p = dir.join(name);
        std::fs::File::create(&p).unwrap().write_all(bytes).unwrap();
        p
    }

    const QUAD_OBJ: &str = "# a unit quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n\
        vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 2\n\
        o a\nf 1/1/1 2/2/1 3/3/1 4/4/1\nl 1 2 3\np 1\n";

    #[test]
    fn a_device_or_directory_named_as_a_mesh_is_refused_not_read() {
        let dir = tempfile::tempdir().unwrap();
        for p in [Path::new("/dev/zero"), dir.path()] {
            for load in [load_obj, load_ply] {
                let e = load(p).unwrap_err();
                assert!(matches!(e, Error::Input { .. }), "{e}");
                assert!(e.to_string().contains("not a regular file"), "{e}");
            }
        }
    }

    #[test]
    fn obj_quad_is_two_triangles_with_uvs_and_normals() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(dir.path(), "quad.obj", QUAD_OBJ.as_bytes());
        let m = load_obj(&p).unwrap();
        assert_eq!(m.triangles.len(), 2, "the polyline and point add nothing");
        assert_eq!(m.positions.len(), 4);
        assert!((m.area() - 1.0).abs() < 1e-6);
        let uvs = m.uvs.as_ref().unwrap();
        // UVs kept as written (OBJ convention).
        for (p, uv) in m.positions.iter().zip(uvs) {
            assert_eq!(Vec2::new(p.x, p.y), *uv);
        }
        let ns = m.normals.as_ref().unwrap();
        assert!(
            ns.iter().all(|n| (*n - Vec3::Z).length() < 1e-6),
            "normalized"
        );
        assert!(m.face_normal_raw(0).z > 0.0);
    }

    #[test]
    fn obj_groups_merge_and_relative_indices_resolve() {
        let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\ng a\nf -3 -2 -1\nv 0 0 1\ng b\nf 1 2 4\n";
        let m = parse_obj(text, Path::new("g.obj")).unwrap();
        assert_eq!(m.triangles.len(), 2);
        assert!(m.normals.is_none() && m.uvs.is_none());
        assert!((m.area() - 1.0).abs() < 1e-6);
    }

    #[test]
    fn obj_mixed_uvs_are_dropped() {
        let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3/1\nf 1 3 2\n";
        let m = parse_obj(text, Path::new("m.obj")).unwrap();
        assert!(m.uvs.is_none());
        assert_eq!(m.triangles.len(), 2);
    }

    #[test]
    fn obj_errors_name_file_and_line() {
        let cases = [
            (
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n",
                "line 4",
                "out of range",
            ),
            ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n", "line 4", "index 0"),
            (
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -4 2 3\n",
                "line 4",
                "out of range",
            ),
            (
                "v 0 0 0\nv 1 0 0\nvt 0 0\nv 0 1 0\nf 1/-2 2/1 3/1\n",
                "line 5",
                "out of range",
            ),
            (
                "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n",
                "line 2",
                "non-finite",
            ),
            (
                "v 0 0 0\nv 1 0 inf\nv 0 1 0\nf 1 2 3\n",
                "line 2",
                "non-finite",
            ),
            (
                "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 0\nf 1//1 2//1 3//1\n",
                "line 4",
                "zero",
            ),
            ("v 0 0 0\nv 1 0 0\nf 1 2\n", "line 3", "at least 3"),
            ("v 0 0 0\nv 1 0 x\n", "line 2", "invalid number"),
            ("v 0 0 0\nv 1 0 0\nv 0 1 0\n", "", "no faces"),
            ("", "", "no faces"),
        ];
        for (text, line, what) in cases {
            let e = parse_obj(text, Path::new("bad.obj"))
                .unwrap_err()
                .to_string();
            assert!(e.starts_with("bad.obj"), "{e}");
            assert!(e.contains(line), "{text:?}: {e}");
            assert!(e.contains(what), "{text:?}: {e}");
        }
    }

    #[test]
    fn obj_missing_file_is_io_error() {
        let e = load_obj(Path::new("/nonexistent/x.obj"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("/nonexistent/x.obj"), "{e}");
    }

    const ASCII_PLY: &str = "ply\nformat ascii 1.0\ncomment test\nelement vertex 4\n\
        property float x\nproperty float y\nproperty float z\nproperty float nx\n\
        property float ny\nproperty float nz\nproperty float s\nproperty float t\n\
        element face 1\nproperty list uchar int vertex_indices\nend_header\n\
        0 0 0 0 0 1 0 0\n2 0 0 0 0 1 1 0\n2 2 0 0 0 1 1 1\n0 2 0 0 0 1 0 1\n4 0 1 2 3\n";

    #[test]
    fn ply_ascii_quad() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(dir.path(), "q.ply", ASCII_PLY.as_bytes());
        let m = load_ply(&p).unwrap();
        assert_eq!(m.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        assert!((m.area() - 4.0).abs() < 1e-6);
        assert_eq!(m.normals.as_ref().unwrap()[2], Vec3::Z);
        // PLY v is Mitsuba's (down); stored flipped.
        assert_eq!(m.uvs.as_ref().unwrap()[2], Vec2::new(1.0, 0.0));
        assert_eq!(m.uvs.as_ref().unwrap()[0], Vec2::new(0.0, 1.0));
    }

    fn binary_ply(big_endian: bool, bad_index: bool) -> Vec<u8> {
        let fmt = if big_endian {
            "binary_big_endian"
        } else {
            "binary_little_endian"
        };
        let mut b = format!(
            "ply\nformat {fmt} 1.0\nelement vertex 3\nproperty double x\nproperty double y\n\
             property double z\nproperty float u\nproperty float v\nproperty uchar red\n\
             element face 1\nproperty list uchar uint vertex_index\nend_header\n"
        )
        .into_bytes();
        let verts = [[0.0f64, 0.0, 0.0], [3.0, 0.0, 0.0], [0.0, 4.0, 0.0]];
        for (i, v) in verts.iter().enumerate() {
            for c in v {
                b.extend(if big_endian {
                    c.to_be_bytes()
                } else {
                    c.to_le_bytes()
                });
            }
            for c in [i as f32 * 0.5, 0.25f32] {
                b.extend(if big_endian {
                    c.to_be_bytes()
                } else {
                    c.to_le_bytes()
                });
            }
            b.push(255);
        }
        b.push(3);
        let last = if bad_index { 3u32 } else { 2 };
        for i in [0u32, 1, last] {
            b.extend(if big_endian {
                i.to_be_bytes()
            } else {
                i.to_le_bytes()
            });
        }
        b
    }

    #[test]
    fn ply_binary_both_byte_orders() {
        let dir = tempfile::tempdir().unwrap();
        for be in [false, true] {
            let p = write(dir.path(), "t.ply", &binary_ply(be, false));
            let m = load_ply(&p).unwrap();
            assert_eq!(m.triangles, vec![[0, 1, 2]]);
            assert!((m.area() - 6.0).abs() < 1e-9, "{}", m.area());
            assert!(m.normals.is_none());
            assert_eq!(m.uvs.as_ref().unwrap()[1], Vec2::new(0.5, 0.75));
        }
    }

    #[test]
    fn ply_errors() {
        let e = parse_ply(&binary_ply(false, true), Path::new("b.ply"))
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("b.ply") && e.contains("face 0") && e.contains("out of range"),
            "{e}"
        );
        let mut nan = binary_ply(false, false);
        let header = nan.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        nan[header + 33..header + 41].copy_from_slice(&f64::NAN.to_le_bytes());
        let e = parse_ply(&nan, Path::new("n.ply")).unwrap_err().to_string();
        assert!(
            e.contains("n.ply") && e.contains("vertex 1") && e.contains("non-finite"),
            "{e}"
        );
        let nan = ASCII_PLY.replace("2 2 0 0 0 1 1 1", "2 nan 0 0 0 1 1 1");
        let e = parse_ply(nan.as_bytes(), Path::new("a.ply"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("a.ply") && e.contains("Line 18") && !e.contains("Custom"),
            "{e}"
        );
        let trunc = &binary_ply(true, false)[..200];
        let e = parse_ply(trunc, Path::new("t.ply"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("t.ply"), "{e}");
        let huge =
            "ply\nformat ascii 1.0\nelement vertex 100000000000\nproperty float x\nend_header\n";
        let e = parse_ply(huge.as_bytes(), Path::new("h.ply"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("records"), "{e}");
        let e = parse_ply(b"not a ply", Path::new("x.ply"))
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("x.ply"), "{e}");
        assert!(!e.contains('\n'));
    }

    #[test]
    fn rectangle_matches_mitsuba() {
        let m = rectangle();
        assert_eq!(m.triangles.len(), 2);
        assert!((m.area() - 4.0).abs() < 1e-6);
        for t in 0..2 {
            assert!(m.face_normal_raw(t).normalize().abs_diff_eq(Vec3::Z, 1e-6));
        }
        // Mitsuba uv (0,0) at (-1,-1): OBJ-convention v = 1 there.
        assert_eq!(m.uvs.as_ref().unwrap()[0], Vec2::new(0.0, 1.0));
        assert_eq!(m.uvs.as_ref().unwrap()[2], Vec2::new(1.0, 0.0));
    }

    #[test]
    fn cube_is_closed_outward_and_ccw() {
        let m = cube();
        assert_eq!(m.positions.len(), 24);
        assert_eq!(m.triangles.len(), 12);
        assert!((m.area() - 24.0).abs() < 1e-5);
        let ns = m.normals.as_ref().unwrap();
        for t in 0..12 {
            let g = m.face_normal_raw(t).normalize();
            let [a, b, c] = m.triangles[t];
            let centroid =
                (m.positions[a as usize] + m.positions[b as usize] + m.positions[c as usize]) / 3.0;
            assert!(g.dot(centroid) > 0.0, "triangle {t} faces inward");
            for i in [a, b, c] {
                assert!(
                    ns[i as usize].abs_diff_eq(g, 1e-6),
                    "normal of triangle {t}"
                );
            }
        }
        let uvs = m.uvs.as_ref().unwrap();
        assert!(uvs.iter().all(|u| u.x == 0.0 || u.x == 1.0));
    }

    #[test]
    fn sphere_is_outward_with_mitsuba_uvs() {
        let m = sphere();
        assert_eq!(m.triangles.len(), 2 * SPHERE_SEGMENTS * (SPHERE_RINGS - 1));
        let area = m.area();
        let exact = 4.0 * std::f64::consts::PI;
        assert!(area < exact && area > exact * 0.999, "{area}");
        let (ns, uvs) = (m.normals.as_ref().unwrap(), m.uvs.as_ref().unwrap());
        for t in 0..m.triangles.len() {
            let [a, b, c] = m.triangles[t];
            let centroid =
                (m.positions[a as usize] + m.positions[b as usize] + m.positions[c as usize]) / 3.0;
            assert!(
                m.face_normal_raw(t).dot(centroid) > 0.0,
                "triangle {t} faces inward"
            );
        }
        for ((p, n), uv) in m.positions.iter().zip(ns).zip(uvs) {
            assert!((p.length() - 1.0).abs() < 1e-6 && *p == *n);
            // theta = pi (1 - v_obj)
            let theta = std::f32::consts::PI * (1.0 - uv.y);
            assert!((p.z - theta.cos()).abs() < 1e-5);
        }
        // A point at phi = pi/2 has u = 1/4.
        let i = (0..m.positions.len())
            .max_by(|&a, &b| m.positions[a].y.total_cmp(&m.positions[b].y))
            .unwrap();
        assert!((uvs[i].x - 0.25).abs() < 1e-6);
    }

    #[test]
    fn flip_and_smooth_normals() {
        let mut m = cube();
        flip_normals(&mut m);
        for t in 0..12 {
            let [a, b, c] = m.triangles[t];
            let centroid =
                (m.positions[a as usize] + m.positions[b as usize] + m.positions[c as usize]) / 3.0;
            assert!(m.face_normal_raw(t).dot(centroid) < 0.0);
            assert!(m.normals.as_ref().unwrap()[a as usize].dot(centroid) < 0.0);
        }
        // A tetrahedron corner shared by three faces at right angles: normal along (1,1,1).
        let t = Mesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
            triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2]],
            ..Default::default()
        };
        let n = compute_vertex_normals(&t);
        assert!(n[0].abs_diff_eq(-Vec3::ONE.normalize(), 1e-6), "{:?}", n[0]);
        let mut q = rectangle();
        flip_v(&mut q);
        assert_eq!(q.uvs.as_ref().unwrap()[0], Vec2::ZERO);
    }
}
