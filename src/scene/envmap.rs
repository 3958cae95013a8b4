//! Environment light as Mitsuba 3.9 defines it (`src/emitters/envmap.cpp`, `constant.cpp`):
//! radiance arriving from infinitely far away, a function of direction only. Here because the
//! scene loader reads the map once, at load (so a bad map is refused before heavy work), and
//! every stage (direct light, photons, re-renders) evaluates and samples the same function.
//!
//! Mitsuba's lat-long convention, exactly: a world direction `w` is taken to the emitter's
//! frame, `d = to_world^-1 w`, then `u = atan2(d.x, -d.z) / 2 pi` (wrapped into [0, 1)) and
//! `v = acos(d.y) / pi` (row 0 is `+y`). The radiance is the map's bilinear interpolation with
//! texel-centred columns that wrap around (`x = u W - 1/2`) and rows pinned to the poles
//! (`y = v (H - 1)`: row 0 is exactly `+y`, row `H - 1` exactly `-y`), times `scale`. Maps
//! smaller than 2 x 3 are padded by repeating the last column and row, as Mitsuba's
//! `Bitmap::pad_to` does. A `constant` emitter is such a map with one radiance everywhere.
//!
//! Sampling (for shadow rays and photons): the sphere is cut into the cells between adjacent
//! texel centres (`W` columns x `H - 1` rows); inside a cell the radiance is exactly the
//! bilinear blend of its four corner texels, so the cell's weight, the exact integral of its
//! luminance over its solid angle, is zero only where the radiance is. A cell is chosen by
//! weight and a direction uniformly in solid angle inside it: the density is piecewise
//! constant and known in closed form ([`EnvMap::pdf`]), for multiple importance sampling.
//!
//! The map is read with the `exr` crate (OpenEXR) or the `image` crate's Radiance decoder
//! (`.hdr`, RGBE), directly: `crate::image` sits above the scene in the layering.

use crate::base::error::Error;
use crate::scene::{luminance, Rgb};
use crate::Result;
use glam::{Mat3, Mat4, Vec3};
use std::f64::consts::PI as PI64;
use std::path::{Path, PathBuf};

/// An environment emitter: a lat-long radiance map around the scene.
#[derive(Debug, Clone, PartialEq)]
pub struct EnvMap {
    /// The image file of an `envmap`, `None` for a `constant` emitter.
    pub file: Option<PathBuf>,
    /// Mitsuba's `scale` (already applied to the texels), kept for exporting the scene.
    pub scale: f32,
    /// A `constant` emitter's radiance (zero for a map).
    pub radiance: Rgb,
    /// Emitter-to-world (a rotation), kept for exporting the scene.
    pub to_world: Mat4,
    /// World-to-emitter rotation.
    from_world: Mat3,
    to_world3: Mat3,
    /// Map size after padding (at least 2 x 3).
    pub width: u32,
    pub height: u32,
    /// Row-major radiance times `scale`, row 0 = `+y`.
    texels: Vec<Rgb>,
    /// Per cell `j * W + i`, the cumulative cell weights, normalized (last = 1), and the
    /// cell's density per steradian (the selection probability over its solid angle): side
    /// by side, so a sample's search ends in the cache line its density is read from.
    cells: Vec<CdfCell>,
    /// Where [`Self::cell`] searches: entry `m` of `n + 1` (`n` cells) is the first cell whose
    /// CDF value exceeds `m / n`.
    guide: Vec<u32>,
    /// `integral of L over the sphere` per channel (steradian x radiance).
    integral: Rgb,
}

impl EnvMap {
    /// A `constant` emitter of radiance `radiance`: a 32 x 17 map of it (any size gives
    /// the same radiance; small cells let the stratified cell pick of the shadow rays spread
    /// them evenly over the sphere).
    pub fn constant(radiance: Rgb, to_world: Mat4) -> EnvMap {
        let texels = vec![radiance.max(Vec3::ZERO); 32 * 17];
        EnvMap::build(None, 1.0, radiance, to_world, 32, 17, texels)
    }

    /// An `envmap` read from `file` (`.exr` or `.hdr`), radiance times `scale`.
    pub fn load(file: &Path, scale: f32, to_world: Mat4) -> Result<EnvMap> {
        let (w, h, px) = read_map(file)?;
        if w == 0 || h == 0 || px.len() != w as usize * h as usize {
            return Err(Error::input(file, "environment map has no pixels"));
        }
        if let Some(bad) = px.iter().position(|p| !p.is_finite()) {
            let (x, y) = (bad % w as usize, bad / w as usize);
            return Err(Error::input(
                file,
                format!("environment map pixel ({x}, {y}) is not finite"),
            ));
        }
        Ok(EnvMap::from_pixels(
            Some(file.to_path_buf()),
            scale,
            to_world,
            w,
            h,
            px,
        ))
    }

    /// A map from row-major linear RGB pixels (row 0 = `+y`); negative values count as 0.
    pub fn from_pixels(
        file: Option<PathBuf>,
        scale: f32,
        to_world: Mat4,
        w: u32,
        h: u32,
        px: Vec<Rgb>,
    ) -> EnvMap {
        let (w2, h2) = (w.max(2), h.max(3));
        let mut texels = Vec::with_capacity((w2 * h2) as usize);
        for y in 0..h2 {
            for x in 0..w2 {
                let p = px[(y.min(h - 1) * w + x.min(w - 1)) as usize];
                texels.push(p.max(Vec3::ZERO) * scale);
            }
        }
        EnvMap::build(file, scale, Vec3::ZERO, to_world, w2, h2, texels)
    }

    fn build(
        file: Option<PathBuf>,
        scale: f32,
        radiance: Rgb,
        to_world: Mat4,
        width: u32,
        height: u32,
        texels: Vec<Rgb>,
    ) -> EnvMap {
        let to_world3 = orthonormalize(Mat3::from_mat4(to_world));
        let mut env = EnvMap {
            file,
            scale,
            radiance,
            to_world,
            from_world: to_world3.transpose(),
            to_world3,
            width,
            height,
            texels,
            cells: Vec::new(),
            guide: Vec::new(),
            integral: Vec3::ZERO,
        };
        env.distribution();
        env
    }

    /// Cell weights (exact luminance integrals), their CDF and densities, and `integral`.
    fn distribution(&mut self) {
        let (w, h) = (self.width as usize, self.height as usize);
        let dphi = 2.0 * PI64 / w as f64;
        let mut acc = 0.0f64;
        let mut integral = glam::DVec3::ZERO;
        let mut weights = Vec::with_capacity(w * (h - 1));
        let mut cdf = Vec::with_capacity(w * (h - 1));
        for j in 0..h - 1 {
            let (wa, wb) = row_weights(j, h);
            for i in 0..w {
                let i1 = (i + 1) % w;
                let top = (self.texel(i, j) + self.texel(i1, j)).as_dvec3() * 0.5;
                let bot = (self.texel(i, j + 1) + self.texel(i1, j + 1)).as_dvec3() * 0.5;
                let c = (top * wa + bot * wb) * dphi;
                integral += c;
                let y = luminance(c.as_vec3()) as f64;
                weights.push(y);
                acc += y;
                cdf.push(acc);
            }
        }
        self.integral = integral.as_vec3();
        if acc > 0.0 {
            cdf.iter_mut().for_each(|c| *c /= acc);
            *cdf.last_mut().expect("cells") = 1.0;
        }
        self.guide = guide(&cdf);
        let density = weights.iter().enumerate().map(|(k, &y)| match acc > 0.0 {
            true => (y / acc / cell_solid_angle(k / w, w, h)) as f32,
            false => 0.0,
        });
        self.cells = (cdf.iter().zip(density))
            .map(|(&cdf, density)| CdfCell { cdf, density })
            .collect();
    }

    fn texel(&self, x: usize, y: usize) -> Rgb {
        self.texels[y * self.width as usize + x]
    }

    /// Radiance arriving from world direction `dir` (towards the environment; any length).
    pub fn eval(&self, dir: Vec3) -> Rgb {
        let d = (self.from_world * dir).normalize_or_zero();
        let u = d.x.atan2(-d.z) * (0.5 / std::f32::consts::PI);
        let v = d.y.clamp(-1.0, 1.0).acos() / std::f32::consts::PI;
        self.eval_uv(u, v)
    }

    /// Mitsuba's bilinear lookup at lat-long coordinates `(u, v)`.
    fn eval_uv(&self, u: f32, v: f32) -> Rgb {
        let (w, h) = (self.width as usize, self.height as usize);
        let x = (u - u.floor()) * w as f32 - 0.5;
        let y = v.clamp(0.0, 1.0) * (h - 1) as f32;
        let (x0, y0) = (x.floor(), y.floor().min((h - 2) as f32));
        let (fx, fy) = (x - x0, y - y0);
        let xi = (x0 as i64).rem_euclid(w as i64) as usize;
        let (xj, yi) = ((xi + 1) % w, y0 as usize);
        let top = self.texel(xi, yi) * (1.0 - fx) + self.texel(xj, yi) * fx;
        let bot = self.texel(xi, yi + 1) * (1.0 - fx) + self.texel(xj, yi + 1) * fx;
        top * (1.0 - fy) + bot * fy
    }

    /// `integral of L(w) dw` over the sphere, per channel.
    pub fn integral(&self) -> Rgb {
        self.integral
    }

    /// The mean radiance over all directions.
    pub fn mean_radiance(&self) -> Rgb {
        self.integral / (4.0 * std::f32::consts::PI)
    }

    /// Whether the map emits anything (a zero map cannot be sampled).
    pub fn is_dark(&self) -> bool {
        self.cells.last().map(|c| c.cdf) != Some(1.0)
    }

    /// A world direction drawn with [`Self::pdf`] from uniform numbers `ucell` (the cell) and
    /// `(u1, u2)` (the point in it), and its density per steradian; `None` for a dark map.
    pub fn sample(&self, ucell: f64, u1: f32, u2: f32) -> Option<(Vec3, f32)> {
        if self.is_dark() {
            return None;
        }
        let k = self.cell(ucell).min(self.cells.len() - 1);
        let (w, h) = (self.width as usize, self.height as usize);
        let (i, j) = (k % w, k / w);
        let (c0, c1) = (row_theta(j, h).cos(), row_theta(j + 1, h).cos());
        let cos_t = c0 + (c1 - c0) * u2 as f64;
        let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
        let phi = 2.0 * PI64 * (i as f64 + 0.5 + u1 as f64) / w as f64;
        // Mitsuba's uv_to_direction: (sin phi sin t, cos t, -cos phi sin t).
        let d = glam::DVec3::new(phi.sin() * sin_t, cos_t, -phi.cos() * sin_t).as_vec3();
        Some(((self.to_world3 * d).normalize(), self.cells[k].density))
    }

    /// The first cell whose CDF value exceeds `u` (`cdf.len()` if none), as a binary search
    /// of the whole CDF finds it, searched between the guide's entries around `u` (a guide
    /// table, Chen and Asau 1974): one or two cells on average, where a search of the whole CDF
    /// of a 2k x 1k map misses the cache at most of its 21 steps (it took more than half of
    /// the living room's direct light even in blocks of 64). The guide's interval of `u` is
    /// widened by one on each side, so the rounding of `u n` cannot put `u` outside it.
    fn cell(&self, u: f64) -> usize {
        // below 0 and NaN: before every guide entry
        if u.is_nan() || u < 0.0 || self.guide.len() < 2 {
            return self.cells.partition_point(|c| c.cdf <= u);
        }
        let n = self.guide.len() - 1;
        let m = ((u * n as f64) as usize).min(n);
        let lo = self.guide[m.saturating_sub(1)] as usize;
        let hi = self.guide[(m + 2).min(n)] as usize;
        lo + self.cells[lo..hi].partition_point(|c| c.cdf <= u)
    }

    /// Density per steradian of [`Self::sample`] at world direction `dir`.
    pub fn pdf(&self, dir: Vec3) -> f32 {
        if self.is_dark() {
            return 0.0;
        }
        let d = (self.from_world * dir).normalize_or_zero();
        let (w, h) = (self.width as usize, self.height as usize);
        let u = d.x.atan2(-d.z) * (0.5 / std::f32::consts::PI);
        let x = (u - u.floor()) * w as f32 - 0.5;
        let i = (x.floor() as i64).rem_euclid(w as i64) as usize;
        let v = d.y.clamp(-1.0, 1.0).acos() / std::f32::consts::PI;
        let j = ((v * (h - 1) as f32).floor() as usize).min(h - 2);
        self.cells[j * w + i].density
    }
}

/// One cell of an environment map's sampling distribution ([`EnvMap::cells`]).
#[derive(Debug, Clone, Copy, PartialEq)]
struct CdfCell {
    cdf: f64,
    density: f32,
}

/// The guide table of a CDF of `n` non-decreasing values in [0, 1]: entry `m` (of `n + 1`) is
/// the first index whose value exceeds `m / n` (`n` if none), in one merge of the two.
fn guide(cdf: &[f64]) -> Vec<u32> {
    let n = cdf.len();
    let mut k = 0;
    (0..=n)
        .map(|m| {
            let x = m as f64 / n as f64;
            while k < n && cdf[k] <= x {
                k += 1;
            }
            k as u32
        })
        .collect()
}

/// The nearest rotation to `m` (columns normalized; the parser refuses anything else).
fn orthonormalize(m: Mat3) -> Mat3 {
    let x = m.x_axis.normalize_or_zero();
    let y = (m.y_axis - x * x.dot(m.y_axis)).normalize_or_zero();
    let z = x.cross(y);
    if x == Vec3::ZERO || y == Vec3::ZERO {
        return Mat3::IDENTITY;
    }
    Mat3::from_cols(x, y, z * m.z_axis.dot(z).signum())
}

/// Polar angle of texel row `j` of `h` rows (row 0 = `+y`, row `h - 1` = `-y`).
fn row_theta(j: usize, h: usize) -> f64 {
    PI64 * j as f64 / (h - 1) as f64
}

/// Solid angle of a cell of row `j` (between texel rows `j` and `j + 1`).
fn cell_solid_angle(j: usize, w: usize, h: usize) -> f64 {
    2.0 * PI64 / w as f64 * (row_theta(j, h).cos() - row_theta(j + 1, h).cos())
}

/// `(int (1 - t) sin t dt, int t sin t dt)` over the cell row `j`, `t` its fraction from row `j`
/// to row `j + 1`: the exact weights of the two rows in the cell's integral over theta.
fn row_weights(j: usize, h: usize) -> (f64, f64) {
    let (t0, t1) = (row_theta(j, h), row_theta(j + 1, h));
    let dt = t1 - t0;
    let s = t0.cos() - t1.cos();
    let wb = (t1.sin() - t0.sin()) / dt - t1.cos();
    (s - wb, wb)
}

/// Width, height and row-major linear RGB pixels of an `.exr` or `.hdr` file.
fn read_map(file: &Path) -> Result<(u32, u32, Vec<Rgb>)> {
    let ext = file
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    let bad = |what: String| Error::input(file, what);
    match ext.as_deref() {
        Some("exr") => read_exr(file).map_err(|e| bad(format!("cannot read environment map: {e}"))),
        Some("hdr") | Some("rgbe") | Some("pic") => {
            read_hdr(file).map_err(|e| bad(format!("cannot read environment map: {e}")))
        }
        _ => Err(bad(
            "environment maps must be OpenEXR (.exr) or Radiance (.hdr) files".to_string(),
        )),
    }
}

/// An OpenEXR file's width, height and linear RGB pixels (also the truth textures').
pub(super) fn read_exr(file: &Path) -> std::result::Result<(u32, u32, Vec<Rgb>), String> {
    use exr::prelude::*;
    if !file.is_file() {
        return Err("no such file".to_string());
    }
    let img = read_first_rgba_layer_from_file(
        file,
        |res, _| (res.width(), vec![Vec3::ZERO; res.width() * res.height()]),
        |(w, px): &mut (usize, Vec<Vec3>), pos, (r, g, b, _a): (f32, f32, f32, f32)| {
            px[pos.y() * *w + pos.x()] = Vec3::new(r, g, b);
        },
    )
    .map_err(|e| e.to_string())?;
    let size = img.layer_data.size;
    let (_, px) = img.layer_data.channel_data.pixels;
    Ok((size.width() as u32, size.height() as u32, px))
}

/// A Radiance HDR file's width, height and linear RGB pixels (also the truth textures').
pub(super) fn read_hdr(file: &Path) -> std::result::Result<(u32, u32, Vec<Rgb>), String> {
    use image::ImageDecoder;
    let f = std::fs::File::open(file).map_err(|e| e.to_string())?;
    let dec = image::codecs::hdr::HdrDecoder::new(std::io::BufReader::new(f))
        .map_err(|e| e.to_string())?;
    let (w, h) = dec.dimensions();
    let mut buf = vec![0f32; w as usize * h as usize * 3];
    dec.read_image(bytemuck::cast_slice_mut(&mut buf))
        .map_err(|e| e.to_string())?;
    let px = buf
        .chunks_exact(3)
        .map(|c| Vec3::new(c[0], c[1], c[2]))
        .collect();
    Ok((w, h, px))
}

#[cfg(test)]
mod tests;
