//! Tile accumulation throughput (photon deposits per second): adding a group of traced photon
//! hits into the memory-mapped `TexelState` tile store, as a photon pass does after every group
//! of batches (bin the deposits by tile with a stable counting sort, then add each tile's flux
//! to `accum`, one tile per task, `window` tiles mapped at a time).
//!
//! The deposits are real: photons traced in the Cornell box fixture (uniform albedo 0.5) by
//! `photon::trace_batch`, outside the timed loop. The timed loop is `photon::add_deposits`
//! (bin, then `TileStore::for_each_tile_mut`), measured with every tile mapped at once (the
//! default budget) and with a 4-tile window (a store many times its memory budget: the
//! map/unmap per window is part of the cost), on 1 and 2 threads.
//!
//! Run with `cargo bench --bench tiles`.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use glam::Vec3;
use kdmap::atlas::context::HitTable;
use kdmap::atlas::store::TexelState;
use kdmap::atlas::texture::Scratch;
use kdmap::atlas::uv::Charts;
use kdmap::atlas::{build_geometry, prepare};
use kdmap::base::progress::Mode;
use kdmap::config::Config;
use kdmap::physics::light::EmitterSampler;
use kdmap::stages::indirect::photon::{
    add_deposits, trace_batch, AlbedoTextures, Deposit, PassContext, PathCounts,
};
use rayon::prelude::*;
use std::path::Path;
use std::time::Duration;

const PHOTONS: u64 = 1 << 18;
const BATCH: u32 = 1 << 14;

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
    let all_tiles = p.window::<TexelState>(&cfg);
    let hits = HitTable::new(&p, &charts);
    let ctx = PassContext::new(&p, &cfg, (&sampler, &charts, &hits, &albedo), 0);
    let outs: Vec<(Vec<Deposit>, PathCounts)> = (0..ctx.batch_count())
        .into_par_iter()
        .map(|b| trace_batch(&ctx, b))
        .collect();
    let deposits: u64 = outs.iter().map(|o| o.0.len() as u64).sum();
    let mut state = p
        .create_store(dir.path().join("state.tiles"), TexelState::default())
        .expect("state store");
    eprintln!(
        "cbox: {} tiles of {} texels ({} KiB each), {deposits} deposits from {PHOTONS} photons",
        p.layout.tile_count,
        p.layout.tile_texels(),
        state.tile_stride_bytes() / 1024
    );

    let mut g = c.benchmark_group("tiles/cbox");
    g.sample_size(20)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(4))
        .throughput(Throughput::Elements(deposits));
    for threads in [1usize, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .expect("pool");
        for (name, window) in [("all_mapped", all_tiles), ("window4", 4)] {
            let id = BenchmarkId::new(format!("accumulate_{name}"), threads);
            g.bench_with_input(id, &window, |b, &w| {
                b.iter(|| pool.install(|| add_deposits(&outs, &mut state, w).expect("accumulate")))
            });
        }
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
