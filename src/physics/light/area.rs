//! Area-light irradiance that is exact where a point is fully lit or fully shadowed: the
//! unoccluded irradiance of each emitter triangle is analytic (Lambert's polygon formula, after
//! clipping the triangle to the receiver's upper hemisphere), and only the visible fraction is
//! estimated, with stratified shadow rays weighted by the unoccluded integrand
//! `cos_r cos_e / d^2`. This ratio estimator is 1 (or 0) with no noise when every sample is
//! visible (or none is), so noise is confined to penumbrae.
//!
//! Shadow boundaries are fitted per piece of the emitter ([`piece`]): a triangle, or two
//! triangles of one plane sharing an edge (a rectangle), whose boundary is searched for,
//! bisected and checked once across the quad instead of once in each triangle.
//!
//! Sidedness: Mitsuba emits on the side of the emitter's *shading* normal. A triangle's front
//! side is its geometric normal `(p1 - p0) x (p2 - p0)`, flipped if the mesh's vertex normals
//! (summed over the triangle) point the other way; the analytic part uses that plane. For
//! smooth-shaded (curved) emitters each shadow sample also checks that its interpolated vertex
//! normal faces the receiver (a back-facing sample counts as not visible), which follows
//! Mitsuba's per-point rule up to the analytic part's flat-triangle approximation. For flat
//! emitters the two rules agree exactly.

mod piece;

use super::{DirectParams, Footprint, Reach};
use crate::base::rng::Rng;
use crate::physics::accel::{offset_origin, Accel};
use crate::scene::Mesh;
use glam::{DVec3, Vec3};
use piece::{pieces, Piece};

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
    for piece in pieces(mesh) {
        let Some((front, unoccluded)) = piece_solid_angle(mesh, &piece, pd, nd) else {
            continue;
        };
        if params.area_samples == 0 {
            total += unoccluded;
            lit = true;
            continue;
        }
        let t = piece.t;
        let mut rng = Rng::new(stream.0 ^ STREAM_TAG, stream.1, t as u64, stream.2);
        let tri = Target {
            mesh,
            t,
            front,
            accel,
            shade: mesh.normals.is_some() && piece.n == 3,
        };
        // The penumbra budget is the emitter's, shared by its pieces by area.
        let piece_area: f64 = piece
            .triangles()
            .map(|t| mesh.triangle_area(t) as f64)
            .sum();
        let share = (piece_area / area).clamp(0.0, 1.0);
        let dense_n =
            ((params.penumbra_samples as f64 * share).ceil() as u32).max(params.area_samples);
        // as many interior checks over a quad as over its two triangles: thin shadows (bars
        // across the light) slip between fewer
        let checks = params.area_samples * (piece.n as u32 - 2);
        let budget = (checks, dense_n, params.fit_depth);
        let (vis, part) = tri.visibility(fp, piece.poly(), budget, &mut rng, dense);
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
        if let Some((_, u)) = facing_solid_angle(mesh, t, pd, nd) {
            total += u;
        }
    }
    total
}

/// Emitter triangle `t`'s unit front normal and its projected solid angle above the
/// hemisphere of normal `nd` at `pd`, if the receiver is strictly on its front side and it
/// shows a positive, finite amount of itself.
fn facing_solid_angle(mesh: &Mesh, t: usize, pd: DVec3, nd: DVec3) -> Option<(DVec3, f64)> {
    let front = front_normal(mesh, t)?;
    let [a, b, c] = mesh.triangle(t);
    let v = [a.as_dvec3() - pd, b.as_dvec3() - pd, c.as_dvec3() - pd];
    // The receiver must be on the front side (strictly) of the emitter's plane.
    if v[0].dot(front) >= 0.0 {
        return None;
    }
    let (poly, m) = clip_to_hemisphere(v, nd);
    if m < 3 {
        return None;
    }
    let u = projected_solid_angle(&poly[..m], nd);
    (u > 0.0 && u.is_finite()).then_some((front, u))
}

/// [`facing_solid_angle`] of a piece: its first facing triangle's front normal and the sum of
/// its triangles' projected solid angles.
fn piece_solid_angle(mesh: &Mesh, piece: &Piece, pd: DVec3, nd: DVec3) -> Option<(DVec3, f64)> {
    let mut found: Option<(DVec3, f64)> = None;
    for t in piece.triangles() {
        if let Some((front, u)) = facing_solid_angle(mesh, t, pd, nd) {
            found = Some(found.map_or((front, u), |(f, s)| (f, s + u)));
        }
    }
    found
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

/// Bisection steps along a triangle edge when locating a shadow boundary (1/1024 of it).
const BISECTIONS: u32 = 10;
/// Stratified interior points that must agree with a fitted shadow boundary (or its absence)
/// before it is trusted.
const EDGE_CHECKS: u32 = 12;
/// Points per side of an emitter triangle where its perimeter is searched for the shadow
/// boundary.
const PERIMETER: u32 = 4;
/// Points along a fitted shadow line (each checked on both sides, close to it).
const LINE_CHECKS: u32 = 6;
/// Most times an emitter triangle is split in four where its shadow boundary is not one
/// straight line (a shadow corner lands in a piece 1/64 of the triangle at depth 3).
pub const FIT_DEPTH: u32 = 3;

/// Fewest rays that sample a piece of an emitter triangle where no shadow line fits.
const LEAF_SAMPLES: u32 = 36;

/// What [`Target::fit_line`] found.
enum Fit {
    /// No shadow boundary: all lit.
    Lit,
    /// No shadow boundary: all dark.
    Dark,
    /// The region `x . m > 0` for every `m` (`x` relative to the receiver) is lit (`true`)
    /// or dark, the rest the opposite: one plane for a straight shadow edge, two for a
    /// corner.
    Region(Vec<DVec3>, bool),
}

impl Fit {
    /// Whether the model says emitter point `x` (relative to the receiver) is lit.
    fn lit(&self, x: DVec3) -> bool {
        match self {
            Fit::Lit => true,
            Fit::Dark => false,
            Fit::Region(planes, lit) => planes.iter().all(|m| m.dot(x) > 0.0) == *lit,
        }
    }

    /// The lit projected solid angle (normal `n`) of `whole` (an emitter piece relative to
    /// the receiver, clipped to its hemisphere; `total` its own).
    fn lit_part(&self, whole: &[DVec3], n: DVec3, total: f64) -> f64 {
        match self {
            Fit::Lit => total,
            Fit::Dark => 0.0,
            Fit::Region(planes, lit) => {
                let region = planes
                    .iter()
                    .fold(whole.to_vec(), |p, m| clip_polygon(&p, *m));
                let inside = if region.len() >= 3 {
                    projected_solid_angle(&region, n)
                } else {
                    0.0
                };
                if *lit {
                    inside
                } else {
                    (total - inside).max(0.0)
                }
            }
        }
    }
}

/// Where the ray `from + s dir` (`s > 0`, in the piece's plane) leaves the convex piece `poly`.
fn exit_point(poly: &[Vec3], from: Vec3, dir: Vec3) -> Option<Vec3> {
    let n = (poly[1] - poly[0]).cross(poly[2] - poly[0]);
    let mut best: Option<f32> = None;
    for e in 0..poly.len() {
        let (a, b) = (poly[e], poly[(e + 1) % poly.len()]);
        // the plane through the edge, perpendicular to the triangle
        let en = (b - a).cross(n);
        let den = en.dot(dir);
        if den.abs() <= f32::EPSILON * en.length() * dir.length() {
            continue;
        }
        let s = en.dot(a - from) / den;
        if s > 1e-6 && best.is_none_or(|b| s < b) {
            best = Some(s);
        }
    }
    best.map(|s| from + dir * (s * 0.999))
}

/// The point where the lines `a1 b1` and `a2 b2` (in a plane of normal `n`) meet.
fn intersect_lines(a1: Vec3, b1: Vec3, a2: Vec3, b2: Vec3, n: Vec3) -> Option<Vec3> {
    let (d1, d2) = (b1 - a1, b2 - a2);
    let c = d1.cross(d2);
    let den = c.dot(n);
    if den.abs() <= 1e-12 * d1.length() * d2.length() * n.length() {
        return None;
    }
    let t = (a2 - a1).cross(d2).dot(n) / den;
    let p = a1 + d1 * t;
    p.is_finite().then_some(p)
}

/// A receiving point: position, shading and geometric normals.
struct Receiver {
    q: Vec3,
    n: Vec3,
    ng: Vec3,
}

/// Stratified visibility of emitter (sub-)triangle `tri` (front normal `front`): `samples`
/// rounded up to `k^2` equal sub-triangles with one uniform point `y` each, seen from the
/// receiver `receiver(rng)` gives for it, weighted by the unoccluded integrand `cos_r cos_e /
/// d^2`; `seen(receiver, y)` says whether `y` lights it. Returns `(sum of weights, sum of
/// weights of lit samples)`.
fn stratified_tri(
    tri: [Vec3; 3],
    front: DVec3,
    samples: u32,
    rng: &mut Rng,
    receiver: &mut dyn FnMut(&mut Rng) -> Receiver,
    seen: &dyn Fn(&Receiver, Vec3) -> bool,
) -> (f64, f64) {
    let [a, b, c] = tri;
    let (e1, e2) = (b - a, c - a);
    let k = super::strata(samples);
    let inv_k = 1.0 / k as f32;
    let (mut wsum, mut vsum) = (0.0f64, 0.0f64);
    let mut sample = |g0: (f32, f32), g1: (f32, f32), g2: (f32, f32)| {
        let r = receiver(rng);
        let su = rng.f32().sqrt();
        let u2 = rng.f32();
        let (w0, w1, w2) = (1.0 - su, su * (1.0 - u2), su * u2);
        let s1 = (w0 * g0.0 + w1 * g1.0 + w2 * g2.0) * inv_k;
        let s2 = (w0 * g0.1 + w1 * g1.1 + w2 * g2.1) * inv_k;
        let y = a + e1 * s1 + e2 * s2;
        let v = y.as_dvec3() - r.q.as_dvec3();
        let d2 = v.length_squared();
        let (cos_r, cos_e) = (v.dot(r.n.as_dvec3()), -v.dot(front));
        if d2.is_nan() || d2 <= 0.0 || cos_r <= 0.0 || cos_e <= 0.0 {
            return;
        }
        let w = cos_r * cos_e / (d2 * d2);
        wsum += w;
        if seen(&r, y) {
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

/// A uniform random point of the convex piece `poly`: a triangle's from two draws, a quad's
/// from a third before them that picks one of its triangles by area.
fn interior_point(poly: &[Vec3], rng: &mut Rng) -> Vec3 {
    let (a, mut b, mut c) = (poly[0], poly[1], poly[2]);
    if let [_, _, _, d] = *poly {
        let (s1, s2) = ((b - a).cross(c - a).length(), (c - a).cross(d - a).length());
        if rng.f32() * (s1 + s2) >= s1 {
            (b, c) = (c, d);
        }
    }
    let su = rng.f32().sqrt();
    let u2 = rng.f32();
    a + (b - a) * (su * (1.0 - u2)) + (c - a) * (su * u2)
}

/// Clips the convex polygon `poly` to the half-space `x . normal >= 0` (a zero normal keeps
/// everything).
fn clip_polygon(poly: &[DVec3], normal: DVec3) -> Vec<DVec3> {
    if normal == DVec3::ZERO {
        return poly.to_vec();
    }
    let mut out = Vec::with_capacity(poly.len() + 1);
    for i in 0..poly.len() {
        let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
        let (ha, hb) = (a.dot(normal), b.dot(normal));
        if ha >= 0.0 {
            out.push(a);
        }
        if (ha >= 0.0) != (hb >= 0.0) {
            out.push(a + (b - a) * (ha / (ha - hb)));
        }
    }
    out
}

/// One emitter piece (a triangle or a flat quad, [`pieces`]) as a shadow-ray target.
struct Target<'a> {
    mesh: &'a Mesh,
    /// The piece's first triangle.
    t: usize,
    /// Unit front normal (see [`front_normal`]).
    front: DVec3,
    accel: &'a Accel,
    /// Whether a shadow sample must also face the receiver by the triangle's interpolated
    /// vertex normal (a curved emitter; a quad's vertex normals are its plane's).
    shade: bool,
}

impl Target<'_> {
    /// The visible fraction of the piece `poly` from `fp` (weighted by the unoccluded
    /// integrand) and whether it is partial, from the texel's center: a soft shadow varies
    /// little across a texel (and linearly, where the center is the mean). The shadow boundary
    /// is looked for around the piece's perimeter and at `checks` interior points: none found,
    /// the piece is wholly lit or wholly dark; one straight boundary (or two lines of a band
    /// or corner), its lit part integrated exactly; else [`Target::fit`] splits it. `dense`
    /// uses the split search at once.
    fn visibility(
        &self,
        fp: &Footprint,
        poly: &[Vec3],
        (checks, dense_n, fit_depth): (u32, u32, u32),
        rng: &mut Rng,
        dense: bool,
    ) -> (f64, bool) {
        let r = Receiver {
            q: fp.p,
            n: fp.n,
            ng: fp.ng,
        };
        if !dense {
            if self.clear(&r, poly) {
                return (1.0, false);
            }
            let seen = |y: Vec3| self.sees(r.q, r.ng, y);
            match self.fit_line(&r, poly, &seen, rng, checks) {
                Some(Fit::Lit) => return (1.0, false),
                Some(Fit::Dark) => return (0.0, false),
                Some(fit) => {
                    let nd = r.n.as_dvec3();
                    let rel: Vec<DVec3> =
                        poly.iter().map(|v| v.as_dvec3() - r.q.as_dvec3()).collect();
                    let whole = clip_polygon(&rel, nd);
                    let total = projected_solid_angle(&whole, nd);
                    if total > 0.0 {
                        return (
                            (fit.lit_part(&whole, nd, total) / total).clamp(0.0, 1.0),
                            true,
                        );
                    }
                }
                None => {}
            }
        }
        let (lit, total) = self.fit(&r, poly, (0, fit_depth), dense_n, rng);
        let v = if total > 0.0 {
            (lit / total).clamp(0.0, 1.0)
        } else {
            0.0
        };
        (v, true)
    }

    /// The part of (sub-)triangle `tri` of the emitter that lights `r`, exactly where the
    /// shadow boundary across it is one straight line (one occluder edge) or absent, as
    /// `(lit, total)` projected solid angles. The boundary is found by bisection along the
    /// two sides it cuts and checked against stratified points; where that fails the
    /// triangle is split in four (shadow corners, curved boundaries) down to `max_depth`
    /// ([`DirectParams::fit_depth`]), and a last failing piece is sampled with `samples`
    /// stratified rays. With `max_depth` 0 the triangle is sampled at once (the first pass
    /// already looked for a line). A quad is fitted as its two triangles, each with half the
    /// samples (the first pass already looked for a line across the whole).
    fn fit(
        &self,
        r: &Receiver,
        poly: &[Vec3],
        (depth, max_depth): (u32, u32),
        samples: u32,
        rng: &mut Rng,
    ) -> (f64, f64) {
        if let [a, b, c, d] = *poly {
            let half = samples.div_ceil(2);
            let (l1, t1) = self.fit(r, &[a, b, c], (depth, max_depth), half, rng);
            let (l2, t2) = self.fit(r, &[a, c, d], (depth, max_depth), half, rng);
            return (l1 + l2, t1 + t2);
        }
        let tri = [poly[0], poly[1], poly[2]];
        let qd = r.q.as_dvec3();
        let nd = r.n.as_dvec3();
        let rel = tri.map(|v| v.as_dvec3() - qd);
        let whole = clip_polygon(&rel, nd);
        let total = if whole.len() >= 3 {
            projected_solid_angle(&whole, nd)
        } else {
            0.0
        };
        if total <= 0.0 || !total.is_finite() {
            return (0.0, 0.0);
        }
        let seen = |y: Vec3| self.sees(r.q, r.ng, y);
        let line = match max_depth {
            0 => None,
            _ => self.fit_line(r, &tri, &seen, rng, EDGE_CHECKS >> depth.min(1)),
        };
        if let Some(fit) = line {
            return (fit.lit_part(&whole, nd, total), total);
        }
        if depth < max_depth {
            let [a, b, c] = tri;
            let (ab, bc, ca) = (a.lerp(b, 0.5), b.lerp(c, 0.5), c.lerp(a, 0.5));
            let mut acc = (0.0, 0.0);
            for t in [[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]] {
                let (l, tt) = self.fit(r, &t, (depth + 1, max_depth), samples / 4, rng);
                acc = (acc.0 + l, acc.1 + tt);
            }
            return acc;
        }
        let fixed = |_: &mut Rng| Receiver {
            q: r.q,
            n: r.n,
            ng: r.ng,
        };
        let sees = |r: &Receiver, y: Vec3| self.sees(r.q, r.ng, y);
        let (w, v) = stratified_tri(
            tri,
            self.front,
            samples.max(LEAF_SAMPLES),
            rng,
            &mut { fixed },
            &sees,
        );
        (if w > 0.0 { total * v / w } else { 0.0 }, total)
    }

    /// How `tri`'s light reaches `r` if its shadow boundary across it is absent, one
    /// straight line (one occluder edge) or two lines meeting inside it (an occluder corner);
    /// `None` otherwise. The boundary is looked for all around the triangle's perimeter
    /// ([`PERIMETER`] points a side) and located by bisection; a fitted model is checked on
    /// both sides close along its boundary (where a bent boundary departs from it) and at
    /// `checks` stratified interior points.
    fn fit_line(
        &self,
        r: &Receiver,
        poly: &[Vec3],
        seen: &dyn Fn(Vec3) -> bool,
        rng: &mut Rng,
        checks: u32,
    ) -> Option<Fit> {
        let m = poly.len();
        let ring: Vec<Vec3> = (0..m)
            .flat_map(|e| {
                (0..PERIMETER)
                    .map(move |i| poly[e].lerp(poly[(e + 1) % m], i as f32 / PERIMETER as f32))
            })
            .collect();
        let vis: Vec<bool> = ring.iter().map(|&y| seen(y)).collect();
        // (crossing point, index of the ring point after it)
        let mut cuts = Vec::with_capacity(4);
        for i in 0..ring.len() {
            let j = (i + 1) % ring.len();
            if vis[i] != vis[j] {
                if cuts.len() == 4 {
                    return None;
                }
                cuts.push((self.bisect(ring[i], ring[j], vis[i], seen), j));
            }
        }
        if let [(e1, a), (e2, b), (e3, c), (e4, d)] = cuts[..] {
            return self.band(
                r,
                poly,
                [e1, e2, e3, e4],
                [ring[a], ring[b], ring[c], ring[d]],
                seen,
                rng,
                checks,
            );
        }
        let cuts: Vec<Vec3> = cuts.iter().map(|c| c.0).collect();
        let [e1, e2] = cuts[..] else {
            let fit = if vis[0] { Fit::Lit } else { Fit::Dark };
            return self
                .check(&fit, r, poly, &[], seen, rng, checks)
                .then_some(fit);
        };
        // one line: lit on the side of the lit perimeter points
        let lit_at = ring[vis.iter().position(|&v| v)?];
        let line = Fit::Region(vec![self.plane(r, e1, e2, lit_at)?], true);
        if self.check(&line, r, poly, &[(e1, e2)], seen, rng, checks) {
            return Some(line);
        }
        let wedge = self.wedge(r, poly, (e1, e2), seen)?;
        let Fit::Region(_, _) = &wedge.0 else {
            return None;
        };
        let segments = [(e1, wedge.1), (wedge.1, e2)];
        let ok = self.check(&wedge.0, r, poly, &segments, seen, rng, checks);
        ok.then_some(wedge.0)
    }

    /// A band of shadow (or light) across the triangle: four boundary crossings `e` around its
    /// perimeter (`after[i]`: a perimeter point just past crossing `i`), joined by two lines,
    /// either `e0 e1` and `e2 e3` or `e1 e2` and `e3 e0`, whichever checks out.
    #[allow(clippy::too_many_arguments)]
    fn band(
        &self,
        r: &Receiver,
        poly: &[Vec3],
        e: [Vec3; 4],
        after: [Vec3; 4],
        seen: &dyn Fn(Vec3) -> bool,
        rng: &mut Rng,
        checks: u32,
    ) -> Option<Fit> {
        for s in [0, 1] {
            let (a0, a1, b0, b1) = (e[s], e[s + 1], e[s + 2], e[(s + 3) % 4]);
            // the middle region holds the perimeter past the first line's second crossing
            let inside = after[s + 1];
            let planes = vec![
                self.plane(r, a0, a1, inside)?,
                self.plane(r, b0, b1, inside)?,
            ];
            let fit = Fit::Region(planes, seen(inside));
            if self.check(&fit, r, poly, &[(a0, a1), (b0, b1)], seen, rng, checks) {
                return Some(fit);
            }
        }
        None
    }

    /// The plane through the receiver and points `a`, `b` of the emitter, as the normal of the
    /// half-space that holds `inside` (`None` if degenerate).
    fn plane(&self, r: &Receiver, a: Vec3, b: Vec3, inside: Vec3) -> Option<DVec3> {
        let qd = r.q.as_dvec3();
        let mut m = (a.as_dvec3() - qd).cross(b.as_dvec3() - qd);
        if m.dot(inside.as_dvec3() - qd) < 0.0 {
            m = -m;
        }
        (m.length_squared() > 0.0 && m.is_finite()).then_some(m)
    }

    /// A corner of the shadow: the boundary enters at `e1`, bends once at an apex inside the
    /// triangle, and leaves at `e2`. The apex is where the boundary lines through `e1` and
    /// `e2` meet, each found from a second boundary point (by bisection across the bulge).
    /// Returns the model (the region on the segment `e1 e2`'s side of both lines, lit or
    /// not as its midpoint) and the apex.
    fn wedge(
        &self,
        r: &Receiver,
        poly: &[Vec3],
        (e1, e2): (Vec3, Vec3),
        seen: &dyn Fn(Vec3) -> bool,
    ) -> Option<(Fit, Vec3)> {
        let mid = e1.lerp(e2, 0.5);
        let mid_lit = seen(mid);
        let w = self.front.as_vec3().cross(e2 - e1).normalize_or_zero();
        // the bulge side: where a perpendicular from the segment crosses the boundary
        let reach = |from: Vec3, dir: Vec3| exit_point(poly, from, dir);
        let side = [w, -w]
            .into_iter()
            .find(|&d| reach(mid, d).is_some_and(|end| seen(end) != mid_lit))?;
        let cross = |t: f32| {
            let from = e1.lerp(e2, t);
            let end = reach(from, side)?;
            let v0 = seen(from);
            (seen(end) != v0).then(|| self.bisect(from, end, v0, seen))
        };
        let (b1, b2) = (cross(0.25)?, cross(0.75)?);
        let apex = intersect_lines(e1, b1, e2, b2, self.front.as_vec3())?;
        let planes = vec![self.plane(r, e1, apex, mid)?, self.plane(r, apex, e2, mid)?];
        Some((Fit::Region(planes, mid_lit), apex))
    }

    /// Whether `fit` predicts what `seen` says: just either side of each of `boundary`'s
    /// segments along it, and at `checks` stratified points of the triangle.
    #[allow(clippy::too_many_arguments)]
    fn check(
        &self,
        fit: &Fit,
        r: &Receiver,
        poly: &[Vec3],
        boundary: &[(Vec3, Vec3)],
        seen: &dyn Fn(Vec3) -> bool,
        rng: &mut Rng,
        checks: u32,
    ) -> bool {
        let qd = r.q.as_dvec3();
        let predict = |y: Vec3| fit.lit(y.as_dvec3() - qd);
        for &(a, b) in boundary {
            let nrm = self.front.as_vec3().cross(b - a).normalize_or_zero();
            let eps = (b - a).length() / 256.0;
            for k in 1..LINE_CHECKS {
                let on = a.lerp(b, k as f32 / LINE_CHECKS as f32);
                for side in [-1.0f32, 1.0] {
                    let y = on + nrm * (side * eps);
                    if predict(y) != seen(y) {
                        return false;
                    }
                }
            }
        }
        (0..checks).all(|_| {
            let y = interior_point(poly, rng);
            predict(y) == seen(y)
        })
    }

    /// The point where visibility changes along `p0 -> p1` (`v0` at `p0`), to `2^-BISECTIONS`
    /// of the edge.
    fn bisect(&self, p0: Vec3, p1: Vec3, v0: bool, seen: &dyn Fn(Vec3) -> bool) -> Vec3 {
        let (mut lo, mut hi) = (0.0f32, 1.0f32);
        for _ in 0..BISECTIONS {
            let mid = 0.5 * (lo + hi);
            if seen(p0.lerp(p1, mid)) == v0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        p0.lerp(p1, 0.5 * (lo + hi))
    }

    /// Whether nothing stands between `r` and any point of the flat piece `poly`, proved by one
    /// traversal of the pyramid the shadow rays would fill ([`Accel::pyramid_clear`]): from the
    /// rays' offset origin to the piece pulled in as they stop short of it. What the first
    /// pass's rays would say there, Lit, without them. Not for a piece whose vertex normals
    /// decide its side point by point, nor one reaching down to the receiver's plane (its rays
    /// may leave from another origin; and the cap that keeps the receiver's own surface out of
    /// the pyramid needs the pyramid above it).
    fn clear(&self, r: &Receiver, poly: &[Vec3]) -> bool {
        if self.shade {
            return false;
        }
        // the rays' origin, lifted off the receiver's plane: how far is `offset_origin`'s own
        // lift, and every ray leaves from it where every corner is above it
        let o = offset_origin(r.q, r.ng, poly[0] - r.q);
        let lift = r.ng.dot(o - r.q);
        if lift.is_nan() || lift <= 0.0 || poly.iter().any(|&c| r.ng.dot(c - r.q) <= lift) {
            return false;
        }
        let keep = 1.0 - super::SHADOW_SHORTEN;
        let base: Vec<Vec3> = poly.iter().map(|&c| o + (c - o) * keep).collect();
        let cap = (r.ng, r.ng.dot(r.q) + 0.5 * lift);
        self.accel.pyramid_clear(o, &base, cap)
    }

    /// Whether emitter point `y` lights receiver point `q`: it faces `q` (front side, and the
    /// shading normal for smooth emitters) and nothing blocks the way.
    fn sees(&self, q: Vec3, ng: Vec3, y: Vec3) -> bool {
        let v = (q - y).as_dvec3();
        if v.dot(self.front) <= 0.0 {
            return false;
        }
        if self.shade {
            let (b1, b2) = self.mesh.barycentric(self.t, y);
            if self.mesh.shading_normal(self.t, b1, b2).dot(q - y) <= 0.0 {
                return false;
            }
        }
        super::visible_to(self.accel, q, ng, y)
    }
}
