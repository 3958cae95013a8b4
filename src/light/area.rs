//! Area-light irradiance that is exact where a point is fully lit or fully shadowed: the
//! unoccluded irradiance of each emitter triangle is analytic (Lambert's polygon formula, after
//! clipping the triangle to the receiver's upper hemisphere), and only the visible fraction is
//! estimated, with stratified shadow rays weighted by the unoccluded integrand
//! `cos_r cos_e / d^2`. This ratio estimator is 1 (or 0) with no noise when every sample is
//! visible (or none is), so noise is confined to penumbrae.
//!
//! Sidedness: Mitsuba emits on the side of the emitter's *shading* normal. A triangle's front
//! side is its geometric normal `(p1 - p0) x (p2 - p0)`, flipped if the mesh's vertex normals
//! (summed over the triangle) point the other way; the analytic part uses that plane. For
//! smooth-shaded (curved) emitters each shadow sample also checks that its interpolated vertex
//! normal faces the receiver (a back-facing sample counts as not visible), which follows
//! Mitsuba's per-point rule up to the analytic part's flat-triangle approximation. For flat
//! emitters the two rules agree exactly.

use super::{DirectParams, Footprint, Reach};
use crate::accel::Accel;
use crate::rng::Rng;
use crate::scene::Mesh;
use glam::{DVec3, Vec3};

/// Mixed into the seed so these streams never coincide with the photon tracer's.
const STREAM_TAG: u64 = 0xa11c_e5ad_0d1e_c700;

/// Mean irradiance over footprint `fp` per unit radiance of the emitter `mesh` (multiply by
/// `L` per channel), and whether some triangle was partly visible (a penumbra). `stream =
/// (seed, emitter index, receiver index)` keys the shadow samples; `dense` skips the first
/// pass (see [`super::texel_irradiance`]).
pub(crate) fn irradiance_factor(
    mesh: &Mesh,
    accel: &Accel,
    fp: &Footprint,
    params: &DirectParams,
    stream: (u64, u64, u64),
    dense: bool,
) -> (f64, Reach) {
    let nd = fp.n.as_dvec3();
    let pd = fp.p.as_dvec3();
    let (mut total, mut lit, mut dark, mut partial) = (0.0, false, false, false);
    let area = mesh.area();
    for t in 0..mesh.triangles.len() {
        let Some(front) = front_normal(mesh, t) else {
            continue;
        };
        let [a, b, c] = mesh.triangle(t);
        let v = [a.as_dvec3() - pd, b.as_dvec3() - pd, c.as_dvec3() - pd];
        // The receiver must be on the front side (strictly) of the emitter's plane.
        if v[0].dot(front) >= 0.0 {
            continue;
        }
        let (poly, m) = clip_to_hemisphere(v, nd);
        if m < 3 {
            continue;
        }
        let unoccluded = projected_solid_angle(&poly[..m], nd);
        if unoccluded <= 0.0 || !unoccluded.is_finite() {
            continue;
        }
        if params.area_samples == 0 {
            total += unoccluded;
            lit = true;
            continue;
        }
        let mut rng = Rng::new(stream.0 ^ STREAM_TAG, stream.1, t as u64, stream.2);
        let tri = Target {
            mesh,
            t,
            front,
            accel,
        };
        // The penumbra budget is the emitter's, shared by its triangles by area.
        let share = (mesh.triangle_area(t) as f64 / area).clamp(0.0, 1.0);
        let dense_n =
            ((params.penumbra_samples as f64 * share).ceil() as u32).max(params.area_samples);
        let (vis, part) = tri.visibility(
            fp,
            (params.area_samples, dense_n),
            &mut rng,
            dense,
            &poly[..m],
        );
        partial |= part;
        lit |= vis >= 1.0;
        dark |= vis <= 0.0;
        total += unoccluded * vis;
    }
    let reach = if partial || (lit && dark) {
        Reach::Partial
    } else if lit {
        Reach::Lit
    } else {
        Reach::Dark
    };
    (total, reach)
}

/// The unoccluded irradiance at `p` (normal `n`) per unit radiance of the emitter `mesh`:
/// Lambert's formula over its triangles, clipped to the hemisphere; no rays.
pub(crate) fn unoccluded_factor(mesh: &Mesh, p: Vec3, n: Vec3) -> f64 {
    let (nd, pd) = (n.as_dvec3(), p.as_dvec3());
    let mut total = 0.0;
    for t in 0..mesh.triangles.len() {
        let Some(front) = front_normal(mesh, t) else {
            continue;
        };
        let [a, b, c] = mesh.triangle(t);
        let v = [a.as_dvec3() - pd, b.as_dvec3() - pd, c.as_dvec3() - pd];
        if v[0].dot(front) >= 0.0 {
            continue;
        }
        let (poly, m) = clip_to_hemisphere(v, nd);
        if m < 3 {
            continue;
        }
        let u = projected_solid_angle(&poly[..m], nd);
        if u > 0.0 && u.is_finite() {
            total += u;
        }
    }
    total
}

/// Unit front normal of triangle `t` (see the module notes), `None` if degenerate.
pub(crate) fn front_normal(mesh: &Mesh, t: usize) -> Option<DVec3> {
    let [a, b, c] = mesh.triangle(t);
    let (a, b, c) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3());
    let g = (b - a).cross(c - a);
    let len = g.length();
    if len.is_nan() || len <= 0.0 || len.is_infinite() {
        return None;
    }
    let mut g = g / len;
    if let Some(ns) = &mesh.normals {
        let [i, j, k] = mesh.triangles[t];
        let s = [i, j, k]
            .iter()
            .filter_map(|&i| ns.get(i as usize))
            .fold(Vec3::ZERO, |acc, v| acc + *v);
        if g.dot(s.as_dvec3()) < 0.0 {
            g = -g;
        }
    }
    Some(g)
}

/// Clip triangle `v` (vertices relative to the receiver) to the half-space `dot(x, n) >= 0`
/// (Sutherland-Hodgman). Returns up to 4 vertices and their count.
pub(crate) fn clip_to_hemisphere(v: [DVec3; 3], n: DVec3) -> ([DVec3; 4], usize) {
    let mut out = [DVec3::ZERO; 4];
    let mut m = 0;
    let h = [v[0].dot(n), v[1].dot(n), v[2].dot(n)];
    for i in 0..3 {
        let j = (i + 1) % 3;
        let (a, b, ha, hb) = (v[i], v[j], h[i], h[j]);
        if ha >= 0.0 {
            out[m] = a;
            m += 1;
        }
        if (ha >= 0.0) != (hb >= 0.0) {
            // The edge crosses the plane: add the crossing point (exactly on it).
            let t = ha / (ha - hb);
            let x = a + (b - a) * t;
            out[m] = x - n * (x.dot(n) / n.length_squared().max(f64::MIN_POSITIVE)).min(0.0);
            m += 1;
        }
    }
    (out, m)
}

/// Lambert's formula: the projected solid angle (cosine-weighted, against unit `n`) of the
/// convex polygon `poly` (vertices relative to the receiver, all in its upper hemisphere),
/// `1/2 |sum_i angle(v_i, v_i+1) * dot(n, normalize(v_i x v_i+1))|`. The irradiance from a
/// uniform radiance `L` is `L` times this (`pi L F`, `F` the configuration factor).
pub(crate) fn projected_solid_angle(poly: &[DVec3], n: DVec3) -> f64 {
    let m = poly.len();
    let mut s = 0.0;
    for i in 0..m {
        let (a, b) = (poly[i], poly[(i + 1) % m]);
        let c = a.cross(b);
        let cl = c.length();
        if cl.is_nan() || cl <= 0.0 {
            continue;
        }
        let angle = cl.atan2(a.dot(b));
        s += angle * c.dot(n) / cl;
    }
    0.5 * s.abs()
}

/// Points of a texel, one per stratum of a `k x k` grid in a random order, for pairing with
/// the strata of an emitter triangle (a point footprint gives its point).
struct TexelStrata {
    fp: Footprint,
    k: u32,
    order: Vec<u32>,
    next: usize,
}

impl TexelStrata {
    fn new(fp: &Footprint, k: u32, rng: &mut Rng) -> TexelStrata {
        let mut order: Vec<u32> = if fp.dx == Vec3::ZERO && fp.dy == Vec3::ZERO {
            Vec::new()
        } else {
            (0..k * k).collect()
        };
        // Fisher-Yates with the footprint's own stream.
        for i in (1..order.len()).rev() {
            let j = (rng.u64() % (i as u64 + 1)) as usize;
            order.swap(i, j);
        }
        TexelStrata {
            fp: *fp,
            k,
            order,
            next: 0,
        }
    }

    fn next(&mut self, rng: &mut Rng) -> Vec3 {
        if self.order.is_empty() {
            return self.fp.p;
        }
        let s = self.order[self.next % self.order.len()];
        self.next += 1;
        let k = self.k as f32;
        let a = ((s % self.k) as f32 + rng.f32()) / k;
        let b = ((s / self.k) as f32 + rng.f32()) / k;
        self.fp.at(a, b)
    }
}

/// One emitter triangle as a shadow-ray target.
struct Target<'a> {
    mesh: &'a Mesh,
    t: usize,
    /// Unit front normal (see [`front_normal`]).
    front: DVec3,
    accel: &'a Accel,
}

impl Target<'_> {
    /// The visible fraction of the triangle from `fp` (weighted by the unoccluded integrand)
    /// and whether it is partial: `first_n` samples first (unless `dense`), `dense_n` where
    /// they disagree. `poly` is the triangle clipped to the receiver's hemisphere (relative to
    /// its center): when no sample lands on it, one ray to its centroid decides.
    fn visibility(
        &self,
        fp: &Footprint,
        (first_n, dense_n): (u32, u32),
        rng: &mut Rng,
        dense: bool,
        poly: &[DVec3],
    ) -> (f64, bool) {
        let first = if dense { dense_n } else { first_n };
        let (w, v) = self.stratified(fp, first, rng);
        if w <= 0.0 {
            // No sample landed where the clipped polygon lies (a sliver above the horizon):
            // one shadow ray to its centroid decides.
            let cen = poly.iter().sum::<DVec3>() / poly.len() as f64;
            let y = (fp.p.as_dvec3() + cen).as_vec3();
            return (
                super::visible_to(self.accel, fp.p, fp.ng, y) as u8 as f64,
                false,
            );
        }
        let vis = v / w;
        let partial = vis > 0.0 && vis < 1.0;
        if !partial || dense || dense_n <= first_n {
            return (vis, partial);
        }
        // A penumbra: estimate again, with many more strata.
        let (w2, v2) = self.stratified(fp, dense_n, rng);
        (if w2 > 0.0 { v2 / w2 } else { vis }, true)
    }

    /// Stratified visibility of the triangle from footprint `fp`: `samples` rounded up to
    /// `k^2` equal sub-triangles with one uniform point each, each paired with a point of
    /// the texel from its own stratum of a `k x k` grid (in a random order), weighted by the
    /// unoccluded integrand `cos_r cos_e / d^2`. Returns `(sum of weights, sum of weights of
    /// visible samples)`.
    fn stratified(&self, fp: &Footprint, samples: u32, rng: &mut Rng) -> (f64, f64) {
        let (mesh, t, front) = (self.mesh, self.t, self.front);
        let [a, b, c] = mesh.triangle(t);
        let (e1, e2) = (b - a, c - a);
        let k = super::strata(samples);
        let inv_k = 1.0 / k as f32;
        let (mut wsum, mut vsum) = (0.0f64, 0.0f64);
        let smooth = mesh.normals.is_some();
        let (n, ng) = (fp.n, fp.ng);
        let nd = n.as_dvec3();
        let mut texel = TexelStrata::new(fp, k, rng);
        let mut sample = |g0: (f32, f32), g1: (f32, f32), g2: (f32, f32)| {
            let p = texel.next(rng);
            let pd = p.as_dvec3();
            // Uniform point in the sub-triangle (g0, g1, g2), grid coordinates along (e1, e2).
            let su = rng.f32().sqrt();
            let u2 = rng.f32();
            let (w0, w1, w2) = (1.0 - su, su * (1.0 - u2), su * u2);
            let s1 = (w0 * g0.0 + w1 * g1.0 + w2 * g2.0) * inv_k;
            let s2 = (w0 * g0.1 + w1 * g1.1 + w2 * g2.1) * inv_k;
            let y = a + e1 * s1 + e2 * s2;
            let v = y.as_dvec3() - pd;
            let d2 = v.length_squared();
            let (cos_r, cos_e) = (v.dot(nd), -v.dot(front));
            if d2.is_nan() || d2 <= 0.0 || cos_r <= 0.0 || cos_e <= 0.0 {
                return;
            }
            let w = cos_r * cos_e / (d2 * d2);
            wsum += w;
            // A smooth-shaded emitter emits only where its shading normal faces p.
            if smooth && mesh.shading_normal(t, s1, s2).dot(p - y) <= 0.0 {
                return;
            }
            if super::visible_to(self.accel, p, ng, y) {
                vsum += w;
            }
        };
        for i in 0..k {
            for j in 0..(k - i) {
                let (fi, fj) = (i as f32, j as f32);
                sample((fi, fj), (fi + 1.0, fj), (fi, fj + 1.0));
                if i + j + 1 < k {
                    sample((fi + 1.0, fj), (fi + 1.0, fj + 1.0), (fi, fj + 1.0));
                }
            }
        }
        (wsum, vsum)
    }
}
