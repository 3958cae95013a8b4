//! The photon pass against closed forms (furnace sphere, open floor), its determinism over
//! thread counts, group sizes and resumes, and the smoothing filter.

use super::*;
use crate::atlas::testing::Built;
use crate::atlas::texture;
use crate::atlas::RunContext;
use crate::scene::{mesh, Emitter, Mesh, Shape, Sides};
use glam::{DVec3, Mat4, Vec2, Vec3};
use std::f64::consts::PI;

fn shape(id: &str, mesh: Mesh, sides: Sides) -> Shape {
    Shape::plain(id, mesh, sides)
}

fn point(position: Vec3, intensity: Vec3) -> Emitter {
    Emitter::Point {
        position,
        intensity,
    }
}

/// A scene with its atlases, layout, geometry store, charts and photon sampler.
struct Fixture {
    dir: tempfile::TempDir,
    p: RunContext,
    geom: TileStore<TexelGeom>,
    charts: Charts,
    hits: HitTable,
    sampler: EmitterSampler,
}

impl Fixture {
    fn new(shapes: Vec<Shape>, emitters: Vec<Emitter>, texels_per_unit: f32) -> Fixture {
        let Built {
            p,
            dir,
            geom,
            charts,
        } = Built::new(shapes, emitters, texels_per_unit, vec![]);
        let sampler = EmitterSampler::new(&p.scene);
        let hits = HitTable::new(&p, &charts);
        Fixture {
            dir,
            p,
            geom,
            charts,
            hits,
            sampler,
        }
    }

    fn ctx<'a>(&'a self, albedo: &'a AlbedoTextures, photons: u64, batch: u32) -> PassContext<'a> {
        PassContext {
            scene: &self.p.scene,
            accel: &self.p.accel,
            sampler: &self.sampler,
            layout: &self.p.layout,
            atlases: &self.p.atlases,
            charts: &self.charts,
            hits: &self.hits,
            albedo,
            seed: 7,
            iteration: 3,
            photons,
            batch_size: batch,
            max_depth: 64,
            paths: Paths::Indirect,
            window: 5,
            group_batches: 0,
        }
    }

    fn state(&self, name: &str) -> TileStore<TexelState> {
        let mut s = self
            .p
            .create_store(self.dir.path().join(name), TexelState::default())
            .unwrap();
        // Garbage in accum must not survive begin_pass.
        s.for_each_tile_mut(3, |_, r| r.iter_mut().for_each(|t| t.accum = [9.0; 3]))
            .unwrap();
        begin_pass(&mut s, 3).unwrap();
        s
    }

    /// A full pass into a fresh store, finished to irradiance.
    fn pass(&self, ctx: &PassContext, name: &str) -> (TileStore<TexelState>, PassStats) {
        let mut s = self.state(name);
        let stats = photon_pass(ctx, &mut s, 0, |_| Ok(())).unwrap();
        finish_pass(&self.geom, &mut s, 4).unwrap();
        (s, stats)
    }

    /// Every texel of every tile: (geometry, accum), in tile order.
    fn texels(&self, s: &TileStore<TexelState>) -> Vec<(TexelGeom, Vec3)> {
        (0..s.tile_count())
            .flat_map(|t| {
                let g = self.geom.read_tile(t).unwrap();
                let st = s.read_tile(t).unwrap();
                g.into_iter()
                    .zip(st)
                    .map(|(g, s)| (g, Vec3::from_array(s.accum)))
                    .collect::<Vec<_>>()
            })
            .collect()
    }

    /// Scratch textures in the fixture's directory, `budget` bytes each.
    fn scratch(&self, budget: u64) -> Scratch {
        Scratch::new(self.dir.path(), budget)
    }

    /// The same albedo `kd` everywhere.
    fn uniform(&self, kd: Vec3) -> AlbedoTextures {
        let s = self.scratch(1 << 30);
        AlbedoTextures::uniform(&self.p.layout, &self.charts, &self.geom, kd, &s).unwrap()
    }

    /// Every texel's chart of `slot`, row-major.
    fn texel_charts(&self, slot: usize) -> Vec<u32> {
        self.charts
            .texel_charts(&self.p.layout, slot, &self.geom)
            .unwrap()
    }

    /// Per slot, the texture-space arrays `(E, bin_area)` of `accum`.
    fn slot_arrays(&self, s: &TileStore<TexelState>, slot: usize) -> (Vec<Vec3>, Vec<f32>) {
        texture::read_slot(&self.p.layout, slot, s, &self.geom, |r, g| {
            let w = if g.covered() { g.bin_area } else { 0.0 };
            (Vec3::from_array(r.accum), w)
        })
        .unwrap()
        .into_iter()
        .unzip()
    }
}

/// Area-weighted mean of `accum` over covered texels.
fn area_mean(texels: &[(TexelGeom, Vec3)]) -> Vec3 {
    let (mut s, mut a) = (DVec3::ZERO, 0.0f64);
    for (g, e) in texels.iter().filter(|(g, _)| g.covered()) {
        s += e.as_dvec3() * g.bin_area as f64;
        a += g.bin_area as f64;
    }
    (s / a).as_vec3()
}

/// The unit sphere turned inside out (normals inward, one-sided) with a point light at its
/// center: the furnace whose every quantity is known.
fn furnace(intensity: Vec3, texels_per_unit: f32) -> Fixture {
    let mut m = mesh::sphere();
    mesh::flip_normals(&mut m);
    Fixture::new(
        vec![shape("sphere", m, Sides::Front)],
        vec![point(Vec3::ZERO, intensity)],
        texels_per_unit,
    )
}

/// Inside a closed surface of area `A` every photon lands, so the total flux deposited after
/// `k >= 1` bounces is `Phi (rho + ... + rho^depth)` and the area-mean `E_i` is that over `A`;
/// for the exact unit sphere this is `E_d rho / (1 - rho)` with `E_d = I / R^2` (the
/// tessellated sphere's area is 0.04% short of `4 pi`, which we account for).
#[test]
fn furnace_sphere_matches_the_closed_form() {
    let i = Vec3::new(1.0, 2.0, 0.5);
    let fx = furnace(i, 16.0);
    let area = fx.p.scene.shapes[0].mesh.area();
    let ed = i.as_dvec3() * (4.0 * PI / area);
    let n = 400_000u64;

    // Grey rho = 0.5: every photon keeps its flux, so texel counts are (nearly) Poisson.
    let rho = 0.5;
    let albedo = fx.uniform(Vec3::splat(rho));
    let ctx = fx.ctx(&albedo, n, 8192);
    let (s, stats) = fx.pass(&ctx, "grey.tiles");
    let texels = fx.texels(&s);
    let want = ed * (rho as f64 / (1.0 - rho as f64));
    let got = area_mean(&texels).as_dvec3();
    let rel = (got / want - 1.0).abs();
    eprintln!(
        "furnace grey: mean E_i {got:.5} vs {want:.5} (rel err {rel:.5}); E_i / (I/R^2) = \
         {:.5}; {stats:?}",
        got.x / i.x as f64
    );
    assert!(rel.max_element() < 0.01, "{got} vs {want}");
    assert_eq!(stats.photons, n);
    assert_eq!(stats.batches, n.div_ceil(8192));
    // The first hit is never deposited: one later hit per photon on average for rho = 0.5
    // (a few percent of them land in uncovered border texels and are dropped).
    let per_photon = (stats.deposits + stats.dropped) as f64 / n as f64;
    assert!((per_photon - 1.0).abs() < 0.02, "{per_photon}");

    // Per-texel spread: texel j collects about Poisson(lambda_j) photons of flux Phi / N.
    let phi = i.x as f64 * 4.0 * PI;
    let (mut z2, mut k) = (0.0f64, 0usize);
    for (g, e) in texels.iter().filter(|(g, _)| g.covered()) {
        if g.bin_area < 0.999 * g.area {
            continue; // border texels: their 8x8-sampled bin areas carry a small error
        }
        let lambda = want.x * g.bin_area as f64 * n as f64 / phi;
        let count = e.x as f64 * g.bin_area as f64 * n as f64 / phi;
        z2 += (count - lambda).powi(2) / lambda;
        k += 1;
    }
    let z2 = z2 / k as f64;
    eprintln!("furnace grey: mean z^2 over {k} interior texels = {z2:.3} (1 = photon noise)");
    assert!(k > 1000);
    assert!(
        (0.85..1.2).contains(&z2),
        "per-texel spread {z2} is not photon noise"
    );
    // Only covered texels hold anything.
    assert!(texels
        .iter()
        .filter(|(g, _)| !g.covered())
        .all(|(_, e)| *e == Vec3::ZERO));

    check_smoothing(&fx, s, want.x);
    check_colored_and_one_bounce(&fx, ed, n);
}

/// Smoothing the furnace's `E_i` (uniform, `want`) cuts per-texel noise, and the store-level
/// filter is the same function as the in-memory one.
fn check_smoothing(fx: &Fixture, s: TileStore<TexelState>, want: f64) {
    // E_i is uniform here, so this is pure noise reduction.
    let (e, wts) = fx.slot_arrays(&s, 0);
    let charts = &fx.texel_charts(0);
    let st = fx.p.layout.slots[0];
    let mut rms0 = 0.0;
    for r in 0..=3u32 {
        let sm = smooth_within_charts(&e, &wts, charts, st.width, st.height, r).unwrap();
        let (mut s2, mut sm_mean, mut m) = (0.0f64, 0.0f64, 0usize);
        for (j, v) in sm.iter().enumerate() {
            if charts[j] != NONE && wts[j] > 0.0 {
                let d = v.x as f64 / want - 1.0;
                s2 += d * d;
                sm_mean += d;
                m += 1;
            }
        }
        let rms = (s2 / m as f64).sqrt();
        if r == 0 {
            rms0 = rms;
        }
        eprintln!(
            "smoothing radius {r}: per-texel rms rel error {rms:.4}, mean {:+.4}, \
             equivalent photons x{:.1}",
            sm_mean / m as f64,
            (rms0 / rms).powi(2)
        );
        if r > 0 {
            assert!(
                rms < 0.6 * rms0,
                "radius {r} should cut the noise: {rms} vs {rms0}"
            );
        }
    }
    // The store-level filter is the same function, whole or tile by tile (a budget of one
    // byte keeps every texture in tiles), bit for bit.
    let sm = smooth_within_charts(&e, &wts, charts, st.width, st.height, 2).unwrap();
    for budget in [1u64 << 30, 1] {
        let mut s2 = fx.state(&format!("smooth-{budget}.tiles"));
        for t in 0..s.tile_count() {
            s2.write_tile(t, &s.read_tile(t).unwrap()).unwrap();
        }
        let scratch = fx.scratch(budget);
        smooth_accum(&fx.p.layout, &fx.charts, &fx.geom, &mut s2, 2, &scratch).unwrap();
        let (e2, _) = fx.slot_arrays(&s2, 0);
        for j in 0..e2.len() {
            if charts[j] != NONE {
                assert_eq!(
                    e2[j].to_array().map(f32::to_bits),
                    sm[j].to_array().map(f32::to_bits)
                );
            }
        }
    }
}

/// Coloured albedo gives per channel `E_i = E_d rho_c / (1 - rho_c)` (Russian roulette on
/// max K_d); one bounce only gives `E_i = E_d rho`.
fn check_colored_and_one_bounce(fx: &Fixture, ed: DVec3, n: u64) {
    // Colored albedo: per channel E_i = E_d rho_c / (1 - rho_c) (Russian roulette on max K_d).
    let rho = Vec3::new(0.5, 0.25, 0.8);
    let albedo = fx.uniform(rho);
    let (s, stats) = fx.pass(&fx.ctx(&albedo, n, 8192), "color.tiles");
    let want = ed * (rho.as_dvec3() / (1.0 - rho.as_dvec3()));
    let got = area_mean(&fx.texels(&s)).as_dvec3();
    let rel = (got / want - 1.0).abs();
    eprintln!("furnace color: mean E_i {got:.5} vs {want:.5} (rel err {rel:.5}); {stats:?}");
    assert!(rel.max_element() < 0.01, "{got} vs {want}");

    // One bounce only: E_i = E_d rho.
    let albedo = fx.uniform(Vec3::splat(0.5));
    let mut ctx = fx.ctx(&albedo, 200_000, 8192);
    ctx.max_depth = 1;
    let (s, _) = fx.pass(&ctx, "depth1.tiles");
    let want = ed * 0.5;
    let got = area_mean(&fx.texels(&s)).as_dvec3();
    eprintln!("furnace max_depth 1: mean E_i {got:.5} vs {want:.5}");
    assert!(
        (got / want - 1.0).abs().max_element() < 0.01,
        "{got} vs {want}"
    );
}

/// With rho = 0 everything absorbs at the first hit: one ray per photon, nothing deposited.
#[test]
fn black_surfaces_absorb_everything() {
    let fx = furnace(Vec3::ONE, 8.0);
    let albedo = fx.uniform(Vec3::ZERO);
    let (s, stats) = fx.pass(&fx.ctx(&albedo, 20_000, 4096), "black.tiles");
    assert_eq!((stats.deposits, stats.dropped), (0, 0));
    assert_eq!(stats.rays, 20_000);
    assert!(fx.texels(&s).iter().all(|(_, e)| *e == Vec3::ZERO));
    // max_depth = 0: no bounce, so nothing either, even with a white surface.
    let albedo = fx.uniform(Vec3::ONE);
    let mut ctx = fx.ctx(&albedo, 20_000, 4096);
    ctx.max_depth = 0;
    let (_, stats) = fx.pass(&ctx, "depth0.tiles");
    assert_eq!((stats.deposits, stats.rays), (0, 20_000));
}

/// A floor under a point light has no second bounce: E_i = 0 exactly. A ceiling that faces
/// away from the room (one-sided) absorbs what reaches its back and receives nothing; the
/// same ceiling two-sided does receive (so the zeros are not an accident of the setup).
#[test]
fn open_floor_and_backside_receiver_get_nothing() {
    let quad = |z: f32, down: bool| {
        let mut m = mesh::rectangle();
        m.transform(&(Mat4::from_translation(Vec3::Z * z) * Mat4::from_scale(Vec3::splat(2.0))));
        if down {
            mesh::flip_normals(&mut m);
        }
        m
    };
    let light = || vec![point(Vec3::Z, Vec3::splat(3.0))];
    let run_with = |shapes: Vec<Shape>, name: &str, kd: &[f32]| {
        let fx = Fixture::new(shapes, light(), 8.0);
        let slots = fx.p.layout.slots.len();
        let kd: Vec<Vec3> = kd.iter().take(slots).map(|&k| Vec3::splat(k)).collect();
        let (l, c, g, s) = (&fx.p.layout, &fx.charts, &fx.geom, fx.scratch(1 << 30));
        let albedo = AlbedoTextures::uniform_per_slot(l, c, g, &kd, &s).unwrap();
        let (s, stats) = fx.pass(&fx.ctx(&albedo, 50_000, 4096), name);
        let per_slot: Vec<Vec3> = (0..fx.p.layout.slots.len())
            .map(|slot| {
                let (e, w) = fx.slot_arrays(&s, slot);
                e.iter().zip(&w).map(|(e, w)| *e * *w).sum::<Vec3>()
            })
            .collect();
        eprintln!("{name}: flux per slot {per_slot:?}; {stats:?}");
        (per_slot, stats)
    };
    let run = |shapes: Vec<Shape>, name: &str| run_with(shapes, name, &[0.9, 0.9]);
    let (f, stats) = run(
        vec![shape("floor", quad(0.0, false), Sides::Front)],
        "floor",
    );
    assert_eq!(f, vec![Vec3::ZERO]);
    assert_eq!(stats.deposits + stats.dropped, 0);

    let back = shape("ceiling", quad(2.0, false), Sides::Front);
    let (f, stats) = run(
        vec![shape("floor", quad(0.0, false), Sides::Front), back],
        "floor + backside ceiling",
    );
    assert_eq!(f, vec![Vec3::ZERO; 2]);
    assert_eq!(stats.deposits + stats.dropped, 0);

    let both = shape("ceiling", quad(2.0, false), Sides::Both);
    let (f, _) = run(
        vec![shape("floor", quad(0.0, false), Sides::Front), both],
        "floor + two-sided ceiling",
    );
    assert!(
        f[0].min_element() > 0.0 && f[1].min_element() > 0.0,
        "{f:?}"
    );
    // A black ceiling returns nothing to the floor; the floor still lights the ceiling.
    let both = shape("ceiling", quad(2.0, false), Sides::Both);
    let (f, _) = run_with(
        vec![shape("floor", quad(0.0, false), Sides::Front), both],
        "floor + black two-sided ceiling",
        &[0.9, 0.0],
    );
    assert!(f[0] == Vec3::ZERO && f[1].min_element() > 0.0, "{f:?}");
}

/// Caustics against the closed form of a mirror image: a point light 1 above a floor (side
/// 4) under a perfect mirror at height 2. A caustic pass deposits exactly the light of the
/// light's image at height 3, `E(x) = 3 I / r^3`: over the floor `I Omega / A`, with `Omega`
/// the floor's solid angle from the image, and per region the same; the direct light is not
/// in it. A solver pass (`Indirect`) over a black floor deposits nothing: that light is the
/// caustic pass's, not `E_i`.
#[test]
fn a_caustic_pass_deposits_the_mirror_image_of_the_light() {
    let quad = |z: f32, down: bool, scale: f32| {
        let mut m = mesh::rectangle();
        m.transform(&(Mat4::from_translation(Vec3::Z * z) * Mat4::from_scale(Vec3::splat(scale))));
        if down {
            mesh::flip_normals(&mut m);
        }
        m
    };
    let mut mirror = shape("mirror", quad(2.0, true, 8.0), Sides::Front);
    mirror.material =
        crate::scene::Material::Known(Box::new(crate::scene::KnownMaterial::perfect_mirror()));
    let floor = shape("floor", quad(0.0, false, 2.0), Sides::Front);
    let i = Vec3::new(2.0, 1.0, 0.5);
    let fx = Fixture::new(vec![floor, mirror], vec![point(Vec3::Z, i)], 8.0);
    let n = 400_000u64;
    let black = fx.uniform(Vec3::ZERO);
    let mut ctx = fx.ctx(&black, n, 8192);
    ctx.paths = Paths::Caustic;
    let (s, stats) = fx.pass(&ctx, "caustic.tiles");
    let texels = fx.texels(&s);
    // the floor's solid angle from the image at height 3
    let omega = 4.0 * (4.0f64 / 13.0).asin();
    let want = i.as_dvec3() * (omega / 16.0);
    let got = area_mean(&texels).as_dvec3();
    let rel = (got / want - 1.0).abs().max_element();
    eprintln!("caustic: mean {got:.5} vs {want:.5}; {stats:?}");
    assert!(rel < 0.01, "{got} vs {want}");
    // every photon that reached the mirror and then the floor, and nothing else
    let share = (stats.deposits + stats.dropped) as f64 / n as f64;
    assert!((share - omega / (4.0 * PI)).abs() < 0.005, "{share}");
    // the profile: a central square against the edge band
    let region = |inner: bool| -> (f64, f64) {
        let (mut got, mut want) = (0.0f64, 0.0f64);
        for (g, e) in texels.iter().filter(|(g, _)| g.covered()) {
            let p = Vec3::from_array(g.position).as_dvec3();
            if (p.x.abs().max(p.y.abs()) < 0.75) != inner {
                continue;
            }
            let r = (p.x * p.x + p.y * p.y + 9.0).sqrt();
            got += e.x as f64 * g.bin_area as f64;
            want += 3.0 * i.x as f64 / r.powi(3) * g.bin_area as f64;
        }
        (got, want)
    };
    for inner in [true, false] {
        let (g, w) = region(inner);
        assert!((g / w - 1.0).abs() < 0.03, "inner {inner}: {g} vs {w}");
    }
    // the same light paths in a solver pass: no diffuse bounce before the floor, no deposit
    let mut ctx = fx.ctx(&black, n / 4, 8192);
    ctx.paths = Paths::Indirect;
    let (s, stats) = fx.pass(&ctx, "indirect.tiles");
    assert_eq!(stats.deposits + stats.dropped, 0, "{stats:?}");
    assert!(fx.texels(&s).iter().all(|(_, e)| *e == Vec3::ZERO));
}

/// The albedo a photon sees is the texel under the hit; `gather` ignores uncovered texels'
/// state and fills the gutter by dilation.
#[test]
fn albedo_lookup_is_the_texel_under_the_point_and_gather_dilates() {
    let fx = furnace(Vec3::ONE, 4.0);
    let st = fx.p.layout.slots[0];
    let mut s = fx.state("kd.tiles");
    // k_d = (x, y, 1) on covered texels, garbage elsewhere (gather must ignore it).
    let layout = fx.p.layout.clone();
    let geom = &fx.geom;
    s.for_each_tile_mut(4, |t, recs| {
        let g = geom.read_tile(t).unwrap();
        for (off, r) in recs.iter_mut().enumerate() {
            r.k_d = match layout.texel_of(t as u32, off as u32) {
                Some((_, x, y)) if g[off].covered() => [x as f32, y as f32, 1.0],
                _ => [-5.0; 3],
            };
        }
    })
    .unwrap();
    // whole, and in tiles (a budget of one byte): the same texels
    for budget in [1u64 << 30, 1] {
        let scratch = fx.scratch(budget);
        let alb =
            AlbedoTextures::read(&fx.p.layout, &fx.charts, &s, &fx.geom, 2, &scratch).unwrap();
        assert_eq!(alb.slots[0].is_whole(), budget > 1);
        let charts = &fx.texel_charts(0);
        let (mut covered, mut filled) = (0, 0);
        for y in 0..st.height {
            for x in 0..st.width {
                let i = (y * st.width + x) as usize;
                let v = alb.lookup(0, Vec2::new(x as f32 + 0.9, y as f32 + 0.1));
                assert_eq!(
                    alb.texel(0, Vec2::new(x as f32 + 0.5, y as f32 + 0.5))
                        .0
                        .chart,
                    charts[i]
                );
                if charts[i] != NONE {
                    assert_eq!(v, Vec3::new(x as f32, y as f32, 1.0));
                    covered += 1;
                } else if v.z == 1.0 {
                    filled += 1; // gutter next to a chart: dilated from covered neighbours
                } else {
                    assert_eq!(v, Vec3::ZERO);
                }
            }
        }
        assert!(covered > 100 && filled > 10, "{covered} {filled}");
        // Clamped outside the texture.
        assert_eq!(
            alb.lookup(0, Vec2::new(-3.0, -1.0)),
            alb.slots[0].get(0, 0).kd
        );
        alb.check().unwrap();
    }
}

/// Bit-identical accum for 1 and 2 threads, any group size, a partial last batch, and a pass
/// interrupted after a group and resumed from there.
#[test]
fn passes_are_bit_identical_across_threads_groups_and_resume() {
    let fx = furnace(Vec3::new(1.0, 0.5, 2.0), 8.0);
    let albedo = fx.uniform(Vec3::new(0.6, 0.3, 0.7));
    let base = fx.ctx(&albedo, 20_500, 1000); // 21 batches, the last one of 500
    let bits = |s: &TileStore<TexelState>| -> Vec<u32> {
        (0..s.tile_count())
            .flat_map(|t| s.read_tile(t).unwrap())
            .flat_map(|r| r.accum.map(f32::to_bits))
            .collect()
    };
    let run = |threads: usize, group: usize, name: &str| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let ctx = PassContext {
            group_batches: group,
            ..base
        };
        let mut s = fx.state(name);
        let mut seen = Vec::new();
        let stats = pool
            .install(|| {
                photon_pass(&ctx, &mut s, 0, |done| {
                    seen.push(done);
                    Ok(())
                })
            })
            .unwrap();
        (bits(&s), stats, seen)
    };
    let (one, st1, seen) = run(1, 0, "a.tiles");
    assert_eq!(seen, vec![16, 21]);
    assert_eq!(st1.photons, 20_500);
    assert!(st1.deposits > 10_000);
    let (two, st2, seen) = run(2, 1, "b.tiles");
    assert_eq!(seen, (1..=21).collect::<Vec<_>>());
    assert_eq!(one, two);
    assert_eq!(
        (st1.rays, st1.deposits, st1.dropped),
        (st2.rays, st2.deposits, st2.dropped)
    );
    assert_eq!(one, run(2, 3, "c.tiles").0);

    // Interrupted after the group ending at batch 9 (the checkpoint), resumed from there.
    let mut s = fx.state("d.tiles");
    let ctx = PassContext {
        group_batches: 3,
        ..base
    };
    let mut at = 0;
    let e = photon_pass(&ctx, &mut s, 0, |done| {
        at = done;
        if done >= 7 {
            Err(Error::internal("simulated crash"))
        } else {
            Ok(())
        }
    });
    assert!(e.is_err());
    assert_eq!(at, 9);
    assert_ne!(bits(&s), one);
    let ctx = PassContext {
        group_batches: 5,
        ..base
    };
    let rest = photon_pass(&ctx, &mut s, at, |_| Ok(())).unwrap();
    assert_eq!(rest.batches, 12);
    assert_eq!(rest.photons, 20_500 - 9000);
    assert_eq!(bits(&s), one);
    // ...and the key matters: another seed gives other bits.
    let ctx = PassContext { seed: 8, ..base };
    let mut s = fx.state("e.tiles");
    photon_pass(&ctx, &mut s, 0, |_| Ok(())).unwrap();
    assert_ne!(bits(&s), one);
    // A replayed photon gives the deposits its batch recorded for it.
    let (batch, _) = trace_batch(&base, 4);
    let mut replay = Vec::new();
    for i in 0..base.batch_len(4) {
        trace_photon(&base, 4, i, &mut replay);
    }
    assert_eq!(batch, replay);
    // Out-of-range resumes are refused.
    assert!(photon_pass(&base, &mut s, 22, |_| Ok(())).is_err());
}

/// The filter averages within a chart only, weighted, and leaves uncovered texels alone.
#[test]
fn smoothing_stays_within_charts() {
    // A 6x1 strip: chart 0 at x = 0..3, a gutter texel at x = 3, chart 1 at x = 4..6.
    let charts = [0, 0, 0, NONE, 1, 1];
    let v: Vec<Vec3> = [1.0, 2.0, 3.0, 100.0, 10.0, 20.0]
        .iter()
        .map(|&x| Vec3::splat(x))
        .collect();
    let w = [1.0, 1.0, 2.0, 5.0, 1.0, 3.0];
    let s = smooth_within_charts(&v, &w, &charts, 6, 1, 1).unwrap();
    let x: Vec<f32> = s.iter().map(|v| v.x).collect();
    assert_eq!(
        x,
        vec![1.5, 9.0 / 4.0, 8.0 / 3.0, 100.0, 70.0 / 4.0, 70.0 / 4.0]
    );
    assert_eq!(smooth_within_charts(&v, &w, &charts, 6, 1, 0).unwrap(), v);
    assert!(smooth_within_charts(&v, &w[..5], &charts, 6, 1, 1).is_err());
}

/// Smoothing where `E_i` is not uniform (a floor under a low two-sided ceiling, point light
/// between them): rms relative error of `N` photons per radius against a `K N`-photon
/// unsmoothed reference, with the reference's own noise (`rms_0^2 / (K + 1)`) taken out in
/// quadrature, so blur bias shows beside the noise gain. A measurement, not a check:
/// `cargo test --lib photon::tests::smoothing_tradeoff -- --ignored --nocapture`.
#[test]
#[ignore]
fn smoothing_tradeoff_on_a_gradient() {
    let quad = |z: f32| {
        let mut m = mesh::rectangle();
        m.transform(&(Mat4::from_translation(Vec3::Z * z) * Mat4::from_scale(Vec3::splat(2.0))));
        m
    };
    let fx = Fixture::new(
        vec![
            shape("floor", quad(0.0), Sides::Front),
            shape("ceiling", quad(1.0), Sides::Both),
        ],
        vec![point(Vec3::new(0.5, 0.0, 0.5), Vec3::ONE)],
        8.0,
    );
    let albedo = fx.uniform(Vec3::splat(0.7));
    let (n, k) = (100_000u64, 40u64);
    let (reference, _) = fx.pass(&fx.ctx(&albedo, k * n, 16384), "ref.tiles");
    let (s, _) = fx.pass(&fx.ctx(&albedo, n, 16384), "n.tiles");
    let st = fx.p.layout.slots[0];
    let (e_ref, _) = fx.slot_arrays(&reference, 0);
    let (e, w) = fx.slot_arrays(&s, 0);
    let charts = &fx.texel_charts(0);
    let mut ref_var = 0.0;
    for r in 0..=4u32 {
        let sm = smooth_within_charts(&e, &w, charts, st.width, st.height, r).unwrap();
        let (mut s2, mut m) = (0.0f64, 0usize);
        for j in 0..sm.len() {
            if charts[j] != NONE && w[j] > 0.0 && e_ref[j].x > 0.0 {
                s2 += (sm[j].x as f64 / e_ref[j].x as f64 - 1.0).powi(2);
                m += 1;
            }
        }
        let ms = s2 / m as f64;
        if r == 0 {
            ref_var = ms / (k + 1) as f64;
        }
        eprintln!(
            "gradient floor, {n} photons, radius {r}: rms rel error {:.4} (vs the reference \
             {:.4}, whose noise is ~{:.4})",
            (ms - ref_var).max(0.0).sqrt(),
            ms.sqrt(),
            ref_var.sqrt()
        );
    }
}
