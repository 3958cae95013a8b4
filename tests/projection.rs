//! The luminance map is what the cameras saw: re-projecting it into each training camera must
//! give back the photo (away from silhouettes and depth edges).

use glam::{Vec2, Vec3};
use kdmap::camera::Camera;
use kdmap::config::Config;
use kdmap::image::{read_exr, read_sensor_image, write_exr_rgb, write_png_srgb, Image};
use kdmap::pipeline::{prepare, run_projection};
use kdmap::progress::Mode;
use kdmap::project::View;
use kdmap::render::{render_view, Texture};
use kdmap::scene::luminance;
use std::path::{Path, PathBuf};

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
    cfg.atlas.texels_per_unit = 128.0;
    if let Ok(v) = std::env::var("KDMAP_DENSITY") {
        cfg.atlas.texels_per_unit = v.parse().unwrap();
    }
    cfg
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

/// Noise-free synthetic photos of cbox-tex: the surface radiance is the true albedo (bilinear
/// bitmap lookups through the meshes' UVs, as Mitsuba does), box-filtered over each pixel with
/// `k x k` rays. Written as float EXR into `dir`; returns the config pointing at them.
fn synthetic_photos(root: &Path, dir: &Path, k: u32) -> Config {
    let mut cfg = config(root);
    let p = prepare(&cfg, Mode::Quiet).unwrap();
    let tex: Vec<(u32, u32, Vec<Vec3>, Vec<[Vec2; 3]>)> = p
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
            let corner = (0..m.triangles.len())
                .map(|t| {
                    let uv = |i: usize| match &m.uvs {
                        Some(u) => {
                            let q = u[m.triangles[t][i] as usize];
                            Vec2::new(q.x * w as f32, (1.0 - q.y) * h as f32)
                        }
                        None => Vec2::splat(0.5),
                    };
                    [uv(0), uv(1), uv(2)]
                })
                .collect();
            (w, h, px, corner)
        })
        .collect();
    let textures: Vec<Option<Texture>> = tex
        .iter()
        .map(|(w, h, px, c)| {
            Some(Texture {
                width: *w,
                height: *h,
                texels: px,
                corner_uv: c,
            })
        })
        .collect();
    let sensors: Vec<usize> = if cfg.views.is_empty() {
        (0..3).collect()
    } else {
        p.views.iter().map(|v| v.0).collect()
    };
    cfg.views.clear();
    for si in sensors {
        let s = &p.scene.sensors[si];
        let cam = Camera::from_sensor(s);
        let img: Vec<Vec3> = render_view(&p.accel, &cam, &textures, k)
            .into_iter()
            .map(|v| v.unwrap_or(Vec3::ZERO))
            .collect();
        let f = dir.join(format!("{}.exr", s.id));
        write_exr_rgb(&f, s.width, s.height, &img, false).unwrap();
        cfg.views.insert(s.id.clone(), f);
    }
    cfg
}

fn reprojection_error(scene_dir: &str, cfg: &Config) -> Vec<(String, f64, usize)> {
    let root = fixture(scene_dir);
    let out = tempfile::tempdir().unwrap();
    let (p, stats) = run_projection(cfg, out.path(), Mode::Quiet).unwrap();
    assert!(stats.views >= 1);
    assert!(
        stats.observed_texels > stats.covered_texels / 2,
        "{stats:?}"
    );

    if let Ok(keep) = std::env::var("KDMAP_KEEP") {
        std::fs::create_dir_all(&keep).unwrap();
        for e in std::fs::read_dir(out.path().join("maps")).unwrap() {
            let e = e.unwrap();
            std::fs::copy(e.path(), Path::new(&keep).join(e.file_name())).unwrap();
        }
    }
    // Read the written maps back, as a user would.
    let mut maps = Vec::new();
    for st in &p.layout.slots {
        let id = &p.scene.shapes[st.shape].id;
        let img = read_exr(out.path().join("maps").join(format!("{id}_luminance.exr"))).unwrap();
        assert_eq!((img.width, img.height), (st.width, st.height));
        assert!(out
            .path()
            .join("maps")
            .join(format!("{id}_luminance.png"))
            .is_file());
        assert!(out
            .path()
            .join("maps")
            .join(format!("{id}_coverage.exr"))
            .is_file());
        maps.push((st.shape, img));
    }
    let mut textures: Vec<Option<Texture>> = (0..p.scene.shapes.len()).map(|_| None).collect();
    for (shape, img) in &maps {
        textures[*shape] = Some(Texture {
            width: img.width,
            height: img.height,
            texels: &img.pixels,
            corner_uv: &p.atlases[*shape].as_ref().unwrap().corner_uv,
        });
    }

    let mut res = Vec::new();
    let eval: Vec<(usize, PathBuf)> = if std::env::var("KDMAP_EVAL_ALL").is_ok() {
        (0..3)
            .map(|i| (i, root.join(format!("images/cam_train_{i}.exr"))))
            .collect()
    } else {
        p.views.clone()
    };
    let render_k: u32 = std::env::var("KDMAP_RENDER_K")
        .map(|v| v.parse().unwrap())
        .unwrap_or(4);
    for (si, path) in &eval {
        let sensor = &p.scene.sensors[*si];
        let photo: Image = read_sensor_image(path, sensor).unwrap();
        let cam = Camera::from_sensor(sensor);
        let view = View::new(&p.scene, &p.accel, cam.clone(), &photo);
        let mut render = render_view(&p.accel, &cam, &textures, render_k);
        if std::env::var("KDMAP_DIRECT").is_ok() {
            for y in 0..photo.height {
                for x in 0..photo.width {
                    let i = (y * photo.width + x) as usize;
                    let pi = view.pixels[i];
                    let mut s = Vec3::ZERO;
                    let mut c = 0;
                    for j in 0..4 {
                        for k in 0..4 {
                            let pix = glam::Vec2::new(
                                x as f32 + (k as f32 + 0.5) / 4.0,
                                y as f32 + (j as f32 + 0.5) / 4.0,
                            );
                            if let Some(v) = view.sample(pix, pi.shape, pi.normal) {
                                s += v;
                                c += 1;
                            }
                        }
                    }
                    render[i] = (c > 0).then(|| s / c as f32);
                }
            }
        }
        let (w, h) = (photo.width as i64, photo.height as i64);
        let clean = |x: i64, y: i64| {
            x >= 0 && y >= 0 && x < w && y < h && view.pixels[(y * w + x) as usize].clean
        };
        // Per-pixel residuals are dominated by the photo's Monte Carlo noise (about 2% per
        // pixel at 1024 spp, white: see the error image), so compare means over B x B blocks
        // of usable pixels; the per-pixel figure is printed for reference.
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
        eprintln!(
            "{scene_dir} {}: per-pixel mean relative difference {:.3}% (photo noise included)",
            sensor.id,
            100.0 * px_sum / px_n.max(1) as f64
        );
        if std::env::var("KDMAP_SIGNED").is_ok() {
            for i in 0..(w * h) as usize {
                let (x, y) = (i as i64 % w, i as i64 / w);
                diff[i] = match usable(x, y) {
                    Some((r, q)) if q > 1e-4 => {
                        let e = ((r - q) / q) as f32 * 5.0;
                        Vec3::new(e.max(0.0), (-e).max(0.0), 0.0)
                    }
                    _ => Vec3::new(0.0, 0.0, 0.2),
                };
            }
        }
        let mean = sum / n.max(1) as f64;
        if mean >= 0.01 || std::env::var("KDMAP_PNG").is_ok() {
            let dir = std::env::var("CARGO_TARGET_TMPDIR").unwrap_or_else(|_| ".".into());
            let f = Path::new(&dir).join(format!("reproj_{scene_dir}_{}.png", sensor.id));
            write_png_srgb(&f, w as u32, h as u32, &diff, 0.0).unwrap();
            eprintln!("wrote the error image (x10) to {}", f.display());
        }
        res.push((sensor.id.clone(), mean, n));
    }
    res
}

fn check_with(scene: &str, cfg: &Config) {
    let res = reprojection_error(scene, cfg);
    for (id, mean, n) in &res {
        eprintln!(
            "{scene} {id}: mean relative difference of 8x8 block means {:.4}% over {n} blocks",
            100.0 * mean
        );
    }
    for (id, mean, n) in res {
        assert!(n > 350, "{scene} {id}: only {n} blocks compared");
        assert!(
            mean < 0.01,
            "{scene} {id}: mean relative difference {:.3}% >= 1%",
            100.0 * mean
        );
    }
}

fn check(scene: &str) {
    check_with(scene, &config(&fixture(scene)));
}

#[test]
fn luminance_map_reprojects_to_the_photos_cbox() {
    check("cbox");
}

/// Not met yet: on the textured walls the three views disagree by 1.4-1.6% (8x8 block means,
/// strongest on the ceiling seen at grazing angles and on the right wall), so a map averaged
/// over views cannot give back each photo to 1%. Kept so the figure is one command away:
/// `cargo test --test projection -- --ignored --nocapture`.
#[test]
#[ignore = "cbox-tex re-projection is 1.4-1.6%, above the 1% target (issue 3 stays open)"]
fn luminance_map_reprojects_to_the_photos_cbox_tex() {
    check("cbox-tex");
}

/// Diagnostic: noise-free synthetic photos (radiance = true albedo, exact box filter).
#[test]
#[ignore]
fn synthetic_cbox_tex() {
    let dir = tempfile::tempdir().unwrap();
    let k = std::env::var("KDMAP_SYNTH_K")
        .map(|v| v.parse().unwrap())
        .unwrap_or(8);
    let cfg = synthetic_photos(&fixture("cbox-tex"), dir.path(), k);
    check_with("cbox-tex", &cfg);
}
