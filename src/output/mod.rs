//! Everything a finished run leaves for its users (`docs/contract.md`, "Output directory"):
//!
//! ```text
//! <out>/textures/<id>_albedo.exr|png     recovered K_d (linear float; sRGB preview at exposure 0)
//! <out>/maps/<id>_error.exr|png          per-texel relative error (PNG: viridis + legend)
//! <out>/maps/<id>_colorless.exr|png      eq. (10)
//! <out>/maps/<id>_coverage.exr|png       observation weight (0 = unobserved, filled)
//! <out>/maps/<id>_direct.exr|png         E_d
//! <out>/maps/<id>_indirect.exr|png       E_i
//! <out>/maps/<id>_luminance.exr|png      L_orig
//! <out>/maps/<id>_kd_stderr.exr|png      estimated standard error of K_d (see `confidence`)
//! <out>/maps/<id>_disagreement.exr|png   views down-weighted as disagreeing (see `project`)
//! <out>/renders/<sensor>.exr|png         each view re-rendered with the recovered albedo
//! <out>/renders/<sensor>_compare.png     original | render | relative error
//! <out>/meshes/<id>.obj (+ .mtl)         world-space meshes with atlas UVs
//! <out>/textures/<id>_albedo_uv.exr|png  a tiled shape's K_d folded into its input UVs
//! <out>/meshes/<id>_uv.obj               ... and its mesh with those UVs (see `uv_fold`)
//! <out>/scene.xml                        the recovered scene for Mitsuba 3 (folded shapes on
//!                                        their input UVs)
//! <out>/scene.glb                        the recovered scene as binary glTF 2.0 (albedo PNGs inside)
//! <out>/report_convergence.svg|png       RMS, mean and max relative error per iteration
//! <out>/report.html, report/             the page a user opens (`page`), before report.json
//! <out>/report.json                      the run's report, with the paper's table; written last
//! ```
//!
//! Map PNGs other than the error map use an automatic exposure (99th percentile at 0.9).
//! Every file is written under a temporary name and renamed into place, so a crash never
//! leaves a half-written output; `report.json` appears last, so its presence means the
//! directory is complete.

pub mod bsdf_xml;
pub mod convergence;
pub mod maps;
pub mod obj;
pub mod out_dir;
pub mod page;
pub mod plot;
pub mod renders;
pub mod scene_glb;
pub mod scene_xml;
pub mod typeface;
pub mod uv_fold;

pub use maps::write_map;
pub use out_dir::check_out_dir;

use crate::atlas::context::HitTable;
use crate::atlas::store::TileStore;
use crate::atlas::store::{TexelGeom, TexelState};
use crate::atlas::texture::{Scratch, SlotTexture};
use crate::atlas::RunContext;
use crate::base::error::{Error, Result};
use crate::base::fsio;
use crate::base::progress::Tick;
use crate::physics::render::Texture;
use crate::report::{PoseCorrection, Report};
use crate::scene::{Scene, Sensor};
use crate::stages::project::keep;
use glam::Vec3;
use rayon::prelude::*;
use std::path::Path;
use std::time::Instant;

/// The units of [`write_outputs`]' progress: every texture's texels and every view's pixels.
pub fn output_units(p: &RunContext) -> u64 {
    let texels: u64 = p
        .layout
        .slots
        .iter()
        .map(|s| s.width as u64 * s.height as u64)
        .sum();
    texels
        + p.views
            .iter()
            .map(|(si, _)| view_pixels(p, *si))
            .sum::<u64>()
}

/// The scene's sensors at the poses the run used: where `poses` (`report.json`) holds an
/// applied refinement of a sensor's pose, that pose.
pub fn posed_sensors(scene: &Scene, poses: &[PoseCorrection]) -> Vec<Sensor> {
    (scene.sensors.iter())
        .map(
            |s| match poses.iter().find(|c| c.view == s.id && c.applied) {
                Some(c) => Sensor {
                    to_world: c.matrix(),
                    ..s.clone()
                },
                None => s.clone(),
            },
        )
        .collect()
}

/// Pixels of sensor `si`'s photo.
fn view_pixels(p: &RunContext, si: usize) -> u64 {
    let s = &p.scene.sensors[si];
    s.width as u64 * s.height as u64
}

/// Write the whole output directory for a finished run (see the module doc): textures and
/// maps per reconstructed shape, meshes, `scene.xml`, the re-rendered views, the convergence
/// plot; then fill `report.table`, `report.timings.output` and `report.rays.output`, write the report page and
/// `report.json` last.
/// The caller sets the other report fields (including `timings.total`) before calling.
/// `tick` gets each shape's texels once its textures and maps are written, and each view's
/// pixels once it is re-rendered ([`output_units`] in all).
#[inline(never)] // a stage entry tools/icount.py measures
pub fn write_outputs(
    p: &RunContext,
    hits: &HitTable,
    (geom, state): (&TileStore<TexelGeom>, &TileStore<TexelState>),
    report: &mut Report,
    out: &Path,
    scratch: &Scratch,
    tick: Tick,
) -> Result<()> {
    let (t0, rays) = (Instant::now(), p.accel.rays());
    fsio::create_dir(out)?;
    // every file but report.json, made durable together before report.json says they are done
    let unsynced = fsio::Unsynced::begin(out);

    // One error scale for every map and comparison image of the run.
    let (scale, confidence) = maps::scan_state(p, state)?;
    report.confidence = confidence;

    // Each shape's re-render texture is kept through the renders: each gets its share of a
    // scratch budget, the temporaries of one shape at a time another.
    let total: u64 = p
        .layout
        .slots
        .iter()
        .map(|s| s.width as u64 * s.height as u64)
        .sum();
    let mut radiance: Vec<Option<SlotTexture<Vec3>>> =
        (0..p.scene.shapes.len()).map(|_| None).collect();
    let mut facts = page::Facts {
        command: "reconstruct".into(),
        error_max: Some(scale.max),
        ..Default::default()
    };
    // Slots side by side, each worker's temporaries its share of the scratch budget; the
    // files are the same bits whether a texture is held whole or in tiles.
    let workers = rayon::current_num_threads().max(1) as u64;
    let temp = scratch.share(1, workers);
    let written: Vec<(SlotTexture<Vec3>, page::ShapeFacts)> = (p.layout.slots.par_iter())
        .enumerate()
        .map(|(slot, st)| {
            let keep = scratch.share(st.width as u64 * st.height as u64, total);
            let done = maps::write_slot(p, geom, state, slot, out, &scale, (&temp, &keep))?;
            tick(st.width as u64 * st.height as u64);
            Ok(done)
        })
        .collect::<Result<_>>()?;
    for (st, (lr, f)) in p.layout.slots.iter().zip(written) {
        facts.shapes.push(f);
        radiance[st.shape] = Some(lr);
    }

    let meshes = out.join("meshes");
    (p.scene.shapes.par_iter().zip(&p.atlases))
        .try_for_each(|(shape, atlas)| obj::write_shape_mesh(&meshes, shape, atlas.as_ref()))?;
    let folded = match report.settings.uv_fold {
        true => {
            let budget = uv_fold::fold_budget(report.settings.memory_budget_mib);
            let (used, mut found) = uv_fold::fold_shapes(p, (geom, state), out, budget)?;
            // the shapes the sigma filter skipped: those that passed every test of the fold
            // but the agreement (the census it counts is the same now as then)
            let filtered = report.settings.denoise_radius > 0;
            for f in &mut found {
                f.atlas_filtered =
                    filtered && !matches!(f.decision.as_str(), "folded" | "disagree");
            }
            report.uv_fold = found;
            used
        }
        false => Vec::new(),
    };
    let sensors = posed_sensors(&p.scene, &report.poses);
    scene_xml::write_scene_xml(out, &p.scene, &sensors, &folded)?;
    let photometric = report.settings.photometric_scale;
    scene_glb::write_scene_glb(out, &p.scene, &sensors, &p.atlases, photometric)?;

    let textures: Vec<Option<Texture>> = radiance
        .iter()
        .enumerate()
        .map(|(si, r)| {
            let (r, a) = (r.as_ref()?, p.atlases[si].as_ref()?);
            Some(Texture {
                texels: r,
                corner_uv: &a.corner_uv,
            })
        })
        .collect();
    let renders = out.join("renders");
    let page_views = page::page_dir(out).join("views");
    // the views as the projection traced them, where it kept them
    let kept = keep::dir(&scratch.dir);
    // views side by side: each re-render is parallel over its rows, its files are not
    let views: Vec<_> = (p.views.par_iter().enumerate())
        .map(|(i, (si, path))| {
            let gain = report.capture.get(i).map_or([1.0; 3], |c| c.gain);
            let done = renders::write_view(
                p,
                hits,
                &textures,
                (&sensors[*si], path, gain),
                (&renders, &page_views, (&kept, i)),
                &scale,
            )?;
            tick(view_pixels(p, *si));
            Ok(done)
        })
        .collect::<Result<_>>()?;
    // the directory itself: each view removed its file (a failed run's go with the scratch
    // directory when the next run opens it)
    let _ = std::fs::remove_dir_all(&kept);
    if !p.views.is_empty() {
        renders::write_masks_json(&renders, &p.scene)?;
    }
    let mut table = Vec::new();
    for (rows, f) in views {
        table.extend(rows);
        facts.views.push(f);
    }
    report.table = table;
    for r in radiance.iter().flatten() {
        r.check()?;
    }

    convergence::write_convergence(out, &report.iterations)?;

    report.timings.output = t0.elapsed().as_secs_f64();
    report.rays.output = p.accel.rays() - rays;
    report.resources.after("output");
    report.timings.total += report.timings.output;
    page::write_page(out, Some(report), &facts)?;
    unsynced.commit()?;
    let json_path = out.join("report.json");
    let json = serde_json::to_string_pretty(report)
        .map_err(|e| Error::internal(format!("cannot serialize the report: {e}")))?;
    fsio::write_atomic(&json_path, json.as_bytes())
}
