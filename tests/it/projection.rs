//! The luminance map is what the cameras saw: re-projecting it into each training camera must
//! give back the photo (away from silhouettes and depth edges).
//!
//! Environment hooks, for investigating a figure (`--nocapture` prints them):
//! - `KDMAP_DENSITY=<texels per unit>` overrides the atlas density (default 128);
//! - `KDMAP_ONLY_VIEW=cam_train_0` projects from (and evaluates) that one view only;
//! - `KDMAP_REFINE_PASSES=<n>` overrides `config::REFINE_PASSES` (0 = the plain weighted mean).

use glam::{Vec2, Vec3};
use kdmap::atlas::context::HitTable;
use kdmap::atlas::store::TileStore;
use kdmap::atlas::store::{TexelGeom, TexelState};
use kdmap::atlas::texture::{Scratch, SlotTexture};
use kdmap::atlas::uv::Charts;
use kdmap::atlas::{build_geometry, prepare, state_dir, RunContext};
use kdmap::base::progress::Mode;
use kdmap::config::Config;
use kdmap::config::REFINE_PASSES;
use kdmap::image::{read_exr, read_sensor_image, write_exr_rgb, write_png_srgb, Image};
use kdmap::output::write_map;
use kdmap::physics::camera::Camera;
use kdmap::physics::render::{bilinear, render_view, Film, Texture};
use kdmap::scene::luminance;
use kdmap::stages::project::{ProjectionStats, View};
use std::path::{Path, PathBuf};

mod pose;

fn fixture(scene_dir: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(scene_dir)
}

fn config(root: &Path) -> Config {
    let mut cfg = Config::for_scene(root.join("input.xml"));
    if let Ok(v) = std::env::var("KDMAP_ONLY_VIEW") {
        cfg.views
            .insert(v.clone(), root.join(format!("images/{v}.exr")));
    }
    cfg.atlas.texels_per_unit = kdmap::config::Density::PerUnit(128.0);
    // `project` below runs the refinement passes itself, so `project_all` must not.
    cfg.refine_passes = 0;
    if let Ok(v) = std::env::var("KDMAP_DENSITY") {
        cfg.atlas.texels_per_unit = kdmap::config::Density::PerUnit(v.parse().unwrap());
    }
    cfg
}

fn refine_passes() -> u32 {
    std::env::var("KDMAP_REFINE_PASSES")
        .map(|v| v.parse().unwrap())
        .unwrap_or(REFINE_PASSES)
}

/// The projection stage (`project::run`: the weighted mean, then `passes` refinement passes),
/// with the luminance maps written to `<out>/maps` and read back as a user would. Returns the
/// prepared scene and the maps by shape.
fn project(cfg: &Config, out: &Path, passes: u32) -> (RunContext, Vec<Option<Image>>) {
    let (p, maps, _) = project_stats(cfg, out, passes);
    (p, maps)
}

/// The projection stage of `p` run alone, its stores in `out`'s state directory: the
/// geometry, the state it left, a scratch in that directory and its statistics.
fn run_projection(
    p: &RunContext,
    cfg: &Config,
    out: &Path,
) -> (
    TileStore<TexelGeom>,
    TileStore<TexelState>,
    Scratch,
    ProjectionStats,
) {
    let dir = state_dir(out);
    std::fs::create_dir_all(&dir).unwrap();
    let geom = build_geometry(p, &dir.join("geometry.tiles"), Mode::Quiet).unwrap();
    let mut state = p
        .create_store(dir.join("state.tiles"), TexelState::default())
        .unwrap();
    let charts = Charts::new(&p.scene, &p.layout, &p.atlases).unwrap();
    let hits = HitTable::new(p, &charts);
    let scratch = Scratch::new(&dir, 1 << 30);
    let stats = kdmap::stages::project::run(
        p,
        cfg,
        (&hits, &charts),
        &geom,
        &mut state,
        Mode::Quiet,
        &scratch,
    )
    .unwrap();
    (geom, state, scratch, stats)
}

/// [`project`], also returning the stage's statistics.
fn project_stats(
    cfg: &Config,
    out: &Path,
    passes: u32,
) -> (RunContext, Vec<Option<Image>>, ProjectionStats) {
    let mut cfg = cfg.clone();
    cfg.refine_passes = passes;
    let p = prepare(&cfg, Mode::Quiet).unwrap();
    let (geom, state, scratch, stats) = run_projection(&p, &cfg, out);
    assert!(stats.views >= 1);
    assert!(
        stats.observed_texels > stats.covered_texels / 2,
        "{stats:?}"
    );
    let maps_dir = out.join("maps");
    let mut maps: Vec<Option<Image>> = (0..p.scene.shapes.len()).map(|_| None).collect();
    for (slot, st) in p.layout.slots.iter().enumerate() {
        let id = &p.scene.shapes[st.shape].id;
        let (l, sc) = (&p.layout, &scratch);
        let lum = SlotTexture::read(l, slot, &state, &geom, sc, "lum", |s, _| {
            Vec3::from_array(s.l_orig)
        })
        .unwrap();
        let observed = SlotTexture::read(l, slot, &state, &geom, sc, "obs", |s, _| {
            (s.weight > 0.0) as u8
        })
        .unwrap();
        let size = (st.width, st.height);
        write_map(&maps_dir, id, "luminance", &lum, &observed, false, sc).unwrap();
        let img = read_exr(maps_dir.join(format!("{id}_luminance.exr"))).unwrap();
        assert_eq!((img.width, img.height), size);
        assert_eq!(img.masked, 0, "{id}: negative or non-finite texels");
        maps[st.shape] = Some(img);
    }
    (p, maps, stats)
}

fn textures<'a>(p: &'a RunContext, maps: &'a [Option<Image>]) -> Vec<Option<Texture<'a>>> {
    maps.iter()
        .enumerate()
        .map(|(i, m)| {
            let m = m.as_ref()?;
            Some(Texture {
                texels: m,
                corner_uv: &p.atlases[i].as_ref()?.corner_uv,
            })
        })
        .collect()
}

/// Per view `(id, mean relative difference of B x B block means, blocks)` between the photo
/// and the maps re-rendered through the camera (box filter, 4 x 4 rays per pixel).
///
/// Per-pixel residuals are dominated by the photo's Monte Carlo noise (about 2% per pixel at
/// 1024 spp, white), so blocks of 8 x 8 pixels whose 3 x 3 neighbourhoods are all clean are
/// compared by their means (noise about 0.25% per block); the per-pixel figure is printed for
/// reference. On failure an x10 error image is written to `target/tmp` (`CARGO_TARGET_TMPDIR`).
fn reprojection_error(
    label: &str,
    p: &RunContext,
    maps: &[Option<Image>],
    photos: &[(usize, PathBuf)],
) -> Vec<(String, f64, usize)> {
    let textures = textures(p, maps);
    let mut res = Vec::new();
    for (si, path) in photos {
        let sensor = &p.scene.sensors[*si];
        let photo = read_sensor_image(path, sensor).unwrap();
        let cam = Camera::from_sensor(sensor);
        let view = View::new(&p.scene, &p.accel, cam.clone(), &photo);
        let render = render_view(&p.accel, &cam, &textures, 4, Film::HitsOnly);
        let (w, h) = (photo.width as i64, photo.height as i64);
        let clean = |x: i64, y: i64| {
            x >= 0 && y >= 0 && x < w && y < h && view.pixels[(y * w + x) as usize].clean
        };
        const B: i64 = 8;
        let usable = |x: i64, y: i64| -> Option<(f64, f64)> {
            let i = (y * w + x) as usize;
            let r = render[i]?;
            let inner = (-1..=1).all(|dy| (-1..=1).all(|dx| clean(x + dx, y + dy)));
            inner.then(|| (luminance(r) as f64, luminance(photo.pixels[i]) as f64))
        };
        let (mut sum, mut n, mut px_sum, mut px_n) = (0.0f64, 0usize, 0.0f64, 0usize);
        let mut diff = vec![Vec3::ZERO; (w * h) as usize];
        for by in 0..h / B {
            for bx in 0..w / B {
                let mut vals = Vec::new();
                for y in by * B..(by + 1) * B {
                    for x in bx * B..(bx + 1) * B {
                        if let Some(v) = usable(x, y) {
                            vals.push(v);
                            if v.1 > 1e-4 {
                                px_sum += (v.0 - v.1).abs() / v.1;
                                px_n += 1;
                            }
                        }
                    }
                }
                if vals.len() < (B * B) as usize {
                    continue;
                }
                let r: f64 = vals.iter().map(|v| v.0).sum();
                let q: f64 = vals.iter().map(|v| v.1).sum();
                if q <= 1e-4 * (B * B) as f64 {
                    continue;
                }
                let e = (r - q).abs() / q;
                for y in by * B..(by + 1) * B {
                    for x in bx * B..(bx + 1) * B {
                        diff[(y * w + x) as usize] = Vec3::splat(e as f32 * 10.0);
                    }
                }
                sum += e;
                n += 1;
            }
        }
        let mean = sum / n.max(1) as f64;
        eprintln!(
            "{label} {}: 8x8 block means differ by {:.3}% over {n} blocks \
             (per pixel {:.3}%, photo noise included)",
            sensor.id,
            100.0 * mean,
            100.0 * px_sum / px_n.max(1) as f64
        );
        if mean >= 0.01 {
            let dir = env!("CARGO_TARGET_TMPDIR");
            let f = Path::new(dir).join(format!("reproj_{label}_{}.png", sensor.id));
            write_png_srgb(&f, w as u32, h as u32, &diff, 0.0).unwrap();
            eprintln!("wrote the error image (x10) to {}", f.display());
        }
        res.push((sensor.id.clone(), mean, n));
    }
    res
}

fn assert_below_1_percent(label: &str, res: &[(String, f64, usize)]) {
    for (id, mean, n) in res {
        assert!(*n > 350, "{label} {id}: only {n} blocks compared");
        assert!(
            *mean < 0.01,
            "{label} {id}: mean relative difference {:.3}% >= 1%",
            100.0 * mean
        );
    }
}

fn check(scene: &str) {
    let cfg = config(&fixture(scene));
    let out = tempfile::tempdir().unwrap();
    let (p, maps) = project(&cfg, out.path(), refine_passes());
    let res = reprojection_error(scene, &p, &maps, &p.views);
    assert_below_1_percent(scene, &res);
}

#[test]
fn luminance_map_reprojects_to_the_photos_cbox() {
    check("cbox");
}

#[test]
fn luminance_map_reprojects_to_the_photos_cbox_tex() {
    check("cbox-tex");
}

/// sRGB PNG -> linear RGB texels, row 0 = top.
fn load_texture(path: &Path) -> (u32, u32, Vec<Vec3>) {
    let pm = tiny_skia::Pixmap::load_png(path).unwrap();
    let lin = |v: u8| {
        let v = v as f32 / 255.0;
        if v <= 0.04045 {
            v / 12.92
        } else {
            ((v + 0.055) / 1.055).powf(2.4)
        }
    };
    let px = pm
        .data()
        .chunks_exact(4)
        .map(|c| Vec3::new(lin(c[0]), lin(c[1]), lin(c[2])))
        .collect();
    (pm.width(), pm.height(), px)
}

/// A known radiance field on cbox-tex: per shape a texture and its per-triangle corner
/// coordinates in texels. The textured walls carry their true albedo bitmaps through the
/// meshes' UVs (bilinear, v up, as Mitsuba's bitmap texture), the rest constant albedos.
struct Field {
    tex: Vec<FieldTexture>,
}

/// `(width, height, texels, per-triangle corner coordinates in texels)`.
type FieldTexture = (Image, Vec<[Vec2; 3]>);

impl Field {
    fn cbox_tex(p: &RunContext, root: &Path) -> Field {
        let tex = p
            .scene
            .shapes
            .iter()
            .map(|s| {
                let file = match s.id.as_str() {
                    "ceiling" => Some("grace_hopper.png"),
                    "left" => Some("brick.png"),
                    "right" => Some("coffee.png"),
                    _ => None,
                };
                let (w, h, px) = match file {
                    Some(f) => load_texture(&root.join("textures").join(f)),
                    None if s.id == "short_box" => (1, 1, vec![Vec3::new(0.7, 0.7, 0.3)]),
                    None => (1, 1, vec![Vec3::splat(0.73)]),
                };
                let m = &s.mesh;
                let corner = m
                    .triangles
                    .iter()
                    .map(|t| {
                        t.map(|v| match &m.uvs {
                            Some(u) => {
                                let q = u[v as usize];
                                Vec2::new(q.x * w as f32, (1.0 - q.y) * h as f32)
                            }
                            None => Vec2::splat(0.5),
                        })
                    })
                    .collect();
                let n = px.len();
                let img = Image {
                    width: w,
                    height: h,
                    pixels: px,
                    valid: vec![true; n],
                    masked: 0,
                };
                (img, corner)
            })
            .collect();
        Field { tex }
    }

    fn textures(&self) -> Vec<Option<Texture<'_>>> {
        self.tex
            .iter()
            .map(|(img, c)| {
                Some(Texture {
                    texels: img,
                    corner_uv: c,
                })
            })
            .collect()
    }

    /// The field at a point of triangle `tri` of shape `shape`.
    fn at(&self, p: &RunContext, shape: usize, tri: usize, q: Vec3) -> Vec3 {
        let [a, b, c] = p.scene.shapes[shape].mesh.triangle(tri);
        let (e1, e2, e) = (b - a, c - a, q - a);
        let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
        let (r1, r2) = (e.dot(e1), e.dot(e2));
        let det = d11 * d22 - d12 * d12;
        let b1 = (r1 * d22 - r2 * d12) / det;
        let b2 = (r2 * d11 - r1 * d12) / det;
        let (img, corner) = &self.tex[shape];
        let cc = corner[tri];
        bilinear(img, cc[0] * (1.0 - b1 - b2) + cc[1] * b1 + cc[2] * b2)
    }
}

/// Mean absolute luminance difference between `maps` and the field over the observed texels
/// of `shape`, relative to the field's mean there. `tiles` holds every tile's
/// `(geometry, state)`.
fn map_error(
    p: &RunContext,
    field: &Field,
    maps: &[Option<Image>],
    tiles: &[(Vec<TexelGeom>, Vec<TexelState>)],
    shape: usize,
) -> f64 {
    let slot = p.layout.slot_of_shape(shape).unwrap();
    let st = p.layout.slots[slot];
    let m = maps[shape].as_ref().unwrap();
    let (mut diff, mut total) = (0.0f64, 0.0f64);
    for y in 0..st.height {
        for x in 0..st.width {
            let (t, off) = p.layout.locate(slot, x, y);
            let (g, s) = (
                &tiles[t as usize].0[off as usize],
                &tiles[t as usize].1[off as usize],
            );
            if !g.covered() || s.weight <= 0.0 {
                continue;
            }
            let v = luminance(m.get(x, y)) as f64;
            let f = luminance(field.at(p, shape, g.tri as usize, g.p())) as f64;
            diff += (v - f).abs();
            total += f;
        }
    }
    diff / total
}

/// The geometry and state stores [`project`] left in `out`.
fn stores(out: &Path) -> (TileStore<TexelGeom>, TileStore<TexelState>) {
    let dir = state_dir(out);
    (
        TileStore::open(dir.join("geometry.tiles")).unwrap(),
        TileStore::open(dir.join("state.tiles")).unwrap(),
    )
}

/// Noise-free synthetic photos of `field` through every training camera of `p` (the radiance
/// box-filtered over each pixel with 8 x 8 rays), `tweak(sensor, pixel index, value)` applied
/// to each pixel, written to `dir` and put in `cfg.views` in place of the photos. Returns
/// `(sensor, file)` per view.
fn synthetic_photos(
    p: &RunContext,
    field: &Field,
    cfg: &mut Config,
    dir: &Path,
    tweak: &dyn Fn(usize, usize, Vec3) -> Vec3,
) -> Vec<(usize, PathBuf)> {
    let sensors: Vec<usize> = p.views.iter().map(|v| v.0).collect();
    cfg.views.clear();
    // a texture-space field seen through the cameras shows no light: nothing to calibrate
    cfg.exposure = kdmap::config::Exposure::Known;
    let mut photos = Vec::new();
    for si in sensors {
        let s = &p.scene.sensors[si];
        let cam = Camera::from_sensor(s);
        let img: Vec<Vec3> = render_view(&p.accel, &cam, &field.textures(), 8, Film::HitsOnly)
            .into_iter()
            .enumerate()
            .map(|(i, v)| tweak(si, i, v.unwrap_or(Vec3::ZERO)))
            .collect();
        let f = dir.join(format!("{}.exr", s.id));
        write_exr_rgb(&f, s.width, s.height, &img, false).unwrap();
        cfg.views.insert(s.id.clone(), f.clone());
        photos.push((si, f));
    }
    photos
}

/// Every tile of the geometry and state stores a run left in `out`.
fn read_tiles(p: &RunContext, out: &Path) -> Vec<(Vec<TexelGeom>, Vec<TexelState>)> {
    let (geom, state) = stores(out);
    (0..p.layout.tile_count as usize)
        .map(|t| (geom.read_tile(t).unwrap(), state.read_tile(t).unwrap()))
        .collect()
}

/// The textured walls of cbox-tex whose maps the synthetic tests judge.
const WALLS: [&str; 3] = ["ceiling", "left", "right"];

/// Per wall of [`WALLS`], [`map_error`] of `maps` against `field`.
fn wall_errors(
    p: &RunContext,
    field: &Field,
    maps: &[Option<Image>],
    tiles: &[(Vec<TexelGeom>, Vec<TexelState>)],
) -> [f64; 3] {
    WALLS.map(|id| {
        let shape = p.scene.shapes.iter().position(|s| s.id == id).unwrap();
        map_error(p, field, maps, tiles, shape)
    })
}

/// cbox-tex's config with noise-free synthetic photos of its [`Field`] in the returned
/// directory, and the photos.
fn synthetic_cbox_tex() -> (Config, Field, tempfile::TempDir, Vec<(usize, PathBuf)>) {
    let root = fixture("cbox-tex");
    let mut cfg = config(&root);
    let p = prepare(&cfg, Mode::Quiet).unwrap();
    let field = Field::cbox_tex(&p, &root);
    let dir = tempfile::tempdir().unwrap();
    let photos = synthetic_photos(&p, &field, &mut cfg, dir.path(), &|_, _, v| v);
    (cfg, field, dir, photos)
}

/// Noise-free synthetic photos of cbox-tex (the radiance is the [`Field`], box-filtered over
/// each pixel with 8 x 8 rays) isolate the projection itself from Monte Carlo noise and
/// lighting. The maps must give the photos back (the plain weighted mean of eq. 1 gives
/// 1.9/1.0/1.3% here, as much as with the real photos: the error is the projection's own
/// blur), and refinement must bring them closer to the true field on the textured walls, not
/// only closer to the photos.
#[test]
fn synthetic_photos_of_known_textures_reproject_and_refine_towards_the_truth() {
    let (cfg, field, _photos_dir, photos) = synthetic_cbox_tex();
    let out = tempfile::tempdir().unwrap();
    let (_, plain) = project(&cfg, out.path(), 0);
    let out = tempfile::tempdir().unwrap();
    let (p, refined) = project(&cfg, out.path(), refine_passes());
    let res = reprojection_error("synthetic", &p, &refined, &photos);
    assert_below_1_percent("synthetic", &res);

    let tiles = read_tiles(&p, out.path());
    let (before, after) = (
        wall_errors(&p, &field, &plain, &tiles),
        wall_errors(&p, &field, &refined, &tiles),
    );
    for (id, (a, b)) in WALLS.iter().zip(before.iter().zip(&after)) {
        eprintln!(
            "synthetic {id}: map vs true field {:.2}% (weighted mean) -> {:.2}% (refined)",
            100.0 * a,
            100.0 * b
        );
        assert!(b < a, "{id}: refinement moved the map away from the truth");
    }
}

/// The refinement's residuals (`report.json` `refinement`): on noise-free synthetic photos
/// every view's render of the maps comes closer to its photo pass after pass, from the
/// weighted mean's blur (7-9% of a pixel's value here) to well under it.
#[test]
fn the_refinement_residual_falls_pass_by_pass_on_noise_free_photos() {
    let (cfg, _field, _photos_dir, _) = synthetic_cbox_tex();
    let out = tempfile::tempdir().unwrap();
    let passes = 4;
    let (_, _, stats) = project_stats(&cfg, out.path(), passes);
    let r = &stats.refine_residual;
    assert_eq!(r.len(), passes as usize, "one entry per pass");
    for v in 0..stats.views {
        let per_pass: Vec<f64> = r.iter().map(|pass| pass[v]).collect();
        eprintln!("view {v}: mean relative residual by pass {per_pass:.4?}");
        assert!(
            per_pass[0] > 0.005,
            "view {v}: the weighted mean's blur {per_pass:?}"
        );
        for w in per_pass.windows(2) {
            assert!(
                w[1] < w[0],
                "view {v}: a pass moved away from the photo {per_pass:?}"
            );
        }
        assert!(
            per_pass[passes as usize - 1] < 0.7 * per_pass[0],
            "view {v}: {per_pass:?}"
        );
    }
    let out = tempfile::tempdir().unwrap();
    let (_, _, none) = project_stats(&cfg, out.path(), 0);
    assert!(none.refine_residual.is_empty(), "no passes, no residuals");
}

/// The refinement's step (`projection.refine_step`) over-relaxes the passes after the first:
/// on the same noise-free synthetic photos, step 1.8 gets the textured walls closer to the true
/// field in the same passes than the plain step 1.
#[test]
fn a_larger_refinement_step_gets_closer_to_the_truth_in_the_same_passes() {
    let (cfg, field, _photos_dir, _) = synthetic_cbox_tex();
    let refined = |step: f32| {
        let mut c = cfg.clone();
        c.refine_step = step;
        let out = tempfile::tempdir().unwrap();
        let (p, maps) = project(&c, out.path(), refine_passes());
        wall_errors(&p, &field, &maps, &read_tiles(&p, out.path()))
    };
    let (one, larger) = (refined(1.0), refined(1.8));
    for (id, (a, b)) in WALLS.iter().zip(one.iter().zip(&larger)) {
        eprintln!(
            "synthetic {id}: map vs true field {:.2}% (step 1) -> {:.2}% (step 1.8)",
            100.0 * a,
            100.0 * b
        );
        // The brick wall (left), whose mortar lines are finer than the photos' pixels, stays
        // where it is (within 1%).
        assert!(*b <= a * 1.01, "{id}: step 1.8 moved away from the truth");
    }
    // and closer on the three walls together (by more than 1% of their summed error)
    let (a, b): (f64, f64) = (one.iter().sum(), larger.iter().sum());
    assert!(
        b < 0.99 * a,
        "step 1.8 is not closer than step 1: {a} -> {b}"
    );
}

/// The refinement's gate (`projection.refine_gate`, from `refine_gated_from`) must not hold
/// back detail: on synthetic cbox-tex photos with noise (the noise probe test's), the default
/// passes, gated from `refine_gated_from` on, leave the textured walls as close to the true
/// field (within 2%) as the same passes ungated, and the uniform surfaces too (Gaussian noise
/// alone the residual shrinkage already keeps out; its gain on real photos is
/// `known::the_refinement_gate_keeps_the_photos_noise_off_uniform_walls`). The same on
/// noise-free photos, where the level the shrinkage judges by is the unresolved detail's.
#[test]
fn the_gate_keeps_texture_detail() {
    let root = fixture("cbox-tex");
    let mut base = config(&root);
    base.noise_probe = false;
    let p = prepare(&base, Mode::Quiet).unwrap();
    let field = Field::cbox_tex(&p, &root);
    let uniform = ["back", "floor", "short_box", "tall_box"];
    let run = |noisy: bool, gate: f32| {
        let mut cfg = base.clone();
        cfg.refine_gate = gate;
        let dir = tempfile::tempdir().unwrap();
        let noise = photo_noise(7);
        let exact = |_: usize, _: usize, v: Vec3| v;
        let tweak: &dyn Fn(usize, usize, Vec3) -> Vec3 = if noisy { &noise } else { &exact };
        synthetic_photos(&p, &field, &mut cfg, dir.path(), tweak);
        let out = tempfile::tempdir().unwrap();
        let (p, maps) = project(&cfg, out.path(), REFINE_PASSES);
        let tiles = read_tiles(&p, out.path());
        let err = |ids: &[&str]| -> f64 {
            ids.iter()
                .map(|id| {
                    let shape = p.scene.shapes.iter().position(|s| s.id == *id).unwrap();
                    map_error(&p, &field, &maps, &tiles, shape)
                })
                .sum::<f64>()
                / ids.len() as f64
        };
        (err(&uniform), err(&WALLS))
    };
    let (u0, t0) = run(true, 0.0);
    let (u1, t1) = run(true, kdmap::config::REFINE_GATE);
    eprintln!(
        "noisy synthetic cbox-tex, {REFINE_PASSES} passes: uniform surfaces {:.2}% -> {:.2}% \
         with the gate, textured walls {:.2}% -> {:.2}%",
        100.0 * u0,
        100.0 * u1,
        100.0 * t0,
        100.0 * t1
    );
    assert!(u1 < 1.02 * u0, "uniform: {u0} -> {u1}");
    assert!(t1 < 1.02 * t0, "textured: {t0} -> {t1}");
    let (nu0, nt0) = run(false, 0.0);
    let (nu1, nt1) = run(false, kdmap::config::REFINE_GATE);
    eprintln!(
        "noise-free: uniform surfaces {:.2}% -> {:.2}%, textured walls {:.2}% -> {:.2}%",
        100.0 * nu0,
        100.0 * nu1,
        100.0 * nt0,
        100.0 * nt1
    );
    assert!(nt1 < 1.02 * nt0, "noise-free textured: {nt0} -> {nt1}");
    assert!(
        nu1 < 1.02 * nu0 + 1e-4,
        "noise-free uniform: {nu0} -> {nu1}"
    );
}

impl Field {
    /// An occlusion scene on cbox-tex's geometry: the back wall and the floor carry a smooth
    /// texture (a product of sines between 0.2 and 1.0, one period across the wall: no detail
    /// the photos cannot resolve, so what is left is the projection's own doing), the two
    /// boxes in front of them are 8x brighter than any of it, the rest constant. A texel of
    /// the wall or floor that took anything from a box's silhouette shows it at once.
    fn occlusion(p: &RunContext) -> Field {
        let n = 64u32;
        let pattern: Vec<Vec3> = (0..n * n)
            .map(|i| {
                let (x, y) = ((i % n) as f32 / n as f32, (i / n) as f32 / n as f32);
                let t = std::f32::consts::TAU;
                let v = 0.6 + 0.4 * (t * x).sin() * (t * y).cos();
                Vec3::new(v, 0.9 * v, 0.8 * v)
            })
            .collect();
        let (bw, bh, brick) = (n, n, pattern);
        let as_image = |w: u32, h: u32, px: Vec<Vec3>| {
            let n = px.len();
            Image {
                width: w,
                height: h,
                pixels: px,
                valid: vec![true; n],
                masked: 0,
            }
        };
        let tex = p
            .scene
            .shapes
            .iter()
            .map(|s| {
                let m = &s.mesh;
                let textured = matches!(s.id.as_str(), "back" | "floor");
                let (img, corner) = if textured {
                    // planar map over the mesh's two longest bounding-box axes
                    let lo = m.positions.iter().fold(Vec3::INFINITY, |a, v| a.min(*v));
                    let hi = m
                        .positions
                        .iter()
                        .fold(Vec3::NEG_INFINITY, |a, v| a.max(*v));
                    let ext = hi - lo;
                    let thin = ext.min_position();
                    let (a, b) = ((thin + 1) % 3, (thin + 2) % 3);
                    let uv = |v: Vec3| {
                        let q = (v - lo) / ext;
                        Vec2::new(q[a] * bw as f32, q[b] * bh as f32)
                    };
                    let c = m
                        .triangles
                        .iter()
                        .map(|t| t.map(|v| uv(m.positions[v as usize])))
                        .collect();
                    (as_image(bw, bh, brick.clone()), c)
                } else {
                    let v = match s.id.as_str() {
                        "short_box" | "tall_box" => Vec3::new(8.0, 8.0, 8.0),
                        _ => Vec3::splat(0.4),
                    };
                    let c = vec![[Vec2::splat(0.5); 3]; m.triangles.len()];
                    (as_image(1, 1, vec![v]), c)
                };
                (img, corner)
            })
            .collect();
        Field { tex }
    }
}

/// Noise-free photos of [`Field::occlusion`] (the radiance, an albedo-like field, box-filtered
/// over each pixel with 8 x 8 rays): pixels whose footprint mixes a box and the surface behind
/// it must not feed the texels behind. The texels of the back wall and the floor near a box's
/// silhouette (within 3 texels of one a view sees a box in front of) must hold the field's
/// value: within 1% on average and 25% at worst; with every pixel counted as clean (no
/// silhouette rule) they would be about 12% off on average, some tenfold.
#[test]
fn silhouettes_of_an_object_in_front_of_a_textured_plane_do_not_leak_into_it() {
    let root = fixture("cbox-tex");
    let mut cfg = config(&root);
    let p = prepare(&cfg, Mode::Quiet).unwrap();
    let field = Field::occlusion(&p);
    let photos_dir = tempfile::tempdir().unwrap();
    synthetic_photos(&p, &field, &mut cfg, photos_dir.path(), &|_, _, v| v);
    let out = tempfile::tempdir().unwrap();
    let (p, _) = project(&cfg, out.path(), refine_passes());
    let (geom, state) = stores(out.path());
    let boxes: Vec<usize> = ["short_box", "tall_box"]
        .iter()
        .map(|id| p.scene.shapes.iter().position(|s| s.id == *id).unwrap())
        .collect();
    for id in ["back", "floor"] {
        let shape = p.scene.shapes.iter().position(|s| s.id == id).unwrap();
        let slot = p.layout.slot_of_shape(shape).unwrap();
        let st = p.layout.slots[slot];
        // per texel: relative error, and whether a camera ray to it first meets a box
        let mut texels = Vec::new();
        for y in 0..st.height {
            for x in 0..st.width {
                let (t, off) = p.layout.locate(slot, x, y);
                let g = geom.read_tile(t as usize).unwrap()[off as usize];
                let s = state.read_tile(t as usize).unwrap()[off as usize];
                if !g.covered() || s.weight <= 0.0 {
                    continue;
                }
                let f = luminance(field.at(&p, shape, g.tri as usize, g.p()));
                let err = (luminance(Vec3::from_array(s.l_orig)) - f).abs() / f;
                let hidden = p.views.iter().any(|(si, _)| {
                    let eye = Camera::from_sensor(&p.scene.sensors[*si]).position();
                    let d = (g.p() - eye).normalize();
                    p.accel
                        .intersect(eye, d, (g.p() - eye).length() * 0.999)
                        .is_some_and(|h| boxes.contains(&(h.shape as usize)))
                });
                texels.push((x, y, err, hidden));
            }
        }
        // texels within 3 texels of one hidden from some view: along the silhouettes
        let hidden: std::collections::HashSet<(u32, u32)> =
            texels.iter().filter(|t| t.3).map(|t| (t.0, t.1)).collect();
        let near = |x: u32, y: u32| {
            (-3i64..=3).any(|dy| {
                (-3i64..=3).any(|dx| {
                    let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                    nx >= 0 && ny >= 0 && hidden.contains(&(nx as u32, ny as u32))
                })
            })
        };
        let (mut edge, mut rest) = (Vec::new(), Vec::new());
        for &(x, y, err, _) in &texels {
            if near(x, y) {
                edge.push(err)
            } else {
                rest.push(err)
            }
        }
        let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len().max(1) as f32;
        let worst = |v: &[f32]| v.iter().cloned().fold(0.0, f32::max);
        eprintln!(
            "occlusion {id}: {} texels near silhouettes, mean error {:.2}% (max {:.1}%); \
             {} elsewhere, {:.2}% (max {:.1}%)",
            edge.len(),
            100.0 * mean(&edge),
            100.0 * worst(&edge),
            rest.len(),
            100.0 * mean(&rest),
            100.0 * worst(&rest),
        );
        assert!(
            edge.len() > 50,
            "{id}: the boxes hide too little of it to test"
        );
        assert!(mean(&edge) < 0.01, "{id}: silhouettes leak");
        assert!(worst(&edge) < 0.25, "{id}: a texel took a box's radiance");
    }
}

/// Noise-free photos of [`Field::occlusion`], one of them with a highlight (four times the
/// radiance in a disc of 16 pixels' radius at its centre: a specular reflection, a passing
/// object): the views that agree outvote it. Over the texels that view sees inside the disc,
/// the plain weighted mean would be off by `3 w_v / W` (near 100% with three views of like
/// weight); the robust fusion must stay within a few percent of the field, and flag that
/// view as disagreeing there, not elsewhere.
#[test]
fn a_view_with_a_highlight_is_outvoted_and_flagged() {
    let root = fixture("cbox-tex");
    let mut cfg = config(&root);
    let p = prepare(&cfg, Mode::Quiet).unwrap();
    let field = Field::occlusion(&p);
    let photos_dir = tempfile::tempdir().unwrap();
    let blob_view = p.views[0].0;
    let (width, centre, radius) = (
        p.scene.sensors[blob_view].width,
        Vec2::new(128.0, 128.0),
        16.0,
    );
    let highlight = |si: usize, i: usize, v: Vec3| {
        let px = Vec2::new((i as u32 % width) as f32, (i as u32 / width) as f32);
        match si == blob_view && (px + 0.5 - centre).length() < radius {
            true => v * 4.0,
            false => v,
        }
    };
    synthetic_photos(&p, &field, &mut cfg, photos_dir.path(), &highlight);
    let out = tempfile::tempdir().unwrap();
    let (p, _) = project(&cfg, out.path(), refine_passes());
    let (geom, state) = stores(out.path());
    let cam = Camera::from_sensor(&p.scene.sensors[blob_view]);
    let (mut inside, mut flagged_in, mut outside, mut flagged_out) = (Vec::new(), 0, 0, 0);
    for t in 0..p.layout.tile_count as usize {
        let (gs, ss) = (geom.read_tile(t).unwrap(), state.read_tile(t).unwrap());
        let slot = p.layout.slot_of_tile(t as u32);
        let shape = p.layout.slots[slot].shape;
        for (g, s) in gs.iter().zip(&ss) {
            if !g.covered() || s.weight <= 0.0 {
                continue;
            }
            let seen = cam.project(g.p()).filter(|_| {
                let eye = cam.position();
                let d = (g.p() - eye).normalize();
                let far = (g.p() - eye).length() * 0.999;
                p.accel.intersect(eye, d, far).is_none()
            });
            // well inside the disc (away from its blurred rim) or well outside it
            match seen.map(|px| (px - centre).length()) {
                Some(r) if r < radius - 4.0 => {
                    let f = luminance(field.at(&p, shape, g.tri as usize, g.p()));
                    let err = (luminance(Vec3::from_array(s.l_orig)) - f).abs() / f;
                    inside.push(err);
                    flagged_in += (s.disagree >= 1.0) as usize;
                }
                Some(r) if r < radius + 4.0 => {}
                _ => {
                    outside += 1;
                    flagged_out += (s.disagree >= 1.0) as usize;
                }
            }
        }
    }
    let mean = inside.iter().sum::<f32>() / inside.len().max(1) as f32;
    eprintln!(
        "highlight: {} texels inside, mean error {:.2}%, {} flagged; {} outside, {} flagged",
        inside.len(),
        100.0 * mean,
        flagged_in,
        outside,
        flagged_out
    );
    assert!(
        inside.len() > 100,
        "the disc covers too few texels to judge"
    );
    assert!(mean < 0.05, "the highlight was not outvoted");
    assert!(
        flagged_in * 10 > inside.len() * 9,
        "the disagreeing view was not counted"
    );
    assert!(
        flagged_out * 100 < outside,
        "views flagged where they agree"
    );
}

/// The photon bins tile every surface: summed over covered texels, `bin_area` (the part of a
/// texel's square on its chart) is each shape's mesh area, to 0.5%.
fn check_bin_areas(density: f32) {
    for scene in ["cbox", "cbox-tex"] {
        {
            let mut cfg = Config::for_scene(fixture(scene).join("input.xml"));
            cfg.atlas.texels_per_unit = kdmap::config::Density::PerUnit(density);
            let p = prepare(&cfg, Mode::Quiet).unwrap();
            let dir = tempfile::tempdir().unwrap();
            let geom = build_geometry(&p, &dir.path().join("geometry.tiles"), Mode::Quiet).unwrap();
            for (slot, st) in p.layout.slots.iter().enumerate() {
                let shape = &p.scene.shapes[st.shape];
                let mesh_area: f64 = (0..shape.mesh.triangles.len())
                    .map(|t| 0.5 * shape.mesh.face_normal_raw(t).length() as f64)
                    .sum();
                let mut bins = 0.0f64;
                for ty in 0..st.tiles_y {
                    for tx in 0..st.tiles_x {
                        let t = st.first_tile + ty * st.tiles_x + tx;
                        assert_eq!(p.layout.slot_of_tile(t), slot);
                        for g in geom.read_tile(t as usize).unwrap() {
                            if g.covered() {
                                bins += g.bin_area as f64;
                            }
                        }
                    }
                }
                let rel = (bins - mesh_area).abs() / mesh_area;
                assert!(
                    rel < 0.005,
                    "{scene} {} at {density} texels/unit: bin areas sum to {bins}, mesh area \
                     {mesh_area} ({:.3}% off)",
                    shape.id,
                    100.0 * rel
                );
            }
        }
    }
}

#[test]
fn bin_areas_sum_to_mesh_areas() {
    check_bin_areas(128.0);
}

/// Not met: at 64 texels per unit the boxes' bins miss 2.07% (short box) and 1.30% (tall box)
/// of their area. Their charts span texel coordinates like [1, 39.4]: the last row and column
/// of texels (39..40) have their centers off the chart, so they are gutter, and the 0.4-texel
/// strip of chart inside them belongs to no bin (photons landing there are dropped). At 128
/// texels per unit the charts end at 77.8, past the last center, and the gap is 0.13%.
#[test]
#[ignore = "chart edges between texel centers leave strips of surface in no bin (atlas)"]
fn bin_areas_sum_to_mesh_areas_at_low_density() {
    check_bin_areas(64.0);
}

/// Per shape of a projection left in `out`: `(shape id, texel index within the run, luminance,
/// predicted standard deviation sqrt(l_var))` of every observed texel.
fn observed_luminance(p: &RunContext, out: &Path) -> Vec<(String, usize, f32, f32)> {
    let mut v = Vec::new();
    for (t, (_, ss)) in read_tiles(p, out).into_iter().enumerate() {
        let slot = p.layout.slot_of_tile(t as u32);
        let id = &p.scene.shapes[p.layout.slots[slot].shape].id;
        for (i, s) in ss.iter().enumerate() {
            if s.weight > 0.0 {
                let l = luminance(Vec3::from_array(s.l_orig));
                v.push((id.clone(), t * ss.len() + i, l, s.l_var.max(0.0).sqrt()));
            }
        }
    }
    v
}

/// A [`synthetic_photos`] tweak that adds a rendered photo's kind of noise: relative, 1.6%
/// at luminance 1 and more on dim surfaces (`1.6% / sqrt(luminance)`, at most 8%), drawn from
/// `seed`, the sensor and the pixel.
fn photo_noise(seed: u64) -> impl Fn(usize, usize, Vec3) -> Vec3 {
    move |si: usize, i: usize, v: Vec3| {
        let rel = 0.016 / luminance(v).max(0.04).sqrt();
        let n = kdmap::base::rng::Rng::new(seed, si as u64, 0, i as u64).normal();
        v * (1.0 + rel * n).max(0.0)
    }
}

/// The median of `v` (sorted in place).
fn median(v: &mut [f32]) -> f32 {
    v.sort_by(f32::total_cmp);
    v[v.len() / 2]
}

/// The noise probe (`project::noise_probe`) must predict the noise the photos give each texel.
/// Two projections of synthetic cbox-tex photos with independent relative noise (2% on the
/// brightest surfaces, more on dim ones, as in a rendered photo) measure it: per shape, the
/// robust spread of the two luminances' relative difference over sqrt 2. The predicted standard
/// deviation (`sqrt(l_var)`, its median over the shape) must be within a factor 1.5 of it on
/// every shape. Without the probe (the noise propagated through the views' weights only) the
/// refinement's amplification on the grazing ceiling is missed.
#[test]
fn the_noise_probe_predicts_the_texel_noise_of_independent_photos() {
    let root = fixture("cbox-tex");
    let base = config(&root);
    let p = prepare(&base, Mode::Quiet).unwrap();
    let field = Field::cbox_tex(&p, &root);
    let run = |seed: u64, probe: bool| {
        let mut cfg = base.clone();
        cfg.noise_probe = probe;
        let dir = tempfile::tempdir().unwrap();
        let noisy = photo_noise(seed);
        synthetic_photos(&p, &field, &mut cfg, dir.path(), &noisy);
        let out = tempfile::tempdir().unwrap();
        let (p, _) = project(&cfg, out.path(), refine_passes());
        observed_luminance(&p, out.path())
    };
    let ratios = |a: &[(String, usize, f32, f32)], b: &[(String, usize, f32, f32)]| {
        let mut by: std::collections::BTreeMap<&str, (Vec<f32>, Vec<f32>)> = Default::default();
        for (x, y) in a.iter().zip(b) {
            assert_eq!((&x.0, x.1), (&y.0, y.1), "the same texels");
            let m = 0.5 * (x.2 + y.2);
            if m > 0.0 {
                let e = by.entry(&x.0).or_default();
                e.0.push((x.2 - y.2) / m / std::f32::consts::SQRT_2);
                e.1.push(x.3 / x.2.max(1e-9));
            }
        }
        by.into_iter()
            .map(|(id, (mut d, mut pred))| {
                let mid = median(&mut d);
                let mut dev: Vec<f32> = d.iter().map(|v| (v - mid).abs()).collect();
                let actual = 1.4826 * median(&mut dev);
                (id.to_string(), actual, median(&mut pred))
            })
            .collect::<Vec<_>>()
    };
    let (a, b) = (run(1, true), run(2, true));
    let (a0, b0) = (run(1, false), run(2, false));
    let (with, without) = (ratios(&a, &b), ratios(&a0, &b0));
    let mut worst_without = 1.0f32;
    for ((id, actual, pred), (_, actual0, pred0)) in with.iter().zip(&without) {
        eprintln!(
            "{id}: texel noise {:.2}%, predicted {:.2}% with the probe, {:.2}% without ({:.2}%)",
            100.0 * actual,
            100.0 * pred,
            100.0 * pred0,
            100.0 * actual0
        );
        let r = actual / pred;
        assert!(
            (1.0 / 1.5..1.5).contains(&r),
            "{id}: measured / predicted {r:.2}"
        );
        let r0 = actual0 / pred0;
        worst_without = worst_without.max(r0).max(1.0 / r0);
    }
    assert!(
        worst_without > 1.5,
        "the propagation alone was within {worst_without:.2}"
    );
}

/// The refinement keeps each view's look-ups within a quarter of the memory budget and looks
/// up the rest again in every pass: at 16 MiB it keeps part of cbox's (the test checks that),
/// at 1 GiB all, and the projection's state is the same to the bit.
#[test]
fn the_projection_is_the_same_whatever_share_of_its_look_ups_is_kept() {
    let root = fixture("cbox");
    let run = |mib: u64| {
        let mut cfg = config(&root);
        cfg.refine_passes = 2;
        cfg.noise_probe = false;
        cfg.memory_budget_mib = mib;
        let out = tempfile::tempdir().unwrap();
        let p = prepare(&cfg, Mode::Quiet).unwrap();
        let (_, state, _, stats) = run_projection(&p, &cfg, out.path());
        let bits: Vec<u32> = (0..state.tile_count())
            .flat_map(|t| state.read_tile(t).unwrap())
            .flat_map(|s| [s.l_orig[0], s.l_orig[1], s.l_orig[2], s.weight, s.l_var])
            .map(f32::to_bits)
            .collect();
        (bits, stats.lookup_bytes)
    };
    let (small, kept_small) = run(16);
    let (large, kept_large) = run(1024);
    eprintln!("look-ups kept: {kept_small} bytes at 16 MiB, {kept_large} at 1 GiB");
    assert!(
        kept_small > 0 && kept_small < kept_large,
        "{kept_small} vs {kept_large}"
    );
    assert!(kept_small <= 4 << 20);
    assert!(small == large, "the kept share changed the projection");
}
