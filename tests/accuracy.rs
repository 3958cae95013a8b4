//! Accuracy of the whole reconstruction against the true albedo of the shipped examples, at
//! CI-sized settings (the full-size figures are in the README).

use kdmap::atlas::layout::{TexelGeom, TexelState};
use kdmap::atlas::tiles::TileStore;
use kdmap::config::Config;
use kdmap::pipeline::{prepare, reconstruct, state_dir};
use kdmap::progress::Mode;
use kdmap::truth::Truth;
use std::path::Path;

fn run(scene: &str, photons: u64, iterations: u32) -> Vec<kdmap::truth::ShapeAccuracy> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(scene);
    let mut cfg = Config::for_scene(root.join("input.xml"));
    cfg.photons = std::env::var("KDMAP_PHOTONS").map_or(photons, |v| v.parse().unwrap());
    cfg.iterations = std::env::var("KDMAP_ITERATIONS").map_or(iterations, |v| v.parse().unwrap());
    if let Ok(v) = std::env::var("KDMAP_DENSITY") {
        cfg.atlas.texels_per_unit = v.parse().unwrap();
    }
    if let Ok(v) = std::env::var("KDMAP_SMOOTH") {
        cfg.smoothing_radius = v.parse().unwrap();
    }
    if let Ok(v) = std::env::var("KDMAP_UPDATE") {
        cfg.update = match v.as_str() {
            "paper" => kdmap::config::UpdateRule::Paper,
            "fixed_point" => kdmap::config::UpdateRule::FixedPoint,
            _ => kdmap::config::UpdateRule::Relaxed,
        };
    }
    let out = tempfile::tempdir().unwrap();
    let report = reconstruct(&cfg, out.path(), Mode::Quiet).unwrap();
    for it in &report.iterations {
        eprintln!(
            "{scene} iteration {}: rms {:.3}% mean {:.3}% max {:.2}%",
            it.iteration,
            100.0 * it.rms_rel_error,
            100.0 * it.mean_rel_error,
            100.0 * it.max_rel_error
        );
    }
    let p = prepare(&cfg, Mode::Quiet).unwrap();
    let dir = state_dir(out.path());
    let geom: TileStore<TexelGeom> = TileStore::open(dir.join("geometry.tiles")).unwrap();
    let state: TileStore<TexelState> = TileStore::open(dir.join("state.tiles")).unwrap();
    let truth = Truth::load(&root.join("truth.xml")).unwrap();
    let acc = truth.accuracy(&p, &geom, &state).unwrap();
    for a in &acc {
        eprintln!(
            "{scene} {}: {} texels, mean relative albedo error {:.2}%, mean K_d {:.4?} vs true {:.4?}",
            a.shape,
            a.texels,
            100.0 * a.mean_rel_error,
            a.mean_kd,
            a.mean_truth
        );
    }
    acc
}

#[test]
fn cbox_albedo_is_recovered() {
    let acc = run("cbox", 1_000_000, 4);
    assert_eq!(acc.len(), 7);
}
