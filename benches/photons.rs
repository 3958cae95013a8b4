//! Photon-pass throughput (photons per second) on the Cornell box fixture, uniform albedo
//! 0.5, with 1 and 2 threads; beside it the raw closest-hit ray rate for random rays in the
//! same scene, so the cost of everything around the rays (emission, texel lookups, roulette,
//! binning into tiles) is visible: `pass rate x rays per photon` vs `ray rate`.
//!
//! As the machine is shared and noisy, the bench also prints the ratio it is about — the
//! time per ray cast in a pass over the time per raw ray — from single-thread runs of the two
//! interleaved in one loop (the median of 7), so that drift hits both sides alike.
//!
//! Run with `cargo bench --bench photons`. Scene preparation is outside the timed loops.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use glam::Vec3;
use kdmap::atlas::context::HitTable;
use kdmap::atlas::store::TexelState;
use kdmap::atlas::store::TileStore;
use kdmap::atlas::texture::Scratch;
use kdmap::atlas::uv::Charts;
use kdmap::atlas::{build_geometry, prepare, RunContext};
use kdmap::base::progress::Mode;
use kdmap::base::rng::Rng;
use kdmap::config::Config;
use kdmap::physics::accel::Accel;
use kdmap::physics::light::EmitterSampler;
use kdmap::stages::indirect::photon::{
    begin_pass, finish_pass, photon_pass, AlbedoTextures, PassContext,
};
use rayon::prelude::*;
use std::path::Path;
use std::time::{Duration, Instant};

const PHOTONS: u64 = 1 << 18;
const BATCH: u32 = 1 << 14;
const RAYS: usize = 1 << 16;

fn bench(c: &mut Criterion) {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/cbox/input.xml");
    let mut cfg = Config::for_scene(scene);
    (cfg.seed, cfg.photons, cfg.batch_size) = (1, PHOTONS, BATCH);
    let dir = tempfile::tempdir().expect("temp dir");
    let p = prepare(&cfg, Mode::Quiet).expect("prepare");
    let geom =
        build_geometry(&p, &dir.path().join("geometry.tiles"), Mode::Quiet).expect("geometry");
    let charts = Charts::new(&p.scene, &p.layout, &p.atlases).expect("charts");
    let sampler = EmitterSampler::new(&p.scene);
    let scratch = Scratch::new(dir.path(), 1 << 30);
    let albedo = AlbedoTextures::uniform(&p.layout, &charts, &geom, Vec3::splat(0.5), &scratch)
        .expect("albedo");
    let window = p.window::<TexelState>(&cfg);
    let hits = HitTable::new(&p, &charts);
    let ctx = PassContext::new(&p, &cfg, (&sampler, &charts, &hits, &albedo), 0);
    let mut state = p
        .create_store(dir.path().join("state.tiles"), TexelState::default())
        .expect("state store");

    // One untimed pass for the path statistics.
    begin_pass(&mut state, window).expect("begin");
    let stats = photon_pass(&ctx, &mut state, 0, |_| Ok(())).expect("pass");
    finish_pass(&geom, &mut state, window).expect("finish");
    let rays_per_photon = stats.rays as f64 / stats.photons as f64;
    eprintln!(
        "cbox: {} texels in {} tiles; per photon {rays_per_photon:.3} rays, {:.3} deposits, \
         {:.4} dropped",
        p.layout
            .slots
            .iter()
            .map(|s| s.width as u64 * s.height as u64)
            .sum::<u64>(),
        p.layout.tile_count,
        stats.deposits as f64 / stats.photons as f64,
        stats.dropped as f64 / stats.photons as f64,
    );

    let rays = random_rays(&p);

    let mut g = c.benchmark_group("photons/cbox");
    g.sample_size(10).warm_up_time(Duration::from_secs(1));
    for threads in [1usize, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        g.measurement_time(Duration::from_secs(8))
            .throughput(Throughput::Elements(PHOTONS));
        g.bench_with_input(BenchmarkId::new("pass", threads), &threads, |b, _| {
            b.iter(|| {
                pool.install(|| {
                    begin_pass(&mut state, window).expect("begin");
                    photon_pass(&ctx, &mut state, 0, |_| Ok(())).expect("pass")
                })
            })
        });
        g.measurement_time(Duration::from_secs(3))
            .throughput(Throughput::Elements(RAYS as u64));
        g.bench_with_input(BenchmarkId::new("closest_ray", threads), &rays, |b, rs| {
            b.iter(|| {
                pool.install(|| {
                    rs.par_chunks(1024)
                        .map(|c| closest_hits(&p.accel, c))
                        .sum::<usize>()
                })
            })
        });
    }
    g.finish();

    let ratios = interleaved_ratios(&ctx, &mut state, window, &p.accel, &rays);
    eprintln!(
        "cbox, 1 thread: time per ray in a photon pass / per raw closest-hit ray = {:.2} \
         (median of 7; range {:.2}..{:.2})",
        ratios[3], ratios[0], ratios[6]
    );
}

/// Random closest-hit rays: origins uniform in the scene's bounds, directions uniform.
fn random_rays(p: &RunContext) -> Vec<(Vec3, Vec3)> {
    let (lo, hi) = p.scene.bounds();
    (0..RAYS as u64)
        .map(|i| {
            let mut r = Rng::new(5, 0, 0, i);
            let o = lo + (hi - lo) * Vec3::new(r.f32(), r.f32(), r.f32());
            let z = 2.0 * r.f32() - 1.0;
            let phi = std::f32::consts::TAU * r.f32();
            let s = (1.0 - z * z).max(0.0).sqrt();
            (o, Vec3::new(s * phi.cos(), s * phi.sin(), z))
        })
        .collect()
}

/// How many of `rays` hit something.
fn closest_hits(accel: &Accel, rays: &[(Vec3, Vec3)]) -> usize {
    rays.iter()
        .filter(|(o, d)| accel.intersect(*o, *d, f32::INFINITY).is_some())
        .count()
}

/// The time per ray cast in a photon pass over the time per raw closest-hit ray, from seven
/// single-thread runs of the two interleaved (so the machine's drift hits both alike), sorted.
fn interleaved_ratios(
    ctx: &PassContext,
    state: &mut TileStore<TexelState>,
    window: usize,
    accel: &Accel,
    rays: &[(Vec3, Vec3)],
) -> Vec<f64> {
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .expect("pool");
    let mut ratios: Vec<f64> = (0..7)
        .map(|_| {
            one.install(|| {
                let t = Instant::now();
                begin_pass(state, window).expect("begin");
                let s = photon_pass(ctx, state, 0, |_| Ok(())).expect("pass");
                let per_pass_ray = t.elapsed().as_secs_f64() / s.rays as f64;
                let t = Instant::now();
                let hits = closest_hits(accel, rays);
                let per_raw_ray = t.elapsed().as_secs_f64() / rays.len() as f64;
                std::hint::black_box(hits);
                per_pass_ray / per_raw_ray
            })
        })
        .collect();
    ratios.sort_by(f64::total_cmp);
    ratios
}

criterion_group!(benches, bench);
criterion_main!(benches);
