//! Work that scales with the scene: a photon budget given per covered texel keeps E_i's noise
//! per texel where it is when the atlas grows; a fixed budget spreads the same photons over
//! more texels, and the noise grows with them.
//!
//! The noise is measured as the mean relative difference of E_i (`maps/back_indirect.exr`,
//! the uniform back wall of the Cornell box) between two runs that differ only in their seed,
//! after one photon pass, at 32 and 64 texels per unit (4x the texels).
//!
//! Also: a memory budget too small for the harmonic relaxation of the unobserved texels keeps
//! the wave's fill for those textures and says so in the report, never silently.

use kdmap::base::progress::Mode;
use kdmap::config::{Config, Density, Method};
use kdmap::image::read_exr;
use kdmap::pipeline::reconstruct;
use std::path::Path;

/// The E_i map of the back wall after one photon pass (`budget` sets the photons).
fn indirect(density: f32, seed: u64, budget: impl Fn(&mut Config)) -> Vec<f32> {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/cbox/input.xml");
    let mut cfg = Config::for_scene(scene);
    cfg.method = Method::Photons;
    cfg.iterations = 1;
    cfg.refine_passes = 0;
    cfg.seed = seed;
    cfg.atlas.texels_per_unit = Density::PerUnit(density);
    budget(&mut cfg);
    let out = tempfile::tempdir().unwrap();
    reconstruct(&cfg, out.path(), Mode::Quiet).unwrap();
    let img = read_exr(out.path().join("maps/back_indirect.exr")).unwrap();
    img.pixels.iter().map(|p| p.y).collect()
}

/// Mean relative difference of E_i between seeds 1 and 2, over texels lit indirectly.
fn noise(density: f32, budget: impl Fn(&mut Config) + Copy) -> f64 {
    let (a, b) = (indirect(density, 1, budget), indirect(density, 2, budget));
    let pairs: Vec<(f32, f32)> = a
        .into_iter()
        .zip(b)
        .filter(|&(x, y)| x > 0.0 && y > 0.0)
        .collect();
    assert!(pairs.len() > 100, "{density}: {} texels", pairs.len());
    let sum: f64 = pairs
        .iter()
        .map(|&(x, y)| ((x - y).abs() / (0.5 * (x + y))) as f64)
        .sum();
    sum / pairs.len() as f64
}

#[test]
fn photons_per_texel_keep_the_noise_per_texel_as_the_atlas_grows() {
    let per_texel = |c: &mut Config| c.photons_per_texel = Some(8.0);
    let (coarse, fine) = (noise(32.0, per_texel), noise(64.0, per_texel));
    eprintln!("per texel: E_i noise {coarse:.4} at 32/unit, {fine:.4} at 64/unit");
    assert!(
        (0.75..1.33).contains(&(fine / coarse)),
        "4x the texels changed the noise per texel {:.2}x with a per-texel budget",
        fine / coarse
    );
    // the control: the same photons at both densities (those of 8 per texel at 32/unit)
    let fixed = |c: &mut Config| c.set_photons(220_000);
    let (coarse, fine) = (noise(32.0, fixed), noise(64.0, fixed));
    eprintln!("fixed: E_i noise {coarse:.4} at 32/unit, {fine:.4} at 64/unit");
    assert!(
        fine / coarse > 1.6,
        "a fixed budget over 4x the texels should about double the noise: {:.2}x",
        fine / coarse
    );
}

/// The relaxation of the fill needs up to 160 bytes per unobserved texel of a texture; at the
/// smallest memory budget (16 MiB: a 4 MiB scratch, 26k such texels) cbox-tex's largest
/// unobserved areas do not fit and are counted in `fill_unrelaxed_texels`; at the default
/// every texture is relaxed.
#[test]
fn a_fill_over_the_memory_budget_is_reported() {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/cbox-tex/input.xml");
    let run = |mib: u64| {
        let mut cfg = Config::for_scene(scene.clone());
        cfg.iterations = 1;
        cfg.refine_passes = 0;
        cfg.memory_budget_mib = mib;
        let out = tempfile::tempdir().unwrap();
        reconstruct(&cfg, out.path(), Mode::Quiet).unwrap().counts
    };
    let (small, default) = (run(16), run(1024));
    assert_eq!(small.filled_texels, default.filled_texels);
    assert!(
        small.fill_unrelaxed_texels > 0 && small.fill_unrelaxed_texels <= small.filled_texels,
        "{} of {} filled texels unrelaxed at 16 MiB",
        small.fill_unrelaxed_texels,
        small.filled_texels
    );
    assert_eq!(default.fill_unrelaxed_texels, 0);
}
