//! The gather against closed forms (a furnace, the configuration factor of a square), its
//! rules (one-sided surfaces, emitters, unobserved texels, chart seams), and determinism.

use super::*;
use crate::atlas::store::TexelGeom;
use crate::atlas::testing::Built;
use crate::atlas::RunContext;
use crate::base::progress::no_tick;
use crate::physics::light::area::projected_solid_angle;
use crate::scene::{mesh, Mesh, Shape, Sides};
use glam::{DVec3, Mat4};

fn shape(id: &str, mesh: Mesh, emission: Option<Vec3>) -> Shape {
    Shape {
        emission,
        ..Shape::plain(id, mesh, Sides::Front)
    }
}

/// A scene ready to gather in: prepared, geometry, charts, hit table, a state store.
struct Fixture {
    _dir: tempfile::TempDir,
    p: RunContext,
    geom: TileStore<TexelGeom>,
    charts: Charts,
    hits: HitTable,
    state: TileStore<TexelState>,
}

impl Fixture {
    fn new(shapes: Vec<Shape>, texels_per_unit: f32) -> Fixture {
        Self::with_levels(shapes, texels_per_unit, vec![])
    }

    /// With per-triangle density levels per shape (`levels[shape]`; missing: uniform).
    fn with_levels(shapes: Vec<Shape>, texels_per_unit: f32, levels: Vec<Vec<u8>>) -> Self {
        let Built {
            p,
            dir,
            geom,
            charts,
        } = Built::new(shapes, vec![], texels_per_unit, levels);
        let hits = HitTable::new(&p, &charts);
        let state = p
            .create_store(dir.path().join("s"), TexelState::default())
            .unwrap();
        Fixture {
            _dir: dir,
            p,
            geom,
            charts,
            hits,
            state,
        }
    }

    /// The radiance of the current state, read through a cache of `budget` bytes.
    fn radiance(&self, budget: u64) -> Radiance {
        let path = self._dir.path().join("radiance.tiles");
        Radiance::from_state(
            &self.p.layout,
            &self.charts,
            &self.state,
            &self.geom,
            &path,
            budget,
            &no_tick,
        )
        .unwrap()
    }

    /// What the gather's rays read: this fixture's scene and `radiance`, seed 5.
    fn context<'a>(&'a self, radiance: &'a Radiance, rays: u32) -> GatherContext<'a> {
        GatherContext {
            accel: &self.p.accel,
            hits: &self.hits,
            radiance,
            seed: 5,
            rays,
            lean_rays: rays,
        }
    }

    /// Scratch textures in the fixture's directory, `budget` bytes each.
    fn scratch(&self, budget: u64) -> Scratch {
        Scratch::new(self._dir.path(), budget)
    }

    /// Every texel's chart of `slot`, row-major.
    fn texel_charts(&self, slot: usize) -> Vec<u32> {
        self.charts
            .texel_charts(&self.p.layout, slot, &self.geom)
            .unwrap()
    }

    /// Sets every covered texel of shape `id` with `f`.
    fn set(&mut self, id: &str, f: impl Fn(&mut TexelState) + Sync + Send) {
        let si = self.p.scene.shapes.iter().position(|s| s.id == id).unwrap();
        let Some(slot) = self.p.layout.slot_of_shape(si) else {
            return;
        };
        let layout = &self.p.layout;
        map_tiles(&mut self.state, &self.geom, 4, |t, g, st| {
            if layout.slot_of_tile(t as u32) != slot {
                return;
            }
            for (g, s) in g.iter().zip(st.iter_mut()) {
                if g.covered() {
                    f(s);
                }
            }
        })
        .unwrap();
    }

    fn observe(&mut self, id: &str, l: Vec3) {
        self.observe_where(id, l, &|_| true);
    }

    /// Observes the texels of shape `id` whose centres `at` accepts with radiance `l`.
    fn observe_where(&mut self, id: &str, l: Vec3, at: &(dyn Fn(Vec3) -> bool + Sync)) {
        let si = self.p.scene.shapes.iter().position(|s| s.id == id).unwrap();
        let slot = self.p.layout.slot_of_shape(si).unwrap();
        let layout = &self.p.layout;
        map_tiles(&mut self.state, &self.geom, 4, |t, g, st| {
            if layout.slot_of_tile(t as u32) != slot {
                return;
            }
            for (g, s) in g.iter().zip(st.iter_mut()) {
                if g.covered() && at(g.p()) {
                    s.l_orig = l.to_array();
                    s.weight = 1.0;
                    s.flags |= flags::OBSERVED;
                }
            }
        })
        .unwrap();
    }

    fn gather(&self, spacing: f32, rays: u32) -> (GatherPoints, Vec<Vec3>) {
        let (points, values, _) = self.gather_seeded(spacing, rays, 5);
        (points, values)
    }

    /// The gather points `spacing` apart on every shape.
    fn points(&self, spacing: f32) -> GatherPoints {
        GatherPoints::new(
            &self.p,
            &self.geom,
            &self.state,
            &self.charts,
            &|_| spacing,
            &self.scratch(1 << 30),
            &no_tick,
        )
        .unwrap()
    }

    /// The points, `E_i` at each and the predicted variance of its luminance, with gather
    /// seed `seed`.
    fn gather_seeded(
        &self,
        spacing: f32,
        rays: u32,
        seed: u64,
    ) -> (GatherPoints, Vec<Vec3>, Vec<f32>) {
        let points = self.points(spacing);
        let (values, var, _) = self.gather_lean(&points, (rays, rays), seed);
        (points, values, var)
    }

    /// The gather at `points` with `rays` per point and `lean` per lean point: `E_i`, its
    /// variance and the rays cast.
    fn gather_lean(
        &self,
        points: &GatherPoints,
        (rays, lean_rays): (u32, u32),
        seed: u64,
    ) -> (Vec<Vec3>, Vec<f32>, u64) {
        let radiance = self.radiance(1 << 30);
        let ctx = GatherContext {
            accel: &self.p.accel,
            hits: &self.hits,
            radiance: &radiance,
            seed,
            rays,
            lean_rays,
        };
        let cache = trace_points(&ctx, points, &no_tick);
        assert_eq!(cache.stats.points as usize, points.points.len());
        let (values, var) = cache.evaluate(&ctx, points);
        let var = var.iter().map(|x| x.x).collect();
        (values, var, cache.stats.rays)
    }

    /// Per point `(E_i, predicted variance of its luminance)` with gather seed `seed`.
    fn gather_variance(&self, spacing: f32, rays: u32, seed: u64) -> Vec<(Vec3, f32)> {
        let (_, v, var) = self.gather_seeded(spacing, rays, seed);
        v.into_iter().zip(var).collect()
    }

    fn slot_of(&self, id: &str) -> usize {
        let si = self.p.scene.shapes.iter().position(|s| s.id == id).unwrap();
        self.p.layout.slot_of_shape(si).unwrap()
    }
}

/// Points of slot `slot` with their values.
fn slot_points(fx: &Fixture, pts: &GatherPoints, vals: &[Vec3], slot: usize) -> Vec<(Point, Vec3)> {
    let c = &pts.slots[slot].levels;
    let a = c[0].start[0] as usize;
    let b = *c.last().unwrap().start.last().unwrap() as usize;
    let _ = fx;
    (a..b).map(|i| (pts.points[i], vals[i])).collect()
}

/// Inside a closed sphere of uniform observed radiance `L` every ray sees `L`: `E_i = pi L`.
/// (Flat facets: with smooth normals the rays below a facet count as nothing, as in Mitsuba.)
#[test]
fn furnace_gathers_pi_l_everywhere() {
    let mut m = mesh::sphere();
    m.normals = None;
    mesh::flip_normals(&mut m); // facing inwards
    let mut fx = Fixture::new(vec![shape("ball", m, None)], 24.0);
    let l = Vec3::new(0.5, 1.0, 2.0);
    fx.observe("ball", l);
    let (pts, vals) = fx.gather(0.1, 64);
    assert!(pts.points.len() > 100, "{} points", pts.points.len());
    let want = l * PI;
    let mut worst = 0.0f32;
    for v in &vals {
        worst = worst.max(((*v - want).abs() / want).max_element());
    }
    assert!(worst < 2e-3, "worst relative error {worst}");
}

/// A furnace (a closed sphere of observed radiance `L`) with a floor inside, and a cube resting
/// on the floor (sunk 0.01 into it), every surface observed at `L` but the floor under the
/// cube, which no camera can see. Every exposed floor point sees `L` in every direction, so
/// every observed floor texel must interpolate `E_i = pi L`. Regression: a gather point on a
/// buried texel (under the cube, seeing only the cube's back faces: `E_i = 0`) pulls the
/// observed texels around the cube down, by up to 77% of `pi L` on this grid, so `K_d = L / E`
/// comes out too high beside every object standing on a floor.
#[test]
fn observed_texels_beside_an_object_on_the_floor_gather_from_exposed_points() {
    let mut sky = mesh::sphere();
    sky.normals = None;
    mesh::flip_normals(&mut sky);
    sky.transform(&Mat4::from_scale(Vec3::splat(3.0)));
    let mut floor = mesh::rectangle();
    floor.transform(&Mat4::from_scale(Vec3::splat(1.5)));
    let mut cube = mesh::cube();
    cube.transform(
        &(Mat4::from_translation(Vec3::new(0.1, -0.2, 0.29)) * Mat4::from_scale(Vec3::splat(0.3))),
    );
    let mut fx = Fixture::new(
        vec![
            shape("sky", sky, None),
            shape("floor", floor, None),
            shape("cube", cube, None),
        ],
        8.0,
    );
    let l = Vec3::new(0.5, 1.0, 2.0);
    for id in ["sky", "floor", "cube"] {
        fx.observe(id, l);
    }
    // the floor under the cube is not observed
    let slot = fx.slot_of("floor");
    let layout = &fx.p.layout;
    let under = |p: Vec3| (p.x - 0.1).abs() < 0.3 && (p.y + 0.2).abs() < 0.3;
    map_tiles(&mut fx.state, &fx.geom, 4, |t, g, st| {
        if layout.slot_of_tile(t as u32) != slot {
            return;
        }
        for (g, s) in g.iter().zip(st.iter_mut()) {
            if g.covered() && under(g.p()) {
                *s = TexelState::default();
            }
        }
    })
    .unwrap();
    let (pts, vals) = fx.gather(0.5, 64);
    assert!(pts.stride(slot) >= 4, "stride {}", pts.stride(slot));
    let tc = fx.texel_charts(slot);
    let scratch = fx.scratch(1 << 30);
    let geom = SlotTexture::read(layout, slot, &fx.geom, &fx.geom, &scratch, "g", |g, _| *g)
        .unwrap()
        .to_vec();
    let st = layout.slots[slot];
    let want = l * PI;
    let (mut worst, mut near) = (0.0f32, 0);
    for y in 0..st.height {
        for x in 0..st.width {
            let i = (y * st.width + x) as usize;
            let (c, g) = (tc[i], geom[i]);
            if c == NONE || !g.covered() || under(g.p()) {
                continue;
            }
            let v = pts.interpolate(&vals, slot, x, y, c);
            worst = worst.max(((v - want).abs() / want).max_element());
            let p = g.p();
            near += ((p.x - 0.1).abs() < 0.5 && (p.y + 0.2).abs() < 0.5) as u32;
        }
    }
    assert!(near > 30, "{near} observed texels around the cube");
    assert!(
        worst < 5e-3,
        "worst relative error of an observed floor texel: {worst}"
    );
}

/// A unit square of radiance `L` one unit above a floor: at a floor point `E_i` is `L` times
/// the square's projected solid angle (Lambert's polygon formula).
#[test]
fn square_above_a_floor_matches_the_configuration_factor() {
    let mut floor = mesh::rectangle(); // z = 0 plane, normal +z
    floor.transform(&Mat4::from_scale(Vec3::splat(2.0)));
    let mut top = mesh::rectangle();
    mesh::flip_normals(&mut top); // facing down, towards the floor
    top.transform(
        &(Mat4::from_translation(Vec3::new(0.3, 0.0, 1.0)) * Mat4::from_scale(Vec3::splat(0.5))),
    );
    let mut fx = Fixture::new(
        vec![shape("floor", floor, None), shape("top", top, None)],
        8.0,
    );
    let l = Vec3::new(1.0, 2.0, 3.0);
    fx.observe("top", l);
    fx.observe("floor", Vec3::splat(7.0));
    let (pts, vals) = fx.gather(0.25, 4096);
    let corners = [(-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)]
        .map(|(x, y)| DVec3::new(0.3 + x, y, 1.0));
    let slot = fx.slot_of("floor");
    let floor_pts = slot_points(&fx, &pts, &vals, slot);
    assert!(floor_pts.len() > 20);
    let want: Vec<Vec3> = floor_pts
        .iter()
        .map(|(pt, _)| {
            let poly: Vec<DVec3> = corners.iter().map(|c| *c - pt.p.as_dvec3()).collect();
            l * projected_solid_angle(&poly, DVec3::Z) as f32
        })
        .collect();
    // Far points see the square through a few dozen of the 4096 rays (the stratified grid
    // catches its edges only to a few rays): within 2% of the largest value at every point,
    // and unbiased over the floor.
    let peak = want.iter().fold(Vec3::ZERO, |a, w| a.max(*w));
    let (mut sum_got, mut sum_want) = (Vec3::ZERO, Vec3::ZERO);
    for ((pt, v), w) in floor_pts.iter().zip(&want) {
        let err = ((*v - *w).abs() / peak).max_element();
        assert!(err < 0.02, "at {}: {v} vs {w} ({err} of the peak)", pt.p);
        sum_got += *v;
        sum_want += *w;
    }
    let mean_err = ((sum_got - sum_want).abs() / sum_want).max_element();
    eprintln!(
        "configuration factor: mean over {} floor points off by {mean_err:.5}",
        want.len()
    );
    assert!(mean_err < 0.003, "mean over the floor off by {mean_err}");
}

/// The floor `[-2, 0] x [-1, 1]` facing up, and a 0.5 x 0.5 square facing down, 1 above
/// it centred at `x = -0.3`: the mirror tests' scene beside [`mirror_wall`].
fn floor_and_square() -> (Mesh, Mesh) {
    let mut floor = mesh::rectangle();
    floor.transform(&Mat4::from_translation(Vec3::new(-1.0, 0.0, 0.0)));
    let mut square = mesh::rectangle();
    mesh::flip_normals(&mut square);
    square.transform(
        &(Mat4::from_translation(Vec3::new(-0.3, 0.0, 1.0)) * Mat4::from_scale(Vec3::splat(0.25))),
    );
    (floor, square)
}

/// A perfect mirror in the plane `x = 0`, facing `-x`, 6 x 6 from `z = 0`.
fn mirror_wall() -> Shape {
    let mut mirror = mesh::rectangle();
    mirror.transform(
        &(Mat4::from_translation(Vec3::new(0.0, 0.0, 3.0))
            * Mat4::from_rotation_y(-std::f32::consts::FRAC_PI_2)
            * Mat4::from_scale(Vec3::splat(3.0))),
    );
    let mut mirror = shape("mirror", mirror, None);
    mirror.material =
        crate::scene::Material::Known(Box::new(crate::scene::KnownMaterial::perfect_mirror()));
    mirror
}

/// A light seen in a mirror brings a gather nothing: that light is a caustic, in `E_d` from
/// the caustic photon pass (`photon::Paths::Caustic`). The floor of the test below under an
/// emitting square and the mirror gathers exactly 0, not the light's image.
#[test]
fn a_light_in_a_mirror_is_not_gathered() {
    let (floor, lamp) = floor_and_square();
    let lamp = shape("lamp", lamp, Some(Vec3::splat(5.0)));
    let mut fx = Fixture::new(vec![shape("floor", floor, None), lamp, mirror_wall()], 8.0);
    fx.observe("floor", Vec3::ZERO);
    let (pts, vals) = fx.gather(0.25, 1024);
    let floor_pts = slot_points(&fx, &pts, &vals, fx.slot_of("floor"));
    assert!(floor_pts.len() > 10);
    assert!(floor_pts.iter().all(|(_, v)| *v == Vec3::ZERO));
}

/// A mirror doubles what a floor sees: the square of the test above at `x = -0.3`, and a
/// perfect mirror in the plane `x = 0` (facing the floor, which ends at it): `E_i` is `L`
/// times the projected solid angle of the square plus that of its mirror image at `x = +0.3`.
#[test]
fn a_square_and_its_mirror_image_match_two_configuration_factors() {
    let (floor, top) = floor_and_square();
    let mut fx = Fixture::new(
        vec![
            shape("floor", floor, None),
            shape("top", top, None),
            mirror_wall(),
        ],
        8.0,
    );
    let l = Vec3::new(1.0, 2.0, 3.0);
    fx.observe("top", l);
    fx.observe("floor", Vec3::ZERO);
    let (pts, vals) = fx.gather(0.25, 4096);
    let square = |cx: f64| {
        [(-0.25, -0.25), (0.25, -0.25), (0.25, 0.25), (-0.25, 0.25)]
            .map(|(x, y)| DVec3::new(cx + x, y, 1.0))
    };
    let floor_pts = slot_points(&fx, &pts, &vals, fx.slot_of("floor"));
    assert!(floor_pts.len() > 10);
    let (mut sum_got, mut sum_want, mut peak) = (Vec3::ZERO, Vec3::ZERO, Vec3::ZERO);
    let want: Vec<Vec3> = floor_pts
        .iter()
        .map(|(pt, _)| {
            let psa = |c: [DVec3; 4]| {
                let poly: Vec<DVec3> = c.iter().map(|c| *c - pt.p.as_dvec3()).collect();
                projected_solid_angle(&poly, DVec3::Z)
            };
            l * (psa(square(-0.3)) + psa(square(0.3))) as f32
        })
        .collect();
    for w in &want {
        peak = peak.max(*w);
    }
    for ((pt, v), w) in floor_pts.iter().zip(&want) {
        let err = ((*v - *w).abs() / peak).max_element();
        assert!(err < 0.02, "at {}: {v} vs {w} ({err} of the peak)", pt.p);
        sum_got += *v;
        sum_want += *w;
    }
    let mean_err = ((sum_got - sum_want).abs() / sum_want).max_element();
    assert!(mean_err < 0.005, "mean over the floor off by {mean_err}");
    // the image is a real share of it (a gather blind to the mirror would fail above)
    let real: f64 = floor_pts
        .iter()
        .map(|(pt, _)| {
            let poly: Vec<DVec3> = square(-0.3).iter().map(|c| *c - pt.p.as_dvec3()).collect();
            projected_solid_angle(&poly, DVec3::Z)
        })
        .sum();
    assert!(sum_want.x as f64 > 1.3 * real, "{} vs {real}", sum_want.x);
}

/// The back of a one-sided surface, an emitter and an unobserved texel (its current estimate
/// `K_d (E_d + E_i) / pi`) under the same square.
#[test]
fn back_faces_emitters_and_unobserved_texels() {
    let build = |flip: bool, emission: Option<Vec3>| {
        let mut top = mesh::rectangle();
        if flip {
            mesh::flip_normals(&mut top);
        }
        top.transform(&(Mat4::from_translation(Vec3::Z) * Mat4::from_scale(Vec3::splat(0.5))));
        Fixture::new(
            vec![
                shape("floor", mesh::rectangle(), None),
                shape("top", top, emission),
            ],
            8.0,
        )
    };
    let floor_mean = |fx: &Fixture| {
        let (pts, vals) = fx.gather(0.25, 256);
        let v = slot_points(fx, &pts, &vals, fx.slot_of("floor"));
        v.iter().map(|(_, e)| *e).sum::<Vec3>() / v.len() as f32
    };
    // facing away from the floor: the floor sees its back, which reflects nothing
    let mut fx = build(false, None);
    fx.observe("top", Vec3::ONE);
    assert_eq!(floor_mean(&fx), Vec3::ZERO);
    // facing the floor but an emitter: its light is E_d, not E_i
    let fx = build(true, Some(Vec3::splat(10.0)));
    assert_eq!(floor_mean(&fx), Vec3::ZERO);
    // unobserved: K_d (E_d + E_i) / pi = 0.5 (2 + 1) / pi, the same as observing it
    let mut fx = build(true, None);
    fx.set("top", |s| {
        s.k_d = [0.5; 3];
        s.e_d = [2.0; 3];
        s.e_i = [1.0; 3];
    });
    let unobserved = floor_mean(&fx);
    fx.observe("top", Vec3::splat(1.5 / PI));
    let observed = floor_mean(&fx);
    assert!(unobserved.x > 0.0);
    assert!(((unobserved - observed).abs() / observed).max_element() < 1e-5);
}

/// Interpolation reproduces a constant and never mixes charts: with every point of a cube
/// (six charts at least) valued by its chart, each texel gets exactly its chart's value.
#[test]
fn interpolation_stays_within_the_chart() {
    let fx = Fixture::new(vec![shape("cube", mesh::cube(), None)], 16.0);
    let pts = fx.points(0.3);
    assert!(pts.stride(0) > 1);
    assert!(interpolates_each_chart_alone(&fx, &pts) > 100);
}

/// With every point of slot 0 valued by its chart (`chart + 1`), checks that each covered
/// texel of slot 0 interpolates exactly its own chart's value; returns how many were checked.
fn interpolates_each_chart_alone(fx: &Fixture, pts: &GatherPoints) -> usize {
    let vals: Vec<Vec3> = pts
        .points
        .iter()
        .map(|p| Vec3::splat(p.chart as f32 + 1.0))
        .collect();
    let tc = &fx.texel_charts(0);
    let st = fx.p.layout.slots[0];
    let mut n = 0;
    for y in 0..st.height {
        for x in 0..st.width {
            let c = tc[(y * st.width + x) as usize];
            if c == NONE {
                continue;
            }
            let v = pts.interpolate(&vals, 0, x, y, c);
            let want = c as f32 + 1.0;
            assert!((v - want).abs().max_element() < 1e-5, "({x}, {y}): {v}");
            n += 1;
        }
    }
    n
}

/// On an atlas with density levels the points stay `spacing` apart on every level: the
/// cube's faces at levels 0, 1 and 2 (texels 1, 2 and 4 times as wide) get the same number
/// of points each, and every texel still interpolates its own chart only.
#[test]
fn points_are_spacing_apart_on_every_density_level() {
    let levels: Vec<u8> = (0..12).map(|t| (t / 4) as u8).collect();
    let fx = Fixture::with_levels(vec![shape("cube", mesh::cube(), None)], 32.0, vec![levels]);
    assert_eq!(fx.p.atlases[0].as_ref().unwrap().levels, 2);
    let pts = fx.points(0.25);
    // a 2 x 2 face at spacing 0.25: about 8 x 8 points, on every level
    let mut per_level = [0usize; 3];
    for p in &pts.points {
        let tri = fx.charts.slots[0]
            .tri_chart
            .iter()
            .position(|&c| c == p.chart)
            .unwrap();
        per_level[tri / 4] += 1;
    }
    for (l, n) in per_level.iter().enumerate() {
        // two faces per level
        assert!((100..=200).contains(n), "level {l}: {per_level:?}");
    }
    assert!(interpolates_each_chart_alone(&fx, &pts) > 100);
}

/// Bilinear radiance lookups read only the hit chart's texels: next to a chart border the
/// other chart's (very different) values never leak in.
#[test]
fn radiance_lookup_ignores_other_charts() {
    let mut fx = Fixture::new(vec![shape("cube", mesh::cube(), None)], 16.0);
    fx.observe("cube", Vec3::ONE);
    // poison every texel of chart 0
    let tc = fx.texel_charts(0);
    let (w, h) = (fx.p.layout.slots[0].width, fx.p.layout.slots[0].height);
    let layout = fx.p.layout.clone();
    map_tiles(&mut fx.state, &fx.geom, 4, |t, _, st| {
        for (o, s) in st.iter_mut().enumerate() {
            if let Some((0, x, y)) = layout.texel_of(t as u32, o as u32) {
                if tc[(y * w + x) as usize] == 0 {
                    s.l_orig = [1e6; 3];
                }
            }
        }
    })
    .unwrap();
    let rad = fx.radiance(1 << 30);
    let mut checked = 0;
    for y in 0..h {
        for x in 0..w {
            let c = tc[(y * w + x) as usize];
            if c == NONE || c == 0 {
                continue;
            }
            for (dx, dy) in [(0.0, 0.0), (0.9, 0.1), (0.5, 0.99)] {
                let uv = Vec2::new(x as f32 + dx, y as f32 + dy);
                assert_eq!(rad.lookup(0, uv, c), (Vec3::ONE, true), "({x}, {y})");
                checked += 1;
            }
        }
    }
    assert!(checked > 100);
}

/// The same points and values with 1 and 2 worker threads, bit for bit.
#[test]
fn gather_is_bit_identical_across_thread_counts() {
    let mut m = mesh::sphere();
    mesh::flip_normals(&mut m);
    let mut inner = mesh::sphere();
    inner.transform(
        &(Mat4::from_translation(Vec3::new(0.2, 0.1, 0.0)) * Mat4::from_scale(Vec3::splat(0.3))),
    );
    let mut fx = Fixture::new(
        vec![shape("room", m, None), shape("ball", inner, None)],
        12.0,
    );
    fx.observe("room", Vec3::new(0.3, 0.2, 0.1));
    fx.set("ball", |s| {
        s.k_d = [0.4; 3];
        s.e_d = [1.0, 2.0, 3.0];
    });
    let run = |threads| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| fx.gather(0.2, 16).1)
    };
    let (a, b) = (run(1), run(2));
    assert_eq!(a, b);
}

/// An observed spherical room (inward normals) around an unobserved ball of radius 0.3 at
/// `at`, whose texels hold a first estimate (`K_d`, `E_d`): hits on it are cached.
fn room_with_ball(at: Vec3) -> Fixture {
    let mut m = mesh::sphere();
    mesh::flip_normals(&mut m);
    let mut inner = mesh::sphere();
    inner.transform(&(Mat4::from_translation(at) * Mat4::from_scale(Vec3::splat(0.3))));
    let mut fx = Fixture::new(
        vec![shape("room", m, None), shape("ball", inner, None)],
        12.0,
    );
    fx.observe("room", Vec3::new(0.3, 0.2, 0.1));
    fx.set("ball", |s| {
        s.k_d = [0.4; 3];
        s.e_d = [1.0, 2.0, 3.0];
    });
    fx
}

/// The next iteration's estimates on [`room_with_ball`]'s ball.
fn next_estimates(fx: &mut Fixture) {
    fx.set("ball", |s| {
        s.k_d = [0.8, 0.5, 0.2];
        s.e_i = [0.5; 3];
    });
}

/// Rays cast once and their unobserved hits re-read with new estimates give what casting the
/// rays again with those estimates gives (the cache is exact, not an approximation).
#[test]
fn cached_hits_reevaluate_like_a_fresh_trace() {
    let mut fx = room_with_ball(Vec3::new(0.2, 0.1, 0.0));
    let points = fx.points(0.2);
    let trace = |fx: &Fixture| {
        let radiance = fx.radiance(1 << 30);
        let cache = trace_points(&fx.context(&radiance, 36), &points, &no_tick);
        (cache, radiance)
    };
    let (cache, _) = trace(&fx);
    assert!(cache.stats.cached_hits > 0 && cache.stats.cached_hits < cache.stats.rays);
    // what report.json's `gather_cached_hits` documents a kept hit to cost
    assert_eq!(std::mem::size_of::<CachedHit>(), 36);
    let kept: usize = cache.hits.iter().map(|h| h.len()).sum();
    assert_eq!(kept as u64, cache.stats.cached_hits);
    // the ball's estimate changes; the room (observed) does not
    next_estimates(&mut fx);
    let (fresh, radiance) = trace(&fx);
    let ctx = fx.context(&radiance, 36);
    let (a, _) = cache.evaluate(&ctx, &points);
    let (b, _) = fresh.evaluate(&ctx, &points);
    for (a, b) in a.iter().zip(&b) {
        assert!(
            (*a - *b).abs().max_element() <= 1e-5 * b.max_element().max(1e-3),
            "{a} vs {b}"
        );
    }
}

/// Through a cache of a few tiles, a lookup at a texel's center returns that texel's own
/// outgoing radiance, read straight from the state: the store, its tile addressing and the
/// cache agree with the state for every covered texel.
#[test]
fn radiance_through_a_tiny_cache_reads_each_texel() {
    let mut fx = Fixture::new(vec![shape("cube", mesh::cube(), None)], 24.0);
    fx.set("cube", |s| s.e_d = [1.0, 2.0, 3.0]);
    let layout = fx.p.layout.clone();
    // a different K_d in every texel, observed radiance in every third
    map_tiles(&mut fx.state, &fx.geom, 4, |t, _, st| {
        for (o, s) in st.iter_mut().enumerate() {
            let i = (t * 4096 + o) as f32;
            s.k_d = [0.1 + (i % 7.0) * 0.1, 0.2, 0.3 + (i % 3.0) * 0.1];
            if (t + o) % 3 == 0 {
                s.flags |= flags::OBSERVED;
                s.l_orig = [i, 0.5, 0.25];
            }
        }
    })
    .unwrap();
    let rad = fx.radiance(1);
    let (st, tc) = (&layout.slots[0], &fx.texel_charts(0));
    let mut checked = 0;
    for t in 0..layout.tile_count {
        let (g, s) = (
            fx.geom.read_tile(t as usize).unwrap(),
            fx.state.read_tile(t as usize).unwrap(),
        );
        for o in 0..layout.tile_texels() {
            let Some((slot, x, y)) = layout.texel_of(t, o as u32) else {
                continue;
            };
            let c = tc[(y * st.width + x) as usize];
            if c == NONE || !g[o].covered() {
                continue;
            }
            let want = if s[o].flags & flags::OBSERVED != 0 {
                Vec3::from_array(s[o].l_orig)
            } else {
                Vec3::from_array(s[o].k_d) / PI * Vec3::new(1.0, 2.0, 3.0)
            };
            let uv = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
            let (l, fixed) = rad.lookup(slot, uv, c);
            assert_eq!(l, want, "texel ({x}, {y})");
            // zero-weight neighbours count too, so fixed implies only this texel observed
            assert!(!fixed || s[o].flags & flags::OBSERVED != 0);
            checked += 1;
        }
    }
    rad.check().unwrap();
    assert!(checked > 1000, "{checked}");
}

/// A floor (`[-2, 2]^2`, facing up) under a 1 x 1 square facing down, 1 above it at
/// `x = 0.3`, the floor observed black: the variance tests' scene (the square's edge is the
/// gather's only variance).
fn floor_under_square() -> Fixture {
    let mut floor = mesh::rectangle();
    floor.transform(&Mat4::from_scale(Vec3::splat(2.0)));
    let mut top = mesh::rectangle();
    mesh::flip_normals(&mut top);
    top.transform(
        &(Mat4::from_translation(Vec3::new(0.3, 0.0, 1.0)) * Mat4::from_scale(Vec3::splat(0.5))),
    );
    let mut fx = Fixture::new(
        vec![shape("floor", floor, None), shape("top", top, None)],
        8.0,
    );
    fx.observe("floor", Vec3::splat(0.0));
    fx
}

/// The variance counts hits on unobserved texels at the radiance of each evaluation, paired
/// as the observed ones are: a square of light seen as observed radiance 2, or unobserved with
/// `K_d E / pi = 2`, gives every point the same `E_i` and the same variance.
#[test]
fn gather_variance_treats_unobserved_hits_as_observed_ones() {
    let mut seen = floor_under_square();
    seen.observe("top", Vec3::splat(2.0));
    let mut unseen = floor_under_square();
    unseen.set("top", |s| {
        s.e_d = [1.0; 3];
        s.k_d = [2.0 * PI; 3];
    });
    let (a, b) = (
        seen.gather_variance(0.25, 64, 3),
        unseen.gather_variance(0.25, 64, 3),
    );
    let close = |x: f32, y: f32| (x - y).abs() <= 1e-4 * x.abs().max(y.abs()) + 1e-9;
    let mut lit = 0;
    for ((ea, va), (eb, vb)) in a.iter().zip(&b) {
        assert!(
            close(ea.x, eb.x) && close(*va, *vb),
            "{ea} {va} vs {eb} {vb}"
        );
        lit += (*va > 0.0) as u32;
    }
    assert!(lit > 10, "{lit} points see the square's edge");
}

/// Closed form of the collapsed-strata variance: `k x k` strata, `k (k / 2)` pairs whose
/// squared differences sum to `pairs` estimate `sum sigma_h^2` (scaled up for the unpaired
/// stratum of each row when `k` is odd); `E = pi / N sum y`, so its variance is
/// `pi^2 sum sigma_h^2 / N^2`. One ray gives no estimate.
#[test]
fn pair_variance_is_the_collapsed_strata_closed_form() {
    let pi2 = std::f32::consts::PI.powi(2);
    let v = super::pair_variance(2.0, 2);
    assert!((v - pi2 * 2.0 / 16.0).abs() < 1e-6, "{v}");
    let v = super::pair_variance(3.0, 3);
    assert!((v - pi2 * 3.0 * 1.5 / 81.0).abs() < 1e-6, "{v}");
    assert_eq!(super::pair_variance(5.0, 1), 0.0);
}

/// The variance of an interpolated `E_i` against Monte Carlo: every point gets independent
/// normal values of its own variance, 400 draws; at every covered texel the spread of the
/// interpolated values is `interpolate_variance` (within 15% over all texels), and
/// interpolating the variances linearly would overstate it by more than 20%.
#[test]
fn interpolated_variance_is_the_spread_of_interpolated_values() {
    let fx = Fixture::new(vec![shape("cube", mesh::cube(), None)], 16.0);
    let pts = fx.points(0.3);
    let var: Vec<Vec3> = (0..pts.points.len())
        .map(|i| Vec3::new(0.5 + (i % 7) as f32 * 0.25, 0.0, 0.0))
        .collect();
    let draws: Vec<Vec<Vec3>> = (0..400u64)
        .map(|d| {
            var.iter()
                .enumerate()
                .map(|(i, v)| Vec3::splat(v.x.sqrt() * Rng::new(9, d, i as u64, 0).normal()))
                .collect()
        })
        .collect();
    let tc = &fx.texel_charts(0);
    let st = fx.p.layout.slots[0];
    let (mut spread, mut predicted, mut linear) = (0.0f64, 0.0f64, 0.0f64);
    for y in 0..st.height {
        for x in 0..st.width {
            let c = tc[(y * st.width + x) as usize];
            if c == NONE {
                continue;
            }
            let vals: Vec<f64> = draws
                .iter()
                .map(|d| pts.interpolate(d, 0, x, y, c).x as f64)
                .collect();
            spread += vals.iter().map(|v| v * v).sum::<f64>() / vals.len() as f64;
            predicted += pts.interpolate_variance(&var, 0, x, y, c) as f64;
            linear += pts.interpolate(&var, 0, x, y, c).x as f64;
        }
    }
    eprintln!(
        "interpolated variance: spread {spread:.1}, predicted {predicted:.1}, linear {linear:.1}"
    );
    assert!(
        (predicted / spread - 1.0).abs() < 0.15,
        "{predicted} vs {spread}"
    );
    assert!(linear > 1.2 * spread, "{linear} vs {spread}");
}

/// The predicted variance of `E_i` is none in a furnace (every ray sees the same radiance),
/// and elsewhere an upper bound of the spread over seeds, but a close one: a square of light
/// above a floor, 64 rays per point, 24 seeds (the collapsed strata of `pair_variance` give
/// 2.0x the spread; the sample variance over the rays, which ignores the stratification,
/// 2.7x).
#[test]
fn gather_variance_is_zero_in_a_furnace_and_bounds_the_spread_over_seeds() {
    let mut m = mesh::sphere();
    m.normals = None;
    mesh::flip_normals(&mut m);
    let mut fx = Fixture::new(vec![shape("ball", m, None)], 24.0);
    fx.observe("ball", Vec3::new(0.5, 1.0, 2.0));
    let furnace = fx.gather_variance(0.1, 64, 5);
    let e = luminance(furnace[0].0);
    assert!(
        furnace.iter().all(|(_, v)| *v <= 1e-8 * e * e),
        "{:?}",
        &furnace[..3]
    );

    let mut fx = floor_under_square();
    fx.observe("top", Vec3::splat(2.0));
    let runs: Vec<Vec<(Vec3, f32)>> = (0..24)
        .map(|seed| fx.gather_variance(0.25, 64, seed))
        .collect();
    let (mut predicted, mut spread) = (0.0f64, 0.0f64);
    for i in 0..runs[0].len() {
        let ys: Vec<f64> = runs.iter().map(|r| luminance(r[i].0) as f64).collect();
        let mean = ys.iter().sum::<f64>() / ys.len() as f64;
        spread += ys.iter().map(|y| (y - mean).powi(2)).sum::<f64>() / (ys.len() - 1) as f64;
        predicted += runs.iter().map(|r| r[i].1 as f64).sum::<f64>() / runs.len() as f64;
    }
    eprintln!("E_i variance: predicted {predicted:.3e}, over seeds {spread:.3e}");
    assert!(
        spread > 0.0 && predicted >= 0.9 * spread,
        "{predicted} vs {spread}"
    );
    assert!(
        predicted < 2.5 * spread,
        "{predicted} vs {spread}: too loose to be of use"
    );
}

/// The plane fit's intercept weights: the mean on a full 3 x 3 grid; a plane recovered
/// exactly from a one-sided set (a chart's corner); nothing from two points or a line.
#[test]
fn intercept_weights_fit_a_plane() {
    let grid: Vec<(usize, f64, f64)> = (0..9)
        .map(|k| (k, (k % 3) as f64 - 1.0, (k / 3) as f64 - 1.0))
        .collect();
    for w in intercept_weights(&grid).unwrap() {
        assert!((w - 1.0 / 9.0).abs() < 1e-12, "{w}");
    }
    let plane = |x: f64, y: f64| 2.0 + 0.5 * x - 0.25 * y;
    let corner = [(0, 0.0, 0.0), (1, 3.0, 0.0), (2, 0.0, 3.0), (3, 3.0, 3.0)];
    let a = intercept_weights(&corner).unwrap();
    let fit: f64 = corner
        .iter()
        .zip(&a)
        .map(|(&(_, x, y), w)| w * plane(x, y))
        .sum();
    assert!((fit - 2.0).abs() < 1e-12, "{fit}");
    assert!(intercept_weights(&corner[..2]).is_none());
    let line = [(0, 0.0, 0.0), (1, 1.0, 1.0), (2, 2.0, 2.0), (3, -1.0, -1.0)];
    assert!(intercept_weights(&line).is_none());
}

/// The points' filter against closed forms. On a flat 2 x 2 chart, points 0.1 apart carry
/// `E_i` = a slope (1 standard error per cell along x) plus noise of that standard error,
/// and a step of 12 standard errors at `x = 0`. Away from the step and the border the
/// noise's RMS falls 2.5-fold (a full 3 x 3 plane fit takes it to a third; a neighbour
/// whose noise departs by more than `z` is left out), and the predicted variance with it;
/// along the borders across the slope it comes through nearly unbiased (0.07 and -0.25
/// standard errors; the mean of the agreeing neighbours instead of the plane: 0.55 and
/// -0.40); next to the step
/// no point is pulled across it (mixing in its three neighbours over the step would move it
/// by 4 standard errors).
#[test]
fn the_points_filter_averages_noise_and_keeps_slopes_and_steps() {
    use crate::atlas::testing::jitter;
    let fx = Fixture::new(vec![shape("floor", mesh::rectangle(), None)], 40.0);
    let pts = fx.points(0.1);
    let sigma = 0.02f32;
    let truth = |p: Vec3| 1.0 + 0.2 * p.x + 0.1 * p.y + if p.x > 0.0 { 12.0 * sigma } else { 0.0 };
    let values: Vec<Vec3> = (pts.points.iter().enumerate())
        .map(|(i, p)| Vec3::splat(truth(p.p) + sigma * 3f32.sqrt() * jitter(i)))
        .collect();
    let var = vec![Vec3::new(sigma * sigma, 0.0, 0.0); values.len()];
    let (f, fv) = pts.filtered(&values, &var, POINT_FILTER_Z);
    assert!(pts.points.len() > 300, "{}", pts.points.len());
    let (mut before, mut after, mut n) = (0.0f64, 0.0f64, 0);
    let (mut border, mut nb) = ([0.0f64; 2], [0usize; 2]);
    let (mut before_in, mut after_in) = (0.0f64, 0.0f64);
    for (i, p) in pts.points.iter().enumerate() {
        let t = truth(p.p);
        let e = (f[i].x - t) as f64;
        if p.p.x.abs() > 0.15 {
            before += ((values[i].x - t) as f64).powi(2);
            after += e * e;
            n += 1;
            assert!(fv[i].x <= var[i].x, "{i}: {}", fv[i].x);
            if p.p.x.abs() > 0.9 {
                let side = (p.p.x > 0.0) as usize;
                border[side] += e;
                nb[side] += 1;
            } else if p.p.y.abs() < 0.9 {
                before_in += ((values[i].x - t) as f64).powi(2);
                after_in += e * e;
            }
        } else {
            assert!(e.abs() < 3.0 * sigma as f64, "{:?}: off by {e}", p.p);
        }
    }
    let (ratio, inner) = ((after / before).sqrt(), (after_in / before_in).sqrt());
    let bias = [0, 1].map(|k| border[k] / nb[k] as f64 / sigma as f64);
    eprintln!(
        "noise RMS after / before {ratio:.3} over {n} points ({inner:.3} off the border); \
         bias on the borders across the slope {bias:.3?} sigma over {nb:?} points"
    );
    assert!(inner < 0.5 && ratio < 0.6, "{inner} {ratio}");
    assert!(bias.iter().all(|b| b.abs() < 0.35), "{bias:?}");
    // off, nothing moves
    assert_eq!(
        pts.filtered(&values, &var, 0.0),
        (values.clone(), var.clone())
    );
}

/// A cache held under a byte limit gives the same bits as one that keeps every hit: the
/// points left out cast the same rays again, at this iteration's radiance.
#[test]
fn a_cache_over_its_limit_retraces_to_the_same_bits() {
    let mut fx = room_with_ball(Vec3::ZERO);
    let points = fx.points(0.2);
    let radiance = fx.radiance(1 << 30);
    let ctx = fx.context(&radiance, 36);
    let all = trace_points(&ctx, &points, &no_tick);
    let half = super::budget::hit_bytes(all.stats.cached_hits as usize / 2);
    let some = trace_points_where(&ctx, &points, (&|_| true, half), &no_tick);
    let none = trace_points_where(&ctx, &points, (&|_| true, 0), &no_tick);
    assert_eq!(all.stats.retraced_points, 0);
    assert!(some.stats.retraced_points > 0 && some.stats.cached_hits <= all.stats.cached_hits / 2);
    assert!(none.stats.cached_hits == 0 && none.stats.retraced_points > 0);
    drop(radiance);
    next_estimates(&mut fx);
    let radiance = fx.radiance(1 << 30);
    let ctx = fx.context(&radiance, 36);
    let want = all.evaluate(&ctx, &points);
    assert!(want.0.iter().any(|v| v.max_element() > 0.0));
    assert_eq!(some.evaluate(&ctx, &points), want);
    assert_eq!(none.evaluate(&ctx, &points), want);
}

/// Many small shapes: their own spacings (a sixteenth of each one's radius) would place far
/// more points than the cap; the floor brings them under it, and a cap they fit leaves them
/// exactly as placed without one.
#[test]
fn the_points_of_many_small_shapes_are_capped() {
    let balls: Vec<Shape> = (0..24)
        .map(|i| {
            let mut m = mesh::sphere();
            let at = Vec3::new((i % 6) as f32 * 0.3, (i / 6) as f32 * 0.3, 0.0);
            m.transform(&(Mat4::from_translation(at) * Mat4::from_scale(Vec3::splat(0.1))));
            shape(&format!("ball_{i}"), m, None)
        })
        .collect();
    let fx = Fixture::new(balls, 160.0);
    let spacing: Vec<f32> = fx.p.scene.shapes.iter().map(|_| 0.1 / 16.0).collect();
    let stores = (&fx.geom, &fx.state, &fx.charts);
    let scratch = fx.scratch(1 << 30);
    let free = GatherPoints::new(
        &fx.p,
        &fx.geom,
        &fx.state,
        &fx.charts,
        &|s| spacing[s],
        &scratch,
        &no_tick,
    )
    .unwrap();
    let n = free.points.len();
    let (same, floor) =
        super::budget::capped_points(&fx.p, stores, &spacing, n, &scratch, &no_tick).unwrap();
    assert_eq!((floor, &same), (0.0, &free));
    let cap = n / 8;
    let (few, floor) =
        super::budget::capped_points(&fx.p, stores, &spacing, cap, &scratch, &no_tick).unwrap();
    assert!(floor > spacing[0], "floor {floor}");
    assert!(
        few.points.len() <= cap && few.points.len() > cap / 4,
        "{} of {cap}",
        few.points.len()
    );
}

/// Points no observed texel reads (none of their chart within [`LEAN_REACH`] cells lies on an
/// observed texel, by brute force over the points) are lean and cast the lean rays; the others
/// gather bit-identically to a run where every point casts all its rays, and the lean ones
/// agree with it on average.
#[test]
fn lean_points_are_those_no_observed_texel_reads() {
    let mut fx = floor_under_square();
    fx.set("floor", |s| {
        (s.weight, s.flags) = (0.0, s.flags & !flags::OBSERVED);
        (s.e_d, s.k_d) = ([1.0; 3], [0.5; 3]);
    });
    fx.observe_where("floor", Vec3::splat(0.1), &|p| p.x < -0.5);
    fx.set("top", |s| (s.e_d, s.k_d) = ([1.0; 3], [2.0 * PI; 3]));
    let pts = fx.points(0.25);
    let stride = |p: &Point| pts.stride(fx.p.layout.slot_of_shape(p.shape as usize).unwrap());
    let cell = |p: &Point| ((p.x / stride(p)) as i64, (p.y / stride(p)) as i64);
    let on_observed = |p: &Point| p.shape == 0 && p.p.x < -0.5;
    for p in &pts.points {
        let read = pts.points.iter().any(|q| {
            let ((a, b), (c, d)) = (cell(p), cell(q));
            let near = (a - c).abs() <= LEAN_REACH && (b - d).abs() <= LEAN_REACH;
            q.shape == p.shape && q.chart == p.chart && near && on_observed(q)
        });
        assert_eq!(p.lean, !read, "point at {} of shape {}", p.p, p.shape);
    }
    let lean = pts.lean_points();
    assert!(
        lean > 20 && lean + 20 < pts.points.len(),
        "{lean} lean points"
    );
    let (full, full_var, full_rays) = fx.gather_lean(&pts, (64, 64), 3);
    let (cut, cut_var, cut_rays) = fx.gather_lean(&pts, (64, 16), 3);
    // the lean points' summed E_i (luminance: every channel alike here) and its variance
    let (mut a, mut b, mut var) = (0.0f64, 0.0f64, 0.0f64);
    for (i, p) in pts.points.iter().enumerate() {
        match p.lean {
            false => assert_eq!(full[i], cut[i], "a point an observed texel reads changed"),
            true => {
                (a, b) = (a + full[i].x as f64, b + cut[i].x as f64);
                var += (full_var[i] + cut_var[i]) as f64;
            }
        }
    }
    assert!(a > 0.0 && var > 0.0, "{a} {var}");
    let z = (b - a) / var.sqrt();
    assert!(
        z.abs() < 4.0,
        "lean points' E_i {a} -> {b}: {z:.1} standard errors"
    );
    let want = full_rays - (lean as u64) * (64 - 16);
    assert_eq!(cut_rays, want, "rays {full_rays} -> {cut_rays}");
}
