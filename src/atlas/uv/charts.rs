//! Which chart (UV island) every triangle of each atlas lies on, and so every texel: a texel's
//! chart is the chart of the triangle owning its center (`TexelGeom::tri` of a covered
//! texel), [`NONE`] in the gutter. It decides whether a light hit on a triangle may be binned
//! into the texel under it (the texel must be on the same chart), and what texture-space
//! filters (E_i smoothing, the fill of unobserved texels) must not cross. Only per-triangle
//! tables are held: the per-texel answer comes from the geometry record at hand, so nothing
//! here grows with the texel count.

use crate::atlas::store::{Layout, TexelGeom};
use crate::atlas::uv::ShapeAtlas;
use crate::atlas::uv::{TexelMap, NONE};
use crate::base::error::{Error, Result};
use crate::scene::Scene;

/// One texel's value and its chart ([`NONE`]: none): what the window filters that stay within
/// a chart read (`project::noise_probe`'s noise, `direct::sampling`'s `E_d` roughness).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct ChartValue {
    pub v: f32,
    pub chart: u32,
}

/// Per slot, which chart each triangle lies on.
#[derive(Debug, Clone, PartialEq)]
pub struct SlotCharts {
    pub width: u32,
    pub height: u32,
    /// Per mesh triangle, its chart, or [`NONE`] (no texel-space area).
    pub tri_chart: Vec<u32>,
}

impl SlotCharts {
    /// The chart under the center of a texel with geometry record `g`: its triangle's chart
    /// if the texel is covered, else [`NONE`].
    #[inline]
    pub fn texel(&self, g: &TexelGeom) -> u32 {
        match g.covered() {
            true => self.tri_chart.get(g.tri as usize).copied().unwrap_or(NONE),
            false => NONE,
        }
    }
}

/// The surfaces light can land on: shape -> slot, and each slot's chart table. Built once per
/// run; 4 bytes per triangle.
#[derive(Debug, Clone, PartialEq)]
pub struct Charts {
    /// Per scene shape, its layout slot (`None`: emitter or otherwise not reconstructed; a
    /// photon hitting it is absorbed).
    pub slot_of_shape: Vec<Option<usize>>,
    pub slots: Vec<SlotCharts>,
}

impl Charts {
    /// `atlases[shape]` must be the atlas of every slot's shape, of the slot's size.
    #[inline(never)] // a stage entry tools/icount.py measures
    pub fn new(scene: &Scene, layout: &Layout, atlases: &[Option<ShapeAtlas>]) -> Result<Self> {
        let mut slot_of_shape = vec![None; scene.shapes.len()];
        let mut slots = Vec::with_capacity(layout.slots.len());
        for (slot, st) in layout.slots.iter().enumerate() {
            let shape = scene.shapes.get(st.shape).ok_or_else(|| {
                Error::internal(format!(
                    "layout slot {slot} names shape {}, the scene has {}",
                    st.shape,
                    scene.shapes.len()
                ))
            })?;
            let atlas = atlases
                .get(st.shape)
                .and_then(|a| a.as_ref())
                .filter(|a| (a.width, a.height) == (st.width, st.height))
                .ok_or_else(|| {
                    Error::internal(format!(
                        "shape '{}' has no {}x{} atlas for its slot",
                        shape.id, st.width, st.height
                    ))
                })?;
            if atlas.corner_uv.len() != shape.mesh.triangles.len() {
                return Err(Error::internal(format!(
                    "shape '{}': atlas has {} triangles, the mesh {}",
                    shape.id,
                    atlas.corner_uv.len(),
                    shape.mesh.triangles.len()
                )));
            }
            let map = TexelMap::new(&shape.mesh, atlas);
            let tri_chart = (0..shape.mesh.triangles.len() as u32)
                .map(|t| map.chart_of(t).unwrap_or(NONE))
                .collect();
            slot_of_shape[st.shape] = Some(slot);
            slots.push(SlotCharts {
                width: st.width,
                height: st.height,
                tri_chart,
            });
        }
        Ok(Charts {
            slot_of_shape,
            slots,
        })
    }

    /// The slot of scene shape `shape`, if photons can land on it.
    #[inline]
    pub fn slot_of_shape(&self, shape: usize) -> Option<usize> {
        self.slot_of_shape.get(shape).copied().flatten()
    }

    /// Every texel's chart of `slot`, row-major, read from the geometry store: a
    /// whole-texture array, for tests and small checks only.
    pub fn texel_charts(
        &self,
        layout: &Layout,
        slot: usize,
        geom: &crate::atlas::store::TileStore<TexelGeom>,
    ) -> Result<Vec<u32>> {
        let c = &self.slots[slot];
        crate::atlas::texture::read_slot(layout, slot, geom, geom, |g, _| c.texel(g))
    }
}
