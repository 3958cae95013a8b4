//! What an unwrap produces for one shape: the texture's size and every triangle's corners in
//! texel coordinates, with the settings that made it.

use crate::scene::Mesh;
use glam::Vec2;
use serde::{Deserialize, Serialize};

/// How a shape's atlas is made.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AtlasSettings {
    /// Texel density: texels per scene unit of length (a texel is `1 / texels_per_unit`
    /// scene units on a side).
    pub texels_per_unit: f32,
    /// Empty texels between charts (unwrapping only): room for dilation, so bilinear lookups
    /// near a chart edge never read another chart or the background.
    pub padding: u32,
    /// Keep the mesh's own UVs (OBJ convention, v up) instead of unwrapping.
    pub use_mesh_uvs: bool,
    /// Largest texture side accepted; a larger atlas is refused, never truncated.
    pub max_size: u32,
}

impl Default for AtlasSettings {
    fn default() -> Self {
        AtlasSettings {
            texels_per_unit: 64.0,
            padding: 2,
            use_mesh_uvs: false,
            max_size: 8192,
        }
    }
}

/// A shape's texture layout.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShapeAtlas {
    pub width: u32,
    pub height: u32,
    /// Per triangle (mesh order), its corners in texel units: `x` in `0..width` (right),
    /// `y` in `0..height` (down, row 0 = top of the image). Triangles that got no chart
    /// (degenerate ones) have all three corners on one point.
    pub corner_uv: Vec<[Vec2; 3]>,
    /// Number of charts (UV islands).
    pub charts: u32,
    /// Texels per scene unit actually used (on triangles at density level 0).
    pub texel_density: f32,
    /// The coarsest density level of its triangles: texels there are `2^levels` times as
    /// large (`crate::atlas::uv::LEVELS`; 0 for a uniform atlas).
    #[serde(default)]
    pub levels: u8,
}

impl ShapeAtlas {
    pub fn texel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// The density level of triangle `t` of `mesh` (its atlas): from the ratio of its texel
    /// and surface areas, `round(log2(texel_density / its density))`; 0 if degenerate.
    pub fn triangle_level(&self, mesh: &Mesh, t: usize) -> u8 {
        if self.levels == 0 {
            return 0;
        }
        let [a, b, c] = self.corner_uv[t];
        let texels = 0.5 * (b - a).perp_dot(c - a).abs();
        let area = mesh.triangle_area(t);
        if !(texels > 0.0 && area > 0.0) {
            return 0;
        }
        let d = (texels / area).sqrt();
        (self.texel_density / d)
            .log2()
            .round()
            .clamp(0.0, f32::from(self.levels)) as u8
    }

    /// Texels per scene unit on its coarsest triangles (`texel_density / 2^levels`): the
    /// density that spacings measured in texels must assume to stay fine enough everywhere.
    pub fn coarsest_density(&self) -> f32 {
        self.texel_density / f32::from(1u16 << self.levels)
    }

    /// The atlas of a shape without surface area: one texel, no chart.
    pub(super) fn empty(mesh: &Mesh, density: f32) -> Self {
        ShapeAtlas {
            width: 1,
            height: 1,
            corner_uv: vec![[Vec2::ZERO; 3]; mesh.triangles.len()],
            charts: 0,
            texel_density: density,
            levels: 0,
        }
    }
}
