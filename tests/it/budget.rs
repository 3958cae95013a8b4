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

/// `n` cubes of edge `edge` on the Cornell box's floor in a grid, as Mitsuba `cube` shapes
/// (one shape each) or as one OBJ mesh of them all: the XML with the box's shapes, emitter
/// and cameras, written beside copies of its meshes and photos in `dir`.
fn cubes_on_the_floor(dir: &Path, n: usize, edge: f32, merged: bool) -> std::path::PathBuf {
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/cbox");
    for sub in ["meshes", "images"] {
        std::fs::create_dir_all(dir.join(sub)).unwrap();
        for e in std::fs::read_dir(fixture.join(sub)).unwrap() {
            let e = e.unwrap();
            std::fs::copy(e.path(), dir.join(sub).join(e.file_name())).unwrap();
        }
    }
    let cols = (n as f32).sqrt().ceil() as usize;
    let step = 1.6 / cols as f32;
    let centre = |i: usize| {
        let (x, z) = ((i % cols) as f32, (i / cols) as f32);
        (-0.8 + (x + 0.5) * step, edge / 2.0, -0.8 + (z + 0.5) * step)
    };
    let xml = std::fs::read_to_string(fixture.join("input.xml")).unwrap();
    let mut shapes = String::new();
    let bsdf = r#"<bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.5, 0.5"/></bsdf>"#;
    if merged {
        let mut obj = String::new();
        for i in 0..n {
            let (cx, cy, cz) = centre(i);
            for k in 0..8 {
                let h = edge / 2.0;
                let (sx, sy, sz) = (k & 1, (k >> 1) & 1, (k >> 2) & 1);
                let (x, y, z) = (
                    cx + h * (2 * sx) as f32 - h,
                    cy + h * (2 * sy) as f32 - h,
                    cz + h * (2 * sz) as f32 - h,
                );
                obj.push_str(&format!("v {x} {y} {z}\n"));
            }
            let b = i * 8 + 1;
            for q in [
                [0, 2, 3, 1],
                [4, 5, 7, 6],
                [0, 1, 5, 4],
                [2, 6, 7, 3],
                [0, 4, 6, 2],
                [1, 3, 7, 5],
            ] {
                let [a, c, d, e] = q.map(|v| b + v);
                obj.push_str(&format!("f {a} {c} {d}\nf {a} {d} {e}\n"));
            }
        }
        std::fs::write(dir.join("meshes/cubes.obj"), obj).unwrap();
        shapes.push_str(&format!(
            r#"<shape type="obj" id="cubes"><string name="filename" value="meshes/cubes.obj"/>{bsdf}</shape>"#
        ));
    } else {
        for i in 0..n {
            let (x, y, z) = centre(i);
            shapes.push_str(&format!(
                r#"<shape type="cube" id="cube_{i}"><transform name="to_world"><scale value="{}"/><translate x="{x}" y="{y}" z="{z}"/></transform>{bsdf}</shape>
"#,
                edge / 2.0
            ));
        }
    }
    let xml = xml.replace("</scene>", &format!("{shapes}</scene>"));
    let path = dir.join("input.xml");
    std::fs::write(&path, xml).unwrap();
    path
}

/// Thousands of small shapes cost what one shape of the same texels costs: their textures'
/// tiles, the gather's rays and its cache follow the texels, not the number of shapes.
#[test]
fn five_thousand_small_shapes_cost_what_one_shape_of_their_texels_costs() {
    let run = |merged: bool| {
        let dir = tempfile::tempdir().unwrap();
        let scene = cubes_on_the_floor(dir.path(), 5000, 0.012, merged);
        let mut cfg = Config::for_scene(scene);
        cfg.iterations = 1;
        cfg.refine_passes = 0;
        cfg.noise_probe = false;
        cfg.gather_rays = 64;
        cfg.atlas.texels_per_unit = Density::PerUnit(96.0);
        let out = dir.path().join("out");
        let report = reconstruct(&cfg, &out, Mode::Quiet).unwrap();
        let tiles = std::fs::metadata(out.join("checkpoint/state.tiles")).map_or(0, |m| m.len());
        (report, tiles)
    };
    let ((many, many_bytes), (one, one_bytes)) = (run(false), run(true));
    let texels = |r: &kdmap::report::Report| r.counts.covered_texels;
    let rays = |r: &kdmap::report::Report| r.iterations[0].gather_rays;
    eprintln!(
        "5000 shapes: {} covered texels, {} tile bytes, {} gather rays; one shape: {}, {}, {}",
        texels(&many),
        many_bytes,
        rays(&many),
        texels(&one),
        one_bytes,
        rays(&one)
    );
    assert!(many.atlas.len() >= 5000);
    assert!(texels(&many) as f64 <= 1.1 * texels(&one) as f64);
    // whole tiles per texture: 64 x 64 tiles would hold 30x the state of one shape
    assert!(many_bytes as f64 <= 2.5 * one_bytes.max(1) as f64);
    // a sixteenth of each cube's radius apart, the points would take every covered texel
    assert!(rays(&many) as f64 <= 1.5 * rays(&one) as f64);
}
