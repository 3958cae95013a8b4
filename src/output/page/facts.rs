//! What the report page needs of a run beyond `report.json`, gathered while the outputs are
//! written and kept in `<out>/report/facts.json`, so `kdmap report` can rebuild the page from
//! the directory alone: per shape its area, texel counts, means and each map's colour scale;
//! per view the size of its value data.

use crate::base::error::{Error, Result};
use crate::base::fsio;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Everything the page knows that `report.json` does not hold.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Facts {
    /// The command that wrote the directory: `"reconstruct"` or `"project"`.
    pub command: String,
    /// Lines describing a run without `report.json` (`project`).
    pub summary: Vec<String>,
    pub shapes: Vec<ShapeFacts>,
    pub views: Vec<ViewFacts>,
    /// The relative error of the error colour scale's brightest colour (reconstruct).
    pub error_max: Option<f32>,
}

/// One texture's figures, over its texels.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ShapeFacts {
    pub shape: String,
    /// Surface area, scene units squared.
    pub area: f64,
    /// Texels on the surface, and those a view saw.
    pub covered: u64,
    pub observed: u64,
    /// Mean recovered `K_d` and mean relative error over the observed texels (reconstruct).
    pub mean_kd: Option<[f64; 3]>,
    pub mean_error: Option<f64>,
    /// Each map written, in order, with the value its PNG shows as white.
    pub maps: Vec<MapScale>,
}

/// A map's PNG preview: `maps/<shape>_<name>.png` shows `value / white` (per channel, sRGB).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MapScale {
    pub name: String,
    pub white: f32,
}

/// A view's images and value data under `report/views/`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ViewFacts {
    pub view: String,
    pub width: u32,
    pub height: u32,
    /// Pixels per value sample along each axis (the value data is subsampled on large photos).
    pub stride: u32,
}

/// The white level of a preview written at `exposure` stops.
pub fn white_of(exposure: f32) -> f32 {
    (-exposure).exp2()
}

impl Facts {
    /// `<page dir>/facts.json`.
    pub fn save(&self, dir: &Path) -> Result<()> {
        fsio::create_dir(dir)?;
        let text = serde_json::to_string_pretty(self)
            .map_err(|e| Error::internal(format!("cannot serialize the page facts: {e}")))?;
        fsio::write_atomic(&dir.join("facts.json"), text.as_bytes())
    }

    /// `<page dir>/facts.json`, or none (a directory written before the page existed).
    pub fn load(dir: &Path) -> Result<Facts> {
        let path = dir.join("facts.json");
        match std::fs::read_to_string(&path) {
            Ok(t) => serde_json::from_str(&t)
                .map_err(|e| Error::input(&path, format!("not a page facts file: {e}"))),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Facts::default()),
            Err(e) => Err(Error::io(&path, e)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn facts_round_trip_and_a_missing_file_is_none() {
        let tmp = tempfile::tempdir().unwrap();
        assert_eq!(Facts::load(tmp.path()).unwrap(), Facts::default());
        let f = Facts {
            command: "project".into(),
            shapes: vec![ShapeFacts {
                shape: "floor".into(),
                covered: 10,
                maps: vec![MapScale {
                    name: "coverage".into(),
                    white: 2.0,
                }],
                ..Default::default()
            }],
            ..Default::default()
        };
        f.save(tmp.path()).unwrap();
        assert_eq!(Facts::load(tmp.path()).unwrap(), f);
        assert_eq!(white_of(1.0), 0.5);
    }
}
