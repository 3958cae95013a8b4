//! COLMAP's perspective camera models as a lens, exactly as COLMAP defines them
//! (`src/colmap/sensor/models.h`), so a camera from structure-from-motion maps pixels to rays
//! as the reconstruction that made it did. Hand-written because the formulas are a few lines
//! and must be COLMAP's to the last operation; no crate holds them.
//!
//! Conventions (COLMAP): the camera looks along +z with x right and y down; a point `(X, Y, Z)`
//! in the camera frame has normalized coordinates `(u, v) = (X / Z, Y / Z)`; the distortion
//! moves them to `(u + du, v + dv)` with
//!
//! ```text
//! r2 = u^2 + v^2,  radial = k1 r2 + k2 r2^2
//! du = u radial + 2 p1 u v + p2 (r2 + 2 u^2)
//! dv = v radial + 2 p2 u v + p1 (r2 + 2 v^2)
//! ```
//!
//! and the pixel is `(fx (u + du) + cx, fy (v + dv) + cy)`, the top-left pixel's centre being
//! `(0.5, 0.5)`. SIMPLE_RADIAL is `k1 = k` alone, RADIAL `k1, k2`, OPENCV all four; the
//! pinhole models have none. A pixel goes back to `(u, v)` by Newton's method on the
//! distortion, as COLMAP's `IterativeUndistortion` does (analytic Jacobian, the same trust
//! region), run to a much tighter tolerance (1e-9 pixels rather than COLMAP's 1e-5 in
//! normalized units).

/// The camera models kdmap reads, by COLMAP's names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LensModel {
    SimplePinhole,
    Pinhole,
    SimpleRadial,
    Radial,
    OpenCv,
}

/// COLMAP's camera models by their id (`CameraModelId`, 0 = SIMPLE_PINHOLE), to name the ones
/// kdmap does not read.
pub const COLMAP_MODELS: [&str; 18] = [
    "SIMPLE_PINHOLE",
    "PINHOLE",
    "SIMPLE_RADIAL",
    "RADIAL",
    "OPENCV",
    "OPENCV_FISHEYE",
    "FULL_OPENCV",
    "FOV",
    "SIMPLE_RADIAL_FISHEYE",
    "RADIAL_FISHEYE",
    "THIN_PRISM_FISHEYE",
    "RAD_TAN_THIN_PRISM_FISHEYE",
    "SIMPLE_DIVISION",
    "DIVISION",
    "SIMPLE_FISHEYE",
    "FISHEYE",
    "EUCM",
    "EQUIRECTANGULAR",
];

/// The models kdmap reads, as a list for refusals.
pub const READ_MODELS: &str = "SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV";

impl LensModel {
    const ALL: [LensModel; 5] = [
        LensModel::SimplePinhole,
        LensModel::Pinhole,
        LensModel::SimpleRadial,
        LensModel::Radial,
        LensModel::OpenCv,
    ];

    /// COLMAP's name of the model.
    pub fn name(self) -> &'static str {
        COLMAP_MODELS[self.id() as usize]
    }

    /// COLMAP's id of the model (the binary format's `model_id`).
    pub fn id(self) -> i32 {
        match self {
            LensModel::SimplePinhole => 0,
            LensModel::Pinhole => 1,
            LensModel::SimpleRadial => 2,
            LensModel::Radial => 3,
            LensModel::OpenCv => 4,
        }
    }

    pub fn from_name(name: &str) -> Option<LensModel> {
        LensModel::ALL.into_iter().find(|m| m.name() == name)
    }

    pub fn from_id(id: i32) -> Option<LensModel> {
        LensModel::ALL.into_iter().find(|m| m.id() == id)
    }

    /// The parameters in COLMAP's order.
    pub fn param_names(self) -> &'static [&'static str] {
        match self {
            LensModel::SimplePinhole => &["f", "cx", "cy"],
            LensModel::Pinhole => &["fx", "fy", "cx", "cy"],
            LensModel::SimpleRadial => &["f", "cx", "cy", "k"],
            LensModel::Radial => &["f", "cx", "cy", "k1", "k2"],
            LensModel::OpenCv => &["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"],
        }
    }
}

/// Why a model id or name is refused, in words: "camera model FULL_OPENCV is not supported
/// (kdmap reads ...)" or "unknown camera model ...".
pub fn refusal(model: &str) -> String {
    if COLMAP_MODELS.contains(&model) {
        format!("camera model {model} is not supported (kdmap reads {READ_MODELS})")
    } else {
        format!("unknown camera model {model} (kdmap reads {READ_MODELS})")
    }
}

/// A COLMAP camera's intrinsics and distortion.
#[derive(Debug, Clone, PartialEq)]
pub struct Lens {
    pub model: LensModel,
    /// The parameters as the model lists them ([`LensModel::param_names`]).
    pub params: Vec<f64>,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// `k1, k2, p1, p2`, zero where the model has none.
    k: [f64; 4],
    /// The undistorted `u^2 + v^2` up to which the distortion is one-to-one (infinite if it
    /// is within [`FOLD_SEARCH`]): points beyond it are not imaged.
    r2_fold: f64,
}

/// How far out (in normalized coordinates, `tan` of the angle off the axis) the fold of a
/// distortion is searched for: 20 is 87 degrees off the axis.
const FOLD_SEARCH: f64 = 20.0;

/// Newton's method stops when its step is below this, in pixels.
const NEWTON_TOL_PX: f64 = 1e-9;

impl Lens {
    /// The lens of `model` with COLMAP's `params`; refused when their count is wrong, one is
    /// not finite or a focal length is not positive.
    pub fn new(model: LensModel, params: &[f64]) -> Result<Lens, String> {
        let names = model.param_names();
        if params.len() != names.len() {
            return Err(format!(
                "{} takes {} parameters ({}), not {}",
                model.name(),
                names.len(),
                names.join(", "),
                params.len()
            ));
        }
        if let Some(i) = params.iter().position(|p| !p.is_finite()) {
            return Err(format!("{}: {} is not finite", model.name(), names[i]));
        }
        let p = params;
        let (fx, fy, cx, cy, k) = match model {
            LensModel::SimplePinhole => (p[0], p[0], p[1], p[2], [0.0; 4]),
            LensModel::Pinhole => (p[0], p[1], p[2], p[3], [0.0; 4]),
            LensModel::SimpleRadial => (p[0], p[0], p[1], p[2], [p[3], 0.0, 0.0, 0.0]),
            LensModel::Radial => (p[0], p[0], p[1], p[2], [p[3], p[4], 0.0, 0.0]),
            LensModel::OpenCv => (p[0], p[1], p[2], p[3], [p[4], p[5], p[6], p[7]]),
        };
        if !(fx > 0.0 && fy > 0.0) {
            return Err(format!(
                "{}: focal lengths must be positive ({} {fx}, {fy})",
                model.name(),
                names[0]
            ));
        }
        let mut lens = Lens {
            model,
            params: params.to_vec(),
            fx,
            fy,
            cx,
            cy,
            k,
            r2_fold: f64::INFINITY,
        };
        lens.r2_fold = lens.fold_radius2();
        Ok(lens)
    }

    /// Whether the model distorts at all (its distortion parameters are not all zero).
    pub fn distorts(&self) -> bool {
        self.k.iter().any(|&k| k != 0.0)
    }

    /// COLMAP's `Distortion`: `(du, dv)` at normalized `(u, v)`.
    pub fn distortion(&self, u: f64, v: f64) -> (f64, f64) {
        let [k1, k2, p1, p2] = self.k;
        let u2 = u * u;
        let uv = u * v;
        let v2 = v * v;
        let r2 = u2 + v2;
        let radial = k1 * r2 + k2 * r2 * r2;
        let du = u * radial + 2.0 * p1 * uv + p2 * (r2 + 2.0 * u2);
        let dv = v * radial + 2.0 * p2 * uv + p1 * (r2 + 2.0 * v2);
        (du, dv)
    }

    /// The Jacobian of `(u, v) -> (u + du, v + dv)`, rows `[d/du, d/dv]` of x then y.
    pub fn jacobian(&self, u: f64, v: f64) -> [[f64; 2]; 2] {
        let [k1, k2, p1, p2] = self.k;
        let r2 = u * u + v * v;
        let radial = k1 * r2 + k2 * r2 * r2;
        // d radial / du = g u, d radial / dv = g v
        let g = 2.0 * k1 + 4.0 * k2 * r2;
        let cross = g * u * v + 2.0 * p1 * u + 2.0 * p2 * v;
        [
            [
                1.0 + radial + g * u * u + 2.0 * p1 * v + 6.0 * p2 * u,
                cross,
            ],
            [
                cross,
                1.0 + radial + g * v * v + 2.0 * p2 * u + 6.0 * p1 * v,
            ],
        ]
    }

    /// COLMAP's `ImgFromCam` for normalized `(u, v)`: the continuous pixel coordinates.
    pub fn pixel(&self, u: f64, v: f64) -> (f64, f64) {
        let (du, dv) = self.distortion(u, v);
        (self.fx * (u + du) + self.cx, self.fy * (v + dv) + self.cy)
    }

    /// COLMAP's `CamFromImg`: normalized `(u, v)` of pixel `(x, y)`, and whether Newton's
    /// method converged (it does wherever the image is valid: see [`Lens::check_image`]).
    pub fn normalized(&self, x: f64, y: f64) -> ((f64, f64), bool) {
        let x0 = ((x - self.cx) / self.fx, (y - self.cy) / self.fy);
        if !self.distorts() {
            return (x0, true);
        }
        self.undistort(x0)
    }

    /// Newton's method on `(u, v) + distortion(u, v) = x0`, from `x0`, with COLMAP's trust
    /// region (a step at most `max(0.1 |x|, 0.1)` long).
    fn undistort(&self, x0: (f64, f64)) -> ((f64, f64), bool) {
        let tol = NEWTON_TOL_PX / self.fx.max(self.fy);
        let (mut u, mut v) = x0;
        for _ in 0..100 {
            let (du, dv) = self.distortion(u, v);
            let [[a, b], [c, d]] = self.jacobian(u, v);
            let det = a * d - b * c;
            if det == 0.0 || !det.is_finite() {
                return ((u, v), false);
            }
            let (ex, ey) = (u + du - x0.0, v + dv - x0.1);
            let (mut sx, mut sy) = ((d * ex - b * ey) / det, (a * ey - c * ex) / det);
            let radius2 = ((u * u + v * v) * 0.01).max(0.01);
            let step2 = sx * sx + sy * sy;
            if step2 > radius2 {
                let s = (radius2 / step2).sqrt();
                (sx, sy) = (sx * s, sy * s);
            }
            u -= sx;
            v -= sy;
            if sx * sx + sy * sy < tol * tol {
                return ((u, v), true);
            }
        }
        ((u, v), false)
    }

    /// Whether normalized `(u, v)` lies where the distortion is one-to-one (so a point there is
    /// imaged where [`Lens::pixel`] says).
    pub fn images(&self, u: f64, v: f64) -> bool {
        u * u + v * v < self.r2_fold
    }

    /// The smallest undistorted radius, squared, at which the distortion stops being one-to-one
    /// (its Jacobian's determinant reaches 0), searched along 64 directions out to
    /// [`FOLD_SEARCH`]; the last radius before it.
    fn fold_radius2(&self) -> f64 {
        if !self.distorts() {
            return f64::INFINITY;
        }
        const STEPS: usize = 4000;
        let mut fold = f64::INFINITY;
        for dir in 0..64 {
            let (sin, cos) = (dir as f64 * std::f64::consts::TAU / 64.0).sin_cos();
            for i in 1..=STEPS {
                let r = FOLD_SEARCH * i as f64 / STEPS as f64;
                if r >= fold {
                    break;
                }
                let [[a, b], [c, d]] = self.jacobian(r * cos, r * sin);
                if a * d - b * c <= 0.0 {
                    fold = FOLD_SEARCH * (i - 1) as f64 / STEPS as f64;
                    break;
                }
            }
        }
        fold * fold
    }

    /// The pixel positions checked on a `width x height` photo: 65 along each edge of the
    /// image (corners included) and a 17 x 17 grid inside.
    fn check_points(width: u32, height: u32) -> Vec<(f64, f64)> {
        let (w, h) = (width as f64, height as f64);
        let mut pts = Vec::new();
        for i in 0..=64 {
            let t = i as f64 / 64.0;
            pts.extend([(t * w, 0.0), (t * w, h), (0.0, t * h), (w, t * h)]);
        }
        for j in 0..=16 {
            for i in 0..=16 {
                pts.push((w * i as f64 / 16.0, h * j as f64 / 16.0));
            }
        }
        pts
    }

    /// Refuses a lens whose distortion is not one-to-one over a `width x height` photo: every
    /// checked pixel must go to a ray and back within 1e-6 pixels, inside the fold radius.
    pub fn check_image(&self, width: u32, height: u32) -> Result<(), String> {
        for (x, y) in Lens::check_points(width, height) {
            let ((u, v), ok) = self.normalized(x, y);
            let (bx, by) = self.pixel(u, v);
            let back = ((bx - x).powi(2) + (by - y).powi(2)).sqrt();
            if !ok || !self.images(u, v) || back.is_nan() || back > 1e-6 {
                return Err(format!(
                    "the {} distortion ({}) folds over the {width}x{height} image: pixel \
                     ({x}, {y}) has no unique ray",
                    self.model.name(),
                    self.describe()
                ));
            }
        }
        Ok(())
    }

    /// The range of normalized `(u_min, u_max, v_min, v_max)` a `width x height` photo sees
    /// (from its border, where a one-to-one distortion takes the image's outline), widened by
    /// 1% of its extent and two pixels so it holds the whole image.
    pub fn image_bounds(&self, width: u32, height: u32) -> [f64; 4] {
        let mut b = [
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ];
        for (x, y) in Lens::check_points(width, height) {
            let ((u, v), _) = self.normalized(x, y);
            b = [b[0].min(u), b[1].max(u), b[2].min(v), b[3].max(v)];
        }
        let mx = 0.01 * (b[1] - b[0]) + 2.0 / self.fx;
        let my = 0.01 * (b[3] - b[2]) + 2.0 / self.fy;
        [b[0] - mx, b[1] + mx, b[2] - my, b[3] + my]
    }

    /// The parameters as `name value` pairs: `fx 333.4, fy 333.4, cx 128, ...`.
    pub fn describe(&self) -> String {
        let names = self.model.param_names();
        let parts: Vec<String> = names
            .iter()
            .zip(&self.params)
            .map(|(n, p)| format!("{n} {p}"))
            .collect();
        parts.join(", ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lenses() -> Vec<Lens> {
        let l = |m: LensModel, p: &[f64]| Lens::new(m, p).unwrap();
        vec![
            l(LensModel::SimplePinhole, &[300.0, 130.0, 95.0]),
            l(LensModel::Pinhole, &[310.0, 290.0, 121.5, 140.25]),
            l(LensModel::SimpleRadial, &[305.0, 128.0, 96.0, -0.08]),
            l(LensModel::Radial, &[320.0, 133.0, 90.0, -0.05, 0.01]),
            l(
                LensModel::OpenCv,
                &[330.0, 315.0, 125.0, 101.0, -0.05, 0.01, 0.002, -0.0015],
            ),
            l(
                LensModel::OpenCv,
                &[333.45, 333.45, 128.0, 128.0, 0.06, 0.02, 0.0, 0.0],
            ),
        ]
    }

    /// One point per model, its pixel computed by hand from COLMAP's formulas, in the order
    /// COLMAP applies them: normalize, distort (radial then tangential terms added), then
    /// focal length and principal point.
    #[test]
    fn distortion_follows_colmap_formulas_by_hand() {
        let (u, v) = (0.3, -0.2);
        // r2 = 0.09 + 0.04 = 0.13, uv = -0.06
        let cases: [(LensModel, &[f64], (f64, f64)); 5] = [
            // x = 300 * 0.3 + 130 = 220, y = 300 * -0.2 + 95 = 35
            (
                LensModel::SimplePinhole,
                &[300.0, 130.0, 95.0],
                (220.0, 35.0),
            ),
            // x = 310 * 0.3 + 121.5 = 214.5, y = 290 * -0.2 + 140.25 = 82.25
            (
                LensModel::Pinhole,
                &[310.0, 290.0, 121.5, 140.25],
                (214.5, 82.25),
            ),
            // radial = -0.1 * 0.13 = -0.013; x = 305 * 0.3 * 0.987 + 128 = 218.3105,
            // y = 305 * -0.2 * 0.987 + 96 = 35.793
            (
                LensModel::SimpleRadial,
                &[305.0, 128.0, 96.0, -0.1],
                (218.3105, 35.793),
            ),
            // radial = -0.05 * 0.13 + 0.01 * 0.0169 = -0.006331; factor 0.993669;
            // x = 320 * 0.3 * 0.993669 + 133 = 228.392224, y = 320 * -0.2 * 0.993669 + 90
            // = 26.405184
            (
                LensModel::Radial,
                &[320.0, 133.0, 90.0, -0.05, 0.01],
                (228.392224, 26.405184),
            ),
            // radial = -0.006331 as above; p1 = 0.002, p2 = -0.0015:
            // du = 0.3 * -0.006331 + 2 * 0.002 * -0.06 + -0.0015 * (0.13 + 0.18)
            //    = -0.0018993 - 0.00024 - 0.000465 = -0.0026043
            // dv = -0.2 * -0.006331 + 2 * -0.0015 * -0.06 + 0.002 * (0.13 + 0.08)
            //    = 0.0012662 + 0.00018 + 0.00042 = 0.0018662
            // x = 330 * 0.2973957 + 125 = 223.140581, y = 315 * -0.1981338 + 101 = 38.587853
            (
                LensModel::OpenCv,
                &[330.0, 315.0, 125.0, 101.0, -0.05, 0.01, 0.002, -0.0015],
                (223.140581, 38.587853),
            ),
        ];
        for (model, params, want) in cases {
            let l = Lens::new(model, params).unwrap();
            let (x, y) = l.pixel(u, v);
            assert!(
                (x - want.0).abs() < 1e-6 && (y - want.1).abs() < 1e-6,
                "{}: ({x}, {y}) vs {want:?}",
                model.name()
            );
        }
    }

    /// Pixel -> normalized -> pixel round trips over the whole image, for every model, to
    /// well under 1e-4 pixels (Newton converges to 1e-9).
    #[test]
    fn pixel_round_trips_under_every_model() {
        for l in lenses() {
            l.check_image(256, 200).unwrap();
            for j in 0..=20 {
                for i in 0..=20 {
                    let (x, y) = (256.0 * i as f64 / 20.0, 200.0 * j as f64 / 20.0);
                    let ((u, v), ok) = l.normalized(x, y);
                    assert!(ok);
                    let (bx, by) = l.pixel(u, v);
                    let e = ((bx - x).powi(2) + (by - y).powi(2)).sqrt();
                    assert!(
                        e < 1e-6,
                        "{}: ({x}, {y}) back at ({bx}, {by})",
                        l.describe()
                    );
                }
            }
        }
    }

    /// The analytic Jacobian equals central differences of the distortion.
    #[test]
    fn jacobian_matches_finite_differences() {
        for l in lenses() {
            for &(u, v) in &[(0.3, -0.2), (-0.5, 0.4), (0.01, 0.7)] {
                let j = l.jacobian(u, v);
                let h = 1e-6;
                let f = |u: f64, v: f64| {
                    let (du, dv) = l.distortion(u, v);
                    (u + du, v + dv)
                };
                let (xp, yp) = f(u + h, v);
                let (xm, ym) = f(u - h, v);
                let (xq, yq) = f(u, v + h);
                let (xn, yn) = f(u, v - h);
                let fd = [
                    [(xp - xm) / (2.0 * h), (xq - xn) / (2.0 * h)],
                    [(yp - ym) / (2.0 * h), (yq - yn) / (2.0 * h)],
                ];
                for r in 0..2 {
                    for c in 0..2 {
                        assert!((j[r][c] - fd[r][c]).abs() < 1e-7, "{j:?} vs {fd:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn bad_parameters_and_folding_lenses_are_refused() {
        let e = Lens::new(LensModel::OpenCv, &[1.0, 2.0, 3.0]).unwrap_err();
        assert!(e.contains("OPENCV takes 8 parameters"), "{e}");
        let e = Lens::new(LensModel::Pinhole, &[-1.0, 2.0, 3.0, 4.0]).unwrap_err();
        assert!(e.contains("positive"), "{e}");
        let e = Lens::new(LensModel::Radial, &[1.0, 2.0, 3.0, f64::NAN, 0.0]).unwrap_err();
        assert!(e.contains("k1 is not finite"), "{e}");
        // k = -0.5: r (1 - 0.5 r^2) peaks at r = 0.816; a 90-degree lens reaches r = 1.41 in
        // its corners.
        let l = Lens::new(LensModel::SimpleRadial, &[100.0, 100.0, 100.0, -0.5]).unwrap();
        assert!((l.r2_fold.sqrt() - 0.8165).abs() < 0.01, "{}", l.r2_fold);
        let e = l.check_image(200, 200).unwrap_err();
        assert!(e.contains("folds over the 200x200 image"), "{e}");
        assert!(!l.images(1.0, 0.0) && l.images(0.5, 0.0));
        let small = Lens::new(LensModel::SimpleRadial, &[100.0, 10.0, 10.0, -0.5]).unwrap();
        assert!(small.check_image(20, 20).is_ok());
    }

    #[test]
    fn model_names_and_ids_are_colmaps() {
        for m in LensModel::ALL {
            assert_eq!(LensModel::from_name(m.name()), Some(m));
            assert_eq!(LensModel::from_id(m.id()), Some(m));
        }
        assert_eq!(LensModel::OpenCv.name(), "OPENCV");
        assert_eq!(COLMAP_MODELS[6], "FULL_OPENCV");
        assert!(refusal("FULL_OPENCV").starts_with("camera model FULL_OPENCV is not supported"));
        assert!(refusal("FOO").starts_with("unknown camera model FOO"));
    }
}
