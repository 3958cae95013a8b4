//! Each photo's gain (exposure times white balance, per RGB channel): `photo = gain x
//! radiance`. A camera picks its own exposure and white balance per shot, so the photos of a
//! real capture are not in one unit; the projection divides each photo by its gain first.
//!
//! Two things fix the gains. **Relative** gains come from the views' overlap: a texel two
//! views see has one radiance, so their values at it differ by the ratio of their gains. Per
//! channel, `p_vt = g_v L_t` over a sample of texels is solved by alternating weighted least
//! squares (the texels' radiance given the gains, the gains given the radiance), robust to
//! texels where views disagree for other reasons (Cauchy weights on the relative residual).
//! The **absolute** scale is not in the diffuse surfaces at all: every albedo scaled by `s`
//! with every photo explains the scene as well (the light they exchange scales with them). It
//! comes from what the scene states in absolute units and a photo shows directly: emitters
//! (an area light's radiance, the sky of an environment map) seen by interior pixels that are
//! neither clipped nor masked; or from gains the run config pins (`[views.<id>] exposure`).
//! Without either, the gains' geometric mean is taken to be 1 and a note says so.
//!
//! Written here: no library solves gains against a texture atlas and a scene's emitters.

use super::{observe_texel, View};
use crate::atlas::store::{TexelGeom, TileStore};
use crate::atlas::RunContext;
use crate::base::error::Result;
use crate::config::{Config, Exposure};
use crate::image::Image;
use crate::physics::light::area::front_normal;
use crate::report::{GainSource, ViewGain};
use crate::scene::{Emitter, Rgb};
use glam::Vec3;
use rayon::prelude::*;

/// Texels sampled for the relative gains (spread evenly over the atlas).
const SAMPLES: u64 = 65_536;
/// Rounds of the alternating solve (it converges geometrically; 40 is far past the
/// float precision the gains are used at for the views' overlap graphs of real captures).
const ROUNDS: usize = 40;
/// Fewest emitter pixels a view needs to anchor the absolute scale.
const MIN_ANCHOR_PIXELS: usize = 9;
/// Fewest texels a view must share with the others for a relative gain.
const MIN_SHARED: usize = 16;
/// Largest spread of an environment map's radiance across one pixel (max / min luminance at
/// its corners and center) for the pixel to anchor: where the sky changes within a pixel (the
/// sun's disc, the horizon) the pixel's mean is not the radiance at its center.
const ENV_SMOOTH: f32 = 1.1;

/// One view's value of one sampled texel.
#[derive(Debug, Clone, Copy)]
struct Obs {
    view: usize,
    value: Vec3,
    weight: f32,
}

/// The gains of `views` (sensor ids `ids`) under `cfg`, from the texels of `geom`.
pub fn estimate(
    p: &RunContext,
    cfg: &Config,
    views: &[View],
    ids: &[String],
    geom: &TileStore<TexelGeom>,
) -> Result<Vec<ViewGain>> {
    let pinned = |i: usize| cfg.pinned_gains.get(&ids[i]).copied();
    if cfg.exposure == Exposure::Known {
        return Ok(name(
            (0..views.len())
                .map(|i| match pinned(i) {
                    Some(g) => ViewGain::given(g, GainSource::Pinned),
                    None => ViewGain::given([1.0; 3], GainSource::Known),
                })
                .collect(),
            ids,
        ));
    }
    let groups = observations(p, views, geom)?;
    let shared = shared_counts(&groups, views.len());
    let relative = relative_gains(&groups, views.len());
    let anchors: Vec<(usize, Option<[f32; 3]>)> = views.iter().map(|v| anchor(p, v)).collect();
    let pins: Vec<Option<[f32; 3]>> = (0..views.len()).map(pinned).collect();
    Ok(combine(&relative, &shared, &anchors, &pins)).map(|gains| name(gains, ids))
}

/// What a run says about its gains: one line, plus one where the absolute scale could not be
/// found or a view shares too little with the others.
pub fn notes(gains: &[ViewGain]) -> Vec<String> {
    let estimated = gains
        .iter()
        .any(|g| !matches!(g.source, GainSource::Known | GainSource::Pinned));
    if !estimated {
        return Vec::new();
    }
    let list: Vec<String> = (gains.iter())
        .map(|g| {
            let [r, gg, b] = g.gain;
            format!(
                "{} {:.3} (white balance {:.3}/{:.3})",
                g.view,
                g.exposure(),
                r / gg,
                b / gg
            )
        })
        .collect();
    let mut out = vec![format!(
        "photo gains (exposure, R/G, B/G): {}",
        list.join(", ")
    )];
    if gains.iter().any(|g| g.source == GainSource::Relative) {
        out.push(
            "the photos' absolute exposure could not be told: no view shows an unclipped \
             emitter and none is pinned, so the gains' geometric mean is taken as 1 (pin one \
             with [views.<id>] exposure = ..., or show the light in a photo)"
                .into(),
        );
    }
    for g in gains.iter().filter(|g| g.source == GainSource::Alone) {
        out.push(format!(
            "view {} shares {} sampled texels with the others and shows no emitter: its gain \
             is left at 1",
            g.view, g.shared_texels
        ));
    }
    out
}

/// The gains with their views' ids.
fn name(mut gains: Vec<ViewGain>, ids: &[String]) -> Vec<ViewGain> {
    for (g, id) in gains.iter_mut().zip(ids) {
        g.view = id.clone();
    }
    gains
}

/// Each photo divided by its gain (masked pixels stay masked).
pub fn apply(photo: &Image, gain: [f32; 3]) -> Image {
    let inv = Vec3::ONE / Vec3::from_array(gain);
    let mut out = photo.clone();
    for px in &mut out.pixels {
        *px *= inv;
    }
    out
}

/// The sampled texels' values in every view that sees them, grouped by texel (only texels
/// two or more views see), in tile order.
fn observations(
    p: &RunContext,
    views: &[View],
    geom: &TileStore<TexelGeom>,
) -> Result<Vec<Vec<Obs>>> {
    let covered: u64 = (0..geom.tile_count())
        .map(|t| Ok(geom.read_tile(t)?.iter().filter(|g| g.covered()).count() as u64))
        .sum::<Result<u64>>()?;
    let stride = covered.div_ceil(SAMPLES).max(1) as usize;
    let tiles: Vec<Vec<Vec<Obs>>> = (0..geom.tile_count())
        .into_par_iter()
        .map(|t| -> Result<Vec<Vec<Obs>>> {
            let g = geom.read_tile(t)?;
            let shape = p.shape_ref(p.layout.slot_of_tile(t as u32));
            let mut out = Vec::new();
            for (i, tg) in g.iter().enumerate().filter(|(_, g)| g.covered()) {
                if (t * g.len() + i) % stride != 0 {
                    continue;
                }
                let obs: Vec<Obs> = (views.iter().enumerate())
                    .filter_map(|(v, view)| {
                        let (value, weight) = observe_texel(view, &shape, tg)?;
                        Some(Obs {
                            view: v,
                            value,
                            weight,
                        })
                    })
                    .collect();
                if obs.len() >= 2 {
                    out.push(obs);
                }
            }
            Ok(out)
        })
        .collect::<Result<_>>()?;
    Ok(tiles.into_iter().flatten().collect())
}

/// Per view, how many sampled texels it shares with another view.
fn shared_counts(groups: &[Vec<Obs>], n: usize) -> Vec<u64> {
    let mut c = vec![0u64; n];
    for g in groups {
        for o in g {
            c[o.view] += 1;
        }
    }
    c
}

/// Per view and channel, its gain relative to the others (geometric mean 1 over the views
/// that share texels; 1 for the others): alternating weighted least squares, robust.
fn relative_gains(groups: &[Vec<Obs>], n: usize) -> Vec<[f64; 3]> {
    let mut out = vec![[1.0; 3]; n];
    for c in 0..3 {
        let g = solve_channel(groups, n, c);
        for v in 0..n {
            out[v][c] = g[v];
        }
    }
    out
}

/// [`relative_gains`] of channel `c`.
fn solve_channel(groups: &[Vec<Obs>], n: usize, c: usize) -> Vec<f64> {
    let mut gain = vec![1.0f64; n];
    let mut robust: Vec<Vec<f64>> = groups.iter().map(|g| vec![1.0; g.len()]).collect();
    for round in 0..ROUNDS {
        let radiance: Vec<f64> = (groups.iter().zip(&robust))
            .map(|(g, r)| texel_radiance(g, r, &gain, c))
            .collect();
        if round >= 4 {
            robust = robust_weights(groups, &radiance, &gain, c);
        }
        let (mut num, mut den) = (vec![0.0f64; n], vec![0.0f64; n]);
        for ((g, r), &l) in groups.iter().zip(&robust).zip(&radiance) {
            for (o, &rw) in g.iter().zip(r) {
                let w = o.weight as f64 * rw;
                num[o.view] += w * o.value[c] as f64 * l;
                den[o.view] += w * l * l;
            }
        }
        for v in 0..n {
            if den[v] > 0.0 && num[v] > 0.0 {
                gain[v] = num[v] / den[v];
            }
        }
        normalise(&mut gain, &den);
    }
    gain
}

/// A texel's radiance given the gains: the weighted mean of its views' values over their gains.
fn texel_radiance(g: &[Obs], robust: &[f64], gain: &[f64], c: usize) -> f64 {
    let (mut s, mut w) = (0.0, 0.0);
    for (o, &r) in g.iter().zip(robust) {
        let k = o.weight as f64 * r;
        s += k * o.value[c] as f64 / gain[o.view];
        w += k;
    }
    if w > 0.0 {
        s / w
    } else {
        0.0
    }
}

/// Cauchy weights of each value's relative residual against its texel's radiance, at three
/// times the residuals' robust spread (1.4826 x their median absolute value).
fn robust_weights(groups: &[Vec<Obs>], radiance: &[f64], gain: &[f64], c: usize) -> Vec<Vec<f64>> {
    let rel = |o: &Obs, l: f64| {
        if l > 0.0 {
            (o.value[c] as f64 / gain[o.view] - l) / l
        } else {
            0.0
        }
    };
    let mut all: Vec<f64> = (groups.iter().zip(radiance))
        .flat_map(|(g, &l)| g.iter().map(move |o| rel(o, l).abs()))
        .collect();
    let k = all.len() / 2;
    let sigma = if all.is_empty() {
        1.0
    } else {
        1.4826 * *all.select_nth_unstable_by(k, f64::total_cmp).1
    };
    let scale = (3.0 * sigma).max(1e-6);
    (groups.iter().zip(radiance))
        .map(|(g, &l)| {
            g.iter()
                .map(|o| 1.0 / (1.0 + (rel(o, l) / scale).powi(2)))
                .collect()
        })
        .collect()
}

/// Scale the gains of the views that share texels (`den > 0`) to geometric mean 1.
fn normalise(gain: &mut [f64], den: &[f64]) {
    let used: Vec<usize> = (0..gain.len()).filter(|&v| den[v] > 0.0).collect();
    if used.is_empty() {
        return;
    }
    let mean = used.iter().map(|&v| gain[v].ln()).sum::<f64>() / used.len() as f64;
    for &v in &used {
        gain[v] /= mean.exp();
    }
}

/// A view's interior emitter pixels, and the median photo / radiance ratio over them per
/// channel if there are enough (see [`MIN_ANCHOR_PIXELS`]).
fn anchor(p: &RunContext, view: &View) -> (usize, Option<[f32; 3]>) {
    let (w, h) = (view.camera.width(), view.camera.height());
    let radiance: Vec<Option<Rgb>> = (0..h)
        .into_par_iter()
        .flat_map_iter(|y| (0..w).map(move |x| emitted(p, view, x, y)))
        .collect();
    let r = 1 + view.camera.filter().reach() as i64;
    let mut ratios: [Vec<f32>; 3] = Default::default();
    for y in 0..h as i64 {
        for x in 0..w as i64 {
            let Some(l) = radiance[(y * w as i64 + x) as usize] else {
                continue;
            };
            if !interior(&radiance, (w as i64, h as i64), (x, y), r, l)
                || !view.image.is_valid(x as u32, y as u32)
            {
                continue;
            }
            let ph = view.image.get(x as u32, y as u32);
            for c in 0..3 {
                if l[c] > 0.0 {
                    ratios[c].push(ph[c] / l[c]);
                }
            }
        }
    }
    let n = ratios[1].len();
    if ratios.iter().any(|r| r.len() < MIN_ANCHOR_PIXELS) {
        return (n, None);
    }
    let med = |v: &mut Vec<f32>| {
        let k = v.len() / 2;
        *v.select_nth_unstable_by(k, f32::total_cmp).1
    };
    let [mut a, mut b, mut c] = ratios;
    (n, Some([med(&mut a), med(&mut b), med(&mut c)]))
}

/// Whether every pixel within `r` of `(x, y)` shows the same emitted radiance `l` (to 1%).
fn interior(
    radiance: &[Option<Rgb>],
    (w, h): (i64, i64),
    (x, y): (i64, i64),
    r: i64,
    l: Rgb,
) -> bool {
    (-r..=r).all(|dy| {
        (-r..=r).all(|dx| {
            let (nx, ny) = (x + dx, y + dy);
            nx >= 0
                && ny >= 0
                && nx < w
                && ny < h
                && radiance[(ny * w + nx) as usize]
                    .is_some_and(|m| (m - l).abs().max_element() <= 0.01 * l.max_element())
        })
    })
}

/// The radiance an emitter sends along pixel `(x, y)`'s center ray, if it sees one directly:
/// an area emitter's front side, or the environment where the ray escapes and the sky is
/// smooth across the pixel.
fn emitted(p: &RunContext, view: &View, x: u32, y: u32) -> Option<Rgb> {
    let (o, d) = view.camera.ray(x as f32 + 0.5, y as f32 + 0.5);
    let scene = &p.scene;
    match p.accel.intersect(o, d, f32::INFINITY) {
        Some(hit) => {
            let shape = &scene.shapes[hit.shape as usize];
            let l = shape.emission?;
            let front = front_normal(&shape.mesh, hit.tri as usize)?;
            (front.dot(d.as_dvec3()) < 0.0).then_some(l)
        }
        None => {
            let sky = |px: f32, py: f32| -> Option<Rgb> {
                let (_, d) = view.camera.ray(px, py);
                let envs = scene.emitters.iter().filter_map(|e| match e {
                    Emitter::Environment(env) => Some(env.eval(d)),
                    _ => None,
                });
                envs.reduce(|a, b| a + b)
            };
            let centre = sky(x as f32 + 0.5, y as f32 + 0.5)?;
            let corners = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]
                .map(|(i, j)| sky(x as f32 + i, y as f32 + j).unwrap_or(Vec3::ZERO));
            let ys = corners
                .iter()
                .chain([&centre])
                .map(|l| crate::scene::luminance(*l));
            let (lo, hi) = ys.fold((f32::MAX, 0.0f32), |(a, b), y| (a.min(y), b.max(y)));
            (lo > 0.0 && hi <= ENV_SMOOTH * lo).then_some(centre)
        }
    }
}

/// The gains from the relative ones, the views' anchors and the pins: pinned views keep
/// their pin and scale the rest (the geometric mean of pin / relative over them); else the
/// emitter anchors do (weighted by their pixels); else the relative gains stand as they are.
fn combine(
    relative: &[[f64; 3]],
    shared: &[u64],
    anchors: &[(usize, Option<[f32; 3]>)],
    pins: &[Option<[f32; 3]>],
) -> Vec<ViewGain> {
    let linked = |v: usize| shared[v] as usize >= MIN_SHARED;
    let scale = |refs: &[(usize, [f32; 3], f64)]| -> Option<[f64; 3]> {
        let w: f64 = refs.iter().map(|r| r.2).sum();
        (w > 0.0).then(|| {
            [0, 1, 2].map(|c| {
                let s: f64 = refs
                    .iter()
                    .map(|&(v, a, k)| k * (a[c] as f64 / relative[v][c]).ln())
                    .sum();
                (s / w).exp()
            })
        })
    };
    let pinned: Vec<(usize, [f32; 3], f64)> = (0..relative.len())
        .filter(|&v| linked(v))
        .filter_map(|v| pins[v].map(|g| (v, g, 1.0)))
        .collect();
    let anchored: Vec<(usize, [f32; 3], f64)> = (0..relative.len())
        .filter(|&v| linked(v))
        .filter_map(|v| anchors[v].1.map(|a| (v, a, anchors[v].0 as f64)))
        .collect();
    let (k, source) = match (scale(&pinned), scale(&anchored)) {
        (Some(k), _) => (k, GainSource::Pinned),
        (None, Some(k)) => (k, GainSource::Emitters),
        (None, None) => ([1.0; 3], GainSource::Relative),
    };
    (0..relative.len())
        .map(|v| {
            let (gain, src) = match (pins[v], linked(v), anchors[v].1) {
                (Some(g), _, _) => (g, GainSource::Pinned),
                (None, true, _) => ([0, 1, 2].map(|c| (k[c] * relative[v][c]) as f32), source),
                (None, false, Some(a)) => (a, GainSource::Emitters),
                (None, false, None) => ([1.0; 3], GainSource::Alone),
            };
            ViewGain {
                view: String::new(),
                gain,
                source: src,
                shared_texels: shared[v],
                anchor_pixels: anchors[v].0 as u64,
                anchor_ratio: anchors[v].1,
            }
        })
        .collect()
}
