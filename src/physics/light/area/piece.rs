//! An area emitter split into the flat convex pieces its shadows are fitted over: two
//! consecutive triangles that share an edge in one plane (a `rectangle`, an OBJ quad) make one
//! quad, anything else stays a triangle. A shadow line crossing a rectangular light crosses
//! both of its triangles; fitted over the quad it is searched for, bisected and checked once
//! instead of twice, and a quad in full light or full shadow is told so by one ring of
//! perimeter rays and one set of interior checks.

use super::front_normal;
use crate::scene::Mesh;
use glam::{DVec3, Vec3};

/// Least cosine between the two triangles' front normals (and a flat emitter's vertex normals
/// and its front) for one plane.
const COPLANAR: f64 = 1.0 - 1e-9;

/// One piece: its first triangle and its corners in order around it (3 or 4).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Piece {
    pub t: usize,
    pub corners: [Vec3; 4],
    pub n: usize,
}

impl Piece {
    /// Its corners in order (3 for a triangle, 4 for a quad).
    pub fn poly(&self) -> &[Vec3] {
        &self.corners[..self.n]
    }

    /// Its triangles' indices in the mesh.
    pub fn triangles(&self) -> std::ops::Range<usize> {
        self.t..self.t + self.n - 2
    }
}

/// The mesh's pieces, in triangle order: each triangle pairs with the next where the two make
/// a flat convex quad ([`quad`]).
pub(crate) fn pieces(mesh: &Mesh) -> Vec<Piece> {
    let mut out = Vec::with_capacity(mesh.triangles.len());
    let mut t = 0;
    while t < mesh.triangles.len() {
        if let Some(corners) = quad(mesh, t) {
            out.push(Piece { t, corners, n: 4 });
            t += 2;
            continue;
        }
        let [a, b, c] = mesh.triangle(t);
        out.push(Piece {
            t,
            corners: [a, b, c, c],
            n: 3,
        });
        t += 1;
    }
    out
}

/// Triangles `t` and `t + 1` as one quad, corners in `t`'s winding, if they share an edge, face
/// the same way in one plane, make a strictly convex quad, and any vertex normals are that
/// plane's (a curved emitter decides its side point by point, so it stays in triangles).
fn quad(mesh: &Mesh, t: usize) -> Option<[Vec3; 4]> {
    let a = mesh.triangles[t];
    let b = *mesh.triangles.get(t + 1)?;
    let e = (0..3).find(|&e| b.contains(&a[e]) && b.contains(&a[(e + 1) % 3]))?;
    let far = *b.iter().find(|v| !a.contains(v))?;
    let front = front_normal(mesh, t)?;
    if front.dot(front_normal(mesh, t + 1)?) < COPLANAR {
        return None;
    }
    let ids = [a[e], far, a[(e + 1) % 3], a[(e + 2) % 3]];
    if let Some(ns) = &mesh.normals {
        let flat = ids.iter().all(|&i| {
            ns.get(i as usize)
                .is_some_and(|n| n.as_dvec3().normalize_or_zero().dot(front) >= COPLANAR)
        });
        if !flat {
            return None;
        }
    }
    let corners = ids.map(|i| mesh.positions[i as usize]);
    convex(&corners, front).then_some(corners)
}

/// Whether the quad turns the same way, strictly, at each corner about `front` (either way).
fn convex(c: &[Vec3; 4], front: DVec3) -> bool {
    let turns = (0..4).map(|i| {
        let (p, q, r) = (c[i], c[(i + 1) % 4], c[(i + 2) % 4]);
        (q - p).as_dvec3().cross((r - q).as_dvec3()).dot(front)
    });
    let turns: Vec<f64> = turns.collect();
    turns.iter().all(|&s| s > 0.0) || turns.iter().all(|&s| s < 0.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::physics::light::tests::{quad as rect, tri};

    fn mesh(positions: Vec<Vec3>, triangles: Vec<[u32; 3]>) -> Mesh {
        Mesh {
            positions,
            normals: None,
            uvs: None,
            triangles,
            flipped: Vec::new(),
        }
    }

    #[test]
    fn a_rectangle_is_one_quad_with_its_four_corners_in_order() {
        let m = rect(Vec3::new(0.0, 2.0, 0.0), Vec3::X * 0.5, Vec3::Z * 0.3);
        let p = pieces(&m);
        assert_eq!(p.len(), 1);
        assert_eq!((p[0].t, p[0].n, p[0].triangles()), (0, 4, 0..2));
        let mut want: Vec<Vec3> = m.positions.clone();
        let mut got: Vec<Vec3> = p[0].poly().to_vec();
        let key = |v: &Vec3| (v.x.to_bits(), v.z.to_bits());
        want.sort_by_key(key);
        got.sort_by_key(key);
        assert_eq!(got, want);
        // in order around: consecutive corners are a side apart, never the diagonal
        for i in 0..4 {
            let d = p[0].corners[i].distance(p[0].corners[(i + 1) % 4]);
            assert!((d - 0.5).abs() < 1e-6 || (d - 0.3).abs() < 1e-6, "{d}");
        }
    }

    #[test]
    fn folded_concave_or_disjoint_pairs_stay_triangles() {
        let flat = |y: f32| {
            vec![
                Vec3::ZERO,
                Vec3::X,
                Vec3::new(1.0, y, 1.0),
                Vec3::Z,
                Vec3::new(2.0, 0.0, -0.5),
            ]
        };
        // folded along the diagonal
        assert_eq!(
            pieces(&mesh(flat(0.3), vec![[0, 1, 2], [0, 2, 3]])).len(),
            2
        );
        assert_eq!(
            pieces(&mesh(flat(0.0), vec![[0, 1, 2], [0, 2, 3]])).len(),
            1
        );
        // concave: a reflex corner where the second triangle juts past the first's side
        assert_eq!(
            pieces(&mesh(flat(0.0), vec![[0, 1, 3], [1, 4, 3]])).len(),
            2
        );
        // sharing one vertex only
        assert_eq!(
            pieces(&mesh(flat(0.0), vec![[0, 1, 4], [0, 3, 2]])).len(),
            2
        );
        // one triangle
        assert_eq!(pieces(&tri(Vec3::ZERO, Vec3::X, Vec3::Z)).len(), 1);
    }

    #[test]
    fn curved_vertex_normals_keep_the_triangles_apart() {
        let mut m = rect(Vec3::new(0.0, 2.0, 0.0), Vec3::X * 0.5, Vec3::Z * 0.3);
        let front = front_normal(&m, 0).unwrap().as_vec3();
        m.normals = Some(vec![front; m.positions.len()]);
        assert_eq!(pieces(&m).len(), 1);
        m.normals.as_mut().unwrap()[0] = (front + Vec3::X * 0.1).normalize();
        assert_eq!(pieces(&m).len(), 2);
    }
}
