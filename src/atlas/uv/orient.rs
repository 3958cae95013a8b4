//! Which side of a two-sided surface its texels stand for: the side the photos see.
//!
//! A `twosided` shape reflects on both sides with one albedo, but a texel holds one
//! irradiance, that of the side its normal points to (direct light from behind the normal
//! counts nothing, the gather looks into the normal's hemisphere). Modelling tools wind
//! triangles either way: the walls of a published interior often have their normals pointing
//! out of the room, so the photos record the lit inner side while the texel's irradiance is
//! that of the dark outer one, and `K_d = L / E` comes out white. Each triangle of a two-sided
//! reconstructed shape is therefore turned (`Mesh::flipped`) to face the side its photos see:
//! the primary rays of every `density::STRIDE`-th pixel of every view vote with the sign of the
//! shading normal along the ray. Triangles no photo sees take the side of the seen triangles
//! they connect to across shared edges (two triangles wound the same way around a shared edge
//! traverse it in opposite directions and keep each other's side; otherwise the side turns).
//! One-sided shapes are never turned: their back reflects nothing, in Mitsuba and here.
//!
//! Deterministic: votes are integer counts and the spread visits triangles in index order.

use super::density::sampled_pixels;
use crate::physics::accel::Accel;
use crate::physics::camera::Camera;
use crate::scene::{Scene, Sides};
use std::collections::{HashMap, VecDeque};

/// What [`orient_two_sided`] did, for the user.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Orientation {
    /// Triangles turned, over all shapes.
    pub flipped: u64,
    /// Ids of the shapes with at least one triangle turned.
    pub shapes: Vec<String>,
}

/// Turns the triangles of every two-sided reconstructed shape of `scene` to face the side the
/// photos of `views` (sensor indices) see; `accel` is the scene's BVH (positions only: turning
/// a triangle does not change it).
pub fn orient_two_sided(scene: &mut Scene, accel: &Accel, views: &[usize]) -> Orientation {
    let votes = side_votes(scene, accel, views);
    let mut out = Orientation::default();
    for (shape, v) in scene.shapes.iter_mut().zip(votes) {
        if !v.iter().any(|&x| x < 0) {
            continue;
        }
        let flipped = spread(&shape.mesh, &v);
        let n = flipped.iter().filter(|&&f| f).count() as u64;
        if n > 0 {
            out.flipped += n;
            out.shapes.push(shape.id.clone());
            shape.mesh.flipped = flipped;
        }
    }
    out
}

/// Per shape and triangle, (pixels that see its front) - (pixels that see its back), for the
/// shapes that can be turned (empty for the others).
fn side_votes(scene: &Scene, accel: &Accel, views: &[usize]) -> Vec<Vec<i32>> {
    let turnable = |s: &crate::scene::Shape| s.sides == Sides::Both && s.is_reconstructed();
    let mut votes: Vec<Vec<i32>> = scene
        .shapes
        .iter()
        .map(|s| match turnable(s) {
            true => vec![0; s.mesh.triangles.len()],
            false => Vec::new(),
        })
        .collect();
    if votes.iter().all(Vec::is_empty) {
        return votes;
    }
    for &v in views {
        let cam = Camera::from_sensor(&scene.sensors[v]);
        let seen = sampled_pixels(&cam, |x, y| {
            let (o, d) = cam.ray(x as f32 + 0.5, y as f32 + 0.5);
            let hit = accel.intersect(o, d, f32::INFINITY)?;
            let s = &scene.shapes[hit.shape as usize];
            if !turnable(s) {
                return None;
            }
            let c = s
                .mesh
                .shading_normal(hit.tri as usize, hit.b1, hit.b2)
                .dot(d);
            (c != 0.0).then_some((hit.shape, hit.tri, if c < 0.0 { 1 } else { -1 }))
        });
        for (s, t, vote) in seen {
            votes[s as usize][t as usize] += vote;
        }
    }
    votes
}

/// The turned triangles of `mesh` from its votes: seen ones by their majority, the rest by
/// the side of the seen ones they connect to (unreached ones keep theirs).
fn spread(mesh: &crate::scene::Mesh, votes: &[i32]) -> Vec<bool> {
    let n = mesh.triangles.len();
    let mut side: Vec<Option<bool>> = votes.iter().map(|&v| (v != 0).then_some(v < 0)).collect();
    let edges = edge_map(mesh);
    let mut queue: VecDeque<usize> = (0..n).filter(|&t| side[t].is_some()).collect();
    while let Some(t) = queue.pop_front() {
        let turned = side[t].unwrap_or(false);
        for (key, forward) in tri_edges(mesh, t) {
            for &(u, u_forward) in edges.get(&key).map_or(&[][..], Vec::as_slice) {
                if side[u].is_some() {
                    continue;
                }
                // Consistent winding runs a shared edge in opposite directions.
                side[u] = Some(if u_forward != forward {
                    turned
                } else {
                    !turned
                });
                queue.push_back(u);
            }
        }
    }
    side.into_iter().map(|s| s.unwrap_or(false)).collect()
}

/// An edge by its two end positions (bit patterns, smaller first): meshes split vertices at
/// UV seams, so indices alone would not connect their triangles.
type EdgeKey = ([u32; 3], [u32; 3]);

/// Triangle `t`'s three edges, each with whether it runs from the smaller key to the larger.
fn tri_edges(mesh: &crate::scene::Mesh, t: usize) -> [(EdgeKey, bool); 3] {
    let p = mesh.triangle(t).map(|v| v.to_array().map(f32::to_bits));
    [(0, 1), (1, 2), (2, 0)].map(|(i, j)| match p[i] <= p[j] {
        true => ((p[i], p[j]), true),
        false => ((p[j], p[i]), false),
    })
}

fn edge_map(mesh: &crate::scene::Mesh) -> HashMap<EdgeKey, Vec<(usize, bool)>> {
    let mut m: HashMap<EdgeKey, Vec<(usize, bool)>> = HashMap::new();
    for t in 0..mesh.triangles.len() {
        for (key, forward) in tri_edges(mesh, t) {
            m.entry(key).or_default().push((t, forward));
        }
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Mesh;
    use glam::Vec3;

    /// Two squares side by side in z = 0 (four triangles); `flip_right` winds the right one
    /// the other way (its normal -z).
    fn strip(flip_right: bool) -> Mesh {
        let positions = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(2.0, 1.0, 0.0),
        ];
        let mut triangles = vec![[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]];
        if flip_right {
            triangles[2] = [1, 5, 4];
            triangles[3] = [1, 2, 5];
        }
        Mesh {
            positions,
            triangles,
            ..Default::default()
        }
    }

    #[test]
    fn seen_triangles_follow_their_votes() {
        let m = strip(false);
        assert_eq!(spread(&m, &[3, -1, 2, -5]), vec![false, true, false, true]);
    }

    #[test]
    fn unseen_triangles_take_the_side_of_their_neighbours() {
        // Only the first triangle is seen, from behind: its consistently wound neighbours
        // turn with it, across the shared edges.
        assert_eq!(spread(&strip(false), &[-2, 0, 0, 0]), vec![true; 4]);
        // The right square is wound the other way: it already faces the seen side.
        assert_eq!(
            spread(&strip(true), &[-2, 0, 0, 0]),
            vec![true, true, false, false]
        );
        // Seen from the front: the seen square keeps its side, the other one turns to it.
        assert_eq!(
            spread(&strip(true), &[4, 0, 0, 0]),
            vec![false, false, true, true]
        );
    }

    #[test]
    fn unreached_triangles_keep_their_side() {
        let mut m = strip(false);
        m.positions.push(Vec3::new(5.0, 5.0, 5.0));
        m.positions.push(Vec3::new(6.0, 5.0, 5.0));
        m.positions.push(Vec3::new(5.0, 6.0, 5.0));
        m.triangles.push([6, 7, 8]);
        assert_eq!(
            spread(&m, &[-1, 0, 0, 0, 0]),
            vec![true, true, true, true, false]
        );
    }

    /// Rectangles at z = 0 (x = 0), z = 0 (x = 3) and z = 0 (x = -3): `wall` twosided with its
    /// normal turned away (-z), `ahead` twosided facing +z, `back` one-sided turned away; a
    /// camera at z = 4 sees all three, a point light of intensity 1 at z = 1.
    fn walls() -> Scene {
        let rect = |id: &str, x: f32, bsdf: &str, flip: bool| {
            format!(
                "<shape type=\"rectangle\" id=\"{id}\"><boolean name=\"flip_normals\" \
                 value=\"{flip}\"/><transform name=\"to_world\"><translate x=\"{x}\"/>\
                 </transform>{bsdf}</shape>"
            )
        };
        let two = "<bsdf type=\"twosided\"><bsdf type=\"diffuse\"/></bsdf>";
        let xml = format!(
            "<scene version=\"3.0.0\">{}{}{}\
             <emitter type=\"point\"><point name=\"position\" x=\"0\" y=\"0\" z=\"1\"/></emitter>\
             <sensor type=\"perspective\" id=\"cam\"><float name=\"fov\" value=\"100\"/>\
             <transform name=\"to_world\"><lookat origin=\"0, 0, 4\" target=\"0, 0, 0\" \
             up=\"0, 1, 0\"/></transform><film type=\"hdrfilm\"><integer name=\"width\" \
             value=\"96\"/><integer name=\"height\" value=\"32\"/></film></sensor></scene>",
            rect("wall", 0.0, two, true),
            rect("ahead", 3.0, two, false),
            rect("back", -3.0, "<bsdf type=\"diffuse\"/>", true),
        );
        crate::scene::mitsuba::parse(&xml, std::path::Path::new("t/scene.xml")).unwrap()
    }

    #[test]
    fn a_two_sided_wall_seen_from_behind_is_turned_and_lit() {
        use crate::physics::light::{direct_irradiance, DirectParams};
        let mut sc = walls();
        let accel = Accel::build(&sc);
        let centre = |sc: &Scene| {
            let n = sc.shapes[0].mesh.shading_normal(0, 0.25, 0.25);
            let ng = sc.shapes[0].mesh.face_normal_raw(0).normalize();
            let e = direct_irradiance(
                sc,
                &accel,
                Vec3::ZERO,
                n,
                ng,
                &DirectParams::default(),
                (1, 2),
            );
            (n, e)
        };
        // before: the texel's side is the far one, which the light does not reach
        let (n, e) = centre(&sc);
        assert!(n.z < 0.0 && e == Vec3::ZERO, "{n} {e}");
        let o = orient_two_sided(&mut sc, &accel, &[0]);
        assert_eq!(
            o,
            Orientation {
                flipped: 2,
                shapes: vec!["wall".into()]
            }
        );
        assert_eq!(sc.shapes[0].mesh.flipped, vec![true, true]);
        assert!(sc.shapes[1].mesh.flipped.is_empty());
        assert!(
            sc.shapes[2].mesh.flipped.is_empty(),
            "one-sided shapes keep their side"
        );
        // after: head-on at distance 1 from a point light of intensity 1, E = 1
        let (n, e) = centre(&sc);
        assert!(n.abs_diff_eq(Vec3::Z, 1e-6), "{n}");
        assert!((e - Vec3::ONE).abs().max_element() < 1e-5, "{e}");
        // turning is idempotent: the turned wall now faces its photos
        let again = orient_two_sided(&mut sc, &accel, &[0]);
        assert_eq!(again.flipped, 0);
    }

    #[test]
    fn without_views_nothing_turns() {
        let mut sc = walls();
        let accel = Accel::build(&sc);
        assert_eq!(
            orient_two_sided(&mut sc, &accel, &[]),
            Orientation::default()
        );
        assert!(sc.shapes.iter().all(|s| s.mesh.flipped.is_empty()));
    }

    #[test]
    fn split_vertices_still_connect() {
        // The right square with its own copies of the shared corners (a UV seam).
        let mut m = strip(false);
        m.positions.push(Vec3::new(1.0, 0.0, 0.0));
        m.positions.push(Vec3::new(1.0, 1.0, 0.0));
        m.triangles[2] = [6, 4, 5];
        m.triangles[3] = [6, 5, 7];
        assert_eq!(spread(&m, &[-1, 0, 0, 0]), vec![true; 4]);
    }
}
