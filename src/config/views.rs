//! The `[views]` table: which photo each sensor has, and how the photos were captured (their
//! exposure and white balance, whether their poses are refined, how 8-bit photos map to
//! linear values, a COLMAP model standing for the sensors). Read by hand from the TOML table,
//! not by serde's derive, because sensor ids and the settings share one table and every
//! refusal must name the key.

use super::Config;
use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The keys of `[views]` that are settings, not sensor ids.
pub const SETTINGS: &[&str] = &["exposure", "refine_pose", "response", "colmap", "to_world"];

/// How each photo's gain (exposure times white balance, per RGB channel) is found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Exposure {
    /// The photos are in the scene's radiance units as they are (gain 1).
    Known,
    /// Each photo's gain is estimated against the others and the known lights.
    Estimate,
}

/// How an 8-bit photo's code values become linear values (HDR photos are linear already).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Response {
    /// The sRGB transfer curve (IEC 61966-2-1), what cameras write into JPEGs.
    Srgb,
    /// Code values are linear.
    Linear,
    /// `(code / 255)^gamma`.
    Gamma(f32),
    /// A measured curve: the linear value of each of the 256 codes, increasing.
    Table(Vec<f32>),
}

/// The `[views]` table as read: photo paths by sensor id, per-view gains, the settings.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RawViews {
    pub photos: BTreeMap<String, PathBuf>,
    pub gains: BTreeMap<String, [f32; 3]>,
    pub exposure: Option<Exposure>,
    pub refine_pose: Option<bool>,
    pub response: Option<Response>,
    pub colmap: Option<PathBuf>,
    pub to_world: Option<[[f64; 4]; 4]>,
}

impl<'de> Deserialize<'de> for RawViews {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let table = toml::Table::deserialize(d)?;
        RawViews::from_table(table).map_err(serde::de::Error::custom)
    }
}

impl RawViews {
    fn from_table(table: toml::Table) -> std::result::Result<RawViews, String> {
        let mut v = RawViews::default();
        for (key, value) in table {
            match key.as_str() {
                "exposure" => v.exposure = Some(exposure(&value)?),
                "refine_pose" => {
                    v.refine_pose = Some(
                        value
                            .as_bool()
                            .ok_or("views.refine_pose: expected true or false")?,
                    )
                }
                "response" => v.response = Some(response(&value)?),
                "colmap" => v.colmap = Some(path(&value, "views.colmap")?),
                "to_world" => v.to_world = Some(matrix(&value)?),
                _ => v.view(key, value)?,
            }
        }
        Ok(v)
    }

    /// A sensor's entry: its photo's path, or a table `{ photo = "...", exposure = g }`.
    fn view(&mut self, id: String, value: toml::Value) -> std::result::Result<(), String> {
        match value {
            toml::Value::String(s) => {
                self.photos.insert(id, PathBuf::from(s));
            }
            toml::Value::Table(t) => {
                for (k, x) in t {
                    match k.as_str() {
                        "photo" => {
                            let p = path(&x, &format!("views.{id}.photo"))?;
                            self.photos.insert(id.clone(), p);
                        }
                        "exposure" => {
                            let g = gain(&x).map_err(|m| format!("views.{id}.exposure: {m}"))?;
                            self.gains.insert(id.clone(), g);
                        }
                        other => {
                            return Err(format!(
                                "views.{id}: unknown key '{other}' (expected photo, exposure)"
                            ))
                        }
                    }
                }
            }
            _ => {
                return Err(format!(
                    "views.{id}: expected a photo path or a table {{ photo = \"...\", exposure = \
                     ... }} (the settings of [views] are {})",
                    SETTINGS.join(", ")
                ))
            }
        }
        Ok(())
    }

    /// The table applied to `c`, paths resolved against `base` (the config's directory).
    pub(super) fn apply(self, base: &Path, c: &mut Config) {
        c.views = (self.photos.into_iter())
            .map(|(k, v)| (k, base.join(v)))
            .collect();
        c.pinned_gains = self.gains;
        if let Some(e) = self.exposure {
            c.exposure = e;
        }
        if let Some(r) = self.refine_pose {
            c.refine_pose = r;
        }
        if let Some(r) = self.response {
            c.response = r;
        }
        c.colmap = self.colmap.map(|p| base.join(p));
        c.colmap_to_world = self.to_world;
    }
}

fn exposure(v: &toml::Value) -> std::result::Result<Exposure, String> {
    match v.as_str() {
        Some("estimate") => Ok(Exposure::Estimate),
        Some("known") => Ok(Exposure::Known),
        _ => Err(format!(
            "views.exposure = {v}: expected \"estimate\" or \"known\""
        )),
    }
}

fn response(v: &toml::Value) -> std::result::Result<Response, String> {
    let bad = || {
        format!(
            "views.response = {v}: expected \"srgb\", \"linear\", a gamma (a number) or the 256 \
             linear values of the codes 0..=255"
        )
    };
    match v {
        toml::Value::String(s) if s == "srgb" => Ok(Response::Srgb),
        toml::Value::String(s) if s == "linear" => Ok(Response::Linear),
        toml::Value::Float(g) => Ok(Response::Gamma(*g as f32)),
        toml::Value::Integer(g) => Ok(Response::Gamma(*g as f32)),
        toml::Value::Array(a) if a.len() == 256 => a
            .iter()
            .map(|x| x.as_float().or(x.as_integer().map(|i| i as f64)))
            .map(|x| x.map(|x| x as f32).ok_or_else(bad))
            .collect::<std::result::Result<Vec<f32>, String>>()
            .map(Response::Table),
        _ => Err(bad()),
    }
}

fn path(v: &toml::Value, key: &str) -> std::result::Result<PathBuf, String> {
    v.as_str()
        .map(PathBuf::from)
        .ok_or_else(|| format!("{key}: expected a path (a string)"))
}

/// A gain: one number for every channel, or `[r, g, b]`.
fn gain(v: &toml::Value) -> std::result::Result<[f32; 3], String> {
    let num = |x: &toml::Value| x.as_float().or(x.as_integer().map(|i| i as f64));
    match v {
        toml::Value::Array(a) if a.len() == 3 => {
            let g: Option<Vec<f64>> = a.iter().map(num).collect();
            g.map(|g| [g[0] as f32, g[1] as f32, g[2] as f32])
                .ok_or_else(|| "expected a number or [r, g, b]".into())
        }
        _ => num(v)
            .map(|g| [g as f32; 3])
            .ok_or_else(|| "expected a number or [r, g, b]".into()),
    }
}

/// A 4x4 matrix as four rows of four numbers.
fn matrix(v: &toml::Value) -> std::result::Result<[[f64; 4]; 4], String> {
    let bad = || "views.to_world: expected four rows of four numbers".to_string();
    let rows = v.as_array().filter(|r| r.len() == 4).ok_or_else(bad)?;
    let mut m = [[0.0; 4]; 4];
    for (i, row) in rows.iter().enumerate() {
        let row = row.as_array().filter(|r| r.len() == 4).ok_or_else(bad)?;
        for (j, x) in row.iter().enumerate() {
            m[i][j] = x
                .as_float()
                .or(x.as_integer().map(|i| i as f64))
                .ok_or_else(bad)?;
        }
    }
    Ok(m)
}

/// The capture settings checked: gains positive, a response curve increasing from 0.
pub(super) fn validate(c: &Config) -> std::result::Result<(), String> {
    for (id, g) in &c.pinned_gains {
        if !g.iter().all(|v| v.is_finite() && *v > 0.0) {
            return Err(format!(
                "views.{id}.exposure = {g:?}: gains must be positive"
            ));
        }
    }
    match &c.response {
        Response::Gamma(g) if !(g.is_finite() && *g > 0.0) => {
            Err(format!("views.response = {g}: a gamma must be positive"))
        }
        Response::Table(t) if !t.windows(2).all(|w| w[1] >= w[0]) || t[0] < 0.0 => {
            Err("views.response: the 256 values must be increasing and not negative".into())
        }
        _ => Ok(()),
    }?;
    if let Some(m) = &c.colmap_to_world {
        if c.colmap.is_none() {
            return Err(
                "views.to_world is set but views.colmap is not: it maps a COLMAP \
                        model's frame to the scene's"
                    .into(),
            );
        }
        Similarity::from_rows(m)?;
    }
    Ok(())
}

/// A similarity transform `x -> scale rotation x + translation` (uniform scale, a proper
/// rotation): `[views] to_world`, from a COLMAP model's frame to the scene's.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity {
    pub scale: f64,
    pub rotation: DMat3,
    pub translation: DVec3,
}

/// How far `A^T A` of a similarity's 3x3 part `A` may be from `scale^2 I`, relative to
/// `scale^2`: rows of rotations typed with six decimals pass, a shear of 1e-4 does not.
const SIMILARITY_TOLERANCE: f64 = 1e-5;

impl Similarity {
    pub const IDENTITY: Similarity = Similarity {
        scale: 1.0,
        rotation: DMat3::IDENTITY,
        translation: DVec3::ZERO,
    };

    /// The similarity of a 4x4 matrix given as rows; refused, in one line naming
    /// `views.to_world`, when it is not one (shear, non-uniform scale, a mirror, a projective
    /// last row). The rotation is re-orthonormalized.
    pub fn from_rows(m: &[[f64; 4]; 4]) -> std::result::Result<Similarity, String> {
        let bad = |what: &str| Err(format!("views.to_world is not a similarity: {what}"));
        if !m.iter().flatten().all(|v| v.is_finite()) {
            return Err("views.to_world: every entry must be finite".into());
        }
        if m[3] != [0.0, 0.0, 0.0, 1.0] {
            return bad("its last row must be 0 0 0 1");
        }
        let a = DMat3::from_cols_array_2d(&[
            [m[0][0], m[1][0], m[2][0]],
            [m[0][1], m[1][1], m[2][1]],
            [m[0][2], m[1][2], m[2][2]],
        ]);
        let det = a.determinant();
        if !det.is_finite() || det <= 0.0 {
            return bad("its 3x3 part must have a positive determinant (no mirror, not singular)");
        }
        let scale = det.cbrt();
        let g = a.transpose() * a * (1.0 / (scale * scale));
        let off = (g - DMat3::IDENTITY).to_cols_array();
        if !off.iter().all(|x| x.abs() <= SIMILARITY_TOLERANCE) {
            return bad(
                "its 3x3 part shears or scales unevenly (A^T A is not a multiple of the identity)",
            );
        }
        let mut rotation = a * (1.0 / scale);
        for _ in 0..3 {
            rotation = (rotation + rotation.inverse().transpose()) * 0.5;
        }
        let translation = DVec3::new(m[0][3], m[1][3], m[2][3]);
        Ok(Similarity {
            scale,
            rotation,
            translation,
        })
    }

    /// The image of point `p`.
    pub fn point(&self, p: DVec3) -> DVec3 {
        self.rotation * p * self.scale + self.translation
    }
}
