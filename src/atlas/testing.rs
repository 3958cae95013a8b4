//! Test fixture shared by the stages' unit tests: a unit cube, prepared at a given density,
//! with its geometry store and charts (built the way a run builds them).

use super::charts::Charts;
use super::layout::TexelGeom;
use super::tiles::TileStore;
use super::unwrap::AtlasSettings;
use super::{build_geometry, Prepared};
use crate::progress::Mode;
use crate::scene::{mesh, Scene, Shape, Sides};

/// A prepared cube, its geometry store (in `dir`) and charts.
pub struct Cube {
    pub p: Prepared,
    pub dir: tempfile::TempDir,
    pub geom: TileStore<TexelGeom>,
    pub charts: Charts,
}

impl Cube {
    /// The cube (one-sided, no emitters, no views) at `texels_per_unit`.
    pub fn new(texels_per_unit: f32) -> Cube {
        let shape = Shape {
            id: "cube".into(),
            kind: "test".into(),
            file: None,
            mesh: mesh::cube(),
            sides: Sides::Front,
            emission: None,
            reflectance: None,
            material: Default::default(),
        };
        let scene = Scene {
            path: "test.xml".into(),
            shapes: vec![shape],
            emitters: vec![],
            sensors: vec![],
            files: vec![],
        };
        let settings = AtlasSettings {
            texels_per_unit,
            ..Default::default()
        };
        let p = Prepared::new(scene, vec![], &settings, 16).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let geom = build_geometry(&p, &dir.path().join("geom.tiles"), Mode::Quiet).unwrap();
        let charts = Charts::new(&p.scene, &p.layout, &p.atlases).unwrap();
        Cube {
            p,
            dir,
            geom,
            charts,
        }
    }
}
