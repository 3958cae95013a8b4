//! What a ray's hit means in texture space, looked up in one place: per BVH primitive (in the
//! BVH's own order, so the closest-hit id indexes it directly) the triangle's unit geometric
//! normal, vertex normals, atlas corner coordinates, layout slot, chart and sidedness,
//! precomputed once per run. Light paths and gather rays hit millions of triangles; this keeps
//! each hit to one table read plus the interpolation at the hit's barycentrics, with no
//! per-hit cross products or mesh indirections.

use crate::atlas::context::RunContext;
use crate::atlas::uv::Charts;
use crate::atlas::uv::NONE;
use crate::physics::accel::{Accel, Hit};
use crate::physics::coat::{self, Coat};
use crate::scene::{Emitter, EnvMap, KnownBsdf, Rgb, Sides};
use glam::{Vec2, Vec3};
use std::sync::Arc;

/// One triangle as light transport sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prim {
    /// Unit geometric normal `(p1 - p0) x (p2 - p0)` normalized (zero if degenerate).
    pub ng: Vec3,
    /// Vertex shading normals (`ng` three times for a mesh without normals).
    pub n: [Vec3; 3],
    /// Corner coordinates in the slot's atlas texels (zero without a slot).
    pub uv: [Vec2; 3],
    /// Layout slot of the shape, or [`NONE`] (emitters and shapes not reconstructed).
    pub slot: u32,
    /// The triangle's chart in its atlas, or [`NONE`].
    pub chart: u32,
    /// Index into `Scene::shapes`.
    pub shape: u32,
    /// Reflects on the front side of its shading normal only (Mitsuba's `diffuse`).
    pub one_sided: bool,
}

/// A closest hit with its surface attributes interpolated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceHit {
    pub hit: Hit,
    /// The hit point, `origin + t * dir`.
    pub p: Vec3,
    /// Unit shading normal at the hit (interpolated, normalized).
    pub ns: Vec3,
    /// Continuous texel coordinates in the slot's atlas.
    pub uv: Vec2,
}

/// [`Prim`] for every BVH primitive, in BVH order, and per shape what light transport needs
/// beyond the atlas: its known material and its emission.
pub struct HitTable {
    prims: Vec<Prim>,
    known: Vec<Option<KnownBsdf>>,
    /// Per shape, the coat over its reconstructed base, if it has one.
    coats: Vec<Option<Coat>>,
    emission: Vec<Option<Rgb>>,
    /// The environment emitters (a ray that leaves the scene sees their sum).
    env: Vec<Arc<EnvMap>>,
}

impl HitTable {
    /// The table for `p`'s scene and atlases, `charts` giving each triangle's chart.
    pub fn new(p: &RunContext, charts: &Charts) -> HitTable {
        let prims = p
            .accel
            .prim_ids()
            .iter()
            .map(|&(shape, tri)| prim(p, charts, shape as usize, tri as usize))
            .collect();
        let shapes = &p.scene.shapes;
        HitTable {
            prims,
            known: shapes
                .iter()
                .map(|s| s.known().map(|k| k.bsdf.clone()))
                .collect(),
            coats: coat::coats(&p.scene),
            emission: shapes.iter().map(|s| s.emission).collect(),
            env: p
                .scene
                .emitters
                .iter()
                .filter_map(|e| match e {
                    Emitter::Environment(m) => Some(m.clone()),
                    _ => None,
                })
                .collect(),
        }
    }

    /// The radiance a ray leaving the scene along `dir` sees (0 without environment light).
    #[inline]
    pub fn environment(&self, dir: Vec3) -> Rgb {
        self.env.iter().map(|m| m.eval(dir)).sum()
    }

    /// The known material of `prim`'s shape (mirrors, glass, ...), if it has one.
    #[inline]
    pub fn known(&self, prim: &Prim) -> Option<&KnownBsdf> {
        self.known[prim.shape as usize].as_ref()
    }

    /// The coat over the reconstructed base of shape `shape`, if it is coated.
    #[inline]
    pub fn coat(&self, shape: u32) -> Option<&Coat> {
        self.coats[shape as usize].as_ref()
    }

    /// The radiance `prim` emits towards a ray arriving along `dir` with shading normal `ns`
    /// at the hit (one-sided area emitters shine on their front side), if its shape emits.
    #[inline]
    pub fn emitted(&self, prim: &Prim, ns: Vec3, dir: Vec3) -> Option<Rgb> {
        let e = self.emission[prim.shape as usize]?;
        Some(if dir.dot(ns) < 0.0 { e } else { Rgb::ZERO })
    }

    /// The record of BVH primitive `id`.
    #[inline]
    pub fn prim(&self, id: u32) -> &Prim {
        &self.prims[id as usize]
    }

    /// The closest hit along `origin + t dir`, `t < tmax`, with its attributes.
    #[inline]
    pub fn trace(
        &self,
        accel: &Accel,
        origin: Vec3,
        dir: Vec3,
        tmax: f32,
    ) -> Option<(SurfaceHit, &Prim)> {
        let hit = accel.intersect(origin, dir, tmax)?;
        let pr = &self.prims[hit.prim as usize];
        let b0 = 1.0 - hit.b1 - hit.b2;
        let ns = (pr.n[0] * b0 + pr.n[1] * hit.b1 + pr.n[2] * hit.b2).normalize_or(pr.ng);
        let uv = pr.uv[0] * b0 + pr.uv[1] * hit.b1 + pr.uv[2] * hit.b2;
        let p = origin + dir * hit.t;
        Some((SurfaceHit { hit, p, ns, uv }, pr))
    }
}

fn prim(p: &RunContext, charts: &Charts, shape: usize, tri: usize) -> Prim {
    let s = &p.scene.shapes[shape];
    let m = &s.mesh;
    let ng = m.face_normal_raw(tri).normalize_or_zero();
    let n = match &m.normals {
        Some(ns) => m.triangles[tri].map(|i| ns[i as usize] * m.side(tri)),
        None => [ng; 3],
    };
    let slot = charts.slot_of_shape(shape);
    let (uv, chart) = match (slot, p.atlases[shape].as_ref()) {
        (Some(slot), Some(a)) => (
            a.corner_uv[tri],
            charts.slots[slot]
                .tri_chart
                .get(tri)
                .copied()
                .unwrap_or(NONE),
        ),
        _ => ([Vec2::ZERO; 3], NONE),
    };
    Prim {
        ng,
        n,
        uv,
        slot: slot.map_or(NONE, |s| s as u32),
        chart,
        shape: shape as u32,
        one_sided: s.sides == Sides::Front,
    }
}
