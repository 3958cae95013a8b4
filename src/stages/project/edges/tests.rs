//! Edge points against the cube's known edges; edge offsets against a step of known place.

use super::*;
use crate::atlas::testing::Built;
use crate::physics::camera::Camera;
use crate::scene::{FovAxis, PixelFilter, Sensor};
use glam::Mat4;

/// Mitsuba's lookat frame: columns (left, up, dir, origin).
fn lookat(origin: Vec3, target: Vec3) -> Mat4 {
    let dir = (target - origin).normalize();
    let left = Vec3::Y.cross(dir).normalize();
    Mat4::from_cols(
        left.extend(0.0),
        dir.cross(left).extend(0.0),
        dir.extend(0.0),
        origin.extend(1.0),
    )
}

fn camera(origin: Vec3, size: u32) -> Camera {
    let m = lookat(origin, Vec3::ZERO);
    Camera::from_sensor(&Sensor::simple(
        "cam",
        m,
        40.0,
        FovAxis::X,
        (size, size),
        PixelFilter::Box,
    ))
}

#[test]
fn the_edges_of_a_cube_lie_on_its_edges_and_run_along_them() {
    let b = Built::cube(4.0);
    let cam = camera(Vec3::new(3.0, 2.2, 4.1), 96);
    let found = edges(&b.p.scene, &b.p.accel, &cam);
    assert!(found.len() > 200, "{} edge points", found.len());
    for e in &found {
        // On a cube edge: two of the three coordinates at +-1.
        let on = (e.point.to_array().iter())
            .filter(|c| (c.abs() - 1.0).abs() < 2e-3)
            .count();
        assert!(on >= 2, "{e:?} is not on an edge of the cube");
        // Along an axis: the tangent is parallel to the one coordinate that varies.
        let free = (0..3)
            .find(|&i| (e.point[i].abs() - 1.0).abs() >= 2e-3)
            .unwrap_or(0);
        let t = e.tangent.normalize();
        if (e.point[free].abs() - 1.0).abs() >= 2e-3 {
            assert!(
                t[free].abs() > 0.999,
                "{e:?}: tangent not along axis {free}"
            );
        }
    }
    // Where the geometry is one plane the photo's edges are not looked for.
    let face_on = camera(Vec3::new(0.0, 0.0, 1.5), 32);
    let inside = edges(&b.p.scene, &b.p.accel, &face_on);
    assert!(inside.is_empty(), "{} edges on one face", inside.len());
}

#[test]
fn a_smooth_surface_that_turns_fast_between_pixels_has_edges_only_on_its_outline() {
    // Mitsuba's sphere, smooth-shaded, about 9 px across: from one pixel centre to the next
    // its normals turn 13 degrees at the centre and more towards the outline, past the
    // crease angle, and points recede past the depth step; none of that is an edge.
    let shape = crate::scene::Shape::plain(
        "ball",
        crate::scene::mesh::sphere(),
        crate::scene::Sides::Front,
    );
    let b = Built::new(vec![shape], vec![], 4.0, vec![]);
    let eye = Vec3::new(2.0, 2.5, 9.2);
    let cam = camera(eye, 32);
    let found = edges(&b.p.scene, &b.p.accel, &cam);
    assert!(
        found.len() > 20,
        "{} edge points on the outline",
        found.len()
    );
    for e in &found {
        // on the outline the view ray grazes the sphere: normal (the point) across the ray
        let grazing = e.point.normalize().dot((e.point - eye).normalize()).abs();
        assert!(grazing < 0.12, "{e:?}: inside the outline ({grazing:.3})");
    }
}

/// A `w x h` photo of a vertical step at `x = at` (pixels are box-filtered: a pixel the step
/// crosses holds the mix of its covered parts), `lo` left of it and `hi` right.
fn step(w: u32, h: u32, at: f32, (lo, hi): (f32, f32)) -> Image {
    let px = |x: u32| {
        let right = (x as f32 + 1.0 - at).clamp(0.0, 1.0);
        Vec3::splat(lo * (1.0 - right) + hi * right)
    };
    Image {
        width: w,
        height: h,
        pixels: (0..w * h).map(|i| px(i % w)).collect(),
        valid: vec![true; (w * h) as usize],
        masked: 0,
    }
}

fn blurred(img: &Image, sigma: f32) -> EdgeImage {
    let (w, h) = (img.width as usize, img.height as usize);
    EdgeImage::new(img, sigma, |v, m| {
        super::super::pose::blur(v, m, w, h, sigma).0
    })
}

#[test]
fn a_step_is_found_where_it_is_to_a_tenth_of_a_pixel() {
    for (at, contrast) in [
        (20.3f32, (0.2f32, 1.0f32)),
        (20.8, (2.0, 0.5)),
        (21.0, (0.1, 0.14)),
    ] {
        let img = step(40, 12, at, contrast);
        for sigma in [0.8f32, 2.0] {
            let e = blurred(&img, sigma);
            for from in [18.0f32, 19.7, 22.2] {
                let p = Vec2::new(from, 6.5);
                let d = e.offset(p, Vec2::X, 3.0 * sigma + 3.0).expect("an edge");
                assert!(
                    (from + d - at).abs() < 0.1,
                    "step at {at}, from {from}: {d}"
                );
                // Along the opposite normal the offset is the opposite.
                let back = e.offset(p, -Vec2::X, 3.0 * sigma + 3.0).unwrap();
                assert!((back + d).abs() < 1e-4, "{back} vs {d}");
            }
        }
    }
}

#[test]
fn no_edge_is_measured_where_there_is_none_or_beyond_reach() {
    let flat = step(40, 12, 100.0, (0.5, 0.5));
    assert_eq!(
        blurred(&flat, 1.0).offset(Vec2::new(20.0, 6.5), Vec2::X, 3.0),
        None
    );
    // 4% is below the contrast an edge needs.
    let faint = step(40, 12, 20.5, (1.0, 1.04));
    assert_eq!(
        blurred(&faint, 1.0).offset(Vec2::new(20.0, 6.5), Vec2::X, 3.0),
        None
    );
    // An edge 6 px away is not within a reach of 3 px.
    let far = step(40, 12, 26.0, (0.2, 1.0));
    assert_eq!(
        blurred(&far, 1.0).offset(Vec2::new(20.0, 6.5), Vec2::X, 3.0),
        None
    );
    // Nor is a gain an edge: the same step at any exposure is found at the same place.
    let a =
        blurred(&step(40, 12, 20.4, (0.2, 1.0)), 1.0).offset(Vec2::new(20.0, 6.5), Vec2::X, 3.0);
    let b =
        blurred(&step(40, 12, 20.4, (0.02, 0.1)), 1.0).offset(Vec2::new(20.0, 6.5), Vec2::X, 3.0);
    assert!((a.unwrap() - b.unwrap()).abs() < 1e-4, "{a:?} vs {b:?}");
}

#[test]
fn an_edge_projects_with_a_normal_across_its_image() {
    let cam = camera(Vec3::new(0.0, 0.0, 5.0), 64);
    let e = Edge {
        point: Vec3::new(0.3, -0.2, 0.0),
        tangent: Vec3::Y,
    };
    let (p, n) = in_image(&cam, &e).unwrap();
    assert_eq!(Some(p), cam.project(e.point));
    // A vertical line in the world is vertical in the photo: its normal is horizontal.
    assert!(n.x.abs() > 0.9999 && n.length() > 0.9999, "{n:?}");
}
