//! Per-shape textures and maps (`textures/<id>_albedo.*`, `maps/<id>_*.exr|png`), each made
//! from the stores as a [`SlotTexture`] (whole when it fits the memory budget, else in tiles)
//! and written a row at a time, so no texture needs to fit in memory. Also builds each shape's
//! re-render texture `L_render = K_d / pi (E_d + E_i)`.

use super::page::{white_of, MapScale, ShapeFacts};
use super::plot::{legend_canvas, ErrorScale, LegendStyle, NO_DATA};
use crate::atlas::store::TileStore;
use crate::atlas::store::{flags, TexelGeom, TexelState};
use crate::atlas::texture::{Scratch, SlotTexture};
use crate::atlas::RunContext;
use crate::base::fsio;
use crate::image::{auto_exposure_with, srgb8, write_exr_rgb_fn, write_png_rows};
use crate::report::Confidence;
use crate::stages::confidence::{kd_stderr, ConfidenceSums};
use crate::Result;
use glam::Vec3;
use std::f32::consts::PI;
use std::path::Path;

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

/// One pass over the state for what the outputs need of all of it: the run's error scale
/// (count, per scale step, the observed texels whose relative error exceeds it, and pick the
/// scale from that, see [`ErrorScale::from_exceedance`]) and the confidence summary of
/// `report.json` (see `confidence`).
pub fn scan_state(
    p: &RunContext,
    state: &TileStore<TexelState>,
) -> Result<(ErrorScale, Confidence)> {
    let mut exceed = [0u64; 9];
    let mut total = 0u64;
    let mut confidence = ConfidenceSums::default();
    for t in 0..p.layout.tile_count as usize {
        for s in state.read_tile(t)? {
            confidence.add(&s);
            if observed(&s) && s.error.is_finite() {
                total += 1;
                for (k, step) in ErrorScale::STEPS.iter().enumerate() {
                    exceed[k] += (s.error > *step) as u64;
                }
            }
        }
    }
    Ok((
        ErrorScale::from_exceedance(&exceed, total),
        confidence.finish(),
    ))
}

/// A per-texel value of a map.
type TexelFn = dyn Fn(&TexelState) -> Vec3 + Sync;

/// Write a texture `<dir>/<name>.exr` (dilated from `cov`) and its sRGB preview at
/// `exposure` stops.
fn write_texture(
    dir: &Path,
    name: &str,
    vals: &SlotTexture<Vec3>,
    cov: &SlotTexture<u8>,
    exposure: f32,
    scratch: &Scratch,
) -> Result<()> {
    let vals = vals.dilated(cov, TEXTURE_DILATE_PASSES, scratch)?;
    write_exr(&dir.join(format!("{name}.exr")), &vals)?;
    write_png(&dir.join(format!("{name}.png")), &vals, exposure)
}

/// `tex` as a float OpenEXR image, read a row band at a time.
fn write_exr(path: &Path, tex: &SlotTexture<Vec3>) -> Result<()> {
    let g = tex.grid;
    write_exr_rgb_fn(path, g.width, g.height, false, |x, y| tex.get(x, y))?;
    tex.check()
}

/// `tex` as an sRGB PNG preview at `exposure` stops, a row at a time.
fn write_png(path: &Path, tex: &SlotTexture<Vec3>, exposure: f32) -> Result<()> {
    let g = tex.grid;
    let scale = exposure.exp2();
    write_png_rows(path, g.width, g.height, |y| {
        Ok(tex
            .row(y)
            .into_iter()
            .flat_map(|c| srgb8(c, scale))
            .collect())
    })?;
    tex.check()
}

/// The automatic exposure of `vals` over the texels of `mask` (see [`auto_exposure_with`]).
fn exposure_of(vals: &SlotTexture<Vec3>, mask: &SlotTexture<u8>) -> f32 {
    auto_exposure_with(|f| {
        for y in 0..vals.grid.height {
            for (v, m) in vals.row(y).into_iter().zip(mask.row(y)) {
                if m != 0 {
                    f(v);
                }
            }
        }
    })
}

/// Write a per-shape map `<dir>/<id>_<name>.exr` (gutter dilated) and, if asked, a PNG
/// preview at the automatic exposure over `cov`; returns the preview's scale.
pub fn write_map(
    dir: &Path,
    id: &str,
    name: &str,
    vals: &SlotTexture<Vec3>,
    cov: &SlotTexture<u8>,
    png: bool,
    scratch: &Scratch,
) -> Result<MapScale> {
    fsio::create_dir(dir)?;
    let exposure = exposure_of(vals, cov);
    let vals = vals.dilated(cov, 4, scratch)?;
    write_exr(&dir.join(format!("{id}_{name}.exr")), &vals)?;
    if png {
        write_png(&dir.join(format!("{id}_{name}.png")), &vals, exposure)?;
    }
    Ok(MapScale {
        name: name.to_string(),
        white: white_of(exposure),
    })
}

/// A shape's figures for the report page: area and texel counts, and the mean of `albedo`
/// over its observed texels (the mean error is added by [`mean_observed`]).
pub fn shape_facts(
    p: &RunContext,
    slot: usize,
    albedo: Option<&SlotTexture<Vec3>>,
    (cov, obs): (&SlotTexture<u8>, &SlotTexture<u8>),
) -> ShapeFacts {
    let covered: u64 = (0..cov.grid.height)
        .map(|y| cov.row(y).iter().filter(|&&c| c != 0).count() as u64)
        .sum();
    let observed: u64 = (0..obs.grid.height)
        .map(|y| obs.row(y).iter().filter(|&&o| o != 0).count() as u64)
        .sum();
    let st = &p.layout.slots[slot];
    ShapeFacts {
        shape: p.slot_id(slot).to_string(),
        area: p.scene.shapes[st.shape].mesh.area(),
        covered,
        observed,
        mean_kd: albedo
            .map(|a| (0..3).map(|k| mean_observed(a, obs, k)).collect::<Vec<_>>())
            .map(|v| [v[0], v[1], v[2]]),
        mean_error: None,
        maps: Vec::new(),
    }
}

/// The mean of channel `k` of `vals` over the texels of `obs`.
pub fn mean_observed(vals: &SlotTexture<Vec3>, obs: &SlotTexture<u8>, k: usize) -> f64 {
    let (mut sum, mut n) = (0f64, 0u64);
    for y in 0..vals.grid.height {
        for (v, o) in vals.row(y).into_iter().zip(obs.row(y)) {
            if o != 0 {
                sum += v[k] as f64;
                n += 1;
            }
        }
    }
    sum / n.max(1) as f64
}

/// Everything for one slot: albedo texture, the error / colorless / coverage / direct /
/// indirect / luminance / K_d standard error / disagreeing views maps, each made from the stores (whole or in tiles, within
/// `scratch`'s budget). Returns the slot's dilated `L_render` texture for re-rendering, made
/// within `keep` (it is kept while every view is re-rendered), and its figures for the page.
pub fn write_slot(
    p: &RunContext,
    geom: &TileStore<TexelGeom>,
    state: &TileStore<TexelState>,
    slot: usize,
    out: &Path,
    scale: &ErrorScale,
    (scratch, keep): (&Scratch, &Scratch),
) -> Result<(SlotTexture<Vec3>, ShapeFacts)> {
    let id = p.slot_id(slot);
    let textures = out.join("textures");
    let maps = out.join("maps");
    for d in [&textures, &maps] {
        fsio::create_dir(d)?;
    }
    let l = &p.layout;
    let tex = |name: &str, f: &TexelFn| {
        SlotTexture::read(l, slot, state, geom, scratch, name, |s, _| f(s))
    };
    let cov = SlotTexture::read(l, slot, state, geom, scratch, "cov", |_, g| {
        g.covered() as u8
    })?;
    let obs = SlotTexture::read(l, slot, state, geom, scratch, "obs", |s, _| {
        observed(s) as u8
    })?;

    let albedo = tex("albedo", &|s| arr(s.k_d))?;
    write_texture(
        &textures,
        &format!("{id}_albedo"),
        &albedo,
        &cov,
        0.0,
        scratch,
    )?;
    let mut facts = shape_facts(p, slot, Some(&albedo), (&cov, &obs));
    drop(albedo);

    // Relative error: defined on observed texels only; 0 elsewhere (see the coverage map).
    let err = tex("error", &|s| {
        Vec3::splat(if observed(s) && s.error.is_finite() {
            s.error
        } else {
            0.0
        })
    })?;
    write_error_png(
        &maps.join(format!("{id}_error.png")),
        &err,
        &cov,
        &obs,
        scale,
    )?;
    write_exr(
        &maps.join(format!("{id}_error.exr")),
        &err.dilated(&cov, 4, scratch)?,
    )?;
    facts.mean_error = Some(mean_observed(&err, &obs, 0));
    facts.maps.push(MapScale {
        name: "error".into(),
        white: scale.max,
    });
    drop(err);

    let each: [(&str, &TexelFn, &SlotTexture<u8>); 7] = [
        ("colorless", &colorless, &cov),
        ("coverage", &|s| Vec3::splat(s.weight), &cov),
        ("direct", &|s| arr(s.e_d), &cov),
        ("indirect", &|s| arr(s.e_i), &cov),
        ("luminance", &|s| arr(s.l_orig), &obs),
        ("kd_stderr", &kd_stderr, &obs),
        ("disagreement", &|s| Vec3::splat(s.disagree), &obs),
    ];
    for (name, f, mask) in each {
        facts.maps.push(write_map(
            &maps,
            id,
            name,
            &tex(name, f)?,
            mask,
            true,
            scratch,
        )?);
    }
    let radiance = SlotTexture::read(l, slot, state, geom, scratch, "l_render", |s, _| {
        l_render(s)
    })?
    .dilated(&cov, TEXTURE_DILATE_PASSES, keep)?;
    Ok((radiance, facts))
}

/// The error map preview: observed texels coloured by `scale`, covered but unobserved ones
/// grey, gutter black; small maps magnified (nearest texel) to at least 256 pixels a side;
/// a legend bar underneath. Streamed a row at a time.
fn write_error_png(
    path: &Path,
    err: &SlotTexture<Vec3>,
    cov: &SlotTexture<u8>,
    obs: &SlotTexture<u8>,
    scale: &ErrorScale,
) -> Result<()> {
    let (w, h) = (err.grid.width, err.grid.height);
    let f = (256 / w.max(h).max(1)).clamp(1, 8);
    let (iw, ih) = (w * f, h * f);
    let cw = iw.max(240);
    let legend = legend_canvas(cw, scale, &LegendStyle::light_on([0, 0, 0], cw))?;
    let lh = legend.height;
    let (mut last, mut rows) = (u32::MAX, (Vec::new(), Vec::new(), Vec::new()));
    write_png_rows(path, cw, ih + lh, |y| {
        if y >= ih {
            return Ok(legend.rgba_row(y - ih));
        }
        if y / f != last {
            last = y / f;
            rows = (err.row(last), cov.row(last), obs.row(last));
        }
        let mut row = vec![0u8; 4 * cw as usize];
        for x in 0..cw {
            let i = (x / f) as usize;
            let c = if x >= iw || rows.1[i] == 0 {
                [0, 0, 0]
            } else if rows.2[i] == 0 {
                NO_DATA
            } else {
                scale.color(rows.0[i].x)
            };
            row[4 * x as usize..4 * x as usize + 4].copy_from_slice(&[c[0], c[1], c[2], 255]);
        }
        Ok(row)
    })?;
    for t in [err.check(), cov.check(), obs.check()] {
        t?;
    }
    Ok(())
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
