//! Each photo's gain (exposure times white balance, per RGB channel): `photo = gain x
//! radiance`. A camera picks its own exposure and white balance per shot, so the photos of a
//! real capture are not in one unit; the projection divides each photo by its gain first.
//!
//! Two things fix the gains. **Relative** gains come from the views' overlap: a texel two
//! views see has one radiance, so their values at it differ by the ratio of their gains. Per
//! channel, `p_vt = g_v L_t` over a sample of texels is solved by alternating weighted least
//! squares (the texels' radiance given the gains, the gains given the radiance), robust to
//! texels where views disagree for other reasons (Cauchy weights on the relative residual).
//! Coated shapes' texels weigh little: their coat mirrors a different part of the scene into
//! each view, a disagreement that is not the gains' and that a large varnished floor under a
//! bright sky makes too common for the robust weights to set aside.
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
use crate::report::{GainSource, ViewCapture};
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
/// An anchor ratio (photo / emitted radiance) below this is taken for emitters the photo does
/// not show (hidden in a render): a real exposure 1000 times too dark would be black anyway.
const DARK_ANCHOR: f32 = 1e-3;
/// Weight of a coated shape's texels against a diffuse one's: its coat mirrors the scene, so
/// its radiance changes with the view; it links views only where nothing diffuse does.
const COATED_WEIGHT: f32 = 0.01;
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
#[inline(never)] // a stage entry tools/icount.py measures
pub fn estimate(
    p: &RunContext,
    cfg: &Config,
    views: &[View],
    ids: &[String],
    geom: &TileStore<TexelGeom>,
) -> Result<Vec<ViewCapture>> {
    let pinned = |i: usize| cfg.pinned_gains.get(&ids[i]).copied();
    if cfg.exposure == Exposure::Known {
        return Ok(name(
            (0..views.len())
                .map(|i| match pinned(i) {
                    Some(g) => ViewCapture::given(g, GainSource::Pinned),
                    None => ViewCapture::given([1.0; 3], GainSource::Known),
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
pub fn notes(gains: &[ViewCapture]) -> Vec<String> {
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
    for g in gains.iter() {
        if g.anchor_pixels >= MIN_ANCHOR_PIXELS as u64 && g.anchor_ratio.is_none() {
            out.push(format!(
                "view {} shows {} emitter pixels, but they are black or clipped in its photo: \
                 not used for the absolute scale",
                g.view, g.anchor_pixels
            ));
        }
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
fn name(mut gains: Vec<ViewCapture>, ids: &[String]) -> Vec<ViewCapture> {
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
            let damp = match p.scene.shapes[shape.index as usize].coated() {
                Some(_) => COATED_WEIGHT,
                None => 1.0,
            };
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
                            weight: weight * damp,
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

/// The sampled values flat, with each texel's range in them.
struct Flat {
    obs: Vec<Obs>,
    texels: Vec<std::ops::Range<usize>>,
}

impl Flat {
    fn new(groups: &[Vec<Obs>]) -> Flat {
        let mut obs = Vec::with_capacity(groups.iter().map(Vec::len).sum());
        let mut texels = Vec::with_capacity(groups.len());
        for g in groups {
            texels.push(obs.len()..obs.len() + g.len());
            obs.extend_from_slice(g);
        }
        Flat { obs, texels }
    }
}

/// Per view and channel, its gain relative to the others (geometric mean 1 over the views
/// that share texels; 1 for the others): alternating weighted least squares, robust. The
/// channels are solved side by side.
fn relative_gains(groups: &[Vec<Obs>], n: usize) -> Vec<[f64; 3]> {
    let flat = Flat::new(groups);
    let per: Vec<Vec<f64>> = (0..3)
        .into_par_iter()
        .map(|c| solve_channel(&flat, n, c))
        .collect();
    (0..n).map(|v| [per[0][v], per[1][v], per[2][v]]).collect()
}

/// [`relative_gains`] of channel `c`.
fn solve_channel(f: &Flat, n: usize, c: usize) -> Vec<f64> {
    let mut gain = vec![1.0f64; n];
    let mut robust = vec![1.0f64; f.obs.len()];
    let mut radiance = vec![0.0f64; f.texels.len()];
    for round in 0..ROUNDS {
        for (l, r) in radiance.iter_mut().zip(&f.texels) {
            *l = texel_radiance(&f.obs[r.clone()], &robust[r.clone()], &gain, c);
        }
        if round >= 4 {
            robust_weights(f, &radiance, &gain, c, &mut robust);
        }
        let (mut num, mut den) = (vec![0.0f64; n], vec![0.0f64; n]);
        for (r, &l) in f.texels.iter().zip(&radiance) {
            for (o, &rw) in f.obs[r.clone()].iter().zip(&robust[r.clone()]) {
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
fn texel_radiance(obs: &[Obs], robust: &[f64], gain: &[f64], c: usize) -> f64 {
    let (mut s, mut w) = (0.0, 0.0);
    for (o, &r) in obs.iter().zip(robust) {
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
/// times the residuals' robust spread (1.4826 x their median absolute value), into `out`.
fn robust_weights(f: &Flat, radiance: &[f64], gain: &[f64], c: usize, out: &mut [f64]) {
    let rel = |o: &Obs, l: f64| {
        if l > 0.0 {
            (o.value[c] as f64 / gain[o.view] - l) / l
        } else {
            0.0
        }
    };
    for (r, &l) in f.texels.iter().zip(radiance) {
        for (o, e) in f.obs[r.clone()].iter().zip(&mut out[r.clone()]) {
            *e = rel(o, l);
        }
    }
    let mut abs: Vec<f64> = out.iter().map(|e| e.abs()).collect();
    let sigma = match abs.len() {
        0 => 1.0,
        k => 1.4826 * *abs.select_nth_unstable_by(k / 2, f64::total_cmp).1,
    };
    let scale = (3.0 * sigma).max(1e-6);
    for e in out.iter_mut() {
        *e = 1.0 / (1.0 + (*e / scale).powi(2));
    }
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

/// A view's interior emitter pixels (masked ones too), and the median photo / radiance ratio
/// over the valid ones per channel if there are enough (see [`MIN_ANCHOR_PIXELS`]).
fn anchor(p: &RunContext, view: &View) -> (usize, Option<[f32; 3]>) {
    let (w, h) = (view.camera.width(), view.camera.height());
    let radiance: Vec<Option<Rgb>> = (0..h)
        .into_par_iter()
        .flat_map_iter(|y| (0..w).map(move |x| emitted(p, view, x, y)))
        .collect();
    let r = 1 + view.camera.filter().reach() as i64;
    let mut ratios: [Vec<f32>; 3] = Default::default();
    let mut n = 0;
    for y in 0..h as i64 {
        for x in 0..w as i64 {
            let Some(l) = radiance[(y * w as i64 + x) as usize] else {
                continue;
            };
            if !interior(&radiance, (w as i64, h as i64), (x, y), r, l) {
                continue;
            }
            n += 1;
            if !view.image.is_valid(x as u32, y as u32) {
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
    if ratios.iter().any(|r| r.len() < MIN_ANCHOR_PIXELS) {
        return (n, None);
    }
    let med = |v: &mut Vec<f32>| {
        let k = v.len() / 2;
        *v.select_nth_unstable_by(k, f32::total_cmp).1
    };
    let [mut a, mut b, mut c] = ratios;
    let ratio = [med(&mut a), med(&mut b), med(&mut c)];
    // emitters black in the photo (hidden in a render, or not the photo of this scene) say
    // nothing about its exposure
    let lum = 0.2126 * ratio[0] + 0.7152 * ratio[1] + 0.0722 * ratio[2];
    (n, (lum > DARK_ANCHOR).then_some(ratio))
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
    let scene = &p.scene;
    // the classification's center ray already says what the pixel sees
    let seen = view.pixels[(y * view.camera.width() + x) as usize].seen_shape();
    if seen.is_some_and(|s| scene.shapes[s as usize].emission.is_none()) {
        return None;
    }
    let (o, d) = view.camera.ray(x as f32 + 0.5, y as f32 + 0.5);
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
) -> Vec<ViewCapture> {
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
            ViewCapture {
                view: String::new(),
                gain,
                source: src,
                shared_texels: shared[v],
                anchor_pixels: anchors[v].0 as u64,
                anchor_ratio: anchors[v].1,
                check: None,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::base::rng::Rng;

    /// `texels` texels of random radiance seen by random subsets of views with gains `gains`,
    /// with relative noise `noise` and a share `bad` of wild values (highlights).
    fn synthetic(gains: &[[f64; 3]], texels: usize, noise: f32, bad: f32) -> Vec<Vec<Obs>> {
        (0..texels as u64)
            .map(|t| {
                let mut r = Rng::new(7, 0, 0, t);
                let l = Vec3::new(r.f32(), r.f32(), r.f32()) * 2.0 + Vec3::splat(0.05);
                let mut out = Vec::new();
                for (v, gain) in gains.iter().enumerate() {
                    if r.f32() >= 0.7 {
                        continue;
                    }
                    let g = Vec3::from_array(gain.map(|x| x as f32));
                    let mut value = g * l * (1.0 + noise * r.normal());
                    if r.f32() < bad {
                        value *= 4.0;
                    }
                    let weight = 0.5 + r.f32();
                    out.push(Obs {
                        view: v,
                        value,
                        weight,
                    });
                }
                out
            })
            .filter(|g| g.len() >= 2)
            .collect()
    }

    #[test]
    fn relative_gains_are_recovered_up_to_their_geometric_mean() {
        let gains = [
            [0.5, 0.55, 0.6],
            [1.9, 1.8, 1.7],
            [1.0, 1.0, 1.0],
            [0.8, 1.1, 1.3],
        ];
        let groups = synthetic(&gains, 4000, 0.02, 0.03);
        let got = relative_gains(&groups, gains.len());
        for c in 0..3 {
            let mean = gains.iter().map(|g| g[c].ln()).sum::<f64>() / gains.len() as f64;
            for (v, g) in gains.iter().enumerate() {
                let want = g[c] / mean.exp();
                let err = (got[v][c] / want - 1.0).abs();
                assert!(err < 2e-3, "view {v} channel {c}: {} vs {want}", got[v][c]);
            }
        }
        // without the robust weights the highlights would pull the gains by percent: they
        // are what the test's 3% of wild values would do to a plain least-squares fit
        let fit: f64 = got.iter().map(|g| g[1].ln()).sum();
        assert!(fit.abs() < 1e-9, "geometric mean 1: {fit}");
    }

    #[test]
    fn pins_then_emitters_then_the_geometric_mean_fix_the_scale() {
        let relative = [[0.5, 0.5, 0.5], [2.0, 2.0, 2.0], [1.0, 1.0, 1.0]];
        let shared = [100, 100, 0];
        let none = [(0, None), (0, None), (0, None)];
        // a pin on view 1 scales the linked view 0 by the same factor; view 2 is alone
        let pins = [None, Some([3.0, 3.0, 3.0]), None];
        let g = combine(&relative, &shared, &none, &pins);
        assert_eq!(g[1].gain, [3.0; 3]);
        assert_eq!(g[1].source, GainSource::Pinned);
        assert!((g[0].gain[0] - 0.75).abs() < 1e-6, "{:?}", g[0].gain);
        assert_eq!((g[2].gain, g[2].source), ([1.0; 3], GainSource::Alone));
        // an emitter seen by view 0 at ratio 0.6 sets the scale: 0.6 / 0.5
        let anchors = [(50, Some([0.6, 0.6, 0.6])), (0, None), (20, Some([4.0; 3]))];
        let g = combine(&relative, &shared, &anchors, &[None; 3]);
        assert!((g[1].gain[1] - 2.4).abs() < 1e-5, "{:?}", g[1].gain);
        assert_eq!(g[0].source, GainSource::Emitters);
        // view 2 shares nothing but shows an emitter: its own ratio
        assert_eq!((g[2].gain, g[2].source), ([4.0; 3], GainSource::Emitters));
        // nothing absolute: the relative gains as they are
        let g = combine(&relative, &shared, &none, &[None; 3]);
        assert_eq!((g[1].gain, g[1].source), ([2.0; 3], GainSource::Relative));
    }

    #[test]
    fn notes_say_when_the_scale_is_unknown() {
        let mut g = ViewCapture::given([1.2, 1.0, 0.9], GainSource::Relative);
        g.view = "cam".into();
        let notes = notes(&[g.clone()]);
        assert!(
            notes[0].contains("cam 1.0") && notes[0].contains("1.200/0.900"),
            "{notes:?}"
        );
        assert!(notes[1].contains("absolute exposure could not be told"));
        g.source = GainSource::Known;
        assert!(notes_of(&g).is_empty());
    }

    fn notes_of(g: &ViewCapture) -> Vec<String> {
        notes(std::slice::from_ref(g))
    }
}
