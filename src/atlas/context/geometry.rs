//! The geometry store: for every texel of every atlas, where its center lies on the surface
//! (position, normals, triangle), the world area of its square and the part of that square on
//! its chart. A pure function of the scene and the atlas settings, so it is rebuilt rather than
//! checkpointed.

use crate::atlas::context::RunContext;
use crate::atlas::store::TileStore;
use crate::atlas::store::{flags, TexelGeom};
use crate::atlas::uv::{TexelMap, TexelSample};
use crate::base::error::Result;
use crate::base::progress::{Mode, Stage};
use rayon::prelude::*;
use std::path::Path;

/// Sub-samples per texel side used to measure a border texel's area on its chart.
const BIN_SUBSAMPLES: u32 = 8;

/// Rasterize every atlas into a new geometry store at `path` (texel -> surface point), one
/// row band of tiles at a time so memory stays bounded by a band, not a texture.
#[inline(never)] // a stage entry tools/icount.py measures
pub fn build_geometry(p: &RunContext, path: &Path, mode: Mode) -> Result<TileStore<TexelGeom>> {
    let mut store = p.create_store(path, TexelGeom::default())?;
    let total: u64 = p
        .layout
        .slots
        .iter()
        .map(|s| s.width as u64 * s.height as u64)
        .sum();
    let stage = Stage::new(mode, "atlas", total, "texels");
    let ts = p.layout.tile_size;
    for st in &p.layout.slots {
        let shape = &p.scene.shapes[st.shape];
        let atlas = p.atlases[st.shape].as_ref().expect("atlas");
        let map = TexelMap::new(&shape.mesh, atlas);
        for ty in 0..st.tiles_y {
            // one band of rows, with a row of margin each side for the border test
            let y0 = (ty * ts).saturating_sub(1);
            let y1 = ((ty + 1) * ts + 1).min(st.height);
            let band = Band {
                y0,
                width: st.width,
                height: st.height,
                samples: map.sample_rows(y0..y1),
            };
            let geo: Vec<Vec<TexelGeom>> = (0..st.tiles_x)
                .into_par_iter()
                .map(|tx| {
                    let span = p.layout.span(st.first_tile + ty * st.tiles_x + tx);
                    let mut recs = vec![TexelGeom::default(); p.layout.tile_texels()];
                    for (off, x, y) in span.texels() {
                        if let Some(g) = texel_geom(&map, &band, x, y) {
                            recs[off] = g;
                        }
                    }
                    recs
                })
                .collect();
            for (tx, recs) in geo.iter().enumerate() {
                let tile = st.first_tile + ty * st.tiles_x + tx as u32;
                store.write_tile(tile as usize, recs)?;
            }
            stage.inc(st.width as u64 * (((ty + 1) * ts).min(st.height) - ty * ts) as u64);
        }
    }
    stage.finish();
    Ok(store)
}

/// Texel-center samples of rows `y0..` of one texture.
struct Band {
    y0: u32,
    width: u32,
    height: u32,
    samples: Vec<Option<TexelSample>>,
}

impl Band {
    fn at(&self, x: u32, y: u32) -> Option<&TexelSample> {
        self.samples
            .get(((y - self.y0) * self.width + x) as usize)?
            .as_ref()
    }

    /// Whether texel `(x, y)` and its 8 neighbours all have their centers on the surface.
    fn interior(&self, x: u32, y: u32) -> bool {
        (-1i32..=1).all(|dy| {
            (-1i32..=1).all(|dx| {
                let (nx, ny) = (x as i32 + dx, y as i32 + dy);
                nx >= 0
                    && ny >= 0
                    && (nx as u32) < self.width
                    && (ny as u32) < self.height
                    && self.at(nx as u32, ny as u32).is_some()
            })
        })
    }
}

/// The geometry record of texel `(x, y)`, if its center lies on the surface. A border
/// texel's bin area is measured with sub-samples of its square.
fn texel_geom(map: &TexelMap, band: &Band, x: u32, y: u32) -> Option<TexelGeom> {
    let s = band.at(x, y)?;
    let bin_area = if band.interior(x, y) {
        s.area
    } else {
        map.subsamples(x, y, BIN_SUBSAMPLES)
            .iter()
            .map(|q| q.area)
            .sum()
    };
    let ng = map
        .mesh()
        .face_normal_raw(s.tri as usize)
        .normalize_or_zero();
    Some(TexelGeom {
        position: s.position.to_array(),
        normal: s.normal.to_array(),
        geo_normal: ng.to_array(),
        area: s.area,
        bin_area,
        tri: s.tri,
        flags: flags::COVERED,
    })
}
