//! The output directory (`docs/contract.md`) checked end to end on the Cornell box: the real
//! projection gives L_orig, then a synthetic but exactly consistent solver state
//! (known K_d per shape, E_d + E_i = pi L_orig / K_d) goes through `write_outputs`, and every
//! file is read back and compared with what it must hold.

use glam::{Vec2, Vec3};
use kdmap::atlas::store::TileStore;
use kdmap::atlas::store::{flags, TexelGeom, TexelState};
use kdmap::atlas::texture::read_slot;
use kdmap::atlas::texture::Scratch;
use kdmap::atlas::{state_dir, RunContext};
use kdmap::base::progress::{no_tick, Mode};
use kdmap::config::Config;
use kdmap::image::{read_exr, read_sensor_image};
use kdmap::output::renders::xy_chromaticity;
use kdmap::output::write_outputs;
use kdmap::physics::camera::Camera;
use kdmap::pipeline::run_projection;
use kdmap::report::{IterationStats, Report};
use kdmap::scene::{luminance, mitsuba, Emitter};
use kdmap::stages::project::View;
use std::f32::consts::PI;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The albedo each shape is given (the truth on the coloured walls).
fn k_d_of(id: &str) -> Vec3 {
    match id {
        "left" => Vec3::new(0.63, 0.065, 0.05),
        "right" => Vec3::new(0.14, 0.45, 0.091),
        "floor" => Vec3::new(0.5, 0.5, 0.5),
        _ => Vec3::new(0.725, 0.71, 0.68),
    }
}

/// A synthetic relative error per texel, so the error map has something to show.
fn error_of(x: u32, y: u32) -> f32 {
    0.0005 * ((x + 2 * y) % 50) as f32
}

struct Run {
    _dir: tempfile::TempDir,
    out: PathBuf,
    p: RunContext,
    geom: TileStore<TexelGeom>,
    state: TileStore<TexelState>,
    report: Report,
}

/// Project the cbox photos, make the state consistent, write the outputs: once for all tests.
fn run() -> &'static Run {
    static RUN: OnceLock<Run> = OnceLock::new();
    RUN.get_or_init(|| {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/cbox");
        let mut cfg = Config::for_scene(root.join("input.xml"));
        cfg.atlas.texels_per_unit = kdmap::config::Density::PerUnit(32.0);
        let dir = tempfile::tempdir().unwrap();
        let proj = dir.path().join("proj");
        let (p, _) = run_projection(&cfg, &proj, Mode::Quiet).unwrap();
        let geom = TileStore::<TexelGeom>::open(state_dir(&proj).join("geometry.tiles")).unwrap();
        let mut state =
            TileStore::<TexelState>::open(state_dir(&proj).join("state.tiles")).unwrap();
        for t in 0..p.layout.tile_count as usize {
            let g = geom.read_tile(t).unwrap();
            let mut st = state.read_tile(t).unwrap();
            for (off, (g, s)) in g.iter().zip(st.iter_mut()).enumerate() {
                let Some((slot, x, y)) = p.layout.texel_of(t as u32, off as u32) else {
                    continue;
                };
                if !g.covered() {
                    continue;
                }
                let kd = k_d_of(&p.scene.shapes[p.layout.slots[slot].shape].id);
                s.k_d = kd.to_array();
                s.flags |= flags::COVERED;
                if s.flags & flags::OBSERVED != 0 {
                    let e = Vec3::from_array(s.l_orig) * PI / kd;
                    s.e_d = (e * 0.75).to_array();
                    s.e_i = (e * 0.25).to_array();
                    s.error = error_of(x, y);
                } else {
                    s.e_d = [1.0, 1.5, 2.0];
                    s.e_i = [0.5; 3];
                    s.flags |= flags::FILLED;
                }
            }
            state.write_tile(t, &st).unwrap();
        }
        let mut report = Report::new(cfg.clone());
        report.stopped_by = "max_iterations".into();
        report.iterations = (0..4)
            .map(|i| IterationStats {
                iteration: i,
                rms_rel_error: 0.1 / 4f64.powi(i as i32),
                mean_rel_error: 0.07 / 4f64.powi(i as i32),
                max_rel_error: 0.5 / 3f64.powi(i as i32),
                ..Default::default()
            })
            .collect();
        // KDMAP_OUTPUT_DIR=<dir> keeps the written directory for a look (and for
        // tools/check_scene_mitsuba.py).
        let out = std::env::var_os("KDMAP_OUTPUT_DIR")
            .map(PathBuf::from)
            .unwrap_or_else(|| dir.path().join("out"));
        let charts = kdmap::atlas::uv::Charts::new(&p.scene, &p.layout, &p.atlases).unwrap();
        let hits = kdmap::atlas::context::HitTable::new(&p, &charts);
        let scratch = Scratch::new(dir.path(), 1 << 28);
        write_outputs(
            &p,
            &hits,
            (&geom, &state),
            &mut report,
            &out,
            &scratch,
            &no_tick,
        )
        .unwrap();
        Run {
            _dir: dir,
            out,
            p,
            geom,
            state,
            report,
        }
    })
}

fn recon_ids(p: &RunContext) -> Vec<String> {
    p.layout
        .slots
        .iter()
        .map(|s| p.scene.shapes[s.shape].id.clone())
        .collect()
}

#[test]
fn every_contract_file_exists() {
    let r = run();
    let mut want = vec![
        "scene.xml".to_string(),
        "report.json".into(),
        "report_convergence.png".into(),
        "report_convergence.svg".into(),
    ];
    for id in recon_ids(&r.p) {
        for f in [
            format!("textures/{id}_albedo.exr"),
            format!("textures/{id}_albedo.png"),
            format!("maps/{id}_error.exr"),
            format!("maps/{id}_error.png"),
            format!("maps/{id}_colorless.exr"),
            format!("maps/{id}_coverage.exr"),
            format!("maps/{id}_direct.exr"),
            format!("maps/{id}_indirect.exr"),
            format!("maps/{id}_luminance.exr"),
            format!("maps/{id}_kd_stderr.exr"),
            format!("maps/{id}_kd_stderr.png"),
            format!("maps/{id}_disagreement.exr"),
            format!("maps/{id}_disagreement.png"),
            format!("meshes/{id}.obj"),
            format!("meshes/{id}.mtl"),
        ] {
            want.push(f);
        }
    }
    want.push("meshes/light.obj".into());
    for (si, _) in &r.p.views {
        let id = &r.p.scene.sensors[*si].id;
        want.push(format!("renders/{id}.exr"));
        want.push(format!("renders/{id}.png"));
        want.push(format!("renders/{id}_compare.png"));
        want.push(format!("renders/{id}_mask.png"));
    }
    want.push("renders/masks.json".into());
    for f in &want {
        assert!(r.out.join(f).is_file(), "missing {f}");
    }
    // nothing left half-written
    for d in ["", "textures", "maps", "renders", "meshes"] {
        for e in std::fs::read_dir(r.out.join(d)).unwrap() {
            let name = e.unwrap().file_name().to_string_lossy().to_string();
            assert!(!name.ends_with(".tmp"), "{d}/{name}");
        }
    }
}

/// Per slot: (state records in texture order, covered mask).
fn texture_state(r: &Run, slot: usize) -> (Vec<TexelState>, Vec<bool>) {
    read_slot(&r.p.layout, slot, &r.state, &r.geom, |s, g| {
        (*s, g.covered())
    })
    .unwrap()
    .into_iter()
    .unzip()
}

#[test]
fn maps_hold_the_state_and_eq_10() {
    let r = run();
    for (slot, id) in recon_ids(&r.p).iter().enumerate() {
        let (recs, cov) = texture_state(r, slot);
        let st = r.p.layout.slots[slot];
        let read = |name: &str| {
            let img = read_exr(r.out.join(name)).unwrap();
            assert_eq!((img.width, img.height), (st.width, st.height), "{name}");
            img.pixels
        };
        let albedo = read(&format!("textures/{id}_albedo.exr"));
        let colorless = read(&format!("maps/{id}_colorless.exr"));
        let error = read(&format!("maps/{id}_error.exr"));
        let coverage = read(&format!("maps/{id}_coverage.exr"));
        let direct = read(&format!("maps/{id}_direct.exr"));
        let indirect = read(&format!("maps/{id}_indirect.exr"));
        let lum = read(&format!("maps/{id}_luminance.exr"));
        let stderr = read(&format!("maps/{id}_kd_stderr.exr"));
        let disagree = read(&format!("maps/{id}_disagreement.exr"));
        let (mut n, mut estimated) = (0, 0);
        for (i, s) in recs.iter().enumerate() {
            if !cov[i] {
                continue;
            }
            n += 1;
            let kd = Vec3::from_array(s.k_d);
            assert_eq!(albedo[i], kd, "{id} texel {i}");
            assert_eq!(kd, k_d_of(id));
            assert_eq!(direct[i], Vec3::from_array(s.e_d));
            assert_eq!(indirect[i], Vec3::from_array(s.e_i));
            assert_eq!(coverage[i], Vec3::splat(s.weight));
            assert_colorless_is_eq_10(s, colorless[i], &format!("{id} texel {i}"));
            if s.flags & flags::OBSERVED != 0 {
                assert_eq!(error[i], Vec3::splat(s.error));
                assert_eq!(lum[i], Vec3::from_array(s.l_orig));
                assert!(s.weight > 0.0);
                assert_eq!(disagree[i], Vec3::splat(s.disagree));
                estimated +=
                    assert_stderr_adds_relative_variances(s, stderr[i], &format!("{id} texel {i}"))
                        as usize;
            } else {
                assert_eq!(error[i], Vec3::ZERO, "unobserved texels have no error");
                assert_eq!(coverage[i], Vec3::ZERO);
            }
        }
        assert!(n > 0, "{id} has covered texels");
        assert!(estimated > 0, "{id}: no texel has a standard error");
        assert_gutter_dilated(&albedo, &cov, (st.width, st.height), id);
        // The error preview is larger than the map: the legend bar sits under it, its labels
        // at the bottom.
        let png = std::fs::read(r.out.join(format!("maps/{id}_error.png"))).unwrap();
        let pm = tiny_skia::Pixmap::decode_png(&png).unwrap();
        assert!(pm.height() > st.height && pm.width() >= st.width);
        let labels = text_pixels(&pm, 0..pm.width(), pm.height() - 30..pm.height());
        assert!(labels > 100, "{id}: {labels} legend text pixels");
    }
}

/// Eq. (10) by hand, in double precision: the colorless luminance is the re-rendered radiance
/// over each channel's share of `K_d`.
fn assert_colorless_is_eq_10(s: &TexelState, colorless: Vec3, what: &str) {
    let l_render: Vec<f64> = (0..3)
        .map(|c| s.k_d[c] as f64 / std::f64::consts::PI * (s.e_d[c] + s.e_i[c]) as f64)
        .collect();
    let sum: f64 = s.k_d.iter().map(|&k| k as f64).sum();
    for c in 0..3 {
        let want = l_render[c] / (s.k_d[c] as f64 / sum);
        let got = colorless[c] as f64;
        assert!(
            (got - want).abs() <= 1e-5 * want.abs().max(1e-6),
            "{what} channel {c}: {got} vs {want}"
        );
    }
}

/// The standard error of `K_d` adds the relative variances of L and E (luminance), in double
/// precision; returns whether the texel has an estimate (no light or no luminance: none, 0).
fn assert_stderr_adds_relative_variances(s: &TexelState, stderr: Vec3, what: &str) -> bool {
    let y = |v: [f32; 3]| 0.2126 * v[0] as f64 + 0.7152 * v[1] as f64 + 0.0722 * v[2] as f64;
    let e = [
        s.e_d[0] + s.e_i[0],
        s.e_d[1] + s.e_i[1],
        s.e_d[2] + s.e_i[2],
    ];
    let (yl, ye) = (y(s.l_orig), y(e));
    let rel = match yl > 0.0 && ye > 0.0 {
        true => (s.l_var as f64 / (yl * yl) + s.e_var as f64 / (ye * ye)).sqrt(),
        false => 0.0,
    };
    for (c, got) in stderr.to_array().into_iter().enumerate() {
        let (want, got) = (s.k_d[c] as f64 * rel, got as f64);
        let ok = (got - want).abs() <= 1e-4 * want + 1e-7;
        assert!(ok, "{what}: {got} vs {want}");
    }
    rel > 0.0
}

/// Gutter next to the charts is dilated: every texel with a covered 8-neighbour holds an
/// albedo, never the black background.
fn assert_gutter_dilated(albedo: &[Vec3], cov: &[bool], (w, h): (u32, u32), id: &str) {
    let (w, h) = (w as i64, h as i64);
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let near = (-1..=1).any(|dy: i64| {
                (-1..=1).any(|dx: i64| {
                    let (nx, ny) = (x + dx, y + dy);
                    nx >= 0 && ny >= 0 && nx < w && ny < h && cov[(ny * w + nx) as usize]
                })
            });
            if near {
                assert!(
                    albedo[i].min_element() > 0.0,
                    "{id} gutter texel ({x}, {y})"
                );
            }
        }
    }
}

/// Pixels of light grey text (the labels' colour, anti-aliased on a dark background) in the
/// given columns and rows: no viridis colour is grey, and the "no data" grey is darker.
fn text_pixels(
    pm: &tiny_skia::Pixmap,
    xs: std::ops::Range<u32>,
    ys: std::ops::Range<u32>,
) -> usize {
    ys.flat_map(|y| xs.clone().map(move |x| (x, y)))
        .filter(|&(x, y)| {
            let p = pm.pixel(x, y).unwrap();
            p.red() > 100 && p.red() == p.green() && p.green() == p.blue()
        })
        .count()
}

#[test]
fn compare_images_have_panel_titles_and_the_legend_under_the_error() {
    let r = run();
    for (si, _) in &r.p.views {
        let s = &r.p.scene.sensors[*si];
        let path = r.out.join(format!("renders/{}_compare.png", s.id));
        let pm = tiny_skia::Pixmap::load_png(&path).unwrap();
        assert_eq!(pm.width(), 3 * s.width + 8);
        let title_rows = 0..12;
        for k in 0..3 {
            let cols = k * (s.width + 4)..k * (s.width + 4) + s.width;
            assert!(text_pixels(&pm, cols, title_rows.clone()) > 20, "title {k}");
        }
        let bottom = pm.height() - 30..pm.height();
        let under_error = text_pixels(&pm, 2 * (s.width + 4)..pm.width(), bottom.clone());
        assert!(under_error > 100, "{under_error} legend text pixels");
        assert_eq!(text_pixels(&pm, 0..2 * s.width, bottom), 0);
    }
}

#[test]
fn the_convergence_chart_is_svg_text_and_a_png() {
    let r = run();
    let svg = std::fs::read_to_string(r.out.join("report_convergence.svg")).unwrap();
    let texts: Vec<&str> = svg.lines().map(str::trim).collect();
    for t in ["RMS", "mean", "max", "iteration", "10%", "1%"] {
        assert!(texts.contains(&t), "no text {t:?} in the SVG");
    }
    let pm = tiny_skia::Pixmap::load_png(r.out.join("report_convergence.png")).unwrap();
    assert_eq!((pm.width(), pm.height()), (800, 500));
}

#[test]
fn rerender_of_a_consistent_state_gives_back_the_photos() {
    let r = run();
    let p = &r.p;
    let back = p.scene.shapes.iter().position(|s| s.id == "back").unwrap() as u32;
    for (si, path) in &p.views {
        let sensor = &p.scene.sensors[*si];
        let photo = read_sensor_image(path, sensor).unwrap();
        let render = read_exr(r.out.join(format!("renders/{}.exr", sensor.id))).unwrap();
        let view = View::new(&p.scene, &p.accel, Camera::from_sensor(sensor), &photo);
        let (w, h) = (photo.width as i64, photo.height as i64);
        let on_back = |x: i64, y: i64| {
            x >= 0 && y >= 0 && x < w && y < h && {
                let px = &view.pixels[(y * w + x) as usize];
                px.clean && px.shape == back
            }
        };
        // As tests/it/projection.rs: means over 8x8 blocks of pixels inside the back wall
        // (photo noise is ~2% per pixel).
        const B: i64 = 8;
        let (mut sum, mut n) = (0.0f64, 0usize);
        for by in 0..h / B {
            for bx in 0..w / B {
                let inside = (by * B - 1..=(by + 1) * B)
                    .all(|y| (bx * B - 1..=(bx + 1) * B).all(|x| on_back(x, y)));
                if !inside {
                    continue;
                }
                let (mut a, mut b) = (0.0f64, 0.0f64);
                for y in by * B..(by + 1) * B {
                    for x in bx * B..(bx + 1) * B {
                        let i = (y * w + x) as usize;
                        a += luminance(render.pixels[i]) as f64;
                        b += luminance(photo.pixels[i]) as f64;
                    }
                }
                sum += (a - b).abs() / b;
                n += 1;
            }
        }
        let mean = sum / n.max(1) as f64;
        eprintln!(
            "{}: back wall, mean relative difference of 8x8 block means {:.3}% over {n} blocks",
            sensor.id,
            100.0 * mean
        );
        assert!(n >= 100, "{}: only {n} blocks", sensor.id);
        assert!(mean < 0.01, "{}: {:.3}%", sensor.id, 100.0 * mean);

        // The table row agrees: mean luminance and chromaticity of the back wall.
        let row = r
            .report
            .table
            .iter()
            .find(|row| row.view == sensor.id && row.shape == "back")
            .expect("a table row for the back wall");
        let [yo, yr] = row.mean_luminance;
        assert!((yr - yo).abs() / yo < 0.005, "{row:?}");
        for k in 0..2 {
            assert!((row.xy[0][k] - row.xy[1][k]).abs() < 2e-3, "{row:?}");
        }
        // Pixels wholly on the light keep the photo's value.
        let light = p.scene.shapes.iter().position(|s| s.id == "light").unwrap() as u32;
        for (i, px) in view.pixels.iter().enumerate() {
            if px.clean && px.shape == light {
                assert_eq!(render.pixels[i], photo.pixels[i]);
            }
        }
    }
}

#[test]
fn report_json_has_the_table_with_consistent_chromaticities() {
    let r = run();
    let text = std::fs::read_to_string(r.out.join("report.json")).unwrap();
    let back: Report = serde_json::from_str(&text).unwrap();
    // serde_json's default float parsing may differ in the last bit: compare with a tolerance.
    assert_eq!(back.table.len(), r.report.table.len());
    assert_eq!(back.iterations.len(), r.report.iterations.len());
    let near = |a: f64, b: f64| (a - b).abs() <= 1e-12 * a.abs().max(b.abs()).max(1e-300);
    for (a, b) in back.table.iter().zip(&r.report.table) {
        assert_eq!((&a.view, &a.shape, a.pixels), (&b.view, &b.shape, b.pixels));
        for k in 0..2 {
            assert!(near(a.mean_luminance[k], b.mean_luminance[k]));
            assert!(near(a.std_luminance[k], b.std_luminance[k]));
            assert!((0..3).all(|c| near(a.mean_rgb[k][c], b.mean_rgb[k][c])));
            assert!((0..2).all(|c| near(a.xy[k][c], b.xy[k][c])));
        }
    }
    assert!(back.timings.output > 0.0);
    // every view sees the back wall, the left and right walls
    for (si, _) in &r.p.views {
        let v = &r.p.scene.sensors[*si].id;
        for shape in ["back", "left", "right"] {
            assert!(
                back.table
                    .iter()
                    .any(|row| &row.view == v && row.shape == shape),
                "{v}/{shape}"
            );
        }
    }
    for row in &back.table {
        assert!(row.pixels > 0 && row.shape != "light");
        for k in 0..2 {
            let xy = xy_chromaticity(row.mean_rgb[k]);
            assert!(
                (0..2).all(|c| (row.xy[k][c] - xy[c]).abs() < 1e-12),
                "{row:?}"
            );
            let y = 0.2126 * row.mean_rgb[k][0]
                + 0.7152 * row.mean_rgb[k][1]
                + 0.0722 * row.mean_rgb[k][2];
            assert!(
                (y - row.mean_luminance[k]).abs() <= 1e-6 * y.max(1e-9),
                "{row:?}"
            );
            assert!(row.std_luminance[k] >= 0.0);
        }
    }
    // the red wall is red, the green wall green
    let left = back.table.iter().find(|r| r.shape == "left").unwrap();
    assert!(left.xy[0][0] > 0.45, "{left:?}");
    let right = back.table.iter().find(|r| r.shape == "right").unwrap();
    assert!(right.xy[0][1] > 0.45, "{right:?}");
    // pure grey -> D65 white
    let [x, y] = xy_chromaticity([0.37; 3]);
    assert!(
        (x - 0.3127).abs() < 1e-4 && (y - 0.3290).abs() < 1e-4,
        "{x} {y}"
    );
}

#[test]
fn scene_xml_round_trips_through_the_loader() {
    let r = run();
    let a = &r.p.scene;
    let xml = r.out.join("scene.xml");
    let b = mitsuba::load(&xml).unwrap();
    let close = |x: Vec3, y: Vec3| (x - y).abs().max_element() <= 1e-5;
    assert_eq!(a.shapes.len(), b.shapes.len());
    for (s, t) in a.shapes.iter().zip(&b.shapes) {
        assert_eq!(s.id, t.id);
        assert_eq!(s.sides, t.sides);
        assert_eq!(s.emission, t.emission);
        assert_eq!(s.mesh.triangles.len(), t.mesh.triangles.len());
        for tri in 0..s.mesh.triangles.len() {
            let (p, q) = (s.mesh.triangle(tri), t.mesh.triangle(tri));
            assert!((0..3).all(|c| close(p[c], q[c])), "{} {tri}", s.id);
            assert!(close(
                s.mesh.shading_normal(tri, 0.3, 0.3),
                t.mesh.shading_normal(tri, 0.3, 0.3)
            ));
        }
    }
    assert_eq!(a.sensors.len(), b.sensors.len());
    for (s, t) in a.sensors.iter().zip(&b.sensors) {
        assert_eq!(
            (&s.id, s.fov_axis, s.width, s.height),
            (&t.id, t.fov_axis, t.width, t.height)
        );
        assert!((s.fov - t.fov).abs() <= 1e-5);
        assert!(s.to_world.abs_diff_eq(t.to_world, 1e-5), "{}", s.id);
    }
    assert_eq!(a.emitters.len(), b.emitters.len());
    match (&a.emitters[0], &b.emitters[0]) {
        (
            Emitter::Area {
                shape: i,
                radiance: x,
            },
            Emitter::Area {
                shape: j,
                radiance: y,
            },
        ) => assert!(i == j && close(*x, *y)),
        e => panic!("{e:?}"),
    }
    // Every file the scene names exists, relative to it; albedo textures are raw bitmaps.
    let text = std::fs::read_to_string(&xml).unwrap();
    let doc = roxmltree_lite_filenames(&text);
    assert!(!doc.is_empty());
    for f in doc {
        assert!(r.out.join(&f).is_file(), "scene.xml names missing {f}");
    }
    for id in recon_ids(&r.p) {
        assert!(text.contains(&format!(
            "<string name=\"filename\" value=\"textures/{id}_albedo.exr\"/><boolean name=\"raw\" value=\"true\"/>"
        )));
    }
}

/// The `filename` values in an XML text (enough for our own output).
fn roxmltree_lite_filenames(text: &str) -> Vec<String> {
    let key = "name=\"filename\" value=\"";
    text.match_indices(key)
        .map(|(i, _)| {
            let rest = &text[i + key.len()..];
            rest[..rest.find('"').unwrap()].to_string()
        })
        .collect()
}

#[test]
fn obj_uvs_map_corners_back_to_their_texels() {
    let r = run();
    for st in &r.p.layout.slots {
        let shape = &r.p.scene.shapes[st.shape];
        let atlas = r.p.atlases[st.shape].as_ref().unwrap();
        let text = std::fs::read_to_string(r.out.join(format!("meshes/{}.obj", shape.id))).unwrap();
        let nums = |l: &str| -> Vec<f32> {
            l.split_whitespace()
                .skip(1)
                .map(|v| v.parse().unwrap())
                .collect()
        };
        let v: Vec<Vec3> = text
            .lines()
            .filter(|l| l.starts_with("v "))
            .map(|l| Vec3::from_slice(&nums(l)))
            .collect();
        let vt: Vec<Vec2> = text
            .lines()
            .filter(|l| l.starts_with("vt "))
            .map(|l| Vec2::from_slice(&nums(l)))
            .collect();
        assert!(text.contains(&format!("mtllib {}.mtl", shape.id)));
        let faces: Vec<&str> = text.lines().filter(|l| l.starts_with("f ")).collect();
        assert_eq!(faces.len(), shape.mesh.triangles.len());
        assert_eq!(
            v, shape.mesh.positions,
            "{}: positions written exactly",
            shape.id
        );
        for uv in &vt {
            assert!(
                (0.0..=1.0).contains(&uv.x) && (0.0..=1.0).contains(&uv.y),
                "{uv}"
            );
        }
        for (t, f) in faces.iter().enumerate() {
            for (c, corner) in f.split_whitespace().skip(1).enumerate() {
                let idx: Vec<usize> = corner.split('/').map(|s| s.parse().unwrap()).collect();
                assert_eq!(idx[0] as u32 - 1, shape.mesh.triangles[t][c]);
                let uv = vt[idx[1] - 1];
                let texel = Vec2::new(
                    uv.x * atlas.width as f32,
                    (1.0 - uv.y) * atlas.height as f32,
                );
                let want = atlas.corner_uv[t][c];
                assert!(
                    (texel - want).abs().max_element() < 1e-3,
                    "{} triangle {t} corner {c}: {texel} vs {want}",
                    shape.id
                );
            }
        }
        let mtl = std::fs::read_to_string(r.out.join(format!("meshes/{}.mtl", shape.id))).unwrap();
        let map = mtl.lines().find_map(|l| l.strip_prefix("map_Kd ")).unwrap();
        assert!(r.out.join("meshes").join(map).is_file(), "{map}");
    }
}

/// The table masks name exactly the pixels of the paper's table: per view, the pixel count of
/// each mask value equals the `pixels` of that shape's table row, and `masks.json` lists the
/// scene's shapes in order.
#[test]
fn table_masks_match_the_table_rows() {
    let r = run();
    let text = std::fs::read_to_string(r.out.join("renders/masks.json")).unwrap();
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let ids: Vec<String> = v["shapes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s.as_str().unwrap().to_string())
        .collect();
    let scene_ids: Vec<String> = r.p.scene.shapes.iter().map(|s| s.id.clone()).collect();
    assert_eq!(ids, scene_ids);
    assert!(!r.report.table.is_empty());
    for (si, _) in &r.p.views {
        let view = &r.p.scene.sensors[*si].id;
        let pm =
            tiny_skia::Pixmap::load_png(r.out.join(format!("renders/{view}_mask.png"))).unwrap();
        let mut counts = vec![0u64; 256];
        for px in pm.pixels() {
            counts[px.red() as usize] += 1;
        }
        let rows: Vec<_> = r.report.table.iter().filter(|t| &t.view == view).collect();
        assert!(!rows.is_empty(), "{view}");
        for row in &rows {
            let k = 1 + ids.iter().position(|i| *i == row.shape).unwrap();
            assert_eq!(counts[k], row.pixels, "{view} {}", row.shape);
        }
        let in_rows: u64 = rows.iter().map(|t| t.pixels).sum();
        assert_eq!(counts[1..].iter().sum::<u64>(), in_rows, "{view}");
    }
}

/// `scene.glb` opens with the `gltf` crate (which validates it), holds every shape's world
/// geometry, and its embedded albedo PNG, looked up at each triangle's centroid UV, is the
/// recovered K_d (8-bit sRGB: within one code value).
#[test]
fn scene_glb_holds_the_geometry_uvs_and_recovered_albedo() {
    let r = run();
    let bytes = std::fs::read(r.out.join("scene.glb")).unwrap();
    let g = gltf::Gltf::from_slice(&bytes).unwrap();
    let blob = g.blob.clone().unwrap();
    let srgb = |v: f32| {
        let v = v.clamp(0.0, 1.0);
        if v <= 0.003_130_8 {
            12.92 * v
        } else {
            1.055 * v.powf(1.0 / 2.4) - 0.055
        }
    };
    let mut textured = 0;
    for mesh in g.meshes() {
        let id = mesh.name().unwrap();
        let shape = r.p.scene.shapes.iter().find(|s| s.id == id).unwrap();
        let prim = mesh.primitives().next().unwrap();
        let rd = prim.reader(|_| Some(&blob[..]));
        let pos: Vec<Vec3> = rd.read_positions().unwrap().map(Vec3::from).collect();
        assert_eq!(pos.len(), 3 * shape.mesh.triangles.len(), "{id}");
        for (t, tri) in shape.mesh.triangles.iter().enumerate() {
            for c in 0..3 {
                assert_eq!(
                    pos[3 * t + c],
                    shape.mesh.positions[tri[c] as usize],
                    "{id}"
                );
            }
        }
        let Some(info) = prim
            .material()
            .pbr_metallic_roughness()
            .base_color_texture()
        else {
            assert!(!shape.is_reconstructed(), "{id} has no texture");
            continue;
        };
        textured += 1;
        let gltf::image::Source::View { view, .. } = info.texture().source().source() else {
            panic!("{id}: texture not embedded")
        };
        let png = &blob[view.offset()..view.offset() + view.length()];
        let pm = tiny_skia::Pixmap::decode_png(png).unwrap();
        let uv: Vec<Vec2> = rd
            .read_tex_coords(0)
            .unwrap()
            .into_f32()
            .map(Vec2::from)
            .collect();
        let want = k_d_of(id);
        for t in 0..shape.mesh.triangles.len() {
            let c = (uv[3 * t] + uv[3 * t + 1] + uv[3 * t + 2]) / 3.0;
            let (x, y) = (
                (c.x * pm.width() as f32) as u32,
                (c.y * pm.height() as f32) as u32,
            );
            let px = pm.pixel(x, y).unwrap();
            let got = [px.red(), px.green(), px.blue()];
            for k in 0..3 {
                let w = srgb(want[k]) * 255.0;
                assert!(
                    (got[k] as f32 - w).abs() <= 1.0,
                    "{id} triangle {t}: {got:?} vs {want}"
                );
            }
        }
    }
    assert_eq!(textured, recon_ids(&r.p).len());
    assert_eq!(g.cameras().count(), r.p.scene.sensors.len());
}

/// The `src` and `href` values of an HTML page, in order.
fn page_links(html: &str) -> Vec<String> {
    let mut v = Vec::new();
    for attr in ["src=\"", "href=\""] {
        for part in html.split(attr).skip(1) {
            v.push(part.split('"').next().unwrap().replace("&amp;", "&"));
        }
    }
    v
}

/// Every file a page links to exists beside it, none is on the network, and every image a
/// user would look for (albedo, map previews, re-renders, comparisons) is on the page.
fn assert_page_links_files(out: &Path, want: &[String]) {
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    let links = page_links(&html);
    for l in &links {
        assert!(!l.contains("://"), "a link off the machine: {l}");
        let file = l.split('#').next().unwrap();
        if !file.is_empty() {
            assert!(
                out.join(file).is_file(),
                "the page links to a missing {file}"
            );
        }
    }
    for w in want {
        assert!(links.contains(w), "the page does not show {w}");
    }
}

/// Image files under `out/sub` whose names end in `suffix`, as page links.
fn pngs(out: &Path, sub: &str, suffix: &str) -> Vec<String> {
    std::fs::read_dir(out.join(sub))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(suffix) && !n.ends_with("_mask.png"))
        .map(|n| format!("{sub}/{n}"))
        .collect()
}

#[test]
fn the_report_page_shows_every_image_and_links_only_files_that_exist() {
    let r = run();
    let mut want = pngs(&r.out, "textures", ".png");
    want.extend(pngs(&r.out, "maps", ".png"));
    want.extend(pngs(&r.out, "renders", ".png"));
    assert!(want.len() > 20, "{want:?}");
    assert_page_links_files(&r.out, &want);
    // each view's photo, error panel and values; the 3D view holds exactly scene.glb
    for (si, _) in &r.p.views {
        let id = &r.p.scene.sensors[*si].id;
        for f in [
            format!("{id}_photo.png"),
            format!("{id}_error.png"),
            format!("{id}.js"),
        ] {
            assert!(r.out.join("report/views").join(&f).is_file(), "{f}");
        }
    }
    let js = std::fs::read_to_string(r.out.join("report/scene_glb.js")).unwrap();
    let b64 = js.split('"').nth(1).unwrap();
    use base64::Engine as _;
    let glb = base64::engine::general_purpose::STANDARD
        .decode(b64)
        .unwrap();
    assert!(glb == std::fs::read(r.out.join("scene.glb")).unwrap());
    // the project run's page: its two maps per shape, no views
    let proj = r._dir.path().join("proj");
    let mut want = pngs(&proj, "maps", "_luminance.png");
    want.extend(pngs(&proj, "maps", "_coverage.png"));
    assert_eq!(want.len(), 2 * recon_ids(&r.p).len());
    assert_page_links_files(&proj, &want);
}

#[test]
fn kdmap_report_rebuilds_the_page_from_the_directory() {
    let r = run();
    let tmp = tempfile::tempdir().unwrap();
    let copy = tmp.path().join("out");
    for sub in ["", "textures", "maps", "renders", "report", "report/views"] {
        std::fs::create_dir_all(copy.join(sub)).unwrap();
        for e in std::fs::read_dir(r.out.join(sub)).unwrap() {
            let p = e.unwrap().path();
            if p.is_file() && p.file_name().unwrap() != "report.html" {
                std::fs::copy(&p, copy.join(sub).join(p.file_name().unwrap())).unwrap();
            }
        }
    }
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_kdmap"))
        .args(["report", copy.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let a = page_links(&std::fs::read_to_string(r.out.join("report.html")).unwrap());
    let b = page_links(&std::fs::read_to_string(copy.join("report.html")).unwrap());
    assert_eq!(a, b);
    // a directory without a run is one clear error naming report.json
    let empty = tmp.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_kdmap"))
        .args(["report", empty.to_str().unwrap()])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("report.json"), "{err}");
}
