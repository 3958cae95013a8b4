//! Mitsuba 3's `perspective` camera, exactly: pixel <-> world ray mapping, point projection and
//! pixel footprints. Every stage that relates photo pixels to the scene goes through here, so
//! the conventions live in one place and are proven against Mitsuba renders in
//! `tests/camera.rs`.
//!
//! Conventions (Mitsuba 3, `perspective.cpp` and `perspective_projection`):
//! - the camera looks along local +z; local +x is the image's LEFT, +y is UP;
//! - film position `(sx, sy)` in [0,1]^2 runs right and DOWN; pixel `(i, j)`'s center is at
//!   `((i + 0.5) / W, (j + 0.5) / H)`; continuous pixel coordinates are `(sx W, sy H)`;
//! - the camera-space direction is `x/z = (1 - 2 sx) tan(fov_x / 2)`,
//!   `y/z = (1 - 2 sy) tan(fov_x / 2) / aspect`, with `aspect = W / H`;
//! - `fov` is converted to `fov_x` according to `fov_axis` (see [`fov_x_degrees`]).
//!
//! Mitsuba starts rays at the near clip plane (0.01 along z by default); we start them at the
//! camera center, which only differs for geometry closer than that to the camera.

use crate::scene::{FovAxis, Sensor};
use glam::{Mat4, Vec2, Vec3};

/// Mitsuba's conversion of `fov` (degrees, along `axis`) to the horizontal field of view in
/// degrees, for a film of `aspect = width / height`.
pub fn fov_x_degrees(fov: f32, axis: FovAxis, aspect: f32) -> f32 {
    let fov = fov as f64;
    let aspect = aspect as f64;
    let from_y = |f: f64| (2.0 * ((f.to_radians() / 2.0).tan() * aspect).atan()).to_degrees();
    let fx = match axis {
        FovAxis::X => fov,
        FovAxis::Y => from_y(fov),
        FovAxis::Diagonal => {
            let d = 2.0 * (fov.to_radians() / 2.0).tan();
            let w = d / (1.0 + 1.0 / (aspect * aspect)).sqrt();
            (2.0 * (w / 2.0).atan()).to_degrees()
        }
        FovAxis::Smaller => {
            if aspect > 1.0 {
                from_y(fov)
            } else {
                fov
            }
        }
        FovAxis::Larger => {
            if aspect > 1.0 {
                fov
            } else {
                from_y(fov)
            }
        }
    };
    fx as f32
}

/// A perspective camera ready for ray generation and projection.
#[derive(Debug, Clone)]
pub struct Camera {
    /// The sensor's id.
    pub id: String,
    to_world: Mat4,
    to_camera: Mat4,
    origin: Vec3,
    /// `tan(fov_x / 2)`.
    tan_x: f32,
    /// `tan(fov_x / 2) / aspect`: the half-extent of the image plane at z = 1 along y.
    tan_y: f32,
    width: u32,
    height: u32,
}

impl Camera {
    /// The camera of a Mitsuba `perspective` sensor.
    pub fn from_sensor(s: &Sensor) -> Camera {
        let aspect = s.width as f32 / s.height as f32;
        let fov_x = fov_x_degrees(s.fov, s.fov_axis, aspect).to_radians();
        let tan_x = (0.5 * fov_x).tan();
        Camera {
            id: s.id.clone(),
            to_world: s.to_world,
            to_camera: s.to_world.inverse(),
            origin: s.to_world.transform_point3(Vec3::ZERO),
            tan_x,
            tan_y: tan_x / aspect,
            width: s.width,
            height: s.height,
        }
    }

    pub fn width(&self) -> u32 {
        self.width
    }

    pub fn height(&self) -> u32 {
        self.height
    }

    /// Camera-to-world transform (columns: left, up, forward, position for a `lookat`).
    pub fn to_world(&self) -> &Mat4 {
        &self.to_world
    }

    /// The center of projection in world space.
    pub fn position(&self) -> Vec3 {
        self.origin
    }

    /// Unit world-space viewing direction (the optical axis).
    pub fn forward(&self) -> Vec3 {
        self.to_world.transform_vector3(Vec3::Z).normalize()
    }

    /// Horizontal field of view in radians.
    pub fn fov_x(&self) -> f32 {
        2.0 * self.tan_x.atan()
    }

    /// Camera-space direction (z = 1) through continuous pixel coordinates `(px, py)`.
    #[inline]
    fn local_dir(&self, px: f32, py: f32) -> Vec3 {
        let sx = px / self.width as f32;
        let sy = py / self.height as f32;
        Vec3::new(
            (1.0 - 2.0 * sx) * self.tan_x,
            (1.0 - 2.0 * sy) * self.tan_y,
            1.0,
        )
    }

    /// The primary ray through continuous pixel coordinates `(px, py)` (`px` in `[0, W)`
    /// rightwards, `py` in `[0, H)` downwards; pixel `(i, j)`'s center is `(i + 0.5, j + 0.5)`):
    /// `(origin, unit direction)` in world space.
    #[inline]
    pub fn ray(&self, px: f32, py: f32) -> (Vec3, Vec3) {
        let d = self.to_world.transform_vector3(self.local_dir(px, py));
        (self.origin, d.normalize())
    }

    /// Continuous pixel coordinates of world point `p` (not clipped to the image), or `None` if
    /// `p` is not in front of the camera.
    #[inline]
    pub fn project(&self, p: Vec3) -> Option<Vec2> {
        let q = self.to_camera.transform_point3(p);
        if q.z <= 0.0 || !q.is_finite() {
            return None;
        }
        let sx = 0.5 * (1.0 - q.x / (q.z * self.tan_x));
        let sy = 0.5 * (1.0 - q.y / (q.z * self.tan_y));
        Some(Vec2::new(sx * self.width as f32, sy * self.height as f32))
    }

    /// Whether any point of the axis-aligned box `lo..hi` may be in view (conservative: `false`
    /// only if the whole box is behind the camera or outside one side of the frustum).
    pub fn may_see(&self, lo: Vec3, hi: Vec3) -> bool {
        let corners: Vec<Vec3> = (0..8)
            .map(|i| {
                let c = Vec3::new(
                    if i & 1 == 0 { lo.x } else { hi.x },
                    if i & 2 == 0 { lo.y } else { hi.y },
                    if i & 4 == 0 { lo.z } else { hi.z },
                );
                self.to_camera.transform_point3(c)
            })
            .collect();
        let (tx, ty) = (self.tan_x, self.tan_y);
        // inside: z > 0, |x| <= tx z, |y| <= ty z
        let outside: [&dyn Fn(Vec3) -> bool; 5] = [
            &|q| q.z <= 0.0,
            &|q| q.x > tx * q.z,
            &|q| q.x < -tx * q.z,
            &|q| q.y > ty * q.z,
            &|q| q.y < -ty * q.z,
        ];
        !outside.iter().any(|out| corners.iter().all(|&q| out(q)))
    }

    /// Whether continuous pixel coordinates fall on the film.
    #[inline]
    pub fn on_film(&self, pix: Vec2) -> bool {
        pix.x >= 0.0 && pix.y >= 0.0 && pix.x < self.width as f32 && pix.y < self.height as f32
    }

    /// The integer pixel `(i, j)` containing world point `p`, if it is in front of the camera
    /// and on the film.
    #[inline]
    pub fn pixel_of(&self, p: Vec3) -> Option<(u32, u32)> {
        let q = self.project(p)?;
        self.on_film(q).then_some((q.x as u32, q.y as u32))
    }

    /// World-space area that one pixel covers, to first order, on a surface through `p` with
    /// normal `n` (either orientation): `|dP/dpx x dP/dpy|` for the ray-plane intersection `P`.
    /// `f32::INFINITY` if `p` is behind the camera or the surface is seen edge-on.
    pub fn pixel_footprint_area(&self, p: Vec3, n: Vec3) -> f32 {
        let q = self.to_camera.transform_point3(p);
        if q.z <= 0.0 {
            return f32::INFINITY;
        }
        let v = p - self.origin;
        let nv = n.dot(v);
        if nv == 0.0 || !nv.is_finite() {
            return f32::INFINITY;
        }
        // The (unnormalized) world direction D(px, py) = M (x/z, y/z, 1) is linear in the pixel
        // coordinates; the hit is P = o + t D with t = q.z (so that t D(p's pixel) = v).
        let dx = self.to_world.transform_vector3(Vec3::new(
            -2.0 * self.tan_x / self.width as f32,
            0.0,
            0.0,
        ));
        let dy = self.to_world.transform_vector3(Vec3::new(
            0.0,
            -2.0 * self.tan_y / self.height as f32,
            0.0,
        ));
        let (a, b) = (dx * q.z, dy * q.z);
        let pa = a - v * (n.dot(a) / nv);
        let pb = b - v * (n.dot(b) / nv);
        pa.cross(pb).length()
    }

    /// Solid angle (steradians) that the pixel containing the direction towards `p` subtends
    /// at the camera, to first order.
    pub fn pixel_solid_angle(&self, p: Vec3) -> f32 {
        let v = p - self.origin;
        let d2 = v.length_squared();
        if d2 == 0.0 {
            return 0.0;
        }
        let a = self.pixel_footprint_area(p, v);
        if a.is_finite() {
            a / d2
        } else {
            0.0
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lookat(origin: Vec3, target: Vec3, up: Vec3) -> Mat4 {
        // Mitsuba's lookat: columns (left, up, dir, origin).
        let dir = (target - origin).normalize();
        let left = up.normalize().cross(dir).normalize();
        let new_up = dir.cross(left);
        Mat4::from_cols(
            left.extend(0.0),
            new_up.extend(0.0),
            dir.extend(0.0),
            origin.extend(1.0),
        )
    }

    fn sensor(w: u32, h: u32, fov: f32, axis: FovAxis, to_world: Mat4) -> Sensor {
        Sensor {
            id: "cam".into(),
            to_world,
            fov,
            fov_axis: axis,
            width: w,
            height: h,
        }
    }

    fn cams() -> Vec<Camera> {
        let m1 = lookat(Vec3::new(-0.8, 1.0, 3.6), Vec3::new(0.0, 1.0, 0.0), Vec3::Y);
        let m2 = lookat(
            Vec3::new(3.0, -2.0, 1.0),
            Vec3::new(0.3, 0.2, -1.0),
            Vec3::Z,
        ) * Mat4::from_scale(Vec3::new(2.0, 0.5, 3.0));
        vec![
            Camera::from_sensor(&sensor(256, 256, 42.0, FovAxis::X, m1)),
            Camera::from_sensor(&sensor(320, 180, 50.0, FovAxis::Y, m1)),
            Camera::from_sensor(&sensor(100, 300, 70.0, FovAxis::Diagonal, m2)),
            Camera::from_sensor(&sensor(64, 48, 30.0, FovAxis::Smaller, Mat4::IDENTITY)),
        ]
    }

    #[test]
    fn fov_axis_conversions_match_hand_computed_values() {
        let close = |a: f32, b: f32| assert!((a - b).abs() < 1e-3, "{a} vs {b}");
        close(fov_x_degrees(40.0, FovAxis::X, 2.0), 40.0);
        // y: 2 atan(tan(20 deg) * 2) = 2 atan(0.727940) = 72.1048 deg
        close(fov_x_degrees(40.0, FovAxis::Y, 2.0), 72.1048);
        // diagonal, aspect 4/3: d = 2 tan 30 = 1.154701, w = d / sqrt(1 + 9/16) = 0.923760,
        // 2 atan(0.461880) = 49.5826 deg
        close(fov_x_degrees(60.0, FovAxis::Diagonal, 4.0 / 3.0), 49.5826);
        // smaller: y for landscape, x for portrait; larger the other way round
        close(
            fov_x_degrees(40.0, FovAxis::Smaller, 2.0),
            fov_x_degrees(40.0, FovAxis::Y, 2.0),
        );
        close(fov_x_degrees(40.0, FovAxis::Smaller, 0.5), 40.0);
        close(fov_x_degrees(40.0, FovAxis::Larger, 2.0), 40.0);
        close(
            fov_x_degrees(40.0, FovAxis::Larger, 0.5),
            fov_x_degrees(40.0, FovAxis::Y, 0.5),
        );
        // y with aspect 0.5: 2 atan(tan 20 * 0.5) = 20.6282 deg
        close(fov_x_degrees(40.0, FovAxis::Y, 0.5), 20.6282);
        // square: every axis but diagonal is the same
        for a in [FovAxis::X, FovAxis::Y, FovAxis::Smaller, FovAxis::Larger] {
            close(fov_x_degrees(33.0, a, 1.0), 33.0);
        }
    }

    #[test]
    fn ray_then_project_round_trips() {
        for c in cams() {
            let (w, h) = (c.width() as f32, c.height() as f32);
            for &(fx, fy) in &[
                (0.5, 0.5),
                (0.01, 0.02),
                (0.99, 0.3),
                (0.25, 0.97),
                (0.7, 0.6),
            ] {
                let (px, py) = (fx * w, fy * h);
                let (o, d) = c.ray(px, py);
                assert!((d.length() - 1.0).abs() < 1e-5);
                assert!((o - c.position()).length() < 1e-6);
                for t in [0.1, 1.0, 7.5] {
                    let q = c.project(o + d * t).unwrap();
                    assert!(
                        (q - Vec2::new(px, py)).length() < 2e-3,
                        "{}: {q} vs ({px}, {py})",
                        c.id
                    );
                }
                assert!(c.project(o - d).is_none(), "behind the camera");
            }
        }
    }

    #[test]
    fn optical_axis_projects_to_the_center() {
        for c in cams() {
            let q = c.project(c.position() + c.forward() * 3.0).unwrap();
            let center = Vec2::new(c.width() as f32, c.height() as f32) * 0.5;
            assert!((q - center).length() < 1e-3, "{q} vs {center}");
            let (_, d) = c.ray(center.x, center.y);
            assert!((d - c.forward()).length() < 1e-5);
        }
    }

    #[test]
    fn local_x_is_left_and_y_is_up() {
        for c in cams() {
            let m = *c.to_world();
            let p = |l: Vec3| m.transform_point3(l);
            let left = c.project(p(Vec3::new(0.2, 0.0, 1.0))).unwrap();
            let up = c.project(p(Vec3::new(0.0, 0.2, 1.0))).unwrap();
            assert!(left.x < 0.5 * c.width() as f32, "{}: +x at {left}", c.id);
            assert!(up.y < 0.5 * c.height() as f32, "{}: +y at {up}", c.id);
        }
        // The top-left pixel looks towards local (+x, +y).
        let c = &cams()[0];
        let (_, d) = c.ray(0.5, 0.5);
        let l = c.to_world().inverse().transform_vector3(d);
        assert!(l.x > 0.0 && l.y > 0.0 && l.z > 0.0, "{l}");
    }

    #[test]
    fn film_edges_span_fov_x() {
        let s = sensor(200, 100, 40.0, FovAxis::Y, Mat4::IDENTITY);
        let c = Camera::from_sensor(&s);
        let (_, l) = c.ray(0.0, 50.0);
        let (_, r) = c.ray(200.0, 50.0);
        let fov_x = l.angle_between(r).to_degrees();
        assert!((fov_x - fov_x_degrees(40.0, FovAxis::Y, 2.0)).abs() < 1e-3);
        let (_, t) = c.ray(100.0, 0.0);
        let (_, b) = c.ray(100.0, 100.0);
        assert!((t.angle_between(b).to_degrees() - 40.0).abs() < 1e-3);
    }

    /// The footprint agrees with intersecting the rays through neighbouring pixels with the
    /// plane, and the solid angles of all pixels add up to the film's solid angle.
    #[test]
    fn footprint_matches_finite_differences() {
        for c in cams() {
            let n = Vec3::new(0.3, -0.8, 0.52).normalize();
            for &(px, py) in &[(10.3, 20.7), (40.0, 30.0)] {
                let (o, d) = c.ray(px, py);
                let p = o + d * 4.0;
                let hit = |px: f32, py: f32| {
                    let (o, d) = c.ray(px, py);
                    o + d * (n.dot(p - o) / n.dot(d))
                };
                let e = 0.01;
                let ax = (hit(px + e, py) - hit(px - e, py)) / (2.0 * e);
                let ay = (hit(px, py + e) - hit(px, py - e)) / (2.0 * e);
                let fd = ax.cross(ay).length();
                let a = c.pixel_footprint_area(p, n);
                assert!((a - fd).abs() < 1e-2 * fd, "{}: {a} vs {fd}", c.id);
                assert_eq!(a, c.pixel_footprint_area(p, -n));
            }
            assert!(c
                .pixel_footprint_area(c.position() - c.forward(), Vec3::Z)
                .is_infinite());
        }
        // sum of pixel solid angles = solid angle of the film rectangle
        let c = Camera::from_sensor(&sensor(64, 48, 60.0, FovAxis::X, Mat4::IDENTITY));
        let mut sum = 0.0f64;
        for j in 0..48 {
            for i in 0..64 {
                let (o, d) = c.ray(i as f32 + 0.5, j as f32 + 0.5);
                sum += c.pixel_solid_angle(o + d * 2.0) as f64;
            }
        }
        // solid angle of a rectangle [-a, a] x [-b, b] at distance 1: 4 asin(ab / sqrt((1+a^2)(1+b^2)))
        let a = (30.0f64).to_radians().tan();
        let b = a * 48.0 / 64.0;
        let exact = 4.0 * (a * b / ((1.0 + a * a) * (1.0 + b * b)).sqrt()).asin();
        assert!((sum - exact).abs() < 1e-3 * exact, "{sum} vs {exact}");
    }
}
