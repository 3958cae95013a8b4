//! Ray casting over the whole scene: one obvhs CWBVH over every triangle of every shape.
//!
//! Closest hit returns (shape, triangle, barycentrics, distance); `occluded` answers shadow
//! rays with `ray_traverse_miss`, which stops at the first hit (obvhs' any-hit traversal does
//! not). obvhs reports primitive ids in BVH order, so we keep our triangles in that order and
//! map back through `primitive_indices` once, at build time. Its triangle test is not
//! watertight, so callers offset ray origins with [`offset_origin`].

use crate::scene::Scene;
use glam::{UVec2, Vec3, Vec3A};
use obvhs::{
    cwbvh::{builder::build_cwbvh_from_tris, CwBvh},
    ray::{Ray, RayHit},
    triangle::Triangle,
    BvhBuildParams,
};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

/// A closest-hit record.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// Index into `Scene::shapes`.
    pub shape: u32,
    /// Triangle index within that shape's mesh.
    pub tri: u32,
    /// Barycentric weights of vertices 1 and 2 (vertex 0 gets `1 - b1 - b2`).
    pub b1: f32,
    pub b2: f32,
    /// Distance along the (unit) ray direction.
    pub t: f32,
    /// The BVH primitive index (see [`Accel::prim_ids`]).
    pub prim: u32,
}

/// The scene's acceleration structure. Immutable and `Sync`: share it across threads.
pub struct Accel {
    /// Rays cast so far (see [`Accel::rays`]).
    rays: RayCount,
    bvh: CwBvh,
    /// Triangles in BVH primitive order.
    tris: Vec<Triangle>,
    /// (shape, triangle) for each BVH primitive.
    ids: Vec<(u32, u32)>,
}

impl Accel {
    /// Build over all shapes of the scene (emitters included: they occlude too).
    pub fn build(scene: &Scene) -> Accel {
        let mut tris = Vec::with_capacity(scene.triangle_count());
        let mut ids = Vec::with_capacity(scene.triangle_count());
        for (si, s) in scene.shapes.iter().enumerate() {
            for t in 0..s.mesh.triangles.len() {
                let [a, b, c] = s.mesh.triangle(t);
                tris.push(Triangle {
                    v0: a.into(),
                    v1: b.into(),
                    v2: c.into(),
                });
                ids.push((si as u32, t as u32));
            }
        }
        Self::from_triangles(tris, ids)
    }

    /// Build from a raw triangle soup (`ids` names each triangle's (shape, tri)).
    pub fn from_triangles(tris: Vec<Triangle>, ids: Vec<(u32, u32)>) -> Accel {
        assert_eq!(tris.len(), ids.len());
        if tris.is_empty() {
            return Accel {
                rays: RayCount::default(),
                bvh: CwBvh::default(),
                tris,
                ids,
            };
        }
        let bvh = build_cwbvh_from_tris(
            &tris,
            BvhBuildParams::medium_build(),
            &mut Duration::default(),
        );
        let order = &bvh.primitive_indices;
        let tris_o = order.iter().map(|&i| tris[i as usize]).collect();
        let ids_o = order.iter().map(|&i| ids[i as usize]).collect();
        Accel {
            rays: RayCount::default(),
            bvh,
            tris: tris_o,
            ids: ids_o,
        }
    }

    /// Rays cast so far by this process ([`Accel::intersect`] and [`Accel::occluded`] calls
    /// alike): what a stage cast is the difference across it.
    pub fn rays(&self) -> u64 {
        self.rays.total()
    }

    pub fn triangle_count(&self) -> usize {
        self.tris.len()
    }

    /// `(shape, triangle)` of every BVH primitive, in BVH order: a [`Hit::prim`] indexes it,
    /// and tables laid out in this order are read with one lookup per hit.
    pub fn prim_ids(&self) -> &[(u32, u32)] {
        &self.ids
    }

    /// Closest hit along `origin + t * dir` for `t` in `(0, tmax)`. `dir` must be unit length.
    #[inline]
    pub fn intersect(&self, origin: Vec3, dir: Vec3, tmax: f32) -> Option<Hit> {
        self.rays.add();
        if self.tris.is_empty() {
            return None;
        }
        let ray = Ray::new(origin.into(), dir.into(), 0.0, tmax);
        let mut hit = RayHit::none();
        let tris = &self.tris;
        if !self
            .bvh
            .ray_traverse(ray, &mut hit, |r, id| tris[id].intersect(r))
        {
            return None;
        }
        let id = hit.primitive_id as usize;
        let tri = &self.tris[id];
        let p: Vec3A = ray.origin + ray.direction * hit.t;
        let (b1, b2) = barycentric(tri, p);
        let (shape, t) = self.ids[id];
        Some(Hit {
            shape,
            tri: t,
            b1,
            b2,
            t: hit.t,
            prim: id as u32,
        })
    }

    /// Whether anything blocks the segment from `origin` along unit `dir` before `tmax`.
    #[inline]
    pub fn occluded(&self, origin: Vec3, dir: Vec3, tmax: f32) -> bool {
        self.rays.add();
        if self.tris.is_empty() {
            return false;
        }
        let ray = Ray::new(origin.into(), dir.into(), 0.0, tmax);
        let tris = &self.tris;
        !self
            .bvh
            .ray_traverse_miss(ray, |r, id| tris[id].intersect(r))
    }

    /// Whether no triangle meets the pyramid from `apex` over the convex planar polygon `base`
    /// (corners in order): then no segment from `apex` to a point of `base` is blocked, a proof
    /// where shadow rays are samples. Conservative: a box or triangle that no face plane of the
    /// pyramid separates (within a relative `1e-5` of the scene's scale) counts as meeting it.
    /// `cap` `(n, h)`: the pyramid lies where `x . n >= h` (a receiver's surface just below an
    /// apex lifted off it, which no other face plane separates). Casts no ray.
    pub fn pyramid_clear(&self, apex: Vec3, base: &[Vec3], cap: (Vec3, f32)) -> bool {
        if self.tris.is_empty() {
            return true;
        }
        let Some(planes) = Pyramid::new(apex, base, cap) else {
            return false;
        };
        let tris = &self.tris;
        let mut clear = true;
        let mut state = self.bvh.new_traversal(planes.axis);
        let mut node;
        obvhs::traverse!(
            self.bvh,
            node,
            state,
            planes.hitmask(node, state.oct_inv4),
            {
                if !planes.separates(&tris[state.primitive_id as usize]) {
                    clear = false;
                    break;
                }
            }
        );
        clear
    }
}

/// The face planes of a pyramid, outward: `x . normal > offset + tol` is outside.
struct Pyramid {
    planes: Vec<(Vec3A, f32, f32)>,
    /// From the apex towards the base (the traversal's order).
    axis: Vec3A,
}

impl Pyramid {
    /// The pyramid from `apex` over `base` cut by `cap` (see [`Accel::pyramid_clear`]); `None`
    /// if degenerate (a base of fewer than 3 corners, a zero face).
    fn new(apex: Vec3, base: &[Vec3], cap: (Vec3, f32)) -> Option<Pyramid> {
        if base.len() < 3 {
            return None;
        }
        let apex = Vec3A::from(apex);
        let corner = |i: usize| Vec3A::from(base[i % base.len()]);
        let centre = (0..base.len()).fold(Vec3A::ZERO, |a, i| a + corner(i)) / base.len() as f32;
        let scale = (0..base.len())
            .fold(apex.abs().max_element(), |m, i| {
                m.max(corner(i).abs().max_element())
            })
            .max(1.0);
        let tol = 1e-5 * scale;
        let outward = |m: Vec3A, on: Vec3A| -> Option<(Vec3A, f32, f32)> {
            let m = m.try_normalize()?;
            let m = if m.dot(centre - on) > 0.0 { -m } else { m };
            Some((m, m.dot(on), tol))
        };
        let mut planes = Vec::with_capacity(base.len() + 2);
        for i in 0..base.len() {
            let (a, b) = (corner(i), corner(i + 1));
            planes.push(outward((a - apex).cross(b - apex), apex)?);
        }
        // the base plane, outward away from the apex (the apex is inside)
        let b0 = corner(0);
        let nb = (corner(1) - b0).cross(corner(2) - b0).try_normalize()?;
        let nb = if nb.dot(apex - b0) > 0.0 { -nb } else { nb };
        planes.push((nb, nb.dot(b0), tol));
        // the cap, outward below it
        planes.push((-Vec3A::from(cap.0), -cap.1, 0.0));
        let axis = (centre - apex).try_normalize()?;
        Some(Pyramid { planes, axis })
    }

    /// Whether a face plane has the whole box outside.
    fn separates_box(&self, lo: Vec3A, hi: Vec3A) -> bool {
        self.planes.iter().any(|&(m, d, tol)| {
            // the box's corner deepest inside the plane
            let near = Vec3A::select(m.cmpgt(Vec3A::ZERO), lo, hi);
            m.dot(near) > d + tol
        })
    }

    /// Whether a face plane has the whole triangle outside.
    fn separates(&self, t: &Triangle) -> bool {
        self.planes.iter().any(|&(m, d, tol)| {
            let lim = d + tol;
            m.dot(t.v0) > lim && m.dot(t.v1) > lim && m.dot(t.v2) > lim
        })
    }

    /// The children of `node` the pyramid may meet, as obvhs' traversal hit mask.
    fn hitmask(&self, node: &obvhs::cwbvh::node::CwBvhNode, oct_inv4: u32) -> u32 {
        use obvhs::cwbvh::node::extract_byte64;
        let (child_bits8, bit_index8) = node.get_child_and_index_bits(oct_inv4);
        let mut mask = 0;
        for child in 0..8 {
            let b = node.child_aabb(child);
            if !self.separates_box(b.min, b.max) {
                mask |= extract_byte64(child_bits8, child) << extract_byte64(bit_index8, child);
            }
        }
        mask
    }
}

/// Counters of rays cast, one per worker thread on its own cache line (a shared counter
/// would bounce between the cores on every ray); rayon's threads take slots 1.., any other
/// thread slot 0. Relaxed: a stage reads the total after its threads have joined.
struct RayCount {
    slots: [Slot; RAY_SLOTS],
}

/// Counter slots (threads beyond share them, still correctly: the adds are atomic).
const RAY_SLOTS: usize = 64;

#[repr(align(128))]
#[derive(Default)]
struct Slot(AtomicU64);

impl Default for RayCount {
    fn default() -> Self {
        RayCount {
            slots: std::array::from_fn(|_| Slot::default()),
        }
    }
}

impl RayCount {
    #[inline(always)]
    fn add(&self) {
        let i = rayon::current_thread_index().map_or(0, |i| 1 + i % (RAY_SLOTS - 1));
        self.slots[i].0.fetch_add(1, Ordering::Relaxed);
    }

    fn total(&self) -> u64 {
        self.slots.iter().map(|s| s.0.load(Ordering::Relaxed)).sum()
    }
}

/// Barycentric weights (of v1, v2) of point `p` in the triangle's plane.
fn barycentric(t: &Triangle, p: Vec3A) -> (f32, f32) {
    let e1 = t.v1 - t.v0;
    let e2 = t.v2 - t.v0;
    let d = p - t.v0;
    let d11 = e1.dot(e1);
    let d12 = e1.dot(e2);
    let d22 = e2.dot(e2);
    let dp1 = d.dot(e1);
    let dp2 = d.dot(e2);
    let den = d11 * d22 - d12 * d12;
    if den == 0.0 {
        return (0.0, 0.0);
    }
    let b1 = (d22 * dp1 - d12 * dp2) / den;
    let b2 = (d11 * dp2 - d12 * dp1) / den;
    (b1.clamp(0.0, 1.0), b2.clamp(0.0, 1.0 - b1.clamp(0.0, 1.0)))
}

/// Offset a ray origin off a surface at `p` with geometric normal `n`, towards the side `dir`
/// leaves on, by an epsilon that scales with the coordinates' magnitude (the triangle test is
/// not watertight and f32 positions carry relative error).
#[inline]
pub fn offset_origin(p: Vec3, n: Vec3, dir: Vec3) -> Vec3 {
    let scale = p.abs().max_element().max(1.0);
    let eps = 1e-4 * scale;
    if n.dot(dir) >= 0.0 {
        p + n * eps
    } else {
        p - n * eps
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::rng::Rng;

    fn soup(n: usize, seed: u64) -> (Vec<Triangle>, Vec<(u32, u32)>) {
        let mut r = Rng::new(seed, 0, 0, 0);
        let mut tris = Vec::new();
        for _ in 0..n {
            let c = Vec3A::new(r.f32(), r.f32(), r.f32()) * 4.0 - 2.0;
            let mut v = || c + Vec3A::new(r.f32(), r.f32(), r.f32()) * 0.6 - 0.3;
            tris.push(Triangle {
                v0: v(),
                v1: v(),
                v2: v(),
            });
        }
        let ids = (0..n as u32).map(|i| (0, i)).collect();
        (tris, ids)
    }

    /// A pyramid found clear passes every shadow ray from its apex to its base, and the test
    /// is not so conservative that it finds few clear (over half of those no ray found
    /// blocked; its plane tests leave out the edge-edge axes): random quads from random apexes
    /// in a soup of 200 triangles, each against 256 rays (brute force).
    #[test]
    fn a_clear_pyramid_passes_every_ray_inside_it() {
        let (tris, ids) = soup(200, 3);
        let acc = Accel::from_triangles(tris, ids);
        let mut r = Rng::new(9, 0, 0, 0);
        let mut p = || Vec3::new(r.f32(), r.f32(), r.f32());
        let (mut clear, mut free, mut blocked) = (0, 0, 0);
        for _ in 0..1500 {
            let apex = p() * 6.0 - 3.0;
            let c = p() * 6.0 - 3.0;
            let (a, b) = ((p() - 0.5) * 0.6, (p() - 0.5) * 0.6);
            let b = (b - a * (a.dot(b) / a.length_squared())).normalize() * b.length();
            let base = [c, c + a, c + a + b, c + b];
            let axis = (c - apex).normalize();
            let cap = (axis, axis.dot(apex) - 100.0);
            let found = acc.pyramid_clear(apex, &base, cap);
            let hit = (0..256).any(|_| {
                let (u, v) = (p().x, p().y);
                let y = c + a * u + b * v;
                let d = y - apex;
                acc.occluded(apex, d / d.length(), d.length())
            });
            assert!(
                !(found && hit),
                "a clear pyramid blocked a ray: {apex} {base:?}"
            );
            clear += found as u32;
            free += !hit as u32;
            blocked += hit as u32;
        }
        assert!(
            blocked > 200 && free > 200,
            "{blocked} blocked, {free} free"
        );
        assert!(clear * 2 > free, "{clear} found clear of {free} free");
        // the cap: a plane just below the apex keeps a floor under it out of the pyramid
        let floor = vec![Triangle {
            v0: Vec3A::new(-9.0, -9.0, 0.0),
            v1: Vec3A::new(9.0, -9.0, 0.0),
            v2: Vec3A::new(0.0, 9.0, 0.0),
        }];
        let acc = Accel::from_triangles(floor, vec![(0, 0)]);
        let apex = Vec3::new(0.0, 0.0, 1e-4);
        let base = [-1.0f32, 1.0].map(|x| Vec3::new(x, -1.0, 2.0));
        let base = [
            base[0],
            base[1],
            Vec3::new(1.0, 1.0, 2.0),
            Vec3::new(-1.0, 1.0, 2.0),
        ];
        assert!(acc.pyramid_clear(apex, &base, (Vec3::Z, 0.5e-4)));
        assert!(!acc.pyramid_clear(apex, &base, (Vec3::Z, -1.0)));
    }

    /// Every ray is counted once, closest-hit and shadow rays alike, from the calling thread
    /// and from rayon's workers, on an empty scene too.
    #[test]
    fn rays_are_counted_from_every_thread() {
        use rayon::prelude::*;
        let (tris, ids) = soup(50, 3);
        let accel = Accel::from_triangles(tris, ids);
        let (o, d) = (Vec3::splat(-3.0), Vec3::ONE.normalize());
        assert_eq!(accel.rays(), 0);
        accel.intersect(o, d, f32::INFINITY);
        accel.occluded(o, d, 1.0);
        assert_eq!(accel.rays(), 2);
        (0..10_000).into_par_iter().for_each(|i| {
            match i % 2 {
                0 => drop(accel.intersect(o, d, f32::INFINITY)),
                _ => drop(accel.occluded(o, d, 1.0)),
            };
        });
        assert_eq!(accel.rays(), 10_002);
        let empty = Accel::from_triangles(Vec::new(), Vec::new());
        empty.occluded(o, d, 1.0);
        assert_eq!(empty.rays(), 1);
    }

    /// The BVH's closest hit and occlusion agree with testing every triangle.
    #[test]
    fn closest_hit_matches_brute_force() {
        let (tris, ids) = soup(500, 7);
        let accel = Accel::from_triangles(tris.clone(), ids);
        let mut r = Rng::new(9, 0, 0, 0);
        let mut hits = 0;
        for _ in 0..2000 {
            let o = Vec3::new(r.f32(), r.f32(), r.f32()) * 8.0 - 4.0;
            let d = (Vec3::new(r.f32(), r.f32(), r.f32()) * 2.0 - 1.0).normalize();
            let ray = Ray::new(o.into(), d.into(), 0.0, f32::INFINITY);
            let (mut best, mut bi) = (f32::INFINITY, usize::MAX);
            for (i, t) in tris.iter().enumerate() {
                let h = t.intersect(&ray);
                if h < best {
                    best = h;
                    bi = i;
                }
            }
            let got = accel.intersect(o, d, f32::INFINITY);
            match got {
                None => assert!(best.is_infinite()),
                Some(h) => {
                    hits += 1;
                    assert_eq!(h.tri as usize, bi);
                    assert!((h.t - best).abs() <= 1e-5 * best.max(1.0));
                    // barycentrics reproduce the hit point
                    let t = &tris[bi];
                    let p = t.v0 * (1.0 - h.b1 - h.b2) + t.v1 * h.b1 + t.v2 * h.b2;
                    let q = Vec3A::from(o) + Vec3A::from(d) * h.t;
                    assert!((p - q).length() < 1e-3, "{p} vs {q}");
                }
            }
            assert!(!accel.occluded(o, d, best * 0.999));
            if best.is_finite() {
                assert!(accel.occluded(o, d, best * 1.001 + 1e-4));
            }
        }
        assert!(hits > 100, "too few hits ({hits}) to mean anything");
    }

    #[test]
    fn empty_scene_never_hits() {
        let a = Accel::from_triangles(vec![], vec![]);
        assert!(a.intersect(Vec3::ZERO, Vec3::Z, 1.0).is_none());
        assert!(!a.occluded(Vec3::ZERO, Vec3::Z, 1.0));
    }
}
