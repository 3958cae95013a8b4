//! Per-shape textures and maps (`textures/<id>_albedo.*`, `maps/<id>_*.exr|png`), from one
//! gather of each shape's texel records. Also builds each shape's re-render texture
//! `L_render = K_d / pi (E_d + E_i)`.

use super::plot::{draw_legend, fill, legend_height, ErrorScale, NO_DATA};
use crate::atlas::layout::{flags, TexelGeom, TexelState};
use crate::atlas::texels::dilate;
use crate::atlas::texture::gather;
use crate::atlas::tiles::TileStore;
use crate::atlas::Prepared;
use crate::fsio;
use crate::image::{auto_exposure, write_exr_rgb, write_pixmap_png, write_png_srgb};
use crate::{Error, Result};
use glam::Vec3;
use std::f32::consts::PI;
use std::path::Path;
use tiny_skia::Pixmap;

/// Dilation passes for the textures a renderer samples (albedo, re-render radiance): wider
/// than a bilinear footprint so mip-mapping viewers don't pull in the black background either.
pub const TEXTURE_DILATE_PASSES: u32 = 8;

fn arr(a: [f32; 3]) -> Vec3 {
    Vec3::from_array(a)
}

fn observed(s: &TexelState) -> bool {
    s.flags & flags::OBSERVED != 0
}

/// The re-rendered radiance of a texel, eq. (2): `K_d / pi * (E_d + E_i)`.
pub fn l_render(s: &TexelState) -> Vec3 {
    arr(s.k_d) / PI * (arr(s.e_d) + arr(s.e_i))
}

/// The "colorless" luminance of eq. (10): `L_render(c) / (K_d(c) / sum_c' K_d(c'))`.
/// Written as the equivalent `(E_d + E_i)(c) / pi * sum_c' K_d(c')`, which equals it wherever
/// `K_d(c) > 0` and stays finite where a channel of `K_d` is 0 (all of them: 0).
pub fn colorless(s: &TexelState) -> Vec3 {
    let sum = s.k_d[0] + s.k_d[1] + s.k_d[2];
    (arr(s.e_d) + arr(s.e_i)) / PI * sum
}

/// Count, per scale step, the observed texels whose relative error exceeds it, and pick the
/// run's error scale from that (see [`ErrorScale::from_exceedance`]).
pub fn error_scale(p: &Prepared, state: &TileStore<TexelState>) -> Result<ErrorScale> {
    let mut exceed = [0u64; 9];
    let mut total = 0u64;
    for t in 0..p.layout.tile_count as usize {
        for s in state.read_tile(t)? {
            if observed(&s) && s.error.is_finite() {
                total += 1;
                for (k, step) in ErrorScale::STEPS.iter().enumerate() {
                    exceed[k] += (s.error > *step) as u64;
                }
            }
        }
    }
    Ok(ErrorScale::from_exceedance(&exceed, total))
}

/// Write a texture `<dir>/<name>.exr` (dilated from `cov`) and its sRGB preview at
/// `exposure` stops.
fn write_texture(
    dir: &Path,
    name: &str,
    (w, h): (u32, u32),
    mut vals: Vec<Vec3>,
    cov: &[bool],
    exposure: f32,
) -> Result<()> {
    dilate(&mut vals, cov, w, h, TEXTURE_DILATE_PASSES)?;
    write_exr_rgb(dir.join(format!("{name}.exr")), w, h, &vals, false)?;
    write_png_srgb(dir.join(format!("{name}.png")), w, h, &vals, exposure)
}

/// Write a per-shape map `<dir>/<id>_<name>.exr` (gutter dilated) and, if asked, a PNG
/// preview at the automatic exposure.
pub fn write_map(
    dir: &Path,
    id: &str,
    name: &str,
    (width, height): (u32, u32),
    mut vals: Vec<Vec3>,
    cov: &[bool],
    png: bool,
) -> Result<()> {
    fsio::create_dir(dir)?;
    let exposure = auto_exposure(&vals, cov);
    dilate(&mut vals, cov, width, height, 4)?;
    write_exr_rgb(
        dir.join(format!("{id}_{name}.exr")),
        width,
        height,
        &vals,
        false,
    )?;
    if png {
        write_png_srgb(
            dir.join(format!("{id}_{name}.png")),
            width,
            height,
            &vals,
            exposure,
        )?;
    }
    Ok(())
}

/// Everything for one slot: albedo texture, the error / colorless / coverage / direct /
/// indirect / luminance maps. Returns the slot's dilated `L_render` texture for re-rendering.
pub fn write_slot(
    p: &Prepared,
    geom: &TileStore<TexelGeom>,
    state: &TileStore<TexelState>,
    slot: usize,
    out: &Path,
    scale: &ErrorScale,
) -> Result<Vec<Vec3>> {
    let st = p.layout.slots[slot];
    let id = p.slot_id(slot);
    let dims = (st.width, st.height);
    let textures = out.join("textures");
    let maps = out.join("maps");
    for d in [&textures, &maps] {
        fsio::create_dir(d)?;
    }
    let recs = gather(&p.layout, slot, state, geom, |s, g| (*s, g.covered()))?;
    let cov: Vec<bool> = recs.iter().map(|r| r.1).collect();
    let map =
        |f: &dyn Fn(&TexelState) -> Vec3| -> Vec<Vec3> { recs.iter().map(|r| f(&r.0)).collect() };

    write_texture(
        &textures,
        &format!("{id}_albedo"),
        dims,
        map(&|s| arr(s.k_d)),
        &cov,
        0.0,
    )?;
    let obs: Vec<bool> = recs.iter().map(|r| observed(&r.0)).collect();

    // Relative error: defined on observed texels only; 0 elsewhere (see the coverage map).
    let err = map(&|s| {
        Vec3::splat(if observed(s) && s.error.is_finite() {
            s.error
        } else {
            0.0
        })
    });
    write_error_png(
        &maps.join(format!("{id}_error.png")),
        dims,
        &err,
        &cov,
        &obs,
        scale,
    )?;
    let mut err_d = err;
    dilate(&mut err_d, &cov, st.width, st.height, 4)?;
    write_exr_rgb(
        maps.join(format!("{id}_error.exr")),
        st.width,
        st.height,
        &err_d,
        false,
    )?;

    write_map(&maps, id, "colorless", dims, map(&colorless), &cov, true)?;
    write_map(
        &maps,
        id,
        "coverage",
        dims,
        map(&|s| Vec3::splat(s.weight)),
        &cov,
        true,
    )?;
    write_map(&maps, id, "direct", dims, map(&|s| arr(s.e_d)), &cov, true)?;
    write_map(
        &maps,
        id,
        "indirect",
        dims,
        map(&|s| arr(s.e_i)),
        &cov,
        true,
    )?;
    write_map(
        &maps,
        id,
        "luminance",
        dims,
        map(&|s| arr(s.l_orig)),
        &obs,
        true,
    )?;

    let mut lr = map(&l_render);
    dilate(&mut lr, &cov, st.width, st.height, TEXTURE_DILATE_PASSES)?;
    Ok(lr)
}

/// The error map preview: observed texels coloured by `scale`, covered but unobserved ones
/// grey, gutter black; small maps magnified (nearest texel) to at least 256 pixels a side;
/// a legend bar underneath.
fn write_error_png(
    path: &Path,
    (w, h): (u32, u32),
    err: &[Vec3],
    cov: &[bool],
    obs: &[bool],
    scale: &ErrorScale,
) -> Result<()> {
    let f = (256 / w.max(h).max(1)).clamp(1, 8);
    let (iw, ih) = (w * f, h * f);
    let cw = iw.max(240);
    let font = if cw >= 600 { 2 } else { 1 };
    let ch = ih + legend_height(font) + 4;
    let mut pm = Pixmap::new(cw, ch).ok_or_else(|| {
        Error::internal(format!("{}: cannot make a {cw}x{ch} PNG", path.display()))
    })?;
    pm.fill(tiny_skia::Color::BLACK);
    let data = pm.data_mut();
    for y in 0..ih {
        for x in 0..iw {
            let i = ((y / f) * w + x / f) as usize;
            let c = if !cov[i] {
                [0, 0, 0]
            } else if !obs[i] {
                NO_DATA
            } else {
                scale.color(err[i].x)
            };
            let o = 4 * (y * cw + x) as usize;
            data[o..o + 4].copy_from_slice(&[c[0], c[1], c[2], 255]);
        }
    }
    fill(&mut pm, 0.0, ih as f32, cw as f32, 1.0, [0, 0, 0]);
    draw_legend(&mut pm, 0, ih as i32 + 2, cw, scale, font, [255, 255, 255]);
    write_pixmap_png(path, &pm)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colorless_is_eq_10_and_finite_on_black_channels() {
        let s = TexelState {
            k_d: [0.6, 0.3, 0.1],
            e_d: [2.0, 3.0, 4.0],
            e_i: [1.0, 0.5, 0.25],
            ..Default::default()
        };
        let l = l_render(&s);
        let c = colorless(&s);
        for k in 0..3 {
            let by_hand = l[k] / (s.k_d[k] / 1.0);
            assert!((c[k] - by_hand).abs() <= 1e-6 * by_hand, "{c} vs {l}");
        }
        let z = TexelState {
            k_d: [0.5, 0.0, 0.0],
            e_d: [1.0; 3],
            ..Default::default()
        };
        assert!(colorless(&z).is_finite());
        assert!(colorless(&TexelState::default()).is_finite());
    }
}
