//! Each view's camera pose refined against the other views before the final projection:
//! its photo aligned with what the other photos say its surfaces look like.
//!
//! Poses from structure-from-motion sit a pixel or two off the scanned mesh, and a photo
//! projected from a pose that far off paints its texture a pixel or two beside where the other
//! photos put it: on a textured Cornell box, 0.3 degrees and 0.5% of the distance (about 2 px)
//! raise the held-out albedo error from 3.9% to 29.9%. This is direct image alignment with
//! known depth (as Open3D's colour map optimisation, Zhou and Koltun 2014, does per camera).
//!
//! **What is minimised.** For view `v` at its pose `P` (where the round starts), the
//! reference `R_v` is the weighted-mean projection of the *other* views (leave-one-out, so
//! `v`'s own misregistration does not hold it where it is: all views are projected into a
//! scratch store of sums once per round, and `v`'s contribution is taken out again texel by
//! texel), re-rendered into `v` at `P` as the refinement passes render (4 x 4 rays per pixel,
//! the film's filter); `X(x)` is the surface point the ray through pixel `x` meets. A pose
//! change `xi` (a rotation `omega` about the camera's centre and a translation `t` of it,
//! world axes, plus the photo's gain `g`, a nuisance) sends `X(x)` to pixel `w(x; xi)` of the
//! moved camera, and the residual is, per RGB channel,
//!
//! ```text
//! r(x) = I_v(w(x; xi)) - g R_v(x)
//! ```
//!
//! minimised in the Huber norm (`k = 1.345` robust standard deviations of the residuals,
//! re-estimated every iteration) by Levenberg-Marquardt with the photo's image gradient and
//! `dw / dxi` by central differences through [`Camera::project`] (so any camera model
//! works), coarse to fine: both images are blurred (sigma about 4, 2, then 1 px: three box
//! passes), a few iterations per level until a step moves the pixels less than
//! `0.002 sigma` px. Only pixels the reference predicts count: the ray through the pixel
//! meets a reconstructed shape whose texels the other views observed, and no emitter, known
//! material or background lies within `3 sigma + 2` px (the photo holds there what the
//! reference cannot); the blur is normalised over those pixels. Depth edges between
//! reconstructed surfaces are kept: there the render's edge sits where the geometry puts it,
//! which ties the pose to the mesh rather than only to the other photos. The focal length is
//! not refined (a seventh geometric parameter nearly interchangeable with a translation along
//! the axis over a room-sized scene).
//!
//! **What the photos leave free, the geometry fixes.** Moving every camera by one rigid
//! motion changes no residual between photos on a diffuse, textured scene except at depth
//! edges, so the photos alone barely observe the common part of the cameras' errors: on a
//! textured Cornell box with every pose off by 0.3 degrees, photometric alignment left each
//! camera about 1 px off, nearly all of it one common motion (0.55 degrees and 2 cm), and the
//! held-out albedo error at 22.9%. The mesh anchors it: at the finest level each view's cost
//! also holds its geometric edges ([`super::edges`]: silhouettes, creases, shape borders,
//! emitter outlines), each the offset, px, between where the camera projects the edge and
//! where the photo's edge is, re-measured at every pose tried, Huber-weighted in its robust
//! spread; together they weigh [`EDGE_SHARE`] times the photometric residuals. The same
//! capture then comes to 0.17-0.32 px RMS per camera (held-out 6.1%, against 4.8% with
//! perfect poses). A weak prior on each correction ([`PRIOR`]: a 1 px move costs a sample
//! what a residual of a tenth of a robust standard deviation costs) settles what neither
//! constrains at the smallest correction, and a prior in degrees and viewing distances
//! ([`BOUND_PRIOR`]) holds the moves that shift the pixels little (in an open scene, sliding a
//! camera along its view of far objects) near the scene's pose.
//!
//! **Bounds.** The correction (relative to the scene's pose) may reach [`MAX_ROTATION_DEG`]
//! and [`MAX_TRANSLATION`] of the viewing distance (the median distance of the view's clean
//! pixels' surface points); a step beyond either ends the view's alignment, which is then
//! reported as not aligned and keeps the scene's pose. So is a view whose photo does not
//! agree better with the others at the refined pose than at the scene's.
//!
//! **Rounds.** All views are aligned against references made from the poses at the round's
//! start, then [`ROUNDS`] - 1 more rounds start from the refined poses, whose references are
//! sharper where every view moved.
//!
//! **Determinism.** No random numbers; sums over pixels are made in fixed chunks and added in
//! chunk order, and the projections and renders are those of the stage, so the result is the
//! same bits for every thread count.

use super::edges::{self, Edge, EdgeImage};
use super::refine::{current_maps, Refine, REFINE_SUPERSAMPLE};
use super::view::{Tap, View};
use super::{observe_texel, project_tile, ROW_BAND};
use crate::atlas::store::{map_tiles, TexelState, TileStore};
use crate::atlas::texture::SlotTexture;
use crate::base::error::{Error, Result};
use crate::base::interrupt;
use crate::base::progress::{Mode, Stage};
use crate::image::Image;
use crate::physics::camera::Camera;
use crate::physics::render::{apply_pixel_filter, render_view_with, Film, Plan};
use crate::report::PoseCorrection;
use crate::scene::luminance;
use glam::{DMat4, DQuat, DVec3, Vec2, Vec3};
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::path::Path;
use std::time::Instant;

/// The largest rotation of a view's camera, degrees.
pub const MAX_ROTATION_DEG: f64 = 2.0;
/// The largest translation of a view's camera, as a share of its viewing distance.
pub const MAX_TRANSLATION: f64 = 0.02;
/// The blur of each level, coarse to fine, pixels.
pub const LEVELS: [f32; 3] = [4.0, 2.0, 1.0];
/// Rounds of alignment over all views.
pub const ROUNDS: u32 = 2;
/// Most Levenberg-Marquardt iterations per level.
const MAX_ITERATIONS: u32 = 15;
/// A level is done when a step moves the pixels less than this times its blur, pixels.
const STEP_TOL: f64 = 0.002;
/// Fewest pixels a view is aligned on.
const MIN_SAMPLES: u64 = 100;
/// The share of a pixel's blur kernel on usable pixels for its blurred value to count.
const MIN_WEIGHT: f32 = 0.5;
/// Pixels kept clear of what the reference cannot predict, beyond three blurs.
const GUARD_PX: f32 = 2.0;
/// Huber's threshold in robust standard deviations (95% efficiency for Gaussian noise).
const HUBER_K: f64 = 1.345;
/// Samples per chunk of a parallel sum (chunks are added in order).
const CHUNK: usize = 1024;
/// The parameters: rotation (3, radians), translation (3, viewing distances), gain.
const PARAMS: usize = 7;

/// How a view's alignment ended.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Status {
    Active,
    Beyond,
    NoImprovement,
    TooFew,
    Alone,
}

impl Status {
    fn name(self) -> &'static str {
        match self {
            Status::Active => "aligned",
            Status::Beyond => "beyond the bound",
            Status::NoImprovement => "no improvement",
            Status::TooFew => "too few pixels",
            Status::Alone => "no other views",
        }
    }
}

/// One view's pose as refined so far: the scene's camera moved by a rotation `rot` about its
/// centre and a translation `shift` of it (world axes), and the photo's gain.
#[derive(Clone)]
struct Pose {
    nominal: Camera,
    camera: Camera,
    rot: DQuat,
    shift: DVec3,
    gain: f64,
    /// The viewing distance: the median distance of the clean pixels' surface points.
    distance: f64,
    status: Status,
    converged: bool,
    iterations: u32,
    /// The relative residual at the scene's pose and at the refined one.
    residual: (f64, f64),
    /// The median edge offset (px) and the edges measured, at the scene's pose and at the
    /// pose the view keeps (once judged).
    edge_px: [(f64, u64); 2],
    /// What a refused alignment had found (rotation, translation).
    found: Option<(DQuat, DVec3)>,
}

impl Pose {
    fn new(view: &View) -> Pose {
        let distance = viewing_distance(view);
        Pose {
            nominal: view.camera.clone(),
            camera: view.camera.clone(),
            rot: DQuat::IDENTITY,
            shift: DVec3::ZERO,
            gain: 1.0,
            distance: distance.unwrap_or(1.0),
            status: match distance {
                Some(_) => Status::Active,
                None => Status::TooFew,
            },
            converged: false,
            iterations: 0,
            residual: (0.0, 0.0),
            edge_px: [(0.0, 0); 2],
            found: None,
        }
    }

    /// The scene's camera rotated by `rot` about its centre and moved by `shift`.
    fn at(&self, rot: DQuat, shift: DVec3) -> Camera {
        let m0 = self.nominal.to_world().as_dmat4();
        let c0 = m0.transform_point3(DVec3::ZERO);
        let t = DMat4::from_translation(c0 + shift)
            * DMat4::from_quat(rot)
            * DMat4::from_translation(-c0);
        self.nominal.with_to_world((t * m0).as_mat4())
    }

    /// This pose moved by `d` (see [`PARAMS`]): rotated about the current centre, then moved.
    fn moved(&self, d: &[f64]) -> Pose {
        let rot = (DQuat::from_scaled_axis(DVec3::new(d[0], d[1], d[2])) * self.rot).normalize();
        let shift = self.shift + DVec3::new(d[3], d[4], d[5]) * self.distance;
        Pose {
            camera: self.at(rot, shift),
            rot,
            shift,
            gain: self.gain + d[6],
            ..self.clone()
        }
    }

    /// How far this pose is from `start`: the rotation vector and the translation in
    /// viewing distances (the first six [`PARAMS`], to first order).
    fn delta_from(&self, start: &Pose) -> [f64; 6] {
        let w = (self.rot * start.rot.inverse()).to_scaled_axis();
        let t = (self.shift - start.shift) / self.distance;
        [w.x, w.y, w.z, t.x, t.y, t.z]
    }

    fn beyond_bound(&self) -> bool {
        self.rot.angle_between(DQuat::IDENTITY).to_degrees() > MAX_ROTATION_DEG
            || self.shift.length() > MAX_TRANSLATION * self.distance
    }

    fn active(&self) -> bool {
        self.status == Status::Active
    }

    /// Whether the camera is not the scene's.
    fn moved_at_all(&self) -> bool {
        self.active() && (self.rot != DQuat::IDENTITY || self.shift != DVec3::ZERO)
    }

    /// Ends the alignment: the view goes back to the scene's pose (what was found is kept for
    /// the report).
    fn refuse(&mut self, status: Status) {
        self.status = status;
        self.found = Some((self.rot, self.shift));
        (self.rot, self.shift) = (DQuat::IDENTITY, DVec3::ZERO);
        self.camera = self.nominal.clone();
    }

    /// What the report says of it; `view` is the view at the scene's pose, `seconds` the
    /// view's share of the time.
    fn correction(&self, view: &View, seconds: f64) -> PoseCorrection {
        let (rot, shift) = self.found.unwrap_or((self.rot, self.shift));
        // A view refused before the verdict keeps the scene's pose: its residual and edges
        // as they were there.
        let judged = self.edge_px[1].1 > 0 || self.residual.1 > 0.0;
        let after = match judged {
            true => (self.residual.1, self.edge_px[1]),
            false => (self.residual.0, self.edge_px[0]),
        };
        PoseCorrection {
            view: view.camera.id.clone(),
            to_world: self.camera.to_world().transpose().to_cols_array_2d(),
            applied: self.active(),
            status: self.status.name().to_string(),
            converged: self.converged,
            rotation_deg: rot.angle_between(DQuat::IDENTITY).to_degrees(),
            translation: shift.length(),
            translation_rel: shift.length() / self.distance,
            shift_px: mean_pixel_shift(view, &self.at(rot, shift)),
            residual_before: self.residual.0,
            residual_after: after.0,
            edge_px_before: self.edge_px[0].0,
            edge_px_after: after.1 .0,
            edges: after.1 .1,
            gain: self.gain,
            iterations: self.iterations,
            seconds,
        }
    }
}

/// Every view of `ctx` with its pose refined against the others: the views rebuilt at the
/// poses found (pixels classified by rays from the refined cameras; views that were not
/// aligned keep the scene's pose) and, per view, what was found.
pub fn refine<'a>(ctx: &Refine<'a>, mode: Mode) -> Result<(Vec<View<'a>>, Vec<PoseCorrection>)> {
    let t = Instant::now();
    let n = ctx.views.len();
    let mut poses: Vec<Pose> = ctx.views.iter().map(Pose::new).collect();
    if n < 2 {
        poses.iter_mut().for_each(|p| p.refuse(Status::Alone));
    }
    let rounds = ROUNDS;
    let stage = Stage::new(mode, "pose refinement", rounds as u64 * n as u64, "views");
    let mut built: Vec<View<'a>>;
    for round in 0..rounds {
        let views: &[View] = match round {
            0 => ctx.views,
            _ => {
                built = at_poses(ctx, &poses)?;
                &built
            }
        };
        if poses.iter().any(Pose::active) {
            refine_round(
                ctx,
                views,
                &mut poses,
                (round == 0, round + 1 == rounds),
                &stage,
            )?;
        }
    }
    stage.finish();
    let share = t.elapsed().as_secs_f64() / n.max(1) as f64;
    let out = (poses.iter().zip(ctx.views))
        .map(|(p, v)| p.correction(v, share))
        .collect();
    Ok((at_poses(ctx, &poses)?, out))
}

/// The views of `ctx` at `poses`: rays cast again for the cameras that moved (shared among
/// the processes of `ctx.shard`).
fn at_poses<'a>(ctx: &Refine<'a>, poses: &[Pose]) -> Result<Vec<View<'a>>> {
    (ctx.views.iter().zip(poses))
        .map(|(v, pose)| match pose.moved_at_all() {
            true => {
                let (scene, accel, cam) = (&ctx.p.scene, &ctx.p.accel, pose.camera.clone());
                View::new_shared(scene, accel, cam, v.image, v.is_loose(), ctx.shard)
            }
            false => Ok(v.with_image(v.image)),
        })
        .collect()
}

/// One round: every view's reference from `views` (at the poses where the round starts),
/// then all poses aligned together, coarse to fine; in the `first` round the residuals at the
/// scene's poses are recorded, in the `last` each view is judged against its scene pose.
fn refine_round(
    ctx: &Refine,
    views: &[View],
    poses: &mut [Pose],
    (first, last): (bool, bool),
    stage: &Stage,
) -> Result<()> {
    let path = ctx.scratch.dir.join("pose-sums.tiles");
    let sums = project_sums(ctx, views, &path)?;
    let mut refs = Vec::with_capacity(views.len());
    for view in views {
        refs.push(Reference::of(ctx, &sums, view)?);
        stage.inc(1);
        interrupt::check(interrupt::NOTHING_SAVED)?;
    }
    drop(sums);
    std::fs::remove_file(&path).map_err(|e| Error::io(&path, e))?;
    let start = poses.to_vec();
    let edges: Vec<Vec<Edge>> = (views.iter())
        .map(|v| edges::edges(&ctx.p.scene, &ctx.p.accel, &v.camera))
        .collect();
    for (i, &sigma) in LEVELS.iter().enumerate() {
        let levels = levels(views, &refs, &edges, &start, sigma);
        let joint = Joint {
            levels: &levels,
            start: &start,
        };
        if first && i + 1 == LEVELS.len() {
            let at_start = evaluate(&joint, &start, &vec![[1.0; 2]; views.len()], false);
            for (v, pose) in poses.iter_mut().enumerate() {
                pose.residual.0 = at_start.relative(v);
                pose.edge_px[0] = edge_median(&levels[v], &start[v]);
            }
        }
        let settled = iterate(&joint, poses, STEP_TOL * sigma as f64);
        if last && i + 1 == LEVELS.len() {
            judge(&joint, poses, settled);
        }
        interrupt::check(interrupt::NOTHING_SAVED)?;
    }
    Ok(())
}

/// Every view projected into a fresh store at `path`: per texel `sum w L` and `sum w`.
fn project_sums(ctx: &Refine, views: &[View], path: &Path) -> Result<TileStore<TexelState>> {
    let (p, shard, bounds) = (ctx.p, ctx.shard, ctx.bounds);
    let mut sums = p.create_store(path, TexelState::default())?;
    for view in views {
        map_tiles(&mut sums, ctx.geom, ctx.window, |t, g, st| {
            if (shard.owns)(t) && bounds[t].is_some_and(|(lo, hi)| view.camera.may_see(lo, hi)) {
                let slot = p.layout.slot_of_tile(t as u32);
                project_tile(view, &p.accel, &p.shape_ref(slot), g, st, false);
            }
        })?;
        interrupt::check(interrupt::NOTHING_SAVED)?;
    }
    (shard.sync)(&mut sums)?;
    Ok(sums)
}

/// The weighted mean of every view but `view`, from the `sums` of all of them, in a fresh
/// store at `path` (texels only `view` observed, or nearly only, are unobserved).
fn leave_one_out(
    ctx: &Refine,
    sums: &TileStore<TexelState>,
    view: &View,
    path: &Path,
) -> Result<TileStore<TexelState>> {
    let (p, shard, bounds) = (ctx.p, ctx.shard, ctx.bounds);
    let mut loo = p.create_store(path, TexelState::default())?;
    let done = map_tiles(&mut loo, ctx.geom, ctx.window, |t, g, st| -> Result<()> {
        if !(shard.owns)(t) {
            return Ok(());
        }
        let all = sums.read_tile(t)?;
        let sees = bounds[t].is_some_and(|(lo, hi)| view.camera.may_see(lo, hi));
        let shape = p.shape_ref(p.layout.slot_of_tile(t as u32));
        for ((g, s), o) in g.iter().zip(&all).zip(st.iter_mut()) {
            if !g.covered() || s.weight <= 0.0 {
                continue;
            }
            let (mut sum, mut w) = (Vec3::from_array(s.l_orig), s.weight);
            if let Some((l, wv)) = observe_texel(view, &shape, g).filter(|_| sees) {
                sum -= l * wv;
                w -= wv;
            }
            if w > 1e-3 * s.weight {
                o.l_orig = (sum / w).max(Vec3::ZERO).to_array();
                o.weight = w;
            }
        }
        Ok(())
    })?;
    done.into_iter().collect::<Result<()>>()?;
    (shard.sync)(&mut loo)?;
    Ok(loo)
}

/// What the other views say a view should see, at the view's current pose.
struct Reference {
    width: usize,
    height: usize,
    /// The others' map re-rendered (zero where there is none).
    render: Vec<Vec3>,
    /// Pixels whose render is whole: the center ray meets a reconstructed shape, and every
    /// texel the pixel reads was observed by another view.
    usable: Vec<bool>,
    /// Summed-area table of the pixels whose center ray meets no reconstructed shape.
    foreign: Vec<u32>,
}

impl Reference {
    /// The reference of `view` from the `sums` of every view.
    fn of(ctx: &Refine, sums: &TileStore<TexelState>, view: &View) -> Result<Reference> {
        let path = ctx.scratch.dir.join("pose-loo.tiles");
        let loo = leave_one_out(ctx, sums, view, &path)?;
        let half = ctx.scratch.share(1, 2);
        let maps = current_maps(ctx.p, &loo, &half)?;
        let seen = observed_maps(ctx, &loo, &half)?;
        let blank = Image {
            width: view.image.width,
            height: view.image.height,
            pixels: vec![Vec3::ZERO; view.image.pixels.len()],
            valid: vec![false; view.image.pixels.len()],
            masked: view.image.pixels.len(),
        };
        let scene = &ctx.p.scene;
        let film = Film::Box {
            scene,
            photo: &blank,
        };
        let rendered = render(ctx, view, &maps, film)?;
        let observed = render(ctx, view, &seen, Film::HitsOnly)?;
        for m in maps.iter().chain(&seen).flatten() {
            m.check()?;
        }
        drop((maps, seen, loo));
        std::fs::remove_file(&path).map_err(|e| Error::io(&path, e))?;
        Ok(Reference::new(ctx, view, rendered, observed))
    }

    fn new(
        ctx: &Refine,
        view: &View,
        render: Vec<Option<Vec3>>,
        observed: Vec<Option<Vec3>>,
    ) -> Reference {
        let (w, h) = (view.camera.width() as usize, view.camera.height() as usize);
        let shapes = &ctx.p.scene.shapes;
        let known = |s: u32| shapes.get(s as usize).is_some_and(|s| s.known().is_some());
        let usable = (render.iter().zip(&observed))
            .map(|(r, o)| r.is_some() && o.is_none_or(|o| o.x >= 0.999))
            .collect();
        let foreign: Vec<bool> = view.pixels.iter().map(|px| known(px.shape)).collect();
        Reference {
            width: w,
            height: h,
            render: render
                .into_iter()
                .map(|r| r.unwrap_or(Vec3::ZERO))
                .collect(),
            usable,
            foreign: summed_area(&foreign, w, h),
        }
    }

    /// The usable pixels with no foreign pixel within `margin` (a square).
    fn mask(&self, margin: usize) -> Vec<bool> {
        let (w, h) = (self.width, self.height);
        let at = |x: usize, y: usize| self.foreign[y * (w + 1) + x];
        (0..w * h)
            .into_par_iter()
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let (x0, y0) = (x.saturating_sub(margin), y.saturating_sub(margin));
                let (x1, y1) = ((x + margin + 1).min(w), (y + margin + 1).min(h));
                self.usable[i] && at(x1, y1) + at(x0, y0) == at(x0, y1) + at(x1, y0)
            })
            .collect()
    }
}

/// The `(w + 1) x (h + 1)` summed-area table of `v`.
fn summed_area(v: &[bool], w: usize, h: usize) -> Vec<u32> {
    let mut s = vec![0u32; (w + 1) * (h + 1)];
    for y in 0..h {
        let mut row = 0;
        for x in 0..w {
            row += v[y * w + x] as u32;
            s[(y + 1) * (w + 1) + x + 1] = s[y * (w + 1) + x + 1] + row;
        }
    }
    s
}

/// Per shape, whether each texel of `loo` is observed (1) or not (0), as a texture.
fn observed_maps(
    ctx: &Refine,
    loo: &TileStore<TexelState>,
    scratch: &crate::atlas::texture::Scratch,
) -> Result<Vec<Option<SlotTexture<Vec3>>>> {
    let p = ctx.p;
    let mut maps: Vec<Option<SlotTexture<Vec3>>> =
        (0..p.scene.shapes.len()).map(|_| None).collect();
    let total: u64 = (p.layout.slots.iter())
        .map(|s| s.width as u64 * s.height as u64)
        .sum();
    for (slot, st) in p.layout.slots.iter().enumerate() {
        let keep = scratch.share(st.width as u64 * st.height as u64, total);
        let seen = SlotTexture::read(&p.layout, slot, loo, ctx.geom, &keep, "seen", |s, _| {
            Vec3::splat((s.weight > 0.0) as u8 as f32)
        })?;
        maps[st.shape] = Some(seen);
    }
    Ok(maps)
}

/// `maps` rendered into `view` as the refinement renders (its film's filter applied); only
/// pixels whose center ray meets a reconstructed shape.
fn render(
    ctx: &Refine,
    view: &View,
    maps: &[Option<SlotTexture<Vec3>>],
    film: Film,
) -> Result<Vec<Option<Vec3>>> {
    let textures = ctx.textures(maps);
    let (w, h) = (view.camera.width(), view.camera.height());
    let owns = ctx.shard.owns;
    let plan = |x: u32, y: u32| match owns((y / ROW_BAND) as usize) {
        true => view.flat(ctx.hits, x, y).map_or(Plan::Trace, Plan::Flat),
        false => Plan::Skip,
    };
    let k = REFINE_SUPERSAMPLE;
    let mut r = render_view_with(&ctx.p.accel, &view.camera, &textures, k, film, &plan);
    (ctx.shard.sync_pixels)(&mut r, (ROW_BAND * w) as usize)?;
    Ok(apply_pixel_filter(&r, w, h, view.camera.filter()))
}

/// Where the ray through pixel `(x, y)`'s center meets the plane its pixel sees.
fn surface_point(view: &View, x: u32, y: u32) -> Option<Vec3> {
    let px = &view.pixels[(y * view.camera.width() + x) as usize];
    px.seen_shape()?;
    let (o, d) = view.camera.ray(x as f32 + 0.5, y as f32 + 0.5);
    let den = px.normal.dot(d);
    let t = (px.plane - px.normal.dot(o)) / den;
    (den.abs() > 1e-6 && t > 0.0 && t.is_finite()).then(|| o + d * t)
}

/// The surface points of the view's clean pixels.
fn clean_points(view: &View) -> Vec<Vec3> {
    let (w, h) = (view.camera.width(), view.camera.height());
    (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .filter(|&(x, y)| view.pixels[(y * w + x) as usize].clean)
        .filter_map(|(x, y)| surface_point(view, x, y))
        .collect()
}

/// The median distance from the camera of the view's clean pixels' surface points.
fn viewing_distance(view: &View) -> Option<f64> {
    let c = view.camera.position();
    let mut d: Vec<f32> = clean_points(view)
        .iter()
        .map(|p| (*p - c).length())
        .collect();
    if d.is_empty() {
        return None;
    }
    let mid = d.len() / 2;
    let (_, m, _) = d.select_nth_unstable_by(mid, f32::total_cmp);
    Some(*m as f64)
}

/// The mean distance, pixels, between where the view's clean pixels' surface points project
/// through its camera and through `camera`.
fn mean_pixel_shift(view: &View, camera: &Camera) -> f64 {
    let (mut sum, mut n) = (0.0f64, 0u64);
    for p in clean_points(view) {
        if let (Some(a), Some(b)) = (view.camera.project(p), camera.project(p)) {
            sum += (a - b).length() as f64;
            n += 1;
        }
    }
    if n == 0 {
        0.0
    } else {
        sum / n as f64
    }
}

/// The photo and the reference blurred at one level, and the pixels aligned on.
struct Level {
    width: usize,
    height: usize,
    /// The blurred photo, its derivatives along x and y, and the share of each pixel's
    /// kernel that fell on usable pixels.
    photo: Vec<Vec3>,
    dx: Vec<Vec3>,
    dy: Vec<Vec3>,
    weight: Vec<f32>,
    samples: Vec<Sample>,
    /// The samples' [`Cross`] terms, `cross[s.cross.0..s.cross.1]` for sample `s`.
    cross: Vec<Cross>,
    /// The mean over the samples of `J^T J`, `J` how the sample's pixel moves with the six
    /// pose parameters: a move `d` shifts the pixels by `sqrt(d^T M d)` px (RMS).
    motion: [[f64; 6]; 6],
    /// The geometry's edges in this view (at the finest level only: at coarser blurs the
    /// strongest edge within reach is too often another one), the photo's edges at this blur
    /// (also at the finest level only), how far from an edge's projection its photo edge is
    /// looked for (px), and each edge's weight ([`EDGE_SHARE`] spread over the edges).
    edges: Vec<Edge>,
    edge_image: Option<EdgeImage>,
    reach: f32,
    edge_weight: f64,
}

/// A pixel aligned on: its index, its surface point, the blurred reference there, and the
/// range of its [`Cross`] terms in [`Level::cross`].
#[derive(Debug, Clone, Copy)]
struct Sample {
    pixel: u32,
    point: Vec3,
    reference: Vec3,
    cross: (u32, u32),
}

/// How the reference at a sample moves with another view's pose: per RGB channel, the
/// derivative by the first six [`PARAMS`] of that view (its share of the sample's texels
/// times its photo's gradient times how its pixel moves).
#[derive(Debug, Clone, Copy)]
struct Cross {
    view: u32,
    l: [[f32; 6]; 3],
}

impl Cross {
    /// The reference's change when the view moved by `d`.
    fn apply(&self, d: &[f64; 6]) -> Vec3 {
        let ch = |c: usize| (0..6).map(|p| self.l[c][p] as f64 * d[p]).sum::<f64>() as f32;
        Vec3::new(ch(0), ch(1), ch(2))
    }
}

impl Level {
    /// The level of blur `sigma` of `view`'s photo and `reference`; pixels every
    /// `sigma / 2` (at least 1) along each axis are aligned on.
    fn new(view: &View, reference: &Reference, edges: &[Edge], sigma: f32) -> Level {
        let (w, h) = (reference.width, reference.height);
        let finest = sigma <= LEVELS[LEVELS.len() - 1];
        let edge_image =
            finest.then(|| EdgeImage::new(view.image, sigma, |v, m| blur(v, m, w, h, sigma).0));
        let mask = reference.mask((3.0 * sigma + GUARD_PX).ceil() as usize);
        let valid: Vec<bool> = (mask.iter().zip(&view.image.valid))
            .map(|(m, v)| *m && *v)
            .collect();
        let (photo, weight) = blur(&view.image.pixels, &valid, w, h, sigma);
        let (refb, rweight) = blur(&reference.render, &mask, w, h, sigma);
        let (dx, dy) = gradients(&photo, w, h);
        let stride = ((sigma / 2.0) as usize).max(1);
        let samples: Vec<Sample> = (0..h)
            .step_by(stride)
            .flat_map(|y| (0..w).step_by(stride).map(move |x| (x, y)))
            .filter(|&(x, y)| mask[y * w + x] && rweight[y * w + x] >= MIN_WEIGHT)
            .filter_map(|(x, y)| {
                Some(Sample {
                    pixel: (y * w + x) as u32,
                    point: surface_point(view, x as u32, y as u32)?,
                    reference: refb[y * w + x],
                    cross: (0, 0),
                })
            })
            .collect();
        let samples_len = samples.len();
        Level {
            width: w,
            height: h,
            photo,
            dx,
            dy,
            weight,
            motion: motion(view, &samples),
            samples,
            cross: Vec::new(),
            edge_weight: EDGE_SHARE * 3.0 * samples_len as f64 / edges.len().max(1) as f64,
            edges: match finest {
                true => edges.to_vec(),
                false => Vec::new(),
            },
            edge_image,
            reach: 3.0 * sigma + 3.0,
        }
    }

    /// The blurred photo and its derivatives at continuous pixel coordinates `q`
    /// (bilinear), where the four pixels around `q` are on the image and mostly usable.
    fn sample(&self, q: Vec2) -> Option<(Vec3, Vec3, Vec3)> {
        let Tap { base, tx, ty } = Tap::inside(q, self.width, self.height)?;
        let i = base as usize;
        let idx = [i, i + 1, i + self.width, i + self.width + 1];
        let wts = [
            (1.0 - tx) * (1.0 - ty),
            tx * (1.0 - ty),
            (1.0 - tx) * ty,
            tx * ty,
        ];
        let mix = |v: &[Vec3]| idx.iter().zip(&wts).map(|(&j, &k)| v[j] * k).sum::<Vec3>();
        let weight: f32 = idx
            .iter()
            .zip(&wts)
            .map(|(&j, &k)| self.weight[j] * k)
            .sum();
        (weight >= MIN_WEIGHT).then(|| (mix(&self.photo), mix(&self.dx), mix(&self.dy)))
    }
}

/// [`Level::motion`] of `samples` (up to 512 of them) seen through `view`'s camera.
fn motion(view: &View, samples: &[Sample]) -> [[f64; 6]; 6] {
    let distance = viewing_distance(view).unwrap_or(1.0);
    let step = (samples.len() / 512).max(1);
    let mut m = [[0.0f64; 6]; 6];
    let mut n = 0u32;
    for s in samples.iter().step_by(step) {
        let Some(dq) = pose_jacobian(&view.camera, s.point, distance) else {
            continue;
        };
        for (a, row) in m.iter_mut().enumerate() {
            for (b, x) in row.iter_mut().enumerate() {
                *x += dq[a].dot(dq[b]) as f64;
            }
        }
        n += 1;
    }
    m.map(|row| row.map(|x| x / n.max(1) as f64))
}

/// Box radius whose threefold pass has standard deviation `sigma` (nearest integer):
/// three passes of radius `r` have variance `r (r + 1)`.
fn box_radius(sigma: f32) -> usize {
    (((0.25 + sigma * sigma).sqrt() - 0.5).round() as usize).max(1)
}

/// `values` blurred over the pixels of `mask` (normalised convolution by three box passes
/// per axis, about a Gaussian of `sigma`), and the share of each pixel's kernel in `mask`.
pub(super) fn blur(
    values: &[Vec3],
    mask: &[bool],
    w: usize,
    h: usize,
    sigma: f32,
) -> (Vec<Vec3>, Vec<f32>) {
    let r = box_radius(sigma);
    let mut a: Vec<[f32; 4]> = (values.iter().zip(mask))
        .map(|(v, &m)| match m {
            true => [v.x, v.y, v.z, 1.0],
            false => [0.0; 4],
        })
        .collect();
    for _ in 0..3 {
        a = box_rows(&a, w, r);
    }
    for _ in 0..3 {
        a = box_cols(&a, w, h, r);
    }
    let full = ((2 * r + 1) as f32).powi(6);
    a.par_iter()
        .map(|s| match s[3] > 0.0 {
            true => (Vec3::new(s[0], s[1], s[2]) / s[3], s[3] / full),
            false => (Vec3::ZERO, 0.0),
        })
        .unzip()
}

fn add4(a: [f32; 4], b: &[f32; 4]) -> [f32; 4] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3]]
}

/// Sums over `2 r + 1` pixels along each row (zero beyond the image).
fn box_rows(a: &[[f32; 4]], w: usize, r: usize) -> Vec<[f32; 4]> {
    a.par_chunks(w)
        .flat_map_iter(|row| {
            (0..w).map(move |x| {
                let (lo, hi) = (x.saturating_sub(r), (x + r + 1).min(w));
                row[lo..hi].iter().fold([0.0; 4], add4)
            })
        })
        .collect()
}

/// Sums over `2 r + 1` pixels along each column (zero beyond the image).
fn box_cols(a: &[[f32; 4]], w: usize, h: usize, r: usize) -> Vec<[f32; 4]> {
    (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            let (lo, hi) = (y.saturating_sub(r), (y + r + 1).min(h));
            (0..w).map(move |x| (lo..hi).map(|yy| &a[yy * w + x]).fold([0.0; 4], add4))
        })
        .collect()
}

/// Central differences along x and y (one-sided at the image's edges).
fn gradients(img: &[Vec3], w: usize, h: usize) -> (Vec<Vec3>, Vec<Vec3>) {
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let (x0, x1) = (x.saturating_sub(1), (x + 1).min(w - 1));
            let (y0, y1) = (y.saturating_sub(1), (y + 1).min(h - 1));
            let gx = (img[y * w + x1] - img[y * w + x0]) / (x1 - x0).max(1) as f32;
            let gy = (img[y1 * w + x] - img[y0 * w + x]) / (y1 - y0).max(1) as f32;
            (gx, gy)
        })
        .unzip()
}

/// Every view's [`Level`] of blur `sigma`, with the [`Cross`] terms of the samples of the
/// views still being aligned (`start`: the poses where the round started, those of `views`).
fn levels(
    views: &[View],
    refs: &[Reference],
    edges: &[Vec<Edge>],
    start: &[Pose],
    sigma: f32,
) -> Vec<Level> {
    let mut levels: Vec<Level> = (views.iter().zip(refs).zip(edges))
        .map(|((v, r), e)| Level::new(v, r, e, sigma))
        .collect();
    let terms: Vec<Vec<Vec<Cross>>> = (0..views.len())
        .map(|v| match start[v].active() {
            true => (levels[v].samples.par_iter())
                .map(|s| cross_terms(views, &levels, start, v, s))
                .collect(),
            false => Vec::new(),
        })
        .collect();
    for (level, terms) in levels.iter_mut().zip(terms) {
        for (s, t) in level.samples.iter_mut().zip(terms) {
            s.cross = (
                level.cross.len() as u32,
                (level.cross.len() + t.len()) as u32,
            );
            level.cross.extend(t);
        }
    }
    levels
}

/// The [`Cross`] terms of sample `s` of view `v`: every other view whose clean pixels see
/// its surface point, with its share of the point's weight (pixels' worth, as the
/// projection weighs: the inverse of its pixel's footprint there).
fn cross_terms(
    views: &[View],
    levels: &[Level],
    start: &[Pose],
    v: usize,
    s: &Sample,
) -> Vec<Cross> {
    let px = &views[v].pixels[s.pixel as usize];
    let mut seen = Vec::new();
    let mut total = 0.0f32;
    for (j, view) in views.iter().enumerate() {
        let Some(q) = view.camera.project(s.point).filter(|_| j != v) else {
            continue;
        };
        if view.sample(q, s.point, px.shape, px.normal).is_none() {
            continue;
        }
        let w = 1.0 / view.camera.pixel_footprint_area(s.point, px.normal);
        if !(w.is_finite() && w > 0.0) {
            continue;
        }
        total += w;
        let dq = pose_jacobian(&view.camera, s.point, start[j].distance);
        if let (Some((_, dx, dy)), Some(dq)) = (levels[j].sample(q), dq) {
            seen.push((j, w, dx.to_array(), dy.to_array(), dq));
        }
    }
    (seen.into_iter())
        .map(|(j, w, dx, dy, dq)| Cross {
            view: j as u32,
            l: [0, 1, 2].map(|c| dq.map(|d| w / total * (dx[c] * d.x + dy[c] * d.y))),
        })
        .collect()
}

/// What a joint step reads: every view's level and where each view started the round (its
/// reference was rendered from the others there).
struct Joint<'a> {
    levels: &'a [Level],
    start: &'a [Pose],
}

/// A 7 x 7 block of the joint normal matrix.
type Block = [[f64; PARAMS]; PARAMS];

/// The joint normal equations and the cost, per view the samples used and their residuals.
#[derive(Debug, Clone, Default)]
struct Normal {
    /// Blocks `(view a, view b)` of the normal matrix, and per view its part of the gradient.
    blocks: BTreeMap<(usize, usize), Block>,
    g: Vec<[f64; PARAMS]>,
    /// The Huber cost of the residuals in robust standard deviations, samples that left the
    /// usable pixels at `huber(3 HUBER_K)` each.
    cost: f64,
    n: Vec<u64>,
    /// Per view, sums of `|Y(r)|` and of the reference's luminance.
    abs: Vec<f64>,
    lum: Vec<f64>,
}

impl Normal {
    fn new(views: usize) -> Normal {
        Normal {
            g: vec![[0.0; PARAMS]; views],
            n: vec![0; views],
            abs: vec![0.0; views],
            lum: vec![0.0; views],
            ..Default::default()
        }
    }

    fn add(&mut self, o: &Normal) {
        for (k, b) in &o.blocks {
            let a = self.blocks.entry(*k).or_insert([[0.0; PARAMS]; PARAMS]);
            for (ra, rb) in a.iter_mut().zip(b) {
                ra.iter_mut().zip(rb).for_each(|(x, y)| *x += y);
            }
        }
        for v in 0..self.g.len() {
            self.g[v].iter_mut().zip(&o.g[v]).for_each(|(x, y)| *x += y);
            (self.n[v], self.abs[v], self.lum[v]) = (
                self.n[v] + o.n[v],
                self.abs[v] + o.abs[v],
                self.lum[v] + o.lum[v],
            );
        }
        self.cost += o.cost;
    }

    /// View `v`'s mean relative residual `sum |Y(r)| / sum Y(g R)`.
    fn relative(&self, v: usize) -> f64 {
        self.abs[v] / self.lum[v].max(f64::MIN_POSITIVE)
    }

    /// `w j_a j_b^T` into the blocks and `w j_a r` into the gradient, for every pair of the
    /// residual's Jacobian `row` (per view, its part).
    fn add_row(&mut self, row: &[(usize, [f64; PARAMS])], w: f64, r: f64) {
        for (a, ja) in row {
            self.g[*a]
                .iter_mut()
                .zip(ja)
                .for_each(|(g, j)| *g += w * j * r);
            for (b, jb) in row {
                let blk = self
                    .blocks
                    .entry((*a, *b))
                    .or_insert([[0.0; PARAMS]; PARAMS]);
                for (ra, x) in blk.iter_mut().zip(ja) {
                    ra.iter_mut().zip(jb).for_each(|(h, y)| *h += w * x * y);
                }
            }
        }
    }
}

fn huber(r: f64, k: f64) -> f64 {
    match r.abs() <= k {
        true => 0.5 * r * r,
        false => k * (r.abs() - 0.5 * k),
    }
}

/// A sample's residual at `poses` (the reference moved to first order with the other views'
/// moves `deltas` since the round's start), the reference there and the photo's derivatives.
fn look(
    level: &Level,
    pose: &Pose,
    s: &Sample,
    deltas: &[[f64; 6]],
) -> Option<(Vec3, Vec3, Vec3, Vec3)> {
    let q = pose.camera.project(s.point)?;
    let (value, dx, dy) = level.sample(q)?;
    let cross = &level.cross[s.cross.0 as usize..s.cross.1 as usize];
    let reference = s.reference
        + cross
            .iter()
            .map(|c| c.apply(&deltas[c.view as usize]))
            .sum::<Vec3>();
    Some((value - reference * pose.gain as f32, reference, dx, dy))
}

/// Per view being aligned, the robust standard deviation of its residuals at `poses`
/// (1.4826 x the median absolute residual over samples and channels); 1 for the others.
fn scales(joint: &Joint, poses: &[Pose]) -> Vec<[f64; 2]> {
    let deltas = deltas(joint, poses);
    (joint.levels.iter().zip(poses))
        .map(|(level, pose)| {
            if !pose.active() {
                return [1.0; 2];
            }
            let r: Vec<f32> = (level.samples.par_iter())
                .flat_map_iter(|s| look(level, pose, s, &deltas).map(|l| l.0.abs().to_array()))
                .flatten_iter()
                .collect();
            [
                robust_sd(r, 1e-12),
                robust_sd(edge_offsets(level, pose), MIN_EDGE_SCALE),
            ]
        })
        .collect()
}

/// 1.4826 x the median of `abs` (1 if empty), at least `floor`.
fn robust_sd(abs: Vec<f32>, floor: f64) -> f64 {
    median(abs).map_or(1.0, |m| (1.4826 * m as f64).max(floor))
}

/// The median (the upper one of an even count) of `v`, `None` if empty.
fn median(mut v: Vec<f32>) -> Option<f32> {
    let mid = v.len() / 2;
    (!v.is_empty()).then(|| *v.select_nth_unstable_by(mid, f32::total_cmp).1)
}

/// The smallest robust spread of the edge offsets, px: the edges' own precision.
const MIN_EDGE_SCALE: f64 = 0.05;

/// The edges' share of a view's cost at the finest level: all its edge offsets together
/// (each in its robust spread) weigh this many times all its photometric residuals (each
/// channel of each sample in its robust spread). Edges outweigh the photos because the photos'
/// pull on the cameras' common motion is their re-render's bias, not information: on the
/// textured Cornell box with every pose off, a share of 3 left 0.37-0.56 px RMS, 10 left
/// 0.17-0.38 px, 30 left 0.17-0.32 px (held-out albedo 11.2%, 7.2%, 6.1%), 100 no better.
const EDGE_SHARE: f64 = 30.0;

/// The median absolute offset (px) of the edges the photo shows at `pose`, and how many.
fn edge_median(level: &Level, pose: &Pose) -> (f64, u64) {
    let d = edge_offsets(level, pose);
    let n = d.len() as u64;
    (median(d).map_or(0.0, f64::from), n)
}

/// The absolute offsets (px) of the edges of `level` the photo shows at `pose`, in edge order.
fn edge_offsets(level: &Level, pose: &Pose) -> Vec<f32> {
    (level.edges.par_iter())
        .filter_map(|e| edge_offset(level, pose, e).map(|m| m.0.abs()))
        .collect()
}

/// Where edge `e`'s photo edge is from its projection through `pose` (px, along the
/// image normal), and that normal.
fn edge_offset(level: &Level, pose: &Pose, e: &Edge) -> Option<(f32, Vec2)> {
    let (p, n) = edges::in_image(&pose.camera, e)?;
    let image = level.edge_image.as_ref()?;
    Some((image.offset(p, n, level.reach)?, n))
}

/// Every view's move since the round's start ([`Pose::delta_from`]).
fn deltas(joint: &Joint, poses: &[Pose]) -> Vec<[f64; 6]> {
    (poses.iter().zip(joint.start))
        .map(|(p, s)| p.delta_from(s))
        .collect()
}

/// The cost of every view being aligned at `poses` (residuals in units of `scale`, per view)
/// and with `jacobian` the joint normal equations; summed in chunks of [`CHUNK`] samples added
/// in order.
fn evaluate(joint: &Joint, poses: &[Pose], scale: &[[f64; 2]], jacobian: bool) -> Normal {
    let n = poses.len();
    let deltas = deltas(joint, poses);
    let mut total = Normal::new(n);
    for (v, level) in joint.levels.iter().enumerate() {
        if !poses[v].active() {
            continue;
        }
        let parts: Vec<Normal> = (level.samples.par_chunks(CHUNK))
            .map(|chunk| {
                let mut s = Normal::new(n);
                for smp in chunk {
                    add_sample(
                        &mut s,
                        (level, v),
                        poses,
                        (&deltas, scale[v][0]),
                        smp,
                        jacobian,
                    );
                }
                s
            })
            .collect();
        parts.iter().for_each(|p| total.add(p));
        let parts: Vec<Normal> = (level.edges.par_chunks(CHUNK))
            .map(|chunk| {
                let mut s = Normal::new(n);
                for e in chunk {
                    add_edge(&mut s, (level, v), &poses[v], scale[v][1], e, jacobian);
                }
                s
            })
            .collect();
        parts.iter().for_each(|p| total.add(p));
        prior(&mut total, level, &poses[v], v, jacobian);
        let lost = level.samples.len() as u64 - total.n[v];
        total.cost += lost as f64 * huber(3.0 * HUBER_K, HUBER_K);
    }
    total
}

/// The weight of the prior on a view's correction: a correction that moves the pixels by
/// 1 px (RMS) costs each sample `PRIOR / 2`, as a residual of `sqrt(PRIOR)` robust standard
/// deviations would. It settles what the photos leave free (moving every view together along
/// a plane changes no residual) at the smallest correction, and biases the rest by about
/// `PRIOR` times the correction over the residuals' curvature (thousandths of a pixel).
const PRIOR: f64 = 0.01;

/// The weight of the bound prior on a view's correction: a correction at the bound
/// ([`MAX_ROTATION_DEG`] about one axis, or [`MAX_TRANSLATION`] along one) costs each sample
/// `BOUND_PRIOR / 2`. [`PRIOR`] weighs a correction by the pixels it moves, so it leaves
/// moves that shift the pixels little nearly free: in an open scene (small objects far off, a
/// ground plane seen at a grazing angle) the cameras slid along such moves past the
/// translation bound (2.0-2.1% of the distance; poses off by 0.5%) and were refused. This
/// prior holds them near the scene's pose, as structure from motion leaves cameras within a
/// fraction of the bound. On the open scene with every pose off by 0.3 degrees and 0.5% (held-out
/// albedo, no prior 11.1%, all three cameras refused): 1 gave 5.8%, 3 5.8%, 10 4.5%, 30 6.5-7.1%,
/// 100 7.9-8.5%.
const BOUND_PRIOR: f64 = 10.0;

/// The bound on parameter `a` of a correction: the bound prior's unit (rotation vector in
/// radians; translation in viewing distances).
fn bound(a: usize) -> f64 {
    match a < 3 {
        true => MAX_ROTATION_DEG.to_radians(),
        false => MAX_TRANSLATION,
    }
}

/// The priors' part of [`evaluate`] for view `v` at `pose`: `PRIOR n / 2 d^T M d +
/// BOUND_PRIOR n / 2 sum_a (d_a / bound_a)^2` for `n` samples, `d` the correction from the
/// scene's pose, `M` the level's [`Level::motion`].
fn prior(total: &mut Normal, level: &Level, pose: &Pose, v: usize, jacobian: bool) {
    let w = pose.rot.to_scaled_axis();
    let t = pose.shift / pose.distance;
    let d = [w.x, w.y, w.z, t.x, t.y, t.z];
    let k = PRIOR * level.samples.len() as f64;
    let md: Vec<f64> = (level.motion.iter())
        .map(|row| row.iter().zip(&d).map(|(m, x)| m * x).sum())
        .collect();
    let kb = BOUND_PRIOR * level.samples.len() as f64;
    total.cost += 0.5 * k * md.iter().zip(&d).map(|(a, b)| a * b).sum::<f64>();
    total.cost += (0..6)
        .map(|a| 0.5 * kb * (d[a] / bound(a)).powi(2))
        .sum::<f64>();
    if !jacobian {
        return;
    }
    let blk = total
        .blocks
        .entry((v, v))
        .or_insert([[0.0; PARAMS]; PARAMS]);
    for (a, (row, m)) in blk.iter_mut().zip(&level.motion).enumerate() {
        total.g[v][a] += k * md[a] + kb * d[a] / bound(a).powi(2);
        row.iter_mut().zip(m).for_each(|(h, x)| *h += k * x);
        row[a] += kb / bound(a).powi(2);
    }
}

/// One edge's part of [`evaluate`]: its offset (in units of `scale`, weighed by the level's
/// `edge_weight`) and how the pose moves its projection across the edge; an edge the photo
/// shows no edge near costs as a lost sample.
fn add_edge(
    s: &mut Normal,
    (level, v): (&Level, usize),
    pose: &Pose,
    scale: f64,
    e: &Edge,
    jacobian: bool,
) {
    let Some((d, n)) = edge_offset(level, pose, e) else {
        s.cost += level.edge_weight * huber(3.0 * HUBER_K, HUBER_K);
        return;
    };
    let r = d as f64 / scale;
    s.cost += level.edge_weight * huber(r, HUBER_K);
    let dq = pose_jacobian(&pose.camera, e.point, pose.distance);
    let (Some(dq), true) = (dq, jacobian) else {
        return;
    };
    let mut j = [0.0; PARAMS];
    for (jp, q) in j.iter_mut().zip(&dq) {
        *jp = -(n.dot(*q) as f64) / scale;
    }
    let w = match r.abs() <= HUBER_K {
        true => 1.0,
        false => HUBER_K / r.abs(),
    };
    s.add_row(&[(v, j)], level.edge_weight * w, r);
}

/// One sample's part of [`evaluate`]: per channel, its Huber-weighted Gauss-Newton terms over
/// its own view's seven parameters and the six of every other view being aligned that sees it.
fn add_sample(
    s: &mut Normal,
    (level, v): (&Level, usize),
    poses: &[Pose],
    (deltas, scale): (&[[f64; 6]], f64),
    smp: &Sample,
    jacobian: bool,
) {
    let pose = &poses[v];
    let Some((r, reference, dx, dy)) = look(level, pose, smp, deltas) else {
        return;
    };
    s.n[v] += 1;
    s.abs[v] += luminance(r).abs() as f64;
    s.lum[v] += luminance(reference * pose.gain as f32) as f64;
    let r = r.to_array().map(|x| x as f64 / scale);
    s.cost += r.iter().map(|&x| huber(x, HUBER_K)).sum::<f64>();
    let dq = pose_jacobian(&pose.camera, smp.point, pose.distance);
    let (Some(dq), true) = (dq, jacobian) else {
        return;
    };
    let cross = &level.cross[smp.cross.0 as usize..smp.cross.1 as usize];
    let (gx, gy, re) = (dx.to_array(), dy.to_array(), reference.to_array());
    let mut row = Vec::with_capacity(1 + cross.len());
    for c in 0..3 {
        row.clear();
        let mut own = [0.0; PARAMS];
        for (p, d) in dq.iter().enumerate() {
            own[p] = (gx[c] * d.x + gy[c] * d.y) as f64 / scale;
        }
        own[6] = -re[c] as f64 / scale;
        row.push((v, own));
        for x in cross.iter().filter(|x| poses[x.view as usize].active()) {
            let mut j = [0.0; PARAMS];
            for (jp, l) in j.iter_mut().zip(&x.l[c]) {
                *jp = -pose.gain * *l as f64 / scale;
            }
            row.push((x.view as usize, j));
        }
        let w = if r[c].abs() <= HUBER_K {
            1.0
        } else {
            HUBER_K / r[c].abs()
        };
        s.add_row(&row, w, r[c]);
    }
}

/// Levenberg-Marquardt on every view being aligned at once, until a step moves every view's
/// pixels less than `tol`: whether it settled. A view whose correction leaves the bounds, or
/// that keeps too few usable pixels, is refused and goes back to the scene's pose.
fn iterate(joint: &Joint, poses: &mut [Pose], tol: f64) -> bool {
    let mut lambda = 1e-3;
    for _ in 0..MAX_ITERATIONS {
        let scale = scales(joint, poses);
        let s = evaluate(joint, poses, &scale, true);
        let few: Vec<usize> = (0..poses.len())
            .filter(|&v| poses[v].active() && s.n[v] < MIN_SAMPLES)
            .collect();
        few.iter().for_each(|&v| poses[v].refuse(Status::TooFew));
        let active: Vec<usize> = (0..poses.len()).filter(|&v| poses[v].active()).collect();
        if active.is_empty() {
            return false;
        }
        if !few.is_empty() {
            continue;
        }
        active.iter().for_each(|&v| poses[v].iterations += 1);
        let Some(next) = lm_step(joint, poses, (&s, &scale), &active, &mut lambda) else {
            return true;
        };
        let moved = (active.iter())
            .map(|&v| mean_shift(&joint.levels[v].samples, &poses[v].camera, &next[v].camera))
            .fold(0.0, f64::max);
        poses.clone_from_slice(&next);
        for &v in &active {
            if poses[v].beyond_bound() {
                poses[v].refuse(Status::Beyond);
            }
        }
        if moved < tol {
            return true;
        }
    }
    false
}

/// A damped Gauss-Newton step of every view in `active` that lowers the cost of `s` (at the
/// residual scales `scale`), `None` if none does (the poses are at a minimum).
fn lm_step(
    joint: &Joint,
    poses: &[Pose],
    (s, scale): (&Normal, &[[f64; 2]]),
    active: &[usize],
    lambda: &mut f64,
) -> Option<Vec<Pose>> {
    let m = PARAMS * active.len();
    let mut h = vec![0.0f64; m * m];
    for (bi, &a) in active.iter().enumerate() {
        for (bj, &b) in active.iter().enumerate() {
            if let Some(blk) = s.blocks.get(&(a, b)) {
                for (i, row) in blk.iter().enumerate() {
                    let at = (bi * PARAMS + i) * m + bj * PARAMS;
                    h[at..at + PARAMS].copy_from_slice(row);
                }
            }
        }
    }
    let g: Vec<f64> = active.iter().flat_map(|&a| s.g[a].map(|x| -x)).collect();
    let trace: f64 = (0..m).map(|i| h[i * m + i]).sum();
    for _ in 0..8 {
        let mut a = h.clone();
        for i in 0..m {
            a[i * m + i] += *lambda * h[i * m + i] + 1e-12 * trace / m as f64;
        }
        if let Some(d) = solve(a, g.clone(), m) {
            let mut next = poses.to_vec();
            for (bi, &v) in active.iter().enumerate() {
                next[v] = poses[v].moved(&d[bi * PARAMS..(bi + 1) * PARAMS]);
            }
            if evaluate(joint, &next, scale, false).cost < s.cost {
                *lambda = (*lambda * 0.25).max(1e-7);
                return Some(next);
            }
        }
        *lambda *= 8.0;
    }
    None
}

/// `a x = b` for an `m x m` row-major `a`, by Gaussian elimination with partial pivoting
/// (`None` if singular).
fn solve(mut a: Vec<f64>, mut b: Vec<f64>, m: usize) -> Option<Vec<f64>> {
    for c in 0..m {
        let p = (c..m).max_by(|&i, &j| a[i * m + c].abs().total_cmp(&a[j * m + c].abs()))?;
        if a[p * m + c].abs() < 1e-300 {
            return None;
        }
        if p != c {
            for k in 0..m {
                a.swap(c * m + k, p * m + k);
            }
            b.swap(c, p);
        }
        for r in c + 1..m {
            let f = a[r * m + c] / a[c * m + c];
            for k in c..m {
                a[r * m + k] -= f * a[c * m + k];
            }
            b[r] -= f * b[c];
        }
    }
    let mut x = vec![0.0; m];
    for r in (0..m).rev() {
        let s: f64 = (r + 1..m).map(|k| a[r * m + k] * x[k]).sum();
        x[r] = (b[r] - s) / a[r * m + r];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// The last round's verdict: per view still aligned, its residual at the scene's pose (the
/// others where they are) and at the refined one; a pose that does not lower it is refused.
/// Then every view's edge offset at the pose it keeps.
fn judge(joint: &Joint, poses: &mut [Pose], settled: bool) {
    let ones = vec![[1.0; 2]; poses.len()];
    let after = evaluate(joint, poses, &ones, false);
    for v in 0..poses.len() {
        if !poses[v].active() {
            continue;
        }
        let mut given = poses.to_vec();
        given[v].camera = given[v].nominal.clone();
        (given[v].rot, given[v].shift) = (DQuat::IDENTITY, DVec3::ZERO);
        let before = evaluate(joint, &given, &ones, false).relative(v);
        poses[v].residual.1 = after.relative(v);
        poses[v].converged = settled;
        if poses[v].residual.1 >= before {
            poses[v].refuse(Status::NoImprovement);
        }
    }
    // How far each camera the run uses sits from the mesh's edges.
    for (pose, level) in poses.iter_mut().zip(joint.levels) {
        pose.edge_px[1] = edge_median(level, pose);
    }
}

/// The mean distance, pixels, between where (up to 512 of) the samples project through `a`
/// and through `b`.
fn mean_shift(samples: &[Sample], a: &Camera, b: &Camera) -> f64 {
    let step = (samples.len() / 512).max(1);
    let (mut sum, mut n) = (0.0f64, 0u64);
    for s in samples.iter().step_by(step) {
        if let (Some(p), Some(q)) = (a.project(s.point), b.project(s.point)) {
            sum += (p - q).length() as f64;
            n += 1;
        }
    }
    if n == 0 {
        f64::INFINITY
    } else {
        sum / n as f64
    }
}

/// How the pixel of world point `p` moves with each pose parameter (rotation about the
/// camera's centre, radians; translation, in `distance`s): the camera moved by `xi` sees `p`
/// where it sees `p - omega x (p - c) - t distance`, and `dpixel / dp` is taken by central
/// differences through the camera.
fn pose_jacobian(cam: &Camera, p: Vec3, distance: f64) -> Option<[Vec2; 6]> {
    let v = p - cam.position();
    let h = 1e-3 * v.length();
    let mut dp = [Vec2::ZERO; 3];
    for (i, e) in [Vec3::X, Vec3::Y, Vec3::Z].into_iter().enumerate() {
        dp[i] = (cam.project(p + e * h)? - cam.project(p - e * h)?) / (2.0 * h);
    }
    let along = |m: Vec3| dp[0] * m.x + dp[1] * m.y + dp[2] * m.z;
    let d = distance as f32;
    Some([
        along(v.cross(Vec3::X)),
        along(v.cross(Vec3::Y)),
        along(v.cross(Vec3::Z)),
        along(-Vec3::X * d),
        along(-Vec3::Y * d),
        along(-Vec3::Z * d),
    ])
}
