//! The immutable scene every stage reads: world-space triangle meshes, emitters and sensors,
//! with units settled at load (scene radiance units per RGB channel, angles in radians).
//!
//! `mitsuba.rs` builds it from a Mitsuba 3 XML file, `gltf.rs` from a glTF 2.0 file, `mesh.rs`
//! loads OBJ/PLY meshes and the built-in shapes; [`load`] picks the format by the file's
//! extension. Nothing downstream knows about XML or glTF.

pub mod colmap;
pub mod envmap;
pub mod filter;
pub mod gltf;
pub mod lens;
pub mod material;
pub mod mesh;
pub mod mitsuba;
pub mod photos;
pub mod truth;

pub use envmap::EnvMap;
pub use filter::PixelFilter;
pub use lens::{Lens, LensModel};
pub use material::{KnownBsdf, KnownMaterial, Rough};

use crate::config::Config;
use crate::Result;
use glam::{Mat4, Vec2, Vec3};
use std::path::PathBuf;
use std::sync::Arc;

/// The scene of a run: `cfg.scene` read as glTF 2.0 if it ends in `.gltf` or `.glb`, else as
/// Mitsuba 3 XML. A glTF scene takes its film sizes from the run's photos and its light units
/// from `cfg.photometric_scale`. With `cfg.colmap`, the COLMAP model's cameras replace the
/// scene's sensors ([`colmap::replace_sensors`]).
pub fn load(cfg: &Config) -> Result<Scene> {
    load_with(cfg, true)
}

/// [`load`] without the meshes (see [`mitsuba::load_outline`]): for the checks that come
/// before the (possibly slow) geometry.
pub fn load_outline(cfg: &Config) -> Result<Scene> {
    load_with(cfg, false)
}

fn load_with(cfg: &Config, meshes: bool) -> Result<Scene> {
    let mut scene = load_file(cfg, meshes)?;
    if let Some(dir) = &cfg.colmap {
        colmap::replace_sensors(&mut scene, dir, cfg.colmap_to_world.as_ref())?;
    }
    Ok(scene)
}

/// The scene file alone, by its format.
fn load_file(cfg: &Config, meshes: bool) -> Result<Scene> {
    if self::gltf::is_gltf(&cfg.scene) {
        let opts = self::gltf::LoadOptions {
            views: &cfg.views,
            photometric_scale: cfg.photometric_scale,
            meshes,
        };
        self::gltf::load(&cfg.scene, &opts)
    } else if meshes {
        mitsuba::load(&cfg.scene)
    } else {
        mitsuba::load_outline(&cfg.scene)
    }
}

/// An RGB triple in scene units (radiance, intensity, irradiance or reflectance, per context).
pub type Rgb = Vec3;

/// Linear-sRGB luminance used for all reports: `Y = 0.2126 R + 0.7152 G + 0.0722 B`.
pub fn luminance(c: Rgb) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

/// A world-space triangle mesh. Triangles are counter-clockwise around their geometric normal
/// `(p1 - p0) x (p2 - p0)`, as in Mitsuba.
#[derive(Debug, Clone, Default)]
pub struct Mesh {
    pub positions: Vec<Vec3>,
    /// Per-vertex shading normals (unit length), if the file had them and `face_normals` is off.
    pub normals: Option<Vec<Vec3>>,
    /// Per-vertex texture coordinates, if the file had them.
    pub uvs: Option<Vec<Vec2>>,
    pub triangles: Vec<[u32; 3]>,
    /// Triangles whose normals are turned (empty: none): a two-sided shape's texels stand
    /// for the side the photos see (`atlas::uv::orient`). Positions and winding are kept.
    pub flipped: Vec<bool>,
}

impl Mesh {
    pub fn triangle(&self, t: usize) -> [Vec3; 3] {
        let [a, b, c] = self.triangles[t];
        [
            self.positions[a as usize],
            self.positions[b as usize],
            self.positions[c as usize],
        ]
    }

    /// Barycentrics `(b1, b2)` of point `p` (in its plane) of triangle `t`: the weights of
    /// vertices 1 and 2; `(0, 0)` for a degenerate triangle.
    pub fn barycentric(&self, t: usize, p: Vec3) -> (f32, f32) {
        let [a, b, c] = self.triangle(t);
        let (e1, e2, d) = (b - a, c - a, p - a);
        let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
        let den = d11 * d22 - d12 * d12;
        if den == 0.0 {
            return (0.0, 0.0);
        }
        let (p1, p2) = (d.dot(e1), d.dot(e2));
        ((d22 * p1 - d12 * p2) / den, (d11 * p2 - d12 * p1) / den)
    }

    /// Unnormalized geometric normal of triangle `t` (length = 2 x area), turned if the
    /// triangle is [`Mesh::flipped`].
    pub fn face_normal_raw(&self, t: usize) -> Vec3 {
        let [p0, p1, p2] = self.triangle(t);
        self.side(t) * (p1 - p0).cross(p2 - p0)
    }

    /// -1 for a [`Mesh::flipped`] triangle, else 1.
    pub fn side(&self, t: usize) -> f32 {
        match self.flipped.get(t) {
            Some(true) => -1.0,
            _ => 1.0,
        }
    }

    pub fn triangle_area(&self, t: usize) -> f32 {
        0.5 * self.face_normal_raw(t).length()
    }

    /// Half the diagonal of the bounding box: the radius of a sphere around the mesh.
    pub fn bounding_radius(&self) -> f32 {
        let lo = self.positions.iter().fold(Vec3::INFINITY, |a, p| a.min(*p));
        let hi = self
            .positions
            .iter()
            .fold(Vec3::NEG_INFINITY, |a, p| a.max(*p));
        match lo.is_finite() && hi.is_finite() {
            true => 0.5 * (hi - lo).length(),
            false => 0.0,
        }
    }

    pub fn area(&self) -> f64 {
        (0..self.triangles.len())
            .map(|t| self.triangle_area(t) as f64)
            .sum()
    }

    /// The shading normal at barycentrics `(b1, b2)` of triangle `t` (weights of vertices 1 and
    /// 2): the interpolated vertex normal if present, else the geometric normal. Unit length.
    pub fn shading_normal(&self, t: usize, b1: f32, b2: f32) -> Vec3 {
        if let Some(n) = &self.normals {
            let [a, b, c] = self.triangles[t];
            let v = n[a as usize] * (1.0 - b1 - b2) + n[b as usize] * b1 + n[c as usize] * b2;
            let l = v.length();
            if l > 0.0 {
                return self.side(t) * (v / l);
            }
        }
        self.face_normal_raw(t).normalize_or_zero()
    }

    /// Apply an affine transform (points by `m`, normals by its inverse transpose).
    pub fn transform(&mut self, m: &Mat4) {
        for p in &mut self.positions {
            *p = m.transform_point3(*p);
        }
        if let Some(ns) = &mut self.normals {
            let nm = m.inverse().transpose();
            for n in ns.iter_mut() {
                *n = nm.transform_vector3(*n).normalize_or_zero();
            }
        }
        // A mirroring transform flips the winding; Mitsuba keeps the index order, so do we.
    }
}

/// Which sides of a surface reflect light. Mitsuba's `diffuse` reflects on the side its
/// (shading) normal points to; `twosided` on both; an emitter-only shape (black BSDF) on none.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sides {
    Front,
    Both,
}

#[derive(Debug, Clone)]
pub struct Shape {
    /// The shape's `id`, or `shape_<index>` in file order.
    pub id: String,
    /// Plugin type as written (`obj`, `ply`, `rectangle`, `cube`, `sphere`).
    pub kind: String,
    /// The mesh file, for file-backed shapes.
    pub file: Option<PathBuf>,
    pub mesh: Mesh,
    pub sides: Sides,
    /// One-sided area emitter radiance on the front side, if the shape emits.
    pub emission: Option<Rgb>,
    /// The diffuse reflectance its BSDF states, if it states one kdmap can read. Never an
    /// input of a reconstruction (that is what kdmap recovers); the truth reader uses it.
    pub reflectance: Option<ReflectanceSpec>,
    /// Whether kdmap recovers this shape's albedo or knows its material.
    pub material: Material,
    /// The name of the material the scene file gives the shape when shapes can share it: the
    /// id of the Mitsuba bsdf it refers to (`<ref id="..."/>`), or `material <i>` for glTF
    /// material `i`. Shapes of one name are one material to the fill of shapes no photo saw.
    pub material_name: Option<String>,
}

/// What a shape's surface is to kdmap.
#[derive(Debug, Clone, PartialEq, Default)]
pub enum Material {
    /// A diffuse surface of unknown albedo: reconstructed.
    #[default]
    Unknown,
    /// A material the scene (or the run config) states and kdmap does not reconstruct:
    /// part of the light transport only.
    Known(Box<KnownMaterial>),
    /// A coated material (`plastic`, `roughplastic`, a `principled` that is one): the coat is
    /// known, the diffuse base under it is reconstructed. The base the scene states is kept
    /// only for writing the material back.
    Coated(Box<KnownMaterial>),
}

/// A diffuse reflectance as a scene file writes it.
#[derive(Debug, Clone, PartialEq)]
pub enum ReflectanceSpec {
    /// `<rgb>`, `<spectrum>` or `<float>`: linear RGB.
    Constant(Rgb),
    /// A `bitmap` texture: the image file (sRGB-encoded unless stated otherwise), looked up
    /// at the mesh's UVs.
    Bitmap(PathBuf),
}

impl Shape {
    /// A plain shape for tests: `mesh` seen from `sides`, no file, no emission, no stated
    /// reflectance, its albedo to be recovered.
    #[cfg(test)]
    pub fn plain(id: &str, mesh: Mesh, sides: Sides) -> Shape {
        Shape {
            id: id.into(),
            kind: "test".into(),
            file: None,
            mesh,
            sides,
            emission: None,
            reflectance: None,
            material: Default::default(),
            material_name: None,
        }
    }

    /// The known material, if the shape has one.
    pub fn known(&self) -> Option<&KnownMaterial> {
        match &self.material {
            Material::Known(k) => Some(k),
            Material::Unknown | Material::Coated(_) => None,
        }
    }

    /// The coated material whose base is reconstructed, if the shape has one.
    pub fn coated(&self) -> Option<&KnownMaterial> {
        match &self.material {
            Material::Coated(k) => Some(k),
            _ => None,
        }
    }

    /// The albedo a known diffuse shape keeps (a run config's `reconstruct = false`): such a
    /// shape has an atlas and is projected like the others, but its `K_d` is pinned.
    pub fn pinned_albedo(&self) -> Option<Rgb> {
        match self.known().map(|k| &k.bsdf) {
            Some(KnownBsdf::Diffuse(rho)) if self.emission.is_none() => Some(*rho),
            _ => None,
        }
    }

    /// Whether the shape gets an atlas: reconstructed ones and pinned known diffuse ones.
    pub fn in_atlas(&self) -> bool {
        self.is_reconstructed() || self.pinned_albedo().is_some()
    }

    /// Whether the albedo of this shape is recovered (emitters and known materials are not; a
    /// coated shape's base is).
    pub fn is_reconstructed(&self) -> bool {
        self.emission.is_none() && matches!(self.material, Material::Unknown | Material::Coated(_))
    }
}

/// Light sources. Area emitters live on their shape (`Shape::emission`) and are listed here
/// too, by shape index, so every light is enumerated in one place.
#[derive(Debug, Clone)]
pub enum Emitter {
    /// Isotropic point light of radiant intensity `intensity` (per steradian).
    Point { position: Vec3, intensity: Rgb },
    /// Mitsuba spot light: at `position`, shining along unit `axis`, intensity `intensity` on
    /// axis, full up to `beam_width`, then falling linearly in angle to zero at `cutoff` (radians).
    Spot {
        position: Vec3,
        axis: Vec3,
        /// The light's full frame (local +z = axis), kept for exporting the scene as it was.
        to_world: Mat4,
        intensity: Rgb,
        cutoff: f32,
        beam_width: f32,
    },
    /// Light from infinitely far away travelling along unit `direction`, with `irradiance`
    /// on a surface perpendicular to it.
    Directional { direction: Vec3, irradiance: Rgb },
    /// One-sided area emitter on shape `shape` with uniform `radiance`.
    Area { shape: usize, radiance: Rgb },
    /// Light from infinitely far away in every direction: Mitsuba's `envmap` (a lat-long
    /// radiance map) or `constant` (one radiance): see [`EnvMap`].
    Environment(Arc<EnvMap>),
}

/// Mitsuba's `fov_axis` choices.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FovAxis {
    X,
    Y,
    Diagonal,
    Smaller,
    Larger,
}

/// A perspective sensor as Mitsuba 3 defines it.
#[derive(Debug, Clone)]
pub struct Sensor {
    /// The sensor's `id`, or `sensor_<index>` (index in file order among the sensors).
    pub id: String,
    /// Camera-to-world; camera looks along local +z, local +x is image left, +y image up.
    pub to_world: Mat4,
    /// Field of view in degrees, along `fov_axis`, as written in the file.
    pub fov: f32,
    pub fov_axis: FovAxis,
    /// The photo's size: the film's crop window (the whole film without one).
    pub width: u32,
    pub height: u32,
    /// The film's full size, which the field of view spans.
    pub film_width: u32,
    pub film_height: u32,
    /// The crop window's top-left pixel on the film (`crop_offset_x/y`).
    pub crop_offset: (u32, u32),
    /// Mitsuba's `principal_point_offset_x/y`: the principal point's offset from the film
    /// center, in fractions of the film's width and height (the image moves the other way).
    pub principal_point: Vec2,
    /// The film's reconstruction filter.
    pub filter: PixelFilter,
    /// A COLMAP camera's lens (its intrinsics and distortion, as COLMAP defines them): when
    /// set, it alone maps pixels to rays, and the fields above describe the nearest Mitsuba
    /// `perspective` sensor (what `scene.xml` gets). `None` for Mitsuba and glTF cameras.
    pub lens: Option<Lens>,
    /// The photo the scene names for this sensor (a COLMAP image's file), if it names one;
    /// else the photo is `<scene dir>/images/<id>.exr`.
    pub photo: Option<PathBuf>,
}

impl Sensor {
    /// A sensor with a whole `width x height` film, a centered principal point and `filter`.
    pub fn simple(
        id: &str,
        to_world: Mat4,
        fov: f32,
        fov_axis: FovAxis,
        (width, height): (u32, u32),
        filter: PixelFilter,
    ) -> Sensor {
        Sensor {
            id: id.to_string(),
            to_world,
            fov,
            fov_axis,
            width,
            height,
            film_width: width,
            film_height: height,
            crop_offset: (0, 0),
            principal_point: Vec2::ZERO,
            filter,
            lens: None,
            photo: None,
        }
    }
}

#[derive(Debug, Clone)]
pub struct Scene {
    /// The scene file (Mitsuba XML or glTF) the scene came from.
    pub path: PathBuf,
    pub shapes: Vec<Shape>,
    pub emitters: Vec<Emitter>,
    pub sensors: Vec<Sensor>,
    /// Every file the scene file names (meshes, textures), in file order: with the scene
    /// file itself, what a run's inputs are.
    pub files: Vec<PathBuf>,
}

impl Scene {
    pub fn dir(&self) -> PathBuf {
        self.path
            .parent()
            .map(|p| p.to_path_buf())
            .unwrap_or_else(|| PathBuf::from("."))
    }

    /// Whether an environment light (`envmap`, `constant`) lights the scene: the one emitter
    /// whose direct light is a sampled estimate everywhere.
    pub fn has_environment(&self) -> bool {
        self.emitters
            .iter()
            .any(|e| matches!(e, Emitter::Environment(_)))
    }

    pub fn triangle_count(&self) -> usize {
        self.shapes.iter().map(|s| s.mesh.triangles.len()).sum()
    }

    /// Axis-aligned bounds of all geometry `(min, max)`.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for s in &self.shapes {
            for p in &s.mesh.positions {
                lo = lo.min(*p);
                hi = hi.max(*p);
            }
        }
        (lo, hi)
    }
}
