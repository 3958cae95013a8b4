//! How fast the BVH answers rays, in rays per second: closest hit and shadow (occluded) queries
//! on the Cornell box fixture and on a generated ~1M-triangle bumpy sphere, with 1 and 2
//! threads. Photon tracing and visibility are ray-bound, so this is the number to watch.
//!
//! Run with `cargo bench --bench raycast`. Builds are outside the timed loops.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use glam::{Vec3, Vec3A};
use kdmap::base::rng::Rng;
use kdmap::physics::accel::Accel;
use obvhs::triangle::Triangle;
use rayon::prelude::*;
use std::hint::black_box;
use std::path::Path;
use std::time::{Duration, Instant};

const RAYS: usize = 1 << 16;
const CHUNK: usize = 1024;

/// A query ray: origin, unit direction and (for shadow rays) the segment length.
#[derive(Clone, Copy)]
struct Query {
    o: Vec3,
    d: Vec3,
    tmax: f32,
}

/// Origins uniform in the bounds; closest-hit rays go in uniform random directions, shadow
/// rays towards a second random point in the bounds (like a connection to a light sample).
fn queries(lo: Vec3, hi: Vec3, seed: u64) -> Vec<Query> {
    (0..RAYS as u64)
        .map(|i| {
            let mut r = Rng::new(seed, 0, 0, i);
            let mut pt = || lo + (hi - lo) * Vec3::new(r.f32(), r.f32(), r.f32());
            let o = pt();
            let t = pt();
            let (d, tmax) = ((t - o).normalize_or(Vec3::Z), (t - o).length());
            Query { o, d, tmax }
        })
        .collect()
}

fn random_dirs(qs: &mut [Query], seed: u64) {
    for (i, q) in qs.iter_mut().enumerate() {
        let mut r = Rng::new(seed, 1, 0, i as u64);
        let z = 2.0 * r.f32() - 1.0;
        let phi = std::f32::consts::TAU * r.f32();
        let s = (1.0 - z * z).max(0.0).sqrt();
        q.d = Vec3::new(s * phi.cos(), s * phi.sin(), z);
        q.tmax = f32::INFINITY;
    }
}

/// A UV sphere of radius ~1 with a bumpy radius: `2 * slices * (stacks - 1)` triangles.
fn bumpy_sphere(slices: usize, stacks: usize) -> Vec<Triangle> {
    let vert = |i: usize, j: usize| -> Vec3A {
        let theta = std::f32::consts::PI * j as f32 / stacks as f32;
        let phi = std::f32::consts::TAU * (i % slices) as f32 / slices as f32;
        let r = 1.0 + 0.05 * (17.0 * theta).sin() * (23.0 * phi).sin();
        Vec3A::new(
            r * theta.sin() * phi.cos(),
            r * theta.cos(),
            r * theta.sin() * phi.sin(),
        )
    };
    let mut tris = Vec::with_capacity(2 * slices * stacks);
    for j in 0..stacks {
        for i in 0..slices {
            let (a, b, c, d) = (
                vert(i, j),
                vert(i + 1, j),
                vert(i, j + 1),
                vert(i + 1, j + 1),
            );
            if j > 0 {
                tris.push(Triangle {
                    v0: a,
                    v1: b,
                    v2: c,
                });
            }
            if j + 1 < stacks {
                tris.push(Triangle {
                    v0: b,
                    v1: d,
                    v2: c,
                });
            }
        }
    }
    tris
}

fn bounds(tris: &[Triangle]) -> (Vec3, Vec3) {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for t in tris {
        for v in [t.v0, t.v1, t.v2] {
            lo = lo.min(v.into());
            hi = hi.max(v.into());
        }
    }
    (lo, hi)
}

fn cbox() -> (Accel, Vec3, Vec3) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/cbox/input.xml");
    let scene = kdmap::scene::mitsuba::load(&path).expect("load the cbox fixture");
    let (lo, hi) = scene.bounds();
    (Accel::build(&scene), lo, hi)
}

fn sphere() -> (Accel, Vec3, Vec3) {
    let t0 = Instant::now();
    let tris = bumpy_sphere(1000, 500);
    let (lo, hi) = bounds(&tris);
    let n = tris.len();
    let ids = (0..n as u32).map(|i| (0, i)).collect();
    let accel = Accel::from_triangles(tris, ids);
    eprintln!(
        "bumpy sphere: {n} triangles, generated and built in {:.2} s",
        t0.elapsed().as_secs_f64()
    );
    (accel, lo, hi)
}

fn bench_scene(c: &mut Criterion, name: &str, (accel, lo, hi): (Accel, Vec3, Vec3)) {
    let shadow = queries(lo, hi, 1);
    let mut closest = shadow.clone();
    random_dirs(&mut closest, 2);
    let mut g = c.benchmark_group(format!("raycast/{name}"));
    g.sample_size(10)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(2))
        .throughput(Throughput::Elements(RAYS as u64));
    for threads in [1usize, 2] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        g.bench_with_input(BenchmarkId::new("closest", threads), &closest, |b, qs| {
            b.iter(|| {
                pool.install(|| {
                    qs.par_chunks(CHUNK)
                        .map(|c| {
                            c.iter()
                                .filter(|q| accel.intersect(q.o, q.d, q.tmax).is_some())
                                .count()
                        })
                        .sum::<usize>()
                })
            })
        });
        g.bench_with_input(BenchmarkId::new("occluded", threads), &shadow, |b, qs| {
            b.iter(|| {
                pool.install(|| {
                    qs.par_chunks(CHUNK)
                        .map(|c| {
                            c.iter()
                                .filter(|q| accel.occluded(q.o, q.d, q.tmax))
                                .count()
                        })
                        .sum::<usize>()
                })
            })
        });
    }
    g.finish();
    let hits = closest
        .iter()
        .filter(|q| black_box(&accel).intersect(q.o, q.d, q.tmax).is_some())
        .count();
    let blocked = shadow
        .iter()
        .filter(|q| accel.occluded(q.o, q.d, q.tmax))
        .count();
    eprintln!(
        "{name}: {} triangles; {:.1}% of closest-hit rays hit, {:.1}% of shadow rays blocked",
        accel.triangle_count(),
        100.0 * hits as f64 / RAYS as f64,
        100.0 * blocked as f64 / RAYS as f64
    );
}

fn raycast(c: &mut Criterion) {
    bench_scene(c, "cbox", cbox());
    bench_scene(c, "sphere_1m", sphere());
}

criterion_group!(benches, raycast);
criterion_main!(benches);
