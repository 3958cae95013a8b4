//! Mitsuba 3's `perspective` camera, exactly: pixel <-> world ray mapping, point projection and
//! pixel footprints. Every stage that relates photo pixels to the scene goes through here, so
//! the conventions live in one place and are proven against Mitsuba renders in
//! `tests/it/camera.rs`.
//!
//! Conventions (Mitsuba 3, `perspective.cpp` and `perspective_projection`):
//! - the camera looks along local +z; local +x is the image's LEFT, +y is UP;
//! - film position `(sx, sy)` in [0,1]^2 runs right and DOWN; pixel `(i, j)`'s center is at
//!   `((i + 0.5) / W, (j + 0.5) / H)`; continuous pixel coordinates are `(sx W, sy H)`;
//! - the camera-space direction is `x/z = (1 - 2 sx) tan(fov_x / 2)`,
//!   `y/z = (1 - 2 sy) tan(fov_x / 2) / aspect`, with `aspect = W / H`;
//! - `fov` is converted to `fov_x` according to `fov_axis` (see [`fov_x_degrees`]), with the
//!   aspect of the whole film;
//! - a crop window (`crop_offset_x/y`, `crop_width/height`) is the part of the film the photo
//!   holds: photo pixel `(i, j)` is film pixel `(i + crop_x, j + crop_y)`;
//! - `principal_point_offset_x/y` (fractions of the film size) move the film position a ray
//!   is generated for: the photo's `(sx, sy)` sees what a centered camera sees at
//!   `(sx + offset_x, sy + offset_y)`, so the image moves by `-offset * film size` pixels
//!   (`perspective.cpp`, `sample_ray`: the sample plus `size * offset / crop_size`).
//!
//! Mitsuba starts rays at the near clip plane (0.01 along z by default); we start them at the
//! camera center, which only differs for geometry closer than that to the camera.
//!
//! A sensor with a COLMAP lens (`Sensor::lens`) maps pixels by the lens instead, exactly as
//! COLMAP does (`scene::lens`: `fx != fy`, the principal point anywhere, radial and tangential
//! distortion). Its camera frame is still Mitsuba's (COLMAP's x right, y down is Mitsuba's
//! `(-x, -y)`), so a Mitsuba-frame point `q` has COLMAP's normalized coordinates
//! `(u, v) = (-q.x / q.z, -q.y / q.z)`; `project` distorts them into a pixel, `ray`
//! undistorts a pixel into them, and the frustum of `may_see` and the footprint of
//! `pixel_footprint_area` follow the distortion. A Mitsuba sensor takes none of these paths.

use crate::scene::{FovAxis, Lens, PixelFilter, Sensor};
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
    /// The photo's size (the crop window).
    width: u32,
    height: u32,
    /// The whole film's size, pixels.
    film: Vec2,
    /// Film position of the photo's top-left corner as the rays see it, in fractions of the
    /// film: crop offset / film size + principal point offset (zero for a plain camera).
    shift: Vec2,
    filter: PixelFilter,
    /// A COLMAP camera's lens, which then maps every pixel.
    lens: Option<LensView>,
}

/// A COLMAP lens as a camera sees through it: the lens, and the photo's frustum in Mitsuba's
/// camera frame (`x/z` low and high, `y/z` low and high).
#[derive(Debug, Clone)]
struct LensView {
    lens: Lens,
    frustum: [f32; 4],
}

impl LensView {
    fn new(lens: &Lens, width: u32, height: u32) -> LensView {
        // Mitsuba's x/z is -u and y/z is -v.
        let [u0, u1, v0, v1] = lens.image_bounds(width, height);
        LensView {
            lens: lens.clone(),
            frustum: [-u1 as f32, -u0 as f32, -v1 as f32, -v0 as f32],
        }
    }

    /// Mitsuba camera-space direction (z = 1) through pixel `(px, py)`.
    #[inline]
    fn local_dir(&self, px: f32, py: f32) -> Vec3 {
        let ((u, v), _) = self.lens.normalized(px as f64, py as f64);
        Vec3::new(-u as f32, -v as f32, 1.0)
    }

    /// The pixel of Mitsuba camera-space point `q` (`q.z > 0`), if the lens images it.
    #[inline]
    fn project(&self, q: Vec3) -> Option<Vec2> {
        let z = q.z as f64;
        let (u, v) = (-q.x as f64 / z, -q.y as f64 / z);
        if !self.lens.images(u, v) {
            return None;
        }
        let (x, y) = self.lens.pixel(u, v);
        Some(Vec2::new(x as f32, y as f32))
    }

    /// The derivatives of the Mitsuba camera-space direction (z = 1) with respect to `px` and
    /// `py` at Mitsuba camera-space point `q`: the inverse of the lens's Jacobian, over the
    /// focal lengths.
    fn pixel_steps(&self, q: Vec3) -> (Vec3, Vec3) {
        let z = q.z as f64;
        let (u, v) = (-q.x as f64 / z, -q.y as f64 / z);
        let [[a, b], [c, d]] = self.lens.jacobian(u, v);
        let det = a * d - b * c;
        let (fx, fy) = (self.lens.fx, self.lens.fy);
        // d(u, v)/dpx = J^-1 (1/fx, 0), d(u, v)/dpy = J^-1 (0, 1/fy); Mitsuba's is minus that.
        let dx = Vec3::new((-d / (det * fx)) as f32, (c / (det * fx)) as f32, 0.0);
        let dy = Vec3::new((b / (det * fy)) as f32, (-a / (det * fy)) as f32, 0.0);
        (dx, dy)
    }
}

impl Camera {
    /// The camera of a Mitsuba `perspective` sensor.
    pub fn from_sensor(s: &Sensor) -> Camera {
        let aspect = s.film_width as f32 / s.film_height as f32;
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
            film: Vec2::new(s.film_width as f32, s.film_height as f32),
            shift: Vec2::new(
                s.crop_offset.0 as f32 / s.film_width as f32,
                s.crop_offset.1 as f32 / s.film_height as f32,
            ) + s.principal_point,
            filter: s.filter,
            lens: s.lens.as_ref().map(|l| LensView::new(l, s.width, s.height)),
        }
    }

    /// The same camera (intrinsics, film, filter) at another pose: camera-to-world `m`.
    pub fn with_to_world(&self, m: Mat4) -> Camera {
        Camera {
            to_world: m,
            to_camera: m.inverse(),
            origin: m.transform_point3(Vec3::ZERO),
            ..self.clone()
        }
    }

    /// The film's reconstruction filter.
    pub fn filter(&self) -> PixelFilter {
        self.filter
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
        if let Some(l) = &self.lens {
            return l.local_dir(px, py);
        }
        let sx = px / self.film.x + self.shift.x;
        let sy = py / self.film.y + self.shift.y;
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
        if let Some(l) = &self.lens {
            return l.project(q);
        }
        let sx = 0.5 * (1.0 - q.x / (q.z * self.tan_x)) - self.shift.x;
        let sy = 0.5 * (1.0 - q.y / (q.z * self.tan_y)) - self.shift.y;
        Some(Vec2::new(sx * self.film.x, sy * self.film.y))
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
        let [x_lo, x_hi, y_lo, y_hi] = self.frustum();
        // inside: z > 0, x_lo z <= x <= x_hi z, y_lo z <= y <= y_hi z
        let outside: [&dyn Fn(Vec3) -> bool; 5] = [
            &|q| q.z <= 0.0,
            &|q| q.x > x_hi * q.z,
            &|q| q.x < x_lo * q.z,
            &|q| q.y > y_hi * q.z,
            &|q| q.y < y_lo * q.z,
        ];
        !outside.iter().any(|out| corners.iter().all(|&q| out(q)))
    }

    /// The photo's frustum: `x/z` from `x_lo` to `x_hi` and `y/z` from `y_lo` to `y_hi` in
    /// camera space (a lens's holds its whole image, with a margin).
    fn frustum(&self) -> [f32; 4] {
        if let Some(l) = &self.lens {
            return l.frustum;
        }
        // The photo spans film positions shift .. shift + size / film, i.e. x/z from
        // (1 - 2 sx_max) tan_x to (1 - 2 sx_min) tan_x (and likewise y).
        let (s0, s1) = (
            self.shift,
            self.shift + Vec2::new(self.width as f32, self.height as f32) / self.film,
        );
        let (x_lo, x_hi) = (
            (1.0 - 2.0 * s1.x) * self.tan_x,
            (1.0 - 2.0 * s0.x) * self.tan_x,
        );
        let (y_lo, y_hi) = (
            (1.0 - 2.0 * s1.y) * self.tan_y,
            (1.0 - 2.0 * s0.y) * self.tan_y,
        );
        [x_lo, x_hi, y_lo, y_hi]
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
        // coordinates (through a lens, to first order at p's pixel); the hit is P = o + t D
        // with t = q.z (so that t D(p's pixel) = v).
        let (dx_local, dy_local) = match &self.lens {
            Some(l) => l.pixel_steps(q),
            None => (
                Vec3::new(-2.0 * self.tan_x / self.film.x, 0.0, 0.0),
                Vec3::new(0.0, -2.0 * self.tan_y / self.film.y, 0.0),
            ),
        };
        let dx = self.to_world.transform_vector3(dx_local);
        let dy = self.to_world.transform_vector3(dy_local);
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
        Sensor::simple("cam", to_world, fov, axis, (w, h), PixelFilter::Box)
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
    /// `principal_point_offset_x/y` and a crop window, parsed from XML, move the image as
    /// Mitsuba 3.9.1 does: a point on the optical axis lands at `film / 2 - offset * film -
    /// crop_offset`. The pixel positions asserted were measured on Mitsuba renders of this
    /// camera (80 x 60, fov 40, a small sphere at the origin and one at (0.8, 0.5, 0)):
    /// centers (40, 30) centered, (32, 30) for x = 0.1, (40, 33) for y = -0.05, (32, 18)
    /// for (0.1, 0.2), (22, 13) with the crop window (10, 5) 50 x 40 on top.
    #[test]
    fn principal_point_offset_and_crop_shift_the_image() {
        let cam = |extra: &str, film: &str| {
            let xml = format!(
                "<scene version=\"3.0.0\"><sensor type=\"perspective\">\
                 <float name=\"fov\" value=\"40\"/>{extra}\
                 <transform name=\"to_world\"><lookat origin=\"0,0,5\" target=\"0,0,0\" up=\"0,1,0\"/></transform>\
                 <film type=\"hdrfilm\"><integer name=\"width\" value=\"80\"/>\
                 <integer name=\"height\" value=\"60\"/>{film}</film></sensor></scene>"
            );
            let s = crate::scene::mitsuba::parse(&xml, std::path::Path::new("c.xml")).unwrap();
            Camera::from_sensor(&s.sensors[0])
        };
        let ppo = |x: f32, y: f32| {
            format!(
                "<float name=\"principal_point_offset_x\" value=\"{x}\"/>\
                 <float name=\"principal_point_offset_y\" value=\"{y}\"/>"
            )
        };
        let crop = "<integer name=\"crop_offset_x\" value=\"10\"/><integer name=\"crop_offset_y\" value=\"5\"/>\
                    <integer name=\"crop_width\" value=\"50\"/><integer name=\"crop_height\" value=\"40\"/>";
        let cases = [
            (cam("", ""), Vec2::new(40.0, 30.0)),
            (cam(&ppo(0.1, 0.0), ""), Vec2::new(32.0, 30.0)),
            (cam(&ppo(0.0, -0.05), ""), Vec2::new(40.0, 33.0)),
            (cam(&ppo(0.1, 0.2), ""), Vec2::new(32.0, 18.0)),
            (cam(&ppo(0.1, 0.2), crop), Vec2::new(22.0, 13.0)),
        ];
        let dot = Vec3::new(0.8, 0.5, 0.0);
        // The dot without offsets: x = 40 (1 + 0.8 / (5 tan 20 deg)), y = 30 (1 - 0.5 / (5 tan_y)).
        let tan_x = 20f32.to_radians().tan();
        let dot0 = Vec2::new(
            40.0 * (1.0 + 0.8 / (5.0 * tan_x)),
            30.0 * (1.0 - 0.5 / (5.0 * tan_x * 0.75)),
        );
        for (c, center) in &cases {
            let q = c.project(Vec3::ZERO).unwrap();
            assert!((q - *center).length() < 1e-3, "{q} vs {center}");
            let shift = *center - Vec2::new(40.0, 30.0);
            let d = c.project(dot).unwrap();
            assert!(
                (d - (dot0 + shift)).length() < 1e-3,
                "{d} vs {}",
                dot0 + shift
            );
            // rays through those pixels go back through the points
            let (o, dir) = c.ray(center.x, center.y);
            assert!((o + dir * 5.0).length() < 1e-4);
        }
        let cropped = &cases[4].0;
        assert_eq!((cropped.width(), cropped.height()), (50, 40));
        // The frustum test follows the shifted, cropped window: the dot at (47.6, 4) in
        // the crop is in view, a point projecting left of the crop window is not.
        assert!(cropped.may_see(dot - Vec3::splat(0.01), dot + Vec3::splat(0.01)));
        let left = Vec3::new(0.85, 0.0, 0.0); // x = 22 + 40 * 0.85 / 1.82 = 40.7 px: in view
        assert!(cropped.may_see(left, left));
        // x = 80 (0.5 (1 - 1.2 / 1.82) - 0.1) - 10 = -4.4 px: left of the crop window, though
        // on the film of a centered camera.
        let off = Vec3::new(-1.2, 0.0, 0.0);
        assert!(!cropped.may_see(off, off));
        assert!(cases[0].0.may_see(off, off));
    }

    /// A camera through `lens` on a `w x h` photo at `to_world`.
    fn lens_camera(lens: Lens, (w, h): (u32, u32), to_world: Mat4) -> Camera {
        let mut s = sensor(w, h, 40.0, FovAxis::X, to_world);
        s.lens = Some(lens);
        Camera::from_sensor(&s)
    }

    /// One camera per COLMAP model, the last two strongly distorted, off-centre and with
    /// unequal focal lengths.
    fn lens_cams() -> Vec<Camera> {
        use crate::scene::LensModel as M;
        let m1 = lookat(Vec3::new(-0.8, 1.0, 3.6), Vec3::new(0.0, 1.0, 0.0), Vec3::Y);
        let m2 = lookat(
            Vec3::new(3.0, -2.0, 1.0),
            Vec3::new(0.3, 0.2, -1.0),
            Vec3::Z,
        );
        let l = |m: M, p: &[f64]| Lens::new(m, p).unwrap();
        vec![
            lens_camera(l(M::SimplePinhole, &[300.0, 128.0, 100.0]), (256, 200), m1),
            lens_camera(l(M::Pinhole, &[310.0, 280.0, 140.5, 90.0]), (256, 200), m2),
            lens_camera(
                l(M::SimpleRadial, &[300.0, 128.0, 100.0, -0.1]),
                (256, 200),
                m1,
            ),
            lens_camera(
                l(M::Radial, &[250.0, 120.0, 110.0, -0.2, 0.05]),
                (256, 200),
                m2,
            ),
            lens_camera(
                l(
                    M::OpenCv,
                    &[260.0, 240.0, 140.0, 90.0, 0.1, -0.02, 0.004, -0.003],
                ),
                (256, 200),
                m1,
            ),
        ]
    }

    /// Pixel -> ray -> pixel under every model: within 1e-4 px in camera space (f32 rays),
    /// and through world space as the Mitsuba camera's own round trip.
    #[test]
    fn lens_pixel_ray_pixel_round_trips_under_every_model() {
        for c in lens_cams() {
            let l = c.lens.as_ref().unwrap();
            for j in 0..=10 {
                for i in 0..=10 {
                    let (px, py) = (25.6 * i as f32, 20.0 * j as f32);
                    let q = l.local_dir(px, py) * 3.0;
                    let back = l.project(q).unwrap();
                    let e = (back - Vec2::new(px, py)).length();
                    assert!(e < 1e-4, "{}: ({px}, {py}) -> {back}", l.lens.describe());
                    let (o, d) = c.ray(px, py);
                    let world = c.project(o + d * 2.5).unwrap();
                    assert!((world - Vec2::new(px, py)).length() < 2e-3, "{world}");
                    assert!(c.may_see(o + d * 2.5, o + d * 2.5));
                }
            }
        }
    }

    /// A COLMAP pinhole camera with Mitsuba's pose, `fx = fy = W / (2 tan(fov_x / 2))` and
    /// `(cx, cy) = (W / 2 - offset_x W, H / 2 - offset_y H)` projects every point where the
    /// Mitsuba camera does, within 1e-3 px, and casts the same rays.
    #[test]
    fn a_colmap_pinhole_is_mitsubas_perspective_camera() {
        let m = lookat(Vec3::new(-0.8, 1.1, 3.6), Vec3::new(0.1, 0.9, 0.0), Vec3::Y);
        let mut s = sensor(256, 192, 42.0, FovAxis::X, m);
        s.principal_point = Vec2::new(0.1, -0.05);
        let mitsuba = Camera::from_sensor(&s);
        let f = 128.0 / (21f64).to_radians().tan();
        let lens = Lens::new(
            crate::scene::LensModel::Pinhole,
            &[f, f, 128.0 - 25.6, 96.0 + 9.6],
        )
        .unwrap();
        let colmap = lens_camera(lens, (256, 192), m);
        for k in 0..200 {
            let t = k as f32 * 0.618;
            let p = Vec3::new(
                (t * 1.3).sin() * 1.2,
                1.0 + t.cos() * 0.8,
                (t * 0.7).sin() - 0.5,
            );
            let (a, b) = (mitsuba.project(p).unwrap(), colmap.project(p).unwrap());
            assert!((a - b).length() < 1e-3, "{p}: {a} vs {b}");
            let (px, py) = ((k % 17) as f32 * 15.0, (k % 13) as f32 * 14.7);
            let (da, db) = (mitsuba.ray(px, py).1, colmap.ray(px, py).1);
            assert!((da - db).length() < 1e-6);
        }
    }

    /// Under distortion the footprint still agrees with intersecting the rays through
    /// neighbouring pixels with the plane.
    #[test]
    fn lens_footprint_matches_finite_differences() {
        for c in lens_cams() {
            let n = Vec3::new(0.3, -0.8, 0.52).normalize();
            for &(px, py) in &[(10.3, 20.7), (128.0, 100.0), (250.0, 190.0)] {
                let (o, d) = c.ray(px, py);
                let p = o + d * 4.0;
                let hit = |px: f32, py: f32| {
                    let (o, d) = c.ray(px, py);
                    o + d * (n.dot(p - o) / n.dot(d))
                };
                let e = 0.05;
                let ax = (hit(px + e, py) - hit(px - e, py)) / (2.0 * e);
                let ay = (hit(px, py + e) - hit(px, py - e)) / (2.0 * e);
                let fd = ax.cross(ay).length();
                let a = c.pixel_footprint_area(p, n);
                assert!((a - fd).abs() < 1e-2 * fd, "({px}, {py}): {a} vs {fd}");
            }
        }
    }

    /// The distorted frustum of `may_see` holds every point some pixel sees, and is not
    /// the whole space: a point beyond the image's corner rays is out.
    #[test]
    fn lens_frustum_holds_the_image_and_no_more_than_a_margin() {
        for c in lens_cams() {
            let (w, h) = (c.width() as f32, c.height() as f32);
            for k in 0..=64 {
                let t = k as f32 / 64.0;
                for (px, py) in [(t * w, 0.0), (t * w, h), (0.0, t * h), (w, t * h)] {
                    let (o, d) = c.ray(px, py);
                    let p = o + d * 3.0;
                    assert!(c.may_see(p, p), "({px}, {py})");
                    let q = c.project(p).unwrap();
                    assert!((q - Vec2::new(px, py)).length() < 2e-3);
                }
            }
            // 30% further out than the top-left corner's ray, in camera space
            let l = c.lens.as_ref().unwrap();
            let corner = l.local_dir(0.0, 0.0);
            let out = c
                .to_world()
                .transform_point3(Vec3::new(corner.x * 1.3, corner.y * 1.3, 1.0));
            assert!(!c.may_see(out, out));
            assert!(c.project(out).is_none_or(|q| !c.on_film(q)));
        }
    }
}
