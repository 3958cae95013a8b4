//! Per-texel solver update throughput (texels per second): `solve::kd_tile` (K_d from
//! eqs. 3-5 with the bound correction) and `solve::compare_update_tile` (comparison eqs. 6-7
//! and the relaxed E_i update) on the Cornell box fixture's atlas at the default density.
//!
//! Two forms each: `kernel`, the pure function over every tile held in memory (the arithmetic
//! alone), and `store`, the pipeline's own loop `pipeline::map_tiles` over the memory-mapped
//! tile stores (geometry tile read, state tile mapped read-write, per-tile results gathered),
//! on 1 and 2 threads. The state is made up but plausible: every covered texel observed, with
//! a radiance, direct and traced irradiance of the scene's order of magnitude, a few percent of
//! texels above the K_d bound. Throughput counts covered texels.
//!
//! `fill`: the fill of unobserved texels (`solve::fill_unobserved_all`: the wave, then the
//! harmonic relaxation by conjugate gradients) over the same atlas with every fourth tile
//! unobserved (tile-sized holes), on 1 and 2 threads; throughput counts the filled texels.
//!
//! Run with `cargo bench --bench update`.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use kdmap::atlas::store::map_tiles;
use kdmap::atlas::store::{flags, TexelGeom, TexelState};
use kdmap::atlas::texture::Scratch;
use kdmap::atlas::uv::Charts;
use kdmap::atlas::{build_geometry, prepare};
use kdmap::base::progress::Mode;
use kdmap::base::rng::Rng;
use kdmap::config::{Config, UpdateRule};
use kdmap::stages::solve::{compare_update_tile, fill_unobserved_all, kd_tile};
use std::path::Path;
use std::time::Duration;

/// A made-up observed state for texel `i` (deterministic).
fn texel_state(g: &TexelGeom, i: u64) -> TexelState {
    let mut r = Rng::new(9, 0, 0, i);
    let mut s = TexelState::default();
    if !g.covered() {
        return s;
    }
    let e_d = [
        2.0 + 3.0 * r.f32(),
        2.0 + 3.0 * r.f32(),
        2.0 + 3.0 * r.f32(),
    ];
    let e_i = e_d.map(|e| 0.4 * e);
    // Albedo 0.05..1.1: a few texels exceed the bound and take the correction path.
    let kd = 0.05 + 1.05 * r.f32();
    s.e_d = e_d;
    s.e_i = e_i;
    s.accum = e_i.map(|e| e * (0.9 + 0.2 * r.f32()));
    s.l_orig = [0, 1, 2].map(|c| kd / std::f32::consts::PI * (e_d[c] + e_i[c]));
    s.weight = 1.0;
    s.flags = flags::COVERED | flags::OBSERVED;
    s
}

fn bench(c: &mut Criterion) {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/cbox/input.xml");
    let cfg = Config::for_scene(scene);
    let dir = tempfile::tempdir().expect("temp dir");
    let p = prepare(&cfg, Mode::Quiet).expect("prepare");
    let geom =
        build_geometry(&p, &dir.path().join("geometry.tiles"), Mode::Quiet).expect("geometry");
    let window = p.window::<TexelState>(&cfg);
    let tiles = geom.tile_count();
    let tile_texels = geom.tile_texels();
    let mut state = p
        .create_store(dir.path().join("state.tiles"), TexelState::default())
        .expect("state store");
    map_tiles(&mut state, &geom, window, |t, g, s| {
        for (k, (gk, sk)) in g.iter().zip(s.iter_mut()).enumerate() {
            *sk = texel_state(gk, (t * tile_texels + k) as u64);
        }
    })
    .expect("fill state");

    // The same, in memory, for the kernels.
    let geom_mem: Vec<Vec<TexelGeom>> = (0..tiles).map(|t| geom.read_tile(t).unwrap()).collect();
    let mut state_mem: Vec<Vec<TexelState>> =
        (0..tiles).map(|t| state.read_tile(t).unwrap()).collect();
    let covered: u64 = geom_mem.iter().flatten().filter(|g| g.covered()).count() as u64;
    eprintln!(
        "cbox: {tiles} tiles of {tile_texels} texels, {covered} covered ({} bytes of state each)",
        std::mem::size_of::<TexelState>()
    );

    let (rule, beta, alpha) = (UpdateRule::Relaxed, glam::Vec3::splat(0.5), 1.0);
    let mut g = c.benchmark_group("update/cbox");
    g.sample_size(20)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3))
        .throughput(Throughput::Elements(covered));
    g.bench_function("kd_tile_kernel", |b| {
        b.iter(|| {
            let mut clamped = 0;
            for (s, gt) in state_mem.iter_mut().zip(&geom_mem) {
                clamped += kd_tile(s, gt);
            }
            clamped
        })
    });
    g.bench_function("compare_update_kernel", |b| {
        b.iter(|| {
            let mut n = 0;
            for (s, gt) in state_mem.iter_mut().zip(&geom_mem) {
                n += compare_update_tile(s, gt, rule, alpha, beta).texels;
            }
            n
        })
    });
    let pools = pools();
    for (threads, pool) in &pools {
        g.bench_with_input(
            BenchmarkId::new("kd_tile_store", threads),
            &threads,
            |b, _| {
                b.iter(|| {
                    pool.install(|| {
                        map_tiles(&mut state, &geom, window, |_, gt, s| kd_tile(s, gt)).expect("kd")
                    })
                })
            },
        );
        g.bench_with_input(
            BenchmarkId::new("compare_update_store", threads),
            &threads,
            |b, _| {
                b.iter(|| {
                    pool.install(|| {
                        map_tiles(&mut state, &geom, window, |_, gt, s| {
                            compare_update_tile(s, gt, rule, alpha, beta)
                        })
                        .expect("update")
                    })
                })
            },
        );
    }
    g.finish();
    bench_fill(c, &pools, &p, &geom, &state, window, dir.path());
}

/// Pools of 1 and 2 threads, with their sizes.
fn pools() -> Vec<(usize, rayon::ThreadPool)> {
    [1usize, 2]
        .into_iter()
        .map(|n| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build();
            (n, pool.expect("pool"))
        })
        .collect()
}

/// The fill over the same atlas with every fourth tile unobserved.
fn bench_fill(
    c: &mut Criterion,
    pools: &[(usize, rayon::ThreadPool)],
    p: &kdmap::atlas::context::RunContext,
    geom: &kdmap::atlas::store::TileStore<TexelGeom>,
    state: &kdmap::atlas::store::TileStore<TexelState>,
    window: usize,
    dir: &Path,
) {
    let charts = Charts::new(&p.scene, &p.layout, &p.atlases).expect("charts");
    let mut holes = p
        .create_store(dir.join("holes.tiles"), TexelState::default())
        .expect("hole store");
    let unobserved: u64 = map_tiles(&mut holes, geom, window, |t, g, s| {
        let src = state.read_tile(t).expect("state tile");
        let mut n = 0;
        for ((g, s), src) in g.iter().zip(s.iter_mut()).zip(src) {
            *s = src;
            if t % 4 == 0 && g.covered() {
                s.flags &= !flags::OBSERVED;
                n += 1;
            }
        }
        n
    })
    .expect("holes")
    .iter()
    .sum();
    let scratch = Scratch::new(dir, 1 << 30);
    let mut g = c.benchmark_group("fill/cbox");
    g.sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(5))
        .throughput(Throughput::Elements(unobserved));
    for (threads, pool) in pools {
        g.bench_with_input(
            BenchmarkId::new("every_4th_tile", threads),
            &threads,
            |b, _| {
                b.iter(|| {
                    pool.install(|| {
                        fill_unobserved_all(&p.layout, &charts, geom, &mut holes, &scratch, &|_| {})
                            .expect("fill")
                    })
                })
            },
        );
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
