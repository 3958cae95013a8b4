//! Projection throughput (texel-views per second): how fast the photos of the Cornell box
//! fixture are projected onto its atlas (pixel classification rays, supersampled bilinear
//! lookups), with 1 and 2 threads, without (`weighted_mean`) and with the default refinement
//! passes (`refined`, each pass re-renders every view from its cached rays and back-projects
//! the residual). Atlas and geometry tiles are built outside the timed loop; each iteration
//! projects all three photos into a fresh state store.
//!
//! `shrink` times the residual shrinkage of one refinement pass on one 12-megapixel view
//! (4096 x 3072, a textured half and a flat half, 2% noise; the local noise level included),
//! in pixels per second, with 1 and 2 threads.
//!
//! Run with `cargo bench --bench projection`.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use kdmap::atlas::context::HitTable;
use kdmap::atlas::store::TexelState;
use kdmap::atlas::uv::Charts;
use kdmap::atlas::{build_geometry, prepare};
use kdmap::base::progress::Mode;
use kdmap::config::Config;
use std::path::Path;
use std::time::Duration;

fn bench(c: &mut Criterion) {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/cbox/input.xml");
    let mut cfg = Config::for_scene(scene);
    cfg.atlas.texels_per_unit = kdmap::config::Density::PerUnit(128.0);
    let dir = tempfile::tempdir().expect("temp dir");
    let p = prepare(&cfg, Mode::Quiet).expect("prepare");
    let geom =
        build_geometry(&p, &dir.path().join("geometry.tiles"), Mode::Quiet).expect("geometry");
    let charts = Charts::new(&p.scene, &p.layout, &p.atlases).expect("charts");
    let hits = HitTable::new(&p, &charts);
    let scratch = kdmap::atlas::texture::Scratch::new(dir.path(), 1 << 30);
    let covered: u64 = {
        let mut st = p
            .create_store(dir.path().join("probe.tiles"), TexelState::default())
            .expect("store");
        kdmap::stages::project::run(
            &p,
            &cfg,
            (&hits, &charts),
            &geom,
            &mut st,
            Mode::Quiet,
            &scratch,
        )
        .expect("project")
        .covered_texels
    };
    let mut g = c.benchmark_group("projection");
    g.sample_size(10).measurement_time(Duration::from_secs(10));
    g.throughput(Throughput::Elements(covered * p.views.len() as u64));
    for (name, passes) in [
        ("weighted_mean", 0),
        ("refined", kdmap::config::REFINE_PASSES),
    ] {
        cfg.refine_passes = passes;
        for threads in [1usize, 2] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            g.bench_with_input(
                BenchmarkId::new(format!("cbox_3_views_{name}"), threads),
                &threads,
                |b, _| {
                    b.iter(|| {
                        pool.install(|| {
                            let mut st = p
                                .create_store(dir.path().join("state.tiles"), TexelState::default())
                                .expect("store");
                            kdmap::stages::project::run(
                                &p,
                                &cfg,
                                (&hits, &charts),
                                &geom,
                                &mut st,
                                Mode::Quiet,
                                &scratch,
                            )
                            .expect("project")
                        })
                    })
                },
            );
        }
    }
    g.finish();
}

fn shrink(c: &mut Criterion) {
    use kdmap::stages::project::{shrink_residual, PixelInfo};
    let (w, h) = (4096usize, 3072usize);
    let mut photo = Vec::with_capacity(w * h);
    let mut residual = Vec::with_capacity(w * h);
    for i in 0..w * h {
        let mut r = kdmap::base::rng::Rng::new(1, 0, 0, i as u64);
        let texture = if i % w < w / 2 { 0.3 * r.f32() } else { 0.0 };
        let e = 0.02 * (r.f32() + r.f32() + r.f32() - 1.5) * 2.0;
        let render = glam::Vec3::splat(1.0 + texture);
        photo.push(render * (1.0 + e));
        residual.push(render * e);
    }
    let pixels = vec![
        PixelInfo {
            shape: 0,
            normal: glam::Vec3::Y,
            plane: 0.0,
            clean: true,
        };
        w * h
    ];
    let mut g = c.benchmark_group("shrink");
    g.sample_size(10).measurement_time(Duration::from_secs(10));
    g.throughput(Throughput::Elements((w * h) as u64));
    for threads in [1usize, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        g.bench_with_input(BenchmarkId::new("12mpx_view", threads), &threads, |b, _| {
            b.iter(|| {
                pool.install(|| {
                    let mut r = residual.clone();
                    shrink_residual(&mut r, &photo, &pixels, w)
                })
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench, shrink);
criterion_main!(benches);
