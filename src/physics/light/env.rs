//! Direct irradiance from an environment emitter (`envmap`, `constant`): light from every
//! direction, so it needs shadow rays everywhere and its estimate is always a sampled one.
//!
//! Per texel, `k x k` pairs of samples (`k^2 >= samples`), each pair one stratified point of
//! the texel's square and two directions: one drawn from the map by luminance
//! ([`EnvMap::sample`], its cell pick stratified over the pairs) and one cosine-weighted about
//! the normal (stratified over a `k x k` grid). They are combined with the balance heuristic
//! (multiple importance sampling), so each unoccluded direction contributes
//! `L(w) cos / (p_map(w) + cos / pi)`: a small bright sun is found by the map's samples, a
//! smooth sky by the cosine ones, and neither makes the other noisy. Every random number is a
//! function of the texel's key; the strata are paired by a keyed shuffle.

use super::Footprint;
use crate::base::rng::Rng;
use crate::physics::accel::{offset_origin, Accel};
use crate::scene::{luminance, EnvMap};
use glam::Vec3;
use std::f32::consts::PI;

/// Mean irradiance over `fp` from `env`, with shadows (`accel`), from about `samples` pairs.
/// `stream` = `(seed, emitter, texel)` keys the random numbers.
pub fn irradiance(
    env: &EnvMap,
    accel: Option<&Accel>,
    fp: &Footprint,
    samples: u32,
    stream: (u64, u64, u64),
) -> Vec3 {
    irradiance_var(env, accel, fp, samples, stream).0
}

/// [`irradiance`] and the variance of the luminance of that mean as if the pairs were
/// independent: their sample variance over their number (0 for one pair). The pairs are
/// stratified, so it is an upper bound: 1.4-2.4x the K_d noise on envmap's shapes.
pub fn irradiance_var(
    env: &EnvMap,
    accel: Option<&Accel>,
    fp: &Footprint,
    samples: u32,
    stream: (u64, u64, u64),
) -> (Vec3, f32) {
    let k = super::strata(samples);
    let n = (k * k) as usize;
    let mut rng = Rng::new(stream.0 ^ ENV_TAG, stream.1, stream.2, 0);
    let perm_map = shuffled(n, &mut rng);
    let perm_cos = shuffled(n, &mut rng);
    let perm_in = shuffled(n, &mut rng);
    let visible = |q: Vec3, d: Vec3| match accel {
        Some(a) => !a.occluded(offset_origin(q, fp.ng, d), d, f32::INFINITY),
        None => true,
    };
    let mut sum = Vec3::ZERO;
    let (mut y1, mut y2) = (0.0f64, 0.0f64);
    for j in 0..n {
        let mut pair = Vec3::ZERO;
        let (a, b) = (
            ((j % k as usize) as f32 + rng.f32()) / k as f32,
            ((j / k as usize) as f32 + rng.f32()) / k as f32,
        );
        let q = if fp.is_point() { fp.p } else { fp.at(a, b) };
        // the map's sample, its cell pick and its point in the cell stratified
        let ucell = (perm_map[j] as f64 + rng.f64()) / n as f64;
        let t = perm_in[j];
        let v1 = ((t % k as usize) as f32 + rng.f32()) / k as f32;
        let v2 = ((t / k as usize) as f32 + rng.f32()) / k as f32;
        if let Some((d, p_map)) = env.sample(ucell, v1, v2) {
            let cos = fp.n.dot(d);
            if cos > 0.0 && visible(q, d) {
                let v = env.eval(d) * (cos / (p_map + cos / PI));
                (sum, pair) = (sum + v, pair + v);
            }
        }
        // the cosine-weighted sample, stratified on a k x k grid
        let s = perm_cos[j];
        let u1 = ((s % k as usize) as f32 + rng.f32()) / k as f32;
        let u2 = ((s / k as usize) as f32 + rng.f32()) / k as f32;
        let d = cosine_dir(fp.n, u1, u2);
        let cos = fp.n.dot(d);
        if cos > 0.0 && visible(q, d) {
            let v = env.eval(d) * (cos / (env.pdf(d) + cos / PI));
            (sum, pair) = (sum + v, pair + v);
        }
        let y = luminance(pair) as f64;
        (y1, y2) = (y1 + y, y2 + y * y);
    }
    let nf = n as f64;
    let var = if n > 1 {
        ((y2 - y1 * y1 / nf).max(0.0) / (nf * (nf - 1.0))) as f32
    } else {
        0.0
    };
    (sum / n as f32, var)
}

/// Mixed into the seed of environment shadow samples.
const ENV_TAG: u64 = 0x5ad0_ed9e_0000_00e7;

/// `0..n` in an order drawn from `rng` (Fisher-Yates).
fn shuffled(n: usize, rng: &mut Rng) -> Vec<usize> {
    let mut v: Vec<usize> = (0..n).collect();
    for i in (1..n).rev() {
        let j = (rng.u64() % (i as u64 + 1)) as usize;
        v.swap(i, j);
    }
    v
}

/// The cosine-weighted direction about unit `n` for uniform `(u1, u2)` (Malley's method).
fn cosine_dir(n: Vec3, u1: f32, u2: f32) -> Vec3 {
    let r = u1.sqrt();
    let phi = 2.0 * PI * u2;
    let (t, b) = n.any_orthonormal_pair();
    (t * (r * phi.cos()) + b * (r * phi.sin()) + n * (1.0 - u1).max(0.0).sqrt()).normalize()
}

#[cfg(test)]
mod tests;
