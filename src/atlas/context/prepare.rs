//! Everything fixed about a run before any stage: the scene, its ray-casting structure, the
//! atlas of every reconstructed shape, their tile layout and the photos, plus the helpers every
//! stage needs to address them (a shape's atlas, a store shaped like the layout, the tile
//! window under the memory budget) and the fingerprint of the run's inputs.
//!
//! [`prepare`] checks every input before any heavy work (the BVH, the unwrap, the geometry
//! store): the scene and its meshes parse, every photo decodes to its end at its sensor's film
//! size, and some emitter has positive power. The decoded photos are kept for the projection,
//! so each is read once.

use crate::atlas::store::{window_tiles_for_budget, TileStore};
use crate::atlas::store::{Layout, TexelGeom};
use crate::atlas::uv::density::{self, DensityPlan, ShapeDensity};
use crate::atlas::uv::orient;
use crate::atlas::uv::{build_atlas_with_progress, AtlasSettings, ShapeAtlas, TexelMap};
use crate::base::error::{Error, Result};
use crate::base::fsio::Fnv;
use crate::base::progress::{note, Mode, Stage};
use crate::config::{Config, Density, Exposure, Response};
use crate::image::{read_photo, Image};
use crate::physics::accel::Accel;
use crate::physics::light::emitter_power;
use crate::report::ShapeTexels;
use crate::scene::photos::is_8bit;
use crate::scene::{KnownBsdf, KnownMaterial, Material, Mesh, Scene, Sides};
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

/// The scene with its acceleration structure, atlases and tile layout: everything fixed.
pub struct RunContext {
    pub scene: Scene,
    pub accel: Accel,
    /// Per shape: its atlas if reconstructed (emitters have none).
    pub atlases: Vec<Option<ShapeAtlas>>,
    pub layout: Layout,
    /// Sensor index -> photo path, for the sensors that have a photo.
    pub views: Vec<(usize, PathBuf)>,
    /// How the 8-bit photos' codes become linear values (the run config's).
    pub response: Response,
    /// The texel density of every reconstructed shape and how it was chosen.
    pub density: DensityPlan,
    /// The photos decoded by [`prepare`], per view, until a stage takes them
    /// ([`RunContext::take_photo`]).
    photos: Mutex<Vec<Option<Image>>>,
}

/// Everything a stage needs about one reconstructed shape's surface and atlas.
pub struct ShapeRef<'a> {
    /// Index into `Scene::shapes`.
    pub index: u32,
    pub mesh: &'a Mesh,
    pub sides: Sides,
    /// Per-triangle corner UVs in texel units.
    pub corner_uv: &'a [[Vec2; 3]],
}

impl ShapeRef<'_> {
    /// World-space edge vectors of one texel on triangle `tri`: `(dP/dx, dP/dy)`, the sides
    /// of the texel's square on the triangle's plane.
    pub fn texel_edges(&self, tri: usize) -> (Vec3, Vec3) {
        texel_jacobian(self.mesh, tri, &self.corner_uv[tri])
    }
}

/// World-space edge vectors of one texel on triangle `tri` of `mesh`, whose corners sit at
/// texel coordinates `uv`: `(dP/dx, dP/dy)`; zero for a triangle without texture area.
pub fn texel_jacobian(mesh: &Mesh, tri: usize, uv: &[Vec2; 3]) -> (Vec3, Vec3) {
    let [p0, p1, p2] = mesh.triangle(tri);
    let (e1, e2) = (p1 - p0, p2 - p0);
    let (d1, d2) = (uv[1] - uv[0], uv[2] - uv[0]);
    let det = d1.x * d2.y - d1.y * d2.x;
    if det == 0.0 || !det.is_finite() {
        return (Vec3::ZERO, Vec3::ZERO);
    }
    let dpdx = (e1 * d2.y - e2 * d1.y) / det;
    let dpdy = (e2 * d1.x - e1 * d2.x) / det;
    (dpdx, dpdy)
}

/// Where a run keeps its tile stores (and its checkpoints): `<out>/checkpoint`.
pub fn state_dir(out: &Path) -> PathBuf {
    out.join("checkpoint")
}

/// Load the scene, pick the views, check every input (photos decoded and sized, some light),
/// then choose the texel densities, unwrap every reconstructed shape and lay out the tiles.
/// What the scene file alone tells (photos against films, no emitter at all) is checked
/// before the meshes are read.
#[inline(never)] // a stage entry tools/icount.py measures
pub fn prepare(cfg: &Config, mode: Mode) -> Result<RunContext> {
    let outline = crate::scene::load_outline(cfg)?;
    let views = match_views(&outline, cfg, mode)?;
    if outline.emitters.is_empty() {
        check_lit(&outline)?;
    }
    note_unscaled(cfg, &outline, &views, mode);
    let photos = read_photos(&outline, &views, &cfg.response, mode)?;
    let scene = crate::scene::load(cfg)?;
    check_lit(&scene)?;
    let mut p = prepare_scene(cfg, scene, views, mode)?;
    p.response = cfg.response.clone();
    *p.photos.lock().unwrap_or_else(|e| e.into_inner()) = photos.into_iter().map(Some).collect();
    Ok(p)
}

/// [`prepare`] without reading the photos or checking the light: the atlas of a run whose
/// inputs were checked when it ran (scoring a finished run).
pub fn prepare_layout(cfg: &Config, mode: Mode) -> Result<RunContext> {
    let scene = crate::scene::load(cfg)?;
    let views = match_views(&scene, cfg, mode)?;
    let mut p = prepare_scene(cfg, scene, views, mode)?;
    p.response = cfg.response.clone();
    Ok(p)
}

fn prepare_scene(
    cfg: &Config,
    mut scene: Scene,
    views: Vec<(usize, PathBuf)>,
    mode: Mode,
) -> Result<RunContext> {
    apply_known_shapes(cfg, &mut scene)?;
    let settings = AtlasSettings {
        texels_per_unit: cfg
            .atlas
            .texels_per_unit
            .per_unit()
            .unwrap_or(density::FALLBACK),
        padding: cfg.atlas.padding,
        use_mesh_uvs: cfg.atlas.use_mesh_uvs,
        max_size: cfg.atlas.max_texture_size,
    };
    let accel = Accel::build(&scene);
    orient(&mut scene, &accel, &views, mode);
    let auto = cfg.atlas.texels_per_unit == Density::Auto;
    let plan = match auto {
        true => plan_density(cfg, &scene, &accel, &views),
        false => DensityPlan::fixed(&scene, settings.texels_per_unit),
    };
    for n in &plan.notes {
        note(mode, n);
    }
    let atlases = build_atlases(&scene, &settings, &plan, auto, mode)?;
    RunContext::assemble(scene, accel, views, atlases, plan, cfg.atlas.tile_size)
}

/// Turns two-sided shapes' triangles to the side the photos of `views` see
/// ([`orient::orient_two_sided`]), with a note when any turned.
fn orient(scene: &mut Scene, accel: &Accel, views: &[(usize, PathBuf)], mode: Mode) {
    let sensors: Vec<usize> = views.iter().map(|v| v.0).collect();
    let o = orient::orient_two_sided(scene, accel, &sensors);
    if o.flipped > 0 {
        let first: Vec<String> = o.shapes.iter().take(3).map(|s| format!("'{s}'")).collect();
        let more = if o.shapes.len() > 3 { ", ..." } else { "" };
        note(
            mode,
            &format!(
                "two-sided shapes: {} triangles of {} shapes ({}{more}) turned to the side the \
                 photos see (their normals pointed away from it)",
                o.flipped,
                o.shapes.len(),
                first.join(", ")
            ),
        );
    }
}

/// Marks the run config's `[shapes.<id>] reconstruct = false` shapes as known diffuse
/// surfaces of the reflectance given, and every coated shape not kept that way as coated (its
/// base reconstructed); an id the scene lacks, a shape that emits or already has a known
/// material, or one kept without a reflectance that has no coat, is refused.
fn apply_known_shapes(cfg: &Config, scene: &mut Scene) -> Result<()> {
    let bad = |id: &str, m: String| match &cfg.source {
        Some(p) => Error::config_in(p, format!("[shapes.{id}]: {m}")),
        None => Error::config(format!("[shapes.{id}]: {m}")),
    };
    for (id, rho) in &cfg.known_shapes {
        let Some(s) = scene.shapes.iter_mut().find(|s| &s.id == id) else {
            return Err(bad(id, format!("the scene has no shape '{id}'")));
        };
        if s.emission.is_some() || s.known().is_some() {
            return Err(bad(
                id,
                format!(
                    "shape '{id}' is an emitter or has a non-diffuse material; only a diffuse \
                     shape takes a known reflectance"
                ),
            ));
        }
        s.material = Material::Known(Box::new(KnownMaterial {
            plugin: "diffuse (known)".into(),
            bsdf: KnownBsdf::Diffuse(Vec3::from_array(*rho)),
        }));
    }
    for id in &cfg.kept_coats {
        let coated = scene
            .shapes
            .iter()
            .find(|s| &s.id == id)
            .map(|s| s.known().is_some_and(|k| k.bsdf.coat().is_some()));
        match coated {
            None => return Err(bad(id, format!("the scene has no shape '{id}'"))),
            Some(false) => {
                return Err(bad(
                    id,
                    "reconstruct = false needs the shape's `reflectance` (a number or [r, g, b]) \
                     unless the shape is a plastic whose stated base is kept"
                        .into(),
                ))
            }
            Some(true) => {}
        }
    }
    for s in &mut scene.shapes {
        let coat = s.known().is_some_and(|k| k.bsdf.coat().is_some());
        if coat && !cfg.kept_coats.contains(&s.id) {
            if let Material::Known(k) = std::mem::take(&mut s.material) {
                s.material = Material::Coated(k);
            }
        }
    }
    Ok(())
}

/// The texel density of every shape under `cfg` (fixed, or from the photos of `views`).
pub fn plan_density(
    cfg: &Config,
    scene: &Scene,
    accel: &Accel,
    views: &[(usize, PathBuf)],
) -> DensityPlan {
    let Some(d) = cfg.atlas.texels_per_unit.per_unit() else {
        let sensors: Vec<usize> = views.iter().map(|v| v.0).collect();
        let fine = density::finest_footprints(scene, accel, &sensors);
        let budget = match cfg.atlas.max_texels {
            0 => density::default_budget(density::photo_pixels(scene, &sensors)),
            n => n,
        };
        return density::plan(scene, &fine, cfg.atlas.max_texture_size, budget);
    };
    DensityPlan::fixed(scene, d)
}

/// Refuses a scene that nothing lights: no emitter, or none with positive finite power.
pub fn check_lit(scene: &Scene) -> Result<()> {
    let lit = scene.emitters.iter().any(|e| {
        let p = emitter_power(scene, e);
        p.is_finite() && p.max_element() > 0.0
    });
    match lit {
        true => Ok(()),
        false => Err(Error::input(
            &scene.path,
            match scene.emitters.len() {
                0 => "the scene is unlit: it has no emitter, and albedo cannot be recovered \
                      without light"
                    .to_string(),
                n => format!(
                    "the scene is unlit: none of its {n} emitters has positive power, and \
                     albedo cannot be recovered without light"
                ),
            },
        )),
    }
}

/// Every view's photo decoded to its end (in parallel; 8-bit ones through `response`) and its
/// size checked against its sensor's film: the first bad photo in view order is the error.
/// Masked pixels are noted.
pub fn read_photos(
    scene: &Scene,
    views: &[(usize, PathBuf)],
    response: &Response,
    mode: Mode,
) -> Result<Vec<Image>> {
    let photos = views
        .par_iter()
        .map(|(si, path)| read_photo(path, &scene.sensors[*si], response))
        .collect::<Vec<Result<Image>>>()
        .into_iter()
        .collect::<Result<Vec<Image>>>()?;
    for ((_, path), image) in views.iter().zip(&photos) {
        if image.masked > 0 {
            let n = image.masked;
            let what = match is_8bit(path) {
                true => "clipped or near-black",
                false => "non-finite or negative",
            };
            note(
                mode,
                &format!("{}: {n} {what} pixels masked", path.display()),
            );
        }
    }
    Ok(photos)
}

/// Notes, once, that the run's 8-bit photos (PNG, JPEG) have no absolute scale when their
/// gains are taken as known and not pinned: their linear values in [0, 1] would be read as
/// scene radiance.
fn note_unscaled(cfg: &Config, scene: &Scene, views: &[(usize, PathBuf)], mode: Mode) {
    if cfg.exposure != Exposure::Known {
        return;
    }
    let ids: Vec<&str> = (views.iter())
        .filter(|(_, p)| is_8bit(p))
        .map(|(si, _)| scene.sensors[*si].id.as_str())
        .filter(|id| !cfg.pinned_gains.contains_key(*id))
        .collect();
    if !ids.is_empty() {
        note(
            mode,
            &format!(
                "8-bit photos have no absolute scale ({}): with [views] exposure = \"known\" \
                 their linear values in [0, 1] are read as scene radiance; set exposure = \
                 \"estimate\" or pin each view's gain ([views.<id>] exposure = g)",
                ids.join(", ")
            ),
        );
    }
}

/// The (sensor, photo) pairs of a run: the config's `views`, or every sensor with its photo
/// beside the scene, the one the scene names (a COLMAP image's) or the one
/// `images/<id>.exr|png|jpg|jpeg` (sensors without one are skipped with a note; a sensor
/// with two is refused).
pub fn match_views(scene: &Scene, cfg: &Config, mode: Mode) -> Result<Vec<(usize, PathBuf)>> {
    let mut views = Vec::new();
    if cfg.views.is_empty() {
        let dir = scene.dir().join("images");
        for (i, s) in scene.sensors.iter().enumerate() {
            let found = match &s.photo {
                Some(p) => p.is_file().then(|| p.clone()),
                None => crate::scene::photos::find(&dir, &s.id)?,
            };
            match found {
                Some(p) => views.push((i, p)),
                None => {
                    let p = (s.photo.clone()).unwrap_or_else(|| dir.join(format!("{}.exr", s.id)));
                    let msg = format!(
                        "sensor '{}' has no photo {} (or .png, .jpg, .jpeg): skipped",
                        s.id,
                        p.display()
                    );
                    note(mode, &msg);
                }
            }
        }
    } else {
        for (id, p) in &cfg.views {
            let i = scene
                .sensors
                .iter()
                .position(|s| &s.id == id)
                .ok_or_else(|| {
                    Error::input(
                        &cfg.scene,
                        format!("views names sensor '{id}', which the scene does not have"),
                    )
                })?;
            views.push((i, p.clone()));
        }
    }
    if views.is_empty() {
        return Err(Error::input(
            &cfg.scene,
            "no photos: no sensor has an images/<sensor id>.exr (or .png, .jpg, .jpeg) and the \
             config names no views",
        ));
    }
    Ok(views)
}

impl RunContext {
    /// `scene` with its acceleration structure, every reconstructed shape unwrapped by
    /// `settings` (one density for all) and the textures laid out in tiles of `tile_size`;
    /// `views` are the (sensor, photo) pairs. An atlas that cannot be made is an error naming
    /// the shape.
    pub fn new(
        scene: Scene,
        views: Vec<(usize, PathBuf)>,
        settings: &AtlasSettings,
        tile_size: u32,
    ) -> Result<RunContext> {
        let plan = DensityPlan::fixed(&scene, settings.texels_per_unit);
        Self::build(scene, views, settings, plan, tile_size, Mode::Quiet)
    }

    /// [`RunContext::new`] with per-triangle density levels (`levels[shape]`, as
    /// `atlas::density` plans them): for tests of what follows the atlas.
    #[cfg(test)]
    pub(crate) fn with_levels(
        scene: Scene,
        settings: &AtlasSettings,
        levels: Vec<Vec<u8>>,
        tile_size: u32,
    ) -> Result<RunContext> {
        let mut plan = DensityPlan::fixed(&scene, settings.texels_per_unit);
        for (d, l) in plan.shapes.iter_mut().zip(levels) {
            if let Some(d) = d {
                d.levels = l;
            }
        }
        Self::build(scene, vec![], settings, plan, tile_size, Mode::Quiet)
    }

    /// The atlases of `plan` (a fixed density) and the BVH, with the unwrap's progress shown
    /// in `mode`.
    fn build(
        scene: Scene,
        views: Vec<(usize, PathBuf)>,
        settings: &AtlasSettings,
        plan: DensityPlan,
        tile_size: u32,
        mode: Mode,
    ) -> Result<RunContext> {
        // The BVH and the shapes' atlases are independent: built side by side, each atlas a
        // pure function of its mesh (so the order of the work never changes a result).
        let (accel, atlases) = rayon::join(
            || Accel::build(&scene),
            || build_atlases(&scene, settings, &plan, false, mode),
        );
        Self::assemble(scene, accel, views, atlases?, plan, tile_size)
    }

    /// Per layout slot, the albedo a known diffuse shape keeps (`None`: reconstructed).
    pub fn pinned(&self) -> Vec<Option<Vec3>> {
        self.layout
            .slots
            .iter()
            .map(|st| self.scene.shapes[st.shape].pinned_albedo())
            .collect()
    }

    /// Per layout slot, its material's index among the material names of the reconstructed
    /// slots (`Shape::material_name`, numbered in slot order; `None`: unnamed, or pinned).
    pub fn material_groups(&self) -> Vec<Option<u32>> {
        let mut names: std::collections::HashMap<&str, u32> = Default::default();
        (self.layout.slots.iter())
            .map(|st| {
                let shape = &self.scene.shapes[st.shape];
                let name = shape.material_name.as_deref()?;
                if shape.pinned_albedo().is_some() {
                    return None;
                }
                let next = names.len() as u32;
                Some(*names.entry(name).or_insert(next))
            })
            .collect()
    }

    fn assemble(
        scene: Scene,
        accel: Accel,
        views: Vec<(usize, PathBuf)>,
        atlases: Vec<Option<ShapeAtlas>>,
        mut density: DensityPlan,
        tile_size: u32,
    ) -> Result<RunContext> {
        let textures: Vec<(usize, u32, u32)> = atlases
            .iter()
            .enumerate()
            .filter_map(|(i, a)| a.as_ref().map(|a| (i, a.width, a.height)))
            .collect();
        // the density an atlas was actually built at (lower if it had to be refitted)
        for (d, a) in density.shapes.iter_mut().zip(&atlases) {
            if let (Some(d), Some(a)) = (d, a) {
                d.texels_per_unit = a.texel_density;
            }
        }
        let layout = Layout::fitted(tile_size, &textures);
        Ok(RunContext {
            scene,
            accel,
            atlases,
            layout,
            views,
            response: Response::Srgb,
            density,
            photos: Mutex::new(Vec::new()),
        })
    }

    /// Per reconstructed shape: its density (and how it was chosen), texture size and covered
    /// texels, counted in `geom` (for report.json).
    #[inline(never)] // a stage entry tools/icount.py measures
    pub fn texel_report(
        &self,
        geom: &TileStore<TexelGeom>,
        window_tiles: usize,
    ) -> Result<Vec<ShapeTexels>> {
        let covered: Vec<AtomicU64> = self
            .layout
            .slots
            .iter()
            .map(|_| AtomicU64::new(0))
            .collect();
        geom.for_each_tile(window_tiles, |t, g| {
            let n = g.iter().filter(|g| g.covered()).count() as u64;
            covered[self.layout.slot_of_tile(t as u32)].fetch_add(n, Ordering::Relaxed);
        })?;
        let rows = self.layout.slots.iter().zip(&covered).map(|(slot, c)| {
            let i = slot.shape;
            let d = self.density.shapes[i].clone();
            let a = self.atlases[i].as_ref();
            let mesh = &self.scene.shapes[i].mesh;
            let area_by_level = d
                .as_ref()
                .and_then(|d| d.level_shares(mesh))
                .map_or(Vec::new(), |s| s.iter().map(|&a| a as f32).collect());
            ShapeTexels {
                shape: self.scene.shapes[i].id.clone(),
                texels_per_unit: a.map_or(0.0, |a| a.texel_density),
                area_by_level,
                finest_footprint: d.as_ref().and_then(|d| d.finest_footprint),
                limited_by: d.and_then(|d| d.limited_by),
                width: a.map_or(0, |a| a.width),
                height: a.map_or(0, |a| a.height),
                covered_texels: c.load(Ordering::Relaxed),
            }
        });
        Ok(rows.collect())
    }

    /// The photo of view `view` as [`prepare`] decoded it, handed over once (`None` if it
    /// was taken already or this `RunContext` was not made by [`prepare`]).
    pub fn take_photo(&self, view: usize) -> Option<Image> {
        let mut photos = self.photos.lock().unwrap_or_else(|e| e.into_inner());
        photos.get_mut(view).and_then(Option::take)
    }

    /// Frees the decoded photos that no stage took (a resumed run does not project).
    pub fn release_photos(&self) {
        self.photos
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clear();
    }

    /// The shape of layout slot `slot`.
    pub fn shape_ref(&self, slot: usize) -> ShapeRef<'_> {
        let si = self.layout.slots[slot].shape;
        let s = &self.scene.shapes[si];
        ShapeRef {
            index: si as u32,
            mesh: &s.mesh,
            sides: s.sides,
            corner_uv: &self.atlases[si]
                .as_ref()
                .expect("reconstructed shape has an atlas")
                .corner_uv,
        }
    }

    /// The id of the shape of layout slot `slot`.
    pub fn slot_id(&self, slot: usize) -> &str {
        &self.scene.shapes[self.layout.slots[slot].shape].id
    }

    /// A new tile store at `path` shaped like this layout (every tile, every texel), each
    /// record `fill`.
    pub fn create_store<T: bytemuck::Pod + Send + Sync>(
        &self,
        path: impl AsRef<Path>,
        fill: T,
    ) -> Result<TileStore<T>> {
        TileStore::create(
            path,
            self.layout.tile_count as usize,
            self.layout.tile_texels(),
            fill,
        )
    }

    /// Opens a run's existing store at `path` and checks that it is shaped like this layout.
    pub fn open_store<T: bytemuck::Pod + Send + Sync>(
        &self,
        path: impl AsRef<Path>,
    ) -> Result<TileStore<T>> {
        let store = TileStore::open(path.as_ref())?;
        if store.tile_count() != self.layout.tile_count as usize
            || store.tile_texels() != self.layout.tile_texels()
        {
            return Err(Error::corrupt(
                path.as_ref(),
                format!(
                    "tile store has {} tiles of {} texels, the atlas layout {} of {}",
                    store.tile_count(),
                    store.tile_texels(),
                    self.layout.tile_count,
                    self.layout.tile_texels()
                ),
            ));
        }
        Ok(store)
    }

    /// Tiles per mapped window for a store of `T`: half the configured memory budget (the
    /// other half is for what a stage keeps beside its window: caches, scratch textures).
    pub fn window<T>(&self, cfg: &Config) -> usize {
        let tile_bytes = (self.layout.tile_texels() * std::mem::size_of::<T>()) as u64;
        window_tiles_for_budget((cfg.memory_budget_mib << 20) / 2, tile_bytes).max(1)
    }

    /// Hash of everything that changes a run's result: the settings without `threads`,
    /// the checkpoint intervals, `memory_budget_mib` and `min_observed_share` (which never
    /// change results), the
    /// scene file, every file it names (meshes, textures) and the photos. A checkpoint made
    /// with other inputs must not be resumed.
    pub fn fingerprint(&self, cfg: &Config) -> Result<u64> {
        let mut h = Fnv::default();
        let mut c = cfg.clone();
        c.threads = 0;
        c.checkpoint_every_batches = 1;
        c.checkpoint_every_seconds = 0.0;
        c.memory_budget_mib = 0;
        c.min_observed_share = 0.0;
        let json = serde_json::to_vec(&c).map_err(|e| Error::internal(format!("settings: {e}")))?;
        h.update(&json);
        let mut hash_file = |p: &Path| -> Result<()> {
            h.update(p.to_string_lossy().as_bytes());
            let bytes = std::fs::read(p).map_err(|e| Error::io(p, e))?;
            h.update(&(bytes.len() as u64).to_le_bytes());
            h.update(&bytes);
            Ok(())
        };
        hash_file(&cfg.scene)?;
        for f in &self.scene.files {
            hash_file(f)?;
        }
        for (_, photo) in &self.views {
            hash_file(photo)?;
        }
        Ok(h.finish())
    }
}

/// Every reconstructed shape's atlas at its planned density, in parallel, with progress in
/// triangles; the first failing shape in scene order is the error. With `refit` (automatic
/// density) an atlas that does not fit `max_size` after all is rebuilt at 0.7x its density,
/// up to three times.
fn build_atlases(
    scene: &Scene,
    settings: &AtlasSettings,
    plan: &DensityPlan,
    refit: bool,
    mode: Mode,
) -> Result<Vec<Option<ShapeAtlas>>> {
    let total: u64 = scene
        .shapes
        .iter()
        .filter(|s| s.in_atlas())
        .map(|s| s.mesh.triangles.len() as u64)
        .sum();
    let stage = Stage::new(mode, "unwrap", total, "triangles");
    let atlases: Vec<Result<Option<ShapeAtlas>>> = scene
        .shapes
        .par_iter()
        .zip(&plan.shapes)
        .map(|(s, d)| match (s.in_atlas(), d) {
            (true, Some(d)) => shape_atlas(&s.mesh, settings, d, refit, &stage)
                .map(Some)
                .map_err(|e| match e {
                    Error::Config { msg, .. } => {
                        Error::config_in(&scene.path, format!("shape '{}': {msg}", s.id))
                    }
                    Error::Input { msg, .. } => {
                        Error::input(&scene.path, format!("shape '{}': {msg}", s.id))
                    }
                    other => other,
                }),
            _ => Ok(None),
        })
        .collect();
    stage.finish();
    atlases.into_iter().collect()
}

/// Share of an unwrap's work done at the start of each of its stages.
fn unwrap_share(stage: &str) -> (f64, f64) {
    match stage {
        "segmenting" => (0.0, 0.3),
        "parameterizing" => (0.3, 0.6),
        "packing" => (0.9, 0.08),
        _ => (0.98, 0.02),
    }
}

fn shape_atlas(
    mesh: &Mesh,
    settings: &AtlasSettings,
    d: &ShapeDensity,
    refit: bool,
    stage: &Stage,
) -> Result<ShapeAtlas> {
    let mut s = AtlasSettings {
        texels_per_unit: d.texels_per_unit,
        ..*settings
    };
    let tris = mesh.triangles.len() as u64;
    // triangles' worth of this shape's work reported so far (monotone; retries add none)
    let shown = AtomicU64::new(0);
    let report = |name: &str, done: usize, total: Option<usize>| {
        let (base, span) = unwrap_share(name);
        let frac = base + span * total.map_or(0.0, |t| done as f64 / t.max(1) as f64);
        let now = (frac.min(1.0) * tris as f64) as u64;
        let before = shown.fetch_max(now, Ordering::Relaxed);
        if now > before {
            stage.inc(now - before);
        }
        true
    };
    let mut tries = 0;
    let mut finer = 0;
    let r = loop {
        match build_atlas_with_progress(mesh, &s, &d.levels, report) {
            Err(Error::Config { .. }) if refit && tries < 3 => {
                s.texels_per_unit *= 0.7;
                tries += 1;
            }
            Ok(a) if finer < MAX_FINER && !covers_a_texel(mesh, &a) => {
                s.texels_per_unit *= 2.0;
                finer += 1;
            }
            r => break r,
        }
    };
    stage.inc(tris.saturating_sub(shown.load(Ordering::Relaxed)));
    r
}

/// Doublings of the density a shape thinner than its texels may take until some texel centre
/// falls on it: 8 (x256). A stair nosing a few millimetres tall, unwrapped at a room's
/// density, covers no texel centre: without texels it would render black and reflect nothing.
const MAX_FINER: u32 = 8;

/// Whether some texel of `atlas` stands for a point of `mesh` (checked on small atlases only:
/// a large one always has covered texels unless the mesh has no area).
fn covers_a_texel(mesh: &Mesh, atlas: &ShapeAtlas) -> bool {
    const SMALL: usize = 1 << 16;
    atlas.texel_count() > SMALL || mesh.area() == 0.0 || TexelMap::new(mesh, atlas).covered() > 0
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `w x h` rectangle in z = 0 (two triangles).
    fn strip(w: f32, h: f32) -> Mesh {
        Mesh {
            positions: vec![
                Vec3::new(0.0, 0.0, 0.0),
                Vec3::new(w, 0.0, 0.0),
                Vec3::new(w, h, 0.0),
                Vec3::new(0.0, h, 0.0),
            ],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            ..Default::default()
        }
    }

    fn atlas_at(mesh: &Mesh, texels_per_unit: f32) -> ShapeAtlas {
        let d = ShapeDensity {
            texels_per_unit,
            finest_footprint: None,
            limited_by: Some("unseen".into()),
            levels: Vec::new(),
        };
        let stage = Stage::new(Mode::Quiet, "unwrap", 2, "triangles");
        shape_atlas(mesh, &AtlasSettings::default(), &d, true, &stage).unwrap()
    }

    #[test]
    fn a_shape_thinner_than_its_texels_still_gets_texels() {
        // 1 x 0.004 units at 13 texels per unit: a fifth of a texel tall, no texel centre on it
        let thin = strip(1.0, 0.004);
        let a = atlas_at(&thin, 13.0);
        let covered = TexelMap::new(&thin, &a).covered();
        assert!(covered > 0, "{a:?}");
        assert!(
            a.texel_density > 13.0 && a.texel_density <= 13.0 * 256.0,
            "{}",
            a.texel_density
        );
        // a shape wide enough keeps the density asked for
        let wide = strip(1.0, 0.5);
        let b = atlas_at(&wide, 13.0);
        assert!((b.texel_density - 13.0).abs() < 1e-3, "{}", b.texel_density);
        assert!(TexelMap::new(&wide, &b).covered() > 0);
    }

    #[test]
    fn jacobian_maps_texel_steps_to_world_steps() {
        let mesh = Mesh {
            positions: vec![
                Vec3::ZERO,
                Vec3::new(2.0, 0.0, 0.0),
                Vec3::new(0.0, 0.0, 3.0),
            ],
            normals: None,
            uvs: None,
            triangles: vec![[0, 1, 2]],
            flipped: Vec::new(),
        };
        // 10 texels along x cover 2 units; 30 texels along y cover 3 units
        let uv = [
            Vec2::new(5.0, 5.0),
            Vec2::new(15.0, 5.0),
            Vec2::new(5.0, 35.0),
        ];
        let (dx, dy) = texel_jacobian(&mesh, 0, &uv);
        assert!((dx - Vec3::new(0.2, 0.0, 0.0)).length() < 1e-6, "{dx}");
        assert!((dy - Vec3::new(0.0, 0.0, 0.1)).length() < 1e-6, "{dy}");
    }
}
