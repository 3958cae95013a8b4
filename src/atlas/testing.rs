//! Test fixture shared by the stages' unit tests: a scene prepared at a given density, with
//! its geometry store and charts (built the way a run builds them).

use super::{build_geometry, RunContext};
use crate::atlas::store::TexelGeom;
use crate::atlas::store::TileStore;
use crate::atlas::texture::{Grid, Scratch, SlotTexture};
use crate::atlas::uv::AtlasSettings;
use crate::atlas::uv::Charts;
use crate::base::progress::Mode;
use crate::scene::{mesh, Emitter, Scene, Shape, Sides};

/// A prepared scene, its geometry store (in `dir`, beside any other store a test makes) and
/// charts.
pub struct Built {
    pub p: RunContext,
    pub dir: tempfile::TempDir,
    pub geom: TileStore<TexelGeom>,
    pub charts: Charts,
}

impl Built {
    /// `shapes` and `emitters` (no views) at `texels_per_unit`, with per-triangle density
    /// levels `levels[shape]` (missing or empty: one density).
    pub fn new(
        shapes: Vec<Shape>,
        emitters: Vec<Emitter>,
        texels_per_unit: f32,
        levels: Vec<Vec<u8>>,
    ) -> Built {
        let scene = Scene {
            path: "test.xml".into(),
            shapes,
            emitters,
            sensors: vec![],
            files: vec![],
        };
        let settings = AtlasSettings {
            texels_per_unit,
            ..Default::default()
        };
        let p = RunContext::with_levels(scene, &settings, levels, 16).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let geom = build_geometry(&p, &dir.path().join("geom.tiles"), Mode::Quiet).unwrap();
        let charts = Charts::new(&p.scene, &p.layout, &p.atlases).unwrap();
        Built {
            p,
            dir,
            geom,
            charts,
        }
    }

    /// A unit cube (one-sided, no emitters) at `texels_per_unit`.
    pub fn cube(texels_per_unit: f32) -> Built {
        let shape = Shape::plain("cube", mesh::cube(), Sides::Front);
        Built::new(vec![shape], vec![], texels_per_unit, vec![])
    }
}

/// A deterministic value in [-1, 1] per index (test noise).
pub fn jitter(i: usize) -> f32 {
    let h = (i as u64 + 1).wrapping_mul(0x9e37_79b9_7f4a_7c15);
    let h = (h ^ (h >> 29)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    ((h >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
}

/// The grid of a lone `w x h` texture in tiles of `ts x ts` texels.
pub fn grid(w: u32, h: u32, ts: u32) -> Grid {
    Grid {
        width: w,
        height: h,
        tile_size: ts,
        tiles_x: w.div_ceil(ts),
        tiles_y: h.div_ceil(ts),
        first_tile: 0,
    }
}

/// A texture of `f(x, y)` on grid `g`, whole or tiled as `s`'s budget allows (a budget of one
/// byte forces tiles).
pub fn texture<V: bytemuck::Pod + Send + Sync>(
    g: Grid,
    s: &Scratch,
    f: impl Fn(u32, u32) -> V + Sync,
) -> SlotTexture<V> {
    SlotTexture::build(g, s, "t", |t| {
        let mut out = vec![V::zeroed(); g.tile_texels()];
        for (off, x, y) in g.texels_of(t) {
            out[off] = f(x, y);
        }
        Ok(out)
    })
    .unwrap()
}

/// Every record of `store`, tile after tile.
pub fn all_records<T: bytemuck::Pod + Send + Sync>(store: &TileStore<T>) -> Vec<T> {
    (0..store.tile_count())
        .flat_map(|t| store.read_tile(t).unwrap())
        .collect()
}
