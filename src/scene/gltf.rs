//! glTF 2.0 (`.gltf` with its buffers, or `.glb`) -> [`Scene`]: the second scene format, for
//! scenes from Blender, three.js and game engines. Parsing and validation are the `gltf`
//! crate's; this module resolves buffers (GLB blob, files beside the scene, base64 `data:`
//! URIs: the crate's own importer would pull in an image decoder kdmap never uses), composes
//! the node hierarchy of the default scene and settles everything once, as
//! [`super::mitsuba`] does:
//!
//! - every triangle primitive of every mesh node is a shape in world space, reconstructed
//!   (diffuse of unknown albedo, [`Material::Unknown`]) whatever its glTF material says:
//!   `baseColor`, `metallic`, `roughness`, `KHR_materials_transmission` and the other
//!   material extensions describe a renderer's appearance, not what the photos show, and
//!   glTF's default material is fully metallic, so a metallic or transmissive material is
//!   recovered as the diffuse albedo that explains the photos (docs/guide.md, "glTF 2.0");
//!   `doubleSided` makes it reflect on both sides, else on its front side only (Mitsuba's
//!   `diffuse`). The primitive's id is its node's name (`<name>_<primitive>` when the mesh
//!   has several primitives);
//! - a primitive whose material emits (`emissiveFactor` x `KHR_materials_emissive_strength`,
//!   read as luminance in nits) is an area light with a black surface, emitting on its front
//!   side only, like Mitsuba's `area` emitter (also when `doubleSided`);
//! - perspective cameras become Mitsuba sensors (glTF looks down -Z with +X right; Mitsuba
//!   looks along +z with +x left: the same frame turned half a turn about y), `yfov` is the
//!   vertical field of view; the film size is the photo's (`[views]` or
//!   `images/<node name>.exr|png|jpg|jpeg`), which must match `aspectRatio` when one is given. A camera
//!   without a photo gets a nominal film [`NOMINAL_HEIGHT`] pixels high. Box pixel filter;
//! - `KHR_lights_punctual` point, spot and directional lights (see [`lights`] for the units
//!   and the spot cone).
//!
//! Every refusal is one line naming the file and the JSON path or node, e.g.
//! `scene.gltf, nodes[3] 'Cam': orthographic cameras are not supported`.

use crate::base::error::{Error, Location};
use crate::scene::{Emitter, Scene, Sensor, Shape};
use crate::Result;
use glam::DMat4;
use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};

mod accessor;
mod lights;
mod primitive;
mod sensor;

pub use lights::spot_cone;
pub use sensor::{gltf_camera_to_world, NOMINAL_HEIGHT};

/// What a glTF scene needs from the run besides the file: the photos (for the film sizes)
/// and the photometric unit conversion.
#[derive(Debug, Clone, Copy)]
pub struct LoadOptions<'a> {
    /// The run config's `[views]` (camera id -> photo); empty = `images/<id>.exr`.
    pub views: &'a BTreeMap<String, PathBuf>,
    /// Scene radiance units per photometric unit (cd, lux, nit): `[units] photometric_scale`.
    pub photometric_scale: f32,
    /// Read the mesh data (false: the outline only, meshes empty).
    pub meshes: bool,
}

/// Whether `path` names a glTF file (`.gltf` or `.glb`, any case).
pub fn is_gltf(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("gltf") || e.eq_ignore_ascii_case("glb"))
}

/// Extensions a file may require: the lights and material or texture extensions (which
/// change appearance only; kdmap reconstructs the surface anyway). Geometry compression
/// (Draco, meshopt, quantization) is not among them.
fn extension_supported(name: &str) -> bool {
    name == "KHR_lights_punctual"
        || name.starts_with("KHR_materials_")
        || name.starts_with("KHR_texture_")
        || name.starts_with("EXT_texture_")
}

/// Load a glTF scene. Relative buffer URIs resolve against the file's directory.
pub fn load(path: &Path, opts: &LoadOptions) -> Result<Scene> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse(&bytes, path, opts)
}

/// [`load`] on the file's bytes already read.
pub fn parse(bytes: &[u8], path: &Path, opts: &LoadOptions) -> Result<Scene> {
    let doc = validated(bytes, path)?;
    for ext in doc.extensions_required() {
        if !extension_supported(ext) {
            return Err(at(
                path,
                "extensionsRequired",
                format!("required extension '{ext}' is not supported"),
            ));
        }
    }
    let dir = path
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from("."));
    let mut files = Vec::new();
    let buffers = if opts.meshes {
        read_buffers(&doc, path, &dir, &mut files)?
    } else {
        Vec::new()
    };
    let mut b = Builder {
        path,
        dir,
        opts,
        buffers: &buffers,
        ids: HashSet::new(),
        shapes: Vec::new(),
        emitters: Vec::new(),
        sensors: Vec::new(),
    };
    b.walk(&doc)?;
    let mut emitters = b.emitters;
    for (i, s) in b.shapes.iter().enumerate() {
        if let Some(radiance) = s.emission {
            emitters.push(Emitter::Area { shape: i, radiance });
        }
    }
    Ok(Scene {
        path: path.to_path_buf(),
        shapes: b.shapes,
        emitters,
        sensors: b.sensors,
        files,
    })
}

/// A `gltf` crate error as a one-line input error: JSON syntax errors with their line and
/// column, validation errors with the first offending JSON path.
/// The document, validated by the `gltf` crate after the references its own validation
/// follows unchecked (a primitive's POSITION accessor) are checked here: an index past the
/// accessors panics inside `gltf-json` otherwise.
fn validated(bytes: &[u8], path: &Path) -> Result<::gltf::Gltf> {
    check_glb_length(bytes, path)?;
    let raw =
        ::gltf::Gltf::from_slice_without_validation(bytes).map_err(|e| gltf_error(path, e))?;
    let root = raw.document.as_json();
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            let pos = ::gltf::json::validation::Checked::Valid(::gltf::Semantic::Positions);
            if let Some(i) = prim.attributes.get(&pos) {
                if i.value() >= root.accessors.len() {
                    let what = format!("meshes[{m}].primitives[{p}].attributes.POSITION");
                    let msg = format!(
                        "accessor {} does not exist ({} accessors)",
                        i.value(),
                        root.accessors.len()
                    );
                    return Err(at(path, &what, msg));
                }
            }
        }
    }
    let blob = raw.blob;
    let document =
        ::gltf::Document::from_json(raw.document.into_json()).map_err(|e| gltf_error(path, e))?;
    Ok(::gltf::Gltf { document, blob })
}

/// A GLB's header length must cover the header and fit in the file: the `gltf` crate
/// subtracts the header's 12 bytes from it unchecked (a panic in debug builds).
fn check_glb_length(bytes: &[u8], path: &Path) -> Result<()> {
    if !bytes.starts_with(b"glTF") {
        return Ok(());
    }
    let length = match bytes.get(8..12) {
        Some(b) => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize,
        None => {
            return Err(Error::input(
                path,
                "malformed GLB: header truncated (under 12 bytes)",
            ))
        }
    };
    if length < 12 || length > bytes.len() {
        let msg = format!(
            "malformed GLB: header length {length} is not between 12 and the file's {} bytes",
            bytes.len()
        );
        return Err(Error::input(path, msg));
    }
    Ok(())
}

fn gltf_error(path: &Path, e: ::gltf::Error) -> Error {
    match e {
        ::gltf::Error::Deserialize(j) => Error::Input {
            path: path.to_path_buf(),
            loc: Location {
                line: Some(j.line() as u32),
                col: Some(j.column() as u32),
                element: None,
            },
            msg: format!("malformed glTF JSON: {j}"),
        },
        ::gltf::Error::Validation(list) => {
            let more = match list.len() {
                0 | 1 => String::new(),
                n => format!(" (and {} more)", n - 1),
            };
            match list.first() {
                Some((p, err)) => at(path, &p.to_string(), format!("invalid glTF: {err}{more}")),
                None => Error::input(path, "invalid glTF"),
            }
        }
        ::gltf::Error::Binary(b) => Error::input(path, format!("malformed GLB: {b:?}")),
        ::gltf::Error::Io(io) => Error::io(path, io),
    }
}

/// An input error at a JSON path or node (`nodes[3] 'Cam'`).
pub(crate) fn at(path: &Path, element: &str, msg: impl Into<String>) -> Error {
    Error::Input {
        path: path.to_path_buf(),
        loc: Location {
            element: Some(element.to_string()),
            ..Default::default()
        },
        msg: msg.into(),
    }
}

/// Every buffer's bytes: the GLB blob, a file beside the scene (recorded in `files`) or a
/// base64 `data:` URI; each at least its `byteLength` long.
fn read_buffers(
    doc: &::gltf::Gltf,
    path: &Path,
    dir: &Path,
    files: &mut Vec<PathBuf>,
) -> Result<Vec<Vec<u8>>> {
    let mut out = Vec::new();
    for buf in doc.buffers() {
        let here = format!("buffers[{}]", buf.index());
        let data = match buf.source() {
            ::gltf::buffer::Source::Bin => doc.blob.clone().ok_or_else(|| {
                at(
                    path,
                    &here,
                    "refers to the GLB binary chunk, which is missing",
                )
            })?,
            ::gltf::buffer::Source::Uri(uri) => {
                if let Some(rest) = uri.strip_prefix("data:") {
                    decode_data_uri(rest).map_err(|m| at(path, &here, m))?
                } else {
                    let file = dir.join(percent_decode(uri));
                    let bytes = std::fs::read(&file).map_err(|e| Error::io(&file, e))?;
                    files.push(file);
                    bytes
                }
            }
        };
        if data.len() < buf.length() {
            return Err(at(
                path,
                &here,
                format!(
                    "holds {} bytes but its byteLength is {}",
                    data.len(),
                    buf.length()
                ),
            ));
        }
        out.push(data);
    }
    Ok(out)
}

/// The bytes of a `data:[<mime>];base64,<data>` URI (the part after `data:`).
fn decode_data_uri(rest: &str) -> std::result::Result<Vec<u8>, String> {
    use base64::Engine as _;
    let (meta, data) = rest.split_once(',').ok_or("malformed data URI (no ',')")?;
    if !meta.ends_with(";base64") {
        return Err("data URI is not base64-encoded".into());
    }
    base64::engine::general_purpose::STANDARD
        .decode(data)
        .map_err(|e| format!("data URI: bad base64: {e}"))
}

/// `%XX` escapes of a relative URI decoded (glTF URIs are RFC 3986); malformed escapes are
/// kept as written.
fn percent_decode(uri: &str) -> String {
    let b = uri.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' && i + 2 < b.len() {
            let hex = |c: u8| (c as char).to_digit(16);
            if let (Some(h), Some(l)) = (hex(b[i + 1]), hex(b[i + 2])) {
                out.push((h * 16 + l) as u8);
                i += 3;
                continue;
            }
        }
        out.push(b[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// The scene under construction while the node tree is walked.
struct Builder<'a> {
    path: &'a Path,
    dir: PathBuf,
    opts: &'a LoadOptions<'a>,
    buffers: &'a [Vec<u8>],
    ids: HashSet<String>,
    shapes: Vec<Shape>,
    emitters: Vec<Emitter>,
    sensors: Vec<Sensor>,
}

/// A node's name for messages: `nodes[3] 'Cam'`.
pub(crate) fn node_label(node: &::gltf::Node) -> String {
    match node.name() {
        Some(n) => format!("nodes[{}] '{n}'", node.index()),
        None => format!("nodes[{}]", node.index()),
    }
}

impl Builder<'_> {
    /// Walk the default scene (or the first) depth-first in file order, composing each
    /// node's transform with its parents'. A node reached twice (two parents, a cycle) is
    /// refused: glTF's node hierarchy is a tree.
    fn walk(&mut self, doc: &::gltf::Gltf) -> Result<()> {
        let scene = doc
            .default_scene()
            .or_else(|| doc.scenes().next())
            .ok_or_else(|| at(self.path, "scenes", "the file defines no scene"))?;
        let mut seen = vec![false; doc.nodes().count()];
        let mut stack: Vec<(::gltf::Node, DMat4)> = scene
            .nodes()
            .map(|n| (n, DMat4::IDENTITY))
            .collect::<Vec<_>>();
        stack.reverse();
        while let Some((node, parent)) = stack.pop() {
            if std::mem::replace(&mut seen[node.index()], true) {
                return Err(at(
                    self.path,
                    &node_label(&node),
                    "node is reached twice (two parents or a cycle): glTF nodes form a tree",
                ));
            }
            let local = glam::Mat4::from_cols_array_2d(&node.transform().matrix()).as_dmat4();
            let world = parent * local;
            if !world.is_finite() {
                return Err(at(self.path, &node_label(&node), "non-finite transform"));
            }
            self.node(&node, &world)?;
            let kids: Vec<_> = node.children().map(|c| (c, world)).collect();
            stack.extend(kids.into_iter().rev());
        }
        Ok(())
    }

    /// The shapes, sensor and light of one node at `world`.
    fn node(&mut self, node: &::gltf::Node, world: &DMat4) -> Result<()> {
        if let Some(mesh) = node.mesh() {
            if node.skin().is_some() {
                return Err(at(
                    self.path,
                    &node_label(node),
                    "skinned meshes are not supported (apply the armature before export)",
                ));
            }
            let weights = node.weights().or(mesh.weights()).unwrap_or(&[]);
            if weights.iter().any(|w| *w != 0.0) {
                return Err(at(
                    self.path,
                    &node_label(node),
                    "morph target weights are not supported (apply the shape keys before export)",
                ));
            }
            let n = mesh.primitives().count();
            for prim in mesh.primitives() {
                let base = self.base_name(node, mesh.name(), "mesh");
                let name = if n == 1 {
                    base
                } else {
                    format!("{base}_{}", prim.index())
                };
                let id = self.unique_id(name, node.index());
                let shape = primitive::shape(self, node, &prim, world, id)?;
                self.shapes.push(shape);
            }
        }
        if let Some(cam) = node.camera() {
            let base = self.base_name(node, cam.name(), "camera");
            let id = self.unique_id(base, node.index());
            let s = sensor::sensor(self, node, &cam, world, id)?;
            self.sensors.push(s);
        }
        if let Some(light) = node.light() {
            let e = lights::emitter(self, node, &light, world)?;
            self.emitters.push(e);
        }
        Ok(())
    }

    /// A usable id from the node's name, else the object's, else `<kind><node index>`:
    /// characters that cannot be in a file name become `_`.
    fn base_name(&self, node: &::gltf::Node, object: Option<&str>, kind: &str) -> String {
        let raw = node.name().or(object).unwrap_or("");
        let clean: String = raw
            .chars()
            .map(|c| {
                if c == '/' || c == '\\' || c.is_control() {
                    '_'
                } else {
                    c
                }
            })
            .collect();
        if clean.is_empty() || clean == "." || clean == ".." {
            format!("{kind}{}", node.index())
        } else {
            clean
        }
    }

    /// `name`, or `name_<node index>` (then `_2`, `_3`, ...) if taken: ids name output files.
    fn unique_id(&mut self, name: String, node: usize) -> String {
        let mut id = name.clone();
        let mut k = 1;
        while self.ids.contains(&id) {
            id = if k == 1 {
                format!("{name}_{node}")
            } else {
                format!("{name}_{node}_{k}")
            };
            k += 1;
        }
        self.ids.insert(id.clone());
        id
    }
}

#[cfg(test)]
mod tests;
