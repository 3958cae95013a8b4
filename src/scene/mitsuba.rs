//! Mitsuba 3 scene XML -> [`Scene`]: the one place that knows the file format. Everything
//! is settled here, once: meshes are in world space, emitter quantities are RGB in scene
//! units, spot angles are radians, ids are assigned.
//!
//! The subset read (see `docs/contract.md`), against Mitsuba 3.9's plugin sources:
//! - `<scene version>`, top-level `<default name value/>` with `$name` substitution in every
//!   attribute value, `<ref id name>` to earlier bsdfs, `name` attributes on any object;
//! - shapes `obj`, `ply`, `rectangle`, `cube`, `sphere` with `to_world`, `flip_normals`,
//!   `face_normals` (meshes), `flip_tex_coords` (obj, ply), `center`/`radius` (sphere),
//!   `silhouette_sampling_weight` (read past);
//! - bsdfs `diffuse` (front side reflects) and `twosided` around any bsdf (both sides), with
//!   any `<texture>`; a diffuse reflectance is read past: it is what kdmap recovers. The
//!   non-diffuse bsdfs of `mitsuba/bsdf.rs` make a shape a known material; the rest parse and
//!   are refused when a shape uses them ("not supported yet");
//! - emitters `point`, `spot`, `directional`, `area` inside a shape, `envmap` (a lat-long
//!   `.exr`/`.hdr` map, `scale`, a rotation `to_world`; see [`super::envmap`]) and `constant`;
//! - sensors `perspective` with an `hdrfilm`, its `rfilter` and `sampler`, and integrators:
//!   see `mitsuba/sensor.rs`.
//!
//! As in Mitsuba, a property no plugin reads is an error, so a setting that would change the
//! answer is never silently ignored; only settings that cannot change it (`integrator`,
//! `sampler`, film output formats, clip planes, `focus_distance` of a pinhole,
//! `sampling_weight`) are read past.
//! Every refusal is one line naming the file, line, column and element, e.g.
//! `scene.xml (line 10, col 5), <shape type="foo">: unknown shape plugin 'foo'`.
//!
//! Transforms follow Mitsuba: inside `<transform>`, each operation left-multiplies what came
//! before (`M = op_n * ... * op_1`); `lookat` builds the frame `(left, up, dir, origin)`.
//!
//! Known differences from Mitsuba: spheres are tessellated (see [`mesh::sphere`]); shape,
//! sensor and emitter ids must be usable as file names; emitter values must be non-negative;
//! sensor and sphere transforms may not shear either (Mitsuba only checks scale).

use crate::base::error::{Error, Location};
use crate::scene::{
    mesh, Emitter, EnvMap, KnownMaterial, Material, Mesh, ReflectanceSpec, Rgb, Scene, Shape, Sides,
};
use crate::Result;
use glam::{DMat3, DMat4, DVec3, Vec3};
use roxmltree::{Document, Node};
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;

mod bsdf;
mod sensor;

pub use sensor::DEFAULT_FILM;

/// Mitsuba's default spot `cutoff_angle`, degrees.
pub const DEFAULT_SPOT_CUTOFF_DEG: f64 = 20.0;

/// Load a Mitsuba 3 scene file. Relative mesh paths resolve against the file's directory.
pub fn load(path: &Path) -> Result<Scene> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    parse(&text, path)
}

/// The scene file alone, its mesh files not read: sensors, emitters, and shapes whose
/// `obj`/`ply` meshes are empty (so area emitters on them have no area). What the checks
/// that must come before the (possibly slow) meshes need: films, photos, emitter count.
pub fn load_outline(path: &Path) -> Result<Scene> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    parse_with(&text, path, false)
}

/// [`load`] on XML text already read; `path` names the file in errors and its directory is
/// where relative mesh paths are looked up.
pub fn parse(text: &str, path: &Path) -> Result<Scene> {
    parse_with(text, path, true)
}

/// [`parse`], reading the mesh files only if `meshes`.
fn parse_with(text: &str, path: &Path, meshes: bool) -> Result<Scene> {
    check_depth(text, path)?;
    let doc = Document::parse(text).map_err(|e| {
        let pos = e.pos();
        Error::Input {
            path: path.to_path_buf(),
            loc: Location {
                line: Some(pos.row),
                col: Some(pos.col),
                element: None,
            },
            msg: format!("malformed XML: {e}"),
        }
    })?;
    let dir = path
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from("."));
    let mut p = Parser {
        doc: &doc,
        path,
        dir,
        params: Vec::new(),
        bsdfs: HashMap::new(),
        textures: HashMap::new(),
        ids: HashSet::new(),
        files: Vec::new(),
        meshes,
    };
    p.scene(doc.root_element())
}

/// Deepest element nesting accepted. Mitsuba scenes nest a handful of levels; roxmltree
/// recurses per level and would overflow the stack (an abort, not an error) on thousands.
pub const MAX_DEPTH: usize = 128;

/// Refuse element nesting deeper than [`MAX_DEPTH`] before roxmltree sees the text. A light
/// scan: comments, CDATA, declarations and processing instructions are skipped, quoted
/// attribute values may hold `>`. Anything malformed is left for roxmltree to report.
fn check_depth(text: &str, path: &Path) -> Result<()> {
    let b = text.as_bytes();
    let mut depth = 0usize;
    let mut i = 0;
    let skip_to = |from: usize, end: &[u8]| -> usize {
        b[from..]
            .windows(end.len())
            .position(|w| w == end)
            .map_or(b.len(), |k| from + k + end.len())
    };
    while i < b.len() {
        if b[i] != b'<' {
            i += 1;
            continue;
        }
        let rest = &b[i..];
        if rest.starts_with(b"<!--") {
            i = skip_to(i + 4, b"-->");
        } else if rest.starts_with(b"<![CDATA[") {
            i = skip_to(i + 9, b"]]>");
        } else if rest.starts_with(b"<?") {
            i = skip_to(i + 2, b"?>");
        } else if rest.starts_with(b"<!") {
            i = skip_to(i + 2, b">");
        } else if rest.starts_with(b"</") {
            depth = depth.saturating_sub(1);
            i = skip_to(i + 2, b">");
        } else {
            // A start tag: find its end outside quotes.
            let mut j = i + 1;
            let mut quote = None;
            while j < b.len() {
                match (quote, b[j]) {
                    (None, b'"' | b'\'') => quote = Some(b[j]),
                    (Some(q), c) if c == q => quote = None,
                    (None, b'>') => break,
                    _ => {}
                }
                j += 1;
            }
            if j < b.len() && b[j - 1] != b'/' {
                depth += 1;
                if depth > MAX_DEPTH {
                    let line = text[..i].matches('\n').count() + 1;
                    return Err(Error::input_at(
                        path,
                        line as u32,
                        format!("elements nested deeper than {MAX_DEPTH} levels"),
                    ));
                }
            }
            i = j + 1;
        }
    }
    Ok(())
}

/// Mitsuba's `coordinate_system(n)` (Duff et al. 2017): the first of two unit vectors that
/// complete unit `n` to an orthonormal basis. Mitsuba uses it as `lookat`'s missing `up` and
/// to orient a `directional` emitter given by its `direction`.
pub fn coordinate_system_first(n: DVec3) -> DVec3 {
    let sign = 1f64.copysign(n.z);
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x)
}

/// Mitsuba 3's `look_at`: columns `(left, new_up, dir, origin)` with `dir = normalize(target -
/// origin)`, `left = normalize(up x dir)`, `new_up = dir x left`. `None` when degenerate
/// (origin = target, or `up` parallel to the view direction).
pub fn look_at(origin: DVec3, target: DVec3, up: Option<DVec3>) -> Option<DMat4> {
    let dir = (target - origin).try_normalize()?;
    let up = up.unwrap_or_else(|| coordinate_system_first(dir));
    let left = up.cross(dir);
    if left.length() <= 1e-9 * up.length() {
        return None;
    }
    let left = left.try_normalize()?;
    let new_up = dir.cross(left);
    Some(DMat4::from_cols(
        left.extend(0.0),
        new_up.extend(0.0),
        dir.extend(0.0),
        origin.extend(1.0),
    ))
}

/// Tags that carry a named value of an object.
const PROPERTY_TAGS: &[&str] = &[
    "float",
    "integer",
    "boolean",
    "string",
    "rgb",
    "spectrum",
    "point",
    "vector",
    "transform",
];

/// Tags that declare (or reference) a nested object.
const OBJECT_TAGS: &[&str] = &[
    "bsdf",
    "emitter",
    "film",
    "sampler",
    "rfilter",
    "integrator",
    "texture",
    "shape",
    "sensor",
    "medium",
    "phase",
    "volume",
    "ref",
];

/// The children of an object element, split into named properties and nested objects. A
/// handler `take`s what it reads; `finish` refuses whatever is left.
struct Props<'a, 'i> {
    items: Vec<(String, Node<'a, 'i>, bool)>,
    objects: Vec<Node<'a, 'i>>,
}

impl<'a, 'i> Props<'a, 'i> {
    /// The property `name`, if present, without marking it read.
    fn peek(&self, name: &str) -> Option<Node<'a, 'i>> {
        self.items.iter().find(|(n, _, _)| n == name).map(|i| i.1)
    }

    fn take(&mut self, name: &str) -> Option<Node<'a, 'i>> {
        let item = self
            .items
            .iter_mut()
            .find(|(n, _, used)| n == name && !*used)?;
        item.2 = true;
        Some(item.1)
    }

    fn finish(self, p: &Parser<'a, 'i>, read_past: &[&str]) -> Result<Vec<Node<'a, 'i>>> {
        for (name, node, used) in &self.items {
            if !used && !read_past.contains(&name.as_str()) {
                let parent = node.parent_element().map(describe).unwrap_or_default();
                return Err(p.err(*node, format!("unsupported property '{name}' on {parent}")));
            }
        }
        Ok(self.objects)
    }
}

struct Parser<'a, 'i> {
    doc: &'a Document<'i>,
    path: &'a Path,
    dir: PathBuf,
    /// `<default>` parameters, in file order.
    params: Vec<(String, String)>,
    /// Every bsdf declared with an id so far.
    bsdfs: HashMap<String, Bsdf>,
    /// The bitmap file of every top-level `<texture type="bitmap" id>` so far.
    textures: HashMap<String, PathBuf>,
    /// Every id used so far (Mitsuba ids share one namespace).
    ids: HashSet<String>,
    /// Every file named so far (meshes, bitmaps), in file order.
    files: Vec<PathBuf>,
    /// Whether mesh files are read (else their meshes are left empty: [`load_outline`]).
    meshes: bool,
}

/// What a shape's bsdf and emitter make of it.
struct ShapeMaterial {
    sides: Sides,
    reflectance: Option<ReflectanceSpec>,
    emission: Option<Rgb>,
    material: Material,
    /// The id of the bsdf the shape refers to (`<ref id="..."/>`).
    name: Option<String>,
}

/// What kdmap reads of a bsdf: which sides reflect, and the reflectance it states.
#[derive(Debug, Clone)]
struct Bsdf {
    sides: Sides,
    reflectance: Option<ReflectanceSpec>,
    /// The plugin name of a bsdf kdmap does not model (also one wrapped in `twosided`):
    /// parsed, not supported yet.
    unsupported: Option<String>,
    /// A non-diffuse bsdf kdmap models: the shape is a known material.
    known: Option<KnownMaterial>,
}

/// Mitsuba 3.9's bsdf plugins kdmap does not model (`src/bsdfs/`; the modelled ones are
/// `diffuse`, `twosided` and [`bsdf::KNOWN_BSDFS`]).
const OTHER_BSDFS: &[&str] = &[
    "circular",
    "hair",
    "measured",
    "measured_polarized",
    "polarizer",
    "pplastic",
    "retarder",
];

/// Mitsuba 3.9's emitter plugins kdmap does not model yet (`src/emitters/`).
const OTHER_EMITTERS: &[&str] = &["projector", "directionalarea", "sunsky", "timed_sunsky"];

/// Mitsuba 3.9's texture plugins (`src/textures/`).
const TEXTURES: &[&str] = &["bitmap", "checkerboard", "mesh_attribute", "volume"];

/// Mitsuba 3.9's shape plugins kdmap does not read yet (`src/shapes/`).
const OTHER_SHAPES: &[&str] = &[
    "disk",
    "cylinder",
    "bsplinecurve",
    "linearcurve",
    "sdfgrid",
    "ellipsoids",
    "ellipsoidsmesh",
    "instance",
    "shapegroup",
    "merge",
    "serialized",
];

/// `<tag type=".." id=".." name="..">` as written, for messages.
fn describe(node: Node) -> String {
    let mut s = format!("<{}", node.tag_name().name());
    for a in ["type", "id", "name"] {
        if let Some(v) = node.attribute(a) {
            let v: String = v.chars().take(60).collect();
            s.push_str(&format!(" {a}=\"{v}\""));
        }
    }
    s.push('>');
    s
}

fn tokens(s: &str) -> Vec<&str> {
    s.split(|c: char| c == ',' || c.is_whitespace())
        .filter(|t| !t.is_empty())
        .collect()
}

impl<'a, 'i> Parser<'a, 'i> {
    // ---- errors and attributes -------------------------------------------------------------

    fn err(&self, node: Node, msg: impl Into<String>) -> Error {
        let pos = self.doc.text_pos_at(node.range().start);
        Error::Input {
            path: self.path.to_path_buf(),
            loc: Location {
                line: Some(pos.row),
                col: Some(pos.col),
                element: Some(describe(node)),
            },
            msg: msg.into(),
        }
    }

    /// An attribute with `$name` parameters substituted; an unknown parameter is an error.
    fn attr(&self, node: Node, name: &str) -> Result<Option<String>> {
        let Some(raw) = node.attribute(name) else {
            return Ok(None);
        };
        if !raw.contains('$') {
            return Ok(Some(raw.to_string()));
        }
        let mut params: Vec<&(String, String)> = self.params.iter().collect();
        // Longest names first, so `$res` never eats the start of `$resx`.
        params.sort_by_key(|(k, _)| std::cmp::Reverse(k.len()));
        let mut v = raw.to_string();
        for (k, val) in params {
            v = v.replace(&format!("${k}"), val);
        }
        if let Some(i) = v.find('$') {
            let undefined: String = v[i + 1..]
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            return Err(self.err(
                node,
                format!("undefined parameter '${undefined}' in attribute '{name}' (no <default> for it)"),
            ));
        }
        Ok(Some(v))
    }

    fn req_attr(&self, node: Node, name: &str) -> Result<String> {
        self.attr(node, name)?
            .ok_or_else(|| self.err(node, format!("missing attribute '{name}'")))
    }

    fn check_attrs(&self, node: Node, allowed: &[&str]) -> Result<()> {
        for a in node.attributes() {
            if !allowed.contains(&a.name()) {
                return Err(self.err(node, format!("unexpected attribute '{}'", a.name())));
            }
        }
        Ok(())
    }

    fn register_id(&mut self, node: Node, id: &str) -> Result<()> {
        let bad = id.is_empty()
            || id == "."
            || id == ".."
            || id.chars().any(|c| c == '/' || c == '\\' || c.is_control());
        if bad {
            return Err(self.err(
                node,
                format!("id '{id}' cannot name output files (no '/', '\\', control characters, '.' or '..')"),
            ));
        }
        if !self.ids.insert(id.to_string()) {
            return Err(self.err(node, format!("duplicate id '{id}'")));
        }
        Ok(())
    }

    fn elements(node: Node<'a, 'i>) -> impl Iterator<Item = Node<'a, 'i>> {
        node.children().filter(Node::is_element)
    }

    fn props(&self, node: Node<'a, 'i>) -> Result<Props<'a, 'i>> {
        let mut props = Props {
            items: Vec::new(),
            objects: Vec::new(),
        };
        for c in Self::elements(node) {
            let tag = c.tag_name().name();
            if PROPERTY_TAGS.contains(&tag) {
                let name = self.req_attr(c, "name")?;
                if props.items.iter().any(|(n, _, _)| *n == name) {
                    return Err(self.err(c, format!("duplicate property '{name}'")));
                }
                props.items.push((name, c, false));
            } else if OBJECT_TAGS.contains(&tag) {
                props.objects.push(c);
            } else if tag == "default" {
                return Err(self.err(c, "<default> is only supported at the top level"));
            } else {
                return Err(self.err(c, format!("unsupported element <{tag}>")));
            }
        }
        Ok(props)
    }

    // ---- values ------------------------------------------------------------------------------

    fn number(&self, node: Node, attr: &str, tok: &str) -> Result<f64> {
        let v: f64 = tok.parse().map_err(|_| {
            self.err(
                node,
                format!("invalid number '{tok}' in attribute '{attr}'"),
            )
        })?;
        if !v.is_finite() || !(v as f32).is_finite() {
            return Err(self.err(
                node,
                format!("non-finite number '{tok}' in attribute '{attr}'"),
            ));
        }
        Ok(v)
    }

    fn numbers(&self, node: Node, attr: &str, s: &str) -> Result<Vec<f64>> {
        tokens(s)
            .into_iter()
            .map(|t| self.number(node, attr, t))
            .collect()
    }

    fn vec3_attr(&self, node: Node, attr: &str) -> Result<Option<DVec3>> {
        let Some(s) = self.attr(node, attr)? else {
            return Ok(None);
        };
        let v = self.numbers(node, attr, &s)?;
        if v.len() != 3 {
            return Err(self.err(
                node,
                format!("attribute '{attr}' needs 3 numbers, found {}", v.len()),
            ));
        }
        Ok(Some(DVec3::new(v[0], v[1], v[2])))
    }

    /// Mitsuba's `x`/`y`/`z` attributes, or `value` with one number (all three) or three.
    fn xyz(&self, node: Node, default: f64) -> Result<DVec3> {
        let comps = ["x", "y", "z"];
        if let Some(s) = self.attr(node, "value")? {
            if comps.iter().any(|c| node.attribute(*c).is_some()) {
                return Err(self.err(node, "cannot mix 'value' with 'x'/'y'/'z'"));
            }
            let v = self.numbers(node, "value", &s)?;
            return match v.len() {
                1 => Ok(DVec3::splat(v[0])),
                3 => Ok(DVec3::new(v[0], v[1], v[2])),
                n => Err(self.err(node, format!("'value' needs 1 or 3 numbers, found {n}"))),
            };
        }
        let mut out = DVec3::splat(default);
        for (k, c) in comps.iter().enumerate() {
            if let Some(s) = self.attr(node, c)? {
                out[k] = self.number(node, c, s.trim())?;
            }
        }
        Ok(out)
    }

    fn expect_tag(&self, node: Node, tags: &[&str]) -> Result<()> {
        let tag = node.tag_name().name();
        if tags.contains(&tag) {
            return Ok(());
        }
        let want: Vec<String> = tags.iter().map(|t| format!("<{t}>")).collect();
        Err(self.err(
            node,
            format!("expected {} here, found <{tag}>", want.join(" or ")),
        ))
    }

    fn value(&self, node: Node) -> Result<String> {
        self.req_attr(node, "value")
    }

    fn float_of(&self, node: Node) -> Result<f64> {
        self.expect_tag(node, &["float", "integer"])?;
        self.check_attrs(node, &["name", "value"])?;
        let s = self.value(node)?;
        self.number(node, "value", s.trim())
    }

    fn int_of(&self, node: Node) -> Result<i64> {
        self.expect_tag(node, &["integer"])?;
        self.check_attrs(node, &["name", "value"])?;
        let s = self.value(node)?;
        s.trim()
            .parse()
            .map_err(|_| self.err(node, format!("invalid integer '{s}'")))
    }

    fn bool_of(&self, node: Node) -> Result<bool> {
        self.expect_tag(node, &["boolean"])?;
        self.check_attrs(node, &["name", "value"])?;
        let s = self.value(node)?;
        match s.trim().to_ascii_lowercase().as_str() {
            "true" => Ok(true),
            "false" => Ok(false),
            _ => Err(self.err(node, format!("invalid boolean '{s}' (true or false)"))),
        }
    }

    fn string_of(&self, node: Node) -> Result<String> {
        self.expect_tag(node, &["string"])?;
        self.check_attrs(node, &["name", "value"])?;
        self.value(node)
    }

    fn vec3_of(&self, node: Node) -> Result<DVec3> {
        self.expect_tag(node, &["point", "vector"])?;
        self.check_attrs(node, &["name", "value", "x", "y", "z"])?;
        self.xyz(node, 0.0)
    }

    /// An RGB quantity: `<rgb value="r, g, b"/>` or `"v"`, `<spectrum value="v"/>`, `<float>`.
    fn color_of(&self, node: Node) -> Result<DVec3> {
        let tag = node.tag_name().name();
        match tag {
            "rgb" => {
                self.check_attrs(node, &["name", "value"])?;
                let s = self.value(node)?;
                let v = self.numbers(node, "value", &s)?;
                match v.len() {
                    1 => Ok(DVec3::splat(v[0])),
                    3 => Ok(DVec3::new(v[0], v[1], v[2])),
                    n => Err(self.err(node, format!("<rgb> needs 1 or 3 numbers, found {n}"))),
                }
            }
            "spectrum" => {
                if node.attribute("filename").is_some() || node.attribute("type").is_some() {
                    return Err(self.err(
                        node,
                        "spectra from files or plugins are not supported; use <rgb>",
                    ));
                }
                self.check_attrs(node, &["name", "value"])?;
                let s = self.value(node)?;
                if s.contains(':') {
                    return Err(self.err(
                        node,
                        "spectrum given as wavelength:value pairs is not supported; use <rgb> or a single value",
                    ));
                }
                let v = self.numbers(node, "value", &s)?;
                if v.len() != 1 {
                    return Err(self.err(
                        node,
                        format!("<spectrum> needs a single value, found {}", v.len()),
                    ));
                }
                Ok(DVec3::splat(v[0]))
            }
            "float" | "integer" => Ok(DVec3::splat(self.float_of(node)?)),
            _ => Err(self.err(
                node,
                format!("expected <rgb>, <spectrum> or <float> here, found <{tag}>"),
            )),
        }
    }

    /// An emitter quantity: non-negative RGB, `default` when absent.
    fn emission(&self, props: &mut Props<'a, 'i>, name: &str, default: f64) -> Result<Rgb> {
        let Some(n) = props.take(name) else {
            return Ok(Vec3::splat(default as f32));
        };
        let c = self.color_of(n)?;
        if c.min_element() < 0.0 {
            return Err(self.err(n, format!("'{name}' must not be negative")));
        }
        Ok(c.as_vec3())
    }

    fn transform_of(&self, node: Node<'a, 'i>) -> Result<DMat4> {
        self.expect_tag(node, &["transform"])?;
        self.check_attrs(node, &["name"])?;
        let mut m = DMat4::IDENTITY;
        for op in Self::elements(node) {
            let t = match op.tag_name().name() {
                "translate" => {
                    self.check_attrs(op, &["value", "x", "y", "z"])?;
                    DMat4::from_translation(self.xyz(op, 0.0)?)
                }
                "scale" => {
                    self.check_attrs(op, &["value", "x", "y", "z"])?;
                    DMat4::from_scale(self.xyz(op, 1.0)?)
                }
                "rotate" => {
                    self.check_attrs(op, &["value", "x", "y", "z", "angle"])?;
                    let axis = self.xyz(op, 0.0)?;
                    let angle = self.req_attr(op, "angle")?;
                    let angle = self.number(op, "angle", angle.trim())?;
                    let axis = axis
                        .try_normalize()
                        .ok_or_else(|| self.err(op, "rotation axis has zero length"))?;
                    DMat4::from_axis_angle(axis, angle.to_radians())
                }
                "matrix" => {
                    self.check_attrs(op, &["value"])?;
                    let s = self.value(op)?;
                    let v = self.numbers(op, "value", &s)?;
                    match v.len() {
                        // Row-major in the file; glam is column-major.
                        16 => {
                            let a: [f64; 16] = v.try_into().unwrap_or([0.0; 16]);
                            DMat4::from_cols_array(&a).transpose()
                        }
                        9 => {
                            let a: [f64; 9] = v.try_into().unwrap_or([0.0; 9]);
                            DMat4::from_mat3(DMat3::from_cols_array(&a).transpose())
                        }
                        n => {
                            return Err(self.err(
                                op,
                                format!("<matrix> needs 16 (4x4) or 9 (3x3) numbers, found {n}"),
                            ))
                        }
                    }
                }
                "lookat" => {
                    self.check_attrs(op, &["origin", "target", "up"])?;
                    let origin = self.vec3_attr(op, "origin")?;
                    let target = self.vec3_attr(op, "target")?;
                    let up = self.vec3_attr(op, "up")?;
                    let (Some(origin), Some(target)) = (origin, target) else {
                        return Err(self.err(op, "<lookat> needs 'origin' and 'target'"));
                    };
                    look_at(origin, target, up).ok_or_else(|| {
                        self.err(
                            op,
                            "degenerate lookat: origin equals target, or 'up' is parallel to the view direction",
                        )
                    })?
                }
                other => {
                    return Err(self.err(op, format!("unsupported transform operation <{other}>")))
                }
            };
            m = t * m;
        }
        if !m.is_finite() || !m.as_mat4().is_finite() {
            return Err(self.err(node, "the transform has non-finite entries"));
        }
        Ok(m)
    }

    fn to_world(&self, props: &mut Props<'a, 'i>) -> Result<Option<(DMat4, Node<'a, 'i>)>> {
        props
            .take("to_world")
            .map(|n| Ok((self.transform_of(n)?, n)))
            .transpose()
    }

    // ---- scene -------------------------------------------------------------------------------

    fn scene(&mut self, root: Node<'a, 'i>) -> Result<Scene> {
        if root.tag_name().name() != "scene" {
            return Err(self.err(root, "the root element must be <scene>"));
        }
        self.check_attrs(root, &["version"])?;
        let version = self.req_attr(root, "version")?;
        let major: Option<u32> = version
            .split('.')
            .next()
            .and_then(|m| m.trim().parse().ok());
        match major {
            Some(m) if m >= 2 => {}
            Some(_) => {
                return Err(self.err(
                    root,
                    format!(
                    "scene version {version} predates Mitsuba 2/3 property names; upgrade the file"
                ),
                ))
            }
            None => return Err(self.err(root, format!("invalid version '{version}'"))),
        }

        let mut scene = Scene {
            path: self.path.to_path_buf(),
            shapes: Vec::new(),
            emitters: Vec::new(),
            sensors: Vec::new(),
            files: Vec::new(),
        };
        for c in Self::elements(root) {
            match c.tag_name().name() {
                "default" => {
                    self.check_attrs(c, &["name", "value"])?;
                    let name = c
                        .attribute("name")
                        .ok_or_else(|| self.err(c, "missing attribute 'name'"))?;
                    let value = c
                        .attribute("value")
                        .ok_or_else(|| self.err(c, "missing attribute 'value'"))?;
                    if name.is_empty() || !name.chars().all(|ch| ch.is_alphanumeric() || ch == '_')
                    {
                        return Err(self.err(c, format!("invalid parameter name '{name}'")));
                    }
                    // As in Mitsuba, the first definition wins.
                    if !self.params.iter().any(|(k, _)| k == name) {
                        self.params.push((name.to_string(), value.to_string()));
                    }
                }
                "shape" => {
                    let index = scene.shapes.len();
                    let shape = self.shape(c, index, &mut scene.emitters)?;
                    scene.shapes.push(shape);
                }
                "bsdf" => {
                    self.bsdf(c)?;
                }
                "emitter" => {
                    let e = self.emitter(c)?;
                    scene.emitters.push(e);
                }
                "sensor" => {
                    let index = scene.sensors.len();
                    let s = self.sensor(c, index)?;
                    scene.sensors.push(s);
                }
                // Rendering settings that cannot change the answer.
                "integrator" => self.integrator(c)?,
                "sampler" => self.sampler(c)?,
                "include" | "path" | "alias" => {
                    return Err(self.err(
                        c,
                        format!(
                            "<{}> is not supported yet; inline the content",
                            c.tag_name().name()
                        ),
                    ))
                }
                // Textures only feed bsdfs, which are not trusted; keep their ids reserved
                // and remember bitmaps for the truth reader.
                "texture" => {
                    self.texture_kind(c)?;
                    if let Some(id) = self.attr(c, "id")? {
                        self.register_id(c, &id)?;
                        if let Some(f) = self.bitmap_file(c) {
                            self.textures.insert(id, f);
                        }
                    }
                }
                other => {
                    return Err(self.err(c, format!("unsupported element <{other}> in <scene>")))
                }
            }
        }
        scene.files = std::mem::take(&mut self.files);
        Ok(scene)
    }

    // ---- shapes ------------------------------------------------------------------------------

    fn shape(
        &mut self,
        node: Node<'a, 'i>,
        index: usize,
        emitters: &mut Vec<Emitter>,
    ) -> Result<Shape> {
        self.check_attrs(node, &["type", "id", "name"])?;
        let kind = self.shape_kind(node)?;
        let id = self
            .attr(node, "id")?
            .unwrap_or_else(|| format!("shape_{index}"));
        self.register_id(node, &id)?;

        let mut props = self.props(node)?;
        let to_world = self.to_world(&mut props)?;
        let flip = props
            .take("flip_normals")
            .map(|n| self.bool_of(n))
            .transpose()?
            .unwrap_or(false);
        let is_mesh = matches!(kind.as_str(), "obj" | "ply" | "cube");
        let face_normals = if is_mesh {
            props
                .take("face_normals")
                .map(|n| self.bool_of(n))
                .transpose()?
                .unwrap_or(false)
        } else {
            false
        };

        let mut m = to_world.map(|(m, _)| m).unwrap_or(DMat4::IDENTITY);
        let mut file = None;
        let mut local: Mesh = match kind.as_str() {
            "obj" | "ply" => {
                let (mesh, p) = self.mesh_file(node, &kind, &mut props)?;
                file = Some(p);
                mesh
            }
            "rectangle" => mesh::rectangle(),
            "cube" => mesh::cube(),
            _ => {
                let at = to_world.map(|(_, n)| n).unwrap_or(node);
                m = self.sphere_frame(&mut props, m, at)?;
                mesh::sphere()
            }
        };
        let objects = props.finish(self, &["silhouette_sampling_weight"])?;

        let det = m.determinant();
        if det == 0.0 || !det.is_finite() {
            let at = to_world.map(|(_, n)| n).unwrap_or(node);
            return Err(self.err(at, "to_world is singular"));
        }
        if face_normals {
            local.normals = None;
        }
        local.transform(&m.as_mat4());
        if !face_normals && local.normals.is_none() && matches!(kind.as_str(), "obj" | "ply") {
            // Mitsuba computes smooth normals for meshes without them, in world space.
            local.normals = Some(mesh::compute_vertex_normals(&local));
        }
        if flip {
            mesh::flip_normals(&mut local);
        }
        mesh::check_finite(&local, file.as_deref().unwrap_or(self.path))
            .map_err(|e| self.err(node, format!("after to_world: {e}")))?;

        let mat = self.shape_material(objects, index, emitters)?;
        Ok(Shape {
            id,
            kind,
            file,
            mesh: local,
            sides: mat.sides,
            emission: mat.emission,
            reflectance: mat.reflectance,
            material: mat.material,
            material_name: mat.name,
        })
    }

    /// A shape's plugin name, refused unless kdmap reads it.
    fn shape_kind(&self, node: Node<'a, 'i>) -> Result<String> {
        let kind = self.req_attr(node, "type")?;
        if !matches!(
            kind.as_str(),
            "obj" | "ply" | "rectangle" | "cube" | "sphere"
        ) {
            let msg = if OTHER_SHAPES.contains(&kind.as_str()) {
                format!("shape '{kind}' is not supported yet (obj, ply, rectangle, cube, sphere)")
            } else {
                format!("unknown shape plugin '{kind}'")
            };
            return Err(self.err(node, msg));
        }
        Ok(kind)
    }

    /// A shape's bsdf (Mitsuba's one-sided diffuse by default), its emission (an area
    /// emitter, added to `emitters`) and whether its material is known.
    fn shape_material(
        &mut self,
        objects: Vec<Node<'a, 'i>>,
        index: usize,
        emitters: &mut Vec<Emitter>,
    ) -> Result<ShapeMaterial> {
        let (bsdf, emission) = self.shape_objects(objects)?;
        let name = (bsdf.as_ref())
            .filter(|(_, at)| at.tag_name().name() == "ref")
            .and_then(|(_, at)| at.attribute("id"))
            .map(String::from);
        if let Some((b, at)) = &bsdf {
            if let Some(kind) = &b.unsupported {
                return Err(self.err(
                    *at,
                    format!("bsdf '{kind}' is not supported yet (diffuse, conductor, dielectric, plastic, principled and their rough, thin, blend, mask, twosided forms are)"),
                ));
            }
        }
        let bsdf = bsdf.map(|(b, _)| b);
        if let Some(radiance) = emission {
            emitters.push(Emitter::Area {
                shape: index,
                radiance,
            });
        }
        // Mitsuba's default bsdf is a one-sided diffuse.
        let bsdf = bsdf.unwrap_or(Bsdf {
            sides: Sides::Front,
            reflectance: None,
            unsupported: None,
            known: None,
        });
        let material = match bsdf.known {
            Some(k) if emission.is_none() => Material::Known(Box::new(k)),
            _ => Material::Unknown,
        };
        Ok(ShapeMaterial {
            sides: bsdf.sides,
            reflectance: bsdf.reflectance,
            emission,
            material,
            name,
        })
    }

    /// An `obj` or `ply` shape's mesh (local space) and its file.
    fn mesh_file(
        &mut self,
        node: Node<'a, 'i>,
        kind: &str,
        props: &mut Props<'a, 'i>,
    ) -> Result<(Mesh, PathBuf)> {
        let fnode = props
            .take("filename")
            .ok_or_else(|| self.err(node, "missing property 'filename'"))?;
        let name = self.string_of(fnode)?;
        let p = self.dir.join(&name);
        let loaded = match kind {
            _ if !self.meshes => Ok(Mesh::default()),
            "obj" => mesh::load_obj(&p),
            _ => mesh::load_ply(&p),
        };
        let mut mesh = loaded.map_err(|e| self.err(node, format!("cannot load mesh: {e}")))?;
        // Mitsuba flips v by default for OBJ files, not for PLY files.
        let flip_tc = props
            .take("flip_tex_coords")
            .map(|n| self.bool_of(n))
            .transpose()?
            .unwrap_or(kind == "obj");
        match (kind, flip_tc) {
            // The file's v already runs down (Mitsuba's convention).
            ("obj", false) => mesh::flip_v(&mut mesh),
            ("ply", true) => mesh::flip_v(&mut mesh),
            _ => {}
        }
        self.files.push(p.clone());
        Ok((mesh, p))
    }

    /// A `sphere`'s frame: `m` with its `center` and `radius` applied; only rotation, uniform
    /// scale and translation are accepted (`at` is the element blamed otherwise).
    fn sphere_frame(&self, props: &mut Props<'a, 'i>, m: DMat4, at: Node) -> Result<DMat4> {
        let center = props
            .take("center")
            .map(|n| self.vec3_of(n))
            .transpose()?
            .unwrap_or(DVec3::ZERO);
        let radius = match props.take("radius") {
            Some(n) => {
                let r = self.float_of(n)?;
                if r <= 0.0 {
                    return Err(self.err(n, "'radius' must be positive"));
                }
                r
            }
            None => 1.0,
        };
        let m = m * DMat4::from_translation(center) * DMat4::from_scale(DVec3::splat(radius));
        let l = DMat3::from_mat4(m);
        let s = l.x_axis.length();
        let similar = [l.x_axis, l.y_axis, l.z_axis]
            .iter()
            .all(|c| (c.length() - s).abs() <= 1e-4 * s)
            && l.x_axis.dot(l.y_axis).abs() <= 1e-4 * s * s
            && l.y_axis.dot(l.z_axis).abs() <= 1e-4 * s * s
            && l.x_axis.dot(l.z_axis).abs() <= 1e-4 * s * s;
        if !similar {
            return Err(self.err(
                at,
                "a sphere's to_world may only rotate, scale uniformly and translate",
            ));
        }
        Ok(m)
    }

    /// A shape's nested objects: the bsdf (or a reference to one) with its element, and an
    /// area emitter.
    #[allow(clippy::type_complexity)]
    fn shape_objects(
        &mut self,
        objects: Vec<Node<'a, 'i>>,
    ) -> Result<(Option<(Bsdf, Node<'a, 'i>)>, Option<Rgb>)> {
        let mut bsdf = None;
        let mut emission = None;
        for o in objects {
            match o.tag_name().name() {
                "bsdf" | "ref" => {
                    let b = if o.tag_name().name() == "bsdf" {
                        self.bsdf(o)?
                    } else {
                        self.bsdf_ref(o)?
                    };
                    if bsdf.replace((b, o)).is_some() {
                        return Err(self.err(o, "a shape can have only one bsdf"));
                    }
                }
                "emitter" => {
                    let r = self.area_emitter(o)?;
                    if emission.replace(r).is_some() {
                        return Err(self.err(o, "a shape can have only one emitter"));
                    }
                }
                "medium" => {
                    return Err(self.err(o, "participating media are not supported"));
                }
                other => {
                    return Err(self.err(o, format!("unsupported element <{other}> in a shape")))
                }
            }
        }
        Ok((bsdf, emission))
    }

    // ---- bsdfs -------------------------------------------------------------------------------

    /// Which sides reflect, and the reflectance the file states (read leniently: it is not
    /// trusted, so a form kdmap cannot read is no error, just no stated reflectance). Every
    /// bsdf plugin of Mitsuba 3.9 parses; the non-diffuse ones come back `unsupported`, and
    /// a shape using one is refused.
    fn bsdf(&mut self, node: Node<'a, 'i>) -> Result<Bsdf> {
        self.check_attrs(node, &["type", "id", "name"])?;
        let kind = self.req_attr(node, "type")?;
        let b = match kind.as_str() {
            "diffuse" => self.diffuse(node)?,
            "twosided" => self.twosided(node)?,
            k if bsdf::KNOWN_BSDFS.contains(&k) => self.known_bsdf(node, k)?,
            k if OTHER_BSDFS.contains(&k) => self.other_bsdf(node, k)?,
            other => return Err(self.err(node, format!("unknown bsdf plugin '{other}'"))),
        };
        if let Some(id) = self.attr(node, "id")? {
            self.register_id(node, &id)?;
            self.bsdfs.insert(id, b.clone());
        }
        Ok(b)
    }

    /// A `diffuse` bsdf: `reflectance` (a value, a nested `<texture>` or a `<ref>` to one).
    fn diffuse(&mut self, node: Node<'a, 'i>) -> Result<Bsdf> {
        let mut props = self.props(node)?;
        props.take("reflectance");
        for o in props.finish(self, &[])? {
            match o.tag_name().name() {
                "texture" => self.texture_kind(o)?,
                "ref" => self.check_attrs(o, &["id", "name"])?,
                other => {
                    return Err(self.err(
                        o,
                        format!("unsupported element <{other}> in a diffuse bsdf"),
                    ))
                }
            }
        }
        Ok(Bsdf {
            sides: Sides::Front,
            reflectance: self.stated_reflectance(node),
            unsupported: None,
            known: None,
        })
    }

    /// A `twosided` bsdf around one or two bsdfs (front and back): both sides reflect.
    fn twosided(&mut self, node: Node<'a, 'i>) -> Result<Bsdf> {
        let mut props = self.props(node)?;
        if let Some(n) = props.take("allow_transmission") {
            self.bool_of(n)?;
        }
        let mut inner: Vec<Bsdf> = Vec::new();
        for c in props.finish(self, &[])? {
            let b = match c.tag_name().name() {
                "bsdf" => self.bsdf(c)?,
                "ref" => self.bsdf_ref(c)?,
                other => {
                    return Err(self.err(
                        c,
                        format!("unsupported element <{other}> in a twosided bsdf"),
                    ))
                }
            };
            if b.sides != Sides::Front && b.known.is_none()
                || c.attribute("type") == Some("twosided")
            {
                return Err(self.err(c, "a twosided bsdf cannot wrap another twosided bsdf"));
            }
            inner.push(b);
        }
        if !(1..=2).contains(&inner.len()) {
            return Err(self.err(node, "twosided needs one or two nested bsdfs"));
        }
        let unsupported = inner.iter().find_map(|b| b.unsupported.clone());
        let front = inner.swap_remove(0);
        Ok(Bsdf {
            sides: Sides::Both,
            reflectance: front.reflectance,
            unsupported,
            known: front.known,
        })
    }

    /// A non-diffuse Mitsuba bsdf: its nested bsdfs and textures are parsed (ids registered,
    /// plugins checked), its properties read past; it comes back `unsupported`.
    fn other_bsdf(&mut self, node: Node<'a, 'i>, kind: &str) -> Result<Bsdf> {
        let props = self.props(node)?;
        for o in props.objects {
            match o.tag_name().name() {
                "bsdf" => {
                    self.bsdf(o)?;
                }
                "texture" => self.texture_kind(o)?,
                "ref" => self.check_attrs(o, &["id", "name"])?,
                other => {
                    return Err(self.err(o, format!("unsupported element <{other}> in a bsdf")))
                }
            }
        }
        Ok(Bsdf {
            sides: Sides::Front,
            reflectance: None,
            unsupported: Some(kind.to_string()),
            known: None,
        })
    }

    /// Check that a `<texture>` names one of Mitsuba 3.9's texture plugins.
    fn texture_kind(&self, node: Node<'a, 'i>) -> Result<()> {
        self.check_attrs(node, &["type", "id", "name"])?;
        let kind = self.req_attr(node, "type")?;
        if !TEXTURES.contains(&kind.as_str()) {
            return Err(self.err(node, format!("unknown texture plugin '{kind}'")));
        }
        Ok(())
    }

    /// The `reflectance` a diffuse bsdf states: a constant, a nested bitmap texture or a
    /// reference to a top-level one. `None` for any other form.
    fn stated_reflectance(&mut self, node: Node<'a, 'i>) -> Option<ReflectanceSpec> {
        self.stated(node, "reflectance")
    }

    /// The reflectance parameter `name` of a bsdf, as [`Parser::stated_reflectance`] reads it.
    pub(super) fn stated(&mut self, node: Node<'a, 'i>, name: &str) -> Option<ReflectanceSpec> {
        let c = Self::elements(node).find(|c| c.attribute("name") == Some(name))?;
        match c.tag_name().name() {
            "rgb" | "spectrum" | "float" | "integer" => {
                Some(ReflectanceSpec::Constant(self.color_of(c).ok()?.as_vec3()))
            }
            "texture" => self.bitmap_file(c).map(ReflectanceSpec::Bitmap),
            "ref" => {
                let id = self.attr(c, "id").ok()??;
                self.textures.get(&id).cloned().map(ReflectanceSpec::Bitmap)
            }
            _ => None,
        }
    }

    /// The file of a `<texture type="bitmap">` (recorded among the scene's files), if it is
    /// one and names a file.
    fn bitmap_file(&mut self, node: Node<'a, 'i>) -> Option<PathBuf> {
        if self.attr(node, "type").ok()?.as_deref() != Some("bitmap") {
            return None;
        }
        let f = Self::elements(node)
            .find(|n| n.attribute("name") == Some("filename"))
            .and_then(|n| self.attr(n, "value").ok().flatten())?;
        let p = self.dir.join(f);
        self.files.push(p.clone());
        Some(p)
    }

    fn bsdf_ref(&self, node: Node) -> Result<Bsdf> {
        self.check_attrs(node, &["id", "name"])?;
        let id = self.req_attr(node, "id")?;
        match self.bsdfs.get(&id) {
            Some(b) => Ok(b.clone()),
            None if self.ids.contains(&id) => {
                Err(self.err(node, format!("'{id}' does not name a bsdf")))
            }
            None => Err(self.err(
                node,
                format!("reference to unknown bsdf '{id}' (it must be declared earlier)"),
            )),
        }
    }

    // ---- emitters ----------------------------------------------------------------------------

    /// An `envmap` (`filename`, `scale`, `to_world`, `mis_compensation`) or a `constant`
    /// (`radiance`) emitter, checked as Mitsuba checks them; the map is read here.
    fn environment(&mut self, mut props: Props<'a, 'i>, kind: &str, node: Node) -> Result<Emitter> {
        if kind == "constant" {
            let radiance = self.emission(&mut props, "radiance", 1.0)?;
            props.finish(self, &["sampling_weight"])?;
            let env = EnvMap::constant(radiance, glam::Mat4::IDENTITY);
            return Ok(Emitter::Environment(Arc::new(env)));
        }
        let f = props
            .take("filename")
            .ok_or_else(|| self.err(node, "missing property 'filename'"))?;
        let file = self.dir.join(self.string_of(f)?);
        self.files.push(file.clone());
        let scale = match props.take("scale") {
            Some(n) => {
                let s = self.float_of(n)?;
                if !(s >= 0.0 && s.is_finite()) {
                    return Err(self.err(n, "'scale' must be a non-negative number"));
                }
                s
            }
            None => 1.0,
        };
        if let Some(n) = props.take("mis_compensation") {
            self.bool_of(n)?;
        }
        let m = match self.to_world(&mut props)? {
            Some((m, n)) if !is_rotation(&m) => {
                return Err(self.err(
                    n,
                    "an environment map's to_world must be a rotation (no scale or shear)",
                ))
            }
            Some((m, _)) => m,
            None => DMat4::IDENTITY,
        };
        props.finish(self, &["sampling_weight"])?;
        let env = EnvMap::load(&file, scale as f32, m.as_mat4())
            .map_err(|e| self.err(f, e.to_string()))?;
        Ok(Emitter::Environment(Arc::new(env)))
    }

    fn emitter_props(&mut self, node: Node<'a, 'i>) -> Result<(String, Props<'a, 'i>)> {
        self.check_attrs(node, &["type", "id", "name"])?;
        let kind = self.req_attr(node, "type")?;
        if let Some(id) = self.attr(node, "id")? {
            self.register_id(node, &id)?;
        }
        let props = self.props(node)?;
        if let Some(o) = props.objects.first() {
            return Err(self.err(
                *o,
                "nested objects in emitters (e.g. textured emission) are not supported",
            ));
        }
        Ok((kind, props))
    }

    fn area_emitter(&mut self, node: Node<'a, 'i>) -> Result<Rgb> {
        let (kind, mut props) = self.emitter_props(node)?;
        if kind != "area" {
            return Err(self.err(
                node,
                format!("unsupported emitter plugin '{kind}' inside a shape (only 'area')"),
            ));
        }
        let radiance = self.emission(&mut props, "radiance", 1.0)?;
        props.finish(self, &["sampling_weight"])?;
        Ok(radiance)
    }

    fn emitter(&mut self, node: Node<'a, 'i>) -> Result<Emitter> {
        let (kind, mut props) = self.emitter_props(node)?;
        let e = match kind.as_str() {
            "point" => {
                let pos = props.take("position");
                let tw = self.to_world(&mut props)?;
                let position = match (pos, tw) {
                    (Some(_), Some((_, n))) => {
                        return Err(self.err(n, "give only one of 'position' and 'to_world'"))
                    }
                    (Some(p), None) => self.vec3_of(p)?,
                    (None, Some((m, _))) => m.transform_point3(DVec3::ZERO),
                    (None, None) => DVec3::ZERO,
                };
                let intensity = self.emission(&mut props, "intensity", 1.0)?;
                Emitter::Point {
                    position: position.as_vec3(),
                    intensity,
                }
            }
            "spot" => {
                let (m, tw_node) = match self.to_world(&mut props)? {
                    Some((m, n)) => (m, n),
                    None => (DMat4::IDENTITY, node),
                };
                let intensity = self.emission(&mut props, "intensity", 1.0)?;
                let cutoff = match props.take("cutoff_angle") {
                    Some(n) => {
                        let c = self.float_of(n)?;
                        if !(c > 0.0 && c < 180.0) {
                            return Err(self.err(n, "'cutoff_angle' must be in (0, 180) degrees"));
                        }
                        c
                    }
                    None => DEFAULT_SPOT_CUTOFF_DEG,
                };
                let beam = match props.take("beam_width") {
                    Some(n) => {
                        let b = self.float_of(n)?;
                        if b < 0.0 {
                            return Err(self.err(n, "'beam_width' must not be negative"));
                        }
                        // Mitsuba clamps a beam wider than the cutoff.
                        b.min(cutoff)
                    }
                    None => cutoff * 0.75,
                };
                let axis = m
                    .transform_vector3(DVec3::Z)
                    .try_normalize()
                    .ok_or_else(|| self.err(tw_node, "to_world collapses the spot axis"))?;
                Emitter::Spot {
                    position: m.transform_point3(DVec3::ZERO).as_vec3(),
                    axis: axis.as_vec3(),
                    to_world: m.as_mat4(),
                    intensity,
                    cutoff: cutoff.to_radians() as f32,
                    beam_width: beam.to_radians() as f32,
                }
            }
            "directional" => {
                let dir = props.take("direction");
                let tw = self.to_world(&mut props)?;
                let (d, at) = match (dir, tw) {
                    (Some(_), Some((_, n))) => {
                        return Err(self.err(n, "give only one of 'direction' and 'to_world'"))
                    }
                    (Some(d), None) => (self.vec3_of(d)?, d),
                    (None, Some((m, n))) => (m.transform_vector3(DVec3::Z), n),
                    (None, None) => (DVec3::Z, node),
                };
                let direction = d
                    .try_normalize()
                    .ok_or_else(|| self.err(at, "the direction has zero length"))?;
                let irradiance = self.emission(&mut props, "irradiance", 1.0)?;
                Emitter::Directional {
                    direction: direction.as_vec3(),
                    irradiance,
                }
            }
            "area" => return Err(self.err(node, "an area emitter must be nested inside a shape")),
            "envmap" | "constant" => return self.environment(props, &kind, node),
            k if OTHER_EMITTERS.contains(&k) => {
                return Err(self.err(
                    node,
                    format!("emitter '{k}' is not supported yet (point, spot, directional, area, envmap, constant)"),
                ))
            }
            other => return Err(self.err(node, format!("unknown emitter plugin '{other}'"))),
        };
        props.finish(self, &["sampling_weight"])?;
        Ok(e)
    }
}

/// Whether the linear part of `m` is a rotation (orthonormal, determinant +1) up to rounding.
fn is_rotation(m: &DMat4) -> bool {
    let r = DMat3::from_mat4(*m);
    let d = r.transpose() * r - DMat3::IDENTITY;
    let err = d
        .x_axis
        .abs()
        .max_element()
        .max(d.y_axis.abs().max_element())
        .max(d.z_axis.abs().max_element());
    err < 1e-4 && r.determinant() > 0.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::FovAxis;

    #[test]
    fn an_outline_has_every_sensor_and_emitter_but_reads_no_mesh() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/cbox/input.xml");
        let (full, outline) = (load(&path).unwrap(), load_outline(&path).unwrap());
        assert_eq!(outline.sensors.len(), full.sensors.len());
        for (a, b) in outline.sensors.iter().zip(&full.sensors) {
            assert_eq!((&a.id, a.width, a.height), (&b.id, b.width, b.height));
        }
        assert_eq!(outline.emitters.len(), full.emitters.len());
        assert_eq!(outline.shapes.len(), full.shapes.len());
        assert!(full.triangle_count() > 0);
        assert_eq!(outline.triangle_count(), 0, "obj meshes are not read");
        // a missing mesh file is only found by the full load
        let text = std::fs::read_to_string(&path).unwrap();
        let text = text.replace("meshes/floor.obj", "meshes/no-such-floor.obj");
        assert!(parse_with(&text, &path, false).is_ok());
        assert!(parse_with(&text, &path, true).is_err());
    }

    fn scene(body: &str) -> Result<Scene> {
        parse(
            &format!("<scene version=\"3.0.0\">\n{body}\n</scene>"),
            Path::new("t/scene.xml"),
        )
    }

    fn shape_with(transform: &str) -> Mesh {
        let s = scene(&format!(
            "<shape type=\"rectangle\"><transform name=\"to_world\">{transform}</transform></shape>"
        ))
        .unwrap();
        s.shapes[0].mesh.clone()
    }

    #[test]
    fn transforms_compose_in_file_order() {
        let tr = "<translate x=\"1\"/><rotate y=\"1\" angle=\"90\"/>";
        let rt = "<rotate y=\"1\" angle=\"90\"/><translate value=\"1, 0, 0\"/>";
        // Rectangle corner (1,1,0): translate -> (2,1,0), rotate 90 about y -> (0,1,-2).
        let a = shape_with(tr).positions[2];
        assert!(a.abs_diff_eq(Vec3::new(0.0, 1.0, -2.0), 1e-6), "{a}");
        // rotate -> (0,1,-1), translate -> (1,1,-1).
        let b = shape_with(rt).positions[2];
        assert!(b.abs_diff_eq(Vec3::new(1.0, 1.0, -1.0), 1e-6), "{b}");
        // scale then matrix (row-major) then 3x3
        let m = shape_with(
            "<scale value=\"2\"/><matrix value=\"1 0 0 5  0 1 0 6  0 0 1 7  0 0 0 1\"/>\
             <matrix value=\"0 -1 0, 1 0 0, 0 0 1\"/>",
        );
        // (1,1,0) -> (2,2,0) -> (7,8,7) -> (-8,7,7)
        assert!(m.positions[2].abs_diff_eq(Vec3::new(-8.0, 7.0, 7.0), 1e-5));
        let s = shape_with("<scale x=\"3\"/>");
        assert!(s.positions[2].abs_diff_eq(Vec3::new(3.0, 1.0, 0.0), 1e-6));
    }

    #[test]
    fn lookat_frame_matches_mitsuba() {
        let m = look_at(
            DVec3::new(1.0, 2.0, 3.0),
            DVec3::new(1.0, 2.0, 0.0),
            Some(DVec3::Y),
        )
        .unwrap();
        // Looking down -z with up +y: left = up x dir = y x -z = -x.
        assert!(m.x_axis.truncate().abs_diff_eq(-DVec3::X, 1e-12));
        assert!(m.y_axis.truncate().abs_diff_eq(DVec3::Y, 1e-12));
        assert!(m.z_axis.truncate().abs_diff_eq(-DVec3::Z, 1e-12));
        assert!(m
            .w_axis
            .truncate()
            .abs_diff_eq(DVec3::new(1.0, 2.0, 3.0), 1e-12));
        assert!(look_at(DVec3::ZERO, DVec3::ZERO, None).is_none());
        assert!(look_at(DVec3::ZERO, DVec3::Y, Some(DVec3::Y)).is_none());
        // Missing up: coordinate_system's first vector, orthogonal to dir.
        for d in [DVec3::Z, -DVec3::Z, DVec3::new(0.3, -0.5, 0.8).normalize()] {
            let s = coordinate_system_first(d);
            assert!(s.dot(d).abs() < 1e-12 && (s.length() - 1.0).abs() < 1e-12);
            let m = look_at(DVec3::ZERO, d, None).unwrap();
            assert!(m.y_axis.truncate().abs_diff_eq(s, 1e-12));
        }
    }

    #[test]
    fn defaults_and_refs() {
        let s = scene(
            "<default name=\"w\" value=\"32\"/><default name=\"wide\" value=\"99\"/>\
             <default name=\"w\" value=\"7\"/>\
             <bsdf type=\"twosided\" id=\"mat\"><bsdf type=\"diffuse\"/></bsdf>\
             <shape type=\"cube\" id=\"c\"><ref id=\"mat\"/></shape>\
             <shape type=\"cube\"><ref name=\"bsdf\" id=\"mat\"/></shape>\
             <shape type=\"cube\"/>\
             <sensor type=\"perspective\"><float name=\"fov\" value=\"45\"/>\
               <film type=\"hdrfilm\"><integer name=\"width\" value=\"$w\"/>\
               <integer name=\"height\" value=\"$wide\"/></film></sensor>",
        )
        .unwrap();
        assert_eq!(s.sensors[0].width, 32);
        assert_eq!(s.sensors[0].height, 99);
        assert_eq!(s.sensors[0].id, "sensor_0");
        let ids: Vec<_> = s.shapes.iter().map(|s| s.id.as_str()).collect();
        assert_eq!(ids, ["c", "shape_1", "shape_2"]);
        assert_eq!(s.shapes[0].sides, Sides::Both);
        assert_eq!(s.shapes[1].sides, Sides::Both);
        assert_eq!(s.shapes[2].sides, Sides::Front);
    }

    #[test]
    fn emitters() {
        let s = scene(
            "<emitter type=\"point\"><point name=\"position\" value=\"1, 2, 3\"/>\
               <rgb name=\"intensity\" value=\"5\"/></emitter>\
             <emitter type=\"point\"><transform name=\"to_world\"><translate z=\"4\"/></transform>\
               <spectrum name=\"intensity\" value=\"2\"/><float name=\"sampling_weight\" value=\"2\"/></emitter>\
             <emitter type=\"spot\"><transform name=\"to_world\">\
               <lookat origin=\"0, 5, 0\" target=\"0, 0, 0\" up=\"0, 0, 1\"/></transform>\
               <float name=\"cutoff_angle\" value=\"40\"/></emitter>\
             <emitter type=\"directional\"><vector name=\"direction\" x=\"0\" y=\"-2\" z=\"0\"/>\
               <rgb name=\"irradiance\" value=\"1, 2, 3\"/></emitter>\
             <shape type=\"sphere\"><point name=\"center\" x=\"1\"/><float name=\"radius\" value=\"0.5\"/>\
               <emitter type=\"area\"><rgb name=\"radiance\" value=\"3, 2, 1\"/></emitter></shape>",
        )
        .unwrap();
        assert_eq!(s.emitters.len(), 5);
        match &s.emitters[0] {
            Emitter::Point {
                position,
                intensity,
            } => {
                assert_eq!(*position, Vec3::new(1.0, 2.0, 3.0));
                assert_eq!(*intensity, Vec3::splat(5.0));
            }
            e => panic!("{e:?}"),
        }
        match &s.emitters[1] {
            Emitter::Point {
                position,
                intensity,
            } => {
                assert_eq!(*position, Vec3::new(0.0, 0.0, 4.0));
                assert_eq!(*intensity, Vec3::splat(2.0));
            }
            e => panic!("{e:?}"),
        }
        match &s.emitters[2] {
            Emitter::Spot {
                position,
                axis,
                cutoff,
                beam_width,
                intensity,
                ..
            } => {
                assert!(position.abs_diff_eq(Vec3::new(0.0, 5.0, 0.0), 1e-6));
                assert!(axis.abs_diff_eq(-Vec3::Y, 1e-6));
                assert!((cutoff - 40f32.to_radians()).abs() < 1e-6);
                assert!((beam_width - 30f32.to_radians()).abs() < 1e-6);
                assert_eq!(*intensity, Vec3::ONE);
            }
            e => panic!("{e:?}"),
        }
        match &s.emitters[3] {
            Emitter::Directional {
                direction,
                irradiance,
            } => {
                assert_eq!(*direction, -Vec3::Y);
                assert_eq!(*irradiance, Vec3::new(1.0, 2.0, 3.0));
            }
            e => panic!("{e:?}"),
        }
        match &s.emitters[4] {
            Emitter::Area { shape, radiance } => {
                assert_eq!(*shape, 0);
                assert_eq!(*radiance, Vec3::new(3.0, 2.0, 1.0));
            }
            e => panic!("{e:?}"),
        }
        let sph = &s.shapes[0];
        assert_eq!(sph.emission, Some(Vec3::new(3.0, 2.0, 1.0)));
        assert!(sph
            .mesh
            .positions
            .iter()
            .all(|p| ((*p - Vec3::X).length() - 0.5).abs() < 1e-5));
    }

    #[test]
    fn sensor_defaults_and_fov_axis() {
        let s = scene(
            "<sensor type=\"perspective\" id=\"a\"/>\
             <sensor type=\"perspective\" id=\"b\"><float name=\"fov\" value=\"30\"/>\
               <string name=\"fov_axis\" value=\"Smaller\"/><float name=\"near_clip\" value=\"0.1\"/>\
               <transform name=\"to_world\"><lookat origin=\"0,0,5\" target=\"0,0,0\"/></transform>\
               <sampler type=\"independent\"><integer name=\"sample_count\" value=\"4\"/></sampler></sensor>",
        )
        .unwrap();
        let a = &s.sensors[0];
        assert_eq!((a.width, a.height), (768, 576));
        assert_eq!(a.fov_axis, FovAxis::Diagonal);
        assert!((a.fov - 46.793).abs() < 1e-2, "{}", a.fov);
        let b = &s.sensors[1];
        assert_eq!(b.fov_axis, FovAxis::Smaller);
        assert!(b
            .to_world
            .w_axis
            .truncate()
            .abs_diff_eq(Vec3::new(0.0, 0.0, 5.0), 1e-6));
        assert!(b.to_world.z_axis.truncate().abs_diff_eq(-Vec3::Z, 1e-6));
    }

    #[test]
    fn flip_and_face_normals() {
        let s = scene(
            "<shape type=\"cube\"><boolean name=\"flip_normals\" value=\"true\"/>\
               <boolean name=\"face_normals\" value=\"true\"/></shape>\
             <shape type=\"rectangle\"><boolean name=\"flip_normals\" value=\"true\"/></shape>",
        )
        .unwrap();
        assert!(s.shapes[0].mesh.normals.is_none());
        assert!(
            s.shapes[0].mesh.face_normal_raw(0).y > 0.0,
            "bottom face now faces in"
        );
        assert!(s.shapes[1].mesh.face_normal_raw(0).z < 0.0);
    }

    #[test]
    fn refusals_name_line_and_element() {
        let cases: &[(&str, &str)] = &[
            ("<shape type=\"foo\"/>", "(line 2, col 1), <shape type=\"foo\">: unknown shape plugin 'foo'"),
            ("<emitter type=\"envmap\"><string name=\"filename\" value=\"sky.exr\"/></emitter>", "<string name=\"filename\">: "),
            ("<emitter type=\"envmap\"><string name=\"filename\" value=\"sky.exr\"/></emitter>", "sky.exr: cannot read environment map"),
            ("<emitter type=\"envmap\"><string name=\"filename\" value=\"sky.png\"/></emitter>", "must be OpenEXR (.exr) or Radiance (.hdr)"),
            ("<emitter type=\"envmap\"><string name=\"filename\" value=\"sky.exr\"/><float name=\"gamma\" value=\"2\"/></emitter>", "unsupported property 'gamma'"),
            ("<emitter type=\"envmap\"><string name=\"filename\" value=\"sky.exr\"/><transform name=\"to_world\"><scale value=\"2\"/></transform></emitter>", "must be a rotation"),
            ("<emitter type=\"envmap\"/>", "missing property 'filename'"),
            ("<emitter type=\"constant\"><rgb name=\"radiance\" value=\"-1\"/></emitter>", "'radiance' must not be negative"),
            ("<emitter type=\"constant\"><texture name=\"radiance\" type=\"bitmap\"/></emitter>", "textured emission"),
            ("<shape type=\"cube\"><emitter type=\"area\"><texture name=\"radiance\" type=\"bitmap\"/></emitter></shape>", "textured emission"),
            ("<emitter type=\"sky\"/>", "unknown emitter plugin 'sky'"),
            ("<emitter type=\"area\"/>", "nested inside a shape"),
            ("<emitter type=\"point\"><texture name=\"intensity\" type=\"bitmap\"/></emitter>", "not supported"),
            ("<shape type=\"cube\"><emitter type=\"area\"><spectrum name=\"radiance\" value=\"400:1, 500:2\"/></emitter></shape>", "wavelength"),
            ("<shape type=\"cube\"><emitter type=\"area\"><rgb name=\"radiance\" value=\"-1\"/></emitter></shape>", "negative"),
            ("<sensor type=\"perspective\"><float name=\"focal_length\" value=\"50\"/></sensor>", "focal_length"),
            ("<sensor type=\"orthographic\"/>", "sensor 'orthographic' is not supported yet"),
            ("<sensor type=\"fisheye\"/>", "unknown sensor plugin 'fisheye'"),
            ("<sensor type=\"perspective\"><float name=\"fov\" value=\"nan\"/></sensor>", "non-finite"),
            ("<sensor type=\"perspective\"><float name=\"fov\" value=\"abc\"/></sensor>", "invalid number"),
            ("<sensor type=\"perspective\"><film type=\"hdrfilm\"><integer name=\"crop_width\" value=\"769\"/></film></sensor>", "crop window"),
            ("<sensor type=\"perspective\"><film type=\"hdrfilm\"><rfilter type=\"tent\"><float name=\"stddev\" value=\"1\"/></rfilter></film></sensor>", "unsupported property 'stddev' on <rfilter type=\"tent\">"),
            ("<sensor type=\"perspective\"><film type=\"hdrfilm\"><rfilter type=\"mitchell\"/></film></sensor>", "rfilter 'mitchell' is not supported yet"),
            ("<sensor type=\"perspective\"><film type=\"hdrfilm\"><string name=\"component_format\" value=\"half\"/></film></sensor>", "invalid component_format 'half'"),
            ("<sensor type=\"perspective\"><float name=\"aperture_radius\" value=\"0.1\"/></sensor>", "unsupported property 'aperture_radius' on <sensor type=\"perspective\">"),
            ("<sensor type=\"perspective\"><float name=\"near_clip\" value=\"0\"/></sensor>", "'near_clip' must be greater than zero"),
            ("<sensor type=\"thinlens\"/>", "sensor 'thinlens' is not supported yet"),
            ("<sensor type=\"perspective\"><sampler type=\"sobol\"/></sensor>", "unknown sampler plugin 'sobol'"),
            ("<sensor type=\"perspective\"><sampler type=\"independent\"><boolean name=\"jitter\" value=\"true\"/></sampler></sensor>", "unsupported property 'jitter'"),
            ("<integrator type=\"photonmapper\"/>", "unknown integrator plugin 'photonmapper'"),
            ("<shape type=\"disk\"/>", "shape 'disk' is not supported yet"),
            ("<shape type=\"sphere\"><bsdf type=\"retarder\"/></shape>", "bsdf 'retarder' is not supported yet"),
            ("<bsdf type=\"pplastic\" id=\"m\"/><shape type=\"sphere\"><ref id=\"m\"/></shape>", "<ref id=\"m\">: bsdf 'pplastic' is not supported yet"),
            ("<shape type=\"cube\"><bsdf type=\"twosided\"><bsdf type=\"hair\"/></bsdf></shape>", "bsdf 'hair' is not supported yet"),
            ("<shape type=\"cube\"><bsdf type=\"blendbsdf\"><bsdf type=\"conductor\"/></bsdf></shape>", "blendbsdf needs 2 nested bsdf(s), found 1"),
            ("<shape type=\"cube\"><bsdf type=\"dielectric\"><string name=\"int_ior\" value=\"unobtainium\"/></bsdf></shape>", "unknown index of refraction 'unobtainium'"),
            ("<shape type=\"cube\"><bsdf type=\"roughconductor\"><string name=\"distribution\" value=\"phong\"/></bsdf></shape>", "invalid distribution 'phong'"),
            ("<shape type=\"cube\"><bsdf type=\"conductor\"><rgb name=\"eta\" value=\"-1\"/></bsdf></shape>", "'eta' must be finite and non-negative"),
            ("<shape type=\"cube\"><bsdf type=\"shiny\"/></shape>", "unknown bsdf plugin 'shiny'"),
            ("<shape type=\"cube\"><bsdf type=\"diffuse\"><float name=\"roughness\" value=\"0.1\"/></bsdf></shape>", "unsupported property 'roughness' on <bsdf type=\"diffuse\">"),
            ("<shape type=\"cube\"><bsdf type=\"diffuse\"><texture type=\"noise\" name=\"reflectance\"/></bsdf></shape>", "unknown texture plugin 'noise'"),
            ("<sensor type=\"perspective\"><transform name=\"to_world\"><scale value=\"2\"/></transform></sensor>", "scale"),
            ("<shape type=\"cube\"><float name=\"radius\" value=\"1\"/></shape>", "unsupported property 'radius' on <shape type=\"cube\">"),
            ("<shape type=\"cube\"><bsdf type=\"measured\"/></shape>", "bsdf 'measured' is not supported yet"),
            ("<shape type=\"cube\"><ref id=\"nope\"/></shape>", "unknown bsdf 'nope'"),
            ("<shape type=\"cube\" id=\"a\"/><shape type=\"cube\" id=\"a\"/>", "duplicate id 'a'"),
            ("<shape type=\"cube\"><transform name=\"to_world\"><lookat origin=\"1,1,1\" target=\"1,1,1\"/></transform></shape>", "degenerate lookat"),
            ("<shape type=\"cube\"><transform name=\"to_world\"><scale value=\"0\"/></transform></shape>", "singular"),
            ("<shape type=\"cube\"><transform name=\"to_world\"><matrix value=\"1 2 3\"/></transform></shape>", "16"),
            ("<shape type=\"cube\"><transform name=\"to_world\"><rotate angle=\"3\"/></transform></shape>", "zero length"),
            ("<shape type=\"obj\"/>", "missing property 'filename'"),
            ("<shape type=\"sphere\"><float name=\"radius\" value=\"$undefined\"/></shape>", "undefined parameter '$undefined'"),
            ("<include filename=\"x.xml\"/>", "<include> is not supported yet"),
            ("<shape type=\"sphere\"><transform name=\"to_world\"><scale x=\"2\"/></transform></shape>", "uniformly"),
            ("<shape type=\"cube\" id=\"a/b\"/>", "id 'a/b'"),
        ];
        for (body, want) in cases {
            let e = scene(body).unwrap_err().to_string();
            assert!(e.starts_with("t/scene.xml (line 2"), "{body}: {e}");
            assert!(e.contains(want), "{body}: {e}");
            assert!(!e.contains('\n'));
        }
        let e = parse(
            "<scene version=\"3.0.0\">\n<shape></scene>",
            Path::new("m.xml"),
        )
        .unwrap_err();
        assert!(e.to_string().starts_with("m.xml (line 2"), "{e}");
        let deep = format!(
            "<scene version=\"3.0\">{}<bsdf type=\"diffuse\"/>{}</scene>",
            "<bsdf type=\"twosided\">".repeat(50_000),
            "</bsdf>".repeat(50_000)
        );
        let e = parse(&deep, Path::new("d.xml")).unwrap_err().to_string();
        assert!(
            e.contains("d.xml (line 1)") && e.contains("nested deeper"),
            "{e}"
        );
        // Quoted '>' and comments do not confuse the depth scan.
        let ok = "<scene version=\"3.0.0\"><!-- <a><b> --><shape type=\"cube\" id=\"a&gt;\"/>\
                  <shape type=\"cube\" id='x>y'/></scene>";
        assert_eq!(parse(ok, Path::new("ok.xml")).unwrap().shapes.len(), 2);
        let e = parse("<scene/>", Path::new("m.xml")).unwrap_err();
        assert!(e.to_string().contains("missing attribute 'version'"), "{e}");
    }
}
