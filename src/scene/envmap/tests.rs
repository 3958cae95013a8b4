//! The lat-long convention, the exact integral and the sampling density of [`EnvMap`], against
//! Mitsuba's formulas written out independently and brute-force quadrature.

use super::*;
use crate::base::rng::Rng;
use std::f32::consts::PI;

/// Mitsuba's `uv_to_direction`.
fn dir_of(u: f32, v: f32) -> Vec3 {
    let (t, p) = (v * PI, u * 2.0 * PI);
    Vec3::new(p.sin() * t.sin(), t.cos(), -p.cos() * t.sin())
}

/// A `w x h` map whose texel `(x, y)` is `f(x, y)`.
fn map(w: u32, h: u32, to_world: Mat4, f: impl Fn(u32, u32) -> Vec3) -> EnvMap {
    let px = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| f(x, y))
        .collect();
    EnvMap::from_pixels(None, 1.0, to_world, w, h, px)
}

fn varied(x: u32, y: u32) -> Vec3 {
    Vec3::new(
        1.0 + x as f32,
        2.0 + (x * 7 + y * 3) as f32 % 5.0,
        0.5 + y as f32,
    )
}

#[test]
fn texel_centres_and_poles_follow_mitsubas_lat_long_layout() {
    let (w, h) = (8, 5);
    let env = map(w, h, Mat4::IDENTITY, varied);
    for y in 1..h - 1 {
        for x in 0..w {
            let d = dir_of((x as f32 + 0.5) / w as f32, y as f32 / (h - 1) as f32);
            let got = env.eval(d);
            assert!(
                (got - varied(x, y)).abs().max_element() < 1e-3,
                "({x}, {y}): {got}"
            );
        }
    }
    // u = 0 (direction -z) is halfway between the last and the first column; +y is row 0.
    let want = (varied(w - 1, 2) + varied(0, 2)) * 0.5;
    assert!((env.eval(dir_of(0.0, 0.5)) - want).abs().max_element() < 1e-3);
    assert!((env.eval(-Vec3::Z) - want).abs().max_element() < 1e-3);
    // at the poles u is arbitrary (as in Mitsuba): only the row counts (z is constant along rows)
    let top = env.eval(dir_of(0.5 / w as f32, 0.0));
    assert!((top.z - varied(0, 0).z).abs() < 1e-3, "{top}");
    let bottom = env.eval(dir_of(3.5 / w as f32, 1.0));
    assert!((bottom.z - varied(3, h - 1).z).abs() < 1e-3, "{bottom}");
}

#[test]
fn to_world_rotates_the_map_and_small_maps_are_padded() {
    let rot = Mat4::from_rotation_y(0.7);
    let (a, b) = (map(8, 5, Mat4::IDENTITY, varied), map(8, 5, rot, varied));
    for d in [
        Vec3::X,
        Vec3::new(0.3, 0.2, -0.9),
        Vec3::new(-0.5, -0.6, 0.1),
    ] {
        let d = d.normalize();
        let r = rot.transform_vector3(d);
        assert!((a.eval(d) - b.eval(r)).abs().max_element() < 1e-3);
        assert!((a.pdf(d) - b.pdf(r)).abs() <= 1e-4 * a.pdf(d));
    }
    // A 1 x 1 map is Mitsuba's 2 x 3 of that pixel: a constant.
    let one = map(1, 1, Mat4::IDENTITY, |_, _| Vec3::new(1.0, 2.0, 3.0));
    assert_eq!((one.width, one.height), (2, 3));
    assert!((one.eval(Vec3::new(0.2, -0.4, 0.3)) - Vec3::new(1.0, 2.0, 3.0)).length() < 1e-5);
}

/// Brute-force `integral of g(w) dw` on a fine (theta, phi) midpoint grid.
fn quadrature(g: impl Fn(Vec3) -> f64) -> f64 {
    let (nt, np) = (600, 1200);
    let mut s = 0.0f64;
    for i in 0..nt {
        let t = (i as f64 + 0.5) / nt as f64 * PI64;
        for j in 0..np {
            let p = (j as f64 + 0.5) / np as f64 * 2.0 * PI64;
            let d = glam::DVec3::new(p.sin() * t.sin(), t.cos(), -p.cos() * t.sin());
            s += g(d.as_vec3()) * t.sin();
        }
    }
    s * (PI64 / nt as f64) * (2.0 * PI64 / np as f64)
}

#[test]
fn the_integral_is_exact_and_the_density_integrates_to_one() {
    let c = EnvMap::constant(Vec3::new(1.0, 0.5, 0.25), Mat4::IDENTITY);
    let want = Vec3::new(1.0, 0.5, 0.25) * 4.0 * PI;
    assert!((c.integral() - want).abs().max_element() < 1e-4);
    assert!((c.pdf(Vec3::X) - 1.0 / (4.0 * PI)).abs() < 1e-6);
    let env = map(16, 9, Mat4::from_rotation_x(0.3), |x, y| {
        varied(x, y) * (1.0 + 20.0 * (y == 3 && x < 4) as u32 as f32)
    });
    for ch in 0..3 {
        let q = quadrature(|d| env.eval(d)[ch] as f64);
        let got = env.integral()[ch] as f64;
        assert!((got - q).abs() < 1e-3 * q, "channel {ch}: {got} vs {q}");
    }
    let p = quadrature(|d| env.pdf(d) as f64);
    assert!((p - 1.0).abs() < 2e-3, "density integrates to {p}");
    assert!((env.mean_radiance() - env.integral() / (4.0 * PI)).length() < 1e-6);
}

#[test]
fn samples_have_the_stated_density_and_estimate_the_integral() {
    let env = map(16, 9, Mat4::from_rotation_y(1.1), |x, y| {
        varied(x, y) * (1.0 + 50.0 * (y == 2 && (5..7).contains(&x)) as u32 as f32)
    });
    let n = 200_000;
    let (mut s, mut s2) = (0.0f64, 0.0f64);
    for i in 0..n {
        let mut r = Rng::new(3, 0, 0, i);
        let (d, pdf) = env.sample(r.f64(), r.f32(), r.f32()).unwrap();
        assert!((d.length() - 1.0).abs() < 1e-4);
        assert!(
            (env.pdf(d) - pdf).abs() <= 1e-3 * pdf,
            "{} vs {pdf}",
            env.pdf(d)
        );
        let x = luminance(env.eval(d)) as f64 / pdf as f64;
        s += x;
        s2 += x * x;
    }
    let m = s / n as f64;
    let se = ((s2 / n as f64 - m * m) / n as f64).sqrt();
    let want = luminance(env.integral()) as f64;
    assert!(
        (m - want).abs() <= 4.0 * se + 1e-6 * want,
        "{m} +- {se} vs {want}"
    );
    // importance sampling by luminance: the estimate is nearly noise-free
    assert!(se < 0.01 * want, "{se}");
}

#[test]
fn a_dark_map_cannot_be_sampled() {
    let env = map(4, 3, Mat4::IDENTITY, |_, _| Vec3::ZERO);
    assert!(env.is_dark());
    assert!(env.sample(0.5, 0.5, 0.5).is_none());
    assert_eq!(env.pdf(Vec3::Y), 0.0);
}

#[test]
fn reads_exr_and_radiance_hdr_files_and_refuses_other_formats() {
    let dir = tempfile::tempdir().unwrap();
    let exr_path = dir.path().join("sky.exr");
    let px = |x: usize, y: usize| (x as f32 + 1.0, y as f32 * 2.0 + 0.5, 0.25);
    exr::prelude::write_rgb_file(&exr_path, 4, 3, px).unwrap();
    let env = EnvMap::load(&exr_path, 2.0, Mat4::IDENTITY).unwrap();
    assert_eq!((env.width, env.height), (4, 3));
    let want = Vec3::new(2.0 * 2.0, 2.0 * (2.0 + 0.5), 0.5);
    let got = env.eval(dir_of(1.5 / 4.0, 0.5));
    assert!((got - want).abs().max_element() < 1e-4, "{got} vs {want}");
    // Radiance RGBE, flat (not run-length encoded) scanlines: 1.0 = (128, 128, 128, 129).
    let hdr_path = dir.path().join("sky.hdr");
    let mut bytes = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 3 +X 2\n".to_vec();
    for k in 0..6u8 {
        bytes.extend_from_slice(&[128, 64 + k, 32, 129]);
    }
    std::fs::write(&hdr_path, bytes).unwrap();
    let env = EnvMap::load(&hdr_path, 1.0, Mat4::IDENTITY).unwrap();
    assert_eq!((env.width, env.height), (2, 3));
    // texel (1, 1) is the 4th pixel: (1, (64 + 3) / 128, 0.25)
    let got = env.eval(dir_of(1.5 / 2.0, 0.5));
    let want = Vec3::new(1.0, 67.0 / 128.0, 0.25);
    assert!((got - want).abs().max_element() < 1e-3, "{got} vs {want}");
    let png = dir.path().join("sky.png");
    std::fs::write(&png, b"x").unwrap();
    let e = EnvMap::load(&png, 1.0, Mat4::IDENTITY)
        .unwrap_err()
        .to_string();
    assert!(e.contains("sky.png") && e.contains(".exr"), "{e}");
    let e = EnvMap::load(&dir.path().join("none.exr"), 1.0, Mat4::IDENTITY).unwrap_err();
    assert!(e.to_string().contains("none.exr"), "{e}");
}

#[test]
fn the_guided_cell_search_finds_what_a_search_of_the_whole_cdf_finds() {
    // sizes whose cell counts are and are not multiples of the block; a map with dark runs
    // (repeated CDF values) and one with a single bright texel
    let bright = |x: u32, y: u32| Vec3::splat(if (x, y) == (5, 3) { 9.0 } else { 0.0 });
    let banded = |x: u32, y: u32| {
        Vec3::splat(if (x / 7 + y) % 3 == 0 {
            0.0
        } else {
            1.0 + x as f32
        })
    };
    for (w, h) in [(64u32, 33u32), (50, 21), (8, 5), (300, 151)] {
        let maps = [
            map(w, h, Mat4::IDENTITY, varied),
            map(w, h, Mat4::IDENTITY, bright),
        ];
        for env in maps.iter().chain([&map(w, h, Mat4::IDENTITY, banded)]) {
            let cdf: Vec<f64> = env.cells.iter().map(|c| c.cdf).collect();
            let whole = |u: f64| cdf.partition_point(|&c| c <= u);
            let mut us: Vec<f64> = (0..2000).map(|i| i as f64 / 1999.0).collect();
            us.extend(cdf.iter().step_by(7).copied());
            us.extend(cdf.iter().step_by(7).map(|&c| c - 1e-12));
            us.extend([-1.0, 0.0, 1.0, 2.0, f64::NAN, 1.0 - 1e-16]);
            // the guide's own bounds and a hair either side
            let n = cdf.len() as f64;
            for m in (0..=cdf.len()).step_by(3) {
                let b = m as f64 / n;
                us.extend([b, b - 1e-15, b + 1e-15, f64::from_bits(b.to_bits() + 1)]);
            }
            for u in us {
                assert_eq!(env.cell(u), whole(u), "{w}x{h}, u = {u}");
            }
        }
    }
}
